//! The P2OS and rFLEX drivers' async shells against the mock's own devices ([`P2osDevice`],
//! [`RflexDevice`]) on a robot of a simulated world, served over an in-memory duplex
//! ([`DuplexDevice`]) with the world stepped on tokio's clock: paused (virtual) time.

use std::time::Duration;

use ima_hal::base::{Bumpers, DifferentialBase, Odometer, VelocityCommand};
use ima_hal::sonar::SonarArray;
use ima_mock_devices::body::WorldBody;
use ima_mock_devices::duplex::{DuplexDevice, DuplexOptions};
use ima_mock_devices::model::DeviceModel;
use ima_mock_devices::p2os::{P2osDevice, P2osModelConfig};
use ima_mock_devices::rflex::{RflexDevice, RflexModelConfig};
use ima_mock_devices::stepper::TokioWorldStepper;
use ima_mock_devices::world::{RobotSpec, SharedWorld, SonarModel, Wall, World};
use ima_p2os::shell::Driver as _;
use ima_p2os::shell::{FixedBaud, P2os};
use ima_rflex::shell::Rflex;
use tokio::io::DuplexStream;

/// What a test keeps alive while it talks to the driver.
type Served<M> = (DuplexDevice<M>, TokioWorldStepper);

/// Robot `spec` facing a wall at x = `wall_x` (exact single-ray sonar, no noise), its
/// firmware `device(body)` served on an in-memory pipe: the host end and what to keep.
fn serve<M: DeviceModel + 'static>(
    spec: RobotSpec,
    wall_x: f64,
    device: impl FnOnce(WorldBody) -> M,
) -> (DuplexStream, Served<M>) {
    let mut w = World::new();
    let id = w.add_robot(spec).unwrap();
    let wall = Wall {
        from: [wall_x, -5.0],
        to: [wall_x, 5.0],
    };
    w.add_wall(wall).unwrap();
    let world = SharedWorld::new(w);
    let sonar = SonarModel {
        rays: 1,
        noise_std_m: 0.0,
        ..SonarModel::default()
    };
    let body = WorldBody::new(world.clone(), id, 7).with_sonar(sonar);
    let (host, dev) = DuplexDevice::spawn(device(body), DuplexOptions::default());
    let stepper = TokioWorldStepper::spawn(world, Duration::from_millis(10));
    (host, (dev, stepper))
}

/// The P2OS driver connected to a Pioneer 2-AT at the origin, a wall at x = `wall_x`.
async fn p2os(wall_x: f64) -> (P2os, Served<P2osDevice>) {
    let mut spec = RobotSpec::new("skeeter", 0.0, 0.0, 0.0);
    spec.track_width_m = 0.588;
    spec.radius_m = 0.33;
    spec.max_wheel_accel_m_s2 = Some(1.0);
    let (host, served) = serve(spec, wall_x, |b| {
        P2osDevice::new(P2osModelConfig::default(), b)
    });
    let clock = ima_hal::time::TokioClock::shared();
    let cfg = ima_p2os::Config::default();
    let p2os = P2os::connect(FixedBaud(host), cfg, Duration::from_secs(5), clock);
    (p2os.await.unwrap(), served)
}

/// The rFLEX driver connected to an ATRV-Jr at the origin, a wall at x = 3 m.
async fn rflex() -> (Rflex, Served<RflexDevice>) {
    let spec = RobotSpec::new("scooter", 0.0, 0.0, 0.0);
    let (host, served) = serve(spec, 3.0, |b| {
        RflexDevice::new(RflexModelConfig::default(), b)
    });
    let clock = ima_hal::time::TokioClock::shared();
    let cfg = ima_rflex::machine::Config::default();
    let base = Rflex::connect(host, cfg, Duration::from_secs(5), clock);
    (base.await.unwrap(), served)
}

/// Command `v` m/s straight ahead `times` times, every 200 ms (a live client: no
/// watchdog stop).
async fn drive<B: DifferentialBase>(base: &mut B, v: f64, times: u32) {
    for _ in 0..times {
        base.set_velocity(VelocityCommand::new(v, 0.0))
            .await
            .unwrap();
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
}

#[tokio::test(start_paused = true)]
async fn p2os_connects_enables_drives_and_sees_the_wall() {
    let (mut p2os, _served) = p2os(2.0).await;
    assert_eq!(p2os.params().subclass, "p2at");
    p2os.enable_motors(true).await.unwrap();
    let start = p2os.odometry().await.unwrap();
    drive(&mut p2os, 0.2, 25).await;
    p2os.stop().await.unwrap();
    tokio::time::sleep(Duration::from_secs(2)).await;
    let end = p2os.odometry().await.unwrap();
    let dx = end.value.x_m() - start.value.x_m();
    assert!(dx > 0.8 && dx < 1.05, "dx = {dx}");
    // Front sonars 3/4 look at the wall 2 m − dx − 0.245 m ahead.
    let scan = p2os.sonar().await.unwrap();
    let r3 = scan.value.get(3).unwrap().range_m;
    let expect = 2.0 - end.value.x_m() - 0.245;
    assert!(
        (r3 * 10f64.to_radians().cos() - expect).abs() < 0.05,
        "r3 {r3} expect {expect}"
    );
    assert_eq!(p2os.transducers().len(), 16);
    assert_eq!(p2os.stats().framer.bad_checksums, 0);
}

#[tokio::test(start_paused = true)]
async fn p2os_motors_refuse_to_move_before_enable() {
    let (mut p2os, _served) = p2os(10.0).await;
    let start = p2os.odometry().await.unwrap();
    drive(&mut p2os, 0.3, 10).await;
    let end = p2os.odometry().await.unwrap();
    assert!((end.value.x_m() - start.value.x_m()).abs() < 1e-9);
    assert!(!p2os.latest().unwrap().motors_enabled);
}

#[tokio::test(start_paused = true)]
async fn rflex_drives_sees_the_wall_and_feels_the_bumper() {
    let (mut base, _served) = rflex().await;
    // Brake first.
    assert!(
        base.set_velocity(VelocityCommand::new(0.2, 0.0))
            .await
            .is_err()
    );
    base.enable_motors(true).await.unwrap();
    let start = base.odometry().await.unwrap();
    drive(&mut base, 0.2, 25).await;
    base.stop().await.unwrap();
    tokio::time::sleep(Duration::from_secs(2)).await;
    let end = base.odometry().await.unwrap();
    let dx = end.value.x_m() - start.value.x_m();
    assert!(dx > 0.9 && dx < 1.05, "dx = {dx}");
    // Sonar 0 (0.40 m ahead, straight on) sees the wall 3 − dx − 0.40 m away.
    tokio::time::sleep(Duration::from_secs(1)).await;
    let scan = base.sonar().await.unwrap();
    let r0 = scan.value.get(0).unwrap().range_m;
    let expect = 3.0 - end.value.x_m() - 0.40;
    assert!((r0 - expect).abs() < 0.01, "r0 {r0} expect {expect}");
    assert_eq!(base.bumpers().await.unwrap().value.front, 0);
    // On to the wall: the front bumper closes before the robot reaches it.
    for _ in 0..100 {
        if base.bumpers().await.unwrap().value.front == 1 {
            break;
        }
        base.set_velocity(VelocityCommand::new(0.2, 0.0))
            .await
            .unwrap();
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    base.stop().await.unwrap();
    let bump = base.bumpers().await.unwrap().value;
    assert_eq!((bump.front, bump.rear), (1, 0));
    let x = base.odometry().await.unwrap().value.x_m();
    assert!(x > 2.0 && x < 3.0, "bumped at x = {x}");
    let st = base.stats();
    assert_eq!(st.framer.bad_checksums, 0);
    assert_eq!(st.session.odometry_rejected, 0);
    base.close().await.unwrap();
}

#[tokio::test(start_paused = true)]
async fn rflex_emergency_stop_engages_the_brake_and_the_watchdog_stops_a_quiet_client() {
    let (mut base, _served) = rflex().await;
    base.enable_motors(true).await.unwrap();
    // One command, then silence: the driver's 0.5 s watchdog zeroes it.
    base.set_velocity(VelocityCommand::new(0.3, 0.0))
        .await
        .unwrap();
    tokio::time::sleep(Duration::from_millis(400)).await;
    let o = base.odometry().await.unwrap();
    assert!(o.value.v_m_s > 0.15, "moving: {}", o.value.v_m_s);
    tokio::time::sleep(Duration::from_millis(1000)).await;
    let o = base.odometry().await.unwrap();
    assert!(o.value.v_m_s.abs() < 1e-9, "stopped by the watchdog");
    // Emergency stop: zero and brake; motion is refused until enabled again.
    base.set_velocity(VelocityCommand::new(0.3, 0.0))
        .await
        .unwrap();
    base.emergency_stop().await.unwrap();
    tokio::time::sleep(Duration::from_millis(1500)).await;
    assert!(base.brake().unwrap().value, "brake engaged");
    assert!(
        base.set_velocity(VelocityCommand::new(0.3, 0.0))
            .await
            .is_err()
    );
    let o = base.odometry().await.unwrap();
    assert!(o.value.v_m_s.abs() < 1e-9);
    base.close().await.unwrap();
}

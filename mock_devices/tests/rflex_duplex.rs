//! The rFLEX driver's async shell against the controller model over an in-memory duplex, in
//! tokio's paused (virtual) time: the mock's own device ([`RflexDevice`]) on a robot of a
//! simulated world, served by [`DuplexDevice`], the world stepped on tokio's clock.

use std::time::Duration;

use ima_hal::base::{Bumpers, DifferentialBase, Odometer, VelocityCommand};
use ima_hal::sonar::SonarArray;
use ima_mock_devices::body::WorldBody;
use ima_mock_devices::duplex::{DuplexDevice, DuplexOptions};
use ima_mock_devices::rflex::{RflexDevice, RflexModelConfig};
use ima_mock_devices::stepper::TokioWorldStepper;
use ima_mock_devices::world::{RobotSpec, SharedWorld, SonarModel, Wall, World};
use ima_rflex::machine::Config;
use ima_rflex::shell::Rflex;

/// The driver connected to an ATRV-Jr at the origin facing a wall at x = 3 m (exact
/// single-ray sonar, no noise); keep the device and the stepper alive.
async fn connect() -> (Rflex, DuplexDevice<RflexDevice>, TokioWorldStepper) {
    let mut w = World::new();
    let id = w
        .add_robot(RobotSpec::new("scooter", 0.0, 0.0, 0.0))
        .unwrap();
    let wall = Wall {
        from: [3.0, -5.0],
        to: [3.0, 5.0],
    };
    w.add_wall(wall).unwrap();
    let world = SharedWorld::new(w);
    let sonar = SonarModel {
        rays: 1,
        noise_std_m: 0.0,
        ..SonarModel::default()
    };
    let body = WorldBody::new(world.clone(), id, 7).with_sonar(sonar);
    let dev = RflexDevice::new(RflexModelConfig::default(), body);
    let (host, dev) = DuplexDevice::spawn(dev, DuplexOptions::default());
    let stepper = TokioWorldStepper::spawn(world, Duration::from_millis(10));
    let base = Rflex::connect(
        host,
        Config::default(),
        Duration::from_secs(5),
        ima_hal::time::TokioClock::shared(),
    )
    .await
    .unwrap();
    (base, dev, stepper)
}

#[tokio::test(start_paused = true)]
async fn driver_drives_sees_the_wall_and_feels_the_bumper_in_virtual_time() {
    let (mut base, _dev, _stepper) = connect().await;
    // Brake first.
    assert!(
        base.set_velocity(VelocityCommand::new(0.2, 0.0))
            .await
            .is_err()
    );
    base.enable_motors(true).await.unwrap();
    let start = base.odometry().await.unwrap();
    // 0.2 m/s for 5 s, refreshing the command every 200 ms.
    for _ in 0..25 {
        base.set_velocity(VelocityCommand::new(0.2, 0.0))
            .await
            .unwrap();
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
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
async fn emergency_stop_engages_the_brake_and_the_watchdog_stops_a_quiet_client() {
    let (mut base, _dev, _stepper) = connect().await;
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

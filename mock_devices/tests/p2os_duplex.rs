//! The P2OS driver's async shell against the firmware model over an in-memory duplex, in
//! tokio's paused (virtual) time: the mock's own device ([`P2osDevice`]) on a robot of a
//! simulated world, served by [`DuplexDevice`], the world stepped on tokio's clock.

use std::time::Duration;

use ima_hal::base::{DifferentialBase, Odometer, VelocityCommand};
use ima_hal::sonar::SonarArray;
use ima_mock_devices::body::WorldBody;
use ima_mock_devices::duplex::{DuplexDevice, DuplexOptions};
use ima_mock_devices::p2os::{P2osDevice, P2osModelConfig};
use ima_mock_devices::stepper::TokioWorldStepper;
use ima_mock_devices::world::{RobotSpec, SharedWorld, SonarModel, Wall, World};
use ima_p2os::shell::{FixedBaud, P2os};

/// The driver connected to a Pioneer 2-AT at the origin facing a wall at x = `wall_x`
/// (exact single-ray sonar, no noise); keep the device and the stepper alive.
async fn connect(wall_x: f64) -> (P2os, DuplexDevice<P2osDevice>, TokioWorldStepper) {
    let mut w = World::new();
    let mut spec = RobotSpec::new("skeeter", 0.0, 0.0, 0.0);
    spec.track_width_m = 0.588;
    spec.radius_m = 0.33;
    spec.max_wheel_accel_m_s2 = Some(1.0);
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
    let dev = P2osDevice::new(P2osModelConfig::default(), body);
    let (host, dev) = DuplexDevice::spawn(dev, DuplexOptions::default());
    let stepper = TokioWorldStepper::spawn(world, Duration::from_millis(10));
    let p2os = P2os::connect(
        FixedBaud(host),
        ima_p2os::Config::default(),
        Duration::from_secs(5),
        ima_hal::time::TokioClock::shared(),
    )
    .await
    .unwrap();
    (p2os, dev, stepper)
}

#[tokio::test(start_paused = true)]
async fn driver_connects_enables_drives_and_sees_the_wall() {
    let (mut p2os, _dev, _stepper) = connect(2.0).await;
    assert_eq!(p2os.params().subclass, "p2at");
    p2os.enable_motors(true).await.unwrap();
    let start = p2os.odometry().await.unwrap();
    // 0.2 m/s for 5 s, refreshing the command every 200 ms.
    for _ in 0..25 {
        p2os.set_velocity(VelocityCommand::new(0.2, 0.0))
            .await
            .unwrap();
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
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
async fn motors_refuse_to_move_before_enable() {
    let (mut p2os, _dev, _stepper) = connect(10.0).await;
    let start = p2os.odometry().await.unwrap();
    for _ in 0..10 {
        p2os.set_velocity(VelocityCommand::new(0.3, 0.0))
            .await
            .unwrap();
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    let end = p2os.odometry().await.unwrap();
    assert!((end.value.x_m() - start.value.x_m()).abs() < 1e-9);
    assert!(!p2os.latest().unwrap().motors_enabled);
}

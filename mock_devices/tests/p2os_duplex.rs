//! The P2OS driver's async shell against the firmware model over an in-memory duplex, in
//! tokio's paused (virtual) time.

use std::time::Duration;

use ima_hal::Instant;
use ima_hal::base::{DifferentialBase, Odometer, VelocityCommand};
use ima_hal::sonar::SonarArray;
use ima_mock_devices::body::DiffDriveBody;
use ima_mock_devices::p2os::{P2osModelConfig, P2osRobot};
use ima_p2os::shell::{FixedBaud, P2os};
use tokio::io::{AsyncReadExt, AsyncWriteExt, DuplexStream};

/// A unicycle with acceleration limits and one wall at x = `wall_x`.
struct Body {
    x: f64,
    y: f64,
    th: f64,
    v: f64,
    w: f64,
    cmd: (f64, f64),
    travel: (f64, f64),
    wall_x: f64,
}

impl Body {
    fn step(&mut self, dt: f64) {
        let (a, alpha) = (0.3, 2.0);
        self.v += (self.cmd.0 - self.v).clamp(-a * dt, a * dt);
        self.w += (self.cmd.1 - self.w).clamp(-alpha * dt, alpha * dt);
        self.x += self.v * self.th.cos() * dt;
        self.y += self.v * self.th.sin() * dt;
        self.th += self.w * dt;
        let half_track = 0.294;
        self.travel.0 += (self.v - self.w * half_track) * dt * 1000.0;
        self.travel.1 += (self.v + self.w * half_track) * dt * 1000.0;
    }
}

impl DiffDriveBody for Body {
    fn drive(&mut self, v: f64, w: f64) {
        self.cmd = (v, w);
    }
    fn pose(&self) -> (f64, f64, f64) {
        (self.x, self.y, self.th)
    }
    fn track_width_m(&self) -> f64 {
        0.588
    }
    fn wheel_speeds_m_s(&self) -> (f64, f64) {
        let ht = 0.294;
        (self.v - self.w * ht, self.v + self.w * ht)
    }
    fn wheel_travel_m(&self) -> (f64, f64) {
        (self.travel.0 / 1000.0, self.travel.1 / 1000.0)
    }
    fn sonar_range_m(&mut self, m: &ima_hal::Isometry2) -> Option<f64> {
        let (s, c) = self.th.sin_cos();
        let t = m.translation.vector;
        let sx = self.x + c * t.x - s * t.y;
        let dir = self.th + m.rotation.angle();
        let dx = dir.cos();
        if dx <= 1e-6 {
            return None;
        }
        let r = (self.wall_x - sx) / dx;
        (r > 0.0).then_some(r)
    }
}

/// Serve the model on `io` until the test ends, stepping the body every 10 ms.
async fn serve(mut io: DuplexStream, mut robot: P2osRobot, mut body: Body) {
    let epoch = tokio::time::Instant::now();
    let now = || Instant::from_micros(epoch.elapsed().as_micros() as u64);
    let mut buf = [0u8; 512];
    let mut tick = tokio::time::interval(Duration::from_millis(10));
    loop {
        tokio::select! {
            r = io.read(&mut buf) => match r {
                Ok(0) | Err(_) => return,
                Ok(n) => robot.handle_rx(&buf[..n], now(), &mut body),
            },
            _ = tick.tick() => {
                body.step(0.01);
                robot.handle_timeout(now(), &mut body);
            }
        }
        let out = robot.take_output();
        if !out.is_empty() && io.write_all(&out).await.is_err() {
            return;
        }
    }
}

fn body(wall_x: f64) -> Body {
    Body {
        x: 0.0,
        y: 0.0,
        th: 0.0,
        v: 0.0,
        w: 0.0,
        cmd: (0.0, 0.0),
        travel: (0.0, 0.0),
        wall_x,
    }
}

#[tokio::test(start_paused = true)]
async fn driver_connects_enables_drives_and_sees_the_wall() {
    let (host, dev) = tokio::io::duplex(4096);
    let b = body(2.0);
    let robot = P2osRobot::new(P2osModelConfig::default(), &b);
    tokio::spawn(serve(dev, robot, b));
    let mut p2os = P2os::connect(
        FixedBaud(host),
        ima_p2os::Config::default(),
        Duration::from_secs(5),
        ima_hal::time::TokioClock::shared(),
    )
    .await
    .unwrap();
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
    let (host, dev) = tokio::io::duplex(4096);
    let b = body(10.0);
    let robot = P2osRobot::new(P2osModelConfig::default(), &b);
    tokio::spawn(serve(dev, robot, b));
    let mut p2os = P2os::connect(
        FixedBaud(host),
        ima_p2os::Config::default(),
        Duration::from_secs(5),
        ima_hal::time::TokioClock::shared(),
    )
    .await
    .unwrap();
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

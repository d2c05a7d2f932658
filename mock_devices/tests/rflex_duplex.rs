//! The rFLEX driver's async shell against the controller model over an in-memory duplex, in
//! tokio's paused (virtual) time.

use std::time::Duration;

use ima_hal::Instant;
use ima_hal::base::{Bumpers, DifferentialBase, Odometer, VelocityCommand};
use ima_hal::sonar::SonarArray;
use ima_mock_devices::body::DiffDriveBody;
use ima_mock_devices::rflex::{RflexModelConfig, RflexRobot};
use ima_rflex::machine::Config;
use ima_rflex::shell::Rflex;
use tokio::io::{AsyncReadExt, AsyncWriteExt, DuplexStream};

/// A unicycle with acceleration limits, a wall at x = `wall_x`, and a front bumper that
/// closes when the centre passes `bump_x`.
struct Body {
    x: f64,
    y: f64,
    th: f64,
    v: f64,
    w: f64,
    cmd: (f64, f64),
    dist: f64,
    turn: f64,
    wall_x: f64,
    bump_x: f64,
}

impl Body {
    fn step(&mut self, dt: f64) {
        let (a, alpha) = (2.0, 5.0);
        self.v += (self.cmd.0 - self.v).clamp(-a * dt, a * dt);
        self.w += (self.cmd.1 - self.w).clamp(-alpha * dt, alpha * dt);
        self.x += self.v * self.th.cos() * dt;
        self.y += self.v * self.th.sin() * dt;
        self.th += self.w * dt;
        self.dist += self.v * dt;
        self.turn += self.w * dt;
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
        0.5
    }
    fn wheel_speeds_m_s(&self) -> (f64, f64) {
        (self.v - self.w * 0.25, self.v + self.w * 0.25)
    }
    fn wheel_travel_m(&self) -> (f64, f64) {
        (self.dist - self.turn * 0.25, self.dist + self.turn * 0.25)
    }
    fn travel(&self) -> (f64, f64) {
        (self.dist, self.turn)
    }
    fn velocity(&self) -> (f64, f64) {
        (self.v, self.w)
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
        (r > 0.0 && r < 5.0).then_some(r)
    }
    fn bumpers(&self) -> (bool, bool) {
        (self.x >= self.bump_x, false)
    }
}

/// Serve the model on `io`, stepping the body every 10 ms.
async fn serve(mut io: DuplexStream, mut robot: RflexRobot, mut body: Body) {
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

fn body() -> Body {
    Body {
        x: 0.0,
        y: 0.0,
        th: 0.0,
        v: 0.0,
        w: 0.0,
        cmd: (0.0, 0.0),
        dist: 0.0,
        turn: 0.0,
        wall_x: 3.0,
        bump_x: 0.9,
    }
}

#[tokio::test(start_paused = true)]
async fn driver_drives_sees_the_wall_and_feels_the_bumper_in_virtual_time() {
    let (host, dev) = tokio::io::duplex(8192);
    let b = body();
    let robot = RflexRobot::new(RflexModelConfig::default(), &b);
    tokio::spawn(serve(dev, robot, b));
    let mut base = Rflex::connect(
        host,
        Config::default(),
        Duration::from_secs(5),
        ima_hal::time::TokioClock::shared(),
    )
    .await
    .unwrap();
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
    // The front bumper closed at x = 0.9.
    let bump = base.bumpers().await.unwrap().value;
    assert_eq!(bump.front, 1);
    assert_eq!(bump.rear, 0);
    let st = base.stats();
    assert_eq!(st.framer.bad_checksums, 0);
    assert_eq!(st.session.odometry_rejected, 0);
    base.close().await.unwrap();
}

#[tokio::test(start_paused = true)]
async fn emergency_stop_engages_the_brake_and_the_watchdog_stops_a_quiet_client() {
    let (host, dev) = tokio::io::duplex(8192);
    let b = body();
    let robot = RflexRobot::new(RflexModelConfig::default(), &b);
    tokio::spawn(serve(dev, robot, b));
    let mut base = Rflex::connect(
        host,
        Config::default(),
        Duration::from_secs(5),
        ima_hal::time::TokioClock::shared(),
    )
    .await
    .unwrap();
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

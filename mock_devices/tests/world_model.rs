//! How a protocol model plugs in: a toy line protocol on the shared world, served on a duplex
//! pipe while a tokio stepper advances the world, all in virtual time.
//!
//! Protocol (host → device): `V <v mm/s> <ω mrad/s>\n` drive; `R\n` read the front sonar.
//! Device → host: `R <mm>\n` per request; `P <x mm> <y mm> <θ mrad>\n` every 100 ms.

use std::time::Duration;

use ima_hal::{Instant, Isometry2};
use ima_mock_devices::duplex::{DuplexDevice, DuplexOptions};
use ima_mock_devices::faults::FaultPlan;
use ima_mock_devices::model::DeviceModel;
use ima_mock_devices::stepper::TokioWorldStepper;
use ima_mock_devices::world::{DriveCommand, RobotId, SharedWorld, SonarModel, World};
use rand::SeedableRng;
use rand::rngs::SmallRng;
use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader};

struct ToyBot {
    world: SharedWorld,
    robot: RobotId,
    sonar: SonarModel,
    rng: SmallRng,
    line: Vec<u8>,
    out: Vec<u8>,
    next_report: Instant,
}

impl ToyBot {
    fn command(&mut self, line: &str) {
        let mut it = line.split_whitespace();
        match it.next() {
            Some("V") => {
                let v: f64 = it.next().and_then(|s| s.parse().ok()).unwrap_or(0.0);
                let w: f64 = it.next().and_then(|s| s.parse().ok()).unwrap_or(0.0);
                self.world.with(|wd| {
                    wd.command(
                        self.robot,
                        DriveCommand::Twist {
                            v_m_s: v / 1000.0,
                            omega_rad_s: w / 1000.0,
                        },
                    )
                });
            }
            Some("R") => {
                let r = {
                    let w = self.world.lock();
                    self.sonar
                        .measure(&w, self.robot, &Isometry2::identity(), &mut self.rng)
                };
                self.out
                    .extend_from_slice(format!("R {}\n", (r * 1000.0).round()).as_bytes());
            }
            _ => {} // unknown line: ignored, like a robot would
        }
    }
}

impl DeviceModel for ToyBot {
    fn handle_rx(&mut self, bytes: &[u8], _now: Instant) {
        for &b in bytes {
            if b == b'\n' {
                let line = String::from_utf8_lossy(&self.line).into_owned();
                self.line.clear();
                self.command(&line);
            } else if self.line.len() < 64 {
                self.line.push(b);
            }
        }
    }
    fn poll_tx(&mut self, out: &mut Vec<u8>) {
        out.append(&mut self.out);
    }
    fn poll_timeout(&self) -> Option<Instant> {
        Some(self.next_report)
    }
    fn handle_timeout(&mut self, now: Instant) {
        let p = self.world.lock().robot(self.robot).unwrap().pose();
        self.out.extend_from_slice(
            format!(
                "P {} {} {}\n",
                (p.x_m * 1000.0).round(),
                (p.y_m * 1000.0).round(),
                (p.theta_rad * 1000.0).round()
            )
            .as_bytes(),
        );
        self.next_report = now + Duration::from_millis(100);
    }
    fn name(&self) -> &str {
        "toybot"
    }
}

#[tokio::test(start_paused = true)]
async fn toy_robot_drives_in_the_world_and_reads_its_sonar() {
    let world = SharedWorld::new(World::default_world());
    let sk = world.lock().robot_id("skeeter").unwrap();
    let model = ToyBot {
        world: world.clone(),
        robot: sk,
        sonar: SonarModel::default(),
        rng: SmallRng::seed_from_u64(world.lock().seed()),
        line: Vec::new(),
        out: Vec::new(),
        next_report: Instant::ZERO,
    };
    let _stepper = TokioWorldStepper::spawn(world.clone(), Duration::from_millis(10));
    let opts = DuplexOptions {
        faults: FaultPlan::parse("r2h.split=1,seed=5").unwrap(), // framing must survive splits
        ..DuplexOptions::default()
    };
    let (host, dev) = DuplexDevice::spawn(model, opts);
    let (rd, mut wr) = tokio::io::split(host);
    let mut lines = BufReader::new(rd).lines();

    // Red is straight ahead at 3 m (radius 0.15): the sonar reads ≈ 2850 mm.
    wr.write_all(b"R\n").await.unwrap();
    let mut range = None;
    while range.is_none() {
        let l = lines.next_line().await.unwrap().unwrap();
        if let Some(r) = l.strip_prefix("R ") {
            range = Some(r.parse::<f64>().unwrap());
        }
    }
    let range = range.unwrap();
    assert!((range - 2850.0).abs() < 60.0, "{range}");

    // Drive 0.2 m/s for 5 s of virtual time.
    wr.write_all(b"V 200 0\n").await.unwrap();
    tokio::time::sleep(Duration::from_secs(5)).await;
    wr.write_all(b"V 0 0\n").await.unwrap();
    tokio::time::sleep(Duration::from_secs(1)).await;
    // Reports piled up in the pipe; read on until one was written after t = 6.5 s (reading
    // the backlog takes no virtual time), which says where the robot stopped.
    let last = loop {
        let l = lines.next_line().await.unwrap().unwrap();
        if l.starts_with('P') && world.lock().time() > Instant::from_millis(6_500) {
            break l;
        }
    };
    let x: f64 = last.split_whitespace().nth(1).unwrap().parse().unwrap();
    assert!((x - 1000.0).abs() < 40.0, "{last}");
    assert!(dev.status().counters.robot_to_host.splits > 0);
    dev.stop().await.unwrap();
}

//! The experiment runs the robots' runtime: every input the runtime read in a simulated run
//! (odometry, compass, laser, broadcasts, SES samples — recorded in the order it read them)
//! is replayed through the brain directly, with the runtime's documented decisions (compass
//! transform, odometry offset, "reached" latch), and the velocity commands must be the same,
//! bit for bit.

use core::time::Duration;
use std::sync::{Arc, Mutex};

use ima_agents::mission::msg::Broadcast;
use ima_agents::mission::scooter::{HeadingRule, ScooterBrain, ScooterHeard, ScooterSay};
use ima_agents::runtime::scooter::ScooterDevices;
use ima_agents::ses::shared::SharedForm;
use ima_hal::base::{BaseLimits, DifferentialBase, Odometer, Odometry, VelocityCommand};
use ima_hal::compass::{Compass, Heading};
use ima_hal::laser::{LaserDescription, LaserScan, LaserScanner};
use ima_hal::time::{Clock, SharedClock};
use ima_hal::{ErrorKind, ErrorType, Instant, Stamped, normalize_angle};
use ima_mock_devices::hal::{SimBase, SimCompass, SimLaser, SimWorld};
use ima_sim::experiment::{RunSpec, SweepConfig, TARGET_COLOUR, world_for};
use ima_sim::runtime::{Delivered, drive, runtime_config, scooter_devices};
use ima_sim::{EndReason, SimConfig};

/// What the runtime read and did, in order.
#[derive(Debug, Clone)]
enum Rec {
    /// `odometry()` called at `now` (the runtime's start, then once per step).
    Odometry {
        now: Instant,
        reading: Stamped<Odometry>,
    },
    /// A compass heading handed to the runtime (`first`: by `heading()`, at start).
    Compass {
        first: bool,
        reading: Stamped<Heading>,
    },
    /// A scan handed to the runtime.
    Scan(Box<Stamped<LaserScan>>),
    /// A velocity command.
    Command(VelocityCommand),
    /// `stop()`.
    Stop,
    /// Queued on Scooter's link.
    Delivered(Delivered),
}

type Log = Arc<Mutex<Vec<Rec>>>;

fn push(log: &Log, r: Rec) {
    log.lock().unwrap().push(r);
}

struct RecBase {
    inner: SimBase,
    log: Log,
    clock: SharedClock,
}

impl ErrorType for RecBase {
    type Error = ErrorKind;
}

impl DifferentialBase for RecBase {
    fn limits(&self) -> BaseLimits {
        self.inner.limits()
    }
    async fn enable_motors(&mut self, enable: bool) -> Result<(), ErrorKind> {
        self.inner.enable_motors(enable).await
    }
    async fn set_velocity(&mut self, cmd: VelocityCommand) -> Result<(), ErrorKind> {
        push(&self.log, Rec::Command(cmd));
        self.inner.set_velocity(cmd).await
    }
    async fn stop(&mut self) -> Result<(), ErrorKind> {
        push(&self.log, Rec::Stop);
        self.inner.stop().await
    }
    async fn emergency_stop(&mut self) -> Result<(), ErrorKind> {
        push(&self.log, Rec::Stop);
        self.inner.emergency_stop().await
    }
}

impl Odometer for RecBase {
    async fn odometry(&mut self) -> Result<Stamped<Odometry>, ErrorKind> {
        let reading = self.inner.odometry().await?;
        push(
            &self.log,
            Rec::Odometry {
                now: self.clock.now(),
                reading,
            },
        );
        Ok(reading)
    }
    async fn next_odometry(&mut self, after: Instant) -> Result<Stamped<Odometry>, ErrorKind> {
        let reading = self.inner.next_odometry(after).await?;
        push(
            &self.log,
            Rec::Odometry {
                now: self.clock.now(),
                reading,
            },
        );
        Ok(reading)
    }
    async fn reset_odometry(&mut self) -> Result<(), ErrorKind> {
        self.inner.reset_odometry().await
    }
}

struct RecLaser {
    inner: SimLaser,
    log: Log,
}

impl ErrorType for RecLaser {
    type Error = ErrorKind;
}

impl LaserScanner for RecLaser {
    fn description(&self) -> LaserDescription {
        self.inner.description()
    }
    async fn scan(&mut self) -> Result<Stamped<LaserScan>, ErrorKind> {
        let s = self.inner.scan().await?;
        push(&self.log, Rec::Scan(Box::new(s.clone())));
        Ok(s)
    }
    async fn next_scan(&mut self, after: Instant) -> Result<Stamped<LaserScan>, ErrorKind> {
        let s = self.inner.next_scan(after).await?;
        push(&self.log, Rec::Scan(Box::new(s.clone())));
        Ok(s)
    }
}

struct RecCompass {
    inner: SimCompass,
    log: Log,
}

impl ErrorType for RecCompass {
    type Error = ErrorKind;
}

impl Compass for RecCompass {
    async fn heading(&mut self) -> Result<Stamped<Heading>, ErrorKind> {
        let reading = self.inner.heading().await?;
        push(
            &self.log,
            Rec::Compass {
                first: true,
                reading,
            },
        );
        Ok(reading)
    }
    async fn next_heading(&mut self, after: Instant) -> Result<Stamped<Heading>, ErrorKind> {
        let reading = self.inner.next_heading(after).await?;
        push(
            &self.log,
            Rec::Compass {
                first: false,
                reading,
            },
        );
        Ok(reading)
    }
}

/// The runtime's loop, step by step from the log: the brain fed directly.
fn replay(log: &[Rec], cfg: &SimConfig) -> Vec<VelocityCommand> {
    let rt = runtime_config(cfg, 0.0);
    let mut start_heading = None;
    let mut brain: Option<ScooterBrain> = None;
    let (mut heard, mut ses): (Vec<Broadcast>, Vec<SharedForm>) = (Vec::new(), Vec::new());
    let mut compass: Option<Stamped<Heading>> = None;
    let mut scan: Option<Stamped<LaserScan>> = None;
    let mut last_odo_at = None;
    let mut reached = false;
    let mut out = Vec::new();
    for r in log {
        match r {
            Rec::Compass {
                first: true,
                reading,
            } => {
                start_heading = Some(rt.common_heading(&reading.value));
            }
            Rec::Compass { reading, .. } => compass = Some(*reading),
            Rec::Scan(s) => scan = Some((**s).clone()),
            Rec::Delivered(Delivered::Heard(b)) => heard.push(b.clone()),
            Rec::Delivered(Delivered::Ses(f)) => ses.push(f.clone()),
            Rec::Odometry { now, reading } => {
                let Some(b) = brain.as_mut() else {
                    // The runtime's start: odometry's θ is the start heading.
                    let mut bc = rt.brain.clone();
                    bc.odometry_heading_offset_rad = normalize_angle(
                        start_heading.expect("a first heading") - reading.value.theta_rad(),
                    );
                    brain = Some(ScooterBrain::new(bc));
                    continue;
                };
                let now = *now;
                for h in heard.drain(..) {
                    if let Some(h) = ScooterHeard::from_broadcast(&h, &rt.brain.robot_name) {
                        let repeat = matches!(&h, ScooterHeard::TargetAccepted { colour }
                            if b.target() == Some(colour));
                        if !repeat {
                            b.handle_heard(&h, now);
                            reached = false;
                        }
                    }
                }
                for f in ses.drain(..) {
                    b.handle_ses(&f, now);
                }
                if Some(reading.at) != last_odo_at {
                    last_odo_at = Some(reading.at);
                    b.handle_odometry(&reading.value, reading.at);
                }
                if let Some(h) = compass.take() {
                    b.handle_compass(rt.common_heading(&h.value), h.at);
                }
                if let Some(s) = scan.take() {
                    b.handle_laser(&s.value, s.at);
                }
                let o = b.step(now);
                out.push(if reached {
                    VelocityCommand::ZERO
                } else {
                    o.command
                });
                if o.messages
                    .iter()
                    .any(|m| matches!(m, ScooterSay::TargetReached { .. }))
                {
                    reached = true;
                }
            }
            Rec::Command(_) | Rec::Stop => {}
        }
    }
    out
}

#[tokio::test(start_paused = true)]
async fn the_runtime_commands_what_the_brain_fed_the_same_inputs_commands() {
    let sweep = SweepConfig::default();
    let spec = RunSpec {
        rule: HeadingRule::Thesis,
        angle_deg: 45.0,
        ds_m: 2.0,
        dt_m: 2.0,
        seed: 7,
    };
    let mut cfg = sweep.sim.clone();
    cfg.seed = spec.seed;
    cfg.brain.heading_rule = spec.rule;
    cfg.brain.cruise_speed_m_s = sweep.speed_m_s;
    let sim = SimWorld::start(
        world_for(spec.angle_deg, spec.ds_m, spec.dt_m, spec.seed),
        cfg.dt,
    );
    let log: Log = Arc::default();
    let ScooterDevices {
        base,
        laser,
        compass,
        halt,
    } = scooter_devices(&sim, &cfg).unwrap();
    let devices = ScooterDevices {
        base: RecBase {
            inner: base,
            log: Arc::clone(&log),
            clock: sim.clock(),
        },
        laser: RecLaser {
            inner: laser,
            log: Arc::clone(&log),
        },
        compass: compass.map(|inner| RecCompass {
            inner,
            log: Arc::clone(&log),
        }),
        halt,
    };
    let tap_log = Arc::clone(&log);
    let tap: ima_sim::runtime::Tap = Arc::new(move |d: &Delivered| {
        push(&tap_log, Rec::Delivered(d.clone()));
    });
    let run = drive(
        &sim,
        devices,
        TARGET_COLOUR,
        &cfg,
        Duration::from_secs(120),
        Some(tap),
    )
    .await
    .unwrap();
    sim.stop();
    assert_eq!(run.outcome.reason, EndReason::Reached, "{run:?}");
    let log = log.lock().unwrap().clone();
    let commanded: Vec<VelocityCommand> = log
        .iter()
        .filter_map(|r| match r {
            Rec::Command(c) => Some(*c),
            _ => None,
        })
        .collect();
    assert!(
        matches!(log.last(), Some(Rec::Stop)),
        "the run ends stopped"
    );
    let replayed = replay(&log, &cfg);
    assert!(commanded.len() > 100, "{} commands", commanded.len());
    assert!(commanded.iter().any(|c| c.v_m_s > 0.0));
    assert_eq!(replayed.len(), commanded.len());
    for (i, (a, b)) in commanded.iter().zip(&replayed).enumerate() {
        assert_eq!(a, b, "command {i} of {}", commanded.len());
    }
    // The runtime's readings are on the simulation's one clock: every odometry reading it
    // took was at most one odometry period old.
    for r in &log {
        if let Rec::Odometry { now, reading } = r {
            assert!(now.saturating_duration_since(reading.at) <= cfg.odometry_period);
            assert!(reading.at <= *now);
        }
    }
}

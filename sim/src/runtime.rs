//! Scooter's real runtime ([`ima_agents::runtime::scooter`]) in a simulated world, in
//! virtual time: the code path the robot runs, over in-process HAL devices
//! ([`crate::hal`]).
//!
//! # What runs
//!
//! A [`SimWorld`] steps the world every [`SimConfig::dt`] on tokio's paused clock. Scooter's
//! devices are a [`SimBase`] (odometry every [`SimConfig::odometry_period`], 10 Hz as on
//! P2OS and rFLEX), a [`SimLaser`] ([`SimConfig::laser`] every [`SimConfig::laser_period`],
//! mounted at the brain's `laser_mount`) and a [`SimCompass`] (true heading + Gaussian
//! noise every [`SimConfig::compass_period`]); every reading is stamped on the simulation's
//! one clock. [`scooter_rt::run`](ima_agents::runtime::scooter::run) reads them in its own tasks, steps the brain at
//! [`SimConfig::control_hz`] (the robots' `agent.control_hz`, 10 Hz) and commands the base —
//! with the runtime's own mission decisions: the "reached" latch, the compass transform into
//! the common frame (the world's +x axis points east; the common heading is Skeeter's), the
//! odometry heading offset taken from the first compass heading.
//!
//! Skeeter is not a runtime here: its observations come from the [`SesObserver`] (the same
//! model as the reference loop [`ScooterSim`](crate::ScooterSim)) and reach Scooter through
//! the runtime's link ([`ScooterLink::channels`]), as the SES samples of Skeeter's `ses`
//! source would. Skeeter scans continuously, so Scooter's re-requests (`RequestHeading`) are
//! counted ([`RuntimeRun::rerequests`]) and otherwise change nothing.
//!
//! # Time line of a run
//!
//! The runtime starts, reads its first compass heading and odometry, and reports
//! `connected`; at that instant (`t = 0` of the run) the commander's target notice and the
//! sample of every camera (the scan that answered the request) are delivered; then a sample
//! after every full scan. The run ends when Scooter says `target-reached` (the broadcast on
//! its link) or at the time cap; the runtime is then stopped (it stops the base).

use core::f64::consts::FRAC_PI_2;
use core::time::Duration;
use std::sync::{Arc, Mutex, PoisonError};

use ima_agents::mission::msg::{Broadcast, Emergency, MissionEvent};
use ima_agents::runtime::link::ScooterLink;
use ima_agents::runtime::scooter::{self as scooter_rt, ScooterDevices, ScooterRuntimeConfig};
use ima_agents::runtime::{EventKind, Events};
use ima_agents::ses::shared::SharedForm;
use ima_hal::Instant;
use ima_hal::base::{DifferentialBase, Odometer};
use ima_hal::compass::Compass;
use ima_hal::laser::LaserScanner;
use ima_hal::time::Clock;
use ima_mock_devices::hal::{
    BaseConfig, CompassConfig, LaserConfig, SimBase, SimCompass, SimLaser, SimWorld,
};
use ima_mock_devices::world::World;
use rand::SeedableRng;
use rand::rngs::SmallRng;
use tokio::sync::watch;

use crate::{EndReason, Outcome, SesObserver, SimConfig, SimError};

/// What the simulation delivered to Scooter's link, in order (for replay tests).
#[derive(Debug, Clone, PartialEq)]
pub enum Delivered {
    /// A broadcast Scooter hears.
    Heard(Broadcast),
    /// An SES sample.
    Ses(SharedForm),
}

/// Called with every delivery, at the moment it is queued on the link.
pub type Tap = Arc<dyn Fn(&Delivered) + Send + Sync>;

/// The result of [`run_runtime`].
#[derive(Debug, Clone, PartialEq)]
pub struct RuntimeRun {
    /// How it ended (times from the run's `t = 0`, the first SES sample).
    pub outcome: Outcome,
    /// SES samples delivered.
    pub samples: u32,
    /// Scooter's true positions, one per world step from `t = 0` until the end.
    pub trajectory: Vec<[f64; 2]>,
    /// Scooter's re-requests of a fresh SES (`RequestHeading`).
    pub rerequests: u32,
}

/// The three devices of robot `scooter` in `sim`, configured from `cfg` (noise seeds derived
/// from `cfg.seed`).
///
/// # Errors
/// [`SimError::NoRobot`] when the world has no `scooter`.
pub fn scooter_devices(
    sim: &SimWorld,
    cfg: &SimConfig,
) -> Result<ScooterDevices<SimBase, SimLaser, SimCompass>, SimError> {
    let no = |_| SimError::NoRobot("scooter");
    let base = sim
        .base(
            "scooter",
            BaseConfig {
                odometry_period: cfg.odometry_period,
                ..BaseConfig::default()
            },
        )
        .map_err(no)?;
    let laser = sim
        .laser(
            "scooter",
            LaserConfig {
                model: cfg.laser,
                mount: cfg.brain.laser_mount,
                period: cfg.laser_period,
                delay: Duration::ZERO,
                seed: cfg.seed ^ 0x006c_6173_6572,
            },
        )
        .map_err(no)?;
    let compass = sim
        .compass(
            "scooter",
            CompassConfig {
                x_axis_heading_rad: FRAC_PI_2,
                noise_rad: cfg.compass_noise_rad,
                period: cfg.compass_period,
                seed: cfg.seed ^ 0x636f_6d70,
            },
        )
        .map_err(no)?;
    Ok(ScooterDevices {
        base,
        laser,
        compass: Some(compass),
        halt: None,
    })
}

/// The runtime's configuration for a simulated Scooter: `cfg`'s brain and control rate; the
/// common frame is Skeeter's heading (the world's +x axis is east).
#[must_use]
pub fn runtime_config(cfg: &SimConfig, skeeter_heading_rad: f64) -> ScooterRuntimeConfig {
    ScooterRuntimeConfig {
        brain: cfg.brain.clone(),
        control_hz: cfg.control_hz,
        time_scale: 1.0,
        // Compass heading of Skeeter's forward axis: +x is east (90°).
        common_heading_deg: 90.0 - skeeter_heading_rad.to_degrees(),
        compass_deviation_deg: 0.0,
        initial_heading_deg: None,
        control_report: Duration::from_secs(2),
        first_reading_timeout: Duration::from_secs(5),
    }
}

/// Run Scooter's runtime in `world` toward the `target` colour until it says it reached it or
/// `max` has passed since `t = 0`, in virtual time (a current-thread tokio runtime with
/// paused time, made here).
///
/// # Errors
/// [`SimError`] when a robot or the target is missing, a period fails [`SimConfig::check_periods`], or the runtime
/// could not start.
pub fn run_runtime(
    world: World,
    target: &str,
    cfg: &SimConfig,
    max: Duration,
) -> Result<RuntimeRun, SimError> {
    // Before any device starts: a zero period would make a timer spin or panic.
    validate(&world, target, cfg)?;
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_time()
        .start_paused(true)
        .build()
        .map_err(|e| SimError::Runtime(format!("building the tokio runtime: {e}")))?;
    rt.block_on(async {
        let sim = SimWorld::start(world, cfg.dt);
        let devices = scooter_devices(&sim, cfg)?;
        let r = drive(&sim, devices, target, cfg, max, None).await;
        sim.stop();
        r
    })
}

/// Check what [`ScooterSim::new`](crate::ScooterSim::new) checks.
fn validate(world: &World, target: &str, cfg: &SimConfig) -> Result<(), SimError> {
    world
        .robot_id("skeeter")
        .ok_or(SimError::NoRobot("skeeter"))?;
    world
        .robot_id("scooter")
        .ok_or(SimError::NoRobot("scooter"))?;
    if !world.objects().iter().any(|o| o.color == target) {
        return Err(SimError::NoTarget(target.to_owned()));
    }
    cfg.check_periods()
}

/// The run's track: Scooter's positions and path length, recorded after every world step.
#[derive(Debug, Default)]
struct Track {
    points: Vec<[f64; 2]>,
    distance_m: f64,
    samples: u32,
}

/// Run the runtime over `devices` (made on `sim`, e.g. by [`scooter_devices`], possibly
/// wrapped) inside the caller's tokio runtime; see [`run_runtime`]. `tap` sees every
/// delivery to Scooter's link.
///
/// # Errors
/// As [`run_runtime`].
pub async fn drive<B, L, C>(
    sim: &SimWorld,
    devices: ScooterDevices<B, L, C>,
    target: &str,
    cfg: &SimConfig,
    max: Duration,
    tap: Option<Tap>,
) -> Result<RuntimeRun, SimError>
where
    B: DifferentialBase + Odometer + Send + 'static,
    L: LaserScanner + Send + 'static,
    C: Compass + Send + 'static,
{
    let world0 = sim.snapshot();
    validate(&world0, target, cfg)?;
    let scooter = world0
        .robot_id("scooter")
        .ok_or(SimError::NoRobot("scooter"))?;
    let skeeter_heading = world0
        .robot_id("skeeter")
        .and_then(|id| world0.robot(id))
        .map_or(0.0, |r| r.pose().theta_rad);
    let clock = sim.clock();
    let (link, mut ends) = ScooterLink::channels();
    let (events, mut event_rx) = Events::channel(256);
    let (stop_tx, stop) = watch::channel(false);
    let rt_cfg = runtime_config(cfg, skeeter_heading);
    let task = tokio::spawn(scooter_rt::run(
        rt_cfg,
        devices,
        link,
        clock.clone(),
        events,
        stop,
    ));
    // Wait for the runtime to be up (first heading and odometry read).
    loop {
        match event_rx.recv().await {
            Some(e) if matches!(e.kind, EventKind::Connected { .. }) => break,
            Some(_) => {}
            None => {
                let r = task.await;
                return Err(SimError::Runtime(format!(
                    "Scooter's runtime ended before it was up: {r:?}"
                )));
            }
        }
    }
    drop(event_rx);
    let t0 = clock.now();
    let position = move |w: &World| {
        w.robot(scooter)
            .map_or([0.0, 0.0], |r| [r.pose().x_m, r.pose().y_m])
    };
    let mut rng = SmallRng::seed_from_u64(cfg.seed);
    let (first, start, observer) = {
        let snapshot = sim.snapshot();
        let mut observer = SesObserver::new(&snapshot, cfg, &cfg.brain.robot_name, t0)?;
        let first = observer.full_look(&snapshot, t0, &mut rng);
        (first, position(&snapshot), observer)
    };
    let track = Arc::new(Mutex::new(Track {
        points: vec![start],
        distance_m: 0.0,
        samples: 1,
    }));
    let deliver = |d: Delivered| -> Delivered {
        if let Some(tap) = &tap {
            tap(&d);
        }
        d
    };
    let notice = Broadcast::mission("commander", MissionEvent::Accepted, target);
    if let Delivered::Heard(b) = deliver(Delivered::Heard(notice)) {
        let _ = ends.heard.try_send(b);
    }
    if let Delivered::Ses(f) = deliver(Delivered::Ses(first)) {
        let _ = ends.ses.try_send(f);
    }
    // Skeeter's cameras and the track, after every world step.
    {
        let track = Arc::clone(&track);
        let ses = ends.ses.clone();
        let tap = tap.clone();
        let mut observer = observer;
        sim.on_step(move |w, now| {
            let p = position(w);
            let mut t = track.lock().unwrap_or_else(PoisonError::into_inner);
            if let Some(last) = t.points.last() {
                t.distance_m += (p[0] - last[0]).hypot(p[1] - last[1]);
            }
            t.points.push(p);
            for form in observer.poll(w, now, &mut rng) {
                t.samples += 1;
                if let Some(tap) = &tap {
                    tap(&Delivered::Ses(form.clone()));
                }
                let _ = ses.try_send(form);
            }
            !ses.is_closed()
        });
    }
    let deadline = tokio::time::Instant::now() + max;
    let mut rerequests = 0u32;
    let mut reached: Option<(Instant, [f64; 2], f64, usize)> = None;
    let robot = cfg.brain.robot_name.clone();
    loop {
        tokio::select! {
            biased;
            said = ends.say.recv() => match said {
                Some(Broadcast::Emergency { robot: by, emergency: Emergency::TargetReached { .. } })
                    if by == robot =>
                {
                    let now = clock.now();
                    let t = track.lock().unwrap_or_else(PoisonError::into_inner);
                    let here = sim.with(|w| position(w));
                    reached = Some((now, here, t.distance_m, t.points.len()));
                    break;
                }
                Some(_) => {}
                None => break,
            },
            r = ends.rerequest.recv() => {
                if r.is_some() {
                    rerequests += 1;
                }
            }
            () = tokio::time::sleep_until(deadline) => break,
        }
    }
    let _ = stop_tx.send(true);
    let ended = task.await;
    let end_t = reached.map_or(clock.now(), |r| r.0);
    let t = track.lock().unwrap_or_else(PoisonError::into_inner);
    let (end, distance_m, len) = match reached {
        Some((_, here, d, n)) => (here, d, n),
        None => (
            t.points.last().copied().unwrap_or(start),
            t.distance_m,
            t.points.len(),
        ),
    };
    match ended {
        Ok(Ok(())) => {}
        Ok(Err(e)) => return Err(SimError::Runtime(e.to_string())),
        Err(e) => return Err(SimError::Runtime(format!("Scooter's runtime failed: {e}"))),
    }
    Ok(RuntimeRun {
        outcome: Outcome {
            reason: if reached.is_some() {
                EndReason::Reached
            } else {
                EndReason::Timeout
            },
            time_s: end_t.saturating_duration_since(t0).as_secs_f64(),
            distance_m,
            start,
            end,
        },
        samples: t.samples,
        trajectory: t.points.iter().take(len).copied().collect(),
        rerequests,
    })
}

//! The robots' runtime: device wiring from configuration and the robot stacks as tokio
//! tasks.
//!
//! * [`devices`] — the hal handles of a robot from its configuration;
//! * [`net`] — the Peer Agent configuration, group key and typed broadcast channel;
//! * [`skeeter`], [`scooter`], [`commander`] — the three processes' stacks;
//! * [`report`] — trajectories, performance index and the SVG of a run.
//!
//! Every stack keeps a [`MissionClock`]: mission time is real time × `agent.time_scale`, so
//! a world sped up K times (`ima mock world --speed K`) sees timeouts and timers in its own
//! time.

pub mod commander;
pub mod devices;
pub mod net;
pub mod report;
pub mod scooter;
pub mod skeeter;

use ima_hal::Instant;
use serde::Serialize;

/// The mission clock: tokio time since the process's epoch × the configured time scale (1
/// on a real robot; the world's speed factor with sped-up mocks).
#[derive(Debug, Clone, Copy)]
pub struct MissionClock {
    epoch: tokio::time::Instant,
    scale: f64,
}

impl MissionClock {
    /// A clock starting now, running `scale` times faster than real time.
    pub fn new(scale: f64) -> Self {
        Self {
            epoch: tokio::time::Instant::now(),
            scale: if scale.is_finite() && scale > 0.0 {
                scale
            } else {
                1.0
            },
        }
    }

    /// Mission time now.
    pub fn now(&self) -> Instant {
        let real = self.epoch.elapsed().as_secs_f64();
        Instant::from_micros((real * self.scale * 1e6) as u64)
    }

    /// Mission seconds now.
    pub fn secs(&self) -> f64 {
        self.now().as_secs_f64()
    }

    /// Real duration of `mission` mission time.
    pub fn real(&self, mission: std::time::Duration) -> std::time::Duration {
        mission.div_f64(self.scale)
    }
}

/// Something a robot stack did, for live progress and `--json`.
#[derive(Debug, Clone, Serialize)]
pub struct Event {
    /// Mission seconds.
    pub t_s: f64,
    /// Which robot (or `commander`).
    pub robot: String,
    /// What: `behaviour`, `broadcast`, `ses`, `target`, `connected`, `error`, …
    pub kind: String,
    /// Details.
    pub detail: serde_json::Value,
}

/// Where stacks report their events: the log (`tracing`, level info) and an optional live
/// sink.
#[derive(Clone, Default)]
pub struct Events {
    sink: Option<tokio::sync::mpsc::UnboundedSender<Event>>,
    /// Whether the stacks also report the web console's detail (kinds `san`, `map`,
    /// `ses-form`, `peer-status`), see [`Events::detailed`].
    detail: bool,
}

impl std::fmt::Debug for Events {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Events")
    }
}

impl Events {
    /// Events forwarded to `sink` too.
    pub fn with_sink(sink: tokio::sync::mpsc::UnboundedSender<Event>) -> Self {
        Self {
            sink: Some(sink),
            detail: false,
        }
    }

    /// These events with the web console's detail too (periodic SAN activations, map and
    /// Peer Agent status; see [`crate::web`]).
    #[must_use]
    pub fn detailed(mut self, on: bool) -> Self {
        self.detail = on;
        self
    }

    /// Whether the web console's detail is wanted (cheap to ask on every loop).
    pub fn wants_detail(&self) -> bool {
        self.detail && self.sink.is_some()
    }

    /// Report an event.
    pub fn emit(&self, clock: &MissionClock, robot: &str, kind: &str, detail: serde_json::Value) {
        let e = Event {
            t_s: clock.secs(),
            robot: robot.to_owned(),
            kind: kind.to_owned(),
            detail,
        };
        tracing::info!(robot, kind, detail = %e.detail, "event");
        if let Some(s) = &self.sink {
            let _ = s.send(e);
        }
    }
}

//! The robots' runtime (feature `runtime`): the tokio loops that turn devices into a robot.
//!
//! The brains of [`crate::mission`] decide; this layer feeds them and carries out what they
//! say, generic over the HAL's traits so that either robot runs on any base, on real drivers,
//! on mock devices or in a simulated world:
//!
//! * [`scooter::run`] — Scooter over any `B: DifferentialBase + Odometer`, `L: LaserScanner`
//!   and optional `C: Compass`: sensors → [`ScooterBrain`](crate::mission::scooter::ScooterBrain)
//!   → velocity commands, with the mission decisions of the loop (the "reached" latch, fleet
//!   stops, de-duplication of target notices, SES re-requests);
//! * [`skeeter::run`] — Skeeter over a base, a [`CameraMux`](ima_hal::camera::CameraMux) and a
//!   [`FrameSource`](ima_hal::camera::FrameSource): the Scan node, its SAN and its Peer Agent
//!   manager publishing the `ses` source;
//! * [`commander::run`] — the commander interface agent over the broadcast channel;
//! * [`link`] — how a robot talks to the others: channels the caller provides (a simulation)
//!   or the Peer Agent network ([`link::ScooterLink::network`], [`link::Bus`]).
//!
//! **One clock.** Every runtime takes the process's [`SharedClock`], the one every driver of
//! the robot stamps its readings on; [`MissionTime`] is a scaled view of it (mission time =
//! clock time × `time_scale`, 1 on a robot, the speed-up of a simulated world otherwise), and
//! device stamps are mapped into mission time with [`MissionTime::at`] — a scan's age is
//! `now − scan.at`.
//!
//! **Typed events.** What a runtime does is reported as an [`Event`] ([`EventKind`]) on a
//! bounded channel ([`Events`]): a slow consumer never blocks a robot, it loses the oldest
//! events and [`EventReceiver::dropped`] counts them. JSON is only the CLI's rendering
//! (`Serialize`: `{t_s, robot, kind, detail}`).
//!
//! **Stops.** A runtime that drives a base stops it on every way out of its loop: a stop
//! request or an error ends with `stop()`; a dropped (cancelled) runtime halts the base's
//! driver through the [`HaltSignal`] the caller hands in (see [`ima_hal::safety`]). The
//! process-level signal and panic handling stays with the program.

pub mod commander;
pub mod events;
pub mod link;
pub mod scooter;
pub mod skeeter;

use core::time::Duration;

use ima_hal::Instant;
use ima_hal::safety::HaltSignal;
use ima_hal::time::{Clock, SharedClock};

pub use events::{Event, EventKind, EventReceiver, Events};

/// Why a runtime could not run.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum RuntimeError {
    /// The Peer Agent network failed (what was being done, and the error).
    Net(String),
    /// A device failed in a way the runtime cannot go on from.
    Device(String),
    /// The configuration is not usable (what, and why).
    Config(String),
}

impl core::fmt::Display for RuntimeError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            RuntimeError::Net(e) => write!(f, "Peer Agent network: {e}"),
            RuntimeError::Device(e) => write!(f, "device: {e}"),
            RuntimeError::Config(e) => write!(f, "configuration: {e}"),
        }
    }
}

impl std::error::Error for RuntimeError {}

/// A request to end a runtime: `true` on the watch ends it (so does a dropped sender).
pub type StopRequest = tokio::sync::watch::Receiver<bool>;

/// Mission time: a scaled view of the process's one clock.
///
/// `now()` is the clock's time × `scale`; [`MissionTime::at`] maps any stamp of that clock
/// (a device reading's `Stamped::at`) the same way, so stamps and `now()` stay comparable.
/// The scale is 1 on a robot and the speed-up factor of a sped-up simulated world, whose
/// timeouts and timers then run in the world's time.
#[derive(Debug, Clone)]
pub struct MissionTime {
    clock: SharedClock,
    scale: f64,
}

impl MissionTime {
    /// Mission time on `clock`, `scale` times faster (a scale that is not finite and
    /// positive counts as 1).
    #[must_use]
    pub fn new(clock: SharedClock, scale: f64) -> Self {
        Self {
            clock,
            scale: if scale.is_finite() && scale > 0.0 {
                scale
            } else {
                1.0
            },
        }
    }

    /// The mission time of `at`, an instant of the underlying clock (a device stamp).
    #[must_use]
    pub fn at(&self, at: Instant) -> Instant {
        if self.scale == 1.0 {
            return at;
        }
        Instant::from_micros((at.as_micros() as f64 * self.scale) as u64)
    }

    /// Mission time now.
    #[must_use]
    pub fn now(&self) -> Instant {
        self.at(self.clock.now())
    }

    /// Mission seconds now.
    #[must_use]
    pub fn secs(&self) -> f64 {
        self.now().as_secs_f64()
    }

    /// The real (clock) duration of `mission` mission time.
    #[must_use]
    pub fn real(&self, mission: Duration) -> Duration {
        Duration::try_from_secs_f64(mission.as_secs_f64() / self.scale).unwrap_or(Duration::MAX)
    }

    /// The scale factor.
    #[must_use]
    pub fn scale(&self) -> f64 {
        self.scale
    }

    /// The underlying clock.
    #[must_use]
    pub fn clock(&self) -> &SharedClock {
        &self.clock
    }
}

impl Clock for MissionTime {
    fn now(&self) -> Instant {
        MissionTime::now(self)
    }
}

/// Halts a base's driver if dropped while armed: the stop on the way out of a runtime that
/// is cancelled (its task aborted, its future dropped) and cannot await `stop()`.
#[derive(Debug)]
pub(crate) struct HaltOnDrop(Option<HaltSignal>);

impl HaltOnDrop {
    pub(crate) fn new(signal: Option<HaltSignal>) -> Self {
        Self(signal)
    }

    /// The runtime stopped the base itself: nothing to do on drop.
    pub(crate) fn disarm(mut self) {
        self.0 = None;
    }

    /// Whether the base's driver was halted already (the process's exit guard halts every
    /// registered device at a signal, before the runtime's own stop: that stop then finds the
    /// driver gone, which is no failure).
    pub(crate) fn already_halted(&self) -> bool {
        self.0.as_ref().is_some_and(HaltSignal::is_requested)
    }
}

impl Drop for HaltOnDrop {
    fn drop(&mut self) {
        if let Some(s) = self.0.take() {
            if !s.is_requested() {
                tracing::warn!("runtime dropped while driving: halting the base");
            }
            s.halt();
        }
    }
}

/// Waits until `stop` asks the runtime to end (a `true`, or the sender dropped).
pub(crate) async fn stopped(stop: &mut StopRequest) {
    loop {
        if *stop.borrow_and_update() {
            return;
        }
        if stop.changed().await.is_err() {
            return;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ima_hal::time::ManualClock;

    #[test]
    fn mission_time_scales_the_one_clock_and_its_stamps() {
        let c = ManualClock::starting_at(Instant::from_millis(1000));
        let m = MissionTime::new(c.shared(), 4.0);
        assert_eq!(m.now(), Instant::from_millis(4000));
        c.advance(Duration::from_millis(500));
        assert_eq!(m.now(), Instant::from_millis(6000));
        // A stamp taken 100 ms (clock) ago is 400 ms (mission) old.
        let stamp = Instant::from_millis(1400);
        assert_eq!(
            m.now().saturating_duration_since(m.at(stamp)),
            Duration::from_millis(400)
        );
        assert_eq!(m.real(Duration::from_secs(4)), Duration::from_secs(1));
        assert!((MissionTime::new(c.shared(), f64::NAN).scale() - 1.0).abs() < 1e-12);
        // A tiny scale saturates instead of panicking (`Duration::div_f64` overflowed).
        let slow = MissionTime::new(c.shared(), 1e-300);
        assert_eq!(slow.real(Duration::from_secs(1)), Duration::MAX);
    }
}

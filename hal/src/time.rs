//! Monotonic time stamps.

use core::ops::{Add, Sub};
use core::time::Duration;

/// A point on a monotonic time line, in microseconds since an arbitrary epoch.
///
/// Protocol cores take it as an argument (`now`), so a test can drive them in virtual time; the
/// I/O shells obtain it from [`MonotonicClock`] (feature `std`) or a simulation clock.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub struct Instant {
    micros: u64,
}

impl Instant {
    /// The epoch.
    pub const ZERO: Self = Self { micros: 0 };

    /// An instant `micros` microseconds after the epoch.
    #[must_use]
    pub const fn from_micros(micros: u64) -> Self {
        Self { micros }
    }

    /// An instant `millis` milliseconds after the epoch.
    #[must_use]
    pub const fn from_millis(millis: u64) -> Self {
        Self {
            micros: millis.saturating_mul(1000),
        }
    }

    /// Microseconds since the epoch.
    #[must_use]
    pub const fn as_micros(self) -> u64 {
        self.micros
    }

    /// Seconds since the epoch, as a float (for logs and plots).
    #[must_use]
    pub fn as_secs_f64(self) -> f64 {
        self.micros as f64 * 1e-6
    }

    /// Time from `earlier` to `self`, or zero if `earlier` is later.
    #[must_use]
    pub fn saturating_duration_since(self, earlier: Self) -> Duration {
        Duration::from_micros(self.micros.saturating_sub(earlier.micros))
    }

    /// `self + d`, or `None` on overflow.
    #[must_use]
    pub fn checked_add(self, d: Duration) -> Option<Self> {
        let d = u64::try_from(d.as_micros()).ok()?;
        self.micros.checked_add(d).map(Self::from_micros)
    }
}

impl Add<Duration> for Instant {
    type Output = Instant;
    /// Saturates at the end of time rather than overflowing.
    fn add(self, d: Duration) -> Instant {
        self.checked_add(d)
            .unwrap_or(Instant::from_micros(u64::MAX))
    }
}

impl Sub<Duration> for Instant {
    type Output = Instant;
    /// Saturates at the epoch.
    fn sub(self, d: Duration) -> Instant {
        let d = u64::try_from(d.as_micros()).unwrap_or(u64::MAX);
        Instant::from_micros(self.micros.saturating_sub(d))
    }
}

/// A value with the instant it was measured (or, for a command, issued).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Stamped<T> {
    /// When the value was true.
    pub at: Instant,
    /// The value.
    pub value: T,
}

impl<T> Stamped<T> {
    /// Stamp `value` with `at`.
    pub const fn new(at: Instant, value: T) -> Self {
        Self { at, value }
    }

    /// Transform the value, keeping the stamp.
    pub fn map<U>(self, f: impl FnOnce(T) -> U) -> Stamped<U> {
        Stamped {
            at: self.at,
            value: f(self.value),
        }
    }
}

/// A source of the current [`Instant`]: the one time base of a process.
///
/// A program makes one clock and passes it to every driver shell, runner and runtime it
/// starts, so `Stamped::at` of a laser scan, an odometry reading and a compass heading taken
/// on one robot are comparable (a scan's age is `clock.now() - scan.at`). Real programs use
/// [`TokioClock`] (feature `tokio`) or [`MonotonicClock`] (feature `std`); the simulation
/// and tests use [`TokioClock`] under tokio's paused time, or [`ManualClock`].
pub trait Clock: Send + Sync + core::fmt::Debug {
    /// The current instant on this clock's time line.
    fn now(&self) -> Instant;
}

impl<C: Clock + ?Sized> Clock for &C {
    fn now(&self) -> Instant {
        (**self).now()
    }
}

/// A clock shared by every part of a process (feature `std`): cheap to clone, one epoch.
#[cfg(feature = "std")]
pub type SharedClock = std::sync::Arc<dyn Clock>;

#[cfg(feature = "std")]
impl<C: Clock + ?Sized> Clock for std::sync::Arc<C> {
    fn now(&self) -> Instant {
        (**self).now()
    }
}

/// A clock that moves only when told to (feature `std`): for tests and step-wise simulation.
/// Clones share one time line.
#[cfg(feature = "std")]
#[derive(Debug, Clone, Default)]
pub struct ManualClock {
    micros: std::sync::Arc<core::sync::atomic::AtomicU64>,
}

#[cfg(feature = "std")]
impl ManualClock {
    /// A clock standing at `at`.
    #[must_use]
    pub fn starting_at(at: Instant) -> Self {
        Self {
            micros: std::sync::Arc::new(core::sync::atomic::AtomicU64::new(at.as_micros())),
        }
    }

    /// Move the clock forward by `d` (saturating at the end of time).
    pub fn advance(&self, d: Duration) {
        let d = u64::try_from(d.as_micros()).unwrap_or(u64::MAX);
        let _ = self.micros.fetch_update(
            core::sync::atomic::Ordering::SeqCst,
            core::sync::atomic::Ordering::SeqCst,
            |m| Some(m.saturating_add(d)),
        );
    }

    /// Set the clock to `at` unless that is earlier than now (it never runs backwards).
    pub fn set(&self, at: Instant) {
        self.micros
            .fetch_max(at.as_micros(), core::sync::atomic::Ordering::SeqCst);
    }

    /// This clock as a [`SharedClock`] (the same time line).
    #[must_use]
    pub fn shared(&self) -> SharedClock {
        std::sync::Arc::new(self.clone())
    }
}

#[cfg(feature = "std")]
impl Clock for ManualClock {
    fn now(&self) -> Instant {
        Instant::from_micros(self.micros.load(core::sync::atomic::Ordering::SeqCst))
    }
}

/// A real monotonic clock whose epoch is its creation (feature `std`).
#[cfg(feature = "std")]
#[derive(Debug, Clone, Copy)]
pub struct MonotonicClock {
    epoch: std::time::Instant,
}

#[cfg(feature = "std")]
impl MonotonicClock {
    /// A clock whose epoch is now.
    #[must_use]
    pub fn new() -> Self {
        Self {
            epoch: std::time::Instant::now(),
        }
    }

    /// The current instant.
    #[must_use]
    pub fn now(&self) -> Instant {
        let us = self.epoch.elapsed().as_micros();
        Instant::from_micros(u64::try_from(us).unwrap_or(u64::MAX))
    }

    /// Convert a std instant taken after the epoch.
    #[must_use]
    pub fn instant(&self, t: std::time::Instant) -> Instant {
        let us = t.saturating_duration_since(self.epoch).as_micros();
        Instant::from_micros(u64::try_from(us).unwrap_or(u64::MAX))
    }
}

#[cfg(feature = "std")]
impl Clock for MonotonicClock {
    fn now(&self) -> Instant {
        MonotonicClock::now(self)
    }
}

#[cfg(feature = "std")]
impl MonotonicClock {
    /// A new clock (epoch now) as a [`SharedClock`].
    #[must_use]
    pub fn shared() -> SharedClock {
        std::sync::Arc::new(Self::new())
    }
}

#[cfg(feature = "std")]
impl Default for MonotonicClock {
    fn default() -> Self {
        Self::new()
    }
}

/// A clock on tokio's monotonic time (feature `tokio`), counted from its creation: the clock
/// of the drivers' async shells. Under `tokio::time::pause` it runs in virtual time, so shell
/// tests need no real waiting.
#[cfg(feature = "tokio")]
#[derive(Debug, Clone, Copy)]
pub struct TokioClock {
    epoch: tokio::time::Instant,
}

#[cfg(feature = "tokio")]
impl TokioClock {
    /// A clock whose epoch is now.
    #[must_use]
    pub fn new() -> Self {
        Self {
            epoch: tokio::time::Instant::now(),
        }
    }

    /// The current instant.
    #[must_use]
    pub fn now(&self) -> Instant {
        Instant::from_micros(u64::try_from(self.epoch.elapsed().as_micros()).unwrap_or(u64::MAX))
    }
}

#[cfg(feature = "tokio")]
impl Clock for TokioClock {
    fn now(&self) -> Instant {
        TokioClock::now(self)
    }
}

#[cfg(feature = "tokio")]
impl TokioClock {
    /// A new clock (epoch now, on tokio's time) as a [`SharedClock`]: the usual one clock of
    /// a program, made once in `main` (or a test) and passed to every shell.
    #[must_use]
    pub fn shared() -> SharedClock {
        std::sync::Arc::new(Self::new())
    }
}

#[cfg(feature = "tokio")]
impl Default for TokioClock {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn arithmetic_saturates() {
        let t = Instant::from_millis(5);
        assert_eq!(t + Duration::from_millis(1), Instant::from_micros(6000));
        assert_eq!(t - Duration::from_secs(1), Instant::ZERO);
        assert_eq!(
            Instant::from_micros(u64::MAX) + Duration::from_secs(1),
            Instant::from_micros(u64::MAX)
        );
        assert_eq!(
            t.saturating_duration_since(Instant::from_millis(7)),
            Duration::ZERO
        );
        assert_eq!(
            Instant::from_millis(7).saturating_duration_since(t),
            Duration::from_millis(2)
        );
    }

    #[cfg(feature = "std")]
    #[test]
    fn manual_clock_is_one_time_line_and_never_runs_back() {
        let c = ManualClock::starting_at(Instant::from_millis(10));
        let shared = c.shared();
        c.advance(Duration::from_millis(5));
        assert_eq!(shared.now(), Instant::from_millis(15));
        c.set(Instant::from_millis(12));
        assert_eq!(shared.now(), Instant::from_millis(15));
        c.set(Instant::from_millis(20));
        assert_eq!(Clock::now(&c), Instant::from_millis(20));
        c.advance(Duration::MAX);
        assert_eq!(c.now(), Instant::from_micros(u64::MAX));
    }

    #[test]
    fn stamped_map_keeps_stamp() {
        let s = Stamped::new(Instant::from_micros(9), 2.0_f64).map(|v| v * 3.0);
        assert_eq!(s.at.as_micros(), 9);
        assert!((s.value - 6.0).abs() < 1e-12);
    }
}

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

    #[test]
    fn stamped_map_keeps_stamp() {
        let s = Stamped::new(Instant::from_micros(9), 2.0_f64).map(|v| v * 3.0);
        assert_eq!(s.at.as_micros(), 9);
        assert!((s.value - 6.0).abs() < 1e-12);
    }
}

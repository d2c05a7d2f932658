//! `ima-hal`: the hardware-abstraction layer of `ima`.
//!
//! One small trait per robot capability, typed readings in SI units, and an error
//! convention borrowed from `embedded-hal` 1.0. Drivers (`ima-p2os`, `ima-rflex`, …)
//! implement these traits; agents consume them and never see a driver type.
//!
//! # Conventions
//!
//! * **Units.** SI everywhere: metres, radians, seconds, m/s, rad/s, volts. Field names
//!   carry the unit as a suffix (`x_m`, `theta_rad`, `v_m_s`) so a reader never has to guess.
//! * **Frames.** The robot frame is x forward, y left, z up; angles are counter-clockwise
//!   positive, normalised to (−π, π] where a single value is reported.
//! * **Time.** Every reading is [`Stamped`] with a monotonic [`Instant`] (microseconds since an
//!   arbitrary epoch). Sans-IO protocol cores receive `now` as an argument; only the I/O
//!   shells read a clock ([`time::MonotonicClock`], with the `std` feature).
//! * **Errors.** Every trait names an associated error type whose [`Error::kind`] maps
//!   onto the small [`ErrorKind`] enum; drivers keep their rich errors behind it.
//! * **Async.** The traits are async; their futures are `Send` so that a tokio task can own a
//!   driver handle. A blocking mirror for simple tools lives in [`blocking`].
//! * **Wire formats.** The byte cursors ([`bytes::Reader`], [`bytes::Writer`]) serve every
//!   binary wire format, the drivers' and the Peer Agent's alike, so agents need no driver
//!   crate to encode a message.
//!
//! The crate is `#![no_std]` unless the `std` feature (on by default) is enabled, so the
//! protocol cores that depend on it stay `no_std` as well.
#![cfg_attr(not(feature = "std"), no_std)]
#![warn(missing_docs)]
// No panics on input: outside tests, these are compile errors, as in the protocol cores.
#![cfg_attr(
    not(test),
    deny(
        clippy::unwrap_used,
        clippy::expect_used,
        clippy::panic,
        clippy::indexing_slicing,
        clippy::unreachable
    )
)]

pub mod base;
pub mod blocking;
pub mod bytes;
pub mod camera;
pub mod compass;
pub mod error;
#[cfg(feature = "std")]
pub mod file;
#[cfg(feature = "fuzzing")]
pub mod fuzzing;
pub mod laser;
pub mod link;
pub mod power;
#[cfg(feature = "std")]
pub mod safety;
#[cfg(feature = "std")]
pub mod serial;
pub mod sonar;
pub mod time;

pub use error::{Error, ErrorKind, ErrorType};
pub use time::{Instant, Stamped};

/// Geometry types used by readings, re-exported so users need not pin `nalgebra` themselves.
pub use nalgebra;

/// A rigid 2-D transform (rotation then translation): poses of the robot in the world and of
/// sensors on the robot.
pub type Isometry2 = nalgebra::Isometry2<f64>;
/// A 2-D point in metres.
pub type Point2 = nalgebra::Point2<f64>;
/// A 2-D vector in metres.
pub type Vector2 = nalgebra::Vector2<f64>;

/// Wrap an angle in radians into (−π, π].
#[must_use]
pub fn normalize_angle(theta_rad: f64) -> f64 {
    use core::f64::consts::PI;
    if !theta_rad.is_finite() {
        return theta_rad;
    }
    let two_pi = 2.0 * PI;
    let mut a = theta_rad % two_pi;
    if a <= -PI {
        a += two_pi;
    } else if a > PI {
        a -= two_pi;
    }
    a
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::f64::consts::PI;

    #[test]
    fn normalize_wraps_into_half_open_interval() {
        assert!((normalize_angle(3.0 * PI) - PI).abs() < 1e-12);
        assert!((normalize_angle(-PI) - PI).abs() < 1e-12);
        assert!((normalize_angle(-3.0 * PI / 2.0) - PI / 2.0).abs() < 1e-12);
        assert!((normalize_angle(0.25) - 0.25).abs() < 1e-15);
        assert!(normalize_angle(f64::NAN).is_nan());
    }
}

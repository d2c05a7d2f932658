//! What both I/O shells share: the driver error, the speed limits and the sonar ring (feature `std`).

use std::io;

use ima_hal::ErrorKind;

use crate::machine::SessionError;

pub use ima_serial::{BaudControl, FixedBaud};

/// Errors of the P2OS drivers (both shells).
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum DriverError {
    /// The driver task has ended (port closed, I/O error, or [`P2os::close`]).
    Disconnected,
    /// The robot did not answer in time.
    Timeout,
    /// The session refused the request.
    Session(SessionError),
    /// The robot never confirmed ENABLE (motors switch or E-stop).
    MotorsRefused,
    /// The robot's subclass has no parameter table (set `Config::params_override`).
    UnsupportedRobot(String),
    /// No rate answered the handshake.
    HandshakeFailed,
    /// The handshake did not complete while connecting: what was seen at each rate tried.
    NoAnswer(Box<ima_hal::link::ProbeReport>),
    /// An I/O error on the port.
    Io(io::ErrorKind),
}

impl std::fmt::Display for DriverError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Disconnected => f.write_str("P2OS driver disconnected"),
            Self::Timeout => f.write_str("P2OS robot did not answer in time"),
            Self::Session(e) => write!(f, "{e}"),
            Self::MotorsRefused => {
                f.write_str("robot did not enable its motors (motor switch off or E-stop engaged?)")
            }
            Self::UnsupportedRobot(s) => write!(
                f,
                "robot subclass {s:?} has no parameter table; set a params override"
            ),
            Self::HandshakeFailed => {
                f.write_str("no answer to the P2OS handshake at the rates probed")
            }
            Self::NoAnswer(report) => write!(
                f,
                "no P2OS robot completed the handshake (robot on? right port?): {report}"
            ),
            Self::Io(k) => write!(f, "serial I/O error: {k}"),
        }
    }
}

impl std::error::Error for DriverError {}

ima_serial::impl_from_link_error!(DriverError);

/// The speed limits of `params`.
#[must_use]
pub fn limits(params: &crate::params::RobotParams) -> ima_hal::base::BaseLimits {
    ima_hal::base::BaseLimits {
        max_v_m_s: params.max_velocity_mm_s / 1000.0,
        max_omega_rad_s: params.max_rot_velocity_deg_s.to_radians(),
    }
}

impl ima_hal::Error for DriverError {
    fn kind(&self) -> ErrorKind {
        match self {
            Self::Disconnected | Self::Io(_) => ErrorKind::Disconnected,
            Self::Timeout | Self::HandshakeFailed | Self::NoAnswer(_) => ErrorKind::Timeout,
            Self::Session(e) => ima_hal::Error::kind(e),
            Self::MotorsRefused | Self::UnsupportedRobot(_) => ErrorKind::Protocol,
        }
    }
}

/// The sonar ring of `params` as HAL transducers (P2OS sonar: 10 cm–5 m, ~30° beams).
#[must_use]
pub fn transducers(params: &crate::params::RobotParams) -> Vec<ima_hal::sonar::SonarTransducer> {
    params
        .sonars
        .iter()
        .map(|s| ima_hal::sonar::SonarTransducer {
            pose: ima_hal::Isometry2::new(
                ima_hal::Vector2::new(s.x_mm / 1000.0, s.y_mm / 1000.0),
                s.heading_deg.to_radians(),
            ),
            min_range_m: 0.1,
            max_range_m: 5.0,
            beam_width_rad: 30f64.to_radians(),
        })
        .collect()
}

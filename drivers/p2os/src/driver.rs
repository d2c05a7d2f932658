//! The P2OS driver's faults (feature `std`); its errors are
//! [`DriverError`] = [`ima_serial::DriverError`]`<`[`Fault`]`>`.

use ima_hal::ErrorKind;
use ima_hal::link::ProbeReport;

use crate::machine::SessionError;

pub use ima_serial::{BaudControl, FixedBaud};

/// Errors of the P2OS driver: the link's, or a [`Fault`] of the robot.
pub type DriverError = ima_serial::DriverError<Fault>;

/// What only a P2OS robot reports.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum Fault {
    /// The session refused the request.
    #[error("{0}")]
    Session(SessionError),
    /// The robot never confirmed ENABLE (motors switch or E-stop).
    #[error("robot did not enable its motors (motor switch off or E-stop engaged?)")]
    MotorsRefused,
    /// The robot's subclass has no parameter table (set `Config::params_override`).
    #[error("robot subclass {0:?} has no parameter table; set a params override")]
    UnsupportedRobot(String),
    /// No rate answered the handshake.
    #[error("no answer to the P2OS handshake at the rates probed")]
    HandshakeFailed,
    /// The handshake did not complete while connecting: what was seen at each rate tried.
    #[error("no P2OS robot completed the handshake (robot on? right port?): {0}")]
    NoAnswer(Box<ProbeReport>),
}

impl From<SessionError> for DriverError {
    fn from(e: SessionError) -> Self {
        Self::Device(Fault::Session(e))
    }
}

impl ima_serial::Fault for Fault {
    const DEVICE: &'static str = "P2OS robot";

    fn kind(&self) -> ErrorKind {
        match self {
            Self::HandshakeFailed | Self::NoAnswer(_) => ErrorKind::Timeout,
            Self::Session(e) => ima_hal::Error::kind(e),
            Self::MotorsRefused | Self::UnsupportedRobot(_) => ErrorKind::Protocol,
        }
    }
}

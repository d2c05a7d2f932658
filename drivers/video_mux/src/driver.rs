//! What both I/O shells share: the driver error (feature `std`).

use std::io;

use ima_hal::ErrorKind;

use crate::machine::{Failure, Refusal, RequestError};

/// Errors of the switcher drivers (both shells).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum DriverError {
    /// The driver task has ended (port closed, I/O error, or `close`).
    Disconnected,
    /// The switcher did not answer after all retries.
    Timeout,
    /// The session refused the request before sending (bad channel, busy).
    Request(RequestError),
    /// The switcher refused (Extron `Enn`, Kramer error).
    Refused(Refusal),
    /// An I/O error on the port.
    Io(io::ErrorKind),
}

impl From<Failure> for DriverError {
    fn from(f: Failure) -> Self {
        match f {
            Failure::Timeout => Self::Timeout,
            Failure::Refused(r) => Self::Refused(r),
        }
    }
}

impl std::fmt::Display for DriverError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Disconnected => f.write_str("video switcher driver disconnected"),
            Self::Timeout => f.write_str("the video switcher did not answer"),
            Self::Request(e) => write!(f, "{e}"),
            Self::Refused(Refusal::Extron(e)) => {
                write!(f, "the switcher refused: E{:02} ({e:?})", e.code())
            }
            Self::Refused(Refusal::Kramer(c)) => write!(f, "the switcher refused: code {c}"),
            Self::Io(k) => write!(f, "serial I/O error: {k}"),
        }
    }
}

impl std::error::Error for DriverError {}

ima_serial::impl_from_link_error!(DriverError);

impl ima_hal::Error for DriverError {
    fn kind(&self) -> ErrorKind {
        match self {
            Self::Disconnected | Self::Io(_) => ErrorKind::Disconnected,
            Self::Timeout => ErrorKind::Timeout,
            Self::Request(e) => ima_hal::Error::kind(e),
            Self::Refused(_) => ErrorKind::Protocol,
        }
    }
}

//! The switcher driver's faults (feature `std`); its errors are [`DriverError`] =
//! [`ima_serial::DriverError`]`<`[`Fault`]`>`.

use ima_hal::ErrorKind;

use crate::machine::{Failure, Refusal, RequestError};

/// Errors of the switcher driver: the link's, or a [`Fault`] of the switcher.
pub type DriverError = ima_serial::DriverError<Fault>;

/// What only a video switcher reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum Fault {
    /// The session refused the request before sending (bad channel, busy).
    Request(RequestError),
    /// The switcher refused (Extron `Enn`, Kramer error).
    Refused(Refusal),
}

impl From<RequestError> for DriverError {
    fn from(e: RequestError) -> Self {
        Self::Device(Fault::Request(e))
    }
}

/// A failed request: no answer after all retries (`Timeout`), or the switcher's refusal.
impl From<Failure> for DriverError {
    fn from(f: Failure) -> Self {
        match f {
            Failure::Timeout => Self::Timeout,
            Failure::Refused(r) => Self::Device(Fault::Refused(r)),
        }
    }
}

impl std::fmt::Display for Fault {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Request(e) => write!(f, "{e}"),
            Self::Refused(Refusal::Extron(e)) => {
                write!(f, "the switcher refused: E{:02} ({e:?})", e.code())
            }
            Self::Refused(Refusal::Kramer(c)) => write!(f, "the switcher refused: code {c}"),
        }
    }
}

impl ima_serial::Fault for Fault {
    const DEVICE: &'static str = "video switcher";

    fn kind(&self) -> ErrorKind {
        match self {
            Self::Request(e) => ima_hal::Error::kind(e),
            Self::Refused(_) => ErrorKind::Protocol,
        }
    }
}

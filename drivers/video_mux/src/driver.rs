//! The switcher driver's faults (feature `std`); its errors are [`DriverError`] =
//! [`ima_serial::DriverError`]`<`[`Fault`]`>`.

use ima_hal::ErrorKind;

use crate::machine::{Failure, Refusal, RequestError};

/// Errors of the switcher driver: the link's, or a [`Fault`] of the switcher.
pub type DriverError = ima_serial::DriverError<Fault>;

/// What only a video switcher reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum Fault {
    /// The session refused the request before sending (bad channel, busy).
    #[error("{0}")]
    Request(RequestError),
    /// The switcher refused (Extron `Enn`, Kramer error).
    #[error("the switcher refused: {}", match .0 {
        Refusal::Extron(e) => e.to_string(),
        Refusal::Kramer(c) => format!("code {c}"),
    })]
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

impl ima_serial::Fault for Fault {
    const DEVICE: &'static str = "video switcher";

    fn kind(&self) -> ErrorKind {
        match self {
            Self::Request(e) => ima_hal::Error::kind(e),
            Self::Refused(_) => ErrorKind::Protocol,
        }
    }
}

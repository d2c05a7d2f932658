//! What both I/O shells share: the driver error (feature `std`).

use std::io;

use ima_hal::ErrorKind;

use crate::machine::{Job, RequestError};

/// Errors of the compass drivers (both shells).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum DriverError {
    /// The driver task has ended (port closed, I/O error, or `close`).
    Disconnected,
    /// The compass did not answer or send data in time.
    Timeout,
    /// The session refused the request (wrong dialect, busy…).
    Request(RequestError),
    /// A configuration or calibration job gave up after its retries.
    JobFailed {
        /// The job.
        job: Job,
        /// The step it was at.
        step: u8,
    },
    /// An I/O error on the port.
    Io(io::ErrorKind),
}

impl std::fmt::Display for DriverError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Disconnected => f.write_str("compass driver disconnected"),
            Self::Timeout => f.write_str("the compass did not answer in time"),
            Self::Request(e) => write!(f, "{e}"),
            Self::JobFailed { job, step } => {
                write!(f, "compass job {job:?} failed at step {step} (no answer)")
            }
            Self::Io(k) => write!(f, "serial I/O error: {k}"),
        }
    }
}

impl std::error::Error for DriverError {}

impl ima_hal::Error for DriverError {
    fn kind(&self) -> ErrorKind {
        match self {
            Self::Disconnected | Self::Io(_) => ErrorKind::Disconnected,
            Self::Timeout | Self::JobFailed { .. } => ErrorKind::Timeout,
            Self::Request(e) => ima_hal::Error::kind(e),
        }
    }
}

//! What both I/O shells share: the driver error (feature `std`).

use std::io;

use ima_hal::ErrorKind;

use crate::machine::{Dialect, ForeignLine, Job, RequestError};

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
    /// The configuration got no usable answer: what the port received meanwhile.
    NoAnswer {
        /// The step of the configuration script it gave up at (`None`: the connect timeout
        /// passed first).
        step: Option<u8>,
        /// Bytes received.
        bytes: u32,
        /// Valid lines (of any dialect) among them.
        lines: u32,
        /// Lines dropped for a bad checksum, length or byte.
        bad_lines: u32,
    },
    /// The device speaks another dialect than the one configured.
    WrongDialect {
        /// The dialect configured.
        expected: Dialect,
        /// What the device sent.
        seen: ForeignLine,
        /// Lines of that dialect seen.
        lines: u32,
    },
}

/// The error for a configuration job that gave up at `step`: the other dialect the device
/// spoke if it sent any ([`DriverError::WrongDialect`]), else what the line carried
/// ([`DriverError::NoAnswer`]).
#[must_use]
pub fn configuration_failed(machine: &crate::machine::Machine, step: u8) -> DriverError {
    let st = machine.stats();
    match machine.foreign_line() {
        Some(seen) => DriverError::WrongDialect {
            expected: machine.config().dialect,
            seen,
            lines: st.foreign_lines,
        },
        None => no_answer(&st, Some(step)),
    }
}

/// No heading (or no answer to configuration `step`): what the line carried.
#[must_use]
pub fn no_answer(st: &crate::machine::Stats, step: Option<u8>) -> DriverError {
    DriverError::NoAnswer {
        step,
        bytes: st.bytes,
        lines: st.framer.lines,
        bad_lines: st
            .framer
            .bad_checksums
            .saturating_add(st.framer.overlong)
            .saturating_add(st.framer.bad_bytes)
            .saturating_add(st.parse_errors),
    }
}

/// A dialect's name for messages (`TCM2`, `KVH C100`, `NMEA`).
#[must_use]
pub fn dialect_name(d: Dialect) -> &'static str {
    match d {
        Dialect::Nmea => "NMEA",
        Dialect::KvhC100 { .. } => "KVH C100 (NMEA)",
        Dialect::Tcm2 { .. } => "TCM2",
    }
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
            Self::NoAnswer {
                step,
                bytes,
                lines,
                bad_lines,
            } => {
                f.write_str("the compass did not answer its configuration")?;
                if let Some(step) = step {
                    write!(f, " (step {step})")?;
                }
                f.write_str(": ")?;
                if *bytes == 0 {
                    return f.write_str("silence on the line (powered? right port? right rate?)");
                }
                write!(
                    f,
                    "received {} bytes, ",
                    ima_hal::link::Thousands(u64::from(*bytes))
                )?;
                match lines {
                    0 => f.write_str("no valid line")?,
                    1 => f.write_str("1 valid line")?,
                    n => write!(f, "{n} valid lines")?,
                }
                if *bad_lines > 0 {
                    write!(f, " ({bad_lines} bad)")?;
                }
                if *lines == 0 {
                    f.write_str(" (wrong rate or wrong device?)")?;
                }
                Ok(())
            }
            Self::WrongDialect {
                expected,
                seen,
                lines,
            } => write!(
                f,
                "the compass answered in {seen}, not {} ({lines} such lines; its configuration got no answer)",
                dialect_name(*expected)
            ),
        }
    }
}

impl std::error::Error for DriverError {}

ima_serial::impl_from_link_error!(DriverError);

impl ima_hal::Error for DriverError {
    fn kind(&self) -> ErrorKind {
        match self {
            Self::Disconnected | Self::Io(_) => ErrorKind::Disconnected,
            Self::Timeout | Self::JobFailed { .. } | Self::NoAnswer { .. } => ErrorKind::Timeout,
            Self::WrongDialect { .. } => ErrorKind::Protocol,
            Self::Request(e) => ima_hal::Error::kind(e),
        }
    }
}

//! The compass driver's faults (feature `std`); its errors are [`DriverError`] =
//! [`ima_serial::DriverError`]`<`[`Fault`]`>`.

use ima_hal::ErrorKind;

use crate::machine::{Dialect, ForeignLine, Job, RequestError};

/// Errors of the compass driver: the link's, or a [`Fault`] of the device.
pub type DriverError = ima_serial::DriverError<Fault>;

/// What only a compass reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum Fault {
    /// The session refused the request (wrong dialect, busy…).
    Request(RequestError),
    /// A configuration or calibration job gave up after its retries.
    JobFailed {
        /// The job.
        job: Job,
        /// The step it was at.
        step: u8,
    },
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
/// spoke if it sent any ([`Fault::WrongDialect`]), else what the line carried
/// ([`Fault::NoAnswer`]).
#[must_use]
pub fn configuration_failed(machine: &crate::machine::Machine, step: u8) -> DriverError {
    let st = machine.stats();
    match machine.foreign_line() {
        Some(seen) => DriverError::Device(Fault::WrongDialect {
            expected: machine.config().dialect,
            seen,
            lines: st.foreign_lines,
        }),
        None => no_answer(&st, Some(step)),
    }
}

/// No heading (or no answer to configuration `step`): what the line carried.
#[must_use]
pub fn no_answer(st: &crate::machine::Stats, step: Option<u8>) -> DriverError {
    DriverError::Device(Fault::NoAnswer {
        step,
        bytes: st.bytes,
        lines: st.framer.lines,
        bad_lines: st
            .framer
            .bad_checksums
            .saturating_add(st.framer.overlong)
            .saturating_add(st.framer.bad_bytes)
            .saturating_add(st.parse_errors),
    })
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

impl std::fmt::Display for Fault {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Request(e) => write!(f, "{e}"),
            Self::JobFailed { job, step } => {
                write!(f, "compass job {job:?} failed at step {step} (no answer)")
            }
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

impl ima_serial::Fault for Fault {
    const DEVICE: &'static str = "compass";

    fn kind(&self) -> ErrorKind {
        match self {
            Self::JobFailed { .. } | Self::NoAnswer { .. } => ErrorKind::Timeout,
            Self::WrongDialect { .. } => ErrorKind::Protocol,
            Self::Request(e) => ima_hal::Error::kind(e),
        }
    }
}

impl From<Fault> for DriverError {
    fn from(f: Fault) -> Self {
        Self::Device(f)
    }
}

impl From<RequestError> for DriverError {
    fn from(e: RequestError) -> Self {
        Self::Device(Fault::Request(e))
    }
}

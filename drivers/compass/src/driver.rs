//! The compass driver's faults (feature `std`); its errors are [`DriverError`] =
//! [`ima_serial::DriverError`]`<`[`Fault`]`>`.

use ima_hal::ErrorKind;
use ima_hal::link::Heard;

use crate::machine::{Dialect, ForeignLine, Job, RequestError};

/// Errors of the compass driver: the link's, or a [`Fault`] of the device.
pub type DriverError = ima_serial::DriverError<Fault>;

/// What only a compass reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum Fault {
    /// The session refused the request (wrong dialect, busy…).
    #[error("{0}")]
    Request(RequestError),
    /// A configuration or calibration job gave up after its retries.
    #[error("the compass's {job} got no answer (step {step})")]
    JobFailed {
        /// The job.
        job: Job,
        /// The step it was at.
        step: u8,
    },
    /// The configuration got no usable answer: what the port received meanwhile.
    #[error("{}: {}",
        step.map_or_else(
            || "no heading came from the compass".to_owned(),
            |s| format!("the compass did not answer its configuration (step {s})"),
        ),
        Heard {
            bytes: (*bytes).into(),
            valid: (*lines).into(),
            bad: (*bad_lines).into(),
            unit: "line",
            silence_hint: "powered? right port? right rate?",
        })]
    NoAnswer {
        /// The step of the configuration script it gave up at (`None`: the connect timeout
        /// passed first, or nothing was asked: an NMEA source is only listened to).
        step: Option<u8>,
        /// Bytes received.
        bytes: u32,
        /// Valid lines (of any dialect) among them.
        lines: u32,
        /// Lines dropped for a bad checksum, length or byte.
        bad_lines: u32,
    },
    /// The device speaks another dialect than the one configured.
    #[error(
        "the compass answered in {seen}, not {} ({lines} such lines; its configuration got no answer)",
        expected.name()
    )]
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
        // An NMEA source is asked nothing: its one step only waits for a heading.
        None if machine.config().dialect == Dialect::Nmea => no_answer(&st, None),
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

impl From<RequestError> for DriverError {
    fn from(e: RequestError) -> Self {
        Self::Device(Fault::Request(e))
    }
}

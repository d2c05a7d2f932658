//! The rFLEX driver's faults and line settings (feature `std`); its errors are
//! [`DriverError`] = [`ima_serial::DriverError`]`<`[`Fault`]`>`.
//!
//! Unlike P2OS, the rFLEX runs at one fixed rate (115200 8N1, spec §1), so the shell needs
//! no line-speed control and takes any byte stream.

use ima_hal::ErrorKind;
use ima_hal::link::Heard;

use crate::machine::CommandError;

/// The rFLEX line speed (spec §1).
pub const BAUD: u32 = 115_200;

/// Errors of the rFLEX driver: the link's, or a [`Fault`] of the base.
pub type DriverError = ima_serial::DriverError<Fault>;

/// What only an rFLEX base reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum Fault {
    /// The machine refused the command.
    #[error("{0}")]
    Command(CommandError),
    /// No motion report arrived while connecting: what the line carried instead.
    #[error("no motion report from the rFLEX base: {}", Heard {
        bytes: *bytes,
        valid: (*frames).into(),
        bad: (*bad_frames).into(),
        unit: "frame",
        silence_hint: "base on? right port?",
    })]
    NoReport {
        /// Bytes received.
        bytes: u64,
        /// Valid frames among them.
        frames: u32,
        /// Frames dropped as bad.
        bad_frames: u32,
    },
}

impl ima_serial::Fault for Fault {
    const DEVICE: &'static str = "rFLEX base";

    fn kind(&self) -> ErrorKind {
        match self {
            Self::NoReport { .. } => ErrorKind::Timeout,
            Self::Command(e) => ima_hal::Error::kind(e),
        }
    }
}

impl From<CommandError> for DriverError {
    fn from(e: CommandError) -> Self {
        Self::Device(Fault::Command(e))
    }
}

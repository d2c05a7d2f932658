//! The rFLEX driver's faults and line settings (feature `std`); its errors are
//! [`DriverError`] = [`ima_serial::DriverError`]`<`[`Fault`]`>`.
//!
//! Unlike P2OS, the rFLEX runs at one fixed rate (115200 8N1, spec §1), so the shell needs
//! no line-speed control and takes any byte stream.

use ima_hal::ErrorKind;

use crate::machine::CommandError;

/// The rFLEX line speed (spec §1).
pub const BAUD: u32 = 115_200;

/// Errors of the rFLEX driver: the link's, or a [`Fault`] of the base.
pub type DriverError = ima_serial::DriverError<Fault>;

/// What only an rFLEX base reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum Fault {
    /// The machine refused the command.
    Command(CommandError),
    /// No motion report arrived while connecting: what the line carried instead.
    NoReport {
        /// Bytes received.
        bytes: u64,
        /// Valid frames among them.
        frames: u32,
        /// Frames dropped as bad.
        bad_frames: u32,
    },
}

impl std::fmt::Display for Fault {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (bytes, frames, bad_frames) = match *self {
            Self::Command(e) => return write!(f, "{e}"),
            Self::NoReport {
                bytes,
                frames,
                bad_frames,
            } => (bytes, frames, bad_frames),
        };
        f.write_str("no motion report from the rFLEX base: ")?;
        if bytes == 0 {
            return f.write_str("silence on the line (base on? right port?)");
        }
        write!(f, "received {} bytes, ", ima_hal::link::Thousands(bytes))?;
        match frames {
            0 => f.write_str("no valid frame")?,
            1 => f.write_str("1 valid frame")?,
            n => write!(f, "{n} valid frames")?,
        }
        if bad_frames > 0 {
            write!(f, " ({bad_frames} bad)")?;
        }
        if frames == 0 {
            f.write_str(" (wrong rate or wrong device?)")?;
        }
        Ok(())
    }
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

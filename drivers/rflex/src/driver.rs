//! What both I/O shells share: the driver error and the serial port settings (feature `std`).
//!
//! Unlike P2OS, the rFLEX runs at one fixed rate (115200 8N1, spec §1), so the shells need no
//! line-speed control and take any byte stream.

use std::io;

use ima_hal::ErrorKind;

use crate::machine::CommandError;

/// The rFLEX line speed (§1).
pub const BAUD: u32 = 115_200;

/// Errors of the rFLEX drivers (both shells).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum DriverError {
    /// The driver task has ended (port closed, I/O error, or `close`).
    Disconnected,
    /// The base did not answer in time (no report at connect, no brake confirmation).
    Timeout,
    /// The session refused the request (motors disabled, not finite, closed).
    Command(CommandError),
    /// An I/O error on the port.
    Io(io::ErrorKind),
    /// No motion report came while connecting: what the line carried meanwhile.
    NoReport {
        /// Bytes received.
        bytes: u64,
        /// Valid frames among them.
        frames: u32,
        /// Frames dropped (checksum, length, escape, size).
        bad_frames: u32,
    },
}

impl std::fmt::Display for DriverError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Disconnected => f.write_str("rFLEX driver disconnected"),
            Self::Timeout => f.write_str("rFLEX base did not answer in time"),
            Self::Command(e) => write!(f, "{e}"),
            Self::Io(k) => write!(f, "serial I/O error: {k}"),
            Self::NoReport {
                bytes,
                frames,
                bad_frames,
            } => {
                f.write_str("no motion report from the rFLEX base: ")?;
                if *bytes == 0 {
                    return f.write_str("silence on the line (base on? right port?)");
                }
                write!(f, "received {} bytes, ", ima_hal::link::Thousands(*bytes))?;
                match frames {
                    0 => f.write_str("no valid frame")?,
                    1 => f.write_str("1 valid frame")?,
                    n => write!(f, "{n} valid frames")?,
                }
                if *bad_frames > 0 {
                    write!(f, " ({bad_frames} bad)")?;
                }
                if *frames == 0 {
                    f.write_str(" (wrong rate or wrong device?)")?;
                }
                Ok(())
            }
        }
    }
}

impl std::error::Error for DriverError {}

impl ima_hal::Error for DriverError {
    fn kind(&self) -> ErrorKind {
        match self {
            Self::Disconnected | Self::Io(_) => ErrorKind::Disconnected,
            Self::Timeout | Self::NoReport { .. } => ErrorKind::Timeout,
            Self::Command(e) => ima_hal::Error::kind(e),
        }
    }
}

ima_serial::impl_from_link_error!(DriverError);

/// The connect error when no motion report came: what the line carried.
#[cfg(feature = "tokio")]
#[must_use]
pub fn no_report(st: &crate::shell::ShellStats) -> DriverError {
    DriverError::NoReport {
        bytes: st.bytes,
        frames: st.framer.frames,
        bad_frames: st.framer.errors(),
    }
}

impl From<CommandError> for DriverError {
    fn from(e: CommandError) -> Self {
        Self::Command(e)
    }
}

//! The SICK LMS driver's faults (its errors are [`DriverError`] =
//! [`ima_serial::DriverError`]`<`[`Fault`]`>`) and scan statistics (feature `std`).

use ima_hal::ErrorKind;

/// The line-rate arithmetic of spec §4 (in [`crate::decode`]).
pub use crate::decode::{expected_scan_rate_hz, line_scan_rate_hz};
use crate::framer::Counters;
use crate::machine::{MachineError, SessionInfo, Stats};

pub use ima_serial::{BaudControl, FixedBaud};

/// How long closing may take: stopping the stream and switching the unit back to 9600
/// ([`crate::machine::Machine::close`]) each need one acknowledged telegram.
pub const CLOSE_TIMEOUT: std::time::Duration = std::time::Duration::from_millis(1500);

/// Errors of the SICK LMS driver: the link's, or a [`Fault`] of the unit.
pub type DriverError = ima_serial::DriverError<Fault>;

/// What only a SICK LMS reports.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum Fault {
    /// The session failed or refused a request.
    #[error("{}", match .0 {
        e @ MachineError::NoDevice => e.to_string(),
        e => format!("SICK LMS session: {e}"),
    })]
    Session(MachineError),
    /// A B0 could not be decoded (unknown measuring mode, reflectivity mode…).
    #[error("SICK LMS scan decoding: {0}")]
    Decode(crate::decode::DecodeError),
    /// No unit answered while connecting: what was seen at each rate tried.
    #[error(
        "no SICK LMS answered (powered? still booting? right port?): {report}{}",
        if *rs422 { "" } else { "; 500000 baud not tried (RS-422 lines only)" }
    )]
    NotFound {
        /// Bytes and frames per rate.
        report: Box<ima_hal::link::ProbeReport>,
        /// 500 000 baud was probed too ([`crate::machine::Config::rs422`]).
        rs422: bool,
    },
}

impl From<MachineError> for DriverError {
    fn from(e: MachineError) -> Self {
        Self::Device(Fault::Session(e))
    }
}

impl ima_serial::Fault for Fault {
    const DEVICE: &'static str = "SICK LMS";

    fn kind(&self) -> ErrorKind {
        match self {
            Self::NotFound { .. }
            | Self::Session(
                MachineError::NoDevice | MachineError::Timeout { .. } | MachineError::StreamStalled,
            ) => ErrorKind::Timeout,
            Self::Session(MachineError::Busy | MachineError::Unsendable { .. }) => ErrorKind::Other,
            Self::Session(MachineError::NeedsRs422) => ErrorKind::InvalidArgument,
            Self::Session(_) | Self::Decode(_) => ErrorKind::Protocol,
        }
    }
}

/// Counters of a running driver.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ScanStats {
    /// Scans decoded and published.
    pub delivered: u64,
    /// B0 frames that did not decode (counted, not published).
    pub decode_errors: u64,
    /// Framer counters (bad CRCs, dropped bytes, expired partial frames, ACK/NAK…).
    pub framer: Counters,
    /// Session statistics (telegrams, retransmissions…).
    pub session: Stats,
    /// Times the session (re)reached the ready state.
    pub readies: u64,
    /// Times the link was lost (stream stalled, device restarted) and recovered by re-probing.
    pub losses: u64,
}

/// Link status as seen by handles: connected once initialised (scans flow if streaming was
/// asked for), with what the session runs with.
pub type LinkStatus = ima_serial::LinkStatus<SessionInfo, DriverError>;

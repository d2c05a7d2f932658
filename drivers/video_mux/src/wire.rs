//! Wire formats of serial video switchers (spec `protocols/compass_video_mux.md` §7b).
//!
//! * [`extron`]: Extron SIS — ASCII commands without terminator (`3!`), replies ending CR LF
//!   (`In3 All`).
//! * [`kramer`]: Kramer Protocol 2000 — 4-byte binary messages.
//!
//! Both directions parse and emit, so the mock switcher can reuse this module.

pub mod extron;
pub mod kramer;

pub use extron::{ExtronCommand, ExtronError, ExtronReply, Signals, TieKind};
pub use kramer::{Instruction, KramerMessage};

/// What was wrong with a message. Small and `Copy`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum WireError {
    /// Nothing to parse.
    Empty,
    /// The output buffer is too small.
    BufferTooSmall,
    /// Fewer bytes than the message needs.
    Truncated,
    /// More bytes than the message has.
    TrailingBytes,
    /// A byte that breaks the format (non-printable in SIS; a misplaced high bit in P2000).
    BadByte(u8),
    /// A number is malformed.
    BadNumber,
    /// A reply this crate does not recognise.
    UnknownReply,
    /// A command this crate does not recognise.
    UnknownCommand,
    /// A value the wire cannot carry: on the emit side, or, parsed, a well-formed number too
    /// large for its field (an input `99999`).
    OutOfRange,
}

impl core::fmt::Display for WireError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Empty => f.write_str("empty message"),
            Self::BufferTooSmall => f.write_str("output buffer too small"),
            Self::Truncated => f.write_str("truncated message"),
            Self::TrailingBytes => f.write_str("trailing bytes after message"),
            Self::BadByte(b) => write!(f, "unexpected byte 0x{b:02x}"),
            Self::BadNumber => f.write_str("malformed number"),
            Self::UnknownReply => f.write_str("unknown reply"),
            Self::UnknownCommand => f.write_str("unknown command"),
            Self::OutOfRange => f.write_str("value out of range"),
        }
    }
}

impl core::error::Error for WireError {}

/// The shared byte cursor.
pub(crate) use ima_hal::bytes::Writer;

ima_hal::cursor_errors!(WireError {
    overflow: |_| WireError::BufferTooSmall
});

/// Parse an unsigned decimal of 1–5 digits: [`WireError::BadNumber`] if it is not one,
/// [`WireError::OutOfRange`] if it is all digits but too large for a `u16`.
pub(crate) fn parse_u16(s: &[u8]) -> Result<u16, WireError> {
    use ima_hal::bytes::{DecimalError, parse_decimal};
    match parse_decimal(s, 5) {
        Ok(v) => u16::try_from(v).map_err(|_| WireError::OutOfRange),
        Err(DecimalError::TooLong { .. }) if s.iter().all(u8::is_ascii_digit) => {
            Err(WireError::OutOfRange)
        }
        Err(_) => Err(WireError::BadNumber),
    }
}

/// A number of at most 255 (`Vrb3`, `F1`), as [`parse_u16`] reads it.
pub(crate) fn parse_u8(s: &[u8]) -> Result<u8, WireError> {
    u8::try_from(parse_u16(s)?).map_err(|_| WireError::OutOfRange)
}

/// Whether `s` is a number: one or more ASCII digits.
pub(crate) fn is_number(s: &[u8]) -> bool {
    !s.is_empty() && s.iter().all(u8::is_ascii_digit)
}

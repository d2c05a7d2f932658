//! Wire format of serial compasses: ASCII lines from the device, ASCII commands to it.
//!
//! Spec: `protocols/compass_video_mux.md` §7a.
//!
//! * [`nmea`]: NMEA 0183 `HDG`, `HDM`, `HDT` sentences, any talker id, checksum checked.
//! * [`tcm2`]: the PNI TCM2 standard output line `$C…P…R…X…Y…Z…T…E…*cs` and its calibration
//!   score `HnVnMn.n`.
//! * [`command`]: KVH C100 (`=t,0`, `=r,N`, `=b,48`) and TCM2 (`h`, `go`, `sdo=t`, …) commands.
//!
//! Everything parses **and** emits, so the mock devices can reuse this module in the device
//! role. Numbers travel as [`Decimal`], which keeps the digits as written, so that
//! `emit(parse(x))` reproduces canonical lines byte for byte and `parse(emit(m)) == m` always.

pub mod command;
pub mod nmea;
pub mod tcm2;

pub use command::{Command, KvhBaud, KvhCommand, KvhFormat, Tcm2Command, Tcm2Format};
pub use nmea::{EastWest, Hdg, Hdm, Hdt, NmeaBody, NmeaSentence, Offset, Talker};
pub use tcm2::{CalScore, Tcm2Data};

/// Longest line a compass sends that this crate accepts (NMEA allows 82 characters including
/// `$` and CR LF; a TCM2 line with every field is about 60).
pub const MAX_LINE: usize = 96;

/// What was wrong with a line or command. Small and `Copy`; nothing here allocates.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum WireError {
    /// Nothing to parse (empty line).
    Empty,
    /// The output buffer is too small for the message.
    BufferTooSmall,
    /// A byte that is not printable ASCII.
    BadByte(u8),
    /// `$…` line without `*hh` (and missing checksums are not allowed by the options).
    MissingChecksum,
    /// The two characters after `*` are not hex digits, or something follows them.
    BadChecksumDigits,
    /// The checksum does not match: `expected` is computed from the line, `got` was sent.
    BadChecksum {
        /// XOR of the bytes between `$` and `*`.
        expected: u8,
        /// The checksum the line carries.
        got: u8,
    },
    /// The NMEA address field is not two talker characters plus three type characters.
    BadAddress,
    /// An NMEA sentence type this crate does not know (the three type letters).
    UnknownSentence([u8; 3]),
    /// Field number `n` (1 = first after the address) is malformed.
    BadField(u8),
    /// Field number `n` is required but missing.
    MissingField(u8),
    /// Field number `n` is not expected (non-empty fields past the end of the sentence).
    ExtraField(u8),
    /// A number is malformed or has too many digits.
    BadNumber,
    /// A TCM2 field letter that is unknown, repeated or out of order.
    BadTcm2Field(u8),
    /// A line that is none of the known kinds.
    UnknownLine,
    /// A command the device does not know.
    UnknownCommand,
    /// A value out of the range the wire format can carry (emit side).
    OutOfRange,
}

impl core::fmt::Display for WireError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Empty => f.write_str("empty line"),
            Self::BufferTooSmall => f.write_str("output buffer too small"),
            Self::BadByte(b) => write!(f, "non-printable byte 0x{b:02x}"),
            Self::MissingChecksum => f.write_str("missing checksum"),
            Self::BadChecksumDigits => f.write_str("malformed checksum"),
            Self::BadChecksum { expected, got } => {
                write!(
                    f,
                    "bad checksum: computed {expected:02X}, line has {got:02X}"
                )
            }
            Self::BadAddress => f.write_str("bad NMEA address field"),
            Self::UnknownSentence(t) => write!(
                f,
                "unknown NMEA sentence {}{}{}",
                char::from(t[0]),
                char::from(t[1]),
                char::from(t[2])
            ),
            Self::BadField(n) => write!(f, "malformed field {n}"),
            Self::MissingField(n) => write!(f, "missing field {n}"),
            Self::ExtraField(n) => write!(f, "unexpected field {n}"),
            Self::BadNumber => f.write_str("malformed number"),
            Self::BadTcm2Field(c) => write!(f, "bad TCM2 field letter 0x{c:02x}"),
            Self::UnknownLine => f.write_str("unknown line"),
            Self::UnknownCommand => f.write_str("unknown command"),
            Self::OutOfRange => f.write_str("value out of range"),
        }
    }
}

impl core::error::Error for WireError {}

/// NMEA 0183 checksum: XOR of all bytes (the caller passes those strictly between `$` and `*`).
#[must_use]
pub fn checksum(body: &[u8]) -> u8 {
    body.iter().fold(0, |acc, b| acc ^ b)
}

/// How strict parsing is (`Default`: strict).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ParseOptions {
    /// Accept `$…` lines with no `*hh` checksum. The spec says TCM2 lines carry the NMEA
    /// checksum but its example line has none, and some TCM2 set-ups turn it off; so the
    /// default (`false`) follows the stated rule and this option admits the alternative.
    pub allow_missing_checksum: bool,
}

/// Anything a compass sends, one line each.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Line {
    /// An NMEA heading sentence.
    Nmea(NmeaSentence),
    /// A TCM2 standard output line (also the reply to `c?`).
    Tcm2(Tcm2Data),
    /// A TCM2 calibration score `HnVnMn.n`.
    CalScore(CalScore),
    /// The KVH `>` prompt: the previous command was accepted.
    Prompt,
}

impl Line {
    /// Parse one line (with or without its CR/LF terminator).
    ///
    /// # Errors
    /// A [`WireError`] saying what is wrong; the caller counts it and goes on.
    pub fn parse(line: &[u8], opts: &ParseOptions) -> Result<Self, WireError> {
        let line = trim_eol(line);
        match line {
            [] => Err(WireError::Empty),
            [b'>', rest @ ..] if rest.iter().all(|b| *b == b' ') => Ok(Self::Prompt),
            [b'$', rest @ ..] => {
                if nmea::looks_like_nmea(rest) {
                    NmeaSentence::parse(line, opts).map(Self::Nmea)
                } else {
                    Tcm2Data::parse(line, opts).map(Self::Tcm2)
                }
            }
            [b'H', ..] => CalScore::parse(line).map(Self::CalScore),
            _ => Err(WireError::UnknownLine),
        }
    }

    /// Write the line, terminated as the device does (CR LF; the prompt is a bare `>`).
    ///
    /// # Errors
    /// [`WireError::BufferTooSmall`], or [`WireError::OutOfRange`] for unrepresentable values.
    pub fn emit(&self, buf: &mut [u8]) -> Result<usize, WireError> {
        match self {
            Self::Nmea(s) => s.emit(buf),
            Self::Tcm2(d) => d.emit(buf),
            Self::CalScore(c) => c.emit(buf),
            Self::Prompt => {
                let mut w = Writer::new(buf);
                w.u8(b'>')?;
                Ok(w.pos())
            }
        }
    }
}

/// Strip trailing CR and LF bytes.
#[must_use]
pub fn trim_eol(mut line: &[u8]) -> &[u8] {
    while let [rest @ .., b'\r' | b'\n'] = line {
        line = rest;
    }
    line
}

/// Split `$body*hh` and check the checksum. Returns the body (between `$` and `*`).
pub(crate) fn split_checked<'a>(
    line: &'a [u8],
    opts: &ParseOptions,
) -> Result<&'a [u8], WireError> {
    let Some((b'$', rest)) = line.split_first() else {
        return Err(WireError::UnknownLine);
    };
    if let Some(b) = rest.iter().find(|b| !(0x20..=0x7e).contains(*b)) {
        return Err(WireError::BadByte(*b));
    }
    match rest.iter().position(|b| *b == b'*') {
        Some(star) => {
            let (body, tail) = rest.split_at(star);
            let got = match tail {
                [b'*', hi, lo] => hex_pair(*hi, *lo).ok_or(WireError::BadChecksumDigits)?,
                _ => return Err(WireError::BadChecksumDigits),
            };
            let expected = checksum(body);
            if expected != got && !cfg!(fuzzing) {
                return Err(WireError::BadChecksum { expected, got });
            }
            Ok(body)
        }
        None if opts.allow_missing_checksum => Ok(rest),
        None => Err(WireError::MissingChecksum),
    }
}

pub(crate) fn hex_val(c: u8) -> Option<u8> {
    match c {
        b'0'..=b'9' => Some(c - b'0'),
        b'A'..=b'F' => Some(c - b'A' + 10),
        b'a'..=b'f' => Some(c - b'a' + 10),
        _ => None,
    }
}

fn hex_pair(hi: u8, lo: u8) -> Option<u8> {
    Some((hex_val(hi)? << 4) | hex_val(lo)?)
}

const HEX: &[u8; 16] = b"0123456789ABCDEF";

/// The shared byte cursor; the ASCII sentences add [`AsciiWriter`].
pub(crate) use ima_hal::bytes::Writer;

ima_hal::cursor_errors!(WireError {
    overflow: |_| WireError::BufferTooSmall
});

/// What compass sentences write beyond bytes and decimals.
pub(crate) trait AsciiWriter {
    /// Upper-case hex with at least `min_digits` digits.
    fn hex(&mut self, v: u16, min_digits: u8) -> Result<(), WireError>;
    /// `*hh` over the bytes written after the leading `$`, then CR LF; the length written.
    fn nmea_tail(&mut self) -> Result<usize, WireError>;
}

impl AsciiWriter for Writer<'_> {
    fn hex(&mut self, v: u16, min_digits: u8) -> Result<(), WireError> {
        let mut started = false;
        for i in (0..4u8).rev() {
            let nib = usize::from((v >> (i * 4)) & 0xf);
            if nib != 0 || i < min_digits || started {
                started = true;
                self.u8(*HEX.get(nib).ok_or(WireError::OutOfRange)?)?;
            }
        }
        if !started {
            self.u8(b'0')?;
        }
        Ok(())
    }

    fn nmea_tail(&mut self) -> Result<usize, WireError> {
        let sum = checksum(self.written().get(1..).unwrap_or_default());
        let hex = |n: u8| {
            HEX.get(usize::from(n))
                .copied()
                .ok_or(WireError::OutOfRange)
        };
        self.u8(b'*')?
            .u8(hex(sum >> 4)?)?
            .u8(hex(sum & 0xf)?)?
            .bytes(b"\r\n")?;
        Ok(self.pos())
    }
}

/// Most digits a [`Decimal`] keeps (an `f64` holds 15 decimal digits exactly).
pub const MAX_DIGITS: u8 = 15;

const POW10: [i64; 16] = [
    1,
    10,
    100,
    1_000,
    10_000,
    100_000,
    1_000_000,
    10_000_000,
    100_000_000,
    1_000_000_000,
    10_000_000_000,
    100_000_000_000,
    1_000_000_000_000,
    10_000_000_000_000,
    100_000_000_000_000,
    1_000_000_000_000_000,
];

fn pow10(n: u8) -> i64 {
    POW10.get(usize::from(n)).copied().unwrap_or(i64::MAX)
}

/// A decimal number as written on the wire: `units / 10^decimals`, printed with at least
/// `int_digits` integer digits (leading zeros kept: KVH writes `005.3`).
///
/// Equality is on the written form (`5.0 != 5.00`); compare [`Decimal::to_f64`] for values.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Decimal {
    units: i64,
    decimals: u8,
    int_digits: u8,
}

impl Decimal {
    /// `0`.
    pub const ZERO: Self = Self {
        units: 0,
        decimals: 0,
        int_digits: 1,
    };

    /// `units / 10^decimals`, printed with the fewest integer digits (at least one).
    /// `None` if it would need more than [`MAX_DIGITS`] digits.
    #[must_use]
    pub fn new(units: i64, decimals: u8) -> Option<Self> {
        Self::with_int_digits(units, decimals, 1)
    }

    /// As [`Decimal::new`], zero-padding the integer part to `int_digits` (`0` prints `.5`
    /// for one half).
    #[must_use]
    pub fn with_int_digits(units: i64, decimals: u8, int_digits: u8) -> Option<Self> {
        if decimals > MAX_DIGITS {
            return None;
        }
        let int_part = units.unsigned_abs() / pow10(decimals).unsigned_abs();
        let needed = if int_part == 0 {
            0
        } else {
            digit_count(int_part)
        };
        let int_digits = int_digits.max(needed);
        if int_digits.saturating_add(decimals) > MAX_DIGITS
            || int_digits.saturating_add(decimals) == 0
        {
            return None;
        }
        Some(Self {
            units,
            decimals,
            int_digits,
        })
    }

    /// The nearest decimal with `decimals` fraction digits; `None` for non-finite or huge
    /// values.
    #[must_use]
    pub fn from_f64(v: f64, decimals: u8) -> Option<Self> {
        if !v.is_finite() || decimals > MAX_DIGITS {
            return None;
        }
        let x = v * pow10(decimals) as f64;
        if x.abs() >= 1e15 {
            return None;
        }
        let units = if x >= 0.0 { x + 0.5 } else { x - 0.5 } as i64;
        Self::new(units, decimals)
    }

    /// The value.
    #[must_use]
    pub fn to_f64(self) -> f64 {
        self.units as f64 / pow10(self.decimals) as f64
    }

    /// The scaled integer (`units / 10^decimals` is the value).
    #[must_use]
    pub fn units(self) -> i64 {
        self.units
    }

    /// Digits after the decimal point.
    #[must_use]
    pub fn decimals(self) -> u8 {
        self.decimals
    }

    /// Parse `[-+]digits[.digits]` (at least one digit, at most [`MAX_DIGITS`]).
    ///
    /// # Errors
    /// [`WireError::BadNumber`].
    pub fn parse(s: &[u8]) -> Result<Self, WireError> {
        let (neg, digits) = match s.split_first() {
            Some((b'-', rest)) => (true, rest),
            Some((b'+', rest)) => (false, rest),
            _ => (false, s),
        };
        let mut units: i64 = 0;
        let mut int_digits: u8 = 0;
        let mut decimals: u8 = 0;
        let mut seen_dot = false;
        for &c in digits {
            match c {
                b'0'..=b'9' => {
                    if int_digits.saturating_add(decimals) >= MAX_DIGITS {
                        return Err(WireError::BadNumber);
                    }
                    units = units * 10 + i64::from(c - b'0');
                    if seen_dot {
                        decimals += 1;
                    } else {
                        int_digits += 1;
                    }
                }
                b'.' if !seen_dot => seen_dot = true,
                _ => return Err(WireError::BadNumber),
            }
        }
        if int_digits == 0 && decimals == 0 {
            return Err(WireError::BadNumber);
        }
        Ok(Self {
            units: if neg { -units } else { units },
            decimals,
            int_digits,
        })
    }

    pub(crate) fn write(self, w: &mut Writer<'_>) -> Result<(), WireError> {
        if self.units < 0 {
            w.u8(b'-')?;
        }
        let abs = self.units.unsigned_abs();
        let scale = pow10(self.decimals).unsigned_abs();
        let int_part = abs / scale;
        if self.int_digits > 0 {
            w.decimal(int_part, self.int_digits)?;
        }
        if self.decimals > 0 {
            w.u8(b'.')?;
            w.decimal(abs % scale, self.decimals)?;
        }
        Ok(())
    }
}

fn digit_count(mut v: u64) -> u8 {
    let mut n = 0;
    while v > 0 {
        n += 1;
        v /= 10;
    }
    n
}

#[cfg(test)]
mod tests {
    use super::*;

    fn emit_decimal(d: Decimal) -> std::string::String {
        let mut buf = [0u8; 32];
        let mut w = Writer::new(&mut buf);
        d.write(&mut w).unwrap();
        let n = w.pos();
        std::string::String::from_utf8(buf[..n].to_vec()).unwrap()
    }

    #[test]
    fn decimal_keeps_written_form() {
        for s in [
            "238.5", "005.3", "-12.4", "0.0", "-0.5", ".5", "12", "55.11", "359.99",
        ] {
            let d = Decimal::parse(s.as_bytes()).unwrap();
            assert_eq!(emit_decimal(d), s, "{s}");
        }
        assert_eq!(Decimal::parse(b"+7.25").map(emit_decimal).unwrap(), "7.25");
        assert!((Decimal::parse(b"-12.4").unwrap().to_f64() + 12.4).abs() < 1e-12);
        for bad in ["", "-", ".", "1.2.3", "1e5", "12a", "1234567890123456"] {
            assert_eq!(
                Decimal::parse(bad.as_bytes()),
                Err(WireError::BadNumber),
                "{bad}"
            );
        }
    }

    #[test]
    fn decimal_from_f64_rounds() {
        assert_eq!(emit_decimal(Decimal::from_f64(238.46, 1).unwrap()), "238.5");
        assert_eq!(emit_decimal(Decimal::from_f64(-0.04, 1).unwrap()), "0.0");
        assert!(Decimal::from_f64(f64::NAN, 1).is_none());
        assert!(Decimal::from_f64(1e20, 1).is_none());
        assert_eq!(
            emit_decimal(Decimal::with_int_digits(53, 1, 3).unwrap()),
            "005.3"
        );
    }

    #[test]
    fn line_dispatch() {
        let o = ParseOptions::default();
        assert!(matches!(
            Line::parse(b"$HCHDM,238.5,M*25\r\n", &o),
            Ok(Line::Nmea(_))
        ));
        // Five upper-case-or-digit characters after `$` must not be mistaken for an address.
        let body = b"C3283";
        let line = std::format!("${}*{:02X}", "C3283", checksum(body));
        assert!(matches!(
            Line::parse(line.as_bytes(), &o),
            Ok(Line::Tcm2(_))
        ));
        // An error-only TCM2 line is five upper-case letters as well (found by fuzzing).
        let line = std::format!("$EFFFF*{:02X}", checksum(b"EFFFF"));
        assert!(matches!(
            Line::parse(line.as_bytes(), &o),
            Ok(Line::Tcm2(_))
        ));
        assert_eq!(Line::parse(b">", &o), Ok(Line::Prompt));
        assert!(matches!(
            Line::parse(b"H1V2M3.0", &o),
            Ok(Line::CalScore(_))
        ));
        assert_eq!(Line::parse(b"hello", &o), Err(WireError::UnknownLine));
        assert_eq!(Line::parse(b"\r\n", &o), Err(WireError::Empty));
        assert_eq!(
            Line::parse(b"$HCHDM,1\x01,M*00", &o),
            Err(WireError::BadByte(1))
        );
    }

    #[test]
    fn checksum_vectors_of_the_spec() {
        assert_eq!(checksum(b"HCHDM,238.5,M"), 0x25);
        assert_eq!(checksum(b"HCHDT,238.5,T"), 0x25);
        assert_eq!(checksum(b"HCHDG,238.5,0.0,E,12.3,W"), 0x6C);
        assert_eq!(checksum(b"HCHDG,238.5,,,,"), 0x4E);
    }
}

//! PNI TCM2 standard output (spec §7a, "PNI TCM2 / 2.5 / 2.6").
//!
//! `$C<hdg>P<pitch>R<roll>X<Bx>Y<By>Z<Bz>T<temp>E<err>*cs` CR LF, for example
//! `$C328.3P28.4R-12.4X55.11Y12.33Z-18.43T22.3E001`. Disabled fields are left out; the ones
//! present come in this order. The checksum is the NMEA one. The reply to `c?` has the same
//! grammar (`$Cnnn.n[Ennn]*cs`).
//!
//! The error field is read as hexadecimal (a bit field; the spec's example `E001` does not say
//! which bit means what, so this crate reports the code and does not interpret it). It is
//! written with three digits.
//!
//! The calibration score `HnVnMn.n` (H and V 0–9, higher better; M distortion, lower better)
//! is [`CalScore`].

use super::{AsciiWriter, Decimal, ParseOptions, WireError, Writer, hex_val, split_checked};

/// One TCM2 standard output line. Every field is optional.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Tcm2Data {
    /// `C`: compass heading, degrees (clockwise from magnetic north).
    pub heading: Option<Decimal>,
    /// `P`: pitch, degrees.
    pub pitch: Option<Decimal>,
    /// `R`: roll, degrees.
    pub roll: Option<Decimal>,
    /// `X`: magnetic field along x (device units, µT by default).
    pub bx: Option<Decimal>,
    /// `Y`: magnetic field along y.
    pub by: Option<Decimal>,
    /// `Z`: magnetic field along z.
    pub bz: Option<Decimal>,
    /// `T`: temperature, °C.
    pub temperature: Option<Decimal>,
    /// `E`: error code (hex bit field; 0 = no error).
    pub error: Option<u16>,
}

/// Field letters in the order the device sends them.
const ORDER: [u8; 8] = *b"CPRXYZTE";

impl Tcm2Data {
    fn slot(&mut self, letter: u8) -> Option<&mut Option<Decimal>> {
        match letter {
            b'C' => Some(&mut self.heading),
            b'P' => Some(&mut self.pitch),
            b'R' => Some(&mut self.roll),
            b'X' => Some(&mut self.bx),
            b'Y' => Some(&mut self.by),
            b'Z' => Some(&mut self.bz),
            b'T' => Some(&mut self.temperature),
            _ => None,
        }
    }

    fn get(&self, letter: u8) -> Option<Decimal> {
        match letter {
            b'C' => self.heading,
            b'P' => self.pitch,
            b'R' => self.roll,
            b'X' => self.bx,
            b'Y' => self.by,
            b'Z' => self.bz,
            b'T' => self.temperature,
            _ => None,
        }
    }

    /// Parse `$C…*cs` (CR LF optional).
    ///
    /// # Errors
    /// [`WireError`]: checksum, [`WireError::BadTcm2Field`] for an unknown, repeated or
    /// out-of-order letter, [`WireError::BadNumber`] for a malformed value,
    /// [`WireError::Empty`] for `$*cs` with no field.
    pub fn parse(line: &[u8], opts: &ParseOptions) -> Result<Self, WireError> {
        let body = split_checked(super::trim_eol(line), opts)?;
        let mut out = Self::default();
        let mut rest = body;
        let mut next_allowed = 0usize; // index into ORDER
        if rest.is_empty() {
            return Err(WireError::Empty);
        }
        while let Some((&letter, tail)) = rest.split_first() {
            let pos = ORDER
                .iter()
                .position(|c| *c == letter)
                .ok_or(WireError::BadTcm2Field(letter))?;
            if pos < next_allowed {
                return Err(WireError::BadTcm2Field(letter));
            }
            next_allowed = pos.saturating_add(1);
            if letter == b'E' {
                // Hex digits run to the end of the body; E is the last field.
                if tail.is_empty() || tail.len() > 4 {
                    return Err(WireError::BadNumber);
                }
                let mut code: u16 = 0;
                for c in tail {
                    let v = hex_val(*c).ok_or(WireError::BadNumber)?;
                    code = (code << 4) | u16::from(v);
                }
                out.error = Some(code);
                rest = &[];
            } else {
                let len = tail
                    .iter()
                    .position(|c| !matches!(c, b'0'..=b'9' | b'-' | b'+' | b'.'))
                    .unwrap_or(tail.len());
                let (num, after) = tail.split_at(len);
                let value = Decimal::parse(num)?;
                if let Some(slot) = out.slot(letter) {
                    *slot = Some(value);
                }
                rest = after;
            }
        }
        Ok(out)
    }

    /// Write `$…*cs` CR LF with the fields that are present.
    ///
    /// # Errors
    /// [`WireError::BufferTooSmall`]; [`WireError::Empty`] if no field is present (the device
    /// never sends that).
    pub fn emit(&self, buf: &mut [u8]) -> Result<usize, WireError> {
        if *self == Self::default() {
            return Err(WireError::Empty);
        }
        let mut w = Writer::new(buf);
        w.u8(b'$')?;
        for letter in ORDER {
            if let Some(v) = self.get(letter) {
                w.u8(letter)?;
                v.write(&mut w)?;
            }
        }
        if let Some(code) = self.error {
            w.u8(b'E')?;
            w.hex(code, 3)?;
        }
        w.nmea_tail()
    }
}

/// A TCM2 user-calibration score `HnVnMn.n`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct CalScore {
    /// Horizontal score, 0–9, higher is better.
    pub h: u8,
    /// Vertical score, 0–9, higher is better.
    pub v: u8,
    /// Magnetic distortion, lower is better.
    pub m: Decimal,
}

impl CalScore {
    /// Parse `HnVnMn.n` (CR LF optional).
    ///
    /// # Errors
    /// [`WireError::UnknownLine`] if the shape is not that; [`WireError::BadNumber`] for a bad
    /// distortion figure.
    pub fn parse(line: &[u8]) -> Result<Self, WireError> {
        match super::trim_eol(line) {
            [b'H', h @ b'0'..=b'9', b'V', v @ b'0'..=b'9', b'M', m @ ..] => Ok(Self {
                h: h - b'0',
                v: v - b'0',
                m: Decimal::parse(m)?,
            }),
            _ => Err(WireError::UnknownLine),
        }
    }

    /// Write `HnVnMn.n` CR LF.
    ///
    /// # Errors
    /// [`WireError::OutOfRange`] for scores above 9; [`WireError::BufferTooSmall`].
    pub fn emit(&self, buf: &mut [u8]) -> Result<usize, WireError> {
        if self.h > 9 || self.v > 9 {
            return Err(WireError::OutOfRange);
        }
        let mut w = Writer::new(buf);
        w.u8(b'H')?;
        w.u8(b'0' + self.h)?;
        w.u8(b'V')?;
        w.u8(b'0' + self.v)?;
        w.u8(b'M')?;
        self.m.write(&mut w)?;
        w.bytes(b"\r\n")?;
        Ok(w.pos())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn d(s: &str) -> Decimal {
        Decimal::parse(s.as_bytes()).unwrap()
    }

    const LAX: ParseOptions = ParseOptions {
        allow_missing_checksum: true,
    };
    const STRICT: ParseOptions = ParseOptions {
        allow_missing_checksum: false,
    };

    fn full() -> Tcm2Data {
        Tcm2Data {
            heading: Some(d("328.3")),
            pitch: Some(d("28.4")),
            roll: Some(d("-12.4")),
            bx: Some(d("55.11")),
            by: Some(d("12.33")),
            bz: Some(d("-18.43")),
            temperature: Some(d("22.3")),
            error: Some(1),
        }
    }

    #[test]
    fn spec_example_without_checksum() {
        let line = b"$C328.3P28.4R-12.4X55.11Y12.33Z-18.43T22.3E001";
        assert_eq!(Tcm2Data::parse(line, &LAX), Ok(full()));
        assert_eq!(
            Tcm2Data::parse(line, &STRICT),
            Err(WireError::MissingChecksum)
        );
    }

    #[test]
    fn spec_example_with_checksum_both_ways() {
        let body = b"C328.3P28.4R-12.4X55.11Y12.33Z-18.43T22.3E001";
        let sum = super::super::checksum(body);
        let mut line = std::vec![b'$'];
        line.extend_from_slice(body);
        line.extend_from_slice(std::format!("*{sum:02X}\r\n").as_bytes());
        assert_eq!(Tcm2Data::parse(&line, &STRICT), Ok(full()));
        let mut buf = [0u8; 96];
        let n = full().emit(&mut buf).unwrap();
        assert_eq!(&buf[..n], &line[..]);
    }

    #[test]
    fn optional_fields() {
        let d1 = Tcm2Data::parse(b"$C123.4E000", &LAX).unwrap();
        assert_eq!(d1.heading, Some(d("123.4")));
        assert_eq!(d1.error, Some(0));
        assert_eq!(d1.pitch, None);
        let d2 = Tcm2Data::parse(b"$P1.5R-2.0T20.0", &LAX).unwrap();
        assert_eq!(d2.heading, None);
        assert_eq!(d2.roll, Some(d("-2.0")));
        assert_eq!(d2.error, None);
        // The `c?` reply.
        let d3 = Tcm2Data::parse(b"$C005.0", &LAX).unwrap();
        assert_eq!(d3.heading, Some(d("005.0")));
    }

    #[test]
    fn bad_lines() {
        assert_eq!(
            Tcm2Data::parse(b"$C1.0C2.0", &LAX),
            Err(WireError::BadTcm2Field(b'C'))
        );
        assert_eq!(
            Tcm2Data::parse(b"$P1.0C2.0", &LAX),
            Err(WireError::BadTcm2Field(b'C'))
        );
        assert_eq!(
            Tcm2Data::parse(b"$Q1.0", &LAX),
            Err(WireError::BadTcm2Field(b'Q'))
        );
        assert_eq!(Tcm2Data::parse(b"$C", &LAX), Err(WireError::BadNumber));
        assert_eq!(Tcm2Data::parse(b"$C1E", &LAX), Err(WireError::BadNumber));
        assert_eq!(Tcm2Data::parse(b"$C1E0G1", &LAX), Err(WireError::BadNumber));
        assert_eq!(Tcm2Data::parse(b"$", &LAX), Err(WireError::Empty));
        assert_eq!(
            Tcm2Data::default().emit(&mut [0u8; 64]),
            Err(WireError::Empty)
        );
    }

    #[test]
    fn cal_score() {
        let s = CalScore::parse(b"H9V8M0.5\r\n").unwrap();
        assert_eq!((s.h, s.v, s.m), (9, 8, d("0.5")));
        let mut buf = [0u8; 16];
        let n = s.emit(&mut buf).unwrap();
        assert_eq!(&buf[..n], b"H9V8M0.5\r\n");
        assert_eq!(CalScore::parse(b"H9V8"), Err(WireError::UnknownLine));
        assert_eq!(CalScore::parse(b"H9V8Mx"), Err(WireError::BadNumber));
    }
}

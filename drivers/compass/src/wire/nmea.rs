//! NMEA 0183 heading sentences (spec §7a, "NMEA 0183 heading sentences").
//!
//! | Sentence | Fields |
//! |---|---|
//! | `$--HDG,h.h,d.d,E\|W,v.v,E\|W*hh` | sensor heading, deviation, variation |
//! | `$--HDM,h.h,M*hh` | heading, magnetic |
//! | `$--HDT,h.h,T*hh` | heading, true |
//!
//! Any two-character talker id is accepted (`HC` = magnetic compass). Every field may be
//! empty; empty fields *after* the last one are tolerated, because the KVH TracVision manual
//! prints a stray comma before `*`. The checksum is required unless
//! [`ParseOptions::allow_missing_checksum`] is set.

use super::{AsciiWriter, Decimal, ParseOptions, WireError, Writer, split_checked};

/// The two-letter talker id (`HC` for a magnetic compass, `HE` gyro, `II` integrated…);
/// upper-case letters only, which is also what tells an NMEA line from a TCM2 one.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Talker(pub [u8; 2]);

impl Talker {
    /// `HC`, heading from a magnetic compass.
    pub const MAGNETIC_COMPASS: Self = Self(*b"HC");
}

/// East or west: the sign of a deviation or variation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum EastWest {
    /// East, positive.
    East,
    /// West, negative.
    West,
}

/// A deviation or variation: a magnitude in degrees and a direction.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Offset {
    /// Magnitude, degrees (as written; normally non-negative).
    pub degrees: Decimal,
    /// East (positive) or west (negative).
    pub dir: EastWest,
}

impl Offset {
    /// Signed value in degrees, east positive.
    #[must_use]
    pub fn signed_deg(&self) -> f64 {
        match self.dir {
            EastWest::East => self.degrees.to_f64(),
            EastWest::West => -self.degrees.to_f64(),
        }
    }
}

/// `HDG`: heading, deviation and variation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Hdg {
    /// Magnetic sensor heading, degrees.
    pub heading: Option<Decimal>,
    /// Magnetic deviation.
    pub deviation: Option<Offset>,
    /// Magnetic variation.
    pub variation: Option<Offset>,
}

/// `HDM`: heading relative to magnetic north.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Hdm {
    /// Heading, degrees.
    pub heading: Option<Decimal>,
}

/// `HDT`: heading relative to true north.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Hdt {
    /// Heading, degrees.
    pub heading: Option<Decimal>,
}

/// The sentences this crate knows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum NmeaBody {
    /// `HDG`.
    Hdg(Hdg),
    /// `HDM`.
    Hdm(Hdm),
    /// `HDT`.
    Hdt(Hdt),
}

/// One NMEA heading sentence.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct NmeaSentence {
    /// Who sent it.
    pub talker: Talker,
    /// What it says.
    pub body: NmeaBody,
}

/// `rest` (after `$`) starts with a 5-letter address followed by `,`. The comma matters: a
/// TCM2 line has none, and one carrying only an error code (`$EFFFF*45`) is five upper-case
/// letters too.
pub(crate) fn looks_like_nmea(rest: &[u8]) -> bool {
    matches!(rest, [a, b, c, d, e, b',', ..] if [a, b, c, d, e].iter().all(|x| x.is_ascii_uppercase()))
}

fn opt_decimal(field: &[u8], n: u8) -> Result<Option<Decimal>, WireError> {
    if field.is_empty() {
        Ok(None)
    } else {
        Decimal::parse(field)
            .map(Some)
            .map_err(|_| WireError::BadField(n))
    }
}

fn opt_offset(value: &[u8], dir: &[u8], n: u8) -> Result<Option<Offset>, WireError> {
    let degrees = opt_decimal(value, n)?;
    let dir = match dir {
        b"" => None,
        b"E" => Some(EastWest::East),
        b"W" => Some(EastWest::West),
        _ => return Err(WireError::BadField(n.saturating_add(1))),
    };
    match (degrees, dir) {
        (Some(degrees), Some(dir)) => Ok(Some(Offset { degrees, dir })),
        (None, _) => Ok(None),
        // A magnitude without a direction has no sign: refuse rather than guess.
        (Some(_), None) => Err(WireError::MissingField(n.saturating_add(1))),
    }
}

fn indicator(field: &[u8], want: u8, n: u8) -> Result<(), WireError> {
    match field {
        [] => Ok(()),
        [c] if *c == want => Ok(()),
        _ => Err(WireError::BadField(n)),
    }
}

impl NmeaSentence {
    /// Parse `$ttSSS,…*hh` (CR LF optional).
    ///
    /// # Errors
    /// [`WireError`] naming the first problem.
    pub fn parse(line: &[u8], opts: &ParseOptions) -> Result<Self, WireError> {
        let body = split_checked(super::trim_eol(line), opts)?;
        let mut fields = body.split(|b| *b == b',');
        let addr = fields.next().unwrap_or(&[]);
        let (talker, kind) = match addr {
            [t0, t1, k0, k1, k2] => (Talker([*t0, *t1]), [*k0, *k1, *k2]),
            _ => return Err(WireError::BadAddress),
        };
        if !addr.iter().all(u8::is_ascii_uppercase) {
            return Err(WireError::BadAddress);
        }
        // Collect up to 5 fields; anything beyond must be empty.
        let mut f: [&[u8]; 5] = [&[]; 5];
        let mut count: u8 = 0;
        for (i, field) in fields.enumerate() {
            let n = u8::try_from(i.saturating_add(1)).unwrap_or(u8::MAX);
            match f.get_mut(i) {
                Some(slot) => *slot = field,
                None if field.is_empty() => {}
                None => return Err(WireError::ExtraField(n)),
            }
            count = n;
        }
        let [f1, f2, f3, f4, f5] = f;
        let body = match &kind {
            b"HDG" => NmeaBody::Hdg(Hdg {
                heading: opt_decimal(f1, 1)?,
                deviation: opt_offset(f2, f3, 2)?,
                variation: opt_offset(f4, f5, 4)?,
            }),
            b"HDM" | b"HDT" => {
                // Fields 3.. must be empty (stray trailing commas are fine).
                if let Some(n) = [f3, f4, f5].iter().position(|x| !x.is_empty()) {
                    return Err(WireError::ExtraField(
                        u8::try_from(n).unwrap_or(0).saturating_add(3),
                    ));
                }
                if count == 0 {
                    return Err(WireError::MissingField(1));
                }
                let heading = opt_decimal(f1, 1)?;
                if kind == *b"HDM" {
                    indicator(f2, b'M', 2)?;
                    NmeaBody::Hdm(Hdm { heading })
                } else {
                    indicator(f2, b'T', 2)?;
                    NmeaBody::Hdt(Hdt { heading })
                }
            }
            _ => return Err(WireError::UnknownSentence(kind)),
        };
        if count == 0 {
            return Err(WireError::MissingField(1));
        }
        Ok(Self { talker, body })
    }

    /// Write `$ttSSS,…*hh` CR LF.
    ///
    /// # Errors
    /// [`WireError::BufferTooSmall`]; [`WireError::BadAddress`] for a talker that is not
    /// two upper-case letters.
    pub fn emit(&self, buf: &mut [u8]) -> Result<usize, WireError> {
        if !self.talker.0.iter().all(u8::is_ascii_uppercase) {
            return Err(WireError::BadAddress);
        }
        let mut w = Writer::new(buf);
        w.u8(b'$')?;
        w.bytes(&self.talker.0)?;
        let opt = |w: &mut Writer<'_>, d: Option<Decimal>| match d {
            Some(d) => d.write(w),
            None => Ok(()),
        };
        match &self.body {
            NmeaBody::Hdg(h) => {
                w.bytes(b"HDG,")?;
                opt(&mut w, h.heading)?;
                for off in [h.deviation, h.variation] {
                    w.u8(b',')?;
                    if let Some(o) = off {
                        o.degrees.write(&mut w)?;
                        w.u8(b',')?;
                        w.u8(match o.dir {
                            EastWest::East => b'E',
                            EastWest::West => b'W',
                        })?;
                    } else {
                        w.u8(b',')?;
                    }
                }
            }
            NmeaBody::Hdm(h) => {
                w.bytes(b"HDM,")?;
                opt(&mut w, h.heading)?;
                w.bytes(b",M")?;
            }
            NmeaBody::Hdt(h) => {
                w.bytes(b"HDT,")?;
                opt(&mut w, h.heading)?;
                w.bytes(b",T")?;
            }
        }
        w.nmea_tail()
    }

    /// The heading in degrees, if the sentence carries one.
    #[must_use]
    pub fn heading_deg(&self) -> Option<f64> {
        match &self.body {
            NmeaBody::Hdg(h) => h.heading,
            NmeaBody::Hdm(h) => h.heading,
            NmeaBody::Hdt(h) => h.heading,
        }
        .map(Decimal::to_f64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn d(s: &str) -> Decimal {
        Decimal::parse(s.as_bytes()).unwrap()
    }

    fn emit(s: &NmeaSentence) -> std::vec::Vec<u8> {
        let mut buf = [0u8; 96];
        let n = s.emit(&mut buf).unwrap();
        buf[..n].to_vec()
    }

    const STRICT: ParseOptions = ParseOptions {
        allow_missing_checksum: false,
    };

    /// The four vectors of spec §7a, both ways, byte-exact.
    #[test]
    fn spec_vectors_both_ways() {
        let cases: [(&[u8], NmeaSentence); 4] = [
            (
                b"$HCHDM,238.5,M*25\r\n",
                NmeaSentence {
                    talker: Talker::MAGNETIC_COMPASS,
                    body: NmeaBody::Hdm(Hdm {
                        heading: Some(d("238.5")),
                    }),
                },
            ),
            (
                b"$HCHDT,238.5,T*25\r\n",
                NmeaSentence {
                    talker: Talker::MAGNETIC_COMPASS,
                    body: NmeaBody::Hdt(Hdt {
                        heading: Some(d("238.5")),
                    }),
                },
            ),
            (
                b"$HCHDG,238.5,0.0,E,12.3,W*6C\r\n",
                NmeaSentence {
                    talker: Talker::MAGNETIC_COMPASS,
                    body: NmeaBody::Hdg(Hdg {
                        heading: Some(d("238.5")),
                        deviation: Some(Offset {
                            degrees: d("0.0"),
                            dir: EastWest::East,
                        }),
                        variation: Some(Offset {
                            degrees: d("12.3"),
                            dir: EastWest::West,
                        }),
                    }),
                },
            ),
            (
                b"$HCHDG,238.5,,,,*4E\r\n",
                NmeaSentence {
                    talker: Talker::MAGNETIC_COMPASS,
                    body: NmeaBody::Hdg(Hdg {
                        heading: Some(d("238.5")),
                        deviation: None,
                        variation: None,
                    }),
                },
            ),
        ];
        for (bytes, msg) in cases {
            assert_eq!(NmeaSentence::parse(bytes, &STRICT), Ok(msg));
            assert_eq!(emit(&msg), bytes);
        }
    }

    #[test]
    fn hdg_signs_and_offsets() {
        let s = NmeaSentence::parse(b"$HCHDG,238.5,0.0,E,12.3,W*6C", &STRICT).unwrap();
        let NmeaBody::Hdg(h) = s.body else { panic!() };
        assert!((h.variation.unwrap().signed_deg() + 12.3).abs() < 1e-12);
        assert_eq!(s.heading_deg(), Some(238.5));
    }

    #[test]
    fn any_talker_and_stray_trailing_comma() {
        let body = b"IIHDT,12.0,T,";
        let line = with_sum(body);
        let s = NmeaSentence::parse(&line, &STRICT).unwrap();
        assert_eq!(s.talker, Talker(*b"II"));
        assert_eq!(s.heading_deg(), Some(12.0));
    }

    #[test]
    fn empty_fields_allowed() {
        let s = NmeaSentence::parse(&with_sum(b"HCHDM,,"), &STRICT).unwrap();
        assert_eq!(s.heading_deg(), None);
        let s = NmeaSentence::parse(&with_sum(b"HCHDG,,,,,"), &STRICT).unwrap();
        assert_eq!(s.heading_deg(), None);
    }

    fn with_sum(body: &[u8]) -> std::vec::Vec<u8> {
        let mut v = std::vec![b'$'];
        v.extend_from_slice(body);
        v.extend_from_slice(std::format!("*{:02X}", super::super::checksum(body)).as_bytes());
        v
    }

    #[test]
    fn errors_are_typed() {
        assert_eq!(
            NmeaSentence::parse(b"$HCHDM,238.5,M*26", &STRICT),
            Err(WireError::BadChecksum {
                expected: 0x25,
                got: 0x26
            })
        );
        assert_eq!(
            NmeaSentence::parse(b"$HCHDM,238.5,M", &STRICT),
            Err(WireError::MissingChecksum)
        );
        assert!(
            NmeaSentence::parse(
                b"$HCHDM,238.5,M",
                &ParseOptions {
                    allow_missing_checksum: true
                }
            )
            .is_ok()
        );
        assert_eq!(
            NmeaSentence::parse(b"$HCHDM,238.5,M*2G", &STRICT),
            Err(WireError::BadChecksumDigits)
        );
        assert_eq!(
            NmeaSentence::parse(&with_sum(b"GPGGA,1,2"), &STRICT),
            Err(WireError::UnknownSentence(*b"GGA"))
        );
        assert_eq!(
            NmeaSentence::parse(&with_sum(b"HCHDM,abc,M"), &STRICT),
            Err(WireError::BadField(1))
        );
        assert_eq!(
            NmeaSentence::parse(&with_sum(b"HCHDM,1.0,T"), &STRICT),
            Err(WireError::BadField(2))
        );
        assert_eq!(
            NmeaSentence::parse(&with_sum(b"HCHDM,1.0,M,7"), &STRICT),
            Err(WireError::ExtraField(3))
        );
        assert_eq!(
            NmeaSentence::parse(&with_sum(b"HCHDG,1,2,,,"), &STRICT),
            Err(WireError::MissingField(3))
        );
        assert_eq!(
            NmeaSentence::parse(&with_sum(b"HCHDG,1,2,E,3,W,9"), &STRICT),
            Err(WireError::ExtraField(6))
        );
        assert_eq!(
            NmeaSentence::parse(&with_sum(b"HCHD,1,M"), &STRICT),
            Err(WireError::BadAddress)
        );
        assert_eq!(
            NmeaSentence::parse(&with_sum(b"HCHDM"), &STRICT),
            Err(WireError::MissingField(1))
        );
    }
}

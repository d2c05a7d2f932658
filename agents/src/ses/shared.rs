//! The **shared form** of SES contents: what one robot sends another.
//!
//! A compact, versioned, big-endian binary list of records, each (object description,
//! azimuth, elevation, optional range, time), headed by the sending robot's name. It is small
//! (≈ 11 bytes + the object name per record) and understandable by a robot of another make:
//! every field is in SI units after a fixed scaling written here.
//!
//! # Layout, version 1
//!
//! | bytes | field | meaning |
//! |---:|---|---|
//! | 2 | magic | `0x53 0x45` (`"SE"`) |
//! | 1 | version | `1` |
//! | 1 | `L` | length of the robot name, 1..=32 |
//! | L | robot | sending robot's name, UTF-8 |
//! | 8 | `sent_at` | send time, µs, on the **sender's** monotonic clock (u64) |
//! | 2 | `N` | record count, 0..=[`MAX_RECORDS`] (u16) |
//! | … | records | `N` records, below |
//! | 2 | CRC | CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF) of every byte before it |
//!
//! Record:
//!
//! | bytes | field | meaning |
//! |---:|---|---|
//! | 1 | flags | bit 0: a range follows; bits 1–7 reserved, must be 0 |
//! | 4 | age | µs between the sensing time and `sent_at` (u32, so at most ~71 min) |
//! | 2 | azimuth | `k · 2π / 65536` rad, counter-clockwise from the sender's forward axis (u16) |
//! | 2 | elevation | `k · (π/2) / 16384` rad, `k ∈ [−16384, 16384]` (i16) |
//! | 1 | confidence | `k / 255` |
//! | 2 | range | only if flag bit 0: `k / 100` m, i.e. centimetres, up to 655.35 m (u16) |
//! | 1 | `M` | length of the object description, 1..=[`MAX_OBJECT_LEN`] |
//! | M | object | object description, UTF-8 |
//!
//! Times travel as *ages* relative to `sent_at` so the receiver can place them on its own
//! clock (`local = now_at_receipt − (sent_at − time)`; transit time is ignored) — the two
//! robots' monotonic clocks share no epoch. Resolution: azimuth 0.0055°, elevation 0.0055°,
//! range 1 cm, time 1 µs; encoding quantises, and decode∘encode is the identity on decoded
//! values. The parser never panics and rejects bad input with a [`DecodeError`]; the fuzz
//! target `ses_shared_form` exercises it. A receiver must reject any version it does not
//! know: a future version may change anything after the version byte.

use core::f64::consts::{FRAC_PI_2, PI};

use ima_hal::Instant;
use ima_hal::bytes::Reader;

use super::{Direction, Entry, Payload, Ses};

/// Magic bytes at the start of every shared form.
pub const MAGIC: [u8; 2] = *b"SE";
/// The version this module writes and reads.
pub const VERSION: u8 = 1;
/// Longest robot name, bytes.
pub const MAX_NAME_LEN: usize = 32;
/// Longest object description, bytes.
pub const MAX_OBJECT_LEN: usize = 64;
/// Most records in one message.
pub const MAX_RECORDS: usize = 1024;

const FLAG_RANGE: u8 = 0x01;
const AZ_STEP: f64 = 2.0 * PI / 65536.0;
const EL_STEP: f64 = FRAC_PI_2 / 16384.0;

/// One shared observation.
#[derive(Debug, Clone, PartialEq)]
pub struct SharedRecord {
    /// Object description (colour name, robot name…).
    pub object: String,
    /// Bearing in the sender's robot frame.
    pub bearing: Direction,
    /// Range in metres, if known.
    pub range_m: Option<f64>,
    /// Confidence in [0, 1].
    pub confidence: f64,
    /// Sensing time on the sender's clock.
    pub time: Instant,
}

/// A decoded (or to-be-encoded) shared form.
#[derive(Debug, Clone, PartialEq)]
pub struct SharedForm {
    /// Name of the sending robot.
    pub source_robot: String,
    /// Send time on the sender's clock.
    pub sent_at: Instant,
    /// The observations.
    pub records: Vec<SharedRecord>,
}

/// Why bytes are not a valid shared form.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DecodeError {
    /// The input ended before the structure did.
    Truncated,
    /// The first two bytes are not [`MAGIC`].
    BadMagic([u8; 2]),
    /// A version this parser does not know.
    UnsupportedVersion(u8),
    /// Robot name length 0 or above [`MAX_NAME_LEN`].
    BadNameLength(u8),
    /// Record count above [`MAX_RECORDS`].
    TooManyRecords(u16),
    /// Reserved flag bits set in a record.
    ReservedFlags(u8),
    /// Elevation code outside ±16384.
    BadElevation(i16),
    /// Object length 0 or above [`MAX_OBJECT_LEN`].
    BadObjectLength(u8),
    /// A name or object is not UTF-8.
    BadUtf8,
    /// A record's age reaches back before the sender's epoch.
    AgeBeforeEpoch,
    /// Bytes left over after the checksum.
    TrailingBytes(usize),
    /// The CRC does not match.
    BadChecksum {
        /// CRC computed over the received bytes.
        expected: u16,
        /// CRC carried by the message.
        got: u16,
    },
}

impl core::fmt::Display for DecodeError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Truncated => f.write_str("truncated shared form"),
            Self::BadMagic(m) => write!(f, "bad magic {m:02x?}"),
            Self::UnsupportedVersion(v) => write!(f, "unsupported shared-form version {v}"),
            Self::BadNameLength(n) => write!(f, "bad robot-name length {n}"),
            Self::TooManyRecords(n) => write!(f, "{n} records exceed the limit {MAX_RECORDS}"),
            Self::ReservedFlags(x) => write!(f, "reserved flag bits set: {x:#04x}"),
            Self::BadElevation(k) => write!(f, "elevation code {k} outside ±16384"),
            Self::BadObjectLength(n) => write!(f, "bad object length {n}"),
            Self::BadUtf8 => f.write_str("name or object is not UTF-8"),
            Self::AgeBeforeEpoch => f.write_str("record age reaches before the sender's epoch"),
            Self::TrailingBytes(n) => write!(f, "{n} trailing bytes"),
            Self::BadChecksum { expected, got } => {
                write!(f, "bad CRC: computed {expected:#06x}, carried {got:#06x}")
            }
        }
    }
}

impl std::error::Error for DecodeError {}

/// Why a shared form cannot be encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EncodeError {
    /// Robot name empty or longer than [`MAX_NAME_LEN`] bytes.
    BadNameLength(usize),
    /// More than [`MAX_RECORDS`] records.
    TooManyRecords(usize),
    /// Record `index` has an empty or too long object description.
    BadObjectLength {
        /// Record index.
        index: usize,
    },
    /// Record `index` is later than `sent_at` or more than `u32::MAX` µs older.
    AgeOutOfRange {
        /// Record index.
        index: usize,
    },
    /// Record `index` has a non-finite bearing or a range outside 0..=655.35 m.
    BadGeometry {
        /// Record index.
        index: usize,
    },
    /// Record `index` has a confidence outside [0, 1].
    BadConfidence {
        /// Record index.
        index: usize,
    },
}

impl core::fmt::Display for EncodeError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::BadNameLength(n) => write!(f, "robot name of {n} bytes (1..={MAX_NAME_LEN})"),
            Self::TooManyRecords(n) => write!(f, "{n} records (at most {MAX_RECORDS})"),
            Self::BadObjectLength { index } => write!(f, "record {index}: bad object length"),
            Self::AgeOutOfRange { index } => write!(f, "record {index}: age out of range"),
            Self::BadGeometry { index } => write!(f, "record {index}: bad bearing or range"),
            Self::BadConfidence { index } => write!(f, "record {index}: bad confidence"),
        }
    }
}

impl std::error::Error for EncodeError {}

/// CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no xor-out).
#[must_use]
pub fn crc16(data: &[u8]) -> u16 {
    let mut crc: u16 = 0xFFFF;
    for &b in data {
        crc ^= u16::from(b) << 8;
        for _ in 0..8 {
            crc = if crc & 0x8000 != 0 {
                (crc << 1) ^ 0x1021
            } else {
                crc << 1
            };
        }
    }
    crc
}

ima_hal::cursor_errors!(DecodeError {
    truncated: |_| DecodeError::Truncated
});

/// A UTF-8 string of `n` bytes.
fn read_str(r: &mut Reader<'_>, n: usize) -> Result<String, DecodeError> {
    core::str::from_utf8(r.take(n)?)
        .map(str::to_owned)
        .map_err(|_| DecodeError::BadUtf8)
}

impl SharedForm {
    /// Parse a shared form. Never panics; any defect gives a typed [`DecodeError`].
    ///
    /// # Errors
    /// See [`DecodeError`].
    pub fn decode(bytes: &[u8]) -> Result<Self, DecodeError> {
        let body_len = bytes.len().checked_sub(2).ok_or(DecodeError::Truncated)?;
        let (body, crc_bytes) = bytes.split_at(body_len);
        let mut r = Reader::new(body);
        let magic = r.array::<2>()?;
        if magic != MAGIC {
            return Err(DecodeError::BadMagic(magic));
        }
        let version = r.u8()?;
        if version != VERSION {
            return Err(DecodeError::UnsupportedVersion(version));
        }
        let name_len = r.u8()?;
        if name_len == 0 || usize::from(name_len) > MAX_NAME_LEN {
            return Err(DecodeError::BadNameLength(name_len));
        }
        let source_robot = read_str(&mut r, usize::from(name_len))?;
        let sent_at = Instant::from_micros(r.be()?);
        let count: u16 = r.be()?;
        if usize::from(count) > MAX_RECORDS {
            return Err(DecodeError::TooManyRecords(count));
        }
        let mut records = Vec::with_capacity(usize::from(count).min(body.len() / 11));
        for _ in 0..count {
            let flags = r.u8()?;
            if flags & !FLAG_RANGE != 0 {
                return Err(DecodeError::ReservedFlags(flags));
            }
            let age = u64::from(r.be::<u32>()?);
            let az: u16 = r.be()?;
            let el: i16 = r.be()?;
            if !(-16384..=16384).contains(&el) {
                return Err(DecodeError::BadElevation(el));
            }
            let conf = r.u8()?;
            let range_m = if flags & FLAG_RANGE != 0 {
                Some(f64::from(r.be::<u16>()?) / 100.0)
            } else {
                None
            };
            let obj_len = r.u8()?;
            if obj_len == 0 || usize::from(obj_len) > MAX_OBJECT_LEN {
                return Err(DecodeError::BadObjectLength(obj_len));
            }
            let object = read_str(&mut r, usize::from(obj_len))?;
            let time = sent_at
                .as_micros()
                .checked_sub(age)
                .map(Instant::from_micros)
                .ok_or(DecodeError::AgeBeforeEpoch)?;
            records.push(SharedRecord {
                object,
                bearing: Direction::new(f64::from(az) * AZ_STEP, f64::from(el) * EL_STEP),
                range_m,
                confidence: f64::from(conf) / 255.0,
                time,
            });
        }
        if !r.is_empty() {
            return Err(DecodeError::TrailingBytes(r.remaining()));
        }
        let got = match crc_bytes {
            [a, b] => u16::from_be_bytes([*a, *b]),
            _ => return Err(DecodeError::Truncated),
        };
        let expected = crc16(body);
        // Fuzz builds skip the check so the fuzzer explores the structure behind it.
        if expected != got && !cfg!(fuzzing) {
            return Err(DecodeError::BadChecksum { expected, got });
        }
        Ok(Self {
            source_robot,
            sent_at,
            records,
        })
    }

    /// Append the encoding to `out`; returns the number of bytes written. On error nothing
    /// is appended.
    ///
    /// # Errors
    /// See [`EncodeError`].
    pub fn encode(&self, out: &mut Vec<u8>) -> Result<usize, EncodeError> {
        let name = self.source_robot.as_bytes();
        if name.is_empty() || name.len() > MAX_NAME_LEN {
            return Err(EncodeError::BadNameLength(name.len()));
        }
        let count = u16::try_from(self.records.len())
            .ok()
            .filter(|&n| usize::from(n) <= MAX_RECORDS)
            .ok_or(EncodeError::TooManyRecords(self.records.len()))?;
        let mut buf = Vec::with_capacity(self.encoded_len());
        buf.extend_from_slice(&MAGIC);
        buf.push(VERSION);
        buf.push(name.len() as u8);
        buf.extend_from_slice(name);
        buf.extend_from_slice(&self.sent_at.as_micros().to_be_bytes());
        buf.extend_from_slice(&count.to_be_bytes());
        for (index, rec) in self.records.iter().enumerate() {
            let obj = rec.object.as_bytes();
            if obj.is_empty() || obj.len() > MAX_OBJECT_LEN {
                return Err(EncodeError::BadObjectLength { index });
            }
            let age = self
                .sent_at
                .as_micros()
                .checked_sub(rec.time.as_micros())
                .and_then(|a| u32::try_from(a).ok())
                .ok_or(EncodeError::AgeOutOfRange { index })?;
            let (az, el) = (rec.bearing.azimuth_rad, rec.bearing.elevation_rad);
            if !(az.is_finite() && el.is_finite() && (-FRAC_PI_2..=FRAC_PI_2).contains(&el)) {
                return Err(EncodeError::BadGeometry { index });
            }
            let range = match rec.range_m {
                Some(r) if r.is_finite() && (0.0..=655.35).contains(&r) => {
                    Some((r * 100.0).round().min(65535.0) as u16)
                }
                Some(_) => return Err(EncodeError::BadGeometry { index }),
                None => None,
            };
            if !(0.0..=1.0).contains(&rec.confidence) {
                return Err(EncodeError::BadConfidence { index });
            }
            let az_code =
                ((ima_hal::normalize_angle(az) / AZ_STEP).round() as i64).rem_euclid(65536) as u16;
            let el_code = ((el / EL_STEP).round() as i64).clamp(-16384, 16384) as i16;
            buf.push(if range.is_some() { FLAG_RANGE } else { 0 });
            buf.extend_from_slice(&age.to_be_bytes());
            buf.extend_from_slice(&az_code.to_be_bytes());
            buf.extend_from_slice(&el_code.to_be_bytes());
            buf.push((rec.confidence * 255.0).round() as u8);
            if let Some(k) = range {
                buf.extend_from_slice(&k.to_be_bytes());
            }
            buf.push(obj.len() as u8);
            buf.extend_from_slice(obj);
        }
        let crc = crc16(&buf);
        buf.extend_from_slice(&crc.to_be_bytes());
        out.extend_from_slice(&buf);
        Ok(buf.len())
    }

    /// The encoding as a new vector.
    ///
    /// # Errors
    /// See [`EncodeError`].
    pub fn to_bytes(&self) -> Result<Vec<u8>, EncodeError> {
        let mut v = Vec::new();
        self.encode(&mut v)?;
        Ok(v)
    }

    /// Size of the encoding in bytes (if it encodes).
    #[must_use]
    pub fn encoded_len(&self) -> usize {
        2 + 1
            + 1
            + self.source_robot.len()
            + 8
            + 2
            + self
                .records
                .iter()
                .map(|r| 11 + 2 * usize::from(r.range_m.is_some()) + r.object.len())
                .sum::<usize>()
            + 2
    }
}

impl Ses {
    /// The shared form of every entry accepted by `filter`: object, bearing, range and
    /// confidence of the payload, stamped `now` on this robot's clock. Entries later than
    /// `now` or older than ~71 minutes are left out (the form cannot carry them).
    pub fn export_shared(
        &self,
        robot: &str,
        now: Instant,
        mut filter: impl FnMut(&Entry) -> bool,
    ) -> SharedForm {
        let records = self
            .iter()
            .filter(|e| {
                e.time <= now
                    && now.saturating_duration_since(e.time).as_micros() <= u128::from(u32::MAX)
            })
            .filter(|e| filter(e))
            .take(MAX_RECORDS)
            .map(|e| SharedRecord {
                object: e.payload.object.clone(),
                bearing: e.payload.bearing,
                range_m: e.payload.range_m,
                confidence: e.payload.confidence,
                time: e.time,
            })
            .collect();
        SharedForm {
            source_robot: robot.to_owned(),
            sent_at: now,
            records,
        }
    }

    /// Post every record of a peer's form, received at `now` on this robot's clock: tag =
    /// object, source = `"peer:<robot>"`, time = `now − (sent_at − time)`. So a peer's newer
    /// report of an object replaces its older one. Bearings stay in the *sender's* frame:
    /// the caller transforms them first if the frames differ. Returns how many were posted.
    pub fn import_shared(&mut self, form: &SharedForm, now: Instant) -> usize {
        let source = format!("peer:{}", form.source_robot);
        let mut n = 0;
        for rec in &form.records {
            let age = form.sent_at.saturating_duration_since(rec.time);
            let payload = Payload {
                object: rec.object.clone(),
                bearing: rec.bearing,
                range_m: rec.range_m,
                confidence: rec.confidence,
            };
            if self.post(&rec.object, &source, now - age, payload).is_ok() {
                n += 1;
            }
        }
        n
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> SharedForm {
        SharedForm {
            source_robot: "skeeter".into(),
            sent_at: Instant::from_micros(10_000_000),
            records: vec![
                SharedRecord {
                    object: "red".into(),
                    bearing: Direction::new(0.5, 0.0),
                    range_m: Some(3.25),
                    confidence: 1.0,
                    time: Instant::from_micros(9_500_000),
                },
                SharedRecord {
                    object: "scooter".into(),
                    bearing: Direction::new(-2.0, -0.1),
                    range_m: None,
                    confidence: 0.5,
                    time: Instant::from_micros(10_000_000),
                },
            ],
        }
    }

    /// Golden vector: one record, every field worked out by hand from the layout table.
    #[test]
    fn golden_vector() {
        let form = SharedForm {
            source_robot: "sk".into(),
            sent_at: Instant::from_micros(0x0102),
            records: vec![SharedRecord {
                object: "red".into(),
                bearing: Direction::new(PI / 2.0, PI / 4.0),
                range_m: Some(2.5),
                confidence: 1.0,
                time: Instant::from_micros(0x0100),
            }],
        };
        let mut body = vec![0x53, 0x45, 0x01, 0x02, b's', b'k'];
        body.extend_from_slice(&[0, 0, 0, 0, 0, 0, 0x01, 0x02]); // sent_at
        body.extend_from_slice(&[0x00, 0x01]); // one record
        body.push(0x01); // range present
        body.extend_from_slice(&[0, 0, 0, 2]); // age 2 µs
        body.extend_from_slice(&[0x40, 0x00]); // azimuth 16384 = π/2
        body.extend_from_slice(&[0x20, 0x00]); // elevation 8192 = π/4
        body.push(0xFF); // confidence 1
        body.extend_from_slice(&[0x00, 0xFA]); // 250 cm
        body.extend_from_slice(&[3, b'r', b'e', b'd']);
        let crc = crc16(&body);
        body.extend_from_slice(&crc.to_be_bytes());
        assert_eq!(form.to_bytes().unwrap(), body);
        assert_eq!(SharedForm::decode(&body).unwrap(), form);
        assert_eq!(form.encoded_len(), body.len());
    }

    #[test]
    fn crc_check_value() {
        assert_eq!(crc16(b"123456789"), 0x29B1);
    }

    #[test]
    fn round_trip_is_exact_after_quantisation() {
        let bytes = sample().to_bytes().unwrap();
        let once = SharedForm::decode(&bytes).unwrap();
        assert_eq!(once.to_bytes().unwrap(), bytes);
        assert_eq!(SharedForm::decode(&once.to_bytes().unwrap()).unwrap(), once);
        let r = &once.records[0];
        assert!((r.bearing.azimuth_rad - 0.5).abs() <= AZ_STEP / 2.0);
        assert_eq!(r.range_m, Some(3.25));
        assert_eq!(r.time, Instant::from_micros(9_500_000));
    }

    #[test]
    fn every_defect_is_a_typed_error() {
        let good = sample().to_bytes().unwrap();
        assert_eq!(SharedForm::decode(&[]), Err(DecodeError::Truncated));
        for cut in 0..good.len() {
            assert!(SharedForm::decode(&good[..cut]).is_err(), "cut {cut}");
        }
        let mut b = good.clone();
        b[0] = b'X';
        assert_eq!(
            SharedForm::decode(&b),
            Err(DecodeError::BadMagic([b'X', b'E']))
        );
        let mut b = good.clone();
        b[2] = 2;
        assert_eq!(
            SharedForm::decode(&b),
            Err(DecodeError::UnsupportedVersion(2))
        );
        let mut b = good.clone();
        let n = b.len();
        b[n - 1] ^= 1;
        assert!(matches!(
            SharedForm::decode(&b),
            Err(DecodeError::BadChecksum { .. })
        ));
        let mut b = good.clone();
        b.insert(n - 2, 0);
        assert_eq!(SharedForm::decode(&b), Err(DecodeError::TrailingBytes(1)));
        // Reserved flag bit in the first record (offset 2+1+1+7+8+2 = 21).
        let mut b = good.clone();
        b[21] = 0x81;
        assert_eq!(
            SharedForm::decode(&b),
            Err(DecodeError::ReservedFlags(0x81))
        );
    }

    #[test]
    fn encode_refuses_what_it_cannot_carry() {
        let mut f = sample();
        f.records[0].time = Instant::from_micros(20_000_000);
        assert_eq!(f.to_bytes(), Err(EncodeError::AgeOutOfRange { index: 0 }));
        let mut f = sample();
        f.records[1].range_m = Some(1000.0);
        assert_eq!(f.to_bytes(), Err(EncodeError::BadGeometry { index: 1 }));
        let mut f = sample();
        f.source_robot = String::new();
        assert_eq!(f.to_bytes(), Err(EncodeError::BadNameLength(0)));
        let mut f = sample();
        f.records[0].object = "x".repeat(65);
        assert_eq!(f.to_bytes(), Err(EncodeError::BadObjectLength { index: 0 }));
    }

    #[test]
    fn export_then_import_moves_ages_to_the_receiver_clock() {
        let mut a = Ses::new(super::super::SesConfig::default()).unwrap();
        a.post(
            "red",
            "vision",
            Instant::from_millis(1_000),
            Payload {
                object: "red".into(),
                bearing: Direction::new(1.0, 0.0),
                range_m: Some(4.0),
                confidence: 0.8,
            },
        )
        .unwrap();
        let form = a.export_shared("skeeter", Instant::from_millis(1_500), |_| true);
        let wire = SharedForm::decode(&form.to_bytes().unwrap()).unwrap();
        let mut b = Ses::new(super::super::SesConfig::default()).unwrap();
        assert_eq!(b.import_shared(&wire, Instant::from_millis(90_000)), 1);
        let e = b.get("red", "peer:skeeter").unwrap();
        assert_eq!(e.time, Instant::from_millis(89_500));
        assert_eq!(e.payload.range_m, Some(4.0));
    }
}

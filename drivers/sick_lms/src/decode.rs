//! From B0 values to SI scans: variants, value masks, special codes and geometry (spec §3.3).

use core::f64::consts::PI;

use ima_hal::Isometry2;
use ima_hal::laser::{BeamFlags, LaserDescription, LaserScan};

use crate::machine::SessionInfo;
use crate::wire::{BaudRate, MeasuringMode, Scan, Units, Values};

/// A scan variant: field width and angular resolution (command `3B`, spec §3.6).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Variant {
    angle_deg: u16,
    res_centideg: u16,
}

impl Variant {
    /// 180° at 1° (181 values).
    pub const W180_R100: Self = Self {
        angle_deg: 180,
        res_centideg: 100,
    };
    /// 180° at 0.5° (361 values).
    pub const W180_R50: Self = Self {
        angle_deg: 180,
        res_centideg: 50,
    };
    /// 100° at 1° (101 values).
    pub const W100_R100: Self = Self {
        angle_deg: 100,
        res_centideg: 100,
    };
    /// 100° at 0.5° (201 values).
    pub const W100_R50: Self = Self {
        angle_deg: 100,
        res_centideg: 50,
    };
    /// 100° at 0.25° (401 values; 0.25° works only with 100°).
    pub const W100_R25: Self = Self {
        angle_deg: 100,
        res_centideg: 25,
    };

    /// The variant of `angle_deg` (100 or 180) and `res_centideg` (25, 50, 100), if the LMS
    /// supports it (0.25° only at 100°).
    #[must_use]
    pub const fn new(angle_deg: u16, res_centideg: u16) -> Option<Self> {
        match (angle_deg, res_centideg) {
            (180, 50 | 100) | (100, 25 | 50 | 100) => Some(Self {
                angle_deg,
                res_centideg,
            }),
            _ => None,
        }
    }

    /// The variant whose full scan has `count` values, if exactly one has.
    #[must_use]
    pub const fn from_count(count: u16) -> Option<Self> {
        match count {
            181 => Some(Self::W180_R100),
            361 => Some(Self::W180_R50),
            101 => Some(Self::W100_R100),
            201 => Some(Self::W100_R50),
            401 => Some(Self::W100_R25),
            _ => None,
        }
    }

    /// Field width, degrees.
    #[must_use]
    pub const fn angle_deg(self) -> u16 {
        self.angle_deg
    }

    /// Resolution, 1/100°.
    #[must_use]
    pub const fn res_centideg(self) -> u16 {
        self.res_centideg
    }

    /// Values in a full scan: width / resolution + 1.
    #[must_use]
    pub const fn values(self) -> u16 {
        self.angle_deg * 100 / self.res_centideg + 1
    }

    /// Angle of value 0 in the LMS convention (0° right, 90° ahead): `(180 − width) / 2`.
    #[must_use]
    pub const fn start_deg(self) -> u16 {
        (180 - self.angle_deg) / 2
    }

    /// Most complete scans per second: the mirror turns at 75 Hz and a scan needs 1, 2 or 4
    /// turns at 1°, 0.5°, 0.25° (spec §4).
    #[must_use]
    pub fn max_scan_rate_hz(self) -> f64 {
        75.0 * f64::from(self.res_centideg) / 100.0
    }

    /// Angle between neighbouring values, radians ([`resolution_rad`]).
    #[must_use]
    pub fn resolution_rad(self) -> f64 {
        resolution_rad(self.res_centideg)
    }
}

/// An angular resolution in 1/100° (variant commands and replies) as radians.
#[must_use]
pub fn resolution_rad(res_centideg: u16) -> f64 {
    f64::from(res_centideg) * PI / 18_000.0
}

/// Why a B0 could not become a [`LaserScan`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum DecodeError {
    /// The measuring mode is not in the spec's table; its value masks are unknown.
    UnknownMeasuringMode(u8),
    /// Mode `3F` reports reflectivity, not ranges.
    NotRanges,
    /// Units `11` are reserved.
    ReservedUnits,
    /// The value count fits no variant (or not the one given).
    UnexpectedCount(u16),
    /// More values than a [`LaserScan`] holds.
    TooManyValues,
}

impl core::fmt::Display for DecodeError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::UnknownMeasuringMode(m) => write!(f, "unknown measuring mode {m:#04x}"),
            Self::NotRanges => f.write_str("measuring mode reports reflectivity, not ranges"),
            Self::ReservedUnits => f.write_str("reserved units code"),
            Self::UnexpectedCount(n) => write!(f, "{n} values fit no known variant"),
            Self::TooManyValues => f.write_str("too many values"),
        }
    }
}

impl core::error::Error for DecodeError {}

/// One decoded value word.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Value {
    /// Distance in the scan's units (`value & mask`).
    pub distance: u16,
    /// Raw bits above the distance mask, shifted down to bit 0 (mode dependent; spec §3.3).
    pub raw_flags: u8,
    /// Device-independent flags for the special codes of 13-bit modes.
    pub flags: BeamFlags,
}

impl Value {
    /// Split `word` according to `mode`. `None` for modes whose masks are unknown.
    #[must_use]
    pub fn decode(word: u16, mode: MeasuringMode) -> Option<Self> {
        let mask = mode.distance_mask()?;
        let distance = word & mask;
        let shift = mask.trailing_ones();
        let raw_flags = u8::try_from(word.checked_shr(shift).unwrap_or(0)).unwrap_or(u8::MAX);
        let flags = if mode.has_special_values() {
            match distance {
                0x1FFF => BeamFlags::NO_RETURN,
                0x1FFE => BeamFlags::DAZZLED,
                0x1FFD => BeamFlags::OVERFLOW,
                0x1FFB => BeamFlags::LOW_SIGNAL,
                0x1FFA => BeamFlags::READ_ERROR,
                0x1FF7 => BeamFlags::ABOVE_MAX_RANGE,
                0x1FF8..=0x1FFF => BeamFlags::RESERVED,
                _ => BeamFlags::VALID,
            }
        } else {
            BeamFlags::VALID
        };
        Some(Self {
            distance,
            raw_flags,
            flags: flags.with_device_bits(raw_flags),
        })
    }
}

/// Convert degrees in the LMS convention (0° right, 90° ahead, counter-clockwise) to radians
/// in the sensor frame (0 ahead, counter-clockwise).
#[must_use]
pub fn lms_deg_to_sensor_rad(deg: f64) -> f64 {
    (deg - 90.0) * PI / 180.0
}

/// Fill `out` from a B0 scan.
///
/// `variant` gives the geometry; `None` infers it from the value count (181, 361, 101, 201,
/// 401). A partial scan (count-word bit 13) is offset by its index × 0.25°. Valid beams get
/// `distance × unit` metres; special codes of 13-bit modes get `NAN` and their
/// [`BeamFlags`]. The raw flag bits travel in [`BeamFlags::device_bits`].
///
/// No allocation and no per-beam push: the beams are appended at once and filled in place,
/// eight values at a time. On [`DecodeError::TooManyValues`] `out` is left empty.
pub fn decode_scan(
    scan: &Scan<'_>,
    mode: MeasuringMode,
    variant: Option<Variant>,
    out: &mut LaserScan,
) -> Result<(), DecodeError> {
    if mode.is_reflectivity() {
        return Err(DecodeError::NotRanges);
    }
    if mode.distance_mask().is_none() {
        return Err(DecodeError::UnknownMeasuringMode(mode.0));
    }
    let unit = scan
        .count_word
        .units()
        .metres()
        .ok_or(DecodeError::ReservedUnits)?;
    let count = scan.count_word.count();
    let v = match variant {
        Some(v) if v.values() == count => v,
        Some(_) => return Err(DecodeError::UnexpectedCount(count)),
        None => Variant::from_count(count).ok_or(DecodeError::UnexpectedCount(count))?,
    };
    let mut start_deg = f64::from(v.start_deg());
    if scan.count_word.partial() {
        start_deg += 0.25 * f64::from(scan.count_word.partial_index());
    }
    out.reset(lms_deg_to_sensor_rad(start_deg), v.resolution_rad());
    let split = WordSplit::new(mode).ok_or(DecodeError::UnknownMeasuringMode(mode.0))?;
    // One length update for the whole scan, then a fill in place (no per-beam push).
    let (ranges, flags) = out
        .append_beams(scan.values.len())
        .map_err(|_| DecodeError::TooManyValues)?;
    match scan.values {
        Values::Wire(bytes) => split.fill_wire(bytes, unit, ranges, flags),
        Values::Words(words) => {
            for ((range, flags), &word) in ranges.iter_mut().zip(flags.iter_mut()).zip(words) {
                (*range, *flags) = split.apply(word, unit);
            }
        }
    }
    Ok(())
}

/// The device-independent flags of the 13-bit modes' top codes, indexed by `distance − 0x1FF6`
/// (index 0: every distance below the codes).
const SPECIAL_FLAGS: [BeamFlags; 10] = [
    BeamFlags::VALID,           // ..=1FF6: a range
    BeamFlags::ABOVE_MAX_RANGE, // 1FF7
    BeamFlags::RESERVED,        // 1FF8
    BeamFlags::RESERVED,        // 1FF9
    BeamFlags::READ_ERROR,      // 1FFA
    BeamFlags::LOW_SIGNAL,      // 1FFB
    BeamFlags::RESERVED,        // 1FFC
    BeamFlags::OVERFLOW,        // 1FFD
    BeamFlags::DAZZLED,         // 1FFE
    BeamFlags::NO_RETURN,       // 1FFF
];

/// A measuring mode's value-word split, worked out once per scan: [`Value::decode`] without the
/// per-word `match` on the mode, and without branches on the special codes.
#[derive(Debug, Clone, Copy)]
struct WordSplit {
    mask: u16,
    /// Shift that brings the bits above the mask down to bit 0 (16: none).
    shift: u32,
    /// Distances above this are special codes (`0x1FF6` in 13-bit modes, none otherwise).
    special_above: u16,
}

impl WordSplit {
    fn new(mode: MeasuringMode) -> Option<Self> {
        let mask = mode.distance_mask()?;
        Some(Self {
            mask,
            shift: mask.trailing_ones(),
            special_above: if mode.has_special_values() {
                0x1FF6
            } else {
                u16::MAX
            },
        })
    }

    /// `(range in metres, flags)` of `word`: `distance × unit`, or `NAN` for a special code.
    #[inline(always)]
    fn apply(self, word: u16, unit: f32) -> (f32, BeamFlags) {
        let distance = word & self.mask;
        // At most 8 bits remain after the shift (masks have 13–16 bits): the cast keeps them.
        let raw = (u32::from(word) >> self.shift) as u8;
        // 0 below the codes, 1..=9 for 1FF7..=1FFF (distance ≤ 1FFF whenever codes exist).
        let code = distance.saturating_sub(self.special_above);
        let flags = SPECIAL_FLAGS
            .get(usize::from(code))
            .copied()
            .unwrap_or(BeamFlags::VALID);
        let range = if flags.is_valid() {
            f32::from(distance) * unit
        } else {
            f32::NAN
        };
        (range, flags.with_device_bits(raw))
    }

    /// Eight words as if none were a special code (ranges, flags with the raw bits only), and
    /// whether one was. Fixed-size arrays in and out, no branches: vectorised.
    #[inline(always)]
    fn common8(self, words: [u16; 8], unit: f32) -> ([f32; 8], [BeamFlags; 8], bool) {
        let mut ranges = [0f32; 8];
        let mut flags = [BeamFlags::VALID; 8];
        let mut special = 0u16;
        for ((range, flag), &word) in ranges.iter_mut().zip(flags.iter_mut()).zip(&words) {
            let distance = word & self.mask;
            *range = f32::from(distance) * unit;
            // At most 8 bits remain after the shift (masks have 13–16 bits).
            *flag = BeamFlags(((u32::from(word) >> self.shift) << 8) as u16);
            special |= u16::from(distance > self.special_above);
        }
        (ranges, flags, special != 0)
    }

    /// Turn the special codes among eight words filled by [`WordSplit::common8`] into `NAN`
    /// and their flag (the raw bits are already in place); the other words are left alone.
    #[inline(always)]
    fn fix_special8(self, words: [u16; 8], ranges: &mut [f32; 8], flags: &mut [BeamFlags; 8]) {
        for ((range, flag), &word) in ranges.iter_mut().zip(flags.iter_mut()).zip(&words) {
            let code = (word & self.mask).saturating_sub(self.special_above);
            let special = SPECIAL_FLAGS
                .get(usize::from(code))
                .copied()
                .unwrap_or(BeamFlags::VALID);
            flag.0 |= special.0;
            if code != 0 {
                *range = f32::NAN;
            }
        }
    }

    /// [`WordSplit::apply`] over little-endian wire words into `ranges` and `flags` (as many as
    /// all three hold). Eight words at a time: first the common case for all eight (a range, no
    /// device-independent flag) in straight-line code the compiler turns into SIMD, then, only
    /// if one of the eight is a special code, [`WordSplit::fix_special8`] over those eight.
    fn fill_wire(self, bytes: &[u8], unit: f32, ranges: &mut [f32], flags: &mut [BeamFlags]) {
        let mut r8 = ranges.chunks_exact_mut(8);
        let mut f8 = flags.chunks_exact_mut(8);
        let mut w8 = bytes.chunks_exact(16);
        for ((r, f), w) in (&mut r8).zip(&mut f8).zip(&mut w8) {
            // chunks_exact(16) hands out 16-byte slices: the fallback is never taken.
            let w: [u8; 16] = w.try_into().unwrap_or([0; 16]);
            let mut words = [0u16; 8];
            for (word, pair) in words.iter_mut().zip(w.chunks_exact(2)) {
                if let [lo, hi] = *pair {
                    *word = u16::from_le_bytes([lo, hi]);
                }
            }
            let (fast_r, fast_f, special) = self.common8(words, unit);
            if let (Ok(r), Ok(f)) = (
                <&mut [f32; 8]>::try_from(r),
                <&mut [BeamFlags; 8]>::try_from(f),
            ) {
                (*r, *f) = (fast_r, fast_f);
                if special {
                    self.fix_special8(words, r, f);
                }
            }
        }
        let rest = r8.into_remainder().iter_mut().zip(f8.into_remainder());
        for ((range, flags), pair) in rest.zip(w8.remainder().chunks_exact(2)) {
            if let [lo, hi] = *pair {
                (*range, *flags) = self.apply(u16::from_le_bytes([lo, hi]), unit);
            }
        }
    }
}

/// The value word a device reports for `range_m` (`None`: no return) in `units` and `mode`:
/// the inverse of [`decode_scan`] for a mock device. Ranges are rounded to the unit and
/// clamped below the special codes (13-bit modes) or to the mask; no return is `1FFF` in
/// 13-bit modes and the mask elsewhere. Flag bits are zero. Reserved units and unknown modes
/// give the no-return code of mode `00`.
#[must_use]
pub fn encode_range_m(range_m: Option<f64>, units: Units, mode: MeasuringMode) -> u16 {
    let (Some(mask), Some(unit)) = (mode.distance_mask(), units.metres()) else {
        return 0x1FFF;
    };
    let top = if mode.has_special_values() {
        0x1FF6
    } else {
        mask
    };
    match range_m {
        Some(r) if r.is_finite() => {
            // Round half up without `f64::round` (not in `core`).
            let counts = r.max(0.0) / f64::from(unit) + 0.5;
            if counts >= f64::from(top) {
                top
            } else {
                // In [0.5, top): truncation is the rounding, nothing is cut off.
                counts as u16
            }
        }
        _ => mask,
    }
}

/// Longest range the mode reports in `units`, metres (e.g. 8.191 m for 13 bits in mm).
#[must_use]
pub fn max_range_m(mode: MeasuringMode, units: Units) -> Option<f64> {
    let mask = mode.distance_mask()?;
    let top = if mode.has_special_values() {
        0x1FF6
    } else {
        mask
    };
    Some(f64::from(top) * f64::from(units.metres()?))
}

/// The [`LaserDescription`] of a variant, mode and unit, mounted at `pose`.
#[must_use]
pub fn describe(
    variant: Variant,
    mode: MeasuringMode,
    units: Units,
    pose: Isometry2,
) -> LaserDescription {
    LaserDescription {
        pose,
        fov_rad: f64::from(variant.angle_deg()) * PI / 180.0,
        resolution_rad: variant.resolution_rad(),
        beams: variant.values(),
        min_range_m: 0.0,
        max_range_m: max_range_m(mode, units).unwrap_or(0.0),
        max_scan_rate_hz: variant.max_scan_rate_hz(),
    }
}

/// The [`LaserDescription`] of a session (defaults: 180°/0.5°, mode 00, mm), for a scanner
/// mounted at `pose`. The scan-rate limit is the lower of the mirror's and the line's (§4).
#[must_use]
pub fn describe_session(info: Option<&SessionInfo>, pose: Isometry2) -> LaserDescription {
    let variant = info.and_then(|i| i.variant).unwrap_or(Variant::W180_R50);
    let (mode, units) = info
        .and_then(|i| i.config)
        .map_or((MeasuringMode::DEFAULT, Units::Mm), |c| {
            (c.measuring_mode(), Units::from_code(u16::from(c.units())))
        });
    let mut d = describe(variant, mode, units, pose);
    if let Some(i) = info {
        d.max_scan_rate_hz = d.max_scan_rate_hz.min(line_scan_rate_hz(i.baud, variant));
    }
    d
}

/// Scans per second the line allows for full scans of `variant` at `baud` (10 bits per byte,
/// frame = 2N + 10 bytes, spec §4's table).
#[must_use]
pub fn line_scan_rate_hz(baud: BaudRate, variant: Variant) -> f64 {
    let bytes = 2.0 * f64::from(variant.values()) + 10.0;
    f64::from(baud.bps()) / (10.0 * bytes)
}

/// Scans per second a unit can deliver: the lower of the mirror's limit and the line's.
#[must_use]
pub fn expected_scan_rate_hz(baud: BaudRate, variant: Variant) -> f64 {
    variant
        .max_scan_rate_hz()
        .min(line_scan_rate_hz(baud, variant))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::wire::{CountWord, StatusByte, Values};

    #[test]
    fn rates_match_the_spec_table() {
        let r = |b, v| (expected_scan_rate_hz(b, v) * 10.0).round() / 10.0;
        assert_eq!(r(BaudRate::B38400, Variant::W180_R50), 5.2);
        assert_eq!(r(BaudRate::B38400, Variant::W180_R100), 10.3);
        assert_eq!(r(BaudRate::B9600, Variant::W180_R50), 1.3);
        assert_eq!(r(BaudRate::B500000, Variant::W180_R50), 37.5);
        assert_eq!(r(BaudRate::B500000, Variant::W180_R100), 75.0);
    }

    #[test]
    fn variants_and_counts() {
        for (v, n) in [
            (Variant::W180_R100, 181),
            (Variant::W180_R50, 361),
            (Variant::W100_R100, 101),
            (Variant::W100_R50, 201),
            (Variant::W100_R25, 401),
        ] {
            assert_eq!(v.values(), n);
            assert_eq!(Variant::from_count(n), Some(v));
            assert_eq!(Variant::new(v.angle_deg(), v.res_centideg()), Some(v));
        }
        assert_eq!(Variant::new(180, 25), None);
        assert_eq!(Variant::W100_R25.start_deg(), 40);
        assert_eq!(Variant::from_count(100), None);
    }

    #[test]
    fn value_masks_by_mode() {
        let w = 0b1010_0000_0000_0101;
        let v = Value::decode(w, MeasuringMode(0x00)).unwrap();
        assert_eq!((v.distance, v.raw_flags), (5, 0b101));
        let v = Value::decode(w, MeasuringMode(0x03)).unwrap();
        assert_eq!((v.distance, v.raw_flags), (0x2005, 0b10));
        let v = Value::decode(w, MeasuringMode(0x05)).unwrap();
        assert_eq!((v.distance, v.raw_flags), (0x2005, 1));
        let v = Value::decode(w, MeasuringMode(0x0F)).unwrap();
        assert_eq!((v.distance, v.raw_flags), (w, 0));
        assert!(Value::decode(w, MeasuringMode(0x0D)).is_none());
    }

    #[test]
    fn special_codes_only_in_13_bit_modes() {
        let m = MeasuringMode::DEFAULT;
        assert_eq!(
            Value::decode(0x1FFF, m).unwrap().flags,
            BeamFlags::NO_RETURN
        );
        assert_eq!(Value::decode(0x1FFE, m).unwrap().flags, BeamFlags::DAZZLED);
        assert_eq!(Value::decode(0x1FFD, m).unwrap().flags, BeamFlags::OVERFLOW);
        assert_eq!(
            Value::decode(0x1FFB, m).unwrap().flags,
            BeamFlags::LOW_SIGNAL
        );
        assert_eq!(
            Value::decode(0x1FFA, m).unwrap().flags,
            BeamFlags::READ_ERROR
        );
        assert_eq!(
            Value::decode(0x1FF7, m).unwrap().flags,
            BeamFlags::ABOVE_MAX_RANGE
        );
        assert_eq!(Value::decode(0x1FF9, m).unwrap().flags, BeamFlags::RESERVED);
        assert!(Value::decode(0x1FF6, m).unwrap().flags.is_valid());
        // Bit 13 set on a special code: still special, raw bit kept.
        let v = Value::decode(0x3FFF, m).unwrap();
        assert!(v.flags.contains(BeamFlags::NO_RETURN));
        assert_eq!(v.flags.device_bits(), 1);
        assert!(
            Value::decode(0x1FFF, MeasuringMode(0x03))
                .unwrap()
                .flags
                .is_valid()
        );
    }

    #[test]
    fn decode_361_mm_geometry_and_ranges() {
        let mut words = [1000u16; 361];
        words[0] = 0x1FFF;
        words[180] = 0x2000 | 2500;
        let s = Scan::full(&words, Units::Mm, StatusByte::NORMAL);
        let mut out = LaserScan::default();
        decode_scan(&s, MeasuringMode::DEFAULT, None, &mut out).unwrap();
        assert_eq!(out.len(), 361);
        assert!((out.start_angle_rad + PI / 2.0).abs() < 1e-12);
        assert!((out.step_rad - 0.5 * PI / 180.0).abs() < 1e-12);
        assert!(out.ranges_m()[0].is_nan());
        assert_eq!(out.flags()[0], BeamFlags::NO_RETURN);
        assert!((out.ranges_m()[1] - 1.0).abs() < 1e-6);
        assert!((out.ranges_m()[180] - 2.5).abs() < 1e-6);
        assert_eq!(out.flags()[180].device_bits(), 1);
        assert!(out.flags()[180].is_valid());
        assert!(
            (out.angle_rad(180)).abs() < 1e-12,
            "middle beam points ahead"
        );
    }

    #[test]
    fn decode_100_deg_partial_and_errors() {
        let words = [10u16; 401];
        let mut s = Scan::full(&words, Units::Cm, StatusByte::NORMAL);
        s.count_word = CountWord(s.count_word.0 | 0x2000 | (2 << 11));
        let mut out = LaserScan::default();
        decode_scan(&s, MeasuringMode::DEFAULT, None, &mut out).unwrap();
        let start = lms_deg_to_sensor_rad(40.5);
        assert!((out.start_angle_rad - start).abs() < 1e-12);
        assert!((out.ranges_m()[3] - 0.1).abs() < 1e-6);
        assert_eq!(
            decode_scan(
                &s,
                MeasuringMode::DEFAULT,
                Some(Variant::W180_R50),
                &mut out
            ),
            Err(DecodeError::UnexpectedCount(401))
        );
        assert_eq!(
            decode_scan(&s, MeasuringMode(0x3F), None, &mut out),
            Err(DecodeError::NotRanges)
        );
        assert_eq!(
            decode_scan(&s, MeasuringMode(0x0E), None, &mut out),
            Err(DecodeError::UnknownMeasuringMode(0x0E))
        );
        let w3 = [1u16, 2, 3];
        let s3 = Scan {
            count_word: CountWord(3 | 0xC000),
            values: Values::Words(&w3),
            indices: None,
            status: StatusByte::NORMAL,
        };
        assert_eq!(
            decode_scan(&s3, MeasuringMode::DEFAULT, None, &mut out),
            Err(DecodeError::ReservedUnits)
        );
    }

    #[test]
    fn encode_is_the_inverse_of_decode() {
        let m = MeasuringMode::DEFAULT;
        assert_eq!(encode_range_m(Some(1.2344), Units::Mm, m), 1234);
        assert_eq!(encode_range_m(Some(1.2346), Units::Mm, m), 1235);
        assert_eq!(encode_range_m(Some(-1.0), Units::Mm, m), 0);
        assert_eq!(encode_range_m(Some(50.0), Units::Mm, m), 0x1FF6);
        assert_eq!(encode_range_m(None, Units::Mm, m), 0x1FFF);
        assert_eq!(encode_range_m(Some(f64::NAN), Units::Cm, m), 0x1FFF);
        assert_eq!(encode_range_m(Some(12.34), Units::Cm, m), 1234);
        assert_eq!(
            encode_range_m(Some(20.0), Units::Mm, MeasuringMode(0x03)),
            0x3FFF
        );
        assert_eq!(encode_range_m(None, Units::Mm, MeasuringMode(0x05)), 0x7FFF);
        assert_eq!(encode_range_m(Some(1.0), Units::Reserved, m), 0x1FFF);
        for r in [0.0, 0.5, 3.217, 8.0] {
            let w = encode_range_m(Some(r), Units::Mm, m);
            let v = Value::decode(w, m).unwrap();
            assert!(v.flags.is_valid());
            assert!((f64::from(v.distance) * 0.001 - r).abs() < 0.0006);
        }
    }

    #[test]
    fn description_limits() {
        let d = describe(
            Variant::W180_R50,
            MeasuringMode::DEFAULT,
            Units::Mm,
            Isometry2::identity(),
        );
        assert_eq!(d.beams, 361);
        assert!((d.fov_rad - PI).abs() < 1e-12);
        assert!((d.max_range_m - 8.182).abs() < 1e-3);
        assert!((d.max_scan_rate_hz - 37.5).abs() < 1e-12);
        let d = describe(
            Variant::W100_R25,
            MeasuringMode::DEFAULT,
            Units::Cm,
            Isometry2::identity(),
        );
        assert!((d.max_range_m - 81.82).abs() < 1e-2);
        assert!((d.max_scan_rate_hz - 18.75).abs() < 1e-12);
    }

    /// The range and flags [`Value::decode`] gives for `word`: the per-word reference.
    fn reference(word: u16, mode: MeasuringMode, unit: f32) -> (f32, BeamFlags) {
        let v = Value::decode(word, mode).unwrap();
        let range = if v.flags.is_valid() {
            f32::from(v.distance) * unit
        } else {
            f32::NAN
        };
        (range, v.flags)
    }

    fn same(a: f32, b: f32) -> bool {
        a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan())
    }

    proptest::proptest! {
        /// The per-scan split gives what `Value::decode` gives for every word, mode and unit,
        /// from wire bytes and from words alike.
        #[test]
        fn decode_scan_equals_value_decode(
            count in proptest::sample::select(vec![101usize, 181, 201, 361, 401]),
            seed in proptest::collection::vec(proptest::prelude::any::<u16>(), 401),
            near_codes in proptest::prelude::any::<bool>(),
            mode in proptest::sample::select(vec![0x00u8, 0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x0F]),
            units in proptest::sample::select(vec![Units::Cm, Units::Mm, Units::Dm]),
        ) {
            let mode = MeasuringMode(mode);
            // Half the cases crowd the special codes (1FF0..=1FFF, any flag bits).
            let words: Vec<u16> = seed[..count]
                .iter()
                .map(|&w| if near_codes { 0x1FF0 | (w & 0xE00F) } else { w })
                .collect();
            let wire: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();
            let unit = units.metres().unwrap();
            for values in [Values::Words(&words), Values::Wire(&wire)] {
                let s = Scan {
                    count_word: CountWord::full_scan(count as u16, units),
                    values,
                    indices: None,
                    status: StatusByte::NORMAL,
                };
                let mut out = LaserScan::default();
                decode_scan(&s, mode, None, &mut out).unwrap();
                proptest::prop_assert_eq!(out.len(), count);
                for (i, &w) in words.iter().enumerate() {
                    let (r, f) = reference(w, mode, unit);
                    proptest::prop_assert!(same(out.ranges_m()[i], r), "word {:#06x}", w);
                    proptest::prop_assert_eq!(out.flags()[i], f, "word {:#06x}", w);
                }
            }
        }
    }

    #[test]
    fn too_many_values_appends_nothing() {
        let words = [100u16; 900];
        let s = Scan {
            count_word: CountWord::full_scan(401, Units::Mm),
            values: Values::Words(&words),
            indices: None,
            status: StatusByte::NORMAL,
        };
        let mut out = LaserScan::default();
        assert_eq!(
            decode_scan(&s, MeasuringMode::DEFAULT, None, &mut out),
            Err(DecodeError::TooManyValues)
        );
        assert!(out.is_empty());
    }

    #[test]
    fn every_word_in_every_mode_matches_value_decode() {
        for mode in [0x00u8, 0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x0F] {
            let mode = MeasuringMode(mode);
            let split = WordSplit::new(mode).unwrap();
            for w in 0..=u16::MAX {
                let (r, f) = split.apply(w, 0.001);
                let (rr, rf) = reference(w, mode, 0.001);
                assert!(same(r, rr), "mode {mode:?} word {w:#06x}");
                assert_eq!(f, rf, "mode {mode:?} word {w:#06x}");
            }
        }
    }
}

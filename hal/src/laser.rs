//! Scanning laser range finders (planar lidar).
//!
//! # Scan layout
//!
//! A [`LaserScan`] is a fan of beams in the sensor frame (x forward, y left, angles
//! counter-clockwise positive): beam `i` points at `start_angle_rad + i * step_rad`. Ranges are
//! metres along the beam, `f32` (millimetre resolution at 80 m needs ~17 bits; `f32` has 24).
//!
//! # Storage: no heap per scan
//!
//! Beams live in fixed-capacity inline vectors (`heapless::Vec`, [`MAX_BEAMS`] entries), so a
//! scan is a plain value: a driver task can fill one in place, hand it over a channel or a
//! `watch`, and the consumer can keep it, all without touching the allocator. The price is a
//! ~4 KiB value that is `memcpy`'d when moved; at the 75 scans/s a SICK LMS tops out at, that is
//! ~300 KiB/s of copying, far below anything measurable. A caller-provided buffer would avoid the
//! copy but would tie a borrow to every trait future, which async traits and channels handle
//! badly.
//!
//! Capacity 802 = 2 × 401: the longest LMS 2xx scan is 401 values (100° at 0.25°), and the
//! factor two leaves room for a merged pair of interleaved partial scans or for a 360°/0.5°
//! scanner (721 beams) without changing the type.

use core::future::Future;

use crate::{ErrorType, Isometry2, Stamped};

/// Most beams a [`LaserScan`] holds.
pub const MAX_BEAMS: usize = 802;

/// Per-beam quality flags: the low byte is device-independent, the high byte carries the
/// device's own raw flag bits for callers that know the device.
///
/// A beam is usable when [`BeamFlags::is_valid`]; invalid beams carry `f32::NAN` as range.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct BeamFlags(pub u16);

impl BeamFlags {
    /// A valid measurement with no raw device bits.
    pub const VALID: Self = Self(0);
    /// No return (nothing within range, or the measurement is invalid).
    pub const NO_RETURN: Self = Self(1 << 0);
    /// The receiver was dazzled (e.g. by sunlight or another scanner).
    pub const DAZZLED: Self = Self(1 << 1);
    /// The measurement overflowed.
    pub const OVERFLOW: Self = Self(1 << 2);
    /// The signal-to-noise ratio was too low.
    pub const LOW_SIGNAL: Self = Self(1 << 3);
    /// The device reported an internal read error for this beam.
    pub const READ_ERROR: Self = Self(1 << 4);
    /// The target was beyond the maximum range.
    pub const ABOVE_MAX_RANGE: Self = Self(1 << 5);
    /// A value the device reserves (neither a range nor a documented error code).
    pub const RESERVED: Self = Self(1 << 6);

    /// Flags with `raw` as the device-specific byte and the given device-independent flags.
    #[must_use]
    pub const fn with_device_bits(self, raw: u8) -> Self {
        Self((self.0 & 0x00FF) | ((raw as u16) << 8))
    }

    /// The device-specific raw flag bits (e.g. a SICK LMS value word's bits above the distance
    /// mask, shifted down to bit 0). Their meaning depends on the device and its mode.
    #[must_use]
    pub const fn device_bits(self) -> u8 {
        (self.0 >> 8) as u8
    }

    /// The range is a measurement (no device-independent error flag is set).
    #[must_use]
    pub const fn is_valid(self) -> bool {
        self.0 & 0x00FF == 0
    }

    /// Every flag of `other` is set in `self` (device bits included).
    #[must_use]
    pub const fn contains(self, other: Self) -> bool {
        self.0 & other.0 == other.0
    }
}

/// The scan is full: it already holds [`MAX_BEAMS`] beams.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ScanFull;

/// One planar scan: geometry plus one range and one set of flags per beam.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct LaserScan {
    /// Angle of beam 0 in the sensor frame, radians (counter-clockwise from x forward).
    pub start_angle_rad: f64,
    /// Angle between consecutive beams, radians (positive: counter-clockwise order).
    pub step_rad: f64,
    ranges_m: heapless::Vec<f32, MAX_BEAMS>,
    flags: heapless::Vec<BeamFlags, MAX_BEAMS>,
}

impl LaserScan {
    /// An empty scan with the given geometry.
    #[must_use]
    pub const fn new(start_angle_rad: f64, step_rad: f64) -> Self {
        Self {
            start_angle_rad,
            step_rad,
            ranges_m: heapless::Vec::new(),
            flags: heapless::Vec::new(),
        }
    }

    /// Remove every beam and set a new geometry, keeping the storage (no allocation either way).
    #[inline]
    pub fn reset(&mut self, start_angle_rad: f64, step_rad: f64) {
        self.start_angle_rad = start_angle_rad;
        self.step_rad = step_rad;
        self.ranges_m.clear();
        self.flags.clear();
    }

    /// Append a beam. Fails (and drops the beam) when the scan is full.
    #[inline]
    pub fn push(&mut self, range_m: f32, flags: BeamFlags) -> Result<(), ScanFull> {
        if self.ranges_m.len() >= MAX_BEAMS {
            return Err(ScanFull);
        }
        self.ranges_m.push(range_m).map_err(|_| ScanFull)?;
        self.flags.push(flags).map_err(|_| ScanFull)
    }

    /// Append `n` beams to fill in place and return their ranges and flags (`NAN` and
    /// [`BeamFlags::NO_RETURN`] until overwritten). Fails, changing nothing, when fewer than `n`
    /// more beams fit.
    ///
    /// For decoders that convert a whole scan at once: one length update for the lot instead of
    /// one per [`LaserScan::push`], so the conversion loop has no loop-carried store.
    #[inline]
    pub fn append_beams(&mut self, n: usize) -> Result<(&mut [f32], &mut [BeamFlags]), ScanFull> {
        let old = self.ranges_m.len();
        let new = old
            .checked_add(n)
            .filter(|&l| l <= MAX_BEAMS)
            .ok_or(ScanFull)?;
        self.ranges_m.resize(new, f32::NAN).map_err(|_| ScanFull)?;
        if self.flags.resize(new, BeamFlags::NO_RETURN).is_err() {
            self.ranges_m.truncate(old);
            return Err(ScanFull);
        }
        let ranges = self.ranges_m.get_mut(old..).unwrap_or_default();
        let flags = self.flags.get_mut(old..).unwrap_or_default();
        Ok((ranges, flags))
    }

    /// Number of beams.
    #[must_use]
    pub fn len(&self) -> usize {
        self.ranges_m.len()
    }

    /// No beams.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.ranges_m.is_empty()
    }

    /// Ranges in metres, one per beam (`NAN` where the beam is invalid).
    #[must_use]
    pub fn ranges_m(&self) -> &[f32] {
        &self.ranges_m
    }

    /// Flags, one per beam (same length as [`LaserScan::ranges_m`]).
    #[must_use]
    pub fn flags(&self) -> &[BeamFlags] {
        &self.flags
    }

    /// Angle of beam `i` in the sensor frame, radians.
    #[must_use]
    pub fn angle_rad(&self, i: usize) -> f64 {
        self.start_angle_rad + self.step_rad * i as f64
    }

    /// `(angle_rad, range_m, flags)` for every beam.
    pub fn beams(&self) -> impl Iterator<Item = (f64, f32, BeamFlags)> + '_ {
        self.ranges_m
            .iter()
            .zip(self.flags.iter())
            .enumerate()
            .map(|(i, (&r, &f))| (self.angle_rad(i), r, f))
    }
}

/// What a scanner is and where it sits: the static description of its scans.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LaserDescription {
    /// Pose of the sensor frame on the robot (x forward along the scan's 0 rad).
    pub pose: Isometry2,
    /// Full field of view, radians (first to last beam).
    pub fov_rad: f64,
    /// Angle between beams, radians.
    pub resolution_rad: f64,
    /// Beams per scan.
    pub beams: u16,
    /// Shortest range the device reports, metres.
    pub min_range_m: f64,
    /// Longest range the device reports in its current mode, metres.
    pub max_range_m: f64,
    /// Most complete scans per second the device can deliver in its current configuration.
    pub max_scan_rate_hz: f64,
}

/// A planar scanning laser range finder.
pub trait LaserScanner: ErrorType {
    /// The current scan geometry and limits (changes only after a reconfiguration).
    fn description(&self) -> LaserDescription;

    /// The most recent scan (waits for the first one after connecting).
    fn scan(&mut self) -> impl Future<Output = Result<Stamped<LaserScan>, Self::Error>> + Send;

    /// Wait for a scan stamped later than `after`.
    fn next_scan(
        &mut self,
        after: crate::Instant,
    ) -> impl Future<Output = Result<Stamped<LaserScan>, Self::Error>> + Send;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn push_until_full_and_reset_keeps_geometry_rules() {
        let mut s = LaserScan::new(-1.0, 0.5);
        for i in 0..MAX_BEAMS {
            assert!(s.push(i as f32, BeamFlags::VALID).is_ok());
        }
        assert_eq!(s.push(0.0, BeamFlags::VALID), Err(ScanFull));
        assert_eq!(s.len(), MAX_BEAMS);
        assert_eq!(s.flags().len(), MAX_BEAMS);
        assert!((s.angle_rad(2) - 0.0).abs() < 1e-12);
        s.reset(0.25, 0.1);
        assert!(s.is_empty());
        assert!((s.start_angle_rad - 0.25).abs() < 1e-12);
    }

    #[test]
    fn append_beams_fills_in_place_or_changes_nothing() {
        let mut s = LaserScan::new(0.0, 1.0);
        s.push(1.0, BeamFlags::VALID).unwrap();
        let (r, f) = s.append_beams(3).unwrap();
        assert_eq!((r.len(), f.len()), (3, 3));
        assert!(r.iter().all(|x| x.is_nan()));
        assert!(f.iter().all(|&x| x == BeamFlags::NO_RETURN));
        r[1] = 2.5;
        f[1] = BeamFlags::VALID;
        assert_eq!(s.len(), 4);
        assert_eq!(s.ranges_m()[0], 1.0);
        assert_eq!(s.ranges_m()[2], 2.5);
        assert_eq!(s.flags()[2], BeamFlags::VALID);
        assert_eq!(s.append_beams(MAX_BEAMS - 3).err(), Some(ScanFull));
        assert_eq!(s.append_beams(usize::MAX).err(), Some(ScanFull));
        assert_eq!((s.len(), s.flags().len()), (4, 4));
        assert_eq!(
            s.append_beams(MAX_BEAMS - 4).map(|(r, _)| r.len()),
            Ok(MAX_BEAMS - 4)
        );
        assert_eq!(s.append_beams(0).map(|(r, _)| r.len()), Ok(0));
        assert_eq!(s.push(0.0, BeamFlags::VALID), Err(ScanFull));
    }

    #[test]
    fn flags_split_device_bits() {
        let f = BeamFlags::DAZZLED.with_device_bits(0b101);
        assert_eq!(f.device_bits(), 0b101);
        assert!(!f.is_valid());
        assert!(f.contains(BeamFlags::DAZZLED));
        assert!(!f.contains(BeamFlags::NO_RETURN));
        assert!(BeamFlags::VALID.with_device_bits(7).is_valid());
    }

    #[test]
    fn beams_iterates_in_order() {
        let mut s = LaserScan::new(0.0, 1.0);
        s.push(1.5, BeamFlags::VALID).unwrap();
        s.push(f32::NAN, BeamFlags::NO_RETURN).unwrap();
        let v: Vec<_> = s.beams().collect();
        assert_eq!(v.len(), 2);
        assert!((v[1].0 - 1.0).abs() < 1e-12);
        assert!(v[1].1.is_nan());
        assert_eq!(v[1].2, BeamFlags::NO_RETURN);
    }
}

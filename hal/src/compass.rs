//! Heading sensors (magnetic compasses).
//!
//! # Angle convention
//!
//! A compass reports a **heading**: the angle from the reference north (magnetic or true) to the
//! robot's forward axis, measured **clockwise** seen from above, in radians in `[0, 2π)`. That is
//! the navigation convention every compass and NMEA sentence uses, and it is *not* the
//! counter-clockwise yaw of the rest of this crate; [`Heading::yaw_enu_rad`] converts (yaw
//! counter-clockwise from east, in (−π, π]).
//!
//! Corrections follow NMEA 0183 HDG: *magnetic = sensor + deviation*, *true = magnetic +
//! variation*, both corrections positive east.

use core::f64::consts::{FRAC_PI_2, TAU};
use core::future::Future;

use crate::{ErrorType, Instant, Stamped};

/// Which north a heading is measured from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum HeadingReference {
    /// Magnetic north (what a bare compass measures; possibly before deviation correction,
    /// see [`Heading::deviation_rad`]).
    Magnetic,
    /// Geographic (true) north.
    True,
}

/// How well a compass is calibrated, as far as the device says.
///
/// PNI TCM2 scores its user calibration as `HnVnMn.n`: horizontal and vertical scores 0–9
/// (higher is better) and a magnetic distortion figure (lower is better). Devices that report
/// nothing leave the whole value out ([`Heading::calibration`] is `None`).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct CalibrationQuality {
    /// Horizontal calibration score, 0–9, higher is better.
    pub horizontal_score: Option<u8>,
    /// Vertical calibration score, 0–9, higher is better.
    pub vertical_score: Option<u8>,
    /// Magnetic distortion figure of the calibration, lower is better (device units).
    pub distortion: Option<f64>,
    /// The device runs continuous automatic calibration.
    pub auto_calibration: bool,
}

/// One heading measurement.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Heading {
    /// Heading in radians, clockwise from the reference north, in `[0, 2π)`.
    pub heading_rad: f64,
    /// The north [`heading_rad`](Self::heading_rad) is measured from.
    pub reference: HeadingReference,
    /// Magnetic deviation of the installation, radians, positive east, where the device says.
    /// When present, a [`Magnetic`](HeadingReference::Magnetic) heading is the *sensor* heading
    /// and the corrected magnetic heading is `heading_rad + deviation_rad`.
    pub deviation_rad: Option<f64>,
    /// Magnetic variation (declination) at the site, radians, positive east, where known.
    pub variation_rad: Option<f64>,
    /// Calibration quality, where the device reports it.
    pub calibration: Option<CalibrationQuality>,
}

impl Heading {
    /// A heading with no corrections or calibration information; `heading_rad` is wrapped
    /// into `[0, 2π)`.
    #[must_use]
    pub fn new(heading_rad: f64, reference: HeadingReference) -> Self {
        Self {
            heading_rad: wrap_2pi(heading_rad),
            reference,
            deviation_rad: None,
            variation_rad: None,
            calibration: None,
        }
    }

    /// Magnetic heading with the deviation applied (if known), `[0, 2π)`; `None` for a true
    /// heading.
    #[must_use]
    pub fn magnetic_rad(&self) -> Option<f64> {
        match self.reference {
            HeadingReference::Magnetic => Some(wrap_2pi(
                self.heading_rad + self.deviation_rad.unwrap_or(0.0),
            )),
            HeadingReference::True => None,
        }
    }

    /// True heading, `[0, 2π)`: the heading itself if it is true, else the magnetic heading
    /// plus the variation when the variation is known.
    #[must_use]
    pub fn true_rad(&self) -> Option<f64> {
        match self.reference {
            HeadingReference::True => Some(self.heading_rad),
            HeadingReference::Magnetic => {
                let var = self.variation_rad?;
                self.magnetic_rad().map(|m| wrap_2pi(m + var))
            }
        }
    }

    /// The heading as a yaw in this crate's convention: counter-clockwise from east (the x axis
    /// of an east-north-up frame), in (−π, π]. Uses the reading's own reference and
    /// corrections as [`magnetic_rad`](Self::magnetic_rad) / [`true_rad`](Self::true_rad) do.
    #[must_use]
    pub fn yaw_enu_rad(&self) -> f64 {
        let h = self
            .true_rad()
            .or_else(|| self.magnetic_rad())
            .unwrap_or(self.heading_rad);
        crate::normalize_angle(FRAC_PI_2 - h)
    }
}

/// Wrap an angle in radians into `[0, 2π)` (non-finite values pass through).
#[must_use]
pub fn wrap_2pi(a: f64) -> f64 {
    if !a.is_finite() {
        return a;
    }
    let r = a % TAU;
    let r = if r < 0.0 { r + TAU } else { r };
    // `r + TAU` can round up to exactly TAU for tiny negative r.
    if r >= TAU { 0.0 } else { r }
}

/// A heading sensor.
pub trait Compass: ErrorType {
    /// The most recent heading (waits for the first one after connecting).
    fn heading(&mut self) -> impl Future<Output = Result<Stamped<Heading>, Self::Error>> + Send;

    /// Wait for a heading measured after `after`.
    fn next_heading(
        &mut self,
        after: Instant,
    ) -> impl Future<Output = Result<Stamped<Heading>, Self::Error>> + Send;
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::f64::consts::PI;

    #[test]
    fn wrap_into_zero_two_pi() {
        assert!((wrap_2pi(-FRAC_PI_2) - 1.5 * PI).abs() < 1e-12);
        assert_eq!(wrap_2pi(TAU), 0.0);
        assert!(wrap_2pi(-1e-300) < TAU);
        assert!(wrap_2pi(f64::NAN).is_nan());
    }

    #[test]
    fn corrections_and_yaw() {
        let mut h = Heading::new(90f64.to_radians(), HeadingReference::Magnetic);
        assert!(h.true_rad().is_none(), "no variation, no true heading");
        h.deviation_rad = Some(2f64.to_radians());
        h.variation_rad = Some(-12f64.to_radians());
        let m = h.magnetic_rad().unwrap().to_degrees();
        let t = h.true_rad().unwrap().to_degrees();
        assert!((m - 92.0).abs() < 1e-9);
        assert!((t - 80.0).abs() < 1e-9);
        // heading 80° (east-ish) is yaw +10° from east, counter-clockwise.
        assert!((h.yaw_enu_rad().to_degrees() - 10.0).abs() < 1e-9);
        let north = Heading::new(0.0, HeadingReference::True);
        assert!((north.yaw_enu_rad() - FRAC_PI_2).abs() < 1e-12);
    }
}

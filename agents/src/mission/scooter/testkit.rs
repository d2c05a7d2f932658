//! Inputs for the agents' unit tests: laser scans of round things, SES samples.

use core::f64::consts::PI;

use ima_hal::laser::{BeamFlags, LaserScan};
use ima_hal::{Instant, Isometry2, Vector2};

use crate::ses::shared::{SharedForm, SharedRecord};

/// A 181-beam scan (−90°…+90°, 1° steps, 8 m range) from a laser at `mount` on a robot at
/// `(x, y, θ)` (world frame), seeing `circles` (centre, radius).
pub(super) fn scan(
    pose: (f64, f64, f64),
    mount: &Isometry2,
    circles: &[([f64; 2], f64)],
) -> LaserScan {
    let mut s = LaserScan::new(-PI / 2.0, PI / 180.0);
    let sensor = Isometry2::new(Vector2::new(pose.0, pose.1), pose.2) * mount;
    let o = sensor.translation.vector;
    for k in 0..181 {
        let dir = sensor.rotation.angle() - PI / 2.0 + f64::from(k) * PI / 180.0;
        let d = Vector2::new(dir.cos(), dir.sin());
        let mut best = f64::INFINITY;
        for (c, r) in circles {
            let f = o - Vector2::new(c[0], c[1]);
            let b = f.dot(&d);
            let disc = b * b - (f.dot(&f) - r * r);
            if disc >= 0.0 {
                let hit = -b - disc.sqrt();
                if hit >= 0.0 {
                    best = best.min(hit);
                }
            }
        }
        if best < 8.0 {
            s.push(best as f32, BeamFlags::VALID).unwrap();
        } else {
            s.push(f32::NAN, BeamFlags::NO_RETURN).unwrap();
        }
    }
    s
}

/// 181 beams, all flagged `flags` (no range).
pub(super) fn uniform_scan(flags: BeamFlags) -> LaserScan {
    let mut s = LaserScan::new(-PI / 2.0, PI / 180.0);
    for _ in 0..181 {
        s.push(f32::NAN, flags).unwrap();
    }
    s
}

/// An SES record of `object` at `bearing_deg` (common frame), sensed at `time`.
pub(super) fn rec(
    object: &str,
    bearing_deg: f64,
    range_m: Option<f64>,
    time: Instant,
) -> SharedRecord {
    SharedRecord {
        object: object.to_owned(),
        bearing: crate::ses::Direction::horizontal(bearing_deg.to_radians()),
        range_m,
        confidence: 1.0,
        time,
    }
}

/// Skeeter's shared form with `records`, sent at `sent_at`.
pub(super) fn form(records: Vec<SharedRecord>, sent_at: Instant) -> SharedForm {
    SharedForm {
        source_robot: "skeeter".to_owned(),
        sent_at,
        records,
    }
}

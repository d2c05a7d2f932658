//! Robot parameter tables, chosen by the subclass string of the SYNC2 reply (spec §8).
//!
//! The values are the published ARIA/Saphira parameter files' facts (spec §8 cites them).
//! `p2at` and `p2at8` differ by a factor of 3.7 in the sonar range unit, so picking the table
//! by subclass matters (spec §10 item 11); an unknown subclass is an error unless the caller
//! overrides it ([`crate::machine::Config::params_override`]).

use ima_hal::base::BaseLimits;
use ima_hal::sonar::SonarTransducer;
use ima_hal::{Isometry2, Vector2};

/// Default encoder resolution of the thesis's robots: 9,850 ticks per wheel turn.
pub const DEFAULT_TICKS_PER_MM: f64 = 19.0;

/// One sonar transducer's mounting: x forward, y left (mm), heading (degrees, CCW).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SonarPose {
    /// Forward offset, mm.
    pub x_mm: f64,
    /// Left offset, mm.
    pub y_mm: f64,
    /// Beam heading, degrees counter-clockwise from forward.
    pub heading_deg: f64,
}

const fn sp(x_mm: f64, y_mm: f64, heading_deg: f64) -> SonarPose {
    SonarPose {
        x_mm,
        y_mm,
        heading_deg,
    }
}

/// Conversion factors and geometry of one robot model.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RobotParams {
    /// Subclass string this table is for (lower case).
    pub subclass: &'static str,
    /// Radians per THPOS unit.
    pub angle_conv: f64,
    /// mm per XPOS/YPOS unit.
    pub dist_conv: f64,
    /// mm/s per wheel-velocity unit.
    pub vel_conv: f64,
    /// mm per sonar range unit.
    pub range_conv: f64,
    /// ω [rad/s] = (R − L) / 2 × this (1/mm).
    pub diff_conv: f64,
    /// VEL2 byte × this = mm/s.
    pub vel2_divisor: f64,
    /// Absolute maximum translational speed, mm/s.
    pub max_velocity_mm_s: f64,
    /// Absolute maximum rotational speed, deg/s.
    pub max_rot_velocity_deg_s: f64,
    /// Robot radius, mm.
    pub radius_mm: f64,
    /// Robot width, mm.
    pub width_mm: f64,
    /// Robot length, mm.
    pub length_mm: f64,
    /// Sonar transducers, by index.
    pub sonars: &'static [SonarPose],
    /// Encoder ticks per mm of wheel travel (for ENCODER packets).
    pub ticks_per_mm: f64,
}

impl RobotParams {
    /// Effective track width implied by `diff_conv`: 2 / diff_conv, mm.
    #[must_use]
    pub fn track_mm(&self) -> f64 {
        2.0 / self.diff_conv
    }

    /// The speed limits of this robot (`max_velocity`, `max_rot_velocity`).
    #[must_use]
    pub fn limits(&self) -> BaseLimits {
        BaseLimits {
            max_v_m_s: self.max_velocity_mm_s / 1000.0,
            max_omega_rad_s: self.max_rot_velocity_deg_s.to_radians(),
        }
    }

    /// The sonar ring as HAL transducers (P2OS sonar: 10 cm–5 m, ~30° beams).
    pub fn transducers(&self) -> impl Iterator<Item = SonarTransducer> + '_ {
        self.sonars.iter().map(|s| SonarTransducer {
            pose: Isometry2::new(
                Vector2::new(s.x_mm / 1000.0, s.y_mm / 1000.0),
                s.heading_deg.to_radians(),
            ),
            min_range_m: 0.1,
            max_range_m: 5.0,
            beam_width_rad: 30f64.to_radians(),
        })
    }

    /// The table for `subclass` (case-insensitive), if known.
    #[must_use]
    pub fn for_subclass(subclass: &[u8]) -> Option<&'static RobotParams> {
        ALL.iter()
            .copied()
            .find(|p| p.subclass.as_bytes().eq_ignore_ascii_case(subclass))
    }

    /// A SIP's XPOS or YPOS in metres: the 15-bit counter read as a signed count
    /// ([`crate::machine::signed15`], the shorter way round from 0, as the odometry reads
    /// every step) × `dist_conv`. A robot at −0.57 m reports 0x7E4D, not 42.68 m.
    #[must_use]
    pub fn position_m(&self, raw: u16) -> f64 {
        f64::from(crate::machine::signed15(raw)) * self.dist_conv / 1000.0
    }

    /// A SIP's THPOS as a heading, radians in (−π, π].
    #[must_use]
    pub fn heading_rad(&self, thpos: i16) -> f64 {
        ima_hal::normalize_angle(f64::from(thpos) * self.angle_conv)
    }

    /// One wheel's velocity count of a SIP in m/s.
    #[must_use]
    pub fn wheel_m_s(&self, raw: i16) -> f64 {
        f64::from(raw) * self.vel_conv / 1000.0
    }

    /// The body's speed (m/s) and turn rate (rad/s) from a SIP's wheel velocity counts, as
    /// the driver's odometry reports them: v = (L + R) / 2 × `vel_conv`,
    /// ω = (R − L) / 2 × `vel_conv` × `diff_conv`.
    #[must_use]
    pub fn body_velocity(&self, left: i16, right: i16) -> (f64, f64) {
        let v_mm_s = (f64::from(left) + f64::from(right)) / 2.0 * self.vel_conv;
        let omega = (f64::from(right) - f64::from(left)) / 2.0 * self.vel_conv * self.diff_conv;
        (v_mm_s / 1000.0, omega)
    }

    /// A sonar range count in metres.
    #[must_use]
    pub fn sonar_range_m(&self, raw: u16) -> f64 {
        f64::from(raw) * self.range_conv / 1000.0
    }

    /// A VEL2 wheel byte in m/s (× `vel2_divisor` mm/s).
    #[must_use]
    pub fn vel2_m_s(&self, raw: i8) -> f64 {
        f64::from(raw) * self.vel2_divisor / 1000.0
    }
}

/// A SIP's battery byte in volts (tenths of a volt).
#[must_use]
pub fn battery_v(raw: u8) -> f64 {
    f64::from(raw) / 10.0
}

/// An ENCODER packet's tick count in metres of wheel travel, at `ticks_per_mm`.
#[must_use]
pub fn encoder_m(ticks: i32, ticks_per_mm: f64) -> f64 {
    f64::from(ticks) * (1.0 / (ticks_per_mm * 1000.0))
}

/// Sonar ring of the P2-AT/P2-AT8 (ARIA `p2at.p`).
pub const P2AT_SONARS: [SonarPose; 16] = [
    sp(147.0, 136.0, 90.0),
    sp(193.0, 119.0, 50.0),
    sp(227.0, 79.0, 30.0),
    sp(245.0, 27.0, 10.0),
    sp(245.0, -27.0, -10.0),
    sp(227.0, -79.0, -30.0),
    sp(193.0, -119.0, -50.0),
    sp(147.0, -136.0, -90.0),
    sp(-144.0, -136.0, -90.0),
    sp(-189.0, -119.0, -130.0),
    sp(-223.0, -79.0, -150.0),
    sp(-241.0, -27.0, -170.0),
    sp(-241.0, 27.0, 170.0),
    sp(-223.0, 79.0, 150.0),
    sp(-189.0, 119.0, 130.0),
    sp(-144.0, 136.0, 90.0),
];

/// Sonar ring of the P2-DX (ARIA `p2dx.p`).
pub const P2DX_SONARS: [SonarPose; 16] = [
    sp(69.0, 136.0, 90.0),
    sp(114.0, 119.0, 50.0),
    sp(148.0, 78.0, 30.0),
    sp(166.0, 27.0, 10.0),
    sp(166.0, -27.0, -10.0),
    sp(148.0, -78.0, -30.0),
    sp(114.0, -119.0, -50.0),
    sp(69.0, -136.0, -90.0),
    sp(-157.0, -136.0, -90.0),
    sp(-203.0, -119.0, -130.0),
    sp(-237.0, -78.0, -150.0),
    sp(-255.0, -27.0, -170.0),
    sp(-255.0, 27.0, 170.0),
    sp(-237.0, 78.0, 150.0),
    sp(-203.0, 119.0, 130.0),
    sp(-157.0, 136.0, 90.0),
];

/// Pioneer 2-AT (P2OS): the thesis's Skeeter.
pub const P2AT: RobotParams = RobotParams {
    subclass: "p2at",
    angle_conv: 0.001534,
    dist_conv: 1.32,
    vel_conv: 1.0,
    range_conv: 0.268,
    diff_conv: 0.0034,
    vel2_divisor: 20.0,
    max_velocity_mm_s: 1200.0,
    max_rot_velocity_deg_s: 300.0,
    radius_mm: 500.0,
    width_mm: 505.0,
    length_mm: 626.0,
    sonars: &P2AT_SONARS,
    ticks_per_mm: DEFAULT_TICKS_PER_MM,
};

/// Pioneer 2-AT8 (newer AT): sonar ranges already in mm.
pub const P2AT8: RobotParams = RobotParams {
    subclass: "p2at8",
    range_conv: 1.0,
    ..P2AT
};

/// Pioneer 2-DX.
pub const P2DX: RobotParams = RobotParams {
    subclass: "p2dx",
    angle_conv: 0.001534,
    dist_conv: 0.84,
    vel_conv: 1.0,
    range_conv: 0.268,
    diff_conv: 0.0056,
    vel2_divisor: 20.0,
    max_velocity_mm_s: 2200.0,
    max_rot_velocity_deg_s: 500.0,
    radius_mm: 250.0,
    width_mm: 425.0,
    length_mm: 511.0,
    sonars: &P2DX_SONARS,
    ticks_per_mm: DEFAULT_TICKS_PER_MM,
};

/// Every built-in table.
pub const ALL: &[&RobotParams] = &[&P2AT, &P2AT8, &P2DX];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn conversions_read_signed_positions_and_si_units() {
        // 0x7E4D = 32333 counts: 435 counts behind the origin, −0.5742 m on a P2-AT.
        assert!((P2AT.position_m(0x7E4D) + 0.5742).abs() < 1e-12);
        assert!((P2AT.position_m(1000) - 1.32).abs() < 1e-12);
        assert!((P2AT.heading_rad(1024) - 1024.0 * 0.001534).abs() < 1e-12);
        assert!((P2AT.wheel_m_s(-250) + 0.25).abs() < 1e-12);
        let (v, w) = P2AT.body_velocity(100, 200);
        assert!((v - 0.15).abs() < 1e-12 && (w - 50.0 * 0.0034).abs() < 1e-12);
        assert!((P2AT.sonar_range_m(1000) - 0.268).abs() < 1e-12);
        assert!((P2AT8.sonar_range_m(1000) - 1.0).abs() < 1e-12);
        assert!((P2AT.vel2_m_s(-10) + 0.2).abs() < 1e-12);
        assert!((battery_v(125) - 12.5).abs() < 1e-12);
        assert!((encoder_m(19_000, 19.0) - 1.0).abs() < 1e-12);
    }

    #[test]
    fn signed_positions_agree_with_the_odometry_step_from_zero() {
        use crate::machine::{signed15, unwrap15};
        for raw in (0..=0x1000_u16).chain(0x7000..=0x7FFF) {
            assert_eq!(signed15(raw), unwrap15(0, raw), "{raw:#06x}");
        }
        assert_eq!(signed15(0x3FFF), 0x3FFF);
        assert_eq!(signed15(0x4000), -0x4000);
        assert_eq!(
            signed15(0xFFFF),
            -1,
            "the 16th bit is not part of the count"
        );
    }

    #[test]
    fn lookup_is_case_insensitive_and_strict() {
        assert_eq!(
            RobotParams::for_subclass(b"P2AT").map(|p| p.subclass),
            Some("p2at")
        );
        assert_eq!(
            RobotParams::for_subclass(b"p2at8").map(|p| p.range_conv),
            Some(1.0)
        );
        assert_eq!(
            RobotParams::for_subclass(b"p2dx").map(|p| p.dist_conv),
            Some(0.84)
        );
        assert!(RobotParams::for_subclass(b"p3dx-sh").is_none());
        assert!(RobotParams::for_subclass(b"").is_none());
    }

    #[test]
    fn p2at_track_and_mirror_symmetry() {
        assert!((P2AT.track_mm() - 588.235).abs() < 0.01);
        for i in 0..8 {
            let (a, b) = (P2AT_SONARS[i], P2AT_SONARS[7 - i]);
            assert_eq!(
                (a.x_mm, a.y_mm, a.heading_deg),
                (b.x_mm, -b.y_mm, -b.heading_deg)
            );
        }
    }
}

//! Robot parameter tables, chosen by the subclass string of the SYNC2 reply (spec §8).
//!
//! The values are the published ARIA/Saphira parameter files' facts (spec §8 cites them).
//! `p2at` and `p2at8` differ by a factor of 3.7 in the sonar range unit, so picking the table
//! by subclass matters (spec §10 item 11); an unknown subclass is an error unless the caller
//! overrides it ([`crate::machine::Config::params_override`]).

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

    /// The table for `subclass` (case-insensitive), if known.
    #[must_use]
    pub fn for_subclass(subclass: &[u8]) -> Option<&'static RobotParams> {
        ALL.iter()
            .copied()
            .find(|p| p.subclass.as_bytes().eq_ignore_ascii_case(subclass))
    }
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

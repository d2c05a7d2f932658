//! Scooter's parameters: the heading rule and source, target recognition, and every
//! threshold of its agents ([`ScooterConfig`]).

use core::time::Duration;

use ima_hal::{Isometry2, Vector2};

use crate::mission::avoid::AvoidConfig;

/// Which heading-calculation rule to use.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HeadingRule {
    /// The thesis's isosceles rule (bearings only).
    Thesis,
    /// Ranges when known (SES or triangulated), else the thesis rule.
    RangeAware,
}

impl HeadingRule {
    /// `"thesis"` or `"range-aware"`.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Thesis => "thesis",
            Self::RangeAware => "range-aware",
        }
    }
}

/// How Scooter's laser recognises the target among the clusters of the target's size
/// (within [`ScooterConfig::see_distance_m`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TargetRecognition {
    /// Only where the plan expects the target: within
    /// [`ScooterConfig::bearing_tolerance_rad`] of θd (heading plans) or
    /// [`ScooterConfig::match_radius_m`] of the estimated point (point plans). The laser
    /// cannot tell colours, so this is what keeps Scooter off the wrong post of a ring of
    /// equal posts; but near a wrong heading estimate it rejects the real target.
    NearEstimate,
    /// Anywhere in the laser's field of view: the nearest cluster of the target's size is
    /// the target. Models a Scooter that *sees* its target (MISSION.md: "sees target → go to
    /// it"), which in a world with one object of the target's size (the heading experiment)
    /// the laser alone can do.
    InView,
}

impl TargetRecognition {
    /// `"near-estimate"` or `"in-view"`.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::NearEstimate => "near-estimate",
            Self::InView => "in-view",
        }
    }
}

/// Where Scooter's heading θh comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HeadingSource {
    /// The compass alone (absolute, noisy, no drift).
    Compass,
    /// Odometry alone (smooth, drifts).
    Odometry,
    /// Both: odometry increments corrected toward the compass by a complementary filter of
    /// gain [`ScooterConfig::fusion_gain`] per compass reading.
    Fused,
}

/// The brain's parameters. [`Default`] suits the demo; the experiment lowers the cruise speed.
#[derive(Debug, Clone, PartialEq)]
pub struct ScooterConfig {
    /// Scooter's object name in Skeeter's SES (`"scooter"`).
    pub robot_name: String,
    /// Heading-calculation rule.
    pub heading_rule: HeadingRule,
    /// Heading source.
    pub heading_source: HeadingSource,
    /// Forward speed while following a heading or going to the target, m/s.
    pub cruise_speed_m_s: f64,
    /// Largest turn rate commanded, rad/s.
    pub max_turn_rate_rad_s: f64,
    /// Proportional steering gain, (rad/s) per rad of heading error.
    pub steering_gain: f64,
    /// Turn in place when the heading error exceeds this, radians.
    pub turn_in_place_enter_rad: f64,
    /// …and drive again once it is below this, radians (hysteresis).
    pub turn_in_place_exit_rad: f64,
    /// Time constant of the turn-rate low-pass filter, seconds (0 = none).
    pub turn_filter_s: f64,
    /// The "lost" timer: no SES sample for this long makes the heading stale.
    pub lost_after: Duration,
    /// Target reached when the target's centre is this close to Scooter's centre, metres.
    pub reach_distance_m: f64,
    /// Farthest distance (Scooter's centre to the target's centre) at which the laser
    /// identifies the target, metres.
    pub see_distance_m: f64,
    /// How a target-sized laser cluster is recognised as the target.
    pub target_recognition: TargetRecognition,
    /// In every [`TargetRecognition`]: a target-sized cluster counts only when it is still
    /// target-sized with range jumps of up to this joined, metres. Laser noise (±50 mm on
    /// the SICK) splits a wider object into target-sized pieces: Skeeter's outline, or a
    /// wall seen at a slant; joined, they are Skeeter or the wall again. A post stands
    /// clear of what is behind it, so joining leaves it whole; a post less than this in front
    /// of something else is not recognised.
    pub join_gap_m: f64,
    /// Target objects' diameter, metres.
    pub target_diameter_m: f64,
    /// Accepted difference between a cluster's width and the target diameter, metres.
    pub diameter_tolerance_m: f64,
    /// Bearing-only plans: a cluster is the target when its common-frame bearing from Scooter
    /// is within this of θd, radians.
    pub bearing_tolerance_rad: f64,
    /// Point plans: a cluster is the target when its centre is within this of the expected
    /// target position, metres.
    pub match_radius_m: f64,
    /// Skeeter's footprint diameter, metres: the range-aware rule ranges Skeeter with the
    /// laser when it is in view (a cluster of this width where Skeeter's bearing says it is).
    pub skeeter_diameter_m: f64,
    /// Accepted difference between a cluster's width and Skeeter's diameter, metres.
    pub skeeter_diameter_tolerance_m: f64,
    /// A Skeeter cluster must lie within this of the direction θ1 + 180°, radians.
    pub skeeter_bearing_tolerance_rad: f64,
    /// Largest range jump between neighbouring beams of one cluster, metres.
    pub cluster_gap_m: f64,
    /// The laser's pose on the robot.
    pub laser_mount: Isometry2,
    /// Ranges at or above this are "no return", metres.
    pub laser_max_range_m: f64,
    /// Complementary-filter gain for [`HeadingSource::Fused`], per compass reading, (0, 1].
    pub fusion_gain: f64,
    /// Scooter's common-frame heading when its odometry was reset, radians.
    pub odometry_heading_offset_rad: f64,
    /// Period of [`ScooterSay::Status`](super::ScooterSay::Status) messages.
    pub status_period: Duration,
    /// While `request-heading` runs (lost), keep following the last plan for at most this
    /// long after the last SES sample, then stand still (Skeeter may simply have lost sight
    /// of the target or of Scooter for a scan or two, e.g. when Scooter hides the target).
    pub coast_for: Duration,
    /// Stop homing this close to Skeeter's estimated position, metres.
    pub home_stop_distance_m: f64,
    /// At most this many samples are averaged into the target position estimate.
    pub max_target_samples: usize,
    /// Time constant smoothing the avoider's steering direction (in the common frame), so
    /// that the 3° steps of its candidate search and laser noise at a corridor's edge do not
    /// reach the wheels, seconds (0 = none).
    pub avoid_smoothing_s: f64,
    /// Obstacle avoidance.
    pub avoid: AvoidConfig,
    /// Obstacle points that leave the laser's field of view (beside and behind Scooter)
    /// are remembered, carried by dead reckoning, while within this distance of Scooter,
    /// metres (0 = no memory). Without it, going round the end of a wall the avoider no
    /// longer sees the post beside it, turns toward it, sees it again, turns away: chatter.
    pub obstacle_memory_m: f64,
    /// The laser is *missing* when its last usable scan is older than this: Scooter then
    /// commands zero forward speed (turning in place stays allowed), because an unseen path
    /// is not a clear one.
    pub laser_stale_after: Duration,
    /// A scan is usable when at least this fraction of its beams is usable (a valid
    /// measurement, or — with [`ScooterConfig::laser_no_return_is_clear`] — a clean "no
    /// return"); a blinded scan (dazzled, read errors, empty) counts as no scan at all.
    pub laser_min_usable_fraction: f64,
    /// A beam flagged only `NO_RETURN`/`ABOVE_MAX_RANGE` means "nothing within range" (the
    /// SICK in an open field), so it counts as usable. Off: only valid measurements count.
    pub laser_no_return_is_clear: bool,
    /// A `scooter` record in an SES sample at most this old (its sensing time against the
    /// sample's send time) means Skeeter sees Scooter: a call-back ends even if the
    /// `scooter-found` broadcast was lost.
    pub found_record_max_age: Duration,
}

impl ScooterConfig {
    /// Whether a laser cluster `width_m` wide has the target's size
    /// ([`target_diameter_m`](Self::target_diameter_m) ±
    /// [`diameter_tolerance_m`](Self::diameter_tolerance_m)).
    #[must_use]
    pub fn is_target_width(&self, width_m: f64) -> bool {
        (width_m - self.target_diameter_m).abs() <= self.diameter_tolerance_m
    }
}

impl Default for ScooterConfig {
    fn default() -> Self {
        Self {
            robot_name: "scooter".to_owned(),
            heading_rule: HeadingRule::RangeAware,
            heading_source: HeadingSource::Fused,
            cruise_speed_m_s: 0.3,
            max_turn_rate_rad_s: 1.0,
            steering_gain: 1.5,
            turn_in_place_enter_rad: 30f64.to_radians(),
            turn_in_place_exit_rad: 8f64.to_radians(),
            turn_filter_s: 0.0,
            lost_after: Duration::from_secs(12),
            reach_distance_m: 0.8,
            see_distance_m: 1.6,
            target_recognition: TargetRecognition::NearEstimate,
            join_gap_m: 0.3,
            target_diameter_m: 0.30,
            diameter_tolerance_m: 0.15,
            bearing_tolerance_rad: 40f64.to_radians(),
            match_radius_m: 0.8,
            skeeter_diameter_m: 0.66,
            skeeter_diameter_tolerance_m: 0.2,
            skeeter_bearing_tolerance_rad: 15f64.to_radians(),
            cluster_gap_m: 0.10,
            laser_mount: Isometry2::new(Vector2::new(0.2, 0.0), 0.0),
            laser_max_range_m: 8.0,
            fusion_gain: 0.05,
            odometry_heading_offset_rad: 0.0,
            status_period: Duration::from_secs(1),
            coast_for: Duration::from_secs(30),
            home_stop_distance_m: 1.2,
            max_target_samples: 12,
            avoid_smoothing_s: 0.6,
            avoid: AvoidConfig::default(),
            obstacle_memory_m: 1.5,
            laser_stale_after: Duration::from_millis(500),
            laser_min_usable_fraction: 0.5,
            laser_no_return_is_clear: true,
            found_record_max_age: Duration::from_secs(10),
        }
    }
}

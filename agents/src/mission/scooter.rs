//! Scooter's brain: the scout's heading agent, heading-calculation agent, obstacle agent,
//! target finder and SAN, as one pure, sans-IO object.
//!
//! # Frames (read this first)
//!
//! * **Common frame.** The thesis measures every bearing "relative to the robots' common
//!   initial heading" (MISSION.md): at the start both robots face the same way, and that
//!   direction is azimuth 0, counter-clockwise positive, radians in (−π, π]. Skeeter never
//!   moves, so its own robot frame *is* the common frame, centred on Skeeter: the bearings
//!   θ1 (Skeeter → Scooter) and θ2 (Skeeter → target) of its SES records are common-frame
//!   bearings.
//! * **Scooter's heading θh** is its heading in the common frame. From the compass
//!   ([`ScooterBrain::handle_compass`] takes it *already in the common frame*: the runtime
//!   subtracts the compass reading taken while the robots faced the common initial heading),
//!   from odometry (odometry heading + [`ScooterConfig::odometry_heading_offset_rad`], 0 when
//!   the odometry was reset while facing the common initial heading), or both fused
//!   ([`HeadingSource`]).
//! * **Dead-reckoning frame (DR).** Scooter's own position estimate: odometry distance
//!   increments rotated by θh, so its axes are the common frame's but its origin is wherever
//!   Scooter started (Scooter does not know where it is relative to Skeeter unless ranges
//!   tell it). Only *differences* of DR positions are used (triangulation, target estimate).
//! * **Robot frame**: x forward, y left (as `ima_hal`); the laser is mounted at
//!   [`ScooterConfig::laser_mount`].
//!
//! # Heading rules ([`HeadingRule`], from [`crate::heading`])
//!
//! Each time a new SES sample arrives the heading-calculation agent computes a plan:
//!
//! * **Thesis**: `θd = thesis_heading(θ1, θ2)`, a fixed common-frame heading followed until
//!   the next sample (the isosceles assumption; exact only on the SES circle).
//! * **Range-aware**: with Skeeter's ranges (SES) for both the target and Scooter — or
//!   Scooter's range triangulated from its own motion between two samples
//!   ([`crate::heading::triangulate_scout_range`]) — the target's position is known
//!   relative to Scooter: `T_dr = P_dr(t_rec) + Dt·u(θ2) − Ds·u(θ1)`, where `P_dr(t_rec)` is
//!   Scooter's DR position when Skeeter's camera saw it. The plan is that **point** (a
//!   running mean over the samples of the current target, which averages range noise out),
//!   and the heading to it is recomputed at every step from dead reckoning. Without ranges
//!   it falls back to the thesis rule.
//!
//! A sample without both Scooter and the target keeps the previous plan and does not reset
//! the lost timer; one where the rule is degenerate (the thesis rule with θ1 = θ2) keeps
//! the previous plan.
//!
//! The controller turns toward θd: in place while the error exceeds
//! [`ScooterConfig::turn_in_place_enter_rad`] (until it is below `…_exit_rad`), otherwise
//! it drives at the cruise speed with proportional steering, the turn rate clamped to
//! [`ScooterConfig::max_turn_rate_rad_s`] (an optional low-pass, `turn_filter_s`, is off by
//! default: its lag made the robot overshoot after turning in place).
//!
//! # Smooth avoidance
//!
//! The [avoider](super::avoid) locks the side it goes round an obstacle on and has
//! enter/exit hysteresis; the brain low-pass filters its steering direction in the common
//! frame ([`ScooterConfig::avoid_smoothing_s`]) so the candidate search's 3° steps and laser
//! noise at a corridor's edge never reach the wheels. In the simulation (`ima-sim` test
//! `a_barrel_on_the_way_is_avoided_smoothly_with_the_real_laser_model`) the turn rate
//! changes sign once while going round a barrel: away, then back. Going round a wide
//! obstacle (a wall with the target behind it) the avoider keeps its side locked while the
//! goal is out of the laser's view, and obstacle points that leave the view are remembered
//! ([`ScooterConfig::obstacle_memory_m`]) so that the post beside Scooter is not forgotten.
//!
//! # Ranges
//!
//! Scooter's range from Skeeter comes, best first, from its own laser (a cluster of
//! Skeeter's diameter where θ1 + 180° says Skeeter is, fresh within 3 s), from the SES
//! record, or from triangulation over two samples.
//!
//! # Behaviours (MISSION.md, "Scooter's SAN"; `agents/networks/scooter.toml`)
//!
//! Agents set the SAN's conditions every step; the SAN spreads activation and the module it
//! fires — or, on a step where nothing reaches the threshold, the executable module with the
//! highest activation (ties by weight) — runs. The brain runs the network with
//! `reset_fired = false` so the running module does not alternate with a runner-up.
//!
//! | condition | set by |
//! |---|---|
//! | `heading-stale` | no SES sample for [`ScooterConfig::lost_after`] (or none yet for this target) |
//! | `heading-known` | a plan exists and is not stale |
//! | `target-in-view` | a laser cluster of the target's diameter where Scooter expects the target |
//! | `obstacle-near` / `path-clear` | the [avoider](super::avoid) (hysteresis) |
//! | `called-back` / `skeeter-in-view` | broadcast `scooter-lost` / `scooter-found`, or an SES sample with a fresh `scooter` record (ends the call-back; the broadcast may be lost) |
//! | `asked-for-target` | broadcast `target-query` |
//! | `at-target` | the target cluster within [`ScooterConfig::reach_distance_m`] |
//! | `path-clear` needs eyes | no usable scan for [`ScooterConfig::laser_stale_after`]: forward speed 0 (turning in place allowed) |
//! | `skeeter-notified` | `target-reached` sent |
//!
//! | module | action |
//! |---|---|
//! | `request-heading` | send [`ScooterSay::RequestHeading`] (again every `lost_after`); coast on the last plan for [`ScooterConfig::coast_for`] after the last sample, then stand still |
//! | `follow-heading` | turn to θd and drive |
//! | `move-to-target` | drive to the laser cluster |
//! | `avoid-obstacle` | steer round the obstacle on a locked side |
//! | `move-to-home` | drive toward Skeeter (DR position when known, else θ1 + 180°) and stop 1.2 m short |
//! | `reply-target-query` | send [`ScooterSay::TargetReply`] (motion continues): "yes" when the laser tracks the target, it was reached, or a fresh plan for it exists (Skeeter's view of the target may just be hidden by Scooter); "no" otherwise |
//! | `notify-skeeter` | send [`ScooterSay::TargetReached`] and stop; resent every [`ScooterConfig::status_period`] until the target's `Accomplished`/`Failed` (or a new target) is heard |
//!
//! Without a target the brain is [`Behaviour::Idle`] (not a SAN module) and stands still.

use core::f64::consts::PI;
use core::time::Duration;
use std::collections::VecDeque;

use ima_hal::base::{Odometry, VelocityCommand};
use ima_hal::laser::LaserScan;
use ima_hal::{Instant, Isometry2, Point2, Vector2, normalize_angle};

use super::avoid::{AvoidConfig, Avoider};
use super::msg::{Broadcast, Emergency, MissionEvent, Pose};
use crate::heading::{self, Observation, Range, RangeSource};
use crate::san::Network;
use crate::ses::shared::{SharedForm, SharedRecord};

/// Scooter's SAN network, `agents/networks/scooter.toml`.
pub const SCOOTER_NETWORK_TOML: &str = include_str!("../../networks/scooter.toml");

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
    /// [`TargetRecognition::InView`] only: a target-sized cluster counts only when it is
    /// still target-sized with range jumps of up to this joined (laser noise splits a wider
    /// object — Skeeter — into target-sized pieces; joined, they are Skeeter again), metres.
    pub in_view_join_gap_m: f64,
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
    /// Period of [`ScooterSay::Status`] messages.
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
            in_view_join_gap_m: 0.3,
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

/// What Scooter hears on the broadcast channel (the runtime converts the typed mission
/// messages of `mission::msg` into these).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ScooterHeard {
    /// A new target colour was accepted (by Skeeter): go find it.
    TargetAccepted {
        /// Colour name, as in the SES.
        colour: String,
    },
    /// The mission for `colour` ended (accomplished or failed): stop and wait (ignored when
    /// `colour` is not the current target).
    MissionEnded {
        /// The target that ended.
        colour: String,
    },
    /// Skeeter's stress call `scooter-lost`: come home.
    ScooterLost,
    /// Skeeter sees Scooter again (`scooter-found`).
    ScooterFound,
    /// Skeeter asks whether Scooter sees the target (`target-query`).
    TargetQuery {
        /// Colour asked about.
        colour: String,
    },
}

/// What Scooter says (the runtime turns these into broadcasts or Peer Agent requests).
#[derive(Debug, Clone, PartialEq)]
pub enum ScooterSay {
    /// `target-reached` (text = colour).
    TargetReached {
        /// Colour reached.
        colour: String,
    },
    /// `target-reply` (text = `"<colour> yes"` / `"<colour> no"`).
    TargetReply {
        /// Colour asked about.
        colour: String,
        /// Whether Scooter sees it with its laser, has reached it, or holds a fresh plan
        /// for it (a sample with the target within [`ScooterConfig::lost_after`]).
        seen: bool,
    },
    /// Periodic `Status`.
    Status {
        /// Running module.
        behaviour: Behaviour,
        /// DR pose `(x_m, y_m, θh_rad)`.
        pose: (f64, f64, f64),
    },
    /// The lost timer ran out: ask Skeeter for a fresh SES sample.
    RequestHeading,
}

impl ScooterSay {
    /// The text of a `target-reply` emergency: `"<colour> yes"` or `"<colour> no"`.
    #[must_use]
    pub fn reply_text(colour: &str, seen: bool) -> String {
        format!("{colour} {}", if seen { "yes" } else { "no" })
    }

    /// The broadcast to send for this output, from robot `robot` (`"scooter"`), with `san`
    /// as the status's SAN summary. `None` for [`ScooterSay::RequestHeading`], which is for
    /// the Peer Agent client (re-request Skeeter's `ses` source), not the broadcast channel.
    /// The status pose is the DR pose in millimetres and milliradians.
    #[must_use]
    pub fn to_broadcast(&self, robot: &str, san: &str) -> Option<Broadcast> {
        match self {
            Self::TargetReached { colour } => Some(Broadcast::emergency(
                robot,
                Emergency::TargetReached {
                    colour: colour.clone(),
                },
            )),
            Self::TargetReply { colour, seen } => Some(Broadcast::emergency(
                robot,
                Emergency::TargetReply {
                    colour: colour.clone(),
                    seen: *seen,
                },
            )),
            Self::Status { behaviour, pose } => {
                let fix = |v: f64| {
                    if v.is_finite() {
                        (v * 1000.0)
                            .round()
                            .clamp(f64::from(i32::MIN), f64::from(i32::MAX))
                            as i32
                    } else {
                        0
                    }
                };
                Some(Broadcast::status(
                    robot,
                    behaviour.as_str(),
                    san,
                    Some(Pose {
                        x_mm: fix(pose.0),
                        y_mm: fix(pose.1),
                        theta_mrad: fix(pose.2),
                    }),
                ))
            }
            Self::RequestHeading => None,
        }
    }
}

impl ScooterHeard {
    /// What a broadcast means to Scooter, if anything: a target `Accepted` by anyone but
    /// Scooter (the commander's request or Skeeter's acceptance) starts a target;
    /// `Accomplished`/`Failed` or a commander's `target-cancel` ends it; the emergencies
    /// `scooter-lost`, `scooter-found` and `target-query` map one to one. Everything else (statuses, Scooter's own
    /// emergencies) is `None`.
    #[must_use]
    pub fn from_broadcast(b: &Broadcast, me: &str) -> Option<Self> {
        if b.robot() == me {
            return None;
        }
        match b {
            Broadcast::Mission { event, target, .. } => Some(match event {
                MissionEvent::Accepted => Self::TargetAccepted {
                    colour: target.clone(),
                },
                MissionEvent::Accomplished | MissionEvent::Failed => Self::MissionEnded {
                    colour: target.clone(),
                },
            }),
            Broadcast::Emergency { emergency, .. } => match emergency {
                Emergency::ScooterLost => Some(Self::ScooterLost),
                Emergency::ScooterFound => Some(Self::ScooterFound),
                Emergency::TargetQuery { colour } => Some(Self::TargetQuery {
                    colour: colour.clone(),
                }),
                // The commander withdrew the target: for Scooter, that target is over.
                Emergency::TargetCancel { colour } => Some(Self::MissionEnded {
                    colour: colour.clone(),
                }),
                // Fleet stop and resume are obeyed by the stack, below the brain.
                Emergency::TargetReply { .. }
                | Emergency::TargetReached { .. }
                | Emergency::FleetStop { .. }
                | Emergency::FleetResume => None,
            },
            Broadcast::Status { .. } => None,
        }
    }
}

/// The running behaviour: a module of Scooter's SAN, or idle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Behaviour {
    /// No target: standing still (not a SAN module).
    Idle,
    /// `request-heading`.
    RequestHeading,
    /// `follow-heading`.
    FollowHeading,
    /// `move-to-target`.
    MoveToTarget,
    /// `avoid-obstacle`.
    AvoidObstacle,
    /// `move-to-home`.
    MoveToHome,
    /// `reply-target-query`.
    ReplyTargetQuery,
    /// `notify-skeeter`.
    NotifySkeeter,
}

impl Behaviour {
    /// The SAN module name (`"idle"` for [`Behaviour::Idle`]).
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Idle => "idle",
            Self::RequestHeading => "request-heading",
            Self::FollowHeading => "follow-heading",
            Self::MoveToTarget => "move-to-target",
            Self::AvoidObstacle => "avoid-obstacle",
            Self::MoveToHome => "move-to-home",
            Self::ReplyTargetQuery => "reply-target-query",
            Self::NotifySkeeter => "notify-skeeter",
        }
    }

    /// The behaviour of a SAN module name.
    #[must_use]
    pub fn from_module(name: &str) -> Option<Self> {
        Some(match name {
            "request-heading" => Self::RequestHeading,
            "follow-heading" => Self::FollowHeading,
            "move-to-target" => Self::MoveToTarget,
            "avoid-obstacle" => Self::AvoidObstacle,
            "move-to-home" => Self::MoveToHome,
            "reply-target-query" => Self::ReplyTargetQuery,
            "notify-skeeter" => Self::NotifySkeeter,
            _ => return None,
        })
    }
}

/// The heading-calculation agent's current plan.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Plan {
    /// Follow a fixed common-frame heading, radians (thesis rule, or range-aware fallback).
    Heading(f64),
    /// Go to a point in the DR frame (range-aware rule with ranges).
    Point(Vector2),
}

/// One step's outputs.
#[derive(Debug, Clone, PartialEq)]
pub struct ScooterOutput {
    /// Velocity command for the base.
    pub command: VelocityCommand,
    /// The running behaviour (SAN module).
    pub behaviour: Behaviour,
    /// Messages to send, oldest first.
    pub messages: Vec<ScooterSay>,
}

/// A laser cluster (robot frame).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cluster {
    /// Estimated centre of the round object that produced it (robot frame).
    pub centre: Point2,
    /// Chord between its first and last returns, metres.
    pub width_m: f64,
}

/// Split a scan into clusters of neighbouring valid returns (range jumps ≤ `gap_m`); each
/// cluster's centre is taken `radius_m` behind its nearest return, in the direction of its
/// returns' mean (a round object's near surface is what the laser sees). Clusters touching the first or
/// last beam are dropped (they may be cut by the field of view).
#[must_use]
pub fn laser_clusters(
    scan: &LaserScan,
    mount: &Isometry2,
    max_range_m: f64,
    gap_m: f64,
    radius_m: f64,
) -> Vec<Cluster> {
    let mut out = Vec::new();
    let mut cur: Vec<Point2> = Vec::new();
    let mut first_beam = true;
    let mut prev_r: Option<f64> = None;
    let n = scan.len();
    let flush = |cur: &mut Vec<Point2>, touches_edge: bool, out: &mut Vec<Cluster>| {
        if let (Some(a), Some(b)) = (cur.first(), cur.last())
            && !touches_edge
            && cur.len() >= 2
        {
            let width_m = (b - a).norm();
            let mean = cur.iter().fold(Vector2::zeros(), |s, p| s + p.coords) / cur.len() as f64;
            // Direction: the returns' mean; distance: the nearest return (the point of a
            // round object nearest the sensor lies on the line to its centre) + radius.
            let origin = mount.translation.vector;
            let los = mean - origin;
            let nearest = cur
                .iter()
                .map(|p| (p.coords - origin).norm())
                .fold(f64::INFINITY, f64::min);
            let centre = if los.norm() > 1e-9 && nearest.is_finite() {
                Point2::from(origin + los.normalize() * (nearest + radius_m))
            } else {
                Point2::from(mean)
            };
            out.push(Cluster { centre, width_m });
        }
        cur.clear();
    };
    let mut cur_starts_at_edge = false;
    for (i, (angle, range, flags)) in scan.beams().enumerate() {
        let r = f64::from(range);
        let valid = flags.is_valid() && r.is_finite() && r > 0.0 && r < max_range_m;
        if !valid {
            flush(&mut cur, cur_starts_at_edge, &mut out);
            prev_r = None;
            first_beam = false;
            continue;
        }
        if prev_r.is_some_and(|p| (p - r).abs() > gap_m) {
            flush(&mut cur, cur_starts_at_edge, &mut out);
        }
        if cur.is_empty() {
            cur_starts_at_edge = first_beam;
        }
        cur.push(mount * Point2::new(r * angle.cos(), r * angle.sin()));
        prev_r = Some(r);
        first_beam = false;
        if i + 1 == n {
            flush(&mut cur, true, &mut out);
        }
    }
    flush(&mut cur, cur_starts_at_edge, &mut out);
    out
}

#[derive(Debug, Clone, Copy)]
struct SesFix {
    /// θ1, common frame.
    scout_bearing: f64,
    /// DR position when Skeeter saw Scooter.
    p_rec: Vector2,
}

/// Scooter's brain. See the [module docs](self).
#[derive(Debug, Clone)]
pub struct ScooterBrain {
    cfg: ScooterConfig,
    san: Network,
    avoider: Avoider,
    // Target and mission.
    target: Option<String>,
    target_since: Instant,
    plan: Option<Plan>,
    target_samples: VecDeque<Vector2>,
    skeeter_dr: Option<Vector2>,
    last_fix: Option<SesFix>,
    last_ses_at: Option<Instant>,
    last_request_at: Option<Instant>,
    reached: bool,
    notified: bool,
    called_back: bool,
    query: Option<String>,
    // Heading and position.
    compass: Option<f64>,
    odo_prev: Option<Isometry2>,
    odo_theta: Option<f64>,
    fused: Option<f64>,
    dr: Vector2,
    history: VecDeque<(Instant, Vector2)>,
    // Laser.
    points: Vec<Point2>,
    /// Obstacle points of the last scan and the memory, DR frame.
    seen_dr: Vec<Vector2>,
    target_fix: Option<(Instant, Vector2)>,
    /// The last target reached and where (DR frame): the object Scooter stands next to is
    /// not the next target, whatever a stale heading points at.
    reached_target: Option<(String, Vector2)>,
    skeeter_fix: Option<(Instant, Vector2)>,
    avoid_heading: Option<f64>,
    /// When the last *usable* scan arrived.
    laser_at: Option<Instant>,
    last_notify_at: Option<Instant>,
    // Controller.
    last_step: Option<Instant>,
    omega: f64,
    turning_in_place: bool,
    behaviour: Behaviour,
    motion: Behaviour,
    last_status: Option<Instant>,
    outbox: Vec<ScooterSay>,
}

const HISTORY_LEN: usize = 4096;

/// A goal: common-frame direction, distance (∞ if unknown), and a DR circle that is not an
/// obstacle (the target itself, or Skeeter when homing).
type Goal = (f64, f64, Option<(Vector2, f64)>);
const TARGET_FIX_TTL: Duration = Duration::from_secs(3);

fn unit(theta: f64) -> Vector2 {
    Vector2::new(theta.cos(), theta.sin())
}

impl ScooterBrain {
    /// A brain with `cfg`, no target, at DR origin.
    ///
    /// # Panics
    /// Never: the embedded network is checked by a unit test.
    #[must_use]
    pub fn new(cfg: ScooterConfig) -> Self {
        #[allow(clippy::expect_used)] // the embedded TOML is a constant, tested
        let mut san = Network::from_toml(SCOOTER_NETWORK_TOML).expect("scooter.toml is valid");
        let mut params = *san.params();
        params.reset_fired = false;
        san.set_params(params);
        Self {
            avoider: Avoider::new(cfg.avoid),
            cfg,
            san,
            target: None,
            target_since: Instant::ZERO,
            plan: None,
            target_samples: VecDeque::new(),
            skeeter_dr: None,
            last_fix: None,
            last_ses_at: None,
            last_request_at: None,
            reached: false,
            notified: false,
            called_back: false,
            query: None,
            compass: None,
            odo_prev: None,
            odo_theta: None,
            fused: None,
            dr: Vector2::zeros(),
            history: VecDeque::new(),
            points: Vec::new(),
            seen_dr: Vec::new(),
            target_fix: None,
            reached_target: None,
            skeeter_fix: None,
            avoid_heading: None,
            laser_at: None,
            last_notify_at: None,
            last_step: None,
            omega: 0.0,
            turning_in_place: false,
            behaviour: Behaviour::Idle,
            motion: Behaviour::Idle,
            last_status: None,
            outbox: Vec::new(),
        }
    }

    /// The parameters.
    #[must_use]
    pub fn config(&self) -> &ScooterConfig {
        &self.cfg
    }

    /// The SAN (for status summaries and traces).
    #[must_use]
    pub fn san(&self) -> &Network {
        &self.san
    }

    /// The current target colour.
    #[must_use]
    pub fn target(&self) -> Option<&str> {
        self.target.as_deref()
    }

    /// The running behaviour after the last [`ScooterBrain::step`].
    #[must_use]
    pub fn behaviour(&self) -> Behaviour {
        self.behaviour
    }

    /// The current plan of the heading-calculation agent.
    #[must_use]
    pub fn plan(&self) -> Option<Plan> {
        self.plan
    }

    /// Scooter's heading θh in the common frame from the configured source, if known.
    #[must_use]
    pub fn heading(&self) -> Option<f64> {
        match self.cfg.heading_source {
            HeadingSource::Compass => self.compass,
            HeadingSource::Odometry => self.odo_theta,
            HeadingSource::Fused => self.fused,
        }
    }

    /// Scooter's DR position (metres, common-frame axes, origin where it started).
    #[must_use]
    pub fn dr_position(&self) -> Vector2 {
        self.dr
    }

    /// The laser obstacles remembered for avoidance, in the DR frame (metres).
    #[must_use]
    pub fn obstacles_dr(&self) -> &[Vector2] {
        &self.seen_dr
    }

    /// The desired common-frame heading θd right now (from the plan), if any.
    #[must_use]
    pub fn desired_heading(&self) -> Option<f64> {
        match self.plan? {
            Plan::Heading(h) => Some(h),
            Plan::Point(p) => {
                let d = p - self.dr;
                (d.norm() > 1e-6).then(|| d.y.atan2(d.x))
            }
        }
    }

    /// Whether the target was reached (and Skeeter told).
    #[must_use]
    pub fn reached(&self) -> bool {
        self.reached
    }

    /// Set a new target colour directly (same as hearing [`ScooterHeard::TargetAccepted`]).
    pub fn set_target(&mut self, colour: &str, now: Instant) {
        self.target = Some(colour.to_owned());
        self.target_since = now;
        self.plan = None;
        self.target_samples.clear();
        self.last_ses_at = None;
        self.last_request_at = None;
        self.reached = false;
        self.notified = false;
        self.last_notify_at = None;
        self.target_fix = None;
        self.avoider.reset();
    }

    /// A typed broadcast from the channel (see [`ScooterHeard::from_broadcast`]); returns
    /// whether it meant anything to Scooter.
    pub fn handle_broadcast(&mut self, b: &Broadcast, now: Instant) -> bool {
        match ScooterHeard::from_broadcast(b, &self.cfg.robot_name) {
            Some(h) => {
                self.handle_heard(&h, now);
                true
            }
            None => false,
        }
    }

    /// A one-line SAN summary for status broadcasts: the true conditions, cut to
    /// [`super::msg::MAX_WIRE_STR`] bytes at a char boundary.
    #[must_use]
    pub fn san_summary(&self) -> String {
        let s = self
            .san
            .condition_names()
            .filter(|c| self.san.condition(c) == Some(true))
            .collect::<Vec<_>>()
            .join(",");
        super::msg::truncate_wire_str(&s).to_owned()
    }

    /// A broadcast heard (already typed). A repeated acceptance of the current target
    /// (the commander's, then Skeeter's) does not restart it.
    pub fn handle_heard(&mut self, heard: &ScooterHeard, now: Instant) {
        match heard {
            ScooterHeard::TargetAccepted { colour } => {
                // Also while reached: the commander polls a processing target, and Skeeter
                // echoes it, until the outcome comes; that must not restart the search.
                if self.target.as_deref() != Some(colour.as_str()) {
                    self.set_target(colour, now);
                }
            }
            ScooterHeard::MissionEnded { colour } => {
                if self.target.as_deref() != Some(colour.as_str()) {
                    return;
                }
                self.target = None;
                self.plan = None;
                self.avoider.reset();
            }
            ScooterHeard::ScooterLost => self.called_back = true,
            ScooterHeard::ScooterFound => self.called_back = false,
            ScooterHeard::TargetQuery { colour } => self.query = Some(colour.clone()),
        }
    }

    /// A compass heading, radians, **common frame** (see the module docs).
    pub fn handle_compass(&mut self, heading_rad: f64, _now: Instant) {
        if !heading_rad.is_finite() {
            return;
        }
        let h = normalize_angle(heading_rad);
        self.compass = Some(h);
        self.fused = Some(match self.fused {
            None => h,
            Some(f) => {
                let k = self.cfg.fusion_gain.clamp(0.0, 1.0);
                normalize_angle(f + k * normalize_angle(h - f))
            }
        });
    }

    /// An odometry reading: advances the odometry heading, the fused heading and the DR
    /// position (distance increments rotated by θh at mid-step).
    pub fn handle_odometry(&mut self, odo: &Odometry, now: Instant) {
        let pose = odo.pose;
        let th = pose.rotation.angle();
        if !(th.is_finite() && pose.translation.vector.iter().all(|c| c.is_finite())) {
            return;
        }
        let odo_theta = normalize_angle(th + self.cfg.odometry_heading_offset_rad);
        let (ds, dth) = match self.odo_prev {
            Some(prev) => {
                let d = pose.translation.vector - prev.translation.vector;
                let pth = prev.rotation.angle();
                (d.x * pth.cos() + d.y * pth.sin(), normalize_angle(th - pth))
            }
            None => (0.0, 0.0),
        };
        // A jump too big to be finite is a reset of the odometry, not a motion.
        let (ds, dth) = if ds.is_finite() && dth.is_finite() {
            (ds, dth)
        } else {
            (0.0, 0.0)
        };
        self.odo_prev = Some(pose);
        self.odo_theta = Some(odo_theta);
        if let Some(f) = self.fused.as_mut() {
            *f = normalize_angle(*f + dth);
        } else if self.cfg.heading_source != HeadingSource::Compass {
            self.fused = Some(odo_theta);
        }
        if let Some(h) = self.heading() {
            let next = self.dr + unit(h - dth / 2.0) * ds;
            if next.iter().all(|c| c.is_finite()) {
                self.dr = next;
            }
        }
        if self.history.len() >= HISTORY_LEN {
            self.history.pop_front();
        }
        self.history.push_back((now, self.dr));
    }

    /// Scooter's DR position at `t` (linear interpolation in the history; the nearest end
    /// outside it).
    fn dr_at(&self, t: Instant) -> Vector2 {
        let mut before: Option<(Instant, Vector2)> = None;
        for &(at, p) in &self.history {
            if at >= t {
                return match before {
                    Some((a0, p0)) if at > a0 => {
                        let span = at.saturating_duration_since(a0).as_secs_f64();
                        let x = t.saturating_duration_since(a0).as_secs_f64() / span;
                        p0 + (p - p0) * x
                    }
                    _ => p,
                };
            }
            before = Some((at, p));
        }
        self.dr
    }

    fn best<'a>(form: &'a SharedForm, name: &str) -> Option<&'a SharedRecord> {
        form.records
            .iter()
            .filter(|r| r.object == name && r.bearing.azimuth_rad.is_finite())
            .max_by(|a, b| a.confidence.total_cmp(&b.confidence))
    }

    /// A sample of Skeeter's SES: the heading-calculation agent computes a new plan when it
    /// holds both Scooter and the current target. Returns whether a plan was made.
    ///
    /// A fresh `scooter` record ([`ScooterConfig::found_record_max_age`]) also ends a
    /// call-back: Skeeter sees Scooter, whether or not its `scooter-found` arrived.
    pub fn handle_ses(&mut self, form: &SharedForm, now: Instant) -> bool {
        if self.called_back
            && form.records.iter().any(|r| {
                r.object == self.cfg.robot_name
                    && r.bearing.azimuth_rad.is_finite()
                    && form.sent_at.saturating_duration_since(r.time)
                        <= self.cfg.found_record_max_age
            })
        {
            self.called_back = false;
        }
        let Some(colour) = self.target.clone() else {
            return false;
        };
        let (Some(me), Some(tg)) = (
            Self::best(form, &self.cfg.robot_name),
            Self::best(form, &colour),
        ) else {
            return false;
        };
        // Sensing time on our clock: now − (sent_at − time).
        let age = form.sent_at.saturating_duration_since(me.time);
        let seen_at = Instant::from_micros(
            now.as_micros()
                .saturating_sub(u64::try_from(age.as_micros()).unwrap_or(u64::MAX)),
        );
        let theta1 = me.bearing.azimuth_rad;
        let theta2 = tg.bearing.azimuth_rad;
        let p_rec = self.dr_at(seen_at);
        let previous = self.last_fix.replace(SesFix {
            scout_bearing: theta1,
            p_rec,
        });
        self.last_ses_at = Some(now);
        let plan = match self.cfg.heading_rule {
            _ if !(theta1.is_finite() && theta2.is_finite()) => None,
            HeadingRule::Thesis => heading::thesis_heading(theta1, theta2)
                .ok()
                .map(Plan::Heading),
            HeadingRule::RangeAware => {
                let valid =
                    |r: Option<f64>| r.filter(|m| m.is_finite() && (0.0..=MAX_RANGE_M).contains(m));
                // Scooter's own laser fix on Skeeter (fresh) beats Skeeter's estimate.
                let laser = self
                    .skeeter_fix
                    .filter(|(at, _)| now.saturating_duration_since(*at) <= TARGET_FIX_TTL)
                    .map(|(_, s)| Range {
                        metres: (s - p_rec).norm(),
                        source: RangeSource::Sensor,
                    });
                let scout = laser.or_else(|| {
                    valid(me.range_m).map(|metres| Range {
                        metres,
                        source: RangeSource::Ses,
                    })
                });
                let scout = scout.or_else(|| {
                    let prev = previous?;
                    heading::triangulate_scout_range(prev.scout_bearing, theta1, p_rec - prev.p_rec)
                        .ok()
                        .filter(|m| m.is_finite() && (0.0..=MAX_RANGE_M).contains(m))
                        .map(|metres| Range {
                            metres,
                            source: RangeSource::Triangulated,
                        })
                });
                let target = valid(tg.range_m).map(|metres| Range {
                    metres,
                    source: RangeSource::Ses,
                });
                match (scout, target) {
                    (Some(s), Some(t))
                        if (p_rec + unit(theta2) * t.metres - unit(theta1) * s.metres)
                            .iter()
                            .all(|c| c.is_finite()) =>
                    {
                        let rel = unit(theta2) * t.metres - unit(theta1) * s.metres;
                        self.skeeter_dr = Some(p_rec - unit(theta1) * s.metres);
                        if self.target_samples.len() >= self.cfg.max_target_samples.max(1) {
                            self.target_samples.pop_front();
                        }
                        self.target_samples.push_back(p_rec + rel);
                        let n = self.target_samples.len() as f64;
                        let mean = self
                            .target_samples
                            .iter()
                            .fold(Vector2::zeros(), |a, p| a + p)
                            / n;
                        Some(Plan::Point(mean))
                    }
                    (s, t) => heading::range_aware_heading(&Observation {
                        scout_range: s,
                        target_range: t,
                        ..Observation::bearings(theta1, theta2)
                    })
                    .ok()
                    .map(|e| Plan::Heading(e.heading_rad)),
                }
            }
        };
        match plan {
            Some(p) if plan_is_finite(p) => {
                self.plan = Some(p);
                true
            }
            _ => false,
        }
    }

    /// A laser scan: obstacle points for the avoider, and the target search.
    ///
    /// A scan that is not usable ([`ScooterConfig::laser_min_usable_fraction`]) is dropped:
    /// it neither clears the path nor refreshes the laser's age.
    pub fn handle_laser(&mut self, scan: &LaserScan, now: Instant) {
        if !self.scan_usable(scan) {
            return;
        }
        avoid_points(scan, &self.cfg, &mut self.points);
        self.laser_at = Some(now);
        let Some(h) = self.heading() else {
            self.seen_dr.clear();
            return;
        };
        self.remember_obstacles(scan, h);
        if let Some(fix) = self.last_fix {
            let expected = normalize_angle(fix.scout_bearing + PI);
            let sr = self.cfg.skeeter_diameter_m / 2.0;
            let best = laser_clusters(
                scan,
                &self.cfg.laser_mount,
                self.cfg.laser_max_range_m,
                self.cfg.cluster_gap_m,
                sr,
            )
            .into_iter()
            .filter(|c| {
                (c.width_m - self.cfg.skeeter_diameter_m).abs()
                    <= self.cfg.skeeter_diameter_tolerance_m
            })
            .filter_map(|c| {
                let d = nalgebra_rotate(h, c.centre.coords);
                let err = normalize_angle(d.y.atan2(d.x) - expected).abs();
                (err <= self.cfg.skeeter_bearing_tolerance_rad).then_some((self.dr + d, err))
            })
            .min_by(|a, b| a.1.total_cmp(&b.1));
            if let Some((p, _)) = best {
                self.skeeter_fix = Some((now, p));
            }
        }
        if self.target.is_none() || self.reached {
            return;
        }
        let r = self.cfg.target_diameter_m / 2.0;
        let clusters = laser_clusters(
            scan,
            &self.cfg.laser_mount,
            self.cfg.laser_max_range_m,
            self.cfg.cluster_gap_m,
            r,
        );
        let target_sized = |c: &Cluster| {
            (c.width_m - self.cfg.target_diameter_m).abs() <= self.cfg.diameter_tolerance_m
        };
        // In-view recognition: the same clusters with bigger range jumps joined; a piece of
        // a wider object is no target.
        let joined: Vec<Cluster> = if self.cfg.target_recognition == TargetRecognition::InView {
            laser_clusters(
                scan,
                &self.cfg.laser_mount,
                self.cfg.laser_max_range_m,
                self.cfg.in_view_join_gap_m.max(self.cfg.cluster_gap_m),
                r,
            )
        } else {
            Vec::new()
        };
        let whole = |c: &Cluster| {
            self.cfg.target_recognition != TargetRecognition::InView
                || joined.iter().any(|j| {
                    target_sized(j) && (j.centre - c.centre).norm() <= self.cfg.diameter_tolerance_m
                })
        };
        let to_dr = |c: &Point2| self.dr + nalgebra_rotate(h, c.coords);
        // The previous target (another colour) is not this one.
        let previous = self
            .reached_target
            .as_ref()
            .filter(|(colour, _)| self.target.as_ref() != Some(colour))
            .map(|(_, p)| *p);
        let expected_point = match self.plan {
            Some(Plan::Point(p)) => Some(p),
            _ => None,
        };
        // While the target is being tracked, it is where we saw it last.
        let tracked = self
            .target_fix
            .filter(|(at, _)| now.saturating_duration_since(*at) <= TARGET_FIX_TTL)
            .map(|(_, p)| p);
        let best = clusters
            .iter()
            .filter(|c| {
                target_sized(c) && c.centre.coords.norm() <= self.cfg.see_distance_m && whole(c)
            })
            .filter_map(|c| {
                let p = to_dr(&c.centre);
                if previous.is_some_and(|q| (p - q).norm() <= self.cfg.match_radius_m) {
                    return None;
                }
                let score = if let Some(t) = tracked {
                    (p - t).norm()
                } else if self.cfg.target_recognition == TargetRecognition::InView {
                    // Nearest first; any distance within sight matches.
                    return Some((p, c.centre.coords.norm()));
                } else if let Some(e) = expected_point {
                    (p - e).norm()
                } else {
                    let hd = self.desired_heading()?;
                    let d = p - self.dr;
                    let err = normalize_angle(d.y.atan2(d.x) - hd).abs();
                    return (err <= self.cfg.bearing_tolerance_rad).then_some((p, err));
                };
                (score <= self.cfg.match_radius_m).then_some((p, score))
            })
            .min_by(|a, b| a.1.total_cmp(&b.1));
        if let Some((p, _)) = best {
            self.target_fix = Some((now, p));
        }
    }

    /// Add the remembered obstacle points that are out of the laser's view now to
    /// `self.points` ([`ScooterConfig::obstacle_memory_m`]); remember this scan's points.
    fn remember_obstacles(&mut self, scan: &LaserScan, h: f64) {
        const MAX_MEMORY: usize = 4096;
        let radius = self.cfg.obstacle_memory_m;
        if !(radius.is_finite() && radius > 0.0) || scan.is_empty() {
            self.seen_dr.clear();
            return;
        }
        let first = scan.angle_rad(0);
        let last = scan.angle_rad(scan.len().saturating_sub(1));
        let (lo, hi) = (first.min(last), first.max(last));
        let margin = 1f64.to_radians();
        let mount_inv = self.cfg.laser_mount.inverse();
        let dr = self.dr;
        let kept: Vec<(Vector2, Point2)> = self
            .seen_dr
            .iter()
            .filter_map(|m| {
                let rel = m - dr;
                let dist = rel.norm();
                if dist.is_nan() || dist > radius {
                    return None;
                }
                let robot = Point2::from(nalgebra_rotate(-h, rel));
                let in_laser = mount_inv * robot;
                let a = in_laser.y.atan2(in_laser.x);
                (a < lo - margin || a > hi + margin).then_some((*m, robot))
            })
            .take(MAX_MEMORY)
            .collect();
        self.seen_dr.clear();
        self.seen_dr.extend(
            self.points
                .iter()
                .map(|p| dr + nalgebra_rotate(h, p.coords)),
        );
        for (m, robot) in kept {
            self.seen_dr.push(m);
            self.points.push(robot);
        }
    }

    /// Whether enough of a scan's beams are usable (see [`ScooterConfig`]).
    fn scan_usable(&self, scan: &LaserScan) -> bool {
        use ima_hal::laser::BeamFlags;
        let n = scan.len();
        if n == 0 {
            return false;
        }
        let errors = [
            BeamFlags::DAZZLED,
            BeamFlags::OVERFLOW,
            BeamFlags::LOW_SIGNAL,
            BeamFlags::READ_ERROR,
            BeamFlags::RESERVED,
        ];
        let usable = scan
            .beams()
            .filter(|(_, r, f)| {
                if f.is_valid() {
                    r.is_finite() && *r >= 0.0
                } else {
                    self.cfg.laser_no_return_is_clear && !errors.iter().any(|e| f.contains(*e))
                }
            })
            .count();
        let need = self.cfg.laser_min_usable_fraction;
        let need = if need.is_finite() {
            need.clamp(0.0, 1.0)
        } else {
            1.0
        };
        usable > 0 && usable as f64 >= need * n as f64
    }

    /// Whether a usable scan came within [`ScooterConfig::laser_stale_after`].
    #[must_use]
    pub fn laser_fresh(&self, now: Instant) -> bool {
        self.laser_at
            .is_some_and(|t| now.saturating_duration_since(t) <= self.cfg.laser_stale_after)
    }

    fn target_in_view(&self, now: Instant) -> Option<Vector2> {
        self.target_fix
            .filter(|(at, _)| now.saturating_duration_since(*at) <= TARGET_FIX_TTL)
            .map(|(_, p)| p)
    }

    fn heading_stale(&self, now: Instant) -> bool {
        match self.last_ses_at {
            None => true,
            Some(t) => now.saturating_duration_since(t) > self.cfg.lost_after,
        }
    }

    /// Set the SAN's conditions from the agents' state.
    fn feed_san(&mut self, now: Instant, obstacle: bool) {
        let stale = self.heading_stale(now) && !self.reached;
        let tiv = self.target_in_view(now).is_some();
        let conds: [(&str, bool); 11] = [
            ("heading-stale", stale),
            ("heading-known", self.plan.is_some() && !stale),
            ("target-in-view", tiv),
            ("path-clear", !obstacle),
            ("obstacle-near", obstacle),
            ("called-back", self.called_back),
            ("skeeter-in-view", !self.called_back),
            ("asked-for-target", self.query.is_some()),
            ("query-answered", self.query.is_none()),
            ("at-target", self.reached),
            ("skeeter-notified", self.notified),
        ];
        for (name, v) in conds {
            let _ = self.san.set_condition(name, v);
        }
    }

    /// Step the SAN and choose among the modules that move or wait (`request-heading`,
    /// `follow-heading`, `move-to-target`, `avoid-obstacle`, `move-to-home`): the fired
    /// module, else the executable one with the highest activation. The two message-only
    /// modules (`reply-target-query`, `notify-skeeter`) are reflexes handled in
    /// [`ScooterBrain::step`].
    fn select(&mut self) -> Behaviour {
        let trace = self.san.step();
        let allowed =
            |b: &Behaviour| !matches!(b, Behaviour::ReplyTargetQuery | Behaviour::NotifySkeeter);
        if let Some(b) = trace
            .fired
            .as_deref()
            .and_then(Behaviour::from_module)
            .filter(allowed)
        {
            return b;
        }
        trace
            .modules
            .iter()
            .filter(|m| m.executable)
            .filter_map(|m| {
                Behaviour::from_module(&m.name)
                    .filter(allowed)
                    .map(|b| (b, m.activation))
            })
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .map_or(Behaviour::Idle, |(b, _)| b)
    }

    /// One control step at `now`: the agents set the SAN's conditions, the SAN chooses the
    /// running module, and the module acts. A reached target makes `notify-skeeter` run
    /// (send `target-reached` once, then stand still); a pending query is answered in the
    /// same step whatever moves (`reply-target-query` is reported for that step).
    pub fn step(&mut self, now: Instant) -> ScooterOutput {
        let dt = self
            .last_step
            .map_or(0.0, |t| now.saturating_duration_since(t).as_secs_f64());
        self.last_step = Some(now);
        let h = self.heading();
        if let (Some(t), Some(_), false) = (self.target_in_view(now), h, self.reached)
            && self.target.is_some()
            && (t - self.dr).norm() <= self.cfg.reach_distance_m
        {
            self.reached = true;
            self.reached_target = self.target.clone().zip(Some(t));
        }
        // Obstacle agent: judge the path toward the current goal.
        let obstacle = match (self.goal(now), h) {
            (Some((dir, dist, ignore)), Some(h)) if self.target.is_some() && !self.reached => {
                let ignore =
                    ignore.map(|(p, r)| (Point2::from(nalgebra_rotate(-h, p - self.dr)), r));
                Some(
                    self.avoider
                        .decide(&self.points, normalize_angle(dir - h), dist, ignore),
                )
            }
            _ => {
                self.avoider.reset();
                None
            }
        };
        let raw = obstacle.filter(|d| d.active).map(|d| d.steer_rad);
        // Smooth the avoider's direction in the common frame (first-order, τ).
        let steer = match (raw, h) {
            (Some(s), Some(h)) => {
                let target = normalize_angle(h + s);
                let tau = self.cfg.avoid_smoothing_s.max(0.0);
                let k = if tau > 0.0 && dt > 0.0 {
                    dt / (tau + dt)
                } else {
                    1.0
                };
                let f = match self.avoid_heading {
                    Some(f) => normalize_angle(f + k * normalize_angle(target - f)),
                    None => target,
                };
                self.avoid_heading = Some(f);
                Some(normalize_angle(f - h))
            }
            _ => {
                self.avoid_heading = None;
                raw
            }
        };
        self.feed_san(now, steer.is_some());
        let chosen = self.select();
        let motion = if self.reached && self.target.is_some() {
            Behaviour::NotifySkeeter
        } else if self.target.is_none() && !(self.called_back && chosen == Behaviour::MoveToHome) {
            Behaviour::Idle
        } else {
            chosen
        };
        let mut command = VelocityCommand::ZERO;
        match motion {
            Behaviour::RequestHeading => {
                let due = self
                    .last_request_at
                    .is_none_or(|t| now.saturating_duration_since(t) >= self.cfg.lost_after);
                if due {
                    self.last_request_at = Some(now);
                    self.outbox.push(ScooterSay::RequestHeading);
                }
                let coast = self.plan.is_some()
                    && self
                        .last_ses_at
                        .is_some_and(|t| now.saturating_duration_since(t) <= self.cfg.coast_for);
                if coast {
                    command = self.drive(self.goal_for(motion, now), h, steer, dt);
                } else {
                    self.omega = 0.0;
                }
            }
            Behaviour::NotifySkeeter => {
                // Sent at once, then again every status period until the mission event
                // for this target (or a new target) arrives: a broadcast may be lost.
                let due = self
                    .last_notify_at
                    .is_none_or(|t| now.saturating_duration_since(t) >= self.cfg.status_period);
                if (!self.notified || due)
                    && let Some(colour) = self.target.clone()
                {
                    self.notified = true;
                    self.last_notify_at = Some(now);
                    self.outbox.push(ScooterSay::TargetReached { colour });
                }
                self.omega = 0.0;
                self.avoider.reset();
            }
            Behaviour::FollowHeading
            | Behaviour::MoveToTarget
            | Behaviour::AvoidObstacle
            | Behaviour::MoveToHome => {
                command = self.drive(self.goal_for(motion, now), h, steer, dt);
            }
            Behaviour::Idle | Behaviour::ReplyTargetQuery => self.omega = 0.0,
        }
        // Blind (no usable scan lately): never drive forward into an unseen path.
        if !self.laser_fresh(now) {
            command.v_m_s = 0.0;
        }
        let command = self.sanitize(command);
        let mut behaviour = motion;
        if let Some(colour) = self.query.take() {
            // "Yes" when the laser tracks the target, or while a fresh plan for it exists:
            // Skeeter may just not see the target because Scooter stands in front of it.
            let seen = self.target.as_deref() == Some(colour.as_str())
                && (self.target_in_view(now).is_some()
                    || (self.plan.is_some() && !self.heading_stale(now))
                    || self.reached);
            self.outbox.push(ScooterSay::TargetReply { colour, seen });
            behaviour = Behaviour::ReplyTargetQuery;
        }
        self.behaviour = behaviour;
        self.motion = motion;
        if self
            .last_status
            .is_none_or(|t| now.saturating_duration_since(t) >= self.cfg.status_period)
        {
            self.last_status = Some(now);
            self.outbox.push(ScooterSay::Status {
                behaviour,
                pose: (self.dr.x, self.dr.y, h.unwrap_or(0.0)),
            });
        }
        ScooterOutput {
            command,
            behaviour,
            messages: std::mem::take(&mut self.outbox),
        }
    }

    /// The last guard before the wheels: a command that is not finite is no motion, and
    /// speeds are clamped to [0, cruise] and ±max turn rate.
    fn sanitize(&mut self, c: VelocityCommand) -> VelocityCommand {
        let max_v = finite_or_zero(self.cfg.cruise_speed_m_s).abs();
        let max_w = finite_or_zero(self.cfg.max_turn_rate_rad_s).abs();
        if !(c.v_m_s.is_finite() && c.omega_rad_s.is_finite()) {
            self.omega = 0.0;
            return VelocityCommand::ZERO;
        }
        VelocityCommand::new(
            c.v_m_s.clamp(0.0, max_v),
            c.omega_rad_s.clamp(-max_w, max_w),
        )
    }

    fn home_goal(&self) -> Option<Goal> {
        match self.skeeter_dr {
            Some(s) => {
                let d = s - self.dr;
                Some((d.y.atan2(d.x), d.norm(), Some((s, 0.6))))
            }
            None => self
                .last_fix
                .map(|f| (normalize_angle(f.scout_bearing + PI), f64::INFINITY, None)),
        }
    }

    fn target_goal(&self, now: Instant) -> Option<Goal> {
        let t = self.target_in_view(now)?;
        let d = t - self.dr;
        let r = self.cfg.target_diameter_m / 2.0 + 0.15;
        Some((d.y.atan2(d.x), d.norm(), Some((t, r))))
    }

    fn plan_goal(&self) -> Option<Goal> {
        let r = self.cfg.target_diameter_m / 2.0 + 0.35;
        match self.plan? {
            Plan::Heading(hd) => Some((hd, f64::INFINITY, None)),
            Plan::Point(p) => {
                let d = p - self.dr;
                Some((d.y.atan2(d.x), d.norm(), Some((p, r))))
            }
        }
    }

    /// The goal of a motion module.
    fn goal_for(&self, b: Behaviour, now: Instant) -> Option<Goal> {
        match b {
            Behaviour::MoveToHome => self.home_goal(),
            Behaviour::MoveToTarget => self.target_goal(now).or_else(|| self.plan_goal()),
            Behaviour::FollowHeading | Behaviour::RequestHeading => self.plan_goal(),
            _ => self.goal(now),
        }
    }

    /// The goal by state priority (called back → home; target in view → target; else the
    /// plan), which the obstacle agent judges the path toward: (common-frame direction,
    /// distance, a DR circle that is not an obstacle).
    fn goal(&self, now: Instant) -> Option<Goal> {
        if self.called_back {
            return self.home_goal();
        }
        self.target_goal(now).or_else(|| self.plan_goal())
    }

    /// The controller: turn toward the goal (or the avoider's steering direction).
    fn drive(
        &mut self,
        goal: Option<Goal>,
        h: Option<f64>,
        avoid_steer: Option<f64>,
        dt: f64,
    ) -> VelocityCommand {
        let (Some(h), Some((dir, dist, _))) = (h, goal) else {
            self.omega = 0.0;
            return VelocityCommand::ZERO;
        };
        // Robot-frame error: the avoider's direction already is robot-frame.
        let err = avoid_steer.unwrap_or_else(|| normalize_angle(dir - h));
        let homing_done = self.called_back && dist <= self.cfg.home_stop_distance_m;
        if self.turning_in_place {
            if err.abs() < self.cfg.turn_in_place_exit_rad {
                self.turning_in_place = false;
            }
        } else if err.abs() > self.cfg.turn_in_place_enter_rad {
            self.turning_in_place = true;
        }
        let max_w = self.cfg.max_turn_rate_rad_s.abs();
        let mut w = (self.cfg.steering_gain * err).clamp(-max_w, max_w);
        if self.turning_in_place {
            // Turn in place at a good fraction of the maximum rate.
            w = err.signum() * (self.cfg.steering_gain * err.abs()).clamp(0.3 * max_w, max_w);
        }
        let tau = self.cfg.turn_filter_s.max(0.0);
        self.omega = if tau > 0.0 && dt > 0.0 {
            self.omega + (w - self.omega) * (dt / (tau + dt))
        } else {
            w
        };
        if homing_done {
            self.omega = 0.0;
            return VelocityCommand::ZERO;
        }
        let v = if self.turning_in_place {
            0.0
        } else {
            self.cfg.cruise_speed_m_s
        };
        VelocityCommand::new(v, self.omega)
    }
}

/// Ranges (SES, triangulated) beyond this are not believed, metres.
const MAX_RANGE_M: f64 = 1000.0;

fn finite_or_zero(v: f64) -> f64 {
    if v.is_finite() { v } else { 0.0 }
}

fn plan_is_finite(p: Plan) -> bool {
    match p {
        Plan::Heading(h) => h.is_finite(),
        Plan::Point(v) => v.iter().all(|c| c.is_finite()),
    }
}

/// Rotate a vector by `theta`.
fn nalgebra_rotate(theta: f64, v: Vector2) -> Vector2 {
    let (s, c) = theta.sin_cos();
    Vector2::new(c * v.x - s * v.y, s * v.x + c * v.y)
}

fn avoid_points(scan: &LaserScan, cfg: &ScooterConfig, out: &mut Vec<Point2>) {
    super::avoid::scan_points(scan, &cfg.laser_mount, cfg.laser_max_range_m, out);
}

#[cfg(test)]
mod tests {
    use super::*;
    use ima_hal::laser::BeamFlags;

    const RED: &str = "red";

    fn t(ms: u64) -> Instant {
        Instant::from_millis(ms)
    }

    fn rec(object: &str, bearing_deg: f64, range_m: Option<f64>, time: Instant) -> SharedRecord {
        SharedRecord {
            object: object.to_owned(),
            bearing: crate::ses::Direction::horizontal(bearing_deg.to_radians()),
            range_m,
            confidence: 1.0,
            time,
        }
    }

    fn form(records: Vec<SharedRecord>, sent_at: Instant) -> SharedForm {
        SharedForm {
            source_robot: "skeeter".to_owned(),
            sent_at,
            records,
        }
    }

    /// A brain whose laser never goes stale after one clear scan at t = 0 (tests that are
    /// not about the laser's age; `blind_scooter_does_not_drive_forward` uses the default).
    fn brain(rule: HeadingRule) -> ScooterBrain {
        let cfg = ScooterConfig {
            heading_rule: rule,
            heading_source: HeadingSource::Compass,
            laser_stale_after: Duration::MAX,
            ..ScooterConfig::default()
        };
        let mut b = ScooterBrain::new(cfg);
        b.handle_compass(0.0, t(0));
        b.handle_odometry(&Odometry::origin(), t(0));
        b.handle_laser(&clear_scan(), t(0));
        b
    }

    /// 181 beams, nothing within range.
    fn clear_scan() -> LaserScan {
        let mut s = LaserScan::new(-PI / 2.0, PI / 180.0);
        for _ in 0..181 {
            s.push(f32::NAN, BeamFlags::NO_RETURN).unwrap();
        }
        s
    }

    /// 181 beams, all dazzled.
    fn blinded_scan() -> LaserScan {
        let mut s = LaserScan::new(-PI / 2.0, PI / 180.0);
        for _ in 0..181 {
            s.push(f32::NAN, BeamFlags::DAZZLED).unwrap();
        }
        s
    }

    #[test]
    fn blind_scooter_does_not_drive_forward() {
        let mut b = ScooterBrain::new(ScooterConfig {
            heading_rule: HeadingRule::Thesis,
            heading_source: HeadingSource::Compass,
            ..ScooterConfig::default()
        });
        b.handle_compass(0.0, t(0));
        b.handle_odometry(&Odometry::origin(), t(0));
        b.set_target(RED, t(0));
        // θd = 180° + 0° − 88° … a plan almost straight ahead: θ1 = 0°, θ2 = 179° → 90.5°;
        // face it so that the controller drives rather than turns in place.
        let f = form(
            vec![rec("scooter", 0.0, None, t(0)), rec(RED, 179.0, None, t(0))],
            t(0),
        );
        assert!(b.handle_ses(&f, t(0)));
        b.handle_compass(b.desired_heading().unwrap(), t(0));
        // No scan ever: no forward speed.
        let out = b.step(t(100));
        assert_eq!(out.behaviour, Behaviour::FollowHeading);
        assert_eq!(out.command.v_m_s, 0.0, "no laser yet");
        // A clear scan: drive.
        b.handle_laser(&clear_scan(), t(200));
        let out = b.step(t(300));
        assert!(out.command.v_m_s > 0.0);
        // 0.5 s later still fresh, 0.6 s later stale.
        assert!(b.step(t(700)).command.v_m_s > 0.0);
        assert_eq!(b.step(t(800)).command.v_m_s, 0.0, "stale laser");
        // A blinded scan does not count as a clear path.
        b.handle_laser(&blinded_scan(), t(900));
        assert_eq!(b.step(t(950)).command.v_m_s, 0.0, "blinded scan");
        // Turning in place stays allowed while blind.
        b.handle_compass(b.desired_heading().unwrap() + 1.0, t(1000));
        let out = b.step(t(1000));
        assert_eq!(out.command.v_m_s, 0.0);
        assert!(out.command.omega_rad_s < 0.0, "turns back toward θd");
        // A configurable age.
        let mut b2 = ScooterBrain::new(ScooterConfig {
            laser_stale_after: Duration::from_secs(2),
            ..b.config().clone()
        });
        b2.handle_laser(&clear_scan(), t(0));
        assert!(b2.laser_fresh(t(1900)) && !b2.laser_fresh(t(2100)));
    }

    fn close_deg(a: f64, b_deg: f64) -> bool {
        normalize_angle(a - b_deg.to_radians()).abs() < 1e-3
    }

    /// A tiny world for closed-loop tests: a unicycle and round things, a 181-beam laser.
    struct Mini {
        x: f64,
        y: f64,
        th: f64,
        circles: Vec<([f64; 2], f64)>,
    }

    impl Mini {
        fn scan(&self, mount: &Isometry2) -> LaserScan {
            let mut s = LaserScan::new(-PI / 2.0, PI / 180.0);
            let sensor = Isometry2::new(Vector2::new(self.x, self.y), self.th) * mount;
            let o = sensor.translation.vector;
            for k in 0..181 {
                let dir = sensor.rotation.angle() - PI / 2.0 + f64::from(k) * PI / 180.0;
                let d = unit(dir);
                let mut best = f64::INFINITY;
                for (c, r) in &self.circles {
                    let f = o - Vector2::new(c[0], c[1]);
                    let b = f.dot(&d);
                    let cc = f.dot(&f) - r * r;
                    let disc = b * b - cc;
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

        fn odo(&self, start: (f64, f64, f64)) -> Odometry {
            let s = Isometry2::new(Vector2::new(start.0, start.1), start.2);
            let p = Isometry2::new(Vector2::new(self.x, self.y), self.th);
            Odometry {
                pose: s.inverse() * p,
                v_m_s: 0.0,
                omega_rad_s: 0.0,
            }
        }

        fn advance(&mut self, c: VelocityCommand, dt: f64) {
            self.th = normalize_angle(self.th + c.omega_rad_s * dt);
            self.x += c.v_m_s * dt * self.th.cos();
            self.y += c.v_m_s * dt * self.th.sin();
        }
    }

    #[test]
    fn embedded_network_loads_and_every_module_has_a_behaviour() {
        let b = ScooterBrain::new(ScooterConfig::default());
        for m in b.san().module_names() {
            let beh = Behaviour::from_module(m).unwrap();
            assert_eq!(beh.as_str(), m);
        }
        assert_eq!(b.behaviour(), Behaviour::Idle);
    }

    #[test]
    fn idle_without_a_target() {
        let mut b = brain(HeadingRule::Thesis);
        let out = b.step(t(0));
        assert_eq!(out.behaviour, Behaviour::Idle);
        assert_eq!(out.command, VelocityCommand::ZERO);
        assert!(!b.handle_ses(&form(vec![rec("scooter", 0.0, None, t(0))], t(0)), t(0)));
    }

    #[test]
    fn thesis_rule_plans_the_isosceles_heading_and_turns_in_place() {
        let mut b = brain(HeadingRule::Thesis);
        b.set_target(RED, t(0));
        let f = form(
            vec![
                rec("scooter", 0.0, Some(3.0), t(0)),
                rec(RED, 90.0, Some(5.0), t(0)),
            ],
            t(0),
        );
        assert!(b.handle_ses(&f, t(0)));
        // Ranges are ignored by the thesis rule: θd = 135°.
        assert!(matches!(b.plan(), Some(Plan::Heading(h)) if close_deg(h, 135.0)));
        b.step(t(0));
        let out = b.step(t(50));
        assert_eq!(out.behaviour, Behaviour::FollowHeading);
        assert_eq!(out.command.v_m_s, 0.0, "turns in place first");
        assert!(
            out.command.omega_rad_s > 0.0,
            "counter-clockwise toward 135°"
        );
    }

    /// A thesis-rule brain with `recognition`, heading for red: Scooter at the origin facing
    /// 0°, Skeeter's SES puts red at 90° of it, so the estimate is θd = 135°.
    fn estimate_at_135_deg(recognition: TargetRecognition) -> ScooterBrain {
        let mut b = ScooterBrain::new(ScooterConfig {
            target_recognition: recognition,
            ..brain(HeadingRule::Thesis).config().clone()
        });
        b.handle_compass(0.0, t(0));
        b.handle_odometry(&Odometry::origin(), t(0));
        b.set_target(RED, t(0));
        let f = form(
            vec![rec("scooter", 0.0, None, t(0)), rec(RED, 90.0, None, t(0))],
            t(0),
        );
        assert!(b.handle_ses(&f, t(0)));
        b
    }

    #[test]
    fn in_view_recognition_takes_the_target_far_off_a_wrong_estimate() {
        // θd = 135° (thesis rule), but the post stands 1 m straight ahead (0°): 135° off
        // the estimate. Near-estimate recognition ignores it; in-view recognition goes to it.
        for (recognition, expected) in [
            (TargetRecognition::NearEstimate, Behaviour::FollowHeading),
            (TargetRecognition::InView, Behaviour::MoveToTarget),
        ] {
            let mut b = estimate_at_135_deg(recognition);
            let w = Mini {
                x: 0.0,
                y: 0.0,
                th: 0.0,
                circles: vec![([1.0, 0.0], 0.15)],
            };
            let mount = b.config().laser_mount;
            b.handle_laser(&w.scan(&mount), t(0));
            let out = b.step(t(0));
            assert_eq!(out.behaviour, expected, "{}", recognition.as_str());
        }
    }

    #[test]
    fn in_view_recognition_ignores_target_sized_pieces_of_a_wider_object() {
        // Two posts side by side, 0.25 m apart in range: each is target-sized on its own,
        // together (joined over the range jump) a 0.6 m object — like Skeeter split in two
        // by laser noise. A lone post at the same place is taken.
        let pair = vec![([1.5, -0.16], 0.15), ([1.75, 0.1], 0.15)];
        let lone = vec![([1.5, -0.16], 0.15)];
        for (circles, expected) in [
            (pair, Behaviour::FollowHeading),
            (lone, Behaviour::MoveToTarget),
        ] {
            let mut b = estimate_at_135_deg(TargetRecognition::InView);
            let w = Mini {
                x: 0.0,
                y: 0.0,
                th: 0.0,
                circles,
            };
            let mount = b.config().laser_mount;
            let scan = w.scan(&mount);
            let c = b.config();
            let fine = laser_clusters(&scan, &mount, c.laser_max_range_m, c.cluster_gap_m, 0.15);
            let joined = laser_clusters(&scan, &mount, c.laser_max_range_m, 0.3, 0.15);
            let sized = |v: &[Cluster]| {
                v.iter()
                    .filter(|k| (k.width_m - c.target_diameter_m).abs() <= c.diameter_tolerance_m)
                    .count()
            };
            if expected == Behaviour::FollowHeading {
                assert_eq!(
                    (sized(&fine), sized(&joined)),
                    (2, 0),
                    "{fine:?} {joined:?}"
                );
            }
            b.handle_laser(&scan, t(0));
            assert_eq!(b.step(t(0)).behaviour, expected);
        }
    }

    #[test]
    fn range_aware_rule_with_ranges_plans_the_target_point() {
        let mut b = brain(HeadingRule::RangeAware);
        b.set_target(RED, t(0));
        let f = form(
            vec![
                rec("scooter", 0.0, Some(2.0), t(0)),
                rec(RED, 90.0, Some(5.0), t(0)),
            ],
            t(0),
        );
        assert!(b.handle_ses(&f, t(0)));
        // Scooter at (2, 0), target at (0, 5): relative (−2, 5) from the DR origin.
        match b.plan() {
            Some(Plan::Point(p)) => assert!((p - Vector2::new(-2.0, 5.0)).norm() < 1e-3),
            other => panic!("{other:?}"),
        }
        assert!(close_deg(
            b.desired_heading().unwrap(),
            5f64.atan2(-2.0).to_degrees()
        ));
    }

    #[test]
    fn range_aware_rule_falls_back_to_the_thesis_rule_without_ranges() {
        let mut b = brain(HeadingRule::RangeAware);
        b.set_target(RED, t(0));
        let f = form(
            vec![rec("scooter", 0.0, None, t(0)), rec(RED, -90.0, None, t(0))],
            t(0),
        );
        assert!(b.handle_ses(&f, t(0)));
        assert!(matches!(b.plan(), Some(Plan::Heading(h)) if close_deg(h, -135.0)));
    }

    #[test]
    fn range_aware_rule_triangulates_scooter_from_its_own_motion() {
        let mut b = brain(HeadingRule::RangeAware);
        b.set_target(RED, t(0));
        // Scooter at (1, 0) in the common frame; Skeeter sees it at 0°.
        let f0 = form(
            vec![
                rec("scooter", 0.0, None, t(0)),
                rec(RED, 180.0, Some(4.0), t(0)),
            ],
            t(0),
        );
        assert!(b.handle_ses(&f0, t(0)));
        assert!(matches!(b.plan(), Some(Plan::Heading(_))));
        // It drives 1 m along +y (heading 90°) to (1, 1): Skeeter sees it at 45°.
        b.handle_compass(PI / 2.0, t(1000));
        b.handle_odometry(
            &Odometry {
                pose: Isometry2::new(Vector2::new(0.0, 0.0), PI / 2.0),
                ..Odometry::origin()
            },
            t(1000),
        );
        b.handle_odometry(
            &Odometry {
                pose: Isometry2::new(Vector2::new(0.0, 1.0), PI / 2.0),
                ..Odometry::origin()
            },
            t(2000),
        );
        let f1 = form(
            vec![
                rec("scooter", 45.0, None, t(2000)),
                rec(RED, 180.0, Some(4.0), t(2000)),
            ],
            t(2000),
        );
        assert!(b.handle_ses(&f1, t(2000)));
        match b.plan() {
            // DR = common − (1, 0): the target (−4, 0) is DR (−5, 0).
            Some(Plan::Point(p)) => assert!((p - Vector2::new(-5.0, 0.0)).norm() < 1e-2, "{p}"),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn ses_record_times_are_placed_on_the_local_clock() {
        let mut b = brain(HeadingRule::RangeAware);
        b.set_target(RED, t(0));
        // Scooter drives along +x: at 1 s it is at DR (0.1, 0), at 3 s at (0.3, 0).
        for k in 0..=30 {
            let x = 0.01 * f64::from(k);
            b.handle_odometry(
                &Odometry {
                    pose: Isometry2::new(Vector2::new(x, 0.0), 0.0),
                    ..Odometry::origin()
                },
                t(100 * u64::try_from(k).unwrap()),
            );
        }
        // Skeeter's clock is 1000 s ahead; the record was sensed 2 s before sending, which
        // arrives at our 3 s: sensed at our 1 s, when DR was (0.1, 0).
        let sk = |ms: u64| Instant::from_millis(1_000_000 + ms);
        let f = form(
            vec![
                rec("scooter", 0.0, Some(2.0), sk(1000)),
                rec(RED, 90.0, Some(2.0), sk(1000)),
            ],
            sk(3000),
        );
        assert!(b.handle_ses(&f, t(3000)));
        match b.plan() {
            // Target relative to Scooter then: (−2, 2); DR (0.1, 0) + that.
            Some(Plan::Point(p)) => assert!((p - Vector2::new(-1.9, 2.0)).norm() < 1e-6, "{p}"),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn lost_timer_requests_a_heading_coasts_then_stops() {
        let mut b = brain(HeadingRule::Thesis);
        b.set_target(RED, t(0));
        // No sample yet: request at once, standing still.
        let out = b.step(t(0));
        assert_eq!(out.behaviour, Behaviour::RequestHeading);
        assert!(out.messages.contains(&ScooterSay::RequestHeading));
        assert_eq!(out.command, VelocityCommand::ZERO);
        let f = form(
            vec![rec("scooter", 0.0, None, t(0)), rec(RED, 179.0, None, t(0))],
            t(0),
        );
        assert!(b.handle_ses(&f, t(100)));
        b.handle_compass(b.desired_heading().unwrap(), t(150));
        let out = b.step(t(200));
        assert_eq!(out.behaviour, Behaviour::FollowHeading);
        // 13 s later: stale (lost_after 12 s), requests again, coasts on the old heading.
        let out = b.step(t(13_200));
        assert_eq!(out.behaviour, Behaviour::RequestHeading);
        assert!(out.messages.contains(&ScooterSay::RequestHeading));
        assert!(out.command.v_m_s > 0.0, "coasting");
        // Not re-requested before another 12 s.
        let out = b.step(t(14_000));
        assert!(!out.messages.contains(&ScooterSay::RequestHeading));
        let out = b.step(t(25_300));
        assert!(out.messages.contains(&ScooterSay::RequestHeading));
        // Past coast_for (30 s after the sample): stand still.
        let out = b.step(t(31_000));
        assert_eq!(out.behaviour, Behaviour::RequestHeading);
        assert_eq!(out.command, VelocityCommand::ZERO);
    }

    #[test]
    fn called_back_goes_home_until_found() {
        let mut b = brain(HeadingRule::Thesis);
        b.set_target(RED, t(0));
        // Skeeter sees Scooter at 90°: home is at 270° = −90° from Scooter.
        let f = form(
            vec![rec("scooter", 90.0, None, t(0)), rec(RED, 0.0, None, t(0))],
            t(0),
        );
        b.handle_ses(&f, t(0));
        b.step(t(0));
        b.handle_broadcast(
            &Broadcast::emergency("skeeter", Emergency::ScooterLost),
            t(100),
        );
        let out = b.step(t(100));
        assert_eq!(out.behaviour, Behaviour::MoveToHome);
        assert!(
            out.command.omega_rad_s < 0.0,
            "turning clockwise toward −90°"
        );
        b.handle_broadcast(
            &Broadcast::emergency("skeeter", Emergency::ScooterFound),
            t(200),
        );
        let out = b.step(t(200));
        assert_eq!(out.behaviour, Behaviour::FollowHeading);
    }

    #[test]
    fn homing_with_ranges_stops_short_of_skeeter() {
        let mut b = brain(HeadingRule::RangeAware);
        b.set_target(RED, t(0));
        let f = form(
            vec![
                rec("scooter", 0.0, Some(1.0), t(0)),
                rec(RED, 90.0, Some(3.0), t(0)),
            ],
            t(0),
        );
        b.handle_ses(&f, t(0));
        b.handle_heard(&ScooterHeard::ScooterLost, t(0));
        let out = b.step(t(0));
        assert_eq!(out.behaviour, Behaviour::MoveToHome);
        assert_eq!(
            out.command,
            VelocityCommand::ZERO,
            "1 m < home_stop_distance"
        );
    }

    #[test]
    fn answers_target_queries_and_keeps_moving() {
        let mut b = brain(HeadingRule::Thesis);
        b.set_target(RED, t(0));
        let f = form(
            vec![rec("scooter", 0.0, None, t(0)), rec(RED, 175.0, None, t(0))],
            t(0),
        );
        b.handle_ses(&f, t(0));
        b.handle_compass(b.desired_heading().unwrap(), t(0));
        let out = b.step(t(0));
        assert_eq!(out.behaviour, Behaviour::FollowHeading);
        let q = Broadcast::emergency(
            "skeeter",
            Emergency::TargetQuery {
                colour: RED.to_owned(),
            },
        );
        assert!(b.handle_broadcast(&q, t(50)));
        let out = b.step(t(50));
        assert_eq!(out.behaviour, Behaviour::ReplyTargetQuery);
        // Not in the laser's sight, but a fresh plan for red: "yes" (Scooter may simply be
        // hiding the target from Skeeter).
        assert!(out.messages.contains(&ScooterSay::TargetReply {
            colour: RED.to_owned(),
            seen: true
        }));
        assert!(out.command.v_m_s > 0.0, "replying does not stop the wheels");
        let out = b.step(t(100));
        assert_eq!(out.behaviour, Behaviour::FollowHeading);
        // Unknown colour, no target in view: no.
        b.handle_heard(
            &ScooterHeard::TargetQuery {
                colour: "blue".to_owned(),
            },
            t(150),
        );
        let out = b.step(t(150));
        assert!(out.messages.contains(&ScooterSay::TargetReply {
            colour: "blue".to_owned(),
            seen: false
        }));
        // The plan gone stale (no sample with red for lost_after = 12 s): no.
        b.handle_heard(
            &ScooterHeard::TargetQuery {
                colour: RED.to_owned(),
            },
            t(12_100),
        );
        let out = b.step(t(12_100));
        assert!(out.messages.contains(&ScooterSay::TargetReply {
            colour: RED.to_owned(),
            seen: false
        }));
    }

    #[test]
    fn finds_the_target_with_the_laser_notifies_until_the_outcome_and_stops() {
        let mut b = brain(HeadingRule::RangeAware);
        b.set_target(RED, t(0));
        // Scooter at (−1.5, 0) facing +x; target at (−0.5, 0) — 1 m ahead.
        let f = form(
            vec![
                rec("scooter", 180.0, Some(1.5), t(0)),
                rec(RED, 180.0, Some(0.5), t(0)),
            ],
            t(0),
        );
        b.handle_ses(&f, t(0));
        let mut w = Mini {
            x: -1.5,
            y: 0.0,
            th: 0.0,
            circles: vec![([-0.5, 0.0], 0.15)],
        };
        let mount = b.config().laser_mount;
        b.handle_laser(&w.scan(&mount), t(0));
        let out = b.step(t(0));
        assert_eq!(out.behaviour, Behaviour::MoveToTarget);
        let mut reached: Vec<u64> = Vec::new();
        let mut now = 0;
        for _ in 0..400 {
            now += 50;
            let first = b.step(t(now));
            w.advance(first.command, 0.05);
            b.handle_odometry(&w.odo((-1.5, 0.0, 0.0)), t(now));
            b.handle_laser(&w.scan(&mount), t(now));
            let mut out = b.step(t(now));
            out.messages.extend(first.messages);
            if out
                .messages
                .iter()
                .any(|m| matches!(m, ScooterSay::TargetReached { .. }))
            {
                reached.push(now);
            }
            if b.reached() {
                assert_eq!(out.behaviour, Behaviour::NotifySkeeter);
                assert_eq!(out.command, VelocityCommand::ZERO);
            }
        }
        // Sent when reached, then again every status period (1 s): it may be lost.
        assert!(reached.len() >= 3, "{reached:?}");
        for w2 in reached.windows(2) {
            assert!((1000..=1050).contains(&(w2[1] - w2[0])), "{reached:?}");
        }
        let d = (w.x + 0.5).hypot(w.y);
        assert!(d <= b.config().reach_distance_m + 0.05 && d > 0.55, "{d}");
        // Skeeter's echo of the acceptance (a commander poll) does not restart the target.
        b.handle_heard(
            &ScooterHeard::TargetAccepted {
                colour: RED.to_owned(),
            },
            t(now + 10),
        );
        assert!(b.reached());
        // The outcome ends the repeats.
        b.handle_heard(
            &ScooterHeard::MissionEnded {
                colour: RED.to_owned(),
            },
            t(now + 20),
        );
        for k in 1..40 {
            let out = b.step(t(now + 50 * k));
            assert_eq!(out.behaviour, Behaviour::Idle);
            assert_eq!(out.command, VelocityCommand::ZERO);
            assert!(
                out.messages
                    .iter()
                    .all(|m| matches!(m, ScooterSay::Status { .. }))
            );
        }
    }

    /// Issue 13: right after a target, a stale SES (or heading) pointing at the object
    /// Scooter stands next to must not make that object the next target.
    #[test]
    fn the_target_just_reached_is_not_the_next_one() {
        let mut b = brain(HeadingRule::RangeAware);
        b.set_target(RED, t(0));
        let ses = |colour: &str, at: u64| {
            form(
                vec![
                    rec("scooter", 180.0, Some(1.5), t(at)),
                    rec(colour, 180.0, Some(0.5), t(at)),
                ],
                t(at),
            )
        };
        b.handle_ses(&ses(RED, 0), t(0));
        let mut w = Mini {
            x: -1.5,
            y: 0.0,
            th: 0.0,
            circles: vec![([-0.5, 0.0], 0.15)],
        };
        let mount = b.config().laser_mount;
        let mut now = 0;
        while !b.reached() && now < 20_000 {
            now += 50;
            let out = b.step(t(now));
            w.advance(out.command, 0.05);
            b.handle_odometry(&w.odo((-1.5, 0.0, 0.0)), t(now));
            b.handle_laser(&w.scan(&mount), t(now));
        }
        assert!(b.reached(), "red reached");
        b.handle_heard(
            &ScooterHeard::MissionEnded {
                colour: RED.to_owned(),
            },
            t(now + 10),
        );
        b.handle_heard(
            &ScooterHeard::TargetAccepted {
                colour: "blue".to_owned(),
            },
            t(now + 20),
        );
        // The SES says blue is where red is (Scooter has not moved since).
        b.handle_ses(&ses("blue", now + 20), t(now + 20));
        for k in 1..40 {
            let at = now + 20 + 50 * k;
            b.handle_laser(&w.scan(&mount), t(at));
            let out = b.step(t(at));
            assert!(
                !out.messages
                    .iter()
                    .any(|m| matches!(m, ScooterSay::TargetReached { .. })),
                "red taken for blue at {at} ms"
            );
        }
        assert!(!b.reached());
        // A second red target is red again.
        b.handle_heard(
            &ScooterHeard::TargetAccepted {
                colour: RED.to_owned(),
            },
            t(now + 5000),
        );
        b.handle_ses(&ses(RED, now + 5000), t(now + 5000));
        b.handle_laser(&w.scan(&mount), t(now + 5050));
        b.step(t(now + 5050));
        assert!(b.reached(), "the same colour again is found at once");
    }

    #[test]
    fn a_new_target_stops_the_target_reached_repeats() {
        let mut b = brain(HeadingRule::RangeAware);
        b.set_target(RED, t(0));
        b.reached = true;
        let out = b.step(t(0));
        assert!(out.messages.contains(&ScooterSay::TargetReached {
            colour: RED.to_owned()
        }));
        b.handle_heard(
            &ScooterHeard::TargetAccepted {
                colour: "blue".to_owned(),
            },
            t(500),
        );
        for k in 1..60 {
            let out = b.step(t(500 + 50 * k));
            assert!(
                !out.messages
                    .iter()
                    .any(|m| matches!(m, ScooterSay::TargetReached { .. }))
            );
        }
    }

    #[test]
    fn a_fresh_scooter_record_ends_a_call_back_when_scooter_found_is_lost() {
        let mut b = brain(HeadingRule::Thesis);
        b.set_target(RED, t(0));
        let f = form(
            vec![rec("scooter", 90.0, None, t(0)), rec(RED, 0.0, None, t(0))],
            t(0),
        );
        b.handle_ses(&f, t(0));
        b.handle_heard(&ScooterHeard::ScooterLost, t(100));
        assert_eq!(b.step(t(100)).behaviour, Behaviour::MoveToHome);
        // A sample without Scooter (or with a stale record) keeps it homing.
        b.handle_ses(&form(vec![rec(RED, 0.0, None, t(200))], t(200)), t(200));
        assert_eq!(b.step(t(200)).behaviour, Behaviour::MoveToHome);
        let stale = form(vec![rec("scooter", 90.0, None, t(300))], t(20_300));
        b.handle_ses(&stale, t(20_300));
        assert_eq!(b.step(t(20_300)).behaviour, Behaviour::MoveToHome);
        // `scooter-found` was lost, but the next sample holds a fresh Scooter record.
        let f = form(vec![rec("scooter", 90.0, None, t(20_400))], t(20_500));
        b.handle_ses(&f, t(20_500));
        assert_ne!(b.step(t(20_500)).behaviour, Behaviour::MoveToHome);
        assert!(!b.san_summary().contains("called-back"));
    }

    #[test]
    fn range_aware_rule_ranges_skeeter_with_the_laser() {
        let mut b = brain(HeadingRule::RangeAware);
        b.set_target(RED, t(0));
        // Bearings only: Scooter at 180°, target at 90°.
        let f0 = form(
            vec![
                rec("scooter", 180.0, None, t(0)),
                rec(RED, 90.0, Some(3.0), t(0)),
            ],
            t(0),
        );
        b.handle_ses(&f0, t(0));
        assert!(matches!(b.plan(), Some(Plan::Heading(_))));
        // Scooter at (−2.5, 0) facing +x sees Skeeter (r 0.33) at the origin.
        let w = Mini {
            x: -2.5,
            y: 0.0,
            th: 0.0,
            circles: vec![([0.0, 0.0], 0.33)],
        };
        b.handle_laser(&w.scan(&b.config().laser_mount), t(100));
        let f1 = form(
            vec![
                rec("scooter", 180.0, None, t(200)),
                rec(RED, 90.0, Some(3.0), t(200)),
            ],
            t(200),
        );
        b.handle_ses(&f1, t(200));
        // Target (0, 3) from Scooter (−2.5, 0): DR (2.5, 3).
        match b.plan() {
            Some(Plan::Point(p)) => assert!((p - Vector2::new(2.5, 3.0)).norm() < 0.05, "{p}"),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn a_post_off_the_expected_position_is_not_the_target() {
        let mut b = brain(HeadingRule::RangeAware);
        b.set_target(RED, t(0));
        let f = form(
            vec![
                rec("scooter", 180.0, Some(3.0), t(0)),
                rec(RED, 90.0, Some(3.0), t(0)),
            ],
            t(0),
        );
        b.handle_ses(&f, t(0));
        // A post 1 m straight ahead; the target is expected up and to the left.
        let w = Mini {
            x: -3.0,
            y: 0.0,
            th: 0.0,
            circles: vec![([-2.0, 0.0], 0.15)],
        };
        b.handle_laser(&w.scan(&b.config().laser_mount), t(0));
        let out = b.step(t(0));
        assert_ne!(out.behaviour, Behaviour::MoveToTarget);
    }

    /// Drive past a barrel standing on the straight path to the target: the avoider takes
    /// over, the turn rate's sign changes at most twice (away, then back), no collision, and
    /// the target is reached.
    #[test]
    fn avoids_an_obstacle_smoothly_and_resumes() {
        let mut b = brain(HeadingRule::RangeAware);
        b.set_target(RED, t(0));
        // Scooter at (−4, 0) facing +x, target at (1, 0.0), barrel (r 0.3) at (−1.5, 0.05).
        let f = form(
            vec![
                rec("scooter", 180.0, Some(4.0), t(0)),
                rec(RED, 0.0, Some(1.0), t(0)),
            ],
            t(0),
        );
        b.handle_ses(&f, t(0));
        let mut w = Mini {
            x: -4.0,
            y: 0.0,
            th: 0.0,
            circles: vec![([1.0, 0.0], 0.15), ([-1.5, 0.05], 0.3)],
        };
        let mount = b.config().laser_mount;
        let mut now = 0;
        let mut omegas = Vec::new();
        let mut saw_avoid = false;
        let mut min_clear = f64::INFINITY;
        for _ in 0..1200 {
            now += 50;
            b.handle_odometry(&w.odo((-4.0, 0.0, 0.0)), t(now));
            b.handle_compass(w.th, t(now));
            b.handle_laser(&w.scan(&mount), t(now));
            let out = b.step(t(now));
            if out.behaviour == Behaviour::AvoidObstacle {
                saw_avoid = true;
            }
            if out.command.omega_rad_s.abs() > 0.02 {
                omegas.push(out.command.omega_rad_s.signum());
            }
            w.advance(out.command, 0.05);
            min_clear = min_clear.min((w.x + 1.5).hypot(w.y - 0.05) - 0.3 - 0.4);
            if b.reached() {
                break;
            }
            // A new sample every 5 s, exact.
            if now % 5000 == 0 {
                let (sx, sy) = (w.x, w.y);
                let f = form(
                    vec![
                        rec(
                            "scooter",
                            sy.atan2(sx).to_degrees(),
                            Some(sx.hypot(sy)),
                            t(now),
                        ),
                        rec(RED, 0.0, Some(1.0), t(now)),
                    ],
                    t(now),
                );
                b.handle_ses(&f, t(now));
            }
        }
        assert!(saw_avoid, "the barrel triggered avoid-obstacle");
        assert!(b.reached(), "target reached after the detour");
        assert!(min_clear > 0.0, "no collision: clearance {min_clear}");
        let flips = omegas.windows(2).filter(|p| p[0] != p[1]).count();
        assert!(
            flips <= 3,
            "turn-rate sign flipped {flips} times: {omegas:?}"
        );
    }

    /// A wall of posts across the way with the target just behind it: going round the
    /// wall's end takes the target more than 90° off Scooter's nose. The avoider keeps its
    /// side locked until the target is in view and free, so the turn rate does not chatter.
    #[test]
    fn goes_round_a_wide_obstacle_without_turn_rate_chatter() {
        let mut b = brain(HeadingRule::RangeAware);
        b.set_target(RED, t(0));
        // Scooter at (−4, 0) facing +x; a wall of posts at x = −1.5, y ∈ [−2.5, 1.5];
        // the target at (−0.6, 0).
        let target = [-0.6, 0.0];
        let sample = |now: u64, sx: f64, sy: f64| {
            form(
                vec![
                    rec(
                        "scooter",
                        sy.atan2(sx).to_degrees(),
                        Some(sx.hypot(sy)),
                        t(now),
                    ),
                    rec(RED, 180.0, Some(0.6), t(now)),
                ],
                t(now),
            )
        };
        b.handle_ses(&sample(0, -4.0, 0.0), t(0));
        let mut circles = vec![(target, 0.15)];
        for k in 0..=20 {
            circles.push(([-1.5, -2.5 + f64::from(k) * 0.2], 0.12));
        }
        let mut w = Mini {
            x: -4.0,
            y: 0.0,
            th: 0.0,
            circles,
        };
        let mount = b.config().laser_mount;
        let mut now = 0;
        let mut omegas = Vec::new();
        let mut out_of_view = false;
        for _ in 0..4000 {
            now += 50;
            b.handle_odometry(&w.odo((-4.0, 0.0, 0.0)), t(now));
            b.handle_compass(w.th, t(now));
            b.handle_laser(&w.scan(&mount), t(now));
            let out = b.step(t(now));
            let g = normalize_angle((target[1] - w.y).atan2(target[0] - w.x) - w.th);
            if out.behaviour == Behaviour::AvoidObstacle && g.abs() > PI / 2.0 {
                out_of_view = true;
            }
            if out.command.omega_rad_s.abs() > 0.02 {
                omegas.push(out.command.omega_rad_s.signum());
            }
            w.advance(out.command, 0.05);
            for (c, r) in w.circles.iter().skip(1) {
                let clear = (w.x - c[0]).hypot(w.y - c[1]) - r - 0.4;
                assert!(clear > 0.0, "hit a post at {:.2},{:.2}", w.x, w.y);
            }
            if b.reached() {
                break;
            }
            if now % 5000 == 0 {
                b.handle_ses(&sample(now, w.x, w.y), t(now));
            }
        }
        assert!(out_of_view, "the detour took the target out of view");
        assert!(
            b.reached(),
            "target reached round the wall: at {:.2},{:.2}",
            w.x,
            w.y
        );
        let flips = omegas.windows(2).filter(|p| p[0] != p[1]).count();
        assert!(
            flips <= 4,
            "turn-rate sign flipped {flips} times: {omegas:?}"
        );
    }

    #[test]
    fn heading_sources_compass_odometry_fused() {
        let mk = |src| {
            let mut b = ScooterBrain::new(ScooterConfig {
                heading_source: src,
                fusion_gain: 0.5,
                odometry_heading_offset_rad: 0.1,
                ..ScooterConfig::default()
            });
            b.handle_odometry(&Odometry::origin(), t(0));
            b.handle_compass(0.3, t(0));
            b.handle_odometry(
                &Odometry {
                    pose: Isometry2::new(Vector2::zeros(), 0.2),
                    ..Odometry::origin()
                },
                t(10),
            );
            b.handle_compass(0.5, t(20));
            b.heading().unwrap()
        };
        assert!((mk(HeadingSource::Compass) - 0.5).abs() < 1e-12);
        assert!((mk(HeadingSource::Odometry) - 0.3).abs() < 1e-12);
        // Fused: starts at the odometry heading 0.1, +0.2 odometry turn… then the compass
        // pulls: first reading 0.3 → 0.1 + 0.5·0.2 = 0.2; +0.2 → 0.4; reading 0.5 → 0.45.
        assert!((mk(HeadingSource::Fused) - 0.45).abs() < 1e-12);
    }

    #[test]
    fn dead_reckoning_rotates_odometry_by_the_heading() {
        let mut b = brain(HeadingRule::Thesis);
        b.handle_compass(PI / 2.0, t(0));
        b.handle_odometry(
            &Odometry {
                pose: Isometry2::new(Vector2::new(1.0, 0.0), 0.0),
                ..Odometry::origin()
            },
            t(100),
        );
        // Odometry says 1 m forward; the compass says we face +y.
        assert!((b.dr_position() - Vector2::new(0.0, 1.0)).norm() < 1e-12);
    }

    #[test]
    fn turn_in_place_hysteresis() {
        let mut b = brain(HeadingRule::Thesis);
        b.set_target(RED, t(0));
        let f = form(
            vec![rec("scooter", 0.0, None, t(0)), rec(RED, 90.0, None, t(0))],
            t(0),
        );
        b.handle_ses(&f, t(0));
        // θd = 135°. Error 135°: in place.
        assert_eq!(b.step(t(0)).command.v_m_s, 0.0);
        // Error 20° (< enter 30°) but still > exit 8°: still in place.
        b.handle_compass(115f64.to_radians(), t(50));
        assert_eq!(b.step(t(50)).command.v_m_s, 0.0);
        // Error 5°: drive; then 20° again: keeps driving (below enter).
        b.handle_compass(130f64.to_radians(), t(100));
        assert!(b.step(t(100)).command.v_m_s > 0.0);
        b.handle_compass(115f64.to_radians(), t(150));
        assert!(b.step(t(150)).command.v_m_s > 0.0);
    }

    #[test]
    fn laser_clusters_measure_width_and_centre() {
        let w = Mini {
            x: 0.0,
            y: 0.0,
            th: 0.0,
            circles: vec![([1.2, 0.0], 0.15), ([1.5, 1.5], 0.4)],
        };
        let mount = Isometry2::new(Vector2::new(0.2, 0.0), 0.0);
        let cs = laser_clusters(&w.scan(&mount), &mount, 8.0, 0.1, 0.15);
        let c = cs
            .iter()
            .find(|c| (c.centre - Point2::new(1.2, 0.0)).norm() < 0.05)
            .unwrap();
        assert!((c.width_m - 0.3).abs() < 0.1, "{c:?}");
        assert!(cs.iter().any(|c| c.width_m > 0.5));
    }

    #[test]
    fn broadcast_mapping_both_ways() {
        let acc = Broadcast::new_target(RED);
        assert_eq!(
            ScooterHeard::from_broadcast(&acc, "scooter"),
            Some(ScooterHeard::TargetAccepted {
                colour: RED.to_owned()
            })
        );
        let done = Broadcast::mission("skeeter", MissionEvent::Accomplished, RED);
        assert_eq!(
            ScooterHeard::from_broadcast(&done, "scooter"),
            Some(ScooterHeard::MissionEnded {
                colour: RED.to_owned()
            })
        );
        let own = Broadcast::emergency(
            "scooter",
            Emergency::TargetReached {
                colour: RED.to_owned(),
            },
        );
        assert_eq!(ScooterHeard::from_broadcast(&own, "scooter"), None);
        let cancel = Broadcast::emergency(
            "commander",
            Emergency::TargetCancel {
                colour: RED.to_owned(),
            },
        );
        assert_eq!(
            ScooterHeard::from_broadcast(&cancel, "scooter"),
            Some(ScooterHeard::MissionEnded {
                colour: RED.to_owned()
            })
        );
        let stop = Broadcast::emergency(
            "commander",
            Emergency::FleetStop {
                reason: String::new(),
            },
        );
        assert_eq!(ScooterHeard::from_broadcast(&stop, "scooter"), None);
        let say = ScooterSay::TargetReply {
            colour: RED.to_owned(),
            seen: true,
        };
        let b = say.to_broadcast("scooter", "").unwrap();
        assert_eq!(b.to_wire(1).code(), b.to_wire(2).code());
        match b {
            Broadcast::Emergency { emergency, .. } => assert_eq!(emergency.text(), "red yes"),
            other => panic!("{other:?}"),
        }
        assert_eq!(ScooterSay::RequestHeading.to_broadcast("scooter", ""), None);
        let st = ScooterSay::Status {
            behaviour: Behaviour::AvoidObstacle,
            pose: (1.0, -2.0, 0.5),
        }
        .to_broadcast("scooter", "path-clear");
        match st {
            Some(Broadcast::Status {
                behaviour, pose, ..
            }) => {
                assert_eq!(behaviour, "avoid-obstacle");
                assert_eq!(
                    pose,
                    Some(Pose {
                        x_mm: 1000,
                        y_mm: -2000,
                        theta_mrad: 500
                    })
                );
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn mission_end_of_another_colour_is_ignored_and_repeated_acceptance_does_not_restart() {
        let mut b = brain(HeadingRule::Thesis);
        b.handle_heard(
            &ScooterHeard::TargetAccepted {
                colour: RED.to_owned(),
            },
            t(0),
        );
        let f = form(
            vec![rec("scooter", 0.0, None, t(0)), rec(RED, 90.0, None, t(0))],
            t(0),
        );
        b.handle_ses(&f, t(0));
        b.handle_heard(
            &ScooterHeard::TargetAccepted {
                colour: RED.to_owned(),
            },
            t(10),
        );
        assert!(
            b.plan().is_some(),
            "Skeeter's echo of the acceptance keeps the plan"
        );
        b.handle_heard(
            &ScooterHeard::MissionEnded {
                colour: "blue".to_owned(),
            },
            t(20),
        );
        assert_eq!(b.target(), Some(RED));
        b.handle_heard(
            &ScooterHeard::MissionEnded {
                colour: RED.to_owned(),
            },
            t(30),
        );
        assert_eq!(b.target(), None);
        assert_eq!(b.step(t(40)).behaviour, Behaviour::Idle);
    }
}

//! Smooth obstacle avoidance for Scooter from its laser scan (pure, sans-IO).
//!
//! The thesis's avoid-obstacle behaviour "made the robot jerk back and forth" (MISSION.md,
//! future work). The jerking comes from two sources, and this module removes both:
//!
//! 1. **Side flipping.** A reactive rule that turns away from the nearer side flips its sign
//!    every time the obstacle's nearest point crosses the robot's axis. Here the side is
//!    **chosen once** when avoidance starts (the side whose first free direction deviates
//!    least from the goal) and **locked** until the path toward the goal is clear again —
//!    which needs the goal direction to be **in view** (within ±`search_limit_rad`) *and*
//!    free: a detour of more than 90° keeps the lock (steering at the free direction in view
//!    nearest the goal) instead of turning back into the obstacle.
//! 2. **On/off chatter.** Avoidance starts when the free corridor toward the goal is shorter
//!    than [`AvoidConfig::enter_distance_m`] and ends only when it is longer than
//!    [`AvoidConfig::exit_distance_m`] (> enter): hysteresis.
//!
//! # Geometry
//!
//! Everything is in the **robot frame** (x forward, y left, angles counter-clockwise, as in
//! `ima_hal`). Obstacles are laser returns turned into points ([`scan_points`]). A direction
//! `φ` is *free for `L` metres* when no point lies in the corridor of half-width
//! `robot_radius_m + margin_m` along `φ` between 0 and `L` ([`free_length`]).
//!
//! While active, the steering direction is the direction nearest the goal direction, on the
//! locked side, that is free for `lookahead_m`, searched in `candidate_step_rad` steps within
//! the laser's field of view (±[`AvoidConfig::search_limit_rad`]); if none is free the robot
//! turns in place toward the locked side. The caller's controller (in
//! [`super::scooter`]) turns toward that direction with a rate limit and a low-pass filter.

use core::f64::consts::{FRAC_PI_2, PI};

use ima_hal::laser::LaserScan;
use ima_hal::{Isometry2, Point2, normalize_angle};

/// Parameters of the avoider.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AvoidConfig {
    /// The robot's footprint radius, metres (ATRV-Jr ≈ 0.40 m).
    pub robot_radius_m: f64,
    /// Extra clearance on each side of the corridor, metres.
    pub margin_m: f64,
    /// Start avoiding when the corridor toward the goal is free for less than this, metres.
    pub enter_distance_m: f64,
    /// Stop avoiding when the corridor toward the goal is free for more than this (or as far
    /// as the goal), metres. Must exceed `enter_distance_m` (hysteresis).
    pub exit_distance_m: f64,
    /// A candidate steering direction must be free for this long, metres.
    pub lookahead_m: f64,
    /// Angular step of the candidate search, radians.
    pub candidate_step_rad: f64,
    /// Candidates are searched within ±this of the robot's forward axis (the laser's field
    /// of view), radians.
    pub search_limit_rad: f64,
}

impl Default for AvoidConfig {
    fn default() -> Self {
        Self {
            robot_radius_m: 0.40,
            margin_m: 0.10,
            enter_distance_m: 0.6,
            exit_distance_m: 1.0,
            lookahead_m: 1.0,
            candidate_step_rad: 3f64.to_radians(),
            search_limit_rad: FRAC_PI_2,
        }
    }
}

/// The side the avoider goes round an obstacle on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Side {
    /// Counter-clockwise: the obstacle stays on the robot's right.
    Left,
    /// Clockwise: the obstacle stays on the robot's left.
    Right,
}

impl Side {
    fn sign(self) -> f64 {
        match self {
            Side::Left => 1.0,
            Side::Right => -1.0,
        }
    }
}

/// What the avoider decided for one scan.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AvoidDecision {
    /// Avoidance is active (the SAN's `obstacle-near`; `path-clear` is its negation).
    pub active: bool,
    /// Direction to steer toward, robot frame, radians: the goal direction when inactive.
    pub steer_rad: f64,
    /// The locked side while active.
    pub side: Option<Side>,
    /// Free length of the corridor toward the goal, metres.
    pub goal_free_m: f64,
}

/// The avoider's state: active or not, and the locked side.
#[derive(Debug, Clone, PartialEq)]
pub struct Avoider {
    cfg: AvoidConfig,
    side: Option<Side>,
}

/// Turn the valid beams of a scan from a laser mounted at `mount` (its pose in the robot
/// frame) into robot-frame points, appended to `out` (cleared first). Beams that are not
/// valid, not finite, non-positive or at/over `max_range_m` are skipped.
pub fn scan_points(scan: &LaserScan, mount: &Isometry2, max_range_m: f64, out: &mut Vec<Point2>) {
    out.clear();
    for (angle, range, flags) in scan.beams() {
        let r = f64::from(range);
        if !flags.is_valid() || !r.is_finite() || r <= 0.0 || r >= max_range_m {
            continue;
        }
        out.push(mount * Point2::new(r * angle.cos(), r * angle.sin()));
    }
}

/// Distance along direction `dir_rad` (robot frame) to the first point inside the corridor of
/// half-width `half_width_m`; `f64::INFINITY` when the corridor is empty. Points behind the
/// robot (negative projection) do not count.
#[must_use]
pub fn free_length(points: &[Point2], dir_rad: f64, half_width_m: f64) -> f64 {
    let (c, s) = (dir_rad.cos(), dir_rad.sin());
    points
        .iter()
        .filter_map(|p| {
            let along = p.x * c + p.y * s;
            let across = (-p.x * s + p.y * c).abs();
            (along >= 0.0 && across < half_width_m).then(|| {
                // The robot's disc first touches the point `along − depth` ahead.
                let depth = (half_width_m * half_width_m - across * across).sqrt();
                (along - depth).max(0.0)
            })
        })
        .fold(f64::INFINITY, f64::min)
}

impl Avoider {
    /// An inactive avoider.
    #[must_use]
    pub fn new(cfg: AvoidConfig) -> Self {
        Self { cfg, side: None }
    }

    /// The parameters.
    #[must_use]
    pub fn config(&self) -> &AvoidConfig {
        &self.cfg
    }

    /// Whether avoidance is active.
    #[must_use]
    pub fn is_active(&self) -> bool {
        self.side.is_some()
    }

    /// Forget any active avoidance (e.g. when the robot stops for good).
    pub fn reset(&mut self) {
        self.side = None;
    }

    fn half_width(&self) -> f64 {
        self.cfg.robot_radius_m + self.cfg.margin_m
    }

    /// First direction from `goal` toward `side` (in candidate steps, within the search
    /// limit) that is free for `lookahead_m`; with its angular deviation from `goal`.
    fn first_free(&self, points: &[Point2], goal: f64, side: Side) -> Option<(f64, f64)> {
        let step = self.cfg.candidate_step_rad.max(1e-3);
        let limit = self.cfg.search_limit_rad;
        let n = (2.0 * PI / step).ceil() as usize;
        (0..=n).find_map(|k| {
            let dev = k as f64 * step;
            let phi = goal + side.sign() * dev;
            let phi_n = normalize_angle(phi);
            (phi_n.abs() <= limit
                && free_length(points, phi_n, self.half_width()) >= self.cfg.lookahead_m)
                .then_some((phi_n, dev))
        })
    }

    /// One decision from the scan `points` (robot frame) toward a goal at direction
    /// `goal_rad` (robot frame) and distance `goal_distance_m` (`f64::INFINITY` if unknown).
    /// `ignore` removes points within the given radius of a robot-frame point (the target
    /// itself, which is not an obstacle when the robot is going to it).
    pub fn decide(
        &mut self,
        points: &[Point2],
        goal_rad: f64,
        goal_distance_m: f64,
        ignore: Option<(Point2, f64)>,
    ) -> AvoidDecision {
        let goal = if goal_rad.is_finite() {
            normalize_angle(goal_rad)
        } else {
            0.0
        };
        let kept: Vec<Point2>;
        let pts: &[Point2] = match ignore {
            Some((c, r)) => {
                kept = points
                    .iter()
                    .copied()
                    .filter(|p| (p - c).norm() > r)
                    .collect();
                &kept
            }
            None => points,
        };
        // The goal direction is only judged when the laser can see it.
        let visible = goal.abs() <= self.cfg.search_limit_rad;
        let goal_free = if visible {
            free_length(pts, goal, self.half_width())
        } else {
            f64::INFINITY
        };
        let reach = goal_distance_m.max(0.0);
        match self.side {
            None => {
                if visible && goal_free < self.cfg.enter_distance_m && goal_free < reach {
                    let left = self.first_free(pts, goal, Side::Left);
                    let right = self.first_free(pts, goal, Side::Right);
                    let side = match (left, right) {
                        (Some((_, dl)), Some((_, dr))) if dr < dl => Side::Right,
                        (None, Some(_)) => Side::Right,
                        _ => Side::Left,
                    };
                    self.side = Some(side);
                } else {
                    return AvoidDecision {
                        active: false,
                        steer_rad: goal,
                        side: None,
                        goal_free_m: goal_free,
                    };
                }
            }
            Some(_) => {
                // Keep the lock while the goal is out of view: a detour of more than 90°
                // must not turn back into the obstacle it is going round.
                if visible && (goal_free >= self.cfg.exit_distance_m || goal_free >= reach) {
                    self.side = None;
                    return AvoidDecision {
                        active: false,
                        steer_rad: goal,
                        side: None,
                        goal_free_m: goal_free,
                    };
                }
            }
        }
        let side = self.side.unwrap_or(Side::Left);
        let steer = match self.first_free(pts, goal, side) {
            Some((phi, _)) => phi,
            // Nothing free in view: turn in place toward the locked side.
            None => side.sign() * (self.cfg.search_limit_rad + self.cfg.candidate_step_rad),
        };
        AvoidDecision {
            active: true,
            steer_rad: steer,
            side: Some(side),
            goal_free_m: goal_free,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn wall_ahead(x: f64, y_from: f64, y_to: f64) -> Vec<Point2> {
        let n = ((y_to - y_from) / 0.02).ceil() as usize;
        (0..=n)
            .map(|i| Point2::new(x, y_from + i as f64 * 0.02))
            .collect()
    }

    #[test]
    fn free_length_of_a_corridor() {
        let pts = [Point2::new(2.0, 0.0), Point2::new(1.0, 2.0)];
        assert!((free_length(&pts, 0.0, 0.5) - 1.5).abs() < 1e-12);
        assert!(free_length(&pts, PI, 0.5).is_infinite());
        // Point off-axis by 0.3 in a 0.5 corridor: touched at 2 − 0.4.
        let pts = [Point2::new(2.0, 0.3)];
        assert!((free_length(&pts, 0.0, 0.5) - 1.6).abs() < 1e-12);
    }

    #[test]
    fn inactive_when_the_way_is_clear() {
        let mut a = Avoider::new(AvoidConfig::default());
        let pts = wall_ahead(3.0, -1.0, 1.0);
        let d = a.decide(&pts, 0.2, f64::INFINITY, None);
        assert!(!d.active);
        assert_eq!(d.steer_rad, 0.2);
    }

    #[test]
    fn picks_the_side_nearer_the_goal_and_locks_it() {
        let mut a = Avoider::new(AvoidConfig::default());
        // A wall segment 0.5 m ahead reaching further to the right than to the left.
        let pts = wall_ahead(0.5, -1.5, 0.6);
        let d = a.decide(&pts, 0.0, f64::INFINITY, None);
        assert!(d.active);
        assert_eq!(d.side, Some(Side::Left));
        assert!(d.steer_rad > 0.0);
        // Goal now slightly right: the side stays locked.
        let d = a.decide(&pts, -0.3, f64::INFINITY, None);
        assert_eq!(d.side, Some(Side::Left));
        assert!(d.steer_rad > 0.0);
    }

    #[test]
    fn hysteresis_between_enter_and_exit() {
        let cfg = AvoidConfig::default();
        let mut a = Avoider::new(cfg);
        let pts = [Point2::new(0.5 + cfg.robot_radius_m + cfg.margin_m, 0.0)];
        // Free for 0.5 < enter: active.
        assert!(a.decide(&pts, 0.0, f64::INFINITY, None).active);
        // Free for 0.8: between enter and exit, stays active.
        let pts = [Point2::new(0.8 + cfg.robot_radius_m + cfg.margin_m, 0.0)];
        assert!(a.decide(&pts, 0.0, f64::INFINITY, None).active);
        // Free for 1.2 > exit: inactive, and 0.8 does not re-enter.
        let far = [Point2::new(1.2 + cfg.robot_radius_m + cfg.margin_m, 0.0)];
        assert!(!a.decide(&far, 0.0, f64::INFINITY, None).active);
        assert!(!a.decide(&pts, 0.0, f64::INFINITY, None).active);
    }

    #[test]
    fn goal_nearer_than_the_obstacle_needs_no_avoidance() {
        let mut a = Avoider::new(AvoidConfig::default());
        let pts = wall_ahead(0.8, -1.0, 1.0);
        assert!(!a.decide(&pts, 0.0, 0.2, None).active);
    }

    #[test]
    fn ignored_points_are_not_obstacles() {
        let mut a = Avoider::new(AvoidConfig::default());
        let pts = [Point2::new(0.5, 0.0)];
        let d = a.decide(&pts, 0.0, f64::INFINITY, Some((Point2::new(0.5, 0.0), 0.2)));
        assert!(!d.active);
    }

    #[test]
    fn boxed_in_turns_in_place_toward_the_locked_side() {
        let mut a = Avoider::new(AvoidConfig::default());
        let pts: Vec<Point2> = (0..=180)
            .map(|k| {
                let t = (f64::from(k) - 90.0).to_radians();
                Point2::new(0.6 * t.cos(), 0.6 * t.sin())
            })
            .collect();
        let d = a.decide(&pts, 0.0, f64::INFINITY, None);
        assert!(d.active);
        assert!(d.steer_rad.abs() > FRAC_PI_2);
    }

    #[test]
    fn scan_points_skip_invalid_beams() {
        use ima_hal::laser::BeamFlags;
        let mut scan = LaserScan::new(-FRAC_PI_2, FRAC_PI_2);
        scan.push(1.0, BeamFlags::VALID).unwrap();
        scan.push(f32::NAN, BeamFlags::NO_RETURN).unwrap();
        scan.push(2.0, BeamFlags::VALID).unwrap();
        let mount = Isometry2::new(ima_hal::Vector2::new(0.2, 0.0), 0.0);
        let mut out = Vec::new();
        scan_points(&scan, &mount, 8.0, &mut out);
        assert_eq!(out.len(), 2);
        assert!((out[0] - Point2::new(0.2, -1.0)).norm() < 1e-9);
        assert!((out[1] - Point2::new(0.2, 2.0)).norm() < 1e-9);
    }

    #[test]
    fn the_lock_holds_while_the_goal_is_out_of_view() {
        let cfg = AvoidConfig::default();
        let mut a = Avoider::new(cfg);
        let pts = wall_ahead(0.5, -1.5, 0.6);
        let d = a.decide(&pts, 0.0, f64::INFINITY, None);
        assert_eq!(d.side, Some(Side::Left));
        // Going round, the goal is 120° to the right (out of view) and nothing is in front:
        // still avoiding on the left side, steering at the in-view direction nearest the goal.
        let d = a.decide(&[], -120f64.to_radians(), f64::INFINITY, None);
        assert!(d.active);
        assert_eq!(d.side, Some(Side::Left));
        assert!(
            d.steer_rad < -FRAC_PI_2 + 0.1 && d.steer_rad >= -FRAC_PI_2,
            "{d:?}"
        );
        // The goal in view and free: done.
        let d = a.decide(&[], -60f64.to_radians(), f64::INFINITY, None);
        assert!(!d.active);
        // In view but blocked (0.8 m, between enter and exit): still locked.
        let mut a = Avoider::new(cfg);
        a.decide(&pts, 0.0, f64::INFINITY, None);
        let blocked = [Point2::new(0.8 + cfg.robot_radius_m + cfg.margin_m, 0.0)];
        let d = a.decide(&blocked, 0.0, f64::INFINITY, None);
        assert!(d.active);
    }
}

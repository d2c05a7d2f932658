//! The obstacle-avoidance agent: the laser's obstacle points (with a memory of those that
//! left the field of view), the laser's age (no usable scan lately = blind), and the
//! [avoider](crate::mission::avoid)'s steering direction toward a goal, low-pass filtered
//! in the common frame ([`ScooterConfig::avoid_smoothing_s`]).

use ima_hal::laser::{BeamFlags, LaserScan};
use ima_hal::{Instant, Point2, Vector2, normalize_angle};

use super::{Goal, ScooterConfig, rotate};
use crate::mission::avoid::{self, Avoider};

/// At most this many remembered obstacle points.
const MAX_MEMORY: usize = 4096;

/// Obstacle points, the avoider and its smoothed direction (see the [module docs](self)).
#[derive(Debug, Clone)]
pub(super) struct ObstacleAgent {
    avoider: Avoider,
    /// Obstacle points, robot frame: the last scan's and the remembered ones out of view.
    points: Vec<Point2>,
    /// Obstacle points of the last scan and the memory, DR frame.
    seen_dr: Vec<Vector2>,
    /// The smoothed avoidance direction, common frame.
    avoid_heading: Option<f64>,
    /// When the last *usable* scan arrived.
    laser_at: Option<Instant>,
}

/// Whether enough of a scan's beams are usable ([`ScooterConfig::laser_min_usable_fraction`],
/// [`ScooterConfig::laser_no_return_is_clear`]).
pub(super) fn scan_usable(scan: &LaserScan, cfg: &ScooterConfig) -> bool {
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
                cfg.laser_no_return_is_clear && !errors.iter().any(|e| f.contains(*e))
            }
        })
        .count();
    let need = cfg.laser_min_usable_fraction;
    let need = if need.is_finite() {
        need.clamp(0.0, 1.0)
    } else {
        1.0
    };
    usable > 0 && usable as f64 >= need * n as f64
}

impl ObstacleAgent {
    /// No points, never saw a scan.
    pub(super) fn new(cfg: &ScooterConfig) -> Self {
        Self {
            avoider: Avoider::new(cfg.avoid),
            points: Vec::new(),
            seen_dr: Vec::new(),
            avoid_heading: None,
            laser_at: None,
        }
    }

    /// Forget the avoider's locked side and hysteresis.
    /// Obstacle points of the last scan and the memory, DR frame (metres).
    pub(super) fn seen_dr(&self) -> &[Vector2] {
        &self.seen_dr
    }

    pub(super) fn reset(&mut self) {
        self.avoider.reset();
    }

    /// Whether a usable scan came within [`ScooterConfig::laser_stale_after`].
    pub(super) fn fresh(&self, now: Instant, cfg: &ScooterConfig) -> bool {
        self.laser_at
            .is_some_and(|t| now.saturating_duration_since(t) <= cfg.laser_stale_after)
    }

    /// A scan, Scooter at `pose` (θh, DR position) when its heading is known. Returns
    /// whether the scan was usable; an unusable one neither clears the path nor refreshes
    /// the laser's age.
    pub(super) fn handle_scan(
        &mut self,
        scan: &LaserScan,
        cfg: &ScooterConfig,
        pose: Option<(f64, Vector2)>,
        now: Instant,
    ) -> bool {
        if !scan_usable(scan, cfg) {
            return false;
        }
        avoid::scan_points(
            scan,
            &cfg.laser_mount,
            cfg.laser_max_range_m,
            &mut self.points,
        );
        self.laser_at = Some(now);
        match pose {
            Some((h, dr)) => self.remember(scan, cfg, h, dr),
            None => self.seen_dr.clear(),
        }
        true
    }

    /// Add the remembered obstacle points that are out of the laser's view now to
    /// `self.points` ([`ScooterConfig::obstacle_memory_m`]); remember this scan's points.
    fn remember(&mut self, scan: &LaserScan, cfg: &ScooterConfig, h: f64, dr: Vector2) {
        let radius = cfg.obstacle_memory_m;
        if !(radius.is_finite() && radius > 0.0) || scan.is_empty() {
            self.seen_dr.clear();
            return;
        }
        let first = scan.angle_rad(0);
        let last = scan.angle_rad(scan.len().saturating_sub(1));
        let (lo, hi) = (first.min(last), first.max(last));
        let margin = 1f64.to_radians();
        let mount_inv = cfg.laser_mount.inverse();
        let kept: Vec<(Vector2, Point2)> = self
            .seen_dr
            .iter()
            .filter_map(|m| {
                let rel = m - dr;
                let dist = rel.norm();
                if dist.is_nan() || dist > radius {
                    return None;
                }
                let robot = Point2::from(rotate(-h, rel));
                let in_laser = mount_inv * robot;
                let a = in_laser.y.atan2(in_laser.x);
                (a < lo - margin || a > hi + margin).then_some((*m, robot))
            })
            .take(MAX_MEMORY)
            .collect();
        self.seen_dr.clear();
        self.seen_dr
            .extend(self.points.iter().map(|p| dr + rotate(h, p.coords)));
        for (m, robot) in kept {
            self.seen_dr.push(m);
            self.points.push(robot);
        }
    }

    /// Judge the path toward `goal` from Scooter at `dr` heading `h`: the robot-frame
    /// steering direction round an obstacle (smoothed), or `None` when the path is clear.
    /// With `engaged` false (no target, or reached), no goal or no heading the avoider is
    /// reset and nothing is near. `dt` is the time since the last step, seconds.
    pub(super) fn steer(
        &mut self,
        cfg: &ScooterConfig,
        goal: Option<Goal>,
        h: Option<f64>,
        dr: Vector2,
        engaged: bool,
        dt: f64,
    ) -> Option<f64> {
        let decision = match (goal, h) {
            (Some((dir, dist, ignore)), Some(h)) if engaged => {
                let ignore = ignore.map(|(p, r)| (Point2::from(rotate(-h, p - dr)), r));
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
        let raw = decision.filter(|d| d.active).map(|d| d.steer_rad);
        // Smooth the avoider's direction in the common frame (first-order, τ).
        match (raw, h) {
            (Some(s), Some(h)) => {
                let target = normalize_angle(h + s);
                let tau = cfg.avoid_smoothing_s.max(0.0);
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
        }
    }
}

#[cfg(test)]
mod tests {
    use core::time::Duration;

    use super::*;
    use crate::mission::scooter::testkit::{scan, uniform_scan};

    fn at(ms: u64) -> Instant {
        Instant::from_millis(ms)
    }

    #[test]
    fn only_usable_scans_refresh_the_laser() {
        let cfg = ScooterConfig::default();
        let mut o = ObstacleAgent::new(&cfg);
        assert!(!o.fresh(at(0), &cfg));
        assert!(!o.handle_scan(&uniform_scan(BeamFlags::DAZZLED), &cfg, None, at(0)));
        assert!(!o.fresh(at(0), &cfg), "a blinded scan is no scan");
        assert!(o.handle_scan(&uniform_scan(BeamFlags::NO_RETURN), &cfg, None, at(0)));
        assert!(o.fresh(at(0), &cfg));
        assert!(!o.fresh(
            at(0) + cfg.laser_stale_after + Duration::from_millis(1),
            &cfg
        ));
        let strict = ScooterConfig {
            laser_no_return_is_clear: false,
            ..cfg.clone()
        };
        assert!(!scan_usable(&uniform_scan(BeamFlags::NO_RETURN), &strict));
        assert!(!scan_usable(&LaserScan::new(0.0, 0.01), &cfg), "empty");
    }

    #[test]
    fn a_post_ahead_makes_it_steer_round_and_a_clear_path_does_not() {
        let cfg = ScooterConfig::default();
        let mut o = ObstacleAgent::new(&cfg);
        let pose = Some((0.0, Vector2::zeros()));
        let goal = Some((0.0, 5.0, None));
        o.handle_scan(
            &scan((0.0, 0.0, 0.0), &cfg.laser_mount, &[]),
            &cfg,
            pose,
            at(0),
        );
        assert_eq!(
            o.steer(&cfg, goal, Some(0.0), Vector2::zeros(), true, 0.1),
            None
        );
        let post = [([1.0, 0.0], 0.2)];
        o.handle_scan(
            &scan((0.0, 0.0, 0.0), &cfg.laser_mount, &post),
            &cfg,
            pose,
            at(100),
        );
        let s = o.steer(&cfg, goal, Some(0.0), Vector2::zeros(), true, 0.1);
        assert!(s.is_some_and(|s| s.abs() > 0.1), "{s:?}");
        // Not engaged (no target, or reached): nothing is near.
        assert_eq!(
            o.steer(&cfg, goal, Some(0.0), Vector2::zeros(), false, 0.1),
            None
        );
        // The goal circle itself is not an obstacle.
        let at_post = Some((0.0, 1.0, Some((Vector2::new(1.0, 0.0), 0.5))));
        assert_eq!(
            o.steer(&cfg, at_post, Some(0.0), Vector2::zeros(), true, 0.1),
            None
        );
    }

    #[test]
    fn points_that_leave_the_view_are_remembered_nearby() {
        let cfg = ScooterConfig::default();
        let mut o = ObstacleAgent::new(&cfg);
        // A post 1 m ahead, then Scooter turned to face away from it (π/2 left of it).
        let post = [([1.0, 0.0], 0.2)];
        let seen = scan((0.0, 0.0, 0.0), &cfg.laser_mount, &post);
        o.handle_scan(&seen, &cfg, Some((0.0, Vector2::zeros())), at(0));
        let n = o.points.len();
        assert!(n > 5);
        let h = core::f64::consts::PI;
        let away = scan((0.0, 0.0, h), &cfg.laser_mount, &post);
        o.handle_scan(&away, &cfg, Some((h, Vector2::zeros())), at(100));
        assert_eq!(o.points.len(), n, "the post behind is remembered");
        // Far away, it is forgotten.
        let far = Vector2::new(-5.0, 0.0);
        o.handle_scan(&away, &cfg, Some((h, far)), at(200));
        o.handle_scan(&away, &cfg, Some((h, far)), at(300));
        assert!(o.points.is_empty());
    }
}

//! The target finder: Scooter's laser looks for the target (a cluster of the target's
//! diameter where the plan expects it, or anywhere in view — [`TargetRecognition`]) and
//! for Skeeter (a cluster of Skeeter's diameter where θ1 + 180° says it is), in the DR
//! frame. The laser cannot tell colours: the last target reached is never the next one, and
//! a target-sized piece of something wider (Skeeter, a wall) is no target
//! ([`ScooterConfig::join_gap_m`]).

use core::f64::consts::PI;
use core::time::Duration;

use ima_hal::laser::LaserScan;
use ima_hal::{Instant, Isometry2, Point2, Vector2, normalize_angle};

use super::{Plan, ScooterConfig, TargetRecognition, rotate};

/// A target or Skeeter fix older than this is forgotten.
pub(super) const FIX_TTL: Duration = Duration::from_secs(3);

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

/// The target finder's state: where the laser last saw the target and Skeeter (DR frame),
/// and the last target reached.
#[derive(Debug, Clone, Default)]
pub(super) struct TargetFinder {
    /// The target as the laser last saw it (DR frame).
    target_fix: Option<(Instant, Vector2)>,
    /// The last target reached and where (DR frame): the object Scooter stands next to is
    /// not the next target, whatever a stale heading points at.
    reached_target: Option<(String, Vector2)>,
    /// Skeeter as the laser last saw it (DR frame).
    skeeter_fix: Option<(Instant, Vector2)>,
}

impl TargetFinder {
    /// The target's DR position while the laser tracks it (a fix within [`FIX_TTL`]).
    pub(super) fn target_in_view(&self, now: Instant) -> Option<Vector2> {
        self.target_fix
            .filter(|(at, _)| now.saturating_duration_since(*at) <= FIX_TTL)
            .map(|(_, p)| p)
    }

    /// Skeeter's DR position while the laser sees it (a fix within [`FIX_TTL`]).
    pub(super) fn skeeter_in_view(&self, now: Instant) -> Option<Vector2> {
        self.skeeter_fix
            .filter(|(at, _)| now.saturating_duration_since(*at) <= FIX_TTL)
            .map(|(_, p)| p)
    }

    /// A new target: forget the old one's fix (the reached one is still remembered).
    pub(super) fn forget_target(&mut self) {
        self.target_fix = None;
    }

    /// `colour` was reached at `at` (DR frame).
    pub(super) fn mark_reached(&mut self, colour: Option<String>, at: Vector2) {
        self.reached_target = colour.zip(Some(at));
    }

    /// Look for Skeeter in `scan` where θ1 + 180° (`scout_bearing` + π) says it is, Scooter
    /// at `dr` heading `h` (common frame).
    pub(super) fn find_skeeter(
        &mut self,
        scan: &LaserScan,
        cfg: &ScooterConfig,
        (h, dr): (f64, Vector2),
        scout_bearing: f64,
        now: Instant,
    ) {
        let expected = normalize_angle(scout_bearing + PI);
        let sr = cfg.skeeter_diameter_m / 2.0;
        let best = laser_clusters(
            scan,
            &cfg.laser_mount,
            cfg.laser_max_range_m,
            cfg.cluster_gap_m,
            sr,
        )
        .into_iter()
        .filter(|c| (c.width_m - cfg.skeeter_diameter_m).abs() <= cfg.skeeter_diameter_tolerance_m)
        .filter_map(|c| {
            let d = rotate(h, c.centre.coords);
            let err = normalize_angle(d.y.atan2(d.x) - expected).abs();
            (err <= cfg.skeeter_bearing_tolerance_rad).then_some((dr + d, err))
        })
        .min_by(|a, b| a.1.total_cmp(&b.1));
        if let Some((p, _)) = best {
            self.skeeter_fix = Some((now, p));
        }
    }

    /// Look for `target` in `scan`, Scooter at `dr` heading `h`; `plan` and
    /// `desired_heading` (the heading-calculation agent's) say where it should be.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn find_target(
        &mut self,
        scan: &LaserScan,
        cfg: &ScooterConfig,
        (h, dr): (f64, Vector2),
        target: &str,
        plan: Option<Plan>,
        desired_heading: Option<f64>,
        now: Instant,
    ) {
        let r = cfg.target_diameter_m / 2.0;
        let clusters = laser_clusters(
            scan,
            &cfg.laser_mount,
            cfg.laser_max_range_m,
            cfg.cluster_gap_m,
            r,
        );
        let target_sized = |c: &Cluster| cfg.is_target_width(c.width_m);
        // The same clusters with bigger range jumps joined: a piece of a wider object (Skeeter
        // split by noise, a wall seen at a slant) is no target, whatever the estimate says.
        let joined = laser_clusters(
            scan,
            &cfg.laser_mount,
            cfg.laser_max_range_m,
            cfg.join_gap_m.max(cfg.cluster_gap_m),
            r,
        );
        let whole = |c: &Cluster| {
            joined.iter().any(|j| {
                target_sized(j) && (j.centre - c.centre).norm() <= cfg.diameter_tolerance_m
            })
        };
        let to_dr = |c: &Point2| dr + rotate(h, c.coords);
        // The previous target (another colour) is not this one.
        let previous = self
            .reached_target
            .as_ref()
            .filter(|(colour, _)| colour != target)
            .map(|(_, p)| *p);
        let expected_point = match plan {
            Some(Plan::Point(p)) => Some(p),
            _ => None,
        };
        // While the target is being tracked, it is where we saw it last.
        let tracked = self.target_in_view(now);
        let best = clusters
            .iter()
            .filter(|c| target_sized(c) && c.centre.coords.norm() <= cfg.see_distance_m && whole(c))
            .filter_map(|c| {
                let p = to_dr(&c.centre);
                if previous.is_some_and(|q| (p - q).norm() <= cfg.match_radius_m) {
                    return None;
                }
                let score = if let Some(t) = tracked {
                    (p - t).norm()
                } else if cfg.target_recognition == TargetRecognition::InView {
                    // Nearest first; any distance within sight matches.
                    return Some((p, c.centre.coords.norm()));
                } else if let Some(e) = expected_point {
                    (p - e).norm()
                } else {
                    let hd = desired_heading?;
                    let d = p - dr;
                    let err = normalize_angle(d.y.atan2(d.x) - hd).abs();
                    return (err <= cfg.bearing_tolerance_rad).then_some((p, err));
                };
                (score <= cfg.match_radius_m).then_some((p, score))
            })
            .min_by(|a, b| a.1.total_cmp(&b.1));
        if let Some((p, _)) = best {
            self.target_fix = Some((now, p));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mission::scooter::testkit::scan;
    use ima_hal::laser::BeamFlags;

    fn at(ms: u64) -> Instant {
        Instant::from_millis(ms)
    }

    fn in_view() -> ScooterConfig {
        ScooterConfig {
            target_recognition: TargetRecognition::InView,
            ..ScooterConfig::default()
        }
    }

    #[test]
    fn clusters_measure_width_and_centre() {
        let cfg = ScooterConfig::default();
        let s = scan((0.0, 0.0, 0.0), &cfg.laser_mount, &[([2.0, 0.5], 0.15)]);
        let c = laser_clusters(&s, &cfg.laser_mount, 8.0, 0.1, 0.15);
        assert_eq!(c.len(), 1, "{c:?}");
        assert!((c[0].centre - Point2::new(2.0, 0.5)).norm() < 0.1, "{c:?}");
        assert!(c[0].width_m > 0.15 && c[0].width_m < 0.35, "{c:?}");
    }

    #[test]
    fn finds_the_target_in_view_and_forgets_it_after_the_ttl() {
        let cfg = in_view();
        let mut f = TargetFinder::default();
        let s = scan((0.0, 0.0, 0.0), &cfg.laser_mount, &[([1.0, 0.3], 0.15)]);
        f.find_target(&s, &cfg, (0.0, Vector2::zeros()), "red", None, None, at(0));
        let p = f.target_in_view(at(0)).unwrap();
        assert!((p - Vector2::new(1.0, 0.3)).norm() < 0.1, "{p:?}");
        assert!(f.target_in_view(at(0) + FIX_TTL).is_some());
        assert!(f.target_in_view(at(1) + FIX_TTL).is_none());
        f.forget_target();
        assert!(f.target_in_view(at(0)).is_none());
    }

    #[test]
    fn the_target_reached_is_not_the_next_one_and_estimates_gate_recognition() {
        let mut f = TargetFinder::default();
        let cfg = in_view();
        let s = scan((0.0, 0.0, 0.0), &cfg.laser_mount, &[([1.0, 0.0], 0.15)]);
        f.mark_reached(Some("red".to_owned()), Vector2::new(1.0, 0.0));
        f.find_target(
            &s,
            &cfg,
            (0.0, Vector2::zeros()),
            "green",
            None,
            None,
            at(0),
        );
        assert!(f.target_in_view(at(0)).is_none(), "red is not green");
        f.find_target(&s, &cfg, (0.0, Vector2::zeros()), "red", None, None, at(0));
        assert!(f.target_in_view(at(0)).is_some(), "but red is red");
        // Near-estimate: only where the heading plan points.
        let cfg = ScooterConfig::default();
        let mut f = TargetFinder::default();
        let off = Some(90f64.to_radians());
        f.find_target(&s, &cfg, (0.0, Vector2::zeros()), "red", None, off, at(0));
        assert!(f.target_in_view(at(0)).is_none(), "90° off the plan");
        f.find_target(
            &s,
            &cfg,
            (0.0, Vector2::zeros()),
            "red",
            None,
            Some(0.1),
            at(0),
        );
        assert!(f.target_in_view(at(0)).is_some());
    }

    /// A wall 1.2 m ahead, its ranges pushed ±60 mm in blocks of 12 beams (as the SICK's
    /// ±50 mm noise can, most easily where the wall is seen at a slant): jumps of 120 mm
    /// split it into target-sized pieces.
    fn noisy_wall_in_pieces() -> LaserScan {
        let mut s = LaserScan::new(-PI / 2.0, PI / 180.0);
        for k in 0..181u32 {
            let a = -PI / 2.0 + f64::from(k) * PI / 180.0;
            let r = 1.2 / a.cos();
            let push = if (k / 12) % 2 == 0 { 0.06 } else { -0.06 };
            if a.cos() > 0.15 && r + push < 8.0 {
                s.push((r + push) as f32, BeamFlags::VALID).unwrap();
            } else {
                s.push(f32::NAN, BeamFlags::NO_RETURN).unwrap();
            }
        }
        s
    }

    #[test]
    fn a_piece_of_a_wall_is_no_target_near_the_estimate_either() {
        // The demonstration sometimes declared green reached beside the arena's wall, 2–3 m
        // from green: the wall's noisy returns made target-sized clusters where the heading
        // estimate pointed.
        let cfg = ScooterConfig::default();
        assert_eq!(cfg.target_recognition, TargetRecognition::NearEstimate);
        let s = noisy_wall_in_pieces();
        let r = cfg.target_diameter_m / 2.0;
        let max = cfg.laser_max_range_m;
        let sized = laser_clusters(&s, &cfg.laser_mount, max, cfg.cluster_gap_m, r)
            .into_iter()
            .filter(|c| {
                cfg.is_target_width(c.width_m) && c.centre.coords.norm() <= cfg.see_distance_m
            })
            .count();
        assert!(
            sized >= 2,
            "the wall must come in target-sized pieces: {sized}"
        );
        // A post 0.7 m ahead, clear of the same wall.
        let mut with_post = LaserScan::new(-PI / 2.0, PI / 180.0);
        let post = scan((0.0, 0.0, 0.0), &cfg.laser_mount, &[([0.7, 0.0], 0.15)]);
        for ((_, w, wf), (_, p, pf)) in s.beams().zip(post.beams()) {
            let (r, fl) = if pf.is_valid() { (p, pf) } else { (w, wf) };
            with_post.push(r, fl).unwrap();
        }
        for recognition in [TargetRecognition::NearEstimate, TargetRecognition::InView] {
            let cfg = ScooterConfig {
                target_recognition: recognition,
                ..ScooterConfig::default()
            };
            // Scooter at the origin, facing the wall, the estimate straight ahead.
            let look = |scan: &LaserScan| {
                let mut f = TargetFinder::default();
                let pose = (0.0, Vector2::zeros());
                f.find_target(scan, &cfg, pose, "green", None, Some(0.0), at(0));
                f.target_in_view(at(0))
            };
            assert!(look(&s).is_none(), "{}", recognition.as_str());
            // The post is still the target.
            let p = look(&with_post).expect("the post");
            assert!((p - Vector2::new(0.7, 0.0)).norm() < 0.1, "{p:?}");
        }
    }

    #[test]
    fn skeeter_is_found_only_where_its_bearing_says() {
        let cfg = ScooterConfig::default();
        let mut f = TargetFinder::default();
        // Skeeter (0.66 m wide) 2 m ahead: Skeeter → Scooter bearing is 180°.
        let s = scan((0.0, 0.0, 0.0), &cfg.laser_mount, &[([2.0, 0.0], 0.33)]);
        f.find_skeeter(&s, &cfg, (0.0, Vector2::zeros()), 0.0, at(0));
        assert!(
            f.skeeter_in_view(at(0)).is_none(),
            "expected behind Scooter"
        );
        f.find_skeeter(
            &s,
            &cfg,
            (0.0, Vector2::zeros()),
            core::f64::consts::PI,
            at(0),
        );
        let p = f.skeeter_in_view(at(0)).unwrap();
        assert!((p - Vector2::new(2.0, 0.0)).norm() < 0.1, "{p:?}");
    }
}

//! The heading agent: Scooter's heading θh in the common frame from the compass, odometry
//! or both fused ([`HeadingSource`]), and its dead-reckoning (DR) position: odometry
//! distance increments rotated by θh, with a short history so that the heading-calculation
//! agent can ask where Scooter was when Skeeter's camera saw it.

use std::collections::VecDeque;

use ima_hal::base::Odometry;
use ima_hal::{Instant, Isometry2, Vector2, normalize_angle};

use super::{HeadingSource, ScooterConfig, unit};

/// DR positions kept for [`HeadingAgent::dr_at`].
const HISTORY_LEN: usize = 4096;

/// θh from each source and the DR position (see the [module docs](self)).
#[derive(Debug, Clone)]
pub(super) struct HeadingAgent {
    source: HeadingSource,
    fusion_gain: f64,
    odometry_offset_rad: f64,
    compass: Option<f64>,
    odo_prev: Option<Isometry2>,
    odo_theta: Option<f64>,
    fused: Option<f64>,
    dr: Vector2,
    history: VecDeque<(Instant, Vector2)>,
}

impl HeadingAgent {
    /// No heading yet, at the DR origin; source, fusion gain and odometry offset from `cfg`.
    pub(super) fn new(cfg: &ScooterConfig) -> Self {
        Self {
            source: cfg.heading_source,
            fusion_gain: cfg.fusion_gain,
            odometry_offset_rad: cfg.odometry_heading_offset_rad,
            compass: None,
            odo_prev: None,
            odo_theta: None,
            fused: None,
            dr: Vector2::zeros(),
            history: VecDeque::new(),
        }
    }

    /// θh from the configured source, if known.
    pub(super) fn heading(&self) -> Option<f64> {
        match self.source {
            HeadingSource::Compass => self.compass,
            HeadingSource::Odometry => self.odo_theta,
            HeadingSource::Fused => self.fused,
        }
    }

    /// The DR position.
    pub(super) fn dr(&self) -> Vector2 {
        self.dr
    }

    /// θh and the DR position, when θh is known.
    pub(super) fn pose(&self) -> Option<(f64, Vector2)> {
        self.heading().map(|h| (h, self.dr))
    }

    /// A compass heading, radians, common frame; not finite is ignored.
    pub(super) fn handle_compass(&mut self, heading_rad: f64) {
        if !heading_rad.is_finite() {
            return;
        }
        let h = normalize_angle(heading_rad);
        self.compass = Some(h);
        self.fused = Some(match self.fused {
            None => h,
            Some(f) => {
                let k = self.fusion_gain.clamp(0.0, 1.0);
                normalize_angle(f + k * normalize_angle(h - f))
            }
        });
    }

    /// An odometry reading: advances the odometry heading, the fused heading and the DR
    /// position (distance increments rotated by θh at mid-step).
    pub(super) fn handle_odometry(&mut self, odo: &Odometry, now: Instant) {
        let pose = odo.pose;
        let th = pose.rotation.angle();
        if !(th.is_finite() && pose.translation.vector.iter().all(|c| c.is_finite())) {
            return;
        }
        let odo_theta = normalize_angle(th + self.odometry_offset_rad);
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
        } else if self.source != HeadingSource::Compass {
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

    /// The DR position at `t` (linear interpolation in the history; the nearest end
    /// outside it).
    pub(super) fn dr_at(&self, t: Instant) -> Vector2 {
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
}

#[cfg(test)]
mod tests {
    use core::f64::consts::FRAC_PI_2;

    use super::*;

    fn agent(source: HeadingSource) -> HeadingAgent {
        HeadingAgent::new(&ScooterConfig {
            heading_source: source,
            fusion_gain: 0.5,
            odometry_heading_offset_rad: FRAC_PI_2,
            ..ScooterConfig::default()
        })
    }

    fn odo(x: f64, y: f64, th: f64) -> Odometry {
        Odometry {
            pose: Isometry2::new(Vector2::new(x, y), th),
            v_m_s: 0.0,
            omega_rad_s: 0.0,
        }
    }

    #[test]
    fn each_source_gives_its_own_heading() {
        let mut c = agent(HeadingSource::Compass);
        assert_eq!(c.heading(), None);
        c.handle_odometry(&odo(0.0, 0.0, 0.0), Instant::ZERO);
        assert_eq!(c.heading(), None, "odometry is not the compass");
        c.handle_compass(0.3);
        assert_eq!(c.heading(), Some(0.3));
        c.handle_compass(f64::NAN);
        assert_eq!(
            c.heading(),
            Some(0.3),
            "a reading that is not finite is ignored"
        );

        let mut o = agent(HeadingSource::Odometry);
        o.handle_compass(0.3);
        o.handle_odometry(&odo(0.0, 0.0, 0.1), Instant::ZERO);
        assert!(
            (o.heading().unwrap() - (0.1 + FRAC_PI_2)).abs() < 1e-12,
            "offset added"
        );
    }

    #[test]
    fn fused_heading_moves_toward_the_compass_by_the_gain() {
        let mut f = agent(HeadingSource::Fused);
        f.handle_compass(0.0);
        f.handle_compass(0.4);
        assert!((f.heading().unwrap() - 0.2).abs() < 1e-12);
        // Odometry increments are added as they are.
        f.handle_odometry(&odo(0.0, 0.0, 0.0), Instant::ZERO);
        f.handle_odometry(&odo(0.0, 0.0, 0.1), Instant::from_millis(100));
        assert!((f.heading().unwrap() - 0.3).abs() < 1e-12);
    }

    #[test]
    fn dead_reckoning_rotates_distance_by_the_heading_and_interpolates_history() {
        let mut a = agent(HeadingSource::Compass);
        a.handle_compass(FRAC_PI_2);
        a.handle_odometry(&odo(0.0, 0.0, 0.0), Instant::from_millis(0));
        a.handle_odometry(&odo(2.0, 0.0, 0.0), Instant::from_millis(1000));
        let p = a.dr();
        assert!(p.x.abs() < 1e-12 && (p.y - 2.0).abs() < 1e-12, "{p:?}");
        let mid = a.dr_at(Instant::from_millis(250));
        assert!((mid.y - 0.5).abs() < 1e-12, "{mid:?}");
        assert_eq!(
            a.dr_at(Instant::from_millis(5000)),
            a.dr(),
            "after the history: now"
        );
        // A pose that is not finite is ignored.
        a.handle_odometry(&odo(f64::INFINITY, 0.0, 0.0), Instant::from_millis(1100));
        assert_eq!(a.dr(), p);
    }
}

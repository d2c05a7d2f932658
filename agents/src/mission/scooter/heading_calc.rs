//! The heading-calculation agent: from each sample of Skeeter's SES that holds both
//! Scooter and the target, a plan ([`Plan`]) by the configured [`HeadingRule`]; it also
//! runs the "lost" timer (no sample for [`ScooterConfig::lost_after`]) and paces the
//! re-requests of a heading.

use std::collections::VecDeque;

use ima_hal::{Instant, Vector2};

use super::heading::HeadingAgent;
use super::{HeadingRule, Plan, ScooterConfig, unit};
use crate::heading::{self, Observation, Range, RangeSource};
use crate::ses::shared::{SharedForm, SharedRecord};

/// Ranges (SES, triangulated) beyond this are not believed, metres.
const MAX_RANGE_M: f64 = 1000.0;

/// What the last usable sample said about Scooter.
#[derive(Debug, Clone, Copy)]
pub(super) struct SesFix {
    /// θ1, common frame.
    pub(super) scout_bearing: f64,
    /// DR position when Skeeter saw Scooter.
    pub(super) p_rec: Vector2,
    /// When Skeeter saw Scooter, on Skeeter's clock (the record's own time): the same
    /// sighting handled again (the runtime replays the latest sample to a new target) is
    /// recognised by it.
    pub(super) sensed: Instant,
    /// Scooter's range from Skeeter at that sighting, if one was known (laser, SES or
    /// triangulated), metres.
    pub(super) scout_range_m: Option<f64>,
}

/// The plan, the samples averaged into it, and the lost timer (see the [module docs](self)).
#[derive(Debug, Clone, Default)]
pub(super) struct HeadingCalculator {
    plan: Option<Plan>,
    target_samples: VecDeque<Vector2>,
    last_fix: Option<SesFix>,
    /// Skeeter's DR position from the last ranged sample (Skeeter never moves).
    skeeter_dr: Option<Vector2>,
    last_ses_at: Option<Instant>,
    last_request_at: Option<Instant>,
}

/// What a sample gave.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(super) struct SampleOutcome {
    /// A new plan was made.
    pub(super) planned: bool,
    /// Skeeter's DR position, when the sample ranged Scooter.
    pub(super) skeeter_dr: Option<Vector2>,
}

fn best<'a>(form: &'a SharedForm, name: &str) -> Option<&'a SharedRecord> {
    form.records
        .iter()
        .filter(|r| r.object == name && r.bearing.azimuth_rad.is_finite())
        .max_by(|a, b| a.confidence.total_cmp(&b.confidence))
}

fn plan_is_finite(p: Plan) -> bool {
    match p {
        Plan::Heading(h) => h.is_finite(),
        Plan::Point(v) => v.iter().all(|c| c.is_finite()),
    }
}

impl HeadingCalculator {
    /// The current plan.
    pub(super) fn plan(&self) -> Option<Plan> {
        self.plan
    }

    /// The last sample's fix on Scooter (kept across targets).
    pub(super) fn last_fix(&self) -> Option<SesFix> {
        self.last_fix
    }

    /// A new target: no plan, no samples, the lost timer runs from scratch.
    pub(super) fn new_target(&mut self) {
        self.plan = None;
        self.target_samples.clear();
        self.last_ses_at = None;
        self.last_request_at = None;
    }

    /// The target ended: drop the plan.
    pub(super) fn drop_plan(&mut self) {
        self.plan = None;
    }

    /// The desired common-frame heading θd from Scooter at `dr`, if any.
    pub(super) fn desired_heading(&self, dr: Vector2) -> Option<f64> {
        match self.plan? {
            Plan::Heading(h) => Some(h),
            Plan::Point(p) => {
                let d = p - dr;
                (d.norm() > 1e-6).then(|| d.y.atan2(d.x))
            }
        }
    }

    /// The lost timer: no sample for this target yet, or none for `lost_after`.
    pub(super) fn stale(&self, now: Instant, lost_after: core::time::Duration) -> bool {
        match self.last_ses_at {
            None => true,
            Some(t) => now.saturating_duration_since(t) > lost_after,
        }
    }

    /// Whether to send a heading request now (the first, then one every `lost_after`);
    /// records it when due.
    pub(super) fn request_due(&mut self, now: Instant, lost_after: core::time::Duration) -> bool {
        let due = self
            .last_request_at
            .is_none_or(|t| now.saturating_duration_since(t) >= lost_after);
        if due {
            self.last_request_at = Some(now);
        }
        due
    }

    /// Whether Scooter may keep following the plan while lost: a plan exists and the last
    /// sample is at most `coast_for` old.
    pub(super) fn coasting(&self, now: Instant, coast_for: core::time::Duration) -> bool {
        self.plan.is_some()
            && self
                .last_ses_at
                .is_some_and(|t| now.saturating_duration_since(t) <= coast_for)
    }

    /// A sample of Skeeter's SES for target `colour`: with both Scooter's
    /// (`cfg.robot_name`) and the target's records, a new plan. `position` gives Scooter's
    /// DR history; `skeeter_seen` is Skeeter's DR position when Scooter's laser sees it
    /// (it beats Skeeter's own range estimate).
    pub(super) fn handle_sample(
        &mut self,
        form: &SharedForm,
        colour: &str,
        cfg: &ScooterConfig,
        position: &HeadingAgent,
        skeeter_seen: Option<Vector2>,
        now: Instant,
    ) -> SampleOutcome {
        let mut out = SampleOutcome::default();
        let (Some(me), Some(tg)) = (best(form, &cfg.robot_name), best(form, colour)) else {
            return out;
        };
        // Sensing time on our clock: now − (sent_at − time).
        let age = form.sent_at.saturating_duration_since(me.time);
        let seen_at = Instant::from_micros(
            now.as_micros()
                .saturating_sub(u64::try_from(age.as_micros()).unwrap_or(u64::MAX)),
        );
        let theta1 = me.bearing.azimuth_rad;
        let theta2 = tg.bearing.azimuth_rad;
        // The same sighting again (a replayed sample, or a copy): Scooter was where it was
        // the first time, with the range found then. Placing it by this handling's `now`
        // would put an old bearing at Scooter's current position, and the two fixes of one
        // sighting triangulate nothing.
        let previous = self.last_fix;
        let same = previous.filter(|f| f.sensed == me.time && f.scout_bearing == theta1);
        let p_rec = same.map_or_else(|| position.dr_at(seen_at), |f| f.p_rec);
        let mut scout_range_m = None;
        self.last_ses_at = Some(now);
        let plan = match cfg.heading_rule {
            _ if !(theta1.is_finite() && theta2.is_finite()) => None,
            HeadingRule::Thesis => heading::thesis_heading(theta1, theta2)
                .ok()
                .map(Plan::Heading),
            HeadingRule::RangeAware => {
                let valid =
                    |r: Option<f64>| r.filter(|m| m.is_finite() && (0.0..=MAX_RANGE_M).contains(m));
                // Scooter's own laser fix on Skeeter (fresh) beats Skeeter's estimate.
                let laser = skeeter_seen.map(|s| Range {
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
                    same?.scout_range_m.map(|metres| Range {
                        metres,
                        source: RangeSource::Triangulated,
                    })
                });
                let scout = scout.or_else(|| {
                    let prev = previous.filter(|_| same.is_none())?;
                    heading::triangulate_scout_range(prev.scout_bearing, theta1, p_rec - prev.p_rec)
                        .ok()
                        .filter(|m| m.is_finite() && (0.0..=MAX_RANGE_M).contains(m))
                        .map(|metres| Range {
                            metres,
                            source: RangeSource::Triangulated,
                        })
                });
                // No parallax (Scooter moved along the bearing line, or across Skeeter):
                // Skeeter is where an earlier ranged sample put it. Without this, the
                // fallback heading would be one from where Scooter was when seen, not
                // from where it is.
                let scout = scout.or_else(|| {
                    self.skeeter_dr
                        .map(|s| (s - p_rec).norm())
                        .filter(|m| m.is_finite() && (0.0..=MAX_RANGE_M).contains(m))
                        .map(|metres| Range {
                            metres,
                            source: RangeSource::Triangulated,
                        })
                });
                scout_range_m = scout.map(|r| r.metres);
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
                        out.skeeter_dr = Some(p_rec - unit(theta1) * s.metres);
                        self.skeeter_dr = out.skeeter_dr;
                        if self.target_samples.len() >= cfg.max_target_samples.max(1) {
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
        self.last_fix = Some(SesFix {
            scout_bearing: theta1,
            p_rec,
            sensed: me.time,
            scout_range_m: scout_range_m.or(same.and_then(|f| f.scout_range_m)),
        });
        if let Some(p) = plan.filter(|p| plan_is_finite(*p)) {
            self.plan = Some(p);
            out.planned = true;
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use core::time::Duration;

    use ima_hal::base::Odometry;

    use super::*;
    use crate::mission::scooter::HeadingSource;
    use crate::mission::scooter::testkit::{form, rec};

    fn cfg(rule: HeadingRule) -> ScooterConfig {
        ScooterConfig {
            heading_rule: rule,
            heading_source: HeadingSource::Compass,
            ..ScooterConfig::default()
        }
    }

    fn at_origin(cfg: &ScooterConfig) -> HeadingAgent {
        let mut h = HeadingAgent::new(cfg);
        h.handle_compass(0.0);
        h.handle_odometry(&Odometry::origin(), Instant::ZERO);
        h
    }

    #[test]
    fn a_sample_with_scooter_and_the_target_makes_a_thesis_plan() {
        let c = cfg(HeadingRule::Thesis);
        let pos = at_origin(&c);
        let mut calc = HeadingCalculator::default();
        let now = Instant::from_millis(1_000);
        // Only Scooter: no plan, and the lost timer is not reset.
        let only_me = form(vec![rec("scooter", 180.0, None, now)], now);
        assert!(
            !calc
                .handle_sample(&only_me, "red", &c, &pos, None, now)
                .planned
        );
        assert!(calc.stale(now, c.lost_after));
        let both = form(
            vec![
                rec("scooter", 180.0, None, now),
                rec("red", 90.0, None, now),
            ],
            now,
        );
        let out = calc.handle_sample(&both, "red", &c, &pos, None, now);
        assert!(out.planned);
        assert_eq!(out.skeeter_dr, None, "bearings only place no Skeeter");
        let want = heading::thesis_heading(PI_F, 90f64.to_radians()).unwrap();
        assert_eq!(calc.plan(), Some(Plan::Heading(want)));
        assert_eq!(calc.desired_heading(Vector2::zeros()), Some(want));
        assert!(!calc.stale(now, c.lost_after));
        assert!(calc.stale(now + c.lost_after + Duration::from_millis(1), c.lost_after));
        calc.new_target();
        assert_eq!(calc.plan(), None);
        assert!(
            calc.last_fix().is_some(),
            "the fix on Scooter outlives the target"
        );
    }

    const PI_F: f64 = core::f64::consts::PI;

    #[test]
    fn ranged_samples_average_into_a_point_and_place_skeeter() {
        let c = cfg(HeadingRule::RangeAware);
        let pos = at_origin(&c);
        let mut calc = HeadingCalculator::default();
        let now = Instant::from_millis(1_000);
        // Skeeter 4 m west of Scooter (θ1 = 180° from Skeeter), target 3 m north of Skeeter.
        let s1 = form(
            vec![
                rec("scooter", 0.0, Some(4.0), now),
                rec("red", 90.0, Some(3.0), now),
            ],
            now,
        );
        let out = calc.handle_sample(&s1, "red", &c, &pos, None, now);
        let skeeter = out.skeeter_dr.unwrap();
        assert!(
            (skeeter - Vector2::new(-4.0, 0.0)).norm() < 1e-9,
            "{skeeter:?}"
        );
        let Some(Plan::Point(p)) = calc.plan() else {
            panic!("{:?}", calc.plan())
        };
        assert!((p - Vector2::new(-4.0, 3.0)).norm() < 1e-9, "{p:?}");
        // A second sample 1 m further: the plan is the mean.
        let s2 = form(
            vec![
                rec("scooter", 0.0, Some(4.0), now),
                rec("red", 90.0, Some(4.0), now),
            ],
            now,
        );
        calc.handle_sample(&s2, "red", &c, &pos, None, now);
        let Some(Plan::Point(p)) = calc.plan() else {
            panic!()
        };
        assert!((p - Vector2::new(-4.0, 3.5)).norm() < 1e-9, "{p:?}");
        // Scooter's laser fix on Skeeter beats the SES range.
        calc.new_target();
        let out = calc.handle_sample(&s1, "red", &c, &pos, Some(Vector2::new(-2.0, 0.0)), now);
        assert!((out.skeeter_dr.unwrap() - Vector2::new(-2.0, 0.0)).norm() < 1e-9);
    }

    /// Under load: a sample whose Scooter record has no range, taken after Scooter moved
    /// along Skeeter's line of sight (no parallax to triangulate), must not fall back to a
    /// bearing heading from where Scooter was: Skeeter is where the last ranged sample put it.
    #[test]
    fn without_range_or_parallax_skeeter_is_where_a_ranged_sample_put_it() {
        let c = cfg(HeadingRule::RangeAware);
        let mut pos = at_origin(&c);
        let mut calc = HeadingCalculator::default();
        // Skeeter 4 m west of Scooter (θ1 = 0°, ranged); target 3 m north of Skeeter.
        let t0 = Instant::from_millis(0);
        let s0 = form(
            vec![
                rec("scooter", 0.0, Some(4.0), t0),
                rec("red", 90.0, Some(3.0), t0),
            ],
            t0,
        );
        assert!(calc.handle_sample(&s0, "red", &c, &pos, None, t0).planned);
        // Scooter drives 2 m toward Skeeter (west): still at 0°, now unranged.
        pos.handle_compass(PI_F);
        pos.handle_odometry(&Odometry::origin(), Instant::from_millis(100));
        pos.handle_odometry(
            &Odometry {
                pose: ima_hal::Isometry2::new(Vector2::new(2.0, 0.0), 0.0),
                ..Odometry::origin()
            },
            Instant::from_millis(5_000),
        );
        let t1 = Instant::from_millis(5_000);
        let s1 = form(
            vec![
                rec("scooter", 0.0, None, t1),
                rec("red", 90.0, Some(3.0), t1),
            ],
            t1,
        );
        calc.new_target();
        assert!(calc.handle_sample(&s1, "red", &c, &pos, None, t1).planned);
        match calc.plan() {
            Some(Plan::Point(p)) => assert!((p - Vector2::new(-4.0, 3.0)).norm() < 1e-6, "{p}"),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn heading_requests_are_paced_and_coasting_ends() {
        let mut calc = HeadingCalculator::default();
        let lost = Duration::from_secs(12);
        assert!(calc.request_due(Instant::from_millis(0), lost));
        assert!(!calc.request_due(Instant::from_millis(11_000), lost));
        assert!(calc.request_due(Instant::from_millis(12_000), lost));
        assert!(
            !calc.coasting(Instant::from_millis(12_000), lost),
            "no plan, no coasting"
        );
    }
}

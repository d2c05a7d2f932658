//! The go-home agent: Skeeter's stress call `scooter-lost` calls Scooter back until Skeeter
//! sees it again (`scooter-found`, or an SES sample with a fresh `scooter` record, as the
//! broadcast may be lost); the way home is toward Skeeter's DR position when a ranged
//! sample placed it, else along θ1 + 180°.

use core::f64::consts::PI;

use ima_hal::{Vector2, normalize_angle};

use super::{Goal, ScooterConfig};
use crate::ses::shared::SharedForm;

/// Radius of the circle round Skeeter's estimated position that is not an obstacle, metres.
const SKEETER_CLEAR_RADIUS_M: f64 = 0.6;

/// The call-back state and where home is (see the [module docs](self)).
#[derive(Debug, Clone, Default)]
pub(super) struct HomeAgent {
    called_back: bool,
    /// Skeeter's DR position, from the last ranged sample.
    skeeter_dr: Option<Vector2>,
}

impl HomeAgent {
    /// Whether Scooter is called back.
    pub(super) fn called_back(&self) -> bool {
        self.called_back
    }

    /// `scooter-lost` (`true`) or `scooter-found` (`false`) heard.
    pub(super) fn set_called_back(&mut self, called_back: bool) {
        self.called_back = called_back;
    }

    /// Skeeter's DR position from a ranged sample.
    pub(super) fn set_skeeter(&mut self, at: Vector2) {
        self.skeeter_dr = Some(at);
    }

    /// An SES sample: a `scooter` record at most [`ScooterConfig::found_record_max_age`]
    /// old (sensing time against send time) ends a call-back.
    pub(super) fn handle_sample(&mut self, form: &SharedForm, cfg: &ScooterConfig) {
        if self.called_back
            && form.records.iter().any(|r| {
                r.object == cfg.robot_name
                    && r.bearing.azimuth_rad.is_finite()
                    && form.sent_at.saturating_duration_since(r.time) <= cfg.found_record_max_age
            })
        {
            self.called_back = false;
        }
    }

    /// The way home from `dr`: toward Skeeter's DR position when known, else along
    /// `scout_bearing` (θ1 of the last sample) + π with no known distance.
    pub(super) fn goal(&self, dr: Vector2, scout_bearing: Option<f64>) -> Option<Goal> {
        match self.skeeter_dr {
            Some(s) => {
                let d = s - dr;
                Some((d.y.atan2(d.x), d.norm(), Some((s, SKEETER_CLEAR_RADIUS_M))))
            }
            None => scout_bearing.map(|b| (normalize_angle(b + PI), f64::INFINITY, None)),
        }
    }
}

#[cfg(test)]
mod tests {
    use core::time::Duration;

    use ima_hal::Instant;

    use super::*;
    use crate::mission::scooter::testkit::{form, rec};

    #[test]
    fn home_is_skeeter_when_placed_else_back_along_the_bearing() {
        let mut home = HomeAgent::default();
        assert_eq!(home.goal(Vector2::zeros(), None), None);
        let (dir, dist, clear) = home.goal(Vector2::zeros(), Some(0.0)).unwrap();
        assert!((dir.abs() - PI).abs() < 1e-12 && dist.is_infinite() && clear.is_none());
        home.set_skeeter(Vector2::new(0.0, 3.0));
        let (dir, dist, clear) = home.goal(Vector2::new(0.0, 1.0), Some(0.0)).unwrap();
        assert!((dir - PI / 2.0).abs() < 1e-12);
        assert!((dist - 2.0).abs() < 1e-12);
        assert_eq!(
            clear,
            Some((Vector2::new(0.0, 3.0), SKEETER_CLEAR_RADIUS_M))
        );
    }

    #[test]
    fn a_fresh_scooter_record_ends_a_call_back_an_old_one_does_not() {
        let cfg = ScooterConfig::default();
        let mut home = HomeAgent::default();
        home.set_called_back(true);
        let sent = Instant::from_millis(100_000);
        let old = sent - cfg.found_record_max_age - Duration::from_secs(1);
        home.handle_sample(&form(vec![rec("scooter", 10.0, None, old)], sent), &cfg);
        assert!(home.called_back());
        home.handle_sample(&form(vec![rec("red", 10.0, None, sent)], sent), &cfg);
        assert!(
            home.called_back(),
            "another object's record says nothing of Scooter"
        );
        home.handle_sample(&form(vec![rec("scooter", 10.0, None, sent)], sent), &cfg);
        assert!(!home.called_back());
    }
}

//! The controller: turn toward a goal direction (or the avoider's), in place while the
//! heading error is large (with hysteresis), otherwise at the cruise speed with
//! proportional steering; and the last guard before the wheels.

use ima_hal::base::VelocityCommand;
use ima_hal::normalize_angle;

use super::{Goal, ScooterConfig};

/// The turn rate and the turn-in-place latch.
#[derive(Debug, Clone, Default)]
pub(super) struct Controller {
    omega: f64,
    turning_in_place: bool,
}

fn finite_or_zero(v: f64) -> f64 {
    if v.is_finite() { v } else { 0.0 }
}

impl Controller {
    /// No turn (the next drive starts from a zero turn rate).
    pub(super) fn halt(&mut self) {
        self.omega = 0.0;
    }

    /// Drive toward `goal` with heading `h`; `avoid_steer` (robot frame) overrides the
    /// goal's direction; when `called_back`, it stops within
    /// [`ScooterConfig::home_stop_distance_m`] of the goal. `dt` is the time since the last
    /// step, seconds.
    pub(super) fn drive(
        &mut self,
        cfg: &ScooterConfig,
        goal: Option<Goal>,
        h: Option<f64>,
        avoid_steer: Option<f64>,
        called_back: bool,
        dt: f64,
    ) -> VelocityCommand {
        let (Some(h), Some((dir, dist, _))) = (h, goal) else {
            self.omega = 0.0;
            return VelocityCommand::ZERO;
        };
        // Robot-frame error: the avoider's direction already is robot-frame.
        let err = avoid_steer.unwrap_or_else(|| normalize_angle(dir - h));
        let homing_done = called_back && dist <= cfg.home_stop_distance_m;
        if self.turning_in_place {
            if err.abs() < cfg.turn_in_place_exit_rad {
                self.turning_in_place = false;
            }
        } else if err.abs() > cfg.turn_in_place_enter_rad {
            self.turning_in_place = true;
        }
        let max_w = cfg.max_turn_rate_rad_s.abs();
        let mut w = (cfg.steering_gain * err).clamp(-max_w, max_w);
        if self.turning_in_place {
            // Turn in place at a good fraction of the maximum rate.
            w = err.signum() * (cfg.steering_gain * err.abs()).clamp(0.3 * max_w, max_w);
        }
        let tau = cfg.turn_filter_s.max(0.0);
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
            cfg.cruise_speed_m_s
        };
        VelocityCommand::new(v, self.omega)
    }

    /// The last guard before the wheels: a command that is not finite is no motion, and
    /// speeds are clamped to [0, cruise] and ±max turn rate.
    pub(super) fn sanitize(&mut self, cfg: &ScooterConfig, c: VelocityCommand) -> VelocityCommand {
        let max_v = finite_or_zero(cfg.cruise_speed_m_s).abs();
        let max_w = finite_or_zero(cfg.max_turn_rate_rad_s).abs();
        if !(c.v_m_s.is_finite() && c.omega_rad_s.is_finite()) {
            self.omega = 0.0;
            return VelocityCommand::ZERO;
        }
        VelocityCommand::new(
            c.v_m_s.clamp(0.0, max_v),
            c.omega_rad_s.clamp(-max_w, max_w),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg() -> ScooterConfig {
        ScooterConfig::default()
    }

    #[test]
    fn turns_in_place_with_hysteresis_then_drives() {
        let c = cfg();
        let mut k = Controller::default();
        let goal = |deg: f64| Some((deg.to_radians(), f64::INFINITY, None));
        let v = k.drive(&c, goal(90.0), Some(0.0), None, false, 0.1);
        assert_eq!(v.v_m_s, 0.0, "90° off: turn in place");
        assert!(v.omega_rad_s > 0.0);
        // 20° is below the entry threshold but above the exit one: still in place.
        let v = k.drive(&c, goal(20.0), Some(0.0), None, false, 0.1);
        assert_eq!(v.v_m_s, 0.0);
        let v = k.drive(&c, goal(5.0), Some(0.0), None, false, 0.1);
        assert_eq!(
            v.v_m_s, c.cruise_speed_m_s,
            "below the exit threshold: drive"
        );
        let v = k.drive(&c, goal(20.0), Some(0.0), None, false, 0.1);
        assert_eq!(v.v_m_s, c.cruise_speed_m_s, "20° does not re-enter");
        assert!((v.omega_rad_s - (c.steering_gain * 20f64.to_radians()).min(1.0)).abs() < 1e-12);
        // The avoider's direction overrides the goal's.
        let v = k.drive(&c, goal(0.0), Some(0.0), Some(-0.1), false, 0.1);
        assert!(v.omega_rad_s < 0.0);
    }

    #[test]
    fn stops_without_heading_goal_or_when_home() {
        let c = cfg();
        let mut k = Controller::default();
        let g = Some((0.0, 1.0, None));
        assert_eq!(
            k.drive(&c, None, Some(0.0), None, false, 0.1),
            VelocityCommand::ZERO
        );
        assert_eq!(
            k.drive(&c, g, None, None, false, 0.1),
            VelocityCommand::ZERO
        );
        assert_eq!(
            k.drive(&c, g, Some(0.0), None, true, 0.1),
            VelocityCommand::ZERO
        );
        assert!(
            k.drive(&c, g, Some(0.0), None, false, 0.1).v_m_s > 0.0,
            "not called back"
        );
    }

    #[test]
    fn sanitize_clamps_and_refuses_non_finite() {
        let c = cfg();
        let mut k = Controller::default();
        let s = k.sanitize(&c, VelocityCommand::new(5.0, -9.0));
        assert_eq!(
            s,
            VelocityCommand::new(c.cruise_speed_m_s, -c.max_turn_rate_rad_s)
        );
        assert_eq!(k.sanitize(&c, VelocityCommand::new(-1.0, 0.0)).v_m_s, 0.0);
        assert_eq!(
            k.sanitize(&c, VelocityCommand::new(f64::NAN, 0.0)),
            VelocityCommand::ZERO
        );
    }
}

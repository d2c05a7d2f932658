//! Scooter's runtime configuration ([`ima_agents::runtime::scooter`]) from its robot
//! configuration.

use std::time::Duration;

use ima_agents::mission::scooter::{HeadingRule, HeadingSource, ScooterConfig};
use ima_agents::runtime::scooter::ScooterRuntimeConfig;

use crate::config::{self, RobotConfig};

/// The brain's configuration from the robot's.
pub fn brain_config(cfg: &RobotConfig, odometry_offset_rad: f64) -> ScooterConfig {
    let a = &cfg.agent;
    ScooterConfig {
        robot_name: cfg.robot.clone(),
        heading_rule: match a.heading_rule {
            config::HeadingRule::Thesis => HeadingRule::Thesis,
            config::HeadingRule::RangeAware => HeadingRule::RangeAware,
        },
        heading_source: match a.heading_source {
            config::HeadingSource::Compass => HeadingSource::Compass,
            config::HeadingSource::Odometry => HeadingSource::Odometry,
            config::HeadingSource::Both => HeadingSource::Fused,
        },
        cruise_speed_m_s: a.cruise_speed_m_s,
        max_turn_rate_rad_s: a.max_turn_rad_s,
        lost_after: Duration::from_secs_f64(a.lost_timeout_s),
        reach_distance_m: a.reach_distance_m,
        // A negative tolerance accepts no laser cluster as Skeeter: the laser fix is off.
        skeeter_diameter_tolerance_m: if a.laser_ranges_skeeter {
            ScooterConfig::default().skeeter_diameter_tolerance_m
        } else {
            -1.0
        },
        see_distance_m: ScooterConfig::default()
            .see_distance_m
            .max(a.reach_distance_m + 0.6),
        odometry_heading_offset_rad: odometry_offset_rad,
        ..ScooterConfig::default()
    }
}

/// Scooter's runtime configuration from its robot configuration (the brain's odometry
/// offset is set by the runtime at start).
pub fn runtime_config(cfg: &RobotConfig) -> ScooterRuntimeConfig {
    let a = &cfg.agent;
    ScooterRuntimeConfig {
        brain: brain_config(cfg, 0.0),
        control_hz: a.control_hz,
        time_scale: a.time_scale,
        common_heading_deg: a.common_heading_deg,
        compass_deviation_deg: cfg
            .devices
            .compass
            .as_ref()
            .map_or(0.0, |c| c.deviation_deg),
        initial_heading_deg: a.initial_heading_deg,
        ..ScooterRuntimeConfig::default()
    }
}

/// The compass heading in the common frame (radians, counter-clockwise), as the runtime
/// computes it.
#[cfg(test)]
fn common_heading(h: &ima_hal::compass::Heading, cfg: &RobotConfig) -> f64 {
    runtime_config(cfg).common_heading(h)
}

#[cfg(test)]
mod tests {
    use super::*;
    use ima_hal::compass::{Heading, HeadingReference};

    fn cfg() -> RobotConfig {
        RobotConfig::from_toml_str(
            "robot = \"scooter\"\nrole = \"scooter\"\nmock = true\n[peer]\ninsecure = true\nconnect = \"127.0.0.1:1\"\n",
        )
        .unwrap()
    }

    #[test]
    fn compass_headings_map_to_the_common_frame() {
        let mut c = cfg();
        // Compass 60° (clockwise from north) = yaw 30° ENU; common heading east (90°).
        let h = Heading::new(60f64.to_radians(), HeadingReference::Magnetic);
        assert!((common_heading(&h, &c).to_degrees() - 30.0).abs() < 1e-9);
        // Common heading north: Scooter is 60° clockwise of it, i.e. −60° counter-clockwise.
        c.agent.common_heading_deg = 0.0;
        assert!((common_heading(&h, &c).to_degrees() + 60.0).abs() < 1e-9);
        // A deviation of 4° east turns the true heading 4° clockwise.
        c.agent.common_heading_deg = 90.0;
        c.devices.compass = Some(crate::config::CompassDeviceConfig {
            port: "x".into(),
            baud: 4800,
            dialect: crate::config::CompassDialect::Kvh,
            deviation_deg: 4.0,
        });
        assert!((common_heading(&h, &c).to_degrees() - 26.0).abs() < 1e-9);
    }

    #[test]
    fn brain_config_follows_the_robot_config() {
        let mut c = cfg();
        c.agent.heading_rule = crate::config::HeadingRule::Thesis;
        c.agent.heading_source = crate::config::HeadingSource::Odometry;
        c.agent.cruise_speed_m_s = 0.05;
        let b = brain_config(&c, 0.5);
        assert_eq!(b.heading_rule, HeadingRule::Thesis);
        assert_eq!(b.heading_source, HeadingSource::Odometry);
        assert!((b.cruise_speed_m_s - 0.05).abs() < 1e-12);
        assert!((b.odometry_heading_offset_rad - 0.5).abs() < 1e-12);
        assert!((b.reach_distance_m - 1.0).abs() < 1e-12);
        assert!(
            b.skeeter_diameter_tolerance_m < 0.0,
            "laser fix on Skeeter off"
        );
        c.agent.laser_ranges_skeeter = true;
        assert!(brain_config(&c, 0.0).skeeter_diameter_tolerance_m > 0.0);
    }
}

//! Skeeter's runtime configuration ([`ima_agents::runtime::skeeter`]) from its robot
//! configuration.

use std::time::Duration;

use anyhow::{Context, Result};
use ima_agents::mission::msg::SCOOTER_TAG;
use ima_agents::mission::scan::ScanConfig;
use ima_agents::mission::skeeter::SkeeterConfig;
use ima_agents::mission::vision::{ColourDb, ColourSpec, HeadGeometry};
use ima_agents::runtime::skeeter::SkeeterRuntimeConfig;

use crate::config::RobotConfig;

/// The colour database of the configuration (the built-in one when empty).
pub fn colour_db(cfg: &RobotConfig) -> Result<ColourDb> {
    if cfg.agent.colours.is_empty() {
        return Ok(ColourDb::default());
    }
    let mut colours: Vec<ColourSpec> = cfg
        .agent
        .colours
        .iter()
        .map(|c| ColourSpec::new(&c.name, c.rgb, c.diameter_m))
        .collect();
    if !colours.iter().any(|c| c.name == SCOOTER_TAG) {
        let d = ColourDb::default();
        colours.extend(d.colours.into_iter().filter(|c| c.name == SCOOTER_TAG));
    }
    ColourDb::new(colours).map_err(|e| anyhow::anyhow!("agent.colours: {e}"))
}

/// Skeeter's runtime configuration from its robot configuration (reads the SAN network
/// file it names).
pub fn runtime_config(cfg: &RobotConfig) -> Result<SkeeterRuntimeConfig> {
    let mut scan = ScanConfig {
        robot: cfg.robot.clone(),
        ..ScanConfig::default()
    };
    if let Some(m) = &cfg.devices.video_mux {
        scan.head = HeadGeometry {
            cameras: m.cameras,
            fov_deg: m.fov_deg,
            first_yaw_deg: 0.0,
        };
    }
    let mut brain = SkeeterConfig {
        robot: cfg.robot.clone(),
        target_timeout: Duration::from_secs_f64(cfg.agent.target_timeout_s),
        stress_repeat: Duration::from_secs(10),
        ..SkeeterConfig::default()
    };
    if let Some(path) = &cfg.agent.network {
        brain.network = ima_hal::file::read_text(path)
            .with_context(|| format!("reading the SAN network {}", path.display()))?;
        // Checked here, before any device opens (the brain checked it only once the devices
        // had connected, in words that named neither the key nor the file).
        use ima_agents::mission::skeeter::{FED_CONDITIONS, SkeeterBrain, SkeeterError};
        SkeeterBrain::new(brain.clone()).map_err(|e| {
            let fed = match e {
                SkeeterError::MissingCondition(_) => format!(
                    " (Skeeter's brain feeds the conditions {})",
                    FED_CONDITIONS.join(", ")
                ),
                SkeeterError::Network(_) => String::new(),
            };
            anyhow::anyhow!("agent.network {}: {e}{fed}", path.display())
        })?;
    }
    Ok(SkeeterRuntimeConfig {
        brain,
        scan,
        colours: colour_db(cfg)?,
        time_scale: cfg.agent.time_scale,
    })
}

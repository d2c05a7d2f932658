//! `ima mock compass`: serve a mock KVH C100 (NMEA) or PNI TCM2 on a robot of the world.

use anyhow::{Context, Result};
use clap::ValueEnum;
use ima_mock_devices::compass::{CompassDevice, CompassModelConfig, MockDialect};
use ima_mock_devices::pty::{PtyDevice, PtyOptions};
use ima_mock_devices::world::{DriveCommand, SharedWorld};

use super::shared::announce_and_wait;

/// Dialects of the mock compass.
#[derive(Debug, Clone, Copy, ValueEnum, PartialEq, Eq)]
pub enum MockCompassDialect {
    /// A KVH C100 streaming NMEA `HDG` (answers `=…` commands with `>`).
    Nmea,
    /// A PNI TCM2 streaming its standard line.
    Tcm2,
}

/// Options of the mock compass (the compass-specific flags of `ima mock`).
#[derive(Debug, Clone, Copy)]
pub struct MockCompassOptions {
    /// The dialect.
    pub dialect: MockCompassDialect,
    /// Installation deviation, degrees east.
    pub deviation_deg: f64,
    /// Turn the robot at this rate, degrees per second (0: stand still).
    pub spin_deg_s: f64,
    /// Noise seed.
    pub seed: u64,
}

/// Serve a mock compass on `robot` of `world` on a new pty (the world is stepped in real
/// time by this device).
pub fn serve_mock(
    world: &SharedWorld,
    robot: &str,
    faults: &str,
    opts: MockCompassOptions,
) -> Result<PtyDevice<CompassDevice>> {
    let id = super::shared::robot_id(world, robot)?;
    if opts.spin_deg_s != 0.0 {
        world.with(|w| {
            w.command(
                id,
                DriveCommand::Twist {
                    v_m_s: 0.0,
                    omega_rad_s: opts.spin_deg_s.to_radians(),
                },
            )
        });
    }
    // `--seed` seeds the faults too (unless the spec names its own `seed=`).
    let plan = super::shared::fault_plan(faults, Some(opts.seed))?;
    let cfg = CompassModelConfig {
        dialect: match opts.dialect {
            MockCompassDialect::Nmea => MockDialect::Kvh,
            MockCompassDialect::Tcm2 => MockDialect::Tcm2,
        },
        deviation_deg: opts.deviation_deg,
        seed: opts.seed,
        ..CompassModelConfig::default()
    };
    PtyDevice::spawn(
        CompassDevice::new(cfg, world.clone(), id),
        PtyOptions {
            faults: plan,
            step_world: Some(world.clone()),
            ..PtyOptions::default()
        },
    )
    .context("starting the pty")
}

/// `ima mock compass`.
pub fn run_mock(
    world: &SharedWorld,
    robot: &str,
    faults: &str,
    opts: MockCompassOptions,
) -> Result<()> {
    let dev = serve_mock(world, robot, faults, opts)?;
    let what = match opts.dialect {
        MockCompassDialect::Nmea => "KVH C100 compass (NMEA)",
        MockCompassDialect::Tcm2 => "PNI TCM2 compass",
    };
    announce_and_wait(dev.path(), what)?;
    let model = dev
        .stop()
        .map_err(|e| anyhow::anyhow!("stopping the pty: {e}"))?;
    let st = model.stats();
    eprintln!(
        "stopped: {} commands, {} bad commands, {} lines sent",
        st.commands, st.bad_commands, st.lines
    );
    Ok(())
}

//! `ima mock sick-lms`: the mock SICK LMS on a pty (called from the `ima mock` dispatcher).

use std::time::Duration;

use anyhow::{Context, Result};
use ima_mock_devices::pty::PtyDevice;
use ima_mock_devices::sick_lms::{SickLmsDevice, SickLmsModelConfig, WorldLaser};
use ima_mock_devices::world::SharedWorld;
use ima_sick_lms::wire::BaudRate;

/// Serve a SICK LMS on `robot` of `world` on a new pty, powering up at `baud`.
pub fn serve_sick_lms(
    world: &SharedWorld,
    robot: &str,
    seed: u64,
    faults: &str,
    baud: u32,
    step_world: bool,
) -> Result<PtyDevice<SickLmsDevice>> {
    let id = super::shared::robot_id(world, robot)?;
    let baud = BaudRate::from_bps(baud)
        .with_context(|| format!("a SICK LMS runs at 9600, 19200, 38400 or 500000, not {baud}"))?;
    let plan = super::shared::fault_plan(faults, Some(seed))?;
    let cfg = SickLmsModelConfig {
        baud,
        ..SickLmsModelConfig::default()
    };
    let laser = WorldLaser::new(world.clone(), id, seed);
    let dev = SickLmsDevice::new(cfg, Box::new(laser), ima_hal::Instant::ZERO);
    super::shared::spawn_on_pty(dev, plan, world, step_world)
}

/// Serve until SIGINT/SIGTERM, then print the unit's counters on stderr.
pub fn run(world: &SharedWorld, robot: &str, seed: u64, faults: &str, baud: u32) -> Result<()> {
    let dev = serve_sick_lms(world, robot, seed, faults, baud, true)?;
    super::shared::announce_and_wait(
        dev.path(),
        &format!("SICK LMS (on {robot}) powering up at {baud} baud"),
    )?;
    let status = dev.status();
    let model = dev
        .stop()
        .map_err(|e| anyhow::anyhow!("stopping the pty: {e}"))?;
    let st = model.model().stats();
    eprintln!(
        "stopped: {} telegrams, {} NAKs, {} scans, {} baud changes, {} EEPROM writes, {} garbled bytes in; link: {}",
        st.telegrams,
        st.naks,
        st.scans,
        st.baud_changes,
        st.eeprom_writes,
        st.garbled_rx,
        status.counters
    );
    std::thread::sleep(Duration::from_millis(10));
    Ok(())
}

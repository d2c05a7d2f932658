//! `ima mock p2os`: serve a Pioneer 2-AT (P2OS) of the world on a pty.

use std::time::Duration;

use anyhow::Result;
use ima_mock_devices::body::WorldBody;
use ima_mock_devices::p2os::{P2osDevice, P2osModelConfig};
use ima_mock_devices::pty::PtyDevice;
use ima_mock_devices::world::SharedWorld;

/// Serve a P2OS robot of `world` on a new pty.
pub fn serve_p2os(
    world: &SharedWorld,
    robot: &str,
    seed: u64,
    faults: &str,
    baud: u32,
    step_world: bool,
) -> Result<PtyDevice<P2osDevice>> {
    let id = super::shared::robot_id(world, robot)?;
    let plan = super::shared::fault_plan(faults, Some(seed))?;
    // Capitalised as P2OS robots name themselves (by character: a name may start with any).
    let mut chars = robot.chars();
    let name: String = chars
        .next()
        .map(|c| c.to_uppercase().chain(chars).collect())
        .unwrap_or_default();
    let cfg = P2osModelConfig {
        name,
        baud,
        ..P2osModelConfig::default()
    };
    let dev = P2osDevice::new(cfg, WorldBody::new(world.clone(), id, seed));
    super::shared::spawn_on_pty(dev, plan, world, step_world)
}

/// Serve robot `robot` of `world` until SIGINT/SIGTERM, printing the pty path on stdout's
/// first line.
pub fn run(world: &SharedWorld, robot: &str, seed: u64, faults: &str, baud: u32) -> Result<()> {
    let dev = serve_p2os(world, robot, seed, faults, baud, true)?;
    super::shared::announce_and_wait(dev.path(), &format!("P2os at {baud} baud"))?;
    let status = dev.status();
    let model = dev
        .stop()
        .map_err(|e| anyhow::anyhow!("stopping the pty: {e}"))?;
    let st = model.robot().stats();
    eprintln!(
        "stopped: {} sessions, {} commands, {} SIPs, {} bad frames, {} watchdog trips; link: {}",
        st.sessions, st.commands, st.sips, st.bad_frames, st.watchdog_trips, status.counters
    );
    std::thread::sleep(Duration::from_millis(10));
    Ok(())
}

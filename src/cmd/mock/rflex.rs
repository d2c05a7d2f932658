//! `ima mock rflex`: serve the mock ATRV-Jr (rFLEX controller, spec §8) on a pty.

use std::time::Duration;

use anyhow::Result;
use ima_mock_devices::body::WorldBody;
use ima_mock_devices::pty::PtyDevice;
use ima_mock_devices::rflex::{RflexDevice, RflexModelConfig};
use ima_mock_devices::world::SharedWorld;

/// Serve an rFLEX base for robot `robot` of `world` on a new pty.
pub fn serve_rflex(
    world: &SharedWorld,
    robot: &str,
    seed: u64,
    faults: &str,
    step_world: bool,
) -> Result<PtyDevice<RflexDevice>> {
    let id = super::shared::robot_id(world, robot)?;
    let plan = super::shared::fault_plan(faults, Some(seed))?;
    let dev = RflexDevice::new(
        RflexModelConfig::default(),
        WorldBody::new(world.clone(), id, seed),
    );
    super::shared::spawn_on_pty(dev, plan, world, step_world)
}

/// Serve until SIGINT/SIGTERM, printing the pty path on stdout's first line.
pub fn run(world: &SharedWorld, robot: &str, seed: u64, faults: &str) -> Result<()> {
    let dev = serve_rflex(world, robot, seed, faults, true)?;
    super::shared::announce_and_wait(
        dev.path(),
        &format!("ATRV-Jr (rFLEX) for {robot:?} at 115200 baud"),
    )?;
    let status = dev.status();
    let model = dev
        .stop()
        .map_err(|e| anyhow::anyhow!("stopping the pty: {e}"))?;
    let st = model.robot().stats();
    eprintln!(
        "stopped: {} commands, {} frames sent, {} motion reports, {} bad frames, {} fail-safe trips; link: {}",
        st.commands,
        st.frames_sent,
        st.motion_reports,
        st.bad_frames,
        st.failsafe_trips,
        status.counters
    );
    std::thread::sleep(Duration::from_millis(10));
    Ok(())
}

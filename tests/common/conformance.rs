//! Helpers of the conformance suite (`tests/conformance.rs`): worlds, serving a mock on a
//! pty with faults, and waiting for a condition with a generous bound.

use std::time::Duration;

use ima_mock_devices::faults::FaultPlan;
use ima_mock_devices::link::LinkState;
use ima_mock_devices::model::DeviceModel;
pub use ima_mock_devices::pty::PtyDevice;
use ima_mock_devices::pty::PtyOptions;
pub use ima_mock_devices::world::SharedWorld;
use ima_mock_devices::world::{RobotId, RobotSpec, Wall, World};

/// A driver's link as the suite sees it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Link {
    /// Data flows.
    Up,
    /// Lost or connecting: the driver noticed the device is gone and is getting it back
    /// (every driver starts connecting too, but the suite reads links only once connected).
    Down,
    /// Failed or closed, named for the failure message.
    Other(String),
}

/// One robot at the origin facing +x, with this track width, footprint radius and top wheel
/// speed, accelerating at 1 m/s².
pub fn robot_world(track_m: f64, radius_m: f64, max_wheel_m_s: f64) -> (SharedWorld, RobotId) {
    let mut w = World::new();
    let mut spec = RobotSpec::new("robot", 0.0, 0.0, 0.0);
    spec.track_width_m = track_m;
    spec.radius_m = radius_m;
    spec.max_wheel_speed_m_s = max_wheel_m_s;
    spec.max_wheel_accel_m_s2 = Some(1.0);
    let id = w.add_robot(spec).unwrap();
    (SharedWorld::new(w), id)
}

/// A robot at the origin facing `yaw_deg` (counter-clockwise from +x), nothing else.
pub fn world_with(yaw_deg: f64) -> (SharedWorld, RobotId) {
    let mut w = World::new();
    let id = w
        .add_robot(RobotSpec::new("robot", 0.0, 0.0, yaw_deg))
        .unwrap();
    (SharedWorld::new(w), id)
}

/// A robot in a 4 m × 4 m box: every laser beam hits a wall within 2.9 m.
pub fn boxed_world() -> (SharedWorld, RobotId) {
    let mut w = World::new();
    let mut spec = RobotSpec::new("robot", 0.0, 0.0, 0.0);
    spec.radius_m = 0.4;
    let id = w.add_robot(spec).unwrap();
    for (from, to) in [
        ([-2.0, -2.0], [2.0, -2.0]),
        ([2.0, -2.0], [2.0, 2.0]),
        ([2.0, 2.0], [-2.0, 2.0]),
        ([-2.0, 2.0], [-2.0, -2.0]),
    ] {
        w.add_wall(Wall { from, to }).unwrap();
    }
    (SharedWorld::new(w), id)
}

/// Serve `model` on a pty with the fault spec `faults`, stepping `world` in real time.
pub fn serve<M: DeviceModel + 'static>(
    world: &SharedWorld,
    model: M,
    faults: &str,
) -> PtyDevice<M> {
    PtyDevice::spawn(
        model,
        PtyOptions {
            faults: FaultPlan::parse(faults).unwrap(),
            step_world: Some(world.clone()),
            ..PtyOptions::default()
        },
    )
    .unwrap()
}

/// Wait until `cond` holds; fail naming `what` after `bound` (a generous bound for a loaded
/// machine, not a timing claim).
pub async fn eventually(what: &str, bound: Duration, cond: impl Fn() -> bool) {
    let t = std::time::Instant::now();
    while !cond() {
        assert!(t.elapsed() < bound, "{what}: not within {bound:?}");
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
}

/// Wait until a hung-up device serves again.
pub async fn wait_device_up<M: DeviceModel + 'static>(dev: &PtyDevice<M>) {
    while dev.status().state != LinkState::Up {
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
}

//! From a robot's configuration to its runtime: the program's side of
//! [`ima_agents::runtime`].
//!
//! * [`net`] — the Peer Agent configuration and the group key from the robot's;
//! * [`skeeter`], [`scooter`], [`commander`] — each runtime's configuration from the robot's
//!   (the runtimes themselves live in [`ima_agents::runtime`], the devices are opened by
//!   [`crate::wiring`]);
//! * [`report`] — trajectories, performance index and the SVG of a run.
//!
//! Mission time is a scaled view of the process's one clock
//! ([`ima_agents::runtime::MissionTime`]): real time × `agent.time_scale`, so a world sped
//! up K times (`ima mock world --speed K`) sees timeouts and timers in its own time.

pub mod commander;
pub mod net;
pub mod report;
pub mod scooter;
pub mod skeeter;

pub use ima_agents::runtime::{Event, EventKind, Events};

/// Capacity of a program's event queue: a printer that falls this far behind loses the
/// oldest events (counted) rather than slowing a robot.
pub const EVENT_QUEUE: usize = 4096;

/// Tells on stderr how many events a printer lost because it fell behind (nothing if none).
pub fn report_dropped(n: u64) {
    if n > 0 {
        eprintln!("ima: {n} event(s) were not shown: the output fell behind");
    }
}

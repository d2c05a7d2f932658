//! The robots' runtime: device wiring from configuration and (as the mission pieces land)
//! the robot stacks as tokio tasks.

pub mod devices;
pub mod report;
pub mod net;

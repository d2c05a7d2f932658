//! The mission: the robots' pure decision logic (sans-IO; time is an [`ima_hal::Instant`]
//! passed in).

pub mod avoid;
pub mod scooter;

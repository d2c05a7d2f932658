//! The mission of the thesis's demonstration (MISSION.md, "The demonstration"): the robots'
//! pure decision logic, sans-IO, with time passed in as an [`ima_hal::Instant`].
//!
//! Nothing here opens a socket, a port or reads a clock; a runtime feeds the inputs and
//! carries out the outputs.
//!
//! * [`msg`] — the typed inter-robot vocabulary (broadcast channel traffic and the SES
//!   source's name) with conversions to and from [`crate::peer::wire::Msg`].
#![allow(clippy::module_name_repetitions)]

pub mod avoid;
pub mod msg;
pub mod scan;
pub mod scooter;
pub mod vision;

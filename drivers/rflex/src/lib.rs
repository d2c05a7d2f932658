//! `ima-rflex`: iRobot/RWI rFLEX protocol (ATRV-Jr): sans-IO wire, framer and session.
//!
//! **Status:** not implemented yet; this crate is a placeholder in the workspace layout and
//! exports nothing.
#![cfg_attr(not(feature = "std"), no_std)]
#![warn(missing_docs)]

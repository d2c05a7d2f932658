//! `ima-rflex`: iRobot/RWI rFLEX protocol (ATRV-Jr): sans-IO wire, framer and session.
//!
//! **Status:** not implemented yet; this crate is a placeholder in the workspace layout and
//! exports nothing.
#![cfg_attr(not(feature = "std"), no_std)]
#![warn(missing_docs)]
// No panics on input: outside tests, these are compile errors in the protocol cores.
#![cfg_attr(
    not(test),
    deny(
        clippy::unwrap_used,
        clippy::expect_used,
        clippy::panic,
        clippy::indexing_slicing,
        clippy::unreachable
    )
)]

//! `ima-p2os`: the Pioneer 2 (P2OS) serial protocol, for the Pioneer 2-AT.
//!
//! Layers, after `smoltcp`/`quinn-proto` (see `DESIGN.md`):
//! * [`wire`] — packets, checksum, typed commands and robot packets; `no_std`, no heap.
//! * [`framer`] — a byte-stream decoder with resynchronisation and counters.
//! * [`params`] — robot parameter tables selected by the SYNC2 subclass.
//! * [`machine`] — the client session (handshake, baud probing, keep-alive, motors,
//!   odometry), sans-IO: it never touches a port or reads a clock.
//! * `shell` (feature `tokio`) — the machine's events as readings and the [`shell::P2os`]
//!   handle implementing the `ima-hal` traits, run by `ima-serial`'s one runner (blocking
//!   code: `ima_serial::blocking::Blocking<P2os>`, feature `serial`).
//!
//! The wire facts and their sources are in the project's protocol spec
//! (`shared/protocols/p2os.md`); section numbers in these docs refer to it.
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

#[cfg(feature = "std")]
pub mod driver;
pub mod framer;
#[cfg(feature = "fuzzing")]
pub mod fuzz_harness;
pub mod machine;
pub mod params;
#[cfg(feature = "tokio")]
pub mod shell;
pub mod wire;

pub use framer::{FrameEvent, Framer, FramerStats};
pub use machine::{Config, Event, Machine, SessionError, SessionState};
pub use params::RobotParams;
pub use wire::{Command, Packet, WireError};

//! `ima-video-mux`: serial video switchers — Extron SIS and, as a second dialect, Kramer
//! Protocol 2000 — as a sans-IO core.
//!
//! Spec: `protocols/compass_video_mux.md` §7b.
//!
//! * [`wire`]: commands and replies of both dialects with `parse` and `emit` in both
//!   directions (the mock switcher reuses them in the device role).
//! * [`framer`]: a bounded CR/LF line framer for SIS replies and a self-synchronising 4-byte
//!   framer for Protocol 2000.
//! * [`machine`]: the session — select with reply matching, timeout and retries; settle time;
//!   query; unsolicited messages. No I/O, no clock: time is passed in as
//!   [`ima_hal::Instant`].
//!
//! The HAL side is [`ima_hal::camera::CameraMux`] (implemented by the async I/O shell `shell::VideoMux`,
//! feature `tokio`; blocking code: `ima_serial::blocking::Blocking<VideoMux>`, feature `serial`) and [`ima_hal::camera::FrameSource`] (frame grabbers and the mock camera head).
//!
//! # Choices where the spec is silent
//!
//! * Kramer replies (bit 6 set on switcher messages, an echo confirms a switch, instruction 5
//!   queries, instruction 16 is an error) are inferred; `expect_reply: false` in
//!   [`machine::Dialect::Kramer`] treats the switcher as mute and confirms on sending.
//! * The reply to an Extron matrix tie (`Out2 In3 All`) is inferred from the single-output
//!   form.
//! * The settle time (default 150 ms) is a project choice; no source gives one.
//! * Error replies are not retried (the switcher understood and refused); silence is.
#![cfg_attr(not(any(test, feature = "std")), no_std)]
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
#[cfg(feature = "std")]
pub mod net_frames;
#[cfg(feature = "tokio")]
pub mod shell;
pub mod wire;

//! `ima-rflex`: the iRobot/RWI rFLEX protocol of the ATRV-Jr, as a sans-IO core.
//!
//! Written from the project's protocol spec (`shared/protocols/rflex.md`); section numbers
//! (§n) in the docs refer to it.
//!
//! * [`wire`]: frame layout, XOR checksum, byte stuffing in both directions, and typed
//!   messages for both roles: [`wire::Command`] (host → base) and [`wire::Report`]
//!   (base → host), each with `parse` and `emit`, so the mock ATRV-Jr reuses this module.
//! * [`framer`]: the strict §2.5 receiver (lenient mode as an option), bounded, with counters.
//! * [`machine`]: the host session: initialisation order (§6), brake release as the explicit
//!   "enable motors", 10 Hz keep-alive, ≥ 0.5 s of zeros after a stop, a 0.5 s command
//!   watchdog, ≥ 5 ms between frames, the shutdown sequence, odometry integration (§4) with a
//!   plausibility rule, the velocity mapping (§5), sonar id → index/pose mapping (§7),
//!   bumpers and battery. It never touches a port or a clock: time is passed in as `now`.
//! * `driver` (feature `std`): the base's [`Fault`](driver::Fault)s; its errors are
//!   `ima_serial::DriverError<Fault>`.
//! * `shell` (feature `tokio`): the async shell, a cloneable `Rflex` handle implementing the
//!   `ima-hal` base, odometry, sonar, bumper and power traits; re-initialises after a lost
//!   link; emergency stop = zero both axes and engage the brake (the spec has no e-stop).
//!   Blocking code uses `ima_serial::blocking::Blocking<Rflex>` (feature `serial`).
//!
//! # Choices where the spec leaves room
//!
//! * **Stuffing of host commands** (§2.4): the driver stuffs per CW (the spec's normative
//!   choice, [`wire::Stuffing::Full`]). No open driver did; if the firmware turns out to reject
//!   stuffed commands (§11 question 1), [`machine::Config::legacy_no_stuff`] sends unstuffed
//!   frames with the Player nudge applied to every 0x1B byte of every field
//!   ([`wire::nudge_u32`]), and, beyond what Player did, also keeps the checksum clear of 0x1B.
//! * **Checksum** (§2.2): header-inclusive XOR, as every working driver computes it; CW's
//!   notes say "contents only", which the drivers contradict.
//! * **Zero translational speed** (§5, P9): UML sends 1 instead of 0; here that is
//!   [`machine::Config::zero_speed_quirk`], off by default.
//! * **Odometry heading**: integrated with the midpoint heading (§4 step 3 says PL uses the
//!   updated one; the midpoint is slightly better). Implausible jumps are rejected (§4 step 5).
//! * **Sonar poses**: the default table maps DTU's 17-sonar ATRV-Jr ids (§7); the poses in it
//!   are placeholders on the robot's outline until Scooter is measured (see
//!   [`machine::SonarMount::atrv_jr_default`]).
//! * **Acks** (§3, \[D\]): 8-byte `rv ts` frames on MOT 7 and DIO 0/4 parse as
//!   [`wire::Report::Ack`] and are ignored by the machine.
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

pub mod framer;
#[cfg(feature = "fuzzing")]
pub mod fuzz_harness;
pub mod machine;
pub mod wire;

#[cfg(feature = "std")]
pub mod driver;
#[cfg(feature = "tokio")]
pub mod shell;

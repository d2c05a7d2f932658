//! The mission of the thesis's demonstration (MISSION.md, "The demonstration"): the robots'
//! pure decision logic, sans-IO, with time passed in as an [`ima_hal::Instant`].
//!
//! Nothing here opens a socket, a port or reads a clock, and nothing needs an async
//! runtime; a runtime (or a virtual-time simulation) feeds the inputs and carries out the
//! outputs.
//!
//! * [`msg`] — the typed inter-robot vocabulary (broadcast channel traffic and the SES
//!   source's name) with conversions to and from [`crate::peer::wire::Msg`].
//! * [`scooter`] — Scooter's brain: heading rules, SAN, laser target finder, controller.
//! * [`avoid`] — smooth laser obstacle avoidance (locked side, hysteresis).
//! * [`vision`] — Skeeter's colour database, blob detector and pinhole geometry (blob
//!   column → bearing, apparent width → range).
//! * [`scan`] — the Scan node: one sweep of the camera head (switch, settle, grab, detect,
//!   post to the SES), ending with a report and the SES shared form to publish; and
//!   [`scan::run_scan`], its async driver over the hal camera traits.
//! * [`skeeter`] — Skeeter's Self Agent: the brain that runs Skeeter's SAN through the
//!   mission (targets, scans, the broadcast behaviours, timeout, reports). Its module docs
//!   map every SAN condition to the input that feeds it and every module to its action.
//! * [`commander`] — the Commander Interface Agent's logic: a series of targets sent one at
//!   a time, each target's progress from Skeeter's mission events, a log of broadcasts.
//!
//! # How a runtime drives Skeeter
//!
//! 1. Build a [`scan::Scanner`] (`Scanner::with_default_ses(ScanConfig::default(),
//!    ColourDb::default())`) and a [`skeeter::SkeeterBrain`]
//!    (`SkeeterBrain::new(SkeeterConfig::default())`); call `brain.start(now)`.
//! 2. Feed every broadcast heard (typed with [`msg::Broadcast::from_wire`]) to
//!    `brain.handle_broadcast(&b, now)`; when Scooter's Peer Agent client is granted the
//!    `ses` source, call `brain.handle_heading_request(now)`.
//! 3. After every input, and when `brain.poll_timeout()` is due
//!    (`brain.handle_timeout(now)`), drain `brain.poll_output()`:
//!    * `Broadcast(b)` → send `b.to_wire(seq)` on the broadcast channel;
//!    * `StartScan` → run [`scan::run_scan`] (or drive the scanner yourself) and feed the
//!      report: `brain.handle_scan(&report, now)`;
//!    * `PublishSes(form)` → publish `form.to_bytes()` as a sample of the Peer Agent source
//!      [`msg::SES_SOURCE`].
//!
//! The commander: `Commander::new(&colours, CommanderConfig::default())`, `start(now)`,
//! send what `poll_broadcast()` gives, feed every broadcast heard to `handle_broadcast`,
//! call `handle_timeout` when `poll_timeout()` is due, stop when `is_finished()`.
//!
//! # Lossy broadcasts
//!
//! The broadcast channel is UDP: any message may be lost, so every message whose loss
//! would stall the mission is repeated until its effect is seen. The commander resends an
//! unanswered target and polls a processing one ([`commander::CommanderConfig::poll_processing`]);
//! Skeeter answers a poll of the target it has just finished with its outcome
//! ([`skeeter::SkeeterConfig::outcome_memory`]) and repeats `scooter-found`
//! ([`skeeter::SkeeterConfig::found_repeats`]) and the stress call; Scooter resends
//! `target-reached` every status period until the outcome is heard, and ends a call-back
//! also on an SES sample that shows it ([`scooter::ScooterConfig::found_record_max_age`]).
//!
//! # How a runtime drives Scooter
//!
//! 1. `let mut brain = ScooterBrain::new(ScooterConfig::default())` (choose
//!    [`scooter::HeadingRule`] and [`scooter::HeadingSource`] in the config; set
//!    `odometry_heading_offset_rad` to Scooter's common-frame heading at the odometry reset).
//! 2. Feed the sensors as they arrive: `handle_odometry(&odo, now)`,
//!    `handle_compass(heading_in_common_frame, now)`, `handle_laser(&scan, now)`; every
//!    sample of Skeeter's `ses` source: `handle_ses(&SharedForm::decode(bytes)?, now)`;
//!    every broadcast heard: `handle_broadcast(&b, now)`.
//!    The laser must keep coming: without a usable scan within
//!    [`scooter::ScooterConfig::laser_stale_after`] (0.5 s) Scooter commands no forward
//!    speed (it may still turn in place).
//! 3. At the control rate (e.g. 10–20 Hz) call `step(now)`: send `out.command` to the
//!    base; for every message `say` in `out.messages`, send
//!    `say.to_broadcast("scooter", &brain.san_summary())` on the broadcast channel, and
//!    on [`scooter::ScooterSay::RequestHeading`] re-request the `ses` source.

#![cfg_attr(
    not(test),
    deny(
        clippy::unwrap_used,
        clippy::expect_used,
        clippy::panic,
        clippy::unreachable,
        clippy::indexing_slicing
    )
)]
#![allow(clippy::module_name_repetitions)]

pub mod avoid;
pub mod commander;
pub mod msg;
pub mod scan;
pub mod scooter;
pub mod skeeter;
pub mod vision;

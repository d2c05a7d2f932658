//! `ima-agents`: the robots' agents. They depend on `ima-hal` only, never on a driver.
//!
//! Pure, deterministic logic with no I/O and no clock reads (time is an
//! [`ima_hal::Instant`] argument; the `peer::net` shell and the `runtime` layer are the
//! exceptions, behind features):
//!
//! * [`ses`] — the Sensory EgoSphere: a geodesic dome of tagged, time-stamped entries, and
//!   its [shared form](ses::shared), the binary list of observations robots exchange.
//! * [`san`] — a Spreading Activation Network after Maes (1989), loaded from TOML.
//! * [`heading`] — the thesis's isosceles heading rule and a range-aware rule.
//! * [`peer`] — the Peer Agent: sans-IO core (manager, client, broadcast channel,
//!   authenticated frames) and, with feature `net`, its tokio TCP/UDP shell.
//! * [`mission`] — the demonstration's pure decision logic: inter-robot vocabulary, vision,
//!   the Scan node, Skeeter's and Scooter's brains, obstacle avoidance, the commander.
//!
//! With feature `runtime`, one layer with I/O on top of those:
//!
//! * `runtime` — Skeeter's, Scooter's and the commander's tokio runtimes, generic over the
//!   HAL traits (any base, laser, compass, camera switcher and frame source), on the
//!   process's one clock, reporting typed events on a bounded channel, linked to the other
//!   robots through channels or the Peer Agent network. The program names the concrete
//!   drivers; the runtimes never do.
//!
//! Everything is `f64`, SI units, radians; degrees appear only at API edges that say so.
#![warn(missing_docs)]

#[cfg(feature = "fuzzing")]
pub mod fuzz_harness;
pub mod heading;
pub mod mission;
pub mod peer;
#[cfg(feature = "runtime")]
pub mod runtime;
pub mod san;
pub mod ses;

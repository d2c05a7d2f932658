//! `ima-compass`: serial compasses — NMEA 0183 `HDG`/`HDM`/`HDT` (KVH C100 and most
//! compasses) and the PNI TCM2 standard output — as a sans-IO core.
//!
//! Spec: `protocols/compass_video_mux.md` §7a.
//!
//! * [`wire`]: typed lines and commands with `parse` and `emit` in both directions (the mock
//!   compass reuses them in the device role).
//! * [`framer`]: a bounded, CR/LF-tolerant line framer that resyncs on `$` and counts what it
//!   drops.
//! * [`machine`]: the session — configures the device for its dialect, runs TCM2 calibration
//!   on request, and turns lines into heading events in radians. No I/O, no clock: time is
//!   passed in as [`ima_hal::Instant`].
//!
//! # Choices where the spec is silent or conflicting
//!
//! * The TCM2 checksum: the spec says the line carries the NMEA checksum, but its example has
//!   none. Lines without `*hh` are refused by default;
//!   [`wire::ParseOptions::allow_missing_checksum`] admits them.
//! * `autocal=d` (stop automatic calibration) is inferred from the `mpcal=e`/`mpcal=d` pair.
//! * After `h`, `mpcal=d` the session waits a bounded time for a `HnVnMn.n` score line; the
//!   spec names the score format but not when the TCM2 sends it.
//! * The KVH C100's calibration commands are unknown (spec "Gap"), so calibration requests are
//!   refused for that dialect.
//! * The TCM2 error field is read as hex and reported, not interpreted.
//!
//! # I/O shells
//!
//! * `shell` (feature `tokio`): an async task owning the port, cloneable
//!   `CompassDriver` handles implementing [`ima_hal::compass::Compass`].
//! * blocking code: `ima_serial::blocking::Blocking<CompassDriver>` (feature `serial`).
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
#[cfg(feature = "tokio")]
pub mod shell;
pub mod wire;

//! `ima-sick-lms`: the SICK LMS 200/291 serial protocol as a sans-IO core.
//!
//! Spec: `shared/protocols/sick_lms.md` (section numbers below refer to it).
//!
//! * [`wire`]: telegram layout, the SICK CRC-16, every command and reply a driver or a mock
//!   needs, both directions parse **and** emit (§1, §3).
//! * [`framer`]: the byte-stream decoder of §5: sync hunt, one-byte resync, ACK/NAK bytes only
//!   between frames, partial-frame expiry, counters; fixed 814-byte buffer, no heap.
//! * [`machine`]: the session of §4: power-up wait, baud probe, baud change with settle and
//!   verify, variant, config read-modify-write, stream start/stop, request/reply matching with
//!   bounded retries and the timeouts of §2. No I/O, no clock: `now` is an argument.
//! * [`decode`]: B0 values to [`ima_hal::laser::LaserScan`] (masks per measuring mode, special
//!   codes, geometry).
//! * [`driver`] (feature `std`): the unit's [`driver::Fault`]s ([`driver::DriverError`] =
//!   `ima_serial::DriverError<Fault>`), [`driver::ScanStats`], the line-rate arithmetic of §4.
//! * `shell` (feature `tokio`): a cloneable `SickLms` handle implementing
//!   [`ima_hal::laser::LaserScanner`], run by `ima-serial`'s runner (blocking code:
//!   `ima_serial::blocking::Blocking<SickLms>`, feature `serial`).
//!
//! # Driving the machine
//!
//! A shell owns the port and the clock; the core only sees bytes and instants:
//!
//! ```
//! use ima_hal::Instant;
//! use ima_hal::laser::LaserScan;
//! use ima_sick_lms::machine::{Config, Event, Machine};
//!
//! let mut m = Machine::new(Config::default(), Instant::ZERO);
//! let mut tx = [0u8; ima_sick_lms::machine::MAX_COMMAND];
//! // 1. Events first: set the UART rate (and flush) before writing anything.
//! assert_eq!(m.poll_event(), Some(Event::SetHostBaud(9600)));
//! // 2. Then the telegram to write: the probe's `20 25` (spec §1.1 vector).
//! let n = m.poll_transmit(&mut tx).ok_or("nothing to send")?;
//! assert_eq!(&tx[..n], &[0x02, 0x00, 0x02, 0x00, 0x20, 0x25, 0x35, 0x08]);
//! // 3. Bytes read from the port; B0 scans come out borrowed, decoded in place.
//! let mut scan = LaserScan::default();
//! m.handle_bytes_with(&[0x06], Instant::from_millis(3), |b0, _at| {
//!     let _ = ima_sick_lms::decode::decode_scan(b0, Default::default(), None, &mut scan);
//! });
//! // 4. Sleep until poll_timeout(), then call handle_timeout(now).
//! let next = m.poll_timeout().ok_or("no timer")?;
//! assert!(next > Instant::from_millis(3));
//! m.handle_timeout(next);
//! # Ok::<(), &'static str>(())
//! ```
//!
//! # Choices where the sources disagree (spec §1–§6)
//!
//! * **Count word:** the value count is bits 0–9 (STB, and the spec's layout). PLY/CAR mask 14
//!   bits; that would fold the partial-scan bits 11–13 into the count, so it is not offered.
//!   Bits 10–15 are exposed raw ([`wire::CountWord::raw_flags`]).
//! * **Flag bits b13–b15 in measuring mode 00:** the sources give three different meanings, so
//!   they are exposed raw ([`decode::Value::raw_flags`], `BeamFlags::device_bits`), never named.
//! * **Reply address:** any `0x80..=0xFF` is accepted (QM units answer at `0x81`).
//! * **`F7` result:** TL says `01` = accepted, QM shows `00` on success. Default: TL;
//!   [`machine::Config::config_write_zero_ok`] accepts `00` as well. Either way the echoed
//!   configuration must equal the one written.
//! * **`92` layout:** undocumented; parsed as `92 [bytes…] S`, the spec's assumption being the
//!   empty case.
//! * **Installation password:** `SICK_LMS` by default (TL); PLY derives it from the type string,
//!   so it is [`machine::Config::password`].
//! * **Units `10` (dm):** decoded as decimetres (CAR/PLY); the TL reserves it.
//! * **ACK byte:** CAR waits for it, STB/PLY ignore it. The machine uses it as the fast
//!   "wrong baud" signal while probing (no ACK within 60 ms), but a reply that arrives without
//!   a seen ACK is accepted anyway.
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

pub mod decode;
#[cfg(feature = "std")]
pub mod driver;
pub mod framer;
#[cfg(feature = "fuzzing")]
pub mod fuzz_harness;
pub mod machine;
#[cfg(feature = "tokio")]
pub mod shell;
pub mod wire;

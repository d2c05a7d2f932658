//! `ima-serial`: what every ima serial driver shares around its protocol core.
//!
//! * [`Machine`] — the one shape of a sans-IO protocol machine: bytes in, timeouts, frames
//!   out, events, next deadline. `no_std`, no heap.
//! * [`LinkStatus`], [`LinkError`] and [`DriverError`] — the link as handles see it, the
//!   ways a link ends that no protocol explains, and the one driver error: those plus the
//!   device's own [`Fault`]s (`std`).
//! * [`BaudControl`] / [`FixedBaud`] — streams whose line speed can (or cannot) change, and
//!   the port opening (`open_port`, feature `tokio`).
//! * [`runner`] (feature `tokio`) — the one async loop that runs a driver's [`runner::Shell`]
//!   over a byte stream (drain events → transmit → flush → wait on read / deadline / call);
//!   [`handle::Handle`] — spawn, connect, calls on the shell, readings, close, the halt
//!   signal: everything a driver handle does the same way, and [`handle::Driver`], the calls
//!   every driver's public handle answers alike; `blocking` (feature `serial`)
//!   — any driver handle driven from blocking code; [`probe::Probe`] — what each line rate
//!   tried received while a driver connects.
//! * [`line`](mod@line) — the bounded line framer of the ASCII protocols (`no_std`, no heap,
//!   no panics); the byte cursors of the binary ones are [`ima_hal::bytes`], shared with the
//!   Peer Agent's wire format.
//!
//! The runners never create a clock: they take the process's [`SharedClock`](ima_hal::time::SharedClock),
//! so every stamp a driver produces is on one time line.
#![cfg_attr(not(any(test, feature = "std")), no_std)]
#![warn(missing_docs)]
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

/// The time stamps machines take.
pub use ima_hal::Instant;

#[cfg(feature = "serial")]
pub mod blocking;
#[cfg(feature = "std")]
mod error;
#[cfg(feature = "tokio")]
pub mod handle;
pub mod line;
#[cfg(feature = "std")]
mod link;
#[cfg(feature = "std")]
mod port;
#[cfg(feature = "tokio")]
pub mod probe;
#[cfg(feature = "tokio")]
pub mod runner;

#[cfg(feature = "std")]
pub use error::{DriverError, Fault};
#[cfg(feature = "std")]
pub use link::{LinkError, LinkStatus};
#[cfg(feature = "tokio")]
pub use port::open_port;
#[cfg(feature = "std")]
pub use port::{BaudControl, FixedBaud};

/// Implement [`Machine`] for a machine type whose inherent methods already have the trait's
/// names (`handle_bytes`, `handle_timeout`, `poll_event`, `poll_timeout`), giving the body of
/// `poll_transmit` (which may or may not need `now`):
///
/// ```ignore
/// ima_serial::impl_machine!(Machine, Event, |m, now, buf| m.poll_transmit(buf));
/// ```
#[macro_export]
macro_rules! impl_machine {
    ($machine:ty, $event:ty, |$m:ident, $now:ident, $buf:ident| $transmit:expr) => {
        impl $crate::Machine for $machine {
            type Event = $event;

            fn handle_bytes(&mut self, bytes: &[u8], now: $crate::Instant) {
                <$machine>::handle_bytes(self, bytes, now);
            }

            fn handle_timeout(&mut self, now: $crate::Instant) {
                <$machine>::handle_timeout(self, now);
            }

            fn poll_transmit(&mut self, $now: $crate::Instant, $buf: &mut [u8]) -> Option<usize> {
                let $m = self;
                $transmit
            }

            fn poll_event(&mut self) -> Option<$event> {
                <$machine>::poll_event(self)
            }

            fn poll_timeout(&self) -> Option<$crate::Instant> {
                <$machine>::poll_timeout(self)
            }
        }
    };
}

/// A sans-IO protocol machine: it never touches a port or reads a clock. The caller feeds it
/// received bytes and the time, drains the frames it wants written and the events it
/// raised, and calls it back at its next deadline.
pub trait Machine {
    /// What the machine tells its shell (readings, link changes, answers to requests).
    type Event;

    /// Feed bytes received at `now` (any split: a byte at a time or many frames at once).
    fn handle_bytes(&mut self, bytes: &[u8], now: Instant);

    /// Run the timers that are due at `now` (retries, keep-alives, watchdogs).
    fn handle_timeout(&mut self, now: Instant);

    /// Write the next frame due at `now` into `buf`; its length, or `None` when nothing
    /// is due (a frame larger than `buf` stays queued).
    fn poll_transmit(&mut self, now: Instant, buf: &mut [u8]) -> Option<usize>;

    /// The next event, if any.
    fn poll_event(&mut self) -> Option<Self::Event>;

    /// When [`handle_timeout`](Self::handle_timeout) should next be called, if ever.
    fn poll_timeout(&self) -> Option<Instant>;
}

//! The Peer Agent over IP: transport-agnostic core (PEER.md).
//!
//! **Status: core only.** This module holds the pure state machines and the wire format. The
//! tokio TCP/UDP shell (manager listener, data-server sockets, multicast with the unicast
//! fallback, key files and `--insecure`), the `ima peer` tools and the loopback benchmarks
//! are not built yet.
//!
//! * [`manager::PeerManager`] — one per robot: registration (duplicate IDs declined), the
//!   competency list and its change pushes, the three-part priority with the pending queue,
//!   task-priority gating and revocation, tickets, heartbeats and loss, bounded queues. It
//!   asks its Self Agent through [`manager::SelfAgent`] ([`manager::FixedSelfAgent`] is a
//!   simple one).
//! * [`client::PeerClient`] — register / unregister / request / disconnect, with the
//!   duplicate-ID retry and manager-loss handling.
//! * [`broadcast`] — sequence-numbered status, emergency and mission messages; receivers drop
//!   duplicates and stale reorderings.
//! * [`data`] — the data channel: [`data::DataServerSession`] refuses a session without a
//!   valid ticket and streams samples latest-value; [`data::DataClientSession`] presents the
//!   ticket and hands samples to the target agent.
//! * [`queue::LatestQueue`] — bounded, latest-value queue for sample streams.
//! * [`wire`] — frames, messages, authentication.
//!
//! No socket, no clock read: time is an [`ima_hal::Instant`] argument; inputs are
//! `handle_frame` / `handle_timeout`, outputs `poll_transmit` / `poll_event` /
//! `poll_timeout`.
//!
//! # Frame (all integers little-endian)
//!
//! | offset | size | field |
//! |---|---|---|
//! | 0 | 2 | magic `"IP"` (`0x49 0x50`) |
//! | 2 | 1 | version, `1` |
//! | 3 | 1 | message type (table below) |
//! | 4 | 2 | body length *N* (u16); above the limit (default 8192) → `Oversize` |
//! | 6 | 8 | sender ID (u64): namespace of the counter |
//! | 14 | 8 | counter (u64): strictly increasing per sender; not above the last → `Replay` |
//! | 22 | *N* | body |
//! | 22+*N* | 32 | HMAC-SHA-256 under the group key over bytes `0 .. 22+N` |
//!
//! On a stream (TCP) frames follow each other; [`wire::frame_len`] gives the length from
//! the header. A frame that fails any check closes its session (no resynchronisation).
//! On UDP one datagram is one frame. The MAC covers header and body, so the counter is
//! authenticated (in the spirit of MAVLink 2 signing, with a full-length tag). Errors are
//! distinct: `Truncated`, `BadMagic`, `BadVersion`, `Oversize`, `TrailingBytes`, `BadMac`,
//! `Replay`, `UnknownType`, `Body(..)` ([`wire::WireError`]); the MAC is checked before the
//! replay counter and both before the body is parsed.
//!
//! **Test vector.** Group key `"group key of the test fleet, 32b"` (32 ASCII bytes), sender
//! `0x11`, counter `0x22`, Register { client `0x0102030405060708`, robot `"scooter"` }:
//!
//! ```text
//! 49 50 01 01 10 00                     magic "IP", version 1, type 0x01, body length 16
//! 11 00 00 00 00 00 00 00               sender 0x11
//! 22 00 00 00 00 00 00 00               counter 0x22
//! 08 07 06 05 04 03 02 01 07            client, robot-name length 7
//! 73 63 6f 6f 74 65 72                  "scooter"
//! 38 7d 60 60 08 11 4c d4 af e4 5a 93 e9 a8 88 1a
//! 69 a4 8d 84 94 d2 c6 d8 30 f9 e0 40 a7 19 ef 94   HMAC-SHA-256
//! ```
//!
//! **Sender IDs and counters.** Every sender (manager, client, data-session end,
//! broadcaster) seals with its own sender ID and a counter that grows by one per frame. The
//! shell should draw sender IDs at random per process start and start counters from a clock
//! that grows across restarts (µs since the UNIX epoch), so a restarted robot is never taken
//! for a replayer. The manager remembers counters per sender *across* its sessions
//! ([`manager::ManagerConfig::max_senders`]), so frames recorded on one session cannot be
//! replayed on a new one; data-session tickets are single-use for the same reason.
//!
//! # Body fields
//!
//! `str` = u8 length then UTF-8 bytes (at most 255). `u64`, `u16`, `u32`, `i32` are
//! little-endian. `source` = `str` name, `str` kind, `u16` schema, `u32` rate in mHz.
//! `list<T>` = u8 count then the items. `ticket` = 32 bytes (see [`manager`]).
//!
//! Reason codes: decline (1 duplicate ID, 2 full); deny (1 not registered, 2 unknown source,
//! 3 queue full); revoke (1 task priority, 2 source gone, 3 shutdown, 4 bad ticket); mission
//! event (1 accepted, 2 accomplished, 3 failed).
//!
//! ## Request channel (client → manager)
//!
//! | type | message | body |
//! |---|---|---|
//! | `0x01` | Register | `u64` client ID, `str` robot |
//! | `0x02` | Unregister | `u64` client |
//! | `0x03` | Request (also renews) | `u64` client, `str` source, `u8` priority |
//! | `0x04` | Disconnect | `u64` client, `str` source |
//! | `0x05` | Heartbeat (both ways, every channel) | empty |
//!
//! ## Reply channel (manager → client)
//!
//! | type | message | body |
//! |---|---|---|
//! | `0x10` | Registered | `u64` client, `list<source>` competency list |
//! | `0x11` | Declined | `u64` client, `u8` decline reason |
//! | `0x12` | Unregistered | `u64` client |
//! | `0x13` | Granted | `u64` client, `str` source, `str` data address `host:port`, `ticket` |
//! | `0x14` | Pending | `u64` client, `str` source |
//! | `0x15` | Denied | `u64` client, `str` source, `u8` deny reason |
//! | `0x16` | Revoked | `u64` client, `str` source, `u8` revoke reason |
//! | `0x17` | SourcesChanged | `list<source>` added or changed, `list<str>` removed |
//!
//! ## Data session (client ↔ data server)
//!
//! | type | message | body |
//! |---|---|---|
//! | `0x20` | OpenData (client → server) | `u64` client, `str` source, `ticket` |
//! | `0x21` | DataAccepted | `str` source |
//! | `0x22` | DataClosed | `str` source, `u8` revoke reason |
//! | `0x23` | Sample | `u64` seq, `u64` stamp µs, `u16` length, payload |
//!
//! The first frame of a data session must be OpenData with a ticket that
//! [`manager::PeerManager::check_ticket`] accepts; otherwise the server answers DataClosed
//! (bad ticket) and closes. Samples are numbered per session from 1; a gap means samples
//! dropped by the latest-value queue.
//!
//! ## Broadcast channel (UDP)
//!
//! | type | message | body |
//! |---|---|---|
//! | `0x30` | Status | `str` robot, `u64` seq, `str` behaviour, `str` SAN summary, `u8` pose flag (0/1), then if 1: `i32` x mm, `i32` y mm, `i32` θ mrad |
//! | `0x31` | Emergency | `str` robot, `u64` seq, `str` kind, `str` text |
//! | `0x32` | Mission | `str` robot, `u64` seq, `u8` mission event, `str` target |
//!
//! # Decisions recorded here
//!
//! * The thesis leaves open whether the three priority levels are summed or ordered; PEER.md
//!   orders them (research note §4) and so does this code ([`manager::Priority`]).
//! * A ticket's expiry bounds only when a data session may be *opened*; the grant itself
//!   lasts until disconnect, revoke or loss.
//! * A task-priority revocation puts the request back in the pending queue; a source removal
//!   or shutdown ends it.
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

pub mod broadcast;
pub mod client;
pub mod data;
pub mod manager;
#[cfg(feature = "net")]
pub mod net;
pub mod queue;
pub mod wire;

#[cfg(test)]
mod tests;

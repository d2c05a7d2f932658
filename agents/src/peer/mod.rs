//! The Peer Agent over IP (PEER.md): a transport-agnostic core and its tokio shell.
//!
//! **Core** (always built, no sockets, no clock reads): the pure state machines and the wire
//! format below. **Shell** (`net`, feature `net` of `ima-agents`; the default features
//! stay free of tokio): the manager's TCP listener and data server, client sessions, UDP
//! multicast/unicast broadcast, key files and TOML config — see "Network shell" below.
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
//! No socket, no clock read in the core: time is an [`ima_hal::Instant`] argument; inputs
//! are `handle_frame` / `handle_timeout`, outputs `poll_transmit` / `poll_event` /
//! `poll_timeout`.
//!
//! # Network shell (`net` feature)
//!
//! Thin tokio shells; each task owns one core state machine and reads its clock from
//! `ima_hal::time::TokioClock`.
//!
//! * **Manager** — `net::spawn_manager(&cfg, key, self_agent)` binds the request-channel
//!   listener (`manager.listen`, port 0 allowed) and the data server
//!   (`manager.data_listen`) and returns a `net::ManagerHandle`: `local_addr`,
//!   `data_addr`, `publisher(SourceInfo)` → `net::SourcePublisher`, `set_task_priority`,
//!   `stats`, `status`, `events` (a stream of `net::ManagerNetEvent`), `shutdown` (grants
//!   revoked with `Shutdown` first) and `abort` (as if the process died). One manager task
//!   owns the [`manager::PeerManager`]; each client connection has a reader task (frames
//!   cut with [`wire::frame_len`]) and a writer task fed by a bounded queue
//!   (`manager.session_queue`; a session that overflows it is closed as a slow consumer).
//!   Each data connection is one task owning a [`data::DataServerSession`]; its ticket is
//!   redeemed by the manager task (one ticket, one session). The Self Agent is any
//!   [`manager::SelfAgent`]; the shell adds the published sources to its list and lets
//!   `set_task_priority` override its task priority. Adding or dropping a publisher
//!   re-scans at once, so registered clients get `SourcesChanged` and grants of a removed
//!   source are revoked (`SourceGone`).
//! * **Publishing** — `SourcePublisher::publish(stamp_us, &[u8])` never blocks: every data
//!   session has a bounded latest-value queue (`manager.data_queue`, default 64); a slow
//!   session loses the oldest samples (the sequence numbers show the gap).
//! * **Client** — `net::PeerClientHandle::connect(addr, &cfg, key)`: `register()` (returns
//!   the competency list; duplicate IDs are retried by the core), `request(source, priority)`
//!   (waits through `Pending` until `Granted`, or fails with `Denied`), `disconnect(source)`,
//!   `unregister()`, `sources()`. A grant gives a `net::Subscription`; its `next().await`
//!   (or `try_next()`) yields `SubscriptionEvent::Sample { seq, stamp_us, payload }`,
//!   `Lost { reason }` (a task-priority revocation: the request is pending again and samples
//!   resume on the next grant) and finally `Closed { reason }` (`ManagerLost`,
//!   `Revoked(SourceGone | Shutdown)`, `Data(..)` for a failed data session,
//!   `Disconnected`, `Unregistered`). When the manager is lost (3 missed heartbeats, a bad
//!   frame, or its connection closed) every data session opened through it is closed and
//!   every subscription ends with `ManagerLost`; the program holding the handle keeps
//!   running.
//! * **Broadcast** — `net::BroadcastChannel::bind(&cfg, robot, key)`: one UDP socket built
//!   with `socket2` (`SO_REUSEADDR` + `SO_REUSEPORT`, so several processes on one host share
//!   the port; group joined on `broadcast.interface`; `IP_MULTICAST_IF`, TTL
//!   `broadcast.ttl` = 1, `IP_MULTICAST_LOOP` on). `send_status` / `send_emergency` /
//!   `send_mission` seal with the core [`broadcast::Broadcaster`] and send to the group
//!   (mode `multicast`), to every `broadcast.peers` address (mode `unicast`, the fallback
//!   where multicast is blocked) or to both (receivers drop the copy as a duplicate).
//!   `recv().await` returns the next new `(Msg, SocketAddr)`; bad MACs, replays, malformed
//!   datagrams, duplicates and stale reorderings are counted in `stats()` and skipped. A
//!   listener (the commander) needs no manager. Multicast on the loopback interface works
//!   (verified in this project's sandbox with `interface = "127.0.0.1"`; the tests cover
//!   multicast, unicast and both). In unicast mode every process on one host needs its own
//!   port, because a unicast datagram reaches only one of the sockets sharing a port.
//! * **Counters and IDs** — every sender (manager, client, data-session end, broadcaster)
//!   draws its sender ID from the OS random source (53 bits, [`client::MAX_ID`], as client
//!   IDs: status and logs show them as JSON numbers) and starts its frame counter (and the
//!   broadcast sequence) at the UNIX time in µs, so a restarted process is not taken for a
//!   replayer. The manager's ticket key is 32 random bytes drawn at start-up.
//! * **Robustness of the shell** — every session loop polls input before timers
//!   (`select!` is biased) and takes input already queued before it handles a timeout, so a
//!   task starved of CPU does not declare a live peer lost. Each listener serves at most
//!   `manager.max_connections` connections (more wait in the kernel backlog); a connection
//!   costs small buffers until it sends a whole frame (data server: until a ticket is
//!   accepted); each client session has at most 4 frames in the manager's shared input
//!   queue; a bad header stops reading a session at once; every socket write is bounded by
//!   the loss window (a peer that reads nothing is lost, and the writer does not hang).
//!   `ManagerHandle::shutdown` returns after the `Revoked(Shutdown)` frames are written (or
//!   the loss window passed). Dropping a `Subscription` disconnects its source; dropping a
//!   `PeerClientHandle` ends every subscription with `Closed { Disconnected }`.
//!   `ManagerHandle::publisher` refuses names/kinds over 255 bytes and a competency list
//!   that would not fit in one frame. Broadcast receivers drop their own messages by node
//!   ID (not robot name), and count the second copy of a frame (mode `both`) as a duplicate.
//! * **Replay after a restart** — a verifier remembers counters only while it runs, so a
//!   frame recorded before the receiver restarted would otherwise open. The shell therefore
//!   refuses the FIRST counter of a sender it does not remember unless it lies within
//!   `now ± max_clock_skew_ms` (default 30 000 ms; 0 turns the check off) of the receiver's
//!   UNIX clock, counted as `Replay`. This applies to the manager's request channel and to
//!   the broadcast receiver; senders move their counter up to their clock before sealing
//!   (`Signer::advance_to`), so a long-running sender stays inside the window. The cores stay
//!   clock-free: the shell passes the bounds in (`wire::Verifier::set_first_counter_window`).
//!   Robots of one group therefore need clocks within the skew of each other (NTP or
//!   similar).
//!
//! ## Configuration (`net::PeerNetConfig`, TOML)
//!
//! | key | default | meaning |
//! |---|---|---|
//! | `robot` | `"robot"` | this robot's name (registration, broadcast sender) |
//! | `key_file` | none | group-key file; tools refuse to run without one unless `--insecure` |
//! | `heartbeat_ms` | 100 | heartbeat on every channel |
//! | `missed_heartbeats` | 3 | intervals without a frame before the peer is lost |
//! | `max_body` | 8192 | body-size limit of incoming frames |
//! | `max_clock_skew_ms` | 30000 | window around the receiver's clock for an unknown sender's first counter (0: off) |
//! | `call_timeout_ms` | 10000 | client `connect`, `register`, `unregister`, `request` (until granted), `disconnect` fail with `NetError::Timeout` after this (0: no limit); a timed-out request is withdrawn |
//! | `manager.listen` | `0.0.0.0:7400` | request channel |
//! | `manager.data_listen` | `0.0.0.0:0` | data server |
//! | `manager.data_advertise` | listener address (0.0.0.0 → the local IP each client reached) | address put in grants |
//! | `manager.rescan_ms` | 1000 | source re-scan interval |
//! | `manager.ticket_lifetime_ms` | 5000 | time to open the data session after a grant |
//! | `manager.max_clients` | 1024 | registered clients at most |
//! | `manager.data_queue` | 64 | samples queued per data session and per subscription |
//! | `manager.session_queue` | 1024 | frames queued per client session |
//! | `manager.max_connections` | 1024 | open connections per listener (request channel, data server), authenticated or not |
//! | `manager.task_priority` | 0 | task priority of the tools' `FixedSelfAgent` |
//! | `manager.robot_priorities` | empty | table robot → priority (a leader highest) |
//! | `manager.unknown_robot_priority` | 0 | robots not listed |
//! | `broadcast.mode` | `"multicast"` | `"multicast"`, `"unicast"` or `"both"` |
//! | `broadcast.group` | `239.255.73.77` | multicast group (organisation-local scope) |
//! | `broadcast.port` | 7477 | UDP port (bound and sent to) |
//! | `broadcast.bind_port` | `port` | port to bind if different (0: any, for send-only tools) |
//! | `broadcast.interface` | `0.0.0.0` | `IP_MULTICAST_IF` and membership; `127.0.0.1` on one host |
//! | `broadcast.bind` | `0.0.0.0` | bind address |
//! | `broadcast.peers` | empty | unicast peers `host:port` |
//! | `broadcast.ttl` | 1 | multicast TTL |
//! | `broadcast.loopback` | true | `IP_MULTICAST_LOOP` |
//! | `broadcast.receive_own` | false | whether `recv` returns this robot's own messages |
//!
//! An annotated example is `configs/peer-manager.toml` at the repository root.
//!
//! ## Key file
//!
//! Hex (at least 64 hex digits = 32 bytes; whitespace and `#` comment lines ignored) or, if
//! the file is not hex, its raw bytes (at least 32). On Unix a key file readable by group or
//! others is refused (`chmod 600`). Generate one with
//! `head -c 32 /dev/urandom | od -An -tx1 | tr -d ' \n' > group.key && chmod 600 group.key`
//! and copy it to every member of the group. The key is never taken from the command line.
//! `--insecure` (tools only) uses `net::INSECURE_KEY`, 32 zero bytes, with a loud warning:
//! anyone can forge frames under it.
//!
//! ## Measured on loopback
//!
//! `cargo bench -p ima-agents --features net --bench peer_net` runs every figure of issue 7
//! (register and request→grant round trips, data-session throughput, broadcast fan-out, a
//! manager with 1,000 clients, loss detection); the figures are in the project README.
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

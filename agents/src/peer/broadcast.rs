//! The broadcast channel between managers, tapped by the commander (PEER.md, "Broadcast
//! channel").
//!
//! [`Broadcaster`] numbers and seals this robot's [`Msg::Status`], [`Msg::Emergency`] and
//! [`Msg::Mission`] messages. [`BroadcastReceiver`] opens frames from any group member and
//! keeps, per sender — the robot name *and* the sending node's ID — the highest sequence
//! number accepted: an equal number is a [`Rejection::Duplicate`] (e.g. the same datagram by
//! multicast and by the unicast fallback), a lower one a [`Rejection::Stale`] reordering.
//! Two processes may share a name (the operator's commander and a one-shot
//! `ima commander stop`, both "commander"); each has its own sequence, so keyed by name alone
//! the later one's higher sequence made every message of the other stale for
//! [`ReceiverConfig::forget_after`] — a fleet stop typed in the running commander among them.
//! A sender not heard for `forget_after` is forgotten, so a restarted robot whose sequence
//! began again is accepted after that quiet time (a restarted process has a new node ID too).
//! The receiver needs no manager: the commander runs one alone.

use std::collections::BTreeMap;
use std::time::Duration;

use ima_hal::Instant;

use super::wire::{
    GroupKey, MissionEvent, Msg, Pose, Signer, Verifier, WireError, parse_unauthenticated,
};

/// Numbers and seals this robot's broadcasts.
#[derive(Debug, Clone)]
pub struct Broadcaster {
    robot: String,
    seq: u64,
    signer: Signer,
}

impl Broadcaster {
    /// A broadcaster for `robot`, whose first message carries sequence `first_seq`.
    #[must_use]
    pub fn new(robot: &str, key: GroupKey, node: u64, first_counter: u64, first_seq: u64) -> Self {
        Self {
            robot: robot.to_owned(),
            seq: first_seq,
            signer: Signer::new(key, node, first_counter),
        }
    }

    /// Moves the frame counter up to `counter` (see [`Signer::advance_to`]).
    pub fn advance_counter(&mut self, counter: u64) {
        self.signer.advance_to(counter);
    }

    /// The sender (node) ID its frames carry.
    #[must_use]
    pub fn node(&self) -> u64 {
        self.signer.sender()
    }

    fn next_seq(&mut self) -> u64 {
        let s = self.seq;
        self.seq = self.seq.wrapping_add(1);
        s
    }

    fn seal(&mut self, msg: &Msg, out: &mut [u8]) -> Result<usize, WireError> {
        self.signer.seal(msg, out)
    }

    /// Seals a status message into `out`.
    ///
    /// # Errors
    /// [`WireError::BufferTooSmall`], [`WireError::FieldTooLong`].
    pub fn status(
        &mut self,
        behaviour: &str,
        san: &str,
        pose: Option<Pose>,
        out: &mut [u8],
    ) -> Result<usize, WireError> {
        let m = Msg::Status {
            robot: self.robot.clone(),
            seq: self.next_seq(),
            behaviour: behaviour.to_owned(),
            san: san.to_owned(),
            pose,
        };
        self.seal(&m, out)
    }

    /// Seals an emergency into `out`.
    ///
    /// # Errors
    /// As [`Broadcaster::status`].
    pub fn emergency(
        &mut self,
        kind: &str,
        text: &str,
        out: &mut [u8],
    ) -> Result<usize, WireError> {
        let m = Msg::Emergency {
            robot: self.robot.clone(),
            seq: self.next_seq(),
            kind: kind.to_owned(),
            text: text.to_owned(),
        };
        self.seal(&m, out)
    }

    /// Seals a mission event into `out`.
    ///
    /// # Errors
    /// As [`Broadcaster::status`].
    pub fn mission(
        &mut self,
        event: MissionEvent,
        target: &str,
        out: &mut [u8],
    ) -> Result<usize, WireError> {
        let m = Msg::Mission {
            robot: self.robot.clone(),
            seq: self.next_seq(),
            event,
            target: target.to_owned(),
        };
        self.seal(&m, out)
    }
}

/// Receiver configuration.
#[derive(Debug, Clone, Copy)]
pub struct ReceiverConfig {
    /// Robots remembered at most (the one heard longest ago is forgotten first; default 64).
    pub max_robots: usize,
    /// A robot silent this long is forgotten (default 10 s).
    pub forget_after: Duration,
    /// Body-size limit.
    pub max_body: usize,
}

impl Default for ReceiverConfig {
    fn default() -> Self {
        Self {
            max_robots: 64,
            forget_after: Duration::from_secs(10),
            max_body: super::wire::DEFAULT_MAX_BODY,
        }
    }
}

/// Why a broadcast frame was dropped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Rejection {
    /// It did not open (bad MAC, replayed counter, malformed…).
    Wire(WireError),
    /// Same sequence number as the last accepted from this robot.
    Duplicate {
        /// Sequence number.
        seq: u64,
    },
    /// Lower sequence number than the last accepted (a stale reordering).
    Stale {
        /// Last accepted.
        last: u64,
        /// This one.
        seq: u64,
    },
    /// A valid frame that is not a broadcast message (type code).
    NotBroadcast(u8),
}

/// Counters of the receiver.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ReceiverStats {
    /// Accepted messages.
    pub accepted: u64,
    /// Wire rejections (see [`BroadcastReceiver::wire_rejects`] for classes).
    pub wire: u64,
    /// Duplicates.
    pub duplicate: u64,
    /// Stale reorderings.
    pub stale: u64,
    /// Non-broadcast messages.
    pub not_broadcast: u64,
}

/// Opens broadcasts and drops duplicates and stale reorderings.
#[derive(Debug, Clone)]
pub struct BroadcastReceiver {
    cfg: ReceiverConfig,
    verifier: Verifier,
    /// (robot, sender node) → (last seq, last heard)
    robots: BTreeMap<(String, u64), (u64, Instant)>,
    stats: ReceiverStats,
    last_sender: Option<u64>,
}

impl BroadcastReceiver {
    /// A receiver for the group.
    #[must_use]
    pub fn new(key: GroupKey, cfg: ReceiverConfig) -> Self {
        Self {
            verifier: Verifier::with_limits(key, cfg.max_body, cfg.max_robots.max(1)),
            cfg,
            robots: BTreeMap::new(),
            stats: ReceiverStats::default(),
            last_sender: None,
        }
    }

    /// Sender (node) ID of the message last returned by
    /// [`BroadcastReceiver::handle_datagram`] (a shell drops its own messages by this ID,
    /// not by robot name, which another process may share).
    #[must_use]
    pub fn last_sender(&self) -> Option<u64> {
        self.last_sender
    }

    /// Counters.
    #[must_use]
    pub fn stats(&self) -> ReceiverStats {
        self.stats
    }

    /// Wire rejections by class.
    #[must_use]
    pub fn wire_rejects(&self) -> super::wire::RejectCounts {
        self.verifier.rejects
    }

    /// Bounds for the first counter of an unknown sender (see
    /// [`super::wire::Verifier::set_first_counter_window`]).
    pub fn set_first_counter_window(&mut self, window: Option<(u64, u64)>) {
        self.verifier.set_first_counter_window(window);
    }

    /// One datagram. Returns the message if it is new.
    ///
    /// # Errors
    /// [`Rejection`]; every rejection is counted.
    pub fn handle_datagram(&mut self, frame: &[u8], now: Instant) -> Result<Msg, Rejection> {
        let r = self.accept(frame, now);
        let s = &mut self.stats;
        let c = match r {
            Ok(_) => &mut s.accepted,
            Err(Rejection::Wire(_)) => &mut s.wire,
            Err(Rejection::Duplicate { .. }) => &mut s.duplicate,
            Err(Rejection::Stale { .. }) => &mut s.stale,
            Err(Rejection::NotBroadcast(_)) => &mut s.not_broadcast,
        };
        *c = c.saturating_add(1);
        r
    }

    fn accept(&mut self, frame: &[u8], now: Instant) -> Result<Msg, Rejection> {
        let o = match self.verifier.open(frame) {
            Ok(o) => o,
            // The frame last accepted from this sender, again (authentic: the MAC is checked
            // before the counter): a second copy, e.g. multicast plus unicast in mode
            // `both`. Counted as a duplicate, not as a replay.
            Err(WireError::Replay { sender, last, got })
                if got == last && self.verifier.knows(sender) =>
            {
                self.verifier.rejects.replay = self.verifier.rejects.replay.saturating_sub(1);
                let seq = match parse_unauthenticated(frame, self.cfg.max_body).map(|o| o.msg) {
                    Ok(
                        Msg::Status { seq, .. }
                        | Msg::Emergency { seq, .. }
                        | Msg::Mission { seq, .. },
                    ) => seq,
                    _ => 0,
                };
                return Err(Rejection::Duplicate { seq });
            }
            Err(e) => return Err(Rejection::Wire(e)),
        };
        let (robot, seq) = match &o.msg {
            Msg::Status { robot, seq, .. }
            | Msg::Emergency { robot, seq, .. }
            | Msg::Mission { robot, seq, .. } => (robot.clone(), *seq),
            other => return Err(Rejection::NotBroadcast(other.code())),
        };
        let from = (robot, o.sender);
        if let Some(&(last, heard)) = self.robots.get(&from)
            && now.saturating_duration_since(heard) < self.cfg.forget_after
        {
            if seq == last {
                return Err(Rejection::Duplicate { seq });
            }
            if seq < last {
                return Err(Rejection::Stale { last, seq });
            }
        }
        if !self.robots.contains_key(&from) && self.robots.len() >= self.cfg.max_robots.max(1) {
            let oldest = self
                .robots
                .iter()
                .min_by_key(|(_, (_, t))| *t)
                .map(|(r, _)| r.clone());
            if let Some(r) = oldest {
                self.robots.remove(&r);
            }
        }
        self.robots.insert(from, (seq, now));
        self.last_sender = Some(o.sender);
        Ok(o.msg)
    }
}

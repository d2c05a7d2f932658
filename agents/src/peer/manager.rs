//! The Peer Agent Manager core: one per robot (PEER.md, "Manager rules").
//!
//! Sans-IO: the shell assigns every client TCP session a [`PeerId`] and feeds
//! [`PeerManager::handle_frame`] the frames cut with [`super::wire::frame_len`], calls
//! [`PeerManager::handle_timeout`] at [`PeerManager::poll_timeout`], writes what
//! [`PeerManager::poll_transmit`] gives to the named session, and acts on
//! [`PeerManager::poll_event`] (notably [`ManagerEvent::ClosePeer`]).
//!
//! # Priority (PEER.md rule 2)
//!
//! A request's [`Priority`] is the pair (robot priority, request priority), compared
//! lexicographically; the robot priority comes from [`ManagerConfig::robot_priorities`]
//! (unknown robots get [`ManagerConfig::unknown_robot_priority`]). A request is granted only
//! when its *request* priority is at least the source robot's current task priority (asked
//! of the [`SelfAgent`]) and the source has a free slot
//! ([`ManagerConfig::max_grants_per_source`]). Otherwise it is pending. Pending requests are
//! examined highest priority first; ties go to the earlier request, then to the lower client
//! ID (arrival is the `now` of the request, so two requests of one instant tie). They are
//! re-examined whenever the task priority changes, a request is made, renewed or
//! withdrawn, a client goes away, or a source changes.
//!
//! When the task priority rises above a granted request's priority, the grant is revoked
//! ([`RevokeReason::TaskPriority`]) and the request goes back to the pending queue with its
//! original arrival order, to be granted again when the task priority falls. A grant at
//! capacity is not pre-empted by a later, higher request (it waits for a slot).
//!
//! # Tickets (rule 3)
//!
//! A ticket is nonce (8, LE) ‖ expiry in µs of the manager's clock (8, LE) ‖ the first 16
//! bytes of HMAC-SHA-256 under the manager's private *ticket key* over `"ima-ticket"` ‖
//! client ‖ source ‖ nonce ‖ expiry. [`PeerManager::check_ticket`] accepts it only while it
//! has not expired, its MAC verifies (constant-time), and the grant it was issued for still
//! stands with the same nonce (so a revoked or re-issued ticket is dead);
//! [`PeerManager::redeem_ticket`] also uses it up (one ticket, one data session).

use std::collections::{BTreeMap, VecDeque};
use std::time::Duration;

use hmac::{Hmac, Mac};
use ima_hal::Instant;
use sha2::Sha256;

use super::wire::{
    DeclineReason, DenyReason, GroupKey, Msg, RejectCounts, RevokeReason, Signer, SourceInfo,
    TICKET_LEN, Ticket, Verifier, WireError,
};

/// The shell's handle for one client session (e.g. a TCP connection number).
pub type PeerId = u64;

/// The Self Agent as the manager sees it (PEER.md, "Self Agent interaction channel").
pub trait SelfAgent {
    /// The robot's current task priority.
    fn task_priority(&mut self, now: Instant) -> u8;
    /// The robot's data sources now (called at every re-scan).
    fn sources(&mut self, now: Instant) -> Vec<SourceInfo>;
    /// Told of every request and every decision about it.
    fn notify(&mut self, decision: &Decision);
}

/// A Self Agent with a fixed (settable) task priority and source list, for tools and tests.
/// Keeps the last [`FixedSelfAgent::MAX_LOG`] decisions.
#[derive(Debug, Clone, Default)]
pub struct FixedSelfAgent {
    /// Task priority reported.
    pub task_priority: u8,
    /// Sources reported.
    pub sources: Vec<SourceInfo>,
    /// Decisions seen, oldest first.
    pub decisions: VecDeque<Decision>,
}

impl FixedSelfAgent {
    /// Decisions kept.
    pub const MAX_LOG: usize = 256;

    /// A Self Agent with this task priority and these sources.
    #[must_use]
    pub fn new(task_priority: u8, sources: Vec<SourceInfo>) -> Self {
        Self {
            task_priority,
            sources,
            decisions: VecDeque::new(),
        }
    }
}

impl SelfAgent for FixedSelfAgent {
    fn task_priority(&mut self, _now: Instant) -> u8 {
        self.task_priority
    }
    fn sources(&mut self, _now: Instant) -> Vec<SourceInfo> {
        self.sources.clone()
    }
    fn notify(&mut self, decision: &Decision) {
        if self.decisions.len() >= Self::MAX_LOG {
            self.decisions.pop_front();
        }
        self.decisions.push_back(decision.clone());
    }
}

/// The ordering key of a request: robot priority first, then request priority.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Priority {
    /// The requesting robot's priority (from config).
    pub robot: u8,
    /// The request's own priority.
    pub request: u8,
}

/// What the manager decided about a request.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Outcome {
    /// Granted (or re-granted on renewal).
    Granted,
    /// Queued.
    Pending,
    /// Refused.
    Denied(DenyReason),
    /// A grant (or pending request) was revoked.
    Revoked(RevokeReason),
    /// The client withdrew it (disconnect, unregister or loss).
    Withdrawn,
}

/// One decision, as shown to the Self Agent and in events.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Decision {
    /// Client ID.
    pub client: u64,
    /// The client's robot.
    pub robot: String,
    /// Source name.
    pub source: String,
    /// The request's priority.
    pub priority: Priority,
    /// The task priority at the time.
    pub task_priority: u8,
    /// What was decided.
    pub outcome: Outcome,
    /// When.
    pub at: Instant,
}

/// Why the manager wants a session closed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CloseReason {
    /// A frame failed to open (malformed, unauthenticated, replayed, oversize…).
    Wire(WireError),
    /// A message a client may not send (its type code).
    Unexpected(u8),
    /// No frame for the configured number of heartbeat intervals.
    Lost,
    /// The session's outgoing queue overflowed.
    SlowConsumer,
}

impl core::fmt::Display for CloseReason {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Wire(e) => write!(f, "a frame failed to open: {e}"),
            Self::Unexpected(code) => {
                write!(f, "a message a client may not send (type {code:#04x})")
            }
            Self::Lost => f.write_str("no frame within the missed-heartbeat window"),
            Self::SlowConsumer => f.write_str("its outgoing queue overflowed (a slow reader)"),
        }
    }
}

/// What the manager reports to its shell and status display.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ManagerEvent {
    /// A client registered.
    Registered {
        /// Session.
        peer: PeerId,
        /// Client ID.
        client: u64,
    },
    /// A registration was declined.
    Declined {
        /// Session.
        peer: PeerId,
        /// Client ID.
        client: u64,
        /// Why.
        reason: DeclineReason,
    },
    /// A client unregistered.
    Unregistered {
        /// Session.
        peer: PeerId,
        /// Client ID.
        client: u64,
    },
    /// A decision about a request (also given to the Self Agent).
    Decision(Decision),
    /// The sources changed at a re-scan.
    SourcesChanged {
        /// Added or changed sources.
        added: Vec<SourceInfo>,
        /// Removed source names.
        removed: Vec<String>,
    },
    /// The shell must close this session; its clients, requests and grants are dropped.
    ClosePeer {
        /// Session.
        peer: PeerId,
        /// Why.
        reason: CloseReason,
        /// The client IDs that were dropped with it.
        clients: Vec<u64>,
    },
}

/// Why a data session's ticket is refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TicketError {
    /// The MAC does not verify (forged, or for another client or source).
    Forged,
    /// Past its expiry.
    Expired,
    /// No standing grant with this ticket (revoked, re-issued, or the client is gone).
    NotGranted,
    /// The ticket already opened a data session.
    AlreadyUsed,
}

impl core::fmt::Display for TicketError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::Forged => "the ticket does not verify",
            Self::Expired => "the ticket has expired",
            Self::NotGranted => "the ticket stands for no grant",
            Self::AlreadyUsed => "the ticket already opened a data session",
        })
    }
}

impl core::error::Error for TicketError {}

/// Manager configuration.
#[derive(Debug, Clone)]
pub struct ManagerConfig {
    /// This robot's name.
    pub robot: String,
    /// Sender ID of this manager's frames.
    pub node: u64,
    /// First frame counter (see [`Signer::new`]).
    pub first_counter: u64,
    /// Address of this robot's data server, put in every grant.
    pub data_address: String,
    /// Heartbeat interval (default 100 ms).
    pub heartbeat: Duration,
    /// A session is lost after this many intervals without a frame (default 3).
    pub missed_heartbeats: u32,
    /// Source re-scan interval (default 1 s).
    pub rescan: Duration,
    /// Ticket lifetime (default 5 s).
    pub ticket_lifetime: Duration,
    /// Robot priorities (a leader gets the highest).
    pub robot_priorities: Vec<(String, u8)>,
    /// Priority of a robot not listed (default 0, the lowest).
    pub unknown_robot_priority: u8,
    /// Maximum registered clients (default 1024).
    pub max_clients: usize,
    /// Maximum pending requests (default 1024).
    pub max_pending: usize,
    /// Maximum grants per source (default unlimited).
    pub max_grants_per_source: usize,
    /// Maximum queued outgoing messages (default 8192); a session that overflows it is closed.
    pub max_outbox: usize,
    /// Maximum queued events (default 1024); the oldest are dropped and counted.
    pub max_events: usize,
    /// Body-size limit of incoming frames.
    pub max_body: usize,
    /// Senders whose last frame counter is remembered (default 4096). The counters are kept
    /// across sessions, so frames recorded on one session cannot be replayed on another;
    /// a sender forgotten to make room (the one heard longest ago) could be replayed.
    pub max_senders: usize,
}

impl ManagerConfig {
    /// Defaults for robot `robot` with data server at `data_address`.
    #[must_use]
    pub fn new(robot: &str, node: u64, data_address: &str) -> Self {
        Self {
            robot: robot.to_owned(),
            node,
            first_counter: 1,
            data_address: data_address.to_owned(),
            heartbeat: Duration::from_millis(100),
            missed_heartbeats: 3,
            rescan: Duration::from_secs(1),
            ticket_lifetime: Duration::from_secs(5),
            robot_priorities: Vec::new(),
            unknown_robot_priority: 0,
            max_clients: 1024,
            max_pending: 1024,
            max_grants_per_source: usize::MAX,
            max_outbox: 8192,
            max_events: 1024,
            max_body: super::wire::DEFAULT_MAX_BODY,
            max_senders: 4096,
        }
    }
}

/// Status of one client, for displays (PEER.md, "Client procedures").
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ClientStatus {
    /// Client ID.
    pub client: u64,
    /// Session.
    pub peer: PeerId,
    /// Robot.
    pub robot: String,
    /// Sources requested and not (yet) granted.
    pub requesting: Vec<String>,
    /// Sources granted.
    pub granted: Vec<String>,
    /// Every open request (pending or granted) with its priority.
    pub requests: Vec<RequestStatus>,
    /// The latest decisions about this client's requests, oldest first (at most
    /// [`RECENT_DECISIONS`]).
    pub recent: Vec<DecisionNote>,
}

/// One open request of a client ([`ClientStatus::requests`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RequestStatus {
    /// Source name.
    pub source: String,
    /// Its priority (robot, request).
    pub priority: Priority,
    /// Granted (else pending).
    pub granted: bool,
}

/// A decision about one of a client's requests ([`ClientStatus::recent`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DecisionNote {
    /// Source name.
    pub source: String,
    /// The request's priority.
    pub priority: Priority,
    /// What was decided.
    pub outcome: Outcome,
    /// When.
    pub at: Instant,
}

/// Decisions kept per client for its status ([`ClientStatus::recent`]).
pub const RECENT_DECISIONS: usize = 8;

/// Health of one request-channel session (PEER.md, "Liveness"), for status displays.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LinkStatus {
    /// The session.
    pub peer: PeerId,
    /// Authenticated frames received on it.
    pub frames_received: u64,
    /// Heartbeats received on it.
    pub heartbeats_received: u64,
    /// Heartbeats sent on it.
    pub heartbeats_sent: u64,
    /// Time since its last authenticated frame.
    pub silent_for: Duration,
    /// Time since it opened.
    pub open_for: Duration,
}

/// Counters.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ManagerStats {
    /// Rejected frames by class (all sessions).
    pub rejects: RejectCounts,
    /// Sessions closed for a bad frame or a forbidden message.
    pub closed_bad: u64,
    /// Sessions declared lost.
    pub lost: u64,
    /// Events dropped because the event queue was full.
    pub dropped_events: u64,
    /// Messages that could not be sealed into the caller's buffer.
    pub emit_errors: u64,
    /// Frames from unknown sessions (ignored).
    pub unknown_peer: u64,
}

#[derive(Debug)]
struct Session {
    last_heard: Instant,
    next_heartbeat: Instant,
    opened: Instant,
    frames_in: u64,
    heartbeats_in: u64,
    heartbeats_out: u64,
    slow: bool,
    /// Data-server address for the grants of this session (`None`: the configured one).
    data_address: Option<String>,
}

#[derive(Debug, Clone)]
struct ClientRec {
    peer: PeerId,
    robot: String,
    robot_priority: u8,
    recent: VecDeque<DecisionNote>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum ReqState {
    Pending,
    Granted { nonce: u64 },
}

#[derive(Debug, Clone)]
struct Req {
    priority: Priority,
    arrival: Instant,
    state: ReqState,
    redeemed: bool,
}

/// The manager state machine.
#[derive(Debug)]
pub struct PeerManager<A: SelfAgent> {
    cfg: ManagerConfig,
    ticket_key: [u8; 32],
    agent: A,
    signer: Signer,
    verifier: Verifier,
    sessions: BTreeMap<PeerId, Session>,
    clients: BTreeMap<u64, ClientRec>,
    requests: BTreeMap<(u64, String), Req>,
    nonces: u64,
    sources: Vec<SourceInfo>,
    task_priority: u8,
    next_rescan: Instant,
    outbox: VecDeque<(PeerId, Msg)>,
    events: VecDeque<ManagerEvent>,
    stats: ManagerStats,
}

impl<A: SelfAgent> PeerManager<A> {
    /// A manager. `ticket_key` must be secret and random (the shell draws it at start-up);
    /// the group key authenticates every frame.
    pub fn new(
        cfg: ManagerConfig,
        key: GroupKey,
        ticket_key: [u8; 32],
        mut agent: A,
        now: Instant,
    ) -> Self {
        let sources = sorted(agent.sources(now));
        let task_priority = agent.task_priority(now);
        let signer = Signer::new(key.clone(), cfg.node, cfg.first_counter);
        let verifier = Verifier::with_limits(key, cfg.max_body, cfg.max_senders);
        Self {
            next_rescan: now + cfg.rescan,
            cfg,
            ticket_key,
            agent,
            signer,
            verifier,
            sessions: BTreeMap::new(),
            clients: BTreeMap::new(),
            requests: BTreeMap::new(),
            nonces: 0,
            sources,
            task_priority,
            outbox: VecDeque::new(),
            events: VecDeque::new(),
            stats: ManagerStats::default(),
        }
    }

    /// The Self Agent.
    pub fn agent(&self) -> &A {
        &self.agent
    }

    /// The Self Agent, mutably (e.g. to change a [`FixedSelfAgent`]'s task priority; the
    /// change is acted on at the next input or timeout).
    pub fn agent_mut(&mut self) -> &mut A {
        &mut self.agent
    }

    /// Counters.
    #[must_use]
    pub fn stats(&self) -> ManagerStats {
        self.stats
    }

    /// The competency list (sorted by name).
    #[must_use]
    pub fn sources(&self) -> &[SourceInfo] {
        &self.sources
    }

    /// The task priority last read from the Self Agent.
    #[must_use]
    pub fn task_priority(&self) -> u8 {
        self.task_priority
    }

    /// Status of every registered client, by client ID.
    #[must_use]
    pub fn status(&self) -> Vec<ClientStatus> {
        self.clients
            .iter()
            .map(|(&client, c)| {
                let mut s = ClientStatus {
                    client,
                    peer: c.peer,
                    robot: c.robot.clone(),
                    requesting: Vec::new(),
                    granted: Vec::new(),
                    requests: Vec::new(),
                    recent: c.recent.iter().cloned().collect(),
                };
                for ((cl, src), r) in &self.requests {
                    if *cl == client {
                        let granted = matches!(r.state, ReqState::Granted { .. });
                        if granted {
                            s.granted.push(src.clone());
                        } else {
                            s.requesting.push(src.clone());
                        }
                        s.requests.push(RequestStatus {
                            source: src.clone(),
                            priority: r.priority,
                            granted,
                        });
                    }
                }
                s
            })
            .collect()
    }

    /// Health of every open session at `now`, by session.
    #[must_use]
    pub fn links(&self, now: Instant) -> Vec<LinkStatus> {
        self.sessions
            .iter()
            .map(|(&peer, s)| LinkStatus {
                peer,
                frames_received: s.frames_in,
                heartbeats_received: s.heartbeats_in,
                heartbeats_sent: s.heartbeats_out,
                silent_for: now.saturating_duration_since(s.last_heard),
                open_for: now.saturating_duration_since(s.opened),
            })
            .collect()
    }

    /// Number of open sessions.
    #[must_use]
    pub fn session_count(&self) -> usize {
        self.sessions.len()
    }

    /// A new session (the shell accepted a connection). Frames from a session not
    /// connected this way are ignored and counted.
    pub fn connect(&mut self, peer: PeerId, now: Instant) {
        self.sessions.insert(
            peer,
            Session {
                last_heard: now,
                next_heartbeat: now,
                opened: now,
                frames_in: 0,
                heartbeats_in: 0,
                heartbeats_out: 0,
                slow: false,
                data_address: None,
            },
        );
    }

    /// Sets the data-server address put in the grants sent on session `peer` (e.g. the
    /// local IP the client reached, when the data server listens on every interface).
    pub fn set_data_address(&mut self, peer: PeerId, address: String) {
        if let Some(s) = self.sessions.get_mut(&peer) {
            s.data_address = Some(address);
        }
    }

    /// The shell saw the session close: its clients, requests and grants are dropped.
    pub fn disconnect(&mut self, peer: PeerId, now: Instant) {
        self.drop_session(peer, None, now);
    }

    /// Bounds for the first counter of an unknown sender (see
    /// [`super::wire::Verifier::set_first_counter_window`]); the shell passes its clock.
    pub fn set_first_counter_window(&mut self, window: Option<(u64, u64)>) {
        self.verifier.set_first_counter_window(window);
    }

    /// One frame from session `peer`. A frame that fails to open, or a message a client may
    /// not send, closes that session ([`ManagerEvent::ClosePeer`]); others are unaffected.
    pub fn handle_frame(&mut self, peer: PeerId, frame: &[u8], now: Instant) {
        self.refresh_task_priority(now);
        if !self.sessions.contains_key(&peer) {
            self.stats.unknown_peer = self.stats.unknown_peer.saturating_add(1);
            return;
        }
        match self.verifier.open(frame) {
            Ok(o) => {
                if let Some(s) = self.sessions.get_mut(&peer) {
                    s.last_heard = now;
                    s.frames_in = s.frames_in.saturating_add(1);
                    if matches!(o.msg, Msg::Heartbeat) {
                        s.heartbeats_in = s.heartbeats_in.saturating_add(1);
                    }
                }
                self.handle_msg(peer, o.msg, now);
            }
            Err(e) => {
                self.stats.rejects = self.verifier.rejects;
                self.stats.closed_bad = self.stats.closed_bad.saturating_add(1);
                self.drop_session(peer, Some(CloseReason::Wire(e)), now);
            }
        }
    }

    fn handle_msg(&mut self, peer: PeerId, msg: Msg, now: Instant) {
        match msg {
            Msg::Heartbeat => {}
            Msg::Register { client, robot } => self.register(peer, client, robot, now),
            Msg::Unregister { client } => {
                if self.clients.get(&client).is_some_and(|c| c.peer == peer) {
                    self.remove_client(client, now);
                    self.send(peer, Msg::Unregistered { client });
                    self.push_event(ManagerEvent::Unregistered { peer, client });
                    self.reexamine(now);
                }
            }
            Msg::Request {
                client,
                source,
                priority,
            } => self.request(peer, client, source, priority, now),
            Msg::Disconnect { client, source } => {
                if self.clients.get(&client).is_some_and(|c| c.peer == peer)
                    && let Some(r) = self.requests.remove(&(client, source.clone()))
                {
                    self.decide(client, &source, r.priority, Outcome::Withdrawn, now);
                    self.reexamine(now);
                }
            }
            other => {
                self.stats.closed_bad = self.stats.closed_bad.saturating_add(1);
                self.drop_session(peer, Some(CloseReason::Unexpected(other.code())), now);
            }
        }
    }

    fn register(&mut self, peer: PeerId, client: u64, robot: String, _now: Instant) {
        let reason = if self.clients.contains_key(&client) {
            Some(DeclineReason::DuplicateId)
        } else if self.clients.len() >= self.cfg.max_clients {
            Some(DeclineReason::Full)
        } else {
            None
        };
        if let Some(reason) = reason {
            self.send(peer, Msg::Declined { client, reason });
            self.push_event(ManagerEvent::Declined {
                peer,
                client,
                reason,
            });
            return;
        }
        let robot_priority = self
            .cfg
            .robot_priorities
            .iter()
            .find(|(r, _)| *r == robot)
            .map_or(self.cfg.unknown_robot_priority, |(_, p)| *p);
        self.clients.insert(
            client,
            ClientRec {
                peer,
                robot,
                robot_priority,
                recent: VecDeque::new(),
            },
        );
        self.send(
            peer,
            Msg::Registered {
                client,
                sources: self.sources.clone(),
            },
        );
        self.push_event(ManagerEvent::Registered { peer, client });
    }

    fn request(&mut self, peer: PeerId, client: u64, source: String, prio: u8, now: Instant) {
        let deny = |this: &mut Self, reason: DenyReason, priority: Priority| {
            this.send(
                peer,
                Msg::Denied {
                    client,
                    source: source.clone(),
                    reason,
                },
            );
            this.decide(client, &source, priority, Outcome::Denied(reason), now);
        };
        let Some(c) = self.clients.get(&client).filter(|c| c.peer == peer) else {
            let p = Priority {
                robot: self.cfg.unknown_robot_priority,
                request: prio,
            };
            deny(self, DenyReason::NotRegistered, p);
            return;
        };
        let priority = Priority {
            robot: c.robot_priority,
            request: prio,
        };
        if !self.sources.iter().any(|s| s.name == source) {
            deny(self, DenyReason::UnknownSource, priority);
            return;
        }
        let key = (client, source.clone());
        if let Some(r) = self.requests.get_mut(&key) {
            // Renewal: new priority; a standing grant gets a fresh ticket.
            // (If the task now outranks the new priority, `reexamine` revokes it instead.)
            r.priority = priority;
            if matches!(r.state, ReqState::Granted { .. }) && prio >= self.task_priority {
                self.grant(client, &source, now);
            }
        } else {
            let pending = self
                .requests
                .values()
                .filter(|r| r.state == ReqState::Pending)
                .count();
            if pending >= self.cfg.max_pending {
                deny(self, DenyReason::QueueFull, priority);
                return;
            }
            self.requests.insert(
                key.clone(),
                Req {
                    priority,
                    arrival: now,
                    state: ReqState::Pending,
                    redeemed: false,
                },
            );
        }
        self.reexamine(now);
        if let Some(r) = self.requests.get(&key)
            && r.state == ReqState::Pending
        {
            self.send(peer, Msg::Pending { client, source });
            self.decide(client, &key.1, priority, Outcome::Pending, now);
        }
    }

    /// Grants and revokes as the rules say; see the module docs.
    fn reexamine(&mut self, now: Instant) {
        let task = self.task_priority;
        // Revoke grants the task now outranks; they become pending again.
        let outranked: Vec<(u64, String)> = self
            .requests
            .iter()
            .filter(|(_, r)| {
                matches!(r.state, ReqState::Granted { .. }) && r.priority.request < task
            })
            .map(|(k, _)| k.clone())
            .collect();
        for (client, source) in outranked {
            if let Some(r) = self.requests.get_mut(&(client, source.clone())) {
                r.state = ReqState::Pending;
                let p = r.priority;
                self.revoke_msg(client, &source, RevokeReason::TaskPriority);
                self.decide(
                    client,
                    &source,
                    p,
                    Outcome::Revoked(RevokeReason::TaskPriority),
                    now,
                );
            }
        }
        // Serve pending requests, best first.
        let mut pending: Vec<(Priority, Instant, u64, String)> = self
            .requests
            .iter()
            .filter(|(_, r)| r.state == ReqState::Pending && r.priority.request >= task)
            .map(|((c, s), r)| (r.priority, r.arrival, *c, s.clone()))
            .collect();
        pending.sort_by(|a, b| b.0.cmp(&a.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
        for (_, _, client, source) in pending {
            let in_use = self
                .requests
                .iter()
                .filter(|((_, s), r)| *s == source && matches!(r.state, ReqState::Granted { .. }))
                .count();
            if in_use < self.cfg.max_grants_per_source {
                self.grant(client, &source, now);
            }
        }
    }

    fn grant(&mut self, client: u64, source: &str, now: Instant) {
        self.nonces = self.nonces.wrapping_add(1);
        let nonce = self.nonces;
        let expiry = now + self.cfg.ticket_lifetime;
        let ticket = self.make_ticket(client, source, nonce, expiry.as_micros());
        let Some(r) = self.requests.get_mut(&(client, source.to_owned())) else {
            return;
        };
        r.state = ReqState::Granted { nonce };
        r.redeemed = false;
        let priority = r.priority;
        if let Some(peer) = self.clients.get(&client).map(|c| c.peer) {
            let address = self
                .sessions
                .get(&peer)
                .and_then(|s| s.data_address.clone())
                .unwrap_or_else(|| self.cfg.data_address.clone());
            self.send(
                peer,
                Msg::Granted {
                    client,
                    source: source.to_owned(),
                    address,
                    ticket,
                },
            );
        }
        self.decide(client, source, priority, Outcome::Granted, now);
    }

    fn ticket_mac(&self, client: u64, source: &str, nonce: u64, expiry: u64) -> Hmac<Sha256> {
        let mut mac = match Hmac::<Sha256>::new_from_slice(&self.ticket_key) {
            Ok(m) => m,
            Err(_) => Hmac::<Sha256>::new(&Default::default()),
        };
        mac.update(b"ima-ticket");
        mac.update(&client.to_le_bytes());
        mac.update(&(source.len() as u64).to_le_bytes());
        mac.update(source.as_bytes());
        mac.update(&nonce.to_le_bytes());
        mac.update(&expiry.to_le_bytes());
        mac
    }

    fn make_ticket(&self, client: u64, source: &str, nonce: u64, expiry: u64) -> Ticket {
        let tag = self
            .ticket_mac(client, source, nonce, expiry)
            .finalize()
            .into_bytes();
        let mut t = [0u8; TICKET_LEN];
        let (n, rest) = t.split_at_mut(8);
        n.copy_from_slice(&nonce.to_le_bytes());
        let (e, m) = rest.split_at_mut(8);
        e.copy_from_slice(&expiry.to_le_bytes());
        for (d, s) in m.iter_mut().zip(tag.iter()) {
            *d = *s;
        }
        t
    }

    /// Redeems a data-session ticket: [`PeerManager::check_ticket`], then marks it used, so
    /// one ticket opens one data session (a recorded OpenData cannot be replayed). After a
    /// data session drops, the client renews its request to get a fresh ticket.
    ///
    /// # Errors
    /// [`TicketError`].
    pub fn redeem_ticket(
        &mut self,
        client: u64,
        source: &str,
        ticket: &Ticket,
        now: Instant,
    ) -> Result<(), TicketError> {
        self.check_ticket(client, source, ticket, now)?;
        if let Some(r) = self.requests.get_mut(&(client, source.to_owned())) {
            r.redeemed = true;
        }
        Ok(())
    }

    /// Checks a data-session ticket without using it up.
    ///
    /// # Errors
    /// [`TicketError`].
    pub fn check_ticket(
        &self,
        client: u64,
        source: &str,
        ticket: &Ticket,
        now: Instant,
    ) -> Result<(), TicketError> {
        let (n, rest) = ticket.split_at(8);
        let (e, m) = rest.split_at(8);
        let mut nb = [0u8; 8];
        nb.copy_from_slice(n);
        let mut eb = [0u8; 8];
        eb.copy_from_slice(e);
        let (nonce, expiry) = (u64::from_le_bytes(nb), u64::from_le_bytes(eb));
        self.ticket_mac(client, source, nonce, expiry)
            .verify_truncated_left(m)
            .map_err(|_| TicketError::Forged)?;
        if now.as_micros() >= expiry {
            return Err(TicketError::Expired);
        }
        match self.requests.get(&(client, source.to_owned())) {
            Some(Req {
                state: ReqState::Granted { nonce: g },
                redeemed,
                ..
            }) if *g == nonce => {
                if *redeemed {
                    Err(TicketError::AlreadyUsed)
                } else {
                    Ok(())
                }
            }
            _ => Err(TicketError::NotGranted),
        }
    }

    fn revoke_msg(&mut self, client: u64, source: &str, reason: RevokeReason) {
        if let Some(peer) = self.clients.get(&client).map(|c| c.peer) {
            self.send(
                peer,
                Msg::Revoked {
                    client,
                    source: source.to_owned(),
                    reason,
                },
            );
        }
    }

    fn decide(&mut self, client: u64, source: &str, priority: Priority, o: Outcome, now: Instant) {
        let robot = self
            .clients
            .get(&client)
            .map(|c| c.robot.clone())
            .unwrap_or_default();
        if let Some(c) = self.clients.get_mut(&client) {
            if c.recent.len() >= RECENT_DECISIONS {
                c.recent.pop_front();
            }
            c.recent.push_back(DecisionNote {
                source: source.to_owned(),
                priority,
                outcome: o,
                at: now,
            });
        }
        let d = Decision {
            client,
            robot,
            source: source.to_owned(),
            priority,
            task_priority: self.task_priority,
            outcome: o,
            at: now,
        };
        self.agent.notify(&d);
        self.push_event(ManagerEvent::Decision(d));
    }

    fn remove_client(&mut self, client: u64, now: Instant) {
        let keys: Vec<(u64, String)> = self
            .requests
            .keys()
            .filter(|(c, _)| *c == client)
            .cloned()
            .collect();
        for k in keys {
            if let Some(r) = self.requests.remove(&k) {
                self.decide(client, &k.1, r.priority, Outcome::Withdrawn, now);
            }
        }
        self.clients.remove(&client);
    }

    fn drop_session(&mut self, peer: PeerId, reason: Option<CloseReason>, now: Instant) {
        if self.sessions.remove(&peer).is_none() {
            return;
        }
        let ids: Vec<u64> = self
            .clients
            .iter()
            .filter(|(_, c)| c.peer == peer)
            .map(|(id, _)| *id)
            .collect();
        for &id in &ids {
            self.remove_client(id, now);
        }
        self.outbox.retain(|(p, _)| *p != peer);
        if let Some(reason) = reason {
            self.push_event(ManagerEvent::ClosePeer {
                peer,
                reason,
                clients: ids,
            });
        }
        self.reexamine(now);
    }

    fn send(&mut self, peer: PeerId, msg: Msg) {
        if self.outbox.len() >= self.cfg.max_outbox {
            // Bounded: the session that cannot keep up is closed, not the queue grown.
            // The session is closed at the next timeout, which is due at once.
            self.outbox.retain(|(p, _)| *p != peer);
            if let Some(s) = self.sessions.get_mut(&peer) {
                s.last_heard = Instant::ZERO;
                s.slow = true;
            }
            return;
        }
        self.outbox.push_back((peer, msg));
    }

    fn push_event(&mut self, e: ManagerEvent) {
        if self.events.len() >= self.cfg.max_events {
            self.events.pop_front();
            self.stats.dropped_events = self.stats.dropped_events.saturating_add(1);
        }
        self.events.push_back(e);
    }

    fn refresh_task_priority(&mut self, now: Instant) {
        let t = self.agent.task_priority(now);
        if t != self.task_priority {
            self.task_priority = t;
            self.reexamine(now);
        }
    }

    fn loss_window(&self) -> Duration {
        self.cfg
            .heartbeat
            .saturating_mul(self.cfg.missed_heartbeats.max(1))
    }

    /// Timers: heartbeats, loss detection, source re-scan, task-priority poll.
    pub fn handle_timeout(&mut self, now: Instant) {
        self.refresh_task_priority(now);
        let window = self.loss_window();
        let lost: Vec<(PeerId, bool)> = self
            .sessions
            .iter()
            .filter(|(_, s)| s.slow || now >= s.last_heard + window)
            .map(|(p, s)| (*p, s.slow))
            .collect();
        for (p, slow) in lost {
            let reason = if slow {
                CloseReason::SlowConsumer
            } else {
                self.stats.lost = self.stats.lost.saturating_add(1);
                CloseReason::Lost
            };
            self.drop_session(p, Some(reason), now);
        }
        let due: Vec<PeerId> = self
            .sessions
            .iter()
            .filter(|(_, s)| now >= s.next_heartbeat)
            .map(|(p, _)| *p)
            .collect();
        for p in due {
            self.send(p, Msg::Heartbeat);
            if let Some(s) = self.sessions.get_mut(&p) {
                s.next_heartbeat = now + self.cfg.heartbeat;
                s.heartbeats_out = s.heartbeats_out.saturating_add(1);
            }
        }
        if now >= self.next_rescan {
            self.next_rescan = now + self.cfg.rescan;
            self.rescan(now);
        }
    }

    /// Re-scans the sources now (also done at every re-scan interval).
    pub fn rescan(&mut self, now: Instant) {
        let new = sorted(self.agent.sources(now));
        let added: Vec<SourceInfo> = new
            .iter()
            .filter(|s| !self.sources.contains(s))
            .cloned()
            .collect();
        let removed: Vec<String> = self
            .sources
            .iter()
            .filter(|o| !new.iter().any(|s| s.name == o.name))
            .map(|o| o.name.clone())
            .collect();
        if added.is_empty() && removed.is_empty() {
            return;
        }
        self.sources = new;
        let gone: Vec<(u64, String)> = self
            .requests
            .keys()
            .filter(|(_, s)| removed.contains(s))
            .cloned()
            .collect();
        for (client, source) in gone {
            if let Some(r) = self.requests.remove(&(client, source.clone())) {
                self.revoke_msg(client, &source, RevokeReason::SourceGone);
                self.decide(
                    client,
                    &source,
                    r.priority,
                    Outcome::Revoked(RevokeReason::SourceGone),
                    now,
                );
            }
        }
        let mut peers: Vec<PeerId> = self.clients.values().map(|c| c.peer).collect();
        peers.sort_unstable();
        peers.dedup();
        for p in peers {
            self.send(
                p,
                Msg::SourcesChanged {
                    added: added.clone(),
                    removed: removed.clone(),
                },
            );
        }
        self.push_event(ManagerEvent::SourcesChanged { added, removed });
        self.reexamine(now);
    }

    /// Shutting down: every grant is revoked with [`RevokeReason::Shutdown`].
    pub fn shutdown(&mut self, now: Instant) {
        let keys: Vec<(u64, String)> = self.requests.keys().cloned().collect();
        for (client, source) in keys {
            if let Some(r) = self.requests.remove(&(client, source.clone())) {
                if matches!(r.state, ReqState::Granted { .. }) {
                    self.revoke_msg(client, &source, RevokeReason::Shutdown);
                }
                self.decide(
                    client,
                    &source,
                    r.priority,
                    Outcome::Revoked(RevokeReason::Shutdown),
                    now,
                );
            }
        }
    }

    /// When [`PeerManager::handle_timeout`] should next be called.
    #[must_use]
    pub fn poll_timeout(&self) -> Option<Instant> {
        let window = self.loss_window();
        self.sessions
            .values()
            .flat_map(|s| [s.next_heartbeat, s.last_heard + window])
            .chain(core::iter::once(self.next_rescan))
            .min()
    }

    /// The next frame to send: `(session, length)` with the frame in `buf[..length]`. `buf`
    /// should hold a maximum frame (`HEADER_LEN + max body + MAC_LEN`); a message that does
    /// not fit is dropped and counted in [`ManagerStats::emit_errors`].
    pub fn poll_transmit(&mut self, buf: &mut [u8]) -> Option<(PeerId, usize)> {
        while let Some((peer, msg)) = self.outbox.pop_front() {
            match self.signer.seal(&msg, buf) {
                Ok(n) => return Some((peer, n)),
                Err(_) => self.stats.emit_errors = self.stats.emit_errors.saturating_add(1),
            }
        }
        None
    }

    /// The next event.
    pub fn poll_event(&mut self) -> Option<ManagerEvent> {
        self.events.pop_front()
    }
}

fn sorted(mut v: Vec<SourceInfo>) -> Vec<SourceInfo> {
    v.sort();
    v.dedup_by(|a, b| a.name == b.name);
    v
}

//! The Peer Agent Client core: one per local agent that wants data from another robot
//! (PEER.md, "Client procedures"), over one session to one manager.
//!
//! The four procedures [`PeerClient::register`], [`PeerClient::unregister`],
//! [`PeerClient::request`] and [`PeerClient::disconnect`] return a typed result at once and
//! queue a frame; the manager's answers come back as [`ClientEvent`]s. A registration
//! declined for a duplicate ID is retried with a fresh ID (the thesis's procedure) up to
//! [`ClientConfig::max_retries`] times. IDs come from a SplitMix64 sequence seeded by the
//! shell with a random value, so the core stays deterministic under test.
//!
//! If nothing arrives from the manager for [`ClientConfig::missed_heartbeats`] intervals, or a
//! frame fails to open, the manager is declared lost: every granted source is reported gone
//! ([`ClientEvent::SourceGone`]) so the shell closes its data sessions and tells the target
//! agent, which keeps running.

use std::collections::{BTreeMap, VecDeque};
use std::time::Duration;

use ima_hal::Instant;

use super::wire::{
    DeclineReason, DenyReason, GroupKey, Msg, RevokeReason, Signer, SourceInfo, Ticket, Verifier,
    WireError,
};

/// Client configuration.
#[derive(Debug, Clone)]
pub struct ClientConfig {
    /// Name of this client's robot.
    pub robot: String,
    /// Sender ID of this client's frames.
    pub node: u64,
    /// First frame counter (see [`Signer::new`]).
    pub first_counter: u64,
    /// Seed of the client-ID sequence (random in the shell).
    pub id_seed: u64,
    /// Heartbeat interval (default 100 ms).
    pub heartbeat: Duration,
    /// The manager is lost after this many intervals without a frame (default 3).
    pub missed_heartbeats: u32,
    /// Retries with a new ID after a duplicate-ID decline (default 8).
    pub max_retries: u32,
    /// Body-size limit of incoming frames.
    pub max_body: usize,
    /// Maximum queued events / outgoing messages (default 1024 each).
    pub max_queue: usize,
}

impl ClientConfig {
    /// Defaults for a client on robot `robot`.
    #[must_use]
    pub fn new(robot: &str, node: u64, id_seed: u64) -> Self {
        Self {
            robot: robot.to_owned(),
            node,
            first_counter: 1,
            id_seed,
            heartbeat: Duration::from_millis(100),
            missed_heartbeats: 3,
            max_retries: 8,
            max_body: super::wire::DEFAULT_MAX_BODY,
            max_queue: 1024,
        }
    }
}

/// Registration state.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Registration {
    /// Not registered.
    Unregistered,
    /// Register sent, no answer yet.
    Registering,
    /// Registered.
    Registered,
    /// Unregister sent, no answer yet.
    Unregistering,
    /// The manager session is lost or closed; nothing more can be done on it.
    Lost,
}

/// State of one requested source.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum SourceState {
    /// Requested, not granted (sent, or pending at the manager).
    Requesting,
    /// Granted: open a data session to `address` with `ticket`.
    Granted {
        /// Data-server address.
        address: String,
        /// Ticket.
        ticket: Ticket,
    },
}

/// A procedure's immediate result.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ClientError {
    /// `register` while registered or registering.
    AlreadyRegistered,
    /// A procedure that needs a registration, without one.
    NotRegistered,
    /// `disconnect` of a source not requested.
    NotRequested,
    /// The manager session is lost.
    Lost,
    /// Too many messages queued.
    QueueFull,
}

impl core::fmt::Display for ClientError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::AlreadyRegistered => "already registered with the manager",
            Self::NotRegistered => "not registered with the manager",
            Self::NotRequested => "that source was not requested",
            Self::Lost => "the manager session is lost",
            Self::QueueFull => "too many messages queued for the manager",
        })
    }
}

impl core::error::Error for ClientError {}

/// What the client reports.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ClientEvent {
    /// Registered under `client`, with the manager's competency list.
    Registered {
        /// Client ID.
        client: u64,
        /// Sources.
        sources: Vec<SourceInfo>,
    },
    /// Registration declined; `retry_with` is the new ID tried, if any.
    Declined {
        /// The declined ID.
        client: u64,
        /// Why.
        reason: DeclineReason,
        /// New ID of the retry (None: gave up).
        retry_with: Option<u64>,
    },
    /// Unregistered.
    Unregistered,
    /// Granted: open the data session.
    Granted {
        /// Source.
        source: String,
        /// Data-server address.
        address: String,
        /// Ticket.
        ticket: Ticket,
    },
    /// The request waits at the manager.
    Pending {
        /// Source.
        source: String,
    },
    /// The request was denied.
    Denied {
        /// Source.
        source: String,
        /// Why.
        reason: DenyReason,
    },
    /// A grant was revoked (for [`RevokeReason::TaskPriority`] the request is pending again).
    Revoked {
        /// Source.
        source: String,
        /// Why.
        reason: RevokeReason,
    },
    /// The manager's sources changed.
    SourcesChanged {
        /// Added or changed.
        added: Vec<SourceInfo>,
        /// Removed names.
        removed: Vec<String>,
    },
    /// Close the data session of this source and tell the target it is gone.
    SourceGone {
        /// Source.
        source: String,
    },
    /// The manager is lost (no frame for the loss window, or a bad frame: `Some(error)`).
    ManagerLost(Option<WireError>),
}

/// The client state machine.
#[derive(Debug)]
pub struct PeerClient {
    cfg: ClientConfig,
    signer: Signer,
    verifier: Verifier,
    id_state: u64,
    id: u64,
    retries: u32,
    reg: Registration,
    sources_known: Vec<SourceInfo>,
    requests: BTreeMap<String, SourceState>,
    last_heard: Instant,
    next_heartbeat: Instant,
    opened: Instant,
    frames_in: u64,
    heartbeats_in: u64,
    heartbeats_out: u64,
    outbox: VecDeque<Msg>,
    events: VecDeque<ClientEvent>,
}

/// Health of a client's session to its manager (PEER.md, "Liveness"), for status displays.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ClientLinkStatus {
    /// The current client ID.
    pub client: u64,
    /// Registration state.
    pub registration: Registration,
    /// Authenticated frames received from the manager.
    pub frames_received: u64,
    /// Heartbeats received from the manager.
    pub heartbeats_received: u64,
    /// Heartbeats sent to the manager.
    pub heartbeats_sent: u64,
    /// Time since the manager's last authenticated frame.
    pub silent_for: Duration,
    /// Time since the session opened.
    pub open_for: Duration,
    /// Frames from the manager refused, by class (a refused frame ends the session).
    pub rejects: super::wire::RejectCounts,
    /// Every requested source, and whether it is granted.
    pub requests: Vec<(String, bool)>,
}

/// The largest client ID (and sender ID the shells draw): 2^53 − 1, the largest integer a
/// JSON reader that holds numbers as doubles (a browser, Foxglove, `jq`) shows exactly.
pub const MAX_ID: u64 = (1 << 53) - 1;

/// The next client ID of the sequence `state`: 53 bits, so that status shown as JSON (in a
/// browser, Foxglove, `jq`) names the client exactly.
fn next_id(state: &mut u64) -> u64 {
    splitmix64(state) >> 11
}

fn splitmix64(state: &mut u64) -> u64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

impl PeerClient {
    /// A client whose session to the manager has just opened at `now`.
    #[must_use]
    pub fn new(cfg: ClientConfig, key: GroupKey, now: Instant) -> Self {
        let mut id_state = cfg.id_seed;
        let id = next_id(&mut id_state);
        Self {
            signer: Signer::new(key.clone(), cfg.node, cfg.first_counter),
            verifier: Verifier::with_limits(key, cfg.max_body, 1),
            id_state,
            id,
            retries: 0,
            reg: Registration::Unregistered,
            sources_known: Vec::new(),
            requests: BTreeMap::new(),
            last_heard: now,
            next_heartbeat: now,
            opened: now,
            frames_in: 0,
            heartbeats_in: 0,
            heartbeats_out: 0,
            outbox: VecDeque::new(),
            events: VecDeque::new(),
            cfg,
        }
    }

    /// The current client ID.
    #[must_use]
    pub fn id(&self) -> u64 {
        self.id
    }

    /// Registration state.
    #[must_use]
    pub fn registration(&self) -> Registration {
        self.reg
    }

    /// The competency list last received.
    #[must_use]
    pub fn sources(&self) -> &[SourceInfo] {
        &self.sources_known
    }

    /// State of every requested source.
    #[must_use]
    pub fn requests(&self) -> &BTreeMap<String, SourceState> {
        &self.requests
    }

    /// Frames rejected so far, by class.
    #[must_use]
    pub fn rejects(&self) -> super::wire::RejectCounts {
        self.verifier.rejects
    }

    /// The session's health at `now`.
    #[must_use]
    pub fn link_status(&self, now: Instant) -> ClientLinkStatus {
        ClientLinkStatus {
            client: self.id,
            registration: self.reg,
            frames_received: self.frames_in,
            heartbeats_received: self.heartbeats_in,
            heartbeats_sent: self.heartbeats_out,
            silent_for: now.saturating_duration_since(self.last_heard),
            open_for: now.saturating_duration_since(self.opened),
            rejects: self.verifier.rejects,
            requests: self
                .requests
                .iter()
                .map(|(k, v)| (k.clone(), matches!(v, SourceState::Granted { .. })))
                .collect(),
        }
    }

    fn send(&mut self, m: Msg) -> Result<(), ClientError> {
        if self.outbox.len() >= self.cfg.max_queue {
            return Err(ClientError::QueueFull);
        }
        self.outbox.push_back(m);
        Ok(())
    }

    fn event(&mut self, e: ClientEvent) {
        if self.events.len() >= self.cfg.max_queue {
            self.events.pop_front();
        }
        self.events.push_back(e);
    }

    fn usable(&self) -> Result<(), ClientError> {
        match self.reg {
            Registration::Lost => Err(ClientError::Lost),
            Registration::Registered => Ok(()),
            _ => Err(ClientError::NotRegistered),
        }
    }

    /// Procedure *register*.
    ///
    /// # Errors
    /// [`ClientError::AlreadyRegistered`], [`ClientError::Lost`], [`ClientError::QueueFull`].
    pub fn register(&mut self) -> Result<(), ClientError> {
        match self.reg {
            Registration::Lost => return Err(ClientError::Lost),
            Registration::Unregistered => {}
            _ => return Err(ClientError::AlreadyRegistered),
        }
        self.retries = 0;
        self.send(Msg::Register {
            client: self.id,
            robot: self.cfg.robot.clone(),
        })?;
        self.reg = Registration::Registering;
        Ok(())
    }

    /// Procedure *unregister* (drops every request and grant at the manager).
    ///
    /// # Errors
    /// [`ClientError::NotRegistered`], [`ClientError::Lost`], [`ClientError::QueueFull`].
    pub fn unregister(&mut self) -> Result<(), ClientError> {
        self.usable()?;
        self.send(Msg::Unregister { client: self.id })?;
        self.reg = Registration::Unregistering;
        self.drop_all_sources();
        Ok(())
    }

    /// Procedure *request* (or renew a request) for `source` at `priority`.
    ///
    /// # Errors
    /// [`ClientError::NotRegistered`], [`ClientError::Lost`], [`ClientError::QueueFull`].
    pub fn request(&mut self, source: &str, priority: u8) -> Result<(), ClientError> {
        self.usable()?;
        self.send(Msg::Request {
            client: self.id,
            source: source.to_owned(),
            priority,
        })?;
        self.requests
            .entry(source.to_owned())
            .or_insert(SourceState::Requesting);
        Ok(())
    }

    /// Procedure *disconnect* from `source` (ends the request or grant).
    ///
    /// # Errors
    /// [`ClientError::NotRequested`], [`ClientError::NotRegistered`], [`ClientError::Lost`],
    /// [`ClientError::QueueFull`].
    pub fn disconnect(&mut self, source: &str) -> Result<(), ClientError> {
        self.usable()?;
        if !self.requests.contains_key(source) {
            return Err(ClientError::NotRequested);
        }
        self.send(Msg::Disconnect {
            client: self.id,
            source: source.to_owned(),
        })?;
        if let Some(SourceState::Granted { .. }) = self.requests.remove(source) {
            self.event(ClientEvent::SourceGone {
                source: source.to_owned(),
            });
        }
        Ok(())
    }

    fn drop_all_sources(&mut self) {
        let granted: Vec<String> = self
            .requests
            .iter()
            .filter(|(_, s)| matches!(s, SourceState::Granted { .. }))
            .map(|(n, _)| n.clone())
            .collect();
        self.requests.clear();
        for source in granted {
            self.event(ClientEvent::SourceGone { source });
        }
    }

    fn lose(&mut self, why: Option<WireError>) {
        if self.reg == Registration::Lost {
            return;
        }
        self.drop_all_sources();
        self.reg = Registration::Lost;
        self.outbox.clear();
        self.event(ClientEvent::ManagerLost(why));
    }

    /// The shell saw the session close.
    pub fn closed(&mut self) {
        self.lose(None);
    }

    /// One frame from the manager.
    pub fn handle_frame(&mut self, frame: &[u8], now: Instant) {
        if self.reg == Registration::Lost {
            return;
        }
        match self.verifier.open(frame) {
            Ok(o) => {
                self.last_heard = now;
                self.frames_in = self.frames_in.saturating_add(1);
                if matches!(o.msg, Msg::Heartbeat) {
                    self.heartbeats_in = self.heartbeats_in.saturating_add(1);
                }
                self.handle_msg(o.msg);
            }
            Err(e) => self.lose(Some(e)),
        }
    }

    fn handle_msg(&mut self, msg: Msg) {
        match msg {
            Msg::Registered { client, sources }
                if client == self.id && self.reg == Registration::Registering =>
            {
                self.reg = Registration::Registered;
                self.sources_known = sources.clone();
                self.event(ClientEvent::Registered { client, sources });
            }
            Msg::Declined { client, reason } if client == self.id => {
                if self.reg != Registration::Registering {
                    return;
                }
                let retry =
                    reason == DeclineReason::DuplicateId && self.retries < self.cfg.max_retries;
                let retry_with = if retry {
                    self.retries = self.retries.saturating_add(1);
                    self.id = next_id(&mut self.id_state);
                    let m = Msg::Register {
                        client: self.id,
                        robot: self.cfg.robot.clone(),
                    };
                    self.send(m).ok().map(|()| self.id)
                } else {
                    None
                };
                if retry_with.is_none() {
                    self.reg = Registration::Unregistered;
                }
                self.event(ClientEvent::Declined {
                    client,
                    reason,
                    retry_with,
                });
            }
            Msg::Unregistered { client } if client == self.id => {
                self.reg = Registration::Unregistered;
                self.event(ClientEvent::Unregistered);
            }
            Msg::Granted {
                client,
                source,
                address,
                ticket,
            } if client == self.id && self.requests.contains_key(&source) => {
                self.requests.insert(
                    source.clone(),
                    SourceState::Granted {
                        address: address.clone(),
                        ticket,
                    },
                );
                self.event(ClientEvent::Granted {
                    source,
                    address,
                    ticket,
                });
            }
            Msg::Pending { client, source }
                if client == self.id && self.requests.contains_key(&source) =>
            {
                self.event(ClientEvent::Pending { source });
            }
            Msg::Denied {
                client,
                source,
                reason,
            } if client == self.id && self.requests.contains_key(&source) => {
                self.requests.remove(&source);
                self.event(ClientEvent::Denied { source, reason });
            }
            Msg::Revoked {
                client,
                source,
                reason,
            } if client == self.id => {
                let was_granted = matches!(
                    self.requests.get(&source),
                    Some(SourceState::Granted { .. })
                );
                if reason == RevokeReason::TaskPriority {
                    if let Some(s) = self.requests.get_mut(&source) {
                        *s = SourceState::Requesting;
                    }
                } else {
                    self.requests.remove(&source);
                }
                if was_granted {
                    self.event(ClientEvent::SourceGone {
                        source: source.clone(),
                    });
                }
                self.event(ClientEvent::Revoked { source, reason });
            }
            Msg::SourcesChanged { added, removed } => {
                self.sources_known.retain(|s| {
                    !removed.contains(&s.name) && !added.iter().any(|a| a.name == s.name)
                });
                self.sources_known.extend(added.iter().cloned());
                self.sources_known.sort();
                self.event(ClientEvent::SourcesChanged { added, removed });
            }
            // Heartbeats, answers for an older ID, and messages not meant for a client are
            // ignored (the MAC proved they come from the group).
            _ => {}
        }
    }

    fn loss_window(&self) -> Duration {
        self.cfg
            .heartbeat
            .saturating_mul(self.cfg.missed_heartbeats.max(1))
    }

    /// Timers: heartbeat and loss detection.
    pub fn handle_timeout(&mut self, now: Instant) {
        if self.reg == Registration::Lost {
            return;
        }
        if now >= self.last_heard + self.loss_window() {
            self.lose(None);
            return;
        }
        if now >= self.next_heartbeat {
            self.next_heartbeat = now + self.cfg.heartbeat;
            if self.send(Msg::Heartbeat).is_ok() {
                self.heartbeats_out = self.heartbeats_out.saturating_add(1);
            }
        }
    }

    /// When [`PeerClient::handle_timeout`] should next be called.
    #[must_use]
    pub fn poll_timeout(&self) -> Option<Instant> {
        (self.reg != Registration::Lost).then(|| {
            self.next_heartbeat
                .min(self.last_heard + self.loss_window())
        })
    }

    /// Moves the frame counter up to `counter` (see [`super::wire::Signer::advance_to`]);
    /// a shell with clock-valued counters calls it with its clock before transmitting.
    pub fn advance_counter(&mut self, counter: u64) {
        self.signer.advance_to(counter);
    }

    /// The next frame for the manager, sealed into `buf`; returns its length.
    pub fn poll_transmit(&mut self, buf: &mut [u8]) -> Option<usize> {
        while let Some(m) = self.outbox.pop_front() {
            if let Ok(n) = self.signer.seal(&m, buf) {
                return Some(n);
            }
        }
        None
    }

    /// The next event.
    pub fn poll_event(&mut self) -> Option<ClientEvent> {
        self.events.pop_front()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Client IDs fit in 53 bits, so JSON readers that hold numbers as doubles show them
    /// exactly (an ID of 64 random bits showed in the browser console rounded).
    #[test]
    fn client_ids_are_exact_as_json_numbers() {
        for seed in [0, 1, 42, u64::MAX, 0x9E37_79B9_7F4A_7C15] {
            let mut state = seed;
            for _ in 0..1000 {
                let id = next_id(&mut state);
                assert!(id <= MAX_ID, "{id}");
                #[allow(clippy::cast_precision_loss, clippy::cast_possible_truncation)]
                let back = (id as f64) as u64;
                assert_eq!(back, id);
            }
        }
    }
}

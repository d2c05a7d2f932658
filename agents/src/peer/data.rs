//! The data transfer channel: source agent → target agent (PEER.md rules 3, 5, 6).
//!
//! * [`DataServerSession`] — the source robot's end of one data session. The first frame must
//!   be [`Msg::OpenData`] with a ticket that the [`TicketAuthority`] (the
//!   [`PeerManager`]) accepts; anything else closes the session
//!   without a sample sent. Samples [`offer`](DataServerSession::offer)ed by the source go
//!   through a [`LatestQueue`]: a slow consumer loses the oldest samples, the source never
//!   blocks and memory stays bounded. The shell calls [`DataServerSession::revoke`] when the
//!   manager revokes the grant (a [`Decision`](super::manager::Decision) with
//!   `Outcome::Revoked` or `Outcome::Withdrawn`).
//! * [`DataClientSession`] — the target robot's end: presents the ticket, queues received
//!   samples for the target agent (again latest-value, bounded), and reports the end of the
//!   stream (closed by the source, damaged, or lost after the missed-heartbeat window) so the
//!   shell closes the socket and tells the target the source is gone.

use std::collections::VecDeque;
use std::time::Duration;

use ima_hal::Instant;

use super::manager::{PeerManager, SelfAgent, TicketError};
use super::queue::LatestQueue;
use super::wire::{GroupKey, Msg, RevokeReason, Signer, Ticket, Verifier, WireError};

/// Who checks tickets for a data server.
pub trait TicketAuthority {
    /// Whether `ticket` admits `client` to `source` now; a ticket that does is used up.
    ///
    /// # Errors
    /// Why not.
    fn redeem(
        &mut self,
        client: u64,
        source: &str,
        ticket: &Ticket,
        now: Instant,
    ) -> Result<(), TicketError>;
}

impl<A: SelfAgent> TicketAuthority for PeerManager<A> {
    fn redeem(
        &mut self,
        client: u64,
        source: &str,
        ticket: &Ticket,
        now: Instant,
    ) -> Result<(), TicketError> {
        self.redeem_ticket(client, source, ticket, now)
    }
}

/// Data-session configuration (both ends).
#[derive(Debug, Clone)]
pub struct DataConfig {
    /// Sender ID of this end's frames.
    pub node: u64,
    /// First frame counter.
    pub first_counter: u64,
    /// Heartbeat interval (default 100 ms); sent when nothing else was sent for this long.
    pub heartbeat: Duration,
    /// The other end is lost after this many intervals without a frame (default 3).
    pub missed_heartbeats: u32,
    /// Samples queued at most (default 64); older ones are dropped.
    pub queue: usize,
    /// Body-size limit of incoming frames.
    pub max_body: usize,
}

impl DataConfig {
    /// Defaults with this sender ID.
    #[must_use]
    pub fn new(node: u64) -> Self {
        Self {
            node,
            first_counter: 1,
            heartbeat: Duration::from_millis(100),
            missed_heartbeats: 3,
            queue: 64,
            max_body: super::wire::DEFAULT_MAX_BODY,
        }
    }

    fn window(&self) -> Duration {
        self.heartbeat.saturating_mul(self.missed_heartbeats.max(1))
    }
}

/// Why a data session ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DataClose {
    /// The ticket was refused.
    Ticket(TicketError),
    /// The grant was revoked, or the server closed the session, for this reason.
    Revoked(RevokeReason),
    /// A frame failed to open.
    Wire(WireError),
    /// A message not allowed at this point (type code).
    Unexpected(u8),
    /// No frame within the missed-heartbeat window.
    Lost,
    /// Closed by this end ([`DataClientSession::close`]).
    Local,
}

impl core::fmt::Display for DataClose {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Ticket(e) => write!(f, "ticket refused: {e}"),
            Self::Revoked(r) => write!(f, "revoked: {r}"),
            Self::Wire(e) => write!(f, "a damaged frame: {e}"),
            Self::Unexpected(code) => write!(f, "an unexpected message (type {code:#04x})"),
            Self::Lost => f.write_str("no frame within the missed-heartbeat window"),
            Self::Local => f.write_str("closed by this end"),
        }
    }
}

/// Events of a data session.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum DataEvent {
    /// The session is open: server side, for `client` and `source`.
    Opened {
        /// Client ID.
        client: u64,
        /// Source.
        source: String,
    },
    /// The session ended; the shell closes the socket after sending what is queued.
    Closed(DataClose),
}

/// One sample as the target agent receives it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Sample {
    /// Sequence number given by the server.
    pub seq: u64,
    /// Measurement time, µs on the source's clock.
    pub stamp_us: u64,
    /// Bytes.
    pub payload: Vec<u8>,
}

#[derive(Debug, Clone, PartialEq, Eq)]
enum ServerState {
    AwaitOpen,
    Streaming { source: String },
    Closed,
}

/// The source robot's end of one data session.
#[derive(Debug)]
pub struct DataServerSession {
    cfg: DataConfig,
    signer: Signer,
    verifier: Verifier,
    state: ServerState,
    queue: LatestQueue<(u64, Vec<u8>)>,
    seq: u64,
    control: VecDeque<Msg>,
    events: VecDeque<DataEvent>,
    last_heard: Instant,
    last_sent: Instant,
}

impl DataServerSession {
    /// A session whose connection was accepted at `now`.
    #[must_use]
    pub fn new(cfg: DataConfig, key: GroupKey, now: Instant) -> Self {
        Self {
            signer: Signer::new(key.clone(), cfg.node, cfg.first_counter),
            verifier: Verifier::with_limits(key, cfg.max_body, 1),
            state: ServerState::AwaitOpen,
            queue: LatestQueue::new(cfg.queue),
            seq: 0,
            control: VecDeque::new(),
            events: VecDeque::new(),
            last_heard: now,
            last_sent: now,
            cfg,
        }
    }

    /// Whether samples are flowing.
    #[must_use]
    pub fn is_streaming(&self) -> bool {
        matches!(self.state, ServerState::Streaming { .. })
    }

    /// Whether the session has ended.
    #[must_use]
    pub fn is_closed(&self) -> bool {
        self.state == ServerState::Closed
    }

    /// Samples dropped by the latest-value queue so far.
    #[must_use]
    pub fn dropped(&self) -> u64 {
        self.queue.dropped()
    }

    fn close(&mut self, why: DataClose, tell: Option<RevokeReason>) {
        if self.state == ServerState::Closed {
            return;
        }
        let source = match &self.state {
            ServerState::Streaming { source } => source.clone(),
            _ => String::new(),
        };
        self.queue.clear();
        if let Some(reason) = tell {
            self.control.push_back(Msg::DataClosed { source, reason });
        }
        self.state = ServerState::Closed;
        self.events.push_back(DataEvent::Closed(why));
    }

    /// One frame from the client.
    pub fn handle_frame(&mut self, frame: &[u8], tickets: &mut impl TicketAuthority, now: Instant) {
        if self.state == ServerState::Closed {
            return;
        }
        let msg = match self.verifier.open(frame) {
            Ok(o) => o.msg,
            Err(e) => return self.close(DataClose::Wire(e), None),
        };
        self.last_heard = now;
        match (&self.state, msg) {
            (
                ServerState::AwaitOpen,
                Msg::OpenData {
                    client,
                    source,
                    ticket,
                },
            ) => match tickets.redeem(client, &source, &ticket, now) {
                Ok(()) => {
                    self.control.push_back(Msg::DataAccepted {
                        source: source.clone(),
                    });
                    self.events.push_back(DataEvent::Opened {
                        client,
                        source: source.clone(),
                    });
                    self.state = ServerState::Streaming { source };
                }
                Err(e) => {
                    self.control.push_back(Msg::DataClosed {
                        source,
                        reason: RevokeReason::BadTicket,
                    });
                    self.state = ServerState::Closed;
                    self.events
                        .push_back(DataEvent::Closed(DataClose::Ticket(e)));
                }
            },
            (ServerState::Streaming { .. }, Msg::Heartbeat) => {}
            (_, other) => self.close(DataClose::Unexpected(other.code()), None),
        }
    }

    /// A sample from the source. Ignored unless streaming; never blocks: when the queue is
    /// full the oldest queued sample is dropped.
    pub fn offer(&mut self, stamp_us: u64, payload: &[u8]) {
        if self.is_streaming() {
            self.queue.push((stamp_us, payload.to_vec()));
        }
    }

    /// The manager revoked the grant (or is shutting down): tell the client and close.
    pub fn revoke(&mut self, reason: RevokeReason) {
        self.close(DataClose::Revoked(reason), Some(reason));
    }

    /// Timers: heartbeat when idle, loss detection.
    pub fn handle_timeout(&mut self, now: Instant) {
        if self.state == ServerState::Closed {
            return;
        }
        if now >= self.last_heard + self.cfg.window() {
            return self.close(DataClose::Lost, None);
        }
        if now >= self.last_sent + self.cfg.heartbeat
            && self.control.is_empty()
            && self.queue.is_empty()
        {
            self.control.push_back(Msg::Heartbeat);
        }
    }

    /// When [`DataServerSession::handle_timeout`] should next be called.
    #[must_use]
    pub fn poll_timeout(&self) -> Option<Instant> {
        (self.state != ServerState::Closed)
            .then(|| (self.last_sent + self.cfg.heartbeat).min(self.last_heard + self.cfg.window()))
    }

    /// The next frame for the client: control messages first, then samples.
    pub fn poll_transmit(&mut self, buf: &mut [u8], now: Instant) -> Option<usize> {
        loop {
            let msg = if let Some(m) = self.control.pop_front() {
                m
            } else {
                let (stamp_us, payload) = self.queue.pop()?;
                self.seq = self.seq.wrapping_add(1);
                Msg::Sample {
                    seq: self.seq,
                    stamp_us,
                    payload,
                }
            };
            if let Ok(n) = self.signer.seal(&msg, buf) {
                self.last_sent = now;
                return Some(n);
            }
        }
    }

    /// The next event.
    pub fn poll_event(&mut self) -> Option<DataEvent> {
        self.events.pop_front()
    }
}

/// The target robot's end of one data session.
#[derive(Debug)]
pub struct DataClientSession {
    cfg: DataConfig,
    signer: Signer,
    verifier: Verifier,
    client: u64,
    source: String,
    open: bool,
    closed: bool,
    samples: LatestQueue<Sample>,
    last_seq: u64,
    gaps: u64,
    control: VecDeque<Msg>,
    events: VecDeque<DataEvent>,
    last_heard: Instant,
    last_sent: Instant,
}

impl DataClientSession {
    /// A session to the data server of a grant, connected at `now`; queues the
    /// [`Msg::OpenData`] with the ticket.
    #[must_use]
    pub fn new(
        cfg: DataConfig,
        key: GroupKey,
        client: u64,
        source: &str,
        ticket: Ticket,
        now: Instant,
    ) -> Self {
        let mut control = VecDeque::new();
        control.push_back(Msg::OpenData {
            client,
            source: source.to_owned(),
            ticket,
        });
        Self {
            signer: Signer::new(key.clone(), cfg.node, cfg.first_counter),
            verifier: Verifier::with_limits(key, cfg.max_body, 1),
            client,
            source: source.to_owned(),
            open: false,
            closed: false,
            samples: LatestQueue::new(cfg.queue),
            last_seq: 0,
            gaps: 0,
            control,
            events: VecDeque::new(),
            last_heard: now,
            last_sent: now,
            cfg,
        }
    }

    /// Whether the server accepted the ticket and the session is still up.
    #[must_use]
    pub fn is_open(&self) -> bool {
        self.open && !self.closed
    }

    /// Samples the server skipped (sequence gaps) plus samples dropped here because the
    /// target was slow.
    #[must_use]
    pub fn lost_samples(&self) -> u64 {
        self.gaps.saturating_add(self.samples.dropped())
    }

    /// The next sample for the target agent (oldest still held).
    pub fn pop_sample(&mut self) -> Option<Sample> {
        self.samples.pop()
    }

    fn end(&mut self, why: DataClose) {
        if !self.closed {
            self.closed = true;
            self.control.clear();
            self.events.push_back(DataEvent::Closed(why));
        }
    }

    /// Closes from this end (disconnect, revoke or manager loss seen by the client).
    pub fn close(&mut self) {
        self.end(DataClose::Local);
    }

    /// One frame from the server.
    pub fn handle_frame(&mut self, frame: &[u8], now: Instant) {
        if self.closed {
            return;
        }
        let msg = match self.verifier.open(frame) {
            Ok(o) => o.msg,
            Err(e) => return self.end(DataClose::Wire(e)),
        };
        self.last_heard = now;
        match msg {
            Msg::DataAccepted { source } if !self.open && source == self.source => {
                self.open = true;
                self.events.push_back(DataEvent::Opened {
                    client: self.client,
                    source,
                });
            }
            Msg::DataClosed { reason, .. } => self.end(DataClose::Revoked(reason)),
            Msg::Heartbeat => {}
            Msg::Sample {
                seq,
                stamp_us,
                payload,
            } if self.open => {
                if seq > self.last_seq.saturating_add(1) {
                    self.gaps = self
                        .gaps
                        .saturating_add(seq - self.last_seq.saturating_add(1));
                }
                self.last_seq = self.last_seq.max(seq);
                self.samples.push(Sample {
                    seq,
                    stamp_us,
                    payload,
                });
            }
            other => self.end(DataClose::Unexpected(other.code())),
        }
    }

    /// Timers: heartbeat when idle, loss detection.
    pub fn handle_timeout(&mut self, now: Instant) {
        if self.closed {
            return;
        }
        if now >= self.last_heard + self.cfg.window() {
            return self.end(DataClose::Lost);
        }
        if now >= self.last_sent + self.cfg.heartbeat && self.control.is_empty() {
            self.control.push_back(Msg::Heartbeat);
        }
    }

    /// When [`DataClientSession::handle_timeout`] should next be called.
    #[must_use]
    pub fn poll_timeout(&self) -> Option<Instant> {
        (!self.closed)
            .then(|| (self.last_sent + self.cfg.heartbeat).min(self.last_heard + self.cfg.window()))
    }

    /// The next frame for the server.
    pub fn poll_transmit(&mut self, buf: &mut [u8], now: Instant) -> Option<usize> {
        while let Some(m) = self.control.pop_front() {
            if let Ok(n) = self.signer.seal(&m, buf) {
                self.last_sent = now;
                return Some(n);
            }
        }
        None
    }

    /// The next event.
    pub fn poll_event(&mut self) -> Option<DataEvent> {
        self.events.pop_front()
    }
}

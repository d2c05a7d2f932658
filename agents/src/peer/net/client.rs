//! The client shell: one task per manager session owning a [`PeerClient`], one task per
//! data session owning a [`DataClientSession`].

use std::collections::{BTreeMap, VecDeque};
use std::sync::{Arc, Mutex, PoisonError};

use ima_hal::time::{Clock, SharedClock, TokioClock};
use tokio::io::AsyncWriteExt;
use tokio::net::{TcpStream, ToSocketAddrs};
use tokio::sync::{Notify, mpsc, oneshot};
use tokio::task::JoinHandle;

use super::config::PeerNetConfig;
use super::frames::{FrameReader, max_frame, write_batch, write_frames};
use super::{AuthFailure, NetError, NotAPeer};
use super::{random_id, random_u64, unix_micros};
use crate::peer::client::{ClientConfig, ClientEvent, ClientLinkStatus, PeerClient};
use crate::peer::data::{DataClientSession, DataClose, DataConfig, DataEvent};
use crate::peer::wire::{
    DenyReason, GroupKey, HEADER_LEN, MAC_LEN, RevokeReason, SourceInfo, Ticket,
};

/// Why a subscription's data stopped for a while (the request stands; samples resume when
/// the manager grants it again).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LossReason {
    /// The grant was revoked (task priority rose above the request's priority); the request
    /// is pending again at the manager.
    Revoked(RevokeReason),
}

impl core::fmt::Display for LossReason {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Revoked(r) => write!(f, "revoked ({r}); pending again"),
        }
    }
}

/// Why a subscription ended (no more events follow).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EndReason {
    /// The manager is lost (missed heartbeats, a bad frame, or its session closed).
    ManagerLost,
    /// The grant was revoked for good (source gone, manager shutting down).
    Revoked(RevokeReason),
    /// The data session failed (lost, damaged frame, ticket refused).
    Data(DataClose),
    /// This client disconnected the source.
    Disconnected,
    /// This client unregistered.
    Unregistered,
    /// A renewal of the request was denied.
    Denied(DenyReason),
}

impl core::fmt::Display for EndReason {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::ManagerLost => f.write_str("the manager is lost"),
            Self::Revoked(r) => write!(f, "revoked: {r}"),
            Self::Data(c) => write!(f, "data session: {c}"),
            Self::Disconnected => f.write_str("disconnected by this client"),
            Self::Unregistered => f.write_str("this client unregistered"),
            Self::Denied(r) => write!(f, "denied: {r}"),
        }
    }
}

/// What a [`Subscription`] yields.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum SubscriptionEvent {
    /// One sample of the source.
    Sample {
        /// Sequence number of the data session (a gap = samples dropped on the way).
        seq: u64,
        /// Measurement time, µs on the source robot's clock.
        stamp_us: u64,
        /// The bytes.
        payload: Vec<u8>,
    },
    /// The data stopped for a while; it resumes when the source grants again.
    Lost {
        /// Why.
        reason: LossReason,
    },
    /// The subscription is over; [`Subscription::next`] returns `None` afterwards.
    Closed {
        /// Why.
        reason: EndReason,
    },
}

struct SubState {
    queue: VecDeque<SubscriptionEvent>,
    samples: usize,
    cap: usize,
    dropped: u64,
    done: bool,
}

struct SubShared {
    state: Mutex<SubState>,
    notify: Notify,
}

impl SubShared {
    fn new(cap: usize) -> Arc<Self> {
        Arc::new(Self {
            state: Mutex::new(SubState {
                queue: VecDeque::new(),
                samples: 0,
                cap: cap.max(1),
                dropped: 0,
                done: false,
            }),
            notify: Notify::new(),
        })
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, SubState> {
        self.state.lock().unwrap_or_else(PoisonError::into_inner)
    }

    fn push(&self, e: SubscriptionEvent) {
        self.push_all(core::iter::once(e));
    }

    /// Queues events under one lock and wakes the reader once.
    fn push_all(&self, events: impl IntoIterator<Item = SubscriptionEvent>) {
        let mut st = self.lock();
        let mut any = false;
        for e in events {
            if st.done {
                break;
            }
            if matches!(e, SubscriptionEvent::Sample { .. }) {
                if st.samples >= st.cap
                    && let Some(i) = st
                        .queue
                        .iter()
                        .position(|e| matches!(e, SubscriptionEvent::Sample { .. }))
                {
                    st.queue.remove(i);
                    st.samples = st.samples.saturating_sub(1);
                    st.dropped = st.dropped.saturating_add(1);
                }
                st.samples = st.samples.saturating_add(1);
            }
            if matches!(e, SubscriptionEvent::Closed { .. }) {
                st.done = true;
            }
            // Interruptions not yet taken collapse into the latest one.
            if matches!(e, SubscriptionEvent::Lost { .. })
                && matches!(st.queue.back(), Some(SubscriptionEvent::Lost { .. }))
            {
                st.queue.pop_back();
            }
            st.queue.push_back(e);
            any = true;
        }
        drop(st);
        if any {
            self.notify.notify_one();
        }
    }
}

/// The receiving end of a granted request: samples (latest-value: a slow reader loses the
/// oldest), interruptions and the end. Dropping it before its end disconnects the source
/// (as [`PeerClientHandle::disconnect`] would).
pub struct Subscription {
    source: String,
    shared: Arc<SubShared>,
    cmd: mpsc::WeakUnboundedSender<Cmd>,
}

impl Drop for Subscription {
    fn drop(&mut self) {
        if self.shared.lock().done {
            return;
        }
        if let Some(cmd) = self.cmd.upgrade() {
            let _ = cmd.send(Cmd::Dropped {
                source: core::mem::take(&mut self.source),
                shared: self.shared.clone(),
            });
        }
    }
}

impl core::fmt::Debug for Subscription {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Subscription")
            .field("source", &self.source)
            .finish_non_exhaustive()
    }
}

impl Subscription {
    /// The source name.
    #[must_use]
    pub fn source(&self) -> &str {
        &self.source
    }

    /// Samples dropped here because the reader was slow.
    #[must_use]
    pub fn dropped(&self) -> u64 {
        self.shared.lock().dropped
    }

    /// The next event if one is queued now (never waits); `None` when nothing is queued or
    /// the subscription is over (see [`Subscription::is_closed`]).
    pub fn try_next(&mut self) -> Option<SubscriptionEvent> {
        let mut st = self.shared.lock();
        let e = st.queue.pop_front()?;
        if matches!(e, SubscriptionEvent::Sample { .. }) {
            st.samples = st.samples.saturating_sub(1);
        }
        Some(e)
    }

    /// Whether the subscription is over and every event has been taken.
    #[must_use]
    pub fn is_closed(&self) -> bool {
        let st = self.shared.lock();
        st.done && st.queue.is_empty()
    }

    /// The next event; `None` after [`SubscriptionEvent::Closed`] has been returned.
    pub async fn next(&mut self) -> Option<SubscriptionEvent> {
        loop {
            {
                let mut st = self.shared.lock();
                if let Some(e) = st.queue.pop_front() {
                    if matches!(e, SubscriptionEvent::Sample { .. }) {
                        st.samples = st.samples.saturating_sub(1);
                    }
                    return Some(e);
                }
                if st.done {
                    return None;
                }
            }
            self.shared.notify.notified().await;
        }
    }
}

type Reply<T> = oneshot::Sender<Result<T, NetError>>;

enum Cmd {
    Register(Reply<Vec<SourceInfo>>),
    Unregister(Reply<()>),
    Request {
        source: String,
        priority: u8,
        reply: Reply<Subscription>,
    },
    Disconnect {
        source: String,
        reply: Reply<()>,
    },
    Sources(oneshot::Sender<(u64, Vec<SourceInfo>)>),
    Link(oneshot::Sender<ClientLinkStatus>),
    /// A subscription was dropped before its end: disconnect its source.
    Dropped {
        source: String,
        shared: Arc<SubShared>,
    },
}

struct DataEnd {
    source: String,
    generation: u64,
    why: DataClose,
}

/// A client session to one manager. Dropping the handle ends the session (and every data
/// session opened through it); every live subscription then ends with
/// [`EndReason::Disconnected`].
#[derive(Debug)]
pub struct PeerClientHandle {
    cmd: mpsc::UnboundedSender<Cmd>,
    task: JoinHandle<()>,
    call_timeout: Option<std::time::Duration>,
    /// Set when the session ended for want of authentication, or with a peer that never
    /// spoke the protocol.
    auth: Arc<Mutex<Option<Loss>>>,
}

/// Why a session that never heard an authenticated frame ended.
#[derive(Debug, Clone, Copy)]
enum Loss {
    Auth(AuthFailure),
    Foreign(NotAPeer),
}

impl PeerClientHandle {
    /// Connects to the manager at `addr` (its request channel). Robot name, heartbeat and
    /// limits come from `cfg`. Must be called inside a tokio runtime.
    ///
    /// # Errors
    /// [`NetError::Io`] when the connection fails.
    pub async fn connect(
        addr: impl ToSocketAddrs,
        cfg: &PeerNetConfig,
        key: GroupKey,
    ) -> Result<Self, NetError> {
        Self::connect_with_clock(addr, cfg, key, TokioClock::shared()).await
    }

    /// [`PeerClientHandle::connect`] on the process's one clock: the client's and its data
    /// sessions' timers and stamps run on `clock` ([`PeerClientHandle::connect`] makes a
    /// [`TokioClock`] of its own).
    ///
    /// # Errors
    /// As [`PeerClientHandle::connect`].
    pub async fn connect_with_clock(
        addr: impl ToSocketAddrs,
        cfg: &PeerNetConfig,
        key: GroupKey,
        clock: SharedClock,
    ) -> Result<Self, NetError> {
        cfg.validate()?;
        // Bounded like the procedures (`call_timeout_ms`): a black-holed address fails
        // with `Timeout` instead of waiting for the OS (minutes).
        let stream = if cfg.call_timeout_ms > 0 {
            let limit = std::time::Duration::from_millis(cfg.call_timeout_ms);
            tokio::time::timeout(limit, TcpStream::connect(addr))
                .await
                .map_err(|_| NetError::Timeout)??
        } else {
            TcpStream::connect(addr).await?
        };
        let _ = stream.set_nodelay(true);
        let peer = stream.peer_addr()?;
        let auth = Arc::new(Mutex::new(None));
        let mut ccfg = ClientConfig::new(&cfg.robot, random_id(), random_u64());
        ccfg.first_counter = unix_micros();
        ccfg.heartbeat = cfg.heartbeat();
        ccfg.missed_heartbeats = cfg.missed_heartbeats;
        ccfg.max_body = cfg.max_body;
        let mut dcfg = DataConfig::new(0);
        dcfg.heartbeat = cfg.heartbeat();
        dcfg.missed_heartbeats = cfg.missed_heartbeats;
        dcfg.queue = cfg.manager.data_queue.max(1);
        dcfg.max_body = cfg.max_body;
        let core = PeerClient::new(ccfg, key.clone(), clock.now());
        let (cmd_tx, cmd_rx) = mpsc::unbounded_channel();
        let task = ClientTask {
            cmd: cmd_tx.downgrade(),
            core,
            clock,
            key,
            dcfg,
            reg_reply: None,
            unreg_reply: None,
            req_replies: BTreeMap::new(),
            subs: BTreeMap::new(),
            generation: 0,
            peer,
            heard_ok: false,
            received: 0,
            head: ([0; 8], 0),
            eof: false,
            auth: auth.clone(),
        };
        let task = tokio::spawn(task.run(stream, cmd_rx));
        Ok(Self {
            cmd: cmd_tx,
            task,
            call_timeout: (cfg.call_timeout_ms > 0)
                .then(|| std::time::Duration::from_millis(cfg.call_timeout_ms)),
            auth,
        })
    }

    /// Why the session is over: [`NetError::Unauthenticated`] when it ended for want of
    /// authentication, [`NetError::NotAPeer`] when the other end never spoke the protocol,
    /// else [`NetError::ManagerLost`].
    fn lost(&self) -> NetError {
        match *self.auth.lock().unwrap_or_else(PoisonError::into_inner) {
            Some(Loss::Auth(a)) => NetError::Unauthenticated(a),
            Some(Loss::Foreign(a)) => NetError::NotAPeer(a),
            None => NetError::ManagerLost,
        }
    }

    /// The authentication failure that ended the session, if it ended so: frames from the
    /// manager that failed authentication, or a manager that closed the session before
    /// sending one authenticated frame (what a manager does with frames under another key).
    #[must_use]
    pub fn auth_failure(&self) -> Option<AuthFailure> {
        match *self.auth.lock().unwrap_or_else(PoisonError::into_inner) {
            Some(Loss::Auth(a)) => Some(a),
            _ => None,
        }
    }

    async fn call<T>(&self, make: impl FnOnce(Reply<T>) -> Cmd) -> Result<T, NetError> {
        let (tx, rx) = oneshot::channel();
        self.cmd.send(make(tx)).map_err(|_| self.lost())?;
        let r = match self.call_timeout {
            // On a timeout the reply's receiver is dropped: the task withdraws a request
            // granted later.
            Some(t) => tokio::time::timeout(t, rx)
                .await
                .map_err(|_| NetError::Timeout)?
                .map_err(|_| self.lost())?,
            None => rx.await.map_err(|_| self.lost())?,
        };
        // A loss reported by the task may be an authentication failure seen meanwhile.
        match r {
            Err(NetError::ManagerLost) => Err(self.lost()),
            other => other,
        }
    }

    /// Procedure *register*: returns the manager's competency list. A duplicate ID is
    /// retried with a fresh one by the core.
    ///
    /// # Errors
    /// [`NetError::Declined`], [`NetError::Client`], [`NetError::ManagerLost`].
    pub async fn register(&self) -> Result<Vec<SourceInfo>, NetError> {
        self.call(Cmd::Register).await
    }

    /// Procedure *unregister*: every subscription ends ([`EndReason::Unregistered`]).
    ///
    /// # Errors
    /// [`NetError::Client`], [`NetError::ManagerLost`].
    pub async fn unregister(&self) -> Result<(), NetError> {
        self.call(Cmd::Unregister).await
    }

    /// Procedure *request*: waits until the manager grants (also after a `Pending`), then
    /// returns the subscription whose data session is being opened.
    ///
    /// # Errors
    /// [`NetError::Denied`], [`NetError::AlreadySubscribed`], [`NetError::Client`],
    /// [`NetError::ManagerLost`], [`NetError::Revoked`] (source removed while pending).
    pub async fn request(&self, source: &str, priority: u8) -> Result<Subscription, NetError> {
        self.call(|reply| Cmd::Request {
            source: source.to_owned(),
            priority,
            reply,
        })
        .await
    }

    /// Procedure *disconnect*: ends the request or grant for `source`; its subscription
    /// ends with [`EndReason::Disconnected`].
    ///
    /// # Errors
    /// [`NetError::Client`], [`NetError::ManagerLost`].
    pub async fn disconnect(&self, source: &str) -> Result<(), NetError> {
        self.call(|reply| Cmd::Disconnect {
            source: source.to_owned(),
            reply,
        })
        .await
    }

    /// The current client ID and the competency list last received.
    ///
    /// # Errors
    /// [`NetError::ManagerLost`] once the session is over.
    pub async fn sources(&self) -> Result<(u64, Vec<SourceInfo>), NetError> {
        let (tx, rx) = oneshot::channel();
        self.cmd.send(Cmd::Sources(tx)).map_err(|_| self.lost())?;
        rx.await.map_err(|_| self.lost())
    }

    /// The session's health: heartbeats both ways, last seen, refused frames, requests.
    ///
    /// # Errors
    /// [`NetError::ManagerLost`] once the session is over.
    pub async fn link_status(&self) -> Result<ClientLinkStatus, NetError> {
        let (tx, rx) = oneshot::channel();
        self.cmd.send(Cmd::Link(tx)).map_err(|_| self.lost())?;
        rx.await.map_err(|_| self.lost())
    }

    /// Whether the manager session is over (lost or closed).
    #[must_use]
    pub fn is_lost(&self) -> bool {
        self.task.is_finished()
    }
}

struct SubRec {
    shared: Arc<SubShared>,
    data: Option<(u64, oneshot::Sender<()>)>,
}

struct ClientTask {
    /// For the subscriptions (weak: the handle's drop still closes the channel).
    cmd: mpsc::WeakUnboundedSender<Cmd>,
    core: PeerClient,
    clock: SharedClock,
    key: GroupKey,
    dcfg: DataConfig,
    reg_reply: Option<Reply<Vec<SourceInfo>>>,
    unreg_reply: Option<Reply<()>>,
    req_replies: BTreeMap<String, Reply<Subscription>>,
    subs: BTreeMap<String, SubRec>,
    generation: u64,
    /// The manager's address (for [`AuthFailure`]).
    peer: std::net::SocketAddr,
    /// A frame from the manager passed authentication.
    heard_ok: bool,
    /// Bytes received from the manager.
    received: u64,
    /// The first bytes read from the manager (frame or not), and how many.
    head: ([u8; 8], u8),
    /// The manager closed the connection.
    eof: bool,
    auth: Arc<Mutex<Option<Loss>>>,
}

impl ClientTask {
    /// Hands frames to the core, noting whether any passed authentication.
    fn frames(&mut self, reader: &mut FrameReader, now: ima_hal::Instant) {
        // The stream's first bytes, frame or not (a short foreign reply makes no frame).
        self.head = reader.head();
        while let Some(f) = reader.next_frame() {
            let before = self.core.rejects();
            self.core.handle_frame(f, now);
            if self.core.rejects() == before {
                self.heard_ok = true;
            }
        }
    }

    /// On the loss of the session: an [`AuthFailure`] when frames from the manager failed
    /// authentication, or when the manager closed the session before one authenticated
    /// frame came back (a manager closes the session of a frame under another key); a
    /// [`NotAPeer`] when no authenticated frame came and the other end sent bytes that are no
    /// Peer frame, or nothing while keeping the connection open.
    fn note_auth_failure(&mut self) {
        let r = self.core.rejects();
        let frames = r.bad_mac;
        let head = self
            .head
            .0
            .get(..usize::from(self.head.1))
            .unwrap_or_default();
        // Bytes that cannot begin a Peer frame, even too few for a header.
        let magic = crate::peer::wire::MAGIC;
        let alien = !head.is_empty() && !head.starts_with(&magic) && !magic.starts_with(head);
        let foreign =
            r.bad_magic > 0 || r.bad_version > 0 || alien || (!self.eof && self.received == 0);
        let loss = if frames > 0 {
            Loss::Auth(AuthFailure {
                from: self.peer,
                frames,
            })
        } else if self.heard_ok {
            return;
        } else if foreign {
            Loss::Foreign(NotAPeer {
                from: self.peer,
                bytes: self.received,
                head: self.head.0,
                head_len: self.head.1,
            })
        } else {
            Loss::Auth(AuthFailure {
                from: self.peer,
                frames,
            })
        };
        *self.auth.lock().unwrap_or_else(PoisonError::into_inner) = Some(loss);
    }

    async fn run(mut self, stream: TcpStream, mut cmds: mpsc::UnboundedReceiver<Cmd>) {
        let max_body = self.dcfg.max_body;
        let (mut rd, wr) = stream.into_split();
        let (wtx, wrx) = mpsc::channel(1024);
        let window = self
            .dcfg
            .heartbeat
            .saturating_mul(self.dcfg.missed_heartbeats.max(1));
        let writer = tokio::spawn(write_frames(wr, wrx, window));
        let (dtx, mut drx) = mpsc::unbounded_channel::<DataEnd>();
        let mut reader = FrameReader::new(max_body);
        let mut buf = vec![0u8; HEADER_LEN + usize::from(u16::MAX) + MAC_LEN];
        let mut lost = false;
        while !lost {
            let sleep = tokio::time::sleep_until(deadline(&self.clock, self.core.poll_timeout()));
            // Biased: input before timers, so that a task that was starved of CPU first
            // takes what its peer sent and only then looks at its deadlines.
            tokio::select! {
                biased;
                r = reader.read_from(&mut rd) => match r {
                    Ok(0) | Err(_) => {
                        self.eof = true;
                        self.core.closed();
                    }
                    Ok(n) => {
                        self.received = self.received.saturating_add(n as u64);
                        let now = self.clock.now();
                        self.frames(&mut reader, now);
                    }
                },
                c = cmds.recv() => match c {
                    Some(c) => self.handle_cmd(c),
                    None => break,
                },
                Some(d) = drx.recv() => self.data_end(d),
                () = sleep => {
                    let now = self.clock.now();
                    match reader.try_read_from(&rd) {
                        Ok(Some(0)) | Err(_) => {
                            self.eof = true;
                            self.core.closed();
                        }
                        Ok(Some(n)) => {
                            self.received = self.received.saturating_add(n as u64);
                            self.frames(&mut reader, now);
                        }
                        Ok(None) => {}
                    }
                    self.core.handle_timeout(self.clock.now());
                }
            }
            // Counters are UNIX µs: keep them close to the clock (the manager checks the
            // first one it hears against its own).
            self.core.advance_counter(unix_micros());
            while let Some(n) = self.core.poll_transmit(&mut buf) {
                if let Some(f) = buf.get(..n)
                    && wtx.try_send(f.to_vec()).is_err()
                {
                    self.core.closed();
                }
            }
            while let Some(e) = self.core.poll_event() {
                if matches!(e, ClientEvent::ManagerLost(_)) {
                    lost = true;
                }
                self.handle_event(e, &dtx);
            }
        }
        // Lost or dropped: every data session ends with the session.
        let reason = if lost {
            EndReason::ManagerLost
        } else {
            EndReason::Disconnected
        };
        for (_, sub) in std::mem::take(&mut self.subs) {
            if let Some((_, close)) = sub.data {
                let _ = close.send(());
            }
            sub.shared.push(SubscriptionEvent::Closed { reason });
        }
        for (_, w) in std::mem::take(&mut self.req_replies) {
            let _ = w.send(Err(NetError::Closed));
        }
        drop(wtx);
        let _ = writer.await;
    }

    fn handle_cmd(&mut self, c: Cmd) {
        match c {
            Cmd::Register(reply) => match self.core.register() {
                Ok(()) => self.reg_reply = Some(reply),
                Err(e) => {
                    let _ = reply.send(Err(e.into()));
                }
            },
            Cmd::Unregister(reply) => match self.core.unregister() {
                Ok(()) => {
                    self.unreg_reply = Some(reply);
                    self.end_all(EndReason::Unregistered);
                }
                Err(e) => {
                    let _ = reply.send(Err(e.into()));
                }
            },
            Cmd::Request {
                source,
                priority,
                reply,
            } => {
                if self.subs.contains_key(&source) || self.req_replies.contains_key(&source) {
                    let _ = reply.send(Err(NetError::AlreadySubscribed));
                    return;
                }
                match self.core.request(&source, priority) {
                    Ok(()) => {
                        self.req_replies.insert(source, reply);
                    }
                    Err(e) => {
                        let _ = reply.send(Err(e.into()));
                    }
                }
            }
            Cmd::Disconnect { source, reply } => {
                let r = self.core.disconnect(&source).map_err(NetError::from);
                if r.is_ok() {
                    self.end_sub(&source, EndReason::Disconnected);
                    if let Some(w) = self.req_replies.remove(&source) {
                        let _ = w.send(Err(NetError::Closed));
                    }
                }
                let _ = reply.send(r);
            }
            Cmd::Sources(reply) => {
                let _ = reply.send((self.core.id(), self.core.sources().to_vec()));
            }
            Cmd::Link(reply) => {
                let _ = reply.send(self.core.link_status(self.clock.now()));
            }
            Cmd::Dropped { source, shared } => {
                if self
                    .subs
                    .get(&source)
                    .is_some_and(|s| Arc::ptr_eq(&s.shared, &shared))
                {
                    let _ = self.core.disconnect(&source);
                    self.end_sub(&source, EndReason::Disconnected);
                }
            }
        }
    }

    fn end_sub(&mut self, source: &str, reason: EndReason) {
        if let Some(sub) = self.subs.remove(source) {
            if let Some((_, close)) = sub.data {
                let _ = close.send(());
            }
            sub.shared.push(SubscriptionEvent::Closed { reason });
        }
    }

    fn end_all(&mut self, reason: EndReason) {
        let names: Vec<String> = self.subs.keys().cloned().collect();
        for n in names {
            self.end_sub(&n, reason);
        }
        for (_, w) in std::mem::take(&mut self.req_replies) {
            let _ = w.send(Err(match reason {
                EndReason::ManagerLost => NetError::ManagerLost,
                _ => NetError::Closed,
            }));
        }
    }

    fn close_data(&mut self, source: &str) {
        if let Some(sub) = self.subs.get_mut(source)
            && let Some((_, close)) = sub.data.take()
        {
            let _ = close.send(());
        }
    }

    fn data_end(&mut self, d: DataEnd) {
        let current = self
            .subs
            .get(&d.source)
            .and_then(|s| s.data.as_ref())
            .is_some_and(|(g, _)| *g == d.generation);
        if !current {
            return;
        }
        if let Some(s) = self.subs.get_mut(&d.source) {
            s.data = None;
        }
        match d.why {
            // The request channel is authoritative for revocations and local closes.
            DataClose::Local | DataClose::Revoked(_) => {}
            why => {
                let _ = self.core.disconnect(&d.source);
                self.end_sub(&d.source, EndReason::Data(why));
            }
        }
    }

    fn handle_event(&mut self, e: ClientEvent, dtx: &mpsc::UnboundedSender<DataEnd>) {
        match e {
            ClientEvent::Registered { sources, .. } => {
                if let Some(r) = self.reg_reply.take() {
                    let _ = r.send(Ok(sources));
                }
            }
            ClientEvent::Declined {
                reason,
                retry_with: None,
                ..
            } => {
                if let Some(r) = self.reg_reply.take() {
                    let _ = r.send(Err(NetError::Declined(reason)));
                }
            }
            ClientEvent::Declined { .. } | ClientEvent::Pending { .. } => {}
            ClientEvent::Unregistered => {
                if let Some(r) = self.unreg_reply.take() {
                    let _ = r.send(Ok(()));
                }
            }
            ClientEvent::Granted {
                source,
                address,
                ticket,
            } => self.granted(source, address, ticket, dtx),
            ClientEvent::Denied { source, reason } => {
                if let Some(r) = self.req_replies.remove(&source) {
                    let _ = r.send(Err(NetError::Denied(reason)));
                }
                self.end_sub(&source, EndReason::Denied(reason));
            }
            ClientEvent::Revoked { source, reason } => {
                if reason == RevokeReason::TaskPriority {
                    self.close_data(&source);
                    if let Some(sub) = self.subs.get(&source) {
                        sub.shared.push(SubscriptionEvent::Lost {
                            reason: LossReason::Revoked(reason),
                        });
                    }
                } else {
                    if let Some(r) = self.req_replies.remove(&source) {
                        let _ = r.send(Err(NetError::Revoked(reason)));
                    }
                    self.end_sub(&source, EndReason::Revoked(reason));
                }
            }
            ClientEvent::SourcesChanged { .. } => {}
            ClientEvent::SourceGone { source } => self.close_data(&source),
            ClientEvent::ManagerLost(why) => {
                match why {
                    Some(e) => tracing::warn!(error = %e, "peer client: manager lost"),
                    None => tracing::warn!("peer client: manager lost (no frame in time)"),
                }
                // Before any reply goes: a caller maps `ManagerLost` to this.
                self.note_auth_failure();
                if let Some(r) = self.reg_reply.take() {
                    let _ = r.send(Err(NetError::ManagerLost));
                }
                if let Some(r) = self.unreg_reply.take() {
                    let _ = r.send(Err(NetError::ManagerLost));
                }
                self.end_all(EndReason::ManagerLost);
            }
        }
    }

    fn granted(
        &mut self,
        source: String,
        address: String,
        ticket: Ticket,
        dtx: &mpsc::UnboundedSender<DataEnd>,
    ) {
        let cap = self.dcfg.queue;
        let sub = self.subs.entry(source.clone()).or_insert_with(|| SubRec {
            shared: SubShared::new(cap),
            data: None,
        });
        if let Some(r) = self.req_replies.remove(&source) {
            let s = Subscription {
                source: source.clone(),
                shared: sub.shared.clone(),
                cmd: self.cmd.clone(),
            };
            if r.send(Ok(s)).is_err() {
                // The requester went away: withdraw.
                let _ = self.core.disconnect(&source);
                self.end_sub(&source, EndReason::Disconnected);
                return;
            }
        }
        if sub.data.is_some() {
            // A renewal while streaming: keep the running data session.
            return;
        }
        self.generation = self.generation.wrapping_add(1);
        let generation = self.generation;
        let (ctx, crx) = oneshot::channel();
        sub.data = Some((generation, ctx));
        let mut cfg = self.dcfg.clone();
        cfg.node = random_id();
        cfg.first_counter = unix_micros();
        tokio::spawn(data_session(DataTask {
            address,
            clock: self.clock.clone(),
            key: self.key.clone(),
            cfg,
            client: self.core.id(),
            source,
            ticket,
            sub: sub.shared.clone(),
            generation,
            close: crx,
            done: dtx.clone(),
        }));
    }
}

fn deadline(clock: &SharedClock, at: Option<ima_hal::Instant>) -> tokio::time::Instant {
    let now = tokio::time::Instant::now();
    match at {
        Some(t) => now + t.saturating_duration_since(clock.now()),
        None => now + std::time::Duration::from_secs(3600),
    }
}

struct DataTask {
    address: String,
    clock: SharedClock,
    key: GroupKey,
    cfg: DataConfig,
    client: u64,
    source: String,
    ticket: Ticket,
    sub: Arc<SubShared>,
    generation: u64,
    close: oneshot::Receiver<()>,
    done: mpsc::UnboundedSender<DataEnd>,
}

async fn data_session(mut t: DataTask) {
    let why = run_data(&mut t).await;
    let _ = t.done.send(DataEnd {
        source: t.source.clone(),
        generation: t.generation,
        why,
    });
}

async fn run_data(t: &mut DataTask) -> DataClose {
    let clock = t.clock.clone();
    let window = t
        .cfg
        .heartbeat
        .saturating_mul(t.cfg.missed_heartbeats.max(1));
    let stream = match tokio::time::timeout(window, TcpStream::connect(t.address.as_str())).await {
        Ok(Ok(s)) => s,
        _ => return DataClose::Lost,
    };
    let _ = stream.set_nodelay(true);
    let max_body = t.cfg.max_body;
    let mut s = DataClientSession::new(
        t.cfg.clone(),
        t.key.clone(),
        t.client,
        &t.source,
        t.ticket,
        clock.now(),
    );
    let (mut rd, mut wr) = stream.into_split();
    let mut reader = FrameReader::new(max_body);
    let mut buf = vec![0u8; max_frame(max_body)];
    let mut out = Vec::with_capacity(1024);
    let mut end = DataClose::Lost;
    let mut closing = false;
    loop {
        let now = clock.now();
        // A write outside the select, bounded by the loss window (a manager that reads
        // nothing is lost).
        if !write_batch(&mut wr, &mut buf, &mut out, window, |b| {
            s.poll_transmit(b, now)
        })
        .await
        {
            return DataClose::Lost;
        }
        while let Some(e) = s.poll_event() {
            if let DataEvent::Closed(why) = e {
                end = why;
                closing = true;
            }
        }
        if closing {
            let _ = tokio::time::timeout(window, wr.shutdown()).await;
            return end;
        }
        let sleep = tokio::time::sleep_until(deadline(&clock, s.poll_timeout()));
        tokio::select! {
            biased;
            r = reader.read_from(&mut rd) => match r {
                Ok(0) | Err(_) => return DataClose::Lost,
                Ok(_) => {
                    let now = clock.now();
                    while let Some(f) = reader.next_frame() {
                        s.handle_frame(f, now);
                    }
                    t.sub.push_all(core::iter::from_fn(|| s.pop_sample()).map(|x| {
                        SubscriptionEvent::Sample {
                            seq: x.seq,
                            stamp_us: x.stamp_us,
                            payload: x.payload,
                        }
                    }));
                }
            },
            _ = &mut t.close => s.close(),
            () = sleep => {
                // Input that waited while this task was starved goes in first.
                match reader.try_read_from(&rd) {
                    Ok(Some(0)) | Err(_) => return DataClose::Lost,
                    Ok(Some(_)) => {
                        let now = clock.now();
                        while let Some(f) = reader.next_frame() {
                            s.handle_frame(f, now);
                        }
                        t.sub.push_all(core::iter::from_fn(|| s.pop_sample()).map(|x| {
                            SubscriptionEvent::Sample {
                                seq: x.seq,
                                stamp_us: x.stamp_us,
                                payload: x.payload,
                            }
                        }));
                    }
                    Ok(None) => {}
                }
                s.handle_timeout(clock.now());
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The web console's Peer page showed `lost: Revoked(TaskPriority)` and the runtime's
    /// retry note `subscription closed: Data(Lost)`: words now, for every variant.
    #[test]
    fn why_a_subscription_paused_or_ended_is_said_in_words() {
        use crate::peer::manager::TicketError;
        let lost = LossReason::Revoked(RevokeReason::TaskPriority);
        assert_eq!(
            lost.to_string(),
            "revoked (the source robot's task priority rose above the request's); pending again"
        );
        let ended = [
            (EndReason::ManagerLost, "the manager is lost"),
            (
                EndReason::Data(DataClose::Lost),
                "data session: no frame within the missed-heartbeat window",
            ),
            (
                EndReason::Data(DataClose::Ticket(TicketError::Expired)),
                "data session: ticket refused: the ticket has expired",
            ),
            (
                EndReason::Data(DataClose::Unexpected(0x21)),
                "data session: an unexpected message (type 0x21)",
            ),
            (
                EndReason::Denied(crate::peer::wire::DenyReason::UnknownSource),
                "denied: the manager has no such source",
            ),
            (
                EndReason::Revoked(RevokeReason::Shutdown),
                "revoked: the manager is shutting down",
            ),
        ];
        for (e, words) in ended {
            assert_eq!(e.to_string(), words);
        }
        let e: NetError = crate::peer::client::ClientError::NotRequested.into();
        assert_eq!(e.to_string(), "client: that source was not requested");
        // Every other variant: words, never the Rust name.
        use crate::peer::client::ClientError;
        use crate::peer::manager::CloseReason;
        let texts = [
            EndReason::Disconnected.to_string(),
            EndReason::Unregistered.to_string(),
            EndReason::Data(DataClose::Revoked(RevokeReason::SourceGone)).to_string(),
            EndReason::Data(DataClose::Local).to_string(),
            TicketError::Forged.to_string(),
            TicketError::NotGranted.to_string(),
            TicketError::AlreadyUsed.to_string(),
            ClientError::AlreadyRegistered.to_string(),
            ClientError::NotRegistered.to_string(),
            ClientError::Lost.to_string(),
            ClientError::QueueFull.to_string(),
            CloseReason::Unexpected(0x21).to_string(),
            CloseReason::Lost.to_string(),
            CloseReason::SlowConsumer.to_string(),
        ];
        for t in texts {
            let rusty = t.split(|c: char| !c.is_alphanumeric()).any(|w| {
                w.len() > 1
                    && w.chars().next().is_some_and(char::is_uppercase)
                    && w.chars().skip(1).any(char::is_uppercase)
            });
            assert!(!rusty && !t.contains('{'), "{t}");
        }
    }

    #[test]
    fn pending_interruptions_collapse_into_the_latest() {
        let s = SubShared::new(4);
        let lost = SubscriptionEvent::Lost {
            reason: LossReason::Revoked(RevokeReason::TaskPriority),
        };
        s.push(lost.clone());
        s.push(lost.clone());
        s.push(SubscriptionEvent::Sample {
            seq: 1,
            stamp_us: 0,
            payload: Vec::new(),
        });
        s.push(lost.clone());
        s.push(lost.clone());
        let q: Vec<_> = s.lock().queue.iter().cloned().collect();
        assert_eq!(q.len(), 3, "{q:?}");
        assert_eq!(q.first(), Some(&lost));
        assert_eq!(q.last(), Some(&lost));
    }
}

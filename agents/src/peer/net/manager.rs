//! The manager shell: request-channel listener, data server, source publishers.

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use ima_hal::Instant;
use ima_hal::time::{Clock, SharedClock, TokioClock};
use tokio::io::AsyncWriteExt;
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{OwnedSemaphorePermit, Semaphore, broadcast, mpsc, oneshot};
use tokio::task::{AbortHandle, JoinHandle};

use super::config::{PeerNetConfig, parse_addr};
use super::frames::{FrameReader, max_frame, write_batch, write_frames};
use super::{NetError, random_id, random_key32, unix_micros};
use crate::peer::data::{DataClose, DataConfig, DataEvent, DataServerSession, TicketAuthority};
use crate::peer::manager::{
    ClientStatus, Decision, LinkStatus, ManagerConfig, ManagerEvent, ManagerStats, Outcome, PeerId,
    PeerManager, SelfAgent, TicketError,
};
use crate::peer::wire::{
    GroupKey, HEADER_LEN, MAC_LEN, Msg, RejectCounts, RevokeReason, SourceInfo, Ticket, Verifier,
};

/// One published sample: source time stamp (µs) and payload.
type SampleItem = (u64, Arc<[u8]>);

/// Frames from all client sessions waiting for the manager task.
const IO_QUEUE: usize = 4096;
/// Frames of one client session in the shared queue at most: one peer cannot fill the
/// queue that every session shares (each frame carries one of the session's credits back
/// to it once the manager task has handled it).
const SESSION_CREDITS: usize = 4;
/// Events kept for slow `events()` subscribers.
const EVENT_QUEUE: usize = 1024;
/// Per-sample overhead of a Sample body: seq 8, stamp 8, length 2.
const SAMPLE_OVERHEAD: usize = 18;
/// Body room of the data server's output buffer before a ticket was accepted (control
/// frames only).
const PRE_STREAM_BODY: usize = 1024;

/// What the manager shell reports on [`ManagerHandle::events`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ManagerNetEvent {
    /// An event of the core (registrations, decisions, source changes, closed sessions).
    Core(ManagerEvent),
    /// A client session was accepted.
    SessionOpened {
        /// Session number.
        peer: PeerId,
        /// Remote address.
        addr: SocketAddr,
    },
    /// A client session ended (closed by the remote, or by the shell because its outgoing
    /// queue overflowed).
    SessionEnded {
        /// Session number.
        peer: PeerId,
        /// Whether the shell closed it as a slow consumer.
        slow: bool,
    },
    /// A data session was opened with a valid ticket.
    DataOpened {
        /// Client ID.
        client: u64,
        /// Source name.
        source: String,
    },
    /// A data session ended.
    DataClosed {
        /// Source name, if the session got that far.
        source: Option<String>,
        /// Why.
        reason: DataClose,
    },
}

/// Counters and state of a running manager.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct ManagerNetStats {
    /// The core's counters (request-channel rejections by class, lost sessions…).
    pub core: ManagerStats,
    /// Open request-channel sessions.
    pub sessions: usize,
    /// Registered clients.
    pub clients: usize,
    /// Open data sessions.
    pub data_sessions: usize,
    /// Data-session frames rejected, by class.
    pub data_rejects: RejectCounts,
    /// Data sessions refused for a bad ticket.
    pub data_bad_tickets: u64,
    /// Sessions closed by the shell because they could not keep up.
    pub slow_closed: u64,
    /// Samples data sessions missed because they fell behind their source's queue (the
    /// oldest are dropped: latest-value semantics).
    pub lagged_samples: u64,
    /// The task priority in force.
    pub task_priority: u8,
    /// The competency list.
    pub sources: Vec<SourceInfo>,
    /// Health of every open request-channel session (heartbeats, last seen), with the
    /// remote address.
    pub links: Vec<SessionLink>,
}

/// One request-channel session's health ([`ManagerNetStats::links`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SessionLink {
    /// The remote address.
    pub addr: SocketAddr,
    /// Heartbeats, frames, last seen.
    pub link: LinkStatus,
}

struct SourceEntry {
    id: u64,
    info: SourceInfo,
    tx: broadcast::Sender<SampleItem>,
}

#[derive(Default)]
struct Shared {
    sources: Mutex<BTreeMap<String, SourceEntry>>,
    next_id: Mutex<u64>,
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

/// The Self Agent the core sees: the caller's agent plus the published sources, and a task
/// priority override set through [`ManagerHandle::set_task_priority`].
struct ShellAgent<A> {
    inner: A,
    shared: Arc<Shared>,
    task_override: Option<u8>,
}

impl<A: SelfAgent> SelfAgent for ShellAgent<A> {
    fn task_priority(&mut self, now: Instant) -> u8 {
        let own = self.inner.task_priority(now);
        self.task_override.unwrap_or(own)
    }
    fn sources(&mut self, now: Instant) -> Vec<SourceInfo> {
        let mut v = self.inner.sources(now);
        v.extend(lock(&self.shared.sources).values().map(|e| e.info.clone()));
        v
    }
    fn notify(&mut self, decision: &Decision) {
        self.inner.notify(decision);
    }
}

struct DataGrant {
    id: u64,
    samples: Option<broadcast::Receiver<SampleItem>>,
    revoke: oneshot::Receiver<RevokeReason>,
}

enum Ctl {
    Redeem {
        client: u64,
        source: String,
        ticket: Ticket,
        reply: oneshot::Sender<Result<DataGrant, TicketError>>,
    },
    DataEnded {
        id: Option<u64>,
        reason: DataClose,
    },
    Rescan,
    /// A data session fell behind its source by this many samples.
    Lagged(u64),
    SetTaskPriority(Option<u8>),
    Stats(oneshot::Sender<ManagerNetStats>),
    Status(oneshot::Sender<Vec<ClientStatus>>),
    Snapshot(oneshot::Sender<(ManagerNetStats, Vec<ClientStatus>)>),
    /// Answered with the writer tasks of the closed sessions, to be awaited.
    Shutdown(oneshot::Sender<Vec<JoinHandle<()>>>),
}

/// Data-session tasks, kept so that shutdown can await their last frames.
type DataTasks = Arc<Mutex<Vec<JoinHandle<()>>>>;

enum Io {
    Accepted {
        peer: PeerId,
        addr: SocketAddr,
        tx: mpsc::Sender<Vec<u8>>,
        reader: AbortHandle,
        writer: JoinHandle<()>,
        /// Data address for this session's grants (see `SessionLimits::advertise_port`).
        data_address: Option<String>,
    },
    Frame {
        peer: PeerId,
        bytes: Vec<u8>,
        /// Released when the frame has been handled.
        _credit: OwnedSemaphorePermit,
    },
    Closed {
        peer: PeerId,
    },
}

/// Publishes one source's samples to every data session streaming it. Dropping it (or
/// [`SourcePublisher::remove`]) removes the source: clients are told at once
/// (`SourcesChanged`, grants revoked with `SourceGone`).
#[derive(Debug)]
pub struct SourcePublisher {
    id: u64,
    name: String,
    tx: broadcast::Sender<SampleItem>,
    shared: Arc<SharedRef>,
    ctl: mpsc::UnboundedSender<Ctl>,
    max_payload: usize,
}

/// Opaque wrapper so `SourcePublisher` can derive `Debug`.
struct SharedRef(Arc<Shared>);

impl core::fmt::Debug for SharedRef {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("Shared(..)")
    }
}

impl SourcePublisher {
    /// The source name.
    #[must_use]
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Largest payload accepted (the peers' body-size limit minus the sample header).
    #[must_use]
    pub fn max_payload(&self) -> usize {
        self.max_payload
    }

    /// Publishes a sample measured at `stamp_us` (µs on this robot's clock). Never blocks:
    /// every data session keeps the latest samples and drops the oldest when it cannot keep
    /// up. Returns the number of data sessions it was queued for.
    ///
    /// # Errors
    /// [`NetError::Config`] when the payload is above [`SourcePublisher::max_payload`].
    pub fn publish(&self, stamp_us: u64, payload: &[u8]) -> Result<usize, NetError> {
        if payload.len() > self.max_payload {
            return Err(NetError::Config(format!(
                "payload of {} bytes above the limit of {}",
                payload.len(),
                self.max_payload
            )));
        }
        Ok(self.tx.send((stamp_us, Arc::from(payload))).unwrap_or(0))
    }

    /// Data sessions streaming this source now.
    #[must_use]
    pub fn subscribers(&self) -> usize {
        self.tx.receiver_count()
    }

    /// Removes the source (same as dropping the publisher).
    pub fn remove(self) {}
}

impl Drop for SourcePublisher {
    fn drop(&mut self) {
        let mut map = lock(&self.shared.0.sources);
        if map.get(&self.name).is_some_and(|e| e.id == self.id) {
            map.remove(&self.name);
        }
        drop(map);
        let _ = self.ctl.send(Ctl::Rescan);
    }
}

/// Handle of a running manager (request-channel listener, data server, manager task).
/// Dropping it shuts the manager down abruptly (tasks aborted, sockets closed); call
/// [`ManagerHandle::shutdown`] for an orderly end with `Revoked(Shutdown)` sent first.
#[derive(Debug)]
pub struct ManagerHandle {
    local_addr: SocketAddr,
    data_addr: SocketAddr,
    ctl: mpsc::UnboundedSender<Ctl>,
    events: broadcast::Sender<ManagerNetEvent>,
    shared: Arc<SharedRef>,
    tasks: Vec<JoinHandle<()>>,
    data_tasks: DataTasks,
    flush_limit: Duration,
    data_queue: usize,
    max_payload: usize,
    max_body: usize,
}

impl ManagerHandle {
    /// Address of the request-channel listener.
    #[must_use]
    pub fn local_addr(&self) -> SocketAddr {
        self.local_addr
    }

    /// Address of the data server.
    #[must_use]
    pub fn data_addr(&self) -> SocketAddr {
        self.data_addr
    }

    /// Adds (or replaces) a source and returns its publisher. Registered clients are told
    /// at once (`SourcesChanged`).
    ///
    /// # Errors
    /// [`NetError::Config`] when the name is empty, the name or kind is longer than 255
    /// bytes, the competency list would hold more than 255 sources, or its encoding would
    /// not fit in one frame of `max_body` bytes (clients could not register).
    pub fn publisher(&self, info: SourceInfo) -> Result<SourcePublisher, NetError> {
        if info.name.is_empty() || info.name.len() > 255 || info.kind.len() > 255 {
            return Err(NetError::Config(format!(
                "source name (1..=255 bytes) or kind (0..=255 bytes) out of range: {:?}/{:?}",
                info.name.len(),
                info.kind.len()
            )));
        }
        {
            let map = lock(&self.shared.0.sources);
            let others = map.values().filter(|e| e.info.name != info.name);
            let count = others.clone().count().saturating_add(1);
            // Registered body: client 8, count 1, per source: name 1+n, kind 1+k, 2, 4.
            let size = others
                .map(|e| &e.info)
                .chain(core::iter::once(&info))
                .map(|s| 8 + s.name.len() + s.kind.len())
                .fold(9usize, usize::saturating_add);
            if count > 255 || size > self.max_body {
                return Err(NetError::Config(format!(
                    "competency list full: {count} sources, {size} bytes encoded (limits 255 \
                     and max_body {})",
                    self.max_body
                )));
            }
        }
        let id = {
            let mut n = lock(&self.shared.0.next_id);
            *n = n.wrapping_add(1);
            *n
        };
        let (tx, _) = broadcast::channel(self.data_queue.max(1));
        lock(&self.shared.0.sources).insert(
            info.name.clone(),
            SourceEntry {
                id,
                info: info.clone(),
                tx: tx.clone(),
            },
        );
        let _ = self.ctl.send(Ctl::Rescan);
        Ok(SourcePublisher {
            id,
            name: info.name,
            tx,
            shared: self.shared.clone(),
            ctl: self.ctl.clone(),
            max_payload: self.max_payload,
        })
    }

    /// Overrides the Self Agent's task priority (`None`: ask the Self Agent again). Grants
    /// below it are revoked; pending requests at or above it are granted.
    pub fn set_task_priority(&self, priority: Option<u8>) {
        let _ = self.ctl.send(Ctl::SetTaskPriority(priority));
    }

    /// A stream of events (a slow subscriber loses the oldest; see
    /// [`broadcast::Receiver`]).
    #[must_use]
    pub fn events(&self) -> broadcast::Receiver<ManagerNetEvent> {
        self.events.subscribe()
    }

    /// Counters and state.
    ///
    /// # Errors
    /// [`NetError::Closed`] when the manager has stopped.
    pub async fn stats(&self) -> Result<ManagerNetStats, NetError> {
        let (tx, rx) = oneshot::channel();
        self.ctl
            .send(Ctl::Stats(tx))
            .map_err(|_| NetError::Closed)?;
        rx.await.map_err(|_| NetError::Closed)
    }

    /// Status of every registered client.
    ///
    /// # Errors
    /// [`NetError::Closed`] when the manager has stopped.
    pub async fn status(&self) -> Result<Vec<ClientStatus>, NetError> {
        let (tx, rx) = oneshot::channel();
        self.ctl
            .send(Ctl::Status(tx))
            .map_err(|_| NetError::Closed)?;
        rx.await.map_err(|_| NetError::Closed)
    }

    /// [`stats`](Self::stats) and [`status`](Self::status) taken together, in one round
    /// trip to the manager's task (a live console or a recording asks several times a
    /// second).
    ///
    /// # Errors
    /// [`NetError::Closed`] when the manager has stopped.
    pub async fn snapshot(&self) -> Result<(ManagerNetStats, Vec<ClientStatus>), NetError> {
        let (tx, rx) = oneshot::channel();
        self.ctl
            .send(Ctl::Snapshot(tx))
            .map_err(|_| NetError::Closed)?;
        rx.await.map_err(|_| NetError::Closed)
    }

    /// Orderly shutdown: every grant is revoked (`Shutdown`) on the request channel and
    /// on every data session, and this returns only once those frames are written and the
    /// sockets closed (or after the loss window, at least 1 s, for a peer that does not
    /// read); then every task is stopped.
    pub async fn shutdown(mut self) {
        let limit = self.flush_limit;
        let (tx, rx) = oneshot::channel();
        let mut writers = Vec::new();
        if self.ctl.send(Ctl::Shutdown(tx)).is_ok()
            && let Ok(Ok(w)) = tokio::time::timeout(limit, rx).await
        {
            writers = w;
        }
        // The accept loops stop taking new sessions.
        for t in self.tasks.drain(..) {
            t.abort();
        }
        let data: Vec<JoinHandle<()>> = std::mem::take(&mut *lock(&self.data_tasks));
        let mut set = tokio::task::JoinSet::new();
        let mut aborts = Vec::new();
        for h in writers.into_iter().chain(data) {
            aborts.push(h.abort_handle());
            set.spawn(async move {
                let _ = h.await;
            });
        }
        let _ =
            tokio::time::timeout(limit, async { while set.join_next().await.is_some() {} }).await;
        for a in aborts {
            a.abort();
        }
    }

    /// Abrupt stop, as if the process died: every task is aborted and every socket closed
    /// without a word to the clients.
    pub fn abort(mut self) {
        self.stop();
    }

    fn stop(&mut self) {
        for t in self.tasks.drain(..) {
            t.abort();
        }
        for t in lock(&self.data_tasks).drain(..) {
            t.abort();
        }
    }
}

impl Drop for ManagerHandle {
    fn drop(&mut self) {
        self.stop();
    }
}

fn advertised(cfg: &PeerNetConfig, bound: SocketAddr) -> String {
    if let Some(a) = &cfg.manager.data_advertise {
        return a.clone();
    }
    let mut a = bound;
    if a.ip().is_unspecified() {
        a.set_ip(std::net::Ipv4Addr::LOCALHOST.into());
    }
    a.to_string()
}

/// Starts a manager: binds the request-channel listener and the data server, and spawns the
/// manager task owning a [`PeerManager`] with `agent` as its Self Agent (wrapped so that
/// published sources and [`ManagerHandle::set_task_priority`] are seen). Must be called
/// inside a tokio runtime.
///
/// # Errors
/// [`NetError::Config`] (bad address), [`NetError::Io`] (bind failed, no OS randomness).
pub async fn spawn_manager<A: SelfAgent + Send + 'static>(
    cfg: &PeerNetConfig,
    key: GroupKey,
    agent: A,
) -> Result<ManagerHandle, NetError> {
    spawn_manager_with_clock(cfg, key, agent, TokioClock::shared()).await
}

/// [`spawn_manager`] on the process's one clock: the manager's and its data sessions'
/// timers and stamps run on `clock` (a robot's runtime passes the clock its devices stamp
/// on; [`spawn_manager`] makes a [`TokioClock`] of its own).
///
/// # Errors
/// As [`spawn_manager`].
pub async fn spawn_manager_with_clock<A: SelfAgent + Send + 'static>(
    cfg: &PeerNetConfig,
    key: GroupKey,
    agent: A,
    clock: SharedClock,
) -> Result<ManagerHandle, NetError> {
    cfg.validate()?;
    let listen = parse_addr(&cfg.manager.listen, "manager.listen").await?;
    let data_listen = parse_addr(&cfg.manager.data_listen, "manager.data_listen").await?;
    let listener = TcpListener::bind(listen)
        .await
        .map_err(super::bind_error("the manager's request channel", listen))?;
    let data_listener = TcpListener::bind(data_listen)
        .await
        .map_err(super::bind_error("the manager's data server", data_listen))?;
    let local_addr = listener.local_addr()?;
    let data_addr = data_listener.local_addr()?;
    let hb = cfg.heartbeat();
    let mut mcfg = ManagerConfig::new(&cfg.robot, random_id(), &advertised(cfg, data_addr));
    mcfg.first_counter = unix_micros();
    mcfg.heartbeat = hb;
    mcfg.missed_heartbeats = cfg.missed_heartbeats;
    mcfg.rescan = Duration::from_millis(cfg.manager.rescan_ms.max(1));
    mcfg.ticket_lifetime = Duration::from_millis(cfg.manager.ticket_lifetime_ms.max(1));
    mcfg.robot_priorities = cfg
        .manager
        .robot_priorities
        .iter()
        .map(|(r, p)| (r.clone(), *p))
        .collect();
    mcfg.unknown_robot_priority = cfg.manager.unknown_robot_priority;
    mcfg.max_clients = cfg.manager.max_clients;
    mcfg.max_body = cfg.max_body;
    let shared = Arc::new(Shared::default());
    let agent = ShellAgent {
        inner: agent,
        shared: shared.clone(),
        task_override: None,
    };
    let core = PeerManager::new(mcfg, key.clone(), random_key32()?, agent, clock.now());
    let (ctl_tx, ctl_rx) = mpsc::unbounded_channel();
    let (io_tx, io_rx) = mpsc::channel(IO_QUEUE);
    let (ev_tx, _) = broadcast::channel(EVENT_QUEUE);
    let max_body = cfg.max_body;
    let data_tasks: DataTasks = Arc::default();
    let session_queue = cfg.manager.session_queue.max(1);
    let max_conns = cfg.manager.max_connections.max(1);
    let window = cfg.loss_window();
    let mut dcfg = DataConfig::new(0);
    dcfg.heartbeat = hb;
    dcfg.missed_heartbeats = cfg.missed_heartbeats;
    dcfg.queue = cfg.manager.data_queue.max(1);
    dcfg.max_body = max_body;

    let task = ManagerTask {
        core,
        clock: clock.clone(),
        sessions: BTreeMap::new(),
        data: BTreeMap::new(),
        next_data: 0,
        events: ev_tx.clone(),
        shared: shared.clone(),
        data_rejects: RejectCounts::default(),
        data_bad_tickets: 0,
        slow_closed: 0,
        lagged_samples: 0,
        out: vec![0u8; HEADER_LEN + usize::from(u16::MAX) + MAC_LEN],
        skew_us: cfg.max_clock_skew_ms.saturating_mul(1000),
    };
    let tasks = vec![
        tokio::spawn(task.run(ctl_rx, io_rx)),
        tokio::spawn(accept_sessions(
            listener,
            io_tx,
            SessionLimits {
                advertise_port: (cfg.manager.data_advertise.is_none()
                    && data_addr.ip().is_unspecified())
                .then_some(data_addr.port()),
                queue: session_queue,
                max_body,
                window,
                conns: Arc::new(Semaphore::new(max_conns)),
            },
        )),
        tokio::spawn(accept_data(
            data_listener,
            ctl_tx.clone(),
            ev_tx.clone(),
            key,
            dcfg,
            data_tasks.clone(),
            Arc::new(Semaphore::new(max_conns)),
            clock,
        )),
    ];
    Ok(ManagerHandle {
        local_addr,
        data_addr,
        ctl: ctl_tx,
        events: ev_tx,
        shared: Arc::new(SharedRef(shared)),
        tasks,
        data_tasks,
        flush_limit: cfg.loss_window().max(Duration::from_secs(1)),
        data_queue: cfg.manager.data_queue,
        max_payload: max_body.saturating_sub(SAMPLE_OVERHEAD),
        max_body,
    })
}

struct SessionRec {
    addr: SocketAddr,
    tx: mpsc::Sender<Vec<u8>>,
    reader: AbortHandle,
    writer: JoinHandle<()>,
}

struct ManagerTask<A: SelfAgent> {
    core: PeerManager<ShellAgent<A>>,
    clock: SharedClock,
    sessions: BTreeMap<PeerId, SessionRec>,
    data: BTreeMap<u64, (u64, String, oneshot::Sender<RevokeReason>)>,
    next_data: u64,
    events: broadcast::Sender<ManagerNetEvent>,
    shared: Arc<Shared>,
    data_rejects: RejectCounts,
    data_bad_tickets: u64,
    slow_closed: u64,
    lagged_samples: u64,
    out: Vec<u8>,
    skew_us: u64,
}

fn deadline(clock: &SharedClock, at: Option<Instant>) -> tokio::time::Instant {
    let now = tokio::time::Instant::now();
    match at {
        Some(t) => now + t.saturating_duration_since(clock.now()),
        None => now + Duration::from_secs(3600),
    }
}

impl<A: SelfAgent> ManagerTask<A> {
    async fn run(mut self, mut ctl: mpsc::UnboundedReceiver<Ctl>, mut io: mpsc::Receiver<Io>) {
        loop {
            let sleep = tokio::time::sleep_until(deadline(&self.clock, self.core.poll_timeout()));
            // Biased: control (low volume, so it cannot starve the rest), then client
            // input, then timers; and the input that queued up is taken before a timeout is
            // handled, so that a starved task does not declare a live client lost.
            tokio::select! {
                biased;
                c = ctl.recv() => match c {
                    Some(Ctl::Shutdown(done)) => {
                        let writers = self.shutdown();
                        let _ = done.send(writers);
                        return;
                    }
                    Some(c) => self.handle_ctl(c),
                    None => return,
                },
                Some(m) = io.recv() => self.handle_io(m),
                () = sleep => {
                    while let Ok(m) = io.try_recv() {
                        self.handle_io(m);
                    }
                    let now = self.clock.now();
                    self.core.handle_timeout(now);
                }
            }
            self.flush();
        }
    }

    fn handle_ctl(&mut self, c: Ctl) {
        let now = self.clock.now();
        match c {
            Ctl::Redeem {
                client,
                source,
                ticket,
                reply,
            } => {
                let r = self.core.redeem_ticket(client, &source, &ticket, now);
                let r = r.map(|()| {
                    self.next_data = self.next_data.wrapping_add(1);
                    let id = self.next_data;
                    let (rtx, rrx) = oneshot::channel();
                    self.data.insert(id, (client, source.clone(), rtx));
                    let samples = lock(&self.shared.sources)
                        .get(&source)
                        .map(|e| e.tx.subscribe());
                    DataGrant {
                        id,
                        samples,
                        revoke: rrx,
                    }
                });
                if r.is_err() {
                    self.data_bad_tickets = self.data_bad_tickets.saturating_add(1);
                }
                let _ = reply.send(r);
            }
            Ctl::DataEnded { id, reason } => {
                if let Some(id) = id {
                    self.data.remove(&id);
                }
                if let DataClose::Wire(e) = reason {
                    tracing::warn!(error = %e, "peer data server: session closed on a bad frame");
                    self.data_rejects.count(e);
                }
            }
            Ctl::Rescan => self.core.rescan(now),
            Ctl::Lagged(n) => self.lagged_samples = self.lagged_samples.saturating_add(n),
            Ctl::SetTaskPriority(p) => {
                self.core.agent_mut().task_override = p;
                self.core.handle_timeout(now);
            }
            Ctl::Stats(reply) => {
                let _ = reply.send(self.stats());
            }
            Ctl::Status(reply) => {
                let _ = reply.send(self.core.status());
            }
            Ctl::Snapshot(reply) => {
                let _ = reply.send((self.stats(), self.core.status()));
            }
            Ctl::Shutdown(_) => {}
        }
    }

    fn stats(&self) -> ManagerNetStats {
        ManagerNetStats {
            core: self.core.stats(),
            sessions: self.core.session_count(),
            clients: self.core.status().len(),
            data_sessions: self.data.len(),
            data_rejects: self.data_rejects,
            data_bad_tickets: self.data_bad_tickets,
            slow_closed: self.slow_closed,
            lagged_samples: self.lagged_samples,
            task_priority: self.core.task_priority(),
            sources: self.core.sources().to_vec(),
            links: self
                .core
                .links(self.clock.now())
                .into_iter()
                .filter_map(|link| {
                    self.sessions
                        .get(&link.peer)
                        .map(|s| SessionLink { addr: s.addr, link })
                })
                .collect(),
        }
    }

    fn handle_io(&mut self, m: Io) {
        let now = self.clock.now();
        match m {
            Io::Accepted {
                peer,
                addr,
                tx,
                reader,
                writer,
                data_address,
            } => {
                self.sessions.insert(
                    peer,
                    SessionRec {
                        addr,
                        tx,
                        reader,
                        writer,
                    },
                );
                self.core.connect(peer, now);
                if let Some(a) = data_address {
                    self.core.set_data_address(peer, a);
                }
                let _ = self
                    .events
                    .send(ManagerNetEvent::SessionOpened { peer, addr });
            }
            Io::Frame { peer, bytes, .. } => {
                let window = self.skew_window();
                self.core.set_first_counter_window(window);
                self.core.handle_frame(peer, &bytes, now);
            }
            Io::Closed { peer } => {
                if self.sessions.remove(&peer).is_some() {
                    self.core.disconnect(peer, now);
                    let _ = self
                        .events
                        .send(ManagerNetEvent::SessionEnded { peer, slow: false });
                }
            }
        }
    }

    /// Closes a session; returns its writer task, which flushes what is queued and then
    /// closes the socket (dropping the sender ends it).
    /// `now ± skew` in UNIX µs for the first counter of an unknown client.
    fn skew_window(&self) -> Option<(u64, u64)> {
        (self.skew_us > 0).then(|| {
            let now = unix_micros();
            (
                now.saturating_sub(self.skew_us),
                now.saturating_add(self.skew_us),
            )
        })
    }

    fn close_session(&mut self, peer: PeerId) -> Option<JoinHandle<()>> {
        self.sessions.remove(&peer).map(|s| {
            s.reader.abort();
            s.writer
        })
    }

    fn flush(&mut self) {
        loop {
            let mut progressed = false;
            let mut slow = Vec::new();
            while let Some((peer, n)) = self.core.poll_transmit(&mut self.out) {
                progressed = true;
                if let (Some(s), Some(frame)) = (self.sessions.get(&peer), self.out.get(..n))
                    && s.tx.try_send(frame.to_vec()).is_err()
                {
                    slow.push(peer);
                }
            }
            for peer in slow {
                if self.sessions.contains_key(&peer) {
                    let _ = self.close_session(peer);
                    self.slow_closed = self.slow_closed.saturating_add(1);
                    self.core.disconnect(peer, self.clock.now());
                    let _ = self
                        .events
                        .send(ManagerNetEvent::SessionEnded { peer, slow: true });
                }
            }
            while let Some(e) = self.core.poll_event() {
                progressed = true;
                match &e {
                    ManagerEvent::ClosePeer {
                        peer,
                        reason,
                        clients,
                    } => {
                        tracing::warn!(peer, %reason, ?clients, "peer manager: session closed");
                        let _ = self.close_session(*peer);
                    }
                    ManagerEvent::Decision(d) => {
                        let reason = match d.outcome {
                            Outcome::Revoked(r) => Some(r),
                            Outcome::Withdrawn => Some(RevokeReason::SourceGone),
                            _ => None,
                        };
                        if let Some(r) = reason {
                            self.revoke_data(d.client, &d.source, r);
                        }
                    }
                    _ => {}
                }
                let _ = self.events.send(ManagerNetEvent::Core(e));
            }
            if !progressed {
                break;
            }
        }
    }

    fn revoke_data(&mut self, client: u64, source: &str, reason: RevokeReason) {
        let ids: Vec<u64> = self
            .data
            .iter()
            .filter(|(_, (c, s, _))| *c == client && s == source)
            .map(|(id, _)| *id)
            .collect();
        for id in ids {
            if let Some((_, _, tx)) = self.data.remove(&id) {
                let _ = tx.send(reason);
            }
        }
    }

    /// Revokes everything (`Shutdown`), queues the frames and closes every session;
    /// returns the writer tasks still flushing.
    fn shutdown(&mut self) -> Vec<JoinHandle<()>> {
        let now = self.clock.now();
        self.core.shutdown(now);
        self.flush();
        for (_, (_, _, tx)) in std::mem::take(&mut self.data) {
            let _ = tx.send(RevokeReason::Shutdown);
        }
        let peers: Vec<PeerId> = self.sessions.keys().copied().collect();
        peers
            .into_iter()
            .filter_map(|p| self.close_session(p))
            .collect()
    }
}

/// Limits of the request-channel sessions.
struct SessionLimits {
    /// Data-server port, when grants must carry the local IP each client reached (no
    /// `data_advertise` and the data server bound to an unspecified address).
    advertise_port: Option<u16>,
    queue: usize,
    max_body: usize,
    window: Duration,
    conns: Arc<Semaphore>,
}

async fn accept_sessions(listener: TcpListener, io: mpsc::Sender<Io>, lim: SessionLimits) {
    let mut next: PeerId = 0;
    loop {
        // At most `max_connections` sessions: the next accept waits for a permit.
        let Ok(permit) = lim.conns.clone().acquire_owned().await else {
            return;
        };
        let (stream, addr) = match listener.accept().await {
            Ok(s) => s,
            Err(e) => {
                tracing::warn!("peer manager: accept failed: {e}");
                tokio::time::sleep(Duration::from_millis(20)).await;
                continue;
            }
        };
        let _ = stream.set_nodelay(true);
        // On a LAN the data server bound to 0.0.0.0 is reached at the IP this client
        // reached us on.
        let data_address = lim.advertise_port.and_then(|port| {
            let local = stream.local_addr().ok()?;
            (!local.ip().is_unspecified()).then(|| SocketAddr::new(local.ip(), port).to_string())
        });
        next = next.wrapping_add(1);
        let peer = next;
        let (mut rd, wr) = stream.into_split();
        let (tx, rx) = mpsc::channel(lim.queue);
        let writer = tokio::spawn(write_frames(wr, rx, lim.window));
        let io2 = io.clone();
        let max_body = lim.max_body;
        // The reader starts once the core knows the session: its first frame (a Register)
        // queued before `Accepted` was dropped as a stranger's, and the client waited out its
        // call timeout (seen with 200 clients registering at once on a loaded machine).
        let (go, known) = oneshot::channel::<()>();
        let reader = tokio::spawn(async move {
            // Held as long as the session's reader runs (dropped when it ends or is aborted).
            let _permit = permit;
            if known.await.is_err() {
                return;
            }
            let credits = Arc::new(Semaphore::new(SESSION_CREDITS));
            let mut fr = FrameReader::new(max_body);
            loop {
                match fr.read_from(&mut rd).await {
                    Ok(0) | Err(_) => break,
                    Ok(_) => {
                        while let Some(f) = fr.next_frame() {
                            let bytes = f.to_vec();
                            let Ok(credit) = credits.clone().acquire_owned().await else {
                                return;
                            };
                            let frame = Io::Frame {
                                peer,
                                bytes,
                                _credit: credit,
                            };
                            if io2.send(frame).await.is_err() {
                                return;
                            }
                        }
                    }
                }
            }
            let _ = io2.send(Io::Closed { peer }).await;
        });
        let accepted = Io::Accepted {
            peer,
            addr,
            tx,
            reader: reader.abort_handle(),
            writer,
            data_address,
        };
        if io.send(accepted).await.is_err() {
            reader.abort();
            return;
        }
        let _ = go.send(());
    }
}

// The data server's parts, each handed on to every session it accepts.
#[allow(clippy::too_many_arguments)]
async fn accept_data(
    listener: TcpListener,
    ctl: mpsc::UnboundedSender<Ctl>,
    events: broadcast::Sender<ManagerNetEvent>,
    key: GroupKey,
    dcfg: DataConfig,
    tasks: DataTasks,
    conns: Arc<Semaphore>,
    clock: SharedClock,
) {
    loop {
        // At most `max_connections` data sessions: the next accept waits for a permit.
        let Ok(permit) = conns.clone().acquire_owned().await else {
            return;
        };
        let stream = match listener.accept().await {
            Ok((s, _)) => s,
            Err(e) => {
                tracing::warn!("peer data server: accept failed: {e}");
                tokio::time::sleep(Duration::from_millis(20)).await;
                continue;
            }
        };
        let _ = stream.set_nodelay(true);
        let mut cfg = dcfg.clone();
        cfg.node = random_id();
        cfg.first_counter = unix_micros();
        let (ctl, events, key, clock) = (ctl.clone(), events.clone(), key.clone(), clock.clone());
        let h = tokio::spawn(async move {
            let _permit = permit;
            serve_data(stream, ctl, events, key, cfg, clock).await;
        });
        let mut t = lock(&tasks);
        t.retain(|h| !h.is_finished());
        t.push(h);
    }
}

/// A ticket decision fetched from the manager task before the core asks for it.
struct Prefetched(Option<Result<(), TicketError>>);

impl TicketAuthority for Prefetched {
    fn redeem(
        &mut self,
        _client: u64,
        _source: &str,
        _ticket: &Ticket,
        _now: Instant,
    ) -> Result<(), TicketError> {
        self.0.take().unwrap_or(Err(TicketError::NotGranted))
    }
}

async fn recv_sample(
    rx: &mut Option<broadcast::Receiver<SampleItem>>,
) -> Result<SampleItem, broadcast::error::RecvError> {
    match rx {
        Some(r) => r.recv().await,
        None => std::future::pending().await,
    }
}

async fn recv_revoke(rx: &mut Option<oneshot::Receiver<RevokeReason>>) -> Option<RevokeReason> {
    match rx {
        Some(r) => {
            let v = r.await.ok();
            if v.is_none() {
                // The manager task is gone: treat as shutdown.
                return Some(RevokeReason::Shutdown);
            }
            v
        }
        None => std::future::pending().await,
    }
}

async fn serve_data(
    stream: TcpStream,
    ctl: mpsc::UnboundedSender<Ctl>,
    events: broadcast::Sender<ManagerNetEvent>,
    key: GroupKey,
    cfg: DataConfig,
    clock: SharedClock,
) {
    let max_body = cfg.max_body;
    let window = cfg.heartbeat.saturating_mul(cfg.missed_heartbeats.max(1));
    let mut s = DataServerSession::new(cfg, key.clone(), clock.now());
    let (mut rd, mut wr) = stream.into_split();
    let mut reader = FrameReader::new(max_body);
    let mut samples: Option<broadcast::Receiver<SampleItem>> = None;
    let mut revoke: Option<oneshot::Receiver<RevokeReason>> = None;
    let mut id = None;
    let mut source: Option<String> = None;
    // Small buffers until a ticket was accepted (control frames are small): a stranger's
    // connection costs little memory.
    let mut buf = vec![0u8; max_frame(PRE_STREAM_BODY)];
    let mut out: Vec<u8> = Vec::new();
    let mut end = DataClose::Lost;
    'run: loop {
        while let Some(ev) = s.poll_event() {
            match ev {
                DataEvent::Opened {
                    client,
                    source: src,
                } => {
                    source = Some(src.clone());
                    let _ = events.send(ManagerNetEvent::DataOpened {
                        client,
                        source: src,
                    });
                }
                DataEvent::Closed(why) => end = why,
            }
        }
        if s.is_streaming() && buf.len() < max_frame(usize::from(u16::MAX)) {
            buf.resize(max_frame(usize::from(u16::MAX)), 0);
        }
        let now = clock.now();
        // A write outside the select, bounded by the loss window (a client that reads
        // nothing is lost, and this task does not hang on it).
        if !write_batch(&mut wr, &mut buf, &mut out, window, |b| {
            s.poll_transmit(b, now)
        })
        .await
        {
            end = DataClose::Lost;
            break;
        }
        if s.is_closed() {
            if out.is_empty() {
                break;
            }
            continue;
        }
        let sleep = tokio::time::sleep_until(deadline(&clock, s.poll_timeout()));
        tokio::select! {
            biased;
            r = reader.read_from(&mut rd) => {
                match r {
                    Ok(0) | Err(_) => {
                        end = DataClose::Lost;
                        break 'run;
                    }
                    Ok(_) => {}
                }
                while let Some(f) = reader.next_frame() {
                    let f = f.to_vec();
                    let mut auth = Prefetched(None);
                    if !s.is_streaming() {
                        let probe = Verifier::with_limits(key.clone(), max_body, 1).open(&f);
                        if let Ok(o) = probe
                            && let Msg::OpenData { client, source, ticket } = o.msg
                        {
                            let (tx, rx) = oneshot::channel();
                            let _ = ctl.send(Ctl::Redeem { client, source, ticket, reply: tx });
                            auth.0 = Some(match rx.await {
                                Ok(Ok(g)) => {
                                    id = Some(g.id);
                                    samples = g.samples;
                                    revoke = Some(g.revoke);
                                    Ok(())
                                }
                                Ok(Err(e)) => Err(e),
                                Err(_) => Err(TicketError::NotGranted),
                            });
                        }
                    }
                    s.handle_frame(&f, &mut auth, clock.now());
                }
            }
            r = recv_sample(&mut samples) => match r {
                Ok((stamp, p)) => {
                    s.offer(stamp, &p);
                    if let Some(rx) = samples.as_mut() {
                        while let Ok((stamp, p)) = rx.try_recv() {
                            s.offer(stamp, &p);
                        }
                    }
                }
                Err(broadcast::error::RecvError::Lagged(n)) => {
                    let _ = ctl.send(Ctl::Lagged(n));
                }
                Err(broadcast::error::RecvError::Closed) => {
                    samples = None;
                    s.revoke(RevokeReason::SourceGone);
                }
            },
            r = recv_revoke(&mut revoke) => {
                revoke = None;
                if let Some(reason) = r {
                    s.revoke(reason);
                }
            }
            () = sleep => {
                // Input that waited while this task was starved goes in first (a client's
                // heartbeat must not be taken for silence).
                // (Only once streaming: an OpenData needs the manager task, which the
                // read arm asks.)
                let pending = if s.is_streaming() {
                    reader.try_read_from(&rd)
                } else {
                    Ok(None)
                };
                match pending {
                    Ok(Some(0)) | Err(_) => {
                        end = DataClose::Lost;
                        break 'run;
                    }
                    Ok(Some(_)) => {
                        let now = clock.now();
                        while let Some(f) = reader.next_frame() {
                            s.handle_frame(f, &mut Prefetched(None), now);
                        }
                    }
                    Ok(None) => {}
                }
                s.handle_timeout(clock.now());
            }
        }
    }
    let _ = tokio::time::timeout(window, wr.shutdown()).await;
    let _ = ctl.send(Ctl::DataEnded { id, reason: end });
    let _ = events.send(ManagerNetEvent::DataClosed {
        source,
        reason: end,
    });
}

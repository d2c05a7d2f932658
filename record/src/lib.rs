//! Recording (MCAP) and live view (Foxglove WebSocket) of ima's devices and readings, on the
//! Foxglove SDK.
//!
//! A [`Recorder`] is a cheap, cloneable handle. Logging never blocks the caller: every message
//! goes into a bounded queue read by one background thread, which encodes it (protobuf, the
//! `foxglove.*` well-known schemas), writes it to the MCAP file (zstd-compressed chunks,
//! message and chunk indexes, a summary) and hands it to the WebSocket server. The thread
//! drains the queue on a tick — every 20 ms with a live view, every 500 ms when it only writes
//! a file — and earlier when the queue fills to a quarter or [`Recorder::finish`] is called, so
//! no message wakes it on its own. When the queue is full the message is dropped and counted;
//! [`Recorder::finish`] reports the counts.
//!
//! What is recorded:
//!
//! * raw serial bytes, both directions, one channel per port ([`raw`], [`Recorder::raw_port`]);
//! * decoded readings through the sink API: [`Recorder::log_scan`],
//!   [`Recorder::log_odometry`], [`Recorder::log_transform`], [`Recorder::log_pose`],
//!   [`Recorder::log_compass`], [`Recorder::log_image`], [`Recorder::log_ses`],
//!   [`Recorder::log_text`], [`Recorder::log_sonar`];
//! * structured state as JSON with a JSON Schema ([`Recorder::log_json`]).
//!
//! [`Options::exclude`] leaves topics out of the file ([`filter`]); without a live view, what
//! is left out is not even built or queued ([`Recorder::wants`]).
//!
//! Stamps: every message's MCAP log time is the recorder's clock (Unix time at the start plus
//! monotonic time since), taken when the message is logged.
//!
//! A crash leaves a file whose complete chunks any MCAP reader recovers (chunks are small, and
//! the data section is flushed every second); [`read`] reads such files too.

pub mod convert;
pub mod filter;
pub mod raw;
pub mod read;

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::mpsc::{self, Receiver, SyncSender, TryRecvError, TrySendError};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use foxglove::{Context, Encode, PartialMetadata, Schema};

/// Decoding of recorded `foxglove.*` messages (protobuf).
pub use foxglove::Decode;
pub use foxglove::messages;

/// Messages the queue holds before new ones are dropped.
pub const DEFAULT_QUEUE: usize = 8192;

/// Bytes the queue may hold (encoded sizes, estimated) before new messages are dropped:
/// memory stays bounded even when every queued message is a camera frame.
pub const MAX_QUEUED_BYTES: usize = 64 << 20;

/// Bytes queued that wake the recorder's thread before its tick.
const WAKE_BYTES: usize = MAX_QUEUED_BYTES / 4;

/// How often the recorder's thread drains the queue while a live view is served (the added
/// latency at most).
const LIVE_TICK: Duration = Duration::from_millis(20);

/// How often it drains the queue when it only writes a file: larger batches keep the
/// compressor's tables in cache (measured: the thread's CPU −45 % against 20 ms), and a
/// crash loses at most this much more than the chunk being filled.
const FILE_TICK: Duration = Duration::from_millis(500);

/// MCAP chunk size, bytes (uncompressed): a crash loses at most this much (about 2 s of the
/// demo); a camera frame is ~230 KB, so smaller chunks would hold one frame each.
const CHUNK_SIZE: u64 = 1024 * 1024;

/// Where the recording goes.
#[derive(Debug, Clone, Default)]
pub struct Options {
    /// The MCAP file to create (it must not exist yet).
    pub mcap: Option<PathBuf>,
    /// The address of the Foxglove WebSocket server.
    pub foxglove: Option<SocketAddr>,
    /// Queue length (0: [`DEFAULT_QUEUE`]).
    pub queue: usize,
    /// Name of the session (the server's name and the file's `ima` metadata).
    pub name: String,
    /// How camera frames are recorded.
    pub images: Images,
    /// Topics left out of the file (a live view still shows them).
    pub exclude: filter::TopicFilter,
}

/// How camera frames are recorded and served ([`Recorder::log_image`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum Images {
    /// `foxglove.RawImage`, `rgb8`: the file's zstd chunks compress them about as well as
    /// PNG does (the demo's noisy frames: ≈130 KB raw+zstd against ≈143 KB PNG), at less CPU.
    #[default]
    Raw,
    /// `foxglove.CompressedImage`, PNG (fast compression), encoded on the recorder's thread
    /// (never the caller's): smaller over a live WebSocket link.
    Png,
}

/// A recorder that could not start.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The MCAP file could not be created.
    #[error("--record {path}: {source}")]
    Create {
        /// The file.
        path: PathBuf,
        /// Why.
        source: foxglove::FoxgloveError,
    },
    /// The WebSocket server could not start.
    #[error("--foxglove {addr}: {reason}")]
    Server {
        /// The address.
        addr: SocketAddr,
        /// Why.
        reason: String,
    },
    /// The background thread could not start.
    #[error("starting the recorder thread: {0}")]
    Thread(std::io::Error),
}

/// What a recording wrote, reported at its end.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Report {
    /// The MCAP file, if any.
    pub path: Option<PathBuf>,
    /// Messages written per topic.
    pub written: BTreeMap<String, u64>,
    /// Messages dropped because the queue was full.
    pub dropped: u64,
    /// The first error writing the file (the recording stopped there), if any.
    pub error: Option<String>,
    /// Size of the file at the end, bytes.
    pub bytes: u64,
    /// The WebSocket server's port, if one ran.
    pub server_port: Option<u16>,
    /// The topics left out of the file, as the patterns were given (empty: none).
    pub excluded: String,
}

impl Report {
    /// All messages written.
    pub fn total(&self) -> u64 {
        self.written.values().sum()
    }

    /// One line for a person.
    pub fn summary(&self) -> String {
        let mut s = match &self.path {
            Some(p) => format!(
                "recorded {} messages on {} topics to {} ({} kB)",
                self.total(),
                self.written.len(),
                p.display(),
                self.bytes.div_ceil(1024)
            ),
            None => format!("published {} messages", self.total()),
        };
        if !self.excluded.is_empty() && self.path.is_some() {
            s.push_str(&format!(" (left out: {})", self.excluded));
        }
        if self.dropped > 0 {
            s.push_str(&format!(
                "; {} dropped (the recorder could not keep up)",
                self.dropped
            ));
        }
        if let Some(e) = &self.error {
            s.push_str(&format!("; writing stopped: {e}"));
        }
        s
    }
}

/// A message that the background thread encodes and logs.
trait Payload: Send {
    fn size(&self) -> usize;
    fn schema(&self) -> Option<Schema>;
    fn encoding(&self) -> String;
    fn encode_into(&self, buf: &mut Vec<u8>);
}

impl<T: Encode + Send> Payload for T {
    fn size(&self) -> usize {
        self.encoded_len().unwrap_or(1024)
    }
    fn schema(&self) -> Option<Schema> {
        T::get_schema()
    }
    fn encoding(&self) -> String {
        T::get_message_encoding()
    }
    fn encode_into(&self, buf: &mut Vec<u8>) {
        // Encoding into a Vec cannot run out of room.
        let _ = self.encode(buf);
    }
}

/// A raw channel's description (sent once, before its first bytes).
struct RawDesc {
    metadata: BTreeMap<String, String>,
}

enum Body {
    Typed(Box<dyn Payload>),
    Raw(Vec<u8>),
    DeclareRaw(RawDesc),
    /// A JSON message and, with a channel's first message, its schema.
    Json(Option<Schema>, Vec<u8>),
}

impl Body {
    fn size(&self) -> usize {
        match self {
            Self::Typed(p) => p.size(),
            Self::Raw(b) | Self::Json(_, b) => b.len(),
            Self::DeclareRaw(_) => 0,
        }
    }
}

enum Msg {
    Log {
        topic: Arc<str>,
        log_time: u64,
        body: Body,
    },
    Finish(mpsc::Sender<Report>),
}

/// What the queue holds (the recorder's thread keeps its own handle on it: holding
/// [`Shared`] would keep the queue's sender alive).
#[derive(Default)]
struct Queued {
    /// Encoded sizes, estimated.
    bytes: AtomicUsize,
    /// Messages (the thread is woken early at `Shared::wake_msgs`).
    msgs: AtomicUsize,
}

struct Shared {
    tx: SyncSender<Msg>,
    dropped: AtomicU64,
    queued: Arc<Queued>,
    /// A quarter of the queue's length.
    wake_msgs: usize,
    /// Stamp of everything logged while non-zero (a replay's recorded time).
    stamp_override: AtomicU64,
    wall0_ns: u64,
    mono0: std::time::Instant,
    finished: Mutex<Option<Report>>,
    /// The recorder's thread (woken by `finish`).
    worker: std::sync::OnceLock<std::thread::Thread>,
    /// JSON topics whose first message (with the schema) is queued.
    json_topics: Mutex<std::collections::BTreeSet<Box<str>>>,
    server_port: Option<u16>,
    images: Images,
    exclude: filter::TopicFilter,
}

/// A recorder: a handle on the background writer (clone it freely).
#[derive(Clone)]
pub struct Recorder {
    shared: Arc<Shared>,
}

impl std::fmt::Debug for Recorder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Recorder")
            .field("dropped", &self.dropped())
            .finish_non_exhaustive()
    }
}

impl Recorder {
    /// Start recording to a file and/or serving a live view, as `opts` say.
    pub fn start(opts: &Options) -> Result<Self, Error> {
        let cap = if opts.queue == 0 {
            DEFAULT_QUEUE
        } else {
            opts.queue
        };
        let (tx, rx) = mpsc::sync_channel(cap);
        let ctx = Context::new();
        let writer = match &opts.mcap {
            Some(path) => {
                // zstd's fastest level on this thread: the robot's cores are for the robot
                // (level 1 and no helper threads: measured in the README's recording rows).
                let options = foxglove::McapWriteOptions::new()
                    .compression(Some(foxglove::McapCompression::Zstd))
                    .compression_level(1)
                    .compression_threads(0)
                    .chunk_size(Some(CHUNK_SIZE))
                    .profile("");
                let mut w = ctx.mcap_writer_with_options(options);
                if !opts.exclude.is_empty() {
                    let f = opts.exclude.clone();
                    w = w.channel_filter_fn(move |c| !f.excludes(c.topic()));
                }
                let w = w
                    .create_new_buffered_file(path)
                    .map_err(|source| Error::Create {
                        path: path.clone(),
                        source,
                    })?;
                let mut meta = BTreeMap::new();
                meta.insert("name".to_owned(), opts.name.clone());
                meta.insert("version".to_owned(), env!("CARGO_PKG_VERSION").to_owned());
                if !opts.exclude.is_empty() {
                    meta.insert("exclude".to_owned(), opts.exclude.describe());
                }
                let _ = w.write_metadata("ima", meta);
                Some(w)
            }
            None => None,
        };
        let server = match opts.foxglove {
            Some(addr) => Some(start_server(&ctx, addr, &opts.name)?),
            None => None,
        };
        let server_port = server.as_ref().map(|(h, _)| h.port());
        let path = opts.mcap.clone();
        let queued = Arc::new(Queued::default());
        let shared = Arc::new(Shared {
            tx,
            dropped: AtomicU64::new(0),
            queued: Arc::clone(&queued),
            wake_msgs: (cap / 4).max(1),
            stamp_override: AtomicU64::new(0),
            wall0_ns: std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX)),
            mono0: std::time::Instant::now(),
            finished: Mutex::new(None),
            json_topics: Mutex::new(std::collections::BTreeSet::new()),
            worker: std::sync::OnceLock::new(),
            server_port,
            images: opts.images,
            exclude: opts.exclude.clone(),
        });
        let worker = Worker {
            queued,
            ctx,
            writer,
            server,
            server_port,
            path,
            channels: BTreeMap::new(),
            raw_meta: BTreeMap::new(),
            written: BTreeMap::new(),
            error: None,
            buf: Vec::new(),
            exclude: opts.exclude.clone(),
        };
        let thread = std::thread::Builder::new()
            .name("ima-record".into())
            .spawn(move || worker.run(rx))
            .map_err(Error::Thread)?;
        let _ = shared.worker.set(thread.thread().clone());
        Ok(Self { shared })
    }

    /// The recorder's clock now: Unix nanoseconds.
    pub fn now_ns(&self) -> u64 {
        let o = self.shared.stamp_override.load(Ordering::Relaxed);
        if o != 0 {
            return o;
        }
        let since = u64::try_from(self.shared.mono0.elapsed().as_nanos()).unwrap_or(u64::MAX);
        self.shared.wall0_ns.saturating_add(since)
    }

    /// The port the WebSocket server listens on, if one runs (useful with port 0).
    pub fn server_port(&self) -> Option<u16> {
        self.shared.server_port
    }

    /// Stamp everything logged from now on with `ns` (Unix nanoseconds) instead of the clock:
    /// a replay keeps the recorded stamps. `None` goes back to the clock.
    pub fn set_stamp(&self, ns: Option<u64>) {
        self.shared
            .stamp_override
            .store(ns.unwrap_or(0), Ordering::Relaxed);
    }

    /// How camera frames are recorded.
    pub fn images(&self) -> Images {
        self.shared.images
    }

    /// Messages dropped so far (queue full).
    pub fn dropped(&self) -> u64 {
        self.shared.dropped.load(Ordering::Relaxed)
    }

    /// Whether anything would take a message on `topic`: a live view takes every topic, the
    /// file what [`Options::exclude`] does not leave out. Callers skip building messages
    /// nobody takes.
    #[must_use]
    pub fn wants(&self, topic: &str) -> bool {
        self.shared.server_port.is_some() || !self.shared.exclude.excludes(topic)
    }

    /// Queue a message; `false` when it was dropped (and counted). A message nobody takes
    /// ([`Self::wants`]) is let go here, before the queue.
    fn send(&self, topic: Arc<str>, body: Body) -> bool {
        if !self.wants(&topic) {
            return true;
        }
        let size = body.size();
        let q = &self.shared.queued;
        let bytes = q
            .bytes
            .fetch_add(size, Ordering::Relaxed)
            .saturating_add(size);
        let msgs = q.msgs.fetch_add(1, Ordering::Relaxed).saturating_add(1);
        let msg = Msg::Log {
            topic,
            log_time: self.now_ns(),
            body,
        };
        if bytes > MAX_QUEUED_BYTES || self.shared.tx.try_send(msg).is_err() {
            q.bytes.fetch_sub(size, Ordering::Relaxed);
            q.msgs.fetch_sub(1, Ordering::Relaxed);
            self.shared.dropped.fetch_add(1, Ordering::Relaxed);
            return false;
        }
        // A burst (a fast replay, a flood of frames) wakes the thread before its tick, long
        // before the queue is full.
        if msgs >= self.shared.wake_msgs || bytes >= WAKE_BYTES {
            self.wake();
        }
        true
    }

    /// Wake the recorder's thread before its tick.
    fn wake(&self) {
        if let Some(t) = self.shared.worker.get() {
            t.unpark();
        }
    }

    /// Log a payload encoded on the background thread.
    fn log_payload(&self, topic: &str, msg: Box<dyn Payload>) {
        let _ = self.send(Arc::from(topic), Body::Typed(msg));
    }

    /// Log any `foxglove` well-known message on `topic`.
    pub fn log<T: Encode + Send + 'static>(&self, topic: &str, msg: T) {
        let _ = self.send(Arc::from(topic), Body::Typed(Box::new(msg)));
    }

    /// Log a JSON object on `topic`: a channel with message encoding `json` and the JSON
    /// Schema `schema()` named `schema_name` (encoding `jsonschema`), which Foxglove's Raw
    /// Messages, Plot and State Transitions panels read. The first message fixes the
    /// channel's schema; `schema` is called only for it (later messages cost only their own
    /// serialisation).
    pub fn log_json<T: serde::Serialize + ?Sized>(
        &self,
        topic: &str,
        schema_name: &str,
        schema: impl FnOnce() -> serde_json::Value,
        value: &T,
    ) {
        let data = serde_json::to_vec(value).unwrap_or_default();
        let mut known = (self.shared.json_topics)
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        let first = !known.contains(topic);
        let schema = first.then(|| {
            let text = serde_json::to_vec(&schema()).unwrap_or_default();
            Schema::new(schema_name, "jsonschema", text)
        });
        if self.send(Arc::from(topic), Body::Json(schema, data)) && first {
            known.insert(topic.into());
        }
    }

    /// Declare a raw serial port and get the handle that records its bytes.
    pub fn raw_port(&self, port: raw::PortInfo) -> raw::RawPort {
        let topic: Arc<str> = Arc::from(port.topic().as_str());
        let desc = Body::DeclareRaw(RawDesc {
            metadata: port.metadata(),
        });
        let _ = self.send(Arc::clone(&topic), desc);
        raw::RawPort::new(self.clone(), topic)
    }

    pub(crate) fn send_raw(&self, topic: &Arc<str>, bytes: Vec<u8>) {
        let _ = self.send(Arc::clone(topic), Body::Raw(bytes));
    }

    /// Finish: write what is queued, close the file (summary, indexes) and stop the server.
    /// Waits at most `wait`; later calls return the first call's report.
    pub fn finish(&self, wait: Duration) -> Report {
        let mut done = self
            .shared
            .finished
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        if let Some(r) = &*done {
            return r.clone();
        }
        let (tx, rx) = mpsc::channel();
        // The finish request must get in even when the queue is full: retry until it does.
        let deadline = std::time::Instant::now() + wait;
        let mut req = Msg::Finish(tx);
        loop {
            match self.shared.tx.try_send(req) {
                Ok(()) => {
                    self.wake();
                    break;
                }
                Err(TrySendError::Full(m)) if std::time::Instant::now() < deadline => {
                    req = m;
                    self.wake();
                    std::thread::sleep(Duration::from_millis(2));
                }
                Err(_) => {
                    let r = Report {
                        dropped: self.dropped(),
                        error: Some("the recorder did not answer".into()),
                        ..Report::default()
                    };
                    *done = Some(r.clone());
                    return r;
                }
            }
        }
        let left = deadline.saturating_duration_since(std::time::Instant::now());
        let mut r = rx.recv_timeout(left).unwrap_or_else(|_| Report {
            error: Some("the recorder did not finish in time".into()),
            ..Report::default()
        });
        r.dropped += self.dropped();
        *done = Some(r.clone());
        r
    }
}

fn start_server(
    ctx: &Arc<Context>,
    addr: SocketAddr,
    name: &str,
) -> Result<(foxglove::WebSocketServerHandle, tokio::runtime::Runtime), Error> {
    let fail = |reason: String| Error::Server { addr, reason };
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .thread_name("ima-foxglove")
        .enable_all()
        .build()
        .map_err(|e| fail(e.to_string()))?;
    let server = ctx
        .websocket_server()
        .name(name)
        .bind(addr.ip().to_string(), addr.port())
        .tokio_runtime(rt.handle())
        // Raw serial bytes stay in the file: a viewer cannot decode them.
        .channel_filter_fn(|c| !c.topic().contains("/serial/"));
    // Started from a plain thread: the caller may be inside another runtime.
    let handle = std::thread::scope(|s| {
        s.spawn(|| rt.block_on(server.start()))
            .join()
            .map_err(|_| fail("the server's start panicked".into()))
    })?
    .map_err(|e| fail(e.to_string()))?;
    Ok((handle, rt))
}

enum Chan {
    Raw(Arc<foxglove::RawChannel>),
}

struct Worker {
    queued: Arc<Queued>,
    ctx: Arc<Context>,
    writer: Option<foxglove::McapWriterHandle<std::io::BufWriter<std::fs::File>>>,
    server: Option<(foxglove::WebSocketServerHandle, tokio::runtime::Runtime)>,
    server_port: Option<u16>,
    path: Option<PathBuf>,
    channels: BTreeMap<Arc<str>, Chan>,
    raw_meta: BTreeMap<Arc<str>, BTreeMap<String, String>>,
    written: BTreeMap<Arc<str>, u64>,
    error: Option<String>,
    buf: Vec<u8>,
    /// Topics kept out of the file (and of its counts).
    exclude: filter::TopicFilter,
}

impl Worker {
    /// Drain the queue every [`LIVE_TICK`] or [`FILE_TICK`] instead of waking for each
    /// message: a sender never has a sleeping receiver to wake (no futex call per message on
    /// the robot's threads), and the thread wakes at a fixed rate however busy the robot is.
    fn run(mut self, rx: Receiver<Msg>) {
        let tick = if self.server.is_some() {
            LIVE_TICK
        } else {
            FILE_TICK
        };
        let mut last_flush = std::time::Instant::now();
        loop {
            loop {
                match rx.try_recv() {
                    Ok(Msg::Log {
                        topic,
                        log_time,
                        body,
                    }) => self.log(topic, log_time, body),
                    Ok(Msg::Finish(reply)) => {
                        // Whatever is still queued goes in first.
                        while let Ok(m) = rx.try_recv() {
                            match m {
                                Msg::Log {
                                    topic,
                                    log_time,
                                    body,
                                } => self.log(topic, log_time, body),
                                Msg::Finish(other) => {
                                    let _ = other.send(Report::default());
                                }
                            }
                        }
                        let report = self.close();
                        let _ = reply.send(report);
                        return;
                    }
                    Err(TryRecvError::Empty) => break,
                    Err(TryRecvError::Disconnected) => {
                        let _ = self.close();
                        return;
                    }
                }
            }
            if last_flush.elapsed() >= Duration::from_secs(1) {
                last_flush = std::time::Instant::now();
                if let Some(w) = &self.writer
                    && let Err(e) = w.flush()
                {
                    self.error.get_or_insert(e.to_string());
                }
            }
            // `finish` unparks the thread so that it need not wait for the tick.
            std::thread::park_timeout(tick);
        }
    }

    fn channel(&mut self, topic: &Arc<str>, body: &Body) -> Option<Arc<foxglove::RawChannel>> {
        if let Some(Chan::Raw(c)) = self.channels.get(topic) {
            return Some(Arc::clone(c));
        }
        let builder = self.ctx.channel_builder(&**topic);
        let builder = match body {
            Body::Typed(p) => builder.schema(p.schema()).message_encoding(p.encoding()),
            Body::Raw(_) => builder
                .message_encoding(raw::ENCODING)
                .metadata(self.raw_meta.get(topic).cloned().unwrap_or_default()),
            Body::Json(schema, _) => builder.schema(schema.clone()).message_encoding("json"),
            Body::DeclareRaw(_) => return None,
        };
        match builder.build_raw() {
            Ok(c) => {
                self.channels
                    .insert(Arc::clone(topic), Chan::Raw(Arc::clone(&c)));
                Some(c)
            }
            Err(e) => {
                tracing::warn!("recorder: channel {topic}: {e}");
                None
            }
        }
    }

    fn log(&mut self, topic: Arc<str>, log_time: u64, body: Body) {
        self.queued.bytes.fetch_sub(body.size(), Ordering::Relaxed);
        self.queued.msgs.fetch_sub(1, Ordering::Relaxed);
        if let Body::DeclareRaw(d) = body {
            self.raw_meta.insert(topic, d.metadata);
            return;
        }
        let Some(chan) = self.channel(&topic, &body) else {
            return;
        };
        let meta = PartialMetadata::with_log_time(log_time);
        match &body {
            Body::Typed(p) => {
                self.buf.clear();
                p.encode_into(&mut self.buf);
                chan.log_with_meta(&self.buf, meta);
            }
            Body::Raw(bytes) | Body::Json(_, bytes) => chan.log_with_meta(bytes, meta),
            Body::DeclareRaw(_) => return,
        }
        // Counted where it ends up: the file (when there is one) or the live view.
        if self.path.is_none() || !self.exclude.excludes(&topic) {
            *self.written.entry(topic).or_insert(0) += 1;
        }
    }

    fn close(&mut self) -> Report {
        if let Some(w) = self.writer.take()
            && let Err(e) = w.close()
        {
            self.error.get_or_insert(e.to_string());
        }
        if let Some((h, rt)) = self.server.take() {
            let shutdown = h.stop();
            rt.block_on(async {
                let _ = tokio::time::timeout(Duration::from_secs(1), shutdown.wait()).await;
            });
            rt.shutdown_timeout(Duration::from_millis(200));
        }
        let bytes = self
            .path
            .as_deref()
            .and_then(|p: &Path| std::fs::metadata(p).ok())
            .map_or(0, |m| m.len());
        Report {
            path: self.path.clone(),
            written: (std::mem::take(&mut self.written).into_iter())
                .map(|(t, n)| (t.to_string(), n))
                .collect(),
            dropped: 0,
            error: self.error.clone(),
            bytes,
            server_port: self.server_port,
            excluded: self.exclude.describe(),
        }
    }
}

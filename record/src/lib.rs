//! Recording (MCAP) and live view (Foxglove WebSocket) of ima's devices and readings, on the
//! Foxglove SDK.
//!
//! A [`Recorder`] is a cheap, cloneable handle. Logging never blocks the caller and never
//! allocates: a message is appended, as a compact record of what changes from one message to
//! the next (a scan's ranges, a pose's numbers, a frame's pixels, raw bytes), to a bounded byte
//! queue. One background thread takes the queue whole, fills each stream's message in place
//! (frame ids, topics and schemas are kept once per stream), encodes it (protobuf, the
//! `foxglove.*` well-known schemas), writes it to the MCAP file (zstd-compressed chunks,
//! message and chunk indexes, a summary) and hands it to the WebSocket server. The live view
//! keeps the last message of every stream it serves and sends them to each new subscriber, so
//! no client misses a channel's first message or waits for a topic that is logged only when
//! it changes. The thread drains the queue on a tick — every 20 ms with a live view, every
//! 500 ms when it only writes a file — and earlier when the queue fills to a quarter or
//! [`Recorder::finish`] is called, so no message wakes it on its own. When the queue is full
//! the message is dropped and counted; [`Recorder::finish`] reports the counts and the CPU time the thread used
//! ([`Report::thread_cpu`]).
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
mod latch;
mod queue;
pub mod raw;
pub mod read;
mod stream;

use std::collections::{BTreeMap, HashMap};
use std::io::{BufWriter, Seek, Write};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use foxglove::{Context, Encode, PartialMetadata, Schema};

/// Decoding of recorded `foxglove.*` messages (protobuf).
pub use foxglove::Decode;
pub use foxglove::messages;

/// Messages the queue holds before new ones are dropped.
pub const DEFAULT_QUEUE: usize = 8192;

/// Bytes the callers' side of the queue may hold before new messages are dropped: memory
/// stays bounded even when every queued message is a camera frame. The check takes each
/// message's declared size before it is written (a JSON state declares none), so one message
/// may take the queue past this by its own size; with the batch the recorder's thread is
/// writing, the queue holds at most about twice this.
pub const MAX_QUEUED_BYTES: usize = 64 << 20;

/// The queue's buffers start this large (about 1.5 s of the demo) …
const INITIAL_BATCH: usize = 2 << 20;

/// … and one grown by a burst beyond this is given back once drained.
const KEEP_BATCH: usize = 8 << 20;

/// The MCAP file's write buffer: at least one compressed chunk per `write` call.
const WRITE_BUFFER: usize = 1 << 20;

/// Bytes queued that wake the recorder's thread before its tick.
const WAKE_BYTES: usize = MAX_QUEUED_BYTES / 4;

/// How often the recorder's thread drains the queue while a live view is served (the added
/// latency at most).
const LIVE_TICK: Duration = Duration::from_millis(20);

/// How often it drains the queue when it only writes a file: larger batches keep the
/// compressor's tables in cache (measured: the thread's CPU −45 % against 20 ms), and a
/// crash loses at most this much more than the chunk being filled.
const FILE_TICK: Duration = Duration::from_millis(500);

/// The largest failed file whose messages are counted again from the file at its end (a
/// read of well under a second from a disk that works, within the recorder's time to
/// finish): a larger one keeps the count of what was logged.
pub const RECOUNT_LIMIT: u64 = 64 << 20;

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
    /// Messages written per topic. After a write error ([`error`](Self::error)) those the file
    /// holds, read back from it, unless [`uncounted`](Self::uncounted) says why not: the
    /// chunk being written when the file failed is lost.
    pub written: BTreeMap<String, u64>,
    /// Why a file that failed was not read back to count what it holds (larger than
    /// [`RECOUNT_LIMIT`], or unreadable): [`written`](Self::written) then counts what was
    /// logged, the lost chunk's messages included.
    pub uncounted: Option<String>,
    /// Messages dropped because the queue was full.
    pub dropped: u64,
    /// Messages logged but not written: their payload could not be encoded (a `Serialize`
    /// or `Encode` error, a payload over 4 GiB, a frame whose pixels do not match its size)
    /// or their channel could not be made.
    pub unwritten: u64,
    /// The first error writing the file (the recording stopped there), if any.
    pub error: Option<String>,
    /// Size of the file at the end, bytes.
    pub bytes: u64,
    /// The WebSocket server's port, if one ran.
    pub server_port: Option<u16>,
    /// The topics left out of the file, as the patterns were given (empty: none).
    pub excluded: String,
    /// The patterns of [`Options::exclude`] that matched no topic logged (a typo: nothing was
    /// left out by them).
    pub excluded_nothing: Vec<String>,
    /// CPU time the recorder's own thread used, from the kernel's per-thread account
    /// (`None` where it cannot be read: not Linux).
    pub thread_cpu: Option<Duration>,
    /// Time the callers' threads spent logging: in [`Recorder::timed`] calls (building
    /// and logging their messages) and in raw ports' logging. Logging never waits for the
    /// recorder's thread, so this is CPU time, give or take a wait for the queue's lock or a
    /// preemption (which make it an overestimate); with [`thread_cpu`](Self::thread_cpu), the
    /// recording's own work.
    pub calls_time: Duration,
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
                "recorded {} messages on {} topics to {} ({} KiB)",
                self.total(),
                self.written.len(),
                p.display(),
                self.bytes.div_ceil(1024)
            ),
            None => format!("published {} messages", self.total()),
        };
        if !self.excluded.is_empty() && self.path.is_some() {
            s.push_str(&format!(" (left out: {}", self.excluded));
            if !self.excluded_nothing.is_empty() {
                s.push_str(&format!(
                    "; no topic matched {}",
                    self.excluded_nothing.join(", ")
                ));
            }
            s.push(')');
        }
        if self.dropped > 0 {
            s.push_str(&format!(
                "; {} dropped (the recorder could not keep up)",
                self.dropped
            ));
        }
        if self.unwritten > 0 {
            s.push_str(&format!(
                "; {} could not be encoded or had no channel",
                self.unwritten
            ));
        }
        if let Some(e) = &self.error {
            s.push_str(&format!("; writing stopped: {e}"));
            if let Some(why) = &self.uncounted {
                s.push_str(&format!(
                    " (the count includes the messages of the chunk lost then: {why})"
                ));
            }
        }
        if let Some(cpu) = self.thread_cpu {
            s.push_str(&format!(
                "; the recorder's thread used {:.0} ms of CPU",
                cpu.as_secs_f64() * 1e3
            ));
        }
        if !self.calls_time.is_zero() {
            s.push_str(&format!(
                ", logging calls {:.0} ms",
                self.calls_time.as_secs_f64() * 1e3
            ));
        }
        s
    }
}

/// The part of the recorder that callers and the recorder's thread share.
struct Inner {
    /// The records logged since the thread last took them.
    batch: queue::Batch,
    /// Every stream registered, by id.
    streams: Vec<Arc<stream::Stream>>,
    /// Stream ids by key (kind, topic and what else fixes the stream's messages).
    by_key: HashMap<Box<str>, u32, std::hash::BuildHasherDefault<KeyHasher>>,
    /// The recorder's thread took its last batch: what is logged now is dropped (and
    /// counted), not left in a queue nobody reads.
    closed: bool,
}

/// What the recorder's thread is asked besides draining the queue.
enum Control {
    Finish(mpsc::Sender<Report>),
}

struct Shared {
    inner: Arc<Mutex<Inner>>,
    control: mpsc::Sender<Control>,
    /// Messages the queue holds before new ones are dropped.
    cap: usize,
    /// A quarter of `cap`: wakes the thread before its tick.
    wake_msgs: usize,
    dropped: AtomicU64,
    /// Messages whose payload could not be written into the queue.
    unwritten: AtomicU64,
    /// Nanoseconds spent in [`Recorder::timed`] calls and raw ports' logging.
    calls_ns: AtomicU64,
    /// Stamp of everything logged while non-zero (a replay's recorded time).
    stamp_override: AtomicU64,
    wall0_ns: u64,
    mono0: std::time::Instant,
    finished: Mutex<Option<Report>>,
    /// The recorder's thread (woken by `finish` and by bursts).
    worker: std::sync::OnceLock<std::thread::Thread>,
    server_port: Option<u16>,
    images: Images,
    exclude: filter::TopicFilter,
    /// The file's first write error: with no live view, nothing is queued after it.
    failure: Arc<Failure>,
    /// The MCAP file, if any.
    path: Option<PathBuf>,
    /// Where each robot is in `map`, as its transforms say (for the compass's arrow).
    places: Mutex<HashMap<String, convert::Place>>,
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

/// A stream's id and whether anything takes its messages.
#[derive(Debug, Clone, Copy)]
pub(crate) struct StreamId {
    id: u32,
    wanted: bool,
}

/// A fast hash for stream keys (short strings the process itself makes, looked up on every
/// message): FNV-1a over the bytes. Not for keys an adversary chooses.
#[derive(Debug, Clone, Copy)]
struct KeyHasher(u64);

impl Default for KeyHasher {
    fn default() -> Self {
        Self(0xcbf2_9ce4_8422_2325)
    }
}

impl std::hash::Hasher for KeyHasher {
    fn finish(&self) -> u64 {
        self.0
    }

    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0 ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3);
        }
    }
}

thread_local! {
    /// Where a stream's key is written to be looked up (reused: no allocation per message).
    static KEY: std::cell::RefCell<String> = const { std::cell::RefCell::new(String::new()) };
}

impl Recorder {
    /// Start recording to a file and/or serving a live view, as `opts` say.
    pub fn start(opts: &Options) -> Result<Self, Error> {
        let cap = if opts.queue == 0 {
            DEFAULT_QUEUE
        } else {
            opts.queue
        };
        let ctx = Context::new();
        let failure = Arc::new(Failure::default());
        // The server first: an address in use must not leave an empty file behind, which the
        // next try would then refuse to overwrite.
        let (server, latch) = match opts.foxglove {
            Some(addr) => {
                let latch = Arc::new(latch::Latch::default());
                let server = start_server(&ctx, addr, &opts.name, &latch)?;
                (Some(server), Some(latch))
            }
            None => (None, None),
        };
        let writer = match &opts.mcap {
            Some(path) => match create_file(&ctx, path, opts, &failure) {
                Ok(w) => Some(w),
                Err(e) => {
                    if let Some((h, rt)) = server {
                        let _ = h.stop();
                        rt.shutdown_background();
                    }
                    return Err(e);
                }
            },
            None => None,
        };
        let server_port = server.as_ref().map(|(h, _)| h.port());
        let inner = Arc::new(Mutex::new(Inner {
            batch: queue::Batch {
                bytes: Vec::with_capacity(INITIAL_BATCH),
                msgs: 0,
                whole: 0,
            },
            streams: Vec::new(),
            by_key: HashMap::default(),
            closed: false,
        }));
        let (control, control_rx) = mpsc::channel();
        let shared = Arc::new(Shared {
            inner: Arc::clone(&inner),
            control,
            cap,
            wake_msgs: (cap / 4).max(1),
            dropped: AtomicU64::new(0),
            unwritten: AtomicU64::new(0),
            calls_ns: AtomicU64::new(0),
            stamp_override: AtomicU64::new(0),
            wall0_ns: std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX)),
            mono0: std::time::Instant::now(),
            finished: Mutex::new(None),
            worker: std::sync::OnceLock::new(),
            server_port,
            images: opts.images,
            exclude: opts.exclude.clone(),
            failure: Arc::clone(&failure),
            path: opts.mcap.clone(),
            places: Mutex::new(HashMap::new()),
        });
        let worker = Worker {
            inner,
            drained: Vec::with_capacity(INITIAL_BATCH),
            ctx,
            writer,
            server,
            server_port,
            latch,
            path: opts.mcap.clone(),
            streams: Vec::new(),
            channels: BTreeMap::new(),
            error: None,
            buf: Vec::new(),
            unwritten: 0,
            exclude: opts.exclude.clone(),
            failure,
        };
        let thread = std::thread::Builder::new()
            .name("ima-record".into())
            .spawn(move || worker.run(&control_rx))
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

    /// Whether the queue is less than half full, in messages and in bytes. A producer that
    /// may outpace the recorder's thread (a replay as fast as possible) waits while it is not,
    /// so that nothing is dropped; a robot's control loop never waits.
    #[must_use]
    pub fn has_room(&self) -> bool {
        let inner = self.lock();
        inner.batch.msgs < self.shared.cap / 2 && inner.batch.bytes.len() < MAX_QUEUED_BYTES / 2
    }

    /// Messages dropped so far (queue full).
    pub fn dropped(&self) -> u64 {
        self.shared.dropped.load(Ordering::Relaxed)
    }

    /// Whether anything would take a message on `topic`: a live view takes every topic but
    /// raw serial bytes, the file what [`Options::exclude`] does not leave out. Callers skip
    /// building messages nobody takes (a live view alone built, and counted as published,
    /// the raw bytes it never serves).
    #[must_use]
    pub fn wants(&self, topic: &str) -> bool {
        (self.shared.server_port.is_some() && served(topic))
            || (self.shared.path.is_some()
                && !self.shared.exclude.excludes(topic)
                && !self.file_failed())
    }

    /// The file could not be written (its first error is in the [`Report`]); with no live
    /// view, nothing takes a message any more.
    fn file_failed(&self) -> bool {
        self.shared.failure.failed.load(Ordering::Relaxed)
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Inner> {
        self.shared
            .inner
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
    }

    /// The stream whose key is `key`'s parts (its kind, topic and what else fixes its
    /// messages), registered by `make` the first time (its topic and what its messages share;
    /// `make` runs outside the lock). Looking it up allocates nothing once the stream exists.
    pub(crate) fn stream(
        &self,
        key: &[&str],
        make: impl FnOnce() -> (String, stream::Proto),
    ) -> StreamId {
        let known = |inner: &Inner, k: &str| {
            let id = *inner.by_key.get(k)?;
            let wanted = inner.streams.get(id as usize).is_some_and(|s| s.wanted);
            Some(StreamId { id, wanted })
        };
        let look_up = |k: &mut String| {
            k.clear();
            // Each part as `<length>:<part>`: unambiguous whatever the parts hold.
            for part in key {
                let mut digits = [0u8; 20];
                let mut n = part.len();
                let mut at = digits.len();
                for d in digits.iter_mut().rev() {
                    *d = b'0' + (n % 10) as u8;
                    at -= 1;
                    n /= 10;
                    if n == 0 {
                        break;
                    }
                }
                k.extend(
                    digits
                        .get(at..)
                        .unwrap_or_default()
                        .iter()
                        .map(|&d| char::from(d)),
                );
                k.push(':');
                k.push_str(part);
            }
            known(&self.lock(), k).ok_or_else(|| Box::<str>::from(k.as_str()))
        };
        // The thread's key buffer, or a fresh one if it is in use or gone (thread exit).
        let key = KEY
            .try_with(|cell| match cell.try_borrow_mut() {
                Ok(mut k) => look_up(&mut k),
                Err(_) => look_up(&mut String::new()),
            })
            .unwrap_or_else(|_| look_up(&mut String::new()));
        let key = match key {
            Ok(s) => return s,
            Err(key) => key,
        };
        // A new stream: `make` may take long or log itself.
        let (topic, proto) = make();
        let wanted = self.wants(&topic);
        let mut inner = self.lock();
        // Another thread may have registered it meanwhile.
        if let Some(s) = known(&inner, &key) {
            return s;
        }
        let id = u32::try_from(inner.streams.len()).unwrap_or(u32::MAX);
        inner.streams.push(Arc::new(stream::Stream {
            topic: topic.into(),
            wanted,
            proto,
        }));
        inner.by_key.insert(key, id);
        StreamId { id, wanted }
    }

    /// Queue a record of stream `s` stamped now (`size`: its payload's length, for the byte
    /// budget; `write` appends the payload and says whether it could). `false` when it was
    /// dropped (queue full), could not be written (both counted) or nothing takes it.
    pub(crate) fn push(
        &self,
        s: StreamId,
        kind: queue::Kind,
        size: usize,
        write: impl FnOnce(&mut Vec<u8>) -> bool,
    ) -> bool {
        if !s.wanted {
            return false;
        }
        self.push_at(s, kind, self.now_ns(), size, write)
    }

    /// [`push`](Self::push) with the stamp `log_time` (Unix nanoseconds): messages that
    /// belong together (a transform and its pose) share one.
    pub(crate) fn push_at(
        &self,
        s: StreamId,
        kind: queue::Kind,
        log_time: u64,
        size: usize,
        write: impl FnOnce(&mut Vec<u8>) -> bool,
    ) -> bool {
        if !s.wanted || (self.shared.server_port.is_none() && self.file_failed()) {
            return false;
        }
        let (kept, wake) = {
            let mut inner = self.lock();
            let closed = inner.closed;
            let b = &mut inner.batch;
            let full = closed
                || b.msgs >= self.shared.cap
                || b.bytes.len().saturating_add(queue::HEADER + size) > MAX_QUEUED_BYTES;
            let kept = !full && b.push(s.id, kind, log_time, write);
            // Counted under the lock: `finish`, which drains under it too, sees every count
            // of a message logged before the end.
            if full {
                self.shared.dropped.fetch_add(1, Ordering::Relaxed);
            } else if !kept {
                self.shared.unwritten.fetch_add(1, Ordering::Relaxed);
            }
            (
                kept,
                b.msgs >= self.shared.wake_msgs || b.bytes.len() >= WAKE_BYTES,
            )
        };
        // A burst (a fast replay, a flood of frames) wakes the thread before its tick, long
        // before the queue is full.
        if wake {
            self.wake();
        }
        kept
    }

    /// Wake the recorder's thread before its tick.
    fn wake(&self) {
        if let Some(t) = self.shared.worker.get() {
            t.unpark();
        }
    }

    /// Log any `foxglove` well-known message on `topic` (encoded on the caller's thread, into
    /// the queue: its `Encode` must not log to this recorder).
    pub fn log<T: Encode>(&self, topic: &str, msg: T) {
        self.log_keyed(&["enc", topic], topic, msg);
    }

    /// [`log`](Self::log) on a stream of its own, `key` (a topic such as `/tf` carries
    /// several: each keeps its own latest message for a late viewer).
    pub(crate) fn log_keyed<T: Encode>(&self, key: &[&str], topic: &str, msg: T) {
        let s = self.stream(key, || {
            let proto = stream::Proto::Encoded {
                schema: T::get_schema(),
                encoding: T::get_message_encoding(),
                metadata: BTreeMap::new(),
            };
            (topic.to_owned(), proto)
        });
        let size = msg.encoded_len().unwrap_or(1024);
        self.push(s, queue::Kind::Encoded, size, |b| msg.encode(b).is_ok());
    }

    /// Log a JSON object on `topic`: a channel with message encoding `json` and the JSON
    /// Schema `schema()` named `schema_name` (encoding `jsonschema`), which Foxglove's Raw
    /// Messages, Plot and State Transitions panels read. The first message fixes the
    /// channel's schema; `schema` is called only for it (outside the queue's lock: it may
    /// log). The value is serialised straight into the queue, under its lock: its `Serialize`
    /// must not log to this recorder.
    pub fn log_json<T: serde::Serialize + ?Sized>(
        &self,
        topic: &str,
        schema_name: &str,
        schema: impl FnOnce() -> serde_json::Value,
        value: &T,
    ) {
        let s = self.stream(&["json", topic], || {
            let text = serde_json::to_vec(&schema()).unwrap_or_default();
            let proto = stream::Proto::Encoded {
                schema: Some(Schema::new(schema_name, "jsonschema", text)),
                encoding: "json".to_owned(),
                metadata: BTreeMap::new(),
            };
            (topic.to_owned(), proto)
        });
        self.push(s, queue::Kind::Encoded, 0, |b| {
            serde_json::to_writer(&mut *b, value).is_ok()
        });
    }

    /// Run `f`, the caller's logging (building its messages and logging them), and count the
    /// time it takes in [`Report::calls_time`]. Raw ports count their own; a call nested in
    /// another is counted twice.
    pub fn timed<R>(&self, f: impl FnOnce(&Self) -> R) -> R {
        let t = std::time::Instant::now();
        let r = f(self);
        let ns = u64::try_from(t.elapsed().as_nanos()).unwrap_or(u64::MAX);
        self.shared.calls_ns.fetch_add(ns, Ordering::Relaxed);
        r
    }

    /// Declare a raw serial port and get the handle that records its bytes.
    pub fn raw_port(&self, port: raw::PortInfo) -> raw::RawPort {
        let topic = port.topic();
        let s = self.stream(&["raw", &topic], || {
            let proto = stream::Proto::Encoded {
                schema: None,
                encoding: raw::ENCODING.to_owned(),
                metadata: port.metadata(),
            };
            (topic.clone(), proto)
        });
        raw::RawPort::new(self.clone(), s, topic.into())
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
        let sent = self.shared.control.send(Control::Finish(tx)).is_ok();
        self.wake();
        let mut r = match sent.then(|| rx.recv_timeout(wait)) {
            Some(Ok(r)) => r,
            // The file is named, so that the command says it is incomplete.
            Some(Err(_)) => Report {
                path: self.shared.path.clone(),
                error: Some("the recorder did not finish in time".into()),
                ..Report::default()
            },
            None => Report {
                path: self.shared.path.clone(),
                error: Some("the recorder did not answer".into()),
                ..Report::default()
            },
        };
        r.dropped += self.dropped();
        r.unwritten += self.shared.unwritten.load(Ordering::Relaxed);
        {
            // Every topic logged was declared as a stream, left out or not.
            let inner = self.lock();
            let topics = inner.streams.iter().map(|s| &*s.topic);
            r.excluded_nothing = self.shared.exclude.unmatched(topics);
        }
        r.calls_time = Duration::from_nanos(self.shared.calls_ns.load(Ordering::Relaxed));
        *done = Some(r.clone());
        r
    }
}

/// Create the MCAP file `path` (it must not exist) with its `ima` metadata: zstd's fastest
/// level, no helper threads (the robot's cores are for the robot), [`CHUNK_SIZE`] chunks,
/// and a large write buffer (one `write` per chunk rather than per 8 KiB).
fn create_file(
    ctx: &Arc<Context>,
    path: &Path,
    opts: &Options,
    failure: &Arc<Failure>,
) -> Result<foxglove::McapWriterHandle<BufWriter<Watched>>, Error> {
    let fail = |source| Error::Create {
        path: path.to_owned(),
        source,
    };
    let file = std::fs::File::create_new(path).map_err(|e| fail(e.into()))?;
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
        .create(BufWriter::with_capacity(
            WRITE_BUFFER,
            Watched {
                file,
                failure: Arc::clone(failure),
            },
        ))
        .map_err(fail)?;
    let mut meta = BTreeMap::new();
    meta.insert("name".to_owned(), opts.name.clone());
    meta.insert("version".to_owned(), env!("CARGO_PKG_VERSION").to_owned());
    if !opts.exclude.is_empty() {
        meta.insert("exclude".to_owned(), opts.exclude.describe());
    }
    let _ = w.write_metadata("ima", meta);
    Ok(w)
}

/// The MCAP file under its write buffer: it keeps the first error the file gave (the MCAP
/// writer reports later writes only as "attempted another write after a write method
/// failed") and raises [`Failure::failed`] for the recorder's thread.
struct Watched {
    file: std::fs::File,
    failure: Arc<Failure>,
}

/// The first error of the file, shared by its writer and the recorder.
#[derive(Debug, Default)]
struct Failure {
    failed: AtomicBool,
    first: Mutex<Option<String>>,
}

impl Failure {
    fn note(&self, e: &std::io::Error) {
        if e.kind() == std::io::ErrorKind::Interrupted {
            return; // retried by the writer
        }
        let mut first = self.first.lock().unwrap_or_else(PoisonError::into_inner);
        first.get_or_insert_with(|| e.to_string());
        self.failed.store(true, Ordering::Release);
    }

    fn first(&self) -> Option<String> {
        self.first
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .clone()
    }
}

impl Write for Watched {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.file.write(buf).inspect_err(|e| self.failure.note(e))
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.file.flush().inspect_err(|e| self.failure.note(e))
    }
}

impl Seek for Watched {
    fn seek(&mut self, pos: std::io::SeekFrom) -> std::io::Result<u64> {
        self.file.seek(pos).inspect_err(|e| self.failure.note(e))
    }
}

/// CPU time of the calling thread so far, from the kernel (`/proc/thread-self/schedstat`:
/// nanoseconds on a CPU, exact); `None` where it cannot be read.
pub fn thread_cpu() -> Option<Duration> {
    let s = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    let ns: u64 = s.split_whitespace().next()?.parse().ok()?;
    Some(Duration::from_nanos(ns))
}

/// Whether the live view serves `topic`: raw serial bytes stay in the file (a viewer cannot
/// decode them).
fn served(topic: &str) -> bool {
    !topic.contains("/serial/")
}

fn start_server(
    ctx: &Arc<Context>,
    addr: SocketAddr,
    name: &str,
    latch: &Arc<latch::Latch>,
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
        .channel_filter_fn(|c| served(c.topic()))
        .listener(Arc::new(latch::Replay(Arc::clone(latch))));
    // Started from a plain thread: the caller may be inside another runtime.
    let handle = std::thread::scope(|s| {
        s.spawn(|| rt.block_on(server.start()))
            .join()
            .map_err(|_| fail("the server's start panicked".into()))
    })?
    .map_err(|e| fail(e.to_string()))?;
    Ok((handle, rt))
}

/// What the recorder's thread keeps of a stream.
struct WorkerStream {
    proto: stream::Proto,
    chan: Option<Arc<foxglove::RawChannel>>,
    topic: Arc<str>,
    /// Counted where it ends up: the file (when there is one) or the live view.
    counted: bool,
    /// How many of its last messages are kept for new subscribers of the live view (0:
    /// none; a log stream keeps its recent lines).
    latch_depth: usize,
    written: u64,
}

struct Worker {
    inner: Arc<Mutex<Inner>>,
    /// The batch being written (swapped with the callers' one; both keep their capacity).
    drained: Vec<u8>,
    ctx: Arc<Context>,
    writer: Option<foxglove::McapWriterHandle<BufWriter<Watched>>>,
    server: Option<(foxglove::WebSocketServerHandle, tokio::runtime::Runtime)>,
    server_port: Option<u16>,
    /// The last message of each served stream (with a live view).
    latch: Option<Arc<latch::Latch>>,
    path: Option<PathBuf>,
    streams: Vec<Option<WorkerStream>>,
    /// One channel per topic (several streams share `/tf`, `/events`).
    channels: BTreeMap<Arc<str>, Arc<foxglove::RawChannel>>,
    error: Option<String>,
    buf: Vec<u8>,
    /// Messages taken from the queue but not written (no channel, or not encodable).
    unwritten: u64,
    /// Topics kept out of the file (and of its counts).
    exclude: filter::TopicFilter,
    /// Raised by the file's first write error.
    failure: Arc<Failure>,
}

impl Worker {
    /// Drain the queue every [`LIVE_TICK`] or [`FILE_TICK`] instead of waking for each
    /// message: a caller never has a sleeping thread to wake (no futex call per message on
    /// the robot's threads), and the thread wakes at a fixed rate however busy the robot is.
    fn run(mut self, control: &mpsc::Receiver<Control>) {
        let tick = if self.server.is_some() {
            LIVE_TICK
        } else {
            FILE_TICK
        };
        let mut last_flush = std::time::Instant::now();
        loop {
            let finish = match control.try_recv() {
                Ok(Control::Finish(reply)) => Some(Some(reply)),
                Err(mpsc::TryRecvError::Empty) => None,
                // Every recorder handle is gone: write what is queued and close.
                Err(mpsc::TryRecvError::Disconnected) => Some(None),
            };
            self.drain(finish.is_some());
            if let Some(reply) = finish {
                let report = self.close();
                if let Some(reply) = reply {
                    let _ = reply.send(report);
                }
                // Later finish requests (from clones) get an empty report.
                while let Ok(Control::Finish(other)) = control.try_recv() {
                    let _ = other.send(Report::default());
                }
                return;
            }
            if last_flush.elapsed() >= Duration::from_secs(1) {
                last_flush = std::time::Instant::now();
                if let Some(w) = &self.writer
                    && let Err(e) = w.flush()
                {
                    if self.failure.failed.load(Ordering::Acquire) {
                        self.stop_file();
                    } else {
                        self.error.get_or_insert(e.to_string());
                    }
                }
            }
            // `finish` and bursts unpark the thread so that it need not wait for the tick.
            std::thread::park_timeout(tick);
        }
    }

    /// Take the callers' batch (swapping buffers under the lock) and write its records;
    /// `last`: the queue closes as it is taken.
    fn drain(&mut self, last: bool) {
        let whole = {
            let mut inner = self.inner.lock().unwrap_or_else(PoisonError::into_inner);
            std::mem::swap(&mut inner.batch.bytes, &mut self.drained);
            inner.batch.msgs = 0;
            inner.closed |= last;
            std::mem::take(&mut inner.batch.whole)
        };
        let drained = std::mem::take(&mut self.drained);
        for r in queue::records(drained.get(..whole).unwrap_or_default()) {
            self.write(r);
        }
        self.drained = drained;
        self.drained.clear();
        // After a burst, give back what a quiet robot never needs.
        if self.drained.capacity() > KEEP_BATCH {
            self.drained = Vec::with_capacity(INITIAL_BATCH);
        }
    }

    /// The stream `id`, fetched from the registry the first time.
    fn stream(&mut self, id: u32) -> Option<&mut WorkerStream> {
        let i = id as usize;
        if self.streams.get(i).is_none_or(Option::is_none) {
            let s = {
                let inner = self.inner.lock().unwrap_or_else(PoisonError::into_inner);
                Arc::clone(inner.streams.get(i)?)
            };
            let chan = match self.channels.get(&s.topic) {
                Some(c) => Some(Arc::clone(c)),
                None => {
                    let (schema, encoding, metadata) = s.proto.channel();
                    let built = (self.ctx.channel_builder(&*s.topic))
                        .schema(schema)
                        .message_encoding(encoding)
                        .metadata(metadata)
                        .build_raw();
                    match built {
                        Ok(c) => {
                            self.channels.insert(Arc::clone(&s.topic), Arc::clone(&c));
                            Some(c)
                        }
                        Err(e) => {
                            tracing::warn!("recorder: channel {}: {e}", s.topic);
                            None
                        }
                    }
                }
            };
            if self.streams.len() <= i {
                self.streams.resize_with(i + 1, || None);
            }
            *self.streams.get_mut(i)? = Some(WorkerStream {
                proto: s.proto.clone(),
                chan,
                counted: self.path.is_none() || !self.exclude.excludes(&s.topic),
                latch_depth: match &s.proto {
                    _ if self.latch.is_none() || !served(&s.topic) => 0,
                    stream::Proto::Text(_) => latch::LOG_DEPTH,
                    _ => 1,
                },
                topic: Arc::clone(&s.topic),
                written: 0,
            });
        }
        self.streams.get_mut(i)?.as_mut()
    }

    fn write(&mut self, r: queue::Record<'_>) {
        let mut buf = std::mem::take(&mut self.buf);
        // A file that failed counts nothing more (a live view alone counts what it was sent).
        let counting = self.path.is_none() || self.writer.is_some();
        let latch = self.latch.clone();
        if let Some(s) = self.stream(r.id)
            && let Some(chan) = &s.chan
            && s.proto
                .encode(r.kind, r.log_time, r.payload, &mut buf)
                .is_some()
        {
            match latch.as_deref() {
                Some(latch) if s.latch_depth > 0 => {
                    latch.log(chan, r.id, s.latch_depth, &buf, r.log_time);
                }
                _ => chan.log_with_meta(&buf, PartialMetadata::with_log_time(r.log_time)),
            }
            if s.counted && counting {
                s.written += 1;
            }
        } else {
            self.unwritten += 1;
        }
        self.buf = buf;
        if self.writer.is_some() && self.failure.failed.load(Ordering::Acquire) {
            self.stop_file();
        }
    }

    /// The file failed (disk full, device gone…): close its writer, which takes it off the
    /// channels (the writer would refuse, and the SDK warn about, every later message), keep
    /// the file's own first error for the report, and say so once. The robot goes on; a
    /// live view goes on.
    fn stop_file(&mut self) {
        if let Some(w) = self.writer.take() {
            // It fails again (the file cannot be written); the first error is the one to tell.
            let _ = w.close();
        }
        self.report_failure();
    }

    /// Say once, with the size written, that the file failed, and keep its first error.
    fn report_failure(&mut self) {
        if self.error.is_some() {
            return;
        }
        let bytes = (self.path.as_deref())
            .and_then(|p| std::fs::metadata(p).ok())
            .map_or(0, |m| m.len());
        let first = self
            .failure
            .first()
            .unwrap_or_else(|| "a write failed".into());
        let path = self.path.as_deref().unwrap_or(Path::new("?"));
        tracing::error!(
            "recording to {}: {first}; writing stopped after {} KiB (the messages of the chunk \
             being written are lost; `ima replay` reads the chunks before)",
            path.display(),
            bytes.div_ceil(1024)
        );
        self.error.get_or_insert(first);
    }

    fn close(&mut self) -> Report {
        if let Some(w) = self.writer.take()
            && let Err(e) = w.close()
        {
            if self.failure.failed.load(Ordering::Acquire) {
                // The file's own error (disk full…), said as when it comes earlier.
                self.report_failure();
            } else {
                self.error.get_or_insert(e.to_string());
            }
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
        let mut written = BTreeMap::new();
        for s in self.streams.iter().flatten().filter(|s| s.written > 0) {
            *written.entry(s.topic.to_string()).or_insert(0) += s.written;
        }
        // A file that failed lost the chunk being written (its messages were counted as they
        // went into it): say what the file holds.
        let mut uncounted = None;
        if let (Some(_), Some(path)) = (&self.error, &self.path) {
            if bytes > RECOUNT_LIMIT {
                uncounted = Some(format!(
                    "the file is over {} MiB, too large to read back",
                    RECOUNT_LIMIT >> 20
                ));
            } else {
                match read::Recording::open(path) {
                    Ok(r) => written = r.count_by_topic(),
                    Err(e) => uncounted = Some(format!("it could not be read back: {e}")),
                }
            }
        }
        Report {
            path: self.path.clone(),
            written,
            uncounted,
            dropped: 0,
            unwritten: self.unwritten,
            error: self.error.clone(),
            bytes,
            server_port: self.server_port,
            excluded: self.exclude.describe(),
            excluded_nothing: Vec::new(),
            thread_cpu: thread_cpu(),
            calls_time: Duration::ZERO,
        }
    }
}

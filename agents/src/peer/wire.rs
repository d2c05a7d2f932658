//! The Peer Agent's frame format and messages (byte tables in the [module docs](super)).
//!
//! * [`Signer`] seals a [`Msg`] into an authenticated frame.
//! * [`Verifier`] opens a frame: header, version, size limit, MAC, replay, body — each
//!   failure a distinct [`WireError`]. It never panics, whatever the bytes.
//! * [`frame_len`] tells a stream reader how long the next frame is (or that the header is
//!   already bad), so a TCP shell can cut frames without trusting more than the header.

use std::collections::BTreeMap;

use hmac::{Hmac, Mac};
use ima_hal::bytes::{Reader, Writer};
use sha2::Sha256;

type HmacSha256 = Hmac<Sha256>;

/// First two bytes of every frame: ASCII `"IP"` (Intelligent-machine Peer).
pub const MAGIC: [u8; 2] = *b"IP";
/// The only frame-format version this build speaks.
pub const VERSION: u8 = 1;
/// Header length: magic 2, version 1, type 1, body length 2, sender 8, counter 8.
pub const HEADER_LEN: usize = 22;
/// Length of the authentication tag (full HMAC-SHA-256 output).
pub const MAC_LEN: usize = 32;
/// Default limit on the body length; bigger frames are refused with [`WireError::Oversize`].
pub const DEFAULT_MAX_BODY: usize = 8192;
/// Length of a [`Ticket`].
pub const TICKET_LEN: usize = 32;
/// Minimum group-key length in bytes.
pub const MIN_KEY_LEN: usize = 16;
/// The longest string a frame carries (a name, a text), in bytes: its length is one byte.
/// Lists hold at most as many entries.
pub const MAX_STR_LEN: usize = u8::MAX as usize;
/// Default number of senders a [`Verifier`] remembers counters for.
pub const DEFAULT_MAX_SENDERS: usize = 256;

/// Why bytes could not be turned into a message (or a message into bytes).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WireError {
    /// Fewer bytes than the header or the declared frame needs.
    Truncated {
        /// Bytes needed.
        need: usize,
        /// Bytes present.
        got: usize,
    },
    /// The frame does not start with [`MAGIC`].
    BadMagic([u8; 2]),
    /// A frame-format version this build does not speak.
    BadVersion(u8),
    /// The declared body is longer than the configured limit.
    Oversize {
        /// Declared body length.
        len: usize,
        /// Configured limit.
        max: usize,
    },
    /// The authentication tag does not match (wrong key, or the frame was altered).
    BadMac,
    /// The counter is not above the last one accepted from this sender.
    Replay {
        /// Sender field of the frame.
        sender: u64,
        /// Last counter accepted from it.
        last: u64,
        /// Counter of this frame.
        got: u64,
    },
    /// Bytes after the end of the declared frame.
    TrailingBytes(usize),
    /// A message type this build does not know.
    UnknownType(u8),
    /// The body of a known type is malformed.
    Body(BodyError),
    /// The output buffer is too small (emit side).
    BufferTooSmall,
    /// A string, list or payload is too long to encode (emit side).
    FieldTooLong,
}

/// What is wrong inside a body.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BodyError {
    /// The body ends inside a field.
    Truncated,
    /// A string is not UTF-8.
    BadUtf8,
    /// An enumeration code this build does not know.
    BadCode(u8),
    /// Bytes left over after the last field.
    TrailingBytes(usize),
}

impl From<BodyError> for WireError {
    fn from(e: BodyError) -> Self {
        WireError::Body(e)
    }
}

impl core::fmt::Display for WireError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Truncated { need, got } => {
                write!(f, "truncated frame: {got} bytes where {need} are needed")
            }
            Self::BadMagic([a, b]) => write!(
                f,
                "not a Peer frame: it starts {a:02x} {b:02x}, not {:02x} {:02x} (\"IP\")",
                MAGIC[0], MAGIC[1]
            ),
            Self::BadVersion(v) => write!(
                f,
                "frame-format version {v}, which this build does not speak (it speaks \
                 {VERSION})"
            ),
            Self::Oversize { len, max } => {
                write!(f, "a body of {len} bytes, over the limit of {max}")
            }
            Self::BadMac => f.write_str(
                "the authentication tag does not match (another group key, or the frame was \
                 altered)",
            ),
            Self::Replay { sender, last, got } => write!(
                f,
                "a replayed or reordered frame: counter {got} from sender {sender:#018x} is not \
                 above its last accepted counter {last}"
            ),
            Self::TrailingBytes(n) => write!(f, "{n} bytes after the end of the frame"),
            Self::UnknownType(t) => write!(f, "message type {t}, which this build does not know"),
            Self::Body(e) => write!(f, "a malformed body: {e}"),
            Self::BufferTooSmall => f.write_str("the frame does not fit the output buffer"),
            Self::FieldTooLong => write!(
                f,
                "a field too long to encode (a name, text or list: at most {MAX_STR_LEN} bytes \
                 or entries; a sample's payload and a whole body: at most 65,535 bytes)"
            ),
        }
    }
}

impl core::fmt::Display for BodyError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Truncated => f.write_str("it ends inside a field"),
            Self::BadUtf8 => f.write_str("a string is not UTF-8"),
            Self::BadCode(c) => write!(f, "code {c}, which this build does not know"),
            Self::TrailingBytes(n) => write!(f, "{n} bytes after its last field"),
        }
    }
}

impl std::error::Error for WireError {}

/// The shared group key (from config or a key file; never from the command line).
#[derive(Clone)]
pub struct GroupKey(Vec<u8>);

impl GroupKey {
    /// A key of at least [`MIN_KEY_LEN`] bytes, or `None`.
    #[must_use]
    pub fn new(bytes: &[u8]) -> Option<Self> {
        (bytes.len() >= MIN_KEY_LEN).then(|| Self(bytes.to_vec()))
    }

    /// A 32-byte key (always long enough).
    #[must_use]
    pub fn from_array(bytes: [u8; 32]) -> Self {
        Self(bytes.to_vec())
    }

    /// Whether every byte is zero: the documented insecure key
    /// ([`crate::peer::net::INSECURE_KEY`] with feature `net`), under which anyone can forge
    /// frames — also when it comes from a key file.
    #[must_use]
    pub fn is_insecure(&self) -> bool {
        self.0.iter().all(|b| *b == 0)
    }

    fn mac(&self) -> HmacSha256 {
        // HMAC accepts keys of any length; `new_from_slice` cannot fail for HMAC.
        match HmacSha256::new_from_slice(&self.0) {
            Ok(m) => m,
            Err(_) => HmacSha256::new(&Default::default()),
        }
    }
}

impl core::fmt::Debug for GroupKey {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("GroupKey(..)")
    }
}

/// An opaque data-session ticket: nonce (8) ‖ expiry µs (8) ‖ truncated HMAC (16),
/// computed by the manager with its private ticket key (see [`super::manager`]).
pub type Ticket = [u8; TICKET_LEN];

/// One data source of the robot (an entry of the competency list).
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct SourceInfo {
    /// Unique name, e.g. `"front-sonar"`.
    pub name: String,
    /// Kind: `ses`, `sonar`, `laser`, `odometry`, `heading`, `status`, …
    pub kind: String,
    /// Schema version of the samples.
    pub schema: u16,
    /// Nominal rate in millihertz (10 Hz = 10 000).
    pub rate_mhz: u32,
}

impl SourceInfo {
    /// A source description; `rate_hz` is stored in millihertz (saturating).
    #[must_use]
    pub fn new(name: &str, kind: &str, schema: u16, rate_hz: f64) -> Self {
        Self {
            name: name.to_owned(),
            kind: kind.to_owned(),
            schema,
            rate_mhz: (rate_hz * 1000.0).clamp(0.0, f64::from(u32::MAX)) as u32,
        }
    }
}

/// Why a registration was declined.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DeclineReason {
    /// Another registered client holds this ID; pick another and retry.
    DuplicateId = 1,
    /// The manager serves its maximum number of clients.
    Full = 2,
}

/// Why a request was denied.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DenyReason {
    /// The client ID is not registered on this session.
    NotRegistered = 1,
    /// No such source.
    UnknownSource = 2,
    /// The pending queue is full.
    QueueFull = 3,
}

impl core::fmt::Display for DeclineReason {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::DuplicateId => "another client holds this client ID",
            Self::Full => "the manager serves its maximum number of clients",
        })
    }
}

impl core::fmt::Display for DenyReason {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::NotRegistered => "this client is not registered with the manager",
            Self::UnknownSource => "the manager has no such source",
            Self::QueueFull => "the manager's queue of pending requests is full",
        })
    }
}

impl core::fmt::Display for RevokeReason {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::TaskPriority => "the source robot's task priority rose above the request's",
            Self::SourceGone => "the source is gone",
            Self::Shutdown => "the manager is shutting down",
            Self::BadTicket => "the ticket is invalid, expired or revoked",
        })
    }
}

/// Why a grant was revoked (or a data session closed).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RevokeReason {
    /// The source robot's task priority rose above the request's priority; the request is
    /// pending again.
    TaskPriority = 1,
    /// The source disappeared.
    SourceGone = 2,
    /// The manager is shutting down.
    Shutdown = 3,
    /// The ticket is invalid, expired or revoked (data session).
    BadTicket = 4,
}

/// A mission event on the broadcast channel.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MissionEvent {
    /// A target was accepted.
    Accepted = 1,
    /// A target was accomplished.
    Accomplished = 2,
    /// A target failed.
    Failed = 3,
}

impl MissionEvent {
    /// The lower-case name: `accepted`, `accomplished`, `failed`.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            MissionEvent::Accepted => "accepted",
            MissionEvent::Accomplished => "accomplished",
            MissionEvent::Failed => "failed",
        }
    }
}

/// A pose in fixed point (millimetres, milliradians), so frames round-trip exactly.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Pose {
    /// x in mm.
    pub x_mm: i32,
    /// y in mm.
    pub y_mm: i32,
    /// Heading in mrad.
    pub theta_mrad: i32,
}

/// Every message of every channel. Type codes are in the [module docs](super).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Msg {
    /// 0x01 client → manager: register `client` for robot `robot`.
    Register {
        /// Client ID generated by the client.
        client: u64,
        /// Name of the client's robot (decides the robot priority).
        robot: String,
    },
    /// 0x02 client → manager.
    Unregister {
        /// Client ID.
        client: u64,
    },
    /// 0x03 client → manager: request (or renew the request for) `source`.
    Request {
        /// Client ID.
        client: u64,
        /// Source name.
        source: String,
        /// The request's own priority.
        priority: u8,
    },
    /// 0x04 client → manager: end the request or grant for `source`.
    Disconnect {
        /// Client ID.
        client: u64,
        /// Source name.
        source: String,
    },
    /// 0x05 both ways, every channel: liveness.
    Heartbeat,
    /// 0x10 manager → client: registration accepted, with the competency list.
    Registered {
        /// Client ID.
        client: u64,
        /// The robot's data sources.
        sources: Vec<SourceInfo>,
    },
    /// 0x11 manager → client: registration declined.
    Declined {
        /// The declined ID.
        client: u64,
        /// Why.
        reason: DeclineReason,
    },
    /// 0x12 manager → client: unregistration done.
    Unregistered {
        /// Client ID.
        client: u64,
    },
    /// 0x13 manager → client: request granted.
    Granted {
        /// Client ID.
        client: u64,
        /// Source name.
        source: String,
        /// Address of the data server (`host:port`).
        address: String,
        /// Ticket to present on the data session.
        ticket: Ticket,
    },
    /// 0x14 manager → client: request queued (the source's task outranks it, or the
    /// source is at capacity).
    Pending {
        /// Client ID.
        client: u64,
        /// Source name.
        source: String,
    },
    /// 0x15 manager → client: request denied.
    Denied {
        /// Client ID.
        client: u64,
        /// Source name.
        source: String,
        /// Why.
        reason: DenyReason,
    },
    /// 0x16 manager → client: a grant was revoked.
    Revoked {
        /// Client ID.
        client: u64,
        /// Source name.
        source: String,
        /// Why.
        reason: RevokeReason,
    },
    /// 0x17 manager → every registered client: sources added and removed by a re-scan.
    SourcesChanged {
        /// New sources (or sources whose description changed).
        added: Vec<SourceInfo>,
        /// Names of removed sources.
        removed: Vec<String>,
    },
    /// 0x20 client → data server: open a data session.
    OpenData {
        /// Client ID.
        client: u64,
        /// Source name.
        source: String,
        /// Ticket from the grant.
        ticket: Ticket,
    },
    /// 0x21 data server → client: the session is open.
    DataAccepted {
        /// Source name.
        source: String,
    },
    /// 0x22 data server → client: the session is refused or ended.
    DataClosed {
        /// Source name.
        source: String,
        /// Why.
        reason: RevokeReason,
    },
    /// 0x23 data server → client: one sample.
    Sample {
        /// Per-session sample sequence number (gaps = samples dropped by latest-value
        /// queueing).
        seq: u64,
        /// When the sample was measured, µs on the source's clock.
        stamp_us: u64,
        /// The sample's bytes (schema per [`SourceInfo::kind`] and `schema`).
        payload: Vec<u8>,
    },
    /// 0x30 broadcast: robot status.
    Status {
        /// Sender robot.
        robot: String,
        /// Per-sender sequence number.
        seq: u64,
        /// Current behaviour.
        behaviour: String,
        /// SAN state summary.
        san: String,
        /// Pose, if known.
        pose: Option<Pose>,
    },
    /// 0x31 broadcast: emergency (e.g. kind `scooter-lost`).
    Emergency {
        /// Sender robot.
        robot: String,
        /// Per-sender sequence number.
        seq: u64,
        /// Machine-readable kind.
        kind: String,
        /// Human-readable text.
        text: String,
    },
    /// 0x32 broadcast: mission event.
    Mission {
        /// Sender robot.
        robot: String,
        /// Per-sender sequence number.
        seq: u64,
        /// What happened.
        event: MissionEvent,
        /// The target, e.g. `"red"`.
        target: String,
    },
}

impl Msg {
    /// The type code of this message.
    #[must_use]
    pub fn code(&self) -> u8 {
        match self {
            Msg::Register { .. } => 0x01,
            Msg::Unregister { .. } => 0x02,
            Msg::Request { .. } => 0x03,
            Msg::Disconnect { .. } => 0x04,
            Msg::Heartbeat => 0x05,
            Msg::Registered { .. } => 0x10,
            Msg::Declined { .. } => 0x11,
            Msg::Unregistered { .. } => 0x12,
            Msg::Granted { .. } => 0x13,
            Msg::Pending { .. } => 0x14,
            Msg::Denied { .. } => 0x15,
            Msg::Revoked { .. } => 0x16,
            Msg::SourcesChanged { .. } => 0x17,
            Msg::OpenData { .. } => 0x20,
            Msg::DataAccepted { .. } => 0x21,
            Msg::DataClosed { .. } => 0x22,
            Msg::Sample { .. } => 0x23,
            Msg::Status { .. } => 0x30,
            Msg::Emergency { .. } => 0x31,
            Msg::Mission { .. } => 0x32,
        }
    }

    /// Encodes the body (no header, no MAC) into `out`; returns its length.
    ///
    /// # Errors
    /// [`WireError::BufferTooSmall`], [`WireError::FieldTooLong`].
    pub fn emit_body(&self, out: &mut [u8]) -> Result<usize, WireError> {
        let mut w = Writer::new(out);
        match self {
            Msg::Register { client, robot } => {
                w.le(*client)?;
                w.str(robot)?;
            }
            Msg::Unregister { client } | Msg::Unregistered { client } => {
                w.le(*client)?;
            }
            Msg::Request {
                client,
                source,
                priority,
            } => {
                w.le(*client)?;
                w.str(source)?;
                w.u8(*priority)?;
            }
            Msg::Disconnect { client, source } | Msg::Pending { client, source } => {
                w.le(*client)?;
                w.str(source)?;
            }
            Msg::Heartbeat => {}
            Msg::Registered { client, sources } => {
                w.le(*client)?;
                w.sources(sources)?;
            }
            Msg::Declined { client, reason } => {
                w.le(*client)?;
                w.u8(*reason as u8)?;
            }
            Msg::Granted {
                client,
                source,
                address,
                ticket,
            } => {
                w.le(*client)?;
                w.str(source)?;
                w.str(address)?;
                w.bytes(ticket)?;
            }
            Msg::Denied {
                client,
                source,
                reason,
            } => {
                w.le(*client)?;
                w.str(source)?;
                w.u8(*reason as u8)?;
            }
            Msg::Revoked {
                client,
                source,
                reason,
            } => {
                w.le(*client)?;
                w.str(source)?;
                w.u8(*reason as u8)?;
            }
            Msg::SourcesChanged { added, removed } => {
                w.sources(added)?;
                w.count(removed.len())?;
                for r in removed {
                    w.str(r)?;
                }
            }
            Msg::OpenData {
                client,
                source,
                ticket,
            } => {
                w.le(*client)?;
                w.str(source)?;
                w.bytes(ticket)?;
            }
            Msg::DataAccepted { source } => {
                w.str(source)?;
            }
            Msg::DataClosed { source, reason } => {
                w.str(source)?;
                w.u8(*reason as u8)?;
            }
            Msg::Sample {
                seq,
                stamp_us,
                payload,
            } => {
                w.le(*seq)?;
                w.le(*stamp_us)?;
                let n = u16::try_from(payload.len()).map_err(|_| WireError::FieldTooLong)?;
                w.le(n)?;
                w.bytes(payload)?;
            }
            Msg::Status {
                robot,
                seq,
                behaviour,
                san,
                pose,
            } => {
                w.str(robot)?;
                w.le(*seq)?;
                w.str(behaviour)?;
                w.str(san)?;
                match pose {
                    None => {
                        w.u8(0)?;
                    }
                    Some(p) => {
                        w.u8(1)?;
                        w.le(p.x_mm)?;
                        w.le(p.y_mm)?;
                        w.le(p.theta_mrad)?;
                    }
                }
            }
            Msg::Emergency {
                robot,
                seq,
                kind,
                text,
            } => {
                w.str(robot)?;
                w.le(*seq)?;
                w.str(kind)?;
                w.str(text)?;
            }
            Msg::Mission {
                robot,
                seq,
                event,
                target,
            } => {
                w.str(robot)?;
                w.le(*seq)?;
                w.u8(*event as u8)?;
                w.str(target)?;
            }
        }
        Ok(w.pos())
    }

    /// Decodes a body of type `code`. Never panics.
    ///
    /// # Errors
    /// [`WireError::UnknownType`] or [`WireError::Body`].
    pub fn parse_body(code: u8, body: &[u8]) -> Result<Msg, WireError> {
        let mut r = Reader::new(body);
        let msg = match code {
            0x01 => Msg::Register {
                client: r.le()?,
                robot: r.str()?,
            },
            0x02 => Msg::Unregister { client: r.le()? },
            0x03 => Msg::Request {
                client: r.le()?,
                source: r.str()?,
                priority: r.u8()?,
            },
            0x04 => Msg::Disconnect {
                client: r.le()?,
                source: r.str()?,
            },
            0x05 => Msg::Heartbeat,
            0x10 => Msg::Registered {
                client: r.le()?,
                sources: r.sources()?,
            },
            0x11 => Msg::Declined {
                client: r.le()?,
                reason: match r.u8()? {
                    1 => DeclineReason::DuplicateId,
                    2 => DeclineReason::Full,
                    c => return Err(BodyError::BadCode(c).into()),
                },
            },
            0x12 => Msg::Unregistered { client: r.le()? },
            0x13 => Msg::Granted {
                client: r.le()?,
                source: r.str()?,
                address: r.str()?,
                ticket: r.array()?,
            },
            0x14 => Msg::Pending {
                client: r.le()?,
                source: r.str()?,
            },
            0x15 => Msg::Denied {
                client: r.le()?,
                source: r.str()?,
                reason: match r.u8()? {
                    1 => DenyReason::NotRegistered,
                    2 => DenyReason::UnknownSource,
                    3 => DenyReason::QueueFull,
                    c => return Err(BodyError::BadCode(c).into()),
                },
            },
            0x16 => Msg::Revoked {
                client: r.le()?,
                source: r.str()?,
                reason: r.revoke()?,
            },
            0x17 => {
                let added = r.sources()?;
                let n = r.u8()?;
                let mut removed = Vec::with_capacity(usize::from(n));
                for _ in 0..n {
                    removed.push(r.str()?);
                }
                Msg::SourcesChanged { added, removed }
            }
            0x20 => Msg::OpenData {
                client: r.le()?,
                source: r.str()?,
                ticket: r.array()?,
            },
            0x21 => Msg::DataAccepted { source: r.str()? },
            0x22 => Msg::DataClosed {
                source: r.str()?,
                reason: r.revoke()?,
            },
            0x23 => {
                let seq = r.le()?;
                let stamp_us = r.le()?;
                let n = r.le::<u16>()?;
                Msg::Sample {
                    seq,
                    stamp_us,
                    payload: r.take(usize::from(n))?.to_vec(),
                }
            }
            0x30 => Msg::Status {
                robot: r.str()?,
                seq: r.le()?,
                behaviour: r.str()?,
                san: r.str()?,
                pose: match r.u8()? {
                    0 => None,
                    1 => Some(Pose {
                        x_mm: r.le::<i32>()?,
                        y_mm: r.le::<i32>()?,
                        theta_mrad: r.le::<i32>()?,
                    }),
                    c => return Err(BodyError::BadCode(c).into()),
                },
            },
            0x31 => Msg::Emergency {
                robot: r.str()?,
                seq: r.le()?,
                kind: r.str()?,
                text: r.str()?,
            },
            0x32 => Msg::Mission {
                robot: r.str()?,
                seq: r.le()?,
                event: match r.u8()? {
                    1 => MissionEvent::Accepted,
                    2 => MissionEvent::Accomplished,
                    3 => MissionEvent::Failed,
                    c => return Err(BodyError::BadCode(c).into()),
                },
                target: r.str()?,
            },
            c => return Err(WireError::UnknownType(c)),
        };
        if r.is_empty() {
            Ok(msg)
        } else {
            Err(BodyError::TrailingBytes(r.remaining()).into())
        }
    }
}

ima_hal::cursor_errors!(WireError {
    truncated: |_| WireError::Body(BodyError::Truncated),
    overflow: |_| WireError::BufferTooSmall,
});
ima_hal::cursor_errors!(BodyError {
    truncated: |_| BodyError::Truncated
});

/// The peer protocol's composite fields, written with the shared byte cursor.
trait WriteFields {
    /// A count that must fit in one byte.
    fn count(&mut self, n: usize) -> Result<(), WireError>;
    /// A string with a one-byte length.
    fn str(&mut self, s: &str) -> Result<(), WireError>;
    /// A source list.
    fn sources(&mut self, list: &[SourceInfo]) -> Result<(), WireError>;
}

impl WriteFields for Writer<'_> {
    fn count(&mut self, n: usize) -> Result<(), WireError> {
        self.u8(u8::try_from(n).map_err(|_| WireError::FieldTooLong)?)?;
        Ok(())
    }
    fn str(&mut self, s: &str) -> Result<(), WireError> {
        self.count(s.len())?;
        self.bytes(s.as_bytes())?;
        Ok(())
    }
    fn sources(&mut self, list: &[SourceInfo]) -> Result<(), WireError> {
        self.count(list.len())?;
        for s in list {
            self.str(&s.name)?;
            self.str(&s.kind)?;
            self.le(s.schema)?.le(s.rate_mhz)?;
        }
        Ok(())
    }
}

/// The peer protocol's composite fields, read with the shared byte cursor.
trait ReadFields {
    /// A string with a one-byte length.
    fn str(&mut self) -> Result<String, BodyError>;
    /// A revocation reason.
    fn revoke(&mut self) -> Result<RevokeReason, BodyError>;
    /// A source list.
    fn sources(&mut self) -> Result<Vec<SourceInfo>, BodyError>;
}

impl ReadFields for Reader<'_> {
    fn str(&mut self) -> Result<String, BodyError> {
        let n = self.u8()?;
        let b = self.take(usize::from(n))?;
        core::str::from_utf8(b)
            .map(str::to_owned)
            .map_err(|_| BodyError::BadUtf8)
    }
    fn revoke(&mut self) -> Result<RevokeReason, BodyError> {
        match self.u8()? {
            1 => Ok(RevokeReason::TaskPriority),
            2 => Ok(RevokeReason::SourceGone),
            3 => Ok(RevokeReason::Shutdown),
            4 => Ok(RevokeReason::BadTicket),
            c => Err(BodyError::BadCode(c)),
        }
    }
    fn sources(&mut self) -> Result<Vec<SourceInfo>, BodyError> {
        let n = self.u8()?;
        let mut v = Vec::with_capacity(usize::from(n));
        for _ in 0..n {
            v.push(SourceInfo {
                name: self.str()?,
                kind: self.str()?,
                schema: self.le()?,
                rate_mhz: self.le()?,
            });
        }
        Ok(v)
    }
}

/// The parsed header of a frame (before the MAC is checked).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Header {
    /// Message type code.
    pub code: u8,
    /// Body length.
    pub body_len: usize,
    /// Sender ID (namespace of the counter).
    pub sender: u64,
    /// Per-sender monotonic counter.
    pub counter: u64,
}

impl Header {
    /// Total frame length: header + body + MAC.
    #[must_use]
    pub fn frame_len(&self) -> usize {
        HEADER_LEN + self.body_len + MAC_LEN
    }
}

/// Parses the header at the start of `bytes` and checks magic, version and size limit.
///
/// # Errors
/// [`WireError::Truncated`] (fewer than [`HEADER_LEN`] bytes), [`WireError::BadMagic`],
/// [`WireError::BadVersion`], [`WireError::Oversize`].
pub fn parse_header(bytes: &[u8], max_body: usize) -> Result<Header, WireError> {
    let (head, _) = bytes
        .split_at_checked(HEADER_LEN)
        .ok_or(WireError::Truncated {
            need: HEADER_LEN,
            got: bytes.len(),
        })?;
    let mut r = Reader::new(head);
    let trunc = |_| WireError::Truncated {
        need: HEADER_LEN,
        got: bytes.len(),
    };
    let magic: [u8; 2] = r.array().map_err(trunc)?;
    if magic != MAGIC {
        return Err(WireError::BadMagic(magic));
    }
    let version = r.u8().map_err(trunc)?;
    if version != VERSION {
        return Err(WireError::BadVersion(version));
    }
    let code = r.u8().map_err(trunc)?;
    let body_len = usize::from(r.le::<u16>().map_err(trunc)?);
    if body_len > max_body {
        return Err(WireError::Oversize {
            len: body_len,
            max: max_body,
        });
    }
    let sender = r.le::<u64>().map_err(trunc)?;
    let counter = r.le::<u64>().map_err(trunc)?;
    Ok(Header {
        code,
        body_len,
        sender,
        counter,
    })
}

/// For a stream reader: `Ok(None)` while fewer than [`HEADER_LEN`] bytes are buffered,
/// `Ok(Some(n))` with the full length of the next frame once the header is in, or the
/// header's error (a session that sees one is closed, so no resynchronisation is needed).
///
/// # Errors
/// As [`parse_header`], except that a short buffer is `Ok(None)`.
pub fn frame_len(buffered: &[u8], max_body: usize) -> Result<Option<usize>, WireError> {
    if buffered.len() < HEADER_LEN {
        return Ok(None);
    }
    parse_header(buffered, max_body).map(|h| Some(h.frame_len()))
}

/// Seals messages into frames for one sender.
#[derive(Debug, Clone)]
pub struct Signer {
    key: GroupKey,
    sender: u64,
    counter: u64,
}

impl Signer {
    /// A signer for `sender` whose first frame carries `first_counter`. A shell should start
    /// from a clock value that grows across restarts (e.g. µs since the UNIX epoch), so a
    /// restarted sender is not taken for a replayer.
    #[must_use]
    pub fn new(key: GroupKey, sender: u64, first_counter: u64) -> Self {
        Self {
            key,
            sender,
            counter: first_counter,
        }
    }

    /// The sender ID.
    #[must_use]
    pub fn sender(&self) -> u64 {
        self.sender
    }

    /// The counter the next frame will carry.
    #[must_use]
    pub fn next_counter(&self) -> u64 {
        self.counter
    }

    /// Moves the next counter up to `counter` (never down). A shell whose counters are
    /// clock values calls this with the current clock before sealing, so that a receiver
    /// that never heard this sender finds a counter close to its own clock (see
    /// [`Verifier::set_first_counter_window`]).
    pub fn advance_to(&mut self, counter: u64) {
        self.counter = self.counter.max(counter);
    }

    /// Writes `msg` as one authenticated frame into `out`; returns the frame length. The
    /// counter advances only on success.
    ///
    /// # Errors
    /// [`WireError::BufferTooSmall`], [`WireError::FieldTooLong`] (incl. a body over 65 535
    /// bytes).
    pub fn seal(&mut self, msg: &Msg, out: &mut [u8]) -> Result<usize, WireError> {
        let body_out = out.get_mut(HEADER_LEN..).ok_or(WireError::BufferTooSmall)?;
        let body_len = msg.emit_body(body_out)?;
        let body_len16 = u16::try_from(body_len).map_err(|_| WireError::FieldTooLong)?;
        let total = HEADER_LEN + body_len + MAC_LEN;
        let frame = out.get_mut(..total).ok_or(WireError::BufferTooSmall)?;
        let mut w = Writer::new(frame);
        w.bytes(&MAGIC)?;
        w.u8(VERSION)?;
        w.u8(msg.code())?;
        w.le(body_len16)?;
        w.le(self.sender)?;
        w.le(self.counter)?;
        let signed = HEADER_LEN + body_len;
        let (data, tag) = frame.split_at_mut(signed);
        let mut mac = self.key.mac();
        mac.update(data);
        tag.copy_from_slice(&mac.finalize().into_bytes());
        self.counter = self.counter.wrapping_add(1);
        Ok(total)
    }

    /// Convenience: seals into a new `Vec`.
    ///
    /// # Errors
    /// As [`Signer::seal`].
    pub fn seal_vec(&mut self, msg: &Msg) -> Result<Vec<u8>, WireError> {
        let mut buf = vec![0u8; HEADER_LEN + MAC_LEN + u16::MAX as usize];
        let n = self.seal(msg, &mut buf)?;
        buf.truncate(n);
        Ok(buf)
    }
}

/// An opened frame.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Opened {
    /// Sender ID.
    pub sender: u64,
    /// Its counter.
    pub counter: u64,
    /// The message.
    pub msg: Msg,
}

/// Counters of rejected frames, one per [`WireError`] class.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RejectCounts {
    /// [`WireError::Truncated`] and [`WireError::TrailingBytes`].
    pub truncated: u64,
    /// [`WireError::BadMagic`].
    pub bad_magic: u64,
    /// [`WireError::BadVersion`].
    pub bad_version: u64,
    /// [`WireError::Oversize`].
    pub oversize: u64,
    /// [`WireError::BadMac`].
    pub bad_mac: u64,
    /// [`WireError::Replay`].
    pub replay: u64,
    /// [`WireError::UnknownType`] and [`WireError::Body`].
    pub malformed: u64,
}

impl RejectCounts {
    /// Counts one error.
    pub fn count(&mut self, e: WireError) {
        let c = match e {
            WireError::Truncated { .. } | WireError::TrailingBytes(_) => &mut self.truncated,
            WireError::BadMagic(_) => &mut self.bad_magic,
            WireError::BadVersion(_) => &mut self.bad_version,
            WireError::Oversize { .. } => &mut self.oversize,
            WireError::BadMac => &mut self.bad_mac,
            WireError::Replay { .. } => &mut self.replay,
            WireError::UnknownType(_)
            | WireError::Body(_)
            | WireError::BufferTooSmall
            | WireError::FieldTooLong => &mut self.malformed,
        };
        *c = c.saturating_add(1);
    }
}

/// Opens frames: checks header, size, MAC and replay, then parses the body. Remembers the
/// last counter of up to `max_senders` senders (when full, the sender heard longest ago is
/// forgotten; on a TCP session there is only one sender).
#[derive(Debug, Clone)]
pub struct Verifier {
    key: GroupKey,
    max_body: usize,
    max_senders: usize,
    /// sender → (last counter, order of last acceptance)
    last: BTreeMap<u64, (u64, u64)>,
    tick: u64,
    /// Bounds (inclusive) of the first counter accepted from an unknown sender.
    first_window: Option<(u64, u64)>,
    /// Rejected frames by class.
    pub rejects: RejectCounts,
}

impl Verifier {
    /// A verifier with [`DEFAULT_MAX_BODY`] and [`DEFAULT_MAX_SENDERS`].
    #[must_use]
    pub fn new(key: GroupKey) -> Self {
        Self::with_limits(key, DEFAULT_MAX_BODY, DEFAULT_MAX_SENDERS)
    }

    /// A verifier with explicit limits (`max_senders` at least 1).
    #[must_use]
    pub fn with_limits(key: GroupKey, max_body: usize, max_senders: usize) -> Self {
        Self {
            key,
            max_body,
            max_senders: max_senders.max(1),
            last: BTreeMap::new(),
            tick: 0,
            first_window: None,
            rejects: RejectCounts::default(),
        }
    }

    /// Whether a counter of `sender` is remembered.
    #[must_use]
    pub fn knows(&self, sender: u64) -> bool {
        self.last.contains_key(&sender)
    }

    /// Bounds (inclusive) for the first counter of a sender this verifier does not
    /// remember; `None` (the default) accepts any. A shell whose counters are clock values
    /// passes `now ± skew` here before opening frames, so that a frame recorded before a
    /// restart (when the verifier forgot every sender) is refused as a
    /// [`WireError::Replay`]. The verifier itself stays clock-free.
    pub fn set_first_counter_window(&mut self, window: Option<(u64, u64)>) {
        self.first_window = window;
    }

    /// The body-size limit.
    #[must_use]
    pub fn max_body(&self) -> usize {
        self.max_body
    }

    /// Opens exactly one frame. Order of checks: header (truncation, magic, version, size),
    /// frame length, MAC, replay, body. Only a frame that passes every check advances the
    /// sender's counter. Every error is also counted in [`Verifier::rejects`].
    ///
    /// # Errors
    /// Every [`WireError`] class except the emit-side ones.
    pub fn open(&mut self, frame: &[u8]) -> Result<Opened, WireError> {
        let r = self.open_inner(frame);
        if let Err(e) = r {
            self.rejects.count(e);
        }
        r
    }

    fn open_inner(&mut self, frame: &[u8]) -> Result<Opened, WireError> {
        let h = parse_header(frame, self.max_body)?;
        let total = h.frame_len();
        if frame.len() < total {
            return Err(WireError::Truncated {
                need: total,
                got: frame.len(),
            });
        }
        if frame.len() > total {
            return Err(WireError::TrailingBytes(frame.len() - total));
        }
        let (data, tag) = frame.split_at(HEADER_LEN + h.body_len);
        let mut mac = self.key.mac();
        mac.update(data);
        mac.verify_slice(tag).map_err(|_| WireError::BadMac)?;
        match self.last.get(&h.sender) {
            Some(&(last, _)) if h.counter <= last => {
                return Err(WireError::Replay {
                    sender: h.sender,
                    last,
                    got: h.counter,
                });
            }
            None => {
                if let Some((lo, hi)) = self.first_window
                    && (h.counter < lo || h.counter > hi)
                {
                    return Err(WireError::Replay {
                        sender: h.sender,
                        last: if h.counter < lo { lo } else { hi },
                        got: h.counter,
                    });
                }
            }
            Some(_) => {}
        }
        let body = data.get(HEADER_LEN..).unwrap_or_default();
        let msg = Msg::parse_body(h.code, body)?;
        self.remember(h.sender, h.counter);
        Ok(Opened {
            sender: h.sender,
            counter: h.counter,
            msg,
        })
    }

    fn remember(&mut self, sender: u64, counter: u64) {
        self.tick = self.tick.wrapping_add(1);
        if !self.last.contains_key(&sender) && self.last.len() >= self.max_senders {
            let oldest = self
                .last
                .iter()
                .min_by_key(|(_, (_, t))| *t)
                .map(|(s, _)| *s);
            if let Some(s) = oldest {
                self.last.remove(&s);
            }
        }
        self.last.insert(sender, (counter, self.tick));
    }
}

/// Parses a frame without checking the MAC or replay (for logs and the fuzz round trip).
///
/// # Errors
/// As [`Verifier::open`] minus [`WireError::BadMac`] and [`WireError::Replay`].
pub fn parse_unauthenticated(frame: &[u8], max_body: usize) -> Result<Opened, WireError> {
    let h = parse_header(frame, max_body)?;
    let total = h.frame_len();
    if frame.len() < total {
        return Err(WireError::Truncated {
            need: total,
            got: frame.len(),
        });
    }
    if frame.len() > total {
        return Err(WireError::TrailingBytes(frame.len() - total));
    }
    let body = frame
        .get(HEADER_LEN..HEADER_LEN + h.body_len)
        .unwrap_or_default();
    Ok(Opened {
        sender: h.sender,
        counter: h.counter,
        msg: Msg::parse_body(h.code, body)?,
    })
}

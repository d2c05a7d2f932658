//! Frames over TCP: a tiny request/response protocol that lets one process own a frame
//! grabber (the mock camera head of `ima mock world`, or a real grabber's server) and other
//! processes grab frames from it. The sans-IO part ([`Request`], [`Header`]) is here under
//! feature `std`; the client `NetFrames`, an [`ima_hal::camera::FrameSource`], needs feature
//! `tokio`.
//!
//! # Protocol (version 1)
//!
//! One TCP connection carries any number of request/response pairs, strictly in turn.
//! All integers are big-endian.
//!
//! **Request** — 6 bytes: magic `IMAF` (`49 4D 41 46`), version `01`, operation `01` (grab
//! the next frame the grabber exposes on the currently selected channel).
//!
//! **Response** — a 36-byte header, then `length` bytes of payload:
//!
//! | offset | size | field |
//! |-------:|-----:|-------|
//! | 0 | 4 | magic `IMAF` |
//! | 4 | 1 | version `01` |
//! | 5 | 1 | status: `0` ok, `1` no camera selected, `2` bad channel, `3` other error |
//! | 6 | 1 | channel of the frame (`0`: unknown/none) |
//! | 7 | 1 | reserved, `0` |
//! | 8 | 4 | width, pixels |
//! | 12 | 4 | height, pixels |
//! | 16 | 8 | exposure stamp, µs on the server's clock |
//! | 24 | 8 | send stamp, µs on the server's clock (when the header was written) |
//! | 32 | 4 | payload length: `width·height·3` when status is `0`, else `0` |
//!
//! The payload is the frame's RGB bytes, row-major from the top-left pixel, 3 bytes per pixel.
//!
//! Clocks are not shared: the client stamps a frame with its own clock at reception minus the
//! frame's age on the server (`send − exposure`), which is exact up to the transfer time.
//!
//! Limits: width and height at most [`MAX_SIDE`], so a hostile header cannot make the client
//! allocate more than `MAX_SIDE² · 3` bytes. A malformed header or request closes the
//! connection (the client reconnects on its next grab).

use ima_hal::ErrorKind;

/// The magic at the start of requests and headers.
pub const MAGIC: [u8; 4] = *b"IMAF";
/// Protocol version.
pub const VERSION: u8 = 1;
/// The only operation: grab a frame.
pub const OP_GRAB: u8 = 1;
/// Size of a request, bytes.
pub const REQUEST_LEN: usize = 6;
/// Size of a response header, bytes.
pub const HEADER_LEN: usize = 36;
/// Largest width or height accepted.
pub const MAX_SIDE: u32 = 4096;

/// A request (only [`Request::Grab`] exists in version 1).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Request {
    /// Grab the next frame.
    Grab,
}

/// Why bytes are not a valid request or header.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WireError {
    /// Fewer bytes than the fixed size.
    Truncated,
    /// The magic is not `IMAF`.
    BadMagic,
    /// A version other than [`VERSION`].
    BadVersion(u8),
    /// An unknown operation.
    UnknownOp(u8),
    /// An unknown status byte.
    UnknownStatus(u8),
    /// Width or height is zero or above [`MAX_SIDE`] on an ok frame.
    BadSize {
        /// Width claimed.
        width: u32,
        /// Height claimed.
        height: u32,
    },
    /// The payload length does not match the status and size.
    BadLength(u32),
}

impl core::fmt::Display for WireError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Truncated => f.write_str("truncated"),
            Self::BadMagic => f.write_str("bad magic (not IMAF)"),
            Self::BadVersion(v) => write!(f, "unsupported version {v}"),
            Self::UnknownOp(o) => write!(f, "unknown operation {o}"),
            Self::UnknownStatus(s) => write!(f, "unknown status {s}"),
            Self::BadSize { width, height } => write!(f, "bad frame size {width}×{height}"),
            Self::BadLength(l) => write!(f, "payload length {l} does not match the header"),
        }
    }
}

impl std::error::Error for WireError {}

impl Request {
    /// The request's bytes.
    #[must_use]
    pub fn emit(self) -> [u8; REQUEST_LEN] {
        let [a, b, c, d] = MAGIC;
        match self {
            Self::Grab => [a, b, c, d, VERSION, OP_GRAB],
        }
    }

    /// Parse a request from the first [`REQUEST_LEN`] bytes of `b`.
    pub fn parse(b: &[u8]) -> Result<Self, WireError> {
        match b {
            [a, bb, c, d, v, op, ..] => {
                if [*a, *bb, *c, *d] != MAGIC {
                    return Err(WireError::BadMagic);
                }
                if *v != VERSION {
                    return Err(WireError::BadVersion(*v));
                }
                match *op {
                    OP_GRAB => Ok(Self::Grab),
                    o => Err(WireError::UnknownOp(o)),
                }
            }
            _ => Err(WireError::Truncated),
        }
    }
}

/// Outcome of a grab on the server.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Status {
    /// A frame follows.
    Ok,
    /// No camera is selected on the switcher.
    NoSignal,
    /// The switcher selects a channel the head does not have.
    BadChannel,
    /// Anything else.
    Other,
}

impl Status {
    fn byte(self) -> u8 {
        match self {
            Self::Ok => 0,
            Self::NoSignal => 1,
            Self::BadChannel => 2,
            Self::Other => 3,
        }
    }

    fn from_byte(b: u8) -> Result<Self, WireError> {
        Ok(match b {
            0 => Self::Ok,
            1 => Self::NoSignal,
            2 => Self::BadChannel,
            3 => Self::Other,
            s => return Err(WireError::UnknownStatus(s)),
        })
    }
}

/// A response header.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Header {
    /// Outcome.
    pub status: Status,
    /// Channel of the frame (`None`: unknown).
    pub channel: Option<u8>,
    /// Width, pixels (0 unless ok).
    pub width: u32,
    /// Height, pixels (0 unless ok).
    pub height: u32,
    /// Exposure stamp, µs on the server's clock.
    pub exposed_us: u64,
    /// Send stamp, µs on the server's clock.
    pub sent_us: u64,
}

impl Header {
    /// Payload bytes that follow this header.
    #[must_use]
    pub fn payload_len(&self) -> u32 {
        if self.status == Status::Ok {
            self.width.saturating_mul(self.height).saturating_mul(3)
        } else {
            0
        }
    }

    /// The header's bytes.
    #[must_use]
    pub fn emit(&self) -> [u8; HEADER_LEN] {
        let mut out = [0u8; HEADER_LEN];
        let fields: [&[u8]; 10] = [
            &MAGIC,
            &[VERSION],
            &[self.status.byte()],
            &[self.channel.unwrap_or(0)],
            &[0],
            &self.width.to_be_bytes(),
            &self.height.to_be_bytes(),
            &self.exposed_us.to_be_bytes(),
            &self.sent_us.to_be_bytes(),
            &self.payload_len().to_be_bytes(),
        ];
        let mut dst = out.iter_mut();
        for b in fields.iter().flat_map(|f| f.iter()) {
            if let Some(d) = dst.next() {
                *d = *b;
            }
        }
        out
    }

    /// Parse a header from the first [`HEADER_LEN`] bytes of `b`, checking sizes and length.
    pub fn parse(b: &[u8]) -> Result<Self, WireError> {
        let b = b.get(..HEADER_LEN).ok_or(WireError::Truncated)?;
        let u32_at = |o: usize| -> Result<u32, WireError> {
            let s = b.get(o..o + 4).ok_or(WireError::Truncated)?;
            Ok(u32::from_be_bytes(
                s.try_into().map_err(|_| WireError::Truncated)?,
            ))
        };
        let u64_at = |o: usize| -> Result<u64, WireError> {
            let s = b.get(o..o + 8).ok_or(WireError::Truncated)?;
            Ok(u64::from_be_bytes(
                s.try_into().map_err(|_| WireError::Truncated)?,
            ))
        };
        let (magic, rest) = b.split_at_checked(4).ok_or(WireError::Truncated)?;
        if magic != MAGIC {
            return Err(WireError::BadMagic);
        }
        let (version, status, channel) = match rest {
            [v, s, c, ..] => (*v, *s, *c),
            _ => return Err(WireError::Truncated),
        };
        if version != VERSION {
            return Err(WireError::BadVersion(version));
        }
        let status = Status::from_byte(status)?;
        let h = Self {
            status,
            channel: (channel != 0).then_some(channel),
            width: u32_at(8)?,
            height: u32_at(12)?,
            exposed_us: u64_at(16)?,
            sent_us: u64_at(24)?,
        };
        let len = u32_at(32)?;
        if status == Status::Ok
            && (h.width == 0 || h.height == 0 || h.width > MAX_SIDE || h.height > MAX_SIDE)
        {
            return Err(WireError::BadSize {
                width: h.width,
                height: h.height,
            });
        }
        if len != h.payload_len() {
            return Err(WireError::BadLength(len));
        }
        Ok(h)
    }
}

/// Errors of the frame client.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NetFrameError {
    /// Connecting, reading or writing failed (the connection is dropped; the next grab
    /// reconnects).
    Io(std::io::ErrorKind),
    /// No answer within the grab timeout.
    Timeout,
    /// The server sent bytes that are not a valid header.
    Wire(WireError),
    /// The server answered with an error status.
    Remote(Status),
}

impl core::fmt::Display for NetFrameError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Io(k) => write!(f, "frame server connection: {k}"),
            Self::Timeout => f.write_str("frame server did not answer in time"),
            Self::Wire(e) => write!(f, "frame server sent a bad header: {e}"),
            Self::Remote(Status::NoSignal) => f.write_str("no camera selected"),
            Self::Remote(Status::BadChannel) => f.write_str("the switcher selects a bad channel"),
            Self::Remote(s) => write!(f, "frame server error {s:?}"),
        }
    }
}

impl std::error::Error for NetFrameError {}

impl ima_hal::Error for NetFrameError {
    fn kind(&self) -> ErrorKind {
        match self {
            Self::Io(_) => ErrorKind::Disconnected,
            Self::Timeout => ErrorKind::Timeout,
            Self::Wire(_) => ErrorKind::Protocol,
            Self::Remote(Status::BadChannel) => ErrorKind::InvalidArgument,
            Self::Remote(_) => ErrorKind::Other,
        }
    }
}

#[cfg(feature = "tokio")]
pub use client::NetFrames;

#[cfg(feature = "tokio")]
mod client {
    use std::time::Duration;

    use ima_hal::camera::{Frame, FrameSource};
    use ima_hal::time::{Clock, SharedClock, TokioClock};
    use ima_hal::{ErrorType, Instant, Stamped};
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    use tokio::net::TcpStream;

    use super::{HEADER_LEN, Header, NetFrameError, Request, Status};

    /// A [`FrameSource`] grabbing frames from a frame server over TCP (see the module docs).
    ///
    /// Connects lazily on the first grab and again after any error. Stamps are on the
    /// client's clock ([`NetFrames::now`]): a [`TokioClock`] of its own, or the process's
    /// one clock given with [`NetFrames::with_clock`].
    #[derive(Debug)]
    pub struct NetFrames {
        addr: String,
        stream: Option<TcpStream>,
        timeout: Duration,
        clock: SharedClock,
        grabs: u64,
    }

    impl NetFrames {
        /// A client of the server at `addr` (`host:port`), not yet connected; each grab
        /// (connection included) must finish within `timeout`.
        #[must_use]
        pub fn new(addr: impl Into<String>, timeout: Duration) -> Self {
            Self {
                addr: addr.into(),
                stream: None,
                timeout,
                clock: TokioClock::shared(),
                grabs: 0,
            }
        }

        /// The same client stamping its frames on `clock` (the process's one clock, which
        /// the robot's other devices stamp on too).
        #[must_use]
        pub fn with_clock(mut self, clock: SharedClock) -> Self {
            self.clock = clock;
            self
        }

        /// Connect now (to fail early with a clear error).
        pub async fn connect(&mut self) -> Result<(), NetFrameError> {
            let s = tokio::time::timeout(self.timeout, TcpStream::connect(&self.addr))
                .await
                .map_err(|_| NetFrameError::Timeout)?
                .map_err(|e| NetFrameError::Io(e.kind()))?;
            let _ = s.set_nodelay(true);
            self.stream = Some(s);
            Ok(())
        }

        /// The server's address.
        #[must_use]
        pub fn addr(&self) -> &str {
            &self.addr
        }

        /// The client's clock (time base of the frames' stamps).
        #[must_use]
        pub fn now(&self) -> Instant {
            self.clock.now()
        }

        /// Frames received so far.
        #[must_use]
        pub fn grabs(&self) -> u64 {
            self.grabs
        }

        async fn exchange(&mut self) -> Result<Stamped<Frame>, NetFrameError> {
            if self.stream.is_none() {
                self.connect().await?;
            }
            let Some(s) = self.stream.as_mut() else {
                return Err(NetFrameError::Io(std::io::ErrorKind::NotConnected));
            };
            let io = |e: std::io::Error| NetFrameError::Io(e.kind());
            s.write_all(&Request::Grab.emit()).await.map_err(io)?;
            let mut hb = [0u8; HEADER_LEN];
            s.read_exact(&mut hb).await.map_err(io)?;
            let h = Header::parse(&hb).map_err(NetFrameError::Wire)?;
            let received = self.clock.now();
            if h.status != Status::Ok {
                return Err(NetFrameError::Remote(h.status));
            }
            let mut frame = Frame::black(h.width, h.height, h.channel).ok_or(
                NetFrameError::Wire(super::WireError::BadSize {
                    width: h.width,
                    height: h.height,
                }),
            )?;
            s.read_exact(&mut frame.pixels).await.map_err(io)?;
            let age = Duration::from_micros(h.sent_us.saturating_sub(h.exposed_us));
            self.grabs = self.grabs.saturating_add(1);
            Ok(Stamped::new(received - age, frame))
        }
    }

    impl ErrorType for NetFrames {
        type Error = NetFrameError;
    }

    impl FrameSource for NetFrames {
        async fn grab(&mut self) -> Result<Stamped<Frame>, NetFrameError> {
            let r = match tokio::time::timeout(self.timeout, self.exchange()).await {
                Ok(r) => r,
                Err(_) => Err(NetFrameError::Timeout),
            };
            // After a transport or framing error the stream position is unknown: reconnect.
            if matches!(
                r,
                Err(NetFrameError::Io(_) | NetFrameError::Timeout | NetFrameError::Wire(_))
            ) {
                self.stream = None;
            }
            r
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn request_round_trip_and_errors() {
        let b = Request::Grab.emit();
        assert_eq!(b, [0x49, 0x4D, 0x41, 0x46, 1, 1]);
        assert_eq!(Request::parse(&b), Ok(Request::Grab));
        assert_eq!(Request::parse(&b[..5]), Err(WireError::Truncated));
        assert_eq!(Request::parse(b"IMAX\x01\x01"), Err(WireError::BadMagic));
        assert_eq!(
            Request::parse(b"IMAF\x02\x01"),
            Err(WireError::BadVersion(2))
        );
        assert_eq!(
            Request::parse(b"IMAF\x01\x07"),
            Err(WireError::UnknownOp(7))
        );
    }

    #[test]
    fn header_vector_and_round_trip() {
        let h = Header {
            status: Status::Ok,
            channel: Some(3),
            width: 2,
            height: 1,
            exposed_us: 0x0102,
            sent_us: 0x0304,
        };
        let b = h.emit();
        let want: [u8; HEADER_LEN] = [
            0x49, 0x4D, 0x41, 0x46, 1, 0, 3, 0, 0, 0, 0, 2, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 1, 2, 0,
            0, 0, 0, 0, 0, 3, 4, 0, 0, 0, 6,
        ];
        assert_eq!(b, want);
        assert_eq!(Header::parse(&b), Ok(h));
        let e = Header {
            status: Status::NoSignal,
            channel: None,
            width: 0,
            height: 0,
            exposed_us: 5,
            sent_us: 6,
        };
        assert_eq!(Header::parse(&e.emit()), Ok(e));
    }

    #[test]
    fn hostile_headers_are_refused() {
        let ok = Header {
            status: Status::Ok,
            channel: Some(1),
            width: 320,
            height: 240,
            exposed_us: 0,
            sent_us: 0,
        };
        let mut b = ok.emit();
        assert_eq!(Header::parse(&b[..35]), Err(WireError::Truncated));
        b[35] ^= 1;
        assert!(matches!(Header::parse(&b), Err(WireError::BadLength(_))));
        let mut big = ok;
        big.width = MAX_SIDE + 1;
        assert!(matches!(
            Header::parse(&big.emit()),
            Err(WireError::BadSize { .. })
        ));
        let mut b = ok.emit();
        b[5] = 9;
        assert_eq!(Header::parse(&b), Err(WireError::UnknownStatus(9)));
        let mut b = ok.emit();
        b[0] = 0;
        assert_eq!(Header::parse(&b), Err(WireError::BadMagic));
    }

    proptest::proptest! {
        #[test]
        fn parse_never_panics(data in proptest::collection::vec(proptest::num::u8::ANY, 0..64)) {
            let _ = Header::parse(&data);
            let _ = Request::parse(&data);
        }

        #[test]
        fn ok_headers_round_trip(ch in 1u8.., w in 1u32..=MAX_SIDE, h in 1u32..=MAX_SIDE, e: u64, s: u64) {
            let hd = Header { status: Status::Ok, channel: Some(ch), width: w, height: h, exposed_us: e, sent_us: s };
            proptest::prop_assert_eq!(Header::parse(&hd.emit()), Ok(hd));
        }
    }
}

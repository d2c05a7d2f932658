//! rFLEX frames and messages (spec `rflex.md` §2–§3): constants, the XOR checksum, byte
//! stuffing, and typed messages in both directions.
//!
//! A frame on the wire is `ESC STX` + stuffed(`port id opcode N data[N] checksum`) + `ESC ETX`
//! (§2.1). The part between the markers, once unstuffed, is called the *content* here: it is
//! 5 + N bytes long, at most [`MAX_CONTENT`].
//!
//! * [`Command`]: what a host sends (the driver emits it, the mock parses it).
//! * [`Report`]: what the base sends (the mock emits it, the driver parses it).
//! * [`RawFrame`]: a checked, borrowed view of one frame's content (port, id, opcode, data);
//!   the [`framer`](crate::framer) yields these.
//!
//! Both message types have `parse(wire)` (a whole stuffed frame, strict §2.5 rules) and
//! `emit(buf)` / `emit_with(id, stuffing, buf)`; `from_raw` parses an already-framed
//! [`RawFrame`]. Frames with a port/opcode this module does not know parse to an
//! `Unknown` variant (§2.5: "ignored, not treated as errors").

use core::fmt;

use ima_hal::bytes::{Overflow, Reader, Writer};

/// Escape byte, first byte of both markers (§2.1).
pub const ESC: u8 = 0x1B;
/// Start-of-frame marker, second byte.
pub const STX: u8 = 0x02;
/// End-of-frame marker, second byte.
pub const ETX: u8 = 0x03;
/// Second byte of the stuffed form of a data 0x1B (`1B 00`, §2.4).
pub const ESC_NUL: u8 = 0x00;
/// Second byte of the deletable pair `1B 01` that follows a stuffed 0x7C (§2.4).
pub const ESC_DEL: u8 = 0x01;
/// The byte that CW's rule stuffs as `7C 1B 01` (§2.4).
pub const PIPE: u8 = 0x7C;

/// Largest data length N (one byte).
pub const MAX_DATA: usize = 255;
/// Largest content (port, id, opcode, N, data, checksum): 5 + 255.
pub const MAX_CONTENT: usize = 5 + MAX_DATA;
/// Largest unstuffed frame including markers (§2.1: 264 bytes).
pub const MAX_FRAME: usize = MAX_CONTENT + 4;
/// Largest stuffed frame: markers plus every content byte tripled (§2.1: 784 bytes).
pub const MAX_WIRE_FRAME: usize = 4 + 3 * MAX_CONTENT;

/// Port numbers (§2.1, §3).
pub mod port {
    /// System: status, LCD.
    pub const SYS: u8 = 1;
    /// Motion control.
    pub const MOT: u8 = 2;
    /// Joystick pendant.
    pub const JSTK: u8 = 3;
    /// Sonar.
    pub const SONAR: u8 = 4;
    /// Digital I/O (bumpers).
    pub const DIO: u8 = 5;
    /// Infrared (not fitted on the ATRV-Jr).
    pub const IR: u8 = 6;
}

/// Opcodes, per port (§3).
pub mod op {
    /// SYS: status request / reply.
    pub const SYS_STATUS: u8 = 1;
    /// MOT: set velocity, acceleration, torque and direction of one axis.
    pub const MOT_AXIS_SET_DIR: u8 = 7;
    /// MOT: restore defaults.
    pub const MOT_SET_DEFAULTS: u8 = 10;
    /// MOT: engage the brake (motors disabled).
    pub const MOT_BRAKE_SET: u8 = 11;
    /// MOT: release the brake (motors enabled).
    pub const MOT_BRAKE_RELEASE: u8 = 12;
    /// MOT: one axis's motion report (base to host).
    pub const MOT_SYSTEM_REPORT: u8 = 33;
    /// MOT: ask for periodic motion reports.
    pub const MOT_SYSTEM_REPORT_REQ: u8 = 34;
    /// JSTK: joystick state request / reply.
    pub const JSTK_GET_STATE: u8 = 0;
    /// SONAR: start/stop firing.
    pub const SONAR_RUN: u8 = 0;
    /// SONAR: range report (base to host).
    pub const SONAR_REPORT: u8 = 2;
    /// DIO: ask for event reports (host to base); its ack uses the same opcode.
    pub const DIO_REPORTS_REQ: u8 = 0;
    /// DIO: an input changed (base to host).
    pub const DIO_REPORT: u8 = 1;
    /// DIO: same layout as [`DIO_REPORT`].
    pub const DIO_UPDATE: u8 = 3;
    /// IR: start/stop (only used to switch IR off at shutdown, §6).
    pub const IR_RUN: u8 = 0;
}

/// What can be wrong with a frame or a message. Small and `Copy`: counted, never fatal.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WireError {
    /// The input ended before the frame did.
    Truncated,
    /// The frame does not start with `ESC STX`.
    BadStart,
    /// Bytes follow the `ESC ETX` that ends the frame.
    TrailingBytes,
    /// `ESC` followed by a byte that is not a stuffing code or marker (strict §2.5).
    BadEscape(u8),
    /// The content unstuffs to more than [`MAX_CONTENT`] bytes.
    Oversize,
    /// The content is shorter than the 5 bytes of header and checksum.
    TooShort(u8),
    /// The length byte does not match the content: `declared` N, `actual` data bytes.
    BadLength {
        /// N from the header.
        declared: u8,
        /// Data bytes actually present.
        actual: u16,
    },
    /// The XOR checksum does not match (§2.2).
    BadChecksum {
        /// What the header and data XOR to.
        expected: u8,
        /// The checksum byte received.
        got: u8,
    },
    /// A known port/opcode with a data length its layout does not allow.
    BadPayload {
        /// Port.
        port: u8,
        /// Opcode.
        opcode: u8,
        /// Data length N.
        len: u8,
    },
    /// The output buffer is too small.
    BufferTooSmall,
    /// The message cannot be emitted (an `Unknown` frame carries no payload).
    NotEmittable,
}

impl fmt::Display for WireError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Self::Truncated => f.write_str("truncated frame"),
            Self::BadStart => f.write_str("frame does not start with ESC STX"),
            Self::TrailingBytes => f.write_str("bytes after ESC ETX"),
            Self::BadEscape(b) => write!(f, "ESC followed by {b:#04x}"),
            Self::Oversize => f.write_str("frame longer than 264 bytes"),
            Self::TooShort(n) => write!(f, "frame content of {n} bytes (< 5)"),
            Self::BadLength { declared, actual } => {
                write!(
                    f,
                    "length byte says {declared}, frame has {actual} data bytes"
                )
            }
            Self::BadChecksum { expected, got } => {
                write!(f, "checksum {got:#04x}, expected {expected:#04x}")
            }
            Self::BadPayload { port, opcode, len } => {
                write!(f, "port {port} opcode {opcode}: bad data length {len}")
            }
            Self::BufferTooSmall => f.write_str("output buffer too small"),
            Self::NotEmittable => f.write_str("message has no wire form"),
        }
    }
}

impl core::error::Error for WireError {}

/// XOR checksum of the content bytes from `port` through the last data byte (§2.2).
#[must_use]
pub fn checksum(header_and_data: &[u8]) -> u8 {
    header_and_data.iter().fold(0, |acc, b| acc ^ b)
}

/// How the content of an emitted frame is made transparent (§2.4).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Stuffing {
    /// CW's rule, both parts: `1B` → `1B 00` and `7C` → `7C 1B 01`. The spec's normative
    /// choice for both directions.
    #[default]
    Full,
    /// Only `1B` → `1B 00` (the mock's switch that leaves 0x7C alone, §8).
    EscOnly,
    /// No stuffing at all: what every legacy driver sends. A 0x1B in the content then reaches
    /// a strict receiver as a framing error; see [`Command::legacy_nudged`].
    None,
}

ima_hal::cursor_errors!(WireError {
    truncated: |_| WireError::Truncated,
    overflow: |_| WireError::BufferTooSmall,
});

/// Write one content byte, stuffed per `stuffing`.
fn put_stuffed(o: &mut Writer<'_>, b: u8, stuffing: Stuffing) -> Result<(), Overflow> {
    o.u8(b)?;
    match (b, stuffing) {
        (ESC, Stuffing::Full | Stuffing::EscOnly) => o.u8(ESC_NUL).map(drop),
        (PIPE, Stuffing::Full) => o.u8(ESC)?.u8(ESC_DEL).map(drop),
        _ => Ok(()),
    }
}

/// Encode one frame: markers, header, `data`, checksum, stuffed per `stuffing`.
/// Returns the number of bytes written to `out` (at most [`MAX_WIRE_FRAME`]).
pub fn encode_frame(
    port: u8,
    id: u8,
    opcode: u8,
    data: &[u8],
    stuffing: Stuffing,
    out: &mut [u8],
) -> Result<usize, WireError> {
    let n = u8::try_from(data.len()).map_err(|_| WireError::Oversize)?;
    let mut o = Writer::new(out);
    o.u8(ESC)?.u8(STX)?;
    let header = [port, id, opcode, n];
    for &b in header.iter().chain(data) {
        put_stuffed(&mut o, b, stuffing)?;
    }
    put_stuffed(&mut o, checksum(&header) ^ checksum(data), stuffing)?;
    o.u8(ESC)?.u8(ETX)?;
    Ok(o.pos())
}

/// Undo stuffing of one whole wire frame (`ESC STX … ESC ETX`, strict §2.5 rules) into
/// `content`; returns the content length. Checks nothing but the framing.
pub fn unstuff_frame(wire: &[u8], content: &mut [u8]) -> Result<usize, WireError> {
    let body = match wire {
        [ESC, STX, body @ ..] => body,
        [] | [ESC] => return Err(WireError::Truncated),
        _ => return Err(WireError::BadStart),
    };
    let mut n = 0usize;
    let mut it = body.iter();
    while let Some(&b) = it.next() {
        let lit = if b == ESC {
            match it.next() {
                None => return Err(WireError::Truncated),
                Some(&ESC_NUL) => Some(ESC),
                Some(&ESC_DEL) => None,
                Some(&ETX) => {
                    return if it.as_slice().is_empty() {
                        Ok(n)
                    } else {
                        Err(WireError::TrailingBytes)
                    };
                }
                Some(&other) => return Err(WireError::BadEscape(other)),
            }
        } else {
            Some(b)
        };
        if let Some(lit) = lit {
            let slot = content.get_mut(n).ok_or(if n >= MAX_CONTENT {
                WireError::Oversize
            } else {
                WireError::BufferTooSmall
            })?;
            *slot = lit;
            n += 1;
        }
    }
    Err(WireError::Truncated)
}

/// One frame's checked content, borrowed: header fields and data (§2.1).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RawFrame<'a> {
    /// Port (§3).
    pub port: u8,
    /// Packet id / sequence number.
    pub id: u8,
    /// Opcode within the port.
    pub opcode: u8,
    /// The N data bytes.
    pub data: &'a [u8],
}

impl<'a> RawFrame<'a> {
    /// Check unstuffed content (`port id opcode N data checksum`): length ≥ 5, N matches,
    /// checksum matches (§2.5).
    pub fn new_checked(content: &'a [u8]) -> Result<Self, WireError> {
        let Some((&sum, rest)) = content.split_last() else {
            return Err(WireError::TooShort(0));
        };
        let [port, id, opcode, n, data @ ..] = rest else {
            return Err(WireError::TooShort(
                u8::try_from(content.len()).unwrap_or(u8::MAX),
            ));
        };
        if usize::from(*n) != data.len() {
            return Err(WireError::BadLength {
                declared: *n,
                actual: u16::try_from(data.len()).unwrap_or(u16::MAX),
            });
        }
        let expected = checksum(rest);
        // Fuzz builds accept any checksum so the fuzzer reaches the payload parsers.
        if expected != sum && !cfg!(fuzzing) {
            return Err(WireError::BadChecksum { expected, got: sum });
        }
        Ok(Self {
            port: *port,
            id: *id,
            opcode: *opcode,
            data,
        })
    }

    /// Unstuff a whole wire frame into `scratch` (≥ [`MAX_CONTENT`] bytes) and check it.
    pub fn parse_wire(wire: &[u8], scratch: &'a mut [u8]) -> Result<Self, WireError> {
        let n = unstuff_frame(wire, scratch)?;
        Self::new_checked(scratch.get(..n).ok_or(WireError::Truncated)?)
    }

    /// Re-encode this frame.
    pub fn emit(&self, stuffing: Stuffing, out: &mut [u8]) -> Result<usize, WireError> {
        encode_frame(self.port, self.id, self.opcode, self.data, stuffing, out)
    }
}

/// Build a payload with `write` in a scratch buffer of [`MAX_DATA`] bytes, then hand it to
/// `then`.
fn with_payload<R>(
    write: impl FnOnce(&mut Writer<'_>) -> Result<(), WireError>,
    then: impl FnOnce(&[u8]) -> R,
) -> Result<R, WireError> {
    let mut data = [0u8; MAX_DATA];
    let mut w = Writer::new(&mut data);
    write(&mut w)?;
    Ok(then(w.written()))
}

fn need(raw: &RawFrame<'_>, len: usize) -> Result<(), WireError> {
    if raw.data.len() == len {
        Ok(())
    } else {
        Err(WireError::BadPayload {
            port: raw.port,
            opcode: raw.opcode,
            len: u8::try_from(raw.data.len()).unwrap_or(u8::MAX),
        })
    }
}

/// A frame this module has no layout for; reported, never an error (§2.5).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct UnknownFrame {
    /// Port.
    pub port: u8,
    /// Packet id.
    pub id: u8,
    /// Opcode.
    pub opcode: u8,
    /// Data length N.
    pub len: u8,
}

impl UnknownFrame {
    fn of(raw: &RawFrame<'_>) -> Self {
        Self {
            port: raw.port,
            id: raw.id,
            opcode: raw.opcode,
            len: u8::try_from(raw.data.len()).unwrap_or(u8::MAX),
        }
    }
}

/// MOT_AXIS_SET_DIR payload (§3 MOT op 7, N = 14): one axis's speed magnitude, acceleration,
/// torque and direction, in controller units.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SetDir {
    /// 0 = translation, 1 = rotation.
    pub axis: u8,
    /// Speed magnitude (units/s).
    pub velocity: u32,
    /// Acceleration (units/s²).
    pub acceleration: u32,
    /// Torque limit.
    pub torque: u32,
    /// Direction byte: `true` (1) if the signed request is ≥ 0. Parsing reads any non-zero
    /// byte as `true`.
    pub forward: bool,
}

/// SONAR_RUN payload (§3 SONAR op 0, N = 13).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SonarRun {
    /// Echo delay, µs (30000 everywhere).
    pub echo_delay_us: u32,
    /// Ping delay, µs (0).
    pub ping_delay_us: u32,
    /// Set delay, µs (0).
    pub set_delay_us: u32,
    /// 2 = run, 0 = stop.
    pub mode: u8,
}

impl SonarRun {
    /// The run command every driver sends (30000, 0, 0, 2).
    pub const ON: Self = Self {
        echo_delay_us: 30_000,
        ping_delay_us: 0,
        set_delay_us: 0,
        mode: 2,
    };
    /// The stop command (30000, 0, 0, 0).
    pub const OFF: Self = Self {
        echo_delay_us: 30_000,
        ping_delay_us: 0,
        set_delay_us: 0,
        mode: 0,
    };
}

/// Packet id hosts use for SONAR_RUN (§2.1).
pub const SONAR_RUN_ID: u8 = 4;

/// A host-to-base message (§3, "H→B").
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Command {
    /// SYS_STATUS request (N = 0).
    SysStatusRequest,
    /// MOT_AXIS_SET_DIR.
    SetDir(SetDir),
    /// MOT_SET_DEFAULTS (N = 0).
    SetDefaults,
    /// MOT_BRAKE_SET (N = 0): motors disabled.
    BrakeSet,
    /// MOT_BRAKE_RELEASE (N = 0): motors enabled.
    BrakeRelease,
    /// MOT_SYSTEM_REPORT_REQ (N = 8).
    SystemReportReq {
        /// Report period in µs (100000 = 10 Hz); 0 with mask 0 turns reports off.
        period_us: u32,
        /// Bit k enables axis k (3 = both).
        mask: u32,
    },
    /// SONAR_RUN.
    SonarRun(SonarRun),
    /// DIO_REPORTS_REQ (N = 4).
    DioReportsReq {
        /// Period (or hold-off) in µs; 0 = off.
        period_us: u32,
    },
    /// JSTK_GET_STATE request (N = 0).
    JoystickRequest,
    /// IR_RUN (N = 21): five u32 then a mode byte; only "all zero" (off) is used here.
    IrRun {
        /// The five u32 parameters (0, 70, 10, 20, 150 when on).
        params: [u32; 5],
        /// 2 = on, 0 = off.
        mode: u8,
    },
    /// Any other port/opcode, or a base-only opcode seen on the host link.
    Unknown(UnknownFrame),
}

impl Command {
    /// IR off, as sent at shutdown (§6).
    pub const IR_OFF: Self = Self::IrRun {
        params: [0; 5],
        mode: 0,
    };

    /// Port and opcode of this command (an unknown frame keeps its own).
    #[must_use]
    pub fn port_opcode(&self) -> (u8, u8) {
        match self {
            Self::SysStatusRequest => (port::SYS, op::SYS_STATUS),
            Self::SetDir(_) => (port::MOT, op::MOT_AXIS_SET_DIR),
            Self::SetDefaults => (port::MOT, op::MOT_SET_DEFAULTS),
            Self::BrakeSet => (port::MOT, op::MOT_BRAKE_SET),
            Self::BrakeRelease => (port::MOT, op::MOT_BRAKE_RELEASE),
            Self::SystemReportReq { .. } => (port::MOT, op::MOT_SYSTEM_REPORT_REQ),
            Self::SonarRun(_) => (port::SONAR, op::SONAR_RUN),
            Self::DioReportsReq { .. } => (port::DIO, op::DIO_REPORTS_REQ),
            Self::JoystickRequest => (port::JSTK, op::JSTK_GET_STATE),
            Self::IrRun { .. } => (port::IR, op::IR_RUN),
            Self::Unknown(u) => (u.port, u.opcode),
        }
    }

    /// The packet id hosts send with this command: 4 for SONAR_RUN, else 0 (§2.1).
    #[must_use]
    pub fn default_id(&self) -> u8 {
        match self {
            Self::SonarRun(_) => SONAR_RUN_ID,
            Self::Unknown(u) => u.id,
            _ => 0,
        }
    }

    /// Interpret a checked frame as a host command.
    pub fn from_raw(raw: &RawFrame<'_>) -> Result<Self, WireError> {
        let mut r = Reader::new(raw.data);
        Ok(match (raw.port, raw.opcode) {
            (port::SYS, op::SYS_STATUS) => {
                need(raw, 0)?;
                Self::SysStatusRequest
            }
            (port::MOT, op::MOT_AXIS_SET_DIR) => {
                need(raw, 14)?;
                Self::SetDir(SetDir {
                    axis: r.u8()?,
                    velocity: r.be::<u32>()?,
                    acceleration: r.be::<u32>()?,
                    torque: r.be::<u32>()?,
                    forward: r.u8()? != 0,
                })
            }
            (port::MOT, op::MOT_SET_DEFAULTS) => {
                need(raw, 0)?;
                Self::SetDefaults
            }
            (port::MOT, op::MOT_BRAKE_SET) => {
                need(raw, 0)?;
                Self::BrakeSet
            }
            (port::MOT, op::MOT_BRAKE_RELEASE) => {
                need(raw, 0)?;
                Self::BrakeRelease
            }
            (port::MOT, op::MOT_SYSTEM_REPORT_REQ) => {
                need(raw, 8)?;
                Self::SystemReportReq {
                    period_us: r.be::<u32>()?,
                    mask: r.be::<u32>()?,
                }
            }
            (port::SONAR, op::SONAR_RUN) => {
                need(raw, 13)?;
                Self::SonarRun(SonarRun {
                    echo_delay_us: r.be::<u32>()?,
                    ping_delay_us: r.be::<u32>()?,
                    set_delay_us: r.be::<u32>()?,
                    mode: r.u8()?,
                })
            }
            (port::DIO, op::DIO_REPORTS_REQ) => {
                need(raw, 4)?;
                Self::DioReportsReq {
                    period_us: r.be::<u32>()?,
                }
            }
            (port::JSTK, op::JSTK_GET_STATE) => {
                need(raw, 0)?;
                Self::JoystickRequest
            }
            (port::IR, op::IR_RUN) => {
                need(raw, 21)?;
                Self::IrRun {
                    params: [
                        r.be::<u32>()?,
                        r.be::<u32>()?,
                        r.be::<u32>()?,
                        r.be::<u32>()?,
                        r.be::<u32>()?,
                    ],
                    mode: r.u8()?,
                }
            }
            _ => Self::Unknown(UnknownFrame::of(raw)),
        })
    }

    /// Parse one whole stuffed wire frame (strict §2.5 rules).
    pub fn parse(wire: &[u8]) -> Result<Self, WireError> {
        let mut scratch = [0u8; MAX_CONTENT];
        Self::from_raw(&RawFrame::parse_wire(wire, &mut scratch)?)
    }

    fn write_payload(&self, w: &mut Writer<'_>) -> Result<(), WireError> {
        match *self {
            Self::SysStatusRequest
            | Self::SetDefaults
            | Self::BrakeSet
            | Self::BrakeRelease
            | Self::JoystickRequest => {}
            Self::SetDir(s) => {
                w.u8(s.axis)?
                    .be(s.velocity)?
                    .be(s.acceleration)?
                    .be(s.torque)?
                    .u8(u8::from(s.forward))?;
            }
            Self::SystemReportReq { period_us, mask } => {
                w.be(period_us)?.be(mask)?;
            }
            Self::SonarRun(s) => {
                w.be(s.echo_delay_us)?
                    .be(s.ping_delay_us)?
                    .be(s.set_delay_us)?
                    .u8(s.mode)?;
            }
            Self::DioReportsReq { period_us } => {
                w.be(period_us)?;
            }
            Self::IrRun { params, mode } => {
                for p in params {
                    w.be(p)?;
                }
                w.u8(mode)?;
            }
            Self::Unknown(_) => return Err(WireError::NotEmittable),
        }
        Ok(())
    }

    /// Emit with the default id and full stuffing (the normative host behaviour, §2.4).
    pub fn emit(&self, out: &mut [u8]) -> Result<usize, WireError> {
        self.emit_with(self.default_id(), Stuffing::Full, out)
    }

    /// Emit with an explicit packet id and stuffing.
    pub fn emit_with(
        &self,
        id: u8,
        stuffing: Stuffing,
        out: &mut [u8],
    ) -> Result<usize, WireError> {
        let (p, o) = self.port_opcode();
        with_payload(
            |w| self.write_payload(w),
            |data| encode_frame(p, id, o, data, stuffing, out),
        )?
    }

    /// The legacy Player/ROS/DTU workaround applied to every u32 field (§2.4, `legacy_no_stuff`):
    /// each 0x1B byte of a field is moved away by [`nudge_u32`]. If the frame's checksum then
    /// still comes out as 0x1B, one of the three low bits of the SET_DIR velocity is flipped
    /// (a change of at most 4 units, i.e. 4/Kd m/s, far below anything measurable); other commands the driver sends never
    /// contain 0x1B. Our extension: the legacy drivers left the checksum exposed (P1).
    #[must_use]
    pub fn legacy_nudged(&self) -> Self {
        match *self {
            Self::SetDir(s) => {
                let mut s = SetDir {
                    velocity: nudge_u32(s.velocity),
                    acceleration: nudge_u32(s.acceleration),
                    torque: nudge_u32(s.torque),
                    ..s
                };
                if Self::SetDir(s).content_checksum() == Some(ESC) {
                    // Flip one low bit of the velocity's last byte: the checksum changes by
                    // the same bit, and the byte itself must not become 0x1B either.
                    let low = s.velocity & 0xFF;
                    let k = [1u32, 2, 4]
                        .into_iter()
                        .find(|k| (low ^ k) != u32::from(ESC))
                        .unwrap_or(1);
                    s.velocity ^= k;
                }
                Self::SetDir(s)
            }
            Self::SystemReportReq { period_us, mask } => Self::SystemReportReq {
                period_us: nudge_u32(period_us),
                mask,
            },
            Self::SonarRun(s) => Self::SonarRun(SonarRun {
                echo_delay_us: nudge_u32(s.echo_delay_us),
                ping_delay_us: nudge_u32(s.ping_delay_us),
                set_delay_us: nudge_u32(s.set_delay_us),
                mode: s.mode,
            }),
            Self::DioReportsReq { period_us } => Self::DioReportsReq {
                period_us: nudge_u32(period_us),
            },
            Self::IrRun { params, mode } => Self::IrRun {
                params: params.map(nudge_u32),
                mode,
            },
            other => other,
        }
    }

    /// The frame checksum this command would have with its default id.
    fn content_checksum(&self) -> Option<u8> {
        let (p, o) = self.port_opcode();
        with_payload(
            |w| self.write_payload(w),
            |data| {
                let n = u8::try_from(data.len()).ok()?;
                Some(checksum(&[p, self.default_id(), o, n]) ^ checksum(data))
            },
        )
        .ok()?
    }
}

/// The Player nudge (§2.4, PL 685d5c65) generalised to every byte of a u32: working from the
/// most significant byte down, a byte equal to 0x1B becomes 0x1C with all lower bytes 0x00
/// if the next lower byte is > 127, else 0x1A with all lower bytes 0xFF. A 0x1B in the
/// least significant byte becomes 0x1C. So 0x1B58 → 0x1AFF (T5) and 0x1B80 → 0x1C00.
#[must_use]
pub fn nudge_u32(v: u32) -> u32 {
    let mut b = v.to_be_bytes();
    let mut i = 0;
    while i < 4 {
        if b.get(i) == Some(&ESC) {
            let next = b.get(i + 1).copied();
            let (hi, fill) = match next {
                Some(n) if n > 127 => (0x1C, 0x00),
                Some(_) => (0x1A, 0xFF),
                None => (0x1C, 0x00),
            };
            for (k, slot) in b.iter_mut().enumerate().skip(i) {
                *slot = if k == i { hi } else { fill };
            }
            break;
        }
        i += 1;
    }
    u32::from_be_bytes(b)
}

/// MOT_SYSTEM_REPORT payload (§3 MOT op 33, N = 25): one axis's state.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MotionReport {
    /// Leading u32 of unknown meaning.
    pub rv: u32,
    /// Controller timestamp (ticks, probably 4 ms).
    pub ts: u32,
    /// 0 = translation, 1 = rotation.
    pub axis: u8,
    /// Cumulative distance (axis 0, units) or bearing (axis 1, units).
    pub position: i32,
    /// Units per second.
    pub velocity: i32,
    /// Units per second².
    pub acceleration: i32,
    /// Torque.
    pub torque: i32,
}

/// One sonar triple {id, range} of a SONAR_REPORT (§3 SONAR op 2).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SonarEcho {
    /// bank × 16 + channel.
    pub id: u8,
    /// Raw range; metres = raw / 1476.
    pub range: u16,
}

/// Most triples a SONAR_REPORT can hold: (255 − 8) / 3.
pub const MAX_ECHOES: usize = (MAX_DATA - 8) / 3;

/// SONAR_REPORT payload: rv, ts, then n triples.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct SonarReport {
    /// Leading u32 of unknown meaning.
    pub rv: u32,
    /// Controller timestamp.
    pub ts: u32,
    /// The readings, in frame order.
    pub echoes: heapless::Vec<SonarEcho, MAX_ECHOES>,
}

/// DIO_REPORT / DIO_UPDATE payload (§3 DIO op 1/3, N = 7).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DioReport {
    /// Controller timestamp.
    pub ts: u32,
    /// Address (0x40 = ATRV-Jr bumpers).
    pub address: u8,
    /// The two data bytes read big-endian.
    pub data: u16,
}

/// Address of the ATRV-Jr bumper inputs (§3 DIO).
pub const DIO_BUMPER_ADDRESS: u8 = 0x40;

/// A base-to-host message (§3, "B→H").
///
/// The sonar variant holds its triples inline (no heap), which makes this enum ~340 bytes.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Report {
    /// SYS_STATUS reply (N = 9).
    SysStatus {
        /// Controller timestamp.
        ts: u32,
        /// Raw battery voltage; volts = raw / 100 + offset (1.2 V on the ATRV-Jr).
        voltage_raw: u32,
        /// Brake byte: `true` (1) = engaged (motors disabled). Any non-zero byte parses as `true`.
        brake_engaged: bool,
    },
    /// MOT_SYSTEM_REPORT.
    Motion(MotionReport),
    /// SONAR_REPORT.
    Sonar(SonarReport),
    /// DIO_REPORT.
    Dio(DioReport),
    /// DIO_UPDATE (same layout).
    DioUpdate(DioReport),
    /// JSTK_GET_STATE reply (N = 13).
    Joystick {
        /// Controller timestamp.
        ts: u32,
        /// Stick x.
        x: i32,
        /// Stick y.
        y: i32,
        /// Buttons; bit 0 = joystick in control.
        buttons: u8,
    },
    /// An 8-byte `rv ts` acknowledgement echoing a command's port and opcode (MOT 7,
    /// DIO 0, DIO 4; §3 "Acks", \[D\]). Drivers ignore them.
    Ack {
        /// Port of the acknowledged command.
        port: u8,
        /// Opcode of the acknowledged command.
        opcode: u8,
        /// Leading u32.
        rv: u32,
        /// Controller timestamp.
        ts: u32,
    },
    /// Any other port/opcode (LCD dumps, IR, unexplored opcodes).
    Unknown(UnknownFrame),
}

/// Port/opcode pairs the base acknowledges with `rv ts` (§3).
fn is_ack(port: u8, opcode: u8) -> bool {
    matches!(
        (port, opcode),
        (port::MOT, op::MOT_AXIS_SET_DIR) | (port::DIO, op::DIO_REPORTS_REQ) | (port::DIO, 4)
    )
}

impl Report {
    /// Port and opcode of this report.
    #[must_use]
    pub fn port_opcode(&self) -> (u8, u8) {
        match self {
            Self::SysStatus { .. } => (port::SYS, op::SYS_STATUS),
            Self::Motion(_) => (port::MOT, op::MOT_SYSTEM_REPORT),
            Self::Sonar(_) => (port::SONAR, op::SONAR_REPORT),
            Self::Dio(_) => (port::DIO, op::DIO_REPORT),
            Self::DioUpdate(_) => (port::DIO, op::DIO_UPDATE),
            Self::Joystick { .. } => (port::JSTK, op::JSTK_GET_STATE),
            Self::Ack { port, opcode, .. } => (*port, *opcode),
            Self::Unknown(u) => (u.port, u.opcode),
        }
    }

    /// Interpret a checked frame as a base report.
    pub fn from_raw(raw: &RawFrame<'_>) -> Result<Self, WireError> {
        let mut r = Reader::new(raw.data);
        Ok(match (raw.port, raw.opcode) {
            (port::SYS, op::SYS_STATUS) => {
                need(raw, 9)?;
                Self::SysStatus {
                    ts: r.be::<u32>()?,
                    voltage_raw: r.be::<u32>()?,
                    brake_engaged: r.u8()? != 0,
                }
            }
            (port::MOT, op::MOT_SYSTEM_REPORT) => {
                need(raw, 25)?;
                Self::Motion(MotionReport {
                    rv: r.be::<u32>()?,
                    ts: r.be::<u32>()?,
                    axis: r.u8()?,
                    position: r.be::<i32>()?,
                    velocity: r.be::<i32>()?,
                    acceleration: r.be::<i32>()?,
                    torque: r.be::<i32>()?,
                })
            }
            (port::SONAR, op::SONAR_REPORT) => {
                let n = raw.data.len();
                if n < 8 || !(n - 8).is_multiple_of(3) {
                    need(raw, 8)?;
                }
                let mut s = SonarReport {
                    rv: r.be::<u32>()?,
                    ts: r.be::<u32>()?,
                    echoes: heapless::Vec::new(),
                };
                for c in r.rest().chunks_exact(3) {
                    if let [id, hi, lo] = *c {
                        let _ = s.echoes.push(SonarEcho {
                            id,
                            range: u16::from_be_bytes([hi, lo]),
                        });
                    }
                }
                Self::Sonar(s)
            }
            (port::DIO, op::DIO_REPORT | op::DIO_UPDATE) => {
                need(raw, 7)?;
                let d = DioReport {
                    ts: r.be::<u32>()?,
                    address: r.u8()?,
                    data: r.be::<u16>()?,
                };
                if raw.opcode == op::DIO_REPORT {
                    Self::Dio(d)
                } else {
                    Self::DioUpdate(d)
                }
            }
            (port::JSTK, op::JSTK_GET_STATE) => {
                need(raw, 13)?;
                Self::Joystick {
                    ts: r.be::<u32>()?,
                    x: r.be::<i32>()?,
                    y: r.be::<i32>()?,
                    buttons: r.u8()?,
                }
            }
            (p, o) if is_ack(p, o) && raw.data.len() == 8 => Self::Ack {
                port: p,
                opcode: o,
                rv: r.be::<u32>()?,
                ts: r.be::<u32>()?,
            },
            _ => Self::Unknown(UnknownFrame::of(raw)),
        })
    }

    /// Parse one whole stuffed wire frame (strict §2.5 rules).
    pub fn parse(wire: &[u8]) -> Result<Self, WireError> {
        let mut scratch = [0u8; MAX_CONTENT];
        Self::from_raw(&RawFrame::parse_wire(wire, &mut scratch)?)
    }

    fn write_payload(&self, w: &mut Writer<'_>) -> Result<(), WireError> {
        match self {
            Self::SysStatus {
                ts,
                voltage_raw,
                brake_engaged,
            } => {
                w.be(*ts)?.be(*voltage_raw)?.u8(u8::from(*brake_engaged))?;
            }
            Self::Motion(m) => {
                w.be(m.rv)?
                    .be(m.ts)?
                    .u8(m.axis)?
                    .be(m.position)?
                    .be(m.velocity)?
                    .be(m.acceleration)?
                    .be(m.torque)?;
            }
            Self::Sonar(s) => {
                w.be(s.rv)?.be(s.ts)?;
                for e in &s.echoes {
                    w.u8(e.id)?.be(e.range)?;
                }
            }
            Self::Dio(d) | Self::DioUpdate(d) => {
                w.be(d.ts)?.u8(d.address)?.be(d.data)?;
            }
            Self::Joystick { ts, x, y, buttons } => {
                w.be(*ts)?.be(*x)?.be(*y)?.u8(*buttons)?;
            }
            Self::Ack {
                port,
                opcode,
                rv,
                ts,
            } => {
                if !is_ack(*port, *opcode) {
                    return Err(WireError::NotEmittable);
                }
                w.be(*rv)?.be(*ts)?;
            }
            Self::Unknown(_) => return Err(WireError::NotEmittable),
        }
        Ok(())
    }

    /// Emit with packet id 0 and full stuffing.
    pub fn emit(&self, out: &mut [u8]) -> Result<usize, WireError> {
        self.emit_with(0, Stuffing::Full, out)
    }

    /// Emit with an explicit packet id (the base counts upward) and stuffing.
    pub fn emit_with(
        &self,
        id: u8,
        stuffing: Stuffing,
        out: &mut [u8],
    ) -> Result<usize, WireError> {
        let (p, o) = self.port_opcode();
        with_payload(
            |w| self.write_payload(w),
            |data| encode_frame(p, id, o, data, stuffing, out),
        )?
    }
}

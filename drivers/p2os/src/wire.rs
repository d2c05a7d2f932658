//! P2OS packets on the wire: framing, checksum, host commands and robot packets.
//!
//! Every packet, in both directions, is `FA FB`, a count byte (payload length + 2), the
//! payload, and a 16-bit checksum sent high byte first (spec §2–§3). The payload's first byte
//! is the command number (host → robot) or the packet type (robot → host). Integers inside the
//! payload are little-endian.
//!
//! * [`checksum`], [`encode_frame`] and [`frame_payload`] deal with the envelope.
//! * [`Command`] is everything a host sends; [`Packet`] is everything a robot sends. Both have
//!   `parse(payload)` and `emit(&mut buf) -> bytes written` (a whole frame, envelope included).
//!
//! Nothing here panics on any input, allocates, or keeps state.
//!
//! # Choices where the sources disagree (spec §4, §6, §7.1)
//! * Signed arguments are sent as ARGINT + value or ARGNINT + magnitude; a robot decodes the
//!   two bytes as an `i16` and negates it for ARGNINT ([`IntArg::value`]). Both VEL2 styles
//!   (Player's raw bytes under ARGINT and ARIA's signed `i16`) therefore decode alike;
//!   [`EncodeOptions::vel2_style`] picks the one to emit (ARIA's by default).
//! * OPEN and CLOSE are emitted bare (ROS/Player) unless [`EncodeOptions::open_close_arg`]
//!   asks for ARIA's `ARGINT 1`; surplus argument bytes are ignored on parse.
//! * SIP byte 14 is taken as grip state, byte 15 as the analog port (spec §7.1's choice).
//! * SIP types 0x32 and 0x33 are SIPs; [`ParseOptions::lenient_sip_types`] widens this to
//!   0x30–0x34 as the ROS driver does.

use core::fmt;

use ima_hal::bytes::{Overflow, Reader, Writer};

/// First header byte.
pub const HEADER0: u8 = 0xFA;
/// Second header byte.
pub const HEADER1: u8 = 0xFB;
/// Smallest valid count byte (one payload byte + two checksum bytes).
pub const MIN_COUNT: u8 = 3;
/// Largest count byte a host may send: P2OS ignores longer commands (spec §2).
pub const MAX_COMMAND_COUNT: u8 = 200;
/// Longest frame on the wire: header, count 255, payload and checksum.
pub const MAX_FRAME_LEN: usize = 3 + 255;
/// Longest payload a frame can carry.
pub const MAX_PAYLOAD_LEN: usize = 255 - 2;

/// Argument-type byte: non-negative integer follows (2 bytes LE).
pub const ARGINT: u8 = 0x3B;
/// Argument-type byte: negative integer follows, as its magnitude (2 bytes LE).
pub const ARGNINT: u8 = 0x1B;
/// Argument-type byte: length-prefixed string follows.
pub const ARGSTR: u8 = 0x2B;

/// What was wrong with a packet. Small and `Copy`, so it can be counted and logged freely.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum WireError {
    /// The input ended before the packet did.
    Truncated,
    /// The first two bytes were not `FA FB`.
    BadHeader,
    /// The count byte is outside what the receiver accepts.
    BadCount(u8),
    /// The frame's length does not match its count byte.
    LengthMismatch {
        /// Length the count byte implies.
        expected: usize,
        /// Length given.
        got: usize,
    },
    /// The checksum does not match the payload.
    BadChecksum {
        /// Checksum computed over the payload.
        expected: u16,
        /// Checksum carried by the frame.
        got: u16,
    },
    /// An empty payload (no command or type byte).
    EmptyPayload,
    /// A command needs an argument and has none.
    MissingArgument(u8),
    /// An argument-type byte that is not ARGINT, ARGNINT or ARGSTR, or the wrong kind for the
    /// command.
    BadArgType(u8),
    /// A SIP claims more sonar readings than it carries, or more than 32.
    BadSonarCount(u8),
    /// A sonar index ≥ 32 in a SIP.
    BadSonarIndex(u8),
    /// A payload longer than a frame can carry.
    PayloadTooLong(usize),
    /// The output buffer cannot hold the frame.
    BufferTooSmall {
        /// Bytes needed.
        need: usize,
    },
    /// A value does not fit the wire field (e.g. a string over 255 bytes).
    ValueOutOfRange,
}

impl fmt::Display for WireError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Self::Truncated => f.write_str("truncated packet"),
            Self::BadHeader => f.write_str("bad header (expected FA FB)"),
            Self::BadCount(c) => write!(f, "bad count byte {c}"),
            Self::LengthMismatch { expected, got } => {
                write!(f, "frame length {got} does not match count ({expected})")
            }
            Self::BadChecksum { expected, got } => {
                write!(
                    f,
                    "bad checksum: computed {expected:#06x}, frame has {got:#06x}"
                )
            }
            Self::EmptyPayload => f.write_str("empty payload"),
            Self::MissingArgument(c) => write!(f, "command {c} needs an argument"),
            Self::BadArgType(t) => write!(f, "bad argument type {t:#04x}"),
            Self::BadSonarCount(n) => write!(f, "bad sonar count {n}"),
            Self::BadSonarIndex(i) => write!(f, "bad sonar index {i}"),
            Self::PayloadTooLong(n) => write!(f, "payload of {n} bytes is too long"),
            Self::BufferTooSmall { need } => {
                write!(f, "output buffer too small ({need} bytes needed)")
            }
            Self::ValueOutOfRange => f.write_str("value out of range for its wire field"),
        }
    }
}

impl core::error::Error for WireError {}

impl WireError {
    /// A short snake_case name, stable for logs and JSON.
    #[must_use]
    pub fn name(&self) -> &'static str {
        match self {
            Self::Truncated => "truncated",
            Self::BadHeader => "bad_header",
            Self::BadCount(_) => "bad_count",
            Self::LengthMismatch { .. } => "length_mismatch",
            Self::BadChecksum { .. } => "bad_checksum",
            Self::EmptyPayload => "empty_payload",
            Self::MissingArgument(_) => "missing_argument",
            Self::BadArgType(_) => "bad_arg_type",
            Self::BadSonarCount(_) => "bad_sonar_count",
            Self::BadSonarIndex(_) => "bad_sonar_index",
            Self::PayloadTooLong(_) => "payload_too_long",
            Self::BufferTooSmall { .. } => "buffer_too_small",
            Self::ValueOutOfRange => "value_out_of_range",
        }
    }
}

/// The P2OS checksum of a payload (spec §3): big-endian byte pairs summed modulo 2¹⁶, an odd
/// last byte XORed into the low byte.
#[must_use]
pub fn checksum(payload: &[u8]) -> u16 {
    let (pairs, rest) = payload.as_chunks::<2>();
    let mut c: u16 = 0;
    for pair in pairs {
        c = c.wrapping_add(u16::from_be_bytes(*pair));
    }
    if let Some(&last) = rest.first() {
        c ^= u16::from(last);
    }
    c
}

/// Wrap `payload` in a frame in `out`; returns the frame length.
pub fn encode_frame(payload: &[u8], out: &mut [u8]) -> Result<usize, WireError> {
    if payload.is_empty() {
        return Err(WireError::EmptyPayload);
    }
    if payload.len() > MAX_PAYLOAD_LEN {
        return Err(WireError::PayloadTooLong(payload.len()));
    }
    let total = payload.len() + 5;
    let Some(frame) = out.get_mut(..total) else {
        return Err(WireError::BufferTooSmall { need: total });
    };
    let (head, rest) = frame.split_at_mut(3);
    let (body, sum) = rest.split_at_mut(payload.len());
    // payload.len() ≤ 253, so the count fits in a u8.
    let count =
        u8::try_from(payload.len() + 2).map_err(|_| WireError::PayloadTooLong(payload.len()))?;
    head.copy_from_slice(&[HEADER0, HEADER1, count]);
    body.copy_from_slice(payload);
    sum.copy_from_slice(&checksum(payload).to_be_bytes());
    Ok(total)
}

/// Check one complete frame (header, count, exact length, checksum) and return its payload.
pub fn frame_payload(frame: &[u8]) -> Result<&[u8], WireError> {
    let [h0, h1, count, rest @ ..] = frame else {
        return Err(WireError::Truncated);
    };
    if (*h0, *h1) != (HEADER0, HEADER1) {
        return Err(WireError::BadHeader);
    }
    if *count < MIN_COUNT {
        return Err(WireError::BadCount(*count));
    }
    let expected = usize::from(*count);
    if rest.len() != expected {
        return Err(if rest.len() < expected {
            WireError::Truncated
        } else {
            WireError::LengthMismatch {
                expected: expected + 3,
                got: frame.len(),
            }
        });
    }
    let (payload, sum) = rest.split_at(expected - 2);
    let got = match sum {
        [hi, lo] => u16::from_be_bytes([*hi, *lo]),
        _ => return Err(WireError::Truncated),
    };
    let computed = checksum(payload);
    if computed != got && !cfg!(fuzzing) {
        return Err(WireError::BadChecksum {
            expected: computed,
            got,
        });
    }
    Ok(payload)
}

// A payload that does not fit the scratch buffer is too long for a frame.
ima_hal::cursor_errors!(WireError {
    truncated: |_| WireError::Truncated,
    overflow: |o| WireError::PayloadTooLong(o.needed()),
});

/// Build a payload with `f` in a scratch buffer, then frame it into `out`.
fn emit_with(
    out: &mut [u8],
    f: impl FnOnce(&mut Writer<'_>) -> Result<(), WireError>,
) -> Result<usize, WireError> {
    let mut scratch = [0u8; MAX_PAYLOAD_LEN];
    let mut w = Writer::new(&mut scratch);
    f(&mut w)?;
    encode_frame(w.written(), out)
}

// ---------------------------------------------------------------------------------------------
// Host → robot
// ---------------------------------------------------------------------------------------------

/// An integer argument as it travels: ARGINT or ARGNINT plus two bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct IntArg {
    /// Sent with ARGNINT (the two bytes are a magnitude).
    pub negative: bool,
    /// The two argument bytes, little-endian.
    pub raw: u16,
}

impl IntArg {
    /// The canonical encoding of `v`: ARGINT + v, or ARGNINT + |v| (spec §4).
    #[must_use]
    pub fn from_value(v: i16) -> Self {
        Self {
            negative: v < 0,
            raw: v.unsigned_abs(),
        }
    }

    /// The value as the robot decodes it: the bytes as an `i16`, negated for ARGNINT.
    #[must_use]
    pub fn value(self) -> i16 {
        let v = self.raw as i16;
        if self.negative { v.wrapping_neg() } else { v }
    }
}

/// A command's argument.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Arg<'a> {
    /// No argument.
    None,
    /// An integer.
    Int(IntArg),
    /// A string: exactly the L bytes its length byte announces (a NUL terminator sent after
    /// them, as ARIA does, is surplus and ignored).
    Str(&'a [u8]),
}

impl<'a> Arg<'a> {
    fn parse(bytes: &'a [u8]) -> Result<Self, WireError> {
        let Some((&ty, rest)) = bytes.split_first() else {
            return Ok(Arg::None);
        };
        match ty {
            ARGINT | ARGNINT => match rest {
                // ROS appends a bare ARGINT to SETO: treat as "no argument".
                [] => Ok(Arg::None),
                [lo, hi, ..] => Ok(Arg::Int(IntArg {
                    negative: ty == ARGNINT,
                    raw: u16::from_le_bytes([*lo, *hi]),
                })),
                [_] => Err(WireError::Truncated),
            },
            ARGSTR => {
                let (&len, data) = rest.split_first().ok_or(WireError::Truncated)?;
                let s = data.get(..usize::from(len)).ok_or(WireError::Truncated)?;
                Ok(Arg::Str(s))
            }
            other => Err(WireError::BadArgType(other)),
        }
    }

    fn write(&self, w: &mut Writer<'_>) -> Result<(), WireError> {
        match *self {
            Arg::None => {}
            Arg::Int(i) => {
                w.u8(if i.negative { ARGNINT } else { ARGINT })?.le(i.raw)?;
            }
            Arg::Str(s) => {
                let len = u8::try_from(s.len()).map_err(|_| WireError::ValueOutOfRange)?;
                w.u8(ARGSTR)?.u8(len)?.bytes(s)?;
            }
        }
        Ok(())
    }
}

macro_rules! int_commands {
    ($( $(#[$doc:meta])* $variant:ident = $num:literal, $name:literal; )*) => {
        /// Commands that take one integer argument (spec §6), by number.
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
        #[non_exhaustive]
        pub enum IntCommand {
            $( $(#[$doc])* $variant, )*
        }

        impl IntCommand {
            /// Every integer command.
            pub const ALL: &'static [IntCommand] = &[$(IntCommand::$variant,)*];

            /// The command number on the wire.
            #[must_use]
            pub const fn number(self) -> u8 {
                match self { $( IntCommand::$variant => $num, )* }
            }

            /// The command for a wire number, if it is an integer command.
            #[must_use]
            pub const fn from_number(n: u8) -> Option<Self> {
                match n { $( $num => Some(IntCommand::$variant), )* _ => None }
            }

            /// snake_case name, as in `ima decode` output.
            #[must_use]
            pub const fn name(self) -> &'static str {
                match self { $( IntCommand::$variant => $name, )* }
            }
        }
    };
}

int_commands! {
    /// 1 enables, 0 disables the motors.
    Enable = 4, "enable";
    /// Translational acceleration (+) or deceleration (−), mm/s².
    SetA = 5, "seta";
    /// Maximum translational velocity, mm/s.
    SetV = 6, "setv";
    /// Translate by this distance, mm.
    Move = 8, "move";
    /// Rotate at this rate, deg/s.
    Rotate = 9, "rotate";
    /// Maximum rotational velocity, deg/s.
    SetRv = 10, "setrv";
    /// Translational velocity, mm/s (+ forward).
    Vel = 11, "vel";
    /// Absolute heading, degrees (+ = CCW).
    Head = 12, "head";
    /// Relative heading change, degrees.
    DHead = 13, "dhead";
    /// Joystick packets: 0 off, 1 one, 2 continuous.
    JoyInfo = 17, "joyinfo";
    /// Request one CONFIG packet.
    Config = 18, "config";
    /// ENCODER packets: 0 stop, 1 one, ≥2 continuous.
    Encoder = 19, "encoder";
    /// Rotational velocity, deg/s (+ = CCW).
    RVel = 21, "rvel";
    /// Heading relative to the last setpoint, degrees.
    DcHead = 22, "dchead";
    /// Rotational acceleration (+) or deceleration (−), deg/s².
    SetRa = 23, "setra";
    /// 1 enables, 0 disables all sonar.
    Sonar = 28, "sonar";
    /// Digital outputs: high byte mask, low byte values.
    DigOut = 30, "digout";
    /// Gripper server command.
    Gripper = 33, "gripper";
    /// Select the analog port reported in the SIP.
    AdSel = 35, "adsel";
    /// Gripper value.
    GripperVal = 36, "gripperval";
    /// Gripper packets: 0/1/≥2.
    GripRequest = 37, "griprequest";
    /// IO packets: 0/1/≥2.
    IoRequest = 40, "iorequest";
    /// Pan-tilt servo: high byte port, low byte pulse width ×10 µs.
    PtuPos = 41, "ptupos";
    /// Fetch 1–200 AUX bytes (0 flushes).
    GetAux = 43, "getaux";
    /// Stall on bump: 0 off, 1 front, 2 rear, 3 either.
    BumpStall = 44, "bump_stall";
    /// Compass module mode.
    Tcm2 = 45, "tcm2";
    /// 1 allows joystick driving.
    JoyDrive = 47, "joydrive";
    /// Host serial rate: 0..4 = 9600..115200.
    HostBaud = 50, "hostbaud";
    /// AUX1 serial rate.
    Aux1Baud = 51, "aux1baud";
    /// AUX2 serial rate.
    Aux2Baud = 52, "aux2baud";
    /// Gyro packets on/off.
    Gyro = 58, "gyro";
    /// Rotation PID proportional gain.
    RotKp = 82, "rotkp";
    /// Rotation PID derivative gain.
    RotKv = 83, "rotkv";
    /// Rotation PID integral gain.
    RotKi = 84, "rotki";
    /// Translation PID proportional gain.
    TransKp = 85, "transkp";
    /// Translation PID derivative gain.
    TransKv = 86, "transkv";
    /// Translation PID integral gain.
    TransKi = 87, "transki";
}

/// Commands that take a string argument.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum StrCommand {
    /// Sonar polling sequence (3).
    Polling,
    /// Play tones: (duration ×20 ms, tone) pairs (15).
    Say,
    /// Write to the AUX serial port (42).
    Tty2,
}

impl StrCommand {
    /// The command number on the wire.
    #[must_use]
    pub const fn number(self) -> u8 {
        match self {
            Self::Polling => 3,
            Self::Say => 15,
            Self::Tty2 => 42,
        }
    }
    /// snake_case name.
    #[must_use]
    pub const fn name(self) -> &'static str {
        match self {
            Self::Polling => "polling",
            Self::Say => "say",
            Self::Tty2 => "tty2",
        }
    }
}

/// Command numbers without an argument or with a fixed meaning.
pub mod cmd {
    /// SYNC0 / PULSE.
    pub const SYNC0: u8 = 0;
    /// SYNC1 / OPEN.
    pub const SYNC1: u8 = 1;
    /// SYNC2 / CLOSE.
    pub const SYNC2: u8 = 2;
    /// SETO: reset odometry.
    pub const SETO: u8 = 7;
    /// STOP.
    pub const STOP: u8 = 29;
    /// VEL2: independent wheel velocities.
    pub const VEL2: u8 = 32;
    /// E_STOP: emergency stop.
    pub const E_STOP: u8 = 55;
}

/// How VEL2 is put on the wire (spec §6; both decode alike).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Vel2Style {
    /// `(left << 8 | right)` as a signed integer: ARGNINT + magnitude when negative (ARIA).
    #[default]
    Aria,
    /// ARGINT + the raw bytes `[right, left]` (Player).
    Player,
}

/// Choices for emitting commands where real clients differ.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct EncodeOptions {
    /// VEL2 encoding.
    pub vel2_style: Vel2Style,
    /// Send OPEN and CLOSE with `ARGINT 1` as ARIA does (default: bare, as ROS and Player).
    pub open_close_arg: bool,
}

/// A host → robot command.
///
/// SYNC0/SYNC1/SYNC2 share their numbers with PULSE/OPEN/CLOSE: the bytes are the same and the
/// robot's state decides the meaning (spec §5.2); see [`Command::PULSE`] and friends.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Command<'a> {
    /// SYNC0, or PULSE on an open session (0).
    Sync0,
    /// SYNC1, or OPEN (1).
    Sync1,
    /// SYNC2, or CLOSE (2).
    Sync2,
    /// SETO: odometry := (0, 0, 0) (7).
    SetOdometry,
    /// STOP: decelerate to a stop, motors stay enabled (29).
    Stop,
    /// E_STOP: emergency stop (55).
    EStop,
    /// A command with one integer argument.
    Int(IntCommand, i16),
    /// VEL2: wheel velocities in units of Vel2Divisor mm/s (32).
    Vel2 {
        /// Left wheel, ×Vel2Divisor mm/s.
        left: i8,
        /// Right wheel, ×Vel2Divisor mm/s.
        right: i8,
    },
    /// A command with a string argument.
    Str(StrCommand, &'a [u8]),
    /// A command number this crate does not model, with its argument.
    Other {
        /// Command number.
        number: u8,
        /// Its argument.
        arg: Arg<'a>,
    },
}

impl<'a> Command<'a> {
    /// PULSE: keep-alive on an open session (same bytes as SYNC0).
    pub const PULSE: Command<'static> = Command::Sync0;
    /// OPEN: start the robot's servers (same bytes as SYNC1).
    pub const OPEN: Command<'static> = Command::Sync1;
    /// CLOSE: end the session (same bytes as SYNC2).
    pub const CLOSE: Command<'static> = Command::Sync2;

    /// `ENABLE 1` or `ENABLE 0`.
    #[must_use]
    pub const fn enable(on: bool) -> Self {
        Command::Int(IntCommand::Enable, on as i16)
    }

    /// The command number on the wire.
    #[must_use]
    pub fn number(&self) -> u8 {
        match self {
            Self::Sync0 => cmd::SYNC0,
            Self::Sync1 => cmd::SYNC1,
            Self::Sync2 => cmd::SYNC2,
            Self::SetOdometry => cmd::SETO,
            Self::Stop => cmd::STOP,
            Self::EStop => cmd::E_STOP,
            Self::Int(c, _) => c.number(),
            Self::Vel2 { .. } => cmd::VEL2,
            Self::Str(c, _) => c.number(),
            Self::Other { number, .. } => *number,
        }
    }

    /// snake_case name, as in `ima decode` output (`sync0` etc. for the aliased numbers).
    #[must_use]
    pub fn name(&self) -> &'static str {
        match self {
            Self::Sync0 => "sync0_pulse",
            Self::Sync1 => "sync1_open",
            Self::Sync2 => "sync2_close",
            Self::SetOdometry => "seto",
            Self::Stop => "stop",
            Self::EStop => "e_stop",
            Self::Int(c, _) => c.name(),
            Self::Vel2 { .. } => "vel2",
            Self::Str(c, _) => c.name(),
            Self::Other { .. } => "unknown_command",
        }
    }

    /// Parse a command payload (command byte + argument), as the robot does.
    pub fn parse(payload: &'a [u8]) -> Result<Self, WireError> {
        let (&number, rest) = payload.split_first().ok_or(WireError::EmptyPayload)?;
        let arg = Arg::parse(rest)?;
        let int = |arg: Arg<'_>| match arg {
            Arg::Int(i) => Ok(i.value()),
            Arg::None => Err(WireError::MissingArgument(number)),
            Arg::Str(_) => Err(WireError::BadArgType(ARGSTR)),
        };
        let string = |arg: Arg<'a>| match arg {
            // Trust L (spec §4): ARIA's NUL terminator is *after* the L bytes and is ignored
            // as surplus; a NUL inside L is data (SAY tone 0, binary TTY2 bytes).
            Arg::Str(s) => Ok(s),
            Arg::None => Err(WireError::MissingArgument(number)),
            Arg::Int(i) => Err(WireError::BadArgType(if i.negative {
                ARGNINT
            } else {
                ARGINT
            })),
        };
        Ok(match number {
            cmd::SYNC0 => Command::Sync0,
            cmd::SYNC1 => Command::Sync1,
            cmd::SYNC2 => Command::Sync2,
            cmd::SETO => Command::SetOdometry,
            cmd::STOP => Command::Stop,
            cmd::E_STOP => Command::EStop,
            cmd::VEL2 => {
                let [right, left] = int(arg)?.to_le_bytes();
                Command::Vel2 {
                    left: left as i8,
                    right: right as i8,
                }
            }
            3 => Command::Str(StrCommand::Polling, string(arg)?),
            15 => Command::Str(StrCommand::Say, string(arg)?),
            42 => Command::Str(StrCommand::Tty2, string(arg)?),
            n => match IntCommand::from_number(n) {
                Some(c) => Command::Int(c, int(arg)?),
                None => Command::Other { number: n, arg },
            },
        })
    }

    /// Emit the whole frame with default [`EncodeOptions`]; returns its length.
    pub fn emit(&self, out: &mut [u8]) -> Result<usize, WireError> {
        self.emit_with(EncodeOptions::default(), out)
    }

    /// Emit the whole frame with the given options; returns its length. A command whose count
    /// byte would exceed [`MAX_COMMAND_COUNT`] (which P2OS ignores) is refused with
    /// [`WireError::PayloadTooLong`].
    pub fn emit_with(&self, opts: EncodeOptions, out: &mut [u8]) -> Result<usize, WireError> {
        let arg = match *self {
            Command::Sync1 | Command::Sync2 if opts.open_close_arg => {
                Arg::Int(IntArg::from_value(1))
            }
            Command::Sync0
            | Command::Sync1
            | Command::Sync2
            | Command::SetOdometry
            | Command::Stop
            | Command::EStop => Arg::None,
            Command::Int(_, v) => Arg::Int(IntArg::from_value(v)),
            Command::Vel2 { left, right } => Arg::Int(match opts.vel2_style {
                Vel2Style::Aria => {
                    IntArg::from_value(i16::from_le_bytes([right as u8, left as u8]))
                }
                Vel2Style::Player => IntArg {
                    negative: false,
                    raw: u16::from_le_bytes([right as u8, left as u8]),
                },
            }),
            Command::Str(_, s) => Arg::Str(s),
            Command::Other { arg, .. } => arg,
        };
        let number = self.number();
        let n = emit_with(out, |w| {
            w.u8(number)?;
            arg.write(w)
        })?;
        // P2OS ignores commands with a count over 200 (spec §2): refuse to emit one.
        let count = n.saturating_sub(3);
        if count > usize::from(MAX_COMMAND_COUNT) {
            return Err(WireError::PayloadTooLong(count.saturating_sub(2)));
        }
        Ok(n)
    }
}

// ---------------------------------------------------------------------------------------------
// Robot → host
// ---------------------------------------------------------------------------------------------

/// Packet type bytes.
pub mod ptype {
    /// CONFIG packet.
    pub const CONFIG: u8 = 0x20;
    /// Standard SIP, robot stopped.
    pub const SIP_STOPPED: u8 = 0x32;
    /// Standard SIP, robot moving.
    pub const SIP_MOVING: u8 = 0x33;
    /// ENCODER packet.
    pub const ENCODER: u8 = 0x90;
    /// AUX1 serial data.
    pub const SERAUX: u8 = 0xB0;
    /// AUX2 serial data.
    pub const SERAUX2: u8 = 0xB8;
}

/// Most sonar readings one SIP may carry (indices are 0–31).
pub const MAX_SIP_SONARS: usize = 32;

/// One sonar reading in a SIP, raw units.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct SonarRaw {
    /// Transducer index (0–31).
    pub index: u8,
    /// Range in sonar units (× RangeConvFactor = mm).
    pub range: u16,
}

/// A standard server information packet (spec §7.1), raw units.
#[derive(Debug, Clone, PartialEq, Eq, Hash, Default)]
pub struct Sip {
    /// Type 0x33 (moving) rather than 0x32 (stopped).
    pub moving: bool,
    /// XPOS, 15 significant bits (× DistConvFactor = mm).
    pub xpos: u16,
    /// YPOS, 15 significant bits.
    pub ypos: u16,
    /// THPOS heading (× AngleConvFactor = rad).
    pub thpos: i16,
    /// Left wheel velocity (× VelConvFactor = mm/s).
    pub left_vel: i16,
    /// Right wheel velocity.
    pub right_vel: i16,
    /// Battery, decivolts.
    pub battery: u8,
    /// Stall and bumper bits (low byte: left stall + rear bumpers; high: right stall + front).
    pub stall_bumpers: u16,
    /// Heading-servo setpoint, THPOS units.
    pub control: i16,
    /// FLAGS: bit 0 motors enabled, bits 1–4 sonar on.
    pub flags: u16,
    /// Compass, 2° units (0 = none).
    pub compass: u8,
    /// New sonar readings since the previous SIP.
    pub sonars: heapless::Vec<SonarRaw, MAX_SIP_SONARS>,
    /// Gripper state (byte 14; spec §7.1 choice).
    pub grip_state: u8,
    /// Selected analog port (byte 15).
    pub anport: u8,
    /// Analog reading, 0–255 = 0–5 V.
    pub analog: u8,
    /// Digital inputs.
    pub digin: u8,
    /// Digital outputs.
    pub digout: u8,
    /// Number of bytes after DIGOUT (AROS/ARCOS extras), ignored.
    pub extra_len: u8,
}

/// Flag bit: motors enabled.
pub const FLAG_MOTORS_ENABLED: u16 = 0x0001;
/// Flag bits: sonar arrays on.
pub const FLAG_SONAR_MASK: u16 = 0x001E;

impl Sip {
    /// Payload length of this SIP (25 + 3k).
    #[must_use]
    pub fn payload_len(&self) -> usize {
        25 + 3 * self.sonars.len()
    }

    /// Motors enabled (FLAGS bit 0).
    #[must_use]
    pub fn motors_enabled(&self) -> bool {
        self.flags & FLAG_MOTORS_ENABLED != 0
    }

    fn parse(moving: bool, body: &[u8]) -> Result<Self, WireError> {
        let mut r = Reader::new(body);
        let mut sip = Sip {
            moving,
            xpos: r.le::<u16>()? & 0x7FFF,
            ypos: r.le::<u16>()? & 0x7FFF,
            thpos: r.le()?,
            left_vel: r.le()?,
            right_vel: r.le()?,
            battery: r.u8()?,
            stall_bumpers: r.le()?,
            control: r.le()?,
            flags: r.le()?,
            compass: r.u8()?,
            ..Sip::default()
        };
        let k = r.u8()?;
        // The count must be consistent with the packet's length (spec §10 item 13).
        if usize::from(k) > MAX_SIP_SONARS || r.remaining() < usize::from(k) * 3 + 5 {
            return Err(WireError::BadSonarCount(k));
        }
        // The length was checked above: take the readings at once, three bytes each.
        for reading in r.take(usize::from(k) * 3)?.chunks_exact(3) {
            let &[index, lo, hi] = reading else {
                return Err(WireError::Truncated);
            };
            let range = u16::from_le_bytes([lo, hi]);
            if usize::from(index) >= MAX_SIP_SONARS {
                return Err(WireError::BadSonarIndex(index));
            }
            sip.sonars
                .push(SonarRaw { index, range })
                .map_err(|_| WireError::BadSonarCount(k))?;
        }
        sip.grip_state = r.u8()?;
        sip.anport = r.u8()?;
        sip.analog = r.u8()?;
        sip.digin = r.u8()?;
        sip.digout = r.u8()?;
        sip.extra_len = u8::try_from(r.remaining()).unwrap_or(u8::MAX);
        Ok(sip)
    }

    fn write(&self, w: &mut Writer<'_>) -> Result<(), WireError> {
        w.u8(if self.moving {
            ptype::SIP_MOVING
        } else {
            ptype::SIP_STOPPED
        })?
        .le(self.xpos & 0x7FFF)?
        .le(self.ypos & 0x7FFF)?
        .le(self.thpos)?
        .le(self.left_vel)?
        .le(self.right_vel)?
        .u8(self.battery)?
        .le(self.stall_bumpers)?
        .le(self.control)?
        .le(self.flags)?
        .u8(self.compass)?
        .u8(self.sonars.len() as u8)?;
        for s in &self.sonars {
            w.u8(s.index)?.le(s.range)?;
        }
        w.u8(self.grip_state)?
            .u8(self.anport)?
            .u8(self.analog)?
            .u8(self.digin)?
            .u8(self.digout)?;
        Ok(())
    }
}

macro_rules! config_fields {
    ($( $(#[$doc:meta])* $field:ident : $ty:ident ),* $(,)?) => {
        /// Numeric CONFIG fields after the name string, in wire order (spec §7.3). Fields a
        /// short (older) packet leaves out read as 0, as ARIA does.
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
        #[allow(missing_docs)]
        pub struct ConfigNumbers {
            $( $(#[$doc])* pub $field: $ty, )*
        }

        impl ConfigNumbers {
            fn read(r: &mut Reader<'_>) -> Self {
                Self { $( $field: r.le::<$ty>().unwrap_or_default(), )* }
            }
            fn write(&self, w: &mut Writer<'_>) -> Result<(), Overflow> {
                $( w.le::<$ty>(self.$field)?; )*
                Ok(())
            }
            /// Visit every field as (name, value) — for printing and JSON.
            pub fn for_each(&self, mut f: impl FnMut(&'static str, i64)) {
                $( f(stringify!($field), i64::from(self.$field)); )*
            }
        }
    };
}

config_fields! {
    /// SIP cycle, ms.
    sip_cycle: u8, host_baud: u8, aux1_baud: u8, has_gripper: u16, front_sonar: u16,
    rear_sonar: u8, low_battery: u16, rev_count: u16,
    /// Robot watchdog, ms.
    watchdog: u16,
    normal_mpacs: u8, stall_val: u16, stall_count: u16, joy_vel: u16, joy_rot_vel: u16,
    rot_vel_max: u16, trans_vel_max: u16, rot_accel: u16, rot_decel: u16, rot_kp: u16,
    rot_kv: u16, rot_ki: u16, trans_accel: u16, trans_decel: u16, trans_kp: u16,
    trans_kv: u16, trans_ki: u16, front_bumps: u8, rear_bumps: u8, has_charger: u8,
    sonar_cycle: u8,
    /// 2 = the robot can switch baud rates.
    reset_baud: u8,
    has_gyro: u8, drift_factor: i16, aux2_baud: u8, aux3_baud: u8, ticks_mm: u16,
    shutdown_volts: u16,
}

/// A CONFIG packet (type 0x20, spec §7.3). Strings are NUL-terminated on the wire.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Config<'a> {
    /// Robot class, e.g. "Pioneer".
    pub robot_type: &'a [u8],
    /// Subclass, e.g. "p2at".
    pub subtype: &'a [u8],
    /// Serial number.
    pub serial: &'a [u8],
    /// Byte after the serial (AMRISim: "AT with P2OS" flag).
    pub four_motors: u8,
    /// Top rotational velocity, deg/s.
    pub rot_vel_top: u16,
    /// Top translational velocity, mm/s.
    pub trans_vel_top: u16,
    /// Top rotational acceleration.
    pub rot_acc_top: u16,
    /// Top translational acceleration.
    pub trans_acc_top: u16,
    /// Maximum PWM.
    pub pwm_max: u16,
    /// Robot name.
    pub name: &'a [u8],
    /// The numeric fields that follow the name.
    pub numbers: ConfigNumbers,
    /// Firmware version string (empty when absent).
    pub firmware: &'a [u8],
}

impl<'a> Config<'a> {
    #[inline(never)]
    fn parse(body: &'a [u8]) -> Self {
        let mut r = Reader::new(body);
        Config {
            robot_type: r.take_until(0).unwrap_or_default(),
            subtype: r.take_until(0).unwrap_or_default(),
            serial: r.take_until(0).unwrap_or_default(),
            four_motors: r.u8().unwrap_or_default(),
            rot_vel_top: r.le().unwrap_or_default(),
            trans_vel_top: r.le().unwrap_or_default(),
            rot_acc_top: r.le().unwrap_or_default(),
            trans_acc_top: r.le().unwrap_or_default(),
            pwm_max: r.le().unwrap_or_default(),
            name: r.take_until(0).unwrap_or_default(),
            numbers: ConfigNumbers::read(&mut r),
            firmware: r.take_until(0).unwrap_or_default(),
        }
    }

    fn write(&self, w: &mut Writer<'_>) -> Result<(), Overflow> {
        w.u8(ptype::CONFIG)?;
        for s in [self.robot_type, self.subtype, self.serial] {
            w.bytes(s)?.u8(0)?;
        }
        w.u8(self.four_motors)?
            .le(self.rot_vel_top)?
            .le(self.trans_vel_top)?
            .le(self.rot_acc_top)?
            .le(self.trans_acc_top)?
            .le(self.pwm_max)?
            .bytes(self.name)?
            .u8(0)?;
        self.numbers.write(w)?;
        w.bytes(self.firmware)?.u8(0)?;
        Ok(())
    }
}

/// Choices for parsing robot packets.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ParseOptions {
    /// Accept packet types 0x30–0x34 as SIPs (the ROS driver's rule); default 0x32/0x33 only.
    pub lenient_sip_types: bool,
}

/// A robot → host packet.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Packet<'a> {
    /// Echo of SYNC0 (payload `00`) or SYNC1 (payload `01`).
    SyncEcho(u8),
    /// Reply to SYNC2: type 0x02 and three NUL-terminated strings.
    SyncReply {
        /// Robot name (user-set in FLASH).
        name: &'a [u8],
        /// Class, e.g. "Pioneer".
        class: &'a [u8],
        /// Subclass, e.g. "p2at".
        subclass: &'a [u8],
    },
    /// A standard SIP.
    Sip(Sip),
    /// A CONFIG packet.
    Config(Config<'a>),
    /// ENCODER packet: raw wheel encoder counts.
    Encoder {
        /// Left count, ticks.
        left: i32,
        /// Right count, ticks.
        right: i32,
    },
    /// Bytes read from an AUX serial port.
    SerAux {
        /// 1 for AUX1 (0xB0), 2 for AUX2 (0xB8).
        port: u8,
        /// The bytes.
        data: &'a [u8],
    },
    /// A packet type this crate does not model (reported, not fatal).
    Unknown {
        /// Type byte.
        ptype: u8,
        /// Payload after the type byte.
        body: &'a [u8],
    },
}

impl<'a> Packet<'a> {
    /// snake_case name, as in `ima decode` output.
    #[must_use]
    pub fn name(&self) -> &'static str {
        match self {
            Self::SyncEcho(0) => "sync0",
            Self::SyncEcho(_) => "sync1",
            Self::SyncReply { .. } => "sync2",
            Self::Sip(_) => "sip",
            Self::Config(_) => "config",
            Self::Encoder { .. } => "encoder",
            Self::SerAux { .. } => "seraux",
            Self::Unknown { .. } => "unknown_packet",
        }
    }

    /// Parse a robot packet payload with default options.
    pub fn parse(payload: &'a [u8]) -> Result<Self, WireError> {
        Self::parse_with(ParseOptions::default(), payload)
    }

    /// Parse a robot packet payload.
    pub fn parse_with(opts: ParseOptions, payload: &'a [u8]) -> Result<Self, WireError> {
        let (&ty, body) = payload.split_first().ok_or(WireError::EmptyPayload)?;
        Ok(match ty {
            0 | 1 if body.is_empty() => Packet::SyncEcho(ty),
            2 => {
                let mut r = Reader::new(body);
                Packet::SyncReply {
                    name: r.take_until(0).unwrap_or_default(),
                    class: r.take_until(0).unwrap_or_default(),
                    subclass: r.take_until(0).unwrap_or_default(),
                }
            }
            ptype::SIP_STOPPED | ptype::SIP_MOVING => {
                Packet::Sip(Sip::parse(ty == ptype::SIP_MOVING, body)?)
            }
            0x30 | 0x31 | 0x34 if opts.lenient_sip_types => {
                Packet::Sip(Sip::parse(ty == 0x33, body)?)
            }
            ptype::CONFIG => Packet::Config(Config::parse(body)),
            ptype::ENCODER => {
                let mut r = Reader::new(body);
                Packet::Encoder {
                    left: r.le()?,
                    right: r.le()?,
                }
            }
            ptype::SERAUX => Packet::SerAux {
                port: 1,
                data: body,
            },
            ptype::SERAUX2 => Packet::SerAux {
                port: 2,
                data: body,
            },
            _ => Packet::Unknown { ptype: ty, body },
        })
    }

    /// Emit the whole frame; returns its length.
    pub fn emit(&self, out: &mut [u8]) -> Result<usize, WireError> {
        emit_with(out, |w| {
            match self {
                Packet::SyncEcho(b) => {
                    w.u8(*b)?;
                }
                Packet::SyncReply {
                    name,
                    class,
                    subclass,
                } => {
                    w.u8(2)?;
                    for s in [name, class, subclass] {
                        w.bytes(s)?.u8(0)?;
                    }
                }
                Packet::Sip(sip) => sip.write(w)?,
                Packet::Config(c) => c.write(w)?,
                Packet::Encoder { left, right } => {
                    w.u8(ptype::ENCODER)?.le(*left)?.le(*right)?;
                }
                Packet::SerAux { port, data } => {
                    w.u8(if *port == 2 {
                        ptype::SERAUX2
                    } else {
                        ptype::SERAUX
                    })?
                    .bytes(data)?;
                }
                Packet::Unknown { ptype, body } => {
                    w.u8(*ptype)?.bytes(body)?;
                }
            }
            Ok(())
        })
    }
}

/// Decode one whole robot frame (envelope + packet).
pub fn parse_robot_frame(frame: &[u8]) -> Result<Packet<'_>, WireError> {
    Packet::parse(frame_payload(frame)?)
}

/// Decode one whole host frame (envelope + command).
pub fn parse_host_frame(frame: &[u8]) -> Result<Command<'_>, WireError> {
    Command::parse(frame_payload(frame)?)
}

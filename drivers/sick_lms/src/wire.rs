//! Telegrams of the SICK LMS 2xx serial protocol: framing, CRC, typed commands and replies.
//!
//! Layout (spec §1): `STX addr LEN(u16 LE) CMD DATA… CRC(u16 LE)`, LEN counting CMD through
//! the last DATA byte, the CRC covering STX through the last DATA byte. In device replies the
//! last DATA byte is the status byte ([`StatusByte`]). Both directions parse *and* emit, so the
//! mock device reuses this module: the host emits [`Command`]s and parses [`Reply`]s, the mock
//! parses [`Command`]s and emits [`Reply`]s.
//!
//! Views borrow: a parsed [`Reply`] points into the telegram (a B0 scan of 361 values is not
//! copied). Nothing here allocates, panics on input, or does I/O.

use core::fmt;

use ima_hal::bytes::{Reader, Writer};

/// Start of every telegram.
pub const STX: u8 = 0x02;
/// Standalone acknowledge byte: the LMS accepted a host telegram (spec §2).
pub const ACK: u8 = 0x06;
/// Standalone negative acknowledge byte: bad CRC or bad frame (spec §2).
pub const NAK: u8 = 0x15;
/// Address the host sends to (broadcast; spec §1).
pub const HOST_TO_LMS_ADDRESS: u8 = 0x00;
/// Default address of LMS replies (`0x80 | LMS address`); replies at `0x80..=0xFF` are accepted.
pub const DEFAULT_REPLY_ADDRESS: u8 = 0x80;
/// Largest LEN accepted (spec §1: reject LEN = 0 and LEN > 808).
pub const MAX_LEN: u16 = 808;
/// Largest whole telegram: LEN + 6 = 814 (401 values plus real-time indices).
pub const MAX_TELEGRAM: usize = MAX_LEN as usize + 6;
/// Most values in one B0 scan (100° at 0.25°).
pub const MAX_VALUES: usize = 401;
/// The factory installation-mode password `SICK_LMS` (spec §3.1).
pub const DEFAULT_PASSWORD: [u8; 8] = *b"SICK_LMS";

/// Command codes (host → LMS), spec §3.
pub mod cmd {
    /// Reset.
    pub const RESET: u8 = 0x10;
    /// Change operating mode.
    pub const SET_MODE: u8 = 0x20;
    /// Request measured values.
    pub const REQUEST_VALUES: u8 = 0x30;
    /// Request status.
    pub const STATUS: u8 = 0x31;
    /// Request error/test messages.
    pub const ERRORS: u8 = 0x32;
    /// Request the type string.
    pub const TYPE: u8 = 0x3A;
    /// Switch variant (field width and resolution).
    pub const VARIANT: u8 = 0x3B;
    /// Read the configuration.
    pub const READ_CONFIG: u8 = 0x74;
    /// Write the configuration (installation mode only).
    pub const WRITE_CONFIG: u8 = 0x77;
}

/// What the command `code` does, in words (`None`: not a command of spec §3).
#[must_use]
pub const fn command_name(code: u8) -> Option<&'static str> {
    Some(match code {
        cmd::RESET => "reset",
        cmd::SET_MODE => "change operating mode",
        cmd::REQUEST_VALUES => "request measured values",
        cmd::STATUS => "request status",
        cmd::ERRORS => "request errors",
        cmd::TYPE => "request type",
        cmd::VARIANT => "switch variant",
        cmd::READ_CONFIG => "read configuration",
        cmd::WRITE_CONFIG => "write configuration",
        _ => return None,
    })
}

/// Reply codes (LMS → host), spec §2–§3. A reply is its request's code + `0x80`, except reset.
pub mod reply {
    /// Power-on telegram (unsolicited; also the second answer to a reset).
    pub const POWER_ON: u8 = 0x90;
    /// Reset confirmation.
    pub const RESET_ACK: u8 = 0x91;
    /// Telegram received correctly but not allowed (unknown command, wrong mode).
    pub const REJECTED: u8 = 0x92;
    /// Operating-mode change result.
    pub const MODE: u8 = 0xA0;
    /// Measured values.
    pub const SCAN: u8 = 0xB0;
    /// Status block.
    pub const STATUS: u8 = 0xB1;
    /// Error pairs.
    pub const ERRORS: u8 = 0xB2;
    /// Type string.
    pub const TYPE: u8 = 0xBA;
    /// Variant result.
    pub const VARIANT: u8 = 0xBB;
    /// Configuration.
    pub const CONFIG: u8 = 0xF4;
    /// Configuration-write result.
    pub const CONFIG_WRITTEN: u8 = 0xF7;
}

/// The reply code that answers command code `command` (spec §2: `+ 0x80`, reset → `0x91`).
#[must_use]
pub const fn expected_reply(command: u8) -> u8 {
    if command == cmd::RESET {
        reply::RESET_ACK
    } else {
        command | 0x80
    }
}

/// Is `code` a command code this module parses?
#[must_use]
pub const fn is_known_command(code: u8) -> bool {
    matches!(
        code,
        cmd::RESET
            | cmd::SET_MODE
            | cmd::REQUEST_VALUES
            | cmd::STATUS
            | cmd::ERRORS
            | cmd::TYPE
            | cmd::VARIANT
            | cmd::READ_CONFIG
            | cmd::WRITE_CONFIG
    )
}

/// Is `code` a reply code this module parses?
#[must_use]
pub const fn is_known_reply(code: u8) -> bool {
    matches!(
        code,
        reply::POWER_ON
            | reply::RESET_ACK
            | reply::REJECTED
            | reply::MODE
            | reply::SCAN
            | reply::STATUS
            | reply::ERRORS
            | reply::TYPE
            | reply::VARIANT
            | reply::CONFIG
            | reply::CONFIG_WRITTEN
    )
}

/// What was wrong with a telegram. Small and `Copy`; every variant names the defect.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum WireError {
    /// Fewer bytes than the layout needs.
    Truncated,
    /// The first byte is not STX.
    BadStx(u8),
    /// An address not allowed in this direction (replies `0x80..=0xFF`, commands `< 0x80`).
    BadAddress(u8),
    /// LEN is 0, above [`MAX_LEN`], or disagrees with the bytes given.
    BadLength(u16),
    /// The CRC on the wire is not the one computed over the telegram.
    BadChecksum {
        /// CRC computed over the received bytes.
        expected: u16,
        /// CRC found on the wire.
        got: u16,
    },
    /// A command or reply code this module does not know.
    UnknownCommand(u8),
    /// A known code whose DATA has the wrong size for it.
    BadPayload {
        /// The command or reply code.
        code: u8,
        /// The DATA length found (bytes after CMD).
        len: u16,
    },
    /// A B0 count word whose value count disagrees with LEN.
    CountMismatch {
        /// Values claimed by the count word.
        count: u16,
        /// LEN of the telegram.
        len: u16,
    },
    /// A value that cannot be encoded (too many values, an unknown baud code, …).
    InvalidField,
    /// The output buffer is too small for the telegram.
    BufferTooSmall,
}

impl fmt::Display for WireError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Truncated => f.write_str("truncated telegram"),
            Self::BadStx(b) => write!(f, "expected STX, got {b:#04x}"),
            Self::BadAddress(a) => write!(f, "address {a:#04x} not allowed here"),
            Self::BadLength(l) => write!(f, "bad LEN {l}"),
            Self::BadChecksum { expected, got } => {
                write!(f, "bad CRC: computed {expected:#06x}, got {got:#06x}")
            }
            Self::UnknownCommand(c) => write!(f, "unknown code {c:#04x}"),
            Self::BadPayload { code, len } => write!(f, "code {code:#04x} with {len} data bytes"),
            Self::CountMismatch { count, len } => {
                write!(f, "B0 count {count} disagrees with LEN {len}")
            }
            Self::InvalidField => f.write_str("field cannot be encoded"),
            Self::BufferTooSmall => f.write_str("output buffer too small"),
        }
    }
}

impl core::error::Error for WireError {}

/// SICK's CRC-16 (spec §1.1): polynomial `0x8005`, initial 0, the previous byte folded into the
/// high half, no reflection, no final XOR. Sent low byte first.
///
/// Computed 32 bytes at a time (see [`crc16_bitwise`] for the definition and the derivation);
/// the result is the same for every input.
#[must_use]
pub fn crc16(bytes: &[u8]) -> u16 {
    let Some(&last) = bytes.last() else {
        return 0;
    };
    // E = Σ b_i·x^(n−1−i) mod P, by Horner's rule over blocks: E ← x^k·E + V_k.
    let mut e: u16 = 0;
    let mut blocks = bytes.chunks_exact(32);
    for block in &mut blocks {
        e = mul_x32(e) ^ reduce39(fold32(block));
    }
    let mut rest = blocks.remainder().chunks_exact(8);
    for block in &mut rest {
        e = mul_x8(e) ^ fold8(be64(block));
    }
    for &b in rest.remainder() {
        e = mul_x(e) ^ u16::from(b);
    }
    // crc = (1 + x^7)·E + x^7·b_(n−1) mod P.
    reduce39(u64::from(e) ^ (u64::from(e) << 7)) ^ (u16::from(last) << 7)
}

/// The bit-serial definition of [`crc16`], one byte per step, exactly as the spec (§1.1) and the
/// C drivers state it. Kept as the reference the fast version is tested against.
///
/// Per byte `b` (with `prev` the byte before it, 0 at the start): `crc ← x·crc mod P` (shift left,
/// XOR `0x8005` if bit 15 was set), then `crc ^= prev << 8 | b`. Over GF(2) with
/// `P = x^16 + x^15 + x^2 + 1` this is `crc_n = Σ x^(n−1−i)·(x^8·b_(i−1) + b_i)`, which regroups
/// as `(1 + x^7)·E + x^7·b_(n−1)` with `E = Σ b_i·x^(n−1−i)`: a register that moves one bit per
/// *byte*. Eight bytes of `E` therefore combine without any reduction into a 15-bit
/// `Σ b_j·x^(7−j)` (three shift-and-mask folds of a `u64`), four of those into a 39-bit
/// `Σ b_j·x^(31−j)` per 32 bytes, and only the reduction of that and the register's own `x^32`
/// step need the byte tables `h·x^(16…40) mod P` below, which `const fn` derives from this
/// definition's shift step at compile time.
#[must_use]
pub fn crc16_bitwise(bytes: &[u8]) -> u16 {
    let mut crc: u16 = 0;
    let mut prev: u8 = 0;
    for &b in bytes {
        crc = mul_x(crc) ^ u16::from_be_bytes([prev, b]);
        prev = b;
    }
    crc
}

/// `x·c mod P`: the register's shift step (spec §1.1).
#[inline(always)]
const fn mul_x(c: u16) -> u16 {
    if c & 0x8000 != 0 {
        (c << 1) ^ 0x8005
    } else {
        c << 1
    }
}

/// `h·x^shifts mod P` for a byte `h`, by [`mul_x`] alone (`h·x^8` fits in 16 bits).
const fn byte_times_x(h: u16, shifts: u32) -> u16 {
    let mut c = h << 8;
    let mut s = 8;
    while s < shifts {
        c = mul_x(c);
        s += 1;
    }
    c
}

/// The table `h ↦ h·x^shifts mod P` over all bytes `h`, built at compile time.
const fn byte_table(shifts: u32) -> [u16; 256] {
    let mut t = [0u16; 256];
    let mut rest: &mut [u16] = &mut t;
    let mut h = 0;
    while let [slot, tail @ ..] = rest {
        *slot = byte_times_x(h, shifts);
        rest = tail;
        h += 1;
    }
    t
}

/// `h·x^16 mod P`: reduces a byte at bits 16–23.
const X16: [u16; 256] = byte_table(16);
/// `h·x^24 mod P`: reduces a byte at bits 24–31.
const X24: [u16; 256] = byte_table(24);
/// `h·x^32 mod P`: reduces a byte at bits 32–39.
const X32: [u16; 256] = byte_table(32);
/// `h·x^40 mod P`: reduces a byte at bits 40–47.
const X40: [u16; 256] = byte_table(40);

/// `table[h]`; a `u8` index is always in range, the fallback is never taken (compiled out).
#[inline(always)]
fn look(table: &[u16; 256], h: u8) -> u16 {
    table.get(usize::from(h)).copied().unwrap_or(0)
}

/// `x^8·e mod P`.
#[inline(always)]
fn mul_x8(e: u16) -> u16 {
    let [hi, lo] = e.to_be_bytes();
    (u16::from(lo) << 8) ^ look(&X16, hi)
}

/// `x^32·e mod P`.
#[inline(always)]
fn mul_x32(e: u16) -> u16 {
    let [hi, lo] = e.to_be_bytes();
    look(&X32, lo) ^ look(&X40, hi)
}

/// `v mod P` for `v` below `2^40`.
#[inline(always)]
fn reduce39(v: u64) -> u16 {
    let [_, _, _, b4, b3, b2, hi, lo] = v.to_be_bytes();
    u16::from_be_bytes([hi, lo]) ^ look(&X16, b2) ^ look(&X24, b3) ^ look(&X32, b4)
}

/// The eight bytes of `block` as a big-endian word, `b_0` the most significant (`block` is 8
/// bytes long; shorter input would read as 0).
#[inline(always)]
fn be64(block: &[u8]) -> u64 {
    u64::from_be_bytes(block.try_into().unwrap_or([0; 8]))
}

/// `Σ b_j·x^(31−j)` over a 32-byte block (39 bits, no reduction needed), as
/// `V(a)·x^16 + V(b)` of its halves, each `fold8(a0)·x^8 + fold8(a1)` with the last fold step
/// done once for both words of a half.
#[inline(always)]
fn fold32(block: &[u8]) -> u64 {
    // chunks_exact(32) hands out 32-byte slices: the fallback is never taken.
    let b: [u8; 32] = block.try_into().unwrap_or([0; 32]);
    let mut w = [0u64; 4];
    for (w, q) in w.iter_mut().zip(b.chunks_exact(8)) {
        *w = fold_quads(be64(q));
    }
    let [w0, w1, w2, w3] = w;
    (u64::from(fold_halves16(w0, w1)) << 16) ^ u64::from(fold_halves16(w2, w3))
}

/// The first two steps of [`fold8`]: two 11-bit `Σ b_j·x^(3−j)`, one per half of `w`.
#[inline(always)]
const fn fold_quads(w: u64) -> u64 {
    // 16-bit lanes (b_2k high, b_2k+1 low) → b_2k·x + b_2k+1 (9 bits).
    let w = ((w >> 7) & 0x01FE_01FE_01FE_01FE) ^ (w & 0x00FF_00FF_00FF_00FF);
    // 32-bit lanes → high·x^2 + low (11 bits).
    ((w >> 14) & 0x0000_07FC_0000_07FC) ^ (w & 0x0000_01FF_0000_01FF)
}

/// The last step of [`fold8`] for two words at once: `fold8(a)·x^8 + fold8(b)` (23 bits) from
/// their [`fold_quads`]. Shifted by 8, `a`'s 11-bit fields stay clear of the other half, so one
/// wider mask serves both.
#[inline(always)]
const fn fold_halves16(a: u64, b: u64) -> u32 {
    let w = (a << 8) ^ b;
    // At most 23 bits set: the cast keeps them all.
    (((w >> 28) & 0x007F_FFF0) ^ (w & 0x0007_FFFF)) as u32
}

/// `Σ b_j·x^(7−j)` over the eight bytes of the big-endian word `w` (`b_0` the most significant;
/// 15 bits, no reduction needed): fold neighbouring bytes, then pairs, then quads, each a
/// shift-and-mask over the whole word.
#[inline(always)]
const fn fold8(w: u64) -> u16 {
    let w = fold_quads(w);
    // Both halves → high·x^4 + low (15 bits); the cast keeps them all.
    (((w >> 28) & 0x7FF0) ^ (w & 0x07FF)) as u16
}

// ---------------------------------------------------------------------------------------------
// The shared byte cursors' errors.

ima_hal::cursor_errors!(WireError {
    truncated: |_| WireError::Truncated,
    overflow: |_| WireError::BufferTooSmall,
});

/// Write the header and CRC around a body already written at `buf[4..4 + body_len]`
/// (CMD + DATA). Returns the telegram length.
fn finish_telegram(buf: &mut [u8], address: u8, body_len: usize) -> Result<usize, WireError> {
    let len = u16::try_from(body_len).map_err(|_| WireError::InvalidField)?;
    if len == 0 || len > MAX_LEN {
        return Err(WireError::BadLength(len));
    }
    let crc_at = body_len + 4;
    let total = crc_at + 2;
    let head = buf.get_mut(..4).ok_or(WireError::BufferTooSmall)?;
    let [lo, hi] = len.to_le_bytes();
    head.copy_from_slice(&[STX, address, lo, hi]);
    let crc = crc16(buf.get(..crc_at).ok_or(WireError::BufferTooSmall)?);
    buf.get_mut(crc_at..total)
        .ok_or(WireError::BufferTooSmall)?
        .copy_from_slice(&crc.to_le_bytes());
    Ok(total)
}

// ---------------------------------------------------------------------------------------------
// Frame view

/// A checked telegram: STX, LEN within bounds and matching the bytes, CRC good.
///
/// The address is *not* judged here (it depends on the direction); [`Command::from_frame`] and
/// [`Reply::from_frame`] do that.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Frame<'a> {
    bytes: &'a [u8],
}

impl<'a> Frame<'a> {
    /// Check `bytes` as exactly one telegram.
    pub fn new_checked(bytes: &'a [u8]) -> Result<Self, WireError> {
        let mut r = Reader::new(bytes);
        let stx = r.u8()?;
        if stx != STX {
            return Err(WireError::BadStx(stx));
        }
        let _address = r.u8()?;
        let len = r.le::<u16>()?;
        if len == 0 || len > MAX_LEN {
            return Err(WireError::BadLength(len));
        }
        let body = r.take(usize::from(len))?;
        let got = r.le::<u16>()?;
        if r.remaining() != 0 {
            return Err(WireError::BadLength(len));
        }
        let covered = bytes.get(..4 + body.len()).ok_or(WireError::Truncated)?;
        let expected = crc16(covered);
        if expected != got && !cfg!(fuzzing) {
            return Err(WireError::BadChecksum { expected, got });
        }
        Ok(Self { bytes })
    }

    /// Wrap bytes already checked by [`Frame::new_checked`].
    pub(crate) const fn new_unchecked(bytes: &'a [u8]) -> Self {
        Self { bytes }
    }

    /// The whole telegram.
    #[must_use]
    pub fn as_bytes(&self) -> &'a [u8] {
        self.bytes
    }

    /// The address byte.
    #[must_use]
    pub fn address(&self) -> u8 {
        self.bytes.get(1).copied().unwrap_or(0)
    }

    /// The command or reply code.
    #[must_use]
    pub fn code(&self) -> u8 {
        self.bytes.get(4).copied().unwrap_or(0)
    }

    /// DATA: the bytes after the code, without the CRC (in replies: ending with the status).
    #[must_use]
    pub fn data(&self) -> &'a [u8] {
        let end = self.bytes.len().saturating_sub(2);
        self.bytes.get(5..end).unwrap_or(&[])
    }
}

// ---------------------------------------------------------------------------------------------
// Shared field types

/// The reply status byte `S` (spec §1). Errors are judged by bits 0–2 only.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct StatusByte(pub u8);

/// Severity in bits 0–2 of the status byte.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Severity {
    /// 0: no error.
    Ok,
    /// 1: information.
    Info,
    /// 2: warning.
    Warning,
    /// 3: error.
    Error,
    /// 4: fatal error.
    Fatal,
    /// 5–7: reserved codes.
    Reserved(u8),
}

impl StatusByte {
    /// The status normal replies carry (`0x10`: OK, device-type bits `10`).
    pub const NORMAL: Self = Self(0x10);

    /// Severity from bits 0–2.
    #[must_use]
    pub const fn severity(self) -> Severity {
        match self.0 & 0x07 {
            0 => Severity::Ok,
            1 => Severity::Info,
            2 => Severity::Warning,
            3 => Severity::Error,
            4 => Severity::Fatal,
            n => Severity::Reserved(n),
        }
    }

    /// Severity is error or fatal (reserved codes count as errors).
    #[must_use]
    pub const fn is_error(self) -> bool {
        self.0 & 0x07 >= 3
    }

    /// Bits 3–4: data source / device type.
    #[must_use]
    pub const fn device_type(self) -> u8 {
        (self.0 >> 3) & 0x03
    }

    /// Bit 5: restart.
    #[must_use]
    pub const fn restart(self) -> bool {
        self.0 & 0x20 != 0
    }

    /// Bit 6: implausible measured values.
    #[must_use]
    pub const fn implausible(self) -> bool {
        self.0 & 0x40 != 0
    }

    /// Bit 7: the front screen is polluted.
    #[must_use]
    pub const fn pollution(self) -> bool {
        self.0 & 0x80 != 0
    }
}

/// Serial rates the LMS 2xx supports (spec §1, §3.1).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum BaudRate {
    /// 9600 baud (power-up default).
    B9600,
    /// 19200 baud.
    B19200,
    /// 38400 baud.
    B38400,
    /// 500 000 baud (RS-422 only).
    B500000,
}

impl BaudRate {
    /// All rates, in the spec's probe order (§4): 9600, 38400, 19200, 500000.
    pub const PROBE_ORDER: [Self; 4] = [Self::B9600, Self::B38400, Self::B19200, Self::B500000];

    /// Bits per second.
    #[must_use]
    pub const fn bps(self) -> u32 {
        match self {
            Self::B9600 => 9600,
            Self::B19200 => 19200,
            Self::B38400 => 38400,
            Self::B500000 => 500_000,
        }
    }

    /// The rate of `bps`, if the LMS supports it.
    #[must_use]
    pub const fn from_bps(bps: u32) -> Option<Self> {
        match bps {
            9600 => Some(Self::B9600),
            19200 => Some(Self::B19200),
            38400 => Some(Self::B38400),
            500_000 => Some(Self::B500000),
            _ => None,
        }
    }

    /// Operating-mode code of `0x20` that switches to this rate.
    #[must_use]
    pub const fn mode_code(self) -> u8 {
        match self {
            Self::B38400 => 0x40,
            Self::B19200 => 0x41,
            Self::B9600 => 0x42,
            Self::B500000 => 0x48,
        }
    }

    /// The rate of a `0x20` mode code.
    #[must_use]
    pub const fn from_mode_code(code: u8) -> Option<Self> {
        match code {
            0x40 => Some(Self::B38400),
            0x41 => Some(Self::B19200),
            0x42 => Some(Self::B9600),
            0x48 => Some(Self::B500000),
            _ => None,
        }
    }

    /// The code the status block reports at offsets 116–117 (spec §3.4).
    #[must_use]
    pub const fn status_code(self) -> u16 {
        match self {
            Self::B9600 => 0x8067,
            Self::B19200 => 0x8033,
            Self::B38400 => 0x8019,
            Self::B500000 => 0x8001,
        }
    }

    /// The rate of a status-block baud code.
    #[must_use]
    pub const fn from_status_code(code: u16) -> Option<Self> {
        match code {
            0x8067 => Some(Self::B9600),
            0x8033 => Some(Self::B19200),
            0x8019 => Some(Self::B38400),
            0x8001 => Some(Self::B500000),
            _ => None,
        }
    }
}

/// Up to 16 raw parameter bytes of a command this module does not type.
pub type Params = heapless::Vec<u8, 16>;

/// Operating modes of command `0x20` (spec §3.1).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ModeRequest {
    /// `00`: installation mode (needed before a config write), with its 8-byte password.
    Installation {
        /// Password, normally [`DEFAULT_PASSWORD`].
        password: [u8; 8],
    },
    /// `10`: diagnostic mode.
    Diagnostic,
    /// `24`: continuous output of all values (B0 stream).
    StreamAll,
    /// `25`: values on request only (the idle mode; stops a stream).
    RequestOnly,
    /// `26`: stream mean values over `samples` scans.
    StreamMean {
        /// Number of scans averaged.
        samples: u8,
    },
    /// `27`: stream a sub-range of values (1-based indices).
    StreamSubrange {
        /// First value (1-based).
        start: u16,
        /// Last value (1-based).
        end: u16,
    },
    /// `28`: mean values of a sub-range.
    MeanSubrange {
        /// Number of scans averaged.
        samples: u8,
        /// First value (1-based).
        start: u16,
        /// Last value (1-based).
        end: u16,
    },
    /// `2A`: stream partial scans.
    StreamPartial,
    /// `40`/`41`/`42`/`48`: switch the serial rate (takes effect after the `A0` reply).
    Baud(BaudRate),
    /// Any other mode code, with its raw parameters (e.g. `2B` range + reflectivity).
    Other {
        /// The mode code (never one of the codes typed above).
        code: u8,
        /// Raw parameter bytes.
        params: Params,
    },
}

impl ModeRequest {
    /// The mode code on the wire.
    #[must_use]
    pub fn code(&self) -> u8 {
        match self {
            Self::Installation { .. } => 0x00,
            Self::Diagnostic => 0x10,
            Self::StreamAll => 0x24,
            Self::RequestOnly => 0x25,
            Self::StreamMean { .. } => 0x26,
            Self::StreamSubrange { .. } => 0x27,
            Self::MeanSubrange { .. } => 0x28,
            Self::StreamPartial => 0x2A,
            Self::Baud(b) => b.mode_code(),
            Self::Other { code, .. } => *code,
        }
    }

    /// Is `code` one of the typed mode codes (never carried by [`ModeRequest::Other`])?
    #[must_use]
    pub const fn is_typed_code(code: u8) -> bool {
        matches!(
            code,
            0x00 | 0x10 | 0x24 | 0x25 | 0x26 | 0x27 | 0x28 | 0x2A | 0x40 | 0x41 | 0x42 | 0x48
        )
    }

    fn parse(data: &[u8]) -> Result<Self, WireError> {
        let bad = || WireError::BadPayload {
            code: cmd::SET_MODE,
            len: u16::try_from(data.len()).unwrap_or(u16::MAX),
        };
        let mut r = Reader::new(data);
        let code = r.u8().map_err(|_| bad())?;
        let m = match code {
            0x00 => Self::Installation {
                password: r.array::<8>().map_err(|_| bad())?,
            },
            0x10 => Self::Diagnostic,
            0x24 => Self::StreamAll,
            0x25 => Self::RequestOnly,
            0x26 => Self::StreamMean {
                samples: r.u8().map_err(|_| bad())?,
            },
            0x27 => Self::StreamSubrange {
                start: r.le::<u16>().map_err(|_| bad())?,
                end: r.le::<u16>().map_err(|_| bad())?,
            },
            0x28 => Self::MeanSubrange {
                samples: r.u8().map_err(|_| bad())?,
                start: r.le::<u16>().map_err(|_| bad())?,
                end: r.le::<u16>().map_err(|_| bad())?,
            },
            0x2A => Self::StreamPartial,
            c => match BaudRate::from_mode_code(c) {
                Some(b) => Self::Baud(b),
                None => {
                    let params = Params::from_slice(r.take_rest()).map_err(|_| bad())?;
                    Self::Other { code: c, params }
                }
            },
        };
        if r.remaining() != 0 {
            return Err(bad());
        }
        Ok(m)
    }

    fn emit(&self, w: &mut Writer<'_>) -> Result<(), WireError> {
        if let Self::Other { code, .. } = self
            && Self::is_typed_code(*code)
        {
            return Err(WireError::InvalidField);
        }
        w.u8(self.code())?;
        match self {
            Self::Installation { password } => {
                w.bytes(password)?;
            }
            Self::StreamMean { samples } => {
                w.u8(*samples)?;
            }
            Self::StreamSubrange { start, end } => {
                w.le(*start)?.le(*end)?;
            }
            Self::MeanSubrange {
                samples,
                start,
                end,
            } => {
                w.u8(*samples)?.le(*start)?.le(*end)?;
            }
            Self::Other { params, .. } => {
                w.bytes(params)?;
            }
            Self::Diagnostic
            | Self::StreamAll
            | Self::RequestOnly
            | Self::StreamPartial
            | Self::Baud(_) => {}
        }
        Ok(())
    }
}

/// The 32- or 34-byte LMS configuration block of `74`/`77` (spec §3.7), kept byte-exact so a
/// read-modify-write changes only what it means to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct LmsConfig {
    bytes: [u8; LmsConfig::LONG],
    long: bool,
}

impl LmsConfig {
    /// Size of the older/QM form.
    pub const SHORT: usize = 32;
    /// Size of the TL/STB form (adds the dazzle multiple evaluation word).
    pub const LONG: usize = 34;
    /// Offset of the availability byte.
    pub const AVAILABILITY: usize = 4;
    /// Offset of the measuring-mode byte.
    pub const MEASURING_MODE: usize = 5;
    /// Offset of the units byte.
    pub const UNITS: usize = 6;

    /// A config from its 32 or 34 raw bytes.
    pub fn from_bytes(raw: &[u8]) -> Result<Self, WireError> {
        let long = match raw.len() {
            Self::SHORT => false,
            Self::LONG => true,
            _ => return Err(WireError::InvalidField),
        };
        let mut bytes = [0u8; Self::LONG];
        bytes
            .get_mut(..raw.len())
            .ok_or(WireError::InvalidField)?
            .copy_from_slice(raw);
        Ok(Self { bytes, long })
    }

    /// An all-zero block of the given form (a starting point for mocks and tests).
    #[must_use]
    pub const fn zeroed(long: bool) -> Self {
        Self {
            bytes: [0; Self::LONG],
            long,
        }
    }

    /// The raw bytes (32 or 34).
    #[must_use]
    pub fn as_bytes(&self) -> &[u8] {
        let n = if self.long { Self::LONG } else { Self::SHORT };
        self.bytes.get(..n).unwrap_or(&self.bytes)
    }

    /// The 34-byte form?
    #[must_use]
    pub const fn is_long(&self) -> bool {
        self.long
    }

    fn byte(&self, i: usize) -> u8 {
        self.bytes.get(i).copied().unwrap_or(0)
    }

    fn set_byte(&mut self, i: usize, v: u8) {
        if let Some(b) = self.bytes.get_mut(i) {
            *b = v;
        }
    }

    /// Blanking, centimetres (bytes 0–1).
    #[must_use]
    pub fn blanking_cm(&self) -> u16 {
        u16::from_le_bytes([self.byte(0), self.byte(1)])
    }

    /// Availability byte 4: `01` high availability, `02` real-time indices, `04` dazzle off.
    #[must_use]
    pub fn availability(&self) -> u8 {
        self.byte(Self::AVAILABILITY)
    }

    /// Set the availability byte.
    pub fn set_availability(&mut self, v: u8) {
        self.set_byte(Self::AVAILABILITY, v);
    }

    /// Measuring mode, byte 5.
    #[must_use]
    pub fn measuring_mode(&self) -> MeasuringMode {
        MeasuringMode(self.byte(Self::MEASURING_MODE))
    }

    /// Set the measuring mode.
    pub fn set_measuring_mode(&mut self, m: MeasuringMode) {
        self.set_byte(Self::MEASURING_MODE, m.0);
    }

    /// Units byte 6: 0 = cm, 1 = mm (2 = dm in CAR/PLY).
    #[must_use]
    pub fn units(&self) -> u8 {
        self.byte(Self::UNITS)
    }

    /// Set the units byte.
    pub fn set_units(&mut self, v: u8) {
        self.set_byte(Self::UNITS, v);
    }
}

/// Measuring mode (config byte 5): decides the value word's distance mask and flag bits
/// (spec §3.3 table).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct MeasuringMode(pub u8);

impl MeasuringMode {
    /// Mode `00`: 8 m in mm / 80 m in cm, three flag bits (default).
    pub const DEFAULT: Self = Self(0x00);

    /// Distance mask of the value word, or `None` for a mode the spec does not list.
    #[must_use]
    pub const fn distance_mask(self) -> Option<u16> {
        match self.0 {
            0x00..=0x02 => Some(0x1FFF),
            0x03 | 0x04 => Some(0x3FFF),
            0x05 | 0x06 => Some(0x7FFF),
            0x0F | 0x3F => Some(0xFFFF),
            _ => None,
        }
    }

    /// The 13-bit modes carry the special codes `1FF7..=1FFF` (spec §3.3).
    #[must_use]
    pub const fn has_special_values(self) -> bool {
        matches!(self.0, 0x00..=0x02)
    }

    /// The mode reports reflectivity, not range (`3F`, LMS 291-S14).
    #[must_use]
    pub const fn is_reflectivity(self) -> bool {
        self.0 == 0x3F
    }
}

/// Distance unit of B0 values (count word bits 14–15, spec §3.3).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Units {
    /// `00`: centimetres.
    Cm,
    /// `01`: millimetres.
    Mm,
    /// `10`: decimetres (CAR; the TL reserves it).
    Dm,
    /// `11`: reserved.
    Reserved,
}

impl Units {
    /// Metres per count, or `None` when reserved.
    #[must_use]
    pub const fn metres(self) -> Option<f32> {
        match self {
            Self::Cm => Some(0.01),
            Self::Mm => Some(0.001),
            Self::Dm => Some(0.1),
            Self::Reserved => None,
        }
    }

    /// The two-bit code.
    #[must_use]
    pub const fn code(self) -> u16 {
        match self {
            Self::Cm => 0,
            Self::Mm => 1,
            Self::Dm => 2,
            Self::Reserved => 3,
        }
    }

    /// From the two-bit code (higher bits ignored).
    #[must_use]
    pub const fn from_code(c: u16) -> Self {
        match c & 3 {
            0 => Self::Cm,
            1 => Self::Mm,
            2 => Self::Dm,
            _ => Self::Reserved,
        }
    }
}

/// The B0 count word (spec §3.3): value count in bits 0–9, raw flags above.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct CountWord(pub u16);

impl CountWord {
    /// Mask of the value count (bits 0–9; STB's choice, see crate docs).
    pub const COUNT_MASK: u16 = 0x03FF;

    /// A count word for a full scan (bits 10–13 zero).
    #[must_use]
    pub const fn full_scan(count: u16, units: Units) -> Self {
        Self((count & Self::COUNT_MASK) | (units.code() << 14))
    }

    /// Number of values.
    #[must_use]
    pub const fn count(self) -> u16 {
        self.0 & Self::COUNT_MASK
    }

    /// Bit 10 (reserved), raw.
    #[must_use]
    pub const fn reserved_bit(self) -> bool {
        self.0 & 0x0400 != 0
    }

    /// Bits 11–12: partial-scan index (offset 0, 0.25, 0.5, 0.75°).
    #[must_use]
    pub const fn partial_index(self) -> u8 {
        ((self.0 >> 11) & 0x03) as u8
    }

    /// Bit 13: this is a partial scan.
    #[must_use]
    pub const fn partial(self) -> bool {
        self.0 & 0x2000 != 0
    }

    /// Bits 14–15: units.
    #[must_use]
    pub const fn units(self) -> Units {
        Units::from_code(self.0 >> 14)
    }

    /// Bits 10–15 as they came (for callers that interpret them differently).
    #[must_use]
    pub const fn raw_flags(self) -> u16 {
        self.0 & !Self::COUNT_MASK
    }
}

/// B0 values: either a borrowed slice of the telegram (parse) or of words (emit from a mock).
#[derive(Debug, Clone, Copy)]
pub enum Values<'a> {
    /// Little-endian words straight from a telegram.
    Wire(&'a [u8]),
    /// Words supplied by the caller.
    Words(&'a [u16]),
}

impl<'a> Values<'a> {
    /// Number of values.
    #[must_use]
    pub fn len(&self) -> usize {
        match self {
            Self::Wire(b) => b.len() / 2,
            Self::Words(w) => w.len(),
        }
    }

    /// No values.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Value `i`.
    #[must_use]
    pub fn get(&self, i: usize) -> Option<u16> {
        match self {
            Self::Wire(b) => {
                let at = i.checked_mul(2)?;
                let lo = *b.get(at)?;
                let hi = *b.get(at.checked_add(1)?)?;
                Some(u16::from_le_bytes([lo, hi]))
            }
            Self::Words(w) => w.get(i).copied(),
        }
    }

    /// Every value in order.
    pub fn iter(&self) -> impl Iterator<Item = u16> + 'a {
        let (wire, words): (&'a [u8], &'a [u16]) = match *self {
            Self::Wire(b) => (b, &[]),
            Self::Words(w) => (&[], w),
        };
        wire.chunks_exact(2)
            .map(|c| match c {
                [lo, hi] => u16::from_le_bytes([*lo, *hi]),
                _ => 0,
            })
            .chain(words.iter().copied())
    }
}

impl PartialEq for Values<'_> {
    fn eq(&self, other: &Self) -> bool {
        self.len() == other.len() && self.iter().eq(other.iter())
    }
}

impl Eq for Values<'_> {}

/// A B0 measured-values telegram (spec §3.3).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Scan<'a> {
    /// The count word (count and raw flags).
    pub count_word: CountWord,
    /// The values, `count_word.count()` of them.
    pub values: Values<'a>,
    /// Real-time `(scan index, telegram index)`, present when config availability bit `0x02`
    /// is set.
    pub indices: Option<(u8, u8)>,
    /// Status byte.
    pub status: StatusByte,
}

impl<'a> Scan<'a> {
    /// A full scan of `values` in `units` (for mocks and tests).
    #[must_use]
    pub fn full(values: &'a [u16], units: Units, status: StatusByte) -> Self {
        let n = u16::try_from(values.len()).unwrap_or(u16::MAX);
        Self {
            count_word: CountWord::full_scan(n, units),
            values: Values::Words(values),
            indices: None,
            status,
        }
    }

    fn parse(data: &'a [u8]) -> Result<Self, WireError> {
        let len = u16::try_from(data.len().saturating_add(1)).unwrap_or(u16::MAX);
        let mut r = Reader::new(data);
        let count_word = CountWord(r.le::<u16>().map_err(|_| WireError::BadPayload {
            code: reply::SCAN,
            len: len.saturating_sub(1),
        })?);
        let n = usize::from(count_word.count());
        let mismatch = WireError::CountMismatch {
            count: count_word.count(),
            len,
        };
        let values_len = n.checked_mul(2).ok_or(mismatch)?;
        // Remaining after the values: S, or two indices and S.
        let extra = r.remaining().checked_sub(values_len).ok_or(mismatch)?;
        let values = Values::Wire(r.take(values_len)?);
        let indices = match extra {
            1 => None,
            3 => Some((r.u8()?, r.u8()?)),
            _ => return Err(mismatch),
        };
        let status = StatusByte(r.u8()?);
        Ok(Self {
            count_word,
            values,
            indices,
            status,
        })
    }

    fn emit(&self, w: &mut Writer<'_>) -> Result<(), WireError> {
        if usize::from(self.count_word.count()) != self.values.len() || self.values.len() > 0x3FF {
            return Err(WireError::InvalidField);
        }
        w.le::<u16>(self.count_word.0)?;
        match self.values {
            Values::Wire(b) => {
                w.bytes(b)?;
            }
            Values::Words(ws) => {
                for &v in ws {
                    w.le::<u16>(v)?;
                }
            }
        }
        if let Some((s, t)) = self.indices {
            w.u8(s)?;
            w.u8(t)?;
        }
        w.u8(self.status.0)?;
        Ok(())
    }
}

/// The B1 status block between `B1` and `S` (spec §3.4). Offsets in the accessor docs count
/// `B1` as offset 0, as the spec's table does. Real units send 152 bytes; any length is
/// accepted and fields past the end read as `None`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StatusBlock<'a>(pub &'a [u8]);

impl<'a> StatusBlock<'a> {
    /// Length real units send.
    pub const TYPICAL_LEN: usize = 152;

    fn at(&self, offset: usize) -> Option<u8> {
        self.0.get(offset.checked_sub(1)?).copied()
    }

    fn word(&self, offset: usize) -> Option<u16> {
        Some(u16::from_le_bytes([
            self.at(offset)?,
            self.at(offset.checked_add(1)?)?,
        ]))
    }

    /// Offsets 1–7: firmware version (ASCII).
    #[must_use]
    pub fn firmware(&self) -> Option<&'a [u8]> {
        self.0.get(0..7)
    }

    /// Offset 8: operating mode.
    #[must_use]
    pub fn operating_mode(&self) -> Option<u8> {
        self.at(8)
    }

    /// Offset 9: device status (nonzero = error).
    #[must_use]
    pub fn device_status(&self) -> Option<u8> {
        self.at(9)
    }

    /// Offset 18: variant type.
    #[must_use]
    pub fn variant_type(&self) -> Option<u8> {
        self.at(18)
    }

    /// Offsets 67–68: motor revolutions.
    #[must_use]
    pub fn motor_revolutions(&self) -> Option<u16> {
        self.word(67)
    }

    /// Offset 102: measuring mode.
    #[must_use]
    pub fn measuring_mode(&self) -> Option<MeasuringMode> {
        self.at(102).map(MeasuringMode)
    }

    /// Offsets 107–108: scan angle, degrees.
    #[must_use]
    pub fn scan_angle_deg(&self) -> Option<u16> {
        self.word(107)
    }

    /// Offsets 109–110: resolution, 1/100°.
    #[must_use]
    pub fn resolution_centideg(&self) -> Option<u16> {
        self.word(109)
    }

    /// Offsets 111–113: restart mode and time, raw.
    #[must_use]
    pub fn restart(&self) -> Option<&'a [u8]> {
        self.0.get(110..113)
    }

    /// Offsets 116–117: baud code, raw (`8067`, `8033`, `8019`, `8001`).
    #[must_use]
    pub fn baud_code(&self) -> Option<u16> {
        self.word(116)
    }

    /// The baud rate the status reports, if the code is known.
    #[must_use]
    pub fn baud(&self) -> Option<BaudRate> {
        self.baud_code().and_then(BaudRate::from_status_code)
    }

    /// Offset 119: permanent-baud flag (nonzero = set; this driver never sets it).
    #[must_use]
    pub fn permanent_baud(&self) -> Option<u8> {
        self.at(119)
    }

    /// Offset 120: address.
    #[must_use]
    pub fn address(&self) -> Option<u8> {
        self.at(120)
    }

    /// Offset 121: field set.
    #[must_use]
    pub fn field_set(&self) -> Option<u8> {
        self.at(121)
    }

    /// Offset 122: units.
    #[must_use]
    pub fn units(&self) -> Option<u8> {
        self.at(122)
    }

    /// Offset 123: laser on/off.
    #[must_use]
    pub fn laser_on(&self) -> Option<u8> {
        self.at(123)
    }

    /// Offsets 124–130: PROM version (ASCII).
    #[must_use]
    pub fn prom_version(&self) -> Option<&'a [u8]> {
        self.0.get(123..130)
    }
}

/// An owned, writable status block for mocks and tests ([`StatusBlock::TYPICAL_LEN`] bytes).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StatusBlockBuf(pub [u8; StatusBlock::TYPICAL_LEN]);

impl Default for StatusBlockBuf {
    fn default() -> Self {
        Self([0; StatusBlock::TYPICAL_LEN])
    }
}

impl StatusBlockBuf {
    fn set(&mut self, offset: usize, v: u8) {
        if let Some(b) = offset.checked_sub(1).and_then(|i| self.0.get_mut(i)) {
            *b = v;
        }
    }

    fn set_word(&mut self, offset: usize, v: u16) {
        let [lo, hi] = v.to_le_bytes();
        self.set(offset, lo);
        self.set(offset + 1, hi);
    }

    /// A view of the block.
    #[must_use]
    pub fn view(&self) -> StatusBlock<'_> {
        StatusBlock(&self.0)
    }

    /// Set the scan angle (107–108) and resolution (109–110).
    pub fn set_variant(&mut self, angle_deg: u16, res_centideg: u16) {
        self.set_word(107, angle_deg);
        self.set_word(109, res_centideg);
    }

    /// Set the baud code (116–117).
    pub fn set_baud(&mut self, b: BaudRate) {
        self.set_word(116, b.status_code());
    }

    /// Set the measuring mode (102).
    pub fn set_measuring_mode(&mut self, m: MeasuringMode) {
        self.set(102, m.0);
    }

    /// Set the device status (9).
    pub fn set_device_status(&mut self, v: u8) {
        self.set(9, v);
    }

    /// Set the operating mode (8).
    pub fn set_operating_mode(&mut self, v: u8) {
        self.set(8, v);
    }

    /// Set the units (122).
    pub fn set_units(&mut self, v: u8) {
        self.set(122, v);
    }
}

/// B2 error pairs `(type, number)` (spec §3.8), borrowed from the telegram.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ErrorPairs<'a>(&'a [u8]);

impl<'a> ErrorPairs<'a> {
    /// Pairs from their flattened bytes (must be of even length).
    pub fn new(raw: &'a [u8]) -> Result<Self, WireError> {
        if !raw.len().is_multiple_of(2) {
            return Err(WireError::InvalidField);
        }
        Ok(Self(raw))
    }

    /// The flattened bytes.
    #[must_use]
    pub fn as_bytes(&self) -> &'a [u8] {
        self.0
    }

    /// Number of pairs.
    #[must_use]
    pub fn len(&self) -> usize {
        self.0.len() / 2
    }

    /// No pairs.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }

    /// `(type, number)` pairs.
    pub fn iter(&self) -> impl Iterator<Item = (u8, u8)> + 'a {
        self.0.chunks_exact(2).map(|c| match c {
            [t, n] => (*t, *n),
            _ => (0, 0),
        })
    }
}

// ---------------------------------------------------------------------------------------------
// Commands

/// A host → LMS telegram (spec §3).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Command {
    /// `10`: reset; answered by ACK, `91`, then `90` at the power-up rate.
    Reset,
    /// `20`: change operating mode; answered by `A0`.
    SetMode(ModeRequest),
    /// `30`: request measured values; `sub = 1` with no params asks for one complete scan.
    RequestValues {
        /// Sub-command (`01` one complete scan; CAR's probe uses `05 B4`).
        sub: u8,
        /// Further raw parameter bytes.
        params: Params,
    },
    /// `31`: request the status block.
    Status,
    /// `32`: request error/test messages.
    Errors,
    /// `3A`: request the type string.
    Type,
    /// `3B`: switch variant.
    Variant {
        /// Scan angle, degrees (100 or 180).
        angle_deg: u16,
        /// Resolution, 1/100° (25, 50 or 100).
        res_centideg: u16,
    },
    /// `74`: read the configuration.
    ReadConfig,
    /// `77`: write the configuration (installation mode only).
    WriteConfig(LmsConfig),
}

impl Command {
    /// `30 01`: one complete scan.
    #[must_use]
    pub fn one_scan() -> Self {
        Self::RequestValues {
            sub: 0x01,
            params: Params::new(),
        }
    }

    /// The command code.
    #[must_use]
    pub fn code(&self) -> u8 {
        match self {
            Self::Reset => cmd::RESET,
            Self::SetMode(_) => cmd::SET_MODE,
            Self::RequestValues { .. } => cmd::REQUEST_VALUES,
            Self::Status => cmd::STATUS,
            Self::Errors => cmd::ERRORS,
            Self::Type => cmd::TYPE,
            Self::Variant { .. } => cmd::VARIANT,
            Self::ReadConfig => cmd::READ_CONFIG,
            Self::WriteConfig(_) => cmd::WRITE_CONFIG,
        }
    }

    /// Parse one whole telegram (checks STX, LEN, CRC and a host address `< 0x80`).
    pub fn parse(telegram: &[u8]) -> Result<Self, WireError> {
        Self::from_frame(&Frame::new_checked(telegram)?)
    }

    /// Type a checked frame as a command.
    pub fn from_frame(frame: &Frame<'_>) -> Result<Self, WireError> {
        if frame.address() >= 0x80 {
            return Err(WireError::BadAddress(frame.address()));
        }
        let code = frame.code();
        let data = frame.data();
        let bad = WireError::BadPayload {
            code,
            len: u16::try_from(data.len()).unwrap_or(u16::MAX),
        };
        let mut r = Reader::new(data);
        let c = match code {
            cmd::RESET => Self::Reset,
            cmd::SET_MODE => return ModeRequest::parse(data).map(Self::SetMode),
            cmd::REQUEST_VALUES => {
                let sub = r.u8().map_err(|_| bad)?;
                let params = Params::from_slice(r.take_rest()).map_err(|_| bad)?;
                Self::RequestValues { sub, params }
            }
            cmd::STATUS => Self::Status,
            cmd::ERRORS => Self::Errors,
            cmd::TYPE => Self::Type,
            cmd::VARIANT => Self::Variant {
                angle_deg: r.le::<u16>().map_err(|_| bad)?,
                res_centideg: r.le::<u16>().map_err(|_| bad)?,
            },
            cmd::READ_CONFIG => Self::ReadConfig,
            cmd::WRITE_CONFIG => {
                Self::WriteConfig(LmsConfig::from_bytes(r.take_rest()).map_err(|_| bad)?)
            }
            other => return Err(WireError::UnknownCommand(other)),
        };
        if r.remaining() != 0 {
            return Err(bad);
        }
        Ok(c)
    }

    /// Emit as a telegram to [`HOST_TO_LMS_ADDRESS`]. Returns the telegram length.
    pub fn emit(&self, buf: &mut [u8]) -> Result<usize, WireError> {
        self.emit_to(HOST_TO_LMS_ADDRESS, buf)
    }

    /// Emit as a telegram with a chosen address (`< 0x80`).
    pub fn emit_to(&self, address: u8, buf: &mut [u8]) -> Result<usize, WireError> {
        if address >= 0x80 {
            return Err(WireError::BadAddress(address));
        }
        let mut w = Writer::new(buf);
        w.skip(4)?;
        w.u8(self.code())?;
        match self {
            Self::SetMode(m) => m.emit(&mut w)?,
            Self::RequestValues { sub, params } => {
                w.u8(*sub)?;
                w.bytes(params)?;
            }
            Self::Variant {
                angle_deg,
                res_centideg,
            } => {
                w.le::<u16>(*angle_deg)?;
                w.le::<u16>(*res_centideg)?;
            }
            Self::WriteConfig(c) => {
                w.bytes(c.as_bytes())?;
            }
            Self::Reset | Self::Status | Self::Errors | Self::Type | Self::ReadConfig => {}
        }
        let body = w.pos() - 4;
        finish_telegram(buf, address, body)
    }

    /// Bytes [`Command::emit`] needs.
    #[must_use]
    pub fn buffer_len(&self) -> usize {
        let data = match self {
            Self::SetMode(m) => {
                1 + match m {
                    ModeRequest::Installation { .. } => 8,
                    ModeRequest::StreamMean { .. } => 1,
                    ModeRequest::StreamSubrange { .. } => 4,
                    ModeRequest::MeanSubrange { .. } => 5,
                    ModeRequest::Other { params, .. } => params.len(),
                    _ => 0,
                }
            }
            Self::RequestValues { params, .. } => 1 + params.len(),
            Self::Variant { .. } => 4,
            Self::WriteConfig(c) => c.as_bytes().len(),
            _ => 0,
        };
        data + 7
    }
}

// ---------------------------------------------------------------------------------------------
// Replies

/// An LMS → host telegram (spec §2–§3). Borrowed views point into the telegram.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Reply<'a> {
    /// `A0`: mode-change result (`00` accepted, nonzero refused).
    ModeChanged {
        /// Result code.
        result: u8,
        /// Status byte.
        status: StatusByte,
    },
    /// `B0`: measured values.
    Scan(Scan<'a>),
    /// `B1`: status block.
    Status {
        /// The block.
        block: StatusBlock<'a>,
        /// Status byte.
        status: StatusByte,
    },
    /// `B2`: error pairs.
    Errors {
        /// The pairs.
        pairs: ErrorPairs<'a>,
        /// Status byte.
        status: StatusByte,
    },
    /// `BA`: type string (ASCII, e.g. `LMS200;30106`).
    Type {
        /// The raw type string.
        text: &'a [u8],
        /// Status byte.
        status: StatusByte,
    },
    /// `BB`: variant result (`accepted` 1 = yes) and the current settings.
    Variant {
        /// `01` accepted, `00` refused.
        accepted: u8,
        /// Current scan angle, degrees.
        angle_deg: u16,
        /// Current resolution, 1/100°.
        res_centideg: u16,
        /// Status byte.
        status: StatusByte,
    },
    /// `F4`: configuration.
    Config {
        /// The block.
        config: LmsConfig,
        /// Status byte.
        status: StatusByte,
    },
    /// `F7`: configuration-write result and echo (TL: `01` accepted; QM shows `00`).
    ConfigWritten {
        /// Result code.
        result: u8,
        /// The echoed block.
        config: LmsConfig,
        /// Status byte.
        status: StatusByte,
    },
    /// `90`: power-on telegram with its text (21 ASCII bytes on real units).
    PowerOn {
        /// The raw text.
        text: &'a [u8],
        /// Status byte.
        status: StatusByte,
    },
    /// `91`: reset confirmation.
    ResetAck {
        /// Status byte.
        status: StatusByte,
    },
    /// `92`: telegram not allowed. Its layout is not documented; the spec assumes `92 S`, any
    /// bytes before `S` are kept raw.
    Rejected {
        /// Raw bytes between the code and `S` (normally empty).
        data: &'a [u8],
        /// Status byte.
        status: StatusByte,
    },
}

impl<'a> Reply<'a> {
    /// The reply code.
    #[must_use]
    pub fn code(&self) -> u8 {
        match self {
            Self::ModeChanged { .. } => reply::MODE,
            Self::Scan(_) => reply::SCAN,
            Self::Status { .. } => reply::STATUS,
            Self::Errors { .. } => reply::ERRORS,
            Self::Type { .. } => reply::TYPE,
            Self::Variant { .. } => reply::VARIANT,
            Self::Config { .. } => reply::CONFIG,
            Self::ConfigWritten { .. } => reply::CONFIG_WRITTEN,
            Self::PowerOn { .. } => reply::POWER_ON,
            Self::ResetAck { .. } => reply::RESET_ACK,
            Self::Rejected { .. } => reply::REJECTED,
        }
    }

    /// The status byte every reply ends with.
    #[must_use]
    pub fn status(&self) -> StatusByte {
        match self {
            Self::Scan(s) => s.status,
            Self::ModeChanged { status, .. }
            | Self::Status { status, .. }
            | Self::Errors { status, .. }
            | Self::Type { status, .. }
            | Self::Variant { status, .. }
            | Self::Config { status, .. }
            | Self::ConfigWritten { status, .. }
            | Self::PowerOn { status, .. }
            | Self::ResetAck { status }
            | Self::Rejected { status, .. } => *status,
        }
    }

    /// Parse one whole telegram (checks STX, LEN, CRC and a reply address `0x80..=0xFF`).
    pub fn parse(telegram: &'a [u8]) -> Result<Self, WireError> {
        Self::from_frame(&Frame::new_checked(telegram)?)
    }

    /// Type a checked frame as a reply.
    pub fn from_frame(frame: &Frame<'a>) -> Result<Self, WireError> {
        if frame.address() < 0x80 {
            return Err(WireError::BadAddress(frame.address()));
        }
        let code = frame.code();
        let data = frame.data();
        let bad = WireError::BadPayload {
            code,
            len: u16::try_from(data.len()).unwrap_or(u16::MAX),
        };
        if !is_known_reply(code) {
            return Err(WireError::UnknownCommand(code));
        }
        // Every reply ends with S.
        let (&s, body) = data.split_last().ok_or(bad)?;
        let status = StatusByte(s);
        let mut r = Reader::new(body);
        let out = match code {
            reply::MODE => Self::ModeChanged {
                result: r.u8().map_err(|_| bad)?,
                status,
            },
            reply::SCAN => return Scan::parse(data).map(Self::Scan),
            reply::STATUS => Self::Status {
                block: StatusBlock(r.take_rest()),
                status,
            },
            reply::ERRORS => Self::Errors {
                pairs: ErrorPairs::new(r.take_rest()).map_err(|_| bad)?,
                status,
            },
            reply::TYPE => Self::Type {
                text: r.take_rest(),
                status,
            },
            reply::VARIANT => Self::Variant {
                accepted: r.u8().map_err(|_| bad)?,
                angle_deg: r.le::<u16>().map_err(|_| bad)?,
                res_centideg: r.le::<u16>().map_err(|_| bad)?,
                status,
            },
            reply::CONFIG => Self::Config {
                config: LmsConfig::from_bytes(r.take_rest()).map_err(|_| bad)?,
                status,
            },
            reply::CONFIG_WRITTEN => Self::ConfigWritten {
                result: r.u8().map_err(|_| bad)?,
                config: LmsConfig::from_bytes(r.take_rest()).map_err(|_| bad)?,
                status,
            },
            reply::POWER_ON => Self::PowerOn {
                text: r.take_rest(),
                status,
            },
            reply::RESET_ACK => Self::ResetAck { status },
            // is_known_reply leaves only REJECTED here.
            _ => Self::Rejected {
                data: r.take_rest(),
                status,
            },
        };
        if r.remaining() != 0 {
            return Err(bad);
        }
        Ok(out)
    }

    /// Emit as a telegram from [`DEFAULT_REPLY_ADDRESS`]. Returns the telegram length.
    pub fn emit(&self, buf: &mut [u8]) -> Result<usize, WireError> {
        self.emit_from(DEFAULT_REPLY_ADDRESS, buf)
    }

    /// Emit as a telegram from a chosen reply address (`0x80..=0xFF`).
    pub fn emit_from(&self, address: u8, buf: &mut [u8]) -> Result<usize, WireError> {
        if address < 0x80 {
            return Err(WireError::BadAddress(address));
        }
        let mut w = Writer::new(buf);
        w.skip(4)?;
        w.u8(self.code())?;
        match self {
            Self::ModeChanged { result, .. } => {
                w.u8(*result)?;
            }
            Self::Scan(s) => {
                s.emit(&mut w)?;
                let body = w.pos() - 4;
                return finish_telegram(buf, address, body);
            }
            Self::Status { block, .. } => {
                w.bytes(block.0)?;
            }
            Self::Errors { pairs, .. } => {
                w.bytes(pairs.as_bytes())?;
            }
            Self::Type { text, .. } | Self::PowerOn { text, .. } => {
                w.bytes(text)?;
            }
            Self::Variant {
                accepted,
                angle_deg,
                res_centideg,
                ..
            } => {
                w.u8(*accepted)?;
                w.le::<u16>(*angle_deg)?;
                w.le::<u16>(*res_centideg)?;
            }
            Self::Config { config, .. } => {
                w.bytes(config.as_bytes())?;
            }
            Self::ConfigWritten { result, config, .. } => {
                w.u8(*result)?;
                w.bytes(config.as_bytes())?;
            }
            Self::ResetAck { .. } => {}
            Self::Rejected { data, .. } => {
                w.bytes(data)?;
            }
        }
        w.u8(self.status().0)?;
        let body = w.pos() - 4;
        finish_telegram(buf, address, body)
    }
}

//! Byte-stream decoder for LMS telegrams (spec §5 "Our rules").
//!
//! * A byte state machine: outside a candidate, a lone `06`/`15` is reported as ACK/NAK; every
//!   other non-STX byte is dropped and counted. Bytes that were part of a failed candidate are
//!   never reported as ACK/NAK (they were not "between frames").
//! * A candidate is accepted only if STX, address (replies `0x80..=0xFF`, commands `< 0x80`),
//!   `1 ≤ LEN ≤ 808`, a known code, a good CRC and a well-formed payload all hold. On any
//!   failure the framer drops **one** byte and rescans what it already holds, because `02 80`
//!   occurs naturally inside range data (spec §5, CAR).
//! * A partial candidate expires after [`PARTIAL_TIMEOUT`] (35 ms) without input: it is then
//!   treated as failed (one byte dropped, the rest rescanned). Time comes in as `now`. A mock
//!   device sets 6 ms ([`Framer::with_partial_timeout`]) and asks for [`Item::BadChecksum`] to
//!   know when to NAK ([`Framer::report_bad_checksums`]).
//! * Every failure is counted in [`Counters`]; a bad frame is never delivered.
//!
//! Storage is one fixed [`MAX_TELEGRAM`]-byte buffer: a 361-value B0 (732 bytes) is copied into
//! it once and handed out as a borrowed [`Frame`]. No heap.

use core::time::Duration;

use ima_hal::Instant;

use crate::wire::{
    ACK, Command, Frame, MAX_LEN, MAX_TELEGRAM, NAK, Reply, STX, WireError, is_known_command,
    is_known_reply,
};

/// Silence after which a partial candidate is abandoned (spec §5 rule 3; STB's byte timeout).
pub const PARTIAL_TIMEOUT: Duration = Duration::from_millis(35);

/// Which side's telegrams the framer accepts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Direction {
    /// Device → host: replies, address `0x80..=0xFF` (the host's framer).
    Replies,
    /// Host → device: commands, address `< 0x80` (the mock device's framer).
    Commands,
}

/// What the framer found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Item<'a> {
    /// A standalone `06` between frames.
    Ack,
    /// A standalone `15` between frames.
    Nak,
    /// A checked telegram whose payload parses for the framer's [`Direction`].
    Frame(Frame<'a>),
    /// A candidate with a good header failed its CRC (only with
    /// [`Framer::report_bad_checksums`]; a mock device answers it with NAK, spec §5 rule 6).
    BadChecksum,
}

/// Result of one [`Framer::push`] call.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Pushed<'a> {
    /// Bytes of the input consumed; feed the rest in the next call.
    pub consumed: usize,
    /// The item found, if any.
    pub item: Option<Item<'a>>,
}

/// Error and traffic counters.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Counters {
    /// Bytes discarded while hunting for STX (garbage, and bytes of failed candidates).
    pub dropped_bytes: u64,
    /// Candidates with a bad CRC.
    pub bad_checksums: u64,
    /// Candidates with a bad address, LEN or unknown code.
    pub bad_headers: u64,
    /// Candidates with a good CRC whose payload did not parse.
    pub bad_payloads: u64,
    /// Partial candidates abandoned after [`PARTIAL_TIMEOUT`] of silence.
    pub expired: u64,
    /// Telegrams delivered.
    pub frames: u64,
    /// Standalone ACK bytes delivered.
    pub acks: u64,
    /// Standalone NAK bytes delivered.
    pub naks: u64,
}

impl Counters {
    /// Items delivered (telegrams, ACKs, NAKs) and candidates rejected, for a probe report.
    #[must_use]
    pub fn tally(&self) -> (u64, u64) {
        let bad = self.bad_checksums + self.bad_headers + self.bad_payloads + self.expired;
        (self.frames + self.acks + self.naks, bad)
    }
}

/// Outcome of examining the buffered candidate.
enum Check {
    /// A whole good telegram of this many bytes starts the window.
    Complete(usize),
    /// The candidate is fine so far and needs this many more bytes.
    NeedMore(usize),
    /// The candidate failed.
    Failed,
}

/// The stream decoder. See the module docs for the rules.
#[derive(Debug, Clone)]
pub struct Framer {
    direction: Direction,
    buf: [u8; MAX_TELEGRAM],
    start: usize,
    end: usize,
    last_input: Instant,
    counters: Counters,
    partial_timeout: Duration,
    report_bad_checksums: bool,
    bad_checksum_seen: bool,
    any_code: bool,
}

impl Framer {
    /// A framer for `direction`.
    #[must_use]
    pub const fn new(direction: Direction) -> Self {
        Self {
            direction,
            buf: [0; MAX_TELEGRAM],
            start: 0,
            end: 0,
            last_input: Instant::ZERO,
            counters: Counters {
                dropped_bytes: 0,
                bad_checksums: 0,
                bad_headers: 0,
                bad_payloads: 0,
                expired: 0,
                frames: 0,
                acks: 0,
                naks: 0,
            },
            partial_timeout: PARTIAL_TIMEOUT,
            report_bad_checksums: false,
            bad_checksum_seen: false,
            any_code: false,
        }
    }

    /// Abandon partial candidates after `timeout` of silence instead of [`PARTIAL_TIMEOUT`]
    /// (a mock device uses 6 ms, the host's inter-byte limit; spec §5 rule 6).
    #[must_use]
    pub const fn with_partial_timeout(mut self, timeout: Duration) -> Self {
        self.partial_timeout = timeout;
        self
    }

    /// Also yield [`Item::BadChecksum`] for each candidate that fails its CRC.
    #[must_use]
    pub const fn report_bad_checksums(mut self, on: bool) -> Self {
        self.report_bad_checksums = on;
        self
    }

    /// Deliver every telegram whose header and CRC are good, whatever its code and payload
    /// (the device role: a real LMS answers every CRC-valid telegram, refusing with `92`
    /// what it cannot do, so its mock must see them). The payload is then the caller's to
    /// check. Off by default.
    #[must_use]
    pub const fn accept_any_code(mut self, on: bool) -> Self {
        self.any_code = on;
        self
    }

    /// The host's framer (device replies).
    #[must_use]
    pub const fn replies() -> Self {
        Self::new(Direction::Replies)
    }

    /// The mock device's framer (host commands).
    #[must_use]
    pub const fn commands() -> Self {
        Self::new(Direction::Commands)
    }

    /// The counters so far.
    #[must_use]
    pub const fn counters(&self) -> Counters {
        self.counters
    }

    /// Bytes of a partial candidate currently held.
    #[must_use]
    pub const fn buffered(&self) -> usize {
        self.end - self.start
    }

    /// When a held partial candidate expires (call [`Framer::push`] with empty input then).
    #[must_use]
    pub fn poll_timeout(&self) -> Option<Instant> {
        (self.buffered() > 0).then(|| self.last_input + self.partial_timeout)
    }

    /// Forget any partial candidate (e.g. after the host changed the line speed and flushed).
    pub fn clear(&mut self) {
        let held = self.buffered() as u64;
        self.counters.dropped_bytes = self.counters.dropped_bytes.saturating_add(held);
        self.start = 0;
        self.end = 0;
    }

    /// Feed bytes received at `now`. Returns how many were consumed and at most one item; call
    /// again with the unconsumed rest (and with empty input) until nothing is consumed and no
    /// item comes back. An empty `input` at or after [`Framer::poll_timeout`] expires a stale
    /// partial candidate.
    pub fn push<'s>(&'s mut self, input: &[u8], now: Instant) -> Pushed<'s> {
        let mut consumed = 0usize;
        loop {
            if self.buffered() == 0 {
                self.start = 0;
                self.end = 0;
                // Hunt directly in the input: bytes here are between frames. Skip everything
                // up to the next STX, ACK or NAK in one search.
                let rest = input.get(consumed..).unwrap_or(&[]);
                if rest.is_empty() {
                    return Pushed {
                        consumed,
                        item: None,
                    };
                }
                self.last_input = now;
                let Some(at) = rest.iter().position(|&b| matches!(b, STX | ACK | NAK)) else {
                    self.count_dropped(rest.len());
                    return Pushed {
                        consumed: consumed + rest.len(),
                        item: None,
                    };
                };
                self.count_dropped(at);
                consumed += at + 1;
                match rest.get(at) {
                    Some(&ACK) => {
                        self.counters.acks = self.counters.acks.saturating_add(1);
                        return Pushed {
                            consumed,
                            item: Some(Item::Ack),
                        };
                    }
                    Some(&NAK) => {
                        self.counters.naks = self.counters.naks.saturating_add(1);
                        return Pushed {
                            consumed,
                            item: Some(Item::Nak),
                        };
                    }
                    _ => {
                        // STX: a candidate starts.
                        if let Some(slot) = self.buf.get_mut(0) {
                            *slot = STX;
                            self.end = 1;
                        }
                    }
                }
                continue;
            }
            match self.check() {
                Check::Complete(n) => {
                    let from = self.start;
                    let to = from + n;
                    self.start = to;
                    self.counters.frames = self.counters.frames.saturating_add(1);
                    // check() verified this exact slice.
                    let frame = self.buf.get(from..to).map(Frame::new_unchecked);
                    return Pushed {
                        consumed,
                        item: frame.map(Item::Frame),
                    };
                }
                Check::Failed => {
                    self.drop_one();
                    if core::mem::take(&mut self.bad_checksum_seen) && self.report_bad_checksums {
                        return Pushed {
                            consumed,
                            item: Some(Item::BadChecksum),
                        };
                    }
                }
                Check::NeedMore(k) => {
                    if now >= self.last_input + self.partial_timeout {
                        // Silence since the candidate's last byte: abandon it (spec §5 rule 3).
                        self.counters.expired = self.counters.expired.saturating_add(1);
                        self.drop_one();
                        continue;
                    }
                    let rest = input.get(consumed..).unwrap_or(&[]);
                    if rest.is_empty() {
                        return Pushed {
                            consumed,
                            item: None,
                        };
                    }
                    let take = k.min(rest.len());
                    self.append(rest.get(..take).unwrap_or(&[]));
                    consumed += take;
                    self.last_input = now;
                }
            }
        }
    }

    /// Push all of `input`, calling `on_item` for each item found (a convenience loop over
    /// [`Framer::push`]).
    pub fn push_all(&mut self, mut input: &[u8], now: Instant, mut on_item: impl FnMut(Item<'_>)) {
        loop {
            let p = self.push(input, now);
            let consumed = p.consumed;
            let got = p.item.is_some();
            if let Some(item) = p.item {
                on_item(item);
            }
            input = input.get(consumed..).unwrap_or(&[]);
            if !got && consumed == 0 {
                break;
            }
        }
    }

    fn append(&mut self, bytes: &[u8]) {
        if self.end + bytes.len() > self.buf.len() {
            self.buf.copy_within(self.start..self.end, 0);
            self.end -= self.start;
            self.start = 0;
        }
        let to = self.end + bytes.len();
        if let Some(dst) = self.buf.get_mut(self.end..to) {
            dst.copy_from_slice(bytes);
            self.end = to;
        }
    }

    /// Drop the first byte of the window (the false STX) and everything up to the next STX.
    fn drop_one(&mut self) {
        let held = self.buf.get(self.start..self.end).unwrap_or(&[]);
        let skip = held
            .iter()
            .skip(1)
            .position(|&b| b == STX)
            .map_or(held.len(), |at| at + 1);
        self.start += skip;
        self.count_dropped(skip);
    }

    fn count_dropped(&mut self, n: usize) {
        let n = u64::try_from(n).unwrap_or(u64::MAX);
        self.counters.dropped_bytes = self.counters.dropped_bytes.saturating_add(n);
    }

    fn check(&mut self) -> Check {
        let w = self.buf.get(self.start..self.end).unwrap_or(&[]);
        // w[0] is STX by construction.
        if let Some(&addr) = w.get(1) {
            let ok = match self.direction {
                Direction::Replies => addr >= 0x80,
                Direction::Commands => addr < 0x80,
            };
            if !ok {
                self.counters.bad_headers = self.counters.bad_headers.saturating_add(1);
                return Check::Failed;
            }
        }
        let len = match (w.get(2), w.get(3)) {
            (Some(&lo), Some(&hi)) => u16::from_le_bytes([lo, hi]),
            _ => return Check::NeedMore(4 - w.len()),
        };
        if len == 0 || len > MAX_LEN {
            self.counters.bad_headers = self.counters.bad_headers.saturating_add(1);
            return Check::Failed;
        }
        let Some(&code) = w.get(4) else {
            return Check::NeedMore(1);
        };
        let known = match self.direction {
            Direction::Replies => is_known_reply(code),
            Direction::Commands => is_known_command(code),
        };
        if !known && !self.any_code {
            self.counters.bad_headers = self.counters.bad_headers.saturating_add(1);
            return Check::Failed;
        }
        let total = usize::from(len) + 6;
        let Some(candidate) = w.get(..total) else {
            return Check::NeedMore(total - w.len());
        };
        let verdict = Frame::new_checked(candidate).and_then(|f| match self.direction {
            _ if self.any_code => Ok(()),
            Direction::Replies => Reply::from_frame(&f).map(|_| ()),
            Direction::Commands => Command::from_frame(&f).map(|_| ()),
        });
        match verdict {
            Ok(()) => Check::Complete(total),
            Err(WireError::BadChecksum { .. }) => {
                self.counters.bad_checksums = self.counters.bad_checksums.saturating_add(1);
                self.bad_checksum_seen = true;
                Check::Failed
            }
            Err(_) => {
                self.counters.bad_payloads = self.counters.bad_payloads.saturating_add(1);
                Check::Failed
            }
        }
    }
}

impl Default for Framer {
    fn default() -> Self {
        Self::replies()
    }
}

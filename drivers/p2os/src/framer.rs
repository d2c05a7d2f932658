//! Byte-stream framer: turns arbitrary chunks of serial input into checked P2OS payloads.
//!
//! Rules (spec §10 items 2, 3 and 13):
//! * a sliding search for `FA FB` (so `FA FA FB` is found);
//! * the count byte is unsigned and must lie in `MIN_COUNT..=max_count`;
//! * after any rejected frame, scanning resumes **one byte** after the rejected header, so an
//!   intact frame hidden inside a bogus claimed body is never lost;
//! * every discarded byte and every rejection is counted.
//!
//! The framer never allocates: it owns a fixed buffer of [`BUFFER_LEN`] bytes. Feed it with
//! [`Framer::feed`] (which copies as much as fits) and pull payloads with
//! [`Framer::next_frame`], or do both with [`Framer::push`] and a callback.

use crate::wire::{self, HEADER0, HEADER1, MIN_COUNT};

/// Size of the framer's internal buffer: two maximal frames.
pub const BUFFER_LEN: usize = 2 * wire::MAX_FRAME_LEN;

/// What the framer has seen since it was created (or [`Framer::reset_stats`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FramerStats {
    /// Frames delivered (checksum good).
    pub frames: u64,
    /// Bytes thrown away while hunting for a header or after a rejected frame.
    pub dropped_bytes: u64,
    /// Frames rejected for a bad checksum.
    pub bad_checksums: u64,
    /// Headers rejected for a count byte out of range.
    pub bad_counts: u64,
    /// Partial frames abandoned by [`Framer::abandon_partial`].
    pub abandoned: u64,
}

impl FramerStats {
    /// Frames delivered and frames rejected (checksum, count, abandoned), for a probe report.
    #[must_use]
    pub fn tally(&self) -> (u64, u64) {
        let bad = self.bad_checksums + self.bad_counts + self.abandoned;
        (self.frames, bad)
    }
}

/// Why the framer rejected a candidate frame (reported to [`Framer::push`]'s callback).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Rejected {
    /// The count byte was out of range.
    BadCount(u8),
    /// The checksum did not match.
    BadChecksum {
        /// Computed over the payload.
        expected: u16,
        /// Carried by the frame.
        got: u16,
    },
}

/// One step of framing: a payload, or a rejected candidate.
#[derive(Debug, PartialEq, Eq)]
pub enum FrameEvent<'a> {
    /// A frame with a good checksum: its payload (type/command byte first).
    Frame(&'a [u8]),
    /// A candidate frame was rejected; scanning resumed one byte after its header.
    Rejected(Rejected),
}

/// A P2OS stream framer. See the [module docs](self).
#[derive(Debug, Clone)]
pub struct Framer {
    buf: [u8; BUFFER_LEN],
    start: usize,
    end: usize,
    max_count: u8,
    consumed: u64,
    stats: FramerStats,
}

impl Default for Framer {
    fn default() -> Self {
        Self::new()
    }
}

impl Framer {
    /// A framer for robot → host traffic (accepts any count byte 3..=255).
    #[must_use]
    pub const fn new() -> Self {
        Self::with_max_count(u8::MAX)
    }

    /// A framer for host → robot traffic: P2OS ignores commands with a count over 200.
    #[must_use]
    pub const fn for_commands() -> Self {
        Self::with_max_count(wire::MAX_COMMAND_COUNT)
    }

    /// A framer that rejects count bytes over `max_count`.
    #[must_use]
    pub const fn with_max_count(max_count: u8) -> Self {
        Self {
            buf: [0; BUFFER_LEN],
            start: 0,
            end: 0,
            max_count,
            consumed: 0,
            stats: FramerStats {
                frames: 0,
                dropped_bytes: 0,
                bad_checksums: 0,
                bad_counts: 0,
                abandoned: 0,
            },
        }
    }

    /// Counters since creation.
    #[must_use]
    pub fn stats(&self) -> FramerStats {
        self.stats
    }

    /// Zero the counters.
    pub fn reset_stats(&mut self) {
        self.stats = FramerStats::default();
    }

    /// Bytes buffered but not yet framed.
    #[must_use]
    pub fn buffered(&self) -> usize {
        self.end - self.start
    }

    /// Forget everything buffered (e.g. after reopening a port); counts it as dropped.
    pub fn clear(&mut self) {
        self.stats.dropped_bytes += self.buffered() as u64;
        self.consumed += self.buffered() as u64;
        self.start = 0;
        self.end = 0;
    }

    /// Copy as much of `input` as fits; returns how many bytes were taken. Call
    /// [`next_frame`](Self::next_frame) until it returns `None` before feeding again.
    pub fn feed(&mut self, input: &[u8]) -> usize {
        if self.start > 0 && self.end + input.len() > BUFFER_LEN {
            self.buf.copy_within(self.start..self.end, 0);
            self.end -= self.start;
            self.start = 0;
        }
        let n = input.len().min(BUFFER_LEN - self.end);
        if let (Some(dst), Some(src)) = (self.buf.get_mut(self.end..self.end + n), input.get(..n)) {
            dst.copy_from_slice(src);
            self.end += n;
            n
        } else {
            0
        }
    }

    /// The stream went quiet in the middle of a frame (the caller's inter-byte timeout, ~100 ms
    /// per spec §10 item 2): give up on the partial frame, and rescan from one byte after its
    /// header. Returns `true` if there was a partial frame.
    pub fn abandon_partial(&mut self) -> bool {
        if self.buffered() == 0 {
            return false;
        }
        self.stats.abandoned += 1;
        self.drop_bytes(1);
        true
    }

    /// Stream offset of the next unconsumed byte: every byte fed so far minus those still
    /// buffered. After [`next_frame`](Self::next_frame) returns a frame of payload length
    /// `p`, that frame began at `position() - (p + 5)`; after a rejection, the rejected header
    /// began at `position() - 1`.
    #[must_use]
    pub fn position(&self) -> u64 {
        self.consumed
    }

    fn drop_bytes(&mut self, n: usize) {
        let n = n.min(self.buffered());
        self.consumed += n as u64;
        self.start += n;
        self.stats.dropped_bytes += n as u64;
        if self.start == self.end {
            self.start = 0;
            self.end = 0;
        }
    }

    /// The next frame or rejection from what has been fed, or `None` if more input is needed.
    pub fn next_frame(&mut self) -> Option<FrameEvent<'_>> {
        loop {
            let window = self.buf.get(self.start..self.end)?;
            // Hunt for the first header byte.
            let Some(pos) = window.iter().position(|&b| b == HEADER0) else {
                let n = window.len();
                self.drop_bytes(n);
                return None;
            };
            if pos > 0 {
                self.drop_bytes(pos);
                continue;
            }
            let (h1, count) = match *window {
                [_, h1, count, ..] => (h1, count),
                [_, h1] if h1 != HEADER1 => {
                    self.drop_bytes(1);
                    continue;
                }
                _ => return None,
            };
            if h1 != HEADER1 {
                self.drop_bytes(1);
                continue;
            }
            if count < MIN_COUNT || count > self.max_count {
                self.stats.bad_counts += 1;
                self.drop_bytes(1);
                return Some(FrameEvent::Rejected(Rejected::BadCount(count)));
            }
            let total = 3 + usize::from(count);
            let frame_start = self.start;
            if frame_start + total > self.end {
                return None;
            }
            let frame = self.buf.get(frame_start..frame_start + total)?;
            match wire::frame_payload(frame) {
                Ok(_) => {
                    self.start += total;
                    self.consumed += total as u64;
                    if self.start == self.end {
                        self.start = 0;
                        self.end = 0;
                    }
                    self.stats.frames += 1;
                    let payload = self.buf.get(frame_start + 3..frame_start + total - 2)?;
                    return Some(FrameEvent::Frame(payload));
                }
                Err(wire::WireError::BadChecksum { expected, got }) => {
                    self.stats.bad_checksums += 1;
                    self.drop_bytes(1);
                    return Some(FrameEvent::Rejected(Rejected::BadChecksum {
                        expected,
                        got,
                    }));
                }
                Err(_) => {
                    // Cannot happen for a well-formed window; treat like a bad header.
                    self.drop_bytes(1);
                }
            }
        }
    }

    /// Feed all of `input`, calling `on_event` for every frame and rejection, in order.
    pub fn push(&mut self, mut input: &[u8], mut on_event: impl FnMut(FrameEvent<'_>)) {
        loop {
            let n = self.feed(input);
            input = input.get(n..).unwrap_or(&[]);
            while let Some(ev) = self.next_frame() {
                on_event(ev);
            }
            if input.is_empty() {
                break;
            }
            if n == 0 && self.buffered() == BUFFER_LEN {
                // Cannot happen (a full buffer always holds a complete frame), but never spin.
                self.drop_bytes(1);
            }
        }
    }
}

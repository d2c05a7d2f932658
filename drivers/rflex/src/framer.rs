//! Byte-stream receiver of spec §2.5: hunts for `ESC STX`, unstuffs, enforces the length
//! byte and the checksum, and yields checked [`RawFrame`]s borrowed from its own buffer.
//!
//! ```text
//! Hunt   --ESC STX-->  InFrame  --ESC ETX--> check length + checksum --> frame / error
//!                       |  ESC 00 -> data 0x1B       ESC 01 -> nothing
//!                       |  ESC 02 -> drop partial frame, start a new one (resync)
//!                       |  ESC xx -> framing error, back to Hunt (strict)
//!                       |            literal 1B xx (lenient, as unstuffed legacy commands arrive)
//!                       +  > 260 content bytes -> oversize, back to Hunt
//! ```
//!
//! Because frames are delimited by markers, not by a length prefix, a bad frame never hides a
//! good one: any `ESC STX` inside a bad frame restarts reception there, so the framer resyncs
//! at the very next start marker.
//!
//! Use [`Framer::decode`] in a loop (each call consumes some input and may yield one item), or
//! [`Framer::push`] with a callback. Errors are items, not the end of the stream (the tokio-util
//! `Decoder` convention for recoverable corruption), and each one is counted in [`Stats`].

use core::time::Duration;

use ima_hal::Instant;

use crate::wire::{ESC, ESC_DEL, ESC_NUL, ETX, MAX_CONTENT, RawFrame, STX, WireError};

/// Receiver options.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FramerConfig {
    /// Read `ESC` + any byte other than 00/01/02/03 as a literal 0x1B followed by that byte,
    /// as unstuffed legacy commands arrive (the mock's `lenient` switch, §8). Off = strict §2.5.
    pub lenient: bool,
    /// Drop a partial frame if no byte arrived for longer than this (§2.5: about 50 ms \[I\]).
    /// Only applies when the caller passes times to [`Framer::bytes_arrived`].
    pub max_gap: Duration,
}

impl Default for FramerConfig {
    fn default() -> Self {
        Self {
            lenient: false,
            max_gap: Duration::from_millis(50),
        }
    }
}

/// Counters of everything the framer threw away (all wrapping `u32`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Stats {
    /// Good frames delivered.
    pub frames: u32,
    /// Bytes discarded: outside frames, and the content of dropped frames.
    pub dropped_bytes: u32,
    /// Frames whose checksum did not match.
    pub bad_checksums: u32,
    /// Frames whose length byte did not match, or shorter than 5 content bytes.
    pub bad_lengths: u32,
    /// `ESC` followed by an invalid byte (strict mode).
    pub bad_escapes: u32,
    /// Frames longer than 264 bytes.
    pub oversize: u32,
    /// Partial frames abandoned by a new `ESC STX`.
    pub restarts: u32,
    /// Partial frames abandoned after an inter-byte gap.
    pub stale: u32,
}

impl Stats {
    /// Every frame-level error (not counting dropped bytes).
    #[must_use]
    pub fn errors(&self) -> u32 {
        self.bad_checksums
            .wrapping_add(self.bad_lengths)
            .wrapping_add(self.bad_escapes)
            .wrapping_add(self.oversize)
            .wrapping_add(self.restarts)
            .wrapping_add(self.stale)
    }
}

/// Why a candidate frame was dropped. Returned as an item; the stream goes on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameError {
    /// The frame completed but failed the length or checksum check.
    Invalid(WireError),
    /// `ESC` followed by this byte inside a frame (strict mode).
    BadEscape(u8),
    /// More than [`MAX_CONTENT`] content bytes.
    Oversize,
    /// A new `ESC STX` arrived before `ESC ETX`.
    Restarted,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    Hunt {
        esc: bool,
    },
    InFrame {
        esc: bool,
    },
    /// A frame was just yielded from `buf`; clear it on the next call.
    Delivered,
}

/// The §2.5 receiver. Holds one frame's content (260 bytes) and no other buffer.
#[derive(Debug, Clone)]
pub struct Framer {
    cfg: FramerConfig,
    state: State,
    buf: [u8; MAX_CONTENT],
    len: usize,
    last_rx: Option<Instant>,
    stats: Stats,
}

impl Default for Framer {
    fn default() -> Self {
        Self::new(FramerConfig::default())
    }
}

fn add(c: &mut u32, n: usize) {
    *c = c.wrapping_add(u32::try_from(n).unwrap_or(u32::MAX));
}

impl Framer {
    /// A framer in the `Hunt` state.
    #[must_use]
    pub fn new(cfg: FramerConfig) -> Self {
        Self {
            cfg,
            state: State::Hunt { esc: false },
            buf: [0; MAX_CONTENT],
            len: 0,
            last_rx: None,
            stats: Stats::default(),
        }
    }

    /// A strict framer (§2.5 defaults).
    #[must_use]
    pub fn strict() -> Self {
        Self::default()
    }

    /// A lenient framer (§8 `lenient`).
    #[must_use]
    pub fn lenient() -> Self {
        Self::new(FramerConfig {
            lenient: true,
            ..FramerConfig::default()
        })
    }

    /// The options.
    #[must_use]
    pub fn config(&self) -> &FramerConfig {
        &self.cfg
    }

    /// Counters so far.
    #[must_use]
    pub fn stats(&self) -> &Stats {
        &self.stats
    }

    /// `true` while a frame is partly received.
    #[must_use]
    pub fn in_frame(&self) -> bool {
        matches!(self.state, State::InFrame { .. })
    }

    /// Tell the framer that bytes arrived at `now`, before passing them to [`decode`]. If it
    /// is in the middle of a frame and the previous bytes came more than `max_gap` earlier,
    /// the partial frame is dropped (counted as `stale`).
    ///
    /// [`decode`]: Framer::decode
    pub fn bytes_arrived(&mut self, now: Instant) {
        if let (true, Some(prev)) = (self.in_frame(), self.last_rx)
            && now.saturating_duration_since(prev) > self.cfg.max_gap
        {
            self.stats.stale = self.stats.stale.wrapping_add(1);
            self.drop_partial();
            self.state = State::Hunt { esc: false };
        }
        self.last_rx = Some(now);
    }

    /// Forget any partial frame and hunt again (e.g. after the port was reopened).
    pub fn reset(&mut self) {
        if self.in_frame() {
            self.drop_partial();
        }
        self.state = State::Hunt { esc: false };
        self.len = 0;
    }

    fn drop_partial(&mut self) {
        // The 2 marker bytes plus the content received so far.
        add(&mut self.stats.dropped_bytes, self.len.saturating_add(2));
        self.len = 0;
    }

    fn append(&mut self, b: u8) -> Result<(), FrameError> {
        match self.buf.get_mut(self.len) {
            Some(slot) => {
                *slot = b;
                self.len += 1;
                Ok(())
            }
            None => Err(FrameError::Oversize),
        }
    }

    /// Consume bytes from `input` until one item is complete or the input is used up. Returns
    /// the number of bytes consumed and the item, if any. A frame borrows the framer's buffer:
    /// drop it before the next call.
    pub fn decode(&mut self, input: &[u8]) -> (usize, Option<Result<RawFrame<'_>, FrameError>>) {
        if self.state == State::Delivered {
            self.len = 0;
            self.state = State::Hunt { esc: false };
        }
        let mut used = 0usize;
        for &b in input {
            used += 1;
            match self.step(b) {
                Step::More => {}
                Step::Error(e) => return (used, Some(Err(e))),
                Step::Complete => return (used, Some(self.complete())),
            }
        }
        (used, None)
    }

    /// `ESC ETX` seen: check the content and hand it out or count the error.
    fn complete(&mut self) -> Result<RawFrame<'_>, FrameError> {
        let Self {
            buf,
            len,
            stats,
            state,
            ..
        } = self;
        let content = buf.get(..*len).unwrap_or(&[]);
        match RawFrame::new_checked(content) {
            Ok(f) => {
                stats.frames = stats.frames.wrapping_add(1);
                *state = State::Delivered;
                Ok(f)
            }
            Err(e) => {
                if let WireError::BadChecksum { .. } = e {
                    stats.bad_checksums = stats.bad_checksums.wrapping_add(1);
                } else {
                    stats.bad_lengths = stats.bad_lengths.wrapping_add(1);
                }
                add(&mut stats.dropped_bytes, len.saturating_add(4));
                *len = 0;
                *state = State::Hunt { esc: false };
                Err(FrameError::Invalid(e))
            }
        }
    }

    /// Feed all of `input`, calling `on_item` for every frame or error.
    pub fn push(
        &mut self,
        mut input: &[u8],
        mut on_item: impl FnMut(Result<RawFrame<'_>, FrameError>),
    ) {
        while !input.is_empty() {
            let (used, item) = self.decode(input);
            if let Some(item) = item {
                on_item(item);
            }
            input = input.get(used..).unwrap_or(&[]);
            if used == 0 {
                break;
            }
        }
    }

    fn step(&mut self, b: u8) -> Step {
        match self.state {
            State::Delivered => {
                self.len = 0;
                self.state = State::Hunt { esc: false };
                self.step(b)
            }
            State::Hunt { esc } => {
                if esc && b == STX {
                    // The ESC was counted as dropped; it belongs to a frame after all.
                    self.stats.dropped_bytes = self.stats.dropped_bytes.wrapping_sub(1);
                    self.len = 0;
                    self.state = State::InFrame { esc: false };
                } else {
                    self.stats.dropped_bytes = self.stats.dropped_bytes.wrapping_add(1);
                    self.state = State::Hunt { esc: b == ESC };
                }
                Step::More
            }
            State::InFrame { esc: false } => {
                if b == ESC {
                    self.state = State::InFrame { esc: true };
                    Step::More
                } else {
                    self.append_or_oversize(b)
                }
            }
            State::InFrame { esc: true } => {
                self.state = State::InFrame { esc: false };
                match b {
                    ESC_NUL => self.append_or_oversize(ESC),
                    ESC_DEL => Step::More,
                    ETX => Step::Complete,
                    STX => {
                        self.stats.restarts = self.stats.restarts.wrapping_add(1);
                        self.drop_partial();
                        Step::Error(FrameError::Restarted)
                    }
                    other if self.cfg.lenient => {
                        if let Step::Error(e) = self.append_or_oversize(ESC) {
                            return Step::Error(e);
                        }
                        if other == ESC {
                            self.state = State::InFrame { esc: true };
                            Step::More
                        } else {
                            self.append_or_oversize(other)
                        }
                    }
                    other => {
                        self.stats.bad_escapes = self.stats.bad_escapes.wrapping_add(1);
                        // What came before, the ESC, and this byte. If this byte is itself an
                        // ESC it may start the next frame: hunt with it pending (§2.5).
                        self.drop_partial();
                        add(&mut self.stats.dropped_bytes, 2);
                        self.state = State::Hunt { esc: other == ESC };
                        Step::Error(FrameError::BadEscape(other))
                    }
                }
            }
        }
    }

    fn append_or_oversize(&mut self, b: u8) -> Step {
        match self.append(b) {
            Ok(()) => Step::More,
            Err(e) => {
                self.stats.oversize = self.stats.oversize.wrapping_add(1);
                self.drop_partial();
                add(&mut self.stats.dropped_bytes, 1);
                self.state = State::Hunt { esc: false };
                Step::Error(e)
            }
        }
    }
}

enum Step {
    More,
    Complete,
    Error(FrameError),
}

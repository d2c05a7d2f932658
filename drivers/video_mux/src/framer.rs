//! Byte-stream framers for switcher replies.
//!
//! * [`LineFramer`] (Extron SIS): the shared [`ima_serial::line`] framer with the plain
//!   rules: lines end with CR LF (CR or LF alone are accepted too); empty lines are skipped;
//!   a line longer than `N` bytes or containing a non-printable byte is dropped whole
//!   (counted) and the framer resyncs at the next terminator.
//! * [`KramerFramer`] (Protocol 2000): 4-byte messages whose first byte has bit 7 clear and
//!   whose other bytes have it set. A byte that breaks that pattern ends the partial message
//!   (counted as dropped) and, if it can start a message, starts the next one; so the framer
//!   resyncs one byte at a time and never skips a possible message start.

pub use ima_serial::line::{Frame, LineStats};

use crate::wire::kramer::LEN;

/// Longest Extron reply line kept (a `Sig` line for 32 inputs is 67 bytes).
pub const MAX_LINE: usize = 96;

/// Counters of a framer (saturating).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct FramerStats {
    /// Frames delivered.
    pub frames: u32,
    /// Bytes thrown away.
    pub dropped_bytes: u32,
    /// Lines dropped for being longer than the bound.
    pub overlong: u32,
    /// Lines dropped for a non-printable byte (Extron), or partial messages cut short by an
    /// out-of-place byte (Kramer).
    pub bad_frames: u32,
}

fn add(c: &mut u32, n: usize) {
    *c = c.saturating_add(u32::try_from(n).unwrap_or(u32::MAX));
}

/// The Extron reply line framer: the shared plain framer; `N` bounds a line (without
/// terminator).
pub type LineFramer<const N: usize = MAX_LINE> = ima_serial::line::LineFramer<N>;

impl From<LineStats> for FramerStats {
    fn from(s: LineStats) -> Self {
        Self {
            frames: s.lines,
            dropped_bytes: s.dropped_bytes,
            overlong: s.overlong,
            bad_frames: s.bad_bytes,
        }
    }
}

/// The Protocol 2000 framer.
#[derive(Debug, Clone, Default)]
pub struct KramerFramer {
    buf: [u8; LEN],
    len: usize,
    stats: FramerStats,
}

impl KramerFramer {
    /// An empty framer.
    #[must_use]
    pub const fn new() -> Self {
        Self {
            buf: [0; LEN],
            len: 0,
            stats: FramerStats {
                frames: 0,
                dropped_bytes: 0,
                overlong: 0,
                bad_frames: 0,
            },
        }
    }

    /// Counters.
    #[must_use]
    pub fn stats(&self) -> FramerStats {
        self.stats
    }

    /// Bytes of the message in progress (0 between messages).
    #[must_use]
    pub const fn pending(&self) -> usize {
        self.len
    }

    /// Feed one byte; returns a complete 4-byte message (not yet parsed).
    pub fn push_byte(&mut self, b: u8) -> Option<[u8; LEN]> {
        let starts = b & 0x80 == 0;
        if starts {
            if self.len > 0 {
                add(&mut self.stats.dropped_bytes, self.len);
                add(&mut self.stats.bad_frames, 1);
            }
            self.len = 0;
        } else if self.len == 0 {
            add(&mut self.stats.dropped_bytes, 1);
            return None;
        }
        if let Some(slot) = self.buf.get_mut(self.len) {
            *slot = b;
        }
        self.len = self.len.saturating_add(1);
        if self.len >= LEN {
            self.len = 0;
            add(&mut self.stats.frames, 1);
            return Some(self.buf);
        }
        None
    }

    /// Feed a chunk; `on_msg` gets every complete message in order.
    pub fn push(&mut self, bytes: &[u8], mut on_msg: impl FnMut([u8; LEN])) {
        for &b in bytes {
            if let Some(m) = self.push_byte(b) {
                on_msg(m);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::vec::Vec;

    fn msgs(f: &mut KramerFramer, chunks: &[&[u8]]) -> Vec<[u8; 4]> {
        let mut out = Vec::new();
        for c in chunks {
            f.push(c, |m| out.push(m));
        }
        out
    }

    #[test]
    fn extron_stats_count_what_the_line_framer_dropped() {
        let mut f = LineFramer::<8>::default();
        let mut out = Vec::new();
        f.push(
            b"\x00\xffIn3\x01 All\r\n0123456789ABC\r\nIn4 All\r\n",
            |fr| {
                if let Frame::Line(l) = fr {
                    out.push(l.to_vec());
                }
            },
        );
        assert_eq!(out, [b"In4 All".to_vec()]);
        let s = FramerStats::from(f.stats());
        assert_eq!(
            s,
            FramerStats {
                frames: 1,
                dropped_bytes: 2 + 8 + 13,
                overlong: 1,
                bad_frames: 1
            }
        );
    }

    #[test]
    fn kramer_frames_and_resync() {
        let mut f = KramerFramer::new();
        let good = [0x41, 0x83, 0x81, 0x81];
        // Noise with the high bit set, a truncated message, then two good ones split oddly.
        let out = msgs(
            &mut f,
            &[&[0xff, 0x90], &[0x41, 0x83], &good[..1], &good[1..], &good],
        );
        assert_eq!(out, [good, good]);
        let s = f.stats();
        assert_eq!(s.dropped_bytes, 4);
        assert_eq!(s.bad_frames, 1);
        // One-byte reads.
        let mut f = KramerFramer::new();
        let chunks: Vec<&[u8]> = good.chunks(1).collect();
        assert_eq!(msgs(&mut f, &chunks), [good]);
    }
}

//! Byte-stream framers for switcher replies.
//!
//! * [`LineFramer`] (Extron SIS): lines end with CR LF (CR or LF alone are accepted too);
//!   empty lines are skipped; a line longer than `N` bytes or containing a non-printable byte
//!   is dropped whole (counted) and the framer resyncs at the next terminator.
//! * [`KramerFramer`] (Protocol 2000): 4-byte messages whose first byte has bit 7 clear and
//!   whose other bytes have it set. A byte that breaks that pattern ends the partial message
//!   (counted as dropped) and, if it can start a message, starts the next one; so the framer
//!   resyncs one byte at a time and never skips a possible message start.

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

/// The Extron reply line framer; `N` bounds a line (without terminator).
#[derive(Debug, Clone)]
pub struct LineFramer<const N: usize = MAX_LINE> {
    buf: heapless::Vec<u8, N>,
    discarding: bool,
    clear_next: bool,
    stats: FramerStats,
}

impl<const N: usize> Default for LineFramer<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> LineFramer<N> {
    /// An empty framer.
    #[must_use]
    pub const fn new() -> Self {
        Self {
            buf: heapless::Vec::new(),
            discarding: false,
            clear_next: false,
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

    /// Feed one byte; returns a complete line (without terminator).
    pub fn push_byte(&mut self, b: u8) -> Option<&[u8]> {
        if self.clear_next {
            self.buf.clear();
            self.clear_next = false;
        }
        match b {
            b'\r' | b'\n' => {
                if self.discarding {
                    self.discarding = false;
                    return None;
                }
                if self.buf.is_empty() {
                    return None;
                }
                self.clear_next = true;
                add(&mut self.stats.frames, 1);
                Some(&self.buf)
            }
            _ if self.discarding => {
                add(&mut self.stats.dropped_bytes, 1);
                None
            }
            0x20..=0x7e => {
                if self.buf.push(b).is_err() {
                    add(
                        &mut self.stats.dropped_bytes,
                        self.buf.len().saturating_add(1),
                    );
                    add(&mut self.stats.overlong, 1);
                    self.buf.clear();
                    self.discarding = true;
                }
                None
            }
            _ => {
                add(
                    &mut self.stats.dropped_bytes,
                    self.buf.len().saturating_add(1),
                );
                if !self.buf.is_empty() {
                    add(&mut self.stats.bad_frames, 1);
                    self.discarding = true;
                }
                self.buf.clear();
                None
            }
        }
    }

    /// Feed a chunk; `on_line` gets every complete line in order.
    pub fn push(&mut self, bytes: &[u8], mut on_line: impl FnMut(&[u8])) {
        for &b in bytes {
            if let Some(l) = self.push_byte(b) {
                on_line(l);
            }
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

    fn lines<const N: usize>(f: &mut LineFramer<N>, chunks: &[&[u8]]) -> Vec<Vec<u8>> {
        let mut out = Vec::new();
        for c in chunks {
            f.push(c, |l| out.push(l.to_vec()));
        }
        out
    }

    fn msgs(f: &mut KramerFramer, chunks: &[&[u8]]) -> Vec<[u8; 4]> {
        let mut out = Vec::new();
        for c in chunks {
            f.push(c, |m| out.push(m));
        }
        out
    }

    #[test]
    fn extron_many_per_read_and_split_reads() {
        let mut f = LineFramer::<96>::new();
        assert_eq!(
            lines(&mut f, &[b"In3 All\r\nE01\r\nVmt1\r\n"]),
            [b"In3 All".to_vec(), b"E01".to_vec(), b"Vmt1".to_vec()]
        );
        let bytes = b"In12 Vid\r\n";
        let chunks: Vec<&[u8]> = bytes.chunks(1).collect();
        assert_eq!(lines(&mut f, &chunks), [b"In12 Vid".to_vec()]);
        assert_eq!(f.stats().frames, 4);
    }

    #[test]
    fn extron_garbage_overlong_then_good() {
        let mut f = LineFramer::<8>::new();
        let out = lines(
            &mut f,
            &[
                b"\x00\xffIn3\x01 All\r\n",
                b"0123456789ABC\r\n",
                b"In4 All\r\n",
            ],
        );
        assert_eq!(out, [b"In4 All".to_vec()]);
        let s = f.stats();
        assert_eq!(s.overlong, 1);
        assert_eq!(s.bad_frames, 1);
        assert_eq!(s.dropped_bytes, 2 + 8 + 13);
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

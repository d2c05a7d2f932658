//! ASCII line framer for compass output (spec §7a: lines end with CR, CR LF or LF).
//!
//! Push bytes in, get whole lines out. The framer
//!
//! * accepts any mix of CR and LF as terminators and ignores empty lines;
//! * treats `$` as a start-of-sentence mark: a `$` in the middle of a line means the line
//!   before it was cut short, so the partial line is dropped (counted) and a new one starts at
//!   the `$` — this is the resync after garbage;
//! * bounds every line to `N` bytes: a longer line is dropped whole, reported once as
//!   [`FrameError::Overlong`], and the framer discards until the next terminator or `$`;
//! * drops a line containing a non-printable byte ([`FrameError::BadByte`]) the same way;
//! * checks the NMEA checksum of `$…*hh` lines and reports a mismatch as
//!   [`FrameError::BadChecksum`] (lines without `*hh` pass; the parser decides);
//! * yields the KVH `>` prompt as [`Frame::Prompt`] as soon as it is seen at the start of a
//!   line (the device does not terminate it).
//!
//! Frames borrow the framer's buffer, so nothing is copied or allocated.

use crate::wire::{self, MAX_LINE};

/// What the framer found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Frame<'a> {
    /// A complete line, without its terminator, checksum verified if it has one.
    Line(&'a [u8]),
    /// A `>` prompt.
    Prompt,
    /// A line was lost; the stream goes on.
    Corrupt(FrameError),
}

/// Why a line was dropped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum FrameError {
    /// Longer than the framer's bound.
    Overlong,
    /// Contained a non-printable byte.
    BadByte(u8),
    /// NMEA checksum mismatch: `expected` computed, `got` sent.
    BadChecksum {
        /// Computed.
        expected: u8,
        /// Sent.
        got: u8,
    },
}

/// Counters of a framer (all saturating).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct FramerStats {
    /// Lines delivered as [`Frame::Line`].
    pub lines: u32,
    /// Prompts delivered.
    pub prompts: u32,
    /// Bytes thrown away (garbage, partial, overlong and corrupt lines).
    pub dropped_bytes: u32,
    /// Lines dropped for a checksum mismatch.
    pub bad_checksums: u32,
    /// Lines dropped for being too long.
    pub overlong: u32,
    /// Lines dropped for a non-printable byte.
    pub bad_bytes: u32,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    /// Between lines.
    Idle,
    /// Collecting a line.
    InLine,
    /// Throwing bytes away until a terminator or `$`.
    Discarding,
}

/// A bounded line framer; `N` is the longest line (without terminator) it keeps.
#[derive(Debug, Clone)]
pub struct LineFramer<const N: usize = MAX_LINE> {
    buf: heapless::Vec<u8, N>,
    state: State,
    clear_next: bool,
    stats: FramerStats,
}

impl<const N: usize> Default for LineFramer<N> {
    fn default() -> Self {
        Self::new()
    }
}

fn add(c: &mut u32, n: usize) {
    *c = c.saturating_add(u32::try_from(n).unwrap_or(u32::MAX));
}

impl<const N: usize> LineFramer<N> {
    /// An empty framer.
    #[must_use]
    pub const fn new() -> Self {
        Self {
            buf: heapless::Vec::new(),
            state: State::Idle,
            clear_next: false,
            stats: FramerStats {
                lines: 0,
                prompts: 0,
                dropped_bytes: 0,
                bad_checksums: 0,
                overlong: 0,
                bad_bytes: 0,
            },
        }
    }

    /// The counters.
    #[must_use]
    pub fn stats(&self) -> FramerStats {
        self.stats
    }

    /// Bytes of the line in progress.
    #[must_use]
    pub fn pending(&self) -> usize {
        if self.clear_next { 0 } else { self.buf.len() }
    }

    /// Forget the line in progress (counted as dropped).
    pub fn reset(&mut self) {
        if !self.clear_next {
            add(&mut self.stats.dropped_bytes, self.buf.len());
        }
        self.buf.clear();
        self.clear_next = false;
        self.state = State::Idle;
    }

    /// Feed one byte; returns a frame when one completes.
    pub fn push_byte(&mut self, b: u8) -> Option<Frame<'_>> {
        if self.clear_next {
            self.buf.clear();
            self.clear_next = false;
        }
        match b {
            b'\r' | b'\n' => {
                let was = self.state;
                self.state = State::Idle;
                if was != State::InLine || self.buf.is_empty() {
                    return None;
                }
                self.clear_next = true;
                if let Some((expected, got)) = checksum_mismatch(&self.buf) {
                    add(&mut self.stats.dropped_bytes, self.buf.len());
                    add(&mut self.stats.bad_checksums, 1);
                    return Some(Frame::Corrupt(FrameError::BadChecksum { expected, got }));
                }
                add(&mut self.stats.lines, 1);
                Some(Frame::Line(&self.buf))
            }
            b'$' => {
                if self.state == State::InLine {
                    add(&mut self.stats.dropped_bytes, self.buf.len());
                }
                self.buf.clear();
                // Capacity is at least 1 for any useful N; a zero-capacity framer discards.
                if self.buf.push(b'$').is_ok() {
                    self.state = State::InLine;
                } else {
                    add(&mut self.stats.dropped_bytes, 1);
                    self.state = State::Discarding;
                }
                None
            }
            b'>' if self.state == State::Idle => {
                add(&mut self.stats.prompts, 1);
                Some(Frame::Prompt)
            }
            0x20..=0x7e => match self.state {
                State::Discarding => {
                    add(&mut self.stats.dropped_bytes, 1);
                    None
                }
                State::Idle | State::InLine => {
                    if self.buf.push(b).is_ok() {
                        self.state = State::InLine;
                        None
                    } else {
                        add(
                            &mut self.stats.dropped_bytes,
                            self.buf.len().saturating_add(1),
                        );
                        add(&mut self.stats.overlong, 1);
                        self.buf.clear();
                        self.state = State::Discarding;
                        Some(Frame::Corrupt(FrameError::Overlong))
                    }
                }
            },
            _ => {
                add(
                    &mut self.stats.dropped_bytes,
                    self.buf.len().saturating_add(1),
                );
                self.buf.clear();
                match self.state {
                    State::InLine => {
                        add(&mut self.stats.bad_bytes, 1);
                        self.state = State::Discarding;
                        Some(Frame::Corrupt(FrameError::BadByte(b)))
                    }
                    // Noise between lines: drop the byte, stay between lines.
                    State::Idle | State::Discarding => None,
                }
            }
        }
    }

    /// Feed a chunk of any size; `on_frame` is called for every frame, in order.
    pub fn push(&mut self, bytes: &[u8], mut on_frame: impl FnMut(Frame<'_>)) {
        for &b in bytes {
            if let Some(f) = self.push_byte(b) {
                on_frame(f);
            }
        }
    }
}

/// `Some((computed, sent))` if the line is `$…*hh` with a mismatching checksum.
fn checksum_mismatch(line: &[u8]) -> Option<(u8, u8)> {
    let (b'$', rest) = line.split_first()? else {
        return None;
    };
    let star = rest.len().checked_sub(3)?;
    let (body, tail) = rest.split_at(star);
    let [b'*', hi, lo] = tail else {
        return None;
    };
    let got = (wire::hex_val(*hi)? << 4) | wire::hex_val(*lo)?;
    let expected = wire::checksum(body);
    (expected != got && !cfg!(fuzzing)).then_some((expected, got))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::vec::Vec;

    #[derive(Debug, PartialEq)]
    enum F {
        L(Vec<u8>),
        P,
        C(FrameError),
    }

    fn run<const N: usize>(fr: &mut LineFramer<N>, chunks: &[&[u8]]) -> Vec<F> {
        let mut out = Vec::new();
        for c in chunks {
            fr.push(c, |f| {
                out.push(match f {
                    Frame::Line(l) => F::L(l.to_vec()),
                    Frame::Prompt => F::P,
                    Frame::Corrupt(e) => F::C(e),
                })
            });
        }
        out
    }

    const HDM: &[u8] = b"$HCHDM,238.5,M*25\r\n";
    const HDT: &[u8] = b"$HCHDT,238.5,T*25\r\n";

    fn l(s: &[u8]) -> F {
        F::L(wire::trim_eol(s).to_vec())
    }

    #[test]
    fn many_frames_per_read() {
        let mut fr = LineFramer::<96>::new();
        let all = [HDM, HDT, HDM].concat();
        assert_eq!(run(&mut fr, &[&all]), [l(HDM), l(HDT), l(HDM)]);
        assert_eq!(fr.stats().lines, 3);
        assert_eq!(fr.stats().dropped_bytes, 0);
    }

    #[test]
    fn one_frame_over_one_byte_reads() {
        let mut fr = LineFramer::<96>::new();
        let chunks: Vec<&[u8]> = HDM.chunks(1).collect();
        assert_eq!(run(&mut fr, &chunks), [l(HDM)]);
    }

    #[test]
    fn cr_only_lf_only_and_blank_lines() {
        let mut fr = LineFramer::<96>::new();
        let out = run(
            &mut fr,
            &[b"\r\n\r\n$HCHDM,238.5,M*25\r$HCHDT,238.5,T*25\n\n\rH9V9M0.1\n"],
        );
        assert_eq!(out, [l(HDM), l(HDT), F::L(b"H9V9M0.1".to_vec())]);
    }

    #[test]
    fn garbage_before_and_between_frames() {
        let mut fr = LineFramer::<96>::new();
        let stream = [b"xx\x00\xff junk".as_slice(), HDM, b"\x07\x08", HDT].concat();
        let out = run(&mut fr, &[&stream]);
        // "xx" then NUL: a line spoilt by a bad byte (reported); the rest up to the `$` is
        // discarded; BEL/BS between lines are dropped silently.
        assert_eq!(out, [F::C(FrameError::BadByte(0)), l(HDM), l(HDT)]);
        assert!(fr.stats().dropped_bytes >= 9);
    }

    #[test]
    fn truncated_frame_then_good_one() {
        let mut fr = LineFramer::<96>::new();
        let out = run(&mut fr, &[b"$HCHDM,23", HDT]);
        assert_eq!(out, [l(HDT)]);
        assert_eq!(fr.stats().dropped_bytes, 9);
    }

    #[test]
    fn overlong_line_then_good_one() {
        let mut fr = LineFramer::<16>::new();
        let long = [b"$".as_slice(), &[b'A'; 40], b"\r\n"].concat();
        let out = run(&mut fr, &[&long, b"$C1.0*01\r\n".as_slice()]);
        // Checksum of "C1.0" is 0x43^0x31^0x2e^0x30 = 0x6C; the second line is corrupt on
        // purpose to check it is reported, then a good short line.
        assert_eq!(
            out,
            [
                F::C(FrameError::Overlong),
                F::C(FrameError::BadChecksum {
                    expected: 0x6C,
                    got: 0x01
                })
            ]
        );
        let out = run(&mut fr, &[b"$C1.0*6C\r\n".as_slice()]);
        assert_eq!(out, [F::L(b"$C1.0*6C".to_vec())]);
        assert_eq!(fr.stats().overlong, 1);
        assert_eq!(fr.stats().bad_checksums, 1);
    }

    #[test]
    fn overlong_resyncs_on_dollar() {
        let mut fr = LineFramer::<16>::new();
        let stream = [&[b'A'; 40][..], HDM].concat();
        let mut fr96 = LineFramer::<96>::new();
        // With N = 16 the HDM line itself (17 bytes) is too long; use the 96 framer for it.
        assert_eq!(
            run(&mut fr, &[&stream]),
            [F::C(FrameError::Overlong), F::C(FrameError::Overlong)]
        );
        let stream = [&[b'A'; 200][..], HDM].concat();
        assert_eq!(
            run(&mut fr96, &[&stream]),
            [F::C(FrameError::Overlong), l(HDM)]
        );
    }

    #[test]
    fn bad_checksum_then_good_frame() {
        let mut fr = LineFramer::<96>::new();
        let out = run(&mut fr, &[b"$HCHDM,238.5,M*26\r\n", HDM]);
        assert_eq!(
            out,
            [
                F::C(FrameError::BadChecksum {
                    expected: 0x25,
                    got: 0x26
                }),
                l(HDM)
            ]
        );
    }

    #[test]
    fn bad_byte_inside_line() {
        let mut fr = LineFramer::<96>::new();
        let out = run(&mut fr, &[b"$HCHDM,2\x0038.5,M*25\r\n", HDT]);
        assert_eq!(out, [F::C(FrameError::BadByte(0)), l(HDT)]);
        assert_eq!(fr.stats().bad_bytes, 1);
    }

    #[test]
    fn prompt_at_line_start_only() {
        let mut fr = LineFramer::<96>::new();
        let out = run(&mut fr, &[b">", HDM, b"\r\n>a>b\r\n"]);
        assert_eq!(out, [F::P, l(HDM), F::P, F::L(b"a>b".to_vec())]);
    }
}

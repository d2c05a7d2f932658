//! A bounded line framer for ASCII protocols (compass NMEA and KVH dialects, Extron SIS).
//! `no_std`, no heap, no panics.
//!
//! Push bytes in (any split), get whole lines out. The framer
//!
//! * accepts any mix of CR and LF as terminators and ignores empty lines;
//! * bounds every line to `N` bytes (without terminator): a longer line is dropped whole,
//!   reported once as [`FrameError::Overlong`], and the framer discards until the next
//!   terminator (or start byte);
//! * drops a line holding a byte outside printable ASCII ([`FrameError::BadByte`]) the same
//!   way; such bytes between lines are dropped silently;
//! * and, as its [`Rules`] say: treats a start byte (NMEA's `$`) in the middle of a line as
//!   the proof that the line before it was cut short — the partial line is dropped (counted)
//!   and a new one starts at the start byte, which is the resync after garbage; yields a
//!   prompt byte (KVH's `>`, which the device does not terminate) as [`Frame::Prompt`] as
//!   soon as it arrives between lines; checks each line's own checksum
//!   ([`FrameError::BadChecksum`]).
//!
//! Lines borrow the framer's buffer, so nothing is copied or allocated. Every dropped byte
//! and line is counted in [`LineStats`].

/// Why a line was dropped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum FrameError {
    /// Longer than the framer's bound.
    Overlong,
    /// Contained this byte, outside printable ASCII.
    BadByte(u8),
    /// The line's checksum did not match: `expected` computed, `got` sent.
    BadChecksum {
        /// Computed over the line.
        expected: u8,
        /// Sent in the line.
        got: u8,
    },
}

impl core::fmt::Display for FrameError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Overlong => f.write_str("line too long"),
            Self::BadByte(b) => write!(f, "non-printable byte 0x{b:02x} in a line"),
            Self::BadChecksum { expected, got } => {
                write!(f, "line checksum 0x{got:02x}, computed 0x{expected:02x}")
            }
        }
    }
}

impl core::error::Error for FrameError {}

/// What the framer found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Frame<'a> {
    /// A complete line, without its terminator (checksum verified, if the rules check one).
    Line(&'a [u8]),
    /// The prompt byte of the [`Rules`].
    Prompt,
    /// A line was lost; the stream goes on.
    Corrupt(FrameError),
}

/// A check of a line's own checksum: `Err(BadChecksum { .. })` (or any other
/// [`FrameError`]) drops the line; lines without a checksum should pass.
pub type Check = fn(&[u8]) -> Result<(), FrameError>;

/// What a dialect adds to the plain framer.
#[derive(Debug, Clone, Copy, Default)]
pub struct Rules {
    /// A byte that always starts a line (NMEA's `$`): met inside a line, it drops the
    /// partial line and starts a new one.
    pub start: Option<u8>,
    /// A byte delivered as [`Frame::Prompt`] when it arrives between lines (KVH's `>`).
    pub prompt: Option<u8>,
    /// Run on every complete line.
    pub check: Option<Check>,
}

impl Rules {
    /// No start byte, no prompt, no checksum: lines are printable ASCII between terminators.
    pub const PLAIN: Self = Self {
        start: None,
        prompt: None,
        check: None,
    };
}

/// Counters of a framer (all saturating).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct LineStats {
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
    /// Throwing bytes away until a terminator or start byte.
    Discarding,
}

/// A bounded line framer; `N` is the longest line (without terminator) it keeps.
#[derive(Debug, Clone)]
pub struct LineFramer<const N: usize> {
    buf: [u8; N],
    len: usize,
    state: State,
    clear_next: bool,
    rules: Rules,
    stats: LineStats,
}

impl<const N: usize> Default for LineFramer<N> {
    /// A framer with the [`Rules::PLAIN`] rules.
    fn default() -> Self {
        Self::new(Rules::PLAIN)
    }
}

fn add(c: &mut u32, n: usize) {
    *c = c.saturating_add(u32::try_from(n).unwrap_or(u32::MAX));
}

impl<const N: usize> LineFramer<N> {
    /// An empty framer following `rules`.
    #[must_use]
    pub const fn new(rules: Rules) -> Self {
        Self {
            buf: [0; N],
            len: 0,
            state: State::Idle,
            clear_next: false,
            rules,
            stats: LineStats {
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
    pub const fn stats(&self) -> LineStats {
        self.stats
    }

    /// Bytes of the line in progress.
    #[must_use]
    pub const fn pending(&self) -> usize {
        if self.clear_next { 0 } else { self.len }
    }

    /// Forget the line in progress (counted as dropped).
    pub fn reset(&mut self) {
        if !self.clear_next {
            add(&mut self.stats.dropped_bytes, self.len);
        }
        self.len = 0;
        self.clear_next = false;
        self.state = State::Idle;
    }

    fn push_to_line(&mut self, b: u8) -> bool {
        match self.buf.get_mut(self.len) {
            Some(slot) => {
                *slot = b;
                self.len = self.len.saturating_add(1);
                true
            }
            None => false,
        }
    }

    /// Drop the line in progress and this byte, and discard until the next terminator.
    fn spoil(&mut self) {
        add(&mut self.stats.dropped_bytes, self.len.saturating_add(1));
        self.len = 0;
        self.state = State::Discarding;
    }

    /// Feed one byte; returns a frame when one completes.
    pub fn push_byte(&mut self, b: u8) -> Option<Frame<'_>> {
        if self.clear_next {
            self.len = 0;
            self.clear_next = false;
        }
        match b {
            b'\r' | b'\n' => {
                let was = self.state;
                self.state = State::Idle;
                if was != State::InLine || self.len == 0 {
                    return None;
                }
                self.clear_next = true;
                let line = self.buf.get(..self.len).unwrap_or_default();
                if let Some(check) = self.rules.check
                    && let Err(e) = check(line)
                {
                    add(&mut self.stats.dropped_bytes, line.len());
                    add(&mut self.stats.bad_checksums, 1);
                    return Some(Frame::Corrupt(e));
                }
                add(&mut self.stats.lines, 1);
                Some(Frame::Line(line))
            }
            _ if Some(b) == self.rules.start => {
                if self.state == State::InLine {
                    add(&mut self.stats.dropped_bytes, self.len);
                }
                self.len = 0;
                if self.push_to_line(b) {
                    self.state = State::InLine;
                } else {
                    // A zero-capacity framer keeps nothing.
                    add(&mut self.stats.dropped_bytes, 1);
                    self.state = State::Discarding;
                }
                None
            }
            _ if Some(b) == self.rules.prompt && self.state == State::Idle => {
                add(&mut self.stats.prompts, 1);
                Some(Frame::Prompt)
            }
            0x20..=0x7e => match self.state {
                State::Discarding => {
                    add(&mut self.stats.dropped_bytes, 1);
                    None
                }
                State::Idle | State::InLine => {
                    if self.push_to_line(b) {
                        self.state = State::InLine;
                        None
                    } else {
                        add(&mut self.stats.overlong, 1);
                        self.spoil();
                        Some(Frame::Corrupt(FrameError::Overlong))
                    }
                }
            },
            _ => match self.state {
                State::InLine => {
                    add(&mut self.stats.bad_bytes, 1);
                    self.spoil();
                    Some(Frame::Corrupt(FrameError::BadByte(b)))
                }
                // Noise between lines: drop the byte, stay where we are.
                State::Idle | State::Discarding => {
                    add(&mut self.stats.dropped_bytes, 1);
                    None
                }
            },
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

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use std::vec::Vec;

    #[derive(Debug, Clone, PartialEq)]
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
                });
            });
        }
        out
    }

    fn l(s: &[u8]) -> F {
        F::L(s.to_vec())
    }

    /// XOR of the bytes between `$` and `*`, checked against the two hex digits after `*`.
    fn xor_check(line: &[u8]) -> Result<(), FrameError> {
        let Some((b'$', rest)) = line.split_first() else {
            return Ok(());
        };
        let Some(star) = rest.len().checked_sub(3) else {
            return Ok(());
        };
        let (body, tail) = rest.split_at(star);
        let [b'*', hi, lo] = tail else {
            return Ok(());
        };
        let hex = |c: u8| char::from(c).to_digit(16);
        let (Some(hi), Some(lo)) = (hex(*hi), hex(*lo)) else {
            return Ok(());
        };
        let got = u8::try_from(hi * 16 + lo).unwrap_or(0);
        let expected = body.iter().fold(0, |a, b| a ^ b);
        if expected == got {
            Ok(())
        } else {
            Err(FrameError::BadChecksum { expected, got })
        }
    }

    const NMEA: Rules = Rules {
        start: Some(b'$'),
        prompt: Some(b'>'),
        check: Some(xor_check),
    };

    const HDM: &[u8] = b"$HCHDM,238.5,M*25\r\n";
    const HDT: &[u8] = b"$HCHDT,238.5,T*25\r\n";

    fn nmea(s: &[u8]) -> F {
        l(s.strip_suffix(b"\r\n").unwrap_or(s))
    }

    #[test]
    fn many_lines_per_read_and_one_byte_reads() {
        let mut f = LineFramer::<96>::default();
        assert_eq!(
            run(&mut f, &[b"In3 All\r\nE01\r\nVmt1\r\n"]),
            [l(b"In3 All"), l(b"E01"), l(b"Vmt1")]
        );
        let bytes = b"In12 Vid\r\n";
        let chunks: Vec<&[u8]> = bytes.chunks(1).collect();
        assert_eq!(run(&mut f, &chunks), [l(b"In12 Vid")]);
        assert_eq!(f.stats().lines, 4);
        assert_eq!(f.stats().dropped_bytes, 0);
    }

    #[test]
    fn cr_only_lf_only_and_blank_lines() {
        let mut fr = LineFramer::<96>::new(NMEA);
        let out = run(
            &mut fr,
            &[b"\r\n\r\n$HCHDM,238.5,M*25\r$HCHDT,238.5,T*25\n\n\rH9V9M0.1\n"],
        );
        assert_eq!(out, [nmea(HDM), nmea(HDT), l(b"H9V9M0.1")]);
    }

    #[test]
    fn plain_garbage_overlong_then_good() {
        let mut f = LineFramer::<8>::default();
        let out = run(
            &mut f,
            &[
                b"\x00\xffIn3\x01 All\r\n",
                b"0123456789ABC\r\n",
                b"In4 All\r\n",
            ],
        );
        assert_eq!(
            out,
            [
                F::C(FrameError::BadByte(1)),
                F::C(FrameError::Overlong),
                l(b"In4 All")
            ]
        );
        let s = f.stats();
        assert_eq!(s.overlong, 1);
        assert_eq!(s.bad_bytes, 1);
        assert_eq!(s.dropped_bytes, 2 + 8 + 13);
    }

    #[test]
    fn garbage_before_and_between_lines() {
        let mut fr = LineFramer::<96>::new(NMEA);
        let stream = [b"xx\x00\xff junk".as_slice(), HDM, b"\x07\x08", HDT].concat();
        let out = run(&mut fr, &[&stream]);
        // "xx" then NUL: a line spoilt by a bad byte (reported); the rest up to the `$` is
        // discarded; BEL/BS between lines are dropped silently.
        assert_eq!(out, [F::C(FrameError::BadByte(0)), nmea(HDM), nmea(HDT)]);
        assert_eq!(fr.stats().dropped_bytes, 3 + 6 + 2);
    }

    #[test]
    fn truncated_line_then_good_one() {
        let mut fr = LineFramer::<96>::new(NMEA);
        let out = run(&mut fr, &[b"$HCHDM,23", HDT]);
        assert_eq!(out, [nmea(HDT)]);
        assert_eq!(fr.stats().dropped_bytes, 9);
        // Without a start byte the two run together into one line.
        let mut plain = LineFramer::<96>::default();
        assert_eq!(run(&mut plain, &[b"$HCHDM,23", HDT]).len(), 1);
        assert_eq!(plain.stats().dropped_bytes, 0);
    }

    #[test]
    fn overlong_then_bad_checksum_then_good() {
        let mut fr = LineFramer::<16>::new(NMEA);
        let long = [b"$".as_slice(), &[b'A'; 40], b"\r\n"].concat();
        let out = run(&mut fr, &[&long, b"$C1.0*01\r\n".as_slice()]);
        // The XOR of "C1.0" is 0x43^0x31^0x2e^0x30 = 0x6C.
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
        assert_eq!(run(&mut fr, &[b"$C1.0*6C\r\n"]), [l(b"$C1.0*6C")]);
        assert_eq!(fr.stats().overlong, 1);
        assert_eq!(fr.stats().bad_checksums, 1);
        assert_eq!(fr.stats().lines, 1);
    }

    #[test]
    fn overlong_resyncs_on_the_start_byte() {
        let mut fr = LineFramer::<16>::new(NMEA);
        let stream = [&[b'A'; 40][..], HDM].concat();
        // With N = 16 the HDM line itself (17 bytes) is too long as well.
        assert_eq!(
            run(&mut fr, &[&stream]),
            [F::C(FrameError::Overlong), F::C(FrameError::Overlong)]
        );
        let mut fr = LineFramer::<96>::new(NMEA);
        let stream = [&[b'A'; 200][..], HDM].concat();
        assert_eq!(
            run(&mut fr, &[&stream]),
            [F::C(FrameError::Overlong), nmea(HDM)]
        );
    }

    #[test]
    fn bad_byte_inside_a_line() {
        let mut fr = LineFramer::<96>::new(NMEA);
        let out = run(&mut fr, &[b"$HCHDM,2\x0038.5,M*25\r\n", HDT]);
        assert_eq!(out, [F::C(FrameError::BadByte(0)), nmea(HDT)]);
        assert_eq!(fr.stats().bad_bytes, 1);
    }

    #[test]
    fn prompt_at_line_start_only() {
        let mut fr = LineFramer::<96>::new(NMEA);
        let out = run(&mut fr, &[b">", HDM, b"\r\n>a>b\r\n"]);
        assert_eq!(out, [F::P, nmea(HDM), F::P, l(b"a>b")]);
        assert_eq!(fr.stats().prompts, 2);
    }

    #[test]
    fn reset_and_pending() {
        let mut fr = LineFramer::<96>::default();
        assert!(run(&mut fr, &[b"abc"]).is_empty());
        assert_eq!(fr.pending(), 3);
        fr.reset();
        assert_eq!(fr.pending(), 0);
        assert_eq!(fr.stats().dropped_bytes, 3);
        assert_eq!(run(&mut fr, &[b"d\n"]), [l(b"d")]);
        assert_eq!(fr.pending(), 0);
    }

    #[test]
    fn zero_capacity_keeps_nothing() {
        let mut fr = LineFramer::<0>::new(NMEA);
        assert_eq!(
            run(&mut fr, &[b"$a\r\nb\r\n>"]),
            [F::C(FrameError::Overlong), F::P]
        );
        assert_eq!(fr.stats().dropped_bytes, 3);
    }

    fn rules() -> impl Strategy<Value = Rules> {
        prop_oneof![Just(Rules::PLAIN), Just(NMEA)]
    }

    fn stream() -> impl Strategy<Value = Vec<u8>> {
        // Bytes biased towards the ones the framer treats specially.
        let byte = prop_oneof![
            3 => proptest::sample::select(b"$>\r\nA,*0".to_vec()),
            1 => any::<u8>(),
        ];
        proptest::collection::vec(byte, 0..300)
    }

    proptest! {
        /// Any split of the input gives the same frames and the same counters.
        #[test]
        fn any_split_gives_the_same_frames(
            rules in rules(),
            bytes in stream(),
            cuts in proptest::collection::vec(any::<proptest::sample::Index>(), 0..8),
        ) {
            let mut whole = LineFramer::<24>::new(rules);
            let want = run(&mut whole, &[&bytes]);
            let mut at: Vec<usize> = cuts.iter().map(|i| i.index(bytes.len() + 1)).collect();
            at.sort_unstable();
            let mut chunks = Vec::new();
            let mut from = 0;
            for &cut in &at {
                chunks.push(&bytes[from..cut]);
                from = cut;
            }
            chunks.push(&bytes[from..]);
            let mut split = LineFramer::<24>::new(rules);
            prop_assert_eq!(run(&mut split, &chunks), want);
            prop_assert_eq!(split.stats(), whole.stats());
        }

        /// Lines are bounded, printable, unterminated; every overlong line is counted; every
        /// byte is either delivered, dropped or still pending.
        #[test]
        fn lines_are_bounded_and_every_byte_is_accounted_for(
            rules in rules(),
            bytes in stream(),
        ) {
            let mut fr = LineFramer::<16>::new(rules);
            let mut delivered = 0usize;
            let mut overlong = 0u32;
            for &b in &bytes {
                match fr.push_byte(b) {
                    Some(Frame::Line(line)) => {
                        prop_assert!(!line.is_empty() && line.len() <= 16);
                        prop_assert!(line.iter().all(|c| (0x20..=0x7e).contains(c)));
                        delivered += line.len();
                    }
                    Some(Frame::Corrupt(FrameError::Overlong)) => overlong += 1,
                    Some(Frame::Prompt) => delivered += 1,
                    _ => {}
                }
            }
            let s = fr.stats();
            prop_assert_eq!(s.overlong, overlong);
            let terminators = bytes.iter().filter(|&&b| b == b'\r' || b == b'\n').count();
            prop_assert_eq!(
                delivered + s.dropped_bytes as usize + fr.pending() + terminators,
                bytes.len()
            );
        }
    }
}

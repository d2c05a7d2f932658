//! [`Decoder`]: `ima decode`'s decoders fed a capture a piece at a time (`ima replay` and
//! `ima decode --mcap` feed a recording's chunks as they are read).

use anyhow::Result;
use serde_json::Value;

/// A decoder fed a capture a piece at a time: [`feed`](Self::feed) emits what the bytes so
/// far complete, [`finish`](Self::finish) what is left at the end (a truncated frame). Offsets
/// count from the first byte fed, and a capture fed whole or in any pieces emits the same
/// objects (`ima replay` and `ima decode --mcap` feed a recording's chunks as they are read).
pub trait Decoder {
    /// Decode the next bytes of the capture.
    fn feed(&mut self, bytes: &[u8], emit: &mut dyn FnMut(Value) -> Result<()>) -> Result<()>;
    /// The capture ended.
    fn finish(&mut self, emit: &mut dyn FnMut(Value) -> Result<()>) -> Result<()>;

    /// Decode a whole capture: [`feed`](Self::feed) it, then [`finish`](Self::finish).
    fn decode_whole(mut self, bytes: &[u8], emit: &mut dyn FnMut(Value) -> Result<()>) -> Result<()>
    where
        Self: Sized,
    {
        self.feed(bytes, emit)?;
        self.finish(emit)
    }
}

/// A host command being read by a decoder of commands that end at a byte: where it began, its
/// first `limit` bytes and its length. Bytes past the limit are counted, not kept, so a stream
/// with no end in sight (the wrong direction, a binary file) cannot grow the decoder.
#[derive(Debug)]
pub struct HostCommand {
    limit: usize,
    start: usize,
    kept: Vec<u8>,
    len: usize,
}

impl HostCommand {
    /// A command of at most `limit` bytes, the first beginning at offset 0.
    pub fn new(limit: usize) -> Self {
        Self {
            limit,
            start: 0,
            kept: Vec::new(),
            len: 0,
        }
    }

    /// The command's next byte.
    pub fn push(&mut self, b: u8) {
        if self.kept.len() < self.limit {
            self.kept.push(b);
        }
        self.len += 1;
    }

    /// The command ended; the next begins at offset `next`. Its offset, and its bytes, or its
    /// length when that is over the limit.
    pub fn end(&mut self, next: usize) -> (usize, std::result::Result<Vec<u8>, usize>) {
        let offset = std::mem::replace(&mut self.start, next);
        let kept = std::mem::take(&mut self.kept);
        match std::mem::take(&mut self.len) {
            len if len > self.limit => (offset, Err(len)),
            _ => (offset, Ok(kept)),
        }
    }

    /// The input ended at offset `end`: a command begun there and not ended is reported, at
    /// its offset, as truncated.
    pub fn finish(&self, end: usize, emit: &mut dyn FnMut(Value) -> Result<()>) -> Result<()> {
        if self.start < end {
            emit(
                serde_json::json!({"kind": "error", "error": "truncated command at end of input",
                "offset": self.start}),
            )?;
        }
        Ok(())
    }
}

/// A boxed decoder (`ima decode` picks one at run time) is one.
impl<D: Decoder + ?Sized> Decoder for Box<D> {
    fn feed(&mut self, bytes: &[u8], emit: &mut dyn FnMut(Value) -> Result<()>) -> Result<()> {
        (**self).feed(bytes, emit)
    }
    fn finish(&mut self, emit: &mut dyn FnMut(Value) -> Result<()>) -> Result<()> {
        (**self).finish(emit)
    }
}

/// Checks for [`Decoder`]s.
/// A line framer's loss in the words of `ima decode`'s errors.
pub fn line_error(e: ima_serial::line::FrameError) -> String {
    use ima_serial::line::FrameError;
    match e {
        FrameError::Overlong => "line too long".into(),
        FrameError::BadByte(b) => format!("non-printable byte {b:#04x}"),
        FrameError::BadChecksum { expected, got } => {
            format!("bad checksum: computed {expected:02X}, line has {got:02X}")
        }
    }
}

#[cfg(test)]
pub mod pieces {
    /// A megabyte with no command end holds the limit, not the megabyte, and is reported as
    /// its length; the command after it is whole.
    #[test]
    fn a_host_command_without_an_end_is_counted_not_kept() {
        let mut c = super::HostCommand::new(16);
        for _ in 0..1 << 20 {
            c.push(b'x');
            assert!(c.kept.capacity() <= 32);
        }
        assert_eq!(c.end((1 << 20) + 1), (0, Err(1 << 20)));
        c.push(b'g');
        c.push(b'o');
        assert_eq!(c.start, (1 << 20) + 1);
        assert_eq!(c.end((1 << 20) + 4), ((1 << 20) + 1, Ok(b"go".to_vec())));
        for _ in 0..16 {
            c.push(b'y');
        }
        assert_eq!(c.end(0).1, Ok(vec![b'y'; 16]), "the limit itself is kept");
    }

    use super::{Decoder, Value};

    fn run(d: &mut dyn Decoder, pieces: &[&[u8]]) -> Vec<Value> {
        let mut out = Vec::new();
        let mut emit = |v: Value| {
            out.push(v);
            Ok(())
        };
        for p in pieces {
            d.feed(p, &mut emit).unwrap();
        }
        d.finish(&mut emit).unwrap();
        out
    }

    /// `capture` fed whole, a byte at a time, and cut in two at every byte (and cut short at
    /// every byte, then fed the rest, from a fresh decoder's view: the same objects either way)
    /// emits the same objects; `fresh` makes a new decoder. Returns what the whole emits.
    pub fn decode_alike(fresh: &dyn Fn() -> Box<dyn Decoder>, capture: &[u8]) -> Vec<Value> {
        let whole = run(&mut *fresh(), &[capture]);
        let bytes: Vec<&[u8]> = capture.chunks(1).collect();
        assert_eq!(run(&mut *fresh(), &bytes), whole, "a byte at a time");
        for at in 0..=capture.len() {
            let (a, b) = capture.split_at(at);
            assert_eq!(run(&mut *fresh(), &[a, b]), whole, "cut at {at}");
            assert_eq!(
                run(&mut *fresh(), &[a, &[], b]),
                whole,
                "cut at {at}, empty between"
            );
        }
        whole
    }
}

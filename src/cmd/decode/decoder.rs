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
#[cfg(test)]
pub mod pieces {
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

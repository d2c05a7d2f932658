//! Fuzz entry points, shared by `fuzz/fuzz_targets/compass_*.rs` (cargo-fuzz) and the corpus
//! replay test (`tests/fuzz_corpus.rs`). None may panic on any input; the round-trip target
//! asserts its invariant (that is its purpose).
#![allow(clippy::panic)]

use core::time::Duration;

use ima_hal::Instant;

use crate::framer::Frame;
use crate::machine::{Config, Dialect, Machine};
use crate::wire::{
    CalScore, Command, Decimal, EastWest, Hdg, Hdm, Hdt, Line, NmeaBody, NmeaSentence, Offset,
    ParseOptions, Talker, Tcm2Data, Tcm2Format,
};

/// Bytes from the device, any garbage: the first byte picks the read size, the rest is the
/// stream. Runs the framer, both parse strictnesses, the device-side command parser and three
/// sessions (NMEA, KVH, TCM2 mid-calibration) with timeouts interleaved.
pub fn compass_lines(data: &[u8]) {
    let Some((&sel, stream)) = data.split_first() else {
        return;
    };
    let chunk = usize::from(sel % 16).saturating_add(1);
    let lax = ParseOptions {
        allow_missing_checksum: true,
    };
    let mut framer = crate::framer::framer::<{ crate::wire::MAX_LINE }>();
    framer.push(stream, |f| {
        if let Frame::Line(l) = f {
            let _ = Line::parse(l, &ParseOptions::default());
            let _ = Line::parse(l, &lax);
            let _ = Command::parse(l);
        }
    });

    let dialects = [
        Dialect::Nmea,
        Dialect::KvhC100 {
            rate_per_minute: 600,
        },
        Dialect::Tcm2 {
            sample_rate_hz: 8,
            output: Tcm2Format::Standard,
        },
    ];
    for dialect in dialects {
        let mut m = Machine::new(Config {
            parse: lax,
            ..Config::for_dialect(dialect)
        });
        let mut now = Instant::ZERO;
        m.start(now);
        let mut buf = [0u8; 32];
        for (i, c) in stream.chunks(chunk).enumerate() {
            now = now + Duration::from_millis(u64::from(sel) * 7 % 400);
            m.handle_bytes(c, now);
            if i % 3 == 0 {
                m.handle_timeout(now);
            }
            if i == 5 {
                let _ = m.start_user_calibration(now);
            }
            if i == 40 {
                let _ = m.stop_user_calibration(now);
            }
            while m.poll_transmit(&mut buf).is_some() {}
            while m.poll_event().is_some() {}
            let _ = m.poll_timeout();
        }
        let _ = m.stats();
    }
}

/// Round trips. (1) `data` as a line: whatever parses must emit and parse back to the same
/// value. (2) `data` as a command, likewise. (3) `data` as a recipe for a message built
/// field by field: emit then parse gives it back.
pub fn compass_roundtrip(data: &[u8]) {
    let lax = ParseOptions {
        allow_missing_checksum: true,
    };
    let mut buf = [0u8; 192];
    if let Ok(line) = Line::parse(data, &lax) {
        let n = line.emit(&mut buf).unwrap_or(0);
        assert!(n > 0, "parsed line must emit: {line:?}");
        let again = Line::parse(buf.get(..n).unwrap_or(&[]), &ParseOptions::default());
        assert_eq!(again, Ok(line));
    }
    if let Ok(cmd) = Command::parse(data) {
        let n = cmd.emit(&mut buf).unwrap_or(0);
        assert_eq!(Command::parse(buf.get(..n).unwrap_or(&[])), Ok(cmd));
    }
    let mut r = Recipe(data);
    let line = r.line();
    if let Ok(n) = line.emit(&mut buf) {
        let got = Line::parse(buf.get(..n).unwrap_or(&[]), &ParseOptions::default());
        assert_eq!(got, Ok(line), "emitted {:?}", buf.get(..n));
    }
}

/// Reads typed values from fuzz bytes (zeros once exhausted).
struct Recipe<'a>(&'a [u8]);

impl Recipe<'_> {
    fn u8(&mut self) -> u8 {
        match self.0.split_first() {
            Some((b, rest)) => {
                self.0 = rest;
                *b
            }
            None => 0,
        }
    }

    fn i32(&mut self) -> i32 {
        i32::from_le_bytes([self.u8(), self.u8(), self.u8(), self.u8()])
    }

    fn bool(&mut self) -> bool {
        self.u8() & 1 == 1
    }

    fn decimal(&mut self) -> Option<Decimal> {
        let units = i64::from(self.i32());
        let d = self.u8() % 6;
        let i = self.u8() % 6;
        Decimal::with_int_digits(units, d, i)
    }

    fn opt_decimal(&mut self) -> Option<Decimal> {
        if self.bool() { self.decimal() } else { None }
    }

    fn offset(&mut self) -> Option<Offset> {
        let dir = if self.bool() {
            EastWest::East
        } else {
            EastWest::West
        };
        self.opt_decimal().map(|degrees| Offset { degrees, dir })
    }

    fn line(&mut self) -> Line {
        match self.u8() % 6 {
            0 => Line::Prompt,
            1 => Line::CalScore(CalScore {
                h: self.u8() % 10,
                v: self.u8() % 10,
                m: self.decimal().unwrap_or(Decimal::ZERO),
            }),
            2 => Line::Tcm2(Tcm2Data {
                heading: self.opt_decimal(),
                pitch: self.opt_decimal(),
                roll: self.opt_decimal(),
                bx: self.opt_decimal(),
                by: self.opt_decimal(),
                bz: self.opt_decimal(),
                temperature: self.opt_decimal(),
                error: self
                    .bool()
                    .then(|| u16::from_le_bytes([self.u8(), self.u8()])),
            }),
            k => {
                let talker = Talker([b'A' + self.u8() % 26, b'A' + self.u8() % 26]);
                let body = match k {
                    3 => NmeaBody::Hdm(Hdm {
                        heading: self.opt_decimal(),
                    }),
                    4 => NmeaBody::Hdt(Hdt {
                        heading: self.opt_decimal(),
                    }),
                    _ => NmeaBody::Hdg(Hdg {
                        heading: self.opt_decimal(),
                        deviation: self.offset(),
                        variation: self.offset(),
                    }),
                };
                Line::Nmea(NmeaSentence { talker, body })
            }
        }
    }
}

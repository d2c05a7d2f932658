//! Fuzz harnesses, shared by `fuzz/fuzz_targets/sick_lms_*.rs` and the corpus replay test.
//!
//! None may panic on any input; the `assert!`s are invariants a fuzzer should break if the
//! code is wrong (a delivered frame that does not parse, emit → parse not giving back the
//! message). Under `cfg(fuzzing)` CRC checks always pass, so the fuzzer reaches the payloads.

use core::time::Duration;

use ima_hal::Instant;
use ima_hal::laser::LaserScan;

use crate::decode::{Variant, decode_scan};
use crate::framer::{Framer, Item};
use crate::machine::{Config, Machine};
use crate::wire::{Command, Frame, MAX_TELEGRAM, MeasuringMode, Reply};

/// A tiny xorshift so chunk sizes and time steps follow from the input's first byte.
struct Rng(u32);

impl Rng {
    fn next(&mut self) -> u32 {
        let mut x = self.0;
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        self.0 = x;
        x
    }
}

/// `sick_lms_framer`: the first byte seeds the chunking and time steps, the rest is a byte
/// stream fed to a reply framer, a command framer and a whole [`Machine`].
pub fn sick_lms_framer(data: &[u8]) {
    let Some((&seed, stream)) = data.split_first() else {
        return;
    };
    let mut rng = Rng(u32::from(seed) | 0x100);
    let mut replies = Framer::replies();
    let mut commands = Framer::commands()
        .with_partial_timeout(Duration::from_millis(6))
        .report_bad_checksums(true);
    let cfg = Config {
        rs422: true,
        ..Config::default()
    };
    let mut now = Instant::ZERO;
    let mut machine = Machine::new(cfg, now);
    let mut out = [0u8; 64];
    let mut scan = LaserScan::default();
    let mut rest = stream;
    while !rest.is_empty() {
        let want = (rng.next() % 97) as usize + 1;
        let n = want.min(rest.len());
        let (chunk, tail) = rest.split_at(n);
        rest = tail;
        // Mostly close together, sometimes past the 35 ms partial-frame expiry.
        let step = if rng.next().is_multiple_of(8) {
            40_000
        } else {
            500
        };
        now = now + Duration::from_micros(step);
        replies.push_all(chunk, now, |item| {
            if let Item::Frame(f) = item {
                assert!(Reply::from_frame(&f).is_ok());
                assert!(f.as_bytes().len() <= MAX_TELEGRAM);
            }
        });
        commands.push_all(chunk, now, |item| {
            if let Item::Frame(f) = item {
                assert!(Command::from_frame(&f).is_ok());
            }
        });
        machine.handle_bytes_with(chunk, now, |s, _| {
            let _ = decode_scan(s, MeasuringMode::DEFAULT, None, &mut scan);
        });
        if machine.poll_timeout().is_some_and(|t| t <= now) {
            machine.handle_timeout(now);
        }
        while machine.poll_event().is_some() {}
        while machine.poll_transmit(&mut out).is_some() {}
    }
    assert!(replies.buffered() <= MAX_TELEGRAM);
}

/// `sick_lms_parse_reply`: one telegram through every parser and the B0 decoder.
pub fn sick_lms_parse_reply(data: &[u8]) {
    let _ = Command::parse(data);
    if let Ok(Reply::Scan(s)) = Reply::parse(data) {
        let mut out = LaserScan::default();
        for mode in [0x00u8, 0x01, 0x03, 0x05, 0x0F, 0x3F, 0x0D] {
            let _ = decode_scan(&s, MeasuringMode(mode), None, &mut out);
            let _ = decode_scan(&s, MeasuringMode(mode), Some(Variant::W180_R50), &mut out);
        }
    } else if let Ok(Reply::Status { block, .. }) = Reply::parse(data) {
        let _ = (block.baud(), block.scan_angle_deg(), block.prom_version());
        let _ = (block.firmware(), block.restart(), block.measuring_mode());
    }
}

/// `sick_lms_roundtrip`: whatever parses must emit and parse back to the same message, with
/// the same bytes (except the CRC, which `cfg(fuzzing)` does not check on the way in).
pub fn sick_lms_roundtrip(data: &[u8]) {
    let Ok(frame) = Frame::new_checked(data) else {
        return;
    };
    let mut buf = [0u8; MAX_TELEGRAM];
    if let Ok(r) = Reply::from_frame(&frame) {
        let n = r.emit_from(frame.address(), &mut buf);
        assert!(n.is_ok());
        let n = n.unwrap_or(0);
        let back = Reply::parse(buf.get(..n).unwrap_or(&[]));
        assert_eq!(back, Ok(r));
        assert_eq!(
            buf.get(..n.saturating_sub(2)),
            data.get(..data.len().saturating_sub(2))
        );
    }
    if let Ok(c) = Command::from_frame(&frame) {
        let n = c.emit_to(frame.address(), &mut buf);
        assert!(n.is_ok());
        let n = n.unwrap_or(0);
        assert_eq!(n, c.buffer_len());
        assert_eq!(Command::parse(buf.get(..n).unwrap_or(&[])), Ok(c));
        assert_eq!(
            buf.get(..n.saturating_sub(2)),
            data.get(..data.len().saturating_sub(2))
        );
    }
}

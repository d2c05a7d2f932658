//! Fuzz harnesses, shared by the `cargo fuzz` targets in `fuzz/` and by the corpus replay test
//! (`tests/fuzz_corpus.rs`). None of them may panic on any input; `rflex_roundtrip` asserts
//! the emit → parse invariant, which is what a round-trip target is for.
//!
//! Under `cfg(fuzzing)` the framer skips checksum verification (as smoltcp does), so the fuzzer
//! reaches the payload parsers without having to guess an XOR.

use core::time::Duration;

use ima_hal::Instant;
use ima_hal::base::VelocityCommand;

use crate::framer::{Framer, FramerConfig};
use crate::machine::{Config, Machine, TX_BUF};
use crate::wire::{
    Command, MAX_CONTENT, MAX_WIRE_FRAME, RawFrame, Report, Stuffing, encode_frame, unstuff_frame,
};

/// Split `data` into a control byte and the rest.
fn control(data: &[u8]) -> (u8, &[u8]) {
    match data.split_first() {
        Some((&c, rest)) => (c, rest),
        None => (0, &[]),
    }
}

/// Robot → host: the whole host session over arbitrary bytes, cut into chunks whose size
/// (1–16) and flags come from the first byte, with virtual time advancing between chunks and
/// user requests sprinkled in.
pub fn rflex_from_robot(data: &[u8]) {
    let (c, rest) = control(data);
    let chunk = usize::from(c & 0x0F) + 1;
    let cfg = Config {
        framer: FramerConfig {
            lenient: c & 0x10 != 0,
            ..FramerConfig::default()
        },
        zero_speed_quirk: c & 0x20 != 0,
        legacy_no_stuff: c & 0x40 != 0,
        release_brake_at_start: c & 0x80 != 0,
        ..Config::default()
    };
    let mut now = Instant::ZERO;
    let mut m = Machine::new(cfg, now);
    let mut buf = [0u8; TX_BUF];
    for (k, piece) in rest.chunks(chunk).enumerate() {
        now = now + Duration::from_millis(u64::from(piece.first().copied().unwrap_or(0) % 64));
        m.handle_bytes(piece, now);
        match k % 7 {
            1 => {
                let _ = m.enable_motors(true, now);
            }
            2 => {
                let v = f64::from(piece.last().copied().unwrap_or(0)) / 100.0 - 1.0;
                let _ = m.set_velocity(VelocityCommand::new(v, -v), now);
            }
            5 if piece.len() == 16 => m.shutdown(now),
            _ => {}
        }
        while m.poll_transmit(&mut buf).is_some() {}
        while m.poll_event().is_some() {}
        if let Some(t) = m.poll_timeout() {
            m.handle_timeout(t.max(now));
        }
    }
    let _ = m.odometry();
}

/// Host → robot: what the mock ATRV-Jr does with its input: strict and lenient framers, and
/// every frame parsed as a [`Command`].
pub fn rflex_from_host(data: &[u8]) {
    let (c, rest) = control(data);
    let chunk = usize::from(c & 0x1F) + 1;
    for lenient in [false, true] {
        let mut f = Framer::new(FramerConfig {
            lenient,
            ..FramerConfig::default()
        });
        let mut t = Instant::ZERO;
        for piece in rest.chunks(chunk) {
            t = t + Duration::from_millis(u64::from(c >> 5) * 10);
            f.bytes_arrived(t);
            f.push(piece, |item| {
                if let Ok(raw) = item {
                    let _ = Command::from_raw(&raw);
                }
            });
        }
    }
    let _ = Command::parse(rest);
}

/// Emit → parse round trips: every frame found in `data` is parsed as a [`Command`] and as a
/// [`Report`]; whatever parses is emitted again (full stuffing, same id) and must parse back
/// to the same message. The raw bytes after the control byte are also framed directly and
/// must unstuff to themselves.
pub fn rflex_roundtrip(data: &[u8]) {
    let (c, rest) = control(data);
    let stuffing = if c & 1 == 0 {
        Stuffing::Full
    } else {
        Stuffing::EscOnly
    };
    let mut f = Framer::strict();
    f.push(rest, |item| {
        if let Ok(raw) = item {
            check_frame(&raw, stuffing);
        }
    });
    // Arbitrary content through the encoder and back.
    if let [port, id, opcode, payload @ ..] = rest {
        let payload = payload.get(..payload.len().min(255)).unwrap_or(&[]);
        let mut wire = [0u8; MAX_WIRE_FRAME];
        let n = encode_frame(*port, *id, *opcode, payload, stuffing, &mut wire);
        assert!(n.is_ok(), "encode of a ≤ 255-byte payload failed");
        let n = n.unwrap_or(0);
        let mut scratch = [0u8; MAX_CONTENT];
        let parsed = RawFrame::parse_wire(wire.get(..n).unwrap_or(&[]), &mut scratch);
        assert_eq!(
            parsed.map(|r| (r.port, r.id, r.opcode, r.data == payload)),
            Ok((*port, *id, *opcode, true))
        );
    }
    let mut scratch = [0u8; MAX_CONTENT];
    let _ = unstuff_frame(rest, &mut scratch);
}

fn check_frame(raw: &RawFrame<'_>, stuffing: Stuffing) {
    let mut wire = [0u8; MAX_WIRE_FRAME];
    if let Ok(cmd) = Command::from_raw(raw)
        && !matches!(cmd, Command::Unknown(_))
    {
        let n = cmd.emit_with(raw.id, stuffing, &mut wire);
        assert!(n.is_ok(), "emit of a parsed command failed: {cmd:?}");
        let back = Command::parse(wire.get(..n.unwrap_or(0)).unwrap_or(&[]));
        assert_eq!(back, Ok(cmd));
    }
    if let Ok(rep) = Report::from_raw(raw)
        && !matches!(rep, Report::Unknown(_))
    {
        let n = rep.emit_with(raw.id, stuffing, &mut wire);
        assert!(n.is_ok(), "emit of a parsed report failed: {rep:?}");
        let back = Report::parse(wire.get(..n.unwrap_or(0)).unwrap_or(&[]));
        assert_eq!(back, Ok(rep));
    }
}

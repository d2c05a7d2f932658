//! Fuzz entry points, shared by `fuzz/fuzz_targets/video_mux_*.rs` (cargo-fuzz) and the
//! corpus replay test (`tests/fuzz_corpus.rs`). None may panic on any input; the round-trip
//! checks assert their invariant (that is their purpose).
#![allow(clippy::panic)]

use core::time::Duration;

use ima_hal::Instant;

use crate::framer::{Frame, LineFramer};
use crate::machine::{Config, Dialect, Machine};
use crate::wire::{ExtronCommand, ExtronReply, KramerMessage, TieKind};

/// Bytes from a switcher, any garbage: the first byte picks the read size and the requests
/// made along the way; the rest is the stream. Runs both dialects' sessions (select, query,
/// timeouts), checks that every SIS reply that parses emits and parses back to itself, and
/// runs the device-side command splitter and parser over the same bytes.
pub fn video_mux_replies(data: &[u8]) {
    let Some((&sel, stream)) = data.split_first() else {
        return;
    };
    let chunk = usize::from(sel % 16).saturating_add(1);

    let mut lines = LineFramer::<{ crate::framer::MAX_LINE }>::default();
    let mut buf = [0u8; 128];
    for &b in stream {
        if let Some(Frame::Line(l)) = lines.push_byte(b)
            && let Ok(r) = ExtronReply::parse(l)
        {
            let n = r.emit(&mut buf).unwrap_or(0);
            assert!(n > 0, "parsed reply must emit: {r:?}");
            assert_eq!(ExtronReply::parse(buf.get(..n).unwrap_or(&[])), Ok(r));
        }
    }

    // Device side: split into commands at action characters, parse, round-trip.
    let mut rest = stream;
    while let Some(end) = ExtronCommand::command_end(rest) {
        let (cmd, tail) = rest.split_at(end);
        if let Ok(c) = ExtronCommand::parse(cmd) {
            let n = c.emit(&mut buf).unwrap_or(0);
            assert_eq!(ExtronCommand::parse(buf.get(..n).unwrap_or(&[])), Ok(c));
        }
        rest = tail;
    }
    for w in stream.windows(4) {
        if let Ok(m) = KramerMessage::parse(w) {
            assert_eq!(m.to_bytes().ok().as_ref().map(|b| &b[..]), Some(w));
        }
    }

    let dialects = [
        Dialect::Extron {
            kind: TieKind::All,
            output: None,
        },
        Dialect::Extron {
            kind: TieKind::Video,
            output: Some(1),
        },
        Dialect::Kramer {
            output: 1,
            machine: 1,
            expect_reply: true,
        },
        Dialect::Kramer {
            output: 1,
            machine: 1,
            expect_reply: false,
        },
    ];
    for dialect in dialects {
        let mut m = Machine::new(Config {
            dialect,
            report_unsolicited: sel & 0x80 != 0,
            ..Config::default()
        });
        let mut now = Instant::ZERO;
        for (i, c) in stream.chunks(chunk).enumerate() {
            now = now + Duration::from_millis(u64::from(sel) * 3 % 700);
            if i % 4 == 0 {
                let channel = c.first().copied().unwrap_or(1) % 9;
                let _ = m.select(channel, now);
            } else if i % 7 == 0 {
                let _ = m.query(now);
            }
            while m.poll_transmit(&mut buf).is_some() {}
            m.handle_bytes(c, now);
            m.handle_timeout(now);
            while m.poll_event().is_some() {}
            let _ = m.poll_timeout();
        }
        let _ = m.stats();
    }
}

/// Bytes from a frame server (`net_frames`, feature `std`): parsed as a request and as a
/// header at every offset; a header that parses must emit and parse back to itself, and its
/// payload length must fit the size limit.
#[cfg(feature = "std")]
pub fn video_mux_net_frames(data: &[u8]) {
    use crate::net_frames::{Header, MAX_SIDE, Request};
    for start in 0..data.len().min(64) {
        let rest = data.get(start..).unwrap_or_default();
        if let Ok(r) = Request::parse(rest) {
            assert_eq!(Request::parse(&r.emit()), Ok(r));
        }
        if let Ok(h) = Header::parse(rest) {
            assert_eq!(Header::parse(&h.emit()), Ok(h));
            assert!(u64::from(h.payload_len()) <= u64::from(MAX_SIDE) * u64::from(MAX_SIDE) * 3);
        }
    }
}

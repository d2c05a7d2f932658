//! Corruption statistics (spec §10 item 13): 20,000 realistic SIPs (0–16 fresh sonar readings
//! each), 1 % of the bytes replaced by a different random value (pinned seeds, so the run is
//! deterministic), read in random chunks of 1–64 bytes through [`Framer::new`] and parsed.
//!
//! What catches what, in order:
//! 1. **Framer, header hunt:** a corrupted `FA FB` hides the frame (its bytes are dropped).
//! 2. **Framer, count byte:** a count under 3 is rejected (`bad_counts`); any other corrupted
//!    count makes the frame's length wrong, and the checksum then fails.
//! 3. **Framer, checksum:** a single corrupted byte is always caught (proved exhaustively in
//!    `proptest_wire.rs`); two or more can cancel (the sum is additive), at about 2⁻¹⁶ per
//!    multi-byte-corrupted frame.
//! 4. **Parse plausibility** (`Packet::parse`), for what passed the checksum: sonar count
//!    inconsistent with the length or > 32 (`BadSonarCount`), sonar index ≥ 32
//!    (`BadSonarIndex`), too short (`Truncated`); a corrupted type byte turns a SIP into a
//!    non-SIP packet, which the session does not take as odometry.
//!
//! Checks after that (odometry jump bounded by speed × time, battery range) belong to the
//! session (`machine`), not to wire parsing, and are not exercised here.
//!
//! Observed with these seeds (x86_64, rand 0.9 `SmallRng`; print them with
//! `cargo test -p ima-p2os --test corruption -- --nocapture`):
//! * 20,000 SIPs (893,253 bytes, 9,027 changed): 12,830 intact, **all delivered**; 7,170
//!   corrupted, all but one rejected by the framer (it counted 6,765 bad checksums and 4 bad
//!   counts; SIPs whose `FA FB` was hit never became candidates); **1 escape**: two
//!   sonar-range low bytes changed by −39 and +39 (payload offsets 48 and 60, both the high
//!   byte of a checksum pair), which cancel in the sum and are plausible values, so no
//!   wire-level check can see them.
//! * 1,000,000 SIPs (the ignored test below, in release mode): 641,605 intact, all delivered
//!   (ARIA lost 2.3 %, spec §10 item 13); 358,395 corrupted; **87** passed the checksum (ARIA:
//!   89); of those, parse caught **14** (sonar index ≥ 32), **3** came out as a non-SIP
//!   packet type, and **70** escaped as SIPs. Their 134 corrupted payload bytes sat in fields
//!   the wire cannot judge: sonar ranges 38, pose (x/y/θ) 30, velocities 14, control 8, stall
//!   8, compass 8, flags 7, battery 4, sonar index (to another valid index) 4, I/O and gripper
//!   bytes 13. Catching more needs the session's checks (odometry jump ≤ speed × time,
//!   battery range).
//!
//! Intact SIPs are never lost: resynchronising one byte after every rejected candidate (spec
//! §10 item 2) keeps them all.

mod common;

use ima_p2os::wire::{Packet, WireError};
use ima_p2os::{FrameEvent, Framer};
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};
use std::collections::HashMap;

const SIPS: usize = 20_000;
const STREAM_SEED: u64 = 0x0002_A7A7;
const CORRUPT_SEED: u64 = 0x0000_C0DE;
const CHUNK_SEED: u64 = 0x0000_5EED;

#[derive(Debug, Default)]
struct Tally {
    intact: usize,
    intact_delivered: usize,
    corrupted: usize,
    /// Corrupted SIPs whose frame passed the framer (checksum good) at its own position.
    corrupted_passed_checksum: usize,
    /// Candidates that passed the checksum but not at a real SIP's position.
    spurious_frames: usize,
    caught_sonar_count: usize,
    caught_sonar_index: usize,
    caught_truncated: usize,
    caught_other_parse: usize,
    /// Passed checksum and parse, but as a non-SIP packet type.
    delivered_as_non_sip: usize,
    /// Passed checksum and parse as a SIP that differs from what was sent.
    escapes_as_sip: usize,
}

#[test]
fn one_percent_byte_corruption_over_20000_sips() {
    let (t, st) = run(SIPS, 0);
    // About a third of the SIPs are hit at 1 % per byte (≈ 45 bytes each).
    assert!(t.corrupted > SIPS / 5 && t.corrupted < SIPS / 2, "{t:?}");
    // ≥ 98 % of the intact SIPs arrive (in fact all of them).
    assert!(t.intact_delivered * 100 >= t.intact * 98, "{t:?}");
    assert_eq!(t.intact_delivered, t.intact, "no intact SIP lost: {t:?}");
    // Every delivered frame is accounted for.
    assert_eq!(
        st.frames as usize,
        t.intact_delivered + t.corrupted_passed_checksum + t.spurious_frames
    );
    // The checksum lets through only a sliver of the corrupted frames (≈ 2⁻¹⁶ of the
    // multi-byte-corrupted ones), and parse plausibility narrows that further.
    assert!(
        t.corrupted_passed_checksum + t.spurious_frames <= 10,
        "{t:?}"
    );
    assert!(t.escapes_as_sip <= t.corrupted_passed_checksum + t.spurious_frames);
    assert!(t.escapes_as_sip <= 5, "{t:?}");
}

/// The spec's scale (1 M SIPs, as in the ARIA measurement of §10 item 13). Slow in a debug
/// build: `cargo test --release -p ima-p2os --test corruption -- --ignored --nocapture`.
#[test]
#[ignore = "long: 1 M SIPs; run by hand in release mode"]
fn one_percent_byte_corruption_over_a_million_sips() {
    let (t, _) = run(1_000_000, 1);
    assert_eq!(t.intact_delivered, t.intact, "no intact SIP lost: {t:?}");
}

fn run(sips_n: usize, seed_offset: u64) -> (Tally, ima_p2os::FramerStats) {
    let (mut stream, spans, sips) = common::sip_stream(STREAM_SEED + seed_offset, sips_n);
    let clean = stream.clone();
    let changed = common::corrupt(&mut stream, 0.01, CORRUPT_SEED + seed_offset);
    assert!(changed.len() > stream.len() / 120 && changed.len() < stream.len() / 80);

    // Which SIPs have at least one changed byte.
    let mut corrupted = vec![false; sips_n];
    let mut s = 0;
    for &pos in &changed {
        while spans[s].1 <= pos {
            s += 1;
        }
        corrupted[s] = true;
    }
    let by_start: HashMap<usize, usize> = spans
        .iter()
        .enumerate()
        .map(|(i, &(a, _))| (a, i))
        .collect();

    let mut t = Tally {
        corrupted: corrupted.iter().filter(|&&c| c).count(),
        ..Tally::default()
    };
    t.intact = sips_n - t.corrupted;

    let mut framer = Framer::new();
    let mut rng = SmallRng::seed_from_u64(CHUNK_SEED + seed_offset);
    let mut fed = 0usize;
    let mut rest = &stream[..];
    while !rest.is_empty() {
        let n = rng.random_range(1..=64usize).min(rest.len());
        let (chunk, later) = rest.split_at(n);
        rest = later;
        let mut chunk = chunk;
        while !chunk.is_empty() {
            let took = framer.feed(chunk);
            chunk = &chunk[took..];
            fed += took;
            loop {
                let payload = match framer.next_frame() {
                    None => break,
                    Some(FrameEvent::Rejected(_)) => continue,
                    Some(FrameEvent::Frame(p)) => p.to_vec(),
                };
                let end = fed - framer.buffered();
                let start = end - payload.len() - 5;
                classify(
                    &mut t, &payload, start, end, &by_start, &spans, &sips, &corrupted, &clean,
                );
            }
        }
    }

    let st = framer.stats();
    eprintln!(
        "corruption: {} bytes, {} changed; {} SIPs: {} intact ({} delivered), {} corrupted \
         ({} passed the checksum at their own position); {} spurious frames; framer: \
         bad_checksums {}, bad_counts {}, dropped {}; caught by parse: sonar count {}, sonar \
         index {}, truncated {}, other {}; delivered as non-SIP {}; ESCAPES as SIP {}",
        stream.len(),
        changed.len(),
        sips_n,
        t.intact,
        t.intact_delivered,
        t.corrupted,
        t.corrupted_passed_checksum,
        t.spurious_frames,
        st.bad_checksums,
        st.bad_counts,
        st.dropped_bytes,
        t.caught_sonar_count,
        t.caught_sonar_index,
        t.caught_truncated,
        t.caught_other_parse,
        t.delivered_as_non_sip,
        t.escapes_as_sip,
    );

    (t, st)
}

#[allow(clippy::too_many_arguments)]
fn classify(
    t: &mut Tally,
    payload: &[u8],
    start: usize,
    end: usize,
    by_start: &HashMap<usize, usize>,
    spans: &[(usize, usize)],
    sips: &[ima_p2os::wire::Sip],
    corrupted: &[bool],
    clean: &[u8],
) {
    let at_sip = by_start.get(&start).copied().filter(|&i| spans[i].1 == end);
    if let Some(i) = at_sip {
        if !corrupted[i] {
            assert_eq!(payload, &clean[start + 3..end - 2]);
            assert_eq!(Packet::parse(payload), Ok(Packet::Sip(sips[i].clone())));
            t.intact_delivered += 1;
            return;
        }
        t.corrupted_passed_checksum += 1;
    } else {
        t.spurious_frames += 1;
    }
    match Packet::parse(payload) {
        Err(WireError::BadSonarCount(_)) => t.caught_sonar_count += 1,
        Err(WireError::BadSonarIndex(_)) => t.caught_sonar_index += 1,
        Err(WireError::Truncated) => t.caught_truncated += 1,
        Err(_) => t.caught_other_parse += 1,
        Ok(Packet::Sip(got)) => {
            t.escapes_as_sip += 1;
            let diff: Vec<(usize, u8, u8)> = payload
                .iter()
                .zip(&clean[start + 3..end - 2])
                .enumerate()
                .filter(|(_, (a, b))| a != b)
                .map(|(k, (a, b))| (k, *b, *a))
                .collect();
            eprintln!(
                "escape: frame at byte {start}, payload (offset, sent, received) {diff:?}, \
                 parsed as {} sonar readings",
                got.sonars.len()
            );
        }
        Ok(_) => t.delivered_as_non_sip += 1,
    }
}

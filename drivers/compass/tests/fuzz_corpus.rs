//! Replays the committed fuzz corpora through the same harness functions cargo-fuzz runs, so
//! `cargo test` catches a regression on any saved input without nightly or cargo-fuzz.

use ima_hal::fuzzing::replay_corpus;

const CORPORA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../fuzz/corpus");

/// Every input and every prefix of it: truncated inputs are the commonest real-world damage.
fn replay(target: &str, harness: fn(&[u8])) {
    replay_corpus(CORPORA, target, harness, true).unwrap();
}

#[test]
fn compass_lines_corpus() {
    replay("compass_lines", ima_compass::fuzz_harness::compass_lines);
}

#[test]
fn compass_roundtrip_corpus() {
    replay(
        "compass_roundtrip",
        ima_compass::fuzz_harness::compass_roundtrip,
    );
}

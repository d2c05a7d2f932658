//! Replays every committed fuzz corpus file through its harness (so `cargo test` covers the
//! corpora even where `cargo fuzz` is not installed).

use ima_hal::fuzzing::replay_corpus;

const CORPORA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../fuzz/corpus");

fn replay(target: &str, harness: fn(&[u8])) {
    replay_corpus(CORPORA, target, harness, false).unwrap();
}

#[test]
fn rflex_from_robot_corpus() {
    replay(
        "rflex_from_robot",
        ima_rflex::fuzz_harness::rflex_from_robot,
    );
}

#[test]
fn rflex_from_host_corpus() {
    replay("rflex_from_host", ima_rflex::fuzz_harness::rflex_from_host);
}

#[test]
fn rflex_roundtrip_corpus() {
    replay("rflex_roundtrip", ima_rflex::fuzz_harness::rflex_roundtrip);
}

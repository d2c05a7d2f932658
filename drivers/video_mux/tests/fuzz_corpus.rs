//! Replays the committed fuzz corpora (and every prefix of each input) through the same
//! harness functions cargo-fuzz runs, so `cargo test` catches a regression on any saved input
//! without nightly or cargo-fuzz.

use ima_hal::fuzzing::replay_corpus;
use ima_video_mux::fuzz_harness;

const CORPORA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../fuzz/corpus");

#[test]
fn video_mux_replies_corpus() {
    let h = fuzz_harness::video_mux_replies;
    replay_corpus(CORPORA, "video_mux_replies", h, true).unwrap();
}

#[test]
fn video_mux_net_frames_corpus() {
    let h = fuzz_harness::video_mux_net_frames;
    replay_corpus(CORPORA, "video_mux_net_frames", h, true).unwrap();
}

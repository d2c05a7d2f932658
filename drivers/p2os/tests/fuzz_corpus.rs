//! Replays every committed fuzz corpus file (`fuzz/corpus/p2os_*`) through the fuzz harness,
//! so the invariants the fuzzer checked keep holding in a plain `cargo test` (with checksums
//! on, unlike the `cfg(fuzzing)` build).

use ima_hal::fuzzing::replay_corpus;
use ima_p2os::fuzz_harness;
use std::path::Path;

const CORPORA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../fuzz/corpus");

fn replay(target: &str, harness: fn(&[u8])) {
    let files = replay_corpus(CORPORA, target, harness, false).unwrap();
    eprintln!("{target}: replayed {files} files");
}

#[test]
fn p2os_from_robot_corpus() {
    replay("p2os_from_robot", fuzz_harness::p2os_from_robot);
}

#[test]
fn p2os_from_host_corpus() {
    replay("p2os_from_host", fuzz_harness::p2os_from_host);
}

#[test]
fn p2os_roundtrip_corpus() {
    replay("p2os_roundtrip", fuzz_harness::p2os_roundtrip);
}

/// The seed corpus really exercises the parsers: the spec's SIP vector delivers one frame.
#[test]
fn seed_corpus_contains_the_spec_vectors() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fuzz/corpus");
    let t20 = std::fs::read(dir.join("p2os_from_robot/t20_sip_whole")).unwrap();
    assert_eq!(t20.len(), 1 + 36);
    assert_eq!(
        ima_p2os::wire::parse_robot_frame(&t20[1..]).map(|p| p.name()),
        Ok("sip")
    );
    let t18 = std::fs::read(dir.join("p2os_from_host/t18_say_whole")).unwrap();
    assert_eq!(
        ima_p2os::wire::parse_host_frame(&t18[1..]).map(|c| c.name()),
        Ok("say")
    );
}

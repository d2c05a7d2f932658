//! Replays every committed fuzz corpus file through its harness (so `cargo test` covers the
//! corpora even where `cargo fuzz` is not installed).

use std::fs;
use std::path::Path;

fn replay(target: &str, harness: fn(&[u8])) {
    let dir = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../fuzz/corpus")).join(target);
    assert!(dir.is_dir(), "missing corpus {}", dir.display());
    let mut n = 0;
    for entry in fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_file() {
            harness(&fs::read(&path).unwrap());
            n += 1;
        }
    }
    assert!(n > 0, "empty corpus {}", dir.display());
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

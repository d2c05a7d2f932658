//! Replays the committed fuzz corpora through the same harness functions cargo-fuzz runs, so
//! `cargo test` catches a regression on any saved input without nightly or cargo-fuzz.

use std::path::PathBuf;

fn replay(target: &str, run: fn(&[u8])) {
    let dir = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../fuzz/corpus")).join(target);
    assert!(
        dir.is_dir(),
        "corpus directory {} is missing",
        dir.display()
    );
    let mut files = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_file() {
            let data = std::fs::read(&path).unwrap();
            run(&data);
            // Every prefix too: truncated inputs are the commonest real-world damage.
            for n in 0..data.len() {
                run(&data[..n]);
            }
            files += 1;
        }
    }
    assert!(files > 0, "corpus directory {} is empty", dir.display());
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

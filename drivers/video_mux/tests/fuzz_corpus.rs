//! Replays the committed fuzz corpus through the same harness function cargo-fuzz runs, so
//! `cargo test` catches a regression on any saved input without nightly or cargo-fuzz.

use std::path::PathBuf;

#[test]
fn video_mux_replies_corpus() {
    let dir = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../fuzz/corpus"))
        .join("video_mux_replies");
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
            ima_video_mux::fuzz_harness::video_mux_replies(&data);
            for n in 0..data.len() {
                ima_video_mux::fuzz_harness::video_mux_replies(&data[..n]);
            }
            files += 1;
        }
    }
    assert!(files > 0, "corpus directory {} is empty", dir.display());
}

#[test]
fn video_mux_net_frames_corpus() {
    let dir = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../fuzz/corpus"))
        .join("video_mux_net_frames");
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
            ima_video_mux::fuzz_harness::video_mux_net_frames(&data);
            for n in 0..data.len() {
                ima_video_mux::fuzz_harness::video_mux_net_frames(&data[..n]);
            }
            files += 1;
        }
    }
    assert!(files > 0, "corpus directory {} is empty", dir.display());
}

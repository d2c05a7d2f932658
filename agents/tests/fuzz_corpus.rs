//! Replay every committed fuzz-corpus file through its harness.

use std::path::Path;

fn replay(dir: &str, harness: fn(&[u8])) {
    let dir = Path::new(dir);
    assert!(dir.is_dir(), "missing corpus {}", dir.display());
    let mut n = 0;
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_file() {
            harness(&std::fs::read(&p).unwrap());
            n += 1;
        }
    }
    assert!(n > 0, "empty corpus {}", dir.display());
}

#[test]
fn ses_shared_form_corpus() {
    replay(
        concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../fuzz/corpus/ses_shared_form"
        ),
        ima_agents::fuzz_harness::ses_shared_form,
    );
}

/// Writes the seed corpus (run with `--ignored` after a format change).
#[test]
#[ignore = "regenerates fuzz/corpus/ses_shared_form"]
fn write_seed_corpus() {
    use ima_agents::ses::Direction;
    use ima_agents::ses::shared::{SharedForm, SharedRecord};
    use ima_hal::Instant;
    let dir = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../fuzz/corpus/ses_shared_form"
    );
    std::fs::create_dir_all(dir).unwrap();
    let rec = |object: &str, az: f64, el: f64, range: Option<f64>, t: u64| SharedRecord {
        object: object.into(),
        bearing: Direction::new(az, el),
        range_m: range,
        confidence: 0.75,
        time: Instant::from_micros(t),
    };
    let forms = [
        SharedForm {
            source_robot: "skeeter".into(),
            sent_at: Instant::from_micros(5_000_000),
            records: vec![],
        },
        SharedForm {
            source_robot: "skeeter".into(),
            sent_at: Instant::from_micros(5_000_000),
            records: vec![
                rec("red", 0.5, 0.0, Some(3.2), 4_000_000),
                rec("scooter", -2.0, 0.1, None, 5_000_000),
                rec("blue", 3.1, -0.2, Some(655.35), 1_000_000),
            ],
        },
        SharedForm {
            source_robot: "s".repeat(32),
            sent_at: Instant::from_micros(u64::MAX),
            records: vec![rec(&"o".repeat(64), -3.0, 1.5, Some(0.0), u64::MAX - 7)],
        },
    ];
    for (i, f) in forms.iter().enumerate() {
        std::fs::write(format!("{dir}/seed-{i}.bin"), f.to_bytes().unwrap()).unwrap();
    }
    let good = forms[1].to_bytes().unwrap();
    std::fs::write(format!("{dir}/truncated.bin"), &good[..good.len() / 2]).unwrap();
    let mut bad = good.clone();
    let n = bad.len();
    bad[n - 1] ^= 0xFF;
    std::fs::write(format!("{dir}/bad-crc.bin"), &bad).unwrap();
    std::fs::write(format!("{dir}/garbage.bin"), b"\x53\x45\x01\xff\x00\x00").unwrap();
}

//! What recording costs, without the noise of a whole demo: one wall second of `ima demo`'s
//! message mix (counts from a release demo at ×4: 9.5 MB and ~8,300 messages over 16 s),
//! logged and written to a fresh MCAP file, `finish` included — so the figure covers the
//! callers' conversions and the recorder thread's encoding, compression and writing.
//!
//! Divided by 1 s, the median approximates the share of one core that recording the demo
//! takes (the recorder's thread mostly waits for `finish` here, so the two run one after the
//! other); the demo itself uses 23–70 ms of CPU per wall second, depending on the machine
//! (`scripts/record-cpu.sh`). `--example cost` measures the two sides' CPU separately.
//!
//! `cargo bench -p ima-record --bench mix`

use std::time::Duration;

use ima_hal::camera::Frame;
use ima_hal::laser::{BeamFlags, LaserScan};
use ima_record::convert::Pose2;
use ima_record::{Options, Recorder};

mod common;
use common::{frame, port};

fn main() {
    divan::main();
}

fn scan(k: u32) -> LaserScan {
    let mut s = LaserScan::new(-core::f64::consts::FRAC_PI_2, 0.5f64.to_radians());
    for i in 0..361u32 {
        let r = 2.0 + ((i * 7 + k) % 50) as f32 * 0.013;
        let _ = s.push(r, BeamFlags::default());
    }
    s
}

/// One wall second of the demo: 4 camera frames, 34 laser scans, ~270 raw serial chunks,
/// ~120 poses and transforms, ~30 log lines and ~26 JSON state messages.
#[divan::bench(sample_count = 20, sample_size = 1)]
fn one_second_of_the_demo(bencher: divan::Bencher) {
    let dir = std::env::temp_dir().join(format!("ima-bench-mix-{}", std::process::id()));
    let _ = std::fs::create_dir_all(&dir);
    let frames: Vec<Frame> = (0..4).map(|i| frame(i, (i % 7 + 1) as u8)).collect();
    let scans: Vec<LaserScan> = (0..34).map(scan).collect();
    let json = serde_json::json!({"t_s": 12.5, "robot": "scooter", "modules": (0..12)
        .map(|i| serde_json::json!({"name": format!("module-{i}"), "activation": 0.25 * f64::from(i), "executable": i % 2 == 0}))
        .collect::<Vec<_>>()});
    let mut n = 0u32;
    bencher.bench_local(|| {
        n += 1;
        let path = dir.join(format!("mix-{n}.mcap"));
        let _ = std::fs::remove_file(&path);
        let rec = Recorder::start(&Options {
            mcap: Some(path.clone()),
            name: "bench".into(),
            ..Options::default()
        })
        .expect("recorder");
        let base = rec.raw_port(port("scooter", "base", 115_200));
        let laser = rec.raw_port(port("scooter", "laser", 38_400));
        let small = rec.raw_port(port("skeeter", "base", 9_600));
        let p = |k: u32| Pose2 {
            x_m: f64::from(k) * 0.01,
            y_m: 0.5,
            theta_rad: 0.1,
        };
        for k in 0..34u32 {
            rec.log_scan("scooter", &scans[k as usize]);
            laser.rx(&[0x5a; 732]);
            for _ in 0..5 {
                base.rx(&[0x1b; 33]);
            }
            base.tx(&[0x1b; 20]);
            small.rx(&[0xfa; 30]);
            rec.log_odometry("scooter", p(k));
            rec.log_ground_truth("scooter", p(k));
            rec.log_ground_truth("skeeter", p(k));
            rec.log_text(
                "/events",
                ima_record::messages::log::Level::Info,
                "scooter",
                "control {\"v\":0.3}",
            );
            if k % 9 == 0 {
                rec.log_image("skeeter", &frames[(k / 9) as usize]);
            }
            if k % 4 == 0 {
                rec.log_compass("scooter", 0.1);
                rec.log_json(
                    "/san/scooter",
                    "ima.SanState",
                    || serde_json::json!({"type": "object"}),
                    &json,
                );
                rec.log_json(
                    "/peer/scooter/status",
                    "ima.PeerStatus",
                    || serde_json::json!({"type": "object"}),
                    &json,
                );
                rec.log_json(
                    "/san/skeeter",
                    "ima.SanState",
                    || serde_json::json!({"type": "object"}),
                    &json,
                );
            }
        }
        let report = rec.finish(Duration::from_secs(30));
        assert_eq!(report.dropped, 0);
        let _ = std::fs::remove_file(&path);
    });
    let _ = std::fs::remove_dir_all(&dir);
}

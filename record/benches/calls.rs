//! What one logging call costs the robot's thread that makes it (the recorder's thread
//! drains the queue meanwhile, on its own tick): a raw serial chunk, a pose, a scan, a log
//! line, a JSON state, a camera frame. Nothing here allocates once a stream exists.
//!
//! `cargo bench -p ima-record --bench calls`

use std::sync::LazyLock;

use ima_hal::camera::Frame;
use ima_hal::laser::{BeamFlags, LaserScan};
use ima_record::convert::Pose2;
use ima_record::raw::{PortInfo, RawPort};
use ima_record::{Options, Recorder};

fn main() {
    divan::main();
}

/// One recorder for every benchmark, writing to a temporary file (its queue is large enough
/// that nothing is dropped: a dropped message would cost less than a kept one).
static REC: LazyLock<Recorder> = LazyLock::new(|| {
    let path = std::env::temp_dir().join(format!("ima-bench-calls-{}.mcap", std::process::id()));
    let _ = std::fs::remove_file(&path);
    Recorder::start(&Options {
        mcap: Some(path),
        name: "bench".into(),
        queue: 1 << 20,
        ..Options::default()
    })
    .expect("recorder")
});

static PORT: LazyLock<RawPort> = LazyLock::new(|| {
    REC.raw_port(PortInfo {
        robot: "scooter".into(),
        device: "base".into(),
        port: "/dev/pts/1".into(),
        baud: 115_200,
        protocol: "rflex".into(),
        params: Default::default(),
    })
});

#[divan::bench]
fn raw_chunk_33_bytes() {
    PORT.rx(divan::black_box(&[0x1b; 33]));
}

#[divan::bench]
fn odometry() {
    REC.log_odometry("scooter", divan::black_box(Pose2::default()));
}

#[divan::bench]
fn ground_truth() {
    REC.log_ground_truth("scooter", divan::black_box(Pose2::default()));
}

#[divan::bench]
fn laser_scan_361(bencher: divan::Bencher) {
    let mut s = LaserScan::new(-1.57, 0.0087);
    for i in 0..361 {
        let _ = s.push(2.0 + i as f32 * 0.01, BeamFlags::default());
    }
    bencher.bench(|| REC.log_scan("scooter", divan::black_box(&s)));
}

#[divan::bench]
fn log_line() {
    REC.log_text(
        "/events",
        ima_record::messages::log::Level::Info,
        "scooter",
        divan::black_box("control {\"v_mps\":0.3,\"w_radps\":0.1}"),
    );
}

#[divan::bench]
fn json_state(bencher: divan::Bencher) {
    let v = serde_json::json!({"t_s": 12.5, "robot": "scooter", "selected": "move-to-target",
        "modules": (0..12).map(|i| serde_json::json!({"name": format!("module-{i}"),
            "activation": 0.25 * f64::from(i), "executable": i % 2 == 0})).collect::<Vec<_>>()});
    bencher.bench(|| {
        REC.log_json(
            "/san/scooter",
            "ima.SanState",
            || serde_json::json!({"type": "object"}),
            divan::black_box(&v),
        );
    });
}

#[divan::bench(sample_count = 50)]
fn camera_frame_320x240(bencher: divan::Bencher) {
    let f = Frame::black(320, 240, Some(3)).expect("frame");
    bencher.bench(|| REC.log_image("skeeter", divan::black_box(&f)));
}

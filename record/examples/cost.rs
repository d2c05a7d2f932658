//! What recording one `ima demo` costs in CPU, without the noise of running the demo: the
//! message mix of one release demo run (its counts per topic, spread evenly over its 16 wall
//! seconds and logged at that pace from two threads, as the robot's threads log them) is
//! recorded to a fresh MCAP file. The callers' cost is the time their logging calls take
//! (summed per slice: the calls never block), the recorder thread's its CPU time from the
//! kernel ([`ima_record::Report::thread_cpu`], exact).
//!
//! `cargo run --release -p ima-record --example cost [-- SPEED [RUNS]]` (SPEED: how much
//! faster than the demo the mix is logged, default 1; RUNS default 3).
//!
//! Compare the total with the demo's own CPU (`scripts/record-cpu.sh` prints both).

use std::time::{Duration, Instant};

use ima_hal::camera::Frame;
use ima_hal::laser::{BeamFlags, LaserScan};
use ima_hal::sonar::{SonarReading, SonarScan, SonarTransducer};
use ima_record::convert::Pose2;
use ima_record::{Options, Recorder};

#[path = "../benches/common/mod.rs"]
mod common;
use common::{frame, port};

/// The demo's wall time, seconds.
const WALL_S: f64 = 16.0;
/// Slices the wall time is cut into (the messages of one slice are logged together).
const SLICES: u32 = 800;

fn scan(k: u32) -> LaserScan {
    let mut s = LaserScan::new(-core::f64::consts::FRAC_PI_2, 0.5f64.to_radians());
    let mut x = k.wrapping_mul(747_796_405).max(1);
    for _ in 0..361u32 {
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        let _ = s.push(2.0 + (x % 4000) as f32 * 0.001, BeamFlags::default());
    }
    s
}

/// Messages per demo run and topic kind (a release `ima demo --json --record`: its
/// `recording.written`).
struct Mix {
    scooter_base: u32,
    scooter_laser: u32,
    skeeter_base: u32,
    compass_raw: u32,
    mux_raw: u32,
    odometry: u32,
    scans: u32,
    events: u32,
    truth: u32,
    compass: u32,
    sonar: u32,
    json: u32,
    frames: u32,
}

const DEMO: Mix = Mix {
    scooter_base: 2559,
    scooter_laser: 579,
    skeeter_base: 214,
    compass_raw: 165,
    mux_raw: 127,
    odometry: 584,
    scans: 547,
    events: 513,
    truth: 642,
    compass: 147,
    sonar: 146,
    json: 450,
    frames: 61,
};

/// How many of `total` fall in slice `i` (evenly spread).
fn share(total: u32, i: u32) -> u32 {
    let at = |k: u32| u64::from(total) * u64::from(k) / u64::from(SLICES);
    (at(i + 1) - at(i)) as u32
}

fn main() {
    let mut args = std::env::args().skip(1);
    let speed: f64 = args.next().and_then(|a| a.parse().ok()).unwrap_or(1.0);
    let runs: u32 = args.next().and_then(|a| a.parse().ok()).unwrap_or(3);
    let dir = std::env::temp_dir().join(format!("ima-cost-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let frames: Vec<Frame> = (0..7).map(|i| frame(i, (i + 1) as u8)).collect();
    let scans: Vec<LaserScan> = (0..50).map(scan).collect();
    let transducers: Vec<SonarTransducer> = (0..8)
        .map(|i| SonarTransducer {
            pose: ima_hal::Isometry2::new(
                ima_hal::Vector2::new(0.1, 0.0),
                f64::from(i) * 0.3 - 1.0,
            ),
            min_range_m: 0.1,
            max_range_m: 5.0,
            beam_width_rad: 0.4,
        })
        .collect();
    let json = serde_json::json!({"t_s": 12.5, "robot": "scooter", "selected": "move-to-target",
        "modules": (0..12).map(|i| serde_json::json!({"name": format!("module-{i}"),
            "activation": 0.25 * f64::from(i), "executable": i % 2 == 0})).collect::<Vec<_>>()});
    println!(
        "recording one demo run's messages ({:.0} s of wall time at ×{speed}), {runs} runs",
        WALL_S
    );
    for run in 0..runs {
        let path = dir.join(format!("cost-{run}.mcap"));
        let _ = std::fs::remove_file(&path);
        let rec = Recorder::start(&Options {
            mcap: Some(path.clone()),
            name: "cost".into(),
            ..Options::default()
        })
        .expect("recorder");
        let slice = Duration::from_secs_f64(WALL_S / f64::from(SLICES) / speed);
        let t0 = Instant::now();
        // Two robot threads, as in the demo (serial and devices on one, the rest on the other).
        let (cpu_a, cpu_b) = std::thread::scope(|s| {
            let serial = s.spawn(|| {
                let sc_base = rec.raw_port(port("scooter", "base", 115_200));
                let sc_laser = rec.raw_port(port("scooter", "laser", 38_400));
                let sk_base = rec.raw_port(port("skeeter", "base", 9_600));
                let compass = rec.raw_port(port("scooter", "compass", 4_800));
                let mux = rec.raw_port(port("skeeter", "video_mux", 9_600));
                let mut busy = Duration::ZERO;
                for i in 0..SLICES {
                    let t = Instant::now();
                    for k in 0..share(DEMO.scooter_base, i) {
                        if k % 3 == 0 {
                            sc_base.tx(&[0x1b; 20]);
                        } else {
                            sc_base.rx(&[0x1b; 33]);
                        }
                    }
                    for _ in 0..share(DEMO.scooter_laser, i) {
                        sc_laser.rx(&[0x5a; 732]);
                    }
                    for _ in 0..share(DEMO.skeeter_base, i) {
                        sk_base.rx(&[0xfa; 30]);
                    }
                    for _ in 0..share(DEMO.compass_raw, i) {
                        compass.rx(b"$HCHDG,101.3,,,,*5A\r\n");
                    }
                    for _ in 0..share(DEMO.mux_raw, i) {
                        mux.rx(b"Vid3 All\r\n");
                    }
                    busy += t.elapsed();
                    std::thread::sleep(slice);
                }
                busy
            });
            let devices = s.spawn(|| {
                let mut busy = Duration::ZERO;
                let mut n = 0u32;
                for i in 0..SLICES {
                    let t = Instant::now();
                    let p = Pose2 {
                        x_m: f64::from(i) * 0.01,
                        y_m: 0.5,
                        theta_rad: 0.1,
                    };
                    for _ in 0..share(DEMO.odometry, i) {
                        rec.log_odometry("scooter", p);
                    }
                    for _ in 0..share(DEMO.scans, i) {
                        n += 1;
                        rec.log_scan("scooter", &scans[(n % 50) as usize]);
                    }
                    for _ in 0..share(DEMO.truth, i) {
                        rec.log_ground_truth(
                            if n.is_multiple_of(2) {
                                "scooter"
                            } else {
                                "skeeter"
                            },
                            p,
                        );
                    }
                    for _ in 0..share(DEMO.events, i) {
                        rec.log_text(
                            "/events",
                            ima_record::messages::log::Level::Info,
                            "scooter",
                            "control {\"v_mps\":0.3,\"w_radps\":0.1,\"dr\":[1.2,0.4]}",
                        );
                    }
                    for _ in 0..share(DEMO.compass, i) {
                        rec.log_compass("scooter", 0.1);
                    }
                    for _ in 0..share(DEMO.sonar, i) {
                        let mut scan = SonarScan::default();
                        for (k, _) in transducers.iter().enumerate() {
                            let _ = scan.readings.push(SonarReading {
                                index: k as u8,
                                range_m: 1.0 + k as f64 * 0.2,
                                at: ima_hal::Instant::ZERO,
                            });
                        }
                        rec.log_sonar("skeeter", &transducers, &scan);
                    }
                    for _ in 0..share(DEMO.json, i) {
                        rec.log_json(
                            "/san/scooter",
                            "ima.SanState",
                            || serde_json::json!({"type": "object"}),
                            &json,
                        );
                    }
                    for _ in 0..share(DEMO.frames, i) {
                        rec.log_image("skeeter", &frames[(i % 7) as usize]);
                    }
                    busy += t.elapsed();
                    std::thread::sleep(slice);
                }
                busy
            });
            (
                serial.join().expect("serial thread"),
                devices.join().expect("devices thread"),
            )
        });
        let report = rec.finish(Duration::from_secs(30));
        let wall = t0.elapsed();
        let ms = |d: Option<Duration>| d.map_or(f64::NAN, |d| d.as_secs_f64() * 1e3);
        let callers = ms(Some(cpu_a + cpu_b));
        let own = ms(report.thread_cpu);
        println!(
            "run {}: callers {callers:.1} ms + recorder thread {own:.1} ms = {:.1} ms CPU; \
             {} messages, {} dropped, {:.2} MB, {:.1} s wall",
            run,
            callers + own,
            report.total(),
            report.dropped,
            report.bytes as f64 / 1e6,
            wall.as_secs_f64()
        );
        let _ = std::fs::remove_file(&path);
    }
    let _ = std::fs::remove_dir_all(&dir);
}

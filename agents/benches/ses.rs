//! SES benchmarks: post, nearest-vertex lookup and query by tag on a default dome (frequency
//! 13, 1,692 vertices) holding ~2,000 entries. `cargo bench -p ima-agents --bench ses`.

use std::hint::black_box;

use divan::Bencher;
use ima_agents::ses::shared::SharedForm;
use ima_agents::ses::{Direction, Dome, Payload, Ses, SesConfig, Vec3};
use ima_hal::Instant;

#[global_allocator]
static ALLOC: divan::AllocProfiler = divan::AllocProfiler::system();

fn main() {
    divan::main();
}

/// Deterministic pseudo-random directions (xorshift).
fn directions(n: usize) -> Vec<Direction> {
    let mut s: u64 = 0x9E37_79B9_7F4A_7C15;
    let mut next = || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    (0..n)
        .map(|_| {
            let az = (next() * 2.0 - 1.0) * std::f64::consts::PI;
            let el = (next() * 2.0 - 1.0).asin();
            Direction::new(az, el)
        })
        .collect()
}

const TAGS: [&str; 8] = [
    "red", "blue", "green", "yellow", "orange", "scooter", "sonar", "laser",
];

/// An SES with 2,000 entries: 8 tags × 250 sources.
fn filled() -> Ses {
    let mut ses = Ses::new(SesConfig::default()).unwrap();
    for (i, d) in directions(2000).into_iter().enumerate() {
        let p = Payload {
            object: TAGS[i % 8].to_owned(),
            bearing: d,
            range_m: Some(2.0),
            confidence: 0.9,
        };
        ses.post(
            TAGS[i % 8],
            &format!("src{}", i / 8),
            Instant::from_millis(i as u64),
            p,
        )
        .unwrap();
    }
    ses
}

#[divan::bench(sample_count = 200, sample_size = 64)]
fn nearest_vertex(b: Bencher) {
    let dome = Dome::new(13).unwrap();
    let q: Vec<Vec3> = directions(1024).iter().map(|d| d.to_unit()).collect();
    let mut i = 0;
    b.bench_local(|| {
        i = (i + 1) & 1023;
        dome.nearest(black_box(&q[i]))
    });
}

#[divan::bench(sample_count = 50, sample_size = 16)]
fn nearest_vertex_brute_force(b: Bencher) {
    let dome = Dome::new(13).unwrap();
    let q: Vec<Vec3> = directions(1024).iter().map(|d| d.to_unit()).collect();
    let mut i = 0;
    b.bench_local(|| {
        i = (i + 1) & 1023;
        dome.nearest_brute(black_box(&q[i]))
    });
}

/// Re-posting an existing (tag, source): the steady state of a sensing agent.
#[divan::bench(sample_count = 200, sample_size = 64)]
fn post_replace(b: Bencher) {
    let mut ses = filled();
    let dirs = directions(1024);
    let mut i = 0_usize;
    b.bench_local(|| {
        i = (i + 1) & 1023;
        let p = Payload {
            object: String::new(),
            bearing: dirs[i],
            range_m: None,
            confidence: 1.0,
        };
        ses.post("red", "src7", Instant::from_millis(5000 + i as u64), p)
            .unwrap()
    });
}

#[divan::bench(sample_count = 200, sample_size = 16)]
fn query_by_tag(b: Bencher) {
    let ses = filled();
    b.bench_local(|| ses.by_tag(black_box("blue")).len());
}

#[divan::bench(sample_count = 200, sample_size = 16)]
fn query_by_direction_15deg(b: Bencher) {
    let ses = filled();
    let dirs = directions(64);
    let mut i = 0;
    b.bench_local(|| {
        i = (i + 1) & 63;
        ses.by_direction(dirs[i], 15f64.to_radians()).len()
    });
}

#[divan::bench(sample_count = 100, sample_size = 4)]
fn shared_form_encode_decode_1024_records(b: Bencher) {
    let ses = filled();
    let form = ses.export_shared("skeeter", Instant::from_millis(10_000), |_| true);
    b.bench_local(|| {
        SharedForm::decode(&form.to_bytes().unwrap())
            .unwrap()
            .records
            .len()
    });
}

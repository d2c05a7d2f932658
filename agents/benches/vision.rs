//! Vision benchmarks: the blob detector on a 320 × 240 frame with three objects and sensor
//! noise, and on a garbage frame of random bytes. `cargo bench -p ima-agents --bench vision`.

use std::hint::black_box;

use divan::Bencher;
use ima_agents::mission::vision::{ColourDb, DetectorConfig, find_blobs, focal_px};
use ima_hal::camera::Frame;

#[global_allocator]
static ALLOC: divan::AllocProfiler = divan::AllocProfiler::system();

fn main() {
    divan::main();
}

fn xorshift(s: &mut u64) -> u64 {
    *s ^= *s << 13;
    *s ^= *s >> 7;
    *s ^= *s << 17;
    *s
}

/// A grey 320 × 240 frame with red, blue and Scooter's marker, ±6 noise.
fn scene() -> Frame {
    let (w, h) = (320u32, 240u32);
    let mut f = Frame::black(w, h, Some(1)).unwrap();
    f.pixels.fill(128);
    let fpx = focal_px(w, 60f64.to_radians());
    for (b, range, radius, rgb) in [
        (0.3f64, 3.0f64, 0.15f64, [220u8, 30, 30]),
        (0.0, 2.0, 0.15, [30, 60, 220]),
        (-0.35, 4.0, 0.4, [235, 235, 235]),
    ] {
        let cx = f64::from(w) / 2.0 - fpx * b.tan();
        let r = fpx * radius / range;
        for y in 0..h {
            for x in 0..w {
                let (dx, dy) = (
                    f64::from(x) + 0.5 - cx,
                    f64::from(y) + 0.5 - f64::from(h) / 2.0,
                );
                if dx * dx + dy * dy <= r * r {
                    f.set_pixel(x, y, rgb);
                }
            }
        }
    }
    let mut s = 7u64;
    for p in &mut f.pixels {
        let j = (xorshift(&mut s) % 13) as i16 - 6;
        *p = (i16::from(*p) + j).clamp(0, 255) as u8;
    }
    f
}

#[divan::bench(sample_count = 50)]
fn find_blobs_three_objects(b: Bencher) {
    let f = scene();
    let db = ColourDb::default();
    let cfg = DetectorConfig::default();
    assert_eq!(find_blobs(&f, &db, &cfg).len(), 3);
    b.bench(|| find_blobs(black_box(&f), &db, &cfg));
}

#[divan::bench(sample_count = 50)]
fn find_blobs_garbage_frame(b: Bencher) {
    let mut f = scene();
    let mut s = 99u64;
    for p in &mut f.pixels {
        *p = xorshift(&mut s) as u8;
    }
    let db = ColourDb::default();
    let cfg = DetectorConfig::default();
    b.bench(|| find_blobs(black_box(&f), &db, &cfg));
}

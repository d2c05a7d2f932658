//! What one camera frame costs to make smaller, losslessly: the demo's noisy 320×240 rgb8
//! frames through zstd level 1 (what the recorder's chunks use), PNG at its two fastest
//! settings (`--record-images png` uses `Fast`). The sizes are
//! printed before the timings. Measured for issue 16 (stop 50): no lossless choice here is
//! cheaper than zstd level 1 for a smaller result (LZ4, tried outside this bench, was faster
//! but left the frames at their full size).
//!
//! `cargo bench -p ima-record --bench frames`

use divan::counter::BytesCount;
use ima_hal::camera::Frame;

#[allow(
    dead_code,
    reason = "the shared test data's serial ports are for the other benches"
)]
mod common;
use common::frame;

fn main() {
    let f = frame(7, 1);
    let raw = f.pixels.len();
    let size = |n: usize| format!("{n} bytes ({:.0} %)", n as f64 * 100.0 / raw as f64);
    eprintln!("one frame: {raw} bytes");
    eprintln!("zstd level 1: {}", size(zstd_1(&f).len()));
    eprintln!(
        "PNG fastest:  {}",
        size(png(&f, png::Compression::Fastest).len())
    );
    eprintln!(
        "PNG fast:     {}",
        size(png(&f, png::Compression::Fast).len())
    );
    divan::main();
}

fn zstd_1(f: &Frame) -> Vec<u8> {
    zstd::bulk::compress(&f.pixels, 1).expect("zstd")
}

fn png(f: &Frame, level: png::Compression) -> Vec<u8> {
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, f.width, f.height);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    enc.set_compression(level);
    let mut w = enc.write_header().expect("png header");
    w.write_image_data(&f.pixels).expect("png data");
    drop(w);
    out
}

#[divan::bench]
fn zstd_level_1(b: divan::Bencher) {
    let f = frame(7, 1);
    b.counter(BytesCount::new(f.pixels.len()))
        .bench(|| zstd_1(divan::black_box(&f)));
}

#[divan::bench]
fn png_fastest(b: divan::Bencher) {
    let f = frame(7, 1);
    b.counter(BytesCount::new(f.pixels.len()))
        .bench(|| png(divan::black_box(&f), png::Compression::Fastest));
}

#[divan::bench]
fn png_fast(b: divan::Bencher) {
    let f = frame(7, 1);
    b.counter(BytesCount::new(f.pixels.len()))
        .bench(|| png(divan::black_box(&f), png::Compression::Fast));
}

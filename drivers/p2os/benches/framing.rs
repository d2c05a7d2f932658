//! Framer + parser throughput over a 1 MiB stream of realistic SIPs (0–16 sonar readings each),
//! clean and with 1 % of its bytes corrupted, and proof of zero heap allocations per frame
//! (`divan::AllocProfiler` counts every allocation made inside a measured iteration).
//!
//! Run: `cargo bench -p ima-p2os --bench framing`.
//!
//! divan prints `alloc:`/`dealloc:` rows only for benchmarks that allocate: the framing
//! benchmarks show none (0 allocations per 1 MiB, hence per frame), while
//! `control_allocating` (which copies each payload into a `Vec`) shows 1 allocation per
//! iteration — proof that the profiler is active.

#[path = "../tests/common/mod.rs"]
mod common;

use divan::counter::{BytesCount, ItemsCount};
use divan::{AllocProfiler, Bencher, black_box};
use ima_p2os::wire::{self, Packet};
use ima_p2os::{FrameEvent, Framer};

#[global_allocator]
static ALLOC: AllocProfiler = AllocProfiler::system();

fn main() {
    divan::main();
}

const MIB: usize = 1 << 20;

fn clean_stream() -> Vec<u8> {
    common::sip_stream_bytes(0x51_7A, MIB)
}

fn corrupted_stream() -> Vec<u8> {
    let mut s = clean_stream();
    common::corrupt(&mut s, 0.01, 0xC0_22);
    s
}

/// Frame and parse everything; returns (SIPs parsed, sonar readings) so nothing is optimised
/// away.
fn frame_and_parse(stream: &[u8], read: usize) -> (usize, usize) {
    let mut framer = Framer::new();
    let (mut sips, mut readings) = (0, 0);
    for chunk in stream.chunks(read) {
        framer.push(chunk, |ev| {
            if let FrameEvent::Frame(p) = ev
                && let Ok(Packet::Sip(sip)) = Packet::parse(p)
            {
                sips += 1;
                readings += sip.sonars.len();
            }
        });
    }
    (sips, readings)
}

/// 1 MiB of clean SIPs handed over in one call.
#[divan::bench(sample_count = 30, sample_size = 1)]
fn clean(bencher: Bencher) {
    let stream = clean_stream();
    bencher
        .counter(BytesCount::new(stream.len()))
        .bench_local(|| frame_and_parse(black_box(&stream), usize::MAX));
}

/// 1 MiB of clean SIPs in 64-byte reads (what a serial port hands over).
#[divan::bench(sample_count = 30, sample_size = 1)]
fn clean_64_byte_reads(bencher: Bencher) {
    let stream = clean_stream();
    bencher
        .counter(BytesCount::new(stream.len()))
        .bench_local(|| frame_and_parse(black_box(&stream), 64));
}

/// 1 MiB of SIPs with 1 % of the bytes corrupted.
#[divan::bench(sample_count = 30, sample_size = 1)]
fn corrupted_1_percent(bencher: Bencher) {
    let stream = corrupted_stream();
    bencher
        .counter(BytesCount::new(stream.len()))
        .bench_local(|| frame_and_parse(black_box(&stream), usize::MAX));
}

/// The checksum alone over 1 MiB (one big payload-sized pass).
#[divan::bench(sample_count = 30, sample_size = 1)]
fn checksum_only(bencher: Bencher) {
    let stream = clean_stream();
    bencher
        .counter(BytesCount::new(stream.len()))
        .bench_local(|| wire::checksum(black_box(&stream)));
}

/// One T20 SIP framed and parsed: the allocation column must read 0.
#[divan::bench(sample_count = 30, sample_size = 1000)]
fn one_sip_frame(bencher: Bencher) {
    let t20: [u8; 36] = [
        0xFA, 0xFB, 0x21, 0x33, 0xE8, 0x03, 0xF4, 0x01, 0x00, 0x04, 0xCE, 0xFF, 0x32, 0x00, 0x7D,
        0x00, 0x00, 0x00, 0x04, 0x01, 0x00, 0x00, 0x02, 0x00, 0x4A, 0x07, 0x07, 0x93, 0x0E, 0x00,
        0x00, 0x00, 0xFF, 0x0F, 0xD9, 0xB2,
    ];
    let mut framer = Framer::new();
    bencher.counter(ItemsCount::new(1usize)).bench_local(|| {
        let mut ok = false;
        framer.push(black_box(&t20), |ev| {
            ok = matches!(ev, FrameEvent::Frame(p) if matches!(Packet::parse(p), Ok(Packet::Sip(_))));
        });
        ok
    });
}

/// Control: the same as `one_sip_frame` but copying the payload into a `Vec` — divan must
/// report exactly 1 allocation per iteration here.
#[divan::bench(sample_count = 30, sample_size = 1000)]
fn control_allocating(bencher: Bencher) {
    let mut frame = [0u8; 16];
    let n = wire::encode_frame(&[0x0B, 0x3B, 0xC8, 0x00], &mut frame).unwrap_or(0);
    let frame = &frame[..n];
    let mut framer = Framer::new();
    bencher.counter(ItemsCount::new(1usize)).bench_local(|| {
        let mut copy = Vec::new();
        framer.push(black_box(frame), |ev| {
            if let FrameEvent::Frame(p) = ev {
                copy = p.to_vec();
            }
        });
        copy
    });
}

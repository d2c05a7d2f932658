//! B0 framing and decoding throughput (361 values, 732-byte telegrams), with allocation
//! counting: `cargo bench -p ima-sick-lms --bench b0`.
//!
//! `stream_frame_decode_b0_361` is the headline number (issue 15): framer +
//! `Reply::from_frame` + `decode_scan` over a stream of 64 back-to-back real-format B0
//! telegrams (varied ranges, special codes and flag bits), in bytes of stream per second.
//! divan's allocation profiler prints `alloc`/`dealloc` rows for any benchmark that allocates.

use divan::counter::{BytesCount, ItemsCount};
use divan::{AllocProfiler, Bencher, black_box};
use ima_hal::Instant;
use ima_hal::laser::LaserScan;
use ima_sick_lms::decode::decode_scan;
use ima_sick_lms::framer::{Framer, Item};
use ima_sick_lms::machine::{Config, Machine};
use ima_sick_lms::wire::{MAX_TELEGRAM, MeasuringMode, Reply, Scan, StatusByte, Units, crc16};

#[global_allocator]
static ALLOC: AllocProfiler = AllocProfiler::system();

fn main() {
    divan::main();
}

fn b0_361() -> Vec<u8> {
    let words: Vec<u16> = (0..361u16)
        .map(|i| if i % 9 == 0 { 0x8002 } else { 500 + i * 7 })
        .collect();
    let mut buf = [0u8; MAX_TELEGRAM];
    let n = Reply::Scan(Scan::full(&words, Units::Mm, StatusByte::NORMAL))
        .emit(&mut buf)
        .unwrap();
    assert_eq!(n, 732);
    buf[..n].to_vec()
}

/// Telegrams in the stream of `stream_frame_decode_b0_361`.
const STREAM_TELEGRAMS: usize = 64;

/// A stream of real-format 361-value B0 telegrams (mm, mode 00): ranges 0.2–8 m with about 3 %
/// no-return codes, an occasional dazzled code and flag bit 13, from a fixed LCG seed.
fn b0_stream() -> Vec<u8> {
    let mut seed: u32 = 0x1234_5678;
    let mut next = move || {
        seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        seed >> 8
    };
    let mut out = Vec::with_capacity(STREAM_TELEGRAMS * 732);
    let mut buf = [0u8; MAX_TELEGRAM];
    for _ in 0..STREAM_TELEGRAMS {
        let words: Vec<u16> = (0..361)
            .map(|_| {
                let r = next();
                match r % 100 {
                    0..=2 => 0x1FFF,
                    3 => 0x1FFE,
                    4 => 0x2000 | (200 + (r >> 8) % 7800) as u16,
                    _ => (200 + (r >> 8) % 7800) as u16,
                }
            })
            .collect();
        let n = Reply::Scan(Scan::full(&words, Units::Mm, StatusByte::NORMAL))
            .emit(&mut buf)
            .unwrap();
        assert_eq!(n, 732);
        out.extend_from_slice(&buf[..n]);
    }
    out
}

/// The headline: framer + `Reply::from_frame` + `decode_scan` over a stream of B0 telegrams.
#[divan::bench(sample_count = 200)]
fn stream_frame_decode_b0_361(b: Bencher) {
    let stream = b0_stream();
    let mut f = Framer::replies();
    let mut scan = LaserScan::default();
    b.counter(BytesCount::new(stream.len()))
        .counter(ItemsCount::new(STREAM_TELEGRAMS))
        .bench_local(|| {
            let mut n = 0usize;
            f.push_all(black_box(&stream), Instant::ZERO, |item| {
                if let Item::Frame(fr) = item
                    && let Ok(Reply::Scan(s)) = Reply::from_frame(&fr)
                    && decode_scan(&s, MeasuringMode::DEFAULT, None, &mut scan).is_ok()
                {
                    n += 1;
                }
            });
            assert_eq!(n, STREAM_TELEGRAMS);
            black_box(&scan);
        });
}

/// Control for the allocation evidence: one `Vec` per iteration, so divan prints its
/// `alloc`/`dealloc` rows here (it omits them where the count is zero, as in every bench above
/// and below).
#[divan::bench(sample_count = 50)]
fn alloc_control_one_vec(b: Bencher) {
    b.bench_local(|| black_box(vec![0u8; 732]));
}

/// `decode_scan` alone on one parsed 361-value B0.
#[divan::bench(sample_count = 200)]
fn decode_b0_361(b: Bencher) {
    let t = b0_stream();
    let Ok(Reply::Scan(s)) = Reply::parse(&t[..732]) else {
        panic!("not a B0");
    };
    let mut scan = LaserScan::default();
    b.counter(BytesCount::new(732usize))
        .counter(ItemsCount::new(1usize))
        .bench_local(|| {
            decode_scan(black_box(&s), MeasuringMode::DEFAULT, None, &mut scan).unwrap();
            black_box(&scan);
        });
}

#[divan::bench(sample_count = 200)]
fn crc16_732_bytes(b: Bencher) {
    let t = b0_361();
    b.counter(BytesCount::new(t.len() - 2))
        .bench(|| crc16(black_box(&t[..t.len() - 2])));
}

#[divan::bench(sample_count = 200)]
fn frame_b0_361(b: Bencher) {
    let t = b0_361();
    let mut f = Framer::replies();
    b.counter(BytesCount::new(t.len()))
        .counter(ItemsCount::new(1usize))
        .bench_local(|| {
            let mut n = 0;
            f.push_all(black_box(&t), Instant::ZERO, |item| {
                if let Item::Frame(fr) = item {
                    n += fr.as_bytes().len();
                }
            });
            assert_eq!(n, 732);
        });
}

#[divan::bench(sample_count = 200)]
fn frame_and_decode_b0_361(b: Bencher) {
    let t = b0_361();
    let mut f = Framer::replies();
    let mut scan = LaserScan::default();
    b.counter(BytesCount::new(t.len()))
        .counter(ItemsCount::new(1usize))
        .bench_local(|| {
            f.push_all(black_box(&t), Instant::ZERO, |item| {
                if let Item::Frame(fr) = item
                    && let Ok(Reply::Scan(s)) = Reply::from_frame(&fr)
                {
                    decode_scan(&s, MeasuringMode::DEFAULT, None, &mut scan).unwrap();
                }
            });
            assert_eq!(scan.len(), 361);
        });
}

/// 16 scans per read through the whole session machine (framer, matching, stats) and decode.
#[divan::bench(sample_count = 100)]
fn machine_16_scans_per_read(b: Bencher) {
    let one = b0_361();
    let stream: Vec<u8> = (0..16).flat_map(|_| one.iter().copied()).collect();
    let mut m = Machine::new(Config::default(), Instant::ZERO);
    let mut scan = LaserScan::default();
    b.counter(BytesCount::new(stream.len()))
        .counter(ItemsCount::new(16usize))
        .bench_local(|| {
            let mut n = 0;
            m.handle_bytes_with(black_box(&stream), Instant::ZERO, |s, _| {
                decode_scan(s, MeasuringMode::DEFAULT, None, &mut scan).unwrap();
                n += 1;
            });
            assert_eq!(n, 16);
        });
}

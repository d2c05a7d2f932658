//! B0 framing and decoding throughput (361 values, 732-byte telegrams), with allocation
//! counting: `cargo bench -p ima-sick-lms --bench b0`.

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
            m.handle_bytes(black_box(&stream), Instant::ZERO, |s, _| {
                decode_scan(s, MeasuringMode::DEFAULT, None, &mut scan).unwrap();
                n += 1;
            });
            assert_eq!(n, 16);
        });
}

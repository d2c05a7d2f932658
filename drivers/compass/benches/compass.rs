//! Parse and session throughput; `AllocProfiler` shows the paths allocate nothing.
//! Run: `cargo bench -p ima-compass`.

use divan::counter::BytesCount;
use divan::{AllocProfiler, Bencher, black_box};
use ima_compass::machine::{Config, Dialect, Machine};
use ima_compass::wire::{Line, ParseOptions};
use ima_hal::Instant;

#[global_allocator]
static ALLOC: AllocProfiler = AllocProfiler::system();

const HDG: &[u8] = b"$HCHDG,238.5,0.0,E,12.3,W*6C\r\n";

fn main() {
    divan::main();
}

#[divan::bench]
fn parse_hdg(b: Bencher) {
    let o = ParseOptions::default();
    b.counter(BytesCount::of_slice(HDG))
        .bench(|| Line::parse(black_box(HDG), &o));
}

#[divan::bench]
fn parse_tcm2(b: Bencher) {
    let line = b"$C328.3P28.4R-12.4X55.11Y12.33Z-18.43T22.3E001*29\r\n";
    let o = ParseOptions::default();
    assert!(Line::parse(line, &o).is_ok());
    b.counter(BytesCount::of_slice(line))
        .bench(|| Line::parse(black_box(line), &o));
}

/// 100 HDG lines through framer, parser and session, heading events drained.
#[divan::bench(sample_count = 200)]
fn session_100_lines(b: Bencher) {
    let stream: Vec<u8> = HDG.repeat(100);
    b.counter(BytesCount::of_slice(&stream))
        .with_inputs(|| Machine::new(Config::for_dialect(Dialect::Nmea)))
        .bench_local_refs(|m| {
            m.handle_bytes(black_box(&stream), Instant::from_millis(1));
            let mut n = 0u32;
            while m.poll_event().is_some() {
                n += 1;
            }
            n
        });
}

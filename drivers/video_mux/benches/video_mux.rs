//! Reply parsing and a select round trip; `AllocProfiler` shows nothing allocates.
//! Run: `cargo bench -p ima-video-mux`.

use divan::counter::BytesCount;
use divan::{AllocProfiler, Bencher, black_box};
use ima_hal::Instant;
use ima_video_mux::machine::{Config, Machine};
use ima_video_mux::wire::{ExtronReply, KramerMessage};

#[global_allocator]
static ALLOC: AllocProfiler = AllocProfiler::system();

fn main() {
    divan::main();
}

#[divan::bench]
fn parse_extron_reply(b: Bencher) {
    let line = b"In003 All\r\n";
    b.counter(BytesCount::of_slice(line))
        .bench(|| ExtronReply::parse(black_box(line)));
}

#[divan::bench]
fn parse_kramer(b: Bencher) {
    let msg = [0x41u8, 0x83, 0x81, 0x81];
    b.bench(|| KramerMessage::parse(black_box(&msg)));
}

/// select → transmit → reply → event, on a fresh session each time.
#[divan::bench(sample_count = 200)]
fn select_round_trip(b: Bencher) {
    b.with_inputs(|| Machine::new(Config::default()))
        .bench_local_refs(|m| {
            let mut buf = [0u8; 16];
            let _ = m.select(3, Instant::from_millis(0));
            let n = m.poll_transmit(&mut buf);
            m.handle_bytes(b"In3 All\r\n", Instant::from_millis(20));
            (n, m.poll_event())
        });
}

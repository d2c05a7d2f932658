//! Decoding throughput of base → host report streams, clean and with 1 % of the bytes
//! corrupted, through the framer + `Report::from_raw`, and through the whole host machine.
//! `divan::AllocProfiler` shows the allocations per iteration (expected: none).
//!
//! Run: `cargo bench -p ima-rflex --bench decode`

use divan::Bencher;
use divan::counter::BytesCount;
use ima_hal::Instant;
use ima_rflex::framer::Framer;
use ima_rflex::machine::{Config, Machine};
use ima_rflex::wire::{
    DioReport, MAX_WIRE_FRAME, MotionReport, Report, SonarEcho, SonarReport, Stuffing,
};

#[global_allocator]
static ALLOC: divan::AllocProfiler = divan::AllocProfiler::system();

fn main() {
    divan::main();
}

/// About 64 KiB of a realistic report mix: per 100 ms, two motion reports, a sonar report of
/// 6 echoes; a status and a bumper report now and then. Values sweep through 0x1B and 0x7C.
fn stream() -> Vec<u8> {
    let mut out = Vec::new();
    let mut buf = [0u8; MAX_WIRE_FRAME];
    let mut id: u8 = 0;
    let mut k: i32 = 0;
    while out.len() < 64 * 1024 {
        let mut reports = vec![
            Report::Motion(MotionReport {
                rv: 0,
                ts: k as u32 * 25,
                axis: 0,
                position: k * 2_723,
                velocity: 27_243,
                acceleration: 0,
                torque: 1_000,
            }),
            Report::Motion(MotionReport {
                rv: 0,
                ts: k as u32 * 25,
                axis: 1,
                position: k * 0x1B7C,
                velocity: -3_700,
                acceleration: 0,
                torque: 500,
            }),
        ];
        let mut echoes = heapless::Vec::new();
        for j in 0..6u8 {
            let _ = echoes.push(SonarEcho {
                id: j,
                range: (k as u16).wrapping_mul(7).wrapping_add(u16::from(j) * 300),
            });
        }
        reports.push(Report::Sonar(SonarReport {
            rv: 0,
            ts: k as u32,
            echoes,
        }));
        if k % 10 == 0 {
            reports.push(Report::SysStatus {
                ts: k as u32,
                voltage_raw: 2630,
                brake_engaged: false,
            });
        }
        if k % 17 == 0 {
            reports.push(Report::Dio(DioReport {
                ts: k as u32,
                address: 0x40,
                data: (k as u16 / 17) & 3,
            }));
        }
        for r in &reports {
            let n = r.emit_with(id, Stuffing::Full, &mut buf).unwrap();
            out.extend_from_slice(&buf[..n]);
            id = id.wrapping_add(1);
        }
        k += 1;
    }
    out
}

/// The same stream with about 1 % of its bytes replaced (seeded xorshift).
fn corrupted() -> Vec<u8> {
    let mut s = stream();
    let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
    for b in s.iter_mut() {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        if x.is_multiple_of(100) {
            *b = (x >> 32) as u8;
        }
    }
    s
}

fn decode_all(f: &mut Framer, bytes: &[u8]) -> usize {
    let mut good = 0usize;
    f.push(bytes, |item| {
        if let Ok(raw) = item
            && Report::from_raw(&raw).is_ok()
        {
            good += 1;
        }
    });
    good
}

#[divan::bench(name = "framer+parse clean", sample_count = 40)]
fn clean(b: Bencher) {
    let s = stream();
    b.counter(BytesCount::new(s.len())).bench_local(|| {
        let mut f = Framer::strict();
        divan::black_box(decode_all(&mut f, divan::black_box(&s)))
    });
}

#[divan::bench(name = "framer+parse 1% corrupt", sample_count = 40)]
fn corrupt(b: Bencher) {
    let s = corrupted();
    b.counter(BytesCount::new(s.len())).bench_local(|| {
        let mut f = Framer::strict();
        divan::black_box(decode_all(&mut f, divan::black_box(&s)))
    });
}

#[divan::bench(name = "machine clean (odometry, sonar, events)", sample_count = 40)]
fn machine(b: Bencher) {
    let s = stream();
    b.counter(BytesCount::new(s.len())).bench_local(|| {
        let mut m = Machine::new(Config::default(), Instant::ZERO);
        let mut t = 0u64;
        let mut events = 0usize;
        for chunk in s.chunks(64) {
            t += 5;
            m.handle_bytes(chunk, Instant::from_millis(t));
            while m.poll_event().is_some() {
                events += 1;
            }
        }
        divan::black_box(events)
    });
}

/// One 34-byte motion report per iteration: the allocation count per frame.
#[divan::bench(name = "one motion report", sample_count = 40)]
fn one_frame(b: Bencher) {
    let s = stream();
    let n = s
        .windows(2)
        .skip(1)
        .position(|w| w == [0x1B, 0x02])
        .unwrap()
        + 1;
    let frame = s[..n].to_vec();
    b.counter(BytesCount::new(frame.len())).bench_local(|| {
        let mut f = Framer::strict();
        divan::black_box(decode_all(&mut f, divan::black_box(&frame)))
    });
}

//! The blocking shell's steady state: one `next_scan` (read, frame, decode, swap) per
//! iteration over a fake unit that streams canned 361-value B0 telegrams from a preallocated
//! buffer. `divan::AllocProfiler` shows the allocations per scan (expected: none):
//! `cargo bench -p ima-sick-lms --features serial --bench shell`.

use std::io::{self, Read, Write};
use std::time::Duration;

use divan::counter::ItemsCount;
use divan::{AllocProfiler, Bencher};
use ima_sick_lms::blocking::{BaudControl, BlockingSickLms};
use ima_sick_lms::machine::Config;
use ima_sick_lms::wire::{
    ACK, BaudRate, Command, LmsConfig, MAX_TELEGRAM, ModeRequest, Reply, Scan, StatusBlock,
    StatusBlockBuf, StatusByte, Units,
};

#[global_allocator]
static ALLOC: AllocProfiler = AllocProfiler::system();

fn main() {
    divan::main();
}

/// Answers the init sequence; once streaming, every read returns one whole B0.
struct FakeLms {
    pending: Vec<u8>,
    b0: Vec<u8>,
    streaming: bool,
}

impl FakeLms {
    fn new() -> Self {
        let words: Vec<u16> = (0..361u16).map(|i| 1000 + i).collect();
        let mut b0 = vec![0u8; MAX_TELEGRAM];
        let n = Reply::Scan(Scan::full(&words, Units::Mm, StatusByte::NORMAL))
            .emit(&mut b0)
            .unwrap();
        b0.truncate(n);
        Self {
            pending: Vec::with_capacity(4096),
            b0,
            streaming: false,
        }
    }

    fn reply(&mut self, r: &Reply<'_>) {
        let mut buf = [0u8; MAX_TELEGRAM];
        let n = r.emit(&mut buf).unwrap();
        self.pending.push(ACK);
        self.pending.extend_from_slice(&buf[..n]);
    }
}

impl Write for FakeLms {
    fn write(&mut self, b: &[u8]) -> io::Result<usize> {
        let status = StatusByte::NORMAL;
        match Command::parse(b).unwrap() {
            Command::SetMode(m) => {
                self.streaming = m == ModeRequest::StreamAll;
                self.reply(&Reply::ModeChanged { result: 0, status });
            }
            Command::Type => self.reply(&Reply::Type {
                text: b"LMS200;30106",
                status,
            }),
            Command::Status => {
                let mut s = StatusBlockBuf::default();
                s.set_variant(180, 50);
                s.set_baud(BaudRate::B9600);
                s.set_units(1);
                self.reply(&Reply::Status {
                    block: StatusBlock(&s.0),
                    status,
                });
            }
            Command::ReadConfig => {
                let mut config = LmsConfig::zeroed(true);
                config.set_units(1);
                self.reply(&Reply::Config { config, status });
            }
            other => panic!("unexpected {other:?}"),
        }
        Ok(b.len())
    }
    fn flush(&mut self) -> io::Result<()> {
        Ok(())
    }
}

impl Read for FakeLms {
    fn read(&mut self, out: &mut [u8]) -> io::Result<usize> {
        if !self.pending.is_empty() {
            let n = self.pending.len().min(out.len());
            out[..n].copy_from_slice(&self.pending[..n]);
            self.pending.drain(..n);
            return Ok(n);
        }
        if self.streaming {
            // Steady state: the same B0 again, from the preallocated buffer (two reads).
            let n = self.b0.len().min(out.len());
            out[..n].copy_from_slice(&self.b0[..n]);
            self.pending.extend_from_slice(&self.b0[n..]);
            return Ok(n);
        }
        Err(io::ErrorKind::TimedOut.into())
    }
}

impl BaudControl for FakeLms {
    fn set_baud(&mut self, _baud: u32) -> io::Result<()> {
        Ok(())
    }
}

#[divan::bench(sample_count = 50, sample_size = 20)]
fn next_scan_361(b: Bencher) {
    let cfg = Config {
        baud: BaudRate::B9600,
        ..Config::default()
    };
    let mut lms = BlockingSickLms::connect(
        FakeLms::new(),
        cfg,
        Duration::from_secs(5),
        ima_hal::time::MonotonicClock::shared(),
    )
    .unwrap();
    for _ in 0..5 {
        lms.next_scan(Duration::from_secs(1)).unwrap();
    }
    b.counter(ItemsCount::new(1usize)).bench_local(|| {
        let s = lms.next_scan(Duration::from_secs(1)).unwrap();
        divan::black_box(s.value.ranges_m().first().copied())
    });
}

//! The driver's steady state through the blocking runner: one `next_scan` (read, frame,
//! decode, swap in the task; wake, wait and copy out in the handle) per iteration, over a
//! fake unit that sends one canned 361-value B0 telegram (from a preallocated buffer) each
//! time the iteration asks for one, as a real unit sends one scan per 13 ms: the figure is
//! the cost of one scan, end to end. `divan::AllocProfiler` shows the allocations per scan:
//! `cargo bench -p ima-sick-lms --features serial --bench shell`.

use std::io;
use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll, Waker};
use std::time::Duration;

use divan::counter::ItemsCount;
use divan::{AllocProfiler, Bencher};
use ima_hal::blocking::LaserScanner as _;
use ima_serial::blocking::Blocking;
use ima_sick_lms::machine::Config;
use ima_sick_lms::shell::Driver as _;
use ima_sick_lms::shell::{BaudControl, SickLms};
use ima_sick_lms::wire::{
    ACK, BaudRate, Command, LmsConfig, MAX_TELEGRAM, ModeRequest, Reply, Scan, StatusBlock,
    StatusBlockBuf, StatusByte, Units,
};
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};

#[global_allocator]
static ALLOC: AllocProfiler = AllocProfiler::system();

fn main() {
    divan::main();
}

/// The bench's side of the fake: B0s the unit may send, and the driver task's waker.
#[derive(Default)]
struct Tap {
    scans: usize,
    waker: Option<Waker>,
}

/// Let the fake send one more B0 (and wake the driver task if it waits for bytes).
fn send_one(tap: &Mutex<Tap>) {
    let mut t = tap.lock().unwrap();
    t.scans += 1;
    if let Some(w) = t.waker.take() {
        w.wake();
    }
}

/// Answers the init sequence; once streaming, a read returns one whole B0 for every
/// [`send_one`].
struct FakeLms {
    pending: Vec<u8>,
    b0: Vec<u8>,
    streaming: bool,
    tap: Arc<Mutex<Tap>>,
}

impl FakeLms {
    fn new(tap: Arc<Mutex<Tap>>) -> Self {
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
            tap,
        }
    }

    fn reply(&mut self, r: &Reply<'_>) {
        let mut buf = [0u8; MAX_TELEGRAM];
        let n = r.emit(&mut buf).unwrap();
        self.pending.push(ACK);
        self.pending.extend_from_slice(&buf[..n]);
    }
}

impl FakeLms {
    fn write(&mut self, b: &[u8]) -> usize {
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
        b.len()
    }
}

impl AsyncWrite for FakeLms {
    fn poll_write(self: Pin<&mut Self>, _: &mut Context<'_>, b: &[u8]) -> Poll<io::Result<usize>> {
        Poll::Ready(Ok(self.get_mut().write(b)))
    }
    fn poll_flush(self: Pin<&mut Self>, _: &mut Context<'_>) -> Poll<io::Result<()>> {
        Poll::Ready(Ok(()))
    }
    fn poll_shutdown(self: Pin<&mut Self>, _: &mut Context<'_>) -> Poll<io::Result<()>> {
        Poll::Ready(Ok(()))
    }
}

impl AsyncRead for FakeLms {
    /// Replies first; once streaming, the same B0 again from the preallocated buffer, once
    /// per [`send_one`]; else nothing (the runner's timers run meanwhile).
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        out: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        let me = self.get_mut();
        if me.pending.is_empty() && me.streaming {
            let mut t = me.tap.lock().unwrap();
            if t.scans == 0 {
                // Store the waker only when it changed: no allocation per scan.
                match &mut t.waker {
                    Some(w) if w.will_wake(cx.waker()) => {}
                    w => *w = Some(cx.waker().clone()),
                }
                return Poll::Pending;
            }
            t.scans -= 1;
        }
        let src = if me.pending.is_empty() && me.streaming {
            &me.b0
        } else {
            &me.pending
        };
        if src.is_empty() {
            return Poll::Pending;
        }
        let n = src.len().min(out.remaining());
        out.put_slice(&src[..n]);
        if me.pending.is_empty() {
            me.pending.extend_from_slice(&me.b0[n..]);
        } else {
            me.pending.drain(..n);
        }
        Poll::Ready(Ok(()))
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
    let tap = Arc::new(Mutex::new(Tap::default()));
    let fake = FakeLms::new(Arc::clone(&tap));
    let mut lms = Blocking::connect(async || {
        let clock = ima_hal::time::TokioClock::shared();
        SickLms::connect(fake, cfg, Duration::from_secs(5), clock).await
    })
    .unwrap();
    send_one(&tap);
    let mut last = lms.next_scan(ima_hal::Instant::ZERO).unwrap().at;
    for _ in 0..5 {
        send_one(&tap);
        last = lms.next_scan(last).unwrap().at;
    }
    let before = lms.get().stats().delivered;
    let mut calls = 0u64;
    b.counter(ItemsCount::new(1usize)).bench_local(|| {
        calls += 1;
        send_one(&tap);
        let s = lms.next_scan(last).unwrap();
        last = s.at;
        divan::black_box(s.value.ranges_m().first().copied())
    });
    // One scan decoded per call: the figure is per scan.
    assert_eq!(lms.get().stats().delivered - before, calls);
}

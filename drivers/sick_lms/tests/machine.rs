//! The session machine against a small simulated LMS, in virtual time.
//!
//! The simulated device follows the robot-side rules of the spec (ACK then reply, `A0` of a
//! baud change sent at the old rate, B0 stream in mode `24`, `77` only in installation mode),
//! and a line model: bytes sent at one rate and read at another arrive as garbage.

use std::collections::VecDeque;
use std::time::Duration;

use ima_hal::Instant;
use ima_sick_lms::decode::Variant;
use ima_sick_lms::framer::{Framer, Item};
use ima_sick_lms::machine::{Config, Event, Machine, MachineError, wire_time};
use ima_sick_lms::wire::*;

const TYPE: &[u8] = b"LMS200;30106";

struct Sim {
    baud: BaudRate,
    host_bps: u32,
    framer: Framer,
    variant: (u16, u16),
    cfg: LmsConfig,
    installation: bool,
    streaming: bool,
    status_byte: u8,
    queue: VecDeque<(Instant, Vec<u8>, BaudRate)>,
    next_scan: Option<Instant>,
    telegram_index: u8,
    // faults
    mute_until: Instant,
    power_on_at: Option<Instant>,
    nak_next: u32,
    silent_after_ack: Vec<u8>,
    reject_variant: bool,
    f7_result: u8,
    // record
    log: Vec<(Instant, Command)>,
    writes: u32,
    garbage_in: usize,
}

impl Sim {
    fn new(baud: BaudRate) -> Self {
        let mut cfg = LmsConfig::zeroed(true);
        cfg.set_units(1);
        Self {
            baud,
            host_bps: 9600,
            framer: Framer::commands()
                .with_partial_timeout(Duration::from_millis(6))
                .report_bad_checksums(true),
            variant: (180, 50),
            cfg,
            installation: false,
            streaming: false,
            status_byte: 0x10,
            queue: VecDeque::new(),
            next_scan: None,
            telegram_index: 0,
            mute_until: Instant::ZERO,
            power_on_at: None,
            nak_next: 0,
            silent_after_ack: Vec::new(),
            reject_variant: false,
            f7_result: 1,
            log: Vec::new(),
            writes: 0,
            garbage_in: 0,
        }
    }

    fn send(&mut self, at: Instant, bytes: Vec<u8>) {
        let rate = self.baud;
        self.queue.push_back((at, bytes, rate));
        self.queue.make_contiguous().sort_by_key(|x| x.0);
    }

    fn reply(&mut self, at: Instant, r: &Reply<'_>) {
        let mut buf = [0u8; MAX_TELEGRAM];
        let n = r.emit(&mut buf).unwrap();
        self.send(at, buf[..n].to_vec());
    }

    fn status(&self) -> StatusByte {
        StatusByte(self.status_byte)
    }

    fn scan_bytes(&mut self) -> Vec<u8> {
        let v = Variant::new(self.variant.0, self.variant.1).unwrap();
        let n = v.values() as usize;
        // Include 02 80 (0x8002) in the data, as real range data may.
        let words: Vec<u16> = (0..n)
            .map(|i| if i % 9 == 0 { 0x8002 } else { 1000 + i as u16 })
            .collect();
        let units = if self.cfg.units() == 1 {
            Units::Mm
        } else {
            Units::Cm
        };
        let mut s = Scan::full(&words, units, self.status());
        if self.cfg.availability() & 0x02 != 0 {
            s.indices = Some((0, self.telegram_index));
            self.telegram_index = self.telegram_index.wrapping_add(1);
        }
        let mut buf = [0u8; MAX_TELEGRAM];
        let n = Reply::Scan(s).emit(&mut buf).unwrap();
        buf[..n].to_vec()
    }

    fn rx(&mut self, bytes: &[u8], now: Instant) {
        if now < self.mute_until {
            return;
        }
        if self.host_bps != self.baud.bps() {
            self.garbage_in += bytes.len();
            return;
        }
        let mut cmds = Vec::new();
        let mut naks = 0;
        self.framer.push_all(bytes, now, |item| match item {
            Item::Frame(f) => cmds.push(Command::from_frame(&f).unwrap()),
            Item::BadChecksum => naks += 1,
            _ => {}
        });
        for _ in 0..naks {
            self.send(now + Duration::from_millis(2), vec![NAK]);
        }
        for c in cmds {
            self.handle(c, now);
        }
    }

    fn handle(&mut self, c: Command, now: Instant) {
        self.log.push((now, c.clone()));
        let ms = |m| now + Duration::from_millis(m);
        if self.streaming {
            // A scan already on its way keeps coming while the command is handled.
            let b = self.scan_bytes();
            self.send(ms(1), b);
        }
        if self.nak_next > 0 {
            self.nak_next -= 1;
            self.send(ms(2), vec![NAK]);
            return;
        }
        self.send(ms(2), vec![ACK]);
        if let Some(pos) = self.silent_after_ack.iter().position(|&x| x == c.code()) {
            self.silent_after_ack.remove(pos);
            // A lost baud-change reply still switches the unit.
            if let Command::SetMode(ModeRequest::Baud(b)) = c {
                self.baud = b;
            }
            return;
        }
        let s = self.status();
        let a0 = |result| Reply::ModeChanged { result, status: s };
        match c {
            Command::SetMode(m) => {
                let result = match m {
                    ModeRequest::RequestOnly => {
                        self.streaming = false;
                        self.next_scan = None;
                        self.installation = false;
                        0
                    }
                    ModeRequest::StreamAll => {
                        self.streaming = true;
                        self.next_scan = Some(ms(15));
                        0
                    }
                    ModeRequest::Installation { password } => {
                        if password == DEFAULT_PASSWORD {
                            self.installation = true;
                            0
                        } else {
                            1
                        }
                    }
                    _ => 0,
                };
                self.reply(ms(10), &a0(result));
                if let ModeRequest::Baud(b) = m {
                    // A0 goes at the old rate; the unit switches after it.
                    self.baud = b;
                }
            }
            Command::Type => self.reply(
                ms(10),
                &Reply::Type {
                    text: TYPE,
                    status: s,
                },
            ),
            Command::Status => {
                let mut b = StatusBlockBuf::default();
                b.set_variant(self.variant.0, self.variant.1);
                b.set_baud(self.baud);
                b.set_measuring_mode(self.cfg.measuring_mode());
                let r = Reply::Status {
                    block: b.view(),
                    status: s,
                };
                self.reply(ms(10), &r);
            }
            Command::Variant {
                angle_deg,
                res_centideg,
            } => {
                if self.reject_variant {
                    self.reply(
                        ms(10),
                        &Reply::Rejected {
                            data: &[],
                            status: s,
                        },
                    );
                    return;
                }
                let ok = Variant::new(angle_deg, res_centideg).is_some() && !self.streaming;
                if ok {
                    self.variant = (angle_deg, res_centideg);
                }
                let r = Reply::Variant {
                    accepted: ok as u8,
                    angle_deg: self.variant.0,
                    res_centideg: self.variant.1,
                    status: s,
                };
                self.reply(ms(10), &r);
            }
            Command::ReadConfig => {
                let r = Reply::Config {
                    config: self.cfg,
                    status: s,
                };
                self.reply(ms(10), &r);
            }
            Command::WriteConfig(cfg) => {
                if !self.installation {
                    self.reply(
                        ms(10),
                        &Reply::Rejected {
                            data: &[],
                            status: s,
                        },
                    );
                    return;
                }
                self.cfg = cfg;
                self.writes += 1;
                let r = Reply::ConfigWritten {
                    result: self.f7_result,
                    config: cfg,
                    status: s,
                };
                self.reply(ms(2000), &r);
            }
            Command::RequestValues { .. } => {
                let b = self.scan_bytes();
                self.send(ms(10), b);
            }
            Command::Errors => self.reply(
                ms(10),
                &Reply::Errors {
                    pairs: ErrorPairs::new(&[]).unwrap(),
                    status: s,
                },
            ),
            Command::Reset => {
                self.reply(ms(10), &Reply::ResetAck { status: s });
                // Reboot: back to 9600, idle, busy until the power-on telegram.
                self.baud = BaudRate::B9600;
                self.streaming = false;
                self.next_scan = None;
                self.installation = false;
                self.mute_until = ms(3000);
                self.power_on_at = Some(ms(3000));
            }
        }
    }

    fn next_time(&self) -> Option<Instant> {
        [
            self.queue.front().map(|x| x.0),
            self.next_scan,
            self.power_on_at,
        ]
        .into_iter()
        .flatten()
        .min()
    }

    /// Output due at `now`.
    fn due(&mut self, now: Instant) -> Vec<(Vec<u8>, BaudRate)> {
        if let Some(t) = self.power_on_at
            && t <= now
        {
            self.power_on_at = None;
            let r = Reply::PowerOn {
                text: b"LMS200;301063;V02.06 ",
                status: StatusByte(0x13),
            };
            self.reply(now, &r);
        }
        if let Some(t) = self.next_scan
            && t <= now
        {
            let b = self.scan_bytes();
            self.send(now, b);
            // 37.5 scans/s at 0.5°; the line may be slower, but the model keeps it simple.
            self.next_scan = Some(t + Duration::from_micros(26_667));
        }
        let mut out = Vec::new();
        while self.queue.front().is_some_and(|x| x.0 <= now) {
            let (_, b, r) = self.queue.pop_front().unwrap();
            out.push((b, r));
        }
        out
    }
}

struct World {
    m: Machine,
    d: Sim,
    now: Instant,
    events: Vec<(Instant, Event)>,
    sent: Vec<(Instant, Vec<u8>)>,
    scans: Vec<(Instant, u16)>,
    host_bps: u32,
    /// Deliver device output in reads of this many bytes.
    chunk: usize,
    /// Corrupt the CRC of this many next host telegrams on the line.
    corrupt_tx: u32,
}

impl World {
    fn new(cfg: Config, d: Sim) -> Self {
        Self {
            m: Machine::new(cfg, Instant::ZERO),
            d,
            now: Instant::ZERO,
            events: Vec::new(),
            sent: Vec::new(),
            scans: Vec::new(),
            host_bps: 9600,
            chunk: usize::MAX,
            corrupt_tx: 0,
        }
    }

    fn pump(&mut self) {
        while let Some(e) = self.m.poll_event() {
            if let Event::SetHostBaud(b) = e {
                self.host_bps = b;
                self.d.host_bps = b;
            }
            self.events.push((self.now, e));
        }
        let mut buf = [0u8; 64];
        while let Some(n) = self.m.poll_transmit(&mut buf) {
            self.sent.push((self.now, buf[..n].to_vec()));
            if self.corrupt_tx > 0 {
                self.corrupt_tx -= 1;
                buf[n - 1] ^= 0x5A;
            }
            self.d.rx(&buf[..n], self.now);
        }
    }

    /// Run until `stop` holds or `limit` of virtual time passes. Returns whether `stop` held.
    fn run(&mut self, limit: Duration, stop: impl Fn(&World) -> bool) -> bool {
        let end = self.now + limit;
        for _ in 0..1_000_000 {
            self.pump();
            if stop(self) {
                return true;
            }
            let t = [self.m.poll_timeout(), self.d.next_time()]
                .into_iter()
                .flatten()
                .min();
            let Some(t) = t else { return false };
            if t > end {
                self.now = end;
                return false;
            }
            self.now = self.now.max(t);
            let now = self.now;
            for (bytes, rate) in self.d.due(now) {
                if rate.bps() == self.host_bps {
                    let scans = &mut self.scans;
                    for c in bytes.chunks(self.chunk) {
                        self.m.handle_bytes_with(c, now, |s, at| {
                            scans.push((at, s.count_word.count()))
                        });
                    }
                } else {
                    // Read at the wrong rate: garbage (never STX/ACK/NAK here).
                    let junk = vec![0xE0; bytes.len() / 3 + 1];
                    self.m.handle_bytes_with(&junk, now, |_, _| {});
                }
            }
            if self.m.poll_timeout().is_some_and(|t| t <= now) {
                self.m.handle_timeout(now);
            }
        }
        panic!("no progress");
    }

    fn run_ready(&mut self) -> bool {
        self.run(Duration::from_secs(120), |w| {
            w.m.is_failed() || w.events.iter().any(|(_, e)| matches!(e, Event::Ready(_)))
        })
    }

    fn codes(&self) -> Vec<Command> {
        self.d.log.iter().map(|(_, c)| c.clone()).collect()
    }

    fn has(&self, f: impl Fn(&Event) -> bool) -> bool {
        self.events.iter().any(|(_, e)| f(e))
    }
}

fn mode(m: ModeRequest) -> Command {
    Command::SetMode(m)
}

fn cfg_38400() -> Config {
    Config {
        baud: BaudRate::B38400,
        rs422: true,
        ..Config::default()
    }
}

#[test]
fn init_from_every_starting_baud() {
    for start in BaudRate::PROBE_ORDER {
        let mut w = World::new(cfg_38400(), Sim::new(start));
        assert!(w.run_ready(), "{start:?}");
        assert!(!w.m.is_failed());
        assert!(w.has(|e| *e == Event::BaudDetected(start)), "{start:?}");
        assert_eq!(w.d.baud, BaudRate::B38400);
        assert_eq!(w.host_bps, 38400);
        assert_eq!(w.m.host_baud(), BaudRate::B38400);
        assert!(w.m.is_streaming() && w.d.streaming);
        assert_eq!(w.m.device_type(), Some(TYPE));
        // Scans flow and are decodable with the session's parameters.
        let t = w.now;
        w.run(Duration::from_millis(300), |_| false);
        let n = w.scans.iter().filter(|(at, _)| *at > t).count();
        assert!(n >= 5, "{start:?}: {n} scans");
        assert!(w.scans.iter().all(|(_, c)| *c == 361));
        assert_eq!(w.m.counters().bad_checksums, 0);
        // Only typed, known commands were ever sent; the permanent-baud command (0x66) cannot
        // even be expressed by `Command`.
        assert_eq!(w.d.framer.counters().bad_headers, 0);
        let baud_changes = w
            .codes()
            .iter()
            .filter(|c| matches!(c, Command::SetMode(ModeRequest::Baud(_))))
            .count();
        assert_eq!(baud_changes, usize::from(start != BaudRate::B38400));
    }
}

#[test]
fn probe_without_rs422_skips_500000() {
    let cfg = Config {
        rs422: false,
        probe_rounds: 1,
        ..Config::default()
    };
    let mut w = World::new(cfg, Sim::new(BaudRate::B500000));
    w.run_ready();
    assert!(w.m.is_failed());
    assert!(w.has(|e| *e == Event::Error(MachineError::NoDevice)));
    assert!(!w.has(|e| *e == Event::SetHostBaud(500_000)));
}

#[test]
fn switch_to_500000_with_settle_and_verify() {
    let cfg = Config {
        baud: BaudRate::B500000,
        rs422: true,
        ..Config::default()
    };
    let mut w = World::new(cfg, Sim::new(BaudRate::B9600));
    assert!(w.run_ready());
    assert_eq!(w.d.baud, BaudRate::B500000);
    assert_eq!(w.host_bps, 500_000);
    let switched_at = w
        .events
        .iter()
        .find(|(_, e)| *e == Event::SetHostBaud(500_000))
        .unwrap()
        .0;
    // The 20 48 was answered at 9600 before the switch, the next telegram (31, verify) comes
    // only after the 250 ms settle.
    let (t_next, next) = w.sent.iter().find(|(t, _)| *t >= switched_at).unwrap();
    assert!(*t_next >= switched_at + Duration::from_millis(250));
    assert_eq!(Command::parse(next).unwrap(), Command::Status);
    let log = w.codes();
    let i = log
        .iter()
        .position(|c| *c == mode(ModeRequest::Baud(BaudRate::B500000)))
        .unwrap();
    assert_eq!(log[i + 1], Command::Status, "verify right after the change");
    // After 500k, a 361-value stream.
    w.run(Duration::from_millis(200), |_| false);
    assert!(w.scans.len() >= 3);
}

#[test]
fn baud_500000_refused_without_rs422() {
    let cfg = Config {
        baud: BaudRate::B500000,
        rs422: false,
        ..Config::default()
    };
    let mut w = World::new(cfg, Sim::new(BaudRate::B9600));
    w.run_ready();
    assert!(w.m.is_failed());
    assert!(
        !w.codes()
            .iter()
            .any(|c| matches!(c, Command::SetMode(ModeRequest::Baud(_))))
    );
}

#[test]
fn lost_baud_change_reply_is_not_retried_blindly() {
    let mut d = Sim::new(BaudRate::B9600);
    d.silent_after_ack = vec![cmd::SET_MODE]; // the first 20 25 of the probe… see below
    // Make the first 20 25 answer normally: drop only the reply of the baud change.
    d.silent_after_ack.clear();
    let mut w = World::new(cfg_38400(), d);
    // Arm the fault just before the baud change: run until identified.
    assert!(w.run(Duration::from_secs(10), |w| {
        w.has(|e| *e == Event::Identified)
    }));
    w.d.silent_after_ack = vec![cmd::SET_MODE];
    // Status is next, then 20 40 whose A0 is lost although the unit switches.
    assert!(w.run_ready());
    assert!(!w.m.is_failed());
    let changes = w
        .codes()
        .iter()
        .filter(|c| **c == mode(ModeRequest::Baud(BaudRate::B38400)))
        .count();
    assert_eq!(changes, 1, "never resent: re-probed instead");
    assert!(w.has(|e| matches!(e, Event::Error(MachineError::Timeout { code: 0x20 }))));
    assert!(w.has(|e| *e == Event::BaudDetected(BaudRate::B38400)));
    assert_eq!(w.host_bps, 38400);
}

fn variant_cycle(from: (u16, u16), to: Variant) {
    let cfg = Config {
        variant: Some(to),
        ..cfg_38400()
    };
    let mut d = Sim::new(BaudRate::B38400);
    d.variant = from;
    let mut w = World::new(cfg, d);
    assert!(w.run_ready());
    assert_eq!(w.d.variant, (to.angle_deg(), to.res_centideg()));
    let sent_3b = w
        .codes()
        .iter()
        .filter(|c| matches!(c, Command::Variant { .. }))
        .count();
    let same = from == (to.angle_deg(), to.res_centideg());
    assert_eq!(sent_3b, usize::from(!same), "{from:?} -> {to:?}");
    assert_eq!(w.m.session().variant, Some(to));
    w.run(Duration::from_millis(200), |_| false);
    assert!(w.scans.iter().all(|(_, n)| *n == to.values()));
    assert!(!w.scans.is_empty());
}

#[test]
fn init_variant_changes() {
    let all = [Variant::W180_R50, Variant::W180_R100, Variant::W100_R25];
    for from in all {
        for to in all {
            variant_cycle((from.angle_deg(), from.res_centideg()), to);
        }
    }
}

#[test]
fn runtime_variant_changes_stop_and_restart_stream() {
    let mut w = World::new(cfg_38400(), Sim::new(BaudRate::B38400));
    assert!(w.run_ready());
    for v in [
        Variant::W180_R100,
        Variant::W100_R25,
        Variant::W180_R50,
        Variant::W100_R25,
    ] {
        w.events.clear();
        w.d.log.clear();
        let now = w.now;
        w.m.set_variant(v, now).unwrap();
        assert_eq!(w.m.set_variant(v, now), Err(MachineError::Busy));
        assert!(w.run_ready());
        let log = w.codes();
        assert_eq!(
            log[0],
            mode(ModeRequest::RequestOnly),
            "stream stopped first"
        );
        let i3b = log
            .iter()
            .position(|c| matches!(c, Command::Variant { .. }))
            .unwrap();
        assert_eq!(
            log[i3b],
            Command::Variant {
                angle_deg: v.angle_deg(),
                res_centideg: v.res_centideg()
            }
        );
        assert_eq!(log.last(), Some(&mode(ModeRequest::StreamAll)));
        assert!(w.has(|e| *e == Event::StreamStopped));
        assert!(w.has(|e| *e == Event::StreamStarted));
        let t = w.now;
        w.run(Duration::from_millis(200), |_| false);
        let after: Vec<u16> = w
            .scans
            .iter()
            .filter(|(at, _)| *at > t)
            .map(|x| x.1)
            .collect();
        assert!(!after.is_empty());
        assert!(after.iter().all(|n| *n == v.values()), "{v:?}");
    }
}

#[test]
fn config_write_skipped_when_unchanged() {
    // Sim starts with units = 1 (mm), the default wish.
    let mut w = World::new(cfg_38400(), Sim::new(BaudRate::B38400));
    assert!(w.run_ready());
    let log = w.codes();
    assert!(log.contains(&Command::ReadConfig));
    assert!(!log.iter().any(|c| matches!(c, Command::WriteConfig(_))));
    assert!(
        !log.iter()
            .any(|c| matches!(c, Command::SetMode(ModeRequest::Installation { .. })))
    );
    assert_eq!(w.d.writes, 0);
    assert!(!w.has(|e| *e == Event::ConfigWritten));
}

#[test]
fn config_written_once_when_it_differs() {
    let cfg = Config {
        availability: Some(0x02),
        measuring_mode: Some(MeasuringMode(0)),
        units: Some(0),
        ..cfg_38400()
    };
    let mut d = Sim::new(BaudRate::B38400);
    d.cfg.set_byte_for_test(20, 0x5A); // an unrelated byte must survive
    let mut w = World::new(cfg.clone(), d);
    assert!(w.run_ready());
    assert_eq!(w.d.writes, 1);
    assert!(w.has(|e| *e == Event::ConfigWritten));
    let log = w.codes();
    let i = log
        .iter()
        .position(|c| matches!(c, Command::WriteConfig(_)))
        .unwrap();
    assert_eq!(
        log[i - 1],
        mode(ModeRequest::Installation {
            password: DEFAULT_PASSWORD
        })
    );
    assert_eq!(log[i + 1], mode(ModeRequest::RequestOnly));
    assert_eq!(w.d.cfg.availability(), 0x02);
    assert_eq!(w.d.cfg.units(), 0);
    assert_eq!(w.d.cfg.as_bytes()[20], 0x5A);
    assert!(w.d.cfg.is_long(), "written back in the form it was read");
    // Real-time indices are now on: scans still parse (2 extra bytes).
    w.run(Duration::from_millis(200), |_| false);
    assert!(!w.scans.is_empty());
    // A second session against the same unit writes nothing.
    let d = std::mem::replace(&mut w.d, Sim::new(BaudRate::B9600));
    let mut d2 = d;
    d2.log.clear();
    d2.host_bps = 9600;
    let mut w2 = World::new(cfg, d2);
    assert!(w2.run_ready());
    assert_eq!(w2.d.writes, 1);
}

#[test]
fn nak_then_successful_retry_after_backoff() {
    let mut d = Sim::new(BaudRate::B9600);
    d.nak_next = 2;
    let cfg = Config {
        baud: BaudRate::B9600,
        ..Config::default()
    };
    let mut w = World::new(cfg, d);
    assert!(w.run_ready());
    assert!(!w.m.is_failed());
    // The first 20 25 was sent three times, 30 ms or more apart after each NAK.
    let probes: Vec<Instant> = w
        .sent
        .iter()
        .filter(|(_, b)| Command::parse(b).unwrap() == mode(ModeRequest::RequestOnly))
        .map(|x| x.0)
        .take(3)
        .collect();
    assert_eq!(probes.len(), 3);
    for p in probes.windows(2) {
        // NAK arrives 2 ms after the telegram, retry ≥ 30 ms after the NAK.
        assert!(p[1] >= p[0] + Duration::from_millis(32), "{p:?}");
    }
    assert_eq!(w.m.stats().retransmissions, 2);
    assert!(w.has(|e| *e == Event::BaudDetected(BaudRate::B9600)));
}

#[test]
fn naks_forever_are_bounded() {
    let mut d = Sim::new(BaudRate::B9600);
    d.nak_next = u32::MAX;
    let cfg = Config {
        probe_rounds: 1,
        retries: 3,
        ..Config::default()
    };
    let mut w = World::new(cfg, d);
    w.run_ready();
    assert!(w.m.is_failed());
    // 1 + 3 attempts at 9600 (NAKed), then the other rates (no answer): 4 each.
    assert_eq!(w.sent.len(), 4 * 3);
    assert!(w.has(|e| *e == Event::Error(MachineError::NoDevice)));
}

#[test]
fn dead_line_times_out_bounded() {
    let mut d = Sim::new(BaudRate::B9600);
    d.mute_until = Instant::from_micros(u64::MAX);
    let cfg = Config {
        rs422: true,
        retries: 2,
        probe_rounds: 2,
        ..Config::default()
    };
    let mut w = World::new(cfg, d);
    let stopped = w.run_ready();
    assert!(stopped && w.m.is_failed());
    // rounds × rates × attempts
    assert_eq!(w.sent.len(), 2 * 4 * 3);
    assert_eq!(w.m.poll_timeout(), None, "nothing left to wait for");
    // Each attempt waited 60 ms plus one 814-byte frame time at its rate, no longer.
    let per_round: Duration = BaudRate::PROBE_ORDER
        .iter()
        .map(|b| 3 * (Duration::from_millis(60) + wire_time(MAX_TELEGRAM, *b)))
        .sum();
    assert_eq!(
        w.now.saturating_duration_since(Instant::ZERO),
        2 * per_round
    );
}

#[test]
fn reply_lost_after_ack_is_retried_then_fails() {
    let mut d = Sim::new(BaudRate::B38400);
    // Status replies vanish (after ACK) four times: 1 + 3 retries, then failure.
    d.silent_after_ack = vec![cmd::STATUS; 4];
    let mut w = World::new(cfg_38400(), d);
    w.run_ready();
    assert!(w.m.is_failed());
    assert!(w.has(|e| *e == Event::Error(MachineError::Timeout { code: cmd::STATUS })));
    let statuses = w.codes().iter().filter(|c| **c == Command::Status).count();
    assert_eq!(statuses, 4);
    // Three lost replies then success: recovers.
    let mut d = Sim::new(BaudRate::B38400);
    d.silent_after_ack = vec![cmd::STATUS; 3];
    let mut w = World::new(cfg_38400(), d);
    assert!(w.run_ready());
    assert!(!w.m.is_failed());
}

#[test]
fn probe_stops_a_running_stream_and_matches_a0_among_b0s() {
    let mut d = Sim::new(BaudRate::B38400);
    d.streaming = true;
    d.next_scan = Some(Instant::ZERO);
    let cfg = Config {
        stream: false,
        ..cfg_38400()
    };
    let mut w = World::new(cfg, d);
    assert!(w.run_ready());
    assert!(!w.d.streaming, "20 25 stopped it");
    assert!(!w.scans.is_empty(), "B0s were flowing meanwhile");
    assert!(w.m.is_ready() && !w.m.is_streaming());
    // Request mode: one scan on demand.
    let n = w.scans.len();
    let now = w.now;
    w.m.request_scan(now).unwrap();
    assert!(w.run(Duration::from_secs(2), |w| w.scans.len() > n
        && w.m.is_ready()));
    assert_eq!(w.scans.len(), n + 1);
    assert_eq!(w.d.log.last().unwrap().1, Command::one_scan());
    // Start and stop the stream on demand.
    let now = w.now;
    w.m.start_stream(now).unwrap();
    assert!(w.run(Duration::from_secs(1), |w| w.m.is_streaming()));
    w.run(Duration::from_millis(100), |_| false);
    let now = w.now;
    w.m.stop_stream(now).unwrap();
    assert!(w.run(Duration::from_secs(1), |w| !w.m.is_streaming()));
    assert!(!w.d.streaming);
}

#[test]
fn power_up_wait_then_probe() {
    let mut d = Sim::new(BaudRate::B9600);
    d.mute_until = Instant::from_millis(30_000);
    d.power_on_at = Some(Instant::from_millis(30_000));
    let cfg = Config {
        power_up_wait: Some(Duration::from_secs(60)),
        ..cfg_38400()
    };
    let mut w = World::new(cfg, d);
    assert!(w.run_ready());
    assert!(w.has(|e| *e == Event::PowerOn));
    // Nothing was sent before the power-on telegram.
    assert!(w.sent[0].0 >= Instant::from_millis(30_000));
    // The QM power-on status 0x13 is surfaced, not fatal.
    assert!(w.has(|e| *e == Event::DeviceStatus(StatusByte(0x13))));
}

#[test]
fn power_up_wait_expires_then_probes_anyway() {
    let d = Sim::new(BaudRate::B9600);
    let cfg = Config {
        power_up_wait: Some(Duration::from_secs(5)),
        ..cfg_38400()
    };
    let mut w = World::new(cfg, d);
    assert!(w.run_ready());
    assert!(w.sent[0].0 >= Instant::from_millis(5_000));
}

#[test]
fn rejection_fails_the_request() {
    let mut d = Sim::new(BaudRate::B38400);
    d.reject_variant = true;
    d.variant = (100, 100);
    let mut w = World::new(cfg_38400(), d);
    w.run_ready();
    assert!(w.m.is_failed());
    assert!(w.has(|e| *e == Event::Error(MachineError::Rejected { code: cmd::VARIANT })));
    let n3b = w
        .codes()
        .iter()
        .filter(|c| matches!(c, Command::Variant { .. }))
        .count();
    assert_eq!(n3b, 1, "a rejection is not retried");
}

#[test]
fn pollution_is_surfaced() {
    let mut d = Sim::new(BaudRate::B38400);
    d.status_byte = 0x90;
    let mut w = World::new(cfg_38400(), d);
    assert!(w.run_ready(), "pollution is not an error");
    assert!(!w.m.is_failed());
    assert!(w.has(|e| matches!(e, Event::DeviceStatus(s) if s.pollution())));
}

#[test]
fn device_error_status_fails_init() {
    let mut d = Sim::new(BaudRate::B38400);
    d.status_byte = 0x13;
    let mut w = World::new(cfg_38400(), d);
    w.run_ready();
    assert!(w.m.is_failed());
    assert!(w.has(|e| matches!(e, Event::Error(MachineError::DeviceError { .. }))));
}

#[test]
fn silent_reboot_to_another_rate_is_caught_by_the_stream_watchdog() {
    let mut w = World::new(cfg_38400(), Sim::new(BaudRate::B9600));
    assert!(w.run_ready());
    // The unit reboots: back at 9600, idle; its 90 is garbage at 38400.
    w.d.baud = BaudRate::B9600;
    w.d.streaming = false;
    w.d.next_scan = None;
    w.d.power_on_at = Some(w.now + Duration::from_millis(5));
    w.events.clear();
    assert!(w.run_ready());
    assert!(w.has(|e| *e == Event::Error(MachineError::StreamStalled)));
    assert!(w.has(|e| *e == Event::BaudDetected(BaudRate::B9600)));
    assert_eq!(w.d.baud, BaudRate::B38400);
    assert!(w.m.is_streaming());
}

#[test]
fn visible_power_on_while_running_restarts_init() {
    let cfg = Config {
        baud: BaudRate::B9600,
        ..Config::default()
    };
    let mut w = World::new(cfg, Sim::new(BaudRate::B9600));
    assert!(w.run_ready());
    w.d.streaming = false;
    w.d.next_scan = None;
    w.d.power_on_at = Some(w.now + Duration::from_millis(5));
    w.events.clear();
    assert!(w.run_ready());
    assert!(w.has(|e| *e == Event::PowerOn));
    assert!(w.has(|e| *e == Event::Restarted));
    assert!(!w.has(|e| *e == Event::Error(MachineError::StreamStalled)));
    assert!(w.m.is_streaming());
}

#[test]
fn watchdog_quiet_while_scans_flow() {
    let mut w = World::new(cfg_38400(), Sim::new(BaudRate::B38400));
    assert!(w.run_ready());
    w.run(Duration::from_secs(20), |_| false);
    assert!(!w.has(|e| matches!(e, Event::Error(_))));
    assert!(w.scans.len() > 500);
}

#[test]
fn requests_refused_while_busy() {
    let mut w = World::new(cfg_38400(), Sim::new(BaudRate::B9600));
    let now = w.now;
    assert_eq!(w.m.request_scan(now), Err(MachineError::Busy));
    assert_eq!(w.m.start_stream(now), Err(MachineError::Busy));
    assert!(w.run_ready());
    assert!(w.m.stop_stream(w.now).is_ok());
    assert_eq!(w.m.stop_stream(w.now), Err(MachineError::Busy));
}

trait SetByte {
    fn set_byte_for_test(&mut self, i: usize, v: u8);
}

impl SetByte for LmsConfig {
    fn set_byte_for_test(&mut self, i: usize, v: u8) {
        let mut raw = self.as_bytes().to_vec();
        raw[i] = v;
        *self = LmsConfig::from_bytes(&raw).unwrap();
    }
}

#[test]
fn reset_waits_for_power_on_then_reinitialises() {
    let mut w = World::new(cfg_38400(), Sim::new(BaudRate::B38400));
    assert!(w.run_ready());
    w.events.clear();
    w.d.log.clear();
    let now = w.now;
    w.m.reset(now).unwrap();
    assert!(w.run_ready());
    assert_eq!(w.codes()[0], Command::Reset);
    assert!(w.has(|e| *e == Event::SetHostBaud(9600)));
    assert!(w.has(|e| *e == Event::PowerOn));
    assert!(
        !w.has(|e| *e == Event::Restarted),
        "an expected 90 is no surprise"
    );
    assert!(w.has(|e| *e == Event::BaudDetected(BaudRate::B9600)));
    // Nothing but the reset was sent before the power-on telegram.
    let t90 = now + Duration::from_millis(3000);
    assert_eq!(w.d.log.iter().filter(|(t, _)| *t < t90).count(), 1);
    assert_eq!(w.d.baud, BaudRate::B38400);
    assert!(w.m.is_streaming());
}

#[test]
fn config_write_result_zero_needs_the_qm_option() {
    let want = Config {
        units: Some(0),
        ..cfg_38400()
    };
    let mut d = Sim::new(BaudRate::B38400);
    d.f7_result = 0;
    let mut w = World::new(want.clone(), d);
    w.run_ready();
    assert!(w.m.is_failed(), "TL: 00 means rejected");
    assert!(w.has(|e| *e
        == Event::Error(MachineError::Refused {
            code: cmd::WRITE_CONFIG,
            result: 0
        })));
    let mut d = Sim::new(BaudRate::B38400);
    d.f7_result = 0;
    let cfg = Config {
        config_write_zero_ok: true,
        ..want
    };
    let mut w = World::new(cfg, d);
    assert!(w.run_ready());
    assert!(w.has(|e| *e == Event::ConfigWritten));
}

#[test]
fn machine_decodes_with_session_parameters() {
    let mut w = World::new(cfg_38400(), Sim::new(BaudRate::B38400));
    assert!(w.run_ready());
    let mut buf = [0u8; MAX_TELEGRAM];
    let words = [1234u16; 361];
    let n = Reply::Scan(Scan::full(&words, Units::Mm, StatusByte::NORMAL))
        .emit(&mut buf)
        .unwrap();
    let Reply::Scan(s) = Reply::parse(&buf[..n]).unwrap() else {
        panic!()
    };
    let mut out = ima_hal::laser::LaserScan::default();
    w.m.decode(&s, &mut out).unwrap();
    assert_eq!(out.len(), 361);
    assert!((out.ranges_m()[7] - 1.234).abs() < 1e-6);
}

#[test]
fn init_and_stream_with_bytes_split_into_small_reads() {
    let mut baseline = None;
    for chunk in [usize::MAX, 1, 2, 13, 500] {
        let mut d = Sim::new(BaudRate::B19200);
        d.streaming = true;
        d.next_scan = Some(Instant::ZERO);
        let mut w = World::new(cfg_38400(), d);
        w.chunk = chunk;
        assert!(w.run_ready(), "chunk {chunk}");
        let t = w.now;
        w.run(Duration::from_millis(300), |_| false);
        assert!(w.scans.iter().filter(|(at, _)| *at > t).count() >= 5);
        assert_eq!(w.m.counters().bad_checksums, 0);
        // Same conversation however the bytes are split (the retransmissions are the probe's
        // at the two wrong rates).
        let r = w.m.stats().retransmissions;
        assert_eq!(*baseline.get_or_insert(r), r, "chunk {chunk}");
        assert_eq!(r, 6);
    }
}

/// Times at which telegrams equal to `c` were sent.
fn sent_times(w: &World, c: &Command) -> Vec<Instant> {
    w.sent
        .iter()
        .filter(|(_, b)| Command::parse(b).as_ref() == Ok(c))
        .map(|x| x.0)
        .collect()
}

#[test]
fn reply_timeouts_follow_the_spec_table() {
    // Mode change: ACK after 2 ms, then up to 3 s (plus one frame time) for A0.
    let mut d = Sim::new(BaudRate::B9600);
    d.silent_after_ack = vec![cmd::SET_MODE];
    let cfg = Config {
        baud: BaudRate::B9600,
        ..Config::default()
    };
    let mut w = World::new(cfg, d);
    assert!(w.run_ready());
    let t = sent_times(&w, &mode(ModeRequest::RequestOnly));
    let frame = wire_time(MAX_TELEGRAM, BaudRate::B9600);
    assert_eq!(
        t[1],
        t[0] + Duration::from_millis(2) + Duration::from_secs(3) + frame
    );

    // Config write: up to 15 s for F7.
    let mut d = Sim::new(BaudRate::B38400);
    d.silent_after_ack = vec![cmd::WRITE_CONFIG];
    let cfg = Config {
        units: Some(0),
        ..cfg_38400()
    };
    let mut w = World::new(cfg, d);
    assert!(w.run_ready());
    let writes: Vec<Instant> = w
        .sent
        .iter()
        .filter(|(_, b)| matches!(Command::parse(b), Ok(Command::WriteConfig(_))))
        .map(|x| x.0)
        .collect();
    assert_eq!(writes.len(), 2);
    let frame = wire_time(MAX_TELEGRAM, BaudRate::B38400);
    assert_eq!(
        writes[1],
        writes[0] + Duration::from_millis(2) + Duration::from_secs(15) + frame
    );
    assert_eq!(w.d.writes, 1, "the lost F7's write did not reach the sim");

    // Other requests: 1 s.
    let mut d = Sim::new(BaudRate::B38400);
    d.silent_after_ack = vec![cmd::TYPE];
    let mut w = World::new(cfg_38400(), d);
    assert!(w.run_ready());
    let t = sent_times(&w, &Command::Type);
    assert_eq!(
        t[1],
        t[0] + Duration::from_millis(2) + Duration::from_secs(1) + frame
    );
}

#[test]
fn corrupted_telegram_is_naked_by_the_device_and_resent() {
    let cfg = Config {
        baud: BaudRate::B9600,
        ..Config::default()
    };
    let mut w = World::new(cfg, Sim::new(BaudRate::B9600));
    w.corrupt_tx = 2;
    assert!(w.run_ready());
    let t = sent_times(&w, &mode(ModeRequest::RequestOnly));
    assert!(t.len() >= 3);
    assert!(t[1] >= t[0] + Duration::from_millis(32), "NAK backoff");
    assert_eq!(w.m.counters().naks, 2);
    assert_eq!(w.d.framer.counters().bad_checksums, 2);
    assert!(w.has(|e| *e == Event::BaudDetected(BaudRate::B9600)));
}

#[test]
fn close_stops_the_stream_and_restores_9600() {
    let cfg = Config {
        baud: BaudRate::B500000,
        rs422: true,
        ..Config::default()
    };
    let mut w = World::new(cfg, Sim::new(BaudRate::B9600));
    assert!(w.run_ready());
    assert!(w.d.streaming);
    let before = w.codes().len();
    let now = w.now;
    w.m.close(now);
    assert!(w.run(Duration::from_secs(5), |w| w.m.is_closed()));
    w.pump();
    let log = w.codes();
    assert_eq!(
        log[before..],
        [
            mode(ModeRequest::RequestOnly),
            mode(ModeRequest::Baud(BaudRate::B9600))
        ]
    );
    assert!(!w.d.streaming);
    assert_eq!(w.d.baud, BaudRate::B9600);
    assert_eq!(w.host_bps, 9600);
    assert!(w.has(|e| *e == Event::Closed));
    // Closing twice is harmless and sends nothing.
    let now = w.now;
    w.m.close(now);
    w.pump();
    assert_eq!(w.codes().len(), log.len());
}

#[test]
fn close_at_9600_idle_or_before_a_unit_was_found_sends_nothing() {
    let cfg = Config {
        baud: BaudRate::B9600,
        stream: false,
        ..Config::default()
    };
    let mut w = World::new(cfg, Sim::new(BaudRate::B9600));
    assert!(w.run_ready());
    let before = w.codes().len();
    let now = w.now;
    w.m.close(now);
    w.pump();
    assert!(w.m.is_closed());
    assert_eq!(w.codes().len(), before);
    // Still probing: nothing to undo.
    let mut w = World::new(cfg_38400(), Sim::new(BaudRate::B9600));
    w.m.close(Instant::ZERO);
    w.pump();
    assert!(w.m.is_closed() && w.has(|e| *e == Event::Closed));
}

#[test]
fn close_gives_up_when_the_unit_is_gone() {
    let mut w = World::new(cfg_38400(), Sim::new(BaudRate::B9600));
    assert!(w.run_ready());
    // The unit goes quiet: the stop is unanswered, the machine still closes (bounded).
    w.d.mute_until = Instant::from_micros(u64::MAX / 2);
    let now = w.now;
    w.m.close(now);
    assert!(w.run(Duration::from_secs(30), |w| w.m.is_closed()));
    assert!(w.has(|e| matches!(e, Event::Error(MachineError::Timeout { .. }))));
}

//! The session machine against the mock LMS of `ima-mock-devices` (the one model of the
//! unit), in virtual time.
//!
//! The model follows the device's rules of the spec (ACK then reply, `A0` of a baud change sent
//! at the old rate, B0 stream in mode `24`, `77` only in installation mode), paces its output
//! by its line rate and garbles what crosses a rate mismatch. Misbehaviour is scripted on the
//! model (`nak_next`, `lose_reply_to`, `refuse`); a cut line and corrupted host telegrams are
//! this harness's.

use std::time::Duration;

use ima_hal::Instant;
use ima_mock_devices::sick_lms::{RangeSource, SickLmsModel, SickLmsModelConfig};
use ima_sick_lms::decode::Variant;
use ima_sick_lms::machine::{Config, Event, Machine, MachineError, wire_time};
use ima_sick_lms::wire::*;

const TYPE: &[u8] = b"LMS200;30106";

/// Ranges that put `02 80` inside the B0 data, as real range data may: 0.512 m then 0.128 m
/// encode as `00 02` `80 00`.
struct Pattern;

impl RangeSource for Pattern {
    fn ranges(&mut self, _: f64, _: f64, count: u16, _: f64, out: &mut Vec<Option<f64>>) {
        out.clear();
        out.extend((0..count).map(|i| {
            Some(match i % 9 {
                0 => 0.512,
                1 => 0.128,
                k => 1.0 + f64::from(k) / 1000.0,
            })
        }));
    }
}

/// The mock unit's configuration in these tests: power-up rate 9600, a 3 s reboot.
fn unit_cfg() -> SickLmsModelConfig {
    SickLmsModelConfig {
        boot_delay: Duration::from_secs(3),
        ..SickLmsModelConfig::default()
    }
}

/// A unit running at `baud`, idle, recording the commands it receives.
fn unit_with(cfg: SickLmsModelConfig, baud: BaudRate) -> SickLmsModel {
    let mut d = SickLmsModel::running(cfg, Box::new(Pattern), Instant::ZERO, baud);
    d.record_commands();
    d
}

fn unit(baud: BaudRate) -> SickLmsModel {
    unit_with(unit_cfg(), baud)
}

struct World {
    m: Machine,
    d: SickLmsModel,
    now: Instant,
    events: Vec<(Instant, Event)>,
    sent: Vec<(Instant, Vec<u8>)>,
    scans: Vec<(Instant, u16)>,
    host_bps: u32,
    /// Deliver device output in reads of this many bytes.
    chunk: usize,
    /// Corrupt the CRC of this many next host telegrams on the line.
    corrupt_tx: u32,
    /// The line is cut (both ways) until then.
    mute_until: Instant,
}

impl World {
    fn new(cfg: Config, mut d: SickLmsModel) -> Self {
        d.set_host_baud(Some(9600));
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
            mute_until: Instant::ZERO,
        }
    }

    fn pump(&mut self) {
        while let Some(e) = self.m.poll_event() {
            if let Event::SetHostBaud(b) = e {
                self.host_bps = b;
                self.d.set_host_baud(Some(b));
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
            if self.now >= self.mute_until {
                self.d.handle_rx(&buf[..n], self.now);
            }
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
            let t = [self.m.poll_timeout(), self.d.poll_timeout()]
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
            if self.d.poll_timeout().is_some_and(|t| t <= now) {
                self.d.handle_timeout(now);
            }
            // The model garbles what it sends at a rate the host is not at.
            let bytes = self.d.take_output();
            if now >= self.mute_until {
                let scans = &mut self.scans;
                for c in bytes.chunks(self.chunk) {
                    self.m
                        .handle_bytes_with(c, now, |s, at| scans.push((at, s.count_word.count())));
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

    /// The commands the unit received, in order.
    fn codes(&self) -> Vec<Command> {
        self.d.commands().iter().map(|(_, c)| c.clone()).collect()
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
        let mut w = World::new(cfg_38400(), unit(start));
        assert!(w.run_ready(), "{start:?}");
        assert!(!w.m.is_failed());
        assert!(w.has(|e| *e == Event::BaudDetected(start)), "{start:?}");
        assert_eq!(w.d.baud(), BaudRate::B38400);
        assert_eq!(w.host_bps, 38400);
        assert_eq!(w.m.host_baud(), BaudRate::B38400);
        assert!(w.m.is_streaming() && w.d.is_streaming());
        assert_eq!(w.m.device_type(), Some(TYPE));
        // Scans flow and are decodable with the session's parameters.
        // 5.2 scans/s at 38400 (the line limit).
        let t = w.now;
        w.run(Duration::from_millis(1500), |_| false);
        let n = w.scans.iter().filter(|(at, _)| *at > t).count();
        assert!(n >= 5, "{start:?}: {n} scans");
        assert!(w.scans.iter().all(|(_, c)| *c == 361));
        assert_eq!(w.m.counters().bad_checksums, 0);
        // Only typed, known commands were ever sent; the permanent-baud command (0x66) cannot
        // even be expressed by `Command`.
        assert_eq!(w.d.framer_counters().bad_headers, 0);
        assert_eq!(w.d.stats().rejected, 0);
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
    let mut w = World::new(cfg, unit(BaudRate::B500000));
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
    let mut w = World::new(cfg, unit(BaudRate::B9600));
    assert!(w.run_ready());
    assert_eq!(w.d.baud(), BaudRate::B500000);
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
    let mut w = World::new(cfg, unit(BaudRate::B9600));
    w.run_ready();
    assert!(w.m.is_failed());
    // The host refused it, not the unit (it once read "command 20h refused (result 48h)").
    assert!(w.has(|e| *e == Event::Error(MachineError::NeedsRs422)));
    assert!(
        !w.codes()
            .iter()
            .any(|c| matches!(c, Command::SetMode(ModeRequest::Baud(_))))
    );
}

#[test]
fn lost_baud_change_reply_is_not_retried_blindly() {
    // The first 20 25 of the probe answers normally: only the baud change's reply is lost.
    let d = unit(BaudRate::B9600);
    let mut w = World::new(cfg_38400(), d);
    // Arm the fault just before the baud change: run until identified.
    assert!(w.run(Duration::from_secs(10), |w| {
        w.has(|e| *e == Event::Identified)
    }));
    w.d.lose_reply_to(cmd::SET_MODE);
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
    let d = unit_with(
        SickLmsModelConfig {
            variant: Variant::new(from.0, from.1).unwrap(),
            ..unit_cfg()
        },
        BaudRate::B38400,
    );
    let mut w = World::new(cfg, d);
    assert!(w.run_ready());
    assert_eq!(w.d.variant(), to);
    let sent_3b = w
        .codes()
        .iter()
        .filter(|c| matches!(c, Command::Variant { .. }))
        .count();
    let same = from == (to.angle_deg(), to.res_centideg());
    assert_eq!(sent_3b, usize::from(!same), "{from:?} -> {to:?}");
    assert_eq!(w.m.session().variant, Some(to));
    w.run(Duration::from_millis(600), |_| false);
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
    let mut w = World::new(cfg_38400(), unit(BaudRate::B38400));
    assert!(w.run_ready());
    for v in [
        Variant::W180_R100,
        Variant::W100_R25,
        Variant::W180_R50,
        Variant::W100_R25,
    ] {
        w.events.clear();
        w.d.clear_commands();
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
        w.run(Duration::from_millis(600), |_| false);
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
    // The unit starts with units = 1 (mm), the default wish.
    let mut w = World::new(cfg_38400(), unit(BaudRate::B38400));
    assert!(w.run_ready());
    let log = w.codes();
    assert!(log.contains(&Command::ReadConfig));
    assert!(!log.iter().any(|c| matches!(c, Command::WriteConfig(_))));
    assert!(
        !log.iter()
            .any(|c| matches!(c, Command::SetMode(ModeRequest::Installation { .. })))
    );
    assert_eq!(w.d.stats().eeprom_writes, 0);
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
    let mut ucfg = unit_cfg();
    ucfg.config.set_byte_for_test(20, 0x5A); // an unrelated byte must survive
    let d = unit_with(ucfg, BaudRate::B38400);
    let mut w = World::new(cfg.clone(), d);
    assert!(w.run_ready());
    assert_eq!(w.d.stats().eeprom_writes, 1);
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
    assert_eq!(w.d.config().availability(), 0x02);
    assert_eq!(w.d.config().units(), 0);
    assert_eq!(w.d.config().as_bytes()[20], 0x5A);
    assert!(
        w.d.config().is_long(),
        "written back in the form it was read"
    );
    // Real-time indices are now on: scans still parse (2 extra bytes).
    w.run(Duration::from_millis(600), |_| false);
    assert!(!w.scans.is_empty());
    // A second session against the same unit (still at 38400, streaming) writes nothing.
    let mut d2 = std::mem::replace(&mut w.d, unit(BaudRate::B9600));
    d2.clear_commands();
    let mut w2 = World::new(cfg, d2);
    assert!(w2.run_ready());
    assert_eq!(w2.d.stats().eeprom_writes, 1);
}

#[test]
fn nak_then_successful_retry_after_backoff() {
    let mut d = unit(BaudRate::B9600);
    d.nak_next(2);
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
        // NAK leaves 2 ms after the telegram (then its byte time), retry ≥ 30 ms after it.
        assert!(p[1] >= p[0] + Duration::from_millis(32), "{p:?}");
    }
    assert_eq!(w.m.stats().retransmissions, 2);
    assert!(w.has(|e| *e == Event::BaudDetected(BaudRate::B9600)));
}

#[test]
fn naks_forever_are_bounded() {
    let mut d = unit(BaudRate::B9600);
    d.nak_next(u32::MAX);
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
    let d = unit(BaudRate::B9600);
    let cfg = Config {
        rs422: true,
        retries: 2,
        probe_rounds: 2,
        ..Config::default()
    };
    let mut w = World::new(cfg, d);
    w.mute_until = Instant::from_micros(u64::MAX);
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
    let mut d = unit(BaudRate::B38400);
    // Status replies vanish (after ACK) four times: 1 + 3 retries, then failure.
    for _ in 0..4 {
        d.lose_reply_to(cmd::STATUS);
    }
    let mut w = World::new(cfg_38400(), d);
    w.run_ready();
    assert!(w.m.is_failed());
    assert!(w.has(|e| *e == Event::Error(MachineError::Timeout { code: cmd::STATUS })));
    let statuses = w.codes().iter().filter(|c| **c == Command::Status).count();
    assert_eq!(statuses, 4);
    // Three lost replies then success: recovers.
    let mut d = unit(BaudRate::B38400);
    for _ in 0..3 {
        d.lose_reply_to(cmd::STATUS);
    }
    let mut w = World::new(cfg_38400(), d);
    assert!(w.run_ready());
    assert!(!w.m.is_failed());
}

#[test]
fn probe_stops_a_running_stream_and_matches_a0_among_b0s() {
    let mut d = unit(BaudRate::B38400);
    d.start_streaming(Instant::ZERO);
    let cfg = Config {
        stream: false,
        ..cfg_38400()
    };
    let mut w = World::new(cfg, d);
    assert!(w.run_ready());
    assert!(!w.d.is_streaming(), "20 25 stopped it");
    assert!(!w.scans.is_empty(), "B0s were flowing meanwhile");
    assert!(w.m.is_ready() && !w.m.is_streaming());
    // Request mode: one scan on demand.
    let n = w.scans.len();
    let now = w.now;
    w.m.request_scan(now).unwrap();
    assert!(w.run(Duration::from_secs(2), |w| w.scans.len() > n
        && w.m.is_ready()));
    assert_eq!(w.scans.len(), n + 1);
    assert_eq!(w.d.commands().last().unwrap().1, Command::one_scan());
    // Start and stop the stream on demand.
    let now = w.now;
    w.m.start_stream(now).unwrap();
    assert!(w.run(Duration::from_secs(1), |w| w.m.is_streaming()));
    w.run(Duration::from_millis(100), |_| false);
    let now = w.now;
    w.m.stop_stream(now).unwrap();
    assert!(w.run(Duration::from_secs(1), |w| !w.m.is_streaming()));
    assert!(!w.d.is_streaming());
}

#[test]
fn power_up_wait_then_probe() {
    // Powered up with the port: busy (deaf) for 30 s, then the power-on telegram.
    let mut d = SickLmsModel::new(
        SickLmsModelConfig {
            boot_delay: Duration::from_secs(30),
            ..unit_cfg()
        },
        Box::new(Pattern),
        Instant::ZERO,
    );
    d.record_commands();
    let cfg = Config {
        power_up_wait: Some(Duration::from_secs(60)),
        ..cfg_38400()
    };
    let mut w = World::new(cfg, d);
    assert!(w.run_ready());
    assert!(w.has(|e| *e == Event::PowerOn));
    // Nothing was sent before the power-on telegram.
    assert!(w.sent[0].0 >= Instant::from_millis(30_000));
    // The QM power-on status 0x13 describes the boot: it is neither fatal nor taken as the
    // device's status (which would read "error" at every power-up); the later replies' status
    // is.
    assert!(!w.has(|e| *e == Event::DeviceStatus(StatusByte(0x13))));
    assert!(w.has(|e| matches!(e, Event::DeviceStatus(s) if !s.is_error())));
}

#[test]
fn power_up_wait_expires_then_probes_anyway() {
    let d = unit(BaudRate::B9600);
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
    let mut d = unit_with(
        SickLmsModelConfig {
            variant: Variant::new(100, 100).unwrap(),
            ..unit_cfg()
        },
        BaudRate::B38400,
    );
    d.refuse(cmd::VARIANT);
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
    let d = unit_with(
        SickLmsModelConfig {
            status: StatusByte(0x90),
            ..unit_cfg()
        },
        BaudRate::B38400,
    );
    let mut w = World::new(cfg_38400(), d);
    assert!(w.run_ready(), "pollution is not an error");
    assert!(!w.m.is_failed());
    assert!(w.has(|e| matches!(e, Event::DeviceStatus(s) if s.pollution())));
}

#[test]
fn device_error_status_fails_init() {
    let d = unit_with(
        SickLmsModelConfig {
            status: StatusByte(0x13),
            ..unit_cfg()
        },
        BaudRate::B38400,
    );
    let mut w = World::new(cfg_38400(), d);
    w.run_ready();
    assert!(w.m.is_failed());
    assert!(w.has(|e| matches!(e, Event::Error(MachineError::DeviceError { .. }))));
}

#[test]
fn silent_reboot_to_another_rate_is_caught_by_the_stream_watchdog() {
    let quick_boot = SickLmsModelConfig {
        boot_delay: Duration::from_millis(5),
        ..unit_cfg()
    };
    let mut w = World::new(cfg_38400(), unit_with(quick_boot, BaudRate::B9600));
    assert!(w.run_ready());
    // The unit reboots: back at 9600, idle; its 90 is garbage at 38400.
    let now = w.now;
    w.d.power_up(now);
    w.events.clear();
    assert!(w.run_ready());
    assert!(w.has(|e| *e == Event::Error(MachineError::StreamStalled)));
    assert!(w.has(|e| *e == Event::BaudDetected(BaudRate::B9600)));
    assert_eq!(w.d.baud(), BaudRate::B38400);
    assert!(w.m.is_streaming());
}

#[test]
fn visible_power_on_while_running_restarts_init() {
    let cfg = Config {
        baud: BaudRate::B9600,
        ..Config::default()
    };
    let quick_boot = SickLmsModelConfig {
        boot_delay: Duration::from_millis(5),
        ..unit_cfg()
    };
    let mut w = World::new(cfg, unit_with(quick_boot, BaudRate::B9600));
    assert!(w.run_ready());
    let now = w.now;
    w.d.power_up(now);
    w.events.clear();
    assert!(w.run_ready());
    assert!(w.has(|e| *e == Event::PowerOn));
    assert!(w.has(|e| *e == Event::Restarted));
    assert!(!w.has(|e| *e == Event::Error(MachineError::StreamStalled)));
    assert!(w.m.is_streaming());
}

#[test]
fn watchdog_quiet_while_scans_flow() {
    // At 500 000 baud: 37.5 scans/s (the mirror limit).
    let cfg = Config {
        baud: BaudRate::B500000,
        ..cfg_38400()
    };
    let mut w = World::new(cfg, unit(BaudRate::B500000));
    assert!(w.run_ready());
    w.run(Duration::from_secs(20), |_| false);
    assert!(!w.has(|e| matches!(e, Event::Error(_))));
    assert!(w.scans.len() > 500);
}

#[test]
fn requests_refused_while_busy() {
    let mut w = World::new(cfg_38400(), unit(BaudRate::B9600));
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
    let mut w = World::new(cfg_38400(), unit(BaudRate::B38400));
    assert!(w.run_ready());
    w.events.clear();
    w.d.clear_commands();
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
    assert_eq!(w.d.commands().iter().filter(|(t, _)| *t < t90).count(), 1);
    assert_eq!(w.d.baud(), BaudRate::B38400);
    assert!(w.m.is_streaming());
}

#[test]
fn config_write_result_zero_needs_the_qm_option() {
    let want = Config {
        units: Some(0),
        ..cfg_38400()
    };
    let qm = SickLmsModelConfig {
        config_write_result: 0,
        ..unit_cfg()
    };
    let d = unit_with(qm.clone(), BaudRate::B38400);
    let mut w = World::new(want.clone(), d);
    w.run_ready();
    assert!(w.m.is_failed(), "TL: 00 means rejected");
    assert!(w.has(|e| *e
        == Event::Error(MachineError::Refused {
            code: cmd::WRITE_CONFIG,
            result: 0
        })));
    let d = unit_with(qm, BaudRate::B38400);
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
    let mut w = World::new(cfg_38400(), unit(BaudRate::B38400));
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
        let mut d = unit(BaudRate::B19200);
        d.start_streaming(Instant::ZERO);
        let mut w = World::new(cfg_38400(), d);
        w.chunk = chunk;
        assert!(w.run_ready(), "chunk {chunk}");
        let t = w.now;
        w.run(Duration::from_millis(1500), |_| false);
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
    // (The ACK leaves the unit 2 ms after the telegram and takes one byte time.)
    let ack = |b| Duration::from_millis(2) + wire_time(1, b);
    let mut d = unit(BaudRate::B9600);
    d.lose_reply_to(cmd::SET_MODE);
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
        t[0] + ack(BaudRate::B9600) + Duration::from_secs(3) + frame
    );

    // Config write: up to 15 s for F7.
    let mut d = unit(BaudRate::B38400);
    d.lose_reply_to(cmd::WRITE_CONFIG);
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
        writes[0] + ack(BaudRate::B38400) + Duration::from_secs(15) + frame
    );
    // The unit wrote before its F7 was lost; the retry writes again.
    assert_eq!(w.d.stats().eeprom_writes, 2);
    assert_eq!(w.d.stats().lost_replies, 1);

    // Other requests: 1 s.
    let mut d = unit(BaudRate::B38400);
    d.lose_reply_to(cmd::TYPE);
    let mut w = World::new(cfg_38400(), d);
    assert!(w.run_ready());
    let t = sent_times(&w, &Command::Type);
    assert_eq!(
        t[1],
        t[0] + ack(BaudRate::B38400) + Duration::from_secs(1) + frame
    );
}

#[test]
fn corrupted_telegram_is_naked_by_the_device_and_resent() {
    let cfg = Config {
        baud: BaudRate::B9600,
        ..Config::default()
    };
    let mut w = World::new(cfg, unit(BaudRate::B9600));
    w.corrupt_tx = 2;
    assert!(w.run_ready());
    let t = sent_times(&w, &mode(ModeRequest::RequestOnly));
    assert!(t.len() >= 3);
    assert!(t[1] >= t[0] + Duration::from_millis(32), "NAK backoff");
    assert_eq!(w.m.counters().naks, 2);
    assert_eq!(w.d.framer_counters().bad_checksums, 2);
    assert_eq!(w.d.stats().naks, 2);
    assert!(w.has(|e| *e == Event::BaudDetected(BaudRate::B9600)));
}

#[test]
fn close_stops_the_stream_and_restores_9600() {
    let cfg = Config {
        baud: BaudRate::B500000,
        rs422: true,
        ..Config::default()
    };
    let mut w = World::new(cfg, unit(BaudRate::B9600));
    assert!(w.run_ready());
    assert!(w.d.is_streaming());
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
    assert!(!w.d.is_streaming());
    assert_eq!(w.d.baud(), BaudRate::B9600);
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
    let mut w = World::new(cfg, unit(BaudRate::B9600));
    assert!(w.run_ready());
    let before = w.codes().len();
    let now = w.now;
    w.m.close(now);
    w.pump();
    assert!(w.m.is_closed());
    assert_eq!(w.codes().len(), before);
    // Still probing: nothing to undo.
    let mut w = World::new(cfg_38400(), unit(BaudRate::B9600));
    w.m.close(Instant::ZERO);
    w.pump();
    assert!(w.m.is_closed() && w.has(|e| *e == Event::Closed));
}

#[test]
fn close_gives_up_when_the_unit_is_gone() {
    let mut w = World::new(cfg_38400(), unit(BaudRate::B9600));
    assert!(w.run_ready());
    // The line goes dead: the stop is unanswered, the machine still closes (bounded).
    w.mute_until = Instant::from_micros(u64::MAX / 2);
    let now = w.now;
    w.m.close(now);
    assert!(w.run(Duration::from_secs(30), |w| w.m.is_closed()));
    assert!(w.has(|e| matches!(e, Event::Error(MachineError::Timeout { .. }))));
}

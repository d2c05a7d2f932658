//! Session tests in virtual time (spec §4–§7); motion reports come from the mock's rFLEX
//! model (`ima-mock-devices`), the one model of the base.

use core::f64::consts::FRAC_PI_2;
use core::time::Duration;

use ima_hal::Instant;
use ima_hal::base::VelocityCommand;
use ima_mock_devices::body::ScriptedBody;
use ima_mock_devices::rflex::{RflexModelConfig, RflexRobot};
use ima_rflex::machine::{CommandError, Config, Event, Machine, Phase, TX_BUF};
use ima_rflex::wire::{
    Command, MAX_WIRE_FRAME, MotionReport, Report, SetDir, SonarRun, Stuffing, WireError,
};

fn ms(t: u64) -> Instant {
    Instant::from_millis(t)
}

/// A virtual-time harness: drives the machine from timeout to timeout and records every frame
/// with the instant it was sent.
struct Sim {
    m: Machine,
    now: Instant,
    sent: Vec<(Instant, Command)>,
    wire: Vec<(Instant, Vec<u8>)>,
    events: Vec<Event>,
}

impl Sim {
    fn new(cfg: Config) -> Self {
        Self {
            m: Machine::new(cfg, Instant::ZERO),
            now: Instant::ZERO,
            sent: Vec::new(),
            wire: Vec::new(),
            events: Vec::new(),
        }
    }

    fn drain(&mut self) {
        let mut buf = [0u8; TX_BUF];
        while let Some(n) = self.m.poll_transmit(&mut buf) {
            let w = buf[..n].to_vec();
            // Lenient parse so that legacy (unstuffed) frames can be inspected too.
            let mut f = ima_rflex::framer::Framer::lenient();
            let mut cmd = None;
            f.push(&w, |r| cmd = Some(Command::from_raw(&r.unwrap()).unwrap()));
            self.sent
                .push((self.now, cmd.expect("one frame per poll_transmit")));
            self.wire.push((self.now, w));
        }
        while let Some(e) = self.m.poll_event() {
            self.events.push(e);
        }
    }

    /// Advance to `end`, waking at every `poll_timeout`.
    fn run_until(&mut self, end: Instant) {
        self.drain();
        for _ in 0..100_000 {
            match self.m.poll_timeout() {
                Some(t) if t <= end => {
                    assert!(
                        t >= self.now || !self.sent.is_empty(),
                        "time went backwards"
                    );
                    self.now = t.max(self.now);
                    self.m.handle_timeout(self.now);
                    self.drain();
                    // Progress guard: a timeout at `now` must have produced something.
                    if self.m.poll_timeout() == Some(self.now) {
                        self.m.handle_timeout(self.now);
                        self.drain();
                        assert_ne!(
                            self.m.poll_timeout(),
                            Some(self.now),
                            "stuck at {:?}",
                            self.now
                        );
                    }
                }
                _ => break,
            }
        }
        self.now = end.max(self.now);
        self.m.handle_timeout(self.now);
        self.drain();
    }

    fn at(&mut self, t: Instant) -> &mut Machine {
        self.run_until(t);
        &mut self.m
    }

    fn set_dirs_since(&self, t: Instant) -> Vec<(Instant, SetDir)> {
        self.sent
            .iter()
            .filter(|(at, _)| *at >= t)
            .filter_map(|(at, c)| match c {
                Command::SetDir(s) => Some((*at, *s)),
                _ => None,
            })
            .collect()
    }

    fn frames_since(&self, t: Instant) -> Vec<Command> {
        self.sent
            .iter()
            .filter(|(at, _)| *at >= t)
            .map(|(_, c)| *c)
            .collect()
    }
}

fn init_frames(cfg: &Config) -> Vec<Command> {
    let mut v = vec![
        Command::SystemReportReq {
            period_us: 100_000,
            mask: 3,
        },
        Command::DioReportsReq { period_us: 100_000 },
        Command::SetDefaults,
        Command::SetDir(SetDir {
            axis: 0,
            velocity: 0,
            acceleration: 63_567,
            torque: 0,
            forward: false,
        }),
        Command::SetDir(SetDir {
            axis: 1,
            velocity: 0,
            acceleration: 100_000,
            torque: 0,
            forward: false,
        }),
    ];
    if cfg.release_brake_at_start {
        v.push(Command::BrakeRelease);
    }
    v.push(Command::SonarRun(SonarRun::ON));
    v.push(Command::SysStatusRequest);
    v
}

#[test]
fn init_order_and_pacing() {
    let mut s = Sim::new(Config::default());
    s.run_until(ms(900));
    let cmds: Vec<Command> = s.sent.iter().map(|(_, c)| *c).collect();
    assert_eq!(cmds, init_frames(&Config::default()));
    // ≥ 5 ms between frames; the first goes out at once.
    assert_eq!(s.sent[0].0, Instant::ZERO);
    for w in s.sent.windows(2) {
        assert!(w[1].0.saturating_duration_since(w[0].0) >= Duration::from_millis(5));
    }
    assert!(s.events.contains(&Event::Initialized));
    assert!(!s.m.motors_enabled());
    // The SONAR_RUN frame goes out with packet id 4 (§2.1).
    let sonar = &s.wire[5].1;
    assert_eq!(sonar[3], 4);
}

#[test]
fn brake_release_at_start_is_an_option() {
    let cfg = Config {
        release_brake_at_start: true,
        sonar_at_start: false,
        ..Config::default()
    };
    let mut s = Sim::new(cfg.clone());
    s.run_until(ms(500));
    let mut want = init_frames(&cfg);
    want.retain(|c| !matches!(c, Command::SonarRun(_)));
    assert_eq!(s.frames_since(Instant::ZERO), want);
    assert!(s.m.motors_enabled());
}

#[test]
fn status_is_polled_about_once_a_second() {
    let mut s = Sim::new(Config::default());
    s.run_until(ms(5_050));
    let times: Vec<Instant> = s
        .sent
        .iter()
        .filter(|(_, c)| *c == Command::SysStatusRequest)
        .map(|(t, _)| *t)
        .collect();
    assert_eq!(times.len(), 6, "{times:?}"); // init + 1, 2, 3, 4, 5 s
    assert_eq!(times[1], ms(1000));
    assert_eq!(times[5], ms(5000));
}

#[test]
fn motion_needs_brake_release() {
    let mut s = Sim::new(Config::default());
    let before = s.sent.len();
    let r = s
        .at(ms(200))
        .set_velocity(VelocityCommand::new(0.3, 0.0), ms(200));
    assert_eq!(r, Err(CommandError::MotorsDisabled));
    s.run_until(ms(800));
    assert!(
        s.set_dirs_since(ms(100)).is_empty(),
        "no motion frames while braked"
    );
    assert!(s.sent.len() > before);
    // A stop is always accepted.
    assert_eq!(s.m.stop(ms(800)), Ok(()));

    s.at(ms(1000)).enable_motors(true, ms(1000)).unwrap();
    s.at(ms(1000))
        .set_velocity(VelocityCommand::new(0.3, 0.0), ms(1000))
        .unwrap();
    s.run_until(ms(1050));
    let after = s.frames_since(ms(1000));
    // Status (due at 1 s), brake release and its status check come before the motion pair.
    let rel = after
        .iter()
        .position(|c| *c == Command::BrakeRelease)
        .unwrap();
    let mv = after
        .iter()
        .position(|c| matches!(c, Command::SetDir(d) if d.velocity == 27_243))
        .unwrap();
    assert!(rel < mv);
    // The pair is exactly T4.
    let mut buf = [0u8; MAX_WIRE_FRAME];
    let pair: Vec<&(Instant, Vec<u8>)> = s
        .wire
        .iter()
        .filter(|(t, w)| *t >= ms(1000) && w[4] == 0x07)
        .take(2)
        .collect();
    let t4 = Command::SetDir(SetDir {
        axis: 0,
        velocity: 27_243,
        acceleration: 63_567,
        torque: 30_000,
        forward: true,
    });
    let n = t4.emit(&mut buf).unwrap();
    assert_eq!(pair[0].1, buf[..n].to_vec());
    assert_eq!(pair[1].1[6], 1, "axis 1 follows axis 0");
}

fn driving_sim() -> Sim {
    let mut s = Sim::new(Config::default());
    s.at(ms(100)).enable_motors(true, ms(100)).unwrap();
    s.run_until(ms(200));
    s
}

#[test]
fn keep_alive_at_10_hz_while_driving() {
    let mut s = driving_sim();
    // The client refreshes every 300 ms (within the 0.5 s watchdog) for 3 s.
    let mut t = 1000;
    while t <= 4000 {
        s.at(ms(t))
            .set_velocity(VelocityCommand::new(0.5, 0.2), ms(t))
            .unwrap();
        t += 300;
    }
    s.run_until(ms(4000));
    let axis0: Vec<Instant> = s
        .set_dirs_since(ms(1000))
        .into_iter()
        .filter(|(_, d)| d.axis == 0)
        .map(|(t, _)| t)
        .collect();
    // 3 s at 10 Hz.
    assert!((30..=32).contains(&axis0.len()), "{}", axis0.len());
    for w in axis0.windows(2) {
        let gap = w[1].saturating_duration_since(w[0]);
        assert!(
            gap <= Duration::from_millis(110),
            "gap {gap:?} at {:?}",
            w[0]
        );
        assert!(
            gap >= Duration::from_millis(10),
            "gap {gap:?} at {:?}",
            w[0]
        );
    }
    // Every motion frame carries the commanded speed: 0.5·90810 and 0.2·37000.
    for (_, d) in s.set_dirs_since(ms(1000)) {
        let want = if d.axis == 0 { 45_405 } else { 7_400 };
        assert_eq!(d.velocity, want);
        assert!(d.forward);
    }
}

#[test]
fn zeros_for_half_a_second_after_a_stop() {
    let mut s = driving_sim();
    s.at(ms(1000))
        .set_velocity(VelocityCommand::new(-0.3, 0.5), ms(1000))
        .unwrap();
    s.at(ms(1250)).stop(ms(1250)).unwrap();
    s.run_until(ms(3000));
    let after = s.set_dirs_since(ms(1250));
    assert!(after.iter().all(|(_, d)| d.velocity == 0));
    let first = after.first().unwrap().0;
    let last = after.last().unwrap().0;
    assert!(first < ms(1260));
    assert!(last >= ms(1750), "zeros only until {last:?}");
    assert!(last <= ms(1860), "zeros went on until {last:?}");
    // Before the stop, reverse motion went out with direction 0.
    let before: Vec<SetDir> = s
        .set_dirs_since(ms(1000))
        .into_iter()
        .filter(|(t, _)| *t < ms(1250))
        .map(|(_, d)| d)
        .collect();
    assert!(
        before
            .iter()
            .any(|d| d.axis == 0 && !d.forward && d.velocity == 27_243)
    );
    // Then only status requests.
    assert!(
        s.frames_since(ms(1900))
            .iter()
            .all(|c| *c == Command::SysStatusRequest)
    );
}

#[test]
fn watchdog_zeroes_a_silent_client() {
    let mut s = driving_sim();
    s.at(ms(1000))
        .set_velocity(VelocityCommand::new(0.4, 0.0), ms(1000))
        .unwrap();
    s.run_until(ms(3000));
    assert!(s.events.contains(&Event::CommandTimeout));
    assert_eq!(s.m.target(), VelocityCommand::ZERO);
    let moving_until = s
        .set_dirs_since(ms(1000))
        .iter()
        .filter(|(_, d)| d.velocity != 0)
        .map(|(t, _)| *t)
        .max()
        .unwrap();
    assert!(moving_until < ms(1500), "moved until {moving_until:?}");
    assert!(
        s.set_dirs_since(ms(1500))
            .iter()
            .any(|(_, d)| d.velocity == 0)
    );
}

#[test]
fn pacing_holds_under_a_burst() {
    let mut s = driving_sim();
    let t = ms(1000);
    s.at(t).set_sonar(false, t).unwrap();
    s.m.set_sonar(true, t).unwrap();
    s.m.enable_motors(true, t).unwrap();
    s.m.set_velocity(VelocityCommand::new(0.1, 0.1), t).unwrap();
    // At a single instant, only one frame may leave.
    s.drain();
    assert_eq!(s.frames_since(t).len(), 1);
    let mut buf = [0u8; TX_BUF];
    assert_eq!(s.m.poll_transmit(&mut buf), None);
    s.run_until(ms(1100));
    let times: Vec<Instant> = s.sent.iter().map(|(t, _)| *t).collect();
    for w in times.windows(2) {
        assert!(w[1].saturating_duration_since(w[0]) >= Duration::from_millis(5));
    }
    assert!(s.frames_since(t).len() >= 6);
}

#[test]
fn shutdown_sequence() {
    let mut s = driving_sim();
    s.at(ms(1000))
        .set_velocity(VelocityCommand::new(0.3, 0.0), ms(1000))
        .unwrap();
    s.at(ms(1200)).shutdown(ms(1200));
    assert_eq!(s.m.phase(), Phase::ShuttingDown);
    s.run_until(ms(3000));
    let zero = |axis, acceleration, torque| {
        Command::SetDir(SetDir {
            axis,
            velocity: 0,
            acceleration,
            torque,
            forward: true,
        })
    };
    assert_eq!(
        s.frames_since(ms(1201)),
        vec![
            zero(0, 63_567, 30_000),
            zero(1, 100_000, 35_000),
            Command::SonarRun(SonarRun::OFF),
            Command::SetDefaults,
            Command::SystemReportReq {
                period_us: 0,
                mask: 0
            },
            Command::DioReportsReq { period_us: 0 },
            Command::IR_OFF,
            Command::BrakeSet,
        ]
    );
    assert_eq!(s.m.phase(), Phase::Closed);
    assert!(s.events.contains(&Event::ShutdownComplete));
    assert_eq!(s.m.poll_timeout(), None);
    assert_eq!(
        s.m.set_velocity(VelocityCommand::ZERO, ms(3000)),
        Err(CommandError::Closed)
    );
}

#[test]
fn zero_speed_quirk_sends_one() {
    let cfg = Config {
        zero_speed_quirk: true,
        ..Config::default()
    };
    let mut s = Sim::new(cfg);
    s.at(ms(100)).enable_motors(true, ms(100)).unwrap();
    s.at(ms(500)).stop(ms(500)).unwrap();
    s.run_until(ms(700));
    let d = s.set_dirs_since(ms(500));
    assert!(
        d.iter()
            .filter(|(_, d)| d.axis == 0)
            .all(|(_, d)| d.velocity == 1)
    );
    assert!(
        d.iter()
            .filter(|(_, d)| d.axis == 1)
            .all(|(_, d)| d.velocity == 0)
    );
}

#[test]
fn legacy_mode_sends_unstuffed_nudged_frames() {
    let cfg = Config {
        legacy_no_stuff: true,
        ..Config::default()
    };
    let mut s = Sim::new(cfg);
    s.at(ms(100)).enable_motors(true, ms(100)).unwrap();
    s.at(ms(200))
        .set_velocity(VelocityCommand::new(0.0, -7000.0 / 37000.0), ms(200))
        .unwrap();
    s.run_until(ms(260));
    let rot = s
        .set_dirs_since(ms(200))
        .into_iter()
        .find(|(_, d)| d.axis == 1)
        .unwrap()
        .1;
    assert_eq!(rot.velocity, 6911); // 0x1B58 → 0x1AFF
    for (_, w) in &s.wire {
        assert!(!w[2..w.len() - 2].contains(&0x1B), "{w:02X?}");
    }
}

// ---- reports -------------------------------------------------------------------------------

/// The mock's rFLEX base reporting both axes every 100 ms, the counters of `pairs`
/// (`(p0, v0, p1, v1)`, one pair per report) starting at `t0`, into the machine; returns the
/// machine's events.
fn feed_pairs(m: &mut Machine, t0: u64, pairs: &[(i32, i32, i32, i32)]) -> Vec<Event> {
    // The mock's scripted body: its travel and velocity are the counters, in SI units.
    let c = RflexModelConfig::default();
    let mut body = ScriptedBody::default();
    let mut base = RflexRobot::new(RflexModelConfig::default(), &body);
    let mut buf = [0u8; MAX_WIRE_FRAME];
    let n = Command::SystemReportReq {
        period_us: 100_000,
        mask: 3,
    }
    .emit(&mut buf)
    .unwrap();
    // The model's clock: requested at 0, reports at 100, 200, … ms (machine time t0, t0 + 100,
    // … ms).
    base.handle_rx(&buf[..n], Instant::ZERO, &mut body);
    let _ = base.take_output();
    let mut ev = Vec::new();
    for (k, &(p0, v0, p1, v1)) in pairs.iter().enumerate() {
        let t = ms(t0 + 100 * k as u64);
        body.travel = Some((f64::from(p0) / c.kd, f64::from(p1) / c.ka));
        body.velocity = Some((f64::from(v0) / c.kd, f64::from(v1) / c.ka));
        let model_t = ms(100 + 100 * k as u64);
        while let Some(due) = base.poll_timeout().filter(|due| *due <= model_t) {
            base.handle_timeout(due, &mut body);
        }
        let bytes = base.take_output();
        m.handle_bytes(&bytes, t);
        while let Some(e) = m.poll_event() {
            ev.push(e);
        }
    }
    ev
}

fn odometries(ev: &[Event]) -> Vec<ima_hal::base::Odometry> {
    ev.iter()
        .filter_map(|e| match e {
            Event::Odometry(o) => Some(o.value),
            _ => None,
        })
        .collect()
}

#[test]
fn odometry_of_a_one_metre_drive() {
    let mut m = Machine::new(Config::default(), Instant::ZERO);
    // Counters start anywhere (here just below i32::MAX, so they wrap on the way).
    let b0 = i32::MAX - 40_000;
    let pairs: Vec<_> = (0..=10)
        .map(|k| (b0.wrapping_add(9_081 * k), 90_810 / 10 * 10 / 10, 5_000, 0))
        .collect();
    let ev = feed_pairs(&mut m, 1000, &pairs);
    let o = odometries(&ev);
    assert_eq!(o.len(), 11, "the first pair only sets the baseline");
    assert_eq!(o[0].x_m(), 0.0);
    let last = o.last().unwrap();
    assert!((last.x_m() - 1.0).abs() < 1e-9, "x = {}", last.x_m());
    assert!(last.y_m().abs() < 1e-9);
    assert!(last.theta_rad().abs() < 1e-12);
    assert!((last.v_m_s - 0.1).abs() < 1e-9);
}

#[test]
fn odometry_of_a_ninety_degree_turn_then_a_drive() {
    let mut m = Machine::new(Config::default(), Instant::ZERO);
    let quarter = (FRAC_PI_2 * 37_000.0).round() as i32; // 58119
    let mut pairs = Vec::new();
    for k in 0..=10 {
        pairs.push((0, 0, quarter * k / 10, quarter));
    }
    // Then 1 m forward, heading +y.
    for k in 1..=10 {
        pairs.push((9_081 * k, 90_810, quarter, 0));
    }
    let ev = feed_pairs(&mut m, 0, &pairs);
    let o = odometries(&ev);
    let turned = o[10];
    assert!((turned.theta_rad() - FRAC_PI_2).abs() < 1e-4);
    assert!(turned.x_m().abs() < 1e-12 && turned.y_m().abs() < 1e-12);
    assert!((turned.omega_rad_s - quarter as f64 / 37_000.0).abs() < 1e-9);
    let end = o.last().unwrap();
    assert!(end.x_m().abs() < 1e-4, "x = {}", end.x_m());
    assert!((end.y_m() - 1.0).abs() < 1e-4, "y = {}", end.y_m());
    assert_eq!(m.odometry(), *end);
    m.reset_odometry();
    assert_eq!(m.odometry().x_m(), 0.0);
}

#[test]
fn odometry_plausibility_rejects_a_jump() {
    let mut m = Machine::new(Config::default(), Instant::ZERO);
    let ev = feed_pairs(
        &mut m,
        0,
        &[
            (0, 0, 0, 0),
            (9_081, 0, 0, 0),           // +0.1 m in 0.1 s: fine
            (9_081 + 908_100, 0, 0, 0), // +10 m in 0.1 s: rejected
            (18_162, 0, 0, 0),          // +0.1 m from the last good baseline (0.2 s): fine
        ],
    );
    let rejected: Vec<f64> = ev
        .iter()
        .filter_map(|e| match e {
            Event::OdometryRejected { delta_m, .. } => Some(*delta_m),
            _ => None,
        })
        .collect();
    assert_eq!(rejected.len(), 1);
    assert!((rejected[0] - 10.0).abs() < 1e-9);
    let o = odometries(&ev);
    assert_eq!(o.len(), 3);
    assert!((o[2].x_m() - 0.2).abs() < 1e-9);
    assert_eq!(m.stats().odometry_rejected, 1);
}

#[test]
fn persistent_jump_rebaselines_after_three_rejections() {
    let mut m = Machine::new(Config::default(), Instant::ZERO);
    let big = 5_000_000;
    let ev = feed_pairs(
        &mut m,
        0,
        &[
            (0, 0, 0, 0),
            (big, 0, 0, 0),
            (big, 0, 0, 0),
            (big, 0, 0, 0), // third rejection: becomes the baseline
            (big + 9_081, 0, 0, 0),
        ],
    );
    let o = odometries(&ev);
    assert_eq!(o.len(), 2);
    assert!((o[1].x_m() - 0.1).abs() < 1e-9);
}

fn hex(s: &str) -> Vec<u8> {
    s.split_whitespace()
        .map(|b| u8::from_str_radix(b, 16).unwrap())
        .collect()
}

#[test]
fn sensor_reports_become_si_events() {
    let mut m = Machine::new(Config::default(), Instant::ZERO);
    let mut bytes = hex("1B 02 01 07 01 09 00 00 12 36 00 00 0A 46 00 66 1B 03"); // T10
    bytes.extend(hex(
        "1B 02 04 08 02 0E 00 00 00 00 00 00 12 37 00 05 C4 10 02 E2 14 1B 03",
    )); // T11
    bytes.extend(hex("1B 02 05 09 01 07 00 00 12 38 40 00 01 61 1B 03")); // T12
    let mut buf = [0u8; MAX_WIRE_FRAME];
    let n = ima_rflex::wire::encode_frame(
        4,
        8,
        2,
        &[0, 0, 0, 0, 0, 0, 0x12, 0x37, 7, 5, 0xC4],
        Stuffing::Full,
        &mut buf,
    )
    .unwrap();
    bytes.extend(&buf[..n]); // sonar id 7: not in the table
    let t = ms(42);
    m.handle_bytes(&bytes, t);
    let mut ev = Vec::new();
    while let Some(e) = m.poll_event() {
        ev.push(e);
    }
    let mut it = ev.iter();
    assert_eq!(it.next(), Some(&Event::LinkUp));
    match it.next() {
        Some(Event::Power(p)) => {
            assert_eq!(p.at, t);
            assert!((p.value.battery_v - 27.5).abs() < 1e-9);
        }
        e => panic!("{e:?}"),
    }
    assert!(matches!(it.next(), Some(Event::Brake(b)) if !b.value));
    match (it.next(), it.next()) {
        (Some(Event::Sonar(a)), Some(Event::Sonar(b))) => {
            assert_eq!((a.index, b.index), (0, 6));
            assert!((a.range_m - 1.0).abs() < 1e-12);
            assert!((b.range_m - 0.5).abs() < 1e-12);
        }
        e => panic!("{e:?}"),
    }
    match it.next() {
        Some(Event::Bumpers(b)) => {
            assert_eq!((b.value.front, b.value.rear), (1, 0));
            assert!(b.value.any_contact());
        }
        e => panic!("{e:?}"),
    }
    assert!(matches!(
        it.next(),
        Some(Event::UnmappedSonar { id: 7, .. })
    ));
    assert!(it.next().is_none());
    assert_eq!(m.framer_stats().frames, 4);
    assert_eq!(m.transducers().len(), 17);
}

#[test]
fn unknown_and_bad_frames_are_counted_not_fatal() {
    let mut m = Machine::new(Config::default(), Instant::ZERO);
    let mut buf = [0u8; MAX_WIRE_FRAME];
    let n = ima_rflex::wire::encode_frame(6, 1, 1, &[1, 2, 3], Stuffing::Full, &mut buf).unwrap();
    let mut bytes = buf[..n].to_vec(); // IR report: unknown here
    let n = ima_rflex::wire::encode_frame(1, 1, 1, &[1], Stuffing::Full, &mut buf).unwrap();
    bytes.extend(&buf[..n]); // SYS_STATUS with a wrong payload length
    let n = Report::Motion(MotionReport {
        rv: 0,
        ts: 1,
        axis: 0,
        position: 5,
        velocity: 5,
        acceleration: 0,
        torque: 0,
    })
    .emit_with(1, Stuffing::Full, &mut buf)
    .unwrap();
    let mut bad = buf[..n].to_vec();
    let k = bad.len() - 3;
    bad[k] ^= 1; // bad checksum
    bytes.extend(bad);
    let ack = Report::Ack {
        port: 2,
        opcode: 7,
        rv: 0,
        ts: 1,
    };
    let n = ack.emit(&mut buf).unwrap();
    bytes.extend(&buf[..n]);
    m.handle_bytes(&bytes, ms(1));
    assert_eq!(m.poll_event(), Some(Event::LinkUp));
    assert!(matches!(m.poll_event(), Some(Event::Unknown(u)) if u.port == 6));
    assert_eq!(m.poll_event(), None);
    assert_eq!(m.stats().unknown_frames, 1);
    assert_eq!(m.stats().bad_payloads, 1);
    assert_eq!(m.stats().acks, 1);
    assert_eq!(m.framer_stats().bad_checksums, 1);
    let _ = WireError::Truncated;
}

#[test]
fn commands_are_clamped_and_checked() {
    let mut s = driving_sim();
    assert_eq!(
        s.m.set_velocity(VelocityCommand::new(f64::NAN, 0.0), ms(300)),
        Err(CommandError::NotFinite)
    );
    s.at(ms(300))
        .set_velocity(VelocityCommand::new(9.0, -9.0), ms(300))
        .unwrap();
    assert_eq!(s.m.target(), VelocityCommand::new(1.0, -1.5));
    s.run_until(ms(330));
    let d = s.set_dirs_since(ms(300));
    assert_eq!(d[0].1.velocity, 90_810);
    assert_eq!(d[1].1.velocity, 55_500);
    assert!(!d[1].1.forward);
}

#[test]
fn disabling_motors_zeroes_then_brakes() {
    let mut s = driving_sim();
    s.at(ms(1000))
        .set_velocity(VelocityCommand::new(0.3, 0.0), ms(1000))
        .unwrap();
    s.at(ms(1100)).enable_motors(false, ms(1100)).unwrap();
    s.run_until(ms(1400));
    let after = s.frames_since(ms(1101));
    assert!(matches!(after[0], Command::SetDir(d) if d.axis == 0 && d.velocity == 0));
    assert!(matches!(after[1], Command::SetDir(d) if d.axis == 1 && d.velocity == 0));
    assert_eq!(after[2], Command::BrakeSet);
    assert_eq!(after[3], Command::SysStatusRequest);
    assert_eq!(after.len(), 4, "no keep-alive once braked: {after:?}");
}

#[test]
fn link_lost_and_regained() {
    let mut s = Sim::new(Config::default());
    s.run_until(ms(999));
    assert!(!s.events.contains(&Event::LinkLost));
    s.run_until(ms(1000));
    assert_eq!(s.events.last(), Some(&Event::LinkLost));
    assert_eq!(s.m.link_up(), Some(false));
    s.run_until(ms(1500));
    assert_eq!(
        s.events.iter().filter(|e| **e == Event::LinkLost).count(),
        1
    );
    s.m.handle_bytes(
        &hex("1B 02 01 07 01 09 00 00 12 36 00 00 0A 46 00 66 1B 03"),
        ms(1500),
    );
    s.drain();
    assert!(s.events.contains(&Event::LinkUp));
    assert_eq!(s.m.link_up(), Some(true));
    // Frames every 400 ms keep it up.
    for k in 1..5 {
        s.run_until(ms(1500 + 400 * k));
        s.m.handle_bytes(
            &hex("1B 02 05 09 01 07 00 00 12 38 40 00 01 61 1B 03"),
            ms(1500 + 400 * k),
        );
    }
    s.run_until(ms(3400));
    assert_eq!(
        s.events.iter().filter(|e| **e == Event::LinkLost).count(),
        1
    );
    s.run_until(ms(4500));
    assert_eq!(
        s.events.iter().filter(|e| **e == Event::LinkLost).count(),
        2
    );
}

#[test]
fn recovery_resends_the_init_every_link_timeout_until_a_motion_report() {
    // Sonar off at start, then asked for: the re-initialisation restarts it.
    let cfg = Config {
        recover: true,
        sonar_at_start: false,
        ..Config::default()
    };
    let mut s = Sim::new(cfg.clone());
    s.run_until(ms(200));
    s.m.set_sonar(true, ms(200)).unwrap();
    s.run_until(ms(999));
    assert!(
        s.frames_since(ms(300))
            .iter()
            .all(|c| *c != Command::SetDefaults)
    );
    // Lost at 1 s: the init goes out at once, then again a link timeout later.
    s.run_until(ms(1100));
    let again = s.frames_since(ms(1000));
    assert_eq!(again.len(), init_frames(&cfg).len(), "{again:?}");
    assert!(again.contains(&Command::SonarRun(SonarRun::ON)));
    s.run_until(ms(2100));
    assert_eq!(
        s.frames_since(ms(1100))
            .iter()
            .filter(|c| **c == Command::SetDefaults)
            .count(),
        1
    );
    // Motion reports again: no more re-initialisation (until the next loss, 1 s after the
    // last report).
    feed_pairs(&mut s.m, 2150, &[(0, 0, 0, 0), (9_081, 0, 0, 0)]);
    s.run_until(ms(3200));
    assert!(
        s.frames_since(ms(2200))
            .iter()
            .all(|c| *c != Command::SetDefaults)
    );
}

#[test]
fn reinitialize_resends_init_keeps_the_pose_and_rebaselines() {
    let mut s = Sim::new(Config::default());
    s.run_until(ms(200));
    // Drive 1 m on odometry, with motors enabled.
    s.m.enable_motors(true, ms(200)).unwrap();
    s.run_until(ms(300));
    let pairs: Vec<_> = (0..=10).map(|k| (9_081 * k, 0, 0, 0)).collect();
    let ev = feed_pairs(&mut s.m, 300, &pairs);
    assert!((odometries(&ev).last().unwrap().x_m() - 1.0).abs() < 1e-9);
    // The base was power-cycled: re-initialise.
    let t = ms(2500);
    s.run_until(t);
    s.m.reinitialize(false, t);
    s.run_until(ms(2700));
    let mut expect = init_frames(&Config::default());
    // The brake is released again (motors were enabled), before SONAR_RUN.
    let at = expect.len() - 2;
    expect.insert(at, Command::BrakeRelease);
    // Zero SET_DIRs carry the driving torques (set_dir_pair), not the init's zero torque.
    let got = s.frames_since(t);
    assert_eq!(got.len(), expect.len(), "{got:?}");
    for (g, e) in got.iter().zip(&expect) {
        match (g, e) {
            (Command::SetDir(a), Command::SetDir(b)) => {
                assert_eq!((a.axis, a.velocity), (b.axis, b.velocity));
            }
            _ => assert_eq!(g, e),
        }
    }
    // Counters restarted at 0: the first pair is a new baseline, the pose is kept.
    let ev = feed_pairs(&mut s.m, 2800, &[(0, 0, 0, 0), (9_081, 0, 0, 0)]);
    let o = odometries(&ev);
    assert_eq!(o.len(), 2);
    assert!((o[0].x_m() - 1.0).abs() < 1e-9);
    assert!((o[1].x_m() - 1.1).abs() < 1e-9);
    assert_eq!(s.m.stats().odometry_rejected, 0);
}

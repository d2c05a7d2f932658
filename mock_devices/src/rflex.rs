//! The base side of rFLEX: an ATRV-Jr's controller as a sans-IO model (spec §8).
//!
//! [`RflexRobot`] reads host commands with `ima_rflex`'s strict framer and `wire` module (so
//! both sides share one framing implementation) and follows the *base's* rules of §8:
//!
//! * brake engaged at power-up; while it is engaged, SET_DIR is stored but nothing moves;
//! * SET_DIR sets a signed target per axis (units/s); the axis ramps toward it at the
//!   commanded acceleration (units/s²) on a [`RflexModelConfig::control_period`] tick;
//!   positions are i32 and wrap;
//! * the fail-safe: no SET_DIR for [`RflexModelConfig::failsafe`] (default 1.0 s \[I\]) sets
//!   both targets to 0;
//! * MOT_SYSTEM_REPORT_REQ: one motion report per mask bit every `period` µs, axis 0 first;
//! * SYS_STATUS replies with a configurable raw voltage and the brake byte;
//! * SONAR_RUN mode 2: one reading per [`RflexModelConfig::sonar_period`] (≈ 40 ms \[I\]),
//!   cycling the configured ids, sent in SONAR_REPORT frames of ≤ 6 triples; mode 0 stops;
//! * DIO_REPORT (address 0x40, front = bit 0, rear = bit 1) on every bumper change once DIO
//!   reports are on;
//! * acks (`rv ts`) on SET_DIR and DIO_REPORTS_REQ, switchable because they are only \[D\];
//! * packet ids count up per frame sent and wrap; timestamps are u32 ticks at 250 Hz \[I\];
//! * all output is stuffed; `7C → 7C 1B 01` is a switch (default on) to exercise the driver.
//!
//! Odometry: the reported axis positions come from the body's true motion (mean wheel travel
//! for axis 0, wheel travel difference over the track for axis 1), scaled by Kd and Ka, so the
//! host's odometry can be checked against the world. The four-wheel skid steer is modelled as
//! a differential drive (the world's robot).

use std::time::Duration;

use ima_hal::Instant;

use crate::body::{DiffDriveBody, WorldBody};
use ima_rflex::framer::{Framer, FramerConfig};
use ima_rflex::machine::SonarMount;
use ima_rflex::wire::{
    Command, DIO_BUMPER_ADDRESS, DioReport, MAX_WIRE_FRAME, MotionReport, Report, SonarEcho,
    SonarReport, Stuffing,
};

/// How the model behaves.
#[derive(Debug, Clone)]
pub struct RflexModelConfig {
    /// Translation units per metre (the controller's own scale, §4).
    pub kd: f64,
    /// Rotation units per radian.
    pub ka: f64,
    /// Raw battery voltage in SYS_STATUS (volts = raw / 100 + 1.2 on the host).
    pub voltage_raw: u32,
    /// Fail-safe: no SET_DIR for this long stops both axes (§8, default 1 s \[I\]).
    pub failsafe: Duration,
    /// Ramp/integration tick.
    pub control_period: Duration,
    /// One sonar reading per this period (§8, ≈ 40 ms \[I\]).
    pub sonar_period: Duration,
    /// Readings per SONAR_REPORT frame (1–6).
    pub echoes_per_frame: usize,
    /// The sonar table (ids cycled in this order, poses for ray casting).
    pub sonar_table: Vec<SonarMount>,
    /// Raw range sent for "no echo".
    pub no_echo_raw: u16,
    /// Sonar units per metre (1476, §3).
    pub sonar_units_per_m: f64,
    /// Answer SET_DIR and DIO_REPORTS_REQ with `rv ts` acks (\[D\]).
    pub acks: bool,
    /// Stuff 0x7C as `7C 1B 01` (default on, §8).
    pub stuff_pipe: bool,
    /// Read unstuffed legacy commands (ESC + other byte = literal), §8 `lenient`.
    pub lenient: bool,
}

impl Default for RflexModelConfig {
    fn default() -> Self {
        Self {
            kd: 90_810.0,
            ka: 37_000.0,
            voltage_raw: 2630,
            failsafe: Duration::from_secs(1),
            control_period: Duration::from_millis(10),
            sonar_period: Duration::from_millis(40),
            echoes_per_frame: 6,
            sonar_table: SonarMount::atrv_jr_default().into_iter().collect(),
            no_echo_raw: 32_766,
            sonar_units_per_m: 1476.0,
            acks: true,
            stuff_pipe: true,
            lenient: false,
        }
    }
}

/// Counters of the model.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RflexModelStats {
    /// Commands executed.
    pub commands: u64,
    /// Frames rejected by the framer or the parser.
    pub bad_frames: u64,
    /// Frames sent.
    pub frames_sent: u64,
    /// Motion reports sent.
    pub motion_reports: u64,
    /// SET_DIR frames received.
    pub set_dirs: u64,
    /// SET_DIR frames received while the brake was engaged.
    pub set_dirs_braked: u64,
    /// Fail-safe trips.
    pub failsafe_trips: u64,
    /// Power cycles.
    pub resets: u64,
}

#[derive(Debug, Clone, Copy, Default)]
struct Axis {
    /// Signed target, units/s.
    target: f64,
    /// Ramped setpoint, units/s.
    current: f64,
    /// Acceleration, units/s².
    accel: f64,
}

/// The rFLEX controller model. See the [module docs](self).
#[derive(Debug)]
pub struct RflexRobot {
    cfg: RflexModelConfig,
    framer: Framer,
    out: Vec<u8>,
    stats: RflexModelStats,
    brake: bool,
    axes: [Axis; 2],
    last_set_dir: Option<Instant>,
    tripped: bool,
    last_tick: Option<Instant>,
    next_tick: Option<Instant>,
    report: Option<(Duration, u32)>,
    next_report: Option<Instant>,
    sonar_on: bool,
    next_ping: Option<Instant>,
    ping_slot: usize,
    pending_echoes: Vec<SonarEcho>,
    dio_on: bool,
    last_bumpers: (bool, bool),
    packet_id: u8,
    epoch: Option<Instant>,
    now: Instant,
    origin: (f64, f64),
}

impl RflexRobot {
    /// A powered-up controller (brake engaged, reports off) whose counters start at `body`'s
    /// travel now.
    pub fn new(cfg: RflexModelConfig, body: &dyn DiffDriveBody) -> Self {
        let framer = Framer::new(FramerConfig {
            lenient: cfg.lenient,
            ..FramerConfig::default()
        });
        Self {
            cfg,
            framer,
            out: Vec::new(),
            stats: RflexModelStats::default(),
            brake: true,
            axes: [Axis::default(); 2],
            last_set_dir: None,
            tripped: false,
            last_tick: None,
            next_tick: None,
            report: None,
            next_report: None,
            sonar_on: false,
            next_ping: None,
            ping_slot: 0,
            pending_echoes: Vec::new(),
            dio_on: false,
            last_bumpers: body.bumpers(),
            packet_id: 0,
            epoch: None,
            now: Instant::ZERO,
            origin: body.travel(),
        }
    }

    /// The configuration.
    pub fn config(&self) -> &RflexModelConfig {
        &self.cfg
    }

    /// Counters.
    pub fn stats(&self) -> RflexModelStats {
        self.stats
    }

    /// Whether the brake is engaged (motors disabled).
    pub fn brake_engaged(&self) -> bool {
        self.brake
    }

    /// The signed targets (units/s) of axis 0 and 1.
    pub fn targets(&self) -> (f64, f64) {
        (self.axes[0].target, self.axes[1].target)
    }

    /// Power-cycle: brake on, everything off, counters restart from zero.
    pub fn reset(&mut self, body: &mut dyn DiffDriveBody) {
        let stats = RflexModelStats {
            resets: self.stats.resets.saturating_add(1),
            ..self.stats
        };
        let cfg = self.cfg.clone();
        body.drive(0.0, 0.0);
        *self = Self::new(cfg, body);
        self.stats = stats;
    }

    /// Bytes that are ready to go to the host.
    pub fn take_output(&mut self) -> Vec<u8> {
        std::mem::take(&mut self.out)
    }

    fn ts(&self) -> u32 {
        let since = self
            .epoch
            .map_or(Duration::ZERO, |e| self.now.saturating_duration_since(e));
        // 250 Hz ticks, wrapping u32.
        (since.as_millis() / 4) as u32
    }

    fn send(&mut self, r: &Report) {
        let mut buf = [0u8; MAX_WIRE_FRAME];
        let stuffing = if self.cfg.stuff_pipe {
            Stuffing::Full
        } else {
            Stuffing::EscOnly
        };
        if let Ok(n) = r.emit_with(self.packet_id, stuffing, &mut buf) {
            self.out.extend_from_slice(buf.get(..n).unwrap_or(&[]));
            self.packet_id = self.packet_id.wrapping_add(1);
            self.stats.frames_sent = self.stats.frames_sent.saturating_add(1);
        }
    }

    /// Bytes from the host.
    pub fn handle_rx(&mut self, bytes: &[u8], now: Instant, body: &mut dyn DiffDriveBody) {
        self.advance(now, body);
        let mut cmds = Vec::new();
        let mut bad = 0u64;
        self.framer.bytes_arrived(now);
        self.framer.push(bytes, |item| match item {
            Ok(raw) => match Command::from_raw(&raw) {
                Ok(c) => cmds.push(c),
                Err(_) => bad += 1,
            },
            Err(_) => bad += 1,
        });
        self.stats.bad_frames = self.stats.bad_frames.saturating_add(bad);
        for c in cmds {
            self.execute(c, body);
        }
    }

    fn execute(&mut self, c: Command, body: &mut dyn DiffDriveBody) {
        self.stats.commands = self.stats.commands.saturating_add(1);
        let now = self.now;
        match c {
            Command::SysStatusRequest => {
                let r = Report::SysStatus {
                    ts: self.ts(),
                    voltage_raw: self.cfg.voltage_raw,
                    brake_engaged: self.brake,
                };
                self.send(&r);
            }
            Command::SetDir(s) => {
                self.stats.set_dirs = self.stats.set_dirs.saturating_add(1);
                if self.brake {
                    self.stats.set_dirs_braked = self.stats.set_dirs_braked.saturating_add(1);
                }
                let sign = if s.forward { 1.0 } else { -1.0 };
                if let Some(a) = self.axes.get_mut(usize::from(s.axis)) {
                    a.target = sign * f64::from(s.velocity);
                    a.accel = f64::from(s.acceleration);
                }
                self.last_set_dir = Some(now);
                self.tripped = false;
                if self.cfg.acks {
                    let r = Report::Ack {
                        port: ima_rflex::wire::port::MOT,
                        opcode: ima_rflex::wire::op::MOT_AXIS_SET_DIR,
                        rv: 0,
                        ts: self.ts(),
                    };
                    self.send(&r);
                }
            }
            Command::SetDefaults => {
                for a in &mut self.axes {
                    a.target = 0.0;
                }
            }
            Command::BrakeSet => {
                self.brake = true;
                for a in &mut self.axes {
                    a.target = 0.0;
                    a.current = 0.0;
                }
                body.drive(0.0, 0.0);
            }
            Command::BrakeRelease => self.brake = false,
            Command::SystemReportReq { period_us, mask } => {
                if period_us == 0 || mask & 3 == 0 {
                    self.report = None;
                    self.next_report = None;
                } else {
                    let p = Duration::from_micros(u64::from(period_us.max(1000)));
                    self.report = Some((p, mask));
                    self.next_report = Some(now + p);
                }
            }
            Command::SonarRun(r) => {
                self.sonar_on = r.mode == 2;
                self.next_ping = self.sonar_on.then(|| now + self.cfg.sonar_period);
                self.pending_echoes.clear();
            }
            Command::DioReportsReq { period_us } => {
                self.dio_on = period_us != 0;
                self.last_bumpers = body.bumpers();
                if self.cfg.acks {
                    let r = Report::Ack {
                        port: ima_rflex::wire::port::DIO,
                        opcode: ima_rflex::wire::op::DIO_REPORTS_REQ,
                        rv: 0,
                        ts: self.ts(),
                    };
                    self.send(&r);
                }
            }
            Command::JoystickRequest => {
                let r = Report::Joystick {
                    ts: self.ts(),
                    x: 0,
                    y: 0,
                    buttons: 0,
                };
                self.send(&r);
            }
            Command::IrRun { .. } | Command::Unknown(_) => {}
        }
    }

    fn advance(&mut self, now: Instant, body: &mut dyn DiffDriveBody) {
        if self.epoch.is_none() {
            self.epoch = Some(now);
            self.next_tick = Some(now + self.cfg.control_period);
            self.last_tick = Some(now);
        }
        if now > self.now {
            self.now = now;
        }
        // Fail-safe.
        if let Some(t) = self.last_set_dir
            && !self.tripped
            && now.saturating_duration_since(t) >= self.cfg.failsafe
        {
            self.tripped = true;
            let moving = self.axes.iter().any(|a| a.target != 0.0);
            for a in &mut self.axes {
                a.target = 0.0;
            }
            if moving {
                self.stats.failsafe_trips = self.stats.failsafe_trips.saturating_add(1);
            }
        }
        let _ = body;
    }

    /// The earliest instant the model wants [`RflexRobot::handle_timeout`].
    pub fn poll_timeout(&self) -> Option<Instant> {
        let mut t = self.next_tick;
        for x in [self.next_report, self.next_ping].into_iter().flatten() {
            t = Some(t.map_or(x, |t| t.min(x)));
        }
        if let Some(s) = self.last_set_dir
            && !self.tripped
        {
            let x = s + self.cfg.failsafe;
            t = Some(t.map_or(x, |t| t.min(x)));
        }
        t
    }

    /// Timers: ramp, reports, sonar, bumpers.
    pub fn handle_timeout(&mut self, now: Instant, body: &mut dyn DiffDriveBody) {
        self.advance(now, body);
        if self.next_tick.is_some_and(|t| now >= t) {
            let dt = self
                .last_tick
                .map_or(0.0, |l| now.saturating_duration_since(l).as_secs_f64());
            self.last_tick = Some(now);
            self.next_tick = Some(now + self.cfg.control_period);
            let brake = self.brake;
            for a in &mut self.axes {
                let target = if brake { 0.0 } else { a.target };
                let step = a.accel.max(0.0) * dt;
                let diff = target - a.current;
                a.current = if diff.abs() <= step {
                    target
                } else {
                    a.current + step.copysign(diff)
                };
            }
            body.drive(
                self.axes[0].current / self.cfg.kd,
                self.axes[1].current / self.cfg.ka,
            );
            let b = body.bumpers();
            if b != self.last_bumpers {
                self.last_bumpers = b;
                if self.dio_on {
                    let data = u16::from(b.0) | (u16::from(b.1) << 1);
                    let r = Report::Dio(DioReport {
                        ts: self.ts(),
                        address: DIO_BUMPER_ADDRESS,
                        data,
                    });
                    self.send(&r);
                }
            }
        }
        if let (Some(t), Some((period, mask))) = (self.next_report, self.report)
            && now >= t
        {
            let mut next = t + period;
            if next <= now {
                next = now + period;
            }
            self.next_report = Some(next);
            let (d, th) = body.travel();
            let (v, w) = body.velocity();
            let pos = [
                wrap_i32((d - self.origin.0) * self.cfg.kd),
                wrap_i32((th - self.origin.1) * self.cfg.ka),
            ];
            let vel = [wrap_i32(v * self.cfg.kd), wrap_i32(w * self.cfg.ka)];
            for axis in 0..2u8 {
                if mask & (1 << axis) == 0 {
                    continue;
                }
                let i = usize::from(axis);
                let r = Report::Motion(MotionReport {
                    rv: 0,
                    ts: self.ts(),
                    axis,
                    position: pos.get(i).copied().unwrap_or(0),
                    velocity: vel.get(i).copied().unwrap_or(0),
                    acceleration: 0,
                    torque: 0,
                });
                self.send(&r);
                self.stats.motion_reports = self.stats.motion_reports.saturating_add(1);
            }
        }
        if let Some(t) = self.next_ping
            && now >= t
            && self.sonar_on
        {
            let mut next = t + self.cfg.sonar_period;
            if next <= now {
                next = now + self.cfg.sonar_period;
            }
            self.next_ping = Some(next);
            let n = self.cfg.sonar_table.len();
            if n > 0 {
                let slot = self.ping_slot % n;
                self.ping_slot = slot.wrapping_add(1);
                if let Some(m) = self.cfg.sonar_table.get(slot).copied() {
                    let raw = body
                        .sonar_range_m(&m.pose)
                        .map_or(self.cfg.no_echo_raw, |r| {
                            let x = (r * self.cfg.sonar_units_per_m).round();
                            if x.is_finite() && x >= 0.0 {
                                (x as u16).min(self.cfg.no_echo_raw)
                            } else {
                                self.cfg.no_echo_raw
                            }
                        });
                    self.pending_echoes.push(SonarEcho {
                        id: m.id,
                        range: raw,
                    });
                }
                if self.pending_echoes.len() >= self.cfg.echoes_per_frame.clamp(1, 6) {
                    let mut echoes = heapless::Vec::new();
                    for e in self.pending_echoes.drain(..) {
                        let _ = echoes.push(e);
                    }
                    let r = Report::Sonar(SonarReport {
                        rv: 0,
                        ts: self.ts(),
                        echoes,
                    });
                    self.send(&r);
                }
            }
        }
    }
}

fn wrap_i32(x: f64) -> i32 {
    if !x.is_finite() {
        return 0;
    }
    // Wrap like the controller's 32-bit counters.
    let r = x.round().rem_euclid(4_294_967_296.0);
    (r as u64 as u32) as i32
}

/// The rFLEX controller on a world robot, ready for a runner ([`crate::pty::PtyDevice`],
/// [`crate::duplex::DuplexDevice`]).
#[derive(Debug)]
pub struct RflexDevice {
    robot: RflexRobot,
    body: WorldBody,
    /// Power-cycle the controller when a hung-up link comes back (default: the cable was
    /// pulled and replugged, so the controller kept its state).
    pub reset_on_reconnect: bool,
}

impl RflexDevice {
    /// The controller `cfg` driving `body`.
    pub fn new(cfg: RflexModelConfig, body: WorldBody) -> Self {
        let robot = RflexRobot::new(cfg, &body);
        Self {
            robot,
            body,
            reset_on_reconnect: false,
        }
    }

    /// The controller model (state, counters).
    pub fn robot(&self) -> &RflexRobot {
        &self.robot
    }
}

impl crate::model::DeviceModel for RflexDevice {
    fn handle_rx(&mut self, bytes: &[u8], now: Instant) {
        self.robot.handle_rx(bytes, now, &mut self.body);
    }

    fn poll_tx(&mut self, out: &mut Vec<u8>) {
        out.extend(self.robot.take_output());
    }

    fn poll_timeout(&self) -> Option<Instant> {
        self.robot.poll_timeout()
    }

    fn handle_timeout(&mut self, now: Instant) {
        self.robot.handle_timeout(now, &mut self.body);
    }

    fn on_reconnect(&mut self, _now: Instant) {
        if self.reset_on_reconnect {
            self.robot.reset(&mut self.body);
        }
    }

    fn name(&self) -> &str {
        "rflex"
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::body::ScriptedBody;
    use ima_rflex::wire::SetDir;

    /// An ideal body (it moves at the command) whose sonars all see 1 m.
    fn toy() -> ScriptedBody {
        ScriptedBody {
            sonar_m: Some(1.0),
            ..ScriptedBody::default()
        }
    }

    fn cmd(c: Command) -> Vec<u8> {
        let mut b = [0u8; MAX_WIRE_FRAME];
        let n = c.emit(&mut b).unwrap();
        b[..n].to_vec()
    }

    fn reports(bytes: &[u8]) -> Vec<Report> {
        let mut f = Framer::strict();
        let mut v = Vec::new();
        f.push(bytes, |i| v.push(Report::from_raw(&i.unwrap()).unwrap()));
        v
    }

    fn run(r: &mut RflexRobot, b: &mut ScriptedBody, from: u64, to: u64) {
        let mut t = from;
        while t <= to {
            r.handle_timeout(Instant::from_millis(t), b);
            t += 1;
        }
    }

    fn set_dir(axis: u8, velocity: u32, forward: bool) -> Command {
        Command::SetDir(SetDir {
            axis,
            velocity,
            acceleration: 90_810,
            torque: 0,
            forward,
        })
    }

    #[test]
    fn brake_holds_until_released_then_ramps_at_the_commanded_acceleration() {
        let mut b = toy();
        let mut r = RflexRobot::new(RflexModelConfig::default(), &b);
        assert!(r.brake_engaged());
        r.handle_rx(&cmd(set_dir(0, 45_405, true)), Instant::ZERO, &mut b);
        run(&mut r, &mut b, 0, 300);
        assert_eq!(b.drive.0, 0.0, "braked robot moved");
        r.handle_rx(
            &cmd(Command::BrakeRelease),
            Instant::from_millis(300),
            &mut b,
        );
        r.handle_rx(
            &cmd(set_dir(0, 45_405, true)),
            Instant::from_millis(300),
            &mut b,
        );
        run(&mut r, &mut b, 301, 550);
        // 1 m/s² for 0.25 s → 0.25 m/s (target 0.5).
        assert!((b.drive.0 - 0.25).abs() < 0.02, "{}", b.drive.0);
        run(&mut r, &mut b, 551, 900);
        assert!((b.drive.0 - 0.5).abs() < 1e-9);
        // Fail-safe 1 s after the last SET_DIR: target 0, ramp down.
        run(&mut r, &mut b, 901, 1900);
        assert_eq!(r.targets().0, 0.0);
        assert_eq!(r.stats().failsafe_trips, 1);
        assert!(b.drive.0 < 0.5);
        run(&mut r, &mut b, 1901, 2500);
        assert_eq!(b.drive.0, 0.0);
    }

    #[test]
    fn reports_status_sonar_and_bumpers() {
        let mut b = toy();
        let mut r = RflexRobot::new(RflexModelConfig::default(), &b);
        let t0 = Instant::ZERO;
        r.handle_rx(
            &cmd(Command::SystemReportReq {
                period_us: 100_000,
                mask: 3,
            }),
            t0,
            &mut b,
        );
        r.handle_rx(
            &cmd(Command::DioReportsReq { period_us: 100_000 }),
            t0,
            &mut b,
        );
        r.handle_rx(
            &cmd(Command::SonarRun(ima_rflex::wire::SonarRun::ON)),
            t0,
            &mut b,
        );
        r.handle_rx(&cmd(Command::SysStatusRequest), t0, &mut b);
        b.travel = Some((1.0, 0.5));
        run(&mut r, &mut b, 0, 250);
        b.bumpers = (true, false);
        run(&mut r, &mut b, 251, 300);
        let out = reports(&r.take_output());
        let motion: Vec<_> = out
            .iter()
            .filter_map(|x| match x {
                Report::Motion(m) => Some(*m),
                _ => None,
            })
            .collect();
        assert_eq!(motion.len(), 6, "3 periods × 2 axes");
        assert_eq!(motion[0].axis, 0);
        assert_eq!(motion[1].axis, 1);
        assert_eq!(motion[0].position, 90_810);
        assert_eq!(motion[1].position, 18_500);
        assert!(out.iter().any(|x| matches!(
            x,
            Report::SysStatus {
                voltage_raw: 2630,
                brake_engaged: true,
                ..
            }
        )));
        let sonar: Vec<_> = out
            .iter()
            .filter_map(|x| match x {
                Report::Sonar(s) => Some(s.clone()),
                _ => None,
            })
            .collect();
        assert_eq!(
            sonar.len(),
            1,
            "6 readings at 40 ms in 300 ms → one frame of 6"
        );
        assert_eq!(sonar[0].echoes.len(), 6);
        assert_eq!(sonar[0].echoes[0].range, 1476);
        assert!(out.iter().any(|x| matches!(
            x,
            Report::Dio(DioReport {
                address: 0x40,
                data: 1,
                ..
            })
        )));
    }

    #[test]
    fn pipe_bytes_are_stuffed_with_the_7c_rule() {
        let mut b = toy();
        let mut r = RflexRobot::new(RflexModelConfig::default(), &b);
        r.handle_rx(
            &cmd(Command::SystemReportReq {
                period_us: 100_000,
                mask: 1,
            }),
            Instant::ZERO,
            &mut b,
        );
        b.travel = Some((f64::from(0x7C7C_i32) / 90_810.0, 0.0));
        run(&mut r, &mut b, 0, 100);
        let out = r.take_output();
        assert!(out.windows(3).any(|w| w == [0x7C, 0x1B, 0x01]));
        let got = reports(&out);
        assert!(
            got.iter()
                .any(|x| matches!(x, Report::Motion(m) if m.position == 0x7C7C))
        );
    }

    #[test]
    fn lenient_mode_reads_unstuffed_legacy_commands() {
        // T5 in its logical (unstuffed) form: ESC followed by 0x58 inside the frame.
        let t5: [u8; 23] = [
            0x1B, 0x02, 0x02, 0x00, 0x07, 0x0E, 0x01, 0x00, 0x00, 0x1B, 0x58, 0x00, 0x01, 0x86,
            0xA0, 0x00, 0x00, 0x88, 0xB8, 0x00, 0x5E, 0x1B, 0x03,
        ];
        for lenient in [false, true] {
            let mut b = toy();
            let cfg = RflexModelConfig {
                lenient,
                ..RflexModelConfig::default()
            };
            let mut r = RflexRobot::new(cfg, &b);
            r.handle_rx(&t5, Instant::ZERO, &mut b);
            assert_eq!(r.stats().set_dirs, u64::from(lenient));
            if lenient {
                assert_eq!(r.targets().1, -7000.0);
            } else {
                assert_eq!(r.stats().bad_frames, 1);
            }
        }
    }

    #[test]
    fn world_body_feels_a_wall_at_the_front_bumper_and_measures_travel() {
        use crate::world::{RobotSpec, SharedWorld, Wall, World};
        let mut w = World::new();
        let mut spec = RobotSpec::new("scooter", 0.0, 0.0, 0.0);
        spec.radius_m = 0.4;
        spec.track_width_m = 0.42;
        let id = w.add_robot(spec).unwrap();
        w.add_wall(Wall {
            from: [1.0, -5.0],
            to: [1.0, 5.0],
        })
        .unwrap();
        let world = SharedWorld::new(w);
        let mut body = WorldBody::new(world.clone(), id, 1);
        assert_eq!(body.bumpers(), (false, false));
        let m = SonarMount::atrv_jr_default()[0];
        let r = body.sonar_range_m(&m.pose).unwrap();
        assert!((r - 0.6).abs() < 0.05, "{r}");
        body.drive(0.5, 0.0);
        for _ in 0..120 {
            world.with(|w| w.step(Duration::from_millis(10)));
        }
        let (d, th) = body.travel();
        let (x, _, _) = body.pose();
        assert!((d - x).abs() < 1e-9 && th.abs() < 1e-9, "{d} {x} {th}");
        assert!(x > 0.58, "{x}");
        assert_eq!(body.bumpers(), (true, false));
    }

    #[test]
    fn bad_frames_are_dropped_silently() {
        let mut b = toy();
        let mut r = RflexRobot::new(RflexModelConfig::default(), &b);
        let mut f = cmd(Command::SysStatusRequest);
        let k = f.len() - 3;
        f[k] ^= 0x55;
        r.handle_rx(&f, Instant::ZERO, &mut b);
        assert_eq!(r.stats().bad_frames, 1);
        assert!(r.take_output().is_empty());
    }
}

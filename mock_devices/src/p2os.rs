//! The robot side of P2OS: a Pioneer 2-AT's firmware as a sans-IO model (spec §5.2).
//!
//! [`P2osRobot`] parses host commands with `ima_p2os::wire` (so both sides share one framing
//! implementation) but follows the *robot's* rules from the spec, not the driver's:
//! idle → synced → open, the SYNC/PULSE byte aliasing, SIPs every cycle carrying the sonar
//! readings fired at 25 Hz per array, motors disabled until ENABLE, the 2 s watchdog with its
//! resume behaviour, CLOSE, CONFIG and ENCODER packets, and the serial line speed.
//!
//! # Line speed and HOSTBAUD
//!
//! The robot powers up at [`P2osModelConfig::baud`]. When CONFIG advertises `ResetBaud = 2`
//! ([`P2osModelConfig::reset_baud`], the default), HOSTBAUD (#50, argument 0..4 = 9600..115200,
//! spec §1) on an open session switches the robot's port at once: the packets after it (the
//! next SIP) go at the new rate, and what the host sends at the old rate is noise, as on a real
//! line (the runner reports the host's rate through [`P2osRobot::set_host_baud`]). ARIA sends
//! PULSE at the new rate and gives up after ~900 ms without a packet; the model keeps the new
//! rate until CLOSE or a power cycle, which put the port back at the power-up rate (ARIA
//! resets its own port to the start rate after CLOSE). An argument outside 0..4, or any
//! HOSTBAUD when `ResetBaud` is not 2, is ignored. Switches are counted in
//! [`P2osModelStats::baud_switches`].
//!
//! It moves a [`DiffDriveBody`] — the simulated world's robot ([`WorldBody`]), or anything
//! else — and reads back the body's motion and sonar ranges.

use std::time::Duration;

use ima_hal::Instant;

use crate::body::{DiffDriveBody, WorldBody};
use ima_p2os::framer::{FrameEvent, Framer};
use ima_p2os::params::{P2AT, RobotParams};
use ima_p2os::wire::{self, Command, ConfigNumbers, IntCommand, Packet, Sip, SonarRaw};

/// How the model behaves.
#[derive(Debug, Clone)]
pub struct P2osModelConfig {
    /// Robot name in the SYNC2 reply and CONFIG.
    pub name: String,
    /// Class string.
    pub class: String,
    /// Subclass string (selects the driver's parameters).
    pub subclass: String,
    /// Parameter table the firmware uses for its units.
    pub params: RobotParams,
    /// The robot's serial rate. The model ignores traffic when the host's line is set to
    /// another rate (see [`P2osRobot::set_host_baud`]).
    pub baud: u32,
    /// SIP period (P2OS: 100 ms; 50 ms allowed).
    pub sip_period: Duration,
    /// Watchdog: no host packet for this long stops the robot.
    pub watchdog: Duration,
    /// Restart at SYNC0 on an out-of-sequence SYNC (firmware); `false` echoes it (AMRISim).
    pub strict_sync: bool,
    /// Sonar firing rate per array.
    pub sonar_hz_per_array: f64,
    /// Sonar on when a session opens.
    pub sonar_on_open: bool,
    /// Encoder ticks per mm of wheel travel.
    pub ticks_per_mm: f64,
    /// Longest sonar range; "no echo" is reported as this.
    pub sonar_max_m: f64,
    /// Shortest sonar range.
    pub sonar_min_m: f64,
    /// Firmware version string in CONFIG.
    pub firmware: String,
    /// The robot has bumper rings: a body's front/rear contact sets all five segment bits of
    /// that ring in the SIP. Off by default (a P2-AT without bumpers, as before).
    pub bumpers: bool,
    /// ResetBaud in CONFIG: 2 (the default) = HOSTBAUD switches the port (see the module
    /// docs); anything else = HOSTBAUD is ignored.
    pub reset_baud: u8,
}

impl Default for P2osModelConfig {
    fn default() -> Self {
        Self {
            name: "Skeeter".into(),
            class: "Pioneer".into(),
            subclass: "p2at".into(),
            params: P2AT,
            baud: 9600,
            sip_period: Duration::from_millis(100),
            watchdog: Duration::from_secs(2),
            strict_sync: true,
            sonar_hz_per_array: 25.0,
            sonar_on_open: true,
            ticks_per_mm: ima_p2os::params::DEFAULT_TICKS_PER_MM,
            sonar_max_m: 5.0,
            sonar_min_m: 0.1,
            firmware: "P2OS 1.M (ima mock firmware, simulated Pioneer 2-AT)".into(),
            bumpers: false,
            reset_baud: 2,
        }
    }
}

/// The firmware's connection state.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RobotLink {
    /// Waiting for SYNC0.
    Idle,
    /// SYNC0 echoed, waiting for SYNC1.
    Sync1,
    /// SYNC1 echoed, waiting for SYNC2.
    Sync2,
    /// SYNC2 answered, waiting for OPEN.
    Synced,
    /// Streaming SIPs, executing commands.
    Open,
}

/// Counters of the model.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct P2osModelStats {
    /// Commands executed.
    pub commands: u64,
    /// Frames rejected (bad checksum, bad count).
    pub bad_frames: u64,
    /// Bytes ignored because the host's line speed did not match.
    pub baud_mismatch_bytes: u64,
    /// SIPs sent.
    pub sips: u64,
    /// Watchdog trips.
    pub watchdog_trips: u64,
    /// Sessions opened.
    pub sessions: u64,
    /// Line-speed switches by HOSTBAUD.
    pub baud_switches: u64,
}

/// The P2OS firmware model. See the [module docs](self).
#[derive(Debug)]
pub struct P2osRobot {
    cfg: P2osModelConfig,
    link: RobotLink,
    framer: Framer,
    out: Vec<u8>,
    stats: P2osModelStats,
    host_baud: Option<u32>,
    /// The port's current rate (the power-up rate until HOSTBAUD).
    baud: u32,
    motors: bool,
    sonar_on: bool,
    /// Setpoints: mm/s and deg/s.
    setpoint: (f64, f64),
    max_v_mm_s: f64,
    max_w_deg_s: f64,
    last_host: Option<Instant>,
    tripped: bool,
    next_sip: Option<Instant>,
    next_ping: Option<Instant>,
    ping_slot: usize,
    pending_sonar: Vec<SonarRaw>,
    origin: (f64, f64, f64),
    encoder_mode: i16,
    noise: u32,
}

impl P2osRobot {
    /// A powered-up robot whose odometry origin is `body`'s pose now.
    pub fn new(cfg: P2osModelConfig, body: &dyn DiffDriveBody) -> Self {
        let max_v = cfg.params.max_velocity_mm_s;
        let max_w = cfg.params.max_rot_velocity_deg_s;
        Self {
            link: RobotLink::Idle,
            framer: Framer::for_commands(),
            out: Vec::new(),
            stats: P2osModelStats::default(),
            host_baud: None,
            baud: cfg.baud,
            motors: false,
            sonar_on: false,
            setpoint: (0.0, 0.0),
            max_v_mm_s: max_v,
            max_w_deg_s: max_w,
            last_host: None,
            tripped: false,
            next_sip: None,
            next_ping: None,
            ping_slot: 0,
            pending_sonar: Vec::new(),
            origin: body.pose(),
            encoder_mode: 0,
            noise: 0x9E37_79B9,
            cfg,
        }
    }

    /// The model's configuration.
    pub fn config(&self) -> &P2osModelConfig {
        &self.cfg
    }

    /// Connection state.
    pub fn link(&self) -> RobotLink {
        self.link
    }

    /// Counters.
    pub fn stats(&self) -> P2osModelStats {
        self.stats
    }

    /// Motors enabled.
    pub fn motors_enabled(&self) -> bool {
        self.motors
    }

    /// The watchdog has stopped the robot.
    pub fn watchdog_tripped(&self) -> bool {
        self.tripped
    }

    /// Tell the model the host side's current line speed (read from the pty's termios), or
    /// `None` if unknown (then every rate matches).
    pub fn set_host_baud(&mut self, baud: Option<u32>) {
        self.host_baud = baud;
    }

    /// The robot port's current line speed (changed by HOSTBAUD).
    pub fn baud(&self) -> u32 {
        self.baud
    }

    fn line_matches(&self) -> bool {
        self.host_baud.is_none_or(|b| b == self.baud)
    }

    /// Power-cycle: back to idle, motors off, odometry origin at the body's pose.
    pub fn reset(&mut self, body: &mut dyn DiffDriveBody) {
        let cfg = self.cfg.clone();
        let host_baud = self.host_baud;
        let stats = self.stats;
        *self = Self::new(cfg, body);
        self.host_baud = host_baud;
        self.stats = stats;
        body.drive(0.0, 0.0);
    }

    /// Bytes from the host at `now`.
    pub fn handle_rx(&mut self, bytes: &[u8], now: Instant, body: &mut dyn DiffDriveBody) {
        if !self.line_matches() {
            // At the wrong rate every byte arrives as line noise.
            self.stats.baud_mismatch_bytes += bytes.len() as u64;
            return;
        }
        let mut cmds: Vec<Vec<u8>> = Vec::new();
        self.framer.push(bytes, |ev| match ev {
            FrameEvent::Frame(p) => cmds.push(p.to_vec()),
            FrameEvent::Rejected(_) => {}
        });
        self.stats.bad_frames = {
            let s = self.framer.stats();
            s.bad_checksums + s.bad_counts
        };
        for payload in cmds {
            // Unparseable commands are dropped silently, as the firmware does (spec §2).
            if let Ok(cmd) = Command::parse(&payload) {
                self.execute(cmd, now, body);
            }
        }
    }

    fn reply(&mut self, p: &Packet<'_>) {
        let mut buf = [0u8; wire::MAX_FRAME_LEN];
        if let Ok(n) = p.emit(&mut buf)
            && let Some(bytes) = buf.get(..n)
        {
            if self.line_matches() {
                self.out.extend_from_slice(bytes);
            } else {
                // What the host reads at the wrong rate: garbage of about the same length.
                for _ in bytes {
                    self.noise ^= self.noise << 13;
                    self.noise ^= self.noise >> 17;
                    self.noise ^= self.noise << 5;
                    self.out.push(self.noise as u8);
                }
            }
        }
    }

    fn sync_reply(&mut self, n: u8) {
        match n {
            0 | 1 => self.reply(&Packet::SyncEcho(n)),
            _ => {
                let (name, class, sub) = (
                    self.cfg.name.clone(),
                    self.cfg.class.clone(),
                    self.cfg.subclass.clone(),
                );
                self.reply(&Packet::SyncReply {
                    name: name.as_bytes(),
                    class: class.as_bytes(),
                    subclass: sub.as_bytes(),
                });
            }
        }
    }

    fn execute(&mut self, cmd: Command<'_>, now: Instant, body: &mut dyn DiffDriveBody) {
        self.stats.commands += 1;
        let sync = match cmd {
            Command::Sync0 => Some(0u8),
            Command::Sync1 => Some(1),
            Command::Sync2 => Some(2),
            _ => None,
        };
        match self.link {
            RobotLink::Idle | RobotLink::Sync1 | RobotLink::Sync2 => {
                let Some(n) = sync else { return };
                let expected = match self.link {
                    RobotLink::Idle => 0,
                    RobotLink::Sync1 => 1,
                    _ => 2,
                };
                if n == expected {
                    self.sync_reply(n);
                    self.link = match n {
                        0 => RobotLink::Sync1,
                        1 => RobotLink::Sync2,
                        _ => RobotLink::Synced,
                    };
                } else if self.cfg.strict_sync {
                    // Out of sequence: restart at SYNC0 (and honour it if it is one).
                    self.link = RobotLink::Idle;
                    if n == 0 {
                        self.sync_reply(0);
                        self.link = RobotLink::Sync1;
                    }
                } else {
                    self.sync_reply(n);
                }
            }
            RobotLink::Synced => match sync {
                Some(1) => self.open(now),
                Some(0) => {
                    self.link = RobotLink::Sync1;
                    self.sync_reply(0);
                }
                Some(_) => self.link = RobotLink::Idle,
                None => {}
            },
            RobotLink::Open => {
                self.last_host = Some(now);
                if self.tripped {
                    // Revived: re-accelerate to the old setpoints (spec §5.2).
                    self.tripped = false;
                    self.apply_drive(body);
                }
                self.execute_open(cmd, body);
            }
        }
    }

    fn open(&mut self, now: Instant) {
        self.link = RobotLink::Open;
        self.stats.sessions += 1;
        self.motors = false;
        self.sonar_on = self.cfg.sonar_on_open;
        self.setpoint = (0.0, 0.0);
        self.max_v_mm_s = self.cfg.params.max_velocity_mm_s;
        self.max_w_deg_s = self.cfg.params.max_rot_velocity_deg_s;
        self.last_host = Some(now);
        self.tripped = false;
        self.next_sip = Some(now + self.cfg.sip_period);
        self.next_ping = Some(now);
        self.pending_sonar.clear();
        self.encoder_mode = 0;
    }

    fn close(&mut self, body: &mut dyn DiffDriveBody) {
        self.link = RobotLink::Idle;
        self.baud = self.cfg.baud;
        self.motors = false;
        self.sonar_on = false;
        self.setpoint = (0.0, 0.0);
        self.next_sip = None;
        self.next_ping = None;
        body.drive(0.0, 0.0);
    }

    fn apply_drive(&mut self, body: &mut dyn DiffDriveBody) {
        if self.motors && !self.tripped {
            body.drive(self.setpoint.0 / 1000.0, self.setpoint.1.to_radians());
        } else {
            body.drive(0.0, 0.0);
        }
    }

    fn execute_open(&mut self, cmd: Command<'_>, body: &mut dyn DiffDriveBody) {
        let clamp_v = |v: f64, m: f64| v.clamp(-m, m);
        match cmd {
            Command::Sync0 => {} // PULSE: the watchdog was fed above.
            Command::Sync1 => {} // OPEN on an open session: nothing to do.
            Command::Sync2 => self.close(body),
            Command::Stop | Command::EStop => {
                self.setpoint = (0.0, 0.0);
                self.apply_drive(body);
            }
            Command::SetOdometry => self.origin = body.pose(),
            Command::Vel2 { left, right } => {
                let d = self.cfg.params.vel2_divisor;
                let (l, r) = (f64::from(left) * d, f64::from(right) * d);
                let v = (l + r) / 2.0;
                let w = ((r - l) / 2.0 * self.cfg.params.diff_conv).to_degrees();
                self.setpoint = (clamp_v(v, self.max_v_mm_s), clamp_v(w, self.max_w_deg_s));
                self.apply_drive(body);
            }
            Command::Int(c, v) => {
                let v = f64::from(v);
                match c {
                    IntCommand::Enable => {
                        self.motors = v != 0.0;
                        self.apply_drive(body);
                    }
                    IntCommand::Vel => {
                        self.setpoint.0 = clamp_v(v, self.max_v_mm_s);
                        self.apply_drive(body);
                    }
                    IntCommand::RVel | IntCommand::Rotate => {
                        self.setpoint.1 = clamp_v(v, self.max_w_deg_s);
                        self.apply_drive(body);
                    }
                    IntCommand::SetV => {
                        self.max_v_mm_s = v.abs().min(self.cfg.params.max_velocity_mm_s);
                    }
                    IntCommand::SetRv => {
                        self.max_w_deg_s = v.abs().min(self.cfg.params.max_rot_velocity_deg_s);
                    }
                    IntCommand::Sonar => self.sonar_on = v != 0.0,
                    IntCommand::HostBaud => {
                        if self.cfg.reset_baud == 2
                            && let Some(&rate) = HOSTBAUD_RATES.get(v as usize)
                            && v >= 0.0
                        {
                            if rate != self.baud {
                                self.stats.baud_switches += 1;
                            }
                            self.baud = rate;
                        }
                    }
                    IntCommand::Config => self.send_config(),
                    IntCommand::Encoder => {
                        self.encoder_mode = v as i16;
                        if self.encoder_mode == 1 {
                            self.send_encoder(body);
                            self.encoder_mode = 0;
                        }
                    }
                    _ => {} // Accepted and ignored (accelerations, gains, gripper, …).
                }
            }
            Command::Str(..) | Command::Other { .. } => {}
        }
    }

    fn send_config(&mut self) {
        let p = self.cfg.params;
        let name = self.cfg.name.clone();
        let sub = self.cfg.subclass.clone();
        let class = self.cfg.class.clone();
        let fw = self.cfg.firmware.clone();
        let cfg = wire::Config {
            robot_type: class.as_bytes(),
            subtype: sub.as_bytes(),
            serial: b"IMA-MOCK-0001",
            four_motors: 1,
            rot_vel_top: p.max_rot_velocity_deg_s as u16,
            trans_vel_top: p.max_velocity_mm_s as u16,
            rot_acc_top: 300,
            trans_acc_top: 2000,
            pwm_max: 500,
            name: name.as_bytes(),
            numbers: ConfigNumbers {
                sip_cycle: self.cfg.sip_period.as_millis().min(255) as u8,
                host_baud: baud_code(self.baud),
                front_sonar: 1,
                rear_sonar: 1,
                low_battery: 110,
                watchdog: self.cfg.watchdog.as_millis().min(65535) as u16,
                rot_vel_max: self.max_w_deg_s as u16,
                trans_vel_max: self.max_v_mm_s as u16,
                rot_accel: 100,
                rot_decel: 100,
                trans_accel: 300,
                trans_decel: 300,
                sonar_cycle: (1000.0 / self.cfg.sonar_hz_per_array) as u8,
                reset_baud: self.cfg.reset_baud,
                ticks_mm: self.cfg.ticks_per_mm.round() as u16,
                shutdown_volts: 105,
                ..ConfigNumbers::default()
            },
            firmware: fw.as_bytes(),
        };
        self.reply(&Packet::Config(cfg));
    }

    fn send_encoder(&mut self, body: &dyn DiffDriveBody) {
        let (l, r) = body.wheel_travel_m();
        let (l, r) = (l * 1000.0, r * 1000.0);
        let k = self.cfg.ticks_per_mm;
        let ticks = |mm: f64| {
            (mm * k)
                .round()
                .clamp(f64::from(i32::MIN), f64::from(i32::MAX)) as i32
        };
        self.reply(&Packet::Encoder {
            left: ticks(l),
            right: ticks(r),
        });
    }

    /// When [`handle_timeout`](Self::handle_timeout) is next due.
    pub fn poll_timeout(&self) -> Option<Instant> {
        let wd = match (self.link, self.last_host, self.tripped) {
            (RobotLink::Open, Some(t), false) => Some(t + self.cfg.watchdog),
            _ => None,
        };
        [self.next_sip, self.next_ping, wd]
            .into_iter()
            .flatten()
            .min()
    }

    /// Run the firmware's timers up to `now`.
    pub fn handle_timeout(&mut self, now: Instant, body: &mut dyn DiffDriveBody) {
        if self.link != RobotLink::Open {
            return;
        }
        if !self.tripped && self.last_host.is_some_and(|t| now >= t + self.cfg.watchdog) {
            self.tripped = true;
            self.stats.watchdog_trips += 1;
            body.drive(0.0, 0.0);
        }
        // Fire sonar: one transducer of each array per ping (25 Hz per array).
        let ping_period = Duration::from_secs_f64(1.0 / self.cfg.sonar_hz_per_array.max(0.1));
        while let Some(t) = self.next_ping.filter(|t| *t <= now) {
            if self.sonar_on {
                self.ping(body);
            }
            self.next_ping = Some(t + ping_period);
        }
        while let Some(t) = self.next_sip.filter(|t| *t <= now) {
            self.send_sip(body);
            if self.encoder_mode >= 2 {
                self.send_encoder(body);
            }
            self.next_sip = Some(t + self.cfg.sip_period);
        }
    }

    fn ping(&mut self, body: &mut dyn DiffDriveBody) {
        let n = self.cfg.params.sonars.len();
        let half = n / 2;
        if half == 0 {
            return;
        }
        let slot = self.ping_slot % half;
        self.ping_slot = self.ping_slot.wrapping_add(1);
        for index in [slot, slot + half] {
            let Some(mount) = self.cfg.params.sonars.get(index).copied() else {
                continue;
            };
            let iso = ima_hal::Isometry2::new(
                ima_hal::Vector2::new(mount.x_mm / 1000.0, mount.y_mm / 1000.0),
                mount.heading_deg.to_radians(),
            );
            let r = body
                .sonar_range_m(&iso)
                .unwrap_or(self.cfg.sonar_max_m)
                .clamp(self.cfg.sonar_min_m, self.cfg.sonar_max_m);
            let raw = (r * 1000.0 / self.cfg.params.range_conv)
                .round()
                .min(65535.0) as u16;
            // A transducer that fires again before a SIP replaces its older reading.
            self.pending_sonar.retain(|s| usize::from(s.index) != index);
            self.pending_sonar.push(SonarRaw {
                index: index as u8,
                range: raw,
            });
        }
    }

    fn send_sip(&mut self, body: &dyn DiffDriveBody) {
        let p = self.cfg.params;
        let (x, y, th) = body.pose();
        let (x0, y0, th0) = self.origin;
        let (s, c) = (-th0).sin_cos();
        let (dx, dy) = (x - x0, y - y0);
        let (ox, oy) = (c * dx - s * dy, s * dx + c * dy);
        let oth = ima_hal::normalize_angle(th - th0);
        let to_units =
            |m: f64| ((m * 1000.0 / p.dist_conv).round() as i64).rem_euclid(32768) as u16;
        let th_units = (oth / p.angle_conv).round() as i64;
        let th_units = (th_units + 2048).rem_euclid(4096) - 2048;
        let (l, r) = body.wheel_speeds_m_s();
        let (l, r) = (l * 1000.0, r * 1000.0);
        let (front, rear) = if self.cfg.bumpers {
            let (f, r) = body.bumpers();
            (if f { 0x1F } else { 0 }, if r { 0x1F } else { 0 })
        } else {
            (0u8, 0u8)
        };
        let mut sonars = heapless::Vec::new();
        for s in self.pending_sonar.drain(..) {
            let _ = sonars.push(s);
        }
        let moving = l.abs() > 0.5 || r.abs() > 0.5;
        let sip = Sip {
            moving,
            xpos: to_units(ox),
            ypos: to_units(oy),
            thpos: th_units as i16,
            left_vel: (l / p.vel_conv).round() as i16,
            right_vel: (r / p.vel_conv).round() as i16,
            battery: (body.battery_v() * 10.0).round().clamp(0.0, 255.0) as u8,
            stall_bumpers: (u16::from(front & 0x1F) << 9) | (u16::from(rear & 0x1F) << 1),
            control: th_units as i16,
            flags: u16::from(self.motors) | if self.sonar_on { 0x001E } else { 0 },
            compass: 0,
            sonars,
            grip_state: 0,
            anport: 0,
            analog: 0,
            digin: 0,
            digout: 0,
            extra_len: 0,
        };
        self.stats.sips += 1;
        self.reply(&Packet::Sip(sip));
    }

    /// Take everything the robot has written since the last call.
    pub fn take_output(&mut self) -> Vec<u8> {
        std::mem::take(&mut self.out)
    }
}

/// The rates of HOSTBAUD's arguments 0..4.
const HOSTBAUD_RATES: [u32; 5] = [9600, 19200, 38400, 57600, 115200];

/// HOSTBAUD code of a rate (0..4 = 9600..115200).
fn baud_code(baud: u32) -> u8 {
    match baud {
        19200 => 1,
        38400 => 2,
        57600 => 3,
        115200 => 4,
        _ => 0,
    }
}

/// The P2OS firmware on a world robot, ready for a runner ([`crate::pty::PtyDevice`],
/// [`crate::duplex::DuplexDevice`]).
#[derive(Debug)]
pub struct P2osDevice {
    robot: P2osRobot,
    body: WorldBody,
    /// Power-cycle the robot when a hung-up link comes back (default: the link was a cable
    /// pulled and replugged, so the firmware kept its session).
    pub reset_on_reconnect: bool,
}

impl P2osDevice {
    /// The firmware `cfg` driving `body`.
    pub fn new(cfg: P2osModelConfig, body: WorldBody) -> Self {
        let robot = P2osRobot::new(cfg, &body);
        Self {
            robot,
            body,
            reset_on_reconnect: false,
        }
    }

    /// The firmware model (state, counters).
    pub fn robot(&self) -> &P2osRobot {
        &self.robot
    }
}

impl crate::model::DeviceModel for P2osDevice {
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

    fn set_host_baud(&mut self, baud: Option<u32>) {
        self.robot.set_host_baud(baud);
    }

    fn name(&self) -> &str {
        "p2os"
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::body::ScriptedBody;

    /// A body that stands still (wheel travel 1 m and −0.5 m), with every sonar reading
    /// 2 m.
    fn still() -> ScriptedBody {
        ScriptedBody {
            track_width_m: 0.4,
            wheel_travel_m: (1.0, -0.5),
            sonar_m: Some(2.0),
            ..ScriptedBody::default()
        }
    }

    fn ms(t: u64) -> Instant {
        Instant::from_millis(t)
    }

    fn frame(c: Command<'_>) -> Vec<u8> {
        let mut b = [0u8; 300];
        let n = c.emit(&mut b).unwrap();
        b[..n].to_vec()
    }

    fn packets(r: &mut P2osRobot) -> Vec<Packet<'static>> {
        let out = r.take_output();
        let mut f = Framer::new();
        let mut v = Vec::new();
        f.push(&out, |ev| {
            if let FrameEvent::Frame(p) = ev {
                let owned: &'static [u8] = Box::leak(p.to_vec().into_boxed_slice());
                v.push(Packet::parse(owned).unwrap());
            }
        });
        v
    }

    fn opened(body: &mut ScriptedBody) -> P2osRobot {
        let mut r = P2osRobot::new(P2osModelConfig::default(), body);
        for (i, c) in [
            Command::Sync0,
            Command::Sync1,
            Command::Sync2,
            Command::OPEN,
        ]
        .into_iter()
        .enumerate()
        {
            r.handle_rx(&frame(c), ms(i as u64), body);
        }
        let p = packets(&mut r);
        assert_eq!(p.len(), 3, "three sync replies");
        assert!(matches!(
            p[2],
            Packet::SyncReply {
                subclass: b"p2at",
                ..
            }
        ));
        assert_eq!(r.link(), RobotLink::Open);
        r
    }

    #[test]
    fn idle_robot_is_silent_and_strict_about_sync_order() {
        let mut body = still();
        let mut r = P2osRobot::new(P2osModelConfig::default(), &body);
        r.handle_rx(&frame(Command::Int(IntCommand::Vel, 100)), ms(0), &mut body);
        r.handle_timeout(ms(500), &mut body);
        assert!(r.take_output().is_empty());
        r.handle_rx(&frame(Command::Sync0), ms(1), &mut body);
        r.handle_rx(&frame(Command::Sync2), ms(2), &mut body); // out of order
        assert_eq!(r.link(), RobotLink::Idle);
        assert_eq!(packets(&mut r), vec![Packet::SyncEcho(0)]);
    }

    #[test]
    fn sips_every_100_ms_with_sonar_and_flags() {
        let mut body = still();
        let mut r = opened(&mut body);
        for t in (10..=1010).step_by(10) {
            r.handle_timeout(ms(t), &mut body);
        }
        let sips: Vec<_> = packets(&mut r)
            .into_iter()
            .filter_map(|p| match p {
                Packet::Sip(s) => Some(s),
                _ => None,
            })
            .collect();
        assert_eq!(sips.len(), 10);
        // 25 Hz per array: ~5 new readings per SIP, each 2 m / 0.268 mm.
        let n: usize = sips.iter().map(|s| s.sonars.len()).sum();
        assert!((45..=55).contains(&n), "{n} readings");
        assert!(sips.iter().flat_map(|s| &s.sonars).all(|s| s.range == 7463));
        assert!(!sips[0].motors_enabled());
        assert_eq!(sips[0].flags & 0x1E, 0x1E, "sonar on");
    }

    #[test]
    fn motors_stay_off_until_enable_and_watchdog_stops_then_resumes() {
        let mut body = still();
        let mut r = opened(&mut body);
        r.handle_rx(
            &frame(Command::Int(IntCommand::Vel, 300)),
            ms(10),
            &mut body,
        );
        assert_eq!(body.drive, (0.0, 0.0), "motors disabled");
        r.handle_rx(&frame(Command::enable(true)), ms(20), &mut body);
        assert!(
            (body.drive.0 - 0.3).abs() < 1e-9,
            "setpoint applies once enabled"
        );
        // Silence: at 2 s the robot stops but keeps streaming.
        r.handle_timeout(ms(2000), &mut body);
        assert!(!r.watchdog_tripped());
        r.handle_timeout(ms(2021), &mut body);
        assert!(r.watchdog_tripped());
        assert_eq!(body.drive, (0.0, 0.0));
        assert_eq!(r.link(), RobotLink::Open);
        // A PULSE revives it and it resumes the old setpoint (spec §5.2).
        r.handle_rx(&frame(Command::PULSE), ms(2500), &mut body);
        assert!(!r.watchdog_tripped());
        assert!((body.drive.0 - 0.3).abs() < 1e-9);
        assert_eq!(r.stats().watchdog_trips, 1);
    }

    #[test]
    fn sync_bytes_alias_pulse_open_close_on_an_open_session() {
        let mut body = still();
        let mut r = opened(&mut body);
        r.handle_rx(&frame(Command::Sync0), ms(10), &mut body); // PULSE
        r.handle_rx(&frame(Command::Sync1), ms(11), &mut body); // OPEN again
        assert_eq!(r.link(), RobotLink::Open);
        assert!(
            packets(&mut r).is_empty(),
            "no sync echo on an open session"
        );
        r.handle_rx(&frame(Command::Sync2), ms(12), &mut body); // CLOSE
        assert_eq!(r.link(), RobotLink::Idle);
        r.handle_timeout(ms(1000), &mut body);
        assert!(r.take_output().is_empty(), "no SIPs after CLOSE");
        assert!(!r.motors_enabled());
    }

    #[test]
    fn config_and_encoder_packets() {
        let mut body = still();
        let mut r = opened(&mut body);
        r.handle_rx(
            &frame(Command::Int(IntCommand::Config, 1)),
            ms(10),
            &mut body,
        );
        let out = r.take_output();
        assert!(out[2] > 127, "CONFIG count byte {} must exceed 127", out[2]);
        let mut f = Framer::new();
        let mut got = None;
        f.push(&out, |ev| {
            if let FrameEvent::Frame(p) = ev
                && let Ok(Packet::Config(c)) = Packet::parse(p)
            {
                got = Some((c.numbers.watchdog, c.subtype.to_vec(), c.numbers.ticks_mm));
            }
        });
        assert_eq!(got, Some((2000, b"p2at".to_vec(), 19)));
        r.handle_rx(
            &frame(Command::Int(IntCommand::Encoder, 2)),
            ms(20),
            &mut body,
        );
        for t in (30..=300).step_by(10) {
            r.handle_timeout(ms(t), &mut body);
        }
        let enc: Vec<_> = packets(&mut r)
            .into_iter()
            .filter(|p| matches!(p, Packet::Encoder { .. }))
            .collect();
        assert!(enc.len() >= 2, "continuous ENCODER packets: {}", enc.len());
        assert_eq!(
            enc[0],
            Packet::Encoder {
                left: 19000,
                right: -9500
            }
        );
    }

    #[test]
    fn hostbaud_switches_the_port_until_close() {
        let mut body = still();
        let mut r = opened(&mut body);
        r.set_host_baud(Some(9600));
        r.handle_rx(
            &frame(Command::Int(IntCommand::HostBaud, 2)),
            ms(10),
            &mut body,
        );
        assert_eq!(r.baud(), 38400);
        assert_eq!(r.stats().baud_switches, 1);
        // The host still at 9600: the next SIP is noise to it, its PULSE noise to the robot.
        r.handle_timeout(ms(110), &mut body);
        assert!(packets(&mut r).is_empty());
        r.handle_rx(&frame(Command::PULSE), ms(120), &mut body);
        assert!(r.stats().baud_mismatch_bytes > 0);
        // The host follows: SIPs parse, CONFIG reports HostBaud 2.
        r.set_host_baud(Some(38400));
        r.handle_timeout(ms(210), &mut body);
        assert!(matches!(packets(&mut r)[..], [Packet::Sip(_)]));
        r.handle_rx(
            &frame(Command::Int(IntCommand::Config, 1)),
            ms(220),
            &mut body,
        );
        let host_baud = packets(&mut r).into_iter().find_map(|p| match p {
            Packet::Config(c) => Some(c.numbers.host_baud),
            _ => None,
        });
        assert_eq!(host_baud, Some(2));
        // Out-of-range arguments are ignored; CLOSE goes back to the power-up rate.
        r.handle_rx(
            &frame(Command::Int(IntCommand::HostBaud, 9)),
            ms(230),
            &mut body,
        );
        assert_eq!(r.baud(), 38400);
        r.handle_rx(&frame(Command::Sync2), ms(240), &mut body);
        assert_eq!(r.baud(), 9600);
        r.set_host_baud(Some(9600));
        r.handle_rx(&frame(Command::Sync0), ms(250), &mut body);
        assert_eq!(packets(&mut r), vec![Packet::SyncEcho(0)]);
        // A robot that does not advertise ResetBaud 2 ignores HOSTBAUD.
        let mut r = P2osRobot::new(
            P2osModelConfig {
                reset_baud: 0,
                ..P2osModelConfig::default()
            },
            &body,
        );
        for c in [
            Command::Sync0,
            Command::Sync1,
            Command::Sync2,
            Command::OPEN,
        ] {
            r.handle_rx(&frame(c), ms(300), &mut body);
        }
        r.handle_rx(
            &frame(Command::Int(IntCommand::HostBaud, 4)),
            ms(310),
            &mut body,
        );
        assert_eq!(r.baud(), 9600);
    }

    #[test]
    fn traffic_at_the_wrong_line_speed_is_noise() {
        let mut body = still();
        let mut r = P2osRobot::new(
            P2osModelConfig {
                baud: 38400,
                ..P2osModelConfig::default()
            },
            &body,
        );
        r.set_host_baud(Some(9600));
        r.handle_rx(&frame(Command::Sync0), ms(0), &mut body);
        assert!(r.take_output().is_empty());
        assert_eq!(r.stats().baud_mismatch_bytes, 6);
        r.set_host_baud(Some(38400));
        r.handle_rx(&frame(Command::Sync0), ms(1), &mut body);
        assert_eq!(packets(&mut r), vec![Packet::SyncEcho(0)]);
    }
}

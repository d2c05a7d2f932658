//! The host side of an rFLEX session (spec §4–§7), sans-IO.
//!
//! Inputs: [`Machine::handle_bytes`] (raw serial bytes; a strict [`Framer`] sits in front),
//! or [`Machine::handle_frame`] (an already-parsed [`Report`]), [`Machine::handle_timeout`],
//! and the user requests [`Machine::set_velocity`], [`Machine::stop`],
//! [`Machine::enable_motors`], [`Machine::set_sonar`], [`Machine::reset_odometry`],
//! [`Machine::shutdown`]. Outputs: [`Machine::poll_transmit`] (one frame per call),
//! [`Machine::poll_event`] and [`Machine::poll_timeout`].
//!
//! Every input takes `now`; the machine remembers the latest and never reads a clock. A shell
//! loops: feed input, drain `poll_transmit`, drain `poll_event`, sleep until `poll_timeout`,
//! call `handle_timeout`.
//!
//! Timing rules (all from §6):
//! * **Init order**: MOT_SYSTEM_REPORT_REQ, DIO_REPORTS_REQ, MOT_SET_DEFAULTS, SET_DIR axis 0
//!   and 1 at rest, (MOT_BRAKE_RELEASE only if [`Config::release_brake_at_start`]), SONAR_RUN,
//!   SYS_STATUS. The brake starts engaged; motion needs [`Machine::enable_motors`] first.
//! * **Keep-alive**: the SET_DIR pair goes out at once on every command and then every
//!   [`Config::keepalive_period`] (100 ms) while the target is non-zero, and for
//!   [`Config::stop_hold`] (0.5 s) after the target became zero.
//! * **Watchdog**: a non-zero target with no new command for [`Config::command_timeout`]
//!   (0.5 s) is zeroed by the machine ([`Event::CommandTimeout`]).
//! * **Pacing**: at least [`Config::min_frame_gap`] (5 ms) between two frames.
//! * **Status**: SYS_STATUS every [`Config::status_period`] (1 s).
//! * **Link**: no good frame for [`Config::link_timeout`] (1 s) → [`Event::LinkLost`]; the next
//!   one → [`Event::LinkUp`] (our addition; the spec names no such rule).
//! * **Shutdown**: SET_DIR 0/0, SONAR_RUN off, MOT_SET_DEFAULTS, MOT_SYSTEM_REPORT_REQ (0, 0),
//!   DIO_REPORTS_REQ (0), IR off, MOT_BRAKE_SET; then [`Event::ShutdownComplete`].

use core::time::Duration;

use ima_hal::base::{BaseLimits, BumperState, Odometry, VelocityCommand};
use ima_hal::nalgebra::{ComplexField, Vector2};
use ima_hal::power::PowerState;
use ima_hal::sonar::{MAX_SONARS, SonarReading, SonarTransducer};
use ima_hal::{Instant, Isometry2, Stamped, normalize_angle};

use crate::framer::{Framer, FramerConfig, Stats as FramerStats};
use crate::wire::{
    Command, DIO_BUMPER_ADDRESS, MAX_WIRE_FRAME, MotionReport, RawFrame, Report, SetDir, SonarRun,
    Stuffing, UnknownFrame, WireError,
};

/// Where one sonar id sits: the index it is reported under and its pose on the robot (§7).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SonarMount {
    /// Sonar id on the wire (bank × 16 + channel).
    pub id: u8,
    /// Index reported in [`SonarReading::index`].
    pub index: u8,
    /// Pose in the robot frame (x forward, y left; the beam along the pose's x axis).
    pub pose: Isometry2,
}

/// DTU's ATRV-Jr id → index map (§7): ids 0–5 → 0–5, 16–20 → 6–10, 32–37 → 16…11.
pub const ATRV_JR_SONAR_IDS: [(u8, u8); 17] = [
    (0, 0),
    (1, 1),
    (2, 2),
    (3, 3),
    (4, 4),
    (5, 5),
    (16, 6),
    (17, 7),
    (18, 8),
    (19, 9),
    (20, 10),
    (37, 11),
    (36, 12),
    (35, 13),
    (34, 14),
    (33, 15),
    (32, 16),
];

/// Half length and half width of the placeholder outline used for default sonar poses, m
/// (an ATRV-Jr is about 0.8 m × 0.55 m).
const HALF_LENGTH_M: f64 = 0.40;
const HALF_WIDTH_M: f64 = 0.275;

impl SonarMount {
    /// The default ATRV-Jr table: DTU's id map ([`ATRV_JR_SONAR_IDS`]) with **placeholder
    /// poses**: index i looks out at yaw 2π·i/17 (counter-clockwise from straight ahead) from
    /// the point where that ray leaves a 0.8 m × 0.55 m rectangle. No source gives the real
    /// poses; measure Scooter's and pass a table in [`Config::sonar_table`] (§7).
    #[must_use]
    pub fn atrv_jr_default() -> heapless::Vec<SonarMount, MAX_SONARS> {
        let mut v = heapless::Vec::new();
        let n = ATRV_JR_SONAR_IDS.len() as f64;
        for (id, index) in ATRV_JR_SONAR_IDS {
            let yaw = normalize_angle(2.0 * core::f64::consts::PI * f64::from(index) / n);
            let (s, c) = (
                <f64 as ComplexField>::sin(yaw),
                <f64 as ComplexField>::cos(yaw),
            );
            // Scale the unit ray to the rectangle's edge.
            let kx = if c.abs() > 1e-9 {
                HALF_LENGTH_M / c.abs()
            } else {
                f64::INFINITY
            };
            let ky = if s.abs() > 1e-9 {
                HALF_WIDTH_M / s.abs()
            } else {
                f64::INFINITY
            };
            let k = kx.min(ky);
            let pose = Isometry2::new(Vector2::new(k * c, k * s), yaw);
            let _ = v.push(SonarMount { id, index, pose });
        }
        v
    }
}

/// Session parameters. [`Config::default`] is the ATRV-Jr of the spec.
#[derive(Debug, Clone, PartialEq)]
pub struct Config {
    /// Translation units per metre (§4; default 90810).
    pub kd: f64,
    /// Rotation units per radian (§4; default 37000).
    pub ka: f64,
    /// Translational acceleration sent with SET_DIR, m/s² (§5; ROS's 0.7).
    pub trans_accel_m_s2: f64,
    /// Translational torque (§5; `STD_TRANS_TORQUE` 30000).
    pub trans_torque: u32,
    /// Rotational acceleration in controller units (§5; `STD_ROT_ACC` 100000).
    pub rot_accel: u32,
    /// Rotational torque (§5; `STD_ROT_TORQUE` 35000).
    pub rot_torque: u32,
    /// Commands are clamped to these; odometry plausibility uses them too.
    pub limits: BaseLimits,
    /// Motion report period, µs (§3; 100000 = 10 Hz).
    pub report_period_us: u32,
    /// DIO report period / hold-off, µs (100000).
    pub dio_period_us: u32,
    /// Send SONAR_RUN on at initialisation.
    pub sonar_at_start: bool,
    /// Release the brake during initialisation (CAR, DTU) instead of waiting for
    /// [`Machine::enable_motors`] (PL, ROS). Default off.
    pub release_brake_at_start: bool,
    /// Period of SYS_STATUS requests (§6: about 1 s).
    pub status_period: Duration,
    /// Period of the SET_DIR keep-alive (§6: 100 ms).
    pub keepalive_period: Duration,
    /// How long zeros keep going out after the target became zero (§6: ≥ 0.5 s).
    pub stop_hold: Duration,
    /// A non-zero target older than this is zeroed by the machine (§6: 0.5 s).
    pub command_timeout: Duration,
    /// Smallest gap between two frames (§6: ≥ 5 ms).
    pub min_frame_gap: Duration,
    /// Send a translational speed of 1 instead of 0 in motion frames (§5 / P9, UML). Off.
    pub zero_speed_quirk: bool,
    /// Send unstuffed frames with the Player nudge on every field (§2.4). Off: stuff per CW.
    pub legacy_no_stuff: bool,
    /// Added to raw/100 to give battery volts (§3 SYS: 1.2 V on the ATRV-Jr).
    pub power_offset_v: f64,
    /// Sonar raw units per metre (§3 SONAR: 1476).
    pub sonar_units_per_m: f64,
    /// Raw sonar values are clipped here; the clipped value means "no echo" (rhogroup: 10000).
    pub sonar_max_raw: u16,
    /// Sonar id → index and pose (§7).
    pub sonar_table: heapless::Vec<SonarMount, MAX_SONARS>,
    /// Send IR off during shutdown (§6 lists it; the ATRV-Jr has no IR).
    pub shutdown_ir_off: bool,
    /// Odometry jumps beyond `3·v_max·Δt + slack` are rejected (§4 step 5), metres (0.05); the
    /// same slack in radians is used for rotation.
    pub odometry_slack: f64,
    /// After this many rejections in a row the next report becomes the new baseline.
    pub odometry_max_rejects: u8,
    /// No good frame for this long (reports come at 10 Hz) raises [`Event::LinkLost`];
    /// the next good frame raises [`Event::LinkUp`]. Default 1 s.
    pub link_timeout: Duration,
    /// Recover a lost link: re-send the §6 initialisation ([`Machine::reinitialize`], sonar
    /// as last asked for) at [`Event::LinkLost`] and every `link_timeout` after, until a
    /// motion report arrives (a power-cycled controller has reports off and the brake on).
    /// Off by default; the driver's shell turns it on.
    pub recover: bool,
    /// The receiver's options (strict by default).
    pub framer: FramerConfig,
}

impl Default for Config {
    fn default() -> Self {
        Self {
            kd: 90_810.0,
            ka: 37_000.0,
            trans_accel_m_s2: 0.7,
            trans_torque: 30_000,
            rot_accel: 100_000,
            rot_torque: 35_000,
            limits: BaseLimits {
                max_v_m_s: 1.0,
                max_omega_rad_s: 1.5,
            },
            report_period_us: 100_000,
            dio_period_us: 100_000,
            sonar_at_start: true,
            release_brake_at_start: false,
            status_period: Duration::from_secs(1),
            keepalive_period: Duration::from_millis(100),
            stop_hold: Duration::from_millis(500),
            command_timeout: Duration::from_millis(500),
            min_frame_gap: Duration::from_millis(5),
            zero_speed_quirk: false,
            legacy_no_stuff: false,
            power_offset_v: 1.2,
            sonar_units_per_m: 1476.0,
            sonar_max_raw: 10_000,
            sonar_table: SonarMount::atrv_jr_default(),
            shutdown_ir_off: true,
            odometry_slack: 0.05,
            odometry_max_rejects: 3,
            link_timeout: Duration::from_secs(1),
            recover: false,
            framer: FramerConfig::default(),
        }
    }
}

impl Config {
    /// Axis-0 (translation) controller units in SI (÷ [`Config::kd`]): a position in m, a
    /// velocity in m/s, an acceleration in m/s².
    #[must_use]
    pub fn translation_si(&self, units: f64) -> f64 {
        units / self.kd
    }

    /// Axis-1 (rotation) controller units in SI (÷ [`Config::ka`]): an angle in rad, a rate
    /// in rad/s, an acceleration in rad/s².
    #[must_use]
    pub fn rotation_si(&self, units: f64) -> f64 {
        units / self.ka
    }

    /// A SYS_STATUS voltage word as battery volts: raw / 100 + [`Config::power_offset_v`].
    #[must_use]
    pub fn battery_v(&self, voltage_raw: u32) -> f64 {
        f64::from(voltage_raw) / 100.0 + self.power_offset_v
    }

    /// A sonar echo in metres, clipped at [`Config::sonar_max_raw`] (the clipped value means
    /// "no echo"), ÷ [`Config::sonar_units_per_m`].
    #[must_use]
    pub fn sonar_range_m(&self, raw: u16) -> f64 {
        f64::from(raw.min(self.sonar_max_raw)) / self.sonar_units_per_m
    }

    /// A SET_DIR's signed speed and its acceleration in SI: (m/s, m/s²) on axis 0,
    /// (rad/s, rad/s²) on axis 1, `None` on any other axis. The inverse of
    /// [`Machine::set_dir_pair`]'s speeds.
    #[must_use]
    pub fn set_dir_si(&self, s: &SetDir) -> Option<(f64, f64)> {
        let sign = if s.forward { 1.0 } else { -1.0 };
        let (v, a) = (f64::from(s.velocity), f64::from(s.acceleration));
        match s.axis {
            0 => Some((sign * self.translation_si(v), self.translation_si(a))),
            1 => Some((sign * self.rotation_si(v), self.rotation_si(a))),
            _ => None,
        }
    }
}

/// `x` rounded half up to a u32, saturating; negative or NaN gives 0 (§5, P10: round, never
/// truncate).
fn round_u32(x: f64) -> u32 {
    if x.is_nan() || x <= 0.0 {
        0
    } else {
        // `as` saturates at u32::MAX.
        (x + 0.5) as u32
    }
}

/// Something the session reports. Readings are stamped with the host `now` of arrival.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Event {
    /// Every initialisation frame has been sent.
    Initialized,
    /// New integrated odometry (after each pair of axis reports; the first pair sets the
    /// baseline and reports the origin).
    Odometry(Stamped<Odometry>),
    /// A pair of axis reports moved implausibly far and was not integrated (§4 step 5).
    OdometryRejected {
        /// When.
        at: Instant,
        /// The translation it implied, m.
        delta_m: f64,
        /// The rotation it implied, rad.
        delta_rad: f64,
    },
    /// Battery voltage from SYS_STATUS.
    Power(Stamped<PowerState>),
    /// Brake state from SYS_STATUS: `true` = engaged (motors disabled).
    Brake(Stamped<bool>),
    /// One sonar range of a mapped transducer.
    Sonar(SonarReading),
    /// A sonar id missing from the table (log these to fill the table in, §7).
    UnmappedSonar {
        /// When.
        at: Instant,
        /// Wire id (bank × 16 + channel).
        id: u8,
        /// Range, m.
        range_m: f64,
    },
    /// Bumpers (DIO address 0x40, §3).
    Bumpers(Stamped<BumperState>),
    /// Any other DIO report.
    Dio {
        /// When.
        at: Instant,
        /// Address.
        address: u8,
        /// Data.
        data: u16,
    },
    /// Joystick pendant state.
    Joystick {
        /// When.
        at: Instant,
        /// Stick x.
        x: i32,
        /// Stick y.
        y: i32,
        /// Buttons (bit 0 = joystick in control).
        buttons: u8,
    },
    /// A frame with a port/opcode the wire module does not know (ignored).
    Unknown(UnknownFrame),
    /// The client sent no command for [`Config::command_timeout`]; the target was zeroed.
    CommandTimeout,
    /// No good frame from the base for [`Config::link_timeout`] (cable, power, baud rate).
    LinkLost,
    /// A good frame arrived: at the first frame, and after [`Event::LinkLost`].
    LinkUp,
    /// The shutdown sequence has been sent; the machine is closed.
    ShutdownComplete,
}

/// Why a request was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CommandError {
    /// Motion needs [`Machine::enable_motors`]`(true)` first (the brake is engaged).
    MotorsDisabled,
    /// NaN or infinite speed.
    NotFinite,
    /// The session is shutting down or closed.
    Closed,
}

impl core::fmt::Display for CommandError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::MotorsDisabled => "motors disabled (brake engaged)",
            Self::NotFinite => "speed is not finite",
            Self::Closed => "session closed",
        })
    }
}

impl core::error::Error for CommandError {}

impl ima_hal::Error for CommandError {
    fn kind(&self) -> ima_hal::ErrorKind {
        match self {
            Self::MotorsDisabled => ima_hal::ErrorKind::Protocol,
            Self::NotFinite => ima_hal::ErrorKind::InvalidArgument,
            Self::Closed => ima_hal::ErrorKind::Disconnected,
        }
    }
}

/// Session counters (all wrapping).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Stats {
    /// Frames transmitted.
    pub tx_frames: u32,
    /// Frames not sent: the caller's buffer was too small, or a full queue (16 requests)
    /// dropped its oldest request.
    pub tx_errors: u32,
    /// Good frames whose payload did not fit their port/opcode.
    pub bad_payloads: u32,
    /// Frames with an unknown port/opcode.
    pub unknown_frames: u32,
    /// Ack frames (ignored).
    pub acks: u32,
    /// Odometry pairs rejected as implausible.
    pub odometry_rejected: u32,
    /// Sonar readings with an id not in the table.
    pub unmapped_sonar: u32,
    /// Events dropped because the event queue was full (oldest first).
    pub events_dropped: u32,
}

/// Where the session is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Phase {
    /// Running (initialisation frames may still be queued).
    Running,
    /// Sending the shutdown sequence.
    ShuttingDown,
    /// Shutdown sent; nothing more will be transmitted.
    Closed,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum MotionTx {
    Idle,
    Both,
    Axis1,
}

#[derive(Debug, Clone, Copy)]
struct OdoState {
    pending: [Option<(i32, i32)>; 2],
    base: Option<(i32, i32)>,
    last_at: Instant,
    x: f64,
    y: f64,
    theta: f64,
    v: f64,
    omega: f64,
    rejects: u8,
}

const TX_QUEUE: usize = 16;
const EVENT_QUEUE: usize = 64;

/// The host session.
#[derive(Debug)]
pub struct Machine {
    cfg: Config,
    framer: Framer,
    phase: Phase,
    now: Instant,
    queue: heapless::Deque<Command, TX_QUEUE>,
    motion: MotionTx,
    last_tx: Option<Instant>,
    initializing: bool,
    motors_enabled: bool,
    target: VelocityCommand,
    last_cmd_at: Instant,
    last_rx: Instant,
    link_up: Option<bool>,
    /// When to re-send the initialisation ([`Config::recover`]).
    reinit_at: Option<Instant>,
    /// The sonar as last asked for (a re-initialisation restarts it).
    sonar_wanted: bool,
    hold_until: Option<Instant>,
    next_keepalive: Instant,
    next_status: Instant,
    odo: OdoState,
    events: heapless::Deque<Event, EVENT_QUEUE>,
    stats: Stats,
}

impl Machine {
    /// Start a session at `now`: queues the initialisation frames of §6.
    #[must_use]
    pub fn new(cfg: Config, now: Instant) -> Self {
        let mut m = Self {
            framer: Framer::new(cfg.framer),
            phase: Phase::Running,
            now,
            queue: heapless::Deque::new(),
            motion: MotionTx::Idle,
            last_tx: None,
            initializing: true,
            motors_enabled: false,
            target: VelocityCommand::ZERO,
            last_cmd_at: now,
            last_rx: now,
            link_up: None,
            reinit_at: None,
            sonar_wanted: false,
            hold_until: None,
            next_keepalive: now,
            next_status: now + cfg.status_period,
            odo: OdoState {
                pending: [None, None],
                base: None,
                last_at: now,
                x: 0.0,
                y: 0.0,
                theta: 0.0,
                v: 0.0,
                omega: 0.0,
                rejects: 0,
            },
            events: heapless::Deque::new(),
            stats: Stats::default(),
            cfg,
        };
        m.enqueue(Command::SystemReportReq {
            period_us: m.cfg.report_period_us,
            mask: 3,
        });
        m.enqueue(Command::DioReportsReq {
            period_us: m.cfg.dio_period_us,
        });
        m.enqueue(Command::SetDefaults);
        m.enqueue(Command::SetDir(SetDir {
            axis: 0,
            velocity: 0,
            acceleration: m.trans_accel_units(),
            torque: 0,
            forward: false,
        }));
        m.enqueue(Command::SetDir(SetDir {
            axis: 1,
            velocity: 0,
            acceleration: m.cfg.rot_accel,
            torque: 0,
            forward: false,
        }));
        if m.cfg.release_brake_at_start {
            m.enqueue(Command::BrakeRelease);
            m.motors_enabled = true;
        }
        if m.cfg.sonar_at_start {
            m.enqueue(Command::SonarRun(SonarRun::ON));
        }
        m.enqueue(Command::SysStatusRequest);
        m
    }

    /// The configuration.
    #[must_use]
    pub fn config(&self) -> &Config {
        &self.cfg
    }

    /// Session counters.
    #[must_use]
    pub fn stats(&self) -> &Stats {
        &self.stats
    }

    /// Receiver counters.
    #[must_use]
    pub fn framer_stats(&self) -> &FramerStats {
        self.framer.stats()
    }

    /// Running, shutting down or closed.
    #[must_use]
    pub fn phase(&self) -> Phase {
        self.phase
    }

    /// Whether motion is allowed (the brake was released by this session).
    #[must_use]
    pub fn motors_enabled(&self) -> bool {
        self.motors_enabled
    }

    /// The velocity currently commanded (after clamping and the watchdog).
    #[must_use]
    pub fn target(&self) -> VelocityCommand {
        self.target
    }

    /// The odometry integrated so far.
    #[must_use]
    pub fn odometry(&self) -> Odometry {
        Odometry {
            pose: Isometry2::new(Vector2::new(self.odo.x, self.odo.y), self.odo.theta),
            v_m_s: self.odo.v,
            omega_rad_s: self.odo.omega,
        }
    }

    /// The transducers of the sonar table, in index order (for `SonarArray::transducers`).
    #[must_use]
    pub fn transducers(&self) -> heapless::Vec<SonarTransducer, MAX_SONARS> {
        let mut mounts = self.cfg.sonar_table.clone();
        mounts.sort_unstable_by_key(|m| m.index);
        let max_range_m = self.cfg.sonar_range_m(self.cfg.sonar_max_raw);
        mounts
            .iter()
            .map(|m| SonarTransducer {
                pose: m.pose,
                min_range_m: 0.0,
                max_range_m,
                beam_width_rad: 30f64.to_radians(),
            })
            .collect()
    }

    /// Translational acceleration in controller units.
    fn trans_accel_units(&self) -> u32 {
        round_u32(self.cfg.trans_accel_m_s2 * self.cfg.kd)
    }

    /// The SET_DIR pair (axis 0, axis 1) for a velocity (§5), without clamping.
    #[must_use]
    pub fn set_dir_pair(&self, cmd: VelocityCommand) -> [SetDir; 2] {
        let mut v = round_u32(cmd.v_m_s.abs() * self.cfg.kd);
        if v == 0 && self.cfg.zero_speed_quirk {
            v = 1;
        }
        [
            SetDir {
                axis: 0,
                velocity: v,
                acceleration: self.trans_accel_units(),
                torque: self.cfg.trans_torque,
                forward: cmd.v_m_s >= 0.0 || cmd.v_m_s.is_nan(),
            },
            SetDir {
                axis: 1,
                velocity: round_u32(cmd.omega_rad_s.abs() * self.cfg.ka),
                acceleration: self.cfg.rot_accel,
                torque: self.cfg.rot_torque,
                forward: cmd.omega_rad_s >= 0.0 || cmd.omega_rad_s.is_nan(),
            },
        ]
    }

    fn enqueue(&mut self, c: Command) {
        if self.queue.push_back(c).is_err() {
            // Full: the oldest non-motion request is least useful; keep the newest.
            let _ = self.queue.pop_front();
            let _ = self.queue.push_back(c);
            self.stats.tx_errors = self.stats.tx_errors.wrapping_add(1);
        }
    }

    fn push_event(&mut self, e: Event) {
        if self.events.push_back(e).is_err() {
            let _ = self.events.pop_front();
            let _ = self.events.push_back(e);
            self.stats.events_dropped = self.stats.events_dropped.wrapping_add(1);
        }
    }

    fn advance(&mut self, now: Instant) {
        if now > self.now {
            self.now = now;
        }
    }

    fn keepalive_active(&self) -> bool {
        self.motors_enabled
            && (self.target != VelocityCommand::ZERO
                || self.hold_until.is_some_and(|h| self.next_keepalive <= h))
    }

    /// Run the timers up to the latest `now`.
    fn tick(&mut self) {
        if self.phase != Phase::Running {
            return;
        }
        let now = self.now;
        if self.link_up != Some(false)
            && now.saturating_duration_since(self.last_rx) >= self.cfg.link_timeout
        {
            self.link_up = Some(false);
            self.push_event(Event::LinkLost);
            if self.cfg.recover {
                self.reinit_at = Some(now);
            }
        }
        if self.reinit_at.is_some_and(|t| now >= t) {
            self.reinitialize(self.sonar_wanted, now);
            self.reinit_at = Some(now + self.cfg.link_timeout);
        }
        if self.target != VelocityCommand::ZERO
            && now.saturating_duration_since(self.last_cmd_at) >= self.cfg.command_timeout
        {
            self.target = VelocityCommand::ZERO;
            self.hold_until = Some(now + self.cfg.stop_hold);
            self.motion = MotionTx::Both;
            self.next_keepalive = now + self.cfg.keepalive_period;
            self.push_event(Event::CommandTimeout);
        }
        if self.keepalive_active() && now >= self.next_keepalive {
            self.motion = MotionTx::Both;
            self.next_keepalive = now + self.cfg.keepalive_period;
        }
        if now >= self.next_status {
            if !self.queue.iter().any(|c| *c == Command::SysStatusRequest) {
                self.enqueue(Command::SysStatusRequest);
            }
            self.next_status = now + self.cfg.status_period;
        }
    }

    /// Time passes (call at or after [`poll_timeout`](Self::poll_timeout)).
    pub fn handle_timeout(&mut self, now: Instant) {
        self.advance(now);
        self.tick();
    }

    /// Bytes arrived from the port at `now`.
    pub fn handle_bytes(&mut self, mut bytes: &[u8], now: Instant) {
        self.advance(now);
        self.tick();
        self.framer.bytes_arrived(now);
        while !bytes.is_empty() {
            let (used, item) = self.framer.decode(bytes);
            let parsed = match item {
                Some(Ok(raw)) => Some(Report::from_raw(&raw)),
                _ => None,
            };
            if let Some(parsed) = parsed {
                match parsed {
                    Ok(r) => self.on_report(&r),
                    Err(_) => self.stats.bad_payloads = self.stats.bad_payloads.wrapping_add(1),
                }
            }
            bytes = bytes.get(used..).unwrap_or(&[]);
            if used == 0 {
                break;
            }
        }
    }

    /// A checked frame arrived (when the shell runs its own framer).
    pub fn handle_raw(&mut self, raw: &RawFrame<'_>, now: Instant) {
        match Report::from_raw(raw) {
            Ok(r) => self.handle_frame(&r, now),
            Err(_) => {
                self.advance(now);
                self.stats.bad_payloads = self.stats.bad_payloads.wrapping_add(1);
            }
        }
    }

    /// A parsed report arrived at `now`.
    pub fn handle_frame(&mut self, report: &Report, now: Instant) {
        self.advance(now);
        self.tick();
        self.on_report(report);
    }

    /// Whether the base is being heard (`None` before the first frame).
    #[must_use]
    pub fn link_up(&self) -> Option<bool> {
        self.link_up
    }

    fn on_report(&mut self, report: &Report) {
        let at = self.now;
        self.last_rx = at;
        if self.link_up != Some(true) {
            self.link_up = Some(true);
            self.push_event(Event::LinkUp);
        }
        match report {
            Report::SysStatus {
                voltage_raw,
                brake_engaged,
                ..
            } => {
                let battery_v = self.cfg.battery_v(*voltage_raw);
                self.push_event(Event::Power(Stamped::new(at, PowerState { battery_v })));
                self.push_event(Event::Brake(Stamped::new(at, *brake_engaged)));
            }
            Report::Motion(m) => self.on_motion(m),
            Report::Sonar(s) => {
                for e in &s.echoes {
                    let range_m = self.cfg.sonar_range_m(e.range);
                    let mount = self.cfg.sonar_table.iter().find(|m| m.id == e.id).copied();
                    match mount {
                        Some(m) => self.push_event(Event::Sonar(SonarReading {
                            index: m.index,
                            range_m,
                            at,
                        })),
                        None => {
                            self.stats.unmapped_sonar = self.stats.unmapped_sonar.wrapping_add(1);
                            self.push_event(Event::UnmappedSonar {
                                at,
                                id: e.id,
                                range_m,
                            });
                        }
                    }
                }
            }
            Report::Dio(d) | Report::DioUpdate(d) => {
                if d.address == DIO_BUMPER_ADDRESS {
                    let b = BumperState {
                        front: d.data & 1,
                        rear: (d.data >> 1) & 1,
                        left_stall: false,
                        right_stall: false,
                    };
                    self.push_event(Event::Bumpers(Stamped::new(at, b)));
                } else {
                    self.push_event(Event::Dio {
                        at,
                        address: d.address,
                        data: d.data,
                    });
                }
            }
            Report::Joystick { x, y, buttons, .. } => self.push_event(Event::Joystick {
                at,
                x: *x,
                y: *y,
                buttons: *buttons,
            }),
            Report::Ack { .. } => self.stats.acks = self.stats.acks.wrapping_add(1),
            Report::Unknown(u) => {
                self.stats.unknown_frames = self.stats.unknown_frames.wrapping_add(1);
                self.push_event(Event::Unknown(*u));
            }
        }
    }

    /// §4: pair the two axes, then integrate.
    fn on_motion(&mut self, m: &MotionReport) {
        let slot = match m.axis {
            0 => self.odo.pending.get_mut(0),
            1 => self.odo.pending.get_mut(1),
            _ => None,
        };
        let Some(slot) = slot else { return };
        *slot = Some((m.position, m.velocity));
        let [Some((p0, v0)), Some((p1, v1))] = self.odo.pending else {
            return;
        };
        self.odo.pending = [None, None];
        let now = self.now;
        let o = &mut self.odo;
        if let Some((b0, b1)) = o.base {
            let d = self.cfg.translation_si(f64::from(p0.wrapping_sub(b0)));
            let a = self.cfg.rotation_si(f64::from(p1.wrapping_sub(b1)));
            let dt = now.saturating_duration_since(o.last_at).as_secs_f64();
            let slack = self.cfg.odometry_slack;
            let max_d = 3.0 * self.cfg.limits.max_v_m_s * dt + slack;
            let max_a = 3.0 * self.cfg.limits.max_omega_rad_s * dt + slack;
            if !(d.abs() <= max_d && a.abs() <= max_a) {
                o.rejects = o.rejects.saturating_add(1);
                if o.rejects >= self.cfg.odometry_max_rejects {
                    // Persistent: the controller's counters really moved (or reset).
                    o.base = Some((p0, p1));
                    o.last_at = now;
                    o.rejects = 0;
                }
                self.stats.odometry_rejected = self.stats.odometry_rejected.wrapping_add(1);
                self.push_event(Event::OdometryRejected {
                    at: now,
                    delta_m: d,
                    delta_rad: a,
                });
                return;
            }
            let mid = o.theta + a / 2.0;
            o.x += d * <f64 as ComplexField>::cos(mid);
            o.y += d * <f64 as ComplexField>::sin(mid);
            o.theta = normalize_angle(o.theta + a);
        }
        o.base = Some((p0, p1));
        o.last_at = now;
        o.rejects = 0;
        o.v = self.cfg.translation_si(f64::from(v0));
        o.omega = self.cfg.rotation_si(f64::from(v1));
        let odo = self.odometry();
        self.reinit_at = None;
        self.push_event(Event::Odometry(Stamped::new(now, odo)));
    }

    /// Command a velocity (clamped to [`Config::limits`]). Sends the SET_DIR pair at once and
    /// keeps it alive (§6). Needs the motors enabled, except for a zero command.
    pub fn set_velocity(&mut self, cmd: VelocityCommand, now: Instant) -> Result<(), CommandError> {
        self.advance(now);
        self.tick();
        if self.phase != Phase::Running {
            return Err(CommandError::Closed);
        }
        if !cmd.is_finite() {
            return Err(CommandError::NotFinite);
        }
        let lim = self.cfg.limits;
        let cmd = VelocityCommand::new(
            cmd.v_m_s.clamp(-lim.max_v_m_s, lim.max_v_m_s),
            cmd.omega_rad_s
                .clamp(-lim.max_omega_rad_s, lim.max_omega_rad_s),
        );
        let is_zero = cmd.v_m_s == 0.0 && cmd.omega_rad_s == 0.0;
        if !is_zero && !self.motors_enabled {
            return Err(CommandError::MotorsDisabled);
        }
        let cmd = if is_zero { VelocityCommand::ZERO } else { cmd };
        let changed = cmd != self.target;
        self.target = cmd;
        self.last_cmd_at = self.now;
        if is_zero {
            self.hold_until = Some(self.now + self.cfg.stop_hold);
        }
        // A new speed goes out at once; a repeated one only feeds the watchdog and rides on
        // the keep-alive (zeros restart the hold, and are sent at once if idle).
        let idle = !self.keepalive_active() && self.motion == MotionTx::Idle;
        if self.motors_enabled && (changed || idle) {
            self.motion = MotionTx::Both;
            self.next_keepalive = self.now + self.cfg.keepalive_period;
        }
        Ok(())
    }

    /// Command zero velocity (zeros go out for [`Config::stop_hold`]).
    pub fn stop(&mut self, now: Instant) -> Result<(), CommandError> {
        self.set_velocity(VelocityCommand::ZERO, now)
    }

    /// Release (`true`) or engage the brake (§3 MOT 11/12). Disabling first sends a zero
    /// SET_DIR pair. A SYS_STATUS request follows, so [`Event::Brake`] confirms the change.
    pub fn enable_motors(&mut self, enable: bool, now: Instant) -> Result<(), CommandError> {
        self.advance(now);
        self.tick();
        if self.phase != Phase::Running {
            return Err(CommandError::Closed);
        }
        if enable {
            self.enqueue(Command::BrakeRelease);
            self.motors_enabled = true;
        } else {
            self.target = VelocityCommand::ZERO;
            self.hold_until = None;
            self.motion = MotionTx::Idle;
            let [a, b] = self.set_dir_pair(VelocityCommand::ZERO);
            self.enqueue(Command::SetDir(a));
            self.enqueue(Command::SetDir(b));
            self.enqueue(Command::BrakeSet);
            self.motors_enabled = false;
        }
        self.enqueue(Command::SysStatusRequest);
        Ok(())
    }

    /// Start or stop the sonar (SONAR_RUN mode 2 / 0).
    pub fn set_sonar(&mut self, on: bool, now: Instant) -> Result<(), CommandError> {
        self.sonar_wanted = on;
        self.advance(now);
        self.tick();
        if self.phase != Phase::Running {
            return Err(CommandError::Closed);
        }
        self.enqueue(Command::SonarRun(if on {
            SonarRun::ON
        } else {
            SonarRun::OFF
        }));
        Ok(())
    }

    /// Send the initialisation frames of §6 again (after the base was lost: it may have been
    /// power-cycled, which turns reports off and engages the brake). The odometry pose is
    /// kept, but the next pair of axis reports only sets a new baseline, so a controller whose
    /// counters restarted does not make the pose jump. If the motors were enabled, the brake
    /// is released again; sonar is restarted if [`Config::sonar_at_start`] or `sonar`.
    /// Queued requests are dropped. Does nothing once shutting down.
    pub fn reinitialize(&mut self, sonar: bool, now: Instant) {
        self.advance(now);
        if self.phase != Phase::Running {
            return;
        }
        self.queue.clear();
        self.odo.base = None;
        self.odo.pending = [None, None];
        self.enqueue(Command::SystemReportReq {
            period_us: self.cfg.report_period_us,
            mask: 3,
        });
        self.enqueue(Command::DioReportsReq {
            period_us: self.cfg.dio_period_us,
        });
        self.enqueue(Command::SetDefaults);
        let [a, b] = self.set_dir_pair(VelocityCommand::ZERO);
        self.enqueue(Command::SetDir(a));
        self.enqueue(Command::SetDir(b));
        if self.motors_enabled {
            self.enqueue(Command::BrakeRelease);
        }
        if sonar || self.cfg.sonar_at_start {
            self.enqueue(Command::SonarRun(SonarRun::ON));
        }
        self.enqueue(Command::SysStatusRequest);
    }

    /// Make the current pose the odometry origin (host side only, §4).
    pub fn reset_odometry(&mut self) {
        self.odo.x = 0.0;
        self.odo.y = 0.0;
        self.odo.theta = 0.0;
    }

    /// Begin the shutdown sequence of §6. Queued requests are dropped.
    pub fn shutdown(&mut self, now: Instant) {
        self.advance(now);
        if self.phase != Phase::Running {
            return;
        }
        self.phase = Phase::ShuttingDown;
        self.queue.clear();
        self.motion = MotionTx::Idle;
        self.target = VelocityCommand::ZERO;
        self.hold_until = None;
        let [a, b] = self.set_dir_pair(VelocityCommand::ZERO);
        self.enqueue(Command::SetDir(a));
        self.enqueue(Command::SetDir(b));
        self.enqueue(Command::SonarRun(SonarRun::OFF));
        self.enqueue(Command::SetDefaults);
        self.enqueue(Command::SystemReportReq {
            period_us: 0,
            mask: 0,
        });
        self.enqueue(Command::DioReportsReq { period_us: 0 });
        if self.cfg.shutdown_ir_off {
            self.enqueue(Command::IR_OFF);
        }
        self.enqueue(Command::BrakeSet);
        self.motors_enabled = false;
    }

    fn has_pending_tx(&self) -> bool {
        !self.queue.is_empty() || self.motion != MotionTx::Idle
    }

    fn next_tx_allowed(&self) -> Instant {
        match self.last_tx {
            Some(t) => t + self.cfg.min_frame_gap,
            None => Instant::ZERO,
        }
    }

    /// The next frame to send, written to `buf` (give it [`MAX_WIRE_FRAME`] bytes). `None`
    /// if nothing is due, or if the 5 ms pacing gap since the last frame has not passed at
    /// the latest `now` the machine was given.
    pub fn poll_transmit(&mut self, buf: &mut [u8]) -> Option<usize> {
        if self.phase == Phase::Closed || !self.has_pending_tx() {
            return None;
        }
        if self.now < self.next_tx_allowed() {
            return None;
        }
        let cmd = match self.motion {
            // Finish a started pair before anything else.
            MotionTx::Axis1 => {
                self.motion = MotionTx::Idle;
                let [_, b] = self.set_dir_pair(self.target);
                Command::SetDir(b)
            }
            _ => match self.queue.pop_front() {
                Some(c) => c,
                None => {
                    self.motion = MotionTx::Axis1;
                    let [a, _] = self.set_dir_pair(self.target);
                    Command::SetDir(a)
                }
            },
        };
        let (cmd, stuffing) = if self.cfg.legacy_no_stuff {
            (cmd.legacy_nudged(), Stuffing::None)
        } else {
            (cmd, Stuffing::Full)
        };
        let res = cmd.emit_with(cmd.default_id(), stuffing, buf);
        self.last_tx = Some(self.now);
        if self.queue.is_empty() {
            if self.initializing {
                self.initializing = false;
                self.push_event(Event::Initialized);
            }
            if self.phase == Phase::ShuttingDown {
                self.phase = Phase::Closed;
                self.push_event(Event::ShutdownComplete);
            }
        }
        match res {
            Ok(n) => {
                self.stats.tx_frames = self.stats.tx_frames.wrapping_add(1);
                Some(n)
            }
            Err(WireError::BufferTooSmall | _) => {
                self.stats.tx_errors = self.stats.tx_errors.wrapping_add(1);
                None
            }
        }
    }

    /// The next event, if any.
    pub fn poll_event(&mut self) -> Option<Event> {
        self.events.pop_front()
    }

    /// When [`handle_timeout`](Self::handle_timeout) should next be called (or `None` once
    /// closed). May be at or before the latest `now` when a frame is ready to send.
    #[must_use]
    pub fn poll_timeout(&self) -> Option<Instant> {
        if self.phase == Phase::Closed {
            return None;
        }
        let mut t: Option<Instant> = None;
        let mut consider = |x: Instant| t = Some(t.map_or(x, |t| t.min(x)));
        if self.has_pending_tx() {
            consider(self.next_tx_allowed().max(self.now));
        }
        if self.phase == Phase::Running {
            consider(self.next_status);
            if self.keepalive_active() {
                consider(self.next_keepalive);
            }
            if self.link_up != Some(false) {
                consider(self.last_rx + self.cfg.link_timeout);
            }
            if let Some(t) = self.reinit_at {
                consider(t);
            }
            if self.target != VelocityCommand::ZERO {
                consider(self.last_cmd_at + self.cfg.command_timeout);
            }
        }
        t
    }
}

/// Bytes a transmit buffer needs.
pub const TX_BUF: usize = MAX_WIRE_FRAME;

ima_serial::impl_machine!(Machine, Event, |m, now, buf| {
    // Time passes to `now` first (frames keep their minimum gap).
    m.advance(now);
    m.poll_transmit(buf)
});

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn config_conversions_are_the_atrv_jr_units() {
        let cfg = Config::default();
        assert!((cfg.translation_si(90_810.0) - 1.0).abs() < 1e-12);
        assert!((cfg.rotation_si(-37_000.0) + 1.0).abs() < 1e-12);
        assert!((cfg.battery_v(2630) - 27.5).abs() < 1e-12);
        assert!((cfg.sonar_range_m(1476) - 1.0).abs() < 1e-12);
        assert_eq!(
            cfg.sonar_range_m(u16::MAX),
            cfg.sonar_range_m(cfg.sonar_max_raw),
            "clipped: no echo"
        );
    }

    #[test]
    fn set_dir_si_inverts_the_set_dir_pair() {
        let m = Machine::new(Config::default(), Instant::ZERO);
        let cmd = VelocityCommand::new(-0.4, 0.7);
        let [t, r] = m.set_dir_pair(cmd);
        let (v, acc) = m.config().set_dir_si(&t).unwrap();
        assert!(
            (v + 0.4).abs() < 1e-5 && (acc - 0.7).abs() < 1e-5,
            "{v} {acc}"
        );
        let (w, _) = m.config().set_dir_si(&r).unwrap();
        assert!((w - 0.7).abs() < 1e-4, "{w}");
        let other = SetDir { axis: 2, ..t };
        assert_eq!(m.config().set_dir_si(&other), None);
    }
}

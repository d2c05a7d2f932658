//! The P2OS client session, sans-IO.
//!
//! [`Machine`] holds everything a host needs to talk to a Pioneer: the handshake with baud
//! probing (spec §5.1), the stale-session CLOSE (§10 item 6), motor enabling checked through
//! the FLAGS bit (§10 item 7), a keep-alive so the robot's 2 s watchdog never fires while the
//! host is alive (§5.2, §10 item 8), a host-side command timeout that stops the robot when the
//! *caller* goes quiet, odometry with the 15-bit unwrap (§7.2), plausibility checks that catch
//! corrupted SIPs the weak checksum lets through (§10 item 13), and link-loss detection with
//! reconnection.
//!
//! It does no I/O and never reads a clock. Drive it with:
//! * [`Machine::connect`] once, then
//! * [`Machine::handle_bytes`] with every chunk of bytes read from the port,
//! * [`Machine::handle_timeout`] whenever [`Machine::poll_timeout`]'s instant has passed,
//! * [`Machine::poll_transmit`] until it returns `None`, writing each frame to the port,
//! * [`Machine::poll_event`] until it returns `None`.
//!
//! Commands ([`Machine::set_velocity`], [`Machine::enable_motors`], …) queue frames; the
//! session paces them at least [`Config::command_spacing`] apart (§5.2).

use core::time::Duration;

use heapless::{Deque, String, Vec};
use ima_hal::base::{BaseLimits, BumperState, Odometry, VelocityCommand};
use ima_hal::power::PowerState;
use ima_hal::sonar::{SonarReading, SonarScan};
use ima_hal::{Instant, Isometry2, Stamped, normalize_angle};

use crate::framer::{FrameEvent, Framer, FramerStats};
use crate::params::RobotParams;
use crate::wire::{self, Command, EncodeOptions, IntCommand, Packet, Sip};

/// Serial rates P2OS supports, in the order they are probed (spec §1, §10 item 5).
pub const DEFAULT_BAUDS: [u32; 5] = [9600, 19200, 38400, 57600, 115200];

/// Machine settings. `Config::default()` suits a P2-AT on a serial line.
#[derive(Debug, Clone, PartialEq)]
pub struct Config {
    /// Rates to probe, in order (at most 8).
    pub bauds: Vec<u32, 8>,
    /// How long to wait for each handshake reply.
    pub sync_step_timeout: Duration,
    /// Handshake attempts at one rate before trying the next.
    pub syncs_per_baud: u8,
    /// After sending CLOSE to a stale session, wait this long (ignoring input) before SYNC0.
    pub close_settle: Duration,
    /// Full probe sweeps before giving up with [`Event::HandshakeFailed`]; `None` = forever.
    pub max_sweeps: Option<u32>,
    /// Send PULSE when nothing else was sent for this long (must be well under the robot's
    /// 2 s watchdog).
    pub keepalive_interval: Duration,
    /// Stop the robot when the caller has not refreshed a non-zero velocity for this long;
    /// `None` disables the host-side timeout (the robot's own watchdog still applies).
    pub command_timeout: Option<Duration>,
    /// No SIP for this long on an open session means the link is lost; the session then
    /// reconnects.
    pub sip_timeout: Duration,
    /// How long to wait for FLAGS to confirm ENABLE before resending.
    pub motor_enable_timeout: Duration,
    /// ENABLE attempts before reporting [`Event::MotorsRefused`].
    pub motor_enable_attempts: u8,
    /// Minimum gap between two frames sent (P2OS wants 3–5 ms).
    pub command_spacing: Duration,
    /// Abandon a partial frame when the line is quiet this long inside it (spec §10 item 2).
    pub inter_byte_timeout: Duration,
    /// Use these parameters whatever the robot's subclass (required for unknown subclasses).
    pub params_override: Option<RobotParams>,
    /// Encoder ticks per mm of wheel travel, for ENCODER packets (thesis: 19).
    pub ticks_per_mm: f64,
    /// Turn the sonar on after opening.
    pub enable_sonar: bool,
    /// Ask for one CONFIG packet after opening.
    pub request_config: bool,
    /// How commands are encoded where clients differ.
    pub encode: EncodeOptions,
    /// An unchanged velocity command is re-sent at most this often (it is only re-asserted in
    /// case a frame was lost; the keep-alive feeds the watchdog). A changed one goes at once.
    pub velocity_resend_interval: Duration,
    /// Consecutive implausible SIPs after which the odometry is re-based on the robot's
    /// values rather than rejected forever (a robot reset or a SETO from elsewhere).
    pub rebase_after_implausible: u8,
    /// How many times faster than the driver's clock the robot's world runs: 1 on a robot;
    /// a sped-up simulated world's factor. The odometry plausibility checks allow position
    /// and heading jumps between SIPs this many times larger (a value below 1 or not finite
    /// counts as 1).
    pub motion_time_scale: f64,
}

impl Default for Config {
    fn default() -> Self {
        Self {
            bauds: Vec::from_slice(&DEFAULT_BAUDS).unwrap_or_default(),
            sync_step_timeout: Duration::from_millis(300),
            syncs_per_baud: 2,
            close_settle: Duration::from_millis(400),
            max_sweeps: None,
            keepalive_interval: Duration::from_millis(400),
            command_timeout: Some(Duration::from_millis(1000)),
            sip_timeout: Duration::from_millis(700),
            motor_enable_timeout: Duration::from_millis(600),
            motor_enable_attempts: 3,
            command_spacing: Duration::from_millis(5),
            inter_byte_timeout: Duration::from_millis(100),
            params_override: None,
            ticks_per_mm: crate::params::DEFAULT_TICKS_PER_MM,
            enable_sonar: true,
            request_config: true,
            encode: EncodeOptions::default(),
            rebase_after_implausible: 3,
            motion_time_scale: 1.0,
            velocity_resend_interval: Duration::from_millis(500),
        }
    }
}

/// Who the robot said it is in its SYNC2 reply.
#[derive(Debug, Clone, PartialEq)]
pub struct RobotIdentity {
    /// Robot name (FLASH).
    pub name: String<32>,
    /// Class, e.g. "Pioneer".
    pub class: String<32>,
    /// Subclass, e.g. "p2at".
    pub subclass: String<32>,
}

/// The owned part of a CONFIG packet a host cares about.
#[derive(Debug, Clone, PartialEq)]
pub struct RobotConfig {
    /// Subclass reported in CONFIG.
    pub subtype: String<32>,
    /// Serial number.
    pub serial: String<32>,
    /// Firmware version.
    pub firmware: String<64>,
    /// The numeric fields.
    pub numbers: wire::ConfigNumbers,
    /// Top translational velocity, mm/s.
    pub trans_vel_top: u16,
    /// Top rotational velocity, deg/s.
    pub rot_vel_top: u16,
}

/// One SIP's worth of state, in SI units.
#[derive(Debug, Clone, PartialEq)]
pub struct RobotState {
    /// Integrated odometry (origin at connect or the last reset).
    pub odometry: Stamped<Odometry>,
    /// Latest reading of every sonar that has reported.
    pub sonar: Stamped<SonarScan>,
    /// Whether this SIP brought new sonar readings.
    pub new_sonar: bool,
    /// Bumpers and stalls.
    pub bumpers: Stamped<BumperState>,
    /// Battery.
    pub power: Stamped<PowerState>,
    /// Motors enabled (FLAGS bit 0).
    pub motors_enabled: bool,
    /// The robot reports it is moving (SIP type 0x33).
    pub moving: bool,
    /// The SIP itself, raw units (what the checks accepted).
    pub sip: Sip,
}

/// Why a session stopped streaming.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DisconnectReason {
    /// No SIP for [`Config::sip_timeout`].
    LinkLost,
    /// The caller closed the session.
    Closed,
}

/// What the session tells its owner.
// `State` is large (a whole sonar scan) by design: the core has no heap, and events are moved
// out one at a time.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, PartialEq)]
pub enum Event {
    /// Set the host's line speed to this rate now (before the next transmit).
    SetBaud(u32),
    /// Discard pending input (after closing a stale session).
    FlushInput,
    /// The session is open and the first SIP arrived.
    Connected {
        /// Who answered.
        identity: RobotIdentity,
        /// The parameter table in use.
        params: RobotParams,
        /// The line speed that worked.
        baud: u32,
    },
    /// The robot's subclass has no parameter table and no override was configured. The
    /// session stops (state [`SessionState::Failed`]).
    UnsupportedRobot(RobotIdentity),
    /// Every probe sweep failed ([`Config::max_sweeps`]); the session stopped trying.
    HandshakeFailed,
    /// The session stopped streaming; unless closed by the caller it is reconnecting.
    Disconnected(DisconnectReason),
    /// A SIP's state.
    State(RobotState),
    /// FLAGS bit 0 changed, or an enable/disable request was confirmed.
    MotorsEnabled(bool),
    /// ENABLE was sent [`Config::motor_enable_attempts`] times and FLAGS never confirmed it
    /// (motors switch off or E-stop engaged, spec §10 item 7).
    MotorsRefused,
    /// The caller did not refresh a non-zero velocity within [`Config::command_timeout`]; the
    /// session commanded zero velocity.
    CommandTimeout,
    /// A CONFIG packet.
    Config(RobotConfig),
    /// An ENCODER packet, converted with [`Config::ticks_per_mm`].
    Encoder {
        /// Left wheel travel, metres.
        left_m: f64,
        /// Right wheel travel, metres.
        right_m: f64,
        /// Raw left count.
        left_ticks: i32,
        /// Raw right count.
        right_ticks: i32,
        /// Reception time.
        at: Instant,
    },
}

/// Where the session is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SessionState {
    /// [`Machine::connect`] not called yet.
    Idle,
    /// Running the SYNC0–SYNC2 handshake.
    Syncing,
    /// Waiting after a CLOSE to a stale session.
    ClosingStale,
    /// OPEN sent; waiting for the first SIP.
    Opening,
    /// SIPs are streaming.
    Open,
    /// Closed by the caller.
    Closed,
    /// Gave up (handshake sweeps exhausted or unsupported robot).
    Failed,
}

/// Why a command was not queued.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SessionError {
    /// The session is not open.
    NotConnected,
    /// An argument was not finite.
    InvalidArgument,
    /// The transmit queue is full.
    QueueFull,
}

impl core::fmt::Display for SessionError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::NotConnected => "P2OS session is not connected",
            Self::InvalidArgument => "argument is not a finite number",
            Self::QueueFull => "P2OS transmit queue is full",
        })
    }
}

impl core::error::Error for SessionError {}

impl ima_hal::Error for SessionError {
    fn kind(&self) -> ima_hal::ErrorKind {
        match self {
            Self::NotConnected => ima_hal::ErrorKind::Disconnected,
            Self::InvalidArgument => ima_hal::ErrorKind::InvalidArgument,
            Self::QueueFull => ima_hal::ErrorKind::Other,
        }
    }
}

/// Counters of everything the session dropped or noticed.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SessionStats {
    /// The framer's counters.
    pub framer: FramerStats,
    /// Frames with a good checksum that did not parse.
    pub parse_errors: u64,
    /// SIPs rejected by the plausibility checks (spec §10 item 13).
    pub implausible_sips: u64,
    /// SIPs delivered.
    pub sips: u64,
    /// Packets of types the session does not use.
    pub unknown_packets: u64,
    /// Frames sent.
    pub frames_sent: u64,
    /// Times a lost link was re-established.
    pub reconnects: u64,
    /// Events dropped because the caller did not drain the queue.
    pub events_dropped: u64,
    /// Host-side command timeouts.
    pub command_timeouts: u64,
}

type Frame = Vec<u8, { wire::MAX_FRAME_LEN }>;

#[derive(Debug, Clone)]
struct Queued {
    frame: Frame,
    /// Frames for the same command number replace each other while queued (latest wins).
    replace_key: Option<u8>,
}

#[derive(Debug, Clone, Copy, Default)]
struct OdoTrack {
    prev: Option<(u16, u16, i16, Instant)>,
    x_mm: f64,
    y_mm: f64,
    theta: f64,
    origin: Option<Isometry2>,
    heading_offset: f64,
    implausible_run: u8,
}

/// The P2OS client session. See the [module docs](self).
#[derive(Debug)]
pub struct Machine {
    cfg: Config,
    state: SessionState,
    framer: Framer,
    tx: Deque<Queued, 16>,
    events: Deque<Event, 16>,
    stats: SessionStats,
    last_tx: Option<Instant>,
    last_rx: Option<Instant>,
    // handshake
    step: u8,
    deadline: Option<Instant>,
    baud_idx: usize,
    attempts_at_baud: u8,
    probes: u32,
    last_good_baud: Option<u32>,
    open_baud: Option<u32>,
    identity: Option<RobotIdentity>,
    // open session
    params: Option<RobotParams>,
    last_sip: Option<Instant>,
    was_connected: bool,
    motors: Option<bool>,
    motors_wanted: Option<bool>,
    enable_deadline: Option<Instant>,
    enable_attempts: u8,
    velocity: (i16, i16),
    velocity_sent_at: Option<Instant>,
    cmd_deadline: Option<Instant>,
    odo: OdoTrack,
    sonar: SonarScan,
}

fn owned<const N: usize>(bytes: &[u8]) -> String<N> {
    let mut s = String::new();
    for &b in bytes {
        let c = if b.is_ascii_graphic() || b == b' ' {
            b as char
        } else {
            '?'
        };
        if s.push(c).is_err() {
            break;
        }
    }
    s
}

impl Machine {
    /// A session with `cfg`, not yet connecting.
    #[must_use]
    pub fn new(cfg: Config) -> Self {
        Self {
            cfg,
            state: SessionState::Idle,
            framer: Framer::new(),
            tx: Deque::new(),
            events: Deque::new(),
            stats: SessionStats::default(),
            last_tx: None,
            last_rx: None,
            step: 0,
            deadline: None,
            baud_idx: 0,
            attempts_at_baud: 0,
            probes: 0,
            last_good_baud: None,
            open_baud: None,
            identity: None,
            params: None,
            last_sip: None,
            was_connected: false,
            motors: None,
            motors_wanted: None,
            enable_deadline: None,
            enable_attempts: 0,
            velocity: (0, 0),
            velocity_sent_at: None,
            cmd_deadline: None,
            odo: OdoTrack::default(),
            sonar: SonarScan::default(),
        }
    }

    /// The configuration.
    #[must_use]
    pub fn config(&self) -> &Config {
        &self.cfg
    }

    /// Where the session is.
    #[must_use]
    pub fn state(&self) -> SessionState {
        self.state
    }

    /// Counters.
    #[must_use]
    pub fn stats(&self) -> SessionStats {
        SessionStats {
            framer: self.framer.stats(),
            ..self.stats
        }
    }

    /// The parameter table in use once connected.
    #[must_use]
    pub fn params(&self) -> Option<&RobotParams> {
        self.params.as_ref()
    }

    /// Speed limits of the connected robot (the p2at table's before connecting).
    #[must_use]
    pub fn limits(&self) -> BaseLimits {
        let p = self.params.as_ref().unwrap_or(&crate::params::P2AT);
        BaseLimits {
            max_v_m_s: p.max_velocity_mm_s / 1000.0,
            max_omega_rad_s: p.max_rot_velocity_deg_s.to_radians(),
        }
    }

    /// Whether SIPs are streaming.
    #[must_use]
    pub fn is_open(&self) -> bool {
        self.state == SessionState::Open
    }

    /// Whether frames are queued that [`poll_transmit`](Self::poll_transmit) has not handed out
    /// yet (a shell that closes keeps transmitting until this is false: STOP, then CLOSE).
    #[must_use]
    pub fn has_pending_transmit(&self) -> bool {
        !self.tx.is_empty()
    }

    // ----------------------------------------------------------------------------------------
    // Caller commands
    // ----------------------------------------------------------------------------------------

    /// Start (or restart) connecting. Emits [`Event::SetBaud`] for the first rate to try.
    pub fn connect(&mut self, now: Instant) {
        self.probes = 0;
        self.baud_idx = 0;
        self.attempts_at_baud = 0;
        let baud = self.current_baud();
        self.push_event(Event::SetBaud(baud));
        self.start_sync(now);
    }

    /// Command a body velocity. It is clamped to the robot's limits and sent as VEL (mm/s) and
    /// RVEL (deg/s); it must be refreshed within [`Config::command_timeout`] or the session
    /// stops the robot.
    pub fn set_velocity(&mut self, cmd: VelocityCommand, now: Instant) -> Result<(), SessionError> {
        if !cmd.is_finite() {
            return Err(SessionError::InvalidArgument);
        }
        self.require_open()?;
        let lim = self.limits();
        let v_mm_s = libm::round(cmd.v_m_s.clamp(-lim.max_v_m_s, lim.max_v_m_s) * 1000.0);
        let w_deg_s = libm::round(
            cmd.omega_rad_s
                .clamp(-lim.max_omega_rad_s, lim.max_omega_rad_s)
                .to_degrees(),
        );
        let (v, w) = (v_mm_s as i16, w_deg_s as i16);
        let unchanged = self.velocity == (v, w)
            && self
                .velocity_sent_at
                .is_some_and(|t| now < t + self.cfg.velocity_resend_interval);
        self.velocity = (v, w);
        self.cmd_deadline = if (v, w) != (0, 0) {
            self.cfg.command_timeout.map(|t| now + t)
        } else {
            None
        };
        if unchanged {
            return Ok(());
        }
        self.velocity_sent_at = Some(now);
        self.queue_velocity(v, w)
    }

    /// Decelerate to a stop (STOP); motors stay enabled.
    pub fn stop(&mut self) -> Result<(), SessionError> {
        self.require_open()?;
        self.velocity = (0, 0);
        self.velocity_sent_at = None;
        self.cmd_deadline = None;
        self.queue(Command::Stop, None)
    }

    /// Emergency stop (E_STOP).
    pub fn emergency_stop(&mut self) -> Result<(), SessionError> {
        self.require_open()?;
        self.velocity = (0, 0);
        self.velocity_sent_at = None;
        self.cmd_deadline = None;
        self.queue(Command::EStop, None)
    }

    /// Enable or disable the motors; confirmed by [`Event::MotorsEnabled`] once FLAGS agrees,
    /// or [`Event::MotorsRefused`] after the configured attempts.
    pub fn enable_motors(&mut self, on: bool, now: Instant) -> Result<(), SessionError> {
        self.require_open()?;
        self.motors_wanted = Some(on);
        self.enable_attempts = 1;
        self.enable_deadline = Some(now + self.cfg.motor_enable_timeout);
        self.queue(Command::enable(on), Some(4))
    }

    /// Turn the sonar on or off.
    pub fn set_sonar(&mut self, on: bool) -> Result<(), SessionError> {
        self.require_open()?;
        self.queue(Command::Int(IntCommand::Sonar, i16::from(on)), Some(28))
    }

    /// Ask for ENCODER packets: 0 stop, 1 one, 2 continuous.
    pub fn request_encoder(&mut self, mode: u8) -> Result<(), SessionError> {
        self.require_open()?;
        self.queue(Command::Int(IntCommand::Encoder, i16::from(mode)), Some(19))
    }

    /// Ask for one CONFIG packet.
    pub fn request_config(&mut self) -> Result<(), SessionError> {
        self.require_open()?;
        self.queue(Command::Int(IntCommand::Config, 1), Some(18))
    }

    /// Queue any command (for tools). Fails if the session is not open.
    pub fn send(&mut self, cmd: Command<'_>) -> Result<(), SessionError> {
        self.require_open()?;
        self.queue(cmd, None)
    }

    /// Make the current pose the odometry origin. Done on the host side (no SETO), so SIPs
    /// in flight cannot undo it.
    pub fn reset_odometry(&mut self) {
        let raw = Isometry2::new(
            ima_hal::Vector2::new(self.odo.x_mm / 1000.0, self.odo.y_mm / 1000.0),
            self.odo.theta,
        );
        self.odo.origin = Some(raw);
    }

    /// Stop the robot and close the session (STOP then CLOSE, spec §5.2).
    ///
    /// Also while reconnecting after a link loss: a robot that went quiet for less than its
    /// watchdog still runs the last session's commands (it drove on at 0.3 m/s when closing
    /// sent nothing), so it gets STOP and CLOSE at the rate that session used, ahead of any
    /// handshake frame still queued; and while closing a stale session just heard, at the
    /// line's rate.
    pub fn close(&mut self) {
        let open = matches!(self.state, SessionState::Open | SessionState::Opening);
        // A stale session was just heard at the line's rate: STOP and CLOSE go there.
        let stale = self.state == SessionState::ClosingStale;
        let reconnecting =
            stale || (self.state == SessionState::Syncing && self.last_good_baud.is_some());
        if reconnecting {
            self.tx.clear();
            if let Some(good) = self.last_good_baud
                && !stale
                && good != self.current_baud()
            {
                self.push_event(Event::SetBaud(good));
            }
        }
        if open || reconnecting {
            let _ = self.queue(Command::Stop, None);
            let _ = self.queue(Command::CLOSE, None);
            self.push_event(Event::Disconnected(DisconnectReason::Closed));
        }
        self.state = SessionState::Closed;
        self.deadline = None;
        self.cmd_deadline = None;
        self.enable_deadline = None;
    }

    /// After [`close`](Self::close), queue STOP and CLOSE again (once the last ones are
    /// written): for a link that was down as it closed, where a stop written into the dead
    /// line is lost, and a robot that drove on until its watchdog met the line again while the
    /// host still ran. Does nothing before `close`.
    pub fn repeat_close(&mut self) {
        if self.state == SessionState::Closed && self.tx.is_empty() {
            let _ = self.queue(Command::Stop, None);
            let _ = self.queue(Command::CLOSE, None);
        }
    }

    // ----------------------------------------------------------------------------------------
    // I/O side
    // ----------------------------------------------------------------------------------------

    /// Bytes read from the port at `now`.
    pub fn handle_bytes(&mut self, bytes: &[u8], now: Instant) {
        self.last_rx = Some(now);
        let mut input = bytes;
        loop {
            let n = self.framer.feed(input);
            input = input.get(n..).unwrap_or(&[]);
            loop {
                let payload: Frame = match self.framer.next_frame() {
                    None => break,
                    Some(FrameEvent::Rejected(_)) => continue,
                    Some(FrameEvent::Frame(p)) => match Vec::from_slice(p) {
                        Ok(v) => v,
                        Err(_) => continue,
                    },
                };
                match Packet::parse(&payload) {
                    Ok(p) => self.handle_packet(p, now),
                    Err(_) => self.stats.parse_errors += 1,
                }
            }
            if input.is_empty() || n == 0 {
                break;
            }
        }
    }

    /// The next frame to write, if one is due at `now`; returns its length in `buf`.
    /// Frames are spaced at least [`Config::command_spacing`] apart.
    pub fn poll_transmit(&mut self, now: Instant, buf: &mut [u8]) -> Option<usize> {
        if let Some(last) = self.last_tx
            && now < last + self.cfg.command_spacing
        {
            return None;
        }
        let q = self.tx.front()?;
        let n = q.frame.len();
        let dst = buf.get_mut(..n)?;
        dst.copy_from_slice(&q.frame);
        self.tx.pop_front();
        self.last_tx = Some(now);
        self.stats.frames_sent += 1;
        Some(n)
    }

    /// The next event, if any.
    pub fn poll_event(&mut self) -> Option<Event> {
        self.events.pop_front()
    }

    /// When [`handle_timeout`](Self::handle_timeout) must next be called.
    #[must_use]
    pub fn poll_timeout(&self) -> Option<Instant> {
        let mut t: Option<Instant> = None;
        let mut consider = |x: Option<Instant>| {
            if let Some(x) = x {
                t = Some(t.map_or(x, |t| t.min(x)));
            }
        };
        consider(self.deadline);
        if !self.tx.is_empty() {
            consider(self.last_tx.map(|l| l + self.cfg.command_spacing));
        }
        if self.framer.buffered() > 0 {
            consider(self.last_rx.map(|r| r + self.cfg.inter_byte_timeout));
        }
        if matches!(self.state, SessionState::Open) {
            consider(self.last_tx.map(|l| l + self.cfg.keepalive_interval));
            consider(self.last_sip.map(|l| l + self.cfg.sip_timeout));
            consider(self.cmd_deadline);
            consider(self.enable_deadline);
        }
        t
    }

    /// Run every timer due at `now`.
    pub fn handle_timeout(&mut self, now: Instant) {
        if self.framer.buffered() > 0
            && self
                .last_rx
                .is_some_and(|r| now >= r + self.cfg.inter_byte_timeout)
        {
            self.framer.abandon_partial();
            // Rescan what is left, now that the partial frame is gone.
            self.handle_bytes(&[], now);
        }
        match self.state {
            SessionState::Syncing | SessionState::Opening => {
                if self.deadline.is_some_and(|d| now >= d) {
                    self.sync_timed_out(now);
                }
            }
            SessionState::ClosingStale => {
                if self.deadline.is_some_and(|d| now >= d) {
                    self.framer.clear();
                    self.push_event(Event::FlushInput);
                    self.start_sync(now);
                }
            }
            SessionState::Open => self.open_timers(now),
            SessionState::Idle | SessionState::Closed | SessionState::Failed => {}
        }
    }

    // ----------------------------------------------------------------------------------------
    // Internals
    // ----------------------------------------------------------------------------------------

    fn require_open(&self) -> Result<(), SessionError> {
        if self.state == SessionState::Open {
            Ok(())
        } else {
            Err(SessionError::NotConnected)
        }
    }

    fn push_event(&mut self, ev: Event) {
        if self.events.is_full() {
            // Keep the newest: drop the oldest event.
            self.events.pop_front();
            self.stats.events_dropped += 1;
        }
        let _ = self.events.push_back(ev);
    }

    fn queue(&mut self, cmd: Command<'_>, replace_key: Option<u8>) -> Result<(), SessionError> {
        let mut buf = [0u8; wire::MAX_FRAME_LEN];
        let n = cmd
            .emit_with(self.cfg.encode, &mut buf)
            .map_err(|_| SessionError::InvalidArgument)?;
        let frame = Frame::from_slice(buf.get(..n).unwrap_or(&[]))
            .map_err(|_| SessionError::InvalidArgument)?;
        if let Some(key) = replace_key
            && let Some(q) = self.tx.iter_mut().find(|q| q.replace_key == Some(key))
        {
            q.frame = frame;
            return Ok(());
        }
        self.tx
            .push_back(Queued { frame, replace_key })
            .map_err(|_| SessionError::QueueFull)
    }

    fn queue_velocity(&mut self, v: i16, w: i16) -> Result<(), SessionError> {
        self.queue(Command::Int(IntCommand::Vel, v), Some(11))?;
        self.queue(Command::Int(IntCommand::RVel, w), Some(21))
    }

    fn current_baud(&self) -> u32 {
        // After a link loss, every other probe goes back to the rate that last worked, so a
        // robot that comes back is found quickly (spec §10 item 5 wants 100–200 ms gaps).
        if let Some(good) = self.last_good_baud
            && self.probes.is_multiple_of(2)
        {
            return good;
        }
        self.cfg
            .bauds
            .get(self.baud_idx % self.cfg.bauds.len().max(1))
            .copied()
            .unwrap_or(9600)
    }

    /// Queue a handshake from SYNC0, behind a STOP. A session left open by a client that died
    /// (SIGKILL, a power cut) has its robot stopped by the watchdog, which the next command
    /// revives: the robot re-accelerates to the old setpoints (§5.2, §10 item 8). SYNC0 is such
    /// a command on an open session (a PULSE), so a handshake alone drove the robot on at the
    /// dead client's speed until the stale-session CLOSE (88 ms later in a run against the
    /// mock). The STOP zeroes the setpoints first; a robot waiting for SYNC0 ignores it.
    fn start_sync(&mut self, now: Instant) {
        self.start_sync_closing(now, false);
    }

    /// [`start_sync`](Self::start_sync), with a CLOSE between the STOP and SYNC0 when
    /// `close_first`.
    fn start_sync_closing(&mut self, now: Instant, close_first: bool) {
        self.state = SessionState::Syncing;
        self.step = 0;
        self.tx.clear();
        let _ = self.queue(Command::Stop, None);
        if close_first {
            let _ = self.queue(Command::CLOSE, None);
        }
        let _ = self.queue(Command::Sync0, None);
        self.deadline = Some(now + self.cfg.sync_step_timeout);
    }

    fn sync_timed_out(&mut self, now: Instant) {
        self.attempts_at_baud = self.attempts_at_baud.saturating_add(1);
        if self.attempts_at_baud >= self.cfg.syncs_per_baud.max(1) {
            self.attempts_at_baud = 0;
            let before = self.current_baud();
            self.probes = self.probes.saturating_add(1);
            if self.last_good_baud.is_none() || self.probes % 2 == 1 {
                self.baud_idx += 1;
            }
            let sweep_len = self.cfg.bauds.len().max(1);
            if self.last_good_baud.is_none() && self.baud_idx.is_multiple_of(sweep_len) {
                let sweeps = (self.baud_idx / sweep_len) as u32;
                if self.cfg.max_sweeps.is_some_and(|m| sweeps >= m) {
                    self.state = SessionState::Failed;
                    self.deadline = None;
                    self.tx.clear();
                    self.push_event(Event::HandshakeFailed);
                    return;
                }
            }
            let after = self.current_baud();
            if after != before {
                self.framer.clear();
                self.push_event(Event::SetBaud(after));
            }
            self.start_sync(now);
        } else {
            // A robot stuck mid-handshake, or one whose session we lost track of, may sit
            // silent: a CLOSE before the next SYNC0 dislodges it (ARIA's habit, §5.1).
            self.start_sync_closing(now, self.attempts_at_baud == 1);
        }
    }

    fn handle_packet(&mut self, p: Packet<'_>, now: Instant) {
        match self.state {
            SessionState::Syncing => self.handle_sync_reply(p, now),
            SessionState::Opening | SessionState::Open => match p {
                Packet::Sip(sip) => self.handle_sip(&sip, now),
                Packet::Config(c) => {
                    let cfg = RobotConfig {
                        subtype: owned(c.subtype),
                        serial: owned(c.serial),
                        firmware: owned(c.firmware),
                        numbers: c.numbers,
                        trans_vel_top: c.trans_vel_top,
                        rot_vel_top: c.rot_vel_top,
                    };
                    self.push_event(Event::Config(cfg));
                }
                Packet::Encoder { left, right } => {
                    let tpm = self.cfg.ticks_per_mm;
                    self.push_event(Event::Encoder {
                        left_m: crate::params::encoder_m(left, tpm),
                        right_m: crate::params::encoder_m(right, tpm),
                        left_ticks: left,
                        right_ticks: right,
                        at: now,
                    });
                }
                _ => self.stats.unknown_packets += 1,
            },
            _ => {}
        }
    }

    fn handle_sync_reply(&mut self, p: Packet<'_>, now: Instant) {
        match (self.step, p) {
            (0, Packet::SyncEcho(0)) | (1, Packet::SyncEcho(1)) => {
                self.step += 1;
                let next = if self.step == 1 {
                    Command::Sync1
                } else {
                    Command::Sync2
                };
                let _ = self.queue(next, None);
                self.deadline = Some(now + self.cfg.sync_step_timeout);
            }
            (
                2,
                Packet::SyncReply {
                    name,
                    class,
                    subclass,
                },
            ) => {
                let identity = RobotIdentity {
                    name: owned(name),
                    class: owned(class),
                    subclass: owned(subclass),
                };
                let params = self
                    .cfg
                    .params_override
                    .or_else(|| RobotParams::for_subclass(subclass).copied());
                let Some(params) = params else {
                    self.state = SessionState::Failed;
                    self.deadline = None;
                    let _ = self.queue(Command::CLOSE, None);
                    self.push_event(Event::UnsupportedRobot(identity));
                    return;
                };
                self.identity = Some(identity);
                self.params = Some(params);
                self.state = SessionState::Opening;
                self.odo.prev = None;
                self.motors = None;
                let _ = self.queue(Command::OPEN, None);
                self.deadline = Some(now + self.cfg.sip_timeout);
            }
            (_, Packet::Sip(_)) => {
                // A session left open (spec §10 item 6): close it, let it settle, start again.
                self.tx.clear();
                let _ = self.queue(Command::CLOSE, None);
                self.state = SessionState::ClosingStale;
                self.deadline = Some(now + self.cfg.close_settle);
            }
            _ => {
                // Out of sequence: the firmware restarts at SYNC0, so do we.
                self.start_sync(now);
            }
        }
    }

    fn open_timers(&mut self, now: Instant) {
        if self
            .last_sip
            .is_some_and(|l| now >= l + self.cfg.sip_timeout)
        {
            self.push_event(Event::Disconnected(DisconnectReason::LinkLost));
            self.last_good_baud = self.open_baud.or(self.last_good_baud);
            self.probes = 0;
            self.attempts_at_baud = 0;
            self.last_sip = None;
            self.cmd_deadline = None;
            self.enable_deadline = None;
            self.start_sync(now);
            return;
        }
        if self.cmd_deadline.is_some_and(|d| now >= d) {
            self.cmd_deadline = None;
            self.velocity = (0, 0);
            self.velocity_sent_at = Some(now);
            self.stats.command_timeouts += 1;
            let _ = self.queue_velocity(0, 0);
            self.push_event(Event::CommandTimeout);
        }
        if self.enable_deadline.is_some_and(|d| now >= d) {
            if self.enable_attempts >= self.cfg.motor_enable_attempts {
                self.enable_deadline = None;
                self.motors_wanted = None;
                self.push_event(Event::MotorsRefused);
            } else if let Some(on) = self.motors_wanted {
                self.enable_attempts += 1;
                self.enable_deadline = Some(now + self.cfg.motor_enable_timeout);
                let _ = self.queue(Command::enable(on), Some(4));
            }
        }
        if self.tx.is_empty()
            && self
                .last_tx
                .is_none_or(|l| now >= l + self.cfg.keepalive_interval)
        {
            let _ = self.queue(Command::PULSE, Some(0));
        }
    }

    fn handle_sip(&mut self, sip: &Sip, now: Instant) {
        let Some(params) = self.params else { return };
        if !self.sip_is_plausible(sip, &params, now) {
            self.stats.implausible_sips += 1;
            return;
        }
        self.stats.sips += 1;
        self.last_sip = Some(now);
        if self.state == SessionState::Opening {
            self.state = SessionState::Open;
            self.deadline = None;
            let baud = self.current_baud();
            self.open_baud = Some(baud);
            if self.was_connected {
                self.stats.reconnects += 1;
            }
            self.was_connected = true;
            if let Some(identity) = self.identity.clone() {
                self.push_event(Event::Connected {
                    identity,
                    params,
                    baud,
                });
            }
            if self.cfg.enable_sonar {
                let _ = self.set_sonar(true);
            }
            if self.cfg.request_config {
                let _ = self.request_config();
            }
            // Re-establish what the caller had asked for before a link loss.
            if let Some(on) = self.motors_wanted {
                let _ = self.enable_motors(on, now);
            }
        }
        self.integrate(sip, &params, now);
        let enabled = sip.motors_enabled();
        let changed = self.motors != Some(enabled);
        self.motors = Some(enabled);
        let confirms = self.motors_wanted == Some(enabled) && self.enable_deadline.is_some();
        if confirms {
            self.enable_deadline = None;
        }
        if changed || confirms {
            self.push_event(Event::MotorsEnabled(enabled));
        }
        let mut new_sonar = false;
        for s in &sip.sonars {
            if usize::from(s.index) < params.sonars.len() {
                new_sonar = true;
                self.sonar.upsert(SonarReading {
                    index: s.index,
                    range_m: params.sonar_range_m(s.range),
                    at: now,
                });
            }
        }
        let bumpers = BumperState {
            front: (sip.stall_bumpers >> 9) & 0x1F,
            rear: (sip.stall_bumpers >> 1) & 0x1F,
            left_stall: sip.stall_bumpers & 0x0001 != 0,
            right_stall: sip.stall_bumpers & 0x0100 != 0,
        };
        let (v_m_s, omega) = params.body_velocity(sip.left_vel, sip.right_vel);
        let raw = Isometry2::new(
            ima_hal::Vector2::new(self.odo.x_mm / 1000.0, self.odo.y_mm / 1000.0),
            self.odo.theta,
        );
        let pose = match self.odo.origin {
            Some(o) => o.inverse() * raw,
            None => raw,
        };
        let state = RobotState {
            odometry: Stamped::new(
                now,
                Odometry {
                    pose,
                    v_m_s,
                    omega_rad_s: omega,
                },
            ),
            sonar: Stamped::new(now, self.sonar.clone()),
            new_sonar,
            bumpers: Stamped::new(now, bumpers),
            power: Stamped::new(
                now,
                PowerState {
                    battery_v: crate::params::battery_v(sip.battery),
                },
            ),
            motors_enabled: enabled,
            moving: sip.moving,
            sip: sip.clone(),
        };
        self.push_event(Event::State(state));
    }

    /// Checks after the checksum (spec §10 item 13): velocities within the robot's limits,
    /// position and heading jumps within what the robot can do since the previous SIP,
    /// sonar indices within the ring, battery within 5–20 V. Sonar count consistency and
    /// indices < 32 were checked by the parser.
    fn sip_is_plausible(&mut self, sip: &Sip, p: &RobotParams, now: Instant) -> bool {
        let vmax = p.max_velocity_mm_s * 1.5 / p.vel_conv;
        let ok_vel =
            f64::from(sip.left_vel).abs() <= vmax && f64::from(sip.right_vel).abs() <= vmax;
        let ok_batt = (50..=200).contains(&sip.battery);
        let ok_sonar = sip
            .sonars
            .iter()
            .all(|s| usize::from(s.index) < p.sonars.len());
        let ok_jump = match self.odo.prev {
            None => true,
            Some((px, py, pth, pt)) => {
                let k = self.cfg.motion_time_scale;
                let k = if k.is_finite() { k.max(1.0) } else { 1.0 };
                let dt = now.saturating_duration_since(pt).as_secs_f64() * k;
                let reach_mm = p.max_velocity_mm_s * 1.5 * dt + 50.0;
                let dx = f64::from(unwrap15(px, sip.xpos)) * p.dist_conv;
                let dy = f64::from(unwrap15(py, sip.ypos)) * p.dist_conv;
                let dth = f64::from(unwrap12(pth, sip.thpos)) * p.angle_conv;
                let turn = p.max_rot_velocity_deg_s.to_radians() * 1.5 * dt + 0.1;
                libm::hypot(dx, dy) <= reach_mm && dth.abs() <= turn
            }
        };
        if ok_vel && ok_batt && ok_sonar && ok_jump {
            self.odo.implausible_run = 0;
            return true;
        }
        if ok_vel && ok_batt && ok_sonar && !ok_jump {
            self.odo.implausible_run = self.odo.implausible_run.saturating_add(1);
            if self.odo.implausible_run >= self.cfg.rebase_after_implausible {
                // The robot's counters really jumped (reset, SETO from elsewhere): accept the
                // new values as the base without moving our pose.
                self.odo.prev = None;
                self.odo.implausible_run = 0;
                return true;
            }
        }
        false
    }

    fn integrate(&mut self, sip: &Sip, p: &RobotParams, now: Instant) {
        // The first SIP of a session only sets the base: the odometry frame's origin is the
        // robot's pose at connect, and after a reconnect the pose continues where it was.
        if let Some((px, py, pth, _)) = self.odo.prev {
            // Integrate the step along the mean heading of the interval (exact for arcs).
            let dth = f64::from(unwrap12(pth, sip.thpos)) * p.angle_conv;
            let dx_r = f64::from(unwrap15(px, sip.xpos)) * p.dist_conv;
            let dy_r = f64::from(unwrap15(py, sip.ypos)) * p.dist_conv;
            // The robot integrates XPOS/YPOS in its own odometry frame; rotate the step from
            // that frame into ours (they differ by the heading offset at the session start).
            let (s, c) = libm::sincos(self.odo.heading_offset);
            self.odo.x_mm += c * dx_r - s * dy_r;
            self.odo.y_mm += s * dx_r + c * dy_r;
            self.odo.theta = normalize_angle(self.odo.theta + dth);
        } else {
            // Our heading = robot heading + offset.
            self.odo.heading_offset =
                normalize_angle(self.odo.theta - f64::from(sip.thpos) * p.angle_conv);
        }
        self.odo.prev = Some((sip.xpos, sip.ypos, sip.thpos, now));
    }
}

/// The signed change between two 15-bit positions, taking the shorter way round (ARIA's rule,
/// spec §7.2): a jump over 0x1000 units is a wrap.
#[must_use]
pub fn unwrap15(prev: u16, new: u16) -> i32 {
    let mut d = i32::from(new & 0x7FFF) - i32::from(prev & 0x7FFF);
    if d > 0x1000 {
        d -= 0x8000;
    } else if d < -0x1000 {
        d += 0x8000;
    }
    d
}

/// A 15-bit position counter (XPOS/YPOS) as a signed count: the shorter way round from 0
/// (two's complement in 15 bits: 0x4000–0x7FFF are negative), the rule [`unwrap15`] applies
/// to every step of the odometry; equal to `unwrap15(0, raw)` whenever that step is within
/// its ±0x1000 window.
#[must_use]
pub fn signed15(raw: u16) -> i32 {
    let v = i32::from(raw & 0x7FFF);
    if v >= 0x4000 { v - 0x8000 } else { v }
}

/// The signed change between two headings in 4096-per-turn units, the shorter way round.
#[must_use]
pub fn unwrap12(prev: i16, new: i16) -> i32 {
    let d = (i32::from(new) - i32::from(prev)).rem_euclid(4096);
    if d >= 2048 { d - 4096 } else { d }
}

ima_serial::impl_machine!(Machine, Event, |m, now, buf| m.poll_transmit(now, buf));

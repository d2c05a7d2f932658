//! The host-side session (spec §4 "Recommended sequence", §2 timing, §6 pitfalls).
//!
//! Sans-IO: inputs are bytes ([`Machine::handle_bytes_with`]) or pre-framed items
//! ([`Machine::handle_frame`], [`Machine::handle_ack`], [`Machine::handle_nak`]) and timer
//! expiry ([`Machine::handle_timeout`]); outputs are telegrams ([`Machine::poll_transmit`]),
//! [`Event`]s ([`Machine::poll_event`]) and the next deadline ([`Machine::poll_timeout`]).
//!
//! **Shell contract.** Drain [`Machine::poll_event`] *before* [`Machine::poll_transmit`]: an
//! [`Event::SetHostBaud`] must take effect (set the UART rate and flush its input) before the
//! next telegram is written.
//!
//! # Initialisation (spec §4)
//!
//! 1. Optional power-up wait: up to [`Config::power_up_wait`] for the `90` telegram.
//! 2. Baud probe: for each rate of 9600, 38400, 19200 (and 500 000 with [`Config::rs422`]):
//!    [`Event::SetHostBaud`], then `20 25` (stops any stream); no ACK within 60 ms (plus one
//!    frame time at that rate, since a running stream may delay it) means "next rate". The
//!    whole list is tried [`Config::probe_rounds`] times.
//! 3. `3A` (type), `31` (status: bits 0–2 of `S` and byte 9 checked).
//! 4. If the rate differs from [`Config::baud`]: `20 4x`, `A0` at the old rate,
//!    [`Event::SetHostBaud`], wait [`Timeouts::settle`], verify with `31`. A failed change is
//!    never retried blindly: the machine re-probes. The permanent-baud flag is never set
//!    (no such command is ever emitted).
//! 5. If [`Config::variant`] differs from the status: `3B`, expecting `BB 01` and the echo.
//! 6. `74`; only if availability, measuring mode or units differ: `20 00 <password>`, `77`
//!    (≤ 15 s), `F7` checked, `20 25`.
//! 7. `20 24` when streaming is wanted, then [`Event::Ready`].
//!
//! # Requests
//!
//! One request at a time (`A0` does not say which `20` sub-mode it confirms). A reply matches
//! by request code + `0x80`; B0 frames keep flowing to the data path meanwhile. A NAK is
//! retried after ≥ 30 ms; a missing ACK or reply is retried up to [`Config::retries`] times.
//! A `92` rejection fails the request at once.

use core::time::Duration;

use ima_hal::Instant;

use crate::decode::Variant;
use crate::framer::{Counters, Framer, Item};
use crate::wire::{
    BaudRate, Command, DEFAULT_PASSWORD, LmsConfig, MeasuringMode, ModeRequest, Reply, Scan,
    StatusByte, expected_reply,
};

/// Largest host telegram the machine emits (`77` with a 34-byte config is 41 bytes).
pub const MAX_COMMAND: usize = 48;

/// The timing table of spec §2.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Timeouts {
    /// ACK/NAK after a host telegram (60 ms). One maximum frame time at the current rate is
    /// added, because a running stream may send the rest of a B0 first.
    pub ack: Duration,
    /// Default reply wait (1 s, STB), plus one maximum frame time at the current rate.
    pub reply: Duration,
    /// Operating-mode change reply (3 s).
    pub mode_change: Duration,
    /// Config write reply (15 s, STB; QM says up to ~7 s).
    pub config_write: Duration,
    /// Wait after a NAK before retransmitting (≥ 30 ms).
    pub nak_backoff: Duration,
    /// Settle after switching the host rate (250 ms, STB; PLY waits 1 s).
    pub settle: Duration,
    /// Reset confirmation `91` after `10` (STB: ≤ 60 s).
    pub reset: Duration,
    /// Power-on telegram `90` after a reset (TL: ≤ 60 s; STB waits 30 s more after `91`).
    pub power_on: Duration,
}

impl Default for Timeouts {
    fn default() -> Self {
        Self {
            ack: Duration::from_millis(60),
            reply: Duration::from_secs(1),
            mode_change: Duration::from_secs(3),
            config_write: Duration::from_secs(15),
            nak_backoff: Duration::from_millis(30),
            settle: Duration::from_millis(250),
            reset: Duration::from_secs(60),
            power_on: Duration::from_secs(60),
        }
    }
}

/// What the session should set up.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Config {
    /// Rate to run at (switched to after the probe).
    pub baud: BaudRate,
    /// An RS-422 link is present: 500 000 baud is probed and may be chosen.
    pub rs422: bool,
    /// Variant to set, or `None` to keep the device's.
    pub variant: Option<Variant>,
    /// Config byte 4 (availability) to set, or `None` to keep.
    pub availability: Option<u8>,
    /// Config byte 5 (measuring mode) to set, or `None` to keep.
    pub measuring_mode: Option<MeasuringMode>,
    /// Config byte 6 (units: 0 cm, 1 mm) to set, or `None` to keep.
    pub units: Option<u8>,
    /// Start the B0 stream (`20 24`) at the end of initialisation.
    pub stream: bool,
    /// Wait up to this long for the power-on telegram `90` before probing (the unit is busy up
    /// to 60 s after power-up; some robots power it when the port opens). `None`: probe at once.
    pub power_up_wait: Option<Duration>,
    /// Installation-mode password (TL: `SICK_LMS`; PLY derives it from the type string).
    pub password: [u8; 8],
    /// Retransmissions after the first attempt (STB/PLY: 3).
    pub retries: u8,
    /// Times the whole probe list is tried before giving up.
    pub probe_rounds: u8,
    /// Re-probes allowed after a failed baud change or verification.
    pub max_reprobes: u8,
    /// Accept an `F7` result of `00` as success (QM) besides `01` (TL).
    pub config_write_zero_ok: bool,
    /// While streaming, no B0 for this long (plus one maximum frame time at the current rate)
    /// means the unit is gone or rebooted at another rate: [`MachineError::StreamStalled`] and
    /// a fresh probe. `None` disables the watchdog.
    pub stream_watchdog: Option<Duration>,
    /// Timing.
    pub timeouts: Timeouts,
}

impl Default for Config {
    fn default() -> Self {
        Self {
            baud: BaudRate::B38400,
            rs422: false,
            variant: Some(Variant::W180_R50),
            availability: None,
            measuring_mode: None,
            units: Some(1),
            stream: true,
            power_up_wait: None,
            password: DEFAULT_PASSWORD,
            retries: 3,
            probe_rounds: 2,
            max_reprobes: 2,
            config_write_zero_ok: false,
            stream_watchdog: Some(Duration::from_secs(1)),
            timeouts: Timeouts::default(),
        }
    }
}

/// Why a request or the initialisation failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum MachineError {
    /// No rate of the probe list got an answer.
    NoDevice,
    /// No ACK/reply to command `code` after every retry.
    Timeout {
        /// The command code.
        code: u8,
    },
    /// NAKed on every attempt.
    Nak {
        /// The command code.
        code: u8,
    },
    /// A `92` rejection.
    Rejected {
        /// The command code.
        code: u8,
    },
    /// The device answered with a refusal (`A0` nonzero, `BB 00`, `F7` failure).
    Refused {
        /// The command code.
        code: u8,
        /// The result byte.
        result: u8,
    },
    /// The status reports an error (severity ≥ 3 in `S`, or a nonzero device-status byte).
    DeviceError {
        /// The status byte of the reply.
        status: StatusByte,
        /// Byte 9 of the status block.
        device_status: u8,
    },
    /// The unit confirmed command `code` with other settings than were asked for (a
    /// variant or configuration echo that does not match).
    NotAsAsked {
        /// The command code.
        code: u8,
    },
    /// 500 000 baud was asked for on a line not configured as RS-422
    /// ([`Config::rs422`]): the host refuses it before asking the unit.
    NeedsRs422,
    /// The unit reports a line speed other than the one just switched to.
    BaudMismatch,
    /// Command `code` did not fit the transmit buffer (a bug of this driver).
    Unsendable {
        /// The command code.
        code: u8,
    },
    /// A request was made while another is in flight or initialisation is running.
    Busy,
    /// The B0 stream stopped arriving (see [`Config::stream_watchdog`]).
    StreamStalled,
}

/// A command code shown as `3Bh (switch variant)`.
struct CommandCode(u8);

impl core::fmt::Display for CommandCode {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match crate::wire::command_name(self.0) {
            Some(name) => write!(f, "{:02X}h ({name})", self.0),
            None => write!(f, "{:02X}h", self.0),
        }
    }
}

impl core::fmt::Display for MachineError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match *self {
            Self::NoDevice => f.write_str(
                "no SICK LMS answered at 9600, 38400 or 19200 baud (nor 500000 with RS-422; \
                 powered? still booting?)",
            ),
            Self::Timeout { code } => {
                write!(
                    f,
                    "no answer to command {} after every retry",
                    CommandCode(code)
                )
            }
            Self::Nak { code } => write!(f, "command {} NAKed on every attempt", CommandCode(code)),
            Self::Rejected { code } => write!(f, "command {} rejected (92h)", CommandCode(code)),
            Self::Refused { code, result } => write!(
                f,
                "command {} refused (result {result:02X}h)",
                CommandCode(code)
            ),
            Self::DeviceError {
                status,
                device_status,
            } => write!(
                f,
                "the unit reports an error (status byte {:02X}h, device status {device_status:02X}h)",
                status.0
            ),
            Self::NotAsAsked { code } => write!(
                f,
                "the unit confirmed command {} with other settings than asked",
                CommandCode(code)
            ),
            Self::NeedsRs422 => {
                f.write_str("500000 baud needs an RS-422 line (set rs422 if this is one)")
            }
            Self::BaudMismatch => {
                f.write_str("the unit reports another line speed than the one just set")
            }
            Self::Unsendable { code } => write!(
                f,
                "command {} did not fit the transmit buffer (a bug of this driver)",
                CommandCode(code)
            ),
            Self::Busy => f.write_str("another request is in progress"),
            Self::StreamStalled => f.write_str("the scan stream stopped arriving"),
        }
    }
}

impl core::error::Error for MachineError {}

/// What the session settled on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SessionInfo {
    /// Line rate in use.
    pub baud: BaudRate,
    /// Variant in use, if known (needed to decode sub-range scans; full scans infer it).
    pub variant: Option<Variant>,
    /// Configuration in use (measuring mode decides the value masks).
    pub config: Option<LmsConfig>,
    /// The B0 stream is running.
    pub streaming: bool,
}

/// Something the shell must do or may want to know.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Event {
    /// Set the host UART to this many bits per second and flush its input, before writing
    /// anything else.
    SetHostBaud(u32),
    /// The power-on telegram `90` arrived.
    PowerOn,
    /// The probe found the device at this rate.
    BaudDetected(BaudRate),
    /// The type string is known ([`Machine::device_type`]).
    Identified,
    /// The status byte of the device changed (pollution, warnings: see [`StatusByte`]).
    DeviceStatus(StatusByte),
    /// The configuration was written to the EEPROM.
    ConfigWritten,
    /// Initialisation or reconfiguration finished.
    Ready(SessionInfo),
    /// The stream started.
    StreamStarted,
    /// The stream stopped.
    StreamStopped,
    /// The device restarted unexpectedly (`90` while running); initialisation starts again.
    Restarted,
    /// A request failed; during initialisation this is final ([`Machine::is_failed`]).
    Error(MachineError),
    /// [`Machine::close`] finished: the stream is stopped and the unit is back at its
    /// power-up rate (or the attempt gave up; see the [`Event::Error`] before it). The shell
    /// may release the port.
    Closed,
}

/// Traffic statistics beyond the framer's counters.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Stats {
    /// B0 frames seen.
    pub scans: u64,
    /// Telegrams sent (retransmissions included).
    pub sent: u64,
    /// Retransmissions.
    pub retransmissions: u64,
    /// Replies that matched no pending request (and were not B0 or `90`).
    pub unexpected: u64,
    /// Events lost because the queue was full.
    pub events_dropped: u64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Phase {
    PowerUp,
    Probe {
        idx: usize,
        round: u8,
    },
    Identify,
    Status,
    BaudChange(BaudRate),
    Settle(BaudRate),
    VerifyBaud(BaudRate),
    Variant(Variant),
    ReadConfig,
    Install,
    WriteConfig,
    LeaveInstall,
    StartStream,
    Ready,
    StopForReconfig,
    StartOp,
    StopOp,
    ScanOp,
    Reset,
    /// Closing: `20 25` sent, then the rate goes back to 9600.
    CloseStop,
    /// Closing: `20 42` sent at the session rate.
    CloseBaud,
    /// Closed (see [`Event::Closed`]).
    Closed,
    Failed,
}

#[derive(Debug, Clone)]
struct Pending {
    command: Command,
    expect: u8,
    acked: bool,
    attempts: u8,
    deadline: Instant,
    retry_at: Option<Instant>,
    reply_timeout: Duration,
    /// A lost answer must not be retried (baud change): fail instead.
    no_blind_retry: bool,
}

/// Everything but the framer, so that a borrowed frame and the session can be used together.
#[derive(Debug, Clone)]
struct Core {
    cfg: Config,
    /// The framer must drop its partial candidate (the host rate changed).
    flush: bool,
    phase: Phase,
    pending: Option<Pending>,
    timer: Option<Instant>,
    tx: heapless::Vec<u8, MAX_COMMAND>,
    events: heapless::Deque<Event, 16>,
    host_baud: BaudRate,
    reprobes: u8,
    status_variant: Option<Variant>,
    variant: Option<Variant>,
    config: Option<LmsConfig>,
    wanted_config: Option<LmsConfig>,
    streaming: bool,
    want_stream: bool,
    last_status: Option<StatusByte>,
    device_type: heapless::Vec<u8, 32>,
    stats: Stats,
}

/// The session state machine. See the module docs.
#[derive(Debug, Clone)]
pub struct Machine {
    framer: Framer,
    core: Core,
}

/// Time to send `bytes` at `baud` (10 bits per byte), rounded up to whole microseconds.
#[must_use]
pub fn wire_time(bytes: usize, baud: BaudRate) -> Duration {
    let bits = (bytes as u64).saturating_mul(10).saturating_mul(1_000_000);
    Duration::from_micros(bits.div_ceil(u64::from(baud.bps())))
}

impl Machine {
    /// A session that starts initialising at `now`.
    #[must_use]
    pub fn new(config: Config, now: Instant) -> Self {
        let want_stream = config.stream;
        let mut m = Core {
            cfg: config,
            flush: false,
            phase: Phase::Failed,
            pending: None,
            timer: None,
            tx: heapless::Vec::new(),
            events: heapless::Deque::new(),
            host_baud: BaudRate::B9600,
            reprobes: 0,
            status_variant: None,
            variant: None,
            config: None,
            wanted_config: None,
            streaming: false,
            want_stream,
            last_status: None,
            device_type: heapless::Vec::new(),
            stats: Stats::default(),
        };
        m.emit(Event::SetHostBaud(BaudRate::B9600.bps()));
        match m.cfg.power_up_wait {
            Some(wait) => {
                m.phase = Phase::PowerUp;
                m.timer = Some(now + wait);
            }
            None => m.enter_probe(0, 0, now),
        }
        Self {
            framer: Framer::replies(),
            core: m,
        }
    }

    /// The configuration.
    #[must_use]
    pub fn config(&self) -> &Config {
        &self.core.cfg
    }

    /// The host rate the machine believes is set.
    #[must_use]
    pub fn host_baud(&self) -> BaudRate {
        self.core.host_baud
    }

    /// Initialisation (or a reconfiguration) finished and no request is in flight.
    #[must_use]
    pub fn is_ready(&self) -> bool {
        self.core.is_ready()
    }

    /// Looking for the unit: waiting for its power-on telegram or probing rates (a
    /// [`Event::SetHostBaud`] now starts a probe at that rate rather than a switch).
    #[must_use]
    pub fn is_probing(&self) -> bool {
        matches!(self.core.phase, Phase::PowerUp | Phase::Probe { .. })
    }

    /// Initialisation gave up (see the last [`Event::Error`]).
    #[must_use]
    pub fn is_failed(&self) -> bool {
        self.core.phase == Phase::Failed
    }

    /// The B0 stream is running.
    #[must_use]
    pub fn is_streaming(&self) -> bool {
        self.core.streaming
    }

    /// The type string from `BA` (e.g. `LMS200;30106`), once identified.
    #[must_use]
    pub fn device_type(&self) -> Option<&[u8]> {
        let t = &self.core.device_type;
        (!t.is_empty()).then_some(t.as_slice())
    }

    /// What the session runs with (variant and measuring mode are needed to decode B0s).
    #[must_use]
    pub fn session(&self) -> SessionInfo {
        self.core.session()
    }

    /// The measuring mode for decoding (the default when the config was not read).
    #[must_use]
    pub fn measuring_mode(&self) -> MeasuringMode {
        self.core
            .config
            .map(|c| c.measuring_mode())
            .unwrap_or(MeasuringMode::DEFAULT)
    }

    /// Framer counters.
    #[must_use]
    pub fn counters(&self) -> Counters {
        self.framer.counters()
    }

    /// Session statistics.
    #[must_use]
    pub fn stats(&self) -> Stats {
        self.core.stats
    }

    /// Copy the next telegram to send into `buf`; returns its length. `None` when nothing is
    /// queued (or `buf` is shorter than the telegram; [`MAX_COMMAND`] bytes always suffice).
    pub fn poll_transmit(&mut self, buf: &mut [u8]) -> Option<usize> {
        let tx = &mut self.core.tx;
        if tx.is_empty() {
            return None;
        }
        let n = tx.len();
        buf.get_mut(..n)?.copy_from_slice(tx);
        tx.clear();
        Some(n)
    }

    /// The next event.
    pub fn poll_event(&mut self) -> Option<Event> {
        self.core.events.pop_front()
    }

    /// When [`Machine::handle_timeout`] must next be called.
    #[must_use]
    pub fn poll_timeout(&self) -> Option<Instant> {
        let p = self
            .core
            .pending
            .as_ref()
            .map(|p| p.retry_at.unwrap_or(p.deadline));
        [p, self.core.timer, self.framer.poll_timeout()]
            .into_iter()
            .flatten()
            .min()
    }

    /// Feed received bytes. Every B0 scan is handed to `on_scan` with `now`, borrowed from the
    /// framer's buffer (decode it there, e.g. with [`crate::decode::decode_scan`]).
    pub fn handle_bytes_with(
        &mut self,
        mut bytes: &[u8],
        now: Instant,
        mut on_scan: impl FnMut(&Scan<'_>, Instant),
    ) {
        loop {
            let p = self.framer.push(bytes, now);
            let consumed = p.consumed;
            let got = p.item.is_some();
            match p.item {
                Some(Item::Ack) => self.core.handle_ack(now),
                Some(Item::Nak) => self.core.handle_nak(now),
                Some(Item::Frame(f)) => {
                    if let Ok(reply) = Reply::from_frame(&f) {
                        if let Reply::Scan(s) = &reply {
                            on_scan(s, now);
                        }
                        self.core.handle_frame(&reply, now);
                    }
                }
                Some(Item::BadChecksum) | None => {}
            }
            if core::mem::take(&mut self.core.flush) {
                self.framer.clear();
            }
            bytes = bytes.get(consumed..).unwrap_or(&[]);
            if !got && consumed == 0 {
                break;
            }
        }
    }

    /// Handle timers due at `now` (request deadlines, settle, power-up wait, partial-frame
    /// expiry). Scans recovered by a partial-frame expiry go to `on_scan`.
    pub fn handle_timeout_with(&mut self, now: Instant, on_scan: impl FnMut(&Scan<'_>, Instant)) {
        if self.framer.poll_timeout().is_some_and(|t| t <= now) {
            self.handle_bytes_with(&[], now, on_scan);
        }
        self.core.handle_timers(now);
        if core::mem::take(&mut self.core.flush) {
            self.framer.clear();
        }
    }

    /// [`Machine::handle_bytes_with`] discarding the scans (they still count in
    /// [`Stats::scans`]).
    pub fn handle_bytes(&mut self, bytes: &[u8], now: Instant) {
        self.handle_bytes_with(bytes, now, |_, _| {});
    }

    /// [`Machine::handle_timeout_with`] discarding scans recovered by a partial-frame expiry
    /// (they still count in [`Stats::scans`]).
    pub fn handle_timeout(&mut self, now: Instant) {
        self.handle_timeout_with(now, |_, _| {});
    }

    /// A standalone ACK arrived (for shells that run their own framer).
    pub fn handle_ack(&mut self, now: Instant) {
        self.core.handle_ack(now);
    }

    /// A standalone NAK arrived: retransmit after the backoff, within the retry bound.
    pub fn handle_nak(&mut self, now: Instant) {
        self.core.handle_nak(now);
    }

    /// A reply telegram arrived (for shells that run their own framer; they must also apply
    /// [`Event::SetHostBaud`] by flushing their framer).
    pub fn handle_frame(&mut self, reply: &Reply<'_>, now: Instant) {
        self.core.handle_frame(reply, now);
        if core::mem::take(&mut self.core.flush) {
            self.framer.clear();
        }
    }

    /// Start the B0 stream (`20 24`). Only when [`Machine::is_ready`].
    pub fn start_stream(&mut self, now: Instant) -> Result<(), MachineError> {
        self.core.start_stream(now)
    }

    /// Stop the B0 stream (`20 25`). Only when [`Machine::is_ready`].
    pub fn stop_stream(&mut self, now: Instant) -> Result<(), MachineError> {
        self.core.stop_stream(now)
    }

    /// Ask for one scan (`30 01`) in request mode. The scan arrives through `on_scan`.
    pub fn request_scan(&mut self, now: Instant) -> Result<(), MachineError> {
        self.core.request_scan(now)
    }

    /// End the session leaving the unit as a fresh one expects it: the stream stopped
    /// (`20 25`) and the line back at the power-up rate, 9600 (`20 42`, answered at the old
    /// rate, then [`Event::SetHostBaud`]`(9600)`). The LMS keeps a switched rate until it is
    /// power-cycled (spec §3.1), so a session that leaves it at 38400 or 500 000 makes the
    /// next program probe for it; STB does the same on close (spec §4).
    ///
    /// Ends with [`Event::Closed`], at once when there is nothing to undo (no unit found yet,
    /// or already idle at 9600). A step that fails (no answer, refusal) is not retried: the
    /// machine reports the [`Event::Error`] and then [`Event::Closed`]. A request in flight
    /// is abandoned. The shell bounds the whole sequence by its own deadline.
    pub fn close(&mut self, now: Instant) {
        self.core.close(now);
    }

    /// [`Machine::close`] has finished ([`Event::Closed`] was queued).
    #[must_use]
    pub fn is_closed(&self) -> bool {
        self.core.phase == Phase::Closed
    }

    /// Change the variant: stop the stream, `3B`, re-read the config, restart the stream if it
    /// was running. Ends with [`Event::Ready`].
    pub fn set_variant(&mut self, variant: Variant, now: Instant) -> Result<(), MachineError> {
        self.core.set_variant(variant, now)
    }

    /// Reset the unit (`10` → `91`), then wait at 9600 for its power-on telegram `90` (≤
    /// [`Timeouts::power_on`]) and initialise again from the probe. Ends with [`Event::Ready`].
    pub fn reset(&mut self, now: Instant) -> Result<(), MachineError> {
        self.core.reset(now)
    }

    /// Decode a B0 with the session's measuring mode, the variant inferred from the value
    /// count (see [`crate::decode::decode_scan`]).
    pub fn decode(
        &self,
        scan: &Scan<'_>,
        out: &mut ima_hal::laser::LaserScan,
    ) -> Result<(), crate::decode::DecodeError> {
        crate::decode::decode_scan(scan, self.measuring_mode(), None, out)
    }
}

impl Core {
    fn handle_timers(&mut self, now: Instant) {
        if let Some(t) = self.timer
            && t <= now
        {
            self.timer = None;
            self.on_timer(now);
        }
        let Some(p) = self.pending.as_mut() else {
            return;
        };
        if let Some(t) = p.retry_at {
            if t <= now {
                p.retry_at = None;
                self.retransmit(now);
            }
            return;
        }
        if p.deadline > now {
            return;
        }
        let code = p.command.code();
        let can_retry = p.attempts <= self.cfg.retries && !p.no_blind_retry;
        if can_retry {
            self.retransmit(now);
        } else {
            self.pending = None;
            self.on_failure(MachineError::Timeout { code }, now);
        }
    }

    /// Initialisation (or a reconfiguration) finished and no request is in flight.
    #[must_use]
    pub fn is_ready(&self) -> bool {
        self.phase == Phase::Ready && self.pending.is_none()
    }

    /// What the session runs with (variant and measuring mode are needed to decode B0s).
    #[must_use]
    pub fn session(&self) -> SessionInfo {
        SessionInfo {
            baud: self.host_baud,
            variant: self.variant,
            config: self.config,
            streaming: self.streaming,
        }
    }

    /// A standalone ACK arrived.
    pub fn handle_ack(&mut self, now: Instant) {
        let baud = self.host_baud;
        let ack_extra = wire_time(crate::wire::MAX_TELEGRAM, baud);
        if let Some(p) = self.pending.as_mut()
            && !p.acked
        {
            p.acked = true;
            p.deadline = now + p.reply_timeout + ack_extra;
        }
    }

    /// A standalone NAK arrived: retransmit after the backoff, within the retry bound.
    pub fn handle_nak(&mut self, now: Instant) {
        let retries = self.cfg.retries;
        let backoff = self.cfg.timeouts.nak_backoff;
        let Some(p) = self.pending.as_mut() else {
            return;
        };
        if p.acked || p.retry_at.is_some() {
            return;
        }
        if p.attempts <= retries {
            p.retry_at = Some(now + backoff);
        } else {
            let code = p.command.code();
            self.pending = None;
            self.on_failure(MachineError::Nak { code }, now);
        }
    }

    /// A reply telegram arrived (use this when the shell runs its own framer).
    pub fn handle_frame(&mut self, reply: &Reply<'_>, now: Instant) {
        // The power-on telegram's status byte describes the boot, not the running unit: a
        // real LMS 200 sends `0x13` (severity 3, "error") in it (spec §1, the QM example), so
        // taking it as the device status would report an error at every power-up. The next
        // reply carries the running status.
        if !matches!(reply, Reply::PowerOn { .. }) {
            self.note_status(reply.status());
        }
        if let Reply::Scan(_) = reply {
            self.stats.scans = self.stats.scans.saturating_add(1);
            if self.phase == Phase::Ready && self.streaming {
                self.arm_watchdog(now);
            }
        }
        if let Reply::PowerOn { .. } = reply {
            self.emit(Event::PowerOn);
            match self.phase {
                Phase::PowerUp => {
                    self.timer = None;
                    self.enter_probe(0, 0, now);
                }
                Phase::Probe { .. } | Phase::Failed | Phase::Closed => {}
                Phase::CloseStop | Phase::CloseBaud => {
                    // Rebooted while closing: it is idle at its power-up rate already.
                    self.streaming = false;
                    self.set_host_baud(BaudRate::B9600);
                    self.closed();
                }
                _ => {
                    // The unit rebooted: it is back at its power-up rate, idle.
                    self.emit(Event::Restarted);
                    self.pending = None;
                    self.timer = None;
                    self.streaming = false;
                    self.reprobes = 0;
                    self.enter_probe(0, 0, now);
                }
            }
            return;
        }
        let Some(p) = self.pending.as_ref() else {
            if !matches!(reply, Reply::Scan(_)) {
                self.stats.unexpected = self.stats.unexpected.saturating_add(1);
            }
            return;
        };
        let code = p.command.code();
        if let Reply::Rejected { .. } = reply {
            self.pending = None;
            self.on_failure(MachineError::Rejected { code }, now);
            return;
        }
        if reply.code() != p.expect {
            if !matches!(reply, Reply::Scan(_)) {
                self.stats.unexpected = self.stats.unexpected.saturating_add(1);
            }
            return;
        }
        self.pending = None;
        self.on_reply(reply, now);
    }

    // ------------------------------------------------------------------ user requests

    /// Start the B0 stream (`20 24`). Only when [`Machine::is_ready`].
    pub fn start_stream(&mut self, now: Instant) -> Result<(), MachineError> {
        self.require_ready()?;
        self.want_stream = true;
        self.phase = Phase::StartOp;
        self.send_mode(ModeRequest::StreamAll, now);
        Ok(())
    }

    /// Stop the B0 stream (`20 25`). Only when [`Machine::is_ready`].
    pub fn stop_stream(&mut self, now: Instant) -> Result<(), MachineError> {
        self.require_ready()?;
        self.want_stream = false;
        self.phase = Phase::StopOp;
        self.send_mode(ModeRequest::RequestOnly, now);
        Ok(())
    }

    /// Ask for one scan (`30 01`) in request mode. The scan arrives through `on_scan`.
    pub fn request_scan(&mut self, now: Instant) -> Result<(), MachineError> {
        self.require_ready()?;
        self.phase = Phase::ScanOp;
        let t = self.cfg.timeouts.reply;
        self.send(Command::one_scan(), t, false, now);
        Ok(())
    }

    /// Change the variant: stop the stream, `3B`, re-read the config, restart the stream if it
    /// was running. Ends with [`Event::Ready`].
    pub fn set_variant(&mut self, variant: Variant, now: Instant) -> Result<(), MachineError> {
        self.require_ready()?;
        self.cfg.variant = Some(variant);
        self.phase = Phase::StopForReconfig;
        self.send_mode(ModeRequest::RequestOnly, now);
        Ok(())
    }

    fn close(&mut self, now: Instant) {
        if matches!(
            self.phase,
            Phase::CloseStop | Phase::CloseBaud | Phase::Closed
        ) {
            return;
        }
        // Only a unit that was found (and may have been switched) has something to undo.
        let found = !matches!(
            self.phase,
            Phase::PowerUp | Phase::Probe { .. } | Phase::Reset | Phase::Failed
        );
        self.pending = None;
        self.timer = None;
        self.want_stream = false;
        if found && self.streaming {
            self.phase = Phase::CloseStop;
            self.send_mode(ModeRequest::RequestOnly, now);
        } else if found && self.host_baud != BaudRate::B9600 {
            self.close_baud(now);
        } else {
            self.closed();
        }
    }

    fn close_baud(&mut self, now: Instant) {
        self.phase = Phase::CloseBaud;
        self.send_mode(ModeRequest::Baud(BaudRate::B9600), now);
    }

    fn closed(&mut self) {
        self.phase = Phase::Closed;
        self.pending = None;
        self.timer = None;
        self.emit(Event::Closed);
    }

    fn reset(&mut self, now: Instant) -> Result<(), MachineError> {
        self.require_ready()?;
        self.phase = Phase::Reset;
        let t = self.cfg.timeouts.reset;
        self.send(Command::Reset, t, true, now);
        Ok(())
    }

    /// After `91` (or a lost `91`): the unit reboots at its power-up rate (9600).
    fn await_power_on(&mut self, now: Instant) {
        self.streaming = false;
        self.reprobes = 0;
        self.phase = Phase::PowerUp;
        if self.host_baud != BaudRate::B9600 {
            self.set_host_baud(BaudRate::B9600);
        }
        self.timer = Some(now + self.cfg.timeouts.power_on);
    }

    fn require_ready(&mut self) -> Result<(), MachineError> {
        if self.is_ready() {
            self.timer = None;
            Ok(())
        } else {
            Err(MachineError::Busy)
        }
    }

    // ------------------------------------------------------------------ internals

    fn emit(&mut self, e: Event) {
        if self.events.push_back(e).is_err() {
            self.stats.events_dropped = self.stats.events_dropped.saturating_add(1);
        }
    }

    fn note_status(&mut self, s: StatusByte) {
        if self.last_status != Some(s) {
            self.last_status = Some(s);
            self.emit(Event::DeviceStatus(s));
        }
    }

    fn set_host_baud(&mut self, b: BaudRate) {
        self.host_baud = b;
        self.flush = true;
        self.emit(Event::SetHostBaud(b.bps()));
    }

    fn probe_list(&self) -> heapless::Vec<BaudRate, 4> {
        BaudRate::PROBE_ORDER
            .into_iter()
            .filter(|b| self.cfg.rs422 || *b != BaudRate::B500000)
            .collect()
    }

    fn enter_probe(&mut self, idx: usize, round: u8, now: Instant) {
        let list = self.probe_list();
        let (idx, round) = if idx >= list.len() {
            (0, round.saturating_add(1))
        } else {
            (idx, round)
        };
        if round >= self.cfg.probe_rounds.max(1) {
            self.fail(MachineError::NoDevice);
            return;
        }
        let Some(&b) = list.get(idx) else {
            self.fail(MachineError::NoDevice);
            return;
        };
        self.phase = Phase::Probe { idx, round };
        self.streaming = false;
        if b != self.host_baud {
            self.set_host_baud(b);
        } else {
            self.flush = true;
        }
        self.send_mode(ModeRequest::RequestOnly, now);
    }

    fn reprobe(&mut self, err: MachineError, now: Instant) {
        self.emit(Event::Error(err));
        if self.reprobes >= self.cfg.max_reprobes {
            self.fail(err);
            return;
        }
        self.reprobes = self.reprobes.saturating_add(1);
        self.enter_probe(0, 0, now);
    }

    fn fail(&mut self, err: MachineError) {
        self.phase = Phase::Failed;
        self.pending = None;
        self.timer = None;
        self.emit(Event::Error(err));
    }

    fn send_mode(&mut self, mode: ModeRequest, now: Instant) {
        let t = self.cfg.timeouts.mode_change;
        let no_blind = matches!(mode, ModeRequest::Baud(_));
        self.send(Command::SetMode(mode), t, no_blind, now);
    }

    fn send(&mut self, command: Command, reply_timeout: Duration, no_blind: bool, now: Instant) {
        let expect = expected_reply(command.code());
        self.pending = Some(Pending {
            command,
            expect,
            acked: false,
            attempts: 0,
            deadline: now,
            retry_at: None,
            reply_timeout,
            no_blind_retry: no_blind,
        });
        self.retransmit(now);
    }

    fn retransmit(&mut self, now: Instant) {
        let ack_wait = self.cfg.timeouts.ack + wire_time(crate::wire::MAX_TELEGRAM, self.host_baud);
        let Some(p) = self.pending.as_mut() else {
            return;
        };
        let mut buf = [0u8; MAX_COMMAND];
        let Ok(n) = p.command.emit(&mut buf) else {
            let code = p.command.code();
            self.pending = None;
            self.fail(MachineError::Unsendable { code });
            return;
        };
        if p.attempts > 0 {
            self.stats.retransmissions = self.stats.retransmissions.saturating_add(1);
        }
        p.attempts = p.attempts.saturating_add(1);
        p.acked = false;
        p.retry_at = None;
        p.deadline = now + ack_wait;
        self.tx.clear();
        // MAX_COMMAND covers every command the machine builds.
        let _ = self.tx.extend_from_slice(buf.get(..n).unwrap_or(&[]));
        self.stats.sent = self.stats.sent.saturating_add(1);
    }

    fn arm_watchdog(&mut self, now: Instant) {
        self.timer = self
            .cfg
            .stream_watchdog
            .map(|wd| now + wd + wire_time(crate::wire::MAX_TELEGRAM, self.host_baud));
    }

    fn on_timer(&mut self, now: Instant) {
        match self.phase {
            Phase::PowerUp => self.enter_probe(0, 0, now),
            Phase::Ready if self.streaming && self.pending.is_none() => {
                self.emit(Event::Error(MachineError::StreamStalled));
                self.streaming = false;
                self.reprobes = 0;
                self.enter_probe(0, 0, now);
            }
            Phase::Settle(b) => {
                self.phase = Phase::VerifyBaud(b);
                let t = self.cfg.timeouts.reply;
                self.send(Command::Status, t, false, now);
            }
            _ => {}
        }
    }

    fn on_failure(&mut self, err: MachineError, now: Instant) {
        match self.phase {
            Phase::Probe { idx, round } => {
                self.enter_probe(idx.saturating_add(1), round, now);
            }
            Phase::BaudChange(_) | Phase::VerifyBaud(_) => self.reprobe(err, now),
            Phase::Reset => {
                // The unit may be rebooting already: wait for its 90, then probe.
                self.emit(Event::Error(err));
                self.await_power_on(now);
            }
            Phase::StartOp | Phase::StopOp | Phase::ScanOp => {
                self.phase = Phase::Ready;
                self.emit(Event::Error(err));
            }
            Phase::CloseStop | Phase::CloseBaud => {
                // Best effort: say what failed and let the shell release the port.
                self.emit(Event::Error(err));
                self.closed();
            }
            _ => self.fail(err),
        }
    }

    fn on_reply(&mut self, reply: &Reply<'_>, now: Instant) {
        let timeouts = self.cfg.timeouts;
        match (self.phase, reply) {
            (Phase::Probe { idx, .. }, Reply::ModeChanged { .. }) => {
                let list = self.probe_list();
                let b = list.get(idx).copied().unwrap_or(self.host_baud);
                self.streaming = false;
                self.emit(Event::BaudDetected(b));
                self.phase = Phase::Identify;
                self.send(Command::Type, timeouts.reply, false, now);
            }
            (Phase::Identify, Reply::Type { text, .. }) => {
                self.device_type.clear();
                let n = text.len().min(self.device_type.capacity());
                let _ = self
                    .device_type
                    .extend_from_slice(text.get(..n).unwrap_or(&[]));
                self.emit(Event::Identified);
                self.phase = Phase::Status;
                self.send(Command::Status, timeouts.reply, false, now);
            }
            (Phase::Status, Reply::Status { block, status }) => {
                let device_status = block.device_status().unwrap_or(0);
                if status.is_error() || device_status != 0 {
                    self.fail(MachineError::DeviceError {
                        status: *status,
                        device_status,
                    });
                    return;
                }
                self.status_variant = match (block.scan_angle_deg(), block.resolution_centideg()) {
                    (Some(a), Some(r)) => Variant::new(a, r),
                    _ => None,
                };
                if self.cfg.baud != self.host_baud {
                    let b = self.cfg.baud;
                    if b == BaudRate::B500000 && !self.cfg.rs422 {
                        self.fail(MachineError::NeedsRs422);
                        return;
                    }
                    self.phase = Phase::BaudChange(b);
                    self.send_mode(ModeRequest::Baud(b), now);
                } else {
                    self.after_baud(now);
                }
            }
            (Phase::BaudChange(b), Reply::ModeChanged { result, .. }) => {
                if *result != 0 {
                    self.reprobe(
                        MachineError::Refused {
                            code: crate::wire::cmd::SET_MODE,
                            result: *result,
                        },
                        now,
                    );
                    return;
                }
                // A0 came at the old rate; now switch the host and let the line settle.
                self.set_host_baud(b);
                self.phase = Phase::Settle(b);
                self.timer = Some(now + timeouts.settle);
            }
            (Phase::VerifyBaud(b), Reply::Status { block, .. }) => {
                if block.baud().is_some_and(|x| x != b) {
                    self.reprobe(MachineError::BaudMismatch, now);
                    return;
                }
                self.after_baud(now);
            }
            (
                Phase::Variant(v),
                Reply::Variant {
                    accepted,
                    angle_deg,
                    res_centideg,
                    ..
                },
            ) => {
                if *accepted != 1 {
                    self.fail(MachineError::Refused {
                        code: crate::wire::cmd::VARIANT,
                        result: *accepted,
                    });
                    return;
                }
                if *angle_deg != v.angle_deg() || *res_centideg != v.res_centideg() {
                    self.fail(MachineError::NotAsAsked {
                        code: crate::wire::cmd::VARIANT,
                    });
                    return;
                }
                self.variant = Some(v);
                self.status_variant = Some(v);
                self.enter_read_config(now);
            }
            (Phase::ReadConfig, Reply::Config { config, .. }) => {
                let mut want = *config;
                if let Some(a) = self.cfg.availability {
                    want.set_availability(a);
                }
                if let Some(m) = self.cfg.measuring_mode {
                    want.set_measuring_mode(m);
                }
                if let Some(u) = self.cfg.units {
                    want.set_units(u);
                }
                self.config = Some(*config);
                if want == *config {
                    self.enter_start(now);
                } else {
                    self.wanted_config = Some(want);
                    self.phase = Phase::Install;
                    let password = self.cfg.password;
                    self.send_mode(ModeRequest::Installation { password }, now);
                }
            }
            (Phase::Install, Reply::ModeChanged { result, .. }) => {
                if *result != 0 {
                    self.fail(MachineError::Refused {
                        code: crate::wire::cmd::SET_MODE,
                        result: *result,
                    });
                    return;
                }
                let Some(want) = self.wanted_config else {
                    self.fail(MachineError::Busy);
                    return;
                };
                self.phase = Phase::WriteConfig;
                self.send(
                    Command::WriteConfig(want),
                    timeouts.config_write,
                    false,
                    now,
                );
            }
            (Phase::WriteConfig, Reply::ConfigWritten { result, config, .. }) => {
                let ok_result = *result == 1 || (*result == 0 && self.cfg.config_write_zero_ok);
                if !ok_result {
                    self.fail(MachineError::Refused {
                        code: crate::wire::cmd::WRITE_CONFIG,
                        result: *result,
                    });
                    return;
                }
                if Some(*config) != self.wanted_config {
                    self.fail(MachineError::NotAsAsked {
                        code: crate::wire::cmd::WRITE_CONFIG,
                    });
                    return;
                }
                self.config = Some(*config);
                self.emit(Event::ConfigWritten);
                self.phase = Phase::LeaveInstall;
                self.send_mode(ModeRequest::RequestOnly, now);
            }
            (Phase::LeaveInstall, Reply::ModeChanged { .. }) => self.enter_start(now),
            (Phase::StartStream | Phase::StartOp, Reply::ModeChanged { result, .. }) => {
                let was_init = self.phase == Phase::StartStream;
                self.phase = Phase::Ready;
                if *result != 0 {
                    self.emit(Event::Error(MachineError::Refused {
                        code: crate::wire::cmd::SET_MODE,
                        result: *result,
                    }));
                    return;
                }
                self.streaming = true;
                self.arm_watchdog(now);
                self.emit(Event::StreamStarted);
                if was_init {
                    self.emit(Event::Ready(self.session()));
                }
            }
            (Phase::StopOp, Reply::ModeChanged { .. }) => {
                self.phase = Phase::Ready;
                self.streaming = false;
                self.emit(Event::StreamStopped);
            }
            (Phase::StopForReconfig, Reply::ModeChanged { .. }) => {
                if self.streaming {
                    self.streaming = false;
                    self.emit(Event::StreamStopped);
                }
                self.phase = Phase::Status;
                self.send(Command::Status, timeouts.reply, false, now);
            }
            (Phase::Reset, Reply::ResetAck { .. }) => self.await_power_on(now),
            (Phase::CloseStop, Reply::ModeChanged { .. }) => {
                self.streaming = false;
                self.emit(Event::StreamStopped);
                if self.host_baud == BaudRate::B9600 {
                    self.closed();
                } else {
                    self.close_baud(now);
                }
            }
            (Phase::CloseBaud, Reply::ModeChanged { result, .. }) => {
                if *result == 0 {
                    // A0 came at the old rate; the unit now listens at 9600.
                    self.set_host_baud(BaudRate::B9600);
                } else {
                    self.emit(Event::Error(MachineError::Refused {
                        code: crate::wire::cmd::SET_MODE,
                        result: *result,
                    }));
                }
                self.closed();
            }
            (Phase::ScanOp, Reply::Scan(_)) => {
                self.phase = Phase::Ready;
            }
            _ => {
                // A reply with the expected code but in no phase that wants it.
                self.stats.unexpected = self.stats.unexpected.saturating_add(1);
            }
        }
    }

    fn after_baud(&mut self, now: Instant) {
        match self.cfg.variant {
            Some(v) if self.status_variant != Some(v) => {
                self.phase = Phase::Variant(v);
                let t = self.cfg.timeouts.reply;
                self.send(
                    Command::Variant {
                        angle_deg: v.angle_deg(),
                        res_centideg: v.res_centideg(),
                    },
                    t,
                    false,
                    now,
                );
            }
            _ => {
                self.variant = self.status_variant;
                self.enter_read_config(now);
            }
        }
    }

    fn enter_read_config(&mut self, now: Instant) {
        self.phase = Phase::ReadConfig;
        let t = self.cfg.timeouts.reply;
        self.send(Command::ReadConfig, t, false, now);
    }

    fn enter_start(&mut self, now: Instant) {
        if self.want_stream {
            self.phase = Phase::StartStream;
            self.send_mode(ModeRequest::StreamAll, now);
        } else {
            self.phase = Phase::Ready;
            self.emit(Event::Ready(self.session()));
        }
    }
}

// Through the trait, scans are counted but not handed out: a shell that wants them (without
// a copy) calls [`Machine::handle_bytes_with`] and [`Machine::handle_timeout_with`].
ima_serial::impl_machine!(Machine, Event, |m, _now, buf| m.poll_transmit(buf));

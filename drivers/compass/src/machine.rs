//! The compass session (spec §7a): configure the device for its dialect, keep an eye on the
//! data stream, run TCM2 calibration on request, and turn lines into heading events.
//!
//! Sans-IO: feed received bytes with [`Machine::handle_bytes`] (or parsed lines with
//! [`Machine::handle_frame`]), call [`Machine::handle_timeout`] when [`Machine::poll_timeout`]
//! is due, send what [`Machine::poll_transmit`] writes, and take [`Machine::poll_event`]s.
//!
//! # Jobs
//!
//! Configuration and calibration run as short command scripts, one at a time:
//!
//! | Job | Dialect | Commands, and what each waits for |
//! |---|---|---|
//! | configure | NMEA (listen only) | — ; first heading |
//! | configure | KVH C100 | `=t,0` → `>`; `=r,N` → `>`; first heading |
//! | configure | TCM2 | `h`, `sdo=t` (or `=n`), `sp=N`, each followed by a command gap; `go` → first data line |
//! | start user calibration | TCM2 | `h`, `mpcal=e` (gaps); `go` → first data line |
//! | stop user calibration | TCM2 | `h` (gap); `mpcal=d` → score line `HnVnMn.n` or score timeout; `go` → data |
//! | automatic calibration on/off | TCM2 | `h`, `autocal=e`/`=d` (gaps); `go` → data |
//! | clear calibration | TCM2 | `h`, `cc` (gaps); `go` → data |
//!
//! A wait for `>` or for data that times out is retried ([`Config::retries`] times per job: a
//! prompt wait re-sends its command, a data wait restarts the script); then the job fails with
//! [`Event::JobFailed`]. The TCM2 does not acknowledge commands, hence the fixed gaps.
//!
//! While no job runs, a data watchdog reports [`Event::DataTimeout`] once when no data line
//! arrived for [`Config::data_timeout`].
//!
//! # The wrong dialect
//!
//! A line of the other dialect (an NMEA sentence when a TCM2 was configured for its standard
//! line, a TCM2 line when an NMEA or KVH source was configured) is not data of this session:
//! it is counted ([`Stats::foreign_lines`]), remembered ([`Machine::foreign_line`]) and
//! otherwise ignored, so it neither completes the configuration nor becomes a heading. A
//! configuration that then fails says what the device spoke instead.

use core::time::Duration;

use heapless::{Deque, Vec};
use ima_hal::compass::{CalibrationQuality, Heading, HeadingReference, wrap_2pi};
use ima_hal::{Instant, Stamped};

use crate::framer::{Frame, FramerStats, LineFramer};
use crate::wire::{
    CalScore, Command, EastWest, KvhCommand, KvhFormat, Line, NmeaBody, NmeaSentence, ParseOptions,
    Talker, Tcm2Command, Tcm2Data, Tcm2Format,
};

/// Which compass is on the port.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Dialect {
    /// Any NMEA heading source, already configured: listen only.
    Nmea,
    /// KVH C100 in NMEA mode at `rate_per_minute` sentences per minute.
    KvhC100 {
        /// Output rate, sentences per minute (600 = 10 Hz, the C100's sampling rate).
        rate_per_minute: u16,
    },
    /// PNI TCM2 family.
    Tcm2 {
        /// Sample rate, Hz (`sp=N`; ARIA uses 8).
        sample_rate_hz: u8,
        /// Standard line (default: carries pitch, roll, temperature and the error code) or
        /// NMEA `HDM` (what ARIA uses).
        output: Tcm2Format,
    },
}

/// Session settings. `Default` is a KVH C100 at 10 Hz.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Config {
    /// The device dialect.
    pub dialect: Dialect,
    /// How strictly lines are parsed.
    pub parse: ParseOptions,
    /// How long to wait for a `>` prompt or for the first data after `go`.
    pub reply_timeout: Duration,
    /// Pause after a TCM2 command that is not acknowledged.
    pub command_gap: Duration,
    /// Retries per job after a timeout.
    pub retries: u8,
    /// How long to wait for the calibration score after `mpcal=d`.
    pub score_timeout: Duration,
    /// Report [`Event::DataTimeout`] after this long without data (`None`: never).
    pub data_timeout: Option<Duration>,
}

impl Default for Config {
    fn default() -> Self {
        Self {
            dialect: Dialect::KvhC100 {
                rate_per_minute: 600,
            },
            parse: ParseOptions::default(),
            reply_timeout: Duration::from_millis(500),
            command_gap: Duration::from_millis(100),
            retries: 2,
            score_timeout: Duration::from_secs(2),
            data_timeout: Some(Duration::from_secs(2)),
        }
    }
}

impl Config {
    /// Defaults for `dialect`.
    #[must_use]
    pub fn for_dialect(dialect: Dialect) -> Self {
        Self {
            dialect,
            ..Self::default()
        }
    }
}

/// What a job was doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Job {
    /// Initial configuration.
    Configure,
    /// Starting a TCM2 user calibration.
    StartUserCalibration,
    /// Stopping a TCM2 user calibration.
    StopUserCalibration,
    /// Switching TCM2 automatic calibration on or off.
    AutoCalibration(bool),
    /// Clearing the TCM2 calibration.
    ClearCalibration,
}

impl core::fmt::Display for Job {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::Configure => "configuration",
            Self::StartUserCalibration => "start of the user calibration",
            Self::StopUserCalibration => "end of the user calibration",
            Self::AutoCalibration(true) => "switching automatic calibration on",
            Self::AutoCalibration(false) => "switching automatic calibration off",
            Self::ClearCalibration => "clearing the calibration",
        })
    }
}

/// Where a reading came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Source {
    /// An NMEA sentence from this talker.
    Nmea(Talker),
    /// A TCM2 standard line.
    Tcm2,
}

/// One measurement, converted to SI.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reading {
    /// Heading, reference, corrections and calibration quality.
    pub heading: Heading,
    /// Pitch, radians (TCM2 standard line only).
    pub pitch_rad: Option<f64>,
    /// Roll, radians (TCM2 standard line only).
    pub roll_rad: Option<f64>,
    /// Temperature, °C (TCM2 standard line only).
    pub temperature_c: Option<f64>,
    /// TCM2 error code as sent (0 = none).
    pub error_code: Option<u16>,
    /// The line it came from.
    pub source: Source,
}

/// What the session reports.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Event {
    /// A heading, stamped with the instant its line was handed in.
    Heading(Stamped<Reading>),
    /// Configuration done and data flowing.
    Configured,
    /// A job gave up after its retries; `step` is the index of the command it was at.
    JobFailed {
        /// The job.
        job: Job,
        /// Step index within the job's script.
        step: u8,
    },
    /// User calibration runs: turn the robot through full circles, then stop it.
    CalibrationStarted,
    /// User calibration stopped, with the device's score if it sent one.
    CalibrationFinished {
        /// The score line, if one arrived within the score timeout.
        score: Option<CalScore>,
    },
    /// Automatic calibration was switched on or off.
    AutoCalibration(bool),
    /// The calibration was cleared.
    CalibrationCleared,
    /// The TCM2 error code changed to a non-zero value.
    DeviceError {
        /// The code as sent (hex bit field).
        code: u16,
    },
    /// No data line for [`Config::data_timeout`] (reported once per silence).
    DataTimeout,
}

/// A line of a dialect other than the configured one (see the [module docs](self)).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ForeignLine {
    /// An NMEA heading sentence, e.g. `$HCHDG` from a KVH C100.
    Nmea {
        /// The talker (`HC`).
        talker: Talker,
        /// The sentence formatter (`HDG`, `HDM`, `HDT`).
        sentence: [u8; 3],
    },
    /// A TCM2 standard line (`$C…P…R…T…E…`).
    Tcm2,
}

impl Dialect {
    /// The dialect's name for messages (`NMEA`, `KVH C100 (NMEA)`, `TCM2`).
    #[must_use]
    pub const fn name(self) -> &'static str {
        match self {
            Self::Nmea => "NMEA",
            Self::KvhC100 { .. } => "KVH C100 (NMEA)",
            Self::Tcm2 { .. } => "TCM2",
        }
    }

    /// The dialect's default line speed (spec §7a: NMEA 4800, TCM2 9600).
    #[must_use]
    pub const fn default_baud(self) -> u32 {
        match self {
            Self::Nmea | Self::KvhC100 { .. } => 4800,
            Self::Tcm2 { .. } => 9600,
        }
    }
}

impl core::fmt::Display for ForeignLine {
    /// `NMEA ($HCHDG…)` or `TCM2 ($C…P…R…)`.
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Nmea { talker, sentence } => {
                f.write_str("NMEA ($")?;
                for &b in talker.0.iter().chain(sentence.iter()) {
                    let c = if b.is_ascii_graphic() { b as char } else { '?' };
                    write!(f, "{c}")?;
                }
                f.write_str("…)")
            }
            Self::Tcm2 => f.write_str("TCM2 ($C…P…R…)"),
        }
    }
}

/// Why a request was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum RequestError {
    /// The dialect has no such command (KVH C100 calibration commands are unknown; NMEA
    /// sources are listen-only).
    Unsupported,
    /// Another job is running.
    Busy,
    /// Stop requested but no user calibration is running.
    NotCalibrating,
}

impl core::fmt::Display for RequestError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::Unsupported => "not supported by this compass dialect",
            Self::Busy => "another compass job is running",
            Self::NotCalibrating => "no user calibration is running",
        })
    }
}

impl core::error::Error for RequestError {}

impl ima_hal::Error for RequestError {
    fn kind(&self) -> ima_hal::ErrorKind {
        match self {
            Self::Unsupported | Self::NotCalibrating => ima_hal::ErrorKind::InvalidArgument,
            Self::Busy => ima_hal::ErrorKind::Other,
        }
    }
}

/// Counters of the session (saturating).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Stats {
    /// The framer's counters.
    pub framer: FramerStats,
    /// Lines that framed but did not parse.
    pub parse_errors: u32,
    /// Heading events produced.
    pub headings: u32,
    /// Events dropped because the caller did not poll (oldest first).
    pub events_dropped: u32,
    /// Bytes received.
    pub bytes: u32,
    /// Lines of another dialect, ignored (see [`Machine::foreign_line`]).
    pub foreign_lines: u32,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Wait {
    /// For a `>`; retried.
    Prompt,
    /// For the command gap.
    Gap,
    /// For a calibration score line, or the score timeout.
    Score,
    /// For any data line; retried by restarting the script.
    Data,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Step {
    cmd: Option<Command>,
    wait: Wait,
}

const MAX_STEPS: usize = 6;
const EVENT_CAPACITY: usize = 16;
const TX_CAPACITY: usize = 4;

#[derive(Debug, Clone)]
struct Script {
    job: Job,
    steps: Vec<Step, MAX_STEPS>,
    index: usize,
    deadline: Instant,
    retries_left: u8,
    score: Option<CalScore>,
}

/// The compass session. See the [module docs](self).
#[derive(Debug, Clone)]
pub struct Machine {
    config: Config,
    framer: LineFramer,
    script: Option<Script>,
    started: bool,
    user_calibrating: bool,
    quality: CalibrationQuality,
    last_error: Option<u16>,
    last_data: Instant,
    stale_reported: bool,
    tx: Deque<Command, TX_CAPACITY>,
    events: Deque<Event, EVENT_CAPACITY>,
    stats: Stats,
    foreign: Option<ForeignLine>,
}

fn kvh(c: KvhCommand) -> Option<Command> {
    Some(Command::Kvh(c))
}

fn tcm(c: Tcm2Command) -> Option<Command> {
    Some(Command::Tcm2(c))
}

impl Machine {
    /// A session that has not started; it parses whatever arrives but sends nothing until
    /// [`Machine::start`].
    #[must_use]
    pub fn new(config: Config) -> Self {
        Self {
            config,
            framer: crate::framer::framer(),
            script: None,
            started: false,
            user_calibrating: false,
            quality: CalibrationQuality::default(),
            last_error: None,
            last_data: Instant::ZERO,
            stale_reported: false,
            tx: Deque::new(),
            foreign: None,
            events: Deque::new(),
            stats: Stats::default(),
        }
    }

    /// The settings.
    #[must_use]
    pub fn config(&self) -> &Config {
        &self.config
    }

    /// Counters.
    #[must_use]
    pub fn stats(&self) -> Stats {
        Stats {
            framer: self.framer.stats(),
            ..self.stats
        }
    }

    /// The job running, if any.
    #[must_use]
    pub fn current_job(&self) -> Option<Job> {
        self.script.as_ref().map(|s| s.job)
    }

    /// A TCM2 user calibration is running (between its start and stop).
    #[must_use]
    pub fn is_user_calibrating(&self) -> bool {
        self.user_calibrating
    }

    /// Calibration quality as far as known (TCM2 only; `None` for other dialects).
    #[must_use]
    pub fn calibration(&self) -> Option<CalibrationQuality> {
        matches!(self.config.dialect, Dialect::Tcm2 { .. }).then_some(self.quality)
    }

    /// Start the session: configure the device (or, for [`Dialect::Nmea`], wait for data).
    pub fn start(&mut self, now: Instant) {
        self.started = true;
        self.last_data = now;
        self.stale_reported = false;
        self.tx.clear();
        self.begin(Job::Configure, now);
    }

    /// Start a TCM2 user calibration.
    ///
    /// # Errors
    /// [`RequestError::Unsupported`] for other dialects, [`RequestError::Busy`] while a job or
    /// a calibration runs.
    pub fn start_user_calibration(&mut self, now: Instant) -> Result<(), RequestError> {
        self.check_tcm2()?;
        if self.user_calibrating {
            return Err(RequestError::Busy);
        }
        self.begin(Job::StartUserCalibration, now);
        Ok(())
    }

    /// Stop the running TCM2 user calibration; [`Event::CalibrationFinished`] follows.
    ///
    /// # Errors
    /// [`RequestError::Unsupported`], [`RequestError::Busy`], [`RequestError::NotCalibrating`].
    pub fn stop_user_calibration(&mut self, now: Instant) -> Result<(), RequestError> {
        self.check_tcm2()?;
        if !self.user_calibrating {
            return Err(RequestError::NotCalibrating);
        }
        self.begin(Job::StopUserCalibration, now);
        Ok(())
    }

    /// Switch TCM2 continuous automatic calibration on or off.
    ///
    /// # Errors
    /// [`RequestError::Unsupported`], [`RequestError::Busy`].
    pub fn set_auto_calibration(&mut self, on: bool, now: Instant) -> Result<(), RequestError> {
        self.check_tcm2()?;
        if self.user_calibrating {
            return Err(RequestError::Busy);
        }
        self.begin(Job::AutoCalibration(on), now);
        Ok(())
    }

    /// Clear the TCM2 calibration.
    ///
    /// # Errors
    /// [`RequestError::Unsupported`], [`RequestError::Busy`].
    pub fn clear_calibration(&mut self, now: Instant) -> Result<(), RequestError> {
        self.check_tcm2()?;
        if self.user_calibrating {
            return Err(RequestError::Busy);
        }
        self.begin(Job::ClearCalibration, now);
        Ok(())
    }

    fn check_tcm2(&self) -> Result<(), RequestError> {
        if !matches!(self.config.dialect, Dialect::Tcm2 { .. }) {
            return Err(RequestError::Unsupported);
        }
        if self.script.is_some() {
            return Err(RequestError::Busy);
        }
        Ok(())
    }

    fn steps(&self, job: Job) -> Vec<Step, MAX_STEPS> {
        use Tcm2Command as T;
        let gap = |c| Step {
            cmd: tcm(c),
            wait: Wait::Gap,
        };
        let go = Step {
            cmd: tcm(T::Go),
            wait: Wait::Data,
        };
        let list: &[Step] = match (job, self.config.dialect) {
            (Job::Configure, Dialect::Nmea) => &[Step {
                cmd: None,
                wait: Wait::Data,
            }],
            (Job::Configure, Dialect::KvhC100 { rate_per_minute }) => &[
                Step {
                    cmd: kvh(KvhCommand::OutputFormat(KvhFormat::Nmea)),
                    wait: Wait::Prompt,
                },
                Step {
                    cmd: kvh(KvhCommand::Rate {
                        per_minute: rate_per_minute,
                    }),
                    wait: Wait::Prompt,
                },
                Step {
                    cmd: None,
                    wait: Wait::Data,
                },
            ],
            (
                Job::Configure,
                Dialect::Tcm2 {
                    sample_rate_hz,
                    output,
                },
            ) => &[
                gap(T::Halt),
                gap(T::OutputFormat(output)),
                gap(T::SampleRate(sample_rate_hz)),
                go,
            ],
            (_, Dialect::Nmea | Dialect::KvhC100 { .. }) => &[],
            (Job::StartUserCalibration, _) => &[gap(T::Halt), gap(T::UserCalibrationOn), go],
            (Job::StopUserCalibration, _) => &[
                gap(T::Halt),
                Step {
                    cmd: tcm(T::UserCalibrationOff),
                    wait: Wait::Score,
                },
                go,
            ],
            (Job::AutoCalibration(on), _) => &[gap(T::Halt), gap(T::AutoCalibration(on)), go],
            (Job::ClearCalibration, _) => &[gap(T::Halt), gap(T::ClearCalibration), go],
        };
        list.iter().copied().take(MAX_STEPS).collect()
    }

    fn begin(&mut self, job: Job, now: Instant) {
        self.script = Some(Script {
            job,
            steps: self.steps(job),
            index: 0,
            deadline: now,
            retries_left: self.config.retries,
            score: None,
        });
        self.run_step(now);
    }

    /// Send the current step's command and arm its deadline; finish the job past the end.
    fn run_step(&mut self, now: Instant) {
        let data_wait = self.data_wait();
        let Some(script) = self.script.as_mut() else {
            return;
        };
        let Some(step) = script.steps.get(script.index).copied() else {
            self.finish();
            return;
        };
        if let Some(cmd) = step.cmd {
            // The queue holds at most one command per step; a full queue only happens when
            // the caller never polls, and then the oldest command is stale anyway.
            if self.tx.is_full() {
                let _ = self.tx.pop_front();
            }
            let _ = self.tx.push_back(cmd);
        }
        let wait = match step.wait {
            Wait::Prompt => self.config.reply_timeout,
            Wait::Data => data_wait,
            Wait::Gap => self.config.command_gap,
            Wait::Score => self.config.score_timeout,
        };
        script.deadline = now + wait;
    }

    /// How long a step waits for the first reading: the reply timeout, or two output periods
    /// of the rate asked when that is longer (at 1 Hz the first heading comes up to 1 s after
    /// the rate is set, and 500 ms failed every configuration). A plain NMEA source's rate is
    /// not known: 2.5 s, for one at 1 Hz.
    fn data_wait(&self) -> Duration {
        let period_ms = match self.config.dialect {
            Dialect::KvhC100 { rate_per_minute } => 60_000 / u64::from(rate_per_minute.max(1)),
            Dialect::Tcm2 { sample_rate_hz, .. } => 1_000 / u64::from(sample_rate_hz.max(1)),
            Dialect::Nmea => 1_250,
        };
        self.config
            .reply_timeout
            .max(Duration::from_millis(2 * period_ms))
    }

    fn next_step(&mut self, now: Instant) {
        if let Some(s) = self.script.as_mut() {
            s.index = s.index.saturating_add(1);
        }
        self.run_step(now);
    }

    fn finish(&mut self) {
        let Some(script) = self.script.take() else {
            return;
        };
        let event = match script.job {
            Job::Configure => Event::Configured,
            Job::StartUserCalibration => {
                self.user_calibrating = true;
                Event::CalibrationStarted
            }
            Job::StopUserCalibration => {
                self.user_calibrating = false;
                if let Some(s) = script.score {
                    self.quality.horizontal_score = Some(s.h);
                    self.quality.vertical_score = Some(s.v);
                    self.quality.distortion = Some(s.m.to_f64());
                }
                Event::CalibrationFinished {
                    score: script.score,
                }
            }
            Job::AutoCalibration(on) => {
                self.quality.auto_calibration = on;
                Event::AutoCalibration(on)
            }
            Job::ClearCalibration => {
                self.quality = CalibrationQuality {
                    auto_calibration: self.quality.auto_calibration,
                    ..CalibrationQuality::default()
                };
                Event::CalibrationCleared
            }
        };
        self.push_event(event);
    }

    fn current_wait(&self) -> Option<Wait> {
        let s = self.script.as_ref()?;
        s.steps.get(s.index).map(|st| st.wait)
    }

    fn push_event(&mut self, e: Event) {
        if self.events.is_full() {
            let _ = self.events.pop_front();
            self.stats.events_dropped = self.stats.events_dropped.saturating_add(1);
        }
        let _ = self.events.push_back(e);
    }

    /// The last line of another dialect seen, if any (see the [module docs](self)).
    #[must_use]
    pub fn foreign_line(&self) -> Option<ForeignLine> {
        self.foreign
    }

    /// Whether a line of this kind belongs to another dialect than the configured one.
    fn is_foreign(&self, line: &Line) -> bool {
        matches!(
            (line, self.config.dialect),
            (
                Line::Nmea(_),
                Dialect::Tcm2 {
                    output: Tcm2Format::Standard,
                    ..
                },
            ) | (Line::Tcm2(_), Dialect::Nmea | Dialect::KvhC100 { .. })
        )
    }

    /// Feed received bytes (any chunking).
    pub fn handle_bytes(&mut self, bytes: &[u8], now: Instant) {
        let n = u32::try_from(bytes.len()).unwrap_or(u32::MAX);
        self.stats.bytes = self.stats.bytes.saturating_add(n);
        for &b in bytes {
            let parsed = match self.framer.push_byte(b) {
                Some(Frame::Line(l)) => Some(Line::parse(l, &self.config.parse)),
                Some(Frame::Prompt) => Some(Ok(Line::Prompt)),
                Some(Frame::Corrupt(_)) | None => None,
            };
            match parsed {
                Some(Ok(line)) => self.handle_frame(line, now),
                Some(Err(_)) => {
                    self.stats.parse_errors = self.stats.parse_errors.saturating_add(1);
                }
                None => {}
            }
        }
    }

    /// Feed one parsed line (what [`Machine::handle_bytes`] does for each line it frames).
    pub fn handle_frame(&mut self, line: Line, now: Instant) {
        if self.is_foreign(&line) {
            self.stats.foreign_lines = self.stats.foreign_lines.saturating_add(1);
            self.foreign = Some(match &line {
                Line::Nmea(s) => ForeignLine::Nmea {
                    talker: s.talker,
                    sentence: match s.body {
                        NmeaBody::Hdg(_) => *b"HDG",
                        NmeaBody::Hdm(_) => *b"HDM",
                        NmeaBody::Hdt(_) => *b"HDT",
                    },
                },
                _ => ForeignLine::Tcm2,
            });
            return;
        }
        match line {
            Line::Prompt => {
                if self.current_wait() == Some(Wait::Prompt) {
                    self.next_step(now);
                }
            }
            Line::CalScore(score) => {
                if self.current_wait() == Some(Wait::Score) {
                    if let Some(s) = self.script.as_mut() {
                        s.score = Some(score);
                    }
                    self.next_step(now);
                } else {
                    self.quality.horizontal_score = Some(score.h);
                    self.quality.vertical_score = Some(score.v);
                    self.quality.distortion = Some(score.m.to_f64());
                }
            }
            Line::Nmea(s) => {
                self.data_seen(now);
                if let Some(r) = self.reading_from_nmea(&s) {
                    self.emit_reading(r, now);
                }
            }
            Line::Tcm2(d) => {
                self.data_seen(now);
                if let Some(code) = d.error {
                    if self.last_error != Some(code) && code != 0 {
                        self.push_event(Event::DeviceError { code });
                    }
                    self.last_error = Some(code);
                }
                if let Some(r) = self.reading_from_tcm2(&d) {
                    self.emit_reading(r, now);
                }
            }
        }
    }

    fn data_seen(&mut self, now: Instant) {
        self.last_data = now;
        self.stale_reported = false;
        if self.current_wait() == Some(Wait::Data) {
            self.next_step(now);
        }
    }

    fn emit_reading(&mut self, r: Reading, now: Instant) {
        self.stats.headings = self.stats.headings.saturating_add(1);
        self.push_event(Event::Heading(Stamped::new(now, r)));
    }

    fn heading(&self, deg: f64, reference: HeadingReference) -> Heading {
        let mut h = Heading::new(wrap_2pi(deg.to_radians()), reference);
        h.calibration = self.calibration();
        h
    }

    fn reading_from_nmea(&self, s: &NmeaSentence) -> Option<Reading> {
        let deg = s.heading_deg()?;
        let heading = match &s.body {
            NmeaBody::Hdg(g) => {
                let mut h = self.heading(deg, HeadingReference::Magnetic);
                let signed = |o: crate::wire::Offset| {
                    let v = o.degrees.to_f64().to_radians();
                    match o.dir {
                        EastWest::East => v,
                        EastWest::West => -v,
                    }
                };
                h.deviation_rad = g.deviation.map(signed);
                h.variation_rad = g.variation.map(signed);
                h
            }
            NmeaBody::Hdm(_) => self.heading(deg, HeadingReference::Magnetic),
            NmeaBody::Hdt(_) => self.heading(deg, HeadingReference::True),
        };
        Some(Reading {
            heading,
            pitch_rad: None,
            roll_rad: None,
            temperature_c: None,
            error_code: None,
            source: Source::Nmea(s.talker),
        })
    }

    fn reading_from_tcm2(&self, d: &Tcm2Data) -> Option<Reading> {
        let deg = d.heading?.to_f64();
        Some(Reading {
            heading: self.heading(deg, HeadingReference::Magnetic),
            pitch_rad: d.pitch.map(|p| p.to_f64().to_radians()),
            roll_rad: d.roll.map(|p| p.to_f64().to_radians()),
            temperature_c: d.temperature.map(crate::wire::Decimal::to_f64),
            error_code: d.error,
            source: Source::Tcm2,
        })
    }

    /// Call when [`Machine::poll_timeout`] is due (calling early or late is harmless).
    pub fn handle_timeout(&mut self, now: Instant) {
        if let Some(s) = self.script.as_mut()
            && now >= s.deadline
        {
            let wait = s.steps.get(s.index).map(|st| st.wait);
            match wait {
                Some(Wait::Gap | Wait::Score) | None => self.next_step(now),
                Some(w @ (Wait::Prompt | Wait::Data)) => {
                    if s.retries_left > 0 {
                        s.retries_left -= 1;
                        if w == Wait::Data {
                            s.index = 0;
                        }
                        self.run_step(now);
                    } else {
                        let (job, step) = (s.job, u8::try_from(s.index).unwrap_or(u8::MAX));
                        self.script = None;
                        self.push_event(Event::JobFailed { job, step });
                        // Watch the data from here on.
                        self.last_data = now;
                        self.stale_reported = false;
                    }
                }
            }
        }
        if let Some(due) = self.watchdog_due()
            && now >= due
        {
            self.stale_reported = true;
            self.push_event(Event::DataTimeout);
        }
    }

    fn watchdog_due(&self) -> Option<Instant> {
        if !self.started || self.script.is_some() || self.stale_reported {
            return None;
        }
        self.config.data_timeout.map(|t| self.last_data + t)
    }

    /// When [`Machine::handle_timeout`] must next be called.
    #[must_use]
    pub fn poll_timeout(&self) -> Option<Instant> {
        let job = self.script.as_ref().map(|s| s.deadline);
        match (job, self.watchdog_due()) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// Write the next command into `buf` (at least [`crate::wire::command::MAX_COMMAND`]
    /// bytes) and return its length. A too-small buffer returns `None` and keeps the command.
    pub fn poll_transmit(&mut self, buf: &mut [u8]) -> Option<usize> {
        let cmd = self.tx.front()?;
        let n = cmd.emit(buf).ok()?;
        let _ = self.tx.pop_front();
        Some(n)
    }

    /// The next event.
    pub fn poll_event(&mut self) -> Option<Event> {
        self.events.pop_front()
    }
}

ima_serial::impl_machine!(Machine, Event, |m, _now, buf| m.poll_transmit(buf));

#[cfg(test)]
mod tests;

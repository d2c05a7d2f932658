//! The async I/O shell (feature `tokio`): one task owns the byte stream and the sans-IO
//! [`Machine`]; cloneable [`CompassDriver`] handles talk to it and implement
//! [`ima_hal::compass::Compass`].
//!
//! The shell is generic over any `AsyncRead + AsyncWrite` stream: a
//! `tokio_serial::SerialStream` from [`open_port`] on a real port or a pty, or an in-memory
//! duplex in tests. It waits with one `select!` over the stream, the machine's next timer and
//! the handles' requests, so a compass that goes quiet never blocks it. Time is tokio time
//! ([`TokioClock`]), so tests can run in paused virtual time.

use std::time::Duration;

use ima_hal::compass::{Compass, Heading};
use ima_hal::{ErrorType, Instant, Stamped};
use ima_serial::runner::{self, End, Flow, Shell};
use ima_serial::{BaudControl, FixedBaud};
use tokio::io::{AsyncRead, AsyncWrite};
use tokio::sync::{mpsc, oneshot, watch};

pub use crate::driver::DriverError;
use crate::machine::{Config, Dialect, Event, Machine, Reading, Stats};
use crate::wire::CalScore;
/// Open a serial port for the shell: `baud` 8N1, no flow control (NMEA compasses: 4800;
/// TCM2: 9600).
pub use ima_serial::open_port;

/// The default line speed of a dialect (spec §7a: NMEA 4800, TCM2 9600).
#[must_use]
pub fn default_baud(dialect: Dialect) -> u32 {
    match dialect {
        Dialect::Nmea | Dialect::KvhC100 { .. } => 4800,
        Dialect::Tcm2 { .. } => 9600,
    }
}

/// The clock types a shell takes: the caller passes the process's one [`SharedClock`]
/// (usually a [`TokioClock`], so paused tests run in virtual time) to `connect`, and every
/// stamp the driver produces is on that time line.
pub use ima_hal::time::{Clock, SharedClock, TokioClock};

/// Link status as seen by handles: connecting while configuring (plain NMEA: until the
/// first sentence), connected while headings flow, lost while the device is silent.
pub type LinkStatus = ima_serial::LinkStatus<(), DriverError>;

/// A calibration request (TCM2 only).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Calibration {
    /// `h`, `mpcal=e`, `go`: start the user calibration (turn the robot through full circles).
    StartUser,
    /// `h`, `mpcal=d`, `go`: stop it; the device's score is returned if it sends one.
    StopUser,
    /// `autocal=e` / `autocal=d`.
    Auto(bool),
    /// `cc`: clear the calibration.
    Clear,
}

/// What a finished calibration request reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CalibrationOutcome {
    /// User calibration runs.
    Started,
    /// User calibration stopped, with the score line if one came.
    Finished(Option<CalScore>),
    /// Automatic calibration switched.
    Auto(bool),
    /// Calibration cleared.
    Cleared,
}

type JobReply = oneshot::Sender<Result<CalibrationOutcome, DriverError>>;

/// A request from a handle to the driver task.
#[derive(Debug)]
pub enum Request {
    /// Run a calibration request.
    Calibrate(Calibration, JobReply),
    /// End the task.
    Close(oneshot::Sender<Result<(), DriverError>>),
}

/// The receiving ends of what [`CompassShell`] publishes.
#[derive(Debug, Clone)]
pub(crate) struct Watches {
    pub(crate) reading: watch::Receiver<Option<Stamped<Reading>>>,
    pub(crate) link: watch::Receiver<LinkStatus>,
    pub(crate) stats: watch::Receiver<Stats>,
}

/// Machine events → readings and answers, for both shells.
#[derive(Debug)]
pub struct CompassShell {
    machine: Machine,
    reading_tx: watch::Sender<Option<Stamped<Reading>>>,
    link_tx: watch::Sender<LinkStatus>,
    stats_tx: watch::Sender<Stats>,
    job: Option<JobReply>,
}

impl CompassShell {
    pub(crate) fn new(cfg: Config) -> (Self, Watches) {
        let (reading_tx, reading) = watch::channel(None);
        let (link_tx, link) = watch::channel(LinkStatus::Connecting);
        let (stats_tx, stats) = watch::channel(Stats::default());
        let shell = Self {
            machine: Machine::new(cfg),
            reading_tx,
            link_tx,
            stats_tx,
            job: None,
        };
        (
            shell,
            Watches {
                reading,
                link,
                stats,
            },
        )
    }

    fn finish_job(&mut self, r: Result<CalibrationOutcome, DriverError>) {
        if let Some(j) = self.job.take() {
            let _ = j.send(r);
        }
    }
}

impl Shell for CompassShell {
    type Machine = Machine;
    type Request = Request;
    const MAX_FRAME: usize = crate::wire::command::MAX_COMMAND;

    fn machine(&mut self) -> &mut Machine {
        &mut self.machine
    }

    fn start(&mut self, now: Instant) {
        self.machine.start(now);
    }

    fn on_event(&mut self, ev: Event, _line: &mut dyn BaudControl) -> std::io::Result<()> {
        match ev {
            Event::Heading(r) => {
                self.reading_tx.send_replace(Some(r));
                if *self.link_tx.borrow() == LinkStatus::Lost {
                    self.link_tx.send_replace(LinkStatus::Connected(()));
                }
            }
            Event::Configured => {
                tracing::info!("compass: configured, data flowing");
                self.link_tx.send_replace(LinkStatus::Connected(()));
            }
            Event::JobFailed { job, step } => {
                tracing::warn!(?job, step, "compass: job failed");
                if job == crate::machine::Job::Configure {
                    let e = crate::driver::configuration_failed(&self.machine, step);
                    self.finish_job(Err(e));
                    self.link_tx.send_replace(LinkStatus::Failed(e));
                } else {
                    self.finish_job(Err(DriverError::JobFailed { job, step }));
                }
            }
            Event::CalibrationStarted => self.finish_job(Ok(CalibrationOutcome::Started)),
            Event::CalibrationFinished { score } => {
                self.finish_job(Ok(CalibrationOutcome::Finished(score)));
            }
            Event::AutoCalibration(on) => self.finish_job(Ok(CalibrationOutcome::Auto(on))),
            Event::CalibrationCleared => self.finish_job(Ok(CalibrationOutcome::Cleared)),
            Event::DeviceError { code } => {
                tracing::warn!(code, "compass: device reports an error code");
            }
            Event::DataTimeout => {
                tracing::warn!("compass: no data");
                if self.link_tx.borrow().is_connected() {
                    self.link_tx.send_replace(LinkStatus::Lost);
                }
            }
        }
        Ok(())
    }

    fn on_request(&mut self, req: Request, now: Instant) -> Flow {
        let (what, reply) = match req {
            Request::Close(done) => {
                let _ = done.send(Ok(()));
                return Flow::Close;
            }
            Request::Calibrate(what, reply) => (what, reply),
        };
        if self.job.is_some() {
            let _ = reply.send(Err(DriverError::Request(
                crate::machine::RequestError::Busy,
            )));
            return Flow::Continue;
        }
        let r = match what {
            Calibration::StartUser => self.machine.start_user_calibration(now),
            Calibration::StopUser => self.machine.stop_user_calibration(now),
            Calibration::Auto(on) => self.machine.set_auto_calibration(on, now),
            Calibration::Clear => self.machine.clear_calibration(now),
        };
        match r {
            Ok(()) => self.job = Some(reply),
            Err(e) => {
                let _ = reply.send(Err(DriverError::Request(e)));
            }
        }
        Flow::Continue
    }

    fn after_round(&mut self) {
        self.stats_tx.send_replace(self.machine.stats());
    }

    fn end(&mut self, how: End) {
        let e = how.error();
        self.finish_job(Err(e));
        let link = match how {
            End::Closed { .. } => LinkStatus::Closed,
            End::Failed(_) => LinkStatus::Failed(e),
        };
        self.link_tx.send_replace(link);
    }
}

/// How long [`CompassDriver::connect`] waits by default.
pub const DEFAULT_CONNECT_TIMEOUT: Duration = Duration::from_secs(5);

/// How long [`Compass::next_heading`] waits for a fresh reading.
pub const HEADING_TIMEOUT: Duration = Duration::from_secs(3);

/// A handle to a running compass driver. Cheap to clone; every clone talks to the same task.
#[derive(Debug, Clone)]
pub struct CompassDriver {
    tx: mpsc::Sender<Request>,
    w: Watches,
    clock: SharedClock,
    dialect: Dialect,
}

impl CompassDriver {
    /// Spawn the driver task on `stream`, configure the device and wait until headings flow
    /// (or `connect_timeout` passes). Must be called inside a tokio runtime.
    ///
    /// # Errors
    /// [`DriverError::WrongDialect`] if the device speaks another dialect,
    /// [`DriverError::NoAnswer`] if configuration gave up or timed out without headings
    /// (with what the line carried), [`DriverError::Timeout`],
    /// [`DriverError::Disconnected`] / [`DriverError::Io`] if the stream failed.
    ///
    /// `clock` is the process's one time base: every reading's stamp is taken on it.
    pub async fn connect<S>(
        stream: S,
        cfg: Config,
        connect_timeout: Duration,
        clock: SharedClock,
    ) -> Result<Self, DriverError>
    where
        S: AsyncRead + AsyncWrite + Unpin + Send + 'static,
    {
        let (shell, mut w) = CompassShell::new(cfg);
        let tx = runner::spawn(shell, FixedBaud(stream), clock.clone(), None);
        match runner::wait_connected(&mut w.link, connect_timeout).await {
            Ok(()) => Ok(Self {
                tx,
                w,
                clock,
                dialect: cfg.dialect,
            }),
            Err(Some(e)) => Err(e),
            Err(None) => {
                let _ = tx.try_send(Request::Close(oneshot::channel().0));
                // Say what the line carried rather than just "in time".
                let st = *w.stats.borrow();
                if st.headings == 0 {
                    return Err(crate::driver::no_answer(&st, None));
                }
                Err(DriverError::Timeout)
            }
        }
    }

    /// The dialect in use.
    #[must_use]
    pub fn dialect(&self) -> Dialect {
        self.dialect
    }

    /// Current link status.
    #[must_use]
    pub fn link(&self) -> LinkStatus {
        *self.w.link.borrow()
    }

    /// Session counters.
    #[must_use]
    pub fn stats(&self) -> Stats {
        *self.w.stats.borrow()
    }

    /// The driver's clock (the time base of every stamp it produces).
    #[must_use]
    pub fn now(&self) -> Instant {
        self.clock.now()
    }

    /// The latest full reading (pitch, roll, temperature where the device sends them).
    #[must_use]
    pub fn latest(&self) -> Option<Stamped<Reading>> {
        *self.w.reading.borrow()
    }

    /// Wait for a reading stamped after `after` (at most `timeout`).
    ///
    /// # Errors
    /// [`DriverError::Timeout`], [`DriverError::Disconnected`].
    pub async fn next_reading(
        &self,
        after: Instant,
        timeout: Duration,
    ) -> Result<Stamped<Reading>, DriverError> {
        let newer = |r: &Option<Stamped<Reading>>| r.filter(|r| r.at > after);
        Ok(runner::wait_for(&self.w.reading, timeout, newer).await?)
    }

    /// Run a TCM2 calibration request and wait for its outcome.
    ///
    /// # Errors
    /// [`DriverError::Request`] (other dialects: `Unsupported`; `Busy`; `NotCalibrating`),
    /// [`DriverError::JobFailed`], [`DriverError::Timeout`], [`DriverError::Disconnected`].
    pub async fn calibrate(&self, what: Calibration) -> Result<CalibrationOutcome, DriverError> {
        let make = |tx| Request::Calibrate(what, tx);
        runner::request(&self.tx, make, Duration::from_secs(10)).await
    }

    /// End the driver task (the device keeps streaming; nothing is sent).
    pub async fn close(&self) {
        let _ = runner::request(&self.tx, Request::Close, Duration::from_secs(2)).await;
    }
}

impl ErrorType for CompassDriver {
    type Error = DriverError;
}

impl Compass for CompassDriver {
    async fn heading(&mut self) -> Result<Stamped<Heading>, DriverError> {
        if let Some(r) = self.latest() {
            return Ok(r.map(|r| r.heading));
        }
        Ok(self
            .next_reading(Instant::ZERO, HEADING_TIMEOUT)
            .await?
            .map(|r| r.heading))
    }

    async fn next_heading(&mut self, after: Instant) -> Result<Stamped<Heading>, DriverError> {
        Ok(self
            .next_reading(after, HEADING_TIMEOUT)
            .await?
            .map(|r| r.heading))
    }
}

//! The I/O shell (feature `tokio`): [`CompassShell`] turns the sans-IO [`Machine`]'s events
//! into readings, and cloneable [`CompassDriver`] handles implement
//! [`ima_hal::compass::Compass`]; [`ima_serial::runner`] does the I/O (one `select!` over
//! the stream, the machine's next timer and the handles' calls, so a compass that goes
//! quiet never blocks it), and blocking code uses
//! `ima_serial::blocking::Blocking<CompassDriver>`.
//!
//! The stream is any `AsyncRead + AsyncWrite`: a `tokio_serial::SerialStream` from
//! [`open_port`] on a real port or a pty, or an in-memory duplex in tests.

use std::time::Duration;

use ima_hal::compass::{Compass, Heading};
use ima_hal::{ErrorType, Instant, Stamped};
use ima_serial::handle::{Handle, Pending, Slot, SlotRx, slot};
use ima_serial::runner::{Reply, Shell};
use ima_serial::{BaudControl, FixedBaud};
use tokio::io::{AsyncRead, AsyncWrite};
use tokio::sync::watch;

pub use crate::driver::{DriverError, Fault};
use crate::machine::{Config, Dialect, Event, Machine, Reading, RequestError, Stats};
use crate::wire::CalScore;
/// The calls every driver handle answers alike: `link`, `stats`, `now`, `halt_signal`, `close`.
pub use ima_serial::handle::Driver;
/// Open a serial port for the shell: `baud` 8N1, no flow control (NMEA compasses: 4800;
/// TCM2: 9600).
pub use ima_serial::open_port;

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

/// Machine events → readings and answers.
#[derive(Debug)]
pub struct CompassShell {
    machine: Machine,
    link: watch::Sender<LinkStatus>,
    reading: Slot<Reading>,
    /// The calibration request being run.
    job: Pending<CalibrationOutcome, Self>,
}

impl Shell for CompassShell {
    type Machine = Machine;
    type Fault = Fault;
    type Up = ();
    type Stats = Stats;
    const MAX_FRAME: usize = crate::wire::command::MAX_COMMAND;

    fn machine(&mut self) -> &mut Machine {
        &mut self.machine
    }

    fn link(&self) -> &watch::Sender<LinkStatus> {
        &self.link
    }

    fn start(&mut self, now: Instant) {
        self.machine.start(now);
    }

    fn on_event(&mut self, ev: Event, _line: &mut dyn BaudControl) -> std::io::Result<()> {
        match ev {
            Event::Heading(r) => {
                self.reading.send_replace(Some(r));
                if *self.link.borrow() == LinkStatus::Lost {
                    self.link.send_replace(LinkStatus::Connected(()));
                }
            }
            Event::Configured => {
                tracing::info!("compass: configured, data flowing");
                self.link.send_replace(LinkStatus::Connected(()));
            }
            Event::JobFailed { job, step } => {
                // While connecting, or for a job a caller still waits on, the caller gets the
                // error: no warning beside it. Otherwise (a re-configuration after a loss, a
                // caller that gave up) it is news.
                let told = self.job.is_heard() || *self.link.borrow() == LinkStatus::Connecting;
                if told {
                    tracing::debug!(%job, step, "compass: job failed");
                } else {
                    tracing::warn!(%job, step, "compass: job failed");
                }
                if job == crate::machine::Job::Configure {
                    let e = crate::driver::configuration_failed(&self.machine, step);
                    self.job.answer(Err(e));
                    self.link.send_replace(LinkStatus::Failed(e));
                } else {
                    self.job.answer(Err(Fault::JobFailed { job, step }.into()));
                }
            }
            Event::CalibrationStarted => self.job.answer(Ok(CalibrationOutcome::Started)),
            Event::CalibrationFinished { score } => {
                self.job.answer(Ok(CalibrationOutcome::Finished(score)));
            }
            Event::AutoCalibration(on) => self.job.answer(Ok(CalibrationOutcome::Auto(on))),
            Event::CalibrationCleared => self.job.answer(Ok(CalibrationOutcome::Cleared)),
            Event::DeviceError { code } => {
                tracing::warn!(code, "compass: device reports an error code");
            }
            Event::DataTimeout => {
                tracing::warn!("compass: no data");
                if self.link.borrow().is_connected() {
                    self.link.send_replace(LinkStatus::Lost);
                }
            }
        }
        Ok(())
    }

    fn stats(&self) -> Stats {
        self.machine.stats()
    }

    /// Say what the line carried rather than just "in time".
    fn no_answer(&mut self) -> DriverError {
        let st = self.machine.stats();
        if st.headings == 0 {
            return crate::driver::no_answer(&st, None);
        }
        DriverError::Timeout
    }
}

/// How long [`CompassDriver::connect`] waits by default.
pub const DEFAULT_CONNECT_TIMEOUT: Duration = Duration::from_secs(5);

/// How long [`Compass::next_heading`] waits for a fresh reading.
pub const HEADING_TIMEOUT: Duration = Duration::from_secs(3);

/// A handle to a running compass driver. Cheap to clone; every clone talks to the same task.
#[derive(Debug, Clone)]
pub struct CompassDriver {
    h: Handle<CompassShell>,
    reading: SlotRx<Reading>,
    dialect: Dialect,
}

impl CompassDriver {
    /// Spawn the driver task on `stream`, configure the device and wait until headings flow
    /// (or `connect_timeout` passes). Must be called inside a tokio runtime.
    ///
    /// # Errors
    /// [`Fault::WrongDialect`] if the device speaks another dialect, [`Fault::NoAnswer`] if
    /// configuration gave up or timed out without headings (with what the line carried),
    /// [`DriverError::Timeout`], [`DriverError::Disconnected`] / [`DriverError::Io`] if the
    /// stream failed.
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
        let (reading_tx, reading) = slot();
        let shell = CompassShell {
            machine: Machine::new(cfg),
            link: watch::channel(LinkStatus::Connecting).0,
            reading: reading_tx,
            job: Pending::default(),
        };
        let stream = FixedBaud(stream);
        let (h, ()) = Handle::connect(shell, stream, clock, connect_timeout, None).await?;
        Ok(Self {
            h,
            reading,
            dialect: cfg.dialect,
        })
    }

    /// The dialect in use.
    #[must_use]
    pub fn dialect(&self) -> Dialect {
        self.dialect
    }

    /// The latest full reading (pitch, roll, temperature where the device sends them).
    #[must_use]
    pub fn latest(&self) -> Option<Stamped<Reading>> {
        *self.reading.borrow()
    }

    /// Wait for a reading stamped after `after` (at most `timeout`).
    ///
    /// # Errors
    /// [`DriverError::Timeout`], [`DriverError::Disconnected`], the link's failure.
    pub async fn next_reading(
        &self,
        after: Instant,
        timeout: Duration,
    ) -> Result<Stamped<Reading>, DriverError> {
        self.h.reading(&self.reading, Some(after), timeout).await
    }

    /// Run a TCM2 calibration request and wait for its outcome.
    ///
    /// # Errors
    /// [`Fault::Request`] (other dialects: `Unsupported`; `Busy`; `NotCalibrating`),
    /// [`Fault::JobFailed`], [`DriverError::Timeout`], [`DriverError::Disconnected`].
    pub async fn calibrate(&self, what: Calibration) -> Result<CalibrationOutcome, DriverError> {
        let f = move |s: &mut CompassShell, now, reply: Reply<_, CompassShell>| {
            let m = &mut s.machine;
            let r = match what {
                _ if s.job.is_waiting() => Err(RequestError::Busy),
                Calibration::StartUser => m.start_user_calibration(now),
                Calibration::StopUser => m.stop_user_calibration(now),
                Calibration::Auto(on) => m.set_auto_calibration(on, now),
                Calibration::Clear => m.clear_calibration(now),
            };
            s.job
                .wait(r.map_err(Into::into), reply, RequestError::Busy.into());
        };
        self.h.defer(Duration::from_secs(10), f).await
    }
}

impl Driver for CompassDriver {
    type Shell = CompassShell;
    const CLOSE_LIMIT: Duration = Duration::from_secs(2);
    fn handle(&self) -> &Handle<CompassShell> {
        &self.h
    }
}

impl ErrorType for CompassDriver {
    type Error = DriverError;
}

impl Compass for CompassDriver {
    async fn heading(&mut self) -> Result<Stamped<Heading>, DriverError> {
        let r = match self.latest() {
            Some(r) => r,
            None => self.next_reading(Instant::ZERO, HEADING_TIMEOUT).await?,
        };
        Ok(r.map(|r| r.heading))
    }

    async fn next_heading(&mut self, after: Instant) -> Result<Stamped<Heading>, DriverError> {
        let r = self.next_reading(after, HEADING_TIMEOUT).await?;
        Ok(r.map(|r| r.heading))
    }
}

//! The async I/O shell (feature `tokio`): one task owns the byte stream and the sans-IO
//! [`Machine`]; cloneable [`CompassDriver`] handles talk to it and implement
//! [`ima_hal::compass::Compass`].
//!
//! The shell is generic over any `AsyncRead + AsyncWrite` stream: a
//! `tokio_serial::SerialStream` from [`open_port`] on a real port or a pty, or an in-memory
//! duplex in tests. It waits with one `select!` over the stream, the machine's next timer and
//! the handles' requests, so a compass that goes quiet never blocks it. Time is tokio time
//! ([`TokioClock`]), so tests can run in paused virtual time.

use std::io;
use std::time::Duration;

use ima_hal::compass::{Compass, Heading};
use ima_hal::{ErrorType, Instant, Stamped};
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::sync::{mpsc, oneshot, watch};

pub use crate::driver::DriverError;
use crate::machine::{Config, Dialect, Event, Machine, Reading, Stats};
use crate::wire::CalScore;

/// Open a serial port for the shell: `baud` 8N1, no flow control (NMEA compasses: 4800;
/// TCM2: 9600).
///
/// A path that is not a serial port (a regular file, `/dev/null`) fails with
/// [`io::ErrorKind::InvalidInput`] and `PATH is not a serial port (…)`.
pub fn open_port(path: &str, baud: u32) -> io::Result<tokio_serial::SerialStream> {
    use tokio_serial::SerialPortBuilderExt;
    tokio_serial::new(path, baud)
        .data_bits(tokio_serial::DataBits::Eight)
        .parity(tokio_serial::Parity::None)
        .stop_bits(tokio_serial::StopBits::One)
        .flow_control(tokio_serial::FlowControl::None)
        .open_native_async()
        .map_err(|e| ima_hal::serial::explain_open_error(path, io::Error::from(e)))
}

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

/// Link status as seen by handles.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LinkStatus {
    /// Configuring the device (or, for plain NMEA, waiting for the first sentence).
    Configuring,
    /// Headings are flowing.
    Running,
    /// No data for the data timeout; waiting for it to come back.
    Silent,
    /// Failed for good.
    Failed(DriverError),
    /// The task ended.
    Closed,
}

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

enum Request {
    Calibrate(Calibration, JobReply),
    Close(oneshot::Sender<()>),
}

impl std::fmt::Debug for Request {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Request")
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
    reading: watch::Receiver<Option<Stamped<Reading>>>,
    link: watch::Receiver<LinkStatus>,
    stats: watch::Receiver<Stats>,
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
        let (tx, rx) = mpsc::channel(8);
        let (reading_tx, reading) = watch::channel(None);
        let (link_tx, mut link) = watch::channel(LinkStatus::Configuring);
        let (stats_tx, stats) = watch::channel(Stats::default());
        let task = Task {
            machine: Machine::new(cfg),
            clock: clock.clone(),
            rx,
            reading_tx,
            link_tx,
            stats_tx,
            job: None,
        };
        tokio::spawn(task.run(stream));
        let waited = tokio::time::timeout(connect_timeout, async {
            loop {
                match *link.borrow_and_update() {
                    LinkStatus::Running => return Ok(()),
                    LinkStatus::Failed(e) => return Err(e),
                    LinkStatus::Closed => return Err(DriverError::Disconnected),
                    LinkStatus::Configuring | LinkStatus::Silent => {}
                }
                if link.changed().await.is_err() {
                    return Err(DriverError::Disconnected);
                }
            }
        })
        .await;
        match waited {
            Ok(Ok(())) => Ok(Self {
                tx,
                reading,
                link,
                stats,
                clock,
                dialect: cfg.dialect,
            }),
            Ok(Err(e)) => Err(e),
            Err(_) => {
                let _ = tx.try_send(Request::Close(oneshot::channel().0));
                // Say what the line carried rather than just "in time".
                let st = *stats.borrow();
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
        *self.link.borrow()
    }

    /// Session counters.
    #[must_use]
    pub fn stats(&self) -> Stats {
        *self.stats.borrow()
    }

    /// The driver's clock (the time base of every stamp it produces).
    #[must_use]
    pub fn now(&self) -> Instant {
        self.clock.now()
    }

    /// The latest full reading (pitch, roll, temperature where the device sends them).
    #[must_use]
    pub fn latest(&self) -> Option<Stamped<Reading>> {
        *self.reading.borrow()
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
        let mut rx = self.reading.clone();
        tokio::time::timeout(timeout, async move {
            loop {
                if let Some(r) = *rx.borrow_and_update()
                    && r.at > after
                {
                    return Ok(r);
                }
                rx.changed().await.map_err(|_| DriverError::Disconnected)?;
            }
        })
        .await
        .map_err(|_| DriverError::Timeout)?
    }

    /// Run a TCM2 calibration request and wait for its outcome.
    ///
    /// # Errors
    /// [`DriverError::Request`] (other dialects: `Unsupported`; `Busy`; `NotCalibrating`),
    /// [`DriverError::JobFailed`], [`DriverError::Timeout`], [`DriverError::Disconnected`].
    pub async fn calibrate(&self, what: Calibration) -> Result<CalibrationOutcome, DriverError> {
        let (tx, rx) = oneshot::channel();
        self.tx
            .send(Request::Calibrate(what, tx))
            .await
            .map_err(|_| DriverError::Disconnected)?;
        match tokio::time::timeout(Duration::from_secs(10), rx).await {
            Ok(Ok(r)) => r,
            Ok(Err(_)) => Err(DriverError::Disconnected),
            Err(_) => Err(DriverError::Timeout),
        }
    }

    /// End the driver task (the device keeps streaming; nothing is sent).
    pub async fn close(&self) {
        let (tx, rx) = oneshot::channel();
        if self.tx.send(Request::Close(tx)).await.is_ok() {
            let _ = tokio::time::timeout(Duration::from_secs(2), rx).await;
        }
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

struct Task {
    machine: Machine,
    clock: SharedClock,
    rx: mpsc::Receiver<Request>,
    reading_tx: watch::Sender<Option<Stamped<Reading>>>,
    link_tx: watch::Sender<LinkStatus>,
    stats_tx: watch::Sender<Stats>,
    job: Option<JobReply>,
}

impl Task {
    async fn run<S>(mut self, mut stream: S)
    where
        S: AsyncRead + AsyncWrite + Unpin + Send + 'static,
    {
        let mut rbuf = [0u8; 256];
        let mut tbuf = [0u8; crate::wire::command::MAX_COMMAND];
        self.machine.start(self.clock.now());
        loop {
            self.drain_events();
            while let Some(n) = self.machine.poll_transmit(&mut tbuf) {
                let Some(cmd) = tbuf.get(..n) else { break };
                tracing::debug!(cmd = %String::from_utf8_lossy(cmd).trim_end(), "compass: send");
                if let Err(e) = stream.write_all(cmd).await {
                    self.fail(DriverError::Io(e.kind()));
                    return;
                }
            }
            let _ = stream.flush().await;
            self.stats_tx.send_replace(self.machine.stats());
            let sleep_for = self
                .machine
                .poll_timeout()
                .map_or(Duration::from_millis(500), |t| {
                    t.saturating_duration_since(self.clock.now())
                });
            tokio::select! {
                r = stream.read(&mut rbuf) => match r {
                    Ok(0) => { self.fail(DriverError::Disconnected); return; }
                    Ok(n) => {
                        let now = self.clock.now();
                        self.machine.handle_bytes(rbuf.get(..n).unwrap_or(&[]), now);
                    }
                    Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                    Err(e) => { self.fail(DriverError::Io(e.kind())); return; }
                },
                () = tokio::time::sleep(sleep_for) => {
                    self.machine.handle_timeout(self.clock.now());
                }
                req = self.rx.recv() => match req {
                    None => { self.close(); return; }
                    Some(Request::Close(done)) => { self.close(); let _ = done.send(()); return; }
                    Some(Request::Calibrate(what, reply)) => self.calibrate(what, reply),
                },
            }
        }
    }

    fn close(&mut self) {
        if let Some(j) = self.job.take() {
            let _ = j.send(Err(DriverError::Disconnected));
        }
        self.link_tx.send_replace(LinkStatus::Closed);
    }

    fn fail(&mut self, e: DriverError) {
        if let Some(j) = self.job.take() {
            let _ = j.send(Err(e));
        }
        self.link_tx.send_replace(LinkStatus::Failed(e));
    }

    fn calibrate(&mut self, what: Calibration, reply: JobReply) {
        if self.job.is_some() {
            let _ = reply.send(Err(DriverError::Request(
                crate::machine::RequestError::Busy,
            )));
            return;
        }
        let now = self.clock.now();
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
    }

    fn finish_job(&mut self, r: Result<CalibrationOutcome, DriverError>) {
        if let Some(j) = self.job.take() {
            let _ = j.send(r);
        }
    }

    fn drain_events(&mut self) {
        while let Some(ev) = self.machine.poll_event() {
            match ev {
                Event::Heading(r) => {
                    self.reading_tx.send_replace(Some(r));
                    if *self.link_tx.borrow() == LinkStatus::Silent {
                        self.link_tx.send_replace(LinkStatus::Running);
                    }
                }
                Event::Configured => {
                    tracing::info!("compass: configured, data flowing");
                    self.link_tx.send_replace(LinkStatus::Running);
                }
                Event::JobFailed { job, step } => {
                    tracing::warn!(?job, step, "compass: job failed");
                    if job == crate::machine::Job::Configure {
                        let e = crate::driver::configuration_failed(&self.machine, step);
                        self.fail(e);
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
                    if *self.link_tx.borrow() == LinkStatus::Running {
                        self.link_tx.send_replace(LinkStatus::Silent);
                    }
                }
            }
        }
    }
}

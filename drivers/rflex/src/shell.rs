//! The async I/O shell (feature `tokio`): one task owns the byte stream and the
//! [`Machine`]; cloneable [`Rflex`] handles talk to it and implement the `ima-hal` traits
//! ([`DifferentialBase`], [`Odometer`], [`SonarArray`], [`Bumpers`], [`Power`]).
//!
//! The task `select!`s over the stream, the machine's next timer and the handles' requests,
//! so a base that goes quiet never blocks it. Time comes from [`TokioClock`], so tests run in
//! paused virtual time.
//!
//! * **Recovery**: when the machine reports [`Event::LinkLost`] the task re-sends the §6
//!   initialisation ([`Machine::reinitialize`]) every [`Config::link_timeout`] until the base
//!   streams motion reports again, so a power-cycled controller (reports off, brake on) comes back with
//!   reports, sonar and — if the motors had been enabled — the brake released.
//! * **Emergency stop**: the spec (§3, §6) names no emergency command, so
//!   [`DifferentialBase::emergency_stop`] zeroes both axes at once (the same SET_DIR pair as
//!   `stop`) and then engages the brake (MOT_BRAKE_SET), so the motors stay disabled until
//!   `enable_motors(true)`.
//! * **Host silence**: if the process dies, nothing is sent and the controller's own
//!   fail-safe stops the robot (§6); if only the client goes quiet, the machine's 0.5 s
//!   command watchdog zeroes the speed.

use std::io;
use std::sync::Arc;
use std::time::Duration;

use ima_hal::base::{
    BaseLimits, BumperState, Bumpers, DifferentialBase, Odometer, Odometry, VelocityCommand,
};
use ima_hal::power::{Power, PowerState};
use ima_hal::safety::{HaltSignal, StopRegistry};
use ima_hal::sonar::{SonarArray, SonarScan, SonarTransducer};
use ima_hal::{ErrorType, Instant, Stamped};
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::sync::{mpsc, oneshot, watch};

pub use crate::driver::{BAUD, DriverError};
use crate::machine::{Config, Event, Machine, Stats, TX_BUF};

/// Open a serial port for the shell: 115200 8N1, no flow control, raw (§1).
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

/// The clock types a shell takes: the caller passes the process's one [`SharedClock`]
/// (usually a [`TokioClock`], so paused tests run in virtual time) to `connect`, and every
/// stamp the driver produces is on that time line.
pub use ima_hal::time::{Clock, SharedClock, TokioClock};

/// Link status as seen by handles.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LinkStatus {
    /// Waiting for the first report.
    Connecting,
    /// Motion reports are arriving.
    Connected,
    /// No report for the link timeout; re-initialising.
    Lost,
    /// The task failed (I/O error, port closed).
    Failed(DriverError),
    /// The task ended.
    Closed,
}

/// Counters the task publishes.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ShellStats {
    /// The session's counters.
    pub session: Stats,
    /// The framer's counters.
    pub framer: crate::framer::Stats,
    /// Links lost and re-initialised.
    pub reconnects: u32,
    /// Bytes received.
    pub bytes: u64,
}

enum Request {
    Velocity(VelocityCommand, oneshot::Sender<Result<(), DriverError>>),
    EStop(oneshot::Sender<Result<(), DriverError>>),
    Motors(bool, oneshot::Sender<Result<(), DriverError>>),
    Sonar(bool, oneshot::Sender<Result<(), DriverError>>),
    ResetOdometry(oneshot::Sender<Result<(), DriverError>>),
    Close(oneshot::Sender<Result<(), DriverError>>),
}

impl std::fmt::Debug for Request {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Request")
    }
}

/// A handle to a running rFLEX driver. Cheap to clone; every clone talks to the same task.
#[derive(Debug, Clone)]
pub struct Rflex {
    tx: mpsc::Sender<Request>,
    odometry: watch::Receiver<Option<Stamped<Odometry>>>,
    sonar: watch::Receiver<Option<Stamped<SonarScan>>>,
    bumpers: watch::Receiver<Option<Stamped<BumperState>>>,
    power: watch::Receiver<Option<Stamped<PowerState>>>,
    brake: watch::Receiver<Option<Stamped<bool>>>,
    link: watch::Receiver<LinkStatus>,
    stats: watch::Receiver<ShellStats>,
    limits: BaseLimits,
    transducers: Arc<[SonarTransducer]>,
    clock: SharedClock,
    halt: HaltSignal,
}

/// How long [`Rflex::connect`] waits for the first motion report by default.
pub const DEFAULT_CONNECT_TIMEOUT: Duration = Duration::from_secs(5);

const REQUEST_TIMEOUT: Duration = Duration::from_secs(1);
const WAIT_TIMEOUT: Duration = Duration::from_secs(2);

impl Rflex {
    /// Spawn the driver task on `stream` (a port opened with [`open_port`], or any byte
    /// stream) and wait until the base streams motion reports (or `connect_timeout` passes).
    /// Must be called inside a tokio runtime.
    ///
    /// `clock` is the process's one time base: every reading's stamp is taken on it.
    pub async fn connect<S>(
        stream: S,
        cfg: Config,
        connect_timeout: Duration,
        clock: SharedClock,
    ) -> Result<Rflex, DriverError>
    where
        S: AsyncRead + AsyncWrite + Unpin + Send + 'static,
    {
        let (tx, rx) = mpsc::channel(32);
        let (odo_tx, odometry) = watch::channel(None);
        let (sonar_tx, sonar) = watch::channel(None);
        let (bump_tx, bumpers) = watch::channel(None);
        let (power_tx, power) = watch::channel(None);
        let (brake_tx, brake) = watch::channel(None);
        let (link_tx, mut link) = watch::channel(LinkStatus::Connecting);
        let (stats_tx, stats) = watch::channel(ShellStats::default());
        let limits = cfg.limits;
        let machine = Machine::new(cfg, clock.now());
        let transducers: Arc<[SonarTransducer]> = machine
            .transducers()
            .iter()
            .copied()
            .collect::<Vec<_>>()
            .into();
        let halt = HaltSignal::new();
        StopRegistry::global().register("rFLEX base", halt.clone());
        let task = Task {
            machine,
            clock: clock.clone(),
            halt: halt.clone(),
            rx,
            odo_tx,
            sonar_tx,
            bump_tx,
            power_tx,
            brake_tx,
            link_tx,
            stats_tx,
            scan: SonarScan::default(),
            motors_waiters: Vec::new(),
            sonar_wanted: false,
            reinit_at: None,
            reconnects: 0,
            bytes: 0,
        };
        tracing::info!(target: "ima::connect", "rFLEX: initialising, waiting for motion reports");
        tokio::spawn(task.run(stream));
        let waited = tokio::time::timeout(connect_timeout, async {
            loop {
                match *link.borrow_and_update() {
                    LinkStatus::Connected => return Ok(()),
                    LinkStatus::Failed(e) => return Err(e),
                    LinkStatus::Closed => return Err(DriverError::Disconnected),
                    LinkStatus::Connecting | LinkStatus::Lost => {}
                }
                if link.changed().await.is_err() {
                    return Err(DriverError::Disconnected);
                }
            }
        })
        .await;
        match waited {
            Ok(Ok(())) => {}
            Ok(Err(e)) => return Err(e),
            Err(_) => {
                let _ = tx.try_send(Request::Close(oneshot::channel().0));
                // Say what the line carried.
                let st = *stats.borrow();
                return Err(DriverError::NoReport {
                    bytes: st.bytes,
                    frames: st.framer.frames,
                    bad_frames: st.framer.errors(),
                });
            }
        }
        Ok(Rflex {
            tx,
            odometry,
            sonar,
            bumpers,
            power,
            brake,
            link,
            stats,
            limits,
            transducers,
            clock,
            halt,
        })
    }

    /// This driver's halt signal: [`HaltSignal::halt`] stops the base and shuts the session
    /// down from any thread without awaiting (the same as [`close`](Self::close),
    /// fire-and-forget).
    #[must_use]
    pub fn halt_signal(&self) -> HaltSignal {
        self.halt.clone()
    }

    /// Current link status.
    #[must_use]
    pub fn link(&self) -> LinkStatus {
        *self.link.borrow()
    }

    /// Counters (session, framer, reconnects).
    #[must_use]
    pub fn stats(&self) -> ShellStats {
        *self.stats.borrow()
    }

    /// The brake as the base last reported it (`true` = engaged), if known.
    #[must_use]
    pub fn brake(&self) -> Option<Stamped<bool>> {
        *self.brake.borrow()
    }

    /// The latest odometry, if any.
    #[must_use]
    pub fn latest_odometry(&self) -> Option<Stamped<Odometry>> {
        *self.odometry.borrow()
    }

    /// The driver's clock (the time base of every stamp it produces).
    #[must_use]
    pub fn now(&self) -> Instant {
        self.clock.now()
    }

    async fn request(
        &self,
        make: impl FnOnce(oneshot::Sender<Result<(), DriverError>>) -> Request,
        timeout: Duration,
    ) -> Result<(), DriverError> {
        let (tx, rx) = oneshot::channel();
        self.tx
            .send(make(tx))
            .await
            .map_err(|_| DriverError::Disconnected)?;
        match tokio::time::timeout(timeout, rx).await {
            Ok(Ok(r)) => r,
            Ok(Err(_)) => Err(DriverError::Disconnected),
            Err(_) => Err(DriverError::Timeout),
        }
    }

    /// Send the shutdown sequence (§6), wait for it to go out, and end the driver task.
    pub async fn close(&self) -> Result<(), DriverError> {
        if self.halt.is_done() {
            return Ok(());
        }
        match self.request(Request::Close, Duration::from_secs(2)).await {
            // The task ended between the check and the request (a halt or the link).
            Err(DriverError::Disconnected) if self.halt.is_done() => Ok(()),
            r => r,
        }
    }
}

/// Wait on `rx` for a value whose stamp is after `after`.
async fn wait_newer<T: Clone>(
    rx: &watch::Receiver<Option<Stamped<T>>>,
    after: Option<Instant>,
) -> Result<Stamped<T>, DriverError> {
    let mut rx = rx.clone();
    tokio::time::timeout(WAIT_TIMEOUT, async move {
        loop {
            if let Some(s) = rx.borrow_and_update().as_ref()
                && after.is_none_or(|a| s.at > a)
            {
                return Ok(s.clone());
            }
            rx.changed().await.map_err(|_| DriverError::Disconnected)?;
        }
    })
    .await
    .map_err(|_| DriverError::Timeout)?
}

impl ErrorType for Rflex {
    type Error = DriverError;
}

impl DifferentialBase for Rflex {
    fn limits(&self) -> BaseLimits {
        self.limits
    }

    /// Release (`true`) or engage the brake; resolves when SYS_STATUS confirms it.
    async fn enable_motors(&mut self, enable: bool) -> Result<(), DriverError> {
        self.request(|tx| Request::Motors(enable, tx), Duration::from_secs(3))
            .await
    }

    async fn set_velocity(&mut self, cmd: VelocityCommand) -> Result<(), DriverError> {
        self.request(|tx| Request::Velocity(cmd, tx), REQUEST_TIMEOUT)
            .await
    }

    async fn stop(&mut self) -> Result<(), DriverError> {
        self.request(
            |tx| Request::Velocity(VelocityCommand::ZERO, tx),
            REQUEST_TIMEOUT,
        )
        .await
    }

    /// Zero both axes and engage the brake (see the [module docs](self)).
    async fn emergency_stop(&mut self) -> Result<(), DriverError> {
        self.request(Request::EStop, REQUEST_TIMEOUT).await
    }
}

impl Odometer for Rflex {
    async fn odometry(&mut self) -> Result<Stamped<Odometry>, DriverError> {
        wait_newer(&self.odometry, None).await
    }

    async fn next_odometry(&mut self, after: Instant) -> Result<Stamped<Odometry>, DriverError> {
        wait_newer(&self.odometry, Some(after)).await
    }

    async fn reset_odometry(&mut self) -> Result<(), DriverError> {
        self.request(Request::ResetOdometry, REQUEST_TIMEOUT).await
    }
}

impl SonarArray for Rflex {
    fn transducers(&self) -> &[SonarTransducer] {
        &self.transducers
    }

    async fn set_sonar_enabled(&mut self, on: bool) -> Result<(), DriverError> {
        self.request(|tx| Request::Sonar(on, tx), REQUEST_TIMEOUT)
            .await
    }

    async fn sonar(&mut self) -> Result<Stamped<SonarScan>, DriverError> {
        wait_newer(&self.sonar, None).await
    }
}

impl Bumpers for Rflex {
    /// The latest DIO bumper report; all clear until the base reports a change.
    async fn bumpers(&mut self) -> Result<Stamped<BumperState>, DriverError> {
        Ok(self
            .bumpers
            .borrow()
            .unwrap_or_else(|| Stamped::new(self.clock.now(), BumperState::default())))
    }
}

impl Power for Rflex {
    async fn power(&mut self) -> Result<Stamped<PowerState>, DriverError> {
        wait_newer(&self.power, None).await
    }
}

struct Task {
    halt: HaltSignal,
    machine: Machine,
    clock: SharedClock,
    rx: mpsc::Receiver<Request>,
    odo_tx: watch::Sender<Option<Stamped<Odometry>>>,
    sonar_tx: watch::Sender<Option<Stamped<SonarScan>>>,
    bump_tx: watch::Sender<Option<Stamped<BumperState>>>,
    power_tx: watch::Sender<Option<Stamped<PowerState>>>,
    brake_tx: watch::Sender<Option<Stamped<bool>>>,
    link_tx: watch::Sender<LinkStatus>,
    stats_tx: watch::Sender<ShellStats>,
    scan: SonarScan,
    motors_waiters: Vec<(bool, oneshot::Sender<Result<(), DriverError>>)>,
    sonar_wanted: bool,
    reinit_at: Option<Instant>,
    reconnects: u32,
    /// Bytes received (for the connect error: silence or garbage).
    bytes: u64,
}

impl Task {
    async fn run<S>(mut self, mut stream: S)
    where
        S: AsyncRead + AsyncWrite + Unpin + Send + 'static,
    {
        // Every way out of this task (return, cancellation, panic) marks the halt done.
        let _done = self.halt.done_on_drop();
        let mut rbuf = [0u8; 512];
        let mut tbuf = [0u8; TX_BUF];
        let mut closing: Option<oneshot::Sender<Result<(), DriverError>>> = None;
        let mut close_requested = false;
        loop {
            let now = self.clock.now();
            self.machine.handle_timeout(now);
            if let Some(t) = self.reinit_at
                && now >= t
            {
                tracing::debug!("rflex: re-sending the initialisation");
                self.machine.reinitialize(self.sonar_wanted, now);
                self.reinit_at = Some(now + self.machine.config().link_timeout);
            }
            while let Some(n) = self.machine.poll_transmit(&mut tbuf) {
                let Some(frame) = tbuf.get(..n) else { break };
                if let Err(e) = stream.write_all(frame).await {
                    self.fail(DriverError::Io(e.kind()));
                    return;
                }
            }
            let _ = stream.flush().await;
            self.drain_events();
            self.publish_stats();
            if close_requested && self.machine.phase() == crate::machine::Phase::Closed {
                self.halt.set_done();
                if let Some(tx) = closing.take() {
                    let _ = tx.send(Ok(()));
                }
                self.link_tx.send_replace(LinkStatus::Closed);
                return;
            }
            let mut wake = self.machine.poll_timeout();
            if let Some(r) = self.reinit_at {
                wake = Some(wake.map_or(r, |w| w.min(r)));
            }
            let sleep_for = wake.map_or(Duration::from_millis(500), |t| {
                t.saturating_duration_since(self.clock.now())
            });
            tokio::select! {
                biased;
                () = self.halt.requested(), if !close_requested => {
                    tracing::info!("rflex: halt requested; stopping the base and shutting down");
                    self.machine.shutdown(self.clock.now());
                    close_requested = true;
                }
                r = stream.read(&mut rbuf) => match r {
                    Ok(0) => { self.fail(DriverError::Disconnected); return; }
                    Ok(n) => {
                        let now = self.clock.now();
                        self.bytes = self.bytes.saturating_add(n as u64);
                        self.machine.handle_bytes(rbuf.get(..n).unwrap_or(&[]), now);
                    }
                    Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                    Err(e) => { self.fail(DriverError::Io(e.kind())); return; }
                },
                () = tokio::time::sleep(sleep_for) => {}
                req = self.rx.recv(), if !close_requested => match req {
                    // Every handle is gone: shut the base down politely.
                    None => {
                        self.machine.shutdown(self.clock.now());
                        close_requested = true;
                    }
                    Some(Request::Close(tx)) => {
                        self.machine.shutdown(self.clock.now());
                        close_requested = true;
                        closing = Some(tx);
                    }
                    Some(req) => self.handle_request(req),
                },
            }
        }
    }

    fn publish_stats(&mut self) {
        let s = ShellStats {
            session: *self.machine.stats(),
            framer: *self.machine.framer_stats(),
            reconnects: self.reconnects,
            bytes: self.bytes,
        };
        self.stats_tx.send_if_modified(|old| {
            let changed = *old != s;
            *old = s;
            changed
        });
    }

    fn fail(&mut self, e: DriverError) {
        for (_, w) in self.motors_waiters.drain(..) {
            let _ = w.send(Err(e));
        }
        self.link_tx.send_replace(LinkStatus::Failed(e));
    }

    fn handle_request(&mut self, req: Request) {
        let now = self.clock.now();
        match req {
            Request::Velocity(cmd, tx) => {
                let _ = tx.send(self.machine.set_velocity(cmd, now).map_err(Into::into));
            }
            Request::EStop(tx) => {
                let r = self
                    .machine
                    .stop(now)
                    .and_then(|()| self.machine.enable_motors(false, now));
                let _ = tx.send(r.map_err(Into::into));
            }
            Request::Sonar(on, tx) => {
                self.sonar_wanted = on;
                let _ = tx.send(self.machine.set_sonar(on, now).map_err(Into::into));
            }
            Request::ResetOdometry(tx) => {
                self.machine.reset_odometry();
                let odo = self.machine.odometry();
                self.odo_tx.send_replace(Some(Stamped::new(now, odo)));
                let _ = tx.send(Ok(()));
            }
            Request::Motors(on, tx) => match self.machine.enable_motors(on, now) {
                Ok(()) => self.motors_waiters.push((on, tx)),
                Err(e) => {
                    let _ = tx.send(Err(e.into()));
                }
            },
            Request::Close(_) => {}
        }
    }

    fn drain_events(&mut self) {
        while let Some(ev) = self.machine.poll_event() {
            match ev {
                Event::Initialized => tracing::debug!("rflex: initialisation sent"),
                // A frame alone (an ack, a status reply) does not prove the base is
                // streaming again (a power-cycled controller has reports off, and may have
                // come back after our last re-initialisation): keep re-initialising until
                // motion reports arrive.
                Event::LinkUp => {}
                Event::LinkLost => {
                    tracing::warn!("rflex: no report from the base; re-initialising");
                    self.reconnects = self.reconnects.wrapping_add(1);
                    self.reinit_at = Some(self.clock.now());
                    self.link_tx.send_replace(LinkStatus::Lost);
                }
                Event::Odometry(o) => {
                    self.odo_tx.send_replace(Some(o));
                    self.reinit_at = None;
                    if *self.link_tx.borrow() != LinkStatus::Connected {
                        self.link_tx.send_replace(LinkStatus::Connected);
                    }
                }
                Event::OdometryRejected {
                    delta_m, delta_rad, ..
                } => {
                    tracing::warn!(delta_m, delta_rad, "rflex: implausible odometry dropped");
                }
                Event::Power(p) => {
                    self.power_tx.send_replace(Some(p));
                }
                Event::Brake(b) => {
                    self.brake_tx.send_replace(Some(b));
                    let released = !b.value;
                    let (done, keep): (Vec<_>, Vec<_>) = self
                        .motors_waiters
                        .drain(..)
                        .partition(|(w, _)| *w == released);
                    self.motors_waiters = keep;
                    for (_, tx) in done {
                        let _ = tx.send(Ok(()));
                    }
                }
                Event::Sonar(r) => {
                    self.scan.upsert(r);
                    self.sonar_tx
                        .send_replace(Some(Stamped::new(r.at, self.scan.clone())));
                }
                Event::UnmappedSonar { id, range_m, .. } => {
                    tracing::debug!(id, range_m, "rflex: sonar id not in the table");
                }
                Event::Bumpers(b) => {
                    self.bump_tx.send_replace(Some(b));
                }
                Event::Dio { address, data, .. } => {
                    tracing::debug!(address, data, "rflex: DIO report");
                }
                Event::Joystick { .. } | Event::Unknown(_) => {}
                Event::CommandTimeout => {
                    tracing::warn!("rflex: no velocity command for 0.5 s; robot stopped");
                }
                Event::ShutdownComplete => {}
            }
        }
    }
}

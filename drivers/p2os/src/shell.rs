//! The async I/O shell (feature `tokio`): one task owns the byte stream and the [`Session`];
//! cloneable [`P2os`] handles talk to it and implement the `ima-hal` traits.
//!
//! The shell is generic over any `AsyncRead + AsyncWrite` stream that can change its line
//! speed ([`BaudControl`]): a `tokio_serial::SerialStream` on a real port or a pty, or an
//! in-memory duplex wrapped in [`FixedBaud`] for tests. It reads with a timeout-free
//! `select!` over the stream, the session's next timer and the handles' requests, so a robot
//! that goes quiet never blocks it (spec §10 item 9).

use std::io;
use std::sync::Arc;
use std::time::Duration;

use ima_hal::base::{
    BaseLimits, BumperState, Bumpers, DifferentialBase, Odometer, Odometry, VelocityCommand,
};
use ima_hal::link::ProbeReport;
use ima_hal::power::{Power, PowerState};
use ima_hal::safety::{HaltSignal, StopRegistry};
use ima_hal::sonar::{SonarArray, SonarScan, SonarTransducer};
use ima_hal::{ErrorType, Instant, Stamped};
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::sync::{mpsc, oneshot, watch};

pub use crate::driver::{BaudControl, DriverError, FixedBaud};
use crate::machine::{
    Config, DisconnectReason, Event, RobotConfig, RobotIdentity, RobotState, Session, SessionError,
    SessionStats,
};
use crate::params::RobotParams;

/// Open a serial port for the shell: 8N1, no flow control, at `baud` (probing changes it).
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
#[derive(Debug, Clone, PartialEq)]
pub enum LinkStatus {
    /// Handshaking (first time or after a loss).
    Connecting,
    /// SIPs are streaming.
    Connected {
        /// Who answered.
        identity: RobotIdentity,
        /// The line speed in use.
        baud: u32,
    },
    /// Lost; the session is reconnecting.
    Lost,
    /// Failed for good.
    Failed(DriverError),
    /// The task ended.
    Closed,
}

enum Request {
    Velocity(VelocityCommand, oneshot::Sender<Result<(), DriverError>>),
    Stop(oneshot::Sender<Result<(), DriverError>>),
    EStop(oneshot::Sender<Result<(), DriverError>>),
    Motors(bool, oneshot::Sender<Result<(), DriverError>>),
    Sonar(bool, oneshot::Sender<Result<(), DriverError>>),
    ResetOdometry(oneshot::Sender<Result<(), DriverError>>),
    Close(oneshot::Sender<Result<(), DriverError>>),
}

/// A handle to a running P2OS driver. Cheap to clone; every clone talks to the same task.
#[derive(Debug, Clone)]
pub struct P2os {
    tx: mpsc::Sender<Request>,
    state: watch::Receiver<Option<RobotState>>,
    link: watch::Receiver<LinkStatus>,
    stats: watch::Receiver<SessionStats>,
    config: watch::Receiver<Option<RobotConfig>>,
    params: RobotParams,
    transducers: Arc<[SonarTransducer]>,
    clock: SharedClock,
    halt: HaltSignal,
}

impl std::fmt::Debug for Request {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Request")
    }
}

/// How long [`P2os::connect`] waits for the handshake by default.
pub const DEFAULT_CONNECT_TIMEOUT: Duration = Duration::from_secs(10);

/// The longest a closing task keeps writing its last frames (STOP, CLOSE) before it gives up.
const CLOSE_DRAIN_LIMIT: Duration = Duration::from_secs(1);

impl P2os {
    /// Spawn the driver task on `stream` and wait until the robot is connected (or
    /// `connect_timeout` passes). Must be called inside a tokio runtime.
    ///
    /// The task registers its [`HaltSignal`] in [`StopRegistry::global`] at once, so a
    /// program's exit guard can stop this robot (STOP, then CLOSE) from any exit path.
    ///
    /// `clock` is the process's one time base: every reading's stamp is taken on it.
    pub async fn connect<S>(
        stream: S,
        cfg: Config,
        connect_timeout: Duration,
        clock: SharedClock,
    ) -> Result<P2os, DriverError>
    where
        S: AsyncRead + AsyncWrite + BaudControl + Unpin + Send + 'static,
    {
        let (tx, rx) = mpsc::channel(32);
        let (state_tx, state) = watch::channel(None);
        let (link_tx, mut link) = watch::channel(LinkStatus::Connecting);
        let (stats_tx, stats) = watch::channel(SessionStats::default());
        let (config_tx, config) = watch::channel(None);
        let (params_tx, params_rx) = oneshot::channel();
        let halt = HaltSignal::new();
        StopRegistry::global().register("P2OS base", halt.clone());
        let (probe_tx, probe) = watch::channel(ProbeReport::new());
        let task = Task {
            session: Session::new(cfg),
            clock: clock.clone(),
            halt: halt.clone(),
            close_waiters: Vec::new(),
            rx,
            state_tx,
            link_tx,
            stats_tx,
            config_tx,
            params_tx: Some(params_tx),
            motors_waiters: Vec::new(),
            probe: ProbeReport::new(),
            probe_tx,
            connected: false,
        };
        tokio::spawn(task.run(stream));
        let waited = tokio::time::timeout(connect_timeout, async {
            loop {
                match &*link.borrow_and_update() {
                    LinkStatus::Connected { .. } => return Ok(()),
                    LinkStatus::Failed(e) => return Err(e.clone()),
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
                // Say what each rate tried received.
                return Err(DriverError::NoAnswer(Box::new(probe.borrow().clone())));
            }
        }
        let params = params_rx.await.map_err(|_| DriverError::Disconnected)?;
        let transducers: Arc<[SonarTransducer]> = crate::driver::transducers(&params).into();
        Ok(P2os {
            tx,
            state,
            link,
            stats,
            config,
            params,
            transducers,
            clock,
            halt,
        })
    }

    /// This driver's halt signal: [`HaltSignal::halt`] stops the robot and closes the session
    /// from any thread without awaiting (the same as [`close`](Self::close), fire-and-forget).
    #[must_use]
    pub fn halt_signal(&self) -> HaltSignal {
        self.halt.clone()
    }

    /// The parameter table in use.
    #[must_use]
    pub fn params(&self) -> &RobotParams {
        &self.params
    }

    /// Current link status.
    #[must_use]
    pub fn link(&self) -> LinkStatus {
        self.link.borrow().clone()
    }

    /// Session counters (frames, drops, bad checksums, implausible SIPs, reconnects…).
    #[must_use]
    pub fn stats(&self) -> SessionStats {
        *self.stats.borrow()
    }

    /// The robot's CONFIG packet, once received.
    #[must_use]
    pub fn robot_config(&self) -> Option<RobotConfig> {
        self.config.borrow().clone()
    }

    /// The latest SIP state, if any.
    #[must_use]
    pub fn latest(&self) -> Option<RobotState> {
        self.state.borrow().clone()
    }

    /// Wait for a SIP state newer than `after` (at most `timeout`).
    pub async fn next_state(
        &mut self,
        after: Instant,
        timeout: Duration,
    ) -> Result<RobotState, DriverError> {
        let mut rx = self.state.clone();
        tokio::time::timeout(timeout, async move {
            loop {
                if let Some(s) = rx.borrow_and_update().as_ref()
                    && s.odometry.at > after
                {
                    return Ok(s.clone());
                }
                rx.changed().await.map_err(|_| DriverError::Disconnected)?;
            }
        })
        .await
        .map_err(|_| DriverError::Timeout)?
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

    /// Stop the robot, close the session and end the driver task. Returns once the last
    /// frames (STOP, then CLOSE) are written to the port, or with an error if they could not
    /// be. Dropping every handle does the same in the background.
    pub async fn close(&self) -> Result<(), DriverError> {
        if self.halt.is_done() {
            return Ok(());
        }
        match self
            .request(Request::Close, CLOSE_DRAIN_LIMIT + Duration::from_secs(1))
            .await
        {
            // The task ended between the check and the request (a halt or the link).
            Err(DriverError::Disconnected) if self.halt.is_done() => Ok(()),
            r => r,
        }
    }

    async fn wait_state(&mut self) -> Result<RobotState, DriverError> {
        if let Some(s) = self.latest() {
            return Ok(s);
        }
        self.next_state(Instant::ZERO, Duration::from_secs(2)).await
    }
}

const REQUEST_TIMEOUT: Duration = Duration::from_secs(1);

impl ErrorType for P2os {
    type Error = DriverError;
}

impl DifferentialBase for P2os {
    fn limits(&self) -> BaseLimits {
        BaseLimits {
            max_v_m_s: self.params.max_velocity_mm_s / 1000.0,
            max_omega_rad_s: self.params.max_rot_velocity_deg_s.to_radians(),
        }
    }

    async fn enable_motors(&mut self, enable: bool) -> Result<(), DriverError> {
        // ENABLE is retried by the session; allow for every attempt.
        self.request(|tx| Request::Motors(enable, tx), Duration::from_secs(3))
            .await
    }

    async fn set_velocity(&mut self, cmd: VelocityCommand) -> Result<(), DriverError> {
        self.request(|tx| Request::Velocity(cmd, tx), REQUEST_TIMEOUT)
            .await
    }

    async fn stop(&mut self) -> Result<(), DriverError> {
        self.request(Request::Stop, REQUEST_TIMEOUT).await
    }

    async fn emergency_stop(&mut self) -> Result<(), DriverError> {
        self.request(Request::EStop, REQUEST_TIMEOUT).await
    }
}

impl Odometer for P2os {
    async fn odometry(&mut self) -> Result<Stamped<Odometry>, DriverError> {
        Ok(self.wait_state().await?.odometry)
    }

    async fn next_odometry(&mut self, after: Instant) -> Result<Stamped<Odometry>, DriverError> {
        Ok(self
            .next_state(after, Duration::from_secs(2))
            .await?
            .odometry)
    }

    async fn reset_odometry(&mut self) -> Result<(), DriverError> {
        self.request(Request::ResetOdometry, REQUEST_TIMEOUT).await
    }
}

impl SonarArray for P2os {
    fn transducers(&self) -> &[SonarTransducer] {
        &self.transducers
    }

    async fn set_sonar_enabled(&mut self, on: bool) -> Result<(), DriverError> {
        self.request(|tx| Request::Sonar(on, tx), REQUEST_TIMEOUT)
            .await
    }

    async fn sonar(&mut self) -> Result<Stamped<SonarScan>, DriverError> {
        Ok(self.wait_state().await?.sonar)
    }
}

impl Bumpers for P2os {
    async fn bumpers(&mut self) -> Result<Stamped<BumperState>, DriverError> {
        Ok(self.wait_state().await?.bumpers)
    }
}

impl Power for P2os {
    async fn power(&mut self) -> Result<Stamped<PowerState>, DriverError> {
        Ok(self.wait_state().await?.power)
    }
}

struct Task {
    session: Session,
    clock: SharedClock,
    halt: HaltSignal,
    close_waiters: Vec<oneshot::Sender<Result<(), DriverError>>>,
    rx: mpsc::Receiver<Request>,
    state_tx: watch::Sender<Option<RobotState>>,
    link_tx: watch::Sender<LinkStatus>,
    stats_tx: watch::Sender<SessionStats>,
    config_tx: watch::Sender<Option<RobotConfig>>,
    params_tx: Option<oneshot::Sender<RobotParams>>,
    motors_waiters: Vec<(bool, oneshot::Sender<Result<(), DriverError>>)>,
    /// What the first connection saw per rate (counted until the first `Connected`).
    probe: ProbeReport,
    probe_tx: watch::Sender<ProbeReport>,
    /// The session was connected once (the probe report is final).
    connected: bool,
}

/// Answer a request that arrived after the session closed.
fn reject(req: Request) {
    match req {
        Request::Velocity(_, tx)
        | Request::Stop(tx)
        | Request::EStop(tx)
        | Request::Motors(_, tx)
        | Request::Sonar(_, tx)
        | Request::ResetOdometry(tx)
        | Request::Close(tx) => {
            let _ = tx.send(Err(DriverError::Disconnected));
        }
    }
}

impl Task {
    async fn run<S>(mut self, mut stream: S)
    where
        S: AsyncRead + AsyncWrite + BaudControl + Unpin + Send + 'static,
    {
        // Every way out of this task (return, cancellation, panic) marks the halt done.
        let _done = self.halt.done_on_drop();
        let mut rbuf = [0u8; 512];
        let mut tbuf = [0u8; crate::wire::MAX_FRAME_LEN];
        self.session.connect(self.clock.now());
        // Set when the task is closing: the instant after which it gives up draining.
        let mut closing: Option<Instant> = None;
        loop {
            // Events first: they may ask for a baud change before the next write.
            if let Err(e) = self.drain_events(&mut stream) {
                self.fail(DriverError::Io(e.kind()));
                return;
            }
            let now = self.clock.now();
            while let Some(n) = self.session.poll_transmit(now, &mut tbuf) {
                let Some(frame) = tbuf.get(..n) else { break };
                if let Err(e) = stream.write_all(frame).await {
                    self.fail(DriverError::Io(e.kind()));
                    return;
                }
            }
            let _ = stream.flush().await;
            self.stats_tx.send_replace(self.session.stats());
            if let Some(limit) = closing {
                // Frames are paced, so STOP and CLOSE may need more than one pass.
                let drained = !self.session.has_pending_transmit();
                if drained || self.clock.now() >= limit {
                    self.finish_close(drained);
                    return;
                }
            }
            let sleep_for = self
                .session
                .poll_timeout()
                .map_or(Duration::from_millis(500), |t| {
                    t.saturating_duration_since(self.clock.now())
                });
            tokio::select! {
                biased;
                () = self.halt.requested(), if closing.is_none() => {
                    tracing::info!("p2os: halt requested; stopping the robot and closing");
                    closing = Some(self.begin_close());
                }
                r = stream.read(&mut rbuf) => match r {
                    Ok(0) => { self.fail(DriverError::Disconnected); return; }
                    Ok(n) => {
                        let now = self.clock.now();
                        self.input(rbuf.get(..n).unwrap_or(&[]), now);
                    }
                    Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                    Err(e) => { self.fail(DriverError::Io(e.kind())); return; }
                },
                () = tokio::time::sleep(sleep_for) => {
                    self.session.handle_timeout(self.clock.now());
                }
                req = self.rx.recv(), if closing.is_none() => match req {
                    None => closing = Some(self.begin_close()),
                    Some(Request::Close(tx)) => {
                        self.close_waiters.push(tx);
                        closing = Some(self.begin_close());
                    }
                    Some(req) => self.handle_request(req),
                },
            }
        }
    }

    /// Queue STOP and CLOSE; returns the instant after which draining gives up.
    fn begin_close(&mut self) -> Instant {
        self.session.close();
        self.clock.now() + CLOSE_DRAIN_LIMIT
    }

    /// The last frames are written (or could not be within the limit): answer the waiters.
    fn finish_close(&mut self, drained: bool) {
        // Nothing more will be written: a waiting exit guard may go on.
        self.halt.set_done();
        let r = if drained {
            Ok(())
        } else {
            tracing::warn!("p2os: the last frames (STOP, CLOSE) could not all be written");
            Err(DriverError::Timeout)
        };
        for tx in self.close_waiters.drain(..) {
            let _ = tx.send(r.clone());
        }
        // Requests that raced with the close get a clear answer rather than a dropped channel.
        self.rx.close();
        while let Ok(req) = self.rx.try_recv() {
            reject(req);
        }
        self.link_tx.send_replace(LinkStatus::Closed);
    }

    /// Feed received bytes to the session, counting them (and the frames they made) per rate
    /// until the first connection.
    fn input(&mut self, bytes: &[u8], now: Instant) {
        let before = self.session.stats().framer;
        self.session.handle_input(bytes, now);
        if !self.connected {
            let after = self.session.stats().framer;
            let bad = |f: crate::framer::FramerStats| f.bad_checksums + f.bad_counts + f.abandoned;
            self.probe.received(bytes.len());
            self.probe.framed(
                after.frames.saturating_sub(before.frames),
                bad(after).saturating_sub(bad(before)),
            );
            self.probe_tx.send_replace(self.probe.clone());
        }
    }

    fn fail(&mut self, e: DriverError) {
        for (_, w) in self.motors_waiters.drain(..) {
            let _ = w.send(Err(e.clone()));
        }
        self.link_tx.send_replace(LinkStatus::Failed(e));
    }

    fn handle_request(&mut self, req: Request) {
        let now = self.clock.now();
        let map = |r: Result<(), SessionError>| r.map_err(DriverError::Session);
        match req {
            Request::Velocity(cmd, tx) => {
                let _ = tx.send(map(self.session.set_velocity(cmd, now)));
            }
            Request::Stop(tx) => {
                let _ = tx.send(map(self.session.stop()));
            }
            Request::EStop(tx) => {
                let _ = tx.send(map(self.session.emergency_stop()));
            }
            Request::Sonar(on, tx) => {
                let _ = tx.send(map(self.session.set_sonar(on)));
            }
            Request::ResetOdometry(tx) => {
                self.session.reset_odometry();
                let _ = tx.send(Ok(()));
            }
            Request::Motors(on, tx) => match self.session.enable_motors(on, now) {
                Ok(()) => self.motors_waiters.push((on, tx)),
                Err(e) => {
                    let _ = tx.send(Err(DriverError::Session(e)));
                }
            },
            Request::Close(tx) => {
                // Handled by the run loop (it drains before answering); not reached.
                let _ = tx.send(Err(DriverError::Disconnected));
            }
        }
    }

    fn drain_events<S: BaudControl>(&mut self, stream: &mut S) -> io::Result<()> {
        while let Some(ev) = self.session.poll_event() {
            match ev {
                Event::SetBaud(b) => {
                    tracing::debug!(baud = b, "p2os: line speed");
                    stream.set_baud(b)?;
                    if !self.connected {
                        self.probe.attempt(b);
                        let n = self.probe.current_tally().map_or(1, |t| t.attempts);
                        tracing::info!(target: "ima::connect", "P2OS: trying {b} baud (attempt {n})");
                        self.probe_tx.send_replace(self.probe.clone());
                    }
                }
                Event::FlushInput => {}
                Event::Connected {
                    identity,
                    params,
                    baud,
                } => {
                    tracing::info!(name = %identity.name, subclass = %identity.subclass, baud, "p2os: connected");
                    self.connected = true;
                    if let Some(tx) = self.params_tx.take() {
                        let _ = tx.send(params);
                    }
                    self.link_tx
                        .send_replace(LinkStatus::Connected { identity, baud });
                }
                Event::UnsupportedRobot(id) => {
                    self.fail(DriverError::UnsupportedRobot(id.subclass.as_str().into()));
                }
                Event::HandshakeFailed => {
                    let e = if self.connected {
                        DriverError::HandshakeFailed
                    } else {
                        DriverError::NoAnswer(Box::new(self.probe.clone()))
                    };
                    self.fail(e);
                }
                Event::Disconnected(DisconnectReason::LinkLost) => {
                    tracing::warn!("p2os: link lost, reconnecting");
                    self.link_tx.send_replace(LinkStatus::Lost);
                }
                Event::Disconnected(DisconnectReason::Closed) => {}
                Event::State(s) => {
                    self.state_tx.send_replace(Some(s));
                }
                Event::MotorsEnabled(on) => {
                    let (done, keep): (Vec<_>, Vec<_>) =
                        self.motors_waiters.drain(..).partition(|(w, _)| *w == on);
                    self.motors_waiters = keep;
                    for (_, tx) in done {
                        let _ = tx.send(Ok(()));
                    }
                }
                Event::MotorsRefused => {
                    for (_, tx) in self.motors_waiters.drain(..) {
                        let _ = tx.send(Err(DriverError::MotorsRefused));
                    }
                }
                Event::CommandTimeout => {
                    tracing::warn!(
                        "p2os: no velocity command for the command timeout; robot stopped"
                    );
                }
                Event::Config(c) => {
                    self.config_tx.send_replace(Some(c));
                }
                Event::Encoder { .. } => {}
            }
        }
        Ok(())
    }
}

//! The async I/O shell (feature `tokio`): the [`ima_serial::runner`] owns the byte stream and
//! the [`Machine`]; cloneable [`P2os`] handles talk to it and implement the `ima-hal` traits.
//! This module is only "machine events → HAL readings" ([`P2osShell`]), shared with the
//! [blocking shell](crate::blocking).

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
use ima_serial::runner::{self, End, Flow, Shell};
use tokio::io::{AsyncRead, AsyncWrite};
use tokio::sync::{mpsc, oneshot, watch};

pub use crate::driver::{BaudControl, DriverError, FixedBaud};
use crate::machine::{
    Config, DisconnectReason, Event, Machine, RobotConfig, RobotIdentity, RobotState, SessionError,
    SessionStats,
};
use crate::params::RobotParams;
/// The clock types a shell takes: the caller passes the process's one [`SharedClock`]
/// (usually a [`TokioClock`], so paused tests run in virtual time) to `connect`, and every
/// stamp the driver produces is on that time line.
pub use ima_hal::time::{Clock, SharedClock, TokioClock};
/// Open a serial port for the shell: 8N1, no flow control, at `baud` (probing changes it).
pub use ima_serial::open_port;

/// Who answered the handshake, at what rate, with which parameter table.
#[derive(Debug, Clone, PartialEq)]
pub struct Connection {
    /// Who answered.
    pub identity: RobotIdentity,
    /// The line speed in use.
    pub baud: u32,
    /// The parameter table in use.
    pub params: RobotParams,
}

/// Link status as seen by handles.
pub type LinkStatus = ima_serial::LinkStatus<Connection, DriverError>;

pub(crate) type Reply = oneshot::Sender<Result<(), DriverError>>;

/// A request from a handle to the driver task.
#[derive(Debug)]
pub enum Request {
    /// Drive.
    Velocity(VelocityCommand, Reply),
    /// Stop.
    Stop(Reply),
    /// Emergency stop.
    EStop(Reply),
    /// Enable or disable the motors (answered when FLAGS confirms).
    Motors(bool, Reply),
    /// Sonar on or off.
    Sonar(bool, Reply),
    /// Zero the odometry.
    ResetOdometry(Reply),
    /// Stop, close the session and end the task.
    Close(Reply),
}

/// The receiving ends of what [`P2osShell`] publishes.
#[derive(Debug, Clone)]
pub(crate) struct Watches {
    pub(crate) state: watch::Receiver<Option<RobotState>>,
    pub(crate) link: watch::Receiver<LinkStatus>,
    pub(crate) stats: watch::Receiver<SessionStats>,
    pub(crate) config: watch::Receiver<Option<RobotConfig>>,
    pub(crate) probe: watch::Receiver<ProbeReport>,
}

/// Machine events → readings and answers, for both shells.
#[derive(Debug)]
pub struct P2osShell {
    machine: Machine,
    state_tx: watch::Sender<Option<RobotState>>,
    link_tx: watch::Sender<LinkStatus>,
    stats_tx: watch::Sender<SessionStats>,
    config_tx: watch::Sender<Option<RobotConfig>>,
    probe_tx: watch::Sender<ProbeReport>,
    probe: ProbeReport,
    motors_waiters: Vec<(bool, Reply)>,
    close_waiters: Vec<Reply>,
    /// The session was connected once (the probe report is final).
    connected: bool,
}

/// The longest a closing task keeps writing its last frames (STOP, CLOSE) before it gives up.
const CLOSE_DRAIN_LIMIT: Duration = Duration::from_secs(1);

impl P2osShell {
    pub(crate) fn new(cfg: Config) -> (Self, Watches) {
        let (state_tx, state) = watch::channel(None);
        let (link_tx, link) = watch::channel(LinkStatus::Connecting);
        let (stats_tx, stats) = watch::channel(SessionStats::default());
        let (config_tx, config) = watch::channel(None);
        let (probe_tx, probe) = watch::channel(ProbeReport::new());
        let shell = Self {
            machine: Machine::new(cfg),
            state_tx,
            link_tx,
            stats_tx,
            config_tx,
            probe_tx,
            probe: ProbeReport::new(),
            motors_waiters: Vec::new(),
            close_waiters: Vec::new(),
            connected: false,
        };
        let w = Watches {
            state,
            link,
            stats,
            config,
            probe,
        };
        (shell, w)
    }

    fn fail(&mut self, e: DriverError) {
        for (_, w) in self.motors_waiters.drain(..) {
            let _ = w.send(Err(e.clone()));
        }
        self.link_tx.send_replace(LinkStatus::Failed(e));
    }
}

impl Shell for P2osShell {
    type Machine = Machine;
    type Request = Request;
    const MAX_FRAME: usize = crate::wire::MAX_FRAME_LEN;

    fn machine(&mut self) -> &mut Machine {
        &mut self.machine
    }

    fn start(&mut self, now: Instant) {
        self.machine.connect(now);
    }

    /// Counts the bytes (and the frames they made) per rate until the first connection.
    fn on_bytes(&mut self, bytes: &[u8], now: Instant) {
        let before = self.machine.stats().framer;
        self.machine.handle_bytes(bytes, now);
        if !self.connected {
            let after = self.machine.stats().framer;
            let bad = |f: crate::framer::FramerStats| f.bad_checksums + f.bad_counts + f.abandoned;
            self.probe.received(bytes.len());
            self.probe.framed(
                after.frames.saturating_sub(before.frames),
                bad(after).saturating_sub(bad(before)),
            );
            self.probe_tx.send_replace(self.probe.clone());
        }
    }

    fn on_event(&mut self, ev: Event, line: &mut dyn BaudControl) -> std::io::Result<()> {
        match ev {
            Event::SetBaud(b) => {
                tracing::debug!(baud = b, "p2os: line speed");
                line.set_baud(b)?;
                if !self.connected {
                    self.probe.attempt(b);
                    let n = self.probe.current_tally().map_or(1, |t| t.attempts);
                    tracing::info!(target: "ima::connect", "P2OS: trying {b} baud (attempt {n})");
                    self.probe_tx.send_replace(self.probe.clone());
                }
            }
            Event::Connected {
                identity,
                params,
                baud,
            } => {
                tracing::info!(name = %identity.name, subclass = %identity.subclass, baud, "p2os: connected");
                self.connected = true;
                let c = Connection {
                    identity,
                    baud,
                    params,
                };
                self.link_tx.send_replace(LinkStatus::Connected(c));
            }
            Event::UnsupportedRobot(id) => {
                self.fail(DriverError::UnsupportedRobot(id.subclass.as_str().into()));
            }
            Event::HandshakeFailed if self.connected => self.fail(DriverError::HandshakeFailed),
            Event::HandshakeFailed => {
                self.fail(DriverError::NoAnswer(Box::new(self.probe.clone())));
            }
            Event::Disconnected(DisconnectReason::LinkLost) => {
                tracing::warn!("p2os: link lost, reconnecting");
                self.link_tx.send_replace(LinkStatus::Lost);
            }
            Event::State(s) => {
                self.state_tx.send_replace(Some(s));
            }
            Event::MotorsEnabled(on) => {
                let (done, keep) = self.motors_waiters.drain(..).partition(|(w, _)| *w == on);
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
                tracing::warn!("p2os: no velocity command for the command timeout; robot stopped");
            }
            Event::Config(c) => {
                self.config_tx.send_replace(Some(c));
            }
            Event::FlushInput | Event::Disconnected(_) | Event::Encoder { .. } => {}
        }
        Ok(())
    }

    fn on_request(&mut self, req: Request, now: Instant) -> Flow {
        let m = &mut self.machine;
        let (r, tx) = match req {
            Request::Velocity(cmd, tx) => (m.set_velocity(cmd, now), tx),
            Request::Stop(tx) => (m.stop(), tx),
            Request::EStop(tx) => (m.emergency_stop(), tx),
            Request::Sonar(on, tx) => (m.set_sonar(on), tx),
            Request::ResetOdometry(tx) => {
                m.reset_odometry();
                (Ok(()), tx)
            }
            Request::Motors(on, tx) => match m.enable_motors(on, now) {
                Ok(()) => {
                    self.motors_waiters.push((on, tx));
                    return Flow::Continue;
                }
                Err(e) => (Err(e), tx),
            },
            Request::Close(tx) => {
                self.close_waiters.push(tx);
                return Flow::Close;
            }
        };
        let _ = tx.send(r.map_err(|e: SessionError| DriverError::Session(e)));
        Flow::Continue
    }

    fn after_round(&mut self) {
        self.stats_tx.send_replace(self.machine.stats());
    }

    /// Queue STOP and CLOSE (frames are paced, so they may need more than one round).
    fn begin_close(&mut self, _now: Instant) -> Duration {
        self.machine.close();
        CLOSE_DRAIN_LIMIT
    }

    fn is_closed(&mut self) -> bool {
        !self.machine.has_pending_transmit()
    }

    fn end(&mut self, how: End) {
        let r = match how {
            End::Closed { drained: true } => Ok(()),
            End::Closed { drained: false } => {
                tracing::warn!("p2os: the last frames (STOP, CLOSE) could not all be written");
                Err(DriverError::Timeout)
            }
            End::Failed(e) => Err(e.into()),
        };
        for tx in self.close_waiters.drain(..) {
            let _ = tx.send(r.clone());
        }
        match r {
            Err(e) if matches!(how, End::Failed(_)) => self.fail(e),
            _ => {
                self.link_tx.send_replace(LinkStatus::Closed);
            }
        }
    }
}

/// A handle to a running P2OS driver. Cheap to clone; every clone talks to the same task.
#[derive(Debug, Clone)]
pub struct P2os {
    tx: mpsc::Sender<Request>,
    w: Watches,
    params: RobotParams,
    transducers: Arc<[SonarTransducer]>,
    clock: SharedClock,
    halt: HaltSignal,
}

/// How long [`P2os::connect`] waits for the handshake by default.
pub const DEFAULT_CONNECT_TIMEOUT: Duration = Duration::from_secs(10);

const REQUEST_TIMEOUT: Duration = Duration::from_secs(1);

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
        let (shell, mut w) = P2osShell::new(cfg);
        let halt = HaltSignal::new();
        StopRegistry::global().register("P2OS base", halt.clone());
        let tx = runner::spawn(shell, stream, clock.clone(), Some(halt.clone()));
        let c = match runner::wait_connected(&mut w.link, connect_timeout).await {
            Ok(c) => c,
            Err(Some(e)) => return Err(e),
            Err(None) => {
                let _ = tx.try_send(Request::Close(oneshot::channel().0));
                // Say what each rate tried received.
                return Err(DriverError::NoAnswer(Box::new(w.probe.borrow().clone())));
            }
        };
        Ok(P2os {
            tx,
            w,
            transducers: crate::driver::transducers(&c.params).into(),
            params: c.params,
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
        self.w.link.borrow().clone()
    }

    /// Session counters (frames, drops, bad checksums, implausible SIPs, reconnects…).
    #[must_use]
    pub fn stats(&self) -> SessionStats {
        *self.w.stats.borrow()
    }

    /// The robot's CONFIG packet, once received.
    #[must_use]
    pub fn robot_config(&self) -> Option<RobotConfig> {
        self.w.config.borrow().clone()
    }

    /// The latest SIP state, if any.
    #[must_use]
    pub fn latest(&self) -> Option<RobotState> {
        self.w.state.borrow().clone()
    }

    /// Wait for a SIP state newer than `after` (at most `timeout`).
    pub async fn next_state(
        &mut self,
        after: Instant,
        timeout: Duration,
    ) -> Result<RobotState, DriverError> {
        let newer = |s: &Option<RobotState>| s.as_ref().filter(|s| s.odometry.at > after).cloned();
        Ok(runner::wait_for(&self.w.state, timeout, newer).await?)
    }

    /// The driver's clock (the time base of every stamp it produces).
    #[must_use]
    pub fn now(&self) -> Instant {
        self.clock.now()
    }

    async fn request(&self, make: impl FnOnce(Reply) -> Request) -> Result<(), DriverError> {
        runner::request(&self.tx, make, REQUEST_TIMEOUT).await
    }

    /// Stop the robot, close the session and end the driver task. Returns once the last
    /// frames (STOP, then CLOSE) are written to the port, or with an error if they could not
    /// be. Dropping every handle does the same in the background.
    pub async fn close(&self) -> Result<(), DriverError> {
        if self.halt.is_done() {
            return Ok(());
        }
        let limit = CLOSE_DRAIN_LIMIT + Duration::from_secs(1);
        match runner::request(&self.tx, Request::Close, limit).await {
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

impl ErrorType for P2os {
    type Error = DriverError;
}

impl DifferentialBase for P2os {
    fn limits(&self) -> BaseLimits {
        crate::driver::limits(&self.params)
    }

    async fn enable_motors(&mut self, enable: bool) -> Result<(), DriverError> {
        // ENABLE is retried by the session; allow for every attempt.
        let make = |tx| Request::Motors(enable, tx);
        runner::request(&self.tx, make, Duration::from_secs(3)).await
    }

    async fn set_velocity(&mut self, cmd: VelocityCommand) -> Result<(), DriverError> {
        self.request(|tx| Request::Velocity(cmd, tx)).await
    }

    async fn stop(&mut self) -> Result<(), DriverError> {
        self.request(Request::Stop).await
    }

    async fn emergency_stop(&mut self) -> Result<(), DriverError> {
        self.request(Request::EStop).await
    }
}

impl Odometer for P2os {
    async fn odometry(&mut self) -> Result<Stamped<Odometry>, DriverError> {
        Ok(self.wait_state().await?.odometry)
    }

    async fn next_odometry(&mut self, after: Instant) -> Result<Stamped<Odometry>, DriverError> {
        let s = self.next_state(after, Duration::from_secs(2)).await?;
        Ok(s.odometry)
    }

    async fn reset_odometry(&mut self) -> Result<(), DriverError> {
        self.request(Request::ResetOdometry).await
    }
}

impl SonarArray for P2os {
    fn transducers(&self) -> &[SonarTransducer] {
        &self.transducers
    }

    async fn set_sonar_enabled(&mut self, on: bool) -> Result<(), DriverError> {
        self.request(|tx| Request::Sonar(on, tx)).await
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

//! The async I/O shell (feature `tokio`): the [`ima_serial::runner`] owns the byte stream and
//! the [`Machine`]; cloneable [`Rflex`] handles talk to it and implement the `ima-hal` traits
//! ([`DifferentialBase`], [`Odometer`], [`SonarArray`], [`Bumpers`], [`Power`]). This module
//! is only "machine events → HAL readings" ([`RflexShell`]), shared with the
//! [blocking shell](crate::blocking).
//!
//! * **Recovery**: when the machine reports [`Event::LinkLost`] the shell re-sends the §6
//!   initialisation ([`Machine::reinitialize`]) every [`Config::link_timeout`] until the base
//!   streams motion reports again, so a power-cycled controller (reports off, brake on) comes
//!   back with reports, sonar and — if the motors had been enabled — the brake released.
//! * **Emergency stop**: the spec (§3, §6) names no emergency command, so
//!   [`DifferentialBase::emergency_stop`] zeroes both axes at once (the same SET_DIR pair as
//!   `stop`) and then engages the brake (MOT_BRAKE_SET), so the motors stay disabled until
//!   `enable_motors(true)`.
//! * **Host silence**: if the process dies, nothing is sent and the controller's own
//!   fail-safe stops the robot (§6); if only the client goes quiet, the machine's 0.5 s
//!   command watchdog zeroes the speed.

use std::sync::Arc;
use std::time::Duration;

use ima_hal::base::{
    BaseLimits, BumperState, Bumpers, DifferentialBase, Odometer, Odometry, VelocityCommand,
};
use ima_hal::power::{Power, PowerState};
use ima_hal::safety::{HaltSignal, StopRegistry};
use ima_hal::sonar::{SonarArray, SonarScan, SonarTransducer};
use ima_hal::{ErrorType, Instant, Stamped};
use ima_serial::runner::{self, End, Flow, Shell};
use ima_serial::{BaudControl, FixedBaud};
use tokio::io::{AsyncRead, AsyncWrite};
use tokio::sync::{mpsc, oneshot, watch};

pub use crate::driver::{BAUD, DriverError};
use crate::machine::{Config, Event, Machine, Phase, Stats, TX_BUF};
/// The clock types a shell takes: the caller passes the process's one [`SharedClock`]
/// (usually a [`TokioClock`], so paused tests run in virtual time) to `connect`, and every
/// stamp the driver produces is on that time line.
pub use ima_hal::time::{Clock, SharedClock, TokioClock};
/// Open a serial port for the shell: `baud` (115200, §1) 8N1, no flow control, raw.
pub use ima_serial::open_port;

/// Link status as seen by handles (connected: motion reports arrive).
pub type LinkStatus = ima_serial::LinkStatus<(), DriverError>;

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

pub(crate) type Reply = oneshot::Sender<Result<(), DriverError>>;

/// A request from a handle to the driver task.
#[derive(Debug)]
pub enum Request {
    /// Drive (zero: stop).
    Velocity(VelocityCommand, Reply),
    /// Zero both axes and engage the brake.
    EStop(Reply),
    /// Release (`true`) or engage the brake (answered when SYS_STATUS confirms).
    Motors(bool, Reply),
    /// Sonar on or off.
    Sonar(bool, Reply),
    /// Zero the odometry.
    ResetOdometry(Reply),
    /// Shut the base down and end the task.
    Close(Reply),
}

type Slot<T> = watch::Sender<Option<Stamped<T>>>;

/// The receiving ends of what [`RflexShell`] publishes.
#[derive(Debug, Clone)]
pub(crate) struct Watches {
    pub(crate) odometry: watch::Receiver<Option<Stamped<Odometry>>>,
    pub(crate) sonar: watch::Receiver<Option<Stamped<SonarScan>>>,
    pub(crate) bumpers: watch::Receiver<Option<Stamped<BumperState>>>,
    pub(crate) power: watch::Receiver<Option<Stamped<PowerState>>>,
    pub(crate) brake: watch::Receiver<Option<Stamped<bool>>>,
    pub(crate) link: watch::Receiver<LinkStatus>,
    pub(crate) stats: watch::Receiver<ShellStats>,
    pub(crate) limits: BaseLimits,
    pub(crate) transducers: Arc<[SonarTransducer]>,
}

/// Machine events → readings and answers, for both shells.
#[derive(Debug)]
pub struct RflexShell {
    machine: Machine,
    odo_tx: Slot<Odometry>,
    sonar_tx: Slot<SonarScan>,
    bump_tx: Slot<BumperState>,
    power_tx: Slot<PowerState>,
    brake_tx: Slot<bool>,
    link_tx: watch::Sender<LinkStatus>,
    stats_tx: watch::Sender<ShellStats>,
    scan: SonarScan,
    motors_waiters: Vec<(bool, Reply)>,
    close_waiters: Vec<Reply>,
    sonar_wanted: bool,
    /// When to re-send the initialisation (`Instant::ZERO`: at once).
    reinit_at: Option<Instant>,
    reconnects: u32,
    /// Bytes received (for the connect error: silence or garbage).
    bytes: u64,
}

impl RflexShell {
    pub(crate) fn new(cfg: Config, now: Instant) -> (Self, Watches) {
        let (odo_tx, odometry) = watch::channel(None);
        let (sonar_tx, sonar) = watch::channel(None);
        let (bump_tx, bumpers) = watch::channel(None);
        let (power_tx, power) = watch::channel(None);
        let (brake_tx, brake) = watch::channel(None);
        let (link_tx, link) = watch::channel(LinkStatus::Connecting);
        let (stats_tx, stats) = watch::channel(ShellStats::default());
        let limits = cfg.limits;
        let machine = Machine::new(cfg, now);
        let transducers = machine.transducers().iter().copied().collect::<Vec<_>>();
        let w = Watches {
            odometry,
            sonar,
            bumpers,
            power,
            brake,
            link,
            stats,
            limits,
            transducers: transducers.into(),
        };
        let shell = Self {
            machine,
            odo_tx,
            sonar_tx,
            bump_tx,
            power_tx,
            brake_tx,
            link_tx,
            stats_tx,
            scan: SonarScan::default(),
            motors_waiters: Vec::new(),
            close_waiters: Vec::new(),
            sonar_wanted: false,
            reinit_at: None,
            reconnects: 0,
            bytes: 0,
        };
        (shell, w)
    }
}

impl Shell for RflexShell {
    type Machine = Machine;
    type Request = Request;
    const MAX_FRAME: usize = TX_BUF;

    fn machine(&mut self) -> &mut Machine {
        &mut self.machine
    }

    fn on_bytes(&mut self, bytes: &[u8], now: Instant) {
        self.bytes = self.bytes.saturating_add(bytes.len() as u64);
        self.machine.handle_bytes(bytes, now);
    }

    fn on_timeout(&mut self, now: Instant) {
        self.machine.handle_timeout(now);
        if self.reinit_at.is_some_and(|t| now >= t) {
            tracing::debug!("rflex: re-sending the initialisation");
            self.machine.reinitialize(self.sonar_wanted, now);
            self.reinit_at = Some(now + self.machine.config().link_timeout);
        }
    }

    fn next_wake(&mut self) -> Option<Instant> {
        [self.machine.poll_timeout(), self.reinit_at]
            .into_iter()
            .flatten()
            .min()
    }

    fn on_event(&mut self, ev: Event, _line: &mut dyn BaudControl) -> std::io::Result<()> {
        match ev {
            Event::Initialized => tracing::debug!("rflex: initialisation sent"),
            Event::LinkLost => {
                tracing::warn!("rflex: no report from the base; re-initialising");
                self.reconnects = self.reconnects.wrapping_add(1);
                self.reinit_at = Some(Instant::ZERO);
                self.link_tx.send_replace(LinkStatus::Lost);
            }
            // A frame alone (an ack, a status reply) does not prove the base is streaming
            // again (a power-cycled controller has reports off): only motion reports do.
            Event::Odometry(o) => {
                self.odo_tx.send_replace(Some(o));
                self.reinit_at = None;
                self.link_tx.send_if_modified(|l| {
                    let up = l.is_connected();
                    *l = LinkStatus::Connected(());
                    !up
                });
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
                let (done, keep) =
                    (self.motors_waiters.drain(..)).partition(|(w, _)| *w == released);
                self.motors_waiters = keep;
                for (_, tx) in done {
                    let _ = tx.send(Ok(()));
                }
            }
            Event::Sonar(r) => {
                self.scan.upsert(r);
                let scan = Stamped::new(r.at, self.scan.clone());
                self.sonar_tx.send_replace(Some(scan));
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
            Event::CommandTimeout => {
                tracing::warn!("rflex: no velocity command for 0.5 s; robot stopped");
            }
            Event::LinkUp | Event::Joystick { .. } | Event::Unknown(_) => {}
            Event::ShutdownComplete => {}
        }
        Ok(())
    }

    fn on_request(&mut self, req: Request, now: Instant) -> Flow {
        let m = &mut self.machine;
        let (r, tx) = match req {
            Request::Velocity(cmd, tx) => (m.set_velocity(cmd, now), tx),
            Request::EStop(tx) => (m.stop(now).and_then(|()| m.enable_motors(false, now)), tx),
            Request::Sonar(on, tx) => {
                self.sonar_wanted = on;
                (m.set_sonar(on, now), tx)
            }
            Request::ResetOdometry(tx) => {
                m.reset_odometry();
                self.odo_tx
                    .send_replace(Some(Stamped::new(now, m.odometry())));
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
        let _ = tx.send(r.map_err(Into::into));
        Flow::Continue
    }

    fn after_round(&mut self) {
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

    /// The shutdown sequence (§6).
    fn begin_close(&mut self, now: Instant) -> Duration {
        self.machine.shutdown(now);
        Duration::from_secs(2)
    }

    fn is_closed(&mut self) -> bool {
        self.machine.phase() == Phase::Closed
    }

    fn end(&mut self, how: End) {
        let (r, link) = match how {
            End::Closed { drained: true } => (Ok(()), LinkStatus::Closed),
            End::Closed { drained: false } => (Err(DriverError::Timeout), LinkStatus::Closed),
            End::Failed(e) => (Err(e.into()), LinkStatus::Failed(e.into())),
        };
        for tx in self.close_waiters.drain(..) {
            let _ = tx.send(r);
        }
        if let Err(e) = r {
            for (_, w) in self.motors_waiters.drain(..) {
                let _ = w.send(Err(e));
            }
        }
        self.link_tx.send_replace(link);
    }
}

/// A handle to a running rFLEX driver. Cheap to clone; every clone talks to the same task.
#[derive(Debug, Clone)]
pub struct Rflex {
    tx: mpsc::Sender<Request>,
    w: Watches,
    clock: SharedClock,
    halt: HaltSignal,
}

/// How long [`Rflex::connect`] waits for the first motion report by default.
pub const DEFAULT_CONNECT_TIMEOUT: Duration = Duration::from_secs(5);

const REQUEST_TIMEOUT: Duration = Duration::from_secs(1);
pub(crate) const WAIT_TIMEOUT: Duration = Duration::from_secs(2);

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
        let (shell, mut w) = RflexShell::new(cfg, clock.now());
        let halt = HaltSignal::new();
        StopRegistry::global().register("rFLEX base", halt.clone());
        tracing::info!(target: "ima::connect", "rFLEX: initialising, waiting for motion reports");
        // One fixed rate (§1): the stream needs no line-speed control.
        let tx = runner::spawn(shell, FixedBaud(stream), clock.clone(), Some(halt.clone()));
        match runner::wait_connected(&mut w.link, connect_timeout).await {
            Ok(()) => Ok(Rflex { tx, w, clock, halt }),
            Err(Some(e)) => Err(e),
            Err(None) => {
                let _ = tx.try_send(Request::Close(oneshot::channel().0));
                Err(crate::driver::no_report(&w.stats.borrow()))
            }
        }
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
        *self.w.link.borrow()
    }

    /// Counters (session, framer, reconnects).
    #[must_use]
    pub fn stats(&self) -> ShellStats {
        *self.w.stats.borrow()
    }

    /// The brake as the base last reported it (`true` = engaged), if known.
    #[must_use]
    pub fn brake(&self) -> Option<Stamped<bool>> {
        *self.w.brake.borrow()
    }

    /// The latest odometry, if any.
    #[must_use]
    pub fn latest_odometry(&self) -> Option<Stamped<Odometry>> {
        *self.w.odometry.borrow()
    }

    /// The driver's clock (the time base of every stamp it produces).
    #[must_use]
    pub fn now(&self) -> Instant {
        self.clock.now()
    }

    async fn request(&self, make: impl FnOnce(Reply) -> Request) -> Result<(), DriverError> {
        runner::request(&self.tx, make, REQUEST_TIMEOUT).await
    }

    /// Send the shutdown sequence (§6), wait for it to go out, and end the driver task.
    pub async fn close(&self) -> Result<(), DriverError> {
        if self.halt.is_done() {
            return Ok(());
        }
        match runner::request(&self.tx, Request::Close, Duration::from_secs(3)).await {
            // The task ended between the check and the request (a halt or the link).
            Err(DriverError::Disconnected) if self.halt.is_done() => Ok(()),
            r => r,
        }
    }
}

/// The value of `rx` once it is stamped after `after` (any value when `None`).
pub(crate) fn newer<T: Clone>(
    after: Option<Instant>,
) -> impl Fn(&Option<Stamped<T>>) -> Option<Stamped<T>> {
    move |s| {
        s.as_ref()
            .filter(|s| after.is_none_or(|a| s.at > a))
            .cloned()
    }
}

impl ErrorType for Rflex {
    type Error = DriverError;
}

impl DifferentialBase for Rflex {
    fn limits(&self) -> BaseLimits {
        self.w.limits
    }

    /// Release (`true`) or engage the brake; resolves when SYS_STATUS confirms it.
    async fn enable_motors(&mut self, enable: bool) -> Result<(), DriverError> {
        let make = |tx| Request::Motors(enable, tx);
        runner::request(&self.tx, make, Duration::from_secs(3)).await
    }

    async fn set_velocity(&mut self, cmd: VelocityCommand) -> Result<(), DriverError> {
        self.request(|tx| Request::Velocity(cmd, tx)).await
    }

    async fn stop(&mut self) -> Result<(), DriverError> {
        self.request(|tx| Request::Velocity(VelocityCommand::ZERO, tx))
            .await
    }

    /// Zero both axes and engage the brake (see the [module docs](self)).
    async fn emergency_stop(&mut self) -> Result<(), DriverError> {
        self.request(Request::EStop).await
    }
}

impl Odometer for Rflex {
    async fn odometry(&mut self) -> Result<Stamped<Odometry>, DriverError> {
        Ok(runner::wait_for(&self.w.odometry, WAIT_TIMEOUT, newer(None)).await?)
    }

    async fn next_odometry(&mut self, after: Instant) -> Result<Stamped<Odometry>, DriverError> {
        Ok(runner::wait_for(&self.w.odometry, WAIT_TIMEOUT, newer(Some(after))).await?)
    }

    async fn reset_odometry(&mut self) -> Result<(), DriverError> {
        self.request(Request::ResetOdometry).await
    }
}

impl SonarArray for Rflex {
    fn transducers(&self) -> &[SonarTransducer] {
        &self.w.transducers
    }

    async fn set_sonar_enabled(&mut self, on: bool) -> Result<(), DriverError> {
        self.request(|tx| Request::Sonar(on, tx)).await
    }

    async fn sonar(&mut self) -> Result<Stamped<SonarScan>, DriverError> {
        Ok(runner::wait_for(&self.w.sonar, WAIT_TIMEOUT, newer(None)).await?)
    }
}

impl Bumpers for Rflex {
    /// The latest DIO bumper report; all clear until the base reports a change.
    async fn bumpers(&mut self) -> Result<Stamped<BumperState>, DriverError> {
        let now = self.clock.now();
        let b = *self.w.bumpers.borrow();
        Ok(b.unwrap_or_else(|| Stamped::new(now, BumperState::default())))
    }
}

impl Power for Rflex {
    async fn power(&mut self) -> Result<Stamped<PowerState>, DriverError> {
        Ok(runner::wait_for(&self.w.power, WAIT_TIMEOUT, newer(None)).await?)
    }
}

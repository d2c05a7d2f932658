//! The I/O shell (feature `tokio`): [`P2osShell`] turns machine events into readings, and
//! the [`P2os`] handle (an [`ima_serial::handle::Handle`] plus the readings) implements the
//! `ima-hal` traits. The [`ima_serial::runner`] does the I/O; blocking code uses
//! `ima_serial::blocking::Blocking<P2os>`.

use std::sync::Arc;
use std::time::Duration;

use ima_hal::base::{
    BaseLimits, BumperState, Bumpers, DifferentialBase, Odometer, Odometry, VelocityCommand,
};
use ima_hal::power::{Power, PowerState};
use ima_hal::sonar::{SonarArray, SonarScan, SonarTransducer};
use ima_hal::{ErrorType, Instant, Stamped};
use ima_serial::handle::{Confirmations, Handle};
use ima_serial::probe::Probe;
use ima_serial::runner::Shell;
use tokio::io::{AsyncRead, AsyncWrite};
use tokio::sync::watch;

pub use crate::driver::{BaudControl, DriverError, Fault, FixedBaud};
use crate::machine::{
    Config, DisconnectReason, Event, Machine, RobotConfig, RobotIdentity, RobotState, SessionStats,
};
use crate::params::RobotParams;
/// The process's one clock, passed to `connect`: every stamp the driver produces is on it.
pub use ima_hal::time::{Clock, SharedClock, TokioClock};
/// The calls every driver handle answers alike: `link`, `stats`, `now`, `halt_signal`, `close`.
pub use ima_serial::handle::Driver;
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

/// Machine events → readings and answers.
#[derive(Debug)]
pub struct P2osShell {
    machine: Machine,
    link: watch::Sender<LinkStatus>,
    state: watch::Sender<Option<RobotState>>,
    config: watch::Sender<Option<RobotConfig>>,
    /// What each rate tried received, until the first connection.
    probe: Probe,
    /// Motor switches waiting for FLAGS to confirm them.
    motors: Confirmations<bool, (), Self>,
}

/// The longest a closing task keeps writing its last frames (STOP, CLOSE) for a robot that
/// never connected. For one that did, the runner allows [`ima_serial::runner::RESTOP_BOUND`]
/// (within [`P2os`]'s `CLOSE_LIMIT`): to repeat them while the robot is gone (for 1.2 s) or
/// still sending, and to wait for its silence after them.
const CLOSE_DRAIN_LIMIT: Duration = Duration::from_secs(1);
// Closing, with or without repeats, ends within `P2os::CLOSE_LIMIT`.
const _: () = assert!(
    ima_serial::runner::RESTOP_BOUND.as_millis() <= <P2os as Driver>::CLOSE_LIMIT.as_millis()
        && CLOSE_DRAIN_LIMIT.as_millis() <= <P2os as Driver>::CLOSE_LIMIT.as_millis()
);

impl P2osShell {
    fn fail(&mut self, f: Fault) {
        self.motors.fail_all(&f.clone().into());
        self.link.send_replace(LinkStatus::Failed(f.into()));
    }
}

impl Shell for P2osShell {
    type Machine = Machine;
    type Fault = Fault;
    type Up = Connection;
    type Stats = SessionStats;
    const MAX_FRAME: usize = crate::wire::MAX_FRAME_LEN;
    /// Three SIP periods: a robot silent this long as the driver closes is taken as gone (its
    /// link is declared lost only after the session's 0.7 s); its STOP and CLOSE are written
    /// again, so a line that comes back stops it at once instead of its watchdog 2 s after
    /// the last command it received.
    const QUIET: Option<Duration> = Some(Duration::from_millis(300));
    const REPEATS_STOP: bool = true;
    /// CLOSE ends the robot's SIPs (spec §5.2): three SIP periods of silence after it show the
    /// robot took it. A SIP 0.15 s or more after them (later than one in flight as the robot
    /// took them) means STOP and CLOSE did not reach it (a line dead from host to robot only,
    /// a corrupted frame): they are written again, and the stop is not claimed unless the
    /// robot then falls silent.
    const SILENT_ONCE_CLOSED: Option<Duration> = Some(Duration::from_millis(300));
    /// The firmware's watchdog (spec §5.2).
    const WATCHDOG: Option<&'static str> = Some("P2OS: 2 s after the last command it received");

    fn machine(&mut self) -> &mut Machine {
        &mut self.machine
    }

    fn link(&self) -> &watch::Sender<LinkStatus> {
        &self.link
    }

    fn start(&mut self, now: Instant) {
        self.machine.connect(now);
    }

    /// Counts the bytes (and the frames they made) per rate until the first connection.
    fn on_bytes(&mut self, bytes: &[u8], now: Instant) {
        let before = self.machine.stats().framer.tally();
        self.machine.handle_bytes(bytes, now);
        let after = self.machine.stats().framer.tally();
        self.probe.received(bytes.len(), before, after);
    }

    fn frames_heard(&self) -> u64 {
        self.machine.stats().framer.frames
    }

    /// STOP and CLOSE again.
    fn repeat_stop(&mut self) {
        self.machine.repeat_close();
    }

    fn on_event(&mut self, ev: Event, line: &mut dyn BaudControl) -> std::io::Result<()> {
        match ev {
            Event::SetBaud(b) => {
                tracing::debug!(baud = b, "p2os: line speed");
                line.set_baud(b)?;
                self.probe.rate(b, true);
            }
            Event::Connected {
                identity,
                params,
                baud,
            } => {
                tracing::info!(name = %identity.name, subclass = %identity.subclass, baud, "p2os: connected");
                self.probe.connected();
                let c = Connection {
                    identity,
                    baud,
                    params,
                };
                self.link.send_replace(LinkStatus::Connected(c));
            }
            Event::UnsupportedRobot(id) => {
                self.fail(Fault::UnsupportedRobot(id.subclass.as_str().into()));
            }
            Event::HandshakeFailed if self.probe.is_done() => self.fail(Fault::HandshakeFailed),
            Event::HandshakeFailed => self.fail(Fault::NoAnswer(Box::new(self.probe.report()))),
            Event::Disconnected(DisconnectReason::LinkLost) => {
                tracing::warn!("p2os: link lost, reconnecting");
                self.link.send_replace(LinkStatus::Lost);
            }
            Event::State(s) => {
                self.state.send_replace(Some(s));
            }
            Event::MotorsEnabled(on) => self.motors.confirm(&on, &()),
            Event::MotorsRefused => self.motors.fail_all(&Fault::MotorsRefused.into()),
            Event::CommandTimeout => {
                tracing::warn!("p2os: no velocity command for the command timeout; stop sent");
            }
            Event::Config(c) => {
                self.config.send_replace(Some(c));
            }
            Event::FlushInput | Event::Disconnected(_) | Event::Encoder { .. } => {}
        }
        Ok(())
    }

    fn stats(&self) -> SessionStats {
        self.machine.stats()
    }

    /// Queue STOP and CLOSE (frames are paced, so they may need more than one round).
    fn begin_close(&mut self, _now: Instant) -> Duration {
        self.machine.close();
        CLOSE_DRAIN_LIMIT
    }

    fn is_closed(&mut self) -> bool {
        !self.machine.has_pending_transmit()
    }

    /// Say what each rate tried received.
    fn no_answer(&mut self) -> DriverError {
        Fault::NoAnswer(Box::new(self.probe.report())).into()
    }
}

/// A handle to a running P2OS driver. Cheap to clone; every clone talks to the same task.
#[derive(Debug, Clone)]
pub struct P2os {
    h: Handle<P2osShell>,
    state: watch::Receiver<Option<RobotState>>,
    config: watch::Receiver<Option<RobotConfig>>,
    params: RobotParams,
    transducers: Arc<[SonarTransducer]>,
}

/// How long [`P2os::connect`] waits for the handshake by default.
pub const DEFAULT_CONNECT_TIMEOUT: Duration = Duration::from_secs(10);

const REQUEST_TIMEOUT: Duration = Duration::from_secs(1);

impl P2os {
    /// Spawn the driver task on `stream` and wait until the robot is connected (or
    /// `connect_timeout` passes). Must be called inside a tokio runtime.
    ///
    /// The task registers its [`HaltSignal`](ima_hal::safety::HaltSignal) in
    /// [`StopRegistry::global`](ima_hal::safety::StopRegistry::global) at once, so a
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
        let (state_tx, state) = watch::channel(None);
        let (config_tx, config) = watch::channel(None);
        let shell = P2osShell {
            machine: Machine::new(cfg),
            link: watch::channel(LinkStatus::Connecting).0,
            state: state_tx,
            config: config_tx,
            probe: Probe::new("P2OS"),
            motors: Confirmations::default(),
        };
        let stop_as = Some("P2OS base");
        let (h, c) = Handle::connect(shell, stream, clock, connect_timeout, stop_as).await?;
        Ok(P2os {
            h,
            state,
            config,
            transducers: c.params.transducers().collect(),
            params: c.params,
        })
    }

    /// The parameter table in use.
    #[must_use]
    pub fn params(&self) -> &RobotParams {
        &self.params
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
        &self,
        after: Instant,
        timeout: Duration,
    ) -> Result<RobotState, DriverError> {
        let newer = |s: &Option<RobotState>| s.as_ref().filter(|s| s.odometry.at > after).cloned();
        self.h.wait_for(&self.state, timeout, newer).await
    }

    async fn call(
        &self,
        f: impl FnOnce(&mut Machine, Instant) -> Result<(), crate::SessionError> + Send + 'static,
    ) -> Result<(), DriverError> {
        let f = |s: &mut P2osShell, now| Ok(f(&mut s.machine, now)?);
        self.h.call(REQUEST_TIMEOUT, f).await
    }

    async fn wait_state(&self) -> Result<RobotState, DriverError> {
        if let Some(s) = self.latest() {
            return Ok(s);
        }
        self.next_state(Instant::ZERO, Duration::from_secs(2)).await
    }
}

/// [`close`](Driver::close) writes STOP, then CLOSE; [`stats`](Driver::stats) are the
/// session's counters (frames, drops, bad checksums, implausible SIPs, reconnects…).
impl Driver for P2os {
    type Shell = P2osShell;
    const CLOSE_LIMIT: Duration = CLOSE_DRAIN_LIMIT.saturating_add(Duration::from_secs(1));
    fn handle(&self) -> &Handle<P2osShell> {
        &self.h
    }
}

impl ErrorType for P2os {
    type Error = DriverError;
}

impl DifferentialBase for P2os {
    fn limits(&self) -> BaseLimits {
        self.params.limits()
    }

    async fn enable_motors(&mut self, enable: bool) -> Result<(), DriverError> {
        // Answered when FLAGS confirms; ENABLE is retried by the session: allow for every
        // attempt.
        let f = move |s: &mut P2osShell, now, reply| {
            let asked = s.machine.enable_motors(enable, now).map_err(Into::into);
            s.motors.wait(enable, asked, reply);
        };
        self.h.defer(Duration::from_secs(3), f).await
    }

    async fn set_velocity(&mut self, cmd: VelocityCommand) -> Result<(), DriverError> {
        self.call(move |m, now| m.set_velocity(cmd, now)).await
    }

    async fn stop(&mut self) -> Result<(), DriverError> {
        self.call(|m, _| m.stop()).await
    }

    async fn emergency_stop(&mut self) -> Result<(), DriverError> {
        self.call(|m, _| m.emergency_stop()).await
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
        self.call(|m, _| {
            m.reset_odometry();
            Ok(())
        })
        .await
    }
}

impl SonarArray for P2os {
    fn transducers(&self) -> &[SonarTransducer] {
        &self.transducers
    }

    async fn set_sonar_enabled(&mut self, on: bool) -> Result<(), DriverError> {
        self.call(move |m, _| m.set_sonar(on)).await
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

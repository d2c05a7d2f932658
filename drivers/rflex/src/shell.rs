//! The I/O shell (feature `tokio`): [`RflexShell`] turns machine events into readings, and
//! the [`Rflex`] handle implements the `ima-hal` traits ([`DifferentialBase`], [`Odometer`],
//! [`SonarArray`], [`Bumpers`], [`Power`]). The [`ima_serial::runner`] does the I/O;
//! blocking code uses `ima_serial::blocking::Blocking<Rflex>`.
//!
//! * **Recovery**: the shell turns on the machine's [`Config::recover`]: from
//!   [`Event::LinkLost`] the §6 initialisation ([`Machine::reinitialize`]) is re-sent every
//!   [`Config::link_timeout`] until the base streams motion reports again, so a power-cycled
//!   controller (reports off, brake on) comes back with reports, sonar and — if the motors
//!   had been enabled — the brake released.
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
use ima_hal::sonar::{SonarArray, SonarScan, SonarTransducer};
use ima_hal::{ErrorType, Instant, Stamped};
use ima_serial::handle::{Confirmations, Handle, Slot, SlotRx as Rx, slot};
use ima_serial::runner::Shell;
use ima_serial::{BaudControl, FixedBaud};
use tokio::io::{AsyncRead, AsyncWrite};
use tokio::sync::watch;

pub use crate::driver::{BAUD, DriverError, Fault};
use crate::machine::{CommandError, Config, Event, Machine, Phase, Stats, TX_BUF};
/// The process's one clock, passed to `connect`: every stamp the driver produces is on it.
pub use ima_hal::time::{Clock, SharedClock, TokioClock};
/// The calls every driver handle answers alike: `link`, `stats`, `now`, `halt_signal`, `close`.
pub use ima_serial::handle::Driver;
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

/// Machine events → readings and answers.
#[derive(Debug)]
pub struct RflexShell {
    machine: Machine,
    link: watch::Sender<LinkStatus>,
    odometry: Slot<Odometry>,
    sonar: Slot<SonarScan>,
    bumpers: Slot<BumperState>,
    power: Slot<PowerState>,
    brake: Slot<bool>,
    scan: SonarScan,
    /// Brake changes waiting for SYS_STATUS to confirm them (keyed by "released").
    motors: Confirmations<bool, (), Self>,
    reconnects: u32,
    bytes: u64,
}

impl Shell for RflexShell {
    type Machine = Machine;
    type Fault = Fault;
    type Up = ();
    type Stats = ShellStats;
    const MAX_FRAME: usize = TX_BUF;
    /// Three report periods: a base silent this long as the driver closes is taken as gone
    /// (its link is declared lost only after the machine's 1 s), and its stop not claimed.
    /// The stop is written once: the base's own fail-safe stops it 1 s after its last command,
    /// about when a repeat could first help.
    const QUIET: Option<Duration> = Some(Duration::from_millis(300));
    /// The controller's fail-safe (spec §6).
    const WATCHDOG: Option<&'static str> =
        Some("rFLEX: its fail-safe, about 1 s after the last command");

    fn machine(&mut self) -> &mut Machine {
        &mut self.machine
    }

    fn link(&self) -> &watch::Sender<LinkStatus> {
        &self.link
    }

    fn on_bytes(&mut self, bytes: &[u8], now: Instant) {
        self.bytes = self.bytes.saturating_add(bytes.len() as u64);
        self.machine.handle_bytes(bytes, now);
    }

    fn frames_heard(&self) -> u64 {
        self.machine.framer_stats().frames.into()
    }

    fn on_event(&mut self, ev: Event, _line: &mut dyn BaudControl) -> std::io::Result<()> {
        match ev {
            Event::Initialized => tracing::debug!("rflex: initialisation sent"),
            Event::LinkLost => {
                tracing::warn!("rflex: no report from the base; re-initialising");
                self.reconnects = self.reconnects.wrapping_add(1);
                self.link.send_replace(LinkStatus::Lost);
            }
            // A frame alone (an ack, a status reply) does not prove the base is streaming
            // again (a power-cycled controller has reports off): only motion reports do.
            Event::Odometry(o) => {
                self.odometry.send_replace(Some(o));
                self.link.send_if_modified(|l| {
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
                self.power.send_replace(Some(p));
            }
            Event::Brake(b) => {
                self.brake.send_replace(Some(b));
                self.motors.confirm(&!b.value, &());
            }
            Event::Sonar(r) => {
                self.scan.upsert(r);
                let scan = Stamped::new(r.at, self.scan.clone());
                self.sonar.send_replace(Some(scan));
            }
            Event::UnmappedSonar { id, range_m, .. } => {
                tracing::debug!(id, range_m, "rflex: sonar id not in the table");
            }
            Event::Bumpers(b) => {
                self.bumpers.send_replace(Some(b));
            }
            Event::Dio { address, data, .. } => {
                tracing::debug!(address, data, "rflex: DIO report");
            }
            Event::CommandTimeout => {
                tracing::warn!("rflex: no velocity command for 0.5 s; stop sent");
            }
            Event::LinkUp | Event::Joystick { .. } | Event::Unknown(_) => {}
            Event::ShutdownComplete => {}
        }
        Ok(())
    }

    fn stats(&self) -> ShellStats {
        ShellStats {
            session: *self.machine.stats(),
            framer: *self.machine.framer_stats(),
            reconnects: self.reconnects,
            bytes: self.bytes,
        }
    }

    fn begin_close(&mut self, now: Instant) -> Duration {
        self.machine.shutdown(now);
        Duration::from_secs(2)
    }

    fn is_closed(&mut self) -> bool {
        self.machine.phase() == Phase::Closed
    }

    /// What the line carried instead of motion reports.
    fn no_answer(&mut self) -> DriverError {
        let st = self.stats();
        DriverError::Device(Fault::NoReport {
            bytes: st.bytes,
            frames: st.framer.frames,
            bad_frames: st.framer.errors(),
        })
    }
}

/// A handle to a running rFLEX driver. Cheap to clone; every clone talks to the same task.
#[derive(Debug, Clone)]
pub struct Rflex {
    h: Handle<RflexShell>,
    odometry: Rx<Odometry>,
    sonar: Rx<SonarScan>,
    bumpers: Rx<BumperState>,
    power: Rx<PowerState>,
    brake: Rx<bool>,
    limits: BaseLimits,
    transducers: Arc<[SonarTransducer]>,
}

/// How long [`Rflex::connect`] waits for motion reports by default.
pub const DEFAULT_CONNECT_TIMEOUT: Duration = Duration::from_secs(5);

const REQUEST_TIMEOUT: Duration = Duration::from_secs(1);
/// How long a reading is waited for.
const WAIT_TIMEOUT: Duration = Duration::from_secs(2);

impl Rflex {
    /// Spawn the driver task on `stream`, send the initialisation (§6) and wait until the
    /// base streams motion reports (or `connect_timeout` passes). Must be called inside a
    /// tokio runtime.
    ///
    /// The task registers its [`HaltSignal`](ima_hal::safety::HaltSignal) in
    /// [`StopRegistry::global`](ima_hal::safety::StopRegistry::global) at once, so a
    /// program's exit guard can stop this base (zero speeds, brake, shutdown) from any exit
    /// path.
    ///
    /// `clock` is the process's one time base: every reading's stamp is taken on it.
    ///
    /// # Errors
    /// [`Fault::NoReport`] (what the line carried instead) when no report came in time.
    pub async fn connect<S>(
        stream: S,
        cfg: Config,
        connect_timeout: Duration,
        clock: SharedClock,
    ) -> Result<Rflex, DriverError>
    where
        S: AsyncRead + AsyncWrite + Unpin + Send + 'static,
    {
        let (odometry_tx, odometry) = slot();
        let (sonar_tx, sonar) = slot();
        let (bumpers_tx, bumpers) = slot();
        let (power_tx, power) = slot();
        let (brake_tx, brake) = slot();
        let limits = cfg.limits;
        let machine = Machine::new(
            Config {
                recover: true,
                ..cfg
            },
            clock.now(),
        );
        let transducers = machine.transducers().iter().copied().collect();
        let shell = RflexShell {
            machine,
            link: watch::channel(LinkStatus::Connecting).0,
            odometry: odometry_tx,
            sonar: sonar_tx,
            bumpers: bumpers_tx,
            power: power_tx,
            brake: brake_tx,
            scan: SonarScan::default(),
            motors: Confirmations::default(),
            reconnects: 0,
            bytes: 0,
        };
        tracing::info!(target: "ima::connect", "rFLEX: initialising, waiting for motion reports");
        // One fixed rate (§1): the stream needs no line-speed control.
        let stream = FixedBaud(stream);
        let stop_as = Some("rFLEX base");
        let (h, ()) = Handle::connect(shell, stream, clock, connect_timeout, stop_as).await?;
        Ok(Rflex {
            h,
            odometry,
            sonar,
            bumpers,
            power,
            brake,
            limits,
            transducers,
        })
    }

    /// The brake as last reported (`true`: engaged).
    #[must_use]
    pub fn brake(&self) -> Option<Stamped<bool>> {
        *self.brake.borrow()
    }

    /// The latest odometry, if any.
    #[must_use]
    pub fn latest_odometry(&self) -> Option<Stamped<Odometry>> {
        *self.odometry.borrow()
    }

    async fn call(
        &self,
        f: impl FnOnce(&mut RflexShell, Instant) -> Result<(), CommandError> + Send + 'static,
    ) -> Result<(), DriverError> {
        self.h.call(REQUEST_TIMEOUT, |s, now| Ok(f(s, now)?)).await
    }
}

/// [`close`](Driver::close) stops the base and runs the shutdown sequence.
impl Driver for Rflex {
    type Shell = RflexShell;
    const CLOSE_LIMIT: Duration = Duration::from_secs(3);
    fn handle(&self) -> &Handle<RflexShell> {
        &self.h
    }
}

impl ErrorType for Rflex {
    type Error = DriverError;
}

impl DifferentialBase for Rflex {
    fn limits(&self) -> BaseLimits {
        self.limits
    }

    /// Release (`true`) or engage the brake; answered when SYS_STATUS confirms.
    async fn enable_motors(&mut self, enable: bool) -> Result<(), DriverError> {
        let f = move |s: &mut RflexShell, now, reply| {
            let asked = s.machine.enable_motors(enable, now).map_err(Into::into);
            s.motors.wait(enable, asked, reply);
        };
        self.h.defer(Duration::from_secs(3), f).await
    }

    async fn set_velocity(&mut self, cmd: VelocityCommand) -> Result<(), DriverError> {
        self.call(move |s, now| s.machine.set_velocity(cmd, now))
            .await
    }

    async fn stop(&mut self) -> Result<(), DriverError> {
        self.set_velocity(VelocityCommand::ZERO).await
    }

    /// Zero both axes and engage the brake.
    async fn emergency_stop(&mut self) -> Result<(), DriverError> {
        let f = |s: &mut RflexShell, now| {
            let m = &mut s.machine;
            m.stop(now).and_then(|()| m.enable_motors(false, now))
        };
        self.call(f).await
    }
}

impl Odometer for Rflex {
    async fn odometry(&mut self) -> Result<Stamped<Odometry>, DriverError> {
        self.h.reading(&self.odometry, None, WAIT_TIMEOUT).await
    }

    async fn next_odometry(&mut self, after: Instant) -> Result<Stamped<Odometry>, DriverError> {
        self.h
            .reading(&self.odometry, Some(after), WAIT_TIMEOUT)
            .await
    }

    async fn reset_odometry(&mut self) -> Result<(), DriverError> {
        self.call(|s, now| {
            s.machine.reset_odometry();
            let zero = Stamped::new(now, s.machine.odometry());
            s.odometry.send_replace(Some(zero));
            Ok(())
        })
        .await
    }
}

impl SonarArray for Rflex {
    fn transducers(&self) -> &[SonarTransducer] {
        &self.transducers
    }

    async fn set_sonar_enabled(&mut self, on: bool) -> Result<(), DriverError> {
        self.call(move |s, now| s.machine.set_sonar(on, now)).await
    }

    async fn sonar(&mut self) -> Result<Stamped<SonarScan>, DriverError> {
        self.h.reading(&self.sonar, None, WAIT_TIMEOUT).await
    }
}

impl Bumpers for Rflex {
    /// The latest bumper report (all clear until the base sends one).
    async fn bumpers(&mut self) -> Result<Stamped<BumperState>, DriverError> {
        let now = self.h.now();
        let b = *self.bumpers.borrow();
        Ok(b.unwrap_or_else(|| Stamped::new(now, BumperState::default())))
    }
}

impl Power for Rflex {
    async fn power(&mut self) -> Result<Stamped<PowerState>, DriverError> {
        self.h.reading(&self.power, None, WAIT_TIMEOUT).await
    }
}

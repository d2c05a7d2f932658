//! The blocking I/O shell (feature `serial`): the [`P2osShell`] run by
//! [`ima_serial::blocking::Blocking`] over any `Read + Write` stream, for simple tools that
//! do not want an async runtime. It implements the blocking mirrors of the `ima-hal` traits
//! ([`ima_hal::blocking`]).
//!
//! The stream's `read` must return within a few milliseconds when nothing arrives (a port
//! from [`open_port`] has a 10 ms timeout). Time only advances inside the driver's calls: a
//! tool that stops calling for longer than the robot's watchdog (2 s) lets the robot stop.

use std::io::{Read, Write};
use std::time::Duration;

use ima_hal::base::{BaseLimits, BumperState, Odometry, VelocityCommand};
use ima_hal::blocking;
use ima_hal::power::PowerState;
use ima_hal::sonar::{SonarScan, SonarTransducer};
use ima_hal::time::SharedClock;
use ima_hal::{ErrorType, Instant, Stamped};
use ima_serial::blocking::Blocking;

pub use crate::driver::{BaudControl, DriverError, FixedBaud};
use crate::machine::{Config, RobotIdentity, RobotState, SessionStats};
use crate::params::RobotParams;
use crate::shell::{Connection, P2osShell, Request, Watches};
/// Open a serial port for the blocking shell: 8N1, no flow control, 10 ms read timeout.
pub use ima_serial::open_blocking_port as open_port;

/// A connected P2OS robot, driven synchronously.
#[derive(Debug)]
pub struct BlockingP2os<S> {
    run: Blocking<P2osShell, S>,
    w: Watches,
    conn: Connection,
    transducers: Vec<SonarTransducer>,
}

const REQUEST_TIMEOUT: Duration = Duration::from_secs(1);

impl<S: Read + Write + BaudControl> BlockingP2os<S> {
    /// Run the handshake on `stream` until the robot streams SIPs, or `timeout` passes;
    /// `clock` is the process's time base.
    ///
    /// # Errors
    /// [`DriverError::Timeout`], the handshake's failure, or the link's.
    pub fn connect(
        stream: S,
        cfg: Config,
        timeout: Duration,
        clock: SharedClock,
    ) -> Result<Self, DriverError> {
        let (shell, w) = P2osShell::new(cfg);
        let mut run = Blocking::new(shell, stream, clock);
        let conn = run.wait_connected(&w.link, timeout)?;
        Ok(Self {
            run,
            w,
            transducers: crate::driver::transducers(&conn.params),
            conn,
        })
    }

    /// Who answered.
    pub fn identity(&self) -> Option<&RobotIdentity> {
        Some(&self.conn.identity)
    }

    /// The parameter table in use.
    pub fn params(&self) -> &RobotParams {
        &self.conn.params
    }

    /// Session counters.
    pub fn stats(&self) -> SessionStats {
        *self.w.stats.borrow()
    }

    /// The latest SIP state.
    pub fn latest(&self) -> Option<RobotState> {
        self.w.state.borrow().clone()
    }

    /// The driver's clock.
    pub fn now(&self) -> Instant {
        self.run.now()
    }

    /// Run I/O and timers for `d` (use it to wait while staying connected).
    ///
    /// # Errors
    /// The link's failure.
    pub fn pump_for(&mut self, d: Duration) -> Result<(), DriverError> {
        Ok(self.run.pump_for(d)?)
    }

    /// One round: send what is due, read what is there (up to the stream's timeout), run
    /// timers, handle events.
    ///
    /// # Errors
    /// The link's failure.
    pub fn pump_once(&mut self) -> Result<(), DriverError> {
        Ok(self.run.pump_once()?)
    }

    fn wait_state(&mut self) -> Result<RobotState, DriverError> {
        let state = self.w.state.clone();
        Ok(self
            .run
            .wait_for(Duration::from_secs(2), |_| state.borrow().clone())?)
    }

    fn request(
        &mut self,
        make: impl FnOnce(crate::shell::Reply) -> Request,
    ) -> Result<(), DriverError> {
        self.run.request(make, REQUEST_TIMEOUT)
    }

    /// Stop the robot and close the session.
    ///
    /// # Errors
    /// [`DriverError::Timeout`] if STOP and CLOSE could not be written in time.
    pub fn close(self) -> Result<(), DriverError> {
        Ok(self.run.close().1?)
    }
}

impl<S> ErrorType for BlockingP2os<S> {
    type Error = DriverError;
}

impl<S: Read + Write + BaudControl> blocking::DifferentialBase for BlockingP2os<S> {
    fn limits(&self) -> BaseLimits {
        crate::driver::limits(&self.conn.params)
    }

    fn enable_motors(&mut self, enable: bool) -> Result<(), DriverError> {
        let make = |tx| Request::Motors(enable, tx);
        self.run.request(make, Duration::from_secs(3))
    }

    fn set_velocity(&mut self, cmd: VelocityCommand) -> Result<(), DriverError> {
        self.request(|tx| Request::Velocity(cmd, tx))
    }

    fn stop(&mut self) -> Result<(), DriverError> {
        self.request(Request::Stop)
    }

    fn emergency_stop(&mut self) -> Result<(), DriverError> {
        self.request(Request::EStop)
    }
}

impl<S: Read + Write + BaudControl> blocking::Odometer for BlockingP2os<S> {
    fn odometry(&mut self) -> Result<Stamped<Odometry>, DriverError> {
        Ok(self.wait_state()?.odometry)
    }

    fn reset_odometry(&mut self) -> Result<(), DriverError> {
        self.request(Request::ResetOdometry)
    }
}

impl<S: Read + Write + BaudControl> blocking::SonarArray for BlockingP2os<S> {
    fn transducers(&self) -> &[SonarTransducer] {
        &self.transducers
    }

    fn sonar(&mut self) -> Result<Stamped<SonarScan>, DriverError> {
        Ok(self.wait_state()?.sonar)
    }
}

impl<S: Read + Write + BaudControl> blocking::Bumpers for BlockingP2os<S> {
    fn bumpers(&mut self) -> Result<Stamped<BumperState>, DriverError> {
        Ok(self.wait_state()?.bumpers)
    }
}

impl<S: Read + Write + BaudControl> blocking::Power for BlockingP2os<S> {
    fn power(&mut self) -> Result<Stamped<PowerState>, DriverError> {
        Ok(self.wait_state()?.power)
    }
}

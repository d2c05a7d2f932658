//! The blocking I/O shell (feature `serial`): the [`RflexShell`] run by
//! [`ima_serial::blocking::Blocking`] over any `Read + Write` stream (a port from
//! [`open_port`], or one wrapped in [`FixedBaud`]). It implements the blocking mirrors of the
//! `ima-hal` traits ([`ima_hal::blocking`]).
//!
//! The stream's `read` must return within a few milliseconds when nothing arrives: the
//! machine's timers (keep-alive, command watchdog, status polls) run between reads.

use std::io::{Read, Write};
use std::time::Duration;

use ima_hal::base::{BaseLimits, BumperState, Odometry, VelocityCommand};
use ima_hal::blocking;
use ima_hal::power::PowerState;
use ima_hal::sonar::{SonarScan, SonarTransducer};
use ima_hal::time::SharedClock;
use ima_hal::{ErrorType, Instant, Stamped};
use ima_serial::blocking::Blocking;
pub use ima_serial::{BaudControl, FixedBaud};

pub use crate::driver::DriverError;
use crate::machine::{Config, Stats};
use crate::shell::{Reply, Request, RflexShell, WAIT_TIMEOUT, Watches, newer};
/// Open a serial port for the blocking shell: 8N1, no flow control, 10 ms read timeout.
pub use ima_serial::open_blocking_port as open_port;

/// A connected rFLEX base, driven synchronously.
#[derive(Debug)]
pub struct BlockingRflex<S> {
    run: Blocking<RflexShell, S>,
    w: Watches,
}

impl<S: Read + Write + BaudControl> BlockingRflex<S> {
    /// Send the initialisation on `stream` and wait until the base streams motion reports,
    /// or `timeout`; `clock` is the process's time base.
    ///
    /// # Errors
    /// [`DriverError::Timeout`], or the link's failure.
    pub fn connect(
        stream: S,
        cfg: Config,
        timeout: Duration,
        clock: SharedClock,
    ) -> Result<Self, DriverError> {
        let (shell, w) = RflexShell::new(cfg, clock.now());
        let mut run = Blocking::new(shell, stream, clock);
        run.wait_connected(&w.link, timeout)?;
        Ok(Self { run, w })
    }

    /// Session counters.
    #[must_use]
    pub fn stats(&self) -> Stats {
        self.w.stats.borrow().session
    }

    /// The driver's clock.
    #[must_use]
    pub fn now(&self) -> Instant {
        self.run.now()
    }

    /// The brake as last reported (`true` = engaged).
    #[must_use]
    pub fn brake(&self) -> Option<Stamped<bool>> {
        *self.w.brake.borrow()
    }

    /// Whether the base is streaming motion reports.
    #[must_use]
    pub fn link_up(&self) -> bool {
        self.w.link.borrow().is_connected()
    }

    /// Run I/O and timers for `d` (use it to wait while staying connected).
    ///
    /// # Errors
    /// The link's failure.
    pub fn pump_for(&mut self, d: Duration) -> Result<(), DriverError> {
        Ok(self.run.pump_for(d)?)
    }

    /// One round: events, frames due, one read (up to the stream's timeout), due timers.
    ///
    /// # Errors
    /// The link's failure.
    pub fn pump_once(&mut self) -> Result<(), DriverError> {
        Ok(self.run.pump_once()?)
    }

    fn request(&mut self, make: impl FnOnce(Reply) -> Request) -> Result<(), DriverError> {
        self.run.request(make, Duration::from_secs(1))
    }

    /// Send the shutdown sequence (§6) and give the stream back.
    ///
    /// # Errors
    /// [`DriverError::Timeout`] if it could not all be written, or the link's failure.
    pub fn close(self) -> Result<S, DriverError> {
        let (stream, r) = self.run.close();
        r?;
        Ok(stream)
    }
}

impl<S> ErrorType for BlockingRflex<S> {
    type Error = DriverError;
}

impl<S: Read + Write + BaudControl> blocking::DifferentialBase for BlockingRflex<S> {
    fn limits(&self) -> BaseLimits {
        self.w.limits
    }

    fn enable_motors(&mut self, enable: bool) -> Result<(), DriverError> {
        let make = |tx| Request::Motors(enable, tx);
        self.run.request(make, Duration::from_secs(3))
    }

    fn set_velocity(&mut self, cmd: VelocityCommand) -> Result<(), DriverError> {
        self.request(|tx| Request::Velocity(cmd, tx))
    }

    fn stop(&mut self) -> Result<(), DriverError> {
        self.request(|tx| Request::Velocity(VelocityCommand::ZERO, tx))
    }

    fn emergency_stop(&mut self) -> Result<(), DriverError> {
        self.request(Request::EStop)
    }
}

impl<S: Read + Write + BaudControl> blocking::Odometer for BlockingRflex<S> {
    fn odometry(&mut self) -> Result<Stamped<Odometry>, DriverError> {
        let rx = self.w.odometry.clone();
        let pick = newer(None);
        Ok(self.run.wait_for(WAIT_TIMEOUT, |_| pick(&rx.borrow()))?)
    }

    fn reset_odometry(&mut self) -> Result<(), DriverError> {
        self.request(Request::ResetOdometry)
    }
}

impl<S: Read + Write + BaudControl> blocking::SonarArray for BlockingRflex<S> {
    fn transducers(&self) -> &[SonarTransducer] {
        &self.w.transducers
    }

    fn sonar(&mut self) -> Result<Stamped<SonarScan>, DriverError> {
        let rx = self.w.sonar.clone();
        let pick = newer(None);
        Ok(self.run.wait_for(WAIT_TIMEOUT, |_| pick(&rx.borrow()))?)
    }
}

impl<S: Read + Write + BaudControl> blocking::Bumpers for BlockingRflex<S> {
    /// The latest DIO bumper report; all clear until the base reports a change.
    fn bumpers(&mut self) -> Result<Stamped<BumperState>, DriverError> {
        let now = self.run.now();
        let b = *self.w.bumpers.borrow();
        Ok(b.unwrap_or_else(|| Stamped::new(now, BumperState::default())))
    }
}

impl<S: Read + Write + BaudControl> blocking::Power for BlockingRflex<S> {
    fn power(&mut self) -> Result<Stamped<PowerState>, DriverError> {
        let rx = self.w.power.clone();
        let pick = newer(None);
        Ok(self.run.wait_for(WAIT_TIMEOUT, |_| pick(&rx.borrow()))?)
    }
}

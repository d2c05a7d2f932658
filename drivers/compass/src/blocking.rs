//! The blocking I/O shell (feature `serial`): the [`CompassShell`] run by
//! [`ima_serial::blocking::Blocking`] over any `Read + Write` stream (a port from
//! [`open_port`], or one wrapped in [`FixedBaud`]), implementing
//! [`ima_hal::blocking::Compass`].
//!
//! The stream's `read` must return within a few milliseconds when nothing arrives: the
//! machine's timers (configuration retries, data timeout) run between reads.

use std::io::{Read, Write};
use std::time::Duration;

use ima_hal::blocking;
use ima_hal::compass::Heading;
use ima_hal::time::SharedClock;
use ima_hal::{ErrorType, Instant, Stamped};
use ima_serial::blocking::Blocking;
pub use ima_serial::{BaudControl, FixedBaud};

pub use crate::driver::DriverError;
use crate::machine::{Config, Reading, Stats};
use crate::shell::{CompassShell, HEADING_TIMEOUT, Watches};
/// Open a serial port for the blocking shell: 8N1, no flow control, 10 ms read timeout.
pub use ima_serial::open_blocking_port as open_port;

/// A configured compass, read synchronously.
#[derive(Debug)]
pub struct BlockingCompass<S> {
    run: Blocking<CompassShell, S>,
    w: Watches,
}

impl<S: Read + Write + BaudControl> BlockingCompass<S> {
    /// Configure the device on `stream` and wait until headings flow, or `timeout` passes;
    /// `clock` is the process's time base.
    ///
    /// # Errors
    /// [`DriverError::NoAnswer`] / [`DriverError::WrongDialect`], [`DriverError::Timeout`],
    /// [`DriverError::Io`].
    pub fn connect(
        stream: S,
        cfg: Config,
        timeout: Duration,
        clock: SharedClock,
    ) -> Result<Self, DriverError> {
        let (shell, w) = CompassShell::new(cfg);
        let mut run = Blocking::new(shell, stream, clock);
        run.wait_connected(&w.link, timeout)?;
        Ok(Self { run, w })
    }

    /// Session counters.
    #[must_use]
    pub fn stats(&self) -> Stats {
        *self.w.stats.borrow()
    }

    /// The driver's clock.
    #[must_use]
    pub fn now(&self) -> Instant {
        self.run.now()
    }

    /// The latest reading, if any.
    #[must_use]
    pub fn latest(&self) -> Option<Stamped<Reading>> {
        *self.w.reading.borrow()
    }

    /// Give the stream back.
    pub fn into_inner(self) -> S {
        self.run.close().0
    }

    /// Read, run timers and send until a reading stamped after `after` arrives, or `timeout`.
    ///
    /// # Errors
    /// [`DriverError::Timeout`], [`DriverError::Io`], [`DriverError::Disconnected`].
    pub fn next_reading(
        &mut self,
        after: Instant,
        timeout: Duration,
    ) -> Result<Stamped<Reading>, DriverError> {
        let rx = self.w.reading.clone();
        let newer = |_: &mut CompassShell| rx.borrow().filter(|r| r.at > after);
        Ok(self.run.wait_for(timeout, newer)?)
    }
}

impl<S> ErrorType for BlockingCompass<S> {
    type Error = DriverError;
}

impl<S: Read + Write + BaudControl> blocking::Compass for BlockingCompass<S> {
    /// The freshest heading: what is buffered now, else the next one.
    fn heading(&mut self) -> Result<Stamped<Heading>, DriverError> {
        self.run.pump_once()?;
        if let Some(r) = self.latest() {
            return Ok(r.map(|r| r.heading));
        }
        Ok(self
            .next_reading(Instant::ZERO, HEADING_TIMEOUT)?
            .map(|r| r.heading))
    }

    fn next_heading(&mut self, after: Instant) -> Result<Stamped<Heading>, DriverError> {
        Ok(self
            .next_reading(after, HEADING_TIMEOUT)?
            .map(|r| r.heading))
    }
}

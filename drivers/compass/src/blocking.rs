//! The blocking I/O shell (feature `serial`): the sans-IO [`Machine`] over any `Read + Write`
//! stream, for simple tools that do not want an async runtime.
//!
//! The stream's `read` must return within a few milliseconds when nothing arrives (a port from
//! [`open_port`] has a 10 ms timeout; `TimedOut` and `WouldBlock` count as "nothing"), because
//! the session's timers run between reads. Time only advances inside the driver's calls.
//! [`BlockingCompass`] implements [`ima_hal::blocking::Compass`], the blocking mirror of
//! [`ima_hal::compass::Compass`].

use std::io::{self, Read, Write};
use std::time::Duration;

use ima_hal::blocking;
use ima_hal::compass::Heading;
use ima_hal::time::MonotonicClock;
use ima_hal::{ErrorType, Instant, Stamped};

pub use crate::driver::DriverError;
use crate::machine::{Config, Event, Job, Machine, Reading, Stats};

/// Open a serial port for the blocking shell: `baud` 8N1, no flow control, 10 ms read
/// timeout.
///
/// A path that is not a serial port (a regular file, `/dev/null`) fails with
/// [`io::ErrorKind::InvalidInput`] and `PATH is not a serial port (…)`.
pub fn open_port(path: &str, baud: u32) -> io::Result<serialport::TTYPort> {
    serialport::new(path, baud)
        .timeout(Duration::from_millis(10))
        .open_native()
        .map_err(|e| ima_hal::serial::explain_open_error(path, io::Error::from(e)))
}

/// A configured compass, read synchronously.
#[derive(Debug)]
pub struct BlockingCompass<S> {
    stream: S,
    machine: Machine,
    clock: MonotonicClock,
    latest: Option<Stamped<Reading>>,
    configured: bool,
    failed: Option<DriverError>,
}

impl<S: Read + Write> BlockingCompass<S> {
    /// Configure the device on `stream` and wait until headings flow, or `timeout` passes.
    ///
    /// # Errors
    /// [`DriverError::JobFailed`], [`DriverError::Timeout`], [`DriverError::Io`].
    pub fn connect(stream: S, cfg: Config, timeout: Duration) -> Result<Self, DriverError> {
        let mut me = Self {
            stream,
            machine: Machine::new(cfg),
            clock: MonotonicClock::new(),
            latest: None,
            configured: false,
            failed: None,
        };
        me.machine.start(me.clock.now());
        let deadline = std::time::Instant::now() + timeout;
        while !me.configured {
            if std::time::Instant::now() >= deadline {
                return Err(DriverError::Timeout);
            }
            me.pump_once()?;
        }
        Ok(me)
    }

    /// Session counters.
    #[must_use]
    pub fn stats(&self) -> Stats {
        self.machine.stats()
    }

    /// The driver's clock.
    #[must_use]
    pub fn now(&self) -> Instant {
        self.clock.now()
    }

    /// The latest reading, if any.
    #[must_use]
    pub fn latest(&self) -> Option<Stamped<Reading>> {
        self.latest
    }

    /// Give the stream back.
    pub fn into_inner(self) -> S {
        self.stream
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
        let deadline = std::time::Instant::now() + timeout;
        loop {
            if let Some(r) = self.latest
                && r.at > after
            {
                return Ok(r);
            }
            if std::time::Instant::now() >= deadline {
                return Err(DriverError::Timeout);
            }
            self.pump_once()?;
        }
    }

    fn pump_available(&mut self) -> Result<(), DriverError> {
        // One pass: whatever is buffered now (bounded by the port timeout).
        self.pump_once()
    }

    fn pump_once(&mut self) -> Result<(), DriverError> {
        if let Some(e) = self.failed {
            return Err(e);
        }
        let mut tbuf = [0u8; crate::wire::command::MAX_COMMAND];
        while let Some(n) = self.machine.poll_transmit(&mut tbuf) {
            let cmd = tbuf.get(..n).unwrap_or(&[]);
            self.stream
                .write_all(cmd)
                .and_then(|()| self.stream.flush())
                .map_err(|e| DriverError::Io(e.kind()))?;
        }
        let mut rbuf = [0u8; 256];
        match self.stream.read(&mut rbuf) {
            Ok(0) => return Err(DriverError::Disconnected),
            Ok(n) => {
                let now = self.clock.now();
                self.machine.handle_bytes(rbuf.get(..n).unwrap_or(&[]), now);
            }
            Err(e)
                if matches!(
                    e.kind(),
                    io::ErrorKind::TimedOut
                        | io::ErrorKind::WouldBlock
                        | io::ErrorKind::Interrupted
                ) => {}
            Err(e) => return Err(DriverError::Io(e.kind())),
        }
        let now = self.clock.now();
        if self.machine.poll_timeout().is_some_and(|t| now >= t) {
            self.machine.handle_timeout(now);
        }
        while let Some(ev) = self.machine.poll_event() {
            match ev {
                Event::Heading(r) => self.latest = Some(r),
                Event::Configured => self.configured = true,
                Event::JobFailed {
                    job: Job::Configure,
                    step,
                } => {
                    let e = crate::driver::configuration_failed(&self.machine, step);
                    self.failed = Some(e);
                    return Err(e);
                }
                _ => {}
            }
        }
        // Commands a timer queued go out on the next call.
        Ok(())
    }
}

impl<S> ErrorType for BlockingCompass<S> {
    type Error = DriverError;
}

impl<S: Read + Write> blocking::Compass for BlockingCompass<S> {
    /// The most recent heading (waits up to 3 s for the first one).
    fn heading(&mut self) -> Result<Stamped<Heading>, DriverError> {
        self.pump_available()?;
        match self.latest {
            Some(r) => Ok(r.map(|r| r.heading)),
            None => self.next_heading(Instant::ZERO),
        }
    }

    /// A heading measured after `after` (waits up to 3 s).
    fn next_heading(&mut self, after: Instant) -> Result<Stamped<Heading>, DriverError> {
        Ok(self
            .next_reading(after, Duration::from_secs(3))?
            .map(|r| r.heading))
    }
}

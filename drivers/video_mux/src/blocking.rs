//! The blocking I/O shell (feature `serial`): the sans-IO [`Machine`] over any `Read + Write`
//! stream, for simple tools without an async runtime.
//!
//! The stream's `read` must return within a few milliseconds when nothing arrives (a port from
//! [`open_port`] has a 10 ms timeout; `TimedOut`/`WouldBlock` count as "nothing").
//! [`BlockingVideoMux`] implements [`ima_hal::blocking::CameraMux`], the blocking mirror of
//! [`ima_hal::camera::CameraMux`].

use std::io::{self, Read, Write};
use std::time::Duration;

use ima_hal::blocking;
use ima_hal::camera::{Channel, Selection};
use ima_hal::time::MonotonicClock;
use ima_hal::{ErrorType, Instant};

pub use crate::driver::DriverError;
use crate::machine::{Config, Event, Machine, Stats};

/// Open a serial port for the blocking shell: `baud` 8N1, no flow control, 10 ms timeout.
///
/// A path that is not a serial port (a regular file, `/dev/null`) fails with
/// [`io::ErrorKind::InvalidInput`] and `PATH is not a serial port (…)`.
pub fn open_port(path: &str, baud: u32) -> io::Result<serialport::TTYPort> {
    serialport::new(path, baud)
        .timeout(Duration::from_millis(10))
        .open_native()
        .map_err(|e| ima_hal::serial::explain_open_error(path, io::Error::from(e)))
}

enum Outcome {
    Selected(Selection),
    Current(Option<Channel>),
    Failed(DriverError),
}

/// A switcher driven synchronously.
#[derive(Debug)]
pub struct BlockingVideoMux<S> {
    stream: S,
    machine: Machine,
    clock: MonotonicClock,
}

impl<S: Read + Write> BlockingVideoMux<S> {
    /// A driver on `stream`; nothing is sent until a request.
    pub fn new(stream: S, config: Config) -> Self {
        Self {
            stream,
            machine: Machine::new(config),
            clock: MonotonicClock::new(),
        }
    }

    /// The settings.
    #[must_use]
    pub fn config(&self) -> &Config {
        self.machine.config()
    }

    /// Counters.
    #[must_use]
    pub fn stats(&self) -> Stats {
        self.machine.stats()
    }

    /// The driver's clock.
    #[must_use]
    pub fn now(&self) -> Instant {
        self.clock.now()
    }

    fn run(&mut self) -> Result<Outcome, DriverError> {
        // The machine bounds the wait (reply timeout × retries); this is a backstop.
        let deadline = std::time::Instant::now() + Duration::from_secs(30);
        let mut tbuf = [0u8; 16];
        let mut rbuf = [0u8; 256];
        loop {
            while let Some(ev) = self.machine.poll_event() {
                match ev {
                    Event::Selected(s) => return Ok(Outcome::Selected(s)),
                    Event::SelectFailed { failure, .. } | Event::QueryFailed { failure } => {
                        return Ok(Outcome::Failed(failure.into()));
                    }
                    Event::Current { channel } => return Ok(Outcome::Current(channel)),
                    _ => {}
                }
            }
            if std::time::Instant::now() >= deadline {
                return Err(DriverError::Timeout);
            }
            while let Some(n) = self.machine.poll_transmit(&mut tbuf) {
                let cmd = tbuf.get(..n).unwrap_or(&[]);
                self.stream
                    .write_all(cmd)
                    .and_then(|()| self.stream.flush())
                    .map_err(|e| DriverError::Io(e.kind()))?;
            }
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
        }
    }
}

impl<S> ErrorType for BlockingVideoMux<S> {
    type Error = DriverError;
}

impl<S: Read + Write> blocking::CameraMux for BlockingVideoMux<S> {
    fn channel_count(&self) -> Channel {
        self.machine.config().channel_count
    }

    fn settle_time(&self) -> Duration {
        self.machine.config().settle_time
    }

    /// Switch to `channel` and wait for the switcher's confirmation (with retries).
    fn select(&mut self, channel: Channel) -> Result<Selection, DriverError> {
        self.machine
            .select(channel, self.clock.now())
            .map_err(DriverError::Request)?;
        match self.run()? {
            Outcome::Selected(s) => Ok(s),
            Outcome::Failed(e) => Err(e),
            Outcome::Current(_) => Err(DriverError::Timeout),
        }
    }

    /// Ask the switcher which channel is selected.
    fn current_channel(&mut self) -> Result<Option<Channel>, DriverError> {
        self.machine
            .query(self.clock.now())
            .map_err(DriverError::Request)?;
        match self.run()? {
            Outcome::Current(c) => Ok(c),
            Outcome::Failed(e) => Err(e),
            Outcome::Selected(_) => Err(DriverError::Timeout),
        }
    }
}

//! The blocking I/O shell (feature `serial`): the [`MuxShell`] run by
//! [`ima_serial::blocking::Blocking`] over any `Read + Write` stream (a port from
//! [`open_port`], or one wrapped in [`FixedBaud`]), for simple tools without an async
//! runtime. [`BlockingVideoMux`] implements [`ima_hal::blocking::CameraMux`], the blocking
//! mirror of [`ima_hal::camera::CameraMux`].

use std::io::{Read, Write};
use std::time::Duration;

use ima_hal::blocking;
use ima_hal::camera::{Channel, Selection};
use ima_hal::time::SharedClock;
use ima_hal::{ErrorType, Instant};
use ima_serial::blocking::Blocking;
pub use ima_serial::{BaudControl, FixedBaud};

pub use crate::driver::DriverError;
use crate::machine::{Config, Stats};
use crate::shell::{MuxShell, Request, Watches, request_timeout};
/// Open a serial port for the blocking shell: `baud` 8N1, no flow control, 10 ms timeout.
pub use ima_serial::open_blocking_port as open_port;

/// A switcher driven synchronously.
#[derive(Debug)]
pub struct BlockingVideoMux<S> {
    run: Blocking<MuxShell, S>,
    w: Watches,
    config: Config,
}

impl<S: Read + Write + BaudControl> BlockingVideoMux<S> {
    /// A driver on `stream`, with `clock` as its time; nothing is sent until a request.
    pub fn new(stream: S, config: Config, clock: SharedClock) -> Self {
        let (shell, w) = MuxShell::new(config);
        let run = Blocking::new(shell, stream, clock);
        Self { run, w, config }
    }

    /// The settings.
    #[must_use]
    pub fn config(&self) -> &Config {
        &self.config
    }

    /// Counters.
    #[must_use]
    pub fn stats(&self) -> Stats {
        *self.w.stats.borrow()
    }

    /// The driver's clock.
    #[must_use]
    pub fn now(&self) -> Instant {
        self.run.now()
    }
}

impl<S> ErrorType for BlockingVideoMux<S> {
    type Error = DriverError;
}

impl<S: Read + Write + BaudControl> blocking::CameraMux for BlockingVideoMux<S> {
    fn channel_count(&self) -> Channel {
        self.config.channel_count
    }

    fn settle_time(&self) -> Duration {
        self.config.settle_time
    }

    /// Switch to `channel` and wait for the switcher's confirmation (with retries).
    fn select(&mut self, channel: Channel) -> Result<Selection, DriverError> {
        let make = |tx| Request::Select(channel, tx);
        self.run.request(make, request_timeout(&self.config))
    }

    /// Ask the switcher which channel is selected.
    fn current_channel(&mut self) -> Result<Option<Channel>, DriverError> {
        self.run
            .request(Request::Query, request_timeout(&self.config))
    }
}

//! The I/O shell (feature `tokio`): [`MuxShell`] turns the sans-IO [`Machine`]'s events into
//! answers and notices, and cloneable [`VideoMux`] handles implement
//! [`ima_hal::camera::CameraMux`]; [`ima_serial::runner`] does the I/O, and blocking code
//! uses `ima_serial::blocking::Blocking<VideoMux>`.
//!
//! The stream is any `AsyncRead + AsyncWrite` (a `tokio_serial::SerialStream` from
//! [`open_port`], or an in-memory duplex in tests). The machine serves one request at a
//! time; a second handle asking while one is pending gets
//! [`RequestError::Busy`].

use std::time::Duration;

use ima_hal::ErrorType;
use ima_hal::camera::{CameraMux, Channel, Selection};
use ima_serial::handle::{Handle, Pending};
use ima_serial::runner::Shell;
use ima_serial::{BaudControl, FixedBaud};
use tokio::io::{AsyncRead, AsyncWrite};
use tokio::sync::watch;

pub use crate::driver::{DriverError, Fault};
use crate::machine::{Config, Event, Machine, RequestError, Stats};
/// The process's one clock, passed to `spawn`: every stamp the driver produces is on it.
pub use ima_hal::time::{Clock, SharedClock, TokioClock};
/// The calls every driver handle answers alike: `link`, `stats`, `now`, `halt_signal`, `close`.
pub use ima_serial::handle::Driver;
/// Open a serial port for the shell: `baud` (Extron default 9600) 8N1, no flow control.
pub use ima_serial::open_port;

/// Something the switcher said on its own (front panel, power-on, signal change).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Notice {
    /// A selection nobody here asked for.
    ExternalSelect(Channel),
    /// The power-on banner.
    Banner,
    /// An error reply with no request pending.
    UnsolicitedError(crate::machine::Refusal),
    /// Signal presence.
    Signals(crate::wire::Signals),
    /// Video mute state.
    Mute(bool),
}

/// The link as handles see it (a switcher is never handshaken: it stays `Connecting` until
/// the task ends).
pub type LinkStatus = ima_serial::LinkStatus<(), DriverError>;

/// Machine events → answers and notices.
#[derive(Debug)]
pub struct MuxShell {
    machine: Machine,
    link: watch::Sender<LinkStatus>,
    current: watch::Sender<Option<Channel>>,
    notices: watch::Sender<Option<Notice>>,
    /// The selection waiting for the switcher's answer (the machine runs one request at a
    /// time: a selection or a query).
    select: Pending<Selection, Self>,
    /// The query waiting for the switcher's answer.
    query: Pending<Option<Channel>, Self>,
}

impl Shell for MuxShell {
    type Machine = Machine;
    type Fault = Fault;
    type Up = ();
    type Stats = Stats;
    const MAX_FRAME: usize = 16;

    fn machine(&mut self) -> &mut Machine {
        &mut self.machine
    }

    fn link(&self) -> &watch::Sender<LinkStatus> {
        &self.link
    }

    fn on_event(&mut self, ev: Event, _line: &mut dyn BaudControl) -> std::io::Result<()> {
        let notice = |n| Some(Some(n));
        let n = match ev {
            Event::Selected(sel) => {
                self.current.send_replace(Some(sel.channel));
                self.select.answer(Ok(sel));
                None
            }
            Event::SelectFailed { failure, .. } => {
                self.select.answer(Err(failure.into()));
                None
            }
            Event::Current { channel } => {
                self.current.send_replace(channel);
                self.query.answer(Ok(channel));
                None
            }
            Event::QueryFailed { failure } => {
                self.query.answer(Err(failure.into()));
                None
            }
            Event::Settled { .. } => None,
            Event::ExternalSelect { channel } => {
                self.current.send_replace(Some(channel));
                notice(Notice::ExternalSelect(channel))
            }
            Event::UnsolicitedError(r) => notice(Notice::UnsolicitedError(r)),
            Event::Signals(s) => notice(Notice::Signals(s)),
            Event::Mute(m) => notice(Notice::Mute(m)),
            Event::Banner => notice(Notice::Banner),
        };
        if let Some(n) = n {
            self.notices.send_replace(n);
        }
        Ok(())
    }

    fn stats(&self) -> Stats {
        self.machine.stats()
    }
}

/// A handle to a running switcher driver. Cheap to clone.
#[derive(Debug, Clone)]
pub struct VideoMux {
    h: Handle<MuxShell>,
    current: watch::Receiver<Option<Channel>>,
    notices: watch::Receiver<Option<Notice>>,
    config: Config,
}

impl VideoMux {
    /// Spawn the driver task on `stream`. Nothing is sent until a request. Must be called
    /// inside a tokio runtime.
    ///
    /// `clock` is the process's one time base: every reading's stamp is taken on it.
    #[must_use]
    pub fn spawn<S>(stream: S, config: Config, clock: SharedClock) -> Self
    where
        S: AsyncRead + AsyncWrite + Unpin + Send + 'static,
    {
        let (current_tx, current) = watch::channel(None);
        let (notices_tx, notices) = watch::channel(None);
        let shell = MuxShell {
            machine: Machine::new(config),
            link: watch::channel(LinkStatus::Connecting).0,
            current: current_tx,
            notices: notices_tx,
            select: Pending::default(),
            query: Pending::default(),
        };
        Self {
            h: Handle::spawn(shell, FixedBaud(stream), clock, None),
            current,
            notices,
            config,
        }
    }

    /// The settings.
    #[must_use]
    pub fn config(&self) -> &Config {
        &self.config
    }

    /// The channel last confirmed or reported by the switcher, without asking it.
    #[must_use]
    pub fn known_channel(&self) -> Option<Channel> {
        *self.current.borrow()
    }

    /// The last unsolicited message, if any.
    #[must_use]
    pub fn last_notice(&self) -> Option<Notice> {
        *self.notices.borrow()
    }

    /// How long a request may take: every attempt, plus slack for a loaded machine.
    fn request_timeout(&self) -> Duration {
        let c = &self.config;
        (c.reply_timeout
            .saturating_mul(u32::from(c.retries).saturating_add(1)))
        .saturating_add(Duration::from_secs(2))
    }
}

impl Driver for VideoMux {
    type Shell = MuxShell;
    const CLOSE_LIMIT: Duration = Duration::from_secs(2);
    fn handle(&self) -> &Handle<MuxShell> {
        &self.h
    }
}

impl ErrorType for VideoMux {
    type Error = DriverError;
}

impl CameraMux for VideoMux {
    fn channel_count(&self) -> Channel {
        self.config.channel_count
    }

    fn settle_time(&self) -> Duration {
        self.config.settle_time
    }

    async fn select(&mut self, channel: Channel) -> Result<Selection, DriverError> {
        let f = move |s: &mut MuxShell, now, tx| {
            let r = s.machine.select(channel, now).map_err(Into::into);
            s.select.wait(r, tx, RequestError::Busy.into());
        };
        self.h.defer(self.request_timeout(), f).await
    }

    async fn current_channel(&mut self) -> Result<Option<Channel>, DriverError> {
        let f = |s: &mut MuxShell, now, tx| {
            let r = s.machine.query(now).map_err(Into::into);
            s.query.wait(r, tx, RequestError::Busy.into());
        };
        self.h.defer(self.request_timeout(), f).await
    }
}

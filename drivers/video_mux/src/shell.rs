//! The async I/O shell (feature `tokio`): one task owns the byte stream and the sans-IO
//! [`Machine`]; cloneable [`VideoMux`] handles talk to it and implement
//! [`ima_hal::camera::CameraMux`].
//!
//! Generic over any `AsyncRead + AsyncWrite` stream (a `tokio_serial::SerialStream` from
//! [`open_port`], or an in-memory duplex in tests). One `select!` over the stream, the
//! machine's next timer and the handles' requests. Time is tokio time ([`TokioClock`]), so
//! tests can run in paused virtual time. The machine serves one request at a time; a second
//! handle asking while one is pending gets [`RequestError::Busy`](crate::machine::RequestError::Busy).

use std::time::Duration;

use ima_hal::camera::{CameraMux, Channel, Selection};
use ima_hal::{ErrorType, Instant};
use ima_serial::runner::{self, End, Flow, Shell};
use ima_serial::{BaudControl, FixedBaud};
use tokio::io::{AsyncRead, AsyncWrite};
use tokio::sync::{mpsc, oneshot, watch};

pub use crate::driver::DriverError;
use crate::machine::{Config, Event, Machine, RequestError, Stats};
/// Open a serial port for the shell: `baud` (Extron default 9600) 8N1, no flow control.
pub use ima_serial::open_port;

/// The clock types a shell takes: the caller passes the process's one [`SharedClock`]
/// (usually a [`TokioClock`], so paused tests run in virtual time) to `connect`, and every
/// stamp the driver produces is on that time line.
pub use ima_hal::time::{Clock, SharedClock, TokioClock};

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

type Answer<T> = oneshot::Sender<Result<T, DriverError>>;

/// A request from a handle to the driver task.
#[derive(Debug)]
pub enum Request {
    /// Select an input.
    Select(Channel, Answer<Selection>),
    /// Ask which input is selected.
    Query(Answer<Option<Channel>>),
    /// End the task.
    Close(Answer<()>),
}

#[derive(Debug)]
enum Waiter {
    Select(Answer<Selection>),
    Query(Answer<Option<Channel>>),
}

/// The receiving ends of what [`MuxShell`] publishes.
#[derive(Debug, Clone)]
pub(crate) struct Watches {
    pub(crate) current: watch::Receiver<Option<Channel>>,
    pub(crate) notices: watch::Receiver<Option<Notice>>,
    pub(crate) stats: watch::Receiver<Stats>,
}

/// Machine events → readings and answers, for both shells.
#[derive(Debug)]
pub struct MuxShell {
    machine: Machine,
    current_tx: watch::Sender<Option<Channel>>,
    notice_tx: watch::Sender<Option<Notice>>,
    stats_tx: watch::Sender<Stats>,
    waiter: Option<Waiter>,
}

impl MuxShell {
    pub(crate) fn new(config: Config) -> (Self, Watches) {
        let (current_tx, current) = watch::channel(None);
        let (notice_tx, notices) = watch::channel(None);
        let (stats_tx, stats) = watch::channel(Stats::default());
        let shell = Self {
            machine: Machine::new(config),
            current_tx,
            notice_tx,
            stats_tx,
            waiter: None,
        };
        let w = Watches {
            current,
            notices,
            stats,
        };
        (shell, w)
    }

    /// Wait for the machine's answer with `tx`, or refuse at once.
    fn wait(&mut self, r: Result<(), RequestError>, waiter: Waiter) {
        let e = match r {
            Ok(()) if self.waiter.is_none() => {
                self.waiter = Some(waiter);
                return;
            }
            Ok(()) => DriverError::Request(RequestError::Busy),
            Err(e) => DriverError::Request(e),
        };
        match waiter {
            Waiter::Select(tx) => drop(tx.send(Err(e))),
            Waiter::Query(tx) => drop(tx.send(Err(e))),
        }
    }
}

impl Shell for MuxShell {
    type Machine = Machine;
    type Request = Request;
    const MAX_FRAME: usize = 16;

    fn machine(&mut self) -> &mut Machine {
        &mut self.machine
    }

    fn on_event(&mut self, ev: Event, _line: &mut dyn BaudControl) -> std::io::Result<()> {
        let notice = |n| Some(Some(n));
        let n = match ev {
            Event::Selected(sel) => {
                self.current_tx.send_replace(Some(sel.channel));
                if let Some(Waiter::Select(w)) = self.waiter.take() {
                    let _ = w.send(Ok(sel));
                }
                None
            }
            Event::SelectFailed { failure, .. } => {
                if let Some(Waiter::Select(w)) = self.waiter.take() {
                    let _ = w.send(Err(failure.into()));
                }
                None
            }
            Event::Current { channel } => {
                self.current_tx.send_replace(channel);
                if let Some(Waiter::Query(w)) = self.waiter.take() {
                    let _ = w.send(Ok(channel));
                }
                None
            }
            Event::QueryFailed { failure } => {
                if let Some(Waiter::Query(w)) = self.waiter.take() {
                    let _ = w.send(Err(failure.into()));
                }
                None
            }
            Event::Settled { .. } => None,
            Event::ExternalSelect { channel } => {
                self.current_tx.send_replace(Some(channel));
                notice(Notice::ExternalSelect(channel))
            }
            Event::UnsolicitedError(r) => notice(Notice::UnsolicitedError(r)),
            Event::Signals(s) => notice(Notice::Signals(s)),
            Event::Mute(m) => notice(Notice::Mute(m)),
            Event::Banner => notice(Notice::Banner),
        };
        if let Some(n) = n {
            self.notice_tx.send_replace(n);
        }
        Ok(())
    }

    fn on_request(&mut self, req: Request, now: Instant) -> Flow {
        match req {
            Request::Select(ch, tx) => {
                let r = self.machine.select(ch, now);
                self.wait(r, Waiter::Select(tx));
            }
            Request::Query(tx) => {
                let r = self.machine.query(now);
                self.wait(r, Waiter::Query(tx));
            }
            Request::Close(done) => {
                let _ = done.send(Ok(()));
                return Flow::Close;
            }
        }
        Flow::Continue
    }

    fn after_round(&mut self) {
        self.stats_tx.send_replace(self.machine.stats());
    }

    fn end(&mut self, how: End) {
        let e = how.error();
        match self.waiter.take() {
            Some(Waiter::Select(w)) => drop(w.send(Err(e))),
            Some(Waiter::Query(w)) => drop(w.send(Err(e))),
            None => {}
        }
    }
}

/// A handle to a running switcher driver. Cheap to clone.
#[derive(Debug, Clone)]
pub struct VideoMux {
    tx: mpsc::Sender<Request>,
    w: Watches,
    config: Config,
    clock: SharedClock,
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
        let (shell, w) = MuxShell::new(config);
        let tx = runner::spawn(shell, FixedBaud(stream), clock.clone(), None);
        Self {
            tx,
            w,
            config,
            clock,
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
        *self.w.current.borrow()
    }

    /// The last unsolicited message, if any.
    #[must_use]
    pub fn last_notice(&self) -> Option<Notice> {
        *self.w.notices.borrow()
    }

    /// Session counters.
    #[must_use]
    pub fn stats(&self) -> Stats {
        *self.w.stats.borrow()
    }

    /// The driver's clock (the time base of [`Selection`] stamps).
    #[must_use]
    pub fn now(&self) -> Instant {
        self.clock.now()
    }

    async fn request<T>(&self, make: impl FnOnce(Answer<T>) -> Request) -> Result<T, DriverError> {
        runner::request(&self.tx, make, request_timeout(&self.config)).await
    }

    /// End the driver task.
    pub async fn close(&self) {
        let _ = runner::request(&self.tx, Request::Close, Duration::from_secs(2)).await;
    }
}

/// How long a request may take: every attempt, plus slack for a loaded machine.
pub(crate) fn request_timeout(config: &Config) -> Duration {
    config
        .reply_timeout
        .saturating_mul(u32::from(config.retries).saturating_add(1))
        .saturating_add(Duration::from_secs(2))
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
        self.request(|tx| Request::Select(channel, tx)).await
    }

    async fn current_channel(&mut self) -> Result<Option<Channel>, DriverError> {
        self.request(Request::Query).await
    }
}

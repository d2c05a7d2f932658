//! The async I/O shell (feature `tokio`): one task owns the byte stream and the sans-IO
//! [`Machine`]; cloneable [`VideoMux`] handles talk to it and implement
//! [`ima_hal::camera::CameraMux`].
//!
//! Generic over any `AsyncRead + AsyncWrite` stream (a `tokio_serial::SerialStream` from
//! [`open_port`], or an in-memory duplex in tests). One `select!` over the stream, the
//! machine's next timer and the handles' requests. Time is tokio time ([`TokioClock`]), so
//! tests can run in paused virtual time. The machine serves one request at a time; a second
//! handle asking while one is pending gets [`RequestError::Busy`](crate::machine::RequestError::Busy).

use std::io;
use std::time::Duration;

use ima_hal::camera::{CameraMux, Channel, Selection};
use ima_hal::{ErrorType, Instant};
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::sync::{mpsc, oneshot, watch};

pub use crate::driver::DriverError;
use crate::machine::{Config, Event, Machine, Stats};

/// Open a serial port for the shell: `baud` (Extron default 9600) 8N1, no flow control.
///
/// A path that is not a serial port (a regular file, `/dev/null`) fails with
/// [`io::ErrorKind::InvalidInput`] and `PATH is not a serial port (…)`.
pub fn open_port(path: &str, baud: u32) -> io::Result<tokio_serial::SerialStream> {
    use tokio_serial::SerialPortBuilderExt;
    tokio_serial::new(path, baud)
        .data_bits(tokio_serial::DataBits::Eight)
        .parity(tokio_serial::Parity::None)
        .stop_bits(tokio_serial::StopBits::One)
        .flow_control(tokio_serial::FlowControl::None)
        .open_native_async()
        .map_err(|e| ima_hal::serial::explain_open_error(path, io::Error::from(e)))
}

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

enum Request {
    Select(Channel, oneshot::Sender<Result<Selection, DriverError>>),
    Query(oneshot::Sender<Result<Option<Channel>, DriverError>>),
    Close(oneshot::Sender<()>),
}

impl std::fmt::Debug for Request {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Request")
    }
}

enum Waiter {
    Select(oneshot::Sender<Result<Selection, DriverError>>),
    Query(oneshot::Sender<Result<Option<Channel>, DriverError>>),
}

/// A handle to a running switcher driver. Cheap to clone.
#[derive(Debug, Clone)]
pub struct VideoMux {
    tx: mpsc::Sender<Request>,
    current: watch::Receiver<Option<Channel>>,
    notices: watch::Receiver<Option<Notice>>,
    stats: watch::Receiver<Stats>,
    config: Config,
    clock: SharedClock,
}

impl VideoMux {
    /// Spawn the driver task on `stream`. Nothing is sent until a request. Must be called
    /// inside a tokio runtime.
    #[must_use]
    ///
    /// `clock` is the process's one time base: every reading's stamp is taken on it.
    pub fn spawn<S>(stream: S, config: Config, clock: SharedClock) -> Self
    where
        S: AsyncRead + AsyncWrite + Unpin + Send + 'static,
    {
        let (tx, rx) = mpsc::channel(8);
        let (current_tx, current) = watch::channel(None);
        let (notice_tx, notices) = watch::channel(None);
        let (stats_tx, stats) = watch::channel(Stats::default());
        let task = Task {
            machine: Machine::new(config),
            clock: clock.clone(),
            rx,
            current_tx,
            notice_tx,
            stats_tx,
            waiter: None,
        };
        tokio::spawn(task.run(stream));
        Self {
            tx,
            current,
            notices,
            stats,
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
        *self.current.borrow()
    }

    /// The last unsolicited message, if any.
    #[must_use]
    pub fn last_notice(&self) -> Option<Notice> {
        *self.notices.borrow()
    }

    /// Session counters.
    #[must_use]
    pub fn stats(&self) -> Stats {
        *self.stats.borrow()
    }

    /// The driver's clock (the time base of [`Selection`] stamps).
    #[must_use]
    pub fn now(&self) -> Instant {
        self.clock.now()
    }

    fn request_timeout(&self) -> Duration {
        // Every attempt, plus slack for a loaded machine.
        self.config
            .reply_timeout
            .saturating_mul(u32::from(self.config.retries).saturating_add(1))
            .saturating_add(Duration::from_secs(2))
    }

    async fn request<T>(
        &self,
        make: impl FnOnce(oneshot::Sender<Result<T, DriverError>>) -> Request,
    ) -> Result<T, DriverError> {
        let (tx, rx) = oneshot::channel();
        self.tx
            .send(make(tx))
            .await
            .map_err(|_| DriverError::Disconnected)?;
        match tokio::time::timeout(self.request_timeout(), rx).await {
            Ok(Ok(r)) => r,
            Ok(Err(_)) => Err(DriverError::Disconnected),
            Err(_) => Err(DriverError::Timeout),
        }
    }

    /// End the driver task.
    pub async fn close(&self) {
        let (tx, rx) = oneshot::channel();
        if self.tx.send(Request::Close(tx)).await.is_ok() {
            let _ = tokio::time::timeout(Duration::from_secs(2), rx).await;
        }
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
        self.request(|tx| Request::Select(channel, tx)).await
    }

    async fn current_channel(&mut self) -> Result<Option<Channel>, DriverError> {
        self.request(Request::Query).await
    }
}

struct Task {
    machine: Machine,
    clock: SharedClock,
    rx: mpsc::Receiver<Request>,
    current_tx: watch::Sender<Option<Channel>>,
    notice_tx: watch::Sender<Option<Notice>>,
    stats_tx: watch::Sender<Stats>,
    waiter: Option<Waiter>,
}

impl Task {
    async fn run<S>(mut self, mut stream: S)
    where
        S: AsyncRead + AsyncWrite + Unpin + Send + 'static,
    {
        let mut rbuf = [0u8; 256];
        let mut tbuf = [0u8; 16];
        loop {
            self.drain_events();
            while let Some(n) = self.machine.poll_transmit(&mut tbuf) {
                let Some(cmd) = tbuf.get(..n) else { break };
                if let Err(e) = stream.write_all(cmd).await {
                    self.fail(DriverError::Io(e.kind()));
                    return;
                }
            }
            let _ = stream.flush().await;
            self.stats_tx.send_replace(self.machine.stats());
            let sleep_for = self
                .machine
                .poll_timeout()
                .map_or(Duration::from_secs(1), |t| {
                    t.saturating_duration_since(self.clock.now())
                });
            tokio::select! {
                r = stream.read(&mut rbuf) => match r {
                    Ok(0) => { self.fail(DriverError::Disconnected); return; }
                    Ok(n) => {
                        let now = self.clock.now();
                        self.machine.handle_bytes(rbuf.get(..n).unwrap_or(&[]), now);
                    }
                    Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                    Err(e) => { self.fail(DriverError::Io(e.kind())); return; }
                },
                () = tokio::time::sleep(sleep_for) => {
                    self.machine.handle_timeout(self.clock.now());
                }
                req = self.rx.recv() => match req {
                    None => { self.fail(DriverError::Disconnected); return; }
                    Some(Request::Close(done)) => {
                        self.fail(DriverError::Disconnected);
                        let _ = done.send(());
                        return;
                    }
                    Some(req) => self.handle_request(req),
                },
            }
        }
    }

    fn fail(&mut self, e: DriverError) {
        match self.waiter.take() {
            Some(Waiter::Select(w)) => {
                let _ = w.send(Err(e));
            }
            Some(Waiter::Query(w)) => {
                let _ = w.send(Err(e));
            }
            None => {}
        }
    }

    fn handle_request(&mut self, req: Request) {
        let now = self.clock.now();
        match req {
            Request::Select(ch, tx) => match self.machine.select(ch, now) {
                Ok(()) if self.waiter.is_none() => self.waiter = Some(Waiter::Select(tx)),
                Ok(()) | Err(crate::machine::RequestError::Busy) => {
                    let _ = tx.send(Err(DriverError::Request(
                        crate::machine::RequestError::Busy,
                    )));
                }
                Err(e) => {
                    let _ = tx.send(Err(DriverError::Request(e)));
                }
            },
            Request::Query(tx) => match self.machine.query(now) {
                Ok(()) if self.waiter.is_none() => self.waiter = Some(Waiter::Query(tx)),
                Ok(()) => {
                    let _ = tx.send(Err(DriverError::Request(
                        crate::machine::RequestError::Busy,
                    )));
                }
                Err(e) => {
                    let _ = tx.send(Err(DriverError::Request(e)));
                }
            },
            Request::Close(done) => {
                let _ = done.send(());
            }
        }
    }

    fn drain_events(&mut self) {
        while let Some(ev) = self.machine.poll_event() {
            match ev {
                Event::Selected(sel) => {
                    self.current_tx.send_replace(Some(sel.channel));
                    if let Some(Waiter::Select(w)) = self.waiter.take() {
                        let _ = w.send(Ok(sel));
                    }
                }
                Event::SelectFailed { failure, .. } => {
                    if let Some(Waiter::Select(w)) = self.waiter.take() {
                        let _ = w.send(Err(failure.into()));
                    }
                }
                Event::Current { channel } => {
                    self.current_tx.send_replace(channel);
                    if let Some(Waiter::Query(w)) = self.waiter.take() {
                        let _ = w.send(Ok(channel));
                    }
                }
                Event::QueryFailed { failure } => {
                    if let Some(Waiter::Query(w)) = self.waiter.take() {
                        let _ = w.send(Err(failure.into()));
                    }
                }
                Event::Settled { .. } => {}
                Event::ExternalSelect { channel } => {
                    self.current_tx.send_replace(Some(channel));
                    self.notice_tx
                        .send_replace(Some(Notice::ExternalSelect(channel)));
                }
                Event::UnsolicitedError(r) => {
                    self.notice_tx
                        .send_replace(Some(Notice::UnsolicitedError(r)));
                }
                Event::Signals(s) => {
                    self.notice_tx.send_replace(Some(Notice::Signals(s)));
                }
                Event::Mute(m) => {
                    self.notice_tx.send_replace(Some(Notice::Mute(m)));
                }
                Event::Banner => {
                    self.notice_tx.send_replace(Some(Notice::Banner));
                }
            }
        }
    }
}

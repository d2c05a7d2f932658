//! What every driver handle does the same way (feature `tokio`): spawn the task, wait for
//! the link, run calls on the shell with a timeout, wait for readings, close.
//!
//! A driver's public handle (`P2os`, `SickLms`, …) holds a [`Handle`] of its shell plus the
//! receivers of the readings it publishes, and implements the `ima-hal` traits on top.

use std::time::Duration;

use ima_hal::safety::{HaltSignal, StopRegistry};
use ima_hal::time::SharedClock;
use ima_hal::{Instant, Stamped};
use tokio::io::{AsyncRead, AsyncWrite};
use tokio::sync::{mpsc, oneshot, watch};

use crate::runner::{self, Error, Msg, Reply, Shell, Status};
use crate::{BaudControl, DriverError, LinkError, LinkStatus};

/// What every driver's public handle offers beside its device's own calls: the link, the
/// counters, the clock, the halt signal, and closing. A handle implements it by naming the
/// [`Handle`] it holds and how long closing may take; the methods come with the trait, so
/// the five drivers answer them alike (`use ima_serial::handle::Driver`, re-exported by
/// every driver crate). A handle may refine [`stats`](Driver::stats) (the SICK driver adds
/// the scans its handles can see).
pub trait Driver {
    /// The shell the driver's task runs.
    type Shell: Shell;

    /// The longest [`close`](Driver::close) waits for the last frames to be written and the
    /// port released.
    const CLOSE_LIMIT: Duration;

    /// The handle of the driver's task, for the methods below (hidden: calling the shell
    /// through it would bypass the driver's own API).
    #[doc(hidden)]
    fn handle(&self) -> &Handle<Self::Shell>;

    /// The link's status now (a driver that only answers requests, such as the video
    /// switcher, stays `Connecting`: it has no stream to be up).
    #[must_use]
    fn link(&self) -> Status<Self::Shell> {
        self.handle().link()
    }

    /// The driver's counters as last published.
    #[must_use]
    fn stats(&self) -> <Self::Shell as Shell>::Stats {
        self.handle().stats()
    }

    /// Now, on the driver's clock (the time base of every stamp it produces).
    #[must_use]
    fn now(&self) -> Instant {
        self.handle().now()
    }

    /// The driver's halt signal: [`HaltSignal::halt`] does what [`close`](Driver::close)
    /// does (a base stops first), from any thread and without awaiting.
    #[must_use]
    fn halt_signal(&self) -> HaltSignal {
        self.handle().halt_signal()
    }

    /// Write the device's last frames (a base: STOP, then its close or shutdown sequence),
    /// release the port and end the task, waiting at most [`Driver::CLOSE_LIMIT`]. Closing a
    /// driver already closed is `Ok`; dropping every handle closes it in the background.
    /// `Ok` says the frames were written, not that the device took them: whether it may not
    /// have (its link was down, or it went on sending) is on the
    /// [`halt_signal`](Driver::halt_signal) ([`HaltSignal::stopped_unheard`]).
    ///
    /// # Errors
    /// `Timeout` if the last frames were not all written in time, or the link's failure.
    fn close(&self) -> impl Future<Output = Result<(), Error<Self::Shell>>> + Send
    where
        Self: Sync,
    {
        self.handle().close(Self::CLOSE_LIMIT)
    }
}

/// A cloneable handle to the task running shell `D`. Dropping every handle closes the
/// task (the shell's last frames are written, then the port is released).
pub struct Handle<D: Shell> {
    tx: mpsc::Sender<Msg<D>>,
    link: watch::Receiver<Status<D>>,
    stats: watch::Receiver<D::Stats>,
    clock: SharedClock,
    halt: HaltSignal,
}

impl<D: Shell> Clone for Handle<D> {
    fn clone(&self) -> Self {
        Self {
            tx: self.tx.clone(),
            link: self.link.clone(),
            stats: self.stats.clone(),
            clock: self.clock.clone(),
            halt: self.halt.clone(),
        }
    }
}

impl<D: Shell> core::fmt::Debug for Handle<D> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Handle")
            .field("device", &<D::Fault as crate::Fault>::DEVICE)
            .field("closed", &self.tx.is_closed())
            .finish_non_exhaustive()
    }
}

impl<D: Shell> Handle<D> {
    /// Spawn the task running `shell` over `stream` on the current tokio runtime, with
    /// `clock` as its time. With `stop_as`, the task's [`HaltSignal`] is registered under
    /// that name in [`StopRegistry::global`], so a program's exit guard can stop the device
    /// from any exit path (every device that can move registers).
    pub fn spawn<S>(shell: D, stream: S, clock: SharedClock, stop_as: Option<&str>) -> Self
    where
        S: AsyncRead + AsyncWrite + BaudControl + Unpin + Send + 'static,
    {
        let halt = HaltSignal::new();
        if let Some(name) = stop_as {
            if let Some(w) = D::WATCHDOG {
                halt.set_watchdog(w);
            }
            StopRegistry::global().register(name, halt.clone());
        }
        let link = shell.link().subscribe();
        let (stats_tx, stats) = watch::channel(shell.stats());
        let (tx, rx) = mpsc::channel(32);
        let task = runner::run(shell, stream, rx, stats_tx, clock.clone(), halt.clone());
        tokio::spawn(task);
        Self {
            tx,
            link,
            stats,
            clock,
            halt,
        }
    }

    /// [`spawn`](Self::spawn), then wait until the link is connected (what it reports),
    /// failed, or `timeout` passes: then the shell says what the line carried
    /// ([`Shell::no_answer`]) and the task is closed.
    ///
    /// # Errors
    /// The link's failure, or the shell's account of a silent or foreign line.
    pub async fn connect<S>(
        shell: D,
        stream: S,
        clock: SharedClock,
        timeout: Duration,
        stop_as: Option<&str>,
    ) -> Result<(Self, D::Up), Error<D>>
    where
        S: AsyncRead + AsyncWrite + BaudControl + Unpin + Send + 'static,
    {
        let h = Self::spawn(shell, stream, clock, stop_as);
        match h.wait_connected(timeout).await {
            Ok(up) => Ok((h, up)),
            Err(DriverError::Timeout) => {
                let e = h
                    .call(Duration::from_secs(1), |d, _| Ok(d.no_answer()))
                    .await;
                let _ = h.tx.try_send(Msg::Close(oneshot::channel().0));
                Err(e.unwrap_or_else(|e| e))
            }
            Err(e) => Err(e),
        }
    }

    /// Wait until the link is connected (what it reports) or failed, at most `timeout`.
    ///
    /// # Errors
    /// The link's failure; [`DriverError::Disconnected`] once closed; `Timeout`.
    pub async fn wait_connected(&self, timeout: Duration) -> Result<D::Up, Error<D>> {
        let link = self.link.clone();
        self.wait_for(&link, timeout, |s| match s {
            LinkStatus::Connected(u) => Some(Ok(u.clone())),
            LinkStatus::Closed => Some(Err(LinkError::Disconnected.into())),
            _ => None,
        })
        .await?
    }

    /// The link's status now.
    #[must_use]
    pub fn link(&self) -> Status<D> {
        self.link.borrow().clone()
    }

    /// The shell's counters as last published (after the task's latest round).
    #[must_use]
    pub fn stats(&self) -> D::Stats {
        self.stats.borrow().clone()
    }

    /// The process's clock this driver stamps with.
    #[must_use]
    pub fn clock(&self) -> &SharedClock {
        &self.clock
    }

    /// Now, on the driver's clock.
    #[must_use]
    pub fn now(&self) -> Instant {
        self.clock.now()
    }

    /// The task's halt signal: [`HaltSignal::halt`] closes the device (its last frames,
    /// e.g. STOP) from any thread without awaiting.
    #[must_use]
    pub fn halt_signal(&self) -> HaltSignal {
        self.halt.clone()
    }

    /// Run `f` on the shell inside the task and wait for its answer, at most `timeout`.
    ///
    /// # Errors
    /// `f`'s error; `Disconnected` if the task is gone, `Timeout` if it did not answer.
    pub async fn call<T: Send + 'static>(
        &self,
        timeout: Duration,
        f: impl FnOnce(&mut D, Instant) -> Result<T, Error<D>> + Send + 'static,
    ) -> Result<T, Error<D>> {
        self.defer(timeout, move |d, now, reply| {
            let _ = reply.send(f(d, now));
        })
        .await
    }

    /// Run `f` on the shell inside the task; it answers through the [`Reply`] it is given,
    /// at once or later (a shell keeps the reply until the device confirms). Waits at
    /// most `timeout`.
    ///
    /// # Errors
    /// The answer's error; `Disconnected` if the task is gone or dropped the reply,
    /// `Timeout` if no answer came in time.
    pub async fn defer<T: Send + 'static>(
        &self,
        timeout: Duration,
        f: impl FnOnce(&mut D, Instant, Reply<T, D>) + Send + 'static,
    ) -> Result<T, Error<D>> {
        let (reply, rx) = oneshot::channel();
        let call = Box::new(move |d: &mut D, now| f(d, now, reply));
        self.tx
            .send(Msg::Call(call))
            .await
            .map_err(|_| LinkError::Disconnected)?;
        match tokio::time::timeout(timeout, rx).await {
            Ok(Ok(r)) => r,
            Ok(Err(_)) => Err(LinkError::Disconnected.into()),
            Err(_) => Err(LinkError::Timeout.into()),
        }
    }

    /// Close: the shell writes its last frames (bounded by [`Shell::begin_close`]), the
    /// port is released, and this returns, waiting at most `limit`. Closing a task that
    /// has already ended is `Ok`.
    ///
    /// # Errors
    /// `Timeout` if the last frames were not all written in time (or `limit` passed), or
    /// the link's failure.
    pub async fn close(&self, limit: Duration) -> Result<(), Error<D>> {
        let (tx, rx) = oneshot::channel();
        if self.halt.is_done() || self.tx.send(Msg::Close(tx)).await.is_err() {
            return Ok(());
        }
        match tokio::time::timeout(limit, rx).await {
            Ok(Ok(r)) => Ok(r?),
            // The task ended between the check and the request (a halt or the link).
            Ok(Err(_)) => Ok(()),
            Err(_) => Err(LinkError::Timeout.into()),
        }
    }

    /// Wait until `pick` finds what it wants in `rx`'s value (checked at once, then on
    /// every change), at most `timeout`; a link that fails meanwhile ends the wait with its
    /// error.
    ///
    /// # Errors
    /// `Timeout`; the link's failure; `Disconnected` if the task is gone.
    pub async fn wait_for<T, R>(
        &self,
        rx: &watch::Receiver<T>,
        timeout: Duration,
        mut pick: impl FnMut(&T) -> Option<R>,
    ) -> Result<R, Error<D>> {
        let mut rx = rx.clone();
        let mut link = self.link.clone();
        let wait = async move {
            loop {
                if let Some(r) = pick(&rx.borrow_and_update()) {
                    return Ok(r);
                }
                if let LinkStatus::Failed(e) = &*link.borrow_and_update() {
                    return Err(e.clone());
                }
                tokio::select! {
                    r = rx.changed() => r.map_err(|_| LinkError::Disconnected)?,
                    r = link.changed() => r.map_err(|_| LinkError::Disconnected)?,
                }
            }
        };
        tokio::time::timeout(timeout, wait)
            .await
            .map_err(|_| DriverError::Timeout)?
    }

    /// The reading in `rx` stamped after `after` (any reading with `None`), waiting at
    /// most `timeout` (see [`wait_for`](Self::wait_for)).
    ///
    /// # Errors
    /// As [`wait_for`](Self::wait_for).
    pub async fn reading<T: Clone>(
        &self,
        rx: &SlotRx<T>,
        after: Option<Instant>,
        timeout: Duration,
    ) -> Result<Stamped<T>, Error<D>> {
        let newer = |s: &Option<Stamped<T>>| {
            s.as_ref()
                .filter(|s| after.is_none_or(|a| s.at > a))
                .cloned()
        };
        self.wait_for(rx, timeout, newer).await
    }
}

/// Where a shell publishes the latest reading of one kind (empty until the first).
pub type Slot<T> = watch::Sender<Option<Stamped<T>>>;
/// Where handles read it.
pub type SlotRx<T> = watch::Receiver<Option<Stamped<T>>>;

/// A reading slot, empty until the first reading.
#[must_use]
pub fn slot<T>() -> (Slot<T>, SlotRx<T>) {
    watch::channel(None)
}

/// Calls a shell answers once the device confirms a state (e.g. "motors enabled"), keyed by
/// the state each waits for.
pub struct Confirmations<K, T, D: Shell> {
    waiting: Vec<(K, Reply<T, D>)>,
}

impl<K, T, D: Shell> Default for Confirmations<K, T, D> {
    fn default() -> Self {
        Self {
            waiting: Vec::new(),
        }
    }
}

impl<K, T, D: Shell> core::fmt::Debug for Confirmations<K, T, D> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "Confirmations({} waiting)", self.waiting.len())
    }
}

impl<K: PartialEq, T: Clone, D: Shell> Confirmations<K, T, D> {
    /// After asking the machine for `want` (`asked`: its answer), wait for the device's
    /// confirmation, or answer the refusal at once.
    pub fn wait(&mut self, want: K, asked: Result<(), Error<D>>, reply: Reply<T, D>) {
        match asked {
            Ok(()) => self.waiting.push((want, reply)),
            Err(e) => drop(reply.send(Err(e))),
        }
    }

    /// The device reports `state`: answer every call waiting for it with `value`.
    pub fn confirm(&mut self, state: &K, value: &T) {
        let (done, keep) = self.waiting.drain(..).partition(|(k, _)| k == state);
        self.waiting = keep;
        for (_, reply) in done {
            let _ = reply.send(Ok(value.clone()));
        }
    }

    /// Answer every waiting call with `e`.
    pub fn fail_all(&mut self, e: &Error<D>) {
        for (_, reply) in self.waiting.drain(..) {
            let _ = reply.send(Err(e.clone()));
        }
    }
}

/// The one call a shell answers later (a reconfiguration, a calibration, a request the
/// device must answer); while it waits, another is refused.
pub struct Pending<T, D: Shell>(Option<Reply<T, D>>);

impl<T, D: Shell> Default for Pending<T, D> {
    fn default() -> Self {
        Self(None)
    }
}

impl<T, D: Shell> core::fmt::Debug for Pending<T, D> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "Pending(waiting: {})", self.0.is_some())
    }
}

impl<T, D: Shell> Pending<T, D> {
    /// Whether a call is waiting.
    #[must_use]
    pub fn is_waiting(&self) -> bool {
        self.0.is_some()
    }

    /// Whether a call is waiting and its caller still listens (it has not given up at its
    /// timeout): an answer would reach someone.
    #[must_use]
    pub fn is_heard(&self) -> bool {
        self.0.as_ref().is_some_and(|r| !r.is_closed())
    }

    /// After asking the machine (`asked`: its answer), keep `reply` for
    /// [`answer`](Self::answer); answer at once with the refusal, or with `busy` if a call
    /// is already waiting.
    pub fn wait(&mut self, asked: Result<(), Error<D>>, reply: Reply<T, D>, busy: Error<D>) {
        match asked {
            Ok(()) if self.0.is_none() => self.0 = Some(reply),
            Ok(()) => drop(reply.send(Err(busy))),
            Err(e) => drop(reply.send(Err(e))),
        }
    }

    /// Answer the waiting call, if any.
    pub fn answer(&mut self, r: Result<T, Error<D>>) {
        if let Some(reply) = self.0.take() {
            let _ = reply.send(r);
        }
    }
}

//! The async runner (feature `tokio`): one task owns the byte stream and a driver's
//! [`Shell`] (its [`Machine`] and what turns events into readings); cloneable handles talk to
//! it through an `mpsc` of requests and `watch` channels of readings.
//!
//! Each round: drain the machine's events (they may change the line speed before the next
//! write) → write every frame due → flush → wait on one `select!` over the halt signal, the
//! stream, the machine's next deadline and the handles' requests. A device that goes quiet
//! never blocks the task. Closing (a `close` request, every handle dropped, or a halt) lets
//! the shell queue its last frames and keeps writing them for a bounded time.

use std::io;
use std::time::Duration;

use ima_hal::Instant;
use ima_hal::safety::HaltSignal;
use ima_hal::time::SharedClock;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::sync::{mpsc, oneshot, watch};

use crate::{BaudControl, LinkError, LinkStatus, Machine};

/// What a request does to the task.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Flow {
    /// Keep running.
    Continue,
    /// Start closing ([`Shell::begin_close`]).
    Close,
}

/// How a task ends.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum End {
    /// Closed; `drained`: the last frames were all written within the bound.
    Closed {
        /// Whether [`Shell::is_closed`] held before the bound passed.
        drained: bool,
    },
    /// The link failed (end of stream, I/O error).
    Failed(LinkError),
}

impl End {
    /// What a request still waiting when the task ends is answered with: the link's
    /// failure, or [`LinkError::Disconnected`] after a close.
    #[must_use]
    pub fn error<E: From<LinkError>>(self) -> E {
        match self {
            Self::Closed { .. } => LinkError::Disconnected.into(),
            Self::Failed(e) => e.into(),
        }
    }
}

/// The driver-specific half of a shell: it owns the machine, turns its events into readings
/// for the handles, and handle requests into machine calls. The runners do the rest.
pub trait Shell {
    /// The protocol machine.
    type Machine: Machine;
    /// What handles ask.
    type Request;
    /// The largest frame the machine writes.
    const MAX_FRAME: usize;

    /// The machine.
    fn machine(&mut self) -> &mut Self::Machine;

    /// Called once before the first round (start a handshake, at `now`).
    fn start(&mut self, _now: Instant) {}

    /// One machine event; `line` changes the line speed.
    ///
    /// # Errors
    /// The line's error, which fails the link.
    fn on_event(
        &mut self,
        event: <Self::Machine as Machine>::Event,
        line: &mut dyn BaudControl,
    ) -> io::Result<()>;

    /// Bytes received at `now` (by default: to the machine).
    fn on_bytes(&mut self, bytes: &[u8], now: Instant) {
        self.machine().handle_bytes(bytes, now);
    }

    /// The deadline of [`next_wake`](Self::next_wake) passed (by default: the machine's
    /// timers).
    fn on_timeout(&mut self, now: Instant) {
        self.machine().handle_timeout(now);
    }

    /// When to call [`on_timeout`](Self::on_timeout) next (by default: the machine's
    /// deadline).
    fn next_wake(&mut self) -> Option<Instant> {
        self.machine().poll_timeout()
    }

    /// A handle's request, at `now`.
    fn on_request(&mut self, request: Self::Request, now: Instant) -> Flow;

    /// After each round's writes (publish counters).
    fn after_round(&mut self) {}

    /// Start closing at `now` (queue the last frames); returns the longest the runner keeps
    /// writing them (by default: nothing to send, close at once).
    fn begin_close(&mut self, _now: Instant) -> Duration {
        Duration::ZERO
    }

    /// Whether the last frames are out (closing ends early; by default: yes).
    fn is_closed(&mut self) -> bool {
        true
    }

    /// The task ends (answer waiters, publish the final link status). The stream is
    /// already released.
    fn end(&mut self, how: End);
}

/// Spawn the task running `shell` over `stream` on the current tokio runtime, with
/// `clock` as its time; returns the request sender. With `halt`, the task closes when the
/// signal is raised and marks it done on every way out.
pub fn spawn<D, S>(
    shell: D,
    stream: S,
    clock: SharedClock,
    halt: Option<HaltSignal>,
) -> mpsc::Sender<D::Request>
where
    D: Shell + Send + 'static,
    D::Request: Send,
    S: AsyncRead + AsyncWrite + BaudControl + Unpin + Send + 'static,
{
    let (tx, rx) = mpsc::channel(32);
    tokio::spawn(run(shell, stream, rx, clock, halt));
    tx
}

/// Run `shell` over `stream` until it closes or the link fails (see the [module docs](self)).
pub async fn run<D, S>(
    mut shell: D,
    mut stream: S,
    mut requests: mpsc::Receiver<D::Request>,
    clock: SharedClock,
    halt: Option<HaltSignal>,
) where
    D: Shell,
    S: AsyncRead + AsyncWrite + BaudControl + Unpin,
{
    // Every way out of this task (return, cancellation, panic) marks the halt done.
    let _done = halt.as_ref().map(HaltSignal::done_on_drop);
    let mut rbuf = [0u8; 1024];
    let mut tbuf = vec![0u8; D::MAX_FRAME];
    shell.start(clock.now());
    // Closing: the instant after which writing the last frames gives up.
    let mut closing: Option<Instant> = None;
    let end = loop {
        if let Err(e) = drain(&mut shell, &mut stream) {
            break End::Failed(e.into());
        }
        if let Err(e) = transmit(&mut shell, &mut stream, &mut tbuf, clock.now()).await {
            break End::Failed(e.into());
        }
        shell.after_round();
        let now = clock.now();
        if let Some(limit) = closing {
            let drained = shell.is_closed();
            if drained || now >= limit {
                break End::Closed { drained };
            }
        }
        let wake = [shell.next_wake(), closing].into_iter().flatten().min();
        let sleep_for = wake.map_or(Duration::from_millis(500), |t| {
            t.saturating_duration_since(now)
        });
        let halted = async {
            match (&halt, closing) {
                (Some(h), None) => h.requested().await,
                _ => std::future::pending().await,
            }
        };
        tokio::select! {
            biased;
            () = halted => {
                tracing::info!("halt requested; stopping the device and closing");
                closing = Some(clock.now() + shell.begin_close(clock.now()));
            }
            r = stream.read(&mut rbuf) => match r {
                Ok(0) => break End::Failed(LinkError::Disconnected),
                Ok(n) => shell.on_bytes(rbuf.get(..n).unwrap_or(&[]), clock.now()),
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) => break End::Failed(e.into()),
            },
            () = tokio::time::sleep(sleep_for) => shell.on_timeout(clock.now()),
            req = requests.recv(), if closing.is_none() => {
                let flow = match req {
                    None => Flow::Close,
                    Some(req) => shell.on_request(req, clock.now()),
                };
                if flow == Flow::Close {
                    closing = Some(clock.now() + shell.begin_close(clock.now()));
                }
            }
        }
    };
    // Release the port before reporting: a caller may reopen it at once.
    drop(stream);
    if let Some(h) = &halt {
        h.set_done();
    }
    requests.close();
    shell.end(end);
}

/// Hand every pending event to the shell.
pub(crate) fn drain<D: Shell>(shell: &mut D, line: &mut dyn BaudControl) -> io::Result<()> {
    while let Some(ev) = shell.machine().poll_event() {
        shell.on_event(ev, line)?;
    }
    Ok(())
}

async fn transmit<D: Shell, S: AsyncWrite + Unpin>(
    shell: &mut D,
    stream: &mut S,
    tbuf: &mut [u8],
    now: Instant,
) -> io::Result<()> {
    while let Some(n) = shell.machine().poll_transmit(now, tbuf) {
        let Some(frame) = tbuf.get(..n) else { break };
        stream.write_all(frame).await?;
    }
    stream.flush().await
}

/// Wait until `link` is connected (its connection), failed (`Err(Some(e))`) or closed
/// (`Err(Some(Disconnected))`); `Err(None)` when `timeout` passes first.
///
/// # Errors
/// As described.
pub async fn wait_connected<U: Clone, E: Clone + From<LinkError>>(
    link: &mut watch::Receiver<LinkStatus<U, E>>,
    timeout: Duration,
) -> Result<U, Option<E>> {
    let waited = tokio::time::timeout(timeout, async {
        loop {
            match &*link.borrow_and_update() {
                LinkStatus::Connected(u) => return Ok(u.clone()),
                LinkStatus::Failed(e) => return Err(e.clone()),
                LinkStatus::Closed => return Err(LinkError::Disconnected.into()),
                LinkStatus::Connecting | LinkStatus::Lost => {}
            }
            if link.changed().await.is_err() {
                return Err(LinkError::Disconnected.into());
            }
        }
    })
    .await;
    match waited {
        Ok(r) => r.map_err(Some),
        Err(_) => Err(None),
    }
}

/// Send a request made by `make` around a reply channel and wait for the answer, at most
/// `timeout`.
///
/// # Errors
/// The task's answer; [`LinkError::Disconnected`] if the task is gone,
/// [`LinkError::Timeout`] if it did not answer in time.
pub async fn request<R, T, E: From<LinkError>>(
    tx: &mpsc::Sender<R>,
    make: impl FnOnce(oneshot::Sender<Result<T, E>>) -> R,
    timeout: Duration,
) -> Result<T, E> {
    let (reply, rx) = oneshot::channel();
    tx.send(make(reply))
        .await
        .map_err(|_| LinkError::Disconnected)?;
    match tokio::time::timeout(timeout, rx).await {
        Ok(Ok(r)) => r,
        Ok(Err(_)) => Err(LinkError::Disconnected.into()),
        Err(_) => Err(LinkError::Timeout.into()),
    }
}

/// Wait until `pick` finds what it wants in `rx`'s value (checked at once, then on every
/// change), at most `timeout`.
///
/// # Errors
/// [`LinkError::Timeout`]; [`LinkError::Disconnected`] if the task is gone.
pub async fn wait_for<T, R>(
    rx: &watch::Receiver<T>,
    timeout: Duration,
    mut pick: impl FnMut(&T) -> Option<R>,
) -> Result<R, LinkError> {
    let mut rx = rx.clone();
    tokio::time::timeout(timeout, async move {
        loop {
            if let Some(r) = pick(&rx.borrow_and_update()) {
                return Ok(r);
            }
            rx.changed().await.map_err(|_| LinkError::Disconnected)?;
        }
    })
    .await
    .map_err(|_| LinkError::Timeout)?
}

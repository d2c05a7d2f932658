//! The async runner (feature `tokio`): one task owns the byte stream and a driver's
//! [`Shell`] (its [`Machine`] and what turns events into readings); cloneable
//! [`Handle`](crate::handle::Handle)s talk to it by sending closures that run on the shell,
//! and read what it publishes on `watch` channels.
//!
//! Each round: drain the machine's events (they may change the line speed before the next
//! write) → write every frame due → flush → wait on one `select!` over the halt signal, the
//! stream, the machine's next deadline and the handles' calls. A device that goes quiet
//! never blocks the task. Closing (a `close` call, every handle dropped, or a halt) lets the
//! shell queue its last frames and keeps writing them for a bounded time (for a device that
//! falls silent once closed, until it has: [`Shell::SILENT_ONCE_CLOSED`]); then the port is
//! released, the link's last status published and every closer answered.

use std::io;
use std::time::Duration;

use ima_hal::Instant;
use ima_hal::safety::HaltSignal;
use ima_hal::time::SharedClock;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::sync::{mpsc, oneshot, watch};

use crate::{BaudControl, DriverError, Fault, LinkError, LinkStatus, Machine};

/// The error of shell `D`'s driver.
pub type Error<D> = DriverError<<D as Shell>::Fault>;
/// The link status handles of shell `D` see.
pub type Status<D> = LinkStatus<<D as Shell>::Up, Error<D>>;
/// Where a shell answers a call it finishes later (after a device's confirmation).
pub type Reply<T, D> = oneshot::Sender<Result<T, Error<D>>>;

/// Closing with the device gone, how long its stop is written again ([`Shell::repeat_stop`]),
/// and how often: a line that comes back in that time gets the stop.
pub const RESTOP_FOR: Duration = Duration::from_millis(1200);
/// See [`RESTOP_FOR`].
pub const RESTOP_EVERY: Duration = Duration::from_millis(100);
/// After the last repeat, how long its frames may take to go out.
const RESTOP_DRAIN: Duration = Duration::from_millis(500);
/// The longest closing with repeats lasts ([`RESTOP_FOR`] and the last repeat's drain; also
/// the bound of a device confirmed by its silence, [`Shell::SILENT_ONCE_CLOSED`]): within the
/// 2 s a program waits for its drivers.
pub const RESTOP_BOUND: Duration = RESTOP_FOR.saturating_add(RESTOP_DRAIN);
const _: () = assert!(RESTOP_BOUND.as_millis() < 2_000);

/// The stop written again while a closing task waits for a gone device's line to come back.
#[derive(Debug, Clone, Copy)]
struct Restop {
    /// The next repeat.
    next: Instant,
    /// The last one.
    until: Instant,
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

/// The driver-specific half of a driver: it owns the machine, turns its events into
/// readings (on `watch` channels) and the link status, and answers the calls handles make
/// on it. The runner does the I/O, the timing and the closing.
pub trait Shell: Sized + Send + 'static {
    /// The protocol machine.
    type Machine: Machine;
    /// The device's own faults.
    type Fault: Fault;
    /// What a connected link reports (who answered, at what rate; `()` for nothing).
    type Up: Clone + Send + Sync + 'static;
    /// The counters handles read ([`Handle::stats`](crate::handle::Handle::stats)).
    type Stats: Clone + PartialEq + Send + Sync + 'static;
    /// The largest frame the machine writes.
    const MAX_FRAME: usize;

    /// The machine.
    fn machine(&mut self) -> &mut Self::Machine;

    /// Where the shell publishes the link's status (the runner publishes the last one).
    fn link(&self) -> &watch::Sender<Status<Self>>;

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

    /// The counters now (the runner publishes them after each round's writes, when they
    /// changed).
    fn stats(&self) -> Self::Stats;

    /// Start closing at `now` (queue the last frames); returns the longest the runner keeps
    /// writing them (by default: nothing to send, close at once).
    fn begin_close(&mut self, _now: Instant) -> Duration {
        Duration::ZERO
    }

    /// A device that streams reports: connected but silent this long as closing begins, it
    /// counts as gone (its link is declared [`Lost`](crate::LinkStatus::Lost) only after the
    /// machine's longer timeout). By default only a lost link counts. A shell that sets it
    /// must count its frames ([`frames_heard`](Self::frames_heard)): with none counted, the
    /// device always counts as gone.
    const QUIET: Option<Duration> = None;

    /// What stops the device by itself when it hears nothing, for the message about a stop
    /// that may not have reached it ([`HaltSignal::set_watchdog`]); none by default.
    const WATCHDOG: Option<&'static str> = None;

    /// Whether [`repeat_stop`](Self::repeat_stop) does anything (by default: no; the stop is
    /// written once).
    const REPEATS_STOP: bool = false;

    /// A device that falls silent once it has taken its close (a P2OS robot's CLOSE ends its
    /// SIPs): with the last frames out, the runner waits until the device has sent nothing
    /// for this long, so that a stop it reports heard was taken. A frame that comes half this
    /// long after the stop was written or later means it was not (a line dead from host to
    /// device only, a frame corrupted on the way): the stop is written again
    /// ([`REPEATS_STOP`](Self::REPEATS_STOP)) and, the device not silent this long when
    /// closing ends, reported unheard. For a device that was connected, closing then lasts
    /// up to the longer of [`begin_close`](Self::begin_close)'s bound and [`RESTOP_BOUND`].
    /// It must exceed the device's report period (several periods: a lost report must not
    /// pass for silence). By default closing ends once the last frames are out.
    const SILENT_ONCE_CLOSED: Option<Duration> = None;

    /// Good frames received so far: what "quiet" and "heard" are judged on.
    fn frames_heard(&self) -> u64 {
        0
    }

    /// Queue the stop frames again: closing with the device gone (see
    /// [`QUIET`](Self::QUIET)), the runner calls it every [`RESTOP_EVERY`] for
    /// [`RESTOP_FOR`], and once more when a frame is heard (the line is back), which ends the
    /// repeats; with [`SILENT_ONCE_CLOSED`](Self::SILENT_ONCE_CLOSED), whenever the device is
    /// still sending after its stop.
    fn repeat_stop(&mut self) {}

    /// Whether the last frames are out (closing ends early; by default: yes).
    fn is_closed(&mut self) -> bool {
        true
    }

    /// The task ends (the stream is already released). Replies the shell still holds are
    /// answered [`Disconnected`](DriverError::Disconnected) when it is dropped; override to
    /// say more.
    fn end(&mut self, _how: End) {}

    /// What a connect that timed out reports: what the line carried (by default
    /// [`DriverError::Timeout`]).
    fn no_answer(&mut self) -> Error<Self> {
        DriverError::Timeout
    }
}

/// A closure a handle runs on the shell inside the task, at the task's `now`.
pub(crate) type Call<D> = Box<dyn FnOnce(&mut D, Instant) + Send>;

/// What handles send the task.
pub(crate) enum Msg<D> {
    /// Run this on the shell.
    Call(Call<D>),
    /// Close; answered once the port is released.
    Close(oneshot::Sender<Result<(), LinkError>>),
}

/// Run `shell` over `stream` until it closes or the link fails (see the [module docs](self)).
/// The task closes when `halt` is raised and marks it done on every way out.
pub(crate) async fn run<D, S>(
    mut shell: D,
    mut stream: S,
    mut requests: mpsc::Receiver<Msg<D>>,
    stats: watch::Sender<D::Stats>,
    clock: SharedClock,
    halt: HaltSignal,
) where
    D: Shell,
    S: AsyncRead + AsyncWrite + BaudControl + Unpin,
{
    // Every way out of this task (return, cancellation, panic) marks the halt done; one that
    // skips the end below (a runtime dropped under it, a panic) also marks the stop unheard:
    // none was written.
    let mut guard = EndGuard {
        halt: halt.clone(),
        ended: false,
    };
    let mut rbuf = [0u8; 1024];
    let mut tbuf = vec![0u8; D::MAX_FRAME];
    let mut closers = Vec::new();
    shell.start(clock.now());
    // Closing: the instant after which writing the last frames gives up.
    let mut closing: Option<Instant> = None;
    // Whether the device was ever connected: a port that fails before has moved nothing.
    let mut ever_up = false;
    // The last good frame; whether the device was gone as closing began, the repeats of its
    // stop, and whether it was heard while they ran (the last one met it).
    let mut last_frame: Option<Instant> = None;
    let mut gone_at_close = false;
    let mut restop: Option<Restop> = None;
    let mut heard_closing = false;
    // A device that falls silent once closed ([`Shell::SILENT_ONCE_CLOSED`]), connected,
    // closing: when its stop was last written on purpose (not a gone device's timed repeats),
    // and whether it had been silent since for long enough when closing ended.
    let mut stop_at: Option<Instant> = None;
    let mut silent = true;
    let end = loop {
        ever_up = ever_up || shell.link().borrow().is_connected();
        if let Err(e) = drain(&mut shell, &mut stream) {
            break End::Failed(e.into());
        }
        if let Err(e) = transmit(&mut shell, &mut stream, &mut tbuf, clock.now()).await {
            break End::Failed(e.into());
        }
        stats.send_if_modified(|old| {
            let s = shell.stats();
            let changed = *old != s;
            *old = s;
            changed
        });
        let now = clock.now();
        // When the device has been silent long enough since its stop and its last frame.
        let silent_at = D::SILENT_ONCE_CLOSED
            .zip(stop_at)
            .map(|(s, t)| last_frame.map_or(t, |f| f.max(t)) + s);
        if let Some(limit) = closing {
            let drained = shell.is_closed() && restop.is_none();
            silent = silent_at.is_none_or(|t| now >= t);
            if (drained && silent) || now >= limit {
                break End::Closed { drained };
            }
        }
        // (A silence already reached waits for the last frames, not for itself.)
        let silence = silent_at.filter(|&t| t > now);
        let wake = [shell.next_wake(), closing, restop.map(|r| r.next), silence]
            .into_iter()
            .flatten()
            .min();
        let sleep_for = wake.map_or(Duration::from_millis(500), |t| {
            t.saturating_duration_since(now)
        });
        let halted = async {
            match closing {
                None => halt.requested().await,
                Some(_) => std::future::pending().await,
            }
        };
        let mut slept = false;
        let mut close = tokio::select! {
            biased;
            () = halted => {
                tracing::info!("halt requested; stopping the device and closing");
                true
            }
            r = stream.read(&mut rbuf) => match r {
                Ok(0) => break End::Failed(LinkError::Disconnected),
                Ok(n) => {
                    let (now, before) = (clock.now(), shell.frames_heard());
                    shell.on_bytes(rbuf.get(..n).unwrap_or(&[]), now);
                    if shell.frames_heard() != before {
                        last_frame = Some(now);
                        // Closing, a gone device heard again (not noise): one more stop meets
                        // it, and the repeats end.
                        if restop.take().is_some() {
                            heard_closing = true;
                            shell.repeat_stop();
                            stop_at = stop_at.map(|_| now);
                        } else if D::REPEATS_STOP
                            && let (Some(s), Some(t)) = (D::SILENT_ONCE_CLOSED, stop_at)
                            && now >= t + s / 2
                        {
                            // Still sending after a frame in flight would have come: not taken;
                            // again.
                            shell.repeat_stop();
                            stop_at = Some(now);
                        }
                    }
                    false
                }
                Err(e) if e.kind() == io::ErrorKind::Interrupted => false,
                Err(e) => break End::Failed(e.into()),
            },
            () = tokio::time::sleep(sleep_for) => {
                slept = true;
                false
            }
            msg = requests.recv(), if closing.is_none() => on_msg(&mut shell, msg, &mut closers, &clock),
        };
        // Reading comes first (bytes that arrived before a deadline count), but a device
        // that never stops sending must not starve the timers or the handles: every round
        // also runs what is due and takes one waiting call.
        let now = clock.now();
        if slept || shell.next_wake().is_some_and(|t| t <= now) {
            shell.on_timeout(now);
        }
        if let Some(r) = &mut restop
            && now >= r.next
        {
            shell.repeat_stop();
            r.next = now + RESTOP_EVERY;
            if now >= r.until {
                restop = None;
            }
        }
        if closing.is_none()
            && !close
            && let Ok(msg) = requests.try_recv()
        {
            close = on_msg(&mut shell, Some(msg), &mut closers, &clock);
        }
        if close {
            // The events of what just ran first (a link declared lost by the timeout that ran
            // in this round), so that the shell closes knowing them.
            if let Err(e) = drain(&mut shell, &mut stream) {
                break End::Failed(e.into());
            }
            let now = clock.now();
            gone_at_close = {
                let link = shell.link().borrow();
                match D::QUIET {
                    Some(q) => link.is_quiet(last_frame, now, q),
                    None => matches!(*link, LinkStatus::Lost),
                }
            };
            let mut bound = shell.begin_close(now);
            // (Connected in this very round counts.)
            ever_up = ever_up || shell.link().borrow().is_connected();
            if ever_up && D::SILENT_ONCE_CLOSED.is_some() {
                stop_at = Some(now);
                // Room for a few repeats and the silence after the last.
                bound = bound.max(RESTOP_BOUND);
            }
            if gone_at_close && D::REPEATS_STOP {
                restop = Some(Restop {
                    next: now + RESTOP_EVERY,
                    until: now + RESTOP_FOR,
                });
                bound = bound.max(RESTOP_BOUND);
            }
            closing = Some(now + bound);
        }
        // Yield now and then, so handles on this thread get to run.
        tokio::task::coop::consume_budget().await;
    };
    // A device that had gone quiet may not have heard its stop, and one whose port failed
    // after it connected may not have been sent it: said to whoever reports it, before the
    // halt is done.
    let unheard = match end {
        // A device never connected has moved nothing: no doubt to raise (a connect that
        // timed out, a port nobody serves).
        End::Closed { .. } => {
            let lost = matches!(*shell.link().borrow(), LinkStatus::Lost);
            if !silent {
                let device = <D::Fault as Fault>::DEVICE;
                tracing::warn!("{device}: still sending after its stop: it may not have taken it");
            }
            (((gone_at_close || lost) && !heard_closing) || !silent) && ever_up
        }
        End::Failed(_) => ever_up || shell.link().borrow().is_connected(),
    };
    if unheard {
        halt.set_stopped_unheard();
    }
    // Release the port before reporting: a caller may reopen it at once.
    drop(stream);
    guard.ended = true;
    // Marks the halt done, before the closers hear.
    drop(guard);
    requests.close();
    shell.end(end);
    let closed = matches!(end, End::Closed { .. });
    let (r, status) = match end {
        End::Closed { drained: true } => (Ok(()), LinkStatus::Closed),
        End::Closed { drained: false } => {
            tracing::warn!("the device's last frames could not all be written in time");
            (Err(LinkError::Timeout), LinkStatus::Closed)
        }
        End::Failed(e) => {
            // The task ends here; without this line a device that vanished (a pulled USB
            // adapter, a mock that quit) left only refused calls behind.
            let device = <D::Fault as Fault>::DEVICE;
            match e {
                LinkError::Disconnected => {
                    tracing::error!("{device}: the port closed; the driver has ended");
                }
                e => tracing::error!("{device}: the port failed ({e}); the driver has ended"),
            }
            (Err(e), LinkStatus::Failed(e.into()))
        }
    };
    // A failure the shell published (why the device was given up) stays the last word.
    shell.link().send_if_modified(|s| {
        let keep = closed && matches!(s, LinkStatus::Failed(_));
        if !keep {
            *s = status.clone();
        }
        !keep
    });
    for tx in closers {
        let _ = tx.send(r);
    }
}

/// Marks a task's halt signal done when dropped, and its stop unheard unless the task reached
/// its end ([`run`]).
struct EndGuard {
    halt: HaltSignal,
    ended: bool,
}

impl Drop for EndGuard {
    fn drop(&mut self) {
        if !self.ended {
            self.halt.set_stopped_unheard();
        }
        self.halt.set_done();
    }
}

/// Run a handle's message; whether it starts closing.
fn on_msg<D: Shell>(
    shell: &mut D,
    msg: Option<Msg<D>>,
    closers: &mut Vec<oneshot::Sender<Result<(), LinkError>>>,
    clock: &SharedClock,
) -> bool {
    match msg {
        Some(Msg::Call(f)) => {
            f(shell, clock.now());
            false
        }
        Some(Msg::Close(tx)) => {
            closers.push(tx);
            true
        }
        // Every handle is gone.
        None => true,
    }
}

/// Hand every pending event to the shell.
fn drain<D: Shell>(shell: &mut D, line: &mut dyn BaudControl) -> io::Result<()> {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::FixedBaud;
    use crate::handle::Handle;
    use std::pin::Pin;
    use std::task::{Context, Poll};

    /// Counts the bytes it is fed (each a frame), and writes a stop (`S`) for each one queued.
    #[derive(Debug, Default)]
    struct Counter {
        frames: u64,
        stops_queued: u32,
    }

    impl Machine for Counter {
        type Event = ();
        fn handle_bytes(&mut self, bytes: &[u8], _: Instant) {
            self.frames += bytes.len() as u64;
        }
        fn handle_timeout(&mut self, _: Instant) {}
        fn poll_transmit(&mut self, _: Instant, buf: &mut [u8]) -> Option<usize> {
            self.stops_queued = self.stops_queued.checked_sub(1)?;
            *buf.first_mut()? = b'S';
            Some(1)
        }
        fn poll_event(&mut self) -> Option<()> {
            None
        }
        fn poll_timeout(&self) -> Option<Instant> {
            None
        }
    }

    #[derive(Debug, Clone, PartialEq)]
    struct Never;
    impl core::fmt::Display for Never {
        fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
            f.write_str("never")
        }
    }
    impl Fault for Never {
        const DEVICE: &'static str = "flood";
        fn kind(&self) -> ima_hal::ErrorKind {
            ima_hal::ErrorKind::Other
        }
    }

    /// A test shell over a [`Counter`]: it closes by writing `S` (again on a repeat); with
    /// `CONFIRMS`, its device falls silent once it takes the stop.
    struct Fake<const CONFIRMS: bool> {
        machine: Counter,
        link: watch::Sender<Status<Self>>,
    }
    /// Closing ends once the stop is written.
    type Flood = Fake<false>;
    /// Closing waits for the device's silence.
    type Closer = Fake<true>;

    impl<const CONFIRMS: bool> Shell for Fake<CONFIRMS> {
        type Machine = Counter;
        type Fault = Never;
        type Up = ();
        type Stats = ();
        const MAX_FRAME: usize = 8;
        const REPEATS_STOP: bool = CONFIRMS;
        const SILENT_ONCE_CLOSED: Option<Duration> = if CONFIRMS {
            Some(Duration::from_millis(300))
        } else {
            None
        };
        fn stats(&self) {}
        fn machine(&mut self) -> &mut Counter {
            &mut self.machine
        }
        fn link(&self) -> &watch::Sender<Status<Self>> {
            &self.link
        }
        fn on_event(&mut self, (): (), _: &mut dyn BaudControl) -> io::Result<()> {
            Ok(())
        }
        fn frames_heard(&self) -> u64 {
            self.machine.frames
        }
        fn begin_close(&mut self, _: Instant) -> Duration {
            self.machine.stops_queued += 1;
            Duration::from_secs(1)
        }
        fn repeat_stop(&mut self) {
            self.machine.stops_queued += 1;
        }
        fn is_closed(&mut self) -> bool {
            self.machine.stops_queued == 0
        }
    }

    /// A waiting call is heard until its caller gives up; it is still waiting after that
    /// (the device's answer is yet to come), but an answer would reach nobody.
    #[test]
    fn a_pending_call_is_heard_until_its_caller_gives_up() {
        let mut p = crate::handle::Pending::<(), Flood>::default();
        assert!(!p.is_waiting() && !p.is_heard());
        let (reply, rx) = oneshot::channel();
        p.wait(Ok(()), reply, crate::DriverError::Timeout);
        assert!(p.is_waiting() && p.is_heard());
        drop(rx);
        assert!(p.is_waiting() && !p.is_heard());
    }

    /// A device that never stops sending.
    struct Firehose;
    impl AsyncRead for Firehose {
        fn poll_read(
            self: Pin<&mut Self>,
            _: &mut Context<'_>,
            buf: &mut tokio::io::ReadBuf<'_>,
        ) -> Poll<io::Result<()>> {
            buf.put_slice(&[0x55; 64]);
            Poll::Ready(Ok(()))
        }
    }
    impl AsyncWrite for Firehose {
        fn poll_write(
            self: Pin<&mut Self>,
            _: &mut Context<'_>,
            b: &[u8],
        ) -> Poll<io::Result<usize>> {
            Poll::Ready(Ok(b.len()))
        }
        fn poll_flush(self: Pin<&mut Self>, _: &mut Context<'_>) -> Poll<io::Result<()>> {
            Poll::Ready(Ok(()))
        }
        fn poll_shutdown(self: Pin<&mut Self>, _: &mut Context<'_>) -> Poll<io::Result<()>> {
            Poll::Ready(Ok(()))
        }
    }

    /// On one thread, a handle's call and close still get through a device that floods.
    #[tokio::test(flavor = "current_thread")]
    async fn a_flooding_device_does_not_starve_the_handles() {
        let shell = Flood {
            machine: Counter::default(),
            link: watch::channel(LinkStatus::Connecting).0,
        };
        let clock = ima_hal::time::TokioClock::shared();
        let h = Handle::spawn(shell, FixedBaud(Firehose), clock, None);
        let seen = h
            .call(Duration::from_secs(5), |s, _| Ok(s.machine.frames))
            .await;
        assert!(seen.is_ok(), "{seen:?}");
        let later = h
            .call(Duration::from_secs(5), |s, _| Ok(s.machine.frames))
            .await;
        assert!(later.unwrap() >= seen.unwrap());
        assert_eq!(h.close(Duration::from_secs(5)).await, Ok(()));
        assert!(matches!(h.link(), LinkStatus::Closed));
        assert!(
            !h.halt_signal().stopped_unheard(),
            "closed with the device heard"
        );
    }

    /// A [`Flood`] driver on one end of an in-memory pipe (inside a runtime); the other end.
    fn flood_on_a_pipe() -> (Handle<Flood>, tokio::io::DuplexStream) {
        let shell = Flood {
            machine: Counter::default(),
            link: watch::channel(LinkStatus::Connecting).0,
        };
        let (ours, theirs) = tokio::io::duplex(64);
        let clock = ima_hal::time::TokioClock::shared();
        (Handle::spawn(shell, FixedBaud(ours), clock, None), theirs)
    }

    /// A port that ends (a pulled adapter, a device that hung up) ends the task without a stop
    /// written: its halt signal says the stop may not have been heard (it said nothing, and a
    /// program then claimed the robot stopped).
    #[tokio::test(flavor = "current_thread")]
    async fn a_port_that_ends_reports_its_stop_unheard() {
        for connected in [true, false] {
            let (h, theirs) = flood_on_a_pipe();
            if connected {
                let up = |s: &mut Flood, _| {
                    s.link.send_replace(LinkStatus::Connected(()));
                    Ok(())
                };
                h.call(Duration::from_secs(5), up).await.unwrap();
            }
            drop(theirs);
            let halt = h.halt_signal();
            tokio::time::timeout(Duration::from_secs(5), async {
                while !halt.is_done() {
                    tokio::time::sleep(Duration::from_millis(1)).await;
                }
            })
            .await
            .unwrap();
            assert!(matches!(h.link(), LinkStatus::Failed(_)), "{:?}", h.link());
            // One never connected has moved nothing: no doubt to raise.
            assert_eq!(halt.stopped_unheard(), connected, "connected: {connected}");
        }
    }

    /// Closed with its link lost: a device that had connected may not have heard its stop;
    /// one that never connected (a connect that timed out on a silent line) raises no doubt
    /// (it did: "keep clear until it stands" for a robot nothing had ever answered for).
    #[tokio::test(flavor = "current_thread")]
    async fn a_lost_link_raises_doubt_only_for_a_device_that_connected() {
        for connected in [true, false] {
            let (h, _theirs) = flood_on_a_pipe();
            let set = |to: Status<Flood>| {
                move |s: &mut Flood, _| {
                    s.link.send_replace(to);
                    Ok(())
                }
            };
            if connected {
                h.call(Duration::from_secs(5), set(LinkStatus::Connected(())))
                    .await
                    .unwrap();
            }
            h.call(Duration::from_secs(5), set(LinkStatus::Lost))
                .await
                .unwrap();
            assert_eq!(h.close(Duration::from_secs(5)).await, Ok(()));
            let unheard = h.halt_signal().stopped_unheard();
            assert_eq!(unheard, connected, "connected: {connected}");
        }
    }

    /// A task dropped before its end (its runtime shut down under it) wrote no stop: its halt
    /// is done, and its stop unheard.
    #[test]
    fn a_task_dropped_before_its_end_reports_its_stop_unheard() {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        let (h, _theirs) = rt.block_on(async {
            let (h, theirs) = flood_on_a_pipe();
            // The task has started: it answers a call.
            h.call(Duration::from_secs(5), |_, _| Ok(())).await.unwrap();
            (h, theirs)
        });
        let halt = h.halt_signal();
        assert!(!halt.is_done());
        drop(rt);
        assert!(halt.is_done() && halt.stopped_unheard());
    }

    /// Close a connected [`Closer`] whose device streams a frame (one byte) every 50 ms and
    /// falls silent once it takes a stop, ignoring the first `ignored` (as a robot does whose
    /// line drops or corrupts them); the stops it received, whether the halt says the stop was unheard, and how long closing took.
    async fn close_against(ignored: u32) -> (u32, bool, Duration) {
        let shell = Closer {
            machine: Counter::default(),
            link: watch::channel(LinkStatus::Connected(())).0,
        };
        let (ours, mut theirs) = tokio::io::duplex(64);
        let clock = ima_hal::time::TokioClock::shared();
        let h = Handle::spawn(shell, FixedBaud(ours), clock, None);
        let device = tokio::spawn(async move {
            let mut stops = 0;
            let mut buf = [0u8; 16];
            let mut tick = tokio::time::interval(Duration::from_millis(50));
            loop {
                tokio::select! {
                    r = theirs.read(&mut buf) => match r {
                        Ok(0) | Err(_) => return stops,
                        Ok(n) => stops += buf.get(..n).unwrap_or(&[]).iter().filter(|&&b| b == b'S').count() as u32,
                    },
                    _ = tick.tick(), if stops <= ignored => {
                        if theirs.write_all(&[1]).await.is_err() {
                            return stops;
                        }
                    }
                }
            }
        });
        tokio::time::sleep(Duration::from_millis(500)).await;
        let t0 = tokio::time::Instant::now();
        assert_eq!(h.close(Duration::from_secs(5)).await, Ok(()));
        let took = t0.elapsed();
        let unheard = h.halt_signal().stopped_unheard();
        (device.await.unwrap(), unheard, took)
    }

    /// A device that falls silent at its first stop: closing waits out the silence and the
    /// stop is heard.
    #[tokio::test(start_paused = true)]
    async fn a_device_silent_after_its_stop_took_it() {
        let (stops, unheard, took) = close_against(0).await;
        assert_eq!(stops, 1);
        assert!(!unheard);
        assert!(took >= Duration::from_millis(300), "{took:?}");
    }

    /// One that ignored the first stops (still sending 150 ms after each) gets it again, takes
    /// a later one, and is heard: three lost stops fit in the bound (they did not in the
    /// shell's 1 s, with a repeat only 300 ms after the last).
    #[tokio::test(start_paused = true)]
    async fn a_stop_the_device_did_not_take_is_written_again() {
        for ignored in [1, 3] {
            let (stops, unheard, _) = close_against(ignored).await;
            assert_eq!(stops, ignored + 1);
            assert!(!unheard, "it fell silent after stop {stops}");
        }
    }

    /// One that never takes it (a line dead from host to device only: its frames still
    /// arrive) gets it again while closing lasts, and the stop is reported unheard. It was
    /// claimed: the device had been heard after it.
    #[tokio::test(start_paused = true)]
    async fn a_device_still_sending_after_its_stops_did_not_hear_them() {
        let (stops, unheard, took) = close_against(u32::MAX).await;
        assert!(stops >= 6, "{stops}");
        assert!(unheard);
        assert!(
            took <= RESTOP_BOUND + Duration::from_millis(100),
            "{took:?}"
        );
    }
}

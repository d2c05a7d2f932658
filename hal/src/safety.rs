//! Stopping what moves, from anywhere in the process (feature `std`).
//!
//! A robot must stop on every exit path of the program that drives it: a normal end, an error,
//! a signal, a closed pipe, a panic on any thread. Remembering a `stop()` in every command does
//! not give that guarantee, so it lives here, one level below the commands:
//!
//! * every driver task that can command motion owns a [`HaltSignal`]: anyone may call
//!   [`HaltSignal::halt`] from any thread (a signal handler task, a panic hook, a drop) without
//!   awaiting; the task then stops the device, closes its session, writes its last frames and
//!   marks the signal [done](HaltSignal::is_done);
//! * the driver registers that signal in the process-wide [`StopRegistry::global`] as it
//!   starts, so a program-level guard can halt *every* moving device and wait until each one's
//!   last frames are on the wire, without knowing which commands opened which devices.
//!
//! The registry only holds signals; it never owns a driver, so registering keeps nothing alive.
//! Signals whose task has ended are pruned as new ones arrive.
//!
//! What this cannot cover is a process that is killed outright (`SIGKILL`, power loss): then the
//! robot's own firmware watchdog is the only defence (see the README's "Safety" section).

use std::future::Future;
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::task::{Context, Poll, Waker};
use std::time::Duration;

#[derive(Debug, Default)]
struct Inner {
    requested: AtomicBool,
    done: AtomicBool,
    unheard: AtomicBool,
    watchdog: std::sync::OnceLock<&'static str>,
    wakers: Mutex<Vec<Waker>>,
}

/// The link between a driver task that can move a robot and whoever may need to stop it.
///
/// Cheap to clone; every clone refers to the same signal. See the [module docs](self).
#[derive(Debug, Clone, Default)]
pub struct HaltSignal {
    inner: Arc<Inner>,
}

impl HaltSignal {
    /// A signal neither requested nor done.
    #[must_use]
    pub fn new() -> Self {
        Self::default()
    }

    /// Ask the task to stop the device and close its session. Returns at once; safe from any
    /// thread and from a panic hook. Idempotent.
    pub fn halt(&self) {
        self.inner.requested.store(true, Ordering::SeqCst);
        let wakers = std::mem::take(
            &mut *self
                .inner
                .wakers
                .lock()
                .unwrap_or_else(PoisonError::into_inner),
        );
        for w in wakers {
            w.wake();
        }
    }

    /// Whether [`halt`](Self::halt) has been called.
    #[must_use]
    pub fn is_requested(&self) -> bool {
        self.inner.requested.load(Ordering::SeqCst)
    }

    /// A future that resolves once [`halt`](Self::halt) has been called (at once if it
    /// already was). Runtime-agnostic; a driver task selects on it.
    #[must_use]
    pub fn requested(&self) -> Requested<'_> {
        Requested { signal: self }
    }

    /// Called by the driver task once its last frames are written (or nothing more can be):
    /// the device has been told to stop, or the link is gone.
    pub fn set_done(&self) {
        self.inner.done.store(true, Ordering::SeqCst);
    }

    /// Called by the driver task, before [`set_done`](Self::set_done), when its stop may not
    /// have reached the device: it closed while the device had gone quiet and was not heard
    /// since, or while a device that falls silent once stopped went on sending; its port
    /// failed after the device connected; or the task ended before its stop.
    /// The device's own watchdog is what stops it then. Messages that would say "stopped"
    /// say so instead ([`StopRegistry::unheard`]).
    pub fn set_stopped_unheard(&self) {
        self.inner.unheard.store(true, Ordering::SeqCst);
    }

    /// Whether the stop may not have reached the device
    /// ([`set_stopped_unheard`](Self::set_stopped_unheard)).
    #[must_use]
    pub fn stopped_unheard(&self) -> bool {
        self.inner.unheard.load(Ordering::SeqCst)
    }

    /// Say what stops the device by itself when it hears nothing (e.g. `"P2OS: 2 s after the
    /// last command it received"`), for messages about a stop that went unheard. The first
    /// call counts.
    pub fn set_watchdog(&self, what: &'static str) {
        let _ = self.inner.watchdog.set(what);
    }

    /// What [`set_watchdog`](Self::set_watchdog) said, if anything.
    #[must_use]
    pub fn watchdog(&self) -> Option<&'static str> {
        self.inner.watchdog.get().copied()
    }

    /// Whether the task has finished (see [`set_done`](Self::set_done)).
    #[must_use]
    pub fn is_done(&self) -> bool {
        self.inner.done.load(Ordering::SeqCst)
    }

    /// A guard that marks the signal done when dropped: a driver task holds one so that every
    /// way out of it (return, error, cancellation, panic) reports completion.
    #[must_use]
    pub fn done_on_drop(&self) -> DoneOnDrop {
        DoneOnDrop(self.clone())
    }

    /// Block the calling thread until the task is done or `timeout` passes; true when done.
    /// For panic hooks and exit paths outside any async runtime.
    #[must_use]
    pub fn wait_done_blocking(&self, timeout: Duration) -> bool {
        let end = std::time::Instant::now() + timeout;
        while !self.is_done() {
            if std::time::Instant::now() >= end {
                return false;
            }
            std::thread::sleep(Duration::from_millis(1));
        }
        true
    }
}

/// The future of [`HaltSignal::requested`].
#[derive(Debug)]
pub struct Requested<'a> {
    signal: &'a HaltSignal,
}

impl Future for Requested<'_> {
    type Output = ();

    fn poll(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<()> {
        if self.signal.is_requested() {
            return Poll::Ready(());
        }
        {
            let mut wakers = self
                .signal
                .inner
                .wakers
                .lock()
                .unwrap_or_else(PoisonError::into_inner);
            if !wakers.iter().any(|w| w.will_wake(cx.waker())) {
                wakers.push(cx.waker().clone());
            }
        }
        // Re-check: a halt between the first check and the registration must not be lost.
        if self.signal.is_requested() {
            Poll::Ready(())
        } else {
            Poll::Pending
        }
    }
}

/// Marks its [`HaltSignal`] done when dropped (see [`HaltSignal::done_on_drop`]).
#[derive(Debug)]
pub struct DoneOnDrop(HaltSignal);

impl Drop for DoneOnDrop {
    fn drop(&mut self) {
        self.0.set_done();
    }
}

/// The halt signals of every device in the process that can move a robot.
///
/// Drivers register themselves (see the [module docs](self)); a program's exit guard calls
/// [`halt_all`](Self::halt_all) and waits.
#[derive(Debug)]
pub struct StopRegistry {
    entries: Mutex<Vec<(String, HaltSignal)>>,
    /// Whether any device ever registered (entries are dropped once their task is done).
    ever: std::sync::atomic::AtomicBool,
}

static GLOBAL: StopRegistry = StopRegistry::new();

impl Default for StopRegistry {
    fn default() -> Self {
        Self::new()
    }
}

impl StopRegistry {
    /// An empty registry (tests; programs use [`global`](Self::global)).
    #[must_use]
    pub const fn new() -> Self {
        Self {
            entries: Mutex::new(Vec::new()),
            ever: std::sync::atomic::AtomicBool::new(false),
        }
    }

    /// The registry of this process.
    #[must_use]
    pub fn global() -> &'static StopRegistry {
        &GLOBAL
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Vec<(String, HaltSignal)>> {
        self.entries.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Register a device's signal under a name for messages (e.g. `"p2os on /dev/ttyS0"`).
    /// Entries whose task is done are dropped at the same time, except those whose stop went
    /// unheard: the program's last words must still name them ([`unheard`](Self::unheard)).
    pub fn register(&self, name: impl Into<String>, signal: HaltSignal) {
        let mut e = self.lock();
        e.retain(|(_, s)| !s.is_done() || s.stopped_unheard());
        e.push((name.into(), signal));
        self.ever.store(true, std::sync::atomic::Ordering::SeqCst);
    }

    /// Whether any device has ever registered in this registry: a program that opened none
    /// (a replay, a decoder, a mock) has nothing it could have stopped.
    #[must_use]
    pub fn ever_registered(&self) -> bool {
        self.ever.load(std::sync::atomic::Ordering::SeqCst)
    }

    /// Halt every registered device whose task is still running; returns how many were asked.
    /// Returns at once.
    pub fn halt_all(&self) -> usize {
        let e = self.lock();
        let mut n = 0;
        for (_, s) in e.iter().filter(|(_, s)| !s.is_done()) {
            s.halt();
            n += 1;
        }
        n
    }

    /// Names of the registered devices whose task has not finished.
    #[must_use]
    pub fn pending(&self) -> Vec<String> {
        self.lock()
            .iter()
            .filter(|(_, s)| !s.is_done())
            .map(|(n, _)| n.clone())
            .collect()
    }

    /// Names of the registered devices whose stop may not have reached them
    /// ([`HaltSignal::set_stopped_unheard`]).
    #[must_use]
    pub fn unheard(&self) -> Vec<String> {
        // One name once (a device reopened under its name after a failure).
        self.of_unheard(|n, _| Some(n.to_owned()))
    }

    /// The watchdogs ([`HaltSignal::watchdog`]) of the devices [`unheard`](Self::unheard)
    /// names, each once.
    #[must_use]
    pub fn unheard_watchdogs(&self) -> Vec<&'static str> {
        self.of_unheard(|_, s| s.watchdog())
    }

    /// `pick` of each registered device whose stop may not have reached it, each value once.
    fn of_unheard<T: PartialEq>(&self, pick: impl Fn(&str, &HaltSignal) -> Option<T>) -> Vec<T> {
        let mut out = Vec::new();
        for (n, s) in self.lock().iter().filter(|(_, s)| s.stopped_unheard()) {
            if let Some(v) = pick(n, s)
                && !out.contains(&v)
            {
                out.push(v);
            }
        }
        out
    }

    /// Whether any registered device's task is still running.
    #[must_use]
    pub fn any_running(&self) -> bool {
        self.lock().iter().any(|(_, s)| !s.is_done())
    }

    /// Block until every registered device is done or `timeout` passes; returns the names of
    /// those still not done. For panic hooks and exit paths outside an async runtime.
    #[must_use]
    pub fn wait_blocking(&self, timeout: Duration) -> Vec<String> {
        let end = std::time::Instant::now() + timeout;
        loop {
            let pending = self.pending();
            if pending.is_empty() || std::time::Instant::now() >= end {
                return pending;
            }
            std::thread::sleep(Duration::from_millis(1));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::AtomicUsize;
    use std::task::Wake;

    struct Count(AtomicUsize);
    impl Wake for Count {
        fn wake(self: Arc<Self>) {
            self.0.fetch_add(1, Ordering::SeqCst);
        }
    }

    #[test]
    fn halt_wakes_a_pending_waiter_and_resolves_later_polls() {
        let s = HaltSignal::new();
        let count = Arc::new(Count(AtomicUsize::new(0)));
        let waker = Waker::from(Arc::clone(&count));
        let mut cx = Context::from_waker(&waker);
        let mut fut = s.requested();
        assert_eq!(Pin::new(&mut fut).poll(&mut cx), Poll::Pending);
        // A second poll with the same waker does not register it twice.
        assert_eq!(Pin::new(&mut fut).poll(&mut cx), Poll::Pending);
        s.clone().halt();
        assert_eq!(count.0.load(Ordering::SeqCst), 1);
        assert_eq!(Pin::new(&mut fut).poll(&mut cx), Poll::Ready(()));
        assert_eq!(Pin::new(&mut s.requested()).poll(&mut cx), Poll::Ready(()));
    }

    #[test]
    fn done_on_drop_marks_done_and_the_registry_forgets_finished_tasks() {
        let reg = StopRegistry::new();
        let a = HaltSignal::new();
        let b = HaltSignal::new();
        assert!(!reg.ever_registered());
        reg.register("a", a.clone());
        reg.register("b", b.clone());
        assert_eq!(reg.pending(), ["a", "b"]);
        assert_eq!(reg.halt_all(), 2);
        assert!(a.is_requested() && b.is_requested());
        drop(a.done_on_drop());
        assert_eq!(reg.pending(), ["b"]);
        assert_eq!(reg.wait_blocking(Duration::from_millis(5)), ["b"]);
        b.set_done();
        assert!(reg.wait_blocking(Duration::from_secs(1)).is_empty());
        assert!(!reg.any_running());
        // Done and forgotten, but it was there: a message may say it was stopped.
        assert!(reg.ever_registered());
        // Registering prunes finished entries: only the new one remains.
        reg.register("c", HaltSignal::new());
        assert_eq!(reg.lock().len(), 1);
        assert_eq!(reg.halt_all(), 1);
    }

    #[test]
    fn the_registry_names_the_devices_stopped_while_unheard() {
        let reg = StopRegistry::new();
        let (heard, unheard) = (HaltSignal::new(), HaltSignal::new());
        reg.register("P2OS base", unheard.clone());
        reg.register("rFLEX base", heard.clone());
        assert!(reg.unheard().is_empty());
        unheard.set_stopped_unheard();
        unheard.set_done();
        heard.set_done();
        assert!(unheard.stopped_unheard() && !heard.stopped_unheard());
        assert_eq!(
            reg.unheard(),
            ["P2OS base"],
            "done devices are still reported"
        );
        // A device opened later (a reconnect, the next robot) prunes the finished entries,
        // but not the one whose stop went unheard: the exit message still names it.
        reg.register("compass", HaltSignal::new());
        assert_eq!(
            reg.unheard(),
            ["P2OS base"],
            "kept through a later register"
        );
        assert_eq!(reg.lock().len(), 2, "the heard, finished entry is dropped");
        // The same device reopened and unheard again is named once.
        let again = HaltSignal::new();
        reg.register("P2OS base", again.clone());
        again.set_stopped_unheard();
        assert_eq!(reg.unheard(), ["P2OS base"]);
        // Its watchdog, as its driver declared it, once too.
        unheard.set_watchdog("P2OS: 2 s");
        again.set_watchdog("P2OS: 2 s");
        heard.set_watchdog("rFLEX: 1 s");
        assert_eq!(reg.unheard_watchdogs(), ["P2OS: 2 s"]);
    }

    #[test]
    fn a_halt_from_another_thread_is_seen_by_a_blocking_waiter() {
        let s = HaltSignal::new();
        let t = {
            let s = s.clone();
            std::thread::spawn(move || {
                while !s.is_requested() {
                    std::thread::yield_now();
                }
                s.set_done();
            })
        };
        s.halt();
        assert!(s.wait_done_blocking(Duration::from_secs(10)));
        t.join().unwrap();
    }
}

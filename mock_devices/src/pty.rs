//! Serve a [`DeviceModel`] on a pseudo-terminal, so a driver opens it like `/dev/ttyS0`.
//!
//! [`PtyDevice::spawn`] creates a pty pair ([`pty_pair`], serialised by a global lock because
//! `TTYPort::pair()` is not known to be thread-safe), keeps the **slave open for the device's
//! whole life** (on Linux the master reads `EIO` once the last slave closes; macOS removes the
//! node) and runs one blocking thread that:
//!
//! 1. reads the master with a short timeout (at most `poll_period`, less when a timer is due),
//! 2. feeds the bytes through a [`DeviceLink`] (faults, model),
//! 3. writes the link's output chunks to the master, one write per chunk.
//!
//! The model's clock ([`ima_hal::Instant`]) starts at [`Instant::ZERO`] when the device is
//! spawned, unless [`PtyOptions::clock`] gives the process's one clock; build timers in the
//! model relative to the `now` of its first call, not to zero.
//!
//! # Stopping
//!
//! [`PtyDevice::stop`] (or dropping the device) stops the thread, closes both ends and gives
//! the model back. [`PtyDevice::hang_up_for`] / [`PtyDevice::hang_up`] /
//! [`PtyDevice::reconnect`] take the link down and up on the **same path** (see
//! [`crate::link`] for why a hang-up is silence rather than a closed pty).
//!
//! # Caveats
//!
//! A pty has no baud rate: bytes arrive as fast as they are written, and consecutive chunks of
//! a split write may be read together by the driver. When the host does not read and the pty
//! buffer is full, a write times out and the chunk is dropped (counted in
//! [`RunnerStatus::write_drops`]), as a UART would overrun.

use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::thread::JoinHandle;
use std::time::Duration;

use ima_hal::Instant;
use ima_hal::time::{Clock, MonotonicClock, SharedClock};
use serialport::{SerialPort, TTYPort};

use crate::faults::FaultPlan;
use crate::link::{DeviceLink, RunnerStatus};
use crate::model::DeviceModel;
use crate::stepper::WorldStepper;
use crate::world::SharedWorld;

static PAIR_LOCK: Mutex<()> = Mutex::new(());

/// `TTYPort::pair()` behind a process-wide lock. Use this (not `pair()` directly) anywhere in
/// the workspace's tests: concurrent `pair()` calls are not known to be safe.
///
/// Both ends are closed on exec: `pair()` opens the master without `O_CLOEXEC`, so every
/// program the process started (a test's `ima`) kept it open, and closing it no longer hung
/// the line up. The ends returned are copies made with `F_DUPFD_CLOEXEC`; the originals are
/// closed here (a program started by another thread in between still inherits them).
pub fn pty_pair() -> serialport::Result<(TTYPort, TTYPort)> {
    let _guard = PAIR_LOCK.lock().unwrap_or_else(PoisonError::into_inner);
    let (master, slave) = TTYPort::pair()?;
    Ok((master.try_clone_native()?, slave.try_clone_native()?))
}

/// Errors of the pty runner.
#[derive(Debug, thiserror::Error)]
pub enum PtyError {
    /// Creating or configuring the pty failed.
    #[error("pty: {0}")]
    Serial(#[from] serialport::Error),
    /// The slave has no path (should not happen on Linux).
    #[error("pty: the slave has no path")]
    NoPath,
    /// Spawning a thread failed.
    #[error("pty: spawning a thread: {0}")]
    Thread(#[from] std::io::Error),
    /// The serving thread panicked (a model bug); the model is lost.
    #[error("pty: the serving thread panicked")]
    Panicked,
}

/// Options of [`PtyDevice::spawn`].
#[derive(Debug, Clone)]
pub struct PtyOptions {
    /// Faults between the model and the port.
    pub faults: FaultPlan,
    /// Longest the thread sleeps in a read before polling the model (default 5 ms).
    pub poll_period: Duration,
    /// If set, this device also steps the world in real time (see [`WorldStepper`]); give it
    /// to exactly one device per world.
    pub step_world: Option<SharedWorld>,
    /// Period of that stepping (default 10 ms).
    pub step_period: Duration,
    /// If set, every chunk the host writes is recorded here with the (wall-clock monotonic)
    /// instant of its arrival, so a test can check what reached the device and when.
    pub host_log: Option<HostLog>,
    /// The clock of the device's model: a process that serves devices to its own drivers
    /// passes its one clock, so the model's and the drivers' instants share one time base.
    /// `None`: a [`MonotonicClock`] starting when the device is spawned.
    pub clock: Option<SharedClock>,
}

/// The bytes a host wrote to a [`PtyDevice`], chunk by chunk, each with the
/// [`std::time::Instant`] of its arrival (comparable across devices and with a test's own
/// clock). Cheap to clone; clones share the record.
#[derive(Debug, Clone, Default)]
pub struct HostLog(Arc<Mutex<Vec<HostChunk>>>);

/// One chunk of a [`HostLog`]: when it arrived and its bytes.
pub type HostChunk = (std::time::Instant, Vec<u8>);

impl HostLog {
    /// An empty record.
    #[must_use]
    pub fn new() -> Self {
        Self::default()
    }

    /// A copy of everything recorded so far.
    #[must_use]
    pub fn snapshot(&self) -> Vec<HostChunk> {
        self.0
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .clone()
    }

    fn push(&self, at: std::time::Instant, bytes: &[u8]) {
        self.0
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .push((at, bytes.to_vec()));
    }
}

impl Default for PtyOptions {
    fn default() -> Self {
        Self {
            faults: FaultPlan::none(),
            poll_period: Duration::from_millis(5),
            step_world: None,
            step_period: WorldStepper::DEFAULT_PERIOD,
            host_log: None,
            clock: None,
        }
    }
}

#[derive(Debug, Clone, Copy)]
enum Control {
    HangUp(Option<Duration>),
    Reconnect,
}

#[derive(Debug)]
struct Shared {
    stop: AtomicBool,
    controls: Mutex<Vec<Control>>,
    status: Mutex<RunnerStatus>,
}

/// A model served on a pty. Stops (and joins its thread) when dropped.
#[derive(Debug)]
pub struct PtyDevice<M> {
    path: PathBuf,
    shared: Arc<Shared>,
    clock: SharedClock,
    thread: Option<JoinHandle<M>>,
    stepper: Option<WorldStepper>,
}

impl<M: DeviceModel + 'static> PtyDevice<M> {
    /// Create a pty and serve `model` on it until stopped.
    pub fn spawn(model: M, opts: PtyOptions) -> Result<Self, PtyError> {
        // The stepper first: if it fails nothing else is running yet.
        let stepper = match opts.step_world {
            Some(w) => Some(WorldStepper::spawn(w, opts.step_period)?),
            None => None,
        };
        let (mut master, slave) = pty_pair()?;
        let path = PathBuf::from(slave.name().ok_or(PtyError::NoPath)?);
        master.set_timeout(opts.poll_period)?;
        let clock: SharedClock = opts
            .clock
            .clone()
            .unwrap_or_else(|| Arc::new(MonotonicClock::new()));
        let shared = Arc::new(Shared {
            stop: AtomicBool::new(false),
            controls: Mutex::new(Vec::new()),
            status: Mutex::new(RunnerStatus::default()),
        });
        let link = DeviceLink::new(model, &opts.faults, clock.now());
        let host_log = opts.host_log.clone();
        let thread_shared = Arc::clone(&shared);
        let thread_clock = clock.clone();
        let poll_period = opts.poll_period.max(Duration::from_millis(1));
        let name = format!("ima-pty-{}", link.model().name());
        let thread = std::thread::Builder::new().name(name).spawn(move || {
            // The slave lives (open) exactly as long as the serving thread.
            serve(
                link,
                master,
                slave,
                &*thread_clock,
                poll_period,
                &thread_shared,
                host_log.as_ref(),
            )
        })?;
        tracing::debug!(path = %path.display(), "pty device serving");
        Ok(Self {
            path,
            shared,
            clock,
            thread: Some(thread),
            stepper,
        })
    }

    /// The slave path (`/dev/pts/N`) a driver opens.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The device's clock (the model's `now`), for scheduling relative to it.
    pub fn now(&self) -> Instant {
        self.clock.now()
    }

    /// Take the link down for `outage`: silent and deaf on the same path, then back.
    pub fn hang_up_for(&self, outage: Duration) {
        self.control(Control::HangUp(Some(outage)));
    }

    /// Take the link down until [`PtyDevice::reconnect`]. (A hang-up *for good* comes only
    /// from a fault spec.)
    pub fn hang_up(&self) {
        self.control(Control::HangUp(Some(Duration::from_secs(u64::from(
            u32::MAX,
        )))));
    }

    /// End an outage now.
    pub fn reconnect(&self) {
        self.control(Control::Reconnect);
    }

    fn control(&self, c: Control) {
        self.shared
            .controls
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .push(c);
    }

    /// Counters and state as of the thread's last loop (≤ `poll_period` old).
    pub fn status(&self) -> RunnerStatus {
        *self
            .shared
            .status
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
    }

    /// Stop serving, close the pty and return the model.
    pub fn stop(mut self) -> Result<M, PtyError> {
        self.halt().ok_or(PtyError::Panicked)
    }

    fn halt(&mut self) -> Option<M> {
        self.shared.stop.store(true, Ordering::Relaxed);
        if let Some(s) = self.stepper.take() {
            s.stop();
        }
        self.thread.take().and_then(|t| t.join().ok())
    }
}

impl<M> Drop for PtyDevice<M> {
    fn drop(&mut self) {
        self.shared.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn serve<M: DeviceModel>(
    mut link: DeviceLink<M>,
    mut master: TTYPort,
    slave: TTYPort,
    clock: &dyn Clock,
    poll_period: Duration,
    shared: &Shared,
    host_log: Option<&HostLog>,
) -> M {
    let mut buf = vec![0u8; 4096];
    let mut write_drops = 0u64;
    let mut io_errors = 0u64;
    let mut timeout = poll_period;
    let mut host_baud: Option<u32> = None;
    while !shared.stop.load(Ordering::Relaxed) {
        let controls: Vec<Control> = std::mem::take(
            &mut *shared
                .controls
                .lock()
                .unwrap_or_else(PoisonError::into_inner),
        );
        let now = clock.now();
        for c in controls {
            match c {
                Control::HangUp(o) => {
                    link.hang_up(now, o);
                    // Forget what the host had sent and we had not read yet.
                    let _ = master.clear(serialport::ClearBuffer::All);
                }
                Control::Reconnect => link.reconnect(now),
            }
        }
        link.poll(now);
        while let Some(chunk) = link.pop_to_host(now) {
            let r = master.write_all(&chunk).and_then(|()| master.flush());
            match r {
                Ok(()) => {}
                Err(e) if e.kind() == std::io::ErrorKind::TimedOut => write_drops += 1,
                Err(e) => {
                    io_errors += 1;
                    tracing::warn!(error = %e, "pty write failed");
                }
            }
        }
        {
            let mut st = shared.status.lock().unwrap_or_else(PoisonError::into_inner);
            *st = RunnerStatus {
                counters: link.counters(),
                state: link.state(),
                write_drops,
                io_errors,
            };
        }
        // Sleep in the read until input, the next timer, or the poll period.
        let now = clock.now();
        let wait = link
            .next_wakeup()
            .map_or(poll_period, |t| t.saturating_duration_since(now))
            .clamp(Duration::from_millis(1), poll_period);
        if wait != timeout && master.set_timeout(wait).is_ok() {
            timeout = wait;
        }
        match master.read(&mut buf) {
            Ok(n) => {
                // The host sets its line speed on its own descriptor of the slave; a tty has
                // one set of line settings, so the slave we hold shows it.
                let baud = serialport::SerialPort::baud_rate(&slave).ok();
                if baud != host_baud {
                    host_baud = baud;
                    link.model_mut().set_host_baud(baud);
                }
                if let Some(bytes) = buf.get(..n) {
                    if let Some(log) = host_log {
                        log.push(std::time::Instant::now(), bytes);
                    }
                    link.from_host(bytes, clock.now());
                }
            }
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {}
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => {
                io_errors += 1;
                tracing::warn!(error = %e, "pty read failed");
                std::thread::sleep(poll_period);
            }
        }
    }
    drop(slave);
    link.into_model()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pair_gives_a_pts_path() {
        let (_m, s) = pty_pair().unwrap();
        assert!(s.name().unwrap().starts_with("/dev/pts/"));
    }
}

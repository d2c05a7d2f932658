//! Serve a [`DeviceModel`] over an in-memory `tokio::io::duplex` pipe, for fast tests.
//!
//! [`DuplexDevice::spawn`] (inside a tokio runtime) returns the host end of the pipe — a
//! [`DuplexStream`], which is `AsyncRead + AsyncWrite` like a `tokio_serial::SerialStream` —
//! and a handle. A task runs the same [`DeviceLink`] as the pty runner (same model, same
//! faults). The model's clock is tokio's clock, starting at [`Instant::ZERO`] at spawn, so
//! under `#[tokio::test(start_paused = true)]` a test runs in virtual time.
//!
//! Differences from the pty: a hang-up **for good** (a fault spec `hangup=…` without an
//! outage) shuts the pipe, so the host reads EOF; a timed outage is silence as on the pty.
//! The task ends (and returns the model) on [`DuplexDevice::stop`], when the handle is dropped,
//! when the host end is dropped, or after a hang-up for good.

use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use ima_hal::Instant;
use tokio::io::{AsyncReadExt, AsyncWriteExt, DuplexStream};
use tokio::sync::mpsc;
use tokio::task::JoinHandle;

use crate::faults::FaultPlan;
use crate::link::{DeviceLink, LinkState, RunnerStatus};
use crate::model::DeviceModel;

/// Options of [`DuplexDevice::spawn`].
#[derive(Debug, Clone)]
pub struct DuplexOptions {
    /// Faults between the model and the pipe.
    pub faults: FaultPlan,
    /// Longest the task waits before polling the model (default 5 ms).
    pub poll_period: Duration,
    /// Pipe buffer per direction, bytes (default 64 KiB).
    pub buffer: usize,
    /// Longest a write to the host may block before the chunk is dropped (default 1 s).
    pub write_timeout: Duration,
}

impl Default for DuplexOptions {
    fn default() -> Self {
        Self {
            faults: FaultPlan::none(),
            poll_period: Duration::from_millis(5),
            buffer: 64 * 1024,
            write_timeout: Duration::from_secs(1),
        }
    }
}

/// Errors of the duplex runner.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum DuplexError {
    /// The serving task panicked or was cancelled; the model is lost.
    #[error("duplex: the serving task failed")]
    TaskFailed,
}

#[derive(Debug, Clone, Copy)]
enum Control {
    HangUp(Option<Duration>),
    Reconnect,
    Stop,
}

/// A model served on an in-memory pipe.
#[derive(Debug)]
pub struct DuplexDevice<M> {
    controls: mpsc::UnboundedSender<Control>,
    status: Arc<Mutex<RunnerStatus>>,
    task: JoinHandle<M>,
}

impl<M: DeviceModel + 'static> DuplexDevice<M> {
    /// Serve `model`; returns the host end of the pipe and the handle. Must be called inside a
    /// tokio runtime.
    pub fn spawn(model: M, opts: DuplexOptions) -> (DuplexStream, Self) {
        let (host, device) = tokio::io::duplex(opts.buffer.max(1));
        let (tx, rx) = mpsc::unbounded_channel();
        let status = Arc::new(Mutex::new(RunnerStatus::default()));
        let task = tokio::spawn(serve(model, device, rx, Arc::clone(&status), opts));
        (
            host,
            Self {
                controls: tx,
                status,
                task,
            },
        )
    }

    /// Take the link down for `outage`, then back.
    pub fn hang_up_for(&self, outage: Duration) {
        let _ = self.controls.send(Control::HangUp(Some(outage)));
    }

    /// End an outage now.
    pub fn reconnect(&self) {
        let _ = self.controls.send(Control::Reconnect);
    }

    /// Counters and state as of the task's last loop.
    pub fn status(&self) -> RunnerStatus {
        *self.status.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// `true` once the task has ended (stopped, host gone, or hung up for good).
    pub fn is_finished(&self) -> bool {
        self.task.is_finished()
    }

    /// Stop serving and return the model.
    pub async fn stop(self) -> Result<M, DuplexError> {
        let _ = self.controls.send(Control::Stop);
        self.task.await.map_err(|_| DuplexError::TaskFailed)
    }
}

async fn serve<M: DeviceModel>(
    model: M,
    mut pipe: DuplexStream,
    mut controls: mpsc::UnboundedReceiver<Control>,
    status: Arc<Mutex<RunnerStatus>>,
    opts: DuplexOptions,
) -> M {
    let start = tokio::time::Instant::now();
    let clock = move || {
        let us = tokio::time::Instant::now()
            .saturating_duration_since(start)
            .as_micros();
        Instant::from_micros(u64::try_from(us).unwrap_or(u64::MAX))
    };
    let poll_period = opts.poll_period.max(Duration::from_micros(100));
    let mut link = DeviceLink::new(model, &opts.faults, clock());
    let mut buf = vec![0u8; 4096];
    let mut write_drops = 0u64;
    let mut io_errors = 0u64;
    'serve: loop {
        let now = clock();
        link.poll(now);
        while let Some(chunk) = link.pop_to_host(now) {
            match tokio::time::timeout(opts.write_timeout, pipe.write_all(&chunk)).await {
                Ok(Ok(())) => {}
                Ok(Err(_)) => break 'serve, // host end gone
                Err(_) => write_drops += 1,
            }
        }
        *status.lock().unwrap_or_else(PoisonError::into_inner) = RunnerStatus {
            counters: link.counters(),
            state: link.state(),
            write_drops,
            io_errors,
        };
        if link.state() == LinkState::Closed {
            let _ = pipe.shutdown().await;
            break;
        }
        let now = clock();
        let wait = link
            .next_wakeup()
            .map_or(poll_period, |t| t.saturating_duration_since(now))
            // Never spin, even if a model keeps asking for a timeout in the past.
            .clamp(Duration::from_micros(100), poll_period);
        tokio::select! {
            r = pipe.read(&mut buf) => match r {
                Ok(0) => break 'serve,
                Ok(n) => {
                    if let Some(bytes) = buf.get(..n) {
                        link.from_host(bytes, clock());
                    }
                }
                Err(_) => {
                    io_errors += 1;
                    break 'serve;
                }
            },
            c = controls.recv() => match c {
                Some(Control::HangUp(o)) => link.hang_up(clock(), o),
                Some(Control::Reconnect) => link.reconnect(clock()),
                Some(Control::Stop) | None => break 'serve,
            },
            () = tokio::time::sleep(wait) => {}
        }
    }
    *status.lock().unwrap_or_else(PoisonError::into_inner) = RunnerStatus {
        counters: link.counters(),
        state: link.state(),
        write_drops,
        io_errors,
    };
    link.into_model()
}

//! The blocking runner (feature `serial`): the same rounds as the [async runner](crate::runner)
//! over any `Read + Write` stream, for tools that do not want an async runtime.
//!
//! The stream's `read` must return within a few milliseconds when nothing arrives (a port
//! from [`open_blocking_port`](crate::open_blocking_port) has a 10 ms timeout): the machine's
//! timers run between reads. Time advances only inside the runner's calls; a tool that stops
//! calling for longer than a device's watchdog lets the device stop, the safe outcome.

use std::io::{self, Read, Write};
use std::time::Duration;

use ima_hal::Instant;
use ima_hal::time::{Clock, SharedClock};
use tokio::sync::oneshot;

use crate::runner::{End, Flow, Shell, drain};
use crate::{BaudControl, LinkError, Machine};

/// A [`Shell`] run synchronously over `S`.
#[derive(Debug)]
pub struct Blocking<D, S> {
    shell: D,
    stream: S,
    clock: SharedClock,
    tbuf: Vec<u8>,
    failed: Option<LinkError>,
}

impl<D: Shell, S: Read + Write + BaudControl> Blocking<D, S> {
    /// Start `shell` over `stream`, with `clock` as its time (nothing is sent until the
    /// first [`pump_once`](Self::pump_once)).
    pub fn new(mut shell: D, stream: S, clock: SharedClock) -> Self {
        shell.start(clock.now());
        Self {
            shell,
            stream,
            clock,
            tbuf: vec![0u8; D::MAX_FRAME],
            failed: None,
        }
    }

    /// The shell.
    pub fn shell(&self) -> &D {
        &self.shell
    }

    /// The shell, mutably.
    pub fn shell_mut(&mut self) -> &mut D {
        &mut self.shell
    }

    /// The runner's clock.
    pub fn now(&self) -> Instant {
        self.clock.now()
    }

    /// One round: events, frames due, one read (up to the stream's timeout), due timers.
    ///
    /// # Errors
    /// The link's failure (end of stream, I/O error); it is final.
    pub fn pump_once(&mut self) -> Result<(), LinkError> {
        if let Some(e) = self.failed {
            return Err(e);
        }
        let r = self.round();
        if let Err(e) = r {
            self.failed = Some(e);
            self.shell.end(End::Failed(e));
        }
        r
    }

    fn round(&mut self) -> Result<(), LinkError> {
        drain(&mut self.shell, &mut self.stream)?;
        let now = self.clock.now();
        while let Some(n) = self.shell.machine().poll_transmit(now, &mut self.tbuf) {
            let Some(frame) = self.tbuf.get(..n) else {
                break;
            };
            self.stream.write_all(frame)?;
        }
        let _ = self.stream.flush();
        self.shell.after_round();
        let mut rbuf = [0u8; 1024];
        match self.stream.read(&mut rbuf) {
            Ok(0) => return Err(LinkError::Disconnected),
            Ok(n) => {
                let now = self.clock.now();
                self.shell.on_bytes(rbuf.get(..n).unwrap_or(&[]), now);
            }
            Err(e)
                if matches!(
                    e.kind(),
                    io::ErrorKind::TimedOut
                        | io::ErrorKind::WouldBlock
                        | io::ErrorKind::Interrupted
                ) => {}
            Err(e) => return Err(e.into()),
        }
        let now = self.clock.now();
        if self.shell.next_wake().is_some_and(|t| t <= now) {
            self.shell.on_timeout(now);
        }
        drain(&mut self.shell, &mut self.stream)?;
        Ok(())
    }

    /// Run rounds for `d` (to wait while staying connected).
    ///
    /// # Errors
    /// As [`pump_once`](Self::pump_once).
    pub fn pump_for(&mut self, d: Duration) -> Result<(), LinkError> {
        let end = self.clock.now() + d;
        while self.clock.now() < end {
            self.pump_once()?;
        }
        Ok(())
    }

    /// Run rounds until `pick` finds what it wants in the shell, at most `timeout`.
    ///
    /// # Errors
    /// [`LinkError::Timeout`], or the link's failure.
    pub fn wait_for<R>(
        &mut self,
        timeout: Duration,
        mut pick: impl FnMut(&mut D) -> Option<R>,
    ) -> Result<R, LinkError> {
        let end = self.clock.now() + timeout;
        loop {
            if let Some(r) = pick(&mut self.shell) {
                return Ok(r);
            }
            if self.clock.now() >= end {
                return Err(LinkError::Timeout);
            }
            self.pump_once()?;
        }
    }

    /// Run rounds until `link` is connected (its connection) or failed (the error), at most
    /// `timeout`.
    ///
    /// # Errors
    /// The link's failure, or [`LinkError::Timeout`] (converted).
    pub fn wait_connected<U: Clone, E: Clone + From<LinkError>>(
        &mut self,
        link: &tokio::sync::watch::Receiver<crate::LinkStatus<U, E>>,
        timeout: Duration,
    ) -> Result<U, E> {
        self.wait_for(timeout, |_| match &*link.borrow() {
            crate::LinkStatus::Connected(u) => Some(Ok(u.clone())),
            crate::LinkStatus::Failed(e) => Some(Err(e.clone())),
            _ => None,
        })?
    }

    /// Hand the shell a request made by `make` around a reply channel, then run rounds
    /// until it answers, at most `timeout`.
    ///
    /// # Errors
    /// The shell's answer; [`LinkError::Timeout`], or the link's failure.
    pub fn request<T, E: From<LinkError>>(
        &mut self,
        make: impl FnOnce(oneshot::Sender<Result<T, E>>) -> D::Request,
        timeout: Duration,
    ) -> Result<T, E> {
        let (reply, mut rx) = oneshot::channel();
        let now = self.clock.now();
        if self.shell.on_request(make(reply), now) == Flow::Close {
            return Err(LinkError::Disconnected.into());
        }
        // At least one round: what the request queued goes out now.
        self.pump_once()?;
        self.wait_for(timeout, |_| match rx.try_recv() {
            Ok(r) => Some(Some(r)),
            Err(oneshot::error::TryRecvError::Empty) => None,
            Err(oneshot::error::TryRecvError::Closed) => Some(None),
        })?
        .unwrap_or(Err(LinkError::Disconnected.into()))
    }

    /// Close: let the shell queue its last frames and write them (bounded by
    /// [`Shell::begin_close`]); gives the stream back with the outcome:
    /// [`LinkError::Timeout`] if they were not all written in time, or the link's failure.
    pub fn close(mut self) -> (S, Result<(), LinkError>) {
        let r = self.drain_close();
        (self.stream, r)
    }

    fn drain_close(&mut self) -> Result<(), LinkError> {
        if let Some(e) = self.failed {
            return Err(e);
        }
        let now = self.clock.now();
        let end = now + self.shell.begin_close(now);
        let drained = loop {
            if self.shell.is_closed() {
                break true;
            }
            if self.clock.now() >= end {
                break false;
            }
            self.pump_once()?;
        };
        self.shell.end(End::Closed { drained });
        if drained {
            Ok(())
        } else {
            Err(LinkError::Timeout)
        }
    }
}

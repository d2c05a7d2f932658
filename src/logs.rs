//! Log lines written by a thread of their own: a driver task that logs never waits on a
//! terminal. A stderr nobody reads (an SSH session that stalled, `2>&1 | less` not scrolled)
//! once blocked the driver at its first warning, so nothing more reached the robot, not even
//! the STOP of a Ctrl-C.
//!
//! Each event is one message on a bounded queue ([`QUEUE`] lines); a line that finds the
//! queue full is dropped and counted, and the count is said at the next [`Logs::flush`] that
//! gets through. [`Logs::flush`] waits a bounded time for the lines queued before it, so a
//! stalled stderr cannot hold an exit up. (`tracing-appender`'s writer does the same, but on
//! a shutdown that times out it prints to stdout, which may be the stalled terminal too, a
//! closed pipe, or `--json` output.)

use std::io::Write as _;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, Sender, SyncSender, sync_channel};
use std::time::Duration;

/// Lines that may wait for stderr before new ones are dropped.
pub const QUEUE: usize = 4096;

enum Msg {
    Line(Vec<u8>),
    /// Answered once every line queued before it is written.
    Flush(Sender<()>),
}

/// Where log lines go (a [`tracing_subscriber::fmt::MakeWriter`]); cheap to clone.
#[derive(Clone)]
pub struct Logs {
    tx: SyncSender<Msg>,
}

/// Lines dropped because the queue was full.
static DROPPED: AtomicU64 = AtomicU64::new(0);

impl Logs {
    /// Start the writing thread. If it cannot start, lines are dropped (and counted).
    #[must_use]
    pub fn start() -> Self {
        let (tx, rx) = sync_channel(QUEUE);
        let _ = std::thread::Builder::new()
            .name("ima-log".into())
            .spawn(move || write_out(&rx));
        Self { tx }
    }

    /// Queue `bytes` as one message; dropped (and counted) when the queue is full.
    pub fn send(&self, bytes: Vec<u8>) {
        if self.tx.try_send(Msg::Line(bytes)).is_err() {
            DROPPED.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// Wait up to `wait` for every line queued so far to be written; whether they were.
    pub fn flush(&self, wait: Duration) -> bool {
        let dropped = DROPPED.swap(0, Ordering::Relaxed);
        if dropped > 0 {
            self.send(
                format!("ima: {dropped} log line(s) dropped: stderr did not keep up\n")
                    .into_bytes(),
            );
        }
        let (ack, done) = std::sync::mpsc::channel();
        if self.tx.try_send(Msg::Flush(ack)).is_err() {
            return false;
        }
        done.recv_timeout(wait).is_ok()
    }
}

fn write_out(rx: &Receiver<Msg>) {
    let mut err = std::io::stderr();
    for m in rx {
        match m {
            // Nowhere left to report a failed write.
            Msg::Line(b) => drop(err.write_all(&b)),
            Msg::Flush(ack) => drop(ack.send(())),
        }
    }
}

/// One event's text, sent whole when the formatter is done with it.
pub struct Line {
    logs: Logs,
    buf: Vec<u8>,
}

impl std::io::Write for Line {
    fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
        self.buf.extend_from_slice(b);
        Ok(b.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

impl Drop for Line {
    fn drop(&mut self) {
        if !self.buf.is_empty() {
            self.logs.send(std::mem::take(&mut self.buf));
        }
    }
}

impl<'a> tracing_subscriber::fmt::MakeWriter<'a> for Logs {
    type Writer = Line;

    fn make_writer(&'a self) -> Line {
        Line {
            logs: self.clone(),
            buf: Vec::new(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Lines go out whole and in order; a flush waits for them.
    #[test]
    fn lines_are_sent_whole_and_flushed() {
        let logs = Logs::start();
        let (tx, rx) = sync_channel(QUEUE);
        let mine = Logs { tx };
        {
            let mut l = tracing_subscriber::fmt::MakeWriter::make_writer(&mine);
            l.write_all(b"one ").unwrap();
            l.write_all(b"line\n").unwrap();
        }
        match rx.try_recv() {
            Ok(Msg::Line(b)) => assert_eq!(b, b"one line\n"),
            _ => panic!("no line"),
        }
        assert!(logs.flush(Duration::from_secs(5)));
    }

    /// A full queue drops (and counts) instead of blocking.
    #[test]
    fn a_full_queue_drops_instead_of_blocking() {
        let (tx, _rx) = sync_channel(2);
        let logs = Logs { tx };
        let before = DROPPED.load(Ordering::Relaxed);
        for _ in 0..5 {
            logs.send(b"x\n".to_vec());
        }
        assert!(DROPPED.load(Ordering::Relaxed) >= before + 3);
        // Nobody writes these out: the flush gives up in its time.
        assert!(!logs.flush(Duration::from_millis(50)));
    }
}

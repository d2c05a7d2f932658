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
//!
//! The program's own messages (the crate's `eprintln!`: `ima run`'s event lines, the demo's
//! live lines, warnings) take the same queue ([`Logs::say`]), in order with the log lines: a
//! task printing them never waits on stderr either (one that did froze a worker thread of a
//! robot's runtime until stderr was read). A message that finds stderr closed ends the
//! command as a closed stdout does (`safety::output_closed`, status 141). The last error
//! line waits for room in the queue for a bounded time ([`Logs::say_last`]), and if stderr
//! does not keep up at the exit, the caller writes it after giving up the rest
//! ([`Logs::abandon`]).

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::mpsc::{Receiver, Sender, SyncSender, TrySendError, sync_channel};
use std::time::{Duration, Instant};

/// Lines that may wait for stderr before new ones are dropped.
pub const QUEUE: usize = 4096;

enum Msg {
    /// A log line: a failed write is ignored.
    Line(Vec<u8>),
    /// The program's own message: a closed stderr ends the command.
    Said(Vec<u8>),
    /// The last error line ([`Logs::say_last`]): written by whoever claims it first, the
    /// writing thread or [`Logs::abandon`]'s caller, never twice.
    Last(Vec<u8>),
    /// Answered once every line queued before it is written.
    Flush(Sender<()>),
}

/// Where log lines go (a [`tracing_subscriber::fmt::MakeWriter`]); cheap to clone.
#[derive(Clone)]
pub struct Logs {
    tx: SyncSender<Msg>,
    state: Arc<State>,
}

/// Shared with the writing thread.
#[derive(Default)]
struct State {
    /// Lines and messages queued and not yet written (or dropped).
    queued: AtomicUsize,
    /// Set by [`Logs::abandon`]: what is still queued is dropped, not written.
    abandoned: AtomicBool,
    /// Lines and messages dropped because the queue was full, not yet said.
    dropped: AtomicU64,
    /// Lines and messages written so far (whether stderr is being read at all).
    written: AtomicU64,
    /// Whether the last error line is claimed, by the writing thread or by
    /// [`Logs::abandon`]'s caller: whoever sets it writes the line.
    last_claimed: AtomicBool,
}

impl Logs {
    /// Start the writing thread. If it cannot start, log lines are dropped (and counted), and
    /// the program's own messages are written by their callers ([`say`](Self::say)).
    #[must_use]
    pub fn start() -> Self {
        Self::start_with(std::io::stderr(), crate::safety::output_closed)
    }

    /// [`start`](Self::start) writing to `out`, calling `closed` when one of the program's
    /// own messages finds it closed (a broken pipe).
    fn start_with(out: impl std::io::Write + Send + 'static, closed: fn()) -> Self {
        let (tx, rx) = sync_channel(QUEUE);
        let state = Arc::new(State::default());
        let st = Arc::clone(&state);
        let _ = std::thread::Builder::new()
            .name("ima-log".into())
            .spawn(move || write_out(&rx, out, closed, &st));
        Self { tx, state }
    }

    /// Queue `m`; `Full` or `Disconnected` gives it back.
    fn queue(&self, m: Msg) -> Result<(), TrySendError<Msg>> {
        let counted = !matches!(m, Msg::Flush(_));
        if counted {
            self.state.queued.fetch_add(1, Ordering::SeqCst);
        }
        let r = self.tx.try_send(m);
        if r.is_err() && counted {
            self.state.queued.fetch_sub(1, Ordering::SeqCst);
        }
        r
    }

    /// [`queue`](Self::queue), retrying while the queue is full until `deadline`.
    fn queue_by(&self, mut m: Msg, deadline: Instant) -> Result<(), TrySendError<Msg>> {
        loop {
            match self.queue(m) {
                Err(TrySendError::Full(back)) if Instant::now() < deadline => {
                    m = back;
                    std::thread::sleep(Duration::from_millis(5));
                }
                r => return r,
            }
        }
    }

    /// Queue `bytes` as one log line; dropped (and counted) when the queue is full.
    pub fn send(&self, bytes: Vec<u8>) {
        if self.queue(Msg::Line(bytes)).is_err() {
            self.state.dropped.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// Queue `bytes` as one of the program's own messages; dropped (and counted) when the
    /// queue is full. A closed stderr found writing it ends the command.
    ///
    /// # Errors
    /// The message back if no thread writes the queue out (it could not start): the caller
    /// writes it itself.
    pub fn say(&self, bytes: Vec<u8>) -> Result<(), Vec<u8>> {
        match self.queue(Msg::Said(bytes)) {
            Ok(()) => Ok(()),
            Err(TrySendError::Full(_)) => {
                self.state.dropped.fetch_add(1, Ordering::Relaxed);
                Ok(())
            }
            Err(TrySendError::Disconnected(Msg::Said(b))) => Err(b),
            Err(TrySendError::Disconnected(_)) => Ok(()),
        }
    }

    /// Queue the last error line, waiting for room until `deadline`; whether it was queued.
    /// If it is still unwritten when the queue is given up ([`abandon`](Self::abandon)), the
    /// caller writes it: the writing thread and the caller claim it, once.
    ///
    /// # Errors
    /// The line back if no thread writes the queue out.
    pub fn say_last(&self, bytes: Vec<u8>, deadline: Instant) -> Result<bool, Vec<u8>> {
        self.state.last_claimed.store(false, Ordering::SeqCst);
        match self.queue_by(Msg::Last(bytes), deadline) {
            Ok(()) => Ok(true),
            // Counted, as [`abandon`](Self::abandon) counts a queued one.
            Err(TrySendError::Full(_)) => {
                self.state.dropped.fetch_add(1, Ordering::Relaxed);
                Ok(false)
            }
            Err(TrySendError::Disconnected(Msg::Last(b))) => Err(b),
            Err(TrySendError::Disconnected(_)) => Ok(false),
        }
    }

    /// Wait up to `wait` for every line queued so far to be written; whether they were. The
    /// lines dropped so far are said first (the count is kept until the note is queued), and
    /// a full queue is waited on for room, within the same time.
    pub fn flush(&self, wait: Duration) -> bool {
        let deadline = Instant::now() + wait;
        let dropped = self.state.dropped.load(Ordering::Relaxed);
        if dropped > 0 {
            let note = format!("ima: {dropped} message(s) dropped: stderr did not keep up\n");
            if self
                .queue_by(Msg::Line(note.into_bytes()), deadline)
                .is_ok()
            {
                self.state.dropped.fetch_sub(dropped, Ordering::Relaxed);
            }
        }
        let (ack, done) = std::sync::mpsc::channel();
        if self.queue_by(Msg::Flush(ack), deadline).is_err() {
            return false;
        }
        done.recv_timeout(deadline.saturating_duration_since(Instant::now()))
            .is_ok()
    }

    /// Lines and messages written so far: whether stderr is read at all, however slowly.
    pub fn written(&self) -> u64 {
        self.state.written.load(Ordering::SeqCst)
    }

    /// Give up on what is still queued (stderr did not keep up at the exit): the writing
    /// thread drops it instead of writing it. How many lines and messages were not written
    /// (the one being written may still get through), with those dropped before and not yet
    /// said, the last error line left out; and whether that line is the caller's to write
    /// (the writing thread has not taken it).
    pub fn abandon(&self) -> (usize, bool) {
        self.state.abandoned.store(true, Ordering::SeqCst);
        let mine = !self.state.last_claimed.swap(true, Ordering::SeqCst);
        let dropped = self.state.dropped.swap(0, Ordering::Relaxed);
        let dropped = usize::try_from(dropped).unwrap_or(usize::MAX);
        let lost = self
            .state
            .queued
            .load(Ordering::SeqCst)
            .saturating_add(dropped);
        (lost, mine)
    }
}

fn write_out(rx: &Receiver<Msg>, mut out: impl std::io::Write, closed: fn(), st: &State) {
    for m in rx {
        let abandoned = st.abandoned.load(Ordering::SeqCst);
        match m {
            Msg::Line(_) | Msg::Said(_) | Msg::Last(_) if abandoned => {}
            Msg::Last(b) => {
                let claimed = !st.last_claimed.swap(true, Ordering::SeqCst);
                if claimed
                    && let Err(e) = out.write_all(&b)
                    && e.kind() == std::io::ErrorKind::BrokenPipe
                {
                    closed();
                }
            }
            // Nowhere left to report a failed write.
            Msg::Line(b) => drop(out.write_all(&b)),
            Msg::Said(b) => {
                if let Err(e) = out.write_all(&b)
                    && e.kind() == std::io::ErrorKind::BrokenPipe
                {
                    closed();
                }
            }
            Msg::Flush(ack) => {
                let _ = ack.send(());
                continue;
            }
        }
        if !abandoned {
            st.written.fetch_add(1, Ordering::SeqCst);
        }
        st.queued.fetch_sub(1, Ordering::SeqCst);
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
    use std::io::Write as _;

    /// A stderr whose writes block until released, sending what each one writes when it
    /// starts.
    struct Gate {
        entered: std::sync::mpsc::Sender<Vec<u8>>,
        release: Receiver<()>,
    }

    impl Gate {
        /// The gate, what its writes start with, and its release (dropping it opens it).
        fn new() -> (Self, Receiver<Vec<u8>>, Sender<()>) {
            let (entered_tx, entered) = std::sync::mpsc::channel();
            let (release, release_rx) = std::sync::mpsc::channel();
            let gate = Self {
                entered: entered_tx,
                release: release_rx,
            };
            (gate, entered, release)
        }
    }

    impl std::io::Write for Gate {
        fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
            let _ = self.entered.send(b.to_vec());
            let _ = self.release.recv();
            Ok(b.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    /// Lines go out whole and in order; a flush waits for them.
    #[test]
    fn lines_are_sent_whole_and_flushed() {
        let logs = Logs::start();
        let (tx, rx) = sync_channel(QUEUE);
        let mine = Logs {
            tx,
            state: Arc::default(),
        };
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
        let logs = Logs {
            tx,
            state: Arc::default(),
        };
        let before = logs.state.dropped.load(Ordering::Relaxed);
        for _ in 0..5 {
            logs.send(b"x\n".to_vec());
        }
        assert!(logs.state.dropped.load(Ordering::Relaxed) >= before + 3);
        // Nobody writes these out: the flush gives up in its time.
        assert!(!logs.flush(Duration::from_millis(50)));
    }

    /// The program's own messages never wait for a stderr nobody reads (the pipe is full):
    /// they queue, then are dropped and counted; a flush gives up in its time.
    #[test]
    fn messages_to_a_stalled_stderr_return_at_once() {
        let (reader, writer) = std::io::pipe().unwrap();
        // Fill the pipe (its writes block from then on) until the reader is dropped.
        let mut filler = writer.try_clone().unwrap();
        let fill = std::thread::spawn(move || while filler.write_all(&[b'.'; 4096]).is_ok() {});
        std::thread::sleep(Duration::from_millis(300));
        let logs = Logs::start_with(writer, || {});
        let (done_tx, done) = std::sync::mpsc::channel();
        let sayer = std::thread::spawn(move || {
            for i in 0..2 * QUEUE {
                logs.say(format!("line {i}\n").into_bytes()).unwrap();
            }
            done_tx
                .send(logs.flush(Duration::from_millis(100)))
                .unwrap();
        });
        // Generous: a message that waited for stderr would never return at all.
        let flushed = done.recv_timeout(Duration::from_secs(30));
        assert_eq!(flushed, Ok(false), "the messages waited for stderr");
        sayer.join().unwrap();
        drop(reader); // the blocked writes fail, and both threads end
        fill.join().unwrap();
    }

    /// Behind a stderr nobody reads, the count of what was dropped is kept until its note can
    /// be queued (it was reset, and the note dropped with the queue full), and giving up
    /// counts everything not written.
    #[test]
    fn the_dropped_count_survives_a_full_queue_and_abandon_counts_all() {
        let (gate, entered, release) = Gate::new();
        let logs = Logs::start_with(gate, || {});
        // The writing thread takes the first and blocks on it; the queue fills behind.
        logs.say(b"first\n".to_vec()).unwrap();
        entered.recv_timeout(Duration::from_secs(30)).unwrap();
        for i in 0..QUEUE + 10 {
            logs.say(format!("line {i}\n").into_bytes()).unwrap();
        }
        assert_eq!(logs.state.dropped.load(Ordering::Relaxed), 10);
        assert!(!logs.flush(Duration::from_millis(50)));
        assert_eq!(logs.state.dropped.load(Ordering::Relaxed), 10);
        // The last error line, queued behind them, is left to the caller when given up.
        assert!(!logs.say_last(b"error\n".to_vec(), Instant::now()).unwrap());
        // Not written: the one being written, the queue's, the dropped and the error line.
        assert_eq!(logs.abandon(), (1 + QUEUE + 10 + 1, true));
        drop(release);
    }

    /// The last error line is written once: by the writing thread if it took it before the
    /// queue was given up (the caller must not write it again), else by the caller.
    #[test]
    fn the_last_error_line_is_written_once() {
        let (gate, entered, release) = Gate::new();
        let logs = Logs::start_with(gate, || {});
        let soon = Instant::now() + Duration::from_secs(5);
        assert!(logs.say_last(b"ima: error: x\n".to_vec(), soon).unwrap());
        // The writing thread is writing it (its write blocks): not the caller's.
        let written = entered.recv_timeout(Duration::from_secs(30)).unwrap();
        assert_eq!(written, b"ima: error: x\n");
        assert_eq!(logs.abandon(), (1, false));
        drop(release);
    }

    /// A message that finds stderr closed (its reader gone) says so; a log line does not.
    #[test]
    fn a_message_to_a_closed_stderr_ends_the_command() {
        static CLOSED: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
        let (reader, writer) = std::io::pipe().unwrap();
        drop(reader);
        let logs = Logs::start_with(writer, || {
            CLOSED.fetch_add(1, Ordering::SeqCst);
        });
        logs.send(b"a log line\n".to_vec());
        assert!(logs.flush(Duration::from_secs(10)));
        assert_eq!(
            CLOSED.load(Ordering::SeqCst),
            0,
            "a log line ended the command"
        );
        logs.say(b"a message\n".to_vec()).unwrap();
        assert!(logs.flush(Duration::from_secs(10)));
        assert_eq!(CLOSED.load(Ordering::SeqCst), 1);
    }
}

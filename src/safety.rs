//! The program's stop guarantee: every device that can move a robot is stopped, and its session
//! closed, on every exit path — a normal end, an error, SIGINT, SIGTERM, SIGHUP, SIGQUIT,
//! Ctrl-Z and the other common signals whose default action would end or suspend the process
//! ([`WATCHED`]), a closed stdout, and a panic on any thread.
//!
//! The guarantee does not depend on each command remembering a `stop()`:
//!
//! * the drivers that can move a robot (`ima-p2os`, `ima-rflex`) register a
//!   [`HaltSignal`](ima_hal::safety::HaltSignal) in the process-wide
//!   [`StopRegistry`] as they start;
//! * [`install`] (first thing in `main`) sets a panic hook that halts every registered device and
//!   waits for its last frames, and a signal thread: the first signal of [`WATCHED`] halts
//!   every device at once and asks the command to wind down ([`cancelled`]); a second
//!   signal, or a command that has not finished [`GRACE`] later, ends the process after the
//!   devices are done;
//! * [`block_on`] is the only way a command runs async code: after the command's future ends
//!   (for whatever reason) it halts every device and waits until their last frames are on the
//!   wire before the runtime — and with it the driver tasks — goes away.
//!
//! What no program can cover is being killed outright (SIGKILL, a power cut): then only the
//! robot's firmware watchdog stops it; the README's "Safety" section gives the times per robot.

use std::future::Future;
use std::io::Write as _;
use std::sync::OnceLock;
use std::sync::atomic::{AtomicI32, Ordering};
use std::time::Duration;

use anyhow::Result;
use ima_hal::safety::StopRegistry;

/// How long a command has after the first signal to wind down before the process ends anyway.
pub const GRACE: Duration = Duration::from_secs(3);

/// How long an exit path waits for every device's last frames.
const DRAIN_WAIT: Duration = Duration::from_secs(2);

/// The signal that interrupted the program (0: none).
static SIGNAL: AtomicI32 = AtomicI32::new(0);

/// Set by a command that answers Ctrl-C itself (a prompt): the first SIGINT then does not end
/// the process after [`GRACE`]; a second one still does.
static OWN_CTRL_C: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Declare that this command answers Ctrl-C itself (e.g. `ima commander` asks whether to stop
/// the robots). Devices are still halted at the first signal; only the forced exit after
/// [`GRACE`] is left out for SIGINT.
pub fn answers_ctrl_c_itself() {
    OWN_CTRL_C.store(true, Ordering::SeqCst);
}

fn cancel_channel() -> &'static tokio::sync::watch::Sender<bool> {
    static CANCEL: OnceLock<tokio::sync::watch::Sender<bool>> = OnceLock::new();
    CANCEL.get_or_init(|| tokio::sync::watch::channel(false).0)
}

/// A signal that ends the program: one whose default action would end or suspend the process
/// without stopping the robot, so the signal thread takes it ([`WATCHED`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Signal(i32);

/// The signals the program takes over, with their names: the four a user sends to end a
/// program; Ctrl-Z and the background-terminal stops (a suspended driver cannot keep the
/// robot safe, so they stop it and end the program instead); and the common others whose
/// default action ends a process (a file-size or CPU-time limit, a stray `kill -USR1`, a
/// timer; an in-process profiler's SIGPROF too, so profile with `perf`). SIGKILL and SIGSTOP
/// cannot be caught (the README's "Safety" section); the faults (SIGSEGV, SIGBUS, SIGILL,
/// SIGFPE, SIGABRT, SIGSYS, SIGTRAP) come from the process itself; SIGPWR, SIGSTKFLT and the
/// real-time signals are not watched.
#[cfg(unix)]
pub const WATCHED: &[(i32, &str)] = &[
    (libc::SIGHUP, "SIGHUP"),
    (libc::SIGINT, "SIGINT"),
    (libc::SIGQUIT, "SIGQUIT"),
    (libc::SIGTERM, "SIGTERM"),
    (libc::SIGTSTP, "SIGTSTP (Ctrl-Z)"),
    (libc::SIGTTIN, "SIGTTIN"),
    (libc::SIGTTOU, "SIGTTOU"),
    (libc::SIGXFSZ, "SIGXFSZ (file size limit)"),
    (libc::SIGXCPU, "SIGXCPU (CPU time limit)"),
    (libc::SIGUSR1, "SIGUSR1"),
    (libc::SIGUSR2, "SIGUSR2"),
    (libc::SIGALRM, "SIGALRM"),
    (libc::SIGVTALRM, "SIGVTALRM"),
    (libc::SIGPROF, "SIGPROF"),
    (libc::SIGIO, "SIGIO"),
];

impl Signal {
    /// SIGINT (Ctrl-C).
    pub const INT: Self = Self(2);

    fn from_number(n: i32) -> Option<Self> {
        #[cfg(unix)]
        return WATCHED.iter().any(|&(w, _)| w == n).then_some(Self(n));
        #[cfg(not(unix))]
        return (n == 2).then_some(Self(n));
    }

    /// The signal's name.
    pub fn name(self) -> &'static str {
        #[cfg(unix)]
        return WATCHED
            .iter()
            .find(|&&(w, _)| w == self.0)
            .map_or("a signal", |&(_, name)| name);
        #[cfg(not(unix))]
        return "SIGINT";
    }

    /// The shell's exit status for a program ended by this signal (128 + its number).
    pub fn exit_code(self) -> u8 {
        u8::try_from(128 + self.0).unwrap_or(u8::MAX)
    }
}

/// Why a command was ended before its time.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Cause {
    /// A signal.
    Signal(Signal),
    /// A panic on some thread of the process.
    Panic,
    /// Standard output (or standard error) was closed by its reader.
    OutputClosed,
}

impl std::fmt::Display for Cause {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Signal(s) => write!(f, "interrupted by {}", s.name()),
            Self::Panic => f.write_str("ended by a panic (a bug: please report it)"),
            Self::OutputClosed => f.write_str("the output was closed by its reader"),
        }
    }
}

impl Cause {
    /// The exit status: 128 + the signal's number, or 101 (Rust's status for a panic).
    pub fn exit_code(self) -> u8 {
        match self {
            Self::Signal(s) => s.exit_code(),
            Self::Panic => 101,
            Self::OutputClosed => 141,
        }
    }
}

/// The command was ended by a signal or a panic; the devices were halted. The message says
/// so only when the command had opened a device that can move.
#[derive(Debug)]
pub struct Interrupted(pub Cause);

impl std::fmt::Display for Interrupted {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.0)?;
        let reg = StopRegistry::global();
        if !reg.ever_registered() {
            return Ok(());
        }
        // What `guarded` saw once its wait ended: by the time this is printed the runtime
        // has shut down and dropped every task still running (the devices not confirmed).
        let seen = SUMMARY
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .clone();
        f.write_str(
            &seen.unwrap_or_else(|| stop_summary(&reg.pending(), unheard_note().as_deref())),
        )
    }
}

/// [`stop_summary`] as the command's exit guard saw it after its wait.
static SUMMARY: std::sync::Mutex<Option<String>> = std::sync::Mutex::new(None);

/// What an interrupted command says of its devices: a device still running after the wait
/// (`pending`), or one whose stop went into a dead link (`note`), is not claimed stopped.
fn stop_summary(pending: &[String], note: Option<&str>) -> String {
    let mut s = String::from("; every device that could move was ");
    if pending.is_empty() && note.is_none() {
        s.push_str("stopped");
        return s;
    }
    s.push_str("asked to stop, but");
    if !pending.is_empty() {
        s.push_str(" the stop of ");
        s.push_str(&pending.join(", "));
        s.push_str(" could not be confirmed");
    }
    if let Some(note) = note {
        s.push_str(if pending.is_empty() { " " } else { ", and " });
        s.push_str(note);
    }
    s
}

impl std::error::Error for Interrupted {}

/// An error whose message already says that a robot's stop is not confirmed and what stops
/// it instead (`ima drive` losing its only base's link while it drove): the way out does not
/// say the unheard note a second time.
#[derive(Debug)]
pub struct StopNotConfirmed(pub String);

impl std::fmt::Display for StopNotConfirmed {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for StopNotConfirmed {}

/// Set once a panic hook ran.
static PANICKED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Set once a task found standard output closed ([`output_closed`]).
static OUTPUT_CLOSED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Why the program was asked to end (a signal first; else a panic; else a closed stdout; else
/// SIGINT as a fallback for a cancellation with none recorded yet).
pub fn cause() -> Cause {
    match signal() {
        Some(s) => Cause::Signal(s),
        None if PANICKED.load(Ordering::SeqCst) => Cause::Panic,
        None if OUTPUT_CLOSED.load(Ordering::SeqCst) => Cause::OutputClosed,
        None => Cause::Signal(Signal::INT),
    }
}

/// A task that prints found standard output closed: halt every device at once and ask the
/// command to end, as a signal would; the program then exits 141 without a message.
pub fn output_closed() {
    OUTPUT_CLOSED.store(true, Ordering::SeqCst);
    StopRegistry::global().halt_all();
    cancel_channel().send_replace(true);
}

/// Whether a print found stdout or stderr closed ([`output_closed`]).
pub fn output_was_closed() -> bool {
    OUTPUT_CLOSED.load(Ordering::SeqCst)
}

/// The signal received so far, if any.
pub fn signal() -> Option<Signal> {
    Signal::from_number(SIGNAL.load(Ordering::SeqCst))
}

/// Resolves once the program has been asked to end (a signal, or a panic on another thread).
pub async fn cancelled() {
    let mut rx = cancel_channel().subscribe();
    let _ = rx.wait_for(|c| *c).await;
}

/// Run `fut` unless the program is asked to end first; then Err([`Interrupted`]) at once (the
/// devices have already been halted by the signal thread).
pub async fn until_cancelled<T>(fut: impl Future<Output = T>) -> Result<T> {
    tokio::select! {
        biased;
        () = cancelled() => Err(Interrupted(cause()).into()),
        r = fut => Ok(r),
    }
}

static LOG: OnceLock<crate::logs::Logs> = OnceLock::new();

/// How long the panic hook waits for its "stopping" line before it halts the devices.
const PANIC_LINE_WAIT: Duration = Duration::from_millis(50);

/// Where log lines and the guard's own messages go ([`crate::logs`]): a stderr nobody reads
/// then never blocks a driver task that logs, nor the signal thread (a blocked warning had
/// kept a driver from sending its keep-alive and STOP, and the signal thread from ending the
/// program).
pub fn set_log_writer(logs: crate::logs::Logs) {
    let _ = LOG.set(logs);
}

/// Write out the log lines still queued, waiting at most a second (a stderr that blocks
/// cannot hold the exit longer).
pub fn flush_logs() {
    flush_logs_by(std::time::Instant::now() + Duration::from_secs(1));
}

/// [`flush_logs`] waiting until `deadline` at most; whether everything queued was written.
pub fn flush_logs_by(deadline: std::time::Instant) -> bool {
    match LOG.get() {
        Some(l) => l.flush(deadline.saturating_duration_since(std::time::Instant::now())),
        None => true,
    }
}

/// The program's last words on stderr: the error line, if any, behind everything queued,
/// all of it written by `deadline` if stderr keeps up. If it does not (a slow or stalled
/// reader), what is still queued is given up, and a note of how many messages were not
/// written and the error line are written directly, waiting at most 1.5 s for a reader that
/// is slow and 0.3 s for one that took nothing (the exit, a second and that, stays within the
/// guard's 3 s after a signal): the error line is never dropped silently behind
/// a backlog of log lines. (It follows the line being written then, or, if that one is longer
/// than what a pipe takes whole, may cut into it.)
pub fn last_words(error: Option<&str>, deadline: std::time::Instant, written_before: u64) {
    let line = error.map(|m| format!("ima: error: {m}\n"));
    let Some(l) = LOG.get() else {
        if let Some(line) = &line {
            say_directly(format_args!("{line}"));
        }
        return;
    };
    let queued = match &line {
        None => true,
        Some(line) => match l.say_last(line.clone().into_bytes(), deadline) {
            Ok(queued) => queued,
            // No thread writes the queue out.
            Err(_) => return say_directly(format_args!("{line}")),
        },
    };
    if queued && flush_logs_by(deadline) {
        return;
    }
    // A reader that took something since the exit began (`written_before`, from
    // [`logs_written`]) is slow, not gone: wait longer for it to take the last words (a pipe
    // frees room a page at a time) than for one that took nothing.
    let wait = if l.written() > written_before {
        Duration::from_millis(1500)
    } else {
        Duration::from_millis(300)
    };
    let (lost, error_line_is_mine) = l.abandon();
    // The error line, if any, is counted among the lost: it is not lost.
    let lost = lost.saturating_sub(usize::from(line.is_some()));
    let mut words = String::new();
    if lost > 0 {
        words = format!("ima: {lost} message(s) not written: stderr did not keep up\n");
    }
    if error_line_is_mine {
        words.push_str(line.as_deref().unwrap_or_default());
    }
    if words.is_empty() {
        return;
    }
    // On a thread of its own (a stderr nobody reads blocks it, not the exit), and on a copy of
    // the descriptor rather than through `Stderr`, whose lock the log thread may hold while a
    // long line of its own waits for the reader: one short write, which a pipe takes whole.
    let (tx, rx) = std::sync::mpsc::channel();
    let spawned = std::thread::Builder::new()
        .name("ima-last-words".into())
        .spawn(move || {
            use std::os::fd::AsFd as _;
            if let Ok(fd) = std::io::stderr().as_fd().try_clone_to_owned() {
                let _ = std::fs::File::from(fd).write_all(words.as_bytes());
            }
            let _ = tx.send(());
        });
    if spawned.is_ok() {
        let _ = rx.recv_timeout(wait);
    }
}

/// How many log lines and messages have been written to stderr so far (0 without a log
/// thread): taken when the exit begins, for [`last_words`].
pub fn logs_written() -> u64 {
    LOG.get().map_or(0, crate::logs::Logs::written)
}

/// A progress line (`ima experiment`'s bar) on stderr, as a log line is: dropped when stderr
/// does not keep up, and never the end of the command when it is closed (the results still
/// go to stdout).
pub fn progress(args: std::fmt::Arguments<'_>) {
    log_line(std::fmt::format(args));
}

fn say(msg: std::fmt::Arguments<'_>) {
    log_line(format!("ima: {msg}\n"));
}

/// `line` on stderr as a log line: through the log thread (dropped when stderr does not keep
/// up), or written here when none runs. stderr may be gone too: never panic, and never block
/// on it while the log thread runs.
fn log_line(line: String) {
    match LOG.get() {
        Some(l) => l.send(line.into_bytes()),
        None => {
            let _ = std::io::stderr().write_all(line.as_bytes());
        }
    }
}

/// Halt every registered device from a thread outside any runtime (so the driver tasks are woken
/// through the runtimes' shared queues), then wait up to `wait` for their last frames.
fn halt_everything_blocking(wait: Duration) -> Vec<String> {
    let reg = StopRegistry::global();
    if !reg.any_running() {
        return Vec::new();
    }
    let _ = std::thread::Builder::new()
        .name("ima-halt".into())
        .spawn(|| StopRegistry::global().halt_all())
        .map(std::thread::JoinHandle::join);
    reg.wait_blocking(wait)
}

/// Install the panic hook and the signal thread. Call once, first thing in `main`.
pub fn install() {
    let previous = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        // The `mcap` crate's panic on a malformed recording is caught and reported as the
        // recording's damage: not the program's panic.
        if ima_record::read::in_guarded_read() {
            return;
        }
        PANICKED.store(true, Ordering::SeqCst);
        if StopRegistry::global().any_running() {
            say(format_args!("panic: stopping every device that could move"));
            // Out before the halt, as it says (the log thread writes it): waiting 50 ms at
            // most, so a stderr nobody reads delays the stop no longer.
            if let Some(l) = LOG.get() {
                let _ = l.flush(PANIC_LINE_WAIT);
            }
        }
        let pending = halt_everything_blocking(DRAIN_WAIT);
        if !pending.is_empty() {
            say(format_args!(
                "panic: could not confirm the stop of {}",
                pending.join(", ")
            ));
        }
        if let Some(note) = unheard_note() {
            say(format_args!("panic: {note}"));
        }
        cancel_channel().send_replace(true);
        // record: the recording gets its summary even after a panic.
        let _ = crate::record::finish();
        flush_logs();
        previous(info);
    }));
    #[cfg(unix)]
    {
        // The command starts once every signal is watched: a Ctrl-C in between was lost when
        // the program was started with SIGINT ignored (a shell's background job), or ended it
        // without a word otherwise, a device it had just opened not stopped.
        let (ready, watched) = std::sync::mpsc::channel();
        match std::thread::Builder::new()
            .name("ima-signals".into())
            .spawn(move || signal_thread(&ready))
        {
            Ok(_) => {
                let _ = watched.recv_timeout(SIGNALS_READY_WAIT);
            }
            Err(e) => say(format_args!("cannot watch for signals: {e}")),
        }
    }
}

/// How long the program waits for its signal thread to watch every signal before the command
/// starts (it takes well under a millisecond; the bound is for a thread that failed).
#[cfg(unix)]
const SIGNALS_READY_WAIT: Duration = Duration::from_secs(2);

/// The signals ignored when the program started (Linux: `SigIgn` of `/proc/self/status`;
/// elsewhere none are known).
#[cfg(unix)]
fn ignored_at_start() -> Vec<i32> {
    let Ok(status) = std::fs::read_to_string("/proc/self/status") else {
        return Vec::new();
    };
    let mask = status
        .lines()
        .find_map(|l| l.strip_prefix("SigIgn:"))
        .and_then(|m| u64::from_str_radix(m.trim(), 16).ok())
        .unwrap_or(0);
    (1..=64).filter(|n| mask & (1 << (n - 1)) != 0).collect()
}

#[cfg(unix)]
/// Watch the signals (`ready` is told once every one is watched), and carry out the first.
fn signal_thread(ready: &std::sync::mpsc::Sender<()>) {
    use tokio::signal::unix::{SignalKind, signal as listen};
    let Ok(rt) = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
    else {
        say(format_args!("cannot watch for signals: no runtime"));
        return;
    };
    rt.block_on(async {
        // One task per signal; each sends its number here.
        let (tx, mut got) = tokio::sync::mpsc::unbounded_channel::<i32>();
        // A signal the program was started with ignored (`trap '' XFSZ`: writes past a size
        // limit then fail with EFBIG instead) cannot end it: it stays ignored. The four a user
        // sends to end a program are always taken, as before.
        let ignored = ignored_at_start();
        let asked_to_end = [libc::SIGHUP, libc::SIGINT, libc::SIGQUIT, libc::SIGTERM];
        for &(n, name) in WATCHED {
            if !asked_to_end.contains(&n) && ignored.contains(&n) {
                continue;
            }
            match listen(SignalKind::from_raw(n)) {
                Ok(mut s) => {
                    let tx = tx.clone();
                    tokio::spawn(
                        async move { while s.recv().await.is_some() && tx.send(n).is_ok() {} },
                    );
                }
                Err(e) => say(format_args!("cannot watch for {name}: {e}")),
            }
        }
        let _ = ready.send(());
        // `got` cannot close: `tx` lives as long as this future.
        let Some(first) = got.recv().await.and_then(Signal::from_number) else {
            return;
        };
        SIGNAL.store(first.0, Ordering::SeqCst);
        // Safety first: every moving device is told to stop before anything else happens.
        let halted = StopRegistry::global().halt_all();
        cancel_channel().send_replace(true);
        if halted > 0 {
            say(format_args!(
                "{}: stopping the robot ({} again to exit at once)",
                first.name(),
                if first == Signal::INT {
                    "Ctrl-C"
                } else {
                    "a second signal"
                }
            ));
        }
        let own = first == Signal::INT && OWN_CTRL_C.load(Ordering::SeqCst);
        // A second signal ends the program at once. A background-terminal stop comes again
        // at each retry of the read or write that raised it: not a second signal.
        let job_control = [libc::SIGTTIN, libc::SIGTTOU].contains(&first.0);
        let deadline = tokio::time::Instant::now() + GRACE;
        let code = loop {
            tokio::select! {
                n = got.recv() => match n {
                    Some(n) if job_control && n == first.0 => {}
                    Some(n) => break Signal::from_number(n).unwrap_or(first).exit_code(),
                    // Cannot happen: this future keeps a sender.
                    None => break first.exit_code(),
                },
                () = tokio::time::sleep_until(deadline), if !own => break first.exit_code(),
            }
        };
        // Either way the devices get their last frames out before the process ends.
        let pending = halt_everything_blocking(Duration::from_millis(500));
        for words in forced_exit_words(halted, &pending, unheard_note().as_deref()) {
            say(format_args!("{words}"));
        }
        // record: close the recording before the forced exit.
        let _ = crate::record::finish();
        flush_logs();
        std::process::exit(i32::from(code));
    });
}

/// What a forced exit says of the devices, `halted` of them halted at the first signal:
/// those whose stop it could not confirm (`pending`: still closing), the note about unheard
/// stops, or, when every one finished and none is in doubt, that each was stopped (the last
/// word a first signal says; it was lost when a quick second Ctrl-C came while the drivers
/// still closed).
fn forced_exit_words(halted: usize, pending: &[String], note: Option<&str>) -> Vec<String> {
    let mut words = Vec::new();
    if !pending.is_empty() {
        words.push(format!(
            "exiting; could not confirm the stop of {}",
            pending.join(", ")
        ));
    }
    if let Some(note) = note {
        words.push(format!("exiting; {note}"));
    } else if halted > 0 && pending.is_empty() {
        words.push(format!("exiting{}", stop_summary(&[], None)));
    }
    words
}

/// Run a command's async body on a multi-threaded tokio runtime under the stop guarantee: when
/// the body ends — done, failed, or dropped [`GRACE`] after a signal it did not act on — every
/// registered device is halted and its last frames are written before the runtime shuts down.
pub fn block_on<T, F>(body: F) -> Result<T>
where
    F: Future<Output = Result<T>>,
{
    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?;
    rt.block_on(guarded(body))
}

/// Test hook: `IMA_INJECT_PANIC=SECONDS` makes a guarded command panic that long after it
/// started, in the command's own code path, so tests can prove the panic path stops the robot.
const INJECT_PANIC_ENV: &str = "IMA_INJECT_PANIC";

async fn injected_panic() {
    match std::env::var(INJECT_PANIC_ENV)
        .ok()
        .and_then(|v| v.parse::<f64>().ok())
        .filter(|s| s.is_finite() && *s >= 0.0 && *s < 3600.0)
    {
        Some(secs) => {
            tokio::time::sleep(Duration::from_secs_f64(secs)).await;
            panic!("{INJECT_PANIC_ENV}: injected panic after {secs} s");
        }
        None => std::future::pending().await,
    }
}

async fn guarded<T, F>(body: F) -> Result<T>
where
    F: Future<Output = Result<T>>,
{
    let r = tokio::select! {
        () = injected_panic() => unreachable!("injected_panic never returns"),
        r = body => r,
        () = async { cancelled().await; tokio::time::sleep(GRACE).await } => {
            Err(Interrupted(cause()).into())
        }
    };
    // Read before the wait below: an error that came before the operator's Ctrl-C (pressed
    // during that wait) stays that error.
    let asked_to_end = asked_to_end();
    halt_and_wait().await;
    *SUMMARY
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner) = Some(stop_summary(
        &StopRegistry::global().pending(),
        unheard_note().as_deref(),
    ));
    // record: every way out of a command closes the recording (its summary and indexes).
    let _ = crate::record::finish();
    let r = after_a_signal(r, asked_to_end);
    say_unheard(&r);
    r
}

/// How often [`recv_unless_asked_to_end`] looks whether the program has been asked to end.
const RECV_POLL: Duration = Duration::from_millis(50);

/// The next message on `rx` for a command that waits on a plain thread (a pipe, a reader
/// thread): `Ok(None)` once every sender is gone, and [`Interrupted`] within 50 ms of the program
/// being asked to end, however long the message takes (a read blocked on a quiet pipe would
/// otherwise hold the command until the signal's grace period ends it without a word).
///
/// # Errors
/// [`Interrupted`], with the cause.
pub fn recv_unless_asked_to_end<T>(rx: &std::sync::mpsc::Receiver<T>) -> Result<Option<T>> {
    use std::sync::mpsc::RecvTimeoutError;
    loop {
        if asked_to_end() {
            return Err(Interrupted(cause()).into());
        }
        match rx.recv_timeout(RECV_POLL) {
            Ok(m) => return Ok(Some(m)),
            Err(RecvTimeoutError::Timeout) => {}
            // A sender that panicked is gone too: that is no end of the input.
            Err(RecvTimeoutError::Disconnected) if asked_to_end() => {
                return Err(Interrupted(cause()).into());
            }
            Err(RecvTimeoutError::Disconnected) => return Ok(None),
        }
    }
}

/// The program has been asked to end: a signal, a panic or a closed stdout. Each flag is set
/// before the devices are halted, so a body that fails because its device was halted finds it
/// set (the cancel channel is only told afterwards).
pub fn asked_to_end() -> bool {
    signal().is_some() || PANICKED.load(Ordering::SeqCst) || OUTPUT_CLOSED.load(Ordering::SeqCst)
}

/// A body that failed after the program was asked to end (`asked_to_end`, read when the body
/// ended) failed because of it: its devices were halted under it (a driver then reports itself
/// disconnected), so the end is reported as the interruption (exit 130 for SIGINT, 141 for a
/// closed stdout), not as that error (`ima demo square` said "error: P2OS robot driver
/// disconnected" and exited 1 on Ctrl-C). The body's own error goes to the debug log.
fn after_a_signal<T>(r: Result<T>, asked_to_end: bool) -> Result<T> {
    match r {
        Err(e) if asked_to_end && !e.chain().any(|c| c.downcast_ref::<Interrupted>().is_some()) => {
            tracing::debug!("after the interruption: {e:#}");
            Err(Interrupted(cause()).into())
        }
        r => r,
    }
}

/// Halt every registered device and wait (at most two seconds) until each has written its last
/// frames. Called by [`block_on`] on every way out of a command.
pub async fn halt_and_wait() {
    let reg = StopRegistry::global();
    if reg.halt_all() == 0 {
        // Every driver already closed (a command's own `close`).
        return;
    }
    let end = tokio::time::Instant::now() + DRAIN_WAIT;
    while reg.any_running() && tokio::time::Instant::now() < end {
        tokio::time::sleep(Duration::from_millis(2)).await;
    }
    let pending = reg.pending();
    if !pending.is_empty() {
        say(format_args!(
            "could not confirm the stop of {}",
            pending.join(", ")
        ));
    }
}

/// What to say of devices whose stop was written while their link was down
/// ([`StopRegistry::unheard`]), if any.
fn unheard_note() -> Option<String> {
    let reg = StopRegistry::global();
    let unheard = reg.unheard();
    (!unheard.is_empty()).then(|| unheard_text(&unheard, &reg.unheard_watchdogs()))
}

/// [`unheard_note`] for the devices named `unheard`, with the watchdogs their drivers declare
/// (`Shell::WATCHDOG`).
fn unheard_text(unheard: &[String], watchdogs: &[&str]) -> String {
    let figures = if watchdogs.is_empty() {
        String::new()
    } else {
        format!(" ({})", watchdogs.join("; "))
    };
    format!(
        "the stop of the {} is not confirmed (its link was down, or it went on sending after the \
         stop): the stop may not have reached the robot, whose own watchdog stops it once it \
         hears nothing{figures}; keep clear until it stands",
        unheard.join(" and the ")
    )
}

/// Say [`unheard_note`] on the way out with `result`, unless its message says it
/// ([`says_the_stop`]). Decided by the result, not by whether the program was asked to end: a Ctrl-C
/// pressed while a failed command's drivers were still closing leaves the command's own
/// error, which does not say it; a closed stdout ends quietly, but stderr may be open.
fn say_unheard<T>(result: &Result<T>) {
    if !says_the_stop(result)
        && let Some(note) = unheard_note()
    {
        say(format_args!("{note}"));
    }
}

/// Whether `result`'s message says what became of the devices: an [`Interrupted`] one (a
/// closed output ends quietly: it says nothing), or a [`StopNotConfirmed`].
fn says_the_stop<T>(result: &Result<T>) -> bool {
    result.as_ref().err().is_some_and(|e| {
        // A context is found by `downcast_ref` on the error, not in its chain.
        e.downcast_ref::<StopNotConfirmed>().is_some()
            || e.chain().any(|c| {
                matches!(
                    c.downcast_ref::<Interrupted>(),
                    Some(Interrupted(cause)) if *cause != Cause::OutputClosed
                )
            })
    })
}

/// Write one line to standard output. A closed stdout is never a panic: it halts every device,
/// asks the command to end ([`output_closed`]) and returns [`Interrupted`] with
/// [`Cause::OutputClosed`], which ends the program quietly with 141.
pub fn out_line(args: std::fmt::Arguments<'_>) -> Result<()> {
    let mut out = std::io::stdout().lock();
    match out.write_fmt(args).and_then(|()| out.write_all(b"\n")) {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => {
            output_closed();
            Err(Interrupted(Cause::OutputClosed).into())
        }
        Err(e) => Err(anyhow::Error::new(e).context("writing to standard output")),
    }
}

/// Write one line to standard error (the crate's `eprintln!`). Never a panic: a stderr whose
/// reader went away ends the command as a closed stdout does ([`output_closed`]: every
/// device halted, the command asked to end, status 141); other errors are ignored (there is
/// nowhere left to report them).
pub fn err_line(args: std::fmt::Arguments<'_>) {
    err_write(format_args!("{args}\n"));
}

/// [`err_line`] without the end of line (the crate's `eprint!`). Once the log writer runs
/// ([`set_log_writer`]) it goes through its queue, never waiting on stderr ([`crate::logs`]).
pub fn err_write(args: std::fmt::Arguments<'_>) {
    if let Some(l) = LOG.get() {
        match l.say(std::fmt::format(args).into_bytes()) {
            Ok(()) => return,
            // No thread writes the queue out: write it here.
            Err(b) => return say_directly(format_args!("{}", String::from_utf8_lossy(&b))),
        }
    }
    say_directly(args);
}

/// Write to stderr from the calling thread (a closed stderr ends the command).
fn say_directly(args: std::fmt::Arguments<'_>) {
    let mut err = std::io::stderr().lock();
    if let Err(e) = err.write_fmt(args)
        && e.kind() == std::io::ErrorKind::BrokenPipe
    {
        output_closed();
    }
}

/// `println!` that returns a `Result` instead of panicking on a closed stdout.
macro_rules! outln {
    ($($arg:tt)*) => {
        $crate::safety::out_line(format_args!($($arg)*))
    };
}
pub(crate) use outln;

/// The exit status and message for a command's result.
pub fn exit_status(result: &Result<()>) -> (u8, Option<String>) {
    let Err(e) = result else {
        return (0, None);
    };
    // A writer that reported a closed stdout as a plain I/O error counts as one too.
    let broken_pipe = || {
        e.chain().any(|c| {
            c.downcast_ref::<std::io::Error>()
                .is_some_and(|io| io.kind() == std::io::ErrorKind::BrokenPipe)
        })
    };
    match e.chain().find_map(|c| c.downcast_ref::<Interrupted>()) {
        Some(Interrupted(Cause::OutputClosed)) => (141, None),
        Some(Interrupted(c)) => (c.exit_code(), Some(crate::error_chain(e))),
        None if broken_pipe() => (141, None),
        None => (1, Some(crate::error_chain(e))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The note gives the watchdog of the base it names (an rFLEX note gave the P2OS one).
    #[test]
    fn the_unheard_note_gives_each_named_base_its_own_watchdog() {
        // As the drivers declare them (`Shell::WATCHDOG`; this crate names no driver here).
        let p2os = "P2OS: 2 s after the last command it received";
        let rflex_watchdog = "rFLEX: its fail-safe, about 1 s after the last command";
        let rflex = unheard_text(&["rFLEX base".to_owned()], &[rflex_watchdog]);
        assert!(
            rflex.contains("(rFLEX: its fail-safe, about 1 s"),
            "{rflex}"
        );
        assert!(!rflex.contains("P2OS"), "{rflex}");
        let both = unheard_text(
            &["P2OS base".to_owned(), "rFLEX base".to_owned()],
            &[p2os, rflex_watchdog],
        );
        assert!(both.starts_with("the stop of the P2OS base and the rFLEX base is not confirmed"));
        assert!(both.contains("(P2OS: 2 s after the last command it received; rFLEX:"));
    }

    /// Only a stop every device confirmed, none into a dead link, is claimed.
    #[test]
    fn the_summary_claims_a_stop_only_when_every_device_confirmed_it() {
        assert_eq!(
            stop_summary(&[], None),
            "; every device that could move was stopped"
        );
        let p = ["P2OS base".to_owned()];
        assert_eq!(
            stop_summary(&p, None),
            "; every device that could move was asked to stop, but the stop of P2OS base could \
             not be confirmed"
        );
        assert_eq!(
            stop_summary(&[], Some("N")),
            "; every device that could move was asked to stop, but N"
        );
        assert!(stop_summary(&p, Some("N")).ends_with("could not be confirmed, and N"));
        // A forced exit claims the stop only when every device finished and none is in doubt.
        let claim = ["exiting; every device that could move was stopped".to_owned()];
        assert_eq!(forced_exit_words(1, &[], None), claim);
        assert!(
            forced_exit_words(0, &[], None).is_empty(),
            "nothing to stop"
        );
        assert_eq!(
            forced_exit_words(1, &p, None),
            ["exiting; could not confirm the stop of P2OS base".to_owned()]
        );
        assert_eq!(
            forced_exit_words(2, &[], Some("N")),
            ["exiting; N".to_owned()]
        );
    }

    /// The note about a stop into a dead link is said by the message of an interruption or a
    /// [`StopNotConfirmed`] error, and on its own otherwise: after a plain error (a Ctrl-C
    /// while a failed command's drivers were closing left that error, and the note was said
    /// nowhere), and after a closed output (which ends quietly).
    #[test]
    fn the_unheard_note_is_said_unless_the_interruption_says_it() {
        let signal: Result<()> = Err(Interrupted(Cause::Signal(Signal::INT)).into());
        assert!(says_the_stop(&signal));
        let closed: Result<()> = Err(Interrupted(Cause::OutputClosed).into());
        assert!(!says_the_stop(&closed));
        let plain: Result<()> = Err(anyhow::anyhow!("the P2OS base: link lost"));
        assert!(!says_the_stop(&plain));
        let said: Result<()> = Err(anyhow::anyhow!("driver disconnected")
            .context(StopNotConfirmed("… keep clear until it stands".into()))
            .context("driving"));
        assert!(says_the_stop(&said));
        assert!(!says_the_stop(&Ok(())));
    }

    #[test]
    fn an_error_is_the_interruption_only_when_the_program_was_asked_to_end() {
        let failed = || -> Result<()> { Err(anyhow::anyhow!("P2OS robot driver disconnected")) };
        // Before any signal: the body's error stays (a pulled cable is not a Ctrl-C).
        let e = after_a_signal(failed(), false).unwrap_err();
        assert_eq!(e.to_string(), "P2OS robot driver disconnected");
        assert_eq!(exit_status(&Err(e)).0, 1);
        // After one: the interruption, with its exit code.
        let e = after_a_signal(failed(), true).unwrap_err();
        assert!(e.downcast_ref::<Interrupted>().is_some(), "{e:#}");
        assert_eq!(exit_status(&Err(e)).0, cause().exit_code());
        // Success and an interruption already reported pass through unchanged.
        assert!(after_a_signal(Ok(()), true).is_ok());
        let closed: Result<()> = Err(Interrupted(Cause::OutputClosed).into());
        assert_eq!(exit_status(&after_a_signal(closed, true)).0, 141);
    }
}

//! The end of a drive, for both bases: where the robot stopped (or that it was still moving),
//! through the HAL's [`Odometer`].

use std::time::Duration;

use ima_hal::base::{Odometer, Odometry};

use crate::safety;

/// How long `ima drive` waits, after STOP, for the robot to report that it stands.
pub const SETTLE_TIMEOUT: Duration = Duration::from_secs(3);

/// Below these a robot counts as standing (m/s, rad/s).
pub const STANDING_V_M_S: f64 = 0.005;
/// See [`STANDING_V_M_S`].
pub const STANDING_OMEGA_RAD_S: f64 = 0.01;

/// After the stop: wait until the base's own odometry says it stands (reports newer than
/// `after`, at most [`SETTLE_TIMEOUT`]) and say where, or that it was still moving and for how
/// long it was watched; `counters` ends the line. Shared by both bases through the HAL's
/// [`Odometer`].
///
/// # Errors
/// [`safety::Interrupted`] when the program is asked to end while it waits (the guard has
/// stopped the robot): the command then ends as interrupted, with the signal's status, not
/// as a drive that ended well (it said "still moving … 3.0 s after the stop" 0.1 s after it,
/// and exited 0).
pub async fn report_end<B: Odometer>(
    base: &mut B,
    mut after: ima_hal::Instant,
    counters: &str,
) -> anyhow::Result<()> {
    let started = tokio::time::Instant::now();
    let deadline = started + SETTLE_TIMEOUT;
    let mut last = None;
    let mut standing = false;
    let interrupted = |last: Option<&Odometry>| {
        report_interrupted(last);
        Err(safety::Interrupted(safety::cause()).into())
    };
    while tokio::time::Instant::now() < deadline {
        let odo = match safety::until_cancelled(base.next_odometry(after)).await {
            Ok(Ok(odo)) => odo,
            Ok(Err(_)) if !safety::asked_to_end() => break,
            Ok(Err(_)) | Err(_) => return interrupted(last.as_ref()),
        };
        after = odo.at;
        let o = odo.value;
        standing = o.v_m_s.abs() < STANDING_V_M_S && o.omega_rad_s.abs() < STANDING_OMEGA_RAD_S;
        last = Some(o);
        if standing {
            break;
        }
    }
    if safety::asked_to_end() {
        return interrupted(last.as_ref());
    }
    match last {
        Some(o) if standing => eprintln!(
            "stopped at x={:.3} m y={:.3} m θ={:.1}°; {counters}",
            o.x_m(),
            o.y_m(),
            o.theta_rad().to_degrees()
        ),
        Some(o) => eprintln!(
            "still moving at {:.3} m/s {:.3} rad/s {:.1} s after the stop; last at x={:.3} m y={:.3} m θ={:.1}°; {counters}",
            o.v_m_s,
            o.omega_rad_s,
            started.elapsed().as_secs_f64(),
            o.x_m(),
            o.y_m(),
            o.theta_rad().to_degrees()
        ),
        None => eprintln!("no report from the robot after the stop; {counters}"),
    }
    Ok(())
}

/// After a signal (the guard has already stopped the robot): where it was last reported.
pub fn report_interrupted(last: Option<&Odometry>) {
    if safety::signal().is_none() {
        return; // a closed stdout ends quietly
    }
    if let Some(o) = last {
        eprintln!(
            "last report before the stop: x={:.3} m y={:.3} m θ={:.1}°, moving at {:.3} m/s",
            o.x_m(),
            o.y_m(),
            o.theta_rad().to_degrees(),
            o.v_m_s
        );
    }
}

/// The state lines printed while the robot moves, written to stdout by a thread of their
/// own: the motion loop never waits on its reader. A reader that stalls (a pipe into a pager
/// nobody scrolls) used to stall the loop, so no velocity command went out: the driver's
/// watchdog stopped the robot short and `--for` was not honoured. Lines that find
/// [`LIVE_LINES`] waiting are dropped and counted; a closed stdout still ends the command as
/// one (every base halted, status 141).
pub struct Live {
    tx: Option<std::sync::mpsc::SyncSender<String>>,
    /// The thread's end: the first write error other than a closed stdout (a full disk), and
    /// the lines it could not write after it.
    thread: Option<std::thread::JoinHandle<Option<(String, u64)>>>,
    /// Told when the thread has written every line (or stopped on an error).
    done: std::sync::mpsc::Receiver<()>,
    dropped: u64,
}

/// How long a drive that ends on an error or a signal waits for its last state lines.
const LIVE_FLUSH: std::time::Duration = std::time::Duration::from_secs(1);

/// Lines that may wait for stdout before new ones are dropped (several seconds of a drive).
pub const LIVE_LINES: usize = 256;

impl Live {
    /// Start the writing thread.
    ///
    /// # Errors
    /// The thread could not start.
    pub fn start() -> anyhow::Result<Self> {
        let (tx, rx) = std::sync::mpsc::sync_channel::<String>(LIVE_LINES);
        let (done_tx, done) = std::sync::mpsc::channel();
        let thread = std::thread::Builder::new()
            .name("ima-drive-out".into())
            .spawn(move || {
                let mut failed: Option<(String, u64)> = None;
                for line in rx {
                    if let Some((_, lost)) = &mut failed {
                        *lost += 1;
                        continue;
                    }
                    // A closed stdout halts the bases and asks the command to end.
                    if let Err(e) = crate::safety::out_line(format_args!("{line}")) {
                        if crate::safety::output_was_closed() {
                            break;
                        }
                        // Another error (a full disk): said at the end, with what was lost.
                        failed = Some((format!("{e:#}"), 1));
                    }
                }
                let _ = done_tx.send(());
                failed
            })?;
        Ok(Self {
            tx: Some(tx),
            thread: Some(thread),
            done,
            dropped: 0,
        })
    }

    /// Queue one line (dropped and counted when [`LIVE_LINES`] are waiting already).
    pub fn line(&mut self, line: String) {
        if let Some(tx) = &self.tx
            && let Err(std::sync::mpsc::TrySendError::Full(_)) = tx.try_send(line)
        {
            self.dropped += 1;
        }
    }

    /// Wait until the queued lines are written (the robot has stopped by then) and say how
    /// many were dropped.
    ///
    /// # Errors
    /// Standard output failed (a full disk): the error and the lines not written, so a run
    /// whose record is incomplete does not end as a success (it ended with status 0 and no
    /// word).
    pub fn finish(mut self) -> anyhow::Result<()> {
        self.tx = None;
        let failed = self.thread.take().and_then(|t| t.join().ok()).flatten();
        self.say_dropped();
        match failed {
            Some((e, lost)) => Err(anyhow::anyhow!("{e}; {lost} state line(s) not written")),
            None => Ok(()),
        }
    }

    fn say_dropped(&mut self) {
        let n = std::mem::take(&mut self.dropped);
        if n > 0 {
            eprintln!("ima drive: {n} state line(s) not printed: standard output did not keep up");
        }
    }
}

/// A drive that ends on an error or a signal (not through [`Live::finish`]) gives the queued
/// lines [`LIVE_FLUSH`] to go out, so its output does not end in a cut line; a reader that
/// does not read does not hold the exit up for longer.
impl Drop for Live {
    fn drop(&mut self) {
        if self.tx.take().is_some() {
            let _ = self.done.recv_timeout(LIVE_FLUSH);
            self.say_dropped();
        }
    }
}

/// A motion that failed because the link to the robot is gone (its port closed, an I/O
/// error) says what that means for the robot: nothing from here can stop it any more, its own
/// watchdog does (the one the driver's shell `S` declares). The message is a
/// [`safety::StopNotConfirmed`], so the way out does not say it a second time. Other errors
/// go as they are.
pub fn link_lost<S: ima_serial::runner::Shell>(e: anyhow::Error) -> anyhow::Error {
    use ima_serial::DriverError;
    let lost = e.chain().any(|c| {
        matches!(
            c.downcast_ref::<DriverError<S::Fault>>(),
            Some(DriverError::Disconnected | DriverError::Io(_))
        )
    });
    if !lost {
        return e;
    }
    let watchdog = S::WATCHDOG.map_or_else(String::new, |w| format!(" ({w})"));
    e.context(safety::StopNotConfirmed(format!(
        "the link to the robot was lost while it was driving: ima can no longer stop it; its \
         own watchdog stops it once it hears nothing{watchdog}; keep clear until it stands"
    )))
}

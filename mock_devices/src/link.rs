//! The sans-IO core shared by every runner: a [`DeviceModel`] between two fault injectors.
//!
//! ```text
//!   host bytes ──▶ [h2r FaultInjector] ─▶ [DelayLine] ─▶ model.handle_rx
//!   model.poll_tx ─▶ [r2h FaultInjector] ─▶ [DelayLine] ─▶ bytes for the host
//! ```
//!
//! A runner reads from its port into [`DeviceLink::from_host`], calls [`DeviceLink::poll`]
//! whenever it wakes, writes every chunk of [`DeviceLink::pop_to_host`], and sleeps until
//! [`DeviceLink::next_wakeup`] (or until bytes arrive). Driving it by hand in virtual time is
//! how the tests check fault timing without a port.
//!
//! # Hang-ups
//!
//! A hang-up — from an injector (`hangup=` in the spec) or from the runner's control handle —
//! takes the link **down** for an outage (or for good): bytes from the host are discarded, the
//! model's output is drained and discarded, and anything queued in the delay lines is dropped.
//! The model keeps running (its timers fire) and is told through
//! [`DeviceModel::on_hangup`]/[`DeviceModel::on_reconnect`].
//!
//! Why not close the pty? On Linux a closed and re-created pseudo-terminal gets a *new*
//! `/dev/pts/N`, so a driver configured with a path could never come back, and closing the
//! last slave makes the master return `EIO`. A down link is silent and deaf on the same path,
//! which is what a driver sees when a cable is pulled or the robot is switched off; when the
//! outage ends the device answers again on the same path. The in-memory duplex runner closes its
//! stream on a hang-up *for good* (a real EOF), and stays silent for a timed outage.

use std::time::Duration;

use ima_hal::Instant;

use crate::faults::{DelayLine, Direction, FaultAction, FaultCounters, FaultInjector, FaultPlan};
use crate::model::DeviceModel;

/// Counters of a link (both injectors plus what the down state swallowed).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
pub struct LinkCounters {
    /// Robot → host injector.
    pub robot_to_host: FaultCounters,
    /// Host → robot injector.
    pub host_to_robot: FaultCounters,
    /// Bytes discarded because the link was down (both directions, incl. queued ones).
    pub discarded_while_down: u64,
    /// Times the link went down.
    pub hangups: u64,
    /// Times it came back.
    pub reconnects: u64,
}

/// In words for an operator: the bytes each end wrote (before faults), then only the faults
/// that happened, e.g. `1200 bytes to the host, 85 from it; injected: 3 byte(s) corrupted,
/// 1 hang-up(s), 1 reconnect(s)` or
/// `…; no faults injected`.
impl core::fmt::Display for LinkCounters {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let (out, inn) = (&self.robot_to_host, &self.host_to_robot);
        write!(
            f,
            "{} bytes to the host, {} from it",
            out.bytes_in, inn.bytes_in
        )?;
        let sum = |g: fn(&FaultCounters) -> u64| g(out) + g(inn);
        let faults = [
            (sum(|c| c.corrupted), "byte(s) corrupted"),
            (sum(|c| c.dropped), "byte(s) dropped"),
            (sum(|c| c.garbage_bytes), "garbage byte(s)"),
            (sum(|c| c.splits), "split write(s)"),
            (sum(|c| c.stalls), "stall(s)"),
            (self.hangups, "hang-up(s)"),
            (self.reconnects, "reconnect(s)"),
            (
                self.discarded_while_down + sum(|c| c.lost_to_hangup),
                "byte(s) lost while down",
            ),
        ];
        let mut first = true;
        for (n, what) in faults.iter().filter(|(n, _)| *n > 0) {
            f.write_str(if first { "; injected: " } else { ", " })?;
            write!(f, "{n} {what}")?;
            first = false;
        }
        if first {
            f.write_str("; no faults injected")?;
        }
        Ok(())
    }
}

/// A snapshot of a running device (pty or duplex runner).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RunnerStatus {
    /// Link counters (faults in both directions, outages).
    pub counters: LinkCounters,
    /// Whether bytes flow.
    pub state: LinkState,
    /// Chunks dropped because the port could not be written in time.
    pub write_drops: u64,
    /// Read/write errors other than timeouts.
    pub io_errors: u64,
}

impl Default for RunnerStatus {
    fn default() -> Self {
        Self {
            counters: LinkCounters::default(),
            state: LinkState::Up,
            write_drops: 0,
            io_errors: 0,
        }
    }
}

/// Whether bytes flow.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LinkState {
    /// Bytes flow.
    Up,
    /// Down until the instant.
    DownUntil(Instant),
    /// Down for good.
    Closed,
}

/// A model behind fault injectors, ready for a runner.
#[derive(Debug)]
pub struct DeviceLink<M> {
    model: M,
    r2h: FaultInjector,
    h2r: FaultInjector,
    r2h_line: DelayLine,
    h2r_line: DelayLine,
    state: LinkState,
    actions: Vec<FaultAction>,
    tx: Vec<u8>,
    discarded: u64,
    hangups: u64,
    reconnects: u64,
}

impl<M: DeviceModel> DeviceLink<M> {
    /// A link whose injectors follow `plan` and whose timed faults count from `now`.
    pub fn new(model: M, plan: &FaultPlan, now: Instant) -> Self {
        Self {
            model,
            r2h: plan.injector(Direction::RobotToHost, now),
            h2r: plan.injector(Direction::HostToRobot, now),
            r2h_line: DelayLine::new(plan.robot_to_host.delay),
            h2r_line: DelayLine::new(plan.host_to_robot.delay),
            state: LinkState::Up,
            actions: Vec::new(),
            tx: Vec::new(),
            discarded: 0,
            hangups: 0,
            reconnects: 0,
        }
    }

    /// The model.
    pub fn model(&self) -> &M {
        &self.model
    }

    /// The model, mutably.
    pub fn model_mut(&mut self) -> &mut M {
        &mut self.model
    }

    /// Take the model back.
    pub fn into_model(self) -> M {
        self.model
    }

    /// Current state (as of the last `poll`).
    pub fn state(&self) -> LinkState {
        self.state
    }

    /// `true` while bytes flow.
    pub fn is_up(&self) -> bool {
        self.state == LinkState::Up
    }

    /// Counters so far.
    pub fn counters(&self) -> LinkCounters {
        LinkCounters {
            robot_to_host: self.r2h.counters(),
            host_to_robot: self.h2r.counters(),
            discarded_while_down: self.discarded,
            hangups: self.hangups,
            reconnects: self.reconnects,
        }
    }

    /// Bytes read from the port.
    pub fn from_host(&mut self, bytes: &[u8], now: Instant) {
        if bytes.is_empty() {
            return;
        }
        if !self.is_up() {
            self.discarded += bytes.len() as u64;
            return;
        }
        self.actions.clear();
        self.h2r.process(bytes, now, &mut self.actions);
        self.apply(Direction::HostToRobot, now);
    }

    /// Take the link down for `outage` (`None` = for good). A longer outage already in
    /// progress is kept; `Closed` stays closed.
    pub fn hang_up(&mut self, now: Instant, outage: Option<Duration>) {
        let new = match outage {
            None => LinkState::Closed,
            Some(d) => LinkState::DownUntil(now + d),
        };
        let merged = match (self.state, new) {
            (LinkState::Closed, _) | (_, LinkState::Closed) => LinkState::Closed,
            (LinkState::DownUntil(a), LinkState::DownUntil(b)) => LinkState::DownUntil(a.max(b)),
            (LinkState::Up, n) => n,
            (LinkState::DownUntil(a), LinkState::Up) => LinkState::DownUntil(a),
        };
        let was_up = self.is_up();
        self.state = merged;
        if was_up {
            self.hangups += 1;
            self.discarded += (self.r2h_line.clear() + self.h2r_line.clear()) as u64;
            self.model.on_hangup(now);
        }
    }

    /// End an outage now (no-op when up or closed for good).
    pub fn reconnect(&mut self, now: Instant) {
        if let LinkState::DownUntil(_) = self.state {
            self.state = LinkState::Up;
            self.reconnects += 1;
            self.model.on_reconnect(now);
        }
    }

    fn apply(&mut self, dir: Direction, now: Instant) {
        let mut hang: Option<Option<Duration>> = None;
        let actions = std::mem::take(&mut self.actions);
        let line = match dir {
            Direction::RobotToHost => &mut self.r2h_line,
            Direction::HostToRobot => &mut self.h2r_line,
        };
        let mut kept = Vec::with_capacity(actions.len());
        for a in actions {
            match a {
                FaultAction::HangUp(o) => hang = Some(o),
                other => kept.push(other),
            }
        }
        line.push(kept, now);
        if let Some(o) = hang {
            self.hang_up(now, o);
        }
    }

    /// Do everything due at `now`: end an outage, fire timed hang-ups, deliver due host bytes
    /// to the model, run its timer, and pass its output through the robot → host faults.
    pub fn poll(&mut self, now: Instant) {
        if let LinkState::DownUntil(t) = self.state
            && now >= t
        {
            self.reconnect(now);
        }
        for dir in [Direction::RobotToHost, Direction::HostToRobot] {
            let inj = match dir {
                Direction::RobotToHost => &mut self.r2h,
                Direction::HostToRobot => &mut self.h2r,
            };
            if let Some(FaultAction::HangUp(o)) = inj.poll_hangup(now) {
                self.hang_up(now, o);
            }
        }
        while let Some(chunk) = self.h2r_line.pop_due(now) {
            self.model.handle_rx(&chunk, now);
        }
        // A model may schedule a timeout that is already due; bound the loop.
        for _ in 0..64 {
            match self.model.poll_timeout() {
                Some(t) if t <= now => self.model.handle_timeout(now),
                _ => break,
            }
        }
        self.tx.clear();
        self.model.poll_tx(&mut self.tx);
        if self.tx.is_empty() {
            return;
        }
        if !self.is_up() {
            self.discarded += self.tx.len() as u64;
            return;
        }
        let tx = std::mem::take(&mut self.tx);
        self.actions.clear();
        self.r2h.process(&tx, now, &mut self.actions);
        self.tx = tx;
        self.apply(Direction::RobotToHost, now);
    }

    /// The next chunk for the host that is due at `now`. Write each as one write.
    pub fn pop_to_host(&mut self, now: Instant) -> Option<Vec<u8>> {
        if self.is_up() {
            self.r2h_line.pop_due(now)
        } else {
            None
        }
    }

    /// When `poll` next has something to do (the runner may wake earlier, e.g. on input).
    pub fn next_wakeup(&self) -> Option<Instant> {
        let mut t: Option<Instant> = None;
        let mut take = |c: Option<Instant>| {
            if let Some(c) = c {
                t = Some(t.map_or(c, |x| x.min(c)));
            }
        };
        take(self.model.poll_timeout());
        take(self.r2h_line.next_due());
        take(self.h2r_line.next_due());
        take(self.r2h.hangup_deadline());
        take(self.h2r.hangup_deadline());
        if let LinkState::DownUntil(d) = self.state {
            take(Some(d));
        }
        t
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn link_counters_read_as_words_with_only_the_faults_that_happened() {
        let mut c = LinkCounters::default();
        c.robot_to_host.bytes_in = 1200;
        c.host_to_robot.bytes_in = 85;
        assert_eq!(
            c.to_string(),
            "1200 bytes to the host, 85 from it; no faults injected"
        );
        c.robot_to_host.corrupted = 2;
        c.host_to_robot.corrupted = 1;
        c.hangups = 1;
        c.reconnects = 1;
        c.discarded_while_down = 7;
        assert_eq!(
            c.to_string(),
            "1200 bytes to the host, 85 from it; injected: 3 byte(s) corrupted, 1 hang-up(s), \
             1 reconnect(s), 7 byte(s) lost while down"
        );
    }

    use super::*;
    use crate::model::EchoModel;

    fn drain(link: &mut DeviceLink<EchoModel>, now: Instant) -> Vec<u8> {
        link.poll(now);
        let mut v = Vec::new();
        while let Some(c) = link.pop_to_host(now) {
            v.extend(c);
        }
        v
    }

    #[test]
    fn clean_link_echoes() {
        let mut l = DeviceLink::new(EchoModel::new(), &FaultPlan::none(), Instant::ZERO);
        l.from_host(b"hello", Instant::ZERO);
        assert_eq!(drain(&mut l, Instant::ZERO), b"hello");
        assert_eq!(l.next_wakeup(), None);
    }

    #[test]
    fn delay_holds_bytes_in_virtual_time() {
        let plan = FaultPlan::parse("r2h.delay=50ms").unwrap();
        let mut l = DeviceLink::new(EchoModel::new(), &plan, Instant::ZERO);
        l.from_host(b"x", Instant::ZERO);
        assert!(drain(&mut l, Instant::ZERO).is_empty());
        assert_eq!(l.next_wakeup(), Some(Instant::from_millis(50)));
        assert_eq!(drain(&mut l, Instant::from_millis(50)), b"x");
    }

    #[test]
    fn timed_hangup_then_recovery() {
        let plan = FaultPlan::parse("hangup=1s:2s").unwrap();
        let mut l = DeviceLink::new(
            EchoModel::with_heartbeat(Instant::ZERO, Duration::from_millis(500), b"."),
            &plan,
            Instant::ZERO,
        );
        assert_eq!(drain(&mut l, Instant::from_millis(500)), b".");
        assert_eq!(l.next_wakeup(), Some(Instant::from_millis(1000)));
        assert!(drain(&mut l, Instant::from_millis(1000)).is_empty());
        assert_eq!(l.state(), LinkState::DownUntil(Instant::from_millis(3000)));
        l.from_host(b"lost", Instant::from_millis(1500));
        assert!(drain(&mut l, Instant::from_millis(1500)).is_empty());
        assert_eq!(drain(&mut l, Instant::from_millis(3000)), b".");
        l.from_host(b"back", Instant::from_millis(3000));
        assert_eq!(drain(&mut l, Instant::from_millis(3000)), b"back");
        let c = l.counters();
        assert_eq!((c.hangups, c.reconnects), (1, 1));
        // Both injectors carry the same timed trigger: the second one merges into the outage.
        assert_eq!(c.robot_to_host.hangups + c.host_to_robot.hangups, 2);
        assert_eq!(c.discarded_while_down, 4 + 2); // "lost" + the beats polled at 1.0 s and 1.5 s
        assert_eq!(l.model().link_events(), (1, 1));
    }

    #[test]
    fn manual_hangup_for_good() {
        let mut l = DeviceLink::new(EchoModel::new(), &FaultPlan::none(), Instant::ZERO);
        l.hang_up(Instant::ZERO, None);
        l.hang_up(Instant::ZERO, Some(Duration::from_secs(1)));
        assert_eq!(l.state(), LinkState::Closed);
        l.reconnect(Instant::from_millis(5));
        assert_eq!(l.state(), LinkState::Closed);
        l.from_host(b"x", Instant::ZERO);
        assert!(drain(&mut l, Instant::from_millis(10_000)).is_empty());
    }
}

//! The Commander Interface Agent's logic (MISSION.md, "The agents": "sends a series of
//! targets, shows each target's progress (processing, done, failed) and the robots'
//! broadcasts").
//!
//! Sans-IO: [`Commander::start`], [`Commander::handle_broadcast`] and
//! [`Commander::handle_timeout`] are the inputs; [`Commander::poll_broadcast`] (targets to
//! send) and [`Commander::poll_timeout`] the outputs.
//!
//! Targets go out **one at a time**, as `Mission{commander, Accepted, colour}`
//! ([`Broadcast::new_target`]). The target is [`TargetState::Sent`] until the observer robot
//! (Skeeter) answers with its own `Accepted` ([`TargetState::Processing`]), then
//! [`TargetState::Done`] on its `Accomplished` or [`TargetState::Failed`] on its `Failed`;
//! then the next target goes out. Broadcasts travel by datagram and may be lost, so an
//! unanswered target is sent again every [`CommanderConfig::resend`], and a target being
//! processed is polled (its `Accepted` sent again) every [`CommanderConfig::poll_processing`]:
//! Skeeter answers a poll about a target it has just finished with its outcome, so a lost
//! `Accomplished`/`Failed` does not leave the series hanging until the give-up timer. If the observer says
//! nothing at all about a target for [`CommanderConfig::give_up_after`] (a dead robot), the
//! commander marks it failed itself. Every broadcast heard is kept in a log.
//!
//! [`Commander::cancel`] withdraws a target: it is failed at once (marked
//! [`Target::cancelled`]), a `target-cancel` goes out (several copies: the observer ends it
//! and Scooter stops pursuing it), and the next target follows. A `target-cancel` heard from
//! another commander process of the same name does the same without sending.
//! [`Commander::fleet_stop`] and [`Commander::fleet_resume`] queue the fleet commands.
//!
//! [`Liveness`] tells, from the broadcasts heard, which robots are alive and which have
//! fallen silent (lost).

use std::collections::{BTreeMap, VecDeque};
use std::time::Duration;

use ima_hal::Instant;

use super::msg::{Broadcast, Emergency, FLEET_COPIES, MissionEvent};

/// Settings of the commander.
#[derive(Debug, Clone, PartialEq)]
pub struct CommanderConfig {
    /// The commander's broadcast name.
    pub robot: String,
    /// The robot whose mission events update the targets (the observer).
    pub observer: String,
    /// An unanswered target is sent again after this long.
    pub resend: Duration,
    /// A target with no word from the observer for this long is failed by the commander
    /// (`None`: wait for ever). Skeeter's own timeout (180 s) normally comes first.
    pub give_up_after: Option<Duration>,
    /// Most broadcasts kept in the log (the oldest go first).
    pub max_log: usize,
    /// While a target is [`TargetState::Processing`], its `Accepted` is sent again (a poll)
    /// this often, so that a lost `Accomplished`/`Failed` is recovered: Skeeter answers a
    /// poll of the target it works on with `Accepted`, and a poll of the target it has just
    /// finished with that target's outcome (`None`: no polling).
    pub poll_processing: Option<Duration>,
}

impl Default for CommanderConfig {
    fn default() -> Self {
        Self {
            robot: super::msg::COMMANDER.to_owned(),
            observer: super::msg::SKEETER.to_owned(),
            resend: Duration::from_secs(2),
            give_up_after: Some(Duration::from_secs(240)),
            max_log: 10_000,
            poll_processing: Some(Duration::from_secs(5)),
        }
    }
}

/// Progress of one target.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum TargetState {
    /// Not sent yet.
    Waiting,
    /// Sent, not yet accepted by the observer.
    Sent,
    /// The observer accepted it and is working on it ("processing").
    Processing,
    /// Accomplished ("done").
    Done,
    /// Failed (reported by the observer, or given up by the commander).
    Failed,
}

impl TargetState {
    /// The word the console shows: `waiting`, `sent`, `processing`, `done`, `failed`.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Waiting => "waiting",
            Self::Sent => "sent",
            Self::Processing => "processing",
            Self::Done => "done",
            Self::Failed => "failed",
        }
    }

    /// Done or failed.
    #[must_use]
    pub fn is_final(self) -> bool {
        matches!(self, Self::Done | Self::Failed)
    }
}

/// One target of the series.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Target {
    /// The colour.
    pub colour: String,
    /// Its progress.
    pub state: TargetState,
    /// When it was first sent.
    pub sent_at: Option<Instant>,
    /// When the observer accepted it.
    pub accepted_at: Option<Instant>,
    /// When it was done or failed.
    pub finished_at: Option<Instant>,
    /// Times it was sent (1 + resends).
    pub sends: u32,
    /// The commander gave up on it (no word from the observer).
    pub given_up: bool,
    /// The operator cancelled it ([`Commander::cancel`]).
    pub cancelled: bool,
}

impl Target {
    /// From first send to the end, if both happened.
    #[must_use]
    pub fn duration(&self) -> Option<Duration> {
        Some(self.finished_at?.saturating_duration_since(self.sent_at?))
    }
}

/// A broadcast heard, and when.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LogEntry {
    /// When it was heard.
    pub at: Instant,
    /// What.
    pub broadcast: Broadcast,
}

/// Counts of a series.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Summary {
    /// Targets in the series.
    pub total: usize,
    /// Accomplished.
    pub done: usize,
    /// Failed.
    pub failed: usize,
    /// Neither yet.
    pub open: usize,
    /// Broadcasts heard.
    pub broadcasts: usize,
}

impl core::fmt::Display for Summary {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(
            f,
            "{} targets: {} done, {} failed, {} open; {} broadcasts heard",
            self.total, self.done, self.failed, self.open, self.broadcasts
        )
    }
}

/// The most targets a series holds, final ones included: the mission's record (and every
/// display of it) stays bounded however many targets an operator or a script adds. The
/// thesis's mission sends three.
pub const MAX_SERIES: usize = 256;

/// [`Commander::add`] refused a target: the series holds [`MAX_SERIES`] already.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SeriesFull;

impl core::fmt::Display for SeriesFull {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(
            f,
            "the series is full ({MAX_SERIES} targets, the most one commander keeps): \
             no target added; start a new commander for a new series"
        )
    }
}

impl core::error::Error for SeriesFull {}

/// The commander's logic ([module docs](self)).
#[derive(Debug, Clone)]
pub struct Commander {
    cfg: CommanderConfig,
    targets: Vec<Target>,
    current: Option<usize>,
    started: bool,
    last_word: Instant,
    next_send: Option<Instant>,
    out: VecDeque<Broadcast>,
    log: VecDeque<LogEntry>,
    heard: usize,
}

impl Commander {
    /// A commander for this series of colours (sent in order).
    #[must_use]
    pub fn new<S: AsRef<str>>(colours: &[S], cfg: CommanderConfig) -> Self {
        Self {
            cfg,
            targets: colours
                .iter()
                .map(|c| Target {
                    colour: c.as_ref().to_owned(),
                    state: TargetState::Waiting,
                    sent_at: None,
                    accepted_at: None,
                    finished_at: None,
                    sends: 0,
                    given_up: false,
                    cancelled: false,
                })
                .collect(),
            current: None,
            started: false,
            last_word: Instant::ZERO,
            next_send: None,
            out: VecDeque::new(),
            log: VecDeque::new(),
            heard: 0,
        }
    }

    /// The settings.
    #[must_use]
    pub fn config(&self) -> &CommanderConfig {
        &self.cfg
    }

    /// Send the first target (no-op if already started).
    pub fn start(&mut self, now: Instant) {
        if !self.started {
            self.started = true;
            self.advance(now);
        }
    }

    /// The targets and their progress, in series order.
    #[must_use]
    pub fn targets(&self) -> &[Target] {
        &self.targets
    }

    /// The target being worked on.
    #[must_use]
    pub fn current(&self) -> Option<&Target> {
        self.targets.get(self.current?)
    }

    /// Broadcasts heard, oldest first (at most [`CommanderConfig::max_log`]).
    pub fn log(&self) -> impl Iterator<Item = &LogEntry> {
        self.log.iter()
    }

    /// Every target is done or failed.
    #[must_use]
    pub fn is_finished(&self) -> bool {
        self.targets.iter().all(|t| t.state.is_final())
    }

    /// Counts of the series.
    #[must_use]
    pub fn summary(&self) -> Summary {
        let count = |s| self.targets.iter().filter(|t| t.state == s).count();
        let (done, failed) = (count(TargetState::Done), count(TargetState::Failed));
        Summary {
            total: self.targets.len(),
            done,
            failed,
            open: self.targets.len() - done - failed,
            broadcasts: self.heard,
        }
    }

    /// The next broadcast to send.
    pub fn poll_broadcast(&mut self) -> Option<Broadcast> {
        self.out.pop_front()
    }

    /// When [`Commander::handle_timeout`] is due (resend, give up).
    #[must_use]
    pub fn poll_timeout(&self) -> Option<Instant> {
        let t = self.targets.get(self.current?)?;
        let give_up = self.cfg.give_up_after.map(|d| self.last_word + d);
        let resend = (t.state == TargetState::Sent
            || (t.state == TargetState::Processing && self.cfg.poll_processing.is_some()))
        .then_some(self.next_send)
        .flatten();
        match (resend, give_up) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// Time passed: resend an unanswered target; give up on a silent observer.
    pub fn handle_timeout(&mut self, now: Instant) {
        let Some(i) = self.current else {
            return;
        };
        if self
            .cfg
            .give_up_after
            .is_some_and(|d| now >= self.last_word + d)
        {
            if let Some(t) = self.targets.get_mut(i) {
                t.state = TargetState::Failed;
                t.finished_at = Some(now);
                t.given_up = true;
            }
            self.advance(now);
            return;
        }
        if let Some(t) = self.targets.get(i)
            && self.next_send.is_some_and(|n| now >= n)
        {
            match t.state {
                TargetState::Sent => self.send(i, now),
                TargetState::Processing => {
                    if let Some(period) = self.cfg.poll_processing {
                        self.send(i, now);
                        self.next_send = Some(now + period);
                    }
                }
                _ => {}
            }
        }
    }

    /// A broadcast heard: logged; the observer's mission events about the current target
    /// update it (others — earlier targets, other robots — are only logged).
    pub fn handle_broadcast(&mut self, b: &Broadcast, now: Instant) {
        self.heard = self.heard.saturating_add(1);
        if self.log.len() >= self.cfg.max_log.max(1) {
            self.log.pop_front();
        }
        self.log.push_back(LogEntry {
            at: now,
            broadcast: b.clone(),
        });
        if let Broadcast::Emergency {
            robot,
            emergency: Emergency::TargetCancel { colour },
        } = b
            && *robot == self.cfg.robot
        {
            // Another commander process withdrew it: follow, without sending again.
            if let Some(t) = self
                .targets
                .iter_mut()
                .find(|t| t.colour == *colour && !t.state.is_final())
            {
                t.state = TargetState::Failed;
                t.cancelled = true;
                t.finished_at = Some(now);
                if self.current().is_some_and(|c| c.colour == *colour) {
                    self.advance(now);
                }
            }
            return;
        }
        let Broadcast::Mission {
            robot,
            event,
            target,
        } = b
        else {
            return;
        };
        if *robot != self.cfg.observer {
            return;
        }
        let Some(i) = self.current else {
            return;
        };
        let Some(t) = self.targets.get_mut(i) else {
            return;
        };
        if t.colour != *target {
            return;
        }
        self.last_word = now;
        match event {
            MissionEvent::Accepted => {
                if t.state == TargetState::Sent {
                    t.state = TargetState::Processing;
                    t.accepted_at = Some(now);
                    self.next_send = self.cfg.poll_processing.map(|d| now + d);
                }
            }
            MissionEvent::Accomplished | MissionEvent::Failed => {
                t.state = if *event == MissionEvent::Accomplished {
                    TargetState::Done
                } else {
                    TargetState::Failed
                };
                t.finished_at = Some(now);
                if t.accepted_at.is_none() {
                    t.accepted_at = Some(now);
                }
                self.advance(now);
            }
        }
    }

    /// The operator withdraws `colour`: a target of the series not yet final becomes
    /// [`TargetState::Failed`] with [`Target::cancelled`] set; if it was the current one,
    /// [`FLEET_COPIES`] copies of `target-cancel` are queued (the observer ends it, Scooter
    /// stops pursuing it) and the next target goes out. Returns whether a target was
    /// cancelled (`false`: no such colour, or already final).
    pub fn cancel(&mut self, colour: &str, now: Instant) -> bool {
        let Some(i) = self
            .targets
            .iter()
            .position(|t| t.colour == colour && !t.state.is_final())
        else {
            return false;
        };
        let was_current = self.current == Some(i);
        if let Some(t) = self.targets.get_mut(i) {
            t.state = TargetState::Failed;
            t.cancelled = true;
            t.finished_at = Some(now);
        }
        if was_current {
            for _ in 0..FLEET_COPIES {
                self.out.push_back(Broadcast::emergency(
                    &self.cfg.robot,
                    Emergency::TargetCancel {
                        colour: colour.to_owned(),
                    },
                ));
            }
            if self.started {
                self.advance(now);
            }
        }
        true
    }

    /// Queues [`FLEET_COPIES`] copies of `fleet-stop` (every robot stops and holds).
    pub fn fleet_stop(&mut self, reason: &str) {
        for _ in 0..FLEET_COPIES {
            self.out.push_back(Broadcast::emergency(
                &self.cfg.robot,
                Emergency::FleetStop {
                    reason: reason.to_owned(),
                },
            ));
        }
    }

    /// The operator appends `colour` to the series (waiting). When the series had run out
    /// (every target final) and the commander has started, it goes out at once.
    ///
    /// # Errors
    /// [`SeriesFull`] when the series already holds [`MAX_SERIES`] targets (final ones
    /// count: the series is the mission's record); nothing changes.
    pub fn add(&mut self, colour: &str, now: Instant) -> Result<(), SeriesFull> {
        if self.targets.len() >= MAX_SERIES {
            return Err(SeriesFull);
        }
        self.targets.push(Target {
            colour: colour.to_owned(),
            state: TargetState::Waiting,
            sent_at: None,
            accepted_at: None,
            finished_at: None,
            sends: 0,
            given_up: false,
            cancelled: false,
        });
        if self.started && self.current().is_none_or(|t| t.state.is_final()) {
            self.advance(now);
        }
        Ok(())
    }

    /// The operator moves the waiting target at position `from` of the series to position
    /// `to`, which must hold a waiting target too (targets already sent or final keep their
    /// places).
    ///
    /// # Errors
    /// A message naming the problem when either position is out of the series or not a
    /// waiting target; positions in it count from 1, as the operator's displays show them.
    pub fn move_target(&mut self, from: usize, to: usize) -> Result<(), String> {
        let n = self.targets.len();
        for (what, i) in [("from", from), ("to", to)] {
            let shown = i.saturating_add(1);
            match self.targets.get(i) {
                None => {
                    return Err(format!(
                        "{what}: no target at position {shown} (the series has {n})"
                    ));
                }
                Some(t) if t.state != TargetState::Waiting => {
                    return Err(format!(
                        "{what}: target {shown} ({}) is {}, only waiting targets move",
                        t.colour,
                        t.state.as_str()
                    ));
                }
                Some(_) => {}
            }
        }
        // Both are waiting, so both come after the current target: its index is unchanged.
        let t = self.targets.remove(from);
        self.targets.insert(to, t);
        Ok(())
    }

    /// Queues [`FLEET_COPIES`] copies of `fleet-resume`.
    pub fn fleet_resume(&mut self) {
        for _ in 0..FLEET_COPIES {
            self.out.push_back(Broadcast::emergency(
                &self.cfg.robot,
                Emergency::FleetResume,
            ));
        }
    }

    fn send(&mut self, i: usize, now: Instant) {
        if let Some(t) = self.targets.get_mut(i) {
            if t.sent_at.is_none() {
                t.sent_at = Some(now);
                t.state = TargetState::Sent;
            }
            t.sends = t.sends.saturating_add(1);
            self.out.push_back(Broadcast::mission(
                &self.cfg.robot,
                MissionEvent::Accepted,
                &t.colour,
            ));
            self.next_send = Some(now + self.cfg.resend);
        }
    }

    /// Send the next waiting target, if any.
    fn advance(&mut self, now: Instant) {
        self.current = self
            .targets
            .iter()
            .position(|t| t.state == TargetState::Waiting);
        self.next_send = None;
        if let Some(i) = self.current {
            self.last_word = now;
            self.send(i, now);
        }
    }
}

/// A robot's liveness as the commander sees it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Life {
    /// Heard within the silence limit.
    Alive,
    /// Silent for longer than the limit.
    Lost,
}

impl Life {
    /// `alive` or `lost`.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Life::Alive => "alive",
            Life::Lost => "lost",
        }
    }
}

/// A change of a robot's [`Life`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LifeChange {
    /// The robot.
    pub robot: String,
    /// Its new state.
    pub life: Life,
    /// How long it had been silent when the change was seen (zero for a robot heard for
    /// the first time).
    pub silent: Duration,
}

/// Which robots are alive, from the broadcasts heard (every robot sends a `Status` at
/// least once a second). A robot silent for longer than the limit is [`Life::Lost`]; heard
/// again, it is [`Life::Alive`]. Sans-IO: [`Liveness::heard`] and
/// [`Liveness::handle_timeout`] are the inputs, their [`LifeChange`]s and
/// [`Liveness::poll_timeout`] the outputs.
#[derive(Debug, Clone)]
pub struct Liveness {
    lost_after: Duration,
    ignore: Vec<String>,
    robots: BTreeMap<String, Heard>,
}

/// What [`Liveness`] knows of one robot.
#[derive(Debug, Clone, Copy)]
struct Heard {
    /// Last broadcast (or when it was first expected).
    last: Instant,
    life: Life,
    /// Heard at least once.
    ever: bool,
}

impl Liveness {
    /// Robots silent for longer than `lost_after` are lost; broadcasts of the names in
    /// `ignore` (the commander's own) are not counted.
    #[must_use]
    pub fn new(lost_after: Duration, ignore: &[&str]) -> Self {
        Self {
            lost_after,
            ignore: ignore.iter().map(|s| (*s).to_owned()).collect(),
            robots: BTreeMap::new(),
        }
    }

    /// The silence limit.
    #[must_use]
    pub fn lost_after(&self) -> Duration {
        self.lost_after
    }

    /// Expects `robot` from `now` on: it is reported alive when first heard, and lost if it
    /// is not heard within the limit.
    pub fn expect(&mut self, robot: &str, now: Instant) {
        if !self.ignore.iter().any(|i| i == robot) {
            self.robots.entry(robot.to_owned()).or_insert(Heard {
                last: now,
                life: Life::Alive,
                ever: false,
            });
        }
    }

    /// A broadcast from `robot` at `now`: a change when it is heard for the first time or
    /// after it was lost.
    pub fn heard(&mut self, robot: &str, now: Instant) -> Option<LifeChange> {
        if self.ignore.iter().any(|i| i == robot) {
            return None;
        }
        let h = self.robots.entry(robot.to_owned()).or_insert(Heard {
            last: now,
            life: Life::Alive,
            ever: false,
        });
        let silent = if h.ever {
            now.saturating_duration_since(h.last)
        } else {
            Duration::ZERO
        };
        let change = !h.ever || h.life == Life::Lost;
        h.last = now;
        h.life = Life::Alive;
        h.ever = true;
        change.then(|| LifeChange {
            robot: robot.to_owned(),
            life: Life::Alive,
            silent,
        })
    }

    /// Time passed: robots silent for longer than the limit become lost (once each).
    pub fn handle_timeout(&mut self, now: Instant) -> Vec<LifeChange> {
        let mut out = Vec::new();
        for (robot, h) in &mut self.robots {
            let silent = now.saturating_duration_since(h.last);
            if h.life == Life::Alive && silent > self.lost_after {
                h.life = Life::Lost;
                out.push(LifeChange {
                    robot: robot.clone(),
                    life: Life::Lost,
                    silent,
                });
            }
        }
        out
    }

    /// When [`Liveness::handle_timeout`] is next due (the earliest alive robot's limit).
    #[must_use]
    pub fn poll_timeout(&self) -> Option<Instant> {
        self.robots
            .values()
            .filter(|h| h.life == Life::Alive)
            .map(|h| h.last + self.lost_after + Duration::from_millis(1))
            .min()
    }

    /// Every robot known and its state.
    pub fn robots(&self) -> impl Iterator<Item = (&str, Life)> {
        self.robots.iter().map(|(r, h)| (r.as_str(), h.life))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mission::msg::{COMMANDER, Emergency, SCOOTER, SKEETER};

    fn t(s: u64) -> Instant {
        Instant::from_millis(s * 1000)
    }

    fn from_skeeter(event: MissionEvent, colour: &str) -> Broadcast {
        Broadcast::mission(SKEETER, event, colour)
    }

    fn drain(c: &mut Commander) -> Vec<Broadcast> {
        std::iter::from_fn(|| c.poll_broadcast()).collect()
    }

    fn states(c: &Commander) -> Vec<&'static str> {
        c.targets().iter().map(|t| t.state.as_str()).collect()
    }

    #[test]
    fn added_targets_queue_up_and_restart_a_finished_series() {
        let mut c = Commander::new(&["red"], CommanderConfig::default());
        c.add("blue", t(0)).unwrap();
        c.start(t(0));
        let _ = drain(&mut c);
        assert_eq!(states(&c), ["sent", "waiting"]);
        c.handle_broadcast(&from_skeeter(MissionEvent::Accomplished, "red"), t(1));
        c.handle_broadcast(&from_skeeter(MissionEvent::Accomplished, "blue"), t(2));
        assert!(c.is_finished());
        let _ = drain(&mut c);
        c.add("green", t(3)).unwrap();
        assert_eq!(states(&c), ["done", "done", "sent"]);
        assert_eq!(drain(&mut c), [Broadcast::new_target("green")]);
    }

    #[test]
    fn a_full_series_refuses_more_targets_and_stays_as_it_was() {
        let mut c = Commander::new(&["red"], CommanderConfig::default());
        for _ in 1..MAX_SERIES {
            assert_eq!(c.add("blue", t(0)), Ok(()));
        }
        assert_eq!(c.targets().len(), MAX_SERIES);
        assert_eq!(c.add("green", t(0)), Err(SeriesFull));
        assert_eq!(c.targets().len(), MAX_SERIES);
        assert!(c.targets().iter().all(|t| t.colour != "green"));
        assert!(SeriesFull.to_string().contains("256 targets"));
    }

    #[test]
    fn only_waiting_targets_move() {
        let mut c = Commander::new(
            &["red", "blue", "green", "yellow"],
            CommanderConfig::default(),
        );
        c.start(t(0));
        let _ = drain(&mut c);
        // Positions in the messages count from 1, as the displays show them.
        let e = c.move_target(0, 2).unwrap_err();
        assert_eq!(e, "from: target 1 (red) is sent, only waiting targets move");
        assert!(
            c.move_target(1, 9)
                .unwrap_err()
                .contains("no target at position 10 (the series has 4)")
        );
        c.move_target(3, 1).unwrap();
        let order: Vec<&str> = c.targets().iter().map(|t| t.colour.as_str()).collect();
        assert_eq!(order, ["red", "yellow", "blue", "green"]);
        c.handle_broadcast(&from_skeeter(MissionEvent::Accomplished, "red"), t(1));
        assert_eq!(drain(&mut c), [Broadcast::new_target("yellow")]);
    }

    #[test]
    fn a_cancelled_target_fails_at_once_and_the_next_goes_out() {
        let mut c = Commander::new(&["red", "blue", "green"], CommanderConfig::default());
        c.start(t(0));
        let _ = drain(&mut c);
        c.handle_broadcast(&from_skeeter(MissionEvent::Accepted, "red"), t(1));
        assert!(!c.cancel("purple", t(2)), "not in the series");
        // A waiting target is cancelled without a word on the channel.
        assert!(c.cancel("green", t(2)));
        assert_eq!(drain(&mut c), []);
        assert!(c.cancel("red", t(3)));
        assert!(!c.cancel("red", t(3)), "already final");
        let out = drain(&mut c);
        let cancel = Broadcast::emergency(
            COMMANDER,
            Emergency::TargetCancel {
                colour: "red".into(),
            },
        );
        assert_eq!(
            out.iter().filter(|b| **b == cancel).count(),
            FLEET_COPIES,
            "{out:?}"
        );
        assert_eq!(out.last(), Some(&Broadcast::new_target("blue")));
        assert_eq!(states(&c), ["failed", "sent", "failed"]);
        assert!(c.targets()[0].cancelled && c.targets()[2].cancelled);
        assert!(!c.targets()[0].given_up);
        // Skeeter's late `Failed` for red changes nothing.
        c.handle_broadcast(&from_skeeter(MissionEvent::Failed, "red"), t(4));
        assert_eq!(states(&c), ["failed", "sent", "failed"]);
        // A cancel by another commander process of the same name is followed.
        c.handle_broadcast(
            &Broadcast::emergency(
                COMMANDER,
                Emergency::TargetCancel {
                    colour: "blue".into(),
                },
            ),
            t(5),
        );
        assert_eq!(states(&c), ["failed", "failed", "failed"]);
        assert!(c.is_finished());
    }

    #[test]
    fn fleet_commands_go_out_several_times() {
        let mut c = Commander::new(&["red"], CommanderConfig::default());
        c.fleet_stop("test");
        c.fleet_resume();
        let out = drain(&mut c);
        assert_eq!(out.len(), 2 * FLEET_COPIES);
        assert!(matches!(
            &out[0],
            Broadcast::Emergency {
                emergency: Emergency::FleetStop { reason },
                ..
            } if reason == "test"
        ));
        assert!(matches!(
            &out[FLEET_COPIES],
            Broadcast::Emergency {
                emergency: Emergency::FleetResume,
                ..
            }
        ));
    }

    #[test]
    fn liveness_reports_a_silent_robot_lost_once_and_back_when_heard() {
        let mut l = Liveness::new(Duration::from_secs(5), &[COMMANDER]);
        assert_eq!(l.poll_timeout(), None);
        l.expect(SKEETER, t(0));
        l.expect(COMMANDER, t(0));
        assert_eq!(l.heard(COMMANDER, t(0)), None, "own name ignored");
        let first = l.heard(SCOOTER, t(1)).unwrap();
        assert_eq!((first.life, first.silent), (Life::Alive, Duration::ZERO));
        assert_eq!(l.heard(SCOOTER, t(2)), None, "no change");
        assert_eq!(l.handle_timeout(t(5)), []);
        // Skeeter (expected at 0, never heard) is lost after 5 s; Scooter after 2 + 5.
        let lost = l.handle_timeout(t(6));
        assert_eq!(lost.len(), 1);
        assert_eq!(
            (lost[0].robot.as_str(), lost[0].life),
            (SKEETER, Life::Lost)
        );
        assert_eq!(l.handle_timeout(t(6)), [], "reported once");
        assert!(l.poll_timeout().unwrap() > t(7));
        let lost = l.handle_timeout(t(8));
        assert_eq!(
            (lost[0].robot.as_str(), lost[0].life),
            (SCOOTER, Life::Lost)
        );
        assert_eq!(lost[0].silent, Duration::from_secs(6));
        assert_eq!(l.poll_timeout(), None, "everyone is lost");
        let back = l.heard(SCOOTER, t(9)).unwrap();
        assert_eq!(
            (back.life, back.silent),
            (Life::Alive, Duration::from_secs(7))
        );
        let states: Vec<_> = l.robots().collect();
        assert_eq!(states, [(SCOOTER, Life::Alive), (SKEETER, Life::Lost)]);
        // An expected robot heard for the first time is reported alive.
        let mut l = Liveness::new(Duration::from_secs(5), &[]);
        l.expect(SKEETER, t(0));
        let first = l.heard(SKEETER, t(1)).unwrap();
        assert_eq!((first.life, first.silent), (Life::Alive, Duration::ZERO));
        assert_eq!(l.heard(SKEETER, t(2)), None);
    }

    #[test]
    fn a_series_goes_out_one_target_at_a_time() {
        let mut c = Commander::new(&["red", "blue", "green"], CommanderConfig::default());
        assert_eq!(drain(&mut c), [], "nothing before start");
        c.start(t(0));
        c.start(t(0));
        assert_eq!(drain(&mut c), [Broadcast::new_target("red")]);
        assert_eq!(states(&c), ["sent", "waiting", "waiting"]);
        c.handle_broadcast(&from_skeeter(MissionEvent::Accepted, "red"), t(1));
        assert_eq!(states(&c), ["processing", "waiting", "waiting"]);
        assert_eq!(drain(&mut c), []);
        c.handle_broadcast(&from_skeeter(MissionEvent::Accomplished, "red"), t(30));
        assert_eq!(drain(&mut c), [Broadcast::new_target("blue")]);
        assert_eq!(states(&c), ["done", "sent", "waiting"]);
        assert_eq!(c.targets()[0].duration(), Some(Duration::from_secs(30)));
        c.handle_broadcast(&from_skeeter(MissionEvent::Accepted, "blue"), t(31));
        c.handle_broadcast(&from_skeeter(MissionEvent::Failed, "blue"), t(40));
        assert_eq!(drain(&mut c), [Broadcast::new_target("green")]);
        assert!(!c.is_finished());
        // Failed straight away, without an Accepted first (it was lost).
        c.handle_broadcast(&from_skeeter(MissionEvent::Failed, "green"), t(41));
        assert_eq!(states(&c), ["done", "failed", "failed"]);
        assert!(c.is_finished());
        assert_eq!(drain(&mut c), []);
        assert_eq!(c.current(), None);
        assert_eq!(c.poll_timeout(), None);
        let s = c.summary();
        assert_eq!(
            (s.total, s.done, s.failed, s.open, s.broadcasts),
            (3, 1, 2, 0, 5)
        );
        assert_eq!(
            s.to_string(),
            "3 targets: 1 done, 2 failed, 0 open; 5 broadcasts heard"
        );
    }

    #[test]
    fn unanswered_targets_are_resent_until_accepted() {
        let mut c = Commander::new(&["red"], CommanderConfig::default());
        c.start(t(0));
        drain(&mut c);
        assert_eq!(c.poll_timeout(), Some(t(2)));
        c.handle_timeout(Instant::from_millis(1999));
        assert_eq!(drain(&mut c), []);
        c.handle_timeout(t(2));
        assert_eq!(drain(&mut c), [Broadcast::new_target("red")]);
        assert_eq!(c.targets()[0].sends, 2);
        assert_eq!(c.targets()[0].sent_at, Some(t(0)), "first send kept");
        c.handle_broadcast(&from_skeeter(MissionEvent::Accepted, "red"), t(3));
        c.handle_timeout(t(7));
        assert_eq!(
            drain(&mut c),
            [],
            "no resend once accepted (only the 5 s poll)"
        );
        assert_eq!(c.targets()[0].accepted_at, Some(t(3)));
    }

    #[test]
    fn only_the_observers_events_about_the_current_target_count_but_all_are_logged() {
        let mut c = Commander::new(&["red", "blue"], CommanderConfig::default());
        c.start(t(0));
        drain(&mut c);
        let noise = [
            Broadcast::mission(SCOOTER, MissionEvent::Accomplished, "red"),
            Broadcast::mission(COMMANDER, MissionEvent::Accepted, "red"),
            from_skeeter(MissionEvent::Accomplished, "blue"),
            Broadcast::emergency(SKEETER, Emergency::ScooterLost),
            Broadcast::status(SCOOTER, "go-to-target", "", None),
        ];
        for (i, b) in noise.iter().enumerate() {
            c.handle_broadcast(b, t(i as u64));
        }
        assert_eq!(states(&c), ["sent", "waiting"]);
        let log: Vec<&Broadcast> = c.log().map(|e| &e.broadcast).collect();
        assert_eq!(log.len(), 5);
        assert_eq!(log[3], &noise[3]);
        assert_eq!(c.log().nth(4).unwrap().at, t(4));
    }

    #[test]
    fn a_silent_observer_is_given_up_on() {
        let mut c = Commander::new(
            &["red", "blue"],
            CommanderConfig {
                give_up_after: Some(Duration::from_secs(60)),
                resend: Duration::from_secs(100),
                poll_processing: None,
                ..CommanderConfig::default()
            },
        );
        c.start(t(0));
        drain(&mut c);
        c.handle_broadcast(&from_skeeter(MissionEvent::Accepted, "red"), t(10));
        assert_eq!(c.poll_timeout(), Some(t(70)), "60 s after the last word");
        c.handle_timeout(t(69));
        assert_eq!(states(&c), ["processing", "waiting"]);
        c.handle_timeout(t(70));
        assert_eq!(states(&c), ["failed", "sent"]);
        assert!(c.targets()[0].given_up);
        assert_eq!(drain(&mut c), [Broadcast::new_target("blue")]);
        // A late report about red changes nothing.
        c.handle_broadcast(&from_skeeter(MissionEvent::Accomplished, "red"), t(71));
        assert_eq!(states(&c), ["failed", "sent"]);
    }

    #[test]
    fn the_log_is_bounded_and_an_empty_series_is_finished() {
        let mut c = Commander::new(
            &["red"],
            CommanderConfig {
                max_log: 3,
                ..CommanderConfig::default()
            },
        );
        for i in 0..5 {
            c.handle_broadcast(&Broadcast::status(SKEETER, "idle", "", None), t(i));
        }
        assert_eq!(c.log().count(), 3);
        assert_eq!(c.log().next().unwrap().at, t(2));
        assert_eq!(c.summary().broadcasts, 5);
        let empty = Commander::new::<&str>(&[], CommanderConfig::default());
        assert!(empty.is_finished());
        assert_eq!(empty.summary(), Summary::default());
    }

    #[test]
    fn a_processing_target_is_polled_so_a_lost_outcome_is_recovered() {
        let mut c = Commander::new(&["red", "blue"], CommanderConfig::default());
        c.start(t(0));
        assert_eq!(drain(&mut c), [Broadcast::new_target("red")]);
        c.handle_broadcast(&from_skeeter(MissionEvent::Accepted, "red"), t(1));
        // Polled every 5 s while processing.
        assert_eq!(c.poll_timeout(), Some(t(6)));
        c.handle_timeout(t(4));
        assert_eq!(drain(&mut c), []);
        c.handle_timeout(t(6));
        assert_eq!(drain(&mut c), [Broadcast::new_target("red")]);
        assert_eq!(c.poll_timeout(), Some(t(11)));
        // Skeeter's echo keeps it processing; the outcome (Skeeter's answer to a poll after
        // the first broadcast of it was lost) ends it.
        c.handle_broadcast(&from_skeeter(MissionEvent::Accepted, "red"), t(7));
        assert_eq!(states(&c), ["processing", "waiting"]);
        c.handle_timeout(t(11));
        assert_eq!(drain(&mut c), [Broadcast::new_target("red")]);
        c.handle_broadcast(&from_skeeter(MissionEvent::Accomplished, "red"), t(11));
        assert_eq!(states(&c), ["done", "sent"]);
        assert_eq!(drain(&mut c), [Broadcast::new_target("blue")]);
        // No polling when switched off.
        let mut c = Commander::new(
            &["red"],
            CommanderConfig {
                poll_processing: None,
                give_up_after: None,
                ..CommanderConfig::default()
            },
        );
        c.start(t(0));
        drain(&mut c);
        c.handle_broadcast(&from_skeeter(MissionEvent::Accepted, "red"), t(1));
        assert_eq!(c.poll_timeout(), None);
        c.handle_timeout(t(100));
        assert_eq!(drain(&mut c), []);
    }
}

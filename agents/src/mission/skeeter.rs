//! Skeeter's Self Agent: [`SkeeterBrain`] drives Skeeter's Spreading Activation Network
//! (`agents/networks/skeeter.toml`, MISSION.md "Skeeter's SAN") through the mission.
//!
//! Sans-IO: inputs are `handle_*(…, now)` calls, outputs are [`SkeeterBrain::poll_output`]
//! and [`SkeeterBrain::poll_timeout`].
//!
//! # Inputs → conditions (the detect/find nodes)
//!
//! The detect/find nodes read the scan report, whose detections are exactly the Scan node's
//! SES entries after the sweep ([`super::scan`] removes what a sweep did not see).
//!
//! | input | conditions it feeds |
//! |---|---|
//! | commander's `Mission{commander, Accepted, colour}` ([`SkeeterBrain::handle_broadcast`]) | a target starts (one at a time; others wait in a queue): `target-requested` ↑, `mission-reported` ↓, the target timer starts |
//! | a [`ScanReport`] ([`SkeeterBrain::handle_scan`]) | `scanner-idle` ↑; with a target: `scan-done` ↑, `target-in-view` / `target-not-in-view` (find-target node), `heading-requested` ↑ only when [`SkeeterConfig::publish_every_scan`] is off; always `scooter-in-view`, with a target `scooter-lost` (detect-Scooter node) |
//! | Scooter's `target-reached` (colour = target) | `scooter-reached-target` ↑ |
//! | Scooter's `target-reply` (colour = target, after a query) | `scooter-cannot-see-target` = not seen |
//! | Scooter's client asks for the SES ([`SkeeterBrain::handle_heading_request`]) | `heading-requested` ↑ |
//! | the target timer ([`SkeeterBrain::handle_timeout`]) | `timeout` ↑ (timeout node) |
//!
//! The find and detect nodes have hysteresis, because a single sweep can miss a thing that
//! is there (Scooter driving between Skeeter and the target hides it; an object can hide
//! Scooter for a moment): `target-not-in-view` is raised after
//! [`SkeeterConfig::query_after_scans`] sweeps in a row without the target, and
//! `scooter-lost` after [`SkeeterConfig::lost_after_scans`] sweeps in a row without Scooter
//! (while a target is being processed: there is no mission to call Scooter back for
//! otherwise), if it has not been called back yet or the last call is older than
//! [`SkeeterConfig::stress_repeat`] (a broadcast may be lost). When a sweep sees Scooter
//! again after a call-back, the brain broadcasts `scooter-found` at once (Scooter resumes its
//! mission), repeats it with the next [`SkeeterConfig::found_repeats`] periodic `Status` broadcasts (a
//! datagram may be lost), and clears `scooter-called-back`.
//!
//! A commander `Accepted` for the target that has just ended is answered with its outcome
//! again ([`SkeeterBrain::handle_target`]): the commander polls a processing target, so a
//! lost `Accomplished`/`Failed` is recovered.
//!
//! # Publishing the SES
//!
//! With [`SkeeterConfig::publish_every_scan`] (the default, as agreed for the Peer Agent
//! source `ses`: one sample per full sweep) every report's shared form is published at once
//! ([`SkeeterOutput::PublishSes`]), whatever it holds: Scooter needs the bearings even when
//! its own or the target's record is missing. The SAN's `send-heading` then answers explicit
//! requests ([`SkeeterBrain::handle_heading_request`], e.g. when Scooter's client is
//! granted the source) with the latest sample. With the option off, the thesis's gating
//! holds: a sweep only makes a sample *due* (`heading-requested`), and `send-heading`
//! publishes it when the target and Scooter are both in view.
//!
//! # Modules → actions
//!
//! After every input the brain runs the network ([`crate::san::Network::step`]) until a
//! module fires, carries out that module's action, updates the conditions the action
//! changes, and repeats until no module is executable (at most 16 firings per input).
//! Every module makes one of its own preconditions false, so this ends.
//!
//! | module | action | conditions after it |
//! |---|---|---|
//! | `scan-for-target` | [`SkeeterOutput::StartScan`] | `scanner-idle` ↓ |
//! | `send-heading` | [`SkeeterOutput::PublishSes`] with the last scan's shared form | `heading-requested` ↓, `heading-sent` ↑ |
//! | `call-back-scooter` | broadcast `scooter-lost` (the stress call) | `scooter-lost` ↓, `scooter-called-back` ↑ |
//! | `ask-scooter` | broadcast `target-query` (colour) | `scan-done` ↓, `scooter-asked` ↑, `scooter-cannot-see-target` ↓ (await the reply) |
//! | `report-failed` | broadcast `Mission{skeeter, Failed, colour}` | the target ends |
//! | `report-timeout` | broadcast `Mission{skeeter, Failed, colour}` | the target ends |
//! | `report-accomplished` | broadcast `Mission{skeeter, Accomplished, colour}` | the target ends |
//! | any other (a network edited to add one) | none | the module's own add/delete lists |
//!
//! When a target ends, its conditions are cleared, `mission-reported` ↑, and the next queued
//! target starts (Skeeter broadcasts its own `Accepted` for it). The running module is the
//! robot's **behaviour** ([`SkeeterBrain::behaviour`]; `idle` with no target), broadcast in
//! a `Status` when it changes and every [`SkeeterConfig::status_interval`].
//!
//! If the network has an executable module but none fires within 64 steps (a threshold the
//! activations never reach, say), the executable module with the highest activation is
//! taken, so that the brain never stalls on a network's parameters.

use std::collections::VecDeque;
use std::time::Duration;

use ima_hal::Instant;

use super::msg::{Broadcast, Emergency, MissionEvent, Pose};
use super::scan::ScanReport;
use crate::san::{Network, SpecError};
use crate::ses::shared::SharedForm;

/// Skeeter's network as shipped (`agents/networks/skeeter.toml`).
pub const SKEETER_NETWORK: &str = include_str!("../../networks/skeeter.toml");

/// Conditions the brain feeds; a network must declare them all.
pub const FED_CONDITIONS: [&str; 15] = [
    "target-requested",
    "scanner-idle",
    "scan-done",
    "target-in-view",
    "target-not-in-view",
    "scooter-in-view",
    "scooter-lost",
    "heading-requested",
    "heading-sent",
    "scooter-called-back",
    "scooter-asked",
    "scooter-cannot-see-target",
    "scooter-reached-target",
    "timeout",
    "mission-reported",
];

/// Behaviour name when no target is being processed.
pub const IDLE: &str = "idle";
/// Module name recorded in a [`TargetOutcome`] for a target the commander cancelled.
pub const CANCELLED: &str = "cancelled";

const MAX_FIRINGS: usize = 16;
const MAX_STEPS: usize = 64;

/// Settings of Skeeter's brain.
#[derive(Debug, Clone, PartialEq)]
pub struct SkeeterConfig {
    /// This robot's broadcast name.
    pub robot: String,
    /// Scooter's broadcast name (its emergencies are listened to).
    pub scooter: String,
    /// The commander's broadcast name (its `Mission Accepted` are new targets).
    pub commander: String,
    /// Scooter's SES tag (its marker in the colour database).
    pub scooter_tag: String,
    /// A target not accomplished within this time fails.
    pub target_timeout: Duration,
    /// While Scooter stays unseen, the stress call is repeated after this long.
    pub stress_repeat: Duration,
    /// Period of `Status` broadcasts (`None`: only when the behaviour changes).
    pub status_interval: Option<Duration>,
    /// Pose reported in `Status` (Skeeter does not move: the common frame's origin).
    pub pose: Option<Pose>,
    /// Targets waiting beyond this many are refused (ignored).
    pub max_queue: usize,
    /// Sweeps in a row without the target before `target-not-in-view` (and the question
    /// to Scooter).
    pub query_after_scans: u32,
    /// Sweeps in a row without Scooter before `scooter-lost` (the stress call).
    pub lost_after_scans: u32,
    /// Publish every sweep's SES ([module docs](self), "Publishing the SES").
    pub publish_every_scan: bool,
    /// The network, TOML ([`crate::san::spec`]).
    pub network: String,
    /// After `scooter-found`, the call is repeated with this many following periodic
    /// `Status` broadcasts ([`SkeeterConfig::status_interval`]; none without it) (a datagram may be lost; Scooter would otherwise home for ever).
    pub found_repeats: u32,
    /// A commander `Accepted` for the target that ended last, within this long of its end, is
    /// answered with that target's outcome (the commander polls because it missed it)
    /// instead of starting the target again. A series asking for the same colour twice in a
    /// row within this window gets the first outcome for the second: keep it short.
    pub outcome_memory: Duration,
}

impl Default for SkeeterConfig {
    fn default() -> Self {
        Self {
            robot: super::msg::SKEETER.to_owned(),
            scooter: super::msg::SCOOTER.to_owned(),
            commander: super::msg::COMMANDER.to_owned(),
            scooter_tag: super::msg::SCOOTER_TAG.to_owned(),
            target_timeout: Duration::from_secs(180),
            stress_repeat: Duration::from_secs(10),
            status_interval: Some(Duration::from_secs(1)),
            pose: Some(Pose {
                x_mm: 0,
                y_mm: 0,
                theta_mrad: 0,
            }),
            max_queue: 16,
            query_after_scans: 2,
            lost_after_scans: 2,
            publish_every_scan: true,
            network: SKEETER_NETWORK.to_owned(),
            found_repeats: 2,
            outcome_memory: Duration::from_secs(20),
        }
    }
}

/// Why a brain could not be built.
#[derive(Debug, Clone, PartialEq)]
pub enum SkeeterError {
    /// The network TOML is invalid.
    Network(SpecError),
    /// The network lacks a condition the brain feeds.
    MissingCondition(&'static str),
}

impl core::fmt::Display for SkeeterError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Network(e) => write!(f, "skeeter network: {e}"),
            Self::MissingCondition(c) => write!(f, "skeeter network lacks condition `{c}`"),
        }
    }
}

impl std::error::Error for SkeeterError {}

/// What the brain asks the runtime to do.
#[derive(Debug, Clone, PartialEq)]
pub enum SkeeterOutput {
    /// Send on the broadcast channel.
    Broadcast(Broadcast),
    /// Start a full scan (then feed its report to [`SkeeterBrain::handle_scan`]).
    StartScan,
    /// Publish this SES sample on the Peer Agent source `ses`.
    PublishSes(SharedForm),
}

/// How a target ended.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TargetOutcome {
    /// The colour.
    pub target: String,
    /// Accomplished or Failed.
    pub event: MissionEvent,
    /// The module that reported it.
    pub module: String,
    /// When it started.
    pub started: Instant,
    /// When it ended.
    pub ended: Instant,
}

#[derive(Debug, Clone)]
struct Active {
    target: String,
    started: Instant,
    deadline: Instant,
}

/// Skeeter's Self Agent ([module docs](self)).
#[derive(Debug)]
pub struct SkeeterBrain {
    cfg: SkeeterConfig,
    net: Network,
    active: Option<Active>,
    queue: VecDeque<String>,
    scanning: bool,
    last_form: Option<SharedForm>,
    last_call: Option<Instant>,
    target_missing: u32,
    scooter_missing: u32,
    behaviour: String,
    next_status: Option<Instant>,
    out: VecDeque<SkeeterOutput>,
    outcomes: Vec<TargetOutcome>,
    firings: u64,
    found_left: u32,
}

impl SkeeterBrain {
    /// A brain with its network parsed from [`SkeeterConfig::network`].
    ///
    /// # Errors
    /// [`SkeeterError`].
    pub fn new(cfg: SkeeterConfig) -> Result<Self, SkeeterError> {
        let net = Network::from_toml(&cfg.network).map_err(SkeeterError::Network)?;
        for c in FED_CONDITIONS {
            if net.condition(c).is_none() {
                return Err(SkeeterError::MissingCondition(c));
            }
        }
        let mut b = Self {
            cfg,
            net,
            active: None,
            queue: VecDeque::new(),
            scanning: false,
            last_form: None,
            last_call: None,
            target_missing: 0,
            scooter_missing: 0,
            behaviour: IDLE.to_owned(),
            next_status: None,
            out: VecDeque::new(),
            outcomes: Vec::new(),
            firings: 0,
            found_left: 0,
        };
        b.set("scanner-idle", true);
        Ok(b)
    }

    /// The settings.
    #[must_use]
    pub fn config(&self) -> &SkeeterConfig {
        &self.cfg
    }

    /// The network (conditions, activations).
    #[must_use]
    pub fn network(&self) -> &Network {
        &self.net
    }

    /// The running module (`idle` with no target).
    #[must_use]
    pub fn behaviour(&self) -> &str {
        &self.behaviour
    }

    /// The target being processed.
    #[must_use]
    pub fn target(&self) -> Option<&str> {
        self.active.as_ref().map(|a| a.target.as_str())
    }

    /// Targets waiting, in order.
    pub fn queued(&self) -> impl Iterator<Item = &str> {
        self.queue.iter().map(String::as_str)
    }

    /// Whether the brain asked for a scan whose report has not come yet.
    #[must_use]
    pub fn is_scanning(&self) -> bool {
        self.scanning
    }

    /// Every target ended so far, in order.
    #[must_use]
    pub fn outcomes(&self) -> &[TargetOutcome] {
        &self.outcomes
    }

    /// Modules fired so far.
    #[must_use]
    pub fn firings(&self) -> u64 {
        self.firings
    }

    /// A one-line SAN summary: the target and the true conditions, cut to
    /// [`super::msg::MAX_WIRE_STR`] bytes at a char boundary (it travels in a `Status`).
    #[must_use]
    pub fn san_summary(&self) -> String {
        let conds: Vec<&str> = self
            .net
            .condition_names()
            .filter(|c| self.net.condition(c) == Some(true))
            .collect();
        let s = format!(
            "target={} conditions={}",
            self.target().unwrap_or("-"),
            conds.join(",")
        );
        super::msg::truncate_wire_str(&s).to_owned()
    }

    /// The next output.
    pub fn poll_output(&mut self) -> Option<SkeeterOutput> {
        self.out.pop_front()
    }

    /// When [`SkeeterBrain::handle_timeout`] is due (target timer, status period).
    #[must_use]
    pub fn poll_timeout(&self) -> Option<Instant> {
        let deadline = self
            .active
            .as_ref()
            .filter(|_| self.net.condition("timeout") != Some(true))
            .map(|a| a.deadline);
        match (deadline, self.next_status) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// Start: the first `Status` goes out now, and the status period begins.
    pub fn start(&mut self, now: Instant) {
        self.status(now);
    }

    /// A new target from the commander (also reached through
    /// [`SkeeterBrain::handle_broadcast`]). The target being processed is answered again with
    /// `Accepted` (the commander resends when it missed the answer); one already waiting is
    /// ignored; otherwise it is queued, and started at once if nothing is being processed.
    ///
    /// The target that ended last, asked for again within [`SkeeterConfig::outcome_memory`]
    /// of its end, is answered with its outcome again (the commander polls a target it
    /// believes is processing; the outcome broadcast was lost) and is not run again.
    pub fn handle_target(&mut self, colour: &str, now: Instant) {
        if self.target() == Some(colour) {
            self.broadcast(Broadcast::mission(
                &self.cfg.robot,
                MissionEvent::Accepted,
                colour,
            ));
            return;
        }
        if let Some(last) = self.outcomes.last()
            && last.target == colour
            && now.saturating_duration_since(last.ended) <= self.cfg.outcome_memory
            && !self.queue.iter().any(|q| q == colour)
        {
            let event = last.event;
            self.broadcast(Broadcast::mission(&self.cfg.robot, event, colour));
            return;
        }
        if self.queue.iter().any(|q| q == colour) || self.queue.len() >= self.cfg.max_queue {
            return;
        }
        self.queue.push_back(colour.to_owned());
        if self.active.is_none() {
            self.next_target(now);
        }
        self.decide(now);
    }

    /// The commander withdrew `colour`: a queued copy is dropped; the target being processed
    /// ends as `Failed` (module `cancelled`, broadcast so that Scooter and the commander see
    /// it) and the next queued target starts. Another colour changes nothing.
    pub fn handle_cancel(&mut self, colour: &str, now: Instant) {
        self.queue.retain(|q| q != colour);
        if self.target() == Some(colour) {
            self.end_target(MissionEvent::Failed, CANCELLED, now);
            self.decide(now);
        }
    }

    /// A broadcast heard on the channel: commander targets and cancels, Scooter's
    /// `target-reached` and `target-reply`. Everything else (statuses, other robots) is
    /// ignored.
    pub fn handle_broadcast(&mut self, b: &Broadcast, now: Instant) {
        match b {
            Broadcast::Mission {
                robot,
                event: MissionEvent::Accepted,
                target,
            } if *robot == self.cfg.commander => self.handle_target(target, now),
            Broadcast::Emergency {
                robot,
                emergency: Emergency::TargetCancel { colour },
            } if *robot == self.cfg.commander => self.handle_cancel(colour, now),
            Broadcast::Emergency { robot, emergency } if *robot == self.cfg.scooter => {
                let current = self.target().map(str::to_owned);
                match emergency {
                    Emergency::TargetReached { colour } if current.as_ref() == Some(colour) => {
                        self.set("scooter-reached-target", true);
                    }
                    Emergency::TargetReply { colour, seen }
                        if current.as_ref() == Some(colour) && self.is("scooter-asked") =>
                    {
                        self.set("scooter-cannot-see-target", !seen);
                    }
                    _ => return,
                }
                self.decide(now);
            }
            _ => {}
        }
    }

    /// Scooter's Peer Agent client asked for the SES: send the latest sample when the
    /// network allows (`send-heading`).
    pub fn handle_heading_request(&mut self, now: Instant) {
        self.set("heading-requested", true);
        self.decide(now);
    }

    /// A full scan ended ([`super::scan::ScanEvent::ScanDone`]).
    pub fn handle_scan(&mut self, report: &ScanReport, now: Instant) {
        self.scanning = false;
        self.set("scanner-idle", true);
        self.last_form = Some(report.shared.clone());
        if self.cfg.publish_every_scan {
            self.out
                .push_back(SkeeterOutput::PublishSes(report.shared.clone()));
        }
        let active = self.active.is_some();
        if let Some(target) = self.target().map(str::to_owned) {
            let seen = report.sees(&target);
            self.target_missing = if seen {
                0
            } else {
                self.target_missing.saturating_add(1)
            };
            self.set("scan-done", true);
            self.set("target-in-view", seen);
            self.set(
                "target-not-in-view",
                self.target_missing >= self.cfg.query_after_scans.max(1),
            );
            if !self.cfg.publish_every_scan {
                self.set("heading-requested", true);
                self.set("heading-sent", false);
            }
        }
        if report.sees(&self.cfg.scooter_tag) {
            self.scooter_missing = 0;
            self.set("scooter-in-view", true);
            self.set("scooter-lost", false);
            if self.is("scooter-called-back") {
                self.set("scooter-called-back", false);
                self.last_call = None;
                self.found_left = self.cfg.found_repeats;
                self.broadcast(Broadcast::emergency(
                    &self.cfg.robot,
                    Emergency::ScooterFound,
                ));
            }
        } else {
            self.scooter_missing = self.scooter_missing.saturating_add(1);
            self.set("scooter-in-view", false);
            let call_due = !self.is("scooter-called-back")
                || self
                    .last_call
                    .is_none_or(|t| now.saturating_duration_since(t) >= self.cfg.stress_repeat);
            if active && call_due && self.scooter_missing >= self.cfg.lost_after_scans.max(1) {
                self.set("scooter-lost", true);
            }
        }
        self.decide(now);
    }

    /// Time passed: the target timer and the status period.
    pub fn handle_timeout(&mut self, now: Instant) {
        if let Some(a) = &self.active
            && now >= a.deadline
        {
            self.set("timeout", true);
        }
        if self.next_status.is_some_and(|t| now >= t) {
            if self.found_left > 0 {
                self.found_left -= 1;
                self.broadcast(Broadcast::emergency(
                    &self.cfg.robot,
                    Emergency::ScooterFound,
                ));
            }
            self.status(now);
        }
        self.decide(now);
    }

    // ---- internals ----

    fn is(&self, c: &str) -> bool {
        self.net.condition(c) == Some(true)
    }

    fn set(&mut self, c: &str, v: bool) {
        // Every fed condition was checked to exist in `new`.
        let _ = self.net.set_condition(c, v);
    }

    fn broadcast(&mut self, b: Broadcast) {
        self.out.push_back(SkeeterOutput::Broadcast(b));
    }

    fn status(&mut self, now: Instant) {
        let b = Broadcast::status(
            &self.cfg.robot,
            &self.behaviour,
            &self.san_summary(),
            self.cfg.pose,
        );
        self.broadcast(b);
        self.next_status = self.cfg.status_interval.map(|d| now + d);
    }

    fn set_behaviour(&mut self, name: &str, now: Instant) {
        if self.behaviour != name {
            self.behaviour = name.to_owned();
            self.status(now);
        }
    }

    fn next_target(&mut self, now: Instant) {
        let Some(target) = self.queue.pop_front() else {
            return;
        };
        self.broadcast(Broadcast::mission(
            &self.cfg.robot,
            MissionEvent::Accepted,
            &target,
        ));
        self.active = Some(Active {
            target,
            started: now,
            deadline: now + self.cfg.target_timeout,
        });
        self.target_missing = 0;
        for c in [
            "scan-done",
            "target-in-view",
            "target-not-in-view",
            "heading-requested",
            "heading-sent",
            "scooter-asked",
            "scooter-cannot-see-target",
            "scooter-reached-target",
            "timeout",
            "mission-reported",
        ] {
            self.set(c, false);
        }
        self.set("target-requested", true);
    }

    fn end_target(&mut self, event: MissionEvent, module: &str, now: Instant) {
        let Some(a) = self.active.take() else {
            return;
        };
        self.broadcast(Broadcast::mission(&self.cfg.robot, event, &a.target));
        self.outcomes.push(TargetOutcome {
            target: a.target,
            event,
            module: module.to_owned(),
            started: a.started,
            ended: now,
        });
        for c in [
            "target-requested",
            "scan-done",
            "target-in-view",
            "target-not-in-view",
            "heading-requested",
            "heading-sent",
            "scooter-asked",
            "scooter-cannot-see-target",
            "scooter-reached-target",
            "timeout",
            "scooter-lost",
        ] {
            self.set(c, false);
        }
        self.set("mission-reported", true);
        if self.queue.is_empty() {
            self.set_behaviour(IDLE, now);
        } else {
            self.next_target(now);
        }
    }

    /// Run the network until it falls quiet ([module docs](self)).
    fn decide(&mut self, now: Instant) {
        for _ in 0..MAX_FIRINGS {
            let Some(module) = self.select() else {
                return;
            };
            self.firings = self.firings.saturating_add(1);
            self.set_behaviour(&module, now);
            self.perform(&module, now);
        }
    }

    /// Step until a module fires; the fallback of the module docs; `None` when nothing is
    /// executable.
    fn select(&mut self) -> Option<String> {
        let mut last = None;
        for _ in 0..MAX_STEPS {
            let t = self.net.step();
            if let Some(f) = t.fired {
                return Some(f);
            }
            if !t.modules.iter().any(|m| m.executable) {
                return None;
            }
            last = Some(t);
        }
        let t = last?;
        t.modules
            .iter()
            .filter(|m| m.executable)
            .fold(None::<&crate::san::ModuleTrace>, |best, m| match best {
                Some(b) if b.activation >= m.activation => Some(b),
                _ => Some(m),
            })
            .map(|m| m.name.clone())
    }

    fn perform(&mut self, module: &str, now: Instant) {
        match module {
            "scan-for-target" => {
                self.set("scanner-idle", false);
                self.scanning = true;
                self.out.push_back(SkeeterOutput::StartScan);
            }
            "send-heading" => {
                self.set("heading-requested", false);
                self.set("heading-sent", true);
                if let Some(form) = self.last_form.clone() {
                    self.out.push_back(SkeeterOutput::PublishSes(form));
                }
            }
            "call-back-scooter" => {
                self.set("scooter-lost", false);
                self.set("scooter-called-back", true);
                self.last_call = Some(now);
                self.found_left = 0;
                self.broadcast(Broadcast::emergency(
                    &self.cfg.robot,
                    Emergency::ScooterLost,
                ));
            }
            "ask-scooter" => {
                self.set("scan-done", false);
                self.set("scooter-asked", true);
                self.set("scooter-cannot-see-target", false);
                if let Some(colour) = self.target().map(str::to_owned) {
                    self.broadcast(Broadcast::emergency(
                        &self.cfg.robot,
                        Emergency::TargetQuery { colour },
                    ));
                }
            }
            "report-failed" | "report-timeout" => {
                self.end_target(MissionEvent::Failed, module, now);
            }
            "report-accomplished" => {
                self.end_target(MissionEvent::Accomplished, module, now);
            }
            other => {
                self.net.apply_effects(other);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mission::msg::{COMMANDER, SCOOTER, SKEETER};
    use crate::mission::scan::Detection;
    use crate::mission::vision::Observation;

    fn t(s: u64) -> Instant {
        Instant::from_millis(s * 1000)
    }

    fn brain() -> SkeeterBrain {
        SkeeterBrain::new(SkeeterConfig {
            status_interval: None,
            ..SkeeterConfig::default()
        })
        .unwrap()
    }

    fn drain(b: &mut SkeeterBrain) -> Vec<SkeeterOutput> {
        std::iter::from_fn(|| b.poll_output()).collect()
    }

    /// Outputs other than Status broadcasts.
    fn actions(b: &mut SkeeterBrain) -> Vec<SkeeterOutput> {
        drain(b)
            .into_iter()
            .filter(|o| !matches!(o, SkeeterOutput::Broadcast(Broadcast::Status { .. })))
            .collect()
    }

    fn report(tags: &[&str], at: Instant) -> ScanReport {
        ScanReport {
            started: at,
            finished: at,
            detections: tags
                .iter()
                .map(|t| Detection {
                    observation: Observation {
                        tag: (*t).to_owned(),
                        channel: 1,
                        bearing_rad: 0.0,
                        bearing_in_camera_rad: 0.0,
                        range_m: None,
                        pixels: 100,
                        clipped: false,
                        occluded: false,
                    },
                    time: at,
                })
                .collect(),
            cameras_ok: 7,
            cameras_failed: 0,
            shared: SharedForm {
                source_robot: SKEETER.to_owned(),
                sent_at: at,
                records: Vec::new(),
            },
        }
    }

    fn mission(event: MissionEvent, target: &str) -> SkeeterOutput {
        SkeeterOutput::Broadcast(Broadcast::mission(SKEETER, event, target))
    }

    fn emergency(e: Emergency) -> SkeeterOutput {
        SkeeterOutput::Broadcast(Broadcast::emergency(SKEETER, e))
    }

    fn from_scooter(e: Emergency) -> Broadcast {
        Broadcast::emergency(SCOOTER, e)
    }

    fn started(colour: &str) -> SkeeterBrain {
        let mut b = brain();
        b.handle_broadcast(&Broadcast::new_target(colour), t(0));
        assert_eq!(
            actions(&mut b),
            [
                mission(MissionEvent::Accepted, colour),
                SkeeterOutput::StartScan
            ]
        );
        assert_eq!(b.behaviour(), "scan-for-target");
        assert!(b.is_scanning());
        b
    }

    #[test]
    fn a_cancelled_target_fails_at_once_and_the_next_one_starts() {
        let mut b = started("red");
        b.handle_broadcast(&Broadcast::new_target("blue"), t(1));
        b.handle_broadcast(&Broadcast::new_target("green"), t(1));
        let _ = drain(&mut b);
        // A cancel from anyone but the commander is ignored.
        let cancel = |c: &str| Emergency::TargetCancel { colour: c.into() };
        b.handle_broadcast(&from_scooter(cancel("red")), t(2));
        assert_eq!(b.target(), Some("red"));
        // A queued target is dropped silently.
        b.handle_broadcast(&Broadcast::emergency(COMMANDER, cancel("blue")), t(2));
        assert_eq!(b.target(), Some("red"));
        assert_eq!(b.queued().collect::<Vec<_>>(), ["green"]);
        // The current one fails (and says so); the next one starts.
        b.handle_broadcast(&Broadcast::emergency(COMMANDER, cancel("red")), t(3));
        let out = actions(&mut b);
        assert!(
            out.contains(&mission(MissionEvent::Failed, "red")),
            "{out:?}"
        );
        assert!(
            out.contains(&mission(MissionEvent::Accepted, "green")),
            "{out:?}"
        );
        assert_eq!(b.target(), Some("green"));
        let last = b.outcomes().last().unwrap();
        assert_eq!(
            (last.target.as_str(), last.module.as_str()),
            ("red", CANCELLED)
        );
    }

    #[test]
    fn shipped_network_loads_and_bad_ones_are_refused() {
        let b = brain();
        assert_eq!(b.behaviour(), IDLE);
        assert_eq!(b.target(), None);
        assert!(matches!(
            SkeeterBrain::new(SkeeterConfig {
                network: "name = 1".into(),
                ..SkeeterConfig::default()
            }),
            Err(SkeeterError::Network(_))
        ));
        let without = SKEETER_NETWORK.replace("name = \"timeout\"", "name = \"time-out\"");
        let without = without.replace("pre = [\"timeout\"]", "pre = [\"time-out\"]");
        assert_eq!(
            SkeeterBrain::new(SkeeterConfig {
                network: without,
                ..SkeeterConfig::default()
            })
            .unwrap_err(),
            SkeeterError::MissingCondition("timeout")
        );
    }

    #[test]
    fn every_scan_is_published_by_default() {
        let mut b = started("red");
        b.handle_scan(&report(&["red", "scooter"], t(3)), t(3));
        let out = actions(&mut b);
        assert!(
            matches!(&out[0], SkeeterOutput::PublishSes(f) if f.sent_at == t(3)),
            "{out:?}"
        );
        assert_eq!(out[1], SkeeterOutput::StartScan, "scanning goes on");
        assert_eq!(out.len(), 2, "{out:?}");
        // Also a sweep that sees neither the target nor Scooter.
        b.handle_scan(&report(&[], t(6)), t(6));
        let out = actions(&mut b);
        assert!(matches!(&out[0], SkeeterOutput::PublishSes(f) if f.sent_at == t(6)));
    }

    #[test]
    fn thesis_mode_sends_the_ses_only_with_target_and_scooter_in_view() {
        let mut b = SkeeterBrain::new(SkeeterConfig {
            status_interval: None,
            publish_every_scan: false,
            lost_after_scans: 1,
            ..SkeeterConfig::default()
        })
        .unwrap();
        b.handle_target("red", t(0));
        drain(&mut b);
        b.handle_scan(&report(&["red", "scooter"], t(3)), t(3));
        let out = actions(&mut b);
        assert_eq!(out.len(), 2, "{out:?}");
        assert!(
            out.iter()
                .any(|o| matches!(o, SkeeterOutput::PublishSes(f) if f.sent_at == t(3)))
        );
        assert!(out.contains(&SkeeterOutput::StartScan));
        assert!(b.network().condition("heading-sent").unwrap());
        assert!(!b.network().condition("heading-requested").unwrap());
        // Scooter lost: no sample, the stress call instead.
        b.handle_scan(&report(&["red"], t(6)), t(6));
        let out = actions(&mut b);
        assert!(
            !out.iter()
                .any(|o| matches!(o, SkeeterOutput::PublishSes(_))),
            "{out:?}"
        );
        assert!(out.contains(&emergency(Emergency::ScooterLost)));
        // Target not seen: no sample either.
        b.handle_scan(&report(&["scooter"], t(9)), t(9));
        let out = actions(&mut b);
        assert!(
            !out.iter()
                .any(|o| matches!(o, SkeeterOutput::PublishSes(_))),
            "{out:?}"
        );
    }

    #[test]
    fn heading_request_sends_the_latest_sample() {
        let mut b = started("red");
        b.handle_scan(&report(&["red", "scooter"], t(3)), t(3));
        drain(&mut b);
        b.handle_heading_request(t(4));
        let out = actions(&mut b);
        assert_eq!(out.len(), 1, "{out:?}");
        assert!(matches!(&out[0], SkeeterOutput::PublishSes(f) if f.sent_at == t(3)));
    }

    #[test]
    fn scooter_reached_target_is_accomplished_and_the_next_target_starts() {
        let mut b = brain();
        b.handle_broadcast(&Broadcast::new_target("red"), t(0));
        b.handle_broadcast(&Broadcast::new_target("blue"), t(1));
        assert_eq!(b.queued().collect::<Vec<_>>(), ["blue"]);
        drain(&mut b);
        b.handle_scan(&report(&["red", "scooter"], t(3)), t(3));
        drain(&mut b);
        // Another colour reached: ignored.
        b.handle_broadcast(
            &from_scooter(Emergency::TargetReached {
                colour: "green".into(),
            }),
            t(4),
        );
        assert_eq!(actions(&mut b), []);
        b.handle_broadcast(
            &from_scooter(Emergency::TargetReached {
                colour: "red".into(),
            }),
            t(5),
        );
        let out = actions(&mut b);
        assert_eq!(
            out,
            [
                mission(MissionEvent::Accomplished, "red"),
                mission(MissionEvent::Accepted, "blue"),
            ],
            "the scan under way serves the next target"
        );
        assert_eq!(b.target(), Some("blue"));
        assert_eq!(b.outcomes().len(), 1);
        assert_eq!(b.outcomes()[0].module, "report-accomplished");
        assert_eq!(b.outcomes()[0].event, MissionEvent::Accomplished);
        // The running scan's report feeds blue; when it ends a new one starts.
        b.handle_scan(&report(&["blue", "scooter"], t(6)), t(6));
        let out = actions(&mut b);
        assert!(out.contains(&SkeeterOutput::StartScan), "{out:?}");
        b.handle_broadcast(
            &from_scooter(Emergency::TargetReached {
                colour: "blue".into(),
            }),
            t(20),
        );
        assert_eq!(
            actions(&mut b),
            [mission(MissionEvent::Accomplished, "blue")]
        );
        assert_eq!(b.behaviour(), IDLE);
        assert_eq!(b.target(), None);
        assert!(b.network().condition("mission-reported").unwrap());
    }

    #[test]
    fn target_not_seen_asks_scooter_and_fails_if_scooter_cannot_see_it_either() {
        let mut b = started("red");
        // One sweep without the target is not enough (it may be hidden for a moment).
        b.handle_scan(&report(&["scooter"], t(3)), t(3));
        let out = actions(&mut b);
        assert!(
            !out.iter()
                .any(|o| matches!(o, SkeeterOutput::Broadcast(Broadcast::Emergency { .. }))),
            "{out:?}"
        );
        assert!(!b.network().condition("target-not-in-view").unwrap());
        b.handle_scan(&report(&["scooter"], t(6)), t(6));
        let out = actions(&mut b);
        assert!(
            out.contains(&emergency(Emergency::TargetQuery {
                colour: "red".into()
            })),
            "{out:?}"
        );
        assert!(out.contains(&SkeeterOutput::StartScan));
        // A reply about another colour, or from another robot: ignored.
        b.handle_broadcast(
            &from_scooter(Emergency::TargetReply {
                colour: "blue".into(),
                seen: false,
            }),
            t(4),
        );
        b.handle_broadcast(
            &Broadcast::emergency(
                "intruder",
                Emergency::TargetReply {
                    colour: "red".into(),
                    seen: false,
                },
            ),
            t(4),
        );
        assert_eq!(actions(&mut b), []);
        b.handle_broadcast(
            &from_scooter(Emergency::TargetReply {
                colour: "red".into(),
                seen: false,
            }),
            t(4),
        );
        assert_eq!(actions(&mut b), [mission(MissionEvent::Failed, "red")]);
        assert_eq!(b.outcomes()[0].module, "report-failed");
        assert_eq!(b.behaviour(), IDLE);
    }

    #[test]
    fn scooter_seeing_the_target_keeps_the_mission_going() {
        let mut b = started("red");
        b.handle_scan(&report(&["scooter"], t(3)), t(3));
        b.handle_scan(&report(&["scooter"], t(4)), t(4));
        drain(&mut b);
        b.handle_broadcast(
            &from_scooter(Emergency::TargetReply {
                colour: "red".into(),
                seen: true,
            }),
            t(4),
        );
        assert_eq!(actions(&mut b), []);
        assert!(b.target().is_some());
        // Asked again at the next scan that misses the target, never twice per scan.
        b.handle_scan(&report(&["scooter"], t(6)), t(6));
        let out = actions(&mut b);
        let queries = out
            .iter()
            .filter(|o| matches!(o, SkeeterOutput::Broadcast(Broadcast::Emergency { .. })))
            .count();
        assert_eq!(queries, 1, "{out:?}");
        // Skeeter now sees it: a late "no" does not fail the mission.
        b.handle_scan(&report(&["red", "scooter"], t(9)), t(9));
        drain(&mut b);
        b.handle_broadcast(
            &from_scooter(Emergency::TargetReply {
                colour: "red".into(),
                seen: false,
            }),
            t(10),
        );
        assert!(
            !actions(&mut b).contains(&mission(MissionEvent::Failed, "red")),
            "Skeeter sees it itself"
        );
        assert_eq!(b.target(), Some("red"));
    }

    #[test]
    fn an_unsolicited_reply_is_ignored() {
        let mut b = started("red");
        b.handle_broadcast(
            &from_scooter(Emergency::TargetReply {
                colour: "red".into(),
                seen: false,
            }),
            t(1),
        );
        assert_eq!(actions(&mut b), []);
        assert!(!b.network().condition("scooter-cannot-see-target").unwrap());
    }

    #[test]
    fn timeout_fails_the_target() {
        let mut b = started("red");
        assert_eq!(b.poll_timeout(), Some(t(180)));
        b.handle_scan(&report(&["red", "scooter"], t(3)), t(3));
        drain(&mut b);
        b.handle_timeout(t(179));
        assert_eq!(actions(&mut b), []);
        b.handle_timeout(t(180));
        assert_eq!(actions(&mut b), [mission(MissionEvent::Failed, "red")]);
        assert_eq!(b.outcomes()[0].module, "report-timeout");
        assert_eq!(b.poll_timeout(), None);
    }

    #[test]
    fn timeout_is_configurable_and_per_target() {
        let mut b = SkeeterBrain::new(SkeeterConfig {
            target_timeout: Duration::from_secs(30),
            status_interval: None,
            ..SkeeterConfig::default()
        })
        .unwrap();
        b.handle_target("red", t(0));
        b.handle_target("blue", t(0));
        b.handle_timeout(t(30));
        let out = actions(&mut b);
        assert_eq!(
            out,
            [
                mission(MissionEvent::Accepted, "red"),
                SkeeterOutput::StartScan,
                mission(MissionEvent::Failed, "red"),
                mission(MissionEvent::Accepted, "blue"),
            ]
        );
        assert_eq!(b.poll_timeout(), Some(t(60)), "blue's own timer");
    }

    #[test]
    fn scooter_lost_stress_call_repeated_then_found() {
        let mut b = started("red");
        // One sweep without Scooter: not yet.
        b.handle_scan(&report(&["red"], t(3)), t(3));
        assert!(!actions(&mut b).contains(&emergency(Emergency::ScooterLost)));
        b.handle_scan(&report(&["red"], t(6)), t(6));
        let out = actions(&mut b);
        assert!(out.contains(&emergency(Emergency::ScooterLost)), "{out:?}");
        assert_eq!(out.len(), 3, "sample, stress call, next scan: {out:?}");
        assert!(b.network().condition("scooter-called-back").unwrap());
        // Still lost 5 s later: no second call yet (repeat after 10 s).
        b.handle_scan(&report(&["red"], t(11)), t(11));
        assert!(!actions(&mut b).contains(&emergency(Emergency::ScooterLost)));
        // 10 s after the call: called again.
        b.handle_scan(&report(&["red"], t(16)), t(16));
        assert!(actions(&mut b).contains(&emergency(Emergency::ScooterLost)));
        // Seen again: scooter-found.
        b.handle_scan(&report(&["red", "scooter"], t(19)), t(19));
        let out = actions(&mut b);
        assert!(out.contains(&emergency(Emergency::ScooterFound)), "{out:?}");
        assert!(!b.network().condition("scooter-called-back").unwrap());
        // Seen once more: no second "found".
        b.handle_scan(&report(&["red", "scooter"], t(22)), t(22));
        assert!(!actions(&mut b).contains(&emergency(Emergency::ScooterFound)));
        // Missed once: the count starts again.
        b.handle_scan(&report(&["red"], t(25)), t(25));
        assert!(!actions(&mut b).contains(&emergency(Emergency::ScooterLost)));
    }

    #[test]
    fn no_stress_call_without_a_target() {
        let mut b = brain();
        for s in 0..5 {
            b.handle_scan(&report(&[], t(s)), t(s));
        }
        let out = actions(&mut b);
        assert!(
            out.iter()
                .all(|o| matches!(o, SkeeterOutput::PublishSes(_))),
            "{out:?}"
        );
        assert_eq!(b.behaviour(), IDLE);
    }

    #[test]
    fn targets_are_processed_one_at_a_time_and_duplicates_ignored() {
        let mut b = brain();
        b.handle_target("red", t(0));
        b.handle_target("blue", t(0));
        b.handle_target("blue", t(0));
        b.handle_target("green", t(0));
        assert_eq!(b.queued().collect::<Vec<_>>(), ["blue", "green"]);
        drain(&mut b);
        // The commander resends the current target: answered again.
        b.handle_target("red", t(1));
        assert_eq!(actions(&mut b), [mission(MissionEvent::Accepted, "red")]);
        // Targets from someone other than the commander, and other events: ignored.
        b.handle_broadcast(
            &Broadcast::mission(SCOOTER, MissionEvent::Accepted, "yellow"),
            t(1),
        );
        b.handle_broadcast(
            &Broadcast::mission(COMMANDER, MissionEvent::Failed, "yellow"),
            t(1),
        );
        assert_eq!(b.queued().count(), 2);
        let mut small = SkeeterBrain::new(SkeeterConfig {
            max_queue: 1,
            status_interval: None,
            ..SkeeterConfig::default()
        })
        .unwrap();
        small.handle_target("a", t(0));
        small.handle_target("b", t(0));
        small.handle_target("c", t(0));
        assert_eq!(small.queued().collect::<Vec<_>>(), ["b"]);
    }

    #[test]
    fn status_reports_the_behaviour_periodically_and_on_change() {
        let mut b = SkeeterBrain::new(SkeeterConfig::default()).unwrap();
        b.start(t(0));
        let out = drain(&mut b);
        assert!(matches!(
            &out[..],
            [SkeeterOutput::Broadcast(Broadcast::Status { behaviour, .. })] if behaviour == IDLE
        ));
        assert_eq!(b.poll_timeout(), Some(t(1)));
        b.handle_timeout(t(1));
        assert_eq!(drain(&mut b).len(), 1);
        b.handle_target("red", Instant::from_millis(1500));
        let out = drain(&mut b);
        let statuses: Vec<(&str, &str)> = out
            .iter()
            .filter_map(|o| match o {
                SkeeterOutput::Broadcast(Broadcast::Status { behaviour, san, .. }) => {
                    Some((behaviour.as_str(), san.as_str()))
                }
                _ => None,
            })
            .collect();
        assert_eq!(statuses.len(), 1, "{out:?}");
        assert_eq!(statuses[0].0, "scan-for-target");
        assert!(statuses[0].1.starts_with("target=red"), "{}", statuses[0].1);
        assert!(statuses[0].1.contains("target-requested"));
        assert_eq!(b.poll_timeout(), Some(Instant::from_millis(2500)));
        assert_eq!(b.behaviour(), "scan-for-target");
    }

    #[test]
    fn a_stalled_network_falls_back_to_the_strongest_executable_module() {
        // A network whose threshold never lets anything fire within 64 steps.
        let net = SKEETER_NETWORK.replace("theta = 45.0", "theta = 1.0e12");
        assert_ne!(net, SKEETER_NETWORK);
        let mut b = SkeeterBrain::new(SkeeterConfig {
            network: net,
            status_interval: None,
            ..SkeeterConfig::default()
        })
        .unwrap();
        b.handle_target("red", t(0));
        let out = actions(&mut b);
        assert!(out.contains(&SkeeterOutput::StartScan), "{out:?}");
    }

    #[test]
    fn scooter_found_is_repeated_on_the_next_status_periods() {
        let mut b = SkeeterBrain::new(SkeeterConfig::default()).unwrap();
        b.start(t(0));
        b.handle_broadcast(&Broadcast::new_target("red"), t(0));
        b.handle_scan(&report(&["red"], t(3)), t(3));
        b.handle_scan(&report(&["red"], t(6)), t(6));
        assert!(drain(&mut b).contains(&emergency(Emergency::ScooterLost)));
        b.handle_scan(&report(&["red", "scooter"], t(9)), t(9));
        assert!(drain(&mut b).contains(&emergency(Emergency::ScooterFound)));
        let founds = |b: &mut SkeeterBrain| {
            drain(b)
                .iter()
                .filter(|o| **o == emergency(Emergency::ScooterFound))
                .count()
        };
        // Status every 1 s: found again with the next two, then no more.
        let mut seen = Vec::new();
        for s in 10..16 {
            b.handle_timeout(t(s));
            seen.push(founds(&mut b));
        }
        assert_eq!(seen, [1, 1, 0, 0, 0, 0]);
        // A new call-back cancels pending repeats.
        b.handle_scan(&report(&["red", "scooter"], t(16)), t(16));
        b.found_left = 2;
        b.handle_scan(&report(&["red"], t(17)), t(17));
        b.handle_scan(&report(&["red"], t(18)), t(18));
        assert!(drain(&mut b).contains(&emergency(Emergency::ScooterLost)));
        b.handle_timeout(t(19));
        assert_eq!(founds(&mut b), 0);
    }

    #[test]
    fn a_poll_for_a_just_finished_target_is_answered_with_its_outcome() {
        let mut b = started("red");
        b.handle_broadcast(
            &from_scooter(Emergency::TargetReached {
                colour: "red".into(),
            }),
            t(5),
        );
        assert!(actions(&mut b).contains(&mission(MissionEvent::Accomplished, "red")));
        assert_eq!(b.outcomes().len(), 1);
        // The outcome was lost; the commander polls: the outcome again, no new run.
        b.handle_broadcast(&Broadcast::new_target("red"), t(10));
        assert_eq!(
            actions(&mut b),
            [mission(MissionEvent::Accomplished, "red")]
        );
        assert_eq!(b.target(), None);
        assert_eq!(b.outcomes().len(), 1);
        // Long after (outcome_memory 20 s): a new request for red runs again.
        b.handle_broadcast(&Broadcast::new_target("red"), t(40));
        let out = actions(&mut b);
        assert_eq!(out[0], mission(MissionEvent::Accepted, "red"));
        assert_eq!(b.target(), Some("red"));
        // A failed target is answered with Failed.
        let mut b = started("blue");
        b.handle_timeout(t(200));
        assert!(actions(&mut b).contains(&mission(MissionEvent::Failed, "blue")));
        b.handle_broadcast(&Broadcast::new_target("blue"), t(205));
        assert_eq!(actions(&mut b), [mission(MissionEvent::Failed, "blue")]);
    }

    #[test]
    fn the_san_summary_fits_a_wire_string() {
        let mut b = brain();
        let long = "ü".repeat(200);
        b.handle_target(&long, t(0));
        let sum = b.san_summary();
        assert!(
            sum.len() <= crate::mission::msg::MAX_WIRE_STR,
            "{}",
            sum.len()
        );
        assert!(sum.starts_with("target=ü"));
    }
}

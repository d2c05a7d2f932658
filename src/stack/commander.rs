//! The commander's runtime: joins the broadcast group and drives
//! [`ima_agents::mission::commander::Commander`] (targets sent one at a time as
//! `Mission { commander, Accepted, colour }`, resent until Skeeter accepts, progress from
//! Skeeter's mission events), reporting every broadcast it hears.

use std::time::Duration;

use anyhow::{Context, Result};
use ima_agents::mission::commander::{
    Commander, CommanderConfig, LifeChange, Liveness, TargetState as CoreState,
};
use ima_agents::mission::msg::{Broadcast, COMMANDER, FLEET_COPIES};
use ima_agents::peer::net::BroadcastChannel;
use ima_agents::peer::wire::GroupKey;
use serde_json::json;

use super::net::{Bus, net_config};
use super::{Events, MissionClock};
use crate::config::RobotConfig;

/// A target's final state.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum TargetState {
    /// Skeeter reported it accomplished.
    Done,
    /// Skeeter reported it failed, or it timed out at the commander.
    Failed,
}

/// One target's outcome.
#[derive(Debug, Clone, serde::Serialize)]
pub struct TargetOutcome {
    /// Colour.
    pub target: String,
    /// Final state.
    pub state: TargetState,
    /// Mission second it was sent.
    pub sent_s: f64,
    /// Mission second Skeeter accepted it (if it did).
    pub accepted_s: Option<f64>,
    /// Mission second it ended.
    pub ended_s: f64,
    /// Why it failed at the commander (given up, cancelled, interrupted), if it did.
    pub reason: Option<String>,
}

/// What the operator asks of a running commander (typed lines on its stdin, Ctrl-C).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Operator {
    /// Withdraw a target ([`Commander::cancel`]).
    Cancel(String),
    /// Send a fleet stop (reason).
    Stop(String),
    /// Send a fleet resume.
    Resume,
    /// Append a target to the series ([`Commander::add`]).
    Add(String),
    /// Move the waiting target at position `from` to position `to`
    /// ([`Commander::move_target`]).
    Move {
        /// Position now.
        from: usize,
        /// Position wanted.
        to: usize,
    },
    /// End the commander, after a fleet stop if `stop`.
    Quit {
        /// Send a fleet stop first.
        stop: bool,
    },
}

/// Options of [`run_with`]: liveness and the operator's requests.
#[derive(Debug, Default)]
pub struct Control {
    /// Report a robot lost after this much (mission) silence; `None`: no liveness reports.
    pub lost_after: Option<Duration>,
    /// The operator's requests.
    pub ops: Option<tokio::sync::mpsc::UnboundedReceiver<Operator>>,
    /// Keep running when every target is final (more may be added), until
    /// [`Operator::Quit`] (the web console).
    pub keep_running: bool,
}

/// How a [`run_with`] ended.
#[derive(Debug, Clone)]
pub struct Finished {
    /// Every target's outcome (targets still open at an interruption count as failed).
    pub outcomes: Vec<TargetOutcome>,
    /// `Some(stopped)` when the operator ended it ([`Operator::Quit`]); `stopped` tells
    /// whether a fleet stop went out.
    pub interrupted: Option<bool>,
}

fn life_event(events: &Events, clock: &MissionClock, me: &str, c: &LifeChange) {
    events.emit(
        clock,
        me,
        "robot",
        json!({"robot": c.robot, "state": c.life.as_str(), "silent_s": c.silent.as_secs_f64()}),
    );
}

/// Run the commander ([`Commander`], the Commander Interface Agent's logic) over `targets`;
/// events go to `events` (kinds `target` on every state change, and `broadcast`; `queue`,
/// the whole series, when a console listens).
///
/// Before the first target it waits (at most `wait.1`, real time) until every robot of
/// `wait.0` has been heard on the broadcast channel, so that no robot misses it.
///
/// With `control`: liveness reports (kind `robot`: `{robot, state: alive|lost, silent_s}`) and
/// the operator's requests (kinds `fleet` for a stop or resume sent, `operator` for a
/// request that could not be carried out). Frames under another group key are reported on
/// stderr (rate-limited).
pub async fn run_with(
    cfg: &RobotConfig,
    key: GroupKey,
    targets: &[String],
    wait: (&[String], Duration),
    events: Events,
    control: Control,
) -> Result<Finished> {
    let clock = MissionClock::new(cfg.agent.time_scale);
    let me = cfg.robot.clone();
    let bus = Bus::bind(cfg, key)?;
    let Control {
        lost_after,
        mut ops,
        keep_running,
    } = control;
    let mut live = lost_after.map(|d| Liveness::new(d, &[me.as_str(), COMMANDER]));
    let mut missing: Vec<&String> = wait.0.iter().collect();
    if let Some(l) = &mut live {
        for r in &missing {
            l.expect(r, clock.now());
        }
    }
    let mut cmd = Commander::new(
        targets,
        CommanderConfig {
            robot: me.clone(),
            resend: Duration::from_secs(3),
            give_up_after: Some(Duration::from_secs_f64(cfg.agent.target_timeout_s)),
            ..CommanderConfig::default()
        },
    );
    let mut shown: Vec<(CoreState, bool)> = cmd
        .targets()
        .iter()
        .map(|t| (t.state, t.cancelled))
        .collect();
    // web console (issue 17): the whole series as a `queue` event on every change.
    let mut queue_changed = true;
    let mut waiting = !missing.is_empty();
    if waiting {
        events.emit(&clock, &me, "waiting", json!({"for": missing}));
    } else {
        cmd.start(clock.now());
    }
    let wait_deadline = tokio::time::Instant::now() + wait.1;
    let mut interrupted = None;
    let mut check = tokio::time::interval(Duration::from_secs(1));
    check.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    loop {
        while let Some(b) = cmd.poll_broadcast() {
            bus.send(&b).await;
        }
        if shown.len() != cmd.targets().len() {
            queue_changed = true;
            shown.resize(cmd.targets().len(), (CoreState::Waiting, false));
        }
        for (t, old) in cmd.targets().iter().zip(shown.iter_mut()) {
            if (t.state, t.cancelled) != *old {
                queue_changed = true;
                *old = (t.state, t.cancelled);
                let time_s = t.duration().map(|d| d.as_secs_f64());
                let mut d = json!({"target": t.colour, "state": t.state.as_str()});
                if t.state.is_final() {
                    d["time_s"] = json!(time_s);
                    d["given_up"] = json!(t.given_up);
                    d["cancelled"] = json!(t.cancelled);
                }
                events.emit(&clock, &me, "target", d);
            }
        }
        if std::mem::take(&mut queue_changed) && events.wants_detail() {
            events.emit(&clock, &me, "queue", queue_json(&cmd));
        }
        if interrupted.is_some() || (!waiting && !keep_running && cmd.is_finished()) {
            break;
        }
        let to_real = |t: ima_hal::Instant| {
            tokio::time::Instant::now() + clock.real(t.saturating_duration_since(clock.now()))
        };
        let wake = [
            cmd.poll_timeout().map(to_real),
            live.as_ref().and_then(Liveness::poll_timeout).map(to_real),
            waiting.then_some(wait_deadline),
        ]
        .into_iter()
        .flatten()
        .min();
        tokio::select! {
            r = bus.recv() => {
                let b = r?;
                let now = clock.now();
                events.emit(&clock, &me, "broadcast", broadcast_json(&b));
                if let Some(c) = live.as_mut().and_then(|l| l.heard(b.robot(), now)) {
                    life_event(&events, &clock, &me, &c);
                }
                if waiting {
                    missing.retain(|m| m.as_str() != b.robot());
                    if missing.is_empty() {
                        waiting = false;
                        cmd.start(now);
                    }
                }
                cmd.handle_broadcast(&b, now);
            }
            op = async {
                match ops.as_mut() {
                    Some(rx) => rx.recv().await,
                    None => std::future::pending().await,
                }
            } => {
                let now = clock.now();
                match op {
                    None => ops = None,
                    Some(Operator::Cancel(colour)) => {
                        if !cmd.cancel(&colour, now) {
                            events.emit(&clock, &me, "operator", json!({"error": format!("no open target {colour:?} to cancel")}));
                        }
                    }
                    Some(Operator::Stop(reason)) => {
                        cmd.fleet_stop(&reason);
                        events.emit(&clock, &me, "fleet", json!({"command": "stop", "reason": reason}));
                    }
                    Some(Operator::Add(colour)) => {
                        // Before the robots are heard it only queues (`start` sends it).
                        cmd.add(&colour, now);
                    }
                    Some(Operator::Move { from, to }) => {
                        if let Err(e) = cmd.move_target(from, to) {
                            events.emit(&clock, &me, "operator", json!({"error": format!("cannot move the target: {e}")}));
                        }
                        // `shown` follows the series' order from now on.
                        shown = cmd.targets().iter().map(|t| (t.state, t.cancelled)).collect();
                        queue_changed = true;
                    }
                    Some(Operator::Resume) => {
                        cmd.fleet_resume();
                        events.emit(&clock, &me, "fleet", json!({"command": "resume"}));
                    }
                    Some(Operator::Quit { stop }) => {
                        if stop {
                            cmd.fleet_stop("the commander was interrupted");
                            events.emit(&clock, &me, "fleet", json!({"command": "stop", "reason": "interrupted"}));
                        }
                        interrupted = Some(stop);
                    }
                }
            }
            () = async {
                match wake {
                    Some(w) => tokio::time::sleep_until(w).await,
                    None => std::future::pending().await,
                }
            } => {
                let now = clock.now();
                if waiting && tokio::time::Instant::now() >= wait_deadline {
                    events.emit(&clock, &me, "waiting", json!({"gave_up_on": missing}));
                    waiting = false;
                    cmd.start(now);
                }
                cmd.handle_timeout(now);
                for c in live.as_mut().map(|l| l.handle_timeout(now)).unwrap_or_default() {
                    life_event(&events, &clock, &me, &c);
                }
            }
            _ = check.tick() => {
                bus.warn_auth();
                // web console (issue 17): the commander's channel counters.
                if events.wants_detail() {
                    events.emit(&clock, &me, "peer-status", json!({"broadcast": crate::web::feed::bus_json(&bus.stats())}));
                }
            }
        }
    }
    let secs = |i: Option<ima_hal::Instant>| i.map(ima_hal::Instant::as_secs_f64);
    let outcomes = cmd
        .targets()
        .iter()
        .map(|t| TargetOutcome {
            target: t.colour.clone(),
            state: if t.state == CoreState::Done {
                TargetState::Done
            } else {
                TargetState::Failed
            },
            sent_s: secs(t.sent_at).unwrap_or(0.0),
            accepted_s: secs(t.accepted_at),
            ended_s: secs(t.finished_at).unwrap_or(0.0),
            reason: if t.cancelled {
                Some("cancelled by the operator".to_owned())
            } else if t.given_up {
                Some("no word from Skeeter: given up".to_owned())
            } else if !t.state.is_final() {
                Some("the commander was interrupted".to_owned())
            } else {
                None
            },
        })
        .collect();
    Ok(Finished {
        outcomes,
        interrupted,
    })
}

/// Sends one fleet command or cancel (`b`) [`FLEET_COPIES`] times, 50 ms apart, from a
/// short-lived commander process (`ima commander stop|resume|cancel`): its socket binds any
/// free port (not the running commander's), and with unicast peers the configured
/// commander address is a destination too, so that a running commander hears a cancel.
/// Returns the destinations reached by the last copy.
pub async fn send_once(cfg: &RobotConfig, key: GroupKey, b: &Broadcast) -> Result<usize> {
    let mut n = net_config(cfg)?;
    if let Some(port) = n.broadcast.bind_port
        && n.broadcast.mode != ima_agents::peer::net::BroadcastMode::Multicast
    {
        let own = format!("{}:{port}", n.broadcast.bind);
        if port != 0 && !n.broadcast.peers.contains(&own) {
            n.broadcast.peers.push(own);
        }
    }
    n.broadcast.bind_port = Some(0);
    let chan = BroadcastChannel::bind(&n, &cfg.robot, key)
        .map_err(|e| anyhow::anyhow!("{e}"))
        .context("binding the broadcast channel")?;
    anyhow::ensure!(
        !chan.destinations().is_empty(),
        "nowhere to send: no broadcast_group and no broadcast_peers in the configuration"
    );
    let mut reached = 0;
    for i in 0..FLEET_COPIES {
        if i > 0 {
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        let r = match b {
            Broadcast::Emergency { emergency, .. } => {
                chan.send_emergency(emergency.kind(), &emergency.text())
                    .await
            }
            Broadcast::Mission { event, target, .. } => chan.send_mission(*event, target).await,
            Broadcast::Status {
                behaviour,
                san,
                pose,
                ..
            } => chan.send_status(behaviour, san, *pose).await,
        };
        reached = r.map_err(|e| anyhow::anyhow!("{e}"))?;
    }
    Ok(reached)
}

/// The whole series (kind `queue`): per target its position, colour, state, times (mission
/// seconds) and why it failed.
pub fn queue_json(cmd: &Commander) -> serde_json::Value {
    let secs = |i: Option<ima_hal::Instant>| i.map(ima_hal::Instant::as_secs_f64);
    let list: Vec<serde_json::Value> = cmd
        .targets()
        .iter()
        .enumerate()
        .map(|(i, t)| {
            json!({"index": i, "target": t.colour, "state": t.state.as_str(),
                "sent_s": secs(t.sent_at), "accepted_s": secs(t.accepted_at),
                "ended_s": secs(t.finished_at),
                "time_s": t.duration().map(|d| d.as_secs_f64()),
                "cancelled": t.cancelled, "given_up": t.given_up, "sends": t.sends})
        })
        .collect();
    json!({"targets": list})
}

/// A broadcast as JSON for the event stream.
pub fn broadcast_json(b: &Broadcast) -> serde_json::Value {
    match b {
        Broadcast::Status {
            robot,
            behaviour,
            san,
            pose,
        } => json!({"type": "status", "robot": robot, "behaviour": behaviour, "san": san,
            "pose": pose.map(|p| json!({"x_m": f64::from(p.x_mm) / 1000.0, "y_m": f64::from(p.y_mm) / 1000.0, "theta_rad": f64::from(p.theta_mrad) / 1000.0}))}),
        Broadcast::Emergency { robot, emergency } => {
            json!({"type": "emergency", "robot": robot, "kind": emergency.kind(), "text": emergency.text()})
        }
        Broadcast::Mission {
            robot,
            event,
            target,
        } => {
            json!({"type": "mission", "robot": robot, "event": event.as_str(), "target": target})
        }
    }
}

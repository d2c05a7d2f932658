//! The commander's runtime: joins the broadcast group and drives
//! [`ima_agents::mission::commander::Commander`] (targets sent one at a time as
//! `Mission { commander, Accepted, colour }`, resent until Skeeter accepts, progress from
//! Skeeter's mission events), reporting every broadcast it hears.

use std::time::Duration;

use anyhow::Result;
use ima_agents::mission::commander::{Commander, CommanderConfig, TargetState as CoreState};
use ima_agents::mission::msg::Broadcast;
use ima_agents::peer::wire::GroupKey;
use serde_json::json;

use super::net::Bus;
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
    /// Why it failed (timeout at the commander), if it did.
    pub reason: Option<String>,
}

/// Run the commander ([`Commander`], the Commander Interface Agent's logic) over `targets`;
/// events go to `events` (kinds `target` on every state change, and `broadcast`).
///
/// Before the first target it waits (at most `wait.1`, real time) until every robot of
/// `wait.0` has been heard on the broadcast channel, so that no robot misses it.
pub async fn run(
    cfg: &RobotConfig,
    key: GroupKey,
    targets: &[String],
    wait: (&[String], Duration),
    events: Events,
) -> Result<Vec<TargetOutcome>> {
    let clock = MissionClock::new(cfg.agent.time_scale);
    let me = cfg.robot.clone();
    let bus = Bus::bind(cfg, key)?;
    let mut missing: Vec<&String> = wait.0.iter().collect();
    if !missing.is_empty() {
        events.emit(&clock, &me, "waiting", json!({"for": missing}));
        let deadline = tokio::time::Instant::now() + wait.1;
        while !missing.is_empty() {
            tokio::select! {
                r = bus.recv() => {
                    let b = r?;
                    events.emit(&clock, &me, "broadcast", broadcast_json(&b));
                    missing.retain(|m| m.as_str() != b.robot());
                }
                () = tokio::time::sleep_until(deadline) => {
                    events.emit(&clock, &me, "waiting", json!({"gave_up_on": missing}));
                    break;
                }
            }
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
    let mut shown: Vec<CoreState> = cmd.targets().iter().map(|t| t.state).collect();
    cmd.start(clock.now());
    loop {
        while let Some(b) = cmd.poll_broadcast() {
            bus.send(&b).await;
        }
        for (t, old) in cmd.targets().iter().zip(shown.iter_mut()) {
            if t.state != *old {
                *old = t.state;
                let time_s = t.duration().map(|d| d.as_secs_f64());
                let mut d = json!({"target": t.colour, "state": t.state.as_str()});
                if t.state.is_final() {
                    d["time_s"] = json!(time_s);
                    d["given_up"] = json!(t.given_up);
                }
                events.emit(&clock, &me, "target", d);
            }
        }
        if cmd.is_finished() {
            break;
        }
        let wake = cmd.poll_timeout().map(|t| {
            tokio::time::Instant::now() + clock.real(t.saturating_duration_since(clock.now()))
        });
        tokio::select! {
            r = bus.recv() => {
                let b = r?;
                events.emit(&clock, &me, "broadcast", broadcast_json(&b));
                cmd.handle_broadcast(&b, clock.now());
            }
            () = async {
                match wake {
                    Some(w) => tokio::time::sleep_until(w).await,
                    None => std::future::pending().await,
                }
            } => cmd.handle_timeout(clock.now()),
        }
    }
    let secs = |i: Option<ima_hal::Instant>| i.map(ima_hal::Instant::as_secs_f64);
    Ok(cmd
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
            reason: t
                .given_up
                .then(|| "no word from Skeeter: given up".to_owned()),
        })
        .collect())
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
            json!({"type": "mission", "robot": robot, "event": format!("{event:?}").to_lowercase(), "target": target})
        }
    }
}

//! The commander: joins the broadcast group, sends the targets one at a time as
//! `Mission { commander, Accepted, colour }`, follows Skeeter's answers (Accepted, then
//! Accomplished or Failed) and reports every broadcast it hears.

use std::time::Duration;

use anyhow::Result;
use ima_agents::mission::msg::{Broadcast, MissionEvent, SKEETER};
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

/// Run the commander over `targets`; events go to `events` (kinds `target` and
/// `broadcast`).
pub async fn run(
    cfg: &RobotConfig,
    key: GroupKey,
    targets: &[String],
    events: Events,
) -> Result<Vec<TargetOutcome>> {
    let clock = MissionClock::new(cfg.agent.time_scale);
    let me = cfg.robot.clone();
    let bus = Bus::bind(cfg, key)?;
    let timeout = Duration::from_secs_f64(cfg.agent.target_timeout_s);
    let mut outcomes = Vec::new();
    for target in targets {
        let sent_s = clock.secs();
        let request = Broadcast::new_target(target);
        events.emit(
            &clock,
            &me,
            "target",
            json!({"target": target, "state": "sent"}),
        );
        bus.send(&request).await;
        let deadline = tokio::time::Instant::now() + clock.real(timeout);
        let resend = clock
            .real(Duration::from_secs(3))
            .max(Duration::from_millis(300));
        let mut next_resend = tokio::time::Instant::now() + resend;
        let mut accepted_s = None;
        let outcome = loop {
            let wait = next_resend.min(deadline);
            let b = tokio::select! {
                r = bus.recv() => r?,
                () = tokio::time::sleep_until(wait) => {
                    let now = tokio::time::Instant::now();
                    if now >= deadline {
                        break TargetOutcome {
                            target: target.clone(),
                            state: TargetState::Failed,
                            sent_s,
                            accepted_s,
                            ended_s: clock.secs(),
                            reason: Some("timed out at the commander".into()),
                        };
                    }
                    if accepted_s.is_none() {
                        // Skeeter has not answered yet: say it again.
                        bus.send(&request).await;
                    }
                    next_resend = now + resend;
                    continue;
                }
            };
            events.emit(&clock, &me, "broadcast", broadcast_json(&b));
            if let Broadcast::Mission {
                robot,
                event,
                target: t,
            } = &b
                && robot == SKEETER
                && t == target
            {
                match event {
                    MissionEvent::Accepted => {
                        if accepted_s.is_none() {
                            accepted_s = Some(clock.secs());
                            events.emit(
                                &clock,
                                &me,
                                "target",
                                json!({"target": target, "state": "processing"}),
                            );
                        }
                    }
                    MissionEvent::Accomplished | MissionEvent::Failed => {
                        break TargetOutcome {
                            target: target.clone(),
                            state: if *event == MissionEvent::Accomplished {
                                TargetState::Done
                            } else {
                                TargetState::Failed
                            },
                            sent_s,
                            accepted_s,
                            ended_s: clock.secs(),
                            reason: None,
                        };
                    }
                }
            }
        };
        events.emit(
            &clock,
            &me,
            "target",
            json!({"target": target, "state": outcome.state, "time_s": outcome.ended_s - outcome.sent_s, "reason": outcome.reason}),
        );
        outcomes.push(outcome);
    }
    Ok(outcomes)
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

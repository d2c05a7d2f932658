//! The detail the robot stacks report for the web console (event kinds `san`, `map`,
//! `ses-form`, `peer-status`), as JSON built from the agents' own types. The stacks call these
//! only when [`crate::stack::Events::wants_detail`] says a console listens; they depend on
//! `ima_agents` types alone, so they can move with the runtime.

use ima_agents::mission::scooter::{Plan, ScooterBrain};
use ima_agents::peer::manager::ClientStatus;
use ima_agents::peer::net::{BroadcastStats, ManagerNetStats};
use ima_agents::peer::wire::RejectCounts;
use ima_agents::san::Network;
use ima_agents::ses::shared::SharedForm;
use serde_json::{Value, json};

/// At most this many laser obstacles go into one `map` event.
pub const MAX_OBSTACLES: usize = 120;

/// A SAN's state: each module's activation and executable flag, the threshold θ, each
/// condition's truth, and the selected behaviour (kind `san`).
pub fn san_json(net: &Network, selected: &str) -> Value {
    let exec = net.executable_flags();
    let modules: Vec<Value> = net
        .module_names()
        .zip(net.activations())
        .zip(exec)
        .map(|((name, a), e)| json!({"name": name, "activation": a, "executable": e}))
        .collect();
    let conditions: Vec<Value> = net
        .condition_names()
        .map(|c| json!({"name": c, "value": net.condition(c) == Some(true)}))
        .collect();
    json!({"network": net.name(), "modules": modules, "threshold": net.threshold(),
        "conditions": conditions, "selected": selected})
}

/// Scooter's belief for the map (kind `map`): DR position, heading, desired heading, plan
/// and the laser obstacles it remembers (DR frame, metres).
pub fn scooter_map_json(brain: &ScooterBrain) -> Value {
    let dr = brain.dr_position();
    let plan = match brain.plan() {
        Some(Plan::Heading(h)) => json!({"heading_rad": h}),
        Some(Plan::Point(p)) => json!({"point": [p.x, p.y]}),
        None => Value::Null,
    };
    let step = brain.obstacles_dr().len().div_ceil(MAX_OBSTACLES).max(1);
    let obstacles: Vec<[f64; 2]> = brain
        .obstacles_dr()
        .iter()
        .step_by(step)
        .filter(|p| p.x.is_finite() && p.y.is_finite())
        .map(|p| [p.x, p.y])
        .collect();
    json!({"dr": [dr.x, dr.y], "heading_rad": brain.heading(),
        "desired_rad": brain.desired_heading(), "plan": plan, "obstacles": obstacles,
        "target": brain.target()})
}

/// A shared form's records (kind `ses-form`): object, bearing in the sender's frame, range
/// where known, confidence.
pub fn ses_json(form: &SharedForm) -> Value {
    let records: Vec<Value> = form
        .records
        .iter()
        .map(|r| {
            json!({"object": r.object, "bearing_rad": r.bearing.azimuth_rad,
                "range_m": r.range_m, "confidence": r.confidence})
        })
        .collect();
    json!({"source": form.source_robot, "records": records})
}

/// Wire rejections by class.
pub fn rejects_json(r: &RejectCounts) -> Value {
    json!({"truncated": r.truncated, "bad_magic": r.bad_magic, "bad_version": r.bad_version,
        "oversize": r.oversize, "bad_mac": r.bad_mac, "replay": r.replay,
        "malformed": r.malformed})
}

/// A broadcast channel's counters.
pub fn bus_json(s: &BroadcastStats) -> Value {
    json!({"accepted": s.receiver.accepted, "duplicate": s.receiver.duplicate,
        "stale": s.receiver.stale, "sent": s.sent, "send_errors": s.send_errors,
        "rejected": rejects_json(&s.wire)})
}

/// A Peer Agent manager's status (kind `peer-status`): sources, clients and their grants,
/// sessions and counters.
pub fn manager_json(s: &ManagerNetStats, clients: &[ClientStatus]) -> Value {
    let sources: Vec<Value> = s
        .sources
        .iter()
        .map(|x| json!({"name": x.name, "kind": x.kind, "rate_mhz": x.rate_mhz}))
        .collect();
    let clients: Vec<Value> = clients
        .iter()
        .map(|c| {
            json!({"client": c.client, "robot": c.robot, "requesting": c.requesting,
                "granted": c.granted})
        })
        .collect();
    json!({"sources": sources, "clients": clients, "sessions": s.sessions,
        "data_sessions": s.data_sessions, "task_priority": s.task_priority,
        "lost": s.core.lost, "closed_bad": s.core.closed_bad,
        "rejected": rejects_json(&s.core.rejects), "data_rejected": rejects_json(&s.data_rejects),
        "data_bad_tickets": s.data_bad_tickets, "slow_closed": s.slow_closed,
        "lagged_samples": s.lagged_samples})
}

//! The runtimes' typed events as the JSON the page works with ([`event_json`]): most are
//! their own `Serialize` form (`kind`, `detail`); Skeeter's published SES
//! ([`EventKind::SesPublished`]) becomes the page's `ses-form`, and the Peer Agent counters
//! ([`EventKind::PeerStatus`], whose types have no JSON form) are rendered here.

use ima_agents::peer::manager::ClientStatus;
use ima_agents::peer::net::{BroadcastStats, ManagerNetStats};
use ima_agents::peer::wire::RejectCounts;
use ima_agents::runtime::events::{PeerStatus, SesMark};
use ima_agents::runtime::{Event, EventKind};
use serde_json::{Value, json};

use super::state::JsonEvent;

/// An event in the JSON form of the page.
pub fn event_json(e: &Event) -> JsonEvent {
    let (kind, detail) = match &e.kind {
        EventKind::SesPublished { marks } => ("ses-form".to_owned(), ses_json(&e.robot, marks)),
        EventKind::PeerStatus(p) => ("peer-status".to_owned(), peer_status_json(p)),
        k => {
            let mut v = serde_json::to_value(k).unwrap_or(Value::Null);
            (k.name().to_owned(), v["detail"].take())
        }
    };
    JsonEvent {
        t_s: e.t_s,
        robot: e.robot.clone(),
        kind,
        detail,
    }
}

/// A published SES sample (page kind `ses-form`): per record the object, its bearing in
/// the sender's frame and its range in metres where Skeeter's vision estimated one (`null`
/// where it did not: a bearing only).
pub fn ses_json(source: &str, marks: &[SesMark]) -> Value {
    let records: Vec<Value> = marks
        .iter()
        .map(|m| {
            json!({"object": m.tag, "bearing_rad": m.azimuth_rad,
                "elevation_rad": m.elevation_rad,
                "range_m": m.range_m.filter(|r| r.is_finite() && *r >= 0.0)})
        })
        .collect();
    json!({"source": source, "records": records})
}

/// Peer Agent status (page kind `peer-status`): the broadcast counters and, for a
/// manager, its sources, clients, sessions and counters, and its address.
pub fn peer_status_json(p: &PeerStatus) -> Value {
    let mut v = match &p.manager {
        Some(m) => manager_json(m, &p.clients),
        None => json!({}),
    };
    if let Some(b) = &p.broadcast {
        v["broadcast"] = bus_json(b);
    }
    if let Some(a) = &p.address {
        v["address"] = json!(a);
    }
    v
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

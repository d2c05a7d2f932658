//! The runtimes' typed events as the JSON the page works with ([`event_json`]): most are
//! their own `Serialize` form (`kind`, `detail`); Skeeter's published SES
//! ([`EventKind::SesPublished`]) becomes the page's `ses-form`, and the Peer Agent counters
//! ([`EventKind::PeerStatus`], whose types have no JSON form) are rendered here.

use ima_agents::peer::client::{ClientLinkStatus, Registration};
use ima_agents::peer::manager::{ClientStatus, DecisionNote, Outcome};
use ima_agents::peer::net::{BroadcastStats, ManagerNetStats};
use ima_agents::peer::wire::RejectCounts;
use ima_agents::runtime::events::{PeerClientView, PeerStatus, SesMark};
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
/// manager, its sources, clients, sessions, link health and counters, and its address; for a
/// robot with a client of another's source, that client (`client`).
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
    if let Some(c) = &p.client {
        v["client"] = client_json(c);
    }
    v
}

/// Wire rejections by class, with the page's three groups: `auth_failures` (frames under
/// another key), `bad_frames` (truncated, bad magic or version, oversize, malformed) and
/// `replayed`.
pub fn rejects_json(r: &RejectCounts) -> Value {
    let bad = [
        r.truncated,
        r.bad_magic,
        r.bad_version,
        r.oversize,
        r.malformed,
    ]
    .iter()
    .fold(0u64, |a, b| a.saturating_add(*b));
    json!({"truncated": r.truncated, "bad_magic": r.bad_magic, "bad_version": r.bad_version,
        "oversize": r.oversize, "bad_mac": r.bad_mac, "replay": r.replay,
        "malformed": r.malformed, "auth_failures": r.bad_mac, "bad_frames": bad,
        "replayed": r.replay})
}

fn ms(d: core::time::Duration) -> u64 {
    u64::try_from(d.as_millis()).unwrap_or(u64::MAX)
}

/// An outcome as the page shows it (`granted`, `pending`, `denied: …`, `revoked: …`,
/// `withdrawn`).
pub fn outcome_text(o: &Outcome) -> String {
    match o {
        Outcome::Granted => "granted".to_owned(),
        Outcome::Pending => "pending".to_owned(),
        Outcome::Denied(r) => format!("denied: {r:?}"),
        Outcome::Revoked(r) => format!("revoked: {r:?}"),
        Outcome::Withdrawn => "withdrawn".to_owned(),
    }
}

fn decision_json(d: &DecisionNote) -> Value {
    json!({"source": d.source, "robot_priority": d.priority.robot,
        "request_priority": d.priority.request, "outcome": outcome_text(&d.outcome),
        "at_ms": d.at.as_micros() / 1000})
}

/// A client session's health as its client sees it.
pub fn client_link_json(l: &ClientLinkStatus) -> Value {
    let reg = match l.registration {
        Registration::Unregistered => "unregistered",
        Registration::Registering => "registering",
        Registration::Registered => "registered",
        Registration::Unregistering => "unregistering",
        Registration::Lost => "lost",
    };
    let requests: Vec<Value> = l
        .requests
        .iter()
        .map(|(s, g)| json!({"source": s, "granted": g}))
        .collect();
    json!({"client": l.client, "registration": reg, "frames_received": l.frames_received,
        "heartbeats_received": l.heartbeats_received, "heartbeats_sent": l.heartbeats_sent,
        "last_seen_ms": ms(l.silent_for), "open_ms": ms(l.open_for),
        "rejected": rejects_json(&l.rejects), "requests": requests})
}

/// A robot's own Peer Agent client: its subscription, request priority, latest outcome,
/// counters and session health.
pub fn client_json(c: &PeerClientView) -> Value {
    json!({"manager": c.manager, "source": c.source, "priority": c.priority,
        "outcome": c.outcome, "grants": c.grants, "samples": c.samples, "retries": c.retries,
        "link": c.link.as_ref().map(client_link_json)})
}

/// A broadcast channel's counters.
pub fn bus_json(s: &BroadcastStats) -> Value {
    json!({"accepted": s.receiver.accepted, "duplicate": s.receiver.duplicate,
        "stale": s.receiver.stale, "sent": s.sent, "send_errors": s.send_errors,
        "rejected": rejects_json(&s.wire)})
}

/// A Peer Agent manager's status (kind `peer-status`): sources, clients with their requests'
/// priorities and latest outcomes, each session's link health (heartbeats both ways, last
/// seen) and the counters.
pub fn manager_json(s: &ManagerNetStats, all: &[ClientStatus]) -> Value {
    let sources: Vec<Value> = s
        .sources
        .iter()
        .map(|x| json!({"name": x.name, "kind": x.kind, "rate_mhz": x.rate_mhz}))
        .collect();
    let clients: Vec<Value> = all
        .iter()
        .map(|c| {
            let requests: Vec<Value> = c
                .requests
                .iter()
                .map(|r| {
                    json!({"source": r.source, "robot_priority": r.priority.robot,
                        "request_priority": r.priority.request, "granted": r.granted})
                })
                .collect();
            let link = s.links.iter().find(|l| l.link.peer == c.peer);
            json!({"client": c.client, "robot": c.robot, "requesting": c.requesting,
                "granted": c.granted, "requests": requests,
                "recent": c.recent.iter().map(decision_json).collect::<Vec<_>>(),
                "session": link.map(|l| l.addr.to_string())})
        })
        .collect();
    let links: Vec<Value> = s
        .links
        .iter()
        .map(|l| {
            let robots: Vec<&str> = all
                .iter()
                .filter(|c| c.peer == l.link.peer)
                .map(|c| c.robot.as_str())
                .collect();
            json!({"session": l.link.peer, "addr": l.addr.to_string(), "robots": robots,
                "frames_received": l.link.frames_received,
                "heartbeats_received": l.link.heartbeats_received,
                "heartbeats_sent": l.link.heartbeats_sent,
                "last_seen_ms": ms(l.link.silent_for), "open_ms": ms(l.link.open_for)})
        })
        .collect();
    json!({"sources": sources, "clients": clients, "sessions": s.sessions,
        "data_sessions": s.data_sessions, "task_priority": s.task_priority,
        "lost": s.core.lost, "closed_bad": s.core.closed_bad,
        "rejected": rejects_json(&s.core.rejects), "data_rejected": rejects_json(&s.data_rejects),
        "data_bad_tickets": s.data_bad_tickets, "slow_closed": s.slow_closed,
        "lagged_samples": s.lagged_samples, "links": links})
}

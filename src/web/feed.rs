//! The runtimes' typed events as the JSON the page works with ([`event_json`]): most are
//! their own `Serialize` form (`kind`, `detail`); Skeeter's published SES
//! ([`EventKind::SesPublished`]) becomes the page's `ses-form`, and the Peer Agent counters
//! ([`EventKind::PeerStatus`], whose types have no JSON form) are rendered here.

use ima_agents::peer::client::{ClientLinkStatus, Registration};
use ima_agents::peer::manager::{ClientStatus, Outcome};
use ima_agents::peer::net::{BroadcastStats, SessionLink};
use ima_agents::peer::wire::RejectCounts;
use ima_agents::runtime::events::{PeerClientView, PeerStatus, SesMark};
use ima_agents::runtime::{Event, EventKind};
use serde::Serialize;
use serde::ser::{SerializeMap, Serializer};
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
    serde_json::to_value(PeerStatusJson(p)).unwrap_or_else(|_| json!({}))
}

/// [`peer_status_json`]'s object, serialised straight from the status (a recording writes it
/// into its queue without building a JSON tree).
#[derive(Debug, Clone, Copy)]
pub struct PeerStatusJson<'a>(pub &'a PeerStatus);

impl Serialize for PeerStatusJson<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let p = self.0;
        let mut m = s.serialize_map(None)?;
        if let Some(st) = &p.manager {
            let sources: Vec<_> = (st.sources.iter())
                .map(|x| Source {
                    name: &x.name,
                    kind: &x.kind,
                    rate_mhz: x.rate_mhz,
                })
                .collect();
            let clients: Vec<_> = (p.clients.iter())
                .map(|c| ClientJson {
                    c,
                    session: st.links.iter().find(|l| l.link.peer == c.peer),
                })
                .collect();
            let links: Vec<_> = (st.links.iter())
                .map(|l| LinkJson {
                    l,
                    clients: &p.clients,
                })
                .collect();
            m.serialize_entry("sources", &sources)?;
            m.serialize_entry("clients", &clients)?;
            m.serialize_entry("sessions", &st.sessions)?;
            m.serialize_entry("data_sessions", &st.data_sessions)?;
            m.serialize_entry("task_priority", &st.task_priority)?;
            m.serialize_entry("lost", &st.core.lost)?;
            m.serialize_entry("closed_bad", &st.core.closed_bad)?;
            m.serialize_entry("rejected", &Rejects(&st.core.rejects))?;
            m.serialize_entry("data_rejected", &Rejects(&st.data_rejects))?;
            m.serialize_entry("data_bad_tickets", &st.data_bad_tickets)?;
            m.serialize_entry("slow_closed", &st.slow_closed)?;
            m.serialize_entry("lagged_samples", &st.lagged_samples)?;
            m.serialize_entry("links", &links)?;
        }
        if let Some(b) = &p.broadcast {
            m.serialize_entry("broadcast", &Bus(b))?;
        }
        if let Some(a) = &p.address {
            m.serialize_entry("address", a)?;
        }
        if let Some(c) = &p.client {
            m.serialize_entry("client", &Client(c))?;
        }
        m.end()
    }
}

/// Wire rejections by class, with the page's three groups: `auth_failures` (frames under
/// another key), `bad_frames` (truncated, bad magic or version, oversize, malformed) and
/// `replayed`.
struct Rejects<'a>(&'a RejectCounts);

impl Serialize for Rejects<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let r = self.0;
        let bad = [
            r.truncated,
            r.bad_magic,
            r.bad_version,
            r.oversize,
            r.malformed,
        ]
        .iter()
        .fold(0u64, |a, b| a.saturating_add(*b));
        let mut m = s.serialize_map(Some(10))?;
        m.serialize_entry("truncated", &r.truncated)?;
        m.serialize_entry("bad_magic", &r.bad_magic)?;
        m.serialize_entry("bad_version", &r.bad_version)?;
        m.serialize_entry("oversize", &r.oversize)?;
        m.serialize_entry("bad_mac", &r.bad_mac)?;
        m.serialize_entry("replay", &r.replay)?;
        m.serialize_entry("malformed", &r.malformed)?;
        m.serialize_entry("auth_failures", &r.bad_mac)?;
        m.serialize_entry("bad_frames", &bad)?;
        m.serialize_entry("replayed", &r.replay)?;
        m.end()
    }
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
        Outcome::Denied(r) => format!("denied: {r}"),
        Outcome::Revoked(r) => format!("revoked: {r}"),
        Outcome::Withdrawn => "withdrawn".to_owned(),
    }
}

/// A value written through its `Display` form (an address), without a `String`.
struct Shown<T>(T);

impl<T: std::fmt::Display> Serialize for Shown<T> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(&self.0)
    }
}

#[derive(Serialize)]
struct Source<'a> {
    name: &'a str,
    kind: &'a str,
    rate_mhz: u32,
}

/// A manager's client: its requests' priorities, latest decisions and session.
struct ClientJson<'a> {
    c: &'a ClientStatus,
    session: Option<&'a SessionLink>,
}

impl Serialize for ClientJson<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        #[derive(Serialize)]
        struct Request<'a> {
            source: &'a str,
            robot_priority: u8,
            request_priority: u8,
            granted: bool,
        }
        #[derive(Serialize)]
        struct Decision<'a> {
            source: &'a str,
            robot_priority: u8,
            request_priority: u8,
            outcome: String,
            at_ms: u64,
        }
        let c = self.c;
        let requests: Vec<_> = (c.requests.iter())
            .map(|r| Request {
                source: &r.source,
                robot_priority: r.priority.robot,
                request_priority: r.priority.request,
                granted: r.granted,
            })
            .collect();
        let recent: Vec<_> = (c.recent.iter())
            .map(|d| Decision {
                source: &d.source,
                robot_priority: d.priority.robot,
                request_priority: d.priority.request,
                outcome: outcome_text(&d.outcome),
                at_ms: d.at.as_micros() / 1000,
            })
            .collect();
        let mut m = s.serialize_map(Some(7))?;
        m.serialize_entry("client", &c.client)?;
        m.serialize_entry("robot", &c.robot)?;
        m.serialize_entry("requesting", &c.requesting)?;
        m.serialize_entry("granted", &c.granted)?;
        m.serialize_entry("requests", &requests)?;
        m.serialize_entry("recent", &recent)?;
        m.serialize_entry("session", &self.session.map(|l| Shown(l.addr)))?;
        m.end()
    }
}

/// A manager's session: its link health and the robots registered over it.
struct LinkJson<'a> {
    l: &'a SessionLink,
    clients: &'a [ClientStatus],
}

impl Serialize for LinkJson<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let l = self.l;
        let robots: Vec<&str> = (self.clients.iter())
            .filter(|c| c.peer == l.link.peer)
            .map(|c| c.robot.as_str())
            .collect();
        let mut m = s.serialize_map(Some(8))?;
        m.serialize_entry("session", &l.link.peer)?;
        m.serialize_entry("addr", &Shown(l.addr))?;
        m.serialize_entry("robots", &robots)?;
        m.serialize_entry("frames_received", &l.link.frames_received)?;
        m.serialize_entry("heartbeats_received", &l.link.heartbeats_received)?;
        m.serialize_entry("heartbeats_sent", &l.link.heartbeats_sent)?;
        m.serialize_entry("last_seen_ms", &ms(l.link.silent_for))?;
        m.serialize_entry("open_ms", &ms(l.link.open_for))?;
        m.end()
    }
}

/// A client session's health as its client sees it.
struct ClientLink<'a>(&'a ClientLinkStatus);

impl Serialize for ClientLink<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        #[derive(Serialize)]
        struct Request<'a> {
            source: &'a str,
            granted: bool,
        }
        let l = self.0;
        let reg = match l.registration {
            Registration::Unregistered => "unregistered",
            Registration::Registering => "registering",
            Registration::Registered => "registered",
            Registration::Unregistering => "unregistering",
            Registration::Lost => "lost",
        };
        let requests: Vec<_> = (l.requests.iter())
            .map(|(source, granted)| Request {
                source,
                granted: *granted,
            })
            .collect();
        let mut m = s.serialize_map(Some(9))?;
        m.serialize_entry("client", &l.client)?;
        m.serialize_entry("registration", reg)?;
        m.serialize_entry("frames_received", &l.frames_received)?;
        m.serialize_entry("heartbeats_received", &l.heartbeats_received)?;
        m.serialize_entry("heartbeats_sent", &l.heartbeats_sent)?;
        m.serialize_entry("last_seen_ms", &ms(l.silent_for))?;
        m.serialize_entry("open_ms", &ms(l.open_for))?;
        m.serialize_entry("rejected", &Rejects(&l.rejects))?;
        m.serialize_entry("requests", &requests)?;
        m.end()
    }
}

/// A robot's own Peer Agent client: its subscription, request priority, latest outcome,
/// counters and session health.
struct Client<'a>(&'a PeerClientView);

impl Serialize for Client<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let c = self.0;
        let mut m = s.serialize_map(Some(8))?;
        m.serialize_entry("manager", &c.manager)?;
        m.serialize_entry("source", &c.source)?;
        m.serialize_entry("priority", &c.priority)?;
        m.serialize_entry("outcome", &c.outcome)?;
        m.serialize_entry("grants", &c.grants)?;
        m.serialize_entry("samples", &c.samples)?;
        m.serialize_entry("retries", &c.retries)?;
        m.serialize_entry("link", &c.link.as_ref().map(ClientLink))?;
        m.end()
    }
}

/// A broadcast channel's counters.
struct Bus<'a>(&'a BroadcastStats);

impl Serialize for Bus<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let b = self.0;
        let mut m = s.serialize_map(Some(6))?;
        m.serialize_entry("accepted", &b.receiver.accepted)?;
        m.serialize_entry("duplicate", &b.receiver.duplicate)?;
        m.serialize_entry("stale", &b.receiver.stale)?;
        m.serialize_entry("sent", &b.sent)?;
        m.serialize_entry("send_errors", &b.send_errors)?;
        m.serialize_entry("rejected", &Rejects(&b.wire))?;
        m.end()
    }
}

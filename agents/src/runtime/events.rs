//! Typed runtime events on a bounded, drop-oldest channel.
//!
//! Every runtime reports what it does as an [`Event`]: the mission time, the robot and an
//! [`EventKind`]. [`Events`] logs each one (`tracing`, level info) and hands it to a bounded
//! [`tokio::sync::broadcast`] channel: sending never waits, so a slow consumer never blocks a
//! robot; when it falls behind it loses the oldest events and its [`EventReceiver`] counts
//! them ([`EventReceiver::dropped`]).
//!
//! The `Serialize` form is the CLI's JSON line: `{"t_s", "robot", "kind", "detail"}` where
//! `kind` is the variant's kebab-case name and `detail` its payload (absent for variants
//! without one).

use serde::Serialize;
use tokio::sync::broadcast;

use super::MissionTime;
use crate::mission::msg::Broadcast;

/// Something a runtime did.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Event {
    /// Mission seconds ([`MissionTime::secs`]).
    pub t_s: f64,
    /// Which robot (or the commander's name).
    pub robot: String,
    /// What happened.
    #[serde(flatten)]
    pub kind: EventKind,
}

impl Event {
    /// The kind's name as in the JSON form (`behaviour`, `target`, …).
    #[must_use]
    pub fn name(&self) -> &'static str {
        self.kind.name()
    }
}

/// One record of a published SES sample: what was seen, and where on Skeeter's sphere.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SesMark {
    /// The object's tag (a colour, or Scooter's).
    pub tag: String,
    /// Azimuth in Skeeter's (common) frame, radians, counter-clockwise.
    pub azimuth_rad: f64,
    /// Elevation, radians.
    pub elevation_rad: f64,
    /// Range, metres, where Skeeter's vision could estimate one (the object's apparent size).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub range_m: Option<f64>,
}

/// What happened, with its details.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "kind", content = "detail", rename_all = "kebab-case")]
pub enum EventKind {
    /// The runtime is up (its devices answer; Skeeter's manager listens).
    Connected {
        /// Scooter: its common-frame heading at start, degrees.
        #[serde(skip_serializing_if = "Option::is_none")]
        start_heading_deg: Option<f64>,
        /// Skeeter: where its Peer Agent manager listens.
        #[serde(skip_serializing_if = "Option::is_none")]
        manager: Option<String>,
    },
    /// The running SAN module changed.
    Behaviour(String),
    /// A mission broadcast heard (its display form).
    Heard(String),
    /// A mission broadcast said (its display form; statuses are not reported).
    Say(String),
    /// Scooter: an SES sample from Skeeter.
    Ses {
        /// Records in the sample.
        records: usize,
        /// Whether the heading calculation made a plan from it.
        planned: bool,
        /// The new target it was replayed for (a sample kept from before the target).
        #[serde(skip_serializing_if = "Option::is_none")]
        target: Option<String>,
    },
    /// Scooter: the command sent to the base (every 2 mission seconds).
    Control(Control),
    /// Scooter asked Skeeter for a fresh heading (a new SES request).
    RequestHeading,
    /// A fleet stop was heard and obeyed.
    FleetStop {
        /// Who sent it.
        by: String,
        /// Why.
        reason: String,
    },
    /// A fleet stop ended.
    FleetResume {
        /// Who ended it (`new target` when a new target did).
        by: String,
        /// The new target that ended it, if one did.
        #[serde(skip_serializing_if = "Option::is_none")]
        target: Option<String>,
    },
    /// Peer Agent link news.
    Peer(PeerNote),
    /// Skeeter: the SES sample it published — what its cameras saw, as bearings — for live
    /// views and recordings.
    SesPublished {
        /// One mark per SES record.
        marks: Vec<SesMark>,
    },
    /// Skeeter: a sweep of its cameras ended.
    Scan {
        /// Tags seen.
        seen: Vec<String>,
        /// Whether Scooter's tag was among them.
        scooter: bool,
        /// Cameras whose frame was searched.
        cameras_ok: u8,
        /// Cameras skipped.
        cameras_failed: u8,
    },
    /// Some input events were lost (a lagging queue) and the runtime acted on the loss.
    Lagged {
        /// Which input.
        input: String,
        /// How many were lost.
        missed: u64,
    },
    /// Frames under another group key were refused (rate-limited report; the CLI shows it
    /// on stderr).
    AuthFailure(String),
    /// The commander: a target's state changed.
    Target(TargetChange),
    /// The commander: a broadcast heard.
    Broadcast(BroadcastView),
    /// The commander: a robot's liveness changed.
    Robot {
        /// The robot.
        robot: String,
        /// `alive` or `lost`.
        state: String,
        /// How long it had been silent.
        silent_s: f64,
    },
    /// The commander waits for robots before its first target, or gave up waiting.
    Waiting(Waiting),
    /// The commander sent a fleet command.
    Fleet {
        /// `stop` or `resume`.
        command: String,
        /// The stop's reason.
        #[serde(skip_serializing_if = "Option::is_none")]
        reason: Option<String>,
    },
    /// The commander could not carry out an operator's request.
    Operator {
        /// Why.
        error: String,
    },
    /// The commander: the whole series after any change (detail, see [`Events::detailed`]).
    Queue {
        /// Every target, in the series' order.
        targets: Vec<QueueEntry>,
    },
    /// A robot's SAN now (detail, see [`Events::detailed`]).
    San(SanView),
    /// Scooter's belief for a map (detail, see [`Events::detailed`]).
    Map(MapView),
    /// Peer Agent counters and status (detail, see [`Events::detailed`]).
    PeerStatus(Box<PeerStatus>),
}

impl EventKind {
    /// The variant's name as in the JSON form.
    #[must_use]
    pub fn name(&self) -> &'static str {
        match self {
            EventKind::Connected { .. } => "connected",
            EventKind::Behaviour(_) => "behaviour",
            EventKind::Heard(_) => "heard",
            EventKind::Say(_) => "say",
            EventKind::Ses { .. } => "ses",
            EventKind::Control(_) => "control",
            EventKind::RequestHeading => "request-heading",
            EventKind::FleetStop { .. } => "fleet-stop",
            EventKind::FleetResume { .. } => "fleet-resume",
            EventKind::Peer(_) => "peer",
            EventKind::SesPublished { .. } => "ses-published",
            EventKind::Scan { .. } => "scan",
            EventKind::Lagged { .. } => "lagged",
            EventKind::AuthFailure(_) => "auth-failure",
            EventKind::Target(_) => "target",
            EventKind::Broadcast(_) => "broadcast",
            EventKind::Robot { .. } => "robot",
            EventKind::Waiting(_) => "waiting",
            EventKind::Fleet { .. } => "fleet",
            EventKind::Operator { .. } => "operator",
            EventKind::Queue { .. } => "queue",
            EventKind::San(_) => "san",
            EventKind::Map(_) => "map",
            EventKind::PeerStatus(_) => "peer-status",
        }
    }
}

/// Scooter's command to its base and what it was based on.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Control {
    /// Forward speed sent, m/s.
    pub v_m_s: f64,
    /// Turn rate sent, rad/s.
    pub omega_rad_s: f64,
    /// Scooter's heading, if it knows it.
    pub heading_rad: Option<f64>,
    /// The heading it wants, if any.
    pub desired_rad: Option<f64>,
    /// Its dead-reckoned position, metres.
    pub dr: [f64; 2],
    /// The running behaviour.
    pub behaviour: &'static str,
    /// Whether a fleet stop holds it.
    pub halted: bool,
}

/// Peer Agent link news.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(untagged)]
pub enum PeerNote {
    /// A source was granted.
    Granted {
        /// The source.
        granted: String,
        /// Scooter: the priority it asked with.
        #[serde(skip_serializing_if = "Option::is_none")]
        priority: Option<u8>,
        /// Scooter: the manager that granted it (first grant of a connection).
        #[serde(skip_serializing_if = "Option::is_none")]
        manager: Option<String>,
        /// Scooter: a re-request was granted.
        #[serde(skip_serializing_if = "Option::is_none")]
        again: Option<bool>,
        /// Skeeter: the robot it was granted to.
        #[serde(skip_serializing_if = "Option::is_none")]
        to: Option<String>,
    },
    /// A subscription was lost (for now).
    Lost {
        /// Why.
        lost: String,
    },
    /// The link failed; it is retried.
    Retry {
        /// Why it failed.
        retry: String,
    },
}

/// A target's state change at the commander.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TargetChange {
    /// The colour.
    pub target: String,
    /// Its state (`pending`, `sent`, `processing`, `done`, `failed`).
    pub state: String,
    /// Final states: the time from sending to the end, seconds.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub time_s: Option<f64>,
    /// Final states: whether the commander gave up on it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub given_up: Option<bool>,
    /// Final states: whether the operator cancelled it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cancelled: Option<bool>,
}

/// The commander waits for robots.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub enum Waiting {
    /// Waiting for these robots.
    #[serde(rename = "for")]
    For(Vec<String>),
    /// Gave up waiting for these.
    #[serde(rename = "gave_up_on")]
    GaveUpOn(Vec<String>),
}

/// A broadcast as the event stream shows it (`type`: `status`, `emergency`, `mission`).
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "type", rename_all = "lowercase")]
pub enum BroadcastView {
    /// A status.
    Status {
        /// Sender.
        robot: String,
        /// Its behaviour.
        behaviour: String,
        /// Its SAN summary.
        san: String,
        /// Its pose, if it sent one.
        pose: Option<PoseView>,
    },
    /// An emergency.
    Emergency {
        /// Sender.
        robot: String,
        /// The emergency's kind.
        kind: String,
        /// Its text.
        text: String,
    },
    /// A mission event.
    Mission {
        /// Sender.
        robot: String,
        /// The event.
        event: String,
        /// The target.
        target: String,
    },
}

/// A broadcast pose in SI units.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PoseView {
    /// x, metres.
    pub x_m: f64,
    /// y, metres.
    pub y_m: f64,
    /// Heading, radians.
    pub theta_rad: f64,
}

impl From<&Broadcast> for BroadcastView {
    fn from(b: &Broadcast) -> Self {
        match b {
            Broadcast::Status {
                robot,
                behaviour,
                san,
                pose,
            } => BroadcastView::Status {
                robot: robot.clone(),
                behaviour: behaviour.clone(),
                san: san.clone(),
                pose: pose.map(|p| PoseView {
                    x_m: f64::from(p.x_mm) / 1000.0,
                    y_m: f64::from(p.y_mm) / 1000.0,
                    theta_rad: f64::from(p.theta_mrad) / 1000.0,
                }),
            },
            Broadcast::Emergency { robot, emergency } => BroadcastView::Emergency {
                robot: robot.clone(),
                kind: emergency.kind().to_owned(),
                text: emergency.text(),
            },
            Broadcast::Mission {
                robot,
                event,
                target,
            } => BroadcastView::Mission {
                robot: robot.clone(),
                event: event.as_str().to_owned(),
                target: target.clone(),
            },
        }
    }
}

/// One target of the commander's series ([`EventKind::Queue`]).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct QueueEntry {
    /// Position in the series.
    pub index: usize,
    /// The colour.
    pub target: String,
    /// Its state (`waiting`, `sent`, `processing`, `done`, `failed`).
    pub state: String,
    /// Mission second it was (last) sent.
    pub sent_s: Option<f64>,
    /// Mission second Skeeter accepted it.
    pub accepted_s: Option<f64>,
    /// Mission second it ended.
    pub ended_s: Option<f64>,
    /// From sending to the end, seconds.
    pub time_s: Option<f64>,
    /// The operator cancelled it.
    pub cancelled: bool,
    /// The commander gave up on it.
    pub given_up: bool,
    /// How often it was sent.
    pub sends: u32,
}

/// One SAN module's state ([`SanView`]).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SanModuleView {
    /// The module (behaviour).
    pub name: String,
    /// Its activation.
    pub activation: f64,
    /// Every precondition true.
    pub executable: bool,
}

/// One SAN condition's truth ([`SanView`]).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SanConditionView {
    /// The condition.
    pub name: String,
    /// Whether it is true (unknown counts as false).
    pub value: bool,
}

/// A SAN's state: each module's activation and executable flag, the threshold θ, each
/// condition's truth and the selected behaviour ([`EventKind::San`]).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SanView {
    /// The network's name.
    pub network: String,
    /// The modules, in declaration order.
    pub modules: Vec<SanModuleView>,
    /// The threshold θ.
    pub threshold: f64,
    /// The conditions.
    pub conditions: Vec<SanConditionView>,
    /// The selected behaviour.
    pub selected: String,
}

impl SanView {
    /// The state of `net` with `selected` running.
    #[must_use]
    pub fn of(net: &crate::san::Network, selected: &str) -> Self {
        let modules = net
            .module_names()
            .zip(net.activations())
            .zip(net.executable_flags())
            .map(|((name, a), e)| SanModuleView {
                name: name.to_string(),
                activation: *a,
                executable: e,
            })
            .collect();
        let conditions = net
            .condition_names()
            .map(|c| SanConditionView {
                name: c.to_string(),
                value: net.condition(c) == Some(true),
            })
            .collect();
        Self {
            network: net.name().to_string(),
            modules,
            threshold: net.threshold(),
            conditions,
            selected: selected.to_owned(),
        }
    }
}

/// Scooter's plan ([`MapView`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(untagged)]
pub enum PlanView {
    /// A fixed common-frame heading.
    Heading {
        /// Radians.
        heading_rad: f64,
    },
    /// A point in the DR frame.
    Point {
        /// Metres.
        point: [f64; 2],
    },
}

/// At most this many laser obstacles go into one [`MapView`].
pub const MAX_MAP_OBSTACLES: usize = 120;

/// Scooter's belief for a map ([`EventKind::Map`]): DR position, heading, desired heading,
/// plan, the laser obstacles it remembers (DR frame, metres, thinned to
/// [`MAX_MAP_OBSTACLES`]) and its target.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MapView {
    /// Dead-reckoned position, metres.
    pub dr: [f64; 2],
    /// Heading, radians, if known.
    pub heading_rad: Option<f64>,
    /// The heading it wants, if any.
    pub desired_rad: Option<f64>,
    /// Its plan, if any.
    pub plan: Option<PlanView>,
    /// Obstacles, DR frame.
    pub obstacles: Vec<[f64; 2]>,
    /// Its target, if any.
    pub target: Option<String>,
}

impl MapView {
    /// Scooter's belief now.
    #[must_use]
    pub fn of(brain: &crate::mission::scooter::ScooterBrain) -> Self {
        use crate::mission::scooter::Plan;
        let dr = brain.dr_position();
        let obs = brain.obstacles_dr();
        let step = obs.len().div_ceil(MAX_MAP_OBSTACLES).max(1);
        Self {
            dr: [dr.x, dr.y],
            heading_rad: brain.heading(),
            desired_rad: brain.desired_heading(),
            plan: brain.plan().map(|p| match p {
                Plan::Heading(h) => PlanView::Heading { heading_rad: h },
                Plan::Point(p) => PlanView::Point { point: [p.x, p.y] },
            }),
            obstacles: obs
                .iter()
                .step_by(step)
                .filter(|p| p.x.is_finite() && p.y.is_finite())
                .map(|p| [p.x, p.y])
                .collect(),
            target: brain.target().map(str::to_owned),
        }
    }
}

/// Peer Agent counters and status ([`EventKind::PeerStatus`]): the broadcast channel's
/// counters and, for a manager, its sources, sessions and clients. The counters' types have
/// no JSON form of their own: the JSON line carries the manager's address only, and the web
/// console renders the rest.
#[derive(Debug, Clone, PartialEq, Serialize, Default)]
pub struct PeerStatus {
    /// The broadcast channel's counters.
    #[serde(skip)]
    pub broadcast: Option<crate::peer::net::BroadcastStats>,
    /// The manager's counters.
    #[serde(skip)]
    pub manager: Option<crate::peer::net::ManagerNetStats>,
    /// The manager's clients.
    #[serde(skip)]
    pub clients: Vec<crate::peer::manager::ClientStatus>,
    /// Where the manager listens.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub address: Option<String>,
    /// The robot's own Peer Agent client (Scooter's subscription of Skeeter's `ses`).
    #[serde(skip)]
    pub client: Option<PeerClientView>,
}

/// A runtime's Peer Agent client as its status page shows it ([`PeerStatus::client`]): the
/// manager it talks to, the source it subscribes with its request priority, what became of
/// the request, and the session's health.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct PeerClientView {
    /// The manager's address.
    pub manager: String,
    /// The source subscribed.
    pub source: String,
    /// The request's priority.
    pub priority: u8,
    /// The latest outcome (`connecting`, `granted`, `lost: …`, `retrying: …`).
    pub outcome: String,
    /// Grants received so far (first grants and re-grants).
    pub grants: u64,
    /// Samples received so far.
    pub samples: u64,
    /// Connections that failed or ended (each is retried).
    pub retries: u64,
    /// The current session's health, when one is open.
    pub link: Option<crate::peer::client::ClientLinkStatus>,
}

/// Where runtimes report their events: the log and, if made with [`Events::channel`], a
/// bounded drop-oldest channel. Cheap to clone; the channel closes when every clone is
/// dropped.
#[derive(Debug, Clone, Default)]
pub struct Events {
    tx: Option<broadcast::Sender<Event>>,
    /// Whether the runtimes also report detail for a live console.
    detail: bool,
}

impl Events {
    /// Whether a runtime's periodic detail (SAN, map, Peer Agent status) is due at `now`:
    /// every `every` on a fixed grid from the first report, `last` updated when it is; never
    /// when nobody wants detail. Counting `every` from the tick that reported made a loop
    /// whose ticks do not divide it report a tick late each time (Scooter's 0.5 s came every
    /// 0.6 s).
    pub fn detail_due(
        &self,
        last: &mut Option<ima_hal::Instant>,
        now: ima_hal::Instant,
        every: std::time::Duration,
    ) -> bool {
        if !self.wants_detail() {
            return false;
        }
        match *last {
            Some(t) if now < t + every => false,
            // On the grid; a runtime that fell more than a period behind starts it again.
            Some(t) if now < t + every + every => {
                *last = Some(t + every);
                true
            }
            _ => {
                *last = Some(now);
                true
            }
        }
    }

    /// Events logged only.
    #[must_use]
    pub fn log_only() -> Self {
        Self::default()
    }

    /// Events logged and queued for the returned receiver, which keeps the latest
    /// `capacity` (at least 1) unread ones.
    #[must_use]
    pub fn channel(capacity: usize) -> (Self, EventReceiver) {
        let (tx, rx) = broadcast::channel(capacity.max(1));
        (
            Self {
                tx: Some(tx),
                detail: false,
            },
            EventReceiver { rx, dropped: 0 },
        )
    }

    /// These events with a live console's detail too, when `on`: the commander's whole
    /// series ([`EventKind::Queue`]), SAN activations ([`EventKind::San`]), Scooter's map
    /// ([`EventKind::Map`]) and Peer Agent status ([`EventKind::PeerStatus`]), reported
    /// periodically. Off by default, so that ordinary event output does not change.
    #[must_use]
    pub fn detailed(mut self, on: bool) -> Self {
        self.detail = on;
        self
    }

    /// Whether the detail of [`Events::detailed`] is wanted (cheap to ask on every loop).
    #[must_use]
    pub fn wants_detail(&self) -> bool {
        self.detail && self.tx.is_some()
    }

    /// Another receiver of this channel's events from now on (`None` for [`Events::log_only`]).
    #[must_use]
    pub fn subscribe(&self) -> Option<EventReceiver> {
        self.tx.as_ref().map(|tx| EventReceiver {
            rx: tx.subscribe(),
            dropped: 0,
        })
    }

    /// Report `kind` for `robot` at mission time `t`. Never waits.
    pub fn emit(&self, t: &MissionTime, robot: &str, kind: EventKind) {
        let e = Event {
            t_s: t.secs(),
            robot: robot.to_owned(),
            kind,
        };
        tracing::info!(robot, kind = e.name(), detail = ?e.kind, "event");
        if let Some(tx) = &self.tx {
            // No receiver left is not an error: nobody is listening.
            let _ = tx.send(e);
        }
    }
}

/// The receiving end of [`Events::channel`].
#[derive(Debug)]
pub struct EventReceiver {
    rx: broadcast::Receiver<Event>,
    dropped: u64,
}

impl EventReceiver {
    /// The next event, or `None` once every [`Events`] clone is dropped and the queue is
    /// empty. Events lost to lagging are skipped and counted.
    pub async fn recv(&mut self) -> Option<Event> {
        loop {
            match self.rx.recv().await {
                Ok(e) => return Some(e),
                Err(broadcast::error::RecvError::Lagged(n)) => {
                    self.dropped = self.dropped.saturating_add(n);
                }
                Err(broadcast::error::RecvError::Closed) => return None,
            }
        }
    }

    /// The next event if one is queued (lost ones counted as in [`EventReceiver::recv`]).
    pub fn try_recv(&mut self) -> Option<Event> {
        loop {
            match self.rx.try_recv() {
                Ok(e) => return Some(e),
                Err(broadcast::error::TryRecvError::Lagged(n)) => {
                    self.dropped = self.dropped.saturating_add(n);
                }
                Err(_) => return None,
            }
        }
    }

    /// Events this receiver lost because it fell behind (the oldest ones go first).
    #[must_use]
    pub fn dropped(&self) -> u64 {
        self.dropped
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Detail every 0.5 s from a loop ticking every ~100 ms (jittered a millisecond either
    /// way) comes twice a second, on a fixed grid; nobody wanting it, never.
    #[test]
    fn detail_comes_on_its_grid_whatever_the_loop_s_jitter() {
        use ima_hal::Instant;
        let (events, _rx) = Events::channel(8);
        let events = events.detailed(true);
        let every = std::time::Duration::from_millis(500);
        let mut last = None;
        let mut due = Vec::new();
        for i in 0..100u64 {
            let jitter = [0, 1, 2][(i % 3) as usize];
            let now = Instant::from_millis(i * 100 + jitter);
            if events.detail_due(&mut last, now, every) {
                due.push(now.as_micros() / 1000);
            }
        }
        assert_eq!(due.len(), 20, "{due:?}");
        assert!(
            due.windows(2).all(|w| (400..=600).contains(&(w[1] - w[0]))),
            "{due:?}"
        );
        let mut last = None;
        assert!(!Events::log_only().detail_due(&mut last, Instant::from_millis(9), every));
        // A runtime that fell behind starts the grid again from now.
        let mut last = Some(Instant::from_millis(0));
        assert!(events.detail_due(&mut last, Instant::from_millis(5_000), every));
        assert_eq!(last, Some(Instant::from_millis(5_000)));
    }
    use ima_hal::time::ManualClock;

    fn t() -> MissionTime {
        MissionTime::new(ManualClock::default().shared(), 1.0)
    }

    #[test]
    fn a_slow_consumer_loses_the_oldest_and_counts_them() {
        let (events, mut rx) = Events::channel(4);
        for i in 0..10 {
            events.emit(&t(), "scooter", EventKind::Behaviour(format!("b{i}")));
        }
        let got: Vec<_> = std::iter::from_fn(|| rx.try_recv()).collect();
        assert_eq!(got.len(), 4);
        assert_eq!(got[0].kind, EventKind::Behaviour("b6".into()));
        assert_eq!(rx.dropped(), 6);
    }

    #[test]
    fn json_form_is_kind_and_detail() {
        let e = Event {
            t_s: 1.5,
            robot: "commander".into(),
            kind: EventKind::Target(TargetChange {
                target: "red".into(),
                state: "done".into(),
                time_s: Some(3.0),
                given_up: Some(false),
                cancelled: Some(false),
            }),
        };
        let v = serde_json::to_value(&e).unwrap();
        assert_eq!(v["kind"], "target");
        assert_eq!(v["detail"]["target"], "red");
        assert_eq!(v["detail"]["state"], "done");
        assert_eq!(v["t_s"], 1.5);
        let e = Event {
            kind: EventKind::Behaviour("move-to-target".into()),
            ..e
        };
        let v = serde_json::to_value(&e).unwrap();
        assert_eq!(v["detail"], "move-to-target");
        let v =
            serde_json::to_value(EventKind::Waiting(Waiting::For(vec!["skeeter".into()]))).unwrap();
        assert_eq!(v["detail"]["for"][0], "skeeter");
        let v = serde_json::to_value(EventKind::RequestHeading).unwrap();
        assert_eq!(v["kind"], "request-heading");
        let b = Broadcast::Mission {
            robot: "scooter".into(),
            event: crate::mission::msg::MissionEvent::Accomplished,
            target: "red".into(),
        };
        let v = serde_json::to_value(EventKind::Broadcast((&b).into())).unwrap();
        assert_eq!(v["detail"]["type"], "mission");
        assert_eq!(v["detail"]["robot"], "scooter");
        for k in [
            EventKind::RequestHeading,
            EventKind::Peer(PeerNote::Retry { retry: "x".into() }),
        ] {
            assert_eq!(serde_json::to_value(&k).unwrap()["kind"], k.name());
        }
    }
}

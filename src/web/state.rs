//! The console's state: everything the page shows, fed from the runtimes' typed events
//! ([`ima_agents::runtime::Event`], rendered by [`super::feed::event_json`]) and, with a
//! simulated world, its ground truth; sent to the browser as one JSON snapshot
//! ([`ConsoleState::snapshot`]).

use std::collections::{BTreeMap, VecDeque};

use serde_json::{Value, json};

use ima_agents::runtime::Event;

/// An event in the JSON form the page works with ([`super::feed::event_json`]).
#[derive(Debug, Clone, PartialEq)]
pub struct JsonEvent {
    /// Mission seconds.
    pub t_s: f64,
    /// Which robot (or the commander).
    pub robot: String,
    /// The kind's name (`target`, `san`, `ses-form`, …).
    pub kind: String,
    /// Its detail.
    pub detail: Value,
}

/// Lines kept in the broadcast log.
pub const MAX_LOG: usize = 250;
/// Points kept per trail (older ones are thinned out, never the newest).
pub const MAX_TRAIL: usize = 400;
/// Samples kept per robot of the SAN activations.
pub const MAX_SAN_HISTORY: usize = 120;
/// Notices (command replies, operator errors) kept.
pub const MAX_NOTICES: usize = 20;
/// Peer Agent events kept per robot.
pub const MAX_PEER_EVENTS: usize = 30;

/// What the console knows of one robot.
#[derive(Debug, Clone, Default)]
pub struct RobotView {
    /// `alive` or `lost` (the commander's liveness), `None` before any report.
    pub life: Option<String>,
    /// Seconds of silence at the last liveness report.
    pub silent_s: f64,
    /// Current behaviour (SAN module).
    pub behaviour: Option<String>,
    /// Mission second it was last heard of.
    pub last_t_s: Option<f64>,
    /// The robot's own belief: x, y (metres, shifted by its origin), heading (radians).
    pub pose: Option<[f64; 3]>,
    /// Belief trail.
    pub trail: Vec<[f64; 2]>,
    /// Ground truth (simulated worlds only).
    pub truth: Option<[f64; 3]>,
    /// Ground-truth trail.
    pub truth_trail: Vec<[f64; 2]>,
    /// Where its belief frame's origin lies in the map (its start, with a simulated world).
    pub origin: [f64; 2],
    /// A fleet stop holds it.
    pub halted: bool,
    /// The SAN summary of its last status broadcast.
    pub san_summary: Option<String>,
}

/// One robot's SAN over time.
#[derive(Debug, Clone, Default)]
pub struct SanView {
    /// The latest `san` event's detail.
    pub latest: Value,
    /// `(t_s, activations)` in module order, oldest first.
    pub history: VecDeque<(f64, Vec<f64>)>,
}

/// The whole console state.
#[derive(Debug, Clone, Default)]
pub struct ConsoleState {
    /// Bumped on every change.
    pub version: u64,
    /// Latest mission second seen.
    pub t_s: f64,
    /// `commander` or `demo`.
    pub mode: String,
    /// Known target colours (what the page offers).
    pub colours: Vec<String>,
    /// The series, as the commander's last `queue` event gave it.
    pub targets: Vec<Value>,
    /// How many targets the series holds or will hold once the adds sent from here reach it:
    /// the commander's series never shrinks, so an add the console accepted counts at once,
    /// and a flood of adds cannot all be told "added" past the commander's limit. (An add
    /// from another console of the same commander, racing, can still be refused by the
    /// commander after an "ok" here; it says so in its log.)
    pub added: usize,
    /// Performance index per target position, when known (simulated worlds).
    pub performance: BTreeMap<usize, f64>,
    /// Robots by name.
    pub robots: BTreeMap<String, RobotView>,
    /// Broadcasts and notable events, oldest first: `(seq, t_s, robot, kind, text)`.
    pub log: VecDeque<Value>,
    log_seq: u64,
    /// Replies and errors for the operator, oldest first.
    pub notices: VecDeque<Value>,
    /// Skeeter's last published SES (`ses-form` detail).
    pub ses: Option<Value>,
    /// Scooter's last `map` detail (plan, heading, obstacles).
    pub scooter_map: Option<Value>,
    /// The simulated world (walls, circles, objects), if any.
    pub world: Option<Value>,
    /// SAN per robot.
    pub san: BTreeMap<String, SanView>,
    /// Peer Agent status per robot (`peer-status` detail).
    pub peer: BTreeMap<String, Value>,
    /// Peer Agent events per robot (grants, losses, retries), oldest first.
    pub peer_events: BTreeMap<String, VecDeque<Value>>,
    /// The mission is over (commander finished); the summary, if any.
    pub over: bool,
    /// The end-of-mission summary.
    pub summary: Option<Value>,
    /// Fleet stop in force (as sent by this console's commander).
    pub fleet_stopped: bool,
}

fn push_capped<T>(q: &mut VecDeque<T>, v: T, cap: usize) {
    if q.len() >= cap {
        q.pop_front();
    }
    q.push_back(v);
}

/// Appends a trail point unless it is within 2 cm of the last; halves old points when full.
fn push_trail(trail: &mut Vec<[f64; 2]>, p: [f64; 2]) {
    if !(p[0].is_finite() && p[1].is_finite()) {
        return;
    }
    // Millimetres are plenty on the map, and keep the state small.
    let p = p.map(|v| (v * 1000.0).round() / 1000.0);
    if trail
        .last()
        .is_some_and(|l| (l[0] - p[0]).hypot(l[1] - p[1]) < 0.02)
    {
        return;
    }
    if trail.len() >= MAX_TRAIL {
        // Keep every other point of the older half.
        let half = trail.len() / 2;
        let mut kept: Vec<[f64; 2]> = trail[..half].iter().step_by(2).copied().collect();
        kept.extend_from_slice(&trail[half..]);
        *trail = kept;
    }
    trail.push(p);
}

fn num(v: &Value) -> Option<f64> {
    v.as_f64().filter(|x| x.is_finite())
}

impl ConsoleState {
    /// A state for `mode` offering `colours`.
    pub fn new(mode: &str, colours: Vec<String>) -> Self {
        Self {
            mode: mode.to_owned(),
            colours,
            ..Self::default()
        }
    }

    fn robot(&mut self, name: &str) -> &mut RobotView {
        self.robots.entry(name.to_owned()).or_default()
    }

    fn log_line(&mut self, t_s: f64, robot: &str, kind: &str, text: String) {
        self.log_seq += 1;
        let line =
            json!({"seq": self.log_seq, "t_s": t_s, "robot": robot, "kind": kind, "text": text});
        push_capped(&mut self.log, line, MAX_LOG);
    }

    /// A reply or error for the operator (`level`: `info`, `warn`, `error`).
    pub fn notice(&mut self, level: &str, text: &str) {
        let n = json!({"t_s": self.t_s, "level": level, "text": text});
        push_capped(&mut self.notices, n, MAX_NOTICES);
        self.version += 1;
    }

    /// Take one runtime event into the state.
    pub fn apply(&mut self, e: &Event) {
        self.apply_json(&super::feed::event_json(e));
    }

    /// Take one event, in its JSON form, into the state.
    pub fn apply_json(&mut self, e: &JsonEvent) {
        self.version += 1;
        if e.t_s.is_finite() && e.t_s > self.t_s {
            self.t_s = e.t_s;
        }
        let d = &e.detail;
        let t = e.t_s;
        match e.kind.as_str() {
            "queue" => {
                if let Some(list) = d["targets"].as_array() {
                    self.targets = list.clone();
                    self.added = self.added.max(self.targets.len());
                }
            }
            "target" => {
                let text = format!(
                    "target {} {}",
                    d["target"].as_str().unwrap_or("?"),
                    d["state"].as_str().unwrap_or("?")
                );
                self.log_line(t, &e.robot, "target", text);
            }
            "robot" => {
                let name = d["robot"].as_str().unwrap_or("?").to_owned();
                let state = d["state"].as_str().unwrap_or("?").to_owned();
                let silent = num(&d["silent_s"]).unwrap_or(0.0);
                let r = self.robot(&name);
                r.life = Some(state.clone());
                r.silent_s = silent;
                self.log_line(t, &name, "liveness", format!("{name} {state}"));
            }
            "broadcast" => self.apply_broadcast(t, d),
            "fleet" => {
                let cmd = d["command"].as_str().unwrap_or("?");
                self.fleet_stopped = cmd == "stop";
                self.log_line(t, &e.robot, "fleet", format!("fleet {cmd} sent"));
            }
            "fleet-stop" => self.robot(&e.robot).halted = true,
            "fleet-resume" => self.robot(&e.robot).halted = false,
            "operator" => {
                if let Some(err) = d["error"].as_str() {
                    let err = err.to_owned();
                    self.notice("error", &err);
                }
            }
            "behaviour" => {
                let b = d.as_str().unwrap_or("?").to_owned();
                self.robot(&e.robot).behaviour = Some(b);
                self.robot(&e.robot).last_t_s = Some(t);
            }
            "san" => {
                let acts: Vec<f64> = d["modules"]
                    .as_array()
                    .map(|m| {
                        m.iter()
                            .map(|x| num(&x["activation"]).unwrap_or(0.0))
                            .collect()
                    })
                    .unwrap_or_default();
                let s = self.san.entry(e.robot.clone()).or_default();
                s.latest = d.clone();
                push_capped(&mut s.history, (t, acts), MAX_SAN_HISTORY);
            }
            "control" => {
                if let (Some(x), Some(y)) = (num(&d["dr"][0]), num(&d["dr"][1])) {
                    let theta = num(&d["heading_rad"]).unwrap_or(0.0);
                    let r = self.robot(&e.robot);
                    let p = [x + r.origin[0], y + r.origin[1]];
                    r.pose = Some([p[0], p[1], theta]);
                    push_trail(&mut r.trail, p);
                }
            }
            "map" => {
                if let (Some(x), Some(y)) = (num(&d["dr"][0]), num(&d["dr"][1])) {
                    let theta = num(&d["heading_rad"]).unwrap_or(0.0);
                    let r = self.robot(&e.robot);
                    let p = [x + r.origin[0], y + r.origin[1]];
                    r.pose = Some([p[0], p[1], theta]);
                    push_trail(&mut r.trail, p);
                }
                self.scooter_map = Some(d.clone());
            }
            "ses-form" => self.ses = Some(json!({"t_s": t, "robot": e.robot, "form": d})),
            "peer-status" => {
                self.peer.insert(e.robot.clone(), d.clone());
            }
            "peer" | "connected" => {
                let q = self.peer_events.entry(e.robot.clone()).or_default();
                push_capped(
                    q,
                    json!({"t_s": t, "kind": e.kind, "detail": d}),
                    MAX_PEER_EVENTS,
                );
            }
            "waiting" => {
                let text = if d.get("for").is_some() {
                    format!("waiting for {}", d["for"])
                } else {
                    format!("gave up waiting for {}", d["gave_up_on"])
                };
                self.log_line(t, &e.robot, "waiting", text);
            }
            _ => {}
        }
    }

    fn apply_broadcast(&mut self, t: f64, d: &Value) {
        let robot = d["robot"].as_str().unwrap_or("?").to_owned();
        let ty = d["type"].as_str().unwrap_or("?").to_owned();
        {
            let r = self.robot(&robot);
            r.last_t_s = Some(t);
        }
        match ty.as_str() {
            "status" => {
                let b = d["behaviour"].as_str().unwrap_or("").to_owned();
                let san = d["san"].as_str().unwrap_or("").to_owned();
                let pose = &d["pose"];
                let r = self.robot(&robot);
                r.behaviour = Some(b.clone());
                r.san_summary = Some(san);
                if let (Some(x), Some(y)) = (num(&pose["x_m"]), num(&pose["y_m"])) {
                    let theta = num(&pose["theta_rad"]).unwrap_or(0.0);
                    let p = [x + r.origin[0], y + r.origin[1]];
                    r.pose = Some([p[0], p[1], theta]);
                    push_trail(&mut r.trail, p);
                }
                self.log_line(t, &robot, "status", b);
            }
            "emergency" => {
                let text = format!(
                    "{} {}",
                    d["kind"].as_str().unwrap_or(""),
                    d["text"].as_str().unwrap_or("")
                );
                self.log_line(t, &robot, "emergency", text.trim().to_owned());
            }
            _ => {
                let text = format!(
                    "{} {}",
                    d["event"].as_str().unwrap_or(""),
                    d["target"].as_str().unwrap_or("")
                );
                self.log_line(t, &robot, "mission", text);
            }
        }
    }

    /// A ground-truth pose of `robot` (simulated worlds). The first one also places the
    /// robot's belief frame: its origin is where the robot starts.
    pub fn truth(&mut self, robot: &str, x: f64, y: f64, theta: f64) {
        if !(x.is_finite() && y.is_finite()) {
            return;
        }
        self.version += 1;
        let r = self.robot(robot);
        if r.truth.is_none() && r.trail.is_empty() {
            r.origin = [x, y];
        }
        r.truth = Some([x, y, theta]);
        push_trail(&mut r.truth_trail, [x, y]);
    }

    /// The performance index of the target at `index`.
    pub fn set_performance(&mut self, index: usize, f: f64) {
        if f.is_finite() {
            self.performance.insert(index, f);
            self.version += 1;
        }
    }

    /// The mission is over; `summary` for the page.
    pub fn finish(&mut self, summary: Value) {
        self.over = true;
        self.summary = Some(summary);
        self.version += 1;
    }

    /// Open (not final) targets of the series named `colour`.
    pub fn open_target(&self, colour: &str) -> bool {
        self.targets.iter().any(|t| {
            t["target"] == colour && !matches!(t["state"].as_str(), Some("done" | "failed"))
        })
    }

    /// Robots reported lost.
    pub fn lost_robots(&self) -> Vec<String> {
        self.robots
            .iter()
            .filter(|(_, r)| r.life.as_deref() == Some("lost"))
            .map(|(n, _)| n.clone())
            .collect()
    }

    /// Everything the page shows, as one JSON object (kind `state`).
    pub fn snapshot(&self) -> Value {
        let robots: BTreeMap<&String, Value> = self
            .robots
            .iter()
            .map(|(n, r)| {
                (
                    n,
                    json!({"life": r.life, "silent_s": r.silent_s, "behaviour": r.behaviour,
                        "last_t_s": r.last_t_s, "pose": r.pose, "trail": r.trail,
                        "truth": r.truth, "truth_trail": r.truth_trail, "halted": r.halted,
                        "san_summary": r.san_summary}),
                )
            })
            .collect();
        let targets: Vec<Value> = self
            .targets
            .iter()
            .enumerate()
            .map(|(i, t)| {
                let mut t = t.clone();
                t["performance"] = json!(self.performance.get(&i));
                t
            })
            .collect();
        let san: BTreeMap<&String, Value> = self
            .san
            .iter()
            .map(|(n, s)| {
                let hist: Vec<Value> = s.history.iter().map(|(t, a)| json!([t, a])).collect();
                (n, json!({"latest": s.latest, "history": hist}))
            })
            .collect();
        json!({
            "type": "state",
            "version": self.version,
            "t_s": self.t_s,
            "mode": self.mode,
            "colours": self.colours,
            "targets": targets,
            "robots": robots,
            "log": self.log,
            "notices": self.notices,
            "ses": self.ses,
            "scooter_map": self.scooter_map,
            "world": self.world,
            "san": san,
            "peer": self.peer,
            "peer_events": self.peer_events,
            "over": self.over,
            "summary": self.summary,
            "fleet_stopped": self.fleet_stopped,
        })
    }
}

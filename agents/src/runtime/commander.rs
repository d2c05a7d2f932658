//! The commander's runtime: drives [`Commander`] (the Commander Interface Agent's logic:
//! targets sent one at a time as `Mission { commander, Accepted, colour }`, resent until
//! Skeeter accepts, progress from Skeeter's mission events) over the broadcast channel,
//! reports every broadcast it hears, the robots' liveness, and carries out the operator's
//! requests.

use core::time::Duration;

use ima_hal::Instant;
use ima_hal::time::SharedClock;
use serde::Serialize;

use super::events::{EventKind, Events, PeerStatus, QueueEntry, TargetChange, Waiting};
use super::link::Bus;
use super::{MissionTime, RuntimeError};
use crate::mission::commander::{
    Commander, CommanderConfig, LifeChange, Liveness, TargetState as CoreState,
};
use crate::mission::msg::COMMANDER;

/// A target's final state.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum TargetState {
    /// Skeeter reported it accomplished.
    Done,
    /// Skeeter reported it failed, or it timed out at the commander.
    Failed,
}

/// One target's outcome.
#[derive(Debug, Clone, Serialize)]
pub struct TargetOutcome {
    /// Colour.
    pub target: String,
    /// Final state.
    pub state: TargetState,
    /// Whether it was sent at all (a target cancelled while it waited never was).
    pub sent: bool,
    /// Mission second it was sent (0 when it never was).
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

/// The commander runtime's configuration.
#[derive(Debug, Clone)]
pub struct CommanderRuntimeConfig {
    /// The core's configuration (its name, resend period, give-up time).
    pub core: CommanderConfig,
    /// Mission time = clock time × this.
    pub time_scale: f64,
    /// Report a robot lost after this much (mission) silence; `None`: no liveness reports.
    pub lost_after: Option<Duration>,
    /// Robots to hear on the broadcast channel before the first target goes out.
    pub wait_for: Vec<String>,
    /// Longest wait for them (real time); then the targets go anyway.
    pub wait_timeout: Duration,
    /// Keep running when every target is final (more may be added with
    /// [`Operator::Add`]), until [`Operator::Quit`] or the operator's channel closes.
    pub keep_running: bool,
}

/// How a [`run`] ended.
#[derive(Debug, Clone)]
pub struct Finished {
    /// Every target's outcome (targets still open at an interruption count as failed).
    pub outcomes: Vec<TargetOutcome>,
    /// `Some(stopped)` when the operator ended it ([`Operator::Quit`]); `stopped` tells
    /// whether a fleet stop went out.
    pub interrupted: Option<bool>,
}

fn life_event(events: &Events, time: &MissionTime, me: &str, c: &LifeChange) {
    events.emit(
        time,
        me,
        EventKind::Robot {
            robot: c.robot.clone(),
            state: c.life.as_str().to_owned(),
            silent_s: c.silent.as_secs_f64(),
        },
    );
}

/// Run the commander over `targets` on `bus` until every target is final or the operator
/// quits (`ops`, `None`: no operator). Events: [`EventKind::Target`] on every state change,
/// [`EventKind::Broadcast`] for each broadcast heard, [`EventKind::Robot`] for liveness,
/// [`EventKind::Waiting`], [`EventKind::Fleet`], [`EventKind::Operator`], and
/// [`EventKind::AuthFailure`] for frames under another group key (rate-limited).
///
/// With [`Events::detailed`] it also reports the whole series ([`EventKind::Queue`]) after
/// every change and its broadcast channel's counters ([`EventKind::PeerStatus`]) once a
/// second.
///
/// Before the first target it waits (at most `cfg.wait_timeout`, real time) until every
/// robot of `cfg.wait_for` has been heard, so that no robot misses it.
pub async fn run(
    cfg: CommanderRuntimeConfig,
    targets: &[String],
    bus: Bus,
    clock: SharedClock,
    events: Events,
    mut ops: Option<tokio::sync::mpsc::UnboundedReceiver<Operator>>,
) -> Result<Finished, RuntimeError> {
    let time = MissionTime::new(clock, cfg.time_scale);
    let me = cfg.core.robot.clone();
    let mut live = cfg
        .lost_after
        .map(|d| Liveness::new(d, &[me.as_str(), COMMANDER]));
    let mut missing: Vec<&String> = cfg.wait_for.iter().collect();
    if let Some(l) = &mut live {
        for r in &missing {
            l.expect(r, time.now());
        }
    }
    let mut cmd = Commander::new(targets, cfg.core.clone());
    let mut shown: Vec<(CoreState, bool)> = cmd
        .targets()
        .iter()
        .map(|t| (t.state, t.cancelled))
        .collect();
    // The whole series as a `Queue` event on every change (detail only).
    let mut queue_changed = true;
    let mut waiting = !missing.is_empty();
    if waiting {
        events.emit(
            &time,
            &me,
            EventKind::Waiting(Waiting::For(missing.iter().map(|s| (*s).clone()).collect())),
        );
    } else {
        cmd.start(time.now());
    }
    let wait_deadline = tokio::time::Instant::now() + cfg.wait_timeout;
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
                let fin = t.state.is_final();
                events.emit(
                    &time,
                    &me,
                    EventKind::Target(TargetChange {
                        target: t.colour.clone(),
                        state: t.state.as_str().to_owned(),
                        time_s: if fin {
                            t.duration().map(|d| d.as_secs_f64())
                        } else {
                            None
                        },
                        given_up: fin.then_some(t.given_up),
                        cancelled: fin.then_some(t.cancelled),
                    }),
                );
            }
        }
        if std::mem::take(&mut queue_changed) && events.wants_detail() {
            events.emit(
                &time,
                &me,
                EventKind::Queue {
                    targets: queue(&cmd),
                },
            );
        }
        let done = !waiting && cmd.is_finished() && (!cfg.keep_running || ops.is_none());
        if interrupted.is_some() || done {
            break;
        }
        let to_real = |t: Instant| {
            tokio::time::Instant::now() + time.real(t.saturating_duration_since(time.now()))
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
                let now = time.now();
                events.emit(&time, &me, EventKind::Broadcast((&b).into()));
                if let Some(c) = live.as_mut().and_then(|l| l.heard(b.robot(), now)) {
                    life_event(&events, &time, &me, &c);
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
                let now = time.now();
                match op {
                    None => ops = None,
                    Some(Operator::Cancel(colour)) => {
                        if !cmd.cancel(&colour, now) {
                            events.emit(&time, &me, EventKind::Operator {
                                error: format!("no open target {colour:?} to cancel"),
                            });
                        }
                    }
                    Some(Operator::Stop(reason)) => {
                        cmd.fleet_stop(&reason);
                        events.emit(&time, &me, EventKind::Fleet { command: "stop".into(), reason: Some(reason) });
                    }
                    Some(Operator::Add(colour)) => {
                        // Before the robots are heard it only queues (`start` sends it).
                        if let Err(e) = cmd.add(&colour, now) {
                            events.emit(&time, &me, EventKind::Operator {
                                error: format!("target {colour} not added: {e}"),
                            });
                        }
                    }
                    Some(Operator::Move { from, to }) => {
                        if let Err(e) = cmd.move_target(from, to) {
                            events.emit(&time, &me, EventKind::Operator {
                                error: format!("cannot move the target: {e}"),
                            });
                        }
                        // `shown` follows the series' order from now on.
                        shown = cmd.targets().iter().map(|t| (t.state, t.cancelled)).collect();
                        queue_changed = true;
                    }
                    Some(Operator::Resume) => {
                        cmd.fleet_resume();
                        events.emit(&time, &me, EventKind::Fleet { command: "resume".into(), reason: None });
                    }
                    Some(Operator::Quit { stop }) => {
                        if stop {
                            cmd.fleet_stop("the commander was interrupted");
                            events.emit(&time, &me, EventKind::Fleet { command: "stop".into(), reason: Some("interrupted".into()) });
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
                let now = time.now();
                if waiting && tokio::time::Instant::now() >= wait_deadline {
                    events.emit(&time, &me, EventKind::Waiting(Waiting::GaveUpOn(
                        missing.iter().map(|s| (*s).clone()).collect(),
                    )));
                    waiting = false;
                    cmd.start(now);
                }
                cmd.handle_timeout(now);
                for c in live.as_mut().map(|l| l.handle_timeout(now)).unwrap_or_default() {
                    life_event(&events, &time, &me, &c);
                }
            }
            _ = check.tick() => {
                if let Some(a) = bus.take_auth_report() {
                    events.emit(&time, &me, EventKind::AuthFailure(a.to_string()));
                }
                if events.wants_detail() {
                    events.emit(&time, &me, EventKind::PeerStatus(Box::new(PeerStatus {
                        broadcast: Some(bus.channel().stats()),
                        ..PeerStatus::default()
                    })));
                }
            }
        }
    }
    let secs = |i: Option<Instant>| i.map(Instant::as_secs_f64);
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
            sent: t.sent_at.is_some(),
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

/// The whole series for [`EventKind::Queue`].
fn queue(cmd: &Commander) -> Vec<QueueEntry> {
    let secs = |i: Option<Instant>| i.map(Instant::as_secs_f64);
    cmd.targets()
        .iter()
        .enumerate()
        .map(|(i, t)| QueueEntry {
            index: i,
            target: t.colour.clone(),
            state: t.state.as_str().to_owned(),
            sent_s: secs(t.sent_at),
            accepted_s: secs(t.accepted_at),
            ended_s: secs(t.finished_at),
            time_s: t.duration().map(|d| d.as_secs_f64()),
            cancelled: t.cancelled,
            given_up: t.given_up,
            sends: t.sends,
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mission::msg::{Broadcast, MissionEvent};
    use crate::peer::net::{BroadcastMode, PeerNetConfig};
    use crate::peer::wire::GroupKey;
    use crate::runtime::EventReceiver;

    fn udp_port() -> u16 {
        std::net::UdpSocket::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port()
    }

    fn net(robot: &str, port: u16, peer: u16) -> PeerNetConfig {
        let mut c = PeerNetConfig::loopback(robot);
        c.broadcast.mode = BroadcastMode::Unicast;
        c.broadcast.bind = "127.0.0.1".into();
        c.broadcast.port = port;
        c.broadcast.bind_port = Some(port);
        c.broadcast.peers = vec![format!("127.0.0.1:{peer}")];
        c
    }

    /// The next `Queue` event's colours and states.
    async fn next_queue(rx: &mut EventReceiver) -> Vec<(String, String)> {
        loop {
            let e = tokio::time::timeout(Duration::from_secs(20), rx.recv())
                .await
                .expect("no queue event in 20 s")
                .expect("events closed");
            if let EventKind::Queue { targets } = e.kind {
                return targets.into_iter().map(|t| (t.target, t.state)).collect();
            }
        }
    }

    fn q(list: &[(&str, &str)]) -> Vec<(String, String)> {
        list.iter()
            .map(|(a, b)| ((*a).to_owned(), (*b).to_owned()))
            .collect()
    }

    #[tokio::test]
    async fn the_operator_adds_and_moves_targets_and_a_kept_commander_waits_for_more() {
        let key = GroupKey::new(b"a test group key, 16+").unwrap();
        let (pc, ps) = (udp_port(), udp_port());
        let clock = ima_hal::time::TokioClock::shared();
        let bus = Bus::bind(&net("commander", pc, ps), key.clone(), clock.clone()).unwrap();
        let skeeter = Bus::bind(&net("skeeter", ps, pc), key, clock.clone()).unwrap();
        let (events, mut rx) = Events::channel(1024);
        let cfg = CommanderRuntimeConfig {
            core: CommanderConfig::default(),
            time_scale: 1.0,
            lost_after: None,
            wait_for: Vec::new(),
            wait_timeout: Duration::from_secs(1),
            keep_running: true,
        };
        let (ops, ops_rx) = tokio::sync::mpsc::unbounded_channel();
        let events = events.detailed(true);
        let run = tokio::spawn(async move {
            run(cfg, &["red".to_owned()], bus, clock, events, Some(ops_rx)).await
        });
        assert_eq!(next_queue(&mut rx).await, q(&[("red", "sent")]));
        ops.send(Operator::Add("blue".into())).unwrap();
        assert_eq!(
            next_queue(&mut rx).await,
            q(&[("red", "sent"), ("blue", "waiting")])
        );
        ops.send(Operator::Add("green".into())).unwrap();
        let _ = next_queue(&mut rx).await;
        ops.send(Operator::Move { from: 2, to: 1 }).unwrap();
        assert_eq!(
            next_queue(&mut rx).await,
            q(&[("red", "sent"), ("green", "waiting"), ("blue", "waiting")])
        );
        // A move of a sent target is refused with a message.
        ops.send(Operator::Move { from: 0, to: 2 }).unwrap();
        let err = loop {
            let e = rx.recv().await.unwrap();
            if let EventKind::Operator { error } = e.kind {
                break error;
            }
        };
        assert!(err.contains("only waiting targets move"), "{err}");
        let said = |c: &str| Broadcast::Mission {
            robot: "skeeter".into(),
            event: MissionEvent::Accomplished,
            target: c.into(),
        };
        for c in ["red", "green", "blue"] {
            // Until the commander hears it (UDP), say it again on every queue change seen.
            loop {
                skeeter.send(&said(c)).await;
                let s = next_queue(&mut rx).await;
                if s.iter().any(|(t, st)| t == c && st == "done") {
                    break;
                }
            }
        }
        // Every target is done, yet the commander keeps running for more.
        tokio::time::sleep(Duration::from_millis(200)).await;
        assert!(!run.is_finished());
        ops.send(Operator::Quit { stop: false }).unwrap();
        let f = tokio::time::timeout(Duration::from_secs(20), run)
            .await
            .unwrap()
            .unwrap()
            .unwrap();
        let order: Vec<_> = f.outcomes.iter().map(|o| o.target.as_str()).collect();
        assert_eq!(order, ["red", "green", "blue"]);
        assert!(f.outcomes.iter().all(|o| o.state == TargetState::Done));
    }

    #[test]
    fn detail_is_off_unless_asked_for() {
        let (e, _rx) = Events::channel(4);
        assert!(!e.wants_detail());
        assert!(e.detailed(true).wants_detail());
        assert!(!Events::log_only().detailed(true).wants_detail());
    }
}

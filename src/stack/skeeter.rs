//! Skeeter's stack: continuous sweeps of the camera head with the Scan node
//! ([`ima_agents::mission::scan`]) over the video switcher and the frame source, each sweep's
//! SES published as the Peer Agent source `ses` on Skeeter's manager, and the mission logic
//! on the broadcast channel ([`SkeeterMission`]).

use std::time::Duration;

use anyhow::{Context, Result};
use ima_agents::mission::msg::{
    Broadcast, COMMANDER, Emergency, MissionEvent, SCOOTER_TAG, SES_SOURCE, SES_SOURCE_KIND,
    SES_SOURCE_SCHEMA,
};
use ima_agents::mission::scan::{ScanConfig, ScanReport, Scanner, run_scan};
use ima_agents::mission::vision::{ColourDb, ColourSpec, HeadGeometry};
use ima_agents::peer::manager::FixedSelfAgent;
use ima_agents::peer::net::spawn_manager;
use ima_agents::peer::wire::{GroupKey, SourceInfo};
use ima_hal::Instant;
use ima_hal::base::DifferentialBase;
use serde_json::json;
use tokio::sync::watch;

use super::devices::SkeeterDevices;
use super::net::{Bus, net_config};
use super::{Events, MissionClock};
use crate::config::RobotConfig;

/// Sweeps in a row without Scooter before the stress call `scooter-lost`.
pub const LOST_AFTER_SWEEPS: u32 = 2;
/// Sweeps in a row without the target before Skeeter asks Scooter (`target-query`).
pub const QUERY_AFTER_SWEEPS: u32 = 2;

/// Skeeter's mission logic (sans-IO): targets from the commander, scan reports, Scooter's
/// broadcasts in; broadcasts out. Time is the mission clock.
#[derive(Debug)]
pub struct SkeeterMission {
    robot: String,
    timeout: Duration,
    target: Option<Target>,
    scooter_missing: u32,
    scooter_lost: bool,
    outbox: Vec<Broadcast>,
}

#[derive(Debug, Clone)]
struct Target {
    colour: String,
    since: Instant,
    missing: u32,
    queried: bool,
}

impl SkeeterMission {
    /// The logic of robot `robot`; a target fails after `timeout`.
    pub fn new(robot: &str, timeout: Duration) -> Self {
        Self {
            robot: robot.to_owned(),
            timeout,
            target: None,
            scooter_missing: 0,
            scooter_lost: false,
            outbox: Vec::new(),
        }
    }

    /// The current target.
    pub fn target(&self) -> Option<&str> {
        self.target.as_ref().map(|t| t.colour.as_str())
    }

    /// The running behaviour (for status broadcasts).
    pub fn behaviour(&self) -> &'static str {
        match &self.target {
            None => "idle",
            Some(_) if self.scooter_lost => "call-scooter-back",
            Some(t) if t.queried => "ask-scooter",
            Some(_) => "share-ses",
        }
    }

    fn say(&mut self, b: Broadcast) {
        self.outbox.push(b);
    }

    fn end(&mut self, event: MissionEvent) {
        if let Some(t) = self.target.take() {
            let b = Broadcast::mission(&self.robot, event, &t.colour);
            self.say(b);
        }
    }

    /// A broadcast heard.
    pub fn handle_broadcast(&mut self, b: &Broadcast, now: Instant) {
        match b {
            Broadcast::Mission {
                robot,
                event: MissionEvent::Accepted,
                target,
            } if robot == COMMANDER => match &self.target {
                // A repeat of the current target: confirm again.
                Some(t) if &t.colour == target => {
                    let b = Broadcast::mission(&self.robot, MissionEvent::Accepted, target);
                    self.say(b);
                }
                Some(_) => {} // one target at a time; the commander waits
                None => {
                    self.target = Some(Target {
                        colour: target.clone(),
                        since: now,
                        missing: 0,
                        queried: false,
                    });
                    let b = Broadcast::mission(&self.robot, MissionEvent::Accepted, target);
                    self.say(b);
                }
            },
            Broadcast::Emergency {
                emergency: Emergency::TargetReached { colour },
                ..
            } if self.target() == Some(colour.as_str()) => {
                self.end(MissionEvent::Accomplished);
            }
            Broadcast::Emergency {
                emergency: Emergency::TargetReply { colour, seen },
                ..
            } if self.target() == Some(colour.as_str()) => {
                if let Some(t) = &mut self.target
                    && t.missing >= QUERY_AFTER_SWEEPS
                {
                    if *seen {
                        // Scooter sees it: keep going, ask again later.
                        t.queried = false;
                        t.missing = 0;
                    } else {
                        // Neither sees the target.
                        self.end(MissionEvent::Failed);
                    }
                }
            }
            _ => {}
        }
    }

    /// A full sweep's report.
    pub fn handle_scan(&mut self, report: &ScanReport, now: Instant) {
        if report.sees(SCOOTER_TAG) {
            self.scooter_missing = 0;
            if self.scooter_lost {
                self.scooter_lost = false;
                let b = Broadcast::emergency(&self.robot, Emergency::ScooterFound);
                self.say(b);
            }
        } else {
            self.scooter_missing = self.scooter_missing.saturating_add(1);
            if self.target.is_some()
                && !self.scooter_lost
                && self.scooter_missing >= LOST_AFTER_SWEEPS
            {
                self.scooter_lost = true;
                let b = Broadcast::emergency(&self.robot, Emergency::ScooterLost);
                self.say(b);
            }
        }
        let mut query = None;
        if let Some(t) = &mut self.target {
            if report.sees(&t.colour) {
                t.missing = 0;
                t.queried = false;
            } else {
                t.missing = t.missing.saturating_add(1);
                if t.missing >= QUERY_AFTER_SWEEPS && !t.queried {
                    t.queried = true;
                    query = Some(t.colour.clone());
                }
            }
        }
        if let Some(colour) = query {
            let b = Broadcast::emergency(&self.robot, Emergency::TargetQuery { colour });
            self.say(b);
        }
        self.handle_timeout(now);
    }

    /// Time passes: a target older than the timeout fails.
    pub fn handle_timeout(&mut self, now: Instant) {
        if let Some(t) = &self.target
            && now.saturating_duration_since(t.since) >= self.timeout
        {
            self.end(MissionEvent::Failed);
        }
    }

    /// Broadcasts to send, oldest first.
    pub fn take_outbox(&mut self) -> Vec<Broadcast> {
        std::mem::take(&mut self.outbox)
    }
}

/// The colour database of the configuration (the built-in one when empty).
pub fn colour_db(cfg: &RobotConfig) -> Result<ColourDb> {
    if cfg.agent.colours.is_empty() {
        return Ok(ColourDb::default());
    }
    let mut colours: Vec<ColourSpec> = cfg
        .agent
        .colours
        .iter()
        .map(|c| ColourSpec::new(&c.name, c.rgb, c.diameter_m))
        .collect();
    if !colours.iter().any(|c| c.name == SCOOTER_TAG) {
        let d = ColourDb::default();
        colours.extend(d.colours.into_iter().filter(|c| c.name == SCOOTER_TAG));
    }
    ColourDb::new(colours).map_err(|e| anyhow::anyhow!("agent.colours: {e:?}"))
}

async fn flush(
    mission: &mut SkeeterMission,
    bus: &Bus,
    events: &Events,
    clock: &MissionClock,
    me: &str,
) {
    for b in mission.take_outbox() {
        events.emit(clock, me, "say", json!(b.to_string()));
        // Mission events and emergencies must not be lost: three copies (receivers are
        // idempotent).
        let times = if matches!(b, Broadcast::Status { .. }) {
            1
        } else {
            3
        };
        bus.send_repeated(&b, times, Duration::from_millis(30)).await;
    }
}

/// Run Skeeter until `stop` turns true.
pub async fn run(
    cfg: RobotConfig,
    key: GroupKey,
    dev: SkeeterDevices,
    events: Events,
    mut stop: watch::Receiver<bool>,
) -> Result<()> {
    let clock = MissionClock::new(cfg.agent.time_scale);
    let scale = cfg.agent.time_scale;
    let me = cfg.robot.clone();
    let SkeeterDevices {
        mut base,
        mut mux,
        mut frames,
    } = dev;
    // Skeeter does not move: make sure its base is stopped.
    let _ = base.stop().await;
    let bus = Bus::bind(&cfg, key.clone())?;
    let net = net_config(&cfg)?;
    let manager = spawn_manager(&net, key, FixedSelfAgent::default())
        .await
        .map_err(|e| anyhow::anyhow!("{e}"))
        .context("starting Skeeter's Peer Agent manager")?;
    let ses = manager.publisher(SourceInfo {
        name: SES_SOURCE.to_owned(),
        kind: SES_SOURCE_KIND.to_owned(),
        schema: SES_SOURCE_SCHEMA,
        rate_mhz: 300,
    });
    events.emit(
        &clock,
        &me,
        "connected",
        json!({"manager": manager.local_addr().to_string()}),
    );
    // The Scan node runs in mission time: its settle and step times are scaled so that, in
    // real time, they are what the hardware needs.
    let mux_settle = ima_hal::camera::CameraMux::settle_time(&mux);
    let mut scan_cfg = ScanConfig {
        robot: me.clone(),
        ..ScanConfig::default()
    };
    if let Some(m) = &cfg.devices.video_mux {
        scan_cfg.head = HeadGeometry {
            cameras: m.cameras,
            fov_deg: m.fov_deg,
            first_yaw_deg: 0.0,
        };
    }
    scan_cfg.settle = scan_cfg.settle.max(mux_settle).mul_f64(scale.max(1.0));
    scan_cfg.step_timeout = scan_cfg.step_timeout.mul_f64(scale);
    let mut scanner = Scanner::with_default_ses(scan_cfg, colour_db(&cfg)?)
        .map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let mut mission = SkeeterMission::new(
        &me,
        Duration::from_secs_f64(cfg.agent.target_timeout_s),
    );
    let (heard_tx, mut heard_rx) = tokio::sync::mpsc::channel::<Broadcast>(64);
    let bus_rx = bus.clone();
    let rx_task = tokio::spawn(async move {
        while let Ok(b) = bus_rx.recv().await {
            if heard_tx.send(b).await.is_err() {
                return;
            }
        }
    });
    let mut last_status = None::<Instant>;
    let result: Result<()> = loop {
        if *stop.borrow() {
            break Ok(());
        }
        // One sweep; broadcasts heard meanwhile are handled at once.
        let sweep = run_scan(
            &mut scanner,
            &mut mux,
            &mut frames,
            |d| tokio::time::sleep(d.div_f64(scale)),
            || clock.now(),
        );
        tokio::pin!(sweep);
        let report = loop {
            tokio::select! {
                r = &mut sweep => break Some(r),
                Some(b) = heard_rx.recv() => {
                    events.emit(&clock, &me, "heard", json!(b.to_string()));
                    mission.handle_broadcast(&b, clock.now());
                    flush(&mut mission, &bus, &events, &clock, &me).await;
                }
                _ = stop.changed() => break None,
            }
        };
        let Some(report) = report else {
            break Ok(());
        };
        let now = clock.now();
        if let Some(report) = report {
            match report.shared.to_bytes() {
                Ok(bytes) => {
                    if let Err(e) = ses.publish(now.as_micros(), &bytes) {
                        tracing::warn!("publishing the SES: {e}");
                    }
                }
                Err(e) => tracing::warn!("encoding the SES: {e:?}"),
            }
            events.emit(
                &clock,
                &me,
                "scan",
                json!({
                    "seen": report.detections.iter().map(|d| d.tag().to_owned()).collect::<Vec<_>>(),
                    "cameras_ok": report.cameras_ok,
                    "cameras_failed": report.cameras_failed,
                }),
            );
            mission.handle_scan(&report, now);
        } else {
            mission.handle_timeout(now);
        }
        flush(&mut mission, &bus, &events, &clock, &me).await;
        if last_status.is_none_or(|t| now.saturating_duration_since(t) >= Duration::from_secs(2))
        {
            last_status = Some(now);
            let target = mission.target().unwrap_or("-").to_owned();
            bus.send(&Broadcast::status(
                &me,
                mission.behaviour(),
                &format!("target {target}"),
                None,
            ))
            .await;
        }
    };
    rx_task.abort();
    manager.shutdown().await;
    result
}

#[cfg(test)]
mod tests {
    use super::*;

    fn t(s: u64) -> Instant {
        Instant::from_millis(s * 1000)
    }

    #[test]
    fn accepts_confirms_repeats_and_accomplishes() {
        let mut m = SkeeterMission::new("skeeter", Duration::from_secs(100));
        m.handle_broadcast(&Broadcast::new_target("red"), t(1));
        let out = m.take_outbox();
        assert_eq!(
            out,
            vec![Broadcast::mission("skeeter", MissionEvent::Accepted, "red")]
        );
        // A repeat is confirmed again; another colour waits.
        m.handle_broadcast(&Broadcast::new_target("red"), t(2));
        m.handle_broadcast(&Broadcast::new_target("blue"), t(2));
        assert_eq!(m.take_outbox().len(), 1);
        assert_eq!(m.target(), Some("red"));
        m.handle_broadcast(
            &Broadcast::emergency(
                "scooter",
                Emergency::TargetReached {
                    colour: "red".into(),
                },
            ),
            t(3),
        );
        assert_eq!(
            m.take_outbox(),
            vec![Broadcast::mission(
                "skeeter",
                MissionEvent::Accomplished,
                "red"
            )]
        );
        assert_eq!(m.target(), None);
    }

    #[test]
    fn times_out() {
        let mut m = SkeeterMission::new("skeeter", Duration::from_secs(10));
        m.handle_broadcast(&Broadcast::new_target("red"), t(1));
        m.take_outbox();
        m.handle_timeout(t(5));
        assert!(m.take_outbox().is_empty());
        m.handle_timeout(t(11));
        assert_eq!(
            m.take_outbox(),
            vec![Broadcast::mission("skeeter", MissionEvent::Failed, "red")]
        );
    }

    #[test]
    fn target_not_seen_asks_scooter_and_fails_if_neither_sees_it() {
        let mut m = SkeeterMission::new("skeeter", Duration::from_secs(100));
        m.handle_broadcast(&Broadcast::new_target("red"), t(1));
        m.take_outbox();
        let empty = ScanReport {
            started: t(1),
            finished: t(2),
            detections: Vec::new(),
            cameras_ok: 7,
            cameras_failed: 0,
            shared: ima_agents::ses::shared::SharedForm {
                source_robot: "skeeter".into(),
                sent_at: t(2),
                records: Vec::new(),
            },
        };
        m.handle_scan(&empty, t(2));
        m.handle_scan(&empty, t(3));
        let out = m.take_outbox();
        assert!(out.contains(&Broadcast::emergency(
            "skeeter",
            Emergency::TargetQuery {
                colour: "red".into()
            }
        )));
        // Scooter was not seen either: the stress call.
        assert!(out.contains(&Broadcast::emergency("skeeter", Emergency::ScooterLost)));
        m.handle_broadcast(
            &Broadcast::emergency(
                "scooter",
                Emergency::TargetReply {
                    colour: "red".into(),
                    seen: false,
                },
            ),
            t(4),
        );
        assert_eq!(
            m.take_outbox(),
            vec![Broadcast::mission("skeeter", MissionEvent::Failed, "red")]
        );
    }
}

//! Skeeter's stack: [`SkeeterBrain`] (its SAN) fed by the broadcast channel, by the Scan
//! node's sweeps ([`ima_agents::mission::scan`] over the video switcher and the frame
//! source, run in their own task) and by its Peer Agent manager's grants of the `ses`
//! source; the brain's outputs go to the broadcast channel, to the scanner and to the `ses`
//! source's publisher.

use std::time::Duration;

use anyhow::{Context, Result};
use ima_agents::mission::msg::{
    Broadcast, Emergency, SCOOTER_TAG, SES_SOURCE, SES_SOURCE_KIND, SES_SOURCE_SCHEMA,
};
use ima_agents::mission::scan::{ScanConfig, ScanReport, Scanner, run_scan};
use ima_agents::mission::skeeter::{SkeeterBrain, SkeeterConfig, SkeeterOutput};
use ima_agents::mission::vision::{ColourDb, ColourSpec, HeadGeometry};
use ima_agents::peer::manager::{FixedSelfAgent, ManagerEvent, Outcome};
use ima_agents::peer::net::{ManagerNetEvent, spawn_manager};
use ima_agents::peer::wire::{GroupKey, SourceInfo};
use ima_hal::base::DifferentialBase;
use serde_json::json;
use tokio::sync::{mpsc, watch};

use super::devices::SkeeterDevices;
use super::net::{Bus, net_config};
use super::{Events, MissionClock};
use crate::config::RobotConfig;

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

/// How often (mission time) the web console's detail is reported.
const DETAIL_EVERY: Duration = Duration::from_secs(1);

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
    let mut grants = manager.events();
    let ses = manager
        .publisher(SourceInfo {
            name: SES_SOURCE.to_owned(),
            kind: SES_SOURCE_KIND.to_owned(),
            schema: SES_SOURCE_SCHEMA,
            rate_mhz: 300,
        })
        .map_err(|e| anyhow::anyhow!("{e}"))
        .context("registering Skeeter's `ses` source")?;
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
    // The scanner task: one sweep per request.
    let (scan_req_tx, mut scan_req_rx) = mpsc::channel::<()>(1);
    let (report_tx, mut report_rx) = mpsc::channel::<Option<ScanReport>>(1);
    let scan_task = tokio::spawn(async move {
        while scan_req_rx.recv().await.is_some() {
            let r = run_scan(
                &mut scanner,
                &mut mux,
                &mut frames,
                |d| tokio::time::sleep(d.div_f64(scale)),
                || clock.now(),
            )
            .await;
            if report_tx.send(r).await.is_err() {
                return;
            }
        }
    });
    let mut brain_cfg = SkeeterConfig {
        robot: me.clone(),
        target_timeout: Duration::from_secs_f64(cfg.agent.target_timeout_s),
        stress_repeat: Duration::from_secs(10),
        ..SkeeterConfig::default()
    };
    if let Some(path) = &cfg.agent.network {
        brain_cfg.network = std::fs::read_to_string(path)
            .with_context(|| format!("reading the SAN network {}", path.display()))?;
    }
    let mut brain =
        SkeeterBrain::new(brain_cfg).map_err(|e| anyhow::anyhow!("Skeeter's SAN: {e:?}"))?;
    let (mut heard_rx, rx_task) = bus.spawn_reader();
    brain.start(clock.now());
    let mut last_behaviour = String::new();
    let mut last_detail: Option<ima_hal::Instant> = None; // web console (issue 17)
    // A fleet stop was heard (reported once; Skeeter's base is held stopped anyway).
    let mut fleet_stopped = false;
    let result: Result<()> = loop {
        // Carry out the brain's outputs.
        while let Some(out) = brain.poll_output() {
            match out {
                SkeeterOutput::Broadcast(b) => {
                    let status = matches!(b, Broadcast::Status { .. });
                    if !status {
                        events.emit(&clock, &me, "say", json!(b.to_string()));
                    }
                    bus.say(&b).await;
                }
                SkeeterOutput::StartScan => {
                    let _ = scan_req_tx.try_send(());
                }
                SkeeterOutput::PublishSes(form) => match form.to_bytes() {
                    // web console (issue 17): the SES as Skeeter publishes it.
                    Ok(bytes) if events.wants_detail() => {
                        events.emit(&clock, &me, "ses-form", crate::web::feed::ses_json(&form));
                        if let Err(e) = ses.publish(clock.now().as_micros(), &bytes) {
                            tracing::warn!("publishing the SES: {e}");
                        }
                    }
                    Ok(bytes) => {
                        if let Err(e) = ses.publish(clock.now().as_micros(), &bytes) {
                            tracing::warn!("publishing the SES: {e}");
                        }
                    }
                    Err(e) => tracing::warn!("encoding the SES: {e:?}"),
                },
            }
        }
        let b = brain.behaviour().to_owned();
        if b != last_behaviour {
            events.emit(&clock, &me, "behaviour", json!(b));
            last_behaviour = b;
        }
        // web console (issue 17): SAN activations and the manager's status, once a second.
        if events.wants_detail()
            && last_detail.is_none_or(|t| clock.now().saturating_duration_since(t) >= DETAIL_EVERY)
        {
            last_detail = Some(clock.now());
            let san = crate::web::feed::san_json(brain.network(), brain.behaviour());
            events.emit(&clock, &me, "san", san);
            if let (Ok(stats), Ok(clients)) = (manager.stats().await, manager.status().await) {
                let mut v = crate::web::feed::manager_json(&stats, &clients);
                v["broadcast"] = crate::web::feed::bus_json(&bus.stats());
                v["address"] = json!(manager.local_addr().to_string());
                events.emit(&clock, &me, "peer-status", v);
            }
        }
        let wake = brain.poll_timeout().map(|t| {
            let wait = t.saturating_duration_since(clock.now());
            tokio::time::Instant::now() + clock.real(wait)
        });
        tokio::select! {
            Some(report) = report_rx.recv() => {
                let now = clock.now();
                match report {
                    Some(report) => {
                        events.emit(
                            &clock,
                            &me,
                            "scan",
                            json!({
                                "seen": report.detections.iter().map(|d| d.tag().to_owned()).collect::<Vec<_>>(),
                                "scooter": report.sees(SCOOTER_TAG),
                                "cameras_ok": report.cameras_ok,
                                "cameras_failed": report.cameras_failed,
                            }),
                        );
                        brain.handle_scan(&report, now);
                    }
                    None => brain.handle_timeout(now),
                }
            }
            Some(b) = heard_rx.recv() => {
                events.emit(&clock, &me, "heard", json!(b.to_string()));
                match &b {
                    Broadcast::Emergency { robot, emergency: Emergency::FleetStop { reason } } => {
                        // Skeeter does not drive, but a fleet stop is obeyed by every base
                        // (each copy: stopping twice is harmless).
                        if let Err(e) = base.stop().await {
                            tracing::warn!("base: {e:?}");
                        }
                        if !fleet_stopped {
                            fleet_stopped = true;
                            events.emit(&clock, &me, "fleet-stop", json!({"by": robot, "reason": reason}));
                        }
                    }
                    Broadcast::Emergency { robot, emergency: Emergency::FleetResume } if fleet_stopped => {
                        fleet_stopped = false;
                        events.emit(&clock, &me, "fleet-resume", json!({"by": robot}));
                    }
                    _ => {}
                }
                brain.handle_broadcast(&b, clock.now());
            }
            ev = grants.recv() => match ev {
                Ok(ManagerNetEvent::Core(ManagerEvent::Decision(d)))
                    if d.source == SES_SOURCE && d.outcome == Outcome::Granted =>
                {
                    events.emit(&clock, &me, "peer", json!({"granted": SES_SOURCE, "to": d.robot}));
                    brain.handle_heading_request(clock.now());
                }
                Ok(_) => {}
                // Some manager events were missed: a grant may be among them, so answer as if.
                Err(tokio::sync::broadcast::error::RecvError::Lagged(n)) => {
                    tracing::warn!("missed {n} Peer Agent manager events");
                    brain.handle_heading_request(clock.now());
                }
                Err(tokio::sync::broadcast::error::RecvError::Closed) => {
                    break Err(anyhow::anyhow!("Skeeter's Peer Agent manager stopped"));
                }
            },
            () = async {
                match wake {
                    Some(w) => tokio::time::sleep_until(w).await,
                    None => std::future::pending().await,
                }
            } => brain.handle_timeout(clock.now()),
            r = stop.changed() => {
                if r.is_err() || *stop.borrow() {
                    break Ok(());
                }
            }
        }
    };
    scan_task.abort();
    rx_task.abort();
    manager.shutdown().await;
    result
}

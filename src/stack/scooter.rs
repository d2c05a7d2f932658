//! Scooter's stack: sensor loops (odometry, compass, laser) feeding [`ScooterBrain`] stepped
//! at `agent.control_hz`, velocity commands to the rFLEX base, a Peer Agent client
//! requesting Skeeter's `ses` source (reconnecting and retrying), its own manager, and the
//! broadcast channel.

use std::time::Duration;

use anyhow::Result;
use ima_agents::mission::msg::{Broadcast, Emergency, SES_SOURCE};
use ima_agents::mission::scooter::{
    HeadingRule, HeadingSource, ScooterBrain, ScooterConfig, ScooterHeard, ScooterSay,
};
use ima_agents::peer::manager::FixedSelfAgent;
use ima_agents::peer::net::{PeerClientHandle, SubscriptionEvent, spawn_manager};
use ima_agents::peer::wire::GroupKey;
use ima_agents::ses::shared::SharedForm;
use ima_hal::base::{DifferentialBase, VelocityCommand};
use ima_hal::laser::{LaserScan, LaserScanner};
use ima_hal::normalize_angle;
use serde_json::json;
use tokio::sync::{mpsc, watch};

use super::devices::ScooterDevices;
use super::net::{Bus, net_config};
use super::{Events, MissionClock};
use crate::config::{self, RobotConfig};

/// The behaviour a robot's status shows while a fleet stop holds it.
pub const FLEET_STOPPED: &str = "fleet-stopped";

/// The brain's configuration from the robot's.
pub fn brain_config(cfg: &RobotConfig, odometry_offset_rad: f64) -> ScooterConfig {
    let a = &cfg.agent;
    ScooterConfig {
        robot_name: cfg.robot.clone(),
        heading_rule: match a.heading_rule {
            config::HeadingRule::Thesis => HeadingRule::Thesis,
            config::HeadingRule::RangeAware => HeadingRule::RangeAware,
        },
        heading_source: match a.heading_source {
            config::HeadingSource::Compass => HeadingSource::Compass,
            config::HeadingSource::Odometry => HeadingSource::Odometry,
            config::HeadingSource::Both => HeadingSource::Fused,
        },
        cruise_speed_m_s: a.cruise_speed_m_s,
        max_turn_rate_rad_s: a.max_turn_rad_s,
        lost_after: Duration::from_secs_f64(a.lost_timeout_s),
        reach_distance_m: a.reach_distance_m,
        // A negative tolerance accepts no laser cluster as Skeeter: the laser fix is off.
        skeeter_diameter_tolerance_m: if a.laser_ranges_skeeter {
            ScooterConfig::default().skeeter_diameter_tolerance_m
        } else {
            -1.0
        },
        see_distance_m: ScooterConfig::default()
            .see_distance_m
            .max(a.reach_distance_m + 0.6),
        odometry_heading_offset_rad: odometry_offset_rad,
        ..ScooterConfig::default()
    }
}

/// The compass heading in the common frame (radians, counter-clockwise).
/// The configured installation deviation (degrees east) is added to the compass heading.
fn common_heading(h: &ima_hal::compass::Heading, cfg: &RobotConfig) -> f64 {
    let common_yaw = normalize_angle((90.0 - cfg.agent.common_heading_deg).to_radians());
    let deviation = cfg
        .devices
        .compass
        .as_ref()
        .map_or(0.0, |c| c.deviation_deg.to_radians());
    normalize_angle(h.yaw_enu_rad() - deviation - common_yaw)
}

/// How often (mission time) the web console's detail is reported.
const DETAIL_EVERY: Duration = Duration::from_millis(500);

/// Run Scooter until `stop` turns true (or a fatal error).
pub async fn run(
    cfg: RobotConfig,
    key: GroupKey,
    dev: ScooterDevices,
    events: Events,
    mut stop: watch::Receiver<bool>,
) -> Result<()> {
    let clock = MissionClock::new(cfg.agent.time_scale);
    let me = cfg.robot.clone();
    let ScooterDevices {
        mut base,
        laser,
        compass,
    } = dev;
    // Odometry heading offset: the compass gives Scooter's common-frame heading at start.
    let start_heading = match &compass {
        Some(c) => c.latest().map(|h| common_heading(&h.value.heading, &cfg)),
        None => None,
    };
    let start_heading = start_heading
        .or(cfg.agent.initial_heading_deg.map(f64::to_radians))
        .unwrap_or(0.0);
    let odo_theta = base.latest_odometry().map_or(0.0, |o| o.value.theta_rad());
    let mut brain = ScooterBrain::new(brain_config(
        &cfg,
        normalize_angle(start_heading - odo_theta),
    ));
    events.emit(
        &clock,
        &me,
        "connected",
        json!({"start_heading_deg": start_heading.to_degrees()}),
    );

    let bus = Bus::bind(&cfg, key.clone())?;
    // Scooter's own manager (no sources of its own yet beyond the competency list).
    let net = net_config(&cfg)?;
    let _manager = if cfg.peer.listen.is_empty() {
        None
    } else {
        Some(
            spawn_manager(&net, key.clone(), FixedSelfAgent::default())
                .await
                .map_err(|e| anyhow::anyhow!("starting Scooter's manager: {e}"))?,
        )
    };

    // Laser: latest scan in a watch channel.
    let (scan_tx, mut scan_rx) = watch::channel::<Option<LaserScan>>(None);
    let laser_task = tokio::spawn({
        let mut laser = laser.clone();
        async move {
            let mut after = laser.now();
            loop {
                match laser.next_scan(after).await {
                    Ok(s) => {
                        after = s.at;
                        if scan_tx.send(Some(s.value)).is_err() {
                            return;
                        }
                    }
                    Err(e) => {
                        tracing::warn!("laser: {e:?}");
                        tokio::time::sleep(Duration::from_millis(200)).await;
                    }
                }
            }
        }
    });

    // SES subscription with reconnect/retry.
    let (ses_tx, mut ses_rx) = mpsc::channel::<SharedForm>(8);
    let (rerequest_tx, rerequest_rx) = mpsc::channel::<()>(1);
    let ses_task = tokio::spawn(ses_loop(
        rerequest_rx,
        cfg.clone(),
        net.clone(),
        key,
        ses_tx,
        events.clone(),
        clock,
    ));

    // Broadcasts.
    let (mut heard_rx, rx_task) = bus.spawn_reader();

    // The brain steps at control_hz of mission time (at most 50 Hz real).
    let period = Duration::from_secs_f64(1.0 / (cfg.agent.control_hz * cfg.agent.time_scale))
        .max(Duration::from_millis(20));
    let mut tick = tokio::time::interval(period);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut last_behaviour = String::new();
    let mut last_detail: Option<ima_hal::Instant> = None; // web console (issue 17)
    let mut last_ses: Option<(ima_hal::Instant, SharedForm)> = None;
    let mut reached: Option<String> = None;
    let mut last_control: Option<ima_hal::Instant> = None;
    let lost_after = Duration::from_secs_f64(cfg.agent.lost_timeout_s);
    let mut last_odo_at = None;
    let mut last_compass_at = None;
    // A fleet stop holds the base at zero until a fleet resume or a new target.
    let mut halted = false;
    let result = loop {
        tokio::select! {
            _ = tick.tick() => {}
            r = stop.changed() => {
                if r.is_err() || *stop.borrow() {
                    break Ok(());
                }
                continue;
            }
        }
        let now = clock.now();
        while let Ok(b) = heard_rx.try_recv() {
            events.emit(&clock, &me, "heard", json!(b.to_string()));
            if let Broadcast::Emergency { robot, emergency } = &b {
                match emergency {
                    Emergency::FleetStop { reason } => {
                        if !halted {
                            halted = true;
                            // At once, not at the end of this tick.
                            if let Err(e) = base.set_velocity(VelocityCommand::ZERO).await {
                                tracing::warn!("base: {e:?}");
                            }
                            events.emit(
                                &clock,
                                &me,
                                "fleet-stop",
                                json!({"by": robot, "reason": reason}),
                            );
                        }
                        continue;
                    }
                    Emergency::FleetResume => {
                        if halted {
                            halted = false;
                            events.emit(&clock, &me, "fleet-resume", json!({"by": robot}));
                        }
                        continue;
                    }
                    _ => {}
                }
            }
            let Some(h) = ScooterHeard::from_broadcast(&b, &me) else {
                continue;
            };
            match &h {
                // Repeats of the current target (several copies are sent) change nothing.
                ScooterHeard::TargetAccepted { colour } if brain.target() == Some(colour) => {}
                ScooterHeard::TargetAccepted { colour } => {
                    if halted {
                        // A new target ends a fleet stop.
                        halted = false;
                        events.emit(
                            &clock,
                            &me,
                            "fleet-resume",
                            json!({"by": "new target", "target": colour}),
                        );
                    }
                    brain.handle_heard(&h, now);
                    reached = None;
                    // Skeeter's latest SES already says where the target is.
                    if let Some((at, form)) = &last_ses
                        && now.saturating_duration_since(*at) < lost_after
                    {
                        let planned = brain.handle_ses(form, now);
                        events.emit(&clock, &me, "ses", json!({"records": form.records.len(), "planned": planned, "target": colour}));
                    }
                }
                ScooterHeard::MissionEnded { .. } => {
                    brain.handle_heard(&h, now);
                    reached = None;
                }
                _ => brain.handle_heard(&h, now),
            }
        }
        while let Ok(form) = ses_rx.try_recv() {
            let planned = brain.handle_ses(&form, now);
            events.emit(
                &clock,
                &me,
                "ses",
                json!({"records": form.records.len(), "planned": planned}),
            );
            last_ses = Some((now, form));
        }
        if let Some(o) = base.latest_odometry()
            && Some(o.at) != last_odo_at
        {
            last_odo_at = Some(o.at);
            brain.handle_odometry(&o.value, now);
        }
        if let Some(c) = compass.as_ref().and_then(|c| c.latest())
            && Some(c.at) != last_compass_at
        {
            last_compass_at = Some(c.at);
            brain.handle_compass(common_heading(&c.value.heading, &cfg), now);
        }
        if scan_rx.has_changed().unwrap_or(false) {
            let scan = scan_rx.borrow_and_update().clone();
            if let Some(scan) = scan {
                brain.handle_laser(&scan, now);
            }
        }
        let out = brain.step(now);
        // Once Scooter has told Skeeter it reached the target it waits there for the end of
        // the mission (or a new target), whatever the brain selects meanwhile.
        let command = if reached.is_some() || halted {
            VelocityCommand::ZERO
        } else {
            out.command
        };
        if let Err(e) = base.set_velocity(command).await {
            tracing::warn!("base: {e:?}");
        }
        if last_control.is_none_or(|t| now.saturating_duration_since(t) >= Duration::from_secs(2)) {
            last_control = Some(now);
            let dr = brain.dr_position();
            events.emit(
                &clock,
                &me,
                "control",
                json!({
                    "v_m_s": command.v_m_s, "omega_rad_s": command.omega_rad_s,
                    "heading_rad": brain.heading(), "desired_rad": brain.desired_heading(),
                    "dr": [dr.x, dr.y], "behaviour": out.behaviour.as_str(),
                    "halted": halted,
                }),
            );
        }
        // web console (issue 17): map, SAN and Peer Agent detail.
        if events.wants_detail()
            && last_detail.is_none_or(|t| now.saturating_duration_since(t) >= DETAIL_EVERY)
        {
            last_detail = Some(now);
            events.emit(
                &clock,
                &me,
                "map",
                crate::web::feed::scooter_map_json(&brain),
            );
            let san = crate::web::feed::san_json(brain.san(), out.behaviour.as_str());
            events.emit(&clock, &me, "san", san);
            let mut v = match &_manager {
                Some(m) => match (m.stats().await, m.status().await) {
                    (Ok(stats), Ok(clients)) => crate::web::feed::manager_json(&stats, &clients),
                    _ => json!({}),
                },
                None => json!({}),
            };
            v["broadcast"] = crate::web::feed::bus_json(&bus.stats());
            events.emit(&clock, &me, "peer-status", v);
        }
        let b = out.behaviour.as_str().to_owned();
        if b != last_behaviour {
            events.emit(&clock, &me, "behaviour", json!(b));
            last_behaviour = b;
        }
        for say in out.messages {
            if let ScooterSay::TargetReached { colour } = &say {
                reached = Some(colour.clone());
            }
            let Some(mut msg) = say.to_broadcast(&me, &brain.san_summary()) else {
                // RequestHeading: ask Skeeter's manager again (a fresh grant makes Skeeter
                // scan and publish).
                events.emit(&clock, &me, "request-heading", json!(null));
                let _ = rerequest_tx.try_send(());
                continue;
            };
            // While a fleet stop holds, the status says so (the brain's module is on hold).
            if halted && let Broadcast::Status { behaviour, .. } = &mut msg {
                *behaviour = FLEET_STOPPED.to_owned();
            }
            if !matches!(msg, Broadcast::Status { .. }) {
                events.emit(&clock, &me, "say", json!(msg.to_string()));
            }
            bus.say(&msg).await;
        }
    };
    laser_task.abort();
    ses_task.abort();
    rx_task.abort();
    let _ = base.stop().await;
    result
}

async fn ses_loop(
    mut rerequest: mpsc::Receiver<()>,
    cfg: RobotConfig,
    net: ima_agents::peer::net::PeerNetConfig,
    key: GroupKey,
    tx: mpsc::Sender<SharedForm>,
    events: Events,
    clock: MissionClock,
) {
    let Some(addr) = cfg.peer.connect.clone() else {
        return;
    };
    let me = cfg.robot.clone();
    let prio = cfg.agent.ses_request_priority;
    loop {
        let r: Result<(), String> = async {
            let client = PeerClientHandle::connect(addr.as_str(), &net, key.clone())
                .await
                .map_err(|e| e.to_string())?;
            client.register().await.map_err(|e| e.to_string())?;
            let mut sub = client
                .request(SES_SOURCE, prio)
                .await
                .map_err(|e| e.to_string())?;
            events.emit(
                &clock,
                &me,
                "peer",
                json!({"granted": SES_SOURCE, "manager": addr, "priority": prio}),
            );
            loop {
                let ev = tokio::select! {
                    ev = sub.next() => ev,
                    Some(()) = rerequest.recv() => {
                        // A fresh request: disconnect and ask again (Skeeter answers a new
                        // grant with its latest SES).
                        let _ = client.disconnect(SES_SOURCE).await;
                        sub = client
                            .request(SES_SOURCE, prio)
                            .await
                            .map_err(|e| e.to_string())?;
                        events.emit(&clock, &me, "peer", json!({"granted": SES_SOURCE, "again": true}));
                        continue;
                    }
                };
                let Some(ev) = ev else { break };
                match ev {
                    SubscriptionEvent::Sample { payload, .. } => match SharedForm::decode(&payload)
                    {
                        Ok(f) => {
                            if tx.send(f).await.is_err() {
                                return Ok(());
                            }
                        }
                        Err(e) => tracing::warn!("bad SES sample: {e:?}"),
                    },
                    SubscriptionEvent::Lost { reason } => {
                        events.emit(&clock, &me, "peer", json!({"lost": crate::cmd::peer::loss_reason_json(&reason)}));
                    }
                    SubscriptionEvent::Closed { reason } => {
                        return Err(format!(
                            "subscription closed: {}",
                            crate::cmd::peer::end_reason_json(&reason)
                        ));
                    }
                }
            }
            Err("subscription ended".to_owned())
        }
        .await;
        if let Err(e) = r {
            events.emit(&clock, &me, "peer", json!({"retry": e}));
        }
        if tx.is_closed() {
            return;
        }
        tokio::time::sleep(Duration::from_secs(1)).await;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ima_hal::compass::{Heading, HeadingReference};

    fn cfg() -> RobotConfig {
        RobotConfig::from_toml_str(
            "robot = \"scooter\"\nrole = \"scooter\"\nmock = true\n[peer]\ninsecure = true\nconnect = \"127.0.0.1:1\"\n",
        )
        .unwrap()
    }

    #[test]
    fn compass_headings_map_to_the_common_frame() {
        let mut c = cfg();
        // Compass 60° (clockwise from north) = yaw 30° ENU; common heading east (90°).
        let h = Heading::new(60f64.to_radians(), HeadingReference::Magnetic);
        assert!((common_heading(&h, &c).to_degrees() - 30.0).abs() < 1e-9);
        // Common heading north: Scooter is 60° clockwise of it, i.e. −60° counter-clockwise.
        c.agent.common_heading_deg = 0.0;
        assert!((common_heading(&h, &c).to_degrees() + 60.0).abs() < 1e-9);
        // A deviation of 4° east turns the true heading 4° clockwise.
        c.agent.common_heading_deg = 90.0;
        c.devices.compass = Some(crate::config::CompassDeviceConfig {
            port: "x".into(),
            baud: 4800,
            dialect: crate::config::CompassDialect::Kvh,
            deviation_deg: 4.0,
        });
        assert!((common_heading(&h, &c).to_degrees() - 26.0).abs() < 1e-9);
    }

    #[test]
    fn brain_config_follows_the_robot_config() {
        let mut c = cfg();
        c.agent.heading_rule = crate::config::HeadingRule::Thesis;
        c.agent.heading_source = crate::config::HeadingSource::Odometry;
        c.agent.cruise_speed_m_s = 0.05;
        let b = brain_config(&c, 0.5);
        assert_eq!(b.heading_rule, HeadingRule::Thesis);
        assert_eq!(b.heading_source, HeadingSource::Odometry);
        assert!((b.cruise_speed_m_s - 0.05).abs() < 1e-12);
        assert!((b.odometry_heading_offset_rad - 0.5).abs() < 1e-12);
        assert!((b.reach_distance_m - 1.0).abs() < 1e-12);
        assert!(
            b.skeeter_diameter_tolerance_m < 0.0,
            "laser fix on Skeeter off"
        );
        c.agent.laser_ranges_skeeter = true;
        assert!(brain_config(&c, 0.0).skeeter_diameter_tolerance_m > 0.0);
    }
}

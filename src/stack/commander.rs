//! The commander's runtime configuration ([`ima_agents::runtime::commander`]) from its
//! configuration, and the one-shot fleet commands of `ima commander stop|resume|cancel`.

use std::time::Duration;

use anyhow::{Context, Result};
use ima_agents::mission::commander::CommanderConfig;
use ima_agents::mission::msg::{Broadcast, FLEET_COPIES};
use ima_agents::peer::net::BroadcastChannel;
use ima_agents::peer::wire::GroupKey;
use ima_agents::runtime::commander::CommanderRuntimeConfig;

use super::net::net_config;
use crate::config::RobotConfig;

/// The commander runtime's configuration from a commander configuration: targets resent
/// every 3 s, given up after `agent.target_timeout_s`; liveness reports after `lost_after`;
/// waits (at most `wait.1`, real time) for the robots of `wait.0` before the first target.
pub fn runtime_config(
    cfg: &RobotConfig,
    wait: (&[String], Duration),
    lost_after: Option<Duration>,
) -> CommanderRuntimeConfig {
    CommanderRuntimeConfig {
        core: CommanderConfig {
            robot: cfg.robot.clone(),
            resend: Duration::from_secs(3),
            give_up_after: Some(Duration::from_secs_f64(cfg.agent.target_timeout_s)),
            ..CommanderConfig::default()
        },
        time_scale: cfg.agent.time_scale,
        lost_after,
        wait_for: wait.0.to_vec(),
        wait_timeout: wait.1,
        keep_running: false,
    }
}

/// Sends one fleet command or cancel (`b`) [`FLEET_COPIES`] times, 50 ms apart, from a
/// short-lived commander process (`ima commander stop|resume|cancel`): its socket binds any
/// free port (not the running commander's), and with unicast peers the configured
/// commander address is a destination too, so that a running commander hears a cancel.
/// Returns the destinations reached by the last copy.
pub async fn send_once(cfg: &RobotConfig, key: GroupKey, b: &Broadcast) -> Result<usize> {
    let mut n = net_config(cfg)?;
    if let Some(port) = n.broadcast.bind_port
        && n.broadcast.mode != ima_agents::peer::net::BroadcastMode::Multicast
    {
        let own = format!("{}:{port}", n.broadcast.bind);
        if port != 0 && !n.broadcast.peers.contains(&own) {
            n.broadcast.peers.push(own);
        }
    }
    n.broadcast.bind_port = Some(0);
    let chan = BroadcastChannel::bind(&n, &cfg.robot, key)
        .map_err(|e| anyhow::anyhow!("{e}"))
        .context("binding the broadcast channel")?;
    anyhow::ensure!(
        !chan.destinations().is_empty(),
        "nowhere to send: no broadcast_group and no broadcast_peers in the configuration"
    );
    let mut reached = 0;
    for i in 0..FLEET_COPIES {
        if i > 0 {
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        let r = match b {
            Broadcast::Emergency { emergency, .. } => {
                chan.send_emergency(emergency.kind(), &emergency.text())
                    .await
            }
            Broadcast::Mission { event, target, .. } => chan.send_mission(*event, target).await,
            Broadcast::Status {
                behaviour,
                san,
                pose,
                ..
            } => chan.send_status(behaviour, san, *pose).await,
        };
        reached = r.map_err(|e| anyhow::anyhow!("{e}"))?;
    }
    Ok(reached)
}

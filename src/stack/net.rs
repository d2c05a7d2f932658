//! The Peer Agent side of a robot process: the configuration mapped onto
//! [`PeerNetConfig`], the group key, and the typed broadcast channel of the mission.

use std::time::Duration;

use anyhow::{Context, Result};
use ima_agents::mission::msg::Broadcast;
use ima_agents::peer::net::{
    BroadcastChannel, BroadcastMode, PeerNetConfig, insecure_key, load_key_file,
};
use ima_agents::peer::wire::GroupKey;

use crate::config::RobotConfig;

/// The [`PeerNetConfig`] of a robot configuration.
pub fn net_config(cfg: &RobotConfig) -> Result<PeerNetConfig> {
    let p = &cfg.peer;
    let mut n = PeerNetConfig {
        robot: cfg.robot.clone(),
        key_file: p.key_file.clone(),
        heartbeat_ms: p.heartbeat_ms.max(1),
        ..PeerNetConfig::default()
    };
    if !p.listen.is_empty() {
        n.manager.listen = p.listen.clone();
    }
    n.manager.data_listen = p.data_listen.clone();
    n.manager.data_advertise = p.data_advertise.clone();
    n.manager.robot_priorities = p.priorities.clone();
    let b = &mut n.broadcast;
    let multicast = !p.broadcast_group.is_empty();
    if multicast {
        let (ip, port) = split_addr(&p.broadcast_group)
            .with_context(|| format!("peer.broadcast_group {:?}", p.broadcast_group))?;
        b.group = ip;
        b.port = port;
    }
    b.peers = p.broadcast_peers.clone();
    b.mode = match (multicast, p.broadcast_peers.is_empty()) {
        (true, true) => BroadcastMode::Multicast,
        (true, false) => BroadcastMode::Both,
        (false, _) => BroadcastMode::Unicast,
    };
    if let Some(bind) = &p.broadcast_bind {
        let (ip, port) =
            split_addr(bind).with_context(|| format!("peer.broadcast_bind {bind:?}"))?;
        b.bind = ip.clone();
        // The local port only: the multicast group keeps its own port as the destination.
        b.bind_port = Some(port);
        if ip.starts_with("127.") {
            b.interface = ip;
        }
    }
    Ok(n)
}

fn split_addr(s: &str) -> Result<(String, u16)> {
    let (ip, port) = s
        .rsplit_once(':')
        .with_context(|| format!("{s:?} is not ip:port"))?;
    let port = port
        .parse::<u16>()
        .with_context(|| format!("bad port in {s:?}"))?;
    Ok((ip.to_owned(), port))
}

/// The group key: `override_key` (the demo's in-memory key), else `peer.key_file`, else the
/// documented insecure key when `peer.insecure` is set.
pub fn group_key(cfg: &RobotConfig, override_key: Option<&GroupKey>) -> Result<GroupKey> {
    if let Some(k) = override_key {
        return Ok(k.clone());
    }
    match (&cfg.peer.key_file, cfg.peer.insecure) {
        // Most key errors name the file already; the others get it added once.
        (Some(path), _) => {
            let key = load_key_file(path).map_err(|e| {
                let text = e.to_string();
                if text.contains(&path.display().to_string()) {
                    anyhow::anyhow!(text)
                } else {
                    anyhow::anyhow!(text)
                        .context(format!("loading the group key {}", path.display()))
                }
            })?;
            if key.is_insecure() {
                eprintln!("ima: WARNING: {}", crate::cmd::peer::zero_key_warning(path));
            }
            Ok(key)
        }
        (None, true) => {
            tracing::warn!("running with the insecure all-zero group key");
            Ok(insecure_key())
        }
        (None, false) => anyhow::bail!("peer.key_file is required (or peer.insecure = true)"),
    }
}

/// The mission's broadcast channel: typed messages over a [`BroadcastChannel`].
#[derive(Debug, Clone)]
pub struct Bus {
    chan: std::sync::Arc<BroadcastChannel>,
}

impl Bus {
    /// Bind the channel of `cfg` with `key`.
    pub fn bind(cfg: &RobotConfig, key: GroupKey) -> Result<Self> {
        let n = net_config(cfg)?;
        let chan = BroadcastChannel::bind(&n, &cfg.robot, key)
            .map_err(|e| anyhow::anyhow!("{e}"))
            .context("binding the broadcast channel")?;
        Ok(Self {
            chan: std::sync::Arc::new(chan),
        })
    }

    /// Send a broadcast (errors are logged: the broadcast channel is best-effort).
    pub async fn send(&self, b: &Broadcast) {
        let r = match b {
            Broadcast::Status {
                behaviour,
                san,
                pose,
                ..
            } => self.chan.send_status(behaviour, san, *pose).await,
            Broadcast::Emergency { emergency, .. } => {
                self.chan
                    .send_emergency(emergency.kind(), &emergency.text())
                    .await
            }
            Broadcast::Mission { event, target, .. } => {
                self.chan.send_mission(*event, target).await
            }
        };
        if let Err(e) = r {
            tracing::warn!("broadcast not sent: {e}");
        }
    }

    /// The next mission broadcast from another robot (unknown or malformed ones are skipped
    /// with a debug log).
    pub async fn recv(&self) -> Result<Broadcast> {
        loop {
            let (msg, from) = self
                .chan
                .recv()
                .await
                .map_err(|e| anyhow::anyhow!("{e}"))
                .context("receiving broadcasts")?;
            match Broadcast::from_wire(&msg) {
                Ok(b) => return Ok(b),
                Err(e) => tracing::debug!("ignoring a broadcast from {from}: {e:?}"),
            }
        }
    }

    /// The channel's counters (web console, issue 17).
    pub fn stats(&self) -> ima_agents::peer::net::BroadcastStats {
        self.chan.stats()
    }

    /// Frames refused for a bad MAC since the last report (at most one report per
    /// [`ima_agents::peer::net::AUTH_REPORT_INTERVAL`]; see
    /// [`BroadcastChannel::take_auth_report`]).
    pub fn take_auth_report(&self) -> Option<ima_agents::peer::net::AuthFailure> {
        self.chan.take_auth_report()
    }

    /// Prints a pending authentication report on stderr (frames under another group key).
    pub fn warn_auth(&self) {
        if let Some(a) = self.take_auth_report() {
            eprintln!("ima: warning: {a}");
        }
    }

    /// A task that hands every mission broadcast heard to a bounded queue (what the robot's
    /// main loop selects on). A socket error is logged and listening goes on; frames under
    /// another group key are reported on stderr (rate-limited, [`Bus::warn_auth`]); the task
    /// ends when the queue's receiver is dropped.
    pub fn spawn_reader(
        &self,
    ) -> (
        tokio::sync::mpsc::Receiver<Broadcast>,
        tokio::task::JoinHandle<()>,
    ) {
        let (tx, rx) = tokio::sync::mpsc::channel::<Broadcast>(64);
        let bus = self.clone();
        let task = tokio::spawn(async move {
            let mut check = tokio::time::interval(Duration::from_secs(1));
            check.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
            loop {
                let r = tokio::select! {
                    r = bus.recv() => r,
                    _ = check.tick() => {
                        bus.warn_auth();
                        continue;
                    }
                };
                match r {
                    Ok(b) => {
                        if tx.send(b).await.is_err() {
                            return;
                        }
                    }
                    Err(e) => {
                        tracing::warn!("broadcast channel: {e:#}");
                        tokio::time::sleep(Duration::from_millis(200)).await;
                    }
                }
            }
        });
        (rx, task)
    }

    /// Send what a robot's brain says: a status once; every other message (mission events,
    /// emergencies, target notices — the ones that must not be lost) three times 30 ms
    /// apart. Receivers drop duplicates by sequence number only, so the copies are new
    /// messages and the receivers are idempotent.
    pub async fn say(&self, b: &Broadcast) {
        let copies = if matches!(b, Broadcast::Status { .. }) {
            1
        } else {
            3
        };
        for i in 0..copies {
            if i > 0 {
                tokio::time::sleep(Duration::from_millis(30)).await;
            }
            self.send(b).await;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg(peer: &str) -> RobotConfig {
        RobotConfig::from_toml_str(&format!(
            "robot = \"skeeter\"\nrole = \"commander\"\n[peer]\ninsecure = true\n{peer}"
        ))
        .unwrap()
    }

    #[test]
    fn peer_settings_map_onto_the_net_config() {
        let n = net_config(&cfg("")).unwrap();
        assert_eq!(n.robot, "skeeter");
        assert_eq!(n.broadcast.mode, BroadcastMode::Multicast);
        assert_eq!(
            (n.broadcast.group.as_str(), n.broadcast.port),
            ("239.255.73.77", 7601)
        );
        let n = net_config(&cfg(
            "listen = \"127.0.0.1:7600\"\nbroadcast_group = \"\"\nbroadcast_peers = [\"127.0.0.1:9\"]\nbroadcast_bind = \"127.0.0.1:7602\"\nheartbeat_ms = 250\n[peer.priorities]\nscooter = 2\n",
        ))
        .unwrap();
        assert_eq!(n.broadcast.mode, BroadcastMode::Unicast);
        assert_eq!(n.broadcast.peers, ["127.0.0.1:9"]);
        assert_eq!(
            (n.broadcast.bind.as_str(), n.broadcast.bind_port),
            ("127.0.0.1", Some(7602))
        );
        assert_eq!(n.broadcast.interface, "127.0.0.1");
        assert_eq!(n.manager.listen, "127.0.0.1:7600");
        assert_eq!(n.manager.robot_priorities.get("scooter"), Some(&2));
        assert_eq!(n.heartbeat_ms, 250);
        let n = net_config(&cfg("broadcast_peers = [\"10.0.0.2:7601\"]\n")).unwrap();
        assert_eq!(n.broadcast.mode, BroadcastMode::Both);
        assert!(net_config(&cfg("broadcast_group = \"nonsense\"\n")).is_err());
    }

    #[test]
    fn keys_come_from_the_file_or_the_insecure_switch() {
        assert!(group_key(&cfg(""), None).is_ok());
        let mut c = cfg("");
        c.peer.insecure = false;
        assert!(group_key(&c, None).is_err());
        c.peer.key_file = Some("/nonexistent/ima.key".into());
        let e = group_key(&c, None).unwrap_err();
        assert!(format!("{e:#}").contains("/nonexistent/ima.key"), "{e:#}");
    }
}

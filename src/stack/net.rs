//! The Peer Agent side of a robot process: the configuration mapped onto
//! [`PeerNetConfig`], the group key, and the mission's broadcast channel ([`Bus`]).

use anyhow::{Context, Result};
use ima_agents::peer::net::{BroadcastMode, PeerNetConfig, insecure_key, load_key_file};
use ima_agents::peer::wire::GroupKey;
use ima_agents::runtime::link::Bus;

use crate::config::{RobotConfig, Role};

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
    } else if cfg.role != Role::Skeeter {
        // Only Skeeter always runs a manager: for Scooter an empty `listen` means none of its
        // own (it started one on the default 0.0.0.0:7400), the commander never runs one.
        n.manager.listen.clear();
    } else if p.insecure && p.key_file.is_none() {
        // The all-zero key lets anyone in: a manager nobody placed stays on loopback, as
        // `ima peer manager --insecure`'s does.
        n.manager.listen = loopback(&n.manager.listen);
        eprintln!(
            "ima: insecure key: the Peer Agent Manager listens on {} only (set peer.listen to \
             choose the address)",
            n.manager.listen
        );
    }
    n.manager.data_listen = p.data_listen.clone();
    n.manager.data_advertise = p.data_advertise.clone();
    place_data_server(&mut n.manager);
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

/// `addr` with an unspecified IP (`0.0.0.0`, `::`) made loopback; anything else as it is.
pub fn loopback(addr: &str) -> String {
    match addr.parse::<std::net::SocketAddr>() {
        Ok(mut sa) if sa.ip().is_unspecified() => {
            sa.set_ip(std::net::Ipv4Addr::LOCALHOST.into());
            sa.to_string()
        }
        _ => addr.to_owned(),
    }
}

/// Put a manager's data server beside its request channel: a `data_listen` whose IP names no
/// interface takes `listen`'s when that one names one, so a manager placed on loopback or on
/// one interface does not serve its data on every interface (its data server listened on
/// `0.0.0.0` beside a request channel on `127.0.0.1`). Not for a manager with a
/// `data_advertise` address: its grants name that one, and the data server stays put.
pub fn place_data_server(m: &mut ima_agents::peer::net::ManagerNetConfig) {
    if m.data_advertise.is_none() {
        m.data_listen = data_beside(&m.data_listen, &m.listen);
    }
}

/// `data` with an unspecified IP given `listen`'s, when that one names an address.
fn data_beside(data: &str, listen: &str) -> String {
    match (
        data.parse::<std::net::SocketAddr>(),
        listen.parse::<std::net::SocketAddr>(),
    ) {
        (Ok(mut d), Ok(l)) if d.ip().is_unspecified() && !l.ip().is_unspecified() => {
            d.set_ip(l.ip());
            d.to_string()
        }
        _ => data.to_owned(),
    }
}

fn split_addr(s: &str) -> Result<(String, u16)> {
    let (ip, port) = ima_agents::peer::net::split_host_port(s)
        .with_context(|| format!("{s:?} is not ip:port (a port number after the last ':')"))?;
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
                let e = if text.contains(&path.display().to_string()) {
                    anyhow::anyhow!(text)
                } else {
                    anyhow::anyhow!(text)
                        .context(format!("loading the group key {}", path.display()))
                };
                // A relative path is taken from the working directory, which a robot started
                // by a service manager may not share with its configuration file.
                match std::env::current_dir() {
                    Ok(cwd) if path.is_relative() && !path.as_os_str().is_empty() => {
                        e.context(format!(
                            "peer.key_file is relative: it is read from the working directory {}",
                            cwd.display()
                        ))
                    }
                    _ => e,
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

/// The mission's broadcast channel of `cfg`, bound with `key` on the process's `clock`.
pub fn bus(cfg: &RobotConfig, key: GroupKey, clock: ima_hal::time::SharedClock) -> Result<Bus> {
    Ok(Bus::bind(&net_config(cfg)?, key, clock)?)
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
        // The configuration's check refuses it first; a configuration built in code is
        // still checked here.
        assert!(
            RobotConfig::from_toml_str(
                "robot = \"c\"\nrole = \"commander\"\n[peer]\ninsecure = true\nbroadcast_group = \"nonsense\"\n"
            )
            .is_err()
        );
        let mut c = cfg("");
        c.peer.broadcast_group = "nonsense".into();
        assert!(net_config(&c).is_err());
    }

    /// With the all-zero key, a manager nobody placed listens on loopback, and a data server
    /// nobody placed listens beside its request channel (it listened on every interface).
    #[test]
    fn an_insecure_manager_nobody_placed_stays_on_loopback() {
        let cfg = |peer: &str| {
            let mut c = cfg(peer);
            c.role = Role::Skeeter;
            c
        };
        let n = net_config(&cfg("")).unwrap();
        assert_eq!(n.manager.listen, "127.0.0.1:7400");
        assert_eq!(n.manager.data_listen, "127.0.0.1:0");
        let n = net_config(&cfg("listen = \"0.0.0.0:7400\"\n")).unwrap();
        assert_eq!(n.manager.listen, "0.0.0.0:7400", "placed on purpose");
        assert_eq!(n.manager.data_listen, "0.0.0.0:0");
        let n = net_config(&cfg("listen = \"10.0.0.5:7400\"\n")).unwrap();
        assert_eq!(n.manager.data_listen, "10.0.0.5:0");
        let n = net_config(&cfg(
            "listen = \"10.0.0.5:7400\"\ndata_listen = \"0.0.0.0:7401\"\n",
        ))
        .unwrap();
        assert_eq!(n.manager.data_listen, "10.0.0.5:7401", "the port kept");
        // An advertised data address is what grants name: the data server stays put.
        let n = net_config(&cfg(
            "listen = \"127.0.0.1:7400\"\ndata_listen = \"0.0.0.0:7401\"\n\
             data_advertise = \"10.8.0.2:7401\"\n",
        ))
        .unwrap();
        assert_eq!(n.manager.data_listen, "0.0.0.0:7401");
        let mut c = cfg("");
        c.peer.insecure = false;
        c.peer.key_file = Some("group.key".into());
        let n = net_config(&c).unwrap();
        assert_eq!(
            n.manager.listen, "0.0.0.0:7400",
            "a real key: the default stands"
        );
        assert_eq!(n.manager.data_listen, "0.0.0.0:0");
        assert_eq!(data_beside("[::]:0", "[::1]:7400"), "[::1]:0");
        assert_eq!(data_beside("127.0.0.2:9", "10.0.0.5:7400"), "127.0.0.2:9");
        assert_eq!(loopback("host.local:7400"), "host.local:7400");
        // Scooter and the commander run no manager unless placed.
        for role in [Role::Scooter, Role::Commander] {
            let mut c = cfg("");
            c.role = role;
            assert_eq!(net_config(&c).unwrap().manager.listen, "", "{role:?}");
        }
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
        assert!(!format!("{e:#}").contains("working directory"), "{e:#}");
        // A relative path: the message says where it was looked for.
        c.peer.key_file = Some("no-such-dir/ima.key".into());
        let e = format!("{:#}", group_key(&c, None).unwrap_err());
        let cwd = std::env::current_dir().unwrap();
        assert!(
            e.contains(&format!("working directory {}", cwd.display())),
            "{e}"
        );
    }
}

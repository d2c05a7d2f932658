//! Serde configuration of the network shell (TOML). Every field has a default; see
//! [`PeerNetConfig`] and the example `configs/peer-manager.toml`.

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use serde::{Deserialize, Serialize};

use super::NetError;

/// Upper bound of `manager.data_queue` and `manager.session_queue` (see
/// [`PeerNetConfig::validate`]).
pub const MAX_QUEUE: usize = 65_536;

/// Upper bound of `heartbeat_ms` (one minute; see [`PeerNetConfig::validate`]).
pub const MAX_PERIOD_MS: u64 = 60_000;

/// Configuration of one robot's Peer Agent over IP.
///
/// ```toml
/// robot = "skeeter"              # default "robot"
/// key_file = "/etc/ima/group.key" # no default: tools refuse to run without a key
/// heartbeat_ms = 100              # default 100 (a LAN)
/// missed_heartbeats = 3           # default 3
/// max_body = 8192                 # default 8192 bytes
///
/// [manager]
/// listen = "127.0.0.1:7400"       # request channel; default 0.0.0.0:7400
/// data_listen = "127.0.0.1:0"     # data server; default 0.0.0.0:0 (any free port)
/// # data_advertise = "10.0.0.5:7401"  # address put in grants; default: the data
/// #                                  # listener's address (bound to 0.0.0.0: the local IP
/// #                                  # each client reached the request channel on)
/// rescan_ms = 1000
/// ticket_lifetime_ms = 5000
/// max_clients = 1024
/// data_queue = 64                 # samples queued per data session (latest value)
/// task_priority = 0               # of the built-in FixedSelfAgent
/// unknown_robot_priority = 0
/// [manager.robot_priorities]
/// commander = 3
/// skeeter = 2
///
/// [broadcast]
/// mode = "multicast"              # "multicast" | "unicast" | "both"
/// group = "239.255.73.77"
/// port = 7477
/// interface = "0.0.0.0"           # IP_MULTICAST_IF / membership; "127.0.0.1" for loopback
/// peers = ["192.168.1.12:7477"]   # unicast fallback
/// ttl = 1
/// loopback = true
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PeerNetConfig {
    /// This robot's name (sent on registration, used as broadcast sender name).
    pub robot: String,
    /// Path of the group-key file (see [`super::load_key_file`]).
    pub key_file: Option<PathBuf>,
    /// Heartbeat interval in ms on every channel (default 100).
    pub heartbeat_ms: u64,
    /// Missed intervals before a peer is declared lost (default 3).
    pub missed_heartbeats: u32,
    /// Body-size limit of incoming frames (default 8192).
    pub max_body: usize,
    /// Clock skew allowed for the FIRST frame counter of a sender not heard before, ms
    /// (default 30 000; 0 turns the check off). Counters are UNIX µs, so a frame recorded
    /// before a restart of the receiver is refused as a replay (see the `peer` module docs).
    pub max_clock_skew_ms: u64,
    /// How long a client's `register`, `unregister`, `request` (until granted) and
    /// `disconnect` wait for the manager's answer before failing with `NetError::Timeout`,
    /// ms (default 10 000; 0: no limit). A request that times out is withdrawn.
    pub call_timeout_ms: u64,
    /// Manager side.
    pub manager: ManagerNetConfig,
    /// Broadcast channel.
    pub broadcast: BroadcastConfig,
}

impl Default for PeerNetConfig {
    fn default() -> Self {
        Self {
            robot: "robot".into(),
            key_file: None,
            heartbeat_ms: 100,
            missed_heartbeats: 3,
            max_body: crate::peer::wire::DEFAULT_MAX_BODY,
            max_clock_skew_ms: 30_000,
            call_timeout_ms: 10_000,
            manager: ManagerNetConfig::default(),
            broadcast: BroadcastConfig::default(),
        }
    }
}

impl PeerNetConfig {
    /// Parses TOML (unknown keys are refused) and [validates](Self::validate) it.
    ///
    /// # Errors
    /// [`NetError::Config`].
    pub fn from_toml(text: &str) -> Result<Self, NetError> {
        let c: Self = toml::from_str(text)
            .map_err(|e| NetError::Config(ima_hal::file::located(text, e.span(), e.message())))?;
        c.validate()?;
        Ok(c)
    }

    /// Checks the limits: `max_body` in 256..=65 535 (the wire's body length is a u16),
    /// `heartbeat_ms` in 1..=60 000 (`MAX_PERIOD_MS`), `missed_heartbeats` in 1..=1000,
    /// `max_clock_skew_ms` at most a day, `call_timeout_ms`, `manager.rescan_ms` and
    /// `manager.ticket_lifetime_ms` at most an hour (the last two at least 1),
    /// `broadcast.ttl` in 1..=255, `manager.data_queue` and
    /// `manager.session_queue` in 1..=[`MAX_QUEUE`], `manager.max_clients` and
    /// `manager.max_connections` at least 1, `manager.data_advertise` a `HOST:PORT`.
    /// [`super::spawn_manager`],
    /// [`super::PeerClientHandle::connect`] and [`super::BroadcastChannel::bind`] call it.
    ///
    /// # Errors
    /// [`NetError::Config`] naming the first bad key.
    pub fn validate(&self) -> Result<(), NetError> {
        let bad = |key: &str, v: &dyn core::fmt::Display, range: &str| {
            Err(NetError::Config(format!(
                "{key} = {v} is out of range ({range})"
            )))
        };
        // Registrations and broadcasts carry the name as a string of at most 255 bytes.
        let max = crate::peer::wire::MAX_STR_LEN;
        if self.robot.is_empty() || self.robot.len() > max {
            return Err(NetError::Config(format!(
                "robot must be a name of 1 to {max} bytes, not {} bytes",
                self.robot.len()
            )));
        }
        if !(256..=usize::from(u16::MAX)).contains(&self.max_body) {
            return bad("max_body", &self.max_body, "256..=65535");
        }
        // Times in ms: (key, value, smallest, largest). A zero period would spin, a huge one
        // overflow the deadlines derived from it (or never declare a dead peer lost).
        let times = [
            ("heartbeat_ms", self.heartbeat_ms, 1, MAX_PERIOD_MS),
            ("max_clock_skew_ms", self.max_clock_skew_ms, 0, 86_400_000),
            ("call_timeout_ms", self.call_timeout_ms, 0, 3_600_000),
            ("manager.rescan_ms", self.manager.rescan_ms, 1, 3_600_000),
            (
                "manager.ticket_lifetime_ms",
                self.manager.ticket_lifetime_ms,
                1,
                3_600_000,
            ),
        ];
        for (key, v, lo, hi) in times {
            if !(lo..=hi).contains(&v) {
                return bad(key, &v, &format!("{lo}..={hi} ms"));
            }
        }
        if !(1..=1000).contains(&self.missed_heartbeats) {
            return bad("missed_heartbeats", &self.missed_heartbeats, "1..=1000");
        }
        if !(1..=255).contains(&self.broadcast.ttl) {
            return bad("broadcast.ttl", &self.broadcast.ttl, "1..=255");
        }
        let m = &self.manager;
        if !(1..=MAX_QUEUE).contains(&m.data_queue) {
            return bad("manager.data_queue", &m.data_queue, "1..=65536");
        }
        if !(1..=MAX_QUEUE).contains(&m.session_queue) {
            return bad("manager.session_queue", &m.session_queue, "1..=65536");
        }
        if m.max_clients == 0 {
            return bad("manager.max_clients", &m.max_clients, "at least 1");
        }
        if m.max_connections == 0 {
            return bad("manager.max_connections", &m.max_connections, "at least 1");
        }
        // Put in grants as it is: clients connect to it, so it must be HOST:PORT.
        if let Some(a) = &m.data_advertise
            && !is_host_port(a)
        {
            return Err(NetError::Config(format!(
                "manager.data_advertise = {a:?} is not HOST:PORT (e.g. \"10.0.0.5:7401\")"
            )));
        }
        Ok(())
    }

    /// Reads and parses a TOML file.
    ///
    /// # Errors
    /// [`NetError::Config`].
    pub fn load(path: &std::path::Path) -> Result<Self, NetError> {
        let text = ima_hal::file::read_text(path)
            .map_err(|e| NetError::Config(format!("{}: {e}", path.display())))?;
        Self::from_toml(&text)
    }

    /// A configuration for tests and tools on loopback: everything on 127.0.0.1 with free
    /// ports, multicast on the loopback interface.
    #[must_use]
    pub fn loopback(robot: &str) -> Self {
        let mut c = Self {
            robot: robot.to_owned(),
            ..Self::default()
        };
        c.manager.listen = "127.0.0.1:0".into();
        c.manager.data_listen = "127.0.0.1:0".into();
        c.broadcast.interface = "127.0.0.1".into();
        c
    }

    /// The heartbeat interval.
    #[must_use]
    pub fn heartbeat(&self) -> Duration {
        Duration::from_millis(self.heartbeat_ms.max(1))
    }

    /// The loss window: `missed_heartbeats` heartbeat intervals.
    #[must_use]
    pub fn loss_window(&self) -> Duration {
        self.heartbeat()
            .saturating_mul(self.missed_heartbeats.max(1))
    }
}

/// The manager's sockets and rules.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ManagerNetConfig {
    /// Request-channel listen address (default `0.0.0.0:7400`).
    pub listen: String,
    /// Data-server listen address (default `0.0.0.0:0`).
    pub data_listen: String,
    /// Data address put in grants (default: the data listener's address; when that is
    /// unspecified, e.g. `0.0.0.0`, each client is given the local IP it reached the request
    /// channel on, with the data port).
    pub data_advertise: Option<String>,
    /// Source re-scan interval, ms (default 1000).
    pub rescan_ms: u64,
    /// Ticket lifetime, ms (default 5000).
    pub ticket_lifetime_ms: u64,
    /// Maximum registered clients (default 1024).
    pub max_clients: usize,
    /// Samples queued per data session; the oldest are dropped (default 64).
    pub data_queue: usize,
    /// Frames queued per client session before it is closed as too slow (default 1024).
    pub session_queue: usize,
    /// Open connections per listener (request channel and data server each), counted from
    /// `accept`, authenticated or not; further connections wait in the kernel's backlog
    /// until one closes (default 1024).
    pub max_connections: usize,
    /// Task priority of the built-in `FixedSelfAgent` (default 0).
    pub task_priority: u8,
    /// Robot priorities; a leader gets the highest (default empty).
    pub robot_priorities: BTreeMap<String, u8>,
    /// Priority of robots not listed (default 0, the lowest).
    pub unknown_robot_priority: u8,
}

impl Default for ManagerNetConfig {
    fn default() -> Self {
        Self {
            listen: "0.0.0.0:7400".into(),
            data_listen: "0.0.0.0:0".into(),
            data_advertise: None,
            rescan_ms: 1000,
            ticket_lifetime_ms: 5000,
            max_clients: 1024,
            data_queue: 64,
            session_queue: 1024,
            max_connections: 1024,
            task_priority: 0,
            robot_priorities: BTreeMap::new(),
            unknown_robot_priority: 0,
        }
    }
}

/// How broadcasts travel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum BroadcastMode {
    /// UDP multicast to `group:port` (default).
    #[default]
    Multicast,
    /// Unicast datagrams to every address of `peers`.
    Unicast,
    /// Both (receivers drop the duplicates).
    Both,
}

/// The broadcast channel's sockets.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BroadcastConfig {
    /// Mode (default multicast).
    pub mode: BroadcastMode,
    /// Multicast group (default `239.255.73.77`, organisation-local scope).
    pub group: String,
    /// UDP port (default 7477); bound with `SO_REUSEADDR`/`SO_REUSEPORT` so several processes
    /// on one host share it for multicast. In unicast mode every process on one host needs
    /// its own port (unicast datagrams reach only one of the sockets sharing a port), so there
    /// it is bound without them: a second process on the port fails to start.
    pub port: u16,
    /// Interface address for `IP_MULTICAST_IF` and the group membership (default
    /// `0.0.0.0`: the system's choice; `127.0.0.1` for loopback).
    pub interface: String,
    /// Bind address (default `0.0.0.0`).
    pub bind: String,
    /// Port to bind when it differs from `port` (default: `port`); `0` binds any free
    /// port, for send-only tools and for unicast receivers that list their own port.
    pub bind_port: Option<u16>,
    /// Unicast peers `ip:port` (fallback where multicast is blocked); IP literals only (no
    /// name lookup: binding never blocks on DNS).
    pub peers: Vec<String>,
    /// Multicast TTL (default 1: the local segment only).
    pub ttl: u32,
    /// `IP_MULTICAST_LOOP` (default true: processes on this host hear each other).
    pub loopback: bool,
    /// Whether `recv` also returns this robot's own broadcasts (default false).
    pub receive_own: bool,
}

impl Default for BroadcastConfig {
    fn default() -> Self {
        Self {
            mode: BroadcastMode::Multicast,
            group: "239.255.73.77".into(),
            port: 7477,
            interface: "0.0.0.0".into(),
            bind: "0.0.0.0".into(),
            bind_port: None,
            peers: Vec::new(),
            ttl: 1,
            loopback: true,
            receive_own: false,
        }
    }
}

/// A synthetic source served by `ima peer manager` (tools and tests).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SyntheticSource {
    /// Source name, e.g. `counter`.
    pub name: String,
    /// Generator: `counter` (u64 LE), `sine` (f64 LE), `blobN` (N bytes).
    pub generator: String,
    /// Samples per second.
    pub rate_hz: f64,
}

/// `ip:port` (an IP literal; no name lookup, so it never blocks).
pub(crate) fn parse_ip_addr(s: &str, what: &str) -> Result<SocketAddr, NetError> {
    s.parse().map_err(|e| {
        NetError::Config(format!(
            "{what} {s:?}: {e} (an IP address and port, e.g. 192.168.1.12:7477)"
        ))
    })
}

/// `host:port`: an IP literal at once, else a name resolved without blocking the runtime
/// (`tokio::net::lookup_host`).
pub(crate) async fn parse_addr(s: &str, what: &str) -> Result<SocketAddr, NetError> {
    if let Ok(a) = s.parse() {
        return Ok(a);
    }
    tokio::net::lookup_host(s)
        .await
        .map_err(|e| NetError::Config(format!("{what} {s:?}: {e}")))?
        .next()
        .ok_or_else(|| NetError::Config(format!("{what} {s:?}: no address")))
}

/// `a` split at its last `:` into the host (possibly empty) and a port number.
#[must_use]
pub fn split_host_port(a: &str) -> Option<(&str, u16)> {
    let (host, port) = a.rsplit_once(':')?;
    Some((host, port.parse().ok()?))
}

/// Whether `a` has the shape `HOST:PORT` (a non-empty host, a port number): what
/// `manager.data_advertise` must be, since clients connect to it as it is.
#[must_use]
pub fn is_host_port(a: &str) -> bool {
    split_host_port(a).is_some_and(|(host, _)| !host.is_empty())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_and_toml() {
        let c = PeerNetConfig::from_toml(
            "robot = \"skeeter\"\nheartbeat_ms = 50\n[manager]\nlisten = \"127.0.0.1:0\"\n\
             [manager.robot_priorities]\ncommander = 3\n[broadcast]\nmode = \"both\"\n\
             peers = [\"127.0.0.1:9\"]\n",
        )
        .unwrap();
        assert_eq!(c.robot, "skeeter");
        assert_eq!(c.heartbeat_ms, 50);
        assert_eq!(c.missed_heartbeats, 3);
        assert_eq!(c.manager.robot_priorities.get("commander"), Some(&3));
        assert_eq!(c.broadcast.mode, BroadcastMode::Both);
        assert_eq!(c.broadcast.port, 7477);
        assert!(PeerNetConfig::from_toml("[manager]\nbogus = 1\n").is_err());
        assert!(PeerNetConfig::from_toml("bogus = 1\n").is_err());
        assert!(parse_ip_addr("127.0.0.1:9", "x").is_ok());
        assert!(parse_ip_addr("localhost:9", "x").is_err());
        assert!(PeerNetConfig::from_toml("max_body = 65536\n").is_err());
        assert!(PeerNetConfig::from_toml("max_body = 65535\n").is_ok());
        assert!(PeerNetConfig::from_toml("heartbeat_ms = 0\n").is_err());
        // Nonsense periods are refused with the key and its range named.
        for (toml, key, range) in [
            (
                "heartbeat_ms = 100000000000\n",
                "heartbeat_ms",
                "1..=60000 ms",
            ),
            ("missed_heartbeats = 0\n", "missed_heartbeats", "1..=1000"),
            (
                "[manager]\nrescan_ms = 0\n",
                "manager.rescan_ms",
                "1..=3600000 ms",
            ),
            (
                "[manager]\nticket_lifetime_ms = 0\n",
                "manager.ticket_lifetime_ms",
                "1..=3600000 ms",
            ),
            (
                "call_timeout_ms = 99999999999\n",
                "call_timeout_ms",
                "0..=3600000 ms",
            ),
            ("[broadcast]\nttl = 0\n", "broadcast.ttl", "1..=255"),
        ] {
            let e = PeerNetConfig::from_toml(toml).unwrap_err().to_string();
            assert!(e.contains(key) && e.contains(range), "{toml}: {e}");
        }
        assert!(PeerNetConfig::from_toml("[manager]\ndata_queue = 0\n").is_err());
        // The advertised data address goes into grants as it is: clients must reach it.
        for bad in ["x", "10.0.0.5", ":7401", "host:99999", "host:port"] {
            let toml = format!("[manager]\ndata_advertise = \"{bad}\"\n");
            let e = PeerNetConfig::from_toml(&toml).unwrap_err().to_string();
            assert!(e.contains("manager.data_advertise"), "{bad}: {e}");
        }
        for good in ["10.0.0.5:7401", "robot.local:7401", "[::1]:7401"] {
            let toml = format!("[manager]\ndata_advertise = \"{good}\"\n");
            assert!(PeerNetConfig::from_toml(&toml).is_ok(), "{good}");
        }
        assert!(PeerNetConfig::from_toml("[manager]\nsession_queue = 100000000\n").is_err());
        assert!(PeerNetConfig::from_toml("[manager]\nmax_connections = 0\n").is_err());
        // A name no frame can carry is refused before the first registration or broadcast.
        for (n, ok) in [(0, false), (1, true), (255, true), (256, false)] {
            let toml = format!("robot = \"{}\"\n", "r".repeat(n));
            let r = PeerNetConfig::from_toml(&toml);
            assert_eq!(r.is_ok(), ok, "{n}: {r:?}");
            if let Err(e) = r {
                assert!(e.to_string().contains(&format!("not {n} bytes")), "{e}");
            }
        }
        assert_eq!(
            PeerNetConfig::from_toml("").unwrap(),
            PeerNetConfig::default()
        );
    }
}

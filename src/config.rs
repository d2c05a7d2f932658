//! Robot configuration files (TOML) for `ima run`, `ima commander` and `ima mock world
//! --write-configs`.
//!
//! One file per process. Examples with real-port defaults and comments:
//! `configs/skeeter.toml`, `configs/scooter.toml`, `configs/commander.toml`.
//!
//! ```toml
//! robot = "skeeter"          # name on the broadcast channel
//! role = "skeeter"           # skeeter | scooter | commander
//! mock = false               # true: serve a simulated world in-process, ignore the ports
//!
//! [devices.base]             # P2OS (Skeeter) or rFLEX (Scooter)
//! kind = "p2os"
//! port = "/dev/ttyS0"
//! baud = 9600
//!
//! [agent]
//! cruise_speed_m_s = 0.3
//!
//! [peer]
//! listen = "0.0.0.0:7600"
//! key_file = "/etc/ima/group.key"
//! ```
//!
//! Unknown keys are errors (a typo must not silently fall back to a default).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use serde::{Deserialize, Serialize};

/// What a process is in the mission.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Role {
    /// The observer: P2OS base, camera head, SES, Peer Agent manager with the `ses` source.
    Skeeter,
    /// The mover: rFLEX base, laser, compass, Peer Agent client of Skeeter's `ses`.
    Scooter,
    /// The operator: joins the broadcast group and sends targets.
    Commander,
}

/// One process's configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RobotConfig {
    /// Name on the broadcast channel and in logs (`skeeter`, `scooter`, `commander`).
    pub robot: String,
    /// The process's part in the mission.
    pub role: Role,
    /// Spawn a simulated world and its mock devices in-process instead of opening the
    /// configured ports (the `[devices]` ports are then ignored).
    #[serde(default)]
    pub mock: bool,
    /// The simulated world used when `mock = true`.
    #[serde(default)]
    pub mock_world: MockWorldConfig,
    /// Serial devices and the frame source.
    #[serde(default)]
    pub devices: Devices,
    /// Agent (brain) settings.
    #[serde(default)]
    pub agent: AgentConfig,
    /// Peer Agent settings.
    #[serde(default)]
    pub peer: PeerConfig,
}

/// The simulated world of `mock = true`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MockWorldConfig {
    /// World file (TOML); the built-in thesis arena when absent.
    pub world: Option<PathBuf>,
    /// Seed of the sensor noise.
    pub seed: u64,
    /// World time runs this many times faster than real time.
    pub speed: f64,
}

impl Default for MockWorldConfig {
    fn default() -> Self {
        Self {
            world: None,
            seed: 1,
            speed: 1.0,
        }
    }
}

/// The devices of a robot. A role needs some of them: Skeeter `base`, `video_mux`,
/// `frames`; Scooter `base`, `laser`, `compass` (the compass is optional when the heading
/// source is odometry).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Devices {
    /// The mobile base.
    pub base: Option<BaseDevice>,
    /// The video switcher of the camera head.
    pub video_mux: Option<MuxDevice>,
    /// Where frames come from.
    pub frames: Option<FramesSource>,
    /// The SICK LMS laser scanner.
    pub laser: Option<LaserDevice>,
    /// The serial compass.
    pub compass: Option<CompassDeviceConfig>,
}

/// Base protocols.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum BaseKind {
    /// Pioneer 2-AT on P2OS (Skeeter).
    P2os,
    /// ATRV-Jr on rFLEX (Scooter).
    Rflex,
}

/// A mobile base on a serial port.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BaseDevice {
    /// Protocol.
    pub kind: BaseKind,
    /// Serial port, e.g. `/dev/ttyS0`.
    pub port: String,
    /// Line speed (P2OS: 9600, the driver also tries the robot's other rates; rFLEX: 115200).
    pub baud: u32,
    /// Seconds to wait for the base to answer.
    #[serde(default = "default_connect_timeout")]
    pub connect_timeout_s: f64,
}

/// Video switcher dialects.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum MuxDialect {
    /// Extron SIS.
    #[default]
    Extron,
    /// Kramer Protocol 2000.
    Kramer,
}

/// The video switcher.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MuxDevice {
    /// Serial port.
    pub port: String,
    /// Line speed (required; Extron switchers ship at 9600).
    pub baud: u32,
    /// Protocol.
    #[serde(default)]
    pub dialect: MuxDialect,
    /// Cameras on the switcher's inputs `1..=cameras`, counter-clockwise from forward.
    #[serde(default = "default_cameras")]
    pub cameras: u8,
    /// Horizontal field of view of each camera, degrees.
    #[serde(default = "default_fov")]
    pub fov_deg: f64,
}

/// A frame source.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FramesSource {
    /// A frame server (`ima_video_mux::net_frames` protocol), `host:port`. On the robot this
    /// is the grabber's server; with the mocks, the address `ima mock world` prints.
    pub addr: String,
    /// Per-grab timeout, milliseconds.
    #[serde(default = "default_grab_timeout")]
    pub timeout_ms: u64,
}

/// The SICK LMS.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LaserDevice {
    /// Serial port.
    pub port: String,
    /// Rate to run at after the probe (9600, 19200, 38400 or 500000).
    pub baud: u32,
    /// An RS-422 link is fitted (500 000 baud possible).
    #[serde(default)]
    pub rs422: bool,
    /// Seconds to wait for the unit's power-on telegram (units powered with the port).
    #[serde(default)]
    pub power_up_wait_s: f64,
}

/// Compass dialects.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum CompassDialect {
    /// KVH C100 (configured to NMEA at 10 Hz).
    #[default]
    Kvh,
    /// Any NMEA 0183 heading source, listen only.
    Nmea,
    /// PNI TCM2.
    Tcm2,
}

/// The serial compass.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CompassDeviceConfig {
    /// Serial port.
    pub port: String,
    /// Line speed (NMEA/KVH 4800, TCM2 9600).
    pub baud: u32,
    /// Dialect.
    #[serde(default)]
    pub dialect: CompassDialect,
    /// Installation deviation, degrees east (heading = compass + deviation).
    #[serde(default)]
    pub deviation_deg: f64,
}

/// Heading-calculation rules (issue 8 / thesis).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum HeadingRule {
    /// The thesis's isosceles rule.
    Thesis,
    /// The range-aware rule (uses Skeeter's range estimates).
    #[default]
    RangeAware,
}

/// Where Scooter's heading comes from.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum HeadingSource {
    /// The compass only.
    Compass,
    /// Odometry only.
    Odometry,
    /// Both (odometry, corrected by the compass).
    #[default]
    Both,
}

/// A colour of the colour database.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ColourEntry {
    /// Name (the target's name for the commander).
    pub name: String,
    /// Reference colour.
    pub rgb: [u8; 3],
    /// Diameter of objects of that colour, metres (for range estimates).
    pub diameter_m: f64,
}

/// Agent (brain) settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AgentConfig {
    /// Scooter: heading-calculation rule.
    pub heading_rule: HeadingRule,
    /// Scooter: heading source.
    pub heading_source: HeadingSource,
    /// Scooter: cruise speed, m/s.
    pub cruise_speed_m_s: f64,
    /// Scooter: largest turn rate, rad/s.
    pub max_turn_rad_s: f64,
    /// Scooter: brain steps per second.
    pub control_hz: f64,
    /// Skeeter: a target not accomplished within this many (mission) seconds fails.
    pub target_timeout_s: f64,
    /// Scooter: the target counts as reached when its centre is this close to Scooter's
    /// centre, metres (ATRV-Jr radius 0.4 m + object radius 0.15 m + clearance).
    pub reach_distance_m: f64,
    /// Scooter, range-aware rule: also range Skeeter with the laser (a cluster of Skeeter's
    /// diameter where its bearing says). Off by default: in the real-time runtime the laser
    /// fix led Scooter astray (targets reached late or falsely; see the CHANGELOG).
    pub laser_ranges_skeeter: bool,
    /// Scooter: seconds without a fresh SES before the lost timer fires.
    pub lost_timeout_s: f64,
    /// Mission clocks run this many times faster than real time. 1 on a real robot (a factor
    /// above 1 also widens the bases' odometry plausibility checks by it); the world's speed
    /// factor with `ima mock world --speed`.
    pub time_scale: f64,
    /// Skeeter: SAN network file (TOML, `agents/networks/skeeter.toml` format); the built-in
    /// network when absent. (Scooter's brain always runs its built-in network.)
    pub network: Option<PathBuf>,
    /// Compass heading (degrees clockwise from north) of the robots' common initial heading,
    /// i.e. the way Skeeter faces; 90 (east) in the built-in arena.
    pub common_heading_deg: f64,
    /// Scooter without a compass: its heading at start in the common frame, degrees
    /// counter-clockwise (with a compass the first reading gives it).
    pub initial_heading_deg: Option<f64>,
    /// Scooter: priority of its request for Skeeter's `ses` source.
    pub ses_request_priority: u8,
    /// Skeeter: the colour database (empty: the built-in thesis colours).
    pub colours: Vec<ColourEntry>,
    /// Commander: a robot silent on the broadcast channel for this many (mission) seconds
    /// is reported lost (every robot sends a status at least once a second).
    pub robot_lost_after_s: f64,
}

impl Default for AgentConfig {
    fn default() -> Self {
        Self {
            heading_rule: HeadingRule::default(),
            heading_source: HeadingSource::default(),
            cruise_speed_m_s: 0.3,
            max_turn_rad_s: 0.8,
            control_hz: 10.0,
            target_timeout_s: 180.0,
            reach_distance_m: 1.0,
            laser_ranges_skeeter: false,
            lost_timeout_s: 20.0,
            time_scale: 1.0,
            network: None,
            common_heading_deg: 90.0,
            initial_heading_deg: None,
            ses_request_priority: 5,
            colours: Vec::new(),
            robot_lost_after_s: 5.0,
        }
    }
}

/// Peer Agent settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PeerConfig {
    /// This robot's manager listens here (TCP). Skeeter always runs one (empty: the Peer
    /// Agent's default `0.0.0.0:7400`, or `127.0.0.1:7400` with the insecure key); for Scooter
    /// empty means no manager of its own; the commander never runs one.
    pub listen: String,
    /// The manager's data server (TCP) listens here (port 0: any free port; an address that
    /// names no interface, `0.0.0.0`, takes `listen`'s IP when that one names one, unless
    /// `data_advertise` is set).
    pub data_listen: String,
    /// The data address put in grants (set it on a LAN when `data_listen` is `0.0.0.0`).
    pub data_advertise: Option<String>,
    /// The manager whose sources this robot requests (Scooter: Skeeter's manager).
    pub connect: Option<String>,
    /// The group key file (32 random bytes, or 64 hex characters). Required unless
    /// `insecure`. A relative path is read from the working directory (as `ima peer`'s
    /// configurations are), not from the configuration file's directory.
    pub key_file: Option<PathBuf>,
    /// Run with a well-known all-zero key (tests and local experiments only).
    pub insecure: bool,
    /// Broadcast multicast group and port, `239.x.y.z:port`; empty: unicast only.
    pub broadcast_group: String,
    /// Unicast broadcast peers (`host:port`), the fallback where multicast is not routed.
    pub broadcast_peers: Vec<String>,
    /// Local address the broadcast socket binds, `ip:port`. Default: all interfaces on the
    /// group's port. With unicast peers on one host every process needs its own port.
    pub broadcast_bind: Option<String>,
    /// Robot priorities of the manager's three-part priority (higher wins).
    pub priorities: BTreeMap<String, u8>,
    /// Heartbeat period, milliseconds.
    pub heartbeat_ms: u64,
}

impl Default for PeerConfig {
    fn default() -> Self {
        Self {
            listen: String::new(),
            data_listen: "0.0.0.0:0".into(),
            data_advertise: None,
            connect: None,
            key_file: None,
            insecure: false,
            broadcast_group: "239.255.73.77:7601".into(),
            broadcast_peers: Vec::new(),
            broadcast_bind: None,
            priorities: BTreeMap::new(),
            heartbeat_ms: 100,
        }
    }
}

fn default_connect_timeout() -> f64 {
    10.0
}
fn default_cameras() -> u8 {
    7
}
fn default_fov() -> f64 {
    60.0
}
fn default_grab_timeout() -> u64 {
    2000
}

impl RobotConfig {
    /// Parse and check a configuration.
    #[cfg(test)]
    pub fn from_toml_str(s: &str) -> Result<Self> {
        Self::from_toml_str_with(s, false)
    }

    /// Parse a configuration, apply `--insecure` (a configuration that names no key file then
    /// runs on the documented all-zero key; one that names a key file keeps it), and check it.
    pub fn from_toml_str_with(s: &str, insecure: bool) -> Result<Self> {
        let mut c: Self = toml::from_str(s)
            .map_err(|e| anyhow::anyhow!("{}", ima_hal::file::located(s, e.span(), e.message())))
            .context("parsing the configuration")?;
        if insecure && c.peer.key_file.is_none() {
            c.peer.insecure = true;
        }
        c.check()?;
        Ok(c)
    }

    /// Read, parse and check a configuration file, with `--insecure` applied before the
    /// checks ([`from_toml_str_with`](Self::from_toml_str_with)).
    pub fn load_with(path: &Path, insecure: bool) -> Result<Self> {
        let s = ima_hal::file::read_text(path)
            .with_context(|| format!("reading {}", path.display()))?;
        Self::from_toml_str_with(&s, insecure).with_context(|| format!("in {}", path.display()))
    }

    /// The configuration as TOML.
    pub fn to_toml(&self) -> Result<String> {
        toml::to_string_pretty(self).context("writing the configuration")
    }

    /// Ranges of the configured devices' timing and geometry values.
    fn check_devices(&self) -> Result<()> {
        let d = &self.devices;
        // Line speeds as `--baud` takes them (0 would mean "hang up" to a real port).
        let bauds = [
            ("base", d.base.as_ref().map(|b| b.baud)),
            ("video_mux", d.video_mux.as_ref().map(|m| m.baud)),
            ("laser", d.laser.as_ref().map(|l| l.baud)),
            ("compass", d.compass.as_ref().map(|c| c.baud)),
        ];
        for (what, baud) in bauds {
            if let Some(b) = baud
                && !(50..=4_000_000).contains(&b)
            {
                bail!("devices.{what}.baud must be 50 to 4000000, not {b}");
            }
        }
        if let Some(b) = &d.base {
            let t = b.connect_timeout_s;
            if !(t.is_finite() && t > 0.0 && t <= 600.0) {
                bail!(
                    "devices.base.connect_timeout_s must be in (0, 600], not {}",
                    shown(t)
                );
            }
        }
        if let Some(m) = &d.video_mux {
            if !(1..=16).contains(&m.cameras) {
                bail!(
                    "devices.video_mux.cameras must be 1 to 16, not {}",
                    m.cameras
                );
            }
            if !(m.fov_deg.is_finite() && m.fov_deg > 0.0 && m.fov_deg <= 360.0) {
                bail!(
                    "devices.video_mux.fov_deg must be in (0, 360], not {}",
                    shown(m.fov_deg)
                );
            }
        }
        if let Some(f) = &d.frames
            && !(1..=60_000).contains(&f.timeout_ms)
        {
            bail!(
                "devices.frames.timeout_ms must be 1 to 60000, not {}",
                f.timeout_ms
            );
        }
        if let Some(l) = &d.laser {
            let w = l.power_up_wait_s;
            if !(w.is_finite() && (0.0..=120.0).contains(&w)) {
                bail!(
                    "devices.laser.power_up_wait_s must be in [0, 120], not {}",
                    shown(w)
                );
            }
        }
        Ok(())
    }

    /// The `[peer]` addresses' shapes, before any device or socket is opened (a typo in
    /// `peer.listen` used to show only once the devices had connected). Names are looked up
    /// when the network starts; these checks need no lookup.
    fn check_addresses(&self) -> Result<()> {
        use ima_agents::peer::net::is_host_port;
        let p = &self.peer;
        let host_ports = [
            ("peer.listen", Some(&p.listen).filter(|l| !l.is_empty())),
            ("peer.data_listen", Some(&p.data_listen)),
            ("peer.connect", p.connect.as_ref()),
        ];
        for (key, a) in host_ports {
            if let Some(a) = a
                && !is_host_port(a)
            {
                bail!("{key} must be HOST:PORT (e.g. \"192.168.1.10:7600\"), not {a:?}");
            }
        }
        // The broadcast socket takes IPv4 literals only (no name lookup).
        let v4 = |key: &str, a: &str| -> Result<std::net::SocketAddrV4> {
            a.parse().map_err(|_| {
                anyhow::anyhow!(
                    "{key} must be an IPv4 address and port (e.g. \"10.0.0.5:7601\"), not {a:?}"
                )
            })
        };
        if !p.broadcast_group.is_empty() {
            let g = v4("peer.broadcast_group", &p.broadcast_group)?;
            if !g.ip().is_multicast() {
                bail!(
                    "peer.broadcast_group {g} is not a multicast address (224.0.0.0 to \
                     239.255.255.255; \"\" with peer.broadcast_peers for unicast only)"
                );
            }
        }
        for a in &p.broadcast_peers {
            v4("peer.broadcast_peers", a)?;
        }
        if let Some(a) = &p.broadcast_bind {
            v4("peer.broadcast_bind", a)?;
        }
        Ok(())
    }

    /// The role's serial devices each name a port of their own. A copied device section
    /// whose `port` was not changed would otherwise fail only when the second device opened
    /// it, after the first had connected, as "Device or resource busy", which reads as
    /// another program holding the port. Paths that name one device through a link
    /// (`/dev/serial/by-id/…`) are compared where they exist. Sections the role does not open
    /// (a laser in Skeeter's configuration) are not compared.
    fn check_ports(&self) -> Result<()> {
        let d = &self.devices;
        let base = ("base", d.base.as_ref().map(|b| &b.port));
        let ports = match self.role {
            Role::Skeeter => vec![base, ("video_mux", d.video_mux.as_ref().map(|m| &m.port))],
            Role::Scooter => vec![
                base,
                ("laser", d.laser.as_ref().map(|l| &l.port)),
                ("compass", d.compass.as_ref().map(|c| &c.port)),
            ],
            Role::Commander => Vec::new(),
        };
        let mut seen: Vec<(&str, &str, std::path::PathBuf)> = Vec::new();
        for (what, port) in ports {
            let Some(port) = port else { continue };
            if port.trim().is_empty() {
                bail!("devices.{what}.port is empty: name the serial port (e.g. /dev/ttyUSB0)");
            }
            let path = std::fs::canonicalize(port).unwrap_or_else(|_| port.into());
            if let Some((other, other_port, _)) = seen.iter().find(|(_, _, p)| *p == path) {
                let same = if other_port == port {
                    String::new()
                } else {
                    format!(" ({other_port} and {port} are one device)")
                };
                bail!(
                    "devices.{other}.port and devices.{what}.port both name {port}{same}: \
                     each device needs its own serial port"
                );
            }
            seen.push((what, port, path));
        }
        Ok(())
    }

    /// Check values and that the role's devices are configured (unless `mock`).
    pub fn check(&self) -> Result<()> {
        let a = &self.agent;
        // (name, value, smallest, largest): bounded so that every duration derived from them
        // is representable.
        let bounded = [
            ("agent.cruise_speed_m_s", a.cruise_speed_m_s, 1e-3, 1.0),
            ("agent.max_turn_rad_s", a.max_turn_rad_s, 1e-3, 10.0),
            ("agent.control_hz", a.control_hz, 0.1, 1000.0),
            ("agent.target_timeout_s", a.target_timeout_s, 1e-3, 1e6),
            ("agent.lost_timeout_s", a.lost_timeout_s, 1e-3, 1e6),
            ("agent.reach_distance_m", a.reach_distance_m, 1e-3, 10.0),
            ("agent.time_scale", a.time_scale, 0.01, 100.0),
            (
                "agent.robot_lost_after_s",
                a.robot_lost_after_s,
                0.1,
                3600.0,
            ),
            // As `ima mock world --speed` takes it.
            ("mock_world.speed", self.mock_world.speed, 0.05, 20.0),
            // Degrees (NaN left Scooter with no heading for ever, standing still).
            (
                "agent.common_heading_deg",
                a.common_heading_deg,
                -360.0,
                360.0,
            ),
            (
                "agent.initial_heading_deg",
                a.initial_heading_deg.unwrap_or(0.0),
                -360.0,
                360.0,
            ),
            (
                "devices.compass.deviation_deg",
                self.devices
                    .compass
                    .as_ref()
                    .map_or(0.0, |c| c.deviation_deg),
                -360.0,
                360.0,
            ),
        ];
        for (name, v, lo, hi) in bounded {
            if !(v.is_finite() && (lo..=hi).contains(&v)) {
                bail!("{name} must be a number in [{lo}, {hi}], not {}", shown(v));
            }
        }
        self.check_devices()?;
        // Peer Agent periods, ms: 0 would spin (it used to be taken as 1), a huge one never
        // declares a dead peer lost.
        if let Some(a) = &self.peer.data_advertise
            && !ima_agents::peer::net::is_host_port(a)
        {
            bail!("peer.data_advertise must be HOST:PORT (e.g. \"10.0.0.5:7401\"), not {a:?}");
        }
        self.check_addresses()?;
        let hb = self.peer.heartbeat_ms;
        if !(10..=60_000).contains(&hb) {
            bail!("peer.heartbeat_ms must be in [10, 60000] ms, not {hb}");
        }
        if a.cruise_speed_m_s > 1.0 {
            bail!("agent.cruise_speed_m_s must be at most 1 m/s");
        }
        if self.robot.trim().is_empty() {
            bail!("robot must be a non-empty name");
        }
        // Every Peer frame carries the name as a string of at most 255 bytes.
        let max = ima_agents::peer::wire::MAX_STR_LEN;
        if self.robot.len() > max {
            bail!(
                "robot must be a name of at most {max} bytes, not {} bytes",
                self.robot.len()
            );
        }
        if !self.peer.insecure && self.peer.key_file.is_none() {
            bail!("peer.key_file is required (or peer.insecure = true for local tests)");
        }
        if self.mock {
            return Ok(());
        }
        self.check_ports()?;
        let d = &self.devices;
        let need = |what: &str, present: bool| {
            if present {
                Ok(())
            } else {
                Err(anyhow::anyhow!(
                    "role {:?} needs [devices.{what}] (or mock = true)",
                    self.role
                ))
            }
        };
        match self.role {
            Role::Skeeter => {
                need("base", d.base.is_some())?;
                need("video_mux", d.video_mux.is_some())?;
                need("frames", d.frames.is_some())?;
                if let Some(b) = &d.base
                    && b.kind != BaseKind::P2os
                {
                    bail!("Skeeter's base is a P2OS robot (devices.base.kind = \"p2os\")");
                }
            }
            Role::Scooter => {
                if a.network.is_some() {
                    bail!("agent.network: Scooter's brain runs its built-in network");
                }
                need("base", d.base.is_some())?;
                need("laser", d.laser.is_some())?;
                if a.heading_source != HeadingSource::Odometry {
                    need("compass", d.compass.is_some())?;
                }
                if let Some(b) = &d.base
                    && b.kind != BaseKind::Rflex
                {
                    bail!("Scooter's base is an rFLEX robot (devices.base.kind = \"rflex\")");
                }
                if self.peer.connect.is_none() {
                    bail!("Scooter needs peer.connect (Skeeter's manager address)");
                }
            }
            Role::Commander => {}
        }
        Ok(())
    }
}

/// Write `key` as 64 hex characters and a newline.
pub fn key_to_hex(key: &[u8; 32]) -> String {
    let mut s: String = key.iter().map(|b| format!("{b:02x}")).collect();
    s.push('\n');
    s
}

/// A number for a message: as written for ordinary magnitudes, in exponent form beyond
/// (`1e300` was printed with all its 301 digits).
pub fn shown(v: f64) -> String {
    if v.is_finite() && v != 0.0 && !(1e-6..1e9).contains(&v.abs()) {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn example(name: &str) -> String {
        std::fs::read_to_string(format!("{}/configs/{name}", env!("CARGO_MANIFEST_DIR"))).unwrap()
    }

    /// Huge and tiny numbers are shown in exponent form, ordinary ones as written; a value
    /// of 1e300 in a key made a 300-digit message.
    #[test]
    fn numbers_in_messages_stay_short() {
        assert_eq!(shown(1e300), "1e300");
        assert_eq!(shown(-2.5e12), "-2.5e12");
        assert_eq!(shown(1e-9), "1e-9");
        assert_eq!(shown(700.0), "700");
        assert_eq!(shown(0.25), "0.25");
        assert_eq!(shown(0.0), "0");
        assert_eq!(shown(f64::NAN), "NaN");
        let text = example("skeeter.toml")
            .replace("connect_timeout_s = 10.0", "connect_timeout_s = 1e300");
        let e = format!("{:#}", RobotConfig::from_toml_str(&text).unwrap_err());
        assert!(e.contains("not 1e300"), "{e}");
    }

    #[test]
    fn example_configs_parse_and_check() {
        let sk = RobotConfig::from_toml_str(&example("skeeter.toml")).unwrap();
        assert_eq!(sk.role, Role::Skeeter);
        assert_eq!(sk.devices.base.as_ref().unwrap().port, "/dev/ttyS0");
        let sc = RobotConfig::from_toml_str(&example("scooter.toml")).unwrap();
        assert_eq!(sc.role, Role::Scooter);
        assert_eq!(sc.devices.base.as_ref().unwrap().kind, BaseKind::Rflex);
        let c = RobotConfig::from_toml_str(&example("commander.toml")).unwrap();
        assert_eq!(c.role, Role::Commander);
        // Round trip through TOML.
        assert_eq!(
            RobotConfig::from_toml_str(&sc.to_toml().unwrap()).unwrap(),
            sc
        );
    }

    #[test]
    fn two_devices_on_one_port_are_refused() {
        let sc = example("scooter.toml");
        let copied = sc.replace("\"/dev/ttyS2\"", "\"/dev/ttyS1\"");
        let e = RobotConfig::from_toml_str(&copied).unwrap_err();
        assert_eq!(
            format!("{e:#}"),
            "devices.laser.port and devices.compass.port both name /dev/ttyS1: each device \
             needs its own serial port"
        );
        // A section the role does not open is not compared (Skeeter has no laser).
        let skeeter = example("skeeter.toml");
        let laser = "\n[devices.laser]\nport = \"/dev/ttyS0\"\nbaud = 9600\n";
        RobotConfig::from_toml_str(&format!("{skeeter}{laser}")).unwrap();
        let empty = sc.replace("\"/dev/ttyS2\"", "\"\"");
        let e = RobotConfig::from_toml_str(&empty).unwrap_err();
        assert!(
            format!("{e:#}").contains("devices.compass.port is empty"),
            "{e:#}"
        );
        // One device under two names (a by-id link and the node it points to).
        #[cfg(unix)]
        {
            let dir = std::env::temp_dir().join(format!("ima-ports-{}", std::process::id()));
            std::fs::create_dir_all(&dir).unwrap();
            let (node, link) = (dir.join("ttyUSB0"), dir.join("by-id-laser"));
            std::fs::write(&node, b"").unwrap();
            let _ = std::fs::remove_file(&link);
            std::os::unix::fs::symlink(&node, &link).unwrap();
            let aliased = sc
                .replace("/dev/ttyS1", link.to_str().unwrap())
                .replace("/dev/ttyS2", node.to_str().unwrap());
            let e = format!("{:#}", RobotConfig::from_toml_str(&aliased).unwrap_err());
            std::fs::remove_dir_all(&dir).unwrap();
            assert!(e.contains(" are one device)"), "{e}");
        }
        // A mock run opens no port: its placeholders may repeat.
        let mock = copied.replace("mock = false", "mock = true");
        assert!(RobotConfig::from_toml_str(&mock).is_ok());
    }

    #[test]
    fn mistakes_are_reported() {
        let base = "robot = \"skeeter\"\nrole = \"skeeter\"\n[peer]\ninsecure = true\n";
        let e = RobotConfig::from_toml_str(base).unwrap_err();
        assert!(format!("{e:#}").contains("devices.base"), "{e:#}");
        let typo = format!("{base}\n[agent]\ncruise_sped_m_s = 1.0\n");
        assert!(RobotConfig::from_toml_str(&typo).is_err());
        let slow =
            "robot = \"x\"\nrole = \"commander\"\nmock = true\n[agent]\ncruise_speed_m_s = -1\n";
        assert!(RobotConfig::from_toml_str(slow).is_err());
        let nokey = "robot = \"c\"\nrole = \"commander\"\n";
        let e = RobotConfig::from_toml_str(nokey).unwrap_err();
        assert!(format!("{e:#}").contains("key_file"), "{e:#}");
        // `--insecure` is applied before the check (it was checked first, so the flag never
        // helped a configuration without a key file); a named key file stays.
        assert!(
            RobotConfig::from_toml_str_with(nokey, true)
                .unwrap()
                .peer
                .insecure
        );
        let named = format!("{nokey}[peer]\nkey_file = \"/k\"\n");
        let c = RobotConfig::from_toml_str_with(&named, true).unwrap();
        assert!(!c.peer.insecure);
        let mock = "robot = \"skeeter\"\nrole = \"skeeter\"\nmock = true\n";
        let e = RobotConfig::from_toml_str(mock).unwrap_err();
        assert!(
            format!("{e:#}").contains("key_file"),
            "a mock run needs a key too: {e:#}"
        );
        let mock = format!("{mock}[peer]\ninsecure = true\n");
        assert!(RobotConfig::from_toml_str(&mock).unwrap().mock);
        // (fragment, key named in the error); `mock` ends in the [peer] table.
        for (bad, key) in [
            ("[agent]\ntime_scale = 1e-300\n", "agent.time_scale"),
            ("[agent]\ncontrol_hz = 1e-300\n", "agent.control_hz"),
            ("[agent]\nlost_timeout_s = 1e300\n", "agent.lost_timeout_s"),
            (
                "[agent]\ntarget_timeout_s = nan\n",
                "agent.target_timeout_s",
            ),
            (
                "[agent]\nrobot_lost_after_s = 0\n",
                "agent.robot_lost_after_s",
            ),
            ("heartbeat_ms = 0\n", "peer.heartbeat_ms"),
            ("heartbeat_ms = 100000000\n", "peer.heartbeat_ms"),
            // As `ima mock world --speed` takes it (it took up to 100).
            ("[mock_world]\nspeed = 50\n", "mock_world.speed"),
        ] {
            let cfg = format!("{mock}{bad}");
            let e = format!("{:#}", RobotConfig::from_toml_str(&cfg).unwrap_err());
            // The key is named, with its range.
            assert!(e.contains(key) && e.contains('['), "{bad}: {e}");
        }
        // Found by trying every key: a NaN heading left Scooter standing for ever, and a baud
        // of 0 (hang up) or 4294967295 was taken as it was.
        let compass = "[devices.compass]\nport = \"/dev/x\"\n";
        for (bad, key) in [
            (
                "[agent]\ncommon_heading_deg = nan\n",
                "agent.common_heading_deg",
            ),
            (
                "[agent]\ninitial_heading_deg = 1e9\n",
                "agent.initial_heading_deg",
            ),
            (&format!("{compass}baud = 0\n"), "devices.compass.baud"),
            (
                &format!("{compass}baud = 4294967295\n"),
                "devices.compass.baud",
            ),
            (
                &format!("{compass}baud = 4800\ndeviation_deg = inf\n"),
                "devices.compass.deviation_deg",
            ),
            ("data_advertise = \"x\"\n", "peer.data_advertise"),
            // Addresses are checked before any device opens (they failed only once the
            // devices had connected).
            ("listen = \"nope\"\n", "peer.listen"),
            ("data_listen = \"7401\"\n", "peer.data_listen"),
            ("connect = \"skeeter\"\n", "peer.connect"),
            ("broadcast_group = \"239.1.2.3\"\n", "peer.broadcast_group"),
            ("broadcast_group = \"10.0.0.1:7601\"\n", "not a multicast"),
            ("broadcast_peers = [\"zz\"]\n", "peer.broadcast_peers"),
            (
                "broadcast_bind = \"localhost:7601\"\n",
                "peer.broadcast_bind",
            ),
        ] {
            let cfg = format!("{mock}{bad}");
            let e = format!("{:#}", RobotConfig::from_toml_str(&cfg).unwrap_err());
            assert!(e.contains(key), "{bad}: {e}");
        }
        let fine = format!("{mock}{compass}baud = 4800\ndeviation_deg = -3.5\n");
        assert!(RobotConfig::from_toml_str(&fine).is_ok());
        let names = format!(
            "{mock}listen = \"skeeter.local:7600\"\nconnect = \"[::1]:7600\"\n\
             broadcast_group = \"\"\nbroadcast_peers = [\"10.0.0.2:7601\"]\n"
        );
        assert!(RobotConfig::from_toml_str(&names).is_ok());
        // A name no Peer frame can carry is refused here, not at the first broadcast.
        let named = |n: usize| {
            let cfg = format!(
                "robot = \"{}\"\nrole = \"commander\"\n[peer]\ninsecure = true\n",
                "r".repeat(n)
            );
            RobotConfig::from_toml_str(&cfg)
        };
        assert!(named(255).is_ok());
        let e = format!("{:#}", named(256).unwrap_err());
        assert!(e.contains("at most 255 bytes, not 256"), "{e}");
    }

    #[test]
    fn hex_keys_are_what_the_peer_agent_reads() {
        let raw = [7u8; 32];
        assert!(ima_agents::peer::net::parse_key(key_to_hex(&raw).as_bytes()).is_ok());
        assert!(ima_agents::peer::net::parse_key(b"0123").is_err());
    }
}

//! `ima mock world`: one simulated world serving every device of both robots (ptys and the
//! TCP frame server), one JSON line of endpoints on stdout, and optionally ready-to-use robot
//! configurations for `ima run` / `ima commander`.

use std::io::Write;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use ima_mock_devices::served::{Endpoints, ServeOptions, ServedWorld};

use crate::config::{
    BaseDevice, BaseKind, CompassDeviceConfig, CompassDialect, Devices, FramesSource, LaserDevice,
    MuxDevice, MuxDialect, PeerConfig, RobotConfig, Role, key_to_hex,
};

/// Options of `ima mock world` (a subset of `ima mock`'s flags).
#[derive(Debug, Clone)]
pub struct WorldOptions {
    /// World file; the thesis arena when absent.
    pub world: Option<PathBuf>,
    /// Seed.
    pub seed: u64,
    /// Speed-up factor.
    pub speed: f64,
    /// Where to bind the frame server.
    pub frames_addr: SocketAddr,
    /// Write skeeter.toml, scooter.toml, commander.toml and group.key here.
    pub write_configs: Option<PathBuf>,
    /// `--faults`, between every serial device and its port.
    pub faults: ima_mock_devices::faults::FaultPlan,
}

/// Start the world and its devices.
pub fn serve(opts: &WorldOptions) -> Result<ServedWorld> {
    let world = super::shared::load_world(opts.world.as_ref(), opts.seed)?;
    ServedWorld::start(
        world,
        &ServeOptions {
            seed: opts.seed,
            speed: opts.speed,
            frames_addr: opts.frames_addr,
            faults: opts.faults.clone(),
            ..ServeOptions::default()
        },
    )
    .context("serving the world")
}

/// 32 random bytes from the operating system.
pub fn random_key() -> Result<[u8; 32]> {
    use std::io::Read;
    let mut key = [0u8; 32];
    std::fs::File::open("/dev/urandom")
        .and_then(|mut f| f.read_exact(&mut key))
        .context("reading /dev/urandom for a group key")?;
    Ok(key)
}

/// The three processes' configurations for a served world: devices on its endpoints, peers on
/// loopback (fresh ports; broadcast over unicast peers), mission clocks at the world's speed.
pub fn loopback_configs(
    e: &Endpoints,
    speed: f64,
    key_file: Option<&Path>,
) -> Result<[RobotConfig; 3]> {
    // Ports are filled in by `assign_ports`; `listen`/`connect` say who has them.
    let peer = |listen: bool, connect: bool| PeerConfig {
        listen: if listen {
            "127.0.0.1:0".into()
        } else {
            String::new()
        },
        data_listen: "127.0.0.1:0".into(),
        connect: connect.then(|| "127.0.0.1:0".into()),
        key_file: key_file.map(Path::to_path_buf),
        insecure: key_file.is_none(),
        broadcast_group: String::new(),
        ..PeerConfig::default()
    };
    let mut base = RobotConfig {
        robot: String::new(),
        role: Role::Commander,
        mock: false,
        mock_world: Default::default(),
        devices: Devices::default(),
        agent: Default::default(),
        peer: PeerConfig::default(),
    };
    base.agent.time_scale = speed;
    let mut skeeter = base.clone();
    skeeter.robot = "skeeter".into();
    skeeter.role = Role::Skeeter;
    skeeter.devices.base = Some(BaseDevice {
        kind: BaseKind::P2os,
        port: e.skeeter.base.display().to_string(),
        baud: 9600,
        connect_timeout_s: 10.0,
    });
    skeeter.devices.video_mux = Some(MuxDevice {
        port: e.skeeter.video_mux.display().to_string(),
        baud: 9600,
        dialect: MuxDialect::Extron,
        cameras: 7,
        fov_deg: 60.0,
    });
    skeeter.devices.frames = Some(FramesSource {
        addr: e.skeeter.frames.clone(),
        timeout_ms: 2000,
    });
    skeeter.peer = peer(true, false);
    skeeter.peer.priorities = [("scooter".to_owned(), 2), ("commander".to_owned(), 1)].into();
    let mut scooter = base.clone();
    scooter.robot = "scooter".into();
    scooter.role = Role::Scooter;
    let (kind, baud) = match e.scooter.base_kind {
        ima_mock_devices::served::BaseKind::Rflex => (BaseKind::Rflex, 115_200),
        ima_mock_devices::served::BaseKind::P2os => (BaseKind::P2os, 9600),
    };
    scooter.devices.base = Some(BaseDevice {
        kind,
        port: e.scooter.base.display().to_string(),
        baud,
        connect_timeout_s: 10.0,
    });
    scooter.devices.laser = Some(LaserDevice {
        port: e.scooter.laser.display().to_string(),
        // The mock LMS has an RS-422 link: 500 000 baud gives 75 scans/s, which a sped-up
        // world needs (38 400 baud gives about 5).
        baud: 500_000,
        rs422: true,
        power_up_wait_s: 0.0,
    });
    scooter.devices.compass = Some(CompassDeviceConfig {
        port: e.scooter.compass.display().to_string(),
        baud: 4800,
        dialect: CompassDialect::Kvh,
        deviation_deg: 0.0,
    });
    scooter.peer = peer(true, true);
    let mut commander = base;
    commander.robot = "commander".into();
    commander.role = Role::Commander;
    commander.peer = peer(false, false);
    let mut fleet = [skeeter, scooter, commander];
    let [a, b, c] = &mut fleet;
    assign_ports([a, b, c])?;
    Ok(fleet)
}

/// Fresh loopback ports for Skeeter, Scooter and the commander of [`loopback_configs`]:
/// both managers' `listen`, Scooter's `connect` to Skeeter's, and each one's broadcast
/// `bind` with the other two as its `peers`. `ima demo` calls it again just before its
/// robots bind, so that another process has milliseconds, not the seconds the devices take
/// to open, to take a port picked and released here (it happened under a parallel test
/// run: Scooter reached another demo's Skeeter, and its own could not bind).
///
/// # Errors
/// No free port.
pub fn assign_ports([skeeter, scooter, commander]: [&mut RobotConfig; 3]) -> Result<()> {
    let (managers, bcast) = ima_mock_devices::served::free_ports(2, 3)?;
    let at = |p: u16| format!("127.0.0.1:{p}");
    skeeter.peer.listen = at(managers[0]);
    scooter.peer.listen = at(managers[1]);
    scooter.peer.connect = Some(at(managers[0]));
    for (i, c) in [skeeter, scooter, commander].into_iter().enumerate() {
        c.peer.broadcast_bind = bcast.get(i).copied().map(at);
        c.peer.broadcast_peers = bcast
            .iter()
            .enumerate()
            .filter(|(j, _)| *j != i)
            .map(|(_, p)| at(*p))
            .collect();
    }
    Ok(())
}

/// The files [`write_configs`] writes into a directory.
pub const CONFIG_FILES: [&str; 4] = [
    "group.key",
    "skeeter.toml",
    "scooter.toml",
    "commander.toml",
];

/// Fails, naming them, when any of [`CONFIG_FILES`] already exists in `dir` (a new group key
/// would lock out every robot still using the old one).
///
/// # Errors
/// The files that exist.
pub fn refuse_overwrite(dir: &Path) -> Result<()> {
    let existing: Vec<String> = CONFIG_FILES
        .iter()
        .map(|f| dir.join(f))
        .filter(|p| p.symlink_metadata().is_ok())
        .map(|p| p.display().to_string())
        .collect();
    anyhow::ensure!(
        existing.is_empty(),
        "--write-configs {}: {} already exist(s); pass --force to replace them",
        dir.display(),
        existing.join(", ")
    );
    Ok(())
}

/// Write the three configurations and a fresh `group.key` into `dir`.
pub fn write_configs(dir: &Path, e: &Endpoints, speed: f64) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let key_path = dir.join("group.key");
    std::fs::write(&key_path, key_to_hex(&random_key()?))
        .with_context(|| format!("writing {}", key_path.display()))?;
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&key_path, std::fs::Permissions::from_mode(0o600))
            .with_context(|| format!("chmod 600 {}", key_path.display()))?;
    }
    let key_path = std::fs::canonicalize(&key_path).unwrap_or(key_path);
    for c in loopback_configs(e, speed, Some(&key_path))? {
        let path = dir.join(format!("{}.toml", c.robot));
        let text = format!(
            "# Written by `ima mock world --write-configs` for the world it serves.\n{}",
            c.to_toml()?
        );
        std::fs::write(&path, text).with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}

/// One line naming where every served device is, for people.
pub fn describe(e: &Endpoints) -> String {
    format!(
        "Skeeter: P2OS {} · switcher {} · frames {}; Scooter: {} {} · LMS {} · compass {}",
        e.skeeter.base.display(),
        e.skeeter.video_mux.display(),
        e.skeeter.frames,
        match e.scooter.base_kind {
            ima_mock_devices::served::BaseKind::Rflex => "rFLEX",
            ima_mock_devices::served::BaseKind::P2os => "P2OS",
        },
        e.scooter.base.display(),
        e.scooter.laser.display(),
        e.scooter.compass.display()
    )
}

/// Run `ima mock world` until SIGINT/SIGTERM.
pub fn run(opts: &WorldOptions) -> Result<()> {
    let served = serve(opts)?;
    let e = served.endpoints().clone();
    if let Some(dir) = &opts.write_configs {
        write_configs(dir, &e, opts.speed)?;
    }
    {
        let line = serde_json::json!({
            "kind": "world",
            "seed": opts.seed,
            "speed": opts.speed,
            "skeeter": e.skeeter,
            "scooter": e.scooter,
            "configs": opts.write_configs,
        });
        let mut out = std::io::stdout().lock();
        writeln!(out, "{line}")?;
        out.flush()?;
    }
    eprintln!(
        "serving the world ×{} (seed {}): {}; Ctrl-C to stop",
        opts.speed,
        opts.seed,
        describe(&e)
    );
    let ended = super::shared::wait_for_interrupt();
    // What each line carried, with the faults injected (`--faults`): the three-process set-up
    // has no other place that says so.
    for (device, status) in served.links() {
        eprintln!("{device}: {}", status.counters);
    }
    drop(served);
    ended
}

//! The three-process mission set-up shared by the end-to-end tests: configurations and a key
//! file for Skeeter, Scooter and the commander on a world the test process serves.

use std::path::{Path, PathBuf};

use ima_mock_devices::served::Endpoints;

/// A free loopback port (TCP, or UDP when `udp`).
pub fn free_port(udp: bool) -> u16 {
    let (tcp, udp) = if udp {
        free_ports(0, 1)
    } else {
        free_ports(1, 0)
    };
    tcp.into_iter().chain(udp).next().unwrap()
}

/// `tcp` TCP and `udp` UDP loopback ports, all different
/// ([`ima_mock_devices::served::free_ports`]).
pub fn free_ports(tcp: usize, udp: usize) -> (Vec<u16>, Vec<u16>) {
    ima_mock_devices::served::free_ports(tcp, udp).unwrap()
}

/// A scratch directory for one test (see [`super::Scratch`]).
pub fn scratch_dir(name: &str) -> super::Scratch {
    super::Scratch::new(name)
}

/// Write the three configurations and a key file, as an operator would.
pub fn write_configs(dir: &Path, e: &Endpoints, speed: f64) -> [PathBuf; 3] {
    let key = dir.join("group.key");
    let hex: String = (0..32u8)
        .map(|i| format!("{:02x}", i.wrapping_mul(37).wrapping_add(11)))
        .collect();
    std::fs::write(&key, format!("{hex}\n")).unwrap();
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&key, std::fs::Permissions::from_mode(0o600)).unwrap();
    }
    let (managers, b) = free_ports(2, 3);
    let (mgr, scooter_mgr) = (managers[0], managers[1]);
    let peers = |i: usize| {
        b.iter()
            .enumerate()
            .filter(|(j, _)| *j != i)
            .map(|(_, p)| format!("\"127.0.0.1:{p}\""))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let peer = |i: usize| {
        format!(
            "key_file = {key:?}\nbroadcast_group = \"\"\nbroadcast_peers = [{}]\nbroadcast_bind = \"127.0.0.1:{}\"\ndata_listen = \"127.0.0.1:0\"\n",
            peers(i),
            b[i]
        )
    };
    let skeeter = format!(
        r#"robot = "skeeter"
role = "skeeter"

[devices.base]
kind = "p2os"
port = {:?}
baud = 9600

[devices.video_mux]
port = {:?}
baud = 9600

[devices.frames]
addr = "{}"

[agent]
time_scale = {speed}
target_timeout_s = 240.0

[peer]
listen = "127.0.0.1:{mgr}"
{}"#,
        e.skeeter.base,
        e.skeeter.video_mux,
        e.skeeter.frames,
        peer(0)
    );
    let scooter = format!(
        r#"robot = "scooter"
role = "scooter"

[devices.base]
kind = "rflex"
port = {:?}
baud = 115200

[devices.laser]
port = {:?}
baud = 500000
rs422 = true

[devices.compass]
port = {:?}
baud = 4800

[agent]
time_scale = {speed}

[peer]
listen = "127.0.0.1:{scooter_mgr}"
connect = "127.0.0.1:{mgr}"
{}"#,
        e.scooter.base,
        e.scooter.laser,
        e.scooter.compass,
        peer(1)
    );
    let commander = format!(
        r#"robot = "commander"
role = "commander"

[agent]
time_scale = {speed}
target_timeout_s = 330.0

[peer]
{}"#,
        peer(2)
    );
    let paths = ["skeeter", "scooter", "commander"].map(|n| dir.join(format!("{n}.toml")));
    for (p, text) in paths.iter().zip([skeeter, scooter, commander]) {
        std::fs::write(p, text).unwrap();
    }
    paths
}

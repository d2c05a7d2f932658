//! The mission end to end as three separate `ima` processes (issue 8): the test process
//! serves the simulated world (every serial device on a pty, Skeeter's frames on the TCP
//! frame server); `ima run --config skeeter.toml`, `ima run --config scooter.toml` and
//! `ima commander --config commander.toml --targets …` talk over loopback sockets (Peer
//! Agent manager/client for the `ses` source, unicast broadcast channel) with a group key
//! from a key file. Asserts on the outcome: the commander exits 0 and its JSON events show
//! every target done.

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::Stdio;
use std::time::{Duration, Instant};

use ima_mock_devices::served::{ServeOptions, ServedWorld};
use ima_mock_devices::world::{SharedWorld, World};

mod common;
use common::mission::{scratch_dir, write_configs};
use common::{Child, ima};

const SPEED: f64 = 4.0;

fn run_robot(config: &Path, log: &Path) -> Child {
    Child(
        ima()
            .args(["run", "--json", "--config"])
            .arg(config)
            .stdout(std::fs::File::create(log).unwrap())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    )
}

#[test]
fn three_processes_accomplish_every_target() {
    let world = SharedWorld::new(World::default_world());
    let served = ServedWorld::start(
        world,
        &ServeOptions {
            seed: 11,
            speed: SPEED,
            ..ServeOptions::default()
        },
    )
    .unwrap();
    let dir = scratch_dir("mission-e2e");
    let [sk, sc, cmd] = write_configs(&dir, served.endpoints(), SPEED);
    let _skeeter = run_robot(&sk, &dir.join("skeeter.jsonl"));
    let _scooter = run_robot(&sc, &dir.join("scooter.jsonl"));
    let mut commander = Child(
        ima()
            .args([
                "commander",
                "--json",
                "--targets",
                "red,blue,green",
                "--config",
            ])
            .arg(&cmd)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    // Read the commander's events until it exits (generous limit for a loaded machine).
    let out = commander.0.stdout.take().unwrap();
    let reader = std::thread::spawn(move || {
        BufReader::new(out)
            .lines()
            .map_while(Result::ok)
            .map(|l| serde_json::from_str::<serde_json::Value>(&l).unwrap())
            .collect::<Vec<_>>()
    });
    let deadline = Instant::now() + Duration::from_secs(400);
    let status = loop {
        if let Some(s) = commander.0.try_wait().unwrap() {
            break s;
        }
        assert!(
            Instant::now() < deadline,
            "the commander did not finish; robots' logs in {}",
            dir.display()
        );
        std::thread::sleep(Duration::from_millis(200));
    };
    let events = reader.join().unwrap();
    let finals: Vec<(String, String)> = events
        .iter()
        .filter(|e| e["kind"] == "target")
        .filter(|e| matches!(e["detail"]["state"].as_str(), Some("done" | "failed")))
        .map(|e| {
            (
                e["detail"]["target"].as_str().unwrap().to_owned(),
                e["detail"]["state"].as_str().unwrap().to_owned(),
            )
        })
        .collect();
    assert_eq!(
        finals,
        [("red", "done"), ("blue", "done"), ("green", "done")]
            .map(|(a, b)| (a.to_owned(), b.to_owned())),
        "robots' logs in {}",
        dir.display()
    );
    assert!(status.success(), "commander exit status {status}");
    let summary = events.iter().find(|e| e["kind"] == "summary").unwrap();
    assert_eq!(summary["done"], 3);
    assert_eq!(summary["failed"], 0);
    // The commander heard the robots' broadcasts: Skeeter's acceptances and Scooter's
    // target-reached notices.
    let heard = |pred: &dyn Fn(&serde_json::Value) -> bool| {
        events
            .iter()
            .filter(|e| e["kind"] == "broadcast")
            .any(|e| pred(&e["detail"]))
    };
    assert!(heard(
        &|d| d["robot"] == "skeeter" && d["event"] == "accepted"
    ));
    assert!(heard(
        &|d| d["robot"] == "scooter" && d["kind"] == "target-reached"
    ));
    // Scooter's stack got Skeeter's SES through the Peer Agent.
    let scooter_log = std::fs::read_to_string(dir.join("scooter.jsonl")).unwrap();
    assert!(
        scooter_log.contains("\"granted\":\"ses\""),
        "Scooter was never granted the ses source"
    );
    // ...and samples of it arrived with observations in them.
    let samples_with_records = scooter_log
        .lines()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .filter(|e| e["kind"] == "ses")
        .filter(|e| e["detail"]["records"].as_u64().unwrap_or(0) > 0)
        .count();
    assert!(
        samples_with_records > 0,
        "no SES sample with observations reached Scooter"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_robot_without_its_devices_fails_with_the_port_named() {
    let dir = scratch_dir("mission-e2e-noport");
    let cfg = dir.join("scooter.toml");
    std::fs::write(
        &cfg,
        "robot = \"scooter\"\nrole = \"scooter\"\n[devices.base]\nkind = \"rflex\"\nport = \"/dev/ima-no-such-port\"\nbaud = 115200\n[devices.laser]\nport = \"/dev/ima-no-laser\"\nbaud = 38400\n[devices.compass]\nport = \"/dev/ima-no-compass\"\nbaud = 4800\n[peer]\ninsecure = true\nconnect = \"127.0.0.1:9\"\n",
    )
    .unwrap();
    let out = ima().args(["run", "--config"]).arg(&cfg).output().unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("/dev/ima-no-such-port"), "{err}");
    // A configuration without a key is refused.
    std::fs::write(&cfg, "robot = \"commander\"\nrole = \"commander\"\n").unwrap();
    let out = ima()
        .args(["commander", "--config"])
        .arg(&cfg)
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("key_file"));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn mock_world_prints_its_endpoints_and_writes_configs() {
    let dir = scratch_dir("mock-world");
    let mut mock = Child(
        ima()
            .args([
                "mock",
                "world",
                "--speed",
                "2",
                "--seed",
                "3",
                "--write-configs",
            ])
            .arg(&dir)
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    let mut line = String::new();
    BufReader::new(mock.0.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let v: serde_json::Value = serde_json::from_str(&line).unwrap();
    assert_eq!(v["kind"], "world");
    for p in [
        &v["skeeter"]["base"],
        &v["skeeter"]["video_mux"],
        &v["scooter"]["base"],
        &v["scooter"]["laser"],
        &v["scooter"]["compass"],
    ] {
        let p = p.as_str().unwrap();
        assert!(p.starts_with("/dev/") && Path::new(p).exists(), "{p}");
    }
    let frames = v["skeeter"]["frames"].as_str().unwrap();
    assert!(std::net::TcpStream::connect(frames).is_ok());
    let skeeter = std::fs::read_to_string(dir.join("skeeter.toml")).unwrap();
    assert!(skeeter.contains(v["skeeter"]["base"].as_str().unwrap()));
    assert!(skeeter.contains(frames));
    assert!(skeeter.contains("time_scale = 2.0"));
    let scooter = std::fs::read_to_string(dir.join("scooter.toml")).unwrap();
    assert!(scooter.contains(v["scooter"]["laser"].as_str().unwrap()));
    assert!(dir.join("commander.toml").exists());
    let key = std::fs::read_to_string(dir.join("group.key")).unwrap();
    assert_eq!(key.trim().len(), 64);
    drop(mock);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn run_with_mock_true_serves_its_own_world() {
    let dir = scratch_dir("run-mock");
    let cfg = dir.join("skeeter.toml");
    std::fs::write(
        &cfg,
        "robot = \"skeeter\"\nrole = \"skeeter\"\nmock = true\n[mock_world]\nspeed = 2.0\n\
         [peer]\ninsecure = true\nlisten = \"127.0.0.1:0\"\ndata_listen = \"127.0.0.1:0\"\n\
         broadcast_group = \"\"\nbroadcast_bind = \"127.0.0.1:0\"\n",
    )
    .unwrap();
    let mut run = Child(
        ima()
            .args(["run", "--json", "--config"])
            .arg(&cfg)
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    let out = BufReader::new(run.0.stdout.take().unwrap());
    let mut kinds = Vec::new();
    for line in out.lines().take(2) {
        let v: serde_json::Value = serde_json::from_str(&line.unwrap()).unwrap();
        kinds.push(v["kind"].as_str().unwrap().to_owned());
    }
    assert_eq!(kinds, ["connected", "behaviour"]);
    drop(run);
    let _ = std::fs::remove_dir_all(&dir);
}

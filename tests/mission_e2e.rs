//! The mission end to end as three separate `ima` processes (issue 8): the test process
//! serves the simulated world (every serial device on a pty, Skeeter's frames on the TCP
//! frame server); `ima run --config skeeter.toml`, `ima run --config scooter.toml` and
//! `ima commander --config commander.toml --targets …` talk over loopback sockets (Peer
//! Agent manager/client for the `ses` source, unicast broadcast channel) with a group key
//! from a key file. Asserts on the outcome: the commander exits 0 and its JSON events show
//! every target done.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
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

/// The multi-process tests run one at a time: each runs a world and three processes, and
/// the CI machine has two cores.
static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn one_at_a_time() -> std::sync::MutexGuard<'static, ()> {
    ONE_AT_A_TIME
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

#[test]
fn three_processes_accomplish_every_target() {
    let _one = one_at_a_time();
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
    // A listening address whose name does not resolve is named before any port is opened
    // (it failed only after the devices had connected).
    let text = std::fs::read_to_string(&cfg).unwrap();
    let unresolvable = text.replace(
        "[peer]\n",
        "[peer]\nlisten = \"ima-no-such-host.invalid:7610\"\n",
    );
    std::fs::write(&cfg, unresolvable).unwrap();
    let out = ima().args(["run", "--config"]).arg(&cfg).output().unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("peer.listen \"ima-no-such-host.invalid:7610\": the name does not resolve")
            && !err.contains("/dev/ima-no"),
        "{err}"
    );
    // A configuration without a key is refused.
    std::fs::write(&cfg, "robot = \"commander\"\nrole = \"commander\"\n").unwrap();
    let out = ima()
        .args(["commander", "--config"])
        .arg(&cfg)
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("key_file"));
    // A commander's configuration given to `ima run` (with --insecure), and a robot's given
    // to `ima commander`: the mix-up is said first (the key was looked at first, and a
    // commander would have spoken under the robot's name).
    let out = ima()
        .args(["run", "--insecure", "--config"])
        .arg(&cfg)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success()
            && err.contains("is a commander's configuration: run it with `ima commander")
            && !err.contains("insecure"),
        "{err}"
    );
    let robot = dir.join("robot.toml");
    std::fs::write(
        &robot,
        "robot = \"skeeter\"\nrole = \"skeeter\"\nmock = true\n[peer]\nkey_file = \"/nonexistent/group.key\"\n",
    )
    .unwrap();
    let out = ima()
        .args(["commander", "--config"])
        .arg(&robot)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success()
            && err.contains("is skeeter's configuration (a robot's), not a commander's")
            && !err.contains("group.key"),
        "{err}"
    );
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

/// A world served in this process and both robots' stacks as `ima run` processes.
struct Fleet {
    world: SharedWorld,
    _served: ServedWorld,
    commander_cfg: PathBuf,
    _skeeter: Child,
    scooter: Child,
    /// Removed with the fleet (after the robots are killed) unless a test failed.
    dir: common::Scratch,
}

impl Fleet {
    /// The world runs `speed` times faster than real time.
    fn start(name: &str, speed: f64) -> Self {
        let world = SharedWorld::new(World::default_world());
        let served = ServedWorld::start(
            world.clone(),
            &ServeOptions {
                seed: 11,
                speed,
                ..ServeOptions::default()
            },
        )
        .unwrap();
        let dir = scratch_dir(name);
        let [sk, sc, cmd] = write_configs(&dir, served.endpoints(), speed);
        let skeeter = run_robot(&sk, &dir.join("skeeter.jsonl"));
        let scooter = run_robot(&sc, &dir.join("scooter.jsonl"));
        Self {
            world,
            _served: served,
            dir,
            commander_cfg: cmd,
            _skeeter: skeeter,
            scooter,
        }
    }

    /// `ima commander --json --config … <args>` with stdin `stdin`.
    fn commander(&self, args: &[&str], stdin: Stdio) -> Commander {
        let mut c = Child(
            ima()
                .args(["commander", "--json", "--config"])
                .arg(&self.commander_cfg)
                .args(args)
                .stdin(stdin)
                .stdout(Stdio::piped())
                .stderr(Stdio::piped())
                .spawn()
                .unwrap(),
        );
        let out = c.0.stdout.take().unwrap();
        let err = c.0.stderr.take().unwrap();
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            for l in BufReader::new(out).lines().map_while(Result::ok) {
                let v = serde_json::from_str::<serde_json::Value>(&l)
                    .unwrap_or_else(|e| panic!("commander output is not JSON ({e}): {l:?}"));
                if tx.send(v).is_err() {
                    return;
                }
            }
        });
        let stderr = std::thread::spawn(move || {
            let mut s = String::new();
            let _ = std::io::Read::read_to_string(&mut BufReader::new(err), &mut s);
            s
        });
        Commander {
            child: c,
            events: rx,
            seen: Vec::new(),
            stderr: Some(stderr),
        }
    }

    /// A one-shot `ima commander stop|resume|cancel …`; its output.
    fn one_shot(&self, args: &[&str]) -> std::process::Output {
        let out = ima()
            .arg("commander")
            .args(args)
            .arg("--config")
            .arg(&self.commander_cfg)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "ima commander {args:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        out
    }

    /// Scooter's ground-truth velocity in the simulated world `(v m/s, ω rad/s)`.
    fn scooter_velocity(&self) -> (f64, f64) {
        self.world.with(|w| {
            let id = w.robot_id("scooter").expect("Scooter in the world");
            w.robot(id).expect("Scooter in the world").velocity()
        })
    }

    /// Scooter's event log (`ima run --json`) as JSON values.
    fn scooter_log(&self) -> Vec<serde_json::Value> {
        std::fs::read_to_string(self.dir.join("scooter.jsonl"))
            .unwrap_or_default()
            .lines()
            .filter_map(|l| serde_json::from_str(l).ok())
            .collect()
    }
}

/// A running `ima commander --json` and the events it printed so far.
struct Commander {
    child: Child,
    events: std::sync::mpsc::Receiver<serde_json::Value>,
    seen: Vec<serde_json::Value>,
    stderr: Option<std::thread::JoinHandle<String>>,
}

impl Commander {
    /// Waits (at most `limit`, a generous bound) for an event matching `pred`.
    fn wait_for(
        &mut self,
        what: &str,
        limit: Duration,
        pred: impl Fn(&serde_json::Value) -> bool,
    ) -> serde_json::Value {
        if let Some(e) = self.seen.iter().find(|e| pred(e)) {
            return e.clone();
        }
        let deadline = Instant::now() + limit;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.events.recv_timeout(left) {
                Ok(e) => {
                    self.seen.push(e.clone());
                    if pred(&e) {
                        return e;
                    }
                }
                Err(_) => panic!("no {what} within {limit:?}; events: {:#?}", self.seen),
            }
        }
    }

    /// Sends SIGINT (Ctrl-C).
    fn interrupt(&self) {
        let ok = std::process::Command::new("kill")
            .args(["-INT", &self.child.0.id().to_string()])
            .status()
            .unwrap()
            .success();
        assert!(ok, "kill -INT");
    }

    /// Waits (generously) for the exit; its status and stderr.
    fn exit(&mut self, limit: Duration) -> (std::process::ExitStatus, String) {
        let deadline = Instant::now() + limit;
        let status = loop {
            if let Some(s) = self.child.0.try_wait().unwrap() {
                break s;
            }
            assert!(Instant::now() < deadline, "the commander did not exit");
            std::thread::sleep(Duration::from_millis(100));
        };
        while let Ok(e) = self.events.recv_timeout(Duration::from_secs(5)) {
            self.seen.push(e);
        }
        let err = self
            .stderr
            .take()
            .map(|h| h.join().unwrap())
            .unwrap_or_default();
        (status, err)
    }
}

fn robot_is(robot: &'static str, state: &'static str) -> impl Fn(&serde_json::Value) -> bool {
    move |e| e["kind"] == "robot" && e["detail"]["robot"] == robot && e["detail"]["state"] == state
}

fn target_is(target: &'static str, state: &'static str) -> impl Fn(&serde_json::Value) -> bool {
    move |e| {
        e["kind"] == "target" && e["detail"]["target"] == target && e["detail"]["state"] == state
    }
}

/// Issue 13: after `kill -9` of Scooter the commander reports it lost once the configured
/// silence has passed; Ctrl-C without `--stop-on-exit` and with stdin not a terminal says
/// the robots were not stopped.
#[cfg(unix)]
#[test]
fn a_killed_robot_is_reported_lost_by_the_commander() {
    let _one = one_at_a_time();
    let mut fleet = Fleet::start("e2e-lost", SPEED);
    // The commander waits for a robot that never comes: it sends no target, so the mission
    // cannot end before the kill.
    let mut c = fleet.commander(
        &[
            "--targets",
            "red",
            "--lost-after",
            "8",
            "--wait-for",
            "skeeter,scooter,nobody",
            "--wait-timeout",
            "600",
        ],
        Stdio::null(),
    );
    let limit = Duration::from_secs(120);
    c.wait_for("Scooter alive", limit, robot_is("scooter", "alive"));
    c.wait_for("Skeeter alive", limit, robot_is("skeeter", "alive"));
    // SIGKILL: no goodbye on the channel.
    fleet.scooter.0.kill().unwrap();
    let lost = c.wait_for("Scooter lost", limit, robot_is("scooter", "lost"));
    let silent = lost["detail"]["silent_s"].as_f64().unwrap();
    assert!(
        silent >= 8.0,
        "reported after {silent} s of silence, limit 8"
    );
    // Skeeter is still talking: whatever it was meanwhile, it is alive at the end.
    c.interrupt();
    let (status, err) = c.exit(Duration::from_secs(60));
    assert!(!status.success());
    assert!(err.contains("stdin is not a terminal"), "{err}");
    assert!(err.contains("NOT stopped"), "{err}");
    let summary = c.seen.iter().find(|e| e["kind"] == "summary").unwrap();
    assert_eq!(summary["interrupted"], true);
    assert_eq!(summary["fleet_stopped"], false);
}

/// Issue 13: Ctrl-C on a commander with `--stop-on-exit` sends a fleet stop, and Scooter's
/// base stands (ground truth of the simulated world) and holds; `ima commander resume`
/// releases it and `ima commander stop` stops it again.
#[cfg(unix)]
#[test]
fn a_fleet_stop_makes_scooter_stand() {
    let _one = one_at_a_time();
    // Real time: red takes long enough to be stopped on the way.
    let fleet = Fleet::start("e2e-stop", 1.0);
    let mut c = fleet.commander(&["--targets", "red", "--stop-on-exit"], Stdio::null());
    c.wait_for(
        "red processing",
        Duration::from_secs(120),
        target_is("red", "processing"),
    );
    // Scooter drives towards red.
    let deadline = Instant::now() + Duration::from_secs(200);
    loop {
        let (v, w) = fleet.scooter_velocity();
        if v.abs() > 0.02 || w.abs() > 0.05 {
            break;
        }
        assert!(Instant::now() < deadline, "Scooter never moved");
        std::thread::sleep(Duration::from_millis(100));
    }
    c.interrupt();
    let (status, err) = c.exit(Duration::from_secs(60));
    assert!(!status.success());
    assert!(err.contains("sending a fleet stop"), "{err}");
    let summary = c.seen.iter().find(|e| e["kind"] == "summary").unwrap();
    assert_eq!(summary["fleet_stopped"], true);
    // The base stands...
    let standing = || {
        let (v, w) = fleet.scooter_velocity();
        v.abs() < 1e-3 && w.abs() < 1e-3
    };
    let deadline = Instant::now() + Duration::from_secs(30);
    while !standing() {
        assert!(
            Instant::now() < deadline,
            "Scooter still moving: {:?}",
            fleet.scooter_velocity()
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    // ...and holds (Scooter's brain still has its target).
    for _ in 0..20 {
        assert!(
            standing(),
            "Scooter moved again: {:?}",
            fleet.scooter_velocity()
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    // Scooter's log: the stop was obeyed, and its control loop holds zero while halted.
    let log = fleet.scooter_log();
    let at = log
        .iter()
        .position(|e| e["kind"] == "fleet-stop")
        .unwrap_or_else(|| panic!("no fleet-stop in Scooter's log: {log:#?}"));
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        let log = fleet.scooter_log();
        let halted: Vec<&serde_json::Value> = log
            .iter()
            .skip(at)
            .filter(|e| e["kind"] == "control")
            .collect();
        if !halted.is_empty() {
            for e in halted {
                assert_eq!(e["detail"]["halted"], true, "{e}");
                assert_eq!(e["detail"]["v_m_s"], 0.0, "{e}");
            }
            break;
        }
        assert!(Instant::now() < deadline, "no control event after the stop");
        std::thread::sleep(Duration::from_millis(200));
    }
    // Resume, then stop again, with the one-shot commands.
    let out = fleet.one_shot(&["resume"]);
    assert!(String::from_utf8_lossy(&out.stdout).contains("fleet resume sent"));
    let deadline = Instant::now() + Duration::from_secs(30);
    while !fleet
        .scooter_log()
        .iter()
        .any(|e| e["kind"] == "fleet-resume")
    {
        assert!(Instant::now() < deadline, "Scooter did not resume");
        std::thread::sleep(Duration::from_millis(100));
    }
    fleet.one_shot(&["stop", "--reason", "test"]);
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        let log = fleet.scooter_log();
        if log
            .iter()
            .any(|e| e["kind"] == "fleet-stop" && e["detail"]["reason"] == "test")
        {
            break;
        }
        assert!(Instant::now() < deadline, "Scooter did not stop again");
        std::thread::sleep(Duration::from_millis(100));
    }
    let deadline = Instant::now() + Duration::from_secs(30);
    while !standing() {
        assert!(Instant::now() < deadline, "Scooter did not stand again");
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// Issue 13: a target can be cancelled, by `ima commander cancel` from another process or
/// by `cancel COLOUR` typed on the commander's stdin; the commander marks it cancelled
/// and goes on, and Skeeter ends it as failed.
#[cfg(unix)]
#[test]
fn a_target_is_cancelled_from_another_process_or_from_stdin() {
    let _one = one_at_a_time();
    // Real time: red is still being processed when the cancel comes.
    let fleet = Fleet::start("e2e-cancel", 1.0);
    let mut c = fleet.commander(&["--targets", "red,blue"], Stdio::piped());
    let limit = Duration::from_secs(120);
    c.wait_for("red processing", limit, target_is("red", "processing"));
    let out = fleet.one_shot(&["cancel", "--target", "red"]);
    assert!(String::from_utf8_lossy(&out.stdout).contains("target cancel sent"));
    let red = c.wait_for("red failed", limit, target_is("red", "failed"));
    assert_eq!(red["detail"]["cancelled"], true, "{red}");
    c.wait_for("blue sent", limit, target_is("blue", "sent"));
    // Skeeter ended red as failed.
    c.wait_for("Skeeter's Failed for red", limit, |e| {
        e["kind"] == "broadcast"
            && e["detail"]["robot"] == "skeeter"
            && e["detail"]["event"] == "failed"
            && e["detail"]["target"] == "red"
    });
    // Typed on stdin.
    {
        use std::io::Write;
        let stdin = c.child.0.stdin.as_mut().unwrap();
        writeln!(stdin, "cancel blue").unwrap();
        stdin.flush().unwrap();
    }
    let blue = c.wait_for("blue failed", limit, target_is("blue", "failed"));
    assert_eq!(blue["detail"]["cancelled"], true, "{blue}");
    // Every target is over: the commander ends, with both failed as cancelled.
    let (status, _) = c.exit(Duration::from_secs(60));
    assert!(!status.success(), "two targets failed");
    let summary = c.seen.iter().find(|e| e["kind"] == "summary").unwrap();
    assert_eq!(summary["failed"], 2);
    for t in summary["targets"].as_array().unwrap() {
        assert_eq!(t["reason"], "cancelled by the operator", "{t}");
    }
}

/// Issue 17: `ima commander --web` against robots started with `ima run` (the README's
/// three-process set-up). The robots are other processes, so the console learns of them from
/// their broadcasts only: each one's liveness, behaviour, SAN summary and pose (Scooter's
/// dead-reckoned pose, Skeeter's fixed place) reach the commander's web state, so the Map
/// shows both robots and the SAN page each one's summary.
#[cfg(unix)]
#[test]
fn the_commanders_console_gets_both_robots_poses_from_separate_processes() {
    use std::io::{Read, Write};
    let _one = one_at_a_time();
    let fleet = Fleet::start("e2e-web", SPEED);
    let port = common::mission::free_port(false);
    let addr = format!("127.0.0.1:{port}");
    let mut c = fleet.commander(
        &["--targets", "red", "--web", &addr, "--stop-on-exit"],
        Stdio::piped(),
    );
    let state = || -> Option<serde_json::Value> {
        let mut s = std::net::TcpStream::connect(&addr).ok()?;
        s.set_read_timeout(Some(Duration::from_secs(10))).ok()?;
        write!(
            s,
            "GET /api/state HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n"
        )
        .ok()?;
        let mut resp = String::new();
        s.read_to_string(&mut resp).ok()?;
        serde_json::from_str(resp.split_once("\r\n\r\n")?.1).ok()
    };
    let has_pose = |v: &serde_json::Value, r: &str| v["robots"][r]["pose"].is_array();
    // Generous bound for a loaded machine: the robots connect to their devices first.
    let deadline = Instant::now() + Duration::from_secs(180);
    let v = loop {
        if let Some(v) = state()
            && has_pose(&v, "scooter")
            && has_pose(&v, "skeeter")
            && v["robots"]["skeeter"]["san_summary"].is_string()
            && v["robots"]["scooter"]["behaviour"].is_string()
        {
            break v;
        }
        assert!(
            Instant::now() < deadline,
            "the console never had both robots' poses; last state: {:#?}; robots' logs in {}",
            state().map(|v| v["robots"].clone()),
            fleet.dir.display()
        );
        std::thread::sleep(Duration::from_millis(250));
    };
    for r in ["skeeter", "scooter"] {
        let p = v["robots"][r]["pose"].as_array().unwrap();
        assert_eq!(p.len(), 3, "{r}: {p:?}");
        assert!(
            p.iter().all(|x| x.as_f64().is_some_and(f64::is_finite)),
            "{r}: {p:?}"
        );
        assert_eq!(v["robots"][r]["life"], "alive", "{r}");
    }
    // Skeeter stands at the common frame's origin.
    assert_eq!(
        v["robots"]["skeeter"]["pose"],
        serde_json::json!([0.0, 0.0, 0.0])
    );
    c.interrupt();
    let _ = c.exit(Duration::from_secs(60));
}

//! `ima peer …` over loopback: key handling, a client printing samples, loss of a killed or
//! frozen manager, broadcast listen/send between processes.

mod common;

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{ChildStdout, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use common::{Child, ima, json_lines, run_ok};
use serde_json::Value;

/// A scratch directory for one test (removed at its end unless it failed).
fn temp_dir(tag: &str) -> common::Scratch {
    common::Scratch::new(&format!("cli-peer-{tag}"))
}

fn manager_config(dir: &std::path::Path, extra: &str) -> PathBuf {
    let p = dir.join("manager.toml");
    std::fs::write(
        &p,
        format!(
            "robot = \"skeeter\"\nheartbeat_ms = 500\n{extra}\n[manager]\nlisten = \"127.0.0.1:0\"\n\
             data_listen = \"127.0.0.1:0\"\n[[synthetic]]\nname = \"counter\"\n\
             generator = \"counter\"\nrate_hz = 100\n[[synthetic]]\nname = \"blob64\"\n\
             generator = \"blob64\"\nrate_hz = 100\n"
        ),
    )
    .unwrap();
    p
}

/// Starts `ima peer manager` and returns it with its request-channel address.
fn spawn_manager(args: &[&str]) -> (Child, String, BufReader<ChildStdout>) {
    let mut m = Child(
        ima()
            .args(["peer", "manager"])
            .args(args)
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    let mut out = BufReader::new(m.0.stdout.take().unwrap());
    let mut first = String::new();
    out.read_line(&mut first).unwrap();
    let v: Value = serde_json::from_str(&first).unwrap();
    assert_eq!(v["event"], "listening");
    (m, v["addr"].as_str().unwrap().to_owned(), out)
}

#[test]
fn manager_refuses_to_run_without_a_key() {
    let dir = temp_dir("nokey");
    let cfg = manager_config(&dir, "");
    let out = ima()
        .args(["peer", "manager", "--config"])
        .arg(&cfg)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("no group key"), "{err}");
    assert!(err.contains("--insecure"), "{err}");
}

#[test]
fn insecure_manager_serves_a_client_that_prints_json_samples() {
    let dir = temp_dir("insecure");
    let cfg = manager_config(&dir, "");
    let (_m, addr, _out) = spawn_manager(&["--insecure", "--config", cfg.to_str().unwrap()]);
    let out = run_ok(
        ima()
            .args(["peer", "client", "--insecure", "--connect", &addr])
            .args(["--request", "blob64", "--count", "7"]),
    );
    let lines = json_lines(&out.stdout);
    assert_eq!(lines[0]["event"], "registered");
    assert_eq!(lines[1]["event"], "granted");
    let samples: Vec<&Value> = lines.iter().filter(|l| l.get("seq").is_some()).collect();
    assert_eq!(samples.len(), 7);
    let mut last = 0;
    for s in samples {
        assert_eq!(s["source"], "blob64");
        assert_eq!(s["len"], 64);
        assert_eq!(s["payload"].as_str().unwrap().len(), 128);
        let seq = s["seq"].as_u64().unwrap();
        assert!(seq > last);
        last = seq;
    }
    // A source the manager does not serve is named, with the ones it does (not `UnknownSource`).
    let out = ima()
        .args(["peer", "client", "--insecure", "--connect", &addr])
        .args(["--request", "blob46", "--count", "1"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("the manager has no source `blob46` (it serves: blob64, counter)"),
        "{err}"
    );
}

#[cfg(unix)]
#[test]
fn key_files_are_required_private_and_must_match() {
    use std::os::unix::fs::PermissionsExt;
    let dir = temp_dir("keys");
    let key = dir.join("group.key");
    std::fs::write(&key, format!("# test key\n{}\n", "5a".repeat(32))).unwrap();
    std::fs::set_permissions(&key, std::fs::Permissions::from_mode(0o644)).unwrap();
    // Relative to the config file's directory (not to the working directory).
    let cfg = manager_config(&dir, "key_file = \"group.key\"");
    let out = ima()
        .args(["peer", "manager", "--config"])
        .arg(&cfg)
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("chmod 600"));
    std::fs::set_permissions(&key, std::fs::Permissions::from_mode(0o600)).unwrap();
    let (_m, addr, _out) = spawn_manager(&["--config", cfg.to_str().unwrap()]);
    let out = run_ok(
        ima()
            .args(["peer", "client", "--key-file"])
            .arg(&key)
            .args(["--connect", &addr, "--request", "counter", "--count", "3"]),
    );
    assert_eq!(
        json_lines(&out.stdout)
            .iter()
            .filter(|l| l.get("seq").is_some())
            .count(),
        3
    );
    // The wrong (insecure) key is refused by the manager.
    let out = ima()
        .args(["peer", "client", "--insecure", "--connect", &addr])
        .args(["--request", "counter", "--count", "1"])
        .output()
        .unwrap();
    assert!(!out.status.success());
}

/// Streams from a manager, does `act` to the manager process, and returns the client's
/// output after the manager's end (no timing is asserted: the client must end by itself).
fn client_sees_loss(act: &str) -> Vec<Value> {
    let dir = temp_dir(act);
    let cfg = manager_config(&dir, "");
    let (m, addr, _out) = spawn_manager(&["--insecure", "--config", cfg.to_str().unwrap()]);
    let mut client = Child(
        ima()
            .args(["peer", "client", "--insecure", "--heartbeat-ms", "500"])
            .args(["--connect", &addr, "--request", "counter"])
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    let mut out = BufReader::new(client.0.stdout.take().unwrap());
    let mut lines = Vec::new();
    let mut l = String::new();
    while lines.len() < 5 {
        l.clear();
        let n = out.read_line(&mut l).unwrap();
        assert!(
            n > 0,
            "the client ended before streaming 5 samples; got {lines:?}"
        );
        let v: Value = serde_json::from_str(&l)
            .unwrap_or_else(|e| panic!("client output is not JSON ({e}): {l:?}"));
        if v.get("seq").is_some() {
            lines.push(v);
        }
    }
    let pid = m.0.id().to_string();
    let status = std::process::Command::new("kill")
        .args([act, &pid])
        .status()
        .unwrap();
    assert!(status.success());
    let mut rest = String::new();
    loop {
        l.clear();
        if out.read_line(&mut l).unwrap() == 0 {
            break;
        }
        rest.push_str(&l);
    }
    let code = client.0.wait().unwrap();
    assert!(!code.success(), "the client reports the end of its source");
    if act == "-STOP" {
        let _ = std::process::Command::new("kill")
            .args(["-CONT", &pid])
            .status();
    }
    drop(m);
    json_lines(rest.as_bytes())
}

#[test]
fn killed_manager_process_is_reported() {
    let lines = client_sees_loss("-KILL");
    let last = lines.last().expect("a closing line");
    assert_eq!(last["event"], "closed");
}

/// SIGTERM (`systemctl stop`) shuts the manager down in order, as Ctrl-C does: its clients
/// are told (revoked: shutdown). It waited out the signal's 3 s grace period and was then
/// ended without a word, so its clients found out only when its heartbeats stopped.
#[test]
fn sigterm_shuts_the_manager_down_and_its_client_is_told() {
    let lines = client_sees_loss("-TERM");
    let last = lines.last().expect("a closing line");
    assert_eq!(last["event"], "closed");
    assert_eq!(last["reason"]["kind"], "revoked", "{last}");
    assert_eq!(last["reason"]["reason"], "shutdown", "{last}");
}

#[test]
fn frozen_manager_is_declared_lost_after_missed_heartbeats() {
    let lines = client_sees_loss("-STOP");
    let last = lines.last().expect("a closing line");
    assert_eq!(last["event"], "closed");
    // A JSON object, not Debug text.
    let reason = &last["reason"];
    assert!(
        reason["kind"] == "manager-lost"
            || (reason["kind"] == "data" && reason["close"]["kind"] == "lost"),
        "{reason}"
    );
}

/// Send a status under `key` with `send_args` once a second until `err` shows the
/// authentication warning (at most 60 s); returns the warning line.
fn await_auth_warning(
    err: &mpsc::Receiver<String>,
    key: &std::path::Path,
    send_args: &[&str],
) -> String {
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        assert!(Instant::now() < deadline, "no authentication warning");
        run_ok(
            ima()
                .args(["peer", "send", "--key-file"])
                .arg(key)
                .args(send_args)
                .args(["status", "--behaviour", "x"]),
        );
        if let Ok(l) = err.recv_timeout(Duration::from_millis(1500))
            && l.contains("failed authentication")
        {
            return l;
        }
    }
}

/// Reads `out` line by line on a thread, so that the test can wait with a deadline.
fn line_channel<R: std::io::Read + Send + 'static>(out: BufReader<R>) -> mpsc::Receiver<String> {
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for l in out.lines() {
            let Ok(l) = l else { return };
            if tx.send(l).is_err() {
                return;
            }
        }
    });
    rx
}

#[test]
fn listener_prints_broadcasts_of_two_managers_and_a_sender() {
    // The listener binds port 0 and the others join the port it got: no "free port" guess
    // that another test could be handed too.
    let mut listener = Child(
        ima()
            .args(["peer", "listen", "--insecure", "--port", "0"])
            .args(["--interface", "127.0.0.1", "--group", "239.255.73.79"])
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    let rx = line_channel(BufReader::new(listener.0.stdout.take().unwrap()));
    let first = rx
        .recv_timeout(Duration::from_secs(30))
        .expect("the listener's first line");
    let first: Value = serde_json::from_str(&first).unwrap();
    assert_eq!(first["event"], "listening");
    let port = first["addr"]
        .as_str()
        .and_then(|a| a.rsplit(':').next())
        .expect("listening address")
        .to_owned();
    assert_ne!(port, "0");
    let bcast = [
        "--insecure",
        "--port",
        &port,
        "--interface",
        "127.0.0.1",
        "--group",
        "239.255.73.79",
    ];
    let dir = temp_dir("bcast");
    let cfg = manager_config(&dir, "");
    let mut managers = Vec::new();
    for robot in ["skeeter", "scooter"] {
        let mut args = vec!["--config", cfg.to_str().unwrap(), "--robot", robot];
        args.extend(["--status-ms", "100"]);
        args.extend(bcast);
        managers.push(spawn_manager(&args));
    }
    // Collect until both managers' status and the commander's mission were heard (the
    // mission is sent again while unheard: UDP gives no delivery guarantee).
    let deadline = Instant::now() + Duration::from_secs(60);
    let mut lines: Vec<Value> = Vec::new();
    let heard = |lines: &[Value]| {
        let status = |r: &str| {
            lines
                .iter()
                .any(|l| l["type"] == "status" && l["robot"] == r)
        };
        let mission = lines
            .iter()
            .any(|l| l["type"] == "mission" && l["robot"] == "commander" && l["target"] == "red");
        (status("skeeter") && status("scooter"), mission)
    };
    let mut next_send = Instant::now();
    loop {
        let (statuses, mission) = heard(&lines);
        if statuses && mission {
            break;
        }
        assert!(Instant::now() < deadline, "not all heard: {lines:?}");
        if !mission && Instant::now() >= next_send {
            let sent = ima()
                .args(["peer", "send", "--robot", "commander"])
                .args(bcast)
                .args(["mission", "--event", "accepted", "--target", "red"])
                .output()
                .unwrap();
            assert!(
                sent.status.success(),
                "{}",
                String::from_utf8_lossy(&sent.stderr)
            );
            next_send = Instant::now() + Duration::from_secs(5);
        }
        if let Ok(l) = rx.recv_timeout(Duration::from_millis(200)) {
            let v: Value = serde_json::from_str(&l)
                .unwrap_or_else(|e| panic!("listener output is not JSON ({e}): {l:?}"));
            lines.push(v);
        }
    }
    // Every line is a broadcast of one of the three senders.
    for l in &lines {
        let robot = l["robot"].as_str().unwrap_or_default();
        assert!(
            ["skeeter", "scooter", "commander"].contains(&robot),
            "{l:?}"
        );
    }
}

fn manager_fails_with(dir: &str, toml: &str, expect: &str) {
    let dir = temp_dir(dir);
    let p = dir.join("bad.toml");
    std::fs::write(&p, toml).unwrap();
    let out = ima()
        .args(["peer", "manager", "--insecure", "--config"])
        .arg(&p)
        .stdout(Stdio::null())
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains(expect), "{err}");
}

/// A config file's mistakes name the file; a value of the wrong type also its line (and what
/// was expected, in words), in the main table and in a `[[synthetic]]` source alike; a value
/// out of range its key.
#[test]
fn config_errors_name_the_file_and_the_line() {
    manager_fails_with(
        "type",
        "robot = \"s\"\nheartbeat_ms = \"x\"\n",
        "bad.toml: TOML parse error at line 2, column 16",
    );
    // In words, not serde's Rust type names ("expected u64").
    manager_fails_with(
        "typewords",
        "robot = \"s\"\nheartbeat_ms = -3\n",
        "invalid value: integer `-3`, expected a whole number, 0 or more",
    );
    manager_fails_with(
        "synthtype",
        "robot = \"s\"\n[[synthetic]]\nname = 5\n",
        "bad.toml: TOML parse error at line 3, column 8",
    );
    manager_fails_with(
        "range",
        "[manager]\nmax_clients = 0\n",
        "bad.toml: configuration: manager.max_clients = 0 is out of range",
    );
}

#[test]
fn bad_synthetic_sources_are_refused() {
    let src = |g: &str, rate: &str| {
        format!(
            "[manager]\nlisten = \"127.0.0.1:0\"\ndata_listen = \"127.0.0.1:0\"\n\
             [[synthetic]]\nname = \"s\"\ngenerator = \"{g}\"\nrate_hz = {rate}\n"
        )
    };
    manager_fails_with("rate0", &src("counter", "0.0"), "rate_hz");
    manager_fails_with("rateneg", &src("counter", "-5.0"), "rate_hz");
    manager_fails_with("ratenan", &src("counter", "nan"), "rate_hz");
    // Far above what the manager can serve or advertise (it ran at 100 kHz, said 4.3 kHz).
    manager_fails_with("ratehuge", &src("counter", "1e12"), "from 0.001 to 100000");
    let twice = format!(
        "{}[[synthetic]]\nname = \"s\"\ngenerator = \"sine\"\nrate_hz = 1.0\n",
        src("counter", "1.0")
    );
    manager_fails_with("twice", &twice, "two [[synthetic]] sources are named \"s\"");
    manager_fails_with("blobbig", &src("blob100000", "1.0"), "payload limit");
    manager_fails_with("unknown", "bogus_key = 1\n", "bogus_key");
}

#[test]
fn insecure_manager_defaults_to_loopback() {
    let dir = temp_dir("loopdefault");
    let p = dir.join("any.toml");
    // listen on every interface (port 0) unless --insecure narrows it.
    std::fs::write(
        &p,
        "[manager]\nlisten = \"0.0.0.0:0\"\ndata_listen = \"0.0.0.0:0\"\n",
    )
    .unwrap();
    let (_m, addr, _out) = spawn_manager(&["--insecure", "--config", p.to_str().unwrap()]);
    assert!(addr.starts_with("127.0.0.1:"), "{addr}");
}

/// `--insecure --listen 127.0.0.1:0`: the data server stays beside the request channel (it
/// listened on every interface, with the all-zero key).
#[test]
fn an_insecure_manager_s_data_server_stays_beside_its_listen_address() {
    let (_m, first) =
        common::spawn_first_line(["peer", "manager", "--insecure", "--listen", "127.0.0.1:0"]);
    let v: Value = serde_json::from_str(&first).unwrap();
    let data = v["data_addr"].as_str().unwrap();
    assert!(data.starts_with("127.0.0.1:"), "{first}");
}

/// A bad status group is refused before the manager says it listens (it printed its
/// "listening" line, then failed), naming the flags that set it.
#[test]
fn a_bad_status_group_fails_before_listening() {
    let out = ima()
        .args([
            "peer",
            "manager",
            "--insecure",
            "--group",
            "bogus",
            "--status-ms",
            "100",
        ])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        out.stdout.is_empty(),
        "{}",
        String::from_utf8_lossy(&out.stdout)
    );
    assert!(
        err.contains("--group") && err.contains("\"bogus\""),
        "{err}"
    );
}

/// An interface that is not one of this host's addresses: the error names it and the group
/// (it was "I/O error: No such device (os error 19)").
#[test]
fn a_listener_on_a_foreign_interface_names_it() {
    let out = ima()
        .args(["peer", "listen", "--insecure", "--interface", "10.99.99.99"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("joining multicast group 239.255.73.77 on interface 10.99.99.99"),
        "{err}"
    );
}

#[test]
fn send_without_destinations_fails() {
    let out = ima()
        .args([
            "peer",
            "send",
            "--insecure",
            "--mode",
            "unicast",
            "--port",
            "0",
        ])
        .args(["emergency", "--kind", "k"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("nowhere to send"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // To the multicast group on port 0: said plainly (it was "Invalid argument (os error 22)").
    let out = ima()
        .args(["peer", "send", "--insecure", "--port", "0"])
        .args(["emergency", "--kind", "k"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("listeners use"),
        "{err}"
    );
}

/// Writes a private hex key file of `byte` repeated.
#[cfg(unix)]
fn key_file(dir: &std::path::Path, name: &str, byte: u8) -> PathBuf {
    use std::os::unix::fs::PermissionsExt;
    let p = dir.join(name);
    std::fs::write(&p, format!("{}\n", format!("{byte:02x}").repeat(32))).unwrap();
    std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o600)).unwrap();
    p
}

/// Issue 13: a client and a listener under another key than their peers say that frames
/// failed authentication, name the address and point at the key file — instead of only
/// "manager lost" or nothing at all.
#[cfg(unix)]
#[test]
fn a_wrong_key_file_is_named_by_the_client_and_the_listener() {
    let dir = temp_dir("wrongkey");
    let key_a = key_file(&dir, "a.key", 0x5a);
    let key_b = key_file(&dir, "b.key", 0xa5);
    let cfg = manager_config(&dir, "");
    let (_m, addr, _out) = spawn_manager(&[
        "--config",
        cfg.to_str().unwrap(),
        "--key-file",
        key_a.to_str().unwrap(),
    ]);
    let out = ima()
        .args(["peer", "client", "--key-file"])
        .arg(&key_b)
        .args(["--connect", &addr, "--request", "counter", "--count", "1"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains(&addr), "{err}");
    assert!(
        err.contains("is the key file the same on every robot?"),
        "{err}"
    );

    // The listener (key A) hears a sender under key B: it says so on stderr, with the
    // sender's address, while stdout stays JSON.
    let mut listener = Child(
        ima()
            .args(["peer", "listen", "--key-file"])
            .arg(&key_a)
            .args(["--port", "0", "--interface", "127.0.0.1"])
            .args(["--group", "239.255.73.80"])
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let out = line_channel(BufReader::new(listener.0.stdout.take().unwrap()));
    let err = line_channel(BufReader::new(listener.0.stderr.take().unwrap()));
    let first: Value = serde_json::from_str(
        &out.recv_timeout(Duration::from_secs(30))
            .expect("the listener's first line"),
    )
    .unwrap();
    let port = first["addr"]
        .as_str()
        .and_then(|a| a.rsplit(':').next())
        .expect("listening address")
        .to_owned();
    let warning = await_auth_warning(
        &err,
        &key_b,
        &[
            "--port",
            &port,
            "--interface",
            "127.0.0.1",
            "--group",
            "239.255.73.80",
        ],
    );
    assert!(warning.contains("from 127.0.0.1:"), "{warning}");
    assert!(
        warning.contains("is the key file the same on every robot?"),
        "{warning}"
    );
    // Nothing under key B reached stdout.
    while let Ok(l) = out.try_recv() {
        let v: Value = serde_json::from_str(&l).unwrap();
        assert_ne!(v["type"], "status", "{l}");
    }
}

/// Issue 13: a key file of zeros is the documented insecure key; it is accepted, but as
/// loudly as `--insecure`.
#[cfg(unix)]
#[test]
fn an_all_zero_key_file_is_warned_about() {
    let dir = temp_dir("zerokey");
    let zero = key_file(&dir, "zero.key", 0);
    let out = ima()
        .args(["peer", "send", "--key-file"])
        .arg(&zero)
        .args(["--mode", "unicast", "--peer", "127.0.0.1:9"])
        .args(["status", "--behaviour", "x"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("WARNING"), "{err}");
    assert!(err.contains("all-zero key"), "{err}");
    assert!(err.contains(zero.to_str().unwrap()), "{err}");
    // A real key says nothing of the kind.
    let real = key_file(&dir, "real.key", 0x42);
    let out = ima()
        .args(["peer", "send", "--key-file"])
        .arg(&real)
        .args(["--mode", "unicast", "--peer", "127.0.0.1:9"])
        .args(["status", "--behaviour", "x"])
        .output()
        .unwrap();
    assert!(!String::from_utf8_lossy(&out.stderr).contains("all-zero"));
}

/// Issue 13: "address already in use" names the address and which socket it was for.
#[test]
fn an_address_in_use_is_named() {
    let dir = temp_dir("inuse");
    let cfg = manager_config(&dir, "");
    let (_m, addr, _out) = spawn_manager(&["--insecure", "--config", cfg.to_str().unwrap()]);
    let out = ima()
        .args(["peer", "manager", "--insecure", "--config"])
        .arg(&cfg)
        .args(["--listen", &addr])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains(&format!("binding the manager's request channel to {addr}")),
        "{err}"
    );
    assert!(
        err.to_lowercase().contains("address already in use"),
        "{err}"
    );
    // The data server's address too.
    let taken = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let data = taken.local_addr().unwrap().to_string();
    let p = dir.join("data.toml");
    std::fs::write(
        &p,
        format!("robot = \"x\"\n[manager]\nlisten = \"127.0.0.1:0\"\ndata_listen = \"{data}\"\n"),
    )
    .unwrap();
    let out = ima()
        .args(["peer", "manager", "--insecure", "--config"])
        .arg(&p)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains(&format!("binding the manager's data server to {data}")),
        "{err}"
    );
}

/// Issue 13: the manager's and the client's JSON lines carry JSON objects, not Rust `Debug`
/// text such as `"Core(SourcesChanged { … })"`.
#[test]
fn manager_and_client_json_has_no_debug_text() {
    fn no_debug_text(v: &Value) {
        match v {
            Value::String(s) => assert!(
                !s.contains(" { ") && !s.contains('(') && !s.contains("::"),
                "Debug-looking text {s:?}"
            ),
            Value::Array(a) => a.iter().for_each(no_debug_text),
            Value::Object(o) => o.values().for_each(no_debug_text),
            _ => {}
        }
    }
    let dir = temp_dir("nodebug");
    let cfg = manager_config(&dir, "");
    let (_m, addr, out) = spawn_manager(&["--insecure", "--config", cfg.to_str().unwrap()]);
    let lines = line_channel(out);
    run_ok(
        ima()
            .args(["peer", "client", "--insecure", "--connect", &addr])
            .args(["--request", "counter", "--count", "2"]),
    );
    // Until the grant's decision has been printed (generous bound).
    let deadline = Instant::now() + Duration::from_secs(60);
    let mut types = Vec::new();
    while !types.iter().any(|t| t == "decision") {
        assert!(Instant::now() < deadline, "no decision event: {types:?}");
        let Ok(l) = lines.recv_timeout(Duration::from_millis(500)) else {
            continue;
        };
        let v: Value = serde_json::from_str(&l).unwrap();
        no_debug_text(&v);
        if v["event"] == "manager" {
            assert!(v["detail"].is_object(), "{l}");
            types.push(v["detail"]["type"].as_str().unwrap().to_owned());
        }
    }
    assert!(types.iter().any(|t| t == "sources-changed"), "{types:?}");
}

/// Issue 13: `ima commander` under key A, hearing a sender under key B, says so on stderr
/// (rate-limited), with the sender's address.
#[cfg(unix)]
#[test]
fn the_commander_names_frames_under_another_key() {
    let dir = temp_dir("cmdkey");
    let key_a = key_file(&dir, "a.key", 0x5a);
    let key_b = key_file(&dir, "b.key", 0xa5);
    let port = common::mission::free_port(true);
    let cfg = dir.join("commander.toml");
    std::fs::write(
        &cfg,
        format!(
            "robot = \"commander\"\nrole = \"commander\"\n[peer]\nkey_file = {key_a:?}\n\
             broadcast_group = \"\"\nbroadcast_peers = [\"127.0.0.1:9\"]\n\
             broadcast_bind = \"127.0.0.1:{port}\"\n"
        ),
    )
    .unwrap();
    let mut commander = Child(
        ima()
            .args(["commander", "--json", "--config"])
            .arg(&cfg)
            .args(["--wait-for", "nobody", "--wait-timeout", "600"])
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let out = line_channel(BufReader::new(commander.0.stdout.take().unwrap()));
    let err = line_channel(BufReader::new(commander.0.stderr.take().unwrap()));
    // Its first line: it is up and waiting.
    out.recv_timeout(Duration::from_secs(30))
        .expect("the commander's first line");
    let warning = await_auth_warning(
        &err,
        &key_b,
        &["--mode", "unicast", "--peer", &format!("127.0.0.1:{port}")],
    );
    assert!(warning.contains("from 127.0.0.1:"), "{warning}");
    assert!(
        warning.contains("is the key file the same on every robot?"),
        "{warning}"
    );
}

/// Issue 13: `ima run` (Skeeter on its own simulated world) under key A says so too.
#[cfg(unix)]
#[test]
fn a_robot_names_frames_under_another_key() {
    let dir = temp_dir("runkey");
    let key_a = key_file(&dir, "a.key", 0x5a);
    let key_b = key_file(&dir, "b.key", 0xa5);
    let port = common::mission::free_port(true);
    let cfg = dir.join("skeeter.toml");
    std::fs::write(
        &cfg,
        format!(
            "robot = \"skeeter\"\nrole = \"skeeter\"\nmock = true\n[peer]\nkey_file = {key_a:?}\n\
             listen = \"127.0.0.1:0\"\ndata_listen = \"127.0.0.1:0\"\nbroadcast_group = \"\"\n\
             broadcast_peers = [\"127.0.0.1:9\"]\nbroadcast_bind = \"127.0.0.1:{port}\"\n"
        ),
    )
    .unwrap();
    let mut run = Child(
        ima()
            .args(["run", "--json", "--config"])
            .arg(&cfg)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let out = line_channel(BufReader::new(run.0.stdout.take().unwrap()));
    let err = line_channel(BufReader::new(run.0.stderr.take().unwrap()));
    out.recv_timeout(Duration::from_secs(60))
        .expect("the robot's first line");
    let warning = await_auth_warning(
        &err,
        &key_b,
        &["--mode", "unicast", "--peer", &format!("127.0.0.1:{port}")],
    );
    assert!(warning.contains("from 127.0.0.1:"), "{warning}");
    assert!(warning.contains("is the key file the same"), "{warning}");
}

/// `ima peer listen` in unicast mode on a free loopback port (`key`: its key arguments): the
/// process, the lines it prints (the first, `listening`, already taken) and its port.
fn unicast_listener(key: &[&std::ffi::OsStr]) -> (Child, mpsc::Receiver<String>, String) {
    let mut listener = Child(
        ima()
            .args(["peer", "listen"])
            .args(key)
            .args([
                "--mode",
                "unicast",
                "--port",
                "0",
                "--interface",
                "127.0.0.1",
            ])
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    let heard = line_channel(BufReader::new(listener.0.stdout.take().unwrap()));
    let first: Value = serde_json::from_str(
        &heard
            .recv_timeout(Duration::from_secs(30))
            .expect("the listener's first line"),
    )
    .unwrap();
    let port = first["addr"]
        .as_str()
        .and_then(|a| a.rsplit(':').next())
        .unwrap()
        .to_owned();
    (listener, heard, port)
}

/// A commander configuration in `dir` whose broadcasts go to 127.0.0.1:`port` only; `key` is
/// its `[peer]` key line (empty for none).
fn commander_config(dir: &std::path::Path, key: &str, port: &str) -> PathBuf {
    let cfg = dir.join("commander.toml");
    std::fs::write(
        &cfg,
        format!(
            "robot = \"commander\"\nrole = \"commander\"\n[peer]\n{key}broadcast_group = \"\"\n\
             broadcast_peers = [\"127.0.0.1:{port}\"]\nbroadcast_bind = \"127.0.0.1:0\"\n"
        ),
    )
    .unwrap();
    cfg
}

/// Wait (at most 30 s) until the listener hears the commander's fleet stop; `said` gives what
/// the commander printed, for the failure message.
fn await_fleet_stop(heard: &mpsc::Receiver<String>, mut said: impl FnMut() -> String) {
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        let l = heard
            .recv_timeout(deadline.saturating_duration_since(Instant::now()))
            .unwrap_or_else(|e| {
                panic!(
                    "a fleet stop on the wire: {e:?}; the commander said: {}",
                    said()
                )
            });
        let v: Value = serde_json::from_str(&l).unwrap();
        if v["type"] == "emergency" && v["kind"] == "fleet-stop" {
            assert_eq!(v["robot"], "commander");
            return;
        }
    }
}

/// Issue 13: Ctrl-C on a commander whose stdin is a terminal asks "stop the robots?"; "y"
/// sends the fleet stop, seen on the wire by a listener.
#[cfg(unix)]
#[test]
fn ctrl_c_on_a_terminal_asks_and_y_sends_the_fleet_stop() {
    use std::io::{Read, Write};
    use std::sync::{Arc, Mutex};
    let dir = temp_dir("prompt");
    let key = key_file(&dir, "a.key", 0x5a);
    // The listener: where the commander's broadcasts go.
    let (_listener, heard, port) = unicast_listener(&["--key-file".as_ref(), key.as_os_str()]);
    let cfg = commander_config(&dir, &format!("key_file = {key:?}\n"), &port);
    // The commander's stdin is the slave of a pseudo-terminal: a terminal.
    let (mut master, slave) = ima_mock_devices::pty::pty_pair().unwrap();
    let slave_path = serialport::SerialPort::name(&slave).expect("the slave's path");
    let tty = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .open(&slave_path)
        .unwrap();
    let mut commander = Child(
        ima()
            .args(["commander", "--json", "--config"])
            .arg(&cfg)
            .args(["--wait-for", "nobody", "--wait-timeout", "600"])
            .stdin(Stdio::from(tty))
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let out = line_channel(BufReader::new(commander.0.stdout.take().unwrap()));
    let err = Arc::new(Mutex::new(String::new()));
    {
        let err = err.clone();
        let mut stderr = commander.0.stderr.take().unwrap();
        std::thread::spawn(move || {
            let mut buf = [0u8; 256];
            while let Ok(n) = stderr.read(&mut buf) {
                if n == 0 {
                    return;
                }
                err.lock()
                    .unwrap()
                    .push_str(&String::from_utf8_lossy(&buf[..n]));
            }
        });
    }
    out.recv_timeout(Duration::from_secs(30))
        .expect("the commander's first line");
    commander.signal("INT");
    let deadline = Instant::now() + Duration::from_secs(30);
    while !err.lock().unwrap().contains("stop the robots? [y/N]") {
        assert!(
            Instant::now() < deadline,
            "no prompt: {}",
            err.lock().unwrap()
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    master.write_all(b"y\n").unwrap();
    master.flush().unwrap();
    // The fleet stop goes out (heard by the listener) and the commander ends.
    await_fleet_stop(&heard, || err.lock().unwrap().clone());
    let deadline = Instant::now() + Duration::from_secs(30);
    let status = loop {
        if let Some(s) = commander.0.try_wait().unwrap() {
            break s;
        }
        assert!(Instant::now() < deadline, "the commander did not exit");
        std::thread::sleep(Duration::from_millis(50));
    };
    assert!(!status.success(), "an interrupted commander fails");
    assert!(
        err.lock().unwrap().contains("sending a fleet stop"),
        "{}",
        err.lock().unwrap()
    );
    drop(slave);
}

/// A commander whose configuration names no key file runs with `--insecure` (the flag was
/// applied after the configuration's check, which refused it first), and a line of stdin
/// that is not UTF-8 gets a hint instead of ending the operator's input: the `stop` typed
/// after it goes out on the wire.
#[test]
fn stray_bytes_on_stdin_do_not_deafen_the_commander_to_a_stop() {
    use std::io::Write;
    let dir = temp_dir("stray");
    let (_listener, heard, port) = unicast_listener(&["--insecure".as_ref()]);
    // No key file: `--insecure` below supplies the key.
    let cfg = commander_config(&dir, "", &port);
    let mut commander = Child(
        ima()
            .args(["commander", "--json", "--insecure", "--config"])
            .arg(&cfg)
            .args(["--wait-for", "nobody", "--wait-timeout", "600"])
            .stdin(Stdio::piped())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let err = line_channel(BufReader::new(commander.0.stderr.take().unwrap()));
    let mut stdin = commander.0.stdin.take().unwrap();
    stdin
        .write_all(b"\xff\xfe stop\nstop stray bytes before\n")
        .unwrap();
    stdin.flush().unwrap();
    await_fleet_stop(&heard, || err.try_iter().collect::<Vec<_>>().join("\n"));
    let hint = loop {
        let l = err
            .recv_timeout(Duration::from_secs(10))
            .expect("a hint on stderr");
        if l.contains("unknown request") {
            break l;
        }
    };
    assert!(
        hint.contains("unknown request \"\u{fffd}\u{fffd} stop\""),
        "{hint}"
    );
}

/// A target the commander gives up on (nobody answers: Skeeter is down) is named with its
/// reason in the text summary. It said only "0 target(s) done, 1 failed" (after 18 s at ×10
/// on a fleet whose Skeeter was not running), the reason being in `--json` alone.
#[test]
fn a_failed_target_is_named_with_its_reason() {
    let dir = temp_dir("cmdreason");
    let cfg = commander_config(&dir, "insecure = true\n", "9");
    let text = std::fs::read_to_string(&cfg).unwrap();
    std::fs::write(&cfg, format!("{text}[agent]\ntarget_timeout_s = 0.5\n")).unwrap();
    let out = ima()
        .args(["commander", "--config"])
        .arg(&cfg)
        .args(["--targets", "red", "--wait-timeout", "0"])
        .stdin(Stdio::null())
        .output()
        .unwrap();
    let (stdout, stderr) = (
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr),
    );
    assert_eq!(out.status.code(), Some(1), "{stdout}{stderr}");
    assert!(
        stdout.ends_with("0 target(s) done, 1 failed\n  red: no word from Skeeter: given up\n"),
        "{stdout}"
    );
    assert!(stderr.contains("1 target(s) failed"), "{stderr}");
}

/// The listener counts what it refuses, by class, and prints its counts when interrupted too
/// (it printed them only at `--count`, and only bad MACs and replays of the refusals).
#[test]
fn the_listener_counts_what_it_refuses_and_says_so_on_ctrl_c() {
    let (listener, heard, port) = unicast_listener(&["--insecure".as_ref()]);
    let to = format!("127.0.0.1:{port}");
    let sock = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    let mut bad_version = b"IP".to_vec();
    bad_version.push(9);
    bad_version.resize(80, 0);
    let bad_magic = b"hello, robot! ".repeat(6);
    for junk in [&bad_magic[..], b"IP", &bad_version] {
        sock.send_to(junk, &to).unwrap();
    }
    // A good message after them: once it is printed, the junk before it was read.
    let sent = ima()
        .args([
            "peer",
            "send",
            "--insecure",
            "--mode",
            "unicast",
            "--peer",
            &to,
        ])
        .args(["mission", "--event", "accepted", "--target", "red"])
        .output()
        .unwrap();
    assert!(
        sent.status.success(),
        "{}",
        String::from_utf8_lossy(&sent.stderr)
    );
    let first: Value = serde_json::from_str(
        &heard
            .recv_timeout(Duration::from_secs(30))
            .expect("the message sent"),
    )
    .unwrap();
    assert_eq!(first["type"], "mission", "{first}");
    listener.wait_until_it_catches(2);
    listener.signal("INT");
    let stats: Value = serde_json::from_str(
        &heard
            .recv_timeout(Duration::from_secs(30))
            .expect("the counts at Ctrl-C"),
    )
    .unwrap();
    assert_eq!(stats["event"], "stats", "{stats}");
    let n = |k: &str| stats[k].as_u64().unwrap_or(u64::MAX);
    assert_eq!(
        [
            n("accepted"),
            n("bad_magic"),
            n("truncated"),
            n("bad_version")
        ],
        [1, 1, 1, 1],
        "{stats}"
    );
    assert_eq!(
        [n("bad_mac"), n("oversize"), n("malformed")],
        [0, 0, 0],
        "{stats}"
    );
    // Then the signal's status, as every command ends (it was 0).
    let mut listener = listener;
    assert_eq!(listener.0.wait().unwrap().code(), Some(130));
}

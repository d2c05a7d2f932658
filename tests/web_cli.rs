//! Issue 17: the `--web` flags of `ima demo` and `ima commander` as a user meets them: bad
//! values refused before any work, and a console bound beyond loopback that asks for the token
//! it printed. (The page itself is tested in a real browser: `tests/browser/`.)

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::process::Stdio;
use std::time::Duration;

mod common;
use common::{Child, ima};

fn stderr(out: &std::process::Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

fn status_of(addr: &str, path: &str) -> u16 {
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    write!(
        s,
        "GET {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n"
    )
    .unwrap();
    let mut out = String::new();
    s.read_to_string(&mut out).unwrap();
    out.split_whitespace()
        .nth(1)
        .and_then(|c| c.parse().ok())
        .unwrap_or(0)
}

#[test]
fn bad_web_flags_are_refused_before_the_mission() {
    for (args, want) in [
        (&["demo", "--web", "nowhere"][..], "not an address"),
        (
            &["demo", "--web", "127.0.0.1:0", "--web-token", "short"][..],
            "--web-token",
        ),
        (
            &["commander", "--config", "/nonexistent.toml", "--web", "x:y"][..],
            "not an address",
        ),
    ] {
        let out = ima().args(args).output().unwrap();
        assert_eq!(out.status.code(), Some(1), "{args:?}");
        let err = stderr(&out);
        assert!(err.contains(want), "{args:?}: {err}");
        assert!(!err.contains("world ×"), "nothing ran: {err}");
    }
}

#[test]
fn beyond_loopback_the_console_asks_for_its_printed_token() {
    let dir = common::Scratch::new("web-token");
    let child = ima()
        .args([
            "demo",
            "--web",
            "0.0.0.0:0",
            "--speed",
            "20",
            "--targets",
            "red",
            "--svg",
        ])
        .arg(dir.join("demo.svg"))
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut child = Child(child);
    let err = child.0.stderr.take().unwrap();
    let mut url = None;
    for line in BufReader::new(err).lines() {
        let line = line.unwrap();
        if let Some(u) = line.strip_prefix("ima: web console at ") {
            url = Some(u.to_owned());
            break;
        }
    }
    let url = url.expect("the console's URL on stderr");
    let (hostport, token) = url
        .strip_prefix("http://")
        .and_then(|r| r.split_once("/?token="))
        .expect("a token in the URL");
    assert_eq!(token.len(), 32, "{url}");
    // Bound to every address, the URL names one a browser can open.
    let (host, port) = hostport.rsplit_once(':').unwrap();
    assert_eq!(host, "127.0.0.1", "{url}");
    let local = format!("127.0.0.1:{port}");
    assert_eq!(status_of(&local, "/"), 401);
    // The page's script loads without the token (the page asks for it without one).
    assert_eq!(status_of(&local, "/app.js"), 200);
    assert_eq!(status_of(&local, "/api/state?token=nope"), 401);
    assert_eq!(status_of(&local, &format!("/?token={token}")), 200);
    assert_eq!(status_of(&local, &format!("/api/state?token={token}")), 200);
}

/// The text commander's stdin `add COLOUR [at N]` and `move COLOUR N` go through the same
/// commander requests as the page: the series changes in the commander's `queue` events and
/// in the console's state alike; bad requests get a clear message on stderr and change
/// nothing. No robot answers (the commander waits for one), so every target stays waiting.
#[cfg(unix)]
#[test]
fn stdin_add_and_move_reorder_the_series_as_the_page_sees_it() {
    let dir = std::env::temp_dir().join(format!("ima-web-stdin-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let (_, udp) = common::mission::free_ports(0, 2);
    let (nobody, bind) = (udp[0], udp[1]);
    let cfg = dir.join("commander.toml");
    std::fs::write(
        &cfg,
        format!(
            "robot = \"commander\"\nrole = \"commander\"\n[peer]\ninsecure = true\nbroadcast_group = \"\"\n\
             broadcast_peers = [\"127.0.0.1:{nobody}\"]\nbroadcast_bind = \"127.0.0.1:{bind}\"\n"
        ),
    )
    .unwrap();
    let mut child = Child(
        ima()
            .args(["commander", "--json", "--insecure", "--targets", "red"])
            .args(["--wait-for", "skeeter", "--wait-timeout", "600"])
            .args(["--web", "127.0.0.1:0", "--config"])
            .arg(&cfg)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    // stderr: the console's address, then the refusals.
    let (err_tx, err_rx) = std::sync::mpsc::channel::<String>();
    let err = child.0.stderr.take().unwrap();
    std::thread::spawn(move || {
        for l in BufReader::new(err).lines().map_while(Result::ok) {
            let _ = err_tx.send(l);
        }
    });
    let next_err = |want: &str| -> String {
        loop {
            let l = err_rx
                .recv_timeout(Duration::from_secs(60))
                .unwrap_or_else(|_| panic!("no stderr line with {want:?}"));
            if l.contains(want) {
                return l;
            }
        }
    };
    let url = next_err("web console at ");
    let addr = url
        .rsplit_once("http://")
        .unwrap()
        .1
        .trim_end_matches('/')
        .to_owned();
    // stdout: the series after each change.
    let (q_tx, q_rx) = std::sync::mpsc::channel::<Vec<String>>();
    let out = child.0.stdout.take().unwrap();
    std::thread::spawn(move || {
        for l in BufReader::new(out).lines().map_while(Result::ok) {
            let v: serde_json::Value = serde_json::from_str(&l).unwrap();
            if v["kind"] == "queue" {
                let order = v["detail"]["targets"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .map(|t| t["target"].as_str().unwrap().to_owned())
                    .collect();
                let _ = q_tx.send(order);
            }
        }
    });
    let wait_series = |want: &[&str]| loop {
        let got = q_rx
            .recv_timeout(Duration::from_secs(60))
            .unwrap_or_else(|_| panic!("no series {want:?}"));
        if got == want {
            return;
        }
    };
    wait_series(&["red"]);
    let mut stdin = child.0.stdin.take().unwrap();
    let mut say = |line: &str| {
        writeln!(stdin, "{line}").unwrap();
        stdin.flush().unwrap();
    };
    say("add blue");
    wait_series(&["red", "blue"]);
    say("add green at 1");
    wait_series(&["green", "red", "blue"]);
    say("move blue 1");
    wait_series(&["blue", "green", "red"]);
    // Bad requests: a message each, and the series stays as it is.
    say("add pink");
    let e = next_err("unknown colour \"pink\"");
    assert!(e.contains("red") && e.contains("blue"), "{e}");
    say("move yellow 1");
    next_err("no waiting target \"yellow\"");
    say("add red at 9");
    next_err("cannot add at position 9");
    say("move red 0");
    next_err("positions count from 1");
    say("fly away");
    next_err("add COLOUR [at N]");
    // The page sees the same series.
    let mut s = TcpStream::connect(&addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    write!(
        s,
        "GET /api/state HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n"
    )
    .unwrap();
    let mut resp = String::new();
    s.read_to_string(&mut resp).unwrap();
    let body = resp.split_once("\r\n\r\n").unwrap().1;
    let state: serde_json::Value = serde_json::from_str(body).unwrap();
    let order: Vec<&str> = state["targets"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| t["target"].as_str().unwrap())
        .collect();
    assert_eq!(order, ["blue", "green", "red"], "{state}");
    assert!(
        state["targets"]
            .as_array()
            .unwrap()
            .iter()
            .all(|t| t["state"] == "waiting")
    );
    let _ = std::fs::remove_dir_all(&dir);
}

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
        "GET {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n"
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
        .arg(std::env::temp_dir().join(format!("ima-web-{}.svg", std::process::id())))
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
    let port = hostport.rsplit_once(':').unwrap().1;
    let local = format!("127.0.0.1:{port}");
    assert_eq!(status_of(&local, "/"), 401);
    assert_eq!(status_of(&local, "/api/state?token=nope"), 401);
    assert_eq!(status_of(&local, &format!("/?token={token}")), 200);
    assert_eq!(status_of(&local, &format!("/api/state?token={token}")), 200);
}

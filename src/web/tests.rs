//! Tests of the console's state, messages and server (plain HTTP/1.1 over TCP).

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::time::Duration;

use serde_json::{Value, json};

use super::*;

fn ev(t_s: f64, robot: &str, kind: &str, detail: Value) -> state::JsonEvent {
    state::JsonEvent {
        t_s,
        robot: robot.into(),
        kind: kind.into(),
        detail,
    }
}

fn colours() -> Vec<String> {
    ["red", "blue", "green"].map(String::from).to_vec()
}

/// One request as the page makes it (JSON, to the address it was served from); the status
/// code and the body.
fn http(addr: SocketAddr, method: &str, path: &str, body: &str) -> (u16, String) {
    let headers = format!("Host: {addr}\r\nContent-Type: application/json\r\n");
    request(addr, method, path, &headers, body)
}

/// One request with these header lines (each ending in CRLF); the status code and the body.
fn request(addr: SocketAddr, method: &str, path: &str, headers: &str, body: &str) -> (u16, String) {
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    write!(
        s,
        "{method} {path} HTTP/1.1\r\n{headers}Connection: close\r\nContent-Length: {}\r\n\r\n{body}",
        body.len()
    )
    .unwrap();
    let mut out = String::new();
    s.read_to_string(&mut out).unwrap();
    let code = out
        .split_whitespace()
        .nth(1)
        .and_then(|c| c.parse().ok())
        .unwrap_or(0);
    let body = out
        .split_once("\r\n\r\n")
        .map(|x| x.1)
        .unwrap_or("")
        .to_owned();
    (code, body)
}

/// Opens the event stream and reads until the first `state` event's data.
fn first_state(addr: SocketAddr) -> (BufReader<TcpStream>, Value) {
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    write!(s, "GET /api/events HTTP/1.1\r\nHost: {addr}\r\n\r\n").unwrap();
    let mut r = BufReader::new(s);
    let mut line = String::new();
    loop {
        line.clear();
        assert!(r.read_line(&mut line).unwrap() > 0, "stream ended");
        if let Some(d) = line.strip_prefix("data: ") {
            return (r, serde_json::from_str(d.trim()).unwrap());
        }
    }
}

#[test]
fn events_build_the_state_the_page_shows() {
    let mut s = ConsoleState::new("demo", colours());
    s.truth("scooter", 1.0, 2.0, 0.0);
    s.apply_json(&ev(
        1.0,
        "commander",
        "queue",
        json!({"targets": [{"index": 0, "target": "red", "state": "sent"}]}),
    ));
    s.apply_json(&ev(
        2.0,
        "commander",
        "broadcast",
        json!({"type": "status", "robot": "scooter", "behaviour": "go-to-target", "san": "",
            "pose": {"x_m": 0.5, "y_m": 0.0, "theta_rad": 0.1}}),
    ));
    s.apply_json(&ev(
        2.5,
        "commander",
        "robot",
        json!({"robot": "skeeter", "state": "lost", "silent_s": 6.0}),
    ));
    for (t, a) in [(3.0, 0.2), (4.0, 0.7)] {
        s.apply_json(&ev(
            t,
            "skeeter",
            "san",
            json!({"modules": [{"name": "scan", "activation": a, "executable": true}],
                "threshold": 0.5, "conditions": [], "selected": "scan"}),
        ));
    }
    s.set_performance(0, 0.8);
    let v = s.snapshot();
    assert_eq!(v["type"], "state");
    assert_eq!(v["targets"][0]["target"], "red");
    assert_eq!(v["targets"][0]["performance"], 0.8);
    // The belief is drawn from the robot's start (its first ground-truth pose).
    assert_eq!(v["robots"]["scooter"]["pose"], json!([1.5, 2.0, 0.1]));
    assert_eq!(v["robots"]["scooter"]["behaviour"], "go-to-target");
    assert_eq!(v["robots"]["skeeter"]["life"], "lost");
    assert_eq!(
        v["san"]["skeeter"]["history"],
        json!([[3.0, [0.2]], [4.0, [0.7]]])
    );
    assert_eq!(v["log"][0]["text"], "go-to-target");
    assert_eq!(v["t_s"], 4.0);
    assert_eq!(s.lost_robots(), ["skeeter"]);
    assert!(s.open_target("red") && !s.open_target("blue"));
}

#[test]
fn logs_and_trails_stay_bounded() {
    let mut s = ConsoleState::new("demo", colours());
    for i in 0..5000 {
        let x = f64::from(i) / 10.0;
        s.apply_json(&ev(
            x,
            "commander",
            "broadcast",
            json!({"type": "status", "robot": "scooter", "behaviour": "b", "san": "",
                "pose": {"x_m": x, "y_m": 0.0, "theta_rad": 0.0}}),
        ));
        s.apply_json(&ev(x, "scooter", "san", json!({"modules": []})));
    }
    let r = &s.robots["scooter"];
    assert!(r.trail.len() <= state::MAX_TRAIL);
    assert_eq!(
        r.trail.last(),
        Some(&[499.9, 0.0]),
        "the newest point is kept"
    );
    assert_eq!(s.log.len(), state::MAX_LOG);
    assert_eq!(s.san["scooter"].history.len(), state::MAX_SAN_HISTORY);
}

#[test]
fn odd_event_details_are_not_a_panic() {
    let mut s = ConsoleState::new("commander", colours());
    for kind in [
        "queue",
        "target",
        "robot",
        "broadcast",
        "fleet",
        "operator",
        "behaviour",
        "san",
        "map",
        "ses-form",
        "peer-status",
        "peer",
        "waiting",
        "what",
    ] {
        for d in [
            json!(null),
            json!(1),
            json!("x"),
            json!({"targets": 3, "dr": ["a"], "pose": {"x_m": "NaN"}}),
        ] {
            s.apply_json(&ev(f64::NAN, "r", kind, d));
        }
    }
    s.truth("r", f64::NAN, 0.0, 0.0);
    let _ = s.snapshot().to_string();
}

#[test]
fn the_server_serves_the_page_state_and_commands() {
    let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel();
    let c = Console::new("commander", colours(), Some(tx), None);
    c.apply_json(&ev(
        0.0,
        "commander",
        "queue",
        json!({"targets": [{"index": 0, "target": "red", "state": "sent"},
            {"index": 1, "target": "blue", "state": "waiting"}]}),
    ));
    let srv = start(Arc::clone(&c), "127.0.0.1:0".parse().unwrap()).unwrap();
    let (code, page) = http(srv.addr, "GET", "/", "");
    assert_eq!(code, 200);
    assert!(page.contains("<title>ima console</title>") && page.contains("app.js"));
    assert!(
        !page.contains("http://") && !page.contains("https://"),
        "no CDN"
    );
    assert_eq!(http(srv.addr, "GET", "/app.js", "").0, 200);
    assert_eq!(http(srv.addr, "GET", "/style.css", "").0, 200);
    let (code, st) = http(srv.addr, "GET", "/api/state", "");
    assert_eq!(code, 200);
    let st: Value = serde_json::from_str(&st).unwrap();
    assert_eq!(st["targets"][1]["target"], "blue");

    let (code, r) = http(
        srv.addr,
        "POST",
        "/api/command",
        r#"{"cmd":"cancel","target":"blue"}"#,
    );
    assert_eq!(code, 200, "{r}");
    let r: Reply = serde_json::from_str(&r).unwrap();
    assert_eq!(r, Reply::ok("target blue cancelled"));
    assert_eq!(rx.try_recv(), Ok(Operator::Cancel("blue".into())));

    let (code, r) = http(
        srv.addr,
        "POST",
        "/api/command",
        r#"{"cmd":"add","target":"mauve"}"#,
    );
    assert_eq!(code, 400);
    let r: Reply = serde_json::from_str(&r).unwrap();
    assert!(
        !r.ok && r.message.contains("unknown colour \"mauve\""),
        "{r:?}"
    );
    let (code, r) = http(srv.addr, "POST", "/api/command", "{not json");
    assert_eq!(code, 400, "{r}");
    assert!(
        rx.try_recv().is_err(),
        "nothing refused reaches the commander"
    );
    // Replies are shown on the page too.
    let st: Value = serde_json::from_str(&http(srv.addr, "GET", "/api/state", "").1).unwrap();
    assert!(st["notices"].as_array().unwrap().len() >= 3);

    // A lost robot: the command goes, with a warning.
    c.apply_json(&ev(
        1.0,
        "commander",
        "robot",
        json!({"robot": "scooter", "state": "lost", "silent_s": 7.0}),
    ));
    let (_, r) = http(srv.addr, "POST", "/api/command", r#"{"cmd":"stop"}"#);
    assert!(r.contains("scooter is lost"), "{r}");
    assert_eq!(rx.try_recv(), Ok(Operator::Stop("operator".into())));

    // A move onto a target already sent is refused here (the commander refused it after an
    // "ok"), in the page's positions (from 1).
    let (code, r) = http(
        srv.addr,
        "POST",
        "/api/command",
        r#"{"cmd":"move","from":1,"to":0}"#,
    );
    assert_eq!(code, 400, "{r}");
    assert!(r.contains("position 1 holds red, which is sent"), "{r}");
    assert!(rx.try_recv().is_err());

    // Another method: 405, saying what to do.
    let (code, r) = http(srv.addr, "GET", "/api/command", "");
    assert_eq!(code, 405);
    assert!(r.contains("use POST"), "{r}");
    assert_eq!(http(srv.addr, "DELETE", "/", "").0, 405);
    assert!(rx.try_recv().is_err());

    // The mission over: read-only.
    c.close_commands();
    let (code, r) = http(srv.addr, "POST", "/api/command", r#"{"cmd":"resume"}"#);
    assert_eq!(code, 400);
    assert!(r.contains("mission is over"), "{r}");
    drop(srv);
}

/// Adds the commander has not shown yet count: a flood of adds gets "ok" only for the room
/// the series has (seen: 1,045 "ok" for 256 added in a flood of 5,000).
#[test]
fn adds_in_flight_count_against_the_series_limit() {
    use ima_agents::mission::commander::MAX_SERIES;
    let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel();
    let c = Console::new("commander", colours(), Some(tx), None);
    let targets: Vec<Value> = (0..MAX_SERIES - 2)
        .map(|i| json!({"index": i, "target": "red", "state": "done"}))
        .collect();
    c.apply_json(&ev(
        0.0,
        "commander",
        "queue",
        json!({ "targets": targets }),
    ));
    let srv = start(Arc::clone(&c), "127.0.0.1:0".parse().unwrap()).unwrap();
    let add = || {
        http(
            srv.addr,
            "POST",
            "/api/command",
            r#"{"cmd":"add","target":"blue"}"#,
        )
    };
    assert_eq!(add().0, 200);
    assert_eq!(add().0, 200);
    let (code, r) = add();
    assert_eq!(code, 400, "{r}");
    assert!(r.contains("the queue is full"), "{r}");
    assert_eq!(rx.try_recv(), Ok(Operator::Add("blue".into())));
    assert_eq!(rx.try_recv(), Ok(Operator::Add("blue".into())));
    assert!(rx.try_recv().is_err(), "the third add stays here");
    // The commander shows one of the two: the other still counts.
    let mut targets = targets;
    targets.push(json!({"index": MAX_SERIES - 2, "target": "blue", "state": "waiting"}));
    c.apply_json(&ev(
        1.0,
        "commander",
        "queue",
        json!({ "targets": targets }),
    ));
    assert_eq!(add().0, 400);
    drop(srv);
}

#[test]
fn beyond_loopback_a_token_is_needed_and_checked() {
    let c = Console::new("demo", colours(), None, None);
    assert!(
        start(Arc::clone(&c), "0.0.0.0:0".parse().unwrap())
            .unwrap_err()
            .to_string()
            .contains("needs a token")
    );
    let c = Console::new("demo", colours(), None, Some("s3cret".into()));
    let srv = start(c, "127.0.0.1:0".parse().unwrap()).unwrap();
    let (code, body) = http(srv.addr, "GET", "/", "");
    assert_eq!(code, 401);
    assert!(body.contains("token"));
    assert_eq!(http(srv.addr, "GET", "/?token=wrong", "").0, 401);
    assert_eq!(http(srv.addr, "GET", "/api/state?token=s3cret", "").0, 200);
    assert_eq!(http(srv.addr, "GET", "/?token=s3cret", "").0, 200);
    // The page loads its script and style sheet without the token (they were refused, so a
    // console beyond loopback had a page without its script); the state still needs it.
    let (code, js) = http(srv.addr, "GET", "/app.js", "");
    assert_eq!(code, 200);
    assert!(js.contains("token"), "the script passes the token on");
    assert_eq!(http(srv.addr, "GET", "/style.css", "").0, 200);
    assert_eq!(http(srv.addr, "GET", "/api/state", "").0, 401);
    assert_eq!(http(srv.addr, "GET", "/api/events", "").0, 401);
    assert_eq!(
        url(srv.addr, Some("s3cret")),
        format!("http://{}/?token=s3cret", srv.addr)
    );
    let any: SocketAddr = "0.0.0.0:8080".parse().unwrap();
    assert_eq!(url(any, Some("t")), "http://127.0.0.1:8080/?token=t");
    let any6: SocketAddr = "[::]:8080".parse().unwrap();
    assert_eq!(url(any6, None), "http://[::1]:8080/");
}

/// A page on another site must not command the robots through the operator's browser (a
/// "simple" cross-site POST needs no preflight, and a loopback console has no token), nor read
/// the console through a domain re-bound to 127.0.0.1.
#[test]
fn other_sites_can_neither_command_nor_read_the_console() {
    let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel();
    let c = Console::new("commander", colours(), Some(tx), None);
    let srv = start(Arc::clone(&c), "127.0.0.1:0".parse().unwrap()).unwrap();
    let a = srv.addr;
    let resume = r#"{"cmd":"resume"}"#;
    let host = format!("Host: {a}\r\n");
    // What a cross-site form or `fetch(…, {mode: "no-cors"})` sends: refused, nothing sent.
    let plain = format!("{host}Content-Type: text/plain\r\n");
    let (code, body) = request(a, "POST", "/api/command", &plain, resume);
    assert_eq!(code, 403, "{body}");
    assert!(body.contains("Content-Type: application/json"), "{body}");
    let evil = format!("{host}Origin: http://evil.example\r\nContent-Type: application/json\r\n");
    let (code, body) = request(a, "POST", "/api/command", &evil, resume);
    assert_eq!(code, 403, "{body}");
    assert!(
        body.contains("another site (http://evil.example)"),
        "{body}"
    );
    // A sandboxed page or a local file says `Origin: null`; a preflight is refused too.
    let null = format!("{host}Origin: null\r\nContent-Type: application/json\r\n");
    assert_eq!(request(a, "POST", "/api/command", &null, resume).0, 403);
    assert_eq!(request(a, "OPTIONS", "/api/command", &evil, "").0, 403);
    assert!(
        rx.try_recv().is_err(),
        "nothing refused reaches the commander"
    );
    // DNS rebinding: the right address, another site's name (also one that starts like a
    // loopback name; the HTTP layer itself answers 400 to a malformed one).
    for name in [
        "[::1].evil.example",
        "localhost.evil.example:80",
        "127.0.0.1:80x",
    ] {
        let h = format!("Host: {name}\r\n");
        let code = request(a, "GET", "/api/state", &h, "").0;
        assert!(code == 403 || code == 400, "{name}: {code}");
    }
    let rebound = "Host: evil.example\r\n";
    assert_eq!(request(a, "GET", "/api/state", rebound, "").0, 403);
    let json = "Content-Type: application/json\r\n";
    let post = format!("{rebound}{json}");
    assert_eq!(request(a, "POST", "/api/command", &post, resume).0, 403);
    assert!(rx.try_recv().is_err());
    // The page itself, by any loopback name, with or without an Origin header.
    let own = format!("{host}Origin: http://{a}\r\n{json}");
    assert_eq!(request(a, "POST", "/api/command", &own, resume).0, 200);
    assert_eq!(rx.try_recv(), Ok(Operator::Resume));
    let port = a.port();
    for name in [
        format!("localhost:{port}"),
        format!("LocalHost.:{port}"),
        format!("[::1]:{port}"),
        "127.0.0.2".into(),
    ] {
        let h = format!("Host: {name}\r\n");
        assert_eq!(request(a, "GET", "/api/state", &h, "").0, 200, "{name}");
    }
    // With a token (a console beyond loopback) any host name may be used, with the token.
    let c = Console::new("demo", colours(), None, Some("s3cret".into()));
    let srv = start(c, "127.0.0.1:0".parse().unwrap()).unwrap();
    let lan = "Host: 192.168.1.20:8080\r\n";
    assert_eq!(
        request(srv.addr, "GET", "/api/state?token=s3cret", lan, "").0,
        200
    );
    assert_eq!(request(srv.addr, "GET", "/api/state", lan, "").0, 401);
}

#[test]
fn fifty_clients_at_once_and_clients_that_vanish_mid_stream() {
    let c = Console::new("demo", colours(), None, None);
    let srv = start(Arc::clone(&c), "127.0.0.1:0".parse().unwrap()).unwrap();
    let mut streams: Vec<_> = (0..50).map(|_| first_state(srv.addr)).collect();
    for (_, v) in &streams {
        assert_eq!(v["type"], "state");
    }
    // Half of them go away mid-stream, without a word.
    streams.truncate(25);
    c.apply_json(&ev(
        5.0,
        "commander",
        "queue",
        json!({"targets": [{"index": 0, "target": "green", "state": "sent"}]}),
    ));
    // The others get the change.
    for (r, _) in &mut streams {
        let mut line = String::new();
        loop {
            line.clear();
            assert!(r.read_line(&mut line).unwrap() > 0);
            if let Some(d) = line.strip_prefix("data: ") {
                let v: Value = serde_json::from_str(d.trim()).unwrap();
                if v["targets"][0]["target"] == "green" {
                    break;
                }
            }
        }
    }
    // One that sends half a request and disconnects.
    {
        let mut s = TcpStream::connect(srv.addr).unwrap();
        let _ = s.write_all(b"POST /api/command HTTP/1.1\r\nContent-Length: 100\r\n\r\n{\"cmd\"");
    }
    drop(streams);
    let (code, _) = http(srv.addr, "GET", "/api/state", "");
    assert_eq!(code, 200, "the server still answers");
    drop(srv);
}

#[test]
fn silent_clients_are_closed_and_cannot_fill_the_server() {
    let c = Console::new("demo", colours(), None, None);
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    listener.set_nonblocking(true).unwrap();
    let addr = listener.local_addr().unwrap();
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let app = router(c);
    // A deadline long enough that every place is still held when the extra client comes,
    // on a loaded machine too.
    let deadline = Duration::from_secs(10);
    std::thread::spawn(move || {
        rt.block_on(async move {
            let l = tokio::net::TcpListener::from_std(listener).unwrap();
            serve(l, app, deadline).await;
        });
    });
    // Every place taken: the first by a command whose body never comes whole, the others by
    // requests whose headers never end.
    let half: Vec<TcpStream> = (0..MAX_CONNECTIONS)
        .map(|i| {
            let mut s = TcpStream::connect(addr).unwrap();
            let sent: &[u8] = if i == 0 {
                b"POST /api/command HTTP/1.1\r\nHost: 127.0.0.1\r\n\
                  Content-Type: application/json\r\nContent-Length: 100\r\n\r\n{\"cmd\""
            } else {
                b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nX-a: "
            };
            s.write_all(sent).unwrap();
            s
        })
        .collect();
    // One more is closed unanswered.
    let mut extra = TcpStream::connect(addr).unwrap();
    extra
        .set_read_timeout(Some(Duration::from_secs(20)))
        .unwrap();
    let _ = extra.write_all(b"GET /api/state HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n");
    let mut got = Vec::new();
    let end = extra.read_to_end(&mut got);
    assert!(
        got.is_empty()
            && !end
                .as_ref()
                .is_err_and(|e| e.kind() == std::io::ErrorKind::WouldBlock),
        "{end:?} {:?}",
        String::from_utf8_lossy(&got)
    );
    // The silent ones are closed at their deadline (not left for ever), the command with
    // "408 Request Timeout"…
    for (i, mut s) in half.into_iter().enumerate() {
        s.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
        let mut rest = Vec::new();
        let end = s.read_to_end(&mut rest);
        if i == 0 {
            let answer = String::from_utf8_lossy(&rest);
            assert!(answer.starts_with("HTTP/1.1 408"), "{answer}");
        }
        assert!(
            !end.as_ref().is_err_and(|e| {
                matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                )
            }),
            "{end:?}"
        );
    }
    // …and their places serve again.
    assert_eq!(http(addr, "GET", "/api/state", "").0, 200);
}

/// A write that waits for a client that does not read (an event stream nobody reads) fails
/// after the limit, freeing the connection's place; a client that reads resets the clock.
#[tokio::test(start_paused = true)]
async fn a_write_the_client_does_not_read_ends_after_the_limit() {
    use tokio::io::{AsyncReadExt as _, AsyncWriteExt as _};
    let (a, mut client) = tokio::io::duplex(64);
    let mut w = WriteDeadline::new(a, Duration::from_secs(30));
    w.write_all(&[1; 64]).await.unwrap();
    // Read within the limit: the next write goes through.
    tokio::time::sleep(Duration::from_secs(20)).await;
    let mut buf = [0; 64];
    client.read_exact(&mut buf).await.unwrap();
    w.write_all(&[2; 64]).await.unwrap();
    // Not read: the write after it fails at the limit, not before.
    let t0 = tokio::time::Instant::now();
    let e = w.write_all(&[3; 1]).await.unwrap_err();
    assert_eq!(e.kind(), std::io::ErrorKind::TimedOut);
    assert_eq!(t0.elapsed(), Duration::from_secs(30));
}

#[test]
fn addresses_parse_or_say_why_not() {
    assert_eq!(
        parse_addr("localhost:9000").unwrap(),
        "127.0.0.1:9000".parse().unwrap()
    );
    assert_eq!(
        parse_addr(DEFAULT_ADDR).unwrap(),
        "127.0.0.1:8080".parse().unwrap()
    );
    let e = format!("{:#}", parse_addr("nowhere").unwrap_err());
    assert!(e.contains("not an address"), "{e}");
    // A port alone is on loopback, as `--foxglove` takes it (`--web 0`: a free port).
    assert_eq!(parse_addr(" 0 ").unwrap(), "127.0.0.1:0".parse().unwrap());
    assert_eq!(
        parse_addr("8081").unwrap(),
        "127.0.0.1:8081".parse().unwrap()
    );
    assert!(parse_addr("99999").is_err());
    assert!(parse_addr("").is_err());
}

#[test]
fn typed_runtime_events_become_the_pages_json() {
    use ima_agents::runtime::events::{
        Control, PeerStatus, QueueEntry, SanModuleView, SanView, SesMark,
    };
    use ima_agents::runtime::{Event, EventKind};
    let e = |robot: &str, kind: EventKind| Event {
        t_s: 2.0,
        robot: robot.into(),
        kind,
    };
    let mut s = ConsoleState::new("demo", colours());
    s.apply(&e(
        "commander",
        EventKind::Queue {
            targets: vec![QueueEntry {
                index: 0,
                target: "red".into(),
                state: "sent".into(),
                sent_s: Some(1.0),
                accepted_s: None,
                ended_s: None,
                time_s: None,
                cancelled: false,
                given_up: false,
                sends: 1,
            }],
        },
    ));
    s.apply(&e(
        "skeeter",
        EventKind::San(SanView {
            network: "skeeter".into(),
            modules: vec![SanModuleView {
                name: "scan".into(),
                activation: 0.75,
                executable: true,
            }],
            threshold: 0.5,
            conditions: Vec::new(),
            selected: "scan".into(),
        }),
    ));
    s.apply(&e(
        "skeeter",
        EventKind::SesPublished {
            marks: vec![
                SesMark {
                    tag: "red".into(),
                    azimuth_rad: 0.5,
                    elevation_rad: 0.0,
                    range_m: Some(2.25),
                },
                SesMark {
                    tag: "scooter".into(),
                    azimuth_rad: -1.0,
                    elevation_rad: 0.0,
                    range_m: None,
                },
                SesMark {
                    tag: "blue".into(),
                    azimuth_rad: 0.1,
                    elevation_rad: 0.0,
                    range_m: Some(f64::NAN),
                },
            ],
        },
    ));
    s.apply(&e(
        "commander",
        EventKind::PeerStatus(Box::new(PeerStatus {
            broadcast: Some(Default::default()),
            ..PeerStatus::default()
        })),
    ));
    s.apply(&e(
        "scooter",
        EventKind::Control(Control {
            v_m_s: 0.2,
            omega_rad_s: 0.0,
            heading_rad: Some(1.0),
            desired_rad: None,
            dr: [1.0, 2.0],
            behaviour: "move-to-target",
            halted: false,
        }),
    ));
    let v = s.snapshot();
    assert_eq!(v["targets"][0]["target"], "red");
    assert_eq!(v["targets"][0]["state"], "sent");
    assert_eq!(
        v["san"]["skeeter"]["latest"]["modules"][0]["activation"],
        0.75
    );
    assert_eq!(v["san"]["skeeter"]["history"][0][1][0], 0.75);
    assert_eq!(v["ses"]["form"]["records"][0]["object"], "red");
    assert_eq!(v["ses"]["form"]["records"][0]["bearing_rad"], 0.5);
    // Ranges where known; a bearing only (null) where not, or where it is not a number.
    assert_eq!(v["ses"]["form"]["records"][0]["range_m"], 2.25);
    assert_eq!(v["ses"]["form"]["records"][1]["object"], "scooter");
    assert!(v["ses"]["form"]["records"][1]["range_m"].is_null());
    assert!(v["ses"]["form"]["records"][2]["range_m"].is_null());
    assert_eq!(v["peer"]["commander"]["broadcast"]["sent"], 0);
    assert_eq!(v["robots"]["scooter"]["pose"][0], 1.0);
    assert_eq!(v["robots"]["scooter"]["pose"][2], 1.0);
}

/// A manager's and a client's Peer Agent status with every part filled in.
fn sample_peer_status() -> ima_agents::runtime::events::PeerStatus {
    use ima_agents::peer::client::{ClientLinkStatus, Registration};
    use ima_agents::peer::manager::{
        ClientStatus, DecisionNote, LinkStatus, Outcome, Priority, RequestStatus,
    };
    use ima_agents::peer::net::{ManagerNetStats, SessionLink};
    use ima_agents::peer::wire::{DenyReason, RejectCounts};
    use ima_agents::runtime::events::{PeerClientView, PeerStatus};
    let p = Priority {
        robot: 1,
        request: 4,
    };
    let rejects = RejectCounts {
        bad_mac: 3,
        replay: 2,
        truncated: 1,
        malformed: 1,
        ..RejectCounts::default()
    };
    let mut stats = ManagerNetStats {
        sessions: 1,
        clients: 1,
        links: vec![SessionLink {
            addr: "127.0.0.1:5000".parse().unwrap(),
            link: LinkStatus {
                peer: 7,
                frames_received: 40,
                heartbeats_received: 31,
                heartbeats_sent: 30,
                silent_for: Duration::from_millis(80),
                open_for: Duration::from_secs(3),
            },
        }],
        ..ManagerNetStats::default()
    };
    stats.core.rejects = rejects;
    PeerStatus {
        manager: Some(stats),
        clients: vec![ClientStatus {
            client: 99,
            peer: 7,
            robot: "scooter".into(),
            requesting: Vec::new(),
            granted: vec!["ses".into()],
            requests: vec![RequestStatus {
                source: "ses".into(),
                priority: p,
                granted: true,
            }],
            recent: vec![
                DecisionNote {
                    source: "ses".into(),
                    priority: p,
                    outcome: Outcome::Denied(DenyReason::UnknownSource),
                    at: ima_hal::Instant::from_millis(500),
                },
                DecisionNote {
                    source: "ses".into(),
                    priority: p,
                    outcome: Outcome::Granted,
                    at: ima_hal::Instant::from_millis(900),
                },
            ],
        }],
        address: Some("127.0.0.1:7400".into()),
        client: Some(PeerClientView {
            manager: "127.0.0.1:7400".into(),
            source: "ses".into(),
            priority: 4,
            outcome: "granted".into(),
            grants: 2,
            samples: 12,
            retries: 1,
            link: Some(ClientLinkStatus {
                client: 99,
                registration: Registration::Registered,
                frames_received: 50,
                heartbeats_received: 30,
                heartbeats_sent: 31,
                silent_for: Duration::from_millis(20),
                open_for: Duration::from_secs(3),
                rejects: RejectCounts::default(),
                requests: vec![("ses".into(), true)],
            }),
        }),
        ..PeerStatus::default()
    }
}

/// The Peer Agent pages' JSON: per manager its sources, clients with request priorities and
/// outcomes, and per session its link health; per client its subscription and session.
#[test]
fn peer_status_carries_link_health_priorities_and_outcomes() {
    use ima_agents::runtime::{Event, EventKind};
    let status = sample_peer_status();
    let mut s = ConsoleState::new("demo", colours());
    s.apply(&Event {
        t_s: 3.0,
        robot: "skeeter".into(),
        kind: EventKind::PeerStatus(Box::new(status)),
    });
    let v = s.snapshot();
    let m = &v["peer"]["skeeter"];
    assert_eq!(m["address"], "127.0.0.1:7400");
    let l = &m["links"][0];
    assert_eq!(l["addr"], "127.0.0.1:5000");
    assert_eq!(l["robots"], json!(["scooter"]));
    assert_eq!(l["heartbeats_received"], 31);
    assert_eq!(l["heartbeats_sent"], 30);
    assert_eq!(l["frames_received"], 40);
    assert_eq!(l["last_seen_ms"], 80);
    assert_eq!(m["rejected"]["auth_failures"], 3);
    assert_eq!(m["rejected"]["replayed"], 2);
    assert_eq!(m["rejected"]["bad_frames"], 2);
    let c = &m["clients"][0];
    assert_eq!(c["robot"], "scooter");
    assert_eq!(c["session"], "127.0.0.1:5000");
    assert_eq!(c["requests"][0]["source"], "ses");
    assert_eq!(c["requests"][0]["robot_priority"], 1);
    assert_eq!(c["requests"][0]["request_priority"], 4);
    assert_eq!(c["requests"][0]["granted"], true);
    assert_eq!(
        c["recent"][0]["outcome"],
        "denied: the manager has no such source"
    );
    assert_eq!(c["recent"][1]["outcome"], "granted");
    assert_eq!(c["recent"][1]["at_ms"], 900);
    let k = &m["client"];
    assert_eq!(k["source"], "ses");
    assert_eq!(k["priority"], 4);
    assert_eq!(k["outcome"], "granted");
    assert_eq!(
        (k["grants"].clone(), k["samples"].clone()),
        (json!(2), json!(12))
    );
    assert_eq!(k["link"]["registration"], "registered");
    assert_eq!(k["link"]["heartbeats_received"], 30);
    assert_eq!(k["link"]["heartbeats_sent"], 31);
    assert_eq!(k["link"]["last_seen_ms"], 20);
    assert_eq!(
        k["link"]["requests"][0],
        json!({"source": "ses", "granted": true})
    );
}

/// The Peer Agent status JSON, field for field, as the page and the recording got it when
/// it was built as a JSON tree (now serialised straight from the status); with a broadcast
/// channel and a source beside.
#[test]
fn peer_status_json_is_unchanged() {
    use ima_agents::peer::net::BroadcastStats;
    let golden = r#"{"address":"127.0.0.1:7400","client":{"grants":2,"link":{"client":99,"frames_received":50,"heartbeats_received":30,"heartbeats_sent":31,"last_seen_ms":20,"open_ms":3000,"registration":"registered","rejected":{"auth_failures":0,"bad_frames":0,"bad_mac":0,"bad_magic":0,"bad_version":0,"malformed":0,"oversize":0,"replay":0,"replayed":0,"truncated":0},"requests":[{"granted":true,"source":"ses"}]},"manager":"127.0.0.1:7400","outcome":"granted","priority":4,"retries":1,"samples":12,"source":"ses"},"clients":[{"client":99,"granted":["ses"],"recent":[{"at_ms":500,"outcome":"denied: the manager has no such source","request_priority":4,"robot_priority":1,"source":"ses"},{"at_ms":900,"outcome":"granted","request_priority":4,"robot_priority":1,"source":"ses"}],"requesting":[],"requests":[{"granted":true,"request_priority":4,"robot_priority":1,"source":"ses"}],"robot":"scooter","session":"127.0.0.1:5000"}],"closed_bad":0,"data_bad_tickets":0,"data_rejected":{"auth_failures":0,"bad_frames":0,"bad_mac":0,"bad_magic":0,"bad_version":0,"malformed":0,"oversize":0,"replay":0,"replayed":0,"truncated":0},"data_sessions":0,"lagged_samples":0,"links":[{"addr":"127.0.0.1:5000","frames_received":40,"heartbeats_received":31,"heartbeats_sent":30,"last_seen_ms":80,"open_ms":3000,"robots":["scooter"],"session":7}],"lost":0,"rejected":{"auth_failures":3,"bad_frames":2,"bad_mac":3,"bad_magic":0,"bad_version":0,"malformed":1,"oversize":0,"replay":2,"replayed":2,"truncated":1},"sessions":1,"slow_closed":0,"sources":[],"task_priority":0}"#;
    let mut want: Value = serde_json::from_str(golden).unwrap();
    let mut status = sample_peer_status();
    assert_eq!(super::feed::peer_status_json(&status), want);
    let mut bus = BroadcastStats {
        sent: 5,
        send_errors: 1,
        ..BroadcastStats::default()
    };
    bus.receiver.accepted = 9;
    bus.receiver.stale = 2;
    bus.wire.oversize = 4;
    status.broadcast = Some(bus);
    if let Some(m) = &mut status.manager {
        m.sources.push(ima_agents::peer::wire::SourceInfo {
            name: "ses".into(),
            kind: "ses".into(),
            schema: 1,
            rate_mhz: 2000,
        });
    }
    want["broadcast"] = json!({"accepted": 9, "duplicate": 0, "stale": 2, "sent": 5,
        "send_errors": 1, "rejected": {"truncated": 0, "bad_magic": 0, "bad_version": 0,
        "oversize": 4, "bad_mac": 0, "replay": 0, "malformed": 0, "auth_failures": 0,
        "bad_frames": 4, "replayed": 0}});
    want["sources"] = json!([{"name": "ses", "kind": "ses", "rate_mhz": 2000}]);
    assert_eq!(super::feed::peer_status_json(&status), want);
    // Without a manager: only what the robot has.
    status.manager = None;
    let v = super::feed::peer_status_json(&status);
    let keys: Vec<&str> = v.as_object().unwrap().keys().map(String::as_str).collect();
    assert_eq!(keys, ["address", "broadcast", "client"]);
}

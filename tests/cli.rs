//! The `ima` program itself: `mock` and `drive` as separate processes over a pty, `decode`,
//! and the demo.

use std::io::Write;
use std::process::{Command, Stdio};

mod common;
use common::{ima, run_ok, spawn_mock};

#[test]
fn mock_and_drive_talk_over_a_pty_in_separate_processes() {
    let (_mock, path) = spawn_mock(&["p2os", "--seed", "3"]);
    let path = path.as_str();
    let out = run_ok(ima().args([
        "drive", "--port", path, "--vel", "0.3", "--turn", "0", "--for", "1.5", "--json",
    ]));
    let lines: Vec<serde_json::Value> = String::from_utf8(out.stdout)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert!(
        lines.len() >= 10,
        "about one report per SIP: {}",
        lines.len()
    );
    let last = lines.last().unwrap();
    assert!(last["x_m"].as_f64().unwrap() > 0.2, "{last}");
    assert!((last["battery_v"].as_f64().unwrap() - 12.5).abs() < 0.05);
    assert!(last["motors_enabled"].as_bool().unwrap());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("connected to Skeeter (Pioneer p2at)"),
        "{stderr}"
    );
}

/// A reader that does not read (a pager nobody scrolls) does not stall the drive: the state
/// lines wait on a thread of their own, the robot drives for `--for` and is stopped and
/// closed, and the lines come out once the reader reads. The motion loop used to block on
/// the full pipe after ~9 s of JSON lines: no velocity command went out, the robot's
/// watchdog stopped it short, and `ima drive` hung until the reader read.
#[test]
fn a_stalled_stdout_does_not_stall_the_drive() {
    let (_mock, path) = spawn_mock(&["p2os", "--seed", "3"]);
    let mut drive = common::Child(
        ima()
            .args(["drive", "--port", &path, "--vel", "0.1", "--turn", "0"])
            .args(["--for", "14", "--json"])
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let (err, _reader) = common::line_channel(drive.0.stderr.take().unwrap());
    // 14 s of JSON lines (~7 KB/s) overfill the pipe (64 KiB), which nobody reads yet.
    let stopped = loop {
        let l = err
            .recv_timeout(std::time::Duration::from_secs(40))
            .expect("the drive ended its motion");
        if l.starts_with("stopped at") || l.starts_with("still moving") {
            break l;
        }
    };
    let x: f64 = stopped
        .strip_prefix("stopped at x=")
        .and_then(|r| r.split(' ').next())
        .and_then(|x| x.parse().ok())
        .unwrap_or_else(|| panic!("{stopped}"));
    assert!(x > 1.2, "drove {x} m of the 1.4 m asked: {stopped}");
    let mut out = String::new();
    std::io::Read::read_to_string(&mut drive.0.stdout.take().unwrap(), &mut out).unwrap();
    assert!(drive.0.wait().unwrap().success());
    let lines = out.lines().count();
    assert!(lines >= 100, "{lines} state lines");
}

/// The robot's port goes away mid-drive (a pulled cable; here the mock is killed): the drive
/// fails saying that nothing from here can stop the robot any more and what does (it said only
/// "P2OS robot driver disconnected"), once (the exit's note said it again).
#[test]
fn a_link_lost_mid_drive_says_who_stops_the_robot_now() {
    let (mut mock, path) = spawn_mock(&["p2os", "--seed", "3"]);
    let mut drive = common::Child(
        ima()
            .args([
                "drive", "--port", &path, "--vel", "0.1", "--for", "30", "--json",
            ])
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let (lines, _out) = common::line_channel(drive.0.stdout.take().unwrap());
    lines
        .recv_timeout(std::time::Duration::from_secs(30))
        .expect("a state line");
    mock.0.kill().unwrap();
    let _ = mock.0.wait();
    let mut err = String::new();
    std::io::Read::read_to_string(&mut drive.0.stderr.take().unwrap(), &mut err).unwrap();
    assert_eq!(drive.0.wait().unwrap().code(), Some(1), "{err}");
    assert!(
        err.contains(
            "the link to the robot was lost while it was driving: ima can no longer stop it; its \
             own watchdog stops it once it hears nothing (P2OS: 2 s after the last command it \
             received); keep clear until it stands"
        ),
        "{err}"
    );
    // Said once: the exit's note about a stop that is not confirmed said it again.
    assert!(!err.contains("is not confirmed"), "{err}");
}

#[test]
fn drive_reports_a_clear_error_when_nothing_answers() {
    // A pty nobody serves: the handshake times out at every rate.
    let (_master, slave) = ima_mock_devices::pty::pty_pair().unwrap();
    let path = serialport::SerialPort::name(&slave).unwrap();
    let out = ima()
        .args([
            "drive",
            "--port",
            &path,
            "--for",
            "0",
            "--connect-timeout",
            "1",
        ])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("connecting to a P2OS robot"), "{err}");
}

/// Bytes are decoded as they are read: a heading written to a live pipe comes out as its line
/// while the pipe stays open (a sniffer's pipe, `< /dev/ttyUSB0`); it used to come out only at
/// the end of the input. Closing the pipe ends the decode with the truncated rest reported.
#[test]
fn decode_shows_each_frame_of_a_live_pipe_as_it_comes() {
    let mut child = ima()
        .args(["decode", "compass"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let mut stdin = child.stdin.take().unwrap();
    let (rx, reader) = common::line_channel(child.stdout.take().unwrap());
    let next = || {
        rx.recv_timeout(std::time::Duration::from_secs(10))
            .expect("no line while the pipe is open")
    };
    stdin.write_all(b"$HCHDM,238.5,M*25\r\n").unwrap();
    stdin.flush().unwrap();
    let first: serde_json::Value = serde_json::from_str(&next()).unwrap();
    assert_eq!(
        (first["kind"].as_str(), first["offset"].as_u64()),
        (Some("hdm"), Some(0))
    );
    stdin.write_all(b"$HCHDM,100.0,M*2").unwrap();
    stdin.flush().unwrap();
    stdin.write_all(b"8\r\n$HCH").unwrap();
    stdin.flush().unwrap();
    let second: serde_json::Value = serde_json::from_str(&next()).unwrap();
    assert_eq!(second["offset"], 19);
    drop(stdin);
    let last: serde_json::Value = serde_json::from_str(&next()).unwrap();
    assert_eq!(last["error"], "truncated line at end of input");
    assert!(child.wait().unwrap().success());
    reader.join().unwrap();
}

/// Ctrl-C while the decode waits on a quiet pipe ends it at once as interrupted (130 and the
/// line saying so); the blocked read used to hold it until the signal's grace period ended the
/// process without a word.
#[test]
fn decode_waiting_on_a_quiet_pipe_ends_on_ctrl_c() {
    let mut child = common::Child(
        ima()
            .args(["decode", "p2os"])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    // Held open, and never written.
    let _stdin = child.0.stdin.take().unwrap();
    child.wait_until_it_catches(2);
    child.signal("INT");
    let out = child.wait_output();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(130), "{err}");
    // The 3 s grace period would end the process without this line.
    assert!(err.contains("interrupted by SIGINT"), "{err}");
}

/// A serial port given as FILE (a tap on a robot's line) is read raw at `--baud`: P2OS
/// commands holding bytes a terminal's line discipline changes or holds (CR, ^S, ^C, and no
/// newline) come out whole while the port is open, from a port left in canonical mode, and a
/// hang-up is said as such after what was left. Without `--baud` the decode says what it
/// needs; with it, a plain file is refused, and so is a port another process has open.
#[test]
fn decode_reads_a_serial_port_raw_at_its_baud() {
    // Closed on exec: the programs run here do not keep the master open, so closing it hangs
    // the line up.
    let (mut master, slave) = ima_mock_devices::pty::pty_pair().unwrap();
    let path = serialport::SerialPort::name(&slave).unwrap();
    // A port any process has open is refused, so the pair's own slave is closed.
    drop(slave);
    // Refused: stderr (a broken refusal would read the port for ever: bounded).
    let refused = |args: &[&str]| {
        let child = ima()
            .arg("decode")
            .args(args)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let out = common::Child(child).output_within(20);
        assert!(!out.status.success());
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    // A port another program has open (here as a driver holds it): named.
    let mut held = serialport::new(&path, 9600).open_native().unwrap();
    let err = refused(&["p2os", &path, "--baud", "9600"]);
    let me = format!("process {} (", std::process::id());
    assert!(
        err.contains(&me) && err.contains("has this port open"),
        "{err}"
    );
    held.set_exclusive(false).unwrap();
    drop(held);
    // `stty` reads and sets the port's modes (the workspace has no unsafe code for termios).
    let stty = |args: &[&str]| {
        let out = Command::new("stty")
            .arg("-F")
            .arg(&path)
            .args(args)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8(out.stdout).unwrap()
    };
    let canonical = || stty(&["-a"]).split_whitespace().any(|w| w == "icanon");
    // A terminal's defaults: lines held until a newline, CR read as LF, ^C and ^S taken.
    stty(&["icanon", "isig", "icrnl", "ixon"]);
    assert!(canonical());
    let err = refused(&["p2os", &path]);
    assert!(err.contains("give its line speed with --baud"), "{err}");
    let err = refused(&["p2os", "Cargo.toml", "--baud", "9600"]);
    assert!(err.contains("--baud is for a serial port"), "{err}");
    assert!(canonical(), "the refusals changed the port");

    let mut child = common::Child(
        ima()
            .args(["decode", "p2os", "--from", "host", &path, "--baud", "9600"])
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let (rx, _reader) = common::line_channel(child.0.stdout.take().unwrap());
    // Written once the decode has the port raw (before, the line discipline takes them).
    let waited = std::time::Instant::now();
    while canonical() {
        if waited.elapsed().as_secs() > 20 {
            child.signal("KILL");
            let out = child.wait_output();
            panic!(
                "the decode never set the port raw: {}",
                String::from_utf8_lossy(&out.stderr)
            );
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    // VEL 13, 19 and 3 mm/s: arguments CR, ^S and ^C.
    master
        .write_all(&[
            0xFA, 0xFB, 0x06, 0x0B, 0x3B, 0x0D, 0x00, 0x18, 0x3B, 0xFA, 0xFB, 0x06, 0x0B, 0x3B,
            0x13, 0x00, 0x1E, 0x3B, 0xFA, 0xFB, 0x06, 0x0B, 0x3B, 0x03, 0x00, 0x0E, 0x3B,
        ])
        .unwrap();
    let mut speeds = Vec::new();
    for _ in 0..3 {
        let line = rx
            .recv_timeout(std::time::Duration::from_secs(10))
            .expect("no frame while the port is open");
        let v: serde_json::Value = serde_json::from_str(&line).unwrap();
        assert_eq!(v["kind"], "vel", "{v}");
        speeds.push(v["v_m_s"].as_f64().unwrap());
    }
    assert_eq!(speeds, [0.013, 0.019, 0.003]);
    // Half a frame, and the line hangs up (an adapter unplugged): the rest is reported, then
    // the hang-up.
    // A hang-up throws away what the port holds unread: closed once the decode has read them
    // (its `rchar` grew by the 4 bytes).
    let rchar = || {
        let io = std::fs::read_to_string(format!("/proc/{}/io", child.0.id())).unwrap();
        io.lines()
            .find_map(|l| l.strip_prefix("rchar: "))
            .and_then(|n| n.trim().parse::<u64>().ok())
            .unwrap()
    };
    let before = rchar();
    master.write_all(&[0xFA, 0xFB, 0x06, 0x0B]).unwrap();
    let waited = std::time::Instant::now();
    while rchar() < before + 4 {
        assert!(
            waited.elapsed().as_secs() < 20,
            "the decode never read them"
        );
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    drop(master);
    let out = child.output_within(20);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("the port went away (unplugged?)"), "{err}");
    let last = rx
        .recv_timeout(std::time::Duration::from_secs(10))
        .expect("no line for the truncated frame");
    let last: serde_json::Value = serde_json::from_str(&last).unwrap();
    assert_eq!(last["error"], "truncated frame at end of input", "{last}");
}

#[test]
fn decode_reads_hex_from_stdin_and_reports_bad_frames() {
    let mut child = ima()
        .args(["decode", "p2os", "--from", "host", "--hex"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    child
        .stdin
        .take()
        .unwrap()
        .write_all(b"FA FB 06 0B 3B C8 00 D3 3B\nFA FB 06 0B 3B C8 00 D3 3C FA FB 03 1D 00 1D\n")
        .unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success());
    let v: Vec<serde_json::Value> = String::from_utf8(out.stdout)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let kinds: Vec<&str> = v.iter().map(|x| x["kind"].as_str().unwrap()).collect();
    assert_eq!(kinds, ["vel", "error", "stop"]);
    assert_eq!(v[0]["v_m_s"], 0.2);
    assert_eq!(v[1]["offset"], 9);
    assert_eq!(v[2]["offset"], 18);
}

/// Bytes of another protocol (or direction) give no frame: the output is empty, so stderr
/// says what likely happened instead of leaving the user with nothing; an MCAP recording is
/// named as one.
#[test]
fn decode_says_so_when_no_frame_was_found() {
    let decode = |args: &[&str], input: &[u8]| {
        let mut child = ima()
            .arg("decode")
            .args(args)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        child.stdin.take().unwrap().write_all(input).unwrap();
        child.wait_with_output().unwrap()
    };
    // NMEA text is no P2OS stream.
    let out = decode(&["p2os"], b"$HCHDG,101.1,,,7.1,W*3C\r\n");
    assert!(out.status.success());
    assert!(out.stdout.is_empty());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("no p2os frame in 25 bytes") && err.contains("`--from host`"),
        "{err}"
    );
    // An MCAP recording given as a capture (`--mcap` forgotten) is refused, pointing at
    // `--mcap` (SICK decoded one into 56,812 lines of noise, with success).
    let mcap = b"\x89MCAP0\r\n\x01\x02\x00\x00\x00\x00\x00\x00\x00ros1";
    let out = decode(&["sick-lms"], mcap);
    assert_eq!(out.status.code(), Some(1), "{out:?}");
    assert!(out.stdout.is_empty(), "{out:?}");
    assert!(
        String::from_utf8_lossy(&out.stderr).contains(
            "stdin is an MCAP recording, not a capture of a port's bytes: decode one of its \
             ports with `ima decode --mcap FILE.mcap --port PORT`"
        ),
        "{out:?}"
    );
    // A frame is not reported; no input at all is, as such (it gave no output at all).
    let out = decode(&["p2os", "--from", "host", "--hex"], b"FA FB 03 1D 00 1D");
    assert!(out.status.success() && out.stderr.is_empty(), "{out:?}");
    let out = decode(&["p2os"], b"");
    assert!(out.status.success() && out.stdout.is_empty(), "{out:?}");
    assert_eq!(
        String::from_utf8_lossy(&out.stderr),
        "ima decode: stdin is empty: no bytes to decode\n"
    );
    // Flags that would be ignored are refused: `--port` without `--mcap` (beside a FILE,
    // clap lets it through), `--robot` for bytes that are not P2OS.
    let out = decode(&["p2os", "--port", "skeeter/base", "-"], b"");
    assert_eq!(out.status.code(), Some(1), "{out:?}");
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("give the recording with --mcap"),
        "{out:?}"
    );
    let out = decode(&["rflex", "--robot", "p2dx"], b"");
    assert!(
        String::from_utf8_lossy(&out.stderr)
            .contains("--robot p2dx picks a P2OS robot's units; rflex bytes"),
        "{out:?}"
    );
    // `-` is stdin (it was taken for a file named `-`: "reading -: No such file").
    let out = decode(
        &["p2os", "--from", "host", "--hex", "-"],
        b"FA FB 03 1D 00 1D",
    );
    assert!(out.status.success() && out.stderr.is_empty(), "{out:?}");
    assert!(
        String::from_utf8_lossy(&out.stdout).contains("\"kind\""),
        "{out:?}"
    );
}

#[test]
fn demo_drives_a_square_with_odometry_matching_ground_truth() {
    let out = run_ok(ima().args(["demo", "square", "--side", "0.4", "--json"]));
    let v: Vec<serde_json::Value> = String::from_utf8(out.stdout)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let corners: Vec<_> = v.iter().filter(|x| x["kind"] == "corner").collect();
    assert_eq!(corners.len(), 4);
    // Back near the start after four sides.
    let last = corners[3];
    assert!(
        last["truth"]["x_m"].as_f64().unwrap().abs() < 0.05,
        "{last}"
    );
    assert!(
        last["truth"]["y_m"].as_f64().unwrap().abs() < 0.05,
        "{last}"
    );
    let summary = v.iter().find(|x| x["kind"] == "summary").unwrap();
    assert!(
        summary["max_position_error_m"].as_f64().unwrap() < 0.02,
        "{summary}"
    );
    assert!(
        summary["max_heading_error_deg"].as_f64().unwrap() < 1.0,
        "{summary}"
    );
}

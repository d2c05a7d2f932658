//! The `ima` program with the SICK LMS: `mock sick-lms` and `scan` as separate processes over
//! a pty, and `decode sick-lms`.

use std::io::Write;
use std::process::Stdio;

mod common;
use common::ima;

fn spawn_mock(extra: &[&str]) -> (common::Child, String) {
    let mut args = vec!["sick-lms", "--seed", "3"];
    args.extend_from_slice(extra);
    common::spawn_mock(&args)
}

#[test]
fn mock_and_scan_talk_over_a_pty_in_separate_processes() {
    let (_mock, path) = spawn_mock(&[]);
    let svg = std::env::temp_dir().join(format!("ima-scan-{}.svg", std::process::id()));
    let out = ima()
        .args([
            "scan", "--port", &path, "--baud", "500000", "--count", "20", "--svg",
        ])
        .arg(&svg)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        stdout.contains("connected: LMS200;30106 at 500000 baud, 180°/0.5°, up to 37.5 scans/s"),
        "{stdout}"
    );
    let scans: Vec<&str> = stdout.lines().filter(|l| l.starts_with("scan ")).collect();
    assert_eq!(scans.len(), 20, "{stdout}");
    assert!(scans.iter().all(|l| l.contains("361 beams")), "{stdout}");
    assert!(
        stdout.contains("20 scans delivered, 0 bad CRCs"),
        "{stdout}"
    );
    let pic = std::fs::read_to_string(&svg).unwrap();
    let _ = std::fs::remove_file(&svg);
    let found = ima_plot::inspect(&pic).unwrap();
    assert!(
        found.any_text_contains("Laser scan: 361 beams over ±90°"),
        "{:?}",
        found.texts
    );
    // Scooter sits inside the 10 m arena: most beams hit something (one dot each).
    assert!(pic.matches(r##"r="2" opacity="1" fill="#CC2222""##).count() > 100);
}

#[test]
fn scan_at_38400_from_a_unit_that_powers_up_at_19200() {
    let (_mock, path) = spawn_mock(&["--baud", "19200"]);
    let out = ima()
        .args(["scan", "--port", &path, "--count", "3"])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("at 38400 baud"), "{stdout}");
    assert!(stdout.contains("up to 5.2 scans/s"), "{stdout}");
}

#[test]
fn decode_sick_lms_hex_from_stdin() {
    let mut child = ima()
        .args(["decode", "sick-lms", "--hex"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    // ACK, a 3-value B0 (spec §1.1), a damaged copy, the reset reply.
    child
        .stdin
        .take()
        .unwrap()
        .write_all(
            b"06 02 80 0A 00 B0 03 40 E8 03 D0 07 FF 1F 10 16 B1 \
              02 80 0A 00 B0 03 40 E8 03 D0 07 FF 1F 10 16 B2 \
              02 80 02 00 91 10 79 30",
        )
        .unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success());
    let lines: Vec<serde_json::Value> = String::from_utf8(out.stdout)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(lines[0]["kind"], "ack");
    assert_eq!(lines[1]["kind"], "scan");
    assert_eq!(lines[1]["ranges_m"][0].as_f64().unwrap(), 1.0);
    assert!(lines[1]["ranges_m"][2].is_null());
    assert_eq!(lines[2]["kind"], "error");
    assert_eq!(lines[2]["offset"], 17);
    assert_eq!(lines.last().unwrap()["kind"], "reset_ack");
    assert_eq!(lines.last().unwrap()["offset"], 33);
    // No bad frame is ever decoded as a scan.
    assert_eq!(lines.iter().filter(|l| l["kind"] == "scan").count(), 1);
}

#[test]
fn decode_sick_lms_host_commands() {
    let mut child = ima()
        .args(["decode", "sick-lms", "--hex", "--from", "host"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    child
        .stdin
        .take()
        .unwrap()
        .write_all(b"02 00 02 00 20 48 58 08 02 00 0A 00 20 00 53 49 43 4B 5F 4C 4D 53 BE C5")
        .unwrap();
    let out = child.wait_with_output().unwrap();
    let lines: Vec<serde_json::Value> = String::from_utf8(out.stdout)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(lines.len(), 2);
    assert_eq!(lines[0]["baud"], 500000);
    assert_eq!(lines[1]["password"], "SICK_LMS");
}

#[test]
fn a_scan_at_500k_leaves_the_unit_where_the_next_scan_finds_it() {
    let (_mock, path) = spawn_mock(&[]);
    let out =
        common::run_ok(ima().args(["scan", "--port", &path, "--baud", "500000", "--count", "1"]));
    assert!(String::from_utf8_lossy(&out.stdout).contains("at 500000 baud"));
    let out = common::run_ok(ima().args(["scan", "--port", &path, "--count", "1"]));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("at 38400 baud"), "{stdout}");
    assert!(stdout.contains("1 scans delivered"), "{stdout}");
    // And that one put it back at 9600 too: the first rate probed answers.
    assert_answers_at_9600_first(&path);
}

/// A scan at 9600 finds the unit at the first rate it tries (it was left at 9600).
fn assert_answers_at_9600_first(path: &str) {
    let out = common::run_ok(ima().args([
        "scan",
        "--port",
        path,
        "--baud",
        "9600",
        "--count",
        "1",
        "--log",
        "ima::connect=info",
    ]));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("SICK LMS: answered at 9600 baud"),
        "{stderr}"
    );
    for b in [38400, 19200, 500000] {
        assert!(!stderr.contains(&format!("trying {b} baud")), "{stderr}");
    }
}

#[test]
fn a_scan_ended_by_a_signal_puts_the_unit_back_at_9600() {
    use std::io::BufRead;
    let (_mock, path) = spawn_mock(&[]);
    let mut scan = common::Child(
        ima()
            .args(["scan", "--port", &path, "--baud", "500000"])
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    let mut lines = std::io::BufReader::new(scan.0.stdout.take().unwrap()).lines();
    // Wait until it streams at 500000.
    let first = lines.next().unwrap().unwrap();
    assert!(first.contains("at 500000 baud"), "{first}");
    assert!(lines.next().unwrap().unwrap().starts_with("scan 1 "));
    let pid = scan.0.id().to_string();
    let killed = std::process::Command::new("kill")
        .args(["-TERM", &pid])
        .status()
        .unwrap();
    assert!(killed.success());
    // Drain stdout so the program never blocks on a full pipe, then wait for it.
    for l in lines.by_ref() {
        if l.is_err() {
            break;
        }
    }
    let status = scan.0.wait().unwrap();
    assert!(
        status.code().is_some(),
        "ended by the signal itself: {status:?}"
    );
    assert_answers_at_9600_first(&path);
}

#[test]
fn a_unit_stuck_at_500k_is_found_on_a_line_that_carries_it() {
    // A unit that powers up at 500000 (permanent-baud flag set by another program): a pty
    // carries any rate, so the probe tries 500000 too.
    let (_mock, path) = spawn_mock(&["--baud", "500000"]);
    let out = common::run_ok(ima().args([
        "scan",
        "--port",
        &path,
        "--count",
        "1",
        "--log",
        "ima::connect=info",
    ]));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("at 38400 baud"), "{stdout}");
    let stderr = String::from_utf8_lossy(&out.stderr);
    for b in [9600, 38400, 19200, 500000] {
        assert!(
            stderr.contains(&format!("SICK LMS: trying {b} baud (attempt 1)")),
            "{stderr}"
        );
    }
}

#[test]
fn scan_json_prints_one_object_per_scan_with_every_beam() {
    let (_mock, path) = spawn_mock(&[]);
    let out = common::run_ok(ima().args(["scan", "--port", &path, "--count", "2", "--json"]));
    let lines = common::json_lines(&out.stdout);
    assert_eq!(lines.len(), 2, "stdout is JSON only");
    for (i, l) in lines.iter().enumerate() {
        assert_eq!(l["scan"], i as u64 + 1);
        assert!(l["stamp_s"].as_f64().unwrap() > 0.0);
        let beams = l["beams"].as_array().unwrap();
        assert_eq!(beams.len(), 361);
        assert_eq!(l["beam_count"], 361);
        assert_eq!(l["status"]["error"], false, "{}", l["status"]);
        assert!(l["status"]["byte"].is_u64());
        // 180° at 0.5°: from -π/2 to +π/2, ranges in metres inside the 10 m arena.
        let a0 = beams[0]["angle_rad"].as_f64().unwrap();
        let a1 = beams[360]["angle_rad"].as_f64().unwrap();
        assert!((a0 + std::f64::consts::FRAC_PI_2).abs() < 1e-6, "{a0}");
        assert!((a1 - std::f64::consts::FRAC_PI_2).abs() < 1e-6, "{a1}");
        let valid: Vec<f64> = beams.iter().filter_map(|b| b["range_m"].as_f64()).collect();
        assert_eq!(valid.len() as u64, l["valid"].as_u64().unwrap());
        assert!(valid.len() > 100);
        assert!(valid.iter().all(|r| *r > 0.0 && *r < 15.0));
    }
    assert!(lines[1]["t_s"].as_f64().unwrap() > 0.0);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("connected: LMS200"), "{stderr}");
    assert!(stderr.contains("2 scans delivered"), "{stderr}");
}

/// Ctrl-C ends a scan stream as it ends every command: the unit closed (its summary said),
/// then status 130 (it was 0, so a supervisor could not tell an interruption from an end).
#[test]
fn ctrl_c_ends_a_scan_with_the_units_summary_and_status_130() {
    let (_mock, path) = spawn_mock(&["--baud", "38400"]);
    let mut scan = common::Child(
        ima()
            .args(["scan", "--port", &path, "--baud", "38400"])
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let (lines, reader) = common::line_channel(scan.0.stdout.take().unwrap());
    // Two scans: the stream runs (and the handler is installed).
    let mut scans = 0;
    while scans < 2 {
        let l = lines
            .recv_timeout(std::time::Duration::from_secs(60))
            .expect("a scan line");
        scans += usize::from(l.starts_with("scan "));
    }
    scan.wait_until_it_catches(2);
    scan.signal("INT");
    let status = scan.0.wait().unwrap();
    let _ = reader.join();
    let rest: Vec<String> = lines.try_iter().collect();
    assert_eq!(status.code(), Some(130), "{rest:?}");
    assert!(
        rest.iter().any(|l| l.contains("scans delivered")),
        "the summary after the close: {rest:?}"
    );
}

/// The LMS goes silent for 7 s mid-stream: `ima scan` waits while the driver re-probes, says
/// so, and goes on (it gave up 5 s into a re-probe that would have recovered).
#[test]
fn scan_waits_through_a_silent_spell() {
    let (_mock, path) = spawn_mock(&["--faults", "hangup=4s:7s"]);
    let out = common::run_ok(ima().args(["scan", "--port", &path, "--count", "25", "--json"]));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(common::json_lines(&out.stdout).len(), 25, "{err}");
    assert!(
        err.contains("no scan for 5 s; waiting while the driver re-probes the LMS")
            && err.contains("scans again"),
        "{err}"
    );
}

//! The `ima` program with the rFLEX base: `mock rflex` and `drive --robot atrv-jr` as separate
//! processes over a pty, and `decode rflex`.

use std::io::Write;
use std::process::Stdio;

mod common;
use common::{ima, spawn_mock};

#[test]
fn mock_rflex_and_drive_atrv_jr_talk_over_a_pty_in_separate_processes() {
    let (_mock, path) = spawn_mock(&["rflex", "--seed", "3"]);
    let path = path.as_str();
    let out = ima()
        .args([
            "drive", "--robot", "atrv-jr", "--port", path, "--vel", "0.3", "--turn", "0", "--for",
            "1.5", "--json",
        ])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    let lines: Vec<serde_json::Value> = String::from_utf8(out.stdout)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    // Odometry at 10 Hz for 1.5 s.
    assert!(
        lines.len() >= 10,
        "about one line per report pair: {}",
        lines.len()
    );
    let last = lines.last().unwrap();
    // Scooter starts at 30° in the default world; odometry starts at the origin, heading 0.
    assert!(last["x_m"].as_f64().unwrap() > 0.2, "{last}");
    assert!(
        (last["battery_v"].as_f64().unwrap() - 27.5).abs() < 1e-6,
        "{last}"
    );
    assert!(
        stderr.contains("connected to an rFLEX base at 115200 baud"),
        "{stderr}"
    );
}

#[test]
fn drive_atrv_jr_reports_a_clear_error_when_nothing_answers() {
    let (_master, slave) = ima_mock_devices::pty::pty_pair().unwrap();
    let path = serialport::SerialPort::name(&slave).unwrap();
    let out = ima()
        .args([
            "drive",
            "--robot",
            "atrv-jr",
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
    assert!(err.contains("connecting to an rFLEX base"), "{err}");
}

#[test]
fn decode_rflex_reads_hex_from_stdin_and_reports_bad_frames() {
    let mut child = ima()
        .args(["decode", "rflex", "--hex"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    // T11 sonar report, T12 bumper report with a damaged checksum, T10 status.
    child
        .stdin
        .take()
        .unwrap()
        .write_all(
            b"1B 02 04 08 02 0E 00 00 00 00 00 00 12 37 00 05 C4 10 02 E2 14 1B 03\n\
              1B 02 05 09 01 07 00 00 12 38 40 00 01 62 1B 03\n\
              1B 02 01 07 01 09 00 00 12 36 00 00 0A 46 00 66 1B 03\n",
        )
        .unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success());
    let v: Vec<serde_json::Value> = String::from_utf8(out.stdout)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let kinds: Vec<&str> = v.iter().map(|x| x["kind"].as_str().unwrap()).collect();
    assert_eq!(kinds, ["sonar", "error", "sys_status"]);
    assert_eq!(v[0]["echoes"][0]["range_m"], 1.0);
    assert_eq!(v[0]["echoes"][1]["range_m"], 0.5);
    assert_eq!(v[0]["echoes"][1]["index"], 6);
    assert_eq!(v[1]["offset"], 23);
    assert_eq!(v[2]["offset"], 39);
    assert_eq!(v[2]["brake_engaged"], false);

    // Host direction: T1 brake release.
    let mut child = ima()
        .args(["decode", "rflex", "--from", "host", "--hex"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    child
        .stdin
        .take()
        .unwrap()
        .write_all(b"1B 02 02 00 0C 00 0E 1B 03")
        .unwrap();
    let out = child.wait_with_output().unwrap();
    let s = String::from_utf8(out.stdout).unwrap();
    let v: serde_json::Value = serde_json::from_str(s.lines().next().unwrap()).unwrap();
    assert_eq!(v["kind"], "brake_release");
}

/// A full disk under `--json` (here `/dev/full`) is an error naming what was lost, after
/// the base is shut down: it ended with status 0 and no word.
#[test]
fn a_full_disk_under_the_state_lines_is_an_error() {
    let (_mock, path) = spawn_mock(&["rflex", "--seed", "3"]);
    let out = ima()
        .args(["drive", "--robot", "atrv-jr", "--port", path.as_str()])
        .args(["--vel", "0.2", "--for", "1", "--json"])
        .stdout(std::fs::File::create("/dev/full").unwrap())
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("No space left on device") && stderr.contains("state line(s) not written"),
        "{stderr}"
    );
    // The base was shut down first, as at any end.
    assert!(
        stderr.contains("stopped at") || stderr.contains("still moving"),
        "{stderr}"
    );
}

#[test]
fn drive_atrv_jr_rejects_a_bad_calibration() {
    let out = ima()
        .args([
            "drive",
            "--robot",
            "atrv-jr",
            "--port",
            "/dev/null",
            "--kd",
            "0",
            "--for",
            "0",
        ])
        .output()
        .unwrap();
    // Refused at parse time (exit 2), with the flag named.
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("--kd") && err.contains("not a plausible translation factor"),
        "{err}"
    );
    // One digit too many: it would have sent 3 m/s for a capped 0.3 m/s, and shown 0.1 m/s.
    let out = ima()
        .args(["drive", "--robot", "atrv-jr", "--port", "/dev/null"])
        .args(["--kd", "908100", "--for", "0"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("22702.5–363240"), "{err}");
}

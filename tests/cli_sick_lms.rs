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
    assert!(pic.starts_with("<svg") && pic.trim_end().ends_with("</svg>"));
    // Scooter sits inside the 10 m arena: most beams hit something.
    assert!(pic.matches(r##"fill="#c22""##).count() > 100);
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

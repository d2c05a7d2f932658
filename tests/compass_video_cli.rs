//! The `ima` program for issue 5: `mock compass` and `compass` as separate processes over a
//! pty (both dialects), `camera grab` to PNG, and `decode compass|video-mux|kramer`.

use std::io::Write;
use std::process::Stdio;

mod common;
use common::{ima, json_lines, run_ok, spawn_mock};

#[test]
fn mock_compass_and_compass_talk_over_a_pty_both_dialects() {
    // Scooter starts at yaw 30°, so the compass reads 60° (deviation 4° east corrected).
    for (mock_dialect, drv_dialect, corrected) in [("nmea", "kvh", true), ("tcm2", "tcm2", false)] {
        let (_mock, path) = spawn_mock(&[
            "compass",
            "--dialect",
            mock_dialect,
            "--deviation",
            if corrected { "4" } else { "0" },
            "--seed",
            "5",
        ]);
        let out = run_ok(ima().args([
            "compass",
            "--port",
            &path,
            "--dialect",
            drv_dialect,
            "--count",
            "20",
            "--json",
        ]));
        let lines = json_lines(&out.stdout);
        assert_eq!(lines.len(), 20);
        // The end line says how many were printed, beside the driver's own count.
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            err.contains("20 headings printed; the driver read"),
            "{err}"
        );
        let mean: f64 = lines
            .iter()
            .map(|l| {
                let key = if corrected {
                    "magnetic_rad"
                } else {
                    "heading_rad"
                };
                l[key].as_f64().unwrap().to_degrees()
            })
            .sum::<f64>()
            / 20.0;
        assert!(
            (mean - 60.0).abs() < 0.5,
            "{mock_dialect}: mean heading {mean}"
        );
        if drv_dialect == "tcm2" {
            assert!(lines[0]["pitch_rad"].is_number());
        } else {
            assert!((lines[0]["deviation_rad"].as_f64().unwrap().to_degrees() - 4.0).abs() < 1e-9);
        }
    }
}

/// One reading a second: the configuration waits two periods for the first heading (it gave
/// up after 500 ms, so `--rate 1` always failed, blaming the device). A compass that goes
/// quiet for longer than 3 s is waited for, not given up on.
#[test]
fn a_slow_rate_and_a_silent_spell_are_waited_for() {
    let (_mock, path) = spawn_mock(&["compass", "--seed", "5"]);
    let out = run_ok(ima().args(["compass", "--port", &path, "--rate", "1", "--count", "2"]));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("2 headings printed"), "{err}");
    let (_mock, path) = spawn_mock(&["compass", "--seed", "5", "--faults", "hangup=1s:4s"]);
    let out = run_ok(ima().args(["compass", "--port", &path, "--count", "30", "--json"]));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(json_lines(&out.stdout).len(), 30, "{err}");
    assert!(
        err.contains("no heading for 3 s; waiting for the compass")
            && err.contains("headings again"),
        "{err}"
    );
}

#[test]
fn compass_on_a_switcher_port_fails_cleanly() {
    let (_mock, path) = spawn_mock(&["video-mux"]);
    // A switcher is no compass: configuration must fail, not hang.
    let out = ima()
        .args([
            "compass",
            "--port",
            &path,
            "--dialect",
            "tcm2",
            "--count",
            "1",
        ])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("compass"));
}

#[test]
fn a_wrong_compass_dialect_is_named_and_fails() {
    // (mock dialect, driver dialect, what the error must say)
    for (mock, drv, says) in [
        (
            "nmea",
            "tcm2",
            "the compass answered in NMEA ($HCHDG…), not TCM2",
        ),
        (
            "tcm2",
            "nmea",
            "the compass answered in TCM2 ($C…P…R…), not NMEA",
        ),
        (
            "tcm2",
            "kvh",
            "the compass answered in TCM2 ($C…P…R…), not KVH C100 (NMEA)",
        ),
    ] {
        let (_mock, path) = spawn_mock(&["compass", "--dialect", mock]);
        let out = ima()
            .args([
                "compass",
                "--port",
                &path,
                "--dialect",
                drv,
                "--count",
                "3",
                "--json",
            ])
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{mock} as {drv}: {stderr}");
        assert!(stderr.contains(says), "{mock} as {drv}: {stderr}");
        let hint = if mock == "nmea" {
            "try --dialect nmea"
        } else {
            "try --dialect tcm2"
        };
        assert!(stderr.contains(hint), "{stderr}");
        // The error says it once: no warning of the failed configuration job before it.
        assert!(!stderr.contains("WARN"), "{stderr}");
        // No heading of the wrong dialect was printed as if it were good.
        assert!(
            out.stdout.is_empty(),
            "{}",
            String::from_utf8_lossy(&out.stdout)
        );
    }
}

#[test]
fn camera_grab_writes_a_png_with_the_expected_blob() {
    let dir = std::env::temp_dir().join(format!("ima-camera-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("ch1.png");
    run_ok(
        ima()
            .args(["camera", "grab", "--channel", "1", "--out"])
            .arg(&file),
    );
    let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&file).unwrap()));
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!((info.width, info.height), (320, 240));
    // The red object is dead ahead of Skeeter: a red blob centred on column 160.
    let (mut sum, mut n) = (0usize, 0usize);
    for (i, p) in buf.chunks_exact(3).enumerate() {
        if p[0] > 200 && p[1] < 50 && p[2] < 50 {
            sum += i % 320;
            n += 1;
        }
    }
    assert!(n > 300, "red pixels: {n}");
    let col = sum as f64 / n as f64 + 0.5;
    assert!((col - 160.0).abs() < 1.5, "{col}");
    // Grabbing before the picture settles says so (it said "settled in 300ms").
    let out = run_ok(
        ima()
            .args(["camera", "grab", "--channel", "2", "--no-settle", "--out"])
            .arg(dir.join("early.png")),
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("before the picture settles"), "{err}");
    assert!(!err.contains("settles in"), "{err}");
    let bad = ima()
        .args(["camera", "grab", "--channel", "9", "--out"])
        .arg(dir.join("x.png"))
        .output()
        .unwrap();
    assert!(!bad.status.success());
    std::fs::remove_dir_all(&dir).ok();
}

fn decode(protocol: &str, extra: &[&str], input: &[u8]) -> Vec<serde_json::Value> {
    let mut child = ima()
        .arg("decode")
        .arg(protocol)
        .args(extra)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    child.stdin.take().unwrap().write_all(input).unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success());
    json_lines(&out.stdout)
}

#[test]
fn decode_compass_and_switchers() {
    let v = decode(
        "compass",
        &[],
        b"$HCHDT,238.5,T*25\r\ngarbage\r\n$HCHDG,238.5,,,,*4E\r\n",
    );
    assert_eq!(v.len(), 3);
    assert_eq!(v[0]["kind"], "hdt");
    assert_eq!(v[0]["reference"], "true");
    assert!((v[0]["heading_rad"].as_f64().unwrap() - 238.5f64.to_radians()).abs() < 1e-12);
    assert_eq!(v[1]["kind"], "error");
    assert_eq!(v[2]["kind"], "hdg");
    assert!(v[2]["deviation"].is_null());
    let v = decode("compass", &["--from", "host"], b"h\rsdo=t\rsp=8\rgo\r");
    assert_eq!(v.len(), 4);
    let v = decode("video-mux", &[], b"In3 All\r\nE13\r\n");
    assert_eq!(v[0]["input"], 3);
    assert_eq!(v[1]["code"], 13);
    let v = decode("video-mux", &["--from", "host"], b"3!");
    assert_eq!(v[0]["kind"], "select");
    // The answers to the information requests, and the requests themselves.
    let v = decode("video-mux", &[], b"V3 A3 F1 Vmt0 Amt0\r\n1.00\r\nVrb3\r\n");
    assert_eq!(
        (&v[0]["kind"], &v[0]["video"], &v[0]["mode"]),
        (
            &serde_json::json!("information"),
            &serde_json::json!(3),
            &serde_json::json!(1)
        )
    );
    assert_eq!(
        (&v[1]["kind"], &v[1]["version"]),
        (&serde_json::json!("firmware"), &serde_json::json!("1.00"))
    );
    assert_eq!(
        (&v[2]["kind"], &v[2]["mode"]),
        (&serde_json::json!("verbose"), &serde_json::json!(3))
    );
    let v = decode("video-mux", &["--from", "host"], b"IQNB");
    let kinds: Vec<&str> = v.iter().map(|x| x["kind"].as_str().unwrap()).collect();
    assert_eq!(
        kinds,
        [
            "information",
            "firmware_version",
            "part_number",
            "read_video_mute"
        ]
    );
    let v = decode("kramer", &["--hex"], b"01 83 81 81");
    assert_eq!(v[0]["kind"], "switch_video");
    assert_eq!(v[0]["input"], 3);
}

/// SIGTERM ends a live compass as it ends every command: the compass closed (its summary
/// said), then status 143 (it was 0).
#[test]
fn sigterm_ends_the_compass_with_its_summary_and_status_143() {
    let (_mock, path) = spawn_mock(&["compass", "--dialect", "nmea", "--seed", "5"]);
    let mut compass = common::Child(
        ima()
            .args(["compass", "--port", &path, "--dialect", "kvh", "--json"])
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let (lines, _out) = common::line_channel(compass.0.stdout.take().unwrap());
    let (err, err_reader) = common::line_channel(compass.0.stderr.take().unwrap());
    for _ in 0..2 {
        lines
            .recv_timeout(std::time::Duration::from_secs(60))
            .expect("a heading line");
    }
    compass.wait_until_it_catches(15);
    compass.signal("TERM");
    let status = compass.0.wait().unwrap();
    let _ = err_reader.join();
    let said: Vec<String> = err.try_iter().collect();
    assert_eq!(status.code(), Some(143), "{said:?}");
    assert!(
        said.iter().any(|l| l.contains("headings printed")),
        "{said:?}"
    );
}

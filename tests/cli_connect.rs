//! How the commands that open a serial port fail: a path that is no serial port is named as
//! such; a device that never answers, or answers with garbage, is reported with what was seen
//! at each rate tried.

mod common;
use common::ima;

/// Run `ima <args>` expecting failure; returns stderr.
fn fails(args: &[&str]) -> String {
    let out = ima().args(args).output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(!out.status.success(), "{args:?} succeeded: {stderr}");
    stderr
}

#[test]
fn a_path_that_is_not_a_serial_port_is_named() {
    let file = std::env::temp_dir().join(format!("ima-not-a-port-{}", std::process::id()));
    std::fs::write(&file, b"not a tty\n").unwrap();
    let file_s = file.to_string_lossy().into_owned();
    for (path, what) in [
        ("/dev/null", "a device that is not a terminal"),
        (file_s.as_str(), "a regular file"),
    ] {
        for cmd in [
            &["drive", "--port", path][..],
            &["drive", "--robot", "atrv-jr", "--port", path],
            &["scan", "--port", path],
            &["compass", "--port", path],
        ] {
            let err = fails(cmd);
            assert!(
                err.contains(&format!("{path} is not a serial port ({what})")),
                "{cmd:?}: {err}"
            );
            assert!(!err.contains("typewriter"), "{cmd:?}: {err}");
        }
    }
    let _ = std::fs::remove_file(&file);
}

/// A pseudo-terminal nobody answers on (`silent`) or that receives noise: its path, and the
/// master end kept open (and fed with noise) for the test's life.
struct Line {
    path: String,
    _keep: Vec<Box<dyn std::any::Any>>,
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
}

impl Drop for Line {
    fn drop(&mut self) {
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
    }
}

fn line(noise: bool) -> Line {
    use serialport::SerialPort;
    use std::io::Write;
    let (mut master, slave) = serialport::TTYPort::pair().unwrap();
    let path = slave.name().unwrap();
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let mut keep: Vec<Box<dyn std::any::Any>> = vec![Box::new(slave)];
    if noise {
        let stop = stop.clone();
        std::thread::spawn(move || {
            // Bytes that never make a frame of any protocol here (no STX, no FA FB, no `$`,
            // no line end).
            let mut x = 0x5Au8;
            while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                let chunk: Vec<u8> = (0..64)
                    .map(|_| {
                        x = x.wrapping_mul(13).wrapping_add(7);
                        0x40 | (x & 0x3F)
                    })
                    .collect();
                if master.write_all(&chunk).is_err() {
                    break;
                }
                std::thread::sleep(std::time::Duration::from_millis(20));
            }
        });
    } else {
        keep.push(Box::new(master));
    }
    Line {
        path,
        _keep: keep,
        stop,
    }
}

#[test]
fn scan_on_a_silent_line_names_every_rate_tried() {
    let l = line(false);
    let err = fails(&["scan", "--port", &l.path, "--log", "ima::connect=info"]);
    assert!(
        err.contains(
            "no SICK LMS answered (powered? still booting? right port?): silence at every rate tried (9600, 38400, 19200, 500000)"
        ),
        "{err}"
    );
    assert!(
        err.contains("SICK LMS: trying 19200 baud (attempt 2)"),
        "{err}"
    );
    assert!(!err.contains("any rate"), "{err}");
}

#[test]
fn scan_on_a_noisy_line_says_what_it_received() {
    let l = line(true);
    let err = fails(&["scan", "--port", &l.path]);
    assert!(
        err.contains("no SICK LMS answered (powered? still booting? right port?): received "),
        "{err}"
    );
    assert!(err.contains(" bytes at 9600 baud, no valid frame"), "{err}");
}

#[test]
fn drive_on_a_silent_line_names_every_rate_tried() {
    let l = line(false);
    let err = fails(&[
        "drive",
        "--port",
        &l.path,
        "--connect-timeout",
        "4",
        "--log",
        "ima::connect=info",
    ]);
    assert!(
        err.contains("no P2OS robot completed the handshake (robot on? right port?): silence at every rate tried (9600, 19200, 38400, 57600, 115200)"),
        "{err}"
    );
    assert!(err.contains("P2OS: trying 9600 baud (attempt 1)"), "{err}");
    assert!(
        err.contains("P2OS: trying 115200 baud (attempt 1)"),
        "{err}"
    );
}

#[test]
fn drive_on_a_noisy_line_says_what_it_received() {
    let l = line(true);
    let err = fails(&["drive", "--port", &l.path, "--connect-timeout", "2"]);
    assert!(
        err.contains("no P2OS robot completed the handshake (robot on? right port?): received "),
        "{err}"
    );
    assert!(err.contains(" bytes at 9600 baud, no valid frame"), "{err}");
}

#[test]
fn rflex_drive_on_silent_and_noisy_lines_says_what_it_saw() {
    let l = line(false);
    let err = fails(&[
        "drive",
        "--robot",
        "atrv-jr",
        "--port",
        &l.path,
        "--connect-timeout",
        "1",
    ]);
    assert!(
        err.contains("at 115200 baud: no motion report from the rFLEX base: silence on the line"),
        "{err}"
    );
    let l = line(true);
    let err = fails(&[
        "drive",
        "--robot",
        "atrv-jr",
        "--port",
        &l.path,
        "--connect-timeout",
        "1",
    ]);
    assert!(
        err.contains("no motion report from the rFLEX base: received "),
        "{err}"
    );
    assert!(err.contains("bytes, no valid frame"), "{err}");
}

#[test]
fn compass_on_silent_and_noisy_lines_says_what_it_saw() {
    let l = line(false);
    let err = fails(&["compass", "--port", &l.path, "--log", "ima::connect=info"]);
    assert!(
        err.contains("compass: configuring a KVH C100 (NMEA) at 4800 baud"),
        "{err}"
    );
    assert!(
        err.contains("the compass did not answer its configuration (step 0): silence on the line"),
        "{err}"
    );
    // An NMEA source is asked nothing: the error says no heading came, not which step of a
    // configuration went unanswered.
    let err = fails(&[
        "compass",
        "--port",
        &l.path,
        "--dialect",
        "nmea",
        "--log",
        "ima::connect=info",
    ]);
    assert!(
        err.contains("compass: listening to an NMEA source at 4800 baud"),
        "{err}"
    );
    assert!(
        err.contains("listening to the compass on ")
            && err.contains("no heading came from the compass: silence on the line"),
        "{err}"
    );
    assert!(!err.contains("configuration"), "{err}");
    let l = line(true);
    let err = fails(&["compass", "--port", &l.path, "--dialect", "tcm2"]);
    assert!(
        err.contains("the compass did not answer its configuration (step 3): received "),
        "{err}"
    );
    assert!(err.contains("bytes, no valid line"), "{err}");
}

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

//! Helpers shared by the tests that run the `ima` program.
#![allow(dead_code)] // each test binary uses a different subset

pub mod mission;

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};

/// The `ima` binary under test.
pub fn ima() -> Command {
    Command::new(env!("CARGO_BIN_EXE_ima"))
}

/// Run `cmd` to the end and return its output; fails the test, showing stderr, when the
/// command does not succeed.
pub fn run_ok(cmd: &mut Command) -> std::process::Output {
    let out = cmd.output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// Kills the child when dropped, so a failing test leaves no process behind.
pub struct Child(pub std::process::Child);

impl Drop for Child {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Start `ima mock <args…>` and read the pty path it prints on its first line.
pub fn spawn_mock(args: &[&str]) -> (Child, String) {
    let mut mock = Child(
        ima()
            .arg("mock")
            .args(args)
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    let mut path = String::new();
    BufReader::new(mock.0.stdout.take().unwrap())
        .read_line(&mut path)
        .unwrap();
    let path = path.trim().to_owned();
    assert!(
        path.starts_with("/dev/"),
        "first line is the pty path: {path:?}"
    );
    (mock, path)
}

/// Parse JSON Lines output.
pub fn json_lines(out: &[u8]) -> Vec<serde_json::Value> {
    String::from_utf8_lossy(out)
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}
pub mod conformance;

//! Helpers shared by the tests that run the `ima` program.
#![allow(dead_code)] // each test binary uses a different subset

pub mod mission;

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};

/// The SICK LMS driver connected to the device on pty `path`: opened at 9600 baud (the unit's
/// rate at power-up), run with `cfg`, 60 s to connect, 10 s to wait for a scan.
pub async fn connect_sick(
    path: &std::path::Path,
    cfg: ima_sick_lms::machine::Config,
) -> ima_sick_lms::shell::SickLms {
    let port = ima_sick_lms::shell::open_port(path.to_str().unwrap(), 9600).unwrap();
    ima_sick_lms::shell::SickLms::connect(
        port,
        cfg,
        std::time::Duration::from_secs(60),
        ima_hal::time::TokioClock::shared(),
    )
    .await
    .unwrap()
    .with_scan_timeout(std::time::Duration::from_secs(10))
}

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

impl Child {
    /// Send signal `sig` (`"INT"`, `"TERM"`, …) to the child, which must still be running.
    pub fn signal(&self, sig: &str) {
        let ok = std::process::Command::new("kill")
            .args([format!("-{sig}"), self.0.id().to_string()])
            .status()
            .unwrap();
        assert!(ok.success(), "kill -{sig}");
    }

    /// Wait (at most 10 s) until the child catches signal number `number` (`2`: SIGINT), as
    /// its `/proc/PID/status` says: a signal sent before its handler is installed would kill
    /// it outright. For a child that prints nothing to wait for first.
    pub fn wait_until_it_catches(&self, number: u32) {
        let path = format!("/proc/{}/status", self.0.id());
        let bit = 1u64 << (number - 1);
        let t0 = std::time::Instant::now();
        loop {
            let caught = std::fs::read_to_string(&path).ok().and_then(|s| {
                let hex = s.lines().find_map(|l| l.strip_prefix("SigCgt:"))?;
                u64::from_str_radix(hex.trim(), 16).ok()
            });
            if caught.is_some_and(|c| c & bit != 0) {
                return;
            }
            assert!(
                t0.elapsed() < std::time::Duration::from_secs(10),
                "the child never caught signal {number}"
            );
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
    }

    /// Its output once it has ended, within `secs` seconds (else it is killed and the test
    /// fails): for a command that should end by itself but might wait forever if broken.
    pub fn output_within(mut self, secs: u64) -> std::process::Output {
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(secs);
        while self.0.try_wait().unwrap().is_none() {
            assert!(
                std::time::Instant::now() < deadline,
                "still running after {secs} s"
            );
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
        self.wait_output()
    }

    /// Wait for the child to end, with what it printed on the outputs still piped.
    pub fn wait_output(&mut self) -> std::process::Output {
        std::mem::replace(
            &mut self.0,
            std::process::Command::new("true").spawn().unwrap(),
        )
        .wait_with_output()
        .unwrap()
    }
}

/// The lines of `out` (a child's stdout) as they come, sent on a channel by a thread of their
/// own (which ends with `out` or once the receiver is dropped), so that a test can wait for
/// each with a timeout.
pub fn line_channel(
    out: impl std::io::Read + Send + 'static,
) -> (
    std::sync::mpsc::Receiver<String>,
    std::thread::JoinHandle<()>,
) {
    let (tx, rx) = std::sync::mpsc::channel();
    let reader = std::thread::spawn(move || {
        for l in BufReader::new(out).lines() {
            if tx.send(l.unwrap()).is_err() {
                break;
            }
        }
    });
    (rx, reader)
}

/// Start `ima <args…>` (its stderr discarded) and read the first line it prints.
pub fn spawn_first_line<S: AsRef<std::ffi::OsStr>>(
    args: impl IntoIterator<Item = S>,
) -> (Child, String) {
    let mut child = Child(
        ima()
            .args(args)
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    let mut line = String::new();
    BufReader::new(child.0.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    (child, line)
}

/// Start `ima mock <args…>` and read the pty path it prints on its first line.
pub fn spawn_mock(args: &[&str]) -> (Child, String) {
    let (mock, path) = spawn_first_line(std::iter::once("mock").chain(args.iter().copied()));
    let path = path.trim().to_owned();
    assert!(
        path.starts_with("/dev/"),
        "first line is the pty path: {path:?}"
    );
    (mock, path)
}

/// A scratch directory for one test: `<temp>/ima-<name>-<pid>`, emptied when made and
/// removed when dropped, except after a failure (a panicking test), when it is kept and its
/// path printed so the files can be looked at.
#[derive(Debug)]
pub struct Scratch(std::path::PathBuf);

impl Scratch {
    /// Make (or empty) the directory.
    pub fn new(name: &str) -> Self {
        let d = std::env::temp_dir().join(format!("ima-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        Self(d)
    }

    /// The directory.
    pub fn path(&self) -> &std::path::Path {
        &self.0
    }
}

impl std::ops::Deref for Scratch {
    type Target = std::path::Path;

    fn deref(&self) -> &std::path::Path {
        &self.0
    }
}

impl AsRef<std::path::Path> for Scratch {
    fn as_ref(&self) -> &std::path::Path {
        &self.0
    }
}

impl AsRef<std::ffi::OsStr> for Scratch {
    fn as_ref(&self) -> &std::ffi::OsStr {
        self.0.as_os_str()
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        if std::thread::panicking() {
            eprintln!("test files kept in {}", self.0.display());
        } else {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
}

/// Parse JSON Lines output.
pub fn json_lines(out: &[u8]) -> Vec<serde_json::Value> {
    String::from_utf8_lossy(out)
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

/// A short mission demo: JSON lines, world ×10, the red target only.
pub const SHORT_DEMO: [&str; 6] = ["demo", "--json", "--speed", "10", "--targets", "red"];

/// The `summary` line of `ima demo --json`'s output; fails the test, showing stderr, when
/// there is none.
pub fn demo_summary(out: &std::process::Output) -> serde_json::Value {
    json_lines(&out.stdout)
        .into_iter()
        .find(|l| l["kind"] == "summary")
        .unwrap_or_else(|| panic!("no summary: {}", String::from_utf8_lossy(&out.stderr)))
}
pub mod conformance;

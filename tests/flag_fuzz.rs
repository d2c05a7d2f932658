//! Every numeric flag of every sub-command (the list in `tests/data/numeric-flags.txt`, which a
//! unit test in `src/main.rs` keeps equal to the program's real flags) is given NaN, ±inf,
//! 1e30, −1 and 0 in a real process: none may panic (exit 101) or abort (134, SIGABRT). A run
//! still going after a few seconds (a server, a demo that accepted a value) is stopped and counts
//! as no panic; the parse-level unit test has already proven that the nonsense values are refused
//! with a message naming the flag.

use std::collections::HashMap;
use std::io::Read as _;
use std::process::Stdio;
use std::time::{Duration, Instant};

mod common;
use common::ima;

const LIST: &str = include_str!("data/numeric-flags.txt");
const VALUES: [&str; 6] = ["NaN", "inf", "-inf", "1e30", "-1", "0"];
const RUN_LIMIT: Duration = Duration::from_secs(4);

/// Arguments that make each sub-command runnable (or fail fast) apart from the flag under test.
fn base_args(path: &str, out_dir: &str) -> Vec<(String, Option<String>)> {
    let f = |flag: &str, v: &str| (flag.to_owned(), Some(v.to_owned()));
    let pos = |v: &str| (v.to_owned(), None);
    match path {
        "demo" | "demo square" | "peer manager" | "peer listen" | "experiment heading" => vec![],
        "mock" => vec![pos("p2os")],
        "drive" | "compass" | "scan" => vec![f("--port", "/dev/null")],
        "camera grab" => vec![f("--channel", "1"), f("--out", out_dir)],
        "commander" => vec![f("--config", "/nonexistent/commander.toml")],
        "peer client" => vec![f("--connect", "127.0.0.1:9"), f("--request", "ses")],
        "peer send" => vec![pos("stop")],
        "san simulate" => vec![pos("/nonexistent/net.toml")],
        "replay" => vec![pos("/nonexistent/recording.mcap")],
        // Not a serial port: refused once the flag is read.
        "decode" => vec![pos("p2os"), pos("/dev/null")],
        other => panic!("no base arguments for `ima {other}`: add them to tests/flag_fuzz.rs"),
    }
}

struct Case {
    argv: Vec<String>,
}

fn cases(out_dir: &str) -> Vec<Case> {
    let mut cases = Vec::new();
    for line in LIST
        .lines()
        .filter(|l| !l.trim().is_empty() && !l.starts_with('#'))
    {
        let (path, flag) = line.rsplit_once(' ').expect("`path --flag` lines");
        let base = base_args(path, out_dir);
        for v in VALUES {
            let mut argv: Vec<String> = path.split(' ').map(str::to_owned).collect();
            for (k, val) in &base {
                if k == flag {
                    continue;
                }
                argv.push(k.clone());
                if let Some(val) = val {
                    argv.push(val.clone());
                }
            }
            argv.push(format!("{flag}={v}"));
            cases.push(Case { argv });
        }
    }
    cases
}

/// Run one case; returns a description of the failure, if any.
fn run(case: &Case) -> Option<String> {
    let mut child = ima()
        .args(&case.argv)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .env("IMA_LOG", "off")
        .spawn()
        .unwrap();
    let mut err = child.stderr.take().unwrap();
    let reader = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = err.read_to_string(&mut s);
        s
    });
    let end = Instant::now() + RUN_LIMIT;
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break Some(s);
        }
        if Instant::now() >= end {
            // Still running without a panic: a server or a long job that accepted the value.
            let _ = child.kill();
            let _ = child.wait();
            break None;
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let stderr = reader.join().unwrap_or_default();
    let panicked = stderr.contains("panicked") || stderr.contains("RUST_BACKTRACE");
    let bad_code = status.is_some_and(|s| {
        use std::os::unix::process::ExitStatusExt;
        matches!(s.code(), Some(101 | 134)) || s.signal() == Some(6)
    });
    (panicked || bad_code).then(|| format!("ima {}: {status:?}\n{stderr}", case.argv.join(" ")))
}

#[test]
fn no_numeric_flag_value_panics_or_aborts() {
    let out_dir = std::env::temp_dir().join(format!("ima-flag-fuzz-{}", std::process::id()));
    std::fs::create_dir_all(&out_dir).unwrap();
    let cases = cases(out_dir.to_str().unwrap());
    assert!(
        cases.len() >= 6 * 40,
        "the flag list was read: {}",
        cases.len()
    );
    let failures = std::sync::Mutex::new(Vec::new());
    let next = std::sync::atomic::AtomicUsize::new(0);
    std::thread::scope(|s| {
        for _ in 0..6 {
            s.spawn(|| {
                loop {
                    let i = next.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
                    let Some(case) = cases.get(i) else { break };
                    if let Some(f) = run(case) {
                        failures.lock().unwrap().push(f);
                    }
                }
            });
        }
    });
    let _ = std::fs::remove_dir_all(&out_dir);
    let failures = failures.into_inner().unwrap();
    assert!(
        failures.is_empty(),
        "{} of {} runs panicked or aborted:\n{}",
        failures.len(),
        cases.len(),
        failures.join("\n")
    );
    // Every listed sub-command had base arguments (no panic above), and each value was tried.
    let per_path: HashMap<String, usize> = cases.iter().fold(HashMap::new(), |mut m, c| {
        *m.entry(c.argv[0].clone()).or_default() += 1;
        m
    });
    assert!(per_path.len() >= 8, "{per_path:?}");
}

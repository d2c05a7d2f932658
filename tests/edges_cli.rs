//! Issue 13: honest edges of the `ima` program — output paths checked before the work,
//! configurations never silently replaced, one meaning and unit per flag, log filters and
//! colours refused with a message that helps, and error chains without repeats.

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::Stdio;

mod common;
use common::{Child, ima, json_lines, run_ok};

/// A fresh scratch directory for one test.
fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("ima-edges-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn stderr(out: &std::process::Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

// Item 1: output paths are checked before the work.

#[test]
fn demo_refuses_an_svg_in_a_missing_directory_before_the_mission() {
    let d = scratch("demo-svg");
    let svg = d.join("no-such-dir/x.svg");
    let out = ima().args(["demo", "--svg"]).arg(&svg).output().unwrap();
    assert!(!out.status.success());
    let err = stderr(&out);
    assert!(
        err.contains("--svg") && err.contains(&svg.display().to_string()),
        "{err}"
    );
    // Nothing was served or run: no world line, no summary.
    assert!(!err.contains("world ×"), "{err}");
    assert!(
        out.stdout.is_empty(),
        "{}",
        String::from_utf8_lossy(&out.stdout)
    );
    let _ = std::fs::remove_dir_all(&d);
}

/// `ima scan --svg` checked its path only after the laser's start-up and the scan.
#[test]
fn scan_refuses_an_svg_in_a_missing_directory_before_opening_the_laser() {
    let d = scratch("scan-svg");
    let svg = d.join("no-such-dir/x.svg");
    let out = ima()
        .args(["scan", "--port", "/dev/ima-no-such-port", "--svg"])
        .arg(&svg)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = stderr(&out);
    assert!(
        err.contains("--svg") && err.contains(&svg.display().to_string()),
        "{err}"
    );
    assert!(
        !err.contains("ima-no-such-port"),
        "the port came first: {err}"
    );
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn demo_prints_its_summary_even_when_the_svg_cannot_be_written() {
    // `/dev/full` passes the check (it opens for writing) but every write fails.
    let out = ima()
        .args(common::SHORT_DEMO)
        .args(["--svg", "/dev/full"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = stderr(&out);
    assert!(err.contains("--svg /dev/full"), "{err}");
    let summary = common::demo_summary(&out);
    assert_eq!(summary["targets"][0]["target"], "red", "{summary}");
}

#[test]
fn experiment_refuses_an_unusable_out_before_the_sweep() {
    let d = scratch("exp-out");
    let file = d.join("a-file");
    std::fs::write(&file, "").unwrap();
    let out = ima()
        .args(["experiment", "heading", "--rule", "thesis", "--out"])
        .arg(&file)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = stderr(&out);
    assert!(
        err.contains("--out") && err.contains("not a directory"),
        "{err}"
    );
    assert!(!err.contains("runs in"), "the sweep ran first: {err}");
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn experiment_prints_its_results_even_when_a_file_cannot_be_written() {
    let d = scratch("exp-late");
    // The directory is fine, but `heading.csv` cannot be created (a directory is in the way).
    std::fs::create_dir_all(d.join("heading.csv")).unwrap();
    let out = ima()
        .args([
            "experiment",
            "heading",
            "--rule",
            "thesis",
            "--json",
            "--out",
        ])
        .arg(&d)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = stderr(&out);
    assert!(
        err.contains("heading.csv") && err.contains("--out"),
        "{err}"
    );
    // The results came first.
    let doc: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(doc.to_string().contains("thesis"), "{doc}");
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn camera_grab_refuses_a_missing_directory_before_grabbing() {
    let d = scratch("grab");
    let png = d.join("missing/cam.png");
    let out = ima()
        .args(["camera", "grab", "--channel", "1", "--out"])
        .arg(&png)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = stderr(&out);
    assert!(err.contains(&format!("--out {}", png.display())), "{err}");
    assert!(!err.contains("switcher confirmed"), "grabbed first: {err}");
    let _ = std::fs::remove_dir_all(&d);
}

// Item 2: `ima mock world --write-configs` does not replace a group key silently.

/// Start `ima mock world --write-configs dir [extra]`; its first stdout line, or `None`
/// when it exited without one.
fn mock_world(dir: &std::path::Path, extra: &[&str]) -> (Child, Option<String>) {
    let mut child = Child(
        ima()
            .args(["mock", "world", "--write-configs"])
            .arg(dir)
            .args(extra)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let mut line = String::new();
    let n = BufReader::new(child.0.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    (child, (n > 0).then_some(line))
}

#[test]
fn mock_world_keeps_existing_configs_unless_forced() {
    let d = scratch("configs");
    std::fs::write(d.join("group.key"), "old key").unwrap();
    std::fs::write(d.join("scooter.toml"), "# mine").unwrap();
    let (mut child, line) = mock_world(&d, &[]);
    assert!(line.is_none(), "served anyway: {line:?}");
    let status = child.0.wait().unwrap();
    assert!(!status.success());
    let mut err = String::new();
    std::io::Read::read_to_string(&mut child.0.stderr.take().unwrap(), &mut err).unwrap();
    assert!(
        err.contains("group.key") && err.contains("scooter.toml") && err.contains("--force"),
        "{err}"
    );
    assert_eq!(
        std::fs::read_to_string(d.join("group.key")).unwrap(),
        "old key"
    );
    drop(child);

    let (_child, line) = mock_world(&d, &["--force"]);
    let line = line.expect("the world's endpoints line");
    assert!(line.contains("\"kind\":\"world\""), "{line}");
    assert_ne!(
        std::fs::read_to_string(d.join("group.key")).unwrap(),
        "old key"
    );
    assert!(d.join("commander.toml").exists());
    let _ = std::fs::remove_dir_all(&d);
}

// Item 4: one meaning and one unit family per flag name; negative values where they mean
// something.

#[test]
fn demo_square_takes_vel_not_speed() {
    let out = run_ok(ima().args(["demo", "square", "--side", "0.3", "--vel", "0.4", "--json"]));
    let v = json_lines(&out.stdout);
    assert_eq!(v.iter().filter(|x| x["kind"] == "corner").count(), 4);
    let out = ima()
        .args(["demo", "square", "--speed", "0.4"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(stderr(&out).contains("as --vel (m/s)"), "{}", stderr(&out));
    let out = ima()
        .args(["demo", "square", "--vel", "2"])
        .output()
        .unwrap();
    // Refused at parse time, naming the flag and its range.
    assert_eq!(out.status.code(), Some(2));
    assert!(
        stderr(&out).contains("--vel") && stderr(&out).contains("at most 1 m/s"),
        "{}",
        stderr(&out)
    );
}

#[test]
fn negative_velocities_and_rates_parse() {
    let out = ima()
        .args([
            "drive",
            "--port",
            "/dev/ima-no-such-port",
            "--vel",
            "-0.2",
            "--turn",
            "-0.5",
            "--for",
            "0",
        ])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = stderr(&out);
    // Past the parser: the port is what failed.
    assert!(err.contains("/dev/ima-no-such-port"), "{err}");
    assert_ne!(out.status.code(), Some(2), "{err}");
    // Every numeric flag takes a negative number as its value and says its range (`--for -1`
    // was "unexpected argument '-1' found", where `--for=-1` got the range).
    for (flag, want) in [
        ("--for", "-1 is out of range: 0–86400 s"),
        ("--baud", "-1 is out of range: 50–4000000 baud"),
        ("--connect-timeout", "a timeout must be more than 0 s"),
    ] {
        let out = ima()
            .args(["drive", "--port", "/dev/ima-no-such-port", flag, "-1"])
            .output()
            .unwrap();
        assert_eq!(out.status.code(), Some(2), "{flag}");
        assert!(stderr(&out).contains(want), "{flag}: {}", stderr(&out));
    }
}

#[test]
fn mock_rates_are_rad_s_and_delays_seconds() {
    let out = run_ok(ima().args(["mock", "--help"]));
    let help = String::from_utf8_lossy(&out.stdout);
    let spin = help
        .lines()
        .skip_while(|l| !l.contains("--spin"))
        .take(3)
        .collect::<String>();
    assert!(spin.contains("rad/s"), "{spin}");
    assert!(help.contains("--switch-delay <SWITCH_DELAY>"), "{help}");
    assert!(!help.contains("--switch-delay-ms"), "{help}");
    let out = ima()
        .args(["mock", "video-mux", "--switch-delay", "20"])
        .output()
        .unwrap();
    assert!(stderr(&out).contains("--switch-delay"), "{}", stderr(&out));
}

// Item 5: log filters, colours and error chains.

#[test]
fn an_invalid_log_filter_is_an_error() {
    let out = ima()
        .args(["--log", "ima=loud", "san", "simulate", "/dev/null"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
    let err = stderr(&out);
    assert!(err.contains("ima=loud") && err.contains("--log"), "{err}");
    let out = ima()
        .env("IMA_LOG", "=[")
        .args(["san", "simulate", "/dev/null"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
}

#[test]
fn logs_have_no_colour_codes_when_stderr_is_not_a_terminal() {
    // The demo square logs at info level (events, the driver's session).
    let out = run_ok(ima().args([
        "--log", "debug", "demo", "square", "--side", "0.2", "--json",
    ]));
    let err = stderr(&out);
    assert!(
        err.contains("DEBUG") || err.contains("INFO"),
        "nothing logged: {err}"
    );
    assert!(!err.contains('\u{1b}'), "ANSI codes: {err:?}");
}

#[test]
fn error_messages_name_a_file_once() {
    let d = scratch("chain");
    let world = d.join("no-world.toml");
    let out = ima()
        .args(["demo", "--world"])
        .arg(&world)
        .output()
        .unwrap();
    let err = stderr(&out);
    assert_eq!(
        err.matches(&world.display().to_string()).count(),
        1,
        "{err}"
    );

    let key = d.join("no-group.key");
    let cfg = d.join("commander.toml");
    std::fs::write(
        &cfg,
        format!(
            "robot = \"commander\"\nrole = \"commander\"\n[peer]\nkey_file = \"{}\"\n",
            key.display()
        ),
    )
    .unwrap();
    let out = ima()
        .args(["commander", "--config"])
        .arg(&cfg)
        .output()
        .unwrap();
    let err = stderr(&out);
    assert!(!out.status.success());
    assert_eq!(err.matches(&key.display().to_string()).count(), 1, "{err}");
    let _ = std::fs::remove_dir_all(&d);
}

// Item 6: an unknown colour lists the known ones.

#[test]
fn unknown_target_colours_list_the_known_ones() {
    let d = scratch("colours");
    let out = ima()
        .args(["demo", "--targets", "red,pink", "--svg"])
        .arg(d.join("x.svg"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = stderr(&out);
    assert!(
        err.contains("\"pink\"") && err.contains("red, green, blue, yellow, orange, purple"),
        "{err}"
    );
    let cfg = d.join("commander.toml");
    std::fs::write(
        &cfg,
        "robot = \"commander\"\nrole = \"commander\"\n[peer]\ninsecure = true\n",
    )
    .unwrap();
    let out = ima()
        .args(["commander", "--targets", "teal", "--config"])
        .arg(&cfg)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = stderr(&out);
    assert!(
        err.contains("\"teal\"") && err.contains("red, green, blue, yellow, orange, purple"),
        "{err}"
    );
    // The one-shot cancel is refused too, before anything is sent.
    let out = ima()
        .args(["commander", "cancel", "--target", "nosuch", "--config"])
        .arg(&cfg)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = stderr(&out);
    assert!(
        err.contains("\"nosuch\"") && err.contains("red, green, blue, yellow, orange, purple"),
        "{err}"
    );
    assert!(
        out.stdout.is_empty(),
        "{}",
        String::from_utf8_lossy(&out.stdout)
    );
    // A stop's reason longer than a broadcast carries is refused, as `ima peer send`'s text
    // is (it was cut to 255 bytes without a word, and the command said "fleet stop sent").
    let out = ima()
        .args([
            "commander",
            "stop",
            "--reason",
            &"x".repeat(300),
            "--config",
        ])
        .arg(&cfg)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
    assert!(
        stderr(&out).contains("300 bytes is too long: a broadcast carries at most 255 bytes"),
        "{}",
        stderr(&out)
    );
    let _ = std::fs::remove_dir_all(&d);
}

/// Paths that are not UTF-8 (a Linux file name may be any bytes): the demo's JSON summary
/// named them through serde_json, which refused them, and the `unwrap` behind `json!`
/// panicked after the mission (status 101). They are now shown as text (U+FFFD for the bad
/// bytes) and the files are written under their real names.
#[cfg(unix)]
#[test]
fn paths_that_are_not_utf8_are_written_and_named() {
    use std::os::unix::ffi::OsStrExt as _;
    let d = scratch("not-utf8");
    let svg = d.join(std::ffi::OsStr::from_bytes(b"\xff.svg"));
    let mcap = d.join(std::ffi::OsStr::from_bytes(b"\xfe.mcap"));
    let out = run_ok(
        ima()
            .args(common::SHORT_DEMO)
            .arg("--svg")
            .arg(&svg)
            .arg("--record")
            .arg(&mcap),
    );
    let summary = common::demo_summary(&out);
    let named = summary["svg"].as_str().unwrap();
    assert!(named.ends_with("\u{fffd}.svg"), "{named}");
    let named = summary["recording"]["path"].as_str().unwrap();
    assert!(named.ends_with("\u{fffd}.mcap"), "{named}");
    assert!(std::fs::metadata(&svg).unwrap().len() > 0);
    assert!(std::fs::metadata(&mcap).unwrap().len() > 0);
    let _ = std::fs::remove_dir_all(&d);
}

/// Every device of a running robot vanishes (the mock world's process is killed; on a robot,
/// a pulled USB hub): each driver says once that its port closed, Scooter's laser and
/// compass readers say once what fails (they logged "laser: Disconnected" and "compass:
/// Disconnected" five times a second each, for as long as the robot ran), and the run ends,
/// naming the device.
#[test]
fn devices_that_vanish_are_reported_once_each() {
    let d = scratch("vanish");
    let args = ["mock", "world", "--speed", "2", "--write-configs"].map(std::ffi::OsStr::new);
    let (mut world, first) = common::spawn_first_line(args.into_iter().chain([d.as_os_str()]));
    assert!(first.contains("\"configs\""), "{first}");
    let err_file = d.join("scooter.err");
    let mut run = Child(
        ima()
            .args(["run", "--config"])
            .arg(d.join("scooter.toml"))
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&err_file).unwrap())
            .spawn()
            .unwrap(),
    );
    // Its devices answered (it waits for Skeeter's Peer link meanwhile).
    let end = std::time::Instant::now() + std::time::Duration::from_secs(60);
    while !std::fs::read_to_string(&err_file)
        .unwrap_or_default()
        .contains("scooter connected")
    {
        assert!(std::time::Instant::now() < end, "Scooter never connected");
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    world.0.kill().unwrap();
    let _ = world.0.wait();
    // The robot's run ends by itself, naming a device that is gone (it ran on, saying it was
    // well, while the commander sent it targets it could not do), within 10 s.
    let end = std::time::Instant::now() + std::time::Duration::from_secs(10);
    let status = loop {
        if let Some(s) = run.0.try_wait().unwrap() {
            break s;
        }
        assert!(
            std::time::Instant::now() < end,
            "the run went on without its devices"
        );
        std::thread::sleep(std::time::Duration::from_millis(50));
    };
    let err = std::fs::read_to_string(&err_file).unwrap();
    assert_eq!(status.code(), Some(1), "{err}");
    assert!(
        err.contains("its driver has ended (the port closed or failed for good): the run ends"),
        "{err}"
    );
    // …in order: the runtime was asked to stop and tried to stop its base (which is gone).
    assert!(err.contains("base: stop failed"), "{err}");
    // One line per kind of error (a timeout, the port's own error, then `Disconnected`).
    for what in ["scooter: laser: ", "scooter: compass: "] {
        let failures = err.lines().filter(|l| l.contains(what)).count();
        assert!(failures <= 3, "{what} {failures} times:\n{err}");
    }
    for device in ["rFLEX base", "SICK LMS", "compass"] {
        assert_eq!(
            err.matches(&format!("{device}: the port ")).count(),
            1,
            "one line for the {device}:\n{err}"
        );
    }
    let _ = std::fs::remove_dir_all(&d);
}

/// A world with two objects of a target's colour is refused before anything starts: Skeeter's
/// cameras cannot tell them apart, and the demo used to run the whole `--target-timeout` (25 s
/// of wall time at ×10) and end with "1 target(s) failed" and no reason.
#[test]
fn a_target_colour_two_objects_share_is_refused_at_once() {
    let objects: String = ["3.0", "-3.0"]
        .iter()
        .map(|x| {
            format!(
                "[[object]]\ncolor = \"red\"\nrgb = [220, 30, 30]\ncenter = [{x}, 2.0]\nradius_m = 0.15\n"
            )
        })
        .collect();
    let err = demo_refuses_world("two-reds", &objects);
    assert!(
        err.contains("2 objects of that colour, at (3.00, 2.00) and (-3.00, 2.00)"),
        "{err}"
    );
}

/// `ima demo --targets red` on a world of Skeeter at (0, 0), Scooter at (-3, 0) and
/// `objects` (TOML): it must refuse before anything starts (no picture written). Returns its
/// stderr.
fn demo_refuses_world(name: &str, objects: &str) -> String {
    let d = scratch(name);
    let world = d.join(format!("{name}.toml"));
    let mut text = String::new();
    for (name, x) in [("skeeter", 0.0), ("scooter", -3.0)] {
        text += &format!("[[robot]]\nname = \"{name}\"\nx_m = {x}\ny_m = 0.0\ntheta_deg = 0.0\n");
    }
    std::fs::write(&world, text + objects).unwrap();
    let out = ima()
        .args(["demo", "--targets", "red", "--world"])
        .arg(&world)
        .arg("--svg")
        .arg(d.join("x.svg"))
        .output()
        .unwrap();
    let err = stderr(&out);
    assert!(!out.status.success(), "{err}");
    assert!(!d.join("x.svg").exists(), "the demo ran: {err}");
    let _ = std::fs::remove_dir_all(&d);
    err
}

/// A target placed under a robot's start (Scooter's, here) is refused before anything starts:
/// the demo ran until Skeeter reported "Scooter lost" (94 s of mission time at ×20), then
/// ended with "1 target(s) failed".
#[test]
fn a_target_under_a_robots_start_is_refused_at_once() {
    let object =
        "[[object]]\ncolor = \"red\"\nrgb = [220, 30, 30]\ncenter = [-3.1, 0.2]\nradius_m = 0.15\n";
    let err = demo_refuses_world("under", object);
    assert!(
        err.contains(
            "scooter starts at (-3.00, 0.00) overlapping the red object at (-3.10, 0.20) (0.22 m \
             from it; it needs 0.45 m)"
        ),
        "{err}"
    );
}

/// A robot of a world file whose name starts with a multi-byte character: `ima mock p2os`
/// capitalised the name by byte and panicked ("byte index 1 is not a char boundary"). It
/// capitalises by character now (`Émile`, which the driver shows as `??mile`: P2OS names
/// are ASCII), and a robot the world lacks is named with the ones it has.
#[test]
fn a_mock_robot_named_in_any_script_serves_and_names_itself() {
    let d = scratch("emile");
    let world = d.join("emile.toml");
    std::fs::write(
        &world,
        "[[robot]]\nname = \"émile\"\nx_m = 0.0\ny_m = 0.0\ntheta_deg = 0.0\n",
    )
    .unwrap();
    let w = world.to_str().unwrap();
    let (_mock, pty) = common::spawn_mock(&["p2os", "--world", w, "--robot", "émile"]);
    let out = ima()
        .args(["drive", "--for", "0.3", "--port", pty.trim()])
        .output()
        .unwrap();
    let err = stderr(&out);
    assert!(out.status.success(), "{err}");
    // The driver shows a name's non-ASCII bytes as `?` (P2OS names are ASCII).
    assert!(err.contains("connected to ??mile (Pioneer"), "{err}");
    let out = ima()
        .args(["mock", "rflex", "--world", w, "--robot", "scooter"])
        .output()
        .unwrap();
    let err = stderr(&out);
    assert!(!out.status.success());
    assert!(
        err.contains("no robot named \"scooter\" (it has: émile)"),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&d);
}

/// `ima mock --help` gives the fault grammar (it pointed to a crate's rustdoc), and every key
/// it lists parses.
#[test]
fn mock_help_gives_the_fault_grammar_and_its_keys_parse() {
    let out = run_ok(ima().args(["mock", "p2os", "--help"]));
    let help = String::from_utf8_lossy(&out.stdout);
    for key in [
        "corrupt=P",
        "drop=P",
        "garbage=P[:MIN-MAX]",
        "split=P",
        "stall=P:DUR",
        "delay=DUR",
        "hangup=DUR[:OUTAGE]",
        "seed=N",
        "r2h.",
    ] {
        assert!(help.contains(key), "{key} missing from:\n{help}");
    }
    let spec = "corrupt=0.01,drop=0.001,garbage=0.001:1-4,split=1,stall=0.0005:300ms,\
                delay=5ms,r2h.hangup=5s:1s,seed=3";
    assert!(ima_mock_devices::faults::FaultPlan::parse(spec).is_ok());
}

/// A configuration error in a huge line quotes a window of it, not the line: a one-line file
/// of 10 MB was echoed whole to stderr. `ima run` and `ima peer` alike.
#[test]
fn a_config_error_in_a_huge_line_is_said_briefly() {
    let d = scratch("hugeline");
    let p = d.join("big.toml");
    std::fs::write(&p, format!("robot = \"{}\" oops\n", "x".repeat(2_000_000))).unwrap();
    for args in [
        &["run", "--insecure"][..],
        &["peer", "manager", "--insecure"][..],
    ] {
        let out = ima().args(args).arg("--config").arg(&p).output().unwrap();
        let err = stderr(&out);
        assert_eq!(out.status.code(), Some(1), "{args:?}");
        assert!(err.len() < 2_000, "{args:?}: {} bytes", err.len());
        assert!(
            err.contains("TOML parse error at line 1, column 2000012") && err.contains('…'),
            "{args:?}: {err}"
        );
    }
    let _ = std::fs::remove_dir_all(&d);
}

/// Flags whose values the program cannot use are refused as the command line is read (status
/// 2, the flag named): an LMS variant or rate (they failed with status 1 after the command
/// started), an empty robot name to wait for (the commander waited for a robot that cannot
/// exist).
#[test]
fn unusable_values_are_refused_as_the_command_line_is_read() {
    for (args, want) in [
        (
            &["scan", "--port", "/dev/null", "--variant", "180x0.25"][..],
            "\"180x0.25\" is not an LMS variant",
        ),
        (
            &["scan", "--port", "/dev/null", "--baud", "4800"][..],
            "4800 is not an LMS rate",
        ),
        (
            &[
                "commander",
                "--config",
                "/dev/null",
                "--wait-for",
                "skeeter,",
            ][..],
            "an empty name names no robot",
        ),
    ] {
        let out = ima().args(args).output().unwrap();
        assert_eq!(out.status.code(), Some(2), "{args:?}: {}", stderr(&out));
        assert!(stderr(&out).contains(want), "{args:?}: {}", stderr(&out));
    }
}

/// `--record` takes a new file only: `-` (stdout elsewhere) made a file named `-`, a device
/// such as `/dev/null` was refused as "the file exists", a FIFO would be waited on for ever,
/// and an existing file is never overwritten. Each is refused before anything starts.
#[test]
fn record_takes_a_new_file_only() {
    let d = scratch("record-new");
    let old = d.join("old.mcap");
    std::fs::write(&old, b"keep").unwrap();
    // A FIFO nobody reads: opening it to test it would wait for a reader for ever.
    let fifo = d.join("fifo");
    assert!(
        std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap()
            .success()
    );
    for (path, why) in [
        (
            fifo.display().to_string(),
            "not a regular file (a recording is written to a new file)",
        ),
        (
            "-".to_owned(),
            "--record -: a recording is written to a file",
        ),
        (
            "/dev/null".to_owned(),
            "--record /dev/null: not a regular file (a recording is written to a new file)",
        ),
        (
            old.display().to_string(),
            "the file exists (a recording never overwrites one)",
        ),
    ] {
        let out = ima()
            .current_dir(&d)
            .args(["demo", "--svg"])
            .arg(d.join("x.svg"))
            .args(["--record", &path])
            .output()
            .unwrap();
        let err = stderr(&out);
        assert_eq!(out.status.code(), Some(1), "{path}: {err}");
        assert!(err.contains(why), "{path}: {err}");
        assert!(!d.join("x.svg").exists(), "the demo ran: {err}");
    }
    assert!(!d.join("-").exists());
    assert_eq!(std::fs::read(&old).unwrap(), b"keep");
    let _ = std::fs::remove_dir_all(&d);
}

/// A directory holding the configurations `ima mock world --write-configs` writes (the world
/// itself ended: no device is served), and Skeeter's: its path and text.
fn skeeter_config(name: &str) -> (std::path::PathBuf, std::path::PathBuf, String) {
    let d = scratch(name);
    let (world, line) = mock_world(&d, &[]);
    assert!(line.is_some(), "the world did not start");
    drop(world);
    let cfg = d.join("skeeter.toml");
    let text = std::fs::read_to_string(&cfg).unwrap();
    (d, cfg, text)
}

/// A SAN network Skeeter's brain cannot run (one that lacks a condition the brain feeds) is
/// refused before any device opens, naming the configuration, the key and the network file.
/// It was found only once the devices had connected: "configuration: Skeeter's SAN: skeeter
/// network lacks condition `target-requested`".
#[test]
fn a_network_skeeter_cannot_run_is_refused_before_its_devices_open() {
    // The world's devices are not needed: the check comes first.
    let (d, cfg, text) = skeeter_config("skeeter-network");
    let toy = concat!(env!("CARGO_MANIFEST_DIR"), "/agents/networks/maes_toy.toml");
    let text = text.replacen("[agent]\n", &format!("[agent]\nnetwork = {toy:?}\n"), 1);
    assert!(text.contains("network = "), "no [agent] table: {text}");
    std::fs::write(&cfg, text).unwrap();
    let out = ima().args(["run", "--config"]).arg(&cfg).output().unwrap();
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains(&format!("in {}", cfg.display()))
            && err.contains(&format!(
                "agent.network {toy}: skeeter network lacks condition"
            ))
            && !err.contains("opening"),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&d);
}

/// A live view asked for on one of the robot's own Peer Agent ports is refused before any
/// device opens (it failed once the devices had connected, blaming "another program").
#[test]
fn a_live_view_on_the_robots_own_port_is_refused_at_once() {
    let (d, cfg, text) = skeeter_config("foxglove-own-port");
    let listen = text
        .lines()
        .find_map(|l| l.strip_prefix("listen = "))
        .expect("peer.listen")
        .trim_matches('"')
        .to_owned();
    let out = ima()
        .args(["run", "--config"])
        .arg(&cfg)
        .args(["--foxglove", &listen])
        .output()
        .unwrap();
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains(&format!(
            "--foxglove {listen}: that is this robot's peer.listen ({listen})"
        )),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&d);
}

//! Issue 14: the robots' path names no driver. Concrete drivers are named only by the wiring
//! module (`src/wiring.rs`) and by the commands that are single-device tools; the agents
//! (`agents/`) never name one, and do not depend on a driver crate.
//!
//! The check reads the sources: outside comments, no `ima_<driver>::` path and no driver
//! shell type (`SickLms`, `CompassDriver`, `VideoMux`, `NetFrames`, `P2os::`, `Rflex::`)
//! may appear. The generic names `P2os`/`Rflex` alone are configuration values
//! (`BaseKind::P2os`) and are allowed; a driver's types cannot be named without its crate
//! path anyway.

use std::path::{Path, PathBuf};

/// Files allowed to name drivers, each with the reason.
const ALLOWED: &[(&str, &str)] = &[
    (
        "src/wiring.rs",
        "the wiring module: opens every robot device from the configuration",
    ),
    (
        "src/cmd/replay.rs",
        "`ima replay`: re-decodes a recording through the drivers' decoders",
    ),
    (
        "src/cmd/camera.rs",
        "`ima camera`: one video switcher and frame source",
    ),
    ("src/cmd/compass.rs", "`ima compass`: one compass"),
    ("src/cmd/scan.rs", "`ima scan`: one SICK LMS"),
    (
        "src/cmd/drive/mod.rs",
        "`ima drive`: one P2OS or rFLEX base",
    ),
    (
        "src/cmd/drive/rflex.rs",
        "`ima drive --robot atrv-jr`: one rFLEX base",
    ),
    (
        "src/cmd/drive/square.rs",
        "`ima demo square`: one P2OS base driving a square",
    ),
    ("src/cmd/mock/mod.rs", "`ima mock`: serves one mock device"),
    (
        "src/cmd/mock/sick.rs",
        "`ima mock sick-lms`: one mock device",
    ),
    (
        "src/cmd/decode/mod.rs",
        "`ima decode`: a driver's wire decoder",
    ),
    (
        "src/cmd/decode/p2os.rs",
        "`ima decode p2os`: a driver's wire decoder",
    ),
    (
        "src/cmd/decode/compass.rs",
        "`ima decode compass`: a driver's wire decoder",
    ),
    (
        "src/cmd/decode/rflex.rs",
        "`ima decode rflex`: a driver's wire decoder",
    ),
    (
        "src/cmd/decode/sick.rs",
        "`ima decode sick`: a driver's wire decoder",
    ),
    (
        "src/cmd/decode/video_mux.rs",
        "`ima decode video-mux`: a driver's wire decoder",
    ),
];

const DRIVER_CRATES: &[&str] = &[
    "ima_p2os",
    "ima_rflex",
    "ima_sick_lms",
    "ima_compass",
    "ima_video_mux",
];

const DRIVER_TYPES: &[&str] = &[
    "SickLms",
    "CompassDriver",
    "VideoMux",
    "NetFrames",
    "P2os::",
    "Rflex::",
];

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let p = e.path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// Driver names in `text` outside `//` comments: (line number, the name).
fn driver_names(text: &str) -> Vec<(usize, String)> {
    let mut found = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let code = line.split("//").next().unwrap_or("");
        for c in DRIVER_CRATES {
            if code.contains(&format!("{c}::")) || code.contains(&format!("use {c}")) {
                found.push((i + 1, (*c).to_owned()));
            }
        }
        for t in DRIVER_TYPES {
            let bare = t.trim_end_matches("::");
            let hit = code.match_indices(t).any(|(at, _)| {
                // A word of its own, and not a variant of another enum (`Device::VideoMux`).
                let before = &code[..at];
                let word_start = !before
                    .chars()
                    .last()
                    .is_some_and(|ch| ch.is_alphanumeric() || ch == '_');
                let after = code[at + bare.len()..].chars().next();
                let word_end =
                    t.ends_with("::") || !after.is_some_and(|ch| ch.is_alphanumeric() || ch == '_');
                word_start && word_end && !before.ends_with("::")
            });
            if hit {
                found.push((i + 1, bare.to_owned()));
            }
        }
    }
    found
}

#[test]
fn no_driver_is_named_outside_the_wiring_module_and_the_device_tools() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = Vec::new();
    rust_files(&root.join("src"), &mut files);
    rust_files(&root.join("agents"), &mut files);
    assert!(
        files.len() > 20,
        "sources not found under {}",
        root.display()
    );
    let mut offenders = Vec::new();
    for f in &files {
        let rel = f
            .strip_prefix(root)
            .unwrap()
            .to_string_lossy()
            .replace('\\', "/");
        if ALLOWED.iter().any(|(a, _)| *a == rel) {
            continue;
        }
        let text = std::fs::read_to_string(f).unwrap();
        for (line, name) in driver_names(&text) {
            offenders.push(format!("{rel}:{line}: {name}"));
        }
    }
    assert!(
        offenders.is_empty(),
        "driver names outside src/wiring.rs and the device tools:\n{}",
        offenders.join("\n")
    );
    // Every allowed file exists (a stale entry would hide a rename).
    for (a, why) in ALLOWED {
        assert!(root.join(a).is_file(), "allowed file {a} ({why}) is gone");
    }
}

#[test]
fn the_agents_crate_depends_on_no_driver() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let manifest = std::fs::read_to_string(root.join("agents/Cargo.toml")).unwrap();
    for c in DRIVER_CRATES {
        let dashed = c.replace('_', "-");
        assert!(
            !manifest.contains(&dashed),
            "agents/Cargo.toml names the driver crate {dashed}"
        );
    }
    // DESIGN.md: `agents` depends on `hal` only. Of the workspace's crates, its manifest
    // names `ima-hal` and itself (the dev-dependency with the fuzz harness), nothing else:
    // not `ima-serial`, whose byte cursors now live in `ima_hal::bytes`.
    let named: Vec<&str> = manifest
        .lines()
        .filter_map(|l| l.trim_start().split([' ', '.', '=']).next())
        .filter(|k| k.starts_with("ima-"))
        .collect();
    assert!(
        named.iter().all(|k| ["ima-hal", "ima-agents"].contains(k)),
        "agents/Cargo.toml depends on {named:?}; only ima-hal is allowed"
    );
    assert!(named.contains(&"ima-hal"), "{named:?}");
}

#[test]
fn the_check_sees_what_it_must() {
    let bad = "use ima_rflex::shell::Rflex;\nlet l: SickLms = x;\nlet b = Rflex::connect(p);\n";
    let names: Vec<String> = driver_names(bad).into_iter().map(|(_, n)| n).collect();
    assert_eq!(names, ["ima_rflex", "SickLms", "Rflex"]);
    let fine = "// uses ima_p2os::shell\nlet k = BaseKind::P2os;\nmatch d { Device::VideoMux => 1 }\nlet s = \"ima_p2os=debug\";\n";
    assert!(driver_names(fine).is_empty(), "{:?}", driver_names(fine));
}

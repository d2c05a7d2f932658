//! `ima experiment heading`: the range-aware half of the sweep through the CLI, its files,
//! and the done criterion (f ≥ 0.95 in every configuration with the thesis robot).

mod common;

use common::{ima, run_ok};

#[test]
fn experiment_heading_range_aware_json_and_files() {
    let dir = std::env::temp_dir().join(format!("ima-experiment-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let out = run_ok(
        ima()
            .args([
                "experiment",
                "heading",
                "--rule",
                "range-aware",
                "--seed",
                "1",
                "--json",
            ])
            .arg("--out")
            .arg(&dir),
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("48/48 runs"), "progress bar: {stderr}");
    let doc: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let runs = doc["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 48);
    for r in runs {
        assert_eq!(r["rule"], "range-aware");
        assert_eq!(r["reason"], "reached", "{r}");
        let f = r["f"].as_f64().unwrap();
        assert!(f >= 0.95, "f = {f} in {r}");
    }
    for name in [
        "heading.csv",
        "heading.json",
        "tables.md",
        "f.svg",
        "trajectories-45.svg",
        "trajectories-90.svg",
        "trajectories-135.svg",
    ] {
        let text = std::fs::read_to_string(dir.join(name)).unwrap();
        assert!(!text.is_empty(), "{name}");
    }
    let csv = std::fs::read_to_string(dir.join("heading.csv")).unwrap();
    assert_eq!(csv.lines().count(), 49);
    let tables = std::fs::read_to_string(dir.join("tables.md")).unwrap();
    assert!(tables.contains("**range-aware, θ = 135°**"));
    // The plots: well-formed, no NaN, the promised labels.
    let f = ima_plot::inspect(&std::fs::read_to_string(dir.join("f.svg")).unwrap()).unwrap();
    for text in [
        "range-aware rule, θ = 45°",
        "range-aware rule, θ = 135°",
        "Ds (m)",
        "Dt (m)",
    ] {
        assert!(f.has_text(text), "f.svg: {text} missing: {:?}", f.texts);
    }
    assert!(
        !f.any_text_contains("thesis rule"),
        "only the range-aware rule ran"
    );
    for angle in [45, 90, 135] {
        let name = format!("trajectories-{angle}.svg");
        let t = ima_plot::inspect(&std::fs::read_to_string(dir.join(&name)).unwrap()).unwrap();
        let title = format!("Heading experiment, θ = {angle}°: Scooter's paths");
        for text in [
            title.as_str(),
            "range-aware rule",
            "x (m)",
            "y (m)",
            "Skeeter",
            "scale 1 m",
        ] {
            assert!(t.has_text(text), "{name}: {text} missing: {:?}", t.texts);
        }
        // Each of the four corner configurations labelled with its f in the legend.
        for (ds, dt) in [(2, 2), (2, 5), (5, 2), (5, 5)] {
            let run = format!("Ds {ds} m, Dt {dt} m: f ");
            assert!(
                t.any_text_contains(&run),
                "{name}: {run} missing: {:?}",
                t.texts
            );
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn experiment_heading_rejects_an_unknown_rule() {
    let out = ima()
        .args(["experiment", "heading", "--rule", "sideways"])
        .output()
        .unwrap();
    assert!(!out.status.success());
}

#[test]
fn experiment_heading_model_and_settings() {
    // A bad setting is refused before any run, naming the key.
    let out = ima()
        .args(["experiment", "heading", "--set", "see_distance_m=-2"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("`see_distance_m`"), "{stderr}");
    let out = ima()
        .args(["experiment", "heading", "--set", "colour=blue"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("`colour`"));
    // The model and the settings are reported in the JSON.
    let out = run_ok(ima().args([
        "experiment",
        "heading",
        "--rule",
        "thesis",
        "--model",
        "estimate-gated",
        "--set",
        "ses_timing=snapshot",
        "--json",
    ]));
    let doc: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(doc["model"], "estimate-gated");
    assert_eq!(doc["settings"][0], "ses_timing=snapshot");
    assert_eq!(doc["runs"].as_array().unwrap().len(), 48);
}

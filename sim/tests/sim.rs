//! The simulation and the heading experiment, end to end (debug builds: a few runs only).

use core::time::Duration;

use ima_agents::mission::scooter::{Behaviour, HeadingRule, ScooterHeard};
use ima_mock_devices::world::World;
use ima_sim::experiment::{
    RobotModel, RunResult, RunSpec, SETTING_KEYS, SettingError, SweepConfig, TARGET_COLOUR,
    ablations, configurations, csv, json, markdown_tables, run_one, summary, svg_f,
    svg_trajectories, world_for,
};
use ima_sim::{EndReason, ScooterSim, SesTiming, SimConfig, SimError};

fn spec(rule: HeadingRule, angle_deg: f64, ds_m: f64, dt_m: f64, seed: u64) -> RunSpec {
    RunSpec {
        rule,
        angle_deg,
        ds_m,
        dt_m,
        seed,
    }
}

#[test]
fn range_aware_runs_score_high_and_the_thesis_rule_is_exact_on_a_short_chord() {
    let cfg = SweepConfig::default();
    for (rule, angle, ds, dt) in [
        (HeadingRule::RangeAware, 90.0, 2.0, 4.0),
        (HeadingRule::RangeAware, 135.0, 5.0, 2.0),
        (HeadingRule::Thesis, 45.0, 2.0, 2.0),
    ] {
        let r = run_one(&spec(rule, angle, ds, dt, 7), &cfg);
        assert_eq!(r.reason, "reached", "{r:?}");
        assert!(r.f >= 0.9, "{rule:?} {angle} {ds} {dt}: f = {}", r.f);
        assert!(r.d_actual_m >= r.d_min_m - 1e-9);
        assert!(r.samples >= 2);
    }
}

/// Both rules are scored against the same shortest path: `d_min` is the configuration's
/// (within the last control step), not the point where a run happened to stop, which gave a
/// path that curved round to the target's side a longer `d_min` and a higher f (3.29 m for
/// the thesis rule against 3.04 m for the range-aware rule here).
#[test]
fn both_rules_are_scored_against_the_same_shortest_path() {
    let cfg = SweepConfig::default();
    let k = configurations(&[HeadingRule::Thesis, HeadingRule::RangeAware], 1);
    let (thesis, range) = [HeadingRule::Thesis, HeadingRule::RangeAware]
        .map(|rule| {
            let s = k
                .iter()
                .find(|s| s.rule == rule && s.angle_deg == 45.0 && s.ds_m == 5.0 && s.dt_m == 2.0)
                .unwrap();
            run_one(s, &cfg)
        })
        .into();
    assert!(
        (thesis.d_min_m - range.d_min_m).abs() < 0.03,
        "{} against {}",
        thesis.d_min_m,
        range.d_min_m
    );
    for r in [&thesis, &range] {
        assert_eq!(r.reason, "reached", "{r:?}");
        assert!(r.d_actual_m >= r.d_min_m, "{r:?}");
    }
}

#[test]
fn the_thesis_rule_spirals_inward_when_the_target_is_farther_than_scooter() {
    // Target 5 m out, Scooter 2 m out, 135° apart: the isosceles rule keeps aiming at
    // Scooter's own (shrinking) circle and ripples along the target's bearing line.
    let cfg = SweepConfig::default();
    let thesis = run_one(&spec(HeadingRule::Thesis, 135.0, 2.0, 5.0, 3), &cfg);
    let range = run_one(&spec(HeadingRule::RangeAware, 135.0, 2.0, 5.0, 3), &cfg);
    assert!(thesis.f < 0.5 * range.f, "{} vs {}", thesis.f, range.f);
}

#[test]
fn runs_are_reproducible_from_the_seed() {
    let cfg = SweepConfig::default();
    let s = spec(HeadingRule::RangeAware, 45.0, 3.0, 2.0, 11);
    let a = run_one(&s, &cfg);
    let b = run_one(&s, &cfg);
    assert_eq!(a, b);
    let c = run_one(&RunSpec { seed: 12, ..s }, &cfg);
    assert_ne!(a.trajectory, c.trajectory, "another seed, other noise");
    // Configuration seeds derive from the sweep seed, the same for both rules.
    let k = configurations(&[HeadingRule::Thesis, HeadingRule::RangeAware], 5);
    assert_eq!(k.len(), 96);
    assert_eq!(k[0].seed, k[48].seed);
    assert_ne!(k[0].seed, k[1].seed);
    // Exact as JSON numbers (`jq` read 16834447057089888969 as 16834447057089888000).
    assert!(k.iter().all(|s| s.seed < 1 << 53));
    assert_ne!(
        configurations(&[HeadingRule::Thesis], 5)[0].seed,
        configurations(&[HeadingRule::Thesis], 6)[0].seed
    );
}

#[test]
fn ses_samples_arrive_at_start_and_after_every_full_scan() {
    let mut sim = ScooterSim::new(
        world_for(90.0, 3.0, 3.0, 1),
        TARGET_COLOUR,
        SimConfig::default(),
    )
    .unwrap();
    assert_eq!(sim.samples(), 1);
    // 10 s at 50 ms: scans complete at 5 s and 10 s (the 10 s one on the step at 10 s).
    for _ in 0..=200 {
        sim.step();
    }
    assert_eq!(sim.samples(), 3);
    assert!(sim.brain().plan().is_some());
}

#[test]
fn setup_errors_are_typed() {
    let w = world_for(90.0, 3.0, 3.0, 1);
    assert_eq!(
        ScooterSim::new(w.clone(), "blue", SimConfig::default()).unwrap_err(),
        SimError::NoTarget("blue".to_owned())
    );
    assert_eq!(
        ScooterSim::new(World::new(), "red", SimConfig::default()).unwrap_err(),
        SimError::NoRobot("skeeter")
    );
    let bad = SimConfig {
        dt: Duration::ZERO,
        ..SimConfig::default()
    };
    assert_eq!(
        ScooterSim::new(w.clone(), "red", bad).unwrap_err(),
        SimError::BadPeriod("the step dt is zero".to_owned())
    );
    // A scan period below the step would pile up samples (1 µs filled 11 GB): refused by
    // both loops, naming the period.
    let fast = SimConfig {
        scan_period: Duration::from_micros(1),
        ..SimConfig::default()
    };
    let e = ScooterSim::new(w.clone(), "red", fast.clone()).unwrap_err();
    assert_eq!(
        e.to_string(),
        "bad simulation period: scan_period (1µs) is shorter than the step dt (50ms)"
    );
    let slow_control = SimConfig {
        control_hz: f64::NAN,
        ..SimConfig::default()
    };
    assert!(matches!(
        ScooterSim::new(w.clone(), "red", slow_control).unwrap_err(),
        SimError::BadPeriod(_)
    ));
    for (name, cfg) in [
        (
            "laser_period",
            SimConfig {
                laser_period: Duration::ZERO,
                ..SimConfig::default()
            },
        ),
        (
            "odometry_period",
            SimConfig {
                odometry_period: Duration::from_millis(1),
                ..SimConfig::default()
            },
        ),
        (
            "compass_period",
            SimConfig {
                compass_period: Duration::from_millis(49),
                ..SimConfig::default()
            },
        ),
    ] {
        let e = cfg.check_periods().unwrap_err();
        assert!(e.to_string().contains(name), "{e}");
    }
    assert_eq!(SimConfig::default().check_periods(), Ok(()));
    // The runtime path refuses before any device's timer starts (a zero period would spin).
    let zero_laser = SimConfig {
        laser_period: Duration::ZERO,
        ..SimConfig::default()
    };
    let e = ima_sim::runtime::run_runtime(w, "red", &zero_laser, Duration::from_secs(10));
    assert!(
        matches!(e, Err(SimError::BadPeriod(ref why)) if why.contains("laser_period")),
        "{e:?}"
    );
}

#[test]
fn called_back_scooter_drives_toward_skeeter() {
    let mut sim = ScooterSim::new(
        world_for(90.0, 4.0, 4.0, 1),
        TARGET_COLOUR,
        SimConfig::default(),
    )
    .unwrap();
    for _ in 0..100 {
        sim.step();
    }
    let now = sim.now();
    sim.brain_mut()
        .handle_heard(&ScooterHeard::ScooterLost, now);
    let dist = |s: &ScooterSim| {
        let p = s.trajectory().last().copied().unwrap();
        p[0].hypot(p[1])
    };
    let before = dist(&sim);
    // The simulated Skeeter keeps seeing Scooter, and an SES sample with a fresh Scooter
    // record ends a call-back (the `scooter-found` may be lost): keep calling it back.
    for _ in 0..200 {
        let now = sim.now();
        sim.brain_mut()
            .handle_heard(&ScooterHeard::ScooterLost, now);
        sim.step();
    }
    assert_eq!(sim.last_output().unwrap().behaviour, Behaviour::MoveToHome);
    assert!(dist(&sim) < before - 0.5, "{} → {}", before, dist(&sim));
}

#[test]
fn default_world_mission_reaches_a_ring_object() {
    // The demo world: six posts 3 m round Skeeter, Scooter 4 m out; go to green (60°).
    let mut sim = ScooterSim::new(World::default_world(), "green", SimConfig::default()).unwrap();
    let o = sim.run(Duration::from_secs(120));
    assert_eq!(o.reason, EndReason::Reached, "{o:?}");
    let end = o.end;
    let green = [
        3.0 * 60f64.to_radians().cos(),
        3.0 * 60f64.to_radians().sin(),
    ];
    assert!(
        (end[0] - green[0]).hypot(end[1] - green[1]) < 1.0,
        "{end:?}"
    );
}

fn fake(rule: &'static str, angle_deg: f64, ds_m: f64, dt_m: f64, f: f64) -> RunResult {
    RunResult {
        rule,
        angle_deg,
        ds_m,
        dt_m,
        seed: 1,
        f,
        d_min_m: 1.0,
        d_actual_m: 1.25,
        t_min_s: 20.0,
        t_actual_s: 25.0,
        reason: "reached",
        end_to_target_m: 0.8,
        samples: 5,
        start: [-ds_m, 0.0],
        target: [0.0, dt_m],
        trajectory: vec![[-ds_m, 0.0], [0.0, dt_m]],
    }
}

#[test]
fn table_csv_json_and_svg_writers() {
    let mut results = vec![
        fake("thesis", 45.0, 2.0, 3.0, 0.5),
        fake("thesis", 45.0, 5.0, 2.0, 0.25),
        fake("range-aware", 90.0, 2.0, 5.0, 0.99),
    ];
    let t = markdown_tables(&results, "thesis");
    // Row Dt = 3, column Ds = 2; row Dt = 2, column Ds = 5 (the last cell of its row).
    assert!(t.contains("| 3 m | 0.50 | — | — | — |"), "{t}");
    assert!(t.contains("| 2 m | — | — | — | 0.25 |"), "{t}");
    // A run that did not reach is marked, not shown as a plain score of 0.
    let mut timeout = fake("thesis", 90.0, 4.0, 4.0, 0.0);
    timeout.reason = "timeout";
    results.push(timeout);
    let t = markdown_tables(&results, "thesis");
    assert!(t.contains("| 4 m | — | — | 0.00* | — |"), "{t}");
    results.pop();
    assert!(t.contains("**thesis, θ = 135°**"));
    assert_eq!(t.matches("| Dt \\ Ds | 2 m | 3 m | 4 m | 5 m |").count(), 3);
    let c = csv(&results);
    let lines: Vec<&str> = c.lines().collect();
    assert_eq!(lines.len(), 4);
    assert!(lines[0].starts_with("rule,angle_deg,ds_m,dt_m,seed,f,"));
    assert_eq!(
        lines[1],
        "thesis,45,2,3,1,0.5000,1.0000,1.2500,20.00,25.00,reached,5"
    );
    let j = json(&results, &SweepConfig::default());
    assert_eq!(j["runs"].as_array().unwrap().len(), 3);
    assert_eq!(j["runs"][2]["rule"], "range-aware");
    assert!(j["runs"][0].get("trajectory").is_none());
    assert_eq!(j["speed_m_s"], 0.05);
    assert_eq!(j["observer"], "geometric");
    let s = summary(&results);
    assert!(s.contains("thesis: 2 runs, f min 0.250"), "{s}");
    let f = ima_plot::inspect(&svg_f(&results)).unwrap();
    for text in [
        "Heading experiment: performance index f per configuration",
        "thesis rule, θ = 45°",
        "range-aware rule, θ = 135°",
        "Ds (m)",
        "Dt (m)",
        "0.99",
        "0.50",
        "—",
    ] {
        assert!(f.has_text(text), "{text} missing: {:?}", f.texts);
    }
    let t = ima_plot::inspect(&svg_trajectories(&results, 45.0)).unwrap();
    for text in [
        "Heading experiment, θ = 45°: Scooter's paths",
        "thesis rule",
        "x (m)",
        "y (m)",
        "Ds 5",
        "Dt 2",
        "Skeeter",
        "scale 1 m",
        // Only (Ds 5, Dt 2) is among the plotted corner configurations at 45°.
        "Ds 5 m, Dt 2 m: f 0.25",
    ] {
        assert!(t.has_text(text), "{text} missing: {:?}", t.texts);
    }
    assert!(!t.any_text_contains("Ds 2 m, Dt 3 m"), "{:?}", t.texts);
    assert!(!t.has_text("range-aware rule"), "no range-aware run at 45°");
}

#[test]
fn plots_survive_odd_results() {
    // A NaN f, a NaN sample in a path, a run not reached, and no runs at all.
    let mut odd = fake("thesis", 135.0, 2.0, 5.0, f64::NAN);
    odd.trajectory.insert(1, [f64::NAN, 1.0]);
    let mut late = fake("range-aware", 135.0, 5.0, 5.0, 0.0);
    late.reason = "timeout";
    let results = vec![odd, late];
    let f = ima_plot::inspect(&svg_f(&results)).unwrap();
    assert!(f.has_text("—*") || f.has_text("—"), "{:?}", f.texts);
    assert!(
        f.has_text("0.00*"),
        "a run not reached is starred: {:?}",
        f.texts
    );
    let t = ima_plot::inspect(&svg_trajectories(&results, 135.0)).unwrap();
    assert!(t.has_text("Ds 2 m, Dt 5 m: f —"), "{:?}", t.texts);
    assert!(
        t.has_text("Ds 5 m, Dt 5 m: f 0.00, timeout"),
        "{:?}",
        t.texts
    );
    for svg in [svg_f(&[]), svg_trajectories(&[], 45.0)] {
        ima_plot::inspect(&svg).unwrap();
    }
    let empty = ima_plot::inspect(&svg_trajectories(&[], 45.0)).unwrap();
    assert!(empty.has_text("no run at θ = 45°"), "{:?}", empty.texts);
}

#[test]
fn camera_observer_runs_the_real_vision_pipeline() {
    let mut cfg = SweepConfig::default();
    cfg.sim.observer = ima_sim::Observer::Camera;
    let r = run_one(&spec(HeadingRule::RangeAware, 90.0, 2.0, 2.0, 1), &cfg);
    assert_eq!(r.reason, "reached", "{r:?}");
    assert!(r.f >= 0.9, "f = {}", r.f);
}

#[test]
fn a_barrel_on_the_way_is_avoided_smoothly_with_the_real_laser_model() {
    use ima_mock_devices::world::Circle;
    // Range-aware, 90°, Ds = Dt = 4: the straight path from (−4, 0) to (0, 4) passes
    // (−2, 2); a barrel of radius 0.3 stands there.
    let mut world = world_for(90.0, 4.0, 4.0, 1);
    world
        .add_circle(Circle {
            center: [-2.0, 2.0],
            radius_m: 0.3,
        })
        .unwrap();
    let mut cfg = SweepConfig::default().sim;
    cfg.brain.heading_rule = HeadingRule::RangeAware;
    let mut sim = ScooterSim::new(world, TARGET_COLOUR, cfg).unwrap();
    let mut signs = Vec::new();
    let mut avoided = false;
    let mut clearance = f64::INFINITY;
    for _ in 0..6000 {
        let out = sim.step().clone();
        avoided |= out.behaviour == Behaviour::AvoidObstacle;
        // Turning while avoiding, ignoring the small corrections of compass noise.
        if out.behaviour == Behaviour::AvoidObstacle && out.command.omega_rad_s.abs() > 0.1 {
            signs.push((out.command.omega_rad_s * 100.0).round() / 100.0);
        }
        let p = *sim.trajectory().last().unwrap();
        clearance = clearance.min((p[0] + 2.0).hypot(p[1] - 2.0) - 0.3 - 0.4);
        if sim.reached_at().is_some() {
            break;
        }
    }
    assert!(avoided, "the barrel made Scooter avoid");
    assert!(
        sim.reached_at().is_some(),
        "and it still reached the target"
    );
    assert!(clearance > 0.0, "never touched the barrel: {clearance}");
    assert!(signs.len() > 10, "it turned while avoiding: {signs:?}");
    let flips = signs
        .windows(2)
        .filter(|w| w[0].signum() != w[1].signum())
        .count();
    eprintln!("avoidance turn rates: {signs:?}");
    // Away from the barrel, then back toward the goal: one change of sign (two allowed).
    assert!(
        flips <= 2,
        "turn-rate sign flipped {flips} times while avoiding: {signs:?}"
    );
}

/// The four configurations where the first sweep's model timed out with the thesis rule,
/// and the range-aware rule's hardest ones (45°, Scooter 2 m out): (angle, Ds, Dt).
const HARD: [(f64, f64, f64); 6] = [
    (45.0, 4.0, 2.0),
    (45.0, 5.0, 2.0),
    (45.0, 5.0, 3.0),
    (45.0, 2.0, 5.0),
    (45.0, 2.0, 2.0),
    (45.0, 2.0, 3.0),
];

fn hard_specs(rule: HeadingRule) -> Vec<RunSpec> {
    // The sweep's own seeds for these configurations.
    configurations(&[rule], 1)
        .into_iter()
        .filter(|s| {
            HARD.iter()
                .any(|&(a, ds, dt)| s.angle_deg == a && s.ds_m == ds && s.dt_m == dt)
        })
        .collect()
}

#[test]
fn the_thesis_robot_reaches_where_the_estimate_gated_model_timed_out() {
    let thesis_robot = SweepConfig::default();
    assert_eq!(thesis_robot.model, RobotModel::ThesisRobot);
    let gated = SweepConfig::for_model(RobotModel::EstimateGated);
    let specs = hard_specs(HeadingRule::Thesis);
    assert_eq!(specs.len(), HARD.len());
    let mut gated_timeouts = 0;
    for s in &specs {
        let r = run_one(s, &thesis_robot);
        assert_eq!(r.reason, "reached", "thesis robot: {r:?}");
        assert!(r.f > 0.1, "thesis robot: {r:?}");
        if run_one(s, &gated).reason == "timeout" {
            gated_timeouts += 1;
        }
    }
    // The first model's failures come from its recognition and turning, not the geometry.
    assert!(gated_timeouts >= 3, "{gated_timeouts}");
}

#[test]
fn the_range_aware_rule_scores_at_least_0_95_on_the_hardest_configurations() {
    let cfg = SweepConfig::default();
    for s in hard_specs(HeadingRule::RangeAware) {
        let r = run_one(&s, &cfg);
        assert_eq!(r.reason, "reached", "{r:?}");
        assert!(r.f >= 0.95, "{r:?}");
    }
}

#[test]
fn recognition_near_the_estimate_is_what_loses_the_target() {
    // Thesis robot with only the recognition switched back: 45°, Dt 2, Ds 5 (a first-sweep
    // timeout) — Scooter passes the target without accepting it.
    let mut cfg = SweepConfig::default();
    cfg.set("recognition", "near-estimate").unwrap();
    let spec = hard_specs(HeadingRule::Thesis)
        .into_iter()
        .find(|s| s.ds_m == 5.0 && s.dt_m == 2.0)
        .unwrap();
    assert_eq!(run_one(&spec, &cfg).reason, "timeout");
    assert_eq!(run_one(&spec, &SweepConfig::default()).reason, "reached");
}

#[test]
fn settings_are_typed_and_name_their_key() {
    let mut cfg = SweepConfig::default();
    let before = cfg.clone();
    assert_eq!(
        cfg.set("see_distance_m", "-1").unwrap_err(),
        SettingError::BadValue {
            key: "see_distance_m",
            value: "-1".to_owned(),
            expected: "a positive number up to 1e6"
        }
    );
    for (k, v) in [
        ("see_distance_m", "NaN"),
        ("see_distance_m", "inf"),
        ("scan_period_s", "0"),
        ("scan_period_s", "1e-12"),
        ("scan_period_s", "0.000001"),
        ("scan_period_s", "0.049"),
        ("bearing_noise_deg", "-0.5"),
        ("turn_in_place", "maybe"),
        ("model", "scooter"),
        ("recognition", ""),
        ("ses_timing", "later"),
        ("ideal_sensors", "false"),
    ] {
        let e = cfg.set(k, v).unwrap_err();
        assert!(e.to_string().contains(&format!("`{k}`")), "{e}");
    }
    assert!(matches!(
        cfg.set("speed", "1"),
        Err(SettingError::UnknownKey(k)) if k == "speed"
    ));
    assert!(matches!(
        cfg.set_pair("model"),
        Err(SettingError::NotKeyValue(_))
    ));
    assert_eq!(cfg, before, "a rejected setting changes nothing");
    for k in SETTING_KEYS {
        let v = match k {
            "loop" => "reference",
            "model" => "estimate-gated",
            "recognition" => "in-view",
            "ses_timing" => "snapshot",
            "turn_in_place" | "ses_ranges" | "ideal_sensors" | "avoid" => "true",
            _ => "0.5",
        };
        cfg.set_pair(&format!("{k} = {v}")).unwrap();
    }
    assert_eq!(cfg.settings.len(), SETTING_KEYS.len());
    assert_eq!(cfg.sim.ses_timing, SesTiming::Snapshot);
    assert_eq!(cfg.engine, ima_sim::experiment::Engine::Reference);
    assert!(matches!(
        cfg.set("loop", "fast"),
        Err(SettingError::BadValue { key: "loop", .. })
    ));
    assert_eq!(cfg.sim.bearing_noise_rad, 0.0, "ideal_sensors came later");
    cfg.set("model", "thesis-robot").unwrap();
    assert_eq!(
        cfg.sim.brain.target_recognition,
        ima_agents::mission::scooter::TargetRecognition::InView
    );
    assert!(ablations().iter().all(|a| {
        let mut c = SweepConfig::for_model(a.model);
        a.settings.iter().all(|s| c.set_pair(s).is_ok())
    }));
}

#[test]
fn snapshot_ses_delivers_fresh_samples_once_per_scan() {
    let cfg = SimConfig {
        ses_timing: SesTiming::Snapshot,
        ..SimConfig::default()
    };
    let mut sim = ScooterSim::new(world_for(90.0, 3.0, 3.0, 1), TARGET_COLOUR, cfg).unwrap();
    for _ in 0..=200 {
        sim.step();
    }
    assert_eq!(sim.samples(), 3);
}

#[test]
fn acceptance_the_full_sweep_with_the_thesis_robot() {
    // Every thesis-rule run reaches its target (as the thesis's Scooter did in all 48), and
    // the range-aware rule scores f ≥ 0.95 in all 48 configurations.
    let results = ima_sim::experiment::run_sweep(&SweepConfig::default(), &|_, _| {});
    assert_eq!(results.len(), 96);
    for r in &results {
        assert_eq!(r.reason, "reached", "{r:?}");
        if r.rule == "range-aware" {
            assert!(r.f >= 0.95, "{r:?}");
        } else {
            assert!(r.f > 0.0, "{r:?}");
        }
    }
    // The thesis rule stays the weaker rule, worst at 135° as the thesis found.
    let mean = |rule: &str, angle: f64| {
        let v: Vec<f64> = results
            .iter()
            .filter(|r| r.rule == rule && r.angle_deg == angle)
            .map(|r| r.f)
            .collect();
        v.iter().sum::<f64>() / v.len() as f64
    };
    assert!(mean("thesis", 135.0) < mean("thesis", 90.0));
    assert!(mean("thesis", 90.0) < mean("thesis", 45.0));
    for a in [45.0, 90.0, 135.0] {
        assert!(mean("thesis", a) < mean("range-aware", a), "{a}");
    }
}

#[test]
fn the_thesis_robot_keeps_its_target_with_the_sicks_worst_range_error() {
    // MISSION.md: the SICK measures to ±50 mm. With σ = 5 cm laser noise Skeeter's outline
    // breaks into target-sized pieces; in-view recognition must not take one for the
    // target (a false `target-reached` would be a "wrong-target" run).
    let mut cfg = SweepConfig::default();
    cfg.set("laser_noise_m", "0.05").unwrap();
    for rule in [HeadingRule::Thesis, HeadingRule::RangeAware] {
        for s in hard_specs(rule) {
            let r = run_one(&s, &cfg);
            assert_eq!(r.reason, "reached", "{r:?}");
            assert!(r.end_to_target_m <= 0.8 + 0.5, "{r:?}");
        }
    }
}

//! `ima experiment heading [--rule thesis|range-aware|both] [--seed S] [--out DIR] [--json]
//! [--model thesis-robot|estimate-gated] [--set KEY=VALUE]…`:
//! the thesis's heading evaluation in virtual time (`ima_sim::experiment`): θ ∈ {45°, 90°,
//! 135°}, Skeeter–Scooter and Skeeter–target distances 2–5 m, Scooter at 0.05 m/s, the SES
//! refreshed by a full scan every 5 s, scored by f = (d_min/d_actual)·(t_min/t_actual).
//!
//! Prints one table per angle and rule (rows Skeeter–target Dt, columns Skeeter–Scooter Ds)
//! and a summary on stdout — or, with `--json`, one JSON document. With `--out DIR` it also
//! writes `heading.csv`, `heading.json`, `tables.md`, `f.svg` and
//! `trajectories-{45,90,135}.svg` there. A progress bar goes to stderr. `--camera` makes
//! Skeeter see through rendered mock-camera frames and the blob detector instead of the
//! geometric model (slower). `--model` picks the robot model (default: the thesis robot,
//! `ima_sim::experiment::RobotModel`) and each `--set KEY=VALUE` changes one model component
//! after it (an ablation, `SweepConfig::set`; a bad key or value is an error naming the key).

use std::io::{IsTerminal, Write};
use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use ima_agents::mission::scooter::HeadingRule;
use ima_sim::Observer;
use ima_sim::experiment::{
    ANGLES_DEG, RobotModel, SweepConfig, csv, json, markdown_tables, run_sweep_until, summary,
    svg_f, svg_trajectories,
};

/// `ima experiment …`.
#[derive(Debug, Clone, clap::Subcommand)]
pub enum ExperimentCommand {
    /// The thesis's heading sweep (48 configurations per rule), in virtual time.
    Heading(HeadingArgs),
}

/// Which rules to run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum RuleArg {
    /// The thesis's isosceles rule.
    Thesis,
    /// The range-aware rule.
    RangeAware,
    /// Both (96 runs).
    Both,
}

/// Which robot model the sweep simulates.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ModelArg {
    /// The robot the thesis describes: target seen anywhere in view within 2.5 m,
    /// constant speed while turning.
    ThesisRobot,
    /// The first sweep's model: target accepted only near the estimate, within 1.6 m;
    /// turns in place.
    EstimateGated,
}

/// Arguments of `ima experiment heading`.
#[derive(Debug, Clone, clap::Args)]
pub struct HeadingArgs {
    /// Heading rule(s).
    #[arg(long, value_enum, default_value_t = RuleArg::Both)]
    pub rule: RuleArg,
    /// Seed of every noise source (the same seed gives the same results).
    #[arg(long, default_value_t = 1, value_parser = crate::cmd::num::seed)]
    pub seed: u64,
    /// Write CSV, JSON, Markdown tables and SVG plots into this directory.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Print one JSON document on stdout instead of the tables.
    #[arg(long)]
    pub json: bool,
    /// Worker threads.
    #[arg(long, default_value_t = 2, value_parser = super::num::int_in::<usize, 1, 256>)]
    pub threads: usize,
    /// Skeeter sees through rendered camera frames and the blob detector instead of the
    /// (faster) geometric observation model.
    #[arg(long)]
    pub camera: bool,
    /// Robot model.
    #[arg(long, value_enum, default_value_t = ModelArg::ThesisRobot)]
    pub model: ModelArg,
    /// Change one model component, e.g. `recognition=near-estimate`, `see_distance_m=3`,
    /// `turn_in_place=true`, `ses_timing=snapshot`, `scan_period_s=1`, `ideal_sensors=true`,
    /// `avoid=false`, `loop=reference` (the lock-step loop instead of Scooter's runtime),
    /// `control_hz=20` (repeatable; applied in order after --model).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
}

/// Run an experiment command.
///
/// # Errors
/// Output files cannot be written.
pub fn run(cmd: &ExperimentCommand) -> anyhow::Result<()> {
    match cmd {
        ExperimentCommand::Heading(a) => heading(a),
    }
}

fn bar(done: usize, total: usize) -> String {
    let width = 30;
    let filled = (done * width).checked_div(total).unwrap_or(width);
    format!(
        "\r[{}{}] {done}/{total} runs",
        "#".repeat(filled),
        ".".repeat(width - filled)
    )
}

fn heading(a: &HeadingArgs) -> anyhow::Result<()> {
    let rules = match a.rule {
        RuleArg::Thesis => vec![HeadingRule::Thesis],
        RuleArg::RangeAware => vec![HeadingRule::RangeAware],
        RuleArg::Both => vec![HeadingRule::Thesis, HeadingRule::RangeAware],
    };
    let model = match a.model {
        ModelArg::ThesisRobot => RobotModel::ThesisRobot,
        ModelArg::EstimateGated => RobotModel::EstimateGated,
    };
    let mut cfg = SweepConfig {
        rules,
        seed: a.seed,
        threads: a.threads.max(1),
        ..SweepConfig::for_model(model)
    };
    for pair in &a.set {
        cfg.set_pair(pair)?;
    }
    if a.camera {
        cfg.sim.observer = Observer::Camera;
    }
    if let Some(dir) = &a.out {
        crate::cmd::output::check_dir("--out", dir)?;
    }
    let tty = std::io::stderr().is_terminal();
    let started = Instant::now();
    let progress = |done: usize, total: usize| {
        // On a terminal the bar redraws in place; otherwise one line per quarter.
        if tty || done == total || (total >= 4 && done.is_multiple_of(total / 4)) {
            // Through the log thread, in order with the messages before it; a closed stderr
            // does not end the sweep (its results go to stdout).
            if tty {
                crate::safety::progress(format_args!("{}", bar(done, total)));
            } else {
                crate::safety::progress(format_args!("{}\n", bar(done, total)));
            }
        }
    };
    // Ctrl-C (or any signal) ends the sweep after the runs under way, at once rather than at
    // the signal's 3 s grace period, with nothing written: a partial sweep's tables would
    // read as the whole.
    let results = run_sweep_until(&cfg, &progress, &crate::safety::asked_to_end);
    let elapsed = started.elapsed().as_secs_f64();
    if tty {
        eprintln!();
    }
    if crate::safety::asked_to_end() {
        eprintln!(
            "{} runs done in {elapsed:.1} s when the sweep was interrupted; nothing written",
            results.len()
        );
        return Err(crate::safety::Interrupted(crate::safety::cause()).into());
    }
    eprintln!("{} runs in {elapsed:.1} s", results.len());
    let mut tables = String::new();
    for rule in ["thesis", "range-aware"] {
        if results.iter().any(|r| r.rule == rule) {
            tables.push_str(&markdown_tables(&results, rule));
        }
    }
    let doc = json(&results, &cfg);
    // The results go to stdout first: a failed file write loses no result.
    {
        let stdout = std::io::stdout();
        let mut out = stdout.lock();
        if a.json {
            writeln!(out, "{doc}")?;
        } else {
            write!(out, "{tables}{}", summary(&results))?;
        }
        out.flush()?;
    }
    if let Some(dir) = &a.out {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("--out {}: creating it", dir.display()))?;
        let write = |name: &str, text: &str| -> anyhow::Result<()> {
            let p = dir.join(name);
            std::fs::write(&p, text).with_context(|| format!("--out: writing {}", p.display()))
        };
        write("heading.csv", &csv(&results))?;
        write("heading.json", &format!("{doc:#}\n"))?;
        write("tables.md", &format!("{tables}{}", summary(&results)))?;
        write("f.svg", &svg_f(&results))?;
        for angle in ANGLES_DEG {
            write(
                &format!("trajectories-{angle:.0}.svg"),
                &svg_trajectories(&results, angle),
            )?;
        }
        eprintln!("wrote {}", dir.display());
    }
    Ok(())
}

//! The ablation table of the heading sweep (`docs/experiment/ablations.md`): each row runs
//! all 96 configurations with one model component changed
//! (`ima_sim::experiment::ablations`):
//! `cargo run --release -p ima-sim --example heading_ablation [-- OUT.md]`.

use std::fmt::Write as _;

use ima_sim::experiment::{SweepConfig, ablations, rule_stats, run_sweep};

fn main() {
    let mut md = String::from(
        "# Heading sweep ablations (seed 1)\n\n\
         Each row runs the 96 configurations (48 per rule) of `ima experiment heading` with the \
         model named and the settings listed (`ima experiment heading --model … --set …` \
         reproduces any row). `estimate-gated` is the first sweep's model, `thesis-robot` the \
         default; rows starting with … change one component of the model above them. \
         Made by `cargo run --release -p ima-sim --example heading_ablation -- \
         docs/experiment/ablations.md`; see `ima_sim::experiment`, \"The thesis robot\".\n\n\
         | model / ablation | settings (`--set`) | thesis: reached | min f | mean f | f < 0.1 | range-aware: reached | min f | mean f |\n\
         |---|---|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    for a in ablations() {
        let mut cfg = SweepConfig::for_model(a.model);
        for s in a.settings {
            if let Err(e) = cfg.set_pair(s) {
                eprintln!("{}: {e}", a.name);
                std::process::exit(2);
            }
        }
        let results = run_sweep(&cfg, &|_, _| {});
        let t = rule_stats(&results, "thesis");
        let r = rule_stats(&results, "range-aware");
        let settings = if a.settings.is_empty() {
            format!("`--model {}`", a.model.as_str())
        } else {
            a.settings
                .iter()
                .map(|s| format!("`{s}`"))
                .collect::<Vec<_>>()
                .join(" ")
        };
        let _ = writeln!(
            md,
            "| {} | {settings} | {}/{} | {:.3} | {:.3} | {} | {}/{} | {:.3} | {:.3} |",
            a.name,
            t.reached,
            t.runs,
            t.min_f,
            t.mean_f,
            t.below_0_1,
            r.reached,
            r.runs,
            r.min_f,
            r.mean_f
        );
        eprintln!("{}", md.lines().last().unwrap_or_default());
    }
    match std::env::args().nth(1) {
        Some(path) => {
            if let Err(e) = std::fs::write(&path, &md) {
                eprintln!("writing {path}: {e}");
                std::process::exit(1);
            }
        }
        None => print!("{md}"),
    }
}

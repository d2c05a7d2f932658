//! `ima san simulate FILE.toml [--state a,b] [--goals x,y] [--steps N]`: run a spreading
//! activation network (format: `ima_agents::san::spec`) in closed-world simulation — each
//! fired module's add/delete lists are applied to the state — and print one JSON object per
//! step on stdout:
//!
//! ```json
//! {"step":1,"threshold":45.0,"modules":[{"name":"pick-up-sprayer","activation":17.4,"executable":true},…],
//!  "fired":null,"next_threshold":40.5,"state":["hand-is-empty","hand-is-empty",…],
//!  "goals":["board-sanded","self-painted"],"protected":[]}
//! ```
//!
//! `threshold` is the θ the selection used, `next_threshold` θ after the step; `state` lists
//! the true propositions (repeated per instance), `goals` the goals still false and
//! `protected` the goals already true.

use std::io::Write;
use std::path::PathBuf;

use anyhow::Context;
use ima_agents::san::Network;

/// Arguments of `ima san simulate`.
#[derive(Debug, Clone, clap::Args)]
pub struct SanSimulateArgs {
    /// Network description (TOML).
    pub file: PathBuf,
    /// Initial state: comma-separated true propositions, replacing the file's initial values
    /// (repeat a name to give a counter several instances).
    #[arg(long, value_delimiter = ',')]
    pub state: Option<Vec<String>>,
    /// Goals, comma-separated, replacing the file's goals.
    #[arg(long, value_delimiter = ',')]
    pub goals: Option<Vec<String>>,
    /// Number of steps to run, 1–1000000.
    #[arg(long, default_value_t = 20, value_parser = super::num::int_in::<u64, 1, 1_000_000>)]
    pub steps: u64,
}

/// Run `ima san simulate`, writing to stdout.
///
/// # Errors
/// The file cannot be read or is not a valid network, or a name in `--state`/`--goals` is
/// not a condition of it.
pub fn run(args: &SanSimulateArgs) -> anyhow::Result<()> {
    let stdout = std::io::stdout();
    let mut out = stdout.lock();
    run_to(args, &mut out)
}

/// Run `ima san simulate`, writing the JSON lines to `out`.
///
/// # Errors
/// As [`run`], plus write errors.
pub fn run_to(args: &SanSimulateArgs, out: &mut impl Write) -> anyhow::Result<()> {
    let text = ima_hal::file::read_text(&args.file)
        .with_context(|| format!("reading {}", args.file.display()))?;
    let mut net =
        Network::from_toml(&text).with_context(|| format!("loading {}", args.file.display()))?;
    let names = |v: &Vec<String>| -> Vec<String> {
        v.iter()
            .map(|s| s.trim().to_owned())
            .filter(|s| !s.is_empty())
            .collect()
    };
    if let Some(s) = &args.state {
        net.set_state(&names(s)).context("--state")?;
    }
    if let Some(g) = &args.goals {
        net.set_goals(&names(g)).context("--goals")?;
    }
    for _ in 0..args.steps {
        let trace = net.simulate_step();
        // As an I/O error, so a closed stdout ends the command as one (status 141, quietly).
        serde_json::to_writer(&mut *out, &trace).map_err(std::io::Error::from)?;
        out.write_all(b"\n")?;
    }
    out.flush()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn toy() -> PathBuf {
        PathBuf::from(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/agents/networks/maes_toy.toml"
        ))
    }

    fn lines(args: &SanSimulateArgs) -> Vec<serde_json::Value> {
        let mut out = Vec::new();
        run_to(args, &mut out).unwrap();
        String::from_utf8(out)
            .unwrap()
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .collect()
    }

    #[test]
    fn one_json_line_per_step_with_the_toy_sequence() {
        let args = SanSimulateArgs {
            file: toy(),
            state: None,
            goals: None,
            steps: 20,
        };
        let v = lines(&args);
        assert_eq!(v.len(), 20);
        assert_eq!(v[0]["step"], 1);
        assert_eq!(v[0]["threshold"], 45.0);
        let fired: Vec<&str> = v.iter().filter_map(|l| l["fired"].as_str()).collect();
        assert_eq!(
            fired,
            [
                "pick-up-sander",
                "pick-up-board",
                "sand-board-in-hand",
                "place-board-in-vise",
                "pick-up-sprayer",
                "spray-paint-self"
            ]
        );
        assert_eq!(
            v[19]["protected"],
            serde_json::json!(["board-sanded", "self-painted"])
        );
    }

    #[test]
    fn state_and_goals_override_the_file() {
        let args = SanSimulateArgs {
            file: toy(),
            state: Some(vec!["sprayer-in-hand".into(), "operational".into()]),
            goals: Some(vec!["self-painted".into()]),
            steps: 5,
        };
        let v = lines(&args);
        assert_eq!(v[0]["fired"], "spray-paint-self");
        assert_eq!(v[0]["goals"], serde_json::json!([]));
        assert_eq!(v[0]["protected"], serde_json::json!(["self-painted"]));
        let bad = SanSimulateArgs {
            state: Some(vec!["nope".into()]),
            ..args
        };
        assert!(run_to(&bad, &mut Vec::new()).is_err());
    }
}

//! `ima commander --config FILE --targets red,blue,green`: send targets one at a time over the
//! broadcast channel, show each target's state and the robots' broadcasts live.

use std::io::Write;
use std::path::PathBuf;
use std::time::Duration;

use anyhow::{Context, Result};
use clap::Args;

use crate::config::RobotConfig;
use crate::stack::commander::TargetState;
use crate::stack::{Event, Events, net};

/// Arguments of `ima commander`.
#[derive(Debug, Args)]
pub struct CommanderArgs {
    /// Configuration file (role `commander`; see `configs/commander.toml`).
    #[arg(long)]
    config: PathBuf,
    /// Target colours, in order.
    #[arg(long, value_delimiter = ',', default_value = "red,blue,green")]
    targets: Vec<String>,
    /// Robots to hear on the broadcast channel before the first target is sent.
    #[arg(long, value_delimiter = ',', default_value = "skeeter,scooter")]
    wait_for: Vec<String>,
    /// Longest wait for them, seconds (then the targets go anyway).
    #[arg(long, default_value_t = 60.0)]
    wait_timeout: f64,
    /// One JSON object per line instead of text.
    #[arg(long)]
    json: bool,
    /// Use the documented insecure all-zero key when the configuration names no key file.
    #[arg(long)]
    insecure: bool,
}

/// Print one event as a line of text or JSON.
pub fn print_event(e: &Event, json: bool) {
    let mut out = std::io::stdout().lock();
    let line = if json {
        serde_json::to_string(e).unwrap_or_default()
    } else {
        let d = &e.detail;
        match e.kind.as_str() {
            "target" => format!(
                "[{:7.1}s] target {:<8} {}",
                e.t_s,
                d["target"].as_str().unwrap_or("?"),
                d["state"].as_str().unwrap_or("?")
            ),
            "broadcast" => format!(
                "[{:7.1}s]   {} {}: {}",
                e.t_s,
                d["type"].as_str().unwrap_or(""),
                d["robot"].as_str().unwrap_or("?"),
                match d["type"].as_str() {
                    Some("status") => d["behaviour"].as_str().unwrap_or("").to_owned(),
                    Some("emergency") => format!(
                        "{} {}",
                        d["kind"].as_str().unwrap_or(""),
                        d["text"].as_str().unwrap_or("")
                    ),
                    _ => format!(
                        "{} {}",
                        d["event"].as_str().unwrap_or(""),
                        d["target"].as_str().unwrap_or("")
                    ),
                }
            ),
            _ => format!("[{:7.1}s] {} {} {}", e.t_s, e.robot, e.kind, d),
        }
    };
    let _ = writeln!(out, "{line}");
    let _ = out.flush();
}

/// Run `ima commander`.
pub fn run(args: &CommanderArgs) -> Result<()> {
    let mut cfg = RobotConfig::load(&args.config)?;
    if args.insecure && cfg.peer.key_file.is_none() {
        cfg.peer.insecure = true;
    }
    anyhow::ensure!(!args.targets.is_empty(), "--targets is empty");
    // Skeeter can only find colours of its database (the configuration's, or the built-in).
    let known: Vec<String> = crate::stack::skeeter::colour_db(&cfg)?
        .colours
        .into_iter()
        .map(|c| c.name)
        .filter(|n| n != ima_agents::mission::msg::SCOOTER_TAG)
        .collect();
    super::check_colours(&args.targets, &known, "the colour database's colours")?;
    let rt = tokio::runtime::Runtime::new()?;
    let outcomes = rt.block_on(async {
        let key = net::group_key(&cfg, None)?;
        let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel::<Event>();
        let json = args.json;
        let printer = tokio::spawn(async move {
            // Text mode: a robot's status is shown when its behaviour changes, not every second.
            let mut last: std::collections::BTreeMap<String, String> = Default::default();
            while let Some(e) = rx.recv().await {
                if !json && e.kind == "broadcast" && e.detail["type"] == "status" {
                    let robot = e.detail["robot"].as_str().unwrap_or("").to_owned();
                    let b = e.detail["behaviour"].as_str().unwrap_or("").to_owned();
                    if last.get(&robot) == Some(&b) {
                        continue;
                    }
                    last.insert(robot, b);
                }
                print_event(&e, json);
            }
        });
        let wait = Duration::try_from_secs_f64(args.wait_timeout.max(0.0)).unwrap_or_default();
        let r = crate::stack::commander::run(
            &cfg,
            key,
            &args.targets,
            (&args.wait_for, wait),
            Events::with_sink(tx),
        )
        .await
        .context("commanding");
        let _ = printer.await;
        r
    })?;
    let done = outcomes
        .iter()
        .filter(|o| o.state == TargetState::Done)
        .count();
    let failed = outcomes.len() - done;
    if args.json {
        println!(
            "{}",
            serde_json::json!({"kind": "summary", "done": done, "failed": failed, "targets": outcomes})
        );
    } else {
        println!("{done} target(s) done, {failed} failed");
    }
    anyhow::ensure!(failed == 0, "{failed} target(s) failed");
    Ok(())
}

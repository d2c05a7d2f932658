//! `ima commander --config FILE --targets red,blue,green`: send targets one at a time over the
//! broadcast channel, show each target's state, the robots' broadcasts and whether each
//! robot is alive, live; take `stop`, `resume` and `cancel COLOUR` requests on stdin.
//! `ima commander stop|resume|cancel --config FILE`: one fleet command, sent several times.

use std::io::{BufRead, IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use ima_agents::mission::msg::{Broadcast, COMMANDER, Emergency, FLEET_COPIES};

use crate::config::RobotConfig;
use ima_agents::runtime::commander::{Operator, TargetState};
use ima_agents::runtime::events::BroadcastView;

use crate::stack::{EVENT_QUEUE, Event, EventKind, Events, net};

/// Arguments of `ima commander`.
///
/// While it runs, lines typed on its stdin are requests: `stop [reason]` (fleet stop),
/// `resume`, `cancel COLOUR`. On Ctrl-C it sends a fleet stop first with `--stop-on-exit`;
/// without it, it asks on a terminal and leaves the robots running when stdin is not one.
#[derive(Debug, Args)]
#[command(
    args_conflicts_with_subcommands = true,
    after_help = "While it runs, type a request and Enter: `stop [reason]` (fleet stop), `resume`, \
                  `cancel COLOUR`.\nCtrl-C: with --stop-on-exit a fleet stop goes out first; \
                  otherwise it asks on a terminal, and leaves the robots running when stdin is \
                  not one.\nEach robot is reported lost after --lost-after seconds of silence."
)]
pub struct CommanderArgs {
    /// One-shot commands to the fleet (instead of running a series of targets).
    #[command(subcommand)]
    action: Option<Action>,
    /// Configuration file (role `commander`; see `configs/commander.toml`).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Target colours, in order.
    #[arg(long, value_delimiter = ',', default_value = "red,blue,green")]
    targets: Vec<String>,
    /// Robots to hear on the broadcast channel before the first target is sent.
    #[arg(long, value_delimiter = ',', default_value = "skeeter,scooter")]
    wait_for: Vec<String>,
    /// Longest wait for them, seconds, 0–86400 (then the targets go anyway).
    #[arg(long, default_value_t = 60.0, value_parser = super::num::seconds)]
    wait_timeout: f64,
    /// Report a robot lost after this many (mission) seconds without a broadcast from it,
    /// 0.1–3600 (overrides `agent.robot_lost_after_s`, default 5).
    #[arg(long, value_parser = super::num::period_seconds)]
    lost_after: Option<f64>,
    /// On Ctrl-C, send a fleet stop before exiting (without it the commander asks on a
    /// terminal, and does not stop the robots when stdin is not one).
    #[arg(long)]
    stop_on_exit: bool,
    /// One JSON object per line instead of text.
    #[arg(long)]
    json: bool,
    /// Use the documented insecure all-zero key when the configuration names no key file.
    #[arg(long)]
    insecure: bool,
    /// Serve the commander console in the browser on ADDR (default 127.0.0.1:8080; port 0
    /// picks a free one). With it the commander keeps running when every target is final
    /// (more can be added from the page) until Ctrl-C.
    #[command(flatten)]
    web: super::WebArgs,
}

/// `ima commander stop|resume|cancel`: one command to the fleet, sent several times.
#[derive(Debug, Subcommand)]
pub enum Action {
    /// Fleet stop: every robot zeroes its velocity at once and holds until `resume` or a
    /// new target.
    Stop {
        #[command(flatten)]
        common: OneShot,
        /// Why (shown by the robots).
        #[arg(long, default_value = "operator")]
        reason: String,
    },
    /// Fleet resume: the robots carry on with their targets.
    Resume {
        #[command(flatten)]
        common: OneShot,
    },
    /// Withdraw a target: Skeeter ends it as failed, Scooter stops pursuing it, a running
    /// commander marks it cancelled and goes on with the next.
    Cancel {
        #[command(flatten)]
        common: OneShot,
        /// The target colour.
        #[arg(long)]
        target: String,
    },
}

/// Options of the one-shot commands.
#[derive(Debug, Args)]
pub struct OneShot {
    /// Configuration file (role `commander`).
    #[arg(long)]
    config: PathBuf,
    /// Use the documented insecure all-zero key when the configuration names no key file.
    #[arg(long)]
    insecure: bool,
    /// One JSON object instead of text.
    #[arg(long)]
    json: bool,
}

fn load(config: &Path, insecure: bool) -> Result<RobotConfig> {
    let mut cfg = RobotConfig::load(config)?;
    if insecure && cfg.peer.key_file.is_none() {
        cfg.peer.insecure = true;
    }
    Ok(cfg)
}

fn one_shot(action: &Action) -> Result<()> {
    let (common, b, what) = match action {
        Action::Stop { common, reason } => (
            common,
            Broadcast::emergency(
                COMMANDER,
                Emergency::FleetStop {
                    reason: reason.clone(),
                },
            ),
            "fleet stop",
        ),
        Action::Resume { common } => (
            common,
            Broadcast::emergency(COMMANDER, Emergency::FleetResume),
            "fleet resume",
        ),
        Action::Cancel { common, target } => (
            common,
            Broadcast::emergency(
                COMMANDER,
                Emergency::TargetCancel {
                    colour: target.clone(),
                },
            ),
            "target cancel",
        ),
    };
    if let Broadcast::Emergency { emergency, .. } = &b {
        // A colour with spaces would not decode at the robots.
        Emergency::from_kind_text(emergency.kind(), &emergency.text())
            .map_err(|e| anyhow::anyhow!("{what}: {e}"))?;
    }
    let cfg = load(&common.config, common.insecure)?;
    let rt = tokio::runtime::Runtime::new()?;
    let n = rt.block_on(async {
        let key = net::group_key(&cfg, None)?;
        crate::stack::commander::send_once(&cfg, key, &b).await
    })?;
    anyhow::ensure!(n > 0, "the {what} reached no destination");
    if common.json {
        crate::safety::out_line(format_args!(
            "{}",
            serde_json::json!({"kind": "sent", "command": what, "copies": FLEET_COPIES, "destinations": n})
        ))
    } else {
        crate::safety::out_line(format_args!(
            "{what} sent ({FLEET_COPIES} copies to {n} destination(s))"
        ))
    }
}

/// A line typed on the commander's stdin as a request (`None` and a hint when unknown).
fn parse_request(line: &str) -> Result<Option<Operator>, String> {
    let mut words = line.split_whitespace();
    let Some(verb) = words.next() else {
        return Ok(None);
    };
    let rest: Vec<&str> = words.collect();
    match (verb, rest.as_slice()) {
        ("stop", r) => Ok(Some(Operator::Stop(if r.is_empty() {
            "operator".to_owned()
        } else {
            r.join(" ")
        }))),
        ("resume", []) => Ok(Some(Operator::Resume)),
        ("cancel", [colour]) => Ok(Some(Operator::Cancel((*colour).to_owned()))),
        _ => Err(format!(
            "unknown request {line:?}: type `stop [reason]`, `resume` or `cancel COLOUR`"
        )),
    }
}

/// Reads stdin lines on a thread of their own (stdin blocks; the thread ends with the
/// process).
fn stdin_lines() -> tokio::sync::mpsc::UnboundedReceiver<String> {
    let (tx, rx) = tokio::sync::mpsc::unbounded_channel();
    std::thread::spawn(move || {
        for line in std::io::stdin().lock().lines() {
            let Ok(line) = line else { return };
            if tx.send(line).is_err() {
                return;
            }
        }
    });
    rx
}

/// The next stdin line; `None` at its end; never, once ended (`lines` is `None`).
async fn next_line(
    lines: &mut Option<tokio::sync::mpsc::UnboundedReceiver<String>>,
) -> Option<String> {
    match lines.as_mut() {
        Some(rx) => rx.recv().await,
        None => std::future::pending().await,
    }
}

/// Turns stdin lines and Ctrl-C into [`Operator`] requests until a quit is sent.
async fn operator(
    ops: tokio::sync::mpsc::UnboundedSender<Operator>,
    stop_on_exit: bool,
    mut interrupt: impl AsyncInterrupt,
) {
    let tty = std::io::stdin().is_terminal();
    let mut lines = Some(stdin_lines());
    loop {
        tokio::select! {
            () = interrupt.next() => break,
            // SIGTERM, SIGHUP, or a closed stdout (see `crate::safety`).
            () = crate::safety::cancelled() => break,
            l = next_line(&mut lines) => match l {
                None => lines = None,
                Some(l) => match parse_request(&l) {
                    Ok(Some(op)) => {
                        if ops.send(op).is_err() {
                            return;
                        }
                    }
                    Ok(None) => {}
                    Err(hint) => eprintln!("ima commander: {hint}"),
                },
            },
        }
    }
    let stop = if stop_on_exit {
        eprintln!("ima commander: interrupted: sending a fleet stop (--stop-on-exit)");
        true
    } else if !tty {
        eprintln!(
            "ima commander: interrupted; stdin is not a terminal, so the robots were NOT \
             stopped (pass --stop-on-exit, or run `ima commander stop`)"
        );
        false
    } else {
        eprint!("stop the robots? [y/N] ");
        let answer = tokio::select! {
            l = next_line(&mut lines) => l,
            () = interrupt.next() => None,
        };
        let yes = answer.is_some_and(|a| matches!(a.trim(), "y" | "Y" | "yes" | "YES" | "Yes"));
        if yes {
            eprintln!("ima commander: sending a fleet stop");
        } else {
            eprintln!("ima commander: the robots were NOT stopped");
        }
        yes
    };
    let _ = ops.send(Operator::Quit { stop });
}

/// The operator's interrupt (Ctrl-C), registered before the commander starts so that an
/// early Ctrl-C is not lost to the default handler.
trait AsyncInterrupt {
    /// Waits for the next interrupt.
    fn next(&mut self) -> impl std::future::Future<Output = ()> + Send;
}

#[cfg(unix)]
impl AsyncInterrupt for tokio::signal::unix::Signal {
    async fn next(&mut self) {
        if self.recv().await.is_none() {
            std::future::pending::<()>().await;
        }
    }
}

#[cfg(not(unix))]
struct CtrlC;

#[cfg(not(unix))]
impl AsyncInterrupt for CtrlC {
    async fn next(&mut self) {
        if tokio::signal::ctrl_c().await.is_err() {
            std::future::pending::<()>().await;
        }
    }
}

/// Print one event as a line of text or JSON; false when standard output is gone.
pub fn print_event(e: &Event, json: bool) -> bool {
    // Refused frames are a warning for the operator, on stderr in either mode.
    if let EventKind::AuthFailure(text) = &e.kind {
        eprintln!("ima: warning: {text}");
        return true;
    }
    let mut out = std::io::stdout().lock();
    let line = if json {
        serde_json::to_string(e).unwrap_or_default()
    } else {
        let v = serde_json::to_value(e).unwrap_or_default();
        let d = &v["detail"];
        match e.name() {
            "target" => format!(
                "[{:7.1}s] target {:<8} {}{}",
                e.t_s,
                d["target"].as_str().unwrap_or("?"),
                d["state"].as_str().unwrap_or("?"),
                if d["cancelled"] == true {
                    " (cancelled)"
                } else {
                    ""
                }
            ),
            "robot" => {
                let robot = d["robot"].as_str().unwrap_or("?");
                let silent = d["silent_s"].as_f64().unwrap_or(0.0);
                match d["state"].as_str() {
                    Some("lost") => format!(
                        "[{:7.1}s] robot {robot} LOST: nothing heard for {silent:.1} s",
                        e.t_s
                    ),
                    _ if silent > 0.0 => format!(
                        "[{:7.1}s] robot {robot} is back (silent for {silent:.1} s)",
                        e.t_s
                    ),
                    _ => format!("[{:7.1}s] robot {robot} alive", e.t_s),
                }
            }
            "fleet" => format!(
                "[{:7.1}s] fleet {} sent",
                e.t_s,
                d["command"].as_str().unwrap_or("?")
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
            _ => format!("[{:7.1}s] {} {} {}", e.t_s, e.robot, e.name(), d),
        }
    };
    writeln!(out, "{line}").and_then(|()| out.flush()).is_ok()
}

/// Run `ima commander`.
pub fn run(args: &CommanderArgs) -> Result<()> {
    if let Some(a) = &args.action {
        return one_shot(a);
    }
    let Some(config) = &args.config else {
        anyhow::bail!(
            "--config is required (a commander configuration, see configs/commander.toml)"
        );
    };
    args.web.check()?;
    let mut cfg = load(config, args.insecure)?;
    if let Some(s) = args.lost_after {
        anyhow::ensure!(
            s.is_finite() && (0.1..=3600.0).contains(&s),
            "--lost-after must be a number of seconds in [0.1, 3600], not {s}"
        );
        cfg.agent.robot_lost_after_s = s;
    }
    anyhow::ensure!(!args.targets.is_empty(), "--targets is empty");
    // Ctrl-C is the operator's: it may ask whether to stop the robots.
    crate::safety::answers_ctrl_c_itself();
    // Skeeter can only find colours of its database (the configuration's, or the built-in).
    let known: Vec<String> = crate::stack::skeeter::colour_db(&cfg)?
        .colours
        .into_iter()
        .map(|c| c.name)
        .filter(|n| n != ima_agents::mission::msg::SCOOTER_TAG)
        .collect();
    super::check_colours(&args.targets, &known, "the colour database's colours")?;
    let rt = tokio::runtime::Runtime::new()?;
    let finished = rt.block_on(async {
        let key = net::group_key(&cfg, None)?;
        #[cfg(unix)]
        let interrupt = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::interrupt())
            .context("installing the Ctrl-C handler")?;
        #[cfg(not(unix))]
        let interrupt = CtrlC;
        let (op_tx, op_rx) = tokio::sync::mpsc::unbounded_channel();
        // web console (issue 17): the page's commands join the operator's requests.
        let web = args
            .web
            .start("commander", known.clone(), Some(op_tx.clone()))?;
        let console = web.as_ref().map(|(c, _)| Arc::clone(c));
        let op_task = tokio::spawn(operator(op_tx, args.stop_on_exit, interrupt));
        let (events, mut rx) = Events::channel(EVENT_QUEUE);
        let events = events.detailed(web.is_some());
        let json = args.json;
        let printer = tokio::spawn(async move {
            // Text mode: a robot's status is shown when its behaviour changes, not every second.
            let mut last: std::collections::BTreeMap<String, String> = Default::default();
            while let Some(e) = rx.recv().await {
                if let Some(c) = &console {
                    c.apply(&e);
                }
                if !json && crate::web::DETAIL_KINDS.contains(&e.name()) {
                    continue;
                }
                if !json
                    && let EventKind::Broadcast(BroadcastView::Status {
                        robot, behaviour, ..
                    }) = &e.kind
                {
                    if last.get(robot) == Some(behaviour) {
                        continue;
                    }
                    last.insert(robot.clone(), behaviour.clone());
                }
                if !print_event(&e, json) {
                    // Nobody reads any more: end the commander as an interruption would.
                    crate::safety::output_closed();
                    break;
                }
            }
            crate::stack::report_dropped(rx.dropped());
        });
        let wait = Duration::try_from_secs_f64(args.wait_timeout.max(0.0)).unwrap_or_default();
        let rt = crate::stack::commander::runtime_config(
            &cfg,
            (&args.wait_for, wait),
            Some(Duration::from_secs_f64(cfg.agent.robot_lost_after_s)),
        );
        let rt = ima_agents::runtime::commander::CommanderRuntimeConfig {
            // web console (issue 17): more targets may be added from the page.
            keep_running: web.is_some(),
            ..rt
        };
        let r = async {
            // The process's one clock.
            let clock = ima_hal::time::TokioClock::shared();
            let bus = net::bus(&cfg, key, clock.clone())?;
            Ok::<_, anyhow::Error>(
                ima_agents::runtime::commander::run(
                    rt,
                    &args.targets,
                    bus,
                    clock,
                    events,
                    Some(op_rx),
                )
                .await?,
            )
        }
        .await
        .context("commanding");
        op_task.abort();
        let _ = printer.await;
        if let Some((c, _server)) = &web {
            c.close_commands();
        }
        r
    })?;
    let outcomes = &finished.outcomes;
    let done = outcomes
        .iter()
        .filter(|o| o.state == TargetState::Done)
        .count();
    let failed = outcomes.len() - done;
    if crate::safety::cause() == crate::safety::Cause::OutputClosed {
        return Err(crate::safety::Interrupted(crate::safety::Cause::OutputClosed).into());
    }
    if args.json {
        crate::safety::out_line(format_args!(
            "{}",
            serde_json::json!({"kind": "summary", "done": done, "failed": failed,
                "interrupted": finished.interrupted.is_some(),
                "fleet_stopped": finished.interrupted == Some(true), "targets": outcomes})
        ))?;
    } else {
        crate::safety::out_line(format_args!("{done} target(s) done, {failed} failed"))?;
    }
    match finished.interrupted {
        Some(true) => anyhow::bail!("interrupted; a fleet stop was sent"),
        Some(false) => anyhow::bail!("interrupted; the robots were NOT stopped"),
        None => {}
    }
    anyhow::ensure!(failed == 0, "{failed} target(s) failed");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn typed_requests_parse_and_others_get_a_hint() {
        assert_eq!(
            parse_request("stop"),
            Ok(Some(Operator::Stop("operator".into())))
        );
        assert_eq!(
            parse_request(" stop  rock ahead "),
            Ok(Some(Operator::Stop("rock ahead".into())))
        );
        assert_eq!(parse_request("resume"), Ok(Some(Operator::Resume)));
        assert_eq!(
            parse_request("cancel red"),
            Ok(Some(Operator::Cancel("red".into())))
        );
        assert_eq!(parse_request("   "), Ok(None));
        for bad in ["cancel", "cancel dark red", "resume now", "go"] {
            assert!(
                parse_request(bad).unwrap_err().contains("cancel COLOUR"),
                "{bad}"
            );
        }
    }
}

//! `ima commander --config FILE --targets red,blue,green`: send targets one at a time over the
//! broadcast channel, show each target's state, the robots' broadcasts and whether each
//! robot is alive, live; take `stop`, `resume`, `cancel COLOUR`, `add COLOUR [at N]` and
//! `move COLOUR N` requests on stdin (checked as the web console checks its commands, and
//! carried out through the same [`Operator`] requests).
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
/// `resume`, `cancel COLOUR`, `add COLOUR [at N]`, `move COLOUR N` (positions from 1, as the
/// `series` lines show them). On Ctrl-C it sends a fleet stop first with `--stop-on-exit`;
/// without it, it asks on a terminal and leaves the robots running when stdin is not one.
#[derive(Debug, Args)]
#[command(
    args_conflicts_with_subcommands = true,
    subcommand_negates_reqs = true,
    after_help = "While it runs, type a request and Enter: `stop [reason]` (fleet stop), `resume`, \
                  `cancel COLOUR`, `add COLOUR [at N]` (append, or insert at position N), \
                  `move COLOUR N` (a waiting target to position N; positions from 1).\nCtrl-C: with --stop-on-exit a fleet stop goes out first; \
                  otherwise it asks on a terminal, and leaves the robots running when stdin is \
                  not one.\nEach robot is reported lost after --lost-after seconds of silence."
)]
pub struct CommanderArgs {
    /// One-shot commands to the fleet (instead of running a series of targets).
    #[command(subcommand)]
    action: Option<Action>,
    /// Configuration file (role `commander`; see `configs/commander.toml`).
    #[arg(long, required = true)]
    config: Option<PathBuf>,
    /// Target colours, in order.
    #[arg(long, value_delimiter = ',', default_value = "red,blue,green", value_parser = super::num::target_colour)]
    targets: Vec<String>,
    /// Robots to hear on the broadcast channel before the first target is sent
    /// (`--wait-timeout 0`: send at once).
    #[arg(long, value_delimiter = ',', default_value = "skeeter,scooter", value_parser = super::num::robot_name)]
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
        /// Why (shown by the robots; at most 255 bytes, what a broadcast carries).
        #[arg(long, default_value = "operator", value_parser = super::num::wire_text)]
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
    RobotConfig::load_with(config, insecure)
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
    // A colour the robots cannot know would be sent, reach them and change nothing: refuse it
    // here, as the running commander's `cancel` does.
    if let Action::Cancel { target, .. } = action {
        super::check_colours(
            std::slice::from_ref(target),
            &known_colours(&cfg)?,
            "the colour database's colours",
        )?;
    }
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

/// The target colours Skeeter can find: its colour database's (the configuration's, or the
/// built-in), without Scooter's own tag.
fn known_colours(cfg: &RobotConfig) -> Result<Vec<String>> {
    Ok(crate::stack::skeeter::colour_db(cfg)?
        .colours
        .into_iter()
        .map(|c| c.name)
        .filter(|n| n != ima_agents::mission::msg::SCOOTER_TAG)
        .collect())
}

/// A request typed on the commander's stdin, before it is checked against the series.
#[derive(Debug, Clone, PartialEq, Eq)]
enum Typed {
    /// `stop [reason]`.
    Stop(Option<String>),
    /// `resume`.
    Resume,
    /// `cancel COLOUR`.
    Cancel(String),
    /// `add COLOUR [at N]` (N from 1).
    Add { colour: String, at: Option<usize> },
    /// `move COLOUR N` (N from 1).
    Move { colour: String, to: usize },
}

const GRAMMAR: &str = "type `stop [reason]`, `resume`, `cancel COLOUR`, `add COLOUR [at N]` or \
                       `move COLOUR N` (positions from 1)";

/// A position typed by a person (from 1).
fn position(word: &str) -> Result<usize, String> {
    match word.parse::<usize>() {
        Ok(n) if n >= 1 => Ok(n),
        _ => Err(format!(
            "{word:?} is not a position: positions count from 1 (the `series` lines show them)"
        )),
    }
}

/// A line typed on the commander's stdin as a request (`None` for a blank line; a hint
/// when it is not one).
fn parse_request(line: &str) -> Result<Option<Typed>, String> {
    let mut words = line.split_whitespace();
    let Some(verb) = words.next() else {
        return Ok(None);
    };
    let rest: Vec<&str> = words.collect();
    let c = |w: &str| w.to_owned();
    match (verb, rest.as_slice()) {
        ("stop", r) => Ok(Some(Typed::Stop((!r.is_empty()).then(|| r.join(" "))))),
        ("resume", []) => Ok(Some(Typed::Resume)),
        ("cancel", [colour]) => Ok(Some(Typed::Cancel(c(colour)))),
        ("add", [colour]) => Ok(Some(Typed::Add {
            colour: c(colour),
            at: None,
        })),
        ("add", [colour, "at", n]) => Ok(Some(Typed::Add {
            colour: c(colour),
            at: Some(position(n)?),
        })),
        ("move", [colour, n]) => Ok(Some(Typed::Move {
            colour: c(colour),
            to: position(n)?,
        })),
        ("help" | "?", []) => Err(format!("requests: {GRAMMAR}")),
        _ => Err(format!("unknown request {line:?}: {GRAMMAR}")),
    }
}

/// The series as the stdin requests see it: each target's colour and state, in order (from
/// the commander's `queue` events, plus the targets added since).
type SeriesView = Arc<std::sync::Mutex<Vec<(String, String)>>>;

fn view(v: &SeriesView) -> std::sync::MutexGuard<'_, Vec<(String, String)>> {
    v.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// Checks a typed request against the colours the robots know and the series, as the web
/// console checks its commands ([`crate::web::msg::to_operator`]), and turns it into the
/// commander's requests.
fn resolve(
    t: Typed,
    known: &[String],
    series: &[(String, String)],
) -> Result<Vec<Operator>, String> {
    use crate::web::msg::{Command, to_operator};
    let n = series.len();
    let open = |c: &str| {
        series
            .iter()
            .any(|(t, s)| t == c && !matches!(s.as_str(), "done" | "failed"))
    };
    let check = |cmd: Command| to_operator(&cmd, known, n, open);
    // Only waiting targets move, so a target can only go where a waiting one is.
    let waiting_at = |p: usize| -> Result<(), String> {
        match series.get(p - 1) {
            Some((t, s)) if s != "waiting" => Err(format!(
                "position {p} holds {t}, which is {s}: only places of waiting targets can be \
                 taken"
            )),
            _ => Ok(()),
        }
    };
    match t {
        Typed::Stop(reason) => Ok(vec![check(Command::Stop { reason })?]),
        Typed::Resume => Ok(vec![Operator::Resume]),
        Typed::Cancel(target) => Ok(vec![check(Command::Cancel { target })?]),
        Typed::Add { colour, at } => {
            let add = check(Command::Add { target: colour })?;
            match at {
                None => Ok(vec![add]),
                Some(p) if p > n + 1 => Err(format!(
                    "cannot add at position {p}: the series has {n} target(s), so 1 to {} are \
                     possible",
                    n + 1
                )),
                // Appended at position n (from 0), then moved.
                Some(p) if p == n + 1 => Ok(vec![add]),
                Some(p) => {
                    waiting_at(p)?;
                    Ok(vec![add, Operator::Move { from: n, to: p - 1 }])
                }
            }
        }
        Typed::Move { colour, to } => {
            if n == 0 {
                return Err("the queue is empty: nothing to move".to_owned());
            }
            let colour = crate::web::msg::colour(&colour, known)?;
            let Some(from) = series
                .iter()
                .position(|(t, s)| *t == colour && s == "waiting")
            else {
                return Err(format!(
                    "no waiting target {colour:?} to move (only waiting targets move; sent, \
                     done and failed ones keep their place)"
                ));
            };
            if to > n {
                return Err(format!(
                    "cannot move to position {to}: the series has {n} target(s)"
                ));
            }
            waiting_at(to)?;
            Ok(vec![check(Command::Move { from, to: to - 1 })?])
        }
    }
}

/// Reads stdin lines on a thread of their own (stdin blocks; the thread ends with the
/// process).
fn stdin_lines() -> tokio::sync::mpsc::UnboundedReceiver<String> {
    let (tx, rx) = tokio::sync::mpsc::unbounded_channel();
    std::thread::spawn(move || {
        read_lines(std::io::stdin().lock(), MAX_LINE, |l| tx.send(l).is_ok());
    });
    rx
}

/// The longest request line kept; the rest of a longer line is skipped.
const MAX_LINE: usize = 1024;

/// Hands `input`'s lines to `take` (until it returns `false` or the input ends), each as
/// text even when it is not UTF-8 (invalid bytes become U+FFFD, so a stray byte gets a hint
/// instead of ending the operator's input: `stop` typed after it still stops the fleet) and
/// cut at `max` bytes (a line without end cannot fill the memory).
fn read_lines(mut input: impl BufRead, max: usize, mut take: impl FnMut(String) -> bool) {
    let mut line = Vec::new();
    loop {
        // What this buffer gives: bytes used, and whether a line (or the input) ended.
        let (used, line_end, input_end) = match input.fill_buf() {
            Ok([]) => (0, false, true),
            Ok(buf) => {
                let nl = buf.iter().position(|&b| b == b'\n');
                let part = buf.get(..nl.unwrap_or(buf.len())).unwrap_or_default();
                let room = max.saturating_sub(line.len());
                line.extend_from_slice(part.get(..part.len().min(room)).unwrap_or_default());
                nl.map_or((buf.len(), false, false), |i| (i + 1, true, false))
            }
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            // A broken stdin: a part of a line is not a request.
            Err(_) => return,
        };
        input.consume(used);
        if input_end && line.is_empty() {
            return;
        }
        if !line_end && !input_end {
            continue;
        }
        if line.last() == Some(&b'\r') {
            line.pop();
        }
        let text = String::from_utf8_lossy(&line).into_owned();
        line.clear();
        if !take(text) || input_end {
            return;
        }
    }
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
    (known, series): (Vec<String>, SeriesView),
    stop_on_exit: bool,
    mut interrupt: impl AsyncInterrupt,
) {
    let tty = std::io::stdin().is_terminal();
    let mut lines = Some(stdin_lines());
    loop {
        tokio::select! {
            // Interrupt first: the safety thread hears the same SIGINT and cancels only after
            // every listener of it was woken, so when `cancelled()` is ready the interrupt is
            // too. Taken here, it cannot linger and answer the prompt below as if a second
            // Ctrl-C had come (that skipped the operator's "y" in 33 of 300 runs under load).
            biased;
            () = interrupt.next() => break,
            // SIGTERM, SIGHUP, or a closed stdout (see `crate::safety`).
            () = crate::safety::cancelled() => break,
            l = next_line(&mut lines) => match l {
                None => lines = None,
                Some(l) => {
                    let r = parse_request(&l)
                        .and_then(|t| t.map(|t| resolve(t, &known, &view(&series))).transpose());
                    match r {
                        Ok(Some(list)) => {
                            for op in list {
                                if let Operator::Add(c) = &op {
                                    // Seen by the next line before the commander's next
                                    // `queue` event.
                                    view(&series).push((c.clone(), "waiting".to_owned()));
                                }
                                if ops.send(op).is_err() {
                                    return;
                                }
                            }
                        }
                        Ok(None) => {}
                        Err(hint) => eprintln!("ima commander: {hint}"),
                    }
                }
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
            "operator" => format!(
                "[{:7.1}s] request refused: {}",
                e.t_s,
                d["error"].as_str().unwrap_or("?")
            ),
            "queue" => format!(
                "[{:7.1}s] series: {}",
                e.t_s,
                d["targets"]
                    .as_array()
                    .map(|l| l
                        .iter()
                        .enumerate()
                        .map(|(i, t)| format!(
                            "{} {} {}",
                            i + 1,
                            t["target"].as_str().unwrap_or("?"),
                            t["state"].as_str().unwrap_or("?")
                        ))
                        .collect::<Vec<_>>()
                        .join(", "))
                    .unwrap_or_default()
            ),
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
    // A robot's configuration would make this commander speak under the robot's name; said
    // before anything else (its key file, say) is looked at.
    if cfg.role != crate::config::Role::Commander {
        anyhow::bail!(
            "{} is {}'s configuration (a robot's), not a commander's: run it with \
             `ima run --config {}`, or give `ima commander` a configuration with \
             role = \"commander\" (see configs/commander.toml)",
            config.display(),
            cfg.robot,
            config.display()
        );
    }
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
    let known = known_colours(&cfg)?;
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
        let series = SeriesView::default();
        let op_task = tokio::spawn(operator(
            op_tx,
            (known.clone(), Arc::clone(&series)),
            args.stop_on_exit,
            interrupt,
        ));
        let (events, mut rx) = Events::channel(EVENT_QUEUE);
        // The series (`queue` events) is wanted by the stdin requests too.
        let events = events.detailed(true);
        let json = args.json;
        let with_web = web.is_some();
        let printer = tokio::spawn(async move {
            // Text mode: a robot's status is shown when its behaviour changes, not every second.
            let mut last: std::collections::BTreeMap<String, String> = Default::default();
            // Text mode: the series is shown when its order changes (adds and moves).
            let mut order: Option<Vec<String>> = None;
            while let Some(e) = rx.recv().await {
                if let Some(c) = &console {
                    c.apply(&e);
                }
                if let EventKind::Queue { targets } = &e.kind {
                    *view(&series) = targets
                        .iter()
                        .map(|t| (t.target.clone(), t.state.clone()))
                        .collect();
                    let now: Vec<String> = targets.iter().map(|t| t.target.clone()).collect();
                    let first = order.is_none();
                    if order.as_ref() != Some(&now) {
                        order = Some(now);
                        if !json && !first && !print_event(&e, false) {
                            crate::safety::output_closed();
                            break;
                        }
                    }
                    if !json {
                        continue;
                    }
                }
                // JSON lines carry the series (`queue`); the other detail is the page's.
                if crate::web::DETAIL_KINDS.contains(&e.name())
                    && (!json || (!with_web && e.name() != "queue"))
                {
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
        // Why each failed, when the commander knows (the JSON summary carries it too): a
        // bare "1 failed" after minutes left the operator to guess that Skeeter was down.
        for line in super::failure_lines(outcomes) {
            crate::safety::out_line(format_args!("{line}"))?;
        }
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
    use ima_agents::mission::commander::MAX_SERIES;

    /// Stdin as the operator's lines: a line that is not UTF-8 is one more (wrong) request,
    /// not the end of the input; an endless line is cut; CR LF and a last line without LF.
    #[test]
    fn stdin_lines_survive_bytes_that_are_not_text() {
        let lines = |input: &[u8], max| {
            let mut got = Vec::new();
            read_lines(std::io::BufReader::with_capacity(4, input), max, |l| {
                got.push(l);
                true
            });
            got
        };
        assert_eq!(
            lines(b"\x00\xff\xfe junk\n stop  \r\nresume", 64),
            ["\0\u{fffd}\u{fffd} junk", " stop  ", "resume"]
        );
        assert!(parse_request(&lines(b"\xff\xfe\n", 64)[0]).is_err());
        assert_eq!(
            lines(b"stop 0123456789abcdef\nresume\n", 8),
            ["stop 012", "resume"]
        );
        assert_eq!(lines(b"", 8), Vec::<String>::new());
        assert_eq!(lines(b"\n\n", 8), ["", ""]);
        // The reader stops when the taker does.
        let mut n = 0;
        read_lines(&b"a\nb\nc\n"[..], 8, |_| {
            n += 1;
            n < 2
        });
        assert_eq!(n, 2);
    }

    #[test]
    fn typed_requests_parse_and_others_get_a_hint() {
        assert_eq!(parse_request("stop"), Ok(Some(Typed::Stop(None))));
        assert_eq!(
            parse_request(" stop  rock ahead "),
            Ok(Some(Typed::Stop(Some("rock ahead".into()))))
        );
        assert_eq!(parse_request("resume"), Ok(Some(Typed::Resume)));
        assert_eq!(
            parse_request("cancel red"),
            Ok(Some(Typed::Cancel("red".into())))
        );
        assert_eq!(
            parse_request("add red"),
            Ok(Some(Typed::Add {
                colour: "red".into(),
                at: None
            }))
        );
        assert_eq!(
            parse_request("add red at 2"),
            Ok(Some(Typed::Add {
                colour: "red".into(),
                at: Some(2)
            }))
        );
        assert_eq!(
            parse_request("move blue 1"),
            Ok(Some(Typed::Move {
                colour: "blue".into(),
                to: 1
            }))
        );
        assert_eq!(parse_request("   "), Ok(None));
        assert!(
            parse_request("help")
                .unwrap_err()
                .starts_with("requests: type")
        );
        for bad in [
            "cancel",
            "cancel dark red",
            "resume now",
            "go",
            "add",
            "add red 2",
            "move red",
            "move red to 2",
        ] {
            assert!(
                parse_request(bad)
                    .unwrap_err()
                    .contains("add COLOUR [at N]"),
                "{bad}"
            );
        }
        for bad in ["move red 0", "add red at -1", "move red x"] {
            assert!(
                parse_request(bad)
                    .unwrap_err()
                    .contains("positions count from 1"),
                "{bad}"
            );
        }
    }

    #[test]
    fn typed_requests_are_checked_against_the_series() {
        let known: Vec<String> = ["red", "blue", "green"].map(String::from).to_vec();
        let series: Vec<(String, String)> = [("red", "sent"), ("blue", "waiting")]
            .map(|(a, b)| (a.to_owned(), b.to_owned()))
            .to_vec();
        let r = |line: &str, s: &[(String, String)]| {
            resolve(parse_request(line).unwrap().unwrap(), &known, s)
        };
        assert_eq!(
            r("add green", &series),
            Ok(vec![Operator::Add("green".into())])
        );
        assert_eq!(
            r("add green at 2", &series),
            Ok(vec![
                Operator::Add("green".into()),
                Operator::Move { from: 2, to: 1 }
            ])
        );
        assert_eq!(
            r("add green at 3", &series),
            Ok(vec![Operator::Add("green".into())])
        );
        assert!(r("add green at 4", &series).unwrap_err().contains("1 to 3"));
        assert_eq!(
            r("move blue 2", &series),
            Ok(vec![Operator::Move { from: 1, to: 1 }])
        );
        let e = r("add pink", &series).unwrap_err();
        assert!(
            e.contains("unknown colour \"pink\"") && e.contains("red, blue, green"),
            "{e}"
        );
        assert!(
            r("move pink 1", &series)
                .unwrap_err()
                .contains("unknown colour")
        );
        assert!(
            r("move red 2", &series)
                .unwrap_err()
                .contains("no waiting target \"red\"")
        );
        assert!(
            r("move blue 3", &series)
                .unwrap_err()
                .contains("has 2 target(s)")
        );
        let e = r("move blue 1", &series).unwrap_err();
        assert!(e.contains("position 1 holds red, which is sent"), "{e}");
        let e = r("add green at 1", &series).unwrap_err();
        assert!(e.contains("position 1 holds red"), "{e}");
        assert!(
            r("move blue 1", &[])
                .unwrap_err()
                .contains("queue is empty")
        );
        assert!(r("cancel red", &[]).unwrap_err().contains("queue is empty"));
        // A full series takes no more targets, but its waiting ones still move.
        let mut full = series.clone();
        full.resize(MAX_SERIES, ("green".into(), "waiting".into()));
        assert!(r("add red", &full).unwrap_err().contains("queue is full"));
        assert_eq!(
            r("move green 2", &full),
            Ok(vec![Operator::Move { from: 2, to: 1 }])
        );
        assert!(
            r("cancel green", &series)
                .unwrap_err()
                .contains("no open target")
        );
        assert_eq!(
            r("cancel blue", &series),
            Ok(vec![Operator::Cancel("blue".into())])
        );
        assert_eq!(
            r("stop", &series),
            Ok(vec![Operator::Stop("operator".into())])
        );
        assert_eq!(r("resume", &[]), Ok(vec![Operator::Resume]));
    }
}

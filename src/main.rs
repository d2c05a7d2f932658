//! `ima`: the command-line program of the `ima` robot stack.
//!
//! Sub-commands grow with the issues; see `ima --help` and the README.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// `eprintln!` that never panics (std's panics when standard error is a pipe whose reader
/// went away: `ima demo 2>&1 >/dev/null | head -1` ended with a panic, status 101). A closed
/// stderr ends the command as a closed stdout does ([`safety::err_line`]): every device
/// halted, the recording closed, status 141. Defined before the modules, so it is the
/// `eprintln!` of the whole crate.
macro_rules! eprintln {
    () => {
        $crate::safety::err_line(format_args!(""))
    };
    ($($arg:tt)*) => {
        $crate::safety::err_line(format_args!($($arg)*))
    };
}

/// `eprint!` that never panics, as [`eprintln!`].
macro_rules! eprint {
    ($($arg:tt)*) => {
        $crate::safety::err_write(format_args!($($arg)*))
    };
}

mod cmd;
mod config;
mod logs;
mod record;
mod safety;
mod stack;
mod web;
mod wiring;

/// Drivers, mock devices and agents for a Pioneer 2-AT (P2OS) and an ATRV-Jr (rFLEX).
#[derive(Debug, Parser)]
#[command(name = "ima", version, about, long_about = None)]
struct Cli {
    /// Log filter (tracing EnvFilter syntax), e.g. `info` or `ima_p2os=debug`; an invalid
    /// filter is an error.
    #[arg(long, global = true, env = "IMA_LOG", default_value = "warn", value_parser = log_filter)]
    log: String,
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// The mission on built-in mock devices (no hardware): both robots and the commander.
    Demo(cmd::demo::DemoArgs),
    /// Serve a mock device on a pseudo-terminal and print its path.
    Mock(cmd::mock::MockArgs),
    /// Connect to a robot base on a serial port and drive it (teleop-style).
    Drive(cmd::drive::DriveArgs),
    /// Decode a capture of a serial protocol into JSON Lines.
    Decode(cmd::decode::DecodeArgs),
    /// Replay an MCAP recording: re-decode its raw bytes, republish the readings, or serve a
    /// recorded port on a pty (`--as-mock`).
    Replay(cmd::replay::ReplayArgs),
    /// Configure a serial compass and print its heading live.
    Compass(cmd::compass::CompassArgs),
    /// Camera head tools (the mock head: grab a frame as PNG).
    #[command(subcommand)]
    Camera(cmd::camera::CameraCommand),
    /// Connect to a SICK LMS laser scanner, print scans, optionally write one as SVG.
    Scan(cmd::scan::ScanArgs),
    /// Run one robot's stack (Skeeter or Scooter) from a configuration file.
    Run(cmd::run::RunArgs),
    /// Send targets to the robots over the broadcast channel and follow the mission live.
    Commander(cmd::commander::CommanderArgs),
    /// Peer Agent over IP: standalone manager, client, broadcast listener and sender.
    #[command(subcommand)]
    Peer(cmd::peer::PeerCommand),
    /// Spreading Activation Network tools.
    #[command(subcommand)]
    San(SanCommand),
    /// Experiments in virtual time (the thesis's heading evaluation).
    #[command(subcommand)]
    Experiment(cmd::experiment::ExperimentCommand),
}

#[derive(Debug, Subcommand)]
enum SanCommand {
    /// Run a network (TOML) step by step, one JSON line per step.
    Simulate(cmd::san::SanSimulateArgs),
}

/// The tracing target of the drivers' connection progress (`ima::connect`).
const CONNECT_TARGET: &str = "ima::connect";

/// The Foxglove server logs each client's mistake (a subscription to an unknown channel, an
/// old subprotocol) at ERROR: any program or web page on the machine could write into the
/// robot's terminal that way. And the SDK warns, in Rust's debug form
/// (`McapError(Io(Os { code: 28, … }))`), of the message a failed file refused, beside the
/// recorder's own line that names the cause: its sink warnings are left out (its sink errors
/// stay). Both unless the filter names `foxglove`.
fn quiet_clients(f: tracing_subscriber::EnvFilter, given: &str) -> tracing_subscriber::EnvFilter {
    if given.contains("foxglove") {
        return f;
    }
    ["foxglove::websocket=off", "foxglove::log_sink_set=error"]
        .into_iter()
        .filter_map(|d| d.parse().ok())
        .fold(f, tracing_subscriber::EnvFilter::add_directive)
}

/// Checks a `--log` filter (clap then reports a bad one with exit status 2).
fn log_filter(s: &str) -> Result<String, String> {
    tracing_subscriber::EnvFilter::try_new(s)
        .map(|_| s.to_owned())
        .map_err(|e| format!("not a log filter ({e}); e.g. `info` or `ima_p2os=debug`"))
}

/// An error and its causes as one line, `outer: inner: …`, leaving out a cause whose text the
/// previous link already ends with (an error that prints its source *and* reports it).
fn error_chain(e: &anyhow::Error) -> String {
    let mut out = String::new();
    let mut prev = String::new();
    for link in e.chain() {
        let text = link.to_string();
        if !prev.is_empty() && prev.ends_with(&text) {
            continue;
        }
        if !out.is_empty() {
            out.push_str(": ");
        }
        out.push_str(&text);
        prev = text;
    }
    out
}

/// Whether `p` parses into a number type.
fn is_numeric(p: &clap::builder::ValueParser) -> bool {
    fn id_of<T>() -> clap::builder::ValueParser
    where
        T: std::str::FromStr + Clone + Send + Sync + 'static,
    {
        clap::builder::ValueParser::new(|s: &str| s.parse::<T>().map_err(|_| "not a number"))
    }
    let t = p.type_id();
    [
        id_of::<f64>(),
        id_of::<f32>(),
        id_of::<u8>(),
        id_of::<u16>(),
        id_of::<u32>(),
        id_of::<u64>(),
        id_of::<usize>(),
        id_of::<i8>(),
        id_of::<i16>(),
        id_of::<i32>(),
        id_of::<i64>(),
    ]
    .iter()
    .any(|v| v.type_id() == t)
}

/// Every numeric flag takes a negative number as its value, so that its parser says what it
/// accepts: `--for -1` was "unexpected argument '-1' found" where `--for=-1` got the range.
fn negative_numbers_are_values(cmd: clap::Command) -> clap::Command {
    cmd.mut_args(|a| {
        if is_numeric(a.get_value_parser()) {
            a.allow_negative_numbers(true)
        } else {
            a
        }
    })
    .mut_subcommands(negative_numbers_are_values)
}

fn main() -> ExitCode {
    // Before anything can move a robot: the panic hook and the signal thread.
    safety::install();
    let mut cmd = negative_numbers_are_values(<Cli as clap::CommandFactory>::command());
    let matches = cmd.get_matches_mut();
    let cli = match <Cli as clap::FromArgMatches>::from_arg_matches(&matches) {
        Ok(cli) => cli,
        Err(e) => e.format(&mut cmd).exit(),
    };
    // On a terminal, show what a connecting driver is trying (rate, attempt) as plain lines:
    // connecting can take tens of seconds and should not look like a hang. A `--log` filter
    // that names the target takes over (and prints it in the log format, also off a TTY).
    use tracing_subscriber::Layer as _;
    use tracing_subscriber::layer::SubscriberExt as _;
    use tracing_subscriber::util::SubscriberInitExt as _;
    let tty = std::io::IsTerminal::is_terminal(&std::io::stderr());
    // Log lines go through a thread of their own (`logs`).
    let log = logs::Logs::start();
    safety::set_log_writer(log.clone());
    let progress = (tty && !cli.log.contains(CONNECT_TARGET)).then(|| {
        tracing_subscriber::fmt::layer()
            .without_time()
            .with_level(false)
            .with_target(false)
            .with_writer(log.clone())
            .with_filter(
                tracing_subscriber::filter::Targets::new()
                    .with_target(CONNECT_TARGET, tracing::Level::INFO),
            )
    });
    tracing_subscriber::registry()
        .with(
            tracing_subscriber::fmt::layer()
                .with_writer(log)
                .with_ansi(tty)
                .with_filter(quiet_clients(
                    tracing_subscriber::EnvFilter::try_new(&cli.log)
                        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn")),
                    &cli.log,
                )),
        )
        .with(progress)
        .init();
    let result = match cli.command {
        Command::Demo(a) => cmd::demo::run(&a),
        Command::Mock(a) => cmd::mock::run(&a),
        Command::Drive(a) => cmd::drive::run(&a),
        Command::Decode(a) => cmd::decode::run(&a),
        Command::Replay(a) => cmd::replay::run(&a),
        Command::Scan(a) => cmd::scan::run(&a),
        Command::San(SanCommand::Simulate(a)) => cmd::san::run(&a),
        Command::Compass(a) => cmd::compass::run(&a),
        Command::Camera(c) => cmd::camera::run(&c),
        Command::Commander(a) => cmd::commander::run(&a),
        Command::Run(a) => cmd::run::run(&a),
        Command::Peer(c) => cmd::peer::run(&c),
        Command::Experiment(c) => cmd::experiment::run(&c),
    };
    // record: a command that failed before its guarded part still closes its recording.
    let _ = record::finish();
    // A recording that could not be written fails a command that otherwise succeeded.
    let result = result.and_then(|()| record::check_written());
    // The messages still queued go out first (waiting a second at most, shared with the
    // error line below): one that finds stderr closed marks it so.
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(1);
    let written = safety::logs_written();
    safety::flush_logs_by(deadline);
    // A print that found stderr closed could not fail the command itself: it ends as one that
    // found stdout closed (141), like the robot's own commands.
    let result = match result {
        Ok(()) if safety::output_was_closed() => {
            Err(safety::Interrupted(safety::Cause::OutputClosed).into())
        }
        r => r,
    };
    let (code, message) = safety::exit_status(&result);
    safety::last_words(message.as_deref(), deadline, written);
    ExitCode::from(code)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug)]
    struct Inner;
    impl std::fmt::Display for Inner {
        fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
            f.write_str("no such file")
        }
    }
    impl std::error::Error for Inner {}

    /// Prints its source and reports it too, like `#[error("pty: {0}")] X(#[from] E)`.
    #[derive(Debug)]
    struct Outer(Inner);
    impl std::fmt::Display for Outer {
        fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
            write!(f, "pty: {}", self.0)
        }
    }
    impl std::error::Error for Outer {
        fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
            Some(&self.0)
        }
    }

    #[test]
    fn error_chains_do_not_repeat_a_cause() {
        let e = anyhow::Error::new(Outer(Inner)).context("serving the world");
        assert_eq!(
            format!("{e:#}"),
            "serving the world: pty: no such file: no such file"
        );
        assert_eq!(error_chain(&e), "serving the world: pty: no such file");
        let plain = anyhow::Error::new(Inner).context("reading x");
        assert_eq!(error_chain(&plain), "reading x: no such file");
    }

    #[test]
    fn bad_log_filters_are_refused() {
        assert!(log_filter("info,ima_p2os=debug").is_ok());
        let e = log_filter("ima=loud").unwrap_err();
        assert!(e.contains("not a log filter"), "{e}");
    }
}

#[cfg(test)]
mod cli_tests {
    use super::{Cli, is_numeric};
    use clap::{CommandFactory, Parser};

    /// The committed list of every numeric flag (`tests/data/numeric-flags.txt`), which the
    /// process-level flag fuzz test (`tests/flag_fuzz.rs`) runs.
    const LISTED: &str = include_str!("../tests/data/numeric-flags.txt");

    /// Every (sub-command path, numeric flag) of the program.
    fn numeric_flags() -> Vec<(Vec<String>, String)> {
        fn walk(cmd: &clap::Command, path: &mut Vec<String>, out: &mut Vec<(Vec<String>, String)>) {
            for a in cmd.get_arguments() {
                if a.get_num_args().is_some_and(|n| n.takes_values())
                    && let Some(long) = a.get_long()
                    && is_numeric(a.get_value_parser())
                {
                    out.push((path.clone(), format!("--{long}")));
                }
            }
            for sub in cmd.get_subcommands() {
                path.push(sub.get_name().to_owned());
                walk(sub, path, out);
                path.pop();
            }
        }
        let mut out = Vec::new();
        let mut cmd = Cli::command();
        cmd.build();
        walk(&cmd, &mut Vec::new(), &mut out);
        out
    }

    #[test]
    fn the_cli_is_well_formed() {
        Cli::command().debug_assert();
    }

    #[test]
    fn the_numeric_flag_list_is_complete() {
        let found: Vec<String> = numeric_flags()
            .into_iter()
            .map(|(p, f)| format!("{} {f}", p.join(" ")))
            .collect();
        let listed: Vec<String> = LISTED
            .lines()
            .filter(|l| !l.trim().is_empty() && !l.starts_with('#'))
            .map(str::to_owned)
            .collect();
        assert_eq!(
            found,
            listed,
            "tests/data/numeric-flags.txt is out of date; it should read:\n{}",
            found.join("\n")
        );
    }

    /// NaN, ±infinity and 1e30 are refused at parse time by every numeric flag of every
    /// sub-command, with a message that names the flag; -1 and 0 are refused the same way
    /// unless they mean something.
    #[test]
    fn every_numeric_flag_refuses_nonsense_at_parse_time() {
        for (path, flag) in numeric_flags() {
            for bad in ["NaN", "inf", "-inf", "1e30", "-1", "0"] {
                let mut argv = vec!["ima".to_owned()];
                argv.extend(path.iter().cloned());
                argv.push(format!("{flag}={bad}"));
                match Cli::try_parse_from(&argv) {
                    Err(e) => {
                        let msg = e.to_string();
                        if matches!(
                            e.kind(),
                            clap::error::ErrorKind::ValueValidation
                                | clap::error::ErrorKind::InvalidValue
                        ) {
                            assert!(msg.contains(&flag), "{argv:?}: {msg}");
                        } else {
                            // Refused for another reason (a missing required flag): the
                            // value itself must still be checked when alone.
                            assert!(!msg.contains("panicked"), "{argv:?}: {msg}");
                            assert!(
                                !["NaN", "inf", "-inf", "1e30"].contains(&bad)
                                    || value_refused(&path, &flag, bad),
                                "{argv:?}: {bad} is not refused by the flag's parser"
                            );
                        }
                    }
                    Ok(_) => assert!(
                        !["NaN", "inf", "-inf", "1e30"].contains(&bad),
                        "{argv:?} accepted {bad}"
                    ),
                }
            }
        }
    }

    /// Whether the flag's own value parser refuses `value` (independent of other arguments).
    fn value_refused(path: &[String], flag: &str, value: &str) -> bool {
        let mut cmd = Cli::command();
        cmd.build();
        let mut c = &cmd;
        for p in path {
            c = c.find_subcommand(p).expect("sub-command");
        }
        let arg = c
            .get_arguments()
            .find(|a| a.get_long() == flag.strip_prefix("--"))
            .expect("flag")
            .clone()
            .required(false);
        clap::Command::new("probe")
            .no_binary_name(true)
            .arg(arg)
            .try_get_matches_from([format!("{flag}={value}")])
            .is_err()
    }
}

//! `ima`: the command-line program of the `ima` robot stack.
//!
//! Sub-commands grow with the issues; see `ima --help` and the README.

use std::io::Write as _;
use std::process::ExitCode;

use clap::{Parser, Subcommand};

mod cmd;
mod config;
mod safety;
mod stack;

/// Drivers, mock devices and agents for a Pioneer 2-AT (P2OS) and an ATRV-Jr (rFLEX).
#[derive(Debug, Parser)]
#[command(name = "ima", version, about, long_about = None)]
struct Cli {
    /// Log filter (tracing EnvFilter syntax), e.g. `info` or `ima_p2os=debug`.
    #[arg(long, global = true, env = "IMA_LOG", default_value = "warn")]
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

fn main() -> ExitCode {
    // Before anything can move a robot: the panic hook and the signal thread.
    safety::install();
    let cli = Cli::parse();
    // On a terminal, show what a connecting driver is trying (rate, attempt) as plain lines:
    // connecting can take tens of seconds and should not look like a hang. A `--log` filter
    // that names the target takes over (and prints it in the log format, also off a TTY).
    use tracing_subscriber::Layer as _;
    use tracing_subscriber::layer::SubscriberExt as _;
    use tracing_subscriber::util::SubscriberInitExt as _;
    let tty = std::io::IsTerminal::is_terminal(&std::io::stderr());
    let progress = (tty && !cli.log.contains(CONNECT_TARGET)).then(|| {
        tracing_subscriber::fmt::layer()
            .without_time()
            .with_level(false)
            .with_target(false)
            .with_writer(std::io::stderr)
            .with_filter(
                tracing_subscriber::filter::Targets::new()
                    .with_target(CONNECT_TARGET, tracing::Level::INFO),
            )
    });
    tracing_subscriber::registry()
        .with(
            tracing_subscriber::fmt::layer()
                .with_writer(std::io::stderr)
                .with_ansi(tty)
                .with_filter(
                    tracing_subscriber::EnvFilter::try_new(&cli.log)
                        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn")),
                ),
        )
        .with(progress)
        .init();
    let result = match cli.command {
        Command::Demo(a) => cmd::demo::run(&a),
        Command::Mock(a) => cmd::mock::run(&a),
        Command::Drive(a) => cmd::drive::run(&a),
        Command::Decode(a) => cmd::decode::run(&a),
        Command::Scan(a) => cmd::scan::run(&a),
        Command::San(SanCommand::Simulate(a)) => cmd::san::run(&a),
        Command::Compass(a) => cmd::compass::run(&a),
        Command::Camera(c) => cmd::camera::run(&c),
        Command::Commander(a) => cmd::commander::run(&a),
        Command::Run(a) => cmd::run::run(&a),
        Command::Peer(c) => cmd::peer::run(&c),
        Command::Experiment(c) => cmd::experiment::run(&c),
    };
    let (code, message) = safety::exit_status(&result);
    if let Some(m) = message {
        let _ = writeln!(std::io::stderr(), "ima: error: {m}");
    }
    ExitCode::from(code)
}

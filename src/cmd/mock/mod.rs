//! `ima mock <device>`: serve a mock device on a pseudo-terminal, print its path on the first
//! line of stdout, and run until interrupted.
//!
//! One module per device ([`p2os`], [`rflex`], [`sick`], [`compass`], [`video_mux`]) and
//! [`world`] for every device of both robots at once; [`shared`] holds what they share
//! (loading the world, announcing the pty and waiting for Ctrl-C). The device modules never
//! call back into this dispatcher.

pub mod compass;
pub mod p2os;
pub mod rflex;
pub mod shared;
pub mod sick;
pub mod video_mux;
pub mod world;

use std::path::PathBuf;
use std::time::Duration;

use anyhow::{Context, Result};
use clap::{Args, ValueEnum};

pub use self::shared::load_world;

/// Devices `ima mock` can serve.
#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum Device {
    /// A Pioneer 2-AT running P2OS.
    P2os,
    /// A serial compass (KVH C100 NMEA or PNI TCM2) on Scooter.
    Compass,
    /// An Extron (or Kramer) video switcher for the 7-camera head.
    VideoMux,
    /// An ATRV-Jr on an rFLEX controller (115200 baud; `--baud` is ignored).
    Rflex,
    /// A SICK LMS 200 laser scanner (on Scooter by default).
    SickLms,
    /// The whole world: every device of both robots (ptys and the TCP frame server); prints
    /// one JSON line of endpoints.
    World,
}

/// `--faults`'s long help: what it does and the grammar ([`ima_mock_devices::faults::GRAMMAR`]).
fn faults_help() -> String {
    format!(
        "Faults between device and port, e.g. `corrupt=0.01,split=1,stall=0.0005:300ms`; for \
         the world, between each of its serial devices and its port. The seed defaults to \
         --seed.\n\n{}",
        ima_mock_devices::faults::GRAMMAR.trim_end()
    )
}

/// Arguments of `ima mock`.
#[derive(Debug, Args)]
pub struct MockArgs {
    /// Device to serve.
    device: Device,
    /// World file (TOML); the built-in thesis arena when absent.
    #[arg(long)]
    world: Option<PathBuf>,
    /// Seed for sensor noise and faults.
    #[arg(long, default_value_t = 1, value_parser = crate::cmd::num::seed)]
    seed: u64,
    /// Faults between device and port, e.g. `corrupt=0.01,split=1,stall=0.0005:300ms`; for
    /// the world, between each of its serial devices and its port (`--help` gives the grammar).
    #[arg(long, default_value = "", long_help = faults_help())]
    faults: String,
    /// Which robot of the world the device belongs to (default: skeeter for p2os and the
    /// video switcher, scooter for rflex, sick-lms and the compass).
    #[arg(long)]
    robot: Option<String>,
    /// The device's serial rate, P2OS and SICK LMS (the driver must find it); the rFLEX,
    /// compass and video switcher mocks answer at any rate a pty carries (`--baud` is
    /// ignored for them).
    #[arg(long, default_value_t = 9600, value_parser = super::num::baud)]
    baud: u32,
    /// Compass: the dialect.
    #[arg(long, value_enum, default_value = "nmea")]
    dialect: compass::MockCompassDialect,
    /// Compass: installation deviation, degrees east.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true, value_parser = super::num::degrees)]
    deviation: f64,
    /// Compass: turn the robot at this rate, rad/s (counter-clockwise positive, like `ima
    /// drive --turn`).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true, value_parser = super::num::turn_rad_s)]
    spin: f64,
    /// Video mux: number of inputs.
    #[arg(long, default_value_t = 7, value_parser = super::num::int_in::<u8, 1, 64>)]
    inputs: u8,
    /// Video mux: switch delay, seconds.
    #[arg(long, default_value_t = 0.03, value_parser = super::num::short_seconds)]
    switch_delay: f64,
    /// Video mux: front-panel auto-switch mode (selections refused with E06).
    #[arg(long)]
    auto_switch: bool,
    /// Video mux: speak Kramer Protocol 2000 instead of Extron SIS.
    #[arg(long)]
    kramer: bool,
    /// World: time factor, 0.05 to 20: world time runs this many times faster than real time
    /// (not a velocity).
    #[arg(long, default_value_t = 1.0, value_parser = super::num::time_factor)]
    speed: f64,
    /// World: address of the TCP frame server (port 0: any free port).
    #[arg(long, default_value = "127.0.0.1:0")]
    frames_addr: std::net::SocketAddr,
    /// World: write skeeter.toml, scooter.toml, commander.toml and group.key into this
    /// directory, ready for `ima run` / `ima commander`.
    #[arg(long)]
    write_configs: Option<PathBuf>,
    /// World: let `--write-configs` replace configurations and a group key already there.
    #[arg(long, requires = "write_configs")]
    force: bool,
}

/// Run `ima mock`.
pub fn run(args: &MockArgs) -> Result<()> {
    let world = load_world(args.world.as_ref(), args.seed)?;
    let robot = args.robot.as_deref();
    match args.device {
        Device::Compass => {
            let opts = compass::MockCompassOptions {
                dialect: args.dialect,
                deviation_deg: args.deviation,
                spin_deg_s: args.spin.to_degrees(),
                seed: args.seed,
            };
            let robot = args.robot.as_deref().unwrap_or("scooter");
            compass::run_mock(&world, robot, &args.faults, opts)
        }
        Device::VideoMux => {
            let opts = video_mux::MockMuxOptions {
                inputs: args.inputs,
                switch_delay: Duration::try_from_secs_f64(args.switch_delay)
                    .ok()
                    .filter(|d| *d <= Duration::from_secs(10))
                    .context("--switch-delay must be in [0, 10] s")?,
                auto_switch: args.auto_switch,
                kramer: args.kramer,
            };
            video_mux::run_mock(&args.faults, args.seed, opts)
        }
        Device::Rflex => rflex::run(
            &world,
            args.robot.as_deref().unwrap_or("scooter"),
            args.seed,
            &args.faults,
        ),
        Device::SickLms => sick::run(
            &world,
            robot.unwrap_or("scooter"),
            args.seed,
            &args.faults,
            args.baud,
        ),
        Device::World => {
            if let Some(dir) = &args.write_configs {
                if !args.force {
                    world::refuse_overwrite(dir)?;
                }
                crate::cmd::output::check_dir("--write-configs", dir)?;
            }
            world::run(&world::WorldOptions {
                world: args.world.clone(),
                seed: args.seed,
                speed: args.speed,
                frames_addr: args.frames_addr,
                write_configs: args.write_configs.clone(),
                faults: shared::fault_plan(&args.faults, Some(args.seed))?,
            })
        }
        Device::P2os => p2os::run(
            &world,
            robot.unwrap_or("skeeter"),
            args.seed,
            &args.faults,
            args.baud,
        ),
    }
}

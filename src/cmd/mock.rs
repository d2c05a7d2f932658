//! `ima mock <device>`: serve a mock device on a pseudo-terminal, print its path on the first
//! line of stdout, and run until interrupted.

use std::io::Write;
use std::path::PathBuf;
use std::time::Duration;

use anyhow::{Context, Result};
use clap::{Args, ValueEnum};
use ima_mock_devices::body::WorldBody;
use ima_mock_devices::faults::FaultPlan;
use ima_mock_devices::p2os::{P2osDevice, P2osModelConfig};
use ima_mock_devices::pty::{PtyDevice, PtyOptions};
use ima_mock_devices::world::{SharedWorld, World};

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

/// Arguments of `ima mock`.
#[derive(Debug, Args)]
pub struct MockArgs {
    /// Device to serve.
    device: Device,
    /// World file (TOML); the built-in thesis arena when absent.
    #[arg(long)]
    world: Option<PathBuf>,
    /// Seed for sensor noise and faults.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Faults between device and port, e.g. `corrupt=0.01,split=1,stall=0.0005:300ms`
    /// (grammar: `ima-mock-devices` docs, module `faults`).
    #[arg(long, default_value = "")]
    faults: String,
    /// Which robot of the world the device belongs to (default: skeeter for p2os and the
    /// video switcher, scooter for rflex, sick-lms and the compass).
    #[arg(long)]
    robot: Option<String>,
    /// The device's serial rate (the driver must find it).
    #[arg(long, default_value_t = 9600, value_parser = super::num::baud)]
    baud: u32,
    /// Compass: the dialect.
    #[arg(long, value_enum, default_value = "nmea")]
    dialect: crate::cmd::compass::MockCompassDialect,
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
    /// World: time factor, world time runs this many times faster than real time (not a
    /// velocity).
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

/// Load the world of `--world`, or the built-in arena, with `seed`.
pub fn load_world(path: Option<&PathBuf>, seed: u64) -> Result<SharedWorld> {
    let mut world = match path {
        // The world's own errors name the file when it cannot be read; parse errors do not.
        Some(p) => World::from_toml_path(p).map_err(|e| match e {
            ima_mock_devices::world::WorldError::Io(_) => anyhow::anyhow!(e),
            e => anyhow::anyhow!(e).context(format!("loading {}", p.display())),
        })?,
        None => World::default_world(),
    };
    world.set_seed(seed);
    Ok(SharedWorld::new(world))
}

/// Serve a P2OS robot of `world` on a new pty.
pub fn serve_p2os(
    world: &SharedWorld,
    robot: &str,
    seed: u64,
    faults: &str,
    baud: u32,
    step_world: bool,
) -> Result<PtyDevice<P2osDevice>> {
    let id = world
        .with(|w| w.robot_id(robot))
        .with_context(|| format!("the world has no robot named {robot:?}"))?;
    let plan = if faults.is_empty() {
        FaultPlan::none()
    } else {
        let mut p = FaultPlan::parse(faults).context("parsing --faults")?;
        if !faults.contains("seed=") {
            p.seed = seed;
        }
        p
    };
    let name = robot[..1].to_uppercase() + &robot[1..];
    let cfg = P2osModelConfig {
        name,
        baud,
        ..P2osModelConfig::default()
    };
    let dev = P2osDevice::new(cfg, WorldBody::new(world.clone(), id, seed));
    PtyDevice::spawn(
        dev,
        PtyOptions {
            faults: plan,
            step_world: step_world.then(|| world.clone()),
            ..PtyOptions::default()
        },
    )
    .context("starting the pty")
}

/// Run `ima mock`.
pub fn run(args: &MockArgs) -> Result<()> {
    let world = load_world(args.world.as_ref(), args.seed)?;
    let robot = args.robot.as_deref();
    let dev = match args.device {
        Device::Compass => {
            let opts = crate::cmd::compass::MockCompassOptions {
                dialect: args.dialect,
                deviation_deg: args.deviation,
                spin_deg_s: args.spin.to_degrees(),
                seed: args.seed,
            };
            let robot = args.robot.as_deref().unwrap_or("scooter");
            return crate::cmd::compass::run_mock(&world, robot, &args.faults, opts);
        }
        Device::VideoMux => {
            let opts = crate::cmd::camera::MockMuxOptions {
                inputs: args.inputs,
                switch_delay: Duration::try_from_secs_f64(args.switch_delay)
                    .ok()
                    .filter(|d| *d <= Duration::from_secs(10))
                    .context("--switch-delay must be in [0, 10] s")?,
                auto_switch: args.auto_switch,
                kramer: args.kramer,
            };
            return crate::cmd::camera::run_mock(&args.faults, opts);
        }
        Device::Rflex => {
            return super::mock_rflex::run(
                &world,
                args.robot.as_deref().unwrap_or("scooter"),
                args.seed,
                &args.faults,
            );
        }
        Device::SickLms => {
            return super::mock_sick::run(
                &world,
                robot.unwrap_or("scooter"),
                args.seed,
                &args.faults,
                args.baud,
            );
        }
        Device::World => {
            if let Some(dir) = &args.write_configs {
                if !args.force {
                    super::mock_world::refuse_overwrite(dir)?;
                }
                super::output::check_dir("--write-configs", dir)?;
            }
            return super::mock_world::run(&super::mock_world::WorldOptions {
                world: args.world.clone(),
                seed: args.seed,
                speed: args.speed,
                frames_addr: args.frames_addr,
                write_configs: args.write_configs.clone(),
            });
        }
        Device::P2os => serve_p2os(
            &world,
            robot.unwrap_or("skeeter"),
            args.seed,
            &args.faults,
            args.baud,
            true,
        )?,
    };
    {
        let mut out = std::io::stdout().lock();
        writeln!(out, "{}", dev.path().display())?;
        out.flush()?;
    }
    eprintln!(
        "serving a mock {:?} on {} at {} baud; Ctrl-C to stop",
        args.device,
        dev.path().display(),
        args.baud
    );
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    rt.block_on(async {
        #[cfg(unix)]
        {
            let mut term =
                tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())?;
            tokio::select! {
                r = tokio::signal::ctrl_c() => r?,
                _ = term.recv() => {}
            }
        }
        #[cfg(not(unix))]
        tokio::signal::ctrl_c().await?;
        anyhow::Ok(())
    })?;
    let status = dev.status();
    let model = dev
        .stop()
        .map_err(|e| anyhow::anyhow!("stopping the pty: {e}"))?;
    let st = model.robot().stats();
    eprintln!(
        "stopped: {} sessions, {} commands, {} SIPs, {} bad frames, {} watchdog trips; link {:?}",
        st.sessions, st.commands, st.sips, st.bad_frames, st.watchdog_trips, status.counters
    );
    std::thread::sleep(Duration::from_millis(10));
    Ok(())
}

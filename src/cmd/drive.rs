//! `ima drive`: connect to a robot base on a serial port and drive it, printing odometry,
//! sonar and battery as it goes (a teleop-style tool like the vendor's demo program).

use std::time::Duration;

use anyhow::{Context, Result};
use clap::{Args, ValueEnum};
use ima_hal::base::{DifferentialBase, Odometer, VelocityCommand};
use ima_p2os::shell::{P2os, open_port};

/// Robot bases `ima drive` can drive.
#[derive(Debug, Clone, Copy, ValueEnum, PartialEq, Eq)]
pub enum Robot {
    /// Pioneer 2-AT on P2OS (baud probed from `--baud`, default 9600).
    P2at,
    /// ATRV-Jr on rFLEX (115200 baud unless `--baud`).
    AtrvJr,
}

/// Arguments of `ima drive`.
#[derive(Debug, Args)]
pub struct DriveArgs {
    /// Serial port (e.g. /dev/ttyS0, /dev/ttyUSB0, or a pty from `ima mock p2os`).
    #[arg(long)]
    port: String,
    /// Which base is on the port.
    #[arg(long, value_enum, default_value = "p2at")]
    robot: Robot,
    /// Line speed. P2OS: the first rate to try (default 9600; the others of 9600–115200 are
    /// probed after it). rFLEX: the rate (default 115200).
    #[arg(long)]
    baud: Option<u32>,
    /// Forward speed, m/s.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    vel: f64,
    /// Turn rate, rad/s (counter-clockwise positive).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    turn: f64,
    /// How long to drive, seconds.
    #[arg(long = "for", default_value_t = 3.0)]
    duration: f64,
    /// Print one JSON object per report instead of text.
    #[arg(long)]
    json: bool,
    /// Use this parameter table (p2at, p2at8, p2dx) whatever subclass the robot reports;
    /// needed for robots whose subclass has no built-in table.
    #[arg(long)]
    params: Option<String>,
    /// rFLEX only: translation units per metre (Kd; ATRV-Jr default 90810, calibrate it).
    #[arg(long)]
    kd: Option<f64>,
    /// rFLEX only: rotation units per radian (Ka; ATRV-Jr default 37000, calibrate it).
    #[arg(long)]
    ka: Option<f64>,
    /// How long to wait for the robot to answer, seconds.
    #[arg(long, default_value_t = 10.0)]
    connect_timeout: f64,
}

/// Run `ima drive`.
pub fn run(args: &DriveArgs) -> Result<()> {
    anyhow::ensure!(
        args.vel.is_finite() && args.turn.is_finite(),
        "--vel and --turn must be numbers"
    );
    anyhow::ensure!(
        args.duration.is_finite() && args.duration >= 0.0,
        "--for must be a non-negative number of seconds"
    );
    let rt = tokio::runtime::Runtime::new()?;
    if args.robot == Robot::AtrvJr {
        let opts = super::drive_rflex::DriveOptions {
            port: args.port.clone(),
            baud: args.baud.unwrap_or(ima_rflex::driver::BAUD),
            vel: args.vel,
            turn: args.turn,
            duration_s: args.duration,
            json: args.json,
            connect_timeout_s: args.connect_timeout,
            kd: args.kd,
            ka: args.ka,
        };
        return rt.block_on(super::drive_rflex::drive(&opts));
    }
    rt.block_on(drive(args))
}

async fn drive(args: &DriveArgs) -> Result<()> {
    let baud = args.baud.unwrap_or(9600);
    let mut cfg = ima_p2os::Config::default();
    let mut bauds = heapless::Vec::<u32, 8>::new();
    let _ = bauds.push(baud);
    for b in ima_p2os::machine::DEFAULT_BAUDS {
        if b != baud {
            let _ = bauds.push(b);
        }
    }
    cfg.bauds = bauds;
    if let Some(name) = &args.params {
        let p = ima_p2os::RobotParams::for_subclass(name.as_bytes())
            .with_context(|| format!("unknown parameter table {name:?} (p2at, p2at8, p2dx)"))?;
        cfg.params_override = Some(*p);
    }
    let port = open_port(&args.port, baud).with_context(|| format!("opening {}", args.port))?;
    let mut robot = P2os::connect(port, cfg, Duration::from_secs_f64(args.connect_timeout))
        .await
        .with_context(|| format!("connecting to a P2OS robot on {}", args.port))?;
    if let ima_p2os::shell::LinkStatus::Connected { identity, baud } = robot.link() {
        eprintln!(
            "connected to {} ({} {}) at {baud} baud",
            identity.name, identity.class, identity.subclass
        );
    }
    robot.enable_motors(true).await.context("enabling motors")?;
    let start = robot.now();
    let cmd = VelocityCommand::new(args.vel, args.turn);
    let end = start + Duration::from_secs_f64(args.duration);
    let mut last = start;
    loop {
        let now = robot.now();
        if now >= end {
            break;
        }
        robot.set_velocity(cmd).await?;
        let st = robot.next_state(last, Duration::from_secs(1)).await?;
        last = st.odometry.at;
        print_state(&st, start, args.json);
    }
    robot.stop().await?;
    // Let the robot decelerate and report where it ended.
    tokio::time::sleep(Duration::from_millis(500)).await;
    let odo = robot.odometry().await?;
    eprintln!(
        "stopped at x={:.3} m y={:.3} m θ={:.1}°; {} SIPs, {} bad checksums, {} implausible",
        odo.value.x_m(),
        odo.value.y_m(),
        odo.value.theta_rad().to_degrees(),
        robot.stats().sips,
        robot.stats().framer.bad_checksums,
        robot.stats().implausible_sips
    );
    robot.close().await.ok();
    Ok(())
}

fn print_state(st: &ima_p2os::machine::RobotState, start: ima_hal::Instant, json: bool) {
    let t = st
        .odometry
        .at
        .saturating_duration_since(start)
        .as_secs_f64();
    let o = &st.odometry.value;
    if json {
        let sonar: Vec<_> = st
            .sonar
            .value
            .readings
            .iter()
            .map(|r| serde_json::json!({"index": r.index, "range_m": r.range_m}))
            .collect();
        println!(
            "{}",
            serde_json::json!({
                "t_s": t, "x_m": o.x_m(), "y_m": o.y_m(), "theta_rad": o.theta_rad(),
                "v_m_s": o.v_m_s, "omega_rad_s": o.omega_rad_s,
                "battery_v": st.power.value.battery_v, "motors_enabled": st.motors_enabled,
                "sonar": sonar,
            })
        );
    } else {
        let ranges: Vec<String> = st
            .sonar
            .value
            .readings
            .iter()
            .filter(|r| r.index < 8)
            .map(|r| format!("{:.2}", r.range_m))
            .collect();
        println!(
            "t={t:6.2}s x={:+.3} y={:+.3} θ={:+6.1}° v={:+.2} ω={:+.2} batt={:.1}V front sonar [{}]",
            o.x_m(),
            o.y_m(),
            o.theta_rad().to_degrees(),
            o.v_m_s,
            o.omega_rad_s,
            st.power.value.battery_v,
            ranges.join(" ")
        );
    }
}

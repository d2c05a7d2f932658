//! `ima drive`: connect to a robot base on a serial port and drive it, printing odometry,
//! sonar and battery as it goes (a teleop-style tool like the vendor's demo program).
//!
//! The P2OS base is driven here, the ATRV-Jr in [`rflex`]; [`report`] ends a drive for both;
//! [`square`] is `ima demo square` (a P2OS base on a mock, driven round a square).

pub mod report;
pub mod rflex;
pub mod square;

use std::time::Duration;

use anyhow::{Context, Result};
use clap::{Args, ValueEnum};
use ima_hal::base::{DifferentialBase, VelocityCommand};
use ima_p2os::shell::Driver as _;
use ima_p2os::shell::{P2os, open_port};

use self::report::{report_end, report_interrupted};
use super::num;
use crate::safety;

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
    #[arg(long, value_parser = num::baud)]
    baud: Option<u32>,
    /// Forward speed, m/s (−10 to 10; capped at the robot's maximum with a warning).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true, value_parser = num::speed_m_s)]
    vel: f64,
    /// Turn rate, rad/s, counter-clockwise positive (−10 to 10; capped at the robot's maximum).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true, value_parser = num::turn_rad_s)]
    turn: f64,
    /// How long to drive, seconds (0 to 86400).
    #[arg(long = "for", default_value_t = 3.0, value_parser = num::seconds)]
    duration: f64,
    /// Print one JSON object per report instead of text.
    #[arg(long)]
    json: bool,
    /// Use this parameter table (p2at, p2at8, p2dx) whatever subclass the robot reports;
    /// needed for robots whose subclass has no built-in table.
    #[arg(long)]
    params: Option<String>,
    /// rFLEX only: translation units per metre (Kd; ATRV-Jr default 90810, calibrate it;
    /// a quarter to four times that: a wrong factor scales every speed and the speed cap).
    #[arg(long, value_parser = num::rflex_kd)]
    kd: Option<f64>,
    /// rFLEX only: rotation units per radian (Ka; ATRV-Jr default 37000, calibrate it; a
    /// quarter to four times that).
    #[arg(long, value_parser = num::rflex_ka)]
    ka: Option<f64>,
    /// How long to wait for the robot to answer, seconds (more than 0, at most 3600).
    #[arg(long, default_value_t = 10.0, value_parser = num::timeout_seconds)]
    connect_timeout: f64,
    /// Recording and live view.
    #[command(flatten)]
    rec: crate::record::RecordArgs,
}

/// Run `ima drive`.
pub fn run(args: &DriveArgs) -> Result<()> {
    let params = check_options(args)?;
    crate::record::start(&args.rec, "ima drive")?; // record
    if args.robot == Robot::AtrvJr {
        let opts = rflex::DriveOptions {
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
        return safety::block_on(rflex::drive(&opts));
    }
    safety::block_on(drive(args, params))
}

/// Refuse an option that belongs to the other base (it would be ignored without a word, and
/// a user who calibrated `--kd` would drive at the default) and parse `--params`. Returns the
/// P2OS parameter table `--params` names.
fn check_options(args: &DriveArgs) -> Result<Option<ima_p2os::RobotParams>> {
    let other: &[(&str, bool, &str)] = match args.robot {
        Robot::P2at => &[
            ("--kd", args.kd.is_some(), "--robot atrv-jr"),
            ("--ka", args.ka.is_some(), "--robot atrv-jr"),
        ],
        Robot::AtrvJr => &[("--params", args.params.is_some(), "--robot p2at")],
    };
    if let Some((flag, _, robot)) = other.iter().find(|(_, given, _)| *given) {
        // The name clap gives the value (every variant has one).
        let name = args.robot.to_possible_value();
        anyhow::bail!(
            "{flag} applies to {robot} only; this drive is for --robot {}",
            name.as_ref()
                .map_or("?", clap::builder::PossibleValue::get_name)
        );
    }
    args.params
        .as_deref()
        .map(|name| {
            ima_p2os::RobotParams::for_subclass(name.as_bytes())
                .copied()
                .with_context(|| format!("unknown parameter table {name:?} (p2at, p2at8, p2dx)"))
        })
        .transpose()
}

async fn drive(args: &DriveArgs, params: Option<ima_p2os::RobotParams>) -> Result<()> {
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
    // A table chosen here overrides the one the robot's SYNC2 reply names: the recording says
    // which, so that a replay reads the SIPs in the units the driver did.
    let recorded: std::collections::BTreeMap<_, _> = params
        .iter()
        .map(|p| ("params".to_owned(), p.subclass.to_owned()))
        .collect();
    cfg.params_override = params;
    let port = open_port(&args.port, baud).with_context(|| format!("opening {}", args.port))?;
    let port = crate::record::tap_with(port, "base", &args.port, baud, "p2os", recorded); // record: raw bytes
    let connect = P2os::connect(
        port,
        cfg,
        num::duration(args.connect_timeout),
        ima_hal::time::TokioClock::shared(),
    );
    let mut robot = safety::until_cancelled(connect)
        .await?
        .with_context(|| format!("connecting to a P2OS robot on {}", args.port))?;
    if let ima_p2os::shell::LinkStatus::Connected(ima_p2os::shell::Connection {
        identity,
        baud,
        ..
    }) = robot.link()
    {
        eprintln!(
            "connected to {} ({} {}) at {baud} baud",
            identity.name, identity.class, identity.subclass
        );
    }
    let limits = robot.limits();
    let cmd = VelocityCommand::new(
        num::cap("--vel", args.vel, limits.max_v_m_s, "m/s"),
        num::cap("--turn", args.turn, limits.max_omega_rad_s, "rad/s"),
    );
    safety::until_cancelled(robot.enable_motors(true))
        .await?
        .context("enabling motors")?;
    let start = robot.now();
    let end = start + num::duration(args.duration);
    let mut last = start;
    let mut live = report::Live::start()?;
    let motion = async {
        while robot.now() < end {
            robot.set_velocity(cmd).await?;
            let st = robot.next_state(last, Duration::from_secs(1)).await?;
            last = st.odometry.at;
            crate::record::with(|r| {
                let p = &st.odometry.value.pose;
                r.log_odometry("robot", ima_record::convert::Pose2::from_isometry(p));
                crate::record::log_fixed_frames(r, "robot", true, false);
                if st.new_sonar {
                    use ima_hal::sonar::SonarArray as _;
                    r.log_sonar("robot", robot.transducers(), &st.sonar.value);
                }
            }); // record: odometry, sonar
            live.line(state_line(&st, start, args.json));
        }
        anyhow::Ok(())
    };
    let moved = safety::until_cancelled(motion).await;
    if let Err(e) = &moved
        && e.is::<safety::Interrupted>()
    {
        report_interrupted(robot.latest().map(|st| st.odometry.value).as_ref());
    }
    moved?.map_err(report::link_lost::<ima_p2os::shell::P2osShell>)?;
    robot.stop().await?;
    let stats = robot.stats();
    let after = robot.now();
    report_end(
        &mut robot,
        after,
        &format!(
            "{} SIPs, {} bad checksums, {} implausible",
            stats.sips, stats.framer.bad_checksums, stats.implausible_sips
        ),
    )
    .await?;
    robot
        .close()
        .await
        .context("closing the session (STOP, CLOSE)")?;
    // The robot is closed: now wait for stdout to take the last state lines.
    live.finish()?;
    Ok(())
}

/// One line of the robot's state, as text or JSON.
fn state_line(st: &ima_p2os::machine::RobotState, start: ima_hal::Instant, json: bool) -> String {
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
        format!(
            "{}",
            serde_json::json!({
                "t_s": t, "x_m": o.x_m(), "y_m": o.y_m(), "theta_rad": o.theta_rad(),
                "v_m_s": o.v_m_s, "omega_rad_s": o.omega_rad_s,
                "battery_v": st.power.value.battery_v, "motors_enabled": st.motors_enabled,
                "sonar": sonar,
            })
        )
    } else {
        let ranges: Vec<String> = st
            .sonar
            .value
            .readings
            .iter()
            .filter(|r| r.index < 8)
            .map(|r| format!("{:.2}", r.range_m))
            .collect();
        format!(
            "t={t:6.2}s x={:+.3} y={:+.3} θ={:+6.1}° v={:+.2} ω={:+.2} batt={:.1}V front sonar [{}]",
            o.x_m(),
            o.y_m(),
            o.theta_rad().to_degrees(),
            o.v_m_s,
            o.omega_rad_s,
            st.power.value.battery_v,
            ranges.join(" ")
        )
    }
}

#[cfg(test)]
mod tests {
    use clap::Parser;

    use super::*;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        drive: DriveArgs,
    }

    fn check(args: &[&str]) -> Result<Option<ima_p2os::RobotParams>> {
        let cli = Cli::try_parse_from(["drive", "--port", "/dev/ttyS0"].iter().chain(args))?;
        check_options(&cli.drive)
    }

    #[test]
    fn an_option_of_the_other_base_is_refused() {
        for (args, flag, robot) in [
            (&["--kd", "90000"][..], "--kd", "--robot atrv-jr"),
            (&["--ka", "37000"], "--ka", "--robot atrv-jr"),
            (
                &["--robot", "atrv-jr", "--params", "p2dx"],
                "--params",
                "--robot p2at",
            ),
        ] {
            let e = check(args).unwrap_err().to_string();
            assert!(
                e.starts_with(&format!("{flag} applies to {robot} only")),
                "{e}"
            );
        }
        assert!(
            check(&["--robot", "atrv-jr", "--kd", "90000", "--ka", "37000"])
                .unwrap()
                .is_none()
        );
        let p = check(&["--params", "p2dx"]).unwrap().expect("a table");
        assert_eq!(Some(&p), ima_p2os::RobotParams::for_subclass(b"p2dx"));
        let e = check(&["--params", "p3"]).unwrap_err().to_string();
        assert!(e.contains("unknown parameter table \"p3\""), "{e}");
    }
}

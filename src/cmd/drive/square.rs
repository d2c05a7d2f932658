//! `ima demo square`: the issue-2 demonstration on built-in mock devices.
//!
//! A simulated Pioneer 2-AT is served on a pseudo-terminal, the real P2OS
//! driver connects to it through the pty exactly as it would to `/dev/ttyS0`, drives a square
//! closed-loop on its odometry, and the program prints the driver's odometry against the
//! simulated world's ground truth at every corner. `--record`/`--foxglove` record or show the
//! robot's raw bytes, its odometry and the ground truth (`/skeeter/...`).

use std::time::Duration;

use crate::safety::outln;
use anyhow::{Context, Result};
use clap::Args;
use ima_hal::base::{DifferentialBase, Odometer, VelocityCommand};
use ima_hal::normalize_angle;
use ima_p2os::shell::Driver as _;
use ima_p2os::shell::{LinkStatus, P2os, open_port};
use serde_json::json;

/// The simulated robot's name in the world and in a recording's topics (`/skeeter/odom`).
const ROBOT: &str = "skeeter";

/// Arguments of `ima demo square`.
#[derive(Debug, Args)]
pub struct SquareArgs {
    /// Side of the square, metres, in (0, 3].
    #[arg(long, default_value_t = 1.0, value_parser = crate::cmd::num::side_m)]
    side: f64,
    /// Cruise velocity, m/s, in (0, 1] (`--vel` as in `ima drive`; `ima demo --speed` is a
    /// time factor).
    #[arg(long, default_value_t = 0.5, value_parser = crate::cmd::num::cruise_m_s)]
    vel: f64,
    /// Not a flag of the square (kept to point at `--vel`): any value is refused.
    #[arg(long, hide = true, allow_hyphen_values = true, value_parser = refuse_speed)]
    speed: Option<String>,
    /// Seed for sensor noise and faults.
    #[arg(long, default_value_t = 1, value_parser = crate::cmd::num::seed)]
    seed: u64,
    /// Faults on the robot's serial line, e.g. `corrupt=0.01` (see `ima mock --help`).
    #[arg(long, default_value = "")]
    faults: String,
    /// Print machine-readable JSON lines instead of a table.
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    rec: crate::record::RecordArgs,
}

/// `--speed` of `ima demo square`: always refused, pointing at `--vel`.
fn refuse_speed(_: &str) -> Result<String, String> {
    Err("`ima demo square` takes its cruise velocity as --vel (m/s); --speed is `ima demo`'s time factor".into())
}

/// Run `ima demo square`.
pub fn run(args: &SquareArgs) -> Result<()> {
    anyhow::ensure!(
        args.speed.is_none(),
        "`ima demo square` takes its cruise velocity as --vel (m/s); --speed is `ima demo`'s time factor"
    );
    anyhow::ensure!(
        args.side.is_finite() && args.side > 0.0 && args.side <= 3.0,
        "--side must be in (0, 3] m"
    );
    anyhow::ensure!(
        args.vel.is_finite() && args.vel > 0.0 && args.vel <= 1.0,
        "--vel must be in (0, 1] m/s"
    );
    crate::record::start(&args.rec, "ima demo square")?; // record
    let world = crate::cmd::mock::shared::load_world(None, args.seed)?;
    let dev =
        crate::cmd::mock::p2os::serve_p2os(&world, "skeeter", args.seed, &args.faults, 9600, true)?;
    let id = world
        .with(|w| w.robot_id("skeeter"))
        .context("no skeeter in the arena")?;
    let truth = move || {
        world.with(|w| {
            w.robot(id)
                .map(|r| {
                    let p = r.pose();
                    (p.x_m, p.y_m, p.theta_rad)
                })
                .unwrap_or_default()
        })
    };
    if !args.json {
        outln!(
            "ima demo: a simulated Pioneer 2-AT on {} (P2OS over a pseudo-terminal)",
            dev.path().display()
        )?;
    }
    let path = dev.path().to_string_lossy().into_owned();
    let rows = crate::safety::block_on(square(args, &path, &truth))?;
    let status = dev.status();
    drop(dev);
    let max_pos = rows.iter().map(|r| r.pos_err_m).fold(0.0, f64::max);
    let max_head = rows
        .iter()
        .map(|r| r.head_err_deg.abs())
        .fold(0.0, f64::max);
    if args.json {
        outln!(
            "{}",
            json!({"kind": "summary", "corners": rows.len(), "max_position_error_m": max_pos,
                "max_heading_error_deg": max_head, "link": status.counters})
        )?;
    } else {
        outln!(
            "done: {} corners, largest odometry error {:.1} mm / {:.2}°",
            rows.len(),
            max_pos * 1000.0,
            max_head
        )?;
    }
    Ok(())
}

struct Row {
    pos_err_m: f64,
    head_err_deg: f64,
}

async fn square(
    args: &SquareArgs,
    path: &str,
    truth: &(dyn Fn() -> (f64, f64, f64) + Sync),
) -> Result<Vec<Row>> {
    let port = open_port(path, 9600)?;
    crate::record::label_ports(ROBOT, [path]);
    let port = crate::record::tap(port, "base", path, 9600, "p2os"); // record: raw bytes
    let mut robot = P2os::connect(
        port,
        ima_p2os::Config::default(),
        Duration::from_secs(10),
        ima_hal::time::TokioClock::shared(),
    )
    .await
    .context("connecting to the simulated robot")?;
    if let (LinkStatus::Connected(ima_p2os::shell::Connection { identity, baud, .. }), false) =
        (robot.link(), args.json)
    {
        outln!(
            "connected to {} ({} {}) at {baud} baud; motors on",
            identity.name,
            identity.class,
            identity.subclass
        )?;
    }
    robot.enable_motors(true).await?;
    robot.reset_odometry().await?;
    let t0 = truth();
    // record: odometry and the ground truth after every SIP the square reads, the odometry
    // frame at the start pose (where the odometry was reset) so that both meet in `map`.
    let pose = |(x_m, y_m, theta_rad): (f64, f64, f64)| ima_record::convert::Pose2 {
        x_m,
        y_m,
        theta_rad,
    };
    let origin = pose(t0);
    let record = |o: &ima_hal::Stamped<ima_hal::base::Odometry>| {
        crate::record::with(|r| {
            crate::record::log_fixed_frames_at(r, ROBOT, origin, true, false);
            let p = ima_record::convert::Pose2::from_isometry(&o.value.pose);
            r.log_odometry(ROBOT, p);
            r.log_ground_truth(ROBOT, pose(truth()));
        });
    };
    // Ground truth in the frame of the start pose, to compare with odometry.
    let rel = |t: (f64, f64, f64)| {
        let (s, c) = (-t0.2).sin_cos();
        let (dx, dy) = (t.0 - t0.0, t.1 - t0.1);
        (
            c * dx - s * dy,
            s * dx + c * dy,
            normalize_angle(t.2 - t0.2),
        )
    };
    if !args.json {
        outln!(
            "{:>6} | {:>8} {:>8} {:>8} | {:>8} {:>8} {:>8} | {:>8} {:>7}",
            "corner",
            "odo x",
            "odo y",
            "odo θ°",
            "true x",
            "true y",
            "true θ°",
            "err mm",
            "err °"
        )?;
    }
    let mut rows = Vec::new();
    for corner in 1..=4 {
        let o = robot.odometry().await?.value;
        let (sx, sy) = (o.x_m(), o.y_m());
        // Straight side, slowing down near its end; one command per SIP (10 Hz).
        let mut at = robot.odometry().await?.at;
        loop {
            let s = robot.next_odometry(at).await?;
            record(&s);
            at = s.at;
            let o = s.value;
            let d = (o.x_m() - sx).hypot(o.y_m() - sy);
            if d >= args.side {
                break;
            }
            let v = approach_speed(args.side - d, args.vel);
            robot.set_velocity(VelocityCommand::new(v, 0.0)).await?;
        }
        // Turn to the next multiple of 90°.
        let goal = normalize_angle(f64::from(corner) * std::f64::consts::FRAC_PI_2);
        loop {
            let s = robot.next_odometry(at).await?;
            record(&s);
            at = s.at;
            let e = normalize_angle(goal - s.value.theta_rad());
            if e.abs() < 0.5f64.to_radians() {
                break;
            }
            let w = (e * 1.5).clamp(-0.8, 0.8);
            let w = if w.abs() < 0.05 { 0.05 * w.signum() } else { w };
            robot.set_velocity(VelocityCommand::new(0.0, w)).await?;
        }
        robot.stop().await?;
        tokio::time::sleep(Duration::from_millis(400)).await;
        let o = robot.odometry().await?.value;
        let t = rel(truth());
        let pos_err = (o.x_m() - t.0).hypot(o.y_m() - t.1);
        let head_err = normalize_angle(o.theta_rad() - t.2).to_degrees();
        if args.json {
            outln!(
                "{}",
                json!({"kind": "corner", "corner": corner,
                    "odometry": {"x_m": o.x_m(), "y_m": o.y_m(), "theta_rad": o.theta_rad()},
                    "truth": {"x_m": t.0, "y_m": t.1, "theta_rad": t.2},
                    "position_error_m": pos_err, "heading_error_deg": head_err})
            )?;
        } else {
            outln!(
                "{corner:>6} | {:>8.3} {:>8.3} {:>8.2} | {:>8.3} {:>8.3} {:>8.2} | {:>8.1} {:>7.2}",
                o.x_m(),
                o.y_m(),
                o.theta_rad().to_degrees(),
                t.0,
                t.1,
                t.2.to_degrees(),
                pos_err * 1000.0,
                head_err
            )?;
        }
        rows.push(Row {
            pos_err_m: pos_err,
            head_err_deg: head_err,
        });
    }
    let st = robot.stats();
    if !args.json {
        outln!(
            "link: {} SIPs, {} frames sent, {} bad checksums, {} implausible SIPs dropped",
            st.sips,
            st.frames_sent,
            st.framer.bad_checksums,
            st.implausible_sips
        )?;
    }
    robot.close().await.ok();
    Ok(rows)
}

/// The speed on a side with `remaining_m` to go: slowing down near the corner, never below
/// 3 cm/s (or `vel`, if that is slower) and never above `vel`.
fn approach_speed(remaining_m: f64, vel: f64) -> f64 {
    (remaining_m * 1.5).min(vel).max(0.03_f64.min(vel))
}

#[cfg(test)]
mod tests {
    use super::approach_speed;

    /// `--vel` below the 3 cm/s floor panicked (`clamp` with min > max).
    #[test]
    fn the_approach_speed_respects_a_cruise_velocity_below_the_floor() {
        assert!((approach_speed(0.5, 0.02) - 0.02).abs() < 1e-12);
        assert!((approach_speed(0.001, 0.02) - 0.02).abs() < 1e-12);
        assert!((approach_speed(0.5, 0.3) - 0.3).abs() < 1e-12);
        assert!((approach_speed(0.1, 0.3) - 0.15).abs() < 1e-12);
        assert!((approach_speed(0.0, 0.3) - 0.03).abs() < 1e-12);
    }
}

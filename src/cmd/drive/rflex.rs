//! `ima drive --robot atrv-jr`: drive an rFLEX base (ATRV-Jr) on a serial port, printing
//! odometry, sonar and battery as it goes.

use anyhow::{Context, Result};
use ima_hal::base::{DifferentialBase, Odometer, Odometry, VelocityCommand};
use ima_hal::power::Power;
use ima_hal::{Instant, Stamped};
use ima_rflex::shell::Driver as _;
use ima_rflex::shell::{Rflex, open_port};

use crate::cmd::num;
use crate::safety;

/// What to do (from `ima drive`'s arguments).
#[derive(Debug, Clone)]
pub struct DriveOptions {
    /// Serial port path.
    pub port: String,
    /// Line speed (rFLEX: 115200).
    pub baud: u32,
    /// Forward speed, m/s.
    pub vel: f64,
    /// Turn rate, rad/s (CCW positive).
    pub turn: f64,
    /// How long to drive, s.
    pub duration_s: f64,
    /// JSON Lines output.
    pub json: bool,
    /// How long to wait for the first report, s.
    pub connect_timeout_s: f64,
    /// Translation units per metre (default: the ATRV-Jr's 90810).
    pub kd: Option<f64>,
    /// Rotation units per radian (default: the ATRV-Jr's 37000).
    pub ka: Option<f64>,
}

/// Connect, release the brake, drive for the duration, stop, report, shut down.
pub async fn drive(o: &DriveOptions) -> Result<()> {
    let mut cfg = ima_rflex::machine::Config::default();
    for (name, value, slot) in [("--kd", o.kd, &mut cfg.kd), ("--ka", o.ka, &mut cfg.ka)] {
        if let Some(v) = value {
            anyhow::ensure!(v.is_finite() && v > 0.0, "{name} must be a positive number");
            *slot = v;
        }
    }
    let port = open_port(&o.port, o.baud).with_context(|| format!("opening {}", o.port))?;
    // record: raw bytes, with the calibration a replay needs to integrate them as the driver
    let params = [
        ("kd".to_owned(), cfg.kd.to_string()),
        ("ka".to_owned(), cfg.ka.to_string()),
    ]
    .into();
    let port = crate::record::tap_with(port, "base", &o.port, o.baud, "rflex", params);
    let connect = Rflex::connect(
        port,
        cfg,
        num::duration(o.connect_timeout_s),
        ima_hal::time::TokioClock::shared(),
    );
    let mut base = safety::until_cancelled(connect).await?.with_context(|| {
        format!(
            "connecting to an rFLEX base on {} at {} baud",
            o.port, o.baud
        )
    })?;
    eprintln!("connected to an rFLEX base at {} baud", o.baud);
    safety::until_cancelled(base.enable_motors(true))
        .await?
        .context("releasing the brake")?;
    let limits = base.limits();
    let cmd = VelocityCommand::new(
        num::cap("--vel", o.vel, limits.max_v_m_s, "m/s"),
        num::cap("--turn", o.turn, limits.max_omega_rad_s, "rad/s"),
    );
    let start = base.now();
    let end = start + num::duration(o.duration_s);
    let mut last = start;
    let mut latest = None;
    let mut live = super::report::Live::start()?;
    let motion = async {
        while base.now() < end {
            base.set_velocity(cmd).await?;
            let odo = base.next_odometry(last).await?;
            last = odo.at;
            crate::record::with(|r| {
                let p = ima_record::convert::Pose2::from_isometry(&odo.value.pose);
                r.log_odometry("robot", p);
                crate::record::log_fixed_frames(r, "robot", true, false);
            }); // record: odometry
            latest = Some(odo.value);
            live.line(state_line(&mut base, odo, start, o.json).await);
        }
        anyhow::Ok(())
    };
    let moved = safety::until_cancelled(motion).await;
    if let Err(e) = &moved
        && e.is::<safety::Interrupted>()
    {
        super::report::report_interrupted(latest.as_ref());
    }
    moved?.map_err(super::report::link_lost::<ima_rflex::shell::RflexShell>)?;
    base.stop().await?;
    let st = base.stats();
    let after = base.now();
    super::report::report_end(
        &mut base,
        after,
        &format!(
            "{} frames, {} framing errors, {} odometry rejected",
            st.framer.frames,
            st.framer.errors(),
            st.session.odometry_rejected
        ),
    )
    .await?;
    base.close()
        .await
        .context("shutting the base down (zero speed, brake)")?;
    // The robot is closed: now wait for stdout to take the last state lines.
    live.finish()?;
    Ok(())
}

/// One line of the base's state (its odometry, battery and sonar), as text or JSON.
async fn state_line(
    base: &mut Rflex,
    odo: Stamped<Odometry>,
    start: Instant,
    json: bool,
) -> String {
    let t = odo.at.saturating_duration_since(start).as_secs_f64();
    let v = odo.value;
    let battery_v = base.power().await.ok().map(|p| p.value.battery_v);
    let sonar = ima_hal::sonar::SonarArray::sonar(base)
        .await
        .ok()
        .map(|s| s.value);
    if json {
        let ranges: Vec<_> = sonar
            .iter()
            .flat_map(|s| s.readings.iter())
            .map(|r| serde_json::json!({"index": r.index, "range_m": r.range_m}))
            .collect();
        format!(
            "{}",
            serde_json::json!({
                "t_s": t, "x_m": v.x_m(), "y_m": v.y_m(), "theta_rad": v.theta_rad(),
                "v_m_s": v.v_m_s, "omega_rad_s": v.omega_rad_s,
                "battery_v": battery_v, "sonar": ranges,
            })
        )
    } else {
        let front: Vec<String> = sonar
            .iter()
            .flat_map(|s| s.readings.iter())
            .filter(|r| r.index <= 2 || r.index >= 15)
            .map(|r| format!("{:.2}", r.range_m))
            .collect();
        format!(
            "t={t:6.2}s x={:+.3} y={:+.3} θ={:+6.1}° v={:+.2} ω={:+.2} batt={} front sonar [{}]",
            v.x_m(),
            v.y_m(),
            v.theta_rad().to_degrees(),
            v.v_m_s,
            v.omega_rad_s,
            battery_v.map_or_else(|| "?".to_owned(), |b| format!("{b:.1}V")),
            front.join(" ")
        )
    }
}

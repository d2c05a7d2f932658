//! `ima replay FILE.mcap`: a recording's raw serial bytes fed back through the real framers
//! and wire decoders (those of `ima decode`), the readings they give republished — live to
//! Foxglove (`--foxglove`), into a new recording (`--record`), as JSON Lines (`--json`) —
//! paced by their recorded stamps (`--speed`, 0: as fast as possible).
//!
//! Readings: SICK LMS scans (`/<robot>/laser/scan`, exactly as decoded), P2OS SIP odometry
//! (`/<robot>/odom`, `/tf`), rFLEX odometry integrated from its motion reports, compass
//! headings (`/<robot>/compass`, east-north-up). The recorded decoded topics are not replayed:
//! they are what the replay re-creates. A recording of the replay (`--record`) also carries
//! every raw channel with its recorded stamps and port metadata, so it can itself be replayed,
//! decoded (`ima decode --mcap`) or served `--as-mock`.
//!
//! `ima replay --as-mock PORT` serves one recorded port's robot→host bytes on a pty instead,
//! paced by their stamps, so a driver can be run against a recording.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::{Context, Result};
use clap::Args;
use ima_hal::laser::{BeamFlags, LaserScan};
use ima_record::convert::Pose2;
use ima_record::raw::Dir;
use ima_record::read::{RawStream, Recording};
use serde_json::{Value, json};

use super::decode::{Protocol, recorded_protocol};
use crate::safety::outln;

/// Arguments of `ima replay`.
#[derive(Debug, Args)]
pub struct ReplayArgs {
    /// The recording (`--record` of `ima demo`, `run`, `drive`, `scan`, `compass`).
    file: PathBuf,
    /// Time factor of the playback, 0.001 to 1000; 0 plays as fast as possible.
    #[arg(long, default_value_t = 1.0, value_parser = speed)]
    speed: f64,
    /// One JSON object per reading on stdout.
    #[arg(long)]
    json: bool,
    /// Serve this port's recorded robot→host bytes on a pseudo-terminal instead (its topic,
    /// `robot/device` or path); prints the pty's path.
    #[arg(long, value_name = "PORT", conflicts_with_all = ["json"])]
    as_mock: Option<String>,
    /// Recording and live view of the replayed readings.
    #[command(flatten)]
    rec: crate::record::RecordArgs,
}

fn speed(s: &str) -> Result<f64, String> {
    let v: f64 = s
        .parse()
        .map_err(|_| format!("{s:?} is not a number (e.g. 1, 4, 0.5; 0 for no pacing)"))?;
    if v == 0.0 || (v.is_finite() && (0.001..=1000.0).contains(&v)) {
        Ok(v)
    } else {
        Err(format!("{} is not 0 or in [0.001, 1000]", s.trim()))
    }
}

/// A reading re-decoded from raw bytes.
#[derive(Debug, Clone, PartialEq)]
pub enum Reading {
    /// A laser scan.
    Scan(Box<LaserScan>),
    /// An odometry pose (odometry frame).
    Odometry(Pose2),
    /// A compass heading, radians, east-north-up (counter-clockwise from east).
    Compass(f64),
}

/// One reading with its stamp and robot.
#[derive(Debug, Clone, PartialEq)]
pub struct Stamped {
    /// Log time of the bytes that completed it (Unix ns).
    pub t_ns: u64,
    /// The robot.
    pub robot: String,
    /// What.
    pub reading: Reading,
}

/// Run `ima replay`.
pub fn run(args: &ReplayArgs) -> Result<()> {
    let rec = Recording::open(&args.file)?;
    if let Some(port) = &args.as_mock {
        let stream = rec.raw_stream(port);
        if let Some(why) = rec.damage() {
            eprintln!("ima replay: the recording is damaged ({why}); serving the bytes it holds");
        }
        let stream = stream?;
        return serve_as_mock(&stream, args.speed);
    }
    let (n, cut) = rec.count();
    if let Some(why) = &cut.0 {
        eprintln!(
            "ima replay: the recording is damaged ({why}); replaying the {n} messages it holds"
        );
    }
    let mut readings = Vec::new();
    let streams = rec.raw_streams();
    if streams.is_empty() {
        // Nothing to re-decode: say why when the recorder was told to leave the ports out.
        let why = rec
            .left_out()
            .map_or_else(String::new, |p| format!(" (the recording left out: {p})"));
        eprintln!("ima replay: no raw serial channel to re-decode in the recording{why}");
    }
    for s in &streams {
        readings.extend(decode_stream(s)?);
    }
    readings.sort_by_key(|r| r.t_ns);
    crate::record::start(&args.rec, "ima replay")?;
    let raw = RawReplay::new(&streams, args.rec.record.is_some());
    let json_out = args.json;
    let speed = args.speed;
    let n = readings.len();
    crate::safety::block_on(async move {
        let t0 = readings.first().map(|r| r.t_ns);
        // Pacing starts at the first reading or raw chunk, whichever is earlier.
        let Some(first) = [t0, raw.first()].into_iter().flatten().min() else {
            return Ok(());
        };
        let start = tokio::time::Instant::now();
        let mut chunks = raw.chunks.iter().peekable();
        let mut readings = readings.iter().peekable();
        loop {
            // The next item in stamp order (a chunk before a reading of the same stamp: the
            // bytes that completed it).
            let next_chunk = chunks.peek().map(|c| c.0);
            let next_reading = readings.peek().map(|r| r.t_ns);
            let t = match (next_chunk, next_reading) {
                (None, None) => break,
                (Some(c), Some(r)) => c.min(r),
                (Some(t), None) | (None, Some(t)) => t,
            };
            if speed > 0.0 {
                let due = Duration::from_nanos(t.saturating_sub(first)).div_f64(speed);
                crate::safety::until_cancelled(tokio::time::sleep_until(start + due)).await?;
            }
            // As fast as possible, the replay could outrun the recorder's queue.
            crate::safety::until_cancelled(crate::record::room()).await?;
            if next_chunk == Some(t) {
                if let Some(c) = chunks.next() {
                    raw.publish(c);
                }
                continue;
            }
            if let Some(r) = readings.next() {
                publish(r);
                if json_out {
                    outln!("{}", reading_json(r, t0.unwrap_or(r.t_ns)))?;
                }
            }
        }
        Ok(())
    })?;
    if !json_out {
        eprintln!("ima replay: {n} readings from {}", args.file.display());
    }
    Ok(())
}

/// The raw chunks a recording of the replay carries, so that it can itself be replayed,
/// decoded or served `--as-mock`: every port's chunks (both directions and line-speed
/// changes) in stamp order, with the port each goes to. Empty without a file (a live view
/// does not show raw bytes).
struct RawReplay<'a> {
    ports: Vec<ima_record::raw::RawPort>,
    /// `(log time, port index, direction, bytes)`, in log-time order.
    chunks: Vec<(u64, usize, Dir, &'a [u8])>,
}

impl<'a> RawReplay<'a> {
    fn new(streams: &'a [RawStream], to_file: bool) -> Self {
        let mut ports = Vec::new();
        crate::record::with(|rec| {
            if !to_file {
                return;
            }
            ports = streams
                .iter()
                .map(|s| rec.raw_port(s.port.clone()))
                .collect();
        });
        let mut chunks: Vec<_> = if ports.is_empty() {
            Vec::new()
        } else {
            streams
                .iter()
                .enumerate()
                .flat_map(|(i, s)| s.chunks.iter().map(move |c| (c.0, i, c.1, &c.2[..])))
                .collect()
        };
        // Stable: each port's chunks keep their recorded order.
        chunks.sort_by_key(|c| c.0);
        Self { ports, chunks }
    }

    fn first(&self) -> Option<u64> {
        self.chunks.first().map(|c| c.0)
    }

    fn publish(&self, &(t_ns, port, dir, bytes): &(u64, usize, Dir, &[u8])) {
        let Some(p) = self.ports.get(port) else {
            return;
        };
        crate::record::with(|rec| rec.set_stamp(Some(t_ns)));
        p.chunk(dir, bytes);
    }
}

fn publish(r: &Stamped) {
    crate::record::with(|rec| {
        // The recorded stamp, so a recording of the replay has the original times.
        rec.set_stamp(Some(r.t_ns));
        match &r.reading {
            Reading::Scan(s) => rec.log_scan(&r.robot, s),
            Reading::Odometry(p) => rec.log_odometry(&r.robot, *p),
            Reading::Compass(h) => rec.log_compass(&r.robot, *h),
        }
    });
}

/// A reading as JSON: `kind`, `robot`, `t_ns`, `t_s` (from the first reading) and the values.
pub fn reading_json(r: &Stamped, t0: u64) -> Value {
    let t_s = r.t_ns.saturating_sub(t0) as f64 / 1e9;
    let mut v = match &r.reading {
        Reading::Scan(s) => json!({"kind": "scan", "start_angle_rad": s.start_angle_rad,
            "step_rad": s.step_rad,
            "ranges_m": s.ranges_m().iter().map(|r| (!r.is_nan()).then_some(*r)).collect::<Vec<_>>()}),
        Reading::Odometry(p) => {
            json!({"kind": "odometry", "x_m": p.x_m, "y_m": p.y_m, "theta_rad": p.theta_rad})
        }
        Reading::Compass(h) => json!({"kind": "compass", "heading_rad": h}),
    };
    v["robot"] = json!(r.robot);
    v["t_ns"] = json!(r.t_ns);
    v["t_s"] = json!(t_s);
    v
}

/// The log time of the chunk holding byte `offset` of the concatenated robot→host bytes.
struct Clock {
    ends: Vec<(usize, u64)>,
}

impl Clock {
    fn new(s: &RawStream) -> Self {
        let mut end = 0;
        let ends = s
            .chunks
            .iter()
            .filter(|c| c.1 == Dir::Rx)
            .map(|c| {
                end += c.2.len();
                (end, c.0)
            })
            .collect();
        Self { ends }
    }

    fn at(&self, offset: usize) -> u64 {
        let i = self.ends.partition_point(|(end, _)| *end <= offset);
        self.ends.get(i).or(self.ends.last()).map_or(0, |(_, t)| *t)
    }
}

/// Re-decode one raw stream's robot→host bytes into readings.
pub fn decode_stream(s: &RawStream) -> Result<Vec<Stamped>> {
    let Some(protocol) = recorded_protocol(&s.port.protocol) else {
        return Ok(Vec::new());
    };
    let bytes = s.rx_bytes();
    let clock = Clock::new(s);
    let robot = s.port.robot.clone();
    let mut out = Vec::new();
    // rFLEX odometry is integrated from the translational and rotational positions.
    let mut rflex: (Option<f64>, Option<f64>, Pose2) = (None, None, Pose2::default());
    let mut emit = |v: Value| -> Result<()> {
        let t_ns = clock.at(v["offset"].as_u64().unwrap_or(0) as usize);
        let reading = match (protocol, v["kind"].as_str()) {
            (Protocol::SickLms, Some("scan")) => scan_of(&v).map(|s| Reading::Scan(Box::new(s))),
            (Protocol::P2os, Some("sip")) => Some(Reading::Odometry(Pose2 {
                x_m: v["x_m"].as_f64().unwrap_or(0.0),
                y_m: v["y_m"].as_f64().unwrap_or(0.0),
                theta_rad: v["theta_rad"].as_f64().unwrap_or(0.0),
            })),
            (Protocol::Rflex, Some("motion")) => {
                rflex_odometry(&mut rflex, &v).map(Reading::Odometry)
            }
            (Protocol::Compass, _) => v["heading_rad"]
                .as_f64()
                .map(|h| Reading::Compass(std::f64::consts::FRAC_PI_2 - h)),
            _ => None,
        };
        if let Some(reading) = reading {
            out.push(Stamped {
                t_ns,
                robot: robot.clone(),
                reading,
            });
        }
        Ok(())
    };
    match protocol {
        Protocol::P2os => {
            let params = ima_p2os::params::RobotParams::for_subclass(b"p2at")
                .context("the P2OS robot parameters")?;
            super::decode::p2os::decode_p2os(&bytes, false, params, &mut emit)?;
        }
        Protocol::SickLms => super::decode::sick::decode_sick_lms(&bytes, false, &mut emit)?,
        Protocol::Rflex => super::decode::rflex::decode_rflex(&bytes, false, &mut emit)?,
        Protocol::Compass => super::decode::compass::decode(&bytes, false, &mut emit)?,
        Protocol::VideoMux | Protocol::Kramer => {}
    }
    Ok(out)
}

/// A scan from `ima decode sick-lms`'s JSON (`None`: a scan without geometry).
fn scan_of(v: &Value) -> Option<LaserScan> {
    let mut s = LaserScan::new(v["start_angle_rad"].as_f64()?, v["step_rad"].as_f64()?);
    for r in v["ranges_m"].as_array()? {
        let (range, flags) = match r.as_f64() {
            Some(x) => (x as f32, BeamFlags::default()),
            None => (f32::NAN, BeamFlags::NO_RETURN),
        };
        s.push(range, flags).ok()?;
    }
    Some(s)
}

/// Integrate an rFLEX motion report (axis 0: translation, axis 1: rotation).
fn rflex_odometry(st: &mut (Option<f64>, Option<f64>, Pose2), v: &Value) -> Option<Pose2> {
    match v["axis"].as_u64()? {
        0 => {
            let d = v["position_m"].as_f64()?;
            let last = st.0.replace(d);
            let step = last.map_or(0.0, |l| d - l);
            st.2.x_m += step * st.2.theta_rad.cos();
            st.2.y_m += step * st.2.theta_rad.sin();
            Some(st.2)
        }
        1 => {
            let a = v["position_rad"].as_f64()?;
            let first = *st.1.get_or_insert(a);
            st.2.theta_rad = a - first;
            None
        }
        _ => None,
    }
}

/// Serve a port's recorded robot→host bytes on a pty. Each chunk the robot sent waits until
/// the host has written as many bytes as it had when the chunk was recorded (so a driver's
/// handshake meets its answers; at most [`AS_MOCK_WAIT`] each), then for its stamp relative to
/// the previous chunk (÷ `speed`).
fn serve_as_mock(s: &RawStream, speed: f64) -> Result<()> {
    use serialport::SerialPort as _;
    let (mut master, slave) =
        ima_mock_devices::pty::pty_pair().context("opening a pseudo-terminal")?;
    let path = slave.name().context("the pseudo-terminal has no path")?;
    master.set_timeout(Duration::from_millis(5))?;
    outln!("{path}")?;
    // (stamp, host bytes written before it, bytes)
    let mut host_before = 0usize;
    let mut chunks: Vec<(u64, usize, &[u8])> = Vec::new();
    for c in &s.chunks {
        match c.1 {
            Dir::Tx => host_before += c.2.len(),
            Dir::Rx => chunks.push((c.0, host_before, &c.2)),
            Dir::Baud => {}
        }
    }
    let mut heard = 0usize;
    let mut buf = [0u8; 512];
    let mut listen = |master: &mut serialport::TTYPort, heard: &mut usize| {
        if let Ok(n) = std::io::Read::read(master, &mut buf) {
            *heard += n;
        }
    };
    let mut sent = 0usize;
    let mut prev_t: Option<u64> = None;
    for (t, need, bytes) in &chunks {
        if crate::safety::signal().is_some() {
            break;
        }
        let waited = std::time::Instant::now();
        while heard < *need && waited.elapsed() < AS_MOCK_WAIT {
            listen(&mut master, &mut heard);
        }
        if speed > 0.0
            && let Some(p) = prev_t
        {
            let gap = Duration::from_nanos(t.saturating_sub(p)).div_f64(speed);
            let until = std::time::Instant::now() + gap.min(Duration::from_secs(5));
            while std::time::Instant::now() < until {
                listen(&mut master, &mut heard);
            }
        }
        prev_t = Some(*t);
        std::io::Write::write_all(&mut master, bytes)
            .with_context(|| format!("writing to {path}"))?;
        sent += bytes.len();
    }
    eprintln!(
        "ima replay: served {sent} bytes of {} ({}) on {path}",
        s.topic, s.port.protocol
    );
    // The driver reads the last bytes before the pty closes.
    std::thread::sleep(Duration::from_millis(500));
    drop(slave);
    Ok(())
}

/// How long `--as-mock` waits for the host's request before sending the recorded answer.
const AS_MOCK_WAIT: Duration = Duration::from_secs(2);

#[cfg(test)]
mod tests {
    /// A factor near 0 overflowed the `Duration` of the first pause (1e-300) or slept for
    /// ever (1e-20): it is refused; 0 still means no pacing.
    #[test]
    fn the_speed_is_0_or_a_sensible_factor() {
        assert_eq!(super::speed("0"), Ok(0.0));
        assert_eq!(super::speed("0.001"), Ok(0.001));
        assert_eq!(super::speed("1000"), Ok(1000.0));
        for bad in ["1e-300", "1e-20", "0.0009", "1001", "-1", "NaN", "inf", "x"] {
            assert!(super::speed(bad).is_err(), "{bad}");
        }
    }
}

//! `ima scan`: connect to a SICK LMS on a serial port, initialise it, print the scan rate and
//! a one-line summary per scan, and optionally write one scan as an SVG picture.

use std::io::Write as _;
use std::path::PathBuf;
use std::time::Duration;

use anyhow::{Context, Result};
use clap::Args;
use ima_hal::Stamped;
use ima_hal::laser::{BeamFlags, LaserScan, LaserScanner};
use ima_sick_lms::decode::Variant;
use ima_sick_lms::driver::expected_scan_rate_hz;
use ima_sick_lms::machine::Config;
use ima_sick_lms::shell::Driver as _;
use ima_sick_lms::shell::{DriverError, Fault, SickLms, open_port};
use ima_sick_lms::wire::{BaudRate, StatusByte};

/// Arguments of `ima scan`.
#[derive(Debug, Args)]
pub struct ScanArgs {
    /// Serial port of the LMS (e.g. /dev/ttyUSB0, or the path `ima mock sick-lms` prints).
    #[arg(long)]
    port: String,
    /// Rate to run at once found: 9600, 19200, 38400 or 500000 (500000 needs RS-422 and is
    /// also probed then).
    #[arg(long, default_value_t = 38400, value_parser = lms_baud)]
    baud: u32,
    /// Variant: 180x1, 180x0.5, 100x1, 100x0.5 or 100x0.25 (field of view x resolution, °).
    #[arg(long, default_value = "180x0.5", value_parser = variant)]
    variant: Variant,
    /// Wait this long (s) for the unit's power-on telegram first (units powered with the
    /// port take up to 60 s to boot).
    #[arg(long, value_parser = super::num::seconds)]
    power_up_wait: Option<f64>,
    /// How often a command the LMS did not acknowledge or answer is sent again (0–100; the
    /// driver's own default is 3: on a noisy line, 1 % of bytes corrupted, three failed
    /// half the starts).
    #[arg(long, default_value_t = 10, value_parser = super::num::int_in::<u8, 0, 100>)]
    retries: u8,
    /// Stop after this many scans (0: run until Ctrl-C).
    #[arg(long, default_value_t = 0, value_parser = super::num::int_in::<u64, 0, 1_000_000_000>)]
    count: u64,
    /// Write the first scan as an SVG picture to this file.
    #[arg(long)]
    svg: Option<PathBuf>,
    /// The line is RS-422 (or a pseudo-terminal, detected by itself): probe 500000 baud too.
    /// An RS-232 line carries at most 38400.
    #[arg(long)]
    rs422: bool,
    /// One JSON object per scan on stdout (every beam's angle and range in SI units); the
    /// connection and summary lines go to stderr.
    #[arg(long)]
    json: bool,
    /// Recording and live view.
    #[command(flatten)]
    rec: crate::record::RecordArgs,
}

/// The variants the LMS has, as `--variant` takes them.
const VARIANTS: &str = "180x1, 180x0.5, 100x1, 100x0.5 or 100x0.25";

/// `--variant`, checked as the command line is read (a wrong one ended the command with
/// status 1 after it started, not 2 with the usage, as every other bad flag).
fn variant(s: &str) -> Result<Variant, String> {
    parse_variant(s).map_err(|e| e.to_string())
}

/// `--baud`: a rate the LMS has, checked as the command line is read.
fn lms_baud(s: &str) -> Result<u32, String> {
    let bps = super::num::baud(s)?;
    match BaudRate::from_bps(bps) {
        Some(_) => Ok(bps),
        None => Err(format!(
            "{bps} is not an LMS rate (9600, 19200, 38400 or 500000)"
        )),
    }
}

fn parse_variant(s: &str) -> Result<Variant> {
    let none = || anyhow::anyhow!("{s:?} is not an LMS variant: they are {VARIANTS}");
    let (a, r) = s.split_once(['x', 'X', '/']).ok_or_else(none)?;
    let a: u16 = a.trim().parse().map_err(|_| none())?;
    let r: f64 = r.trim().parse().map_err(|_| none())?;
    let centi = (r * 100.0).round();
    if !(1.0..=100.0).contains(&centi) {
        return Err(none());
    }
    Variant::new(a, centi as u16).ok_or_else(none)
}

/// One-line summary of a scan.
#[must_use]
pub fn summary(s: &LaserScan) -> String {
    let valid: Vec<f32> = s
        .ranges_m()
        .iter()
        .copied()
        .filter(|r| r.is_finite())
        .collect();
    let min = valid.iter().copied().fold(f32::INFINITY, f32::min);
    let max = valid.iter().copied().fold(0.0f32, f32::max);
    let mean = if valid.is_empty() {
        f32::NAN
    } else {
        valid.iter().sum::<f32>() / valid.len() as f32
    };
    let ahead = s
        .beams()
        .min_by(|a, b| a.0.abs().total_cmp(&b.0.abs()))
        .map_or(f32::NAN, |b| b.1);
    format!(
        "{} beams, {} valid, min {min:.3} m, mean {mean:.3} m, max {max:.3} m, ahead {ahead:.3} m",
        s.len(),
        valid.len()
    )
}

/// The scan as an SVG picture, top view: the scanner at the origin looking up the page (x
/// ahead, y to the left), one ray and dot per valid beam, range rings, axes in metres, a
/// legend with the beam counts and a scale bar.
#[must_use]
pub fn svg(s: &LaserScan) -> String {
    use ima_plot::plotters::prelude::*;
    use ima_plot::{LegendRow, Mark};

    let ret = RGBColor(204, 34, 34);
    let ray = RGBColor(244, 192, 192);
    let scanner = RGBColor(34, 34, 102);
    let ring_colour = RGBColor(170, 170, 170);
    // Page coordinates: (right of the scanner, ahead) = (−y, x).
    let hits: Vec<(f64, f64)> = s
        .beams()
        .filter(|(a, r, f)| f.is_valid() && r.is_finite() && *r >= 0.0 && a.is_finite())
        .map(|(a, r, _)| (-f64::from(r) * a.sin(), f64::from(r) * a.cos()))
        .collect();
    let reach = hits
        .iter()
        .map(|p| p.0.hypot(p.1))
        .fold(1.0f64, f64::max)
        .ceil();
    let lowest = hits.iter().map(|p| p.1).fold(0.0f64, f64::min);
    let frame = ima_plot::Frame::new(
        (-reach - 0.2)..(reach + 0.2),
        (lowest.min(0.0) - 0.5)..(reach + 0.2),
    );
    let px_per_m = (620.0 / frame.width().max(frame.height())).clamp(5.0, 200.0);
    let ring_step = ima_plot::grid_step(px_per_m, 40.0);
    let (cw, ch) = ima_plot::metric_chart_size(&frame, px_per_m);
    let invalid = s.len() - hits.len();
    let fov = s
        .beams()
        .map(|b| b.0.abs())
        .fold(0.0f64, f64::max)
        .to_degrees();
    let nearest = hits
        .iter()
        .map(|p| p.0.hypot(p.1))
        .fold(f64::INFINITY, f64::min);
    let title = if nearest.is_finite() {
        format!(
            "Laser scan: {} beams over ±{fov:.0}°, {} valid, nearest {nearest:.2} m",
            s.len(),
            hits.len()
        )
    } else {
        format!("Laser scan: {} beams over ±{fov:.0}°, none valid", s.len())
    };
    let step = if ring_step >= 1.0 {
        format!("{ring_step:.0} m")
    } else {
        format!("{ring_step:.1} m")
    };
    let rows = vec![
        LegendRow::Heading("Scan (top view)".into()),
        LegendRow::entry(
            Mark::Dot,
            ret,
            format!("return: {} valid beams", hits.len()),
        ),
        LegendRow::entry(Mark::Line, ray, "beam, scanner to return"),
        LegendRow::entry(Mark::Square, scanner, "scanner, x ahead (up)"),
        LegendRow::entry(Mark::Ring, ring_colour, format!("range ring every {step}")),
        LegendRow::Note(format!("beams without a range (not drawn): {invalid}")),
        LegendRow::scale_bar(px_per_m),
    ];
    let (lw, lh) = ima_plot::legend_size(&rows);
    ima_plot::render(cw + lw, ch.max(lh) + ima_plot::TITLE_H, |root| {
        let body = ima_plot::titled(root, &title, None)?;
        let (plot, side) = body.split_horizontally(cw);
        let x_desc = "right of the scanner, −y (m)";
        let mut chart = ima_plot::metric_chart(&plot, &frame, x_desc, "ahead, x (m)")?;
        let mut r = ring_step;
        while r <= reach + 1e-9 {
            ima_plot::ring(&mut chart, (0.0, 0.0), r, ring_colour, true)?;
            r += ring_step;
        }
        // All rays as one polyline out and back through the scanner.
        let rays = hits.iter().flat_map(|&p| [(0.0, 0.0), p]);
        ima_plot::line(&mut chart, rays, ray, 1, false)?;
        chart.draw_series(hits.iter().map(|&p| Circle::new(p, 2, ret.filled())))?;
        ima_plot::line(&mut chart, [(0.0, 0.0), (0.0, 0.3)], scanner, 2, false)?;
        ima_plot::mark(&mut chart, (0.0, 0.0), Mark::Square, scanner)?;
        ima_plot::legend(&side, &rows)
    })
}

/// The flags of a beam that is not a valid range, by name (`[]` for a valid one).
fn flag_names(f: BeamFlags) -> Vec<&'static str> {
    [
        (BeamFlags::NO_RETURN, "no_return"),
        (BeamFlags::DAZZLED, "dazzled"),
        (BeamFlags::OVERFLOW, "overflow"),
        (BeamFlags::LOW_SIGNAL, "low_signal"),
        (BeamFlags::READ_ERROR, "read_error"),
        (BeamFlags::ABOVE_MAX_RANGE, "above_max_range"),
        (BeamFlags::RESERVED, "reserved"),
    ]
    .into_iter()
    .filter(|(b, _)| f.contains(*b))
    .map(|(_, n)| n)
    .collect()
}

/// One scan as a JSON object: its index (1-based) and stamp, then every beam with its angle
/// (radians, sensor frame, counter-clockwise from ahead) and range (metres, `null` when the
/// beam has no valid range) and, for an invalid beam, why; `status` is the unit's latest
/// status byte (`null` before any telegram), decoded.
#[must_use]
pub fn scan_json(
    index: u64,
    t_s: f64,
    s: &Stamped<LaserScan>,
    status: Option<StatusByte>,
) -> serde_json::Value {
    let beams: Vec<serde_json::Value> = s
        .value
        .beams()
        .map(|(a, r, f)| {
            let mut b = serde_json::json!({
                "angle_rad": a,
                "range_m": if f.is_valid() && r.is_finite() { Some(r) } else { None },
            });
            if !f.is_valid() {
                b["flags"] = serde_json::json!(flag_names(f));
            }
            if f.device_bits() != 0 {
                b["device_bits"] = serde_json::json!(f.device_bits());
            }
            b
        })
        .collect();
    let valid = s
        .value
        .beams()
        .filter(|(_, r, f)| f.is_valid() && r.is_finite())
        .count();
    let status = status.map(|b| {
        serde_json::json!({
            "byte": b.0,
            "error": b.is_error(),
            "pollution": b.pollution(),
            "implausible": b.implausible(),
            "restart": b.restart(),
        })
    });
    serde_json::json!({
        "scan": index,
        "t_s": t_s,
        "stamp_s": s.at.as_secs_f64(),
        "status": status,
        "beam_count": s.value.len(),
        "valid": valid,
        "beams": beams,
    })
}

/// Whether `path` is a pseudo-terminal (a mock), whose line carries 500 000 baud like an
/// RS-422 adapter.
fn is_pty(path: &str) -> bool {
    let p = std::fs::canonicalize(path).unwrap_or_else(|_| PathBuf::from(path));
    let p = p.to_string_lossy();
    p.starts_with("/dev/pts/")
        || p.strip_prefix("/dev/ttys")
            .is_some_and(|n| n.starts_with(|c: char| c.is_ascii_digit()))
}

/// Run `ima scan`.
pub fn run(args: &ScanArgs) -> Result<()> {
    // Checked by `lms_baud` already.
    let baud = BaudRate::from_bps(args.baud).context("--baud is not an LMS rate")?;
    let variant = args.variant;
    if let Some(p) = &args.svg {
        // Before the scan: a typo in the path must not cost the laser's start-up.
        super::output::check_file("--svg", p)?;
        if let Some(r) = &args.rec.record {
            super::output::distinct_outputs(("--svg", p), ("--record", r))?;
        }
    }
    let rs422 = args.rs422 || baud == BaudRate::B500000 || is_pty(&args.port);
    let cfg = Config {
        baud,
        rs422,
        variant: Some(variant),
        power_up_wait: args
            .power_up_wait
            .filter(|s| s.is_finite() && *s > 0.0)
            .map(Duration::from_secs_f64),
        retries: args.retries,
        ..Config::default()
    };
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()?;
    crate::record::start(&args.rec, "ima scan")?; // record
    let r = rt.block_on(async {
        let port = open_port(&args.port, 9600).with_context(|| format!("opening {}", args.port))?;
        let port = crate::record::tap(port, "laser", &args.port, 9600, "sick-lms"); // record: raw bytes
        let wait = cfg.power_up_wait.unwrap_or_default();
        let connect = SickLms::connect(
            port,
            cfg,
            wait + Duration::from_secs(60),
            ima_hal::time::TokioClock::shared(),
        );
        let lms = match crate::safety::until_cancelled(connect).await? {
            Ok(l) => l.with_scan_timeout(Duration::from_secs(5)),
            Err(e @ DriverError::Device(Fault::NotFound { rs422: false, .. })) => {
                return Err(anyhow::Error::new(e)
                    .context("initialising the LMS (pass --rs422 if the line is RS-422)"));
            }
            Err(e) => return Err(anyhow::Error::new(e).context("initialising the LMS")),
        };
        // Close on every path: the unit goes back to 9600 for the next program.
        let result = scan_loop(args, lms.clone(), variant).await;
        let closed = lms.close().await;
        result?;
        closed.context("closing the LMS (it may be left at the session's rate)")?;
        // Ended by a signal: the unit is closed; the status says how it ended (130 for
        // Ctrl-C, 143 for SIGTERM), as every command's does.
        if let Some(s) = crate::safety::signal() {
            return Err(crate::safety::Interrupted(crate::safety::Cause::Signal(s)).into());
        }
        Ok(())
    });
    let _ = crate::record::finish(); // record: close the file
    r
}

async fn scan_loop(args: &ScanArgs, mut lms: SickLms, variant: Variant) -> Result<()> {
    let info = lms.session().context("not ready")?;
    let connected = format!(
        "connected: {} at {} baud, {}°/{}°, up to {:.1} scans/s (mirror and line)",
        lms.device_type(),
        info.baud.bps(),
        variant.angle_deg(),
        f64::from(variant.res_centideg()) / 100.0,
        expected_scan_rate_hz(info.baud, variant)
    );
    if args.json {
        eprintln!("{connected}");
    } else {
        writeln!(std::io::stdout().lock(), "{connected}")?;
    }
    let mut n = 0u64;
    let mut first: Option<ima_hal::Instant> = None;
    let mut last = lms.now();
    // SIGINT, SIGTERM, SIGHUP (or a panic elsewhere) end the loop, so the unit is closed
    // (and put back at 9600) within the signal's grace time.
    let stop = crate::safety::cancelled();
    tokio::pin!(stop);
    // A stream that stalls (a corrupted line, a replug) is re-probed by the driver; the loop
    // waits for it, saying so once per gap, and fails only when the driver has ended. (It gave
    // up 5 s into a re-probe that would have recovered.)
    let mut gap = false;
    loop {
        let s = tokio::select! {
            s = lms.next_scan(last) => s,
            _ = &mut stop => break,
        };
        let s = match s {
            Ok(s) => s,
            Err(DriverError::Timeout) if !lms.link().is_ended() => {
                if !gap {
                    eprintln!(
                        "ima scan: no scan for 5 s; waiting while the driver re-probes the LMS"
                    );
                    gap = true;
                }
                continue;
            }
            Err(e) => return Err(e).context("waiting for a scan"),
        };
        if std::mem::take(&mut gap) {
            eprintln!("ima scan: scans again");
        }
        last = s.at;
        crate::record::with(|r| {
            r.log_scan("robot", &s.value);
            crate::record::log_fixed_frames(r, "robot", false, true);
        }); // record: scan, the frames that place it
        n += 1;
        let t0 = *first.get_or_insert(s.at);
        let secs = s.at.saturating_duration_since(t0).as_secs_f64();
        {
            let mut out = std::io::stdout().lock();
            if args.json {
                writeln!(out, "{}", scan_json(n, secs, &s, lms.device_status()))?;
            } else {
                let rate = if n > 1 && secs > 0.0 {
                    format!("{:.1} scans/s", (n - 1) as f64 / secs)
                } else {
                    "rate pending".to_owned()
                };
                writeln!(
                    out,
                    "scan {n} at {:.3} s ({rate}): {}",
                    s.at.as_secs_f64(),
                    summary(&s.value)
                )?;
            }
            out.flush()?;
        }
        if n == 1
            && let Some(p) = &args.svg
        {
            std::fs::write(p, svg(&s.value)).with_context(|| format!("writing {}", p.display()))?;
            if args.json {
                eprintln!("wrote {}", p.display());
            } else {
                writeln!(std::io::stdout().lock(), "wrote {}", p.display())?;
            }
        }
        if args.count > 0 && n >= args.count {
            break;
        }
    }
    // `n`, not the driver's counter: the stream runs on while this line is written, and the
    // count is of the scans this command received.
    let st = lms.stats();
    let line = format!(
        "{n} scans delivered, {} bad CRCs, {} bytes dropped, {} retransmissions",
        st.framer.bad_checksums, st.framer.dropped_bytes, st.session.retransmissions
    );
    if args.json {
        eprintln!("{line}");
    } else {
        writeln!(std::io::stdout().lock(), "{line}")?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use ima_hal::laser::BeamFlags;

    #[test]
    fn variants_parse() {
        assert_eq!(parse_variant("180x0.5").unwrap(), Variant::W180_R50);
        assert_eq!(parse_variant("100x0.25").unwrap(), Variant::W100_R25);
        assert!(parse_variant("180x0.25").is_err());
        assert!(parse_variant("oops").is_err());
        // Every refusal names the value and lists the variants there are (clap names the
        // flag), as the command line is read.
        for bad in ["oops", "180x0.25", "180xq", "1e9x1", "180x999"] {
            let e = variant(bad).unwrap_err();
            assert!(
                e.starts_with(&format!("{bad:?} is not an LMS variant")) && e.contains("100x0.25"),
                "{e}"
            );
        }
        assert_eq!(lms_baud("9600"), Ok(9600));
        assert_eq!(
            lms_baud("4800"),
            Err("4800 is not an LMS rate (9600, 19200, 38400 or 500000)".to_owned())
        );
    }

    #[test]
    fn json_has_every_beam_in_si_units() {
        let mut s = LaserScan::new(-1.0, 1.0);
        s.push(2.0, BeamFlags::VALID).unwrap();
        s.push(f32::NAN, BeamFlags::NO_RETURN).unwrap();
        s.push(1.5, BeamFlags::DAZZLED).unwrap();
        let at = ima_hal::Instant::from_micros(1_500_000);
        let j = scan_json(3, 0.25, &Stamped::new(at, s), Some(StatusByte(0x90)));
        assert_eq!(j["status"]["byte"], 0x90);
        assert_eq!(j["status"]["pollution"], true);
        assert_eq!(j["status"]["error"], false);
        assert_eq!(j["scan"], 3);
        assert_eq!(j["stamp_s"], 1.5);
        assert_eq!(j["valid"], 1);
        let beams = j["beams"].as_array().unwrap();
        assert_eq!(beams.len(), 3);
        assert_eq!(beams[0]["angle_rad"], -1.0);
        assert_eq!(beams[0]["range_m"], 2.0);
        assert!(beams[0].get("flags").is_none());
        assert!(beams[1]["range_m"].is_null());
        assert_eq!(beams[1]["flags"], serde_json::json!(["no_return"]));
        assert!(beams[2]["range_m"].is_null());
        assert_eq!(beams[2]["flags"], serde_json::json!(["dazzled"]));
    }

    #[test]
    fn svg_and_summary() {
        let mut s = LaserScan::new(-1.0, 1.0);
        s.push(2.0, BeamFlags::VALID).unwrap();
        s.push(f32::NAN, BeamFlags::NO_RETURN).unwrap();
        s.push(1.0, BeamFlags::VALID).unwrap();
        let t = summary(&s);
        assert!(t.contains("3 beams, 2 valid"), "{t}");
        let pic = svg(&s);
        let found = ima_plot::inspect(&pic).unwrap();
        // One dot per valid beam (the legend's dot is larger).
        assert_eq!(
            pic.matches(r##"r="2" opacity="1" fill="#CC2222""##).count(),
            2,
            "{pic}"
        );
        for text in [
            "Laser scan: 3 beams over ±57°, 2 valid, nearest 1.00 m",
            "return: 2 valid beams",
            "beams without a range (not drawn): 1",
            "right of the scanner, −y (m)",
            "ahead, x (m)",
            "scale 50 cm",
        ] {
            assert!(found.has_text(text), "{text} missing: {:?}", found.texts);
        }
        // A scan without a valid beam still draws.
        let mut none = LaserScan::new(-1.0, 1.0);
        none.push(f32::NAN, BeamFlags::NO_RETURN).unwrap();
        let found = ima_plot::inspect(&svg(&none)).unwrap();
        assert!(found.has_text("Laser scan: 1 beams over ±57°, none valid"));
    }
}

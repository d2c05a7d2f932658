//! `ima scan`: connect to a SICK LMS on a serial port, initialise it, print the scan rate and
//! a one-line summary per scan, and optionally write one scan as an SVG picture.

use std::fmt::Write as _;
use std::path::PathBuf;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use clap::Args;
use ima_hal::laser::{LaserScan, LaserScanner};
use ima_sick_lms::decode::Variant;
use ima_sick_lms::driver::expected_scan_rate_hz;
use ima_sick_lms::machine::Config;
use ima_sick_lms::shell::{SickLms, open_port};
use ima_sick_lms::wire::BaudRate;

/// Arguments of `ima scan`.
#[derive(Debug, Args)]
pub struct ScanArgs {
    /// Serial port of the LMS (e.g. /dev/ttyUSB0, or the path `ima mock sick-lms` prints).
    #[arg(long)]
    port: String,
    /// Rate to run at once found: 9600, 19200, 38400 or 500000 (500000 needs RS-422 and is
    /// also probed then).
    #[arg(long, default_value_t = 38400)]
    baud: u32,
    /// Variant: 180x1, 180x0.5, 100x1, 100x0.5 or 100x0.25 (field of view x resolution, °).
    #[arg(long, default_value = "180x0.5")]
    variant: String,
    /// Wait this long (s) for the unit's power-on telegram first (units powered with the
    /// port take up to 60 s to boot).
    #[arg(long)]
    power_up_wait: Option<f64>,
    /// Stop after this many scans (0: run until Ctrl-C).
    #[arg(long, default_value_t = 0)]
    count: u64,
    /// Write the first scan as an SVG picture to this file.
    #[arg(long)]
    svg: Option<PathBuf>,
}

fn parse_variant(s: &str) -> Result<Variant> {
    let (a, r) = s
        .split_once(['x', 'X', '/'])
        .context("variant is FOVxRES, e.g. 180x0.5")?;
    let a: u16 = a.trim().parse().context("field of view")?;
    let r: f64 = r.trim().parse().context("resolution")?;
    let centi = (r * 100.0).round();
    if !(1.0..=100.0).contains(&centi) {
        bail!("resolution {r}° unsupported");
    }
    Variant::new(a, centi as u16).with_context(|| format!("the LMS has no {s} variant"))
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

/// The scan as an SVG picture: sensor at the centre, x (ahead) up, one dot per valid beam,
/// 1 m grid circles.
#[must_use]
pub fn svg(s: &LaserScan) -> String {
    let max = s
        .ranges_m()
        .iter()
        .copied()
        .filter(|r| r.is_finite())
        .fold(1.0f32, f32::max)
        .ceil();
    let size: f64 = 800.0;
    let scale = (size / 2.0 - 20.0) / f64::from(max);
    let c = size / 2.0;
    let mut out = String::new();
    let _ = writeln!(
        out,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{size}" height="{size}" viewBox="0 0 {size} {size}">"#
    );
    let _ = writeln!(out, r#"<rect width="100%" height="100%" fill="white"/>"#);
    for m in 1..=(max as u32) {
        let _ = writeln!(
            out,
            r##"<circle cx="{c}" cy="{c}" r="{:.1}" fill="none" stroke="#ddd"/>"##,
            f64::from(m) * scale
        );
    }
    let mut path = String::new();
    for (a, r, f) in s.beams() {
        if !f.is_valid() || !r.is_finite() {
            continue;
        }
        // Sensor frame: x ahead (screen up), y left (screen left).
        let x = c - f64::from(r) * a.sin() * scale;
        let y = c - f64::from(r) * a.cos() * scale;
        let _ = write!(path, "M{c:.1},{c:.1}L{x:.1},{y:.1}");
        let _ = writeln!(
            out,
            r##"<circle cx="{x:.1}" cy="{y:.1}" r="2" fill="#c22"/>"##
        );
    }
    let _ = writeln!(
        out,
        r##"<path d="{path}" stroke="#f4c0c0" stroke-width="0.5" fill="none"/>"##
    );
    let _ = writeln!(
        out,
        r##"<circle cx="{c}" cy="{c}" r="5" fill="#226"/><text x="10" y="20" font-family="sans-serif" font-size="14">{} beams, grid 1 m</text>"##,
        s.len()
    );
    out.push_str("</svg>\n");
    out
}

/// Run `ima scan`.
pub fn run(args: &ScanArgs) -> Result<()> {
    let baud = BaudRate::from_bps(args.baud)
        .with_context(|| format!("--baud {} is not an LMS rate", args.baud))?;
    let variant = parse_variant(&args.variant)?;
    let cfg = Config {
        baud,
        rs422: baud == BaudRate::B500000,
        variant: Some(variant),
        power_up_wait: args
            .power_up_wait
            .filter(|s| s.is_finite() && *s > 0.0)
            .map(Duration::from_secs_f64),
        ..Config::default()
    };
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()?;
    rt.block_on(async {
        let port = open_port(&args.port, 9600).with_context(|| format!("opening {}", args.port))?;
        let wait = cfg.power_up_wait.unwrap_or_default();
        let mut lms = SickLms::connect(port, cfg, wait + Duration::from_secs(60))
            .await
            .context("initialising the LMS")?
            .with_scan_timeout(Duration::from_secs(5));
        let info = lms.session().context("not ready")?;
        println!(
            "connected: {} at {} baud, {}°/{}°, up to {:.1} scans/s (mirror and line)",
            lms.device_type(),
            info.baud.bps(),
            variant.angle_deg(),
            f64::from(variant.res_centideg()) / 100.0,
            expected_scan_rate_hz(info.baud, variant)
        );
        let mut n = 0u64;
        let mut first: Option<ima_hal::Instant> = None;
        let mut last = lms.now();
        let stop = tokio::signal::ctrl_c();
        tokio::pin!(stop);
        loop {
            let s = tokio::select! {
                s = lms.next_scan(last) => s.context("waiting for a scan")?,
                _ = &mut stop => break,
            };
            last = s.at;
            n += 1;
            let t0 = *first.get_or_insert(s.at);
            let secs = s.at.saturating_duration_since(t0).as_secs_f64();
            let rate = if n > 1 && secs > 0.0 {
                format!("{:.1} scans/s", (n - 1) as f64 / secs)
            } else {
                "rate pending".to_owned()
            };
            println!(
                "scan {n} at {:.3} s ({rate}): {}",
                s.at.as_secs_f64(),
                summary(&s.value)
            );
            if n == 1
                && let Some(p) = &args.svg
            {
                std::fs::write(p, svg(&s.value))
                    .with_context(|| format!("writing {}", p.display()))?;
                println!("wrote {}", p.display());
            }
            if args.count > 0 && n >= args.count {
                break;
            }
        }
        let st = lms.stats();
        println!(
            "{} scans delivered, {} bad CRCs, {} bytes dropped, {} retransmissions",
            st.delivered,
            st.framer.bad_checksums,
            st.framer.dropped_bytes,
            st.session.retransmissions
        );
        let _ = lms.close().await;
        anyhow::Ok(())
    })
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
        assert!(pic.starts_with("<svg") && pic.ends_with("</svg>\n"));
        assert_eq!(pic.matches(r##"fill="#c22""##).count(), 2);
    }
}

//! `ima compass --port PATH`: configure a serial compass and print its heading live (the mock
//! compass is `crate::cmd::mock::compass`).

use std::io::Write;
use std::time::Duration;

use anyhow::{Context, Result};
use clap::{Args, ValueEnum};
use ima_compass::driver::{DriverError, Fault};
use ima_compass::machine::{Config, Dialect, ForeignLine};
use ima_compass::shell::Driver as _;
use ima_compass::shell::{CompassDriver, open_port};
use ima_compass::wire::Tcm2Format;
use ima_hal::compass::HeadingReference;

/// Compass dialects the driver speaks.
#[derive(Debug, Clone, Copy, ValueEnum, PartialEq, Eq)]
pub enum DriverDialect {
    /// KVH C100: set NMEA output (`=t,0`) and the rate (`=r,N`), then read NMEA.
    Kvh,
    /// Any NMEA 0183 heading source, already configured: listen only.
    Nmea,
    /// PNI TCM2: `h`, `sdo=t`, `sp=N`, `go`, then read the standard line.
    Tcm2,
}

/// Arguments of `ima compass`.
#[derive(Debug, Args)]
pub struct CompassArgs {
    /// Serial port (or the pty printed by `ima mock compass`).
    #[arg(long)]
    port: String,
    /// The compass on the port.
    #[arg(long, value_enum, default_value = "kvh")]
    dialect: DriverDialect,
    /// Line speed (default: 4800 for NMEA/KVH, 9600 for TCM2).
    #[arg(long, value_parser = super::num::baud)]
    baud: Option<u32>,
    /// Readings per second asked of the device (KVH: ×60 per minute, at most 10; TCM2:
    /// `sp=N`, at most 8; more is capped, with a warning; a plain NMEA source is asked
    /// nothing).
    #[arg(long, default_value_t = 10, value_parser = super::num::int_in::<u16, 1, 100>)]
    rate: u16,
    /// Stop after this many readings (0: run until interrupted).
    #[arg(long, default_value_t = 0, value_parser = super::num::int_in::<u64, 0, 1_000_000_000>)]
    count: u64,
    /// One JSON object per reading instead of text.
    #[arg(long)]
    json: bool,
    /// Recording and live view.
    #[command(flatten)]
    rec: crate::record::RecordArgs,
}

fn config(args: &CompassArgs) -> Config {
    let dialect = match args.dialect {
        DriverDialect::Kvh => Dialect::KvhC100 {
            rate_per_minute: args.rate.saturating_mul(60).clamp(1, 600),
        },
        DriverDialect::Nmea => Dialect::Nmea,
        DriverDialect::Tcm2 => Dialect::Tcm2 {
            sample_rate_hz: u8::try_from(args.rate.clamp(1, 8)).unwrap_or(8),
            output: Tcm2Format::Standard,
        },
    };
    Config::for_dialect(dialect)
}

/// Run `ima compass`.
pub fn run(args: &CompassArgs) -> Result<()> {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    crate::record::start(&args.rec, "ima compass")?; // record
    let r = rt.block_on(run_async(args));
    let _ = crate::record::finish(); // record: close the file
    r
}

/// How long `ima compass` waits for a compass that went silent before it gives up (after the
/// first 3 s without a heading).
const SILENCE_LIMIT: Duration = Duration::from_secs(30);

async fn run_async(args: &CompassArgs) -> Result<()> {
    let cfg = config(args);
    let most = match args.dialect {
        DriverDialect::Kvh => 10,
        DriverDialect::Tcm2 => 8,
        DriverDialect::Nmea => u16::MAX,
    };
    if args.rate > most {
        eprintln!(
            "ima compass: --rate {} is more than a {} gives: asking for {most} a second",
            args.rate,
            cfg.dialect.name()
        );
    }
    let baud = args.baud.unwrap_or_else(|| cfg.dialect.default_baud());
    let port = open_port(&args.port, baud).with_context(|| format!("opening {}", args.port))?;
    let protocol = match args.dialect {
        DriverDialect::Kvh => "compass-kvh",
        DriverDialect::Nmea => "compass-nmea",
        DriverDialect::Tcm2 => "compass-tcm2",
    };
    let port = crate::record::tap(port, "compass", &args.port, baud, protocol); // record: raw bytes
    // An NMEA source is asked nothing: it is only listened to.
    let (doing, what) = match args.dialect {
        DriverDialect::Nmea => ("listening to", "an NMEA source".to_owned()),
        _ => ("configuring", format!("a {}", cfg.dialect.name())),
    };
    tracing::info!(
        target: "ima::connect",
        "compass: {doing} {what} at {baud} baud on {}",
        args.port
    );
    let drv = match CompassDriver::connect(
        port,
        cfg,
        Duration::from_secs(10),
        ima_hal::time::TokioClock::shared(),
    )
    .await
    {
        Ok(d) => d,
        Err(e) => {
            let hint = match e {
                DriverError::Device(Fault::WrongDialect {
                    seen: ForeignLine::Nmea { .. },
                    ..
                }) => ": try --dialect nmea (or --dialect kvh for a KVH C100)",
                DriverError::Device(Fault::WrongDialect {
                    seen: ForeignLine::Tcm2,
                    ..
                }) => ": try --dialect tcm2",
                DriverError::Device(Fault::NoAnswer { lines, .. })
                    if lines > 0 && args.dialect == DriverDialect::Kvh =>
                {
                    " (an NMEA source that takes no commands? try --dialect nmea)"
                }
                _ => "",
            };
            return Err(anyhow::anyhow!("{e}{hint}"))
                .with_context(|| format!("{doing} the compass on {} at {baud} baud", args.port));
        }
    };
    let start = drv.now();
    let mut after = start;
    let mut n = 0u64;
    let mut stdout = std::io::stdout();
    // A compass that goes quiet is waited for, saying so once per silence, for up to
    // SILENCE_LIMIT: a live display gave up after 3 s without a heading (a replug, a brown-out).
    let mut quiet: Option<std::time::Instant> = None;
    loop {
        let r = tokio::select! {
            r = drv.next_reading(after, Duration::from_secs(3)) => r,
            () = crate::safety::cancelled() => break,
        };
        let r = match r {
            Ok(r) => r,
            Err(DriverError::Timeout) if !drv.link().is_ended() => {
                let since = *quiet.get_or_insert_with(|| {
                    eprintln!("ima compass: no heading for 3 s; waiting for the compass");
                    std::time::Instant::now()
                });
                if since.elapsed() >= SILENCE_LIMIT {
                    anyhow::bail!(
                        "no heading from the compass for {} s: it went silent (unplugged? \
                         powered off?)",
                        SILENCE_LIMIT.as_secs() + 3
                    );
                }
                continue;
            }
            Err(e) => return Err(e).context("reading the compass"),
        };
        if quiet.take().is_some() {
            eprintln!("ima compass: headings again");
        }
        after = r.at;
        let h = &r.value.heading;
        crate::record::with(|rec| rec.log_compass("robot", h.yaw_enu_rad())); // record: heading
        let t = r.at.saturating_duration_since(start).as_secs_f64();
        let reference = match h.reference {
            HeadingReference::Magnetic => "magnetic",
            HeadingReference::True => "true",
        };
        let line = if args.json {
            serde_json::json!({
                "t_s": t,
                "heading_rad": h.heading_rad,
                "heading_deg": h.heading_rad.to_degrees(),
                "reference": reference,
                "deviation_rad": h.deviation_rad,
                "variation_rad": h.variation_rad,
                "magnetic_rad": h.magnetic_rad(),
                "true_rad": h.true_rad(),
                "yaw_enu_rad": h.yaw_enu_rad(),
                "pitch_rad": r.value.pitch_rad,
                "roll_rad": r.value.roll_rad,
                "temperature_c": r.value.temperature_c,
                "error_code": r.value.error_code,
            })
            .to_string()
        } else {
            let mut s = format!(
                "t={t:7.2}s heading {:6.1}° {reference}",
                h.heading_rad.to_degrees()
            );
            if let Some(d) = h.deviation_rad {
                s.push_str(&format!(" deviation {:+.1}°", d.to_degrees()));
                if let Some(m) = h.magnetic_rad() {
                    s.push_str(&format!(" → {:6.1}° corrected", m.to_degrees()));
                }
            }
            if let (Some(p), Some(rl)) = (r.value.pitch_rad, r.value.roll_rad) {
                s.push_str(&format!(
                    " pitch {:+.1}° roll {:+.1}°",
                    p.to_degrees(),
                    rl.to_degrees()
                ));
            }
            s
        };
        writeln!(stdout, "{line}")?;
        stdout.flush()?;
        n += 1;
        if args.count > 0 && n >= args.count {
            break;
        }
    }
    let st = drv.stats();
    // The driver's count includes the readings that came before the first one printed (the
    // one that confirmed the connection, and any before the start).
    eprintln!(
        "{n} headings printed; the driver read {} headings, {} parse errors, {} bad checksums, \
         {} bytes dropped",
        st.headings, st.parse_errors, st.framer.bad_checksums, st.framer.dropped_bytes
    );
    drv.close().await.context("closing the compass")?;
    // Ended by a signal: the status says how (130 for Ctrl-C, 143 for SIGTERM), as every
    // command's does.
    if let Some(s) = crate::safety::signal() {
        return Err(crate::safety::Interrupted(crate::safety::Cause::Signal(s)).into());
    }
    Ok(())
}

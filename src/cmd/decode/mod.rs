//! `ima decode <protocol>`: a capture in, one JSON object per frame out.
//!
//! Contract (shared by every protocol): input is raw bytes, or hex text with `--hex`, from a
//! file or stdin; output is JSON Lines, one object per frame in input order, each with a
//! `"kind"` key (the snake_case message name); physical fields are in SI units with
//! unit-suffixed names (`x_m`, `theta_rad`, `range_m`, `battery_v`) next to the raw values; a
//! bad frame is `{"kind":"error","error":"<reason>","offset":<byte offset>}` and decoding goes
//! on.
//!
//! One module per protocol ([`p2os`], [`rflex`], [`sick`], [`compass`], [`video_mux`]); each
//! takes the bytes, the side that sent them and an `emit` callback, and takes its SI
//! conversions from the driver crate (the driver's own functions, so that `ima decode` shows
//! what the driver would report). [`hex`] reads `--hex` input.

pub mod compass;
pub mod decoder;
pub mod hex;
pub mod p2os;
pub mod rflex;
pub mod sick;
pub mod video_mux;

use std::io::{Read, Write};
use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::{Args, ValueEnum};
use ima_p2os::params::RobotParams;
use serde_json::Value;

pub use self::decoder::Decoder;
pub use self::hex::parse_hex;

/// The largest capture `ima decode` reads (a file or stdin): 1 GiB, about a day of a busy
/// serial line at 115200 baud.
const CAPTURE_LIMIT: u64 = 1 << 30;

/// Protocols `ima decode` understands.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Protocol {
    /// Pioneer 2 P2OS.
    P2os,
    /// Serial compass: NMEA HDG/HDM/HDT, TCM2 lines (`--from host`: KVH/TCM2 commands).
    Compass,
    /// Extron SIS video switcher (`--from host`: SIS commands).
    VideoMux,
    /// Kramer Protocol 2000 video switcher (both directions).
    Kramer,
    /// iRobot/RWI rFLEX (ATRV-Jr).
    Rflex,
    /// SICK LMS 200/291 laser scanner telegrams.
    SickLms,
}

impl Protocol {
    /// The name on the command line (`p2os`, `sick-lms`, …).
    fn name(self) -> String {
        self.to_possible_value()
            .map_or_else(String::new, |v| v.get_name().to_owned())
    }
}

/// Which side of the link the capture is from.
#[derive(Debug, Clone, Copy, ValueEnum, PartialEq, Eq)]
pub enum Direction {
    /// Bytes the robot sent (SIPs, sync replies, CONFIG…).
    Robot,
    /// Bytes the host sent (commands).
    Host,
}

/// Arguments of `ima decode`.
#[derive(Debug, Args)]
pub struct DecodeArgs {
    /// Protocol of the capture (with `--mcap`: the port's recorded protocol when absent).
    #[arg(required_unless_present = "mcap")]
    protocol: Option<Protocol>,
    /// Read the bytes of one serial port from an MCAP recording (`ima ... --record`) instead;
    /// `--from` picks the direction.
    #[arg(long, value_name = "FILE.mcap", requires = "port", conflicts_with_all = ["file", "hex"])]
    mcap: Option<PathBuf>,
    /// With `--mcap`: the port, as its topic (`/scooter/serial/laser`), `robot/device`
    /// (`scooter/laser`) or path.
    #[arg(long, requires = "mcap")]
    port: Option<String>,
    /// Which side sent the bytes.
    #[arg(long, value_enum, default_value = "robot")]
    from: Direction,
    /// The input is hex text (whitespace, commas and `0x` prefixes allowed).
    #[arg(long)]
    hex: bool,
    /// Robot parameters for unit conversion (P2OS subclass: p2at, p2at8, p2dx).
    #[arg(long, default_value = "p2at")]
    robot: String,
    /// Capture file; stdin when absent or `-`.
    file: Option<PathBuf>,
}

/// Run `ima decode`.
pub fn run(args: &DecodeArgs) -> Result<()> {
    let mut raw = Vec::new();
    let mut protocol = args.protocol;
    match &args.file {
        _ if args.mcap.is_some() => {
            let (bytes, recorded) = mcap_bytes(args)?;
            raw = bytes;
            protocol = protocol.or(recorded);
        }
        // `-` is stdin, as for most Unix tools.
        Some(p) if p.as_os_str() != "-" => {
            raw = ima_hal::file::read_limited(p, CAPTURE_LIMIT)
                .with_context(|| format!("reading {}", p.display()))?;
        }
        Some(_) | None => {
            std::io::stdin()
                .take(CAPTURE_LIMIT + 1)
                .read_to_end(&mut raw)
                .context("reading stdin")?;
            anyhow::ensure!(
                raw.len() as u64 <= CAPTURE_LIMIT,
                "stdin: more than {CAPTURE_LIMIT} bytes; decode a capture in parts"
            );
        }
    }
    let bytes = if args.hex {
        parse_hex(std::str::from_utf8(&raw).context("--hex input is not text")?)?
    } else {
        raw
    };
    let params = RobotParams::for_subclass(args.robot.as_bytes())
        .with_context(|| format!("unknown P2OS robot {:?} (p2at, p2at8, p2dx)", args.robot))?;
    let stdout = std::io::stdout();
    let mut out = std::io::BufWriter::new(stdout.lock());
    let host = args.from == Direction::Host;
    let (mut frames, mut errors) = (0u64, 0u64);
    let mut emit = |v: Value| -> Result<()> {
        if v["kind"] == "error" {
            errors += 1;
        } else {
            frames += 1;
        }
        // As an `io::Error`, so that a closed stdout ends the program quietly (141).
        serde_json::to_writer(&mut out, &v).map_err(std::io::Error::from)?;
        out.write_all(b"\n")?;
        Ok(())
    };
    let Some(protocol) = protocol else {
        anyhow::bail!("give the protocol: the recording's port names none that `ima decode` knows");
    };
    match protocol {
        Protocol::P2os => p2os::decode_p2os(&bytes, host, params, &mut emit)?,
        Protocol::Compass => compass::decode(&bytes, host, &mut emit)?,
        Protocol::SickLms => sick::decode_sick_lms(&bytes, host, &mut emit)?,
        Protocol::VideoMux => video_mux::decode_extron(&bytes, host, &mut emit)?,
        Protocol::Kramer => video_mux::decode_kramer(&bytes, &mut emit)?,
        Protocol::Rflex => rflex::decode_rflex(&bytes, host, &mut emit)?,
    }
    out.flush()?;
    if let Some(why) = nothing_decoded(protocol, args.from, bytes.len(), frames, errors) {
        eprintln!("ima decode: {why}");
    }
    Ok(())
}

/// What to tell a user whose `bytes` gave no frame at all (the output is then empty or only
/// errors, which reads as "nothing happened"): most likely the wrong protocol or direction.
fn nothing_decoded(
    protocol: Protocol,
    from: Direction,
    bytes: usize,
    frames: u64,
    errors: u64,
) -> Option<String> {
    if bytes == 0 || frames > 0 {
        return None;
    }
    let name = protocol.name();
    let rejected = if errors > 0 {
        format!(" ({errors} rejected)")
    } else {
        String::new()
    };
    // Kramer's protocol is the same both ways: no direction to suggest.
    if matches!(protocol, Protocol::Kramer) {
        return Some(format!(
            "no {name} frame in {bytes} bytes{rejected}: another protocol?"
        ));
    }
    let other = match from {
        Direction::Robot => "host",
        Direction::Host => "robot",
    };
    Some(format!(
        "no {name} frame in {bytes} bytes{rejected}: another protocol, or the other direction \
         (`--from {other}`)?"
    ))
}

/// The protocol of a recorded port's `protocol` metadata.
pub fn recorded_protocol(name: &str) -> Option<Protocol> {
    Some(match name {
        "p2os" => Protocol::P2os,
        "rflex" => Protocol::Rflex,
        "sick-lms" => Protocol::SickLms,
        "compass-kvh" | "compass-nmea" | "compass-tcm2" => Protocol::Compass,
        "video-mux-extron" => Protocol::VideoMux,
        "video-mux-kramer" => Protocol::Kramer,
        _ => return None,
    })
}

/// `--mcap FILE --port NAME`: the port's bytes in the `--from` direction, and its protocol.
fn mcap_bytes(args: &DecodeArgs) -> Result<(Vec<u8>, Option<Protocol>)> {
    let (Some(path), Some(port)) = (&args.mcap, &args.port) else {
        anyhow::bail!("--mcap needs --port");
    };
    let rec = ima_record::read::Recording::open(path)?;
    let stream = rec.raw_stream(port);
    if let Some(why) = rec.damage() {
        eprintln!("ima decode: the recording is damaged ({why}); decoding the bytes it holds");
    }
    let stream = stream?;
    let recorded = recorded_protocol(&stream.port.protocol);
    if let (Some(asked), Some(rec)) = (args.protocol, recorded)
        && asked != rec
    {
        eprintln!(
            "ima decode: {} was recorded as {}; decoding it as {} as asked",
            stream.topic,
            stream.port.protocol,
            asked.name()
        );
    }
    let want = match args.from {
        Direction::Robot => ima_record::raw::Dir::Rx,
        Direction::Host => ima_record::raw::Dir::Tx,
    };
    let bytes = stream
        .chunks
        .iter()
        .filter(|c| c.1 == want)
        .flat_map(|c| c.2.iter().copied())
        .collect();
    Ok((bytes, recorded))
}

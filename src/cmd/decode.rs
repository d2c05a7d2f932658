//! `ima decode <protocol>`: a capture in, one JSON object per frame out.
//!
//! Contract (shared by every protocol): input is raw bytes, or hex text with `--hex`, from a
//! file or stdin; output is JSON Lines, one object per frame in input order, each with a
//! `"kind"` key (the snake_case message name); physical fields are in SI units with
//! unit-suffixed names (`x_m`, `theta_rad`, `range_m`, `battery_v`) next to the raw values; a
//! bad frame is `{"kind":"error","error":"<reason>","offset":<byte offset>}` and decoding goes
//! on.

use std::io::{Read, Write};
use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use clap::{Args, ValueEnum};
use ima_p2os::framer::{FrameEvent, Framer, Rejected};
use ima_p2os::params::RobotParams;
use ima_p2os::wire::{Arg, Command, Packet};
use serde_json::{Value, json};

/// Protocols `ima decode` understands.
#[derive(Debug, Clone, Copy, ValueEnum)]
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
    /// Capture file; stdin when absent.
    file: Option<PathBuf>,
}

/// Parse hex text: tokens split by whitespace or commas, optional `0x` prefix, pairs of digits.
pub fn parse_hex(text: &str) -> Result<Vec<u8>> {
    let mut out = Vec::new();
    for token in text.split(|c: char| c.is_whitespace() || c == ',') {
        let t = token.trim_start_matches("0x").trim_start_matches("0X");
        if t.is_empty() {
            continue;
        }
        if t.len() % 2 != 0 {
            bail!("hex token {token:?} has an odd number of digits");
        }
        for i in (0..t.len()).step_by(2) {
            let pair = t.get(i..i + 2).context("hex token")?;
            out.push(u8::from_str_radix(pair, 16).with_context(|| format!("bad hex {pair:?}"))?);
        }
    }
    Ok(out)
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
        Some(p) => {
            raw = std::fs::read(p).with_context(|| format!("reading {}", p.display()))?;
        }
        None => {
            std::io::stdin()
                .read_to_end(&mut raw)
                .context("reading stdin")?;
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
    let mut emit = |v: Value| -> Result<()> {
        serde_json::to_writer(&mut out, &v)?;
        out.write_all(b"\n")?;
        Ok(())
    };
    let Some(protocol) = protocol else {
        bail!("give the protocol: the recording's port names none that `ima decode` knows");
    };
    match protocol {
        Protocol::P2os => decode_p2os(&bytes, args.from, params, &mut emit)?,
        Protocol::Compass => super::decode_compass::decode(&bytes, host, &mut emit)?,
        Protocol::SickLms => super::decode_sick::decode_sick_lms(&bytes, host, &mut emit)?,
        Protocol::VideoMux => super::decode_video_mux::decode_extron(&bytes, host, &mut emit)?,
        Protocol::Kramer => super::decode_video_mux::decode_kramer(&bytes, &mut emit)?,
        Protocol::Rflex => super::decode_rflex::decode_rflex(&bytes, args.from, &mut emit)?,
    }
    out.flush()?;
    Ok(())
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
        bail!("--mcap needs --port");
    };
    let rec = ima_record::read::Recording::open(path)?;
    let stream = rec.raw_stream(port)?;
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
    Ok((bytes, recorded_protocol(&stream.port.protocol)))
}

/// Decode a P2OS byte stream, calling `emit` with one JSON object per frame or error.
pub fn decode_p2os(
    bytes: &[u8],
    from: Direction,
    params: &RobotParams,
    emit: &mut dyn FnMut(Value) -> Result<()>,
) -> Result<()> {
    let mut framer = if from == Direction::Host {
        Framer::for_commands()
    } else {
        Framer::new()
    };
    let mut input = bytes;
    loop {
        let n = framer.feed(input);
        input = input.get(n..).unwrap_or(&[]);
        loop {
            let (v, frame_len) = match framer.next_frame() {
                None => break,
                Some(FrameEvent::Rejected(r)) => {
                    let reason = match r {
                        Rejected::BadCount(c) => format!("bad count byte {c}"),
                        Rejected::BadChecksum { expected, got } => {
                            format!("bad checksum: computed {expected:#06x}, frame has {got:#06x}")
                        }
                    };
                    (Err(reason), 0usize)
                }
                Some(FrameEvent::Frame(p)) => {
                    let v = if from == Direction::Host {
                        Command::parse(p).map(command_json)
                    } else {
                        Packet::parse(p).map(|pk| packet_json(&pk, params))
                    };
                    (v.map_err(|e| e.to_string()), p.len() + 5)
                }
            };
            let offset = if frame_len == 0 {
                framer.position().saturating_sub(1)
            } else {
                framer.position().saturating_sub(frame_len as u64)
            };
            emit(match v {
                Ok(mut v) => {
                    v["offset"] = json!(offset);
                    v
                }
                Err(e) => json!({"kind": "error", "error": e, "offset": offset}),
            })?;
        }
        if input.is_empty() || n == 0 {
            break;
        }
    }
    if framer.buffered() > 0 {
        emit(
            json!({"kind": "error", "error": "truncated frame at end of input",
            "offset": framer.position()}),
        )?;
    }
    Ok(())
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

fn command_json(c: Command<'_>) -> Value {
    let mut v = json!({"kind": c.name(), "command": c.number()});
    match c {
        Command::Int(ic, x) => {
            v["value"] = json!(x);
            let si = match ic {
                ima_p2os::wire::IntCommand::Vel | ima_p2os::wire::IntCommand::SetV => {
                    Some(("v_m_s", f64::from(x) / 1000.0))
                }
                ima_p2os::wire::IntCommand::RVel
                | ima_p2os::wire::IntCommand::Rotate
                | ima_p2os::wire::IntCommand::SetRv => {
                    Some(("omega_rad_s", f64::from(x).to_radians()))
                }
                ima_p2os::wire::IntCommand::Move => Some(("distance_m", f64::from(x) / 1000.0)),
                ima_p2os::wire::IntCommand::Head
                | ima_p2os::wire::IntCommand::DHead
                | ima_p2os::wire::IntCommand::DcHead => {
                    Some(("heading_rad", f64::from(x).to_radians()))
                }
                ima_p2os::wire::IntCommand::SetA => Some(("accel_m_s2", f64::from(x) / 1000.0)),
                ima_p2os::wire::IntCommand::SetRa => {
                    Some(("accel_rad_s2", f64::from(x).to_radians()))
                }
                _ => None,
            };
            if let Some((k, x)) = si {
                v[k] = json!(x);
            }
        }
        Command::Vel2 { left, right } => {
            v["left_raw"] = json!(left);
            v["right_raw"] = json!(right);
            v["left_m_s"] = json!(f64::from(left) * 0.020);
            v["right_m_s"] = json!(f64::from(right) * 0.020);
        }
        Command::Str(_, s) => v["bytes"] = json!(s),
        Command::Other { arg, .. } => {
            v["arg"] = match arg {
                Arg::None => Value::Null,
                Arg::Int(i) => json!(i.value()),
                Arg::Str(s) => json!(s),
            }
        }
        _ => {}
    }
    v
}

fn packet_json(p: &Packet<'_>, params: &RobotParams) -> Value {
    let mut v = json!({"kind": p.name()});
    match p {
        Packet::SyncEcho(b) => v["byte"] = json!(b),
        Packet::SyncReply {
            name,
            class,
            subclass,
        } => {
            v["name"] = json!(text(name));
            v["class"] = json!(text(class));
            v["subclass"] = json!(text(subclass));
        }
        Packet::Sip(s) => {
            let vel = |x: i16| f64::from(x) * params.vel_conv / 1000.0;
            v = json!({
                "kind": "sip",
                "moving": s.moving,
                "x_raw": s.xpos, "x_m": f64::from(s.xpos) * params.dist_conv / 1000.0,
                "y_raw": s.ypos, "y_m": f64::from(s.ypos) * params.dist_conv / 1000.0,
                "theta_raw": s.thpos,
                "theta_rad": ima_hal::normalize_angle(f64::from(s.thpos) * params.angle_conv),
                "left_vel_raw": s.left_vel, "left_vel_m_s": vel(s.left_vel),
                "right_vel_raw": s.right_vel, "right_vel_m_s": vel(s.right_vel),
                "v_m_s": (vel(s.left_vel) + vel(s.right_vel)) / 2.0,
                "omega_rad_s": (f64::from(s.right_vel) - f64::from(s.left_vel)) / 2.0
                    * params.vel_conv * params.diff_conv,
                "battery_raw": s.battery, "battery_v": f64::from(s.battery) / 10.0,
                "stall_bumpers": s.stall_bumpers,
                "control_raw": s.control,
                "flags": s.flags, "motors_enabled": s.motors_enabled(),
                "compass_raw": s.compass,
                "sonar": s.sonars.iter().map(|r| json!({
                    "index": r.index, "range_raw": r.range,
                    "range_m": f64::from(r.range) * params.range_conv / 1000.0,
                })).collect::<Vec<_>>(),
                "grip_state": s.grip_state, "anport": s.anport,
                "analog_raw": s.analog, "analog_v": f64::from(s.analog) * 5.0 / 255.0,
                "digin": s.digin, "digout": s.digout, "extra_bytes": s.extra_len,
            });
        }
        Packet::Config(c) => {
            v["type"] = json!(text(c.robot_type));
            v["subtype"] = json!(text(c.subtype));
            v["serial"] = json!(text(c.serial));
            v["name"] = json!(text(c.name));
            v["firmware"] = json!(text(c.firmware));
            v["rot_vel_top_rad_s"] = json!(f64::from(c.rot_vel_top).to_radians());
            v["trans_vel_top_m_s"] = json!(f64::from(c.trans_vel_top) / 1000.0);
            let mut fields = serde_json::Map::new();
            c.numbers.for_each(|k, x| {
                fields.insert(k.into(), json!(x));
            });
            v["fields"] = Value::Object(fields);
        }
        Packet::Encoder { left, right } => {
            v["left_ticks"] = json!(left);
            v["right_ticks"] = json!(right);
            v["left_m"] = json!(f64::from(*left) / params.ticks_per_mm / 1000.0);
            v["right_m"] = json!(f64::from(*right) / params.ticks_per_mm / 1000.0);
        }
        Packet::SerAux { port, data } => {
            v["port"] = json!(port);
            v["bytes"] = json!(data);
        }
        Packet::Unknown { ptype, body } => {
            v["type"] = json!(ptype);
            v["bytes"] = json!(body);
        }
    }
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    fn decode(bytes: &[u8], from: Direction) -> Vec<Value> {
        let mut out = Vec::new();
        decode_p2os(bytes, from, &ima_p2os::params::P2AT, &mut |v| {
            out.push(v);
            Ok(())
        })
        .unwrap();
        out
    }

    #[test]
    fn t20_sip_decodes_to_si_fields() {
        let bytes = parse_hex(
            "FA FB 21 33 E8 03 F4 01 00 04 CE FF 32 00 7D 00 00 00 04 01 00 00 02 00 4A 07 07 93 0E 00 00 00 FF 0F D9 B2",
        )
        .unwrap();
        let v = decode(&bytes, Direction::Robot);
        assert_eq!(v.len(), 1);
        assert_eq!(v[0]["kind"], "sip");
        assert!((v[0]["x_m"].as_f64().unwrap() - 1.32).abs() < 1e-9);
        assert!((v[0]["theta_rad"].as_f64().unwrap() - 1.570816).abs() < 1e-6);
        assert!((v[0]["omega_rad_s"].as_f64().unwrap() - 0.17).abs() < 1e-9);
        assert!((v[0]["battery_v"].as_f64().unwrap() - 12.5).abs() < 1e-9);
        assert_eq!(v[0]["sonar"][1]["index"], 7);
        assert_eq!(v[0]["offset"], 0);
    }

    #[test]
    fn bad_frames_become_errors_with_offsets_and_decoding_goes_on() {
        let mut bytes = parse_hex("00 11 FA FB 06 0B 3B C8 00 D3 3C").unwrap(); // bad checksum at 2
        bytes.extend(parse_hex("FA FB 06 0B 1B C8 00 D3 1B").unwrap()); // VEL -200 at 11
        let v = decode(&bytes, Direction::Host);
        assert_eq!(v[0]["kind"], "error");
        assert_eq!(v[0]["offset"], 2);
        assert!(v[0]["error"].as_str().unwrap().contains("checksum"));
        assert_eq!(v[1]["kind"], "vel");
        assert_eq!(v[1]["offset"], 11);
        assert!((v[1]["v_m_s"].as_f64().unwrap() + 0.2).abs() < 1e-12);
        assert_eq!(v.len(), 2);
    }

    #[test]
    fn hex_parser_accepts_common_forms_and_rejects_odd_digits() {
        assert_eq!(
            parse_hex("FA fb,0x03 0000").unwrap(),
            vec![0xFA, 0xFB, 3, 0, 0]
        );
        assert!(parse_hex("F").is_err());
        assert!(parse_hex("zz").is_err());
    }
}

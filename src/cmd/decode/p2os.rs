//! `ima decode p2os`: a P2OS capture (either direction) as JSON Lines, under the contract of
//! `ima decode` (see the parent module). SIP fields use the driver's conversions
//! ([`RobotParams`] methods, [`ima_p2os::params::battery_v`]); XPOS/YPOS are read as the
//! signed 15-bit counts the driver's odometry uses ([`ima_p2os::machine::signed15`]).

use anyhow::Result;
use ima_p2os::framer::{FrameEvent, Framer, Rejected};
use ima_p2os::params::{RobotParams, battery_v, encoder_m};
use ima_p2os::wire::{Arg, Command, Packet};
use serde_json::{Value, json};

use super::decoder::Decoder;

/// A P2OS byte stream decoded a piece at a time (see [`Decoder`]): one JSON object per frame or
/// error.
pub struct P2osDecoder<'a> {
    framer: Framer,
    host: bool,
    params: &'a RobotParams,
    /// Take the parameter table the robot names in its SYNC2 reply, as the driver does.
    follow: bool,
}

impl<'a> P2osDecoder<'a> {
    /// A decoder of the host's commands (`host`) or the robot's packets, in `params`' units.
    pub fn new(host: bool, params: &'a RobotParams) -> Self {
        let framer = if host {
            Framer::for_commands()
        } else {
            Framer::new()
        };
        Self {
            framer,
            host,
            params,
            follow: false,
        }
    }

    /// A decoder of the robot's packets in `params`' units until the robot's SYNC2 reply names
    /// a subclass that has a table (`p2at`, `p2at8`, `p2dx`, in any case), in that table's from
    /// then on: the one the driver takes when it is not told one. The reply's object says which
    /// (`"params"`); an unknown subclass keeps the table in use.
    pub fn following(params: &'a RobotParams) -> Self {
        Self {
            follow: true,
            ..Self::new(false, params)
        }
    }
}

impl Decoder for P2osDecoder<'_> {
    fn feed(&mut self, bytes: &[u8], emit: &mut dyn FnMut(Value) -> Result<()>) -> Result<()> {
        let (framer, host, follow) = (&mut self.framer, self.host, self.follow);
        let params = &mut self.params;
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
                            Rejected::BadChecksum { expected, got } => format!(
                                "bad checksum: computed {expected:#06x}, frame has {got:#06x}"
                            ),
                        };
                        (Err(reason), 0usize)
                    }
                    Some(FrameEvent::Frame(p)) => {
                        let v = if host {
                            Command::parse(p).map(|c| command_json(c, params))
                        } else {
                            Packet::parse(p).map(|pk| match &pk {
                                Packet::SyncReply { subclass, .. } if follow => {
                                    if let Some(own) = RobotParams::for_subclass(subclass) {
                                        *params = own;
                                    }
                                    let mut v = packet_json(&pk, params);
                                    v["params"] = json!(params.subclass);
                                    v
                                }
                                _ => packet_json(&pk, params),
                            })
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
        Ok(())
    }

    fn finish(&mut self, emit: &mut dyn FnMut(Value) -> Result<()>) -> Result<()> {
        if self.framer.buffered() > 0 {
            emit(
                json!({"kind": "error", "error": "truncated frame at end of input",
                "offset": self.framer.position()}),
            )?;
        }
        Ok(())
    }
}

/// The parameter table a recorded P2OS port's metadata names (`params`: the driver was told
/// one, which overrides the robot's SYNC2 reply), if it names one this program has.
pub fn recorded_params(
    recorded: &std::collections::BTreeMap<String, String>,
) -> Option<&'static RobotParams> {
    RobotParams::for_subclass(recorded.get("params")?.as_bytes())
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

fn command_json(c: Command<'_>, params: &RobotParams) -> Value {
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
            v["left_m_s"] = json!(params.vel2_m_s(left));
            v["right_m_s"] = json!(params.vel2_m_s(right));
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
            let (v_m_s, omega_rad_s) = params.body_velocity(s.left_vel, s.right_vel);
            v = json!({
                "kind": "sip",
                "moving": s.moving,
                "x_raw": s.xpos, "x_m": params.position_m(s.xpos),
                "y_raw": s.ypos, "y_m": params.position_m(s.ypos),
                "theta_raw": s.thpos,
                "theta_rad": params.heading_rad(s.thpos),
                "left_vel_raw": s.left_vel, "left_vel_m_s": params.wheel_m_s(s.left_vel),
                "right_vel_raw": s.right_vel, "right_vel_m_s": params.wheel_m_s(s.right_vel),
                "v_m_s": v_m_s,
                "omega_rad_s": omega_rad_s,
                "battery_raw": s.battery, "battery_v": battery_v(s.battery),
                "stall_bumpers": s.stall_bumpers,
                "control_raw": s.control,
                "flags": s.flags, "motors_enabled": s.motors_enabled(),
                "compass_raw": s.compass,
                "sonar": s.sonars.iter().map(|r| json!({
                    "index": r.index, "range_raw": r.range,
                    "range_m": params.sonar_range_m(r.range),
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
            v["left_m"] = json!(encoder_m(*left, params.ticks_per_mm));
            v["right_m"] = json!(encoder_m(*right, params.ticks_per_mm));
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
    use crate::cmd::decode::hex::parse_hex;

    fn decode(bytes: &[u8], host: bool) -> Vec<Value> {
        let mut out = Vec::new();
        P2osDecoder::new(host, &ima_p2os::params::P2AT)
            .decode_whole(bytes, &mut |v| {
                out.push(v);
                Ok(())
            })
            .unwrap();
        out
    }

    /// Fed in pieces, the stream decodes as fed whole (both directions, with damage).
    #[test]
    fn pieces_decode_as_the_whole() {
        let mut robot = parse_hex(
            "FA FB 21 33 E8 03 F4 01 00 04 CE FF 32 00 7D 00 00 00 04 01 00 00 02 00 4A 07 07 93 0E 00 00 00 FF 0F D9 B2",
        )
        .unwrap();
        robot.extend(parse_hex("00 11 FA FB 06 0B 3B C8 00 D3 3C FA FB").unwrap());
        robot.extend(robot.clone());
        let v = crate::cmd::decode::decoder::pieces::decode_alike(
            &|| Box::new(P2osDecoder::new(false, &ima_p2os::params::P2AT)),
            &robot,
        );
        assert!(v.iter().any(|v| v["kind"] == "sip"), "{v:?}");
        assert!(v.iter().any(|v| v["kind"] == "error"), "{v:?}");
        let mut host = parse_hex("00 11 FA FB 06 0B 3B C8 00 D3 3C").unwrap();
        host.extend(parse_hex("FA FB 06 0B 1B C8 00 D3 1B FA").unwrap());
        let v = crate::cmd::decode::decoder::pieces::decode_alike(
            &|| Box::new(P2osDecoder::new(true, &ima_p2os::params::P2AT)),
            &host,
        );
        assert_eq!(
            v.last().unwrap()["error"],
            "truncated frame at end of input"
        );
    }

    #[test]
    fn t20_sip_decodes_to_si_fields() {
        let bytes = parse_hex(
            "FA FB 21 33 E8 03 F4 01 00 04 CE FF 32 00 7D 00 00 00 04 01 00 00 02 00 4A 07 07 93 0E 00 00 00 FF 0F D9 B2",
        )
        .unwrap();
        let v = decode(&bytes, false);
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
        let v = decode(&bytes, true);
        assert_eq!(v[0]["kind"], "error");
        assert_eq!(v[0]["offset"], 2);
        assert!(v[0]["error"].as_str().unwrap().contains("checksum"));
        assert_eq!(v[1]["kind"], "vel");
        assert_eq!(v[1]["offset"], 11);
        assert!((v[1]["v_m_s"].as_f64().unwrap() + 0.2).abs() < 1e-12);
        assert_eq!(v.len(), 2);
    }

    fn sip_frame(sip: ima_p2os::wire::Sip) -> Vec<u8> {
        let mut out = [0u8; 256];
        let n = Packet::Sip(sip).emit(&mut out).unwrap();
        out[..n].to_vec()
    }

    fn f(v: &Value, key: &str) -> f64 {
        v[key].as_f64().unwrap_or_else(|| panic!("{key} in {v}"))
    }

    fn sync2_frame(subclass: &[u8]) -> Vec<u8> {
        let mut out = [0u8; 256];
        let reply = Packet::SyncReply {
            name: b"Skeeter",
            class: b"Pioneer",
            subclass,
        };
        let n = reply.emit(&mut out).unwrap();
        out[..n].to_vec()
    }

    /// Without `--robot`, a SIP is read in the units of the robot its SYNC2 reply names (a
    /// P2-DX: 0.84 mm per count, not the P2-AT's 1.32), as the driver reads it; an unknown
    /// subclass keeps the table in use; `--robot` fixes the table whatever the robot says.
    #[test]
    fn the_robot_s_own_sync2_reply_picks_its_units() {
        let sip = sip_frame(ima_p2os::wire::Sip {
            xpos: 1000,
            ..Default::default()
        });
        let decode_with = |d: P2osDecoder<'_>, bytes: &[u8]| {
            let mut out = Vec::new();
            d.decode_whole(bytes, &mut |v| {
                out.push(v);
                Ok(())
            })
            .unwrap();
            out
        };
        let p2at = &ima_p2os::params::P2AT;
        let mut bytes = sip.clone();
        bytes.extend(sync2_frame(b"p2dx"));
        bytes.extend(&sip);
        let v = decode_with(P2osDecoder::following(p2at), &bytes);
        assert!((f(&v[0], "x_m") - 1.32).abs() < 1e-12, "{v:?}");
        assert_eq!(
            (&v[1]["kind"], &v[1]["params"]),
            (&json!("sync2"), &json!("p2dx"))
        );
        assert!((f(&v[2], "x_m") - 0.84).abs() < 1e-12, "{v:?}");
        // Decoded in pieces, the same.
        let pieces = crate::cmd::decode::decoder::pieces::decode_alike(
            &|| Box::new(P2osDecoder::following(p2at)),
            &bytes,
        );
        assert_eq!(pieces, v);
        let mut unknown = sync2_frame(b"p3xx");
        unknown.extend(&sip);
        let v = decode_with(P2osDecoder::following(p2at), &unknown);
        assert_eq!(v[0]["params"], "p2at");
        assert!((f(&v[1], "x_m") - 1.32).abs() < 1e-12, "{v:?}");
        let v = decode_with(P2osDecoder::new(false, p2at), &bytes);
        assert!(v[1].get("params").is_none(), "{v:?}");
        assert!((f(&v[2], "x_m") - 1.32).abs() < 1e-12, "{v:?}");
    }

    #[test]
    fn a_wrapped_position_is_negative_as_the_odometry_reads_it() {
        // A P2-AT 0.57 m behind its origin reports XPOS 0x7E4D (435 counts below 2^15); read
        // unsigned that was 42.68 m.
        let sip = ima_p2os::wire::Sip {
            xpos: 0x7E4D,
            ypos: 100,
            battery: 125,
            ..Default::default()
        };
        let v = decode(&sip_frame(sip), false);
        assert_eq!(v[0]["kind"], "sip");
        assert_eq!(v[0]["x_raw"], 0x7E4D);
        let x = f(&v[0], "x_m");
        assert!((x + 0.5742).abs() < 1e-12, "x_m = {x}");
        assert_eq!(x, ima_p2os::params::P2AT.position_m(0x7E4D));
        assert_eq!(
            f64::from(ima_p2os::machine::signed15(0x7E4D)),
            f64::from(ima_p2os::machine::unwrap15(0, 0x7E4D)),
            "the same count the odometry's step from 0 gives"
        );
        assert!((f(&v[0], "y_m") - 0.132).abs() < 1e-12);
    }

    #[test]
    fn sip_fields_are_the_drivers_conversions() {
        use ima_p2os::params::P2AT;
        let mut sip = ima_p2os::wire::Sip {
            xpos: 0x4321,
            ypos: 0x0123,
            thpos: -1500,
            left_vel: -333,
            right_vel: 517,
            battery: 131,
            ..Default::default()
        };
        sip.sonars
            .push(ima_p2os::wire::SonarRaw {
                index: 3,
                range: 4321,
            })
            .unwrap();
        let v = decode(&sip_frame(sip.clone()), false);
        let (vel, omega) = P2AT.body_velocity(sip.left_vel, sip.right_vel);
        assert_eq!(f(&v[0], "x_m"), P2AT.position_m(sip.xpos));
        assert_eq!(f(&v[0], "y_m"), P2AT.position_m(sip.ypos));
        assert_eq!(f(&v[0], "theta_rad"), P2AT.heading_rad(sip.thpos));
        assert_eq!(f(&v[0], "v_m_s"), vel);
        assert_eq!(f(&v[0], "omega_rad_s"), omega);
        assert_eq!(f(&v[0], "left_vel_m_s"), P2AT.wheel_m_s(sip.left_vel));
        assert_eq!(f(&v[0], "right_vel_m_s"), P2AT.wheel_m_s(sip.right_vel));
        assert_eq!(f(&v[0], "battery_v"), battery_v(sip.battery));
        assert_eq!(f(&v[0]["sonar"][0], "range_m"), P2AT.sonar_range_m(4321));
        // The encoder packet and VEL2 take the driver's conversions too.
        let mut out = [0u8; 64];
        let n = Packet::Encoder {
            left: 1900,
            right: -3800,
        }
        .emit(&mut out)
        .unwrap();
        let e = decode(&out[..n], false);
        assert_eq!(f(&e[0], "left_m"), encoder_m(1900, P2AT.ticks_per_mm));
        assert_eq!(f(&e[0], "right_m"), encoder_m(-3800, P2AT.ticks_per_mm));
        let n = Command::Vel2 {
            left: -7,
            right: 12,
        }
        .emit(&mut out)
        .unwrap();
        let c = decode(&out[..n], true);
        assert_eq!(c[0]["kind"], "vel2");
        assert_eq!(f(&c[0], "left_m_s"), P2AT.vel2_m_s(-7));
        assert_eq!(f(&c[0], "right_m_s"), P2AT.vel2_m_s(12));
    }
}

//! `ima decode rflex`: an rFLEX capture (either direction) as JSON Lines, under the contract
//! of `ima decode` (see the parent module): one object per frame with a snake_case `"kind"`,
//! SI fields with unit suffixes next to the raw values, converted by the driver's own
//! [`Config`] methods (ATRV-Jr defaults: Kd 90810 units/m, Ka 37000 units/rad, sonar 1476
//! units/m clipped at 10000 = no echo, battery raw/100 + 1.2 V), `"offset"` = byte offset of
//! the frame's `ESC STX`, and `{"kind":"error","error":…,"offset":…}` for a dropped frame.

use anyhow::Result;
use ima_rflex::framer::{FrameError, Framer};
use ima_rflex::machine::Config;
use ima_rflex::wire::{Command, Report, SetDir};
use serde_json::{Value, json};

use super::decoder::Decoder;

/// An rFLEX byte stream decoded a piece at a time (see [`Decoder`]): one JSON object per frame
/// or error.
pub struct RflexDecoder {
    cfg: Config,
    host: bool,
    framer: Framer,
    /// Offset of the first byte of the next feed.
    base: usize,
    /// Offset of the most recent ESC STX (where the current candidate frame began).
    start: usize,
    prev_esc: bool,
    /// The framer took nothing of a non-empty input: the rest of the capture is not read.
    stuck: bool,
}

impl RflexDecoder {
    /// A decoder of the host's commands (`host`) or the base's reports, in the ATRV-Jr's
    /// units.
    pub fn new(host: bool) -> Self {
        Self::with_config(host, Config::default())
    }

    /// A decoder converting with `cfg`'s factors (`kd`, `ka`, sonar, battery): a recorded
    /// port's, from [`recorded_config`].
    pub fn with_config(host: bool, cfg: Config) -> Self {
        Self {
            cfg,
            host,
            framer: Framer::strict(),
            base: 0,
            start: 0,
            prev_esc: false,
            stuck: false,
        }
    }
}

impl Decoder for RflexDecoder {
    fn feed(&mut self, bytes: &[u8], emit: &mut dyn FnMut(Value) -> Result<()>) -> Result<()> {
        let base = self.base;
        self.base = self.base.saturating_add(bytes.len());
        let mut pos = 0usize;
        while pos < bytes.len() && !self.stuck {
            let rest = bytes.get(pos..).unwrap_or(&[]);
            let (used, item) = self.framer.decode(rest);
            // Track the last ESC STX inside the consumed bytes.
            for (i, &b) in rest.iter().take(used).enumerate() {
                if self.prev_esc && b == ima_rflex::wire::STX {
                    self.start = base.saturating_add(pos + i).saturating_sub(1);
                }
                self.prev_esc = b == ima_rflex::wire::ESC && !self.prev_esc;
            }
            pos += used;
            if let Some(item) = item {
                let v = match item {
                    Ok(raw) => {
                        let v = if self.host {
                            Command::from_raw(&raw).map(|c| command_json(&c, &self.cfg))
                        } else {
                            Report::from_raw(&raw).map(|r| report_json(&r, &self.cfg))
                        };
                        match v {
                            Ok(mut v) => {
                                v["id"] = json!(raw.id);
                                v["offset"] = json!(self.start);
                                v
                            }
                            Err(e) => {
                                json!({"kind": "error", "error": e.to_string(), "offset": self.start})
                            }
                        }
                    }
                    Err(e) => {
                        let reason = match e {
                            FrameError::Invalid(w) => w.to_string(),
                            FrameError::BadEscape(b) => format!("ESC followed by {b:#04x}"),
                            FrameError::Oversize => "frame longer than 264 bytes".to_owned(),
                            FrameError::Restarted => "ESC STX before ESC ETX".to_owned(),
                        };
                        json!({"kind": "error", "error": reason, "offset": self.start})
                    }
                };
                emit(v)?;
            }
            self.stuck = used == 0;
        }
        Ok(())
    }

    fn finish(&mut self, emit: &mut dyn FnMut(Value) -> Result<()>) -> Result<()> {
        if self.framer.in_frame() {
            emit(
                json!({"kind": "error", "error": "truncated frame at end of input", "offset": self.start}),
            )?;
        }
        Ok(())
    }
}

fn set_dir_json(s: &SetDir, cfg: &Config) -> Value {
    let mut v = json!({
        "kind": "set_dir", "axis": s.axis, "velocity": s.velocity,
        "acceleration": s.acceleration, "torque": s.torque, "forward": s.forward,
    });
    let names = match s.axis {
        0 => Some(("v_m_s", "accel_m_s2")),
        1 => Some(("omega_rad_s", "accel_rad_s2")),
        _ => None,
    };
    if let (Some((speed, accel)), Some((x, a))) = (names, cfg.set_dir_si(s)) {
        v[speed] = json!(x);
        v[accel] = json!(a);
    }
    v
}

fn command_json(c: &Command, cfg: &Config) -> Value {
    match c {
        Command::SysStatusRequest => json!({"kind": "sys_status_request"}),
        Command::SetDir(s) => set_dir_json(s, cfg),
        Command::SetDefaults => json!({"kind": "set_defaults"}),
        Command::BrakeSet => json!({"kind": "brake_set"}),
        Command::BrakeRelease => json!({"kind": "brake_release"}),
        Command::SystemReportReq { period_us, mask } => json!({
            "kind": "system_report_req", "period_us": period_us, "mask": mask,
            "period_s": f64::from(*period_us) / 1e6,
        }),
        Command::SonarRun(r) => json!({
            "kind": "sonar_run", "echo_delay_us": r.echo_delay_us, "ping_delay_us": r.ping_delay_us,
            "set_delay_us": r.set_delay_us, "mode": r.mode, "on": r.mode == 2,
        }),
        Command::DioReportsReq { period_us } => json!({
            "kind": "dio_reports_req", "period_us": period_us, "period_s": f64::from(*period_us) / 1e6,
        }),
        Command::JoystickRequest => json!({"kind": "joystick_request"}),
        Command::IrRun { params, mode } => {
            json!({"kind": "ir_run", "params": params, "mode": mode})
        }
        Command::Unknown(u) => json!({
            "kind": "unknown", "port": u.port, "opcode": u.opcode, "len": u.len,
        }),
    }
}

fn report_json(r: &Report, cfg: &Config) -> Value {
    match r {
        Report::SysStatus {
            ts,
            voltage_raw,
            brake_engaged,
        } => json!({
            "kind": "sys_status", "ts": ts, "voltage_raw": voltage_raw,
            "battery_v": cfg.battery_v(*voltage_raw),
            "brake_engaged": brake_engaged,
        }),
        Report::Motion(m) => {
            let mut v = json!({
                "kind": "motion", "rv": m.rv, "ts": m.ts, "axis": m.axis, "position": m.position,
                "velocity": m.velocity, "acceleration": m.acceleration, "torque": m.torque,
            });
            match m.axis {
                0 => {
                    v["position_m"] = json!(cfg.translation_si(f64::from(m.position)));
                    v["v_m_s"] = json!(cfg.translation_si(f64::from(m.velocity)));
                }
                1 => {
                    v["position_rad"] = json!(cfg.rotation_si(f64::from(m.position)));
                    v["omega_rad_s"] = json!(cfg.rotation_si(f64::from(m.velocity)));
                }
                _ => {}
            }
            v
        }
        Report::Sonar(s) => {
            let echoes: Vec<Value> = s
                .echoes
                .iter()
                .map(|e| {
                    let index = cfg
                        .sonar_table
                        .iter()
                        .find(|m| m.id == e.id)
                        .map(|m| m.index);
                    json!({
                        "id": e.id, "index": index, "range": e.range,
                        "range_m": cfg.sonar_range_m(e.range),
                    })
                })
                .collect();
            json!({"kind": "sonar", "rv": s.rv, "ts": s.ts, "echoes": echoes})
        }
        Report::Dio(d) | Report::DioUpdate(d) => {
            let kind = if matches!(r, Report::Dio(_)) {
                "dio"
            } else {
                "dio_update"
            };
            let mut v = json!({"kind": kind, "ts": d.ts, "address": d.address, "data": d.data});
            if d.address == ima_rflex::wire::DIO_BUMPER_ADDRESS {
                v["front_bumper"] = json!(d.data & 1 != 0);
                v["rear_bumper"] = json!(d.data & 2 != 0);
            }
            v
        }
        Report::Joystick { ts, x, y, buttons } => json!({
            "kind": "joystick", "ts": ts, "x": x, "y": y, "buttons": buttons,
        }),
        Report::Ack {
            port,
            opcode,
            rv,
            ts,
        } => json!({"kind": "ack", "port": port, "opcode": opcode, "rv": rv, "ts": ts}),
        Report::Unknown(u) => json!({
            "kind": "unknown", "port": u.port, "opcode": u.opcode, "len": u.len,
        }),
    }
}

/// The rFLEX driver's configuration as a recording's channel metadata gives it (`time_scale`,
/// `kd`, `ka`; the ATRV-Jr's and real time where absent or not a positive number), as its shell
/// runs it (recovering after a silence).
pub fn recorded_config(params: &std::collections::BTreeMap<String, String>) -> Config {
    let number = |k: &str| {
        params
            .get(k)
            .and_then(|v| v.parse::<f64>().ok())
            .filter(|v| v.is_finite() && *v > 0.0)
    };
    let mut cfg = crate::wiring::rflex_config(number("time_scale").unwrap_or(1.0));
    if let Some(kd) = number("kd") {
        cfg.kd = kd;
    }
    if let Some(ka) = number("ka") {
        cfg.ka = ka;
    }
    cfg.recover = true;
    cfg
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(hex: &str, host: bool) -> Vec<Value> {
        let bytes = crate::cmd::decode::hex::parse_hex(hex).unwrap();
        let mut v = Vec::new();
        RflexDecoder::new(host)
            .decode_whole(&bytes, &mut |x| {
                v.push(x);
                Ok(())
            })
            .unwrap();
        v
    }

    /// Fed in pieces, the stream decodes as fed whole (both directions, with damage).
    #[test]
    fn pieces_decode_as_the_whole() {
        let hex = crate::cmd::decode::hex::parse_hex;
        let reports = hex(
            "1B 02 02 05 21 19 00 00 00 00 00 00 12 34 00 00 01 62 BA 00 00 6A 6B 00 00 00 00 00 00 00 00 C1 1B 03 \
             1B 02 01 07 01 09 00 00 12 36 00 00 0A 46 00 66 1B 03 1B 02 01",
        )
        .unwrap();
        let v = crate::cmd::decode::decoder::pieces::decode_alike(
            &|| Box::new(RflexDecoder::new(false)),
            &reports,
        );
        assert_eq!(v.len(), 3, "{v:?}");
        let commands = hex(
            "FF 1B 02 02 00 07 0E 01 00 00 1B 00 58 00 01 86 A0 00 00 88 B8 00 5E 1B 03 \
             1B 02 02 00 0C 00 0F 1B 03 1B 02 01",
        )
        .unwrap();
        let v = crate::cmd::decode::decoder::pieces::decode_alike(
            &|| Box::new(RflexDecoder::new(true)),
            &commands,
        );
        assert_eq!(v.len(), 3, "{v:?}");
    }

    #[test]
    fn t7_motion_report_and_t10_status() {
        let v = run(
            "1B 02 02 05 21 19 00 00 00 00 00 00 12 34 00 00 01 62 BA 00 00 6A 6B 00 00 00 00 00 00 00 00 C1 1B 03 \
             1B 02 01 07 01 09 00 00 12 36 00 00 0A 46 00 66 1B 03",
            false,
        );
        assert_eq!(v.len(), 2);
        assert_eq!(v[0]["kind"], "motion");
        assert_eq!(v[0]["position_m"], 1.0);
        assert!((v[0]["v_m_s"].as_f64().unwrap() - 0.3).abs() < 1e-12);
        assert_eq!(v[0]["offset"], 0);
        assert_eq!(v[0]["id"], 5);
        assert_eq!(v[1]["kind"], "sys_status");
        assert!((v[1]["battery_v"].as_f64().unwrap() - 27.5).abs() < 1e-9);
        assert_eq!(v[1]["offset"], 34);
    }

    #[test]
    fn t5_stuffed_command_and_bad_frames() {
        let v = run(
            "FF 1B 02 02 00 07 0E 01 00 00 1B 00 58 00 01 86 A0 00 00 88 B8 00 5E 1B 03 \
             1B 02 02 00 0C 00 0F 1B 03 1B 02 01",
            true,
        );
        assert_eq!(v.len(), 3, "{v:?}");
        assert_eq!(v[0]["kind"], "set_dir");
        assert_eq!(v[0]["velocity"], 7000);
        assert!((v[0]["omega_rad_s"].as_f64().unwrap() + 7000.0 / 37000.0).abs() < 1e-12);
        assert_eq!(v[0]["offset"], 1);
        assert_eq!(v[1]["kind"], "error");
        assert_eq!(v[1]["offset"], 25);
        assert_eq!(v[2]["kind"], "error");
        assert_eq!(v[2]["offset"], 34);
    }

    fn emitted(r: &Report) -> Vec<Value> {
        let mut out = [0u8; 600];
        let n = r.emit(&mut out).unwrap();
        let mut v = Vec::new();
        RflexDecoder::new(false)
            .decode_whole(&out[..n], &mut |x| {
                v.push(x);
                Ok(())
            })
            .unwrap();
        v
    }

    fn f(v: &Value, key: &str) -> f64 {
        v[key].as_f64().unwrap_or_else(|| panic!("{key} in {v}"))
    }

    #[test]
    fn si_fields_are_the_drivers_conversions() {
        use ima_rflex::wire::{MotionReport, SonarEcho, SonarReport};
        let cfg = Config::default();
        let status = emitted(&Report::SysStatus {
            ts: 1,
            voltage_raw: 2417,
            brake_engaged: false,
        });
        assert_eq!(f(&status[0], "battery_v"), cfg.battery_v(2417));
        for axis in [0, 1] {
            let m = MotionReport {
                rv: 0,
                ts: 2,
                axis,
                position: -123_456,
                velocity: 7_890,
                acceleration: 0,
                torque: 0,
            };
            let v = emitted(&Report::Motion(m));
            if axis == 0 {
                assert_eq!(f(&v[0], "position_m"), cfg.translation_si(-123_456.0));
                assert_eq!(f(&v[0], "v_m_s"), cfg.translation_si(7_890.0));
            } else {
                assert_eq!(f(&v[0], "position_rad"), cfg.rotation_si(-123_456.0));
                assert_eq!(f(&v[0], "omega_rad_s"), cfg.rotation_si(7_890.0));
            }
        }
        let mut sonar = SonarReport::default();
        for (id, range) in [(0x00, 2952), (0x01, 30_000)] {
            sonar.echoes.push(SonarEcho { id, range }).unwrap();
        }
        let v = emitted(&Report::Sonar(sonar));
        let echoes = v[0]["echoes"].as_array().unwrap();
        assert_eq!(f(&echoes[0], "range_m"), cfg.sonar_range_m(2952));
        assert_eq!(
            f(&echoes[1], "range_m"),
            cfg.sonar_range_m(30_000),
            "clipped at the driver's no-echo value"
        );
        // A SET_DIR pair the driver would send decodes back to its speeds.
        let machine = ima_rflex::machine::Machine::new(cfg.clone(), ima_hal::Instant::ZERO);
        let [t, r] = machine.set_dir_pair(ima_hal::base::VelocityCommand::new(-0.25, 0.5));
        for (s, speed, accel) in [
            (t, "v_m_s", "accel_m_s2"),
            (r, "omega_rad_s", "accel_rad_s2"),
        ] {
            let mut out = [0u8; 64];
            let n = Command::SetDir(s).emit(&mut out).unwrap();
            let mut v = Vec::new();
            RflexDecoder::new(true)
                .decode_whole(&out[..n], &mut |x| {
                    v.push(x);
                    Ok(())
                })
                .unwrap();
            let (x, a) = cfg.set_dir_si(&s).unwrap();
            assert_eq!(f(&v[0], speed), x);
            assert_eq!(f(&v[0], accel), a);
        }
    }
}

//! `ima decode compass`: NMEA `HDG`/`HDM`/`HDT`, TCM2 lines, calibration scores and KVH
//! prompts (device side), or KVH/TCM2 commands (`--from host`), as JSON Lines (the contract of
//! `ima decode`).

use anyhow::Result;
use ima_compass::framer::{self, Frame, LineFramer};
use ima_compass::wire::{
    Command, Decimal, KvhCommand, Line, NmeaBody, Offset, ParseOptions, Tcm2Command, Tcm2Data,
};
use serde_json::{Value, json};

use super::decoder::{Decoder, HostCommand};

fn deg(d: Option<Decimal>) -> Option<f64> {
    d.map(Decimal::to_f64)
}

fn offset_json(o: Option<Offset>) -> Value {
    match o {
        Some(o) => json!({"deg": o.signed_deg(), "rad": o.signed_deg().to_radians()}),
        None => Value::Null,
    }
}

fn heading_fields(v: &mut Value, h: Option<f64>) {
    v["heading_deg"] = json!(h);
    v["heading_rad"] = json!(h.map(f64::to_radians));
}

fn line_json(line: &Line) -> Value {
    match line {
        Line::Prompt => json!({"kind": "prompt"}),
        Line::CalScore(s) => json!({
            "kind": "calibration_score", "horizontal": s.h, "vertical": s.v,
            "distortion": s.m.to_f64(),
        }),
        Line::Nmea(s) => {
            let talker = String::from_utf8_lossy(&s.talker.0).into_owned();
            let (kind, reference) = match s.body {
                NmeaBody::Hdg(_) => ("hdg", "magnetic"),
                NmeaBody::Hdm(_) => ("hdm", "magnetic"),
                NmeaBody::Hdt(_) => ("hdt", "true"),
            };
            let mut v = json!({"kind": kind, "talker": talker, "reference": reference});
            heading_fields(&mut v, s.heading_deg());
            if let NmeaBody::Hdg(g) = s.body {
                v["deviation"] = offset_json(g.deviation);
                v["variation"] = offset_json(g.variation);
            }
            v
        }
        Line::Tcm2(d) => tcm2_json(d),
    }
}

fn tcm2_json(d: &Tcm2Data) -> Value {
    let mut v = json!({"kind": "tcm2", "reference": "magnetic"});
    heading_fields(&mut v, deg(d.heading));
    v["pitch_rad"] = json!(deg(d.pitch).map(f64::to_radians));
    v["roll_rad"] = json!(deg(d.roll).map(f64::to_radians));
    v["bx"] = json!(deg(d.bx));
    v["by"] = json!(deg(d.by));
    v["bz"] = json!(deg(d.bz));
    v["temperature_c"] = json!(deg(d.temperature));
    v["error_code"] = json!(d.error);
    v
}

fn command_json(c: Command) -> Value {
    match c {
        Command::Kvh(k) => match k {
            KvhCommand::OutputFormat(f) => {
                json!({"kind": "kvh_output_format", "format": format!("{f:?}")})
            }
            KvhCommand::Rate { per_minute } => json!({
                "kind": "kvh_rate", "per_minute": per_minute,
                "rate_hz": f64::from(per_minute) / 60.0,
            }),
            KvhCommand::Baud(b) => json!({"kind": "kvh_baud", "baud": format!("{b:?}")}),
        },
        Command::Tcm2(t) => match t {
            Tcm2Command::Halt => json!({"kind": "tcm2_halt"}),
            Tcm2Command::Go => json!({"kind": "tcm2_go"}),
            Tcm2Command::QueryOutput => json!({"kind": "tcm2_query_output"}),
            Tcm2Command::QueryCompass => json!({"kind": "tcm2_query_compass"}),
            Tcm2Command::SampleRate(hz) => json!({"kind": "tcm2_sample_rate", "rate_hz": hz}),
            Tcm2Command::OutputFormat(f) => {
                json!({"kind": "tcm2_output_format", "format": format!("{f:?}")})
            }
            Tcm2Command::ClearCalibration => json!({"kind": "tcm2_clear_calibration"}),
            Tcm2Command::UserCalibrationOn => json!({"kind": "tcm2_user_calibration", "on": true}),
            Tcm2Command::UserCalibrationOff => {
                json!({"kind": "tcm2_user_calibration", "on": false})
            }
            Tcm2Command::AutoCalibration(on) => json!({"kind": "tcm2_auto_calibration", "on": on}),
        },
    }
}

/// A compass byte stream (`from_host`: the host's commands) decoded a piece at a time (see
/// [`Decoder`]).
pub struct CompassDecoder {
    from_host: bool,
    framer: LineFramer,
    opts: ParseOptions,
    /// Offset of the first byte of the next feed.
    base: usize,
    /// The host's line being read.
    line: HostCommand,
}

/// Host lines longer than this are reported as too long, not kept: no command comes near it
/// ([`ima_compass::wire::command::MAX_COMMAND`] bytes with its terminator), and a stream
/// with no line end (a wrong direction, binary bytes) must not grow the decoder's memory.
const LONGEST_LINE: usize = 64;

impl CompassDecoder {
    /// A decoder of the host's commands (`from_host`) or the compass's lines.
    pub fn new(from_host: bool) -> Self {
        Self {
            from_host,
            framer: framer::framer(),
            opts: ParseOptions::default(),
            base: 0,
            line: HostCommand::new(LONGEST_LINE),
        }
    }

    fn feed_commands(
        &mut self,
        bytes: &[u8],
        base: usize,
        emit: &mut dyn FnMut(Value) -> Result<()>,
    ) -> Result<()> {
        for (k, &b) in bytes.iter().enumerate() {
            if b != b'\r' && b != b'\n' {
                self.line.push(b);
                continue;
            }
            let (offset, line) = match self.line.end(base.saturating_add(k + 1)) {
                (_, Ok(line)) if line.is_empty() => continue,
                (offset, Ok(line)) => (offset, line),
                (offset, Err(len)) => {
                    let error = format!(
                        "a line of {len} bytes, longer than any command (at most {})",
                        ima_compass::wire::command::MAX_COMMAND
                    );
                    emit(json!({"kind": "error", "error": error, "offset": offset}))?;
                    continue;
                }
            };
            emit(match Command::parse(&line) {
                Ok(c) => {
                    let mut v = command_json(c);
                    v["offset"] = json!(offset);
                    v
                }
                Err(e) => json!({"kind": "error", "error": e.to_string(), "offset": offset}),
            })?;
        }
        Ok(())
    }
}

impl Decoder for CompassDecoder {
    fn feed(&mut self, bytes: &[u8], emit: &mut dyn FnMut(Value) -> Result<()>) -> Result<()> {
        let base = self.base;
        self.base = self.base.saturating_add(bytes.len());
        if self.from_host {
            return self.feed_commands(bytes, base, emit);
        }
        for (k, &b) in bytes.iter().enumerate() {
            let i = base.saturating_add(k);
            let v = match self.framer.push_byte(b) {
                None => continue,
                Some(Frame::Prompt) => {
                    let mut v = line_json(&Line::Prompt);
                    v["offset"] = json!(i);
                    v
                }
                Some(Frame::Corrupt(e)) => {
                    json!({"kind": "error", "error": super::decoder::line_error(e), "offset": i})
                }
                Some(Frame::Line(l)) => {
                    let offset = i.saturating_sub(l.len());
                    match Line::parse(l, &self.opts) {
                        Ok(line) => {
                            let mut v = line_json(&line);
                            v["offset"] = json!(offset);
                            v
                        }
                        Err(e) => {
                            json!({"kind": "error", "error": e.to_string(), "offset": offset})
                        }
                    }
                }
            };
            emit(v)?;
        }
        Ok(())
    }

    fn finish(&mut self, emit: &mut dyn FnMut(Value) -> Result<()>) -> Result<()> {
        if self.from_host {
            self.line.finish(self.base, emit)?;
        } else if self.framer.pending() > 0 {
            emit(
                json!({"kind": "error", "error": "truncated line at end of input",
                "offset": self.base.saturating_sub(self.framer.pending())}),
            )?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(bytes: &[u8], host: bool) -> Vec<Value> {
        let mut out = Vec::new();
        CompassDecoder::new(host)
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
        let lines: &[u8] =
            b"$HCHDM,238.5,M*25\r\n$HCHDG,238.5,0.0,E,12.3,W*6C\r\n$HCHDM,238.5,M*26\r\n>\
              $C328.3P28.4R-12.4T22.3E001*XX\r\nH8V7M0.4\r\n$HCH";
        let v = crate::cmd::decode::decoder::pieces::decode_alike(
            &|| Box::new(CompassDecoder::new(false)),
            lines,
        );
        assert_eq!(v.len(), 7, "{v:?}");
        let commands: &[u8] = b"=t,0\r=r,600\r\n\nh\rsp=8\rgo\rbogus\r=r,6";
        let v = crate::cmd::decode::decoder::pieces::decode_alike(
            &|| Box::new(CompassDecoder::new(true)),
            commands,
        );
        assert_eq!(
            v.last().unwrap()["error"],
            "truncated command at end of input"
        );
    }

    #[test]
    fn spec_vectors_and_errors() {
        let v = run(
            b"$HCHDM,238.5,M*25\r\n$HCHDG,238.5,0.0,E,12.3,W*6C\r\n$HCHDM,238.5,M*26\r\n>\
              $C328.3P28.4R-12.4T22.3E001*XX\r\nH8V7M0.4\r\n",
            false,
        );
        assert_eq!(v[0]["kind"], "hdm");
        assert!((v[0]["heading_deg"].as_f64().unwrap() - 238.5).abs() < 1e-9);
        assert_eq!(v[0]["offset"], 0);
        assert_eq!(v[1]["kind"], "hdg");
        assert!((v[1]["variation"]["deg"].as_f64().unwrap() + 12.3).abs() < 1e-9);
        assert_eq!(v[2]["kind"], "error");
        assert_eq!(v[3]["kind"], "prompt");
        assert_eq!(v[4]["kind"], "error");
        assert_eq!(v[5]["kind"], "calibration_score");
        assert_eq!(v.len(), 6);
    }

    /// A host line longer than any command is reported as its length, and the commands around
    /// it decode, however the stream is cut.
    #[test]
    fn a_host_line_longer_than_any_command_is_reported() {
        let v = crate::cmd::decode::decoder::pieces::decode_alike(
            &|| Box::new(CompassDecoder::new(true)),
            b"h\rthis-line-is-far-longer-than-any-compass-command-a-host-sends-it-is-eighty-bytes\rgo\r",
        );
        let kinds: Vec<_> = v.iter().map(|x| x["kind"].as_str().unwrap()).collect();
        assert_eq!(kinds, ["tcm2_halt", "error", "tcm2_go"]);
        assert_eq!(
            v[1]["error"],
            "a line of 80 bytes, longer than any command (at most 16)"
        );
        assert_eq!((&v[1]["offset"], &v[2]["offset"]), (&2.into(), &83.into()));
    }

    #[test]
    fn commands() {
        let v = run(b"=t,0\r=r,600\rh\rsp=8\rgo\rbogus\r", true);
        let kinds: Vec<_> = v.iter().map(|x| x["kind"].as_str().unwrap()).collect();
        assert_eq!(
            kinds,
            [
                "kvh_output_format",
                "kvh_rate",
                "tcm2_halt",
                "tcm2_sample_rate",
                "tcm2_go",
                "error"
            ]
        );
        assert_eq!(v[1]["rate_hz"], 10.0);
    }
}

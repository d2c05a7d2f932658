//! `ima decode sick-lms`: SICK LMS telegrams to JSON Lines (the contract of
//! `ima decode`): one object per telegram or standalone ACK/NAK byte, in input
//! order, with `"kind"` and `"offset"`; ranges in metres (`ranges_m`, `null` for special
//! codes) next to the raw value words; angles in radians. A telegram with a bad CRC becomes
//! `{"kind":"error",...}` and decoding goes on. B0 values are decoded with measuring mode 00
//! (the default; the raw words are always there for other modes).

use anyhow::Result;
use ima_hal::laser::LaserScan;
use ima_sick_lms::decode::{Value as LmsValue, decode_scan, resolution_rad};
use ima_sick_lms::framer::{Direction, Framer, Item};
use ima_sick_lms::wire::{
    Command, Frame, LmsConfig, MeasuringMode, ModeRequest, Reply, StatusByte,
};
use serde_json::{Value, json};

use super::decoder::Decoder;

/// How far back a candidate that failed its CRC can have begun: its claimed length (16 bits)
/// and the 6 bytes around it, and a little more.
const LOOKBACK: usize = (u16::MAX as usize) + 8;

/// A SICK LMS byte stream (host → LMS commands, or LMS replies) decoded a piece at a time (see
/// [`Decoder`]): one JSON object per item.
pub struct SickDecoder {
    from_host: bool,
    framer: Framer,
    /// Bytes consumed by the framer so far.
    pos: usize,
    /// The last bytes fed (at least [`LOOKBACK`] before those of the current feed), from
    /// offset `seen0`, to find where a failed candidate began.
    seen: Vec<u8>,
    seen0: usize,
    scan: LaserScan,
}

impl SickDecoder {
    /// A decoder of the host's commands (`from_host`) or the unit's replies.
    pub fn new(from_host: bool) -> Self {
        let dir = if from_host {
            Direction::Commands
        } else {
            Direction::Replies
        };
        // Captures have no timing: never expire a partial telegram.
        let framer = Framer::new(dir)
            .report_bad_checksums(true)
            .with_partial_timeout(core::time::Duration::from_secs(u64::MAX / 4_000_000));
        Self {
            from_host,
            framer,
            pos: 0,
            seen: Vec::new(),
            seen0: 0,
            scan: LaserScan::default(),
        }
    }
}

impl Decoder for SickDecoder {
    fn feed(&mut self, bytes: &[u8], emit: &mut dyn FnMut(Value) -> Result<()>) -> Result<()> {
        enum Got {
            Ack,
            Nak,
            Bad,
            Frame(Vec<u8>),
        }
        let old = self.seen.len().saturating_sub(LOOKBACK);
        self.seen.drain(..old);
        self.seen0 += old;
        self.seen.extend_from_slice(bytes);
        let now = ima_hal::Instant::ZERO;
        let mut input = bytes;
        loop {
            let p = self.framer.push(input, now);
            let consumed = p.consumed;
            let item = p.item.map(|i| match i {
                Item::Ack => Got::Ack,
                Item::Nak => Got::Nak,
                Item::BadChecksum => Got::Bad,
                Item::Frame(f) => Got::Frame(f.as_bytes().to_vec()),
            });
            self.pos = self.pos.saturating_add(consumed);
            let pos = self.pos;
            let held = self.framer.buffered();
            let got = item.is_some();
            let v = match item {
                None => None,
                Some(Got::Ack) => Some(json!({"kind": "ack", "offset": pos - 1})),
                Some(Got::Nak) => Some(json!({"kind": "nak", "offset": pos - 1})),
                Some(Got::Bad) => {
                    let start =
                        bad_candidate_start(&self.seen, pos - self.seen0).map(|s| s + self.seen0);
                    Some(json!({"kind": "error",
                        "error": "bad CRC (candidate dropped, resynchronising one byte on)",
                        "offset": start}))
                }
                Some(Got::Frame(raw)) => {
                    let offset = pos.saturating_sub(held + raw.len());
                    let mut v = match Frame::new_checked(&raw) {
                        Err(e) => json!({"kind": "error", "error": e.to_string()}),
                        Ok(f) => {
                            let mut v = if self.from_host {
                                Command::from_frame(&f).map_or_else(
                                    |e| json!({"kind": "error", "error": e.to_string()}),
                                    |c| command_json(&c),
                                )
                            } else {
                                match Reply::from_frame(&f) {
                                    Ok(r) => reply_json(&r, &mut self.scan),
                                    Err(e) => json!({"kind": "error", "error": e.to_string()}),
                                }
                            };
                            v["address"] = json!(f.address());
                            v
                        }
                    };
                    v["offset"] = json!(offset);
                    Some(v)
                }
            };
            if let Some(v) = v {
                emit(v)?;
            }
            input = input.get(consumed..).unwrap_or(&[]);
            if !got && consumed == 0 {
                break;
            }
        }
        Ok(())
    }

    fn finish(&mut self, emit: &mut dyn FnMut(Value) -> Result<()>) -> Result<()> {
        if self.framer.buffered() > 0 {
            emit(
                json!({"kind": "error", "error": "truncated telegram at end of input",
                "offset": self.pos - self.framer.buffered()}),
            )?;
        }
        Ok(())
    }
}

/// Where the candidate that just failed its CRC began: the framer reads exactly a claimed
/// telegram (`LEN + 6` bytes) before checking it, so it is the STX whose claimed end is `end`.
fn bad_candidate_start(bytes: &[u8], end: usize) -> Option<usize> {
    // A telegram holds at least one byte (its command or reply code): LEN ≥ 1, s ≤ end - 7.
    (0..=end.saturating_sub(7)).rev().find(|&s| {
        let len = bytes
            .get(s + 2..s + 4)
            .and_then(|l| <[u8; 2]>::try_from(l).ok())
            .map(|l| usize::from(u16::from_le_bytes(l)));
        bytes.get(s) == Some(&0x02) && len.is_some_and(|l| s + l + 6 == end)
    })
}

fn status_json(s: StatusByte) -> Value {
    json!({"raw": s.0, "severity": format!("{:?}", s.severity()).to_lowercase(),
        "error": s.is_error(), "pollution": s.pollution(), "restart": s.restart(),
        "implausible": s.implausible()})
}

fn config_json(c: &LmsConfig) -> Value {
    json!({"len": c.as_bytes().len(), "bytes": c.as_bytes(), "blanking_cm": c.blanking_cm(),
        "availability": c.availability(), "measuring_mode": c.measuring_mode().0,
        "units": c.units()})
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

fn command_json(c: &Command) -> Value {
    match c {
        Command::Reset => json!({"kind": "reset"}),
        Command::SetMode(m) => {
            let mut v = json!({"kind": "set_mode", "mode": m.code()});
            match m {
                ModeRequest::Installation { password } => v["password"] = json!(text(password)),
                ModeRequest::Baud(b) => v["baud"] = json!(b.bps()),
                ModeRequest::StreamAll => v["name"] = json!("stream_all"),
                ModeRequest::RequestOnly => v["name"] = json!("request_only"),
                ModeRequest::StreamSubrange { start, end } => {
                    v["start"] = json!(start);
                    v["end"] = json!(end);
                }
                _ => {}
            }
            v
        }
        Command::RequestValues { sub, params } => {
            json!({"kind": "request_values", "sub": sub, "params": params.as_slice()})
        }
        Command::Status => json!({"kind": "status_request"}),
        Command::Errors => json!({"kind": "errors_request"}),
        Command::Type => json!({"kind": "type_request"}),
        Command::Variant {
            angle_deg,
            res_centideg,
        } => json!({"kind": "variant_request", "angle_deg": angle_deg,
            "resolution_rad": resolution_rad(*res_centideg),
            "res_centideg": res_centideg}),
        Command::ReadConfig => json!({"kind": "read_config"}),
        Command::WriteConfig(c) => json!({"kind": "write_config", "config": config_json(c)}),
    }
}

fn reply_json(r: &Reply<'_>, scan: &mut LaserScan) -> Value {
    let status = status_json(r.status());
    match r {
        Reply::ModeChanged { result, .. } => {
            json!({"kind": "mode_changed", "result": result, "accepted": *result == 0, "status": status})
        }
        Reply::Scan(s) => {
            let cw = s.count_word;
            let values: Vec<u16> = s.values.iter().collect();
            let mut v = json!({"kind": "scan", "count": cw.count(),
                "units": format!("{:?}", cw.units()).to_lowercase(), "partial": cw.partial(),
                "partial_index": cw.partial_index(), "raw_flags": cw.raw_flags(),
                "indices": s.indices.map(|(a, b)| [a, b]), "values": values, "status": status});
            match decode_scan(s, MeasuringMode::DEFAULT, None, scan) {
                Ok(()) => {
                    v["start_angle_rad"] = json!(scan.start_angle_rad);
                    v["step_rad"] = json!(scan.step_rad);
                    let ranges: Vec<Option<f32>> = scan
                        .ranges_m()
                        .iter()
                        .map(|r| (!r.is_nan()).then_some(*r))
                        .collect();
                    v["ranges_m"] = json!(ranges);
                }
                Err(e) => {
                    // Not a full-scan count (sub-range, unusual variant): ranges without
                    // geometry.
                    let unit = cw.units().metres();
                    let ranges: Vec<Option<f32>> = s
                        .values
                        .iter()
                        .map(|w| {
                            let val = LmsValue::decode(w, MeasuringMode::DEFAULT)?;
                            let u = unit?;
                            val.flags.is_valid().then(|| f32::from(val.distance) * u)
                        })
                        .collect();
                    v["ranges_m"] = json!(ranges);
                    v["geometry"] = json!(format!("unknown: {e}"));
                }
            }
            v
        }
        Reply::Status { block, .. } => json!({"kind": "status",
            "len": block.0.len(),
            "firmware": block.firmware().map(text),
            "operating_mode": block.operating_mode(), "device_status": block.device_status(),
            "measuring_mode": block.measuring_mode().map(|m| m.0),
            "scan_angle_deg": block.scan_angle_deg(),
            "resolution_centideg": block.resolution_centideg(),
            "baud": block.baud().map(|b| b.bps()), "baud_code": block.baud_code(),
            "permanent_baud": block.permanent_baud(), "units": block.units(),
            "status": status}),
        Reply::Errors { pairs, .. } => {
            let p: Vec<[u8; 2]> = pairs.iter().map(|(t, n)| [t, n]).collect();
            json!({"kind": "errors", "errors": p, "status": status})
        }
        Reply::Type { text: t, .. } => json!({"kind": "type", "text": text(t), "status": status}),
        Reply::Variant {
            accepted,
            angle_deg,
            res_centideg,
            ..
        } => json!({"kind": "variant", "accepted": *accepted == 1, "angle_deg": angle_deg,
            "res_centideg": res_centideg,
            "resolution_rad": resolution_rad(*res_centideg), "status": status}),
        Reply::Config { config, .. } => {
            json!({"kind": "config", "config": config_json(config), "status": status})
        }
        Reply::ConfigWritten { result, config, .. } => json!({"kind": "config_written",
            "result": result, "config": config_json(config), "status": status}),
        Reply::PowerOn { text: t, .. } => {
            json!({"kind": "power_on", "text": text(t), "status": status})
        }
        Reply::ResetAck { .. } => json!({"kind": "reset_ack", "status": status}),
        Reply::Rejected { data, .. } => {
            json!({"kind": "rejected", "data": data, "status": status})
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The synthetic 3-value B0 of spec §1.1.
    const B0_3_VALUES: [u8; 16] = [
        0x02, 0x80, 0x0A, 0x00, 0xB0, 0x03, 0x40, 0xE8, 0x03, 0xD0, 0x07, 0xFF, 0x1F, 0x10, 0x16,
        0xB1,
    ];

    fn decode(bytes: &[u8], from_host: bool) -> Vec<Value> {
        let mut out = Vec::new();
        SickDecoder::new(from_host)
            .decode_whole(bytes, &mut |v| {
                out.push(v);
                Ok(())
            })
            .unwrap();
        out
    }

    /// Fed in pieces, the stream decodes as fed whole (both directions, with a bad CRC).
    #[test]
    fn pieces_decode_as_the_whole() {
        let mut b = vec![0x06];
        b.extend(B0_3_VALUES);
        b.extend([0x02, 0x80, 0x02, 0x00, 0x91, 0x10, 0x79, 0x31]); // CRC damaged
        b.extend([
            0x15, 0x02, 0x80, 0x02, 0x00, 0x91, 0x10, 0x79, 0x30, 0x02, 0x80,
        ]);
        let v = crate::cmd::decode::decoder::pieces::decode_alike(
            &|| Box::new(SickDecoder::new(false)),
            &b,
        );
        let kinds: Vec<_> = v.iter().map(|x| x["kind"].as_str().unwrap()).collect();
        assert!(
            kinds.contains(&"scan") && kinds.contains(&"error"),
            "{kinds:?}"
        );
        let mut c = vec![0x02, 0x00, 0x02, 0x00, 0x20, 0x24, 0x34, 0x08];
        c.extend([0x02, 0x00, 0x01, 0x00, 0x31, 0x15, 0x13]); // CRC damaged
        c.extend([
            0x02, 0x00, 0x05, 0x00, 0x3B, 0x64, 0x00, 0x19, 0x00, 0xE7, 0x72,
        ]);
        let v = crate::cmd::decode::decoder::pieces::decode_alike(
            &|| Box::new(SickDecoder::new(true)),
            &c,
        );
        assert!(
            v.iter().any(|x| x["kind"] == "error" && x["offset"] == 8),
            "{v:?}"
        );
    }

    /// Past its lookback window (64 KiB of earlier bytes dropped), a telegram that fails its
    /// CRC, split over feeds, still gets its offset, as fed whole.
    #[test]
    fn a_bad_crc_after_64_kib_is_placed_in_pieces_too() {
        let mut b = vec![0u8; 70_000];
        b.extend([0x02, 0x00, 0x01, 0x00, 0x31, 0x15, 0x13]); // CRC damaged
        b.extend([0x02, 0x00, 0x02, 0x00, 0x20, 0x24, 0x34, 0x08]);
        let whole = decode(&b, true);
        let bad = whole.iter().find(|v| v["kind"] == "error").unwrap();
        assert_eq!(bad["offset"], 70_000);
        for size in [1000, 4096, 69_999, 70_003] {
            let mut d = SickDecoder::new(true);
            let mut out = Vec::new();
            let mut emit = |v: Value| {
                out.push(v);
                Ok(())
            };
            for piece in b.chunks(size) {
                d.feed(piece, &mut emit).unwrap();
            }
            d.finish(&mut emit).unwrap();
            assert!(d.seen0 > 0, "the window moved");
            assert_eq!(out, whole, "pieces of {size}");
        }
    }

    #[test]
    fn spec_vectors_decode() {
        // ACK, then the synthetic 3-value B0 of spec §1.1, then the QM-style reset reply.
        let mut b = vec![0x06];
        b.extend(B0_3_VALUES);
        b.extend([0x02, 0x80, 0x02, 0x00, 0x91, 0x10, 0x79, 0x30]);
        let v = decode(&b, false);
        assert_eq!(v[0]["kind"], "ack");
        assert_eq!(v[1]["kind"], "scan");
        assert_eq!(v[1]["offset"], 1);
        assert_eq!(v[1]["values"], json!([1000, 2000, 0x1FFF]));
        assert_eq!(v[1]["units"], "mm");
        // Three values fit no variant: ranges without geometry, and why in words.
        assert_eq!(v[1]["geometry"], "unknown: 3 values fit no known variant");
        assert_eq!(v[2]["kind"], "reset_ack");
        assert_eq!(v[2]["offset"], 17);
    }

    #[test]
    fn commands_and_bad_crc() {
        let mut b = vec![0x02, 0x00, 0x02, 0x00, 0x20, 0x24, 0x34, 0x08];
        b.extend([0x02, 0x00, 0x01, 0x00, 0x31, 0x15, 0x13]); // CRC damaged
        b.extend([
            0x02, 0x00, 0x05, 0x00, 0x3B, 0x64, 0x00, 0x19, 0x00, 0xE7, 0x72,
        ]);
        let v = decode(&b, true);
        assert_eq!(v[0]["kind"], "set_mode");
        assert_eq!(v[0]["name"], "stream_all");
        assert!(v.iter().any(|x| x["kind"] == "error"));
        let last = v.last().unwrap();
        assert_eq!(last["kind"], "variant_request");
        assert_eq!(last["angle_deg"], 100);
        assert_eq!(last["offset"], 15);
    }
}

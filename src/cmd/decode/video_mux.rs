//! `ima decode video-mux` (Extron SIS) and `ima decode kramer` (Protocol 2000): switcher
//! replies (device side) or commands (`--from host`) as JSON Lines (the contract of
//! `ima decode`).

use anyhow::Result;
use ima_video_mux::framer::{Frame, KramerFramer, LineFramer};
use ima_video_mux::wire::{ExtronCommand, ExtronReply, Instruction, KramerMessage, TieKind};
use serde_json::{Value, json};

fn tie(k: TieKind) -> &'static str {
    match k {
        TieKind::All => "all",
        TieKind::Video => "video",
        TieKind::Audio => "audio",
    }
}

fn reply_json(r: &ExtronReply) -> Value {
    match *r {
        ExtronReply::Input { input, kind, .. } => {
            json!({"kind": "input", "input": input, "tie": tie(kind)})
        }
        ExtronReply::Tie {
            output,
            input,
            kind,
        } => json!({"kind": "tie", "output": output, "input": input, "tie": tie(kind)}),
        ExtronReply::Current(n) => json!({"kind": "current", "input": n}),
        ExtronReply::Signals(s) => {
            let present: Vec<bool> = (1..=s.count).map(|i| s.present(i)).collect();
            json!({"kind": "signals", "present": present})
        }
        ExtronReply::Mute(m) => json!({"kind": "mute", "on": m}),
        ExtronReply::Error(e) => {
            json!({"kind": "switcher_error", "code": e.code(), "name": format!("{e:?}")})
        }
        ExtronReply::Banner => json!({"kind": "banner"}),
    }
}

fn command_json(c: &ExtronCommand) -> Value {
    match *c {
        ExtronCommand::Select { input, kind } => {
            json!({"kind": "select", "input": input, "tie": tie(kind)})
        }
        ExtronCommand::Tie {
            input,
            output,
            kind,
        } => json!({"kind": "tie", "input": input, "output": output, "tie": tie(kind)}),
        ExtronCommand::QueryInput => json!({"kind": "query_input"}),
        ExtronCommand::SignalStatus => json!({"kind": "signal_status"}),
        ExtronCommand::VideoMute(on) => json!({"kind": "video_mute", "on": on}),
    }
}

fn kramer_json(m: &KramerMessage) -> Value {
    json!({
        "kind": match m.instruction {
            Instruction::SwitchVideo => "switch_video",
            Instruction::RequestVideoStatus => "request_video_status",
            Instruction::Error => "switcher_error",
            Instruction::Other(_) => "other",
        },
        "instruction": m.instruction.code(),
        "from_switcher": m.from_switcher,
        "input": m.input, "output": m.output, "machine": m.machine,
    })
}

fn with_offset(mut v: Value, offset: usize) -> Value {
    v["offset"] = json!(offset);
    v
}

/// Decode an Extron SIS byte stream; `from_host` selects the command direction.
pub fn decode_extron(
    bytes: &[u8],
    from_host: bool,
    emit: &mut dyn FnMut(Value) -> Result<()>,
) -> Result<()> {
    if from_host {
        let mut start = 0usize;
        while start < bytes.len() {
            let rest = bytes.get(start..).unwrap_or(&[]);
            let Some(end) = ExtronCommand::command_end(rest) else {
                emit(
                    json!({"kind": "error", "error": "truncated command at end of input", "offset": start}),
                )?;
                break;
            };
            let raw = rest.get(..end).unwrap_or(&[]);
            let trimmed: Vec<u8> = raw
                .iter()
                .copied()
                .filter(|b| !matches!(b, b'\r' | b'\n' | b' '))
                .collect();
            emit(match ExtronCommand::parse(&trimmed) {
                Ok(c) => with_offset(command_json(&c), start),
                Err(e) => json!({"kind": "error", "error": e.to_string(), "offset": start}),
            })?;
            start += end;
        }
        return Ok(());
    }
    let mut framer: LineFramer = LineFramer::default();
    for (i, &b) in bytes.iter().enumerate() {
        if let Some(Frame::Line(l)) = framer.push_byte(b) {
            let offset = i.saturating_sub(l.len());
            emit(match ExtronReply::parse(l) {
                Ok(r) => with_offset(reply_json(&r), offset),
                Err(e) => json!({"kind": "error", "error": e.to_string(), "offset": offset}),
            })?;
        }
    }
    Ok(())
}

/// Decode a Kramer Protocol 2000 byte stream (both directions look alike; bit 6 tells).
pub fn decode_kramer(bytes: &[u8], emit: &mut dyn FnMut(Value) -> Result<()>) -> Result<()> {
    let mut framer = KramerFramer::new();
    for (i, &b) in bytes.iter().enumerate() {
        if let Some(m) = framer.push_byte(b) {
            let offset = i.saturating_sub(ima_video_mux::wire::kramer::LEN - 1);
            emit(match KramerMessage::parse(&m) {
                Ok(k) => with_offset(kramer_json(&k), offset),
                Err(e) => json!({"kind": "error", "error": e.to_string(), "offset": offset}),
            })?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(f: impl FnOnce(&mut dyn FnMut(Value) -> Result<()>) -> Result<()>) -> Vec<Value> {
        let mut out = Vec::new();
        f(&mut |v| {
            out.push(v);
            Ok(())
        })
        .unwrap();
        out
    }

    #[test]
    fn extron_both_ways() {
        let v = run(|e| decode_extron(b"In3 All\r\nE01\r\n3\r\nSig 1 0 1\r\nfoo\r\n", false, e));
        let kinds: Vec<_> = v.iter().map(|x| x["kind"].as_str().unwrap()).collect();
        assert_eq!(
            kinds,
            ["input", "switcher_error", "current", "signals", "error"]
        );
        assert_eq!(v[1]["code"], 1);
        assert_eq!(v[1]["offset"], 9);
        let v = run(|e| decode_extron(b"3!!2&1B12", true, e));
        let kinds: Vec<_> = v.iter().map(|x| x["kind"].as_str().unwrap()).collect();
        assert_eq!(
            kinds,
            ["select", "query_input", "select", "video_mute", "error"]
        );
    }

    #[test]
    fn kramer() {
        let v = run(|e| decode_kramer(&[0x01, 0x83, 0x81, 0x81, 0x41, 0x83, 0x81, 0x81], e));
        assert_eq!(v.len(), 2);
        assert_eq!(v[0]["input"], 3);
        assert_eq!(v[1]["from_switcher"], true);
        assert_eq!(v[1]["offset"], 4);
    }
}

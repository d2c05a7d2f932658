//! `ima decode video-mux` (Extron SIS) and `ima decode kramer` (Protocol 2000): switcher
//! replies (device side) or commands (`--from host`) as JSON Lines (the contract of
//! `ima decode`).

use anyhow::Result;
use ima_video_mux::framer::{Frame, KramerFramer, LineFramer};
use ima_video_mux::wire::{ExtronCommand, ExtronReply, Instruction, KramerMessage, TieKind};
use serde_json::{Value, json};

use super::decoder::{Decoder, HostCommand};

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
        ExtronReply::Information {
            video,
            audio,
            mode,
            video_mute,
            audio_mute,
        } => json!({"kind": "information", "video": video, "audio": audio, "mode": mode,
            "video_mute": video_mute, "audio_mute": audio_mute}),
        ExtronReply::Firmware { major, hundredths } => {
            json!({"kind": "firmware", "version": format!("{major}.{hundredths:02}")})
        }
        ExtronReply::Verbose(n) => json!({"kind": "verbose", "mode": n}),
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
        ExtronCommand::ReadVideoMute => json!({"kind": "read_video_mute"}),
        ExtronCommand::Information => json!({"kind": "information"}),
        ExtronCommand::PartNumber => json!({"kind": "part_number"}),
        ExtronCommand::FirmwareVersion => json!({"kind": "firmware_version"}),
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

/// Host commands longer than this (blanks left out) are reported as too long, not kept: the
/// longest command the driver sends is a few bytes, and a stream with no command end (the
/// wrong direction, binary bytes) must not grow the decoder's memory.
const LONGEST_COMMAND: usize = 32;

/// An Extron SIS byte stream (`from_host`: the host's commands) decoded a piece at a time (see
/// [`Decoder`]).
#[derive(Debug)]
pub struct ExtronDecoder {
    from_host: bool,
    framer: LineFramer,
    /// Offset of the first byte of the next feed.
    base: usize,
    /// The host's command being read (its bytes but blanks).
    command: HostCommand,
}

impl ExtronDecoder {
    /// A decoder of the host's commands (`from_host`) or the switcher's replies.
    pub fn new(from_host: bool) -> Self {
        Self {
            from_host,
            framer: LineFramer::default(),
            base: 0,
            command: HostCommand::new(LONGEST_COMMAND),
        }
    }

    fn feed_commands(
        &mut self,
        bytes: &[u8],
        base: usize,
        emit: &mut dyn FnMut(Value) -> Result<()>,
    ) -> Result<()> {
        for (k, &b) in bytes.iter().enumerate() {
            if !matches!(b, b'\r' | b'\n' | b' ') {
                self.command.push(b);
            }
            if ExtronCommand::command_end(&[b]).is_none() {
                continue;
            }
            emit(match self.command.end(base.saturating_add(k + 1)) {
                (offset, Err(len)) => {
                    let error =
                        format!("a command of {len} bytes, longer than any the switcher takes");
                    json!({"kind": "error", "error": error, "offset": offset})
                }
                (offset, Ok(command)) => match ExtronCommand::parse(&command) {
                    Ok(c) => with_offset(command_json(&c), offset),
                    Err(e) => json!({"kind": "error", "error": e.to_string(), "offset": offset}),
                },
            })?;
        }
        Ok(())
    }
}

impl Decoder for ExtronDecoder {
    fn feed(&mut self, bytes: &[u8], emit: &mut dyn FnMut(Value) -> Result<()>) -> Result<()> {
        let base = self.base;
        self.base = self.base.saturating_add(bytes.len());
        if self.from_host {
            return self.feed_commands(bytes, base, emit);
        }
        for (k, &b) in bytes.iter().enumerate() {
            let i = base.saturating_add(k);
            let v = match self.framer.push_byte(b) {
                None | Some(Frame::Prompt) => continue,
                // A line too long or with a byte no reply has: lost, and said (the framer
                // picks up at the next line).
                Some(Frame::Corrupt(e)) => {
                    json!({"kind": "error", "error": super::decoder::line_error(e), "offset": i})
                }
                Some(Frame::Line(l)) => {
                    let offset = i.saturating_sub(l.len());
                    match ExtronReply::parse(l) {
                        Ok(r) => with_offset(reply_json(&r), offset),
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
            self.command.finish(self.base, emit)?;
        } else if self.framer.pending() > 0 {
            let offset = self.base.saturating_sub(self.framer.pending());
            emit(
                json!({"kind": "error", "error": "truncated line at end of input", "offset": offset}),
            )?;
        }
        Ok(())
    }
}

/// A Kramer Protocol 2000 byte stream decoded a piece at a time (see [`Decoder`]); both
/// directions look alike (bit 6 tells). What the framer drops is said: a run of bytes that
/// start no message as one error where the run ends, a message cut short by the next one's
/// first byte (or by the end of the input) as one error each.
#[derive(Debug, Default)]
pub struct KramerDecoder {
    framer: KramerFramer,
    /// Offset of the first byte of the next feed.
    base: usize,
    /// Bytes that start no message, not yet said: (offset of the first, how many).
    stray: Option<(usize, usize)>,
}

impl KramerDecoder {
    /// Say the run of stray bytes, if any.
    fn stray_said(&mut self, emit: &mut dyn FnMut(Value) -> Result<()>) -> Result<()> {
        match self.stray.take() {
            Some((offset, n)) => emit(json!({"kind": "error", "offset": offset,
                "error": format!("{n} byte(s) that start no message (bit 7 set outside one)")})),
            None => Ok(()),
        }
    }
}

impl Decoder for KramerDecoder {
    fn feed(&mut self, bytes: &[u8], emit: &mut dyn FnMut(Value) -> Result<()>) -> Result<()> {
        use ima_video_mux::wire::kramer::LEN;
        let base = self.base;
        self.base = self.base.saturating_add(bytes.len());
        for (k, &b) in bytes.iter().enumerate() {
            let i = base.saturating_add(k);
            let partial = self.framer.pending();
            let starts = b & 0x80 == 0;
            if !starts && partial == 0 {
                let run = self.stray.get_or_insert((i, 0));
                run.1 = run.1.saturating_add(1);
            } else {
                self.stray_said(emit)?;
            }
            if starts && partial > 0 {
                let error = format!("a message cut short after {partial} of its {LEN} bytes");
                emit(
                    json!({"kind": "error", "error": error, "offset": i.saturating_sub(partial)}),
                )?;
            }
            if let Some(m) = self.framer.push_byte(b) {
                let offset = i.saturating_sub(LEN - 1);
                emit(match KramerMessage::parse(&m) {
                    Ok(k) => with_offset(kramer_json(&k), offset),
                    Err(e) => json!({"kind": "error", "error": e.to_string(), "offset": offset}),
                })?;
            }
        }
        Ok(())
    }

    fn finish(&mut self, emit: &mut dyn FnMut(Value) -> Result<()>) -> Result<()> {
        self.stray_said(emit)?;
        let partial = self.framer.pending();
        if partial > 0 {
            let offset = self.base.saturating_sub(partial);
            emit(
                json!({"kind": "error", "error": "truncated message at end of input", "offset": offset}),
            )?;
        }
        Ok(())
    }
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
        let v = run(|e| {
            ExtronDecoder::new(false)
                .decode_whole(b"In3 All\r\nE01\r\n3\r\nSig 1 0 1\r\nfoo\r\n", e)
        });
        let kinds: Vec<_> = v.iter().map(|x| x["kind"].as_str().unwrap()).collect();
        assert_eq!(
            kinds,
            ["input", "switcher_error", "current", "signals", "error"]
        );
        assert_eq!(v[1]["code"], 1);
        assert_eq!(v[1]["offset"], 9);
        let v = run(|e| ExtronDecoder::new(true).decode_whole(b"3!!2&1B12", e));
        let kinds: Vec<_> = v.iter().map(|x| x["kind"].as_str().unwrap()).collect();
        assert_eq!(
            kinds,
            ["select", "query_input", "select", "video_mute", "error"]
        );
    }

    /// Fed in pieces, both switchers' streams decode as fed whole, both ways, with damage.
    #[test]
    fn pieces_decode_as_the_whole() {
        use crate::cmd::decode::decoder::pieces::decode_alike;
        let v = decode_alike(
            &|| Box::new(ExtronDecoder::new(false)),
            b"In3 All\r\nE01\r\n3\r\nSig 1 0 1\r\nfoo\r\nIn",
        );
        assert_eq!(v.len(), 6, "{v:?}");
        assert_eq!(v[5]["error"], "truncated line at end of input");
        let v = decode_alike(&|| Box::new(ExtronDecoder::new(true)), b"3!!\r\n2&1B12");
        assert_eq!(
            v.last().unwrap()["error"],
            "truncated command at end of input"
        );
        let v = decode_alike(
            &|| Box::new(KramerDecoder::default()),
            &[0x01, 0x83, 0x81, 0x81, 0x41, 0x83, 0x81, 0x81, 0x01],
        );
        assert_eq!(v.len(), 3, "{v:?}");
        assert_eq!(v[2]["error"], "truncated message at end of input");
    }

    /// What the framers drop is said, where it was, however the stream is cut: Extron lines
    /// with a byte no reply has, too long, or cut by the end; Kramer bytes that start no
    /// message (one error per run) and messages cut short.
    #[test]
    fn dropped_bytes_are_said_not_lost() {
        use crate::cmd::decode::decoder::pieces::decode_alike;
        let mut extron = b"In\x012 All\r\nIn2 All\r\n".to_vec();
        extron.extend([b'x'; 200]);
        extron.extend(b"\r\nIn3 All\r\nxxxx");
        /// Each output as (its error, or its kind; its offset).
        fn said(v: &[Value]) -> Vec<(&str, u64)> {
            v.iter()
                .map(|x| {
                    let what = x["error"].as_str().or(x["kind"].as_str()).unwrap();
                    (what, x["offset"].as_u64().unwrap())
                })
                .collect()
        }
        let v = decode_alike(&|| Box::new(ExtronDecoder::new(false)), &extron);
        assert_eq!(
            said(&v),
            [
                ("non-printable byte 0x01", 2),
                ("input", 10),
                ("line too long", 115),
                ("input", 221),
                ("truncated line at end of input", 230),
            ]
        );
        let kramer = [
            0x81, 0x81, 0x81, 0x01, 0x83, 0x01, 0x83, 0x81, 0x81, 0x41, 0x83,
        ];
        let v = decode_alike(&|| Box::new(KramerDecoder::default()), &kramer);
        assert_eq!(
            said(&v),
            [
                ("3 byte(s) that start no message (bit 7 set outside one)", 0),
                ("a message cut short after 2 of its 4 bytes", 3),
                ("switch_video", 5),
                ("truncated message at end of input", 9),
            ]
        );
    }

    /// A host command longer than any the switcher takes is reported as its length, and the
    /// commands around it decode, however the stream is cut.
    #[test]
    fn a_host_command_longer_than_any_is_reported() {
        let mut bytes = b"3!".to_vec();
        bytes.extend([b'7'; 40]);
        bytes.extend(b"!2&");
        let v = crate::cmd::decode::decoder::pieces::decode_alike(
            &|| Box::new(ExtronDecoder::new(true)),
            &bytes,
        );
        let kinds: Vec<_> = v.iter().map(|x| x["kind"].as_str().unwrap()).collect();
        assert_eq!(kinds, ["select", "error", "select"]);
        assert_eq!(
            v[1]["error"],
            "a command of 41 bytes, longer than any the switcher takes"
        );
        assert_eq!((&v[1]["offset"], &v[2]["offset"]), (&2.into(), &43.into()));
    }

    #[test]
    fn kramer() {
        let v = run(|e| {
            KramerDecoder::default()
                .decode_whole(&[0x01, 0x83, 0x81, 0x81, 0x41, 0x83, 0x81, 0x81], e)
        });
        assert_eq!(v.len(), 2);
        assert_eq!(v[0]["input"], 3);
        assert_eq!(v[1]["from_switcher"], true);
        assert_eq!(v[1]["offset"], 4);
    }
}

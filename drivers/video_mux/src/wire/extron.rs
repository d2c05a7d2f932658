//! Extron SIS (Simple Instruction Set), spec §7b "Extron SIS".
//!
//! Commands have **no terminator**: a command ends at its action character (`!`, `&`, `$`,
//! `%`, `S`, `B`); letters are case-insensitive. Replies end with CR LF.
//!
//! | Command | Action | Reply |
//! |---|---|---|
//! | `3!` / `3&` / `3$` | select input 3: all / video / audio | `In3 All` / `In3 Vid` / `In3 Aud` (some models pad: `In003 All`) |
//! | `3*2!` / `3*2%` / `3*2$` | matrix tie of input 3 to output 2 | `Out2 In3 All` / `… Vid` / `… Aud` |
//! | `!` | query current input | the input number |
//! | `0S` | signal presence on all inputs | `Sig 1 1 0 …` |
//! | `1B` / `0B` | video mute on / off | `Vmt1` / `Vmt0` |
//!
//! Errors: `E01` bad input number, `E06` change not allowed, `E10` bad command, `E13` bad value.
//! Unsolicited: a copyright banner at power-on ([`ExtronReply::Banner`]), `In<n> All` after a
//! front-panel selection, `Sig …` when signals change.
//!
//! The exact reply to `Out… In…` ties is inferred from the single-output form (the bridgecmdr
//! source names the commands, not the replies).

use super::{WireError, Writer, is_number, parse_u8, parse_u16};

/// What a selection switches.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum TieKind {
    /// Video and audio (`!`, reply `All`).
    All,
    /// Video only (`&` on a switcher, `%` on a matrix; reply `Vid`).
    Video,
    /// Audio only (`$`, reply `Aud`).
    Audio,
}

impl TieKind {
    fn word(self) -> &'static [u8] {
        match self {
            Self::All => b"All",
            Self::Video => b"Vid",
            Self::Audio => b"Aud",
        }
    }

    fn from_word(w: &[u8]) -> Option<Self> {
        match w {
            b"All" => Some(Self::All),
            b"Vid" => Some(Self::Video),
            b"Aud" => Some(Self::Audio),
            _ => None,
        }
    }
}

/// A command from the host to an Extron switcher.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ExtronCommand {
    /// `N!`, `N&`, `N$`: select input `input`.
    Select {
        /// Input number (1-based).
        input: u16,
        /// What to switch.
        kind: TieKind,
    },
    /// `I*O!`, `I*O%`, `I*O$`: tie input to output on a matrix.
    Tie {
        /// Input number.
        input: u16,
        /// Output number.
        output: u16,
        /// What to tie.
        kind: TieKind,
    },
    /// `!`: which input is selected.
    QueryInput,
    /// `0S`: signal presence on all inputs.
    SignalStatus,
    /// `1B` / `0B`: video mute on / off.
    VideoMute(bool),
    /// `B`: is the video muted (answered `0` or `1`; SW AV manual).
    ReadVideoMute,
    /// `I`: information request (selected inputs, switch mode, mutes: `V3 A3 F1 Vmt0 Amt0`
    /// on the SW VGA and MTP manuals; the fields vary by model).
    Information,
    /// `N`: the part number (`60-xxx-xx`).
    PartNumber,
    /// `Q`: the firmware version (`1.23`).
    FirmwareVersion,
}

/// Longest command emitted (`65535*65535!`).
pub const MAX_COMMAND: usize = 12;

impl ExtronCommand {
    /// Write the command (no terminator: SIS needs none).
    ///
    /// # Errors
    /// [`WireError::BufferTooSmall`].
    pub fn emit(&self, buf: &mut [u8]) -> Result<usize, WireError> {
        let mut w = Writer::new(buf);
        match *self {
            Self::Select { input, kind } => {
                w.decimal(u64::from(input), 1)?;
                w.u8(match kind {
                    TieKind::All => b'!',
                    TieKind::Video => b'&',
                    TieKind::Audio => b'$',
                })?;
            }
            Self::Tie {
                input,
                output,
                kind,
            } => {
                w.decimal(u64::from(input), 1)?;
                w.u8(b'*')?;
                w.decimal(u64::from(output), 1)?;
                w.u8(match kind {
                    TieKind::All => b'!',
                    TieKind::Video => b'%',
                    TieKind::Audio => b'$',
                })?;
            }
            Self::QueryInput => {
                w.u8(b'!')?;
            }
            Self::SignalStatus => {
                w.bytes(b"0S")?;
            }
            Self::VideoMute(on) => {
                w.bytes(if on { b"1B" } else { b"0B" })?;
            }
            Self::ReadVideoMute => {
                w.u8(b'B')?;
            }
            Self::Information => {
                w.u8(b'I')?;
            }
            Self::PartNumber => {
                w.u8(b'N')?;
            }
            Self::FirmwareVersion => {
                w.u8(b'Q')?;
            }
        }
        Ok(w.pos())
    }

    /// Where the first command in `buf` ends (exclusive), if its action character has
    /// arrived. For the device side: commands carry no terminator.
    #[must_use]
    pub fn command_end(buf: &[u8]) -> Option<usize> {
        buf.iter()
            .position(|c| {
                matches!(
                    c.to_ascii_uppercase(),
                    b'!' | b'&' | b'$' | b'%' | b'S' | b'B' | b'I' | b'N' | b'Q'
                )
            })
            .map(|i| i.saturating_add(1))
    }

    /// Parse one complete command (device side).
    ///
    /// # Errors
    /// [`WireError::UnknownCommand`], [`WireError::BadNumber`], [`WireError::Empty`];
    /// [`WireError::OutOfRange`] for an input or output too large for its field (`99999!`).
    pub fn parse(cmd: &[u8]) -> Result<Self, WireError> {
        let Some((&action, args)) = cmd.split_last() else {
            return Err(WireError::Empty);
        };
        match (action.to_ascii_uppercase(), args) {
            (b'!', []) => Ok(Self::QueryInput),
            (b'S', b"0") => Ok(Self::SignalStatus),
            (b'B', b"1") => Ok(Self::VideoMute(true)),
            (b'B', b"0") => Ok(Self::VideoMute(false)),
            (b'B', []) => Ok(Self::ReadVideoMute),
            (b'I', []) => Ok(Self::Information),
            (b'N', []) => Ok(Self::PartNumber),
            (b'Q', []) => Ok(Self::FirmwareVersion),
            (b'!' | b'&' | b'$' | b'%', _) => {
                let tie = args.iter().position(|c| *c == b'*');
                match tie {
                    Some(star) => {
                        let (i, o) = args.split_at(star);
                        let o = o.get(1..).unwrap_or(&[]);
                        let kind = match action {
                            b'!' => TieKind::All,
                            b'%' => TieKind::Video,
                            b'$' => TieKind::Audio,
                            _ => return Err(WireError::UnknownCommand),
                        };
                        Ok(Self::Tie {
                            input: parse_u16(i)?,
                            output: parse_u16(o)?,
                            kind,
                        })
                    }
                    None => {
                        let kind = match action {
                            b'!' => TieKind::All,
                            b'&' => TieKind::Video,
                            b'$' => TieKind::Audio,
                            _ => return Err(WireError::UnknownCommand),
                        };
                        Ok(Self::Select {
                            input: parse_u16(args)?,
                            kind,
                        })
                    }
                }
            }
            _ => Err(WireError::UnknownCommand),
        }
    }
}

/// An Extron error reply `Enn`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ExtronError {
    /// `E01`: invalid input number.
    InvalidInput,
    /// `E06`: invalid change (e.g. auto-switch mode is on).
    ChangeNotAllowed,
    /// `E10`: invalid command.
    InvalidCommand,
    /// `E13`: invalid value.
    InvalidValue,
    /// Any other `Enn`.
    Other(u8),
}

impl core::fmt::Display for ExtronError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let what = match self {
            Self::InvalidInput => "invalid input number",
            Self::ChangeNotAllowed => "change not allowed (auto-switching on?)",
            Self::InvalidCommand => "invalid command",
            Self::InvalidValue => "invalid value",
            Self::Other(_) => "an error code this driver does not know",
        };
        write!(f, "E{:02} ({what})", self.code())
    }
}

impl ExtronError {
    /// The numeric code.
    #[must_use]
    pub fn code(self) -> u8 {
        match self {
            Self::InvalidInput => 1,
            Self::ChangeNotAllowed => 6,
            Self::InvalidCommand => 10,
            Self::InvalidValue => 13,
            Self::Other(n) => n,
        }
    }

    /// The error of code `n`.
    #[must_use]
    pub fn from_code(n: u8) -> Self {
        match n {
            1 => Self::InvalidInput,
            6 => Self::ChangeNotAllowed,
            10 => Self::InvalidCommand,
            13 => Self::InvalidValue,
            n => Self::Other(n),
        }
    }
}

/// Most inputs a `Sig` reply can carry here.
pub const MAX_SIGNALS: u8 = 32;

/// Signal presence per input: bit `i` = input `i + 1`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Signals {
    /// Bit `i` set = signal on input `i + 1`.
    pub mask: u32,
    /// Number of inputs reported (1–[`MAX_SIGNALS`]).
    pub count: u8,
}

impl Signals {
    /// Signal present on `input` (1-based).
    #[must_use]
    pub fn present(&self, input: u8) -> bool {
        input >= 1 && input <= self.count && self.mask & (1u32 << (input - 1)) != 0
    }
}

/// A line from an Extron switcher.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ExtronReply {
    /// `In<n> All|Vid|Aud`: input selected (reply, or unsolicited after a front-panel change).
    Input {
        /// Input number.
        input: u16,
        /// What was switched.
        kind: TieKind,
        /// Digits as written (`In003` has 3); emit pads to this.
        digits: u8,
    },
    /// `Out<o> In<i> All|Vid|Aud`: matrix tie.
    Tie {
        /// Output number.
        output: u16,
        /// Input number.
        input: u16,
        /// What was tied.
        kind: TieKind,
    },
    /// A bare number: the answer to `!` (0 = no input).
    Current(u16),
    /// `Sig 1 0 …`: signal presence.
    Signals(Signals),
    /// `Vmt1` / `Vmt0`.
    Mute(bool),
    /// `Enn`.
    Error(ExtronError),
    /// The power-on copyright banner (any line naming Extron or a copyright).
    Banner,
    /// The answer to `I`: `V<in> A<in>`, then, where the model gives them, `F<mode>`,
    /// `Vmt<0|1>` and `Amt<0|1>` (SW VGA and MTP manuals; fields after those are not kept).
    Information {
        /// Video input selected.
        video: u16,
        /// Audio input selected.
        audio: u16,
        /// Switch mode (1 manual, 2 auto), if given.
        mode: Option<u8>,
        /// Video mute, if given.
        video_mute: Option<bool>,
        /// Audio mute, if given.
        audio_mute: Option<bool>,
    },
    /// The answer to `Q`: the firmware version, two decimals (`1.23`).
    Firmware {
        /// Before the point.
        major: u16,
        /// The two decimals, 0–99.
        hundredths: u8,
    },
    /// The answer to an escape command `<n>CV`: the verbose mode set (`Vrb3`).
    Verbose(u8),
}

/// The banner [`ExtronReply::Banner`] emits.
pub const BANNER: &[u8] = b"(c) Copyright 2002, Extron Electronics, SW AV";

/// `V<in> A<in>[ F<mode>][ Vmt<0|1>][ Amt<0|1>]`, fields after those ignored.
fn parse_information(line: &[u8]) -> Result<ExtronReply, WireError> {
    let mut fields = line.split(|c| *c == b' ').filter(|f| !f.is_empty());
    let number = |f: Option<&[u8]>, tag: u8| match f {
        Some([t, n @ ..]) if *t == tag && is_number(n) => parse_u16(n),
        _ => Err(WireError::UnknownReply),
    };
    let video = number(fields.next(), b'V')?;
    let audio = number(fields.next(), b'A')?;
    let (mut mode, mut video_mute, mut audio_mute) = (None, None, None);
    for f in fields {
        match f {
            [b'F', n @ ..] if is_number(n) => mode = Some(parse_u8(n)?),
            b"Vmt0" | b"Vmt1" => video_mute = Some(f == b"Vmt1"),
            b"Amt0" | b"Amt1" => audio_mute = Some(f == b"Amt1"),
            _ => {}
        }
    }
    Ok(ExtronReply::Information {
        video,
        audio,
        mode,
        video_mute,
        audio_mute,
    })
}

fn split_digits(s: &[u8]) -> (&[u8], &[u8]) {
    let n = s.iter().take_while(|c| c.is_ascii_digit()).count();
    s.split_at(n)
}

fn contains(hay: &[u8], needle: &[u8]) -> bool {
    hay.windows(needle.len())
        .any(|w| w.eq_ignore_ascii_case(needle))
}

impl ExtronReply {
    /// Parse one reply line (CR LF optional).
    ///
    /// # Errors
    /// [`WireError::UnknownReply`], [`WireError::BadNumber`], [`WireError::BadByte`],
    /// [`WireError::Empty`].
    pub fn parse(line: &[u8]) -> Result<Self, WireError> {
        let mut line = line;
        while let [rest @ .., b'\r' | b'\n'] = line {
            line = rest;
        }
        if let Some(b) = line.iter().find(|b| !(0x20..=0x7e).contains(*b)) {
            return Err(WireError::BadByte(*b));
        }
        match line {
            [] => Err(WireError::Empty),
            [b'I', b'n', rest @ ..] => {
                let (num, tail) = split_digits(rest);
                let kind = match tail {
                    [b' ', w @ ..] => TieKind::from_word(w).ok_or(WireError::UnknownReply)?,
                    _ => return Err(WireError::UnknownReply),
                };
                Ok(Self::Input {
                    input: parse_u16(num)?,
                    kind,
                    digits: u8::try_from(num.len()).map_err(|_| WireError::BadNumber)?,
                })
            }
            [b'O', b'u', b't', rest @ ..] => {
                let (out, tail) = split_digits(rest);
                let [b' ', b'I', b'n', tail @ ..] = tail else {
                    return Err(WireError::UnknownReply);
                };
                let (inp, tail) = split_digits(tail);
                let kind = match tail {
                    [b' ', w @ ..] => TieKind::from_word(w).ok_or(WireError::UnknownReply)?,
                    _ => return Err(WireError::UnknownReply),
                };
                Ok(Self::Tie {
                    output: parse_u16(out)?,
                    input: parse_u16(inp)?,
                    kind,
                })
            }
            [b'E', a, b] if a.is_ascii_digit() && b.is_ascii_digit() => Ok(Self::Error(
                ExtronError::from_code((a - b'0') * 10 + (b - b'0')),
            )),
            [b'V', b'm', b't', b'1'] => Ok(Self::Mute(true)),
            [b'V', b'm', b't', b'0'] => Ok(Self::Mute(false)),
            [b'S', b'i', b'g', rest @ ..] => {
                let mut mask = 0u32;
                let mut count = 0u8;
                for item in rest.split(|c| *c == b' ').filter(|s| !s.is_empty()) {
                    if count >= MAX_SIGNALS {
                        return Err(WireError::BadNumber);
                    }
                    match item {
                        b"1" => mask |= 1 << count,
                        b"0" => {}
                        _ => return Err(WireError::BadNumber),
                    }
                    count += 1;
                }
                if count == 0 {
                    return Err(WireError::UnknownReply);
                }
                Ok(Self::Signals(Signals { mask, count }))
            }
            [b'V', b'r', b'b', n @ ..] if is_number(n) => Ok(Self::Verbose(parse_u8(n)?)),
            l if contains(l, b"extron") || contains(l, b"copyright") => Ok(Self::Banner),
            [b'V', d, ..] if d.is_ascii_digit() => parse_information(line),
            l if l.iter().all(u8::is_ascii_digit) => Ok(Self::Current(parse_u16(l)?)),
            [d, ..] if d.is_ascii_digit() => {
                let (major, tail) = split_digits(line);
                let [b'.', hundredths @ ..] = tail else {
                    return Err(WireError::UnknownReply);
                };
                if hundredths.len() != 2 || !is_number(hundredths) {
                    return Err(WireError::UnknownReply);
                }
                Ok(Self::Firmware {
                    major: parse_u16(major)?,
                    hundredths: parse_u8(hundredths)?,
                })
            }
            _ => Err(WireError::UnknownReply),
        }
    }

    /// Write the reply and its CR LF.
    ///
    /// # Errors
    /// [`WireError::BufferTooSmall`]; [`WireError::OutOfRange`] for an empty or oversized
    /// signal list or more than 5 digits.
    pub fn emit(&self, buf: &mut [u8]) -> Result<usize, WireError> {
        let mut w = Writer::new(buf);
        match *self {
            Self::Input {
                input,
                kind,
                digits,
            } => {
                if digits > 5 {
                    return Err(WireError::OutOfRange);
                }
                w.bytes(b"In")?;
                w.decimal(u64::from(input), digits)?;
                w.u8(b' ')?;
                w.bytes(kind.word())?;
            }
            Self::Tie {
                output,
                input,
                kind,
            } => {
                w.bytes(b"Out")?;
                w.decimal(u64::from(output), 1)?;
                w.bytes(b" In")?;
                w.decimal(u64::from(input), 1)?;
                w.u8(b' ')?;
                w.bytes(kind.word())?;
            }
            Self::Current(n) => {
                w.decimal(u64::from(n), 1)?;
            }
            Self::Signals(s) => {
                if s.count == 0 || s.count > MAX_SIGNALS {
                    return Err(WireError::OutOfRange);
                }
                w.bytes(b"Sig")?;
                for i in 0..s.count {
                    w.u8(b' ')?;
                    w.u8(if s.mask & (1 << i) != 0 { b'1' } else { b'0' })?;
                }
            }
            Self::Mute(on) => {
                w.bytes(if on { b"Vmt1" } else { b"Vmt0" })?;
            }
            Self::Error(e) => {
                let c = e.code();
                if c > 99 {
                    return Err(WireError::OutOfRange);
                }
                w.u8(b'E')?;
                w.decimal(u64::from(c), 2)?;
            }
            Self::Banner => {
                w.bytes(BANNER)?;
            }
            Self::Information {
                video,
                audio,
                mode,
                video_mute,
                audio_mute,
            } => {
                w.u8(b'V')?;
                w.decimal(u64::from(video), 1)?;
                w.bytes(b" A")?;
                w.decimal(u64::from(audio), 1)?;
                if let Some(m) = mode {
                    w.bytes(b" F")?;
                    w.decimal(u64::from(m), 1)?;
                }
                if let Some(m) = video_mute {
                    w.bytes(if m { b" Vmt1" } else { b" Vmt0" })?;
                }
                if let Some(m) = audio_mute {
                    w.bytes(if m { b" Amt1" } else { b" Amt0" })?;
                }
            }
            Self::Firmware { major, hundredths } => {
                if hundredths > 99 {
                    return Err(WireError::OutOfRange);
                }
                w.decimal(u64::from(major), 1)?;
                w.u8(b'.')?;
                w.decimal(u64::from(hundredths), 2)?;
            }
            Self::Verbose(n) => {
                w.bytes(b"Vrb")?;
                w.decimal(u64::from(n), 1)?;
            }
        }
        w.bytes(b"\r\n")?;
        Ok(w.pos())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn emit_cmd(c: ExtronCommand) -> std::vec::Vec<u8> {
        let mut b = [0u8; MAX_COMMAND];
        let n = c.emit(&mut b).unwrap();
        b[..n].to_vec()
    }

    fn emit_reply(r: ExtronReply) -> std::vec::Vec<u8> {
        let mut b = [0u8; 128];
        let n = r.emit(&mut b).unwrap();
        b[..n].to_vec()
    }

    /// Every command of the spec's table, byte-exact both ways.
    #[test]
    fn spec_commands_both_ways() {
        let cases: [(&[u8], ExtronCommand); 10] = [
            (
                b"3!",
                ExtronCommand::Select {
                    input: 3,
                    kind: TieKind::All,
                },
            ),
            (
                b"3&",
                ExtronCommand::Select {
                    input: 3,
                    kind: TieKind::Video,
                },
            ),
            (
                b"3$",
                ExtronCommand::Select {
                    input: 3,
                    kind: TieKind::Audio,
                },
            ),
            (b"!", ExtronCommand::QueryInput),
            (b"0S", ExtronCommand::SignalStatus),
            (b"1B", ExtronCommand::VideoMute(true)),
            (b"0B", ExtronCommand::VideoMute(false)),
            (
                b"3*2!",
                ExtronCommand::Tie {
                    input: 3,
                    output: 2,
                    kind: TieKind::All,
                },
            ),
            (
                b"3*2%",
                ExtronCommand::Tie {
                    input: 3,
                    output: 2,
                    kind: TieKind::Video,
                },
            ),
            (
                b"12*1$",
                ExtronCommand::Tie {
                    input: 12,
                    output: 1,
                    kind: TieKind::Audio,
                },
            ),
        ];
        for (bytes, cmd) in cases {
            assert_eq!(emit_cmd(cmd), bytes);
            assert_eq!(ExtronCommand::parse(bytes), Ok(cmd));
            assert_eq!(ExtronCommand::command_end(bytes), Some(bytes.len()));
        }
        // Case-insensitive letters on the device side.
        assert_eq!(ExtronCommand::parse(b"0s"), Ok(ExtronCommand::SignalStatus));
        assert_eq!(
            ExtronCommand::parse(b"1b"),
            Ok(ExtronCommand::VideoMute(true))
        );
        assert_eq!(ExtronCommand::command_end(b"12"), None);
        assert_eq!(ExtronCommand::command_end(b"1!2!"), Some(2));
        assert_eq!(ExtronCommand::parse(b"3%"), Err(WireError::UnknownCommand));
        assert_eq!(
            ExtronCommand::parse(b"3*1&"),
            Err(WireError::UnknownCommand)
        );
        assert_eq!(ExtronCommand::parse(b"x!"), Err(WireError::BadNumber));
        assert_eq!(ExtronCommand::parse(b"2S"), Err(WireError::UnknownCommand));
        assert_eq!(ExtronCommand::parse(b""), Err(WireError::Empty));
    }

    /// Every reply of the spec, byte-exact both ways.
    #[test]
    fn spec_replies_both_ways() {
        let cases: [(&[u8], ExtronReply); 12] = [
            (
                b"In3 All\r\n",
                ExtronReply::Input {
                    input: 3,
                    kind: TieKind::All,
                    digits: 1,
                },
            ),
            (
                b"In003 All\r\n",
                ExtronReply::Input {
                    input: 3,
                    kind: TieKind::All,
                    digits: 3,
                },
            ),
            (
                b"In3 Vid\r\n",
                ExtronReply::Input {
                    input: 3,
                    kind: TieKind::Video,
                    digits: 1,
                },
            ),
            (
                b"In3 Aud\r\n",
                ExtronReply::Input {
                    input: 3,
                    kind: TieKind::Audio,
                    digits: 1,
                },
            ),
            (b"3\r\n", ExtronReply::Current(3)),
            (
                b"Sig 1 1 0\r\n",
                ExtronReply::Signals(Signals {
                    mask: 0b011,
                    count: 3,
                }),
            ),
            (b"Vmt1\r\n", ExtronReply::Mute(true)),
            (b"Vmt0\r\n", ExtronReply::Mute(false)),
            (b"E01\r\n", ExtronReply::Error(ExtronError::InvalidInput)),
            (
                b"E06\r\n",
                ExtronReply::Error(ExtronError::ChangeNotAllowed),
            ),
            (b"E10\r\n", ExtronReply::Error(ExtronError::InvalidCommand)),
            (b"E13\r\n", ExtronReply::Error(ExtronError::InvalidValue)),
        ];
        for (bytes, reply) in cases {
            assert_eq!(ExtronReply::parse(bytes), Ok(reply), "{bytes:?}");
            assert_eq!(emit_reply(reply), bytes);
        }
        assert_eq!(
            ExtronReply::parse(b"Out2 In3 All"),
            Ok(ExtronReply::Tie {
                output: 2,
                input: 3,
                kind: TieKind::All
            })
        );
        assert_eq!(
            ExtronReply::parse(b"(c) Copyright 1999, Extron Electronics SW4 AV, V1.02"),
            Ok(ExtronReply::Banner)
        );
        assert_eq!(
            ExtronReply::parse(&emit_reply(ExtronReply::Banner)),
            Ok(ExtronReply::Banner)
        );
        assert_eq!(
            ExtronReply::parse(b"E99"),
            Ok(ExtronReply::Error(ExtronError::Other(99)))
        );
        let s = match ExtronReply::parse(b"Sig 0 1").unwrap() {
            ExtronReply::Signals(s) => s,
            _ => panic!(),
        };
        assert!(!s.present(1) && s.present(2) && !s.present(3) && !s.present(0));
    }

    #[test]
    fn bad_replies() {
        for bad in [
            &b"In3"[..],
            b"In All",
            b"In3 Foo",
            b"Out2 In All",
            b"Sig",
            b"Sig 2",
            b"hello",
            b"In3\x00All",
            b"99999999",
        ] {
            assert!(ExtronReply::parse(bad).is_err(), "{bad:?}");
        }
        assert_eq!(ExtronReply::parse(b"\r\n"), Err(WireError::Empty));
        assert_eq!(
            ExtronReply::Signals(Signals { mask: 0, count: 0 }).emit(&mut [0u8; 64]),
            Err(WireError::OutOfRange)
        );
    }
}

//! Kramer Protocol 2000, spec §7b "Kramer Protocol 2000".
//!
//! Every message is 4 bytes: `instruction`, `0x80 + input`, `0x80 + output`,
//! `0x80 + machine`. The spec gives the host's switch command (`01 81 81 81` selects input 1
//! on output 1 of machine 1). What follows is **inferred** (general Protocol 2000 knowledge,
//! not from the spec's source) and isolated so it can be switched off in the session:
//!
//! * bit 6 of the first byte is set on messages *from* the switcher, which echo the command as
//!   the reply (`41 83 81 81` confirms input 3 on output 1);
//! * instruction 5 asks which input feeds an output (the reply carries the input);
//! * instruction 16 is the switcher's error reply.
//!
//! The high bit makes the stream self-synchronising: a first byte has bit 7 clear, the other
//! three have it set.

use super::WireError;

/// Message length.
pub const LEN: usize = 4;

/// Protocol 2000 instructions this crate names.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Instruction {
    /// 1: switch video.
    SwitchVideo,
    /// 5: request which input feeds an output (inferred).
    RequestVideoStatus,
    /// 16: error (inferred).
    Error,
    /// Any other instruction (0–63).
    Other(u8),
}

impl Instruction {
    /// The 6-bit code.
    #[must_use]
    pub fn code(self) -> u8 {
        match self {
            Self::SwitchVideo => 1,
            Self::RequestVideoStatus => 5,
            Self::Error => 16,
            Self::Other(n) => n,
        }
    }

    /// The instruction of a 6-bit code.
    #[must_use]
    pub fn from_code(n: u8) -> Self {
        match n {
            1 => Self::SwitchVideo,
            5 => Self::RequestVideoStatus,
            16 => Self::Error,
            n => Self::Other(n),
        }
    }
}

/// One Protocol 2000 message, either direction.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct KramerMessage {
    /// What it does.
    pub instruction: Instruction,
    /// Sent by the switcher (bit 6 of the first byte; inferred).
    pub from_switcher: bool,
    /// Input number, 0–127 (1-based inputs; 0 = none / query).
    pub input: u8,
    /// Output number, 0–127.
    pub output: u8,
    /// Machine number, 0–127 (1 for a single switcher).
    pub machine: u8,
}

impl KramerMessage {
    /// The host command selecting `input` on `output` of `machine`.
    #[must_use]
    pub const fn switch_video(input: u8, output: u8, machine: u8) -> Self {
        Self {
            instruction: Instruction::SwitchVideo,
            from_switcher: false,
            input,
            output,
            machine,
        }
    }

    /// The host query for the input feeding `output` (inferred instruction 5).
    #[must_use]
    pub const fn request_status(output: u8, machine: u8) -> Self {
        Self {
            instruction: Instruction::RequestVideoStatus,
            from_switcher: false,
            input: 0,
            output,
            machine,
        }
    }

    /// The same message as the switcher's reply (bit 6 set).
    #[must_use]
    pub const fn as_reply(self) -> Self {
        Self {
            from_switcher: true,
            ..self
        }
    }

    /// Parse exactly 4 bytes.
    ///
    /// # Errors
    /// [`WireError::Truncated`] / [`WireError::TrailingBytes`] for other lengths;
    /// [`WireError::BadByte`] if bit 7 is set in the first byte or clear in another.
    pub fn parse(bytes: &[u8]) -> Result<Self, WireError> {
        let [b0, b1, b2, b3] = match bytes {
            [a, b, c, d] => [*a, *b, *c, *d],
            s if s.len() < LEN => return Err(WireError::Truncated),
            _ => return Err(WireError::TrailingBytes),
        };
        if b0 & 0x80 != 0 {
            return Err(WireError::BadByte(b0));
        }
        if let Some(b) = [b1, b2, b3].into_iter().find(|b| b & 0x80 == 0) {
            return Err(WireError::BadByte(b));
        }
        Ok(Self {
            instruction: Instruction::from_code(b0 & 0x3f),
            from_switcher: b0 & 0x40 != 0,
            input: b1 & 0x7f,
            output: b2 & 0x7f,
            machine: b3 & 0x7f,
        })
    }

    /// The 4 bytes.
    ///
    /// # Errors
    /// [`WireError::OutOfRange`] for an instruction above 63 or a number above 127.
    pub fn to_bytes(&self) -> Result<[u8; LEN], WireError> {
        let code = self.instruction.code();
        if code > 0x3f || self.input > 0x7f || self.output > 0x7f || self.machine > 0x7f {
            return Err(WireError::OutOfRange);
        }
        let flag = if self.from_switcher { 0x40 } else { 0 };
        Ok([
            code | flag,
            0x80 | self.input,
            0x80 | self.output,
            0x80 | self.machine,
        ])
    }

    /// Write the 4 bytes.
    ///
    /// # Errors
    /// [`WireError::OutOfRange`], [`WireError::BufferTooSmall`].
    pub fn emit(&self, buf: &mut [u8]) -> Result<usize, WireError> {
        let bytes = self.to_bytes()?;
        buf.get_mut(..LEN)
            .ok_or(WireError::BufferTooSmall)?
            .copy_from_slice(&bytes);
        Ok(LEN)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spec_switch_command_both_ways() {
        let m = KramerMessage::switch_video(3, 1, 1);
        assert_eq!(m.to_bytes(), Ok([0x01, 0x83, 0x81, 0x81]));
        assert_eq!(KramerMessage::parse(&[0x01, 0x83, 0x81, 0x81]), Ok(m));
        let r = m.as_reply();
        assert_eq!(r.to_bytes(), Ok([0x41, 0x83, 0x81, 0x81]));
        assert_eq!(KramerMessage::parse(&[0x41, 0x83, 0x81, 0x81]), Ok(r));
        assert_eq!(
            KramerMessage::request_status(1, 1).to_bytes(),
            Ok([0x05, 0x80, 0x81, 0x81])
        );
    }

    #[test]
    fn bad_messages() {
        assert_eq!(
            KramerMessage::parse(&[0x01, 0x83]),
            Err(WireError::Truncated)
        );
        assert_eq!(
            KramerMessage::parse(&[0x01, 0x83, 0x81, 0x81, 0]),
            Err(WireError::TrailingBytes)
        );
        assert_eq!(
            KramerMessage::parse(&[0x81, 0x83, 0x81, 0x81]),
            Err(WireError::BadByte(0x81))
        );
        assert_eq!(
            KramerMessage::parse(&[0x01, 0x03, 0x81, 0x81]),
            Err(WireError::BadByte(0x03))
        );
        assert_eq!(
            KramerMessage::switch_video(128, 1, 1).to_bytes(),
            Err(WireError::OutOfRange)
        );
        let mut small = [0u8; 3];
        assert_eq!(
            KramerMessage::switch_video(1, 1, 1).emit(&mut small),
            Err(WireError::BufferTooSmall)
        );
        assert_eq!(
            KramerMessage {
                instruction: Instruction::Other(64),
                ..KramerMessage::switch_video(1, 1, 1)
            }
            .to_bytes(),
            Err(WireError::OutOfRange)
        );
    }
}

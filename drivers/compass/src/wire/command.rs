//! Commands from the host to the compass (spec §7a command tables). All are ASCII terminated
//! by CR; [`Command::parse`] (the device side, for mocks) accepts CR, LF or CR LF, or none.
//!
//! `autocal=d` (turn automatic calibration off) is not in the spec's table; it follows the
//! `=e`/`=d` pattern of `mpcal` and is marked inferred.

use super::{WireError, Writer};

/// KVH C100 output format (`=t,N`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum KvhFormat {
    /// `=t,0`: NMEA sentences.
    Nmea,
    /// `=t,1`: KVH's own format.
    Kvh,
    /// `=t,2`: corrected X/Y.
    CorrectedXy,
    /// `=t,3`: uncorrected X/Y.
    UncorrectedXy,
}

/// KVH C100 baud rate (`=b,48` / `=b,96`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum KvhBaud {
    /// 4800 baud.
    B4800,
    /// 9600 baud.
    B9600,
}

/// A KVH C100 command `=<letter>,<arg>` CR; the device answers `>` when it accepts it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum KvhCommand {
    /// `=t,N`: output format.
    OutputFormat(KvhFormat),
    /// `=r,N`: output rate in messages per **minute** (the KVH library uses 6, 60, 600).
    Rate {
        /// Messages per minute.
        per_minute: u16,
    },
    /// `=b,48` / `=b,96`.
    Baud(KvhBaud),
}

/// TCM2 output format (`sdo=…`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Tcm2Format {
    /// `sdo=t`: the standard output line.
    Standard,
    /// `sdo=n`: NMEA `HDM`.
    Nmea,
    /// `sdo=m`: mouse.
    Mouse,
}

/// A PNI TCM2 command (ASCII + CR).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Tcm2Command {
    /// `h`: halt, enter standby.
    Halt,
    /// `go`: start continuous output.
    Go,
    /// `s?`: one output word.
    QueryOutput,
    /// `c?`: one compass reading.
    QueryCompass,
    /// `sp=N`: sample rate in Hz (ARIA uses 8, the maximum it knows).
    SampleRate(u8),
    /// `sdo=t|n|m`: output format.
    OutputFormat(Tcm2Format),
    /// `cc`: clear calibration.
    ClearCalibration,
    /// `mpcal=e`: enable (start) user calibration; continuous output (`go`) follows.
    UserCalibrationOn,
    /// `mpcal=d`: disable (stop) user calibration, after `h`.
    UserCalibrationOff,
    /// `autocal=e` / `autocal=d` (the `=d` form is inferred).
    AutoCalibration(bool),
}

/// Any command.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Command {
    /// A KVH C100 command.
    Kvh(KvhCommand),
    /// A PNI TCM2 command.
    Tcm2(Tcm2Command),
}

/// Longest command this crate emits, with CR.
pub const MAX_COMMAND: usize = 16;

impl KvhCommand {
    fn write(&self, w: &mut Writer<'_>) -> Result<(), WireError> {
        match self {
            Self::OutputFormat(f) => {
                w.bytes(b"=t,")?;
                w.u8(match f {
                    KvhFormat::Nmea => b'0',
                    KvhFormat::Kvh => b'1',
                    KvhFormat::CorrectedXy => b'2',
                    KvhFormat::UncorrectedXy => b'3',
                })
            }
            Self::Rate { per_minute } => {
                w.bytes(b"=r,")?;
                w.decimal(u64::from(*per_minute), 1)
            }
            Self::Baud(KvhBaud::B4800) => w.bytes(b"=b,48"),
            Self::Baud(KvhBaud::B9600) => w.bytes(b"=b,96"),
        }?;
        Ok(())
    }

    fn parse(s: &[u8]) -> Result<Self, WireError> {
        match s {
            b"=t,0" => Ok(Self::OutputFormat(KvhFormat::Nmea)),
            b"=t,1" => Ok(Self::OutputFormat(KvhFormat::Kvh)),
            b"=t,2" => Ok(Self::OutputFormat(KvhFormat::CorrectedXy)),
            b"=t,3" => Ok(Self::OutputFormat(KvhFormat::UncorrectedXy)),
            b"=b,48" => Ok(Self::Baud(KvhBaud::B4800)),
            b"=b,96" => Ok(Self::Baud(KvhBaud::B9600)),
            [b'=', b'r', b',', n @ ..] => Ok(Self::Rate {
                per_minute: parse_uint(n)?,
            }),
            _ => Err(WireError::UnknownCommand),
        }
    }
}

impl Tcm2Command {
    fn write(&self, w: &mut Writer<'_>) -> Result<(), WireError> {
        match self {
            Self::Halt => w.bytes(b"h"),
            Self::Go => w.bytes(b"go"),
            Self::QueryOutput => w.bytes(b"s?"),
            Self::QueryCompass => w.bytes(b"c?"),
            Self::SampleRate(n) => {
                w.bytes(b"sp=")?;
                w.decimal(u64::from(*n), 1)
            }
            Self::OutputFormat(Tcm2Format::Standard) => w.bytes(b"sdo=t"),
            Self::OutputFormat(Tcm2Format::Nmea) => w.bytes(b"sdo=n"),
            Self::OutputFormat(Tcm2Format::Mouse) => w.bytes(b"sdo=m"),
            Self::ClearCalibration => w.bytes(b"cc"),
            Self::UserCalibrationOn => w.bytes(b"mpcal=e"),
            Self::UserCalibrationOff => w.bytes(b"mpcal=d"),
            Self::AutoCalibration(true) => w.bytes(b"autocal=e"),
            Self::AutoCalibration(false) => w.bytes(b"autocal=d"),
        }?;
        Ok(())
    }

    fn parse(s: &[u8]) -> Result<Self, WireError> {
        match s {
            b"h" => Ok(Self::Halt),
            b"go" => Ok(Self::Go),
            b"s?" => Ok(Self::QueryOutput),
            b"c?" => Ok(Self::QueryCompass),
            b"sdo=t" => Ok(Self::OutputFormat(Tcm2Format::Standard)),
            b"sdo=n" => Ok(Self::OutputFormat(Tcm2Format::Nmea)),
            b"sdo=m" => Ok(Self::OutputFormat(Tcm2Format::Mouse)),
            b"cc" => Ok(Self::ClearCalibration),
            b"mpcal=e" => Ok(Self::UserCalibrationOn),
            b"mpcal=d" => Ok(Self::UserCalibrationOff),
            b"autocal=e" => Ok(Self::AutoCalibration(true)),
            b"autocal=d" => Ok(Self::AutoCalibration(false)),
            [b's', b'p', b'=', n @ ..] => Ok(Self::SampleRate(parse_uint(n)?)),
            _ => Err(WireError::UnknownCommand),
        }
    }
}

fn parse_uint<T: TryFrom<u64>>(s: &[u8]) -> Result<T, WireError> {
    let v = ima_hal::bytes::parse_decimal(s, 5).map_err(|_| WireError::BadNumber)?;
    T::try_from(v).map_err(|_| WireError::OutOfRange)
}

impl Command {
    /// Write the command and its CR terminator.
    ///
    /// # Errors
    /// [`WireError::BufferTooSmall`] (no command is longer than [`MAX_COMMAND`]).
    pub fn emit(&self, buf: &mut [u8]) -> Result<usize, WireError> {
        let mut w = Writer::new(buf);
        match self {
            Self::Kvh(c) => c.write(&mut w)?,
            Self::Tcm2(c) => c.write(&mut w)?,
        }
        w.u8(b'\r')?;
        Ok(w.pos())
    }

    /// Parse one command line (device side). KVH commands start with `=`, everything else is
    /// read as TCM2.
    ///
    /// # Errors
    /// [`WireError::UnknownCommand`], [`WireError::BadNumber`], [`WireError::OutOfRange`].
    pub fn parse(line: &[u8]) -> Result<Self, WireError> {
        let line = super::trim_eol(line);
        match line {
            [] => Err(WireError::Empty),
            [b'=', ..] => KvhCommand::parse(line).map(Self::Kvh),
            _ => Tcm2Command::parse(line).map(Self::Tcm2),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn emit(c: Command) -> std::vec::Vec<u8> {
        let mut buf = [0u8; MAX_COMMAND];
        let n = c.emit(&mut buf).unwrap();
        buf[..n].to_vec()
    }

    /// Every command of the spec's tables, byte-exact both ways.
    #[test]
    fn spec_commands_both_ways() {
        use Tcm2Command as T;
        let cases: [(&[u8], Command); 19] = [
            (
                b"=t,0\r",
                Command::Kvh(KvhCommand::OutputFormat(KvhFormat::Nmea)),
            ),
            (
                b"=t,1\r",
                Command::Kvh(KvhCommand::OutputFormat(KvhFormat::Kvh)),
            ),
            (
                b"=t,2\r",
                Command::Kvh(KvhCommand::OutputFormat(KvhFormat::CorrectedXy)),
            ),
            (
                b"=t,3\r",
                Command::Kvh(KvhCommand::OutputFormat(KvhFormat::UncorrectedXy)),
            ),
            (
                b"=r,60\r",
                Command::Kvh(KvhCommand::Rate { per_minute: 60 }),
            ),
            (
                b"=r,600\r",
                Command::Kvh(KvhCommand::Rate { per_minute: 600 }),
            ),
            (b"=b,48\r", Command::Kvh(KvhCommand::Baud(KvhBaud::B4800))),
            (b"=b,96\r", Command::Kvh(KvhCommand::Baud(KvhBaud::B9600))),
            (b"h\r", Command::Tcm2(T::Halt)),
            (b"go\r", Command::Tcm2(T::Go)),
            (b"s?\r", Command::Tcm2(T::QueryOutput)),
            (b"c?\r", Command::Tcm2(T::QueryCompass)),
            (b"sp=8\r", Command::Tcm2(T::SampleRate(8))),
            (
                b"sdo=t\r",
                Command::Tcm2(T::OutputFormat(Tcm2Format::Standard)),
            ),
            (b"sdo=n\r", Command::Tcm2(T::OutputFormat(Tcm2Format::Nmea))),
            (
                b"sdo=m\r",
                Command::Tcm2(T::OutputFormat(Tcm2Format::Mouse)),
            ),
            (b"cc\r", Command::Tcm2(T::ClearCalibration)),
            (b"mpcal=e\r", Command::Tcm2(T::UserCalibrationOn)),
            (b"autocal=e\r", Command::Tcm2(T::AutoCalibration(true))),
        ];
        for (bytes, cmd) in cases {
            assert_eq!(emit(cmd), bytes);
            assert_eq!(Command::parse(bytes), Ok(cmd));
        }
        assert_eq!(
            Command::parse(b"mpcal=d\r\n"),
            Ok(Command::Tcm2(T::UserCalibrationOff))
        );
    }

    #[test]
    fn bad_commands() {
        assert_eq!(Command::parse(b"=x,1"), Err(WireError::UnknownCommand));
        assert_eq!(Command::parse(b"=r,"), Err(WireError::BadNumber));
        assert_eq!(Command::parse(b"=r,99999"), Err(WireError::OutOfRange));
        assert_eq!(Command::parse(b"sp=300"), Err(WireError::OutOfRange));
        assert_eq!(Command::parse(b"sp=1a"), Err(WireError::BadNumber));
        assert_eq!(Command::parse(b"\r"), Err(WireError::Empty));
        assert_eq!(Command::parse(b"zz"), Err(WireError::UnknownCommand));
        assert_eq!(
            Command::Tcm2(Tcm2Command::Go).emit(&mut [0u8; 2]),
            Err(WireError::BufferTooSmall)
        );
    }
}

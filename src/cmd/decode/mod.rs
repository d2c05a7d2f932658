//! `ima decode <protocol>`: a capture in, one JSON object per frame out.
//!
//! Contract (shared by every protocol): input is raw bytes (decoded as they are read), or hex
//! text with `--hex`, from a file or stdin; output is JSON Lines, one object per frame in input
//! order, each with a `"kind"` key (the snake_case message name); physical fields are in SI
//! units with unit-suffixed names (`x_m`, `theta_rad`, `range_m`, `battery_v`) next to the raw
//! values; a bad frame is `{"kind":"error","error":"<reason>","offset":<byte offset>}` and
//! decoding goes on.
//!
//! One module per protocol ([`p2os`], [`rflex`], [`sick`], [`compass`], [`video_mux`]); each
//! has a [`Decoder`] that takes the bytes a piece at a time and an `emit` callback (which side
//! sent them, where the two differ, is chosen when it is made), and takes its SI conversions
//! from the driver crate (the driver's own functions, so that `ima decode` shows what the
//! driver would report); [`decoder()`] picks one. [`hex`] reads `--hex` input. A host line or
//! command with no end in sight is counted, not kept ([`decoder::HostCommand`]).

pub mod compass;
pub mod decoder;
pub mod hex;
pub mod p2os;
pub mod rflex;
pub mod sick;
pub mod video_mux;

use std::io::{Read, Write};
use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::{Args, ValueEnum};
use ima_p2os::params::RobotParams;
use ima_record::read::Truncation;
use serde_json::Value;

pub use self::decoder::Decoder;
pub use self::hex::parse_hex;

/// The most hex text `ima decode --hex` reads (a file or stdin), parsed whole: 1 GiB. Raw
/// bytes have no limit: they are decoded as they are read.
const HEX_LIMIT: u64 = 1 << 30;

/// Protocols `ima decode` understands.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
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

impl Protocol {
    /// The name on the command line (`p2os`, `sick-lms`, …).
    fn name(self) -> String {
        self.to_possible_value()
            .map_or_else(String::new, |v| v.get_name().to_owned())
    }
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
    /// Robot parameters for unit conversion (P2OS subclass: p2at, p2at8, p2dx). When absent,
    /// the robot's bytes are read in the units of the robot its SYNC2 reply names (as the
    /// driver takes them), the P2-AT's until then; the host's bytes in the P2-AT's.
    #[arg(long)]
    robot: Option<String>,
    /// Capture file; stdin when absent or `-`. Bytes are decoded as they are read, so a pipe
    /// or a serial port (a tap on a robot's line: give `--baud`) shows each frame as it comes.
    file: Option<PathBuf>,
    /// FILE is a serial port: read it raw (8N1, no flow control, no byte changed) at this
    /// line speed. Needed when FILE is one; its settings are those of the line it taps.
    #[arg(long, value_parser = crate::cmd::num::baud, requires = "file", conflicts_with_all = ["mcap", "hex"])]
    baud: Option<u32>,
}

/// Run `ima decode`.
pub fn run(args: &DecodeArgs) -> Result<()> {
    // clap drops `--port`'s need of `--mcap` when a FILE is given (`--mcap` conflicts with it).
    anyhow::ensure!(
        args.port.is_none() || args.mcap.is_some(),
        "--port names a serial port of a recording: give the recording with --mcap FILE.mcap \
         (a capture FILE is decoded whole)"
    );
    if let Some(path) = &args.mcap {
        return run_mcap(args, path);
    }
    let Some(protocol) = args.protocol else {
        anyhow::bail!("give the protocol of the capture");
    };
    let mut out = Output::new(args, protocol)?;
    // `-` is stdin, as for most Unix tools.
    let file = args.file.clone().filter(|p| p.as_os_str() != "-");
    anyhow::ensure!(
        file.is_some() || args.baud.is_none(),
        "--baud is for a serial port given as FILE (stdin is read as it is)"
    );
    let name = file
        .as_deref()
        .map_or_else(|| "stdin".to_owned(), |p| p.display().to_string());
    let (pieces, reader) = read_pieces(file, args.baud)?;
    let mut d = decoder(protocol, args.from == Direction::Host, out.params, None);
    if args.hex {
        let mut text = Vec::new();
        while let Some(piece) = crate::safety::recv_unless_asked_to_end(&pieces)? {
            text.extend(piece.with_context(|| format!("reading {name}"))?);
            anyhow::ensure!(
                text.len() as u64 <= HEX_LIMIT,
                "{name}: more than {HEX_LIMIT} bytes of hex text; give the capture as bytes \
                 (without --hex), which is decoded as it is read"
            );
        }
        let bytes = parse_hex(std::str::from_utf8(&text).context("--hex input is not text")?)?;
        d.decode_whole(&bytes, &mut |v| out.emit(v))?;
        return out.end(bytes.len() as u64);
    }
    // Bytes are decoded as they are read, and each piece's frames written out before the next
    // read: a capture of any length takes no more memory than a few pieces, and a live line
    // (a tap on a serial line, a sniffer's pipe) shows each frame as it comes.
    let mut read = 0u64;
    let ended = loop {
        let piece = match crate::safety::recv_unless_asked_to_end(&pieces) {
            Ok(Some(Ok(piece))) => piece,
            Ok(Some(Err(e))) => {
                break Some(anyhow::Error::new(e).context(format!("reading {name}")));
            }
            Ok(None) => break None,
            Err(e) => break Some(e),
        };
        // An MCAP recording given as a capture decoded into tens of thousands of
        // "frames" of noise, with success.
        if read == 0 && ima_record::read::is_mcap(&piece) {
            let f = args.file.as_deref().filter(|p| p.as_os_str() != "-");
            let f = f.map_or_else(|| "FILE.mcap".to_owned(), |p| p.display().to_string());
            anyhow::bail!(
                "{name} is an MCAP recording, not a capture of a port's bytes: decode one of its \
                 ports with `ima decode --mcap {f} --port PORT` (`ima replay {f}` re-decodes \
                 them all)"
            );
        }
        read = read.saturating_add(piece.len() as u64);
        d.feed(&piece, &mut |v| out.emit(v))?;
        out.flush()?;
    };
    if ended.is_none() && reader.join().is_err() {
        anyhow::bail!("reading {name} failed (a bug: please report it)");
    }
    // Ctrl-C, or a read that failed (an adapter unplugged), ends a live decode: what is left,
    // and the hint when nothing was a frame (a wrong rate or side), are said first.
    d.finish(&mut |v| out.emit(v))?;
    out.end(read)?;
    if read == 0 && ended.is_none() {
        // An empty file gave no output at all, where noise gets a hint.
        eprintln!("ima decode: {name} is empty: no bytes to decode");
    }
    ended.map_or(Ok(()), Err)
}

/// The pieces of a capture as they are read, or the error that ended the reading.
type Pieces = std::sync::mpsc::Receiver<std::io::Result<Vec<u8>>>;

/// Read `file` (stdin when `None`; a serial port at `baud`, [`open_capture`]) on a thread of
/// its own, in pieces of up to 64 KiB as they come, so that the command waiting for them (a
/// quiet pipe, a FIFO not yet opened by a writer) still ends at once on Ctrl-C. The thread
/// stops at its next piece once the receiver is dropped; an error (opening included) is the
/// last message.
fn read_pieces(
    file: Option<PathBuf>,
    baud: Option<u32>,
) -> Result<(Pieces, std::thread::JoinHandle<()>)> {
    let (tx, pieces) = std::sync::mpsc::sync_channel(4);
    let reader = std::thread::Builder::new()
        .name("ima-decode-read".into())
        .spawn(move || {
            let input = match file {
                Some(p) => open_capture(&p, baud),
                None => Ok(Box::new(std::io::stdin()) as Box<dyn Read>),
            };
            let mut input = match input {
                Ok(i) => i,
                Err(e) => {
                    let _ = tx.send(Err(e));
                    return;
                }
            };
            let mut buf = vec![0u8; 64 << 10];
            loop {
                let got = match input.read(&mut buf) {
                    Ok(0) => return,
                    Ok(n) => Ok(buf.get(..n).unwrap_or_default().to_vec()),
                    // A serial port's read gives up after its timeout: a quiet line.
                    Err(e) if e.kind() == std::io::ErrorKind::TimedOut => continue,
                    Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                    Err(e) => Err(e),
                };
                let failed = got.is_err();
                // The decode has ended (a closed stdout, a signal): stop reading.
                if tx.send(got).is_err() || failed {
                    return;
                }
            }
        })
        .context("starting the capture's reader")?;
    Ok((pieces, reader))
}

/// Open the capture at `path`: a file, a pipe or a FIFO as it is; a serial port (a terminal)
/// raw at `baud`, which it needs (a terminal read as it is set would change or hold bytes: a
/// line in canonical mode is held until a newline, CR may become LF, and ^C, ^S, ^Q vanish).
///
/// A tap takes the port for itself: one that a process of this user (any process, for root)
/// has open (a driver, a terminal program, this very terminal) is refused with its name, as
/// its settings would be changed and its bytes shared; and none can open it while the tap
/// reads.
fn open_capture(path: &std::path::Path, baud: Option<u32>) -> std::io::Result<Box<dyn Read>> {
    use std::io::{Error, ErrorKind, IsTerminal};
    use std::os::unix::fs::{FileTypeExt, MetadataExt, OpenOptionsExt};
    let meta = std::fs::metadata(path)?;
    let shown = path.display().to_string();
    let explain = |e: Error| ima_hal::serial::explain_open_error(&shown, e);
    let char_device = meta.file_type().is_char_device();
    // Who else has it open, before it is opened here (a terminal: the shell, ima's own
    // standard streams).
    let holder = if char_device && baud.is_some() {
        holder_of(meta.rdev())
    } else {
        None
    };
    let busy = |(pid, name): (u32, String)| {
        let why = if pid == std::process::id() {
            "this is ima's own terminal: a tap needs a port of its own, wired to listen to the \
             line"
                .to_owned()
        } else {
            format!(
                "process {pid} ({name}) has this port open: a tap needs a port of its own, wired \
                 to listen to the line (reading this one would change its settings and take \
                 some of its bytes)"
            )
        };
        Error::new(ErrorKind::ResourceBusy, why)
    };
    // Looked at without waiting for a carrier (a serial port's open may, without CLOCAL) and
    // without becoming the process's controlling terminal. A port a driver holds may refuse
    // even that (TIOCEXCL): its holder is named then too.
    let serial = char_device
        && std::fs::OpenOptions::new()
            .read(true)
            .custom_flags(libc::O_NOCTTY | libc::O_NONBLOCK)
            .open(path)
            .map_err(|e| match holder.clone() {
                Some(h) if e.raw_os_error() == Some(libc::EBUSY) => busy(h),
                _ => explain(e),
            })?
            .is_terminal();
    if serial
        && baud.is_some()
        && let Some(h) = holder
    {
        return Err(busy(h));
    }
    match (serial, baud) {
        (false, None) => Ok(Box::new(std::fs::File::open(path)?)),
        (false, Some(_)) => Err(Error::new(
            ErrorKind::InvalidInput,
            "--baud is for a serial port, and this is not one (a file, pipe or FIFO is read \
             as it is, without --baud)",
        )),
        (true, None) => Err(Error::new(
            ErrorKind::InvalidInput,
            "this is a serial port: give its line speed with --baud RATE (what the device \
             sends at, e.g. --baud 9600), and it is read raw at that speed",
        )),
        (true, Some(baud)) => {
            // Exclusive, as a driver opens its port: no program opens it while the tap reads.
            let port = serialport::new(path.to_string_lossy(), baud)
                .timeout(std::time::Duration::from_millis(200))
                .open_native()
                .map_err(|e| explain(e.into()))?;
            Ok(Box::new(SerialTap(port)))
        }
    }
}

/// A serial port read by a tap: a hang-up (an adapter unplugged, a pty closed), which reads as
/// a broken pipe or an I/O error, is said as such.
struct SerialTap(serialport::TTYPort);

impl Read for SerialTap {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        self.0.read(buf).map_err(|e| {
            let gone =
                e.kind() == std::io::ErrorKind::BrokenPipe || e.raw_os_error() == Some(libc::EIO);
            if gone {
                // Not a broken pipe any more: that is how a closed stdout ends the command.
                std::io::Error::other(format!("the port went away (unplugged?): {e}"))
            } else {
                e
            }
        })
    }
}

/// A process that has the device `rdev` open (its id and name), from `/proc` (Linux; only
/// the processes whose descriptors this user may read: the user's own, or all for root). This
/// process is looked at first, so that its own terminal is named as such; the terminal aliases
/// (`/dev/tty`, `/dev/console`) count as this process's. Only descriptors on `/dev` are looked
/// at (a `stat` elsewhere could wait on a hung network mount).
fn holder_of(rdev: u64) -> Option<(u32, String)> {
    use std::os::unix::fs::{FileTypeExt, MetadataExt};
    let me = std::process::id();
    let is_rdev = |p: &std::path::Path| {
        std::fs::metadata(p).is_ok_and(|m| m.file_type().is_char_device() && m.rdev() == rdev)
    };
    if ["/dev/tty", "/dev/console"]
        .iter()
        .any(|p| is_rdev(p.as_ref()))
    {
        return Some((me, String::new()));
    }
    let holds = |proc: &std::path::Path| {
        std::fs::read_dir(proc.join("fd")).is_ok_and(|fds| {
            fds.flatten().any(|fd| {
                let path = fd.path();
                std::fs::read_link(&path).is_ok_and(|t| t.starts_with("/dev/")) && is_rdev(&path)
            })
        })
    };
    if holds(std::path::Path::new("/proc/self")) {
        return Some((me, String::new()));
    }
    for proc in std::fs::read_dir("/proc").ok()?.flatten() {
        let Some(pid) = proc
            .file_name()
            .to_str()
            .and_then(|p| p.parse::<u32>().ok())
        else {
            continue;
        };
        if pid != me && holds(&proc.path()) {
            let name = std::fs::read_to_string(proc.path().join("comm")).unwrap_or_default();
            return Some((pid, name.trim().to_owned()));
        }
    }
    None
}

/// The decoder of `protocol`, for the host's side (`host`) or the device's, in the units its
/// driver used. `params`: the P2OS robot's table as `--robot` gives it; `recorded`: a
/// recorded port's driver parameters (an rFLEX's `kd` and `ka`; the P2OS table the driver was
/// told, `params`). A P2OS port with neither is read in the table of the robot its SYNC2
/// reply names, the P2-AT's until then (the host's bytes: the P2-AT's).
pub fn decoder(
    protocol: Protocol,
    host: bool,
    params: Option<&'static RobotParams>,
    recorded: Option<&std::collections::BTreeMap<String, String>>,
) -> Box<dyn Decoder + Send> {
    let params = params.or_else(|| recorded.and_then(p2os::recorded_params));
    if let (Protocol::P2os, None, false) = (protocol, params, host) {
        return Box::new(p2os::P2osDecoder::following(&ima_p2os::params::P2AT));
    }
    let params = params.unwrap_or(&ima_p2os::params::P2AT);
    if let (Protocol::Rflex, Some(r)) = (protocol, recorded) {
        let cfg = rflex::recorded_config(r);
        return Box::new(rflex::RflexDecoder::with_config(host, cfg));
    }
    match protocol {
        Protocol::P2os => Box::new(p2os::P2osDecoder::new(host, params)),
        Protocol::Compass => Box::new(compass::CompassDecoder::new(host)),
        Protocol::SickLms => Box::new(sick::SickDecoder::new(host)),
        Protocol::VideoMux => Box::new(video_mux::ExtronDecoder::new(host)),
        Protocol::Kramer => Box::new(video_mux::KramerDecoder::default()),
        Protocol::Rflex => Box::new(rflex::RflexDecoder::new(host)),
    }
}

/// Where decoded frames go: JSON Lines on stdout, counted for the closing hint.
struct Output {
    out: std::io::BufWriter<std::io::StdoutLock<'static>>,
    protocol: Protocol,
    from: Direction,
    /// The P2OS robot's parameters as `--robot` gives them (`None`: see [`decoder()`]).
    params: Option<&'static RobotParams>,
    frames: u64,
    errors: u64,
}

impl Output {
    fn new(args: &DecodeArgs, protocol: Protocol) -> Result<Self> {
        let params = match &args.robot {
            Some(r) if protocol != Protocol::P2os => anyhow::bail!(
                "--robot {r} picks a P2OS robot's units; {} bytes have no such table",
                protocol.name()
            ),
            None => None,
            Some(r) => Some(
                RobotParams::for_subclass(r.as_bytes())
                    .with_context(|| format!("unknown P2OS robot {r:?} (p2at, p2at8, p2dx)"))?,
            ),
        };
        Ok(Self {
            out: std::io::BufWriter::new(std::io::stdout().lock()),
            protocol,
            from: args.from,
            params,
            frames: 0,
            errors: 0,
        })
    }

    fn emit(&mut self, v: Value) -> Result<()> {
        if v["kind"] == "error" {
            self.errors += 1;
        } else {
            self.frames += 1;
        }
        // As an `io::Error`, so that a closed stdout ends the program quietly (141).
        serde_json::to_writer(&mut self.out, &v).map_err(std::io::Error::from)?;
        self.out.write_all(b"\n")?;
        Ok(())
    }

    /// Write out what is buffered (as an `io::Error`, so that a closed stdout ends the program
    /// quietly).
    fn flush(&mut self) -> Result<()> {
        self.out.flush()?;
        Ok(())
    }

    /// The input (`bytes` long) ended: flush, and say so if it gave no frame at all.
    fn end(&mut self, bytes: u64) -> Result<()> {
        self.out.flush()?;
        let (protocol, from) = (self.protocol, self.from);
        if let Some(why) = nothing_decoded(protocol, from, bytes, self.frames, self.errors) {
            eprintln!("ima decode: {why}");
        }
        Ok(())
    }
}

/// What to tell a user whose `bytes` gave no frame at all (the output is then empty or only
/// errors, which reads as "nothing happened"): most likely the wrong protocol or direction.
fn nothing_decoded(
    protocol: Protocol,
    from: Direction,
    bytes: u64,
    frames: u64,
    errors: u64,
) -> Option<String> {
    if bytes == 0 || frames > 0 {
        return None;
    }
    let name = protocol.name();
    let rejected = if errors > 0 {
        format!(" ({errors} rejected)")
    } else {
        String::new()
    };
    // Kramer's protocol is the same both ways: no direction to suggest.
    if matches!(protocol, Protocol::Kramer) {
        return Some(format!(
            "no {name} frame in {bytes} bytes{rejected}: another protocol?"
        ));
    }
    let other = match from {
        Direction::Robot => "host",
        Direction::Host => "robot",
    };
    Some(format!(
        "no {name} frame in {bytes} bytes{rejected}: another protocol, or the other direction \
         (`--from {other}`)?"
    ))
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

/// `--mcap FILE --port NAME`: the port's bytes in the `--from` direction, decoded a chunk at a
/// time as the recording is read (memory does not grow with its length), as the port's
/// recorded protocol unless one is given.
fn run_mcap(args: &DecodeArgs, path: &std::path::Path) -> Result<()> {
    let Some(port) = &args.port else {
        anyhow::bail!("--mcap needs --port");
    };
    let rec = ima_record::read::Recording::open(path)?;
    let damage = rec.damage();
    if let Some(why) = &damage {
        eprintln!("ima decode: the recording is damaged ({why}); decoding the bytes it holds");
    }
    let want = match args.from {
        Direction::Robot => ima_record::raw::Dir::Rx,
        Direction::Host => ima_record::raw::Dir::Tx,
    };
    // Made at the port's first chunk, which names its protocol.
    let mut decoding: Option<(Box<dyn Decoder + Send>, Output)> = None;
    let mut failed = None;
    let mut bytes = 0u64;
    let read = rec.each_chunk_of(port, |c| {
        if decoding.is_none() {
            match chunk_protocol(args, c.topic, &c.port.protocol).and_then(|p| {
                let out = Output::new(args, p)?;
                Ok((p, out))
            }) {
                Ok((p, out)) => {
                    let host = args.from == Direction::Host;
                    let d = decoder(p, host, out.params, Some(&c.port.params));
                    decoding = Some((d, out));
                }
                Err(e) => {
                    failed = Some(e);
                    return false;
                }
            }
        }
        let Some((d, out)) = &mut decoding else {
            return false;
        };
        if c.dir != want {
            return true;
        }
        bytes = bytes.saturating_add(c.bytes.len() as u64);
        // This runs under the guard that reports a panic of the `mcap` crate as damage to the
        // file; a panic of ours is a bug to report as one, not damage.
        let fed = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            d.feed(c.bytes, &mut |v| out.emit(v))
        }));
        let e = match fed {
            Ok(Ok(())) => return true,
            Ok(Err(e)) => e,
            Err(p) => anyhow::anyhow!(
                "decoding {} failed (a bug: please report it): {}",
                c.topic,
                ima_record::read::panic_message(&*p)
            ),
        };
        failed = Some(e);
        false
    });
    // A port not found in a file that broke on the way may be in the part not read.
    let cut = read.inspect_err(|_| {
        if let Some(why) = Truncation(rec.damage()).beyond(damage.as_deref()) {
            eprintln!("ima decode: the recording is damaged ({why})");
        }
    })?;
    if let Some(e) = failed {
        return Err(e);
    }
    let Some((mut d, mut out)) = decoding else {
        anyhow::bail!("no chunk of {port} in the recording");
    };
    d.finish(&mut |v| out.emit(v))?;
    if let Some(why) = cut.beyond(damage.as_deref()) {
        eprintln!("ima decode: the recording ends early ({why}); decoded what it holds");
    }
    out.end(bytes)
}

/// The protocol to decode a recorded port as: the one asked for (said when it differs from
/// the recorded one), else the recorded one.
fn chunk_protocol(args: &DecodeArgs, topic: &str, recorded_as: &str) -> Result<Protocol> {
    let recorded = recorded_protocol(recorded_as);
    if let (Some(asked), Some(rec)) = (args.protocol, recorded)
        && asked != rec
    {
        eprintln!(
            "ima decode: {topic} was recorded as {recorded_as}; decoding it as {} as asked",
            asked.name()
        );
    }
    args.protocol.or(recorded).with_context(|| {
        format!(
            "give the protocol: {topic} was recorded as {recorded_as:?}, which `ima decode` \
             does not know"
        )
    })
}

//! A serial video switcher as a device model (Extron SIS; Kramer Protocol 2000 as a second
//! dialect), and the [`VideoBus`] it shares with the mock camera head (spec
//! `protocols/compass_video_mux.md` §7b).
//!
//! # The video bus
//!
//! The switcher and the camera head ([`crate::camera::MockCameraHead`]) are two devices on one
//! video cable. [`VideoBus`] models that cable: the switcher writes which input it passes and
//! when it switched; the camera head reads it to decide what a grabbed frame shows (a frame
//! grabbed before the settle time is garbage). The bus is the only shared state and the only
//! clock reader of the pair: it stamps switches with `tokio::time::Instant::now()`, which is
//! real time on a plain thread and virtual time in a paused tokio test. A camera head without a
//! switcher is "told the channel" through the same bus ([`VideoBus::switch`]).
//!
//! # Switcher behaviour
//!
//! * Extron: `N!`/`N&`/`N$` select input N (1..=inputs) and answer `InN All|Vid|Aud` after
//!   the [switch delay](MuxModelConfig::switch_delay); `!` answers the current input; `0S`
//!   answers `Sig 1 1 …`; `1B`/`0B` answer `Vmt1`/`Vmt0`. Errors: `E01` for an input out of
//!   range (however many digits), `E06` for a selection while auto-switch mode is on, `E10`
//!   for an unknown command. Matrix ties `I*1!` are accepted for output 1 (`Out1 InI All`);
//!   other outputs give `E01`.
//!   The information requests of the SIS manuals are answered too, so that a control system
//!   that asks them first is not left waiting (they used to be taken for the start of the next
//!   command): `I` answers `V<in> A<in> F<mode> Vmt<0|1> Amt0` (mode 1 manual, 2 auto-switch;
//!   SW VGA and MTP manuals), `Q` the model's firmware version [`FIRMWARE`], `B` the video
//!   mute (`0`/`1`; SW AV manual); `N` (part number) gets `E10`, as the model has none.
//!   Escape commands (`ESC …` or `W…`, ended by CR or `|`) are read whole: `ESC 3CV` (verbose
//!   mode) answers `Vrb3`, any other `E10` (they were taken for the start of the next command).
//! * Commands are answered in order: one that comes while a switch is under way waits for it
//!   (`3!I` answers `In3 All`, then `V3 …`; it answered the old input first).
//!   A power-on banner is sent once, when the model starts.
//! * Kramer (`expect_reply` drivers): a video switch to output 1 of machine 1 is echoed with
//!   bit 6 set after the switch delay; a status request answers the input; anything else is
//!   ignored.
//! * Commands are case-insensitive; a pause of 10 s between characters drops a partial command
//!   (SIS rule).

use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use ima_hal::Instant;
use ima_hal::camera::Channel;
use ima_video_mux::wire::extron::BANNER;
use ima_video_mux::wire::{
    ExtronCommand, ExtronError, ExtronReply, Instruction, KramerMessage, Signals, TieKind,
    WireError,
};

use crate::model::DeviceModel;

/// The mock switcher's answer to `Q` (its firmware version, `1.00`).
pub const FIRMWARE: ExtronReply = ExtronReply::Firmware {
    major: 1,
    hundredths: 0,
};

#[derive(Debug, Clone, Copy)]
struct BusState {
    channel: Option<Channel>,
    switched_at: tokio::time::Instant,
    switches: u64,
}

/// The video cable between the mock switcher and the mock camera head. Cheap to clone.
#[derive(Debug, Clone)]
pub struct VideoBus(Arc<Mutex<BusState>>);

impl Default for VideoBus {
    fn default() -> Self {
        Self::new(None)
    }
}

impl VideoBus {
    /// A bus passing `channel` (long settled).
    #[must_use]
    pub fn new(channel: Option<Channel>) -> Self {
        let now = tokio::time::Instant::now();
        let long_ago = now.checked_sub(Duration::from_secs(3600)).unwrap_or(now);
        Self(Arc::new(Mutex::new(BusState {
            channel,
            switched_at: long_ago,
            switches: 0,
        })))
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, BusState> {
        self.0.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Switch the picture to `channel` now.
    pub fn switch(&self, channel: Channel) {
        let mut s = self.lock();
        s.channel = Some(channel);
        s.switched_at = tokio::time::Instant::now();
        s.switches = s.switches.saturating_add(1);
    }

    /// The channel on the cable and how long ago it was switched.
    #[must_use]
    pub fn current(&self) -> (Option<Channel>, Duration) {
        let s = self.lock();
        (s.channel, s.switched_at.elapsed())
    }

    /// Switches so far.
    #[must_use]
    pub fn switches(&self) -> u64 {
        self.lock().switches
    }
}

/// Which protocol the mock speaks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MuxDialect {
    /// Extron SIS.
    Extron,
    /// Kramer Protocol 2000.
    Kramer,
}

/// Settings of the mock switcher.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MuxModelConfig {
    /// Protocol.
    pub dialect: MuxDialect,
    /// Number of inputs (cameras).
    pub inputs: Channel,
    /// Time from a command to the switch and its reply (relay plus vertical-interval wait;
    /// default 30 ms).
    pub switch_delay: Duration,
    /// Front-panel auto-switch mode: selections are refused with `E06`.
    pub auto_switch: bool,
    /// Zero-pad `In` replies to this many digits (`In003 All`; 1 = no padding).
    pub reply_digits: u8,
    /// Send the copyright banner at start.
    pub banner: bool,
}

impl Default for MuxModelConfig {
    fn default() -> Self {
        Self {
            dialect: MuxDialect::Extron,
            inputs: 7,
            switch_delay: Duration::from_millis(30),
            auto_switch: false,
            reply_digits: 1,
            banner: true,
        }
    }
}

/// Counters of the mock.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct MuxModelStats {
    /// Commands understood.
    pub commands: u32,
    /// Error replies sent.
    pub errors: u32,
    /// Switches made.
    pub switches: u32,
}

#[derive(Debug, Clone, Copy)]
enum Pending {
    Extron {
        input: u16,
        kind: TieKind,
        tie: bool,
    },
    Kramer(KramerMessage),
}

const MAX_PARTIAL: usize = 16;
/// Commands kept while a switch is under way (more are ignored).
const MAX_DEFERRED: usize = 32;
const SIS_ABORT: Duration = Duration::from_secs(10);

/// Whether `c` starts an SIS escape command (`ESC` on a serial port, `W` as its stand-in),
/// which ends at CR or `|` ([`ends_escape`]).
fn is_escape(c: u8) -> bool {
    matches!(c, 0x1b | b'W' | b'w')
}

/// Whether `b` ends an SIS escape command.
fn ends_escape(b: u8) -> bool {
    b == b'\r' || b == b'|'
}

/// The mock switcher, a [`DeviceModel`].
#[derive(Debug)]
pub struct MuxDevice {
    cfg: MuxModelConfig,
    bus: VideoBus,
    partial: Vec<u8>,
    last_byte: Instant,
    out: Vec<u8>,
    current: Option<Channel>,
    muted: bool,
    pending: Vec<(Instant, Pending)>,
    /// Extron commands that came while a switch was under way: answered in order, after it.
    deferred: std::collections::VecDeque<Vec<u8>>,
    /// Skipping the rest of an escape command too long to keep (until CR or `|`).
    discarding: bool,
    banner_due: bool,
    stats: MuxModelStats,
}

impl MuxDevice {
    /// A switcher driving `bus`.
    #[must_use]
    pub fn new(cfg: MuxModelConfig, bus: VideoBus) -> Self {
        let current = bus.current().0;
        Self {
            cfg,
            bus,
            partial: Vec::new(),
            last_byte: Instant::ZERO,
            out: Vec::new(),
            current,
            muted: false,
            pending: Vec::new(),
            deferred: std::collections::VecDeque::new(),
            discarding: false,
            banner_due: cfg.banner && cfg.dialect == MuxDialect::Extron,
            stats: MuxModelStats::default(),
        }
    }

    /// Counters.
    #[must_use]
    pub fn stats(&self) -> MuxModelStats {
        self.stats
    }

    /// The input the switcher passes.
    #[must_use]
    pub fn current(&self) -> Option<Channel> {
        self.current
    }

    /// The bus it drives.
    #[must_use]
    pub fn bus(&self) -> &VideoBus {
        &self.bus
    }

    fn reply(&mut self, r: ExtronReply) {
        let mut buf = [0u8; 96];
        if let Ok(n) = r.emit(&mut buf) {
            self.out.extend_from_slice(buf.get(..n).unwrap_or(&[]));
        }
        if matches!(r, ExtronReply::Error(_)) {
            self.stats.errors = self.stats.errors.saturating_add(1);
        }
    }

    fn extron(&mut self, cmd: &[u8], now: Instant) {
        let c = match ExtronCommand::parse(cmd) {
            Ok(c) => c,
            Err(e) => {
                // A number too large for the wire (`99999!`) is an input out of range, as a
                // unit says, not an unknown command.
                let e = match e {
                    WireError::OutOfRange => ExtronError::InvalidInput,
                    _ => ExtronError::InvalidCommand,
                };
                self.reply(ExtronReply::Error(e));
                return;
            }
        };
        self.stats.commands = self.stats.commands.saturating_add(1);
        let select = |me: &mut Self, input: u16, kind, tie| {
            if me.cfg.auto_switch {
                me.reply(ExtronReply::Error(ExtronError::ChangeNotAllowed));
            } else if input == 0 || input > u16::from(me.cfg.inputs) {
                me.reply(ExtronReply::Error(ExtronError::InvalidInput));
            } else {
                let at = now + me.cfg.switch_delay;
                me.pending.push((at, Pending::Extron { input, kind, tie }));
            }
        };
        match c {
            ExtronCommand::Select { input, kind } => select(self, input, kind, false),
            ExtronCommand::Tie {
                input,
                output: 1,
                kind,
            } => select(self, input, kind, true),
            ExtronCommand::Tie { .. } => self.reply(ExtronReply::Error(ExtronError::InvalidInput)),
            ExtronCommand::QueryInput => {
                self.reply(ExtronReply::Current(self.current.map_or(0, u16::from)));
            }
            ExtronCommand::SignalStatus => {
                let count = self
                    .cfg
                    .inputs
                    .min(ima_video_mux::wire::extron::MAX_SIGNALS);
                let mask = if count >= 32 {
                    u32::MAX
                } else {
                    (1u32 << count) - 1
                };
                self.reply(ExtronReply::Signals(Signals { count, mask }));
            }
            ExtronCommand::VideoMute(on) => {
                self.muted = on;
                self.reply(ExtronReply::Mute(on));
            }
            ExtronCommand::ReadVideoMute => self.reply_line(if self.muted { "1" } else { "0" }),
            ExtronCommand::Information => {
                let input = self.current.map_or(0, u16::from);
                self.reply(ExtronReply::Information {
                    video: input,
                    audio: input,
                    mode: Some(if self.cfg.auto_switch { 2 } else { 1 }),
                    video_mute: Some(self.muted),
                    audio_mute: Some(false),
                });
            }
            ExtronCommand::FirmwareVersion => self.reply(FIRMWARE),
            // The model has no part number of its own.
            ExtronCommand::PartNumber => {
                self.reply(ExtronReply::Error(ExtronError::InvalidCommand))
            }
        }
    }

    /// A complete Extron command: answered now, or after the switch under way and the
    /// commands before it (a unit answers in order: `3!I` gave the old input, then `In3 All`).
    fn command(&mut self, cmd: Vec<u8>, now: Instant) {
        if self.pending.is_empty() && self.deferred.is_empty() {
            self.execute(&cmd, now);
        } else if self.deferred.len() < MAX_DEFERRED {
            self.deferred.push_back(cmd);
        } else {
            // No room to keep it: refused at once rather than left unanswered.
            self.reply(ExtronReply::Error(ExtronError::InvalidCommand));
        }
    }

    fn execute(&mut self, cmd: &[u8], now: Instant) {
        match cmd.split_first() {
            Some((&c, body)) if is_escape(c) => self.escape(body),
            _ => self.extron(cmd, now),
        }
    }

    /// An escape command: `<n>CV` (verbose mode) answers `Vrb<n>`; the model takes no other.
    fn escape(&mut self, body: &[u8]) {
        let upper = body.to_ascii_uppercase();
        let mode = upper
            .strip_suffix(b"CV")
            .and_then(|d| ima_hal::bytes::parse_decimal(d, 2).ok())
            .and_then(|n| u8::try_from(n).ok());
        match mode {
            Some(n) => self.reply(ExtronReply::Verbose(n)),
            None => self.reply(ExtronReply::Error(ExtronError::InvalidCommand)),
        }
    }

    /// A reply the wire module has no type for, ended with CR LF.
    fn reply_line(&mut self, line: &str) {
        self.out.extend_from_slice(line.as_bytes());
        self.out.extend_from_slice(b"\r\n");
    }

    fn kramer(&mut self, m: KramerMessage, now: Instant) {
        if m.from_switcher || m.machine != 1 {
            return;
        }
        match m.instruction {
            Instruction::SwitchVideo if m.output == 1 || m.output == 0 => {
                self.stats.commands = self.stats.commands.saturating_add(1);
                if m.input >= 1 && m.input <= self.cfg.inputs {
                    let at = now + self.cfg.switch_delay;
                    self.pending.push((at, Pending::Kramer(m)));
                }
            }
            Instruction::RequestVideoStatus => {
                self.stats.commands = self.stats.commands.saturating_add(1);
                let r = KramerMessage {
                    input: self.current.unwrap_or(0),
                    ..m.as_reply()
                };
                if let Ok(b) = r.to_bytes() {
                    self.out.extend_from_slice(&b);
                }
            }
            _ => {}
        }
    }

    fn complete(&mut self, p: Pending) {
        match p {
            Pending::Extron { input, kind, tie } => {
                let ch = Channel::try_from(input).unwrap_or(Channel::MAX);
                self.switch_to(ch);
                let r = if tie {
                    ExtronReply::Tie {
                        output: 1,
                        input,
                        kind,
                    }
                } else {
                    ExtronReply::Input {
                        input,
                        kind,
                        digits: self.cfg.reply_digits.max(1),
                    }
                };
                self.reply(r);
            }
            Pending::Kramer(m) => {
                self.switch_to(m.input);
                if let Ok(b) = m.as_reply().to_bytes() {
                    self.out.extend_from_slice(&b);
                }
            }
        }
    }

    fn switch_to(&mut self, ch: Channel) {
        self.current = Some(ch);
        self.bus.switch(ch);
        self.stats.switches = self.stats.switches.saturating_add(1);
    }
}

impl DeviceModel for MuxDevice {
    fn handle_rx(&mut self, bytes: &[u8], now: Instant) {
        if !self.partial.is_empty() && now.saturating_duration_since(self.last_byte) >= SIS_ABORT {
            self.partial.clear();
        }
        self.last_byte = now;
        match self.cfg.dialect {
            MuxDialect::Extron => {
                for &b in bytes {
                    // The rest of an escape command too long to keep, up to its end.
                    if self.discarding {
                        self.discarding = !ends_escape(b);
                        continue;
                    }
                    // An escape command (`ESC …` or `W…`) ends at CR or `|`.
                    if self.partial.first().is_some_and(|&c| is_escape(c)) {
                        if ends_escape(b) {
                            let cmd = std::mem::take(&mut self.partial);
                            self.command(cmd, now);
                        } else if self.partial.len() >= MAX_PARTIAL {
                            self.partial.clear();
                            self.discarding = true;
                            self.reply(ExtronReply::Error(ExtronError::InvalidCommand));
                        } else {
                            self.partial.push(b);
                        }
                        continue;
                    }
                    if b == b'\r' || b == b'\n' || b == b' ' {
                        continue;
                    }
                    self.partial.push(b);
                    if let Some(end) = ExtronCommand::command_end(&self.partial) {
                        let cmd: Vec<u8> = self.partial.drain(..end).collect();
                        self.command(cmd, now);
                    } else if self.partial.len() > MAX_PARTIAL {
                        self.partial.clear();
                        self.reply(ExtronReply::Error(ExtronError::InvalidCommand));
                    }
                }
            }
            MuxDialect::Kramer => {
                for &b in bytes {
                    // A byte with bit 7 clear starts a message (self-synchronising).
                    if b & 0x80 == 0 {
                        self.partial.clear();
                    }
                    self.partial.push(b);
                    if self.partial.len() == ima_video_mux::wire::kramer::LEN {
                        let msg = KramerMessage::parse(&self.partial);
                        self.partial.clear();
                        if let Ok(m) = msg {
                            self.kramer(m, now);
                        }
                    } else if self.partial.len() > ima_video_mux::wire::kramer::LEN {
                        self.partial.clear();
                    }
                }
            }
        }
    }

    fn poll_tx(&mut self, out: &mut Vec<u8>) {
        if self.banner_due {
            self.banner_due = false;
            out.extend_from_slice(BANNER);
            out.extend_from_slice(b"\r\n");
        }
        out.append(&mut self.out);
    }

    fn poll_timeout(&self) -> Option<Instant> {
        self.pending.iter().map(|(t, _)| *t).min()
    }

    fn handle_timeout(&mut self, now: Instant) {
        let (due, later): (Vec<_>, Vec<_>) = self.pending.drain(..).partition(|(t, _)| *t <= now);
        self.pending = later;
        for (_, p) in due {
            self.complete(p);
        }
        // The commands that waited for the switch, in order, until one starts another.
        while self.pending.is_empty()
            && let Some(cmd) = self.deferred.pop_front()
        {
            self.execute(&cmd, now);
        }
    }

    fn name(&self) -> &str {
        "video-mux"
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(d: &mut MuxDevice, input: &[u8], now: Instant) -> Vec<u8> {
        d.handle_rx(input, now);
        let later = now + Duration::from_secs(1);
        d.handle_timeout(later);
        let mut out = Vec::new();
        d.poll_tx(&mut out);
        out
    }

    #[test]
    fn extron_select_query_and_errors() {
        let bus = VideoBus::default();
        let mut d = MuxDevice::new(MuxModelConfig::default(), bus.clone());
        let out = run(&mut d, b"3!", Instant::ZERO);
        assert!(
            out.ends_with(b"In3 All\r\n"),
            "{:?}",
            String::from_utf8_lossy(&out)
        );
        assert!(out.starts_with(BANNER));
        assert_eq!(bus.current().0, Some(3));
        assert_eq!(run(&mut d, b"!", Instant::ZERO), b"3\r\n");
        assert_eq!(run(&mut d, b"9!", Instant::ZERO), b"E01\r\n");
        // Too large for the wire's number: still an input out of range.
        assert_eq!(run(&mut d, b"99999!", Instant::ZERO), b"E01\r\n");
        assert_eq!(run(&mut d, b"4294967296&", Instant::ZERO), b"E01\r\n");
        assert_eq!(run(&mut d, b"5x!", Instant::ZERO), b"E10\r\n");
        assert_eq!(run(&mut d, b"2&", Instant::ZERO), b"In2 Vid\r\n");
        assert_eq!(run(&mut d, b"1B", Instant::ZERO), b"Vmt1\r\n");
        // Information requests are answered, and never swallow the command after them.
        assert_eq!(run(&mut d, b"b", Instant::ZERO), b"1\r\n");
        assert_eq!(run(&mut d, b"I", Instant::ZERO), b"V2 A2 F1 Vmt1 Amt0\r\n");
        assert_eq!(run(&mut d, b"q!", Instant::ZERO), b"1.00\r\n2\r\n");
        assert_eq!(run(&mut d, b"N3!", Instant::ZERO), b"E10\r\nIn3 All\r\n");
        assert_eq!(run(&mut d, b"0B", Instant::ZERO), b"Vmt0\r\n");
        // In order: a query behind a switch answers after it, with the new input.
        assert_eq!(
            run(&mut d, b"3!I", Instant::ZERO),
            b"In3 All\r\nV3 A3 F1 Vmt0 Amt0\r\n"
        );
        assert_eq!(
            run(&mut d, b"2!Q!", Instant::ZERO),
            b"In2 All\r\n1.00\r\n2\r\n"
        );
        // Escape commands end at CR or `|` and never swallow the next command.
        assert_eq!(
            run(&mut d, b"\x1b3CV\rQ", Instant::ZERO),
            b"Vrb3\r\n1.00\r\n"
        );
        assert_eq!(
            run(&mut d, b"W3CV|I", Instant::ZERO),
            b"Vrb3\r\nV2 A2 F1 Vmt0 Amt0\r\n"
        );
        assert_eq!(run(&mut d, b"WXYZ|!", Instant::ZERO), b"E10\r\n2\r\n");
        // One too long to keep is refused, and its rest up to its end is skipped.
        assert_eq!(
            run(&mut d, b"W0123456789ABCDEFGHIJ3!|!", Instant::ZERO),
            b"E10\r\n2\r\n"
        );
        let mut auto = MuxDevice::new(
            MuxModelConfig {
                auto_switch: true,
                banner: false,
                ..MuxModelConfig::default()
            },
            VideoBus::default(),
        );
        assert_eq!(run(&mut auto, b"2!", Instant::ZERO), b"E06\r\n");
    }

    #[test]
    fn switch_waits_for_the_delay() {
        let mut d = MuxDevice::new(MuxModelConfig::default(), VideoBus::default());
        d.handle_rx(b"4!", Instant::ZERO);
        assert_eq!(d.poll_timeout(), Some(Instant::from_millis(30)));
        d.handle_timeout(Instant::from_millis(29));
        assert_eq!(d.current(), None);
        d.handle_timeout(Instant::from_millis(30));
        assert_eq!(d.current(), Some(4));
    }

    #[test]
    fn kramer_echo() {
        let cfg = MuxModelConfig {
            dialect: MuxDialect::Kramer,
            ..MuxModelConfig::default()
        };
        let mut d = MuxDevice::new(cfg, VideoBus::default());
        let cmd = KramerMessage::switch_video(5, 1, 1).to_bytes().unwrap();
        let out = run(&mut d, &cmd, Instant::ZERO);
        assert_eq!(
            KramerMessage::parse(&out).unwrap(),
            KramerMessage::switch_video(5, 1, 1).as_reply()
        );
        assert_eq!(d.current(), Some(5));
    }
}

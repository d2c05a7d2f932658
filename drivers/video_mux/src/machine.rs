//! The switcher session (spec §7b): select a channel and match the switcher's reply, with a
//! reply timeout and retries, then report when the picture has settled; ask which channel is
//! selected; report what the switcher says on its own.
//!
//! Sans-IO: feed received bytes with [`Machine::handle_bytes`] (or parsed replies with
//! [`Machine::handle_frame`]), call [`Machine::handle_timeout`] when [`Machine::poll_timeout`]
//! is due, send what [`Machine::poll_transmit`] writes, take [`Machine::poll_event`]s.
//!
//! # Rules
//!
//! * One request (select or query) at a time; another is refused with
//!   [`RequestError::Busy`].
//! * Select: the command is sent; the reply naming the requested channel confirms it
//!   (Extron `In<n> …`, or `Out<o> In<n> …` for a matrix output; Kramer the echo with
//!   bit 6 set). Silence for [`Config::reply_timeout`] re-sends the command, up to
//!   [`Config::retries`] times, then [`Failure::Timeout`]. An error reply (Extron `Enn`,
//!   Kramer instruction 16) fails the request at once, without retry: the switcher
//!   understood and refused.
//! * On confirmation, [`Event::Selected`] carries `settled_at = confirmed_at + settle_time`;
//!   at that instant [`Event::Settled`] follows (a later select cancels it).
//! * A selection the switcher reports that nobody asked for (front panel, or a reply naming
//!   another channel while a select is pending) updates the current channel and is reported
//!   as [`Event::ExternalSelect`]; the pending request keeps waiting for its own reply.
//! * Other unsolicited lines (banner, `Sig …`, mute) are reported if
//!   [`Config::report_unsolicited`] is set, else only counted.
//! * Kramer switchers that do not answer ([`Dialect::Kramer`] `expect_reply: false`) are
//!   taken as confirmed at once (`confirmed_at` = the `now` of [`Machine::select`]; the
//!   command goes out with the next [`Machine::poll_transmit`]).

use core::time::Duration;

use heapless::Deque;
use ima_hal::Instant;
use ima_hal::camera::{Channel, Selection};

use crate::framer::{Frame, FramerStats, KramerFramer, LineFramer};
use crate::wire::{
    ExtronCommand, ExtronError, ExtronReply, Instruction, KramerMessage, Signals, TieKind,
};

/// Which switcher protocol is on the port.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Dialect {
    /// Extron SIS.
    Extron {
        /// What a selection switches (`!` all, `&` video, `$` audio).
        kind: TieKind,
        /// `None`: a single-output switcher (`N!`). `Some(o)`: a matrix, tie to output `o`
        /// (`N*o!`).
        output: Option<u16>,
    },
    /// Kramer Protocol 2000.
    Kramer {
        /// Output number (1 for a single-output switcher).
        output: u8,
        /// Machine number (1 for a single switcher).
        machine: u8,
        /// Wait for the switcher's echo (inferred behaviour; see [`crate::wire::kramer`]).
        expect_reply: bool,
    },
}

/// Session settings. `Default`: Extron, single output, 7 channels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Config {
    /// The protocol.
    pub dialect: Dialect,
    /// Valid channels are `1..=channel_count`.
    pub channel_count: Channel,
    /// How long to wait for a reply before re-sending.
    pub reply_timeout: Duration,
    /// Re-sends after a timeout before giving up.
    pub retries: u8,
    /// Time from a confirmed switch until frames show the new camera. A project choice (no
    /// source gives it): two to three frames of the grabber plus sync lock.
    pub settle_time: Duration,
    /// Report banners, signal and mute lines as events (else only count them).
    pub report_unsolicited: bool,
}

impl Default for Config {
    fn default() -> Self {
        Self {
            dialect: Dialect::Extron {
                kind: TieKind::All,
                output: None,
            },
            channel_count: 7,
            reply_timeout: Duration::from_millis(500),
            retries: 2,
            settle_time: Duration::from_millis(150),
            report_unsolicited: true,
        }
    }
}

/// A parsed reply of either dialect.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Reply {
    /// Extron SIS line.
    Extron(ExtronReply),
    /// Kramer message.
    Kramer(KramerMessage),
}

/// A switcher's refusal.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Refusal {
    /// Extron `Enn`.
    Extron(ExtronError),
    /// Kramer error message (inferred instruction 16), with its input byte as the code.
    Kramer(u8),
}

/// Why a request failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Failure {
    /// No matching reply after all retries.
    Timeout,
    /// The switcher refused.
    Refused(Refusal),
}

/// What the session reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Event {
    /// A requested selection was confirmed.
    Selected(Selection),
    /// The selected channel's picture has settled.
    Settled {
        /// The channel.
        channel: Channel,
    },
    /// A requested selection failed.
    SelectFailed {
        /// The channel asked for.
        channel: Channel,
        /// Why.
        failure: Failure,
    },
    /// Answer to a query (`None`: the switcher reports no input).
    Current {
        /// The channel.
        channel: Option<Channel>,
    },
    /// A query failed.
    QueryFailed {
        /// Why.
        failure: Failure,
    },
    /// The switcher reports a selection nobody here asked for.
    ExternalSelect {
        /// The channel now selected.
        channel: Channel,
    },
    /// An error reply with no request pending.
    UnsolicitedError(Refusal),
    /// Signal presence (Extron `Sig`).
    Signals(Signals),
    /// Video mute state (Extron `Vmt`).
    Mute(bool),
    /// The power-on banner: the switcher (re)started.
    Banner,
}

/// Why a request was refused before anything was sent.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum RequestError {
    /// Channel outside `1..=channel_count` (or beyond what the dialect can carry).
    InvalidChannel(Channel),
    /// Another request is pending.
    Busy,
}

impl core::fmt::Display for RequestError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::InvalidChannel(c) => write!(f, "invalid channel {c}"),
            Self::Busy => f.write_str("another switcher request is pending"),
        }
    }
}

impl core::error::Error for RequestError {}

impl ima_hal::Error for RequestError {
    fn kind(&self) -> ima_hal::ErrorKind {
        match self {
            Self::InvalidChannel(_) => ima_hal::ErrorKind::InvalidArgument,
            Self::Busy => ima_hal::ErrorKind::Other,
        }
    }
}

/// Counters (saturating).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Stats {
    /// The active framer's counters.
    pub framer: FramerStats,
    /// Frames that did not parse.
    pub parse_errors: u32,
    /// Replies that matched nothing and were not reported.
    pub ignored: u32,
    /// Commands re-sent after a timeout.
    pub retransmissions: u32,
    /// Events dropped because the caller did not poll.
    pub events_dropped: u32,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Command {
    Extron(ExtronCommand),
    Kramer(KramerMessage),
}

impl Command {
    fn emit(&self, buf: &mut [u8]) -> Option<usize> {
        match self {
            Self::Extron(c) => c.emit(buf).ok(),
            Self::Kramer(m) => m.emit(buf).ok(),
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum RequestKind {
    Select(Channel),
    Query,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Pending {
    kind: RequestKind,
    cmd: Command,
    deadline: Instant,
    retries_left: u8,
}

const EVENT_CAPACITY: usize = 16;

/// The switcher session. See the [module docs](self).
#[derive(Debug, Clone)]
pub struct Machine {
    config: Config,
    lines: LineFramer,
    kramer: KramerFramer,
    pending: Option<Pending>,
    tx: Option<Command>,
    current: Option<Channel>,
    settling: Option<(Channel, Instant)>,
    events: Deque<Event, EVENT_CAPACITY>,
    stats: Stats,
}

impl Machine {
    /// A session; nothing is sent until a request.
    #[must_use]
    pub fn new(config: Config) -> Self {
        Self {
            config,
            lines: LineFramer::default(),
            kramer: KramerFramer::new(),
            pending: None,
            tx: None,
            current: None,
            settling: None,
            events: Deque::new(),
            stats: Stats::default(),
        }
    }

    /// The settings.
    #[must_use]
    pub fn config(&self) -> &Config {
        &self.config
    }

    /// The channel last confirmed or reported by the switcher.
    #[must_use]
    pub fn current_channel(&self) -> Option<Channel> {
        self.current
    }

    /// A request is pending.
    #[must_use]
    pub fn is_busy(&self) -> bool {
        self.pending.is_some()
    }

    /// Counters.
    #[must_use]
    pub fn stats(&self) -> Stats {
        let framer = match self.config.dialect {
            Dialect::Extron { .. } => self.lines.stats().into(),
            Dialect::Kramer { .. } => self.kramer.stats(),
        };
        Stats {
            framer,
            ..self.stats
        }
    }

    /// Ask for `channel`; [`Event::Selected`] or [`Event::SelectFailed`] follows.
    ///
    /// # Errors
    /// [`RequestError::InvalidChannel`], [`RequestError::Busy`].
    pub fn select(&mut self, channel: Channel, now: Instant) -> Result<(), RequestError> {
        if channel == 0 || channel > self.config.channel_count {
            return Err(RequestError::InvalidChannel(channel));
        }
        if self.is_busy() {
            return Err(RequestError::Busy);
        }
        let cmd = match self.config.dialect {
            Dialect::Extron { kind, output: None } => Command::Extron(ExtronCommand::Select {
                input: u16::from(channel),
                kind,
            }),
            Dialect::Extron {
                kind,
                output: Some(output),
            } => Command::Extron(ExtronCommand::Tie {
                input: u16::from(channel),
                output,
                kind,
            }),
            Dialect::Kramer {
                output,
                machine,
                expect_reply,
            } => {
                if channel > 0x7f {
                    return Err(RequestError::InvalidChannel(channel));
                }
                let cmd = Command::Kramer(KramerMessage::switch_video(channel, output, machine));
                if !expect_reply {
                    self.tx = Some(cmd);
                    self.confirm(channel, now);
                    return Ok(());
                }
                cmd
            }
        };
        self.settling = None;
        self.send(RequestKind::Select(channel), cmd, now);
        Ok(())
    }

    /// Ask which channel is selected; [`Event::Current`] or [`Event::QueryFailed`] follows.
    /// A Kramer switcher configured without replies answers from memory at once.
    ///
    /// # Errors
    /// [`RequestError::Busy`].
    pub fn query(&mut self, now: Instant) -> Result<(), RequestError> {
        if self.is_busy() {
            return Err(RequestError::Busy);
        }
        let cmd = match self.config.dialect {
            Dialect::Extron { .. } => Command::Extron(ExtronCommand::QueryInput),
            Dialect::Kramer {
                output,
                machine,
                expect_reply,
            } => {
                if !expect_reply {
                    self.push_event(Event::Current {
                        channel: self.current,
                    });
                    return Ok(());
                }
                Command::Kramer(KramerMessage::request_status(output, machine))
            }
        };
        self.send(RequestKind::Query, cmd, now);
        Ok(())
    }

    fn send(&mut self, kind: RequestKind, cmd: Command, now: Instant) {
        self.tx = Some(cmd);
        self.pending = Some(Pending {
            kind,
            cmd,
            deadline: now + self.config.reply_timeout,
            retries_left: self.config.retries,
        });
    }

    fn push_event(&mut self, e: Event) {
        if self.events.is_full() {
            let _ = self.events.pop_front();
            self.stats.events_dropped = self.stats.events_dropped.saturating_add(1);
        }
        let _ = self.events.push_back(e);
    }

    fn count_parse_error(&mut self) {
        self.stats.parse_errors = self.stats.parse_errors.saturating_add(1);
    }

    /// Feed received bytes (any chunking).
    pub fn handle_bytes(&mut self, bytes: &[u8], now: Instant) {
        for &b in bytes {
            let reply = match self.config.dialect {
                Dialect::Extron { .. } => match self.lines.push_byte(b) {
                    Some(Frame::Line(l)) => Some(ExtronReply::parse(l).map(Reply::Extron)),
                    Some(Frame::Prompt | Frame::Corrupt(_)) | None => None,
                },
                Dialect::Kramer { .. } => self
                    .kramer
                    .push_byte(b)
                    .map(|m| KramerMessage::parse(&m).map(Reply::Kramer)),
            };
            match reply {
                Some(Ok(r)) => self.handle_frame(r, now),
                Some(Err(_)) => self.count_parse_error(),
                None => {}
            }
        }
    }

    /// Feed one parsed reply (what [`Machine::handle_bytes`] does for each reply it frames).
    pub fn handle_frame(&mut self, reply: Reply, now: Instant) {
        let pending = self.pending.map(|p| p.kind);
        match reply {
            Reply::Extron(r) => self.handle_extron(r, pending, now),
            Reply::Kramer(m) => self.handle_kramer(m, pending, now),
        }
    }

    fn handle_extron(&mut self, r: ExtronReply, pending: Option<RequestKind>, now: Instant) {
        let my_output = match self.config.dialect {
            Dialect::Extron { output, .. } => output,
            Dialect::Kramer { .. } => None,
        };
        match r {
            ExtronReply::Input { input, .. } if my_output.is_none() => {
                self.reported_selection(input, pending, now);
            }
            ExtronReply::Tie { output, input, .. } if my_output == Some(output) => {
                self.reported_selection(input, pending, now);
            }
            ExtronReply::Current(n) if pending == Some(RequestKind::Query) => {
                self.pending = None;
                let channel = Channel::try_from(n).ok().filter(|c| *c != 0);
                self.current = channel;
                self.push_event(Event::Current { channel });
            }
            ExtronReply::Error(e) => self.refused(Refusal::Extron(e), pending),
            ExtronReply::Signals(s) => self.unsolicited(Event::Signals(s)),
            ExtronReply::Mute(m) => self.unsolicited(Event::Mute(m)),
            ExtronReply::Banner => self.unsolicited(Event::Banner),
            ExtronReply::Input { .. }
            | ExtronReply::Tie { .. }
            | ExtronReply::Current(_)
            | ExtronReply::Information { .. }
            | ExtronReply::Firmware { .. }
            | ExtronReply::Verbose(_) => {
                self.stats.ignored = self.stats.ignored.saturating_add(1);
            }
        }
    }

    fn handle_kramer(&mut self, m: KramerMessage, pending: Option<RequestKind>, now: Instant) {
        let Dialect::Kramer {
            output, machine, ..
        } = self.config.dialect
        else {
            self.stats.ignored = self.stats.ignored.saturating_add(1);
            return;
        };
        if !m.from_switcher || m.machine != machine {
            self.stats.ignored = self.stats.ignored.saturating_add(1);
            return;
        }
        match m.instruction {
            Instruction::SwitchVideo if m.output == output => {
                self.reported_selection(u16::from(m.input), pending, now);
            }
            Instruction::RequestVideoStatus
                if m.output == output && pending == Some(RequestKind::Query) =>
            {
                self.pending = None;
                let channel = Some(m.input).filter(|c| *c != 0);
                self.current = channel;
                self.push_event(Event::Current { channel });
            }
            Instruction::Error => self.refused(Refusal::Kramer(m.input), pending),
            _ => self.stats.ignored = self.stats.ignored.saturating_add(1),
        }
    }

    /// The switcher says `input` is now selected.
    fn reported_selection(&mut self, input: u16, pending: Option<RequestKind>, now: Instant) {
        let Ok(channel) = Channel::try_from(input) else {
            self.stats.ignored = self.stats.ignored.saturating_add(1);
            return;
        };
        match pending {
            Some(RequestKind::Select(want)) if want == channel => {
                self.pending = None;
                self.confirm(channel, now);
            }
            Some(RequestKind::Query) => {
                // Some models answer `!` with `In<n> All`.
                self.pending = None;
                self.current = Some(channel).filter(|c| *c != 0);
                self.push_event(Event::Current {
                    channel: self.current,
                });
            }
            _ => {
                self.current = Some(channel).filter(|c| *c != 0);
                self.settling = None;
                self.push_event(Event::ExternalSelect { channel });
            }
        }
    }

    fn confirm(&mut self, channel: Channel, now: Instant) {
        let settled_at = now + self.config.settle_time;
        self.current = Some(channel);
        self.settling = Some((channel, settled_at));
        self.push_event(Event::Selected(Selection {
            channel,
            confirmed_at: now,
            settled_at,
        }));
    }

    fn refused(&mut self, refusal: Refusal, pending: Option<RequestKind>) {
        self.pending = None;
        let failure = Failure::Refused(refusal);
        match pending {
            Some(RequestKind::Select(channel)) => {
                self.push_event(Event::SelectFailed { channel, failure });
            }
            Some(RequestKind::Query) => self.push_event(Event::QueryFailed { failure }),
            None => self.push_event(Event::UnsolicitedError(refusal)),
        }
    }

    fn unsolicited(&mut self, e: Event) {
        if self.config.report_unsolicited {
            self.push_event(e);
        } else {
            self.stats.ignored = self.stats.ignored.saturating_add(1);
        }
    }

    /// Call when [`Machine::poll_timeout`] is due (early or late calls are harmless).
    pub fn handle_timeout(&mut self, now: Instant) {
        if let Some(p) = self.pending.as_mut()
            && now >= p.deadline
        {
            if p.retries_left > 0 {
                p.retries_left -= 1;
                p.deadline = now + self.config.reply_timeout;
                self.tx = Some(p.cmd);
                self.stats.retransmissions = self.stats.retransmissions.saturating_add(1);
            } else {
                let kind = p.kind;
                self.pending = None;
                self.tx = None;
                let failure = Failure::Timeout;
                self.push_event(match kind {
                    RequestKind::Select(channel) => Event::SelectFailed { channel, failure },
                    RequestKind::Query => Event::QueryFailed { failure },
                });
            }
        }
        if let Some((channel, at)) = self.settling
            && now >= at
        {
            self.settling = None;
            self.push_event(Event::Settled { channel });
        }
    }

    /// When [`Machine::handle_timeout`] must next be called.
    #[must_use]
    pub fn poll_timeout(&self) -> Option<Instant> {
        let a = self.pending.map(|p| p.deadline);
        let b = self.settling.map(|(_, t)| t);
        match (a, b) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// Write the next command into `buf` (12 bytes suffice) and return its length. A
    /// too-small buffer returns `None` and keeps the command.
    pub fn poll_transmit(&mut self, buf: &mut [u8]) -> Option<usize> {
        let cmd = self.tx?;
        let n = cmd.emit(buf)?;
        self.tx = None;
        Some(n)
    }

    /// The next event.
    pub fn poll_event(&mut self) -> Option<Event> {
        self.events.pop_front()
    }
}

ima_serial::impl_machine!(Machine, Event, |m, _now, buf| m.poll_transmit(buf));

#[cfg(test)]
mod tests;

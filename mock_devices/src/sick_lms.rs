//! The SICK LMS 200/291 as a sans-IO device model (spec `sick_lms.md`).
//!
//! [`SickLmsModel`] parses host telegrams with `ima_sick_lms::framer`/`wire` (one framing
//! implementation for both sides) but follows the *device's* rules:
//!
//! * **Power-up** at [`SickLmsModelConfig::baud`] (9600 like a real unit, unless configured),
//!   busy for [`SickLmsModelConfig::boot_delay`], then the power-on telegram `90` (§3.8).
//!   Reset `10` answers `91`, reboots at the power-up rate and sends `90` again.
//! * **Receive side** (§5 rule 6): bytes outside a frame other than `02` are ignored; a
//!   telegram with a bad CRC gets `15` (NAK) and is dropped; a partial telegram is abandoned
//!   after [`SickLmsModelConfig::inter_byte_gap`] of silence. A good telegram gets `06` (ACK)
//!   after [`SickLmsModelConfig::ack_delay`] (≤ 60 ms, §2), then its reply.
//! * **Line speed.** The unit runs at one rate at a time; `20 4x` answers `A0` at the old
//!   rate and switches once that reply has left. When the host's line is set to another rate
//!   ([`crate::model::DeviceModel::set_host_baud`]), what the host sends is noise to the unit
//!   (dropped, counted in [`SickLmsStats::garbled_rx`]) and what the unit sends reaches the host
//!   as noise: each byte is replaced by `0xF0 | (b & 0x0F)`, a stand-in for framing-error
//!   garbage that never forms an STX, ACK or NAK (counted in [`SickLmsStats::garbled_tx`]).
//! * **Output pacing.** A pty has no baud timing, so the model paces itself: every byte takes
//!   10 bit times at the unit's rate; a telegram is released when its last byte would have
//!   left the unit, and the next one starts after it.
//! * **Streaming** (`20 24`): the next B0 starts when the previous one has finished sending
//!   *and* a new scan is due (mirror at [`SickLmsModelConfig::mirror_hz`], 1/2/4 revolutions per
//!   scan at 1°/0.5°/0.25°, §4), so the rate is the lower of line and mirror: ≈5.2 scans/s for
//!   361 values at 38400, 37.5 at 500 000.
//! * **Variants** (`3B`, §3.6), **config** read/write (`74`/`77`, §3.7; a write needs
//!   installation mode `20 00 SICK_LMS` and counts as one EEPROM write), status `31` (B1 with
//!   the fields of the spec's table), type `3A`, errors `32`, one scan `30`. Unsupported
//!   operating modes (mean values, sub-ranges, partial scans) are refused with `92` (layout
//!   `92 S`, the spec's assumption).
//! * **Every CRC-valid telegram is answered**, as a real unit does (§2: ACK, then a reply or
//!   the `92` refusal), so a client never waits out a timeout on a good telegram. The choices
//!   where the spec is silent:
//!   - a **short config write** (`77` with fewer than 32 config bytes, e.g. the 7-byte
//!     `02 00 08 00 77 00 00 00 00 00 01 01 CD FA` that long-used clients send, spec §3.7) is
//!     accepted: ACK, the bytes given overwrite the first bytes of the configuration, the rest
//!     is kept, and `F7` echoes the whole configuration (in installation mode; otherwise `92`,
//!     like a full write). Counted in [`SickLmsStats::short_config_writes`];
//!   - a **parameterless query with stray bytes** (`31`, `32`, `3A`, `74` followed by data) is
//!     answered as the query, the extra bytes ignored (counted in
//!     [`SickLmsStats::tolerated`]): the request is unambiguous and harmless to answer;
//!   - **anything else the unit cannot parse** — an unknown code such as `45`, a known code
//!     with a malformed payload — is ACKed (the telegram arrived intact) and refused with
//!     `92 S` (counted in [`SickLmsStats::rejected`]).
//! * **Scripted misbehaviour** for driver tests: [`SickLmsModel::nak_next`] (NAK good
//!   telegrams), [`SickLmsModel::lose_reply_to`] (a reply lost on the line after its ACK; the
//!   command still took effect), [`SickLmsModel::refuse`] (a command this unit refuses with
//!   `92`), [`SickLmsModelConfig::config_write_result`] (QM units answer `F7 00` on success),
//!   and an opt-in log of the commands received ([`SickLmsModel::record_commands`]).
//! * **Ranges** come from a [`RangeSource`]: a [`WorldLaser`] ray-casts the simulated world
//!   from the laser's mount on its robot and adds uniform noise (±50 mm by default), encoded
//!   in the configured measuring mode and units (mode 00 in mm, the 8 m mode, by default).

use std::collections::VecDeque;
use std::time::Duration;

use ima_hal::{Instant, Isometry2};
use ima_sick_lms::decode::{Variant, encode_range_m, lms_deg_to_sensor_rad, max_range_m};
use ima_sick_lms::framer::{Framer, Item};
use ima_sick_lms::machine::wire_time;
use ima_sick_lms::wire::{
    ACK, BaudRate, Command, DEFAULT_PASSWORD, DEFAULT_REPLY_ADDRESS, ErrorPairs, LmsConfig,
    MAX_TELEGRAM, MeasuringMode, ModeRequest, NAK, Reply, Scan, StatusBlock, StatusBlockBuf,
    StatusByte, Units, Values,
};
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};

/// Where the model's ranges come from.
pub trait RangeSource: Send {
    /// Ranges of `count` beams starting at `start_rad` (sensor frame, 0 = straight ahead,
    /// counter-clockwise) every `step_rad`, into `out` (cleared first); `None` = no return
    /// within `max_range_m`.
    fn ranges(
        &mut self,
        start_rad: f64,
        step_rad: f64,
        count: u16,
        max_range_m: f64,
        out: &mut Vec<Option<f64>>,
    );
}

/// A laser on a robot of a [`crate::world::World`]: ray casts plus uniform noise.
#[derive(Debug)]
pub struct WorldLaser {
    world: crate::world::SharedWorld,
    robot: crate::world::RobotId,
    mount: Isometry2,
    noise_m: f64,
    rng: SmallRng,
}

impl WorldLaser {
    /// The laser of `robot`, mounted at its centre facing forward, ±50 mm uniform noise seeded
    /// with `seed`.
    pub fn new(world: crate::world::SharedWorld, robot: crate::world::RobotId, seed: u64) -> Self {
        Self {
            world,
            robot,
            mount: Isometry2::identity(),
            noise_m: 0.05,
            rng: SmallRng::seed_from_u64(seed),
        }
    }

    /// Mount the laser at `mount` on the robot.
    #[must_use]
    pub fn with_mount(mut self, mount: Isometry2) -> Self {
        self.mount = mount;
        self
    }

    /// Uniform noise of ±`noise_m` metres (0 for none).
    #[must_use]
    pub fn with_noise(mut self, noise_m: f64) -> Self {
        self.noise_m = if noise_m.is_finite() {
            noise_m.abs()
        } else {
            0.0
        };
        self
    }
}

impl RangeSource for WorldLaser {
    fn ranges(
        &mut self,
        start_rad: f64,
        step_rad: f64,
        count: u16,
        max_range_m: f64,
        out: &mut Vec<Option<f64>>,
    ) {
        let model = crate::world::LaserModel {
            start_rad,
            step_rad,
            count,
            max_range_m,
            noise_std_m: 0.0,
        };
        let mut rng = SmallRng::seed_from_u64(0);
        self.world
            .with(|w| model.scan(w, self.robot, &self.mount, &mut rng, out));
        if self.noise_m > 0.0 {
            for r in out.iter_mut().flatten() {
                *r = (*r + self.rng.random_range(-self.noise_m..=self.noise_m)).max(0.0);
            }
        }
    }
}

/// How the mock unit behaves.
#[derive(Debug, Clone)]
pub struct SickLmsModelConfig {
    /// Power-up rate (a real unit: 9600 unless the permanent-baud flag was set, §6).
    pub baud: BaudRate,
    /// Reply address (`0x80`; QM units answer at `0x81`).
    pub address: u8,
    /// Busy time after power-up or reset before the `90` telegram (real units: up to 60 s).
    pub boot_delay: Duration,
    /// Type string of `BA` (§3.5).
    pub type_string: String,
    /// The 21 ASCII bytes of the power-on telegram (padded or cut to 21).
    pub power_on_text: String,
    /// Variant at power-up.
    pub variant: Variant,
    /// Configuration at power-up (34-byte form; mode 00, mm by default).
    pub config: LmsConfig,
    /// ACK/NAK delay after a telegram (≤ 60 ms, §2).
    pub ack_delay: Duration,
    /// Delay between the ACK and an ordinary reply.
    pub reply_delay: Duration,
    /// Delay of an operating-mode reply (`A0`; ≤ 3 s).
    pub mode_delay: Duration,
    /// Delay of a config write reply (`F7`; real units take up to ~7 s).
    pub config_write_delay: Duration,
    /// Silence after which a partial host telegram is abandoned (6 ms, §5).
    pub inter_byte_gap: Duration,
    /// Mirror speed (75 Hz).
    pub mirror_hz: f64,
    /// `500000` can be selected (an RS-422 link); otherwise `20 48` is refused (`A0 01`).
    pub rs422: bool,
    /// Status byte of replies (`0x10` normal; set bit 7 to report pollution).
    pub status: StatusByte,
    /// Result byte of `F7` after a config write (TL: `01` accepted; QM units answer `00` on
    /// success, spec §3.7).
    pub config_write_result: u8,
}

impl Default for SickLmsModelConfig {
    fn default() -> Self {
        let mut config = LmsConfig::zeroed(true);
        config.set_units(1);
        config.set_measuring_mode(MeasuringMode::DEFAULT);
        Self {
            baud: BaudRate::B9600,
            address: DEFAULT_REPLY_ADDRESS,
            boot_delay: Duration::from_millis(200),
            type_string: "LMS200;30106".into(),
            power_on_text: "LMS200;301063;V02.06 ".into(),
            variant: Variant::W180_R50,
            config,
            ack_delay: Duration::from_millis(2),
            reply_delay: Duration::from_millis(3),
            mode_delay: Duration::from_millis(10),
            config_write_delay: Duration::from_millis(300),
            inter_byte_gap: Duration::from_millis(6),
            mirror_hz: 75.0,
            rs422: true,
            status: StatusByte::NORMAL,
            config_write_result: 1,
        }
    }
}

/// Counters of the model.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SickLmsStats {
    /// Telegrams accepted (ACKed).
    pub telegrams: u64,
    /// Telegrams with a bad CRC (NAKed).
    pub naks: u64,
    /// Commands refused with `92`.
    pub rejected: u64,
    /// B0 scans sent.
    pub scans: u64,
    /// Config writes (EEPROM writes).
    pub eeprom_writes: u64,
    /// Rate changes.
    pub baud_changes: u64,
    /// Variant changes.
    pub variant_changes: u64,
    /// Power-ups and resets.
    pub boots: u64,
    /// Host bytes lost because the host's line was at another rate.
    pub garbled_rx: u64,
    /// Unit bytes garbled because the host's line was at another rate.
    pub garbled_tx: u64,
    /// Host bytes that were ignored (outside a frame, abandoned partials, while booting).
    pub ignored_rx: u64,
    /// Short config writes (`77` with fewer than 32 config bytes) accepted.
    pub short_config_writes: u64,
    /// Parameterless queries answered although stray bytes followed the code.
    pub tolerated: u64,
    /// Good telegrams NAKed on purpose ([`SickLmsModel::nak_next`]).
    pub scripted_naks: u64,
    /// Replies dropped on purpose ([`SickLmsModel::lose_reply_to`]).
    pub lost_replies: u64,
}

/// A CRC-valid host telegram, as the unit understood it.
#[derive(Debug)]
enum Received {
    /// A command of the wire module.
    Command(Command),
    /// `77` with fewer than 32 config bytes: these overwrite the configuration's first bytes.
    ShortConfig(Vec<u8>),
    /// A parameterless query followed by stray bytes, answered as the query.
    Tolerated(Command),
    /// Anything else: refused with `92`.
    Unparsable(u8),
    /// A candidate whose CRC failed: NAK.
    BadCrc,
}

impl Received {
    fn classify(f: &ima_sick_lms::wire::Frame<'_>) -> Self {
        use ima_sick_lms::wire::cmd;
        if let Ok(c) = Command::from_frame(f) {
            return Self::Command(c);
        }
        let data = f.data();
        match f.code() {
            cmd::WRITE_CONFIG if !data.is_empty() && data.len() < LmsConfig::SHORT => {
                Self::ShortConfig(data.to_vec())
            }
            cmd::STATUS => Self::Tolerated(Command::Status),
            cmd::ERRORS => Self::Tolerated(Command::Errors),
            cmd::TYPE => Self::Tolerated(Command::Type),
            cmd::READ_CONFIG => Self::Tolerated(Command::ReadConfig),
            code => Self::Unparsable(code),
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum OpMode {
    Installation,
    Diagnostic,
    RequestOnly,
    Streaming,
}

#[derive(Debug)]
struct Outgoing {
    bytes: Vec<u8>,
    /// Earliest instant the first byte may leave.
    not_before: Instant,
    /// Switch to this rate once the telegram has left (baud change, reset).
    then_baud: Option<BaudRate>,
    is_scan: bool,
}

/// The SICK LMS firmware, sans-IO. See the module docs.
pub struct SickLmsModel {
    cfg: SickLmsModelConfig,
    source: Box<dyn RangeSource>,
    framer: Framer,
    baud: BaudRate,
    host_baud: Option<u32>,
    booted_at: Option<Instant>,
    boot_until: Option<Instant>,
    mode: OpMode,
    variant: Variant,
    config: LmsConfig,
    /// Telegrams waiting for the line, in order.
    queue: VecDeque<Outgoing>,
    /// The line is busy until then (the telegram being sent finishes).
    line_free: Instant,
    /// Bytes released to the host, waiting for `poll_tx`.
    out: Vec<u8>,
    next_scan_due: Instant,
    scan_index: u8,
    telegram_index: u8,
    ranges: Vec<Option<f64>>,
    words: Vec<u16>,
    stats: SickLmsStats,
    nak_next: u32,
    lose_reply_to: Vec<u8>,
    losing_reply: bool,
    refuse: Vec<u8>,
    log: Option<Vec<(Instant, Command)>>,
}

impl std::fmt::Debug for SickLmsModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SickLmsModel")
            .field("baud", &self.baud)
            .field("mode", &self.mode)
            .field("variant", &self.variant)
            .field("stats", &self.stats)
            .finish_non_exhaustive()
    }
}

impl SickLmsModel {
    /// A unit that powers up at `now`, measuring with `source`.
    pub fn new(cfg: SickLmsModelConfig, source: Box<dyn RangeSource>, now: Instant) -> Self {
        let framer = Framer::commands()
            .with_partial_timeout(cfg.inter_byte_gap)
            .report_bad_checksums(true)
            .accept_any_code(true);
        let mut m = Self {
            baud: cfg.baud,
            variant: cfg.variant,
            config: cfg.config,
            cfg,
            source,
            framer,
            host_baud: None,
            booted_at: None,
            boot_until: None,
            mode: OpMode::RequestOnly,
            queue: VecDeque::new(),
            line_free: now,
            out: Vec::new(),
            next_scan_due: now,
            scan_index: 0,
            telegram_index: 0,
            ranges: Vec::with_capacity(401),
            words: Vec::with_capacity(401),
            stats: SickLmsStats::default(),
            nak_next: 0,
            lose_reply_to: Vec::new(),
            losing_reply: false,
            refuse: Vec::new(),
            log: None,
        };
        m.power_up(now);
        m
    }

    /// A unit that has been running since before `now`: booted, its power-on telegram long
    /// gone, idle (mode `25`) at `baud` (a previous host may have switched it; a reset or
    /// power cycle goes back to [`SickLmsModelConfig::baud`]). For tests that start mid-life.
    pub fn running(
        cfg: SickLmsModelConfig,
        source: Box<dyn RangeSource>,
        now: Instant,
        baud: BaudRate,
    ) -> Self {
        let mut m = Self::new(cfg, source, now);
        m.boot_until = None;
        m.booted_at = Some(now);
        m.baud = baud;
        m
    }

    /// The counters of the unit's telegram framer (bad headers, CRCs, payloads, …).
    #[must_use]
    pub fn framer_counters(&self) -> ima_sick_lms::framer::Counters {
        self.framer.counters()
    }

    /// Put the unit in streaming mode (`24`) from `now`, as a previous host may have left it.
    pub fn start_streaming(&mut self, now: Instant) {
        self.mode = OpMode::Streaming;
        self.next_scan_due = now;
    }

    /// NAK the next `n` good telegrams instead of executing them (a unit too busy to listen).
    pub fn nak_next(&mut self, n: u32) {
        self.nak_next = n;
    }

    /// Lose the reply to the next telegram with command code `code` on the line: the ACK goes
    /// out and the command takes effect (a baud change still switches), but the reply never
    /// reaches the host. Calls accumulate (one loss each).
    pub fn lose_reply_to(&mut self, code: u8) {
        self.lose_reply_to.push(code);
    }

    /// Refuse every telegram with command code `code` with `92` (a unit without the feature).
    pub fn refuse(&mut self, code: u8) {
        if !self.refuse.contains(&code) {
            self.refuse.push(code);
        }
    }

    /// Start keeping a log of the commands received (with their arrival instants).
    pub fn record_commands(&mut self) {
        self.log.get_or_insert_with(Vec::new);
    }

    /// The commands received since [`SickLmsModel::record_commands`] (empty when not
    /// recording).
    #[must_use]
    pub fn commands(&self) -> &[(Instant, Command)] {
        self.log.as_deref().unwrap_or(&[])
    }

    /// Empty the command log (recording goes on).
    pub fn clear_commands(&mut self) {
        if let Some(l) = &mut self.log {
            l.clear();
        }
    }

    /// Counters.
    #[must_use]
    pub fn stats(&self) -> SickLmsStats {
        self.stats
    }

    /// The unit's current line rate.
    #[must_use]
    pub fn baud(&self) -> BaudRate {
        self.baud
    }

    /// The current variant.
    #[must_use]
    pub fn variant(&self) -> Variant {
        self.variant
    }

    /// The current configuration.
    #[must_use]
    pub fn config(&self) -> LmsConfig {
        self.config
    }

    /// The unit is streaming B0 scans.
    #[must_use]
    pub fn is_streaming(&self) -> bool {
        self.mode == OpMode::Streaming
    }

    /// Power-cycle the unit: back to the power-up rate, variant and stream state (the
    /// EEPROM configuration is kept), busy for the boot delay, then `90`.
    pub fn power_up(&mut self, now: Instant) {
        self.baud = self.cfg.baud;
        self.variant = self.cfg.variant;
        self.mode = OpMode::RequestOnly;
        self.queue.clear();
        self.framer.clear();
        self.line_free = now;
        self.booted_at = None;
        self.boot_until = Some(now + self.cfg.boot_delay);
        self.stats.boots = self.stats.boots.saturating_add(1);
    }

    fn line_matches(&self) -> bool {
        self.host_baud.is_none_or(|h| h == self.baud.bps())
    }

    /// Feed host bytes.
    pub fn handle_rx(&mut self, bytes: &[u8], now: Instant) {
        if self.boot_until.is_some() {
            self.stats.ignored_rx = self.stats.ignored_rx.saturating_add(bytes.len() as u64);
            return;
        }
        if !self.line_matches() {
            self.stats.garbled_rx = self.stats.garbled_rx.saturating_add(bytes.len() as u64);
            self.framer.clear();
            return;
        }
        let before = self.framer.counters().dropped_bytes;
        let mut received: Vec<Received> = Vec::new();
        self.framer.push_all(bytes, now, |item| match item {
            Item::Frame(f) => received.push(Received::classify(&f)),
            Item::BadChecksum => received.push(Received::BadCrc),
            Item::Ack | Item::Nak => {}
        });
        let dropped = self.framer.counters().dropped_bytes.saturating_sub(before);
        self.stats.ignored_rx = self.stats.ignored_rx.saturating_add(dropped);
        for r in received {
            match r {
                Received::Command(c) => self.execute(c, now),
                Received::Tolerated(c) => {
                    self.stats.tolerated = self.stats.tolerated.saturating_add(1);
                    self.execute(c, now);
                }
                Received::ShortConfig(data) => self.write_short_config(&data, now),
                Received::Unparsable(code) => {
                    if self.acknowledge(code, now) {
                        self.reject(now + self.cfg.ack_delay + self.cfg.reply_delay);
                        self.losing_reply = false;
                    }
                }
                Received::BadCrc => {
                    self.stats.naks = self.stats.naks.saturating_add(1);
                    self.send_raw(vec![NAK], now + self.cfg.ack_delay, None, false);
                }
            }
        }
        self.release(now);
    }

    /// Bytes released to the host so far.
    pub fn take_output(&mut self) -> Vec<u8> {
        std::mem::take(&mut self.out)
    }

    /// The host's line rate changed (`None`: unknown, treated as matching).
    pub fn set_host_baud(&mut self, baud: Option<u32>) {
        self.host_baud = baud;
    }

    /// When [`SickLmsModel::handle_timeout`] must next be called.
    #[must_use]
    pub fn poll_timeout(&self) -> Option<Instant> {
        let release = self.queue.front().map(|o| self.release_at(o));
        let scan = (self.mode == OpMode::Streaming && !self.queue.iter().any(|o| o.is_scan))
            .then(|| self.next_scan_due.max(self.line_free));
        [self.boot_until, release, scan, self.framer.poll_timeout()]
            .into_iter()
            .flatten()
            .min()
    }

    /// Timers: boot, telegram release, the scan stream, partial-telegram expiry.
    pub fn handle_timeout(&mut self, now: Instant) {
        if let Some(t) = self.boot_until
            && t <= now
        {
            self.boot_until = None;
            self.booted_at = Some(now);
            let mut text = [b' '; 21];
            for (d, s) in text.iter_mut().zip(self.cfg.power_on_text.bytes()) {
                *d = s;
            }
            self.send_reply(
                &Reply::PowerOn {
                    text: &text,
                    status: StatusByte(self.cfg.status.0 | 0x03),
                },
                now,
                None,
            );
        }
        if self.framer.poll_timeout().is_some_and(|t| t <= now) {
            let before = self.framer.counters().dropped_bytes;
            self.framer.push_all(&[], now, |_| {});
            let dropped = self.framer.counters().dropped_bytes.saturating_sub(before);
            self.stats.ignored_rx = self.stats.ignored_rx.saturating_add(dropped);
        }
        self.release(now);
        if self.mode == OpMode::Streaming
            && !self.queue.iter().any(|o| o.is_scan)
            && now >= self.next_scan_due.max(self.line_free)
        {
            self.queue_scan(now);
            let period = self.scan_period();
            let mut next = self.next_scan_due + period;
            if next <= now {
                // The line is slower than the mirror: the next B0 carries the newest scan.
                next = now + period;
            }
            self.next_scan_due = next;
            self.release(now);
        }
    }

    fn scan_period(&self) -> Duration {
        let revs = match self.variant.res_centideg() {
            25 => 4.0,
            50 => 2.0,
            _ => 1.0,
        };
        let hz = if self.cfg.mirror_hz.is_finite() && self.cfg.mirror_hz > 0.0 {
            self.cfg.mirror_hz
        } else {
            75.0
        };
        Duration::from_secs_f64(revs / hz)
    }

    fn release_at(&self, o: &Outgoing) -> Instant {
        o.not_before.max(self.line_free) + wire_time(o.bytes.len(), self.baud)
    }

    /// Move telegrams whose last byte has left the unit to the output.
    fn release(&mut self, now: Instant) {
        while let Some(front) = self.queue.front() {
            let done = self.release_at(front);
            if done > now {
                break;
            }
            let Some(o) = self.queue.pop_front() else {
                break;
            };
            self.line_free = done;
            if self.line_matches() {
                self.out.extend_from_slice(&o.bytes);
            } else {
                self.stats.garbled_tx = self.stats.garbled_tx.saturating_add(o.bytes.len() as u64);
                self.out.extend(o.bytes.iter().map(|b| 0xF0 | (b & 0x0F)));
            }
            if o.is_scan {
                self.stats.scans = self.stats.scans.saturating_add(1);
            }
            if let Some(b) = o.then_baud {
                self.baud = b;
                self.framer.clear();
            }
        }
    }

    fn send_raw(
        &mut self,
        mut bytes: Vec<u8>,
        not_before: Instant,
        then_baud: Option<BaudRate>,
        is_scan: bool,
    ) {
        if self.losing_reply && !is_scan && bytes != [ACK] && bytes != [NAK] {
            // Lost on the line; what the telegram does to the unit (a rate switch) still holds.
            self.losing_reply = false;
            self.stats.lost_replies = self.stats.lost_replies.saturating_add(1);
            bytes.clear();
        }
        self.queue.push_back(Outgoing {
            bytes,
            not_before,
            then_baud,
            is_scan,
        });
    }

    fn send_reply(&mut self, reply: &Reply<'_>, not_before: Instant, then_baud: Option<BaudRate>) {
        let mut buf = vec![0u8; MAX_TELEGRAM];
        match reply.emit_from(self.cfg.address, &mut buf) {
            Ok(n) => {
                buf.truncate(n);
                let is_scan = matches!(reply, Reply::Scan(_));
                self.send_raw(buf, not_before, then_baud, is_scan);
            }
            Err(e) => tracing::warn!(error = ?e, "sick_lms mock: could not emit a reply"),
        }
    }

    fn reject(&mut self, at: Instant) {
        self.stats.rejected = self.stats.rejected.saturating_add(1);
        self.send_reply(
            &Reply::Rejected {
                data: &[],
                status: self.cfg.status,
            },
            at,
            None,
        );
    }

    /// Count a good telegram and answer ACK, or NAK it when so scripted (then `false`: the
    /// telegram is not executed). Arms the scripted reply loss.
    fn acknowledge(&mut self, code: u8, now: Instant) -> bool {
        let at = now + self.cfg.ack_delay;
        if self.nak_next > 0 {
            self.nak_next -= 1;
            self.stats.scripted_naks = self.stats.scripted_naks.saturating_add(1);
            self.send_raw(vec![NAK], at, None, false);
            return false;
        }
        self.stats.telegrams = self.stats.telegrams.saturating_add(1);
        self.send_raw(vec![ACK], at, None, false);
        if let Some(i) = self.lose_reply_to.iter().position(|&c| c == code) {
            self.lose_reply_to.remove(i);
            self.losing_reply = true;
        }
        true
    }

    /// `77` with fewer than 32 config bytes: overwrite the first bytes, keep the rest.
    fn write_short_config(&mut self, data: &[u8], now: Instant) {
        use ima_sick_lms::wire::cmd;
        if !self.acknowledge(cmd::WRITE_CONFIG, now) {
            return;
        }
        let ack_at = now + self.cfg.ack_delay;
        if self.mode != OpMode::Installation || self.refuse.contains(&cmd::WRITE_CONFIG) {
            self.reject(ack_at + self.cfg.reply_delay);
            return;
        }
        let mut raw = self.config.as_bytes().to_vec();
        for (d, s) in raw.iter_mut().zip(data) {
            *d = *s;
        }
        if let Ok(new) = LmsConfig::from_bytes(&raw) {
            self.config = new;
        }
        self.stats.eeprom_writes = self.stats.eeprom_writes.saturating_add(1);
        self.stats.short_config_writes = self.stats.short_config_writes.saturating_add(1);
        let reply = Reply::ConfigWritten {
            result: self.cfg.config_write_result,
            config: self.config,
            status: self.cfg.status,
        };
        self.send_reply(&reply, ack_at + self.cfg.config_write_delay, None);
        self.losing_reply = false;
    }

    fn execute(&mut self, c: Command, now: Instant) {
        if let Some(log) = &mut self.log {
            log.push((now, c.clone()));
        }
        if !self.acknowledge(c.code(), now) {
            return;
        }
        let ack_at = now + self.cfg.ack_delay;
        let at = ack_at + self.cfg.reply_delay;
        if self.refuse.contains(&c.code()) {
            self.reject(at);
            self.losing_reply = false;
            return;
        }
        self.execute_accepted(c, now);
        self.losing_reply = false;
    }

    fn execute_accepted(&mut self, c: Command, now: Instant) {
        let ack_at = now + self.cfg.ack_delay;
        let at = ack_at + self.cfg.reply_delay;
        let status = self.cfg.status;
        let mode_at = ack_at + self.cfg.mode_delay;
        let ok = |result| Reply::ModeChanged { result, status };
        match c {
            Command::Reset => {
                self.send_reply(&Reply::ResetAck { status }, at, None);
                self.mode = OpMode::RequestOnly;
                // Reboot once the 91 has left: power-up rate, boot delay, 90.
                let after = self.queue.back().map_or(at, |o| self.release_at(o));
                self.queue.push_back(Outgoing {
                    bytes: Vec::new(),
                    not_before: after,
                    then_baud: Some(self.cfg.baud),
                    is_scan: false,
                });
                self.boot_until = Some(after + self.cfg.boot_delay);
                self.variant = self.cfg.variant;
                self.stats.boots = self.stats.boots.saturating_add(1);
            }
            Command::SetMode(m) => match m {
                ModeRequest::Installation { password } => {
                    if password == DEFAULT_PASSWORD {
                        self.mode = OpMode::Installation;
                        self.send_reply(&ok(0), mode_at, None);
                    } else {
                        self.send_reply(&ok(1), mode_at, None);
                    }
                }
                ModeRequest::Diagnostic => {
                    self.mode = OpMode::Diagnostic;
                    self.send_reply(&ok(0), mode_at, None);
                }
                ModeRequest::RequestOnly => {
                    self.mode = OpMode::RequestOnly;
                    self.send_reply(&ok(0), mode_at, None);
                }
                ModeRequest::StreamAll => {
                    self.send_reply(&ok(0), mode_at, None);
                    self.mode = OpMode::Streaming;
                    self.next_scan_due = mode_at;
                }
                ModeRequest::Baud(b) => {
                    if b == BaudRate::B500000 && !self.cfg.rs422 {
                        self.send_reply(&ok(1), mode_at, None);
                    } else {
                        self.stats.baud_changes = self.stats.baud_changes.saturating_add(1);
                        // A0 at the old rate, then the switch.
                        self.send_reply(&ok(0), mode_at, Some(b));
                    }
                }
                ModeRequest::StreamMean { .. }
                | ModeRequest::StreamSubrange { .. }
                | ModeRequest::MeanSubrange { .. }
                | ModeRequest::StreamPartial
                | ModeRequest::Other { .. } => self.reject(at),
            },
            Command::RequestValues { .. } => self.queue_scan(at),
            Command::Status => {
                let mut b = StatusBlockBuf::default();
                b.set_variant(self.variant.angle_deg(), self.variant.res_centideg());
                b.set_baud(self.baud);
                b.set_measuring_mode(self.config.measuring_mode());
                b.set_units(self.config.units());
                b.set_device_status(0);
                b.set_operating_mode(match self.mode {
                    OpMode::Installation => 0x00,
                    OpMode::Diagnostic => 0x10,
                    OpMode::RequestOnly => 0x25,
                    OpMode::Streaming => 0x24,
                });
                if let Some(fw) = b.0.get_mut(0..7) {
                    fw.copy_from_slice(b"V02.06 ");
                }
                self.send_reply(
                    &Reply::Status {
                        block: StatusBlock(&b.0),
                        status,
                    },
                    at,
                    None,
                );
            }
            Command::Errors => {
                if let Ok(pairs) = ErrorPairs::new(&[]) {
                    self.send_reply(&Reply::Errors { pairs, status }, at, None);
                }
            }
            Command::Type => {
                let text = self.cfg.type_string.clone();
                self.send_reply(
                    &Reply::Type {
                        text: text.as_bytes(),
                        status,
                    },
                    at,
                    None,
                );
            }
            Command::Variant {
                angle_deg,
                res_centideg,
            } => {
                let accepted = match Variant::new(angle_deg, res_centideg) {
                    Some(v) => {
                        if v != self.variant {
                            self.stats.variant_changes =
                                self.stats.variant_changes.saturating_add(1);
                        }
                        self.variant = v;
                        // The unit stops sending data when the variant changes midstream.
                        if self.mode == OpMode::Streaming {
                            self.mode = OpMode::RequestOnly;
                        }
                        1
                    }
                    None => 0,
                };
                self.send_reply(
                    &Reply::Variant {
                        accepted,
                        angle_deg: self.variant.angle_deg(),
                        res_centideg: self.variant.res_centideg(),
                        status,
                    },
                    at,
                    None,
                );
            }
            Command::ReadConfig => {
                let config = self.config;
                self.send_reply(&Reply::Config { config, status }, at, None);
            }
            Command::WriteConfig(new) => {
                if self.mode != OpMode::Installation {
                    self.reject(at);
                    return;
                }
                self.config = new;
                self.stats.eeprom_writes = self.stats.eeprom_writes.saturating_add(1);
                self.send_reply(
                    &Reply::ConfigWritten {
                        result: self.cfg.config_write_result,
                        config: new,
                        status,
                    },
                    ack_at + self.cfg.config_write_delay,
                    None,
                );
            }
        }
    }

    fn queue_scan(&mut self, at: Instant) {
        let v = self.variant;
        let mode = self.config.measuring_mode();
        let units = Units::from_code(u16::from(self.config.units()));
        let max = max_range_m(mode, units).unwrap_or(8.191);
        let start = lms_deg_to_sensor_rad(f64::from(v.start_deg()));
        let step = f64::from(v.res_centideg()).to_radians() / 100.0;
        let mut ranges = std::mem::take(&mut self.ranges);
        self.source
            .ranges(start, step, v.values(), max, &mut ranges);
        self.words.clear();
        self.words
            .extend(ranges.iter().map(|r| encode_range_m(*r, units, mode)));
        self.ranges = ranges;
        let indices = (self.config.availability() & 0x02 != 0).then(|| {
            let i = (self.scan_index, self.telegram_index);
            self.scan_index = self.scan_index.wrapping_add(1);
            i
        });
        self.telegram_index = self.telegram_index.wrapping_add(1);
        let mut scan = Scan::full(&self.words, units, self.cfg.status);
        scan.indices = indices;
        let reply = Reply::Scan(Scan {
            values: Values::Words(&self.words),
            ..scan
        });
        let mut buf = vec![0u8; MAX_TELEGRAM];
        match reply.emit_from(self.cfg.address, &mut buf) {
            Ok(n) => {
                buf.truncate(n);
                self.send_raw(buf, at, None, true);
            }
            Err(e) => tracing::warn!(error = ?e, "sick_lms mock: could not emit a scan"),
        }
    }
}

/// The mock LMS on a world robot, ready for a runner ([`crate::pty::PtyDevice`],
/// [`crate::duplex::DuplexDevice`]).
#[derive(Debug)]
pub struct SickLmsDevice {
    model: SickLmsModel,
    /// Power-cycle the unit when a hung-up link comes back (default: the cable was pulled
    /// and replugged; the unit kept running at its rate).
    pub reset_on_reconnect: bool,
}

impl SickLmsDevice {
    /// The unit `cfg` measuring with `source`, powering up at `now`.
    pub fn new(cfg: SickLmsModelConfig, source: Box<dyn RangeSource>, now: Instant) -> Self {
        Self {
            model: SickLmsModel::new(cfg, source, now),
            reset_on_reconnect: false,
        }
    }

    /// The firmware model (state, counters).
    #[must_use]
    pub fn model(&self) -> &SickLmsModel {
        &self.model
    }
}

impl crate::model::DeviceModel for SickLmsDevice {
    fn handle_rx(&mut self, bytes: &[u8], now: Instant) {
        self.model.handle_rx(bytes, now);
    }

    fn poll_tx(&mut self, out: &mut Vec<u8>) {
        out.append(&mut self.model.out);
    }

    fn poll_timeout(&self) -> Option<Instant> {
        self.model.poll_timeout()
    }

    fn handle_timeout(&mut self, now: Instant) {
        self.model.handle_timeout(now);
    }

    fn set_host_baud(&mut self, baud: Option<u32>) {
        self.model.set_host_baud(baud);
    }

    fn on_reconnect(&mut self, now: Instant) {
        if self.reset_on_reconnect {
            self.model.power_up(now);
        }
    }

    fn name(&self) -> &str {
        "sick_lms"
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ima_sick_lms::framer::Framer;

    struct Flat(f64);
    impl RangeSource for Flat {
        fn ranges(&mut self, _: f64, _: f64, count: u16, _: f64, out: &mut Vec<Option<f64>>) {
            out.clear();
            out.resize(usize::from(count), Some(self.0));
        }
    }

    fn cmd(c: &Command) -> Vec<u8> {
        let mut b = [0u8; 64];
        let n = c.emit(&mut b).unwrap();
        b[..n].to_vec()
    }

    /// Run the model until `until`, collecting (code or raw byte) of everything it sends.
    fn run(m: &mut SickLmsModel, until: Instant) -> Vec<Vec<u8>> {
        let mut bytes = Vec::new();
        while let Some(t) = m.poll_timeout() {
            if t > until {
                break;
            }
            m.handle_timeout(t);
            bytes.extend(m.take_output());
        }
        bytes.extend(m.take_output());
        let mut f = Framer::replies();
        let mut items = Vec::new();
        f.push_all(&bytes, until, |i| match i {
            Item::Ack => items.push(vec![ACK]),
            Item::Nak => items.push(vec![NAK]),
            Item::Frame(fr) => items.push(fr.as_bytes().to_vec()),
            Item::BadChecksum => items.push(vec![]),
        });
        items
    }

    fn model() -> SickLmsModel {
        SickLmsModel::new(
            SickLmsModelConfig::default(),
            Box::new(Flat(2.0)),
            Instant::ZERO,
        )
    }

    #[test]
    fn boots_then_sends_power_on_and_ignores_traffic_meanwhile() {
        let mut m = model();
        m.handle_rx(&cmd(&Command::Status), Instant::from_millis(10));
        let items = run(&mut m, Instant::from_millis(1000));
        assert_eq!(items.len(), 1);
        assert_eq!(items[0][4], 0x90);
        assert_eq!(items[0].len(), 6 + 23);
        assert!(m.stats().ignored_rx > 0);
    }

    #[test]
    fn acks_then_replies_and_naks_bad_crc() {
        let mut m = model();
        run(&mut m, Instant::from_millis(1000));
        let t = Instant::from_millis(1000);
        m.handle_rx(&cmd(&Command::Type), t);
        let mut bad = cmd(&Command::Status);
        let last = bad.len() - 1;
        bad[last] ^= 0x40;
        m.handle_rx(&bad, t);
        let items = run(&mut m, Instant::from_millis(2000));
        assert_eq!(items[0], vec![ACK]);
        assert_eq!(items[1][4], 0xBA);
        assert_eq!(items[2], vec![NAK]);
        assert_eq!(m.stats().naks, 1);
    }

    #[test]
    fn baud_change_answers_at_old_rate_then_mismatch_is_garbage() {
        let mut m = model();
        run(&mut m, Instant::from_millis(1000));
        m.set_host_baud(Some(9600));
        m.handle_rx(
            &cmd(&Command::SetMode(ModeRequest::Baud(BaudRate::B38400))),
            Instant::from_millis(1000),
        );
        let items = run(&mut m, Instant::from_millis(2000));
        assert_eq!(items[1][4], 0xA0);
        assert_eq!(m.baud(), BaudRate::B38400);
        // Host still at 9600: its telegram is noise, nothing answers.
        m.handle_rx(&cmd(&Command::Status), Instant::from_millis(2000));
        assert!(run(&mut m, Instant::from_millis(3000)).is_empty());
        assert!(m.stats().garbled_rx > 0);
        m.set_host_baud(Some(38400));
        m.handle_rx(&cmd(&Command::Status), Instant::from_millis(3000));
        let items = run(&mut m, Instant::from_millis(4000));
        assert_eq!(items[1][4], 0xB1);
    }

    #[test]
    fn stream_rate_is_limited_by_line_and_mirror() {
        for (baud, want) in [(BaudRate::B38400, 5.2), (BaudRate::B500000, 37.5)] {
            let cfg = SickLmsModelConfig {
                baud,
                ..SickLmsModelConfig::default()
            };
            let mut m = SickLmsModel::new(cfg, Box::new(Flat(2.0)), Instant::ZERO);
            run(&mut m, Instant::from_millis(1000));
            m.handle_rx(
                &cmd(&Command::SetMode(ModeRequest::StreamAll)),
                Instant::from_millis(1000),
            );
            run(&mut m, Instant::from_millis(2000));
            let before = m.stats().scans;
            let items = run(&mut m, Instant::from_millis(12_000));
            let rate = (m.stats().scans - before) as f64 / 10.0;
            assert!((rate - want).abs() < 0.3, "{baud:?}: {rate}");
            // Every B0 has 361 values of 2 m in mm.
            let b0 = items.iter().find(|i| i.get(4) == Some(&0xB0)).unwrap();
            assert_eq!(b0.len(), 732);
            assert_eq!(u16::from_le_bytes([b0[7], b0[8]]), 2000);
        }
    }

    #[test]
    fn config_write_needs_installation_mode_and_counts() {
        let mut m = model();
        run(&mut m, Instant::from_millis(1000));
        let mut c = m.config();
        c.set_units(0);
        m.handle_rx(&cmd(&Command::WriteConfig(c)), Instant::from_millis(1000));
        let items = run(&mut m, Instant::from_millis(2000));
        assert_eq!(items[1][4], 0x92);
        m.handle_rx(
            &cmd(&Command::SetMode(ModeRequest::Installation {
                password: DEFAULT_PASSWORD,
            })),
            Instant::from_millis(2000),
        );
        m.handle_rx(&cmd(&Command::WriteConfig(c)), Instant::from_millis(2100));
        let items = run(&mut m, Instant::from_millis(4000));
        assert!(items.iter().any(|i| i.get(4) == Some(&0xF7)));
        assert_eq!(m.stats().eeprom_writes, 1);
        assert_eq!(m.config().units(), 0);
    }

    /// The 7-byte short config write long-used clients send, verbatim (CRC `CD FA`).
    const SHORT_CONFIG: [u8; 14] = [
        0x02, 0x00, 0x08, 0x00, 0x77, 0x00, 0x00, 0x00, 0x00, 0x00, 0x01, 0x01, 0xCD, 0xFA,
    ];

    /// A telegram to the unit with `data` (code first) and a correct CRC.
    fn telegram(data: &[u8]) -> Vec<u8> {
        let mut t = vec![0x02, 0x00];
        t.extend_from_slice(&u16::try_from(data.len()).unwrap().to_le_bytes());
        t.extend_from_slice(data);
        let crc = ima_sick_lms::wire::crc16(&t);
        t.extend_from_slice(&crc.to_le_bytes());
        t
    }

    #[test]
    fn the_short_config_write_is_crc_valid_acked_and_applied() {
        assert_eq!(
            telegram(&SHORT_CONFIG[4..12]),
            SHORT_CONFIG,
            "CRC CD FA is right"
        );
        let mut m = model();
        run(&mut m, Instant::from_millis(1000));
        let mut before = m.config();
        before.set_units(0);
        before.set_measuring_mode(MeasuringMode(0));
        m.handle_rx(
            &cmd(&Command::WriteConfig(before)),
            Instant::from_millis(1000),
        );
        // Outside installation mode: ACK + 92, nothing written.
        m.handle_rx(&SHORT_CONFIG, Instant::from_millis(1001));
        let items = run(&mut m, Instant::from_millis(2000));
        assert_eq!(items[0], vec![ACK]);
        assert_eq!(items[1][4], 0x92);
        assert_eq!(items[2], vec![ACK]);
        assert_eq!(items[3][4], 0x92);
        m.handle_rx(
            &cmd(&Command::SetMode(ModeRequest::Installation {
                password: DEFAULT_PASSWORD,
            })),
            Instant::from_millis(2000),
        );
        run(&mut m, Instant::from_millis(2500));
        let untouched = m.config().as_bytes()[7..].to_vec();
        m.handle_rx(&SHORT_CONFIG, Instant::from_millis(2500));
        let items = run(&mut m, Instant::from_millis(4000));
        assert_eq!(items[0], vec![ACK]);
        let f7 = &items[1];
        assert_eq!(f7[4], 0xF7);
        assert_eq!(f7[5], 1, "accepted");
        // The seven bytes were applied, the rest kept; F7 echoes the whole configuration.
        assert_eq!(m.config().measuring_mode(), MeasuringMode(1));
        assert_eq!(m.config().units(), 1);
        assert_eq!(&m.config().as_bytes()[7..], &untouched[..]);
        assert_eq!(&f7[6..6 + LmsConfig::LONG], m.config().as_bytes());
        assert_eq!(m.stats().short_config_writes, 1);
        assert_eq!(m.stats().eeprom_writes, 1);
    }

    #[test]
    fn every_crc_valid_telegram_is_answered() {
        let mut m = model();
        run(&mut m, Instant::from_millis(1000));
        // An unknown command: ACK, then the 92 refusal.
        m.handle_rx(&telegram(&[0x45]), Instant::from_millis(1000));
        let items = run(&mut m, Instant::from_millis(1500));
        assert_eq!(items, vec![vec![ACK], items[1].clone()]);
        assert_eq!(items[1][4], 0x92);
        // A status request with a stray byte: answered as the status request.
        m.handle_rx(&telegram(&[0x31, 0x07]), Instant::from_millis(1500));
        let items = run(&mut m, Instant::from_millis(2000));
        assert_eq!(items[0], vec![ACK]);
        assert_eq!(items[1][4], 0xB1);
        assert_eq!(m.stats().tolerated, 1);
        // A known command with a malformed payload (a variant of 3 bytes): refused.
        m.handle_rx(
            &telegram(&[0x3B, 0xB4, 0x00, 0x32]),
            Instant::from_millis(2000),
        );
        let items = run(&mut m, Instant::from_millis(2500));
        assert_eq!(items[0], vec![ACK]);
        assert_eq!(items[1][4], 0x92);
        assert_eq!(m.stats().rejected, 2);
        // Every code, with and without a stray byte, gets an ACK and exactly one telegram.
        for code in 0u8..=0x7F {
            for data in [vec![code], vec![code, 0x5A]] {
                let mut m = SickLmsModel::running(
                    SickLmsModelConfig::default(),
                    Box::new(Flat(2.0)),
                    Instant::ZERO,
                    BaudRate::B9600,
                );
                m.handle_rx(&telegram(&data), Instant::ZERO);
                let items = run(&mut m, Instant::from_millis(5000));
                assert_eq!(items.first(), Some(&vec![ACK]), "{data:02X?}");
                assert!(
                    items.get(1).is_some_and(|t| t.len() > 1),
                    "{data:02X?}: {items:02X?}"
                );
            }
        }
    }

    #[test]
    fn scripted_naks_lost_replies_and_refusals() {
        let mut m = SickLmsModel::running(
            SickLmsModelConfig::default(),
            Box::new(Flat(2.0)),
            Instant::ZERO,
            BaudRate::B9600,
        );
        m.record_commands();
        m.nak_next(1);
        m.lose_reply_to(0x3A);
        m.refuse(0x3B);
        let t = Instant::ZERO;
        m.handle_rx(&cmd(&Command::Type), t);
        let items = run(&mut m, Instant::from_millis(100));
        assert_eq!(items, vec![vec![NAK]]);
        m.handle_rx(&cmd(&Command::Type), Instant::from_millis(100));
        let items = run(&mut m, Instant::from_millis(200));
        assert_eq!(items, vec![vec![ACK]], "reply lost after the ACK");
        m.handle_rx(&cmd(&Command::Type), Instant::from_millis(200));
        let items = run(&mut m, Instant::from_millis(300));
        assert_eq!(items[1][4], 0xBA);
        m.handle_rx(
            &cmd(&Command::Variant {
                angle_deg: 100,
                res_centideg: 25,
            }),
            Instant::from_millis(300),
        );
        let items = run(&mut m, Instant::from_millis(400));
        assert_eq!(items[1][4], 0x92);
        assert_eq!(m.variant(), Variant::W180_R50);
        assert_eq!(m.commands().len(), 4);
        assert_eq!(m.stats().scripted_naks, 1);
        assert_eq!(m.stats().lost_replies, 1);
    }

    #[test]
    fn variant_change_and_reset() {
        let mut m = model();
        run(&mut m, Instant::from_millis(1000));
        m.handle_rx(
            &cmd(&Command::Variant {
                angle_deg: 100,
                res_centideg: 25,
            }),
            Instant::from_millis(1000),
        );
        m.handle_rx(
            &cmd(&Command::Variant {
                angle_deg: 180,
                res_centideg: 25,
            }),
            Instant::from_millis(1010),
        );
        let items = run(&mut m, Instant::from_millis(2000));
        let bb: Vec<_> = items.iter().filter(|i| i.get(4) == Some(&0xBB)).collect();
        assert_eq!(bb[0][5], 1);
        assert_eq!(bb[1][5], 0);
        assert_eq!(m.variant(), Variant::W100_R25);
        m.handle_rx(&cmd(&Command::Reset), Instant::from_millis(2000));
        let items = run(&mut m, Instant::from_millis(4000));
        assert_eq!(items[1][4], 0x91);
        assert_eq!(items[2][4], 0x90);
        assert_eq!(m.variant(), Variant::W180_R50);
    }
}

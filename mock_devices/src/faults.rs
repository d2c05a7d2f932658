//! A seeded fault injector for byte streams, in the manner of smoltcp's `FaultInjector`.
//!
//! It sits between a device model and its port, separately in each direction
//! (robot → host and host → robot). It is **pure**: [`FaultInjector::process`] turns a buffer
//! into a list of [`FaultAction`]s (data chunks, stalls, a hang-up) and a [`DelayLine`] turns
//! those into chunks that are due at a given instant; the runners
//! ([`crate::pty`], [`crate::duplex`], via [`crate::link::DeviceLink`]) apply them with real
//! timing. The same seed and the same input give the same faults.
//!
//! # Spec-string grammar
//!
//! ([`GRAMMAR`], which `ima mock --help` prints too.)
//!
#![doc = concat!("```text\n", include_str!("faults_grammar.txt"), "```")]
//!
//! Example: `corrupt=0.01,drop=0.001,garbage=0.001,split=1,stall=0.0005:300ms,hangup=5s,seed=42`.
//! [`FaultPlan`]'s `Display` prints a spec string that parses back to the same plan (log it to
//! reproduce a run). Each direction draws from its own generator, seeded from `seed` and the
//! direction, so the faults in one direction do not depend on the traffic in the other.
//!
//! # What a hang-up means
//!
//! The injector only reports [`FaultAction::HangUp`]; the runner takes the link down: bytes in
//! both directions are discarded until the outage ends (or forever). See
//! [`crate::link::DeviceLink`] for why the pty keeps its path during an outage.

use std::collections::VecDeque;
use std::fmt;
use std::str::FromStr;
use std::time::Duration;

use ima_hal::Instant;
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};

/// The spec-string grammar, as plain text (the module's documentation and `ima mock --help`
/// show it).
pub const GRAMMAR: &str = include_str!("faults_grammar.txt");

/// When a direction hangs up the link.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum HangupTrigger {
    /// Once, this long after the injector's start.
    At(Duration),
    /// Before each byte, with this probability.
    Probability(f64),
}

/// Faults of one direction. Probabilities outside [0, 1] or non-finite are treated as 0 by the
/// injector (the spec parser rejects them).
#[derive(Debug, Clone, PartialEq)]
pub struct FaultConfig {
    /// Per-byte probability of corrupting it.
    pub corrupt: f64,
    /// Per-byte probability of dropping it.
    pub drop: f64,
    /// Per-byte probability of inserting a garbage burst before it.
    pub garbage: f64,
    /// Shortest garbage burst, bytes (at least 1).
    pub garbage_min: u16,
    /// Longest garbage burst, bytes.
    pub garbage_max: u16,
    /// Per-write probability of cutting the write into random chunks.
    pub split: f64,
    /// Per-byte probability of a stall before it.
    pub stall: f64,
    /// Length of a stall.
    pub stall_for: Duration,
    /// Fixed latency of every chunk.
    pub delay: Duration,
    /// When to hang up, if ever.
    pub hangup: Option<HangupTrigger>,
    /// How long a hang-up lasts; `None` = for good.
    pub hangup_for: Option<Duration>,
}

impl Default for FaultConfig {
    fn default() -> Self {
        Self {
            corrupt: 0.0,
            drop: 0.0,
            garbage: 0.0,
            garbage_min: 1,
            garbage_max: 16,
            split: 0.0,
            stall: 0.0,
            stall_for: Duration::ZERO,
            delay: Duration::ZERO,
            hangup: None,
            hangup_for: None,
        }
    }
}

impl FaultConfig {
    /// No faults at all.
    #[must_use]
    pub fn none() -> Self {
        Self::default()
    }

    /// `true` if this config never changes the stream.
    #[must_use]
    pub fn is_clean(&self) -> bool {
        *self == Self::default()
    }
}

/// Faults of both directions plus the seed: what a spec string describes.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct FaultPlan {
    /// Seed of both directions' generators.
    pub seed: u64,
    /// Faults on bytes the robot sends to the host.
    pub robot_to_host: FaultConfig,
    /// Faults on bytes the host sends to the robot.
    pub host_to_robot: FaultConfig,
}

/// Which direction of the link.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Direction {
    /// Robot (device model) → host (driver).
    RobotToHost,
    /// Host (driver) → robot (device model).
    HostToRobot,
}

impl FaultPlan {
    /// No faults, seed 0.
    #[must_use]
    pub fn none() -> Self {
        Self::default()
    }

    /// Parse a spec string (grammar in the [module docs](self)).
    pub fn parse(spec: &str) -> Result<Self, FaultSpecError> {
        spec.parse()
    }

    /// The injector of one direction, whose clock starts at `start`.
    #[must_use]
    pub fn injector(&self, dir: Direction, start: Instant) -> FaultInjector {
        let (cfg, salt) = match dir {
            Direction::RobotToHost => (&self.robot_to_host, 0x5232_4800_0000_0001_u64),
            Direction::HostToRobot => (&self.host_to_robot, 0x4832_5200_0000_0002_u64),
        };
        FaultInjector::new(cfg.clone(), self.seed ^ salt, start)
    }
}

/// Why a fault spec string was rejected. `item` is the offending `key=value` text.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum FaultSpecError {
    /// An item without `=`.
    #[error("fault spec item {item:?}: expected key=value")]
    MissingValue {
        /// The item.
        item: String,
    },
    /// A key this grammar does not have.
    #[error(
        "fault spec item {item:?}: unknown key (the keys: corrupt, drop, split, garbage, \
         stall, delay, hangup, seed; r2h. or h2r. before a key for one direction)"
    )]
    UnknownKey {
        /// The item.
        item: String,
    },
    /// A direction prefix other than `r2h`/`h2r`, or one on `seed`.
    #[error("fault spec item {item:?}: bad direction (use r2h. or h2r.)")]
    BadDirection {
        /// The item.
        item: String,
    },
    /// Not a probability in [0, 1].
    #[error("fault spec item {item:?}: expected a probability in [0, 1]")]
    BadProbability {
        /// The item.
        item: String,
    },
    /// Not a duration such as `300ms`, or one over a day.
    #[error(
        "fault spec item {item:?}: expected a duration like 300ms, 5s, 250us, 1min, at most one \
         day (1440min)"
    )]
    BadDuration {
        /// The item.
        item: String,
    },
    /// Not an integer (seed, garbage lengths) or a malformed `MIN-MAX`.
    #[error("fault spec item {item:?}: expected {expected}")]
    BadNumber {
        /// The item.
        item: String,
        /// What the value must be.
        expected: &'static str,
    },
    /// A value has the wrong number of `:`-separated parts (e.g. `stall=0.1` without a duration).
    #[error("fault spec item {item:?}: wrong number of ':' parts: {key} takes {form}")]
    BadShape {
        /// The item.
        item: String,
        /// Its key.
        key: String,
        /// The values the key takes, e.g. `P:DUR (stall=0.01:300ms)`.
        form: &'static str,
    },
}

/// The longest duration a fault takes: one day, as the command line's flags.
const MAX_DURATION: Duration = Duration::from_secs(86_400);

/// A fault's duration: [`parse_duration`], at most [`MAX_DURATION`].
fn fault_duration(s: &str) -> Option<Duration> {
    parse_duration(s).filter(|d| *d <= MAX_DURATION)
}

fn parse_prob(s: &str) -> Option<f64> {
    let p: f64 = s.trim().parse().ok()?;
    (p.is_finite() && (0.0..=1.0).contains(&p)).then_some(p)
}

/// Parse a duration with a unit: `ns`, `us`, `ms`, `s` or `min` (decimal allowed, e.g. `1.5s`).
pub fn parse_duration(s: &str) -> Option<Duration> {
    let s = s.trim();
    let (num, scale) = if let Some(n) = s.strip_suffix("ns") {
        (n, 1e-9)
    } else if let Some(n) = s.strip_suffix("us") {
        (n, 1e-6)
    } else if let Some(n) = s.strip_suffix("ms") {
        (n, 1e-3)
    } else if let Some(n) = s.strip_suffix("min") {
        (n, 60.0)
    } else if let Some(n) = s.strip_suffix('s') {
        (n, 1.0)
    } else {
        return None;
    };
    let v: f64 = num.trim().parse().ok()?;
    if !(v.is_finite() && v >= 0.0) {
        return None;
    }
    Duration::try_from_secs_f64(v * scale).ok()
}

impl FromStr for FaultPlan {
    type Err = FaultSpecError;

    fn from_str(spec: &str) -> Result<Self, Self::Err> {
        let mut plan = FaultPlan::default();
        for raw in spec.split(',') {
            let item = raw.trim();
            if item.is_empty() {
                continue;
            }
            let e_item = || item.to_owned();
            let (lhs, value) = item
                .split_once('=')
                .ok_or_else(|| FaultSpecError::MissingValue { item: e_item() })?;
            let (lhs, value) = (lhs.trim(), value.trim());
            let (dirs, key): (&[Direction], &str) = match lhs.split_once('.') {
                None => (&[Direction::RobotToHost, Direction::HostToRobot], lhs),
                Some(("r2h", k)) => (&[Direction::RobotToHost], k),
                Some(("h2r", k)) => (&[Direction::HostToRobot], k),
                Some(_) => return Err(FaultSpecError::BadDirection { item: e_item() }),
            };
            if key == "seed" {
                if dirs.len() != 2 {
                    return Err(FaultSpecError::BadDirection { item: e_item() });
                }
                plan.seed = value.parse().map_err(|_| FaultSpecError::BadNumber {
                    item: e_item(),
                    expected: "a whole number 0–18446744073709551615",
                })?;
                continue;
            }
            let prob =
                |s: &str| parse_prob(s).ok_or(FaultSpecError::BadProbability { item: e_item() });
            let dur =
                |s: &str| fault_duration(s).ok_or(FaultSpecError::BadDuration { item: e_item() });
            let shape = |form| FaultSpecError::BadShape {
                item: e_item(),
                key: key.to_owned(),
                form,
            };
            let parts: Vec<&str> = value.split(':').collect();
            // Build the change once, then apply it to each selected direction.
            let apply: Box<dyn Fn(&mut FaultConfig)> = match (key, parts.as_slice()) {
                ("corrupt", [p]) => {
                    let p = prob(p)?;
                    Box::new(move |c| c.corrupt = p)
                }
                ("drop", [p]) => {
                    let p = prob(p)?;
                    Box::new(move |c| c.drop = p)
                }
                ("split", [p]) => {
                    let p = prob(p)?;
                    Box::new(move |c| c.split = p)
                }
                ("garbage", [p]) => {
                    let p = prob(p)?;
                    Box::new(move |c| c.garbage = p)
                }
                ("garbage", [p, range]) => {
                    let p = prob(p)?;
                    let bad = || FaultSpecError::BadNumber {
                        item: e_item(),
                        expected: "lengths MIN-MAX with 1 ≤ MIN ≤ MAX ≤ 65535 (garbage=0.01:1-8)",
                    };
                    let (lo, hi) = range.split_once('-').ok_or_else(bad)?;
                    let lo: u16 = lo.trim().parse().map_err(|_| bad())?;
                    let hi: u16 = hi.trim().parse().map_err(|_| bad())?;
                    if lo == 0 || hi < lo {
                        return Err(bad());
                    }
                    Box::new(move |c| {
                        c.garbage = p;
                        c.garbage_min = lo;
                        c.garbage_max = hi;
                    })
                }
                ("stall", [p, d]) => {
                    let p = prob(p)?;
                    let d = dur(d)?;
                    Box::new(move |c| {
                        c.stall = p;
                        c.stall_for = d;
                    })
                }
                ("delay", [d]) => {
                    let d = dur(d)?;
                    Box::new(move |c| c.delay = d)
                }
                ("hangup", [when, rest @ ..]) if rest.len() <= 1 => {
                    let trigger = if let Some(d) = fault_duration(when) {
                        HangupTrigger::At(d)
                    } else if let Some(p) = parse_prob(when) {
                        HangupTrigger::Probability(p)
                    } else {
                        return Err(FaultSpecError::BadDuration { item: e_item() });
                    };
                    let outage = match rest.first() {
                        Some(o) => Some(dur(o)?),
                        None => None,
                    };
                    Box::new(move |c| {
                        c.hangup = Some(trigger);
                        c.hangup_for = outage;
                    })
                }
                ("corrupt" | "drop" | "split", _) => return Err(shape("P (corrupt=0.01)")),
                ("garbage", _) => return Err(shape("P or P:MIN-MAX (garbage=0.01:1-8)")),
                ("stall", _) => return Err(shape("P:DUR (stall=0.01:300ms)")),
                ("delay", _) => return Err(shape("DUR (delay=20ms)")),
                ("hangup", _) => {
                    return Err(shape("AT or P, then :DUR if it ends (hangup=5s:2s)"));
                }
                _ => return Err(FaultSpecError::UnknownKey { item: e_item() }),
            };
            for d in dirs {
                match d {
                    Direction::RobotToHost => apply(&mut plan.robot_to_host),
                    Direction::HostToRobot => apply(&mut plan.host_to_robot),
                }
            }
        }
        Ok(plan)
    }
}

impl fmt::Display for FaultPlan {
    /// The canonical spec string: `seed=N`, then every non-default field of each direction
    /// with its `r2h.`/`h2r.` prefix, durations in `ns`. Parses back to an equal plan when the
    /// probabilities are in [0, 1].
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "seed={}", self.seed)?;
        let d = FaultConfig::default();
        let ns = |x: Duration| format!("{}ns", x.as_nanos());
        for (pre, c) in [("r2h.", &self.robot_to_host), ("h2r.", &self.host_to_robot)] {
            if c.corrupt != d.corrupt {
                write!(f, ",{pre}corrupt={}", c.corrupt)?;
            }
            if c.drop != d.drop {
                write!(f, ",{pre}drop={}", c.drop)?;
            }
            if (c.garbage, c.garbage_min, c.garbage_max)
                != (d.garbage, d.garbage_min, d.garbage_max)
            {
                write!(
                    f,
                    ",{pre}garbage={}:{}-{}",
                    c.garbage, c.garbage_min, c.garbage_max
                )?;
            }
            if c.split != d.split {
                write!(f, ",{pre}split={}", c.split)?;
            }
            if (c.stall, c.stall_for) != (d.stall, d.stall_for) {
                write!(f, ",{pre}stall={}:{}", c.stall, ns(c.stall_for))?;
            }
            if c.delay != d.delay {
                write!(f, ",{pre}delay={}", ns(c.delay))?;
            }
            if let Some(h) = c.hangup {
                match h {
                    HangupTrigger::At(t) => write!(f, ",{pre}hangup={}", ns(t))?,
                    HangupTrigger::Probability(p) => write!(f, ",{pre}hangup={p}")?,
                }
                if let Some(o) = c.hangup_for {
                    write!(f, ":{}", ns(o))?;
                }
            }
        }
        Ok(())
    }
}

/// What the injector tells the runner to do, in order.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum FaultAction {
    /// Send these bytes as one write.
    Data(Vec<u8>),
    /// Hold the stream for this long before what follows.
    Stall(Duration),
    /// Take the link down for this long (`None` = for good). Nothing follows.
    HangUp(Option<Duration>),
}

/// What an injector did, for tests and logs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
pub struct FaultCounters {
    /// Bytes given to the injector.
    pub bytes_in: u64,
    /// Bytes it passed on (including garbage, after corruption).
    pub bytes_out: u64,
    /// Bytes corrupted.
    pub corrupted: u64,
    /// Bytes dropped.
    pub dropped: u64,
    /// Garbage bursts inserted.
    pub garbage_bursts: u64,
    /// Garbage bytes inserted.
    pub garbage_bytes: u64,
    /// Writes that were split.
    pub splits: u64,
    /// Chunks emitted (a write that is not split is one chunk).
    pub chunks: u64,
    /// Stalls inserted.
    pub stalls: u64,
    /// Hang-ups triggered.
    pub hangups: u64,
    /// Input bytes lost because they followed a hang-up in the same buffer.
    pub lost_to_hangup: u64,
}

/// The fault injector of one direction. Deterministic for a given seed and input sequence.
#[derive(Debug, Clone)]
pub struct FaultInjector {
    cfg: FaultConfig,
    rng: SmallRng,
    start: Instant,
    timed_hangup_done: bool,
    counters: FaultCounters,
}

fn p_ok(p: f64) -> f64 {
    if p.is_finite() {
        p.clamp(0.0, 1.0)
    } else {
        0.0
    }
}

impl FaultInjector {
    /// An injector with its own generator seeded by `seed`; timed hang-ups count from `start`.
    #[must_use]
    pub fn new(cfg: FaultConfig, seed: u64, start: Instant) -> Self {
        Self {
            cfg,
            rng: SmallRng::seed_from_u64(seed),
            start,
            timed_hangup_done: false,
            counters: FaultCounters::default(),
        }
    }

    /// An injector that passes everything through untouched.
    #[must_use]
    pub fn clean() -> Self {
        Self::new(FaultConfig::none(), 0, Instant::ZERO)
    }

    /// Its configuration.
    #[must_use]
    pub fn config(&self) -> &FaultConfig {
        &self.cfg
    }

    /// What it has done so far.
    #[must_use]
    pub fn counters(&self) -> FaultCounters {
        self.counters
    }

    /// When a timed hang-up is due, if one is still pending.
    #[must_use]
    pub fn hangup_deadline(&self) -> Option<Instant> {
        match self.cfg.hangup {
            Some(HangupTrigger::At(d)) if !self.timed_hangup_done => Some(self.start + d),
            _ => None,
        }
    }

    /// A timed hang-up, if it is due at `now` (fires once). Call it even when no bytes flow.
    pub fn poll_hangup(&mut self, now: Instant) -> Option<FaultAction> {
        if self.hangup_deadline().is_some_and(|t| now >= t) {
            self.timed_hangup_done = true;
            self.counters.hangups += 1;
            return Some(FaultAction::HangUp(self.cfg.hangup_for));
        }
        None
    }

    fn chance(&mut self, p: f64) -> bool {
        let p = p_ok(p);
        // Draw only when the fault is enabled, so that enabling one fault does not change the
        // pattern of the others' absence, and clean configs consume no randomness.
        p > 0.0 && self.rng.random::<f64>() < p
    }

    /// Transform one write of `input` at `now` into actions appended to `out`.
    pub fn process(&mut self, input: &[u8], now: Instant, out: &mut Vec<FaultAction>) {
        self.counters.bytes_in = self.counters.bytes_in.saturating_add(input.len() as u64);
        if let Some(h) = self.poll_hangup(now) {
            self.counters.lost_to_hangup += input.len() as u64;
            out.push(h);
            return;
        }
        let mut chunk: Vec<u8> = Vec::with_capacity(input.len());
        for (i, &b) in input.iter().enumerate() {
            if let Some(HangupTrigger::Probability(p)) = self.cfg.hangup
                && self.chance(p)
            {
                self.flush_chunk(&mut chunk, out);
                self.counters.hangups += 1;
                self.counters.lost_to_hangup += (input.len() - i) as u64;
                out.push(FaultAction::HangUp(self.cfg.hangup_for));
                return;
            }
            if self.chance(self.cfg.stall) {
                self.flush_chunk(&mut chunk, out);
                self.counters.stalls += 1;
                out.push(FaultAction::Stall(self.cfg.stall_for));
            }
            if self.chance(self.cfg.garbage) {
                let lo = self.cfg.garbage_min.max(1);
                let hi = self.cfg.garbage_max.max(lo);
                let n = self.rng.random_range(lo..=hi);
                for _ in 0..n {
                    chunk.push(self.rng.random());
                }
                self.counters.garbage_bursts += 1;
                self.counters.garbage_bytes += u64::from(n);
            }
            if self.chance(self.cfg.drop) {
                self.counters.dropped += 1;
                continue;
            }
            if self.chance(self.cfg.corrupt) {
                let mask: u8 = self.rng.random_range(1..=255);
                chunk.push(b ^ mask);
                self.counters.corrupted += 1;
            } else {
                chunk.push(b);
            }
        }
        self.flush_chunk(&mut chunk, out);
    }

    fn flush_chunk(&mut self, chunk: &mut Vec<u8>, out: &mut Vec<FaultAction>) {
        if chunk.is_empty() {
            return;
        }
        let data = std::mem::take(chunk);
        self.counters.bytes_out += data.len() as u64;
        if data.len() > 1 && self.chance(self.cfg.split) {
            self.counters.splits += 1;
            let mut rest = data.as_slice();
            while !rest.is_empty() {
                let n = self.rng.random_range(1..=rest.len());
                let (head, tail) = rest.split_at(n);
                out.push(FaultAction::Data(head.to_vec()));
                self.counters.chunks += 1;
                rest = tail;
            }
        } else {
            out.push(FaultAction::Data(data));
            self.counters.chunks += 1;
        }
    }
}

/// Turns data and stall actions into chunks that are due at given instants: every chunk is
/// delayed by the fixed latency, and a stall holds back everything after it.
#[derive(Debug, Clone, Default)]
pub struct DelayLine {
    delay: Duration,
    queue: VecDeque<(Instant, Vec<u8>)>,
    busy_until: Instant,
}

impl DelayLine {
    /// A line with a fixed latency.
    #[must_use]
    pub fn new(delay: Duration) -> Self {
        Self {
            delay,
            ..Self::default()
        }
    }

    /// Queue data and stalls (hang-ups are the caller's business and are ignored here).
    pub fn push(&mut self, actions: impl IntoIterator<Item = FaultAction>, now: Instant) {
        for a in actions {
            let earliest = (now + self.delay).max(self.busy_until);
            match a {
                FaultAction::Data(d) => {
                    self.queue.push_back((earliest, d));
                    self.busy_until = earliest;
                }
                FaultAction::Stall(s) => self.busy_until = earliest + s,
                FaultAction::HangUp(_) => {}
            }
        }
    }

    /// The next chunk if it is due at `now`.
    pub fn pop_due(&mut self, now: Instant) -> Option<Vec<u8>> {
        if self.queue.front().is_some_and(|(t, _)| *t <= now) {
            self.queue.pop_front().map(|(_, d)| d)
        } else {
            None
        }
    }

    /// When the next chunk is due.
    #[must_use]
    pub fn next_due(&self) -> Option<Instant> {
        self.queue.front().map(|(t, _)| *t)
    }

    /// Number of queued bytes.
    #[must_use]
    pub fn queued_bytes(&self) -> usize {
        self.queue.iter().map(|(_, d)| d.len()).sum()
    }

    /// Drop everything queued and forget stalls; returns the bytes dropped.
    pub fn clear(&mut self) -> usize {
        let n = self.queued_bytes();
        self.queue.clear();
        self.busy_until = Instant::ZERO;
        n
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn data_of(actions: &[FaultAction]) -> Vec<u8> {
        actions
            .iter()
            .filter_map(|a| match a {
                FaultAction::Data(d) => Some(d.clone()),
                _ => None,
            })
            .flatten()
            .collect()
    }

    #[test]
    fn parses_the_example_spec() {
        let p: FaultPlan =
            "corrupt=0.01,drop=0.001,garbage=0.001,split=1,stall=0.0005:300ms,hangup=5s,seed=42"
                .parse()
                .unwrap();
        assert_eq!(p.seed, 42);
        for c in [&p.robot_to_host, &p.host_to_robot] {
            assert_eq!(c.corrupt, 0.01);
            assert_eq!(c.drop, 0.001);
            assert_eq!(c.garbage, 0.001);
            assert_eq!(c.split, 1.0);
            assert_eq!(c.stall, 0.0005);
            assert_eq!(c.stall_for, Duration::from_millis(300));
            assert_eq!(c.hangup, Some(HangupTrigger::At(Duration::from_secs(5))));
            assert_eq!(c.hangup_for, None);
        }
    }

    #[test]
    fn parses_directions_and_variants() {
        let p = FaultPlan::parse(
            " r2h.corrupt=0.5 , h2r.drop=1, garbage=0.1:2-4, delay=1.5ms, hangup=0.01:2s, r2h.hangup=10s:500ms ",
        )
        .unwrap();
        assert_eq!(p.robot_to_host.corrupt, 0.5);
        assert_eq!(p.host_to_robot.corrupt, 0.0);
        assert_eq!(p.host_to_robot.drop, 1.0);
        assert_eq!(p.robot_to_host.drop, 0.0);
        assert_eq!(
            (p.robot_to_host.garbage_min, p.robot_to_host.garbage_max),
            (2, 4)
        );
        assert_eq!(p.host_to_robot.delay, Duration::from_micros(1500));
        assert_eq!(
            p.host_to_robot.hangup,
            Some(HangupTrigger::Probability(0.01))
        );
        assert_eq!(p.host_to_robot.hangup_for, Some(Duration::from_secs(2)));
        assert_eq!(
            p.robot_to_host.hangup,
            Some(HangupTrigger::At(Duration::from_secs(10)))
        );
        assert_eq!(p.robot_to_host.hangup_for, Some(Duration::from_millis(500)));
        assert_eq!(FaultPlan::parse("").unwrap(), FaultPlan::none());
        assert!(FaultPlan::parse(",,").unwrap().robot_to_host.is_clean());
        assert_eq!(parse_duration("1min"), Some(Duration::from_secs(60)));
        assert_eq!(parse_duration("250us"), Some(Duration::from_micros(250)));
        assert_eq!(parse_duration("5"), None);
        assert_eq!(parse_duration("-1s"), None);
    }

    #[test]
    fn spec_errors_are_typed() {
        use FaultSpecError as E;
        let item = |s: &str| s.to_owned();
        assert_eq!(
            FaultPlan::parse("corrupt"),
            Err(E::MissingValue {
                item: item("corrupt")
            })
        );
        assert_eq!(
            FaultPlan::parse("bogus=1"),
            Err(E::UnknownKey {
                item: item("bogus=1")
            })
        );
        // The message lists the keys there are.
        let e = FaultPlan::parse("curropt=0.1").unwrap_err().to_string();
        assert!(e.contains("corrupt, drop") && e.contains("r2h."), "{e}");
        assert_eq!(
            FaultPlan::parse("x2y.drop=0.1"),
            Err(E::BadDirection {
                item: item("x2y.drop=0.1")
            })
        );
        assert_eq!(
            FaultPlan::parse("r2h.seed=1"),
            Err(E::BadDirection {
                item: item("r2h.seed=1")
            })
        );
        assert_eq!(
            FaultPlan::parse("drop=1.5"),
            Err(E::BadProbability {
                item: item("drop=1.5")
            })
        );
        assert_eq!(
            FaultPlan::parse("drop=nan"),
            Err(E::BadProbability {
                item: item("drop=nan")
            })
        );
        assert_eq!(
            FaultPlan::parse("stall=0.1:300"),
            Err(E::BadDuration {
                item: item("stall=0.1:300")
            })
        );
        assert_eq!(
            FaultPlan::parse("stall=0.1"),
            Err(E::BadShape {
                item: item("stall=0.1"),
                key: "stall".into(),
                form: "P:DUR (stall=0.01:300ms)",
            })
        );
        assert_eq!(
            FaultPlan::parse("corrupt=0.1:2"),
            Err(E::BadShape {
                item: item("corrupt=0.1:2"),
                key: "corrupt".into(),
                form: "P (corrupt=0.01)",
            })
        );
        assert_eq!(
            FaultPlan::parse("seed=-3"),
            Err(E::BadNumber {
                item: item("seed=-3"),
                expected: "a whole number 0–18446744073709551615",
            })
        );
        assert_eq!(
            FaultPlan::parse("garbage=0.1:5-2"),
            Err(E::BadNumber {
                item: item("garbage=0.1:5-2"),
                expected: "lengths MIN-MAX with 1 ≤ MIN ≤ MAX ≤ 65535 (garbage=0.01:1-8)",
            })
        );
        assert_eq!(
            FaultPlan::parse("garbage=0.1:0-2"),
            Err(E::BadNumber {
                item: item("garbage=0.1:0-2"),
                expected: "lengths MIN-MAX with 1 ≤ MIN ≤ MAX ≤ 65535 (garbage=0.01:1-8)",
            })
        );
        assert_eq!(
            FaultPlan::parse("hangup=soon"),
            Err(E::BadDuration {
                item: item("hangup=soon")
            })
        );
        assert_eq!(
            FaultPlan::parse("hangup=1s:2s:3s"),
            Err(E::BadShape {
                item: item("hangup=1s:2s:3s"),
                key: "hangup".into(),
                form: "AT or P, then :DUR if it ends (hangup=5s:2s)",
            })
        );
        // A duration over a day is refused, as the command line's are.
        assert_eq!(
            FaultPlan::parse("delay=1e10ms"),
            Err(E::BadDuration {
                item: item("delay=1e10ms")
            })
        );
        assert!(FaultPlan::parse("stall=1:1440min").is_ok());
        assert!(FaultPlan::parse("hangup=1441min").is_err());
        // Errors print the item.
        assert!(
            E::UnknownKey { item: item("q=1") }
                .to_string()
                .contains("q=1")
        );
    }

    fn run(plan: &FaultPlan, input: &[u8]) -> (Vec<FaultAction>, FaultCounters) {
        let mut inj = plan.injector(Direction::RobotToHost, Instant::ZERO);
        let mut out = Vec::new();
        for chunk in input.chunks(100) {
            inj.process(chunk, Instant::ZERO, &mut out);
        }
        (out, inj.counters())
    }

    #[test]
    fn clean_config_passes_through() {
        let input: Vec<u8> = (0..=255).collect();
        let (out, c) = run(&FaultPlan::none(), &input);
        assert_eq!(data_of(&out), input);
        assert_eq!(c.bytes_in, 256);
        assert_eq!(c.bytes_out, 256);
        assert_eq!(c.chunks, 3);
    }

    #[test]
    fn same_seed_same_faults_other_seed_other_faults() {
        let input: Vec<u8> = (0..10_000u32).map(|i| i as u8).collect();
        let spec = "corrupt=0.01,drop=0.01,garbage=0.01,split=0.5,stall=0.01:1ms";
        let a = run(
            &FaultPlan::parse(&format!("{spec},seed=42")).unwrap(),
            &input,
        );
        let b = run(
            &FaultPlan::parse(&format!("{spec},seed=42")).unwrap(),
            &input,
        );
        let c = run(
            &FaultPlan::parse(&format!("{spec},seed=43")).unwrap(),
            &input,
        );
        assert_eq!(a, b);
        assert_ne!(a.0, c.0);
    }

    #[test]
    fn one_percent_corruption_over_100k_bytes() {
        let input = vec![0x55u8; 100_000];
        let (out, c) = run(&FaultPlan::parse("corrupt=0.01,seed=42").unwrap(), &input);
        let data = data_of(&out);
        assert_eq!(data.len(), 100_000);
        let changed = data.iter().filter(|&&b| b != 0x55).count() as u64;
        assert_eq!(changed, c.corrupted);
        // Binomial(100k, 0.01): mean 1000, sd ≈ 31.5; ±5 sd.
        assert!((840..=1160).contains(&changed), "{changed}");
        assert_eq!(c.dropped, 0);
    }

    #[test]
    fn drop_and_garbage_statistics() {
        let input = vec![0u8; 100_000];
        let (out, c) = run(
            &FaultPlan::parse("drop=0.01,garbage=0.001:4-4,seed=9").unwrap(),
            &input,
        );
        assert!((840..=1160).contains(&c.dropped), "{}", c.dropped);
        assert!(
            (50..=150).contains(&c.garbage_bursts),
            "{}",
            c.garbage_bursts
        );
        assert_eq!(c.garbage_bytes, 4 * c.garbage_bursts);
        assert_eq!(
            data_of(&out).len() as u64,
            100_000 - c.dropped + c.garbage_bytes
        );
        assert_eq!(c.bytes_out, 100_000 - c.dropped + c.garbage_bytes);
    }

    #[test]
    fn split_cuts_writes_without_losing_bytes() {
        let input: Vec<u8> = (0..1000u32).map(|i| i as u8).collect();
        let (out, c) = run(&FaultPlan::parse("split=1,seed=1").unwrap(), &input);
        assert_eq!(data_of(&out), input);
        assert_eq!(c.splits, 10);
        assert!(c.chunks > 10);
        assert_eq!(c.chunks as usize, out.len());
    }

    #[test]
    fn stalls_and_delay_line_timing() {
        let mut inj = FaultInjector::new(
            FaultConfig {
                stall: 1.0,
                stall_for: Duration::from_millis(300),
                ..FaultConfig::none()
            },
            1,
            Instant::ZERO,
        );
        let mut out = Vec::new();
        inj.process(b"ab", Instant::ZERO, &mut out);
        assert_eq!(
            out,
            vec![
                FaultAction::Stall(Duration::from_millis(300)),
                FaultAction::Data(b"a".to_vec()),
                FaultAction::Stall(Duration::from_millis(300)),
                FaultAction::Data(b"b".to_vec()),
            ]
        );
        let mut line = DelayLine::new(Duration::from_millis(10));
        line.push(out, Instant::ZERO);
        assert_eq!(line.pop_due(Instant::from_millis(309)), None);
        assert_eq!(line.next_due(), Some(Instant::from_millis(310)));
        assert_eq!(line.pop_due(Instant::from_millis(310)), Some(b"a".to_vec()));
        assert_eq!(line.next_due(), Some(Instant::from_millis(610)));
        assert_eq!(line.queued_bytes(), 1);
        assert_eq!(line.clear(), 1);
        assert_eq!(line.pop_due(Instant::from_millis(10_000)), None);
    }

    #[test]
    fn timed_hangup_fires_once_and_probabilistic_hangup_cuts_the_buffer() {
        let plan = FaultPlan::parse("hangup=5s:2s").unwrap();
        let mut inj = plan.injector(Direction::RobotToHost, Instant::from_millis(1000));
        assert_eq!(inj.hangup_deadline(), Some(Instant::from_millis(6000)));
        assert_eq!(inj.poll_hangup(Instant::from_millis(5999)), None);
        assert_eq!(
            inj.poll_hangup(Instant::from_millis(6000)),
            Some(FaultAction::HangUp(Some(Duration::from_secs(2))))
        );
        assert_eq!(inj.poll_hangup(Instant::from_millis(9000)), None);
        assert_eq!(inj.counters().hangups, 1);

        let plan = FaultPlan::parse("hangup=0.01,seed=3").unwrap();
        let mut inj = plan.injector(Direction::HostToRobot, Instant::ZERO);
        let mut out = Vec::new();
        inj.process(&[7u8; 10_000], Instant::ZERO, &mut out);
        assert_eq!(out.last(), Some(&FaultAction::HangUp(None)));
        let c = inj.counters();
        assert_eq!(c.hangups, 1);
        assert_eq!(c.bytes_out + c.lost_to_hangup, 10_000);
        assert!(c.lost_to_hangup > 0);
    }

    #[test]
    fn directions_have_independent_generators() {
        let plan = FaultPlan::parse("corrupt=0.5,seed=1").unwrap();
        let mut a = plan.injector(Direction::RobotToHost, Instant::ZERO);
        let mut b = plan.injector(Direction::HostToRobot, Instant::ZERO);
        let (mut oa, mut ob) = (Vec::new(), Vec::new());
        a.process(&[0; 64], Instant::ZERO, &mut oa);
        b.process(&[0; 64], Instant::ZERO, &mut ob);
        assert_ne!(oa, ob);
    }

    #[test]
    fn display_of_the_example_parses_back() {
        let p = FaultPlan::parse(
            "corrupt=0.01,drop=0.001,garbage=0.001,split=1,stall=0.0005:300ms,hangup=5s,seed=42",
        )
        .unwrap();
        let s = p.to_string();
        assert!(s.starts_with("seed=42,r2h.corrupt=0.01,"), "{s}");
        assert_eq!(FaultPlan::parse(&s).unwrap(), p);
        assert_eq!(FaultPlan::none().to_string(), "seed=0");
    }

    fn arb_config() -> impl proptest::strategy::Strategy<Value = FaultConfig> {
        use proptest::prelude::*;
        let p = || prop_oneof![Just(0.0), 0.0f64..=1.0];
        let dur = || (0u64..10_000_000_000).prop_map(Duration::from_nanos);
        let hang = prop_oneof![
            Just(None),
            dur().prop_map(|d| Some(HangupTrigger::At(d))),
            p().prop_map(|q| Some(HangupTrigger::Probability(q))),
        ];
        (
            (p(), p(), p(), 1u16..100, 0u16..100, p()),
            (p(), dur(), dur(), hang, proptest::option::of(dur())),
        )
            .prop_map(
                |(
                    (corrupt, drop, garbage, gmin, gextra, split),
                    (stall, stall_for, delay, hangup, hangup_for),
                )| {
                    FaultConfig {
                        corrupt,
                        drop,
                        garbage,
                        garbage_min: gmin,
                        garbage_max: gmin.saturating_add(gextra),
                        split,
                        stall,
                        stall_for,
                        delay,
                        hangup_for: hangup.and(hangup_for),
                        hangup,
                    }
                },
            )
    }

    proptest::proptest! {
        #[test]
        fn display_parse_round_trip(seed in proptest::num::u64::ANY, a in arb_config(), b in arb_config()) {
            let plan = FaultPlan { seed, robot_to_host: a, host_to_robot: b };
            let text = plan.to_string();
            proptest::prop_assert_eq!(FaultPlan::parse(&text), Ok(plan), "{}", text);
        }

        #[test]
        fn any_spec_string_parses_or_errs(s in ".{0,60}") {
            let _ = FaultPlan::parse(&s);
        }

        #[test]
        fn any_config_any_input_never_panics(
            corrupt in -1.0f64..2.0, drop in 0.0f64..1.0, garbage in 0.0f64..0.2,
            split in 0.0f64..1.0, gmin in 0u16..5, gmax in 0u16..5,
            input in proptest::collection::vec(proptest::num::u8::ANY, 0..300),
        ) {
            let cfg = FaultConfig { corrupt, drop, garbage, split, garbage_min: gmin,
                garbage_max: gmax, hangup: Some(HangupTrigger::Probability(0.001)), ..FaultConfig::none() };
            let mut inj = FaultInjector::new(cfg, 5, Instant::ZERO);
            let mut out = Vec::new();
            inj.process(&input, Instant::ZERO, &mut out);
            let c = inj.counters();
            let n = data_of(&out).len() as u64;
            proptest::prop_assert_eq!(n, c.bytes_out);
        }
    }
}

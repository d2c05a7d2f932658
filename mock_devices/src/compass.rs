//! A serial compass as a device model: a KVH C100 in NMEA mode or a PNI TCM2, mounted on a
//! robot of the simulated world (spec `protocols/compass_video_mux.md` §7a).
//!
//! # What it measures
//!
//! The world is east-north-up: +x east, +y north, robot yaw counter-clockwise from +x. The
//! compass heading is clockwise from north, so the *true* heading is `90° − yaw`. The world
//! has no magnetic variation (magnetic north = true north). The installation has a
//! [`deviation`](CompassModelConfig::deviation_deg) (positive east, NMEA's sign): the sensor
//! reads `magnetic − deviation`, plus Gaussian noise of
//! [`noise_deg`](CompassModelConfig::noise_deg) standard deviation (default 0.5°, the C100's
//! accuracy figure).
//!
//! # Dialects
//!
//! * [`MockDialect::Kvh`]: streams NMEA at `=r,N` sentences per minute (default 600, 10 Hz),
//!   either `HDG` (sensor heading **and** the deviation, so a driver can correct) or `HDM`
//!   (sensor heading only). Answers every accepted `=…` command with `>`; after `=t,1..3`
//!   (formats not modelled) it sends nothing until `=t,0`.
//! * [`MockDialect::Tcm2`]: streams at `sp=N` Hz (default 8) the standard line
//!   `$C…P…R…T…E000*hh` (`sdo=t`) or `$HCHDM` (`sdo=n`). `h` halts, `go` resumes, `c?` / `s?`
//!   answer one line, `mpcal=e`/`mpcal=d` run a user calibration (`mpcal=d` after `h` answers
//!   a score `H8V8M0.4`), `autocal=e|d` and `cc` are accepted. Commands are not acknowledged,
//!   as on the real device.
//!
//! Unknown or malformed command lines are counted and ignored.

use std::time::Duration;

use ima_compass::wire::{
    CalScore, Command, Decimal, EastWest, Hdg, Hdm, KvhCommand, KvhFormat, NmeaBody, NmeaSentence,
    Offset, Talker, Tcm2Command, Tcm2Data, Tcm2Format,
};
use ima_hal::Instant;
use rand::SeedableRng;
use rand::rngs::SmallRng;

use crate::model::DeviceModel;
use crate::world::{RobotId, SharedWorld, gaussian};

/// Which compass the mock is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MockDialect {
    /// KVH C100 in NMEA mode.
    Kvh,
    /// PNI TCM2.
    Tcm2,
}

/// Which NMEA sentence the KVH mock streams.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MockSentence {
    /// `$HCHDG,<sensor>,<dev>,E|W,,*hh`.
    Hdg,
    /// `$HCHDM,<sensor>,M*hh`.
    Hdm,
}

/// Settings of the mock compass.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CompassModelConfig {
    /// The dialect.
    pub dialect: MockDialect,
    /// KVH: the sentence streamed.
    pub sentence: MockSentence,
    /// Standard deviation of the heading noise, degrees.
    pub noise_deg: f64,
    /// Installation deviation, degrees, positive east (sensor = magnetic − deviation).
    pub deviation_deg: f64,
    /// Seed of the noise generator.
    pub seed: u64,
}

impl Default for CompassModelConfig {
    fn default() -> Self {
        Self {
            dialect: MockDialect::Kvh,
            sentence: MockSentence::Hdg,
            noise_deg: 0.5,
            deviation_deg: 0.0,
            seed: 1,
        }
    }
}

/// Counters of the mock.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct CompassModelStats {
    /// Command lines understood.
    pub commands: u32,
    /// Command lines refused (unknown, malformed, over-long).
    pub bad_commands: u32,
    /// Data lines sent.
    pub lines: u32,
    /// User calibrations completed.
    pub calibrations: u32,
}

const MAX_COMMAND_LINE: usize = 32;

/// The mock compass, a [`DeviceModel`].
#[derive(Debug)]
pub struct CompassDevice {
    cfg: CompassModelConfig,
    world: SharedWorld,
    robot: RobotId,
    rng: SmallRng,
    rx: Vec<u8>,
    rx_overflow: bool,
    out: Vec<u8>,
    streaming: bool,
    kvh_nmea: bool,
    tcm2_format: Tcm2Format,
    period: Duration,
    next_line: Option<Instant>,
    user_cal: bool,
    auto_cal: bool,
    stats: CompassModelStats,
}

/// The true heading of `robot` in degrees, clockwise from north, `[0, 360)` (`None` if the
/// world has no such robot).
#[must_use]
pub fn world_heading_deg(world: &SharedWorld, robot: RobotId) -> Option<f64> {
    world
        .with(|w| w.robot(robot).map(|r| r.pose().theta_rad.to_degrees()))
        .map(|yaw| (90.0 - yaw).rem_euclid(360.0))
}

impl CompassDevice {
    /// A compass on `robot` of `world`, streaming from power-on.
    #[must_use]
    pub fn new(cfg: CompassModelConfig, world: SharedWorld, robot: RobotId) -> Self {
        let period = match cfg.dialect {
            MockDialect::Kvh => Duration::from_millis(100),
            MockDialect::Tcm2 => Duration::from_millis(125),
        };
        Self {
            cfg,
            world,
            robot,
            rng: SmallRng::seed_from_u64(cfg.seed),
            rx: Vec::new(),
            rx_overflow: false,
            out: Vec::new(),
            streaming: true,
            kvh_nmea: true,
            tcm2_format: Tcm2Format::Standard,
            period,
            next_line: Some(Instant::ZERO),
            user_cal: false,
            auto_cal: false,
            stats: CompassModelStats::default(),
        }
    }

    /// Counters.
    #[must_use]
    pub fn stats(&self) -> CompassModelStats {
        self.stats
    }

    /// The output period in force.
    #[must_use]
    pub fn period(&self) -> Duration {
        self.period
    }

    /// Streaming continuously (not halted).
    #[must_use]
    pub fn is_streaming(&self) -> bool {
        self.streaming
    }

    /// Sensor heading now, degrees `[0, 360)`, with noise.
    fn sensor_deg(&mut self) -> f64 {
        let truth = world_heading_deg(&self.world, self.robot).unwrap_or(0.0);
        let noise = gaussian(&mut self.rng) * self.cfg.noise_deg;
        (truth - self.cfg.deviation_deg + noise).rem_euclid(360.0)
    }

    fn push_line(&mut self, line: &impl Emit) {
        let mut buf = [0u8; ima_compass::wire::MAX_LINE];
        if let Ok(n) = line.emit_into(&mut buf) {
            self.out.extend_from_slice(buf.get(..n).unwrap_or(&[]));
            self.stats.lines = self.stats.lines.saturating_add(1);
        }
    }

    fn hdm(&mut self) -> NmeaSentence {
        let h = self.sensor_deg();
        NmeaSentence {
            talker: Talker::MAGNETIC_COMPASS,
            body: NmeaBody::Hdm(Hdm {
                heading: Decimal::from_f64(h, 1),
            }),
        }
    }

    fn data_line(&mut self) {
        match self.cfg.dialect {
            MockDialect::Kvh => {
                if !self.kvh_nmea {
                    return;
                }
                let s = match self.cfg.sentence {
                    MockSentence::Hdm => self.hdm(),
                    MockSentence::Hdg => {
                        let h = self.sensor_deg();
                        let d = self.cfg.deviation_deg;
                        NmeaSentence {
                            talker: Talker::MAGNETIC_COMPASS,
                            body: NmeaBody::Hdg(Hdg {
                                heading: Decimal::from_f64(h, 1),
                                deviation: Decimal::from_f64(d.abs(), 1).map(|degrees| Offset {
                                    degrees,
                                    dir: if d < 0.0 {
                                        EastWest::West
                                    } else {
                                        EastWest::East
                                    },
                                }),
                                variation: None,
                            }),
                        }
                    }
                };
                self.push_line(&s);
            }
            MockDialect::Tcm2 => match self.tcm2_format {
                Tcm2Format::Nmea => {
                    let s = self.hdm();
                    self.push_line(&s);
                }
                Tcm2Format::Standard => {
                    let h = self.sensor_deg();
                    let pitch = gaussian(&mut self.rng) * 0.2;
                    let roll = gaussian(&mut self.rng) * 0.2;
                    let d = Tcm2Data {
                        heading: Decimal::from_f64(h, 1),
                        pitch: Decimal::from_f64(pitch, 1),
                        roll: Decimal::from_f64(roll, 1),
                        temperature: Decimal::from_f64(22.5, 1),
                        error: Some(0),
                        ..Tcm2Data::default()
                    };
                    self.push_line(&d);
                }
                // Mouse mode: binary, not modelled; nothing is sent.
                Tcm2Format::Mouse => {}
            },
        }
    }

    fn command(&mut self, cmd: Command, now: Instant) {
        self.stats.commands = self.stats.commands.saturating_add(1);
        match (self.cfg.dialect, cmd) {
            (MockDialect::Kvh, Command::Kvh(k)) => {
                match k {
                    KvhCommand::OutputFormat(f) => self.kvh_nmea = f == KvhFormat::Nmea,
                    KvhCommand::Rate { per_minute } => {
                        let per_minute = u64::from(per_minute.max(1));
                        self.period = Duration::from_micros(60_000_000 / per_minute);
                        self.next_line = Some(now + self.period);
                    }
                    KvhCommand::Baud(_) => {}
                }
                self.out.push(b'>');
            }
            (MockDialect::Tcm2, Command::Tcm2(t)) => match t {
                Tcm2Command::Halt => {
                    self.streaming = false;
                    self.next_line = None;
                }
                Tcm2Command::Go => {
                    self.streaming = true;
                    self.next_line = Some(now + self.period);
                }
                Tcm2Command::QueryOutput | Tcm2Command::QueryCompass => self.data_line(),
                Tcm2Command::SampleRate(hz) => {
                    self.period = Duration::from_micros(1_000_000 / u64::from(hz.max(1)));
                }
                Tcm2Command::OutputFormat(f) => self.tcm2_format = f,
                Tcm2Command::ClearCalibration => {}
                Tcm2Command::UserCalibrationOn => self.user_cal = true,
                Tcm2Command::UserCalibrationOff => {
                    if self.user_cal {
                        self.user_cal = false;
                        self.stats.calibrations = self.stats.calibrations.saturating_add(1);
                        let score = CalScore {
                            h: 8,
                            v: 8,
                            m: Decimal::from_f64(0.4, 1).unwrap_or(Decimal::ZERO),
                        };
                        self.push_line(&score);
                    }
                }
                Tcm2Command::AutoCalibration(on) => self.auto_cal = on,
            },
            // The other device's commands mean nothing here.
            _ => {
                self.stats.commands = self.stats.commands.saturating_sub(1);
                self.stats.bad_commands = self.stats.bad_commands.saturating_add(1);
            }
        }
    }
}

/// Lines the mock emits.
trait Emit {
    fn emit_into(&self, buf: &mut [u8]) -> Result<usize, ima_compass::wire::WireError>;
}

impl Emit for NmeaSentence {
    fn emit_into(&self, buf: &mut [u8]) -> Result<usize, ima_compass::wire::WireError> {
        self.emit(buf)
    }
}

impl Emit for Tcm2Data {
    fn emit_into(&self, buf: &mut [u8]) -> Result<usize, ima_compass::wire::WireError> {
        self.emit(buf)
    }
}

impl Emit for CalScore {
    fn emit_into(&self, buf: &mut [u8]) -> Result<usize, ima_compass::wire::WireError> {
        self.emit(buf)
    }
}

impl DeviceModel for CompassDevice {
    fn handle_rx(&mut self, bytes: &[u8], now: Instant) {
        for &b in bytes {
            if b == b'\r' || b == b'\n' {
                if !self.rx.is_empty() || self.rx_overflow {
                    let line = std::mem::take(&mut self.rx);
                    if self.rx_overflow {
                        self.rx_overflow = false;
                        self.stats.bad_commands = self.stats.bad_commands.saturating_add(1);
                    } else {
                        match Command::parse(&line) {
                            Ok(c) => self.command(c, now),
                            Err(_) => {
                                self.stats.bad_commands = self.stats.bad_commands.saturating_add(1);
                            }
                        }
                    }
                }
            } else if self.rx.len() < MAX_COMMAND_LINE {
                self.rx.push(b);
            } else {
                self.rx_overflow = true;
            }
        }
    }

    fn poll_tx(&mut self, out: &mut Vec<u8>) {
        out.append(&mut self.out);
    }

    fn poll_timeout(&self) -> Option<Instant> {
        if self.streaming { self.next_line } else { None }
    }

    fn handle_timeout(&mut self, now: Instant) {
        let Some(t) = self.next_line else { return };
        if !self.streaming || now < t {
            return;
        }
        self.data_line();
        // Skip missed periods rather than bursting them.
        let mut next = t + self.period;
        if next <= now {
            next = now + self.period;
        }
        self.next_line = Some(next);
    }

    fn name(&self) -> &str {
        "compass"
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::World;
    use ima_compass::wire::{Line, ParseOptions};

    fn lines(out: &[u8]) -> Vec<Line> {
        out.split(|b| *b == b'\n' || *b == b'\r')
            .filter(|l| !l.is_empty())
            .map(|l| Line::parse(l, &ParseOptions::default()).unwrap())
            .collect()
    }

    fn device(dialect: MockDialect, deviation_deg: f64) -> (CompassDevice, SharedWorld, RobotId) {
        let world = SharedWorld::new(World::default_world());
        let id = world.with(|w| w.robot_id("scooter")).unwrap();
        let cfg = CompassModelConfig {
            dialect,
            noise_deg: 0.0,
            deviation_deg,
            ..CompassModelConfig::default()
        };
        (CompassDevice::new(cfg, world.clone(), id), world, id)
    }

    #[test]
    fn kvh_streams_hdg_with_deviation_and_answers_prompts() {
        let (mut d, world, id) = device(MockDialect::Kvh, 2.0);
        // Scooter starts at yaw 30°: heading 60°.
        assert!((world_heading_deg(&world, id).unwrap() - 60.0).abs() < 1e-9);
        d.handle_timeout(Instant::ZERO);
        let mut out = Vec::new();
        d.poll_tx(&mut out);
        assert_eq!(out, b"$HCHDG,58.0,2.0,E,,*16\r\n");
        d.handle_rx(b"=r,60\r", Instant::from_millis(10));
        out.clear();
        d.poll_tx(&mut out);
        assert_eq!(out, b">");
        assert_eq!(d.period(), Duration::from_secs(1));
        d.handle_rx(b"=t,1\r=t,0\rbogus\r", Instant::from_millis(20));
        assert_eq!(d.stats().bad_commands, 1);
    }

    #[test]
    fn tcm2_halt_go_query_and_calibration() {
        let (mut d, _, _) = device(MockDialect::Tcm2, 0.0);
        let mut out = Vec::new();
        d.handle_rx(b"h\r", Instant::ZERO);
        assert!(!d.is_streaming());
        assert_eq!(d.poll_timeout(), None);
        d.handle_rx(b"c?\r", Instant::ZERO);
        d.poll_tx(&mut out);
        match lines(&out).as_slice() {
            [Line::Tcm2(t)] => assert!((t.heading.unwrap().to_f64() - 60.0).abs() < 1e-9),
            other => panic!("{other:?}"),
        }
        out.clear();
        d.handle_rx(b"mpcal=e\rgo\rh\rmpcal=d\r", Instant::from_millis(5));
        d.poll_tx(&mut out);
        assert!(matches!(lines(&out).as_slice(), [Line::CalScore(_)]));
        d.handle_rx(b"sdo=n\rsp=4\rgo\r", Instant::from_millis(10));
        assert_eq!(d.period(), Duration::from_millis(250));
        d.handle_timeout(Instant::from_millis(260));
        out.clear();
        d.poll_tx(&mut out);
        assert!(matches!(lines(&out).as_slice(), [Line::Nmea(_)]));
    }
}

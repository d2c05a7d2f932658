//! `ima replay FILE.mcap`: a recording's raw serial bytes fed back through the real framers
//! and wire decoders (those of `ima decode`), the readings they give republished — live to
//! Foxglove (`--foxglove`), into a new recording (`--record`), as JSON Lines (`--json`) —
//! paced by their recorded stamps (`--speed`, 0: as fast as possible).
//!
//! Readings: SICK LMS scans (`/<robot>/laser/scan`, exactly as decoded), P2OS SIP odometry
//! (`/<robot>/odom`, `/tf`) and sonar (`/<robot>/sonar`, after each SIP that brought readings),
//! rFLEX odometry as the driver's own session machine integrates its motion reports, compass
//! headings (`/<robot>/compass`, east-north-up), each in the units the driver used (the
//! channel's recorded parameters, `ima decode`'s `decoder`). The recorded decoded topics are not replayed:
//! they are what the replay re-creates. A recording of the replay (`--record`) also carries
//! every raw channel with its recorded stamps and port metadata, so it can itself be replayed,
//! decoded (`ima decode --mcap`) or served `--as-mock`.
//!
//! Memory: the file is read on a thread of its own a chunk at a time, each port's bytes
//! re-decoded as they come ([`super::decode::Decoder`]); the playback holds the items of the
//! last [`REORDER`] of stamps, to play them in stamp order. A replay holds about as much for an
//! hour's recording as for a minute's.
//!
//! `ima replay --as-mock PORT` serves one recorded port's robot→host bytes on a pty instead,
//! paced by their stamps, so a driver can be run against a recording (that port's bytes are
//! read into memory first).

use std::path::PathBuf;
use std::time::Duration;

use anyhow::{Context, Result};
use clap::Args;
use ima_hal::laser::{BeamFlags, LaserScan};
use ima_hal::sonar::{SonarReading, SonarScan, SonarTransducer};
use ima_record::convert::Pose2;
use ima_record::raw::Dir;
use ima_record::read::{Recording, Truncation};
use serde_json::{Value, json};

use super::decode::{Decoder, Protocol, recorded_protocol};
use crate::safety::outln;

/// Arguments of `ima replay`.
#[derive(Debug, Args)]
pub struct ReplayArgs {
    /// The recording (`--record` of `ima demo`, `run`, `drive`, `scan`, `compass`).
    file: PathBuf,
    /// Time factor of the playback, 0.001 to 1000; 0 plays as fast as possible.
    #[arg(long, default_value_t = 1.0, value_parser = super::num::replay_speed)]
    speed: f64,
    /// One JSON object per reading on stdout.
    #[arg(long)]
    json: bool,
    /// Serve this port's recorded robot→host bytes on a pseudo-terminal instead (its topic,
    /// `robot/device` or path); prints the pty's path. It re-decodes nothing, so it takes
    /// neither `--json` nor `--record`/`--foxglove`.
    #[arg(long, value_name = "PORT", conflicts_with_all = ["json", "record", "foxglove"])]
    as_mock: Option<String>,
    /// Recording and live view of the replayed readings.
    #[command(flatten)]
    rec: crate::record::RecordArgs,
}

/// A reading re-decoded from raw bytes.
#[derive(Debug, Clone, PartialEq)]
pub enum Reading {
    /// A laser scan.
    Scan(Box<LaserScan>),
    /// An odometry pose (odometry frame).
    Odometry(Pose2),
    /// A compass heading, radians, east-north-up (counter-clockwise from east).
    Compass(f64),
    /// The latest reading of every sonar transducer heard so far, after a P2OS SIP that
    /// brought new ones (as the live recording logs them), and where the transducers sit.
    Sonar(std::sync::Arc<[SonarTransducer]>, Box<SonarScan>),
}

/// One reading with its stamp and robot.
#[derive(Debug, Clone, PartialEq)]
pub struct Stamped {
    /// Log time of the bytes that completed it (Unix ns).
    pub t_ns: u64,
    /// The robot.
    pub robot: String,
    /// What.
    pub reading: Reading,
}

/// Run `ima replay`.
pub fn run(args: &ReplayArgs) -> Result<()> {
    let rec = Recording::open(&args.file)?;
    if let Some(port) = &args.as_mock {
        return serve_as_mock(rec, port, args.speed);
    }
    // What opening found (a second pass to count the messages first would read the whole
    // file once more); what the reading itself meets is said at the end.
    let damage = rec.damage();
    if let Some(why) = &damage {
        eprintln!("ima replay: the recording is damaged ({why}); replaying what it holds");
    }
    let left_out = rec.left_out();
    // Republished every recorded second, stamped on the recording's clock, so the replayed
    // readings have a place in `map` (a viewer that follows it, the shipped layout, could not
    // show a replay's scans), wherever a re-recording is read from.
    let fixed = if args.rec.is_off() {
        Vec::new()
    } else {
        rec.fixed_transforms()
    };
    crate::record::start(&args.rec, "ima replay")?;
    let to_file = args.rec.record.is_some();
    let file = args.file.display().to_string();
    // The file is read and re-decoded on a thread of its own, a chunk at a time, into items in
    // file order; the playback puts them in stamp order (a window of REORDER) and paces them.
    let (tx, mut items) = tokio::sync::mpsc::channel::<Item>(1024);
    let reader = std::thread::Builder::new()
        .name("ima-replay-read".into())
        .spawn(move || read_items(&rec, to_file, &tx))
        .context("starting the replay's reader")?;
    let json_out = args.json;
    let speed = args.speed;
    if !json_out {
        // A replay shows nothing by itself: say what it does while it plays (it printed only
        // its count at the end, after as long as the recording lasted).
        let pace = if speed > 0.0 {
            format!("at ×{speed}")
        } else {
            "as fast as it can".to_owned()
        };
        let hint = if args.rec.is_off() {
            "; `--json` prints each reading, `--foxglove` serves them to a live view"
        } else {
            ""
        };
        eprintln!("ima replay: re-decoding {file} {pace}{hint}");
    }
    // Readings played so far, for the line at the end (also after a Ctrl-C).
    let count = std::sync::Arc::new(std::sync::atomic::AtomicUsize::new(0));
    let counted = std::sync::Arc::clone(&count);
    let played = crate::safety::block_on(async move {
        let mut order = Reorder::default();
        let mut raw = RawReplay::default();
        // Pacing starts at the first item, a reading or a raw chunk; `t_s` at the first
        // reading.
        let mut first: Option<(u64, tokio::time::Instant)> = None;
        let mut t0: Option<u64> = None;
        // The recorded stamp at which the fixed transforms were last sent.
        let mut fixed_sent: Option<u64> = None;
        loop {
            let next = match order.next_due() {
                Some(item) => item,
                None => match crate::safety::until_cancelled(items.recv()).await? {
                    Some(item) => {
                        order.push(item);
                        continue;
                    }
                    None if order.is_empty() => break,
                    None => {
                        order.ended();
                        continue;
                    }
                },
            };
            let t = next.t_ns();
            // The clock starts with the first item played, not before the first read.
            let (first, start) = *first.get_or_insert((t, tokio::time::Instant::now()));
            if speed > 0.0 {
                let due = Duration::from_nanos(t.saturating_sub(first)).div_f64(speed);
                crate::safety::until_cancelled(tokio::time::sleep_until(start + due)).await?;
            }
            // As fast as possible, the replay could outrun the recorder's queue.
            crate::safety::until_cancelled(crate::record::room()).await?;
            if !fixed.is_empty() && fixed_sent.is_none_or(|f| t < f || t - f >= 1_000_000_000) {
                fixed_sent = Some(t);
                crate::record::with(|r| {
                    r.set_stamp(Some(t));
                    for (parent, child, [x_m, y_m, theta_rad]) in &fixed {
                        let p = ima_record::convert::Pose2 {
                            x_m: *x_m,
                            y_m: *y_m,
                            theta_rad: *theta_rad,
                        };
                        r.log_transform(parent, child, p);
                    }
                });
            }
            match next {
                Item::Raw(c) => raw.publish(&c),
                Item::Reading(r) => {
                    counted.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    publish(&r.reading);
                    if json_out {
                        let t0 = *t0.get_or_insert(t);
                        outln!("{}", reading_json(&r.reading, t0))?;
                    }
                }
            }
        }
        Ok(order.late)
    });
    // The reader ends once the playback stops taking items (its channel is closed).
    let read = reader
        .join()
        .map_err(|_| anyhow::anyhow!("the replay's reader failed"))?;
    let n = count.load(std::sync::atomic::Ordering::Relaxed);
    let late = played.inspect_err(|_| {
        if !json_out {
            eprintln!("ima replay: {n} readings from {file}, replayed before it stopped");
        }
    })?;
    let (streams, cut) = read?;
    let ends_early = cut.beyond(damage.as_deref());
    if streams == 0 && n == 0 && (damage.is_some() || ends_early.is_some()) {
        // A damaged file that gave nothing at all: a failure, not an empty replay.
        let why = ends_early.or(damage).unwrap_or_default();
        anyhow::bail!("nothing to replay in {file}: the recording is damaged ({why})");
    }
    if let Some(why) = ends_early {
        eprintln!("ima replay: the recording ends early ({why}); replayed what it holds");
    }
    if late > 0 {
        eprintln!(
            "ima replay: {late} items were read more than {} s of stamps after later ones \
             (a frame's bytes straddled a pause, or the file is out of order) and were played \
             late",
            REORDER.as_secs()
        );
    }
    if streams == 0 {
        // Nothing to re-decode: say why when the recorder was told to leave the ports out.
        let why = left_out.map_or_else(String::new, |p| format!(" (the recording left out: {p})"));
        eprintln!("ima replay: no raw serial channel to re-decode in the recording{why}");
    }
    if !json_out {
        eprintln!("ima replay: {n} readings from {file}");
    }
    Ok(())
}

/// How far behind the latest stamp read an item is held, so that items read a little out of
/// stamp order (a frame stamped by the chunk it began in, read with the one that ended it;
/// two robots' threads logging at once) are played in order. An item read later than that
/// (a frame whose bytes straddle a pause longer than this) is played at once, out of order,
/// and counted ([`Reorder::late`]).
const REORDER: Duration = Duration::from_secs(2);

/// [`REORDER`] in nanoseconds.
fn window() -> u64 {
    u64::try_from(REORDER.as_nanos()).unwrap_or(u64::MAX)
}

/// What the reader hands the playback.
#[derive(Debug)]
enum Item {
    /// A raw chunk to record again (only with `--record`).
    Raw(RawItem),
    /// A reading re-decoded.
    Reading(ReadingItem),
}

/// A raw chunk for a recording of the replay.
#[derive(Debug)]
struct RawItem {
    t_ns: u64,
    topic: std::sync::Arc<str>,
    seq: u64,
    port: std::sync::Arc<ima_record::raw::PortInfo>,
    dir: Dir,
    bytes: Vec<u8>,
}

/// A reading, with its stream's topic and its place in the stream.
#[derive(Debug)]
struct ReadingItem {
    topic: std::sync::Arc<str>,
    seq: u64,
    reading: Stamped,
}

impl Item {
    fn t_ns(&self) -> u64 {
        match self {
            Self::Raw(c) => c.t_ns,
            Self::Reading(r) => r.reading.t_ns,
        }
    }

    /// Play order: by stamp, a raw chunk before a reading of the same stamp (the bytes that
    /// completed it), then by stream (topic) and by place in the stream.
    fn key(&self) -> (u64, bool, &str, u64) {
        match self {
            Self::Raw(c) => (c.t_ns, false, &c.topic, c.seq),
            Self::Reading(r) => (r.reading.t_ns, true, &r.topic, r.seq),
        }
    }
}

impl PartialEq for Item {
    fn eq(&self, other: &Self) -> bool {
        self.key() == other.key()
    }
}

impl Eq for Item {}

impl PartialOrd for Item {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for Item {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        self.key().cmp(&other.key())
    }
}

/// Items in play order: each is held until an item stamped [`REORDER`] later has been read
/// (or the reading ended).
#[derive(Debug, Default)]
struct Reorder {
    held: std::collections::BinaryHeap<std::cmp::Reverse<Item>>,
    latest: u64,
    ended: bool,
    /// Items read after the window had passed them (played out of order).
    late: u64,
}

impl Reorder {
    fn push(&mut self, item: Item) {
        if item.t_ns().saturating_add(window()) < self.latest {
            self.late += 1;
        }
        self.latest = self.latest.max(item.t_ns());
        self.held.push(std::cmp::Reverse(item));
    }

    fn ended(&mut self) {
        self.ended = true;
    }

    fn is_empty(&self) -> bool {
        self.held.is_empty()
    }

    /// The next item in play order, once no item read later can come before it.
    fn next_due(&mut self) -> Option<Item> {
        let due = self.held.peek().is_some_and(|std::cmp::Reverse(i)| {
            self.ended || i.t_ns().saturating_add(window()) < self.latest
        });
        if due {
            self.held.pop().map(|std::cmp::Reverse(i)| i)
        } else {
            None
        }
    }
}

/// The raw ports of a recording of the replay, opened as their first chunks come, so that it
/// can itself be replayed, decoded or served `--as-mock`.
#[derive(Default)]
struct RawReplay {
    ports: std::collections::HashMap<std::sync::Arc<str>, Option<ima_record::raw::RawPort>>,
}

impl RawReplay {
    fn publish(&mut self, c: &RawItem) {
        let port = self.ports.entry(c.topic.clone()).or_insert_with(|| {
            let mut p = None;
            crate::record::with(|rec| p = Some(rec.raw_port((*c.port).clone())));
            p
        });
        let Some(p) = port else {
            return;
        };
        crate::record::with(|rec| rec.set_stamp(Some(c.t_ns)));
        p.chunk(c.dir, &c.bytes);
    }
}

/// Read the recording's raw chunks in file order, re-decode each port's robot→host bytes
/// as they come, and hand the playback the readings (and, `to_file`, the chunks themselves).
/// Returns how many raw streams the recording has, and why the reading stopped early (as
/// [`Recording::each_raw_chunk`] says it); stops early when the playback has.
fn read_items(
    rec: &Recording,
    to_file: bool,
    tx: &tokio::sync::mpsc::Sender<Item>,
) -> Result<(usize, ima_record::read::Truncation)> {
    let mut streams: std::collections::BTreeMap<String, StreamDecoder> = Default::default();
    let mut failed = None;
    let cut = rec.each_raw_chunk(|c| {
        let s = match streams.get_mut(c.topic) {
            Some(s) => s,
            None => match StreamDecoder::new(c.topic, c.port) {
                Ok(s) => streams.entry(c.topic.to_owned()).or_insert(s),
                Err(e) => {
                    failed = Some(e);
                    return false;
                }
            },
        };
        if to_file {
            let item = Item::Raw(RawItem {
                t_ns: c.log_time,
                topic: s.topic.clone(),
                seq: s.chunks,
                port: s.port.clone(),
                dir: c.dir,
                bytes: c.bytes.to_vec(),
            });
            s.chunks += 1;
            if tx.blocking_send(item).is_err() {
                return false;
            }
        }
        if c.dir != Dir::Rx {
            return true;
        }
        // This runs under the guard that reports a panic of the `mcap` crate as damage to the
        // file; a panic of ours is a bug to report as one, not damage.
        let fed = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            s.feed(c.log_time, c.bytes, tx)
        }));
        fed.unwrap_or_else(|p| {
            let what = ima_record::read::panic_message(&*p);
            failed = Some(anyhow::anyhow!(
                "re-decoding {} failed (a bug: please report it): {what}",
                c.topic
            ));
            false
        })
    });
    if let Some(e) = failed {
        return Err(e);
    }
    let n = streams.len();
    for s in streams.values_mut() {
        s.finish(tx);
    }
    Ok((n, cut))
}

fn publish(r: &Stamped) {
    crate::record::with(|rec| {
        // The recorded stamp, so a recording of the replay has the original times.
        rec.set_stamp(Some(r.t_ns));
        match &r.reading {
            Reading::Scan(s) => rec.log_scan(&r.robot, s),
            Reading::Odometry(p) => rec.log_odometry(&r.robot, *p),
            Reading::Compass(h) => rec.log_compass(&r.robot, *h),
            Reading::Sonar(transducers, scan) => rec.log_sonar(&r.robot, transducers, scan),
        }
    });
}

/// A reading as JSON: `kind`, `robot`, `t_ns`, `t_s` (from the first reading) and the values.
pub fn reading_json(r: &Stamped, t0: u64) -> Value {
    let t_s = r.t_ns.saturating_sub(t0) as f64 / 1e9;
    let mut v = match &r.reading {
        Reading::Scan(s) => json!({"kind": "scan", "start_angle_rad": s.start_angle_rad,
            "step_rad": s.step_rad,
            "ranges_m": s.ranges_m().iter().map(|r| (!r.is_nan()).then_some(*r)).collect::<Vec<_>>()}),
        Reading::Odometry(p) => {
            json!({"kind": "odometry", "x_m": p.x_m, "y_m": p.y_m, "theta_rad": p.theta_rad})
        }
        Reading::Compass(yaw) => json!({"kind": "compass", "yaw_rad": yaw}),
        Reading::Sonar(_, scan) => json!({"kind": "sonar", "readings": scan.readings.iter()
            .map(|r| json!({"index": r.index, "range_m": r.range_m})).collect::<Vec<_>>()}),
    };
    v["robot"] = json!(r.robot);
    v["t_ns"] = json!(r.t_ns);
    v["t_s"] = json!(t_s);
    v
}

/// How many bytes behind the end of the newest robot→host chunk an older chunk's stamp is
/// kept once that chunk is decoded: a reading is stamped by the chunk its frame began in,
/// and every frame a reading comes from is far shorter.
const CLOCK_SPAN: usize = 256 << 10;

/// One raw stream being re-decoded as its chunks are read: its decoder (`ima decode`'s), the
/// stamps of its latest robot→host chunks, and the rFLEX odometry integrated so far.
struct StreamDecoder {
    topic: std::sync::Arc<str>,
    port: std::sync::Arc<ima_record::raw::PortInfo>,
    protocol: Option<Protocol>,
    decoder: Option<Box<dyn Decoder + Send>>,
    /// `(end offset, log time)` of the robot→host chunks fed, oldest first, those more than
    /// [`CLOCK_SPAN`] bytes behind dropped.
    clock: std::collections::VecDeque<(usize, u64)>,
    /// Robot→host bytes fed so far.
    fed: usize,
    /// An rFLEX stream's odometry comes from the driver's own session machine (its pairing of
    /// the two axes, midpoint integration and plausibility rule), fed the motion reports.
    rflex: Option<Box<ima_rflex::machine::Machine>>,
    /// A P2OS stream's sonar: where the transducers sit (in the table `ima decode` reads the
    /// ranges with: the one the driver was told, else the one the robot's SYNC2 reply names,
    /// the P2-AT's until then), and the latest reading of each.
    sonar: Option<(std::sync::Arc<[SonarTransducer]>, SonarScan)>,
    /// Raw chunks handed on so far (the next one's place in the stream).
    chunks: u64,
    /// Readings handed on so far.
    readings: u64,
}

impl StreamDecoder {
    fn new(topic: &str, port: &ima_record::raw::PortInfo) -> Result<Self> {
        let protocol = recorded_protocol(&port.protocol);
        // The table the driver was told, else the P2-AT's until the robot's SYNC2 reply names
        // its own (`follow_robot`).
        let params =
            super::decode::p2os::recorded_params(&port.params).unwrap_or(&ima_p2os::params::P2AT);
        let sonar = (protocol == Some(Protocol::P2os))
            .then(|| (params.transducers().collect(), SonarScan::default()));
        // The switchers' ports carry commands and acknowledgements, no reading.
        let decoder = match protocol {
            Some(Protocol::VideoMux | Protocol::Kramer) | None => None,
            Some(p) => Some(super::decode::decoder(p, false, None, Some(&port.params))),
        };
        Ok(Self {
            topic: topic.into(),
            port: std::sync::Arc::new(port.clone()),
            protocol,
            decoder,
            clock: std::collections::VecDeque::new(),
            fed: 0,
            sonar,
            rflex: (protocol == Some(Protocol::Rflex)).then(|| {
                Box::new(ima_rflex::machine::Machine::new(
                    super::decode::rflex::recorded_config(&port.params),
                    ima_hal::Instant::ZERO,
                ))
            }),
            chunks: 0,
            readings: 0,
        })
    }

    /// The log time of the chunk holding robot→host byte `offset` (the latest chunk's past
    /// the end; the oldest kept before the kept ones).
    fn stamp(&self, offset: usize) -> u64 {
        let i = self.clock.partition_point(|(end, _)| *end <= offset);
        self.clock
            .get(i)
            .or(self.clock.back())
            .map_or(0, |(_, t)| *t)
    }

    /// Feed the robot→host `bytes` logged at `t_ns`; hand on what they complete. `false`:
    /// the playback has stopped.
    fn feed(&mut self, t_ns: u64, bytes: &[u8], tx: &tokio::sync::mpsc::Sender<Item>) -> bool {
        let Some(mut decoder) = self.decoder.take() else {
            return true;
        };
        self.fed += bytes.len();
        self.clock.push_back((self.fed, t_ns));
        let mut open = true;
        let _ = decoder.feed(bytes, &mut |v| {
            open = open && self.hand_on(&v, tx);
            Ok(())
        });
        self.decoder = Some(decoder);
        // After the feed: a frame that began in an older chunk and ended in this one (however
        // long) had that chunk's stamp.
        while self
            .clock
            .front()
            .is_some_and(|(end, _)| end + CLOCK_SPAN < self.fed)
        {
            self.clock.pop_front();
        }
        open
    }

    /// The end of the stream: hand on what its last bytes complete.
    fn finish(&mut self, tx: &tokio::sync::mpsc::Sender<Item>) {
        let Some(mut decoder) = self.decoder.take() else {
            return;
        };
        let _ = decoder.finish(&mut |v| {
            self.hand_on(&v, tx);
            Ok(())
        });
    }

    /// Turn one of `ima decode`'s objects into a reading and hand it on; `false`: the
    /// playback has stopped.
    fn hand_on(&mut self, v: &Value, tx: &tokio::sync::mpsc::Sender<Item>) -> bool {
        let offset = usize::try_from(v["offset"].as_u64().unwrap_or(0)).unwrap_or(usize::MAX);
        let t_ns = self.stamp(offset);
        if v["kind"] == "sync2" {
            self.follow_robot(v);
        }
        let reading = match (self.protocol, v["kind"].as_str()) {
            (Some(Protocol::SickLms), Some("scan")) => {
                scan_of(v).map(|s| Reading::Scan(Box::new(s)))
            }
            (Some(Protocol::P2os), Some("sip")) => Some(Reading::Odometry(Pose2 {
                x_m: v["x_m"].as_f64().unwrap_or(0.0),
                y_m: v["y_m"].as_f64().unwrap_or(0.0),
                theta_rad: v["theta_rad"].as_f64().unwrap_or(0.0),
            })),
            (Some(Protocol::Rflex), Some("motion")) => self
                .rflex
                .as_deref_mut()
                .and_then(|m| rflex_odometry(m, v, t_ns))
                .map(Reading::Odometry),
            (Some(Protocol::Compass), _) => compass_yaw(v).map(Reading::Compass),
            _ => None,
        };
        // A SIP that brought sonar readings: the sonar too, after its odometry.
        if self.protocol == Some(Protocol::P2os)
            && v["kind"] == "sip"
            && let Some(sonar) = self.sonar_of(v, t_ns)
        {
            if let Some(r) = reading
                && !self.send(r, t_ns, tx)
            {
                return false;
            }
            return self.send(sonar, t_ns, tx);
        }
        let Some(reading) = reading else {
            return true;
        };
        self.send(reading, t_ns, tx)
    }

    /// A P2OS robot's SYNC2 reply named the parameter table the decoder now reads its SIPs
    /// with: place the sonar where that robot's transducers sit.
    fn follow_robot(&mut self, v: &Value) {
        let Some((transducers, scan)) = self.sonar.as_mut() else {
            return;
        };
        let Some(params) = v["params"]
            .as_str()
            .and_then(|p| ima_p2os::params::RobotParams::for_subclass(p.as_bytes()))
        else {
            return;
        };
        let now: std::sync::Arc<[SonarTransducer]> = params.transducers().collect();
        if now != *transducers {
            *transducers = now;
            *scan = SonarScan::default();
        }
    }

    /// The sonar after a SIP's `sonar` readings, if it brought any.
    fn sonar_of(&mut self, v: &Value, t_ns: u64) -> Option<Reading> {
        let (transducers, scan) = self.sonar.as_mut()?;
        let at = ima_hal::Instant::from_micros(t_ns / 1000);
        let mut new = false;
        for r in v["sonar"].as_array()? {
            let (Some(index), Some(range_m)) = (r["index"].as_u64(), r["range_m"].as_f64()) else {
                continue;
            };
            let Ok(index) = u8::try_from(index) else {
                continue;
            };
            new |= scan.upsert(SonarReading { index, range_m, at });
        }
        new.then(|| Reading::Sonar(transducers.clone(), Box::new(scan.clone())))
    }

    /// Hand one reading on; `false`: the playback has stopped.
    fn send(&mut self, reading: Reading, t_ns: u64, tx: &tokio::sync::mpsc::Sender<Item>) -> bool {
        let item = Item::Reading(ReadingItem {
            topic: self.topic.clone(),
            seq: self.readings,
            reading: Stamped {
                t_ns,
                robot: self.port.robot.clone(),
                reading,
            },
        });
        self.readings += 1;
        tx.blocking_send(item).is_ok()
    }
}

/// A scan from `ima decode sick-lms`'s JSON (`None`: a scan without geometry).
fn scan_of(v: &Value) -> Option<LaserScan> {
    let mut s = LaserScan::new(v["start_angle_rad"].as_f64()?, v["step_rad"].as_f64()?);
    for r in v["ranges_m"].as_array()? {
        let (range, flags) = match r.as_f64() {
            Some(x) => (x as f32, BeamFlags::default()),
            None => (f32::NAN, BeamFlags::NO_RETURN),
        };
        s.push(range, flags).ok()?;
    }
    Some(s)
}

/// The yaw the live recording logs for one of `ima decode compass`'s lines: the driver's
/// [`Heading`](ima_hal::compass::Heading) (the line's own reference, deviation and variation)
/// as an east-north-up yaw in (−π, π].
fn compass_yaw(v: &Value) -> Option<f64> {
    use ima_hal::compass::{Heading, HeadingReference};
    let reference = match v["reference"].as_str() {
        Some("true") => HeadingReference::True,
        _ => HeadingReference::Magnetic,
    };
    let mut h = Heading::new(v["heading_rad"].as_f64()?, reference);
    h.deviation_rad = v["deviation"]["rad"].as_f64();
    h.variation_rad = v["variation"]["rad"].as_f64();
    Some(h.yaw_enu_rad())
}

/// Feed an rFLEX motion report (`ima decode rflex`'s object, received at `t_ns`) to the
/// driver's session machine; the odometry it integrates, once both axes of a cycle are in.
fn rflex_odometry(m: &mut ima_rflex::machine::Machine, v: &Value, t_ns: u64) -> Option<Pose2> {
    let int = |k: &str| v[k].as_i64().and_then(|x| i32::try_from(x).ok());
    let report = ima_rflex::wire::Report::Motion(ima_rflex::wire::MotionReport {
        rv: v["rv"].as_u64().and_then(|x| u32::try_from(x).ok())?,
        ts: v["ts"].as_u64().and_then(|x| u32::try_from(x).ok())?,
        axis: v["axis"].as_u64().and_then(|x| u8::try_from(x).ok())?,
        position: int("position")?,
        velocity: int("velocity")?,
        acceleration: int("acceleration")?,
        torque: int("torque")?,
    });
    m.handle_frame(&report, ima_hal::Instant::from_micros(t_ns / 1000));
    // What it would send (its keep-alives) goes nowhere: nothing is driven in a replay.
    let mut frame = [0u8; ima_rflex::wire::MAX_WIRE_FRAME];
    while m.poll_transmit(&mut frame).is_some() {}
    let mut odometry = None;
    while let Some(e) = m.poll_event() {
        if let ima_rflex::machine::Event::Odometry(o) = e {
            odometry = Some(Pose2::from_isometry(&o.value.pose));
        }
    }
    odometry
}

/// What `--as-mock`'s reader sends the server.
enum AsMock {
    /// The port found (its topic and protocol), before its first chunk.
    Port(String, String),
    /// A chunk the robot sent: its stamp, the bytes the host had written before it, the bytes.
    Rx(u64, usize, Vec<u8>),
}

/// Serve a port's recorded robot→host bytes on a pty. Each chunk the robot sent waits until
/// the host has written as many bytes as it had when the chunk was recorded (so a driver's
/// handshake meets its answers; at most [`AS_MOCK_WAIT`] each), then for its stamp relative to
/// the previous chunk (÷ `speed`). The recording is read on a thread of its own, a chunk at a
/// time, as the bytes are served: memory does not grow with the recording's length.
fn serve_as_mock(rec: Recording, name: &str, speed: f64) -> Result<()> {
    use serialport::SerialPort as _;
    let damage = rec.damage();
    if let Some(why) = &damage {
        eprintln!("ima replay: the recording is damaged ({why}); serving the bytes it holds");
    }
    let (tx, chunks) = std::sync::mpsc::sync_channel::<AsMock>(256);
    let wanted = name.to_owned();
    // The reader ends at the port's next chunk once `chunks` is dropped (on every way out of
    // this function, an early `?` included), or with the process.
    let reader = std::thread::Builder::new()
        .name("ima-replay-read".into())
        .spawn(move || {
            let mut host_before = 0usize;
            let mut found = false;
            let read = rec.each_chunk_of(&wanted, |c| {
                if !found {
                    found = true;
                    let port = AsMock::Port(c.topic.to_owned(), c.port.protocol.clone());
                    if tx.send(port).is_err() {
                        return false;
                    }
                }
                match c.dir {
                    Dir::Tx => host_before += c.bytes.len(),
                    // The server is gone (a signal, a failed write): stop reading.
                    Dir::Rx => {
                        return tx
                            .send(AsMock::Rx(c.log_time, host_before, c.bytes.to_vec()))
                            .is_ok();
                    }
                    Dir::Baud => {}
                }
                true
            });
            // What reading met besides what opening found (the `mcap` crate's own stop).
            (read, rec.damage())
        })
        .context("starting the replay's reader")?;
    let asked_to_end = crate::safety::asked_to_end;
    let interrupted = || Err(crate::safety::Interrupted(crate::safety::cause()).into());
    // The port is known at its first chunk; a name no channel answers to is known at the end.
    let Some(AsMock::Port(topic, protocol)) = crate::safety::recv_unless_asked_to_end(&chunks)?
    else {
        let (read, found) = reader
            .join()
            .map_err(|_| anyhow::anyhow!("the replay's reader failed"))?;
        if let Some(why) = Truncation(found).beyond(damage.as_deref()) {
            eprintln!("ima replay: the recording is damaged ({why})");
        }
        read?;
        anyhow::bail!("no chunk of {name} in the recording");
    };
    let (mut master, slave) =
        ima_mock_devices::pty::pty_pair().context("opening a pseudo-terminal")?;
    let path = slave.name().context("the pseudo-terminal has no path")?;
    master.set_timeout(Duration::from_millis(5))?;
    outln!("{path}")?;
    let mut line = AsMockLine {
        master,
        slave: Some(slave),
        heard: 0,
        gone: false,
    };
    let mut sent = 0usize;
    let mut prev_t: Option<u64> = None;
    let served = |sent: usize| {
        eprintln!("ima replay: served {sent} bytes of {topic} ({protocol}) on {path}");
    };
    loop {
        let (t, need, bytes) = match crate::safety::recv_unless_asked_to_end(&chunks) {
            Ok(Some(AsMock::Rx(t, need, bytes))) => (t, need, bytes),
            Ok(Some(AsMock::Port(..))) => continue,
            Ok(None) => break,
            Err(e) => {
                served(sent);
                return Err(e);
            }
        };
        let waited = std::time::Instant::now();
        while line.heard < need && waited.elapsed() < AS_MOCK_WAIT && line.open() {
            line.listen();
        }
        if speed > 0.0
            && let Some(p) = prev_t
        {
            let gap = Duration::from_nanos(t.saturating_sub(p)).div_f64(speed);
            let until = std::time::Instant::now() + gap.min(Duration::from_secs(5));
            while std::time::Instant::now() < until && line.open() {
                line.listen();
            }
        }
        if line.open() {
            prev_t = Some(t);
            sent += line
                .write(&bytes)
                .with_context(|| format!("writing to {path}"))?;
        }
        if asked_to_end() {
            served(sent);
            return interrupted();
        }
        if line.gone {
            // The driver closed the port: nobody reads the rest (it waited out every chunk's
            // request, 2 s each, into a pty nobody had open).
            eprintln!("ima replay: the client closed {path}");
            served(sent);
            return Ok(());
        }
    }
    let AsMockLine { slave, .. } = line;
    let (read, _) = reader
        .join()
        .map_err(|_| anyhow::anyhow!("the replay's reader failed"))?;
    served(sent);
    if let Some(why) = read?.beyond(damage.as_deref()) {
        eprintln!("ima replay: the recording ends early ({why}); served what it holds");
    }
    // The driver reads the last bytes before the pty closes.
    std::thread::sleep(Duration::from_millis(500));
    drop(slave);
    Ok(())
}

/// How long `--as-mock` waits for the host's request before sending the recorded answer.
const AS_MOCK_WAIT: Duration = Duration::from_secs(2);

/// `--as-mock`'s side of the pty, and whether its client is there.
///
/// The server holds the port's far end open until the client is first heard: with no far end
/// open, this side reads a hang-up, the same as after a client's close. Then it lets go, so
/// that the client's close shows as a hang-up here (a client that never writes is never known
/// to have left).
struct AsMockLine {
    master: serialport::TTYPort,
    slave: Option<serialport::TTYPort>,
    /// Bytes the client wrote so far.
    heard: usize,
    /// The client was heard, then closed the port.
    gone: bool,
}

impl AsMockLine {
    /// Whether to go on waiting: the client is there and nobody asked the program to end.
    fn open(&self) -> bool {
        !self.gone && !crate::safety::asked_to_end()
    }

    /// Read what the client wrote (at most the master's 5 ms timeout).
    fn listen(&mut self) {
        let mut buf = [0u8; 512];
        match std::io::Read::read(&mut self.master, &mut buf) {
            Ok(n) => {
                self.heard += n;
                if n > 0 {
                    self.slave = None;
                }
            }
            // No far end open: the client closed it (once this side let go of its own).
            Err(e) if self.slave.is_none() && hung_up(&e) => self.gone = true,
            Err(_) => {}
        }
    }

    /// Write `bytes`, as the client reads them: a pty holds a few kB, so a large chunk waits
    /// for the client (a client not yet heard, which may not have opened the port, is
    /// waited for as long as it takes). Ends early when the client closes the port or the
    /// program is asked to end. Returns how many bytes went out.
    ///
    /// # Errors
    /// The write fails, or a client that was heard takes no byte for [`AS_MOCK_WAIT`] (it
    /// stopped reading).
    fn write(&mut self, all: &[u8]) -> std::io::Result<usize> {
        let mut bytes = all;
        let mut progress = std::time::Instant::now();
        while !bytes.is_empty() && self.open() {
            match std::io::Write::write(&mut self.master, bytes) {
                Ok(n) => {
                    bytes = bytes.get(n..).unwrap_or_default();
                    progress = std::time::Instant::now();
                }
                Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {
                    if self.slave.is_none() && progress.elapsed() >= AS_MOCK_WAIT {
                        return Err(std::io::Error::new(
                            e.kind(),
                            format!(
                                "the client took no byte for {} s (it stopped reading)",
                                AS_MOCK_WAIT.as_secs()
                            ),
                        ));
                    }
                    self.listen();
                }
                // The write's own poll sees the client's close first (`--speed 0`, a chunk
                // with no gap before it).
                Err(e) if self.slave.is_none() && hung_up(&e) => self.gone = true,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(e),
            }
        }
        Ok(all.len() - bytes.len())
    }
}

/// Whether an error of the pty's master says no far end is open: `serialport` turns the
/// poll's hang-up into a broken pipe.
fn hung_up(e: &std::io::Error) -> bool {
    e.kind() == std::io::ErrorKind::BrokenPipe
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reading(topic: &str, seq: u64, t_ns: u64) -> Item {
        Item::Reading(ReadingItem {
            topic: topic.into(),
            seq,
            reading: Stamped {
                t_ns,
                robot: "r".into(),
                reading: Reading::Compass(0.0),
            },
        })
    }

    fn raw(topic: &str, seq: u64, t_ns: u64) -> Item {
        Item::Raw(RawItem {
            t_ns,
            topic: topic.into(),
            seq,
            port: std::sync::Arc::new(port("compass-kvh")),
            dir: Dir::Rx,
            bytes: Vec::new(),
        })
    }

    fn port(protocol: &str) -> ima_record::raw::PortInfo {
        ima_record::raw::PortInfo {
            robot: "scooter".into(),
            device: "laser".into(),
            port: "/dev/pts/3".into(),
            baud: 38_400,
            protocol: protocol.into(),
            params: Default::default(),
        }
    }

    fn what(i: &Item) -> (u64, bool, String, u64) {
        let (t, reading, topic, seq) = i.key();
        (t, reading, topic.to_owned(), seq)
    }

    /// Items read out of stamp order within the window play in order: by stamp, a raw chunk
    /// before a reading of the same stamp, then by topic and place in the stream (the order
    /// of the replay that sorted a whole recording); none is played before the window passes.
    #[test]
    fn items_play_in_stamp_order_within_the_window() {
        let s = 1_000_000_000u64;
        let mut order = Reorder::default();
        for item in [
            reading("/b", 0, 5 * s),
            reading("/a", 0, 5 * s),
            raw("/b", 0, 5 * s),
            reading("/a", 1, 4 * s),
            reading("/a", 2, 6 * s),
            reading("/a", 3, 6 * s + 1),
        ] {
            order.push(item);
        }
        // Nothing is more than 2 s behind the latest (6 s + 1 ns) but the one at 4 s.
        assert_eq!(
            what(&order.next_due().unwrap()),
            (4 * s, true, "/a".into(), 1)
        );
        assert!(order.next_due().is_none());
        order.push(reading("/a", 4, 8 * s + 2));
        let due: Vec<_> = std::iter::from_fn(|| order.next_due())
            .map(|i| what(&i))
            .collect();
        assert_eq!(
            due,
            [
                (5 * s, false, "/b".into(), 0),
                (5 * s, true, "/a".into(), 0),
                (5 * s, true, "/b".into(), 0),
                (6 * s, true, "/a".into(), 2),
                (6 * s + 1, true, "/a".into(), 3),
            ]
        );
        order.ended();
        assert_eq!(what(&order.next_due().unwrap()).0, 8 * s + 2);
        assert!(order.is_empty());
    }

    /// An item read more than the window after a later one is played at once and counted.
    #[test]
    fn an_item_read_past_the_window_is_counted_late() {
        let s = 1_000_000_000u64;
        let mut order = Reorder::default();
        order.push(reading("/a", 0, 0));
        order.push(reading("/a", 1, 5 * s));
        assert_eq!(order.late, 0);
        order.push(reading("/b", 0, s));
        assert_eq!(order.late, 1);
        // Exactly the window behind the latest: held, and not late.
        order.push(reading("/b", 1, 3 * s));
        assert_eq!(order.late, 1);
        let due: Vec<_> = std::iter::from_fn(|| order.next_due())
            .map(|i| what(&i).0)
            .collect();
        assert_eq!(due, [0, s]);
    }

    /// A frame that began in a chunk and ended in a chunk longer than the clock's span keeps
    /// the first chunk's stamp (the span is pruned after the feed).
    #[test]
    fn a_long_chunk_keeps_the_stamp_of_the_chunk_a_frame_began_in() {
        let (tx, mut rx) = tokio::sync::mpsc::channel(8);
        let mut d = StreamDecoder::new("/scooter/serial/compass", &port("compass-kvh")).unwrap();
        assert!(d.feed(200, b"$HCHDM", &tx));
        let mut rest = b",238.5,M*25\r\n".to_vec();
        rest.extend(std::iter::repeat_n(b'\n', CLOCK_SPAN + 1000));
        assert!(d.feed(300, &rest, &tx));
        let Ok(Item::Reading(r)) = rx.try_recv() else {
            panic!("a reading");
        };
        assert_eq!(r.reading.t_ns, 200);
        // The older chunk is gone now.
        assert_eq!(d.clock.len(), 1);
    }

    /// A line split across two chunks is stamped by the chunk it began in, as the replay that
    /// decoded a whole stream at once stamped it; it is handed on when the second comes.
    #[test]
    fn a_reading_is_stamped_by_the_chunk_its_frame_began_in() {
        let line = b"$HCHDM,238.5,M*25\r\n";
        let (tx, mut rx) = tokio::sync::mpsc::channel(8);
        let mut d = StreamDecoder::new("/scooter/serial/compass", &port("compass-kvh")).unwrap();
        assert!(d.feed(100, b"\r\n", &tx));
        assert!(d.feed(200, &line[..5], &tx));
        assert!(rx.try_recv().is_err());
        assert!(d.feed(300, &line[5..], &tx));
        d.finish(&tx);
        let Ok(Item::Reading(r)) = rx.try_recv() else {
            panic!("a reading");
        };
        assert_eq!(
            (r.reading.t_ns, r.seq, &*r.topic),
            (200, 0, "/scooter/serial/compass")
        );
        let Reading::Compass(h) = r.reading.reading else {
            panic!("a heading");
        };
        assert!((h - (90.0f64 - 238.5).to_radians()).abs() < 1e-9, "{h}");
        assert!(rx.try_recv().is_err());
        // A closed playback stops the reading.
        drop(rx);
        let mut d = StreamDecoder::new("/scooter/serial/compass", &port("compass-kvh")).unwrap();
        assert!(!d.feed(400, line, &tx));
    }
    /// A P2OS robot whose SYNC2 reply names a P2-DX: its SIPs' sonar is placed where a
    /// P2-DX's transducers sit (the table its ranges were read with), not a P2-AT's.
    #[test]
    fn a_replayed_p2os_sonar_sits_where_the_named_robot_s_transducers_do() {
        let frame = |p: ima_p2os::wire::Packet<'_>| {
            let mut out = [0u8; 256];
            let n = p.emit(&mut out).unwrap();
            out[..n].to_vec()
        };
        let sip = ima_p2os::wire::Sip {
            sonars: [ima_p2os::wire::SonarRaw {
                index: 0,
                range: 500,
            }]
            .into_iter()
            .collect(),
            ..Default::default()
        };
        let mut bytes = frame(ima_p2os::wire::Packet::SyncReply {
            name: b"Skeeter",
            class: b"Pioneer",
            subclass: b"p2dx",
        });
        bytes.extend(frame(ima_p2os::wire::Packet::Sip(sip)));
        let (tx, mut rx) = tokio::sync::mpsc::channel(8);
        let mut d = StreamDecoder::new("/skeeter/serial/base", &port("p2os")).unwrap();
        assert!(d.feed(100, &bytes, &tx));
        let sonar = std::iter::from_fn(|| rx.try_recv().ok())
            .find_map(|i| match i {
                Item::Reading(r) => match r.reading.reading {
                    Reading::Sonar(t, _) => Some(t),
                    _ => None,
                },
                Item::Raw(_) => None,
            })
            .expect("a sonar reading");
        let p2dx: std::sync::Arc<[SonarTransducer]> =
            ima_p2os::params::P2DX.transducers().collect();
        let p2at: std::sync::Arc<[SonarTransducer]> =
            ima_p2os::params::P2AT.transducers().collect();
        assert_ne!(p2dx, p2at, "the two tables differ");
        assert_eq!(sonar, p2dx);
    }

    /// A heading of 350° (10° west of north) replays as a yaw of 100° in (−π, π], as the live
    /// recording logs it, not −260°: the same rotation, but the opposite quaternion.
    #[test]
    fn a_replayed_heading_is_a_yaw_in_the_live_range() {
        let (tx, mut rx) = tokio::sync::mpsc::channel(8);
        let mut d = StreamDecoder::new("/scooter/serial/compass", &port("compass-kvh")).unwrap();
        let mut yaw_deg = |t_ns, line: &[u8]| {
            assert!(d.feed(t_ns, line, &tx));
            let Ok(Item::Reading(r)) = rx.try_recv() else {
                panic!("a reading");
            };
            let Reading::Compass(yaw) = r.reading.reading else {
                panic!("a heading");
            };
            yaw.to_degrees()
        };
        let yaw = yaw_deg(100, b"$HCHDM,350.0,M*2F\r\n");
        assert!((yaw - 100.0).abs() < 1e-9, "{yaw}");
        let live = ima_hal::compass::Heading::new(
            350f64.to_radians(),
            ima_hal::compass::HeadingReference::Magnetic,
        );
        assert!((yaw - live.yaw_enu_rad().to_degrees()).abs() < 1e-9);
        // An HDG line's deviation (2° E) and variation (10° W) count, as the driver's heading
        // counts them: true heading 342°, yaw 108° (it was 100°, the bare sensor heading).
        let yaw = yaw_deg(200, b"$HCHDG,350.0,2.0,E,10.0,W*65\r\n");
        assert!((yaw - 108.0).abs() < 1e-9, "{yaw}");
    }

    /// A factor near 0 overflowed the `Duration` of the first pause (1e-300) or slept for
    /// ever (1e-20): it is refused; 0 still means no pacing.
    #[test]
    fn the_speed_is_0_or_a_sensible_factor() {
        assert_eq!(crate::cmd::num::replay_speed("0"), Ok(0.0));
        assert_eq!(crate::cmd::num::replay_speed("0.001"), Ok(0.001));
        assert_eq!(crate::cmd::num::replay_speed("1000"), Ok(1000.0));
        for bad in ["1e-300", "1e-20", "0.0009", "1001", "-1", "NaN", "inf", "x"] {
            assert!(crate::cmd::num::replay_speed(bad).is_err(), "{bad}");
        }
    }
}

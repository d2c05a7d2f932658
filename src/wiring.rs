//! The wiring: the one module of the program that names concrete drivers.
//!
//! It opens a robot's devices from its configuration (tokio shells over tokio-serial ports,
//! every error naming the device and the port), on the process's one clock, and hands them
//! to the runtimes of [`ima_agents::runtime`], which know only the HAL traits. A robot's
//! base is whatever its configuration names (`[devices.base] kind = "p2os" | "rflex"`):
//! either robot runs on either base. A test (`tests` below) checks that no other module of
//! the robots' path names a driver crate or type.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use anyhow::{Context, Result};
use ima_agents::peer::wire::GroupKey;
use ima_agents::runtime::link::{ScooterLink, SesRequest, SkeeterLink};
use ima_agents::runtime::{Events, StopRequest, scooter, skeeter};
use ima_compass::machine::{Config as CompassConfig, Dialect as CompassWireDialect};
use ima_compass::shell::CompassDriver;
use ima_hal::base::DifferentialBase;
use ima_hal::safety::HaltSignal;
use ima_hal::time::SharedClock;
use ima_p2os::shell::Driver as _;
use ima_p2os::shell::P2os;
use ima_rflex::shell::Rflex;
use ima_sick_lms::shell::SickLms;
use ima_sick_lms::wire::BaudRate;
use ima_video_mux::machine::{Config as MuxConfig, Dialect as MuxWireDialect};
use ima_video_mux::net_frames::NetFrames;
use ima_video_mux::shell::VideoMux;
use ima_video_mux::wire::TieKind;

use crate::config::{
    BaseDevice, BaseKind, CompassDeviceConfig, CompassDialect, FramesSource, LaserDevice,
    MuxDevice, MuxDialect, RobotConfig, Role,
};
use crate::stack;

fn secs(s: f64) -> Duration {
    Duration::try_from_secs_f64(s).unwrap_or(Duration::from_secs(10))
}

/// Connect to a P2OS base (trying the configured rate first, then the robot's others).
/// `time_scale` > 1 (a sped-up simulated world) widens the driver's odometry plausibility
/// checks by that factor, since the world moves that much faster per real second.
pub async fn open_p2os(d: &BaseDevice, time_scale: f64, clock: &SharedClock) -> Result<P2os> {
    anyhow::ensure!(
        d.kind == BaseKind::P2os,
        "the base on {} is not configured as p2os",
        d.port
    );
    let port = ima_p2os::shell::open_port(&d.port, d.baud)
        .with_context(|| format!("opening the P2OS base port {}", d.port))?;
    let port = crate::record::tap(port, "base", &d.port, d.baud, "p2os"); // record: raw bytes
    let mut cfg = ima_p2os::Config::default();
    let mut bauds: heapless::Vec<u32, 8> = heapless::Vec::new();
    let _ = bauds.push(d.baud);
    for b in &cfg.bauds {
        if *b != d.baud {
            let _ = bauds.push(*b);
        }
    }
    cfg.bauds = bauds;
    cfg.motion_time_scale = time_scale;
    P2os::connect(port, cfg, secs(d.connect_timeout_s), clock.clone())
        .await
        .with_context(|| format!("connecting to the P2OS base on {}", d.port))
}

/// The rFLEX driver's configuration for a world `time_scale` times faster than real time
/// (see [`open_rflex`]); `ima replay` builds the same to re-integrate a recording.
pub fn rflex_config(time_scale: f64) -> ima_rflex::machine::Config {
    let mut cfg = ima_rflex::machine::Config::default();
    let k = if time_scale.is_finite() {
        time_scale.max(1.0)
    } else {
        1.0
    };
    cfg.limits.max_v_m_s *= k;
    cfg.limits.max_omega_rad_s *= k;
    // Motion reports as often in world time as at real speed (at most 50 per second).
    cfg.report_period_us = ((f64::from(cfg.report_period_us) / k) as u32).max(20_000);
    // The controller ramps velocities in its own (real) time: accelerations × k give the
    // configured ramps in world time, so Scooter stops and turns as at real speed.
    cfg.trans_accel_m_s2 *= k;
    cfg.rot_accel = (f64::from(cfg.rot_accel) * k).min(f64::from(u32::MAX)) as u32;
    cfg
}

/// Connect to an rFLEX base and release its brake. `time_scale` > 1 (a sped-up simulated
/// world) widens the driver's odometry plausibility limits by that factor, since the world
/// moves that much faster per real second, asks for motion reports that much more often, and
/// multiplies the accelerations by it (the controller ramps in real time).
pub async fn open_rflex(d: &BaseDevice, time_scale: f64, clock: &SharedClock) -> Result<Rflex> {
    anyhow::ensure!(
        d.kind == BaseKind::Rflex,
        "the base on {} is not configured as rflex",
        d.port
    );
    let port = ima_rflex::shell::open_port(&d.port, d.baud)
        .with_context(|| format!("opening the rFLEX base port {}", d.port))?;
    let cfg = rflex_config(time_scale);
    // record: raw bytes, with the time scale a replay needs to integrate them as the driver
    // does (its odometry plausibility limits)
    let params = [("time_scale".to_owned(), time_scale.to_string())].into();
    let port = crate::record::tap_with(port, "base", &d.port, d.baud, "rflex", params);
    let mut base = Rflex::connect(port, cfg, secs(d.connect_timeout_s), clock.clone())
        .await
        .with_context(|| format!("connecting to the rFLEX base on {}", d.port))?;
    base.enable_motors(true)
        .await
        .with_context(|| format!("releasing the brake of the rFLEX base on {}", d.port))?;
    Ok(base)
}

/// Connect to a SICK LMS and start its scan stream.
pub async fn open_laser(d: &LaserDevice, clock: &SharedClock) -> Result<SickLms> {
    let baud = BaudRate::from_bps(d.baud).with_context(|| {
        format!(
            "laser on {}: a SICK LMS runs at 9600, 19200, 38400 or 500000, not {}",
            d.port, d.baud
        )
    })?;
    let port = ima_sick_lms::shell::open_port(&d.port, 9600)
        .with_context(|| format!("opening the SICK LMS port {}", d.port))?;
    let port = crate::record::tap(port, "laser", &d.port, 9600, "sick-lms"); // record: raw bytes
    let wait = secs(d.power_up_wait_s.max(0.0));
    let cfg = ima_sick_lms::machine::Config {
        baud,
        rs422: d.rs422,
        stream: true,
        power_up_wait: (d.power_up_wait_s > 0.0).then_some(wait),
        ..ima_sick_lms::machine::Config::default()
    };
    let lms = SickLms::connect(port, cfg, wait + Duration::from_secs(60), clock.clone())
        .await
        .with_context(|| format!("initialising the SICK LMS on {}", d.port))?
        .with_scan_timeout(Duration::from_secs(5));
    Ok(lms)
}

/// Connect to a serial compass and wait for headings.
pub async fn open_compass(d: &CompassDeviceConfig, clock: &SharedClock) -> Result<CompassDriver> {
    let dialect = match d.dialect {
        CompassDialect::Kvh => CompassWireDialect::KvhC100 {
            rate_per_minute: 600,
        },
        CompassDialect::Nmea => CompassWireDialect::Nmea,
        CompassDialect::Tcm2 => CompassWireDialect::Tcm2 {
            sample_rate_hz: 8,
            output: ima_compass::wire::Tcm2Format::Standard,
        },
    };
    let port = ima_compass::shell::open_port(&d.port, d.baud)
        .with_context(|| format!("opening the compass port {}", d.port))?;
    let protocol = match d.dialect {
        CompassDialect::Kvh => "compass-kvh",
        CompassDialect::Nmea => "compass-nmea",
        CompassDialect::Tcm2 => "compass-tcm2",
    };
    let port = crate::record::tap(port, "compass", &d.port, d.baud, protocol); // record: raw bytes
    CompassDriver::connect(
        port,
        CompassConfig::for_dialect(dialect),
        Duration::from_secs(10),
        clock.clone(),
    )
    .await
    .with_context(|| format!("configuring the compass on {}", d.port))
}

/// Open the video switcher (the driver task starts at once; the first selection proves the
/// link).
pub fn open_mux(d: &MuxDevice, clock: &SharedClock) -> Result<VideoMux> {
    let port = ima_video_mux::shell::open_port(&d.port, d.baud)
        .with_context(|| format!("opening the video switcher port {}", d.port))?;
    let protocol = match d.dialect {
        MuxDialect::Extron => "video-mux-extron",
        MuxDialect::Kramer => "video-mux-kramer",
    };
    let port = crate::record::tap(port, "video_mux", &d.port, d.baud, protocol); // record: raw bytes
    let dialect = match d.dialect {
        MuxDialect::Extron => MuxWireDialect::Extron {
            kind: TieKind::All,
            output: None,
        },
        MuxDialect::Kramer => MuxWireDialect::Kramer {
            output: 1,
            machine: 1,
            expect_reply: true,
        },
    };
    Ok(VideoMux::spawn(
        port,
        MuxConfig {
            dialect,
            channel_count: d.cameras,
            ..MuxConfig::default()
        },
        clock.clone(),
    ))
}

/// Connect to the frame server (frames stamped on `clock`).
pub async fn open_frames(f: &FramesSource, clock: &SharedClock) -> Result<NetFrames> {
    let mut frames = NetFrames::new(f.addr.clone(), Duration::from_millis(f.timeout_ms))
        .with_clock(clock.clone());
    frames
        .connect()
        .await
        .map_err(|e| anyhow::anyhow!("{e}"))
        .with_context(|| format!("connecting to the frame server {}", f.addr))?;
    Ok(frames)
}

/// A robot's base, of the kind its configuration names (a handle: clones talk to the same
/// driver task).
#[derive(Debug, Clone)]
pub enum Base {
    /// A P2OS controller (Pioneer 2-AT).
    P2os(P2os),
    /// An rFLEX controller (ATRV-Jr), brake released.
    Rflex(Rflex),
}

impl Base {
    /// The driver's halt signal.
    fn halt_signal(&self) -> HaltSignal {
        match self {
            Base::P2os(b) => b.halt_signal(),
            Base::Rflex(b) => b.halt_signal(),
        }
    }
}

/// Open the base `d` names. `time_scale`: see [`open_p2os`] and [`open_rflex`]. `drives`: the robot moves, so
/// a P2OS base's motors are enabled (an rFLEX base's brake is released either way).
pub async fn open_base(
    d: &BaseDevice,
    time_scale: f64,
    drives: bool,
    clock: &SharedClock,
) -> Result<Base> {
    Ok(match d.kind {
        BaseKind::P2os => {
            let mut b = open_p2os(d, time_scale, clock).await?;
            if drives {
                b.enable_motors(true).await.with_context(|| {
                    format!("enabling the motors of the P2OS base on {}", d.port)
                })?;
            }
            Base::P2os(b)
        }
        BaseKind::Rflex => Base::Rflex(open_rflex(d, time_scale, clock).await?),
    })
}

/// Skeeter's devices (opened, not yet running).
#[derive(Debug)]
pub struct SkeeterHw {
    base: Base,
    mux: VideoMux,
    frames: NetFrames,
    /// The frame client's frames received, copied out while the runtime owns it.
    frames_received: Arc<AtomicU64>,
}

/// Scooter's devices (opened, not yet running).
#[derive(Debug)]
pub struct ScooterHw {
    base: Base,
    laser: SickLms,
    compass: Option<CompassDriver>,
    /// Scans the runtime read (each once).
    scans_read: Arc<AtomicU64>,
}

impl SkeeterHw {
    /// A handle on the drivers' own counters, readable after the runtime has ended.
    pub fn counters(&self) -> DriverCounters {
        DriverCounters {
            base: Some(self.base.clone()),
            laser: None,
            scans_read: None,
            frames_received: Some(Arc::clone(&self.frames_received)),
        }
    }
}

impl ScooterHw {
    /// A handle on the drivers' own counters, readable after the runtime has ended.
    pub fn counters(&self) -> DriverCounters {
        DriverCounters {
            base: Some(self.base.clone()),
            laser: Some(self.laser.clone()),
            scans_read: Some(Arc::clone(&self.scans_read)),
            frames_received: None,
        }
    }
}

/// What a robot's drivers counted, taken from the drivers themselves (not from the
/// recorder), so a recording's message counts can be checked against them. Fields a robot
/// has no device for are absent.
#[derive(Debug, Clone, Default, PartialEq, Eq, serde::Serialize)]
pub struct DriverCounts {
    /// The base's protocol (`p2os`, `rflex`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub base: Option<&'static str>,
    /// Good frames the base's framer delivered (every packet the base sent with a good
    /// checksum: status, motion, sonar, configuration, acknowledgements).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub base_frames: Option<u64>,
    /// Frames the base's framer lost: bad checksums or lengths, and partial frames it
    /// abandoned after a gap in the bytes (which a re-decoding of the recorded bytes, blind
    /// to their timing, may still find whole).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub base_framer_drops: Option<u64>,
    /// P2OS only: server information packets (SIPs) the open session decoded, delivered or
    /// rejected as implausible (SIPs arriving while the driver closes the session are
    /// ignored by it, though recorded).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub base_sips: Option<u64>,
    /// SICK LMS: scans the driver decoded and published.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub laser_scans: Option<u64>,
    /// SICK LMS: telegrams the framer lost (bad checksums, headers or payloads, and partial
    /// telegrams abandoned after a silence).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub laser_framer_drops: Option<u64>,
    /// SICK LMS: scan telegrams that did not decode.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub laser_decode_errors: Option<u64>,
    /// Scans the robot's runtime read (each scan once; scans the driver published while the
    /// runtime was busy are superseded, so this is at most `laser_scans`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub laser_scans_read: Option<u64>,
    /// Camera frames the frame client received.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub camera_frames: Option<u64>,
}

/// Handles on a robot's drivers for their counters ([`SkeeterHw::counters`],
/// [`ScooterHw::counters`]). They keep the drivers running: call [`DriverCounters::close`]
/// once the runtime has ended.
#[derive(Debug)]
pub struct DriverCounters {
    base: Option<Base>,
    laser: Option<SickLms>,
    scans_read: Option<Arc<AtomicU64>>,
    frames_received: Option<Arc<AtomicU64>>,
}

impl DriverCounters {
    /// Close the drivers (so they read no more bytes: the counts are final and match the
    /// raw bytes recorded) and read their counters.
    pub async fn close(self) -> DriverCounts {
        let base = async {
            match &self.base {
                Some(Base::P2os(b)) => {
                    let _ = b.close().await;
                    let s = b.stats();
                    let f = s.framer;
                    let drops = f.bad_checksums + f.bad_counts + f.abandoned;
                    Some(("p2os", f.frames, drops, Some(s.sips + s.implausible_sips)))
                }
                Some(Base::Rflex(b)) => {
                    let _ = b.close().await;
                    let f = b.stats().framer;
                    let drops = f.errors().wrapping_add(f.restarts).wrapping_add(f.stale);
                    Some(("rflex", u64::from(f.frames), u64::from(drops), None))
                }
                None => None,
            }
        };
        let laser = async {
            match &self.laser {
                Some(l) => {
                    let _ = l.close().await;
                    Some(l.stats())
                }
                None => None,
            }
        };
        let (base, laser) = tokio::join!(base, laser);
        DriverCounts {
            base: base.map(|b| b.0),
            base_frames: base.map(|b| b.1),
            base_framer_drops: base.map(|b| b.2),
            base_sips: base.and_then(|b| b.3),
            laser_scans: laser.map(|s| s.delivered),
            laser_framer_drops: laser.map(|s| {
                let f = s.framer;
                f.bad_checksums + f.bad_headers + f.bad_payloads + f.expired
            }),
            laser_decode_errors: laser.map(|s| s.decode_errors),
            laser_scans_read: self.scans_read.map(|n| n.load(Ordering::Relaxed)),
            camera_frames: self.frames_received.map(|n| n.load(Ordering::Relaxed)),
        }
    }
}

/// record: name the robot whose ports these are (raw channels `/<robot>/serial/<device>`).
fn label_ports(cfg: &RobotConfig) {
    let d = &cfg.devices;
    let ports = [
        d.base.as_ref().map(|b| b.port.as_str()),
        d.laser.as_ref().map(|l| l.port.as_str()),
        d.compass.as_ref().map(|c| c.port.as_str()),
        d.video_mux.as_ref().map(|m| m.port.as_str()),
    ];
    crate::record::label_ports(&cfg.robot, ports.into_iter().flatten());
}

fn missing(what: &str) -> anyhow::Error {
    anyhow::anyhow!("the configuration has no [devices.{what}]")
}

/// Open Skeeter's devices.
pub async fn open_skeeter(cfg: &RobotConfig, clock: &SharedClock) -> Result<SkeeterHw> {
    anyhow::ensure!(cfg.role == Role::Skeeter, "not a Skeeter configuration");
    let d = &cfg.devices;
    label_ports(cfg); // record: raw channels named by robot
    // The serial ports first: a missing one is named at once (the frame server's refusal
    // used to be the only thing said when nothing was there).
    let mux = open_mux(
        d.video_mux.as_ref().ok_or_else(|| missing("video_mux"))?,
        clock,
    )?;
    let base = open_base(
        d.base.as_ref().ok_or_else(|| missing("base"))?,
        cfg.agent.time_scale,
        false,
        clock,
    )
    .await?;
    let frames = open_frames(d.frames.as_ref().ok_or_else(|| missing("frames"))?, clock).await?;
    Ok(SkeeterHw {
        base,
        mux,
        frames,
        frames_received: Arc::default(),
    })
}

/// Open Scooter's devices (all three at once).
pub async fn open_scooter(cfg: &RobotConfig, clock: &SharedClock) -> Result<ScooterHw> {
    anyhow::ensure!(cfg.role == Role::Scooter, "not a Scooter configuration");
    let d = &cfg.devices;
    label_ports(cfg); // record: raw channels named by robot
    let base = d.base.as_ref().ok_or_else(|| missing("base"))?;
    let laser = d.laser.as_ref().ok_or_else(|| missing("laser"))?;
    let compass = async {
        match &d.compass {
            Some(c) => open_compass(c, clock).await.map(Some),
            None => Ok(None),
        }
    };
    let (base, laser, compass) = tokio::join!(
        open_base(base, cfg.agent.time_scale, true, clock),
        open_laser(laser, clock),
        compass
    );
    Ok(ScooterHw {
        base: base?,
        laser: laser?,
        compass: compass?,
        scans_read: Arc::default(),
    })
}

/// A task aborted when dropped (on every way out of a runtime's run).
pub(crate) struct AbortOnDrop(pub(crate) Option<tokio::task::JoinHandle<()>>);

impl Drop for AbortOnDrop {
    fn drop(&mut self) {
        if let Some(t) = &self.0 {
            t.abort();
        }
    }
}

/// record: a P2OS base's sonar as `/<robot>/sonar` (a point cloud in `<robot>/base_link`) after
/// every SIP that brought new readings and, with `odometry`, its odometry (`/<robot>/odom` and
/// the `odom → base_link` transform) after every SIP — while a recorder runs and until the
/// returned guard drops (the task holds a handle on the base, which would keep its driver
/// running). Odometry for Skeeter, whose runtime never reads it (the recording had no
/// `/skeeter/odom`, so nothing placed `skeeter/base_link` in the map); Scooter's runtime reads
/// its own through [`crate::record::Recorded`], which records it.
fn record_base(base: &Base, robot: &str, odometry: bool) -> AbortOnDrop {
    let Base::P2os(b) = base else {
        return AbortOnDrop(None);
    };
    if !crate::record::active() {
        return AbortOnDrop(None);
    }
    let b = b.clone();
    let robot = robot.to_owned();
    AbortOnDrop(Some(tokio::spawn(async move {
        use ima_hal::sonar::SonarArray;
        let transducers = b.transducers().to_vec();
        let mut last = ima_hal::Instant::ZERO;
        loop {
            match b.next_state(last, Duration::from_secs(2)).await {
                Ok(st) => {
                    last = st.odometry.at;
                    crate::record::with(|r| {
                        if odometry {
                            let pose = &st.odometry.value.pose;
                            let pose = ima_record::convert::Pose2::from_isometry(pose);
                            r.log_odometry(&robot, pose);
                        }
                        if st.new_sonar {
                            r.log_sonar(&robot, &transducers, &st.sonar.value);
                        }
                    });
                }
                Err(_) => tokio::time::sleep(Duration::from_millis(200)).await,
            }
        }
    })))
}

/// A device whose driver has ended, by name (`checks`: each device's "has it ended?").
type EndedCheck = (&'static str, Box<dyn Fn() -> bool + Send + Sync>);

/// Resolves with the name of the first device whose driver has ended for good, unless the
/// robot is asked to stop first (its drivers then close on purpose: this never resolves). A
/// robot whose devices are gone (a pulled USB hub; the mock world killed) used to run on,
/// broadcasting that it was well, while the commander sent it targets it could not do.
async fn a_device_ended(checks: Vec<EndedCheck>, mut stop: StopRequest) -> &'static str {
    let mut tick = tokio::time::interval(Duration::from_millis(250));
    loop {
        tokio::select! {
            _ = tick.tick() => {}
            r = stop.changed() => if r.is_err() { std::future::pending::<()>().await },
        }
        // Asked to stop, or a signal, a closed stdout, a panic: the drivers close on purpose.
        let on_purpose = || *stop.borrow() || crate::safety::asked_to_end();
        if on_purpose() {
            std::future::pending::<()>().await;
        }
        if let Some((name, _)) = checks.iter().find(|(_, f)| f()) {
            // Asked meanwhile (a signal between the two looks): that is why it closed.
            if on_purpose() {
                std::future::pending::<()>().await;
            }
            return name;
        }
    }
}

/// The error that ends a robot's run when one of its devices is gone.
fn device_gone(robot: &str, device: &str) -> anyhow::Error {
    anyhow::anyhow!(
        "{robot}'s {device}: its driver has ended (the port closed or failed for good): the run \
         ends, so that the other robots and the commander see {robot} lost (start it again once \
         the device is back)"
    )
}

/// Run a robot's runtime (`run`, given its own stop request) until it ends, or until one of
/// its devices is gone (`checks`): then the runtime is asked to stop and given 3 s to end in
/// order (its base stopped, its Peer Agent link shut down, its tasks ended), and the error
/// names the device. `stop` is the robot's stop request, passed on to the runtime.
async fn run_watching<Fut>(
    robot: &str,
    checks: Vec<EndedCheck>,
    stop: StopRequest,
    run: impl FnOnce(StopRequest) -> Fut,
) -> Result<()>
where
    Fut: std::future::Future<Output = Result<(), ima_agents::runtime::RuntimeError>>,
{
    let (tx, rx) = tokio::sync::watch::channel(*stop.borrow());
    let forward = {
        let (mut outer, tx) = (stop.clone(), tx.clone());
        AbortOnDrop(Some(tokio::spawn(async move {
            while outer.changed().await.is_ok() {
                let asked = *outer.borrow();
                let _ = tx.send(asked);
            }
        })))
    };
    let gone = a_device_ended(checks, stop);
    let run = run(rx);
    tokio::pin!(run);
    let ended = tokio::select! {
        r = &mut run => r.map_err(anyhow::Error::from),
        device = gone => {
            let _ = tx.send(true);
            let _ = tokio::time::timeout(Duration::from_secs(3), &mut run).await;
            Err(device_gone(robot, device))
        }
    };
    drop(forward);
    ended
}

/// The base's "has it ended?".
fn base_check(base: &Base) -> EndedCheck {
    match base {
        Base::P2os(b) => {
            let b = b.clone();
            ("base", Box::new(move || b.link().is_ended()))
        }
        Base::Rflex(b) => {
            let b = b.clone();
            ("base", Box::new(move || b.link().is_ended()))
        }
    }
}

/// Run Scooter's runtime ([`scooter::run`]) on its devices, linked to the other robots over
/// the Peer Agent network of `cfg`, until `stop`, or until one of its devices is gone (an
/// error naming it).
pub async fn run_scooter(
    cfg: &RobotConfig,
    key: GroupKey,
    hw: ScooterHw,
    clock: SharedClock,
    events: Events,
    stop: StopRequest,
) -> Result<()> {
    let rt = stack::scooter::runtime_config(cfg);
    let net = stack::net::net_config(cfg)?;
    let time = ima_agents::runtime::MissionTime::new(clock.clone(), rt.time_scale);
    let ses = cfg.peer.connect.clone().map(|manager| SesRequest {
        manager,
        priority: cfg.agent.ses_request_priority,
        retry_after: Duration::from_secs(1),
    });
    let link = ScooterLink::network(&net, key, ses, events.clone(), time).await?;
    let ScooterHw {
        base,
        laser,
        compass,
        scans_read,
    } = hw;
    let halt = Some(base.halt_signal());
    let mut checks = vec![base_check(&base)];
    {
        let l = laser.clone();
        checks.push(("laser", Box::new(move || l.link().is_ended())));
    }
    // The compass is optional: Scooter goes on without it, as it starts without one.
    let _base = record_base(&base, &cfg.robot, false); // record: sonar
    // record: scans, odometry and headings as the runtime reads them.
    let laser = crate::record::Recorded::new(laser, &cfg.robot).counting(scans_read);
    let compass = compass.map(|c| crate::record::Recorded::new(c, &cfg.robot));
    match base {
        Base::P2os(base) => {
            let dev = scooter::ScooterDevices {
                base: crate::record::Recorded::new(base, &cfg.robot),
                laser,
                compass,
                halt,
            };
            let run = |stop| scooter::run(rt, dev, link, clock, events, stop);
            run_watching(&cfg.robot, checks, stop, run).await?;
        }
        Base::Rflex(base) => {
            let dev = scooter::ScooterDevices {
                base: crate::record::Recorded::new(base, &cfg.robot),
                laser,
                compass,
                halt,
            };
            let run = |stop| scooter::run(rt, dev, link, clock, events, stop);
            run_watching(&cfg.robot, checks, stop, run).await?;
        }
    }
    Ok(())
}

/// Run Skeeter's runtime ([`skeeter::run`]) on its devices, with its Peer Agent manager and
/// broadcast channel as configured in `cfg`, until `stop`. `rt` is its runtime configuration
/// ([`stack::skeeter::runtime_config`]), read and checked before the devices were opened.
pub async fn run_skeeter(
    cfg: &RobotConfig,
    rt: skeeter::SkeeterRuntimeConfig,
    key: GroupKey,
    hw: SkeeterHw,
    clock: SharedClock,
    events: Events,
    stop: StopRequest,
) -> Result<()> {
    let net = stack::net::net_config(cfg)?;
    let time = ima_agents::runtime::MissionTime::new(clock.clone(), rt.time_scale);
    let SkeeterHw {
        base,
        mux,
        frames,
        frames_received,
    } = hw;
    // record: odometry, sonar (from now: not only once the Peer Agent manager is up)
    let _base = record_base(&base, &cfg.robot, true);
    let link = SkeeterLink::network(&net, key, events.clone(), time)
        .await
        .context("starting Skeeter's Peer Agent manager")?;
    let mut checks = vec![base_check(&base)];
    {
        let m = mux.clone();
        checks.push(("video switcher", Box::new(move || m.link().is_ended())));
    }
    // record: camera frames (and the client's own count of them)
    let frames = crate::record::frames(frames, &cfg.robot)
        .counting(frames_received, NetFrames::grabs)
        .mounted(rt.scan.head);
    match base {
        Base::P2os(base) => {
            let dev = skeeter::SkeeterDevices { base, mux, frames };
            let run = |stop| skeeter::run(rt, dev, link, clock, events, stop);
            run_watching(&cfg.robot, checks, stop, run).await?;
        }
        Base::Rflex(base) => {
            let dev = skeeter::SkeeterDevices { base, mux, frames };
            let run = |stop| skeeter::run(rt, dev, link, clock, events, stop);
            run_watching(&cfg.robot, checks, stop, run).await?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use ima_hal::base::Odometer;
    use ima_hal::camera::{CameraMux, FrameSource};
    use ima_hal::compass::Compass;
    use ima_hal::laser::LaserScanner;
    use ima_hal::time::Clock;
    use ima_mock_devices::served::{BaseKind as Served, ServeOptions, ServedWorld};

    fn serve(scooter_base: Served) -> ServedWorld {
        let world = crate::cmd::mock::load_world(None, 3).unwrap();
        ServedWorld::start(
            world,
            &ServeOptions {
                seed: 3,
                scooter_base,
                ..ServeOptions::default()
            },
        )
        .unwrap()
    }

    async fn odometry(b: &mut Base) -> ima_hal::Stamped<ima_hal::base::Odometry> {
        match b {
            Base::P2os(b) => b.odometry().await.unwrap(),
            Base::Rflex(b) => b.odometry().await.unwrap(),
        }
    }

    async fn next_odometry(
        b: &mut Base,
        after: ima_hal::Instant,
    ) -> ima_hal::Stamped<ima_hal::base::Odometry> {
        match b {
            Base::P2os(b) => b.next_odometry(after).await.unwrap(),
            Base::Rflex(b) => b.next_odometry(after).await.unwrap(),
        }
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn every_device_opens_on_a_served_world() {
        let served = serve(Served::Rflex);
        let [sk, sc, _] =
            crate::cmd::mock_world::loopback_configs(served.endpoints(), 1.0, None).unwrap();
        let clock = ima_hal::time::TokioClock::shared();
        let (a, b) = tokio::join!(open_skeeter(&sk, &clock), open_scooter(&sc, &clock));
        let mut sk = a.unwrap();
        let mut sc = b.unwrap();
        assert!(matches!(sk.base, Base::P2os(_)));
        assert!(matches!(sc.base, Base::Rflex(_)));
        odometry(&mut sk.base).await;
        let sel = sk.mux.select(1).await.unwrap();
        assert_eq!(sel.channel, 1);
        tokio::time::sleep(sk.mux.settle_time() + Duration::from_millis(50)).await;
        let f = sk.frames.grab().await.unwrap();
        assert_eq!(f.value.channel, Some(1));
        // Red is straight ahead of Skeeter in the default world.
        let red = ima_mock_devices::camera::find_color(&f.value, [220, 30, 30], 12);
        assert!(red.is_some());
        let s = sc.laser.scan().await.unwrap();
        assert!(!s.value.is_empty());
        let h = sc.compass.as_mut().unwrap().heading().await.unwrap();
        // Scooter faces 30° ENU = 60° compass.
        assert!((h.value.heading_rad.to_degrees() - 60.0).abs() < 5.0);
        odometry(&mut sc.base).await;
    }

    /// Issue 14: the devices of one robot stamp on one time base. A scan and an odometry
    /// reading waited for together both carry stamps inside the window in which they were
    /// awaited, so they differ by less than that window (their transport delay); with a
    /// clock per device they would differ by the devices' epochs.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_scan_and_an_odometry_reading_share_one_time_base() {
        let served = serve(Served::Rflex);
        let [_, sc, _] =
            crate::cmd::mock_world::loopback_configs(served.endpoints(), 1.0, None).unwrap();
        let clock = ima_hal::time::TokioClock::shared();
        // Let the clock's epoch lie well before the devices open.
        tokio::time::sleep(Duration::from_millis(300)).await;
        let mut sc = open_scooter(&sc, &clock).await.unwrap();
        for _ in 0..3 {
            let t0 = clock.now();
            let (scan, odo) = tokio::join!(sc.laser.next_scan(t0), next_odometry(&mut sc.base, t0));
            let t1 = clock.now();
            let scan = scan.unwrap();
            let window = t1.saturating_duration_since(t0);
            for at in [scan.at, odo.at] {
                assert!(t0 <= at && at <= t1, "{at:?} outside [{t0:?}, {t1:?}]");
            }
            let gap = if scan.at > odo.at {
                scan.at.saturating_duration_since(odo.at)
            } else {
                odo.at.saturating_duration_since(scan.at)
            };
            assert!(gap <= window, "{gap:?} > {window:?}");
            assert!(window < Duration::from_secs(1), "{window:?}");
        }
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn scooter_opens_on_a_p2os_base() {
        let served = serve(Served::P2os);
        let [_, sc, _] =
            crate::cmd::mock_world::loopback_configs(served.endpoints(), 1.0, None).unwrap();
        assert_eq!(sc.devices.base.as_ref().unwrap().kind, BaseKind::P2os);
        let clock = ima_hal::time::TokioClock::shared();
        let mut sc = open_scooter(&sc, &clock).await.unwrap();
        assert!(matches!(sc.base, Base::P2os(_)));
        odometry(&mut sc.base).await;
    }

    #[tokio::test]
    async fn errors_name_the_port() {
        let d = BaseDevice {
            kind: BaseKind::P2os,
            port: "/dev/ima-no-such-port".into(),
            baud: 9600,
            connect_timeout_s: 1.0,
        };
        let e = open_p2os(&d, 1.0, &ima_hal::time::TokioClock::shared())
            .await
            .unwrap_err();
        assert!(format!("{e:#}").contains("/dev/ima-no-such-port"), "{e:#}");
        let f = FramesSource {
            addr: "127.0.0.1:1".into(),
            timeout_ms: 500,
        };
        let e = open_frames(&f, &ima_hal::time::TokioClock::shared())
            .await
            .unwrap_err();
        assert!(format!("{e:#}").contains("127.0.0.1:1"), "{e:#}");
    }
}

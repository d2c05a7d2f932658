//! One simulated world serving every device of both robots: the world stepped in real time
//! × a speed factor, every serial device on its own pseudo-terminal, and Skeeter's frame
//! grabber on a TCP frame server (protocol: `ima_video_mux::net_frames`).
//!
//! [`ServedWorld::start`] is what `ima mock world`, `ima demo` and the mission tests run:
//!
//! | robot | device | served as |
//! |---|---|---|
//! | Skeeter | P2OS base (and sonar) | pty |
//! | Skeeter | Extron video switcher | pty, sharing a [`VideoBus`] with the camera head |
//! | Skeeter | 7-camera head + frame grabber | TCP frame server ([`FrameServer`]) |
//! | Scooter | rFLEX base (and sonar) | pty |
//! | Scooter | SICK LMS 200 | pty |
//! | Scooter | KVH C100 compass (NMEA) | pty |
//!
//! Device timing (SIP period, scan rate, switch delay, frame clock) stays real time; only the
//! world's motion runs `speed` times faster. Robots' agents that want mission time to match
//! the world's use the same factor on their clocks.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::Duration;

use ima_hal::camera::FrameSource;
use ima_video_mux::net_frames::{HEADER_LEN, Header, REQUEST_LEN, Request, Status};
use tokio::io::{AsyncReadExt, AsyncWriteExt};

use crate::body::WorldBody;
use crate::camera::{CameraConfig, CameraError, MockCameraHead};
use crate::compass::{CompassDevice, CompassModelConfig};
use crate::faults::FaultPlan;
use ima_hal::time::Clock as _;

use crate::p2os::{P2osDevice, P2osModelConfig};
use crate::pty::{HostLog, PtyDevice, PtyError, PtyOptions};
use crate::rflex::{RflexDevice, RflexModelConfig};
use crate::sick_lms::{SickLmsDevice, SickLmsModelConfig, WorldLaser};
use crate::video_mux::{MuxDevice, MuxModelConfig, VideoBus};
use crate::world::SharedWorld;

/// Errors starting a served world.
#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    /// The world has no robot of that name.
    #[error("the world has no robot named {0:?}")]
    NoRobot(String),
    /// The speed factor is not in (0, 100].
    #[error("speed factor must be in (0, 100], not {0}")]
    BadSpeed(f64),
    /// A pty could not be served.
    #[error("{0}")]
    Pty(#[from] PtyError),
    /// The frame server could not start.
    #[error("frame server: {0}")]
    Io(#[from] std::io::Error),
}

/// Options of [`ServedWorld::start`].
#[derive(Debug, Clone)]
pub struct ServeOptions {
    /// Seed of every device's noise.
    pub seed: u64,
    /// World time runs this many times faster than real time.
    pub speed: f64,
    /// Name of the robot with the P2OS base, switcher and camera head.
    pub skeeter: String,
    /// Name of the robot with the rFLEX base, laser and compass.
    pub scooter: String,
    /// Address the frame server binds (port 0: any free port).
    pub frames_addr: SocketAddr,
    /// The camera head.
    pub camera: CameraConfig,
    /// If set, what the host writes to Skeeter's P2OS base is recorded here (tests).
    pub skeeter_base_log: Option<HostLog>,
    /// If set, what the host writes to Scooter's base is recorded here (tests).
    pub scooter_base_log: Option<HostLog>,
    /// The kind of base Scooter's body is served as (its own rFLEX, or a P2OS controller).
    pub scooter_base: BaseKind,
    /// The clock of every served device's model ([`PtyOptions::clock`]): a program serving
    /// the world to its own drivers passes its one clock. `None`: each device's own.
    pub clock: Option<ima_hal::time::SharedClock>,
    /// Faults between every served serial device and its port (`ima mock world --faults`);
    /// each device's seed is the plan's plus its place in the order base, switcher, Scooter's
    /// base, laser, compass, so no two lose the same bytes.
    pub faults: FaultPlan,
}

/// A kind of served base controller.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum BaseKind {
    /// An rFLEX controller (the ATRV-Jr's), 115 200 baud.
    #[default]
    Rflex,
    /// A P2OS controller (the Pioneer 2-AT's), 9600 baud.
    P2os,
}

impl Default for ServeOptions {
    fn default() -> Self {
        Self {
            seed: 1,
            speed: 1.0,
            skeeter: "skeeter".into(),
            scooter: "scooter".into(),
            frames_addr: SocketAddr::from(([127, 0, 0, 1], 0)),
            camera: CameraConfig::default(),
            skeeter_base_log: None,
            scooter_base_log: None,
            scooter_base: BaseKind::Rflex,
            clock: None,
            faults: FaultPlan::none(),
        }
    }
}

/// Where each device is served (serialisable, e.g. as the JSON line of `ima mock world`).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Endpoints {
    /// Skeeter's devices.
    pub skeeter: SkeeterEndpoints,
    /// Scooter's devices.
    pub scooter: ScooterEndpoints,
}

/// Skeeter's device paths.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SkeeterEndpoints {
    /// The P2OS base (9600 baud).
    pub base: PathBuf,
    /// The Extron switcher (9600 baud).
    pub video_mux: PathBuf,
    /// The frame server, `host:port`.
    pub frames: String,
}

/// Scooter's device paths.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ScooterEndpoints {
    /// The base (rFLEX at 115200 baud, or P2OS at 9600: see `base_kind`).
    pub base: PathBuf,
    /// Which controller the base is.
    #[serde(default)]
    pub base_kind: BaseKind,
    /// The SICK LMS (powers up at 9600 baud).
    pub laser: PathBuf,
    /// The KVH C100 compass (NMEA, 4800 baud).
    pub compass: PathBuf,
}

/// A world and every device of both robots, served until dropped.
#[derive(Debug)]
pub struct ServedWorld {
    world: SharedWorld,
    endpoints: Endpoints,
    // Field order = drop order: the stepper stops first, then the devices.
    _stepper: ScaledStepper,
    _frames: FrameServer,
    p2os: PtyDevice<P2osDevice>,
    mux: PtyDevice<MuxDevice>,
    scooter_base: ScooterBase,
    laser: PtyDevice<SickLmsDevice>,
    compass: PtyDevice<CompassDevice>,
}

impl ServedWorld {
    /// Serve `world` with `opts`.
    pub fn start(world: SharedWorld, opts: &ServeOptions) -> Result<Self, ServeError> {
        if !(opts.speed.is_finite() && opts.speed > 0.0 && opts.speed <= 100.0) {
            return Err(ServeError::BadSpeed(opts.speed));
        }
        let id = |name: &str| {
            world
                .with(|w| w.robot_id(name))
                .ok_or_else(|| ServeError::NoRobot(name.to_owned()))
        };
        let (sk, sc) = (id(&opts.skeeter)?, id(&opts.scooter)?);
        let seed = opts.seed;
        let next = std::cell::Cell::new(0u64);
        let pty = || {
            let mut faults = opts.faults.clone();
            faults.seed = faults.seed.wrapping_add(next.replace(next.get() + 1));
            PtyOptions {
                clock: opts.clock.clone(),
                faults,
                ..PtyOptions::default()
            }
        };
        let cap = |s: &str| {
            let mut c = s.chars();
            c.next()
                .map(|f| f.to_uppercase().chain(c).collect::<String>())
                .unwrap_or_default()
        };
        let p2os = PtyDevice::spawn(
            P2osDevice::new(
                P2osModelConfig {
                    name: cap(&opts.skeeter),
                    ..P2osModelConfig::default()
                },
                WorldBody::new(world.clone(), sk, seed),
            ),
            PtyOptions {
                host_log: opts.skeeter_base_log.clone(),
                ..pty()
            },
        )?;
        let bus = VideoBus::new(None);
        let mux = PtyDevice::spawn(
            MuxDevice::new(MuxModelConfig::default(), bus.clone()),
            pty(),
        )?;
        let scooter_log = PtyOptions {
            host_log: opts.scooter_base_log.clone(),
            ..pty()
        };
        let scooter_base = match opts.scooter_base {
            BaseKind::Rflex => ScooterBase::Rflex(PtyDevice::spawn(
                RflexDevice::new(
                    RflexModelConfig::default(),
                    WorldBody::new(world.clone(), sc, seed.wrapping_add(1)),
                ),
                scooter_log,
            )?),
            BaseKind::P2os => ScooterBase::P2os(PtyDevice::spawn(
                P2osDevice::new(
                    P2osModelConfig {
                        name: cap(&opts.scooter),
                        ..P2osModelConfig::default()
                    },
                    WorldBody::new(world.clone(), sc, seed.wrapping_add(1)),
                ),
                scooter_log,
            )?),
        };
        let laser = PtyDevice::spawn(
            SickLmsDevice::new(
                SickLmsModelConfig::default(),
                Box::new(WorldLaser::new(world.clone(), sc, seed.wrapping_add(2))),
                opts.clock
                    .as_ref()
                    .map_or(ima_hal::Instant::ZERO, |c| c.now()),
            ),
            pty(),
        )?;
        let compass = PtyDevice::spawn(
            CompassDevice::new(
                CompassModelConfig {
                    seed: seed.wrapping_add(3),
                    ..CompassModelConfig::default()
                },
                world.clone(),
                sc,
            ),
            pty(),
        )?;
        let camera = CameraConfig {
            seed: seed.wrapping_add(4),
            ..opts.camera
        };
        let frames = FrameServer::spawn(opts.frames_addr, camera, world.clone(), sk, bus)?;
        let stepper = ScaledStepper::spawn(world.clone(), opts.speed)?;
        let endpoints = Endpoints {
            skeeter: SkeeterEndpoints {
                base: p2os.path().to_path_buf(),
                video_mux: mux.path().to_path_buf(),
                frames: frames.addr().to_string(),
            },
            scooter: ScooterEndpoints {
                base: scooter_base.path().to_path_buf(),
                base_kind: opts.scooter_base,
                laser: laser.path().to_path_buf(),
                compass: compass.path().to_path_buf(),
            },
        };
        Ok(Self {
            world,
            endpoints,
            _stepper: stepper,
            _frames: frames,
            p2os,
            mux,
            scooter_base,
            laser,
            compass,
        })
    }

    /// The world.
    #[must_use]
    pub fn world(&self) -> &SharedWorld {
        &self.world
    }

    /// Where each device is served.
    #[must_use]
    pub fn endpoints(&self) -> &Endpoints {
        &self.endpoints
    }

    /// Each served serial device's link, by name (`skeeter base`, …): the bytes each end
    /// wrote, the faults injected ([`ServeOptions::faults`]), outages.
    #[must_use]
    pub fn links(&self) -> [(&'static str, crate::link::RunnerStatus); 5] {
        let base = match &self.scooter_base {
            ScooterBase::Rflex(d) => d.status(),
            ScooterBase::P2os(d) => d.status(),
        };
        [
            ("skeeter base", self.p2os.status()),
            ("skeeter video_mux", self.mux.status()),
            ("scooter base", base),
            ("scooter laser", self.laser.status()),
            ("scooter compass", self.compass.status()),
        ]
    }
}

/// Scooter's served base controller.
#[derive(Debug)]
enum ScooterBase {
    Rflex(PtyDevice<RflexDevice>),
    P2os(PtyDevice<P2osDevice>),
}

impl ScooterBase {
    fn path(&self) -> &std::path::Path {
        match self {
            ScooterBase::Rflex(d) => d.path(),
            ScooterBase::P2os(d) => d.path(),
        }
    }
}

/// A thread stepping a world every 10 ms by the real elapsed time × `speed`.
#[derive(Debug)]
pub struct ScaledStepper {
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl ScaledStepper {
    /// Start stepping.
    pub fn spawn(world: SharedWorld, speed: f64) -> std::io::Result<Self> {
        let stop = Arc::new(AtomicBool::new(false));
        let flag = Arc::clone(&stop);
        let speed = if speed.is_finite() && speed > 0.0 {
            speed
        } else {
            1.0
        };
        let thread = std::thread::Builder::new()
            .name("ima-world-stepper".into())
            .spawn(move || {
                let mut last = std::time::Instant::now();
                while !flag.load(Ordering::Relaxed) {
                    std::thread::sleep(Duration::from_millis(10));
                    let now = std::time::Instant::now();
                    let dt = now.saturating_duration_since(last).mul_f64(speed);
                    last = now;
                    // Sub-steps of at most 10 ms of world time keep the dynamics stable.
                    let n = (dt.as_secs_f64() / 0.01).ceil().clamp(1.0, 1000.0);
                    let sub = dt.div_f64(n);
                    world.with(|w| {
                        for _ in 0..(n as u32) {
                            w.step(sub);
                        }
                    });
                }
            })?;
        Ok(Self {
            stop,
            thread: Some(thread),
        })
    }
}

impl Drop for ScaledStepper {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// The frame server: a thread running a small tokio runtime that serves the camera head's
/// frames over TCP (protocol: `ima_video_mux::net_frames`). Grabs from all connections are
/// serialised (one grabber). Stops when dropped.
#[derive(Debug)]
pub struct FrameServer {
    addr: SocketAddr,
    shutdown: Option<tokio::sync::oneshot::Sender<()>>,
    thread: Option<JoinHandle<()>>,
}

impl FrameServer {
    /// Bind `addr` and serve the head `cfg` on `robot` of `world`, reading the channel from
    /// `bus`.
    pub fn spawn(
        addr: SocketAddr,
        cfg: CameraConfig,
        world: SharedWorld,
        robot: crate::world::RobotId,
        bus: VideoBus,
    ) -> std::io::Result<Self> {
        let std_listener = std::net::TcpListener::bind(addr)?;
        std_listener.set_nonblocking(true)?;
        let addr = std_listener.local_addr()?;
        let (tx, rx) = tokio::sync::oneshot::channel::<()>();
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()?;
        let thread = std::thread::Builder::new()
            .name("ima-frame-server".into())
            .spawn(move || {
                rt.block_on(async move {
                    let Ok(listener) = tokio::net::TcpListener::from_std(std_listener) else {
                        return;
                    };
                    let head = Arc::new(tokio::sync::Mutex::new(MockCameraHead::new(
                        cfg, world, robot, bus,
                    )));
                    let accept = async {
                        while let Ok((sock, _)) = listener.accept().await {
                            let _ = sock.set_nodelay(true);
                            tokio::spawn(serve_frames(sock, Arc::clone(&head)));
                        }
                    };
                    tokio::select! {
                        () = accept => {}
                        _ = rx => {}
                    }
                });
            })?;
        Ok(Self {
            addr,
            shutdown: Some(tx),
            thread: Some(thread),
        })
    }

    /// The bound address.
    #[must_use]
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }
}

impl Drop for FrameServer {
    fn drop(&mut self) {
        if let Some(tx) = self.shutdown.take() {
            let _ = tx.send(());
        }
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

async fn serve_frames(
    mut sock: tokio::net::TcpStream,
    head: Arc<tokio::sync::Mutex<MockCameraHead>>,
) {
    let mut req = [0u8; REQUEST_LEN];
    loop {
        if sock.read_exact(&mut req).await.is_err() {
            return;
        }
        if Request::parse(&req).is_err() {
            tracing::debug!("frame server: bad request; closing");
            return;
        }
        let (grabbed, sent) = {
            let mut h = head.lock().await;
            let g = h.grab().await;
            (g, h.now())
        };
        let (header, pixels) = match grabbed {
            Ok(f) => (
                Header {
                    status: Status::Ok,
                    channel: f.value.channel,
                    width: f.value.width,
                    height: f.value.height,
                    exposed_us: f.at.as_micros(),
                    sent_us: sent.as_micros(),
                },
                f.value.pixels,
            ),
            Err(e) => (
                Header {
                    status: match e {
                        CameraError::NoSignal => Status::NoSignal,
                        CameraError::BadChannel(_) => Status::BadChannel,
                    },
                    channel: None,
                    width: 0,
                    height: 0,
                    exposed_us: sent.as_micros(),
                    sent_us: sent.as_micros(),
                },
                Vec::new(),
            ),
        };
        let hb: [u8; HEADER_LEN] = header.emit();
        if sock.write_all(&hb).await.is_err() || sock.write_all(&pixels).await.is_err() {
            return;
        }
    }
}

/// `tcp` free loopback TCP ports and `udp` free loopback UDP ports, all different: each pick
/// stays bound until every one is made (picked one at a time and released at once, two
/// picks could be the same port, and two of a fleet's sockets then fail to bind). They are
/// released on return; another process may take one meanwhile, which only makes the later
/// bind fail with a clear error. For the Peer Agents of a fleet served on one machine.
///
/// # Errors
/// No free port (the system's ephemeral ports are exhausted).
pub fn free_ports(tcp: usize, udp: usize) -> std::io::Result<(Vec<u16>, Vec<u16>)> {
    let listeners = (0..tcp)
        .map(|_| std::net::TcpListener::bind("127.0.0.1:0"))
        .collect::<std::io::Result<Vec<_>>>()?;
    let sockets = (0..udp)
        .map(|_| std::net::UdpSocket::bind("127.0.0.1:0"))
        .collect::<std::io::Result<Vec<_>>>()?;
    let tcp = listeners
        .iter()
        .map(|l| l.local_addr().map(|a| a.port()))
        .collect::<std::io::Result<_>>()?;
    let udp = sockets
        .iter()
        .map(|s| s.local_addr().map(|a| a.port()))
        .collect::<std::io::Result<_>>()?;
    Ok((tcp, udp))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::World;

    #[test]
    fn frame_server_serves_the_selected_camera() {
        let world = SharedWorld::new(World::default_world());
        let sk = world.with(|w| w.robot_id("skeeter")).unwrap();
        let bus = VideoBus::new(None);
        let cfg = CameraConfig::default();
        let srv = FrameServer::spawn(
            SocketAddr::from(([127, 0, 0, 1], 0)),
            cfg,
            world,
            sk,
            bus.clone(),
        )
        .unwrap();
        let mut s = std::net::TcpStream::connect(srv.addr()).unwrap();
        use std::io::{Read, Write};
        s.write_all(&Request::Grab.emit()).unwrap();
        let mut hb = [0u8; HEADER_LEN];
        s.read_exact(&mut hb).unwrap();
        assert_eq!(Header::parse(&hb).unwrap().status, Status::NoSignal);
        bus.switch(1);
        std::thread::sleep(cfg.settle_time + Duration::from_millis(50));
        s.write_all(&Request::Grab.emit()).unwrap();
        s.read_exact(&mut hb).unwrap();
        let h = Header::parse(&hb).unwrap();
        assert_eq!(h.status, Status::Ok);
        assert_eq!((h.width, h.height, h.channel), (320, 240, Some(1)));
        let mut px = vec![0u8; h.payload_len() as usize];
        s.read_exact(&mut px).unwrap();
        let frame = ima_hal::camera::Frame {
            width: 320,
            height: 240,
            channel: Some(1),
            pixels: px,
        };
        // The red object straight ahead of Skeeter is in the middle of channel 1.
        let (col, _) = crate::camera::find_color(&frame, [220, 30, 30], 12).unwrap();
        assert!((col - 160.0).abs() < 2.0, "{col}");
        // A bad request closes the connection.
        s.write_all(b"NOPE!!").unwrap();
        assert_eq!(s.read(&mut hb).unwrap_or(0), 0);
    }

    #[test]
    fn served_world_starts_every_device_and_steps_faster() {
        let world = SharedWorld::new(World::default_world());
        let opts = ServeOptions {
            speed: 4.0,
            ..ServeOptions::default()
        };
        let served = ServedWorld::start(world, &opts).unwrap();
        let e = served.endpoints().clone();
        for p in [
            &e.skeeter.base,
            &e.skeeter.video_mux,
            &e.scooter.base,
            &e.scooter.laser,
            &e.scooter.compass,
        ] {
            assert!(p.exists(), "{}", p.display());
        }
        let start = std::time::Instant::now();
        std::thread::sleep(Duration::from_millis(300));
        let t = served.world().with(|w| w.time());
        let real = start.elapsed();
        // World time is ahead of real time (4× nominal; only "ahead" is asserted).
        assert!(
            t.as_micros() > u64::try_from(real.as_micros()).unwrap(),
            "{t:?} vs {real:?}"
        );
        assert!(
            ServedWorld::start(
                SharedWorld::new(World::default_world()),
                &ServeOptions {
                    speed: 0.0,
                    ..ServeOptions::default()
                }
            )
            .is_err()
        );
    }

    /// The world's `--faults` reach its serial devices (they were parsed and dropped): the
    /// compass, which talks unasked, has its bytes corrupted, and no two devices draw the same
    /// faults.
    #[test]
    fn the_worlds_faults_reach_its_devices() {
        let opts = ServeOptions {
            faults: FaultPlan::parse("corrupt=0.5").unwrap(),
            ..ServeOptions::default()
        };
        let served = ServedWorld::start(SharedWorld::new(World::default_world()), &opts).unwrap();
        let e = served.endpoints().clone();
        // Something must read the compass's pty for its bytes to flow: a thread, so that a
        // silent compass fails the test at its limit instead of hanging it.
        let mut port = std::fs::File::open(&e.scooter.compass).unwrap();
        std::thread::spawn(move || {
            let mut buf = [0u8; 256];
            while std::io::Read::read(&mut port, &mut buf).is_ok_and(|n| n > 0) {}
        });
        let t0 = std::time::Instant::now();
        let mut corrupted = 0;
        while corrupted == 0 && t0.elapsed() < Duration::from_secs(20) {
            std::thread::sleep(Duration::from_millis(20));
            let [.., (_, compass)] = served.links();
            corrupted = compass.counters.robot_to_host.corrupted;
        }
        assert!(corrupted > 0, "no byte of the compass corrupted");
        let [(name, clean), ..] = ServedWorld::start(
            SharedWorld::new(World::default_world()),
            &ServeOptions::default(),
        )
        .unwrap()
        .links();
        assert_eq!(name, "skeeter base");
        assert_eq!(clean.counters.robot_to_host.corrupted, 0);
    }
}

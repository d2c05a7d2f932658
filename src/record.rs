//! `--record FILE.mcap` and `--foxglove [ADDR]`: the process's one recorder (an
//! [`ima_record::Recorder`]), the tap that records a serial port's bytes, the frame source
//! that records camera frames, the HAL decorators that record readings as the runtime reads
//! them, and [`log_event`], which turns the runtimes' events into log lines, the SES scene and
//! — from their periodic detail ([`is_detail`]) — JSON state topics with a JSON Schema
//! (`/san/<robot>`, `/peer/<robot>/status`, `/commander/queue`, `/<robot>/map`).
//!
//! A command starts the recorder with [`start`] from its [`RecordArgs`]; anything may then log
//! through [`with`] (nothing happens when no recorder runs). [`finish`] closes the file and
//! prints what was written; the safety guard ([`crate::safety`]) calls [`finish`] on every way
//! out (done, error, signal, closed stdout, panic), so the file always gets its summary.
//!
//! Hook points elsewhere are marked `// record:` so they can be moved as one.

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::pin::Pin;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, PoisonError, RwLock};
use std::task::{Context, Poll};
use std::time::Duration;

use anyhow::Result;
use clap::Args;
use ima_record::raw::{PortInfo, RawPort};
use ima_record::{Options, Recorder, Report};
use serde_json::{Value, json};
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};

/// The default address of the live view.
pub const DEFAULT_FOXGLOVE: &str = "127.0.0.1:8765";

/// `--record` and `--foxglove`.
#[derive(Debug, Clone, Default, Args)]
pub struct RecordArgs {
    /// Record every device's raw bytes and the decoded readings to this MCAP file (it must not
    /// exist yet).
    #[arg(long, value_name = "FILE.mcap")]
    pub record: Option<PathBuf>,
    /// Serve a live view to Foxglove on this address (WebSocket; default 127.0.0.1:8765,
    /// loopback only unless another address is given).
    /// `ADDR` is `ip:port`, `localhost:port` or a port alone (on 127.0.0.1).
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = DEFAULT_FOXGLOVE,
          value_parser = foxglove_addr)]
    pub foxglove: Option<SocketAddr>,
    /// Camera frames raw (`foxglove.RawImage`, rgb8; the file's zstd compresses them as well
    /// as PNG would) or as PNG (`foxglove.CompressedImage`, compressed on the recorder's
    /// thread; lighter on a live link, more CPU).
    #[arg(long, value_enum, value_name = "FORMAT", default_value_t = ImageFormat::Raw)]
    pub record_images: ImageFormat,
    /// Leave topics out of the file (repeatable): a topic path whose segments may be `*`,
    /// matching every topic below it, e.g. `/*/camera` (every camera: four fifths of the
    /// demo's recorded bytes) or `/scooter/serial/laser` (one raw port, which then cannot be
    /// replayed). A live view still shows them.
    #[arg(long, value_name = "TOPIC", requires = "record")]
    pub record_exclude: Vec<ima_record::filter::TopicPattern>,
}

/// `--record-images`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum ImageFormat {
    /// `foxglove.RawImage`, rgb8.
    #[default]
    Raw,
    /// PNG in `foxglove.CompressedImage`.
    Png,
}

/// A `--foxglove` address: `ip:port` (`0.0.0.0:8765` to serve every interface),
/// `localhost:port` or a port alone, both on 127.0.0.1.
///
/// # Errors
/// A message naming the accepted forms.
pub fn foxglove_addr(s: &str) -> Result<SocketAddr, String> {
    // The URL this program prints for the live view (`ws://127.0.0.1:8765`) is taken too.
    let s = s.trim();
    let s = s.strip_prefix("ws://").unwrap_or(s);
    let s = s.strip_suffix('/').unwrap_or(s);
    crate::web::socket_addr(s).ok_or_else(|| {
        // `ima replay rec.mcap` typed as `ima replay --foxglove rec.mcap`: the optional
        // address took the file.
        let file = s.ends_with(".mcap") || s.contains('/') || Path::new(s).is_file();
        let hint = if file {
            format!(
                "; {s:?} looks like a file: a recording to replay goes before --foxglove \
                 (`ima replay {s} --foxglove`), a file to write is `--record {s}`"
            )
        } else {
            String::new()
        };
        format!(
            "not an address such as {DEFAULT_FOXGLOVE}, localhost:8765, 0.0.0.0:8765 \
             (every interface) or a port alone (8765){hint}"
        )
    })
}

impl RecordArgs {
    /// Neither asked for.
    pub fn is_off(&self) -> bool {
        self.record.is_none() && self.foxglove.is_none()
    }
}

fn current() -> &'static RwLock<Option<Recorder>> {
    static CURRENT: RwLock<Option<Recorder>> = RwLock::new(None);
    &CURRENT
}

/// Port path → robot name, for the raw channels' topics.
fn robots() -> &'static RwLock<Vec<(String, String)>> {
    static ROBOTS: RwLock<Vec<(String, String)>> = RwLock::new(Vec::new());
    &ROBOTS
}

/// Start the recorder `args` ask for (none: nothing). `name` names the session.
pub fn start(args: &RecordArgs, name: &str) -> Result<()> {
    if args.is_off() {
        return Ok(());
    }
    if let Some(p) = &args.record {
        // `-` is stdin or stdout elsewhere (`ima decode`); here it made a file named `-`.
        anyhow::ensure!(
            p.as_os_str() != "-",
            "--record -: a recording is written to a file (an MCAP file ends with an index of \
             what it holds); name one, e.g. --record run.mcap"
        );
        // Looked at before `check_file` opens it to test it: opening a FIFO for writing waits
        // for a reader, and a serial port (`--record` typed for `--port`) may wait for its
        // carrier and toggles its modem lines.
        let what = match std::fs::metadata(p) {
            Ok(m) if m.is_file() => Some("the file exists (a recording never overwrites one)"),
            Ok(m) if m.is_dir() => None, // said by `check_file`
            Ok(_) => Some("not a regular file (a recording is written to a new file)"),
            Err(_) => None,
        };
        if let Some(what) = what {
            anyhow::bail!("--record {}: {what}", p.display());
        }
        crate::cmd::output::check_file("--record", p)?;
    }
    let rec = Recorder::start(&Options {
        mcap: args.record.clone(),
        foxglove: args.foxglove,
        queue: 0,
        name: name.to_owned(),
        images: match args.record_images {
            ImageFormat::Png => ima_record::Images::Png,
            ImageFormat::Raw => ima_record::Images::Raw,
        },
        exclude: ima_record::filter::TopicFilter::new(args.record_exclude.clone()),
    })?;
    if let Some(port) = rec.server_port() {
        let bound = args
            .foxglove
            .map_or(std::net::Ipv4Addr::LOCALHOST.into(), |a| a.ip());
        // A URL a client can open: every address (`0.0.0.0`, `[::]`) by its loopback one.
        let ip = match bound {
            std::net::IpAddr::V4(a) if a.is_unspecified() => std::net::Ipv4Addr::LOCALHOST.into(),
            std::net::IpAddr::V6(a) if a.is_unspecified() => std::net::Ipv6Addr::LOCALHOST.into(),
            ip => ip,
        };
        let url = std::net::SocketAddr::new(ip, port);
        eprintln!("ima: live view for Foxglove on ws://{url} (open docs/foxglove-layout.json)");
        if !bound.is_loopback() {
            eprintln!(
                "ima: warning: the live view is served on {bound}, beyond loopback, with no \
                 token: anyone who can reach this machine there can watch the robot (from \
                 another machine, use this machine's address)"
            );
        }
    }
    *current().write().unwrap_or_else(PoisonError::into_inner) = Some(rec);
    Ok(())
}

/// Where each robot started in `map` (metres), when a simulated world says so: a robot's
/// dead-reckoned belief, measured from its start in the compass's east-north-up axes, is
/// placed in `map` by it.
fn starts() -> &'static RwLock<BTreeMap<String, (f64, f64)>> {
    static STARTS: std::sync::OnceLock<RwLock<BTreeMap<String, (f64, f64)>>> =
        std::sync::OnceLock::new();
    STARTS.get_or_init(Default::default)
}

/// Say where `robot` started in `map` (the demo's world): its `/<robot>/belief` is then
/// recorded in `map` (without it, in `map` too, measured from the start: a real robot's
/// `ima run` has no other frame for it).
pub fn set_start(robot: &str, x_m: f64, y_m: f64) {
    starts()
        .write()
        .unwrap_or_else(PoisonError::into_inner)
        .insert(robot.to_owned(), (x_m, y_m));
}

/// The `foxglove.Log` level of a stack event, so a Log panel can show the failures alone: a
/// failed target, a fleet stop, a robot lost, a refused operator request, frames under
/// another key, a lost link or subscription and lost events are warnings; the rest is
/// information.
fn event_level(kind: &ima_agents::runtime::EventKind) -> ima_record::messages::log::Level {
    use ima_agents::runtime::EventKind;
    use ima_agents::runtime::events::PeerNote;
    use ima_record::messages::log::Level;
    let warning = match kind {
        EventKind::Target(t) => t.state == "failed",
        EventKind::Robot { state, .. } => state == "lost",
        EventKind::FleetStop { .. }
        | EventKind::Operator { .. }
        | EventKind::AuthFailure(_)
        | EventKind::Lagged { .. }
        | EventKind::Peer(PeerNote::Lost { .. } | PeerNote::Retry { .. }) => true,
        EventKind::Fleet { command, .. } => command == "stop",
        _ => false,
    };
    if warning { Level::Warning } else { Level::Info }
}

/// The fixed frames of a robot alone in a command (`ima drive`, `ima scan`, `ima run`), so
/// that a viewer that follows `map` (the shipped layout) can place it: `map` →
/// `<robot>/odom` at the origin, `<robot>/odom` → `<robot>/base_link` at the origin when nothing gives the robot's
/// odometry (a scanner alone), and `<robot>/base_link` → `<robot>/laser` with a `laser`. At
/// most once a second of the recording's clock (for viewers that join late or seek), whatever
/// the caller's rate.
pub fn log_fixed_frames(r: &Recorder, robot: &str, odometry: bool, laser: bool) {
    log_fixed_frames_at(
        r,
        robot,
        ima_record::convert::Pose2::default(),
        odometry,
        laser,
    );
}

/// [`log_fixed_frames`] with `<robot>/odom` at `origin` in `map` (where the odometry was
/// reset, as in `ima demo square`).
pub fn log_fixed_frames_at(
    r: &Recorder,
    robot: &str,
    origin: ima_record::convert::Pose2,
    odometry: bool,
    laser: bool,
) {
    static LAST: std::sync::Mutex<BTreeMap<String, u64>> = std::sync::Mutex::new(BTreeMap::new());
    {
        let now = r.now_ns();
        let mut last = LAST.lock().unwrap_or_else(PoisonError::into_inner);
        if last
            .get(robot)
            .is_some_and(|&t| t <= now && now - t < 1_000_000_000)
        {
            return;
        }
        last.insert(robot.to_owned(), now);
    }
    let at_origin = ima_record::convert::Pose2::default();
    let (odom, base) = (format!("{robot}/odom"), format!("{robot}/base_link"));
    r.log_odom_origin(robot, origin);
    if !odometry {
        r.log_transform(&odom, &base, at_origin);
    }
    if laser {
        r.log_transform(&base, &format!("{robot}/laser"), at_origin);
    }
}

/// Use the recorder, if one runs.
pub fn with(f: impl FnOnce(&Recorder)) {
    if let Some(r) = &*current().read().unwrap_or_else(PoisonError::into_inner) {
        // Counted as the recording's work on the caller's thread (`Report::calls_time`).
        r.timed(f);
    }
}

/// Wait while the recorder's queue is half full ([`Recorder::has_room`]), waking its thread:
/// for a producer that may outpace it (a replay as fast as possible), which must not make it
/// drop messages. Returns at once when nothing records.
pub async fn room() {
    loop {
        let mut full = false;
        with(|r| full = !r.has_room());
        if !full {
            return;
        }
        tokio::time::sleep(Duration::from_millis(1)).await;
    }
}

/// Finish the recording (if any): close the file, stop the server, print one line to stderr.
/// Callers racing each other (the command's guard, the signal thread before its forced exit)
/// all wait until the file is closed; the line is printed once.
pub fn finish() -> Option<Report> {
    static PRINTED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);
    let rec = current()
        .read()
        .unwrap_or_else(PoisonError::into_inner)
        .clone()?;
    // Serialised inside the recorder: a second caller waits for the first's report.
    let report = rec.finish(Duration::from_secs(5));
    *current().write().unwrap_or_else(PoisonError::into_inner) = None;
    if !PRINTED.swap(true, std::sync::atomic::Ordering::SeqCst) {
        *last().write().unwrap_or_else(PoisonError::into_inner) = Some(report.clone());
        eprintln!("ima: {}", report.summary());
    }
    Some(report)
}

fn last() -> &'static RwLock<Option<Report>> {
    static LAST: RwLock<Option<Report>> = RwLock::new(None);
    &LAST
}

/// The report of the finished recording, if one finished.
pub fn last_report() -> Option<Report> {
    last()
        .read()
        .unwrap_or_else(PoisonError::into_inner)
        .clone()
}

/// `Err` when the finished recording's file could not be written to its end (disk full,
/// device gone): the command's data was not all kept, so it does not end with success.
pub fn check_written() -> Result<()> {
    match last_report() {
        Some(Report {
            path: Some(path),
            error: Some(e),
            ..
        }) => anyhow::bail!(
            "the recording to {} is incomplete ({e}); `ima replay` reads what it holds",
            path.display()
        ),
        _ => Ok(()),
    }
}

/// Name the robot whose devices are on `ports` (so their raw channels are
/// `/<robot>/serial/<device>`).
pub fn label_ports<'a>(robot: &str, ports: impl IntoIterator<Item = &'a str>) {
    let mut m = robots().write().unwrap_or_else(PoisonError::into_inner);
    for p in ports {
        m.retain(|(port, _)| port != p);
        m.push((p.to_owned(), robot.to_owned()));
    }
}

/// Wrap a serial port so its bytes are recorded (a pass-through when no recorder runs).
/// `device` is `base`, `laser`, `compass` or `video_mux`; `protocol` the protocol spoken.
pub fn tap<S>(stream: S, device: &str, port: &str, baud: u32, protocol: &str) -> Tap<S> {
    tap_with(stream, device, port, baud, protocol, BTreeMap::new())
}

/// [`tap`] with the driver's parameters a replay needs to re-decode the bytes as it did
/// (`time_scale`, an rFLEX's `kd` and `ka`, a P2OS robot's `params` table when the driver was
/// told one), in the channel's metadata.
pub fn tap_with<S>(
    stream: S,
    device: &str,
    port: &str,
    baud: u32,
    protocol: &str,
    params: BTreeMap<String, String>,
) -> Tap<S> {
    let mut raw = None;
    with(|r| {
        let robot = robots()
            .read()
            .unwrap_or_else(PoisonError::into_inner)
            .iter()
            .find(|(p, _)| p == port)
            .map_or_else(|| "robot".to_owned(), |(_, r)| r.clone());
        raw = Some(r.raw_port(PortInfo {
            robot,
            device: device.to_owned(),
            port: port.to_owned(),
            baud,
            protocol: protocol.to_owned(),
            params,
        }));
    });
    Tap { inner: stream, raw }
}

/// A serial stream whose bytes, both ways, go to the recorder.
#[derive(Debug)]
pub struct Tap<S> {
    inner: S,
    raw: Option<RawPort>,
}

impl<S: AsyncRead + Unpin> AsyncRead for Tap<S> {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<std::io::Result<()>> {
        let before = buf.filled().len();
        let r = Pin::new(&mut self.inner).poll_read(cx, buf);
        if let (Poll::Ready(Ok(())), Some(raw)) = (&r, &self.raw) {
            raw.rx(buf.filled().get(before..).unwrap_or_default());
        }
        r
    }
}

impl<S: AsyncWrite + Unpin> AsyncWrite for Tap<S> {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        data: &[u8],
    ) -> Poll<std::io::Result<usize>> {
        let r = Pin::new(&mut self.inner).poll_write(cx, data);
        if let (Poll::Ready(Ok(n)), Some(raw)) = (&r, &self.raw) {
            raw.tx(data.get(..*n).unwrap_or_default());
        }
        r
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.inner).poll_flush(cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.inner).poll_shutdown(cx)
    }
}

/// One `BaudControl` (`ima_serial`) for every driver: line-speed changes are recorded too.
impl<S: ima_serial::BaudControl> ima_serial::BaudControl for Tap<S> {
    fn set_baud(&mut self, baud: u32) -> std::io::Result<()> {
        self.inner.set_baud(baud)?;
        if let Some(raw) = &self.raw {
            raw.baud(baud);
        }
        Ok(())
    }

    fn clear_input(&mut self) -> std::io::Result<()> {
        self.inner.clear_input()
    }
}

/// A frame source whose frames go to the recorder as `foxglove.RawImage`.
#[derive(Debug)]
pub struct RecordedFrames<F> {
    inner: F,
    robot: String,
    /// Where to copy the source's own frame counter after each frame (see
    /// [`RecordedFrames::counting`]).
    count: Option<FrameCounter<F>>,
    /// Where the head's cameras look (see [`RecordedFrames::mounted`]).
    head: Option<ima_agents::mission::vision::HeadGeometry>,
}

/// Where a frame source's own counter is copied, and how it is read.
type FrameCounter<F> = (Arc<AtomicU64>, fn(&F) -> u64);

/// Record the frames `inner` gives, as `robot`'s camera.
pub fn frames<F>(inner: F, robot: &str) -> RecordedFrames<F> {
    RecordedFrames {
        inner,
        robot: robot.to_owned(),
        count: None,
        head: None,
    }
}

impl<F> RecordedFrames<F> {
    /// After each frame, copy the source's own counter (`read`, e.g. the frame client's
    /// frames received) into `into`, so it can be read while the runtime owns the source.
    #[must_use]
    pub fn counting(mut self, into: Arc<AtomicU64>, read: fn(&F) -> u64) -> Self {
        self.count = Some((into, read));
        self
    }

    /// Record with each frame where its camera looks (its optical frame on `/tf` and its
    /// calibration, [`Recorder::log_camera_mount`]), from the head geometry the robot's vision
    /// uses: a 3-D view places the images (without it, their frame had no transform).
    #[must_use]
    pub fn mounted(mut self, head: ima_agents::mission::vision::HeadGeometry) -> Self {
        self.head = Some(head);
        self
    }
}

impl<F: ima_hal::ErrorType> ima_hal::ErrorType for RecordedFrames<F> {
    type Error = F::Error;
}

impl<F: ima_hal::camera::FrameSource + Send> ima_hal::camera::FrameSource for RecordedFrames<F> {
    async fn grab(&mut self) -> Result<ima_hal::Stamped<ima_hal::camera::Frame>, Self::Error> {
        let f = self.inner.grab().await?;
        if let Some((into, read)) = &self.count {
            into.store(read(&self.inner), Ordering::Relaxed);
        }
        with(|r| {
            let frame = &f.value;
            if let Some(head) = &self.head {
                let mount = ima_record::convert::CameraMount {
                    channel: frame.channel,
                    yaw_rad: (frame.channel)
                        .and_then(|c| head.camera_yaw_rad(c))
                        .unwrap_or(0.0),
                    hfov_rad: head.fov_rad(),
                    width: frame.width,
                    height: frame.height,
                };
                r.log_camera_mount(&self.robot, &mount);
            }
            r.log_image(&self.robot, frame);
        });
        Ok(f)
    }
}

/// A HAL device whose readings go to the recorder as the runtime reads them (each stamp
/// once): scans as `foxglove.LaserScan`, odometry as the `odom → base_link` transform,
/// headings on the compass topic. Commands pass through untouched.
#[derive(Debug)]
pub struct Recorded<T> {
    inner: T,
    robot: String,
    last: Option<ima_hal::Instant>,
    /// Readings read (each stamp once), counted whether or not a recorder runs.
    read: Option<Arc<AtomicU64>>,
}

impl<T> Recorded<T> {
    /// Record what `inner` reads, as `robot`'s.
    pub fn new(inner: T, robot: &str) -> Self {
        Self {
            inner,
            robot: robot.to_owned(),
            last: None,
            read: None,
        }
    }

    /// Count the readings the runtime reads (each stamp once: exactly the messages this
    /// decorator logs) in `into`.
    #[must_use]
    pub fn counting(mut self, into: Arc<AtomicU64>) -> Self {
        self.read = Some(into);
        self
    }

    /// Whether `at` is a reading not yet recorded.
    fn fresh(&mut self, at: ima_hal::Instant) -> bool {
        let fresh = self.last != Some(at);
        self.last = Some(at);
        if fresh && let Some(n) = &self.read {
            n.fetch_add(1, Ordering::Relaxed);
        }
        fresh
    }
}

impl<T: ima_hal::ErrorType> ima_hal::ErrorType for Recorded<T> {
    type Error = T::Error;
}

impl<T: ima_hal::laser::LaserScanner + Send> ima_hal::laser::LaserScanner for Recorded<T> {
    fn description(&self) -> ima_hal::laser::LaserDescription {
        self.inner.description()
    }

    async fn scan(&mut self) -> Result<ima_hal::Stamped<ima_hal::laser::LaserScan>, Self::Error> {
        let s = self.inner.scan().await?;
        if self.fresh(s.at) {
            with(|r| r.log_scan(&self.robot, &s.value));
        }
        Ok(s)
    }

    async fn next_scan(
        &mut self,
        after: ima_hal::Instant,
    ) -> Result<ima_hal::Stamped<ima_hal::laser::LaserScan>, Self::Error> {
        let s = self.inner.next_scan(after).await?;
        if self.fresh(s.at) {
            with(|r| r.log_scan(&self.robot, &s.value));
        }
        Ok(s)
    }
}

impl<T: ima_hal::compass::Compass + Send> ima_hal::compass::Compass for Recorded<T> {
    async fn heading(
        &mut self,
    ) -> Result<ima_hal::Stamped<ima_hal::compass::Heading>, Self::Error> {
        let h = self.inner.heading().await?;
        if self.fresh(h.at) {
            with(|r| r.log_compass(&self.robot, h.value.yaw_enu_rad()));
        }
        Ok(h)
    }

    async fn next_heading(
        &mut self,
        after: ima_hal::Instant,
    ) -> Result<ima_hal::Stamped<ima_hal::compass::Heading>, Self::Error> {
        let h = self.inner.next_heading(after).await?;
        if self.fresh(h.at) {
            with(|r| r.log_compass(&self.robot, h.value.yaw_enu_rad()));
        }
        Ok(h)
    }
}

impl<T: ima_hal::base::DifferentialBase + Send> ima_hal::base::DifferentialBase for Recorded<T> {
    fn limits(&self) -> ima_hal::base::BaseLimits {
        self.inner.limits()
    }

    async fn enable_motors(&mut self, enable: bool) -> Result<(), Self::Error> {
        self.inner.enable_motors(enable).await
    }

    async fn set_velocity(
        &mut self,
        cmd: ima_hal::base::VelocityCommand,
    ) -> Result<(), Self::Error> {
        self.inner.set_velocity(cmd).await
    }

    async fn stop(&mut self) -> Result<(), Self::Error> {
        self.inner.stop().await
    }

    async fn emergency_stop(&mut self) -> Result<(), Self::Error> {
        self.inner.emergency_stop().await
    }
}

impl<T: ima_hal::base::Odometer + Send> ima_hal::base::Odometer for Recorded<T> {
    async fn odometry(&mut self) -> Result<ima_hal::Stamped<ima_hal::base::Odometry>, Self::Error> {
        let o = self.inner.odometry().await?;
        if self.fresh(o.at) {
            with(|r| {
                r.log_odometry(
                    &self.robot,
                    ima_record::convert::Pose2::from_isometry(&o.value.pose),
                );
            });
        }
        Ok(o)
    }

    async fn next_odometry(
        &mut self,
        after: ima_hal::Instant,
    ) -> Result<ima_hal::Stamped<ima_hal::base::Odometry>, Self::Error> {
        let o = self.inner.next_odometry(after).await?;
        if self.fresh(o.at) {
            with(|r| {
                r.log_odometry(
                    &self.robot,
                    ima_record::convert::Pose2::from_isometry(&o.value.pose),
                );
            });
        }
        Ok(o)
    }

    async fn reset_odometry(&mut self) -> Result<(), Self::Error> {
        self.inner.reset_odometry().await
    }
}

/// Whether a recorder runs (the runtimes then report their detail: see [`is_detail`]).
pub fn active() -> bool {
    current()
        .read()
        .unwrap_or_else(PoisonError::into_inner)
        .is_some()
}

/// Whether `kind` is the periodic detail a live console or a recording asks for
/// ([`ima_agents::runtime::Events::detailed`]): the commander's series, a SAN's state,
/// Scooter's map, Peer Agent status. Commands that turn the detail on only for the recording
/// leave these events out of their own output.
pub fn is_detail(kind: &ima_agents::runtime::EventKind) -> bool {
    use ima_agents::runtime::EventKind;
    matches!(
        kind,
        EventKind::Queue { .. } | EventKind::San(_) | EventKind::Map(_) | EventKind::PeerStatus(_)
    )
}

/// A module or condition name as a JSON key usable in a Foxglove message path
/// (`/san/scooter.activation.move_to_target`): `-` becomes `_`.
fn path_key(name: &str) -> String {
    name.replace('-', "_")
}

/// The JSON Schema of `/san/<robot>` for a network with `modules`.
fn san_schema(modules: &[String]) -> Value {
    let per_module = |t: &str| -> serde_json::Map<String, Value> {
        modules
            .iter()
            .map(|m| (path_key(m), json!({"type": t})))
            .collect()
    };
    json!({
        "title": "ima.SanState",
        "description": "A robot's spreading activation network: each module's activation and \
            executable flag (also by module name, '-' as '_'), the threshold, each \
            condition's truth, and the selected behaviour.",
        "type": "object",
        "properties": {
            "t_s": {"type": "number", "description": "mission seconds"},
            "robot": {"type": "string"},
            "network": {"type": "string"},
            "selected": {"type": "string", "description": "the selected behaviour"},
            "threshold": {"type": "number"},
            "activation": {"type": "object", "properties": per_module("number")},
            "executable": {"type": "object", "properties": per_module("boolean")},
            "modules": {"type": "array", "items": {"type": "object", "properties": {
                "name": {"type": "string"}, "activation": {"type": "number"},
                "executable": {"type": "boolean"}}}},
            "conditions": {"type": "array", "items": {"type": "object", "properties": {
                "name": {"type": "string"}, "value": {"type": "boolean"}}}},
        },
    })
}

/// The JSON Schema of `/peer/<robot>/status`.
fn peer_schema() -> Value {
    let int = json!({"type": "integer"});
    let rejects = json!({"type": "object", "properties": {
        "truncated": int, "bad_magic": int, "bad_version": int, "oversize": int,
        "bad_mac": int, "replay": int, "malformed": int}});
    json!({
        "title": "ima.PeerStatus",
        "description": "Peer Agent status: the broadcast channel's counters; for a manager, \
            its sources, its clients with their requested and granted sources, its links' \
            health, sessions and counters; for a client, its link to the other manager.",
        "type": "object",
        "properties": {
            "t_s": {"type": "number", "description": "mission seconds"},
            "robot": {"type": "string"},
            "address": {"type": ["string", "null"], "description": "where the manager listens"},
            "broadcast": {"type": "object", "properties": {
                "accepted": int, "duplicate": int, "stale": int, "sent": int,
                "send_errors": int, "rejected": rejects}},
            "sources": {"type": "array", "items": {"type": "object", "properties": {
                "name": {"type": "string"}, "kind": {"type": "string"}, "rate_mhz": int}}},
            "clients": {"type": "array", "items": {"type": "object", "properties": {
                "client": int, "robot": {"type": "string"},
                "requesting": {"type": "array", "items": {"type": "string"}},
                "granted": {"type": "array", "items": {"type": "string"}}}}},
            "links": {"type": "array", "items": {"type": "object", "properties": {
                "session": int, "addr": {"type": "string"},
                "robots": {"type": "array", "items": {"type": "string"}},
                "frames_received": int, "heartbeats_received": int, "heartbeats_sent": int,
                "last_seen_ms": int, "open_ms": int}}},
            "client": {"type": ["object", "null"], "description": "this robot's own client of another \
                manager (Scooter's of Skeeter's ses source)", "properties": {
                "manager": {"type": "string"}, "source": {"type": "string"},
                "outcome": {"type": "string"}, "priority": int, "grants": int,
                "retries": int, "samples": int, "link": {"type": ["object", "null"], "properties": {
                    "registration": {"type": "string"}, "frames_received": int,
                    "heartbeats_received": int, "heartbeats_sent": int, "last_seen_ms": int,
                    "open_ms": int}}}},
            "sessions": int, "data_sessions": int, "task_priority": int, "lost": int,
            "closed_bad": int, "slow_closed": int, "lagged_samples": int,
            "data_bad_tickets": int, "rejected": rejects, "data_rejected": rejects,
        },
    })
}

/// The JSON Schema of `/commander/queue`.
fn queue_schema() -> Value {
    let num = json!({"type": "number"});
    // Times not reached yet are null.
    let maybe = json!({"type": ["number", "null"]});
    json!({
        "title": "ima.TargetQueue",
        "description": "The commander's series of targets, after each change.",
        "type": "object",
        "properties": {
            "t_s": num, "robot": {"type": "string"},
            "targets": {"type": "array", "items": {"type": "object", "properties": {
                "index": {"type": "integer"}, "target": {"type": "string"},
                "state": {"type": "string"}, "sent_s": maybe, "accepted_s": maybe,
                "ended_s": maybe, "time_s": maybe, "cancelled": {"type": "boolean"},
                "given_up": {"type": "boolean"}, "sends": {"type": "integer"}}}},
        },
    })
}

/// The JSON Schema of `/<robot>/map`.
fn map_schema() -> Value {
    let num = json!({"type": "number"});
    json!({
        "title": "ima.ScooterMap",
        "description": "Scooter's belief: dead-reckoned position, heading, desired heading, \
            plan, remembered laser obstacles (DR frame, metres) and target.",
        "type": "object",
        "properties": {
            "t_s": num, "robot": {"type": "string"},
            "dr": {"type": "array", "items": num},
            // What Scooter does not know yet is null.
            "heading_rad": {"type": ["number", "null"]},
            "desired_rad": {"type": ["number", "null"]},
            "plan": {"type": ["object", "null"], "properties": {
                "heading_rad": num, "point": {"type": "array", "items": num}}},
            "obstacles": {"type": "array", "items": {"type": "array", "items": num}},
            "target": {"type": ["string", "null"]},
        },
    })
}

/// A module name as a JSON key of [`san_schema`] (`-` as `_`), written without a `String`.
struct PathKey<'a>(&'a str);

impl serde::Serialize for PathKey<'_> {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        struct Key<'a>(&'a str);
        impl std::fmt::Display for Key<'_> {
            fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                for part in self.0.split('-').enumerate() {
                    if part.0 > 0 {
                        f.write_str("_")?;
                    }
                    f.write_str(part.1)?;
                }
                Ok(())
            }
        }
        s.collect_str(&Key(self.0))
    }
}

/// A SAN's state as the JSON of [`san_schema`]: the view, the event's time and robot, and
/// each module's activation and executable flag by name. Serialised straight into the
/// recorder's queue (no JSON tree is built).
struct SanJson<'a> {
    e: &'a ima_agents::runtime::Event,
    v: &'a ima_agents::runtime::events::SanView,
}

impl serde::Serialize for SanJson<'_> {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeMap;
        let v = self.v;
        let mut m = s.serialize_map(None)?;
        m.serialize_entry("network", &v.network)?;
        m.serialize_entry("modules", &v.modules)?;
        m.serialize_entry("threshold", &v.threshold)?;
        m.serialize_entry("conditions", &v.conditions)?;
        m.serialize_entry("selected", &v.selected)?;
        m.serialize_entry("t_s", &self.e.t_s)?;
        m.serialize_entry("robot", &self.e.robot)?;
        m.serialize_entry("activation", &ByModule(&v.modules, |m| m.activation))?;
        m.serialize_entry("executable", &ExecByModule(&v.modules))?;
        m.end()
    }
}

/// `{module: activation}` of [`SanJson`].
struct ByModule<'a>(
    &'a [ima_agents::runtime::events::SanModuleView],
    fn(&ima_agents::runtime::events::SanModuleView) -> f64,
);

impl serde::Serialize for ByModule<'_> {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_map(self.0.iter().map(|m| (PathKey(&m.name), (self.1)(m))))
    }
}

/// `{module: executable}` of [`SanJson`].
struct ExecByModule<'a>(&'a [ima_agents::runtime::events::SanModuleView]);

impl serde::Serialize for ExecByModule<'_> {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_map(self.0.iter().map(|m| (PathKey(&m.name), m.executable)))
    }
}

/// A detail value with the event's time and robot beside its own fields.
#[derive(serde::Serialize)]
struct WithStamp<'a, T: serde::Serialize> {
    t_s: f64,
    robot: &'a str,
    #[serde(flatten)]
    v: T,
}

/// The `/events` line of an event: its kind's name, then its detail as JSON (`null` when it
/// has none), written into `out`.
fn event_line(kind: &ima_agents::runtime::EventKind, out: &mut String) {
    // The kind serialises as `{"kind":"<name>","detail":<detail>}` (adjacently tagged): keep
    // the detail's text as it is written, instead of building a JSON tree to pick it out.
    let json = serde_json::to_string(kind).unwrap_or_default();
    let name = kind.name();
    let head = format!("{{\"kind\":\"{name}\"");
    out.clear();
    out.push_str(name);
    out.push(' ');
    match json.strip_prefix(&head) {
        Some("}") => out.push_str("null"),
        Some(rest) => match rest
            .strip_prefix(",\"detail\":")
            .and_then(|d| d.strip_suffix('}'))
        {
            Some(detail) => out.push_str(detail),
            None => out.push_str(&json),
        },
        None => out.push_str(&json),
    }
}

/// Record a runtime event: every event but the periodic detail as a line on `/events`,
/// broadcasts said on the broadcast log, Skeeter's published SES as the dome, Scooter's
/// belief (dead-reckoned position and heading, from its control reports) as a pose in `map`,
/// and the detail ([`is_detail`]) as JSON state topics: `/san/<robot>`,
/// `/peer/<robot>/status`, `/commander/queue`, `/<robot>/map`. The state is serialised
/// straight into the recorder's queue.
pub fn log_event(e: &ima_agents::runtime::Event) {
    use ima_agents::runtime::EventKind;
    with(|r| {
        match &e.kind {
            EventKind::San(v) => {
                let names = || v.modules.iter().map(|m| m.name.clone()).collect::<Vec<_>>();
                let topic = format!("/san/{}", e.robot);
                let json = SanJson { e, v };
                return r.log_json(&topic, "ima.SanState", || san_schema(&names()), &json);
            }
            EventKind::PeerStatus(p) => {
                let v = WithStamp {
                    t_s: e.t_s,
                    robot: &e.robot,
                    v: crate::web::feed::PeerStatusJson(p),
                };
                let topic = format!("/peer/{}/status", e.robot);
                return r.log_json(&topic, "ima.PeerStatus", peer_schema, &v);
            }
            EventKind::Queue { targets } => {
                #[derive(serde::Serialize)]
                struct Targets<'a> {
                    targets: &'a [ima_agents::runtime::events::QueueEntry],
                }
                let v = WithStamp {
                    t_s: e.t_s,
                    robot: &e.robot,
                    v: Targets { targets },
                };
                return r.log_json("/commander/queue", "ima.TargetQueue", queue_schema, &v);
            }
            EventKind::Map(m) => {
                let topic = format!("/{}/map", e.robot);
                let v = WithStamp {
                    t_s: e.t_s,
                    robot: &e.robot,
                    v: m,
                };
                return r.log_json(&topic, "ima.ScooterMap", map_schema, &v);
            }
            _ => {}
        }
        thread_local! {
            static LINE: std::cell::RefCell<String> = const { std::cell::RefCell::new(String::new()) };
        }
        let log_line = |line: &mut String| {
            event_line(&e.kind, line);
            r.log_text("/events", event_level(&e.kind), &e.robot, line);
        };
        // The thread's line buffer, or a fresh one if it is in use or gone (thread exit).
        let _ = LINE
            .try_with(|cell| match cell.try_borrow_mut() {
                Ok(mut line) => log_line(&mut line),
                Err(_) => log_line(&mut String::new()),
            })
            .map_err(|_| log_line(&mut String::new()));
        match &e.kind {
            EventKind::Say(text) => r.log_broadcast(&e.robot, text),
            EventKind::SesPublished { marks } => {
                let marks: Vec<ima_record::convert::SesMark> = marks
                    .iter()
                    .map(|m| ima_record::convert::SesMark {
                        azimuth_rad: m.azimuth_rad,
                        elevation_rad: m.elevation_rad,
                        tag: m.tag.clone(),
                    })
                    .collect();
                r.log_ses(&e.robot, &marks);
            }
            EventKind::Control(c) => {
                let (x0, y0) = starts()
                    .read()
                    .unwrap_or_else(PoisonError::into_inner)
                    .get(&e.robot)
                    .copied()
                    .unwrap_or_default();
                r.log_pose(
                    &format!("/{}/belief", e.robot),
                    "map",
                    ima_record::convert::Pose2 {
                        x_m: x0 + c.dr[0],
                        y_m: y0 + c.dr[1],
                        theta_rad: c.heading_rad.unwrap_or(0.0),
                    },
                );
            }
            _ => {}
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};

    fn event(kind: ima_agents::runtime::EventKind) -> ima_agents::runtime::Event {
        ima_agents::runtime::Event {
            t_s: 12.5,
            robot: "scooter".into(),
            kind,
        }
    }

    /// Failures are warnings in the Log panels (every event was INFO).
    #[test]
    fn failures_are_logged_as_warnings() {
        use ima_agents::runtime::EventKind;
        use ima_agents::runtime::events::TargetChange;
        use ima_record::messages::log::Level;
        let target = |state: &str| {
            EventKind::Target(TargetChange {
                target: "red".into(),
                state: state.into(),
                time_s: None,
                given_up: None,
                cancelled: None,
            })
        };
        assert_eq!(event_level(&target("failed")), Level::Warning);
        assert_eq!(event_level(&target("done")), Level::Info);
        let stop = EventKind::FleetStop {
            by: "commander".into(),
            reason: "test".into(),
        };
        assert_eq!(event_level(&stop), Level::Warning);
        assert_eq!(
            event_level(&EventKind::Behaviour("scan".into())),
            Level::Info
        );
    }

    /// What the state topics held when they were built as JSON trees: the typed
    /// serialisation must write the same objects.
    fn stamped_tree(e: &ima_agents::runtime::Event, mut v: Value) -> Value {
        v["t_s"] = json!(e.t_s);
        v["robot"] = json!(e.robot);
        v
    }

    /// `localhost:8766` and a port alone were refused as "invalid socket address syntax"
    /// (while `--web` took `localhost:PORT`).
    #[test]
    fn foxglove_addresses_take_localhost_and_a_port_alone() {
        let ok = |s: &str| foxglove_addr(s).unwrap().to_string();
        assert_eq!(ok("localhost:8766"), "127.0.0.1:8766");
        assert_eq!(ok("8766"), "127.0.0.1:8766");
        assert_eq!(ok(" 0.0.0.0:8765 "), "0.0.0.0:8765");
        assert_eq!(ok("[::1]:9000"), "[::1]:9000");
        for bad in [
            "",
            "localhost",
            "localhost:99999",
            "99999",
            "example.org:80",
            "1.2.3:4",
        ] {
            let e = foxglove_addr(bad).unwrap_err();
            assert!(e.contains("localhost:8765"), "{bad:?}: {e}");
            assert!(!e.contains("looks like a file"), "{bad:?}: {e}");
        }
        // The file of `ima replay --foxglove rec.mcap`, taken as the address.
        for file in ["rec.mcap", "/tmp/x"] {
            let e = foxglove_addr(file).unwrap_err();
            assert!(
                e.ends_with(&format!(
                    "; {file:?} looks like a file: a recording to replay goes before \
                     --foxglove (`ima replay {file} --foxglove`), a file to write is \
                     `--record {file}`"
                )),
                "{e}"
            );
        }
        // The URL the live view is announced with.
        assert_eq!(ok("ws://127.0.0.1:8766"), "127.0.0.1:8766");
        assert_eq!(ok("ws://localhost:8766/"), "127.0.0.1:8766");
        let e = foxglove_addr("ws://nowhere").unwrap_err();
        assert!(!e.contains("looks like a file"), "{e}");
    }

    #[test]
    fn the_san_state_is_the_json_it_was() {
        use ima_agents::runtime::events::{SanConditionView, SanModuleView, SanView};
        let v = SanView {
            network: "scooter".into(),
            modules: vec![
                SanModuleView {
                    name: "move-to-target".into(),
                    activation: 0.75,
                    executable: true,
                },
                SanModuleView {
                    name: "go-home".into(),
                    activation: 0.25,
                    executable: false,
                },
            ],
            threshold: 0.5,
            conditions: vec![SanConditionView {
                name: "target-known".into(),
                value: true,
            }],
            selected: "move-to-target".into(),
        };
        let e = event(ima_agents::runtime::EventKind::San(v.clone()));
        let mut want = stamped_tree(&e, serde_json::to_value(&v).unwrap());
        want["activation"] = json!({"move_to_target": 0.75, "go_home": 0.25});
        want["executable"] = json!({"move_to_target": true, "go_home": false});
        let got = serde_json::to_value(SanJson { e: &e, v: &v }).unwrap();
        assert_eq!(got, want);
    }

    #[test]
    fn the_map_and_the_queue_carry_their_stamp_beside_their_fields() {
        use ima_agents::runtime::events::MapView;
        let m = MapView {
            dr: [1.0, 2.0],
            heading_rad: Some(0.5),
            desired_rad: None,
            plan: None,
            obstacles: vec![[3.0, 4.0]],
            target: Some("red".into()),
        };
        let e = event(ima_agents::runtime::EventKind::Map(m.clone()));
        let want = stamped_tree(&e, serde_json::to_value(&m).unwrap());
        let got = serde_json::to_value(WithStamp {
            t_s: e.t_s,
            robot: &e.robot,
            v: &m,
        })
        .unwrap();
        assert_eq!(got, want);
    }

    #[test]
    fn the_peer_status_topic_is_the_page_json_with_its_stamp() {
        let p = ima_agents::runtime::events::PeerStatus {
            address: Some("127.0.0.1:7400".into()),
            ..Default::default()
        };
        let e = event(ima_agents::runtime::EventKind::PeerStatus(Box::new(
            p.clone(),
        )));
        let want = stamped_tree(&e, crate::web::feed::peer_status_json(&p));
        let got = serde_json::to_value(WithStamp {
            t_s: e.t_s,
            robot: &e.robot,
            v: crate::web::feed::PeerStatusJson(&p),
        })
        .unwrap();
        assert_eq!(got, want);
    }

    #[test]
    fn an_event_line_is_its_name_and_its_detail() {
        use ima_agents::runtime::EventKind;
        for kind in [
            EventKind::RequestHeading,
            EventKind::Behaviour("move-to-target".into()),
            EventKind::FleetStop {
                by: "commander".into(),
                reason: "operator \"stop\" }".into(),
            },
            EventKind::Ses {
                records: 3,
                planned: true,
                target: None,
            },
        ] {
            let tree = serde_json::to_value(&kind).unwrap();
            let mut got = String::new();
            event_line(&kind, &mut got);
            // The same name and the same detail (its fields in declaration order now, where
            // the JSON tree sorted them).
            let (name, detail) = got.split_once(' ').unwrap();
            assert_eq!(name, kind.name());
            let detail: Value = serde_json::from_str(detail).unwrap();
            assert_eq!(
                detail,
                tree.get("detail").cloned().unwrap_or_default(),
                "{got}"
            );
        }
    }

    #[tokio::test]
    async fn a_tap_without_a_recorder_passes_bytes_through() {
        let (a, mut b) = tokio::io::duplex(64);
        let mut t = Tap {
            inner: a,
            raw: None,
        };
        t.write_all(b"ping").await.unwrap();
        let mut buf = [0u8; 4];
        b.read_exact(&mut buf).await.unwrap();
        assert_eq!(&buf, b"ping");
        b.write_all(b"pong").await.unwrap();
        t.read_exact(&mut buf).await.unwrap();
        assert_eq!(&buf, b"pong");
    }
}

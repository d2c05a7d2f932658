//! The **Scan node** (issue 8; MISSION.md, "The demonstration"): one full sweep of
//! Skeeter's camera head, as a sans-IO state machine, and a small async driver for it.
//!
//! # The sweep
//!
//! For each camera `1..=N` of the [`HeadGeometry`]:
//!
//! 1. [`ScanCommand::Switch`]`(ch)` — the runtime selects the channel on the video mux and
//!    reports [`Scanner::handle_switched`] (or [`Scanner::handle_switch_failed`]);
//! 2. the node waits the settle time ([`ScanConfig::settle`]; [`Scanner::poll_timeout`] /
//!    [`Scanner::handle_timeout`]) so the grabber no longer shows the previous camera or a
//!    torn image;
//! 3. [`ScanCommand::Grab`] — the runtime grabs a frame and hands it over with
//!    [`Scanner::handle_frame`] (or [`Scanner::handle_grab_failed`]). A frame that says it
//!    came from another channel is refused and grabbed again (at most
//!    [`ScanConfig::frame_retries`] times);
//! 4. the frame is searched for every colour of the [`ColourDb`] ([`super::vision`]), and
//!    each detection is posted to the SES: tag = colour name (or `scooter`), source =
//!    [`ScanConfig::source`], direction = camera yaw + blob bearing in Skeeter's frame
//!    (horizontal), range and confidence in the payload, time = when the frame arrived.
//!
//! A camera whose switch or frame does not come within [`ScanConfig::step_timeout`] is
//! skipped ([`ScanEvent::CameraFailed`]); the sweep goes on.
//!
//! Neighbouring cameras overlap (7 cameras of 60° leave 8.6° seen twice), and the SES keeps
//! one entry per `(tag, source)`: within one sweep the **best** sighting of each tag is kept
//! (a whole blob beats one cut by the frame edge, then the larger blob). Two objects of the
//! same colour are therefore one entry — the colour database assumes one object per colour,
//! as the thesis's demonstration does. When the sweep ends, the node's entries whose tag was
//! **not** seen in it are removed, so the SES (and the shared form) always describes the
//! latest full sweep: an object that vanished does not linger for the SES's time-to-live.
//!
//! The sweep ends with [`ScanEvent::ScanDone`] carrying a [`ScanReport`]: the detections
//! and the [`SharedForm`] of the node's SES entries, ready to publish as the Peer Agent
//! source `ses` (one sample per full scan, [`super::msg::SES_SOURCE`]).
//!
//! # Driving it
//!
//! [`run_scan`] runs one sweep against any [`CameraMux`] + [`FrameSource`] with a sleep
//! function and a clock supplied by the caller (tokio's in the runtime, a virtual one in a
//! simulation); this crate needs no async runtime.

use core::future::Future;
use core::pin::pin;
use core::task::Poll;
use std::collections::VecDeque;
use std::time::Duration;

use ima_hal::Instant;
use ima_hal::camera::{CameraMux, Channel, Frame, FrameSource};

use super::vision::{ColourDb, DetectorConfig, HeadGeometry, Observation, observe_frame};
use crate::ses::shared::SharedForm;
use crate::ses::{Direction, DomeError, Payload, Ses, SesConfig};

/// Settings of the Scan node.
#[derive(Debug, Clone, PartialEq)]
pub struct ScanConfig {
    /// The camera head.
    pub head: HeadGeometry,
    /// The blob detector.
    pub detector: DetectorConfig,
    /// Wait after a confirmed switch before grabbing (the mux's settle time; the mock head
    /// garbles frames for 150 ms).
    pub settle: Duration,
    /// Longest wait for a switch confirmation or a frame before the camera is skipped.
    pub step_timeout: Duration,
    /// Frames from the wrong channel grabbed again at most this many times.
    pub frame_retries: u8,
    /// This robot's name (in the shared form).
    pub robot: String,
    /// SES source name of the node's entries.
    pub source: String,
}

impl Default for ScanConfig {
    fn default() -> Self {
        Self {
            head: HeadGeometry::default(),
            detector: DetectorConfig::default(),
            settle: Duration::from_millis(150),
            step_timeout: Duration::from_secs(2),
            frame_retries: 2,
            robot: super::msg::SKEETER.to_owned(),
            source: "vision".to_owned(),
        }
    }
}

/// What the node asks the runtime to do.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ScanCommand {
    /// Select this channel on the video mux.
    Switch(Channel),
    /// Grab one frame.
    Grab,
}

/// Why a camera was skipped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CameraFailure {
    /// The mux refused or failed the switch.
    SwitchFailed,
    /// No switch confirmation within the step timeout.
    SwitchTimeout,
    /// The frame source failed.
    GrabFailed,
    /// No frame within the step timeout.
    GrabTimeout,
    /// Every frame came from another channel.
    WrongChannel,
}

/// One detection of a sweep: an observation and when its frame arrived.
#[derive(Debug, Clone, PartialEq)]
pub struct Detection {
    /// Tag, camera, bearing in Skeeter's frame, range, size.
    pub observation: Observation,
    /// When the frame was taken in (`now` of [`Scanner::handle_frame`]).
    pub time: Instant,
}

impl Detection {
    /// The tag (colour name or `scooter`).
    #[must_use]
    pub fn tag(&self) -> &str {
        &self.observation.tag
    }
}

/// The outcome of a full sweep.
#[derive(Debug, Clone, PartialEq)]
pub struct ScanReport {
    /// When the sweep began.
    pub started: Instant,
    /// When it ended.
    pub finished: Instant,
    /// The best detection of each tag seen, in the order first seen.
    pub detections: Vec<Detection>,
    /// Cameras whose frame was searched.
    pub cameras_ok: u8,
    /// Cameras skipped.
    pub cameras_failed: u8,
    /// The node's SES entries after the sweep, as the shared form to publish.
    pub shared: SharedForm,
}

impl ScanReport {
    /// The detection of `tag`, if seen.
    #[must_use]
    pub fn get(&self, tag: &str) -> Option<&Detection> {
        self.detections.iter().find(|d| d.tag() == tag)
    }

    /// Whether `tag` was seen.
    #[must_use]
    pub fn sees(&self, tag: &str) -> bool {
        self.get(tag).is_some()
    }
}

/// What the node reports.
#[derive(Debug, Clone, PartialEq)]
pub enum ScanEvent {
    /// A camera's frame was searched.
    Camera {
        /// The camera.
        channel: Channel,
        /// Observations in its frame.
        observations: usize,
    },
    /// A camera was skipped.
    CameraFailed {
        /// The camera.
        channel: Channel,
        /// Why.
        why: CameraFailure,
    },
    /// The sweep is over.
    ScanDone(ScanReport),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    Idle,
    Switching {
        ch: Channel,
        deadline: Instant,
    },
    Settling {
        ch: Channel,
        until: Instant,
    },
    Grabbing {
        ch: Channel,
        deadline: Instant,
        retries: u8,
    },
}

/// The Scan node ([module docs](self)). It owns Skeeter's SES.
#[derive(Debug)]
pub struct Scanner {
    cfg: ScanConfig,
    db: ColourDb,
    ses: Ses,
    state: State,
    commands: VecDeque<ScanCommand>,
    events: VecDeque<ScanEvent>,
    found: Vec<Detection>,
    started: Instant,
    ok: u8,
    failed: u8,
    sweeps: u64,
    /// A lower bound on the settle wait for the sweep under way (set by [`run_scan`] from
    /// the mux's own settle time; zero otherwise), so the configuration is never changed.
    settle_floor: Duration,
}

impl Scanner {
    /// A node posting into `ses`.
    #[must_use]
    pub fn new(cfg: ScanConfig, db: ColourDb, ses: Ses) -> Self {
        Self {
            cfg,
            db,
            ses,
            state: State::Idle,
            commands: VecDeque::new(),
            events: VecDeque::new(),
            found: Vec::new(),
            started: Instant::ZERO,
            ok: 0,
            failed: 0,
            sweeps: 0,
            settle_floor: Duration::ZERO,
        }
    }

    /// A node with an SES of default settings.
    ///
    /// # Errors
    /// [`DomeError`] (not with the defaults).
    pub fn with_default_ses(cfg: ScanConfig, db: ColourDb) -> Result<Self, DomeError> {
        Ok(Self::new(cfg, db, Ses::new(SesConfig::default())?))
    }

    /// The settings.
    #[must_use]
    pub fn config(&self) -> &ScanConfig {
        &self.cfg
    }

    /// Change the settings (takes effect at the next step).
    pub fn config_mut(&mut self) -> &mut ScanConfig {
        &mut self.cfg
    }

    /// The colour database.
    #[must_use]
    pub fn colours(&self) -> &ColourDb {
        &self.db
    }

    /// Skeeter's SES.
    #[must_use]
    pub fn ses(&self) -> &Ses {
        &self.ses
    }

    /// Skeeter's SES, to post other agents' data or expire entries.
    pub fn ses_mut(&mut self) -> &mut Ses {
        &mut self.ses
    }

    /// Full sweeps completed.
    #[must_use]
    pub fn sweeps(&self) -> u64 {
        self.sweeps
    }

    /// Whether a sweep is under way.
    #[must_use]
    pub fn is_scanning(&self) -> bool {
        self.state != State::Idle
    }

    /// The shared form of the node's SES entries, stamped `now`.
    #[must_use]
    pub fn shared_form(&self, now: Instant) -> SharedForm {
        let source = self.cfg.source.clone();
        self.ses
            .export_shared(&self.cfg.robot, now, |e| e.source == source)
    }

    /// Begin a sweep at camera 1. Returns `false` (and changes nothing) if one is under way
    /// or the head has no camera.
    pub fn start(&mut self, now: Instant) -> bool {
        if self.is_scanning() || self.cfg.head.cameras == 0 {
            return false;
        }
        self.found.clear();
        self.settle_floor = Duration::ZERO;
        self.started = now;
        self.ok = 0;
        self.failed = 0;
        self.switch_to(1, now);
        true
    }

    /// Abandon the sweep under way (nothing is posted or removed beyond what was already).
    pub fn cancel(&mut self) {
        self.state = State::Idle;
        self.commands.clear();
    }

    /// The next command for the runtime.
    pub fn poll_command(&mut self) -> Option<ScanCommand> {
        self.commands.pop_front()
    }

    /// The next event.
    pub fn poll_event(&mut self) -> Option<ScanEvent> {
        self.events.pop_front()
    }

    /// When [`Scanner::handle_timeout`] is due.
    #[must_use]
    pub fn poll_timeout(&self) -> Option<Instant> {
        match self.state {
            State::Idle => None,
            State::Switching { deadline, .. } | State::Grabbing { deadline, .. } => Some(deadline),
            State::Settling { until, .. } => Some(until),
        }
    }

    /// The settle wait of the sweep under way: [`ScanConfig::settle`], or more when
    /// [`run_scan`] raised it to the mux's settle time for this sweep.
    #[must_use]
    pub fn settle_time(&self) -> Duration {
        self.cfg.settle.max(self.settle_floor)
    }

    /// The mux confirmed the switch to `channel` at `now`; the settle wait begins. A
    /// confirmation for another channel, or when none is awaited, is ignored.
    pub fn handle_switched(&mut self, channel: Channel, now: Instant) {
        if let State::Switching { ch, .. } = self.state
            && ch == channel
        {
            self.state = State::Settling {
                ch,
                until: now + self.settle_time(),
            };
        }
    }

    /// The switch failed: the camera is skipped.
    pub fn handle_switch_failed(&mut self, now: Instant) {
        if let State::Switching { ch, .. } = self.state {
            self.skip(ch, CameraFailure::SwitchFailed, now);
        }
    }

    /// The grab failed: the camera is skipped.
    pub fn handle_grab_failed(&mut self, now: Instant) {
        if let State::Grabbing { ch, .. } = self.state {
            self.skip(ch, CameraFailure::GrabFailed, now);
        }
    }

    /// Time passed: the settle wait ends (→ [`ScanCommand::Grab`]) or a step times out.
    pub fn handle_timeout(&mut self, now: Instant) {
        match self.state {
            State::Settling { ch, until } if now >= until => {
                self.state = State::Grabbing {
                    ch,
                    deadline: now + self.cfg.step_timeout,
                    retries: 0,
                };
                self.commands.push_back(ScanCommand::Grab);
            }
            State::Switching { ch, deadline } if now >= deadline => {
                self.skip(ch, CameraFailure::SwitchTimeout, now);
            }
            State::Grabbing { ch, deadline, .. } if now >= deadline => {
                self.skip(ch, CameraFailure::GrabTimeout, now);
            }
            _ => {}
        }
    }

    /// The grabbed frame, taken in at `now`: search it, post the detections, go on to the
    /// next camera (or end the sweep). A frame not awaited is ignored; one that says it came
    /// from another channel is grabbed again.
    pub fn handle_frame(&mut self, frame: &Frame, now: Instant) {
        let State::Grabbing {
            ch,
            deadline,
            retries,
        } = self.state
        else {
            return;
        };
        if frame.channel.is_some_and(|c| c != ch) {
            if retries < self.cfg.frame_retries {
                self.state = State::Grabbing {
                    ch,
                    deadline,
                    retries: retries.saturating_add(1),
                };
                self.commands.push_back(ScanCommand::Grab);
            } else {
                self.skip(ch, CameraFailure::WrongChannel, now);
            }
            return;
        }
        let obs = observe_frame(frame, ch, &self.db, &self.cfg.head, &self.cfg.detector);
        self.events.push_back(ScanEvent::Camera {
            channel: ch,
            observations: obs.len(),
        });
        for o in obs {
            self.offer(o, now);
        }
        self.ok = self.ok.saturating_add(1);
        self.next_camera(ch, now);
    }

    /// Keep `o` if it is the best sighting of its tag in this sweep, and post it.
    fn offer(&mut self, o: Observation, now: Instant) {
        let better = match self.found.iter().position(|d| d.tag() == o.tag) {
            Some(i) => match self.found.get(i) {
                Some(d) if o.better_than(&d.observation) => {
                    self.found.remove(i);
                    true
                }
                _ => false,
            },
            None => true,
        };
        if !better {
            return;
        }
        let payload = Payload {
            object: o.tag.clone(),
            bearing: Direction::horizontal(o.bearing_rad),
            range_m: o.range_m,
            confidence: o.confidence(),
        };
        // A post can only fail on non-finite geometry, which the vision code never makes.
        if self
            .ses
            .post(&o.tag, &self.cfg.source, now, payload)
            .is_ok()
        {
            self.found.push(Detection {
                observation: o,
                time: now,
            });
        }
    }

    fn skip(&mut self, ch: Channel, why: CameraFailure, now: Instant) {
        self.events
            .push_back(ScanEvent::CameraFailed { channel: ch, why });
        self.failed = self.failed.saturating_add(1);
        self.next_camera(ch, now);
    }

    fn switch_to(&mut self, ch: Channel, now: Instant) {
        self.state = State::Switching {
            ch,
            deadline: now + self.cfg.step_timeout,
        };
        self.commands.push_back(ScanCommand::Switch(ch));
    }

    fn next_camera(&mut self, ch: Channel, now: Instant) {
        self.commands.clear();
        if ch < self.cfg.head.cameras {
            self.switch_to(ch.saturating_add(1), now);
        } else {
            self.finish(now);
        }
    }

    fn finish(&mut self, now: Instant) {
        self.state = State::Idle;
        self.sweeps = self.sweeps.saturating_add(1);
        // Forget what this sweep did not see.
        let stale: Vec<String> = self
            .ses
            .iter()
            .filter(|e| e.source == self.cfg.source && !self.found.iter().any(|d| d.tag() == e.tag))
            .map(|e| e.tag.clone())
            .collect();
        for tag in stale {
            self.ses.remove(&tag, &self.cfg.source);
        }
        let report = ScanReport {
            started: self.started,
            finished: now,
            detections: core::mem::take(&mut self.found),
            cameras_ok: self.ok,
            cameras_failed: self.failed,
            shared: self.shared_form(now),
        };
        self.events.push_back(ScanEvent::ScanDone(report));
    }
}

/// Await `fut`, but give up when `timeout` (a sleep future) completes first.
async fn or_timeout<T>(
    fut: impl Future<Output = T>,
    timeout: impl Future<Output = ()>,
) -> Option<T> {
    let mut fut = pin!(fut);
    let mut timeout = pin!(timeout);
    core::future::poll_fn(|cx| {
        if let Poll::Ready(v) = fut.as_mut().poll(cx) {
            return Poll::Ready(Some(v));
        }
        if timeout.as_mut().poll(cx).is_ready() {
            return Poll::Ready(None);
        }
        Poll::Pending
    })
    .await
}

/// Run one full sweep of `scanner` with a video mux and a frame source. `sleep(d)` must wait
/// `d` (e.g. `tokio::time::sleep`), `now()` read the clock the SES times use. Every mux or
/// frame-source call is bounded by the node's step timeout. The settle wait is the larger
/// of [`ScanConfig::settle`] and the mux's [`CameraMux::settle_time`], for this sweep only
/// ([`Scanner::settle_time`]; the configuration is not changed).
///
/// # Cancel safety
///
/// On a step timeout the pending `mux.select(ch)` or `frames.grab()` future is **dropped**
/// (the camera counts as failed and the sweep goes on). So both must be cancel-safe: a
/// call dropped half-way (a command written but its reply not read, a frame half
/// received) must leave the device usable for the next call — e.g. the driver discards
/// stale bytes or a stale reply at its next call, or resynchronises its framer. A driver
/// that is not cancel-safe makes every camera after a timeout fail or see the wrong
/// channel. Likewise, dropping the `run_scan` future itself leaves the sweep under way in
/// the scanner: call [`Scanner::cancel`] before the next one.
///
/// Returns the [`ScanReport`], or `None` if a sweep was already under way (it is left
/// alone). Per-camera events are drained and dropped; use the state machine directly to
/// see them.
pub async fn run_scan<M, F, S, SF, C>(
    scanner: &mut Scanner,
    mux: &mut M,
    frames: &mut F,
    mut sleep: S,
    mut now: C,
) -> Option<ScanReport>
where
    M: CameraMux,
    F: FrameSource,
    S: FnMut(Duration) -> SF,
    SF: Future<Output = ()>,
    C: FnMut() -> Instant,
{
    if !scanner.start(now()) {
        return None;
    }
    // For this sweep only: the configuration is left as it was.
    scanner.settle_floor = mux.settle_time();
    let step = scanner.cfg.step_timeout;
    loop {
        while let Some(cmd) = scanner.poll_command() {
            match cmd {
                ScanCommand::Switch(ch) => match or_timeout(mux.select(ch), sleep(step)).await {
                    Some(Ok(_)) => scanner.handle_switched(ch, now()),
                    Some(Err(_)) => scanner.handle_switch_failed(now()),
                    None => scanner.handle_timeout(now()),
                },
                ScanCommand::Grab => match or_timeout(frames.grab(), sleep(step)).await {
                    Some(Ok(f)) => scanner.handle_frame(&f.value, now()),
                    Some(Err(_)) => scanner.handle_grab_failed(now()),
                    None => scanner.handle_timeout(now()),
                },
            }
        }
        while let Some(ev) = scanner.poll_event() {
            if let ScanEvent::ScanDone(report) = ev {
                return Some(report);
            }
        }
        let deadline = scanner.poll_timeout()?;
        let t = now();
        if deadline > t {
            sleep(deadline.saturating_duration_since(t)).await;
        }
        scanner.handle_timeout(now().max(deadline));
    }
}

#[cfg(test)]
mod tests {
    use super::super::vision::testing::{draw_disc, grey};
    use super::*;
    use core::f64::consts::TAU;
    use std::sync::Arc;
    use std::sync::atomic::{AtomicU8, AtomicU64, Ordering};

    const W: u32 = 320;
    const H: u32 = 240;

    fn t(ms: u64) -> Instant {
        Instant::from_millis(ms)
    }

    /// A world of discs (bearing in Skeeter's frame, range, radius, rgb) rendered per camera.
    #[derive(Clone)]
    struct Scene {
        things: Vec<(f64, f64, f64, [u8; 3])>,
    }

    impl Scene {
        fn render(&self, ch: Channel) -> Frame {
            let head = HeadGeometry::default();
            let yaw = head.camera_yaw_rad(ch).unwrap();
            let mut f = grey(W, H, Some(ch));
            let half = head.fov_rad() / 2.0;
            for &(b, r, rad, rgb) in &self.things {
                let rel = ima_hal::normalize_angle(b - yaw);
                if rel.abs() <= half {
                    draw_disc(&mut f, head.fov_rad(), rel, r, rad, rgb);
                }
            }
            f
        }
    }

    fn default_scene() -> Scene {
        // red ahead at 3 m, blue at 120°, scooter at 210° 4 m.
        Scene {
            things: vec![
                (0.0, 3.0, 0.15, [220, 30, 30]),
                (120f64.to_radians(), 3.0, 0.15, [30, 60, 220]),
                (210f64.to_radians(), 4.0, 0.4, [235, 235, 235]),
            ],
        }
    }

    fn scanner() -> Scanner {
        Scanner::with_default_ses(ScanConfig::default(), ColourDb::default()).unwrap()
    }

    /// Drive a sweep in virtual time, answering every command at once (switch takes 30 ms,
    /// a frame 50 ms).
    fn sweep(
        s: &mut Scanner,
        scene: &Scene,
        start: Instant,
    ) -> (ScanReport, Vec<ScanEvent>, Instant) {
        assert!(s.start(start));
        let mut now = start;
        let mut events = Vec::new();
        let mut current = None;
        for _ in 0..1000 {
            while let Some(c) = s.poll_command() {
                match c {
                    ScanCommand::Switch(ch) => {
                        now = now + Duration::from_millis(30);
                        current = Some(ch);
                        s.handle_switched(ch, now);
                    }
                    ScanCommand::Grab => {
                        now = now + Duration::from_millis(50);
                        s.handle_frame(&scene.render(current.unwrap()), now);
                    }
                }
            }
            while let Some(e) = s.poll_event() {
                if let ScanEvent::ScanDone(r) = e {
                    return (r, events, now);
                }
                events.push(e);
            }
            let d = s.poll_timeout().expect("a sweep under way has a timeout");
            now = now.max(d);
            s.handle_timeout(now);
        }
        panic!("sweep did not end");
    }

    #[test]
    fn full_sweep_switches_settles_grabs_every_camera_in_order() {
        let mut s = scanner();
        assert!(s.start(t(0)));
        assert!(!s.start(t(0)), "one sweep at a time");
        assert_eq!(s.poll_command(), Some(ScanCommand::Switch(1)));
        assert_eq!(s.poll_command(), None);
        assert_eq!(s.poll_timeout(), Some(t(2000)), "switch deadline");
        s.handle_switched(1, t(30));
        assert_eq!(s.poll_command(), None, "no grab before the settle time");
        assert_eq!(s.poll_timeout(), Some(t(180)));
        s.handle_timeout(t(179));
        assert_eq!(s.poll_command(), None);
        s.handle_timeout(t(180));
        assert_eq!(s.poll_command(), Some(ScanCommand::Grab));
        s.handle_frame(&default_scene().render(1), t(230));
        assert_eq!(
            s.poll_event(),
            Some(ScanEvent::Camera {
                channel: 1,
                observations: 1
            })
        );
        assert_eq!(s.poll_command(), Some(ScanCommand::Switch(2)));
        assert_eq!(s.ses().get("red", "vision").map(|e| e.time), Some(t(230)));
    }

    #[test]
    fn sweep_posts_bearings_and_ranges_in_skeeters_frame() {
        let mut s = scanner();
        let (r, events, end) = sweep(&mut s, &default_scene(), t(1000));
        assert_eq!(r.cameras_ok, 7);
        assert_eq!(r.cameras_failed, 0);
        assert_eq!(events.len(), 7);
        assert_eq!(r.started, t(1000));
        assert_eq!(r.finished, end);
        // 7 × (30 ms switch + 150 ms settle + 50 ms frame)
        assert_eq!(end, t(1000 + 7 * 230));
        let tags: Vec<&str> = r.detections.iter().map(Detection::tag).collect();
        assert_eq!(tags.len(), 3, "{tags:?}");
        let f = super::super::vision::focal_px(W, 60f64.to_radians());
        for (tag, b, range) in [
            ("red", 0.0, 3.0),
            ("blue", 120.0, 3.0),
            ("scooter", 210.0, 4.0),
        ] {
            let d = r.get(tag).unwrap();
            let want = ima_hal::normalize_angle(f64::to_radians(b));
            let err = ima_hal::normalize_angle(d.observation.bearing_rad - want).abs();
            assert!(err < 0.5 / f, "{tag}: {err}");
            let got = d.observation.range_m.unwrap();
            assert!((got - range).abs() < 0.05 * range, "{tag}: {got}");
            let e = s.ses().get(tag, "vision").unwrap();
            assert!((e.payload.bearing.azimuth_rad - want).abs() < 0.5 / f);
            assert_eq!(e.payload.range_m, d.observation.range_m);
        }
        assert!(r.sees("scooter") && !r.sees("green"));
        // The shared form holds the same three records, from skeeter.
        assert_eq!(r.shared.source_robot, "skeeter");
        assert_eq!(r.shared.records.len(), 3);
        assert_eq!(r.shared.sent_at, end);
        assert_eq!(s.sweeps(), 1);
        assert!(!s.is_scanning());
        assert_eq!(s.poll_timeout(), None);
    }

    #[test]
    fn overlap_keeps_the_best_sighting_and_stale_entries_go() {
        // An object at 25.7°, seen by camera 1 (edge, cut) and camera 2 (edge, cut too?):
        // camera 1 axis 0°, camera 2 axis 51.4°; 27° is 3° inside camera 1's edge and
        // 24.4° off camera 2's axis — whole there.
        let scene = Scene {
            things: vec![(27f64.to_radians(), 2.0, 0.15, [240, 220, 40])],
        };
        let mut s = scanner();
        let (r, _, _) = sweep(&mut s, &scene, t(0));
        let d = r.get("yellow").unwrap();
        assert_eq!(d.observation.channel, 2);
        assert!(!d.observation.clipped);
        assert_eq!(r.detections.len(), 1);
        assert!((d.observation.bearing_rad - 27f64.to_radians()).abs() < 0.005);
        // Next sweep: the yellow object is gone, scooter appears.
        let scene2 = Scene {
            things: vec![(-1.0, 3.0, 0.4, [235, 235, 235])],
        };
        let (r2, _, _) = sweep(&mut s, &scene2, t(10_000));
        assert!(!r2.sees("yellow"));
        assert!(
            s.ses().get("yellow", "vision").is_none(),
            "stale entry removed"
        );
        assert!(s.ses().get("scooter", "vision").is_some());
        assert_eq!(r2.shared.records.len(), 1);
        // Other sources' entries are left alone.
        s.ses_mut()
            .post(
                "green",
                "peer:scooter",
                t(20_000),
                Payload {
                    object: "green".into(),
                    bearing: Direction::horizontal(0.0),
                    range_m: None,
                    confidence: 1.0,
                },
            )
            .unwrap();
        let (r3, _, _) = sweep(&mut s, &scene2, t(20_000));
        assert!(s.ses().get("green", "peer:scooter").is_some());
        assert_eq!(
            r3.shared.records.len(),
            1,
            "only the node's entries are shared"
        );
    }

    #[test]
    fn failures_and_timeouts_skip_a_camera() {
        let mut s = scanner();
        assert!(s.start(t(0)));
        assert_eq!(s.poll_command(), Some(ScanCommand::Switch(1)));
        s.handle_switch_failed(t(10));
        assert_eq!(
            s.poll_event(),
            Some(ScanEvent::CameraFailed {
                channel: 1,
                why: CameraFailure::SwitchFailed
            })
        );
        assert_eq!(s.poll_command(), Some(ScanCommand::Switch(2)));
        // No answer: timeout 2 s after the switch command.
        s.handle_timeout(t(2009));
        assert_eq!(s.poll_event(), None);
        s.handle_timeout(t(2010));
        assert_eq!(
            s.poll_event(),
            Some(ScanEvent::CameraFailed {
                channel: 2,
                why: CameraFailure::SwitchTimeout
            })
        );
        assert_eq!(s.poll_command(), Some(ScanCommand::Switch(3)));
        s.handle_switched(4, t(2020));
        assert_eq!(
            s.poll_timeout(),
            Some(t(4010)),
            "a confirmation for another channel is ignored"
        );
        s.handle_switched(3, t(2020));
        s.handle_timeout(t(2170));
        assert_eq!(s.poll_command(), Some(ScanCommand::Grab));
        s.handle_grab_failed(t(2180));
        assert_eq!(
            s.poll_event(),
            Some(ScanEvent::CameraFailed {
                channel: 3,
                why: CameraFailure::GrabFailed
            })
        );
        assert_eq!(s.poll_command(), Some(ScanCommand::Switch(4)));
        s.handle_switched(4, t(2200));
        s.handle_timeout(t(2350));
        assert_eq!(s.poll_command(), Some(ScanCommand::Grab));
        s.handle_timeout(t(4349));
        assert_eq!(s.poll_event(), None);
        s.handle_timeout(t(4350));
        assert_eq!(
            s.poll_event(),
            Some(ScanEvent::CameraFailed {
                channel: 4,
                why: CameraFailure::GrabTimeout
            })
        );
        // Frames from the wrong channel: re-grabbed twice, then skipped.
        assert_eq!(s.poll_command(), Some(ScanCommand::Switch(5)));
        s.handle_switched(5, t(4400));
        s.handle_timeout(t(4550));
        let wrong = default_scene().render(6);
        for _ in 0..2 {
            assert_eq!(s.poll_command(), Some(ScanCommand::Grab));
            s.handle_frame(&wrong, t(4600));
            assert_eq!(s.poll_event(), None);
        }
        assert_eq!(s.poll_command(), Some(ScanCommand::Grab));
        s.handle_frame(&wrong, t(4600));
        assert_eq!(
            s.poll_event(),
            Some(ScanEvent::CameraFailed {
                channel: 5,
                why: CameraFailure::WrongChannel
            })
        );
        // A frame nobody asked for is ignored.
        s.handle_frame(&wrong, t(4601));
        assert_eq!(s.poll_event(), None);
        assert_eq!(s.poll_command(), Some(ScanCommand::Switch(6)));
        s.cancel();
        assert!(!s.is_scanning());
        assert_eq!(s.poll_command(), None);
    }

    #[test]
    fn a_frame_without_a_channel_tag_is_accepted() {
        let mut s = scanner();
        s.start(t(0));
        s.poll_command();
        s.handle_switched(1, t(0));
        s.handle_timeout(t(150));
        s.poll_command();
        let mut f = default_scene().render(1);
        f.channel = None;
        s.handle_frame(&f, t(200));
        assert!(matches!(
            s.poll_event(),
            Some(ScanEvent::Camera {
                channel: 1,
                observations: 1
            })
        ));
    }

    // ---- the async driver, with fake hal devices and a virtual clock ----

    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    struct FakeError;
    impl core::fmt::Display for FakeError {
        fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
            f.write_str("the fake device failed")
        }
    }
    impl ima_hal::Error for FakeError {
        fn kind(&self) -> ima_hal::ErrorKind {
            ima_hal::ErrorKind::Other
        }
    }

    /// Virtual clock, µs.
    #[derive(Clone, Default)]
    struct Clock(Arc<AtomicU64>);
    impl Clock {
        fn now(&self) -> Instant {
            Instant::from_micros(self.0.load(Ordering::SeqCst))
        }
        fn advance(&self, d: Duration) {
            self.0
                .fetch_add(u64::try_from(d.as_micros()).unwrap(), Ordering::SeqCst);
        }
    }

    #[derive(Clone, Default)]
    struct Bus {
        current: Arc<AtomicU8>,
        switched_at: Arc<AtomicU64>,
    }

    struct FakeMux {
        clock: Clock,
        bus: Bus,
        fail: Option<Channel>,
    }
    impl ima_hal::ErrorType for FakeMux {
        type Error = FakeError;
    }
    impl CameraMux for FakeMux {
        fn channel_count(&self) -> Channel {
            7
        }
        fn settle_time(&self) -> Duration {
            Duration::from_millis(200)
        }
        async fn select(
            &mut self,
            channel: Channel,
        ) -> Result<ima_hal::camera::Selection, FakeError> {
            self.clock.advance(Duration::from_millis(20));
            if self.fail == Some(channel) {
                return Err(FakeError);
            }
            let now = self.clock.now();
            self.bus.current.store(channel, Ordering::SeqCst);
            self.bus
                .switched_at
                .store(now.as_micros(), Ordering::SeqCst);
            Ok(ima_hal::camera::Selection {
                channel,
                confirmed_at: now,
                settled_at: now + Duration::from_millis(200),
            })
        }
        async fn current_channel(&mut self) -> Result<Option<Channel>, FakeError> {
            Ok(Some(self.bus.current.load(Ordering::SeqCst)))
        }
    }

    struct FakeHead {
        clock: Clock,
        bus: Bus,
        scene: Scene,
    }
    impl ima_hal::ErrorType for FakeHead {
        type Error = FakeError;
    }
    impl FrameSource for FakeHead {
        async fn grab(&mut self) -> Result<ima_hal::Stamped<Frame>, FakeError> {
            self.clock.advance(Duration::from_millis(40));
            let now = self.clock.now().as_micros();
            let ch = self.bus.current.load(Ordering::SeqCst);
            // Garbage before the mux settles, as the mock head does.
            let frame = if now - self.bus.switched_at.load(Ordering::SeqCst) < 200_000 {
                let mut f = grey(W, H, Some(ch));
                super::super::vision::testing::speckle(&mut f, 1, now);
                f
            } else {
                self.scene.render(ch)
            };
            Ok(ima_hal::Stamped::new(Instant::from_micros(now), frame))
        }
    }

    fn block_on<F: Future>(fut: F) -> F::Output {
        let mut fut = pin!(fut);
        let mut cx = core::task::Context::from_waker(core::task::Waker::noop());
        loop {
            if let Poll::Ready(v) = fut.as_mut().poll(&mut cx) {
                return v;
            }
        }
    }

    fn run(
        s: &mut Scanner,
        mux: &mut FakeMux,
        head: &mut impl FrameSource,
        clock: &Clock,
    ) -> Option<ScanReport> {
        let (c1, c2) = (clock.clone(), clock.clone());
        block_on(run_scan(
            s,
            mux,
            head,
            move |d| {
                let c = c1.clone();
                async move { c.advance(d) }
            },
            move || c2.now(),
        ))
    }

    #[test]
    fn run_scan_drives_hal_devices_in_virtual_time() {
        let clock = Clock::default();
        clock.advance(Duration::from_secs(5));
        let bus = Bus::default();
        let mut mux = FakeMux {
            clock: clock.clone(),
            bus: bus.clone(),
            fail: Some(4),
        };
        let mut head = FakeHead {
            clock: clock.clone(),
            bus,
            scene: default_scene(),
        };
        let mut s = scanner();
        let report = run(&mut s, &mut mux, &mut head, &clock).unwrap();
        assert_eq!(report.cameras_ok, 6);
        assert_eq!(report.cameras_failed, 1, "camera 4 refused");
        assert!(report.sees("red") && report.sees("blue") && report.sees("scooter"));
        assert_eq!(
            s.settle_time(),
            Duration::from_millis(200),
            "the mux's wins"
        );
        assert_eq!(
            s.config().settle,
            Duration::from_millis(150),
            "for the sweep only: the configuration is unchanged"
        );
        // A sweep driven without run_scan waits the configured time again.
        let mut s2 = scanner();
        s2.settle_floor = Duration::from_millis(900);
        assert!(s2.start(Instant::ZERO));
        assert_eq!(s2.settle_time(), Duration::from_millis(150));
        // 6 × (20 + 200 + 40) + 20 for the refused camera
        assert_eq!(report.started, Instant::from_millis(5000));
        assert_eq!(
            report.finished.saturating_duration_since(report.started),
            Duration::from_millis(6 * 260 + 20)
        );
        let blue = report.get("blue").unwrap();
        assert!((blue.observation.bearing_rad - TAU / 3.0).abs() < 0.005);
        // A second sweep runs the same way.
        assert!(run(&mut s, &mut mux, &mut head, &clock).is_some());
        assert_eq!(s.sweeps(), 2);
    }

    #[test]
    fn run_scan_times_out_a_hung_device() {
        struct Hung;
        impl ima_hal::ErrorType for Hung {
            type Error = FakeError;
        }
        impl FrameSource for Hung {
            async fn grab(&mut self) -> Result<ima_hal::Stamped<Frame>, FakeError> {
                core::future::pending::<Result<ima_hal::Stamped<Frame>, FakeError>>().await
            }
        }
        let clock = Clock::default();
        let mut mux = FakeMux {
            clock: clock.clone(),
            bus: Bus::default(),
            fail: None,
        };
        let mut s = scanner();
        let report = run(&mut s, &mut mux, &mut Hung, &clock).unwrap();
        assert_eq!(report.cameras_ok, 0);
        assert_eq!(report.cameras_failed, 7);
        assert!(report.detections.is_empty());
        // 7 × (20 ms switch + 200 ms settle + 2 s grab timeout)
        assert_eq!(report.finished, Instant::from_millis(7 * 2220));
    }
}

//! The mock omni-directional camera head of Skeeter: `cameras` cameras at equal spacing round
//! the robot behind one video switcher and one frame grabber, rendering the simulated world's
//! coloured objects (spec `protocols/compass_video_mux.md` §7b; issue 5).
//!
//! # Design
//!
//! * [`CameraHead`] is the sans-IO renderer: given a channel and how long ago the switch
//!   happened, it draws a frame from the world. No clock, no I/O; tests call it directly.
//! * [`MockCameraHead`] is the frame source ([`ima_hal::camera::FrameSource`]): it reads the
//!   selected channel and the switch instant from the [`VideoBus`] it shares with the mock
//!   switcher ([`crate::video_mux::MuxDevice`]), waits for the next frame of the grabber, and
//!   renders. Without a switcher, whoever owns the bus is the switcher:
//!   [`VideoBus::switch`] "tells the head the channel". Time is tokio time, so sweeps run in
//!   virtual time under `tokio::time::pause`.
//!
//! # Geometry and picture
//!
//! Channel `k` (1-based) looks along the robot's heading plus `(k − 1) · 360° / cameras`,
//! counter-clockwise (channel 1 forward). A pinhole camera of horizontal field of view
//! [`fov_deg`](CameraConfig::fov_deg): an object at bearing `b` (counter-clockwise from the
//! optical axis) has its centre at column `w/2 − f·tan b` with `f = (w/2) / tan(fov/2)`, on
//! the middle row (cameras at object height), drawn in the object's colour as a disc of
//! radius `f·tan(asin(r/range))` ≈ `f · r / range` pixels stretched by perspective off the
//! axis (an ellipse, `/cos²b` across and `/cos b` up), so that its angular width is
//! `2·asin(r/range)` wherever it appears, as through a real pinhole lens. Objects come from
//! [`crate::world::World::visible_objects`] (centre in view, not hidden; the robot itself is
//! transparent). Other robots that carry a marker ([`crate::world::RobotSpec::marker_rgb`])
//! are drawn the same way, as a disc of their footprint radius in the marker colour
//! ([`crate::world::World::visible_markers`]); robots without a marker are not drawn. The
//! background is a plain grey; every pixel gets uniform noise of ±
//! [`noise`](CameraConfig::noise).
//!
//! A frame exposed less than [`settle_time`](CameraConfig::settle_time) after a switch is
//! garbage (random pixels), as on real hardware while the grabber re-locks.
//!
//! # Timing
//!
//! The grabber exposes a frame every [`frame_interval`](CameraConfig::frame_interval) (30 Hz
//! by default) and needs [`transfer_time`](CameraConfig::transfer_time) to deliver it. A
//! sweep of all cameras costs, per camera, the switch (switcher delay + serial), the settle
//! time, up to one frame interval and the transfer: about 0.3 s, 2 s for 7 cameras with the
//! defaults — the thesis reports a sweep under 5 s. [`CameraConfig::sweep_estimate`] gives
//! the figure for a configuration.

use std::f64::consts::TAU;
use std::time::Duration;

use ima_hal::camera::{Channel, Frame, FrameSource};
use ima_hal::{ErrorKind, ErrorType, Instant, Stamped};
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};

use crate::video_mux::VideoBus;
use crate::world::{Pose, RobotId, SharedWorld};

/// Settings of the camera head.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraConfig {
    /// Cameras round the robot (channels `1..=cameras`).
    pub cameras: Channel,
    /// Horizontal field of view of each camera, degrees.
    pub fov_deg: f64,
    /// Frame width, pixels.
    pub width: u32,
    /// Frame height, pixels.
    pub height: u32,
    /// Objects farther than this are not drawn, metres.
    pub max_range_m: f64,
    /// Background colour.
    pub background: [u8; 3],
    /// Uniform pixel noise amplitude (± levels).
    pub noise: u8,
    /// Frames exposed sooner than this after a switch are garbage.
    pub settle_time: Duration,
    /// Period of the grabber's frames.
    pub frame_interval: Duration,
    /// Time to deliver a frame after its exposure.
    pub transfer_time: Duration,
    /// Seed of the noise generator.
    pub seed: u64,
}

impl Default for CameraConfig {
    fn default() -> Self {
        Self {
            cameras: 7,
            fov_deg: 60.0,
            width: 320,
            height: 240,
            max_range_m: 12.0,
            background: [128, 128, 128],
            noise: 6,
            settle_time: Duration::from_millis(150),
            frame_interval: Duration::from_micros(33_333),
            transfer_time: Duration::from_millis(40),
            seed: 1,
        }
    }
}

impl CameraConfig {
    /// Worst-case time to sweep every camera once, given the switcher's reply time per
    /// selection (switch delay plus serial round trip).
    #[must_use]
    pub fn sweep_estimate(&self, switch_reply: Duration) -> Duration {
        let per = switch_reply
            .saturating_add(self.settle_time)
            .saturating_add(self.frame_interval)
            .saturating_add(self.transfer_time);
        per.saturating_mul(u32::from(self.cameras))
    }

    /// Focal length in pixels.
    #[must_use]
    pub fn focal_px(&self) -> f64 {
        let half = (self.fov_deg.to_radians() / 2.0).tan();
        if half > 0.0 {
            f64::from(self.width) / 2.0 / half
        } else {
            0.0
        }
    }

    /// Optical axis of `channel` relative to the robot's heading, radians counter-clockwise
    /// (`None` outside `1..=cameras`).
    #[must_use]
    pub fn camera_yaw_rad(&self, channel: Channel) -> Option<f64> {
        if channel == 0 || channel > self.cameras {
            return None;
        }
        Some(f64::from(channel - 1) * TAU / f64::from(self.cameras))
    }

    /// Column (pixels from the left, fractional) of something at `bearing_rad`
    /// counter-clockwise from the optical axis.
    #[must_use]
    pub fn column_for_bearing(&self, bearing_rad: f64) -> f64 {
        f64::from(self.width) / 2.0 - self.focal_px() * bearing_rad.tan()
    }
}

/// The sans-IO renderer of the camera head.
#[derive(Debug)]
pub struct CameraHead {
    cfg: CameraConfig,
    world: SharedWorld,
    robot: RobotId,
    rng: SmallRng,
}

impl CameraHead {
    /// The head on `robot` of `world`.
    #[must_use]
    pub fn new(cfg: CameraConfig, world: SharedWorld, robot: RobotId) -> Self {
        Self {
            cfg,
            world,
            robot,
            rng: SmallRng::seed_from_u64(cfg.seed),
        }
    }

    /// The settings.
    #[must_use]
    pub fn config(&self) -> &CameraConfig {
        &self.cfg
    }

    /// The view pose of `channel` now (`None` for a bad channel or robot).
    #[must_use]
    pub fn view(&self, channel: Channel) -> Option<Pose> {
        let yaw = self.cfg.camera_yaw_rad(channel)?;
        let p = self.world.with(|w| w.robot(self.robot).map(|r| r.pose()))?;
        Some(Pose::new(
            p.x_m,
            p.y_m,
            ima_hal::normalize_angle(p.theta_rad + yaw),
        ))
    }

    /// Render what `channel` shows, exposed `since_switch` after the switch to it. `None`
    /// for a channel outside `1..=cameras` (or a frame size that overflows memory).
    pub fn render(&mut self, channel: Channel, since_switch: Duration) -> Option<Frame> {
        let view = self.view(channel)?;
        let (w, h) = (self.cfg.width, self.cfg.height);
        let mut frame = Frame::black(w, h, Some(channel))?;
        if since_switch < self.cfg.settle_time {
            self.rng.fill(frame.pixels.as_mut_slice());
            return Some(frame);
        }
        let half_fov = self.cfg.fov_deg.to_radians() / 2.0;
        // (bearing, range, colour, radius) of every object and robot marker in view.
        let mut sightings = self.world.with(|wd| {
            let max = self.cfg.max_range_m;
            let mut v: Vec<(f64, f64, [u8; 3], f64)> = wd
                .visible_objects(view, half_fov, max, Some(self.robot))
                .into_iter()
                .filter_map(|s| {
                    wd.objects()
                        .get(s.object)
                        .map(|o| (s.bearing_rad, s.range_m, o.rgb, o.radius_m))
                })
                .collect();
            v.extend(
                wd.visible_markers(view, half_fov, max, Some(self.robot))
                    .into_iter()
                    .map(|m| (m.bearing_rad, m.range_m, m.rgb, m.radius_m)),
            );
            v
        });
        let mut px = vec![self.cfg.background; usize::try_from(u64::from(w) * u64::from(h)).ok()?];
        // Far things first, so near ones cover them.
        sightings.sort_by(|a, b| b.1.total_cmp(&a.1));
        let f = self.cfg.focal_px();
        let cy = f64::from(h) / 2.0;
        for (bearing_rad, range_m, rgb, radius_m) in sightings {
            let cx = self.cfg.column_for_bearing(bearing_rad);
            let (rx, ry) = disc_radii_px(f, bearing_rad, range_m, radius_m);
            let x0 = (cx - rx).floor().max(0.0) as u32;
            let x1 = ((cx + rx).ceil().max(0.0) as u32).min(w);
            let y0 = (cy - ry).floor().max(0.0) as u32;
            let y1 = ((cy + ry).ceil().max(0.0) as u32).min(h);
            for y in y0..y1 {
                for x in x0..x1 {
                    let (dx, dy) = (
                        (f64::from(x) + 0.5 - cx) / rx,
                        (f64::from(y) + 0.5 - cy) / ry,
                    );
                    if dx * dx + dy * dy <= 1.0
                        && let Some(p) = px.get_mut((y as usize) * (w as usize) + x as usize)
                    {
                        *p = rgb;
                    }
                }
            }
        }
        let n = i16::from(self.cfg.noise);
        for (dst, src) in frame.pixels.chunks_exact_mut(3).zip(px) {
            for (d, s) in dst.iter_mut().zip(src) {
                let jitter = if n > 0 {
                    self.rng.random_range(-n..=n)
                } else {
                    0
                };
                *d = (i16::from(s) + jitter).clamp(0, 255) as u8;
            }
        }
        Some(frame)
    }
}

/// Horizontal and vertical radii, pixels, of the image of a round object of radius
/// `radius_m` whose centre is `range_m` away at `bearing_rad` from the optical axis, for a
/// focal length of `f` pixels: on the axis `f·tan β` with `β = asin(r/d)` the object's
/// angular radius (≈ `f·r/d`), stretched by perspective off the axis (`/cos²b` across,
/// `/cos b` up), so the object's *angular* width is `2β` wherever it is in the picture.
/// At least one pixel each.
fn disc_radii_px(f: f64, bearing_rad: f64, range_m: f64, radius_m: f64) -> (f64, f64) {
    let c = bearing_rad.cos().abs().max(0.1);
    let d = range_m.max(radius_m * 1.01).max(1e-3);
    let r = f * radius_m / (d * d - radius_m * radius_m).max(1e-9).sqrt();
    ((r / (c * c)).max(1.0), (r / c).max(1.0))
}

/// Errors of the mock camera head.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CameraError {
    /// No channel is selected on the bus.
    NoSignal,
    /// The bus carries a channel the head does not have.
    BadChannel(Channel),
}

impl std::fmt::Display for CameraError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::NoSignal => f.write_str("no camera selected on the video bus"),
            Self::BadChannel(c) => write!(f, "the camera head has no channel {c}"),
        }
    }
}

impl std::error::Error for CameraError {}

impl ima_hal::Error for CameraError {
    fn kind(&self) -> ErrorKind {
        match self {
            Self::NoSignal => ErrorKind::Other,
            Self::BadChannel(_) => ErrorKind::InvalidArgument,
        }
    }
}

/// The camera head plus its frame grabber: a [`FrameSource`] reading the channel from a
/// [`VideoBus`].
#[derive(Debug)]
pub struct MockCameraHead {
    head: CameraHead,
    bus: VideoBus,
    epoch: tokio::time::Instant,
}

impl MockCameraHead {
    /// A head on `robot` of `world`, fed through `bus`.
    #[must_use]
    pub fn new(cfg: CameraConfig, world: SharedWorld, robot: RobotId, bus: VideoBus) -> Self {
        Self {
            head: CameraHead::new(cfg, world, robot),
            bus,
            epoch: tokio::time::Instant::now(),
        }
    }

    /// The renderer.
    #[must_use]
    pub fn head(&self) -> &CameraHead {
        &self.head
    }

    /// The bus.
    #[must_use]
    pub fn bus(&self) -> &VideoBus {
        &self.bus
    }

    /// The head's clock (the time base of frame stamps).
    #[must_use]
    pub fn now(&self) -> Instant {
        Instant::from_micros(u64::try_from(self.epoch.elapsed().as_micros()).unwrap_or(u64::MAX))
    }
}

impl ErrorType for MockCameraHead {
    type Error = CameraError;
}

impl FrameSource for MockCameraHead {
    async fn grab(&mut self) -> Result<Stamped<Frame>, CameraError> {
        // Wait for the next exposure of the grabber's frame clock.
        let period = self.head.cfg.frame_interval.max(Duration::from_millis(1));
        let elapsed = self.epoch.elapsed();
        let k = elapsed.as_nanos() / period.as_nanos() + 1;
        let next = Duration::from_nanos(u64::try_from(k * period.as_nanos()).unwrap_or(u64::MAX));
        tokio::time::sleep_until(self.epoch + next).await;
        let exposed = self.now();
        let (channel, since) = self.bus.current();
        let channel = channel.ok_or(CameraError::NoSignal)?;
        let frame = self
            .head
            .render(channel, since)
            .ok_or(CameraError::BadChannel(channel))?;
        tokio::time::sleep(self.head.cfg.transfer_time).await;
        Ok(Stamped::new(exposed, frame))
    }
}

/// Centroid column of the pixels within `tolerance` (per channel) of `rgb`, and their count.
/// For tests and tools looking for blobs.
#[must_use]
pub fn find_color(frame: &Frame, rgb: [u8; 3], tolerance: u8) -> Option<(f64, usize)> {
    let w = usize::try_from(frame.width).ok()?;
    let (mut sum, mut n) = (0f64, 0usize);
    for (i, p) in frame.pixels.chunks_exact(3).enumerate() {
        if p.iter().zip(rgb).all(|(a, b)| a.abs_diff(b) <= tolerance) {
            sum += (i % w.max(1)) as f64;
            n += 1;
        }
    }
    (n > 0).then(|| (sum / n as f64 + 0.5, n))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::World;

    fn head(cfg: CameraConfig) -> (CameraHead, SharedWorld) {
        let world = SharedWorld::new(World::default_world());
        let id = world.with(|w| w.robot_id("skeeter")).unwrap();
        (CameraHead::new(cfg, world.clone(), id), world)
    }

    #[test]
    fn red_ahead_is_in_the_middle_of_channel_1() {
        let (mut h, _) = head(CameraConfig::default());
        let f = h.render(1, Duration::from_secs(1)).unwrap();
        assert!(f.is_consistent());
        let (col, n) = find_color(&f, [220, 30, 30], 12).unwrap();
        assert!((col - 160.0).abs() < 1.0, "{col}");
        // radius 0.15 m at 3 m: f·r/d = 277·0.05 ≈ 13.9 px → ~600 px of disc.
        assert!(n > 400 && n < 800, "{n}");
    }

    #[test]
    fn green_at_60_degrees_is_left_of_centre_on_channel_2() {
        let cfg = CameraConfig::default();
        let (mut h, _) = head(cfg);
        let f = h.render(2, Duration::from_secs(1)).unwrap();
        let bearing = 60f64.to_radians() - cfg.camera_yaw_rad(2).unwrap();
        let want = cfg.column_for_bearing(bearing);
        let (col, _) = find_color(&f, [30, 180, 60], 12).unwrap();
        assert!((col - want).abs() < 1.0, "{col} vs {want}");
        assert!(want < 160.0);
        assert!(
            find_color(&f, [220, 30, 30], 12).is_none(),
            "red is out of view"
        );
    }

    #[test]
    fn frames_before_settle_are_garbage_and_bad_channels_refused() {
        let (mut h, _) = head(CameraConfig::default());
        let f = h.render(1, Duration::from_millis(10)).unwrap();
        let grey = find_color(&f, [128, 128, 128], 6).map_or(0, |c| c.1);
        assert!(
            grey < 320 * 240 / 5,
            "garbage should not look like the background"
        );
        assert!(h.render(0, Duration::ZERO).is_none());
        assert!(h.render(8, Duration::ZERO).is_none());
    }

    #[test]
    fn scooter_marker_is_drawn_at_its_bearing() {
        use crate::world::DEFAULT_SCOOTER_MARKER;
        let cfg = CameraConfig::default();
        let (mut h, world) = head(cfg);
        // Scooter is at 210° from Skeeter, 4 m: channel 4 looks along 3·360/7 ≈ 154°,
        // channel 5 along ≈ 206°.
        let f = h.render(5, Duration::from_secs(1)).unwrap();
        let bearing = 210f64.to_radians() - cfg.camera_yaw_rad(5).unwrap();
        let want = cfg.column_for_bearing(bearing);
        let (col, n) = find_color(&f, DEFAULT_SCOOTER_MARKER, 12).unwrap();
        assert!((col - want).abs() < 1.0, "{col} vs {want}");
        // radius 0.4 m at 4 m: 277·0.1 ≈ 27.7 px → ~2400 px of disc.
        assert!(n > 1800 && n < 3000, "{n}");
        // Without a marker Scooter is not drawn.
        world.with(|w| {
            let id = w.robot_id("scooter").unwrap();
            let spec = w.robot(id).unwrap().spec().clone();
            let mut w2 = World::new();
            for r in w.robots() {
                let mut s = r.spec().clone();
                if s.name == spec.name {
                    s.marker_rgb = None;
                }
                w2.add_robot(s).unwrap();
            }
            *w = w2;
        });
        let f = h.render(5, Duration::from_secs(1)).unwrap();
        assert!(find_color(&f, DEFAULT_SCOOTER_MARKER, 12).is_none());
    }

    #[test]
    fn sweep_estimate_is_under_five_seconds() {
        let est = CameraConfig::default().sweep_estimate(Duration::from_millis(40));
        assert!(est < Duration::from_secs(5), "{est:?}");
    }

    #[tokio::test(start_paused = true)]
    async fn sweep_in_virtual_time() {
        let world = SharedWorld::new(World::default_world());
        let id = world.with(|w| w.robot_id("skeeter")).unwrap();
        let bus = VideoBus::new(None);
        let cfg = CameraConfig::default();
        let mut cam = MockCameraHead::new(cfg, world, id, bus.clone());
        assert_eq!(cam.grab().await.unwrap_err(), CameraError::NoSignal);
        let start = tokio::time::Instant::now();
        for ch in 1..=7 {
            bus.switch(ch);
            tokio::time::sleep(Duration::from_millis(30) + cfg.settle_time).await;
            let f = cam.grab().await.unwrap();
            assert_eq!(f.value.channel, Some(ch));
            assert!(find_color(&f.value, cfg.background, 6).unwrap().1 > 320 * 240 / 2);
        }
        let took = start.elapsed();
        assert!(took < Duration::from_secs(5), "{took:?}");
        assert!(
            took <= cfg.sweep_estimate(Duration::from_millis(30)),
            "{took:?}"
        );
    }
}

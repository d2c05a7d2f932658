//! ima's readings as `foxglove.*` messages, and the [`Recorder`]'s sink API over them.
//!
//! Frames: `map` → `<robot>/odom` → `<robot>/base_link` → `<robot>/laser` and
//! `<robot>/camera/<channel>` (each camera's optical frame, [`Recorder::log_camera_mount`]; one
//! tree for every robot of a session). Topics: `/<robot>/laser/scan`, `/<robot>/odom` (pose in
//! the odometry frame), `/<robot>/compass`, `/<robot>/camera/<channel>` (and its
//! `/calibration`), `/<robot>/ses`, `/<robot>/sonar`, `/<robot>/truth`, `/tf`, `/broadcasts`,
//! `/events`.

use std::sync::PoisonError;

use foxglove::messages::{
    CameraCalibration, Color, FrameTransform, LaserScan, Log, PackedElementField, PointCloud, Pose,
    PoseInFrame, Quaternion, RawImage, SceneEntity, SceneUpdate, SpherePrimitive, TextPrimitive,
    Timestamp, Vector3, log, packed_element_field::NumericType,
};
use ima_hal::camera::Frame;

use crate::Recorder;
use crate::queue::Kind;
use crate::stream::Proto;

/// A planar pose: metres and radians (counter-clockwise).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Pose2 {
    /// x, metres.
    pub x_m: f64,
    /// y, metres.
    pub y_m: f64,
    /// Heading, radians.
    pub theta_rad: f64,
}

/// Where a robot is: its `odom` frame in `map`, and its `base_link` in `odom`.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct Place {
    origin: Pose2,
    odom: Pose2,
}

impl Place {
    /// The robot's `base_link` in `map`.
    fn in_map(&self) -> Pose2 {
        let (o, p) = (self.origin, self.odom);
        let (s, c) = o.theta_rad.sin_cos();
        Pose2 {
            x_m: o.x_m + c * p.x_m - s * p.y_m,
            y_m: o.y_m + s * p.x_m + c * p.y_m,
            theta_rad: o.theta_rad + p.theta_rad,
        }
    }
}

impl Pose2 {
    /// From the HAL's isometry.
    pub fn from_isometry(p: &ima_hal::Isometry2) -> Self {
        Self {
            x_m: p.translation.x,
            y_m: p.translation.y,
            theta_rad: p.rotation.angle(),
        }
    }
}

/// A Sensory EgoSphere mark: a dome vertex holding a tag.
#[derive(Debug, Clone, PartialEq)]
pub struct SesMark {
    /// Azimuth, radians, counter-clockwise from the robot's forward axis.
    pub azimuth_rad: f64,
    /// Elevation, radians.
    pub elevation_rad: f64,
    /// The tag (a colour name, or anything else).
    pub tag: String,
}

/// A marker on the map (a target, a robot's belief).
#[derive(Debug, Clone, PartialEq)]
pub struct MapMarker {
    /// The marker's id (one entity per id).
    pub id: String,
    /// Position, metres, in `map`.
    pub x_m: f64,
    /// Position, metres, in `map`.
    pub y_m: f64,
    /// Label shown next to it.
    pub label: String,
    /// A colour name (see [`colour`]).
    pub colour: String,
}

/// Timestamp of Unix nanoseconds.
pub fn stamp(ns: u64) -> Timestamp {
    let sec = u32::try_from(ns / 1_000_000_000).unwrap_or(u32::MAX);
    Timestamp::new(sec, (ns % 1_000_000_000) as u32)
}

fn quat_z(theta: f64) -> Quaternion {
    let h = theta / 2.0;
    Quaternion {
        x: 0.0,
        y: 0.0,
        z: h.sin(),
        w: h.cos(),
    }
}

/// The optical frame of `robot`'s camera on mux `channel`: `<robot>/camera/<channel>`
/// (`<robot>/camera` without one); its images' topic is the same with a leading `/`.
#[must_use]
pub fn camera_frame(robot: &str, channel: Option<u8>) -> String {
    match channel {
        Some(c) => format!("{robot}/camera/{c}"),
        None => format!("{robot}/camera"),
    }
}

/// Where a camera of a head looks, for [`Recorder::log_camera_mount`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraMount {
    /// The mux channel (`None`: a single camera).
    pub channel: Option<u8>,
    /// The lens's direction in the robot's `base_link`, radians counter-clockwise from
    /// forward.
    pub yaw_rad: f64,
    /// The horizontal field of view, radians.
    pub hfov_rad: f64,
    /// Image size, pixels.
    pub width: u32,
    /// Image size, pixels.
    pub height: u32,
}

impl CameraMount {
    /// The camera's optical frame ([`camera_frame`]).
    #[must_use]
    pub fn frame(&self, robot: &str) -> String {
        camera_frame(robot, self.channel)
    }

    /// `base_link` → the optical frame (z along the lens, x to the image's right, y down,
    /// as `foxglove.RawImage` defines it): the turn by the yaw, then the optical axes.
    #[must_use]
    pub fn transform(&self, robot: &str, at_ns: u64) -> FrameTransform {
        // The optical axes in a forward-looking camera's body frame (x forward, z up):
        // x_opt = −y, y_opt = −z, z_opt = x; as a quaternion (x, y, z, w).
        let (bx, by, bz, bw) = (-0.5, 0.5, -0.5, 0.5);
        let (s, c) = (self.yaw_rad / 2.0).sin_cos();
        FrameTransform {
            timestamp: Some(stamp(at_ns)),
            parent_frame_id: format!("{robot}/base_link"),
            child_frame_id: self.frame(robot),
            translation: Some(Vector3::default()),
            // quat_z(yaw) ⊗ optical
            rotation: Some(Quaternion {
                x: c * bx - s * by,
                y: c * by + s * bx,
                z: c * bz + s * bw,
                w: c * bw - s * bz,
            }),
        }
    }

    /// A pinhole calibration from the field of view (square pixels, the centre the principal
    /// point, no distortion): what a viewer needs to place the image in 3-D. `None` for a
    /// field of view a pinhole cannot have (180° or more, or none).
    #[must_use]
    pub fn calibration(&self, robot: &str, at_ns: u64) -> Option<CameraCalibration> {
        if !(self.hfov_rad > 0.0 && self.hfov_rad < std::f64::consts::PI) {
            return None;
        }
        let (w, h) = (f64::from(self.width), f64::from(self.height));
        let f = w / 2.0 / (self.hfov_rad / 2.0).tan();
        let (cx, cy) = (w / 2.0, h / 2.0);
        Some(CameraCalibration {
            timestamp: Some(stamp(at_ns)),
            frame_id: self.frame(robot),
            width: self.width,
            height: self.height,
            distortion_model: "plumb_bob".to_owned(),
            d: vec![0.0; 5],
            k: vec![f, 0.0, cx, 0.0, f, cy, 0.0, 0.0, 1.0],
            r: vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            p: vec![f, 0.0, cx, 0.0, 0.0, f, cy, 0.0, 0.0, 0.0, 1.0, 0.0],
        })
    }
}

pub(crate) fn pose3(p: Pose2) -> Pose {
    Pose {
        position: Some(Vector3 {
            x: p.x_m,
            y: p.y_m,
            z: 0.0,
        }),
        orientation: Some(quat_z(p.theta_rad)),
    }
}

/// An RGBA colour for a tag: the usual colour names, grey for anything else.
pub fn colour(tag: &str) -> Color {
    let (r, g, b) = match tag.to_ascii_lowercase().as_str() {
        "red" => (0.9, 0.1, 0.1),
        "green" => (0.1, 0.75, 0.2),
        "blue" => (0.15, 0.3, 0.95),
        "yellow" => (0.95, 0.85, 0.1),
        "orange" => (1.0, 0.55, 0.0),
        "purple" | "magenta" => (0.7, 0.2, 0.8),
        "cyan" => (0.1, 0.8, 0.85),
        "white" => (0.95, 0.95, 0.95),
        "black" => (0.1, 0.1, 0.1),
        _ => (0.6, 0.6, 0.6),
    };
    Color { r, g, b, a: 1.0 }
}

/// A laser scan in `frame_id`.
pub fn laser_scan(frame_id: &str, at_ns: u64, s: &ima_hal::laser::LaserScan) -> LaserScan {
    let n = s.len();
    LaserScan {
        timestamp: Some(stamp(at_ns)),
        frame_id: frame_id.to_owned(),
        pose: Some(pose3(Pose2::default())),
        start_angle: s.start_angle_rad,
        end_angle: s.angle_rad(n.saturating_sub(1)),
        ranges: s.ranges_m().iter().map(|&r| f64::from(r)).collect(),
        intensities: Vec::new(),
    }
}

/// Bytes per point of [`sonar_cloud`]: `x`, `y`, `z`, `range` as little-endian `f32`.
pub const SONAR_POINT_STRIDE: u32 = 16;

/// A sonar scan as a point cloud in `frame_id` (the robot's `base_link`): one point per
/// transducer that heard an echo (a reading below the transducer's maximum range, which
/// means "no echo"), at its range along the transducer's beam axis. Fields `x`, `y`, `z`
/// (metres, z = 0) and `range` (metres), [`SONAR_POINT_STRIDE`] bytes per point.
pub fn sonar_cloud(
    frame_id: &str,
    at_ns: u64,
    transducers: &[ima_hal::sonar::SonarTransducer],
    scan: &ima_hal::sonar::SonarScan,
) -> PointCloud {
    let mut data = Vec::with_capacity(scan.readings.len() * SONAR_POINT_STRIDE as usize);
    sonar_points(transducers, scan, &mut data);
    let field = |name: &str, offset: u32| PackedElementField {
        name: name.to_owned(),
        offset,
        r#type: NumericType::Float32 as i32,
    };
    PointCloud {
        timestamp: Some(stamp(at_ns)),
        frame_id: frame_id.to_owned(),
        pose: Some(pose3(Pose2::default())),
        point_stride: SONAR_POINT_STRIDE,
        fields: vec![
            field("x", 0),
            field("y", 4),
            field("z", 8),
            field("range", 12),
        ],
        data: data.into(),
    }
}

/// The points of [`sonar_cloud`], appended to `out`.
fn sonar_points(
    transducers: &[ima_hal::sonar::SonarTransducer],
    scan: &ima_hal::sonar::SonarScan,
    out: &mut Vec<u8>,
) {
    for r in &scan.readings {
        let Some(t) = transducers.get(usize::from(r.index)) else {
            continue;
        };
        if !r.range_m.is_finite() || r.range_m >= t.max_range_m {
            continue;
        }
        let p = t.pose * ima_hal::Point2::new(r.range_m, 0.0);
        for v in [p.x, p.y, 0.0, r.range_m] {
            out.extend_from_slice(&(v as f32).to_le_bytes());
        }
    }
}

/// A transform `parent` → `child`.
pub fn transform(parent: &str, child: &str, at_ns: u64, p: Pose2) -> FrameTransform {
    let q = pose3(p);
    FrameTransform {
        timestamp: Some(stamp(at_ns)),
        parent_frame_id: parent.to_owned(),
        child_frame_id: child.to_owned(),
        translation: q.position,
        rotation: q.orientation,
    }
}

/// A pose in `frame_id`.
pub fn pose_in_frame(frame_id: &str, at_ns: u64, p: Pose2) -> PoseInFrame {
    PoseInFrame {
        timestamp: Some(stamp(at_ns)),
        frame_id: frame_id.to_owned(),
        pose: Some(pose3(p)),
    }
}

/// An RGB frame.
pub fn raw_image(frame_id: &str, at_ns: u64, f: &Frame) -> RawImage {
    RawImage {
        timestamp: Some(stamp(at_ns)),
        frame_id: frame_id.to_owned(),
        width: f.width,
        height: f.height,
        encoding: "rgb8".to_owned(),
        step: f.width.saturating_mul(3),
        data: f.pixels.clone().into(),
    }
}

/// An `rgb8` frame as PNG (fast compression); `None` if the pixels do not make a
/// `width` × `height` frame.
pub fn png(width: u32, height: u32, pixels: &[u8]) -> Option<Vec<u8>> {
    let wanted = u128::from(width) * u128::from(height) * 3;
    if width == 0 || height == 0 || u128::try_from(pixels.len()).ok()? != wanted {
        return None;
    }
    let mut out = Vec::with_capacity(pixels.len() / 4);
    let mut enc = png::Encoder::new(&mut out, width, height);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    enc.set_compression(png::Compression::Fast);
    enc.write_header().ok()?.write_image_data(pixels).ok()?;
    Some(out)
}

/// A log line.
pub fn log_line(at_ns: u64, level: log::Level, name: &str, message: &str) -> Log {
    Log {
        timestamp: Some(stamp(at_ns)),
        level: level as i32,
        message: message.to_owned(),
        name: name.to_owned(),
        file: String::new(),
        line: 0,
    }
}

/// The SES as a scene: one sphere per occupied vertex on a 1 m dome around `frame_id`,
/// coloured by tag, with the tag as text.
pub fn ses_scene(frame_id: &str, at_ns: u64, marks: &[SesMark]) -> SceneUpdate {
    let mut e = SceneEntity {
        timestamp: Some(stamp(at_ns)),
        frame_id: frame_id.to_owned(),
        id: "ses".to_owned(),
        ..SceneEntity::default()
    };
    for m in marks {
        let (ce, se) = (m.elevation_rad.cos(), m.elevation_rad.sin());
        let pos = Vector3 {
            x: ce * m.azimuth_rad.cos(),
            y: ce * m.azimuth_rad.sin(),
            z: se,
        };
        let pose = Pose {
            position: Some(pos),
            orientation: Some(quat_z(0.0)),
        };
        e.spheres.push(SpherePrimitive {
            pose: Some(pose),
            size: Some(Vector3 {
                x: 0.12,
                y: 0.12,
                z: 0.12,
            }),
            color: Some(colour(&m.tag)),
        });
        e.texts.push(TextPrimitive {
            pose: Some(pose),
            billboard: true,
            font_size: 12.0,
            scale_invariant: true,
            color: Some(colour(&m.tag)),
            text: m.tag.clone(),
        });
    }
    SceneUpdate {
        deletions: Vec::new(),
        entities: vec![e],
    }
}

/// Markers on the map, one entity each.
pub fn map_markers(at_ns: u64, markers: &[MapMarker]) -> SceneUpdate {
    let entities = markers
        .iter()
        .map(|m| {
            let pose = pose3(Pose2 {
                x_m: m.x_m,
                y_m: m.y_m,
                theta_rad: 0.0,
            });
            SceneEntity {
                timestamp: Some(stamp(at_ns)),
                frame_id: "map".to_owned(),
                id: m.id.clone(),
                spheres: vec![SpherePrimitive {
                    pose: Some(pose),
                    size: Some(Vector3 {
                        x: 0.3,
                        y: 0.3,
                        z: 0.3,
                    }),
                    color: Some(colour(&m.colour)),
                }],
                texts: vec![TextPrimitive {
                    pose: Some(pose),
                    billboard: true,
                    font_size: 14.0,
                    scale_invariant: true,
                    color: Some(colour("white")),
                    text: m.label.clone(),
                }],
                ..SceneEntity::default()
            }
        })
        .collect();
    SceneUpdate {
        deletions: Vec::new(),
        entities,
    }
}

/// The arena in `map`: its walls as grey segments on the floor (3 cm wide) and its round
/// obstacles as grey cylinders 0.5 m tall, one entity — what the laser sees and Scooter
/// avoids, beside the coloured objects of [`map_markers`].
pub fn arena_scene(
    at_ns: u64,
    walls: &[([f64; 2], [f64; 2])],
    posts: &[([f64; 2], f64)],
) -> SceneUpdate {
    use foxglove::messages::{CylinderPrimitive, LinePrimitive, Point3, line_primitive};
    let grey = Color {
        r: 0.6,
        g: 0.6,
        b: 0.6,
        a: 1.0,
    };
    let point = |p: [f64; 2]| Point3 {
        x: p[0],
        y: p[1],
        z: 0.0,
    };
    let lines = (!walls.is_empty())
        .then(|| LinePrimitive {
            r#type: line_primitive::Type::LineList as i32,
            pose: Some(pose3(Pose2::default())),
            thickness: 0.03,
            scale_invariant: false,
            points: walls
                .iter()
                .flat_map(|(a, b)| [point(*a), point(*b)])
                .collect(),
            color: Some(grey),
            ..LinePrimitive::default()
        })
        .into_iter()
        .collect();
    let cylinders = posts
        .iter()
        .map(|(c, r)| CylinderPrimitive {
            pose: Some(pose3(Pose2 {
                x_m: c[0],
                y_m: c[1],
                theta_rad: 0.0,
            })),
            size: Some(Vector3 {
                x: 2.0 * r,
                y: 2.0 * r,
                z: 0.5,
            }),
            bottom_scale: 1.0,
            top_scale: 1.0,
            color: Some(grey),
        })
        .collect();
    SceneUpdate {
        deletions: Vec::new(),
        entities: vec![SceneEntity {
            timestamp: Some(stamp(at_ns)),
            frame_id: "map".to_owned(),
            id: "arena".to_owned(),
            lines,
            cylinders,
            ..SceneEntity::default()
        }],
    }
}

/// The sink API: readings by robot, on the topics and frames of this module.
/// `n` in decimal, written into `buf` (no allocation).
fn decimal(mut n: u8, buf: &mut [u8; 3]) -> &str {
    let mut start = buf.len();
    for slot in buf.iter_mut().rev() {
        *slot = b'0' + n % 10;
        start -= 1;
        n /= 10;
        if n == 0 {
            break;
        }
    }
    buf.get(start..)
        .and_then(|d| std::str::from_utf8(d).ok())
        .unwrap_or("")
}

impl Recorder {
    /// A planar pose on stream `s`.
    fn log_pose2(&self, s: crate::StreamId, p: Pose2) {
        self.log_pose2_at(s, self.now_ns(), p);
    }

    /// A planar pose of stream `s` stamped `at_ns` (Unix nanoseconds).
    fn log_pose2_at(&self, s: crate::StreamId, at_ns: u64, p: Pose2) {
        self.push_at(s, Kind::Pose, at_ns, 24, |b| {
            for v in [p.x_m, p.y_m, p.theta_rad] {
                b.extend_from_slice(&v.to_le_bytes());
            }
            true
        });
    }

    /// A laser scan of `robot` on `/<robot>/laser/scan` (frame `<robot>/laser`).
    pub fn log_scan(&self, robot: &str, s: &ima_hal::laser::LaserScan) {
        let stream = self.stream(&["scan", robot], || {
            let proto = Proto::Scan(LaserScan {
                frame_id: format!("{robot}/laser"),
                pose: Some(pose3(Pose2::default())),
                ..LaserScan::default()
            });
            (format!("/{robot}/laser/scan"), proto)
        });
        let ranges = s.ranges_m();
        self.push(stream, Kind::Scan, 16 + 4 * ranges.len(), |b| {
            b.extend_from_slice(&s.start_angle_rad.to_le_bytes());
            b.extend_from_slice(&s.step_rad.to_le_bytes());
            for r in ranges {
                b.extend_from_slice(&r.to_le_bytes());
            }
            true
        });
    }

    /// Odometry of `robot`: the `<robot>/odom` → `<robot>/base_link` transform on `/tf`
    /// and the pose on `/<robot>/odom`, both with one stamp.
    pub fn log_odometry(&self, robot: &str, p: Pose2) {
        let at = self.now_ns();
        let tf = self.stream(&["tf-odom", robot], || {
            let proto = Proto::Transform(FrameTransform {
                parent_frame_id: format!("{robot}/odom"),
                child_frame_id: format!("{robot}/base_link"),
                ..FrameTransform::default()
            });
            ("/tf".to_owned(), proto)
        });
        self.log_pose2_at(tf, at, p);
        let pose = self.stream(&["odom", robot], || {
            let proto = Proto::Pose(PoseInFrame {
                frame_id: format!("{robot}/odom"),
                ..PoseInFrame::default()
            });
            (format!("/{robot}/odom"), proto)
        });
        self.log_pose2_at(pose, at, p);
        self.place(robot, |pl| pl.odom = p);
    }

    /// Where `robot`'s `odom` frame is in `map` (`map` → `<robot>/odom` on `/tf`, as
    /// [`log_transform`](Self::log_transform) logs it).
    pub fn log_odom_origin(&self, robot: &str, p: Pose2) {
        self.log_transform("map", &format!("{robot}/odom"), p);
    }

    /// Update where `robot` is.
    fn place(&self, robot: &str, f: impl FnOnce(&mut Place)) {
        let mut places = (self.shared.places.lock()).unwrap_or_else(PoisonError::into_inner);
        match places.get_mut(robot) {
            Some(pl) => f(pl),
            None => f(places.entry(robot.to_owned()).or_default()),
        }
    }

    /// A static or moving transform `parent` → `child` on `/tf`.
    /// `map` → `<robot>/odom` also says where the robot's compass arrow goes
    /// ([`log_compass`](Self::log_compass)).
    pub fn log_transform(&self, parent: &str, child: &str, p: Pose2) {
        if parent == "map"
            && let Some(robot) = child.strip_suffix("/odom")
        {
            self.place(robot, |pl| pl.origin = p);
        }
        let s = self.stream(&["tf", parent, child], || {
            let proto = Proto::Transform(FrameTransform {
                parent_frame_id: parent.to_owned(),
                child_frame_id: child.to_owned(),
                ..FrameTransform::default()
            });
            ("/tf".to_owned(), proto)
        });
        self.log_pose2(s, p);
    }

    /// A pose in `frame` on `topic` (a belief, a goal).
    pub fn log_pose(&self, topic: &str, frame: &str, p: Pose2) {
        let s = self.stream(&["pose", topic, frame], || {
            let proto = Proto::Pose(PoseInFrame {
                frame_id: frame.to_owned(),
                ..PoseInFrame::default()
            });
            (topic.to_owned(), proto)
        });
        self.log_pose2(s, p);
    }

    /// The world's ground truth for `robot`: its pose in `map` on `/<robot>/truth`.
    pub fn log_ground_truth(&self, robot: &str, p: Pose2) {
        let s = self.stream(&["truth", robot], || {
            let proto = Proto::Pose(PoseInFrame {
                frame_id: "map".to_owned(),
                ..PoseInFrame::default()
            });
            (format!("/{robot}/truth"), proto)
        });
        self.log_pose2(s, p);
    }

    /// A compass heading of `robot` (radians, counter-clockwise from east: east-north-up) as
    /// an orientation in `map` on `/<robot>/compass`, placed where the robot's transforms put
    /// it (its odometry in its `odom` frame, [`log_odom_origin`](Self::log_odom_origin)). An
    /// absolute heading: in the robot's `base_link`, as it was, a viewer turned it by the
    /// robot's own yaw once more and drew it at twice the heading; at the map's origin, as it
    /// then was, it pointed away from the robot.
    pub fn log_compass(&self, robot: &str, heading_rad: f64) {
        let s = self.stream(&["compass", robot], || {
            let proto = Proto::Pose(PoseInFrame {
                frame_id: "map".to_owned(),
                ..PoseInFrame::default()
            });
            (format!("/{robot}/compass"), proto)
        });
        let at = (self
            .shared
            .places
            .lock()
            .unwrap_or_else(PoisonError::into_inner))
        .get(robot)
        .map(Place::in_map)
        .unwrap_or_default();
        let p = Pose2 {
            theta_rad: heading_rad,
            ..at
        };
        self.log_pose2(s, p);
    }

    /// A sonar scan of `robot` on `/<robot>/sonar` (see [`sonar_cloud`]; frame
    /// `<robot>/base_link`).
    pub fn log_sonar(
        &self,
        robot: &str,
        transducers: &[ima_hal::sonar::SonarTransducer],
        scan: &ima_hal::sonar::SonarScan,
    ) {
        let s = self.stream(&["sonar", robot], || {
            let mut proto = sonar_cloud(
                &format!("{robot}/base_link"),
                0,
                &[],
                &ima_hal::sonar::SonarScan::default(),
            );
            proto.data = Default::default();
            (format!("/{robot}/sonar"), Proto::Cloud(proto))
        });
        let size = scan.readings.len() * SONAR_POINT_STRIDE as usize;
        self.push(s, Kind::Cloud, size, |b| {
            sonar_points(transducers, scan, b);
            true
        });
    }

    /// A camera frame of `robot` on `/<robot>/camera/<channel>` (or `/<robot>/camera`), as
    /// [`crate::Options::images`] says: `foxglove.CompressedImage` (PNG, compressed on the
    /// recorder's thread) or `foxglove.RawImage`.
    pub fn log_image(&self, robot: &str, f: &Frame) {
        let png = self.images() == crate::Images::Png;
        let make = || {
            // In the camera's optical frame, on the topic of the same name.
            let frame_id = camera_frame(robot, f.channel);
            let topic = format!("/{frame_id}");
            let raw = RawImage {
                frame_id,
                encoding: "rgb8".to_owned(),
                ..RawImage::default()
            };
            (topic, Proto::Image { raw, png })
        };
        let mut digits = [0; 3];
        let s = match f.channel {
            Some(c) => self.stream(&["image", robot, decimal(c, &mut digits)], make),
            None => self.stream(&["image", robot], make),
        };
        self.push(s, Kind::Image, 8 + f.pixels.len(), |b| {
            b.extend_from_slice(&f.width.to_le_bytes());
            b.extend_from_slice(&f.height.to_le_bytes());
            b.extend_from_slice(&f.pixels);
            true
        });
    }

    /// Where `robot`'s camera `mount` looks: its optical frame under `<robot>/base_link` on
    /// `/tf`, and its pinhole calibration on `/<robot>/camera/<channel>/calibration`, so that a
    /// 3-D view can place its images. Log it beside each frame (a head's cameras take turns).
    pub fn log_camera_mount(&self, robot: &str, mount: &CameraMount) {
        let at = self.now_ns();
        let frame = mount.frame(robot);
        self.log_keyed(&["camtf", &frame], "/tf", mount.transform(robot, at));
        if let Some(c) = mount.calibration(robot, at) {
            self.log(&format!("/{frame}/calibration"), c);
        }
    }

    /// The SES of `robot` on `/<robot>/ses` (around `<robot>/base_link`).
    pub fn log_ses(&self, robot: &str, marks: &[SesMark]) {
        let at = self.now_ns();
        self.log(
            &format!("/{robot}/ses"),
            ses_scene(&format!("{robot}/base_link"), at, marks),
        );
    }

    /// Markers on the map on `topic` (targets, beliefs).
    pub fn log_markers(&self, topic: &str, markers: &[MapMarker]) {
        let at = self.now_ns();
        self.log(topic, map_markers(at, markers));
    }

    /// The arena's walls and round obstacles on `topic` (see [`arena_scene`]).
    pub fn log_arena(
        &self,
        topic: &str,
        walls: &[([f64; 2], [f64; 2])],
        posts: &[([f64; 2], f64)],
    ) {
        let at = self.now_ns();
        self.log(topic, arena_scene(at, walls, posts));
    }

    /// A line of text on `topic` (`/broadcasts`, `/events`) as `foxglove.Log`, `name` being
    /// who said it.
    pub fn log_text(&self, topic: &str, level: log::Level, name: &str, message: &str) {
        let s = self.stream(&["text", topic, name], || {
            let proto = Proto::Text(Log {
                name: name.to_owned(),
                ..Log::default()
            });
            (topic.to_owned(), proto)
        });
        self.push(s, Kind::Text, 1 + message.len(), |b| {
            b.push(level as u8);
            b.extend_from_slice(message.as_bytes());
            true
        });
    }

    /// A broadcast heard or said by `robot`, on `/broadcasts`.
    pub fn log_broadcast(&self, robot: &str, text: &str) {
        self.log_text("/broadcasts", log::Level::Info, robot, text);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A robot's place in `map`: its odometry turned and moved by its `odom` frame's pose.
    #[test]
    fn a_place_composes_the_odometry_frame_and_the_odometry() {
        let pl = Place {
            origin: Pose2 {
                x_m: 2.0,
                y_m: 1.0,
                theta_rad: std::f64::consts::FRAC_PI_2,
            },
            odom: Pose2 {
                x_m: 1.5,
                y_m: -0.25,
                theta_rad: 0.5,
            },
        };
        let m = pl.in_map();
        assert!((m.x_m - 2.25).abs() < 1e-12, "{m:?}");
        assert!((m.y_m - 2.5).abs() < 1e-12, "{m:?}");
        assert!((m.theta_rad - (std::f64::consts::FRAC_PI_2 + 0.5)).abs() < 1e-12);
    }
}

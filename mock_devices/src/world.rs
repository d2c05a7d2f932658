//! A 2-D simulated world: differential-drive robots, walls, round obstacles and coloured objects.
//!
//! The world is the single source of ground truth that every mock device reads: a base model
//! integrates its commanded wheel speeds here and reads back pose and wheel travel (for
//! encoders and odometry), a sonar or laser model ray-casts against it ([`World::cast`],
//! [`SonarModel`]), a compass reads the robot's heading, and a camera model asks which
//! [`ColoredObject`]s are in view ([`World::visible_objects`]).
//!
//! # Time
//!
//! The world never reads a clock. The caller advances it with [`World::step`] by a `dt`; the
//! world keeps its own virtual time ([`World::time`]). The pty runner steps it in real time from
//! a [`crate::stepper::WorldStepper`]; a simulation can step it as fast as it likes.
//!
//! # Frames and units
//!
//! World frame: x, y in metres, θ in radians counter-clockwise from +x, normalised to (−π, π].
//! Robot frame: x forward, y left (as in `ima-hal`). Wheel travel is in millimetres, signed,
//! cumulative since the robot was created.
//!
//! # Kinematics
//!
//! Each robot is a differential drive with a track width `b`. A command is either wheel
//! speeds `(vl, vr)` or a twist `(v, ω)`, converted with `vl = v − ω·b/2`, `vr = v + ω·b/2`
//! and clamped to the robot's maximum wheel speed. Each wheel's actual speed moves toward its
//! command at no more than the wheel acceleration limit. While both wheels are at their
//! commands the motion is integrated **exactly** along the circular arc of constant (v, ω);
//! during an acceleration ramp it is integrated by exact arcs over sub-steps of at most 1 ms
//! at the mean speed of each sub-step (the error is far below a millimetre).
//!
//! Robots do not collide: they pass through walls and each other. Collision response is left to
//! the agents' obstacle avoidance, which is what the mission tests measure.
//!
//! # World files
//!
//! [`World::from_toml_str`] reads the format described on [`WorldFile`]; [`World::default_world`]
//! builds the thesis demonstration arena in code.

use std::f64::consts::PI;
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::Duration;

use ima_hal::{Instant, Isometry2, Point2, normalize_angle};
use rand::Rng;
use serde::{Deserialize, Serialize};

/// Index of a robot in its [`World`] (stable: robots are never removed).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct RobotId(pub usize);

/// A pose in the world frame.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Pose {
    /// x, metres.
    pub x_m: f64,
    /// y, metres.
    pub y_m: f64,
    /// Heading, radians CCW from +x, in (−π, π].
    pub theta_rad: f64,
}

impl Pose {
    /// A pose from its parts (θ is normalised).
    #[must_use]
    pub fn new(x_m: f64, y_m: f64, theta_rad: f64) -> Self {
        Self {
            x_m,
            y_m,
            theta_rad: normalize_angle(theta_rad),
        }
    }

    /// The position as a point.
    #[must_use]
    pub fn point(&self) -> Point2 {
        Point2::new(self.x_m, self.y_m)
    }

    /// The pose as an `ima-hal` isometry.
    #[must_use]
    pub fn to_isometry(&self) -> Isometry2 {
        Isometry2::new(nalgebra_vec(self.x_m, self.y_m), self.theta_rad)
    }

    /// Compose with a pose given in this pose's frame (e.g. a sensor mount): world pose of the
    /// sensor.
    #[must_use]
    pub fn compose(&self, local: &Isometry2) -> Pose {
        let iso = self.to_isometry() * local;
        Pose::new(iso.translation.x, iso.translation.y, iso.rotation.angle())
    }
}

fn nalgebra_vec(x: f64, y: f64) -> ima_hal::Vector2 {
    ima_hal::Vector2::new(x, y)
}

/// What a robot is told to do.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum DriveCommand {
    /// Wheel surface speeds, m/s (left, right).
    Wheels {
        /// Left wheel, m/s.
        left_m_s: f64,
        /// Right wheel, m/s.
        right_m_s: f64,
    },
    /// Body twist: forward speed and turn rate.
    Twist {
        /// Forward speed, m/s.
        v_m_s: f64,
        /// Turn rate, rad/s, CCW positive.
        omega_rad_s: f64,
    },
}

impl DriveCommand {
    /// Stop both wheels.
    pub const STOP: Self = Self::Wheels {
        left_m_s: 0.0,
        right_m_s: 0.0,
    };
}

/// Static description of a robot (what a world file gives).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RobotSpec {
    /// Unique name (e.g. `skeeter`, `scooter`).
    pub name: String,
    /// Start x, metres.
    pub x_m: f64,
    /// Start y, metres.
    pub y_m: f64,
    /// Start heading, degrees CCW from +x.
    #[serde(default)]
    pub theta_deg: f64,
    /// Radius of the robot's footprint as seen by other robots' sensors, metres.
    #[serde(default = "default_radius")]
    pub radius_m: f64,
    /// Distance between the left and right wheel contact lines, metres.
    #[serde(default = "default_track")]
    pub track_width_m: f64,
    /// Largest wheel speed magnitude, m/s.
    #[serde(default = "default_max_wheel")]
    pub max_wheel_speed_m_s: f64,
    /// Largest wheel acceleration magnitude, m/s²; absent = instantaneous.
    #[serde(default)]
    pub max_wheel_accel_m_s2: Option<f64>,
    /// Colour of the marker the robot carries, as other robots' cameras see it: drawn as a
    /// disc of the footprint radius ([`RobotSpec::radius_m`]) by
    /// [`crate::camera::CameraHead`]. Absent (the default, also for world files written
    /// before markers existed) = the robot is invisible to cameras.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub marker_rgb: Option<[u8; 3]>,
}

fn default_radius() -> f64 {
    0.3
}
fn default_track() -> f64 {
    0.5
}
fn default_max_wheel() -> f64 {
    1.0
}

impl RobotSpec {
    /// A spec with defaults for everything but the name and start pose.
    #[must_use]
    pub fn new(name: &str, x_m: f64, y_m: f64, theta_deg: f64) -> Self {
        Self {
            name: name.to_owned(),
            x_m,
            y_m,
            theta_deg,
            radius_m: default_radius(),
            track_width_m: default_track(),
            max_wheel_speed_m_s: default_max_wheel(),
            max_wheel_accel_m_s2: None,
            marker_rgb: None,
        }
    }

    fn validate(&self) -> Result<(), WorldError> {
        let bad = |field: &'static str| WorldError::Invalid {
            item: format!("robot {:?}", self.name),
            field,
        };
        if self.name.is_empty() {
            return Err(bad("name"));
        }
        finite(self.x_m).ok_or_else(|| bad("x_m"))?;
        finite(self.y_m).ok_or_else(|| bad("y_m"))?;
        self.theta_deg
            .is_finite()
            .then_some(())
            .ok_or_else(|| bad("theta_deg"))?;
        positive(self.radius_m).ok_or_else(|| bad("radius_m"))?;
        positive(self.track_width_m).ok_or_else(|| bad("track_width_m"))?;
        positive(self.max_wheel_speed_m_s).ok_or_else(|| bad("max_wheel_speed_m_s"))?;
        if let Some(a) = self.max_wheel_accel_m_s2 {
            positive(a).ok_or_else(|| bad("max_wheel_accel_m_s2"))?;
        }
        Ok(())
    }
}

/// The largest magnitude of a world's coordinates and sizes (metres; speeds in m/s and
/// accelerations in m/s² too): 10 km. Larger finite numbers (a wall from −1e308 to 1e308 m) are
/// no world a robot drives in, and overflow the geometry and the plots.
pub const MAX_EXTENT_M: f64 = 10_000.0;

fn finite(x: f64) -> Option<f64> {
    (x.is_finite() && x.abs() <= MAX_EXTENT_M).then_some(x)
}
fn positive(x: f64) -> Option<f64> {
    (x.is_finite() && x > 0.0 && x <= MAX_EXTENT_M).then_some(x)
}

/// A simulated differential-drive robot.
#[derive(Debug, Clone, PartialEq)]
pub struct Robot {
    spec: RobotSpec,
    pose: Pose,
    cmd_left_m_s: f64,
    cmd_right_m_s: f64,
    left_m_s: f64,
    right_m_s: f64,
    travel_left_mm: f64,
    travel_right_mm: f64,
}

impl Robot {
    /// A robot at rest at its spec's start pose (the spec was validated by
    /// [`World::add_robot`]).
    fn new(spec: RobotSpec) -> Self {
        let pose = Pose::new(spec.x_m, spec.y_m, spec.theta_deg.to_radians());
        Self {
            spec,
            pose,
            cmd_left_m_s: 0.0,
            cmd_right_m_s: 0.0,
            left_m_s: 0.0,
            right_m_s: 0.0,
            travel_left_mm: 0.0,
            travel_right_mm: 0.0,
        }
    }

    /// The robot's name.
    #[must_use]
    pub fn name(&self) -> &str {
        &self.spec.name
    }

    /// Its static description.
    #[must_use]
    pub fn spec(&self) -> &RobotSpec {
        &self.spec
    }

    /// Ground-truth pose.
    #[must_use]
    pub fn pose(&self) -> Pose {
        self.pose
    }

    /// Teleport (e.g. to reset a scenario). Velocities are kept.
    pub fn set_pose(&mut self, pose: Pose) {
        if pose.x_m.is_finite() && pose.y_m.is_finite() && pose.theta_rad.is_finite() {
            self.pose = Pose::new(pose.x_m, pose.y_m, pose.theta_rad);
        }
    }

    /// Footprint radius, metres.
    #[must_use]
    pub fn radius_m(&self) -> f64 {
        self.spec.radius_m
    }

    /// Track width, metres.
    #[must_use]
    pub fn track_width_m(&self) -> f64 {
        self.spec.track_width_m
    }

    /// Set the command. Non-finite values count as 0; speeds are clamped to the wheel limit.
    pub fn command(&mut self, cmd: DriveCommand) {
        let (l, r) = match cmd {
            DriveCommand::Wheels {
                left_m_s,
                right_m_s,
            } => (left_m_s, right_m_s),
            DriveCommand::Twist { v_m_s, omega_rad_s } => {
                let v = or_zero(v_m_s);
                let w = or_zero(omega_rad_s) * self.spec.track_width_m / 2.0;
                (v - w, v + w)
            }
        };
        let max = self.spec.max_wheel_speed_m_s;
        self.cmd_left_m_s = or_zero(l).max(-max).min(max);
        self.cmd_right_m_s = or_zero(r).max(-max).min(max);
    }

    /// Commanded wheel speeds after clamping, m/s (left, right).
    #[must_use]
    pub fn commanded_wheels(&self) -> (f64, f64) {
        (self.cmd_left_m_s, self.cmd_right_m_s)
    }

    /// Actual wheel speeds, m/s (left, right).
    #[must_use]
    pub fn wheel_speeds(&self) -> (f64, f64) {
        (self.left_m_s, self.right_m_s)
    }

    /// Actual body velocity `(v m/s, ω rad/s)`.
    #[must_use]
    pub fn velocity(&self) -> (f64, f64) {
        twist(self.left_m_s, self.right_m_s, self.spec.track_width_m)
    }

    /// Cumulative signed wheel travel in millimetres (left, right), for encoder models.
    #[must_use]
    pub fn wheel_travel_mm(&self) -> (f64, f64) {
        (self.travel_left_mm, self.travel_right_mm)
    }

    /// Advance by `dt` seconds (non-finite or non-positive `dt` does nothing).
    pub fn step(&mut self, dt: f64) {
        if !(dt.is_finite() && dt > 0.0) {
            return;
        }
        let mut remaining = dt;
        // Ramp phase: piecewise-linear wheel speeds until both reach their commands.
        if let Some(accel) = self.spec.max_wheel_accel_m_s2 {
            let mut guard = 0;
            while remaining > 0.0 && guard < 4 {
                guard += 1;
                let tl = (self.cmd_left_m_s - self.left_m_s).abs() / accel;
                let tr = (self.cmd_right_m_s - self.right_m_s).abs() / accel;
                // Next breakpoint: one wheel reaches its command.
                let next = [tl, tr]
                    .into_iter()
                    .filter(|t| *t > 0.0)
                    .fold(f64::INFINITY, f64::min);
                if !next.is_finite() {
                    break;
                }
                let seg = next.min(remaining);
                self.ramp_segment(seg, accel);
                remaining -= seg;
            }
        } else {
            self.left_m_s = self.cmd_left_m_s;
            self.right_m_s = self.cmd_right_m_s;
        }
        if remaining > 0.0 {
            let (l, r) = (self.left_m_s, self.right_m_s);
            self.arc(l, r, remaining);
            self.travel_left_mm += l * remaining * 1000.0;
            self.travel_right_mm += r * remaining * 1000.0;
        }
    }

    /// Both wheels accelerate (toward their commands) linearly for `seg` seconds.
    fn ramp_segment(&mut self, seg: f64, accel: f64) {
        let lim = accel * seg;
        let dl = (self.cmd_left_m_s - self.left_m_s).max(-lim).min(lim) / seg;
        let dr = (self.cmd_right_m_s - self.right_m_s).max(-lim).min(lim) / seg;
        // Sub-steps of at most 1 ms (and at most 10 000 of them).
        let n = (seg / 1e-3).ceil().clamp(1.0, 10_000.0);
        let h = seg / n;
        let steps = n as u32;
        for _ in 0..steps {
            let l0 = self.left_m_s;
            let r0 = self.right_m_s;
            let l1 = l0 + dl * h;
            let r1 = r0 + dr * h;
            self.arc((l0 + l1) / 2.0, (r0 + r1) / 2.0, h);
            self.travel_left_mm += (l0 + l1) / 2.0 * h * 1000.0;
            self.travel_right_mm += (r0 + r1) / 2.0 * h * 1000.0;
            self.left_m_s = l1;
            self.right_m_s = r1;
        }
        // Land exactly on the command when the segment ended at a breakpoint.
        if (self.cmd_left_m_s - self.left_m_s).abs() < 1e-9 {
            self.left_m_s = self.cmd_left_m_s;
        }
        if (self.cmd_right_m_s - self.right_m_s).abs() < 1e-9 {
            self.right_m_s = self.cmd_right_m_s;
        }
    }

    /// Exact integration of constant wheel speeds over `t` seconds.
    fn arc(&mut self, l: f64, r: f64, t: f64) {
        let (v, w) = twist(l, r, self.spec.track_width_m);
        let th = self.pose.theta_rad;
        let dth = w * t;
        let (dx, dy) = if dth.abs() < 1e-9 {
            // Straight line (second-order term keeps tiny turns accurate).
            let mid = th + dth / 2.0;
            (v * t * mid.cos(), v * t * mid.sin())
        } else {
            let k = v / w;
            (
                k * ((th + dth).sin() - th.sin()),
                -k * ((th + dth).cos() - th.cos()),
            )
        };
        self.pose = Pose::new(self.pose.x_m + dx, self.pose.y_m + dy, th + dth);
    }
}

fn or_zero(x: f64) -> f64 {
    if x.is_finite() { x } else { 0.0 }
}

fn twist(l: f64, r: f64, track: f64) -> (f64, f64) {
    ((l + r) / 2.0, (r - l) / track)
}

/// A wall: a line segment.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Wall {
    /// One end `[x, y]`, metres.
    pub from: [f64; 2],
    /// The other end `[x, y]`, metres.
    pub to: [f64; 2],
}

/// A round obstacle (a post, a barrel).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Circle {
    /// Centre `[x, y]`, metres.
    pub center: [f64; 2],
    /// Radius, metres.
    pub radius_m: f64,
}

/// A coloured object (what the thesis's cameras look for): a round obstacle with a colour.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ColoredObject {
    /// Colour name as the colour database calls it (`red`, `blue`, …).
    pub color: String,
    /// Its colour as seen by a camera, 8-bit RGB.
    pub rgb: [u8; 3],
    /// Centre `[x, y]`, metres.
    pub center: [f64; 2],
    /// Radius, metres.
    pub radius_m: f64,
}

/// What a ray hit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Target {
    /// A wall, by index in [`World::walls`].
    Wall(usize),
    /// A round obstacle, by index in [`World::circles`].
    Circle(usize),
    /// A coloured object, by index in [`World::objects`].
    Object(usize),
    /// A robot's footprint.
    Robot(RobotId),
}

/// A ray-cast hit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// Distance from the ray origin, metres (0 if the origin is inside the thing).
    pub distance_m: f64,
    /// What was hit.
    pub target: Target,
}

/// A coloured object seen from a viewpoint (see [`World::visible_objects`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sighting {
    /// Index in [`World::objects`].
    pub object: usize,
    /// Bearing of the object's centre relative to the viewing direction, radians CCW.
    pub bearing_rad: f64,
    /// Distance to the object's centre, metres.
    pub range_m: f64,
}

/// A robot's marker seen from a viewpoint (see [`World::visible_markers`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MarkerSighting {
    /// The robot.
    pub robot: RobotId,
    /// Its marker colour.
    pub rgb: [u8; 3],
    /// The marker's radius (the robot's footprint radius), metres.
    pub radius_m: f64,
    /// Bearing of the robot's centre relative to the viewing direction, radians CCW.
    pub bearing_rad: f64,
    /// Distance to the robot's centre, metres.
    pub range_m: f64,
}

/// Scooter's marker colour in [`World::default_world`]: white-ish, a colour no object has.
pub const DEFAULT_SCOOTER_MARKER: [u8; 3] = [235, 235, 235];

/// Errors of world construction and world files.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum WorldError {
    /// The TOML did not parse or did not match the schema.
    #[error("world file: {0}")]
    Toml(String),
    /// A number is out of range (non-finite, beyond [`MAX_EXTENT_M`], or a radius/width that is
    /// not positive).
    #[error(
        "{item}: invalid {field} (numbers must be finite and within ±{MAX_EXTENT_M}; sizes \
         positive)"
    )]
    Invalid {
        /// Which item (e.g. `robot "skeeter"`, `wall 3`).
        item: String,
        /// Which field.
        field: &'static str,
    },
    /// The file could not be read.
    #[error("world file: {0}")]
    Io(String),
    /// Two robots share a name.
    #[error("duplicate robot name {0:?}")]
    DuplicateRobot(String),
}

/// The TOML world file.
///
/// ```toml
/// seed = 7                      # optional: seed for sensor noise in models built from the world
///
/// [[robot]]
/// name = "skeeter"
/// x_m = 0.0
/// y_m = 0.0
/// theta_deg = 0.0               # optional, default 0
/// radius_m = 0.33               # optional, default 0.3
/// track_width_m = 0.588         # optional, default 0.5
/// max_wheel_speed_m_s = 1.2     # optional, default 1.0
/// max_wheel_accel_m_s2 = 0.5    # optional, default: instantaneous
/// marker_rgb = [235, 235, 235]  # optional: marker colour seen by cameras; default none
///
/// [[wall]]
/// from = [-5.0, -5.0]
/// to = [5.0, -5.0]
///
/// [[circle]]
/// center = [1.0, 1.0]
/// radius_m = 0.1
///
/// [[object]]
/// color = "red"
/// rgb = [220, 30, 30]
/// center = [3.0, 0.0]
/// radius_m = 0.15
/// ```
///
/// Unknown keys are errors (a typo should not silently build another world).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WorldFile {
    /// Seed for noise in sensor models.
    #[serde(default)]
    pub seed: u64,
    /// Robots.
    #[serde(default, rename = "robot")]
    pub robots: Vec<RobotSpec>,
    /// Walls.
    #[serde(default, rename = "wall")]
    pub walls: Vec<Wall>,
    /// Round obstacles.
    #[serde(default, rename = "circle")]
    pub circles: Vec<Circle>,
    /// Coloured objects.
    #[serde(default, rename = "object")]
    pub objects: Vec<ColoredObject>,
}

/// The simulated world.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct World {
    seed: u64,
    time: Instant,
    robots: Vec<Robot>,
    walls: Vec<Wall>,
    circles: Vec<Circle>,
    objects: Vec<ColoredObject>,
}

fn finite_pt(p: [f64; 2]) -> bool {
    p.iter().all(|v| finite(*v).is_some())
}

impl World {
    /// An empty world at time zero.
    #[must_use]
    pub fn new() -> Self {
        Self::default()
    }

    /// Build from a parsed world file, validating every number.
    pub fn from_file(file: WorldFile) -> Result<Self, WorldError> {
        let mut w = World {
            seed: file.seed,
            ..World::default()
        };
        for r in file.robots {
            w.add_robot(r)?;
        }
        for wall in file.walls {
            w.add_wall(wall)?;
        }
        for c in file.circles {
            w.add_circle(c)?;
        }
        for o in file.objects {
            w.add_object(o)?;
        }
        Ok(w)
    }

    /// Parse a TOML world file (format on [`WorldFile`]).
    pub fn from_toml_str(s: &str) -> Result<Self, WorldError> {
        let file: WorldFile = toml::from_str(s)
            .map_err(|e| WorldError::Toml(ima_hal::file::located(s, e.span(), e.message())))?;
        Self::from_file(file)
    }

    /// Read and parse a TOML world file.
    pub fn from_toml_path(path: &std::path::Path) -> Result<Self, WorldError> {
        let text = ima_hal::file::read_text(path)
            .map_err(|e| WorldError::Io(format!("{}: {e}", path.display())))?;
        Self::from_toml_str(&text)
    }

    /// The world as a world file (time and motion state are not saved).
    #[must_use]
    pub fn to_file(&self) -> WorldFile {
        WorldFile {
            seed: self.seed,
            robots: self
                .robots
                .iter()
                .map(|r| {
                    let mut s = r.spec.clone();
                    s.x_m = r.pose.x_m;
                    s.y_m = r.pose.y_m;
                    s.theta_deg = r.pose.theta_rad.to_degrees();
                    s
                })
                .collect(),
            walls: self.walls.clone(),
            circles: self.circles.clone(),
            objects: self.objects.clone(),
        }
    }

    /// The thesis demonstration arena: a 10 m × 10 m room centred on the origin; Skeeter
    /// (Pioneer 2-AT) at the centre facing +x, Scooter (ATRV-Jr) 4 m from the centre at
    /// bearing 210° (between two objects, so Skeeter sees it) facing the centre, and a ring of
    /// six coloured objects 3 m from the centre, one every 60° starting at +x: red, green,
    /// blue, yellow, orange, purple. Scooter carries a white-ish marker `[235, 235, 235]`
    /// (a colour no object has) so Skeeter's cameras can find it; Skeeter carries none.
    ///
    /// Robot figures: Skeeter's track 0.588 m (P2OS DiffConvFactor, p2os.md §8), footprint
    /// radius 0.33 m, wheels ≤ 1.2 m/s; Scooter's track 0.42 m, radius 0.40 m, wheels
    /// ≤ 1.0 m/s (approximate ATRV-Jr figures). Both accelerate wheels at ≤ 1 m/s².
    #[must_use]
    pub fn default_world() -> Self {
        let mut w = World::new();
        let half = 5.0;
        let corners = [[-half, -half], [half, -half], [half, half], [-half, half]];
        for i in 0..4 {
            let from = corners.get(i).copied().unwrap_or_default();
            let to = corners.get((i + 1) % 4).copied().unwrap_or_default();
            let _ = w.add_wall(Wall { from, to });
        }
        let mut skeeter = RobotSpec::new("skeeter", 0.0, 0.0, 0.0);
        skeeter.radius_m = 0.33;
        skeeter.track_width_m = 0.588;
        skeeter.max_wheel_speed_m_s = 1.2;
        skeeter.max_wheel_accel_m_s2 = Some(1.0);
        let a = 210f64.to_radians();
        let mut scooter = RobotSpec::new("scooter", 4.0 * a.cos(), 4.0 * a.sin(), 30.0);
        scooter.radius_m = 0.4;
        scooter.track_width_m = 0.42;
        scooter.max_wheel_speed_m_s = 1.0;
        scooter.max_wheel_accel_m_s2 = Some(1.0);
        scooter.marker_rgb = Some(DEFAULT_SCOOTER_MARKER);
        let _ = w.add_robot(skeeter);
        let _ = w.add_robot(scooter);
        let colours: [(&str, [u8; 3]); 6] = [
            ("red", [220, 30, 30]),
            ("green", [30, 180, 60]),
            ("blue", [30, 60, 220]),
            ("yellow", [240, 220, 40]),
            ("orange", [250, 140, 20]),
            ("purple", [140, 40, 170]),
        ];
        for (i, (name, rgb)) in colours.iter().enumerate() {
            let a = i as f64 * PI / 3.0;
            let _ = w.add_object(ColoredObject {
                color: (*name).to_owned(),
                rgb: *rgb,
                center: [3.0 * a.cos(), 3.0 * a.sin()],
                radius_m: 0.15,
            });
        }
        w
    }

    /// Seed for sensor-noise generators of models built on this world.
    #[must_use]
    pub fn seed(&self) -> u64 {
        self.seed
    }

    /// Set the noise seed.
    pub fn set_seed(&mut self, seed: u64) {
        self.seed = seed;
    }

    /// Virtual time: the sum of every `dt` given to [`World::step`].
    #[must_use]
    pub fn time(&self) -> Instant {
        self.time
    }

    /// Add a robot; its name must be new.
    pub fn add_robot(&mut self, spec: RobotSpec) -> Result<RobotId, WorldError> {
        spec.validate()?;
        if self.robot_id(&spec.name).is_some() {
            return Err(WorldError::DuplicateRobot(spec.name));
        }
        self.robots.push(Robot::new(spec));
        Ok(RobotId(self.robots.len() - 1))
    }

    /// Add a wall (both ends finite); returns its index.
    pub fn add_wall(&mut self, wall: Wall) -> Result<usize, WorldError> {
        let bad = |field| invalid(format!("wall {}", self.walls.len()), field);
        if !finite_pt(wall.from) {
            return Err(bad("from"));
        }
        if !finite_pt(wall.to) {
            return Err(bad("to"));
        }
        self.walls.push(wall);
        Ok(self.walls.len() - 1)
    }

    /// Add a round obstacle; returns its index.
    pub fn add_circle(&mut self, c: Circle) -> Result<usize, WorldError> {
        let bad = |field| invalid(format!("circle {}", self.circles.len()), field);
        if !finite_pt(c.center) {
            return Err(bad("center"));
        }
        positive(c.radius_m).ok_or_else(|| bad("radius_m"))?;
        self.circles.push(c);
        Ok(self.circles.len() - 1)
    }

    /// Add a coloured object (non-empty colour name); returns its index.
    pub fn add_object(&mut self, o: ColoredObject) -> Result<usize, WorldError> {
        let bad = |field| invalid(format!("object {}", self.objects.len()), field);
        if !finite_pt(o.center) {
            return Err(bad("center"));
        }
        positive(o.radius_m).ok_or_else(|| bad("radius_m"))?;
        if o.color.is_empty() {
            return Err(bad("color"));
        }
        self.objects.push(o);
        Ok(self.objects.len() - 1)
    }

    /// All robots, indexed by [`RobotId`].
    #[must_use]
    pub fn robots(&self) -> &[Robot] {
        &self.robots
    }

    /// Walls.
    #[must_use]
    pub fn walls(&self) -> &[Wall] {
        &self.walls
    }

    /// Round obstacles.
    #[must_use]
    pub fn circles(&self) -> &[Circle] {
        &self.circles
    }

    /// Coloured objects.
    #[must_use]
    pub fn objects(&self) -> &[ColoredObject] {
        &self.objects
    }

    /// The id of the robot with this name.
    #[must_use]
    pub fn robot_id(&self, name: &str) -> Option<RobotId> {
        self.robots
            .iter()
            .position(|r| r.name() == name)
            .map(RobotId)
    }

    /// A robot.
    #[must_use]
    pub fn robot(&self, id: RobotId) -> Option<&Robot> {
        self.robots.get(id.0)
    }

    /// A robot, mutably (to command or teleport it).
    pub fn robot_mut(&mut self, id: RobotId) -> Option<&mut Robot> {
        self.robots.get_mut(id.0)
    }

    /// Command a robot; `false` if there is no such robot.
    pub fn command(&mut self, id: RobotId, cmd: DriveCommand) -> bool {
        self.robot_mut(id).map(|r| r.command(cmd)).is_some()
    }

    /// Advance virtual time by `dt`, moving every robot.
    pub fn step(&mut self, dt: Duration) {
        let secs = dt.as_secs_f64();
        for r in &mut self.robots {
            r.step(secs);
        }
        self.time = self.time + dt;
    }

    /// Cast a ray from `origin` in world direction `dir_rad`; the nearest hit within
    /// `max_range_m`, against walls, circles, objects and every robot.
    #[must_use]
    pub fn cast(&self, origin: Point2, dir_rad: f64, max_range_m: f64) -> Option<Hit> {
        self.cast_ignoring(origin, dir_rad, max_range_m, None)
    }

    /// As [`World::cast`], but robot `ignore` (the one carrying the sensor) is transparent.
    #[must_use]
    pub fn cast_ignoring(
        &self,
        origin: Point2,
        dir_rad: f64,
        max_range_m: f64,
        ignore: Option<RobotId>,
    ) -> Option<Hit> {
        if !(origin.x.is_finite()
            && origin.y.is_finite()
            && dir_rad.is_finite()
            && max_range_m.is_finite()
            && max_range_m >= 0.0)
        {
            return None;
        }
        let (dx, dy) = (dir_rad.cos(), dir_rad.sin());
        let o = (origin.x, origin.y);
        let mut best: Option<Hit> = None;
        let mut consider = |t: Option<f64>, target: Target| {
            if let Some(t) = t
                && t <= max_range_m
                && best.is_none_or(|b| t < b.distance_m)
            {
                best = Some(Hit {
                    distance_m: t,
                    target,
                });
            }
        };
        for (i, w) in self.walls.iter().enumerate() {
            consider(ray_segment(o, (dx, dy), w.from, w.to), Target::Wall(i));
        }
        for (i, c) in self.circles.iter().enumerate() {
            consider(
                ray_circle(o, (dx, dy), c.center, c.radius_m),
                Target::Circle(i),
            );
        }
        for (i, c) in self.objects.iter().enumerate() {
            consider(
                ray_circle(o, (dx, dy), c.center, c.radius_m),
                Target::Object(i),
            );
        }
        for (i, r) in self.robots.iter().enumerate() {
            if Some(RobotId(i)) == ignore {
                continue;
            }
            let c = [r.pose.x_m, r.pose.y_m];
            consider(
                ray_circle(o, (dx, dy), c, r.radius_m()),
                Target::Robot(RobotId(i)),
            );
        }
        best
    }

    /// Coloured objects whose centre lies within `half_fov_rad` of `view`'s heading, closer than
    /// `max_range_m`, and not hidden: a ray to the centre hits that object first. Robot
    /// `ignore` (the viewer) is transparent. Sorted by bearing, right to left.
    #[must_use]
    pub fn visible_objects(
        &self,
        view: Pose,
        half_fov_rad: f64,
        max_range_m: f64,
        ignore: Option<RobotId>,
    ) -> Vec<Sighting> {
        let mut out = Vec::new();
        for (i, o) in self.objects.iter().enumerate() {
            let (ex, ey) = (o.center[0] - view.x_m, o.center[1] - view.y_m);
            let range = ex.hypot(ey);
            if range.is_nan() || range > max_range_m {
                continue;
            }
            let abs_dir = ey.atan2(ex);
            let bearing = normalize_angle(abs_dir - view.theta_rad);
            if bearing.is_nan() || bearing.abs() > half_fov_rad {
                continue;
            }
            let hit = self.cast_ignoring(view.point(), abs_dir, range, ignore);
            if hit.is_some_and(|h| h.target == Target::Object(i)) {
                out.push(Sighting {
                    object: i,
                    bearing_rad: bearing,
                    range_m: range,
                });
            }
        }
        out.sort_by(|a, b| a.bearing_rad.total_cmp(&b.bearing_rad));
        out
    }

    /// Markers of robots (those with a [`RobotSpec::marker_rgb`]) whose centre lies within
    /// `half_fov_rad` of `view`'s heading, closer than `max_range_m`, and not hidden: a ray
    /// to the centre hits that robot first. Robot `ignore` (the viewer) is transparent and
    /// never listed. Sorted by bearing, right to left.
    #[must_use]
    pub fn visible_markers(
        &self,
        view: Pose,
        half_fov_rad: f64,
        max_range_m: f64,
        ignore: Option<RobotId>,
    ) -> Vec<MarkerSighting> {
        let mut out = Vec::new();
        for (i, r) in self.robots.iter().enumerate() {
            let id = RobotId(i);
            let Some(rgb) = r.spec.marker_rgb else {
                continue;
            };
            if Some(id) == ignore {
                continue;
            }
            let (ex, ey) = (r.pose.x_m - view.x_m, r.pose.y_m - view.y_m);
            let range = ex.hypot(ey);
            if range.is_nan() || range > max_range_m {
                continue;
            }
            let abs_dir = ey.atan2(ex);
            let bearing = normalize_angle(abs_dir - view.theta_rad);
            if bearing.is_nan() || bearing.abs() > half_fov_rad {
                continue;
            }
            let hit = self.cast_ignoring(view.point(), abs_dir, range, ignore);
            if hit.is_some_and(|h| h.target == Target::Robot(id)) {
                out.push(MarkerSighting {
                    robot: id,
                    rgb,
                    radius_m: r.radius_m(),
                    bearing_rad: bearing,
                    range_m: range,
                });
            }
        }
        out.sort_by(|a, b| a.bearing_rad.total_cmp(&b.bearing_rad));
        out
    }
}

fn invalid(item: String, field: &'static str) -> WorldError {
    WorldError::Invalid { item, field }
}

/// A robot that starts overlapping something: see [`World::start_overlap`]. Its `Display` is
/// the sentence a user reads, e.g. `scooter starts at (-3.00, 0.00) overlapping the red object
/// at (-3.10, 0.20) (0.22 m from it; it needs 0.45 m)`.
#[derive(Debug, Clone, PartialEq)]
pub struct StartOverlap {
    /// The robot.
    pub robot: String,
    /// Its start, `[x, y]` metres.
    pub at: [f64; 2],
    /// What it overlaps, in words (`scooter at (0.20, 0.00)`, `the wall from … to …`).
    pub what: String,
    /// The distance from the robot's centre to the other shape (its centre, or the wall).
    pub gap_m: f64,
    /// The distance the two would need to be clear of each other.
    pub needs_m: f64,
}

impl core::fmt::Display for StartOverlap {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(
            f,
            "{} starts at {} overlapping {} ({:.2} m from it; it needs {:.2} m)",
            self.robot,
            point_text(self.at),
            self.what,
            self.gap_m,
            self.needs_m
        )
    }
}

/// A point as messages show it: `(x.xx, y.yy)`, metres.
#[must_use]
pub fn point_text(p: [f64; 2]) -> String {
    format!("({:.2}, {:.2})", p[0], p[1])
}

impl World {
    /// The first robot whose start overlaps another robot, a round obstacle, a coloured
    /// object or a wall, if any. The world itself lets robots pass through everything; a
    /// mission that starts so could only fail (nothing can be seen or reached from inside it).
    #[must_use]
    pub fn start_overlap(&self) -> Option<StartOverlap> {
        let dist = |a: [f64; 2], b: [f64; 2]| (a[0] - b[0]).hypot(a[1] - b[1]);
        let start = |s: &RobotSpec| [s.x_m, s.y_m];
        for (i, r) in self.robots.iter().enumerate() {
            let s = &r.spec;
            let p = start(s);
            let others = self.robots.iter().skip(i + 1).map(|o| {
                let o = &o.spec;
                let what = format!("{} at {}", o.name, point_text(start(o)));
                (what, dist(p, start(o)), s.radius_m + o.radius_m)
            });
            let circles = self.circles.iter().map(|c| {
                let what = format!("the obstacle at {}", point_text(c.center));
                (what, dist(p, c.center), s.radius_m + c.radius_m)
            });
            let objects = self.objects.iter().map(|o| {
                let what = format!("the {} object at {}", o.color, point_text(o.center));
                (what, dist(p, o.center), s.radius_m + o.radius_m)
            });
            let walls = self.walls.iter().map(|w| {
                let what = format!(
                    "the wall from {} to {}",
                    point_text(w.from),
                    point_text(w.to)
                );
                (what, segment_distance(p, w.from, w.to), s.radius_m)
            });
            let mut all = others.chain(circles).chain(objects).chain(walls);
            if let Some((what, gap_m, needs_m)) = all.find(|(_, gap, needs)| gap < needs) {
                return Some(StartOverlap {
                    robot: s.name.clone(),
                    at: p,
                    what,
                    gap_m,
                    needs_m,
                });
            }
        }
        None
    }
}

/// The distance from `p` to the segment from `a` to `b`.
fn segment_distance(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let len2 = dx * dx + dy * dy;
    let t = if len2 > 0.0 {
        (((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (p[0] - a[0] - t * dx).hypot(p[1] - a[1] - t * dy)
}

/// Distance along a unit ray to a segment, if it crosses it ahead (t ≥ 0).
fn ray_segment(o: (f64, f64), d: (f64, f64), a: [f64; 2], b: [f64; 2]) -> Option<f64> {
    let [ax, ay] = a;
    let [bx, by] = b;
    let (ex, ey) = (bx - ax, by - ay);
    let denom = d.0 * ey - d.1 * ex;
    if denom.abs() < 1e-12 {
        return None; // parallel (a grazing ray does not echo)
    }
    let (wx, wy) = (ax - o.0, ay - o.1);
    let t = (wx * ey - wy * ex) / denom;
    let u = (wx * d.1 - wy * d.0) / denom;
    (t >= 0.0 && (0.0..=1.0).contains(&u)).then_some(t)
}

/// Distance along a unit ray to a circle's boundary; 0 if the origin is inside.
fn ray_circle(o: (f64, f64), d: (f64, f64), c: [f64; 2], r: f64) -> Option<f64> {
    let (fx, fy) = (o.0 - c[0], o.1 - c[1]);
    let cc = fx * fx + fy * fy - r * r;
    if cc <= 0.0 {
        return Some(0.0);
    }
    let b = fx * d.0 + fy * d.1;
    let disc = b * b - cc;
    if disc < 0.0 {
        return None;
    }
    let t = -b - disc.sqrt();
    (t >= 0.0).then_some(t)
}

/// A world shared between device models and the stepper: `Arc<Mutex<World>>` with a lock that
/// shrugs off poisoning (a panicked holder cannot have left the world half-updated in a way
/// that matters more than stopping the whole simulation would).
///
/// Models that need the world hold a clone of the handle and lock it briefly inside their
/// `handle_rx`/`handle_timeout`; never hold the guard across I/O.
#[derive(Debug, Clone, Default)]
pub struct SharedWorld(Arc<Mutex<World>>);

impl SharedWorld {
    /// Wrap a world.
    #[must_use]
    pub fn new(world: World) -> Self {
        Self(Arc::new(Mutex::new(world)))
    }

    /// Lock the world.
    pub fn lock(&self) -> MutexGuard<'_, World> {
        self.0.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Run `f` with the world locked.
    pub fn with<R>(&self, f: impl FnOnce(&mut World) -> R) -> R {
        f(&mut self.lock())
    }
}

/// A sonar transducer model: a cone of `beam_width_rad` sampled by `rays` rays; the nearest
/// echo, plus Gaussian noise, clamped to `[min_range_m, max_range_m]`. No echo reads
/// `max_range_m` exactly (as the P2OS firmware reports it, p2os.md §8: 10 cm – 5 m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SonarModel {
    /// Shortest reported range, metres.
    pub min_range_m: f64,
    /// Longest reported range and the "no echo" value, metres.
    pub max_range_m: f64,
    /// Full beam width, radians (the default 25° is typical of Polaroid 6500 transducers).
    pub beam_width_rad: f64,
    /// Rays sampled across the beam (at least 1; one ray is the beam axis).
    pub rays: u16,
    /// Standard deviation of the range noise, metres (0 = exact).
    pub noise_std_m: f64,
}

impl Default for SonarModel {
    fn default() -> Self {
        Self {
            min_range_m: 0.1,
            max_range_m: 5.0,
            beam_width_rad: 25f64.to_radians(),
            rays: 7,
            noise_std_m: 0.01,
        }
    }
}

impl SonarModel {
    /// A model with a transducer's limits and beam width (and the default rays and noise).
    #[must_use]
    pub fn from_transducer(t: &ima_hal::sonar::SonarTransducer) -> Self {
        Self {
            min_range_m: t.min_range_m,
            max_range_m: t.max_range_m,
            beam_width_rad: t.beam_width_rad,
            ..Self::default()
        }
    }

    /// The noiseless nearest echo in the beam from world pose `sensor` (the robot `ignore` is
    /// transparent), before clamping; `None` = no echo within `max_range_m`.
    #[must_use]
    pub fn nearest_echo(
        &self,
        world: &World,
        sensor: Pose,
        ignore: Option<RobotId>,
    ) -> Option<Hit> {
        let n = self.rays.max(1);
        let width = if self.beam_width_rad.is_finite() {
            self.beam_width_rad.clamp(0.0, PI)
        } else {
            0.0
        };
        let mut best: Option<Hit> = None;
        for k in 0..n {
            let off = if n == 1 {
                0.0
            } else {
                -width / 2.0 + width * f64::from(k) / f64::from(n - 1)
            };
            let h = world.cast_ignoring(
                sensor.point(),
                sensor.theta_rad + off,
                self.max_range_m,
                ignore,
            );
            if let Some(h) = h
                && best.is_none_or(|b| h.distance_m < b.distance_m)
            {
                best = Some(h);
            }
        }
        best
    }

    /// One reading in metres from a transducer mounted at `mount` (robot frame) on `robot`.
    /// Returns `max_range_m` for no echo, or if the robot does not exist.
    pub fn measure(
        &self,
        world: &World,
        robot: RobotId,
        mount: &Isometry2,
        rng: &mut impl Rng,
    ) -> f64 {
        let Some(r) = world.robot(robot) else {
            return self.max_range_m;
        };
        let sensor = r.pose().compose(mount);
        self.measure_from(world, sensor, Some(robot), rng)
    }

    /// One reading in metres from world pose `sensor` (robot `ignore` transparent).
    pub fn measure_from(
        &self,
        world: &World,
        sensor: Pose,
        ignore: Option<RobotId>,
        rng: &mut impl Rng,
    ) -> f64 {
        // Sanitise a hand-built config instead of panicking in `clamp`.
        let max = if self.max_range_m.is_finite() && self.max_range_m > 0.0 {
            self.max_range_m
        } else {
            0.0
        };
        let min = if self.min_range_m.is_finite() && self.min_range_m > 0.0 {
            self.min_range_m.min(max)
        } else {
            0.0
        };
        match self.nearest_echo(world, sensor, ignore) {
            None => max,
            Some(h) => {
                let noise = if self.noise_std_m.is_finite() {
                    gaussian(rng) * self.noise_std_m
                } else {
                    0.0
                };
                let noisy = h.distance_m + noise;
                if noisy.is_finite() {
                    noisy.clamp(min, max)
                } else {
                    max
                }
            }
        }
    }
}

/// A scanning range finder (a SICK LMS and the like): `count` beams from `start_rad`
/// (relative to the mount's heading, CCW) every `step_rad`, each a single ray, with Gaussian
/// noise. The LMS 200 default is 181 beams from −90° every 1°, 8.191 m in mm mode.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LaserModel {
    /// Angle of the first beam relative to the mount heading, radians.
    pub start_rad: f64,
    /// Angle between beams, radians (CCW positive).
    pub step_rad: f64,
    /// Number of beams.
    pub count: u16,
    /// Longest range; beyond it a beam has no return, metres.
    pub max_range_m: f64,
    /// Standard deviation of the range noise, metres.
    pub noise_std_m: f64,
}

impl Default for LaserModel {
    fn default() -> Self {
        Self {
            start_rad: -PI / 2.0,
            step_rad: PI / 180.0,
            count: 181,
            max_range_m: 8.191,
            noise_std_m: 0.01,
        }
    }
}

impl LaserModel {
    /// One scan from a scanner mounted at `mount` on `robot` into `out` (cleared first):
    /// `Some(range_m)` per beam, `None` for no return (or if the robot does not exist, all
    /// `None`). Noisy ranges are clamped to `[0, max_range_m]`.
    pub fn scan(
        &self,
        world: &World,
        robot: RobotId,
        mount: &Isometry2,
        rng: &mut impl Rng,
        out: &mut Vec<Option<f64>>,
    ) {
        out.clear();
        let Some(r) = world.robot(robot) else {
            out.resize(usize::from(self.count), None);
            return;
        };
        let sensor = r.pose().compose(mount);
        let max = if self.max_range_m.is_finite() && self.max_range_m > 0.0 {
            self.max_range_m
        } else {
            0.0
        };
        for k in 0..self.count {
            let dir = sensor.theta_rad + self.start_rad + self.step_rad * f64::from(k);
            let hit = world.cast_ignoring(sensor.point(), dir, max, Some(robot));
            out.push(hit.map(|h| {
                let noise = if self.noise_std_m.is_finite() {
                    gaussian(rng) * self.noise_std_m
                } else {
                    0.0
                };
                let v = h.distance_m + noise;
                if v.is_finite() {
                    v.max(0.0).min(max)
                } else {
                    max
                }
            }));
        }
    }
}

/// A standard normal sample (Box–Muller).
pub fn gaussian(rng: &mut impl Rng) -> f64 {
    // u1 in (0, 1] so that ln(u1) is finite.
    let u1 = 1.0 - rng.random::<f64>();
    let u2 = rng.random::<f64>();
    (-2.0 * u1.ln()).sqrt() * (2.0 * PI * u2).cos()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand::rngs::SmallRng;

    #[test]
    fn segment_distance_to_the_segment_its_ends_and_a_point() {
        assert!((segment_distance([0.0, 1.0], [-1.0, 0.0], [1.0, 0.0]) - 1.0).abs() < 1e-12);
        assert!((segment_distance([3.0, 4.0], [0.0, 0.0], [0.0, 0.0]) - 5.0).abs() < 1e-12);
        let corner = segment_distance([2.0, 1.0], [-1.0, 0.0], [1.0, 0.0]);
        assert!((corner - 2f64.sqrt()).abs() < 1e-12);
    }

    fn bare_robot() -> World {
        let mut w = World::new();
        w.add_robot(RobotSpec::new("r", 0.0, 0.0, 0.0)).unwrap();
        w
    }

    #[test]
    fn straight_one_metre_at_0_2_m_s() {
        let mut w = bare_robot();
        let id = RobotId(0);
        w.command(
            id,
            DriveCommand::Twist {
                v_m_s: 0.2,
                omega_rad_s: 0.0,
            },
        );
        for _ in 0..500 {
            w.step(Duration::from_millis(10));
        }
        let p = w.robot(id).unwrap().pose();
        assert!((p.x_m - 1.0).abs() < 1e-9, "{p:?}");
        assert!(p.y_m.abs() < 1e-9);
        let (l, r) = w.robot(id).unwrap().wheel_travel_mm();
        assert!((l - 1000.0).abs() < 1e-6 && (r - 1000.0).abs() < 1e-6);
        assert_eq!(w.time(), Instant::from_millis(5000));
    }

    #[test]
    fn one_big_step_equals_many_small_steps_on_an_arc() {
        let mut a = bare_robot();
        let mut b = bare_robot();
        let cmd = DriveCommand::Twist {
            v_m_s: 0.3,
            omega_rad_s: 0.4,
        };
        a.command(RobotId(0), cmd);
        b.command(RobotId(0), cmd);
        a.step(Duration::from_secs(7));
        for _ in 0..700 {
            b.step(Duration::from_millis(10));
        }
        let (pa, pb) = (a.robots()[0].pose(), b.robots()[0].pose());
        assert!((pa.x_m - pb.x_m).abs() < 1e-9 && (pa.y_m - pb.y_m).abs() < 1e-9);
        // The arc has radius v/ω = 0.75 m: the robot stays on the circle centred (0, 0.75).
        assert!(((pa.x_m).hypot(pa.y_m - 0.75) - 0.75).abs() < 1e-9);
        assert!((pa.theta_rad - normalize_angle(2.8)).abs() < 1e-9);
    }

    #[test]
    fn turn_ninety_degrees_in_place() {
        let mut w = bare_robot();
        w.command(
            RobotId(0),
            DriveCommand::Twist {
                v_m_s: 0.0,
                omega_rad_s: PI / 4.0,
            },
        );
        w.step(Duration::from_secs(2));
        let r = &w.robots()[0];
        assert!((r.pose().theta_rad - PI / 2.0).abs() < 1e-9);
        assert!(r.pose().x_m.abs() < 1e-12 && r.pose().y_m.abs() < 1e-12);
        // Wheels travelled opposite arcs of b/2 · π/2.
        let (l, rr) = r.wheel_travel_mm();
        let arc = 0.25 * PI / 2.0 * 1000.0;
        assert!((l + arc).abs() < 1e-6 && (rr - arc).abs() < 1e-6);
    }

    #[test]
    fn acceleration_limit_ramps_speed() {
        let mut w = World::new();
        let mut s = RobotSpec::new("r", 0.0, 0.0, 0.0);
        s.max_wheel_accel_m_s2 = Some(0.5);
        w.add_robot(s).unwrap();
        w.command(
            RobotId(0),
            DriveCommand::Wheels {
                left_m_s: 0.5,
                right_m_s: 0.5,
            },
        );
        w.step(Duration::from_millis(500));
        let r = &w.robots()[0];
        assert!((r.wheel_speeds().0 - 0.25).abs() < 1e-9);
        // x = a t² / 2 = 0.0625
        assert!((r.pose().x_m - 0.0625).abs() < 1e-6, "{:?}", r.pose());
        w.step(Duration::from_secs(2));
        let r = &w.robots()[0];
        assert_eq!(r.wheel_speeds(), (0.5, 0.5));
        // Ramp to 0.5 takes 1 s (0.25 m), then 1.5 s at 0.5 m/s.
        assert!((r.pose().x_m - 1.0).abs() < 1e-6, "{:?}", r.pose());
    }

    #[test]
    fn commands_are_clamped_and_sanitised() {
        let mut w = bare_robot();
        w.command(
            RobotId(0),
            DriveCommand::Wheels {
                left_m_s: f64::NAN,
                right_m_s: 99.0,
            },
        );
        assert_eq!(w.robots()[0].commanded_wheels(), (0.0, 1.0));
        w.step(Duration::from_secs(1));
        assert!(w.robots()[0].pose().x_m.is_finite());
        assert!(!w.command(RobotId(9), DriveCommand::STOP));
    }

    #[test]
    fn ray_hits_wall_at_right_distance() {
        let mut w = World::new();
        w.add_wall(Wall {
            from: [2.0, -1.0],
            to: [2.0, 1.0],
        })
        .unwrap();
        let h = w.cast(Point2::new(0.5, 0.0), 0.0, 10.0).unwrap();
        assert!((h.distance_m - 1.5).abs() < 1e-12);
        assert_eq!(h.target, Target::Wall(0));
        // At 45° the wall is 1.5·√2 away but the segment ends at y = 1 → miss.
        assert!(w.cast(Point2::new(0.5, 0.0), PI / 4.0, 10.0).is_none());
        // Out of range.
        assert!(w.cast(Point2::new(0.5, 0.0), 0.0, 1.0).is_none());
        // Behind.
        assert!(w.cast(Point2::new(0.5, 0.0), PI, 10.0).is_none());
    }

    #[test]
    fn ray_hits_nearest_of_circle_object_and_robot() {
        let mut w = World::default_world();
        let sk = w.robot_id("skeeter").unwrap();
        // From Skeeter along +x: the red object at 3 m, radius 0.15.
        let p = w.robot(sk).unwrap().pose().point();
        let h = w.cast_ignoring(p, 0.0, 10.0, Some(sk)).unwrap();
        assert_eq!(h.target, Target::Object(0));
        assert!((h.distance_m - 2.85).abs() < 1e-9);
        // Without ignoring itself the ray starts inside Skeeter.
        let h = w.cast(p, 0.0, 10.0).unwrap();
        assert_eq!(
            h,
            Hit {
                distance_m: 0.0,
                target: Target::Robot(sk)
            }
        );
        // Toward 210° Scooter (4 m away, radius 0.4) is hit at 3.6.
        let h = w
            .cast_ignoring(p, 210f64.to_radians(), 10.0, Some(sk))
            .unwrap();
        assert_eq!(h.target, Target::Robot(w.robot_id("scooter").unwrap()));
        assert!((h.distance_m - 3.6).abs() < 1e-9);
        w.add_circle(Circle {
            center: [1.0, 0.0],
            radius_m: 0.1,
        })
        .unwrap();
        let h = w.cast_ignoring(p, 0.0, 10.0, Some(sk)).unwrap();
        assert_eq!(h.target, Target::Circle(0));
        assert!((h.distance_m - 0.9).abs() < 1e-9);
    }

    #[test]
    fn cast_rejects_non_finite_input() {
        let w = World::default_world();
        assert!(w.cast(Point2::new(f64::NAN, 0.0), 0.0, 5.0).is_none());
        assert!(w.cast(Point2::new(0.0, 0.0), f64::INFINITY, 5.0).is_none());
        assert!(w.cast(Point2::new(0.0, 0.0), 0.0, -1.0).is_none());
    }

    fn wall_at_one_metre() -> World {
        let mut w = bare_robot();
        w.add_wall(Wall {
            from: [1.0, -3.0],
            to: [1.0, 3.0],
        })
        .unwrap();
        w
    }

    #[test]
    fn sonar_reads_one_metre_wall_with_noise() {
        let w = wall_at_one_metre();
        let m = SonarModel::default();
        let mut rng = SmallRng::seed_from_u64(1);
        let mount = Isometry2::identity();
        let n = 2000;
        let readings: Vec<f64> = (0..n)
            .map(|_| m.measure(&w, RobotId(0), &mount, &mut rng))
            .collect();
        let mean = readings.iter().sum::<f64>() / f64::from(n);
        let var = readings.iter().map(|r| (r - mean).powi(2)).sum::<f64>() / f64::from(n);
        assert!((mean - 1.0).abs() < 0.002, "mean {mean}");
        assert!((var.sqrt() - 0.01).abs() < 0.002, "std {}", var.sqrt());
        assert!(readings.iter().all(|r| (r - 1.0).abs() < 0.06));
        // A beam 30° off the normal still sees the wall's nearest point in its cone only if
        // the cone reaches it: with 25° width at 30° it reads 1/cos(17.5°).
        let mount = Isometry2::new(ima_hal::Vector2::zeros(), 30f64.to_radians());
        let exact = SonarModel {
            noise_std_m: 0.0,
            ..m
        };
        let r = exact.measure(&w, RobotId(0), &mount, &mut rng);
        assert!((r - 1.0 / 17.5f64.to_radians().cos()).abs() < 1e-9, "{r}");
    }

    #[test]
    fn sonar_no_echo_reads_max_and_clamps_to_min() {
        let w = wall_at_one_metre();
        let m = SonarModel::default();
        let mut rng = SmallRng::seed_from_u64(2);
        let back = Isometry2::new(ima_hal::Vector2::zeros(), PI);
        assert_eq!(m.measure(&w, RobotId(0), &back, &mut rng), 5.0);
        let near = Isometry2::new(ima_hal::Vector2::new(0.97, 0.0), 0.0);
        assert_eq!(m.measure(&w, RobotId(0), &near, &mut rng), 0.1);
        assert_eq!(m.measure(&w, RobotId(5), &near, &mut rng), 5.0);
    }

    #[test]
    fn sonar_from_hal_transducer() {
        let t = ima_hal::sonar::SonarTransducer {
            pose: Isometry2::identity(),
            min_range_m: 0.1,
            max_range_m: 5.0,
            beam_width_rad: 0.5,
        };
        let m = SonarModel::from_transducer(&t);
        assert_eq!(m.beam_width_rad, 0.5);
        assert_eq!(m.max_range_m, 5.0);
    }

    #[test]
    fn visible_objects_respects_fov_and_occlusion() {
        let mut w = World::default_world();
        let sk = w.robot_id("skeeter").unwrap();
        let view = w.robot(sk).unwrap().pose();
        let seen = w.visible_objects(view, 0.5, 5.0, Some(sk));
        assert_eq!(seen.len(), 1);
        assert_eq!(w.objects()[seen[0].object].color, "red");
        assert!((seen[0].range_m - 3.0).abs() < 1e-9);
        // Put a post in front of red: hidden.
        w.add_circle(Circle {
            center: [1.5, 0.0],
            radius_m: 0.2,
        })
        .unwrap();
        assert!(w.visible_objects(view, 0.5, 5.0, Some(sk)).is_empty());
        // All around: the five others.
        assert_eq!(w.visible_objects(view, PI, 5.0, Some(sk)).len(), 5);
    }

    #[test]
    fn world_file_round_trip_and_errors() {
        let text = r#"
            seed = 7
            [[robot]]
            name = "skeeter"
            x_m = 1.0
            y_m = 2.0
            theta_deg = 90.0
            max_wheel_accel_m_s2 = 0.5

            [[wall]]
            from = [0.0, 0.0]
            to = [1.0, 0.0]

            [[circle]]
            center = [3.0, 3.0]
            radius_m = 0.2

            [[object]]
            color = "red"
            rgb = [255, 0, 0]
            center = [2.0, 0.0]
            radius_m = 0.1
        "#;
        let w = World::from_toml_str(text).unwrap();
        assert_eq!(w.seed(), 7);
        assert_eq!(w.robots().len(), 1);
        assert!((w.robots()[0].pose().theta_rad - PI / 2.0).abs() < 1e-12);
        assert_eq!(w.walls().len(), 1);
        assert_eq!(w.circles().len(), 1);
        assert_eq!(w.objects()[0].rgb, [255, 0, 0]);
        let again = toml::to_string(&w.to_file()).unwrap();
        let w2 = World::from_toml_str(&again).unwrap();
        assert_eq!(w2.to_file(), w.to_file());

        assert!(matches!(
            World::from_toml_str("robot = 3"),
            Err(WorldError::Toml(_))
        ));
        assert!(matches!(
            World::from_toml_str("colour = 1"),
            Err(WorldError::Toml(_))
        ));
        let dup = "[[robot]]\nname='a'\nx_m=0.0\ny_m=0.0\n[[robot]]\nname='a'\nx_m=1.0\ny_m=0.0\n";
        assert_eq!(
            World::from_toml_str(dup),
            Err(WorldError::DuplicateRobot("a".into()))
        );
        let neg = "[[circle]]\ncenter=[0.0,0.0]\nradius_m=-1.0\n";
        assert_eq!(
            World::from_toml_str(neg),
            Err(WorldError::Invalid {
                item: "circle 0".into(),
                field: "radius_m"
            })
        );
        // A wall across the whole f64 range made the demo's plot spin for ever.
        let huge = "[[wall]]\nfrom=[-1e308,-1e308]\nto=[1e308,1e308]\n";
        let e = World::from_toml_str(huge).unwrap_err();
        assert_eq!(
            e,
            WorldError::Invalid {
                item: "wall 0".into(),
                field: "from"
            }
        );
        assert!(e.to_string().contains("within ±10000"), "{e}");
        let nan = "[[robot]]\nname='a'\nx_m=nan\ny_m=0.0\n";
        assert!(matches!(
            World::from_toml_str(nan),
            Err(WorldError::Invalid { field: "x_m", .. })
        ));
        let zero_track = "[[robot]]\nname='a'\nx_m=0.0\ny_m=0.0\ntrack_width_m=0.0\n";
        assert!(matches!(
            World::from_toml_str(zero_track),
            Err(WorldError::Invalid {
                field: "track_width_m",
                ..
            })
        ));
    }

    #[test]
    fn default_world_is_the_demo_arena() {
        let w = World::default_world();
        assert_eq!(w.walls().len(), 4);
        assert_eq!(w.objects().len(), 6);
        assert!(w.robot_id("skeeter").is_some() && w.robot_id("scooter").is_some());
        // From the centre along +y the north wall is 5 m away (no object at 90°).
        let h = w
            .cast_ignoring(Point2::origin(), PI / 2.0, 10.0, w.robot_id("skeeter"))
            .unwrap();
        assert_eq!(h.target, Target::Wall(2));
        assert!((h.distance_m - 5.0).abs() < 1e-12);
    }

    #[test]
    fn shared_world_locks() {
        let s = SharedWorld::new(World::default_world());
        let s2 = s.clone();
        s.with(|w| w.step(Duration::from_millis(10)));
        assert_eq!(s2.lock().time(), Instant::from_millis(10));
    }

    #[test]
    fn laser_scan_sees_the_room() {
        let w = World::default_world();
        let sk = w.robot_id("skeeter").unwrap();
        let m = LaserModel {
            noise_std_m: 0.0,
            ..LaserModel::default()
        };
        let mut rng = SmallRng::seed_from_u64(4);
        let mut out = Vec::new();
        m.scan(&w, sk, &Isometry2::identity(), &mut rng, &mut out);
        assert_eq!(out.len(), 181);
        // Beam 90 looks straight ahead at red (3 m − 0.15 m).
        assert!((out[90].unwrap() - 2.85).abs() < 1e-9);
        // Beam 0 looks right (−90°): the south wall at 5 m.
        assert!((out[0].unwrap() - 5.0).abs() < 1e-9);
        // A short laser sees nothing there.
        let short = LaserModel {
            max_range_m: 1.0,
            ..m
        };
        short.scan(&w, sk, &Isometry2::identity(), &mut rng, &mut out);
        assert!(out.iter().all(Option::is_none));
        short.scan(&w, RobotId(7), &Isometry2::identity(), &mut rng, &mut out);
        assert_eq!(out.len(), 181);
    }

    #[test]
    fn sonar_survives_nonsense_config() {
        let w = wall_at_one_metre();
        let mut rng = SmallRng::seed_from_u64(3);
        let m = SonarModel {
            min_range_m: f64::NAN,
            max_range_m: f64::NAN,
            beam_width_rad: f64::INFINITY,
            rays: 0,
            noise_std_m: f64::NAN,
        };
        let r = m.measure(&w, RobotId(0), &Isometry2::identity(), &mut rng);
        assert!(r.is_finite());
        let m = SonarModel {
            min_range_m: 3.0,
            max_range_m: 2.0,
            ..SonarModel::default()
        };
        let r = m.measure(&w, RobotId(0), &Isometry2::identity(), &mut rng);
        assert_eq!(r, 2.0);
    }

    #[test]
    fn world_file_from_path() {
        let dir = std::env::temp_dir().join(format!("ima-world-{}.toml", std::process::id()));
        std::fs::write(
            &dir,
            toml::to_string(&World::default_world().to_file()).unwrap(),
        )
        .unwrap();
        let w = World::from_toml_path(&dir).unwrap();
        std::fs::remove_file(&dir).unwrap();
        assert_eq!(w.to_file(), World::default_world().to_file());
        assert!(matches!(
            World::from_toml_path(std::path::Path::new("/nonexistent/w.toml")),
            Err(WorldError::Io(_))
        ));
    }

    proptest::proptest! {
        #[test]
        fn any_text_is_a_world_or_an_error(s in "(\\[\\[robot\\]\\]\n|name='a'\n|x_m=[0-9.e-]{1,4}\n|y_m=1\n|radius_m=-?[0-9]\n|.{0,8}\n){0,8}") {
            let _ = World::from_toml_str(&s);
        }

        #[test]
        fn stepping_never_produces_non_finite_poses(
            l in -10.0f64..10.0, r in -10.0f64..10.0, dt_ms in 0u64..100_000,
            accel in proptest::option::of(0.01f64..10.0),
        ) {
            let mut w = World::new();
            let mut s = RobotSpec::new("r", 0.0, 0.0, 0.0);
            s.max_wheel_accel_m_s2 = accel;
            w.add_robot(s).unwrap();
            w.command(RobotId(0), DriveCommand::Wheels { left_m_s: l, right_m_s: r });
            w.step(Duration::from_millis(dt_ms));
            let p = w.robots()[0].pose();
            proptest::prop_assert!(p.x_m.is_finite() && p.y_m.is_finite() && p.theta_rad.is_finite());
            proptest::prop_assert!(p.theta_rad > -PI - 1e-12 && p.theta_rad <= PI + 1e-12);
        }
    }

    #[test]
    fn markers_in_world_files_are_optional_and_round_trip() {
        let old = "[[robot]]\nname = \"a\"\nx_m = 0.0\ny_m = 0.0\n";
        let w = World::from_toml_str(old).unwrap();
        assert_eq!(w.robots()[0].spec().marker_rgb, None);
        assert!(!toml::to_string(&w.to_file()).unwrap().contains("marker"));
        let new = format!("{old}marker_rgb = [1, 2, 3]\n");
        let w = World::from_toml_str(&new).unwrap();
        assert_eq!(w.robots()[0].spec().marker_rgb, Some([1, 2, 3]));
        let again = World::from_toml_str(&toml::to_string(&w.to_file()).unwrap()).unwrap();
        assert_eq!(again.to_file(), w.to_file());
        assert!(World::from_toml_str(&format!("{old}marker_rgb = [1, 2]\n")).is_err());
        assert!(World::from_toml_str(&format!("{old}marker_rgb = [1, 2, 300]\n")).is_err());
    }

    #[test]
    fn default_world_scooter_marker_is_visible_from_skeeter() {
        let w = World::default_world();
        let sk = w.robot_id("skeeter").unwrap();
        let sc = w.robot_id("scooter").unwrap();
        assert_eq!(w.robot(sk).unwrap().spec().marker_rgb, None);
        assert_eq!(
            w.robot(sc).unwrap().spec().marker_rgb,
            Some(DEFAULT_SCOOTER_MARKER)
        );
        assert!(
            w.objects().iter().all(|o| o.rgb != DEFAULT_SCOOTER_MARKER),
            "no object has the marker colour"
        );
        // Scooter is at 210°, 4 m.
        let view = Pose::new(0.0, 0.0, 210f64.to_radians());
        let seen = w.visible_markers(view, 0.5, 12.0, Some(sk));
        assert_eq!(seen.len(), 1);
        let m = seen[0];
        assert_eq!(m.robot, sc);
        assert_eq!(m.rgb, DEFAULT_SCOOTER_MARKER);
        assert!((m.range_m - 4.0).abs() < 1e-9);
        assert!(m.bearing_rad.abs() < 1e-9);
        assert!((m.radius_m - 0.4).abs() < 1e-12);
        // Out of view, out of range, and the viewer itself.
        assert!(
            w.visible_markers(Pose::new(0.0, 0.0, 0.0), 0.5, 12.0, Some(sk))
                .is_empty()
        );
        assert!(w.visible_markers(view, 0.5, 3.0, Some(sk)).is_empty());
        let from_scooter = Pose::new(-10.0, -10.0, 0.0);
        assert!(
            w.visible_markers(from_scooter, PI, 30.0, Some(sc))
                .is_empty()
        );
    }

    #[test]
    fn a_hidden_marker_is_not_visible() {
        let mut w = World::new();
        let a = w.add_robot(RobotSpec::new("a", 0.0, 0.0, 0.0)).unwrap();
        let mut b = RobotSpec::new("b", 4.0, 0.0, 0.0);
        b.marker_rgb = Some([9, 9, 9]);
        w.add_robot(b).unwrap();
        let view = Pose::new(0.0, 0.0, 0.0);
        assert_eq!(w.visible_markers(view, 0.5, 10.0, Some(a)).len(), 1);
        w.add_circle(Circle {
            center: [2.0, 0.0],
            radius_m: 0.2,
        })
        .unwrap();
        assert!(w.visible_markers(view, 0.5, 10.0, Some(a)).is_empty());
    }
}

//! The differential-drive body both base models move: [`DiffDriveBody`]; [`WorldBody`],
//! a robot of the simulated [`crate::world::World`]; and [`ScriptedBody`], whose readings a
//! test sets directly.
//!
//! A Pioneer 2-AT (P2OS) and an ATRV-Jr (rFLEX, a skid steer modelled as a differential
//! drive) are one kind of body to their firmware: it commands a forward speed and a turn rate
//! and reads back wheel travel, wheel speeds, sonar ranges, the battery and bumper contact.
//! Each firmware model converts these to its own units (P2OS encoder ticks and SIP units,
//! rFLEX Kd/Ka axis counts).

use ima_hal::Isometry2;

/// What a base's firmware drives and senses.
pub trait DiffDriveBody {
    /// Command the drive: forward speed (m/s) and turn rate (rad/s, counter-clockwise
    /// positive). The body applies its own acceleration limits.
    fn drive(&mut self, v_m_s: f64, omega_rad_s: f64);
    /// The body's true pose in its world: x, y (m), θ (rad).
    fn pose(&self) -> (f64, f64, f64);
    /// Distance between the wheel contact lines, m.
    fn track_width_m(&self) -> f64;
    /// Current wheel speeds (left, right), m/s.
    fn wheel_speeds_m_s(&self) -> (f64, f64);
    /// Total wheel travel since power-on (left, right), m.
    fn wheel_travel_m(&self) -> (f64, f64);
    /// Range seen by a sonar mounted at `mount` on the body (the beam along the mount's x
    /// axis), m; `None` = no echo.
    fn sonar_range_m(&mut self, mount: &Isometry2) -> Option<f64>;
    /// Battery voltage.
    fn battery_v(&self) -> f64 {
        12.5
    }
    /// Bumper contact: (front, rear).
    fn bumpers(&self) -> (bool, bool) {
        (false, false)
    }
    /// Total travel (m, the mean of the wheels) and total turn (rad) since power-on, as the
    /// wheels measured them.
    fn travel(&self) -> (f64, f64) {
        let (l, r) = self.wheel_travel_m();
        ((l + r) / 2.0, (r - l) / self.track_width_m().max(1e-6))
    }
    /// Current forward speed (m/s) and turn rate (rad/s), from the wheel speeds.
    fn velocity(&self) -> (f64, f64) {
        let (l, r) = self.wheel_speeds_m_s();
        ((l + r) / 2.0, (r - l) / self.track_width_m().max(1e-6))
    }
}

/// A robot of a [`crate::world::SharedWorld`] as a base's body: drive commands go to the
/// world, sonar ranges are ray casts with the [`crate::world::SonarModel`]'s beam and noise,
/// and a bumper touches when the world's geometry is within [`WorldBody::bump_margin_m`] of
/// the footprint, ahead or behind.
#[derive(Debug)]
pub struct WorldBody {
    world: crate::world::SharedWorld,
    robot: crate::world::RobotId,
    sonar: crate::world::SonarModel,
    rng: rand::rngs::SmallRng,
    /// Battery voltage reported (12.5 V by default).
    pub battery_v: f64,
    /// Contact distance beyond the footprint radius that counts as a bump, m (0.02).
    pub bump_margin_m: f64,
}

impl WorldBody {
    /// The body of `robot` in `world`; sonar noise is seeded with `seed`.
    pub fn new(world: crate::world::SharedWorld, robot: crate::world::RobotId, seed: u64) -> Self {
        use rand::SeedableRng;
        Self {
            world,
            robot,
            sonar: crate::world::SonarModel::default(),
            rng: rand::rngs::SmallRng::seed_from_u64(seed),
            battery_v: 12.5,
            bump_margin_m: 0.02,
        }
    }

    /// Use this sonar model (beam width, rays, noise, limits).
    #[must_use]
    pub fn with_sonar(mut self, sonar: crate::world::SonarModel) -> Self {
        self.sonar = sonar;
        self
    }

    fn robot<T: Default>(&self, f: impl FnOnce(&crate::world::Robot) -> T) -> T {
        self.world
            .with(|w| w.robot(self.robot).map(f))
            .unwrap_or_default()
    }
}

impl DiffDriveBody for WorldBody {
    fn drive(&mut self, v_m_s: f64, omega_rad_s: f64) {
        self.world.with(|w| {
            w.command(
                self.robot,
                crate::world::DriveCommand::Twist { v_m_s, omega_rad_s },
            )
        });
    }

    fn pose(&self) -> (f64, f64, f64) {
        self.robot(|r| {
            let p = r.pose();
            (p.x_m, p.y_m, p.theta_rad)
        })
    }

    fn track_width_m(&self) -> f64 {
        self.robot(crate::world::Robot::track_width_m)
    }

    fn wheel_speeds_m_s(&self) -> (f64, f64) {
        self.robot(crate::world::Robot::wheel_speeds)
    }

    fn wheel_travel_m(&self) -> (f64, f64) {
        self.robot(|r| {
            let (l, rr) = r.wheel_travel_mm();
            (l / 1000.0, rr / 1000.0)
        })
    }

    fn velocity(&self) -> (f64, f64) {
        self.robot(crate::world::Robot::velocity)
    }

    fn sonar_range_m(&mut self, mount: &Isometry2) -> Option<f64> {
        let sonar = self.sonar;
        let rng = &mut self.rng;
        let r = self
            .world
            .with(|w| sonar.measure(w, self.robot, mount, rng));
        (r < sonar.max_range_m).then_some(r)
    }

    fn battery_v(&self) -> f64 {
        self.battery_v
    }

    fn bumpers(&self) -> (bool, bool) {
        self.world.with(|w| {
            let Some(r) = w.robot(self.robot) else {
                return (false, false);
            };
            let p = r.pose();
            let reach = r.radius_m() + self.bump_margin_m;
            let hit = |dir: f64| {
                w.cast_ignoring(p.point(), dir, reach, Some(self.robot))
                    .is_some()
            };
            (hit(p.theta_rad), hit(p.theta_rad + std::f64::consts::PI))
        })
    }
}

/// A body whose readings a test sets directly: no world, no physics. Drive commands are
/// recorded; unless [`velocity`](Self::velocity) is set, the body moves at the last command
/// (an ideal body that follows instantly). Travel is the wheels' unless
/// [`travel`](Self::travel) is set (the rFLEX model reads axis travel, the P2OS model wheel
/// travel).
#[derive(Debug, Clone, PartialEq)]
pub struct ScriptedBody {
    /// The last drive command: forward speed (m/s), turn rate (rad/s).
    pub drive: (f64, f64),
    /// Drive commands received.
    pub drives: u32,
    /// Reported pose: x, y (m), θ (rad).
    pub pose: (f64, f64, f64),
    /// Distance between the wheel contact lines, m (0.5).
    pub track_width_m: f64,
    /// Wheel speeds (left, right), m/s.
    pub wheel_speeds_m_s: (f64, f64),
    /// Wheel travel since power-on (left, right), m.
    pub wheel_travel_m: (f64, f64),
    /// Travel (m) and turn (rad) since power-on; `None`: from the wheel travel.
    pub travel: Option<(f64, f64)>,
    /// Forward speed (m/s) and turn rate (rad/s); `None`: the last drive command.
    pub velocity: Option<(f64, f64)>,
    /// What every sonar sees, m; `None` = no echo.
    pub sonar_m: Option<f64>,
    /// Bumper contact: (front, rear).
    pub bumpers: (bool, bool),
    /// Battery voltage (12.5 V).
    pub battery_v: f64,
}

impl Default for ScriptedBody {
    fn default() -> Self {
        Self {
            drive: (0.0, 0.0),
            drives: 0,
            pose: (0.0, 0.0, 0.0),
            track_width_m: 0.5,
            wheel_speeds_m_s: (0.0, 0.0),
            wheel_travel_m: (0.0, 0.0),
            travel: None,
            velocity: None,
            sonar_m: None,
            bumpers: (false, false),
            battery_v: 12.5,
        }
    }
}

impl DiffDriveBody for ScriptedBody {
    fn drive(&mut self, v_m_s: f64, omega_rad_s: f64) {
        self.drive = (v_m_s, omega_rad_s);
        self.drives = self.drives.saturating_add(1);
    }

    fn pose(&self) -> (f64, f64, f64) {
        self.pose
    }

    fn track_width_m(&self) -> f64 {
        self.track_width_m
    }

    fn wheel_speeds_m_s(&self) -> (f64, f64) {
        self.wheel_speeds_m_s
    }

    fn wheel_travel_m(&self) -> (f64, f64) {
        self.wheel_travel_m
    }

    fn sonar_range_m(&mut self, _mount: &Isometry2) -> Option<f64> {
        self.sonar_m
    }

    fn battery_v(&self) -> f64 {
        self.battery_v
    }

    fn bumpers(&self) -> (bool, bool) {
        self.bumpers
    }

    fn travel(&self) -> (f64, f64) {
        self.travel.unwrap_or_else(|| {
            let (l, r) = self.wheel_travel_m;
            ((l + r) / 2.0, (r - l) / self.track_width_m.max(1e-6))
        })
    }

    fn velocity(&self) -> (f64, f64) {
        self.velocity.unwrap_or(self.drive)
    }
}

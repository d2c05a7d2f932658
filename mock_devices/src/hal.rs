//! In-process HAL devices on a simulated world: no protocol, no port — a
//! [`DifferentialBase`] + [`Odometer`], a [`LaserScanner`] and a [`Compass`] that read and
//! drive a [`World`] directly, for tests and the virtual-time simulation.
//!
//! # Time
//!
//! A [`SimWorld`] owns the world and one tokio task that steps it by a fixed `dt` on tokio's
//! clock. Under paused time (`#[tokio::test(start_paused = true)]`, `tokio::time::pause`, or a
//! runtime built with `start_paused(true)`) that is **virtual time**: tokio jumps to the next
//! timer whenever every task waits, so a mission of minutes runs in milliseconds and the same
//! inputs give the same run. Every reading is stamped on the one [`SharedClock`] of the
//! simulation ([`SimWorld::clock`], a [`TokioClock`] unless another tokio-time clock is given),
//! so the `Stamped::at` of a scan, an odometry reading and a heading of one robot are
//! comparable, as the HAL promises.
//!
//! # Readings
//!
//! Sensors are sampled by the stepping task right after a world step, when their period is
//! due, and stamped with that step's instant: a reading describes the world exactly at its
//! stamp. A device may add a transport delay ([`LaserConfig::delay`]): the reading is then
//! *published* that much later, still stamped with the instant it describes — the age a
//! consumer sees is `clock.now() − reading.at`. Periods and delays are rounded up to whole
//! steps.
//!
//! * odometry ([`SimBase`]): the robot's true pose relative to the pose at the last
//!   [`Odometer::reset_odometry`] (at creation: the start pose) and its true velocity — the
//!   mock world's wheels do not slip;
//! * laser ([`SimLaser`]): a [`LaserModel`] scan from the sensor's mount, with its noise;
//! * compass ([`SimCompass`]): the true heading (clockwise from north, the world's +x axis
//!   pointing at [`CompassConfig::x_axis_heading_rad`]) plus Gaussian noise.
//!
//! # Safety
//!
//! Like the real drivers, a [`SimBase`] stops its robot when commands stop coming for
//! [`BaseConfig::command_timeout`], and when the simulation is stopped every device reports
//! [`ErrorKind::Disconnected`].

use core::f64::consts::FRAC_PI_2;
use core::time::Duration;
use std::collections::VecDeque;
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};

use ima_hal::base::{BaseLimits, DifferentialBase, Odometer, Odometry, VelocityCommand};
use ima_hal::compass::{Compass, Heading, HeadingReference};
use ima_hal::laser::{BeamFlags, LaserDescription, LaserScan, LaserScanner};
use ima_hal::time::{Clock, SharedClock, TokioClock};
use ima_hal::{ErrorKind, ErrorType, Instant, Isometry2, Stamped};
use rand::SeedableRng;
use rand::rngs::SmallRng;
use tokio::sync::watch;

use crate::world::{DriveCommand, LaserModel, RobotId, World, gaussian};

/// Why a simulated device could not be made.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SimDeviceError {
    /// The world has no robot of this name.
    #[error("the simulated world has no robot named `{0}`")]
    NoRobot(String),
    /// The simulation was stopped.
    #[error("the simulation was stopped")]
    Stopped,
}

/// A sensor hook: called by the stepping task after every step with the world and the step's
/// instant; returns `false` once its readers are gone (it is then dropped).
type Hook = Box<dyn FnMut(&World, Instant) -> bool + Send>;

/// One base's command state, kept with the world so the stepping task can enforce its
/// command timeout.
struct BaseSlot {
    robot: RobotId,
    enabled: bool,
    last_command: Instant,
    command_timeout: Option<Duration>,
    origin: Isometry2,
    period: Duration,
    next_due: Instant,
    odometry: watch::Sender<Option<Stamped<Odometry>>>,
}

struct State {
    world: World,
    /// The instant of the last step on the simulation's clock.
    now: Instant,
    stopped: bool,
    bases: Vec<BaseSlot>,
    hooks: Vec<Hook>,
}

impl State {
    fn odometry_of(&self, slot: &BaseSlot) -> Option<Odometry> {
        let r = self.world.robot(slot.robot)?;
        let (v, w) = r.velocity();
        Some(Odometry {
            pose: slot.origin.inverse() * r.pose().to_isometry(),
            v_m_s: v,
            omega_rad_s: w,
        })
    }

    fn step(&mut self, dt: Duration, now: Instant) {
        for b in &self.bases {
            let silent = b
                .command_timeout
                .is_some_and(|t| now.saturating_duration_since(b.last_command) > t);
            if silent || !b.enabled {
                self.world.command(b.robot, DriveCommand::STOP);
            }
        }
        self.world.step(dt);
        self.now = now;
        let mut readings = Vec::new();
        for (i, b) in self.bases.iter().enumerate() {
            if b.next_due <= now
                && let Some(o) = self.odometry_of(b)
            {
                readings.push((i, o));
            }
        }
        for (i, o) in readings {
            if let Some(b) = self.bases.get_mut(i) {
                b.next_due = now + b.period;
                b.odometry.send_replace(Some(Stamped::new(now, o)));
            }
        }
        let world = &self.world;
        self.hooks.retain_mut(|h| h(world, now));
    }
}

struct Shared {
    state: Mutex<State>,
    stepper: Mutex<Option<tokio::task::JoinHandle<()>>>,
}

impl Drop for Shared {
    fn drop(&mut self) {
        if let Some(t) = self
            .stepper
            .get_mut()
            .unwrap_or_else(PoisonError::into_inner)
            .take()
        {
            t.abort();
        }
    }
}

/// A world stepped in (usually virtual) tokio time, and the factory of its devices. Cheap to
/// clone: clones and devices share one world; the stepping task ends with
/// [`SimWorld::stop`] or when the last handle (devices included) is dropped.
#[derive(Clone)]
pub struct SimWorld {
    shared: Arc<Shared>,
    clock: SharedClock,
    dt: Duration,
}

impl core::fmt::Debug for SimWorld {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("SimWorld")
            .field("dt", &self.dt)
            .finish_non_exhaustive()
    }
}

impl SimWorld {
    /// Start stepping `world` every `dt` (at least 1 ms) with a new [`TokioClock`] as the
    /// simulation's clock. Call inside a tokio runtime; pause its time first for virtual
    /// time.
    #[must_use]
    pub fn start(world: World, dt: Duration) -> Self {
        Self::start_with_clock(world, dt, TokioClock::shared())
    }

    /// As [`SimWorld::start`] with a given clock, which must run on tokio's time (a
    /// [`TokioClock`] made in this runtime): the steps are paced by tokio's timer and stamped
    /// by `clock`.
    #[must_use]
    pub fn start_with_clock(world: World, dt: Duration, clock: SharedClock) -> Self {
        let dt = dt.max(Duration::from_millis(1));
        let shared = Arc::new(Shared {
            state: Mutex::new(State {
                world,
                now: clock.now(),
                stopped: false,
                bases: Vec::new(),
                hooks: Vec::new(),
            }),
            stepper: Mutex::new(None),
        });
        let weak = Arc::downgrade(&shared);
        let task_clock = clock.clone();
        let task = tokio::spawn(async move {
            let mut next = tokio::time::Instant::now();
            loop {
                next += dt;
                tokio::time::sleep_until(next).await;
                let Some(shared) = weak.upgrade() else {
                    return;
                };
                let now = task_clock.now();
                let mut st = shared.state.lock().unwrap_or_else(PoisonError::into_inner);
                if st.stopped {
                    return;
                }
                st.step(dt, now);
            }
        });
        *shared
            .stepper
            .lock()
            .unwrap_or_else(PoisonError::into_inner) = Some(task);
        Self { shared, clock, dt }
    }

    fn lock(&self) -> MutexGuard<'_, State> {
        self.shared
            .state
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
    }

    /// The simulation's clock: every reading is stamped on it.
    #[must_use]
    pub fn clock(&self) -> SharedClock {
        self.clock.clone()
    }

    /// The step.
    #[must_use]
    pub fn dt(&self) -> Duration {
        self.dt
    }

    /// The instant of the last step on [`SimWorld::clock`] (the start instant before the
    /// first step).
    #[must_use]
    pub fn last_step(&self) -> Instant {
        self.lock().now
    }

    /// Run `f` on the world (between steps; keep it short, never await inside).
    pub fn with<R>(&self, f: impl FnOnce(&mut World) -> R) -> R {
        f(&mut self.lock().world)
    }

    /// A copy of the world as it is now.
    #[must_use]
    pub fn snapshot(&self) -> World {
        self.lock().world.clone()
    }

    /// Call `hook` after every step with the world and the step's instant, until it returns
    /// `false` or the simulation stops: for observers that are not HAL devices (another
    /// robot's cameras, a trajectory recorder).
    pub fn on_step(&self, hook: impl FnMut(&World, Instant) -> bool + Send + 'static) {
        let mut st = self.lock();
        if !st.stopped {
            st.hooks.push(Box::new(hook));
        }
    }

    /// Stop stepping; every device then reports [`ErrorKind::Disconnected`]. The robots keep
    /// their last state (a stopped world does not move).
    pub fn stop(&self) {
        {
            let mut st = self.lock();
            st.stopped = true;
            // Dropping the senders wakes every waiting reader with an error.
            st.bases.clear();
            st.hooks.clear();
        }
        if let Some(t) = self
            .shared
            .stepper
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .take()
        {
            t.abort();
        }
    }

    fn robot(&self, name: &str) -> Result<RobotId, SimDeviceError> {
        self.lock()
            .world
            .robot_id(name)
            .ok_or_else(|| SimDeviceError::NoRobot(name.to_owned()))
    }

    /// The base of robot `name`: velocity commands drive it in the world, odometry reads it.
    ///
    /// # Errors
    /// [`SimDeviceError`] when there is no such robot or the simulation was stopped.
    pub fn base(&self, name: &str, cfg: BaseConfig) -> Result<SimBase, SimDeviceError> {
        let robot = self.robot(name)?;
        let mut st = self.lock();
        if st.stopped {
            return Err(SimDeviceError::Stopped);
        }
        let (limits, origin) = {
            let r = st
                .world
                .robot(robot)
                .ok_or_else(|| SimDeviceError::NoRobot(name.to_owned()))?;
            let max = r.spec().max_wheel_speed_m_s;
            let limits = cfg.limits.unwrap_or(BaseLimits {
                max_v_m_s: max,
                max_omega_rad_s: 2.0 * max / r.track_width_m(),
            });
            (limits, r.pose().to_isometry())
        };
        let now = st.now;
        let slot = BaseSlot {
            robot,
            enabled: true,
            last_command: now,
            command_timeout: cfg.command_timeout,
            origin,
            period: cfg.odometry_period,
            next_due: now + cfg.odometry_period,
            odometry: watch::Sender::new(None),
        };
        let first = st.odometry_of(&slot).map(|o| Stamped::new(now, o));
        slot.odometry.send_replace(first);
        let odometry = slot.odometry.subscribe();
        let index = st.bases.len();
        st.bases.push(slot);
        Ok(SimBase {
            world: self.clone(),
            robot,
            index,
            limits,
            odometry,
        })
    }

    /// A laser scanner on robot `name`.
    ///
    /// # Errors
    /// [`SimDeviceError`] when there is no such robot or the simulation was stopped.
    pub fn laser(&self, name: &str, cfg: LaserConfig) -> Result<SimLaser, SimDeviceError> {
        let robot = self.robot(name)?;
        let (tx, rx) = watch::channel(None);
        let description = cfg.description();
        let mut rng = SmallRng::seed_from_u64(cfg.seed);
        let mut buf = Vec::with_capacity(usize::from(cfg.model.count));
        let mut pending: VecDeque<Stamped<LaserScan>> = VecDeque::new();
        let mut due = self.last_step();
        let LaserConfig {
            model,
            mount,
            period,
            delay,
            ..
        } = cfg;
        self.add_hook(move |world, now| {
            if due <= now {
                due = now + period;
                model.scan(world, robot, &mount, &mut rng, &mut buf);
                let mut scan = LaserScan::new(model.start_rad, model.step_rad);
                for r in &buf {
                    // A scan holds at most MAX_BEAMS; the model's count is a u16 the
                    // description promises, so a longer model is cut, not a panic.
                    let _ = match r {
                        Some(m) => scan.push(*m as f32, BeamFlags::VALID),
                        None => scan.push(f32::NAN, BeamFlags::NO_RETURN),
                    };
                }
                pending.push_back(Stamped::new(now, scan));
            }
            while pending
                .front()
                .is_some_and(|s| s.at + delay <= now || delay.is_zero())
            {
                if let Some(s) = pending.pop_front() {
                    tx.send_replace(Some(s));
                }
            }
            !tx.is_closed()
        })?;
        Ok(SimLaser { rx, description })
    }

    /// A compass on robot `name`.
    ///
    /// # Errors
    /// [`SimDeviceError`] when there is no such robot or the simulation was stopped.
    pub fn compass(&self, name: &str, cfg: CompassConfig) -> Result<SimCompass, SimDeviceError> {
        let robot = self.robot(name)?;
        let (tx, rx) = watch::channel(None);
        let mut rng = SmallRng::seed_from_u64(cfg.seed);
        let mut due = self.last_step();
        self.add_hook(move |world, now| {
            if due <= now {
                due = now + cfg.period;
                if let Some(r) = world.robot(robot) {
                    let noise = if cfg.noise_rad.is_finite() {
                        cfg.noise_rad * gaussian(&mut rng)
                    } else {
                        0.0
                    };
                    let h = cfg.x_axis_heading_rad - r.pose().theta_rad + noise;
                    tx.send_replace(Some(Stamped::new(
                        now,
                        Heading::new(h, HeadingReference::Magnetic),
                    )));
                }
            }
            !tx.is_closed()
        })?;
        Ok(SimCompass { rx })
    }

    fn add_hook(
        &self,
        hook: impl FnMut(&World, Instant) -> bool + Send + 'static,
    ) -> Result<(), SimDeviceError> {
        let mut st = self.lock();
        if st.stopped {
            return Err(SimDeviceError::Stopped);
        }
        st.hooks.push(Box::new(hook));
        Ok(())
    }
}

/// Settings of a [`SimBase`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BaseConfig {
    /// Limits commands are clamped to; `None` = the robot's wheel limit (`max_v` = the
    /// wheel speed, `max_ω` = 2 · wheel speed / track width).
    pub limits: Option<BaseLimits>,
    /// Stop the robot when no command came for this long (`None`: hold the last command).
    pub command_timeout: Option<Duration>,
    /// One odometry reading every this often (10 Hz, as P2OS and rFLEX report).
    pub odometry_period: Duration,
}

impl Default for BaseConfig {
    fn default() -> Self {
        Self {
            limits: None,
            command_timeout: Some(Duration::from_secs(1)),
            odometry_period: Duration::from_millis(100),
        }
    }
}

/// Settings of a [`SimLaser`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LaserConfig {
    /// The scan geometry and noise.
    pub model: LaserModel,
    /// The sensor's pose on the robot.
    pub mount: Isometry2,
    /// One scan every this often.
    pub period: Duration,
    /// Transport delay: a scan is published this long after the instant it describes.
    pub delay: Duration,
    /// Seed of the range noise.
    pub seed: u64,
}

impl Default for LaserConfig {
    fn default() -> Self {
        Self {
            model: LaserModel::default(),
            mount: Isometry2::identity(),
            period: Duration::from_millis(200),
            delay: Duration::ZERO,
            seed: 1,
        }
    }
}

impl LaserConfig {
    /// The [`LaserDescription`] of scans made with these settings.
    #[must_use]
    pub fn description(&self) -> LaserDescription {
        let m = &self.model;
        let period = self.period.as_secs_f64();
        LaserDescription {
            pose: self.mount,
            fov_rad: m.step_rad.abs() * f64::from(m.count.saturating_sub(1)),
            resolution_rad: m.step_rad.abs(),
            beams: m.count,
            min_range_m: 0.0,
            max_range_m: m.max_range_m,
            max_scan_rate_hz: if period > 0.0 { 1.0 / period } else { 0.0 },
        }
    }
}

/// Settings of a [`SimCompass`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CompassConfig {
    /// The compass heading (clockwise from north, radians) of the world's +x axis; π/2 (the
    /// default) makes +x east and +y north.
    pub x_axis_heading_rad: f64,
    /// Standard deviation of the heading noise, radians.
    pub noise_rad: f64,
    /// One heading every this often.
    pub period: Duration,
    /// Seed of the noise.
    pub seed: u64,
}

impl Default for CompassConfig {
    fn default() -> Self {
        Self {
            x_axis_heading_rad: FRAC_PI_2,
            noise_rad: 0.5f64.to_radians(),
            period: Duration::from_millis(100),
            seed: 2,
        }
    }
}

/// The latest reading of a watch, waiting for the first; `Disconnected` once the simulation
/// stopped.
async fn latest<T: Clone + Send + Sync>(
    rx: &mut watch::Receiver<Option<Stamped<T>>>,
) -> Result<Stamped<T>, ErrorKind> {
    newer(rx, None).await
}

/// The first reading stamped after `after` (or any reading for `None`).
async fn newer<T: Clone + Send + Sync>(
    rx: &mut watch::Receiver<Option<Stamped<T>>>,
    after: Option<Instant>,
) -> Result<Stamped<T>, ErrorKind> {
    let r = rx
        .wait_for(|v| v.as_ref().is_some_and(|s| after.is_none_or(|a| s.at > a)))
        .await
        .map_err(|_| ErrorKind::Disconnected)?;
    r.clone().ok_or(ErrorKind::Disconnected)
}

/// A simulated differential-drive base with odometry ([`SimWorld::base`]).
#[derive(Debug, Clone)]
pub struct SimBase {
    world: SimWorld,
    robot: RobotId,
    index: usize,
    limits: BaseLimits,
    odometry: watch::Receiver<Option<Stamped<Odometry>>>,
}

impl SimBase {
    /// The robot this base drives.
    #[must_use]
    pub fn robot(&self) -> RobotId {
        self.robot
    }

    /// Apply `f` to this base's slot and the world; `Disconnected` once stopped.
    fn with_slot<R>(
        &self,
        f: impl FnOnce(&mut BaseSlot, &mut World, Instant) -> R,
    ) -> Result<R, ErrorKind> {
        let mut st = self.world.lock();
        let now = st.now;
        let State { world, bases, .. } = &mut *st;
        let slot = bases.get_mut(self.index).ok_or(ErrorKind::Disconnected)?;
        Ok(f(slot, world, now))
    }

    fn drive(&self, cmd: VelocityCommand) -> Result<(), ErrorKind> {
        let clamp = |x: f64, m: f64| x.max(-m).min(m);
        let (v, w) = (
            clamp(cmd.v_m_s, self.limits.max_v_m_s),
            clamp(cmd.omega_rad_s, self.limits.max_omega_rad_s),
        );
        let ok = cmd.is_finite();
        self.with_slot(|slot, world, now| {
            slot.last_command = now;
            let twist = if ok && slot.enabled {
                DriveCommand::Twist {
                    v_m_s: v,
                    omega_rad_s: w,
                }
            } else {
                DriveCommand::STOP
            };
            world.command(slot.robot, twist);
        })?;
        if ok {
            Ok(())
        } else {
            Err(ErrorKind::InvalidArgument)
        }
    }
}

impl ErrorType for SimBase {
    type Error = ErrorKind;
}

impl DifferentialBase for SimBase {
    fn limits(&self) -> BaseLimits {
        self.limits
    }

    /// Motors start enabled; disabled, the robot is held at zero whatever is commanded.
    async fn enable_motors(&mut self, enable: bool) -> Result<(), ErrorKind> {
        self.with_slot(|slot, world, _| {
            slot.enabled = enable;
            if !enable {
                world.command(slot.robot, DriveCommand::STOP);
            }
        })
    }

    /// Clamped to [`DifferentialBase::limits`]; a non-finite command stops the robot and is
    /// refused with [`ErrorKind::InvalidArgument`].
    async fn set_velocity(&mut self, cmd: VelocityCommand) -> Result<(), ErrorKind> {
        self.drive(cmd)
    }

    async fn stop(&mut self) -> Result<(), ErrorKind> {
        self.drive(VelocityCommand::ZERO)
    }

    /// As [`DifferentialBase::stop`]: the world's wheels decelerate at their limit either
    /// way.
    async fn emergency_stop(&mut self) -> Result<(), ErrorKind> {
        self.drive(VelocityCommand::ZERO)
    }
}

impl Odometer for SimBase {
    async fn odometry(&mut self) -> Result<Stamped<Odometry>, ErrorKind> {
        latest(&mut self.odometry).await
    }

    async fn next_odometry(&mut self, after: Instant) -> Result<Stamped<Odometry>, ErrorKind> {
        newer(&mut self.odometry, Some(after)).await
    }

    /// The current pose becomes the origin; a reading at the last step's instant is published
    /// at once.
    async fn reset_odometry(&mut self) -> Result<(), ErrorKind> {
        let mut st = self.world.lock();
        let now = st.now;
        let pose = st
            .world
            .robot(self.robot)
            .map(|r| r.pose().to_isometry())
            .ok_or(ErrorKind::Disconnected)?;
        let State { world, bases, .. } = &mut *st;
        let slot = bases.get_mut(self.index).ok_or(ErrorKind::Disconnected)?;
        slot.origin = pose;
        let (v, w) = world.robot(self.robot).map_or((0.0, 0.0), |r| r.velocity());
        slot.odometry.send_replace(Some(Stamped::new(
            now,
            Odometry {
                pose: Isometry2::identity(),
                v_m_s: v,
                omega_rad_s: w,
            },
        )));
        Ok(())
    }
}

/// A simulated scanning laser ([`SimWorld::laser`]).
#[derive(Debug, Clone)]
pub struct SimLaser {
    rx: watch::Receiver<Option<Stamped<LaserScan>>>,
    description: LaserDescription,
}

impl ErrorType for SimLaser {
    type Error = ErrorKind;
}

impl LaserScanner for SimLaser {
    fn description(&self) -> LaserDescription {
        self.description
    }

    async fn scan(&mut self) -> Result<Stamped<LaserScan>, ErrorKind> {
        latest(&mut self.rx).await
    }

    async fn next_scan(&mut self, after: Instant) -> Result<Stamped<LaserScan>, ErrorKind> {
        newer(&mut self.rx, Some(after)).await
    }
}

/// A simulated compass ([`SimWorld::compass`]).
#[derive(Debug, Clone)]
pub struct SimCompass {
    rx: watch::Receiver<Option<Stamped<Heading>>>,
}

impl ErrorType for SimCompass {
    type Error = ErrorKind;
}

impl Compass for SimCompass {
    async fn heading(&mut self) -> Result<Stamped<Heading>, ErrorKind> {
        latest(&mut self.rx).await
    }

    async fn next_heading(&mut self, after: Instant) -> Result<Stamped<Heading>, ErrorKind> {
        newer(&mut self.rx, Some(after)).await
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::{RobotSpec, Wall};

    fn world() -> World {
        let mut w = World::new();
        w.add_robot(RobotSpec::new("bot", 0.0, 0.0, 0.0)).unwrap();
        // A wall 3 m ahead, across the laser's centre beam.
        w.add_wall(Wall {
            from: [3.0, -5.0],
            to: [3.0, 5.0],
        })
        .unwrap();
        w
    }

    fn quiet_laser() -> LaserConfig {
        LaserConfig {
            model: LaserModel {
                noise_std_m: 0.0,
                ..LaserModel::default()
            },
            ..LaserConfig::default()
        }
    }

    fn centre_range(scan: &LaserScan) -> f32 {
        scan.ranges_m()[scan.len() / 2]
    }

    #[tokio::test(start_paused = true)]
    async fn a_commanded_twist_moves_the_world_and_odometry_follows() {
        let sim = SimWorld::start(world(), Duration::from_millis(50));
        let mut base = sim.base("bot", BaseConfig::default()).unwrap();
        let mut laser = sim.laser("bot", quiet_laser()).unwrap();
        let first = laser.scan().await.unwrap();
        assert!((centre_range(&first.value) - 3.0).abs() < 1e-3);
        let o0 = base.odometry().await.unwrap();
        assert!(o0.value.x_m().abs() < 1e-12);
        // Keep commanding (the base stops after its 1 s command timeout otherwise).
        for _ in 0..20 {
            base.set_velocity(VelocityCommand::new(0.5, 0.0))
                .await
                .unwrap();
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        // The world as of its last step (this task may run before the step of this instant).
        let (x, x_at) = (
            sim.with(|w| w.robot(RobotId(0)).unwrap().pose().x_m),
            sim.last_step(),
        );
        assert!((x - 1.0).abs() < 0.06, "moved 0.5 m/s for 2 s: x = {x}");
        let o = base.next_odometry(o0.at).await.unwrap();
        assert!((o.value.x_m() - x).abs() < 0.06, "odometry {o:?}, x {x}");
        assert!((o.value.v_m_s - 0.5).abs() < 1e-9);
        let s = laser.next_scan(first.at).await.unwrap();
        // The scan is up to one period old: where the robot was at its stamp.
        let age = x_at.saturating_duration_since(s.at).as_secs_f64();
        let x_then = x - 0.5 * age;
        assert!(
            (f64::from(centre_range(&s.value)) - (3.0 - x_then)).abs() < 1e-3,
            "the wall came closer: {} (x {x}, age {age} s)",
            centre_range(&s.value)
        );
    }

    #[tokio::test(start_paused = true)]
    async fn readings_of_one_robot_share_the_clock() {
        let sim = SimWorld::start(world(), Duration::from_millis(50));
        let clock = sim.clock();
        let mut base = sim.base("bot", BaseConfig::default()).unwrap();
        let laser_cfg = LaserConfig {
            delay: Duration::from_millis(100),
            ..quiet_laser()
        };
        let mut laser = sim.laser("bot", laser_cfg).unwrap();
        let mut compass = sim.compass("bot", CompassConfig::default()).unwrap();
        tokio::time::sleep(Duration::from_millis(1234)).await;
        // Taken together: every reading is at most one period (plus the laser's transport
        // delay) old on the one clock, and none is from the future.
        let now = clock.now();
        let s = laser.scan().await.unwrap();
        let o = base.odometry().await.unwrap();
        let h = compass.heading().await.unwrap();
        for (what, at, bound) in [
            ("scan", s.at, laser_cfg.period + laser_cfg.delay),
            ("odometry", o.at, BaseConfig::default().odometry_period),
            ("heading", h.at, CompassConfig::default().period),
        ] {
            assert!(at <= now, "{what} stamped in the future");
            assert!(
                now.saturating_duration_since(at) <= bound,
                "{what} {at:?} too old at {now:?}"
            );
        }
        assert!(
            o.at.saturating_duration_since(s.at) <= laser_cfg.period + laser_cfg.delay,
            "scan {:?} and odometry {:?} differ by more than the scan period plus its delay",
            s.at,
            o.at
        );
        // The delayed scan describes the world at its stamp, not at its publication.
        assert!(now.saturating_duration_since(s.at) >= laser_cfg.delay);
        // Facing +x = east: heading π/2, clockwise from north.
        assert!((h.value.heading_rad - FRAC_PI_2).abs() < 3.0 * 0.5f64.to_radians());
        assert!(h.value.yaw_enu_rad().abs() < 3.0 * 0.5f64.to_radians());
    }

    #[tokio::test(start_paused = true)]
    async fn next_reading_waits_for_a_newer_stamp() {
        let sim = SimWorld::start(world(), Duration::from_millis(50));
        let mut laser = sim.laser("bot", quiet_laser()).unwrap();
        let a = laser.scan().await.unwrap();
        let b = laser.next_scan(a.at).await.unwrap();
        let c = laser.next_scan(b.at).await.unwrap();
        assert_eq!(
            c.at.saturating_duration_since(b.at),
            Duration::from_millis(200)
        );
        assert_eq!(
            b.at.saturating_duration_since(a.at),
            Duration::from_millis(200)
        );
    }

    #[tokio::test(start_paused = true)]
    async fn a_silent_caller_is_stopped_and_a_bad_command_refused() {
        let sim = SimWorld::start(world(), Duration::from_millis(50));
        let mut base = sim.base("bot", BaseConfig::default()).unwrap();
        base.set_velocity(VelocityCommand::new(0.5, 0.0))
            .await
            .unwrap();
        tokio::time::sleep(Duration::from_secs(5)).await;
        let x = sim.with(|w| w.robot(RobotId(0)).unwrap().pose().x_m);
        assert!(
            (0.4..0.65).contains(&x),
            "stopped after the 1 s timeout: {x}"
        );
        base.set_velocity(VelocityCommand::new(0.5, 0.0))
            .await
            .unwrap();
        assert_eq!(
            base.set_velocity(VelocityCommand::new(f64::NAN, 0.0)).await,
            Err(ErrorKind::InvalidArgument)
        );
        tokio::time::sleep(Duration::from_millis(500)).await;
        let x2 = sim.with(|w| w.robot(RobotId(0)).unwrap().pose().x_m);
        assert!((x2 - x).abs() < 1e-9, "a NaN command stops the robot");
        // Commands are clamped to the limits: 2 · 1 m/s / 0.5 m.
        assert!((base.limits().max_omega_rad_s - 4.0).abs() < 1e-12);
        base.enable_motors(false).await.unwrap();
        base.set_velocity(VelocityCommand::new(0.5, 0.0))
            .await
            .unwrap();
        tokio::time::sleep(Duration::from_millis(500)).await;
        let x3 = sim.with(|w| w.robot(RobotId(0)).unwrap().pose().x_m);
        assert!((x3 - x).abs() < 1e-9, "disabled motors hold the robot");
    }

    #[tokio::test(start_paused = true)]
    async fn reset_moves_the_origin_and_stop_disconnects() {
        let sim = SimWorld::start(world(), Duration::from_millis(50));
        let mut base = sim.base("bot", BaseConfig::default()).unwrap();
        sim.with(|w| {
            w.robot_mut(RobotId(0))
                .unwrap()
                .set_pose(crate::world::Pose::new(1.0, 2.0, 0.5))
        });
        tokio::time::sleep(Duration::from_millis(200)).await;
        let o = base.odometry().await.unwrap();
        assert!((o.value.x_m() - 1.0).abs() < 1e-9 && (o.value.theta_rad() - 0.5).abs() < 1e-9);
        base.reset_odometry().await.unwrap();
        let o = base.odometry().await.unwrap();
        assert!(o.value.x_m().abs() < 1e-12 && o.value.theta_rad().abs() < 1e-12);
        let mut laser = sim.laser("bot", quiet_laser()).unwrap();
        assert!(matches!(
            sim.compass("nobody", CompassConfig::default()),
            Err(SimDeviceError::NoRobot(_))
        ));
        sim.stop();
        assert_eq!(
            base.next_odometry(o.at).await.err(),
            Some(ErrorKind::Disconnected)
        );
        assert_eq!(
            laser.next_scan(Instant::from_micros(u64::MAX)).await.err(),
            Some(ErrorKind::Disconnected)
        );
        assert_eq!(
            base.set_velocity(VelocityCommand::ZERO).await,
            Err(ErrorKind::Disconnected)
        );
        assert!(matches!(
            sim.base("bot", BaseConfig::default()),
            Err(SimDeviceError::Stopped)
        ));
    }
}

//! Differential-drive bases and their odometry.

use core::future::Future;

use crate::{ErrorType, Isometry2, Stamped};

/// A body-frame velocity command for a differential (or skid-steer) base.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct VelocityCommand {
    /// Forward speed in m/s (negative = backwards).
    pub v_m_s: f64,
    /// Turn rate in rad/s, counter-clockwise positive.
    pub omega_rad_s: f64,
}

impl VelocityCommand {
    /// Standing still.
    pub const ZERO: Self = Self {
        v_m_s: 0.0,
        omega_rad_s: 0.0,
    };

    /// A command of `v_m_s` forward and `omega_rad_s` turn rate.
    #[must_use]
    pub const fn new(v_m_s: f64, omega_rad_s: f64) -> Self {
        Self { v_m_s, omega_rad_s }
    }

    /// Both components finite.
    #[must_use]
    pub fn is_finite(&self) -> bool {
        self.v_m_s.is_finite() && self.omega_rad_s.is_finite()
    }
}

/// Speed limits a base enforces (commands beyond them are clamped by the driver).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BaseLimits {
    /// Largest forward/backward speed, m/s.
    pub max_v_m_s: f64,
    /// Largest turn rate, rad/s.
    pub max_omega_rad_s: f64,
}

/// Integrated odometry: where the base believes it is, and how fast it moves.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Odometry {
    /// Pose of the robot frame in the odometry frame (the pose at the last reset is identity).
    pub pose: Isometry2,
    /// Forward speed, m/s.
    pub v_m_s: f64,
    /// Turn rate, rad/s (counter-clockwise positive).
    pub omega_rad_s: f64,
}

impl Odometry {
    /// At the origin, standing still.
    #[must_use]
    pub fn origin() -> Self {
        Self {
            pose: Isometry2::identity(),
            v_m_s: 0.0,
            omega_rad_s: 0.0,
        }
    }

    /// x of the pose, metres.
    #[must_use]
    pub fn x_m(&self) -> f64 {
        self.pose.translation.x
    }

    /// y of the pose, metres.
    #[must_use]
    pub fn y_m(&self) -> f64 {
        self.pose.translation.y
    }

    /// Heading of the pose, radians in (−π, π].
    #[must_use]
    pub fn theta_rad(&self) -> f64 {
        self.pose.rotation.angle()
    }
}

/// A base driven by a forward speed and a turn rate.
///
/// Drivers keep the robot's safety rules: a base whose caller stops sending commands is
/// stopped by the driver after its documented command timeout.
pub trait DifferentialBase: ErrorType {
    /// The limits the driver clamps commands to.
    fn limits(&self) -> BaseLimits;

    /// Enable (`true`) or disable the drive motors. Resolves once the robot confirms.
    fn enable_motors(&mut self, enable: bool) -> impl Future<Output = Result<(), Self::Error>> + Send;

    /// Command a velocity; it holds until the next command, a stop, or the command timeout.
    fn set_velocity(
        &mut self,
        cmd: VelocityCommand,
    ) -> impl Future<Output = Result<(), Self::Error>> + Send;

    /// Decelerate to a stop; motors stay enabled.
    fn stop(&mut self) -> impl Future<Output = Result<(), Self::Error>> + Send;

    /// Stop as fast as the base can, overriding the normal deceleration.
    fn emergency_stop(&mut self) -> impl Future<Output = Result<(), Self::Error>> + Send;
}

/// A source of integrated odometry.
pub trait Odometer: ErrorType {
    /// The most recent odometry (waits for the first one after connecting).
    fn odometry(&mut self) -> impl Future<Output = Result<Stamped<Odometry>, Self::Error>> + Send;

    /// Wait for an odometry reading newer than `after`.
    fn next_odometry(
        &mut self,
        after: crate::Instant,
    ) -> impl Future<Output = Result<Stamped<Odometry>, Self::Error>> + Send;

    /// Make the current pose the origin of the odometry frame.
    fn reset_odometry(&mut self) -> impl Future<Output = Result<(), Self::Error>> + Send;
}

/// Contact switches and wheel stalls.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct BumperState {
    /// One bit per front bumper segment, bit 0 = leftmost.
    pub front: u16,
    /// One bit per rear bumper segment.
    pub rear: u16,
    /// The left wheel(s) stalled.
    pub left_stall: bool,
    /// The right wheel(s) stalled.
    pub right_stall: bool,
}

impl BumperState {
    /// Any bumper pressed.
    #[must_use]
    pub fn any_contact(&self) -> bool {
        self.front != 0 || self.rear != 0
    }
}

/// Bumpers and stall detection.
pub trait Bumpers: ErrorType {
    /// The latest bumper and stall state.
    fn bumpers(&mut self) -> impl Future<Output = Result<Stamped<BumperState>, Self::Error>> + Send;
}

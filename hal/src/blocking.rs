//! Blocking mirrors of the async traits, for simple command-line tools and scripts that do not
//! want an async runtime. Semantics are those of the async trait of the same name.

use crate::base::{BaseLimits, BumperState, Odometry, VelocityCommand};
use crate::power::PowerState;
use crate::sonar::{SonarScan, SonarTransducer};
use crate::{ErrorType, Stamped};

/// Blocking [`crate::base::DifferentialBase`].
pub trait DifferentialBase: ErrorType {
    /// See [`crate::base::DifferentialBase::limits`].
    fn limits(&self) -> BaseLimits;
    /// See [`crate::base::DifferentialBase::enable_motors`].
    fn enable_motors(&mut self, enable: bool) -> Result<(), Self::Error>;
    /// See [`crate::base::DifferentialBase::set_velocity`].
    fn set_velocity(&mut self, cmd: VelocityCommand) -> Result<(), Self::Error>;
    /// See [`crate::base::DifferentialBase::stop`].
    fn stop(&mut self) -> Result<(), Self::Error>;
    /// See [`crate::base::DifferentialBase::emergency_stop`].
    fn emergency_stop(&mut self) -> Result<(), Self::Error>;
}

/// Blocking [`crate::base::Odometer`].
pub trait Odometer: ErrorType {
    /// See [`crate::base::Odometer::odometry`].
    fn odometry(&mut self) -> Result<Stamped<Odometry>, Self::Error>;
    /// See [`crate::base::Odometer::reset_odometry`].
    fn reset_odometry(&mut self) -> Result<(), Self::Error>;
}

/// Blocking [`crate::sonar::SonarArray`].
pub trait SonarArray: ErrorType {
    /// See [`crate::sonar::SonarArray::transducers`].
    fn transducers(&self) -> &[SonarTransducer];
    /// See [`crate::sonar::SonarArray::sonar`].
    fn sonar(&mut self) -> Result<Stamped<SonarScan>, Self::Error>;
}

/// Blocking [`crate::base::Bumpers`].
pub trait Bumpers: ErrorType {
    /// See [`crate::base::Bumpers::bumpers`].
    fn bumpers(&mut self) -> Result<Stamped<BumperState>, Self::Error>;
}

/// Blocking [`crate::power::Power`].
pub trait Power: ErrorType {
    /// See [`crate::power::Power::power`].
    fn power(&mut self) -> Result<Stamped<PowerState>, Self::Error>;
}

/// Blocking [`crate::compass::Compass`].
pub trait Compass: ErrorType {
    /// See [`crate::compass::Compass::heading`].
    fn heading(&mut self) -> Result<Stamped<crate::compass::Heading>, Self::Error>;
    /// See [`crate::compass::Compass::next_heading`].
    fn next_heading(
        &mut self,
        after: crate::Instant,
    ) -> Result<Stamped<crate::compass::Heading>, Self::Error>;
}

/// Blocking [`crate::camera::CameraMux`].
pub trait CameraMux: ErrorType {
    /// See [`crate::camera::CameraMux::channel_count`].
    fn channel_count(&self) -> crate::camera::Channel;
    /// See [`crate::camera::CameraMux::settle_time`].
    fn settle_time(&self) -> core::time::Duration;
    /// See [`crate::camera::CameraMux::select`].
    fn select(
        &mut self,
        channel: crate::camera::Channel,
    ) -> Result<crate::camera::Selection, Self::Error>;
    /// See [`crate::camera::CameraMux::current_channel`].
    fn current_channel(&mut self) -> Result<Option<crate::camera::Channel>, Self::Error>;
}

/// Blocking [`crate::laser::LaserScanner`].
pub trait LaserScanner: ErrorType {
    /// See [`crate::laser::LaserScanner::description`].
    fn description(&self) -> crate::laser::LaserDescription;
    /// See [`crate::laser::LaserScanner::scan`].
    fn scan(&mut self) -> Result<Stamped<crate::laser::LaserScan>, Self::Error>;
    /// See [`crate::laser::LaserScanner::next_scan`].
    fn next_scan(
        &mut self,
        after: crate::Instant,
    ) -> Result<Stamped<crate::laser::LaserScan>, Self::Error>;
}

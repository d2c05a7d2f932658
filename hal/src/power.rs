//! Battery and power.

use core::future::Future;

use crate::{ErrorType, Stamped};

/// What a robot reports about its power supply.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PowerState {
    /// Battery voltage, volts.
    pub battery_v: f64,
}

/// A battery monitor.
pub trait Power: ErrorType {
    /// The latest power reading.
    fn power(&mut self) -> impl Future<Output = Result<Stamped<PowerState>, Self::Error>> + Send;
}

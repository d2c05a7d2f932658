//! The blocking runner (feature `serial`): any driver handle, driven from plain blocking
//! code, for tools and scripts that do not want an async runtime.
//!
//! [`Blocking<T>`] owns a single-threaded tokio runtime and the async handle `T`; each call
//! runs the handle's async method to completion on it, and it implements every
//! [`ima_hal::blocking`] trait whose async twin `T` implements. So there is one blocking
//! implementation for every driver, and it behaves exactly like the async one.
//!
//! The driver's task only runs inside a call: a tool that stops calling for longer than a
//! device's watchdog lets the device stop, the safe outcome. Dropping a `Blocking` closes
//! the driver (its last frames, e.g. STOP then CLOSE, are written) before it returns.
//! Do not use it from inside an async runtime.

use std::time::Duration;

use ima_hal::base::{BaseLimits, BumperState, Odometry, VelocityCommand};
use ima_hal::camera::{Channel, Selection};
use ima_hal::compass::Heading;
use ima_hal::laser::{LaserDescription, LaserScan};
use ima_hal::power::PowerState;
use ima_hal::sonar::{SonarScan, SonarTransducer};
use ima_hal::{ErrorType, Instant, Stamped, blocking as b};

use crate::LinkError;

/// An async driver handle `T`, run synchronously (see the [module docs](self)).
#[derive(Debug)]
pub struct Blocking<T> {
    // Dropped first: the handles go, the driver task starts closing …
    inner: T,
    // … and the runtime runs it to the end before it goes.
    rt: Runtime,
}

/// The runtime; dropping it first lets the tasks still alive finish (bounded).
#[derive(Debug)]
struct Runtime(tokio::runtime::Runtime);

/// The longest a dropped [`Blocking`] lets its driver task write its last frames.
const CLOSE_LIMIT: Duration = Duration::from_secs(3);

impl Drop for Runtime {
    fn drop(&mut self) {
        // Inside another runtime we must not block; the device's watchdog is the fallback.
        if tokio::runtime::Handle::try_current().is_ok() {
            return;
        }
        let metrics = self.0.metrics();
        self.0.block_on(async {
            let _ = tokio::time::timeout(CLOSE_LIMIT, async {
                while metrics.num_alive_tasks() > 0 {
                    tokio::time::sleep(Duration::from_millis(2)).await;
                }
            })
            .await;
        });
    }
}

impl<T> Blocking<T> {
    /// Make a runtime and run `connect` (which opens the port and connects the driver, e.g.
    /// `async || P2os::connect(open_port(path, 9600)?, cfg, timeout, clock).await`) on it.
    ///
    /// # Errors
    /// `connect`'s error, or the runtime's (as [`LinkError::Io`]).
    pub fn connect<E: From<LinkError>>(
        connect: impl AsyncFnOnce() -> Result<T, E>,
    ) -> Result<Self, E> {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .map_err(LinkError::from)?;
        let inner = rt.block_on(connect())?;
        Ok(Self {
            inner,
            rt: Runtime(rt),
        })
    }

    /// Run `f` on the handle to completion (any of its async methods, e.g. `close`).
    pub fn run<R>(&mut self, f: impl AsyncFnOnce(&mut T) -> R) -> R {
        self.rt.0.block_on(f(&mut self.inner))
    }

    /// The async handle (for what needs no waiting: counters, the latest reading).
    pub fn get(&self) -> &T {
        &self.inner
    }

    /// Let the driver run for `d` (to wait while staying connected).
    pub fn pump_for(&mut self, d: Duration) {
        self.rt
            .0
            .block_on(async move { tokio::time::sleep(d).await });
    }
}

impl<T: ErrorType> ErrorType for Blocking<T> {
    type Error = T::Error;
}

/// `fn name(&mut self, args) -> Result<R, Self::Error>` as a blocking call of `T::name`.
macro_rules! block {
    ($($name:ident($($arg:ident: $ty:ty),*) -> $ret:ty;)*) => {$(
        fn $name(&mut self, $($arg: $ty),*) -> Result<$ret, Self::Error> {
            self.rt.0.block_on(self.inner.$name($($arg),*))
        }
    )*};
}

impl<T: ima_hal::base::DifferentialBase> b::DifferentialBase for Blocking<T> {
    fn limits(&self) -> BaseLimits {
        self.inner.limits()
    }
    block! {
        enable_motors(enable: bool) -> ();
        set_velocity(cmd: VelocityCommand) -> ();
        stop() -> ();
        emergency_stop() -> ();
    }
}

impl<T: ima_hal::base::Odometer> b::Odometer for Blocking<T> {
    block! {
        odometry() -> Stamped<Odometry>;
        reset_odometry() -> ();
    }
}

impl<T: ima_hal::sonar::SonarArray> b::SonarArray for Blocking<T> {
    fn transducers(&self) -> &[SonarTransducer] {
        self.inner.transducers()
    }
    block! { sonar() -> Stamped<SonarScan>; }
}

impl<T: ima_hal::base::Bumpers> b::Bumpers for Blocking<T> {
    block! { bumpers() -> Stamped<BumperState>; }
}

impl<T: ima_hal::power::Power> b::Power for Blocking<T> {
    block! { power() -> Stamped<PowerState>; }
}

impl<T: ima_hal::compass::Compass> b::Compass for Blocking<T> {
    block! {
        heading() -> Stamped<Heading>;
        next_heading(after: Instant) -> Stamped<Heading>;
    }
}

impl<T: ima_hal::camera::CameraMux> b::CameraMux for Blocking<T> {
    fn channel_count(&self) -> Channel {
        self.inner.channel_count()
    }
    fn settle_time(&self) -> Duration {
        self.inner.settle_time()
    }
    block! {
        select(channel: Channel) -> Selection;
        current_channel() -> Option<Channel>;
    }
}

impl<T: ima_hal::laser::LaserScanner> b::LaserScanner for Blocking<T> {
    fn description(&self) -> LaserDescription {
        self.inner.description()
    }
    block! {
        scan() -> Stamped<LaserScan>;
        next_scan(after: Instant) -> Stamped<LaserScan>;
    }
}

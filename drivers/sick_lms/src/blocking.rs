//! The blocking I/O shell (feature `serial`): the [`SickShell`] run by
//! [`ima_serial::blocking::Blocking`] over any `Read + Write` stream, for tools that do not
//! want an async runtime.
//!
//! The stream's `read` must return within a few milliseconds when nothing arrives (a port
//! opened by [`open_port`] has a 10 ms timeout), because the machine's timers run between
//! reads. Scans are decoded in place and swapped out of the shell: no heap, no copy per scan.

use std::io::{Read, Write};
use std::time::Duration;

use ima_hal::laser::{LaserDescription, LaserScan};
use ima_hal::time::SharedClock;
use ima_hal::{Instant, Isometry2, Stamped};
use ima_serial::blocking::Blocking;

use crate::decode::Variant;
pub use crate::driver::{BaudControl, DriverError, FixedBaud, ScanStats};
use crate::machine::{Config, SessionInfo};
use crate::shell::{LinkStatus, Request, SickShell, Watches};
/// Open a serial port for the blocking shell: 8N1, no flow control, 10 ms read timeout.
pub use ima_serial::open_blocking_port as open_port;

/// A SICK LMS driven synchronously.
#[derive(Debug)]
pub struct BlockingSickLms<S> {
    run: Blocking<SickShell, S>,
    w: Watches,
    scan: Stamped<LaserScan>,
    seq: u64,
    pose: Isometry2,
}

impl<S: Read + Write + BaudControl> BlockingSickLms<S> {
    /// Initialise the unit on `stream` (probe, baud, variant, config, stream) within
    /// `timeout`; `clock` is the process's time base.
    ///
    /// # Errors
    /// [`DriverError::Timeout`], the initialisation's failure, or the link's.
    pub fn connect(
        stream: S,
        cfg: Config,
        timeout: Duration,
        clock: SharedClock,
    ) -> Result<Self, DriverError> {
        let (shell, w) = SickShell::new(cfg, clock.now());
        let mut me = Self {
            run: Blocking::new(shell, stream, clock),
            w,
            scan: Stamped::new(Instant::ZERO, LaserScan::default()),
            seq: 0,
            pose: Isometry2::identity(),
        };
        me.run.wait_connected(&me.w.link, timeout)?;
        Ok(me)
    }

    /// Set where the scanner sits on the robot (reported by [`Self::description`]).
    #[must_use]
    pub fn with_pose(mut self, pose: Isometry2) -> Self {
        self.pose = pose;
        self
    }

    /// What the session runs with.
    pub fn session(&self) -> SessionInfo {
        self.run.shell().machine_ref().session()
    }

    /// Counters.
    pub fn stats(&self) -> ScanStats {
        *self.w.stats.borrow()
    }

    /// The unit's type string (e.g. `LMS200;30106`), once identified.
    pub fn device_type(&self) -> Option<&[u8]> {
        self.run.shell().machine_ref().device_type()
    }

    /// Geometry and limits of the current configuration.
    pub fn description(&self) -> LaserDescription {
        crate::driver::description(Some(&self.session()), self.pose)
    }

    /// The latest scan, if any arrived.
    pub fn latest(&self) -> Option<&Stamped<LaserScan>> {
        (self.seq > 0).then_some(&self.scan)
    }

    /// Wait (at most `timeout`) for the next scan and borrow it. The borrow ends at the next
    /// call; copy the scan to keep it.
    ///
    /// # Errors
    /// [`DriverError::Timeout`], the session's failure, or the link's.
    pub fn next_scan(&mut self, timeout: Duration) -> Result<&Stamped<LaserScan>, DriverError> {
        let (seq, scan, link) = (self.seq, &mut self.scan, &self.w.link);
        self.seq = self.run.wait_for(timeout, |shell| {
            if let LinkStatus::Failed(e) = &*link.borrow() {
                return Some(Err(e.clone()));
            }
            shell.take_newer(seq, scan).map(Ok)
        })??;
        Ok(&self.scan)
    }

    /// Change the variant (stream stopped, `3B`, stream restarted) within `timeout`.
    ///
    /// # Errors
    /// The session's refusal, [`DriverError::Timeout`], or the link's failure.
    pub fn set_variant(
        &mut self,
        variant: Variant,
        timeout: Duration,
    ) -> Result<SessionInfo, DriverError> {
        self.run
            .request(|tx| Request::Variant(variant, tx), timeout)
    }

    /// Stop the stream, put the unit back at 9600 (at most [`crate::driver::CLOSE_TIMEOUT`])
    /// and hand the stream back.
    pub fn close(self) -> S {
        self.run.close().0
    }
}

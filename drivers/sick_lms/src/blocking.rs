//! The blocking I/O shell (feature `serial`): the sans-IO [`Machine`] over any `Read + Write`
//! stream, for tools that do not want an async runtime.
//!
//! The stream's `read` must return within a few milliseconds when nothing arrives (a port
//! opened by [`open_port`] has a 10 ms timeout), because the machine's timers run between
//! reads. Scans are decoded in place into one reused [`LaserScan`]: no heap per scan.

use std::io::{self, Read, Write};
use std::time::Duration;

use ima_hal::laser::{LaserDescription, LaserScan};
use ima_hal::time::MonotonicClock;
use ima_hal::{Instant, Isometry2, Stamped};

use crate::decode::{Variant, decode_scan};
pub use crate::driver::{BaudControl, DriverError, FixedBaud, ScanStats};
use crate::machine::{Config, Event, MAX_COMMAND, Machine, MachineError, SessionInfo};

/// Open a serial port for the blocking shell: 8N1, no flow control, 10 ms read timeout.
///
/// A path that is not a serial port (a regular file, `/dev/null`) fails with
/// [`io::ErrorKind::InvalidInput`] and `PATH is not a serial port (…)`.
pub fn open_port(path: &str, baud: u32) -> io::Result<serialport::TTYPort> {
    serialport::new(path, baud)
        .timeout(Duration::from_millis(10))
        .open_native()
        .map_err(|e| ima_hal::serial::explain_open_error(path, io::Error::from(e)))
}

/// A SICK LMS driven synchronously.
#[derive(Debug)]
pub struct BlockingSickLms<S> {
    stream: S,
    machine: Machine,
    clock: MonotonicClock,
    scan: Stamped<LaserScan>,
    work: LaserScan,
    seq: u64,
    stats: ScanStats,
    ready: Option<SessionInfo>,
    error: Option<MachineError>,
    pose: Isometry2,
}

impl<S: Read + Write + BaudControl> BlockingSickLms<S> {
    /// Initialise the unit on `stream` (probe, baud, variant, config, stream) within `timeout`.
    pub fn connect(stream: S, cfg: Config, timeout: Duration) -> Result<Self, DriverError> {
        let clock = MonotonicClock::new();
        let mut me = Self {
            stream,
            machine: Machine::new(cfg, clock.now()),
            clock,
            scan: Stamped::new(Instant::ZERO, LaserScan::default()),
            work: LaserScan::default(),
            seq: 0,
            stats: ScanStats::default(),
            ready: None,
            error: None,
            pose: Isometry2::identity(),
        };
        me.wait_ready(timeout)?;
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
        self.machine.session()
    }

    /// Counters.
    pub fn stats(&self) -> ScanStats {
        let mut s = self.stats;
        s.framer = self.machine.counters();
        s.session = self.machine.stats();
        s
    }

    /// The unit's type string (e.g. `LMS200;30106`), once identified.
    pub fn device_type(&self) -> Option<&[u8]> {
        self.machine.device_type()
    }

    /// Geometry and limits of the current configuration.
    pub fn description(&self) -> LaserDescription {
        crate::driver::description(Some(&self.machine.session()), self.pose)
    }

    /// The latest scan, if any arrived.
    pub fn latest(&self) -> Option<&Stamped<LaserScan>> {
        (self.seq > 0).then_some(&self.scan)
    }

    /// Wait (at most `timeout`) for the next scan and borrow it. The borrow ends at the next
    /// call; copy the scan to keep it.
    pub fn next_scan(&mut self, timeout: Duration) -> Result<&Stamped<LaserScan>, DriverError> {
        let seq = self.seq;
        let deadline = std::time::Instant::now() + timeout;
        while self.seq == seq {
            if std::time::Instant::now() >= deadline {
                return Err(DriverError::Timeout);
            }
            self.pump_once()?;
            if self.machine.is_failed() {
                return Err(DriverError::Session(
                    self.error.unwrap_or(MachineError::NoDevice),
                ));
            }
        }
        Ok(&self.scan)
    }

    /// Change the variant (stream stopped, `3B`, stream restarted) within `timeout`.
    pub fn set_variant(
        &mut self,
        variant: Variant,
        timeout: Duration,
    ) -> Result<SessionInfo, DriverError> {
        let now = self.clock.now();
        self.machine
            .set_variant(variant, now)
            .map_err(DriverError::Session)?;
        self.ready = None;
        self.wait_ready(timeout)
    }

    /// Stop the stream, put the unit back at 9600 ([`Machine::close`]; at most
    /// [`crate::driver::CLOSE_TIMEOUT`]) and hand the stream back.
    pub fn close(mut self) -> S {
        let now = self.clock.now();
        self.machine.close(now);
        let deadline = std::time::Instant::now() + crate::driver::CLOSE_TIMEOUT;
        while !self.machine.is_closed() && std::time::Instant::now() < deadline {
            if self.pump_once().is_err() {
                break;
            }
        }
        // Write what the machine queued last and apply its final rate change.
        let _ = self.pump_once();
        self.stream
    }

    fn wait_ready(&mut self, timeout: Duration) -> Result<SessionInfo, DriverError> {
        self.error = None;
        let deadline = std::time::Instant::now() + timeout;
        loop {
            if let Some(i) = self.ready {
                return Ok(i);
            }
            if self.machine.is_failed() {
                return Err(DriverError::Session(
                    self.error.unwrap_or(MachineError::NoDevice),
                ));
            }
            if let Some(e) = self.error.take() {
                return Err(DriverError::Session(e));
            }
            if std::time::Instant::now() >= deadline {
                return Err(DriverError::Timeout);
            }
            self.pump_once()?;
        }
    }

    /// One round: events, writes, one read (≤ the port timeout), timers.
    fn pump_once(&mut self) -> Result<(), DriverError> {
        self.drain_events()?;
        let mut tbuf = [0u8; MAX_COMMAND];
        while let Some(n) = self.machine.poll_transmit(&mut tbuf) {
            let frame = tbuf.get(..n).unwrap_or(&[]);
            self.stream
                .write_all(frame)
                .and_then(|()| self.stream.flush())
                .map_err(|e| DriverError::Io(e.kind()))?;
        }
        let mut rbuf = [0u8; 1024];
        match self.stream.read(&mut rbuf) {
            Ok(0) => return Err(DriverError::Disconnected),
            Ok(n) => {
                let now = self.clock.now();
                let mode = self.machine.measuring_mode();
                let (scan, work, seq, stats) = (
                    &mut self.scan,
                    &mut self.work,
                    &mut self.seq,
                    &mut self.stats,
                );
                self.machine
                    .handle_bytes(rbuf.get(..n).unwrap_or(&[]), now, |b0, at| {
                        take_scan(b0, at, mode, scan, work, seq, stats);
                    });
            }
            Err(e)
                if matches!(
                    e.kind(),
                    io::ErrorKind::TimedOut
                        | io::ErrorKind::WouldBlock
                        | io::ErrorKind::Interrupted
                ) => {}
            Err(e) => return Err(DriverError::Io(e.kind())),
        }
        let now = self.clock.now();
        if self.machine.poll_timeout().is_some_and(|t| t <= now) {
            let mode = self.machine.measuring_mode();
            let (scan, work, seq, stats) = (
                &mut self.scan,
                &mut self.work,
                &mut self.seq,
                &mut self.stats,
            );
            self.machine.handle_timeout_with(now, |b0, at| {
                take_scan(b0, at, mode, scan, work, seq, stats);
            });
        }
        self.drain_events()
    }

    fn drain_events(&mut self) -> Result<(), DriverError> {
        while let Some(ev) = self.machine.poll_event() {
            match ev {
                Event::SetHostBaud(b) => {
                    tracing::debug!(baud = b, "sick_lms: line speed");
                    self.stream
                        .set_baud(b)
                        .and_then(|()| self.stream.clear_input())
                        .map_err(|e| DriverError::Io(e.kind()))?;
                }
                Event::Ready(i) => {
                    self.stats.readies = self.stats.readies.saturating_add(1);
                    self.ready = Some(i);
                }
                Event::Error(MachineError::StreamStalled) | Event::Restarted => {
                    self.stats.losses = self.stats.losses.saturating_add(1);
                    self.ready = None;
                }
                Event::Error(e) => self.error = Some(e),
                _ => {}
            }
        }
        Ok(())
    }
}

fn take_scan(
    b0: &crate::wire::Scan<'_>,
    at: Instant,
    mode: crate::wire::MeasuringMode,
    scan: &mut Stamped<LaserScan>,
    work: &mut LaserScan,
    seq: &mut u64,
    stats: &mut ScanStats,
) {
    // Decode aside, then swap: a bad B0 never clobbers the latest good scan.
    match decode_scan(b0, mode, None, work) {
        Ok(()) => {
            core::mem::swap(&mut scan.value, work);
            scan.at = at;
            *seq = seq.saturating_add(1);
            stats.delivered = stats.delivered.saturating_add(1);
        }
        Err(_) => stats.decode_errors = stats.decode_errors.saturating_add(1),
    }
}

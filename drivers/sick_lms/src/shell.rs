//! The I/O shell (feature `tokio`): [`SickShell`] turns the sans-IO
//! [`Machine`]'s events into scans, and cloneable [`SickLms`] handles implement
//! [`ima_hal::laser::LaserScanner`]; [`ima_serial::runner`] does the I/O, and blocking code
//! uses `ima_serial::blocking::Blocking<SickLms>`.
//!
//! The shell is generic over any `AsyncRead + AsyncWrite` stream that can change its line
//! speed ([`BaudControl`]): a `tokio_serial::SerialStream` on a real port or a pty, or an
//! in-memory duplex wrapped in [`FixedBaud`]. Time is tokio's ([`TokioClock`]), so tests can
//! run in paused virtual time.
//!
//! **No heap per scan.** The task decodes every B0 in place (borrowed from the framer) into
//! one work [`LaserScan`] and swaps it into a `watch` slot; handles copy the inline scan out.
//! Neither step allocates.
//!
//! **Losses.** When the stream stalls (watchdog) or the unit restarts, the machine re-probes
//! and re-initialises by itself; handles see [`LinkStatus::Lost`] and then
//! [`LinkStatus::Connected`](ima_serial::LinkStatus::Connected) again. Only a failed initialisation is final.

use std::time::Duration;

use ima_hal::laser::{LaserDescription, LaserScan, LaserScanner};
use ima_hal::link::ProbeReport;
use ima_hal::{ErrorType, Instant, Isometry2, Stamped};
use ima_serial::handle::{Handle, Pending};
use ima_serial::probe::Probe;
use ima_serial::runner::{End, Reply, Shell};
use tokio::io::{AsyncRead, AsyncWrite};
use tokio::sync::watch;

use crate::decode::{Variant, decode_scan};
pub use crate::driver::{
    BaudControl, CLOSE_TIMEOUT, DriverError, Fault, FixedBaud, LinkStatus, ScanStats,
};
use crate::machine::{Config, Event, MAX_COMMAND, Machine, MachineError, SessionInfo};
use crate::wire::{MeasuringMode, StatusByte};
/// The process's one clock, passed to `connect`: every stamp the driver produces is on it.
pub use ima_hal::time::{Clock, SharedClock, TokioClock};
/// The calls every driver handle answers alike: `link`, `stats`, `now`, `halt_signal`, `close`.
pub use ima_serial::handle::Driver;
/// Open a serial port for the shell: 8N1, no flow control, at `baud` (probing changes it).
pub use ima_serial::open_port;

/// The latest scan and its sequence number (0: none yet).
#[derive(Debug, Clone)]
struct Slot {
    seq: u64,
    scan: Stamped<LaserScan>,
}

/// How long [`SickLms::connect`] waits for the unit by default (power-up takes up to 30 s).
pub const DEFAULT_CONNECT_TIMEOUT: Duration = Duration::from_secs(30);

/// A handle to a running SICK LMS driver. Cheap to clone; every clone talks to the same task.
#[derive(Debug, Clone)]
pub struct SickLms {
    h: Handle<SickShell>,
    scan: watch::Receiver<Slot>,
    device_type: watch::Receiver<String>,
    status: watch::Receiver<Option<StatusByte>>,
    probe: watch::Receiver<ProbeReport>,
    pose: Isometry2,
    scan_timeout: Duration,
}

impl SickLms {
    /// Spawn the driver task on `stream` and wait until the unit is initialised (probe,
    /// baud, variant, configuration, streaming as `cfg` asks) or `connect_timeout` passes.
    /// Must be called inside a tokio runtime. `clock` is the process's one time base.
    ///
    /// # Errors
    /// [`Fault::NotFound`] (what each rate tried received) if no unit answered; the
    /// session's failure.
    pub async fn connect<S>(
        stream: S,
        cfg: Config,
        connect_timeout: Duration,
        clock: SharedClock,
    ) -> Result<SickLms, DriverError>
    where
        S: AsyncRead + AsyncWrite + BaudControl + Unpin + Send + 'static,
    {
        let empty = Stamped::new(Instant::ZERO, LaserScan::default());
        let (scan_tx, scan) = watch::channel(Slot {
            seq: 0,
            scan: empty,
        });
        let (type_tx, device_type) = watch::channel(String::new());
        let (status_tx, status) = watch::channel(None);
        let probe = Probe::new("SICK LMS");
        let shell = SickShell {
            machine: Machine::new(cfg, clock.now()),
            link: watch::channel(LinkStatus::Connecting).0,
            out: Scans {
                slot: scan_tx,
                work: LaserScan::default(),
                stats: ScanStats::default(),
            },
            device_type: type_tx,
            status: status_tx,
            waiter: Pending::default(),
            probe,
        };
        let probe = shell.probe.subscribe();
        let (h, _) = Handle::connect(shell, stream, clock, connect_timeout, None).await?;
        Ok(SickLms {
            h,
            scan,
            device_type,
            status,
            probe,
            pose: Isometry2::identity(),
            scan_timeout: Duration::from_secs(3),
        })
    }

    /// Where the scanner sits on the robot (the [`LaserDescription`]'s pose).
    #[must_use]
    pub fn with_pose(mut self, pose: Isometry2) -> Self {
        self.pose = pose;
        self
    }

    /// How long [`LaserScanner::next_scan`] waits for a scan (default 3 s).
    #[must_use]
    pub fn with_scan_timeout(mut self, timeout: Duration) -> Self {
        self.scan_timeout = timeout;
        self
    }

    /// What the session runs with, once initialised.
    #[must_use]
    pub fn session(&self) -> Option<SessionInfo> {
        self.h.link().connection().copied()
    }

    /// The unit's type string (e.g. `LMS200;30106`), once identified.
    #[must_use]
    pub fn device_type(&self) -> String {
        self.device_type.borrow().clone()
    }

    /// The unit's last status byte (pollution, errors), if any.
    #[must_use]
    pub fn device_status(&self) -> Option<StatusByte> {
        *self.status.borrow()
    }

    /// What each rate tried while connecting received (bytes, frames).
    #[must_use]
    pub fn probe_report(&self) -> ProbeReport {
        self.probe.borrow().clone()
    }

    /// Wait until the session is ready again (after a loss or a reconfiguration).
    ///
    /// # Errors
    /// The link's failure, or `Timeout`.
    pub async fn wait_ready(&self, timeout: Duration) -> Result<SessionInfo, DriverError> {
        self.h.wait_connected(timeout).await
    }

    /// Ask the machine for `start` and keep the reply until the session is ready again
    /// (`start` answers `Some` when there is nothing to do).
    async fn reconfigure(
        &self,
        timeout: Duration,
        start: impl FnOnce(&mut Machine, Instant) -> Result<Option<SessionInfo>, MachineError>
        + Send
        + 'static,
    ) -> Result<SessionInfo, DriverError> {
        let f = |s: &mut SickShell, now, reply: Reply<SessionInfo, SickShell>| match start(
            &mut s.machine,
            now,
        ) {
            Ok(Some(info)) => drop(reply.send(Ok(info))),
            Ok(None) => {
                if !s.waiter.is_waiting() {
                    s.link.send_replace(LinkStatus::Connecting);
                }
                s.waiter.wait(Ok(()), reply, MachineError::Busy.into());
            }
            Err(e) => drop(reply.send(Err(e.into()))),
        };
        self.h.defer(timeout, f).await
    }

    /// Switch the scan variant (angle and resolution); returns the new session.
    ///
    /// # Errors
    /// The unit's refusal, or `Timeout`.
    pub async fn set_variant(&self, variant: Variant) -> Result<SessionInfo, DriverError> {
        let start = move |m: &mut Machine, now| m.set_variant(variant, now).map(|()| None);
        self.reconfigure(Duration::from_secs(20), start).await
    }

    /// Start or stop the scan stream; returns the session.
    ///
    /// # Errors
    /// The unit's refusal, or `Timeout`.
    pub async fn set_streaming(&self, on: bool) -> Result<SessionInfo, DriverError> {
        let start = move |m: &mut Machine, now| match on {
            _ if on == m.is_streaming() && m.is_ready() => Ok(Some(m.session())),
            true => m.start_stream(now).map(|()| None),
            false => m.stop_stream(now).map(|()| None),
        };
        self.reconfigure(Duration::from_secs(10), start).await
    }

    async fn wait_scan(&self, after: Instant) -> Result<Stamped<LaserScan>, DriverError> {
        let newer = |s: &Slot| (s.seq > 0 && s.scan.at > after).then(|| s.scan.clone());
        self.h.wait_for(&self.scan, self.scan_timeout, newer).await
    }
}

/// [`close`](Driver::close) stops the stream and puts the unit back at its power-up rate;
/// [`stats`](Driver::stats) count the scans delivered up to the latest a handle can see.
impl Driver for SickLms {
    type Shell = SickShell;
    const CLOSE_LIMIT: Duration = CLOSE_TIMEOUT.saturating_add(Duration::from_secs(1));
    fn handle(&self) -> &Handle<SickShell> {
        &self.h
    }
    fn stats(&self) -> ScanStats {
        let delivered = self.scan.borrow().seq;
        ScanStats {
            delivered,
            ..self.h.stats()
        }
    }
}

impl ErrorType for SickLms {
    type Error = DriverError;
}

impl LaserScanner for SickLms {
    fn description(&self) -> LaserDescription {
        crate::decode::describe_session(self.session().as_ref(), self.pose)
    }

    async fn scan(&mut self) -> Result<Stamped<LaserScan>, DriverError> {
        self.wait_scan(Instant::ZERO).await
    }

    async fn next_scan(&mut self, after: Instant) -> Result<Stamped<LaserScan>, DriverError> {
        self.wait_scan(after).await
    }
}

/// Machine events → scans, the link status and answers.
#[derive(Debug)]
pub struct SickShell {
    machine: Machine,
    link: watch::Sender<LinkStatus>,
    out: Scans,
    device_type: watch::Sender<String>,
    status: watch::Sender<Option<StatusByte>>,
    /// The reconfiguration being waited for.
    waiter: Pending<SessionInfo, Self>,
    /// What each rate tried received, until the first connection.
    probe: Probe,
}

/// Where decoded scans and their counters go.
#[derive(Debug)]
struct Scans {
    slot: watch::Sender<Slot>,
    /// Where the next scan is decoded (swapped into the slot: no copy, no heap).
    work: LaserScan,
    stats: ScanStats,
}

impl Scans {
    /// Decode one B0 into the work buffer and swap it into the slot (with its number, so a
    /// handle woken by the scan sees it counted). A bad B0 never clobbers the latest good
    /// scan.
    fn publish(&mut self, b0: &crate::wire::Scan<'_>, at: Instant, mode: MeasuringMode) {
        let st = &mut self.stats;
        if decode_scan(b0, mode, None, &mut self.work).is_err() {
            st.decode_errors = st.decode_errors.saturating_add(1);
            return;
        }
        st.delivered = st.delivered.saturating_add(1);
        let delivered = st.delivered;
        let work = &mut self.work;
        self.slot.send_modify(|slot| {
            core::mem::swap(&mut slot.scan.value, work);
            slot.scan.at = at;
            slot.seq = delivered;
        });
    }
}

impl Shell for SickShell {
    type Machine = Machine;
    type Fault = Fault;
    type Up = SessionInfo;
    type Stats = ScanStats;
    const MAX_FRAME: usize = MAX_COMMAND;

    fn machine(&mut self) -> &mut Machine {
        &mut self.machine
    }

    fn link(&self) -> &watch::Sender<LinkStatus> {
        &self.link
    }

    fn on_bytes(&mut self, bytes: &[u8], now: Instant) {
        let before = self.machine.counters().tally();
        let mode = self.machine.measuring_mode();
        (self.machine).handle_bytes_with(bytes, now, |b0, at| self.out.publish(b0, at, mode));
        let after = self.machine.counters().tally();
        self.probe.received(bytes.len(), before, after);
    }

    fn on_timeout(&mut self, now: Instant) {
        let mode = self.machine.measuring_mode();
        (self.machine).handle_timeout_with(now, |b0, at| self.out.publish(b0, at, mode));
    }

    fn on_event(&mut self, ev: Event, line: &mut dyn BaudControl) -> std::io::Result<()> {
        match ev {
            Event::SetHostBaud(b) => {
                tracing::debug!(baud = b, "sick_lms: line speed");
                line.set_baud(b)?;
                line.clear_input()?;
                self.probe.rate(b, self.machine.is_probing());
            }
            Event::Identified => {
                if let Some(t) = self.machine.device_type() {
                    let t = String::from_utf8_lossy(t).trim().to_owned();
                    self.device_type.send_replace(t);
                }
            }
            Event::Ready(info) => {
                let baud = info.baud.bps();
                tracing::info!(baud, streaming = info.streaming, "sick_lms: ready");
                self.out.stats.readies = self.out.stats.readies.saturating_add(1);
                self.probe.connected();
                self.waiter.answer(Ok(info));
                self.link.send_replace(LinkStatus::Connected(info));
            }
            // A stream start/stop request ends with `Ready` only during initialisation;
            // answer the waiter here too.
            Event::StreamStarted | Event::StreamStopped if self.machine.is_ready() => {
                let info = self.machine.session();
                self.waiter.answer(Ok(info));
                self.link.send_replace(LinkStatus::Connected(info));
            }
            Event::Restarted => {
                tracing::warn!("sick_lms: unit restarted, re-initialising");
                self.out.stats.losses = self.out.stats.losses.saturating_add(1);
                self.link.send_replace(LinkStatus::Lost);
            }
            Event::Error(e) => {
                self.waiter.answer(Err(e.into()));
                if self.machine.is_failed() {
                    let err = if e == MachineError::NoDevice {
                        self.no_answer()
                    } else {
                        e.into()
                    };
                    self.link.send_replace(LinkStatus::Failed(err));
                } else if e == MachineError::StreamStalled {
                    tracing::warn!("sick_lms: stream stalled, re-probing");
                    self.out.stats.losses = self.out.stats.losses.saturating_add(1);
                    self.link.send_replace(LinkStatus::Lost);
                } else if self.machine.is_ready() {
                    let info = self.machine.session();
                    self.link.send_replace(LinkStatus::Connected(info));
                } else {
                    tracing::debug!(error = %e, "sick_lms: request failed");
                }
            }
            Event::DeviceStatus(s) => {
                if s.pollution() || s.is_error() {
                    tracing::warn!(status = s.0, "sick_lms: device status");
                }
                self.status.send_replace(Some(s));
            }
            Event::BaudDetected(b) if !self.probe.is_done() => {
                tracing::info!(target: "ima::connect", "SICK LMS: answered at {} baud", b.bps());
            }
            Event::StreamStarted
            | Event::StreamStopped
            | Event::PowerOn
            | Event::Closed
            | Event::BaudDetected(_)
            | Event::ConfigWritten => {}
        }
        Ok(())
    }

    fn stats(&self) -> ScanStats {
        ScanStats {
            framer: self.machine.counters(),
            session: self.machine.stats(),
            ..self.out.stats
        }
    }

    /// Stop the stream and put the unit back at 9600, within [`CLOSE_TIMEOUT`].
    fn begin_close(&mut self, now: Instant) -> Duration {
        self.waiter.answer(Err(DriverError::Disconnected));
        self.machine.close(now);
        CLOSE_TIMEOUT
    }

    fn is_closed(&mut self) -> bool {
        self.machine.is_closed()
    }

    fn end(&mut self, how: End) {
        if let End::Failed(e) = how {
            self.waiter.answer(Err(e.into()));
        }
    }

    /// Nothing valid came back: say what was seen at each rate.
    fn no_answer(&mut self) -> DriverError {
        let report = Box::new(self.probe.report());
        if report.total_frames() > 0 {
            return DriverError::Timeout;
        }
        let rs422 = self.machine.config().rs422;
        DriverError::Device(Fault::NotFound { report, rs422 })
    }
}

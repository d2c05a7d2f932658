//! The async I/O shell (feature `tokio`): one task owns the byte stream and the sans-IO
//! [`Machine`]; cloneable [`SickLms`] handles talk to it and implement
//! [`ima_hal::laser::LaserScanner`].
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
use ima_serial::runner::{self, End, Flow, Shell};
use tokio::io::{AsyncRead, AsyncWrite};
use tokio::sync::{mpsc, oneshot, watch};

use crate::decode::{Variant, decode_scan};
pub use crate::driver::{
    BaudControl, CLOSE_TIMEOUT, DriverError, FixedBaud, LinkStatus, ScanStats,
};
use crate::machine::{Config, Event, MAX_COMMAND, Machine, MachineError, SessionInfo};
use crate::wire::{MeasuringMode, StatusByte};
/// The clock types a shell takes: the caller passes the process's one [`SharedClock`]
/// (usually a [`TokioClock`], so paused tests run in virtual time) to `connect`, and every
/// stamp the driver produces is on that time line.
pub use ima_hal::time::{Clock, SharedClock, TokioClock};
/// Open a serial port for the shell: 8N1, no flow control, at `baud` (the probe changes it).
pub use ima_serial::open_port;

/// The latest scan and its sequence number (0: none yet).
#[derive(Debug, Clone)]
pub(crate) struct Slot {
    /// 0: none yet.
    pub(crate) seq: u64,
    pub(crate) scan: Stamped<LaserScan>,
}

impl Default for Slot {
    fn default() -> Self {
        Self {
            seq: 0,
            scan: Stamped::new(Instant::ZERO, LaserScan::default()),
        }
    }
}

pub(crate) type Reply = oneshot::Sender<Result<SessionInfo, DriverError>>;

/// A request from a handle to the driver task.
#[derive(Debug)]
pub enum Request {
    /// Change the scan variant (answered at `Ready`).
    Variant(Variant, Reply),
    /// Start or stop the B0 stream.
    Stream(bool, Reply),
    /// Stop, restore 9600 and end the task (answered at once; the link says when it ended).
    Close(oneshot::Sender<()>),
}

/// The receiving ends of what [`SickShell`] publishes.
#[derive(Debug, Clone)]
pub(crate) struct Watches {
    pub(crate) scan: watch::Receiver<Slot>,
    pub(crate) link: watch::Receiver<LinkStatus>,
    pub(crate) stats: watch::Receiver<ScanStats>,
    pub(crate) device_type: watch::Receiver<String>,
    pub(crate) probe: watch::Receiver<ProbeReport>,
    pub(crate) status: watch::Receiver<Option<StatusByte>>,
}

/// How long [`SickLms::connect`] waits by default: a probe round over four rates with
/// retries, a baud change and a config write fit well inside it.
pub const DEFAULT_CONNECT_TIMEOUT: Duration = Duration::from_secs(30);

/// A handle to a running SICK LMS driver. Cheap to clone; every clone talks to the same task.
#[derive(Debug, Clone)]
pub struct SickLms {
    tx: mpsc::Sender<Request>,
    w: Watches,
    pose: Isometry2,
    clock: SharedClock,
    scan_timeout: Duration,
}

impl SickLms {
    /// Spawn the driver task on `stream` and wait until the session is ready (or
    /// `connect_timeout` passes). Must be called inside a tokio runtime.
    ///
    /// `clock` is the process's one time base: every reading's stamp is taken on it.
    pub async fn connect<S>(
        stream: S,
        cfg: Config,
        connect_timeout: Duration,
        clock: SharedClock,
    ) -> Result<SickLms, DriverError>
    where
        S: AsyncRead + AsyncWrite + BaudControl + Unpin + Send + 'static,
    {
        let rs422 = cfg.rs422;
        let (shell, mut w) = SickShell::new(cfg, clock.now());
        let tx = runner::spawn(shell, stream, clock.clone(), None);
        match runner::wait_connected(&mut w.link, connect_timeout).await {
            Ok(_) => {}
            Err(Some(e)) => return Err(e),
            Err(None) => {
                let _ = tx.try_send(Request::Close(oneshot::channel().0));
                let report = w.probe.borrow().clone();
                // Nothing valid came back: say what was seen at each rate.
                if report.total_frames() == 0 {
                    let report = Box::new(report);
                    return Err(DriverError::NotFound { report, rs422 });
                }
                return Err(DriverError::Timeout);
            }
        }
        Ok(SickLms {
            tx,
            w,
            pose: Isometry2::identity(),
            clock,
            scan_timeout: Duration::from_secs(3),
        })
    }

    /// Set where the scanner sits on the robot (reported by [`LaserScanner::description`]).
    #[must_use]
    pub fn with_pose(mut self, pose: Isometry2) -> Self {
        self.pose = pose;
        self
    }

    /// How long [`LaserScanner::scan`] / [`LaserScanner::next_scan`] wait (default 3 s).
    #[must_use]
    pub fn with_scan_timeout(mut self, timeout: Duration) -> Self {
        self.scan_timeout = timeout;
        self
    }

    /// Current link status.
    #[must_use]
    pub fn link(&self) -> LinkStatus {
        self.w.link.borrow().clone()
    }

    /// What the session runs with, when ready.
    #[must_use]
    pub fn session(&self) -> Option<SessionInfo> {
        self.w.link.borrow().connection().copied()
    }

    /// Counters (scans delivered, bad CRCs, retransmissions, losses…).
    #[must_use]
    pub fn stats(&self) -> ScanStats {
        *self.w.stats.borrow()
    }

    /// The type string the unit reported (e.g. `LMS200;30106`), empty until identified.
    #[must_use]
    pub fn device_type(&self) -> String {
        self.w.device_type.borrow().clone()
    }

    /// The unit's latest status byte (pollution, implausible values, errors), once any
    /// telegram arrived.
    #[must_use]
    pub fn device_status(&self) -> Option<StatusByte> {
        *self.w.status.borrow()
    }

    /// What the first connection saw at each rate it tried (bytes, valid frames).
    #[must_use]
    pub fn probe_report(&self) -> ProbeReport {
        self.w.probe.borrow().clone()
    }

    /// The driver's clock (the time base of every stamp it produces).
    #[must_use]
    pub fn now(&self) -> Instant {
        self.clock.now()
    }

    /// Wait until the link is ready again (after a loss), at most `timeout`.
    pub async fn wait_ready(&self, timeout: Duration) -> Result<SessionInfo, DriverError> {
        let mut link = self.w.link.clone();
        runner::wait_connected(&mut link, timeout)
            .await
            .map_err(|e| e.unwrap_or(DriverError::Timeout))
    }

    async fn request(
        &self,
        make: impl FnOnce(Reply) -> Request,
        timeout: Duration,
    ) -> Result<SessionInfo, DriverError> {
        runner::request(&self.tx, make, timeout).await
    }

    /// Change the scan variant (stream stopped, `3B`, stream restarted; spec §3.6).
    pub async fn set_variant(&self, variant: Variant) -> Result<SessionInfo, DriverError> {
        self.request(|tx| Request::Variant(variant, tx), Duration::from_secs(20))
            .await
    }

    /// Start (`20 24`) or stop (`20 25`) the B0 stream.
    pub async fn set_streaming(&self, on: bool) -> Result<SessionInfo, DriverError> {
        self.request(|tx| Request::Stream(on, tx), Duration::from_secs(10))
            .await
    }

    /// Stop the stream, switch the unit back to its power-up rate (9600: the LMS keeps a
    /// switched rate until it is power-cycled, and the next program would have to find it)
    /// and end the driver task, releasing the port. Bounded by [`CLOSE_TIMEOUT`]: a unit that
    /// does not answer is left as it is. Dropping every handle does the same.
    pub async fn close(&self) -> Result<(), DriverError> {
        let (tx, rx) = oneshot::channel();
        self.tx
            .send(Request::Close(tx))
            .await
            .map_err(|_| DriverError::Disconnected)?;
        let mut link = self.w.link.clone();
        tokio::time::timeout(CLOSE_TIMEOUT + Duration::from_secs(1), async move {
            let _ = rx.await;
            // Wait until the task has let go of the port.
            while !matches!(
                &*link.borrow_and_update(),
                LinkStatus::Closed | LinkStatus::Failed(_)
            ) {
                if link.changed().await.is_err() {
                    break;
                }
            }
        })
        .await
        .map_err(|_| DriverError::Timeout)
    }

    /// Wait for a scan with sequence number above `after_seq` and stamped after `after`.
    async fn wait_scan(&self, after: Instant) -> Result<Stamped<LaserScan>, DriverError> {
        let mut rx = self.w.scan.clone();
        let mut link = self.w.link.clone();
        tokio::time::timeout(self.scan_timeout, async move {
            loop {
                {
                    let s = rx.borrow_and_update();
                    if s.seq > 0 && s.scan.at > after {
                        return Ok(s.scan.clone());
                    }
                }
                if let LinkStatus::Failed(e) = &*link.borrow_and_update() {
                    return Err(e.clone());
                }
                tokio::select! {
                    r = rx.changed() => r.map_err(|_| DriverError::Disconnected)?,
                    r = link.changed() => r.map_err(|_| DriverError::Disconnected)?,
                }
            }
        })
        .await
        .map_err(|_| DriverError::Timeout)?
    }
}

impl ErrorType for SickLms {
    type Error = DriverError;
}

impl LaserScanner for SickLms {
    fn description(&self) -> LaserDescription {
        crate::driver::description(self.session().as_ref(), self.pose)
    }

    async fn scan(&mut self) -> Result<Stamped<LaserScan>, DriverError> {
        {
            let s = self.w.scan.borrow();
            if s.seq > 0 {
                return Ok(s.scan.clone());
            }
        }
        self.wait_scan(Instant::ZERO).await
    }

    async fn next_scan(&mut self, after: Instant) -> Result<Stamped<LaserScan>, DriverError> {
        self.wait_scan(after).await
    }
}

/// Machine events → scans, status and answers, for both shells.
#[derive(Debug)]
pub struct SickShell {
    machine: Machine,
    scan_tx: watch::Sender<Slot>,
    link_tx: watch::Sender<LinkStatus>,
    stats_tx: watch::Sender<ScanStats>,
    type_tx: watch::Sender<String>,
    probe_tx: watch::Sender<ProbeReport>,
    status_tx: watch::Sender<Option<StatusByte>>,
    /// The caller of the reconfiguration in flight (answered at `Ready` or `Error`).
    waiter: Option<Reply>,
    /// Decoding buffer, swapped into the watch slot (no allocation per scan).
    work: LaserScan,
    stats: ScanStats,
    seq: u64,
    /// What the first connection saw per rate (counted until the first `Ready`).
    probe: ProbeReport,
    /// The session was ready once (the probe report is final).
    connected: bool,
}

impl SickShell {
    pub(crate) fn new(cfg: Config, now: Instant) -> (Self, Watches) {
        let (scan_tx, scan) = watch::channel(Slot::default());
        let (link_tx, link) = watch::channel(LinkStatus::Connecting);
        let (stats_tx, stats) = watch::channel(ScanStats::default());
        let (type_tx, device_type) = watch::channel(String::new());
        let (probe_tx, probe) = watch::channel(ProbeReport::new());
        let (status_tx, status) = watch::channel(None);
        let shell = Self {
            machine: Machine::new(cfg, now),
            scan_tx,
            link_tx,
            stats_tx,
            type_tx,
            probe_tx,
            status_tx,
            waiter: None,
            work: LaserScan::default(),
            stats: ScanStats::default(),
            seq: 0,
            probe: ProbeReport::new(),
            connected: false,
        };
        let w = Watches {
            scan,
            link,
            stats,
            device_type,
            probe,
            status,
        };
        (shell, w)
    }

    /// The machine (read-only).
    pub(crate) fn machine_ref(&self) -> &Machine {
        &self.machine
    }

    /// If a scan newer than `seq` arrived, swap it into `into` (no copy) and return its
    /// sequence number.
    pub(crate) fn take_newer(&mut self, seq: u64, into: &mut Stamped<LaserScan>) -> Option<u64> {
        let mut got = None;
        self.scan_tx.send_if_modified(|slot| {
            if slot.seq > seq {
                core::mem::swap(&mut slot.scan, into);
                got = Some(slot.seq);
            }
            false
        });
        got
    }

    fn answer(&mut self, r: Result<SessionInfo, DriverError>) {
        if let Some(w) = self.waiter.take() {
            let _ = w.send(r);
        }
    }
}

impl Shell for SickShell {
    type Machine = Machine;
    type Request = Request;
    const MAX_FRAME: usize = MAX_COMMAND;

    fn machine(&mut self) -> &mut Machine {
        &mut self.machine
    }

    /// Decodes every B0 in place (borrowed from the framer); counts bytes and frames per
    /// rate until the first connection.
    fn on_bytes(&mut self, bytes: &[u8], now: Instant) {
        let before = (!self.connected).then(|| self.machine.counters());
        let mode = self.machine.measuring_mode();
        let mut out = Out {
            work: &mut self.work,
            stats: &mut self.stats,
            stats_tx: &self.stats_tx,
            scan_tx: &self.scan_tx,
            seq: &mut self.seq,
        };
        self.machine
            .handle_bytes_with(bytes, now, |b0, at| out.publish(b0, at, mode));
        if let Some(b) = before {
            let a = self.machine.counters();
            let bad = |c: crate::framer::Counters| {
                c.bad_checksums + c.bad_headers + c.bad_payloads + c.expired
            };
            self.probe.received(bytes.len());
            self.probe.framed(
                (a.frames + a.acks + a.naks).saturating_sub(b.frames + b.acks + b.naks),
                bad(a).saturating_sub(bad(b)),
            );
            self.probe_tx.send_replace(self.probe.clone());
        }
    }

    fn on_timeout(&mut self, now: Instant) {
        let mode = self.machine.measuring_mode();
        let mut out = Out {
            work: &mut self.work,
            stats: &mut self.stats,
            stats_tx: &self.stats_tx,
            scan_tx: &self.scan_tx,
            seq: &mut self.seq,
        };
        self.machine
            .handle_timeout_with(now, |b0, at| out.publish(b0, at, mode));
    }

    fn on_event(&mut self, ev: Event, line: &mut dyn BaudControl) -> std::io::Result<()> {
        match ev {
            Event::SetHostBaud(b) => {
                tracing::debug!(baud = b, "sick_lms: line speed");
                line.set_baud(b)?;
                line.clear_input()?;
                if !self.connected {
                    if self.machine.is_probing() {
                        self.probe.attempt(b);
                        let n = self.probe.current_tally().map_or(1, |t| t.attempts);
                        tracing::info!(target: "ima::connect", "SICK LMS: trying {b} baud (attempt {n})");
                    } else {
                        self.probe.set_rate(b);
                        tracing::info!(target: "ima::connect", "SICK LMS: switching to {b} baud");
                    }
                    self.probe_tx.send_replace(self.probe.clone());
                }
            }
            Event::Identified => {
                if let Some(t) = self.machine.device_type() {
                    let t = String::from_utf8_lossy(t).trim().to_owned();
                    self.type_tx.send_replace(t);
                }
            }
            Event::Ready(info) => {
                let baud = info.baud.bps();
                tracing::info!(baud, streaming = info.streaming, "sick_lms: ready");
                self.stats.readies = self.stats.readies.saturating_add(1);
                self.connected = true;
                self.answer(Ok(info));
                self.link_tx.send_replace(LinkStatus::Connected(info));
            }
            // A stream start/stop request ends with `Ready` only during initialisation;
            // answer the waiter here too.
            Event::StreamStarted | Event::StreamStopped if self.machine.is_ready() => {
                let info = self.machine.session();
                self.answer(Ok(info));
                self.link_tx.send_replace(LinkStatus::Connected(info));
            }
            Event::Restarted => {
                tracing::warn!("sick_lms: unit restarted, re-initialising");
                self.stats.losses = self.stats.losses.saturating_add(1);
                self.link_tx.send_replace(LinkStatus::Lost);
            }
            Event::Error(e) => {
                self.answer(Err(DriverError::Session(e)));
                if self.machine.is_failed() {
                    let err = if e == MachineError::NoDevice {
                        let report = Box::new(self.probe.clone());
                        let rs422 = self.machine.config().rs422;
                        DriverError::NotFound { report, rs422 }
                    } else {
                        DriverError::Session(e)
                    };
                    self.link_tx.send_replace(LinkStatus::Failed(err));
                } else if e == MachineError::StreamStalled {
                    tracing::warn!("sick_lms: stream stalled, re-probing");
                    self.stats.losses = self.stats.losses.saturating_add(1);
                    self.link_tx.send_replace(LinkStatus::Lost);
                } else if self.machine.is_ready() {
                    let info = self.machine.session();
                    self.link_tx.send_replace(LinkStatus::Connected(info));
                } else {
                    tracing::debug!(error = ?e, "sick_lms: request failed");
                }
            }
            Event::DeviceStatus(s) => {
                if s.pollution() || s.is_error() {
                    tracing::warn!(status = s.0, "sick_lms: device status");
                }
                self.status_tx.send_replace(Some(s));
            }
            Event::BaudDetected(b) if !self.connected => {
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

    fn on_request(&mut self, req: Request, now: Instant) -> Flow {
        let m = &mut self.machine;
        let (result, tx) = match req {
            Request::Close(tx) => {
                let _ = tx.send(());
                return Flow::Close;
            }
            Request::Variant(v, tx) => (m.set_variant(v, now), tx),
            Request::Stream(on, tx) if on == m.is_streaming() && m.is_ready() => {
                let _ = tx.send(Ok(m.session()));
                return Flow::Continue;
            }
            Request::Stream(true, tx) => (m.start_stream(now), tx),
            Request::Stream(false, tx) => (m.stop_stream(now), tx),
        };
        match result {
            Ok(()) => {
                self.link_tx.send_replace(LinkStatus::Connecting);
                self.waiter = Some(tx);
            }
            Err(e) => {
                let _ = tx.send(Err(DriverError::Session(e)));
            }
        }
        Flow::Continue
    }

    fn after_round(&mut self) {
        self.stats.framer = self.machine.counters();
        self.stats.session = self.machine.stats();
        let s = self.stats;
        self.stats_tx.send_if_modified(|old| {
            let changed = *old != s;
            *old = s;
            changed
        });
    }

    /// Stop the stream and put the unit back at 9600, within [`CLOSE_TIMEOUT`].
    fn begin_close(&mut self, now: Instant) -> Duration {
        self.answer(Err(DriverError::Disconnected));
        self.machine.close(now);
        CLOSE_TIMEOUT
    }

    fn is_closed(&mut self) -> bool {
        self.machine.is_closed()
    }

    fn end(&mut self, how: End) {
        let link = match how {
            End::Closed { .. } => LinkStatus::Closed,
            End::Failed(e) => LinkStatus::Failed(e.into()),
        };
        if let End::Failed(e) = how {
            self.answer(Err(e.into()));
        }
        self.link_tx.send_replace(link);
    }
}

/// Where decoded scans go (borrowed from the shell while the machine holds the frame).
struct Out<'a> {
    work: &'a mut LaserScan,
    stats: &'a mut ScanStats,
    stats_tx: &'a watch::Sender<ScanStats>,
    scan_tx: &'a watch::Sender<Slot>,
    seq: &'a mut u64,
}

impl Out<'_> {
    /// Decode one B0 into the work buffer and swap it into the watch slot (counters are
    /// published first, so a handle woken by the scan sees it counted). A bad B0 never
    /// clobbers the latest good scan.
    fn publish(&mut self, b0: &crate::wire::Scan<'_>, at: Instant, mode: MeasuringMode) {
        match decode_scan(b0, mode, None, self.work) {
            Ok(()) => {
                *self.seq = self.seq.saturating_add(1);
                let s = *self.seq;
                self.stats.delivered = self.stats.delivered.saturating_add(1);
                let delivered = self.stats.delivered;
                self.stats_tx.send_modify(|st| st.delivered = delivered);
                let work = &mut *self.work;
                self.scan_tx.send_modify(|slot| {
                    core::mem::swap(&mut slot.scan.value, work);
                    slot.scan.at = at;
                    slot.seq = s;
                });
            }
            Err(_) => self.stats.decode_errors = self.stats.decode_errors.saturating_add(1),
        }
    }
}

//! The robot-side protocol model interface.
//!
//! A [`DeviceModel`] is the device's half of a serial protocol, written sans-IO like a driver's
//! `machine` but in the other role: it consumes the bytes the host sent, produces the bytes the
//! device answers, and asks to be woken at an instant for its own timers (a P2OS watchdog, a
//! SICK LMS telegram stream, a sonar ping schedule). It never touches a port or a clock; a
//! runner ([`crate::link::DeviceLink`] inside [`crate::pty::PtyDevice`] or
//! [`crate::duplex::DuplexDevice`]) feeds it.
//!
//! # Reaching the world
//!
//! A model that needs the simulated world holds a [`crate::world::SharedWorld`] handle (an
//! `Arc<Mutex<World>>`) given to its constructor, and locks it briefly inside its handlers:
//! e.g. a base model writes the commanded wheel speeds in `handle_rx` and reads the pose and
//! wheel travel when it builds a status packet in `handle_timeout`. Whoever owns time advances
//! the world: a [`crate::stepper::WorldStepper`] in real time, or a simulation loop in virtual
//! time. Models never step the world themselves (several devices share one robot).
//!
//! # Plugging in a protocol
//!
//! ```ignore
//! pub struct P2osRobot { world: SharedWorld, robot: RobotId, framer: ima_p2os::framer::Framer, out: Vec<u8>, next_sip: Option<Instant>, .. }
//! impl DeviceModel for P2osRobot {
//!     fn handle_rx(&mut self, bytes: &[u8], now: Instant) { /* framer.push(bytes) → commands → world */ }
//!     fn poll_tx(&mut self, out: &mut Vec<u8>) { out.append(&mut self.out) }
//!     fn poll_timeout(&self) -> Option<Instant> { self.next_sip }
//!     fn handle_timeout(&mut self, now: Instant) { /* emit a SIP from world state, schedule next */ }
//! }
//! ```
//!
//! # Call order
//!
//! The runner calls, in any interleaving: `handle_rx` with bytes as they arrive (after
//! faults), `handle_timeout(now)` once `now >= poll_timeout()`, and `poll_tx` after every one of
//! those calls to collect output. `now` never goes backwards.

use ima_hal::Instant;

/// The device's half of a serial protocol, sans-IO.
pub trait DeviceModel: Send {
    /// Bytes from the host (already through the host → robot fault injector), in order.
    fn handle_rx(&mut self, bytes: &[u8], now: Instant);

    /// Append everything the device has to send now to `out`.
    fn poll_tx(&mut self, out: &mut Vec<u8>);

    /// The earliest instant the model wants [`DeviceModel::handle_timeout`] called, if any.
    fn poll_timeout(&self) -> Option<Instant>;

    /// Called once `now >= poll_timeout()`.
    fn handle_timeout(&mut self, now: Instant);

    /// The host's line speed, as the host last set it on its end of the line (`None` when
    /// unknown, e.g. on an in-memory pipe). A model of a device with a fixed rate treats
    /// traffic at another rate as noise. Called before the bytes that follow the change.
    fn set_host_baud(&mut self, baud: Option<u32>) {
        let _ = baud;
    }

    /// The link went down (a hang-up): bytes no longer flow either way. Default: nothing, as
    /// for a pulled cable (the device keeps running and its output is discarded). A model
    /// emulating a power cut can reset its session here.
    fn on_hangup(&mut self, now: Instant) {
        let _ = now;
    }

    /// The link came back after [`DeviceModel::on_hangup`]. Default: nothing.
    fn on_reconnect(&mut self, now: Instant) {
        let _ = now;
    }

    /// A short name for logs.
    fn name(&self) -> &str {
        "device"
    }
}

impl<M: DeviceModel + ?Sized> DeviceModel for Box<M> {
    fn handle_rx(&mut self, bytes: &[u8], now: Instant) {
        (**self).handle_rx(bytes, now);
    }
    fn poll_tx(&mut self, out: &mut Vec<u8>) {
        (**self).poll_tx(out);
    }
    fn poll_timeout(&self) -> Option<Instant> {
        (**self).poll_timeout()
    }
    fn handle_timeout(&mut self, now: Instant) {
        (**self).handle_timeout(now);
    }
    fn on_hangup(&mut self, now: Instant) {
        (**self).on_hangup(now);
    }
    fn on_reconnect(&mut self, now: Instant) {
        (**self).on_reconnect(now);
    }
    fn name(&self) -> &str {
        (**self).name()
    }
}

/// A model that sends back every byte it receives, and optionally a heartbeat byte string at a
/// fixed period (to exercise timers). For runner tests.
#[derive(Debug, Clone, Default)]
pub struct EchoModel {
    pending: Vec<u8>,
    heartbeat: Option<(std::time::Duration, Vec<u8>)>,
    next_beat: Option<Instant>,
    received: u64,
    hangups: u32,
    reconnects: u32,
}

impl EchoModel {
    /// A plain echo.
    #[must_use]
    pub fn new() -> Self {
        Self::default()
    }

    /// An echo that also sends `beat` every `period`, starting `period` after `start`
    /// (a zero period is treated as 1 ms).
    #[must_use]
    pub fn with_heartbeat(start: Instant, period: std::time::Duration, beat: &[u8]) -> Self {
        let period = period.max(std::time::Duration::from_millis(1));
        Self {
            heartbeat: Some((period, beat.to_vec())),
            next_beat: Some(start + period),
            ..Self::default()
        }
    }

    /// Bytes received so far.
    #[must_use]
    pub fn received(&self) -> u64 {
        self.received
    }

    /// (hang-ups, reconnects) seen.
    #[must_use]
    pub fn link_events(&self) -> (u32, u32) {
        (self.hangups, self.reconnects)
    }
}

impl DeviceModel for EchoModel {
    fn handle_rx(&mut self, bytes: &[u8], _now: Instant) {
        self.received = self.received.saturating_add(bytes.len() as u64);
        self.pending.extend_from_slice(bytes);
    }

    fn poll_tx(&mut self, out: &mut Vec<u8>) {
        out.append(&mut self.pending);
    }

    fn poll_timeout(&self) -> Option<Instant> {
        self.next_beat
    }

    fn handle_timeout(&mut self, now: Instant) {
        if let (Some((period, beat)), Some(t)) = (&self.heartbeat, self.next_beat)
            && now >= t
        {
            self.pending.extend_from_slice(beat);
            // Skip missed beats rather than bursting them.
            let mut next = t + *period;
            if next <= now {
                next = now + *period;
            }
            self.next_beat = Some(next);
        }
    }

    fn on_hangup(&mut self, _now: Instant) {
        self.hangups += 1;
    }

    fn on_reconnect(&mut self, _now: Instant) {
        self.reconnects += 1;
    }

    fn name(&self) -> &str {
        "echo"
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn echo_echoes_and_beats() {
        let mut m = EchoModel::with_heartbeat(Instant::ZERO, Duration::from_millis(100), b"*");
        m.handle_rx(b"hi", Instant::ZERO);
        let mut out = Vec::new();
        m.poll_tx(&mut out);
        assert_eq!(out, b"hi");
        assert_eq!(m.poll_timeout(), Some(Instant::from_millis(100)));
        m.handle_timeout(Instant::from_millis(100));
        m.handle_timeout(Instant::from_millis(150)); // early: nothing
        m.handle_timeout(Instant::from_millis(1000)); // late: one beat, no burst
        out.clear();
        m.poll_tx(&mut out);
        assert_eq!(out, b"**");
        assert_eq!(m.poll_timeout(), Some(Instant::from_millis(1100)));
        let mut boxed: Box<dyn DeviceModel> = Box::new(m);
        boxed.on_hangup(Instant::ZERO);
        assert_eq!(boxed.name(), "echo");
    }
}

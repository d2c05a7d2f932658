//! The connect-time account of a driver that probes line rates (feature `tokio`): what each
//! rate tried received, until the first connection.

use ima_hal::link::ProbeReport;
use tokio::sync::watch;

/// A [`ProbeReport`] a shell fills while it looks for its device (on a `watch`, so a handle
/// can show it), final once the device first answers: later rate changes and bytes are
/// not counted.
#[derive(Debug)]
pub struct Probe {
    device: &'static str,
    report: watch::Sender<ProbeReport>,
    done: bool,
}

impl Probe {
    /// An empty report; `device` names the device in the connect log (`P2OS`, `SICK LMS`).
    #[must_use]
    pub fn new(device: &'static str) -> Self {
        Self {
            device,
            report: watch::channel(ProbeReport::new()).0,
            done: false,
        }
    }

    /// Where a handle reads the report.
    #[must_use]
    pub fn subscribe(&self) -> watch::Receiver<ProbeReport> {
        self.report.subscribe()
    }

    /// The report so far.
    #[must_use]
    pub fn report(&self) -> ProbeReport {
        self.report.borrow().clone()
    }

    /// Whether the device has answered once (the report is final).
    #[must_use]
    pub fn is_done(&self) -> bool {
        self.done
    }

    /// The device answered: stop counting.
    pub fn connected(&mut self) {
        self.done = true;
    }

    /// The line is now at `baud`: a new `attempt` at that rate (logged as `trying {baud}
    /// baud (attempt {n})`), or a switch the device agreed to (`switching to {baud} baud`).
    pub fn rate(&mut self, baud: u32, attempt: bool) {
        if self.done {
            return;
        }
        let device = self.device;
        self.report.send_modify(|p| {
            if attempt {
                p.attempt(baud);
                let n = p.current_tally().map_or(1, |t| t.attempts);
                tracing::info!(target: "ima::connect", "{device}: trying {baud} baud (attempt {n})");
            } else {
                p.set_rate(baud);
                tracing::info!(target: "ima::connect", "{device}: switching to {baud} baud");
            }
        });
    }

    /// `bytes` bytes arrived; the framer's (valid, bad) frame counts went from `before` to
    /// `after`.
    pub fn received(&mut self, bytes: usize, before: (u64, u64), after: (u64, u64)) {
        if self.done {
            return;
        }
        self.report.send_modify(|p| {
            p.received(bytes);
            p.framed(
                after.0.saturating_sub(before.0),
                after.1.saturating_sub(before.1),
            );
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_until_the_first_connection() {
        let mut p = Probe::new("printer");
        let rx = p.subscribe();
        p.rate(9600, true);
        p.received(10, (0, 0), (0, 2));
        p.rate(9600, true);
        p.rate(38400, true);
        p.received(20, (0, 2), (3, 2));
        p.rate(115_200, false);
        p.connected();
        p.received(5, (3, 2), (4, 2));
        p.rate(9600, true);
        assert!(p.is_done());
        let r = rx.borrow().clone();
        assert_eq!(r, p.report());
        let t: Vec<_> = r
            .rates()
            .iter()
            .map(|t| (t.baud, t.attempts, t.bytes, t.frames, t.bad_frames))
            .collect();
        assert_eq!(
            t,
            [
                (9600, 2, 10, 0, 2),
                (38400, 1, 20, 3, 0),
                (115_200, 0, 0, 0, 0)
            ]
        );
    }
}

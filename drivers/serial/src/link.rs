//! The link as handles see it, and the ways a link ends that no protocol explains.

use std::io;

/// A driver's link, as its handles see it. `U` is what a connected link reports (who
/// answered, at what rate; `()` when there is nothing to say), `E` the driver's error.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LinkStatus<U, E> {
    /// Handshaking or configuring (first time, or after a request that re-configures).
    Connecting,
    /// The device answers and data flows.
    Connected(U),
    /// The device went quiet or restarted; the driver is recovering by itself.
    Lost,
    /// Failed for good.
    Failed(E),
    /// The driver task ended.
    Closed,
}

impl<U, E> LinkStatus<U, E> {
    /// Whether the link is connected.
    #[must_use]
    pub fn is_connected(&self) -> bool {
        matches!(self, Self::Connected(_))
    }

    /// Whether the link has ended for good ([`Failed`](Self::Failed) or
    /// [`Closed`](Self::Closed)): the driver does not come back by itself.
    #[must_use]
    pub fn is_ended(&self) -> bool {
        matches!(self, Self::Failed(_) | Self::Closed)
    }

    /// Whether a robot on this link may not hear a stop written at `now`: the link is
    /// [`Lost`](Self::Lost), or [`Connected`](Self::Connected) but with nothing good heard
    /// for `quiet` (a device that streams reports every 100 ms, silent for 300 ms, is gone
    /// long before its driver's link timeout says so). `last_heard`: the last good frame.
    #[must_use]
    pub fn is_quiet(
        &self,
        last_heard: Option<ima_hal::Instant>,
        now: ima_hal::Instant,
        quiet: std::time::Duration,
    ) -> bool {
        match self {
            Self::Lost => true,
            Self::Connected(_) => {
                last_heard.is_none_or(|t| now.saturating_duration_since(t) > quiet)
            }
            _ => false,
        }
    }

    /// What a connected link reports.
    #[must_use]
    pub fn connection(&self) -> Option<&U> {
        match self {
            Self::Connected(u) => Some(u),
            _ => None,
        }
    }
}

/// How a link ended or a wait failed, whatever the protocol: every driver error converts
/// from it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LinkError {
    /// The driver task has ended (port closed, end of stream, or `close`).
    Disconnected,
    /// No answer in time.
    Timeout,
    /// An I/O error on the port.
    Io(io::ErrorKind),
}

impl From<io::Error> for LinkError {
    fn from(e: io::Error) -> Self {
        Self::Io(e.kind())
    }
}

impl core::fmt::Display for LinkError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Disconnected => f.write_str("driver disconnected"),
            Self::Timeout => f.write_str("no answer in time"),
            Self::Io(k) => write!(f, "serial I/O error: {k}"),
        }
    }
}

impl std::error::Error for LinkError {}

impl ima_hal::Error for LinkError {
    fn kind(&self) -> ima_hal::ErrorKind {
        match self {
            Self::Disconnected | Self::Io(_) => ima_hal::ErrorKind::Disconnected,
            Self::Timeout => ima_hal::ErrorKind::Timeout,
        }
    }
}

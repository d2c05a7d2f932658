//! The one driver error: the ways any serial link fails, plus the device's own faults.

use std::io;

use ima_hal::ErrorKind;

use crate::LinkError;

/// What only one kind of device can report (a refused command, a wrong dialect, no answer
/// to its handshake with what the line carried). Each driver has one such type; its errors
/// are [`DriverError<ItsFault>`](DriverError).
pub trait Fault: Clone + core::fmt::Debug + core::fmt::Display + Send + Sync + 'static {
    /// How messages name the device ("P2OS robot", "SICK LMS", …).
    const DEVICE: &'static str;

    /// The HAL's classification of this fault.
    fn kind(&self) -> ErrorKind;
}

/// The errors of every serial driver: the three ways a link fails, whatever the protocol,
/// and the device's own [`Fault`]s.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum DriverError<F> {
    /// The driver task has ended (port closed, end of stream, or `close`).
    Disconnected,
    /// The device did not answer in time.
    Timeout,
    /// An I/O error on the port.
    Io(io::ErrorKind),
    /// What the device (or its protocol) reported.
    Device(F),
}

impl<F> DriverError<F> {
    /// The device's fault, if this is one.
    #[must_use]
    pub fn fault(&self) -> Option<&F> {
        match self {
            Self::Device(f) => Some(f),
            _ => None,
        }
    }
}

impl<F> From<LinkError> for DriverError<F> {
    fn from(e: LinkError) -> Self {
        match e {
            LinkError::Disconnected => Self::Disconnected,
            LinkError::Timeout => Self::Timeout,
            LinkError::Io(k) => Self::Io(k),
        }
    }
}

impl<F: Fault> From<F> for DriverError<F> {
    fn from(f: F) -> Self {
        Self::Device(f)
    }
}

impl<F: Fault> core::fmt::Display for DriverError<F> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Disconnected => write!(f, "{} driver disconnected", F::DEVICE),
            Self::Timeout => write!(f, "the {} did not answer in time", F::DEVICE),
            Self::Io(k) => write!(f, "serial I/O error on the {} port: {k}", F::DEVICE),
            Self::Device(e) => core::fmt::Display::fmt(e, f),
        }
    }
}

impl<F: Fault> std::error::Error for DriverError<F> {}

impl<F: Fault> ima_hal::Error for DriverError<F> {
    fn kind(&self) -> ErrorKind {
        match self {
            Self::Disconnected | Self::Io(_) => ErrorKind::Disconnected,
            Self::Timeout => ErrorKind::Timeout,
            Self::Device(e) => e.kind(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, Clone, PartialEq)]
    struct Jam;
    impl core::fmt::Display for Jam {
        fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
            f.write_str("paper jam")
        }
    }
    impl Fault for Jam {
        const DEVICE: &'static str = "printer";
        fn kind(&self) -> ErrorKind {
            ErrorKind::Protocol
        }
    }

    #[test]
    fn messages_name_the_device_and_kinds_follow_the_link() {
        use ima_hal::Error as _;
        let e = |l| DriverError::<Jam>::from(l);
        assert_eq!(
            e(LinkError::Disconnected).to_string(),
            "printer driver disconnected"
        );
        assert_eq!(
            e(LinkError::Timeout).to_string(),
            "the printer did not answer in time"
        );
        let io = e(LinkError::Io(io::ErrorKind::BrokenPipe));
        assert!(
            io.to_string()
                .starts_with("serial I/O error on the printer port")
        );
        assert_eq!(io.kind(), ErrorKind::Disconnected);
        assert_eq!(e(LinkError::Timeout).kind(), ErrorKind::Timeout);
        let d = DriverError::from(Jam);
        assert_eq!(
            (d.to_string().as_str(), d.kind()),
            ("paper jam", ErrorKind::Protocol)
        );
        assert_eq!(d.fault(), Some(&Jam));
    }
}

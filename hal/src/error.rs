//! The error convention shared by every HAL trait (after `embedded-hal` 1.0).

/// What kind of failure a driver error is, so that generic code can react without knowing the
/// driver: retry on [`Timeout`](ErrorKind::Timeout), reconnect on
/// [`Disconnected`](ErrorKind::Disconnected), and so on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum ErrorKind {
    /// The device did not answer in time.
    Timeout,
    /// The link to the device is gone (port closed, hung up, driver task ended).
    Disconnected,
    /// The device answered with something the protocol does not allow, or refused a request.
    Protocol,
    /// The caller asked for something out of range or unsupported by this device.
    InvalidArgument,
    /// Anything else.
    Other,
}

impl core::fmt::Display for ErrorKind {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::Timeout => "timed out",
            Self::Disconnected => "device disconnected",
            Self::Protocol => "protocol error",
            Self::InvalidArgument => "invalid argument",
            Self::Other => "other error",
        })
    }
}

/// A driver error: anything that can say what [`ErrorKind`] it is, and say it in words.
///
/// Unlike `embedded-hal` 1.0, whose errors need only `Debug`, an error here must also
/// `Display`: generic code (the agents' runtimes) reports a device's failure to the person at
/// the robot, who should read "no answer to command 3Bh (switch variant) after every retry",
/// not `Device(Session(Timeout { code: 59 }))`.
pub trait Error: core::fmt::Debug + core::fmt::Display {
    /// The kind of this error.
    fn kind(&self) -> ErrorKind;
}

impl Error for ErrorKind {
    fn kind(&self) -> ErrorKind {
        *self
    }
}

impl Error for core::convert::Infallible {
    fn kind(&self) -> ErrorKind {
        match *self {}
    }
}

/// Names the error type of a device; every HAL trait has this as its supertrait.
pub trait ErrorType {
    /// The driver's error type.
    type Error: Error;
}

impl<T: ErrorType + ?Sized> ErrorType for &mut T {
    type Error = T::Error;
}

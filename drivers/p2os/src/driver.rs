//! What both I/O shells share: the driver error and line-speed control (feature `std`).

use std::io;

use ima_hal::ErrorKind;

use crate::machine::SessionError;

/// A byte stream whose line speed can be changed (for baud probing).
pub trait BaudControl {
    /// Set the line speed.
    fn set_baud(&mut self, baud: u32) -> io::Result<()>;
}

#[cfg(feature = "tokio")]
impl BaudControl for tokio_serial::SerialStream {
    fn set_baud(&mut self, baud: u32) -> io::Result<()> {
        tokio_serial::SerialPort::set_baud_rate(self, baud).map_err(io::Error::from)
    }
}

/// Wraps a stream that has no line speed (an in-memory duplex, a TCP bridge): baud changes
/// are accepted and ignored.
#[derive(Debug)]
pub struct FixedBaud<S>(pub S);

impl<S> BaudControl for FixedBaud<S> {
    fn set_baud(&mut self, _baud: u32) -> io::Result<()> {
        Ok(())
    }
}

#[cfg(feature = "tokio")]
impl<S: tokio::io::AsyncRead + Unpin> tokio::io::AsyncRead for FixedBaud<S> {
    fn poll_read(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        buf: &mut tokio::io::ReadBuf<'_>,
    ) -> std::task::Poll<io::Result<()>> {
        std::pin::Pin::new(&mut self.0).poll_read(cx, buf)
    }
}

#[cfg(feature = "tokio")]
impl<S: tokio::io::AsyncWrite + Unpin> tokio::io::AsyncWrite for FixedBaud<S> {
    fn poll_write(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        buf: &[u8],
    ) -> std::task::Poll<io::Result<usize>> {
        std::pin::Pin::new(&mut self.0).poll_write(cx, buf)
    }
    fn poll_flush(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<io::Result<()>> {
        std::pin::Pin::new(&mut self.0).poll_flush(cx)
    }
    fn poll_shutdown(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<io::Result<()>> {
        std::pin::Pin::new(&mut self.0).poll_shutdown(cx)
    }
}

#[cfg(feature = "serial")]
impl BaudControl for serialport::TTYPort {
    fn set_baud(&mut self, baud: u32) -> io::Result<()> {
        serialport::SerialPort::set_baud_rate(self, baud).map_err(io::Error::from)
    }
}

#[cfg(feature = "serial")]
impl BaudControl for Box<dyn serialport::SerialPort> {
    fn set_baud(&mut self, baud: u32) -> io::Result<()> {
        self.set_baud_rate(baud).map_err(io::Error::from)
    }
}

impl<S: io::Read> io::Read for FixedBaud<S> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        self.0.read(buf)
    }
}

impl<S: io::Write> io::Write for FixedBaud<S> {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        self.0.write(buf)
    }
    fn flush(&mut self) -> io::Result<()> {
        self.0.flush()
    }
}

/// Errors of the P2OS drivers (both shells).
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum DriverError {
    /// The driver task has ended (port closed, I/O error, or [`P2os::close`]).
    Disconnected,
    /// The robot did not answer in time.
    Timeout,
    /// The session refused the request.
    Session(SessionError),
    /// The robot never confirmed ENABLE (motors switch or E-stop).
    MotorsRefused,
    /// The robot's subclass has no parameter table (set `Config::params_override`).
    UnsupportedRobot(String),
    /// No rate answered the handshake.
    HandshakeFailed,
    /// The handshake did not complete while connecting: what was seen at each rate tried.
    NoAnswer(Box<ima_hal::link::ProbeReport>),
    /// An I/O error on the port.
    Io(io::ErrorKind),
}

impl std::fmt::Display for DriverError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Disconnected => f.write_str("P2OS driver disconnected"),
            Self::Timeout => f.write_str("P2OS robot did not answer in time"),
            Self::Session(e) => write!(f, "{e}"),
            Self::MotorsRefused => {
                f.write_str("robot did not enable its motors (motor switch off or E-stop engaged?)")
            }
            Self::UnsupportedRobot(s) => write!(
                f,
                "robot subclass {s:?} has no parameter table; set a params override"
            ),
            Self::HandshakeFailed => {
                f.write_str("no answer to the P2OS handshake at the rates probed")
            }
            Self::NoAnswer(report) => write!(
                f,
                "no P2OS robot completed the handshake (robot on? right port?): {report}"
            ),
            Self::Io(k) => write!(f, "serial I/O error: {k}"),
        }
    }
}

impl std::error::Error for DriverError {}

impl ima_hal::Error for DriverError {
    fn kind(&self) -> ErrorKind {
        match self {
            Self::Disconnected | Self::Io(_) => ErrorKind::Disconnected,
            Self::Timeout | Self::HandshakeFailed | Self::NoAnswer(_) => ErrorKind::Timeout,
            Self::Session(e) => ima_hal::Error::kind(e),
            Self::MotorsRefused | Self::UnsupportedRobot(_) => ErrorKind::Protocol,
        }
    }
}

/// The sonar ring of `params` as HAL transducers (P2OS sonar: 10 cm–5 m, ~30° beams).
#[must_use]
pub fn transducers(params: &crate::params::RobotParams) -> Vec<ima_hal::sonar::SonarTransducer> {
    params
        .sonars
        .iter()
        .map(|s| ima_hal::sonar::SonarTransducer {
            pose: ima_hal::Isometry2::new(
                ima_hal::Vector2::new(s.x_mm / 1000.0, s.y_mm / 1000.0),
                s.heading_deg.to_radians(),
            ),
            min_range_m: 0.1,
            max_range_m: 5.0,
            beam_width_rad: 30f64.to_radians(),
        })
        .collect()
}

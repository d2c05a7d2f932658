//! Line-speed control and port opening.

use std::io;

/// A byte stream whose line speed can be changed (baud probing, rate switches).
pub trait BaudControl {
    /// Set the line speed.
    fn set_baud(&mut self, baud: u32) -> io::Result<()>;

    /// Drop what the port has received but nobody read yet (stale bytes at the old rate).
    /// Streams without a receive buffer of their own do nothing.
    fn clear_input(&mut self) -> io::Result<()> {
        Ok(())
    }
}

impl<T: BaudControl + ?Sized> BaudControl for &mut T {
    fn set_baud(&mut self, baud: u32) -> io::Result<()> {
        (**self).set_baud(baud)
    }
    fn clear_input(&mut self) -> io::Result<()> {
        (**self).clear_input()
    }
}

/// Wraps a stream that has no line speed (an in-memory duplex, a TCP bridge): rate changes
/// are accepted and ignored.
#[derive(Debug)]
pub struct FixedBaud<S>(pub S);

impl<S> BaudControl for FixedBaud<S> {
    fn set_baud(&mut self, _baud: u32) -> io::Result<()> {
        Ok(())
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

#[cfg(feature = "tokio")]
mod async_io {
    use std::io;
    use std::pin::Pin;
    use std::task::{Context, Poll};

    use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};

    use super::{BaudControl, FixedBaud};

    impl BaudControl for tokio_serial::SerialStream {
        fn set_baud(&mut self, baud: u32) -> io::Result<()> {
            tokio_serial::SerialPort::set_baud_rate(self, baud).map_err(io::Error::from)
        }
        fn clear_input(&mut self) -> io::Result<()> {
            tokio_serial::SerialPort::clear(self, tokio_serial::ClearBuffer::Input)
                .map_err(io::Error::from)
        }
    }

    impl<S: AsyncRead + Unpin> AsyncRead for FixedBaud<S> {
        fn poll_read(
            mut self: Pin<&mut Self>,
            cx: &mut Context<'_>,
            buf: &mut ReadBuf<'_>,
        ) -> Poll<io::Result<()>> {
            Pin::new(&mut self.0).poll_read(cx, buf)
        }
    }

    impl<S: AsyncWrite + Unpin> AsyncWrite for FixedBaud<S> {
        fn poll_write(
            mut self: Pin<&mut Self>,
            cx: &mut Context<'_>,
            buf: &[u8],
        ) -> Poll<io::Result<usize>> {
            Pin::new(&mut self.0).poll_write(cx, buf)
        }
        fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
            Pin::new(&mut self.0).poll_flush(cx)
        }
        fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
            Pin::new(&mut self.0).poll_shutdown(cx)
        }
    }
}

/// Open a serial port for the async runner: `baud` 8N1, no flow control (a probe may change
/// the rate later), with its receive buffer emptied.
///
/// Bytes the system held for the port before it was opened are stale: a device that talks
/// by itself (a compass's NMEA stream) may have filled the kernel's receive queue (a pty
/// whose other end a mock keeps open does) long before this program started, and each would
/// become a reading stamped now. Without the flush, `ima compass` opened 20 s after
/// `ima mock compass` read 210 stale headings before the first fresh one. (What a USB
/// adapter's own chip still holds arrives after the flush; a built-in port receives nothing
/// while it is closed.)
///
/// # Errors
/// A path that is not a serial port (a regular file, `/dev/null`) fails with
/// [`io::ErrorKind::InvalidInput`] and `PATH is not a serial port (…)`; a port that is not
/// there lists the serial ports that are, one the user may not open says what would let them,
/// and one another program holds says so ([`ima_hal::serial::explain_open_error`]); other
/// errors as the system reports them.
#[cfg(feature = "tokio")]
pub fn open_port(path: &str, baud: u32) -> io::Result<tokio_serial::SerialStream> {
    use tokio_serial::SerialPortBuilderExt;
    let mut port = tokio_serial::new(path, baud)
        .data_bits(tokio_serial::DataBits::Eight)
        .parity(tokio_serial::Parity::None)
        .stop_bits(tokio_serial::StopBits::One)
        .flow_control(tokio_serial::FlowControl::None)
        .open_native_async()
        .map_err(|e| ima_hal::serial::explain_open_error(path, io::Error::from(e)))?;
    port.clear_input()?;
    Ok(port)
}

//! `open_port` on a pty: what the port received before it was opened is dropped.
#![cfg(all(unix, feature = "tokio"))]

use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio_serial::SerialPort;

#[tokio::test]
async fn bytes_received_before_the_port_opened_are_dropped() {
    // The far end stays open, as a mock's does: the pty keeps what it is sent.
    let (mut device, held) = tokio_serial::SerialStream::pair().expect("a pty pair");
    let path = held.name().expect("the pty has a path");
    device.write_all(b"$HCHDG,1.0,,,,*00\r\n").await.unwrap();
    device.flush().await.unwrap();
    // Let the stale line reach the port's receive buffer before the program opens it.
    tokio::time::sleep(Duration::from_millis(50)).await;
    let mut port = ima_serial::open_port(&path, 9600).expect("the pty opens");
    device.write_all(b"fresh\n").await.unwrap();
    let mut got = Vec::new();
    let mut buf = [0u8; 64];
    while !got.ends_with(b"fresh\n") {
        let read = tokio::time::timeout(Duration::from_secs(5), port.read(&mut buf)).await;
        let n = read.expect("the fresh bytes arrive").unwrap();
        got.extend_from_slice(&buf[..n]);
    }
    assert_eq!(got, b"fresh\n", "{}", String::from_utf8_lossy(&got));
}

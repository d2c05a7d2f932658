//! The in-memory duplex runner, in tokio's paused (virtual) time.

use std::time::Duration;

use ima_hal::Instant;
use ima_mock_devices::duplex::{DuplexDevice, DuplexOptions};
use ima_mock_devices::faults::FaultPlan;
use ima_mock_devices::link::LinkState;
use ima_mock_devices::model::EchoModel;
use tokio::io::{AsyncReadExt, AsyncWriteExt, DuplexStream};

async fn read_n(s: &mut DuplexStream, n: usize) -> Vec<u8> {
    let mut got = vec![0u8; n];
    tokio::time::timeout(Duration::from_secs(30), s.read_exact(&mut got))
        .await
        .expect("timed out")
        .expect("read");
    got
}

#[tokio::test(start_paused = true)]
async fn echo_round_trip() {
    let (mut host, dev) = DuplexDevice::spawn(EchoModel::new(), DuplexOptions::default());
    host.write_all(b"hello").await.unwrap();
    assert_eq!(read_n(&mut host, 5).await, b"hello");
    let model = dev.stop().await.unwrap();
    assert_eq!(model.received(), 5);
}

#[tokio::test(start_paused = true)]
async fn heartbeats_arrive_in_virtual_time() {
    let model = EchoModel::with_heartbeat(Instant::ZERO, Duration::from_secs(1), b"*");
    let (mut host, dev) = DuplexDevice::spawn(model, DuplexOptions::default());
    // Ten seconds of beats, instantly.
    assert_eq!(read_n(&mut host, 10).await, b"**********");
    dev.stop().await.unwrap();
}

#[tokio::test(start_paused = true)]
async fn faults_apply_and_are_counted() {
    let opts = DuplexOptions {
        faults: FaultPlan::parse("r2h.drop=0.1,r2h.split=1,seed=3").unwrap(),
        ..DuplexOptions::default()
    };
    let (mut host, dev) = DuplexDevice::spawn(EchoModel::new(), opts);
    let msg = vec![0xAAu8; 5000];
    host.write_all(&msg).await.unwrap();
    tokio::time::sleep(Duration::from_millis(100)).await;
    let st = dev.status();
    let expected = 5000 - st.counters.robot_to_host.dropped as usize;
    assert!(st.counters.robot_to_host.dropped > 350, "{st:?}");
    assert_eq!(read_n(&mut host, expected).await, vec![0xAA; expected]);
    assert!(st.counters.robot_to_host.splits >= 1);
    dev.stop().await.unwrap();
}

#[tokio::test(start_paused = true)]
async fn hang_up_for_a_while_then_recover() {
    let (mut host, dev) = DuplexDevice::spawn(EchoModel::new(), DuplexOptions::default());
    dev.hang_up_for(Duration::from_secs(2));
    tokio::time::sleep(Duration::from_millis(10)).await;
    assert!(matches!(dev.status().state, LinkState::DownUntil(_)));
    host.write_all(b"lost").await.unwrap();
    tokio::time::sleep(Duration::from_millis(500)).await;
    let mut b = [0u8; 1];
    assert!(
        tokio::time::timeout(Duration::from_millis(500), host.read(&mut b))
            .await
            .is_err()
    );
    tokio::time::sleep(Duration::from_secs(2)).await;
    host.write_all(b"back").await.unwrap();
    assert_eq!(read_n(&mut host, 4).await, b"back");
    let st = dev.status();
    assert_eq!((st.counters.hangups, st.counters.reconnects), (1, 1));
    assert_eq!(st.counters.discarded_while_down, 4);
    dev.stop().await.unwrap();
}

#[tokio::test(start_paused = true)]
async fn hang_up_for_good_closes_the_pipe() {
    let opts = DuplexOptions {
        faults: FaultPlan::parse("hangup=3s").unwrap(),
        ..DuplexOptions::default()
    };
    let (mut host, dev) = DuplexDevice::spawn(EchoModel::new(), opts);
    host.write_all(b"ok").await.unwrap();
    assert_eq!(read_n(&mut host, 2).await, b"ok");
    let mut rest = Vec::new();
    let n = tokio::time::timeout(Duration::from_secs(30), host.read_to_end(&mut rest))
        .await
        .unwrap()
        .unwrap();
    assert_eq!(n, 0, "EOF after the hang-up");
    let model = dev.stop().await.unwrap();
    assert_eq!(model.link_events(), (1, 0));
}

#[tokio::test(start_paused = true)]
async fn host_dropping_its_end_ends_the_task() {
    let (host, dev) = DuplexDevice::spawn(EchoModel::new(), DuplexOptions::default());
    drop(host);
    tokio::time::sleep(Duration::from_millis(50)).await;
    assert!(dev.is_finished());
    dev.stop().await.unwrap();
}

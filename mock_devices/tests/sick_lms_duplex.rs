//! The SICK LMS driver's async shell against the mock LMS over an in-memory duplex, in tokio's
//! paused (virtual) time: scan rates set by line and mirror (spec §4), variants, and recovery
//! after an outage, all without waiting in real time.

use std::time::Duration;

use ima_hal::laser::LaserScanner;
use ima_mock_devices::duplex::{DuplexDevice, DuplexOptions};
use ima_mock_devices::sick_lms::{RangeSource, SickLmsDevice, SickLmsModelConfig};
use ima_sick_lms::decode::Variant;
use ima_sick_lms::machine::Config;
use ima_sick_lms::shell::Driver as _;
use ima_sick_lms::shell::{FixedBaud, SickLms};
use ima_sick_lms::wire::BaudRate;

/// Every beam sees 2.5 m.
struct Flat;

impl RangeSource for Flat {
    fn ranges(&mut self, _: f64, _: f64, count: u16, _: f64, out: &mut Vec<Option<f64>>) {
        out.clear();
        out.resize(usize::from(count), Some(2.5));
    }
}

async fn setup(baud: BaudRate) -> (SickLms, DuplexDevice<SickLmsDevice>) {
    let dev = SickLmsDevice::new(
        SickLmsModelConfig {
            baud,
            boot_delay: Duration::ZERO,
            ..SickLmsModelConfig::default()
        },
        Box::new(Flat),
        ima_hal::Instant::ZERO,
    );
    let (pipe, runner) = DuplexDevice::spawn(dev, DuplexOptions::default());
    // A pipe has no line rate: the driver's rate changes are no-ops, the mock paces itself.
    let cfg = Config {
        baud,
        rs422: baud == BaudRate::B500000,
        ..Config::default()
    };
    let lms = SickLms::connect(
        FixedBaud(pipe),
        cfg,
        Duration::from_secs(60),
        ima_hal::time::TokioClock::shared(),
    )
    .await
    .unwrap()
    .with_scan_timeout(Duration::from_secs(5));
    (lms, runner)
}

/// Scans delivered over `secs` virtual seconds, per second.
async fn rate(lms: &mut SickLms, secs: u64) -> f64 {
    let mut last = lms.next_scan(lms.now()).await.unwrap().at;
    let t0 = last;
    let mut n = 0u32;
    while last.saturating_duration_since(t0) < Duration::from_secs(secs) {
        last = lms.next_scan(last).await.unwrap().at;
        n += 1;
    }
    f64::from(n) / last.saturating_duration_since(t0).as_secs_f64()
}

#[tokio::test(start_paused = true)]
async fn scan_rate_follows_line_and_mirror() {
    for (baud, variant, want) in [
        (BaudRate::B38400, Variant::W180_R50, 5.2),
        (BaudRate::B38400, Variant::W180_R100, 10.3),
        (BaudRate::B500000, Variant::W180_R50, 37.5),
        (BaudRate::B500000, Variant::W180_R100, 75.0),
        (BaudRate::B500000, Variant::W100_R25, 18.75),
    ] {
        let (mut lms, runner) = setup(baud).await;
        lms.set_variant(variant).await.unwrap();
        let r = rate(&mut lms, 10).await;
        assert!(
            (r - want).abs() < want * 0.03,
            "{baud:?} {variant:?}: {r} vs {want}"
        );
        let s = lms.scan().await.unwrap();
        assert_eq!(s.value.len(), usize::from(variant.values()));
        assert!(s.value.ranges_m().iter().all(|r| (*r - 2.5).abs() < 1e-3));
        lms.close().await.unwrap();
        runner.stop().await.unwrap();
    }
}

#[tokio::test(start_paused = true)]
async fn outage_is_detected_and_recovered_in_virtual_time() {
    let (mut lms, runner) = setup(BaudRate::B38400).await;
    lms.next_scan(lms.now()).await.unwrap();
    runner.hang_up_for(Duration::from_secs(3));
    tokio::time::sleep(Duration::from_secs(2)).await;
    assert!(
        lms.stats().losses >= 1
            || !matches!(lms.link(), ima_sick_lms::shell::LinkStatus::Connected(_)),
        "{:?}",
        lms.link()
    );
    lms.wait_ready(Duration::from_secs(60)).await.unwrap();
    let after = lms.now();
    let s = lms.next_scan(after).await.unwrap();
    assert!(s.at > after);
    assert!(lms.stats().losses >= 1);
    let st = runner.stop().await.unwrap().model().stats();
    assert!(st.scans > 10);
}

#[tokio::test(start_paused = true)]
async fn stream_stops_and_starts_on_request() {
    let (mut lms, runner) = setup(BaudRate::B500000).await;
    lms.next_scan(lms.now()).await.unwrap();
    let info = lms.set_streaming(false).await.unwrap();
    assert!(!info.streaming);
    let quiet_from = lms.now() + Duration::from_millis(100);
    let mut quiet = lms.clone().with_scan_timeout(Duration::from_secs(2));
    assert!(matches!(
        quiet.next_scan(quiet_from).await,
        Err(ima_sick_lms::driver::DriverError::Timeout)
    ));
    assert!(matches!(
        lms.link(),
        ima_sick_lms::shell::LinkStatus::Connected(_)
    ));
    let info = lms.set_streaming(true).await.unwrap();
    assert!(info.streaming);
    let after = lms.now();
    assert!(lms.next_scan(after).await.unwrap().at > after);
    assert!(runner.stop().await.unwrap().model().is_streaming());
}

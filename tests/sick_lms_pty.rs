//! End to end: the real SICK LMS driver (async and blocking shells) against the mock LMS over
//! real pseudo-terminals, in real time, with the simulated world as ground truth.

mod common;

use std::time::Duration;

use ima_hal::laser::{LaserScan, LaserScanner};
use ima_mock_devices::faults::FaultPlan;
use ima_mock_devices::pty::{PtyDevice, PtyOptions};
use ima_mock_devices::sick_lms::{SickLmsDevice, SickLmsModelConfig, WorldLaser};
use ima_mock_devices::world::{RobotId, RobotSpec, SharedWorld, Wall, World};
use ima_sick_lms::decode::Variant;
use ima_sick_lms::machine::Config;
use ima_sick_lms::shell::Driver as _;
use ima_sick_lms::shell::{DriverError, SickLms, open_port};
use ima_sick_lms::wire::BaudRate;

/// Scooter at the origin facing +x; `walls` as (from, to).
fn world(walls: &[([f64; 2], [f64; 2])]) -> (SharedWorld, RobotId) {
    let mut w = World::new();
    let mut spec = RobotSpec::new("scooter", 0.0, 0.0, 0.0);
    spec.radius_m = 0.4;
    spec.track_width_m = 0.42;
    let id = w.add_robot(spec).unwrap();
    for &(from, to) in walls {
        w.add_wall(Wall { from, to }).unwrap();
    }
    (SharedWorld::new(w), id)
}

/// A 4 m × 4 m box around the robot: every beam hits a wall within 2.9 m.
fn boxed() -> (SharedWorld, RobotId) {
    world(&[
        ([-2.0, -2.0], [2.0, -2.0]),
        ([2.0, -2.0], [2.0, 2.0]),
        ([2.0, 2.0], [-2.0, 2.0]),
        ([-2.0, 2.0], [-2.0, -2.0]),
    ])
}

fn serve(
    world: &SharedWorld,
    id: RobotId,
    cfg: SickLmsModelConfig,
    noise_m: f64,
    faults: &str,
) -> PtyDevice<SickLmsDevice> {
    let laser = WorldLaser::new(world.clone(), id, 5).with_noise(noise_m);
    let dev = SickLmsDevice::new(cfg, Box::new(laser), ima_hal::Instant::ZERO);
    let dev = PtyDevice::spawn(
        dev,
        PtyOptions {
            faults: FaultPlan::parse(faults).unwrap(),
            ..PtyOptions::default()
        },
    )
    .unwrap();
    // Let the unit boot (its 200 ms boot delay) before the host starts probing.
    std::thread::sleep(Duration::from_millis(300));
    dev
}

fn fast() -> Config {
    Config {
        baud: BaudRate::B500000,
        rs422: true,
        ..Config::default()
    }
}

async fn connect(dev: &PtyDevice<SickLmsDevice>, cfg: Config) -> SickLms {
    common::connect_sick(dev.path(), cfg).await
}

async fn next(l: &mut SickLms) -> ima_hal::Stamped<LaserScan> {
    let after = l.now();
    l.next_scan(after).await.unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn initialises_from_every_starting_baud_and_switches_to_500k() {
    let mut jobs = Vec::new();
    for baud in [
        BaudRate::B9600,
        BaudRate::B19200,
        BaudRate::B38400,
        BaudRate::B500000,
    ] {
        jobs.push(tokio::spawn(async move {
            let (w, id) = boxed();
            let dev = serve(
                &w,
                id,
                SickLmsModelConfig {
                    baud,
                    ..SickLmsModelConfig::default()
                },
                0.05,
                "",
            );
            let mut l = connect(&dev, fast()).await;
            let info = l.session().unwrap();
            assert_eq!(info.baud, BaudRate::B500000, "from {baud:?}");
            assert!(info.streaming);
            for _ in 0..3 {
                let s = next(&mut l).await;
                assert_eq!(s.value.len(), 361);
            }
            assert!(l.description().max_scan_rate_hz > 37.0);
            l.close().await.unwrap();
            let m = dev.stop().unwrap();
            // Closing put the unit back at its power-up rate, idle.
            assert_eq!(m.model().baud(), BaudRate::B9600, "from {baud:?}");
            assert!(!m.model().is_streaming());
            assert_eq!(
                m.model().stats().baud_changes,
                u64::from(baud != BaudRate::B500000) + 1
            );
            // The probe's telegrams at the wrong rates reached the unit as noise only.
            if baud != BaudRate::B9600 {
                assert!(m.model().stats().garbled_rx > 0, "from {baud:?}");
            }
        }));
    }
    for j in jobs {
        j.await.unwrap();
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_session_at_500k_leaves_the_unit_at_9600_for_an_rs232_host() {
    let (w, id) = boxed();
    let dev = serve(&w, id, SickLmsModelConfig::default(), 0.0, "");
    let l = connect(&dev, fast()).await;
    assert_eq!(l.session().unwrap().baud, BaudRate::B500000);
    l.close().await.unwrap();
    // The next program has no RS-422 (500000 is not probed) and still finds the unit.
    let rs232 = Config {
        rs422: false,
        ..Config::default()
    };
    let l = connect(&dev, rs232).await;
    assert_eq!(l.session().unwrap().baud, BaudRate::B38400);
    let first = l.probe_report();
    assert_eq!(first.rates().first().map(|t| t.baud), Some(9600));
    assert!(first.total_frames() > 0);
    l.close().await.unwrap();
    let m = dev.stop().unwrap();
    assert_eq!(m.model().baud(), BaudRate::B9600);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn variant_changes_round_trip() {
    let (w, id) = boxed();
    let dev = serve(&w, id, SickLmsModelConfig::default(), 0.05, "");
    let mut l = connect(&dev, fast()).await;
    assert_eq!(next(&mut l).await.value.len(), 361);
    for (v, beams) in [
        (Variant::W180_R100, 181),
        (Variant::W100_R25, 401),
        (Variant::W180_R50, 361),
    ] {
        let info = l.set_variant(v).await.unwrap();
        assert_eq!(info.variant, Some(v));
        assert!(info.streaming);
        let s = next(&mut l).await;
        assert_eq!(s.value.len(), beams);
        assert_eq!(l.description().beams, beams as u16);
    }
    l.close().await.unwrap();
    let m = dev.stop().unwrap();
    assert_eq!(m.model().stats().variant_changes, 3);
    assert_eq!(m.model().variant(), Variant::W180_R50);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn config_write_only_when_it_differs() {
    let (w, id) = boxed();
    let dev = serve(&w, id, SickLmsModelConfig::default(), 0.05, "");
    // 1. The unit already measures in mm: nothing written.
    let l = connect(&dev, fast()).await;
    l.close().await.unwrap();
    // 2. Ask for cm: one write. 3. Again cm: skipped.
    for _ in 0..2 {
        let cfg = Config {
            units: Some(0),
            ..fast()
        };
        let mut l = connect(&dev, cfg).await;
        let s = next(&mut l).await;
        // cm units decode to metres as well.
        assert!(s.value.ranges_m().iter().all(|r| (0.3..3.0).contains(r)));
        l.close().await.unwrap();
    }
    let m = dev.stop().unwrap();
    assert_eq!(m.model().stats().eeprom_writes, 1);
    assert_eq!(m.model().config().units(), 0);
}

/// Ranges each beam must show in the noiseless box (ray-cast truth).
fn truth(w: &SharedWorld, id: RobotId) -> Vec<f64> {
    use ima_mock_devices::sick_lms::RangeSource;
    let mut l = WorldLaser::new(w.clone(), id, 0).with_noise(0.0);
    let mut out = Vec::new();
    l.ranges(
        -std::f64::consts::FRAC_PI_2,
        0.5f64.to_radians(),
        361,
        8.191,
        &mut out,
    );
    out.into_iter().map(|r| r.unwrap()).collect()
}

/// Every delivered scan must be the true one, beam for beam (mm rounding only).
fn assert_true_scan(s: &LaserScan, want: &[f64]) {
    assert_eq!(s.len(), 361);
    for (i, (r, t)) in s.ranges_m().iter().zip(want).enumerate() {
        assert!(
            (f64::from(*r) - t).abs() < 0.0011,
            "beam {i}: {r} vs truth {t}"
        );
    }
}

/// A tolerant session for a noisy line: many retries for the long replies.
fn noisy(watchdog: bool) -> Config {
    Config {
        retries: 30,
        stream_watchdog: watchdog.then_some(Duration::from_secs(1)),
        ..fast()
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stream_survives_corruption_and_delivers_no_bad_scan() {
    // 0.05 % per byte: about 30 % of the 732-byte B0 frames are damaged.
    let (w, id) = boxed();
    let want = truth(&w, id);
    let dev = serve(
        &w,
        id,
        SickLmsModelConfig::default(),
        0.0,
        "r2h.corrupt=0.0005,seed=11",
    );
    let mut l = connect(&dev, noisy(true)).await;
    let mut last = l.now();
    for _ in 0..40 {
        let s = l.next_scan(last).await.unwrap();
        last = s.at;
        assert_true_scan(&s.value, &want);
    }
    let st = l.stats();
    assert!(
        st.framer.bad_checksums + st.framer.bad_headers > 0,
        "{st:?}"
    );
    assert_eq!(st.decode_errors, 0);
    l.close().await.unwrap();
    let m = dev.stop().unwrap();
    assert!(m.model().stats().scans > st.delivered, "{st:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn one_percent_byte_corruption_counts_bad_frames_and_delivers_none() {
    // 1 % per byte leaves a 732-byte B0 intact with probability 0.99^732 ≈ 0.07 %: the stream
    // is nearly all bad frames. They are counted and never delivered; the session keeps
    // running (its stall watchdog is off, since almost no good B0 arrives).
    let (w, id) = boxed();
    let want = truth(&w, id);
    let dev = serve(
        &w,
        id,
        SickLmsModelConfig::default(),
        0.0,
        "r2h.corrupt=0.01,seed=12",
    );
    let l = connect(&dev, noisy(false)).await;
    let mut rx = l.clone();
    let start = l.stats();
    let until = tokio::time::Instant::now() + Duration::from_secs(3);
    let mut last = l.now();
    while tokio::time::Instant::now() < until {
        if let Ok(Ok(s)) =
            tokio::time::timeout(Duration::from_millis(500), rx.next_scan(last)).await
        {
            last = s.at;
            assert_true_scan(&s.value, &want);
        }
    }
    let st = l.stats();
    let bad = st.framer.bad_checksums + st.framer.bad_headers + st.framer.expired
        - (start.framer.bad_checksums + start.framer.bad_headers + start.framer.expired);
    assert!(bad >= 30, "{st:?}");
    assert_eq!(st.decode_errors, 0);
    assert!(matches!(
        l.link(),
        ima_sick_lms::shell::LinkStatus::Connected(_)
    ));
    l.close().await.unwrap();
    let m = dev.stop().unwrap();
    assert!(m.model().stats().scans >= 60);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn corrupted_request_is_naked_and_retried() {
    let (w, id) = boxed();
    let dev = serve(
        &w,
        id,
        SickLmsModelConfig::default(),
        0.05,
        "h2r.corrupt=0.03,seed=4",
    );
    let mut l = connect(
        &dev,
        Config {
            baud: BaudRate::B38400,
            ..Config::default()
        },
    )
    .await;
    assert_eq!(next(&mut l).await.value.len(), 361);
    let st = l.stats();
    assert!(st.framer.naks > 0, "{st:?}");
    assert!(st.session.retransmissions > 0, "{st:?}");
    l.close().await.unwrap();
    let m = dev.stop().unwrap();
    assert!(m.model().stats().naks > 0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn recovers_after_the_mock_hangs_up() {
    let (w, id) = boxed();
    let dev = serve(&w, id, SickLmsModelConfig::default(), 0.05, "");
    let mut l = connect(
        &dev,
        Config {
            baud: BaudRate::B38400,
            ..Config::default()
        },
    )
    .await;
    next(&mut l).await;
    dev.hang_up_for(Duration::from_millis(1500));
    tokio::time::sleep(Duration::from_millis(1600)).await;
    let info = l.wait_ready(Duration::from_secs(60)).await.unwrap();
    assert_eq!(info.baud, BaudRate::B38400);
    // Scans flow again, stamped after the outage.
    let after = l.now();
    let s = tokio::time::timeout(Duration::from_secs(60), async {
        loop {
            match l.next_scan(after).await {
                Ok(s) => return s,
                Err(_) => continue,
            }
        }
    })
    .await
    .unwrap();
    assert_eq!(s.value.len(), 361);
    assert!(l.stats().losses >= 1, "{:?}", l.stats());
    l.close().await.unwrap();
    dev.stop().unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn wall_at_two_metres_reads_two_metres() {
    // A 3 m wide wall 2 m ahead; nothing else in the world.
    let (w, id) = world(&[([2.0, -1.5], [2.0, 1.5])]);
    let dev = serve(&w, id, SickLmsModelConfig::default(), 0.05, "");
    let mut l = connect(&dev, fast()).await;
    let s = next(&mut l).await;
    let edge = (1.5f64 / 2.0).atan() - 0.01;
    let mut hits = 0;
    for (a, r, f) in s.value.beams() {
        if a.abs() < edge {
            assert!(f.is_valid(), "beam at {a} rad: {f:?}");
            let x = f64::from(r) * a.cos();
            assert!((x - 2.0).abs() <= 0.05 + 1e-3, "beam at {a} rad: x = {x}");
            hits += 1;
        } else if a.abs() > edge + 0.02 {
            assert!(!f.is_valid() && r.is_nan(), "beam at {a} rad saw {r}");
        }
    }
    // ±36.9° at 0.5°: 147 beams hit the wall.
    assert!(hits >= 140, "{hits}");
    l.close().await.unwrap();
    dev.stop().unwrap();
}

#[test]
fn blocking_shell_streams_over_a_pty() {
    use ima_hal::blocking::LaserScanner as _;
    let (w, id) = boxed();
    let dev = serve(&w, id, SickLmsModelConfig::default(), 0.05, "");
    let path = dev.path().to_str().unwrap().to_owned();
    let mut l = ima_serial::blocking::Blocking::connect(async || {
        let port = open_port(&path, 9600).unwrap();
        let clock = ima_hal::time::TokioClock::shared();
        let l = SickLms::connect(port, fast(), Duration::from_secs(60), clock).await?;
        Ok::<_, DriverError>(l.with_scan_timeout(Duration::from_secs(10)))
    })
    .unwrap();
    assert_eq!(l.get().session().unwrap().baud, BaudRate::B500000);
    let mut last = ima_hal::Instant::ZERO;
    for _ in 0..5 {
        let s = l.next_scan(last).unwrap();
        assert_eq!(s.value.len(), 361);
        assert!(s.at > last);
        last = s.at;
    }
    let info = l.run(async |l| l.set_variant(Variant::W180_R100).await);
    assert_eq!(info.unwrap().variant, Some(Variant::W180_R100));
    assert_eq!(l.next_scan(l.get().now()).unwrap().value.len(), 181);
    assert_eq!(l.get().stats().decode_errors, 0);
    // Dropping it closes the driver: the unit is back at its power-up rate.
    drop(l);
    let m = dev.stop().unwrap();
    assert_eq!(m.model().baud(), BaudRate::B9600);
}

//! End to end: the compass driver (tokio shell) against the mock compass over real
//! pseudo-terminals, both dialects, with the simulated world as ground truth. The test steps
//! the world itself (no stepper) so the truth is known exactly while readings are compared.

use std::time::Duration;

use ima_compass::machine::{Config, Dialect, Source};
use ima_compass::shell::Driver as _;
use ima_compass::shell::{Calibration, CalibrationOutcome, CompassDriver, open_port};
use ima_compass::wire::Tcm2Format;
use ima_hal::compass::Compass;
use ima_mock_devices::compass::{
    CompassDevice, CompassModelConfig, MockDialect, MockSentence, world_heading_deg,
};
use ima_mock_devices::pty::{PtyDevice, PtyOptions};
use ima_mock_devices::world::{DriveCommand, RobotId, SharedWorld, World};

fn setup(cfg: CompassModelConfig) -> (SharedWorld, RobotId, PtyDevice<CompassDevice>) {
    let world = SharedWorld::new(World::default_world());
    let id = world.with(|w| w.robot_id("scooter")).unwrap();
    let dev = PtyDevice::spawn(
        CompassDevice::new(cfg, world.clone(), id),
        PtyOptions::default(),
    )
    .unwrap();
    (world, id, dev)
}

async fn connect(dev: &PtyDevice<CompassDevice>, dialect: Dialect) -> CompassDriver {
    let port = open_port(dev.path().to_str().unwrap(), 4800).unwrap();
    CompassDriver::connect(
        port,
        Config::for_dialect(dialect),
        Duration::from_secs(10),
        ima_hal::time::TokioClock::shared(),
    )
    .await
    .unwrap()
}

/// Signed smallest difference a − b in degrees.
fn diff_deg(a: f64, b: f64) -> f64 {
    (a - b + 540.0).rem_euclid(360.0) - 180.0
}

/// Turn the robot in steps; after each, average ten fresh readings and compare with the
/// world's heading. Returns the largest error seen, degrees.
async fn turn_and_compare(
    drv: &mut CompassDriver,
    world: &SharedWorld,
    id: RobotId,
    magnetic_corrected: bool,
) -> f64 {
    world.with(|w| {
        w.command(
            id,
            DriveCommand::Twist {
                v_m_s: 0.0,
                omega_rad_s: 1.0,
            },
        )
    });
    let mut worst: f64 = 0.0;
    let mut seen_wrap = false;
    let mut last_truth = world_heading_deg(world, id).unwrap();
    for _ in 0..8 {
        world.with(|w| w.step(Duration::from_millis(500)));
        let truth = world_heading_deg(world, id).unwrap();
        seen_wrap |= truth > last_truth; // heading decreases while turning left, except at the wrap
        last_truth = truth;
        // Let lines sampled before the step drain out of the pty.
        tokio::time::sleep(Duration::from_millis(300)).await;
        let mut after = drv.now();
        let (mut s, mut c) = (0.0f64, 0.0f64);
        for _ in 0..10 {
            let h = drv.next_heading(after).await.unwrap();
            after = h.at;
            let rad = if magnetic_corrected {
                h.value.magnetic_rad().unwrap()
            } else {
                h.value.heading_rad
            };
            s += rad.sin();
            c += rad.cos();
        }
        let mean = s.atan2(c).to_degrees().rem_euclid(360.0);
        worst = worst.max(diff_deg(mean, truth).abs());
        eprintln!("truth {truth:6.2}°  mean of 10 readings {mean:6.2}°");
    }
    assert!(seen_wrap, "the turn crossed north");
    worst
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn kvh_nmea_heading_follows_the_world_while_turning() {
    let (world, id, dev) = setup(CompassModelConfig {
        dialect: MockDialect::Kvh,
        sentence: MockSentence::Hdg,
        deviation_deg: 3.0,
        seed: 11,
        ..CompassModelConfig::default()
    });
    let mut drv = connect(
        &dev,
        Dialect::KvhC100 {
            rate_per_minute: 600,
        },
    )
    .await;
    let first = drv.heading().await.unwrap();
    assert_eq!(
        first
            .value
            .deviation_rad
            .map(f64::to_degrees)
            .map(|d| (d * 10.0).round()),
        Some(30.0)
    );
    let worst = turn_and_compare(&mut drv, &world, id, true).await;
    assert!(worst < 1.0, "worst averaged error {worst:.2}°");
    let latest = drv.latest().unwrap();
    assert!(matches!(latest.value.source, Source::Nmea(_)));
    // The C100's calibration commands are unknown: refused, nothing sent.
    assert_eq!(
        drv.calibrate(Calibration::StartUser).await,
        Err(ima_compass::machine::RequestError::Unsupported.into())
    );
    let st = dev.stop().unwrap().stats();
    assert_eq!(st.commands, 2, "=t,0 and =r,600");
    assert_eq!(st.bad_commands, 0);
    assert_eq!(drv.stats().parse_errors, 0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tcm2_heading_follows_the_world_and_calibrates() {
    let (world, id, dev) = setup(CompassModelConfig {
        dialect: MockDialect::Tcm2,
        seed: 12,
        ..CompassModelConfig::default()
    });
    let mut drv = connect(
        &dev,
        Dialect::Tcm2 {
            sample_rate_hz: 8,
            output: Tcm2Format::Standard,
        },
    )
    .await;
    let worst = turn_and_compare(&mut drv, &world, id, false).await;
    assert!(worst < 1.0, "worst averaged error {worst:.2}°");
    let r = drv.latest().unwrap().value;
    assert_eq!(r.source, Source::Tcm2);
    assert!(r.pitch_rad.is_some() && r.temperature_c.is_some());
    assert_eq!(r.error_code, Some(0));
    assert_eq!(
        drv.calibrate(Calibration::StartUser).await,
        Ok(CalibrationOutcome::Started)
    );
    match drv.calibrate(Calibration::StopUser).await {
        Ok(CalibrationOutcome::Finished(Some(score))) => {
            assert_eq!((score.h, score.v), (8, 8));
        }
        other => panic!("{other:?}"),
    }
    // Readings after the job carry the score (the latest one may predate it).
    let now = drv.now();
    let cal = drv
        .next_heading(now)
        .await
        .unwrap()
        .value
        .calibration
        .unwrap();
    assert_eq!(cal.horizontal_score, Some(8));
    assert_eq!(
        drv.calibrate(Calibration::Auto(true)).await,
        Ok(CalibrationOutcome::Auto(true))
    );
    // Data flows again after every job.
    let now = drv.now();
    drv.next_heading(now).await.unwrap();
    let st = dev.stop().unwrap().stats();
    assert_eq!(st.calibrations, 1);
    assert_eq!(st.bad_commands, 0);
}

#[test]
fn blocking_shell_reads_the_mock() {
    use ima_hal::blocking::Compass as _;
    let (world, id, dev) = setup(CompassModelConfig {
        noise_deg: 0.0,
        ..CompassModelConfig::default()
    });
    let path = dev.path().to_str().unwrap().to_owned();
    let mut c = ima_serial::blocking::Blocking::connect(async || {
        let port = ima_compass::shell::open_port(&path, 4800).unwrap();
        let cfg = Config::for_dialect(Dialect::KvhC100 {
            rate_per_minute: 600,
        });
        let clock = ima_hal::time::TokioClock::shared();
        CompassDriver::connect(port, cfg, Duration::from_secs(10), clock).await
    })
    .unwrap();
    let h = c.heading().unwrap();
    let truth = world_heading_deg(&world, id).unwrap();
    let got = h.value.magnetic_rad().unwrap().to_degrees();
    assert!(diff_deg(got, truth).abs() < 0.11, "{got} vs {truth}");
    let next = c.next_heading(h.at).unwrap();
    assert!(next.at > h.at);
}

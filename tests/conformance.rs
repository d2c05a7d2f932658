//! The conformance suite: what every driver of a base (`DifferentialBase + Odometer`), a laser
//! (`LaserScanner`) and a compass (`Compass`) must do, run once per driver against its mock
//! over a real pseudo-terminal in real time, with the simulated world as ground truth.
//!
//! * **Bases** (P2OS, rFLEX): drive 1 m and turn 90° on odometry under 1 % byte corruption in
//!   both directions, and agree with the world; a host that goes silent (its process dies: no
//!   stop, no close) is stopped by the *device's* watchdog within the device's window; a
//!   replug (the mock hangs up for 2 s, power-cycled or not) is reported as a lost link and
//!   recovered, and the base drives again.
//! * **Laser** (SICK LMS): under 1 % corruption every scan delivered is the true one beam for
//!   beam; after a replug the driver re-probes by itself and scans flow again.
//! * **Compasses** (KVH C100 NMEA, PNI TCM2): under 1 % corruption every heading delivered is
//!   the world's; after a replug the driver reports the silence and recovers.
//!
//! Each driver enters through one rig: the only place that opens its port and calls its
//! `connect` ([`Rig::connect`]), maps its link status to [`Link`], and builds its mock.
//! The generic checks never name a driver.

mod common;

use std::path::Path;
use std::time::Duration;

use common::conformance::{Link, SharedWorld, eventually, serve, wait_device_up, world_with};
use ima_hal::base::{DifferentialBase, Odometer, VelocityCommand};
use ima_hal::compass::Compass;
use ima_hal::laser::LaserScanner;
use ima_mock_devices::model::DeviceModel;
use ima_mock_devices::world::RobotId;
use ima_serial::LinkStatus;
use ima_serial::handle::Driver as DriverCalls;

/// A driver and its mock, joined over a pty.
trait Rig {
    /// The connected driver.
    type Driver: DriverCalls + Send + Sync + 'static;
    /// The mock device.
    type Device: DeviceModel + 'static;
    /// The mock on the world's robot `id`; `reset_on_reconnect` power-cycles it on a replug.
    fn device(world: &SharedWorld, id: RobotId, reset_on_reconnect: bool) -> Self::Device;
    /// Open the pty at `path` and connect the driver: the one call of the driver's `connect`.
    async fn connect(path: &Path) -> Self::Driver;
}

/// A driver's link status, as the suite sees it: one reading for every driver.
fn link<D: DriverCalls>(d: &D) -> Link {
    match d.link() {
        LinkStatus::Connected(_) => Link::Up,
        LinkStatus::Lost | LinkStatus::Connecting => Link::Down,
        LinkStatus::Failed(e) => Link::Other(format!("failed: {e}")),
        LinkStatus::Closed => Link::Other("closed".into()),
    }
}

/// Close the driver politely: it must say it closed.
async fn close<D: DriverCalls + Sync>(d: D) {
    d.close().await.unwrap();
}

/// What a base rig adds.
trait BaseRig: Rig<Driver: DifferentialBase + Odometer> {
    /// The world the base lives in (its robot at the origin facing +x).
    fn world() -> (SharedWorld, RobotId);
    /// When the body must have stopped after the host went silent (the device's watchdog
    /// window, with the ramp down), as (earliest, latest).
    const STOP_WINDOW: (Duration, Duration);
    /// How soon after the device is back the driver must have reconnected.
    const RECONNECT_WITHIN: Duration;
    /// Watchdog stops the device model counted.
    fn watchdog_trips(dev: &Self::Device) -> u64;
    /// Reconnections the driver counted.
    fn reconnects(d: &Self::Driver) -> u64;
}

fn truth(world: &SharedWorld, id: RobotId) -> (f64, f64, f64) {
    world.with(|w| {
        let p = w.robot(id).unwrap().pose();
        (p.x_m, p.y_m, p.theta_rad)
    })
}

/// Drive straight until odometry says 1 m, then turn 90° counter-clockwise on odometry, on a
/// line that corrupts 1 % of the bytes each way; odometry must agree with the world.
async fn base_drives_and_turns_under_corruption<R: BaseRig>() {
    let (world, id) = R::world();
    let dev = serve(
        &world,
        R::device(&world, id, false),
        "corrupt=0.01,seed=20261124",
    );
    let mut base = R::connect(dev.path()).await;
    base.enable_motors(true).await.unwrap();
    let o0 = base.odometry().await.unwrap().value;
    let t0 = truth(&world, id);
    loop {
        let o = base.odometry().await.unwrap().value;
        let d = (o.x_m() - o0.x_m()).hypot(o.y_m() - o0.y_m());
        if d >= 1.0 {
            break;
        }
        let v = (1.0 - d).clamp(0.03, 0.3);
        base.set_velocity(VelocityCommand::new(v, 0.0))
            .await
            .unwrap();
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    base.stop().await.unwrap();
    tokio::time::sleep(Duration::from_millis(800)).await;
    let o1 = base.odometry().await.unwrap().value;
    let t1 = truth(&world, id);
    let odo_d = (o1.x_m() - o0.x_m()).hypot(o1.y_m() - o0.y_m());
    let true_d = (t1.0 - t0.0).hypot(t1.1 - t0.1);
    assert!(true_d > 0.9, "moved {true_d} m");
    assert!(
        ((odo_d - true_d) / true_d).abs() < 0.02,
        "odometry {odo_d:.4} m vs ground truth {true_d:.4} m"
    );
    let h0 = o1.theta_rad();
    loop {
        let o = base.odometry().await.unwrap().value;
        let turned = ima_hal::normalize_angle(o.theta_rad() - h0);
        if turned >= std::f64::consts::FRAC_PI_2 {
            break;
        }
        let w = ((std::f64::consts::FRAC_PI_2 - turned) * 2.0).clamp(0.05, 0.6);
        base.set_velocity(VelocityCommand::new(0.0, w))
            .await
            .unwrap();
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    base.stop().await.unwrap();
    tokio::time::sleep(Duration::from_millis(800)).await;
    let o2 = base.odometry().await.unwrap().value;
    let t2 = truth(&world, id);
    let odo_turn = ima_hal::normalize_angle(o2.theta_rad() - h0).to_degrees();
    let true_turn = ima_hal::normalize_angle(t2.2 - t1.2).to_degrees();
    assert!(
        (odo_turn - true_turn).abs() < 3.0,
        "odometry turn {odo_turn:.2}° vs ground truth {true_turn:.2}°"
    );
    assert!((true_turn - 90.0).abs() < 10.0, "turned {true_turn}°");
    assert_eq!(link(&base), Link::Up);
    close(base).await;
    dev.stop().unwrap();
}

/// The host process dies mid-drive (its tasks vanish: no stop, no close); the device's own
/// watchdog stops the body within its window.
fn base_stops_when_the_host_goes_silent<R: BaseRig>() {
    let (world, id) = R::world();
    let dev = serve(&world, R::device(&world, id, false), "");
    let rt = tokio::runtime::Runtime::new().unwrap();
    let path = dev.path().to_owned();
    // Keep the handle alive past the runtime: dropping the last handle would stop the base
    // politely, which is not what a dying host does.
    let handle = rt.block_on(async {
        let mut base = R::connect(&path).await;
        base.enable_motors(true).await.unwrap();
        for _ in 0..15 {
            base.set_velocity(VelocityCommand::new(0.1, 0.0))
                .await
                .unwrap();
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        base
    });
    let speed = || world.with(|w| w.robot(id).unwrap().velocity().0);
    assert!(speed() > 0.09, "moving before the host dies: {}", speed());
    drop(rt);
    let silent_at = std::time::Instant::now();
    drop(handle);
    while speed().abs() > 1e-3 {
        assert!(
            silent_at.elapsed() < Duration::from_secs(4),
            "never stopped"
        );
        std::thread::sleep(Duration::from_millis(5));
    }
    let stopped_after = silent_at.elapsed();
    let (early, late) = R::STOP_WINDOW;
    assert!(
        stopped_after <= late,
        "stopped {stopped_after:?} after the host went silent"
    );
    assert!(
        stopped_after >= early,
        "watchdog fired early: {stopped_after:?}"
    );
    assert_eq!(R::watchdog_trips(&dev.stop().unwrap()), 1);
}

/// The mock hangs up for 2 s (the cable pulled, or the device power-cycled); the driver
/// reports the lost link, reconnects by itself within the rig's bound once the device is
/// back, odometry flows and the base drives again without the host enabling the motors
/// anew (the driver restores them after a power cycle).
async fn base_recovers_from_a_replug<R: BaseRig>() {
    let (world, id) = R::world();
    for reset in [false, true] {
        let dev = serve(&world, R::device(&world, id, reset), "");
        let mut base = R::connect(dev.path()).await;
        base.enable_motors(true).await.unwrap();
        dev.hang_up_for(Duration::from_secs(2));
        eventually("loss reported", Duration::from_secs(3), || {
            link(&base) == Link::Down
        })
        .await;
        wait_device_up(&dev).await;
        eventually("reconnected", R::RECONNECT_WITHIN, || {
            link(&base) == Link::Up
        })
        .await;
        let after = base.odometry().await.unwrap().at;
        base.next_odometry(after).await.unwrap();
        let x0 = truth(&world, id).0;
        for _ in 0..6 {
            base.set_velocity(VelocityCommand::new(0.3, 0.0))
                .await
                .unwrap();
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        assert!(
            truth(&world, id).0 - x0 > 0.03,
            "drives again (reset = {reset})"
        );
        assert!(R::reconnects(&base) >= 1, "reset = {reset}");
        close(base).await;
        dev.stop().unwrap();
    }
}

/// What a laser rig adds.
trait LaserRig: Rig<Driver: LaserScanner> {
    /// A world where every beam hits something.
    fn world() -> (SharedWorld, RobotId);
    /// The noiseless ranges the laser must report in that world, beam by beam.
    fn truth(world: &SharedWorld, id: RobotId) -> Vec<f64>;
    /// The device with 1 % of its bytes corrupted on the way to the host.
    const CORRUPTION: &'static str;
    /// [`Rig::connect`] for that line.
    async fn connect_noisy(path: &Path) -> Self::Driver;
}

/// Every scan delivered on a line that corrupts 1 % of the device's bytes is the true one,
/// and the driver keeps going (up, or re-initialising by itself; never failed).
async fn laser_delivers_only_true_scans_under_corruption<R: LaserRig>() {
    let (world, id) = R::world();
    let want = R::truth(&world, id);
    let dev = serve(&world, R::device(&world, id, false), R::CORRUPTION);
    let mut laser = R::connect_noisy(dev.path()).await;
    let until = tokio::time::Instant::now() + Duration::from_secs(3);
    let mut last = ima_hal::Instant::ZERO;
    while tokio::time::Instant::now() < until {
        if let Ok(Ok(s)) =
            tokio::time::timeout(Duration::from_millis(500), laser.next_scan(last)).await
        {
            last = s.at;
            assert_eq!(s.value.len(), want.len());
            for (i, (r, t)) in s.value.ranges_m().iter().zip(&want).enumerate() {
                assert!(
                    (f64::from(*r) - t).abs() < 0.0011,
                    "beam {i}: {r} vs truth {t}"
                );
            }
        }
    }
    let seen = link(&laser);
    assert!(matches!(seen, Link::Up | Link::Down), "{seen:?}");
    close(laser).await;
    dev.stop().unwrap();
}

/// The mock hangs up for 1.5 s; the driver notices, re-probes by itself and scans stamped
/// after the outage flow again.
async fn laser_recovers_from_a_replug<R: LaserRig>() {
    let (world, id) = R::world();
    let dev = serve(&world, R::device(&world, id, false), "");
    let mut laser = R::connect(dev.path()).await;
    laser.scan().await.unwrap();
    dev.hang_up_for(Duration::from_millis(1500));
    eventually("loss reported", Duration::from_secs(5), || {
        link(&laser) == Link::Down
    })
    .await;
    wait_device_up(&dev).await;
    eventually("ready again", Duration::from_secs(60), || {
        link(&laser) == Link::Up
    })
    .await;
    let after = laser.scan().await.unwrap().at;
    let s = laser.next_scan(after).await.unwrap();
    assert_eq!(s.value.len(), R::truth(&world, id).len());
    close(laser).await;
    dev.stop().unwrap();
}

/// What a compass rig adds.
trait CompassRig: Rig<Driver: Compass> {}

/// World heading of robot `id`, degrees clockwise from north.
fn compass_truth_deg(world: &SharedWorld, id: RobotId) -> f64 {
    ima_mock_devices::compass::world_heading_deg(world, id).unwrap()
}

fn diff_deg(a: f64, b: f64) -> f64 {
    (a - b + 540.0).rem_euclid(360.0) - 180.0
}

/// Every heading delivered on a line that corrupts 1 % of the device's bytes is the world's
/// (within the mock's noise), and at least a few get through.
async fn compass_delivers_only_true_headings_under_corruption<R: CompassRig>() {
    let (world, id) = world_with(40.0);
    let want = compass_truth_deg(&world, id);
    let dev = serve(
        &world,
        R::device(&world, id, false),
        "r2h.corrupt=0.01,seed=5",
    );
    let mut compass = R::connect(dev.path()).await;
    let mut after = compass.heading().await.unwrap().at;
    for _ in 0..20 {
        let h = compass.next_heading(after).await.unwrap();
        after = h.at;
        let got = h.value.heading_rad.to_degrees();
        assert!(
            diff_deg(got, want).abs() < 1.0,
            "{got:.2}° vs truth {want:.2}°"
        );
    }
    assert_eq!(link(&compass), Link::Up);
    close(compass).await;
    dev.stop().unwrap();
}

/// The mock hangs up for 2 s; the driver reports the silence and headings flow again after.
async fn compass_recovers_from_a_replug<R: CompassRig>() {
    let (world, id) = world_with(0.0);
    let dev = serve(&world, R::device(&world, id, false), "");
    let mut compass = R::connect(dev.path()).await;
    compass.heading().await.unwrap();
    dev.hang_up_for(Duration::from_secs(2));
    eventually("silence reported", Duration::from_secs(5), || {
        link(&compass) == Link::Down
    })
    .await;
    wait_device_up(&dev).await;
    eventually("running again", Duration::from_secs(5), || {
        link(&compass) == Link::Up
    })
    .await;
    let after = compass.heading().await.unwrap().at;
    compass.next_heading(after).await.unwrap();
    close(compass).await;
    dev.stop().unwrap();
}

// ---- one rig per driver --------------------------------------------------------------------

/// How long a driver may take to find its device.
const CONNECT_TIMEOUT: Duration = Duration::from_secs(10);

mod p2os {
    use super::*;
    use ima_mock_devices::body::WorldBody;
    use ima_mock_devices::p2os::{P2osDevice, P2osModelConfig};
    use ima_p2os::shell::{P2os, open_port};

    pub struct P2osRig;

    impl Rig for P2osRig {
        type Driver = P2os;
        type Device = P2osDevice;
        fn device(world: &SharedWorld, id: RobotId, reset: bool) -> P2osDevice {
            let mut d = P2osDevice::new(
                P2osModelConfig::default(),
                WorldBody::new(world.clone(), id, 7),
            );
            d.reset_on_reconnect = reset;
            d
        }
        async fn connect(path: &Path) -> P2os {
            let port = open_port(path.to_str().unwrap(), 9600).unwrap();
            P2os::connect(
                port,
                ima_p2os::Config::default(),
                CONNECT_TIMEOUT,
                ima_hal::time::TokioClock::shared(),
            )
            .await
            .unwrap()
        }
    }

    impl BaseRig for P2osRig {
        fn world() -> (SharedWorld, RobotId) {
            common::conformance::robot_world(0.588, 0.33, 1.2)
        }
        // The 2 s watchdog after the last command (≤ 100 ms before the host died).
        const STOP_WINDOW: (Duration, Duration) =
            (Duration::from_millis(1800), Duration::from_millis(2200));
        const RECONNECT_WITHIN: Duration = Duration::from_secs(2);
        fn watchdog_trips(dev: &P2osDevice) -> u64 {
            dev.robot().stats().watchdog_trips
        }
        fn reconnects(d: &P2os) -> u64 {
            d.stats().reconnects
        }
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn drives_and_turns_under_corruption() {
        base_drives_and_turns_under_corruption::<P2osRig>().await;
    }

    #[test]
    fn stops_when_the_host_goes_silent() {
        base_stops_when_the_host_goes_silent::<P2osRig>();
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn recovers_from_a_replug() {
        base_recovers_from_a_replug::<P2osRig>().await;
    }
}

mod rflex {
    use super::*;
    use ima_mock_devices::body::WorldBody;
    use ima_mock_devices::rflex::{RflexDevice, RflexModelConfig};
    use ima_rflex::shell::{Rflex, open_port};

    pub struct RflexRig;

    impl Rig for RflexRig {
        type Driver = Rflex;
        type Device = RflexDevice;
        fn device(world: &SharedWorld, id: RobotId, reset: bool) -> RflexDevice {
            let mut d = RflexDevice::new(
                RflexModelConfig::default(),
                WorldBody::new(world.clone(), id, 7),
            );
            d.reset_on_reconnect = reset;
            d
        }
        async fn connect(path: &Path) -> Rflex {
            let port = open_port(path.to_str().unwrap(), 115_200).unwrap();
            Rflex::connect(
                port,
                ima_rflex::machine::Config::default(),
                CONNECT_TIMEOUT,
                ima_hal::time::TokioClock::shared(),
            )
            .await
            .unwrap()
        }
    }

    impl BaseRig for RflexRig {
        fn world() -> (SharedWorld, RobotId) {
            common::conformance::robot_world(0.42, 0.4, 1.0)
        }
        // The 1.0 s fail-safe after the last SET_DIR (≤ 100 ms before the host died), then a
        // ramp down from 0.1 m/s (≈ 0.15 s); generous on top for a loaded machine.
        const STOP_WINDOW: (Duration, Duration) =
            (Duration::from_millis(850), Duration::from_millis(2000));
        const RECONNECT_WITHIN: Duration = Duration::from_secs(5);
        fn watchdog_trips(dev: &RflexDevice) -> u64 {
            dev.robot().stats().failsafe_trips
        }
        fn reconnects(d: &Rflex) -> u64 {
            u64::from(d.stats().reconnects)
        }
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn drives_and_turns_under_corruption() {
        base_drives_and_turns_under_corruption::<RflexRig>().await;
    }

    #[test]
    fn stops_when_the_host_goes_silent() {
        base_stops_when_the_host_goes_silent::<RflexRig>();
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn recovers_from_a_replug() {
        base_recovers_from_a_replug::<RflexRig>().await;
    }
}

mod sick_lms {
    use super::*;
    use ima_mock_devices::sick_lms::{RangeSource, SickLmsDevice, SickLmsModelConfig, WorldLaser};
    use ima_sick_lms::machine::Config;
    use ima_sick_lms::shell::SickLms;
    use ima_sick_lms::wire::BaudRate;

    pub struct SickLmsRig;

    impl Rig for SickLmsRig {
        type Driver = SickLms;
        type Device = SickLmsDevice;
        fn device(world: &SharedWorld, id: RobotId, reset: bool) -> SickLmsDevice {
            let laser = WorldLaser::new(world.clone(), id, 5).with_noise(0.0);
            let mut d = SickLmsDevice::new(
                SickLmsModelConfig::default(),
                Box::new(laser),
                ima_hal::Instant::ZERO,
            );
            d.reset_on_reconnect = reset;
            d
        }
        async fn connect(path: &Path) -> SickLms {
            connect_with_retries(path, Config::default().retries).await
        }
    }

    /// Connect at 9600 baud and go on at 500000 (RS-422), with `retries` per request; a
    /// stream that stalls for 1 s (a replug; or 1 % per byte, where almost every 732-byte B0
    /// is damaged) makes it re-probe.
    async fn connect_with_retries(path: &Path, retries: u8) -> SickLms {
        // Let the unit boot (its 200 ms boot delay) before probing.
        tokio::time::sleep(Duration::from_millis(300)).await;
        let cfg = Config {
            baud: BaudRate::B500000,
            rs422: true,
            retries,
            stream_watchdog: Some(Duration::from_secs(1)),
            ..Config::default()
        };
        common::connect_sick(path, cfg).await
    }

    impl LaserRig for SickLmsRig {
        /// Many retries for the replies on a line that corrupts 1 % of the bytes (3 fail
        /// to configure it: each lost reply costs its 1 s timeout). Not used for the clean
        /// line: at a rate the unit no longer speaks, every retry waits out that timeout,
        /// so the replug test took 54 s with 30 against 9 s with the driver's default 3.
        async fn connect_noisy(path: &Path) -> SickLms {
            connect_with_retries(path, 30).await
        }
        fn world() -> (SharedWorld, RobotId) {
            common::conformance::boxed_world()
        }
        fn truth(world: &SharedWorld, id: RobotId) -> Vec<f64> {
            let mut l = WorldLaser::new(world.clone(), id, 0).with_noise(0.0);
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
        const CORRUPTION: &'static str = "r2h.corrupt=0.01,seed=12";
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn delivers_only_true_scans_under_corruption() {
        laser_delivers_only_true_scans_under_corruption::<SickLmsRig>().await;
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn recovers_from_a_replug() {
        laser_recovers_from_a_replug::<SickLmsRig>().await;
    }
}

mod compass {
    use super::*;
    use ima_compass::machine::{Config, Dialect};
    use ima_compass::shell::{CompassDriver, open_port};
    use ima_compass::wire::Tcm2Format;
    use ima_mock_devices::compass::{CompassDevice, CompassModelConfig, MockDialect, MockSentence};

    /// A compass rig of one dialect: the mock's and the driver's.
    pub trait DialectRig {
        /// The mock's dialect and sentence.
        fn mock() -> CompassModelConfig;
        /// The driver's dialect.
        fn dialect() -> Dialect;
    }

    impl<D: DialectRig> Rig for D {
        type Driver = CompassDriver;
        type Device = CompassDevice;
        fn device(world: &SharedWorld, id: RobotId, _reset: bool) -> CompassDevice {
            CompassDevice::new(
                CompassModelConfig {
                    noise_deg: 0.0,
                    deviation_deg: 0.0,
                    ..D::mock()
                },
                world.clone(),
                id,
            )
        }
        async fn connect(path: &Path) -> CompassDriver {
            let port = open_port(path.to_str().unwrap(), 4800).unwrap();
            CompassDriver::connect(
                port,
                Config::for_dialect(D::dialect()),
                CONNECT_TIMEOUT,
                ima_hal::time::TokioClock::shared(),
            )
            .await
            .unwrap()
        }
    }

    impl<D: DialectRig> CompassRig for D {}

    /// KVH C100, NMEA `HDG` at 10 Hz.
    pub struct Kvh;

    impl DialectRig for Kvh {
        fn mock() -> CompassModelConfig {
            CompassModelConfig {
                dialect: MockDialect::Kvh,
                sentence: MockSentence::Hdg,
                seed: 11,
                ..CompassModelConfig::default()
            }
        }
        fn dialect() -> Dialect {
            Dialect::KvhC100 {
                rate_per_minute: 600,
            }
        }
    }

    /// PNI TCM2, standard output at 8 Hz.
    pub struct Tcm2;

    impl DialectRig for Tcm2 {
        fn mock() -> CompassModelConfig {
            CompassModelConfig {
                dialect: MockDialect::Tcm2,
                seed: 12,
                ..CompassModelConfig::default()
            }
        }
        fn dialect() -> Dialect {
            Dialect::Tcm2 {
                sample_rate_hz: 8,
                output: Tcm2Format::Standard,
            }
        }
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn kvh_delivers_only_true_headings_under_corruption() {
        compass_delivers_only_true_headings_under_corruption::<Kvh>().await;
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn kvh_recovers_from_a_replug() {
        compass_recovers_from_a_replug::<Kvh>().await;
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn tcm2_delivers_only_true_headings_under_corruption() {
        compass_delivers_only_true_headings_under_corruption::<Tcm2>().await;
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn tcm2_recovers_from_a_replug() {
        compass_recovers_from_a_replug::<Tcm2>().await;
    }
}

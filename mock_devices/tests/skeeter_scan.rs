//! Skeeter's Scan node (`ima_agents::mission::scan`) against the mock camera head and the
//! mock video switcher driven by the real `ima-video-mux` shell, in tokio's paused time: a
//! full sweep of the default world finds every object and Scooter's marker at the right
//! bearing and range, in under five seconds.

use std::time::Duration;

use ima_agents::mission::scan::{ScanConfig, Scanner, run_scan};
use ima_agents::mission::vision::ColourDb;
use ima_hal::Instant;
use ima_mock_devices::camera::{CameraConfig, MockCameraHead};
use ima_mock_devices::duplex::{DuplexDevice, DuplexOptions};
use ima_mock_devices::video_mux::{MuxDevice, MuxModelConfig, VideoBus};
use ima_mock_devices::world::{SharedWorld, World};
use ima_video_mux::shell::VideoMux;

#[tokio::test(start_paused = true)]
async fn a_sweep_of_the_default_world_finds_everything() {
    let world = SharedWorld::new(World::default_world());
    let id = world.with(|w| w.robot_id("skeeter")).unwrap();
    let bus = VideoBus::default();
    let (stream, _dev) = DuplexDevice::spawn(
        MuxDevice::new(MuxModelConfig::default(), bus.clone()),
        DuplexOptions::default(),
    );
    let mut mux = VideoMux::spawn(
        stream,
        ima_video_mux::machine::Config::default(),
        ima_hal::time::TokioClock::shared(),
    );
    let mut head = MockCameraHead::new(CameraConfig::default(), world, id, bus);
    let mut scanner =
        Scanner::with_default_ses(ScanConfig::default(), ColourDb::default()).unwrap();
    let epoch = tokio::time::Instant::now();
    let now = move || Instant::from_micros(epoch.elapsed().as_micros() as u64);
    for sweep in 0..2 {
        let report = run_scan(&mut scanner, &mut mux, &mut head, tokio::time::sleep, now)
            .await
            .unwrap();
        assert_eq!(report.cameras_ok, 7, "sweep {sweep}");
        let took = report.finished.saturating_duration_since(report.started);
        assert!(took < Duration::from_secs(5), "{took:?}");
        let want = [
            ("red", 0.0, 3.0),
            ("green", 60.0, 3.0),
            ("blue", 120.0, 3.0),
            ("yellow", 180.0, 3.0),
            ("orange", -120.0, 3.0),
            ("purple", -60.0, 3.0),
            ("scooter", -150.0, 4.0),
        ];
        assert_eq!(
            report.detections.len(),
            want.len(),
            "{:?}",
            report.detections
        );
        for (tag, deg, range) in want {
            let d = report.get(tag).unwrap_or_else(|| panic!("{tag} not seen"));
            let err = ima_hal::normalize_angle(d.observation.bearing_rad - f64::to_radians(deg));
            assert!(
                err.abs().to_degrees() < 0.2,
                "{tag}: {} °",
                err.to_degrees()
            );
            let r = d.observation.range_m.expect("whole blob has a range");
            assert!((r - range).abs() < 0.05 * range, "{tag}: {r} m");
        }
        assert_eq!(report.shared.records.len(), want.len());
        assert_eq!(report.shared.source_robot, "skeeter");
    }
    assert_eq!(scanner.sweeps(), 2);
}

//! The compass and switcher shells against their mock devices over in-memory duplexes, in
//! tokio's paused (virtual) time: exact timing rules, silence and recovery.

use std::time::Duration;

use ima_compass::machine::{Config, Dialect};
use ima_compass::shell::Driver as _;
use ima_compass::shell::{CompassDriver, LinkStatus};
use ima_compass::wire::Tcm2Format;
use ima_hal::camera::{CameraMux, FrameSource};
use ima_hal::compass::Compass;
use ima_mock_devices::camera::{CameraConfig, MockCameraHead, find_color};
use ima_mock_devices::compass::{
    CompassDevice, CompassModelConfig, MockDialect, world_heading_deg,
};
use ima_mock_devices::duplex::{DuplexDevice, DuplexOptions};
use ima_mock_devices::video_mux::{MuxDevice, MuxModelConfig, VideoBus};
use ima_mock_devices::world::{SharedWorld, World};
use ima_video_mux::shell::VideoMux;

#[tokio::test(start_paused = true)]
async fn tcm2_configures_goes_silent_and_recovers() {
    let world = SharedWorld::new(World::default_world());
    let id = world.with(|w| w.robot_id("scooter")).unwrap();
    let model = CompassDevice::new(
        CompassModelConfig {
            dialect: MockDialect::Tcm2,
            noise_deg: 0.0,
            ..CompassModelConfig::default()
        },
        world.clone(),
        id,
    );
    let (stream, dev) = DuplexDevice::spawn(model, DuplexOptions::default());
    let mut drv = CompassDriver::connect(
        stream,
        Config::for_dialect(Dialect::Tcm2 {
            sample_rate_hz: 8,
            output: Tcm2Format::Standard,
        }),
        Duration::from_secs(5),
        ima_hal::time::TokioClock::shared(),
    )
    .await
    .unwrap();
    // h, sdo=t, sp=8 with 100 ms gaps, then go: configured before 0.5 s of virtual time.
    assert!(drv.now().as_secs_f64() < 0.5, "{:?}", drv.now());
    let h = drv.heading().await.unwrap();
    let truth = world_heading_deg(&world, id).unwrap();
    assert!((h.value.heading_rad.to_degrees() - truth).abs() < 0.06);
    // 8 Hz: eight readings a second.
    let t0 = h.at;
    let mut after = t0;
    for _ in 0..8 {
        after = drv.next_heading(after).await.unwrap().at;
    }
    let dt = after.saturating_duration_since(t0);
    assert!(
        dt >= Duration::from_millis(990) && dt <= Duration::from_millis(1010),
        "{dt:?}"
    );
    // Silence: the data watchdog (2 s) reports it, and data coming back clears it.
    dev.hang_up_for(Duration::from_secs(4));
    tokio::time::sleep(Duration::from_secs(3)).await;
    assert_eq!(drv.link(), LinkStatus::Lost);
    tokio::time::sleep(Duration::from_secs(2)).await;
    let now = drv.now();
    drv.next_heading(now).await.unwrap();
    assert_eq!(drv.link(), LinkStatus::Connected(()));
    let model = dev.stop().await.unwrap();
    assert_eq!(model.stats().bad_commands, 0);
}

#[tokio::test(start_paused = true)]
async fn mux_switch_delay_settle_and_garbage_frames() {
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
    let cfg = CameraConfig::default();
    let mut cam = MockCameraHead::new(cfg, world, id, bus.clone());
    let asked = mux.now();
    let sel = mux.select(1).await.unwrap();
    let took = sel.confirmed_at.saturating_duration_since(asked);
    // 30 ms switch delay plus the runner's polling (5 ms) at most.
    assert!(
        took >= Duration::from_millis(30) && took <= Duration::from_millis(45),
        "{took:?}"
    );
    // Right after the confirmation: the next frame is exposed before the settle time.
    let early = cam.grab().await.unwrap().value;
    let grey = find_color(&early, cfg.background, 6).map_or(0, |c| c.1);
    assert!(
        grey < 320 * 240 / 5,
        "a frame before the settle time is garbage"
    );
    assert!(find_color(&early, [220, 30, 30], 12).is_none_or(|(_, n)| n < 100));
    tokio::time::sleep(sel.settled_at.saturating_duration_since(mux.now())).await;
    let good = cam.grab().await.unwrap().value;
    let (col, n) = find_color(&good, [220, 30, 30], 12).unwrap();
    assert!(n > 300 && (col - 160.0).abs() < 1.0, "{col} {n}");
    // The switcher answers the query with what it shows.
    assert_eq!(mux.current_channel().await.unwrap(), Some(1));
    assert_eq!(mux.known_channel(), Some(1));
}

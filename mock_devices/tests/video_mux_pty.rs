//! End to end: the switcher driver against the mock Extron switcher over a real pty, and the
//! mock camera head fed by that switcher.

use std::time::Duration;

use ima_hal::camera::{CameraMux, FrameSource};
use ima_hal::{Error, ErrorKind};
use ima_mock_devices::camera::{CameraConfig, MockCameraHead, find_color};
use ima_mock_devices::pty::{PtyDevice, PtyOptions};
use ima_mock_devices::video_mux::{MuxDevice, MuxModelConfig, VideoBus};
use ima_mock_devices::world::{SharedWorld, World};
use ima_video_mux::machine::{Config, Refusal};
use ima_video_mux::shell::Driver as _;
use ima_video_mux::shell::{DriverError, Notice, VideoMux, open_port};
use ima_video_mux::wire::ExtronError;

fn serve(cfg: MuxModelConfig, bus: &VideoBus) -> PtyDevice<MuxDevice> {
    PtyDevice::spawn(MuxDevice::new(cfg, bus.clone()), PtyOptions::default()).unwrap()
}

fn driver(dev: &PtyDevice<MuxDevice>) -> VideoMux {
    let port = open_port(dev.path().to_str().unwrap(), 9600).unwrap();
    VideoMux::spawn(port, Config::default(), ima_hal::time::TokioClock::shared())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn select_query_and_refusals_over_a_pty() {
    let bus = VideoBus::default();
    let dev = serve(
        MuxModelConfig {
            inputs: 5,
            ..MuxModelConfig::default()
        },
        &bus,
    );
    let mut mux = driver(&dev);
    for ch in [3u8, 1, 5] {
        let sel = mux.select(ch).await.unwrap();
        assert_eq!(sel.channel, ch);
        assert_eq!(
            sel.settled_at.saturating_duration_since(sel.confirmed_at),
            mux.settle_time()
        );
        assert_eq!(bus.current().0, Some(ch), "the switcher really switched");
        assert_eq!(mux.current_channel().await.unwrap(), Some(ch));
    }
    // Channel 6 exists for the driver (7 channels) but not on this 5-input switcher: E01.
    let e = mux.select(6).await.unwrap_err();
    assert_eq!(
        e,
        DriverError::Device(ima_video_mux::driver::Fault::Refused(Refusal::Extron(
            ExtronError::InvalidInput
        )))
    );
    assert_eq!(e.kind(), ErrorKind::Protocol);
    // Out of range for the driver: refused before sending.
    let e = mux.select(8).await.unwrap_err();
    assert_eq!(e.kind(), ErrorKind::InvalidArgument);
    assert_eq!(bus.current().0, Some(5), "refusals switch nothing");
    // The power-on banner was seen and reported.
    assert!(mux.stats().framer.dropped_bytes == 0);
    let st = dev.stop().unwrap().stats();
    assert_eq!(st.switches, 3);
    assert_eq!(st.errors, 1);
    let _ = Notice::Banner;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn auto_switch_mode_refuses_with_e06() {
    let bus = VideoBus::default();
    let dev = serve(
        MuxModelConfig {
            auto_switch: true,
            ..MuxModelConfig::default()
        },
        &bus,
    );
    let mut mux = driver(&dev);
    assert_eq!(
        mux.select(2).await,
        Err(DriverError::Device(ima_video_mux::driver::Fault::Refused(
            Refusal::Extron(ExtronError::ChangeNotAllowed)
        )))
    );
    drop(dev);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn silent_switcher_times_out() {
    // A pty nobody answers on: the driver retries, then reports a timeout.
    let (_master, slave) = ima_mock_devices::pty::pty_pair().unwrap();
    let path = serialport::SerialPort::name(&slave).unwrap();
    let port = open_port(&path, 9600).unwrap();
    let mut mux = VideoMux::spawn(
        port,
        Config {
            reply_timeout: Duration::from_millis(100),
            retries: 1,
            ..Config::default()
        },
        ima_hal::time::TokioClock::shared(),
    );
    assert_eq!(mux.select(2).await, Err(DriverError::Timeout));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sweep_all_cameras_through_the_real_switcher() {
    let world = SharedWorld::new(World::default_world());
    let id = world.with(|w| w.robot_id("skeeter")).unwrap();
    let bus = VideoBus::default();
    let dev = serve(MuxModelConfig::default(), &bus);
    let mut mux = driver(&dev);
    let cfg = CameraConfig::default();
    let mut cam = MockCameraHead::new(cfg, world.clone(), id, bus.clone());
    let start = std::time::Instant::now();
    let mut seen = Vec::new();
    for ch in 1..=cfg.cameras {
        let sel = mux.select(ch).await.unwrap();
        let wait = sel.settled_at.saturating_duration_since(mux.now());
        tokio::time::sleep(wait).await;
        let f = cam.grab().await.unwrap().value;
        assert_eq!(f.channel, Some(ch));
        // Objects every 60° at 3 m; cameras every 51.4°: count the colours seen.
        for (name, rgb) in [
            ("red", [220, 30, 30]),
            ("green", [30, 180, 60]),
            ("blue", [30, 60, 220]),
            ("yellow", [240, 220, 40]),
            ("orange", [250, 140, 20]),
            ("purple", [140, 40, 170]),
        ] {
            if find_color(&f, rgb, 12).is_some_and(|(_, n)| n > 100) {
                seen.push(name);
            }
        }
    }
    eprintln!("sweep of 7 cameras over a pty took {:?}", start.elapsed());
    seen.sort_unstable();
    seen.dedup();
    assert_eq!(
        seen.len(),
        6,
        "every object appears in some camera: {seen:?}"
    );
}

#[test]
fn blocking_shell_selects_and_queries() {
    use ima_hal::blocking::CameraMux as _;
    let bus = VideoBus::default();
    let dev = PtyDevice::spawn(
        MuxDevice::new(MuxModelConfig::default(), bus.clone()),
        PtyOptions::default(),
    )
    .unwrap();
    let path = dev.path().to_str().unwrap().to_owned();
    let mut mux = ima_serial::blocking::Blocking::connect(async || {
        let port = ima_video_mux::shell::open_port(&path, 9600).unwrap();
        let clock = ima_hal::time::TokioClock::shared();
        Ok::<_, ima_video_mux::driver::DriverError>(VideoMux::spawn(port, Config::default(), clock))
    })
    .unwrap();
    let sel = mux.select(4).unwrap();
    assert_eq!(sel.channel, 4);
    assert_eq!(bus.current().0, Some(4));
    assert_eq!(mux.current_channel().unwrap(), Some(4));
    assert_eq!(
        mux.select(0).unwrap_err().kind(),
        ErrorKind::InvalidArgument
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn kramer_dialect_over_a_pty() {
    let bus = VideoBus::default();
    let dev = serve(
        MuxModelConfig {
            dialect: ima_mock_devices::video_mux::MuxDialect::Kramer,
            ..MuxModelConfig::default()
        },
        &bus,
    );
    let port = open_port(dev.path().to_str().unwrap(), 9600).unwrap();
    let mut mux = VideoMux::spawn(
        port,
        Config {
            dialect: ima_video_mux::machine::Dialect::Kramer {
                output: 1,
                machine: 1,
                expect_reply: true,
            },
            ..Config::default()
        },
        ima_hal::time::TokioClock::shared(),
    );
    let sel = mux.select(6).await.unwrap();
    assert_eq!(sel.channel, 6);
    assert_eq!(bus.current().0, Some(6));
    assert_eq!(mux.current_channel().await.unwrap(), Some(6));
}

//! The frame client (`ima_video_mux::net_frames::NetFrames`, a hal `FrameSource`) against
//! the mock frame server over loopback TCP: no signal before a switch, the selected camera's
//! frame after it, and a fresh connection after the server went away and came back.

use std::net::SocketAddr;
use std::time::Duration;

use ima_hal::camera::FrameSource;
use ima_mock_devices::camera::{CameraConfig, find_color};
use ima_mock_devices::served::FrameServer;
use ima_mock_devices::video_mux::VideoBus;
use ima_mock_devices::world::{SharedWorld, World};
use ima_video_mux::net_frames::{NetFrameError, NetFrames, Status};

fn server(addr: SocketAddr, bus: &VideoBus) -> FrameServer {
    let world = SharedWorld::new(World::default_world());
    let sk = world.with(|w| w.robot_id("skeeter")).unwrap();
    FrameServer::spawn(addr, CameraConfig::default(), world, sk, bus.clone()).unwrap()
}

#[tokio::test]
async fn client_grabs_the_selected_camera_and_reconnects() {
    let bus = VideoBus::new(None);
    let srv = server("127.0.0.1:0".parse().unwrap(), &bus);
    let addr = srv.addr();
    let mut cam = NetFrames::new(addr.to_string(), Duration::from_secs(5));
    assert_eq!(
        cam.grab().await.unwrap_err(),
        NetFrameError::Remote(Status::NoSignal)
    );
    bus.switch(1);
    tokio::time::sleep(Duration::from_millis(250)).await;
    let f = cam.grab().await.unwrap();
    assert_eq!(
        (f.value.width, f.value.height, f.value.channel),
        (320, 240, Some(1))
    );
    assert!(f.at <= cam.now());
    let (col, _) = find_color(&f.value, [220, 30, 30], 12).unwrap();
    assert!(
        (col - 160.0).abs() < 2.0,
        "red straight ahead: column {col}"
    );
    // The server goes away: the grab fails with a transport error …
    drop(srv);
    let e = cam.grab().await.unwrap_err();
    assert!(
        matches!(e, NetFrameError::Io(_) | NetFrameError::Timeout),
        "{e:?}"
    );
    // … and comes back on the same address: the next grab reconnects.
    let _srv = server(addr, &bus);
    tokio::time::sleep(Duration::from_millis(250)).await;
    let f = cam.grab().await.unwrap();
    assert_eq!(f.value.channel, Some(1));
    assert_eq!(cam.grabs(), 2);
}

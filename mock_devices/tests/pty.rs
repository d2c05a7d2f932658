//! The pty runner against a real pty opened the way a driver opens a serial port.

use std::io::{Read, Write};
use std::time::{Duration, Instant as StdInstant};

use ima_hal::Instant;
use ima_mock_devices::faults::{Direction, FaultAction, FaultPlan};
use ima_mock_devices::link::LinkState;
use ima_mock_devices::model::EchoModel;
use ima_mock_devices::pty::{PtyDevice, PtyOptions};
use serialport::TTYPort;

fn open(path: &std::path::Path) -> TTYPort {
    serialport::new(path.to_string_lossy(), 9600)
        .timeout(Duration::from_millis(50))
        .open_native()
        .expect("open the slave like a serial port")
}

/// Read until `n` bytes arrived or `deadline` passed (a generous bound, not a timing claim).
fn read_n(port: &mut TTYPort, n: usize, deadline: Duration) -> Vec<u8> {
    let end = StdInstant::now() + deadline;
    let mut got = Vec::new();
    let mut buf = [0u8; 256];
    while got.len() < n && StdInstant::now() < end {
        match port.read(&mut buf) {
            Ok(k) => got.extend_from_slice(&buf[..k]),
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {}
            Err(e) => panic!("read: {e}"),
        }
    }
    got
}

#[test]
fn echo_round_trip_through_a_real_pty() {
    let dev = PtyDevice::spawn(EchoModel::new(), PtyOptions::default()).unwrap();
    assert!(dev.path().starts_with("/dev/pts/"));
    let mut port = open(dev.path());
    let msg: Vec<u8> = (0..=255u8).collect(); // every byte value: the line is raw
    port.write_all(&msg).unwrap();
    assert_eq!(read_n(&mut port, msg.len(), Duration::from_secs(5)), msg);
    // A driver may close and reopen the same path while the device lives.
    drop(port);
    let mut port = open(dev.path());
    port.write_all(b"again").unwrap();
    assert_eq!(read_n(&mut port, 5, Duration::from_secs(5)), b"again");
    let model = dev.stop().unwrap();
    assert_eq!(model.received(), 256 + 5);
}

#[test]
fn hang_up_then_recover_on_the_same_path() {
    let dev = PtyDevice::spawn(EchoModel::new(), PtyOptions::default()).unwrap();
    let path = dev.path().to_path_buf();
    let mut port = open(&path);
    port.write_all(b"a").unwrap();
    assert_eq!(read_n(&mut port, 1, Duration::from_secs(5)), b"a");

    dev.hang_up_for(Duration::from_secs(2));
    // Wait until the thread has taken the link down.
    let end = StdInstant::now() + Duration::from_secs(5);
    while dev.status().state == LinkState::Up && StdInstant::now() < end {
        std::thread::sleep(Duration::from_millis(5));
    }
    assert!(matches!(dev.status().state, LinkState::DownUntil(_)));
    port.write_all(b"lost").unwrap();
    assert!(read_n(&mut port, 1, Duration::from_millis(300)).is_empty());

    // Keep knocking on the same open port until the device answers again.
    let end = StdInstant::now() + Duration::from_secs(10);
    let mut got = Vec::new();
    while got.is_empty() && StdInstant::now() < end {
        port.write_all(b"c").unwrap();
        got = read_n(&mut port, 1, Duration::from_millis(100));
    }
    assert!(!got.is_empty(), "device did not come back");
    assert!(got.iter().all(|&b| b == b'c'), "{got:?}");
    assert_eq!(dev.path(), path.as_path());
    let st = dev.status();
    assert_eq!(st.state, LinkState::Up);
    assert_eq!((st.counters.hangups, st.counters.reconnects), (1, 1));
    assert!(st.counters.discarded_while_down >= 4);
    let model = dev.stop().unwrap();
    assert_eq!(model.link_events(), (1, 1));
}

#[test]
fn manual_hang_up_and_reconnect() {
    let dev = PtyDevice::spawn(EchoModel::new(), PtyOptions::default()).unwrap();
    let mut port = open(dev.path());
    dev.hang_up();
    let end = StdInstant::now() + Duration::from_secs(5);
    while dev.status().state == LinkState::Up && StdInstant::now() < end {
        std::thread::sleep(Duration::from_millis(5));
    }
    port.write_all(b"x").unwrap();
    assert!(read_n(&mut port, 1, Duration::from_millis(200)).is_empty());
    dev.reconnect();
    let end = StdInstant::now() + Duration::from_secs(5);
    while dev.status().state != LinkState::Up && StdInstant::now() < end {
        std::thread::sleep(Duration::from_millis(5));
    }
    port.write_all(b"y").unwrap();
    assert_eq!(read_n(&mut port, 1, Duration::from_secs(5)), b"y");
}

#[test]
fn corruption_through_the_pty_matches_the_pure_injector() {
    let plan = FaultPlan::parse("r2h.corrupt=0.2,seed=7").unwrap();
    let dev = PtyDevice::spawn(
        EchoModel::new(),
        PtyOptions {
            faults: plan.clone(),
            ..PtyOptions::default()
        },
    )
    .unwrap();
    let mut port = open(dev.path());
    let msg: Vec<u8> = (0..2000u32).map(|i| (i % 251) as u8).collect();
    port.write_all(&msg).unwrap();
    let got = read_n(&mut port, msg.len(), Duration::from_secs(5));
    assert_eq!(got.len(), msg.len());
    // Per-byte faults do not depend on how the bytes were chunked: the same seed gives the
    // same corruption as running the injector by hand.
    let mut inj = plan.injector(Direction::RobotToHost, Instant::ZERO);
    let mut actions = Vec::new();
    inj.process(&msg, Instant::ZERO, &mut actions);
    let expected: Vec<u8> = actions
        .into_iter()
        .flat_map(|a| match a {
            FaultAction::Data(d) => d,
            _ => Vec::new(),
        })
        .collect();
    assert_eq!(got, expected);
    let corrupted = got.iter().zip(&msg).filter(|(a, b)| a != b).count() as u64;
    let end = StdInstant::now() + Duration::from_secs(5);
    while dev.status().counters.robot_to_host.corrupted < corrupted && StdInstant::now() < end {
        std::thread::sleep(Duration::from_millis(5));
    }
    assert_eq!(dev.status().counters.robot_to_host.corrupted, corrupted);
    assert!(corrupted > 300 && corrupted < 500, "{corrupted}");
}

#[test]
fn timed_hangup_for_good_from_the_spec_goes_silent() {
    let dev = PtyDevice::spawn(
        EchoModel::new(),
        PtyOptions {
            faults: FaultPlan::parse("hangup=100ms").unwrap(),
            ..PtyOptions::default()
        },
    )
    .unwrap();
    let mut port = open(dev.path());
    let end = StdInstant::now() + Duration::from_secs(5);
    while dev.status().state != LinkState::Closed && StdInstant::now() < end {
        std::thread::sleep(Duration::from_millis(5));
    }
    assert_eq!(dev.status().state, LinkState::Closed);
    port.write_all(b"z").unwrap();
    assert!(read_n(&mut port, 1, Duration::from_millis(200)).is_empty());
}

#[test]
fn many_devices_in_parallel_get_distinct_paths() {
    let handles: Vec<_> = (0..4)
        .map(|_| std::thread::spawn(|| PtyDevice::spawn(EchoModel::new(), PtyOptions::default())))
        .collect();
    let devs: Vec<_> = handles
        .into_iter()
        .map(|h| h.join().unwrap().unwrap())
        .collect();
    let mut paths: Vec<_> = devs.iter().map(|d| d.path().to_path_buf()).collect();
    paths.sort();
    paths.dedup();
    assert_eq!(paths.len(), 4);
}

#[test]
fn a_device_can_step_the_world() {
    use ima_mock_devices::world::{DriveCommand, SharedWorld, World};
    let world = SharedWorld::new(World::default_world());
    let sk = world.lock().robot_id("skeeter").unwrap();
    world.with(|w| {
        w.command(
            sk,
            DriveCommand::Twist {
                v_m_s: 0.3,
                omega_rad_s: 0.0,
            },
        )
    });
    let dev = PtyDevice::spawn(
        EchoModel::new(),
        PtyOptions {
            step_world: Some(world.clone()),
            ..PtyOptions::default()
        },
    )
    .unwrap();
    let end = StdInstant::now() + Duration::from_secs(5);
    while world.lock().robot(sk).unwrap().pose().x_m <= 0.0 && StdInstant::now() < end {
        std::thread::sleep(Duration::from_millis(10));
    }
    assert!(world.lock().robot(sk).unwrap().pose().x_m > 0.0);
    dev.stop().unwrap();
}

/// Packets (payloads) in `bytes` that pass the P2OS framer.
fn p2os_packets(bytes: &[u8]) -> Vec<Vec<u8>> {
    let mut f = ima_p2os::framer::Framer::new();
    let mut v = Vec::new();
    f.push(bytes, |ev| {
        if let ima_p2os::framer::FrameEvent::Frame(p) = ev {
            v.push(p.to_vec());
        }
    });
    v
}

fn p2os_frame(c: ima_p2os::wire::Command<'_>) -> Vec<u8> {
    let mut b = [0u8; 300];
    let n = c.emit(&mut b).unwrap();
    b[..n].to_vec()
}

/// A client switches the P2OS mock's line with HOSTBAUD, as ARIA does: the command at the old
/// rate, its own port to the new one, then PULSE; the robot's packets arrive intact at the new
/// rate, and CLOSE puts the robot back at its power-up rate.
#[test]
fn p2os_hostbaud_switches_the_line_over_a_pty() {
    use ima_mock_devices::body::WorldBody;
    use ima_mock_devices::p2os::{P2osDevice, P2osModelConfig};
    use ima_mock_devices::world::{RobotSpec, SharedWorld, World};
    use ima_p2os::wire::{Command, IntCommand};
    use serialport::SerialPort;

    let mut w = World::new();
    let id = w
        .add_robot(RobotSpec::new("skeeter", 0.0, 0.0, 0.0))
        .unwrap();
    let world = SharedWorld::new(w);
    let dev = PtyDevice::spawn(
        P2osDevice::new(
            P2osModelConfig::default(),
            WorldBody::new(world.clone(), id, 1),
        ),
        PtyOptions::default(),
    )
    .unwrap();
    let mut port = open(dev.path());
    for c in [Command::Sync0, Command::Sync1, Command::Sync2] {
        port.write_all(&p2os_frame(c)).unwrap();
        let got = read_n(&mut port, 5, Duration::from_secs(5));
        assert!(!p2os_packets(&got).is_empty(), "{c:?} answered");
        std::thread::sleep(Duration::from_millis(50)); // the rest of the SYNC2 reply
        let _ = read_n(&mut port, 4096, Duration::from_millis(100));
    }
    port.write_all(&p2os_frame(Command::OPEN)).unwrap();
    let sips = read_n(&mut port, 200, Duration::from_secs(5));
    assert!(!p2os_packets(&sips).is_empty(), "SIPs at 9600");
    // HOSTBAUD 2 at 9600; give it time to reach the robot before the host's port switches
    // (ARIA sleeps 10 ms), then PULSE at 38400. Retried: a loaded machine may be slow.
    let mut switched = false;
    for _ in 0..5 {
        port.set_baud_rate(9600).unwrap();
        port.write_all(&p2os_frame(Command::Int(IntCommand::HostBaud, 2)))
            .unwrap();
        std::thread::sleep(Duration::from_millis(100));
        port.set_baud_rate(38400).unwrap();
        let _ = port.clear(serialport::ClearBuffer::Input);
        port.write_all(&p2os_frame(Command::PULSE)).unwrap();
        let got = read_n(&mut port, 400, Duration::from_secs(2));
        if !p2os_packets(&got).is_empty() {
            switched = true;
            break;
        }
    }
    assert!(switched, "packets at 38400 after HOSTBAUD");
    port.write_all(&p2os_frame(Command::CLOSE)).unwrap();
    std::thread::sleep(Duration::from_millis(200));
    let dev_model = dev.stop().unwrap();
    assert_eq!(dev_model.robot().stats().baud_switches, 1);
    assert_eq!(
        dev_model.robot().baud(),
        9600,
        "CLOSE restores the power-up rate"
    );
}

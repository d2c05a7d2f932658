//! Skeeter's side of the mission end to end in virtual time, with nothing but this crate:
//! the commander's series goes over an in-memory broadcast channel (every message through
//! `peer::wire::Msg` and back), Skeeter's brain asks for sweeps, the Scan node renders-and-
//! searches frames of a simple pinhole scene, and a scripted Scooter answers on the channel.

use std::collections::VecDeque;
use std::time::Duration;

use ima_agents::mission::commander::{Commander, CommanderConfig, TargetState};
use ima_agents::mission::msg::{Broadcast, Emergency, MissionEvent, SCOOTER};
use ima_agents::mission::scan::{ScanCommand, ScanConfig, ScanEvent, ScanReport, Scanner};
use ima_agents::mission::skeeter::{SkeeterBrain, SkeeterConfig, SkeeterOutput};
use ima_agents::mission::vision::{ColourDb, HeadGeometry, focal_px};
use ima_agents::ses::shared::SharedForm;
use ima_hal::Instant;
use ima_hal::camera::{Channel, Frame};

/// Things round Skeeter: (bearing rad, range m, radius m, rgb).
struct Scene(Vec<(f64, f64, f64, [u8; 3])>);

impl Scene {
    fn render(&self, ch: Channel) -> Frame {
        let head = HeadGeometry::default();
        let (w, h) = (320u32, 240u32);
        let mut f = Frame::black(w, h, Some(ch)).unwrap();
        f.pixels.fill(128);
        let fov = head.fov_rad();
        let fpx = focal_px(w, fov);
        let yaw = head.camera_yaw_rad(ch).unwrap();
        for &(b, range, radius, rgb) in &self.0 {
            let rel = ima_hal::normalize_angle(b - yaw);
            if rel.abs() > fov / 2.0 {
                continue;
            }
            let cx = f64::from(w) / 2.0 - fpx * rel.tan();
            let r = fpx * radius / range / rel.cos().powi(2);
            for y in 0..h {
                for x in 0..w {
                    let (dx, dy) = (f64::from(x) + 0.5 - cx, f64::from(y) + 0.5 - 120.0);
                    if dx * dx + dy * dy <= r * r {
                        f.set_pixel(x, y, rgb);
                    }
                }
            }
        }
        f
    }
}

/// One sweep, sans-IO, 230 ms per camera.
fn sweep(scanner: &mut Scanner, scene: &Scene, now: &mut Instant) -> ScanReport {
    assert!(scanner.start(*now));
    let mut ch = 0;
    loop {
        while let Some(c) = scanner.poll_command() {
            match c {
                ScanCommand::Switch(c) => {
                    *now = *now + Duration::from_millis(30);
                    ch = c;
                    scanner.handle_switched(c, *now);
                }
                ScanCommand::Grab => {
                    *now = *now + Duration::from_millis(50);
                    scanner.handle_frame(&scene.render(ch), *now);
                }
            }
        }
        while let Some(e) = scanner.poll_event() {
            if let ScanEvent::ScanDone(r) = e {
                return r;
            }
        }
        let d = scanner.poll_timeout().unwrap();
        *now = (*now).max(d);
        scanner.handle_timeout(*now);
    }
}

/// Over the wire and back, as the broadcast channel does.
fn wire(b: &Broadcast, seq: u64) -> Broadcast {
    Broadcast::from_wire(&b.to_wire(seq)).unwrap()
}

#[test]
fn a_series_done_failed_and_timed_out() {
    let scene = Scene(vec![
        (0.0, 3.0, 0.15, [220, 30, 30]),   // red
        (2.0, 3.0, 0.15, [30, 60, 220]),   // blue
        (-2.6, 4.0, 0.4, [235, 235, 235]), // scooter
    ]);
    let mut scanner =
        Scanner::with_default_ses(ScanConfig::default(), ColourDb::default()).unwrap();
    let mut brain = SkeeterBrain::new(SkeeterConfig {
        target_timeout: Duration::from_secs(20),
        ..SkeeterConfig::default()
    })
    .unwrap();
    let mut commander = Commander::new(&["red", "purple", "blue"], CommanderConfig::default());
    let mut now = Instant::ZERO;
    brain.start(now);
    commander.start(now);
    let mut seq = 0u64;
    let mut to_skeeter: VecDeque<Broadcast> = VecDeque::new();
    let mut published: Vec<SharedForm> = Vec::new();
    let mut sweeps = 0u32;
    let mut scan_wanted = false;
    // Scripted Scooter: reaches red after 3 sweeps of it; never sees purple; sees blue
    // but never gets there (so blue times out).
    let mut red_sweeps = 0;
    for _ in 0..2_000 {
        if commander.is_finished() {
            break;
        }
        while let Some(b) = commander.poll_broadcast() {
            seq += 1;
            to_skeeter.push_back(wire(&b, seq));
        }
        while let Some(b) = to_skeeter.pop_front() {
            brain.handle_broadcast(&b, now);
        }
        while let Some(o) = brain.poll_output() {
            match o {
                SkeeterOutput::Broadcast(b) => {
                    seq += 1;
                    let b = wire(&b, seq);
                    commander.handle_broadcast(&b, now);
                    if let Broadcast::Emergency {
                        emergency: Emergency::TargetQuery { colour },
                        ..
                    } = &b
                    {
                        to_skeeter.push_back(Broadcast::emergency(
                            SCOOTER,
                            Emergency::TargetReply {
                                colour: colour.clone(),
                                seen: colour == "blue",
                            },
                        ));
                    }
                }
                SkeeterOutput::StartScan => scan_wanted = true,
                SkeeterOutput::PublishSes(form) => published.push(form),
            }
        }
        if !to_skeeter.is_empty() {
            continue;
        }
        if scan_wanted {
            scan_wanted = false;
            let report = sweep(&mut scanner, &scene, &mut now);
            sweeps += 1;
            if brain.target() == Some("red") {
                red_sweeps += 1;
                if red_sweeps == 3 {
                    to_skeeter.push_back(Broadcast::emergency(
                        SCOOTER,
                        Emergency::TargetReached {
                            colour: "red".into(),
                        },
                    ));
                }
            }
            brain.handle_scan(&report, now);
            // Timers that fell due during the sweep.
            if brain.poll_timeout().is_some_and(|t| t <= now) {
                brain.handle_timeout(now);
            }
            if commander.poll_timeout().is_some_and(|t| t <= now) {
                commander.handle_timeout(now);
            }
        } else {
            // Nothing to do: let time pass to the next timer.
            let next = [brain.poll_timeout(), commander.poll_timeout()]
                .into_iter()
                .flatten()
                .min()
                .unwrap();
            now = now.max(next);
            brain.handle_timeout(now);
            commander.handle_timeout(now);
        }
    }
    assert!(commander.is_finished());
    while let Some(o) = brain.poll_output() {
        if let SkeeterOutput::PublishSes(form) = o {
            published.push(form);
        }
    }
    let states: Vec<TargetState> = commander.targets().iter().map(|t| t.state).collect();
    assert_eq!(
        states,
        [TargetState::Done, TargetState::Failed, TargetState::Failed]
    );
    let outcomes: Vec<(&str, &str)> = brain
        .outcomes()
        .iter()
        .map(|o| (o.target.as_str(), o.module.as_str()))
        .collect();
    assert_eq!(
        outcomes,
        [
            ("red", "report-accomplished"),
            ("purple", "report-failed"),
            ("blue", "report-timeout"),
        ]
    );
    // Blue fails at the first check after its 20 s (the harness looks after each sweep).
    let blue = &brain.outcomes()[2];
    let took = blue.ended.saturating_duration_since(blue.started);
    assert!(
        took >= Duration::from_secs(20) && took < Duration::from_millis(21_610),
        "{took:?}"
    );
    // One sample per sweep, each with red, blue and Scooter at the right bearings.
    assert_eq!(published.len() as u32, sweeps);
    let last = published.last().unwrap();
    assert_eq!(last.records.len(), 3);
    for (object, want) in [("red", 0.0), ("blue", 2.0), ("scooter", -2.6)] {
        let r = last.records.iter().find(|r| r.object == object).unwrap();
        assert!((r.bearing.azimuth_rad - want).abs() < 0.005, "{object}");
    }
    // The commander heard Skeeter's statuses and its question about purple.
    let heard: Vec<String> = commander.log().map(|e| e.broadcast.to_string()).collect();
    assert!(
        heard.iter().any(|h| h == "skeeter: target-query (purple)"),
        "{heard:?}"
    );
    assert!(
        heard
            .iter()
            .any(|h| h.starts_with("skeeter: status scan-for-target"))
    );
    assert!(heard.contains(&"skeeter: mission red accomplished".to_owned()));
    let summary = commander.summary();
    assert_eq!((summary.done, summary.failed, summary.open), (1, 2, 0));
    assert_eq!(
        brain.outcomes()[0].event,
        MissionEvent::Accomplished,
        "red accomplished"
    );
}

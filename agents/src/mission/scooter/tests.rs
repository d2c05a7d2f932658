//! ScooterBrain end to end: the agents wired by the SAN, through the public API.
use super::*;
use core::f64::consts::PI;
use core::time::Duration;

use ima_hal::laser::BeamFlags;
use ima_hal::{Isometry2, Point2, normalize_angle};

use crate::mission::msg::{Emergency, MissionEvent, Pose};
use crate::ses::shared::SharedRecord;

const RED: &str = "red";

fn t(ms: u64) -> Instant {
    Instant::from_millis(ms)
}

fn rec(object: &str, bearing_deg: f64, range_m: Option<f64>, time: Instant) -> SharedRecord {
    SharedRecord {
        object: object.to_owned(),
        bearing: crate::ses::Direction::horizontal(bearing_deg.to_radians()),
        range_m,
        confidence: 1.0,
        time,
    }
}

fn form(records: Vec<SharedRecord>, sent_at: Instant) -> SharedForm {
    SharedForm {
        source_robot: "skeeter".to_owned(),
        sent_at,
        records,
    }
}

/// A brain whose laser never goes stale after one clear scan at t = 0 (tests that are
/// not about the laser's age; `blind_scooter_does_not_drive_forward` uses the default).
fn brain(rule: HeadingRule) -> ScooterBrain {
    let cfg = ScooterConfig {
        heading_rule: rule,
        heading_source: HeadingSource::Compass,
        laser_stale_after: Duration::MAX,
        ..ScooterConfig::default()
    };
    let mut b = ScooterBrain::new(cfg);
    b.handle_compass(0.0, t(0));
    b.handle_odometry(&Odometry::origin(), t(0));
    b.handle_laser(&clear_scan(), t(0));
    b
}

/// 181 beams, nothing within range.
fn clear_scan() -> LaserScan {
    let mut s = LaserScan::new(-PI / 2.0, PI / 180.0);
    for _ in 0..181 {
        s.push(f32::NAN, BeamFlags::NO_RETURN).unwrap();
    }
    s
}

/// 181 beams, all dazzled.
fn blinded_scan() -> LaserScan {
    let mut s = LaserScan::new(-PI / 2.0, PI / 180.0);
    for _ in 0..181 {
        s.push(f32::NAN, BeamFlags::DAZZLED).unwrap();
    }
    s
}

#[test]
fn blind_scooter_does_not_drive_forward() {
    let mut b = ScooterBrain::new(ScooterConfig {
        heading_rule: HeadingRule::Thesis,
        heading_source: HeadingSource::Compass,
        ..ScooterConfig::default()
    });
    b.handle_compass(0.0, t(0));
    b.handle_odometry(&Odometry::origin(), t(0));
    b.set_target(RED, t(0));
    // θd = 180° + 0° − 88° … a plan almost straight ahead: θ1 = 0°, θ2 = 179° → 90.5°;
    // face it so that the controller drives rather than turns in place.
    let f = form(
        vec![rec("scooter", 0.0, None, t(0)), rec(RED, 179.0, None, t(0))],
        t(0),
    );
    assert!(b.handle_ses(&f, t(0)));
    b.handle_compass(b.desired_heading().unwrap(), t(0));
    // No scan ever: no forward speed.
    let out = b.step(t(100));
    assert_eq!(out.behaviour, Behaviour::FollowHeading);
    assert_eq!(out.command.v_m_s, 0.0, "no laser yet");
    // A clear scan: drive.
    b.handle_laser(&clear_scan(), t(200));
    let out = b.step(t(300));
    assert!(out.command.v_m_s > 0.0);
    // 0.5 s later still fresh, 0.6 s later stale.
    assert!(b.step(t(700)).command.v_m_s > 0.0);
    assert_eq!(b.step(t(800)).command.v_m_s, 0.0, "stale laser");
    // A blinded scan does not count as a clear path.
    b.handle_laser(&blinded_scan(), t(900));
    assert_eq!(b.step(t(950)).command.v_m_s, 0.0, "blinded scan");
    // Turning in place stays allowed while blind.
    b.handle_compass(b.desired_heading().unwrap() + 1.0, t(1000));
    let out = b.step(t(1000));
    assert_eq!(out.command.v_m_s, 0.0);
    assert!(out.command.omega_rad_s < 0.0, "turns back toward θd");
    // A configurable age.
    let mut b2 = ScooterBrain::new(ScooterConfig {
        laser_stale_after: Duration::from_secs(2),
        ..b.config().clone()
    });
    b2.handle_laser(&clear_scan(), t(0));
    assert!(b2.laser_fresh(t(1900)) && !b2.laser_fresh(t(2100)));
}

fn close_deg(a: f64, b_deg: f64) -> bool {
    normalize_angle(a - b_deg.to_radians()).abs() < 1e-3
}

/// A tiny world for closed-loop tests: a unicycle and round things, a 181-beam laser.
struct Mini {
    x: f64,
    y: f64,
    th: f64,
    circles: Vec<([f64; 2], f64)>,
}

impl Mini {
    fn scan(&self, mount: &Isometry2) -> LaserScan {
        let mut s = LaserScan::new(-PI / 2.0, PI / 180.0);
        let sensor = Isometry2::new(Vector2::new(self.x, self.y), self.th) * mount;
        let o = sensor.translation.vector;
        for k in 0..181 {
            let dir = sensor.rotation.angle() - PI / 2.0 + f64::from(k) * PI / 180.0;
            let d = unit(dir);
            let mut best = f64::INFINITY;
            for (c, r) in &self.circles {
                let f = o - Vector2::new(c[0], c[1]);
                let b = f.dot(&d);
                let cc = f.dot(&f) - r * r;
                let disc = b * b - cc;
                if disc >= 0.0 {
                    let hit = -b - disc.sqrt();
                    if hit >= 0.0 {
                        best = best.min(hit);
                    }
                }
            }
            if best < 8.0 {
                s.push(best as f32, BeamFlags::VALID).unwrap();
            } else {
                s.push(f32::NAN, BeamFlags::NO_RETURN).unwrap();
            }
        }
        s
    }

    fn odo(&self, start: (f64, f64, f64)) -> Odometry {
        let s = Isometry2::new(Vector2::new(start.0, start.1), start.2);
        let p = Isometry2::new(Vector2::new(self.x, self.y), self.th);
        Odometry {
            pose: s.inverse() * p,
            v_m_s: 0.0,
            omega_rad_s: 0.0,
        }
    }

    fn advance(&mut self, c: VelocityCommand, dt: f64) {
        self.th = normalize_angle(self.th + c.omega_rad_s * dt);
        self.x += c.v_m_s * dt * self.th.cos();
        self.y += c.v_m_s * dt * self.th.sin();
    }
}

#[test]
fn embedded_network_loads_and_every_module_has_a_behaviour() {
    let b = ScooterBrain::new(ScooterConfig::default());
    for m in b.san().module_names() {
        let beh = Behaviour::from_module(m).unwrap();
        assert_eq!(beh.as_str(), m);
    }
    assert_eq!(b.behaviour(), Behaviour::Idle);
}

#[test]
fn idle_without_a_target() {
    let mut b = brain(HeadingRule::Thesis);
    let out = b.step(t(0));
    assert_eq!(out.behaviour, Behaviour::Idle);
    assert_eq!(out.command, VelocityCommand::ZERO);
    assert!(!b.handle_ses(&form(vec![rec("scooter", 0.0, None, t(0))], t(0)), t(0)));
}

#[test]
fn thesis_rule_plans_the_isosceles_heading_and_turns_in_place() {
    let mut b = brain(HeadingRule::Thesis);
    b.set_target(RED, t(0));
    let f = form(
        vec![
            rec("scooter", 0.0, Some(3.0), t(0)),
            rec(RED, 90.0, Some(5.0), t(0)),
        ],
        t(0),
    );
    assert!(b.handle_ses(&f, t(0)));
    // Ranges are ignored by the thesis rule: θd = 135°.
    assert!(matches!(b.plan(), Some(Plan::Heading(h)) if close_deg(h, 135.0)));
    b.step(t(0));
    let out = b.step(t(50));
    assert_eq!(out.behaviour, Behaviour::FollowHeading);
    assert_eq!(out.command.v_m_s, 0.0, "turns in place first");
    assert!(
        out.command.omega_rad_s > 0.0,
        "counter-clockwise toward 135°"
    );
}

/// A thesis-rule brain with `recognition`, heading for red: Scooter at the origin facing
/// 0°, Skeeter's SES puts red at 90° of it, so the estimate is θd = 135°.
fn estimate_at_135_deg(recognition: TargetRecognition) -> ScooterBrain {
    let mut b = ScooterBrain::new(ScooterConfig {
        target_recognition: recognition,
        ..brain(HeadingRule::Thesis).config().clone()
    });
    b.handle_compass(0.0, t(0));
    b.handle_odometry(&Odometry::origin(), t(0));
    b.set_target(RED, t(0));
    let f = form(
        vec![rec("scooter", 0.0, None, t(0)), rec(RED, 90.0, None, t(0))],
        t(0),
    );
    assert!(b.handle_ses(&f, t(0)));
    b
}

#[test]
fn in_view_recognition_takes_the_target_far_off_a_wrong_estimate() {
    // θd = 135° (thesis rule), but the post stands 1 m straight ahead (0°): 135° off
    // the estimate. Near-estimate recognition ignores it; in-view recognition goes to it.
    for (recognition, expected) in [
        (TargetRecognition::NearEstimate, Behaviour::FollowHeading),
        (TargetRecognition::InView, Behaviour::MoveToTarget),
    ] {
        let mut b = estimate_at_135_deg(recognition);
        let w = Mini {
            x: 0.0,
            y: 0.0,
            th: 0.0,
            circles: vec![([1.0, 0.0], 0.15)],
        };
        let mount = b.config().laser_mount;
        b.handle_laser(&w.scan(&mount), t(0));
        let out = b.step(t(0));
        assert_eq!(out.behaviour, expected, "{}", recognition.as_str());
    }
}

#[test]
fn in_view_recognition_ignores_target_sized_pieces_of_a_wider_object() {
    // Two posts side by side, 0.25 m apart in range: each is target-sized on its own,
    // together (joined over the range jump) a 0.6 m object — like Skeeter split in two
    // by laser noise. A lone post at the same place is taken.
    let pair = vec![([1.5, -0.16], 0.15), ([1.75, 0.1], 0.15)];
    let lone = vec![([1.5, -0.16], 0.15)];
    for (circles, expected) in [
        (pair, Behaviour::FollowHeading),
        (lone, Behaviour::MoveToTarget),
    ] {
        let mut b = estimate_at_135_deg(TargetRecognition::InView);
        let w = Mini {
            x: 0.0,
            y: 0.0,
            th: 0.0,
            circles,
        };
        let mount = b.config().laser_mount;
        let scan = w.scan(&mount);
        let c = b.config();
        let fine = laser_clusters(&scan, &mount, c.laser_max_range_m, c.cluster_gap_m, 0.15);
        let joined = laser_clusters(&scan, &mount, c.laser_max_range_m, 0.3, 0.15);
        let sized = |v: &[Cluster]| v.iter().filter(|k| c.is_target_width(k.width_m)).count();
        if expected == Behaviour::FollowHeading {
            assert_eq!(
                (sized(&fine), sized(&joined)),
                (2, 0),
                "{fine:?} {joined:?}"
            );
        }
        b.handle_laser(&scan, t(0));
        assert_eq!(b.step(t(0)).behaviour, expected);
    }
}

#[test]
fn range_aware_rule_with_ranges_plans_the_target_point() {
    let mut b = brain(HeadingRule::RangeAware);
    b.set_target(RED, t(0));
    let f = form(
        vec![
            rec("scooter", 0.0, Some(2.0), t(0)),
            rec(RED, 90.0, Some(5.0), t(0)),
        ],
        t(0),
    );
    assert!(b.handle_ses(&f, t(0)));
    // Scooter at (2, 0), target at (0, 5): relative (−2, 5) from the DR origin.
    match b.plan() {
        Some(Plan::Point(p)) => assert!((p - Vector2::new(-2.0, 5.0)).norm() < 1e-3),
        other => panic!("{other:?}"),
    }
    assert!(close_deg(
        b.desired_heading().unwrap(),
        5f64.atan2(-2.0).to_degrees()
    ));
}

#[test]
fn range_aware_rule_falls_back_to_the_thesis_rule_without_ranges() {
    let mut b = brain(HeadingRule::RangeAware);
    b.set_target(RED, t(0));
    let f = form(
        vec![rec("scooter", 0.0, None, t(0)), rec(RED, -90.0, None, t(0))],
        t(0),
    );
    assert!(b.handle_ses(&f, t(0)));
    assert!(matches!(b.plan(), Some(Plan::Heading(h)) if close_deg(h, -135.0)));
}

#[test]
fn range_aware_rule_triangulates_scooter_from_its_own_motion() {
    let mut b = brain(HeadingRule::RangeAware);
    b.set_target(RED, t(0));
    // Scooter at (1, 0) in the common frame; Skeeter sees it at 0°.
    let f0 = form(
        vec![
            rec("scooter", 0.0, None, t(0)),
            rec(RED, 180.0, Some(4.0), t(0)),
        ],
        t(0),
    );
    assert!(b.handle_ses(&f0, t(0)));
    assert!(matches!(b.plan(), Some(Plan::Heading(_))));
    // It drives 1 m along +y (heading 90°) to (1, 1): Skeeter sees it at 45°.
    b.handle_compass(PI / 2.0, t(1000));
    b.handle_odometry(
        &Odometry {
            pose: Isometry2::new(Vector2::new(0.0, 0.0), PI / 2.0),
            ..Odometry::origin()
        },
        t(1000),
    );
    b.handle_odometry(
        &Odometry {
            pose: Isometry2::new(Vector2::new(0.0, 1.0), PI / 2.0),
            ..Odometry::origin()
        },
        t(2000),
    );
    let f1 = form(
        vec![
            rec("scooter", 45.0, None, t(2000)),
            rec(RED, 180.0, Some(4.0), t(2000)),
        ],
        t(2000),
    );
    assert!(b.handle_ses(&f1, t(2000)));
    match b.plan() {
        // DR = common − (1, 0): the target (−4, 0) is DR (−5, 0).
        Some(Plan::Point(p)) => assert!((p - Vector2::new(-5.0, 0.0)).norm() < 1e-2, "{p}"),
        other => panic!("{other:?}"),
    }
}

#[test]
fn ses_record_times_are_placed_on_the_local_clock() {
    let mut b = brain(HeadingRule::RangeAware);
    b.set_target(RED, t(0));
    // Scooter drives along +x: at 1 s it is at DR (0.1, 0), at 3 s at (0.3, 0).
    for k in 0..=30 {
        let x = 0.01 * f64::from(k);
        b.handle_odometry(
            &Odometry {
                pose: Isometry2::new(Vector2::new(x, 0.0), 0.0),
                ..Odometry::origin()
            },
            t(100 * u64::try_from(k).unwrap()),
        );
    }
    // Skeeter's clock is 1000 s ahead; the record was sensed 2 s before sending, which
    // arrives at our 3 s: sensed at our 1 s, when DR was (0.1, 0).
    let sk = |ms: u64| Instant::from_millis(1_000_000 + ms);
    let f = form(
        vec![
            rec("scooter", 0.0, Some(2.0), sk(1000)),
            rec(RED, 90.0, Some(2.0), sk(1000)),
        ],
        sk(3000),
    );
    assert!(b.handle_ses(&f, t(3000)));
    match b.plan() {
        // Target relative to Scooter then: (−2, 2); DR (0.1, 0) + that.
        Some(Plan::Point(p)) => assert!((p - Vector2::new(-1.9, 2.0)).norm() < 1e-6, "{p}"),
        other => panic!("{other:?}"),
    }
}

#[test]
fn lost_timer_requests_a_heading_coasts_then_stops() {
    let mut b = brain(HeadingRule::Thesis);
    b.set_target(RED, t(0));
    // No sample yet: request at once, standing still.
    let out = b.step(t(0));
    assert_eq!(out.behaviour, Behaviour::RequestHeading);
    assert!(out.messages.contains(&ScooterSay::RequestHeading));
    assert_eq!(out.command, VelocityCommand::ZERO);
    let f = form(
        vec![rec("scooter", 0.0, None, t(0)), rec(RED, 179.0, None, t(0))],
        t(0),
    );
    assert!(b.handle_ses(&f, t(100)));
    b.handle_compass(b.desired_heading().unwrap(), t(150));
    let out = b.step(t(200));
    assert_eq!(out.behaviour, Behaviour::FollowHeading);
    // 13 s later: stale (lost_after 12 s), requests again, coasts on the old heading.
    let out = b.step(t(13_200));
    assert_eq!(out.behaviour, Behaviour::RequestHeading);
    assert!(out.messages.contains(&ScooterSay::RequestHeading));
    assert!(out.command.v_m_s > 0.0, "coasting");
    // Not re-requested before another 12 s.
    let out = b.step(t(14_000));
    assert!(!out.messages.contains(&ScooterSay::RequestHeading));
    let out = b.step(t(25_300));
    assert!(out.messages.contains(&ScooterSay::RequestHeading));
    // Past coast_for (30 s after the sample): stand still.
    let out = b.step(t(31_000));
    assert_eq!(out.behaviour, Behaviour::RequestHeading);
    assert_eq!(out.command, VelocityCommand::ZERO);
}

#[test]
fn called_back_goes_home_until_found() {
    let mut b = brain(HeadingRule::Thesis);
    b.set_target(RED, t(0));
    // Skeeter sees Scooter at 90°: home is at 270° = −90° from Scooter.
    let f = form(
        vec![rec("scooter", 90.0, None, t(0)), rec(RED, 0.0, None, t(0))],
        t(0),
    );
    b.handle_ses(&f, t(0));
    b.step(t(0));
    b.handle_broadcast(
        &Broadcast::emergency("skeeter", Emergency::ScooterLost),
        t(100),
    );
    let out = b.step(t(100));
    assert_eq!(out.behaviour, Behaviour::MoveToHome);
    assert!(
        out.command.omega_rad_s < 0.0,
        "turning clockwise toward −90°"
    );
    b.handle_broadcast(
        &Broadcast::emergency("skeeter", Emergency::ScooterFound),
        t(200),
    );
    let out = b.step(t(200));
    assert_eq!(out.behaviour, Behaviour::FollowHeading);
}

#[test]
fn homing_with_ranges_stops_short_of_skeeter() {
    let mut b = brain(HeadingRule::RangeAware);
    b.set_target(RED, t(0));
    let f = form(
        vec![
            rec("scooter", 0.0, Some(1.0), t(0)),
            rec(RED, 90.0, Some(3.0), t(0)),
        ],
        t(0),
    );
    b.handle_ses(&f, t(0));
    b.handle_heard(&ScooterHeard::ScooterLost, t(0));
    let out = b.step(t(0));
    assert_eq!(out.behaviour, Behaviour::MoveToHome);
    assert_eq!(
        out.command,
        VelocityCommand::ZERO,
        "1 m < home_stop_distance"
    );
}

#[test]
fn answers_target_queries_and_keeps_moving() {
    let mut b = brain(HeadingRule::Thesis);
    b.set_target(RED, t(0));
    let f = form(
        vec![rec("scooter", 0.0, None, t(0)), rec(RED, 175.0, None, t(0))],
        t(0),
    );
    b.handle_ses(&f, t(0));
    b.handle_compass(b.desired_heading().unwrap(), t(0));
    let out = b.step(t(0));
    assert_eq!(out.behaviour, Behaviour::FollowHeading);
    let q = Broadcast::emergency(
        "skeeter",
        Emergency::TargetQuery {
            colour: RED.to_owned(),
        },
    );
    assert!(b.handle_broadcast(&q, t(50)));
    let out = b.step(t(50));
    assert_eq!(out.behaviour, Behaviour::ReplyTargetQuery);
    // Not in the laser's sight, but a fresh plan for red: "yes" (Scooter may simply be
    // hiding the target from Skeeter).
    assert!(out.messages.contains(&ScooterSay::TargetReply {
        colour: RED.to_owned(),
        seen: true
    }));
    assert!(out.command.v_m_s > 0.0, "replying does not stop the wheels");
    let out = b.step(t(100));
    assert_eq!(out.behaviour, Behaviour::FollowHeading);
    // Unknown colour, no target in view: no.
    b.handle_heard(
        &ScooterHeard::TargetQuery {
            colour: "blue".to_owned(),
        },
        t(150),
    );
    let out = b.step(t(150));
    assert!(out.messages.contains(&ScooterSay::TargetReply {
        colour: "blue".to_owned(),
        seen: false
    }));
    // The plan gone stale (no sample with red for lost_after = 12 s): no.
    b.handle_heard(
        &ScooterHeard::TargetQuery {
            colour: RED.to_owned(),
        },
        t(12_100),
    );
    let out = b.step(t(12_100));
    assert!(out.messages.contains(&ScooterSay::TargetReply {
        colour: RED.to_owned(),
        seen: false
    }));
}

#[test]
fn finds_the_target_with_the_laser_notifies_until_the_outcome_and_stops() {
    let mut b = brain(HeadingRule::RangeAware);
    b.set_target(RED, t(0));
    // Scooter at (−1.5, 0) facing +x; target at (−0.5, 0) — 1 m ahead.
    let f = form(
        vec![
            rec("scooter", 180.0, Some(1.5), t(0)),
            rec(RED, 180.0, Some(0.5), t(0)),
        ],
        t(0),
    );
    b.handle_ses(&f, t(0));
    let mut w = Mini {
        x: -1.5,
        y: 0.0,
        th: 0.0,
        circles: vec![([-0.5, 0.0], 0.15)],
    };
    let mount = b.config().laser_mount;
    b.handle_laser(&w.scan(&mount), t(0));
    let out = b.step(t(0));
    assert_eq!(out.behaviour, Behaviour::MoveToTarget);
    let mut reached: Vec<u64> = Vec::new();
    let mut now = 0;
    for _ in 0..400 {
        now += 50;
        let first = b.step(t(now));
        w.advance(first.command, 0.05);
        b.handle_odometry(&w.odo((-1.5, 0.0, 0.0)), t(now));
        b.handle_laser(&w.scan(&mount), t(now));
        let mut out = b.step(t(now));
        out.messages.extend(first.messages);
        if out
            .messages
            .iter()
            .any(|m| matches!(m, ScooterSay::TargetReached { .. }))
        {
            reached.push(now);
        }
        if b.reached() {
            assert_eq!(out.behaviour, Behaviour::NotifySkeeter);
            assert_eq!(out.command, VelocityCommand::ZERO);
        }
    }
    // Sent when reached, then again every status period (1 s): it may be lost.
    assert!(reached.len() >= 3, "{reached:?}");
    for w2 in reached.windows(2) {
        assert!((1000..=1050).contains(&(w2[1] - w2[0])), "{reached:?}");
    }
    let d = (w.x + 0.5).hypot(w.y);
    assert!(d <= b.config().reach_distance_m + 0.05 && d > 0.55, "{d}");
    // Skeeter's echo of the acceptance (a commander poll) does not restart the target.
    b.handle_heard(
        &ScooterHeard::TargetAccepted {
            colour: RED.to_owned(),
        },
        t(now + 10),
    );
    assert!(b.reached());
    // The outcome ends the repeats.
    b.handle_heard(
        &ScooterHeard::MissionEnded {
            colour: RED.to_owned(),
        },
        t(now + 20),
    );
    for k in 1..40 {
        let out = b.step(t(now + 50 * k));
        assert_eq!(out.behaviour, Behaviour::Idle);
        assert_eq!(out.command, VelocityCommand::ZERO);
        assert!(
            out.messages
                .iter()
                .all(|m| matches!(m, ScooterSay::Status { .. }))
        );
    }
}

/// Issue 13: right after a target, a stale SES (or heading) pointing at the object
/// Scooter stands next to must not make that object the next target.
#[test]
fn the_target_just_reached_is_not_the_next_one() {
    let mut b = brain(HeadingRule::RangeAware);
    b.set_target(RED, t(0));
    let ses = |colour: &str, at: u64| {
        form(
            vec![
                rec("scooter", 180.0, Some(1.5), t(at)),
                rec(colour, 180.0, Some(0.5), t(at)),
            ],
            t(at),
        )
    };
    b.handle_ses(&ses(RED, 0), t(0));
    let mut w = Mini {
        x: -1.5,
        y: 0.0,
        th: 0.0,
        circles: vec![([-0.5, 0.0], 0.15)],
    };
    let mount = b.config().laser_mount;
    let mut now = 0;
    while !b.reached() && now < 20_000 {
        now += 50;
        let out = b.step(t(now));
        w.advance(out.command, 0.05);
        b.handle_odometry(&w.odo((-1.5, 0.0, 0.0)), t(now));
        b.handle_laser(&w.scan(&mount), t(now));
    }
    assert!(b.reached(), "red reached");
    b.handle_heard(
        &ScooterHeard::MissionEnded {
            colour: RED.to_owned(),
        },
        t(now + 10),
    );
    b.handle_heard(
        &ScooterHeard::TargetAccepted {
            colour: "blue".to_owned(),
        },
        t(now + 20),
    );
    // The SES says blue is where red is (Scooter has not moved since).
    b.handle_ses(&ses("blue", now + 20), t(now + 20));
    for k in 1..40 {
        let at = now + 20 + 50 * k;
        b.handle_laser(&w.scan(&mount), t(at));
        let out = b.step(t(at));
        assert!(
            !out.messages
                .iter()
                .any(|m| matches!(m, ScooterSay::TargetReached { .. })),
            "red taken for blue at {at} ms"
        );
    }
    assert!(!b.reached());
    // A second red target is red again.
    b.handle_heard(
        &ScooterHeard::TargetAccepted {
            colour: RED.to_owned(),
        },
        t(now + 5000),
    );
    b.handle_ses(&ses(RED, now + 5000), t(now + 5000));
    b.handle_laser(&w.scan(&mount), t(now + 5050));
    b.step(t(now + 5050));
    assert!(b.reached(), "the same colour again is found at once");
}

#[test]
fn a_new_target_stops_the_target_reached_repeats() {
    let mut b = brain(HeadingRule::RangeAware);
    b.set_target(RED, t(0));
    b.reached = true;
    let out = b.step(t(0));
    assert!(out.messages.contains(&ScooterSay::TargetReached {
        colour: RED.to_owned()
    }));
    b.handle_heard(
        &ScooterHeard::TargetAccepted {
            colour: "blue".to_owned(),
        },
        t(500),
    );
    for k in 1..60 {
        let out = b.step(t(500 + 50 * k));
        assert!(
            !out.messages
                .iter()
                .any(|m| matches!(m, ScooterSay::TargetReached { .. }))
        );
    }
}

#[test]
fn a_fresh_scooter_record_ends_a_call_back_when_scooter_found_is_lost() {
    let mut b = brain(HeadingRule::Thesis);
    b.set_target(RED, t(0));
    let f = form(
        vec![rec("scooter", 90.0, None, t(0)), rec(RED, 0.0, None, t(0))],
        t(0),
    );
    b.handle_ses(&f, t(0));
    b.handle_heard(&ScooterHeard::ScooterLost, t(100));
    assert_eq!(b.step(t(100)).behaviour, Behaviour::MoveToHome);
    // A sample without Scooter (or with a stale record) keeps it homing.
    b.handle_ses(&form(vec![rec(RED, 0.0, None, t(200))], t(200)), t(200));
    assert_eq!(b.step(t(200)).behaviour, Behaviour::MoveToHome);
    let stale = form(vec![rec("scooter", 90.0, None, t(300))], t(20_300));
    b.handle_ses(&stale, t(20_300));
    assert_eq!(b.step(t(20_300)).behaviour, Behaviour::MoveToHome);
    // `scooter-found` was lost, but the next sample holds a fresh Scooter record.
    let f = form(vec![rec("scooter", 90.0, None, t(20_400))], t(20_500));
    b.handle_ses(&f, t(20_500));
    assert_ne!(b.step(t(20_500)).behaviour, Behaviour::MoveToHome);
    assert!(!b.san_summary().contains("called-back"));
}

#[test]
fn range_aware_rule_ranges_skeeter_with_the_laser() {
    let mut b = brain(HeadingRule::RangeAware);
    b.set_target(RED, t(0));
    // Bearings only: Scooter at 180°, target at 90°.
    let f0 = form(
        vec![
            rec("scooter", 180.0, None, t(0)),
            rec(RED, 90.0, Some(3.0), t(0)),
        ],
        t(0),
    );
    b.handle_ses(&f0, t(0));
    assert!(matches!(b.plan(), Some(Plan::Heading(_))));
    // Scooter at (−2.5, 0) facing +x sees Skeeter (r 0.33) at the origin.
    let w = Mini {
        x: -2.5,
        y: 0.0,
        th: 0.0,
        circles: vec![([0.0, 0.0], 0.33)],
    };
    b.handle_laser(&w.scan(&b.config().laser_mount), t(100));
    let f1 = form(
        vec![
            rec("scooter", 180.0, None, t(200)),
            rec(RED, 90.0, Some(3.0), t(200)),
        ],
        t(200),
    );
    b.handle_ses(&f1, t(200));
    // Target (0, 3) from Scooter (−2.5, 0): DR (2.5, 3).
    match b.plan() {
        Some(Plan::Point(p)) => assert!((p - Vector2::new(2.5, 3.0)).norm() < 0.05, "{p}"),
        other => panic!("{other:?}"),
    }
}

#[test]
fn a_post_off_the_expected_position_is_not_the_target() {
    let mut b = brain(HeadingRule::RangeAware);
    b.set_target(RED, t(0));
    let f = form(
        vec![
            rec("scooter", 180.0, Some(3.0), t(0)),
            rec(RED, 90.0, Some(3.0), t(0)),
        ],
        t(0),
    );
    b.handle_ses(&f, t(0));
    // A post 1 m straight ahead; the target is expected up and to the left.
    let w = Mini {
        x: -3.0,
        y: 0.0,
        th: 0.0,
        circles: vec![([-2.0, 0.0], 0.15)],
    };
    b.handle_laser(&w.scan(&b.config().laser_mount), t(0));
    let out = b.step(t(0));
    assert_ne!(out.behaviour, Behaviour::MoveToTarget);
}

/// Drive past a barrel standing on the straight path to the target: the avoider takes
/// over, the turn rate's sign changes at most twice (away, then back), no collision, and
/// the target is reached.
#[test]
fn avoids_an_obstacle_smoothly_and_resumes() {
    let mut b = brain(HeadingRule::RangeAware);
    b.set_target(RED, t(0));
    // Scooter at (−4, 0) facing +x, target at (1, 0.0), barrel (r 0.3) at (−1.5, 0.05).
    let f = form(
        vec![
            rec("scooter", 180.0, Some(4.0), t(0)),
            rec(RED, 0.0, Some(1.0), t(0)),
        ],
        t(0),
    );
    b.handle_ses(&f, t(0));
    let mut w = Mini {
        x: -4.0,
        y: 0.0,
        th: 0.0,
        circles: vec![([1.0, 0.0], 0.15), ([-1.5, 0.05], 0.3)],
    };
    let mount = b.config().laser_mount;
    let mut now = 0;
    let mut omegas = Vec::new();
    let mut saw_avoid = false;
    let mut min_clear = f64::INFINITY;
    for _ in 0..1200 {
        now += 50;
        b.handle_odometry(&w.odo((-4.0, 0.0, 0.0)), t(now));
        b.handle_compass(w.th, t(now));
        b.handle_laser(&w.scan(&mount), t(now));
        let out = b.step(t(now));
        if out.behaviour == Behaviour::AvoidObstacle {
            saw_avoid = true;
        }
        if out.command.omega_rad_s.abs() > 0.02 {
            omegas.push(out.command.omega_rad_s.signum());
        }
        w.advance(out.command, 0.05);
        min_clear = min_clear.min((w.x + 1.5).hypot(w.y - 0.05) - 0.3 - 0.4);
        if b.reached() {
            break;
        }
        // A new sample every 5 s, exact.
        if now % 5000 == 0 {
            let (sx, sy) = (w.x, w.y);
            let f = form(
                vec![
                    rec(
                        "scooter",
                        sy.atan2(sx).to_degrees(),
                        Some(sx.hypot(sy)),
                        t(now),
                    ),
                    rec(RED, 0.0, Some(1.0), t(now)),
                ],
                t(now),
            );
            b.handle_ses(&f, t(now));
        }
    }
    assert!(saw_avoid, "the barrel triggered avoid-obstacle");
    assert!(b.reached(), "target reached after the detour");
    assert!(min_clear > 0.0, "no collision: clearance {min_clear}");
    let flips = omegas.windows(2).filter(|p| p[0] != p[1]).count();
    assert!(
        flips <= 3,
        "turn-rate sign flipped {flips} times: {omegas:?}"
    );
}

/// A wall of posts across the way with the target just behind it: going round the
/// wall's end takes the target more than 90° off Scooter's nose. The avoider keeps its
/// side locked until the target is in view and free, so the turn rate does not chatter.
#[test]
fn goes_round_a_wide_obstacle_without_turn_rate_chatter() {
    let mut b = brain(HeadingRule::RangeAware);
    b.set_target(RED, t(0));
    // Scooter at (−4, 0) facing +x; a wall of posts at x = −1.5, y ∈ [−2.5, 1.5];
    // the target at (−0.6, 0).
    let target = [-0.6, 0.0];
    let sample = |now: u64, sx: f64, sy: f64| {
        form(
            vec![
                rec(
                    "scooter",
                    sy.atan2(sx).to_degrees(),
                    Some(sx.hypot(sy)),
                    t(now),
                ),
                rec(RED, 180.0, Some(0.6), t(now)),
            ],
            t(now),
        )
    };
    b.handle_ses(&sample(0, -4.0, 0.0), t(0));
    let mut circles = vec![(target, 0.15)];
    for k in 0..=20 {
        circles.push(([-1.5, -2.5 + f64::from(k) * 0.2], 0.12));
    }
    let mut w = Mini {
        x: -4.0,
        y: 0.0,
        th: 0.0,
        circles,
    };
    let mount = b.config().laser_mount;
    let mut now = 0;
    let mut omegas = Vec::new();
    let mut out_of_view = false;
    for _ in 0..4000 {
        now += 50;
        b.handle_odometry(&w.odo((-4.0, 0.0, 0.0)), t(now));
        b.handle_compass(w.th, t(now));
        b.handle_laser(&w.scan(&mount), t(now));
        let out = b.step(t(now));
        let g = normalize_angle((target[1] - w.y).atan2(target[0] - w.x) - w.th);
        if out.behaviour == Behaviour::AvoidObstacle && g.abs() > PI / 2.0 {
            out_of_view = true;
        }
        if out.command.omega_rad_s.abs() > 0.02 {
            omegas.push(out.command.omega_rad_s.signum());
        }
        w.advance(out.command, 0.05);
        for (c, r) in w.circles.iter().skip(1) {
            let clear = (w.x - c[0]).hypot(w.y - c[1]) - r - 0.4;
            assert!(clear > 0.0, "hit a post at {:.2},{:.2}", w.x, w.y);
        }
        if b.reached() {
            break;
        }
        if now % 5000 == 0 {
            b.handle_ses(&sample(now, w.x, w.y), t(now));
        }
    }
    assert!(out_of_view, "the detour took the target out of view");
    assert!(
        b.reached(),
        "target reached round the wall: at {:.2},{:.2}",
        w.x,
        w.y
    );
    let flips = omegas.windows(2).filter(|p| p[0] != p[1]).count();
    assert!(
        flips <= 4,
        "turn-rate sign flipped {flips} times: {omegas:?}"
    );
}

#[test]
fn heading_sources_compass_odometry_fused() {
    let mk = |src| {
        let mut b = ScooterBrain::new(ScooterConfig {
            heading_source: src,
            fusion_gain: 0.5,
            odometry_heading_offset_rad: 0.1,
            ..ScooterConfig::default()
        });
        b.handle_odometry(&Odometry::origin(), t(0));
        b.handle_compass(0.3, t(0));
        b.handle_odometry(
            &Odometry {
                pose: Isometry2::new(Vector2::zeros(), 0.2),
                ..Odometry::origin()
            },
            t(10),
        );
        b.handle_compass(0.5, t(20));
        b.heading().unwrap()
    };
    assert!((mk(HeadingSource::Compass) - 0.5).abs() < 1e-12);
    assert!((mk(HeadingSource::Odometry) - 0.3).abs() < 1e-12);
    // Fused: starts at the odometry heading 0.1, +0.2 odometry turn… then the compass
    // pulls: first reading 0.3 → 0.1 + 0.5·0.2 = 0.2; +0.2 → 0.4; reading 0.5 → 0.45.
    assert!((mk(HeadingSource::Fused) - 0.45).abs() < 1e-12);
}

#[test]
fn dead_reckoning_rotates_odometry_by_the_heading() {
    let mut b = brain(HeadingRule::Thesis);
    b.handle_compass(PI / 2.0, t(0));
    b.handle_odometry(
        &Odometry {
            pose: Isometry2::new(Vector2::new(1.0, 0.0), 0.0),
            ..Odometry::origin()
        },
        t(100),
    );
    // Odometry says 1 m forward; the compass says we face +y.
    assert!((b.dr_position() - Vector2::new(0.0, 1.0)).norm() < 1e-12);
}

#[test]
fn turn_in_place_hysteresis() {
    let mut b = brain(HeadingRule::Thesis);
    b.set_target(RED, t(0));
    let f = form(
        vec![rec("scooter", 0.0, None, t(0)), rec(RED, 90.0, None, t(0))],
        t(0),
    );
    b.handle_ses(&f, t(0));
    // θd = 135°. Error 135°: in place.
    assert_eq!(b.step(t(0)).command.v_m_s, 0.0);
    // Error 20° (< enter 30°) but still > exit 8°: still in place.
    b.handle_compass(115f64.to_radians(), t(50));
    assert_eq!(b.step(t(50)).command.v_m_s, 0.0);
    // Error 5°: drive; then 20° again: keeps driving (below enter).
    b.handle_compass(130f64.to_radians(), t(100));
    assert!(b.step(t(100)).command.v_m_s > 0.0);
    b.handle_compass(115f64.to_radians(), t(150));
    assert!(b.step(t(150)).command.v_m_s > 0.0);
}

#[test]
fn laser_clusters_measure_width_and_centre() {
    let w = Mini {
        x: 0.0,
        y: 0.0,
        th: 0.0,
        circles: vec![([1.2, 0.0], 0.15), ([1.5, 1.5], 0.4)],
    };
    let mount = Isometry2::new(Vector2::new(0.2, 0.0), 0.0);
    let cs = laser_clusters(&w.scan(&mount), &mount, 8.0, 0.1, 0.15);
    let c = cs
        .iter()
        .find(|c| (c.centre - Point2::new(1.2, 0.0)).norm() < 0.05)
        .unwrap();
    assert!((c.width_m - 0.3).abs() < 0.1, "{c:?}");
    assert!(cs.iter().any(|c| c.width_m > 0.5));
}

#[test]
fn broadcast_mapping_both_ways() {
    let acc = Broadcast::new_target(RED);
    assert_eq!(
        ScooterHeard::from_broadcast(&acc, "scooter"),
        Some(ScooterHeard::TargetAccepted {
            colour: RED.to_owned()
        })
    );
    let done = Broadcast::mission("skeeter", MissionEvent::Accomplished, RED);
    assert_eq!(
        ScooterHeard::from_broadcast(&done, "scooter"),
        Some(ScooterHeard::MissionEnded {
            colour: RED.to_owned()
        })
    );
    let own = Broadcast::emergency(
        "scooter",
        Emergency::TargetReached {
            colour: RED.to_owned(),
        },
    );
    assert_eq!(ScooterHeard::from_broadcast(&own, "scooter"), None);
    let cancel = Broadcast::emergency(
        "commander",
        Emergency::TargetCancel {
            colour: RED.to_owned(),
        },
    );
    assert_eq!(
        ScooterHeard::from_broadcast(&cancel, "scooter"),
        Some(ScooterHeard::MissionEnded {
            colour: RED.to_owned()
        })
    );
    let stop = Broadcast::emergency(
        "commander",
        Emergency::FleetStop {
            reason: String::new(),
        },
    );
    assert_eq!(ScooterHeard::from_broadcast(&stop, "scooter"), None);
    let say = ScooterSay::TargetReply {
        colour: RED.to_owned(),
        seen: true,
    };
    let b = say.to_broadcast("scooter", "").unwrap();
    assert_eq!(b.to_wire(1).code(), b.to_wire(2).code());
    match b {
        Broadcast::Emergency { emergency, .. } => assert_eq!(emergency.text(), "red yes"),
        other => panic!("{other:?}"),
    }
    assert_eq!(ScooterSay::RequestHeading.to_broadcast("scooter", ""), None);
    let st = ScooterSay::Status {
        behaviour: Behaviour::AvoidObstacle,
        pose: (1.0, -2.0, 0.5),
    }
    .to_broadcast("scooter", "path-clear");
    match st {
        Some(Broadcast::Status {
            behaviour, pose, ..
        }) => {
            assert_eq!(behaviour, "avoid-obstacle");
            assert_eq!(
                pose,
                Some(Pose {
                    x_mm: 1000,
                    y_mm: -2000,
                    theta_mrad: 500
                })
            );
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn mission_end_of_another_colour_is_ignored_and_repeated_acceptance_does_not_restart() {
    let mut b = brain(HeadingRule::Thesis);
    b.handle_heard(
        &ScooterHeard::TargetAccepted {
            colour: RED.to_owned(),
        },
        t(0),
    );
    let f = form(
        vec![rec("scooter", 0.0, None, t(0)), rec(RED, 90.0, None, t(0))],
        t(0),
    );
    b.handle_ses(&f, t(0));
    b.handle_heard(
        &ScooterHeard::TargetAccepted {
            colour: RED.to_owned(),
        },
        t(10),
    );
    assert!(
        b.plan().is_some(),
        "Skeeter's echo of the acceptance keeps the plan"
    );
    b.handle_heard(
        &ScooterHeard::MissionEnded {
            colour: "blue".to_owned(),
        },
        t(20),
    );
    assert_eq!(b.target(), Some(RED));
    b.handle_heard(
        &ScooterHeard::MissionEnded {
            colour: RED.to_owned(),
        },
        t(30),
    );
    assert_eq!(b.target(), None);
    assert_eq!(b.step(t(40)).behaviour, Behaviour::Idle);
}

/// Under load (`tests/demo_seeds.rs`, seed 1): Skeeter's scans came every 15–18 s, so the
/// sample the runtime replayed to a new target was 5 s old, and its Scooter record had no
/// range (the range of that sighting had been triangulated from the sample before). Handled
/// as if Scooter had been seen at the replay's `now`, the sighting was placed at Scooter's
/// current position and its two fixes triangulated nothing: the plan fell back to a bearing
/// heading from where Scooter had been, 20° off blue, and the laser took the green post
/// beside that heading for blue — "done" 3 m from blue. The same sighting handled again
/// keeps its position and range: the plan is blue's point, and Scooter stops at blue.
#[test]
fn a_replayed_sample_keeps_its_sighting_and_scooter_stops_at_the_right_post() {
    const BLUE: &str = "blue";
    let mut b = brain(HeadingRule::RangeAware);
    // Common frame: Skeeter at (0, 0); red (3, 0), green (1.5, 2.6), blue (−1.5, 2.6).
    // Scooter starts at (−4, 0) facing 0: DR = common − (−4, 0).
    let start = (-4.0, 0.0, 0.0);
    let dr_of = |x: f64, y: f64| Vector2::new(x - start.0, y - start.1);
    let posts = [
        ([3.0, 0.0], 0.15),
        ([1.5, 2.598], 0.15),
        ([-1.5, 2.598], 0.15),
        ([0.0, 0.0], 0.33),
    ];
    let sample = |scooter: (f64, Option<f64>), colour: &str, bearing: f64, ms: u64| {
        form(
            vec![
                rec("scooter", scooter.0, scooter.1, t(ms)),
                rec(colour, bearing, Some(3.0), t(ms)),
            ],
            t(ms),
        )
    };
    b.set_target(RED, t(0));
    assert!(b.handle_ses(&sample((180.0, Some(4.0)), RED, 0.0, 0), t(0)));
    // Scooter drives (odometry only) to (1, −1), where Skeeter sees it at −45°, no range.
    let mut w = Mini {
        x: start.0,
        y: start.1,
        th: start.2,
        circles: Vec::new(),
    };
    for k in 1..=100u32 {
        let f = f64::from(k) / 100.0;
        w.x = -4.0 + 5.0 * f;
        w.y = -f;
        w.th = (-1f64).atan2(5.0);
        b.handle_compass(w.th, t(u64::from(k) * 100));
        b.handle_odometry(&w.odo(start), t(u64::from(k) * 100));
    }
    let red = sample((-45.0, None), RED, 0.0, 10_000);
    assert!(b.handle_ses(&red, t(10_000)));
    match b.plan() {
        Some(Plan::Point(p)) => assert!((p - dr_of(3.0, 0.0)).norm() < 0.05, "{p}"),
        other => panic!("red: {other:?}"),
    }
    // On to (2.2, −0.3), next to red; red is done, blue is next, and the runtime replays
    // the latest sample (5 s old; it holds blue too) at the new target's time.
    for k in 1..=50u32 {
        let f = f64::from(k) / 50.0;
        w.x = 1.0 + 1.2 * f;
        w.y = -1.0 + 0.7 * f;
        w.th = 0.7f64.atan2(1.2);
        b.handle_compass(w.th, t(10_000 + u64::from(k) * 100));
        b.handle_odometry(&w.odo(start), t(10_000 + u64::from(k) * 100));
    }
    let mut replay = red.clone();
    replay.records.push(rec(BLUE, 120.0, Some(3.0), t(10_000)));
    b.handle_heard(
        &ScooterHeard::MissionEnded {
            colour: RED.to_owned(),
        },
        t(15_000),
    );
    b.handle_heard(
        &ScooterHeard::TargetAccepted {
            colour: BLUE.to_owned(),
        },
        t(15_000),
    );
    assert!(b.handle_ses(&replay, t(15_000)));
    match b.plan() {
        Some(Plan::Point(p)) => assert!((p - dr_of(-1.5, 2.598)).norm() < 0.1, "{p}"),
        other => panic!("blue from the replayed sample: {other:?}"),
    }
    // Closed loop among the posts: Scooter reaches blue, not green.
    w.circles = posts.to_vec();
    let mount = b.config().laser_mount;
    let mut now = 15_000;
    while !b.reached() && now < 75_000 {
        now += 50;
        b.handle_compass(w.th, t(now));
        b.handle_odometry(&w.odo(start), t(now));
        b.handle_laser(&w.scan(&mount), t(now));
        let out = b.step(t(now));
        w.advance(out.command, 0.05);
    }
    assert!(
        b.reached(),
        "blue not reached; Scooter at ({}, {})",
        w.x,
        w.y
    );
    let gap = (w.x + 1.5).hypot(w.y - 2.598);
    assert!(
        gap < 1.2,
        "reached 'blue' {gap:.2} m from it, at ({}, {})",
        w.x,
        w.y
    );
}

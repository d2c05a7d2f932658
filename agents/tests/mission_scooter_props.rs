//! Property test of Scooter's brain: whatever it is fed — NaN or infinite bearings and
//! ranges in an SES sample, NaN/inf odometry or compass readings, broken laser scans, any
//! broadcast — every velocity command is finite and within the configured limits.

use core::time::Duration;

use ima_agents::mission::msg::{Broadcast, Emergency, MissionEvent};
use ima_agents::mission::scooter::{HeadingRule, HeadingSource, ScooterBrain, ScooterConfig};
use ima_agents::ses::Direction;
use ima_agents::ses::shared::{SharedForm, SharedRecord};
use ima_hal::base::Odometry;
use ima_hal::laser::{BeamFlags, LaserScan};
use ima_hal::{Instant, Isometry2, Vector2};
use proptest::prelude::*;

/// A float that is often ordinary and sometimes NaN, ±inf, huge or tiny.
fn wild() -> impl Strategy<Value = f64> {
    prop_oneof![
        6 => -10.0f64..10.0,
        1 => Just(f64::NAN),
        1 => Just(f64::INFINITY),
        1 => Just(f64::NEG_INFINITY),
        1 => Just(1e300),
        1 => Just(-1e300),
        1 => Just(f64::MAX),
        1 => Just(-f64::MAX),
        1 => Just(f64::MIN_POSITIVE),
        1 => any::<f64>(),
    ]
}

fn wild_f32() -> impl Strategy<Value = f32> {
    prop_oneof![
        6 => 0.0f32..9.0,
        1 => Just(f32::NAN),
        1 => Just(f32::INFINITY),
        1 => Just(-1.0f32),
        1 => any::<f32>(),
    ]
}

#[derive(Debug, Clone)]
enum Input {
    Odometry(f64, f64, f64),
    Compass(f64),
    Ses {
        scout: (f64, Option<f64>),
        target: (f64, Option<f64>),
        age_ms: u64,
    },
    Laser(Vec<(f32, bool)>),
    Broadcast(u8),
    Step(u64),
}

fn input() -> impl Strategy<Value = Input> {
    prop_oneof![
        1 => (wild(), wild(), wild()).prop_map(|(x, y, t)| Input::Odometry(x, y, t)),
        1 => wild().prop_map(Input::Compass),
        1 => (
            (wild(), proptest::option::of(wild())),
            (wild(), proptest::option::of(wild())),
            0u64..20_000,
        )
            .prop_map(|(scout, target, age_ms)| Input::Ses {
                scout,
                target,
                age_ms
            }),
        1 => proptest::collection::vec((wild_f32(), any::<bool>()), 0..40).prop_map(Input::Laser),
        1 => (0u8..6).prop_map(Input::Broadcast),
        3 => (0u64..3_000).prop_map(Input::Step),
    ]
}

fn record(object: &str, (bearing, range): (f64, Option<f64>), time: Instant) -> SharedRecord {
    SharedRecord {
        object: object.to_owned(),
        // Built directly (not normalised) so that NaN and inf get through.
        bearing: Direction {
            azimuth_rad: bearing,
            elevation_rad: 0.0,
        },
        range_m: range,
        confidence: 1.0,
        time,
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn commands_are_always_finite_and_within_limits(
        rule in prop_oneof![Just(HeadingRule::Thesis), Just(HeadingRule::RangeAware)],
        source in prop_oneof![
            Just(HeadingSource::Compass),
            Just(HeadingSource::Odometry),
            Just(HeadingSource::Fused)
        ],
        inputs in proptest::collection::vec(input(), 1..120),
    ) {
        let cfg = ScooterConfig {
            heading_rule: rule,
            heading_source: source,
            ..ScooterConfig::default()
        };
        let (max_v, max_w) = (cfg.cruise_speed_m_s, cfg.max_turn_rate_rad_s);
        let mut b = ScooterBrain::new(cfg);
        b.set_target("red", Instant::ZERO);
        let mut now = Instant::ZERO;
        for i in inputs {
            match i {
                Input::Odometry(x, y, th) => {
                    let odo = Odometry {
                        pose: Isometry2::new(Vector2::new(x, y), th),
                        v_m_s: 0.0,
                        omega_rad_s: 0.0,
                    };
                    b.handle_odometry(&odo, now);
                }
                Input::Compass(h) => b.handle_compass(h, now),
                Input::Ses { scout, target, age_ms } => {
                    let time = Instant::from_micros(
                        now.as_micros().saturating_sub(age_ms * 1000),
                    );
                    let form = SharedForm {
                        source_robot: "skeeter".to_owned(),
                        sent_at: now,
                        records: vec![record("scooter", scout, time), record("red", target, time)],
                    };
                    b.handle_ses(&form, now);
                }
                Input::Laser(beams) => {
                    let mut scan = LaserScan::new(-core::f64::consts::FRAC_PI_2, 0.1);
                    for (r, ok) in beams {
                        let flags = if ok { BeamFlags::VALID } else { BeamFlags::NO_RETURN };
                        let _ = scan.push(r, flags);
                    }
                    b.handle_laser(&scan, now);
                }
                Input::Broadcast(k) => {
                    let msg = match k {
                        0 => Broadcast::emergency("skeeter", Emergency::ScooterLost),
                        1 => Broadcast::emergency("skeeter", Emergency::ScooterFound),
                        2 => Broadcast::emergency(
                            "skeeter",
                            Emergency::TargetQuery { colour: "red".into() },
                        ),
                        3 => Broadcast::mission("skeeter", MissionEvent::Accepted, "red"),
                        4 => Broadcast::mission("skeeter", MissionEvent::Accomplished, "red"),
                        _ => Broadcast::mission("commander", MissionEvent::Accepted, "blue"),
                    };
                    b.handle_broadcast(&msg, now);
                }
                Input::Step(ms) => {
                    now = now + Duration::from_millis(ms);
                    let out = b.step(now);
                    let c = out.command;
                    prop_assert!(c.v_m_s.is_finite() && c.omega_rad_s.is_finite(), "{c:?}");
                    prop_assert!((0.0..=max_v).contains(&c.v_m_s), "{c:?}");
                    prop_assert!(c.omega_rad_s.abs() <= max_w, "{c:?}");
                    for m in out.messages {
                        // Every broadcast Scooter says can be sent.
                        if let Some(bc) = m.to_broadcast("scooter", &b.san_summary()) {
                            let w = bc.to_wire(1);
                            let mut buf = [0u8; 2048];
                            prop_assert!(w.emit_body(&mut buf).is_ok());
                        }
                    }
                }
            }
        }
    }
}

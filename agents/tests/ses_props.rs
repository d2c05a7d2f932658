//! Property tests of the SES dome and store.

use ima_agents::ses::shared::SharedForm;
use ima_agents::ses::{Direction, Dome, Payload, Ses, SesConfig, Vec3};
use ima_hal::Instant;
use proptest::prelude::*;
use std::sync::OnceLock;

const FREQS: [u32; 6] = [1, 2, 5, 8, 13, 16];

fn empty_ses() -> Ses {
    static S: OnceLock<Ses> = OnceLock::new();
    S.get_or_init(|| Ses::new(SesConfig::default()).unwrap())
        .clone()
}

fn domes() -> &'static Vec<Dome> {
    static D: OnceLock<Vec<Dome>> = OnceLock::new();
    D.get_or_init(|| FREQS.iter().map(|&n| Dome::new(n).unwrap()).collect())
}

/// Random non-zero query vectors (they need not be unit length).
fn direction() -> impl Strategy<Value = Vec3> {
    (-1.0f64..1.0, -1.0f64..1.0, -1.0f64..1.0)
        .prop_filter("non-zero", |(x, y, z)| x * x + y * y + z * z > 1e-6)
        .prop_map(|(x, y, z)| Vec3::new(x, y, z))
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(3000))]

    /// The greedy walk (from the cube-map hint, and from an arbitrary hint) equals brute force.
    #[test]
    fn nearest_equals_brute_force(d in direction(), which in 0usize..FREQS.len(), hint in any::<u32>()) {
        let dome = &domes()[which];
        let brute = dome.nearest_brute(&d);
        prop_assert_eq!(dome.nearest(&d), brute);
        let hint = hint % dome.len() as u32;
        prop_assert_eq!(dome.nearest_from(&d, hint), brute);
    }

    /// Angles -> vector -> angles is the identity (away from the poles, where azimuth is
    /// undefined).
    #[test]
    fn angles_round_trip(az in -3.1f64..3.1, el in -1.5f64..1.5) {
        let d = Direction::new(az, el);
        let back = Direction::from_vector(&d.to_unit()).unwrap();
        prop_assert!((back.azimuth_rad - d.azimuth_rad).abs() < 1e-12);
        prop_assert!((back.elevation_rad - d.elevation_rad).abs() < 1e-12);
        prop_assert!((d.to_unit().norm() - 1.0).abs() < 1e-12);
    }

    /// Directions exactly on vertices (and near ties between two vertices) still agree.
    #[test]
    fn vertices_and_midpoints_agree(which in 0usize..FREQS.len(), v in any::<u32>()) {
        let dome = &domes()[which];
        let v = v % dome.len() as u32;
        let p = dome.vertex(v).unwrap();
        prop_assert_eq!(dome.nearest(&p), v);
        for &w in dome.neighbours(v) {
            let mid = p + dome.vertex(w).unwrap();
            prop_assert_eq!(dome.nearest(&mid), dome.nearest_brute(&mid));
        }
    }

    /// Whatever is posted is found by direction, tag and time, and the SES shared form
    /// round-trips it within the documented resolution.
    #[test]
    fn posted_entries_are_found(
        posts in proptest::collection::vec((-3.0f64..3.0, -1.5f64..1.5, 0u64..10_000, 0usize..4, 0usize..6), 1..40)
    ) {
        let mut ses = empty_ses();
        for &(az, el, t, tag, src) in &posts {
            let p = Payload {
                object: format!("o{tag}"),
                bearing: Direction::new(az, el),
                range_m: Some(1.5),
                confidence: 0.5,
            };
            ses.post(&format!("t{tag}"), &format!("s{src}"), Instant::from_millis(t), p).unwrap();
        }
        // One entry per distinct (tag, source).
        let mut keys: Vec<(usize, usize)> = posts.iter().map(|p| (p.3, p.4)).collect();
        keys.sort_unstable();
        keys.dedup();
        prop_assert_eq!(ses.len(), keys.len());
        for e in ses.iter() {
            let near = ses.by_direction(e.payload.bearing, 1e-9);
            prop_assert!(near.iter().any(|x| x.tag == e.tag && x.source == e.source));
            prop_assert!(ses.by_tag(&e.tag).iter().any(|x| x.source == e.source));
            prop_assert!(ses.by_time(e.time, e.time).iter().any(|x| x.tag == e.tag && x.source == e.source));
        }
        let form = ses.export_shared("skeeter", Instant::from_millis(20_000), |_| true);
        let back = SharedForm::decode(&form.to_bytes().unwrap()).unwrap();
        prop_assert_eq!(back.records.len(), ses.len());
        for (a, b) in form.records.iter().zip(&back.records) {
            prop_assert!(a.bearing.angle_to(b.bearing) < 1e-4);
            prop_assert_eq!(a.time, b.time);
        }
    }

    /// The parser never panics on arbitrary bytes.
    #[test]
    fn decode_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..200)) {
        ima_agents::fuzz_harness::ses_shared_form(&bytes);
        let mut framed = b"SE\x01\x03abc".to_vec();
        framed.extend_from_slice(&bytes);
        ima_agents::fuzz_harness::ses_shared_form(&framed);
    }
}

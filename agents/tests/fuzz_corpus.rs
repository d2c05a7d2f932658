//! Replay every committed fuzz-corpus file through its harness.

use ima_hal::fuzzing::replay_corpus;

const CORPORA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../fuzz/corpus");

#[test]
fn ses_shared_form_corpus() {
    let h = ima_agents::fuzz_harness::ses_shared_form;
    replay_corpus(CORPORA, "ses_shared_form", h, false).unwrap();
}

/// Writes the seed corpus (run with `--ignored` after a format change).
#[test]
#[ignore = "regenerates fuzz/corpus/ses_shared_form"]
fn write_seed_corpus() {
    use ima_agents::ses::Direction;
    use ima_agents::ses::shared::{SharedForm, SharedRecord};
    use ima_hal::Instant;
    let dir = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../fuzz/corpus/ses_shared_form"
    );
    std::fs::create_dir_all(dir).unwrap();
    let rec = |object: &str, az: f64, el: f64, range: Option<f64>, t: u64| SharedRecord {
        object: object.into(),
        bearing: Direction::new(az, el),
        range_m: range,
        confidence: 0.75,
        time: Instant::from_micros(t),
    };
    let forms = [
        SharedForm {
            source_robot: "skeeter".into(),
            sent_at: Instant::from_micros(5_000_000),
            records: vec![],
        },
        SharedForm {
            source_robot: "skeeter".into(),
            sent_at: Instant::from_micros(5_000_000),
            records: vec![
                rec("red", 0.5, 0.0, Some(3.2), 4_000_000),
                rec("scooter", -2.0, 0.1, None, 5_000_000),
                rec("blue", 3.1, -0.2, Some(655.35), 1_000_000),
            ],
        },
        SharedForm {
            source_robot: "s".repeat(32),
            sent_at: Instant::from_micros(u64::MAX),
            records: vec![rec(&"o".repeat(64), -3.0, 1.5, Some(0.0), u64::MAX - 7)],
        },
    ];
    for (i, f) in forms.iter().enumerate() {
        std::fs::write(format!("{dir}/seed-{i}.bin"), f.to_bytes().unwrap()).unwrap();
    }
    let good = forms[1].to_bytes().unwrap();
    std::fs::write(format!("{dir}/truncated.bin"), &good[..good.len() / 2]).unwrap();
    let mut bad = good.clone();
    let n = bad.len();
    bad[n - 1] ^= 0xFF;
    std::fs::write(format!("{dir}/bad-crc.bin"), &bad).unwrap();
    std::fs::write(format!("{dir}/garbage.bin"), b"\x53\x45\x01\xff\x00\x00").unwrap();
}

const PEER_CORPUS: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../fuzz/corpus/peer_frames");

#[test]
fn peer_frames_corpus() {
    let h = ima_agents::fuzz_harness::peer_frames;
    replay_corpus(CORPORA, "peer_frames", h, false).unwrap();
}

/// Writes the `peer_frames` seed corpus (run with `--ignored` after a format change).
#[test]
#[ignore = "regenerates fuzz/corpus/peer_frames"]
fn write_peer_seed_corpus() {
    use ima_agents::fuzz_harness::PEER_FUZZ_KEY;
    use ima_agents::peer::wire::{
        DeclineReason, DenyReason, GroupKey, MissionEvent, Msg, Pose, RevokeReason, Signer,
        SourceInfo,
    };
    std::fs::create_dir_all(PEER_CORPUS).unwrap();
    let key = GroupKey::new(PEER_FUZZ_KEY).unwrap();
    let s = |n: &str| SourceInfo {
        name: n.into(),
        kind: n.into(),
        schema: 1,
        rate_mhz: 10_000,
    };
    let msgs = vec![
        Msg::Register {
            client: 7,
            robot: "scooter".into(),
        },
        Msg::Unregister { client: 7 },
        Msg::Request {
            client: 7,
            source: "ses".into(),
            priority: 3,
        },
        Msg::Disconnect {
            client: 7,
            source: "ses".into(),
        },
        Msg::Heartbeat,
        Msg::Registered {
            client: 7,
            sources: vec![s("ses"), s("sonar")],
        },
        Msg::Declined {
            client: 7,
            reason: DeclineReason::DuplicateId,
        },
        Msg::Unregistered { client: 7 },
        Msg::Granted {
            client: 7,
            source: "ses".into(),
            address: "10.0.0.7:7401".into(),
            ticket: [5; 32],
        },
        Msg::Pending {
            client: 7,
            source: "ses".into(),
        },
        Msg::Denied {
            client: 7,
            source: "x".into(),
            reason: DenyReason::UnknownSource,
        },
        Msg::Revoked {
            client: 7,
            source: "ses".into(),
            reason: RevokeReason::TaskPriority,
        },
        Msg::SourcesChanged {
            added: vec![s("laser")],
            removed: vec!["sonar".into()],
        },
        Msg::OpenData {
            client: 7,
            source: "ses".into(),
            ticket: [5; 32],
        },
        Msg::DataAccepted {
            source: "ses".into(),
        },
        Msg::DataClosed {
            source: "ses".into(),
            reason: RevokeReason::BadTicket,
        },
        Msg::Sample {
            seq: 1,
            stamp_us: 2,
            payload: vec![1, 2, 3, 4],
        },
        Msg::Status {
            robot: "skeeter".into(),
            seq: 1,
            behaviour: "scan".into(),
            san: "find-red".into(),
            pose: Some(Pose {
                x_mm: 1000,
                y_mm: -20,
                theta_mrad: 1571,
            }),
        },
        Msg::Emergency {
            robot: "skeeter".into(),
            seq: 2,
            kind: "scooter-lost".into(),
            text: "Scooter lost".into(),
        },
        Msg::Mission {
            robot: "skeeter".into(),
            seq: 3,
            event: MissionEvent::Accomplished,
            target: "red".into(),
        },
    ];
    let mut sg = Signer::new(key.clone(), 42, 1);
    for (i, m) in msgs.iter().enumerate() {
        let mut f = vec![0u8];
        f.extend(sg.seal_vec(m).unwrap());
        std::fs::write(
            format!("{PEER_CORPUS}/msg-{i:02x}-{:02x}.bin", m.code()),
            &f,
        )
        .unwrap();
    }
    // Client session streams: register, request, renew, disconnect, unregister (both modes).
    for mode in [0u8, 1, 0x51] {
        let mut sg = Signer::new(key.clone(), 43, 1);
        let mut f = vec![mode];
        for m in [
            Msg::Register {
                client: 1,
                robot: "leader".into(),
            },
            Msg::Request {
                client: 1,
                source: "ses".into(),
                priority: 7,
            },
            Msg::Heartbeat,
            Msg::Request {
                client: 1,
                source: "sonar".into(),
                priority: 1,
            },
            Msg::Disconnect {
                client: 1,
                source: "ses".into(),
            },
            Msg::Unregister { client: 1 },
        ] {
            f.extend(sg.seal_vec(&m).unwrap());
        }
        std::fs::write(format!("{PEER_CORPUS}/stream-{mode:02x}.bin"), &f).unwrap();
    }
    let good = sg.seal_vec(&Msg::Heartbeat).unwrap();
    let mut t = vec![0u8];
    t.extend(&good[..good.len() - 3]);
    std::fs::write(format!("{PEER_CORPUS}/truncated.bin"), &t).unwrap();
    let mut bad = vec![0u8];
    bad.extend(&good);
    let n = bad.len();
    bad[n - 1] ^= 1;
    std::fs::write(format!("{PEER_CORPUS}/bad-mac.bin"), &bad).unwrap();
    let mut v = vec![0u8];
    v.extend(&good);
    v[3] = 9;
    std::fs::write(format!("{PEER_CORPUS}/bad-version.bin"), &v).unwrap();
    std::fs::write(
        format!("{PEER_CORPUS}/garbage.bin"),
        b"\x01IP\x01\x03\xff\xff",
    )
    .unwrap();
}

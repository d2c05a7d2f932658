//! Replays every committed fuzz corpus file through its harness (so `cargo test` covers the
//! corpora without nightly). `cargo test -p ima-sick-lms --test fuzz_corpus -- --ignored`
//! regenerates the seed files from the spec vectors.

use std::path::PathBuf;

use ima_sick_lms::fuzz_harness;
use ima_sick_lms::wire::*;

type Harness = fn(&[u8]);

const TARGETS: [(&str, Harness); 3] = [
    ("sick_lms_framer", fuzz_harness::sick_lms_framer),
    ("sick_lms_parse_reply", fuzz_harness::sick_lms_parse_reply),
    ("sick_lms_roundtrip", fuzz_harness::sick_lms_roundtrip),
];

const CORPORA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../fuzz/corpus");

fn dir(target: &str) -> PathBuf {
    PathBuf::from(CORPORA).join(target)
}

#[test]
fn replay_committed_corpora() {
    for (target, harness) in TARGETS {
        ima_hal::fuzzing::replay_corpus(CORPORA, target, harness, false).unwrap();
    }
}

fn emit_r(r: &Reply<'_>, addr: u8) -> Vec<u8> {
    let mut buf = [0u8; MAX_TELEGRAM];
    let n = r.emit_from(addr, &mut buf).unwrap();
    buf[..n].to_vec()
}

fn emit_c(c: &Command) -> Vec<u8> {
    let mut buf = [0u8; 64];
    let n = c.emit(&mut buf).unwrap();
    buf[..n].to_vec()
}

/// The spec's telegrams (§1.1 table and §3 examples), one per file.
fn telegrams() -> Vec<(&'static str, Vec<u8>)> {
    let s = StatusByte::NORMAL;
    let mut status = StatusBlockBuf::default();
    status.set_variant(180, 50);
    status.set_baud(BaudRate::B38400);
    let words361 = vec![1000u16; 361];
    let words181 = vec![1000u16; 181];
    let words401: Vec<u16> = (0..401u16)
        .map(|i| if i % 5 == 0 { 0x8002 } else { 0x1FFF - (i % 9) })
        .collect();
    let mut idx = Scan::full(&words181, Units::Cm, StatusByte(0x90));
    idx.indices = Some((3, 250));
    let mut cfg = LmsConfig::zeroed(true);
    cfg.set_units(1);
    let mut power = Vec::new();
    power.extend_from_slice(b"LMS200;301063;V02.06 ");
    vec![
        (
            "cmd_stop_stream",
            emit_c(&Command::SetMode(ModeRequest::RequestOnly)),
        ),
        (
            "cmd_stream",
            emit_c(&Command::SetMode(ModeRequest::StreamAll)),
        ),
        (
            "cmd_baud_500k",
            emit_c(&Command::SetMode(ModeRequest::Baud(BaudRate::B500000))),
        ),
        (
            "cmd_install",
            emit_c(&Command::SetMode(ModeRequest::Installation {
                password: DEFAULT_PASSWORD,
            })),
        ),
        (
            "cmd_subrange",
            emit_c(&Command::SetMode(ModeRequest::MeanSubrange {
                samples: 4,
                start: 2,
                end: 180,
            })),
        ),
        ("cmd_status", emit_c(&Command::Status)),
        ("cmd_one_scan", emit_c(&Command::one_scan())),
        (
            "cmd_variant_100_025",
            emit_c(&Command::Variant {
                angle_deg: 100,
                res_centideg: 25,
            }),
        ),
        ("cmd_write_config", emit_c(&Command::WriteConfig(cfg))),
        ("cmd_reset", emit_c(&Command::Reset)),
        (
            "reply_a0_81",
            emit_r(
                &Reply::ModeChanged {
                    result: 0,
                    status: s,
                },
                0x81,
            ),
        ),
        (
            "reply_reset_ack",
            emit_r(&Reply::ResetAck { status: s }, 0x80),
        ),
        (
            "reply_power_on",
            emit_r(
                &Reply::PowerOn {
                    text: &power,
                    status: StatusByte(0x13),
                },
                0x81,
            ),
        ),
        (
            "reply_variant",
            emit_r(
                &Reply::Variant {
                    accepted: 1,
                    angle_deg: 180,
                    res_centideg: 50,
                    status: s,
                },
                0x80,
            ),
        ),
        (
            "reply_status",
            emit_r(
                &Reply::Status {
                    block: status.view(),
                    status: s,
                },
                0x80,
            ),
        ),
        (
            "reply_config",
            emit_r(
                &Reply::Config {
                    config: cfg,
                    status: s,
                },
                0x80,
            ),
        ),
        (
            "reply_b0_361",
            emit_r(&Reply::Scan(Scan::full(&words361, Units::Mm, s)), 0x80),
        ),
        ("reply_b0_181_indices", emit_r(&Reply::Scan(idx), 0x80)),
        (
            "reply_b0_401_sync_inside",
            emit_r(&Reply::Scan(Scan::full(&words401, Units::Cm, s)), 0x80),
        ),
        (
            "reply_rejected",
            emit_r(
                &Reply::Rejected {
                    data: &[],
                    status: s,
                },
                0x80,
            ),
        ),
    ]
}

#[test]
#[ignore = "writes the seed corpora; run by hand"]
fn generate_seed_corpora() {
    let tele = telegrams();
    for target in ["sick_lms_parse_reply", "sick_lms_roundtrip"] {
        let d = dir(target);
        std::fs::create_dir_all(&d).unwrap();
        for (name, bytes) in &tele {
            std::fs::write(d.join(format!("{name}.bin")), bytes).unwrap();
        }
    }
    // Streams for the framer target: first byte seeds the chunking.
    let get = |n: &str| tele.iter().find(|(k, _)| *k == n).unwrap().1.clone();
    let mut conversation = vec![ACK];
    for k in [
        "reply_a0_81",
        "reply_status",
        "reply_variant",
        "reply_config",
        "reply_b0_361",
        "reply_b0_401_sync_inside",
    ] {
        conversation.extend(get(k));
        conversation.push(ACK);
    }
    let b0 = get("reply_b0_361");
    let mut truncated = b0[..300].to_vec();
    truncated.extend(get("reply_a0_81"));
    truncated.extend(b0.clone());
    let mut lost_stx = b0[1..].to_vec();
    lost_stx.extend(get("reply_b0_401_sync_inside"));
    let mut corrupted = b0.clone();
    corrupted[100] ^= 0x10;
    corrupted.extend([NAK, 0x55, 0xAA]);
    corrupted.extend(get("reply_b0_181_indices"));
    let mut commands = Vec::new();
    for k in [
        "cmd_stop_stream",
        "cmd_status",
        "cmd_install",
        "cmd_write_config",
    ] {
        commands.extend(get(k));
    }
    let d = dir("sick_lms_framer");
    std::fs::create_dir_all(&d).unwrap();
    for (seed, name, stream) in [
        (1u8, "conversation", conversation),
        (7, "truncated_then_good", truncated),
        (200, "lost_stx_sync_inside", lost_stx),
        (42, "corrupted_then_good", corrupted),
        (3, "commands", commands),
    ] {
        let mut v = vec![seed];
        v.extend(stream);
        std::fs::write(d.join(format!("{name}.bin")), v).unwrap();
    }
}

//! The framing list (DESIGN.md / tokio-util) plus the LMS-specific rules of spec §5.

use ima_hal::Instant;
use ima_sick_lms::framer::{Counters, Direction, Framer, Item, PARTIAL_TIMEOUT};
use ima_sick_lms::wire::*;
use proptest::prelude::*;

#[derive(Debug, Clone, PartialEq, Eq)]
enum Got {
    Ack,
    Nak,
    Bad,
    Frame(Vec<u8>),
}

fn feed(f: &mut Framer, bytes: &[u8], now: Instant, out: &mut Vec<Got>) {
    f.push_all(bytes, now, |item| {
        out.push(match item {
            Item::Ack => Got::Ack,
            Item::Nak => Got::Nak,
            Item::BadChecksum => Got::Bad,
            Item::Frame(fr) => Got::Frame(fr.as_bytes().to_vec()),
        })
    });
}

fn reply(r: &Reply<'_>) -> Vec<u8> {
    let mut buf = [0u8; MAX_TELEGRAM];
    let n = r.emit(&mut buf).unwrap();
    buf[..n].to_vec()
}

fn a0() -> Vec<u8> {
    reply(&Reply::ModeChanged {
        result: 0,
        status: StatusByte::NORMAL,
    })
}

fn status_reply() -> Vec<u8> {
    let b = StatusBlockBuf::default();
    reply(&Reply::Status {
        block: b.view(),
        status: StatusByte::NORMAL,
    })
}

/// A 361-value B0 whose data contains `02 80` many times (value 0x8002 is `02 80` LE).
fn b0_with_sync_inside() -> Vec<u8> {
    let mut words = [1000u16; 361];
    for (i, w) in words.iter_mut().enumerate() {
        if i % 7 == 0 {
            *w = 0x8002;
        }
        if i % 11 == 0 {
            *w = 0x0602; // 02 06: STX then ACK
        }
    }
    // Also a complete fake header inside: 02 80 03 00 A0 ...
    words[100] = 0x8002;
    words[101] = 0x0003;
    words[102] = 0x00A0;
    let t = reply(&Reply::Scan(Scan::full(
        &words,
        Units::Mm,
        StatusByte::NORMAL,
    )));
    assert!(t.windows(2).skip(1).any(|w| w == [0x02, 0x80]));
    t
}

const T0: Instant = Instant::ZERO;

#[test]
fn many_frames_per_read() {
    let mut stream = Vec::new();
    let frames = [a0(), status_reply(), b0_with_sync_inside(), a0()];
    for f in &frames {
        stream.extend_from_slice(f);
    }
    let mut f = Framer::replies();
    let mut out = Vec::new();
    feed(&mut f, &stream, T0, &mut out);
    assert_eq!(
        out,
        frames.iter().cloned().map(Got::Frame).collect::<Vec<_>>()
    );
    assert_eq!(f.counters().dropped_bytes, 0);
    assert_eq!(f.counters().frames, 4);
}

#[test]
fn one_frame_over_many_reads_including_single_bytes() {
    let frame = b0_with_sync_inside();
    for chunk in [1usize, 2, 3, 7, 100, 731] {
        let mut f = Framer::replies();
        let mut out = Vec::new();
        for (i, c) in frame.chunks(chunk).enumerate() {
            feed(&mut f, c, Instant::from_micros(i as u64), &mut out);
        }
        assert_eq!(out, vec![Got::Frame(frame.clone())], "chunk {chunk}");
        assert_eq!(f.counters(), {
            Counters {
                frames: 1,
                ..Counters::default()
            }
        });
    }
}

#[test]
fn garbage_before_and_between_frames() {
    let mut stream = vec![0xFF, 0x00, 0x80, 0x33];
    stream.extend(a0());
    stream.extend([0x55, 0xAA, 0x80]);
    stream.extend(status_reply());
    let mut f = Framer::replies();
    let mut out = Vec::new();
    feed(&mut f, &stream, T0, &mut out);
    assert_eq!(out, vec![Got::Frame(a0()), Got::Frame(status_reply())]);
    assert_eq!(f.counters().dropped_bytes, 7);
}

#[test]
fn truncated_frame_then_a_good_one() {
    let b0 = b0_with_sync_inside();
    let mut stream = b0[..300].to_vec();
    stream.extend(a0());
    stream.extend(b0.clone());
    let mut f = Framer::replies();
    let mut out = Vec::new();
    feed(&mut f, &stream, T0, &mut out);
    // The truncated candidate swallows the A0 and part of the next B0, fails its CRC, and the
    // one-byte rescan finds both good frames again.
    assert_eq!(out, vec![Got::Frame(a0()), Got::Frame(b0)]);
    assert!(f.counters().bad_checksums >= 1);
}

#[test]
fn truncated_frame_then_a_short_good_one_recovered_at_expiry() {
    let b0 = b0_with_sync_inside();
    let mut stream = b0[..50].to_vec();
    stream.extend(a0());
    let mut f = Framer::replies();
    let mut out = Vec::new();
    feed(&mut f, &stream, T0, &mut out);
    assert!(out.is_empty(), "still waiting for the claimed 732 bytes");
    let deadline = f.poll_timeout().unwrap();
    assert_eq!(deadline, T0 + PARTIAL_TIMEOUT);
    feed(
        &mut f,
        &[],
        deadline - core::time::Duration::from_micros(1),
        &mut out,
    );
    assert!(out.is_empty());
    feed(&mut f, &[], deadline, &mut out);
    assert_eq!(out, vec![Got::Frame(a0())]);
    assert!(f.counters().expired >= 1);
    assert_eq!(f.buffered(), 0);
    assert_eq!(f.poll_timeout(), None);
}

#[test]
fn partial_expires_when_new_bytes_come_late() {
    let a = a0();
    let mut f = Framer::replies();
    let mut out = Vec::new();
    feed(&mut f, &a[..5], T0, &mut out);
    // 40 ms later a whole new frame: the stale partial must not absorb it.
    feed(&mut f, &a, Instant::from_millis(40), &mut out);
    assert_eq!(out, vec![Got::Frame(a.clone())]);
    assert_eq!(f.counters().expired, 1);
    // Within 35 ms, a split frame is fine.
    feed(&mut f, &a[..5], Instant::from_millis(100), &mut out);
    feed(&mut f, &a[5..], Instant::from_millis(134), &mut out);
    assert_eq!(out.len(), 2);
}

#[test]
fn oversize_and_zero_length_rejected() {
    let mut stream = vec![0x02, 0x80, 0x29, 0x03]; // LEN 809
    stream.extend([0x02, 0x80, 0x00, 0x00]); // LEN 0
    stream.extend(a0());
    let mut f = Framer::replies();
    let mut out = Vec::new();
    feed(&mut f, &stream, T0, &mut out);
    assert_eq!(out, vec![Got::Frame(a0())]);
    assert_eq!(f.counters().bad_headers, 2);
}

#[test]
fn bad_checksum_then_a_good_frame() {
    let mut bad = status_reply();
    let k = bad.len() - 1;
    bad[k] ^= 0x40;
    let mut stream = bad;
    stream.extend(a0());
    let mut f = Framer::replies();
    let mut out = Vec::new();
    feed(&mut f, &stream, T0, &mut out);
    assert_eq!(out, vec![Got::Frame(a0())]);
    assert_eq!(f.counters().bad_checksums, 1);
}

#[test]
fn b0_with_02_80_inside_after_a_lost_first_byte() {
    // Lose the STX of a B0: the embedded 02 80 (and the fake A0 header) must not produce a
    // frame, and the next good B0 must come through.
    let b0 = b0_with_sync_inside();
    let mut stream = b0[1..].to_vec();
    stream.extend(b0.clone());
    for chunk in [1usize, 13, 4096] {
        let mut f = Framer::replies();
        let mut out = Vec::new();
        for c in stream.chunks(chunk) {
            feed(&mut f, c, T0, &mut out);
        }
        assert_eq!(out, vec![Got::Frame(b0.clone())], "chunk {chunk}");
        assert!(f.counters().dropped_bytes >= 731);
    }
}

#[test]
fn corrupted_b0_never_delivered_and_next_found() {
    let b0 = b0_with_sync_inside();
    let mut bad = b0.clone();
    bad[400] ^= 0x01;
    let mut stream = bad;
    stream.extend(b0.clone());
    let mut f = Framer::replies();
    let mut out = Vec::new();
    feed(&mut f, &stream, T0, &mut out);
    assert_eq!(out, vec![Got::Frame(b0)]);
    // The corrupted B0, and the fake `02 80 03 00 A0` header inside its data on rescan.
    assert_eq!(f.counters().bad_checksums, 2);
}

#[test]
fn ack_nak_only_between_frames() {
    let mut stream = vec![ACK];
    stream.extend(a0());
    stream.push(NAK);
    stream.push(0x33);
    stream.push(ACK);
    let mut f = Framer::replies();
    let mut out = Vec::new();
    feed(&mut f, &stream, T0, &mut out);
    assert_eq!(
        out,
        vec![Got::Ack, Got::Frame(a0()), Got::Nak, Got::Ack],
        "lone bytes between frames count"
    );
    // 06 and 15 inside a failed candidate are not ACK/NAK.
    let mut bad = vec![0x02, 0x80, 0x05, 0x00, 0xA0, ACK, NAK, ACK, NAK, 0x10, 0, 0];
    bad.extend(a0());
    let mut f = Framer::replies();
    let mut out = Vec::new();
    feed(&mut f, &bad, T0, &mut out);
    assert_eq!(out, vec![Got::Frame(a0())]);
    assert_eq!(f.counters().acks + f.counters().naks, 0);
    // 06 inside good B0 data is not an ACK either.
    let b0 = b0_with_sync_inside();
    assert!(b0.contains(&ACK));
    let mut f = Framer::replies();
    let mut out = Vec::new();
    feed(&mut f, &b0, T0, &mut out);
    assert_eq!(out, vec![Got::Frame(b0)]);
}

#[test]
fn reply_addresses_80_to_ff_accepted() {
    for addr in [0x80u8, 0x81, 0xC3, 0xFF] {
        let mut buf = [0u8; 32];
        let n = Reply::ResetAck {
            status: StatusByte::NORMAL,
        }
        .emit_from(addr, &mut buf)
        .unwrap();
        let mut f = Framer::replies();
        let mut out = Vec::new();
        feed(&mut f, &buf[..n], T0, &mut out);
        assert_eq!(out, vec![Got::Frame(buf[..n].to_vec())], "{addr:#x}");
    }
}

#[test]
fn direction_filters_commands_and_replies() {
    let mut cmd = [0u8; 16];
    let n = Command::Status.emit(&mut cmd).unwrap();
    let mut stream = cmd[..n].to_vec();
    stream.extend(a0());
    let mut host = Framer::replies();
    let mut dev = Framer::new(Direction::Commands);
    let (mut oh, mut od) = (Vec::new(), Vec::new());
    feed(&mut host, &stream, T0, &mut oh);
    feed(&mut dev, &stream, T0, &mut od);
    // (The command's CRC byte 0x15 may read as a NAK to the host framer: it is past the
    // failed header, so between frames as far as the host can tell.)
    oh.retain(|g| matches!(g, Got::Frame(_)));
    assert_eq!(oh, vec![Got::Frame(a0())]);
    assert_eq!(od, vec![Got::Frame(cmd[..n].to_vec())]);
}

#[test]
fn good_crc_bad_payload_is_dropped() {
    // A0 with two result bytes: CRC good, payload wrong.
    let mut t = vec![0x02, 0x80, 0x04, 0x00, 0xA0, 0x00, 0x00, 0x10];
    let c = crc16(&t);
    t.extend(c.to_le_bytes());
    t.extend(a0());
    let mut f = Framer::replies();
    let mut out = Vec::new();
    feed(&mut f, &t, T0, &mut out);
    assert_eq!(out, vec![Got::Frame(a0())]);
    assert_eq!(f.counters().bad_payloads, 1);
}

fn arb_frame() -> impl Strategy<Value = Vec<u8>> {
    prop_oneof![
        Just(a0()),
        Just(status_reply()),
        Just(b0_with_sync_inside()),
        (0u8..=255).prop_map(|s| reply(&Reply::ResetAck {
            status: StatusByte(s)
        })),
        proptest::collection::vec(any::<u16>(), 0..40)
            .prop_map(|w| reply(&Reply::Scan(Scan::full(&w, Units::Cm, StatusByte::NORMAL)))),
    ]
}

/// Noise that cannot start a candidate (no STX) nor look like ACK/NAK.
fn arb_noise() -> impl Strategy<Value = Vec<u8>> {
    proptest::collection::vec(
        any::<u8>().prop_filter("no STX/ACK/NAK", |b| ![STX, ACK, NAK].contains(b)),
        0..20,
    )
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(200))]

    #[test]
    fn never_loses_a_good_frame_behind_noise(
        parts in proptest::collection::vec((arb_noise(), arb_frame()), 1..8),
        chunk in 1usize..900,
    ) {
        let mut stream = Vec::new();
        let mut want = Vec::new();
        for (noise, frame) in &parts {
            stream.extend(noise);
            stream.extend(frame);
            want.push(Got::Frame(frame.clone()));
        }
        let mut f = Framer::replies();
        let mut out = Vec::new();
        for c in stream.chunks(chunk) {
            feed(&mut f, c, T0, &mut out);
        }
        prop_assert_eq!(out, want);
    }

    #[test]
    fn items_do_not_depend_on_chunking(
        parts in proptest::collection::vec(
            (proptest::collection::vec(any::<u8>(), 0..12), arb_frame()),
            1..6,
        ),
        chunk in 1usize..200,
    ) {
        // Noise here may contain STX, ACK and NAK: whatever the framer makes of the stream, it
        // makes the same of it however the stream is split.
        let mut stream = Vec::new();
        for (noise, frame) in &parts {
            stream.extend(noise);
            stream.extend(frame);
        }
        let mut whole = Vec::new();
        feed(&mut Framer::replies(), &stream, T0, &mut whole);
        let mut f = Framer::replies();
        let mut split = Vec::new();
        for c in stream.chunks(chunk) {
            feed(&mut f, c, T0, &mut split);
        }
        prop_assert_eq!(whole, split);
    }

    #[test]
    fn arbitrary_bytes_never_yield_a_bad_frame(
        bytes in proptest::collection::vec(any::<u8>(), 0..2000),
        chunk in 1usize..64,
    ) {
        let mut f = Framer::replies();
        let mut step = 0u64;
        for c in bytes.chunks(chunk) {
            step += 1;
            f.push_all(c, Instant::from_millis(step * 10), |item| {
                if let Item::Frame(fr) = item {
                    assert!(Reply::parse(fr.as_bytes()).is_ok());
                }
            });
        }
        prop_assert!(f.buffered() <= MAX_TELEGRAM);
    }
}

#[test]
fn mock_role_reports_bad_checksums_and_uses_a_6_ms_gap() {
    use core::time::Duration;
    let mut cmd = [0u8; 16];
    let n = Command::Status.emit(&mut cmd).unwrap();
    let good = cmd[..n].to_vec();
    let mut bad = good.clone();
    bad[n - 1] ^= 0xFF;
    let mk = || {
        Framer::commands()
            .with_partial_timeout(Duration::from_millis(6))
            .report_bad_checksums(true)
    };
    let mut f = mk();
    let mut out = Vec::new();
    let mut stream = bad.clone();
    stream.extend(&good);
    feed(&mut f, &stream, T0, &mut out);
    assert_eq!(out, vec![Got::Bad, Got::Frame(good.clone())]);
    // A 7 ms gap inside a telegram abandons it; 5 ms does not.
    let mut f = mk();
    let mut out = Vec::new();
    feed(&mut f, &good[..3], T0, &mut out);
    feed(&mut f, &good[3..], Instant::from_millis(5), &mut out);
    assert_eq!(out, vec![Got::Frame(good.clone())]);
    feed(&mut f, &good[..3], Instant::from_millis(10), &mut out);
    assert_eq!(f.poll_timeout(), Some(Instant::from_millis(16)));
    feed(&mut f, &good[3..], Instant::from_millis(17), &mut out);
    let frames = out.iter().filter(|g| matches!(g, Got::Frame(_))).count();
    assert_eq!(frames, 1, "the tail alone is not a telegram");
    assert_eq!(f.counters().expired, 1);
    // The host framer does not report them by default.
    let mut h = Framer::replies();
    let mut bad_reply = a0();
    bad_reply[6] ^= 1;
    let mut out = Vec::new();
    feed(&mut h, &bad_reply, T0, &mut out);
    assert!(out.is_empty());
    assert_eq!(h.counters().bad_checksums, 1);
}

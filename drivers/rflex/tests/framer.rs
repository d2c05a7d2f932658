//! The framer list (tokio-util's `framed_read.rs` cases, adapted to a marker-delimited link)
//! and property tests of stuffing and resynchronisation.

use ima_hal::Instant;
use ima_rflex::framer::{FrameError, Framer, FramerConfig};
use ima_rflex::wire::{
    Command, ESC, MAX_WIRE_FRAME, PIPE, RawFrame, Report, Stuffing, WireError, encode_frame,
};
use proptest::prelude::*;

/// (port, id, opcode, data) of a frame, owned.
type Owned = (u8, u8, u8, Vec<u8>);

fn own(f: &RawFrame<'_>) -> Owned {
    (f.port, f.id, f.opcode, f.data.to_vec())
}

fn frame(port: u8, id: u8, opcode: u8, data: &[u8], stuffing: Stuffing) -> Vec<u8> {
    let mut buf = [0u8; MAX_WIRE_FRAME];
    let n = encode_frame(port, id, opcode, data, stuffing, &mut buf).unwrap();
    buf[..n].to_vec()
}

fn t1() -> Vec<u8> {
    frame(2, 0, 0x0C, &[], Stuffing::Full)
}
fn t2() -> Vec<u8> {
    frame(1, 0, 0x01, &[], Stuffing::Full)
}
/// A report full of bytes that need stuffing.
fn busy() -> Vec<u8> {
    frame(
        2,
        0x1B,
        0x21,
        &[0x1B, 0x7C, 0x03, 0x02, 0x1B, 0x1B, 0x00, 0x7C],
        Stuffing::Full,
    )
}

/// Feed `chunks` and collect frames and errors.
fn run(f: &mut Framer, chunks: &[&[u8]]) -> (Vec<Owned>, Vec<FrameError>) {
    let mut ok = Vec::new();
    let mut err = Vec::new();
    for c in chunks {
        f.push(c, |r| match r {
            Ok(raw) => ok.push(own(&raw)),
            Err(e) => err.push(e),
        });
    }
    (ok, err)
}

fn expected(frames: &[Vec<u8>]) -> Vec<Owned> {
    frames
        .iter()
        .map(|w| {
            let mut s = [0u8; 300];
            own(&RawFrame::parse_wire(w, &mut s).unwrap())
        })
        .collect()
}

#[test]
fn many_frames_in_one_read() {
    let all = [t1(), t2(), busy(), t1()];
    let stream: Vec<u8> = all.concat();
    let mut f = Framer::strict();
    let (ok, err) = run(&mut f, &[&stream]);
    assert_eq!(ok, expected(&all));
    assert!(err.is_empty());
    assert_eq!(f.stats().frames, 4);
    assert_eq!(f.stats().dropped_bytes, 0);
}

#[test]
fn one_frame_over_many_reads_including_single_bytes() {
    let w = busy();
    for split in 1..w.len() {
        let mut f = Framer::strict();
        let (ok, err) = run(&mut f, &[&w[..split], &w[split..]]);
        assert_eq!(ok, expected(std::slice::from_ref(&w)), "split at {split}");
        assert!(err.is_empty());
    }
    let mut f = Framer::strict();
    let singles: Vec<&[u8]> = w.chunks(1).collect();
    let (ok, _) = run(&mut f, &singles);
    assert_eq!(ok, expected(std::slice::from_ref(&w)));
}

#[test]
fn garbage_before_and_between_frames() {
    let mut stream = b"ASCII text\r\n\x03\x1B\x00".to_vec();
    stream.extend(t1());
    stream.extend([0x7C, 0x1B, 0x01, 0xFF, 0x1B]);
    stream.extend(busy());
    let mut f = Framer::strict();
    let (ok, err) = run(&mut f, &[&stream]);
    assert_eq!(ok, expected(&[t1(), busy()]));
    assert!(err.is_empty());
    assert_eq!(f.stats().dropped_bytes, 15 + 5);
}

#[test]
fn truncated_frame_then_a_good_one() {
    let mut stream = t1()[..5].to_vec();
    stream.extend(t2());
    let mut f = Framer::strict();
    let (ok, err) = run(&mut f, &[&stream]);
    assert_eq!(ok, expected(&[t2()]));
    assert_eq!(err, vec![FrameError::Restarted]);
}

#[test]
fn stalled_frame_is_dropped_after_the_gap() {
    let w = t2();
    let mut f = Framer::strict();
    f.bytes_arrived(Instant::from_millis(0));
    let (ok, _) = run(&mut f, &[&t1()[..4]]);
    assert!(ok.is_empty());
    // 60 ms later (> 50 ms): the rest of t1 arrives, then t2. The tail of t1 is noise now.
    f.bytes_arrived(Instant::from_millis(60));
    let mut rest = t1()[4..].to_vec();
    rest.extend(&w);
    let (ok, err) = run(&mut f, &[&rest]);
    assert_eq!(ok, expected(&[w]));
    assert!(err.is_empty());
    assert_eq!(f.stats().stale, 1);
    // Within the gap nothing is dropped.
    let mut g = Framer::strict();
    g.bytes_arrived(Instant::from_millis(0));
    run(&mut g, &[&t1()[..4]]);
    g.bytes_arrived(Instant::from_millis(40));
    let (ok, _) = run(&mut g, &[&t1()[4..]]);
    assert_eq!(ok, expected(&[t1()]));
}

#[test]
fn oversize_frame_then_a_good_one() {
    let mut stream = vec![ESC, 0x02];
    stream.extend(std::iter::repeat_n(0x55, 400));
    stream.extend([ESC, 0x03]);
    stream.extend(t1());
    let mut f = Framer::strict();
    let (ok, err) = run(&mut f, &[&stream]);
    assert_eq!(ok, expected(&[t1()]));
    assert_eq!(err, vec![FrameError::Oversize]);
    assert_eq!(f.stats().oversize, 1);
}

#[test]
fn largest_frame_is_accepted() {
    let data = [ESC; 255];
    let w = frame(4, 1, 2, &data, Stuffing::Full);
    let mut f = Framer::strict();
    let (ok, err) = run(&mut f, &[&w]);
    assert!(err.is_empty());
    assert_eq!(ok[0].3, data.to_vec());
}

#[test]
fn bad_checksum_then_a_good_frame() {
    let mut bad = t1();
    bad[6] ^= 0x40;
    let mut stream = bad;
    stream.extend(t2());
    let mut f = Framer::strict();
    let (ok, err) = run(&mut f, &[&stream]);
    assert_eq!(ok, expected(&[t2()]));
    assert_eq!(
        err,
        vec![FrameError::Invalid(WireError::BadChecksum {
            expected: 0x0E,
            got: 0x4E
        })]
    );
    assert_eq!(f.stats().bad_checksums, 1);
}

#[test]
fn length_is_enforced() {
    // A stray 0x00 (pitfall P3) leaves the XOR unchanged; the length byte catches it.
    let mut bad = frame(2, 0, 0x21, &[1, 2, 3], Stuffing::Full);
    bad.insert(8, 0x00);
    let mut stream = bad;
    stream.extend(t1());
    let mut f = Framer::strict();
    let (ok, err) = run(&mut f, &[&stream]);
    assert_eq!(ok, expected(&[t1()]));
    assert_eq!(
        err,
        vec![FrameError::Invalid(WireError::BadLength {
            declared: 3,
            actual: 4
        })]
    );
    // Shorter than a header.
    let mut f = Framer::strict();
    let (_, err) = run(&mut f, &[&[ESC, 0x02, 1, 2, ESC, 0x03]]);
    assert_eq!(err, vec![FrameError::Invalid(WireError::TooShort(2))]);
}

#[test]
fn bad_escape_then_a_good_frame() {
    // ESC 0x58 inside a frame; then ESC ESC STX: the second ESC starts the next frame.
    let mut stream = vec![ESC, 0x02, 2, 0, ESC, 0x58];
    stream.extend(t1());
    stream.extend([ESC, 0x02, 2, ESC]);
    stream.extend(t2());
    let mut f = Framer::strict();
    let (ok, err) = run(&mut f, &[&stream]);
    assert_eq!(ok, expected(&[t1(), t2()]));
    assert_eq!(
        err,
        vec![FrameError::BadEscape(0x58), FrameError::BadEscape(ESC)]
    );
}

#[test]
fn etx_and_stx_bytes_are_plain_data_unless_escaped() {
    let w = frame(5, 0x03, 0x02, &[0x03, 0x02, 0x03], Stuffing::Full);
    let mut f = Framer::strict();
    let (ok, err) = run(&mut f, &[&w]);
    assert!(err.is_empty());
    assert_eq!(ok, vec![(5, 3, 2, vec![3, 2, 3])]);
}

#[test]
fn esc_only_stuffing_is_understood_too() {
    let data = [PIPE, ESC, PIPE];
    let w = frame(2, 0, 0x21, &data, Stuffing::EscOnly);
    let mut f = Framer::strict();
    let (ok, _) = run(&mut f, &[&w]);
    assert_eq!(ok, vec![(2, 0, 0x21, data.to_vec())]);
}

#[test]
fn lenient_reads_unknown_escapes_as_literal() {
    let data = [0x00, ESC, 0x58, ESC, ESC, 0x42];
    // Unstuffed on the wire: ESC 58, ESC ESC 42 (second ESC pairs with 42).
    let w = frame(2, 0, 7, &data, Stuffing::None);
    let mut f = Framer::new(FramerConfig {
        lenient: true,
        ..FramerConfig::default()
    });
    let (ok, err) = run(&mut f, &[&w]);
    assert!(err.is_empty(), "{err:?}");
    assert_eq!(ok, vec![(2, 0, 7, data.to_vec())]);
    let mut s = Framer::strict();
    let (ok, _) = run(&mut s, &[&w]);
    assert!(ok.is_empty());
}

#[test]
fn unknown_ports_are_frames_not_errors() {
    let w = frame(9, 0, 0x55, &[1, 2], Stuffing::Full);
    assert!(matches!(Report::parse(&w), Ok(Report::Unknown(u)) if u.port == 9 && u.len == 2));
    assert!(matches!(Command::parse(&w), Ok(Command::Unknown(u)) if u.opcode == 0x55));
}

#[test]
fn wire_parse_rejects_malformed_frames() {
    assert_eq!(Command::parse(&[]), Err(WireError::Truncated));
    assert_eq!(Command::parse(&[0x1B, 0x03]), Err(WireError::BadStart));
    assert_eq!(Command::parse(&t1()[..7]), Err(WireError::Truncated));
    let mut trailing = t1();
    trailing.push(0);
    assert_eq!(Command::parse(&trailing), Err(WireError::TrailingBytes));
    // Known opcode with the wrong payload length.
    let w = frame(2, 0, 0x0C, &[1], Stuffing::Full);
    assert_eq!(
        Command::parse(&w),
        Err(WireError::BadPayload {
            port: 2,
            opcode: 0x0C,
            len: 1
        })
    );
}

fn data_full_of_specials() -> impl Strategy<Value = Vec<u8>> {
    prop::collection::vec(
        prop_oneof![
            3 => Just(ESC),
            3 => Just(PIPE),
            1 => Just(0x00),
            1 => Just(0x01),
            1 => Just(0x02),
            1 => Just(0x03),
            2 => any::<u8>(),
        ],
        0..=255,
    )
}

proptest! {
    /// Stuffing round trip: any header and data, full of 0x1B and 0x7C, through the encoder,
    /// split at random, and back through the strict framer.
    #[test]
    fn stuffing_round_trip(
        port in any::<u8>(),
        id in prop_oneof![Just(ESC), Just(PIPE), any::<u8>()],
        opcode in any::<u8>(),
        data in data_full_of_specials(),
        esc_only in any::<bool>(),
        split in any::<prop::sample::Index>(),
    ) {
        let st = if esc_only { Stuffing::EscOnly } else { Stuffing::Full };
        let w = frame(port, id, opcode, &data, st);
        prop_assert!(w.len() <= MAX_WIRE_FRAME);
        let at = split.index(w.len());
        let mut f = Framer::strict();
        let (ok, err) = run(&mut f, &[&w[..at], &w[at..]]);
        prop_assert!(err.is_empty());
        prop_assert_eq!(ok, vec![(port, id, opcode, data.clone())]);
        // The stuffed body never contains a bare ESC followed by anything but 00/01/03.
        for pair in w[2..w.len() - 2].windows(2) {
            if pair[0] == ESC {
                prop_assert!(pair[1] == 0x00 || pair[1] == 0x01);
            }
        }
    }

    /// Good frames are never lost behind noise, whatever the noise and however the stream is cut.
    #[test]
    fn framer_never_loses_a_good_frame_behind_noise(
        items in prop::collection::vec(
            (prop::collection::vec(any::<u8>(), 0..40), data_full_of_specials(), any::<u8>()),
            1..6,
        ),
        cuts in prop::collection::vec(1usize..50, 0..40),
    ) {
        let mut stream = Vec::new();
        let mut want = Vec::new();
        for (noise, data, id) in &items {
            stream.extend(noise);
            let w = frame(4, *id, 2, data, Stuffing::Full);
            stream.extend(&w);
            want.push((4u8, *id, 2u8, data.clone()));
        }
        let mut chunks = Vec::new();
        let mut rest: &[u8] = &stream;
        for c in cuts {
            if rest.is_empty() { break; }
            let c = c.min(rest.len());
            chunks.push(&rest[..c]);
            rest = &rest[c..];
        }
        chunks.push(rest);
        let mut f = Framer::strict();
        let (ok, _) = run(&mut f, &chunks);
        // Noise may itself contain a valid frame; every good frame must still be there, in order.
        let mut it = ok.iter();
        for w in &want {
            prop_assert!(it.any(|g| g == w), "lost {:?}", w);
        }
    }

    /// The framer survives any bytes and its counters stay consistent.
    #[test]
    fn framer_survives_anything(bytes in prop::collection::vec(any::<u8>(), 0..2000)) {
        let mut f = Framer::strict();
        let (ok, err) = run(&mut f, &[&bytes]);
        prop_assert_eq!(ok.len() as u32, f.stats().frames);
        prop_assert_eq!(err.len() as u32, f.stats().errors());
        let mut g = Framer::lenient();
        run(&mut g, &[&bytes]);
    }
}

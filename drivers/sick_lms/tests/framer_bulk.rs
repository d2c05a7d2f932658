//! The framer's bulk paths (one slice search for STX/ACK/NAK between frames, one search for the
//! next STX after a failed candidate) against the byte-at-a-time framer they replaced
//! (`reference_framer`): the same items, counters and held bytes for the same reads.

mod reference_framer;

use reference_framer::RefFramer;

use ima_hal::Instant;
use ima_sick_lms::framer::{Counters, Direction, Framer, Item};
use ima_sick_lms::wire::*;
use proptest::prelude::*;

#[derive(Debug, Clone, PartialEq, Eq)]
enum Got {
    Ack,
    Nak,
    Bad,
    Frame(Vec<u8>),
}

fn got(item: Item<'_>) -> Got {
    match item {
        Item::Ack => Got::Ack,
        Item::Nak => Got::Nak,
        Item::BadChecksum => Got::Bad,
        Item::Frame(fr) => Got::Frame(fr.as_bytes().to_vec()),
    }
}

/// The two framers under one face, so that one driver loop runs both.
trait Framing {
    fn push<'s>(&'s mut self, input: &[u8], now: Instant) -> ima_sick_lms::framer::Pushed<'s>;
    fn counters(&self) -> Counters;
    fn buffered(&self) -> usize;
}

impl Framing for Framer {
    fn push<'s>(&'s mut self, input: &[u8], now: Instant) -> ima_sick_lms::framer::Pushed<'s> {
        Framer::push(self, input, now)
    }
    fn counters(&self) -> Counters {
        Framer::counters(self)
    }
    fn buffered(&self) -> usize {
        Framer::buffered(self)
    }
}

impl Framing for RefFramer {
    fn push<'s>(&'s mut self, input: &[u8], now: Instant) -> ima_sick_lms::framer::Pushed<'s> {
        RefFramer::push(self, input, now)
    }
    fn counters(&self) -> Counters {
        RefFramer::counters(self)
    }
    fn buffered(&self) -> usize {
        RefFramer::buffered(self)
    }
}

/// Reads of `chunk` bytes, one every 10 ms when `spaced` (partial candidates expire), each fed
/// with `push` until nothing more comes: items, counters, held bytes, and the `consumed` of
/// every call.
fn run(mut f: impl Framing, stream: &[u8], chunk: usize, spaced: bool) -> Outcome {
    let mut out = Outcome::default();
    for (i, mut c) in stream.chunks(chunk.max(1)).enumerate() {
        let now = Instant::from_millis(if spaced { i as u64 * 10 } else { 0 });
        loop {
            let p = f.push(c, now);
            out.consumed.push(p.consumed);
            let done = p.item.is_none() && p.consumed == 0;
            if let Some(item) = p.item {
                out.items.push(got(item));
            }
            c = &c[p.consumed..];
            if done {
                break;
            }
        }
    }
    out.counters = f.counters();
    out.held = f.buffered();
    out
}

#[derive(Debug, Default, PartialEq, Eq)]
struct Outcome {
    items: Vec<Got>,
    counters: Counters,
    held: usize,
    consumed: Vec<usize>,
}

fn reply(r: &Reply<'_>) -> Vec<u8> {
    let mut buf = [0u8; MAX_TELEGRAM];
    let n = r.emit(&mut buf).unwrap();
    buf[..n].to_vec()
}

fn arb_frame() -> impl Strategy<Value = Vec<u8>> {
    prop_oneof![
        (0u8..=255).prop_map(|s| reply(&Reply::ResetAck {
            status: StatusByte(s)
        })),
        proptest::collection::vec(any::<u16>(), 0..40)
            .prop_map(|w| reply(&Reply::Scan(Scan::full(&w, Units::Mm, StatusByte::NORMAL)))),
        // B0 values full of STX, ACK, NAK and 0x80: false starts inside a good frame.
        proptest::collection::vec(
            prop_oneof![
                Just(0x8002u16),
                Just(0x0602),
                Just(0x1502),
                Just(0x0280),
                any::<u16>()
            ],
            0..40,
        )
        .prop_map(|w| reply(&Reply::Scan(Scan::full(&w, Units::Mm, StatusByte::NORMAL)))),
    ]
}

/// Noise crowded with the bytes the framer looks for.
fn arb_noise() -> impl Strategy<Value = Vec<u8>> {
    proptest::collection::vec(
        prop_oneof![Just(STX), Just(ACK), Just(NAK), Just(0x80u8), any::<u8>()],
        0..40,
    )
}

/// A frame with one byte flipped (bad CRC or bad header), or cut short.
fn damaged(frame: &[u8], at: usize, cut: bool) -> Vec<u8> {
    let mut f = frame.to_vec();
    let at = at % f.len();
    if cut {
        f.truncate(at);
    } else {
        f[at] ^= 0x5A;
    }
    f
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]

    #[test]
    fn bulk_equals_byte_at_a_time(
        parts in proptest::collection::vec(
            (arb_noise(), arb_frame(), any::<bool>(), any::<usize>(), any::<bool>()),
            1..6,
        ),
        chunk in 2usize..1000,
        commands in any::<bool>(),
        report in any::<bool>(),
    ) {
        let mut stream = Vec::new();
        for (noise, frame, spoil, at, cut) in &parts {
            stream.extend(noise);
            if *spoil {
                stream.extend(damaged(frame, *at, *cut));
            } else {
                stream.extend(frame);
            }
        }
        let direction = if commands { Direction::Commands } else { Direction::Replies };
        for chunk in [1, chunk, stream.len()] {
            for spaced in [false, true] {
                let new = run(
                    Framer::new(direction).report_bad_checksums(report),
                    &stream,
                    chunk,
                    spaced,
                );
                let old = run(
                    RefFramer::new(direction).report_bad_checksums(report),
                    &stream,
                    chunk,
                    spaced,
                );
                prop_assert_eq!(new, old, "chunk {} spaced {}", chunk, spaced);
            }
        }
    }
}

#[test]
fn garbage_is_skipped_in_one_push_and_counted() {
    let garbage: Vec<u8> = (0..5000u32)
        .map(|i| (i * 7 % 251) as u8)
        .filter(|b| ![STX, ACK, NAK].contains(b))
        .collect();
    let mut f = Framer::replies();
    let p = f.push(&garbage, Instant::ZERO);
    assert_eq!((p.consumed, p.item), (garbage.len(), None));
    assert_eq!(f.counters().dropped_bytes, garbage.len() as u64);
    assert_eq!(f.buffered(), 0);

    let mut stream = garbage.clone();
    stream.push(ACK);
    stream.extend(&garbage);
    stream.extend(reply(&Reply::ResetAck {
        status: StatusByte::NORMAL,
    }));
    let o = run(Framer::replies(), &stream, stream.len(), false);
    assert_eq!(o.items.len(), 2);
    assert_eq!(o.items[0], Got::Ack);
    assert!(matches!(o.items[1], Got::Frame(_)));
    assert_eq!(o.counters.dropped_bytes, 2 * garbage.len() as u64);
    assert_eq!((o.counters.acks, o.counters.frames, o.held), (1, 1, 0));
}

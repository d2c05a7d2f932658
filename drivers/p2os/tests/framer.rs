//! Framer behaviour (DESIGN.md "Tests", spec §2 and §10 items 2, 3, 13): many frames per read,
//! one frame over many reads, garbage, `FA FA FB`, truncated frames, bad count bytes, bad
//! checksums, a good frame hidden in a bogus claimed body, exact counters, `abandon_partial`,
//! `clear`, and `feed`/`next_frame` ≡ `push`.

use ima_p2os::framer::{BUFFER_LEN, Rejected};
use ima_p2os::wire::{self, MAX_COMMAND_COUNT};
use ima_p2os::{FrameEvent, Framer, FramerStats};

/// An owned copy of a [`FrameEvent`].
#[derive(Debug, Clone, PartialEq, Eq)]
enum Ev {
    Frame(Vec<u8>),
    Rej(Rejected),
}

fn own(ev: FrameEvent<'_>) -> Ev {
    match ev {
        FrameEvent::Frame(p) => Ev::Frame(p.to_vec()),
        FrameEvent::Rejected(r) => Ev::Rej(r),
    }
}

fn frame(payload: &[u8]) -> Vec<u8> {
    let mut buf = [0u8; wire::MAX_FRAME_LEN];
    let n = wire::encode_frame(payload, &mut buf).unwrap();
    buf[..n].to_vec()
}

/// Push `input` in chunks of `chunk` bytes, collecting every event.
fn push_chunked(f: &mut Framer, input: &[u8], chunk: usize) -> Vec<Ev> {
    let mut out = Vec::new();
    for c in input.chunks(chunk.max(1)) {
        f.push(c, |ev| out.push(own(ev)));
    }
    out
}

fn frames_only(evs: &[Ev]) -> Vec<Vec<u8>> {
    evs.iter()
        .filter_map(|e| match e {
            Ev::Frame(p) => Some(p.clone()),
            Ev::Rej(_) => None,
        })
        .collect()
}

/// The byte-accounting invariant: every byte fed is in a delivered frame, dropped, or buffered.
fn assert_accounted(f: &Framer, fed: usize, evs: &[Ev]) {
    let in_frames: usize = frames_only(evs).iter().map(|p| p.len() + 5).sum();
    assert_eq!(
        in_frames as u64 + f.stats().dropped_bytes + f.buffered() as u64,
        fed as u64,
        "bytes fed = bytes in frames + dropped + buffered"
    );
}

const SIP_T20: &str = "FA FB 21 33 E8 03 F4 01 00 04 CE FF 32 00 7D 00 00 00 04 01 00 00 02 00 4A 07 07 93 0E 00 00 00 FF 0F D9 B2";

fn hex(s: &str) -> Vec<u8> {
    s.split_whitespace()
        .map(|b| u8::from_str_radix(b, 16).unwrap())
        .collect()
}

/// Three distinct frames of different lengths (odd and even payloads).
fn three_frames() -> (Vec<Vec<u8>>, Vec<u8>) {
    let payloads = vec![
        hex(SIP_T20)[3..34].to_vec(),
        vec![0x0B, 0x3B, 0xC8, 0x00],
        vec![0x02, b'P', b'2', b'A', b'T', 0, b'P', 0, b'p', 0],
    ];
    let stream = payloads.iter().flat_map(|p| frame(p)).collect();
    (payloads, stream)
}

#[test]
fn many_frames_per_read() {
    let (payloads, stream) = three_frames();
    let mut f = Framer::new();
    let evs = push_chunked(&mut f, &stream, stream.len());
    assert_eq!(frames_only(&evs), payloads);
    assert_eq!(evs.len(), 3, "no rejections");
    assert_eq!(
        f.stats(),
        FramerStats {
            frames: 3,
            ..FramerStats::default()
        }
    );
    assert_eq!(f.buffered(), 0);
}

#[test]
fn many_frames_per_read_fill_more_than_the_buffer() {
    // 40 T20 SIPs (1,440 bytes, more than BUFFER_LEN) in one push.
    let one = hex(SIP_T20);
    let stream: Vec<u8> = one.iter().copied().cycle().take(one.len() * 40).collect();
    assert!(stream.len() > BUFFER_LEN);
    let mut f = Framer::new();
    let evs = push_chunked(&mut f, &stream, stream.len());
    assert_eq!(evs.len(), 40);
    assert!(evs.iter().all(|e| *e == Ev::Frame(one[3..34].to_vec())));
    assert_eq!(f.stats().frames, 40);
    assert_eq!(f.stats().dropped_bytes, 0);
}

#[test]
fn one_frame_over_many_reads_at_every_split_point() {
    let (payloads, stream) = three_frames();
    for split in 0..=stream.len() {
        let mut f = Framer::new();
        let mut evs = Vec::new();
        f.push(&stream[..split], |ev| evs.push(own(ev)));
        f.push(&stream[split..], |ev| evs.push(own(ev)));
        assert_eq!(frames_only(&evs), payloads, "split at {split}");
        assert_eq!(f.stats().frames, 3);
        assert_eq!(f.stats().dropped_bytes, 0);
    }
    // Two split points: every (i, j) pair.
    for i in 0..=stream.len() {
        for j in i..=stream.len() {
            let mut f = Framer::new();
            let mut evs = Vec::new();
            for part in [&stream[..i], &stream[i..j], &stream[j..]] {
                f.push(part, |ev| evs.push(own(ev)));
            }
            assert_eq!(frames_only(&evs), payloads, "splits at {i}, {j}");
        }
    }
}

#[test]
fn one_byte_reads() {
    let (payloads, stream) = three_frames();
    let mut f = Framer::new();
    let mut evs = Vec::new();
    for (i, b) in stream.iter().enumerate() {
        let before = evs.len();
        f.push(&[*b], |ev| evs.push(own(ev)));
        // A frame comes out exactly when its last byte arrives.
        let ends: Vec<usize> = {
            let mut acc = 0;
            payloads
                .iter()
                .map(|p| {
                    acc += p.len() + 5;
                    acc - 1
                })
                .collect()
        };
        assert_eq!(
            evs.len() - before,
            usize::from(ends.contains(&i)),
            "byte {i}"
        );
    }
    assert_eq!(frames_only(&evs), payloads);
    assert_eq!(f.stats().frames, 3);
}

#[test]
fn feed_then_next_frame_one_byte_at_a_time() {
    let (payloads, stream) = three_frames();
    let mut f = Framer::new();
    let mut got = Vec::new();
    for b in &stream {
        assert_eq!(f.feed(std::slice::from_ref(b)), 1);
        while let Some(ev) = f.next_frame() {
            got.push(own(ev));
        }
    }
    assert_eq!(frames_only(&got), payloads);
}

#[test]
fn garbage_before_and_between_frames_including_fa_and_fa_fb() {
    let (payloads, _) = three_frames();
    let garbage: [&[u8]; 4] = [
        // Plain noise, a lone FA, FA followed by a non-FB.
        &[0x00, 0x13, 0xFA, 0x55, 0xFB, 0xFA, 0x00],
        // FA FB with an undersized count, then FA FB with a count claiming part of the next
        // frame (bad checksum), then FA FA.
        &[0xFA, 0xFB, 0x01, 0xFA, 0xFB, 0x05, 0xFA, 0xFA],
        // FB alone, FA FB 02 (undersized), trailing FA.
        &[0xFB, 0xFA, 0xFB, 0x02, 0xFA],
        // Garbage after the last frame, ending in a lone FB.
        &[0x01, 0x02, 0xFB],
    ];
    let mut stream = Vec::new();
    for (g, p) in garbage.iter().zip(&payloads) {
        stream.extend_from_slice(g);
        stream.extend(frame(p));
    }
    stream.extend_from_slice(garbage[3]);
    for chunk in [1, 2, 3, 7, 64, stream.len()] {
        let mut f = Framer::new();
        let evs = push_chunked(&mut f, &stream, chunk);
        assert_eq!(frames_only(&evs), payloads, "chunk {chunk}");
        let s = f.stats();
        assert_eq!(s.frames, 3);
        assert_eq!(s.bad_counts, 2, "FA FB 01 and FA FB 02");
        assert_eq!(s.bad_checksums, 1, "FA FB 05 …");
        assert_eq!(f.buffered(), 0);
        let garbage_len: usize = garbage.iter().map(|g| g.len()).sum();
        assert_eq!(s.dropped_bytes, garbage_len as u64, "chunk {chunk}");
        assert_accounted(&f, stream.len(), &evs);
    }
}

#[test]
fn fa_fa_fb_header_is_found() {
    let p = [0x1D];
    let mut stream = vec![0xFA];
    stream.extend(frame(&p));
    assert_eq!(&stream[..3], &[0xFA, 0xFA, 0xFB]);
    for chunk in 1..=stream.len() {
        let mut f = Framer::new();
        let evs = push_chunked(&mut f, &stream, chunk);
        assert_eq!(evs, vec![Ev::Frame(p.to_vec())], "chunk {chunk}");
        assert_eq!(f.stats().dropped_bytes, 1);
    }
    // Several FAs in a row.
    let mut stream = vec![0xFA; 5];
    stream.extend(frame(&p));
    let mut f = Framer::new();
    assert_eq!(
        push_chunked(&mut f, &stream, 1),
        vec![Ev::Frame(p.to_vec())]
    );
    assert_eq!(f.stats().dropped_bytes, 5);
}

#[test]
fn truncated_frame_then_a_good_one() {
    let sip = hex(SIP_T20);
    let good = frame(&[0x04, 0x3B, 0x01, 0x00]);
    // The first 10 bytes of a SIP (it claims 33 more bytes after the count), then a good frame
    // and enough padding to complete the bogus claim.
    let mut stream = sip[..10].to_vec();
    stream.extend(&good);
    stream.extend([0x00; 30]);
    for chunk in [1, 5, stream.len()] {
        let mut f = Framer::new();
        let evs = push_chunked(&mut f, &stream, chunk);
        assert_eq!(
            frames_only(&evs),
            vec![good[3..7].to_vec()],
            "chunk {chunk}"
        );
        assert_eq!(f.stats().bad_checksums, 1);
        assert_eq!(f.stats().dropped_bytes, 10 + 30);
        assert_eq!(f.buffered(), 0);
    }
}

#[test]
fn truncated_frame_at_end_of_stream_waits_then_is_abandoned() {
    let sip = hex(SIP_T20);
    let good = frame(&[0x1D]);
    let mut stream = good.clone();
    stream.extend(&sip[..20]);
    let mut f = Framer::new();
    let evs = push_chunked(&mut f, &stream, 3);
    assert_eq!(frames_only(&evs), vec![vec![0x1D]]);
    assert_eq!(f.buffered(), 20, "the partial SIP waits for more bytes");
    assert_eq!(f.stats().dropped_bytes, 0);
    // The caller's inter-byte timeout fires: the partial frame is given up, and what follows
    // its header byte is rescanned (here: no other header, so all of it is dropped).
    assert!(f.abandon_partial());
    let mut more = Vec::new();
    while let Some(ev) = f.next_frame() {
        more.push(own(ev));
    }
    assert!(more.is_empty());
    assert_eq!(f.stats().abandoned, 1);
    assert_eq!(f.stats().dropped_bytes, 20);
    assert_eq!(f.buffered(), 0);
    assert!(!f.abandon_partial(), "nothing left to abandon");
    assert_eq!(f.stats().abandoned, 1);
}

#[test]
fn abandon_partial_rescans_the_partial_frame() {
    // A bogus header claims 0x40 bytes; inside its claimed body sits a complete good frame,
    // and the stream then goes quiet before the claim is satisfied.
    let good = frame(&[0x0B, 0x3B, 0xC8, 0x00]);
    let mut stream = vec![0xFA, 0xFB, 0x40, 0x11];
    stream.extend(&good);
    stream.extend([0x22, 0x33]);
    let mut f = Framer::new();
    let evs = push_chunked(&mut f, &stream, stream.len());
    assert!(evs.is_empty(), "still waiting for the bogus claim");
    assert_eq!(f.buffered(), stream.len());
    assert!(f.abandon_partial());
    let mut evs = Vec::new();
    while let Some(ev) = f.next_frame() {
        evs.push(own(ev));
    }
    assert_eq!(evs, vec![Ev::Frame(good[3..7].to_vec())]);
    let s = f.stats();
    assert_eq!(s.abandoned, 1);
    assert_eq!(s.frames, 1);
    // FA (abandoned) + FB 40 11 (hunt) + 22 33 (hunt after the frame).
    assert_eq!(s.dropped_bytes, 6);
    assert_eq!(f.buffered(), 0);
}

#[test]
fn undersized_count_bytes_are_rejected() {
    for count in 0..wire::MIN_COUNT {
        let good = frame(&[0x1D]);
        let mut stream = vec![0xFA, 0xFB, count];
        stream.extend(&good);
        let mut f = Framer::new();
        let evs = push_chunked(&mut f, &stream, 1);
        assert_eq!(
            evs,
            vec![Ev::Rej(Rejected::BadCount(count)), Ev::Frame(vec![0x1D])]
        );
        assert_eq!(f.stats().bad_counts, 1);
        assert_eq!(f.stats().dropped_bytes, 3);
    }
}

#[test]
fn oversize_count_byte_for_commands_and_largest_frames_from_the_robot() {
    // A frame with a valid checksum and count 201.
    let payload: Vec<u8> = (0..199u8).collect();
    let big = frame(&payload);
    assert_eq!(big[2], 201);
    let good = frame(&[0x1D]);
    let mut stream = big.clone();
    stream.extend(&good);

    // Host → robot: P2OS ignores count > 200, so the framer rejects it and resyncs.
    let mut f = Framer::for_commands();
    let evs = push_chunked(&mut f, &stream, 7);
    assert_eq!(evs[0], Ev::Rej(Rejected::BadCount(201)));
    assert_eq!(frames_only(&evs), vec![vec![0x1D]]);
    assert_eq!(f.stats().bad_counts, 1);
    assert_eq!(f.stats().frames, 1);

    // Exactly 200 is accepted by `for_commands`.
    let p200: Vec<u8> = (0..198u8).collect();
    let f200 = frame(&p200);
    assert_eq!(f200[2], MAX_COMMAND_COUNT);
    let mut f = Framer::for_commands();
    assert_eq!(push_chunked(&mut f, &f200, 13), vec![Ev::Frame(p200)]);

    // Robot → host: any count 3..=255 is accepted (spec §2 choice, §10 item 3).
    let mut f = Framer::new();
    let evs = push_chunked(&mut f, &stream, 7);
    assert_eq!(frames_only(&evs), vec![payload, vec![0x1D]]);
    let p255: Vec<u8> = (0..253u8).map(|i| i.wrapping_mul(7)).collect();
    let f255 = frame(&p255);
    assert_eq!(f255[2], 255);
    let mut f = Framer::new();
    assert_eq!(
        push_chunked(&mut f, &f255, 1),
        vec![Ev::Frame(p255.clone())]
    );

    // A custom limit.
    let mut f = Framer::with_max_count(10);
    let evs = push_chunked(&mut f, &f255, 64);
    assert_eq!(evs.first(), Some(&Ev::Rej(Rejected::BadCount(255))));
    assert_eq!(f.stats().frames, 0);
}

#[test]
fn bad_checksum_then_a_good_frame() {
    let mut bad = frame(&[0x0B, 0x3B, 0xC8, 0x00]);
    let n = bad.len();
    bad[n - 1] ^= 0x01;
    let good = frame(&[0x0B, 0x1B, 0xC8, 0x00]);
    let mut stream = bad.clone();
    stream.extend(&good);
    for chunk in 1..=stream.len() {
        let mut f = Framer::new();
        let evs = push_chunked(&mut f, &stream, chunk);
        assert_eq!(
            evs,
            vec![
                Ev::Rej(Rejected::BadChecksum {
                    expected: 0xD33B,
                    got: 0xD33A
                }),
                Ev::Frame(good[3..7].to_vec())
            ],
            "chunk {chunk}"
        );
        assert_eq!(f.stats().bad_checksums, 1);
        assert_eq!(f.stats().dropped_bytes, bad.len() as u64);
    }
}

#[test]
fn good_frame_hidden_in_the_claimed_body_of_a_bogus_header_is_found() {
    // FA FB 20 claims 32 bytes; a complete good frame sits inside that claim. A receiver that
    // skips the claimed body (ARIA, ROS; spec §10 item 2) would lose it.
    let good = hex(SIP_T20);
    let mut stream = vec![0xFA, 0xFB, 0x20];
    stream.extend(&good);
    let good2 = frame(&[0x1D]);
    stream.extend(&good2);
    for chunk in [1, 2, 5, 36, stream.len()] {
        let mut f = Framer::new();
        let evs = push_chunked(&mut f, &stream, chunk);
        assert!(matches!(evs[0], Ev::Rej(Rejected::BadChecksum { .. })));
        assert_eq!(
            frames_only(&evs),
            vec![good[3..34].to_vec(), vec![0x1D]],
            "chunk {chunk}"
        );
        assert_eq!(f.stats().dropped_bytes, 3);
        assert_eq!(f.stats().bad_checksums, 1);
    }
    // The same with a claim longer than the rest of the stream: still found once the claim is
    // given up (abandon_partial) — and found at once if the claim is satisfiable.
    let mut stream = vec![0xFA, 0xFB, 0xFF];
    stream.extend(&good);
    let mut f = Framer::new();
    assert!(push_chunked(&mut f, &stream, 4).is_empty());
    assert!(f.abandon_partial());
    let mut evs = Vec::new();
    while let Some(ev) = f.next_frame() {
        evs.push(own(ev));
    }
    assert_eq!(evs, vec![Ev::Frame(good[3..34].to_vec())]);
}

#[test]
fn stats_counters_are_exact() {
    let good = frame(&[0x1D]);
    let mut bad_sum = frame(&[0x0B, 0x3B, 0xC8, 0x00]);
    bad_sum[5] ^= 0x40;
    let mut stream = Vec::new();
    stream.extend([0x00, 0x01, 0x02]); // 3 dropped
    stream.extend(&good); // frame 1
    stream.extend([0xFA, 0xFB, 0x00]); // bad count, 3 dropped
    stream.extend(&good); // frame 2
    stream.extend(&bad_sum); // bad checksum, 9 dropped (no FA inside after byte 0)
    stream.extend(&good); // frame 3
    stream.extend([0xFA, 0x00]); // 2 dropped
    let mut f = Framer::new();
    let evs = push_chunked(&mut f, &stream, 4);
    assert_eq!(
        f.stats(),
        FramerStats {
            frames: 3,
            dropped_bytes: 3 + 3 + 9 + 2,
            bad_checksums: 1,
            bad_counts: 1,
            abandoned: 0,
        }
    );
    assert_eq!(evs.len(), 5);
    assert_accounted(&f, stream.len(), &evs);
    f.reset_stats();
    assert_eq!(f.stats(), FramerStats::default());
}

#[test]
fn clear_forgets_buffered_bytes_and_counts_them() {
    let sip = hex(SIP_T20);
    let mut f = Framer::new();
    assert!(push_chunked(&mut f, &sip[..15], 15).is_empty());
    assert_eq!(f.buffered(), 15);
    f.clear();
    assert_eq!(f.buffered(), 0);
    assert_eq!(f.stats().dropped_bytes, 15);
    // The rest of that SIP is now garbage; the next whole one comes through.
    let mut stream = sip[15..].to_vec();
    stream.extend(&sip);
    let evs = push_chunked(&mut f, &stream, 8);
    assert_eq!(evs, vec![Ev::Frame(sip[3..34].to_vec())]);
    assert_eq!(f.stats().dropped_bytes, 15 + (sip.len() - 15) as u64);
    // Clearing an empty framer changes nothing.
    let before = f.stats();
    f.clear();
    assert_eq!(f.stats(), before);
}

#[test]
fn feed_returns_how_much_fits() {
    let mut f = Framer::new();
    // A header claiming 255 bytes keeps everything buffered.
    let mut big = vec![0xFA, 0xFB, 0xFF];
    // (0x01 filler: an all-zero body would carry a valid checksum of 0.)
    big.extend(vec![0x01; 2 * BUFFER_LEN]);
    let n = f.feed(&big);
    assert_eq!(n, BUFFER_LEN);
    // The claim is complete within the buffer: it is rejected and the rest is hunted through.
    let mut evs = Vec::new();
    while let Some(ev) = f.next_frame() {
        evs.push(own(ev));
    }
    assert!(matches!(evs[..], [Ev::Rej(Rejected::BadChecksum { .. })]));
    assert_eq!(f.buffered(), 0);
    assert_eq!(f.feed(&big[n..]), BUFFER_LEN);
}

/// Events from `push` equal those from `feed` + `next_frame` driven by hand, for a stream with
/// garbage, rejections and frames, for many chunkings.
#[test]
fn feed_next_frame_and_push_are_equivalent() {
    let (payloads, _) = three_frames();
    let mut stream = Vec::new();
    for (i, p) in payloads.iter().cycle().take(30).enumerate() {
        stream.extend(frame(p));
        match i % 4 {
            0 => stream.extend([0xFA, 0xFB, 0x01]),
            1 => stream.extend([0xFA, 0xFB, 0x10, 0xFA]),
            2 => stream.extend([0x00, 0xFA, 0xFA]),
            _ => {}
        }
    }
    for chunk in [1, 3, 17, 100, 600, stream.len()] {
        let mut a = Framer::new();
        let by_push = push_chunked(&mut a, &stream, chunk);

        let mut b = Framer::new();
        let mut by_hand = Vec::new();
        for c in stream.chunks(chunk) {
            let mut rest = c;
            while !rest.is_empty() {
                let n = b.feed(rest);
                rest = &rest[n..];
                while let Some(ev) = b.next_frame() {
                    by_hand.push(own(ev));
                }
            }
        }
        assert_eq!(by_push, by_hand, "chunk {chunk}");
        assert_eq!(a.stats(), b.stats());
        assert_eq!(a.buffered(), b.buffered());
        assert_eq!(frames_only(&by_push).len(), 30);
        assert_accounted(&a, stream.len(), &by_push);
    }
}

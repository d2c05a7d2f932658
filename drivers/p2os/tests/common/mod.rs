//! Realistic SIP streams for the corruption test and the benchmark: a P2-AT driving about at
//! up to ~1 m/s, ~10 SIPs/s, with a varied number of fresh sonar readings per SIP (spec §7.1,
//! §8 "sonar timing": ≈5 per SIP on average, sometimes none, sometimes a full ring of 16).

#![allow(dead_code)]

use ima_p2os::wire::{self, Packet, Sip, SonarRaw};
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};

/// One SIP of a robot that is at `(x, y)` (platform units) at step `i`.
pub fn realistic_sip(rng: &mut SmallRng, i: usize) -> Sip {
    let k = match rng.random_range(0..100u32) {
        0..=9 => 0,
        10..=89 => rng.random_range(1..=8),
        90..=96 => rng.random_range(9..=15),
        _ => 16,
    };
    let first = rng.random_range(0..16u8);
    let sonars = (0..k)
        .map(|j| SonarRaw {
            index: (first + j) % 16,
            range: rng.random_range(373..=18_657),
        })
        .collect();
    let v: i16 = rng.random_range(-50..=800);
    let w: i16 = rng.random_range(-100..=100);
    Sip {
        moving: v != 0,
        // Odometry creeping forward, wrapping at 15 bits like the real thing.
        xpos: (i as u16).wrapping_mul(3) & 0x7FFF,
        ypos: (i as u16 / 7) & 0x7FFF,
        thpos: (i as i16).wrapping_mul(5) % 2048,
        left_vel: v - w,
        right_vel: v + w,
        battery: rng.random_range(118..=130),
        stall_bumpers: if rng.random_bool(0.02) { 0x0101 } else { 0 },
        control: (i as i16) % 2048,
        flags: 0x001F,
        compass: 0,
        sonars,
        grip_state: 0,
        anport: 0,
        analog: rng.random(),
        digin: 0xFF,
        digout: 0x0F,
        extra_len: 0,
    }
}

/// A stream of `n` SIP frames: the bytes, each frame's `[start, end)` span, and the SIPs.
pub fn sip_stream(seed: u64, n: usize) -> (Vec<u8>, Vec<(usize, usize)>, Vec<Sip>) {
    let mut rng = SmallRng::seed_from_u64(seed);
    let mut bytes = Vec::with_capacity(n * 45);
    let mut spans = Vec::with_capacity(n);
    let mut sips = Vec::with_capacity(n);
    let mut buf = [0u8; wire::MAX_FRAME_LEN];
    for i in 0..n {
        let sip = realistic_sip(&mut rng, i);
        let len = Packet::Sip(sip.clone())
            .emit(&mut buf)
            .expect("SIP fits a frame");
        spans.push((bytes.len(), bytes.len() + len));
        bytes.extend_from_slice(&buf[..len]);
        sips.push(sip);
    }
    (bytes, spans, sips)
}

/// A stream of realistic SIP frames of at least `min_len` bytes.
pub fn sip_stream_bytes(seed: u64, min_len: usize) -> Vec<u8> {
    let mut rng = SmallRng::seed_from_u64(seed);
    let mut bytes = Vec::with_capacity(min_len + wire::MAX_FRAME_LEN);
    let mut buf = [0u8; wire::MAX_FRAME_LEN];
    let mut i = 0;
    while bytes.len() < min_len {
        let sip = realistic_sip(&mut rng, i);
        let len = Packet::Sip(sip).emit(&mut buf).expect("SIP fits a frame");
        bytes.extend_from_slice(&buf[..len]);
        i += 1;
    }
    bytes
}

/// Corrupt each byte with probability `p` (replaced by a different value); returns the
/// positions changed, in order.
pub fn corrupt(bytes: &mut [u8], p: f64, seed: u64) -> Vec<usize> {
    let mut rng = SmallRng::seed_from_u64(seed);
    let mut changed = Vec::new();
    for (i, b) in bytes.iter_mut().enumerate() {
        if rng.random_bool(p) {
            *b ^= rng.random_range(1..=255u8);
            changed.push(i);
        }
    }
    changed
}

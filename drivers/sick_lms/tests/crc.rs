//! The sixteen-bytes-at-a-time `crc16` against the bit-serial definition `crc16_bitwise`
//! (spec §1.1): random contents and lengths, every length around the block sizes, and the
//! spec's vectors through both.

use ima_sick_lms::wire::{crc16, crc16_bitwise};
use proptest::prelude::*;

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2048))]

    #[test]
    fn fast_equals_bitwise(bytes in proptest::collection::vec(any::<u8>(), 0..2000)) {
        prop_assert_eq!(crc16(&bytes), crc16_bitwise(&bytes));
    }

    /// Every suffix and prefix: the block/remainder split lands everywhere.
    #[test]
    fn fast_equals_bitwise_on_every_cut(bytes in proptest::collection::vec(any::<u8>(), 0..80)) {
        for i in 0..=bytes.len() {
            prop_assert_eq!(crc16(&bytes[i..]), crc16_bitwise(&bytes[i..]));
            prop_assert_eq!(crc16(&bytes[..i]), crc16_bitwise(&bytes[..i]));
        }
    }

    /// Sparse inputs (mostly zero, a few set bits) find a wrong table entry or fold mask fast.
    #[test]
    fn fast_equals_bitwise_sparse(
        len in 0usize..900,
        bits in proptest::collection::vec((any::<usize>(), 0u8..8), 1..4),
    ) {
        let mut bytes = vec![0u8; len];
        for (at, bit) in bits {
            if len > 0 {
                bytes[at % len] ^= 1 << bit;
            }
        }
        prop_assert_eq!(crc16(&bytes), crc16_bitwise(&bytes));
    }
}

#[test]
fn every_single_bit_up_to_48_bytes() {
    for len in 1..=48 {
        for bit in 0..len * 8 {
            let mut bytes = vec![0u8; len];
            bytes[bit / 8] = 1 << (bit % 8);
            assert_eq!(crc16(&bytes), crc16_bitwise(&bytes), "len {len} bit {bit}");
        }
    }
}

#[test]
fn constant_fills_up_to_max_telegram() {
    for fill in [0x00u8, 0xFF, 0x02, 0x80, 0xAA] {
        for len in 0..=ima_sick_lms::wire::MAX_TELEGRAM {
            let bytes = vec![fill; len];
            assert_eq!(
                crc16(&bytes),
                crc16_bitwise(&bytes),
                "fill {fill:#04x} len {len}"
            );
        }
    }
}

#[test]
fn spec_vectors_through_both() {
    for (bytes, crc) in [
        (&b"123456789"[..], 0xA656u16),
        (&[][..], 0),
        (&[0x02, 0x00, 0x02, 0x00, 0x20, 0x25][..], 0x0835),
        (&[0x02, 0x00, 0x02, 0x00, 0x20, 0x24][..], 0x0834),
    ] {
        assert_eq!(crc16(bytes), crc, "{bytes:02x?}");
        assert_eq!(crc16_bitwise(bytes), crc, "{bytes:02x?}");
    }
}

//! The queue between the robot's threads and the recorder's: one growable byte buffer of
//! records, appended to under a short lock and swapped out whole by the recorder's thread.
//! A message costs its caller a copy of its numbers or bytes, never a heap allocation (the
//! buffers keep their capacity from one batch to the next).
//!
//! A record: stream id (`u32`), [`Kind`] (`u8`), log time (`u64`, Unix ns), payload length
//! (`u32`), all little-endian, then the payload. What a payload holds depends on the kind
//! (see [`Kind`]); the recorder's thread turns it into the stream's message.

/// Bytes before a record's payload.
pub(crate) const HEADER: usize = 17;

/// What a record's payload holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Kind {
    /// The message itself, encoded (raw serial bytes, JSON, any `foxglove::Encode`).
    Encoded = 0,
    /// A laser scan: start angle and step (`f64`, radians), then the ranges (`f32`, metres).
    Scan = 1,
    /// A planar pose: x, y (metres), heading (radians), each `f64`.
    Pose = 2,
    /// A camera frame: width and height (`u32`), then the `rgb8` pixels.
    Image = 3,
    /// A point cloud's packed points.
    Cloud = 4,
    /// A log line: its level (`u8`), then the text (UTF-8).
    Text = 5,
}

impl Kind {
    fn from_byte(b: u8) -> Option<Self> {
        Some(match b {
            0 => Self::Encoded,
            1 => Self::Scan,
            2 => Self::Pose,
            3 => Self::Image,
            4 => Self::Cloud,
            5 => Self::Text,
            _ => return None,
        })
    }
}

/// The records logged since the recorder's thread last took them.
#[derive(Debug, Default)]
pub(crate) struct Batch {
    pub(crate) bytes: Vec<u8>,
    pub(crate) msgs: usize,
    /// Where the last whole record ends: a payload whose writer panicked (the lock is then
    /// poisoned, and taken over) leaves no half record behind.
    pub(crate) whole: usize,
}

impl Batch {
    /// Append a record of stream `id`; `write` appends the payload and says whether it
    /// could (if not, the record is taken back). Returns whether it was kept.
    pub(crate) fn push(
        &mut self,
        id: u32,
        kind: Kind,
        log_time: u64,
        write: impl FnOnce(&mut Vec<u8>) -> bool,
    ) -> bool {
        self.bytes.truncate(self.whole);
        let start = self.bytes.len();
        self.bytes.extend_from_slice(&id.to_le_bytes());
        self.bytes.push(kind as u8);
        self.bytes.extend_from_slice(&log_time.to_le_bytes());
        self.bytes.extend_from_slice(&[0; 4]);
        let len = write(&mut self.bytes)
            .then(|| u32::try_from(self.bytes.len() - start - HEADER).ok())
            .flatten();
        match (len, self.bytes.get_mut(start + HEADER - 4..start + HEADER)) {
            (Some(len), Some(slot)) => {
                slot.copy_from_slice(&len.to_le_bytes());
                self.msgs += 1;
                self.whole = self.bytes.len();
                true
            }
            _ => {
                self.bytes.truncate(start);
                false
            }
        }
    }
}

/// One record of a drained batch.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Record<'a> {
    pub(crate) id: u32,
    pub(crate) kind: Kind,
    pub(crate) log_time: u64,
    pub(crate) payload: &'a [u8],
}

/// The records of a drained batch, in the order they were logged.
pub(crate) fn records(mut rest: &[u8]) -> impl Iterator<Item = Record<'_>> {
    std::iter::from_fn(move || {
        let (head, tail) = rest.split_at_checked(HEADER)?;
        let id = u32::from_le_bytes(head.get(0..4)?.try_into().ok()?);
        let kind = Kind::from_byte(*head.get(4)?)?;
        let log_time = u64::from_le_bytes(head.get(5..13)?.try_into().ok()?);
        let len = u32::from_le_bytes(head.get(13..17)?.try_into().ok()?);
        let (payload, tail) = tail.split_at_checked(usize::try_from(len).ok()?)?;
        rest = tail;
        Some(Record {
            id,
            kind,
            log_time,
            payload,
        })
    })
}

/// `f64`s from the front of `b` (little-endian), and what follows them.
pub(crate) fn f64s<const N: usize>(b: &[u8]) -> Option<([f64; N], &[u8])> {
    let mut out = [0.0; N];
    let mut rest = b;
    for v in &mut out {
        let (x, tail) = rest.split_first_chunk::<8>()?;
        *v = f64::from_le_bytes(*x);
        rest = tail;
    }
    Some((out, rest))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn records_come_back_as_pushed_and_a_refused_payload_leaves_nothing() {
        let mut b = Batch::default();
        assert!(b.push(7, Kind::Pose, 42, |v| {
            for x in [1.0f64, 2.0, 3.0] {
                v.extend_from_slice(&x.to_le_bytes());
            }
            true
        }));
        assert!(!b.push(8, Kind::Text, 43, |v| {
            v.extend_from_slice(b"half written");
            false
        }));
        assert!(b.push(9, Kind::Encoded, 44, |v| {
            v.extend_from_slice(b"\x01abc");
            true
        }));
        assert!(b.push(10, Kind::Cloud, 45, |_| true));
        assert_eq!(b.msgs, 3);
        let got: Vec<Record<'_>> = records(&b.bytes).collect();
        assert_eq!(got.len(), 3);
        assert_eq!(
            (got[0].id, got[0].kind, got[0].log_time),
            (7, Kind::Pose, 42)
        );
        assert_eq!(f64s::<3>(got[0].payload), Some(([1.0, 2.0, 3.0], &[][..])));
        assert_eq!((got[1].id, got[1].payload), (9, &b"\x01abc"[..]));
        assert_eq!((got[2].id, got[2].payload), (10, &[][..]));
    }

    #[test]
    fn a_payload_writer_that_panics_leaves_no_half_record() {
        let mut b = Batch::default();
        b.push(1, Kind::Encoded, 1, |v| {
            v.extend_from_slice(b"kept");
            true
        });
        let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            b.push(2, Kind::Encoded, 2, |v| {
                v.extend_from_slice(b"half");
                panic!("a Serialize impl failed")
            })
        }));
        assert!(r.is_err());
        b.push(3, Kind::Encoded, 3, |v| {
            v.extend_from_slice(b"next");
            true
        });
        let got: Vec<(u32, &[u8])> = records(&b.bytes[..b.whole])
            .map(|r| (r.id, r.payload))
            .collect();
        assert_eq!(got, [(1, &b"kept"[..]), (3, &b"next"[..])]);
    }

    #[test]
    fn a_cut_buffer_ends_the_records_without_panicking() {
        let mut b = Batch::default();
        b.push(1, Kind::Encoded, 1, |v| {
            v.extend_from_slice(&[0xAA; 40]);
            true
        });
        for cut in 0..b.bytes.len() {
            assert_eq!(records(&b.bytes[..cut]).count(), 0, "cut at {cut}");
        }
        assert_eq!(f64s::<2>(&[0; 15]), None);
    }
}

//! Byte cursors for wire formats: a [`Reader`] over received bytes and a [`Writer`] into an
//! output buffer. `no_std`, no heap, no panics: a read past the end is a [`Truncated`], a
//! write past the end an [`Overflow`], each saying how far it got, and the cursor is left
//! where it was.
//!
//! Integers are read and written by width and byte order: `r.le::<u16>()`, `w.be(v_u32)`.
//! The order is always spelled out, because the drivers' protocols use both (P2OS and SICK
//! little-endian, rFLEX big-endian).
//!
//! ```
//! use ima_hal::bytes::{Reader, Writer};
//!
//! let mut buf = [0u8; 8];
//! let mut w = Writer::new(&mut buf);
//! w.u8(0x02)?.le(0x0304u16)?.be(-2i16)?;
//! assert_eq!(w.written(), [0x02, 0x04, 0x03, 0xFF, 0xFE]);
//!
//! let mut r = Reader::new(&[0x02, 0x04, 0x03, 0xFF, 0xFE]);
//! assert_eq!(r.u8()?, 2);
//! assert_eq!(r.le::<u16>()?, 0x0304);
//! assert_eq!(r.be::<i16>()?, -2);
//! assert!(r.u8().is_err());
//! # Ok::<(), Box<dyn core::error::Error>>(())
//! ```
use core::fmt;

/// A read wanted more bytes than were left.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Truncated {
    /// Bytes the read needed.
    pub wanted: usize,
    /// Bytes that were left.
    pub left: usize,
}

impl fmt::Display for Truncated {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "truncated: a read of {} bytes with {} left",
            self.wanted, self.left
        )
    }
}

impl core::error::Error for Truncated {}

/// A write did not fit in the output buffer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Overflow {
    /// Where the write would have started.
    pub at: usize,
    /// Bytes the write needed.
    pub wanted: usize,
    /// Size of the buffer.
    pub capacity: usize,
}

impl Overflow {
    /// The length the output would have had with this write: `at + wanted` (saturating).
    #[must_use]
    pub const fn needed(&self) -> usize {
        self.at.saturating_add(self.wanted)
    }
}

impl fmt::Display for Overflow {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "output buffer too small: {} bytes at offset {} in a buffer of {}",
            self.wanted, self.at, self.capacity
        )
    }
}

impl core::error::Error for Overflow {}

/// Implement `From<Truncated>` and/or `From<Overflow>` for a wire error, so that `?` turns
/// a cursor's error into the protocol's own:
///
/// ```
/// # #[derive(Debug, PartialEq)]
/// enum WireError { Truncated, TooLong(usize) }
/// ima_hal::cursor_errors!(WireError {
///     truncated: |_| WireError::Truncated,
///     overflow: |o| WireError::TooLong(o.needed()),
/// });
/// let e: WireError = ima_hal::bytes::Reader::new(&[]).u8().unwrap_err().into();
/// assert_eq!(e, WireError::Truncated);
/// ```
#[macro_export]
macro_rules! cursor_errors {
    ($error:ty { $($kind:ident: |$e:pat_param| $value:expr),+ $(,)? }) => {
        $( $crate::cursor_errors!(@one $error, $kind, $e, $value); )+
    };
    (@one $error:ty, truncated, $e:pat_param, $value:expr) => {
        impl From<$crate::bytes::Truncated> for $error {
            fn from($e: $crate::bytes::Truncated) -> Self {
                $value
            }
        }
    };
    (@one $error:ty, overflow, $e:pat_param, $value:expr) => {
        impl From<$crate::bytes::Overflow> for $error {
            fn from($e: $crate::bytes::Overflow) -> Self {
                $value
            }
        }
    };
}

mod sealed {
    pub trait Sealed {}
}

/// A fixed-width integer the cursors read and write (`u8` … `u64`, `i8` … `i64`).
pub trait Int: sealed::Sealed + Copy {
    /// Its width in bytes.
    const SIZE: usize;
    /// Its bytes.
    type Bytes: AsRef<[u8]>;
    /// The little-endian value at the front of `bytes` and the rest, if there is room.
    fn split_le(bytes: &[u8]) -> Option<(Self, &[u8])>;
    /// The big-endian value at the front of `bytes` and the rest, if there is room.
    fn split_be(bytes: &[u8]) -> Option<(Self, &[u8])>;
    /// Little-endian bytes.
    fn to_le(self) -> Self::Bytes;
    /// Big-endian bytes.
    fn to_be(self) -> Self::Bytes;
}

macro_rules! int {
    ($($t:ty),*) => {$(
        impl sealed::Sealed for $t {}
        impl Int for $t {
            const SIZE: usize = core::mem::size_of::<$t>();
            type Bytes = [u8; core::mem::size_of::<$t>()];
            #[inline(always)]
            fn split_le(bytes: &[u8]) -> Option<(Self, &[u8])> {
                let (head, tail) = bytes.split_first_chunk::<{ core::mem::size_of::<$t>() }>()?;
                Some((<$t>::from_le_bytes(*head), tail))
            }
            #[inline(always)]
            fn split_be(bytes: &[u8]) -> Option<(Self, &[u8])> {
                let (head, tail) = bytes.split_first_chunk::<{ core::mem::size_of::<$t>() }>()?;
                Some((<$t>::from_be_bytes(*head), tail))
            }
            #[inline(always)]
            fn to_le(self) -> Self::Bytes {
                self.to_le_bytes()
            }
            #[inline(always)]
            fn to_be(self) -> Self::Bytes {
                self.to_be_bytes()
            }
        }
    )*};
}

int!(u8, i8, u16, i16, u32, i32, u64, i64);

/// Reads a byte slice front to back. Every read either takes exactly what it asks for or
/// fails with [`Truncated`] and takes nothing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Reader<'a> {
    rest: &'a [u8],
}

impl<'a> Reader<'a> {
    /// A reader at the start of `bytes`.
    #[inline]
    #[must_use]
    pub const fn new(bytes: &'a [u8]) -> Self {
        Self { rest: bytes }
    }

    /// How many bytes are left.
    #[inline]
    #[must_use]
    pub const fn remaining(&self) -> usize {
        self.rest.len()
    }

    /// Nothing is left.
    #[inline]
    #[must_use]
    pub const fn is_empty(&self) -> bool {
        self.rest.is_empty()
    }

    /// The bytes left, without taking them.
    #[inline]
    #[must_use]
    pub const fn rest(&self) -> &'a [u8] {
        self.rest
    }

    /// Take the next `n` bytes.
    ///
    /// # Errors
    /// [`Truncated`] when fewer than `n` are left.
    #[inline]
    pub fn take(&mut self, n: usize) -> Result<&'a [u8], Truncated> {
        match self.rest.split_at_checked(n) {
            Some((head, tail)) => {
                self.rest = tail;
                Ok(head)
            }
            None => Err(self.short(n)),
        }
    }

    /// Take everything left (possibly nothing).
    #[inline]
    pub fn take_rest(&mut self) -> &'a [u8] {
        core::mem::take(&mut self.rest)
    }

    /// Take the bytes before the next `delimiter` and consume the delimiter; without one,
    /// take everything left (an unterminated last field).
    ///
    /// # Errors
    /// [`Truncated`] when nothing is left.
    #[inline]
    pub fn take_until(&mut self, delimiter: u8) -> Result<&'a [u8], Truncated> {
        if self.rest.is_empty() {
            return Err(Truncated { wanted: 1, left: 0 });
        }
        let end = self
            .rest
            .iter()
            .position(|&b| b == delimiter)
            .unwrap_or(self.rest.len());
        let (field, tail) = self.rest.split_at(end);
        self.rest = tail.get(1..).unwrap_or_default();
        Ok(field)
    }

    /// Skip `n` bytes.
    ///
    /// # Errors
    /// [`Truncated`] when fewer than `n` are left.
    #[inline]
    pub fn skip(&mut self, n: usize) -> Result<(), Truncated> {
        self.take(n).map(|_| ())
    }

    /// The next `N` bytes as an array.
    ///
    /// # Errors
    /// [`Truncated`] when fewer than `N` are left.
    #[inline]
    pub fn array<const N: usize>(&mut self) -> Result<[u8; N], Truncated> {
        match self.rest.split_first_chunk::<N>() {
            Some((head, tail)) => {
                self.rest = tail;
                Ok(*head)
            }
            None => Err(self.short(N)),
        }
    }

    /// The next byte.
    ///
    /// # Errors
    /// [`Truncated`] when nothing is left.
    #[inline]
    pub fn u8(&mut self) -> Result<u8, Truncated> {
        match self.rest.split_first() {
            Some((&b, tail)) => {
                self.rest = tail;
                Ok(b)
            }
            None => Err(self.short(1)),
        }
    }

    /// The next little-endian integer.
    ///
    /// # Errors
    /// [`Truncated`] when fewer than its width are left.
    #[inline]
    pub fn le<T: Int>(&mut self) -> Result<T, Truncated> {
        self.int(T::split_le)
    }

    /// The next big-endian integer.
    ///
    /// # Errors
    /// [`Truncated`] when fewer than its width are left.
    #[inline]
    pub fn be<T: Int>(&mut self) -> Result<T, Truncated> {
        self.int(T::split_be)
    }

    #[inline(always)]
    fn int<T: Int>(
        &mut self,
        split: impl FnOnce(&'a [u8]) -> Option<(T, &'a [u8])>,
    ) -> Result<T, Truncated> {
        match split(self.rest) {
            Some((v, tail)) => {
                self.rest = tail;
                Ok(v)
            }
            None => Err(self.short(T::SIZE)),
        }
    }

    /// The error of a read of `wanted` bytes that did not fit.
    #[inline(always)]
    fn short(&self, wanted: usize) -> Truncated {
        Truncated {
            wanted,
            left: self.rest.len(),
        }
    }
}

/// Writes into a byte buffer front to back. Every write either puts all its bytes or fails
/// with [`Overflow`] and puts none; writes return the writer, so they chain with `?`.
#[derive(Debug)]
pub struct Writer<'a> {
    buf: &'a mut [u8],
    pos: usize,
}

impl<'a> Writer<'a> {
    /// A writer at the start of `buf`.
    #[inline]
    #[must_use]
    pub const fn new(buf: &'a mut [u8]) -> Self {
        Self { buf, pos: 0 }
    }

    /// Bytes written so far (the offset of the next write).
    #[inline]
    #[must_use]
    pub const fn pos(&self) -> usize {
        self.pos
    }

    /// Room left.
    #[inline]
    #[must_use]
    pub const fn remaining(&self) -> usize {
        self.buf.len().saturating_sub(self.pos)
    }

    /// The bytes written so far.
    #[inline]
    #[must_use]
    pub fn written(&self) -> &[u8] {
        self.buf.get(..self.pos).unwrap_or_default()
    }

    /// The next `n` bytes of the buffer, to be filled by the caller, and the position moved
    /// past them.
    ///
    /// # Errors
    /// [`Overflow`] when fewer than `n` bytes of room are left.
    #[inline]
    pub fn reserve(&mut self, n: usize) -> Result<&mut [u8], Overflow> {
        let at = self.pos;
        let capacity = self.buf.len();
        let end = at
            .checked_add(n)
            .filter(|&e| e <= capacity)
            .ok_or(Overflow {
                at,
                wanted: n,
                capacity,
            })?;
        self.pos = end;
        Ok(self.buf.get_mut(at..end).unwrap_or_default())
    }

    /// Move past `n` bytes, leaving them as they are (a header filled in later).
    ///
    /// # Errors
    /// [`Overflow`] when fewer than `n` bytes of room are left.
    #[inline]
    pub fn skip(&mut self, n: usize) -> Result<&mut Self, Overflow> {
        self.reserve(n)?;
        Ok(self)
    }

    /// Write `bytes`.
    ///
    /// # Errors
    /// [`Overflow`] when they do not fit.
    #[inline]
    pub fn bytes(&mut self, bytes: &[u8]) -> Result<&mut Self, Overflow> {
        self.reserve(bytes.len())?.copy_from_slice(bytes);
        Ok(self)
    }

    /// Write one byte.
    ///
    /// # Errors
    /// [`Overflow`] when the buffer is full.
    #[inline]
    pub fn u8(&mut self, b: u8) -> Result<&mut Self, Overflow> {
        match self.buf.get_mut(self.pos) {
            Some(slot) => {
                *slot = b;
                self.pos = self.pos.saturating_add(1);
                Ok(self)
            }
            None => Err(Overflow {
                at: self.pos,
                wanted: 1,
                capacity: self.buf.len(),
            }),
        }
    }

    /// Write a little-endian integer.
    ///
    /// # Errors
    /// [`Overflow`] when it does not fit.
    #[inline]
    pub fn le<T: Int>(&mut self, v: T) -> Result<&mut Self, Overflow> {
        self.bytes(v.to_le().as_ref())
    }

    /// Write a big-endian integer.
    ///
    /// # Errors
    /// [`Overflow`] when it does not fit.
    #[inline]
    pub fn be<T: Int>(&mut self, v: T) -> Result<&mut Self, Overflow> {
        self.bytes(v.to_be().as_ref())
    }

    /// Write `v` in ASCII decimal, zero-padded to at least `min_digits` digits (at most 20).
    ///
    /// # Errors
    /// [`Overflow`] when the digits do not fit (nothing is written then).
    pub fn decimal(&mut self, v: u64, min_digits: u8) -> Result<&mut Self, Overflow> {
        let mut digits = [b'0'; 20];
        let mut n = 0usize;
        let mut rest = v;
        for slot in digits.iter_mut().rev() {
            // `rest % 10` is below 10, so the cast is exact.
            *slot = b'0' + (rest % 10) as u8;
            rest /= 10;
            n = n.saturating_add(1);
            if rest == 0 && n >= usize::from(min_digits) {
                break;
            }
        }
        let start = digits.len().saturating_sub(n);
        self.bytes(digits.get(start..).unwrap_or_default())
    }
}

/// Why ASCII digits did not parse as a decimal.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum DecimalError {
    /// No digits.
    Empty,
    /// More digits than allowed.
    TooLong {
        /// The most digits allowed.
        max: u8,
    },
    /// A byte that is not an ASCII digit.
    NotADigit(u8),
}

impl fmt::Display for DecimalError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Empty => f.write_str("no digits"),
            Self::TooLong { max } => write!(f, "more than {max} digits"),
            Self::NotADigit(b) => write!(f, "byte 0x{b:02x} is not a digit"),
        }
    }
}

impl core::error::Error for DecimalError {}

/// Parse 1 to `max_digits` ASCII decimal digits (no sign, no spaces; leading zeros allowed),
/// the inverse of [`Writer::decimal`]. `max_digits` is capped at 19, so the value always
/// fits.
///
/// # Errors
/// [`DecimalError`] naming what was wrong.
pub fn parse_decimal(digits: &[u8], max_digits: u8) -> Result<u64, DecimalError> {
    let max = max_digits.min(19);
    if digits.is_empty() {
        return Err(DecimalError::Empty);
    }
    if digits.len() > usize::from(max) {
        return Err(DecimalError::TooLong { max });
    }
    digits.iter().try_fold(0u64, |v, &c| {
        if c.is_ascii_digit() {
            Ok(v.saturating_mul(10).saturating_add(u64::from(c - b'0')))
        } else {
            Err(DecimalError::NotADigit(c))
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use std::vec::Vec;

    #[test]
    fn reads_both_orders_and_every_width() {
        let bytes = [1, 2, 3, 4, 5, 6, 7, 8, 0xFF, 0xFE];
        let mut r = Reader::new(&bytes);
        assert_eq!(r.le::<u16>(), Ok(0x0201));
        assert_eq!(r.be::<u16>(), Ok(0x0304));
        assert_eq!(r.le::<u32>(), Ok(0x0807_0605));
        assert_eq!(r.be::<i16>(), Ok(-2));
        assert!(r.is_empty());
        let mut r = Reader::new(&bytes);
        assert_eq!(r.be::<u64>(), Ok(0x0102_0304_0506_0708));
        assert_eq!(r.le::<i8>(), Ok(-1));
        assert_eq!(r.remaining(), 1);
        let mut r = Reader::new(&bytes);
        assert_eq!(r.le::<i64>(), Ok(0x0807_0605_0403_0201));
        assert_eq!(r.be::<i32>(), Err(Truncated { wanted: 4, left: 2 }));
    }

    #[test]
    fn a_failed_read_takes_nothing() {
        let mut r = Reader::new(&[9, 8, 7]);
        assert_eq!(r.take(4), Err(Truncated { wanted: 4, left: 3 }));
        assert_eq!(r.array::<4>(), Err(Truncated { wanted: 4, left: 3 }));
        assert_eq!(r.le::<u32>(), Err(Truncated { wanted: 4, left: 3 }));
        assert_eq!(r.rest(), [9, 8, 7]);
        assert_eq!(r.array::<2>(), Ok([9, 8]));
        assert_eq!(r.skip(2), Err(Truncated { wanted: 2, left: 1 }));
        assert_eq!(r.take_rest(), [7]);
        assert_eq!(r.u8(), Err(Truncated { wanted: 1, left: 0 }));
        assert_eq!(r.take(0), Ok(&[][..]));
        assert_eq!(
            r.take(usize::MAX),
            Err(Truncated {
                wanted: usize::MAX,
                left: 0
            })
        );
    }

    #[test]
    fn take_until_splits_terminated_and_unterminated_fields() {
        let mut r = Reader::new(b"ab\0\0cd");
        assert_eq!(r.take_until(0), Ok(&b"ab"[..]));
        assert_eq!(r.take_until(0), Ok(&b""[..]));
        assert_eq!(r.take_until(0), Ok(&b"cd"[..]));
        assert_eq!(r.take_until(0), Err(Truncated { wanted: 1, left: 0 }));
    }

    #[test]
    fn writes_both_orders_and_refuses_what_does_not_fit() {
        let mut buf = [0u8; 7];
        let mut w = Writer::new(&mut buf);
        w.le(0x0201u16)
            .unwrap()
            .be(0x0304u16)
            .unwrap()
            .u8(5)
            .unwrap();
        assert_eq!(w.remaining(), 2);
        assert_eq!(
            w.le(1u32).map(|_| ()),
            Err(Overflow {
                at: 5,
                wanted: 4,
                capacity: 7
            })
        );
        assert_eq!(w.pos(), 5, "a failed write moves nothing");
        w.skip(1).unwrap().u8(6).unwrap();
        assert_eq!(
            w.u8(7).map(|_| ()),
            Err(Overflow {
                at: 7,
                wanted: 1,
                capacity: 7
            })
        );
        assert_eq!(w.written(), [1, 2, 3, 4, 5, 0, 6]);
        assert!(w.reserve(usize::MAX).is_err());
    }

    #[test]
    fn decimal_pads_and_refuses_whole() {
        let mut buf = [0u8; 32];
        let mut w = Writer::new(&mut buf);
        w.decimal(0, 0).unwrap().u8(b' ').unwrap();
        w.decimal(7, 3).unwrap().u8(b' ').unwrap();
        w.decimal(1234, 2).unwrap().u8(b' ').unwrap();
        w.decimal(u64::MAX, 0).unwrap();
        assert_eq!(w.written(), b"0 007 1234 18446744073709551615");
        let mut small = [0u8; 2];
        let mut w = Writer::new(&mut small);
        assert!(w.decimal(123, 0).is_err());
        assert_eq!(w.pos(), 0);
    }

    #[test]
    fn parse_decimal_reads_what_decimal_writes() {
        assert_eq!(parse_decimal(b"0", 5), Ok(0));
        assert_eq!(parse_decimal(b"007", 5), Ok(7));
        assert_eq!(parse_decimal(b"65535", 5), Ok(65_535));
        assert_eq!(parse_decimal(b"99999", 5), Ok(99_999));
        assert_eq!(parse_decimal(b"", 5), Err(DecimalError::Empty));
        assert_eq!(
            parse_decimal(b"123456", 5),
            Err(DecimalError::TooLong { max: 5 })
        );
        assert_eq!(parse_decimal(b"1-2", 5), Err(DecimalError::NotADigit(b'-')));
        assert_eq!(
            parse_decimal(b"18446744073709551615", 20),
            Err(DecimalError::TooLong { max: 19 })
        );
        assert_eq!(
            parse_decimal(b"9999999999999999999", 255),
            Ok(9_999_999_999_999_999_999)
        );
    }

    proptest! {
        /// Any value with any padding reads back as written.
        #[test]
        fn decimal_round_trip(v in any::<u64>(), pad in 0u8..25) {
            let mut buf = [0u8; 32];
            let mut w = Writer::new(&mut buf);
            w.decimal(v, pad).unwrap();
            let n = w.pos();
            prop_assert!(n >= usize::from(pad).min(20));
            if n <= 19 {
                prop_assert_eq!(parse_decimal(&buf[..n], 19), Ok(v));
            }
        }

        /// Whatever is written in whatever order reads back, and no sequence of reads on any
        /// input panics.
        #[test]
        fn round_trip(values in proptest::collection::vec((any::<u64>(), 0u8..8), 0..40)) {
            let mut buf = [0u8; 200];
            let mut w = Writer::new(&mut buf);
            for &(v, kind) in &values {
                let r = match kind {
                    0 => w.u8(v as u8).map(|_| ()),
                    1 => w.le(v as u16).map(|_| ()),
                    2 => w.be(v as i16).map(|_| ()),
                    3 => w.le(v as u32).map(|_| ()),
                    4 => w.be(v as i32).map(|_| ()),
                    5 => w.le(v).map(|_| ()),
                    6 => w.be(v as i64).map(|_| ()),
                    _ => w.bytes(&v.to_le_bytes()[..(v % 9) as usize]).map(|_| ()),
                };
                prop_assert!(r.is_ok() || w.remaining() < 8);
                if r.is_err() {
                    break;
                }
            }
            let written: Vec<u8> = w.written().to_vec();
            let mut r = Reader::new(&written);
            for &(v, kind) in &values {
                if r.is_empty() {
                    break;
                }
                match kind {
                    0 => prop_assert_eq!(r.u8(), Ok(v as u8)),
                    1 => prop_assert_eq!(r.le::<u16>(), Ok(v as u16)),
                    2 => prop_assert_eq!(r.be::<i16>(), Ok(v as i16)),
                    3 => prop_assert_eq!(r.le::<u32>(), Ok(v as u32)),
                    4 => prop_assert_eq!(r.be::<i32>(), Ok(v as i32)),
                    5 => prop_assert_eq!(r.le::<u64>(), Ok(v)),
                    6 => prop_assert_eq!(r.be::<i64>(), Ok(v as i64)),
                    _ => prop_assert_eq!(r.take((v % 9) as usize), Ok(&v.to_le_bytes()[..(v % 9) as usize])),
                }
            }
        }

        #[test]
        fn any_reads_on_any_bytes(bytes in proptest::collection::vec(any::<u8>(), 0..64),
                                  ops in proptest::collection::vec(0u8..9, 0..64)) {
            let mut r = Reader::new(&bytes);
            for op in ops {
                let before = r.remaining();
                let ok = match op {
                    0 => r.u8().is_ok(),
                    1 => r.le::<u16>().is_ok(),
                    2 => r.be::<u32>().is_ok(),
                    3 => r.le::<i64>().is_ok(),
                    4 => r.array::<3>().is_ok(),
                    5 => r.take(usize::from(op)).is_ok(),
                    6 => r.take_until(0).is_ok(),
                    7 => r.skip(2).is_ok(),
                    _ => { r.take_rest(); true }
                };
                prop_assert!(ok || r.remaining() == before);
            }
        }
    }
}

//! The compass line framer (spec §7a: lines end with CR, CR LF or LF): the shared
//! [`ima_serial::line::LineFramer`] with the compass [`RULES`] —
//!
//! * `$` starts a sentence: a `$` in the middle of a line means the line before it was cut
//!   short, so the partial line is dropped (counted) and a new one starts at the `$` (the
//!   resync after garbage);
//! * the KVH `>` prompt is yielded as [`Frame::Prompt`] as soon as it is seen at the start
//!   of a line (the device does not terminate it);
//! * the NMEA checksum of `$…*hh` lines is checked and a mismatch reported as
//!   [`FrameError::BadChecksum`] (lines without `*hh` pass; the parser decides).
//!
//! Lines are bounded (overlong lines and lines with a non-printable byte are dropped and
//! counted); frames borrow the framer's buffer, so nothing is copied or allocated.

pub use ima_serial::line::{Frame, FrameError, LineStats as FramerStats, Rules};

use crate::wire::{self, MAX_LINE};

/// The compass framer; `N` is the longest line (without terminator) it keeps.
pub type LineFramer<const N: usize = MAX_LINE> = ima_serial::line::LineFramer<N>;

/// The compass dialects' framing rules: `$` starts a sentence, `>` is the KVH prompt, NMEA
/// checksums are checked.
pub const RULES: Rules = Rules {
    start: Some(b'$'),
    prompt: Some(b'>'),
    check: Some(nmea_check),
};

/// A framer with the compass [`RULES`].
#[must_use]
pub const fn framer<const N: usize>() -> LineFramer<N> {
    LineFramer::new(RULES)
}

/// `Err(BadChecksum)` if the line is `$…*hh` with a mismatching checksum.
fn nmea_check(line: &[u8]) -> Result<(), FrameError> {
    match checksum_mismatch(line) {
        Some((expected, got)) => Err(FrameError::BadChecksum { expected, got }),
        None => Ok(()),
    }
}

/// `Some((computed, sent))` if the line is `$…*hh` with a mismatching checksum.
fn checksum_mismatch(line: &[u8]) -> Option<(u8, u8)> {
    let (b'$', rest) = line.split_first()? else {
        return None;
    };
    let star = rest.len().checked_sub(3)?;
    let (body, tail) = rest.split_at(star);
    let [b'*', hi, lo] = tail else {
        return None;
    };
    let got = (wire::hex_val(*hi)? << 4) | wire::hex_val(*lo)?;
    let expected = wire::checksum(body);
    (expected != got && !cfg!(fuzzing)).then_some((expected, got))
}

#[cfg(test)]
mod tests {
    //! The framer's behaviour is tested in `ima_serial::line`; these check the compass rules.
    use super::*;
    use std::vec::Vec;

    /// Lines (a prompt as `>`) in order, the errors, and the counters.
    fn run(chunks: &[&[u8]]) -> (Vec<Vec<u8>>, Vec<FrameError>, FramerStats) {
        let mut fr = framer::<96>();
        let (mut lines, mut errors) = (Vec::new(), Vec::new());
        for c in chunks {
            fr.push(c, |f| match f {
                Frame::Line(l) => lines.push(l.to_vec()),
                Frame::Prompt => lines.push(b">".to_vec()),
                Frame::Corrupt(e) => errors.push(e),
            });
        }
        (lines, errors, fr.stats())
    }

    const HDM: &[u8] = b"$HCHDM,238.5,M*25\r\n";
    const HDT: &[u8] = b"$HCHDT,238.5,T*25\r\n";

    fn l(s: &[u8]) -> Vec<u8> {
        wire::trim_eol(s).to_vec()
    }

    #[test]
    fn bad_checksum_then_good_frame() {
        let (lines, errors, stats) = run(&[b"$HCHDM,238.5,M*26\r\n", HDM]);
        assert_eq!(lines, [l(HDM)]);
        assert_eq!(
            errors,
            [FrameError::BadChecksum {
                expected: 0x25,
                got: 0x26
            }]
        );
        assert_eq!((stats.bad_checksums, stats.lines), (1, 1));
    }

    #[test]
    fn dollar_resyncs_a_truncated_frame() {
        let (lines, errors, stats) = run(&[b"$HCHDM,23", HDT]);
        assert_eq!(lines, [l(HDT)]);
        assert!(errors.is_empty());
        assert_eq!(stats.dropped_bytes, 9);
    }

    #[test]
    fn prompt_at_line_start_only() {
        let (lines, _, stats) = run(&[b">", HDM, b"\r\n>a>b\r\n"]);
        assert_eq!(
            lines,
            [b">".to_vec(), l(HDM), b">".to_vec(), b"a>b".to_vec()]
        );
        assert_eq!(stats.prompts, 2);
    }
}

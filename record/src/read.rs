//! Reading recordings back (with the `mcap` crate), including files cut short by a crash.
//!
//! Malformed files: the `mcap` crate (0.26) panics on some records it cannot hold — a length
//! near `u64::MAX` (an overflow in its slicing), a chunk claiming an absurd uncompressed size
//! (`capacity overflow`, or an allocation that aborts the process), or a record inside a chunk
//! whose length is corrupt (it sizes a buffer from it). So [`Recording::open`] first walks the
//! file's record structure itself, decompressing each chunk, and hands the crate only what is
//! sound:
//! - a chunk that would decompress to more than [`MAX_CHUNK_BYTES`], does not decompress to
//!   what it claims, does not match its CRC (when it has one), names a compression this reader
//!   lacks (zstd and none are read), or whose records overrun it, is skipped when its own
//!   length is sound (a flipped byte in one chunk loses that chunk's messages, about a second
//!   of a demo, not the rest of the file); so is a message index whose entries do not fill it (the crate would
//!   stop there; no message is lost). At the first skipped stretch the file's top-level schema
//!   and channel records are put in, so when the file has its summary (it was closed), the
//!   messages after a skipped chunk keep their channels even if that chunk defined them; in a
//!   file a crash cut short, they may not;
//! - after a record whose length runs past the file, the walk goes on at the next sound chunk;
//!   where none follows (a recorder that crashed mid-chunk), the recording ends there;
//! - the walk decompresses at most 1 GiB plus 256 bytes per byte of file (a crafted file of
//!   small chunks each claiming 256 MiB would otherwise take hours); past that, the file ends
//!   there.
//!
//! What was skipped, where the file ends early, and bytes that follow its end (two files
//! joined) are reported as its [`Truncation`] and by [`Recording::damage`]. Any other panic of the crate is caught ([`in_guarded_read`] tells a
//! program's panic hook to stay quiet) and reported the same way.
//!
//! Memory: [`Recording::open`] walks the file a record at a time and, when nothing needs
//! skipping (a closed recording, or one a crash cut short at its end), leaves it on disk: each
//! read streams it again, one chunk in memory at a time, so replaying an hour of cameras
//! (about 2 GB) does not hold 2 GB. A file with a stretch to skip (a damaged chunk, or damage
//! that a sound chunk follows) is read whole, to be repaired in its own buffer (held once: a
//! 277 MB file with one damaged chunk replays in 295 MB); so, to keep the walk's memory
//! bounded, is one with a record over [`MAX_CHUNK_BYTES`] plus 1 MiB, or with more than 64 MiB
//! after its damage ([`Recording::holds_file`]). A file still being written is read up to where
//! it was when it was opened. A file changed after it was opened is not checked again: each
//! read still holds one chunk at most, and a record the `mcap` crate cannot take ends that
//! read as damage.

use std::cell::Cell;
use std::collections::BTreeMap;
use std::fs::File;
use std::io::Read;
use std::panic::AssertUnwindSafe;
use std::path::Path;

use ima_hal::bytes::Reader;

use crate::raw::{self, Chunk, PortInfo};

/// The largest uncompressed chunk a recording may have: 256 MiB (the recorder writes 1 MiB
/// chunks; one larger message makes one larger chunk).
pub const MAX_CHUNK_BYTES: u64 = 256 << 20;

/// A recording: left in its file and streamed by each read, or held in memory (see the
/// module docs).
#[derive(Debug)]
pub struct Recording {
    /// Where the bytes are.
    source: Source,
    /// Where its sound record structure ends (the whole file when nothing is wrong).
    sound: u64,
    /// What is wrong with the file, if anything: the stretches skipped, then why it ends at
    /// `sound` before its footer.
    damage: Option<String>,
    /// Why the `mcap` crate stopped before the end of the sound part, once a read saw it.
    stopped: std::sync::OnceLock<String>,
}

/// Where a recording's bytes are.
#[derive(Debug)]
enum Source {
    /// In memory: the file without its skipped damaged stretches, when it had any.
    Memory(Vec<u8>),
    /// In the file, read again by each read.
    File(File),
}

/// The largest top-level record the streaming walk reads into memory: a chunk of
/// [`MAX_CHUNK_BYTES`] and its header. A file with a longer one is read whole.
const MAX_RECORD_BYTES: u64 = MAX_CHUNK_BYTES + (1 << 20);

/// The most of a file's end the streaming walk reads to check that no sound chunk follows
/// damage (a crash leaves less than a chunk); with more, the file is read whole.
const MAX_TAIL_BYTES: u64 = 64 << 20;

/// `buf.len()` bytes of `file` from offset `at` (positional reads: a `&File` shared by
/// readers keeps no cursor).
fn read_exact_at(file: &File, buf: &mut [u8], at: u64) -> std::io::Result<()> {
    let end = at.saturating_add(buf.len() as u64);
    FileRange { file, at, end }.read_exact(buf)
}

#[cfg(unix)]
fn read_at(file: &File, buf: &mut [u8], at: u64) -> std::io::Result<usize> {
    std::os::unix::fs::FileExt::read_at(file, buf, at)
}

#[cfg(windows)]
fn read_at(file: &File, buf: &mut [u8], at: u64) -> std::io::Result<usize> {
    std::os::windows::fs::FileExt::seek_read(file, buf, at)
}

#[cfg(not(any(unix, windows)))]
fn read_at(mut file: &File, buf: &mut [u8], at: u64) -> std::io::Result<usize> {
    use std::io::Seek;
    file.seek(std::io::SeekFrom::Start(at))?;
    file.read(buf)
}

/// A [`Read`] over `file` from `at` to `end`, by positional reads.
struct FileRange<'a> {
    file: &'a File,
    at: u64,
    end: u64,
}

impl Read for FileRange<'_> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let left = usize::try_from(self.end.saturating_sub(self.at)).unwrap_or(usize::MAX);
        let want = buf.len().min(left);
        let n = read_at(self.file, buf.get_mut(..want).unwrap_or_default(), self.at)?;
        self.at += n as u64;
        Ok(n)
    }
}

thread_local! {
    static GUARDED: Cell<bool> = const { Cell::new(false) };
}

/// Whether this thread is reading a recording under the guard that catches the `mcap` crate's
/// panics on malformed files (a program's panic hook should then stay quiet: the panic is
/// caught and reported as the recording's damage).
#[must_use]
pub fn in_guarded_read() -> bool {
    GUARDED.with(Cell::get)
}

/// Run `f` catching a panic of the `mcap` crate; `Err` names it.
fn guarded<T>(f: impl FnOnce() -> T) -> Result<T, String> {
    let was = GUARDED.with(|g| g.replace(true));
    let r = std::panic::catch_unwind(AssertUnwindSafe(f));
    GUARDED.with(|g| g.set(was));
    r.map_err(|p| {
        format!(
            "the MCAP reader failed on a malformed record: {}",
            panic_message(&*p)
        )
    })
}

/// The message a caught panic carries (`"a panic"` when it carries none): for callers of
/// [`Recording::each_raw_chunk`] that catch their own panics under its guard.
#[must_use]
pub fn panic_message(p: &(dyn std::any::Any + Send)) -> String {
    p.downcast_ref::<&str>()
        .map(|s| (*s).to_owned())
        .or_else(|| p.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "a panic".into())
}

const OP_HEADER: u8 = 0x01;
const OP_FOOTER: u8 = 0x02;
const OP_SCHEMA: u8 = 0x03;
const OP_CHANNEL: u8 = 0x04;
const OP_CHUNK: u8 = 0x06;
const OP_MESSAGE_INDEX: u8 = 0x07;
const OP_ATTACHMENT: u8 = 0x09;
const OP_DATA_END: u8 = 0x0f;

/// The file's top level as [`survey`] found it.
#[derive(Debug, Default)]
struct Survey {
    /// Where the sound structure ends: the file's end, or the damage nothing sound follows.
    end: usize,
    /// What is wrong at `end`, if anything.
    damage: Option<String>,
    /// Damaged stretches the walk went past: a chunk whose framing is sound but whose contents
    /// are not, or bytes up to the next sound chunk after a broken record. With why.
    skipped: Vec<(std::ops::Range<usize>, String)>,
    /// Top-level schema and channel records (the summary repeats every definition).
    defs: Vec<std::ops::Range<usize>>,
    /// Bytes after the file's end, said ([`after_the_end`]).
    after_end: Option<String>,
}

/// How many bytes the walk may still decompress: chunks claim their uncompressed size, and a
/// small file of crafted chunks could otherwise claim terabytes (256 MiB each). Real
/// recordings decompress to a few times their size.
struct Budget(u64);

impl Budget {
    /// For a file of `len` bytes: 1 GiB, plus 256 bytes per byte of file.
    fn for_file(len: u64) -> Self {
        Self((1u64 << 30).saturating_add(len.saturating_mul(256)))
    }

    /// Take `n` bytes of the budget; `false` (and nothing taken) when there are not that many.
    fn take(&mut self, n: u64) -> bool {
        let ok = n <= self.0;
        if ok {
            self.0 -= n;
        }
        ok
    }
}

/// One top-level record at `at`: its opcode and end, or why it is not sound (a chunk's
/// contents are checked: [`chunk_problem`]). `Ok(None)`: fewer than 9 bytes left. `b[0]` is
/// byte `base` of the file (the messages name file offsets).
fn top_record(
    b: &[u8],
    at: usize,
    base: u64,
    budget: &mut Budget,
) -> Result<Option<(u8, usize)>, String> {
    let mut r = Reader::new(b.get(at..).unwrap_or_default());
    let (Ok(op), Ok(len)) = (r.u8(), r.le::<u64>()) else {
        return Ok(None);
    };
    let follow = r.remaining();
    let Some(body) = usize::try_from(len).ok().and_then(|n| r.take(n).ok()) else {
        return Err(claims_too_much(op, base + at as u64, len, follow as u64));
    };
    if let Some(why) = record_problem(op, body, base + at as u64, budget) {
        return Err(why);
    }
    Ok(Some((op, b.len() - r.remaining())))
}

/// Why a record at file offset `at` is broken: its length runs past the file. A chunk whose
/// length is all ones is the `mcap` writer's placeholder, overwritten when the chunk is done.
fn claims_too_much(op: u8, at: u64, len: u64, follow: u64) -> String {
    if op == OP_CHUNK && len == u64::MAX {
        return format!(
            "the chunk at byte {at} was never finished (the recorder is still writing it, or \
             stopped before it could; its messages are not in the file)"
        );
    }
    format!("record 0x{op:02x} at byte {at} claims {len} bytes, but {follow} follow")
}

/// What is wrong with the whole top-level record `op` (body `body`) at file offset `at`.
fn record_problem(op: u8, body: &[u8], at: u64, budget: &mut Budget) -> Option<String> {
    if op == 0x00 {
        // No MCAP record has it (a zeroed stretch reads as a run of these).
        return Some(format!(
            "record at byte {at} has opcode 0x00, which no MCAP record has (zeroed bytes?)"
        ));
    }
    // A top-level record of a known kind (header, metadata, a summary's definitions and
    // indexes…) whose fields do not parse stops the `mcap` reader's whole read; chunks and
    // message indexes are checked above, and attachments (which the recorder never writes)
    // are left to it.
    if (OP_HEADER..=OP_DATA_END).contains(&op)
        && ![OP_CHUNK, OP_MESSAGE_INDEX, OP_ATTACHMENT].contains(&op)
    {
        match guarded(|| mcap::read::parse_record(op, body).err()) {
            Ok(None) => {}
            Ok(Some(e)) => {
                return Some(format!(
                    "record 0x{op:02x} at byte {at} does not parse ({e})"
                ));
            }
            Err(why) => return Some(format!("record 0x{op:02x} at byte {at}: {why}")),
        }
    }
    if op == OP_CHUNK
        && let Some(why) = chunk_problem(body, budget)
    {
        return Some(format!("chunk at byte {at}: {why}; its messages are lost"));
    }
    if op == OP_MESSAGE_INDEX && !message_index_sound(body) {
        // The `mcap` reader parses it and would stop the whole read there.
        return Some(format!(
            "message index at byte {at}: its entries do not fill it (an index: no message is lost)"
        ));
    }
    None
}

/// Whether a message index record's body is whole: a channel id, then a byte length that its
/// 16-byte entries (log time, offset) fill exactly.
fn message_index_sound(body: &[u8]) -> bool {
    let mut r = Reader::new(body);
    let (Ok(_channel), Ok(n)) = (r.le::<u16>(), r.le::<u32>()) else {
        return false;
    };
    n % 16 == 0 && u64::from(n) == r.remaining() as u64
}

/// The record at `at` when its length fits in the file: its opcode, body and end.
fn record_at(b: &[u8], at: usize) -> Option<(u8, &[u8], usize)> {
    let mut r = Reader::new(b.get(at..)?);
    let (Ok(op), Ok(len)) = (r.u8(), r.le::<u64>()) else {
        return None;
    };
    let body = r.take(usize::try_from(len).ok()?).ok()?;
    Some((op, body, b.len() - r.remaining()))
}

/// Where a chunk record at `at` ends when it is framed exactly: its header and records fill
/// its length, which fits in the file. A cheap test before a chunk is decompressed: noise
/// rarely passes it.
fn framed_chunk(b: &[u8], at: usize) -> Option<usize> {
    let (OP_CHUNK, body, end) = record_at(b, at)? else {
        return None;
    };
    let mut body = Reader::new(body);
    // Times, uncompressed size, CRC; then the compression name and the records.
    body.skip(28).ok()?;
    let name = usize::try_from(body.le::<u32>().ok()?).ok()?;
    body.skip(name).ok()?;
    let records = body.le::<u64>().ok()?;
    (records == body.remaining() as u64).then_some(end)
}

/// Where a damaged record at `at` ends when its own length can be trusted: a chunk framed
/// exactly, or a message index whose length fits in the file.
fn trusted_end(b: &[u8], at: usize) -> Option<usize> {
    framed_chunk(b, at).or_else(|| match record_at(b, at)? {
        (OP_MESSAGE_INDEX, _, end) => Some(end),
        _ => None,
    })
}

/// The next sound chunk record after `from`, as (start, end): where a walk that met a broken
/// record picks up again. A candidate framed exactly but unsound is passed over whole, so
/// the scan stays linear.
fn next_sound_chunk(b: &[u8], from: usize, budget: &mut Budget) -> Option<(usize, usize)> {
    let mut k = from;
    while k < b.len() {
        if let Some(end) = framed_chunk(b, k) {
            if let Ok(Some((OP_CHUNK, _))) = top_record(b, k, 0, budget) {
                return Some((k, end));
            }
            k = end;
        } else {
            k += 1;
        }
    }
    None
}

/// Walk the file's top level from `start` (after the magic) to the footer. A chunk whose
/// framing is exact but whose contents are not sound (a flipped byte in its compressed data)
/// is skipped; after a record whose length is broken the walk goes on at the next sound chunk.
/// Only where no sound chunk follows (a file cut short by a crash) does the walk end early.
fn survey(b: &[u8], start: usize) -> Survey {
    let mut s = Survey::default();
    let mut budget = Budget::for_file(b.len() as u64);
    let mut at = start;
    loop {
        match top_record(b, at, 0, &mut budget) {
            Ok(None) => {
                // Fewer than 9 bytes left, and no footer: a recorder stopped between two
                // records, or a few bytes into one (what the `mcap` crate calls "ended in the
                // middle of a record" either way).
                s.end = at;
                s.damage = Some(cut_between_records(at as u64, b.len() as u64));
                return s;
            }
            Ok(Some((op, next))) => {
                if op == OP_FOOTER {
                    s.end = b.len();
                    s.after_end = after_the_end(b.len() as u64, next as u64);
                    return s;
                }
                if op == OP_SCHEMA || op == OP_CHANNEL {
                    s.defs.push(at..next);
                }
                at = next;
            }
            Err(why) => {
                // A chunk framed exactly: its own length says where the next record is.
                // Otherwise the next sound chunk, which has been checked already.
                let (gap_end, next) = match trusted_end(b, at) {
                    Some(end) => (end, end),
                    None => match next_sound_chunk(b, at + 1, &mut budget) {
                        Some((k, end)) => (k, end),
                        None => {
                            s.end = at;
                            s.damage = Some(why);
                            return s;
                        }
                    },
                };
                s.skipped.push((at..gap_end, why));
                at = next;
            }
        }
    }
}

/// A file of `len` bytes whose records stop at `at` with fewer than a record's header left,
/// and no footer: a recorder stopped between two records, or a few bytes into one (the
/// `mcap` crate said "MCAP file ended in the middle of a record" either way).
fn cut_between_records(at: u64, len: u64) -> String {
    if at >= len {
        format!("it stops after byte {at}, between two records, without its footer")
    } else {
        format!(
            "it stops {} bytes into the record at byte {at}, without its footer",
            len - at
        )
    }
}

/// Bytes after a file's end (its footer record, ending at `footer_end`, and the closing
/// magic), which no reader reads: said, so that two recordings joined by `cat` do not read as
/// the first alone without a word.
fn after_the_end(len: u64, footer_end: u64) -> Option<String> {
    let extra = len.saturating_sub(footer_end.saturating_add(mcap::MAGIC.len() as u64));
    (extra > 0).then(|| {
        format!("{extra} bytes follow the file's end and are not read (another file appended?)")
    })
}

/// What [`survey_file`] found.
#[derive(Debug)]
enum FileSurvey {
    /// Nothing to skip: the sound structure ends at `end` (the file's end, or damage after
    /// which no sound chunk follows), with what is wrong there, and what follows the file's
    /// end.
    Sound {
        end: u64,
        damage: Option<String>,
        after_end: Option<String>,
    },
    /// Something must be skipped, or a record is too long to check a piece at a time: the
    /// file is read whole and walked by [`survey`].
    ReadWhole,
}

/// How much [`survey_file`] reads into memory at once.
#[derive(Debug, Clone, Copy)]
struct Limits {
    /// The longest record it checks ([`MAX_RECORD_BYTES`]).
    record: u64,
    /// The most of the file's end it reads after damage ([`MAX_TAIL_BYTES`]).
    tail: u64,
}

const LIMITS: Limits = Limits {
    record: MAX_RECORD_BYTES,
    tail: MAX_TAIL_BYTES,
};

/// [`survey`] a record at a time from the file (`len` bytes, its magic checked): the same
/// walk, holding one record (and, after damage, at most `limits.tail` of the file's end).
fn survey_file(file: &File, len: u64, limits: Limits) -> std::io::Result<FileSurvey> {
    let mut budget = Budget::for_file(len);
    let mut at = mcap::MAGIC.len() as u64;
    let mut buf = Vec::new();
    loop {
        let left = len.saturating_sub(at);
        if left < 9 {
            return Ok(FileSurvey::Sound {
                end: at,
                damage: Some(cut_between_records(at, len)),
                after_end: None,
            });
        }
        let mut head = [0u8; 9];
        read_exact_at(file, &mut head, at)?;
        let [op, l @ ..] = head;
        let body_len = u64::from_le_bytes(l);
        let why = if body_len > left - 9 {
            claims_too_much(op, at, body_len, left - 9)
        } else if body_len > limits.record {
            return Ok(FileSurvey::ReadWhole);
        } else {
            // Bounded by `limits.record`.
            buf.resize(usize::try_from(body_len).unwrap_or(0), 0);
            read_exact_at(file, &mut buf, at + 9)?;
            match record_problem(op, &buf, at, &mut budget) {
                None if op == OP_FOOTER => {
                    return Ok(FileSurvey::Sound {
                        end: len,
                        damage: None,
                        after_end: after_the_end(len, at + 9 + body_len),
                    });
                }
                None => {
                    at += 9 + body_len;
                    continue;
                }
                Some(why) => why,
            }
        };
        // Damage at `at`: the walk ends here only if nothing it could go on at follows (as in
        // `survey`); that is a look at the file's end, which a crash leaves short.
        let tail_len = len - at;
        if tail_len > limits.tail {
            return Ok(FileSurvey::ReadWhole);
        }
        buf.resize(usize::try_from(tail_len).unwrap_or(0), 0);
        read_exact_at(file, &mut buf, at)?;
        if trusted_end(&buf, 0).is_some() || next_sound_chunk(&buf, 1, &mut budget).is_some() {
            return Ok(FileSurvey::ReadWhole);
        }
        return Ok(FileSurvey::Sound {
            end: at,
            damage: Some(why),
            after_end: None,
        });
    }
}

/// Walk the records inside a chunk (opcode, u64 length, body): the offset where the sound
/// structure ends and what is wrong there. 1–8 bytes left over are damage (the reader would
/// take the bytes after the chunk for the rest of a record).
fn walk(b: &[u8]) -> (usize, Option<String>) {
    let mut r = Reader::new(b);
    while !r.is_empty() {
        let at = b.len() - r.remaining();
        let mut next = r;
        let (Ok(op), Ok(len)) = (next.u8(), next.le::<u64>()) else {
            let n = r.remaining();
            return (at, Some(format!("{n} stray bytes at byte {at}")));
        };
        let follow = next.remaining();
        let Some(body) = usize::try_from(len).ok().and_then(|n| next.take(n).ok()) else {
            let why =
                format!("record 0x{op:02x} at byte {at} claims {len} bytes, but {follow} follow");
            return (at, Some(why));
        };
        // A data end record has no place in a chunk. `MessageStream` parses it there (and
        // stops where it has no CRC), `io::MessageReader` passes over it: too short for its
        // CRC, it is damage, so that reading a file streamed or held gives one answer.
        if op == OP_DATA_END && body.len() < 4 {
            return (
                at,
                Some(format!("data end record at byte {at} without its CRC")),
            );
        }
        r = next;
    }
    (b.len(), None)
}

/// What is wrong with a chunk record's body, if anything. Its claimed uncompressed size is
/// taken from `budget` before it is decompressed.
fn chunk_problem(body: &[u8], budget: &mut Budget) -> Option<String> {
    let mut r = Reader::new(body);
    // Start and end times, uncompressed size, CRC, compression name, records.
    let (Ok(()), Ok(size), Ok(crc), Ok(name_len)) =
        (r.skip(16), r.le::<u64>(), r.le::<u32>(), r.le::<u32>())
    else {
        return Some("its header is cut short".into());
    };
    if size > MAX_CHUNK_BYTES {
        return Some(format!(
            "it would decompress to {size} bytes, more than the {} MiB this reader accepts",
            MAX_CHUNK_BYTES >> 20
        ));
    }
    let name = usize::try_from(name_len).ok().and_then(|n| r.take(n).ok());
    let (Some(name), Ok(records_len)) = (name, r.le::<u64>()) else {
        return Some("its compression name overruns it".into());
    };
    let follow = r.remaining();
    let Some(records) = usize::try_from(records_len)
        .ok()
        .and_then(|n| r.take(n).ok())
    else {
        return Some(format!(
            "its records claim {records_len} bytes, but {follow} follow"
        ));
    };
    let inflated;
    let plain = match name {
        b"" => records,
        b"zstd" => {
            if !budget.take(size) {
                return Some(
                    "the chunks so far would decompress to more than 256 times the file's size \
                     (and 1 GiB): a crafted file, not a recording"
                        .into(),
                );
            }
            // `size` is at most MAX_CHUNK_BYTES: the buffer is bounded.
            inflated = match zstd::bulk::decompress(records, usize::try_from(size).ok()?) {
                Ok(d) => d,
                Err(e) => return Some(format!("its zstd data does not decompress ({e})")),
            };
            if inflated.len() as u64 != size {
                return Some(format!(
                    "it decompresses to {} bytes, not the {size} it claims",
                    inflated.len()
                ));
            }
            &inflated
        }
        // Skipped like any damage: the chunks after it still read.
        other => {
            return Some(format!(
                "its compression {:?} is not one this reader has (zstd, or none)",
                String::from_utf8_lossy(other)
            ));
        }
    };
    // A CRC of 0 means none was written (MCAP spec, Chunk).
    let sum = crc32fast::hash(plain);
    if crc != 0 && sum != crc {
        return Some(format!(
            "its records do not match its CRC (stored {crc:08x}, computed {sum:08x})"
        ));
    }
    walk(plain)
        .1
        .map(|why| format!("its {why} (after decompression)"))
}

/// The file without the stretches `survey` skipped, up to its sound end. At the first gap
/// go the file's top-level schema and channel records (the summary's, when the file has one):
/// a skipped chunk may have held the definitions the later chunks' messages use. Everything
/// before the first gap is read as it was; the `mcap` reader accepts a definition repeated
/// unchanged.
fn repair(b: &[u8], survey: &Survey) -> Vec<u8> {
    let mut out = Vec::with_capacity(survey.end);
    // The ranges come from one walk in file order; `get` keeps a slip from panicking.
    let mut copy = |r: std::ops::Range<usize>| out.extend_from_slice(b.get(r).unwrap_or_default());
    let mut at = 0;
    for (i, (gap, _)) in survey.skipped.iter().enumerate() {
        copy(at..gap.start);
        if i == 0 {
            for d in &survey.defs {
                copy(d.clone());
            }
        }
        at = gap.end;
    }
    copy(at..survey.end);
    out
}

/// What is said of a file, one part after the other ("; "), or nothing.
fn joined<const N: usize>(parts: [Option<String>; N]) -> Option<String> {
    let parts: Vec<String> = parts.into_iter().flatten().collect();
    (!parts.is_empty()).then(|| parts.join("; "))
}

/// [`repair`] in `b`'s own buffer, when the definitions fit in the first skipped stretch (a
/// damaged chunk is usually much larger than the file's definitions): the file is not held
/// twice. Every move is towards the start, so nothing is overwritten before it is moved; the
/// definitions are copied first, from sound records outside the stretch they go into.
/// `false` (and `b` unchanged) when they do not fit.
fn repair_in_place(b: &mut Vec<u8>, survey: &Survey) -> bool {
    let Some((first, _)) = survey.skipped.first() else {
        b.truncate(survey.end);
        return true;
    };
    let defs: usize = survey.defs.iter().map(std::ops::Range::len).sum();
    if defs > first.len() || !laid_out(survey, b.len()) {
        return false;
    }
    let mut w = first.start;
    for d in &survey.defs {
        b.copy_within(d.clone(), w);
        w += d.len();
    }
    let starts = survey.skipped.iter().map(|(r, _)| r.end);
    let ends = survey.skipped.iter().skip(1).map(|(r, _)| r.start);
    for (start, end) in starts.zip(ends.chain([survey.end])) {
        if start < end {
            b.copy_within(start..end, w);
            w += end - start;
        }
    }
    b.truncate(w);
    true
}

/// Whether `survey`'s ranges are as a walk of a `len`-byte file makes them, which the
/// in-place repairs rely on: skipped stretches non-empty, in file order and apart, before the
/// sound end; definitions within the file and outside every stretch.
fn laid_out(survey: &Survey, len: usize) -> bool {
    let gaps = || survey.skipped.iter().map(|(r, _)| r);
    let in_order = gaps().all(|r| r.start < r.end)
        && gaps().zip(gaps().skip(1)).all(|(a, b)| a.end <= b.start)
        && gaps().next_back().is_none_or(|r| r.end <= survey.end);
    let defs_apart = survey.defs.iter().all(|d| {
        d.start <= d.end && d.end <= len && gaps().all(|g| d.end <= g.start || g.end <= d.start)
    });
    in_order && defs_apart && survey.end <= len
}

/// [`repair`] of a file held in `b`, in its own buffer: when the definitions do not fit in the
/// first skipped stretch, the rest of the file is first moved up by what they lack (the
/// buffer grows by that much, not by the file's size).
fn repair_owned(mut b: Vec<u8>, survey: &Survey) -> Vec<u8> {
    if repair_in_place(&mut b, survey) {
        return b;
    }
    let Some((first, _)) = survey.skipped.first() else {
        return repair(&b, survey);
    };
    let defs: usize = survey.defs.iter().map(std::ops::Range::len).sum();
    let extra = defs.saturating_sub(first.len());
    let old = b.len();
    if !laid_out(survey, old) || b.try_reserve_exact(extra).is_err() {
        return repair(&b, survey);
    }
    b.resize(old + extra, 0);
    b.copy_within(first.end..old, first.end + extra);
    let moved = |r: &std::ops::Range<usize>| {
        if r.start >= first.end {
            r.start + extra..r.end + extra
        } else {
            r.clone()
        }
    };
    let mut skipped: Vec<_> = survey
        .skipped
        .iter()
        .map(|(r, w)| (moved(r), w.clone()))
        .collect();
    if let Some((r, _)) = skipped.first_mut() {
        r.end += extra;
    }
    let shifted = Survey {
        end: if survey.end >= first.end {
            survey.end + extra
        } else {
            survey.end
        },
        skipped,
        defs: survey.defs.iter().map(moved).collect(),
        ..Survey::default()
    };
    if repair_in_place(&mut b, &shifted) {
        b
    } else {
        // Not reached: the definitions fit the widened stretch.
        repair(&b, &shifted)
    }
}

/// The damage where a walk ends early, as [`Recording::damage`] says it.
fn ends_early(why: String) -> String {
    format!("it ends early: {why} (the file was cut short or is damaged)")
}

/// The first `sound` bytes of `b` (without the stretches the walk skipped).
fn sound_part(b: &[u8], sound: u64) -> &[u8] {
    usize::try_from(sound)
        .ok()
        .and_then(|n| b.get(..n))
        .unwrap_or(b)
}

/// The `ima` metadata record among the top-level records of `src` (an MCAP file), read a
/// record at a time without opening the chunks.
fn ima_metadata_in(mut src: impl Read) -> Option<BTreeMap<String, String>> {
    use mcap::sans_io::{LinearReadEvent, LinearReader, LinearReaderOptions};
    let opts = LinearReaderOptions::default()
        .with_emit_chunks(true)
        .with_record_length_limit(MAX_RECORD_BYTES as usize);
    let mut r = LinearReader::new_with_options(opts);
    while let Some(event) = r.next_event() {
        match event.ok()? {
            LinearReadEvent::ReadRequest(n) => {
                let got = loop {
                    match src.read(r.insert(n)) {
                        Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                        got => break got.ok()?,
                    }
                };
                r.notify_read(got);
            }
            LinearReadEvent::Record { data, opcode } => {
                if let Ok(mcap::records::Record::Metadata(m)) = mcap::parse_record(opcode, data)
                    && m.name == "ima"
                {
                    return Some(m.metadata);
                }
            }
        }
    }
    None
}

/// A recording that cannot be read.
#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    /// The file cannot be read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// Why.
        source: std::io::Error,
    },
    /// Not an MCAP file at all.
    #[error("{0}: not an MCAP file ({1})")]
    NotMcap(String, String),
    /// No such raw channel.
    #[error("no raw serial channel {wanted} in the recording; it has: {have}{left_out}")]
    NoPort {
        /// What was asked for.
        wanted: String,
        /// What there is.
        have: String,
        /// `" (the recording left out: PATTERNS)"` when it was made with `--record-exclude`,
        /// else empty.
        left_out: String,
    },
}

/// Whether `start` (a file's first bytes) is how an MCAP file begins: its magic.
#[must_use]
pub fn is_mcap(start: &[u8]) -> bool {
    start.starts_with(mcap::MAGIC)
}

/// One message of a recording.
#[derive(Debug, Clone, PartialEq)]
pub struct Message {
    /// Topic.
    pub topic: String,
    /// Schema name (empty: none).
    pub schema: String,
    /// Log time, Unix nanoseconds.
    pub log_time: u64,
    /// The payload.
    pub data: Vec<u8>,
}

/// One raw serial channel's chunks.
#[derive(Debug, Clone, PartialEq)]
pub struct RawStream {
    /// The port.
    pub port: PortInfo,
    /// The topic.
    pub topic: String,
    /// `(log time, direction, bytes)`; a baud change is [`raw::Dir::Baud`] with the rate as
    /// 4 bytes little-endian.
    pub chunks: Vec<(u64, raw::Dir, Vec<u8>)>,
}

impl RawStream {
    /// A stream of `c`'s port, without chunks yet.
    fn of(c: &RawChunk<'_>) -> Self {
        Self {
            port: c.port.clone(),
            topic: c.topic.to_owned(),
            chunks: Vec::new(),
        }
    }

    /// Keep a copy of `c`.
    fn push(&mut self, c: &RawChunk<'_>) {
        self.chunks.push((c.log_time, c.dir, c.bytes.to_vec()));
    }

    /// All bytes the device sent, in order.
    pub fn rx_bytes(&self) -> Vec<u8> {
        self.chunks
            .iter()
            .filter(|c| c.1 == raw::Dir::Rx)
            .flat_map(|c| c.2.iter().copied())
            .collect()
    }
}

/// One raw serial chunk of a recording, as [`Recording::each_raw_chunk`] reads it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RawChunk<'a> {
    /// The channel's topic.
    pub topic: &'a str,
    /// The port (from the channel's metadata).
    pub port: &'a PortInfo,
    /// Log time, Unix nanoseconds.
    pub log_time: u64,
    /// Which way the bytes went; [`raw::Dir::Baud`] is a line-speed change, the rate as 4
    /// bytes little-endian.
    pub dir: raw::Dir,
    /// The bytes.
    pub bytes: &'a [u8],
}

/// What reading could not give: damaged stretches skipped, or the file cut short by a crash.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Truncation(pub Option<String>);

impl Truncation {
    /// Why reading stopped early, unless that is `known` already (the damage found on opening,
    /// said before the reading): what a reader has left to say at its end.
    #[must_use]
    pub fn beyond(self, known: Option<&str>) -> Option<String> {
        self.0.filter(|why| known != Some(why.as_str()))
    }
}

impl Recording {
    /// Open a file (a regular file: a device such as `/dev/zero` would never end). Its
    /// structure is checked here, a record at a time; a sound file (or one a crash cut short)
    /// stays on disk and each read streams it again: see the module docs.
    pub fn open(path: &Path) -> Result<Self, ReadError> {
        let io = |source| ReadError::Io {
            path: path.display().to_string(),
            source,
        };
        let not_mcap = |why: String| ReadError::NotMcap(path.display().to_string(), why);
        let regular = |m: std::fs::Metadata| {
            m.is_file()
                .then_some(m)
                .ok_or_else(|| not_mcap("not a regular file".into()))
        };
        // Checked before opening too: opening a FIFO waits for a writer.
        regular(std::fs::metadata(path).map_err(io)?)?;
        let file = File::open(path).map_err(io)?;
        let meta = regular(file.metadata().map_err(io)?)?;
        let len = meta.len();
        let mut magic = [0u8; 8];
        if len < magic.len() as u64
            || read_exact_at(&file, &mut magic, 0).is_err()
            || magic != *mcap::MAGIC
        {
            return Err(not_mcap("no MCAP magic at the start".into()));
        }
        match survey_file(&file, len, LIMITS).map_err(io)? {
            FileSurvey::Sound {
                end,
                damage,
                after_end,
            } => Ok(Self {
                source: Source::File(file),
                sound: end,
                damage: joined([damage.map(ends_early), after_end]),
                stopped: std::sync::OnceLock::new(),
            }),
            FileSurvey::ReadWhole => {
                let mut bytes = Vec::new();
                // As `fs::read` does: one allocation when the memory is there.
                let _ = bytes.try_reserve_exact(usize::try_from(len).unwrap_or(0));
                let mut r = FileRange {
                    file: &file,
                    at: 0,
                    end: len,
                };
                r.read_to_end(&mut bytes).map_err(io)?;
                Self::from_bytes(bytes).map_err(not_mcap)
            }
        }
    }

    /// Whether the whole file is held in memory: one given as bytes
    /// ([`from_bytes`](Self::from_bytes)), or a file with a stretch to skip (read whole to be
    /// repaired), a record over [`MAX_CHUNK_BYTES`] plus 1 MiB, or more than 64 MiB after its
    /// damage. Otherwise each read streams the file, one chunk in memory at a time.
    #[must_use]
    pub fn holds_file(&self) -> bool {
        matches!(self.source, Source::Memory(_))
    }

    /// A recording held in memory; `Err` says why it is not an MCAP file.
    pub fn from_bytes(bytes: Vec<u8>) -> Result<Self, String> {
        if !is_mcap(&bytes) {
            return Err("no MCAP magic at the start".into());
        }
        let survey = survey(&bytes, mcap::MAGIC.len());
        let end = survey.damage.clone().map(ends_early);
        let skipped = (!survey.skipped.is_empty()).then(|| {
            let n = survey.skipped.len();
            let size: usize = survey.skipped.iter().map(|(r, _)| r.len()).sum();
            let (_, first) = &survey.skipped[0];
            let what = if n == 1 { "stretch" } else { "stretches" };
            format!(
                "{n} damaged {what} of {} KiB skipped (first: {first})",
                size.div_ceil(1024)
            )
        });
        let damage = joined([skipped, end, survey.after_end.clone()]);
        let (bytes, sound) = if survey.skipped.is_empty() {
            (bytes, survey.end)
        } else {
            let bytes = repair_owned(bytes, &survey);
            let sound = bytes.len();
            (bytes, sound)
        };
        Ok(Self {
            source: Source::Memory(bytes),
            sound: sound as u64,
            damage,
            stopped: std::sync::OnceLock::new(),
        })
    }

    /// Run `f` over every message the `mcap` crate gives for the sound part, until it returns
    /// `false` (`f` must only copy what it needs, or parse it with code that cannot panic: it
    /// runs under the panic guard, which would report a panic of ours as damage to the file).
    /// An error or a panic of the crate is kept for [`damage`](Self::damage); the crate's
    /// words for a prefix that ends inside a record or without a footer (a cut, which the
    /// walker's damage explains) are returned.
    fn each<'a>(&'a self, mut f: impl FnMut(mcap::Message<'a>) -> bool) -> Option<String> {
        let end = guarded(|| -> Result<(), mcap::McapError> {
            match &self.source {
                Source::Memory(b) => {
                    for m in mcap::MessageStream::new(sound_part(b, self.sound))? {
                        if !f(m?) {
                            break;
                        }
                    }
                }
                Source::File(file) => {
                    let opts = mcap::sans_io::LinearReaderOptions::default()
                        .with_record_length_limit(MAX_RECORD_BYTES as usize);
                    let bytes = std::io::BufReader::with_capacity(1 << 16, self.range(file));
                    for m in mcap::io::MessageReader::new_with_options(bytes, opts) {
                        if !f(m?) {
                            break;
                        }
                    }
                }
            }
            Ok(())
        });
        let early = match end {
            Ok(Ok(())) => return None,
            Ok(Err(e @ (mcap::McapError::UnexpectedEof | mcap::McapError::BadFooter))) => {
                return Some(e.to_string());
            }
            Ok(Err(e)) => e.to_string(),
            Err(panic) => panic,
        };
        let _ = self.stopped.set(early);
        None
    }

    /// The file's sound part, read from the file.
    fn range<'a>(&self, file: &'a File) -> FileRange<'a> {
        FileRange {
            file,
            at: 0,
            end: self.sound,
        }
    }

    /// What is wrong with the file, if anything: the `mcap` crate's error (once a read has
    /// met it), and what the walk skipped and where the file's sound structure ends, and why.
    #[must_use]
    pub fn damage(&self) -> Option<String> {
        match (self.stopped.get(), &self.damage) {
            (Some(e), Some(d)) => Some(format!("{e}; also: {d}")),
            (Some(e), None) => Some(e.clone()),
            (None, d) => d.clone(),
        }
    }

    /// Every message in file order, and why reading stopped early (a crashed recorder's file
    /// ends in the middle of a chunk: the complete chunks before it are all returned).
    ///
    /// A file whose structure is damaged ([`damage`](Self::damage)) gives the messages the
    /// walk kept (those of skipped chunks, and those after where the file ends early, are
    /// not there), with the damage as the reason.
    pub fn messages(&self) -> (Vec<Message>, Truncation) {
        let mut out = Vec::new();
        let cut = self.each(|m| {
            out.push(Message {
                topic: m.channel.topic.clone(),
                schema: m
                    .channel
                    .schema
                    .as_ref()
                    .map(|s| s.name.clone())
                    .unwrap_or_default(),
                log_time: m.log_time,
                data: m.data.into_owned(),
            });
            true
        });
        // The crate's own stop comes first (it stopped before the walker's damage).
        (out, Truncation(self.damage().or(cut)))
    }

    /// How many messages the file holds, and why reading stopped early (as
    /// [`messages`](Self::messages), without keeping them).
    pub fn count(&self) -> (usize, Truncation) {
        let mut n = 0;
        let cut = self.each(|_| {
            n += 1;
            true
        });
        (n, Truncation(self.damage().or(cut)))
    }

    /// How many messages the file holds on each topic (as [`count`](Self::count), by topic).
    #[must_use]
    pub fn count_by_topic(&self) -> BTreeMap<String, u64> {
        let mut out = BTreeMap::new();
        self.each(|m| {
            *out.entry(m.channel.topic.clone()).or_insert(0) += 1;
            true
        });
        out
    }

    /// Every channel: topic → (schema name, metadata).
    pub fn channels(&self) -> BTreeMap<String, (String, BTreeMap<String, String>)> {
        let mut out = BTreeMap::new();
        self.each(|m| {
            out.entry(m.channel.topic.clone()).or_insert_with(|| {
                (
                    m.channel
                        .schema
                        .as_ref()
                        .map(|s| s.name.clone())
                        .unwrap_or_default(),
                    m.channel.metadata.clone(),
                )
            });
            true
        });
        out
    }

    /// The transforms that do not move, as the first 5 s of the recording's `/tf` hold them
    /// (the recorder sends them again every second): `map` → `<robot>/odom` (where each robot
    /// started), `<robot>/base_link` → `<robot>/laser`, and `<robot>/odom` →
    /// `<robot>/base_link` for a robot with no odometry to replay (`ima scan`'s).
    /// `(parent, child, [x, y, yaw])`, metres and radians; a replay republishes them, so its
    /// readings have a place in `map`. The window starts at the first `/tf`, and the read
    /// stops 30 s of log time into the file whatever it holds.
    pub fn fixed_transforms(&self) -> Vec<(String, String, [f64; 3])> {
        use foxglove::Decode as _;
        let mut out: Vec<(String, String, [f64; 3])> = Vec::new();
        let mut odometry: Vec<String> = Vec::new();
        let (mut start, mut first_tf): (Option<u64>, Option<u64>) = (None, None);
        self.each(|m| {
            let t = m.log_time;
            let since = |t0: Option<u64>| t0.map_or(0, |t0| t.saturating_sub(t0));
            if since(Some(*start.get_or_insert(t))) > 30_000_000_000
                || since(first_tf) > 5_000_000_000
            {
                return false;
            }
            let topic = &m.channel.topic;
            if let Some(robot) = topic
                .strip_prefix('/')
                .and_then(|r| r.strip_suffix("/odom"))
                && !odometry.iter().any(|o| o == robot)
            {
                odometry.push(robot.to_owned());
            }
            if topic != "/tf" {
                return true;
            }
            first_tf.get_or_insert(t);
            let Ok(tf) = foxglove::messages::FrameTransform::decode(&m.data[..]) else {
                return true;
            };
            let (parent, child) = (&tf.parent_frame_id, &tf.child_frame_id);
            let fixed = parent == "map"
                || child.ends_with("/laser")
                || (parent.ends_with("/odom") && child.ends_with("/base_link"));
            let known = out.iter().any(|(p, c, _)| p == parent && c == child);
            if fixed && !known {
                let (x, y) = tf.translation.map_or((0.0, 0.0), |v| (v.x, v.y));
                let yaw = tf.rotation.map_or(0.0, |q| 2.0 * q.z.atan2(q.w));
                out.push((parent.clone(), child.clone(), [x, y, yaw]));
            }
            true
        });
        // A robot's odometry moves: its `odom` → `base_link` is the replay's to publish.
        out.retain(|(p, c, _)| {
            let moving = c.ends_with("/base_link")
                && p.strip_suffix("/odom")
                    .is_some_and(|r| odometry.iter().any(|o| o == r));
            !moving
        });
        out
    }

    /// Every channel whose schema is a JSON Schema (encoding `jsonschema`, the `ima.*` state
    /// topics): topic → the schema, parsed (`Null` where it does not parse).
    pub fn json_schemas(&self) -> BTreeMap<String, serde_json::Value> {
        let mut out = BTreeMap::new();
        self.each(|m| {
            if let Some(s) = m
                .channel
                .schema
                .as_ref()
                .filter(|s| s.encoding == "jsonschema")
            {
                out.entry(m.channel.topic.clone())
                    .or_insert_with(|| serde_json::from_slice(&s.data).unwrap_or_default());
            }
            true
        });
        out
    }

    /// Every raw serial channel with its chunks, copied out message by message as the chunks
    /// are read (no other message is kept: replaying or decoding a long recording holds its
    /// raw bytes, not every camera frame it decompressed on the way).
    pub fn raw_streams(&self) -> Vec<RawStream> {
        let mut by_topic: BTreeMap<String, RawStream> = BTreeMap::new();
        self.each_raw_chunk(|c| {
            match by_topic.get_mut(c.topic) {
                Some(s) => s.push(&c),
                None => by_topic
                    .entry(c.topic.to_owned())
                    .or_insert(RawStream::of(&c))
                    .push(&c),
            }
            true
        });
        by_topic.into_values().collect()
    }

    /// Every raw serial chunk in file order, to `f` until it returns `false`, holding none of
    /// them (a replay re-decodes a long recording this way); and why reading stopped early,
    /// as [`messages`](Self::messages) says it. `f` runs under the guard that catches the
    /// `mcap` crate's panics: it must not panic itself.
    pub fn each_raw_chunk(&self, mut f: impl FnMut(RawChunk<'_>) -> bool) -> Truncation {
        // Topic → its port, or `None` for a raw channel without port metadata (passed over).
        let mut ports: BTreeMap<String, Option<PortInfo>> = BTreeMap::new();
        let cut = self.each(|m| {
            if m.channel.message_encoding != raw::ENCODING {
                return true;
            }
            let topic = &m.channel.topic;
            if !ports.contains_key(topic) {
                ports.insert(topic.clone(), PortInfo::from_metadata(&m.channel.metadata));
            }
            let Some(Some(port)) = ports.get(topic) else {
                return true;
            };
            let baud;
            let (dir, bytes) = match raw::parse(&m.data) {
                Some(Chunk::Bytes(d, b)) => (d, b),
                Some(Chunk::Baud(b)) => {
                    baud = b.to_le_bytes();
                    (raw::Dir::Baud, &baud[..])
                }
                None => return true,
            };
            f(RawChunk {
                topic,
                port,
                log_time: m.log_time,
                dir,
                bytes,
            })
        });
        Truncation(self.damage().or(cut))
    }

    /// The `ima` metadata record the recorder writes first (the session's `name`, the
    /// `version`, and under `exclude` the patterns of topics left out of the file), if the file
    /// has one. Found in files cut short by a crash too.
    pub fn ima_metadata(&self) -> Option<BTreeMap<String, String>> {
        guarded(|| match &self.source {
            Source::Memory(b) => ima_metadata_in(sound_part(b, self.sound)),
            Source::File(file) => ima_metadata_in(self.range(file)),
        })
        .unwrap_or_else(|panic| {
            let _ = self.stopped.set(panic);
            None
        })
    }

    /// The topic patterns the recorder was told to leave out (`--record-exclude`), as given,
    /// comma-separated; `None` when it left nothing out.
    pub fn left_out(&self) -> Option<String> {
        self.ima_metadata()?.remove("exclude")
    }

    /// The raw stream whose topic, `robot/device` or port path is `name` (only its bytes are
    /// kept); should two channels answer to `name`, the first in file order (see
    /// [`each_chunk_of`](Self::each_chunk_of)).
    pub fn raw_stream(&self, name: &str) -> Result<RawStream, ReadError> {
        let mut stream: Option<RawStream> = None;
        self.each_chunk_of(name, |c| {
            stream.get_or_insert_with(|| RawStream::of(&c)).push(&c);
            true
        })?;
        // `each_chunk_of` found the port, so it gave at least one chunk.
        stream.ok_or_else(|| self.no_port(name, Vec::new()))
    }

    /// The raw chunks of one port, named as [`raw_stream`](Self::raw_stream) names it, to `f`
    /// in file order as they are read, holding none of them (`ima replay --as-mock` and
    /// `ima decode --mcap` serve or decode a long recording this way), until `f` returns
    /// `false`; and why reading stopped early, as [`messages`](Self::messages) says it.
    ///
    /// Should two channels answer to `name` (two robots' ports at one path), the first in
    /// file order is the one read. `f` runs under the guard that catches the `mcap` crate's
    /// panics: it must not panic itself.
    ///
    /// # Errors
    /// [`ReadError::NoPort`], naming every raw channel the recording has, if none answers to
    /// `name` (known only once the file has been read to its end).
    pub fn each_chunk_of(
        &self,
        name: &str,
        mut f: impl FnMut(RawChunk<'_>) -> bool,
    ) -> Result<Truncation, ReadError> {
        // The channel read, once one answers; every raw channel seen, as "topic (path)".
        let mut chosen: Option<String> = None;
        let mut seen: BTreeMap<String, String> = BTreeMap::new();
        let cut = self.each_raw_chunk(|c| {
            if chosen.is_none() {
                if !seen.contains_key(c.topic) {
                    seen.insert(c.topic.to_owned(), c.port.port.clone());
                }
                if is_port(c.topic, c.port, name) {
                    chosen = Some(c.topic.to_owned());
                }
            }
            if chosen.as_deref() != Some(c.topic) {
                return true;
            }
            f(c)
        });
        if chosen.is_none() {
            let have = seen.iter().map(|(t, p)| format!("{t} ({p})")).collect();
            return Err(self.no_port(name, have));
        }
        Ok(cut)
    }

    fn no_port(&self, name: &str, have: Vec<String>) -> ReadError {
        ReadError::NoPort {
            wanted: name.to_owned(),
            have: if have.is_empty() {
                "none".into()
            } else {
                have.join(", ")
            },
            left_out: self
                .left_out()
                .map(|p| format!(" (the recording left out: {p})"))
                .unwrap_or_default(),
        }
    }
}

/// Whether the raw channel `topic` of `port` answers to `name`: its topic (with or without
/// the leading `/`), its port's path, or `robot/device`.
fn is_port(topic: &str, port: &PortInfo, name: &str) -> bool {
    topic == name
        || topic.trim_start_matches('/') == name
        || port.port == name
        || (name.strip_prefix(port.robot.as_str())).and_then(|r| r.strip_prefix('/'))
            == Some(port.device.as_str())
}

#[cfg(test)]
mod tests {
    use super::*;

    proptest::proptest! {
        /// Repairing in the file's own buffer gives what the copying repair gives, whenever
        /// the definitions fit in the first skipped stretch (otherwise it leaves the buffer as
        /// it was), and with room made for them when they do not.
        #[test]
        fn repairing_in_place_is_the_copying_repair(
            len in 0usize..400,
            cuts in proptest::collection::vec(0usize..400, 0..8),
            defs in proptest::collection::vec((0usize..400, 0usize..20), 0..4),
            seed in proptest::prelude::any::<u8>(),
        ) {
            let b: Vec<u8> = (0..len).map(|i| (i as u8).wrapping_mul(31) ^ seed).collect();
            // Sorted, disjoint skipped stretches from pairs of cut points; definitions outside
            // them; the sound end after the last.
            let mut cuts: Vec<usize> = cuts.into_iter().map(|c| c.min(len)).collect();
            cuts.sort_unstable();
            cuts.dedup();
            let end = cuts.pop().unwrap_or(len);
            let skipped: Vec<_> = cuts
                .chunks_exact(2)
                .map(|c| (c[0]..c[1], String::new()))
                .collect();
            let inside = |p: usize| skipped.iter().any(|(r, _)| r.start <= p && p < r.end);
            let defs: Vec<_> = defs
                .into_iter()
                .map(|(s, n)| s.min(end)..(s + n).min(end))
                .filter(|d| !d.clone().any(inside))
                .collect();
            let survey = Survey { end, skipped, defs, ..Survey::default() };
            let copied = repair(&b, &survey);
            let mut own = b.clone();
            if repair_in_place(&mut own, &survey) {
                proptest::prop_assert_eq!(&own, &copied);
            } else {
                proptest::prop_assert_eq!(&own, &b);
            }
            proptest::prop_assert_eq!(repair_owned(b, &survey), copied);
        }
    }

    fn record(op: u8, body: &[u8]) -> Vec<u8> {
        let mut r = vec![op];
        r.extend_from_slice(&(body.len() as u64).to_le_bytes());
        r.extend_from_slice(body);
        r
    }

    /// An uncompressed chunk holding `records`.
    fn chunk(records: &[u8]) -> Vec<u8> {
        let mut b = Vec::new();
        b.extend_from_slice(&[0; 16]); // message start and end times
        b.extend_from_slice(&(records.len() as u64).to_le_bytes());
        b.extend_from_slice(&[0; 8]); // CRC (none), compression name: empty
        b.extend_from_slice(&(records.len() as u64).to_le_bytes());
        b.extend_from_slice(records);
        record(OP_CHUNK, &b)
    }

    fn survey_of(bytes: &[u8], limits: Limits) -> FileSurvey {
        let path = std::env::temp_dir().join(format!(
            "ima-record-survey-{}-{}.mcap",
            std::process::id(),
            bytes.len()
        ));
        std::fs::write(&path, bytes).unwrap();
        let file = File::open(&path).unwrap();
        let _ = std::fs::remove_file(&path);
        survey_file(&file, bytes.len() as u64, limits).unwrap()
    }

    /// A record over the walk's limit, or more of the file after damage than it reads, sends
    /// the file to the in-memory walk; within the limits the same file is streamed.
    #[test]
    fn past_its_limits_the_walk_reads_the_file_whole() {
        let mut sound = mcap::MAGIC.to_vec();
        sound.extend(chunk(&record(0x07, &[0; 6])));
        match survey_of(&sound, LIMITS) {
            FileSurvey::Sound {
                end,
                damage: Some(why),
                ..
            } => {
                assert_eq!(end, sound.len() as u64);
                assert!(
                    why.contains("between two records, without its footer"),
                    "{why}"
                );
            }
            other => panic!("a sound file is streamed (its missing footer said): {other:?}"),
        }
        let small = Limits {
            record: 8,
            tail: 64,
        };
        assert!(matches!(survey_of(&sound, small), FileSurvey::ReadWhole));

        // A broken length after the chunk, then 100 bytes: no sound chunk follows.
        let mut cut = sound.clone();
        cut.push(0x05);
        cut.extend_from_slice(&1000u64.to_le_bytes());
        cut.extend_from_slice(&[0; 100]);
        match survey_of(&cut, LIMITS) {
            FileSurvey::Sound {
                end,
                damage: Some(why),
                ..
            } => {
                assert_eq!(end, sound.len() as u64);
                assert!(why.contains("claims 1000 bytes, but 100 follow"), "{why}");
            }
            other => panic!("{other:?}"),
        }
        let short_tail = Limits {
            record: MAX_RECORD_BYTES,
            tail: 64,
        };
        assert!(matches!(survey_of(&cut, short_tail), FileSurvey::ReadWhole));
    }
}

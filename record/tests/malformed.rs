//! Malformed recordings: every reading method returns what comes before the damage and says
//! what it is, and none panics. The `mcap` crate (0.26) panicked on the first three files below
//! (a record length near `u64::MAX`, a chunk claiming an absurd uncompressed size, an
//! uncompressed chunk whose inner record overruns it), and on about one single-byte corruption
//! of a real recording in ten.

use std::time::Duration;

use ima_record::convert::Pose2;
use ima_record::raw::PortInfo;
use ima_record::read::Recording;
use ima_record::{Options, Recorder};

const MAGIC: &[u8] = b"\x89MCAP0\r\n";

fn record(op: u8, body: &[u8]) -> Vec<u8> {
    let mut r = vec![op];
    r.extend_from_slice(&(body.len() as u64).to_le_bytes());
    r.extend_from_slice(body);
    r
}

/// A chunk record: `size` claimed uncompressed, `compression`, `records` as stored.
fn chunk(size: u64, compression: &str, records: &[u8]) -> Vec<u8> {
    let mut b = Vec::new();
    b.extend_from_slice(&0u64.to_le_bytes()); // message start time
    b.extend_from_slice(&0u64.to_le_bytes()); // message end time
    b.extend_from_slice(&size.to_le_bytes());
    b.extend_from_slice(&0u32.to_le_bytes()); // CRC: none
    b.extend_from_slice(&(compression.len() as u32).to_le_bytes());
    b.extend_from_slice(compression.as_bytes());
    b.extend_from_slice(&(records.len() as u64).to_le_bytes());
    b.extend_from_slice(records);
    record(0x06, &b)
}

/// Everything a recording gives: its messages and why they stop, its channels, raw streams,
/// `ima` metadata, one raw stream by name (or what it says when it has none) and damage
/// (asked last: a read can add to it).
type Everything = (
    Vec<ima_record::read::Message>,
    Option<String>,
    Vec<String>,
    Vec<ima_record::read::RawStream>,
    Option<std::collections::BTreeMap<String, String>>,
    Result<ima_record::read::RawStream, String>,
    Option<String>,
);

fn everything(rec: &Recording) -> Everything {
    let (msgs, why) = rec.messages();
    let channels = rec.channels().into_keys().collect();
    (
        msgs,
        why.0,
        channels,
        rec.raw_streams(),
        rec.ima_metadata(),
        rec.raw_stream("skeeter/base").map_err(|e| e.to_string()),
        rec.damage(),
    )
}

/// Every reading method on `bytes` (none may panic); the damage reported by `messages`.
/// The reader's own check must have caught it: a panic of the `mcap` crate, even caught,
/// fails the test. The same bytes as a file, opened (and streamed, unless they need repair),
/// must read exactly alike.
fn read_all(bytes: Vec<u8>) -> Option<String> {
    let opened = open_as_file(&bytes);
    let Ok(rec) = Recording::from_bytes(bytes) else {
        assert!(opened.is_err(), "a file of the same bytes opened");
        return None;
    };
    let _ = rec.raw_stream("base");
    let all = everything(&rec);
    let why = all.1.clone();
    // Counting gives what reading gives, without keeping the messages.
    let (n, cut) = rec.count();
    assert_eq!((n, &cut.0), (all.0.len(), &why));
    for w in [&why, &rec.damage()].into_iter().flatten() {
        assert!(
            !w.contains("the MCAP reader failed"),
            "a panic got past the check: {w}"
        );
    }
    let opened = opened.expect("the bytes as a file open");
    assert!(
        everything(&opened) == all,
        "the file reads otherwise: {why:?}"
    );
    // Only a file with a stretch to skip is held (these files are far below the walk's
    // limits); every other one is streamed.
    let skipped = why.as_deref().unwrap_or("").contains(" skipped (first: ");
    assert_eq!(opened.holds_file(), skipped, "{why:?}");
    why
}

/// `bytes` written to a file and opened.
fn open_as_file(bytes: &[u8]) -> Result<Recording, ima_record::read::ReadError> {
    use std::sync::atomic::{AtomicU32, Ordering};
    static N: AtomicU32 = AtomicU32::new(0);
    let n = N.fetch_add(1, Ordering::Relaxed);
    let path =
        std::env::temp_dir().join(format!("ima-record-open-{}-{n}.mcap", std::process::id()));
    std::fs::write(&path, bytes).unwrap();
    let rec = Recording::open(&path);
    // Open files stay readable once unlinked.
    let _ = std::fs::remove_file(&path);
    rec
}

#[test]
fn a_record_length_near_u64_max_is_damage_not_a_panic() {
    let mut f = MAGIC.to_vec();
    f.push(0x01);
    f.extend_from_slice(&[0xff; 8]);
    let why = read_all(f).expect("damage");
    assert!(why.contains("claims 18446744073709551615 bytes"), "{why}");
}

/// A recorder writes a chunk's header with a length of all ones and fills it in when the chunk
/// is done: a file read while it is written, or after its recorder was killed, ends in one.
#[test]
fn a_chunk_being_written_is_named_as_such() {
    let mut f = MAGIC.to_vec();
    f.push(0x06);
    f.extend_from_slice(&[0xff; 8]);
    f.extend_from_slice(&[0; 44]);
    let why = read_all(f).expect("damage");
    assert!(
        why.contains("it ends early: the chunk at byte 8 was never finished"),
        "{why}"
    );
}

/// `MessageStream` parses a data end record inside a chunk and stops where it has no CRC;
/// `io::MessageReader` passes over it. Both readings skip the chunk now.
#[test]
fn a_data_end_record_without_its_crc_in_a_chunk_is_damage() {
    let why = uncompressed_chunk_damage(&record(0x0f, &[1, 2]));
    assert!(
        why.contains("its data end record at byte 0 without its CRC"),
        "{why}"
    );
}

#[test]
fn a_chunk_claiming_an_absurd_size_is_damage_not_an_allocation() {
    let mut f = MAGIC.to_vec();
    f.extend(chunk(u64::MAX, "zstd", &[]));
    let why = read_all(f).expect("damage");
    assert!(
        why.contains("chunk at byte 8") && why.contains("256 MiB"),
        "{why}"
    );
}

/// The damage reported for a file holding one uncompressed chunk of `records`.
fn uncompressed_chunk_damage(records: &[u8]) -> String {
    let mut f = MAGIC.to_vec();
    f.extend(chunk(records.len() as u64, "", records));
    read_all(f).expect("damage")
}

#[test]
fn an_uncompressed_chunk_whose_record_overruns_it_is_damage() {
    let mut inner = vec![0x05];
    inner.extend_from_slice(&(u64::MAX - 3).to_le_bytes());
    let why = uncompressed_chunk_damage(&inner);
    assert!(why.contains("its record 0x05 at byte 0 claims"), "{why}");
}

/// The reader would take the bytes after the chunk for the rest of that record.
#[test]
fn an_uncompressed_chunk_ending_in_stray_bytes_is_damage() {
    let mut inner = record(0x07, &[]);
    inner.extend_from_slice(&[0x05, 1, 2]);
    let why = uncompressed_chunk_damage(&inner);
    assert!(why.contains("3 stray bytes at byte 9"), "{why}");
}

/// A recorder writing `path`, and its one raw port (robot, device, baud, protocol) on
/// `/dev/pts/9`.
fn recorder(
    path: &std::path::Path,
    name: &str,
    (robot, device, baud, protocol): (&str, &str, u32, &str),
) -> (Recorder, ima_record::raw::RawPort) {
    let rec = Recorder::start(&Options {
        mcap: Some(path.to_path_buf()),
        name: name.into(),
        ..Options::default()
    })
    .unwrap();
    let port = rec.raw_port(PortInfo {
        robot: robot.into(),
        device: device.into(),
        port: "/dev/pts/9".into(),
        baud,
        protocol: protocol.into(),
        params: Default::default(),
    });
    (rec, port)
}

#[test]
fn single_byte_corruptions_of_a_real_recording_never_panic() {
    let dir = std::env::temp_dir().join(format!("ima-record-malformed-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("small.mcap");
    let _ = std::fs::remove_file(&path);
    let (rec, port) = recorder(&path, "malformed", ("skeeter", "base", 9600, "p2os"));
    for i in 0..40u8 {
        port.tx(&[0xfa, 0xfb, 3, i, 0, i]);
        port.rx(&[0xfa, 0xfb, 3, 0, i, i]);
        let x_m = f64::from(i) * 0.1;
        rec.log_odometry(
            "skeeter",
            Pose2 {
                x_m,
                ..Pose2::default()
            },
        );
    }
    let report = rec.finish(Duration::from_secs(10));
    assert_eq!(report.error, None);
    let good = std::fs::read(&path).unwrap();
    assert_eq!(read_all(good.clone()), None);
    let mut damaged = 0;
    for at in (MAGIC.len()..good.len()).step_by(3) {
        for v in [0xff, good[at] ^ 0x5e] {
            let mut bad = good.clone();
            bad[at] = v;
            damaged += usize::from(read_all(bad).is_some());
        }
        // Cut there too.
        let _ = read_all(good[..at].to_vec());
    }
    assert!(damaged > 0);
    let _ = std::fs::remove_dir_all(&dir);
}

/// A recording of `n` raw messages of 64 KiB of noise (each chunk then holds about 16), and the
/// offsets of its top-level chunk records.
fn noisy_recording(name: &str, n: u32) -> (Vec<u8>, Vec<usize>) {
    let dir = std::env::temp_dir().join(format!("ima-record-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("noisy.mcap");
    let _ = std::fs::remove_file(&path);
    let (rec, port) = recorder(&path, name, ("scooter", "laser", 38400, "sick-lms"));
    let mut x = 0x2545_f491_4f6c_dd1d_u64; // xorshift: incompressible bytes
    for _ in 0..n {
        let noise: Vec<u8> = (0..64 * 1024)
            .map(|_| {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                x as u8
            })
            .collect();
        port.rx(&noise);
    }
    assert_eq!(rec.finish(Duration::from_secs(30)).error, None);
    let bytes = std::fs::read(&path).unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    let mut chunks = Vec::new();
    let mut at = MAGIC.len();
    while at + 9 <= bytes.len() && bytes[at] != 0x02 {
        if bytes[at] == 0x06 {
            chunks.push(at);
        }
        at += 9 + usize::try_from(u64::from_le_bytes(
            bytes[at + 1..at + 9].try_into().unwrap(),
        ))
        .unwrap();
    }
    (bytes, chunks)
}

/// A flipped byte in one chunk (caught by zstd, by the chunk's CRC or as a compression
/// nobody has), or a broken chunk length, loses that chunk's messages, not the rest of the file: the reader skips the chunk (or picks up at the next sound one), the later
/// messages keep their channel (defined in the skipped chunk; the summary repeats it), and the
/// damage says what was skipped. It used to end the recording at the first bad chunk.
#[test]
fn a_damaged_chunk_in_the_middle_loses_only_its_own_messages() {
    let (good, chunks) = noisy_recording("skip", 64);
    assert!(chunks.len() >= 4, "{chunks:?}");
    let all = Recording::from_bytes(good.clone()).unwrap().count();
    assert_eq!(all, (64, Default::default()));
    // Sound, and cut short inside its last chunk (a crash): streamed from the file, not held.
    for bytes in [&good[..], &good[..chunks[chunks.len() - 1] + 100]] {
        let opened = open_as_file(bytes).unwrap();
        assert!(!opened.holds_file());
        let held = Recording::from_bytes(bytes.to_vec()).unwrap();
        assert!(everything(&opened) == everything(&held));
    }
    // (what is broken, the damage's words): the first chunk holds the channel definition.
    let compressed = |c: usize| c + 9 + 44 + 2; // record, chunk header, into zstd's frame header
    for (at, flip, words) in [
        (
            compressed(chunks[0]),
            0x55,
            "its zstd data does not decompress",
        ),
        (
            compressed(chunks[1]),
            0x55,
            "its zstd data does not decompress",
        ),
        (chunks[1] + 6, 0x40, "claims"), // the chunk record's length, far past the file
        // Its CRC; a byte deep in its (stored, incompressible) data; its compression's name.
        (chunks[1] + 9 + 24, 0x01, "do not match its CRC"),
        (compressed(chunks[1]) + 1000, 0x01, "do not match its CRC"),
        (
            chunks[1] + 9 + 32,
            0x20,
            "compression \"Zstd\" is not one this reader has",
        ),
    ] {
        let mut bad = good.clone();
        bad[at] ^= flip;
        // Damage in the middle: the file is read whole to be repaired, and reads alike.
        let opened = open_as_file(&bad).unwrap();
        assert!(opened.holds_file());
        let rec = Recording::from_bytes(bad).unwrap();
        assert!(everything(&opened) == everything(&rec));
        let (msgs, why) = rec.messages();
        let why = why.0.expect("the damage is reported");
        assert!(
            why.contains("1 damaged stretch") && why.contains(words) && !why.contains("ends early"),
            "{why}"
        );
        // One chunk's messages lost; every other one read, on its channel.
        assert!(
            (40..64).contains(&msgs.len()),
            "{} of 64: {why}",
            msgs.len()
        );
        assert!(msgs.iter().all(|m| m.topic == "/scooter/serial/laser"));
        assert_eq!(
            rec.raw_stream("scooter/laser").unwrap().chunks.len(),
            msgs.len()
        );
    }
    // Cut inside the last chunk (a crash), with a damaged chunk before: both are said.
    let mut bad = good[..chunks[chunks.len() - 1] + 100].to_vec();
    bad[compressed(chunks[1])] ^= 0x55;
    let why = Recording::from_bytes(bad).unwrap().count().1.0.unwrap();
    assert!(
        why.contains("1 damaged stretch") && why.contains("it ends early"),
        "{why}"
    );
}

/// A message index whose entries do not fill it: the `mcap` crate parses it and stopped the
/// whole read there. It is skipped now, and no message is lost.
#[test]
fn a_damaged_message_index_loses_no_message() {
    let (mut bad, chunks) = noisy_recording("index", 32);
    // The message index right after the second chunk: its entries' byte length, made odd.
    let len = |at: usize| {
        usize::try_from(u64::from_le_bytes(bad[at + 1..at + 9].try_into().unwrap())).unwrap()
    };
    let index = chunks[1] + 9 + len(chunks[1]);
    assert_eq!(bad[index], 0x07, "a message index follows the chunk");
    bad[index + 9 + 2] ^= 0x01;
    let rec = Recording::from_bytes(bad).unwrap();
    let (msgs, why) = rec.messages();
    let why = why.0.expect("the damage is reported");
    assert!(
        why.contains("message index at byte") && why.contains("no message is lost"),
        "{why}"
    );
    assert_eq!(msgs.len(), 32, "{why}");
}

/// A zeroed stretch from inside the file's metadata record to inside its second chunk (a
/// bad disk block, a file system's hole): the metadata no longer parses, and the `mcap` reader
/// used to stop the whole read there. Now the stretch is skipped and the chunks after it read,
/// on their channel (defined in the first, zeroed chunk; the summary repeats it).
#[test]
fn a_zeroed_stretch_loses_only_what_it_covers() {
    let (good, chunks) = noisy_recording("zeroed", 64);
    let mut at = MAGIC.len();
    let meta = loop {
        if good[at] == 0x0c {
            break at;
        }
        assert!(at < chunks[0], "a metadata record before the first chunk");
        at += 9 + usize::try_from(u64::from_le_bytes(good[at + 1..at + 9].try_into().unwrap()))
            .unwrap();
    };
    let mut bad = good.clone();
    bad[meta + 20..chunks[1] + 100].fill(0);
    let opened = open_as_file(&bad).unwrap();
    assert!(opened.holds_file());
    let rec = Recording::from_bytes(bad).unwrap();
    assert!(everything(&opened) == everything(&rec));
    let (msgs, why) = rec.messages();
    let why = why.0.expect("the damage is reported");
    assert!(
        why.contains("1 damaged stretch")
            && why.contains("record 0x0c at byte")
            && why.contains("does not parse"),
        "{why}"
    );
    assert!(
        (20..64).contains(&msgs.len()),
        "{} of 64: {why}",
        msgs.len()
    );
    assert!(msgs.iter().all(|m| m.topic == "/scooter/serial/laser"));
}

/// Two recordings joined (`cat a.mcap b.mcap`): the first is read whole and what follows its
/// end is said (it was read as the first alone, without a word).
#[test]
fn bytes_after_the_end_are_said() {
    let (good, _) = noisy_recording("joined", 8);
    let mut joined = good.clone();
    joined.extend_from_slice(&good);
    let opened = open_as_file(&joined).unwrap();
    assert!(!opened.holds_file());
    let held = Recording::from_bytes(joined).unwrap();
    assert!(everything(&opened) == everything(&held));
    let why = held.damage().expect("said");
    assert_eq!(
        why,
        format!(
            "{} bytes follow the file's end and are not read (another file appended?)",
            good.len()
        )
    );
    let (msgs, cut) = held.messages();
    assert_eq!(msgs.len(), 8);
    // What reading met is the same: said as the file's damage, not found again.
    assert_eq!(cut.0.as_deref(), Some(why.as_str()));
    assert_eq!(Recording::from_bytes(good).unwrap().damage(), None);
}

/// A crafted file of small chunks that each claim a large uncompressed size: the walk stops
/// decompressing at its budget (1 GiB plus 256 bytes per byte of file) instead of going on
/// for as long as the file has chunks.
#[test]
fn chunks_claiming_more_than_the_budget_end_the_walk() {
    const SIZE: usize = 16 << 20;
    // One uncompressed record filling the chunk: a message record of zeros.
    let mut plain = record(0x05, &vec![0u8; SIZE - 9]);
    plain.truncate(SIZE);
    let packed = zstd::bulk::compress(&plain, 1).unwrap();
    let bomb = chunk(SIZE as u64, "zstd", &packed);
    let mut f = MAGIC.to_vec();
    for _ in 0..80 {
        f.extend_from_slice(&bomb); // 80 × 16 MiB = 1.25 GiB claimed
    }
    let file_len = f.len() as u64;
    let why = read_all(f).expect("damage");
    assert!(why.contains("more than 256 times the file's size"), "{why}");
    // Every chunk the budget allowed was checked; the first refused one ends the file.
    let allowed = ((1u64 << 30) + 256 * file_len) / SIZE as u64;
    let at = MAGIC.len() as u64 + allowed * bomb.len() as u64;
    assert!(why.contains(&format!("chunk at byte {at}:")), "{why}");
}

/// Only regular files are read, and a FIFO is refused without opening it (opening one waits
/// for a writer: the reader hung when it opened the file before looking at it).
#[cfg(unix)]
#[test]
fn a_fifo_or_a_directory_is_refused_at_once() {
    let dir = std::env::temp_dir().join(format!("ima-record-fifo-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let fifo = dir.join("pipe.mcap");
    let made = std::process::Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .unwrap();
    assert!(made.success());
    // On a thread, so a regression fails the test instead of hanging it.
    let (tx, rx) = std::sync::mpsc::channel();
    for path in [fifo, dir.clone()] {
        let tx = tx.clone();
        std::thread::spawn(move || {
            let _ = tx.send(Recording::open(&path).map(|_| ()).unwrap_err().to_string());
        });
        let err = rx.recv_timeout(Duration::from_secs(10)).expect("no answer");
        assert!(
            err.ends_with("not an MCAP file (not a regular file)"),
            "{err}"
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// A file cut a few bytes into a record's header (a recorder killed between two records)
/// says where and how, in its own words ("MCAP file ended in the middle of a record" was the
/// `mcap` crate's, whatever the cut); one cut exactly between records says the end is missing.
#[test]
fn a_file_cut_between_or_inside_records_says_where() {
    let mut b = MAGIC.to_vec();
    b.extend(record(0x01, &[0; 8])); // a header: profile and library, both empty
    b.extend(chunk(0, "", &[]));
    let between = b.len();
    b.extend_from_slice(&[0x06, 0xff, 0xff]);
    assert_eq!(
        read_all(b.clone()).as_deref(),
        Some(
            "it ends early: it stops 3 bytes into the record at byte 74, without its footer \
             (the file was cut short or is damaged)"
        )
    );
    assert_eq!(
        read_all(b[..between].to_vec()).as_deref(),
        Some(
            "it ends early: it stops after byte 74, between two records, without its footer \
             (the file was cut short or is damaged)"
        )
    );
}

//! Bounded reads of the files a program is given (feature `std`): a configuration, a world, a
//! network, a capture. `std::fs::read` of `/dev/zero` (or a FIFO that never ends) grows without
//! bound until the process is killed; these stop at a limit and say so.

use std::io::{self, Read};
use std::path::Path;

/// The limit for text files a person writes (configurations, worlds, networks): 16 MiB.
pub const TEXT_LIMIT: u64 = 16 << 20;

/// The bytes of `path`, or an [`io::ErrorKind::InvalidData`] error if it holds more than
/// `limit` bytes.
///
/// # Errors
/// Opening or reading fails, or the file is larger than `limit`.
pub fn read_limited(path: &Path, limit: u64) -> io::Result<Vec<u8>> {
    let mut out = Vec::new();
    std::fs::File::open(path)?
        .take(limit.saturating_add(1))
        .read_to_end(&mut out)?;
    if out.len() as u64 > limit {
        return Err(io::Error::new(
            io::ErrorKind::InvalidData,
            format!("more than {limit} bytes (a device such as /dev/zero, or the wrong file?)"),
        ));
    }
    Ok(out)
}

/// The text of `path` (at most [`TEXT_LIMIT`] bytes of UTF-8).
///
/// # Errors
/// As [`read_limited`], or the text is not UTF-8.
pub fn read_text(path: &Path) -> io::Result<String> {
    String::from_utf8(read_limited(path, TEXT_LIMIT)?)
        .map_err(|e| io::Error::new(io::ErrorKind::InvalidData, e))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_file_over_the_limit_is_an_error_and_dev_zero_ends() {
        let dir = std::env::temp_dir().join(format!("ima-hal-file-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("a.toml");
        std::fs::write(&p, "x = 1\n").unwrap();
        assert_eq!(read_text(&p).unwrap(), "x = 1\n");
        assert_eq!(read_limited(&p, 6).unwrap().len(), 6);
        let e = read_limited(&p, 5).unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::InvalidData);
        assert!(e.to_string().contains("more than 5 bytes"), "{e}");
        let zero = Path::new("/dev/zero");
        if zero.exists() {
            assert!(read_limited(zero, 1 << 20).is_err());
        }
        std::fs::write(&p, [0xff, 0xfe]).unwrap();
        assert!(read_text(&p).is_err());
        let _ = std::fs::remove_dir_all(&dir);
    }
}

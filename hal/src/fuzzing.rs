//! Replaying committed fuzz corpora in a plain `cargo test` (feature `fuzzing`), so a
//! regression on any saved input shows without nightly or `cargo-fuzz`. Every crate with fuzz
//! targets calls [`replay_corpus`] from its `tests/fuzz_corpus.rs`.

use std::io;
use std::path::Path;

/// Run `harness` on every file of fuzz target `target`'s corpus, `corpora/<target>`
/// (`corpora`: the workspace's `fuzz/corpus`), and with `prefixes` on every prefix of each
/// file too (a truncated input is the commonest damage; this costs time quadratic in the
/// files' lengths, so it suits corpora of short inputs). Returns how many files were
/// replayed. The harness checks each input: it panics on one it finds wrong.
///
/// # Errors
/// The directory is missing or unreadable, holds no file, or a file cannot be read; each
/// error names the path.
pub fn replay_corpus(
    corpora: &str,
    target: &str,
    harness: fn(&[u8]),
    prefixes: bool,
) -> io::Result<usize> {
    let dir = Path::new(corpora).join(target);
    let named =
        |e: io::Error, path: &Path| io::Error::new(e.kind(), format!("{}: {e}", path.display()));
    let mut files = 0;
    for entry in std::fs::read_dir(&dir).map_err(|e| named(e, &dir))? {
        let path = entry.map_err(|e| named(e, &dir))?.path();
        if !path.is_file() {
            continue;
        }
        let data = std::fs::read(&path).map_err(|e| named(e, &path))?;
        harness(&data);
        if prefixes {
            for n in 0..data.len() {
                harness(data.get(..n).unwrap_or_default());
            }
        }
        files += 1;
    }
    if files == 0 {
        return Err(io::Error::new(
            io::ErrorKind::NotFound,
            format!("corpus directory {} holds no file", dir.display()),
        ));
    }
    Ok(files)
}

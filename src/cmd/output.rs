//! Output paths checked before the work: a command that writes a file (or a directory of
//! files) at the end checks first that it will be able to, so a long run is not lost to a
//! typo in a path. Every error names the flag and the path.

use std::fs::OpenOptions;
use std::path::Path;

use anyhow::{Context, Result, bail};

/// Checks that the file `path` of option `flag` can be written: its directory exists and the
/// file can be created (or, when it exists, opened for writing). Leaves nothing behind: a
/// file created for the check is removed again, an existing one is not modified.
///
/// # Errors
/// The directory is missing or not a directory, `path` is a directory, or the file cannot be
/// created or opened for writing.
pub fn check_file(flag: &str, path: &Path) -> Result<()> {
    let shown = path.display();
    if path.as_os_str().is_empty() {
        bail!("{flag}: the path is empty");
    }
    let parent = dir_of(path);
    match parent.metadata() {
        Ok(m) if m.is_dir() => {}
        Ok(_) => bail!("{flag} {shown}: {} is not a directory", parent.display()),
        Err(e) => bail!("{flag} {shown}: directory {}: {e}", parent.display()),
    }
    if path.is_dir() {
        bail!("{flag} {shown}: is a directory, not a file");
    }
    match OpenOptions::new().write(true).create_new(true).open(path) {
        Ok(f) => {
            drop(f);
            std::fs::remove_file(path)
                .with_context(|| format!("{flag} {shown}: removing the test file"))?;
        }
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
            // Exists: writable without truncating it now.
            OpenOptions::new()
                .write(true)
                .open(path)
                .with_context(|| format!("{flag} {shown}: cannot write it"))?;
        }
        Err(e) => bail!("{flag} {shown}: cannot create it: {e}"),
    }
    Ok(())
}

/// The directory a file `path` goes into (`.` for a bare name).
fn dir_of(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

/// Refuses two output options naming one file (`--svg run.mcap --record run.mcap`: the
/// picture written at the end replaced the recording). Paths are compared after resolving
/// their directories, so `x.mcap` and `./x.mcap` are one file.
///
/// # Errors
/// The two name one file.
pub fn distinct_outputs(a: (&str, &Path), b: (&str, &Path)) -> Result<()> {
    let resolved = |p: &Path| {
        std::fs::canonicalize(dir_of(p))
            .ok()
            .zip(p.file_name())
            .map(|(d, f)| d.join(f))
    };
    if let (Some(x), Some(y)) = (resolved(a.1), resolved(b.1))
        && x == y
    {
        bail!(
            "{} and {} name one file, {}: each needs its own",
            a.0,
            b.0,
            a.1.display()
        );
    }
    Ok(())
}

/// Checks that files can be written into the directory `dir` of option `flag`, creating it
/// (and its parents) when missing, as the command would at the end.
///
/// # Errors
/// `dir` cannot be created, is not a directory, or a file cannot be created in it.
pub fn check_dir(flag: &str, dir: &Path) -> Result<()> {
    let shown = dir.display();
    if dir.as_os_str().is_empty() {
        bail!("{flag}: the path is empty");
    }
    if dir.exists() && !dir.is_dir() {
        bail!("{flag} {shown}: not a directory");
    }
    std::fs::create_dir_all(dir).with_context(|| format!("{flag} {shown}: cannot create it"))?;
    // A probe file with a name no output uses.
    let probe = dir.join(format!(".ima-write-check-{}", std::process::id()));
    match OpenOptions::new().write(true).create_new(true).open(&probe) {
        Ok(f) => {
            drop(f);
            std::fs::remove_file(&probe)
                .with_context(|| format!("{flag} {shown}: removing the test file"))?;
            Ok(())
        }
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => Ok(()),
        Err(e) => bail!("{flag} {shown}: cannot write files there: {e}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> std::path::PathBuf {
        let d = std::env::temp_dir().join(format!("ima-output-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn files_in_missing_directories_are_refused_and_checks_leave_nothing() {
        let d = scratch("file");
        let e = check_file("--svg", &d.join("nope/x.svg")).unwrap_err();
        let text = format!("{e:#}");
        assert!(
            text.starts_with("--svg ") && text.contains("nope"),
            "{text}"
        );
        check_file("--svg", &d.join("x.svg")).unwrap();
        assert!(!d.join("x.svg").exists(), "the check left a file");
        std::fs::write(d.join("old.svg"), "keep").unwrap();
        check_file("--svg", &d.join("old.svg")).unwrap();
        assert_eq!(std::fs::read_to_string(d.join("old.svg")).unwrap(), "keep");
        assert!(
            check_file("--svg", &d).is_err(),
            "a directory is not a file"
        );
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn two_options_naming_one_file_are_refused() {
        let d = scratch("same");
        let a = d.join("run.mcap");
        let b = d.join("sub/../run.mcap");
        std::fs::create_dir_all(d.join("sub")).unwrap();
        let e = distinct_outputs(("--svg", &a), ("--record", &b)).unwrap_err();
        assert!(
            format!("{e:#}").starts_with("--svg and --record name one file"),
            "{e:#}"
        );
        distinct_outputs(("--svg", &d.join("run.svg")), ("--record", &a)).unwrap();
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn directories_are_created_and_probed() {
        let d = scratch("dir");
        check_dir("--out", &d.join("a/b")).unwrap();
        assert!(d.join("a/b").is_dir());
        assert_eq!(std::fs::read_dir(d.join("a/b")).unwrap().count(), 0);
        std::fs::write(d.join("f"), "").unwrap();
        let e = check_dir("--out", &d.join("f")).unwrap_err();
        assert!(format!("{e:#}").contains("not a directory"), "{e:#}");
        let _ = std::fs::remove_dir_all(&d);
    }
}

//! Group-key files.
//!
//! A key file holds either **hex** (64 or more hex digits, i.e. at least 32 bytes; spaces,
//! newlines and `#` comment lines are ignored) or **raw** bytes (at least 32 of them). A file
//! that is valid UTF-8 text is read as hex, and malformed hex is an error (never silently
//! taken as raw bytes); only content that is not UTF-8 is taken as raw. Generate one with
//! `head -c 32 /dev/urandom | od -An -tx1 | tr -d ' \n' > group.key && chmod 600 group.key`.
//! A file readable by group or others is refused on Unix (a shared secret should not be
//! world-readable); `chmod 600` it.

use std::path::Path;

use super::NetError;
use crate::peer::wire::GroupKey;

/// Minimum key length accepted from a key file, in bytes.
pub const KEY_FILE_MIN_LEN: usize = 32;

/// The documented **insecure** key used with `--insecure`: 32 zero bytes. Anyone can forge
/// frames under it; it exists so tools run on a bench without a key file.
pub const INSECURE_KEY: [u8; 32] = [0u8; 32];

/// The insecure all-zero key ([`INSECURE_KEY`]).
#[must_use]
pub fn insecure_key() -> GroupKey {
    GroupKey::from_array(INSECURE_KEY)
}

/// Parses the contents of a key file (UTF-8 text: hex; otherwise raw bytes; see the module
/// docs).
///
/// # Errors
/// [`NetError::Key`] when text is not well-formed hex, or fewer than [`KEY_FILE_MIN_LEN`]
/// bytes result.
pub fn parse_key(contents: &[u8]) -> Result<GroupKey, NetError> {
    let bytes = match core::str::from_utf8(contents) {
        Ok(text) => parse_hex(text)?,
        Err(_) => contents.to_vec(),
    };
    if bytes.len() < KEY_FILE_MIN_LEN {
        return Err(NetError::Key(format!(
            "{} bytes of key material, need at least {KEY_FILE_MIN_LEN}",
            bytes.len()
        )));
    }
    GroupKey::new(&bytes).ok_or_else(|| NetError::Key("key too short".into()))
}

fn parse_hex(text: &str) -> Result<Vec<u8>, NetError> {
    let digits: Vec<u8> = text
        .lines()
        .filter(|l| !l.trim_start().starts_with('#'))
        .flat_map(|l| l.bytes())
        .filter(|b| !b.is_ascii_whitespace())
        .collect();
    if let Some(b) = digits.iter().find(|b| !b.is_ascii_hexdigit()) {
        return Err(NetError::Key(format!(
            "the key file is text but not hex (found {:?}); write the key as hex digits",
            char::from(*b)
        )));
    }
    if !digits.len().is_multiple_of(2) {
        return Err(NetError::Key(format!(
            "odd number of hex digits ({})",
            digits.len()
        )));
    }
    digits
        .chunks(2)
        .map(|p| {
            core::str::from_utf8(p)
                .ok()
                .and_then(|s| u8::from_str_radix(s, 16).ok())
                .ok_or_else(|| NetError::Key("bad hex digit".into()))
        })
        .collect()
}

/// The shell command that makes a group key file `file`: 32 random bytes as hex, readable by
/// its owner only from the start (the umask is set before the file exists).
#[must_use]
pub fn make_key_command(file: &str) -> String {
    format!("(umask 077 && head -c 32 /dev/urandom | od -An -v -tx1 | tr -d ' \\n' > {file})")
}

/// Loads the group key from `path`. On Unix a file readable by group or others is refused.
///
/// # Errors
/// [`NetError::Key`] (missing, unreadable, too permissive, too short).
pub fn load_key_file(path: &Path) -> Result<GroupKey, NetError> {
    use std::io::Read;
    if path.as_os_str().is_empty() {
        // It said "group key: : No such file or directory".
        return Err(NetError::Key(
            "the key file's path is empty: give the path of the group's key file".into(),
        ));
    }
    let err = |e: std::io::Error| NetError::Key(format!("{}: {e}", path.display()));
    // The permissions are checked on the opened handle, so the file read is the file
    // checked (no swap between a check by path and the open).
    let file = std::fs::File::open(path).map_err(|e| {
        if e.kind() == std::io::ErrorKind::NotFound {
            // The first thing a new group needs: say how to make one.
            NetError::Key(format!(
                "{}: {e}; make it with `{}` (readable by its owner only, from the start) and \
                 copy it to every robot and the commander",
                path.display(),
                make_key_command("FILE")
            ))
        } else {
            err(e)
        }
    })?;
    let meta = file.metadata().map_err(err)?;
    // A directory (or a device) first: its mode says nothing about a key.
    if !meta.is_file() {
        return Err(NetError::Key(format!(
            "{}: not a regular file",
            path.display()
        )));
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let mode = meta.permissions().mode();
        if mode & 0o077 != 0 {
            return Err(NetError::Key(format!(
                "{}: mode {:o} lets group/others read it; chmod 600 it",
                path.display(),
                mode & 0o777
            )));
        }
    }
    let mut contents = Vec::new();
    // A key file is small: read at most 64 KiB.
    file.take(64 * 1024)
        .read_to_end(&mut contents)
        .map_err(err)?;
    parse_key(&contents)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hex_and_raw_keys() {
        let hex = "# test key\n".to_owned() + &"ab".repeat(32) + "\n";
        assert!(parse_key(hex.as_bytes()).is_ok());
        // Raw bytes only when the content is not UTF-8.
        assert!(parse_key(&[0xffu8; 40]).is_ok());
        assert!(matches!(parse_key(b"abcd"), Err(NetError::Key(_))));
        // Malformed hex text is a hex error, not a raw key.
        let typo = "ab".repeat(31) + "zz";
        match parse_key(typo.as_bytes()) {
            Err(NetError::Key(m)) => assert!(m.contains("hex"), "{m}"),
            other => panic!("{other:?}"),
        }
        let odd = "ab".repeat(32) + "a";
        assert!(matches!(parse_key(odd.as_bytes()), Err(NetError::Key(_))));
        let text = "this is a passphrase of more than thirty-two bytes";
        assert!(matches!(parse_key(text.as_bytes()), Err(NetError::Key(_))));
        assert!(matches!(
            parse_key(&"ab".repeat(8).into_bytes()),
            Err(NetError::Key(_))
        ));
    }

    #[test]
    fn an_empty_path_is_named_as_such() {
        let e = load_key_file(Path::new("")).unwrap_err().to_string();
        assert!(e.contains("the key file's path is empty"), "{e}");
    }

    #[cfg(unix)]
    #[test]
    fn permissive_file_refused() {
        use std::os::unix::fs::PermissionsExt;
        let dir = std::env::temp_dir().join(format!("ima-key-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("k");
        std::fs::write(&p, "cd".repeat(32)).unwrap();
        std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o644)).unwrap();
        assert!(load_key_file(&p).is_err());
        std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o600)).unwrap();
        assert!(load_key_file(&p).is_ok());
        // A missing file's error says how to make one, and that command makes a good key.
        let missing = dir.join("missing");
        let e = load_key_file(&missing).unwrap_err().to_string();
        let make = e.split('`').nth(1).unwrap_or_else(|| panic!("{e}"));
        let make = make.replace("FILE", &format!("'{}'", missing.display()));
        let make = make.as_str();
        assert!(e.contains("No such file"), "{e}");
        let made = std::process::Command::new("sh")
            .args(["-c", make])
            .status()
            .unwrap();
        assert!(made.success(), "{make}");
        assert!(load_key_file(&missing).is_ok(), "{make}");
        // A directory was reported as a mode problem ("mode 777 lets group/others read it").
        std::fs::set_permissions(&dir, std::fs::Permissions::from_mode(0o777)).unwrap();
        let e = load_key_file(&dir).unwrap_err().to_string();
        assert!(e.contains("not a regular file"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

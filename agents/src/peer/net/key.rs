//! Group-key files.
//!
//! A key file holds either **hex** (64 or more hex digits, i.e. at least 32 bytes; spaces,
//! newlines and `#` comment lines are ignored) or **raw** bytes (at least 32 of them; a file
//! that is not valid hex is taken as raw). Generate one with
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

/// Parses the contents of a key file (hex, else raw bytes; see the module docs).
///
/// # Errors
/// [`NetError::Key`] when fewer than [`KEY_FILE_MIN_LEN`] bytes result.
pub fn parse_key(contents: &[u8]) -> Result<GroupKey, NetError> {
    let bytes = parse_hex(contents).unwrap_or_else(|| contents.to_vec());
    if bytes.len() < KEY_FILE_MIN_LEN {
        return Err(NetError::Key(format!(
            "{} bytes of key material, need at least {KEY_FILE_MIN_LEN}",
            bytes.len()
        )));
    }
    GroupKey::new(&bytes).ok_or_else(|| NetError::Key("key too short".into()))
}

fn parse_hex(contents: &[u8]) -> Option<Vec<u8>> {
    let text = core::str::from_utf8(contents).ok()?;
    let digits: Vec<u8> = text
        .lines()
        .filter(|l| !l.trim_start().starts_with('#'))
        .flat_map(|l| l.bytes())
        .filter(|b| !b.is_ascii_whitespace())
        .collect();
    if digits.is_empty() || !digits.len().is_multiple_of(2) {
        return None;
    }
    digits
        .chunks(2)
        .map(|p| {
            let s = core::str::from_utf8(p).ok()?;
            u8::from_str_radix(s, 16).ok()
        })
        .collect()
}

/// Loads the group key from `path`. On Unix a file readable by group or others is refused.
///
/// # Errors
/// [`NetError::Key`] (missing, unreadable, too permissive, too short).
pub fn load_key_file(path: &Path) -> Result<GroupKey, NetError> {
    let meta =
        std::fs::metadata(path).map_err(|e| NetError::Key(format!("{}: {e}", path.display())))?;
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
    #[cfg(not(unix))]
    let _ = meta;
    let contents =
        std::fs::read(path).map_err(|e| NetError::Key(format!("{}: {e}", path.display())))?;
    parse_key(&contents)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hex_and_raw_keys() {
        let hex = "# test key\n".to_owned() + &"ab".repeat(32) + "\n";
        assert!(parse_key(hex.as_bytes()).is_ok());
        assert!(parse_key(&[7u8; 40]).is_ok());
        assert!(matches!(parse_key(b"abcd"), Err(NetError::Key(_))));
        assert!(matches!(
            parse_key(&"ab".repeat(8).into_bytes()),
            Err(NetError::Key(_))
        ));
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
        assert!(load_key_file(&dir.join("missing")).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

//! Serial-port helpers shared by the drivers' `open_port` functions (feature `std`).

use std::io;

/// Turn the error of opening `path` as a serial port into one that names the problem when
/// the path is not a serial port at all: a regular file, a directory, or a device that is no
/// terminal (`/dev/null`) fails the terminal set-up with the cryptic `ENOTTY` ("Not a
/// typewriter"); this says `PATH is not a serial port (a regular file)` instead. A port another
/// program holds (`EBUSY`, or the serial crate's exclusive lock refused) says so, and how to
/// find that program. Other errors (no such file, permission denied) are returned unchanged.
#[must_use]
pub fn explain_open_error(path: &str, err: io::Error) -> io::Error {
    let what = match std::fs::metadata(path) {
        Ok(m) if m.is_file() => Some("a regular file"),
        Ok(m) if m.is_dir() => Some("a directory"),
        Ok(_) if is_not_a_tty(&err) => Some("a device that is not a terminal"),
        _ => None,
    };
    match what {
        Some(what) => io::Error::new(
            io::ErrorKind::InvalidInput,
            format!("{path} is not a serial port ({what})"),
        ),
        None if is_busy(&err) => io::Error::new(
            io::ErrorKind::ResourceBusy,
            format!(
                "{path} is in use by another program (a port is opened by one program at a \
                 time; `fuser {path}` names it): {err}"
            ),
        ),
        None => err,
    }
}

/// `EBUSY`, or the serial crate's "exclusive lock" refusal: another program holds the port
/// (it took the exclusive lock, or this one could not take it). The serial crate reports
/// `EBUSY` from `open` by its text alone ("Device or resource busy", the errno dropped).
fn is_busy(err: &io::Error) -> bool {
    const EBUSY: i32 = 16; // Linux, macOS and the BSDs
    let msg = err.to_string();
    err.raw_os_error() == Some(EBUSY)
        || msg.contains("exclusive lock")
        || msg.contains("Device or resource busy")
}

/// `ENOTTY`, however the serial crate reported it.
fn is_not_a_tty(err: &io::Error) -> bool {
    const ENOTTY: i32 = 25; // Linux, macOS and the BSDs
    if err.raw_os_error() == Some(ENOTTY) {
        return true;
    }
    let msg = err.to_string();
    msg.contains("Not a typewriter") || msg.contains("Inappropriate ioctl")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A second program on a port (`ima scan` while another runs) was told only "Unable to
    /// acquire exclusive lock on serial port".
    #[test]
    fn a_port_another_program_holds_is_named_busy() {
        let locked = io::Error::other("Unable to acquire exclusive lock on serial port");
        let e = explain_open_error("/dev/ttyUSB0", locked);
        assert_eq!(e.kind(), io::ErrorKind::ResourceBusy);
        assert_eq!(
            e.to_string(),
            "/dev/ttyUSB0 is in use by another program (a port is opened by one program at a \
             time; `fuser /dev/ttyUSB0` names it): Unable to acquire exclusive lock on serial port"
        );
        // As the serial crate reports EBUSY from `open`: its text, no errno.
        let held = io::Error::new(io::ErrorKind::NotFound, "Device or resource busy");
        let busy = explain_open_error("/dev/ttyUSB0", held);
        assert_eq!(busy.kind(), io::ErrorKind::ResourceBusy);
        assert!(
            busy.to_string().contains("is in use by another program"),
            "{busy}"
        );
        let busy = explain_open_error("/dev/ttyUSB0", io::Error::from_raw_os_error(16));
        assert!(
            busy.to_string().contains("is in use by another program"),
            "{busy}"
        );
        let absent = explain_open_error("/dev/ttyUSB9", io::Error::from_raw_os_error(2));
        assert!(!absent.to_string().contains("in use"), "{absent}");
    }

    #[test]
    fn files_and_non_terminals_are_named() {
        let file = std::env::temp_dir().join(format!("ima-hal-serial-{}", std::process::id()));
        std::fs::write(&file, b"x").unwrap();
        let p = file.to_string_lossy().into_owned();
        let e = explain_open_error(&p, io::Error::other("Not a typewriter"));
        let _ = std::fs::remove_file(&file);
        assert_eq!(
            e.to_string(),
            format!("{p} is not a serial port (a regular file)")
        );
        assert_eq!(e.kind(), io::ErrorKind::InvalidInput);
        #[cfg(unix)]
        {
            let e = explain_open_error("/dev/null", io::Error::other("Not a typewriter"));
            assert_eq!(
                e.to_string(),
                "/dev/null is not a serial port (a device that is not a terminal)"
            );
            // A real failure on a device is kept.
            let e = explain_open_error(
                "/dev/null",
                io::Error::new(io::ErrorKind::PermissionDenied, "Permission denied"),
            );
            assert_eq!(e.kind(), io::ErrorKind::PermissionDenied);
        }
        let e = explain_open_error(
            "/no/such/port",
            io::Error::new(io::ErrorKind::NotFound, "No such file or directory"),
        );
        assert_eq!(e.kind(), io::ErrorKind::NotFound);
    }
}

//! Serial-port helpers shared by the drivers' `open_port` functions (feature `std`).

use std::io;
use std::path::Path;

/// Turn the error of opening `path` as a serial port into one that names the problem when
/// the path is not a serial port at all: a regular file, a directory, or a device that is no
/// terminal (`/dev/null`) fails the terminal set-up with the cryptic `ENOTTY` ("Not a
/// typewriter"); this says `PATH is not a serial port (a regular file)` instead. A port another
/// program holds (`EBUSY`, or the serial crate's exclusive lock refused) says so, and how to
/// find that program. A port that is not there lists the serial ports that are (a USB adapter
/// takes the next free number after a replug); a port the user may not open names the group
/// that may and how to join it. Other errors are returned unchanged.
#[must_use]
pub fn explain_open_error(path: &str, err: io::Error) -> io::Error {
    let meta = std::fs::metadata(path).ok();
    let what = match &meta {
        Some(m) if m.is_file() => Some("a regular file"),
        Some(m) if m.is_dir() => Some("a directory"),
        Some(_) if is_not_a_tty(&err) => Some("a device that is not a terminal"),
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
        None if err.kind() == io::ErrorKind::NotFound && meta.is_none() => io::Error::new(
            io::ErrorKind::NotFound,
            format!("no such port ({err}); {}", ports_here(Path::new("/dev"))),
        ),
        None if err.kind() == io::ErrorKind::PermissionDenied => io::Error::new(
            io::ErrorKind::PermissionDenied,
            format!("permission denied; {}", who_may_open(meta.as_ref())),
        ),
        None => err,
    }
}

/// The serial ports under `dev` (a `/dev`), as a sentence: the stable names under
/// `serial/by-id/` (with the port each names), then `ttyUSB*` and `ttyACM*`. The built-in
/// `ttyS*` are left out: Linux lists 32 of them whether or not a UART is behind them.
/// (`serialport::available_ports` is not used: without libudev it panics where
/// `/sys/class/tty` is missing, and it knows no by-id names.)
fn ports_here(dev: &Path) -> String {
    let names = |dir: &Path, prefixes: &[&str]| -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(dir)
            .into_iter()
            .flatten()
            .flatten()
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .filter(|n| prefixes.is_empty() || prefixes.iter().any(|p| n.starts_with(p)))
            .filter(|n| dir.join(n).exists()) // not a dangling by-id link
            .collect();
        // `ttyUSB2` before `ttyUSB10`: by the name without its trailing number, then by it.
        v.sort_by_key(|n| {
            let stem = n.trim_end_matches(|c: char| c.is_ascii_digit());
            let number: u64 = n.get(stem.len()..).unwrap_or("").parse().unwrap_or(0);
            (stem.to_owned(), number, n.clone())
        });
        v
    };
    let by_id_dir = dev.join("serial").join("by-id");
    let mut ports: Vec<String> = names(&by_id_dir, &[])
        .into_iter()
        .map(|n| {
            let link = by_id_dir.join(&n);
            match std::fs::read_link(&link) {
                Ok(to) => {
                    let to = to
                        .file_name()
                        .map_or_else(String::new, |t| dev.join(t).to_string_lossy().into_owned());
                    format!("{} (-> {to})", link.display())
                }
                Err(_) => link.display().to_string(),
            }
        })
        .collect();
    let by_id = ports.len();
    ports.extend(
        names(dev, &["ttyUSB", "ttyACM"])
            .into_iter()
            .map(|n| dev.join(n).to_string_lossy().into_owned()),
    );
    if ports.is_empty() {
        return format!(
            "no USB serial port is present ({0}/ttyUSB*, {0}/ttyACM* and {0}/serial/by-id/ are \
             empty): is the adapter plugged in?",
            dev.display()
        );
    }
    let hint = if by_id > 0 {
        "; a by-id name stays the same across replugs"
    } else {
        ""
    };
    format!("serial ports here: {}{hint}", ports.join(", "))
}

/// Who may open the port of `meta`: its group, and how to join it (on Debian and Ubuntu
/// serial ports belong to `dialout`).
#[cfg(unix)]
fn who_may_open(meta: Option<&std::fs::Metadata>) -> String {
    use std::os::unix::fs::MetadataExt;
    let Some(meta) = meta else {
        return "this user may not open it".into();
    };
    let gid = meta.gid();
    let group = std::fs::read_to_string("/etc/group")
        .ok()
        .and_then(|g| group_name(&g, gid));
    access_advice(gid, meta.mode(), group.as_deref())
}

#[cfg(not(unix))]
fn who_may_open(_meta: Option<&std::fs::Metadata>) -> String {
    "this user may not open it".into()
}

/// What to do about a port of group `gid` (named `group`) and permission bits `mode`: join
/// the group when it may read and write the port (and is not root's), else ask for a udev
/// rule, since joining would not help.
#[cfg_attr(not(unix), allow(dead_code))]
fn access_advice(gid: u32, mode: u32, group: Option<&str>) -> String {
    let perm = mode & 0o777;
    let group_rw = mode & 0o060 == 0o060;
    match group {
        Some(g) if group_rw && gid != 0 => format!(
            "it belongs to group `{g}`: add this user (`sudo usermod -aG {g} $USER`), then log \
             in again"
        ),
        None if group_rw && gid != 0 => {
            format!("it belongs to group {gid}: add this user to that group, then log in again")
        }
        _ => format!(
            "only its owner may open it (mode {perm:03o}); a udev rule can give it to a group \
             such as `dialout` (GROUP=\"dialout\", MODE=\"0660\")"
        ),
    }
}

/// The name of group `gid` in an `/etc/group` text.
#[cfg_attr(not(unix), allow(dead_code))]
fn group_name(etc_group: &str, gid: u32) -> Option<String> {
    etc_group.lines().find_map(|line| {
        let mut f = line.split(':');
        let name = f.next()?;
        let id: u32 = f.nth(1)?.parse().ok()?;
        (id == gid && !name.is_empty()).then(|| name.to_owned())
    })
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

    /// `ima drive --port /dev/ttyUSB0` with the adapter on ttyUSB1 said only "No such file or
    /// directory"; it now lists the ports that are there.
    #[test]
    fn a_missing_port_lists_the_ports_that_are_there() {
        let dev = std::env::temp_dir().join(format!("ima-hal-dev-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dev);
        std::fs::create_dir_all(&dev).unwrap();
        let d = dev.display().to_string();
        assert_eq!(
            ports_here(&dev),
            format!(
                "no USB serial port is present ({d}/ttyUSB*, {d}/ttyACM* and {d}/serial/by-id/ \
                 are empty): is the adapter plugged in?"
            )
        );
        for n in [
            "ttyUSB10", "ttyUSB1", "ttyUSB2", "ttyACM0", "ttyS0", "tty0", "null",
        ] {
            std::fs::write(dev.join(n), b"").unwrap();
        }
        assert_eq!(
            ports_here(&dev),
            format!("serial ports here: {d}/ttyACM0, {d}/ttyUSB1, {d}/ttyUSB2, {d}/ttyUSB10")
        );
        for n in ["ttyUSB10", "ttyUSB2"] {
            std::fs::remove_file(dev.join(n)).unwrap();
        }
        #[cfg(unix)]
        {
            let by_id = dev.join("serial/by-id");
            std::fs::create_dir_all(&by_id).unwrap();
            std::os::unix::fs::symlink("../../ttyUSB1", by_id.join("usb-FTDI_FT232R-if00-port0"))
                .unwrap();
            // A link to a port that is gone (unplugged) is not listed.
            std::os::unix::fs::symlink("../../ttyUSB7", by_id.join("usb-Prolific-if00-port0"))
                .unwrap();
            assert_eq!(
                ports_here(&dev),
                format!(
                    "serial ports here: {d}/serial/by-id/usb-FTDI_FT232R-if00-port0 (-> \
                     {d}/ttyUSB1), {d}/ttyACM0, {d}/ttyUSB1; a by-id name stays the same across \
                     replugs"
                )
            );
        }
        let _ = std::fs::remove_dir_all(&dev);
        let e = explain_open_error("/dev/ttyUSB97", io::Error::from_raw_os_error(2));
        assert_eq!(e.kind(), io::ErrorKind::NotFound);
        assert!(e.to_string().starts_with("no such port ("), "{e}");
    }

    /// A user outside the port's group was told only "Permission denied"; the advice fits
    /// the port's mode (joining a group that may not read the port would not help).
    #[test]
    fn a_port_the_user_may_not_open_names_its_group() {
        let etc_group = "root:x:0:\ndialout:x:20:pi\nbroken line\nplugdev:x:46:\n";
        assert_eq!(group_name(etc_group, 20).as_deref(), Some("dialout"));
        assert_eq!(group_name(etc_group, 46).as_deref(), Some("plugdev"));
        assert_eq!(group_name(etc_group, 7), None);
        let udev = "a udev rule can give it to a group such as `dialout` (GROUP=\"dialout\", \
                    MODE=\"0660\")";
        // A USB adapter on Debian: crw-rw---- root dialout.
        assert_eq!(
            access_advice(20, 0o20660, Some("dialout")),
            "it belongs to group `dialout`: add this user (`sudo usermod -aG dialout $USER`), \
             then log in again"
        );
        assert_eq!(
            access_advice(1234, 0o20660, None),
            "it belongs to group 1234: add this user to that group, then log in again"
        );
        // A pty: crw--w---- root tty; the group may not read it.
        assert_eq!(
            access_advice(5, 0o20620, Some("tty")),
            format!("only its owner may open it (mode 620); {udev}")
        );
        // Root's group, even with rw: never "join root".
        assert_eq!(
            access_advice(0, 0o20660, Some("root")),
            format!("only its owner may open it (mode 660); {udev}")
        );
        let denied = io::Error::new(io::ErrorKind::PermissionDenied, "Permission denied");
        let e = explain_open_error("/dev/null", denied);
        assert_eq!(e.kind(), io::ErrorKind::PermissionDenied);
        assert!(e.to_string().starts_with("permission denied; "), "{e}");
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

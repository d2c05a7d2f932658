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

/// The most characters of a line [`located`] shows.
const EXCERPT_CHARS: usize = 100;
/// The most characters of a message [`located`] shows.
const MESSAGE_CHARS: usize = 400;

/// A parser's error in `text` said the way `toml` says it (the line and column, the line with
/// the span marked, then `message`), but bounded: a line or a message (which may quote a
/// value) longer than a screen is cut around the span with `…`. A one-line file of 10 MB had
/// its whole line echoed to stderr. `span` is a byte range of `text`; without one, only the
/// (bounded) message.
#[must_use]
pub fn located(text: &str, span: Option<core::ops::Range<usize>>, message: &str) -> String {
    let message = plain_types(&clip(message, 0, MESSAGE_CHARS).0);
    let Some(span) = span.filter(|s| s.start <= text.len()) else {
        return message;
    };
    let start = floor_boundary(text, span.start);
    let line_start = text
        .get(..start)
        .and_then(|t| t.rfind('\n'))
        .map_or(0, |i| i + 1);
    let line_end = text
        .get(start..)
        .and_then(|t| t.find('\n'))
        .map_or(text.len(), |i| start + i);
    let line = text
        .get(line_start..line_end)
        .unwrap_or("")
        .trim_end_matches('\r');
    let number = text
        .get(..line_start)
        .map_or(0, |t| t.matches('\n').count())
        + 1;
    let column = text.get(line_start..start).map_or(0, |t| t.chars().count());
    let marked = text
        .get(start..floor_boundary(text, span.end.min(line_end)))
        .map_or(0, |t| t.chars().count())
        .max(1);
    // A window of the line around the column.
    let from = column.saturating_sub(EXCERPT_CHARS / 2);
    let (shown, cut_front) = clip(line, from, EXCERPT_CHARS);
    let caret_at = column - from + usize::from(cut_front);
    let room = EXCERPT_CHARS.saturating_sub(column - from).max(1);
    let gutter = " ".repeat(number.to_string().len());
    format!(
        "TOML parse error at line {number}, column {}\n{gutter} |\n{number} | {shown}\n{gutter} | {}{}\n{message}",
        column + 1,
        " ".repeat(caret_at),
        "^".repeat(marked.min(room)),
    )
}

/// `message` with serde's Rust type names said in words: "invalid value: integer `300`,
/// expected u8" reads "…, expected a whole number from 0 to 255". A person writing a
/// configuration need not know what a `u8` is.
fn plain_types(message: &str) -> String {
    const WORDS: [(&str, &str); 12] = [
        ("u8", "a whole number from 0 to 255"),
        ("u16", "a whole number from 0 to 65535"),
        ("u32", "a whole number from 0 to 4294967295"),
        ("u64", "a whole number, 0 or more"),
        ("usize", "a whole number, 0 or more"),
        ("i8", "a whole number from -128 to 127"),
        ("i16", "a whole number from -32768 to 32767"),
        ("i32", "a whole number from -2147483648 to 2147483647"),
        ("i64", "a whole number"),
        ("isize", "a whole number"),
        ("f32", "a number"),
        ("f64", "a number"),
    ];
    let mut out = String::with_capacity(message.len());
    let mut rest = message;
    while let Some(at) = rest.find("expected ") {
        let (head, tail) = rest.split_at(at + "expected ".len());
        out.push_str(head);
        let name_len = tail
            .find(|c: char| !c.is_ascii_alphanumeric())
            .unwrap_or(tail.len());
        let (name, after) = tail.split_at(name_len);
        match WORDS.iter().find(|(rust, _)| *rust == name) {
            Some((_, words)) => out.push_str(words),
            None => out.push_str(name),
        }
        rest = after;
    }
    out.push_str(rest);
    out
}

/// `s` from character `from`, at most `max` characters of it, with `…` where it was cut; and
/// whether the front was cut.
fn clip(s: &str, from: usize, max: usize) -> (String, bool) {
    let total = s.chars().count();
    let mut out = String::new();
    let cut_front = from > 0;
    if cut_front {
        out.push('…');
    }
    out.extend(s.chars().skip(from).take(max));
    if from.saturating_add(max) < total {
        out.push('…');
    }
    (out, cut_front)
}

/// The largest char boundary of `s` at or below `i`.
fn floor_boundary(s: &str, i: usize) -> usize {
    let mut i = i.min(s.len());
    while !s.is_char_boundary(i) {
        i -= 1;
    }
    i
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn located_errors_show_the_line_and_stay_short() {
        let text = "a = 1\nheartbeat_ms = \"x\"\n";
        let at = text.find("\"x").unwrap();
        assert_eq!(
            located(text, Some(at..at + 3), "invalid type"),
            "TOML parse error at line 2, column 16\n  |\n2 | heartbeat_ms = \"x\"\n  |                ^^^\ninvalid type"
        );
        // A 10 MB line and a message quoting it: a few hundred characters, the span marked.
        let long = format!("k = \"{}\" oops", "é".repeat(5_000_000));
        let at = long.find("oops").unwrap();
        let msg = format!("invalid value {long}");
        let e = located(&long, Some(at..at + 4), &msg);
        assert!(e.len() < 2_000, "{} bytes", e.len());
        assert!(
            e.starts_with("TOML parse error at line 1, column 5000008\n"),
            "{e}"
        );
        assert!(e.contains("…éééé"), "{e}");
        let lines: Vec<&str> = e.lines().collect();
        let caret = lines[3].find('^').unwrap();
        let oops = lines[2].find("oops").unwrap();
        assert_eq!(
            lines[2][..oops].chars().count(),
            lines[3][..caret].chars().count()
        );
        // No span, or one past the end: the message alone; spans inside a character do not panic.
        assert_eq!(located("x", None, "bad"), "bad");
        assert_eq!(located("x", Some(9..10), "bad"), "bad");
        let _ = located("é", Some(1..2), "bad");
        let _ = located("a\n", Some(2..2), "bad");
    }

    #[test]
    fn serde_type_names_are_said_in_words() {
        let text = "task_priority = 300\n";
        let e = located(
            text,
            Some(16..19),
            "invalid value: integer `300`, expected u8",
        );
        assert!(
            e.ends_with("invalid value: integer `300`, expected a whole number from 0 to 255"),
            "{e}"
        );
        assert_eq!(
            plain_types("invalid type: string \"x\", expected f64; expected u16s, expected u64"),
            "invalid type: string \"x\", expected a number; expected u16s, \
             expected a whole number, 0 or more"
        );
        for kept in [
            "expected a boolean",
            "expected `,`",
            "expected ",
            "",
            "u8 expected",
        ] {
            assert_eq!(plain_types(kept), kept);
        }
    }

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

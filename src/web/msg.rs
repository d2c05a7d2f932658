//! The messages between the page and the server: commands the page posts
//! (`POST /api/command`, one JSON object) and the replies it gets. The live feed is the
//! state snapshot ([`super::state::ConsoleState::snapshot`]) as server-sent events.

use serde::{Deserialize, Serialize};

use ima_agents::mission::commander::MAX_SERIES;
use ima_agents::runtime::commander::Operator;

/// A command from the page.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize, Serialize)]
#[serde(tag = "cmd", rename_all = "lowercase", deny_unknown_fields)]
pub enum Command {
    /// Append a target to the queue.
    Add {
        /// Colour.
        target: String,
    },
    /// Withdraw a target (the first open one of that colour).
    Cancel {
        /// Colour.
        target: String,
    },
    /// Move the waiting target at `from` to `to` (positions in the queue, from 0).
    Move {
        /// Position now.
        from: usize,
        /// Position wanted.
        to: usize,
    },
    /// Fleet stop.
    Stop {
        /// Why (shown by the robots); `operator` when absent.
        #[serde(default)]
        reason: Option<String>,
    },
    /// Fleet resume.
    Resume,
}

/// The server's answer to a command.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Reply {
    /// Whether the command went to the commander.
    pub ok: bool,
    /// What happened, or what is wrong, in words for the operator.
    pub message: String,
}

impl Reply {
    /// A command carried out.
    pub fn ok(message: impl Into<String>) -> Self {
        Self {
            ok: true,
            message: message.into(),
        }
    }

    /// A command refused.
    pub fn refused(message: impl Into<String>) -> Self {
        Self {
            ok: false,
            message: message.into(),
        }
    }
}

/// A command's body parsed, with a message naming the problem when it is not one.
pub fn parse_command(body: &[u8]) -> Result<Command, String> {
    if body.iter().all(u8::is_ascii_whitespace) {
        return Err("empty command: send a JSON object such as {\"cmd\":\"stop\"}".to_owned());
    }
    serde_json::from_slice(body).map_err(|e| {
        format!(
            "not a command ({e}); commands are add/cancel {{target}}, move {{from, to}}, \
             stop {{reason?}}, resume"
        )
    })
}

/// Longest colour or reason accepted (the wire carries short strings).
pub const MAX_TEXT: usize = 64;

/// `c` (blanks around it ignored) checked as a target colour the robots can find
/// (`colours`), or what is wrong with it.
pub fn colour(c: &str, colours: &[String]) -> Result<String, String> {
    let c = c.trim();
    if c.is_empty() {
        return Err("no colour given: pick one of the list".to_owned());
    }
    if c.len() > MAX_TEXT || c.chars().any(char::is_whitespace) {
        return Err(format!(
            "{:?} is not a colour (one word, at most {MAX_TEXT} bytes)",
            c.chars().take(MAX_TEXT).collect::<String>()
        ));
    }
    if !colours.iter().any(|k| k == c) {
        return Err(format!(
            "unknown colour {c:?}: the robots know {}",
            colours.join(", ")
        ));
    }
    Ok(c.to_owned())
}

/// Checks a command against what the console knows (`colours`: colours the robots can find;
/// `open`: whether an open target of a colour is queued; `queue_len`) and turns it into the
/// commander's request, or says what is wrong.
pub fn to_operator(
    cmd: &Command,
    colours: &[String],
    queue_len: usize,
    open: impl Fn(&str) -> bool,
) -> Result<Operator, String> {
    let colour = |c: &str| colour(c, colours);
    match cmd {
        Command::Add { target } => {
            let c = colour(target)?;
            if queue_len >= MAX_SERIES {
                return Err(format!(
                    "the queue is full ({MAX_SERIES} targets, the most one commander keeps): \
                     {c} not added"
                ));
            }
            Ok(Operator::Add(c))
        }
        Command::Cancel { target } => {
            let c = colour(target)?;
            if queue_len == 0 {
                return Err("the queue is empty: nothing to cancel".to_owned());
            }
            if !open(&c) {
                return Err(format!(
                    "no open target {c:?} to cancel (done, failed or not queued)"
                ));
            }
            Ok(Operator::Cancel(c))
        }
        Command::Move { from, to } => {
            if queue_len == 0 {
                return Err("the queue is empty: nothing to move".to_owned());
            }
            if *from >= queue_len || *to >= queue_len {
                return Err(format!(
                    "no target at position {} (the queue has {queue_len})",
                    (*from).max(*to).saturating_add(1)
                ));
            }
            Ok(Operator::Move {
                from: *from,
                to: *to,
            })
        }
        Command::Stop { reason } => {
            let r = reason.as_deref().map(str::trim).unwrap_or("");
            let r = if r.is_empty() { "operator" } else { r };
            if r.len() > MAX_TEXT {
                return Err(format!("the reason is longer than {MAX_TEXT} bytes"));
            }
            Ok(Operator::Stop(r.to_owned()))
        }
        Command::Resume => Ok(Operator::Resume),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn colours() -> Vec<String> {
        ["red", "blue", "green"].map(String::from).to_vec()
    }

    #[test]
    fn commands_parse_from_the_pages_json() {
        assert_eq!(
            parse_command(br#"{"cmd":"add","target":"red"}"#),
            Ok(Command::Add {
                target: "red".into()
            })
        );
        assert_eq!(
            parse_command(br#"{"cmd":"move","from":2,"to":1}"#),
            Ok(Command::Move { from: 2, to: 1 })
        );
        assert_eq!(
            parse_command(br#"{"cmd":"stop"}"#),
            Ok(Command::Stop { reason: None })
        );
        assert_eq!(parse_command(br#"{"cmd":"resume"}"#), Ok(Command::Resume));
        // And back: the page's shape.
        let v = serde_json::to_value(Command::Cancel {
            target: "blue".into(),
        })
        .unwrap();
        assert_eq!(v, serde_json::json!({"cmd": "cancel", "target": "blue"}));
    }

    #[test]
    fn bad_bodies_get_a_message_not_a_panic() {
        for bad in [
            &b""[..],
            b"  ",
            b"{",
            b"[]",
            b"{\"cmd\":\"fly\"}",
            b"{\"cmd\":\"add\"}",
            b"{\"cmd\":\"move\",\"from\":-1,\"to\":0}",
            b"{\"cmd\":\"stop\",\"extra\":1}",
            b"\xff\xfe",
        ] {
            let e = parse_command(bad).unwrap_err();
            assert!(e.contains("command"), "{e}");
        }
    }

    #[test]
    fn commands_are_checked_before_they_reach_the_commander() {
        let open = |c: &str| c == "blue";
        let op = |c: Command| to_operator(&c, &colours(), 3, open);
        assert_eq!(
            op(Command::Add {
                target: " red ".into()
            }),
            Ok(Operator::Add("red".into()))
        );
        let e = op(Command::Add {
            target: "purple".into(),
        })
        .unwrap_err();
        assert!(e.contains("unknown colour \"purple\"") && e.contains("red, blue, green"));
        assert!(
            op(Command::Add { target: "".into() })
                .unwrap_err()
                .contains("no colour")
        );
        assert!(
            op(Command::Add {
                target: "dark red".into()
            })
            .unwrap_err()
            .contains("not a colour")
        );
        assert_eq!(
            op(Command::Cancel {
                target: "blue".into()
            }),
            Ok(Operator::Cancel("blue".into()))
        );
        assert!(
            op(Command::Cancel {
                target: "red".into()
            })
            .unwrap_err()
            .contains("no open target")
        );
        assert!(
            to_operator(
                &Command::Cancel {
                    target: "red".into()
                },
                &colours(),
                0,
                open
            )
            .unwrap_err()
            .contains("queue is empty")
        );
        assert!(
            op(Command::Move { from: 0, to: 7 })
                .unwrap_err()
                .contains("position 8 (the queue has 3)")
        );
        // The page's numbers are any JSON number a usize holds: no overflow (a panic in a
        // debug build, "position 0" in a release one).
        let e = op(Command::Move {
            from: usize::MAX,
            to: 0,
        })
        .unwrap_err();
        assert!(e.contains(&format!("position {}", usize::MAX)), "{e}");
        let full = to_operator(
            &Command::Add {
                target: "red".into(),
            },
            &colours(),
            MAX_SERIES,
            open,
        );
        assert!(full.unwrap_err().contains("queue is full (256 targets"));
        assert_eq!(
            op(Command::Stop { reason: None }),
            Ok(Operator::Stop("operator".into()))
        );
        assert!(
            op(Command::Stop {
                reason: Some("x".repeat(100))
            })
            .is_err()
        );
    }
}

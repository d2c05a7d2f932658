//! The mission's inter-robot vocabulary (PHASE 3 architecture, "Inter-robot traffic").
//!
//! Two channels carry the mission:
//!
//! * **Skeeter → Scooter SES**: Skeeter's Sensory EgoSphere in the
//!   [shared form](crate::ses::shared::SharedForm), published as a Peer Agent *source*
//!   named [`SES_SOURCE`] of kind [`SES_SOURCE_KIND`] (schema [`SES_SOURCE_SCHEMA`]) on
//!   Skeeter's manager, one sample per full scan. Records: object = a colour name or
//!   [`SCOOTER_TAG`], bearing in Skeeter's frame (the common frame: Skeeter does not move
//!   and its initial heading is the robots' common initial heading), optional range in
//!   metres, confidence, time.
//! * **Broadcast channel** ([PEER.md](crate::peer)): everything else, typed here as
//!   [`Broadcast`]:
//!
//! | [`Broadcast`] | wire [`Msg`] | kind / text |
//! |---|---|---|
//! | [`Broadcast::Status`] | [`Msg::Status`] | behaviour = running SAN module |
//! | [`Emergency::ScooterLost`] | [`Msg::Emergency`] | `scooter-lost` (Skeeter's stress call) |
//! | [`Emergency::ScooterFound`] | [`Msg::Emergency`] | `scooter-found` (Skeeter sees it again) |
//! | [`Emergency::TargetQuery`] | [`Msg::Emergency`] | `target-query`, text = colour |
//! | [`Emergency::TargetReply`] | [`Msg::Emergency`] | `target-reply`, text = `"<colour> yes"` / `"<colour> no"` |
//! | [`Emergency::TargetReached`] | [`Msg::Emergency`] | `target-reached`, text = colour |
//! | [`Emergency::FleetStop`] | [`Msg::Emergency`] | `fleet-stop`, text = `v1` and a free reason (every robot stops at once and holds) |
//! | [`Emergency::FleetResume`] | [`Msg::Emergency`] | `fleet-resume`, text = `v1` (the robots may move again) |
//! | [`Emergency::TargetCancel`] | [`Msg::Emergency`] | `target-cancel`, text = colour (the commander withdraws a target) |
//! | [`Broadcast::Mission`] | [`Msg::Mission`] | event Accepted / Accomplished / Failed, target colour |
//!
//! The fleet commands travel as emergencies so that the wire format does not change: a
//! robot built before them decodes them as an unknown emergency kind (a typed
//! [`MsgError::UnknownKind`], ignored), and every earlier message decodes as before. The
//! text of `fleet-stop` and `fleet-resume` starts with a version word (`v1`); a text
//! without one is taken as version 1 too.
//!
//! The commander sends a new target as `Mission { robot: "commander", Accepted, colour }`;
//! Skeeter answers with its own `Accepted`, later `Accomplished` or `Failed`.
//!
//! Conversion from the wire never panics: a message that is not a broadcast, an unknown
//! emergency kind or a malformed text is a typed [`MsgError`]. Per-sender sequence numbers
//! belong to the broadcast channel ([`crate::peer::broadcast`]), not to this vocabulary:
//! [`Broadcast::to_wire`] takes the number to stamp, [`Broadcast::from_wire`] drops it.

use core::fmt;

pub use crate::peer::wire::{MissionEvent, Msg, Pose};

/// Skeeter's robot name on the broadcast channel and in SES shared forms.
pub const SKEETER: &str = "skeeter";
/// Scooter's robot name on the broadcast channel.
pub const SCOOTER: &str = "scooter";
/// The commander's name on the broadcast channel.
pub const COMMANDER: &str = "commander";
/// SES tag / shared-form object description of Scooter's marker, as Skeeter sees it.
pub const SCOOTER_TAG: &str = "scooter";
/// Name of Skeeter's SES Peer Agent source.
pub const SES_SOURCE: &str = "ses";
/// Kind of Skeeter's SES Peer Agent source.
pub const SES_SOURCE_KIND: &str = "ses";
/// Schema of the SES source's samples: the shared-form version
/// ([`crate::ses::shared::VERSION`]).
pub const SES_SOURCE_SCHEMA: u16 = crate::ses::shared::VERSION as u16;

/// Longest string field of a wire message, bytes (its length travels in one byte).
pub const MAX_WIRE_STR: usize = 255;

/// `s` cut to at most [`MAX_WIRE_STR`] bytes, at a char boundary (a longer string could
/// not be sent: emitting the message would fail with `FieldTooLong`).
#[must_use]
pub fn truncate_wire_str(s: &str) -> &str {
    if s.len() <= MAX_WIRE_STR {
        return s;
    }
    let mut end = MAX_WIRE_STR;
    while end > 0 && !s.is_char_boundary(end) {
        end -= 1;
    }
    s.get(..end).unwrap_or("")
}

/// Emergency kind string of [`Emergency::ScooterLost`].
pub const KIND_SCOOTER_LOST: &str = "scooter-lost";
/// Emergency kind string of [`Emergency::ScooterFound`].
pub const KIND_SCOOTER_FOUND: &str = "scooter-found";
/// Emergency kind string of [`Emergency::TargetQuery`].
pub const KIND_TARGET_QUERY: &str = "target-query";
/// Emergency kind string of [`Emergency::TargetReply`].
pub const KIND_TARGET_REPLY: &str = "target-reply";
/// Emergency kind string of [`Emergency::TargetReached`].
pub const KIND_TARGET_REACHED: &str = "target-reached";
/// Emergency kind string of [`Emergency::FleetStop`].
pub const KIND_FLEET_STOP: &str = "fleet-stop";
/// Emergency kind string of [`Emergency::FleetResume`].
pub const KIND_FLEET_RESUME: &str = "fleet-resume";
/// Emergency kind string of [`Emergency::TargetCancel`].
pub const KIND_TARGET_CANCEL: &str = "target-cancel";
/// Version word that starts the text of the fleet commands (`fleet-stop`, `fleet-resume`).
pub const FLEET_VERSION: &str = "v1";
/// Copies of a fleet command a commander sends (broadcasts are datagrams and may be lost;
/// the robots obey the first and ignore the repeats).
pub const FLEET_COPIES: usize = 5;

/// An emergency on the broadcast channel, typed by its kind.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Emergency {
    /// `scooter-lost`: Skeeter lost sight of Scooter (the stress call; Scooter goes home).
    ScooterLost,
    /// `scooter-found`: Skeeter sees Scooter again (Scooter resumes its mission).
    ScooterFound,
    /// `target-query`: Skeeter cannot see `colour` and asks whether Scooter does.
    TargetQuery {
        /// The target colour.
        colour: String,
    },
    /// `target-reply`: Scooter's answer to a [`Emergency::TargetQuery`].
    TargetReply {
        /// The target colour.
        colour: String,
        /// Whether Scooter sees it.
        seen: bool,
    },
    /// `target-reached`: Scooter sees the target close up.
    TargetReached {
        /// The target colour.
        colour: String,
    },
    /// `fleet-stop`: every robot zeroes its velocity at once and holds until a
    /// [`Emergency::FleetResume`] or a new target.
    FleetStop {
        /// Why (free text, shown to the operator; may be empty).
        reason: String,
    },
    /// `fleet-resume`: the robots may move again (they carry on with their targets).
    FleetResume,
    /// `target-cancel`: the commander withdraws a target; the observer ends it as failed
    /// and the robots stop pursuing it.
    TargetCancel {
        /// The target colour.
        colour: String,
    },
}

impl Emergency {
    /// The machine-readable kind string (`scooter-lost`, …).
    #[must_use]
    pub fn kind(&self) -> &'static str {
        match self {
            Emergency::ScooterLost => KIND_SCOOTER_LOST,
            Emergency::ScooterFound => KIND_SCOOTER_FOUND,
            Emergency::TargetQuery { .. } => KIND_TARGET_QUERY,
            Emergency::TargetReply { .. } => KIND_TARGET_REPLY,
            Emergency::TargetReached { .. } => KIND_TARGET_REACHED,
            Emergency::FleetStop { .. } => KIND_FLEET_STOP,
            Emergency::FleetResume => KIND_FLEET_RESUME,
            Emergency::TargetCancel { .. } => KIND_TARGET_CANCEL,
        }
    }

    /// The text carried on the wire: the colour (query, reached), `"<colour> yes|no"`
    /// (reply) or a human-readable sentence (lost, found).
    #[must_use]
    pub fn text(&self) -> String {
        match self {
            Emergency::ScooterLost => "Scooter lost".to_owned(),
            Emergency::ScooterFound => "Scooter found".to_owned(),
            Emergency::TargetQuery { colour }
            | Emergency::TargetReached { colour }
            | Emergency::TargetCancel { colour } => colour.clone(),
            Emergency::FleetStop { reason } if reason.is_empty() => FLEET_VERSION.to_owned(),
            Emergency::FleetStop { reason } => {
                truncate_wire_str(&format!("{FLEET_VERSION} {reason}")).to_owned()
            }
            Emergency::FleetResume => FLEET_VERSION.to_owned(),
            Emergency::TargetReply { colour, seen } => {
                format!("{colour} {}", if *seen { "yes" } else { "no" })
            }
        }
    }

    /// Types an emergency from its wire `kind` and `text`. The text of `scooter-lost` and
    /// `scooter-found` is free; a colour must be non-empty and contain no whitespace.
    ///
    /// # Errors
    /// [`MsgError::UnknownKind`], [`MsgError::BadColour`], [`MsgError::BadReply`].
    pub fn from_kind_text(kind: &str, text: &str) -> Result<Self, MsgError> {
        match kind {
            KIND_SCOOTER_LOST => Ok(Emergency::ScooterLost),
            KIND_SCOOTER_FOUND => Ok(Emergency::ScooterFound),
            KIND_TARGET_QUERY => Ok(Emergency::TargetQuery {
                colour: colour(text)?,
            }),
            KIND_TARGET_REACHED => Ok(Emergency::TargetReached {
                colour: colour(text)?,
            }),
            KIND_TARGET_CANCEL => Ok(Emergency::TargetCancel {
                colour: colour(text)?,
            }),
            KIND_FLEET_STOP => Ok(Emergency::FleetStop {
                reason: fleet_text(text)?.to_owned(),
            }),
            KIND_FLEET_RESUME => fleet_text(text).map(|_| Emergency::FleetResume),
            KIND_TARGET_REPLY => {
                let mut words = text.split_whitespace();
                let (Some(c), Some(answer), None) = (words.next(), words.next(), words.next())
                else {
                    return Err(MsgError::BadReply);
                };
                let seen = match answer {
                    "yes" => true,
                    "no" => false,
                    _ => return Err(MsgError::BadReply),
                };
                Ok(Emergency::TargetReply {
                    colour: c.to_owned(),
                    seen,
                })
            }
            _ => Err(MsgError::UnknownKind),
        }
    }
}

/// The text of a fleet command after its version word: `v1 …` or no version word (taken
/// as version 1); another `vN` is [`MsgError::UnsupportedVersion`].
fn fleet_text(text: &str) -> Result<&str, MsgError> {
    let t = text.trim();
    let (first, rest) = t.split_once(' ').unwrap_or((t, ""));
    if first == FLEET_VERSION {
        return Ok(rest.trim());
    }
    let is_version = first.len() > 1
        && first.starts_with('v')
        && first.bytes().skip(1).all(|b| b.is_ascii_digit());
    if is_version {
        Err(MsgError::UnsupportedVersion)
    } else {
        Ok(t)
    }
}

fn colour(text: &str) -> Result<String, MsgError> {
    let t = text.trim();
    if t.is_empty() || t.chars().any(char::is_whitespace) {
        Err(MsgError::BadColour)
    } else {
        Ok(t.to_owned())
    }
}

/// One broadcast-channel message of the mission, without its sequence number.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Broadcast {
    /// A robot's status: the running SAN module and a SAN summary.
    Status {
        /// Sender robot.
        robot: String,
        /// The running SAN module ("behaviour").
        behaviour: String,
        /// A SAN state summary (free text).
        san: String,
        /// Pose, if the robot knows it.
        pose: Option<Pose>,
    },
    /// An emergency.
    Emergency {
        /// Sender robot.
        robot: String,
        /// What happened.
        emergency: Emergency,
    },
    /// A mission event about one target.
    Mission {
        /// Sender robot (`commander` for a new target).
        robot: String,
        /// What happened.
        event: MissionEvent,
        /// The target colour.
        target: String,
    },
}

impl Broadcast {
    /// A status broadcast. Its text fields are cut to [`MAX_WIRE_STR`] bytes at a char
    /// boundary ([`truncate_wire_str`]), so that it can always be sent.
    #[must_use]
    pub fn status(robot: &str, behaviour: &str, san: &str, pose: Option<Pose>) -> Self {
        Broadcast::Status {
            robot: truncate_wire_str(robot).to_owned(),
            behaviour: truncate_wire_str(behaviour).to_owned(),
            san: truncate_wire_str(san).to_owned(),
            pose,
        }
    }

    /// An emergency broadcast.
    #[must_use]
    pub fn emergency(robot: &str, emergency: Emergency) -> Self {
        Broadcast::Emergency {
            robot: robot.to_owned(),
            emergency,
        }
    }

    /// A mission-event broadcast.
    #[must_use]
    pub fn mission(robot: &str, event: MissionEvent, target: &str) -> Self {
        Broadcast::Mission {
            robot: robot.to_owned(),
            event,
            target: target.to_owned(),
        }
    }

    /// The commander's request for a new target: `Mission { commander, Accepted, colour }`.
    #[must_use]
    pub fn new_target(colour: &str) -> Self {
        Self::mission(COMMANDER, MissionEvent::Accepted, colour)
    }

    /// The sending robot.
    #[must_use]
    pub fn robot(&self) -> &str {
        match self {
            Broadcast::Status { robot, .. }
            | Broadcast::Emergency { robot, .. }
            | Broadcast::Mission { robot, .. } => robot,
        }
    }

    /// The wire message, stamped with the per-sender sequence number `seq`.
    #[must_use]
    pub fn to_wire(&self, seq: u64) -> Msg {
        match self {
            Broadcast::Status {
                robot,
                behaviour,
                san,
                pose,
            } => Msg::Status {
                robot: robot.clone(),
                seq,
                behaviour: behaviour.clone(),
                san: san.clone(),
                pose: *pose,
            },
            Broadcast::Emergency { robot, emergency } => Msg::Emergency {
                robot: robot.clone(),
                seq,
                kind: emergency.kind().to_owned(),
                text: emergency.text(),
            },
            Broadcast::Mission {
                robot,
                event,
                target,
            } => Msg::Mission {
                robot: robot.clone(),
                seq,
                event: *event,
                target: target.clone(),
            },
        }
    }

    /// Types a wire message (the sequence number is dropped).
    ///
    /// # Errors
    /// [`MsgError::NotBroadcast`] for a message of another channel, and the errors of
    /// [`Emergency::from_kind_text`]; a mission with an empty or spaced target is
    /// [`MsgError::BadColour`].
    pub fn from_wire(msg: &Msg) -> Result<Self, MsgError> {
        match msg {
            Msg::Status {
                robot,
                behaviour,
                san,
                pose,
                ..
            } => Ok(Broadcast::Status {
                robot: robot.clone(),
                behaviour: behaviour.clone(),
                san: san.clone(),
                pose: *pose,
            }),
            Msg::Emergency {
                robot, kind, text, ..
            } => Ok(Broadcast::Emergency {
                robot: robot.clone(),
                emergency: Emergency::from_kind_text(kind, text)?,
            }),
            Msg::Mission {
                robot,
                event,
                target,
                ..
            } => Ok(Broadcast::Mission {
                robot: robot.clone(),
                event: *event,
                target: colour(target)?,
            }),
            other => Err(MsgError::NotBroadcast(other.code())),
        }
    }
}

impl TryFrom<&Msg> for Broadcast {
    type Error = MsgError;

    fn try_from(msg: &Msg) -> Result<Self, MsgError> {
        Broadcast::from_wire(msg)
    }
}

impl fmt::Display for Broadcast {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Broadcast::Status {
                robot, behaviour, ..
            } => write!(f, "{robot}: status {behaviour}"),
            Broadcast::Emergency { robot, emergency } => {
                write!(f, "{robot}: {} ({})", emergency.kind(), emergency.text())
            }
            Broadcast::Mission {
                robot,
                event,
                target,
            } => write!(f, "{robot}: mission {target} {}", event.as_str()),
        }
    }
}

/// Why a wire message is not a mission [`Broadcast`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MsgError {
    /// The message (type code given) belongs to another channel.
    NotBroadcast(u8),
    /// The emergency kind is not one of the mission's.
    UnknownKind,
    /// A colour text is empty or contains whitespace.
    BadColour,
    /// A `target-reply` text is not `"<colour> yes"` / `"<colour> no"`.
    BadReply,
    /// A fleet command of a later version than [`FLEET_VERSION`].
    UnsupportedVersion,
}

impl fmt::Display for MsgError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            MsgError::NotBroadcast(c) => write!(f, "message type {c:#04x} is not a broadcast"),
            MsgError::UnknownKind => f.write_str("unknown emergency kind"),
            MsgError::BadColour => f.write_str("empty or malformed colour"),
            MsgError::BadReply => f.write_str("target-reply text is not \"<colour> yes|no\""),
            MsgError::UnsupportedVersion => {
                write!(f, "fleet command of a version other than {FLEET_VERSION}")
            }
        }
    }
}

impl std::error::Error for MsgError {}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn all() -> Vec<Broadcast> {
        vec![
            Broadcast::status(SKEETER, "scan", "scan=0.8", None),
            Broadcast::status(
                SCOOTER,
                "go-to-target",
                "",
                Some(Pose {
                    x_mm: -1,
                    y_mm: 2,
                    theta_mrad: 3,
                }),
            ),
            Broadcast::emergency(SKEETER, Emergency::ScooterLost),
            Broadcast::emergency(SKEETER, Emergency::ScooterFound),
            Broadcast::emergency(
                SKEETER,
                Emergency::TargetQuery {
                    colour: "red".into(),
                },
            ),
            Broadcast::emergency(
                SCOOTER,
                Emergency::TargetReply {
                    colour: "red".into(),
                    seen: true,
                },
            ),
            Broadcast::emergency(
                SCOOTER,
                Emergency::TargetReply {
                    colour: "blue".into(),
                    seen: false,
                },
            ),
            Broadcast::emergency(
                SCOOTER,
                Emergency::TargetReached {
                    colour: "green".into(),
                },
            ),
            Broadcast::new_target("yellow"),
            Broadcast::emergency(
                COMMANDER,
                Emergency::FleetStop {
                    reason: "operator pressed stop".into(),
                },
            ),
            Broadcast::emergency(COMMANDER, Emergency::FleetStop { reason: "".into() }),
            Broadcast::emergency(COMMANDER, Emergency::FleetResume),
            Broadcast::emergency(
                COMMANDER,
                Emergency::TargetCancel {
                    colour: "red".into(),
                },
            ),
            Broadcast::mission(SKEETER, MissionEvent::Accomplished, "yellow"),
            Broadcast::mission(SKEETER, MissionEvent::Failed, "cyan"),
        ]
    }

    #[test]
    fn every_broadcast_round_trips_through_wire_msg_and_bytes() {
        for (i, b) in all().into_iter().enumerate() {
            let seq = i as u64 + 7;
            let m = b.to_wire(seq);
            assert_eq!(Broadcast::from_wire(&m), Ok(b.clone()));
            assert_eq!(Broadcast::try_from(&m), Ok(b.clone()));
            // and through the wire body encoding
            let mut buf = [0u8; 512];
            let n = m.emit_body(&mut buf).unwrap();
            let back = Msg::parse_body(m.code(), &buf[..n]).unwrap();
            assert_eq!(back, m);
            assert_eq!(Broadcast::from_wire(&back), Ok(b));
        }
    }

    #[test]
    fn long_status_texts_are_cut_at_a_char_boundary_and_still_emit() {
        assert_eq!(truncate_wire_str("short"), "short");
        // 254 ASCII bytes then a 3-byte char across the 255 limit.
        let s = format!("{}€tail", "a".repeat(254));
        let cut = truncate_wire_str(&s);
        assert_eq!(cut.len(), 254);
        assert!(cut.chars().all(|c| c == 'a'));
        let exact = "b".repeat(255);
        assert_eq!(truncate_wire_str(&exact), exact);
        let long = "é".repeat(400);
        let b = Broadcast::status("skeeter", "scan-for-target", &long, None);
        let Broadcast::Status { san, .. } = &b else {
            panic!("a status")
        };
        assert!(san.len() <= MAX_WIRE_STR && san.len() >= MAX_WIRE_STR - 1);
        let mut buf = [0u8; 1024];
        let m = b.to_wire(1);
        let n = m.emit_body(&mut buf).unwrap();
        assert_eq!(Msg::parse_body(m.code(), &buf[..n]).unwrap(), m);
    }

    #[test]
    fn wire_texts_are_the_agreed_ones() {
        let m = Broadcast::emergency(
            SCOOTER,
            Emergency::TargetReply {
                colour: "red".into(),
                seen: false,
            },
        )
        .to_wire(1);
        assert_eq!(
            m,
            Msg::Emergency {
                robot: "scooter".into(),
                seq: 1,
                kind: "target-reply".into(),
                text: "red no".into()
            }
        );
        let m = Broadcast::emergency(SKEETER, Emergency::ScooterLost).to_wire(2);
        let Msg::Emergency { kind, .. } = m else {
            panic!()
        };
        assert_eq!(kind, "scooter-lost");
        assert_eq!(
            Broadcast::new_target("red").to_wire(0),
            Msg::Mission {
                robot: "commander".into(),
                seq: 0,
                event: MissionEvent::Accepted,
                target: "red".into()
            }
        );
    }

    #[test]
    fn bad_wire_messages_are_typed_errors() {
        assert_eq!(
            Broadcast::from_wire(&Msg::Heartbeat),
            Err(MsgError::NotBroadcast(0x05))
        );
        let em = |kind: &str, text: &str| Msg::Emergency {
            robot: "x".into(),
            seq: 0,
            kind: kind.into(),
            text: text.into(),
        };
        assert_eq!(
            Broadcast::from_wire(&em("fire", "")),
            Err(MsgError::UnknownKind)
        );
        assert_eq!(
            Broadcast::from_wire(&em("target-query", "  ")),
            Err(MsgError::BadColour)
        );
        assert_eq!(
            Broadcast::from_wire(&em("target-reached", "dark red")),
            Err(MsgError::BadColour)
        );
        for t in ["red", "red maybe", "red yes please", ""] {
            assert_eq!(
                Broadcast::from_wire(&em("target-reply", t)),
                Err(MsgError::BadReply),
                "{t:?}"
            );
        }
        // surrounding whitespace is tolerated
        assert_eq!(
            Emergency::from_kind_text("target-reply", " red  yes "),
            Ok(Emergency::TargetReply {
                colour: "red".into(),
                seen: true
            })
        );
        let bad_mission = Msg::Mission {
            robot: "commander".into(),
            seq: 0,
            event: MissionEvent::Accepted,
            target: String::new(),
        };
        assert_eq!(Broadcast::from_wire(&bad_mission), Err(MsgError::BadColour));
        // The free text of lost/found is ignored.
        assert_eq!(
            Emergency::from_kind_text("scooter-lost", "anything at all"),
            Ok(Emergency::ScooterLost)
        );
    }

    #[test]
    fn fleet_commands_have_versioned_texts_and_old_messages_still_decode() {
        let stop = Broadcast::emergency(
            COMMANDER,
            Emergency::FleetStop {
                reason: "ctrl-c".into(),
            },
        );
        let Msg::Emergency { kind, text, .. } = stop.to_wire(3) else {
            panic!("an emergency")
        };
        assert_eq!((kind.as_str(), text.as_str()), ("fleet-stop", "v1 ctrl-c"));
        assert_eq!(
            Emergency::from_kind_text("fleet-resume", "v1"),
            Ok(Emergency::FleetResume)
        );
        // No version word: version 1, the whole text is the reason.
        assert_eq!(
            Emergency::from_kind_text("fleet-stop", "stop now"),
            Ok(Emergency::FleetStop {
                reason: "stop now".into()
            })
        );
        // A later version is refused, not misread.
        assert_eq!(
            Emergency::from_kind_text("fleet-stop", "v2 halt"),
            Err(MsgError::UnsupportedVersion)
        );
        assert_eq!(
            Emergency::from_kind_text("target-cancel", "dark red"),
            Err(MsgError::BadColour)
        );
        // The earlier vocabulary decodes exactly as before.
        assert_eq!(
            Emergency::from_kind_text("target-reached", "red"),
            Ok(Emergency::TargetReached {
                colour: "red".into()
            })
        );
        assert_eq!(
            Emergency::from_kind_text("scooter-found", ""),
            Ok(Emergency::ScooterFound)
        );
    }

    #[test]
    fn display_and_robot() {
        let b = Broadcast::mission(SKEETER, MissionEvent::Failed, "red");
        assert_eq!(b.robot(), "skeeter");
        assert_eq!(b.to_string(), "skeeter: mission red failed");
        assert!(MsgError::NotBroadcast(1).to_string().contains("0x01"));
    }

    proptest! {
        #[test]
        fn any_emergency_kind_and_text_never_panics(kind in ".{0,20}", text in ".{0,40}") {
            if let Ok(e) = Emergency::from_kind_text(&kind, &text) {
                // what parses re-emits to something that parses to the same thing
                prop_assert_eq!(Emergency::from_kind_text(e.kind(), &e.text()), Ok(e));
            }
        }

        #[test]
        fn colour_round_trips(c in "[a-z][a-z0-9_-]{0,15}", seen: bool) {
            for e in [
                Emergency::TargetQuery { colour: c.clone() },
                Emergency::TargetReached { colour: c.clone() },
                Emergency::TargetReply { colour: c.clone(), seen },
            ] {
                let b = Broadcast::emergency(SKEETER, e);
                prop_assert_eq!(Broadcast::from_wire(&b.to_wire(1)), Ok(b));
            }
        }
    }
}

//! What Scooter hears ([`ScooterHeard`]) and says ([`ScooterSay`]) on the broadcast channel,
//! and their mapping to and from the typed mission messages.

use crate::mission::msg::{Broadcast, Emergency, MissionEvent, Pose};

use super::Behaviour;

/// What Scooter hears on the broadcast channel (the runtime converts the typed mission
/// messages of `mission::msg` into these).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ScooterHeard {
    /// A new target colour was accepted (by Skeeter): go find it.
    TargetAccepted {
        /// Colour name, as in the SES.
        colour: String,
    },
    /// The mission for `colour` ended (accomplished or failed): stop and wait (ignored when
    /// `colour` is not the current target).
    MissionEnded {
        /// The target that ended.
        colour: String,
    },
    /// Skeeter's stress call `scooter-lost`: come home.
    ScooterLost,
    /// Skeeter sees Scooter again (`scooter-found`).
    ScooterFound,
    /// Skeeter asks whether Scooter sees the target (`target-query`).
    TargetQuery {
        /// Colour asked about.
        colour: String,
    },
}

/// What Scooter says (the runtime turns these into broadcasts or Peer Agent requests).
#[derive(Debug, Clone, PartialEq)]
pub enum ScooterSay {
    /// `target-reached` (text = colour).
    TargetReached {
        /// Colour reached.
        colour: String,
    },
    /// `target-reply` (text = `"<colour> yes"` / `"<colour> no"`).
    TargetReply {
        /// Colour asked about.
        colour: String,
        /// Whether Scooter sees it with its laser, has reached it, or holds a fresh plan
        /// for it (a sample with the target within [`ScooterConfig::lost_after`](super::ScooterConfig::lost_after)).
        seen: bool,
    },
    /// Periodic `Status`.
    Status {
        /// Running module.
        behaviour: Behaviour,
        /// DR pose `(x_m, y_m, θh_rad)`.
        pose: (f64, f64, f64),
    },
    /// The lost timer ran out: ask Skeeter for a fresh SES sample.
    RequestHeading,
}

impl ScooterSay {
    /// The text of a `target-reply` emergency: `"<colour> yes"` or `"<colour> no"`.
    #[must_use]
    pub fn reply_text(colour: &str, seen: bool) -> String {
        format!("{colour} {}", if seen { "yes" } else { "no" })
    }

    /// The broadcast to send for this output, from robot `robot` (`"scooter"`), with `san`
    /// as the status's SAN summary. `None` for [`ScooterSay::RequestHeading`], which is for
    /// the Peer Agent client (re-request Skeeter's `ses` source), not the broadcast channel.
    /// The status pose is the DR pose in millimetres and milliradians.
    #[must_use]
    pub fn to_broadcast(&self, robot: &str, san: &str) -> Option<Broadcast> {
        match self {
            Self::TargetReached { colour } => Some(Broadcast::emergency(
                robot,
                Emergency::TargetReached {
                    colour: colour.clone(),
                },
            )),
            Self::TargetReply { colour, seen } => Some(Broadcast::emergency(
                robot,
                Emergency::TargetReply {
                    colour: colour.clone(),
                    seen: *seen,
                },
            )),
            Self::Status { behaviour, pose } => {
                let fix = |v: f64| {
                    if v.is_finite() {
                        (v * 1000.0)
                            .round()
                            .clamp(f64::from(i32::MIN), f64::from(i32::MAX))
                            as i32
                    } else {
                        0
                    }
                };
                Some(Broadcast::status(
                    robot,
                    behaviour.as_str(),
                    san,
                    Some(Pose {
                        x_mm: fix(pose.0),
                        y_mm: fix(pose.1),
                        theta_mrad: fix(pose.2),
                    }),
                ))
            }
            Self::RequestHeading => None,
        }
    }
}

impl ScooterHeard {
    /// What a broadcast means to Scooter, if anything: a target `Accepted` by anyone but
    /// Scooter (the commander's request or Skeeter's acceptance) starts a target;
    /// `Accomplished`/`Failed` or a commander's `target-cancel` ends it; the emergencies
    /// `scooter-lost`, `scooter-found` and `target-query` map one to one. Everything else (statuses, Scooter's own
    /// emergencies) is `None`.
    #[must_use]
    pub fn from_broadcast(b: &Broadcast, me: &str) -> Option<Self> {
        if b.robot() == me {
            return None;
        }
        match b {
            Broadcast::Mission { event, target, .. } => Some(match event {
                MissionEvent::Accepted => Self::TargetAccepted {
                    colour: target.clone(),
                },
                MissionEvent::Accomplished | MissionEvent::Failed => Self::MissionEnded {
                    colour: target.clone(),
                },
            }),
            Broadcast::Emergency { emergency, .. } => match emergency {
                Emergency::ScooterLost => Some(Self::ScooterLost),
                Emergency::ScooterFound => Some(Self::ScooterFound),
                Emergency::TargetQuery { colour } => Some(Self::TargetQuery {
                    colour: colour.clone(),
                }),
                // The commander withdrew the target: for Scooter, that target is over.
                Emergency::TargetCancel { colour } => Some(Self::MissionEnded {
                    colour: colour.clone(),
                }),
                // Fleet stop and resume are obeyed by the stack, below the brain.
                Emergency::TargetReply { .. }
                | Emergency::TargetReached { .. }
                | Emergency::FleetStop { .. }
                | Emergency::FleetResume => None,
            },
            Broadcast::Status { .. } => None,
        }
    }
}

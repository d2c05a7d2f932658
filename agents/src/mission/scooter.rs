//! Scooter's brain: the scout's agents, each a small sans-IO type in its own file, wired by
//! Scooter's SAN behind the [`ScooterBrain`] facade.
//!
//! | agent | file | state |
//! |---|---|---|
//! | heading | `scooter/heading.rs` | θh from compass/odometry/fused, DR position and its history |
//! | heading calculation | `scooter/heading_calc.rs` | the plan from SES samples, the lost timer, heading requests |
//! | obstacle avoidance | `scooter/obstacle.rs` | laser obstacle points (and their memory), the laser's age, the avoider's smoothed direction |
//! | target finder | `scooter/target_finder.rs` | the laser's fixes on the target and on Skeeter, the last target reached |
//! | go-home | `scooter/home.rs` | the call-back and where Skeeter is |
//! | controller | `scooter/controller.rs` | turn rate, turn-in-place latch, the last guard before the wheels |
//!
//! The facade feeds each input to the agents that use it, sets the SAN's conditions from
//! their state every [`ScooterBrain::step`], lets the SAN choose the running module, and
//! carries the module out with the controller. The agents never call each other: the
//! facade passes what one needs from another (the DR history to the heading calculation,
//! Skeeter's laser fix to the range-aware rule, a ranged Skeeter position to go-home).
//! The parameters are in `scooter/config.rs`, the broadcast vocabulary in
//! `scooter/messages.rs` (both re-exported here).
//!
//! # Frames (read this first)
//!
//! * **Common frame.** The thesis measures every bearing "relative to the robots' common
//!   initial heading" (MISSION.md): at the start both robots face the same way, and that
//!   direction is azimuth 0, counter-clockwise positive, radians in (−π, π]. Skeeter never
//!   moves, so its own robot frame *is* the common frame, centred on Skeeter: the bearings
//!   θ1 (Skeeter → Scooter) and θ2 (Skeeter → target) of its SES records are common-frame
//!   bearings.
//! * **Scooter's heading θh** is its heading in the common frame. From the compass
//!   ([`ScooterBrain::handle_compass`] takes it *already in the common frame*: the runtime
//!   subtracts the compass reading taken while the robots faced the common initial heading),
//!   from odometry (odometry heading + [`ScooterConfig::odometry_heading_offset_rad`], 0 when
//!   the odometry was reset while facing the common initial heading), or both fused
//!   ([`HeadingSource`]).
//! * **Dead-reckoning frame (DR).** Scooter's own position estimate: odometry distance
//!   increments rotated by θh, so its axes are the common frame's but its origin is wherever
//!   Scooter started (Scooter does not know where it is relative to Skeeter unless ranges
//!   tell it). Only *differences* of DR positions are used (triangulation, target estimate).
//! * **Robot frame**: x forward, y left (as `ima_hal`); the laser is mounted at
//!   [`ScooterConfig::laser_mount`].
//!
//! # Heading rules ([`HeadingRule`], from [`crate::heading`])
//!
//! Each time a new SES sample arrives the heading-calculation agent computes a plan:
//!
//! * **Thesis**: `θd = thesis_heading(θ1, θ2)`, a fixed common-frame heading followed until
//!   the next sample (the isosceles assumption; exact only on the SES circle).
//! * **Range-aware**: with Skeeter's ranges (SES) for both the target and Scooter — or
//!   Scooter's range triangulated from its own motion between two samples
//!   ([`crate::heading::triangulate_scout_range`]) — the target's position is known
//!   relative to Scooter: `T_dr = P_dr(t_rec) + Dt·u(θ2) − Ds·u(θ1)`, where `P_dr(t_rec)` is
//!   Scooter's DR position when Skeeter's camera saw it. The plan is that **point** (a
//!   running mean over the samples of the current target, which averages range noise out),
//!   and the heading to it is recomputed at every step from dead reckoning. Without ranges
//!   it falls back to the thesis rule.
//!
//! A sample without both Scooter and the target keeps the previous plan and does not reset
//! the lost timer; one where the rule is degenerate (the thesis rule with θ1 = θ2) keeps
//! the previous plan.
//!
//! The controller turns toward θd: in place while the error exceeds
//! [`ScooterConfig::turn_in_place_enter_rad`] (until it is below `…_exit_rad`), otherwise
//! it drives at the cruise speed with proportional steering, the turn rate clamped to
//! [`ScooterConfig::max_turn_rate_rad_s`] (an optional low-pass, `turn_filter_s`, is off by
//! default: its lag made the robot overshoot after turning in place).
//!
//! # Smooth avoidance
//!
//! The [avoider](super::avoid) locks the side it goes round an obstacle on and has
//! enter/exit hysteresis; the brain low-pass filters its steering direction in the common
//! frame ([`ScooterConfig::avoid_smoothing_s`]) so the candidate search's 3° steps and laser
//! noise at a corridor's edge never reach the wheels. In the simulation (`ima-sim` test
//! `a_barrel_on_the_way_is_avoided_smoothly_with_the_real_laser_model`) the turn rate
//! changes sign once while going round a barrel: away, then back. Going round a wide
//! obstacle (a wall with the target behind it) the avoider keeps its side locked while the
//! goal is out of the laser's view, and obstacle points that leave the view are remembered
//! ([`ScooterConfig::obstacle_memory_m`]) so that the post beside Scooter is not forgotten.
//!
//! # Ranges
//!
//! Scooter's range from Skeeter comes, best first, from its own laser (a cluster of
//! Skeeter's diameter where θ1 + 180° says Skeeter is, fresh within 3 s), from the SES
//! record, or from triangulation over two samples.
//!
//! # Behaviours (MISSION.md, "Scooter's SAN"; `agents/networks/scooter.toml`)
//!
//! Agents set the SAN's conditions every step; the SAN spreads activation and the module it
//! fires — or, on a step where nothing reaches the threshold, the executable module with the
//! highest activation (ties by weight) — runs. The brain runs the network with
//! `reset_fired = false` so the running module does not alternate with a runner-up.
//!
//! | condition | set by |
//! |---|---|
//! | `heading-stale` | no SES sample for [`ScooterConfig::lost_after`] (or none yet for this target) |
//! | `heading-known` | a plan exists and is not stale |
//! | `target-in-view` | a laser cluster of the target's diameter where Scooter expects the target |
//! | `obstacle-near` / `path-clear` | the [avoider](super::avoid) (hysteresis) |
//! | `called-back` / `skeeter-in-view` | broadcast `scooter-lost` / `scooter-found`, or an SES sample with a fresh `scooter` record (ends the call-back; the broadcast may be lost) |
//! | `asked-for-target` | broadcast `target-query` |
//! | `at-target` | the target cluster within [`ScooterConfig::reach_distance_m`] |
//! | `path-clear` needs eyes | no usable scan for [`ScooterConfig::laser_stale_after`]: forward speed 0 (turning in place allowed) |
//! | `skeeter-notified` | `target-reached` sent |
//!
//! | module | action |
//! |---|---|
//! | `request-heading` | send [`ScooterSay::RequestHeading`] (again every `lost_after`); coast on the last plan for [`ScooterConfig::coast_for`] after the last sample, then stand still |
//! | `follow-heading` | turn to θd and drive |
//! | `move-to-target` | drive to the laser cluster |
//! | `avoid-obstacle` | steer round the obstacle on a locked side |
//! | `move-to-home` | drive toward Skeeter (DR position when known, else θ1 + 180°) and stop 1.2 m short |
//! | `reply-target-query` | send [`ScooterSay::TargetReply`] (motion continues): "yes" when the laser tracks the target, it was reached, or a fresh plan for it exists (Skeeter's view of the target may just be hidden by Scooter); "no" otherwise |
//! | `notify-skeeter` | send [`ScooterSay::TargetReached`] and stop; resent every [`ScooterConfig::status_period`] until the target's `Accomplished`/`Failed` (or a new target) is heard |
//!
//! Without a target the brain is [`Behaviour::Idle`] (not a SAN module) and stands still.

mod config;
mod controller;
mod heading;
mod heading_calc;
mod home;
mod messages;
mod obstacle;
mod target_finder;

use ima_hal::base::{Odometry, VelocityCommand};
use ima_hal::laser::LaserScan;
use ima_hal::{Instant, Vector2};

pub use self::config::{HeadingRule, HeadingSource, ScooterConfig, TargetRecognition};
pub use self::messages::{ScooterHeard, ScooterSay};
pub use self::target_finder::{Cluster, laser_clusters};

use self::controller::Controller;
use self::heading::HeadingAgent;
use self::heading_calc::HeadingCalculator;
use self::home::HomeAgent;
use self::obstacle::ObstacleAgent;
use self::target_finder::TargetFinder;
use super::msg::Broadcast;
use crate::san::Network;
use crate::ses::shared::SharedForm;

/// Scooter's SAN network, `agents/networks/scooter.toml`.
pub const SCOOTER_NETWORK_TOML: &str = include_str!("../../networks/scooter.toml");

/// The running behaviour: a module of Scooter's SAN, or idle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Behaviour {
    /// No target: standing still (not a SAN module).
    Idle,
    /// `request-heading`.
    RequestHeading,
    /// `follow-heading`.
    FollowHeading,
    /// `move-to-target`.
    MoveToTarget,
    /// `avoid-obstacle`.
    AvoidObstacle,
    /// `move-to-home`.
    MoveToHome,
    /// `reply-target-query`.
    ReplyTargetQuery,
    /// `notify-skeeter`.
    NotifySkeeter,
}

impl Behaviour {
    /// The SAN module name (`"idle"` for [`Behaviour::Idle`]).
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Idle => "idle",
            Self::RequestHeading => "request-heading",
            Self::FollowHeading => "follow-heading",
            Self::MoveToTarget => "move-to-target",
            Self::AvoidObstacle => "avoid-obstacle",
            Self::MoveToHome => "move-to-home",
            Self::ReplyTargetQuery => "reply-target-query",
            Self::NotifySkeeter => "notify-skeeter",
        }
    }

    /// The behaviour of a SAN module name.
    #[must_use]
    pub fn from_module(name: &str) -> Option<Self> {
        Some(match name {
            "request-heading" => Self::RequestHeading,
            "follow-heading" => Self::FollowHeading,
            "move-to-target" => Self::MoveToTarget,
            "avoid-obstacle" => Self::AvoidObstacle,
            "move-to-home" => Self::MoveToHome,
            "reply-target-query" => Self::ReplyTargetQuery,
            "notify-skeeter" => Self::NotifySkeeter,
            _ => return None,
        })
    }
}

/// The heading-calculation agent's current plan.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Plan {
    /// Follow a fixed common-frame heading, radians (thesis rule, or range-aware fallback).
    Heading(f64),
    /// Go to a point in the DR frame (range-aware rule with ranges).
    Point(Vector2),
}

/// One step's outputs.
#[derive(Debug, Clone, PartialEq)]
pub struct ScooterOutput {
    /// Velocity command for the base.
    pub command: VelocityCommand,
    /// The running behaviour (SAN module).
    pub behaviour: Behaviour,
    /// Messages to send, oldest first.
    pub messages: Vec<ScooterSay>,
}

/// A goal: common-frame direction, distance (∞ if unknown), and a DR circle that is not an
/// obstacle (the target itself, or Skeeter when homing).
type Goal = (f64, f64, Option<(Vector2, f64)>);

/// The unit vector at angle `theta`.
fn unit(theta: f64) -> Vector2 {
    Vector2::new(theta.cos(), theta.sin())
}

/// Rotate a vector by `theta`.
fn rotate(theta: f64, v: Vector2) -> Vector2 {
    let (s, c) = theta.sin_cos();
    Vector2::new(c * v.x - s * v.y, s * v.x + c * v.y)
}

/// Scooter's brain: a facade that feeds its agents (see the [module docs](self)) and lets
/// the SAN choose among their modules.
#[derive(Debug, Clone)]
pub struct ScooterBrain {
    cfg: ScooterConfig,
    san: Network,
    /// θh and dead reckoning.
    heading: HeadingAgent,
    /// The plan from SES samples, the lost timer.
    calc: HeadingCalculator,
    /// Obstacle points, the avoider, the laser's age.
    obstacle: ObstacleAgent,
    /// The laser's target and Skeeter fixes.
    finder: TargetFinder,
    /// Call-backs and the way home.
    home: HomeAgent,
    /// Turn rate and turn-in-place latch.
    controller: Controller,
    // Mission.
    target: Option<String>,
    reached: bool,
    notified: bool,
    query: Option<String>,
    last_notify_at: Option<Instant>,
    last_step: Option<Instant>,
    behaviour: Behaviour,
    last_status: Option<Instant>,
    outbox: Vec<ScooterSay>,
}

impl ScooterBrain {
    /// A brain with `cfg`, no target, at DR origin.
    ///
    /// # Panics
    /// Never: the embedded network is checked by a unit test.
    #[must_use]
    pub fn new(cfg: ScooterConfig) -> Self {
        #[allow(clippy::expect_used)] // the embedded TOML is a constant, tested
        let mut san = Network::from_toml(SCOOTER_NETWORK_TOML).expect("scooter.toml is valid");
        let mut params = *san.params();
        params.reset_fired = false;
        san.set_params(params);
        Self {
            heading: HeadingAgent::new(&cfg),
            obstacle: ObstacleAgent::new(&cfg),
            calc: HeadingCalculator::default(),
            finder: TargetFinder::default(),
            home: HomeAgent::default(),
            controller: Controller::default(),
            cfg,
            san,
            target: None,
            reached: false,
            notified: false,
            query: None,
            last_notify_at: None,
            last_step: None,
            behaviour: Behaviour::Idle,
            last_status: None,
            outbox: Vec::new(),
        }
    }

    /// The parameters.
    #[must_use]
    pub fn config(&self) -> &ScooterConfig {
        &self.cfg
    }

    /// The SAN (for status summaries and traces).
    #[must_use]
    pub fn san(&self) -> &Network {
        &self.san
    }

    /// The current target colour.
    #[must_use]
    pub fn target(&self) -> Option<&str> {
        self.target.as_deref()
    }

    /// The running behaviour after the last [`ScooterBrain::step`].
    #[must_use]
    pub fn behaviour(&self) -> Behaviour {
        self.behaviour
    }

    /// The current plan of the heading-calculation agent.
    #[must_use]
    pub fn plan(&self) -> Option<Plan> {
        self.calc.plan()
    }

    /// Scooter's heading θh in the common frame from the configured source, if known.
    #[must_use]
    pub fn heading(&self) -> Option<f64> {
        self.heading.heading()
    }

    /// Scooter's DR position (metres, common-frame axes, origin where it started).
    #[must_use]
    pub fn dr_position(&self) -> Vector2 {
        self.heading.dr()
    }

    /// The laser obstacles remembered for avoidance, in the DR frame (metres).
    #[must_use]
    pub fn obstacles_dr(&self) -> &[Vector2] {
        self.obstacle.seen_dr()
    }

    /// The desired common-frame heading θd right now (from the plan), if any.
    #[must_use]
    pub fn desired_heading(&self) -> Option<f64> {
        self.calc.desired_heading(self.heading.dr())
    }

    /// Whether the target was reached (and Skeeter told).
    #[must_use]
    pub fn reached(&self) -> bool {
        self.reached
    }

    /// Set a new target colour directly (same as hearing [`ScooterHeard::TargetAccepted`]).
    pub fn set_target(&mut self, colour: &str, _now: Instant) {
        self.target = Some(colour.to_owned());
        self.calc.new_target();
        self.reached = false;
        self.notified = false;
        self.last_notify_at = None;
        self.finder.forget_target();
        self.obstacle.reset();
    }

    /// A typed broadcast from the channel (see [`ScooterHeard::from_broadcast`]); returns
    /// whether it meant anything to Scooter.
    pub fn handle_broadcast(&mut self, b: &Broadcast, now: Instant) -> bool {
        match ScooterHeard::from_broadcast(b, &self.cfg.robot_name) {
            Some(h) => {
                self.handle_heard(&h, now);
                true
            }
            None => false,
        }
    }

    /// A one-line SAN summary for status broadcasts: the true conditions, cut to
    /// [`super::msg::MAX_WIRE_STR`] bytes at a char boundary.
    #[must_use]
    pub fn san_summary(&self) -> String {
        let s = self
            .san
            .condition_names()
            .filter(|c| self.san.condition(c) == Some(true))
            .collect::<Vec<_>>()
            .join(",");
        super::msg::truncate_wire_str(&s).to_owned()
    }

    /// A broadcast heard (already typed). A repeated acceptance of the current target
    /// (the commander's, then Skeeter's) does not restart it.
    pub fn handle_heard(&mut self, heard: &ScooterHeard, now: Instant) {
        match heard {
            ScooterHeard::TargetAccepted { colour } => {
                // Also while reached: the commander polls a processing target, and Skeeter
                // echoes it, until the outcome comes; that must not restart the search.
                if self.target.as_deref() != Some(colour.as_str()) {
                    self.set_target(colour, now);
                }
            }
            ScooterHeard::MissionEnded { colour } => {
                if self.target.as_deref() != Some(colour.as_str()) {
                    return;
                }
                self.target = None;
                self.calc.drop_plan();
                self.obstacle.reset();
            }
            ScooterHeard::ScooterLost => self.home.set_called_back(true),
            ScooterHeard::ScooterFound => self.home.set_called_back(false),
            ScooterHeard::TargetQuery { colour } => self.query = Some(colour.clone()),
        }
    }

    /// A compass heading, radians, **common frame** (see the module docs).
    pub fn handle_compass(&mut self, heading_rad: f64, _now: Instant) {
        self.heading.handle_compass(heading_rad);
    }

    /// An odometry reading: advances the odometry heading, the fused heading and the DR
    /// position (distance increments rotated by θh at mid-step).
    pub fn handle_odometry(&mut self, odo: &Odometry, now: Instant) {
        self.heading.handle_odometry(odo, now);
    }

    /// A sample of Skeeter's SES: the heading-calculation agent computes a new plan when it
    /// holds both Scooter and the current target. Returns whether a plan was made.
    ///
    /// A fresh `scooter` record ([`ScooterConfig::found_record_max_age`]) also ends a
    /// call-back: Skeeter sees Scooter, whether or not its `scooter-found` arrived.
    pub fn handle_ses(&mut self, form: &SharedForm, now: Instant) -> bool {
        self.home.handle_sample(form, &self.cfg);
        let Some(colour) = self.target.as_deref() else {
            return false;
        };
        let skeeter_seen = self.finder.skeeter_in_view(now);
        let out =
            self.calc
                .handle_sample(form, colour, &self.cfg, &self.heading, skeeter_seen, now);
        if let Some(s) = out.skeeter_dr {
            self.home.set_skeeter(s);
        }
        out.planned
    }

    /// A laser scan: obstacle points for the avoider, and the target search.
    ///
    /// A scan that is not usable ([`ScooterConfig::laser_min_usable_fraction`]) is dropped:
    /// it neither clears the path nor refreshes the laser's age.
    pub fn handle_laser(&mut self, scan: &LaserScan, now: Instant) {
        let pose = self.heading.pose();
        if !self.obstacle.handle_scan(scan, &self.cfg, pose, now) {
            return;
        }
        let Some(pose) = pose else {
            return;
        };
        if let Some(fix) = self.calc.last_fix() {
            self.finder
                .find_skeeter(scan, &self.cfg, pose, fix.scout_bearing, now);
        }
        let Some(target) = self.target.as_deref().filter(|_| !self.reached) else {
            return;
        };
        self.finder.find_target(
            scan,
            &self.cfg,
            pose,
            target,
            self.calc.plan(),
            self.calc.desired_heading(pose.1),
            now,
        );
    }

    /// Whether a usable scan came within [`ScooterConfig::laser_stale_after`].
    #[must_use]
    pub fn laser_fresh(&self, now: Instant) -> bool {
        self.obstacle.fresh(now, &self.cfg)
    }

    fn heading_stale(&self, now: Instant) -> bool {
        self.calc.stale(now, self.cfg.lost_after)
    }

    /// Set the SAN's conditions from the agents' state.
    fn feed_san(&mut self, now: Instant, obstacle: bool) {
        let stale = self.heading_stale(now) && !self.reached;
        let tiv = self.finder.target_in_view(now).is_some();
        let called_back = self.home.called_back();
        let conds: [(&str, bool); 11] = [
            ("heading-stale", stale),
            ("heading-known", self.calc.plan().is_some() && !stale),
            ("target-in-view", tiv),
            ("path-clear", !obstacle),
            ("obstacle-near", obstacle),
            ("called-back", called_back),
            ("skeeter-in-view", !called_back),
            ("asked-for-target", self.query.is_some()),
            ("query-answered", self.query.is_none()),
            ("at-target", self.reached),
            ("skeeter-notified", self.notified),
        ];
        for (name, v) in conds {
            let _ = self.san.set_condition(name, v);
        }
    }

    /// Step the SAN and choose among the modules that move or wait (`request-heading`,
    /// `follow-heading`, `move-to-target`, `avoid-obstacle`, `move-to-home`): the fired
    /// module, else the executable one with the highest activation. The two message-only
    /// modules (`reply-target-query`, `notify-skeeter`) are reflexes handled in
    /// [`ScooterBrain::step`].
    fn select(&mut self) -> Behaviour {
        let trace = self.san.step();
        let allowed =
            |b: &Behaviour| !matches!(b, Behaviour::ReplyTargetQuery | Behaviour::NotifySkeeter);
        if let Some(b) = trace
            .fired
            .as_deref()
            .and_then(Behaviour::from_module)
            .filter(allowed)
        {
            return b;
        }
        trace
            .modules
            .iter()
            .filter(|m| m.executable)
            .filter_map(|m| {
                Behaviour::from_module(&m.name)
                    .filter(allowed)
                    .map(|b| (b, m.activation))
            })
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .map_or(Behaviour::Idle, |(b, _)| b)
    }

    /// One control step at `now`: the agents set the SAN's conditions, the SAN chooses the
    /// running module, and the module acts. A reached target makes `notify-skeeter` run
    /// (send `target-reached` once, then stand still); a pending query is answered in the
    /// same step whatever moves (`reply-target-query` is reported for that step).
    pub fn step(&mut self, now: Instant) -> ScooterOutput {
        let dt = self
            .last_step
            .map_or(0.0, |t| now.saturating_duration_since(t).as_secs_f64());
        self.last_step = Some(now);
        let h = self.heading.heading();
        let dr = self.heading.dr();
        if let (Some(t), Some(_), false) = (self.finder.target_in_view(now), h, self.reached)
            && self.target.is_some()
            && (t - dr).norm() <= self.cfg.reach_distance_m
        {
            self.reached = true;
            self.finder.mark_reached(self.target.clone(), t);
        }
        // Obstacle agent: judge the path toward the current goal.
        let engaged = self.target.is_some() && !self.reached;
        let goal = self.goal(now);
        let steer = self.obstacle.steer(&self.cfg, goal, h, dr, engaged, dt);
        self.feed_san(now, steer.is_some());
        let chosen = self.select();
        let called_back = self.home.called_back();
        let motion = if self.reached && self.target.is_some() {
            Behaviour::NotifySkeeter
        } else if self.target.is_none() && !(called_back && chosen == Behaviour::MoveToHome) {
            Behaviour::Idle
        } else {
            chosen
        };
        let mut command = VelocityCommand::ZERO;
        match motion {
            Behaviour::RequestHeading => {
                if self.calc.request_due(now, self.cfg.lost_after) {
                    self.outbox.push(ScooterSay::RequestHeading);
                }
                if self.calc.coasting(now, self.cfg.coast_for) {
                    let goal = self.goal_for(motion, now);
                    command = self
                        .controller
                        .drive(&self.cfg, goal, h, steer, called_back, dt);
                } else {
                    self.controller.halt();
                }
            }
            Behaviour::NotifySkeeter => {
                // Sent at once, then again every status period until the mission event
                // for this target (or a new target) arrives: a broadcast may be lost.
                let due = self
                    .last_notify_at
                    .is_none_or(|t| now.saturating_duration_since(t) >= self.cfg.status_period);
                if (!self.notified || due)
                    && let Some(colour) = self.target.clone()
                {
                    self.notified = true;
                    self.last_notify_at = Some(now);
                    self.outbox.push(ScooterSay::TargetReached { colour });
                }
                self.controller.halt();
                self.obstacle.reset();
            }
            Behaviour::FollowHeading
            | Behaviour::MoveToTarget
            | Behaviour::AvoidObstacle
            | Behaviour::MoveToHome => {
                let goal = self.goal_for(motion, now);
                command = self
                    .controller
                    .drive(&self.cfg, goal, h, steer, called_back, dt);
            }
            Behaviour::Idle | Behaviour::ReplyTargetQuery => self.controller.halt(),
        }
        // Blind (no usable scan lately): never drive forward into an unseen path.
        if !self.laser_fresh(now) {
            command.v_m_s = 0.0;
        }
        let command = self.controller.sanitize(&self.cfg, command);
        let mut behaviour = motion;
        if let Some(colour) = self.query.take() {
            // "Yes" when the laser tracks the target, or while a fresh plan for it exists:
            // Skeeter may just not see the target because Scooter stands in front of it.
            let seen = self.target.as_deref() == Some(colour.as_str())
                && (self.finder.target_in_view(now).is_some()
                    || (self.calc.plan().is_some() && !self.heading_stale(now))
                    || self.reached);
            self.outbox.push(ScooterSay::TargetReply { colour, seen });
            behaviour = Behaviour::ReplyTargetQuery;
        }
        self.behaviour = behaviour;
        if self
            .last_status
            .is_none_or(|t| now.saturating_duration_since(t) >= self.cfg.status_period)
        {
            self.last_status = Some(now);
            self.outbox.push(ScooterSay::Status {
                behaviour,
                pose: (dr.x, dr.y, h.unwrap_or(0.0)),
            });
        }
        ScooterOutput {
            command,
            behaviour,
            messages: std::mem::take(&mut self.outbox),
        }
    }

    fn home_goal(&self) -> Option<Goal> {
        let bearing = self.calc.last_fix().map(|f| f.scout_bearing);
        self.home.goal(self.heading.dr(), bearing)
    }

    fn target_goal(&self, now: Instant) -> Option<Goal> {
        let t = self.finder.target_in_view(now)?;
        let d = t - self.heading.dr();
        let r = self.cfg.target_diameter_m / 2.0 + 0.15;
        Some((d.y.atan2(d.x), d.norm(), Some((t, r))))
    }

    fn plan_goal(&self) -> Option<Goal> {
        let r = self.cfg.target_diameter_m / 2.0 + 0.35;
        match self.calc.plan()? {
            Plan::Heading(hd) => Some((hd, f64::INFINITY, None)),
            Plan::Point(p) => {
                let d = p - self.heading.dr();
                Some((d.y.atan2(d.x), d.norm(), Some((p, r))))
            }
        }
    }

    /// The goal of a motion module.
    fn goal_for(&self, b: Behaviour, now: Instant) -> Option<Goal> {
        match b {
            Behaviour::MoveToHome => self.home_goal(),
            Behaviour::MoveToTarget => self.target_goal(now).or_else(|| self.plan_goal()),
            Behaviour::FollowHeading | Behaviour::RequestHeading => self.plan_goal(),
            _ => self.goal(now),
        }
    }

    /// The goal by state priority (called back → home; target in view → target; else the
    /// plan), which the obstacle agent judges the path toward: (common-frame direction,
    /// distance, a DR circle that is not an obstacle).
    fn goal(&self, now: Instant) -> Option<Goal> {
        if self.home.called_back() {
            return self.home_goal();
        }
        self.target_goal(now).or_else(|| self.plan_goal())
    }
}

#[cfg(test)]
mod testkit;
#[cfg(test)]
mod tests;

//! Scooter's runtime: its sensors feed [`ScooterBrain`], stepped at `control_hz` of mission
//! time, and its velocity commands go to the base; broadcasts and Skeeter's SES arrive
//! through a [`ScooterLink`].
//!
//! Generic over the HAL: any `B: DifferentialBase + Odometer` (a P2OS or an rFLEX base, a
//! simulated one), any `L: LaserScanner`, and an optional `C: Compass` ([`NoCompass`] when
//! there is none). Every reading reaches the brain with its own stamp mapped into mission
//! time ([`MissionTime::at`]): odometry at `o.at`, headings at `h.at`, scans at `scan.at`
//! (so the brain's scan age is `now − scan.at`).
//!
//! The mission decisions of the loop, besides the brain's own:
//!
//! * **reached latch** — once the brain says `TargetReached`, the base is held at zero until
//!   the mission ends or a new target arrives, whatever the brain selects meanwhile;
//! * **fleet stop** — an `Emergency::FleetStop` heard zeroes the base at once and holds it
//!   until `FleetResume` or a new target; statuses then show [`FLEET_STOPPED`];
//! * **target notices** — repeats of the current target (several copies are sent) change
//!   nothing; a new target replays Skeeter's latest SES if it is younger than
//!   `brain.lost_after`, stamped with the time it arrived (the lost timer runs from then);
//!   the commander's target is not taken while the observer works on another one it
//!   accepted (it queues the commander's behind it, and says when it starts it), so that the
//!   two robots never pursue different targets;
//! * **heading requests** — the brain's `RequestHeading` becomes a re-request on the link.

use core::time::Duration;

use ima_hal::base::{DifferentialBase, Odometer, VelocityCommand};
use ima_hal::compass::{Compass, Heading};
use ima_hal::laser::{LaserScan, LaserScanner};
use ima_hal::safety::HaltSignal;
use ima_hal::time::{SharedClock, Stamped};
use ima_hal::{Error as _, ErrorKind, ErrorType, Instant, normalize_angle};
use tokio::sync::watch;

use super::events::{Control, EventKind, Events, MapView, SanView};
use super::link::ScooterLink;
use super::{HaltOnDrop, MissionTime, RuntimeError, StopRequest, stopped};
use crate::mission::msg::{Broadcast, COMMANDER, Emergency, MissionEvent};
use crate::mission::scooter::{ScooterBrain, ScooterConfig, ScooterHeard, ScooterSay};
use crate::ses::shared::SharedForm;

/// The behaviour a robot's status shows while a fleet stop holds it.
pub const FLEET_STOPPED: &str = "fleet-stopped";

/// Scooter's runtime configuration.
#[derive(Debug, Clone)]
pub struct ScooterRuntimeConfig {
    /// The brain's configuration. Its `odometry_heading_offset_rad` is replaced at start:
    /// the runtime aligns odometry with the start heading (compass, else
    /// `initial_heading_deg`, else 0).
    pub brain: ScooterConfig,
    /// Brain steps per mission second (the loop runs at most at 50 Hz real).
    pub control_hz: f64,
    /// Mission time = clock time × this (1 on a robot; a sped-up world's factor).
    pub time_scale: f64,
    /// The common frame's heading, degrees clockwise from north (90: east).
    pub common_heading_deg: f64,
    /// The compass's installation deviation, degrees east (added to its heading).
    pub compass_deviation_deg: f64,
    /// The start heading in the common frame when there is no compass, degrees.
    pub initial_heading_deg: Option<f64>,
    /// How often a [`EventKind::Control`] event reports the command, mission time.
    pub control_report: Duration,
    /// How long to wait at start for the first odometry and compass readings (real time).
    pub first_reading_timeout: Duration,
}

impl Default for ScooterRuntimeConfig {
    fn default() -> Self {
        Self {
            brain: ScooterConfig::default(),
            control_hz: 10.0,
            time_scale: 1.0,
            common_heading_deg: 90.0,
            compass_deviation_deg: 0.0,
            initial_heading_deg: None,
            control_report: Duration::from_secs(2),
            first_reading_timeout: Duration::from_secs(5),
        }
    }
}

impl ScooterRuntimeConfig {
    /// A compass heading in the common frame (radians, counter-clockwise), the configured
    /// deviation added.
    #[must_use]
    pub fn common_heading(&self, h: &Heading) -> f64 {
        let common_yaw = normalize_angle((90.0 - self.common_heading_deg).to_radians());
        normalize_angle(h.yaw_enu_rad() - self.compass_deviation_deg.to_radians() - common_yaw)
    }
}

/// Scooter's devices, opened by the caller (on the process's one clock).
#[derive(Debug)]
pub struct ScooterDevices<B, L, C = NoCompass> {
    /// The base: drives and reports odometry.
    pub base: B,
    /// The laser.
    pub laser: L,
    /// The compass, if Scooter has one.
    pub compass: Option<C>,
    /// The base driver's halt signal ([`ima_hal::safety`]): raised if the runtime is
    /// dropped (cancelled) before it could stop the base itself. `None`: no such guard.
    pub halt: Option<HaltSignal>,
}

/// The compass type of a Scooter without one (it cannot be constructed).
#[derive(Debug, Clone, Copy)]
pub enum NoCompass {}

impl ErrorType for NoCompass {
    type Error = core::convert::Infallible;
}

impl Compass for NoCompass {
    async fn heading(&mut self) -> Result<Stamped<Heading>, Self::Error> {
        match *self {}
    }

    async fn next_heading(&mut self, _after: Instant) -> Result<Stamped<Heading>, Self::Error> {
        match *self {}
    }
}

/// Run Scooter until `stop` asks it to end.
///
/// * `cfg` — the runtime's configuration ([`ScooterRuntimeConfig`]);
/// * `devices` — the base, laser and optional compass, already connected (an rFLEX base
///   with its brake released); the laser and compass are read in tasks of their own, the
///   base's odometry once per step;
/// * `link` — broadcasts and SES samples in, what Scooter says out
///   ([`ScooterLink::network`] on a robot, [`ScooterLink::channels`] in a simulation);
/// * `clock` — the process's one clock, the one the devices stamp their readings on;
/// * `events` — where the runtime reports ([`EventKind`]); never blocks;
/// * `stop` — `true` (or the sender dropped) ends the run.
///
/// On every way out the base is stopped: `stop()` at the end of the loop, and the driver's
/// halt signal (`devices.halt`) if that fails or if the returned future is dropped before
/// it finishes. Returns an error only if the run could not start.
pub async fn run<B, L, C>(
    cfg: ScooterRuntimeConfig,
    devices: ScooterDevices<B, L, C>,
    mut link: ScooterLink,
    clock: SharedClock,
    events: Events,
    mut stop: StopRequest,
) -> Result<(), RuntimeError>
where
    B: DifferentialBase + Odometer + Send + 'static,
    L: LaserScanner + Send + 'static,
    C: Compass + Send + 'static,
{
    let time = MissionTime::new(clock, cfg.time_scale);
    let me = cfg.brain.robot_name.clone();
    let ScooterDevices {
        mut base,
        laser,
        compass,
        halt,
    } = devices;
    let guard = HaltOnDrop::new(halt);
    let wait = cfg.first_reading_timeout;

    // The compass, read in its own task; its first heading sets the start heading.
    let (compass_tx, mut compass_rx) = watch::channel::<Option<Stamped<Heading>>>(None);
    let mut tasks = Tasks::default();
    let mut start_heading = None;
    if let Some(mut c) = compass {
        match tokio::time::timeout(wait, c.heading()).await {
            Ok(Ok(h)) => {
                start_heading = Some(cfg.common_heading(&h.value));
                compass_tx.send_replace(Some(h));
                compass_rx.mark_unchanged();
            }
            Ok(Err(e)) => tracing::warn!("compass: no first heading: {e}"),
            Err(_) => tracing::warn!("compass: no first heading in {wait:?}"),
        }
        let next = async move |after| c.next_heading(after).await;
        tasks
            .0
            .push(tokio::spawn(pump("compass", compass_tx, next)));
    }
    let start_heading = start_heading
        .or(cfg.initial_heading_deg.map(f64::to_radians))
        .unwrap_or(0.0);
    // Odometry's heading offset: odometry's θ at start is the start heading.
    let odo_theta = match tokio::time::timeout(wait, base.odometry()).await {
        Ok(Ok(o)) => o.value.theta_rad(),
        Ok(Err(e)) => {
            tracing::warn!("base: no first odometry: {e}");
            0.0
        }
        Err(_) => {
            tracing::warn!("base: no first odometry in {wait:?}");
            0.0
        }
    };
    let mut brain_cfg = cfg.brain.clone();
    brain_cfg.odometry_heading_offset_rad = normalize_angle(start_heading - odo_theta);
    let lost_after = brain_cfg.lost_after;
    let mut brain = ScooterBrain::new(brain_cfg);
    events.emit(
        &time,
        &me,
        EventKind::Connected {
            start_heading_deg: Some(start_heading.to_degrees()),
            manager: None,
        },
    );

    // The laser: the latest scan in a watch channel.
    let (scan_tx, mut scan_rx) = watch::channel::<Option<Stamped<LaserScan>>>(None);
    let mut laser = laser;
    let next = async move |after| laser.next_scan(after).await;
    tasks.0.push(tokio::spawn(pump("laser", scan_tx, next)));

    // The brain steps at control_hz of mission time (at most 50 Hz real).
    let hz = if cfg.control_hz.is_finite() && cfg.control_hz > 0.0 {
        cfg.control_hz
    } else {
        10.0
    };
    let period = Duration::try_from_secs_f64(1.0 / (hz * time.scale()))
        .unwrap_or(Duration::from_millis(100))
        .max(Duration::from_millis(20));
    let mut tick = tokio::time::interval(period);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut st = LoopState::default();
    loop {
        tokio::select! {
            _ = tick.tick() => {}
            () = stopped(&mut stop) => break,
        }
        let now = time.now();
        while let Ok(b) = link.heard.try_recv() {
            st.heard(&b, &mut brain, &mut base, &time, &events, &me, lost_after)
                .await;
        }
        while let Ok(form) = link.ses.try_recv() {
            let planned = brain.handle_ses(&form, now);
            events.emit(
                &time,
                &me,
                EventKind::Ses {
                    records: form.records.len(),
                    planned,
                    target: None,
                },
            );
            st.last_ses = Some((now, form));
        }
        if let Ok(Ok(o)) = tokio::time::timeout(period, base.odometry()).await
            && Some(o.at) != st.last_odo_at
        {
            st.last_odo_at = Some(o.at);
            brain.handle_odometry(&o.value, time.at(o.at));
        }
        if compass_rx.has_changed().unwrap_or(false) {
            let h = *compass_rx.borrow_and_update();
            if let Some(h) = h {
                brain.handle_compass(cfg.common_heading(&h.value), time.at(h.at));
            }
        }
        if scan_rx.has_changed().unwrap_or(false) {
            let scan = scan_rx.borrow_and_update().clone();
            if let Some(scan) = scan {
                brain.handle_laser(&scan.value, time.at(scan.at));
            }
        }
        let out = brain.step(now);
        // Once Scooter has told Skeeter it reached the target it waits there for the end of
        // the mission (or a new target), whatever the brain selects meanwhile.
        let command = if st.reached.is_some() || st.halted {
            VelocityCommand::ZERO
        } else {
            out.command
        };
        // As text at once: a device's error need not be `Send`, and the loop awaits below.
        let refused = base
            .set_velocity(command)
            .await
            .err()
            .map(|e| e.to_string());
        st.base_refusals.note(refused);
        if st
            .last_control
            .is_none_or(|t| now.saturating_duration_since(t) >= cfg.control_report)
        {
            st.last_control = Some(now);
            let dr = brain.dr_position();
            events.emit(
                &time,
                &me,
                EventKind::Control(Control {
                    v_m_s: command.v_m_s,
                    omega_rad_s: command.omega_rad_s,
                    heading_rad: brain.heading(),
                    desired_rad: brain.desired_heading(),
                    dr: [dr.x, dr.y],
                    behaviour: out.behaviour.as_str(),
                    halted: st.halted,
                }),
            );
        }
        // A live console's detail: map, SAN and Peer Agent status.
        if events.detail_due(&mut st.last_detail, now, DETAIL_EVERY) {
            events.emit(&time, &me, EventKind::Map(MapView::of(&brain)));
            let san = SanView::of(brain.san(), out.behaviour.as_str());
            events.emit(&time, &me, EventKind::San(san));
            if let Some(p) = link.peer_status().await {
                events.emit(&time, &me, EventKind::PeerStatus(Box::new(p)));
            }
        }
        let b = out.behaviour.as_str();
        if b != st.last_behaviour {
            events.emit(&time, &me, EventKind::Behaviour(b.to_owned()));
            st.last_behaviour = b;
        }
        for say in out.messages {
            if let ScooterSay::TargetReached { colour } = &say {
                st.reached = Some(colour.clone());
            }
            let Some(mut msg) = say.to_broadcast(&me, &brain.san_summary()) else {
                // RequestHeading: ask Skeeter's manager again (a fresh grant makes Skeeter
                // scan and publish).
                events.emit(&time, &me, EventKind::RequestHeading);
                let _ = link.rerequest.try_send(());
                continue;
            };
            // While a fleet stop holds, the status says so (the brain's module is on hold).
            if st.halted
                && let Broadcast::Status { behaviour, .. } = &mut msg
            {
                FLEET_STOPPED.clone_into(behaviour);
            }
            if !matches!(msg, Broadcast::Status { .. }) {
                events.emit(&time, &me, EventKind::Say(msg.to_string()));
            }
            if link.say.try_send(msg).is_err() {
                tracing::warn!("Scooter's broadcast queue is full or closed: a message is lost");
            }
        }
    }
    drop(tasks);
    match tokio::time::timeout(Duration::from_secs(2), base.stop()).await {
        Ok(Ok(())) => guard.disarm(),
        // Halted by the exit guard already (a signal): the driver stops the base itself on
        // its halt and reports its own failures; the runtime's stop found it gone.
        Ok(Err(e)) if guard.already_halted() && e.kind() == ErrorKind::Disconnected => {
            tracing::debug!("base: halted by the exit guard before the runtime's stop ({e})");
        }
        // The guard halts the driver on the way out.
        Ok(Err(e)) => tracing::warn!("base: stop failed ({e}); halting its driver"),
        Err(_) => tracing::warn!("base: stop unanswered; halting its driver"),
    }
    Ok(())
}

/// How often (mission time) a live console's detail is reported ([`Events::detailed`]).
const DETAIL_EVERY: Duration = Duration::from_millis(500);

/// Tasks aborted when dropped.
#[derive(Default)]
struct Tasks(Vec<tokio::task::JoinHandle<()>>);

impl Drop for Tasks {
    fn drop(&mut self) {
        for t in &self.0 {
            t.abort();
        }
    }
}

/// The loop's own state (the mission decisions around the brain).
#[derive(Default)]
struct LoopState {
    last_behaviour: &'static str,
    last_ses: Option<(Instant, SharedForm)>,
    /// The target Scooter said it reached: the base is held at zero.
    reached: Option<String>,
    last_control: Option<Instant>,
    /// When a console's detail was last reported.
    last_detail: Option<Instant>,
    last_odo_at: Option<Instant>,
    /// A fleet stop holds the base at zero until a fleet resume or a new target.
    halted: bool,
    /// The target the observer (a robot, not the commander) accepted and has not ended, the
    /// observer, and when it was last heard: it works on one target at a time and queues the
    /// commander's next ones behind it.
    observer_target: Option<ObserverTarget>,
    /// The control loop's velocity commands the base refused in a row.
    base_refusals: Refusals,
}

/// A device that fails every call (a lost link, a halted driver, an unplugged laser) is
/// reported once, not on every control tick or read: the first failure and every change of
/// error are logged, and the count when calls go through again.
struct Refusals {
    /// The device, as the log names it.
    what: &'static str,
    /// The last error (its `Debug` text) and how many times in a row it came.
    last: Option<(String, u64)>,
}

/// The control loop's: the base's velocity commands.
impl Default for Refusals {
    fn default() -> Self {
        Self::new("base")
    }
}

impl Refusals {
    fn new(what: &'static str) -> Self {
        Self { what, last: None }
    }

    /// One call: `refused` is the device's error (its `Debug` text), `None` when the call
    /// went through.
    fn note(&mut self, refused: Option<String>) {
        let what = self.what;
        match (refused, &mut self.last) {
            (Some(text), Some((last, n))) if text == *last => *n += 1,
            (Some(text), Some((last, n))) => {
                tracing::warn!("{what}: {text} (after {n} failure(s): {last})");
                self.last = Some((text, 1));
            }
            (Some(text), None) => {
                tracing::warn!("{what}: {text} (further failures of the same kind are counted)");
                self.last = Some((text, 1));
            }
            (None, Some((last, n))) => {
                tracing::info!("{what}: working again after {n} failure(s) ({last})");
                self.last = None;
            }
            (None, None) => {}
        }
    }

    /// Refusals in a row so far.
    #[cfg(test)]
    fn count(&self) -> u64 {
        self.last.as_ref().map_or(0, |(_, n)| *n)
    }
}

/// The loop's end (usually after a halt) says how the last run of refusals ended.
impl Drop for Refusals {
    fn drop(&mut self) {
        if let Some((last, n)) = &self.last
            && *n > 1
        {
            let what = self.what;
            tracing::info!("{what}: {n} failure(s) in a row until the loop ended ({last})");
        }
    }
}

impl LoopState {
    /// A broadcast heard: fleet stops and resumes, then what the brain hears.
    #[allow(clippy::too_many_arguments)]
    async fn heard<B: DifferentialBase>(
        &mut self,
        b: &Broadcast,
        brain: &mut ScooterBrain,
        base: &mut B,
        time: &MissionTime,
        events: &Events,
        me: &str,
        lost_after: Duration,
    ) {
        let now = time.now();
        events.emit(time, me, EventKind::Heard(b.to_string()));
        if let Broadcast::Emergency { robot, emergency } = b {
            match emergency {
                Emergency::FleetStop { reason } => {
                    if !self.halted {
                        self.halted = true;
                        // At once, not at the end of this step.
                        if let Err(e) = base.set_velocity(VelocityCommand::ZERO).await {
                            tracing::warn!("base: {e}");
                        }
                        events.emit(
                            time,
                            me,
                            EventKind::FleetStop {
                                by: robot.clone(),
                                reason: reason.clone(),
                            },
                        );
                    }
                    return;
                }
                Emergency::FleetResume => {
                    if self.halted {
                        self.halted = false;
                        events.emit(
                            time,
                            me,
                            EventKind::FleetResume {
                                by: robot.clone(),
                                target: None,
                            },
                        );
                    }
                    return;
                }
                _ => {}
            }
        }
        self.follow_observer(b, me, now);
        let Some(h) = ScooterHeard::from_broadcast(b, me) else {
            return;
        };
        match &h {
            // Repeats of the current target (several copies are sent) change nothing.
            ScooterHeard::TargetAccepted { colour } if brain.target() == Some(colour) => {}
            // The observer still works on another target and queued this one behind it (a
            // console restarted while a target was in progress): taken when the observer
            // starts it. Taking it at once sent Scooter after it while Skeeter went on
            // with the other until its timeout.
            ScooterHeard::TargetAccepted { colour }
                if b.robot() == COMMANDER
                    && self.observer_target.as_ref().is_some_and(|o| {
                        o.target != *colour && now.saturating_duration_since(o.heard) < lost_after
                    }) => {}
            ScooterHeard::TargetAccepted { colour } => {
                if self.halted {
                    // A new target ends a fleet stop.
                    self.halted = false;
                    events.emit(
                        time,
                        me,
                        EventKind::FleetResume {
                            by: "new target".to_owned(),
                            target: Some(colour.clone()),
                        },
                    );
                }
                brain.handle_heard(&h, now);
                self.reached = None;
                // Skeeter's latest SES already says where the target is.
                if let Some((at, form)) = &self.last_ses
                    && now.saturating_duration_since(*at) < lost_after
                {
                    // At the time it arrived: it is no fresher for being replayed.
                    let planned = brain.handle_ses(form, *at);
                    events.emit(
                        time,
                        me,
                        EventKind::Ses {
                            records: form.records.len(),
                            planned,
                            target: Some(colour.clone()),
                        },
                    );
                }
            }
            ScooterHeard::MissionEnded { .. } => {
                brain.handle_heard(&h, now);
                self.reached = None;
            }
            _ => brain.handle_heard(&h, now),
        }
    }
}

/// A target the observer works on ([`LoopState::observer_target`]).
struct ObserverTarget {
    target: String,
    observer: String,
    /// When the observer was last heard (any broadcast): one silent for the brain's
    /// `lost_after` (gone for good, say) holds back no target of the commander's.
    heard: Instant,
}

impl LoopState {
    /// Track the observer's target: accepted by a robot other than the commander, until
    /// that robot ends it or the commander cancels it.
    fn follow_observer(&mut self, b: &Broadcast, me: &str, now: Instant) {
        if let Some(o) = &mut self.observer_target
            && o.observer == b.robot()
        {
            o.heard = now;
        }
        let ended = match b {
            Broadcast::Mission {
                robot,
                event: MissionEvent::Accepted,
                target,
            } if robot != me && robot != COMMANDER => {
                self.observer_target = Some(ObserverTarget {
                    target: target.clone(),
                    observer: robot.clone(),
                    heard: now,
                });
                return;
            }
            Broadcast::Mission {
                event: MissionEvent::Accomplished | MissionEvent::Failed,
                target,
                ..
            } => target,
            Broadcast::Emergency {
                emergency: Emergency::TargetCancel { colour },
                ..
            } => colour,
            _ => return,
        };
        if self
            .observer_target
            .as_ref()
            .is_some_and(|o| o.target == *ended)
        {
            self.observer_target = None;
        }
    }
}

/// Keep `tx` holding the latest reading `next(after)` gives (each newer than the last); on
/// an error, say so and try again 200 ms later. Ends when nobody listens any more.
async fn pump<T, E: core::fmt::Display>(
    what: &'static str,
    tx: watch::Sender<Option<Stamped<T>>>,
    mut next: impl AsyncFnMut(Instant) -> Result<Stamped<T>, E>,
) {
    let mut after = Instant::ZERO;
    // A device gone for good fails every read: logged once, then counted.
    let mut failures = Refusals::new(what);
    loop {
        // The error is dropped before the pause (a device's error need not be `Send`).
        let failed = match next(after).await {
            Ok(r) => {
                failures.note(None);
                after = r.at;
                if tx.send(Some(r)).is_err() {
                    return;
                }
                false
            }
            Err(e) => {
                failures.note(Some(e.to_string()));
                true
            }
        };
        if failed {
            tokio::time::sleep(Duration::from_millis(200)).await;
        }
    }
}

#[cfg(test)]
mod tests {
    use std::sync::{Arc, Mutex};

    use ima_hal::base::{BaseLimits, Odometry};
    use ima_hal::laser::LaserDescription;
    use ima_hal::time::{Clock, TokioClock};

    use super::*;
    use crate::mission::msg::MissionEvent;

    #[test]
    fn a_base_refusing_every_tick_is_counted_not_logged_each_time() {
        let mut r = Refusals::default();
        r.note(None);
        assert_eq!(r.count(), 0);
        for _ in 0..150 {
            r.note(Some("Disconnected".to_owned()));
        }
        assert_eq!(r.count(), 150);
        assert_eq!(
            r.last.as_ref().map(|(t, _)| t.as_str()),
            Some("Disconnected")
        );
        // Another error starts a new run; a command that goes through ends it.
        r.note(Some("Timeout".to_owned()));
        assert_eq!(r.count(), 1);
        r.note(None);
        assert_eq!(r.count(), 0);
        assert!(r.last.is_none());
    }

    /// What the fake base was told.
    #[derive(Debug, Clone, Copy, PartialEq)]
    enum Cmd {
        Vel(VelocityCommand),
        Stop,
    }

    #[derive(Debug, Clone)]
    struct FakeBase {
        clock: SharedClock,
        log: Arc<Mutex<Vec<Cmd>>>,
    }

    impl ErrorType for FakeBase {
        type Error = core::convert::Infallible;
    }

    impl DifferentialBase for FakeBase {
        fn limits(&self) -> BaseLimits {
            BaseLimits {
                max_v_m_s: 1.0,
                max_omega_rad_s: 1.0,
            }
        }
        async fn enable_motors(&mut self, _on: bool) -> Result<(), Self::Error> {
            Ok(())
        }
        async fn set_velocity(&mut self, cmd: VelocityCommand) -> Result<(), Self::Error> {
            self.log.lock().unwrap().push(Cmd::Vel(cmd));
            Ok(())
        }
        async fn stop(&mut self) -> Result<(), Self::Error> {
            self.log.lock().unwrap().push(Cmd::Stop);
            Ok(())
        }
        async fn emergency_stop(&mut self) -> Result<(), Self::Error> {
            self.stop().await
        }
    }

    impl Odometer for FakeBase {
        async fn odometry(&mut self) -> Result<Stamped<Odometry>, Self::Error> {
            Ok(Stamped::new(self.clock.now(), Odometry::origin()))
        }
        async fn next_odometry(
            &mut self,
            _after: Instant,
        ) -> Result<Stamped<Odometry>, Self::Error> {
            tokio::time::sleep(Duration::from_millis(50)).await;
            self.odometry().await
        }
        async fn reset_odometry(&mut self) -> Result<(), Self::Error> {
            Ok(())
        }
    }

    /// A laser in an empty world (every beam at maximum range), 10 scans a second.
    #[derive(Debug)]
    struct FakeLaser(SharedClock);

    impl ErrorType for FakeLaser {
        type Error = core::convert::Infallible;
    }

    impl LaserScanner for FakeLaser {
        fn description(&self) -> LaserDescription {
            LaserDescription {
                pose: ima_hal::Isometry2::identity(),
                fov_rad: core::f64::consts::PI,
                resolution_rad: core::f64::consts::PI / 180.0,
                beams: 181,
                min_range_m: 0.0,
                max_range_m: 8.0,
                max_scan_rate_hz: 10.0,
            }
        }
        async fn scan(&mut self) -> Result<Stamped<LaserScan>, Self::Error> {
            let mut s = LaserScan::new(0.0, core::f64::consts::PI / 180.0);
            for _ in 0..181 {
                let _ = s.push(8.0, ima_hal::laser::BeamFlags::default());
            }
            Ok(Stamped::new(self.0.now(), s))
        }
        async fn next_scan(&mut self, _after: Instant) -> Result<Stamped<LaserScan>, Self::Error> {
            tokio::time::sleep(Duration::from_millis(100)).await;
            self.scan().await
        }
    }

    fn devices(
        clock: &SharedClock,
        halt: Option<HaltSignal>,
    ) -> (ScooterDevices<FakeBase, FakeLaser>, Arc<Mutex<Vec<Cmd>>>) {
        let log = Arc::new(Mutex::new(Vec::new()));
        (
            ScooterDevices {
                base: FakeBase {
                    clock: clock.clone(),
                    log: Arc::clone(&log),
                },
                laser: FakeLaser(clock.clone()),
                compass: None,
                halt,
            },
            log,
        )
    }

    fn cfg() -> ScooterRuntimeConfig {
        let mut c = ScooterRuntimeConfig::default();
        c.brain.robot_name = "scooter".into();
        c
    }

    /// Scooter's runtime started on the fake devices: its task, the link's far ends, its stop
    /// and the base's command log.
    type Started = (
        tokio::task::JoinHandle<Result<(), RuntimeError>>,
        crate::runtime::link::ScooterLinkEnds,
        watch::Sender<bool>,
        Arc<Mutex<Vec<Cmd>>>,
    );

    /// Start Scooter's runtime on the fake devices with `events`.
    fn started(events: Events) -> Started {
        let clock = TokioClock::shared();
        let (dev, log) = devices(&clock, None);
        let (link, ends) = ScooterLink::channels();
        let (stop_tx, stop) = watch::channel(false);
        let run = tokio::spawn(run(cfg(), dev, link, clock, events, stop));
        (run, ends, stop_tx, log)
    }

    #[tokio::test(start_paused = true)]
    async fn a_stop_request_ends_the_run_with_the_base_stopped() {
        let (events, mut rx) = Events::channel(256);
        let (run, mut ends, stop_tx, log) = started(events);
        // A target from the commander: Scooter hears it and asks for a heading.
        let target = Broadcast::mission("commander", MissionEvent::Accepted, "red");
        ends.heard.send(target.clone()).await.unwrap();
        ends.heard.send(target).await.unwrap();
        tokio::time::sleep(Duration::from_secs(3)).await;
        stop_tx.send(true).unwrap();
        run.await.unwrap().unwrap();
        let log = log.lock().unwrap().clone();
        assert_eq!(log.last(), Some(&Cmd::Stop), "{log:?}");
        assert!(log.iter().filter(|c| matches!(c, Cmd::Vel(_))).count() >= 20);
        let mut kinds = Vec::new();
        while let Some(e) = rx.try_recv() {
            kinds.push(e.name());
        }
        assert_eq!(kinds.first(), Some(&"connected"), "{kinds:?}");
        assert!(kinds.contains(&"control"), "{kinds:?}");
        // The repeated target notice was heard twice but replayed nothing.
        assert_eq!(
            kinds.iter().filter(|k| **k == "heard").count(),
            2,
            "{kinds:?}"
        );
        // Statuses go out on the link (a status at least every second).
        let mut said = Vec::new();
        while let Ok(b) = ends.say.try_recv() {
            said.push(b);
        }
        assert!(
            said.iter().any(|b| matches!(b, Broadcast::Status { .. })),
            "{said:?}"
        );
    }

    #[tokio::test(start_paused = true)]
    async fn a_fleet_stop_holds_the_base_at_zero() {
        let (run, ends, stop_tx, log) = started(Events::log_only());
        ends.heard
            .send(Broadcast::mission(
                "commander",
                MissionEvent::Accepted,
                "red",
            ))
            .await
            .unwrap();
        tokio::time::sleep(Duration::from_secs(1)).await;
        ends.heard
            .send(Broadcast::Emergency {
                robot: "commander".into(),
                emergency: Emergency::FleetStop {
                    reason: "test".into(),
                },
            })
            .await
            .unwrap();
        tokio::time::sleep(Duration::from_millis(300)).await;
        held_at_zero(&log, Duration::from_secs(2)).await;
        stop_tx.send(true).unwrap();
        run.await.unwrap().unwrap();
    }

    /// Every velocity command of the next `span` is zero, and there is one.
    async fn held_at_zero(log: &Arc<Mutex<Vec<Cmd>>>, span: Duration) {
        let n = log.lock().unwrap().len();
        tokio::time::sleep(span).await;
        let after: Vec<Cmd> = log.lock().unwrap()[n..].to_vec();
        assert!(!after.is_empty());
        assert!(
            after.iter().all(|c| *c == Cmd::Vel(VelocityCommand::ZERO)),
            "{after:?}"
        );
    }

    /// A console restarted while the observer worked on a target: the new console's target
    /// is queued by the observer, and Scooter waits for it too (it went after it at once,
    /// ending its fleet stop, while Skeeter went on with the other target until its timeout);
    /// an observer gone silent holds nothing back.
    #[tokio::test(start_paused = true)]
    async fn the_commanders_target_waits_while_the_observer_works_on_another() {
        let (events, mut rx) = Events::channel(4096);
        let (run, ends, stop_tx, log) = started(events);
        let say = |robot: &str, event, target: &str| Broadcast::mission(robot, event, target);
        ends.heard
            .send(say("skeeter", MissionEvent::Accepted, "purple"))
            .await
            .unwrap();
        tokio::time::sleep(Duration::from_secs(1)).await;
        let stop_all = Emergency::FleetStop {
            reason: "interrupted".into(),
        };
        let heard = [
            Broadcast::emergency(COMMANDER, stop_all),
            Broadcast::new_target("blue"),
        ];
        for b in heard {
            ends.heard.send(b).await.unwrap();
        }
        tokio::time::sleep(Duration::from_secs(2)).await;
        let resumed = |rx: &mut crate::runtime::events::EventReceiver| {
            let mut by = Vec::new();
            while let Some(e) = rx.try_recv() {
                if let EventKind::FleetResume { target, .. } = e.kind {
                    by.push(target);
                }
            }
            by
        };
        assert_eq!(
            resumed(&mut rx),
            [],
            "blue taken while Skeeter works on purple"
        );
        held_at_zero(&log, Duration::from_secs(1)).await;
        // Skeeter ends purple and starts blue: now Scooter takes it.
        ends.heard
            .send(say("skeeter", MissionEvent::Failed, "purple"))
            .await
            .unwrap();
        ends.heard
            .send(say("skeeter", MissionEvent::Accepted, "blue"))
            .await
            .unwrap();
        tokio::time::sleep(Duration::from_millis(500)).await;
        assert_eq!(resumed(&mut rx), [Some("blue".to_owned())]);
        // An observer gone silent (for the brain's `lost_after`, 12 s) holds nothing back.
        ends.heard
            .send(say("skeeter", MissionEvent::Accepted, "green"))
            .await
            .unwrap();
        let stop_all = Emergency::FleetStop {
            reason: "again".into(),
        };
        let stop_all = Broadcast::emergency(COMMANDER, stop_all);
        ends.heard.send(stop_all).await.unwrap();
        tokio::time::sleep(Duration::from_secs(13)).await;
        let yellow = Broadcast::new_target("yellow");
        ends.heard.send(yellow).await.unwrap();
        tokio::time::sleep(Duration::from_millis(500)).await;
        assert_eq!(resumed(&mut rx), [Some("yellow".to_owned())]);
        stop_tx.send(true).unwrap();
        run.await.unwrap().unwrap();
    }

    #[tokio::test(start_paused = true)]
    async fn a_dropped_runtime_halts_its_base() {
        let clock = TokioClock::shared();
        let halt = HaltSignal::new();
        let (dev, _log) = devices(&clock, Some(halt.clone()));
        let (link, _ends) = ScooterLink::channels();
        let (_stop_tx, stop) = watch::channel(false);
        let run = tokio::spawn(run(cfg(), dev, link, clock, Events::log_only(), stop));
        tokio::time::sleep(Duration::from_secs(1)).await;
        assert!(!halt.is_requested());
        run.abort();
        let _ = run.await;
        assert!(halt.is_requested());
    }
}

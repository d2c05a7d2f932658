//! Skeeter's runtime: [`SkeeterBrain`] (its SAN) fed by the broadcasts heard, by the Scan
//! node's sweeps ([`crate::mission::scan`] over a [`CameraMux`] and a [`FrameSource`], in a
//! task of their own) and by the grants of its `ses` source; the brain's outputs go to the
//! link (broadcasts, SES samples) and to the scanner.
//!
//! Mission decisions of the loop: Skeeter does not drive, but it stops its base at start
//! and on every fleet stop heard; a grant of its `ses` source is a heading request, and so
//! is a lost batch of manager events ([`SesGrant::Lagged`]: a grant may be among them, so
//! it answers as if one had come).

use core::time::Duration;

use ima_hal::base::DifferentialBase;
use ima_hal::camera::{CameraMux, FrameSource};
use ima_hal::time::SharedClock;
use tokio::sync::mpsc;

use super::events::{EventKind, Events, PeerNote, SanView};
use super::link::{SesGrant, SkeeterLink};
use super::{MissionTime, RuntimeError, StopRequest, stopped};
use crate::mission::msg::{Broadcast, Emergency, SCOOTER_TAG, SES_SOURCE};
use crate::mission::scan::{ScanConfig, ScanReport, Scanner, run_scan};
use crate::mission::skeeter::{SkeeterBrain, SkeeterConfig, SkeeterOutput};
use crate::mission::vision::ColourDb;

/// Skeeter's runtime configuration.
#[derive(Debug, Clone)]
pub struct SkeeterRuntimeConfig {
    /// The brain's configuration (its SAN, timeouts, robot name).
    pub brain: SkeeterConfig,
    /// The Scan node's configuration; its settle and step times are real-time needs of the
    /// hardware, scaled into mission time by the runtime.
    pub scan: ScanConfig,
    /// The colours it recognises.
    pub colours: ColourDb,
    /// Mission time = clock time × this.
    pub time_scale: f64,
}

/// Skeeter's devices, opened by the caller on the process's one clock.
#[derive(Debug)]
pub struct SkeeterDevices<B, M, F> {
    /// Its base (held stopped).
    pub base: B,
    /// The video switcher of its camera head.
    pub mux: M,
    /// The frame grabber.
    pub frames: F,
}

/// How often (mission time) a live console's detail is reported ([`Events::detailed`]).
const DETAIL_EVERY: Duration = Duration::from_secs(1);

/// Run Skeeter until `stop` asks it to end, or its link's manager stops (an error).
///
/// `devices` are connected already; `link` carries broadcasts, grants of its `ses` source
/// and the SES samples it publishes ([`SkeeterLink::network`] on a robot); `clock` is the
/// process's one clock; `events` receives what it does. Its base is stopped at start, on
/// every fleet stop heard, and at the end.
pub async fn run<B, M, F>(
    cfg: SkeeterRuntimeConfig,
    devices: SkeeterDevices<B, M, F>,
    mut link: SkeeterLink,
    clock: SharedClock,
    events: Events,
    mut stop: StopRequest,
) -> Result<(), RuntimeError>
where
    B: DifferentialBase + Send + 'static,
    M: CameraMux + Send + 'static,
    F: FrameSource + Send + 'static,
{
    let time = MissionTime::new(clock, cfg.time_scale);
    let scale = time.scale();
    let me = cfg.brain.robot.clone();
    let SkeeterDevices {
        mut base,
        mut mux,
        mut frames,
    } = devices;
    // Skeeter does not move: make sure its base is stopped.
    if let Err(e) = base.stop().await {
        tracing::warn!("base: {e}");
    }
    events.emit(
        &time,
        &me,
        EventKind::Connected {
            start_heading_deg: None,
            manager: link.manager_addr(),
        },
    );
    // The Scan node runs in mission time: its settle and step times are scaled so that, in
    // real time, they are what the hardware needs.
    let mut scan_cfg = cfg.scan.clone();
    scan_cfg.settle = scan_cfg
        .settle
        .max(mux.settle_time())
        .mul_f64(scale.max(1.0));
    scan_cfg.step_timeout = scan_cfg.step_timeout.mul_f64(scale);
    let mut scanner = Scanner::with_default_ses(scan_cfg, cfg.colours.clone())
        .map_err(|e| RuntimeError::Config(format!("Skeeter's scanner: {e}")))?;
    let mut brain = SkeeterBrain::new(cfg.brain.clone())
        .map_err(|e| RuntimeError::Config(format!("Skeeter's SAN: {e}")))?;
    // The scanner task: one sweep per request.
    let (scan_req_tx, mut scan_req_rx) = mpsc::channel::<()>(1);
    let (report_tx, mut report_rx) = mpsc::channel::<Option<ScanReport>>(1);
    let scan_task = tokio::spawn({
        let time = time.clone();
        async move {
            // Sweeps in a row in which every camera failed (the switcher or the grabber is
            // gone): the next waits, so a dead device is not swept thousands of times a
            // second (it was, with a broadcast and a log line each).
            let mut blind = 0u32;
            while scan_req_rx.recv().await.is_some() {
                if blind > 0 {
                    tokio::time::sleep(blind_backoff(blind)).await;
                }
                let r = run_scan(
                    &mut scanner,
                    &mut mux,
                    &mut frames,
                    |d| tokio::time::sleep(d.div_f64(scale)),
                    || time.now(),
                )
                .await;
                match &r {
                    Some(r) if r.cameras_ok == 0 && r.cameras_failed > 0 => {
                        blind = blind.saturating_add(1);
                        if blind.is_power_of_two() {
                            tracing::warn!(
                                "Skeeter: every camera failed in {blind} sweep(s) in a row; \
                                 the next sweep waits {:?}",
                                blind_backoff(blind)
                            );
                        }
                    }
                    Some(_) => blind = 0,
                    None => {}
                }
                if report_tx.send(r).await.is_err() {
                    return;
                }
            }
        }
    });
    // Broadcasts and SES samples lost to a full queue, warned at the 1st, 2nd, 4th, 8th…
    let (mut said_lost, mut ses_lost) = (0u64, 0u64);
    brain.start(time.now());
    let mut last_behaviour = String::new();
    let mut last_detail: Option<ima_hal::Instant> = None;
    // A fleet stop was heard (reported once; the base is held stopped anyway).
    let mut fleet_stopped = false;
    let result = loop {
        // Carry out the brain's outputs.
        while let Some(out) = brain.poll_output() {
            match out {
                SkeeterOutput::Broadcast(b) => {
                    if !matches!(b, Broadcast::Status { .. }) {
                        events.emit(&time, &me, EventKind::Say(b.to_string()));
                    }
                    if link.say.try_send(b).is_err() {
                        said_lost += 1;
                        if said_lost.is_power_of_two() {
                            tracing::warn!(
                                "Skeeter's broadcast queue is full or closed: {said_lost} \
                                 message(s) lost so far"
                            );
                        }
                    }
                }
                SkeeterOutput::StartScan => {
                    let _ = scan_req_tx.try_send(());
                }
                SkeeterOutput::PublishSes(form) => {
                    let marks = form
                        .records
                        .iter()
                        .map(|r| crate::runtime::events::SesMark {
                            tag: r.object.clone(),
                            azimuth_rad: r.bearing.azimuth_rad,
                            elevation_rad: r.bearing.elevation_rad,
                            range_m: r.range_m.filter(|m| m.is_finite() && *m >= 0.0),
                        })
                        .collect();
                    events.emit(&time, &me, EventKind::SesPublished { marks });
                    if link.publish.try_send(form).is_err() {
                        ses_lost += 1;
                        if ses_lost.is_power_of_two() {
                            tracing::warn!(
                                "Skeeter's SES queue is full or closed: {ses_lost} sample(s) \
                                 lost so far"
                            );
                        }
                    }
                }
            }
        }
        if brain.behaviour() != last_behaviour {
            last_behaviour = brain.behaviour().to_owned();
            events.emit(&time, &me, EventKind::Behaviour(last_behaviour.clone()));
        }
        // A live console's detail: SAN activations and the manager's status, once a second.
        if events.detail_due(&mut last_detail, time.now(), DETAIL_EVERY) {
            let san = SanView::of(brain.network(), brain.behaviour());
            events.emit(&time, &me, EventKind::San(san));
            if let Some(p) = link.peer_status().await {
                events.emit(&time, &me, EventKind::PeerStatus(Box::new(p)));
            }
        }
        let wake = brain.poll_timeout().map(|t| {
            let wait = t.saturating_duration_since(time.now());
            tokio::time::Instant::now() + time.real(wait)
        });
        tokio::select! {
            Some(report) = report_rx.recv() => {
                let now = time.now();
                match report {
                    Some(report) => {
                        events.emit(&time, &me, EventKind::Scan {
                            seen: report.detections.iter().map(|d| d.tag().to_owned()).collect(),
                            scooter: report.sees(SCOOTER_TAG),
                            cameras_ok: report.cameras_ok,
                            cameras_failed: report.cameras_failed,
                        });
                        brain.handle_scan(&report, now);
                    }
                    None => brain.handle_timeout(now),
                }
            }
            Some(b) = link.heard.recv() => {
                events.emit(&time, &me, EventKind::Heard(b.to_string()));
                match &b {
                    Broadcast::Emergency { robot, emergency: Emergency::FleetStop { reason } } => {
                        // Skeeter does not drive, but a fleet stop is obeyed by every base
                        // (each copy: stopping twice is harmless).
                        if let Err(e) = base.stop().await {
                            tracing::warn!("base: {e}");
                        }
                        if !fleet_stopped {
                            fleet_stopped = true;
                            events.emit(&time, &me, EventKind::FleetStop { by: robot.clone(), reason: reason.clone() });
                        }
                    }
                    Broadcast::Emergency { robot, emergency: Emergency::FleetResume } if fleet_stopped => {
                        fleet_stopped = false;
                        events.emit(&time, &me, EventKind::FleetResume { by: robot.clone(), target: None });
                    }
                    _ => {}
                }
                brain.handle_broadcast(&b, time.now());
            }
            g = link.grants.recv() => match g {
                Some(SesGrant::Granted { to }) => {
                    events.emit(&time, &me, EventKind::Peer(PeerNote::Granted {
                        granted: SES_SOURCE.to_owned(), priority: None, manager: None, again: None, to: Some(to),
                    }));
                    brain.handle_heading_request(time.now());
                }
                // Some manager events were missed: a grant may be among them, so answer as if.
                Some(SesGrant::Lagged { missed }) => {
                    events.emit(&time, &me, EventKind::Lagged { input: "manager events".to_owned(), missed });
                    brain.handle_heading_request(time.now());
                }
                None => break Err(RuntimeError::Net("Skeeter's Peer Agent manager stopped".to_owned())),
            },
            () = async {
                match wake {
                    Some(w) => tokio::time::sleep_until(w).await,
                    None => std::future::pending().await,
                }
            } => brain.handle_timeout(time.now()),
            () = stopped(&mut stop) => break Ok(()),
        }
    };
    scan_task.abort();
    if let Err(e) = tokio::time::timeout(Duration::from_secs(2), base.stop()).await {
        tracing::warn!("base: stop unanswered: {e}");
    }
    link.shutdown().await;
    result
}

/// How long the sweep after `blind` blind sweeps in a row waits (real time): 0.5 s, doubling,
/// at most 4 s (so the first sweep after the cameras come back waits at most that long).
fn blind_backoff(blind: u32) -> Duration {
    Duration::from_millis(500).saturating_mul(1 << blind.saturating_sub(1).min(3))
}

#[cfg(test)]
mod tests {
    use std::sync::{Arc, Mutex};

    use ima_hal::base::{BaseLimits, VelocityCommand};
    use ima_hal::camera::{Channel, Frame, Selection};
    use ima_hal::time::{Clock, TokioClock};
    use ima_hal::{ErrorType, Stamped};
    use tokio::sync::watch;

    use super::*;
    use crate::mission::msg::MissionEvent;

    /// A base that counts its stops.
    #[derive(Debug, Clone, Default)]
    struct Base(Arc<Mutex<u32>>);

    impl ErrorType for Base {
        type Error = core::convert::Infallible;
    }

    impl DifferentialBase for Base {
        fn limits(&self) -> BaseLimits {
            BaseLimits {
                max_v_m_s: 0.5,
                max_omega_rad_s: 1.0,
            }
        }
        async fn enable_motors(&mut self, _on: bool) -> Result<(), Self::Error> {
            Ok(())
        }
        async fn set_velocity(&mut self, _c: VelocityCommand) -> Result<(), Self::Error> {
            Ok(())
        }
        async fn stop(&mut self) -> Result<(), Self::Error> {
            *self.0.lock().unwrap() += 1;
            Ok(())
        }
        async fn emergency_stop(&mut self) -> Result<(), Self::Error> {
            self.stop().await
        }
    }

    /// A seven-camera switcher that switches at once.
    #[derive(Debug)]
    struct Mux(SharedClock, Channel);

    impl ErrorType for Mux {
        type Error = core::convert::Infallible;
    }

    impl CameraMux for Mux {
        fn channel_count(&self) -> Channel {
            7
        }
        fn settle_time(&self) -> Duration {
            Duration::from_millis(10)
        }
        async fn select(&mut self, channel: Channel) -> Result<Selection, Self::Error> {
            self.1 = channel;
            let now = self.0.now();
            Ok(Selection {
                channel,
                confirmed_at: now,
                settled_at: now,
            })
        }
        async fn current_channel(&mut self) -> Result<Option<Channel>, Self::Error> {
            Ok(Some(self.1))
        }
    }

    /// Black frames: nothing is ever seen.
    #[derive(Debug)]
    struct Frames(SharedClock);

    impl ErrorType for Frames {
        type Error = core::convert::Infallible;
    }

    impl FrameSource for Frames {
        async fn grab(&mut self) -> Result<Stamped<Frame>, Self::Error> {
            tokio::time::sleep(Duration::from_millis(20)).await;
            Ok(Stamped::new(
                self.0.now(),
                Frame::black(64, 48, None).unwrap(),
            ))
        }
    }

    /// A switcher whose port has closed: every call fails at once.
    #[derive(Debug)]
    struct DeadMux(Arc<Mutex<u32>>);

    impl ErrorType for DeadMux {
        type Error = ima_hal::ErrorKind;
    }

    impl CameraMux for DeadMux {
        fn channel_count(&self) -> Channel {
            7
        }
        fn settle_time(&self) -> Duration {
            Duration::from_millis(10)
        }
        async fn select(&mut self, _channel: Channel) -> Result<Selection, Self::Error> {
            *self.0.lock().unwrap() += 1;
            Err(ima_hal::ErrorKind::Disconnected)
        }
        async fn current_channel(&mut self) -> Result<Option<Channel>, Self::Error> {
            Err(ima_hal::ErrorKind::Disconnected)
        }
    }

    /// With its switcher gone every sweep fails at once, and the SAN asks for the next at
    /// once: the sweeps back off (0.5 s, doubling, at most 4 s) instead of running thousands
    /// of times a second with a broadcast and a warning each.
    #[tokio::test(start_paused = true)]
    async fn sweeps_with_every_camera_failed_back_off() {
        let clock = TokioClock::shared();
        let selects = Arc::new(Mutex::new(0));
        let dev = SkeeterDevices {
            base: Base::default(),
            mux: DeadMux(Arc::clone(&selects)),
            frames: Frames(clock.clone()),
        };
        let (run, _ends, mut rx, stop_tx) = started(dev, clock, 100_000).await;
        tokio::time::sleep(Duration::from_secs(60)).await;
        stop_tx.send(true).unwrap();
        run.await.unwrap().unwrap();
        let mut blind = 0;
        while let Some(e) = rx.try_recv() {
            if let EventKind::Scan {
                cameras_ok,
                cameras_failed,
                ..
            } = e.kind
            {
                assert_eq!((cameras_ok, cameras_failed), (0, 7));
                blind += 1;
            }
        }
        // 1 + after 0.5, 1, 2, 4, 4, 4… s: about 18 sweeps in a minute, not thousands.
        assert!((5..=25).contains(&blind), "{blind} blind sweeps in 60 s");
        assert_eq!(*selects.lock().unwrap(), blind * 7);
    }

    /// Skeeter's runtime started on `dev` (events kept: `events`), given the commander's
    /// target red: its task, the link's other ends, its events and its stop request.
    async fn started<B, M, F>(
        dev: SkeeterDevices<B, M, F>,
        clock: SharedClock,
        events: usize,
    ) -> (
        tokio::task::JoinHandle<Result<(), RuntimeError>>,
        crate::runtime::link::SkeeterLinkEnds,
        crate::runtime::EventReceiver,
        watch::Sender<bool>,
    )
    where
        B: DifferentialBase + Send + 'static,
        M: CameraMux + Send + 'static,
        F: FrameSource + Send + 'static,
    {
        let (link, ends) = SkeeterLink::channels();
        let (events, rx) = Events::channel(events);
        let (stop_tx, stop) = watch::channel(false);
        let run = tokio::spawn(run(cfg(), dev, link, clock, events, stop));
        ends.heard
            .send(Broadcast::mission(
                "commander",
                MissionEvent::Accepted,
                "red",
            ))
            .await
            .unwrap();
        (run, ends, rx, stop_tx)
    }

    fn cfg() -> SkeeterRuntimeConfig {
        SkeeterRuntimeConfig {
            brain: SkeeterConfig {
                robot: "skeeter".into(),
                ..SkeeterConfig::default()
            },
            scan: ScanConfig {
                robot: "skeeter".into(),
                ..ScanConfig::default()
            },
            colours: ColourDb::default(),
            time_scale: 1.0,
        }
    }

    #[tokio::test(start_paused = true)]
    async fn skeeter_scans_for_a_target_obeys_a_fleet_stop_and_stops_on_a_lost_manager() {
        let clock = TokioClock::shared();
        let stops = Base::default();
        let dev = SkeeterDevices {
            base: stops.clone(),
            mux: Mux(clock.clone(), 1),
            frames: Frames(clock.clone()),
        };
        let (run, mut ends, mut rx, _stop_tx) = started(dev, clock, 1024).await;
        tokio::time::sleep(Duration::from_secs(5)).await;
        ends.heard
            .send(Broadcast::Emergency {
                robot: "commander".into(),
                emergency: Emergency::FleetStop {
                    reason: "test".into(),
                },
            })
            .await
            .unwrap();
        // A lost batch of manager events is answered as a heading request.
        ends.grants
            .send(SesGrant::Lagged { missed: 3 })
            .await
            .unwrap();
        tokio::time::sleep(Duration::from_secs(1)).await;
        let before_end = *stops.0.lock().unwrap();
        // At start and on the fleet stop.
        assert!(before_end >= 2, "{before_end}");
        // The manager is gone: the runtime ends with an error, its base stopped.
        drop(ends.grants);
        let r = run.await.unwrap();
        assert!(matches!(r, Err(RuntimeError::Net(_))), "{r:?}");
        assert_eq!(*stops.0.lock().unwrap(), before_end + 1);
        let mut kinds = Vec::new();
        while let Some(e) = rx.try_recv() {
            kinds.push(e.name());
        }
        for k in ["connected", "scan", "fleet-stop", "lagged"] {
            assert!(kinds.contains(&k), "{k} missing from {kinds:?}");
        }
        // Skeeter said something (its acceptance of the target, statuses).
        assert!(ends.say.try_recv().is_ok());
    }
}

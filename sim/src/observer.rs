//! Skeeter's observations of the world: the SES samples Scooter receives (see the
//! [crate docs](crate), step 1). One [`SesObserver`] serves both loops — the reference
//! [`ScooterSim`](crate::ScooterSim) and the runtime in virtual time (`crate::runtime`) —
//! so they see the same model.

use core::f64::consts::PI;
use core::time::Duration;

use ima_agents::mission::vision::{ColourDb, DetectorConfig, HeadGeometry, observe_frame};
use ima_agents::ses::Direction;
use ima_agents::ses::shared::{SharedForm, SharedRecord};
use ima_hal::{Instant, normalize_angle};
use ima_mock_devices::camera::{CameraConfig, CameraHead};
use ima_mock_devices::world::{RobotId, SharedWorld, Target, World, gaussian};
use rand::rngs::SmallRng;

use crate::{CAMERAS, Observer, SesTiming, SimConfig, SimError};

/// The camera pipeline: a copy of the world the mock head renders from, the head, and the
/// vision's colour database.
struct CameraRig {
    world: SharedWorld,
    head: CameraHead,
    db: ColourDb,
    geometry: HeadGeometry,
    detector: DetectorConfig,
}

impl core::fmt::Debug for CameraRig {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("CameraRig").finish_non_exhaustive()
    }
}

/// Skeeter's 7-camera head looking at the world on a schedule ([`SesTiming`]) and
/// assembling SES samples ([`SharedForm`]s, the payload of Skeeter's `ses` source).
#[derive(Debug)]
pub struct SesObserver {
    skeeter: RobotId,
    scooter: RobotId,
    scooter_name: String,
    timing: SesTiming,
    camera_range_m: f64,
    bearing_noise_rad: f64,
    ses_ranges: bool,
    range_noise_rel: f64,
    camera_period: Duration,
    next_grab: Instant,
    grab_index: u32,
    pending: Vec<SharedRecord>,
    camera: Option<CameraRig>,
}

impl SesObserver {
    /// Skeeter (robot `skeeter` of `world`) observing, with Scooter (robot `scooter`)
    /// recorded under `scooter_name`; the first scheduled grab is one camera period after
    /// `now`.
    ///
    /// # Errors
    /// [`SimError`] when a robot is missing or a period fails [`SimConfig::check_periods`].
    pub fn new(
        world: &World,
        cfg: &SimConfig,
        scooter_name: &str,
        now: Instant,
    ) -> Result<Self, SimError> {
        let skeeter = world
            .robot_id("skeeter")
            .ok_or(SimError::NoRobot("skeeter"))?;
        let scooter = world
            .robot_id("scooter")
            .ok_or(SimError::NoRobot("scooter"))?;
        cfg.check_periods()?;
        let camera_period = match cfg.ses_timing {
            SesTiming::Staggered => cfg.scan_period / CAMERAS,
            SesTiming::Snapshot => cfg.scan_period,
        };
        let camera = (cfg.observer == Observer::Camera).then(|| {
            let shared = SharedWorld::new(world.clone());
            let cam_cfg = CameraConfig {
                seed: cfg.seed,
                ..CameraConfig::default()
            };
            CameraRig {
                head: CameraHead::new(cam_cfg, shared.clone(), skeeter),
                world: shared,
                db: ColourDb::default(),
                geometry: HeadGeometry {
                    cameras: cam_cfg.cameras,
                    fov_deg: cam_cfg.fov_deg,
                    first_yaw_deg: 0.0,
                },
                detector: DetectorConfig::default(),
            }
        });
        Ok(Self {
            skeeter,
            scooter,
            scooter_name: scooter_name.to_owned(),
            timing: cfg.ses_timing,
            camera_range_m: cfg.camera_range_m,
            bearing_noise_rad: cfg.bearing_noise_rad,
            ses_ranges: cfg.ses_ranges,
            range_noise_rel: cfg.range_noise_rel,
            camera_period,
            next_grab: now + camera_period,
            grab_index: 0,
            pending: Vec::new(),
            camera,
        })
    }

    /// Camera `c`'s sector contains common-frame bearing `b`.
    fn camera_of(b: f64) -> u32 {
        let sector = 2.0 * PI / f64::from(CAMERAS);
        let k = (normalize_angle(b) / sector).round();
        (k.rem_euclid(f64::from(CAMERAS))) as u32
    }

    fn noisy_range(&self, r: f64, rng: &mut SmallRng) -> Option<f64> {
        self.ses_ranges
            .then(|| (r * (1.0 + self.range_noise_rel * gaussian(rng))).max(0.0))
    }

    /// The sample of every camera at once, stamped `now` (the scan that answered the
    /// commander's request at the start).
    pub fn full_look(&mut self, world: &World, now: Instant, rng: &mut SmallRng) -> SharedForm {
        let mut records = Vec::new();
        for c in 0..CAMERAS {
            self.observe(world, c, now, rng, &mut records);
        }
        form(records, now)
    }

    /// The samples completed by `now` (grabs due up to `now` are made on `world` as it is),
    /// stamped `now`, oldest first. Call at least once per camera period.
    pub fn poll(&mut self, world: &World, now: Instant, rng: &mut SmallRng) -> Vec<SharedForm> {
        let mut out = Vec::new();
        while self.timing == SesTiming::Snapshot && self.next_grab <= now {
            out.push(self.full_look(world, now, rng));
            self.next_grab = self.next_grab + self.camera_period;
        }
        while self.next_grab <= now {
            let at = self.next_grab;
            let mut recs = core::mem::take(&mut self.pending);
            self.observe(world, self.grab_index, at, rng, &mut recs);
            self.grab_index += 1;
            if self.grab_index >= CAMERAS {
                self.grab_index = 0;
                out.push(form(recs, now));
            } else {
                self.pending = recs;
            }
            self.next_grab = at + self.camera_period;
        }
        out
    }

    /// What camera `c` (0-based; mux channel `c + 1`) sees now, appended to `out`.
    fn observe(
        &mut self,
        world: &World,
        c: u32,
        now: Instant,
        rng: &mut SmallRng,
        out: &mut Vec<SharedRecord>,
    ) {
        if let Some(rig) = self.camera.as_mut() {
            *rig.world.lock() = world.clone();
            let channel = u8::try_from(c + 1).unwrap_or(1);
            let settled = Duration::from_secs(1);
            if let Some(frame) = rig.head.render(channel, settled) {
                for o in observe_frame(&frame, channel, &rig.db, &rig.geometry, &rig.detector) {
                    let confidence = o.confidence();
                    out.push(SharedRecord {
                        object: o.tag,
                        // Skeeter's robot frame is the common frame.
                        bearing: Direction::horizontal(o.bearing_rad),
                        range_m: if self.ses_ranges { o.range_m } else { None },
                        confidence,
                        time: now,
                    });
                }
            }
            return;
        }
        let Some(sk) = world.robot(self.skeeter).map(|r| r.pose()) else {
            return;
        };
        let sightings = world.visible_objects(sk, PI, self.camera_range_m, Some(self.skeeter));
        for s in sightings {
            if Self::camera_of(s.bearing_rad) != c {
                continue;
            }
            let Some(colour) = world.objects().get(s.object).map(|o| o.color.clone()) else {
                continue;
            };
            let bearing = s.bearing_rad + self.bearing_noise_rad * gaussian(rng);
            let range_m = self.noisy_range(s.range_m, rng);
            out.push(SharedRecord {
                object: colour,
                bearing: Direction::horizontal(bearing),
                range_m,
                confidence: 1.0,
                time: now,
            });
        }
        if let Some(sc) = world.robot(self.scooter).map(|r| r.pose()) {
            let (ex, ey) = (sc.x_m - sk.x_m, sc.y_m - sk.y_m);
            let range = ex.hypot(ey);
            let abs_dir = ey.atan2(ex);
            let bearing = normalize_angle(abs_dir - sk.theta_rad);
            let visible = range <= self.camera_range_m
                && world
                    .cast_ignoring(sk.point(), abs_dir, range, Some(self.skeeter))
                    .is_some_and(|h| h.target == Target::Robot(self.scooter));
            if visible && Self::camera_of(bearing) == c {
                let b = bearing + self.bearing_noise_rad * gaussian(rng);
                let range_m = self.noisy_range(range, rng);
                out.push(SharedRecord {
                    object: self.scooter_name.clone(),
                    bearing: Direction::horizontal(b),
                    range_m,
                    confidence: 1.0,
                    time: now,
                });
            }
        }
    }
}

fn form(records: Vec<SharedRecord>, now: Instant) -> SharedForm {
    SharedForm {
        source_robot: "skeeter".to_owned(),
        sent_at: now,
        records,
    }
}

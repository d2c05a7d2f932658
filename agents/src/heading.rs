//! Heading rules for the scout (Scooter) from the observer's (Skeeter's) SES data.
//!
//! Bearings are angles in the robots' **common frame** (their common initial heading is
//! azimuth 0, counter-clockwise positive, as in the SES), measured at the observer: `θ1` to
//! the scout, `θ2` to the target. Headings come back normalised to (−π, π]. All functions are
//! pure; degenerate geometry is a typed [`Degenerate`], never NaN.
//!
//! * [`thesis_heading`] — the thesis rule exactly (MISSION.md, "The heading algorithm"):
//!   both objects are put on the "SES circle" round the observer, the triangle
//!   observer–scout–target is isosceles, `θ3 = (180° − |θ1 − θ2|)/2` and
//!   `θd = 180° + θ1 ± θ3`, with `−` when the target lies counter-clockwise of the scout as
//!   seen from the observer (`θ2 − θ1 ∈ (0, π)`) and `+` when clockwise. Exact only when the
//!   scout and the target are equally far from the observer.
//! * [`range_aware_heading`] — uses ranges whenever they are known (an SES range, a
//!   sonar/laser range along the bearing) and otherwise *estimates the scout's range* from its
//!   own motion between two SES updates ([`triangulate_scout_range`]: odometry displacement
//!   rotated into the common frame by the compass, against the observer's two bearings to
//!   the scout). With both ranges it is exact; with only one (or none) the isosceles
//!   assumption is the best the geometry allows, and it falls back to the thesis rule and
//!   says so in [`Method`].
//! * [`sonar_range_along`] — the observer's own sonar range along a bearing (a consumer of
//!   [`ima_hal::sonar`]).
//! * [`sweep_48`] — the thesis's 48 start configurations and each rule's initial-heading
//!   error from geometry alone.

use core::f64::consts::PI;

use ima_hal::sonar::{SonarScan, SonarTransducer};
use ima_hal::{Vector2, normalize_angle};

/// Why no heading can be computed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Degenerate {
    /// An input is NaN or infinite, or a range is negative.
    NonFinite,
    /// Thesis rule: the target lies on the scout's bearing (`θ1 = θ2`); on the SES circle
    /// the scout would be at the target, and the side of the turn is undefined.
    SameBearing,
    /// The scout is at the target (within 1 µm): no direction to go.
    AtTarget,
    /// Triangulation: the scout moved less than [`MIN_BASELINE_M`].
    NoMotion,
    /// Triangulation: the observer's bearing to the scout changed by less than
    /// [`MIN_PARALLAX_RAD`], so the range is unobservable (the scout moved radially).
    NoParallax,
    /// Triangulation: the solution puts the scout behind the observer (a negative range):
    /// bearings and displacement disagree.
    Inconsistent,
}

impl core::fmt::Display for Degenerate {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::NonFinite => "non-finite input",
            Self::SameBearing => "target on the scout's bearing",
            Self::AtTarget => "scout is at the target",
            Self::NoMotion => "scout did not move enough to triangulate",
            Self::NoParallax => "bearing to the scout did not change enough to triangulate",
            Self::Inconsistent => "bearings and displacement disagree",
        })
    }
}

impl std::error::Error for Degenerate {}

/// Shortest scout displacement used for triangulation, metres.
pub const MIN_BASELINE_M: f64 = 0.01;
/// Smallest change of the observer's bearing to the scout used for triangulation (0.5°,
/// the compass's accuracy), radians.
pub const MIN_PARALLAX_RAD: f64 = 0.5 * PI / 180.0;
const AT_TARGET_M: f64 = 1e-6;

/// Where a range came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RangeSource {
    /// The SES entry carried a range.
    Ses,
    /// A sonar or laser return along the bearing.
    Sensor,
    /// Triangulated from the scout's own motion ([`triangulate_scout_range`]).
    Triangulated,
}

/// A range in metres with its provenance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Range {
    /// Metres, finite and non-negative.
    pub metres: f64,
    /// Provenance.
    pub source: RangeSource,
}

/// How a heading was obtained.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Method {
    /// The thesis's isosceles rule.
    Thesis,
    /// Both ranges known: exact geometry.
    Ranges {
        /// Source of the observer–scout range.
        scout: RangeSource,
        /// Source of the observer–target range.
        target: RangeSource,
    },
    /// The range-aware rule had to fall back to the thesis rule.
    ThesisFallback {
        /// The observer–scout range was unknown and could not be triangulated.
        scout_missing: bool,
        /// The observer–target range was unknown.
        target_missing: bool,
    },
}

/// A desired heading (common frame, radians in (−π, π]) and how it was obtained.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeadingEstimate {
    /// Desired heading θd.
    pub heading_rad: f64,
    /// Method used.
    pub method: Method,
}

/// The scout's motion between two SES updates, for [`triangulate_scout_range`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScoutMotion {
    /// The observer's bearing to the scout at the earlier update, radians.
    pub previous_scout_bearing_rad: f64,
    /// The scout's displacement since then, in the common frame, metres (odometry distance
    /// rotated by the compass heading).
    pub displacement_m: Vector2,
}

/// Everything the range-aware rule may use.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Observation {
    /// θ1: observer's bearing to the scout, radians.
    pub scout_bearing_rad: f64,
    /// θ2: observer's bearing to the target, radians.
    pub target_bearing_rad: f64,
    /// Observer–scout range, if measured.
    pub scout_range: Option<Range>,
    /// Observer–target range, if measured.
    pub target_range: Option<Range>,
    /// The scout's motion since the previous update, if any.
    pub motion: Option<ScoutMotion>,
}

impl Observation {
    /// Bearings only.
    #[must_use]
    pub fn bearings(scout_bearing_rad: f64, target_bearing_rad: f64) -> Self {
        Self {
            scout_bearing_rad,
            target_bearing_rad,
            scout_range: None,
            target_range: None,
            motion: None,
        }
    }
}

fn unit(theta: f64) -> Vector2 {
    Vector2::new(theta.cos(), theta.sin())
}

fn cross(a: &Vector2, b: &Vector2) -> f64 {
    a.x * b.y - a.y * b.x
}

/// The thesis rule: `θ3 = (π − |θ1 − θ2|)/2`, `θd = π + θ1 ∓ θ3` (see the module docs for
/// the side), normalised to (−π, π]. `|θ1 − θ2|` is the angular difference in [0, π].
///
/// # Errors
/// [`Degenerate::NonFinite`] or [`Degenerate::SameBearing`].
pub fn thesis_heading(scout_bearing_rad: f64, target_bearing_rad: f64) -> Result<f64, Degenerate> {
    if !(scout_bearing_rad.is_finite() && target_bearing_rad.is_finite()) {
        return Err(Degenerate::NonFinite);
    }
    let delta = normalize_angle(target_bearing_rad - scout_bearing_rad);
    if delta.abs() <= 1e-12 {
        return Err(Degenerate::SameBearing);
    }
    let theta3 = (PI - delta.abs()) / 2.0;
    // Target counter-clockwise of the scout (delta > 0): turn clockwise from "towards the
    // observer", i.e. subtract θ3. delta = π gives θ3 = 0 and either side agrees.
    Ok(normalize_angle(
        PI + scout_bearing_rad - delta.signum() * theta3,
    ))
}

/// The thesis rule with angles in degrees at the edge (result in (−180°, 180°]).
///
/// # Errors
/// As [`thesis_heading`].
pub fn thesis_heading_deg(
    scout_bearing_deg: f64,
    target_bearing_deg: f64,
) -> Result<f64, Degenerate> {
    thesis_heading(
        scout_bearing_deg.to_radians(),
        target_bearing_deg.to_radians(),
    )
    .map(f64::to_degrees)
}

/// The turn `θd − θh` from the current heading to the desired one, in (−π, π].
#[must_use]
pub fn turn(desired_rad: f64, current_rad: f64) -> f64 {
    normalize_angle(desired_rad - current_rad)
}

/// Exact heading from the scout to the target given both ranges.
///
/// # Errors
/// [`Degenerate::NonFinite`] (also for a negative range) or [`Degenerate::AtTarget`].
pub fn heading_from_ranges(
    scout_bearing_rad: f64,
    scout_range_m: f64,
    target_bearing_rad: f64,
    target_range_m: f64,
) -> Result<f64, Degenerate> {
    let ok = |r: f64| r.is_finite() && r >= 0.0;
    if !(scout_bearing_rad.is_finite()
        && target_bearing_rad.is_finite()
        && ok(scout_range_m)
        && ok(target_range_m))
    {
        return Err(Degenerate::NonFinite);
    }
    let d = unit(target_bearing_rad) * target_range_m - unit(scout_bearing_rad) * scout_range_m;
    if d.norm() <= AT_TARGET_M {
        return Err(Degenerate::AtTarget);
    }
    Ok(d.y.atan2(d.x))
}

/// The observer–scout range *now*, from the observer's bearings to the scout before (`θa`)
/// and after (`θb`) a known displacement `d` of the scout: solves
/// `ρb·u(θb) − ρa·u(θa) = d`, so `ρb = (u(θa) × d) / sin(θb − θa)`.
///
/// # Errors
/// [`Degenerate::NonFinite`], [`Degenerate::NoMotion`], [`Degenerate::NoParallax`] or
/// [`Degenerate::Inconsistent`] (a negative range).
pub fn triangulate_scout_range(
    previous_bearing_rad: f64,
    bearing_rad: f64,
    displacement_m: Vector2,
) -> Result<f64, Degenerate> {
    if !(previous_bearing_rad.is_finite()
        && bearing_rad.is_finite()
        && displacement_m.iter().all(|c| c.is_finite()))
    {
        return Err(Degenerate::NonFinite);
    }
    if displacement_m.norm() < MIN_BASELINE_M {
        return Err(Degenerate::NoMotion);
    }
    let s = normalize_angle(bearing_rad - previous_bearing_rad).sin();
    if s.abs() < MIN_PARALLAX_RAD.sin() {
        return Err(Degenerate::NoParallax);
    }
    let (ua, ub) = (unit(previous_bearing_rad), unit(bearing_rad));
    let rho_b = cross(&ua, &displacement_m) / s;
    let rho_a = cross(&ub, &displacement_m) / s;
    if rho_a < 0.0 || rho_b < 0.0 || !rho_b.is_finite() {
        return Err(Degenerate::Inconsistent);
    }
    Ok(rho_b)
}

/// The range-aware rule (see the module docs): exact whenever both ranges are known or the
/// scout's range can be triangulated and the target's is known; otherwise the thesis rule,
/// flagged as [`Method::ThesisFallback`].
///
/// # Errors
/// [`Degenerate`] for non-finite inputs, a scout at the target, or (in fallback) a target
/// on the scout's bearing.
pub fn range_aware_heading(obs: &Observation) -> Result<HeadingEstimate, Degenerate> {
    let valid = |r: &Range| r.metres.is_finite() && r.metres >= 0.0;
    if obs.scout_range.is_some_and(|r| !valid(&r)) || obs.target_range.is_some_and(|r| !valid(&r)) {
        return Err(Degenerate::NonFinite);
    }
    let scout = obs.scout_range.or_else(|| {
        let m = obs.motion?;
        triangulate_scout_range(
            m.previous_scout_bearing_rad,
            obs.scout_bearing_rad,
            m.displacement_m,
        )
        .ok()
        .map(|metres| Range {
            metres,
            source: RangeSource::Triangulated,
        })
    });
    match (scout, obs.target_range) {
        (Some(s), Some(t)) => Ok(HeadingEstimate {
            heading_rad: heading_from_ranges(
                obs.scout_bearing_rad,
                s.metres,
                obs.target_bearing_rad,
                t.metres,
            )?,
            method: Method::Ranges {
                scout: s.source,
                target: t.source,
            },
        }),
        (s, t) => Ok(HeadingEstimate {
            heading_rad: thesis_heading(obs.scout_bearing_rad, obs.target_bearing_rad)?,
            method: Method::ThesisFallback {
                scout_missing: s.is_none(),
                target_missing: t.is_none(),
            },
        }),
    }
}

/// The observer's own sonar range along a bearing (robot frame, radians): among the
/// transducers whose beam (axis ± half the beam width) contains the bearing and that report
/// an echo (`min_range_m ≤ r < max_range_m`), the nearest echo, expressed as a distance from
/// the robot centre (the transducer's offset is added along its beam axis). `None` when no
/// beam covers the bearing or none has an echo.
///
/// Caveat: a sonar echo is the nearest reflector in the beam, which may be another object
/// than the one the camera saw on that bearing; callers should check it against the SES
/// (e.g. accept it only within a plausible band).
#[must_use]
pub fn sonar_range_along(
    scan: &SonarScan,
    transducers: &[SonarTransducer],
    bearing_rad: f64,
) -> Option<Range> {
    if !bearing_rad.is_finite() {
        return None;
    }
    scan.readings
        .iter()
        .filter_map(|r| {
            let t = transducers.get(usize::from(r.index))?;
            let axis = t.pose.rotation.angle();
            let covers = normalize_angle(bearing_rad - axis).abs() <= t.beam_width_rad / 2.0;
            let echo =
                r.range_m.is_finite() && r.range_m >= t.min_range_m && r.range_m < t.max_range_m;
            (covers && echo).then(|| (t.pose.translation.vector + unit(axis) * r.range_m).norm())
        })
        .filter(|d| d.is_finite())
        .min_by(f64::total_cmp)
        .map(|metres| Range {
            metres,
            source: RangeSource::Sensor,
        })
}

/// One of the thesis's 48 start configurations and each rule's initial-heading error.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SweepRow {
    /// Angle scout–observer–target, degrees (45, 90 or 135).
    pub angle_deg: f64,
    /// Observer–scout distance Ds, metres.
    pub ds_m: f64,
    /// Observer–target distance Dt, metres.
    pub dt_m: f64,
    /// True heading from the scout to the target, degrees.
    pub true_heading_deg: f64,
    /// |error| of the thesis rule, degrees.
    pub thesis_error_deg: f64,
    /// |error| of the range-aware rule with exact ranges, degrees.
    pub range_exact_error_deg: f64,
    /// Worst |error| of the range-aware rule when each range is off by ±`range_noise_m`.
    pub range_noisy_error_deg: f64,
}

/// The thesis sweep: θ ∈ {45°, 90°, 135°}, Ds, Dt ∈ {2, 3, 4, 5} m. The observer is at the
/// origin, the scout at bearing 0 and distance Ds, the target at bearing +θ and distance Dt
/// (by symmetry the other side gives the same errors). Errors are the absolute angle between
/// the rule's heading and the true one, from geometry alone (no driving). The noisy column
/// takes the worst of the four sign combinations of ±`range_noise_m` on the two ranges.
#[must_use]
pub fn sweep_48(range_noise_m: f64) -> Vec<SweepRow> {
    let mut rows = Vec::with_capacity(48);
    for angle_deg in [45.0_f64, 90.0, 135.0] {
        let th = angle_deg.to_radians();
        for ds in [2.0, 3.0, 4.0, 5.0] {
            for dt in [2.0, 3.0, 4.0, 5.0] {
                let truth = heading_from_ranges(0.0, ds, th, dt).unwrap_or(f64::NAN);
                let err = |h: Result<f64, Degenerate>| {
                    h.map_or(f64::NAN, |h| turn(h, truth).abs().to_degrees())
                };
                let thesis = err(thesis_heading(0.0, th));
                let exact = err(heading_from_ranges(0.0, ds, th, dt));
                let mut noisy: f64 = 0.0;
                for (a, b) in [(1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)] {
                    let e = err(heading_from_ranges(
                        0.0,
                        ds + a * range_noise_m,
                        th,
                        dt + b * range_noise_m,
                    ));
                    noisy = noisy.max(e);
                }
                rows.push(SweepRow {
                    angle_deg,
                    ds_m: ds,
                    dt_m: dt,
                    true_heading_deg: truth.to_degrees(),
                    thesis_error_deg: thesis,
                    range_exact_error_deg: exact,
                    range_noisy_error_deg: noisy,
                });
            }
        }
    }
    rows
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn close(a: f64, b: f64) -> bool {
        turn(a, b).abs() < 1e-9
    }

    #[test]
    fn thesis_rule_worked_examples() {
        // Scout at 0°, target at +90° on the same circle: heading 135°.
        assert!((thesis_heading_deg(0.0, 90.0).unwrap() - 135.0).abs() < 1e-9);
        // Target at −90°: heading 225° = −135°.
        assert!((thesis_heading_deg(0.0, -90.0).unwrap() + 135.0).abs() < 1e-9);
        // Target opposite: straight through the observer.
        assert!((thesis_heading_deg(30.0, 210.0).unwrap() + 150.0).abs() < 1e-9);
        // Wrap-around: scout at 170°, target at −170° (20° counter-clockwise).
        assert!(
            (thesis_heading_deg(170.0, -170.0).unwrap() - (180.0 + 170.0 - 80.0 - 360.0)).abs()
                < 1e-9
        );
        assert_eq!(thesis_heading(1.0, 1.0), Err(Degenerate::SameBearing));
        assert_eq!(thesis_heading(f64::NAN, 1.0), Err(Degenerate::NonFinite));
    }

    #[test]
    fn triangulation_recovers_the_range() {
        // Scout moves from (1, 0) to (1, 1).
        let r = triangulate_scout_range(0.0, PI / 4.0, Vector2::new(0.0, 1.0)).unwrap();
        assert!((r - 2f64.sqrt()).abs() < 1e-12);
        assert_eq!(
            triangulate_scout_range(0.0, 0.0, Vector2::new(1.0, 0.0)),
            Err(Degenerate::NoParallax)
        );
        assert_eq!(
            triangulate_scout_range(0.0, 0.3, Vector2::new(0.0, 0.001)),
            Err(Degenerate::NoMotion)
        );
        // Bearing swings the wrong way for this displacement.
        assert_eq!(
            triangulate_scout_range(0.0, -PI / 4.0, Vector2::new(0.0, 1.0)),
            Err(Degenerate::Inconsistent)
        );
    }

    #[test]
    fn range_aware_methods() {
        let mut o = Observation::bearings(0.0, PI / 2.0);
        let e = range_aware_heading(&o).unwrap();
        assert_eq!(
            e.method,
            Method::ThesisFallback {
                scout_missing: true,
                target_missing: true
            }
        );
        o.target_range = Some(Range {
            metres: 5.0,
            source: RangeSource::Sensor,
        });
        o.scout_bearing_rad = PI / 4.0;
        o.motion = Some(ScoutMotion {
            previous_scout_bearing_rad: 0.0,
            displacement_m: Vector2::new(0.0, 1.0),
        });
        let e = range_aware_heading(&o).unwrap();
        assert_eq!(
            e.method,
            Method::Ranges {
                scout: RangeSource::Triangulated,
                target: RangeSource::Sensor
            }
        );
        // Scout at (1, 1), target at (0, 5).
        assert!(close(e.heading_rad, 4f64.atan2(-1.0)));
        o.scout_range = Some(Range {
            metres: -1.0,
            source: RangeSource::Ses,
        });
        assert_eq!(range_aware_heading(&o), Err(Degenerate::NonFinite));
        assert_eq!(
            heading_from_ranges(0.3, 2.0, 0.3, 2.0),
            Err(Degenerate::AtTarget)
        );
    }

    #[test]
    fn sonar_range_along_picks_the_covering_beam() {
        use ima_hal::sonar::SonarReading;
        use ima_hal::{Instant, Isometry2};
        let tr = |deg: f64| SonarTransducer {
            pose: Isometry2::new(unit(deg.to_radians()) * 0.2, deg.to_radians()),
            min_range_m: 0.1,
            max_range_m: 5.0,
            beam_width_rad: 30f64.to_radians(),
        };
        let transducers = [tr(0.0), tr(20.0), tr(90.0)];
        let mut scan = SonarScan::default();
        for (index, range_m) in [(0, 3.0), (1, 2.0), (2, 5.0)] {
            scan.upsert(SonarReading {
                index,
                range_m,
                at: Instant::ZERO,
            });
        }
        // 10°: both front beams cover it; the nearer echo wins, plus the 0.2 m offset.
        let r = sonar_range_along(&scan, &transducers, 10f64.to_radians()).unwrap();
        assert!((r.metres - 2.2).abs() < 1e-12);
        assert_eq!(r.source, RangeSource::Sensor);
        // -10°: only the 0° beam.
        let r = sonar_range_along(&scan, &transducers, (-10f64).to_radians()).unwrap();
        assert!((r.metres - 3.2).abs() < 1e-12);
        // 90°: the beam reports max range = no echo. 180°: no beam.
        assert_eq!(sonar_range_along(&scan, &transducers, PI / 2.0), None);
        assert_eq!(sonar_range_along(&scan, &transducers, PI), None);
        assert_eq!(sonar_range_along(&scan, &transducers, f64::NAN), None);
    }

    #[test]
    fn sweep_has_48_rows_and_thesis_is_exact_on_the_circle() {
        let rows = sweep_48(0.05);
        assert_eq!(rows.len(), 48);
        for r in &rows {
            assert!(r.range_exact_error_deg < 1e-9);
            assert!(r.thesis_error_deg.is_finite() && r.range_noisy_error_deg.is_finite());
            if r.ds_m == r.dt_m {
                assert!(r.thesis_error_deg < 1e-9, "{r:?}");
            } else {
                assert!(r.thesis_error_deg > 1.0, "{r:?}");
            }
        }
        // Hand check: θ = 90°, Ds = 2, Dt = 5: truth atan2(5, −2) = 111.80°, thesis 135°.
        let r = rows
            .iter()
            .find(|r| r.angle_deg == 90.0 && r.ds_m == 2.0 && r.dt_m == 5.0)
            .unwrap();
        assert!((r.true_heading_deg - 111.801_409).abs() < 1e-5);
        assert!((r.thesis_error_deg - 23.198_591).abs() < 1e-5);
    }

    fn angle() -> impl Strategy<Value = f64> {
        -PI..PI
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(2000))]

        #[test]
        fn thesis_is_exact_on_the_ses_circle(t1 in angle(), t2 in angle(), r in 0.1f64..10.0) {
            prop_assume!(normalize_angle(t2 - t1).abs() > 1e-6);
            let h = thesis_heading(t1, t2).unwrap();
            let truth = heading_from_ranges(t1, r, t2, r).unwrap();
            prop_assert!(turn(h, truth).abs() < 1e-9, "{h} vs {truth}");
        }

        #[test]
        fn range_aware_is_exact_with_exact_ranges(
            t1 in angle(), t2 in angle(), r1 in 0.0f64..10.0, r2 in 0.0f64..10.0
        ) {
            let (s, t) = (unit(t1) * r1, unit(t2) * r2);
            prop_assume!((t - s).norm() > 1e-3);
            let truth = (t - s).y.atan2((t - s).x);
            let o = Observation {
                scout_range: Some(Range { metres: r1, source: RangeSource::Sensor }),
                target_range: Some(Range { metres: r2, source: RangeSource::Ses }),
                ..Observation::bearings(t1, t2)
            };
            let e = range_aware_heading(&o).unwrap();
            prop_assert!(turn(e.heading_rad, truth).abs() < 1e-9);
        }

        #[test]
        fn range_aware_is_exact_with_triangulated_scout_range(
            t2 in angle(), r2 in 0.5f64..8.0,
            sx in -6.0f64..6.0, sy in -6.0f64..6.0, dx in -1.0f64..1.0, dy in -1.0f64..1.0
        ) {
            let before = Vector2::new(sx, sy);
            let d = Vector2::new(dx, dy);
            let now = before + d;
            prop_assume!(before.norm() > 0.3 && now.norm() > 0.3 && d.norm() > 0.05);
            let (ta, tb) = (before.y.atan2(before.x), now.y.atan2(now.x));
            // Bearings that differ by almost 0 or almost π (the scout moved along the line
            // through the observer) leave the triangle degenerate: the rule falls back then.
            prop_assume!(normalize_angle(tb - ta).sin().abs() > 0.02);
            let target = unit(t2) * r2;
            prop_assume!((target - now).norm() > 1e-3);
            let o = Observation {
                target_range: Some(Range { metres: r2, source: RangeSource::Sensor }),
                motion: Some(ScoutMotion { previous_scout_bearing_rad: ta, displacement_m: d }),
                ..Observation::bearings(tb, t2)
            };
            let e = range_aware_heading(&o).unwrap();
            let truth = (target - now).y.atan2((target - now).x);
            prop_assert!(turn(e.heading_rad, truth).abs() < 1e-6, "{:?}", e);
        }

        #[test]
        fn both_rules_are_continuous_away_from_degeneracy(
            t1 in angle(), t2 in angle(), r1 in 0.5f64..8.0, r2 in 0.5f64..8.0,
            e1 in -1e-7f64..1e-7, e2 in -1e-7f64..1e-7
        ) {
            prop_assume!(normalize_angle(t2 - t1).abs() > 1e-3);
            let a = thesis_heading(t1, t2).unwrap();
            let b = thesis_heading(t1 + e1, t2 + e2).unwrap();
            prop_assert!(turn(a, b).abs() < 1e-6);
            let (s, t) = (unit(t1) * r1, unit(t2) * r2);
            prop_assume!((t - s).norm() > 1e-2);
            let a = heading_from_ranges(t1, r1, t2, r2).unwrap();
            let b = heading_from_ranges(t1 + e1, r1 + e2, t2 - e1, r2 - e2).unwrap();
            prop_assert!(turn(a, b).abs() < 1e-4);
        }

        #[test]
        fn never_nan(t1 in proptest::num::f64::ANY, t2 in proptest::num::f64::ANY, r in proptest::num::f64::ANY) {
            if let Ok(h) = thesis_heading(t1, t2) { prop_assert!(h.is_finite()); }
            if let Ok(h) = heading_from_ranges(t1, r, t2, r) { prop_assert!(h.is_finite()); }
            if let Ok(r) = triangulate_scout_range(t1, t2, Vector2::new(r, 1.0)) { prop_assert!(r.is_finite()); }
        }
    }
}

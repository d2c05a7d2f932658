//! Skeeter's vision: a colour database, a blob detector and the pinhole geometry that turns a
//! blob's columns into a bearing and its apparent width into a range.
//!
//! # Colour database
//!
//! A [`ColourDb`] lists the colours the robot looks for (MISSION.md, "The demonstration":
//! "finds the colours of its colour database"), each with a tolerance and the object's real
//! diameter (for ranging). It is data, read from TOML:
//!
//! ```toml
//! [[colour]]
//! name = "red"          # SES tag and shared-form object description
//! rgb = [220, 30, 30]
//! tolerance = 30        # optional, default 30: largest per-channel difference that matches
//! diameter_m = 0.30     # real diameter of the object, metres (0 = unknown: no range)
//! ```
//!
//! [`ColourDb::default`] holds the default world's six object colours (0.30 m cylinders) and
//! the `scooter` marker (white-ish `[235, 235, 235]`, 0.80 m: the ATRV-Jr footprint).
//!
//! # Detector
//!
//! [`find_blobs`] classifies every pixel to the first colour of the database within its
//! tolerance (per channel), then labels 4-connected components of equal colour and keeps
//! those of at least [`DetectorConfig::min_pixels`] pixels. Sensor noise that leaves a pixel
//! within tolerance does not matter; isolated wrong pixels (salt-and-pepper noise, a garbage
//! frame of random bytes) form components far smaller than the threshold and are dropped.
//! No heap beyond one label per pixel and a work stack.
//!
//! # Geometry
//!
//! A pinhole camera of horizontal field of view `fov` on a frame `w` pixels wide has the
//! focal length `f = (w/2) / tan(fov/2)` pixels. A point at column `c` (pixels from the left
//! edge, continuous: pixel `x` spans `[x, x+1)`) lies at the bearing `atan((w/2 − c) / f)`,
//! counter-clockwise from the optical axis (left of centre is positive), and the camera's
//! yaw adds to it ([`HeadGeometry::camera_yaw_rad`]: camera `k` of `n` looks along
//! `first_yaw + (k − 1)·360°/n`, counter-clockwise, camera 1 forward by default).
//!
//! A blob's bearing is that of its pixel centroid's column. Its range comes from its
//! apparent angular width `α` (between the left edge of its leftmost column and the right
//! edge of its rightmost one) and the object's diameter `D`: `r = (D/2) / sin(α/2)`.
//! Discretisation makes the width uncertain by about one pixel, i.e. a relative range error
//! of about `1 / width_px` (≈ 4 % for a 0.30 m object at 3 m with the default 60°, 320 px
//! camera). A blob touching the left or right frame edge is cut off: its range is `None` and
//! its bearing is biased towards the frame's inside (it is marked [`Blob::clipped`]).
//!
//! A blob that a blob of another colour borders on the left or right (at least
//! [`OCCLUSION_MIN_PX`] pixels of the one next to pixels of the other in a row) may be
//! partly hidden by it, or hide part of it: which one is in front does not show in the
//! colours. Both are marked [`Blob::occluded`] and get no range either, since a sliver of a
//! target beside the robot that hides the rest of it would give a range many times too
//! long (a tenth of the width, ten times the range). The check assumes sharp edges, as the
//! mock camera draws them; a real camera's mixed edge pixels can leave a one-pixel gap of
//! unclassified colour between two touching objects, which this check does not bridge.

use core::f64::consts::TAU;

use ima_hal::camera::{Channel, Frame};
use serde::{Deserialize, Serialize};

/// One colour the robot looks for.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ColourSpec {
    /// Name: the SES tag and shared-form object description (e.g. `red`, `scooter`).
    pub name: String,
    /// Nominal colour.
    pub rgb: [u8; 3],
    /// Largest per-channel difference from [`ColourSpec::rgb`] that still matches.
    #[serde(default = "default_tolerance")]
    pub tolerance: u8,
    /// The object's real diameter, metres (`0` = unknown: no range estimate).
    #[serde(default)]
    pub diameter_m: f64,
}

fn default_tolerance() -> u8 {
    30
}

impl ColourSpec {
    /// A colour with the default tolerance.
    #[must_use]
    pub fn new(name: &str, rgb: [u8; 3], diameter_m: f64) -> Self {
        Self {
            name: name.to_owned(),
            rgb,
            tolerance: default_tolerance(),
            diameter_m,
        }
    }

    /// Whether `px` is within tolerance of this colour on every channel.
    #[must_use]
    pub fn matches(&self, px: [u8; 3]) -> bool {
        px.iter()
            .zip(self.rgb)
            .all(|(a, b)| a.abs_diff(b) <= self.tolerance)
    }
}

/// The default world's object diameter (0.15 m radius cylinders), metres.
pub const DEFAULT_OBJECT_DIAMETER_M: f64 = 0.30;
/// Diameter of Scooter's marker in the default world (its 0.40 m footprint radius), metres.
pub const DEFAULT_SCOOTER_DIAMETER_M: f64 = 0.80;
/// Scooter's marker colour in the default world.
pub const DEFAULT_SCOOTER_MARKER: [u8; 3] = [235, 235, 235];

/// A colour database ([module docs](self) for the TOML format).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ColourDb {
    /// The colours, in matching priority order (a pixel goes to the first that matches).
    #[serde(rename = "colour", default)]
    pub colours: Vec<ColourSpec>,
}

impl Default for ColourDb {
    /// The default world's six colours and the `scooter` marker.
    fn default() -> Self {
        let objects: [(&str, [u8; 3]); 6] = [
            ("red", [220, 30, 30]),
            ("green", [30, 180, 60]),
            ("blue", [30, 60, 220]),
            ("yellow", [240, 220, 40]),
            ("orange", [250, 140, 20]),
            ("purple", [140, 40, 170]),
        ];
        let mut colours: Vec<ColourSpec> = objects
            .iter()
            .map(|(n, rgb)| ColourSpec::new(n, *rgb, DEFAULT_OBJECT_DIAMETER_M))
            .collect();
        colours.push(ColourSpec::new(
            crate::mission::msg::SCOOTER_TAG,
            DEFAULT_SCOOTER_MARKER,
            DEFAULT_SCOOTER_DIAMETER_M,
        ));
        Self { colours }
    }
}

/// Why a colour database was refused.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ColourDbError {
    /// The TOML did not parse or did not match the schema.
    Toml(String),
    /// A colour has an empty name, or one with whitespace (names travel as single words).
    BadName(String),
    /// Two colours share a name.
    Duplicate(String),
    /// A diameter is negative or not finite.
    BadDiameter(String),
}

impl core::fmt::Display for ColourDbError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Toml(e) => write!(f, "colour database: {e}"),
            Self::BadName(n) => write!(f, "colour database: bad colour name {n:?}"),
            Self::Duplicate(n) => write!(f, "colour database: duplicate colour {n:?}"),
            Self::BadDiameter(n) => write!(f, "colour database: bad diameter of {n:?}"),
        }
    }
}

impl std::error::Error for ColourDbError {}

impl ColourDb {
    /// A database of these colours.
    ///
    /// # Errors
    /// As [`ColourDb::validate`].
    pub fn new(colours: Vec<ColourSpec>) -> Result<Self, ColourDbError> {
        let db = Self { colours };
        db.validate()?;
        Ok(db)
    }

    /// Parse and validate TOML.
    ///
    /// # Errors
    /// [`ColourDbError`].
    pub fn from_toml(text: &str) -> Result<Self, ColourDbError> {
        let db: Self = toml::from_str(text).map_err(|e| {
            ColourDbError::Toml(ima_hal::file::located(text, e.span(), e.message()))
        })?;
        db.validate()?;
        Ok(db)
    }

    /// Check names (non-empty, one word, unique) and diameters (finite, ≥ 0).
    ///
    /// # Errors
    /// [`ColourDbError`].
    pub fn validate(&self) -> Result<(), ColourDbError> {
        for (i, c) in self.colours.iter().enumerate() {
            if c.name.is_empty()
                || c.name.chars().any(char::is_whitespace)
                || c.name.len() > crate::ses::shared::MAX_OBJECT_LEN
            {
                return Err(ColourDbError::BadName(c.name.clone()));
            }
            if self.colours.iter().take(i).any(|o| o.name == c.name) {
                return Err(ColourDbError::Duplicate(c.name.clone()));
            }
            if !(c.diameter_m.is_finite() && c.diameter_m >= 0.0) {
                return Err(ColourDbError::BadDiameter(c.name.clone()));
            }
        }
        Ok(())
    }

    /// The colour called `name`.
    #[must_use]
    pub fn get(&self, name: &str) -> Option<&ColourSpec> {
        self.colours.iter().find(|c| c.name == name)
    }

    /// Index of the first colour matching `px`.
    #[must_use]
    pub fn classify(&self, px: [u8; 3]) -> Option<usize> {
        self.colours.iter().position(|c| c.matches(px))
    }
}

/// Settings of the blob detector.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DetectorConfig {
    /// Smallest connected component kept, pixels.
    pub min_pixels: usize,
}

impl Default for DetectorConfig {
    fn default() -> Self {
        Self { min_pixels: 6 }
    }
}

/// A connected region of one colour in a frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Blob {
    /// Index of its colour in the [`ColourDb`].
    pub colour: usize,
    /// Leftmost column.
    pub col_min: u32,
    /// Rightmost column (inclusive).
    pub col_max: u32,
    /// Top row.
    pub row_min: u32,
    /// Bottom row (inclusive).
    pub row_max: u32,
    /// Pixel count.
    pub pixels: usize,
    /// Mean column of its pixel centres (pixel `x` has its centre at `x + 0.5`).
    pub centroid_col: f64,
    /// It touches the left or right frame edge (so it may be cut off).
    pub clipped: bool,
    /// A blob of another colour borders it on the left or right ([module docs](self)), so
    /// one of the two may hide part of the other.
    pub occluded: bool,
}

/// Fewest pixels of a blob that must border another colour's pixels on the left or right
/// for it to count as [`Blob::occluded`] (one is not enough: a noisy pixel could do it).
pub const OCCLUSION_MIN_PX: usize = 2;

impl Blob {
    /// Width in pixels, from the left edge of the leftmost column to the right edge of the
    /// rightmost.
    #[must_use]
    pub fn width_px(&self) -> u32 {
        self.col_max.saturating_sub(self.col_min).saturating_add(1)
    }
}

/// Find the blobs of every database colour in `frame` ([module docs](self)), largest first
/// (ties: by colour, then left to right). An inconsistent frame (pixel buffer of the wrong
/// size) gives no blobs.
#[must_use]
pub fn find_blobs(frame: &Frame, db: &ColourDb, cfg: &DetectorConfig) -> Vec<Blob> {
    let (Ok(w), Ok(h)) = (usize::try_from(frame.width), usize::try_from(frame.height)) else {
        return Vec::new();
    };
    if !frame.is_consistent() || w == 0 || h == 0 || db.colours.is_empty() {
        return Vec::new();
    }
    // Label per pixel: its colour index or NONE, with DONE set once the pixel is assigned
    // to a component (so a later component still sees its neighbours' colours).
    const NONE: u16 = 0x7FFF;
    const DONE: u16 = 0x8000;
    let mut label: Vec<u16> = frame
        .pixels
        .chunks_exact(3)
        .map(|p| match p {
            [r, g, b] => db
                .classify([*r, *g, *b])
                .and_then(|i| u16::try_from(i).ok())
                .filter(|&i| i < NONE)
                .unwrap_or(NONE),
            _ => NONE,
        })
        .collect();
    let mut blobs = Vec::new();
    let mut stack: Vec<usize> = Vec::new();
    for start in 0..label.len() {
        let colour = match label.get(start) {
            Some(&c) if c != NONE && c & DONE == 0 => c,
            _ => continue,
        };
        if let Some(l) = label.get_mut(start) {
            *l |= DONE;
        }
        stack.clear();
        stack.push(start);
        let (mut cmin, mut cmax, mut rmin, mut rmax) = (usize::MAX, 0usize, usize::MAX, 0usize);
        let (mut n, mut sum_x, mut border) = (0usize, 0f64, 0usize);
        // Whether pixel `j` has another database colour than this component's.
        let other = |l: &[u16], j: usize| {
            l.get(j)
                .is_some_and(|&l| ![NONE, colour].contains(&(l & !DONE)))
        };
        while let Some(i) = stack.pop() {
            let (x, y) = (i % w, i / w);
            cmin = cmin.min(x);
            cmax = cmax.max(x);
            rmin = rmin.min(y);
            rmax = rmax.max(y);
            n += 1;
            sum_x += x as f64 + 0.5;
            if (x > 0 && other(&label, i - 1)) || (x + 1 < w && other(&label, i + 1)) {
                border += 1;
            }
            let mut visit = |j: usize| {
                if let Some(l) = label.get_mut(j)
                    && *l == colour
                {
                    *l |= DONE;
                    stack.push(j);
                }
            };
            if x > 0 {
                visit(i - 1);
            }
            if x + 1 < w {
                visit(i + 1);
            }
            if y > 0 {
                visit(i - w);
            }
            if y + 1 < h {
                visit(i + w);
            }
        }
        if n >= cfg.min_pixels.max(1) {
            let u = |v: usize| u32::try_from(v).unwrap_or(u32::MAX);
            blobs.push(Blob {
                colour: usize::from(colour),
                col_min: u(cmin),
                col_max: u(cmax),
                row_min: u(rmin),
                row_max: u(rmax),
                pixels: n,
                centroid_col: sum_x / n as f64,
                clipped: cmin == 0 || cmax + 1 >= w,
                occluded: border >= OCCLUSION_MIN_PX,
            });
        }
    }
    blobs.sort_by(|a, b| {
        b.pixels
            .cmp(&a.pixels)
            .then(a.colour.cmp(&b.colour))
            .then(a.col_min.cmp(&b.col_min))
    });
    blobs
}

/// Focal length in pixels of a pinhole camera `width` pixels wide with horizontal field of
/// view `hfov_rad`: `(width/2) / tan(hfov/2)`; `0` for a field of view outside (0, π).
#[must_use]
pub fn focal_px(width: u32, hfov_rad: f64) -> f64 {
    if !(hfov_rad > 0.0 && hfov_rad < core::f64::consts::PI) {
        return 0.0;
    }
    f64::from(width) / 2.0 / (hfov_rad / 2.0).tan()
}

/// Bearing (radians, counter-clockwise from the optical axis) of the continuous column
/// `col` of a frame `width` pixels wide, field of view `hfov_rad`.
#[must_use]
pub fn bearing_of_column(col: f64, width: u32, hfov_rad: f64) -> f64 {
    let f = focal_px(width, hfov_rad);
    if f <= 0.0 {
        return 0.0;
    }
    ((f64::from(width) / 2.0 - col) / f).atan()
}

/// Range (metres) to the centre of a round object of diameter `diameter_m` that subtends
/// the angle `angular_width_rad`: `(D/2) / sin(α/2)`. `None` for a non-positive diameter or
/// an angle outside (0, π).
#[must_use]
pub fn range_from_angular_width(angular_width_rad: f64, diameter_m: f64) -> Option<f64> {
    let ok_d = diameter_m > 0.0 && diameter_m.is_finite();
    let ok_a = angular_width_rad > 0.0 && angular_width_rad < core::f64::consts::PI;
    if !(ok_d && ok_a) {
        return None;
    }
    Some(diameter_m / 2.0 / (angular_width_rad / 2.0).sin())
}

/// The geometry of an omni-directional camera head: `cameras` cameras at equal spacing,
/// counter-clockwise, camera 1 at `first_yaw_deg` from the robot's forward axis.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct HeadGeometry {
    /// Number of cameras (channels `1..=cameras`).
    pub cameras: Channel,
    /// Horizontal field of view of each camera, degrees.
    pub fov_deg: f64,
    /// Yaw of camera 1, degrees counter-clockwise from the robot's forward axis.
    pub first_yaw_deg: f64,
}

impl Default for HeadGeometry {
    /// Skeeter's head: 7 cameras of 60°, camera 1 forward (as the mock head).
    fn default() -> Self {
        Self {
            cameras: 7,
            fov_deg: 60.0,
            first_yaw_deg: 0.0,
        }
    }
}

impl HeadGeometry {
    /// Horizontal field of view, radians.
    #[must_use]
    pub fn fov_rad(&self) -> f64 {
        self.fov_deg.to_radians()
    }

    /// Optical axis of `channel` relative to the robot's forward axis, radians
    /// counter-clockwise, normalised to (−π, π] (`None` outside `1..=cameras`).
    #[must_use]
    pub fn camera_yaw_rad(&self, channel: Channel) -> Option<f64> {
        if channel == 0 || channel > self.cameras {
            return None;
        }
        Some(ima_hal::normalize_angle(
            self.first_yaw_deg.to_radians()
                + f64::from(channel - 1) * TAU / f64::from(self.cameras),
        ))
    }

    /// Turn a blob seen by `channel` into an observation in the robot's frame.
    #[must_use]
    pub fn observe(
        &self,
        channel: Channel,
        frame_width: u32,
        blob: &Blob,
        colour: &ColourSpec,
    ) -> Option<Observation> {
        let yaw = self.camera_yaw_rad(channel)?;
        let fov = self.fov_rad();
        let bearing_cam = bearing_of_column(blob.centroid_col, frame_width, fov);
        let range_m = if blob.clipped || blob.occluded {
            None
        } else {
            let left = bearing_of_column(f64::from(blob.col_min), frame_width, fov);
            let right =
                bearing_of_column(f64::from(blob.col_max.saturating_add(1)), frame_width, fov);
            range_from_angular_width(left - right, colour.diameter_m)
        };
        Some(Observation {
            tag: colour.name.clone(),
            channel,
            bearing_rad: ima_hal::normalize_angle(yaw + bearing_cam),
            bearing_in_camera_rad: bearing_cam,
            range_m,
            pixels: blob.pixels,
            clipped: blob.clipped,
            occluded: blob.occluded,
        })
    }
}

/// A blob turned into a direction (and maybe a range) in the robot's frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Observation {
    /// Colour name (SES tag).
    pub tag: String,
    /// The camera.
    pub channel: Channel,
    /// Bearing in the robot's frame, radians counter-clockwise from forward, (−π, π].
    pub bearing_rad: f64,
    /// Bearing relative to the camera's optical axis, radians.
    pub bearing_in_camera_rad: f64,
    /// Range estimate, metres (`None` when clipped, occluded or the diameter is unknown).
    pub range_m: Option<f64>,
    /// Pixel count of the blob.
    pub pixels: usize,
    /// The blob touched a frame edge.
    pub clipped: bool,
    /// The blob bordered another colour's ([`Blob::occluded`]).
    pub occluded: bool,
}

impl Observation {
    /// Whether the whole object may not be in the blob (cut by a frame edge or bordered by
    /// another object).
    #[must_use]
    pub fn is_partial(&self) -> bool {
        self.clipped || self.occluded
    }

    /// Confidence posted to the SES: 1 for a whole blob, 0.5 for a
    /// [partial](Self::is_partial) one.
    #[must_use]
    pub fn confidence(&self) -> f64 {
        if self.is_partial() { 0.5 } else { 1.0 }
    }

    /// Whether `self` is a better sighting than `other` of the same thing: a whole blob
    /// beats a [partial](Self::is_partial) one, then the larger blob wins.
    #[must_use]
    pub fn better_than(&self, other: &Observation) -> bool {
        match (self.is_partial(), other.is_partial()) {
            (false, true) => true,
            (true, false) => false,
            _ => self.pixels > other.pixels,
        }
    }
}

/// Detect every database colour in a frame from `channel` and turn the blobs into
/// observations (largest first).
#[must_use]
pub fn observe_frame(
    frame: &Frame,
    channel: Channel,
    db: &ColourDb,
    head: &HeadGeometry,
    cfg: &DetectorConfig,
) -> Vec<Observation> {
    find_blobs(frame, db, cfg)
        .iter()
        .filter_map(|b| head.observe(channel, frame.width, b, db.colours.get(b.colour)?))
        .collect()
}

/// A tiny pinhole renderer for tests (here and in the scan tests): discs on a grey
/// background, drawn as the mock camera head draws them.
#[cfg(test)]
pub(crate) mod testing {
    use super::*;

    /// Draw a disc of `radius_m` at `range_m` and `bearing_rad` (camera frame) in `rgb`:
    /// radius `f·tan(asin(r/d))` on the axis, stretched by perspective off the axis
    /// (`/cos²b` across, `/cos b` up), as the mock camera head draws it.
    pub fn draw_disc(
        frame: &mut Frame,
        hfov_rad: f64,
        bearing_rad: f64,
        range_m: f64,
        radius_m: f64,
        rgb: [u8; 3],
    ) {
        let f = focal_px(frame.width, hfov_rad);
        let cx = f64::from(frame.width) / 2.0 - f * bearing_rad.tan();
        let cy = f64::from(frame.height) / 2.0;
        let c = bearing_rad.cos().abs().max(0.1);
        let r = f * radius_m / (range_m * range_m - radius_m * radius_m).sqrt();
        let (rx, ry) = ((r / (c * c)).max(1.0), (r / c).max(1.0));
        for y in 0..frame.height {
            for x in 0..frame.width {
                let (dx, dy) = (
                    (f64::from(x) + 0.5 - cx) / rx,
                    (f64::from(y) + 0.5 - cy) / ry,
                );
                if dx * dx + dy * dy <= 1.0 {
                    frame.set_pixel(x, y, rgb);
                }
            }
        }
    }

    /// A grey frame.
    pub fn grey(width: u32, height: u32, channel: Option<Channel>) -> Frame {
        let mut f = Frame::black(width, height, channel).unwrap();
        f.pixels.fill(128);
        f
    }

    /// Add uniform noise of ± `n` to every byte (deterministic LCG).
    pub fn add_noise(frame: &mut Frame, n: u8, seed: u64) {
        let mut s = seed.wrapping_mul(6364136223846793005).wrapping_add(1);
        for p in &mut frame.pixels {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let j = i16::try_from((s >> 33) % (2 * u64::from(n) + 1)).unwrap() - i16::from(n);
            *p = (i16::from(*p) + j).clamp(0, 255) as u8;
        }
    }

    /// Replace a fraction of pixels by random colours (salt-and-pepper noise).
    pub fn speckle(frame: &mut Frame, one_in: u64, seed: u64) {
        let mut s = seed ^ 0x9E37_79B9_7F4A_7C15;
        for px in frame.pixels.chunks_exact_mut(3) {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            if (s >> 40).is_multiple_of(one_in) {
                px[0] = (s >> 8) as u8;
                px[1] = (s >> 16) as u8;
                px[2] = (s >> 24) as u8;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::testing::*;
    use super::*;
    use proptest::prelude::*;

    const W: u32 = 320;
    const H: u32 = 240;

    fn fov() -> f64 {
        60f64.to_radians()
    }

    #[test]
    fn default_db_has_the_world_colours_and_scooter() {
        let db = ColourDb::default();
        db.validate().unwrap();
        let names: Vec<&str> = db.colours.iter().map(|c| c.name.as_str()).collect();
        assert_eq!(
            names,
            [
                "red", "green", "blue", "yellow", "orange", "purple", "scooter"
            ]
        );
        assert_eq!(db.get("scooter").unwrap().rgb, [235, 235, 235]);
        // The tolerances do not overlap: no colour's nominal value matches another.
        for a in &db.colours {
            for b in &db.colours {
                if a.name != b.name {
                    assert!(!a.matches(b.rgb), "{} matches {}", a.name, b.name);
                }
            }
            assert!(
                !a.matches([128, 128, 128]),
                "{} matches the background",
                a.name
            );
        }
    }

    #[test]
    fn colour_db_toml_round_trip_and_errors() {
        let db = ColourDb::default();
        let text = toml::to_string(&db).unwrap();
        assert_eq!(ColourDb::from_toml(&text).unwrap(), db);
        let one = "[[colour]]\nname = \"red\"\nrgb = [1, 2, 3]\n";
        let d = ColourDb::from_toml(one).unwrap();
        assert_eq!(d.colours[0].tolerance, 30);
        assert_eq!(d.colours[0].diameter_m, 0.0);
        assert!(matches!(
            ColourDb::from_toml("[[colour]]\nname = \"red\"\n"),
            Err(ColourDbError::Toml(_))
        ));
        assert_eq!(
            ColourDb::from_toml(&format!("{one}{one}")),
            Err(ColourDbError::Duplicate("red".into()))
        );
        assert_eq!(
            ColourDb::from_toml("[[colour]]\nname = \"dark red\"\nrgb = [1, 2, 3]\n"),
            Err(ColourDbError::BadName("dark red".into()))
        );
        assert_eq!(
            ColourDb::from_toml(&format!("{one}diameter_m = -1.0\n")),
            Err(ColourDbError::BadDiameter("red".into()))
        );
        assert!(matches!(
            ColourDb::from_toml(&format!("{one}typo = 1\n")),
            Err(ColourDbError::Toml(_))
        ));
    }

    #[test]
    fn one_red_disc_ahead() {
        let db = ColourDb::default();
        let mut f = grey(W, H, Some(1));
        draw_disc(&mut f, fov(), 0.0, 3.0, 0.15, [220, 30, 30]);
        add_noise(&mut f, 6, 1);
        let blobs = find_blobs(&f, &db, &DetectorConfig::default());
        assert_eq!(blobs.len(), 1, "{blobs:?}");
        let b = &blobs[0];
        assert_eq!(db.colours[b.colour].name, "red");
        assert!((b.centroid_col - 160.0).abs() < 0.5);
        assert!(!b.clipped);
        let head = HeadGeometry::default();
        let o = head.observe(1, W, b, &db.colours[b.colour]).unwrap();
        assert!(o.bearing_rad.abs() < 0.5 / focal_px(W, fov()));
        let r = o.range_m.unwrap();
        assert!((r - 3.0).abs() < 0.15, "{r}");
        assert_eq!(o.confidence(), 1.0);
    }

    #[test]
    fn garbage_frames_and_speckle_give_no_blobs() {
        let db = ColourDb::default();
        // A frame of random bytes, as the grabber delivers before the mux settles.
        let mut f = grey(W, H, None);
        speckle(&mut f, 1, 7);
        assert!(find_blobs(&f, &db, &DetectorConfig::default()).is_empty());
        // Sparse speckle over a real disc: still exactly the disc.
        let mut f = grey(W, H, None);
        draw_disc(&mut f, fov(), 0.2, 4.0, 0.15, [30, 60, 220]);
        speckle(&mut f, 20, 3);
        add_noise(&mut f, 6, 2);
        let blobs = find_blobs(&f, &db, &DetectorConfig::default());
        assert_eq!(blobs.len(), 1, "{blobs:?}");
        let want = bearing_of_column(
            f64::from(W) / 2.0 - focal_px(W, fov()) * 0.2f64.tan(),
            W,
            fov(),
        );
        let got = bearing_of_column(blobs[0].centroid_col, W, fov());
        assert!(
            (got - want).abs() < 1.0 / focal_px(W, fov()),
            "{got} {want}"
        );
    }

    /// A noisy frame of green 3 m away on the axis and Scooter's marker (0.40 m radius)
    /// `range_m` away at `bearing_deg` to the left, drawn over green.
    fn green_and_marker(bearing_deg: f64, range_m: f64) -> Frame {
        let mut f = grey(W, H, Some(2));
        draw_disc(&mut f, fov(), 0.0, 3.0, 0.15, [30, 180, 60]);
        let b = bearing_deg.to_radians();
        draw_disc(&mut f, fov(), b, range_m, 0.40, [235, 235, 235]);
        add_noise(&mut f, 6, 5);
        f
    }

    /// Scooter's marker in front of green hides all but a sliver of it: the sliver is 5 of
    /// the disc's 28 columns, so its width alone would put green 16.7 m away, not 3 m. Both
    /// blobs border each other: neither gets a range, and both are partial.
    #[test]
    fn a_target_partly_hidden_by_the_robot_gets_no_range() {
        let db = ColourDb::default();
        let head = HeadGeometry::default();
        // The marker 1.5 m away, centred 14.6° to the left.
        let f = green_and_marker(14.6, 1.5);
        let blobs = find_blobs(&f, &db, &DetectorConfig::default());
        assert_eq!(blobs.len(), 2, "{blobs:?}");
        let green = blobs
            .iter()
            .find(|b| db.colours[b.colour].name == "green")
            .unwrap();
        assert!(green.width_px() <= 6, "{green:?}");
        for b in &blobs {
            assert!(b.occluded && !b.clipped, "{b:?}");
            let o = head.observe(2, W, b, &db.colours[b.colour]).unwrap();
            assert_eq!(o.range_m, None, "{o:?}");
            assert!(o.is_partial());
            assert_eq!(o.confidence(), 0.5);
        }
        // Without the check the sliver's width would have ranged green far beyond 3 m.
        let whole = Blob {
            occluded: false,
            ..green.clone()
        };
        let r = head
            .observe(2, W, &whole, db.get("green").unwrap())
            .unwrap()
            .range_m;
        assert!(r.unwrap() > 10.0, "{r:?}");
    }

    /// Two discs apart, and a single stray pixel of another colour beside a disc, leave
    /// both whole and ranged.
    #[test]
    fn separate_discs_and_a_stray_pixel_are_not_occlusion() {
        let db = ColourDb::default();
        let head = HeadGeometry::default();
        let mut f = green_and_marker(12.0, 3.0);
        // One red pixel just right of green, on its middle row.
        let green = db.get("green").unwrap();
        let green_right = (0..W)
            .rev()
            .find(|&x| f.pixel(x, H / 2).is_some_and(|p| green.matches(p)))
            .unwrap();
        f.set_pixel(green_right + 1, H / 2, [220, 30, 30]);
        let blobs = find_blobs(&f, &db, &DetectorConfig::default());
        assert_eq!(blobs.len(), 2, "{blobs:?}");
        for b in &blobs {
            assert!(!b.occluded, "{b:?}");
            let o = head.observe(2, W, b, &db.colours[b.colour]).unwrap();
            let r = o.range_m.unwrap();
            assert!((r - 3.0).abs() < 0.2, "{o:?}");
            assert!(!o.is_partial());
        }
    }

    #[test]
    fn clipped_blobs_have_no_range_and_bad_frames_no_blobs() {
        let db = ColourDb::default();
        let mut f = grey(W, H, None);
        // Centre 1° inside the left edge of the field of view.
        draw_disc(&mut f, fov(), 29f64.to_radians(), 2.0, 0.15, [240, 220, 40]);
        let blobs = find_blobs(&f, &db, &DetectorConfig::default());
        assert_eq!(blobs.len(), 1);
        assert!(blobs[0].clipped);
        assert_eq!(blobs[0].col_min, 0);
        let o = HeadGeometry::default()
            .observe(3, W, &blobs[0], db.get("yellow").unwrap())
            .unwrap();
        assert_eq!(o.range_m, None);
        assert_eq!(o.confidence(), 0.5);
        let mut bad = f.clone();
        bad.pixels.pop();
        assert!(find_blobs(&bad, &db, &DetectorConfig::default()).is_empty());
        let empty = Frame::black(0, 0, None).unwrap();
        assert!(find_blobs(&empty, &db, &DetectorConfig::default()).is_empty());
        assert!(
            find_blobs(
                &f,
                &ColourDb { colours: vec![] },
                &DetectorConfig::default()
            )
            .is_empty()
        );
    }

    #[test]
    fn two_colours_and_sizes_sorted_largest_first() {
        let db = ColourDb::default();
        let mut f = grey(W, H, None);
        draw_disc(&mut f, fov(), 0.3, 4.0, 0.15, [140, 40, 170]);
        draw_disc(&mut f, fov(), -0.2, 4.0, 0.4, [235, 235, 235]);
        let obs = observe_frame(
            &f,
            2,
            &db,
            &HeadGeometry::default(),
            &DetectorConfig::default(),
        );
        assert_eq!(obs.len(), 2);
        assert_eq!(obs[0].tag, "scooter");
        assert_eq!(obs[1].tag, "purple");
        let yaw2 = TAU / 7.0;
        assert!((obs[1].bearing_rad - (yaw2 + 0.3)).abs() < 0.01);
        assert!((obs[0].bearing_rad - (yaw2 - 0.2)).abs() < 0.01);
        assert!((obs[0].range_m.unwrap() - 4.0).abs() < 0.2);
    }

    #[test]
    fn head_geometry() {
        let h = HeadGeometry::default();
        assert_eq!(h.camera_yaw_rad(0), None);
        assert_eq!(h.camera_yaw_rad(8), None);
        assert_eq!(h.camera_yaw_rad(1), Some(0.0));
        let y5 = h.camera_yaw_rad(5).unwrap();
        assert!(
            (y5 - (4.0 * TAU / 7.0 - TAU)).abs() < 1e-12,
            "normalised: {y5}"
        );
        assert_eq!(focal_px(320, 0.0), 0.0);
        assert!((focal_px(320, fov()) - 160.0 / (30f64.to_radians()).tan()).abs() < 1e-9);
        assert_eq!(bearing_of_column(160.0, 320, fov()), 0.0);
        assert!(bearing_of_column(0.0, 320, fov()) > 0.0, "left is CCW");
        assert!((bearing_of_column(0.0, 320, fov()) - fov() / 2.0).abs() < 1e-12);
        assert_eq!(range_from_angular_width(0.0, 0.3), None);
        assert_eq!(range_from_angular_width(0.1, 0.0), None);
        let r = range_from_angular_width(2.0 * (0.15f64 / 3.0).asin(), 0.3).unwrap();
        assert!((r - 3.0).abs() < 1e-12);
    }

    proptest! {
        // Each case renders and searches a full frame: fewer cases keep debug runs short.
        #![proptest_config(ProptestConfig::with_cases(96))]

        /// The bearing of a rendered disc is within half a pixel's angle of the truth,
        /// for any disc wholly in view, 1–5 m away, and any camera.
        #[test]
        fn bearing_within_half_a_pixel(
            frac in -0.9f64..0.9,
            range in 1.0f64..5.0,
            radius in 0.1f64..0.4,
            channel in 1u8..=7,
            noise in 0u8..10,
            seed: u64,
        ) {
            let f_px = focal_px(W, fov());
            let r_px = f_px * radius / range;
            // keep the whole disc inside the frame (r_px/cos²(30°) at most)
            let max_b = ((f64::from(W) / 2.0 - r_px * 4.0 / 3.0 - 2.0) / f_px).atan();
            let b = frac * max_b;
            let mut db = ColourDb::default();
            db.colours[1].diameter_m = 2.0 * radius; // green
            let mut f = grey(W, H, Some(channel));
            draw_disc(&mut f, fov(), b, range, radius, [30, 180, 60]);
            add_noise(&mut f, noise, seed);
            let head = HeadGeometry::default();
            let obs = observe_frame(&f, channel, &db, &head, &DetectorConfig::default());
            prop_assert_eq!(obs.len(), 1);
            let o = &obs[0];
            let half_px_angle = 0.5 / f_px;
            let want = ima_hal::normalize_angle(head.camera_yaw_rad(channel).unwrap() + b);
            let err = ima_hal::normalize_angle(o.bearing_rad - want).abs();
            prop_assert!(err <= half_px_angle, "err {} > {}", err, half_px_angle);
            // Range within about one pixel of width (the blob is 2·r_px/cos²b wide).
            let r = o.range_m.unwrap();
            let width = 2.0 * r_px / b.cos().powi(2);
            prop_assert!((r - range).abs() / range < 1.2 / width + 0.005, "{} vs {}", r, range);
        }

        /// Any bytes and sizes: never panics.
        #[test]
        fn any_frame_never_panics(w in 0u32..40, h in 0u32..40, bytes in proptest::collection::vec(any::<u8>(), 0..5000)) {
            let frame = Frame { width: w, height: h, channel: None, pixels: bytes };
            let _ = find_blobs(&frame, &ColourDb::default(), &DetectorConfig { min_pixels: 1 });
        }
    }
}

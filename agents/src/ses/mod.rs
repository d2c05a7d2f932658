//! The Sensory EgoSphere (SES): the robot's short-term spatial memory.
//!
//! A geodesic [`Dome`] centred on the robot indexes tagged, time-stamped [`Entry`]s by
//! direction. A sensing agent posts what it perceived at the vertex nearest the stimulus's
//! direction; other agents query by direction (within an angular radius), by tag or by time
//! window. Entries expire after a time-to-live set per tag, and each vertex holds at most a
//! fixed number of entries (the oldest goes first). Posting again with the same
//! `(tag, source)` replaces the earlier entry, so the SES is a *current-state* memory
//! (research note §1.4).
//!
//! # Frames and units
//!
//! Directions are in the **robot frame**: x forward, y left, z up. **Azimuth** is measured
//! counter-clockwise from +x in the x–y plane (seen from above), normalised to (−π, π];
//! **elevation** is the angle above the x–y plane, in [−π/2, π/2]. So
//! `x = cos(el)·cos(az)`, `y = cos(el)·sin(az)`, `z = sin(el)`. Radians and metres throughout.
//!
//! The SES never reads a clock: times are [`ima_hal::Instant`]s passed by the caller.
//!
//! What robots exchange is the [`shared`] form: a compact, versioned binary list of
//! (object, azimuth, elevation, optional range, time) records tagged with the sender.

pub mod dome;
pub mod shared;

use std::collections::{BTreeSet, HashMap};
use std::time::Duration;

use ima_hal::Instant;

pub use dome::{DEFAULT_FREQUENCY, Dome, DomeError, MAX_FREQUENCY, Vec3, VertexId};

/// A direction in the robot frame (see the [module docs](self) for the convention).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Direction {
    /// Azimuth, radians, counter-clockwise from +x (forward), in (−π, π].
    pub azimuth_rad: f64,
    /// Elevation, radians above the horizontal plane, in [−π/2, π/2].
    pub elevation_rad: f64,
}

impl Direction {
    /// A direction from azimuth and elevation in radians; the azimuth is normalised to
    /// (−π, π] and the elevation clamped to [−π/2, π/2].
    #[must_use]
    pub fn new(azimuth_rad: f64, elevation_rad: f64) -> Self {
        use core::f64::consts::FRAC_PI_2;
        Self {
            azimuth_rad: ima_hal::normalize_angle(azimuth_rad),
            elevation_rad: elevation_rad.clamp(-FRAC_PI_2, FRAC_PI_2),
        }
    }

    /// A horizontal direction (elevation 0).
    #[must_use]
    pub fn horizontal(azimuth_rad: f64) -> Self {
        Self::new(azimuth_rad, 0.0)
    }

    /// A direction from azimuth and elevation in degrees (API edge for people and configs).
    #[must_use]
    pub fn from_degrees(azimuth_deg: f64, elevation_deg: f64) -> Self {
        Self::new(azimuth_deg.to_radians(), elevation_deg.to_radians())
    }

    /// The unit vector `(cos el·cos az, cos el·sin az, sin el)`.
    #[must_use]
    pub fn to_unit(self) -> Vec3 {
        let (se, ce) = self.elevation_rad.sin_cos();
        let (sa, ca) = self.azimuth_rad.sin_cos();
        Vec3::new(ce * ca, ce * sa, se)
    }

    /// The direction of a vector: `az = atan2(y, x)`, `el = atan2(z, √(x²+y²))`. `None` for
    /// a zero or non-finite vector. Straight up/down gets azimuth 0.
    #[must_use]
    pub fn from_vector(v: &Vec3) -> Option<Self> {
        if !v.iter().all(|c| c.is_finite()) || v.norm_squared() == 0.0 {
            return None;
        }
        let h = v.x.hypot(v.y);
        let az = if h == 0.0 { 0.0 } else { v.y.atan2(v.x) };
        Some(Self::new(az, v.z.atan2(h)))
    }

    /// Great-circle angle to `other`, radians in [0, π].
    #[must_use]
    pub fn angle_to(self, other: Self) -> f64 {
        let (a, b) = (self.to_unit(), other.to_unit());
        a.cross(&b).norm().atan2(a.dot(&b))
    }
}

/// What a sensing agent perceived: the entry's payload.
#[derive(Debug, Clone, PartialEq)]
pub struct Payload {
    /// Object description (e.g. a colour name, `"scooter"`).
    pub object: String,
    /// Exact bearing of the stimulus (the vertex is only its index).
    pub bearing: Direction,
    /// Range to the object in metres, if known.
    pub range_m: Option<f64>,
    /// Confidence in [0, 1].
    pub confidence: f64,
}

/// One tagged, time-stamped entry of the SES.
#[derive(Debug, Clone, PartialEq)]
pub struct Entry {
    /// Kind of data (`red`, `scooter`, `sonar`, …).
    pub tag: String,
    /// The agent (or remote robot) that posted it.
    pub source: String,
    /// When the stimulus was sensed.
    pub time: Instant,
    /// What was sensed.
    pub payload: Payload,
    /// The vertex it is stored at (nearest to `payload.bearing`).
    pub vertex: VertexId,
}

/// Why a post was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PostError {
    /// The bearing or the range is not finite, or the range is negative.
    BadGeometry,
    /// The confidence is not in [0, 1].
    BadConfidence,
}

impl core::fmt::Display for PostError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::BadGeometry => "bearing or range is not a finite, non-negative value",
            Self::BadConfidence => "confidence is outside [0, 1]",
        })
    }
}

impl std::error::Error for PostError {}

/// What a successful [`Ses::post`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PostOutcome {
    /// Vertex the entry is stored at.
    pub vertex: VertexId,
    /// An earlier entry with the same `(tag, source)` was replaced.
    pub replaced: bool,
    /// Number of older entries dropped from the vertex to honour the per-vertex cap.
    pub evicted: usize,
}

/// Tunables of an [`Ses`].
#[derive(Debug, Clone, PartialEq)]
pub struct SesConfig {
    /// Dome frequency ([`DEFAULT_FREQUENCY`] = 13).
    pub frequency: u32,
    /// Maximum entries per vertex; posting beyond it drops the oldest there. Default 16.
    pub max_per_vertex: usize,
    /// Time-to-live of entries whose tag has no entry in `ttl_by_tag`; `None` = no expiry.
    /// Default 30 s (six of Skeeter's 5 s scans).
    pub default_ttl: Option<Duration>,
    /// Time-to-live per tag.
    pub ttl_by_tag: HashMap<String, Duration>,
}

impl Default for SesConfig {
    fn default() -> Self {
        Self {
            frequency: DEFAULT_FREQUENCY,
            max_per_vertex: 16,
            default_ttl: Some(Duration::from_secs(30)),
            ttl_by_tag: HashMap::new(),
        }
    }
}

type Slot = u32;

#[derive(Debug, Clone, Default)]
struct TagIndex {
    sources: HashMap<String, Slot>,
    by_time: BTreeSet<(Instant, Slot)>,
}

/// The Sensory EgoSphere. See the [module docs](self).
///
/// Storage: a slab of entries, a per-vertex list, a `(tag, source)` index for replacement, a
/// per-tag set and a time-ordered set, so posting, replacing, tag queries, time-window queries
/// and expiry cost O(log n) plus the size of the answer.
#[derive(Debug, Clone)]
pub struct Ses {
    dome: Dome,
    config: SesConfig,
    slots: Vec<Option<Entry>>,
    free: Vec<Slot>,
    at_vertex: Vec<Vec<Slot>>,
    /// Per tag: source -> slot (the replacement key) and the tag's entries by time. Emptied
    /// indexes are kept so a tag's strings are allocated once.
    tags: HashMap<String, TagIndex>,
    by_time: BTreeSet<(Instant, Slot)>,
}

impl Ses {
    /// An empty SES.
    ///
    /// # Errors
    /// [`DomeError`] if the frequency is out of range.
    pub fn new(config: SesConfig) -> Result<Self, DomeError> {
        let dome = Dome::new(config.frequency)?;
        let at_vertex = vec![Vec::new(); dome.len()];
        Ok(Self {
            dome,
            config,
            slots: Vec::new(),
            free: Vec::new(),
            at_vertex,
            tags: HashMap::new(),
            by_time: BTreeSet::new(),
        })
    }

    /// The dome that indexes this SES.
    #[must_use]
    pub fn dome(&self) -> &Dome {
        &self.dome
    }

    /// The configuration.
    #[must_use]
    pub fn config(&self) -> &SesConfig {
        &self.config
    }

    /// Set the time-to-live of a tag (applies at the next [`Ses::expire`]).
    pub fn set_ttl(&mut self, tag: &str, ttl: Duration) {
        self.config.ttl_by_tag.insert(tag.to_owned(), ttl);
    }

    /// Number of entries stored.
    #[must_use]
    pub fn len(&self) -> usize {
        self.by_time.len()
    }

    /// Whether the SES holds no entry.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.by_time.is_empty()
    }

    /// Store `payload` under `(tag, source)` at the vertex nearest its bearing, replacing any
    /// earlier entry with the same `(tag, source)`. The new entry always lands; if the vertex
    /// then holds more than `max_per_vertex` entries, the oldest *other* entries there go.
    ///
    /// # Errors
    /// [`PostError`] for a non-finite bearing, a negative/non-finite range or a confidence
    /// outside [0, 1]; the SES is unchanged.
    pub fn post(
        &mut self,
        tag: &str,
        source: &str,
        time: Instant,
        payload: Payload,
    ) -> Result<PostOutcome, PostError> {
        let b = payload.bearing;
        if !(b.azimuth_rad.is_finite() && b.elevation_rad.is_finite())
            || payload
                .range_m
                .is_some_and(|r| !(r.is_finite() && r >= 0.0))
        {
            return Err(PostError::BadGeometry);
        }
        if !(0.0..=1.0).contains(&payload.confidence) {
            return Err(PostError::BadConfidence);
        }
        let vertex = self.dome.nearest(&b.to_unit());
        let existing = self
            .tags
            .get(tag)
            .and_then(|t| t.sources.get(source))
            .copied();
        let slot =
            match existing.and_then(|s| Some((s, self.entry(s)?.time, self.entry(s)?.vertex))) {
                // Replace in place: no allocation in the steady state of a sensing agent.
                Some((slot, old_time, old_vertex)) => {
                    if let Some(t) = self.tags.get_mut(tag) {
                        t.by_time.remove(&(old_time, slot));
                        t.by_time.insert((time, slot));
                    }
                    self.by_time.remove(&(old_time, slot));
                    if let Some(list) = self.at_vertex.get_mut(old_vertex as usize) {
                        list.retain(|&s| s != slot);
                    }
                    if let Some(Some(e)) = self.slots.get_mut(slot as usize) {
                        e.time = time;
                        e.payload = payload;
                        e.vertex = vertex;
                    }
                    slot
                }
                None => {
                    let entry = Entry {
                        tag: tag.to_owned(),
                        source: source.to_owned(),
                        time,
                        payload,
                        vertex,
                    };
                    let slot = match self.free.pop() {
                        Some(s) => {
                            if let Some(x) = self.slots.get_mut(s as usize) {
                                *x = Some(entry);
                            }
                            s
                        }
                        None => {
                            self.slots.push(Some(entry));
                            (self.slots.len() - 1) as Slot
                        }
                    };
                    let t = match self.tags.get_mut(tag) {
                        Some(t) => t,
                        None => self.tags.entry(tag.to_owned()).or_default(),
                    };
                    t.sources.insert(source.to_owned(), slot);
                    t.by_time.insert((time, slot));
                    slot
                }
            };
        let replaced = existing.is_some();
        self.by_time.insert((time, slot));
        let mut evicted = 0;
        if let Some(list) = self.at_vertex.get_mut(vertex as usize) {
            list.push(slot);
        }
        while self
            .at_vertex
            .get(vertex as usize)
            .is_some_and(|l| l.len() > self.config.max_per_vertex.max(1))
        {
            let oldest = self.at_vertex.get(vertex as usize).and_then(|l| {
                l.iter()
                    .copied()
                    .filter(|&s| s != slot)
                    .min_by_key(|&s| (self.slot_time(s), s))
            });
            match oldest {
                Some(s) => {
                    self.remove_slot(s);
                    evicted += 1;
                }
                None => break,
            }
        }
        Ok(PostOutcome {
            vertex,
            replaced,
            evicted,
        })
    }

    /// Remove the entry posted under `(tag, source)`; returns it if there was one.
    pub fn remove(&mut self, tag: &str, source: &str) -> Option<Entry> {
        let slot = *self.tags.get(tag)?.sources.get(source)?;
        self.remove_slot(slot)
    }

    /// Drop every entry whose age at `now` exceeds its tag's time-to-live (an entry of age
    /// exactly the TTL survives). Returns how many were dropped.
    pub fn expire(&mut self, now: Instant) -> usize {
        let mut doomed = Vec::new();
        for &(t, slot) in &self.by_time {
            if let Some(Some(e)) = self.slots.get(slot as usize) {
                let ttl = self
                    .config
                    .ttl_by_tag
                    .get(&e.tag)
                    .copied()
                    .or(self.config.default_ttl);
                if ttl.is_some_and(|ttl| now.saturating_duration_since(t) > ttl) {
                    doomed.push(slot);
                }
            }
        }
        for &s in &doomed {
            self.remove_slot(s);
        }
        doomed.len()
    }

    /// The entry posted under `(tag, source)`.
    #[must_use]
    pub fn get(&self, tag: &str, source: &str) -> Option<&Entry> {
        let slot = *self.tags.get(tag)?.sources.get(source)?;
        self.entry(slot)
    }

    /// Entries stored at vertex `v` (oldest first).
    #[must_use]
    pub fn at_vertex(&self, v: VertexId) -> Vec<&Entry> {
        let mut out: Vec<&Entry> = self
            .at_vertex
            .get(v as usize)
            .map(|l| l.iter().filter_map(|&s| self.entry(s)).collect())
            .unwrap_or_default();
        out.sort_by(|a, b| order(a, b));
        out
    }

    /// Entries whose bearing lies within `radius_rad` of `dir` (great-circle angle), oldest
    /// first. Only the vertices that can hold such entries are visited.
    #[must_use]
    pub fn by_direction(&self, dir: Direction, radius_rad: f64) -> Vec<&Entry> {
        if !(radius_rad.is_finite() && radius_rad >= 0.0) {
            return Vec::new();
        }
        let reach = radius_rad + self.dome.cell_radius_rad() + 1e-9;
        let mut out = Vec::new();
        for v in self.dome.within(&dir.to_unit(), reach) {
            for e in self
                .at_vertex
                .get(v as usize)
                .into_iter()
                .flatten()
                .filter_map(|&s| self.entry(s))
            {
                if e.payload.bearing.angle_to(dir) <= radius_rad {
                    out.push(e);
                }
            }
        }
        out.sort_by(|a, b| order(a, b));
        out
    }

    /// Entries with tag `tag`, oldest first.
    #[must_use]
    pub fn by_tag(&self, tag: &str) -> Vec<&Entry> {
        let Some(t) = self.tags.get(tag) else {
            return Vec::new();
        };
        let mut out = Vec::with_capacity(t.by_time.len());
        out.extend(t.by_time.iter().filter_map(|&(_, s)| self.entry(s)));
        out
    }

    /// Entries sensed in the closed window `[from, to]`, oldest first.
    #[must_use]
    pub fn by_time(&self, from: Instant, to: Instant) -> Vec<&Entry> {
        if from > to {
            return Vec::new();
        }
        self.by_time
            .range((from, 0)..=(to, Slot::MAX))
            .filter_map(|&(_, s)| self.entry(s))
            .collect()
    }

    /// Every entry, oldest first.
    pub fn iter(&self) -> impl Iterator<Item = &Entry> {
        self.by_time.iter().filter_map(|&(_, s)| self.entry(s))
    }

    fn entry(&self, slot: Slot) -> Option<&Entry> {
        self.slots.get(slot as usize).and_then(Option::as_ref)
    }

    fn slot_time(&self, slot: Slot) -> Instant {
        self.entry(slot).map_or(Instant::ZERO, |e| e.time)
    }

    fn remove_slot(&mut self, slot: Slot) -> Option<Entry> {
        let e = self.slots.get_mut(slot as usize)?.take()?;
        self.free.push(slot);
        if let Some(t) = self.tags.get_mut(&e.tag) {
            t.sources.remove(&e.source);
            t.by_time.remove(&(e.time, slot));
        }
        self.by_time.remove(&(e.time, slot));
        if let Some(list) = self.at_vertex.get_mut(e.vertex as usize) {
            list.retain(|&s| s != slot);
        }
        Some(e)
    }
}

fn order(a: &Entry, b: &Entry) -> core::cmp::Ordering {
    (a.time, &a.tag, &a.source).cmp(&(b.time, &b.tag, &b.source))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn payload(object: &str, az_deg: f64) -> Payload {
        Payload {
            object: object.into(),
            bearing: Direction::from_degrees(az_deg, 0.0),
            range_m: None,
            confidence: 0.9,
        }
    }

    fn ses() -> Ses {
        Ses::new(SesConfig::default()).unwrap()
    }

    #[test]
    fn convention_x_forward_y_left_z_up() {
        let f = Direction::from_degrees(0.0, 0.0).to_unit();
        assert!((f - Vec3::new(1.0, 0.0, 0.0)).norm() < 1e-12);
        let l = Direction::from_degrees(90.0, 0.0).to_unit();
        assert!((l - Vec3::new(0.0, 1.0, 0.0)).norm() < 1e-12);
        let u = Direction::from_degrees(0.0, 90.0).to_unit();
        assert!((u - Vec3::new(0.0, 0.0, 1.0)).norm() < 1e-12);
        let back = Direction::from_vector(&Vec3::new(-1.0, -1.0, 0.0)).unwrap();
        assert!((back.azimuth_rad.to_degrees() + 135.0).abs() < 1e-12);
        assert_eq!(Direction::from_vector(&Vec3::zeros()), None);
        assert!((Direction::from_degrees(270.0, 0.0).azimuth_rad.to_degrees() + 90.0).abs() < 1e-9);
    }

    #[test]
    fn same_tag_and_source_replaces() {
        let mut s = ses();
        let a = s
            .post(
                "red",
                "vision",
                Instant::from_millis(1),
                payload("red", 10.0),
            )
            .unwrap();
        assert!(!a.replaced);
        let b = s
            .post(
                "red",
                "vision",
                Instant::from_millis(2),
                payload("red", -120.0),
            )
            .unwrap();
        assert!(b.replaced);
        assert_eq!(s.len(), 1);
        assert!(s.at_vertex(a.vertex).is_empty());
        assert_eq!(s.at_vertex(b.vertex).len(), 1);
        // A different source is a different entry.
        s.post(
            "red",
            "peer:scooter",
            Instant::from_millis(3),
            payload("red", 10.0),
        )
        .unwrap();
        assert_eq!(s.by_tag("red").len(), 2);
        assert_eq!(
            s.remove("red", "vision").unwrap().time,
            Instant::from_millis(2)
        );
        assert_eq!(s.len(), 1);
    }

    #[test]
    fn queries_by_direction_tag_and_time() {
        let mut s = ses();
        for (i, az) in [0.0, 5.0, 20.0, 90.0, 179.0, -179.0].iter().enumerate() {
            s.post(
                &format!("t{}", i % 2),
                &format!("src{i}"),
                Instant::from_millis(i as u64),
                payload("o", *az),
            )
            .unwrap();
        }
        let near = s.by_direction(Direction::from_degrees(0.0, 0.0), 10f64.to_radians());
        assert_eq!(near.len(), 2);
        let wrap = s.by_direction(Direction::from_degrees(180.0, 0.0), 2f64.to_radians());
        assert_eq!(wrap.len(), 2);
        assert_eq!(s.by_tag("t0").len(), 3);
        assert_eq!(s.by_tag("t1").len(), 3);
        assert!(s.by_tag("nope").is_empty());
        let w = s.by_time(Instant::from_millis(1), Instant::from_millis(3));
        assert_eq!(
            w.iter().map(|e| e.source.as_str()).collect::<Vec<_>>(),
            ["src1", "src2", "src3"]
        );
        assert!(
            s.by_time(Instant::from_millis(3), Instant::from_millis(1))
                .is_empty()
        );
        assert!(
            s.by_direction(Direction::horizontal(0.0), f64::NAN)
                .is_empty()
        );
        assert_eq!(s.by_direction(Direction::horizontal(0.0), 4.0).len(), 6);
    }

    #[test]
    fn by_direction_matches_a_scan_for_elevated_entries() {
        let mut s = ses();
        let mut k = 0;
        for az in (-180..180).step_by(7) {
            for el in (-90..=90).step_by(11) {
                let p = Payload {
                    bearing: Direction::from_degrees(f64::from(az) + 0.3, f64::from(el)),
                    ..payload("o", 0.0)
                };
                s.post("x", &format!("{k}"), Instant::from_millis(k), p)
                    .unwrap();
                k += 1;
            }
        }
        let q = Direction::from_degrees(33.0, 21.0);
        for r in [0.01, 0.1, 0.3, 1.0] {
            let fast = s.by_direction(q, r).len();
            let scan = s
                .iter()
                .filter(|e| e.payload.bearing.angle_to(q) <= r)
                .count();
            assert_eq!(fast, scan, "radius {r}");
        }
    }

    #[test]
    fn ttl_per_tag_and_default() {
        let mut s = ses();
        s.set_ttl("sonar", Duration::from_secs(1));
        s.post("sonar", "a", Instant::from_millis(0), payload("wall", 0.0))
            .unwrap();
        s.post("red", "b", Instant::from_millis(0), payload("red", 30.0))
            .unwrap();
        assert_eq!(
            s.expire(Instant::from_millis(1000)),
            0,
            "age == ttl survives"
        );
        assert_eq!(s.expire(Instant::from_millis(1001)), 1);
        assert!(s.by_tag("sonar").is_empty());
        assert_eq!(s.expire(Instant::from_millis(30_000)), 0);
        assert_eq!(s.expire(Instant::from_millis(30_001)), 1);
        assert!(s.is_empty());
    }

    #[test]
    fn cap_per_vertex_drops_the_oldest() {
        let mut s = Ses::new(SesConfig {
            max_per_vertex: 3,
            ..SesConfig::default()
        })
        .unwrap();
        for i in 0..5_u64 {
            let out = s
                .post(
                    "red",
                    &format!("s{i}"),
                    Instant::from_millis(10 - i),
                    payload("red", 45.0),
                )
                .unwrap();
            assert_eq!(out.evicted, usize::from(i >= 3));
        }
        let left: Vec<_> = s.iter().map(|e| e.source.as_str()).collect();
        // Times were 10, 9, 8, 7, 6. The new entry always lands; the oldest *other* entry at
        // the vertex goes: s3 evicts s2 (t=8), s4 evicts s3 (t=7).
        assert_eq!(left, ["s4", "s1", "s0"]);
    }

    #[test]
    fn bad_posts_are_refused() {
        let mut s = ses();
        let mut p = payload("x", 0.0);
        p.bearing.azimuth_rad = f64::NAN;
        assert_eq!(
            s.post("t", "s", Instant::ZERO, p),
            Err(PostError::BadGeometry)
        );
        let mut p = payload("x", 0.0);
        p.range_m = Some(-1.0);
        assert_eq!(
            s.post("t", "s", Instant::ZERO, p),
            Err(PostError::BadGeometry)
        );
        let mut p = payload("x", 0.0);
        p.confidence = 1.5;
        assert_eq!(
            s.post("t", "s", Instant::ZERO, p),
            Err(PostError::BadConfidence)
        );
        assert!(s.is_empty());
    }
}

//! The icosahedral geodesic dome that indexes the Sensory EgoSphere.
//!
//! Construction (Class I, "frequency n"): take the 12 vertices of a regular icosahedron, split
//! every one of its 20 faces into an `n × n` triangular grid, and push every grid point out to
//! the unit sphere. The result has `10n² + 2` vertices, `30n²` edges and `20n²` faces; the 12
//! original corners have five neighbours, every other vertex six (research note §1.1–1.2).
//!
//! # Nearest-vertex lookup and why the greedy walk is exact
//!
//! The vertex nearest a unit direction `q` (smallest great-circle angle) is the vertex with the
//! largest dot product `q · v`. That is a *linear* objective over the vertices of the convex
//! polytope spanned by the dome. For a convex polytope, a vertex none of whose polytope-edge
//! neighbours improves a linear objective is a global optimum (the argument behind the simplex
//! method). The dome's triangles triangulate the faces of that polytope — **provided** the
//! triangulated surface is convex, i.e. across every mesh edge the two triangles fold inwards
//! (or lie flat). [`Dome::new`] checks this for every edge and records the answer
//! ([`Dome::is_convex`]); the unit tests confirm it for frequencies 1..=16, 20, 24, 32 and 40 (all of 1..=40 passed once). When it holds,
//! [`Dome::nearest`] walks greedily from a hint to a neighbour with a larger dot product and
//! stops at the global optimum; when it does not hold (never observed), it falls back to the
//! brute-force scan [`Dome::nearest_brute`]. Ties (equal dot products) are broken towards the
//! lower vertex id in both paths, so the walk and the scan agree exactly; a proptest checks
//! this over many random directions and several frequencies.
//!
//! Hints come from a small cube map: each of 6 × `CUBE_CELLS²` cells stores the vertex nearest
//! its centre, so a lookup costs one division, one table read and a walk of a few steps — no
//! trigonometry.

use std::collections::HashMap;

use ima_hal::nalgebra::Vector3;

/// A 3-D vector in the robot frame (x forward, y left, z up).
pub type Vec3 = Vector3<f64>;

/// Index of a vertex of a [`Dome`] (`0 .. dome.len()`). The 12 icosahedron corners are 0..12.
pub type VertexId = u32;

/// Highest frequency [`Dome::new`] accepts (64 gives 40,962 vertices).
pub const MAX_FREQUENCY: u32 = 64;

/// Default frequency of the SES dome: 13 (1,692 vertices, neighbour spacing 4.1–5.8°, mean 5.1°).
///
/// Why 13: the dome is an *index*, not the precision of the memory — every entry keeps its
/// exact bearing in its payload — so the cell only has to be small compared with the angles the
/// agents reason about. A 5° cell is finer than a camera's colour-blob bearing (one of Skeeter's
/// seven cameras covers ~51°, and blob centroids are good to a few degrees) and than a sonar
/// beam (~15–30°), yet coarse enough that a neighbourhood query of ±15° touches only a few
/// dozen vertices and the whole dome fits in ~100 kB. It is also the value the research note
/// half-recalls for ISAC's SES (unverified); the frequency is a constructor parameter.
pub const DEFAULT_FREQUENCY: u32 = 13;

/// Cube-map resolution used for nearest-vertex hints (cells per cube-face side).
const CUBE_CELLS: usize = 16;

/// Why a dome could not be built.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DomeError {
    /// Frequency 0 or above [`MAX_FREQUENCY`].
    BadFrequency(u32),
}

impl core::fmt::Display for DomeError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::BadFrequency(n) => {
                write!(f, "dome frequency {n} is outside 1..={MAX_FREQUENCY}")
            }
        }
    }
}

impl std::error::Error for DomeError {}

/// An icosahedral geodesic dome of frequency `n`: unit vertices, their neighbours and a fast
/// nearest-vertex lookup. See the [module docs](self).
#[derive(Debug, Clone)]
pub struct Dome {
    frequency: u32,
    vertices: Vec<Vec3>,
    /// Neighbour lists, flattened: neighbours of `v` are `nbr[nbr_start[v]..nbr_start[v + 1]]`.
    nbr: Vec<VertexId>,
    nbr_start: Vec<usize>,
    triangles: Vec<[VertexId; 3]>,
    convex: bool,
    cell_radius_rad: f64,
    cube: Vec<VertexId>,
}

/// The 12 corners and 20 outward-wound faces of the icosahedron.
fn icosahedron() -> ([Vec3; 12], [[usize; 3]; 20]) {
    let p = (1.0 + 5.0_f64.sqrt()) / 2.0;
    let raw = [
        [-1.0, p, 0.0],
        [1.0, p, 0.0],
        [-1.0, -p, 0.0],
        [1.0, -p, 0.0],
        [0.0, -1.0, p],
        [0.0, 1.0, p],
        [0.0, -1.0, -p],
        [0.0, 1.0, -p],
        [p, 0.0, -1.0],
        [p, 0.0, 1.0],
        [-p, 0.0, -1.0],
        [-p, 0.0, 1.0],
    ];
    let v = raw.map(|[x, y, z]| Vec3::new(x, y, z).normalize());
    let faces = [
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    (v, faces)
}

impl Dome {
    /// Build the dome of frequency `n` (`10n² + 2` vertices).
    ///
    /// # Errors
    /// [`DomeError::BadFrequency`] unless `1 <= n <= MAX_FREQUENCY`.
    pub fn new(n: u32) -> Result<Self, DomeError> {
        if n == 0 || n > MAX_FREQUENCY {
            return Err(DomeError::BadFrequency(n));
        }
        let (corners, faces) = icosahedron();
        let nn = n as usize;
        let mut vertices: Vec<Vec3> = corners.to_vec();
        // Exact dedup of shared edges: key a grid point by its position as a weighted sum of
        // icosahedron corners, (corner, weight) sorted — identical on both faces of an edge.
        let mut ids: HashMap<[(usize, usize); 3], VertexId> = HashMap::new();
        let mut triangles = Vec::with_capacity(20 * nn * nn);
        for face in faces {
            let [a, b, c] = face;
            // Point (i, j): weight n-i-j on a, i on b, j on c.
            let mut grid = vec![0 as VertexId; (nn + 1) * (nn + 1)];
            for i in 0..=nn {
                for j in 0..=(nn - i) {
                    let wa = nn - i - j;
                    let id = if wa == nn {
                        a as VertexId
                    } else if i == nn {
                        b as VertexId
                    } else if j == nn {
                        c as VertexId
                    } else {
                        let mut key = [(a, wa), (b, i), (c, j)];
                        for k in &mut key {
                            if k.1 == 0 {
                                *k = (usize::MAX, 0);
                            }
                        }
                        key.sort_unstable();
                        *ids.entry(key).or_insert_with(|| {
                            let p = corners[a] * wa as f64
                                + corners[b] * i as f64
                                + corners[c] * j as f64;
                            vertices.push(p.normalize());
                            (vertices.len() - 1) as VertexId
                        })
                    };
                    grid[i * (nn + 1) + j] = id;
                }
            }
            let g = |i: usize, j: usize| grid[i * (nn + 1) + j];
            for i in 0..nn {
                for j in 0..(nn - i) {
                    triangles.push([g(i, j), g(i + 1, j), g(i, j + 1)]);
                    if i + j + 1 < nn {
                        triangles.push([g(i + 1, j), g(i + 1, j + 1), g(i, j + 1)]);
                    }
                }
            }
        }
        let vcount = vertices.len();
        let mut sets: Vec<Vec<VertexId>> = vec![Vec::with_capacity(6); vcount];
        // Edge -> opposite vertices, for the convexity check.
        let mut edges: HashMap<(VertexId, VertexId), Vec<(VertexId, usize)>> = HashMap::new();
        for (t, tri) in triangles.iter().enumerate() {
            for k in 0..3 {
                let (u, w, o) = (tri[k], tri[(k + 1) % 3], tri[(k + 2) % 3]);
                if !sets[u as usize].contains(&w) {
                    sets[u as usize].push(w);
                }
                if !sets[w as usize].contains(&u) {
                    sets[w as usize].push(u);
                }
                edges.entry((u.min(w), u.max(w))).or_default().push((o, t));
            }
        }
        let normal = |t: &[VertexId; 3]| {
            let [a, b, c] = t.map(|i| vertices[i as usize]);
            (b - a).cross(&(c - a))
        };
        let mut convex = edges.len() == 30 * nn * nn;
        for opp in edges.values() {
            if let [(_, t1), (o2, _)] = opp.as_slice() {
                let tri = &triangles[*t1];
                let nrm = normal(tri);
                // Outward winding: the normal points away from the centre.
                let a = vertices[tri[0] as usize];
                if nrm.dot(&a) <= 0.0 || nrm.dot(&(vertices[*o2 as usize] - a)) > 1e-12 {
                    convex = false;
                }
            } else {
                convex = false;
            }
        }
        // Covering bound: max angle from a triangle's circumcentre to its corners.
        let mut cell_radius_rad: f64 = 0.0;
        for tri in &triangles {
            let c = normal(tri).normalize();
            let a = vertices[tri[0] as usize];
            cell_radius_rad = cell_radius_rad.max(c.dot(&a).clamp(-1.0, 1.0).acos());
        }
        let mut nbr_start = Vec::with_capacity(vcount + 1);
        let mut nbr = Vec::with_capacity(6 * vcount);
        for s in &mut sets {
            s.sort_unstable();
            nbr_start.push(nbr.len());
            nbr.extend_from_slice(s);
        }
        nbr_start.push(nbr.len());
        let mut dome = Self {
            frequency: n,
            vertices,
            nbr,
            nbr_start,
            triangles,
            convex,
            cell_radius_rad,
            cube: Vec::new(),
        };
        let mut cube = Vec::with_capacity(6 * CUBE_CELLS * CUBE_CELLS);
        for cell in 0..6 * CUBE_CELLS * CUBE_CELLS {
            cube.push(dome.nearest_brute(&cube_cell_centre(cell)));
        }
        dome.cube = cube;
        Ok(dome)
    }

    /// The frequency `n`.
    #[must_use]
    pub fn frequency(&self) -> u32 {
        self.frequency
    }

    /// Number of vertices, `10n² + 2`.
    #[must_use]
    pub fn len(&self) -> usize {
        self.vertices.len()
    }

    /// Always `false`: a dome has at least 12 vertices.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.vertices.is_empty()
    }

    /// Unit vector of vertex `v`, or `None` if out of range.
    #[must_use]
    pub fn vertex(&self, v: VertexId) -> Option<Vec3> {
        self.vertices.get(v as usize).copied()
    }

    /// All unit vertex vectors, indexed by [`VertexId`].
    #[must_use]
    pub fn vertices(&self) -> &[Vec3] {
        &self.vertices
    }

    /// Neighbours of vertex `v` in ascending id order (5 for the 12 corners, 6 otherwise; empty
    /// if `v` is out of range).
    #[must_use]
    pub fn neighbours(&self, v: VertexId) -> &[VertexId] {
        let v = v as usize;
        match (self.nbr_start.get(v), self.nbr_start.get(v + 1)) {
            (Some(&s), Some(&e)) => self.nbr.get(s..e).unwrap_or(&[]),
            _ => &[],
        }
    }

    /// The `20n²` triangles, each wound counter-clockwise seen from outside.
    #[must_use]
    pub fn triangles(&self) -> &[[VertexId; 3]] {
        &self.triangles
    }

    /// Whether the triangulated dome is convex across every edge (see the module docs); when
    /// it is, the greedy walk is exact.
    #[must_use]
    pub fn is_convex(&self) -> bool {
        self.convex
    }

    /// An upper bound (radians) on the angle from any direction to its nearest vertex.
    #[must_use]
    pub fn cell_radius_rad(&self) -> f64 {
        self.cell_radius_rad
    }

    /// Nearest vertex to the direction `dir` (need not be unit length; a zero or non-finite
    /// vector gives vertex 0). Exact; ties go to the lower id.
    #[must_use]
    pub fn nearest(&self, dir: &Vec3) -> VertexId {
        match cube_cell(dir).and_then(|c| self.cube.get(c)) {
            Some(&hint) => self.nearest_from(dir, hint),
            None => 0,
        }
    }

    /// Nearest vertex to `dir`, walking from `hint` (any vertex; a good hint makes it O(1)).
    /// Exact, same result as [`Dome::nearest_brute`].
    #[must_use]
    pub fn nearest_from(&self, dir: &Vec3, hint: VertexId) -> VertexId {
        if !self.convex || !dir.iter().all(|c| c.is_finite()) {
            return self.nearest_brute(dir);
        }
        let mut best = if (hint as usize) < self.vertices.len() {
            hint
        } else {
            0
        };
        let mut best_dot = self.dot(best, dir);
        loop {
            let mut moved = false;
            for &w in self.neighbours(best) {
                let d = self.dot(w, dir);
                if d > best_dot || (d == best_dot && w < best) {
                    best = w;
                    best_dot = d;
                    moved = true;
                }
            }
            if !moved {
                return best;
            }
        }
    }

    /// Nearest vertex by scanning every vertex: the reference oracle. Ties go to the lower id.
    #[must_use]
    pub fn nearest_brute(&self, dir: &Vec3) -> VertexId {
        let mut best = 0;
        let mut best_dot = f64::NEG_INFINITY;
        for (i, v) in self.vertices.iter().enumerate() {
            let d = v.dot(dir);
            if d > best_dot {
                best = i as VertexId;
                best_dot = d;
            }
        }
        best
    }

    /// Vertices whose direction lies within `radius_rad` of `dir`, found by a breadth-first
    /// search from the nearest vertex (exact: on a convex polytope the vertices inside a cap
    /// form a connected subgraph). Sorted by id.
    #[must_use]
    pub fn within(&self, dir: &Vec3, radius_rad: f64) -> Vec<VertexId> {
        let Some(q) = dir.try_normalize(0.0) else {
            return Vec::new();
        };
        if !radius_rad.is_finite() || radius_rad < 0.0 {
            return Vec::new();
        }
        if radius_rad >= core::f64::consts::PI || !self.convex {
            let c = radius_rad.min(core::f64::consts::PI).cos();
            return (0..self.vertices.len() as VertexId)
                .filter(|&v| self.dot(v, &q) >= c)
                .collect();
        }
        let min_dot = radius_rad.cos();
        let start = self.nearest(&q);
        if self.dot(start, &q) < min_dot {
            return Vec::new();
        }
        let mut seen = vec![false; self.vertices.len()];
        let mut out = vec![start];
        if let Some(s) = seen.get_mut(start as usize) {
            *s = true;
        }
        let mut head = 0;
        while let Some(&v) = out.get(head) {
            head += 1;
            for &w in self.neighbours(v) {
                if let Some(s) = seen.get_mut(w as usize)
                    && !*s
                    && self.dot(w, &q) >= min_dot
                {
                    *s = true;
                    out.push(w);
                }
            }
        }
        out.sort_unstable();
        out
    }

    fn dot(&self, v: VertexId, dir: &Vec3) -> f64 {
        self.vertices
            .get(v as usize)
            .map_or(f64::NEG_INFINITY, |p| p.dot(dir))
    }
}

/// Cube-map cell of a direction, or `None` for a zero/non-finite vector.
fn cube_cell(d: &Vec3) -> Option<usize> {
    let (ax, ay, az) = (d.x.abs(), d.y.abs(), d.z.abs());
    let m = ax.max(ay).max(az);
    if !(d.iter().all(|c| c.is_finite()) && m > 0.0) {
        return None;
    }
    let (face, u, v) = if ax >= ay && ax >= az {
        (usize::from(d.x < 0.0), d.y / m, d.z / m)
    } else if ay >= az {
        (2 + usize::from(d.y < 0.0), d.x / m, d.z / m)
    } else {
        (4 + usize::from(d.z < 0.0), d.x / m, d.y / m)
    };
    let cell = |t: f64| {
        let k = ((t + 1.0) * 0.5 * CUBE_CELLS as f64) as usize;
        k.min(CUBE_CELLS - 1)
    };
    Some((face * CUBE_CELLS + cell(u)) * CUBE_CELLS + cell(v))
}

/// Direction through the centre of cube-map cell `c` (inverse of [`cube_cell`]).
fn cube_cell_centre(c: usize) -> Vec3 {
    let v = c % CUBE_CELLS;
    let u = (c / CUBE_CELLS) % CUBE_CELLS;
    let face = c / (CUBE_CELLS * CUBE_CELLS);
    let t = |k: usize| (k as f64 + 0.5) / CUBE_CELLS as f64 * 2.0 - 1.0;
    let (u, v) = (t(u), t(v));
    let s = if face.is_multiple_of(2) { 1.0 } else { -1.0 };
    match face / 2 {
        0 => Vec3::new(s, u, v),
        1 => Vec3::new(u, s, v),
        _ => Vec3::new(u, v, s),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_and_valences_for_many_frequencies() {
        for n in 1..=20 {
            let d = Dome::new(n).unwrap();
            let n = n as usize;
            assert_eq!(d.len(), 10 * n * n + 2);
            assert_eq!(d.triangles().len(), 20 * n * n);
            let edges: usize = (0..d.len() as u32).map(|v| d.neighbours(v).len()).sum();
            assert_eq!(edges, 2 * 30 * n * n);
            let fives = (0..d.len() as u32)
                .filter(|&v| d.neighbours(v).len() == 5)
                .count();
            assert_eq!(fives, 12);
            assert!((0..d.len() as u32).all(|v| matches!(d.neighbours(v).len(), 5 | 6)));
            assert!((0..12).all(|v| d.neighbours(v).len() == 5));
            for v in d.vertices() {
                assert!((v.norm() - 1.0).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn neighbourhood_is_symmetric() {
        let d = Dome::new(5).unwrap();
        for v in 0..d.len() as u32 {
            for &w in d.neighbours(v) {
                assert!(d.neighbours(w).contains(&v));
                assert_ne!(v, w);
            }
        }
    }

    #[test]
    fn dome_is_convex_for_many_frequencies() {
        // 1..=40 all pass too; kept shorter because debug builds are slow.
        for n in (1..=16).chain([20, 24, 32, 40]) {
            assert!(Dome::new(n).unwrap().is_convex(), "frequency {n}");
        }
    }

    #[test]
    fn bad_frequencies_are_typed_errors() {
        assert_eq!(Dome::new(0).unwrap_err(), DomeError::BadFrequency(0));
        assert_eq!(Dome::new(65).unwrap_err(), DomeError::BadFrequency(65));
    }

    #[test]
    fn default_spacing_matches_the_documented_figures() {
        let d = Dome::new(DEFAULT_FREQUENCY).unwrap();
        assert_eq!(d.len(), 1692);
        let (mut lo, mut hi, mut sum, mut k) = (f64::MAX, 0.0_f64, 0.0, 0);
        for v in 0..d.len() as u32 {
            let p = d.vertex(v).unwrap();
            let m = d
                .neighbours(v)
                .iter()
                .map(|&w| p.dot(&d.vertex(w).unwrap()).acos().to_degrees())
                .fold(f64::MAX, f64::min);
            lo = lo.min(m);
            hi = hi.max(m);
            sum += m;
            k += 1;
        }
        let mean = sum / f64::from(k);
        assert!((4.0..4.2).contains(&lo), "{lo}");
        assert!((5.0..5.2).contains(&mean), "{mean}");
        assert!((5.7..5.9).contains(&hi), "{hi}");
        assert!(d.cell_radius_rad().to_degrees() < 4.0);
    }

    #[test]
    fn cube_cells_round_trip() {
        for c in 0..6 * CUBE_CELLS * CUBE_CELLS {
            assert_eq!(cube_cell(&cube_cell_centre(c)), Some(c));
        }
        assert_eq!(cube_cell(&Vec3::zeros()), None);
        assert_eq!(cube_cell(&Vec3::new(f64::NAN, 0.0, 1.0)), None);
    }

    #[test]
    fn within_matches_a_scan() {
        let d = Dome::new(7).unwrap();
        let q = Vec3::new(0.3, -0.5, 0.2).normalize();
        for r in [0.0_f64, 0.05, 0.2, 0.7, 1.5, 3.0, 4.0] {
            let scan: Vec<u32> = (0..d.len() as u32)
                .filter(|&v| d.vertex(v).unwrap().dot(&q) >= r.min(core::f64::consts::PI).cos())
                .collect();
            assert_eq!(d.within(&q, r), scan, "radius {r}");
        }
    }
}

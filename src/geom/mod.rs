//! Geometry shared by the builder and the tools: one small set of `[f64; 3]`
//! vector helpers, a positions-and-triangles [`Mesh`], the exact closest
//! point on a triangle ([`tri`]), a bounding-volume hierarchy over a mesh's
//! triangles ([`bvh`]) and the splitmix64 generator random samples use.
//!
//! Takes: positions and triangles. Gives: areas, bounds, closest points and
//! nearest-triangle queries, pure functions of their inputs (no I/O, no
//! store; `lod`, `metro` and `simplify` build on it, it imports none of them).

pub mod bvh;
pub mod keys;
pub mod tri;

pub use bvh::{Bvh, Closest};
pub use keys::{demorton, morton3, pos_bits, Welder};
pub use tri::{closest_point_segment, closest_point_triangle, face_samples, TriKind};

use crate::mesh::{Aabb, Vertex};

/// A point or vector.
pub type P3 = [f64; 3];

// The vector helpers: plain componentwise arithmetic in a fixed order, so
// every caller computes bit-identical results.

#[inline]
pub fn sub(a: P3, b: P3) -> P3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
#[inline]
pub fn add(a: P3, b: P3) -> P3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
#[inline]
pub fn scale(a: P3, s: f64) -> P3 {
    [a[0] * s, a[1] * s, a[2] * s]
}
#[inline]
pub fn dot(a: P3, b: P3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
#[inline]
pub fn cross(a: P3, b: P3) -> P3 {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}
#[inline]
pub fn dist2(a: P3, b: P3) -> f64 {
    let d = sub(a, b);
    dot(d, d)
}

/// A triangle mesh reduced to what distance queries need: positions and
/// triangles (metro's operands, lod's node error).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    pub positions: Vec<P3>,
    pub triangles: Vec<[u32; 3]>,
}

impl Mesh {
    pub fn new(positions: Vec<P3>, triangles: Vec<[u32; 3]>) -> Mesh {
        Mesh { positions, triangles }
    }
    /// From full vertices (attributes are ignored).
    pub fn from_vertices(vertices: &[Vertex], triangles: Vec<[u32; 3]>) -> Mesh {
        Mesh { positions: vertices.iter().map(|v| v.pos).collect(), triangles }
    }
    #[inline]
    pub fn corners(&self, t: usize) -> [P3; 3] {
        self.triangles[t].map(|i| self.positions[i as usize])
    }
    /// Bounding box of the vertices referenced by triangles.
    pub fn bbox(&self) -> Aabb {
        let mut b = Aabb::EMPTY;
        for t in &self.triangles {
            for &i in t {
                b.add(self.positions[i as usize]);
            }
        }
        b
    }
    /// Total triangle area.
    pub fn area(&self) -> f64 {
        (0..self.triangles.len()).map(|t| tri_area(self.corners(t))).sum()
    }
    /// Vertices referenced by a triangle, in the order of first reference
    /// (face by face, corner by corner).
    pub fn first_reference_vertices(&self) -> Vec<u32> {
        let mut seen = vec![false; self.positions.len()];
        let mut out = Vec::new();
        for t in &self.triangles {
            for &i in t {
                if !std::mem::replace(&mut seen[i as usize], true) {
                    out.push(i);
                }
            }
        }
        out
    }
    /// Vertices referenced by at least one triangle.
    pub fn referenced_vertices(&self) -> Vec<u32> {
        let mut used = vec![false; self.positions.len()];
        for t in &self.triangles {
            for &i in t {
                used[i as usize] = true;
            }
        }
        (0..self.positions.len() as u32).filter(|&i| used[i as usize]).collect()
    }
    pub(crate) fn check_indices(&self) -> std::result::Result<(), String> {
        let n = self.positions.len() as u64;
        match self.triangles.iter().position(|t| t.iter().any(|&i| i as u64 >= n)) {
            Some(k) => Err(format!("triangle {k} has a vertex index out of range (vertex count {n})")),
            None => Ok(()),
        }
    }
}

/// Area of the triangle `c`.
#[inline]
pub fn tri_area(c: [P3; 3]) -> f64 {
    let n = cross(sub(c[1], c[0]), sub(c[2], c[0]));
    0.5 * dot(n, n).sqrt()
}

/// splitmix64's increment (2^64 / golden ratio).
pub(crate) const GOLDEN: u64 = 0x9E37_79B9_7F4A_7C15;

/// splitmix64's output mix: a well-spread 64-bit hash of `x`.
#[inline]
pub(crate) fn mix64(x: u64) -> u64 {
    let mut z = x.wrapping_add(GOLDEN);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// splitmix64: a tiny seeded generator (the project's one: metro's
/// samples, the unit tests and the benchmarks draw from it).
#[derive(Clone, Debug)]
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Rng {
        Rng(mix64(seed))
    }
    /// The textbook splitmix64 started at raw `state` (no seed mixing):
    /// outputs the mix of `state + k·GOLDEN`, k = 1, 2, …
    pub fn from_state(state: u64) -> Rng {
        Rng(state.wrapping_sub(GOLDEN))
    }
    #[inline]
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(GOLDEN);
        mix64(self.0)
    }
    /// Uniform in [0, 1).
    #[inline]
    pub fn f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }
    /// Uniform in [lo, hi).
    #[inline]
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.f64()
    }
}

/// The triangles of an n × n grid of quads over (n + 1)² vertices in row
/// order, each quad split along its rising diagonal (a test mesh's index).
#[cfg(test)]
pub(crate) fn grid_triangles(n: u32) -> Vec<[u32; 3]> {
    let mut triangles = Vec::with_capacity(2 * (n * n) as usize);
    for y in 0..n {
        for x in 0..n {
            let v = y * (n + 1) + x;
            triangles.push([v, v + 1, v + n + 2]);
            triangles.push([v, v + n + 2, v + n + 1]);
        }
    }
    triangles
}

/// Random small triangles in the unit cube, every tenth degenerate (a test
/// mesh for the indexes built on it).
#[cfg(test)]
pub(crate) fn random_mesh(n: usize, seed: u64) -> Mesh {
    let mut rng = Rng::new(seed);
    let mut positions = Vec::new();
    let mut triangles = Vec::new();
    for t in 0..n {
        let c = [rng.f64(), rng.f64(), rng.f64()];
        let s = 0.1 * rng.f64();
        let mut r = || [c[0] + s * rng.f64(), c[1] + s * rng.f64(), c[2] + s * rng.f64()];
        let (p0, p1) = (r(), r());
        let p2 = if t % 10 == 0 { p1 } else { r() }; // some degenerate
        let base = positions.len() as u32;
        positions.extend([p0, p1, p2]);
        triangles.push([base, base + 1, base + 2]);
    }
    Mesh { positions, triangles }
}

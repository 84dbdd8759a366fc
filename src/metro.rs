//! Metro: the two-sided surface distance between two triangle meshes, after
//! Cignoni, Rocchini and Scopigno, "Metro: measuring error on simplified
//! surfaces" (1998), as implemented by vcglib's `metro`.
//!
//! Takes: two meshes `A` and `B`, each a PLY path or `STORE@L` (level `L` of
//! an octolod store: the level's whole-level cut, node meshes read one by one
//! and concatenated in memory with bit-identical positions welded, so it
//! samples like the PLY `octolod extract` would write), a sample budget and a
//! seed. Gives: per direction (`A -> B`: samples on A, distance to the closest
//! point of B; `B -> A` the other way) and combined, the maximum (Hausdorff),
//! mean and RMS distance and the sample counts, each absolute and relative to
//! **the bounding-box diagonal of A** (A is meant to be the reference, e.g.
//! the original, so figures for several simplifications of it share one
//! scale; vcglib's Metro divides by the diagonal of the union box instead,
//! which the report also lists). Combined figures: max of the two maxima;
//! mean and RMS over all samples of both directions together (so with the
//! default budget, equal sample counts, the combined mean is the average of
//! the two directional means). Bounding boxes, areas, vertex and face counts
//! of both meshes come with it. A `STORE@L` mesh is held in memory whole; a
//! paged, out-of-core variant (sampling node by node and querying a BVH of
//! the other mesh's node bounds, loading nodes on demand) is future work.
//!
//! Sampling (per direction, of the source mesh S, total budget `N`, by
//! default `10 * max(faces of A, faces of B)` like Metro, `--samples`
//! overrides): as in vcglib's `Sampling::Hausdorff`,
//! 1. every vertex referenced by a triangle (unreferenced ones are not part
//!    of the surface), `V` samples — all of them even when `V >= N`;
//! 2. with `R = N - V` left, every unique edge gets samples at equally spaced
//!    interior points, `sqrt(R / area(S))` per unit length exactly like
//!    Metro (the spacing the face samples will have), which at the default
//!    budget puts about 70 % of the samples on edges (~7 per face of the
//!    larger mesh). One guard Metro lacks: the edges take at most
//!    [`EDGE_SHARE_MAX`] (90 %) of `R`, which only binds below ~6 samples
//!    per face, where Metro's edges would take the whole budget and leave
//!    the face interiors (where a simplification's error peaks) unsampled.
//!    Length-proportional, fractions carried from edge to edge in edge
//!    order, which is the sorted (low, high) vertex-index order;
//! 3. what is left after the edges, `R - E`, goes to the faces (Metro's
//!    `Hausdorff()` subtracts the vertex samples a second time here, giving
//!    the faces `R - E - V`; octolod keeps the total at `N` as `--samples`
//!    promises, so its faces get `V` more), proportionally to area
//!    (fractions carried in face order), each face's `n` samples *stratified*:
//!    the face is cut into `m² >= n` similar sub-triangles (`m = ceil(sqrt
//!    n)`), `n` of them are picked at equal index spacing with a random
//!    offset, and one uniform random point is drawn in each.
//!
//! The randomness is a splitmix64 hash of (seed, direction, face, sample), so
//! the sample set depends on the seed only, not on thread count or chunking.
//!
//! Distance: for each sample, the exact closest point on the target mesh,
//! found in a bounding-volume hierarchy over the target's triangles (median
//! split of triangle centroids along the longest axis, at most 4 triangles a
//! leaf, flattened depth-first into one array with the left child next to
//! its parent; subtrees above 64 K triangles built in parallel) by a pruned
//! nearest-first traversal: the nearer child first, any box farther than the
//! best distance found so far skipped, and the search seeded with the
//! previous sample's closest triangle (samples come in surface order, so the
//! seed is usually already the answer and prunes almost everything). The
//! point–triangle distance is Ericson's Voronoi-region method (Real-Time
//! Collision Detection §5.1.5) for well-shaped triangles; thin triangles
//! (height below 1e-3 of the longest edge) use a plane projection with an
//! edge-sign inside test and fall back to the edges, and degenerate ones
//! (height at most 1e-8 of the longest edge: collinear or coincident
//! corners) are the union of their three edges as segments, so no input
//! produces NaN.
//!
//! Determinism: samples are processed in fixed chunks of [`CHUNK`] samples
//! (vertex chunks, then edge chunks, then face chunks) in parallel with
//! rayon; each chunk sums sequentially, and the chunk partial sums are
//! combined in chunk order, so every figure is bit-identical for a given
//! seed whatever the thread count. The JSON report holds no timings, so it
//! can be diffed.
//!
//! Complexity: building each BVH is O(F log F) time and O(F) memory (about
//! 100 bytes a triangle with the reordered copy of its corners); sampling is
//! O(N) plus an O(F) prefix pass and an O(E log E) edge sort; each query is
//! O(log F) expected on reasonable meshes (worst case O(F)), so a direction
//! costs O(N log F) and runs on all cores.
//!
//! Thresholds (`--max-hausdorff`, `--max-rms`, `--max-mean`) are checked
//! against the combined figures, absolute (`0.01`) or as a percentage of A's
//! diagonal (`0.1%`); the CLI exits with [`EXIT_THRESHOLD`] (3) when one is
//! exceeded, distinct from 1 for errors.

use crate::error::{Error, Location, Result};
use crate::mesh::{Aabb, Vertex};
use crate::progress::Progress;
use rayon::prelude::*;
use std::collections::HashMap;
use std::fmt;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Exit status of `octolod metro` when a threshold is exceeded (1 is an error).
pub const EXIT_THRESHOLD: u8 = 3;
/// Default samples per direction per face of the larger mesh (Metro's 10).
pub const SAMPLES_PER_FACE: u64 = 10;
/// Samples per parallel work item; fixed, so results do not depend on threads.
pub const CHUNK: u64 = 16 * 1024;
/// Most of the non-vertex budget the edges may take (Metro has no cap; see
/// the module documentation).
pub const EDGE_SHARE_MAX: f64 = 0.9;

type P3 = [f64; 3];

#[inline]
fn sub(a: P3, b: P3) -> P3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
#[inline]
fn add(a: P3, b: P3) -> P3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
#[inline]
fn scale(a: P3, s: f64) -> P3 {
    [a[0] * s, a[1] * s, a[2] * s]
}
#[inline]
fn dot(a: P3, b: P3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
#[inline]
fn cross(a: P3, b: P3) -> P3 {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}
#[inline]
fn dist2(a: P3, b: P3) -> f64 {
    let d = sub(a, b);
    dot(d, d)
}

// ---------------------------------------------------------------------------
// Meshes and loading.

/// A triangle mesh reduced to what metro needs: positions and triangles.
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
    fn corners(&self, t: usize) -> [P3; 3] {
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
    fn check_indices(&self) -> std::result::Result<(), String> {
        let n = self.positions.len() as u64;
        match self.triangles.iter().position(|t| t.iter().any(|&i| i as u64 >= n)) {
            Some(k) => Err(format!("triangle {k} has a vertex index out of range (vertex count {n})")),
            None => Ok(()),
        }
    }
}

#[inline]
fn tri_area(c: [P3; 3]) -> f64 {
    let n = cross(sub(c[1], c[0]), sub(c[2], c[0]));
    0.5 * dot(n, n).sqrt()
}

/// Where a metro operand comes from.
#[derive(Clone, Debug, PartialEq)]
pub enum Source {
    Ply(PathBuf),
    /// A store directory and a level.
    Store(PathBuf, u8),
}

impl Source {
    /// `PATH.ply` or `STORE@L`. A spec is a store when the part before the
    /// last `@` is a directory (or the whole spec names nothing and the part
    /// after `@` is a number); a bare store directory is a usage error.
    pub fn parse(spec: &str) -> Result<Source> {
        if let Some((dir, level)) = spec.rsplit_once('@') {
            let numeric = !level.is_empty() && level.bytes().all(|c| c.is_ascii_digit());
            if Path::new(dir).is_dir() || (numeric && !Path::new(spec).exists()) {
                let l: u8 = level.parse().map_err(|_| {
                    Error::Usage(format!("'{spec}': the level after '@' must be a number from 0 to 255, not '{level}'"))
                })?;
                return Ok(Source::Store(PathBuf::from(dir), l));
            }
        }
        if Path::new(spec).is_dir() {
            return Err(Error::Usage(format!("'{spec}' is a directory; name a store level as {spec}@L (e.g. {spec}@0)")));
        }
        Ok(Source::Ply(PathBuf::from(spec)))
    }
    pub fn load(&self) -> Result<Mesh> {
        match self {
            Source::Ply(p) => load_ply(p),
            Source::Store(d, l) => load_store_level(d, *l),
        }
    }
}

impl fmt::Display for Source {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Source::Ply(p) => write!(f, "{}", p.display()),
            Source::Store(d, l) => write!(f, "{}@{l}", d.display()),
        }
    }
}

fn loc(path: &Path) -> Location {
    Location { file: path.to_path_buf(), ..Default::default() }
}

/// Reads a whole PLY (any format the reader takes; polygons fan-triangulated,
/// triangles with a repeated index dropped).
pub fn load_ply(path: &Path) -> Result<Mesh> {
    let (_, sink, _) = crate::ply::read::read_all(path)?;
    if sink.vertices.len() as u64 > u32::MAX as u64 + 1 {
        return Err(Error::input(loc(path), format!("{} vertices: metro takes at most 2^32", sink.vertices.len())));
    }
    let mesh = Mesh {
        positions: sink.vertices.iter().map(|v| v.pos).collect(),
        triangles: sink.triangles.iter().map(|t| t.map(|i| i as u32)).collect(),
    };
    if mesh.triangles.is_empty() {
        return Err(Error::input(loc(path), "no triangles to measure"));
    }
    Ok(mesh)
}

/// Level `level` of the store at `dir`: the whole-level cut's node meshes,
/// concatenated in memory, bit-identical positions welded.
pub fn load_store_level(dir: &Path, level: u8) -> Result<Mesh> {
    let store = crate::store::Store::open(dir)?;
    crate::pipeline::check_level(&store, level)?;
    let mut mesh = Mesh::default();
    let mut weld: HashMap<[u64; 3], u32> = HashMap::new();
    for i in crate::simplify::level_cut(&store.nodes, level) {
        let n = &store.nodes[i];
        let m = crate::pipeline::read_level_mesh(&store, i, level)?;
        let ids: Vec<u32> = m
            .vertices
            .iter()
            .map(|v| {
                let next = mesh.positions.len() as u32;
                *weld.entry(v.pos.map(f64::to_bits)).or_insert_with(|| {
                    mesh.positions.push(v.pos);
                    next
                })
            })
            .collect();
        for t in &m.triangles {
            if t.iter().any(|&k| k as usize >= ids.len()) {
                return Err(Error::input(loc(&store.pack_path(n.level as usize)), format!("node {i}: vertex index out of range")));
            }
            mesh.triangles.push(t.map(|k| ids[k as usize]));
        }
    }
    if mesh.triangles.is_empty() {
        return Err(Error::input(loc(dir), format!("level {level} has no triangles to measure")));
    }
    Ok(mesh)
}

// ---------------------------------------------------------------------------
// Point–triangle distance.

/// Closest point to `p` on segment `ab` (a zero-length segment is its point).
#[inline]
pub fn closest_point_segment(p: P3, a: P3, b: P3) -> P3 {
    let ab = sub(b, a);
    let l = dot(ab, ab);
    if l <= 0.0 {
        return a;
    }
    let t = (dot(sub(p, a), ab) / l).clamp(0.0, 1.0);
    add(a, scale(ab, t))
}

/// How a triangle's closest point is computed; see [`TriKind::of`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TriKind {
    /// Ericson's Voronoi-region method.
    Regular,
    /// Plane projection with an exact inside test, else the edges.
    Thin,
    /// The union of the three edges as segments.
    Degenerate,
}

impl TriKind {
    /// By the ratio of the height over the longest edge to that edge,
    /// `h/L`: regular when at least 1e-3 (Ericson's barycentrics then
    /// round to ~1e-10 relative), degenerate when at most 1e-8 (where the
    /// computed normal's rounding, ~1e-16/(h/L), would cost more than
    /// ignoring the interior, ≤ h), thin in between.
    #[inline]
    pub fn of(a: P3, b: P3, c: P3) -> TriKind {
        let (ab, ac, bc) = (sub(b, a), sub(c, a), sub(c, b));
        let n = cross(ab, ac);
        let nn = dot(n, n); // (2 area)² = (L h)²
        let e = dot(ab, ab).max(dot(ac, ac)).max(dot(bc, bc));
        let ll = e * e;
        if nn.is_nan() || nn <= 1e-16 * ll || nn <= 0.0 {
            TriKind::Degenerate
        } else if nn < 1e-6 * ll {
            TriKind::Thin
        } else {
            TriKind::Regular
        }
    }
}

/// Closest point to `p` on the triangle `abc`, whatever its shape.
#[inline]
pub fn closest_point_triangle(p: P3, a: P3, b: P3, c: P3) -> P3 {
    closest_point_triangle_kind(p, a, b, c, TriKind::of(a, b, c))
}

#[inline]
fn closest_point_triangle_kind(p: P3, a: P3, b: P3, c: P3, kind: TriKind) -> P3 {
    match kind {
        TriKind::Regular => ericson(p, a, b, c),
        TriKind::Thin => {
            let n = cross(sub(b, a), sub(c, a));
            let inside = dot(cross(sub(b, a), sub(p, a)), n) >= 0.0
                && dot(cross(sub(c, b), sub(p, b)), n) >= 0.0
                && dot(cross(sub(a, c), sub(p, c)), n) >= 0.0;
            if inside {
                let t = dot(sub(p, a), n) / dot(n, n);
                sub(p, scale(n, t))
            } else {
                closest_on_edges(p, a, b, c)
            }
        }
        TriKind::Degenerate => closest_on_edges(p, a, b, c),
    }
}

#[inline]
fn closest_on_edges(p: P3, a: P3, b: P3, c: P3) -> P3 {
    let mut best = closest_point_segment(p, a, b);
    let mut d = dist2(p, best);
    for q in [closest_point_segment(p, b, c), closest_point_segment(p, c, a)] {
        let e = dist2(p, q);
        if e < d {
            d = e;
            best = q;
        }
    }
    best
}

/// Ericson, Real-Time Collision Detection §5.1.5 (non-degenerate triangles).
#[inline]
fn ericson(p: P3, a: P3, b: P3, c: P3) -> P3 {
    let ab = sub(b, a);
    let ac = sub(c, a);
    let ap = sub(p, a);
    let d1 = dot(ab, ap);
    let d2 = dot(ac, ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = sub(p, b);
    let d3 = dot(ab, bp);
    let d4 = dot(ac, bp);
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return add(a, scale(ab, d1 / (d1 - d3)));
    }
    let cp = sub(p, c);
    let d5 = dot(ab, cp);
    let d6 = dot(ac, cp);
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return add(a, scale(ac, d2 / (d2 - d6)));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return add(b, scale(sub(c, b), w));
    }
    let denom = va + vb + vc;
    if denom.is_nan() || denom <= 0.0 {
        return closest_on_edges(p, a, b, c);
    }
    let v = vb / denom;
    let w = vc / denom;
    add(a, add(scale(ab, v), scale(ac, w)))
}

// ---------------------------------------------------------------------------
// Bounding-volume hierarchy.

/// Triangles per leaf at most.
const LEAF_TRIS: usize = 4;
/// Subtrees with more triangles than this are built in parallel.
const PAR_BUILD: usize = 64 * 1024;

#[derive(Clone, Copy, Debug)]
struct Node {
    min: P3,
    max: P3,
    /// Leaf: first triangle slot. Inner: index of the right child (the left
    /// child is the next node).
    start: u32,
    /// Leaf: triangle count (> 0). Inner: 0.
    count: u32,
}

impl Node {
    #[inline]
    fn dist2(&self, p: P3) -> f64 {
        let e = |k: usize| (self.min[k] - p[k]).max(p[k] - self.max[k]).max(0.0);
        let (x, y, z) = (e(0), e(1), e(2));
        x * x + y * y + z * z
    }
    fn shifted(mut self, by: u32) -> Node {
        if self.count == 0 {
            self.start += by;
        }
        self
    }
}

/// The closest point of a mesh to a query point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Closest {
    /// Squared distance.
    pub dist2: f64,
    pub point: P3,
    /// Index of the triangle in the mesh the BVH was built from.
    pub triangle: u32,
}

/// A BVH over a mesh's triangles, holding its own copy of the corners in
/// leaf order.
pub struct Bvh {
    nodes: Vec<Node>,
    tris: Vec<[P3; 3]>,
    kinds: Vec<TriKind>,
    ids: Vec<u32>,
}

impl Bvh {
    pub fn new(mesh: &Mesh) -> Bvh {
        let mut items: Vec<(P3, u32)> = (0..mesh.triangles.len())
            .into_par_iter()
            .map(|t| {
                let c = mesh.corners(t);
                ([0, 1, 2].map(|k| (c[0][k] + c[1][k] + c[2][k]) / 3.0), t as u32)
            })
            .collect();
        let nodes = if items.is_empty() { Vec::new() } else { build(mesh, &mut items, 0) };
        let tris: Vec<[P3; 3]> = items.par_iter().map(|&(_, t)| mesh.corners(t as usize)).collect();
        let kinds = tris.par_iter().map(|c| TriKind::of(c[0], c[1], c[2])).collect();
        Bvh { nodes, tris, kinds, ids: items.iter().map(|&(_, t)| t).collect() }
    }
    pub fn len(&self) -> usize {
        self.tris.len()
    }
    pub fn is_empty(&self) -> bool {
        self.tris.is_empty()
    }
    /// Number of BVH nodes.
    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }
    /// The exact closest point of the mesh to `p` (None for an empty mesh).
    pub fn closest(&self, p: P3) -> Option<Closest> {
        if self.is_empty() {
            return None;
        }
        let (d, slot, q) = self.nearest(p, u32::MAX);
        Some(Closest { dist2: d, point: q, triangle: self.ids[slot as usize] })
    }
    #[inline]
    fn tri_closest(&self, slot: u32, p: P3) -> P3 {
        let c = &self.tris[slot as usize];
        closest_point_triangle_kind(p, c[0], c[1], c[2], self.kinds[slot as usize])
    }
    /// (squared distance, triangle slot, point); `hint` is a slot to try
    /// first (u32::MAX for none). Requires a non-empty BVH.
    fn nearest(&self, p: P3, hint: u32) -> (f64, u32, P3) {
        let (mut best2, mut best, mut bq) = (f64::INFINITY, u32::MAX, p);
        if hint != u32::MAX {
            bq = self.tri_closest(hint, p);
            best2 = dist2(p, bq);
            best = hint;
        }
        let mut stack = [(0u32, 0f64); 64];
        let mut sp = 0usize;
        let mut node = 0u32;
        let mut nd = self.nodes[0].dist2(p);
        loop {
            if nd < best2 {
                let n = &self.nodes[node as usize];
                if n.count > 0 {
                    for s in n.start..n.start + n.count {
                        if s == hint {
                            continue;
                        }
                        let q = self.tri_closest(s, p);
                        let d = dist2(p, q);
                        if d < best2 {
                            best2 = d;
                            best = s;
                            bq = q;
                        }
                    }
                } else {
                    let (l, r) = (node + 1, n.start);
                    let dl = self.nodes[l as usize].dist2(p);
                    let dr = self.nodes[r as usize].dist2(p);
                    let (near, dn, far, df) = if dl <= dr { (l, dl, r, dr) } else { (r, dr, l, dl) };
                    if df < best2 {
                        stack[sp] = (far, df);
                        sp += 1;
                    }
                    node = near;
                    nd = dn;
                    continue;
                }
            }
            if sp == 0 {
                break;
            }
            sp -= 1;
            (node, nd) = stack[sp];
        }
        if best == u32::MAX {
            // Only possible with non-finite coordinates; answer something.
            best = 0;
            bq = self.tri_closest(0, p);
            best2 = dist2(p, bq);
        }
        (best2, best, bq)
    }
}

fn bounds(mesh: &Mesh, items: &[(P3, u32)]) -> (Aabb, Aabb) {
    let (mut b, mut cb) = (Aabb::EMPTY, Aabb::EMPTY);
    for &(c, t) in items {
        for &i in &mesh.triangles[t as usize] {
            b.add(mesh.positions[i as usize]);
        }
        cb.add(c);
    }
    (b, cb)
}

/// Builds the subtree over `items` (whose first slot is `offset`), node
/// indices relative to the subtree's root.
fn build(mesh: &Mesh, items: &mut [(P3, u32)], offset: usize) -> Vec<Node> {
    if items.len() <= PAR_BUILD {
        let mut out = Vec::with_capacity(2 * items.len() / LEAF_TRIS + 1);
        build_seq(mesh, items, offset, &mut out);
        return out;
    }
    let (b, mid) = split(mesh, items);
    let (l, r) = items.split_at_mut(mid);
    let (lv, rv) = rayon::join(|| build(mesh, l, offset), || build(mesh, r, offset + mid));
    let mut out = Vec::with_capacity(1 + lv.len() + rv.len());
    let right = 1 + lv.len() as u32;
    out.push(Node { min: b.min, max: b.max, start: right, count: 0 });
    out.extend(lv.into_iter().map(|n| n.shifted(1)));
    out.extend(rv.into_iter().map(|n| n.shifted(right)));
    out
}

fn build_seq(mesh: &Mesh, items: &mut [(P3, u32)], offset: usize, out: &mut Vec<Node>) {
    if items.len() <= LEAF_TRIS {
        let (b, _) = bounds(mesh, items);
        out.push(Node { min: b.min, max: b.max, start: offset as u32, count: items.len() as u32 });
        return;
    }
    let me = out.len();
    let (b, mid) = split(mesh, items);
    out.push(Node { min: b.min, max: b.max, start: 0, count: 0 });
    let (l, r) = items.split_at_mut(mid);
    build_seq(mesh, l, offset, out);
    out[me].start = out.len() as u32;
    build_seq(mesh, r, offset + mid, out);
}

/// The node's box, and the median split of its items along the longest axis
/// of the centroid bounds (ties broken by triangle index: deterministic).
fn split(mesh: &Mesh, items: &mut [(P3, u32)]) -> (Aabb, usize) {
    let (b, cb) = bounds(mesh, items);
    let ext = [0, 1, 2].map(|k| cb.max[k] - cb.min[k]);
    let axis = if ext[0] >= ext[1] && ext[0] >= ext[2] {
        0
    } else if ext[1] >= ext[2] {
        1
    } else {
        2
    };
    let mid = items.len() / 2;
    items.select_nth_unstable_by(mid, |x, y| x.0[axis].total_cmp(&y.0[axis]).then(x.1.cmp(&y.1)));
    (b, mid)
}

// ---------------------------------------------------------------------------
// Sampling.

const GOLDEN: u64 = 0x9E37_79B9_7F4A_7C15;

#[inline]
fn mix64(x: u64) -> u64 {
    let mut z = x.wrapping_add(GOLDEN);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// splitmix64: a tiny seeded generator.
#[derive(Clone, Debug)]
struct Rng(u64);

impl Rng {
    fn new(seed: u64) -> Rng {
        Rng(mix64(seed))
    }
    #[inline]
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(GOLDEN);
        mix64(self.0)
    }
    /// Uniform in [0, 1).
    #[inline]
    fn f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }
}

#[inline]
fn isqrt(x: u64) -> u64 {
    let mut r = (x as f64).sqrt() as u64;
    while r * r > x {
        r -= 1;
    }
    while (r + 1) * (r + 1) <= x {
        r += 1;
    }
    r
}

/// Sample `i` of `n` stratified samples on triangle `c` whose per-face offset
/// is `offset` in [0,1) and per-sample generator `rng`.
#[inline]
fn face_sample(c: &[P3; 3], i: u64, n: u64, offset: f64, rng: &mut Rng) -> P3 {
    let m = isqrt(n - 1) + 1; // ceil(sqrt(n)) for n >= 1
    let cells = m * m;
    let idx = (((i as f64 + offset) * cells as f64 / n as f64) as u64).min(cells - 1);
    let band = isqrt(idx);
    let k = idx - band * band;
    let (mut s, mut t) = (rng.f64(), rng.f64());
    if s + t > 1.0 {
        s = 1.0 - s;
        t = 1.0 - t;
    }
    // Lattice coordinates (x, y), x + y <= m, in units of (b - a)/m, (c - a)/m.
    let (x, y) = if k % 2 == 0 {
        let a = k / 2;
        (a as f64 + s, (band - a) as f64 + t)
    } else {
        let a = k / 2;
        ((a + 1) as f64 - s, (band - a) as f64 - t)
    };
    let (u, v) = (x / m as f64, y / m as f64);
    add(c[0], add(scale(sub(c[1], c[0]), u), scale(sub(c[2], c[0]), v)))
}

/// The sample plan of one direction: which points, in which order.
struct Plan {
    verts: Vec<u32>,
    edges: Vec<[u32; 2]>,
    /// `edge_prefix[e]` = samples on edges before `e` (len E + 1).
    edge_prefix: Vec<u64>,
    face_prefix: Vec<u64>,
    seed: u64,
}

impl Plan {
    fn new(src: &Mesh, target: u64, seed: u64) -> Plan {
        let verts = src.referenced_vertices();
        let areas: Vec<f64> = (0..src.triangles.len()).into_par_iter().map(|t| tri_area(src.corners(t))).collect();
        let area: f64 = areas.iter().sum();
        let mut keys: Vec<u64> = src
            .triangles
            .par_iter()
            .flat_map_iter(|t| {
                (0..3).map(move |k| {
                    let (a, b) = (t[k], t[(k + 1) % 3]);
                    ((a.min(b) as u64) << 32) | a.max(b) as u64
                })
            })
            .collect();
        keys.par_sort_unstable();
        keys.dedup();
        let edges: Vec<[u32; 2]> = keys.iter().map(|&k| [(k >> 32) as u32, k as u32]).collect();
        drop(keys);
        let mut left = target.saturating_sub(verts.len() as u64);
        let mut edge_prefix = vec![0u64; edges.len() + 1];
        let mut face_prefix = vec![0u64; areas.len() + 1];
        if left > 0 {
            let lens: Vec<f64> =
                edges.par_iter().map(|e| dist2(src.positions[e[0] as usize], src.positions[e[1] as usize]).sqrt()).collect();
            let total: f64 = lens.iter().sum();
            let per_len = if area > 0.0 {
                // Metro's density; the cap only binds at tiny budgets.
                (left as f64 / area).sqrt().min(EDGE_SHARE_MAX * left as f64 / total)
            } else if total > 0.0 {
                left as f64 / total
            } else {
                0.0
            };
            carry_prefix(&lens, per_len, &mut edge_prefix);
            left = left.saturating_sub(edge_prefix[edges.len()]);
            if left > 0 && area > 0.0 {
                carry_prefix(&areas, left as f64 / area, &mut face_prefix);
            }
        }
        Plan { verts, edges, edge_prefix, face_prefix, seed }
    }
    fn counts(&self) -> (u64, u64, u64) {
        (self.verts.len() as u64, *self.edge_prefix.last().unwrap(), *self.face_prefix.last().unwrap())
    }
}

/// `prefix[i+1] = floor(density * sum(w[..=i]))`: Metro's carried fractions.
fn carry_prefix(w: &[f64], density: f64, prefix: &mut [u64]) {
    let mut acc = 0.0f64;
    prefix[0] = 0;
    for (i, &x) in w.iter().enumerate() {
        acc += x * density;
        prefix[i + 1] = (acc.floor() as u64).max(prefix[i]);
    }
}

/// Distances of one direction.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Distances {
    pub samples: u64,
    pub vertex_samples: u64,
    pub edge_samples: u64,
    pub face_samples: u64,
    /// Hausdorff (one-sided, or two-sided for the combined figures).
    pub max: f64,
    pub mean: f64,
    pub rms: f64,
    /// Where the maximum was found (a sample on the source mesh).
    pub max_at: P3,
    /// Sum and sum of squares of the distances (for combining).
    pub sum: f64,
    pub sum2: f64,
}

impl Distances {
    fn combine(&self, o: &Distances) -> Distances {
        let samples = self.samples + o.samples;
        let (sum, sum2) = (self.sum + o.sum, self.sum2 + o.sum2);
        let (max, max_at) = if o.max > self.max { (o.max, o.max_at) } else { (self.max, self.max_at) };
        Distances {
            samples,
            vertex_samples: self.vertex_samples + o.vertex_samples,
            edge_samples: self.edge_samples + o.edge_samples,
            face_samples: self.face_samples + o.face_samples,
            max,
            mean: if samples > 0 { sum / samples as f64 } else { 0.0 },
            rms: if samples > 0 { (sum2 / samples as f64).sqrt() } else { 0.0 },
            max_at,
            sum,
            sum2,
        }
    }
}

#[derive(Clone, Copy, Default)]
struct Acc {
    n: u64,
    sum: f64,
    sum2: f64,
    max: f64,
    max_at: P3,
}

impl Acc {
    #[inline]
    fn add(&mut self, d2: f64, p: P3) {
        let d = d2.sqrt();
        if self.n == 0 || d > self.max {
            self.max = d;
            self.max_at = p;
        }
        self.n += 1;
        self.sum += d;
        self.sum2 += d2;
    }
}

#[derive(Clone, Copy)]
enum Kind {
    Vertex,
    Edge,
    Face,
}

/// One-sided distances from `src`'s samples to the mesh `target` indexes:
/// about `samples` samples (see the module documentation), from `seed`.
pub fn one_sided(src: &Mesh, target: &Bvh, samples: u64, seed: u64, progress: &Progress) -> Result<Distances> {
    if target.is_empty() {
        return Err(Error::Usage("metro: the target mesh has no triangles".into()));
    }
    if src.triangles.is_empty() {
        return Err(Error::Usage("metro: the source mesh has no triangles".into()));
    }
    src.check_indices().map_err(|m| Error::Usage(format!("metro: source mesh: {m}")))?;
    let plan = Plan::new(src, samples, seed);
    let (nv, ne, nf) = plan.counts();
    let mut jobs: Vec<(Kind, u64, u64)> = Vec::new();
    for (kind, n) in [(Kind::Vertex, nv), (Kind::Edge, ne), (Kind::Face, nf)] {
        let mut s = 0;
        while s < n {
            jobs.push((kind, s, (s + CHUNK).min(n)));
            s += CHUNK;
        }
    }
    let parts: Vec<Acc> = jobs.into_par_iter().map(|(kind, s, e)| run_job(src, target, &plan, kind, s, e, progress)).collect();
    let mut acc = Acc::default();
    for p in &parts {
        if p.n > 0 && (acc.n == 0 || p.max > acc.max) {
            acc.max = p.max;
            acc.max_at = p.max_at;
        }
        acc.n += p.n;
        acc.sum += p.sum;
        acc.sum2 += p.sum2;
    }
    let n = acc.n.max(1) as f64;
    Ok(Distances {
        samples: acc.n,
        vertex_samples: nv,
        edge_samples: ne,
        face_samples: nf,
        max: acc.max,
        mean: acc.sum / n,
        rms: (acc.sum2 / n).sqrt(),
        max_at: acc.max_at,
        sum: acc.sum,
        sum2: acc.sum2,
    })
}

/// Samples `[s, e)` of one kind, sequentially, seeded with the previous
/// sample's closest triangle.
fn run_job(src: &Mesh, bvh: &Bvh, plan: &Plan, kind: Kind, s: u64, e: u64, progress: &Progress) -> Acc {
    let mut acc = Acc::default();
    let mut hint = u32::MAX;
    let mut query = |p: P3, acc: &mut Acc| {
        let (d2, slot, _) = bvh.nearest(p, hint);
        hint = slot;
        acc.add(d2, p);
    };
    match kind {
        Kind::Vertex => {
            for &v in &plan.verts[s as usize..e as usize] {
                query(src.positions[v as usize], &mut acc);
            }
        }
        Kind::Edge => {
            let mut ei = plan.edge_prefix.partition_point(|&x| x <= s) - 1;
            let mut g = s;
            while g < e {
                let (lo, hi) = (plan.edge_prefix[ei], plan.edge_prefix[ei + 1]);
                let n = hi - lo;
                if n > 0 {
                    let [a, b] = plan.edges[ei].map(|i| src.positions[i as usize]);
                    let ab = sub(b, a);
                    for i in (g - lo)..(n.min(e - lo)) {
                        query(add(a, scale(ab, (i + 1) as f64 / (n + 1) as f64)), &mut acc);
                    }
                }
                g = hi.max(g);
                ei += 1;
            }
        }
        Kind::Face => {
            let mut fi = plan.face_prefix.partition_point(|&x| x <= s) - 1;
            let mut g = s;
            while g < e {
                let (lo, hi) = (plan.face_prefix[fi], plan.face_prefix[fi + 1]);
                let n = hi - lo;
                if n > 0 {
                    let c = src.corners(fi);
                    let fseed = plan.seed ^ mix64((fi as u64).wrapping_mul(GOLDEN) ^ 0xFACE);
                    let offset = Rng::new(fseed).f64();
                    for i in (g - lo)..(n.min(e - lo)) {
                        let mut rng = Rng::new(fseed.wrapping_add(mix64(i + 1)));
                        query(face_sample(&c, i, n, offset, &mut rng), &mut acc);
                    }
                }
                g = hi.max(g);
                fi += 1;
            }
        }
    }
    progress.inc(e - s);
    acc
}

// ---------------------------------------------------------------------------
// The two-sided comparison and its report.

/// What to measure.
#[derive(Clone, Debug)]
pub struct Options {
    /// Samples per direction; None: [`SAMPLES_PER_FACE`] × the larger face count.
    pub samples: Option<u64>,
    pub seed: u64,
    pub quiet: bool,
}

impl Default for Options {
    fn default() -> Self {
        Options { samples: None, seed: 1, quiet: true }
    }
}

/// Figures of one operand.
#[derive(Clone, Debug, PartialEq)]
pub struct MeshSummary {
    /// The spec it was loaded from (`A`/`B` when compared in memory).
    pub source: String,
    /// Vertices referenced by triangles.
    pub vertices: u64,
    pub faces: u64,
    pub area: f64,
    pub bbox: Aabb,
}

impl MeshSummary {
    fn of(m: &Mesh, source: &str) -> MeshSummary {
        MeshSummary {
            source: source.to_string(),
            vertices: m.referenced_vertices().len() as u64,
            faces: m.triangles.len() as u64,
            area: m.area(),
            bbox: m.bbox(),
        }
    }
}

/// Seconds spent (not part of the JSON report, which is deterministic).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Timings {
    pub load: f64,
    pub bvh: f64,
    pub a_to_b: f64,
    pub b_to_a: f64,
}

/// The result of [`compare`].
#[derive(Clone, Debug, PartialEq)]
pub struct Report {
    pub a: MeshSummary,
    pub b: MeshSummary,
    /// The diagonal relative figures and percentage thresholds refer to:
    /// A's bounding box.
    pub diagonal: f64,
    /// Diagonal of the union of both boxes (what vcglib's Metro uses).
    pub union_diagonal: f64,
    pub seed: u64,
    /// Samples per direction asked for.
    pub samples_target: u64,
    pub a_to_b: Distances,
    pub b_to_a: Distances,
    /// Max of both maxima; mean and RMS over the samples of both directions.
    pub combined: Distances,
    pub seconds: Timings,
}

/// Two-sided Metro distance between `a` and `b`.
pub fn compare(a: &Mesh, b: &Mesh, opts: &Options) -> Result<Report> {
    for (m, name) in [(a, "A"), (b, "B")] {
        if m.triangles.is_empty() {
            return Err(Error::Usage(format!("metro: mesh {name} has no triangles")));
        }
        m.check_indices().map_err(|e| Error::Usage(format!("metro: mesh {name}: {e}")))?;
    }
    let target = match opts.samples {
        Some(0) => return Err(Error::Usage("metro: --samples must be at least 1".into())),
        Some(n) => n,
        None => SAMPLES_PER_FACE * a.triangles.len().max(b.triangles.len()) as u64,
    };
    let t0 = Instant::now();
    let (bvh_a, bvh_b) = rayon::join(|| Bvh::new(a), || Bvh::new(b));
    let t1 = Instant::now();
    let seed_ab = mix64(opts.seed ^ 0xA70B);
    let seed_ba = mix64(opts.seed ^ 0xB70A);
    let pa = Progress::items(target, "A -> B", opts.quiet);
    let ab = one_sided(a, &bvh_b, target, seed_ab, &pa)?;
    pa.finish();
    let t2 = Instant::now();
    drop(bvh_b);
    let pb = Progress::items(target, "B -> A", opts.quiet);
    let ba = one_sided(b, &bvh_a, target, seed_ba, &pb)?;
    pb.finish();
    let t3 = Instant::now();
    let (sa, sb) = (MeshSummary::of(a, "A"), MeshSummary::of(b, "B"));
    let mut u = sa.bbox;
    u.merge(&sb.bbox);
    Ok(Report {
        diagonal: sa.bbox.diagonal(),
        union_diagonal: u.diagonal(),
        a: sa,
        b: sb,
        seed: opts.seed,
        samples_target: target,
        combined: ab.combine(&ba),
        a_to_b: ab,
        b_to_a: ba,
        seconds: Timings {
            load: 0.0,
            bvh: (t1 - t0).as_secs_f64(),
            a_to_b: (t2 - t1).as_secs_f64(),
            b_to_a: (t3 - t2).as_secs_f64(),
        },
    })
}

/// A distance limit: absolute, or a percentage of the reference diagonal.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Threshold {
    Absolute(f64),
    Percent(f64),
}

impl Threshold {
    /// `0.01` (absolute) or `0.1%` (of the diagonal); finite and >= 0.
    pub fn parse(s: &str) -> Result<Threshold> {
        let t = s.trim();
        let (num, pct) = match t.strip_suffix('%') {
            Some(n) => (n.trim_end(), true),
            None => (t, false),
        };
        let bad = || Error::Usage(format!("bad threshold '{s}': expected a distance like 0.01 or a percentage of the diagonal like 0.1%"));
        let x: f64 = num.parse().map_err(|_| bad())?;
        if !x.is_finite() || x < 0.0 || num.starts_with('+') {
            return Err(bad());
        }
        Ok(if pct { Threshold::Percent(x) } else { Threshold::Absolute(x) })
    }
    /// The absolute limit for a given diagonal.
    pub fn limit(&self, diagonal: f64) -> f64 {
        match *self {
            Threshold::Absolute(x) => x,
            Threshold::Percent(p) => p / 100.0 * diagonal,
        }
    }
}

impl fmt::Display for Threshold {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Threshold::Absolute(x) => write!(f, "{x}"),
            Threshold::Percent(p) => write!(f, "{p}%"),
        }
    }
}

/// Limits on the combined figures.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Limits {
    pub hausdorff: Option<Threshold>,
    pub rms: Option<Threshold>,
    pub mean: Option<Threshold>,
}

impl Limits {
    /// Parses the three optional CLI strings.
    pub fn parse(hausdorff: Option<&str>, rms: Option<&str>, mean: Option<&str>) -> Result<Limits> {
        let p = |s: Option<&str>| s.map(Threshold::parse).transpose();
        Ok(Limits { hausdorff: p(hausdorff)?, rms: p(rms)?, mean: p(mean)? })
    }
}

/// One threshold checked against the combined figures.
#[derive(Clone, Debug, PartialEq)]
pub struct Check {
    /// `hausdorff`, `rms` or `mean`.
    pub metric: &'static str,
    /// The CLI option, e.g. `--max-hausdorff`.
    pub option: &'static str,
    pub threshold: Threshold,
    /// Absolute limit.
    pub limit: f64,
    pub value: f64,
    pub exceeded: bool,
}

impl Report {
    /// Every given threshold, exceeded or not (value > limit exceeds).
    pub fn check(&self, limits: &Limits) -> Vec<Check> {
        let c = &self.combined;
        [
            ("hausdorff", "--max-hausdorff", limits.hausdorff, c.max),
            ("rms", "--max-rms", limits.rms, c.rms),
            ("mean", "--max-mean", limits.mean, c.mean),
        ]
        .into_iter()
        .filter_map(|(metric, option, t, value)| {
            t.map(|threshold| {
                let limit = threshold.limit(self.diagonal);
                Check { metric, option, threshold, limit, value, exceeded: value > limit }
            })
        })
        .collect()
    }

    fn rel(&self, x: f64) -> f64 {
        if self.diagonal > 0.0 {
            x / self.diagonal
        } else {
            f64::NAN
        }
    }

    /// One JSON object (no timings: a pure function of the inputs, options
    /// and seed).
    pub fn to_json(&self, limits: &Limits) -> String {
        let mesh = |m: &MeshSummary| {
            format!(
                "{{\"source\":{},\"vertices\":{},\"faces\":{},\"area\":{},\"bbox\":{{\"min\":{},\"max\":{}}},\"diagonal\":{}}}",
                jstr(&m.source),
                m.vertices,
                m.faces,
                jnum(m.area),
                jvec(m.bbox.min),
                jvec(m.bbox.max),
                jnum(m.bbox.diagonal())
            )
        };
        let dist = |d: &Distances| {
            format!(
                "{{\"samples\":{},\"vertex_samples\":{},\"edge_samples\":{},\"face_samples\":{},\"max\":{},\"mean\":{},\"rms\":{},\"max_rel\":{},\"mean_rel\":{},\"rms_rel\":{},\"max_at\":{}}}",
                d.samples,
                d.vertex_samples,
                d.edge_samples,
                d.face_samples,
                jnum(d.max),
                jnum(d.mean),
                jnum(d.rms),
                jnum(self.rel(d.max)),
                jnum(self.rel(d.mean)),
                jnum(self.rel(d.rms)),
                jvec(d.max_at)
            )
        };
        let checks = self.check(limits);
        let th: Vec<String> = checks
            .iter()
            .map(|c| {
                format!(
                    "{{\"metric\":{},\"option\":{},\"given\":{},\"limit\":{},\"value\":{},\"exceeded\":{}}}",
                    jstr(c.metric),
                    jstr(c.option),
                    jstr(&c.threshold.to_string()),
                    jnum(c.limit),
                    jnum(c.value),
                    c.exceeded
                )
            })
            .collect();
        format!(
            "{{\"a\":{},\"b\":{},\"diagonal\":{},\"diagonal_of\":\"a\",\"union_diagonal\":{},\"seed\":{},\"samples_target\":{},\"a_to_b\":{},\"b_to_a\":{},\"combined\":{},\"hausdorff\":{},\"hausdorff_rel\":{},\"thresholds\":[{}],\"pass\":{}}}",
            mesh(&self.a),
            mesh(&self.b),
            jnum(self.diagonal),
            jnum(self.union_diagonal),
            self.seed,
            self.samples_target,
            dist(&self.a_to_b),
            dist(&self.b_to_a),
            dist(&self.combined),
            jnum(self.combined.max),
            jnum(self.rel(self.combined.max)),
            th.join(","),
            !checks.iter().any(|c| c.exceeded)
        )
    }

    /// The human-readable report.
    pub fn table(&self) -> String {
        use std::fmt::Write as _;
        let mut s = String::new();
        let bb = |b: &Aabb| {
            format!(
                "[{:.6}, {:.6}, {:.6}] .. [{:.6}, {:.6}, {:.6}]",
                b.min[0], b.min[1], b.min[2], b.max[0], b.max[1], b.max[2]
            )
        };
        for (name, m) in [("A", &self.a), ("B", &self.b)] {
            let _ = writeln!(
                s,
                "{name}: {}: {} faces, {} vertices, area {:.6e}, bbox {}, diagonal {:.6e}",
                m.source,
                m.faces,
                m.vertices,
                m.area,
                bb(&m.bbox),
                m.bbox.diagonal()
            );
        }
        let _ = writeln!(
            s,
            "relative figures: % of A's bbox diagonal {:.6e} (union diagonal {:.6e}); {} samples per direction asked, seed {}",
            self.diagonal, self.union_diagonal, self.samples_target, self.seed
        );
        let _ = writeln!(
            s,
            "{:<9} {:>11} {:>10} {:>10} {:>10} {:>13} {:>13} {:>13} {:>10} {:>10} {:>10}",
            "direction", "samples", "vertex", "edge", "face", "max", "mean", "rms", "max %", "mean %", "rms %"
        );
        for (name, d) in [("A -> B", &self.a_to_b), ("B -> A", &self.b_to_a), ("both", &self.combined)] {
            let _ = writeln!(
                s,
                "{name:<9} {:>11} {:>10} {:>10} {:>10} {:>13.6e} {:>13.6e} {:>13.6e} {:>10.5} {:>10.5} {:>10.5}",
                d.samples,
                d.vertex_samples,
                d.edge_samples,
                d.face_samples,
                d.max,
                d.mean,
                d.rms,
                100.0 * self.rel(d.max),
                100.0 * self.rel(d.mean),
                100.0 * self.rel(d.rms)
            );
        }
        let _ = writeln!(
            s,
            "hausdorff (two-sided): {:.6e} ({:.5}% of diagonal), at [{}, {}, {}]",
            self.combined.max,
            100.0 * self.rel(self.combined.max),
            self.combined.max_at[0],
            self.combined.max_at[1],
            self.combined.max_at[2]
        );
        let t = &self.seconds;
        let q = t.a_to_b + t.b_to_a;
        let _ = write!(
            s,
            "time: load {:.3} s, BVH {:.3} s, A -> B {:.3} s, B -> A {:.3} s; {:.3} M samples/s",
            t.load,
            t.bvh,
            t.a_to_b,
            t.b_to_a,
            self.combined.samples as f64 / 1e6 / q.max(1e-9)
        );
        s
    }
}

fn jnum(x: f64) -> String {
    if x.is_finite() {
        format!("{x:?}")
    } else {
        "null".into()
    }
}

fn jvec(p: P3) -> String {
    format!("[{},{},{}]", jnum(p[0]), jnum(p[1]), jnum(p[2]))
}

fn jstr(s: &str) -> String {
    let mut o = String::with_capacity(s.len() + 2);
    o.push('"');
    for c in s.chars() {
        match c {
            '"' => o.push_str("\\\""),
            '\\' => o.push_str("\\\\"),
            '\n' => o.push_str("\\n"),
            '\r' => o.push_str("\\r"),
            '\t' => o.push_str("\\t"),
            c if (c as u32) < 0x20 => o.push_str(&format!("\\u{:04x}", c as u32)),
            c => o.push(c),
        }
    }
    o.push('"');
    o
}

// ---------------------------------------------------------------------------
// Command line.

/// `octolod metro A B [--samples N] [--seed S] [--json] [--max-hausdorff X]
/// [--max-rms Y] [--max-mean Z]`.
#[derive(Clone, Debug, Default)]
pub struct CliArgs {
    pub a: String,
    pub b: String,
    pub samples: Option<u64>,
    pub seed: u64,
    pub json: bool,
    pub max_hausdorff: Option<String>,
    pub max_rms: Option<String>,
    pub max_mean: Option<String>,
    pub quiet: bool,
}

/// Runs the command: prints the table (or JSON) on stdout and each exceeded
/// threshold on stderr. Ok(false) when a threshold is exceeded (the binary
/// then exits with [`EXIT_THRESHOLD`]).
pub fn run_cli(args: &CliArgs) -> Result<bool> {
    let limits = Limits::parse(args.max_hausdorff.as_deref(), args.max_rms.as_deref(), args.max_mean.as_deref())?;
    if args.samples == Some(0) {
        return Err(Error::Usage("metro: --samples must be at least 1".into()));
    }
    let (sa, sb) = (Source::parse(&args.a)?, Source::parse(&args.b)?);
    let t0 = Instant::now();
    let (a, b) = rayon::join(|| sa.load(), || sb.load());
    let (a, b) = (a?, b?);
    let load = t0.elapsed().as_secs_f64();
    let mut r = compare(&a, &b, &Options { samples: args.samples, seed: args.seed, quiet: args.quiet })?;
    r.a.source = sa.to_string();
    r.b.source = sb.to_string();
    r.seconds.load = load;
    let mut out = std::io::stdout().lock();
    let text = if args.json { r.to_json(&limits) } else { r.table() };
    let _ = writeln!(out, "{text}");
    let _ = out.flush();
    let checks = r.check(&limits);
    let mut ok = true;
    for c in checks.iter().filter(|c| c.exceeded) {
        ok = false;
        eprintln!(
            "octolod: metro: {} {:.6e} exceeds {} {} (limit {:.6e})",
            c.metric, c.value, c.option, c.threshold, c.limit
        );
    }
    Ok(ok)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn brute_closest(m: &Mesh, p: P3) -> f64 {
        (0..m.triangles.len())
            .map(|t| {
                let c = m.corners(t);
                dist2(p, closest_point_triangle(p, c[0], c[1], c[2]))
            })
            .fold(f64::INFINITY, f64::min)
    }

    /// Closest point by dense parametric search plus local refinement (reference).
    fn reference_d2(p: P3, a: P3, b: P3, c: P3) -> f64 {
        let mut best = f64::INFINITY;
        let n = 200;
        for i in 0..=n {
            for j in 0..=(n - i) {
                let (u, v) = (i as f64 / n as f64, j as f64 / n as f64);
                let q = add(a, add(scale(sub(b, a), u), scale(sub(c, a), v)));
                best = best.min(dist2(p, q));
            }
        }
        for (s, e) in [(a, b), (b, c), (c, a)] {
            best = best.min(dist2(p, closest_point_segment(p, s, e)));
        }
        best
    }

    fn close(a: P3, b: P3) -> bool {
        dist2(a, b).sqrt() <= 1e-12
    }

    #[test]
    fn point_triangle_vertex_edge_and_face_regions() {
        let (a, b, c) = ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]);
        assert_eq!(TriKind::of(a, b, c), TriKind::Regular);
        let cases: [(P3, P3); 8] = [
            ([-1.0, -1.0, 1.0], a),             // vertex a
            ([2.0, -0.5, -3.0], b),             // vertex b
            ([-0.2, 3.0, 0.5], c),              // vertex c
            ([0.5, -1.0, 0.0], [0.5, 0.0, 0.0]), // edge ab
            ([-2.0, 0.25, 1.0], [0.0, 0.25, 0.0]), // edge ca
            ([1.0, 1.0, 0.0], [0.5, 0.5, 0.0]), // edge bc
            ([0.25, 0.25, 3.0], [0.25, 0.25, 0.0]), // face, above
            ([0.1, 0.2, -2.0], [0.1, 0.2, 0.0]), // face, below
        ];
        for (p, want) in cases {
            let q = closest_point_triangle(p, a, b, c);
            assert!(close(q, want), "p {p:?}: got {q:?}, want {want:?}");
            // Every corner order gives the same point.
            assert!(close(closest_point_triangle(p, b, c, a), want));
            assert!(close(closest_point_triangle(p, c, b, a), want));
        }
    }

    #[test]
    fn point_triangle_degenerate_and_thin() {
        // Collinear, c beyond b: the closest point is on segment bc.
        let (a, b, c) = ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]);
        assert_eq!(TriKind::of(a, b, c), TriKind::Degenerate);
        for (p, want) in [([1.8, 1.0, 0.0], [1.8, 0.0, 0.0]), ([3.0, 0.0, 1.0], c), ([-1.0, 2.0, 0.0], a)] {
            for q in [closest_point_triangle(p, a, b, c), closest_point_triangle(p, c, a, b), closest_point_triangle(p, b, c, a)] {
                assert!(q.iter().all(|x| x.is_finite()));
                assert!(close(q, want), "p {p:?}: got {q:?}, want {want:?}");
            }
        }
        // Repeated corner, and all three coincident.
        let q = closest_point_triangle([0.5, 1.0, 0.0], a, a, b);
        assert!(close(q, [0.5, 0.0, 0.0]), "{q:?}");
        let q = closest_point_triangle([1.0, 2.0, 3.0], b, b, b);
        assert_eq!(q, b);
        // A thin sliver (aspect 1e-7): inside the face, and just outside it.
        let (a, b, c) = ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.5, 1e-7, 0.0]);
        assert_eq!(TriKind::of(a, b, c), TriKind::Thin);
        let q = closest_point_triangle([0.5, 5e-8, 1.0], a, b, c);
        assert!(close(q, [0.5, 5e-8, 0.0]), "{q:?}");
        let q = closest_point_triangle([0.5, 1.0, 0.0], a, b, c);
        assert!(close(q, c), "{q:?}");
        let q = closest_point_triangle([0.25, -1.0, 0.0], a, b, c);
        assert!(close(q, [0.25, 0.0, 0.0]), "{q:?}");
    }

    #[test]
    fn point_triangle_matches_a_dense_reference_on_random_triangles() {
        let mut rng = Rng::new(7);
        let mut r = || 2.0 * rng.f64() - 1.0;
        for k in 0..300 {
            let a = [r(), r(), r()];
            let b = [r(), r(), r()];
            // Every third triangle thin or degenerate.
            let c = match k % 3 {
                0 => [r(), r(), r()],
                1 => add(a, scale(sub(b, a), 1.7)),
                _ => add(add(a, scale(sub(b, a), 0.3)), [1e-5 * r(), 1e-5 * r(), 1e-5 * r()]),
            };
            let p = [2.0 * r(), 2.0 * r(), 2.0 * r()];
            let q = closest_point_triangle(p, a, b, c);
            let d = dist2(p, q).sqrt();
            let want = reference_d2(p, a, b, c).sqrt();
            let longest = [dist2(a, b), dist2(b, c), dist2(c, a)].into_iter().fold(0.0, f64::max).sqrt();
            // The grid reference is an upper bound, within its spacing.
            assert!(d <= want + 1e-12, "case {k}: {d} > reference {want}");
            assert!(d >= want - longest / 150.0, "case {k}: {d} far below reference {want}");
            // The point lies on the triangle: its distance to it is ~0.
            let back = dist2(q, closest_point_triangle(q, a, b, c)).sqrt();
            assert!(back < 1e-9, "case {k}: returned point is {back} off the triangle");
        }
    }

    fn random_mesh(n: usize, seed: u64) -> Mesh {
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

    #[test]
    fn bvh_closest_equals_brute_force() {
        for (n, seed) in [(1usize, 1u64), (3, 2), (37, 3), (1500, 4)] {
            let m = random_mesh(n, seed);
            let bvh = Bvh::new(&m);
            assert_eq!(bvh.len(), n);
            let mut rng = Rng::new(seed + 100);
            let mut hint = u32::MAX;
            for _ in 0..400 {
                let p = [1.6 * rng.f64() - 0.3, 1.6 * rng.f64() - 0.3, 1.6 * rng.f64() - 0.3];
                let got = bvh.closest(p).unwrap();
                let want = brute_closest(&m, p);
                assert!((got.dist2 - want).abs() <= 1e-12 * want.max(1e-300), "n {n}: {} vs {want}", got.dist2);
                // The reported triangle and point agree with the distance.
                let c = m.corners(got.triangle as usize);
                let q = closest_point_triangle(p, c[0], c[1], c[2]);
                assert!((dist2(p, q) - got.dist2).abs() <= 1e-12 * want.max(1e-300));
                // Seeded with a (usually wrong) hint: same answer.
                let (d2, slot, _) = bvh.nearest(p, hint);
                assert!((d2 - want).abs() <= 1e-12 * want.max(1e-300));
                hint = slot;
            }
        }
    }

    #[test]
    fn bvh_large_enough_for_the_parallel_build_is_well_formed() {
        let m = random_mesh(PAR_BUILD + 5000, 9);
        let bvh = Bvh::new(&m);
        // Every triangle exactly once, in leaves that cover it.
        let mut seen = vec![false; m.triangles.len()];
        for (k, n) in bvh.nodes.iter().enumerate() {
            if n.count > 0 {
                for s in n.start..n.start + n.count {
                    let id = bvh.ids[s as usize] as usize;
                    assert!(!seen[id]);
                    seen[id] = true;
                    for p in m.corners(id) {
                        assert!((0..3).all(|a| n.min[a] <= p[a] && p[a] <= n.max[a]));
                    }
                }
            } else {
                assert!(n.start as usize > k + 1 && (n.start as usize) < bvh.nodes.len());
            }
        }
        assert!(seen.iter().all(|&s| s));
        let mut rng = Rng::new(5);
        for _ in 0..50 {
            let p = [rng.f64(), rng.f64(), rng.f64()];
            let want = brute_closest(&m, p);
            assert!((bvh.closest(p).unwrap().dist2 - want).abs() <= 1e-12 * want);
        }
    }

    #[test]
    fn stratified_face_samples_stay_on_the_face_and_spread() {
        let c = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        for n in [1u64, 2, 3, 7, 10, 100] {
            let mut quad = [0u32; 4];
            for i in 0..n {
                let mut rng = Rng::new(i * 31 + n);
                let p = face_sample(&c, i, n, 0.37, &mut rng);
                assert!(p[0] >= 0.0 && p[1] >= 0.0 && p[0] + p[1] <= 1.0 + 1e-15 && p[2] == 0.0, "{p:?}");
                // Which quarter (by the 4 similar sub-triangles).
                let q = if p[0] >= 0.5 { 1 } else if p[1] >= 0.5 { 2 } else if p[0] + p[1] <= 0.5 { 0 } else { 3 };
                quad[q] += 1;
            }
            if n == 100 {
                // Stratified: each quarter of the area gets 25 ± 3.
                assert!(quad.iter().all(|&k| (22..=28).contains(&k)), "{quad:?}");
            }
        }
    }

    #[test]
    fn sample_plan_follows_metro_budget() {
        // Unit square of 2 triangles.
        let m = Mesh::new(
            vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0], [5.0, 5.0, 5.0]],
            vec![[0, 1, 2], [0, 2, 3]],
        );
        let plan = Plan::new(&m, 1000, 1);
        let (v, e, f) = plan.counts();
        assert_eq!(v, 4, "the unreferenced vertex is not sampled");
        assert_eq!(plan.edges.len(), 5);
        // R = 996; sqrt(996) per unit length over total length 4 + sqrt 2.
        let want_e = (996f64.sqrt() * (4.0 + 2f64.sqrt())).floor() as u64;
        assert!(e.abs_diff(want_e) <= 1, "{e} vs {want_e}");
        assert!((v + e + f).abs_diff(1000) <= 1, "{v} + {e} + {f}");
        // A small budget: Metro's density would put sqrt(20) * 5.41 = 24 samples
        // on the edges, more than the 20 the vertices leave; the cap keeps 10 %
        // for the faces.
        let (v, e, f) = Plan::new(&m, 24, 1).counts();
        assert!(v == 4 && (17..=18).contains(&e) && e + f == 20, "{v} {e} {f}");
        // Budget below the vertex count: vertices only.
        let (v, e, f) = Plan::new(&m, 3, 1).counts();
        assert_eq!((v, e, f), (4, 0, 0));
    }

    #[test]
    fn thresholds_parse() {
        assert_eq!(Threshold::parse("0.01").unwrap(), Threshold::Absolute(0.01));
        assert_eq!(Threshold::parse("0.1%").unwrap(), Threshold::Percent(0.1));
        assert_eq!(Threshold::parse("1e-3").unwrap(), Threshold::Absolute(1e-3));
        assert_eq!(Threshold::parse("2 %").unwrap(), Threshold::Percent(2.0));
        for bad in ["", "%", "abc", "1%%", "-1", "-0.5%", "nan", "inf", "1x", "+1"] {
            assert!(matches!(Threshold::parse(bad), Err(Error::Usage(_))), "'{bad}' accepted");
        }
        assert_eq!(Threshold::Percent(0.5).limit(4.0), 0.02);
        assert_eq!(Threshold::Absolute(0.5).limit(4.0), 0.5);
    }

    #[test]
    fn results_do_not_depend_on_thread_count() {
        let a = random_mesh(300, 11);
        let b = random_mesh(200, 12);
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| compare(&a, &b, &Options { samples: Some(3 * CHUNK + 123), seed: 4, quiet: true }).unwrap())
        };
        let (r1, r3) = (run(1), run(3));
        assert_eq!(r1.to_json(&Limits::default()), r3.to_json(&Limits::default()));
        assert_eq!(r1.combined.sum.to_bits(), r3.combined.sum.to_bits());
        assert!(r1.combined.max > 0.0);
        let r_other = compare(&a, &b, &Options { samples: Some(3 * CHUNK + 123), seed: 5, quiet: true }).unwrap();
        assert_ne!(r1.combined.sum, r_other.combined.sum, "the seed changes the face samples");
    }

    #[test]
    fn json_escapes_and_numbers() {
        assert_eq!(jstr("a\"b\\c\n"), "\"a\\\"b\\\\c\\n\"");
        assert_eq!(jnum(f64::NAN), "null");
        assert_eq!(jnum(1.0), "1.0");
        assert_eq!(jnum(1e-7), "1e-7");
    }
}

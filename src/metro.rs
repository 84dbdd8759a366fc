//! Metro: the two-sided surface distance between two triangle meshes, after
//! Cignoni, Rocchini and Scopigno, "Metro: measuring error on simplified
//! surfaces" (1998), as implemented by vcglib's `metro`.
//!
//! Takes: two meshes `A` and `B`, each a PLY path (held in memory whole) or
//! `STORE@L` (level `L` of an octolod store, paged: see "Paging" below; it
//! measures as the level's whole-level cut with bit-identical positions
//! welded, the mesh `octolod extract` writes), a sample budget, a seed and a
//! memory budget (`--mem`). Gives: per direction (`A -> B`: samples on A, distance to the closest
//! point of B; `B -> A` the other way) and combined, the maximum (Hausdorff),
//! mean and RMS distance and the sample counts, each absolute and relative to
//! **the bounding-box diagonal of A** (A is meant to be the reference, e.g.
//! the original, so figures for several simplifications of it share one
//! scale; vcglib's Metro divides by the diagonal of the union box instead,
//! which the report also lists). Combined figures: max of the two maxima;
//! mean and RMS over all samples of both directions together (so with the
//! default budget, equal sample counts, the combined mean is the average of
//! the two directional means). Bounding boxes, areas, vertex and face counts
//! of both meshes come with it.
//!
//! Sampling (per direction, of the source mesh S, total budget `N`, by
//! default `10 * max(faces of A, faces of B)` like Metro, `--samples`
//! overrides): as in vcglib's `Sampling::Hausdorff`,
//! 1. every vertex referenced by a triangle (unreferenced ones are not part
//!    of the surface), `V` samples — all of them even when `V >= N` — in the
//!    order of first reference (face by face, corner by corner);
//! 2. with `R = N - V` left, every unique edge gets samples at equally spaced
//!    interior points, `sqrt(R / area(S))` per unit length exactly like
//!    Metro (the spacing the face samples will have), which at the default
//!    budget puts about 70 % of the samples on edges (~7 per face of the
//!    larger mesh). One guard Metro lacks: the edges take at most
//!    [`EDGE_SHARE_MAX`] (90 %) of `R`, which only binds below ~6 samples
//!    per face, where Metro's edges would take the whole budget and leave
//!    the face interiors (where a simplification's error peaks) unsampled.
//!    Length-proportional, fractions carried from edge to edge in edge
//!    order: the order of first occurrence (face `f`'s corner `k` meets edge
//!    `(t[k], t[k+1])`), each edge directed as first met;
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
//! Determinism: samples are summed in fixed jobs of [`CHUNK`] samples
//! (vertex jobs, then edge jobs, then face jobs, each starting at a multiple
//! of `CHUNK` within its kind), generated and queried a batch of jobs at a
//! time in parallel with rayon; each job sums sequentially, and the job
//! partial sums are combined in job order, so every figure is bit-identical
//! for a given seed whatever the thread count, batch size or memory budget.
//! The JSON report holds no timings, so it can be diffed; its `paging`
//! object (present only with a store operand) holds cache counters and peak
//! RSS, which depend on scheduling.
//!
//! Paging (a `STORE@L` operand): the level is never loaded whole. Opening
//! it reads `nodes.bin` (kept in memory, ~300 bytes a node) and the cut's
//! node meshes once, in parallel, for their exact bounds (the nodes'
//! `content` boxes bound the original triangles, not a simplified mesh,
//! whose cluster representatives may leave them). The cut's nodes are the
//! level's *parts*; a hierarchy over their bounds is the top level of its
//! index. A part is read with one positioned read when needed and kept in
//! one LRU page cache shared by both operands, under a byte budget: as a
//! query target, its triangles' BVH (built on load); as a sample source,
//! its mesh welded in first-reference order with its edges and sorted
//! lookups. Resident bytes are the heap bytes of live entries (cached, or
//! evicted but still held by a query) plus a reservation, for each load in
//! flight, of the load's estimated peak (payload, decoded vertices, weld
//! map, the structure being built), an upper bound swapped for the real
//! size once built; the cache evicts unheld entries, least recently used
//! first, before a reservation would exceed its budget.
//! * Queries against a paged level come a batch at a time (up to 1 M
//!   samples), sorted along a Morton curve of the target's box, in pieces
//!   of consecutive queries per worker. A worker keeps the part of its last
//!   answer (its *home*) and searches it first, which bounds the rest: only
//!   a part whose box is nearer than the best so far can hold a nearer
//!   point, and such a box lies within `d + dist(p, home box)` of the home
//!   box, so the worker's list of the parts near its home (rebuilt with
//!   twice the radius when a query reaches past it) settles the query;
//!   without a home, a nearer-child-first walk of the box tree does. A part
//!   is searched (loaded if needed) only while its box is nearer than the
//!   best so far. Each answer is the minimum over the same triangles as in
//!   memory, so the distances equal the in-memory ones (bit for bit but for
//!   a near-tie pruned differently by the two hierarchies).
//! * Sampling a paged level gives the samples the welded level would give
//!   in memory, in the same order: parts in cut order (the in-memory
//!   concatenation order), in each its vertices and edges in first-
//!   reference and first-occurrence order, skipping those an earlier part
//!   already has (bit-identical positions; only earlier parts whose bounds
//!   meet this part's are asked), then its faces, with the carried
//!   fractions running across parts and faces numbered globally. That takes
//!   three passes over the parts: vertices (which also totals the area and
//!   the owned edges' length the densities need), edges, faces.
//! * Budget: `--mem` (default [`DEFAULT_MEM`]) covers the batch buffers
//!   (48 bytes a sample) and the cache; given explicitly, also each PLY
//!   operand's estimated in-memory size ([`ply_estimate`]); a PLY that does
//!   not fit is streamed into a scratch store of its level 0 (the exact
//!   input: soup + octree under `--mem`, leaves sized to the budget) and
//!   paged like a store level. The cache must hold what one direction holds at once: a paged
//!   source's current part and one earlier part, and two parts per query
//!   worker (its home and one other); the number of workers is cut to fit,
//!   and a budget below one worker's worth is a usage error naming the
//!   minimum. Fixed overheads (the store indexes, thread stacks) come on
//!   top; the report gives the cache's peak and the process's peak RSS.
//!
//! Complexity: building each BVH is O(F log F) time and O(F) memory (about
//! 100 bytes a triangle with the reordered copy of its corners); sampling is
//! O(N) plus an O(F) prefix pass and an O(E log E) edge sort; each query is
//! O(log F) expected on reasonable meshes (worst case O(F)), so a direction
//! costs O(N log F) and runs on all cores. Paged, memory is O(budget +
//! nodes) and each part is read once per pass and per role while the cache
//! holds the working set, more often below it (the report counts loads).
//!
//! Thresholds (`--max-hausdorff`, `--max-rms`, `--max-mean`) are checked
//! against the combined figures, absolute (`0.01`) or as a percentage of A's
//! diagonal (`0.1%`); the CLI exits with [`EXIT_THRESHOLD`] (3) when one is
//! exceeded, distinct from 1 for errors.

use crate::error::{Error, Location, Result};
use crate::mesh::{Aabb, Vertex};
use crate::progress::Progress;
use crate::store::{IndexedMesh, NodeRec, Store};
use rayon::prelude::*;
use std::collections::{BTreeMap, HashMap};
use std::fmt;
use std::io::Write;
use std::mem::size_of;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::sync::{Arc, Condvar, Mutex};
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
    store.check_level(level)?;
    let mut mesh = Mesh::default();
    let mut weld: HashMap<[u64; 3], u32> = HashMap::new();
    for i in store.level_nodes(level) {
        let n = &store.nodes[i];
        let m = store.read_node(i)?.mesh;
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
        Self::build(mesh, true)
    }
    /// `parallel: false` builds on the calling thread only: the page cache
    /// builds node indexes inside worker threads that must not pick up other
    /// work (and other cache entries) while they wait.
    fn build(mesh: &Mesh, parallel: bool) -> Bvh {
        let centroid = |t: usize| {
            let c = mesh.corners(t);
            ([0, 1, 2].map(|k| (c[0][k] + c[1][k] + c[2][k]) / 3.0), t as u32)
        };
        let n = mesh.triangles.len();
        let mut items: Vec<(P3, u32)> =
            if parallel { (0..n).into_par_iter().map(centroid).collect() } else { (0..n).map(centroid).collect() };
        let nodes = if items.is_empty() {
            Vec::new()
        } else if parallel {
            build(mesh, &mut items, 0)
        } else {
            let mut out = Vec::with_capacity(n / 2 + 1);
            build_seq(mesh, &mut items, 0, &mut out);
            out
        };
        let corners = |&(_, t): &(P3, u32)| mesh.corners(t as usize);
        let kind = |c: &[P3; 3]| TriKind::of(c[0], c[1], c[2]);
        let (tris, kinds): (Vec<[P3; 3]>, Vec<TriKind>) = if parallel {
            let tris: Vec<[P3; 3]> = items.par_iter().map(corners).collect();
            let kinds = tris.par_iter().map(kind).collect();
            (tris, kinds)
        } else {
            let tris: Vec<[P3; 3]> = items.iter().map(corners).collect();
            let kinds = tris.iter().map(kind).collect();
            (tris, kinds)
        };
        let mut bvh = Bvh { nodes, tris, kinds, ids: items.iter().map(|&(_, t)| t).collect() };
        bvh.nodes.shrink_to_fit();
        bvh
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
    /// Heap bytes held.
    pub fn bytes(&self) -> u64 {
        (self.nodes.capacity() * size_of::<Node>()
            + self.tris.capacity() * size_of::<[P3; 3]>()
            + self.kinds.capacity() * size_of::<TriKind>()
            + self.ids.capacity() * size_of::<u32>()) as u64
    }
    /// An upper bound of [`Bvh::bytes`] plus the build's temporaries for `f`
    /// triangles: leaves hold 2 to 4 triangles (median splits of more than
    /// 4), so there are at most `f` nodes.
    fn bytes_bound(f: u64) -> u64 {
        let node = size_of::<Node>() as u64;
        node * f.max(1) + (size_of::<[P3; 3]>() + size_of::<TriKind>() + size_of::<u32>()) as u64 * f
            + size_of::<(P3, u32)>() as u64 * f
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
        self.nearest_within(p, hint, f64::INFINITY).unwrap_or_else(|| {
            // Only possible with non-finite coordinates; answer something.
            let q = self.tri_closest(0, p);
            (dist2(p, q), 0, q)
        })
    }
    /// The closest point if its squared distance is below `bound2`:
    /// (squared distance, triangle slot, point). The answer is the minimum
    /// over the triangles of their computed squared distances whatever the
    /// hint or bound, so indexes over different groupings of the same
    /// triangles agree.
    fn nearest_within(&self, p: P3, hint: u32, bound2: f64) -> Option<(f64, u32, P3)> {
        let (mut best2, mut best, mut bq) = (bound2, u32::MAX, p);
        if self.nodes.is_empty() {
            return None;
        }
        if hint != u32::MAX {
            let q = self.tri_closest(hint, p);
            let d = dist2(p, q);
            if d < best2 {
                best2 = d;
                best = hint;
                bq = q;
            }
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
        (best != u32::MAX).then_some((best2, best, bq))
    }
}

/// A hierarchy over boxes, one box a leaf: the top level of a paged mesh,
/// over its parts' exact bounds.
struct BoxTree {
    nodes: Vec<Node>,
    /// Leaf `start` indexes this; the values are part indices.
    items: Vec<u32>,
}

impl BoxTree {
    /// Over the non-empty `boxes`.
    fn new(boxes: &[Aabb]) -> BoxTree {
        let mut items: Vec<(P3, u32)> =
            boxes.iter().enumerate().filter(|(_, b)| !b.is_empty()).map(|(i, b)| (b.center(), i as u32)).collect();
        let mut nodes = Vec::with_capacity(2 * items.len());
        if !items.is_empty() {
            box_build(boxes, &mut items, 0, &mut nodes);
        }
        BoxTree { nodes, items: items.iter().map(|&(_, i)| i).collect() }
    }
    /// Calls `f` with every part whose box meets `b` (closed boxes).
    fn overlapping(&self, b: &Aabb, mut f: impl FnMut(usize)) {
        if self.nodes.is_empty() {
            return;
        }
        let mut stack = vec![0u32];
        while let Some(i) = stack.pop() {
            let n = &self.nodes[i as usize];
            if !(0..3).all(|k| n.min[k] <= b.max[k] && b.min[k] <= n.max[k]) {
                continue;
            }
            if n.count > 0 {
                f(self.items[n.start as usize] as usize);
            } else {
                stack.push(n.start);
                stack.push(i + 1);
            }
        }
    }
}

fn box_build(boxes: &[Aabb], items: &mut [(P3, u32)], offset: usize, out: &mut Vec<Node>) {
    let (mut b, mut cb) = (Aabb::EMPTY, Aabb::EMPTY);
    for &(c, i) in items.iter() {
        b.merge(&boxes[i as usize]);
        cb.add(c);
    }
    if items.len() == 1 {
        out.push(Node { min: b.min, max: b.max, start: offset as u32, count: 1 });
        return;
    }
    let me = out.len();
    out.push(Node { min: b.min, max: b.max, start: 0, count: 0 });
    let axis = longest_axis(&cb);
    let mid = items.len() / 2;
    items.select_nth_unstable_by(mid, |x, y| x.0[axis].total_cmp(&y.0[axis]).then(x.1.cmp(&y.1)));
    let (l, r) = items.split_at_mut(mid);
    box_build(boxes, l, offset, out);
    out[me].start = out.len() as u32;
    box_build(boxes, r, offset + mid, out);
}

fn longest_axis(cb: &Aabb) -> usize {
    let ext = [0, 1, 2].map(|k| cb.max[k] - cb.min[k]);
    if ext[0] >= ext[1] && ext[0] >= ext[2] {
        0
    } else if ext[1] >= ext[2] {
        1
    } else {
        2
    }
}

#[inline]
fn inside(b: &Aabb, p: P3) -> bool {
    (0..3).all(|k| b.min[k] <= p[k] && p[k] <= b.max[k])
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
    let axis = longest_axis(&cb);
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

/// Metro's edge density, in samples per unit length, for `left` samples
/// after the vertices, area `area` and total edge length `total_len`: the
/// spacing of `left` face samples, `sqrt(left / area)`, with the
/// [`EDGE_SHARE_MAX`] cap; everything along the edges when there is no area.
fn edge_density(left: u64, area: f64, total_len: f64) -> f64 {
    if left == 0 {
        0.0
    } else if area > 0.0 {
        // Metro's density; the cap only binds at tiny budgets.
        (left as f64 / area).sqrt().min(EDGE_SHARE_MAX * left as f64 / total_len)
    } else if total_len > 0.0 {
        left as f64 / total_len
    } else {
        0.0
    }
}

/// Face samples per unit area for `left` samples after vertices and edges.
fn face_density(left: u64, area: f64) -> f64 {
    if left > 0 && area > 0.0 {
        left as f64 / area
    } else {
        0.0
    }
}

/// Metro's carried fractions, one element at a time: adds `x * density` to
/// the running `acc` and returns how many samples the element gets
/// (`floor(acc)` minus those handed out so far, `prev`).
#[inline]
fn carry(acc: &mut f64, prev: &mut u64, x: f64, density: f64) -> u64 {
    *acc += x * density;
    let c = (acc.floor() as u64).max(*prev);
    let n = c - *prev;
    *prev = c;
    n
}

/// `prefix[i+1]` = samples on elements `..=i` by [`carry`].
fn carry_prefix(w: &[f64], density: f64, prefix: &mut [u64]) {
    let (mut acc, mut prev) = (0.0f64, 0u64);
    prefix[0] = 0;
    for (i, &x) in w.iter().enumerate() {
        carry(&mut acc, &mut prev, x, density);
        prefix[i + 1] = prev;
    }
}

#[inline]
fn seg_len(a: P3, b: P3) -> f64 {
    dist2(a, b).sqrt()
}

/// Sample `i` of the `n` equally spaced interior points of edge `ab`.
#[inline]
fn edge_point(a: P3, b: P3, i: u64, n: u64) -> P3 {
    add(a, scale(sub(b, a), (i + 1) as f64 / (n + 1) as f64))
}

/// The per-face seed and stratification offset of face `fi` (global index).
#[inline]
fn face_seed(seed: u64, fi: u64) -> (u64, f64) {
    let fseed = seed ^ mix64(fi.wrapping_mul(GOLDEN) ^ 0xFACE);
    (fseed, Rng::new(fseed).f64())
}

/// Sample `i` of a face's `n` stratified samples.
#[inline]
fn face_point(c: &[P3; 3], fseed: u64, offset: f64, i: u64, n: u64) -> P3 {
    let mut rng = Rng::new(fseed.wrapping_add(mix64(i + 1)));
    face_sample(c, i, n, offset, &mut rng)
}

/// The distinct edges of `triangles` in the order of first occurrence
/// (face by face, corner `k` giving edge `(t[k], t[k+1])`), each directed as
/// first met.
fn first_occurrence_edges(triangles: &[[u32; 3]], parallel: bool) -> Vec<[u32; 2]> {
    let occ = |(f, t): (usize, &[u32; 3])| {
        let t = *t;
        (0..3).map(move |k| {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            (((a.min(b) as u64) << 32) | a.max(b) as u64, 3 * f as u64 + k as u64)
        })
    };
    let mut keys: Vec<(u64, u64)> = if parallel {
        triangles.par_iter().enumerate().flat_map_iter(occ).collect()
    } else {
        triangles.iter().enumerate().flat_map(occ).collect()
    };
    if parallel {
        keys.par_sort_unstable();
    } else {
        keys.sort_unstable();
    }
    keys.dedup_by_key(|k| k.0);
    let mut first: Vec<u64> = keys.iter().map(|k| k.1).collect();
    drop(keys);
    if parallel {
        first.par_sort_unstable();
    } else {
        first.sort_unstable();
    }
    first
        .iter()
        .map(|&o| {
            let (t, k) = (&triangles[(o / 3) as usize], (o % 3) as usize);
            [t[k], t[(k + 1) % 3]]
        })
        .collect()
}

/// The sample plan of an in-memory mesh: which points, in which order.
struct Plan {
    /// Referenced vertices in the order of first reference.
    verts: Vec<u32>,
    /// See [`first_occurrence_edges`].
    edges: Vec<[u32; 2]>,
    /// `edge_prefix[e]` = samples on edges before `e` (len E + 1).
    edge_prefix: Vec<u64>,
    face_prefix: Vec<u64>,
    seed: u64,
}

impl Plan {
    fn new(src: &Mesh, target: u64, seed: u64) -> Plan {
        let verts = src.first_reference_vertices();
        let edges = first_occurrence_edges(&src.triangles, true);
        let areas: Vec<f64> = (0..src.triangles.len()).into_par_iter().map(|t| tri_area(src.corners(t))).collect();
        let area = areas.iter().fold(0.0, |s, &a| s + a);
        let left = target.saturating_sub(verts.len() as u64);
        let mut edge_prefix = vec![0u64; edges.len() + 1];
        let mut face_prefix = vec![0u64; areas.len() + 1];
        if left > 0 {
            let pos = &src.positions;
            let lens: Vec<f64> = edges.par_iter().map(|e| seg_len(pos[e[0] as usize], pos[e[1] as usize])).collect();
            let total = lens.iter().fold(0.0, |s, &l| s + l);
            carry_prefix(&lens, edge_density(left, area, total), &mut edge_prefix);
            let left = left.saturating_sub(edge_prefix[edges.len()]);
            carry_prefix(&areas, face_density(left, area), &mut face_prefix);
        }
        Plan { verts, edges, edge_prefix, face_prefix, seed }
    }
    fn counts(&self) -> (u64, u64, u64) {
        (self.verts.len() as u64, *self.edge_prefix.last().unwrap(), *self.face_prefix.last().unwrap())
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

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    Vertex,
    Edge,
    Face,
}

/// A run of consecutive samples of one kind, the unit of summation: it
/// starts at a multiple of [`CHUNK`] within its kind and holds at most
/// `CHUNK` samples, so the partial sums, added in job order, do not depend
/// on threads, batches or paging.
#[derive(Clone, Copy, Debug)]
struct Job {
    /// Index of the first sample within its kind (a multiple of CHUNK).
    start: u64,
    len: usize,
    /// Offset of the first sample in the batch.
    at: usize,
}

/// Produces the samples of one direction in order, a batch of whole jobs at a time.
trait Gen {
    /// Appends whole jobs to `points`/`jobs` (at least one if any is left,
    /// no more than `max` samples unless a single job is larger). False when
    /// nothing was left.
    fn fill(&mut self, points: &mut Vec<P3>, jobs: &mut Vec<Job>, max: usize) -> Result<bool>;
    /// (vertex, edge, face) samples, final once `fill` returned false.
    fn counts(&self) -> (u64, u64, u64);
}

/// The samples of an in-memory mesh, from its [`Plan`], generated in parallel.
struct MemGen<'a> {
    src: &'a Mesh,
    plan: Plan,
    /// (kind, first, end) of every job, in order.
    jobs: Vec<(Kind, u64, u64)>,
    next: usize,
}

impl<'a> MemGen<'a> {
    fn new(src: &'a Mesh, target: u64, seed: u64) -> MemGen<'a> {
        let plan = Plan::new(src, target, seed);
        let (nv, ne, nf) = plan.counts();
        let mut jobs = Vec::new();
        for (kind, n) in [(Kind::Vertex, nv), (Kind::Edge, ne), (Kind::Face, nf)] {
            let mut s = 0;
            while s < n {
                jobs.push((kind, s, (s + CHUNK).min(n)));
                s += CHUNK;
            }
        }
        MemGen { src, plan, jobs, next: 0 }
    }
}

impl Gen for MemGen<'_> {
    fn fill(&mut self, points: &mut Vec<P3>, jobs: &mut Vec<Job>, max: usize) -> Result<bool> {
        let first = self.next;
        let base = points.len();
        let mut end = base;
        while self.next < self.jobs.len() {
            let (_, s, e) = self.jobs[self.next];
            let len = (e - s) as usize;
            if self.next > first && end + len > max {
                break;
            }
            jobs.push(Job { start: s, len, at: end });
            end += len;
            self.next += 1;
        }
        if self.next == first {
            return Ok(false);
        }
        points.resize(end, [0.0; 3]);
        let mut rest = &mut points[base..];
        let mut work = Vec::with_capacity(self.next - first);
        for &(kind, s, e) in &self.jobs[first..self.next] {
            let (head, tail) = rest.split_at_mut((e - s) as usize);
            work.push((kind, s, e, head));
            rest = tail;
        }
        let (src, plan) = (self.src, &self.plan);
        work.into_par_iter().for_each(|(kind, s, e, out)| gen_job(src, plan, kind, s, e, out));
        Ok(true)
    }
    fn counts(&self) -> (u64, u64, u64) {
        self.plan.counts()
    }
}

/// Samples `[s, e)` of one kind into `out`.
fn gen_job(src: &Mesh, plan: &Plan, kind: Kind, s: u64, e: u64, out: &mut [P3]) {
    let mut k = 0usize;
    let mut put = |p: P3| {
        out[k] = p;
        k += 1;
    };
    match kind {
        Kind::Vertex => {
            for &v in &plan.verts[s as usize..e as usize] {
                put(src.positions[v as usize]);
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
                    for i in (g - lo)..(n.min(e - lo)) {
                        put(edge_point(a, b, i, n));
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
                    let (fseed, offset) = face_seed(plan.seed, fi as u64);
                    for i in (g - lo)..(n.min(e - lo)) {
                        put(face_point(&c, fseed, offset, i, n));
                    }
                }
                g = hi.max(g);
                fi += 1;
            }
        }
    }
    debug_assert_eq!(k, out.len());
}

// ---------------------------------------------------------------------------
// Paging: a store level as parts (its cut's nodes), node meshes on demand.

/// Default `--mem`.
pub const DEFAULT_MEM: u64 = 1 << 30;
/// Samples at most per batch (queried together, sorted along a Morton curve
/// when the target is paged).
const BATCH_MAX: usize = 1 << 20;
/// Bytes a batch costs per sample: the point, its distance, its sort key.
const BATCH_BYTES_PER_SAMPLE: u64 = 48;
/// Queries per unit of parallel work against a paged target.
const PIECE: usize = 1024;

/// Bytes of live cache entries and reservations, and their peak.
#[derive(Debug, Default)]
struct Acct {
    resident: AtomicU64,
    peak: AtomicU64,
}

impl Acct {
    fn add(&self, n: u64) {
        let r = self.resident.fetch_add(n, Relaxed) + n;
        self.peak.fetch_max(r, Relaxed);
    }
    fn sub(&self, n: u64) {
        self.resident.fetch_sub(n, Relaxed);
    }
    fn resident(&self) -> u64 {
        self.resident.load(Relaxed)
    }
}

/// What a part holds when it serves as a sample source: its mesh welded in
/// first-reference order, its edges, and lookups for the ownership test.
struct SrcPart {
    /// Distinct referenced positions, in the order of first reference.
    positions: Vec<P3>,
    triangles: Vec<[u32; 3]>,
    /// See [`first_occurrence_edges`].
    edges: Vec<[u32; 2]>,
    /// Position bits → index, sorted.
    sorted: Vec<([u64; 3], u32)>,
    /// `low << 32 | high` of every edge, sorted.
    edge_keys: Vec<u64>,
}

impl SrcPart {
    fn build(m: &IndexedMesh) -> SrcPart {
        let (positions, triangles) = weld_first_reference(m);
        let edges = first_occurrence_edges(&triangles, false);
        let mut sorted: Vec<([u64; 3], u32)> =
            positions.iter().enumerate().map(|(i, p)| (p.map(f64::to_bits), i as u32)).collect();
        sorted.sort_unstable();
        let mut edge_keys: Vec<u64> =
            edges.iter().map(|e| ((e[0].min(e[1]) as u64) << 32) | e[0].max(e[1]) as u64).collect();
        edge_keys.sort_unstable();
        SrcPart { positions, triangles, edges, sorted, edge_keys }
    }
    fn find(&self, p: P3) -> Option<u32> {
        let bits = p.map(f64::to_bits);
        self.sorted.binary_search_by(|x| x.0.cmp(&bits)).ok().map(|k| self.sorted[k].1)
    }
    fn has_edge(&self, p: P3, q: P3) -> bool {
        match (self.find(p), self.find(q)) {
            (Some(a), Some(b)) => self.edge_keys.binary_search(&(((a.min(b) as u64) << 32) | a.max(b) as u64)).is_ok(),
            _ => false,
        }
    }
    fn bytes(&self) -> u64 {
        (self.positions.capacity() * size_of::<P3>()
            + self.triangles.capacity() * size_of::<[u32; 3]>()
            + self.edges.capacity() * size_of::<[u32; 2]>()
            + self.sorted.capacity() * size_of::<([u64; 3], u32)>()
            + self.edge_keys.capacity() * size_of::<u64>()) as u64
    }
}

/// A node mesh with bit-identical positions merged and unreferenced ones
/// dropped, vertices numbered in the order of first reference (the weld
/// [`load_store_level`] does across the whole level, node by node).
fn weld_first_reference(m: &IndexedMesh) -> (Vec<P3>, Vec<[u32; 3]>) {
    let mut ids: HashMap<[u64; 3], u32> = HashMap::with_capacity(m.vertices.len());
    let mut positions = Vec::with_capacity(m.vertices.len());
    let mut triangles = Vec::with_capacity(m.triangles.len());
    for t in &m.triangles {
        triangles.push(t.map(|v| {
            let p = m.vertices[v as usize].pos;
            let next = positions.len() as u32;
            *ids.entry(p.map(f64::to_bits)).or_insert_with(|| {
                positions.push(p);
                next
            })
        }));
    }
    positions.shrink_to_fit();
    (positions, triangles)
}

enum Payload {
    Src(SrcPart),
    Tgt(Bvh),
}

impl Payload {
    fn bytes(&self) -> u64 {
        match self {
            Payload::Src(s) => s.bytes(),
            Payload::Tgt(b) => b.bytes(),
        }
    }
}

/// A cache entry; its bytes count as resident until the last holder drops it.
struct Entry {
    payload: Payload,
    bytes: u64,
    acct: Arc<Acct>,
}

impl Entry {
    fn src(&self) -> &SrcPart {
        match &self.payload {
            Payload::Src(s) => s,
            Payload::Tgt(_) => unreachable!("a query index where a sample source was expected"),
        }
    }
    fn bvh(&self) -> &Bvh {
        match &self.payload {
            Payload::Tgt(b) => b,
            Payload::Src(_) => unreachable!("a sample source where a query index was expected"),
        }
    }
}

impl Drop for Entry {
    fn drop(&mut self) {
        self.acct.sub(self.bytes);
    }
}

enum CacheSlot {
    Loading,
    Ready(Arc<Entry>, u64),
}

#[derive(Default)]
struct CacheState {
    map: HashMap<u64, CacheSlot>,
    /// Last-use tick → key.
    lru: BTreeMap<u64, u64>,
    tick: u64,
}

/// The page cache shared by the paged operands: node meshes and their
/// indexes, least recently used first out, under a byte budget. Resident
/// bytes are the heap bytes of live entries (cached or still held by a
/// query) plus reservations for loads in flight (the estimated peak of a
/// load: payload, decoded vertices, weld map, the structure being built),
/// swapped for the entry's real size once built.
pub struct Cache {
    budget: u64,
    acct: Arc<Acct>,
    state: Mutex<CacheState>,
    ready: Condvar,
    loads: AtomicU64,
    hits: AtomicU64,
    evictions: AtomicU64,
    overcommits: AtomicU64,
    bytes_read: AtomicU64,
    scan_bytes: AtomicU64,
}

/// Holds `bytes` of the budget until dropped.
struct Reservation<'a>(&'a Cache, u64);

impl Drop for Reservation<'_> {
    fn drop(&mut self) {
        self.0.acct.sub(self.1);
    }
}

impl Cache {
    fn new(budget: u64) -> Cache {
        Cache {
            budget,
            acct: Arc::new(Acct::default()),
            state: Mutex::new(CacheState::default()),
            ready: Condvar::new(),
            loads: AtomicU64::new(0),
            hits: AtomicU64::new(0),
            evictions: AtomicU64::new(0),
            overcommits: AtomicU64::new(0),
            bytes_read: AtomicU64::new(0),
            scan_bytes: AtomicU64::new(0),
        }
    }

    /// Evicts least recently used entries nobody holds until `need` more
    /// bytes fit (or nothing more can go: counted as an overcommit).
    fn make_room(&self, st: &mut CacheState, need: u64) {
        while self.acct.resident() + need > self.budget {
            let victim = st
                .lru
                .iter()
                .find(|(_, k)| matches!(st.map.get(k), Some(CacheSlot::Ready(e, _)) if Arc::strong_count(e) == 1))
                .map(|(&t, &k)| (t, k));
            let Some((t, k)) = victim else {
                self.overcommits.fetch_add(1, Relaxed);
                return;
            };
            st.lru.remove(&t);
            st.map.remove(&k);
            self.evictions.fetch_add(1, Relaxed);
        }
    }

    fn reserve(&self, bytes: u64) -> Reservation<'_> {
        let mut st = self.state.lock().unwrap();
        self.make_room(&mut st, bytes);
        self.acct.add(bytes);
        Reservation(self, bytes)
    }

    /// The entry for `key`, loading it with `load` (which returns the
    /// payload and the bytes it read) under a reservation of `estimate`
    /// bytes if absent. Concurrent requests for the same key wait for one load.
    fn get(&self, key: u64, estimate: u64, load: impl FnOnce() -> Result<(Payload, u64)>) -> Result<Arc<Entry>> {
        let mut st = self.state.lock().unwrap();
        loop {
            match st.map.get(&key) {
                Some(CacheSlot::Ready(e, t)) => {
                    let (e, t) = (e.clone(), *t);
                    st.tick += 1;
                    let now = st.tick;
                    st.lru.remove(&t);
                    st.lru.insert(now, key);
                    st.map.insert(key, CacheSlot::Ready(e.clone(), now));
                    self.hits.fetch_add(1, Relaxed);
                    return Ok(e);
                }
                Some(CacheSlot::Loading) => st = self.ready.wait(st).unwrap(),
                None => break,
            }
        }
        self.make_room(&mut st, estimate);
        self.acct.add(estimate);
        st.map.insert(key, CacheSlot::Loading);
        drop(st);
        let loaded = load();
        let mut st = self.state.lock().unwrap();
        st.map.remove(&key);
        let out = match loaded {
            Ok((payload, read)) => {
                let bytes = payload.bytes();
                if bytes > estimate {
                    self.acct.add(bytes - estimate);
                } else {
                    self.acct.sub(estimate - bytes);
                }
                let e = Arc::new(Entry { payload, bytes, acct: self.acct.clone() });
                st.tick += 1;
                let now = st.tick;
                st.lru.insert(now, key);
                st.map.insert(key, CacheSlot::Ready(e.clone(), now));
                self.loads.fetch_add(1, Relaxed);
                self.bytes_read.fetch_add(read, Relaxed);
                Ok(e)
            }
            Err(err) => {
                self.acct.sub(estimate);
                Err(err)
            }
        };
        drop(st);
        self.ready.notify_all();
        out
    }
}

const ROLE_SRC: u64 = 0;
const ROLE_TGT: u64 = 1;

/// Upper bounds of the bytes a part costs in the cache, from its slot.
#[derive(Clone, Copy, Debug, Default)]
struct PartCost {
    /// Reading and decoding: the payload buffer and the decoded mesh.
    load: u64,
    /// As a sample source (load, weld map and the built [`SrcPart`]).
    src: u64,
    /// As a query index (load, the mesh and the built [`Bvh`]).
    tgt: u64,
}

impl PartCost {
    fn of(s: &NodeRec) -> PartCost {
        let (v, f) = (s.verts as u64, s.tris as u64);
        let load = s.bytes as u64 + v * size_of::<Vertex>() as u64 + f * size_of::<[u32; 3]>() as u64;
        // Weld map (hashbrown: ≤ 2 buckets of 33 bytes per entry), positions,
        // triangles, edges (≤ 3f), their sort temporaries, sorted lookups.
        let src = load + 80 * v + 24 * v + 12 * f + 8 * 3 * f + 16 * 3 * f + 8 * 3 * f + 32 * v;
        let tgt = load + 24 * v + 12 * f + Bvh::bytes_bound(f);
        PartCost { load, src, tgt }
    }
}

/// A level of an octolod store opened for paging: the cut's nodes are its
/// parts, each read with one positioned read when needed.
pub struct PagedLevel {
    name: String,
    store: Store,
    /// Which operand (cache keys).
    op: u64,
    /// Store node of each part, in cut order (= the in-memory level's order).
    nodes: Vec<usize>,
    costs: Vec<PartCost>,
    /// Exact bounds of each part's triangles (from the opening scan).
    boxes: Vec<Aabb>,
    /// Triangles before each part (len parts + 1).
    face_base: Vec<u64>,
    tree: BoxTree,
    bbox: Aabb,
}

impl PagedLevel {
    /// Opens `dir`'s level `level` and scans its parts once (in parallel,
    /// each read under a reservation) for their exact bounds.
    fn open(dir: &Path, level: u8, name: String, op: u64, cache: &Cache, threads: usize, quiet: bool) -> Result<PagedLevel> {
        let store = Store::open(dir)?;
        store.check_level(level)?;
        let nodes = store.level_nodes(level);
        let costs: Vec<PartCost> = nodes.iter().map(|&i| PartCost::of(&store.nodes[i])).collect();
        let max_load = costs.iter().map(|c| c.load).max().unwrap_or(0).max(1);
        let t = threads.min((cache.budget / max_load).max(1) as usize).max(1);
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(t)
            .build()
            .map_err(|e| Error::Usage(format!("metro: cannot start {t} threads: {e}")))?;
        let progress = Progress::items(nodes.len() as u64, if op == 0 { "scan A" } else { "scan B" }, quiet);
        let scanned: Vec<(Aabb, u64)> = pool.install(|| {
            (0..nodes.len())
                .into_par_iter()
                .map(|k| {
                    let _r = cache.reserve(costs[k].load);
                    let m = store.read_node(nodes[k])?.mesh;
                    cache.scan_bytes.fetch_add(store.nodes[nodes[k]].bytes as u64, Relaxed);
                    let mut b = Aabb::EMPTY;
                    for t in &m.triangles {
                        for &i in t {
                            b.add(m.vertices[i as usize].pos);
                        }
                    }
                    progress.inc(1);
                    Ok((b, m.triangles.len() as u64))
                })
                .collect::<Result<Vec<_>>>()
        })?;
        progress.finish();
        let boxes: Vec<Aabb> = scanned.iter().map(|x| x.0).collect();
        let mut face_base = Vec::with_capacity(nodes.len() + 1);
        face_base.push(0u64);
        for x in &scanned {
            face_base.push(face_base.last().unwrap() + x.1);
        }
        let mut bbox = Aabb::EMPTY;
        for b in &boxes {
            bbox.merge(b);
        }
        let tree = BoxTree::new(&boxes);
        Ok(PagedLevel { name, store, op, nodes, costs, boxes, face_base, tree, bbox })
    }

    pub fn parts(&self) -> usize {
        self.nodes.len()
    }
    pub fn faces(&self) -> u64 {
        *self.face_base.last().unwrap()
    }
    fn max_src(&self) -> u64 {
        self.costs.iter().map(|c| c.src).max().unwrap_or(0)
    }
    fn max_tgt(&self) -> u64 {
        self.costs.iter().map(|c| c.tgt).max().unwrap_or(0)
    }
    fn key(&self, role: u64, part: usize) -> u64 {
        (self.op << 40) | (role << 32) | part as u64
    }
    fn read(&self, part: usize) -> Result<(IndexedMesh, u64)> {
        let m = self.store.read_node(self.nodes[part])?.mesh;
        Ok((m, self.store.nodes[self.nodes[part]].bytes as u64))
    }
    fn get_src(&self, cache: &Cache, part: usize) -> Result<Arc<Entry>> {
        cache.get(self.key(ROLE_SRC, part), self.costs[part].src, || {
            let (m, read) = self.read(part)?;
            Ok((Payload::Src(SrcPart::build(&m)), read))
        })
    }
    fn get_tgt(&self, cache: &Cache, part: usize) -> Result<Arc<Entry>> {
        cache.get(self.key(ROLE_TGT, part), self.costs[part].tgt, || {
            let (m, read) = self.read(part)?;
            let mesh = Mesh { positions: m.vertices.iter().map(|v| v.pos).collect(), triangles: m.triangles };
            Ok((Payload::Tgt(Bvh::build(&mesh, false)), read))
        })
    }

    /// Part `n` as a sample source, with which of its vertices (`want_v`)
    /// and edges (`want_e`) it owns: those no earlier part has (by bit-
    /// identical positions), so each vertex and edge of the welded level is
    /// sampled once, by the first part that has it, as in memory. Only
    /// earlier parts whose box meets part `n`'s can share anything with it.
    fn owned(&self, cache: &Cache, n: usize, want_v: bool, want_e: bool) -> Result<(Arc<Entry>, Vec<bool>, Vec<bool>)> {
        let e = self.get_src(cache, n)?;
        let s = e.src();
        let mut vown = vec![true; if want_v { s.positions.len() } else { 0 }];
        let mut eown = vec![true; if want_e { s.edges.len() } else { 0 }];
        let mut cands = Vec::new();
        self.tree.overlapping(&self.boxes[n], |m| {
            if m < n {
                cands.push(m)
            }
        });
        cands.sort_unstable();
        let mut within = vec![false; s.positions.len()];
        for m in cands {
            let bm = &self.boxes[m];
            let mut any = false;
            for (w, &p) in within.iter_mut().zip(&s.positions) {
                *w = inside(bm, p);
                any |= *w;
            }
            if !any {
                continue;
            }
            let em = self.get_src(cache, m)?;
            let sm = em.src();
            for (i, own) in vown.iter_mut().enumerate() {
                if *own && within[i] && sm.find(s.positions[i]).is_some() {
                    *own = false;
                }
            }
            for (k, own) in eown.iter_mut().enumerate() {
                let [a, b] = s.edges[k];
                if *own && within[a as usize] && within[b as usize] && sm.has_edge(s.positions[a as usize], s.positions[b as usize]) {
                    *own = false;
                }
            }
        }
        Ok((e, vown, eown))
    }
}

/// The samples of a paged level, part by part: the same points in the same
/// order as [`Plan`] gives for the welded level in memory (parts in cut
/// order; in each, its owned vertices and edges in first-reference and
/// first-occurrence order, then its faces), with Metro's carried fractions
/// running across parts. Three passes over the parts: vertices (which also
/// totals the area and the owned edges' length, needed for the densities),
/// edges, faces.
struct PagedGen<'a> {
    lvl: &'a PagedLevel,
    cache: &'a Cache,
    target: u64,
    seed: u64,
    kind: Kind,
    done: bool,
    /// Index of the next sample within its kind.
    idx: u64,
    part: usize,
    cur: Option<Arc<Entry>>,
    /// The current part's owned vertices or edges.
    list: Vec<u32>,
    /// Next element of the current part (list entry or face).
    li: usize,
    /// (next, count) of the current edge's or face's samples.
    sub: (u64, u64),
    elem: [P3; 3],
    fseed: u64,
    foffset: f64,
    nv: u64,
    area: f64,
    len_total: f64,
    per_len: f64,
    fdens: f64,
    acc: f64,
    prev: u64,
    ne: u64,
    nf: u64,
}

enum Step {
    Open,
    Close,
    Point(P3),
    Edge(P3, P3),
    Face([P3; 3]),
}

impl<'a> PagedGen<'a> {
    fn new(lvl: &'a PagedLevel, cache: &'a Cache, target: u64, seed: u64) -> PagedGen<'a> {
        PagedGen {
            lvl,
            cache,
            target,
            seed,
            kind: Kind::Vertex,
            done: false,
            idx: 0,
            part: 0,
            cur: None,
            list: Vec::new(),
            li: 0,
            sub: (0, 0),
            elem: [[0.0; 3]; 3],
            fseed: 0,
            foffset: 0.0,
            nv: 0,
            area: 0.0,
            len_total: 0.0,
            per_len: 0.0,
            fdens: 0.0,
            acc: 0.0,
            prev: 0,
            ne: 0,
            nf: 0,
        }
    }

    /// Figures of the welded level (valid after the vertex pass).
    fn summary(&self) -> MeshSummary {
        MeshSummary {
            source: self.lvl.name.clone(),
            vertices: self.nv,
            faces: self.lvl.faces(),
            area: self.area,
            bbox: self.lvl.bbox,
        }
    }

    fn open_part(&mut self) -> Result<()> {
        let n = self.part;
        self.li = 0;
        self.list.clear();
        match self.kind {
            Kind::Vertex => {
                let (e, vown, eown) = self.lvl.owned(self.cache, n, true, true)?;
                let s = e.src();
                for t in &s.triangles {
                    self.area += tri_area(t.map(|i| s.positions[i as usize]));
                }
                for (k, ed) in s.edges.iter().enumerate() {
                    if eown[k] {
                        self.len_total += seg_len(s.positions[ed[0] as usize], s.positions[ed[1] as usize]);
                    }
                }
                self.list.extend((0..s.positions.len() as u32).filter(|&i| vown[i as usize]));
                self.nv += self.list.len() as u64;
                self.cur = Some(e);
            }
            Kind::Edge => {
                let (e, _, eown) = self.lvl.owned(self.cache, n, false, true)?;
                self.list.extend((0..eown.len() as u32).filter(|&k| eown[k as usize]));
                self.cur = Some(e);
            }
            Kind::Face => self.cur = Some(self.lvl.get_src(self.cache, n)?),
        }
        Ok(())
    }

    /// Ends the current kind and sets up the next.
    fn next_kind(&mut self) {
        let handed = self.prev;
        (self.part, self.cur, self.idx, self.sub, self.li, self.acc, self.prev) = (0, None, 0, (0, 0), 0, 0.0, 0);
        self.list.clear();
        let left = self.target.saturating_sub(self.nv);
        match self.kind {
            Kind::Vertex => {
                self.per_len = edge_density(left, self.area, self.len_total);
                self.kind = Kind::Edge;
            }
            Kind::Edge => {
                self.ne = handed;
                self.fdens = face_density(left.saturating_sub(self.ne), self.area);
                self.kind = Kind::Face;
            }
            Kind::Face => {
                self.nf = handed;
                self.done = true;
            }
        }
    }

    /// The next sample of the current kind; None when the kind is exhausted.
    fn next_point(&mut self) -> Result<Option<P3>> {
        loop {
            if self.sub.0 < self.sub.1 {
                let (i, n) = self.sub;
                self.sub.0 += 1;
                return Ok(Some(match self.kind {
                    Kind::Edge => edge_point(self.elem[0], self.elem[1], i, n),
                    _ => face_point(&self.elem, self.fseed, self.foffset, i, n),
                }));
            }
            let step = match &self.cur {
                None => Step::Open,
                Some(e) => {
                    let s = e.src();
                    let at = |i: u32| s.positions[i as usize];
                    match self.kind {
                        Kind::Vertex if self.li < self.list.len() => Step::Point(at(self.list[self.li])),
                        Kind::Edge if self.li < self.list.len() => {
                            let [a, b] = s.edges[self.list[self.li] as usize];
                            Step::Edge(at(a), at(b))
                        }
                        Kind::Face if self.li < s.triangles.len() => Step::Face(s.triangles[self.li].map(at)),
                        _ => Step::Close,
                    }
                }
            };
            match step {
                Step::Point(p) => {
                    self.li += 1;
                    return Ok(Some(p));
                }
                Step::Edge(a, b) => {
                    self.li += 1;
                    let n = carry(&mut self.acc, &mut self.prev, seg_len(a, b), self.per_len);
                    self.elem = [a, b, b];
                    self.sub = (0, n);
                }
                Step::Face(c) => {
                    let f = self.lvl.face_base[self.part] + self.li as u64;
                    self.li += 1;
                    let n = carry(&mut self.acc, &mut self.prev, tri_area(c), self.fdens);
                    if n > 0 {
                        (self.fseed, self.foffset) = face_seed(self.seed, f);
                    }
                    self.elem = c;
                    self.sub = (0, n);
                }
                Step::Close => {
                    self.cur = None;
                    self.part += 1;
                }
                Step::Open => {
                    if self.part >= self.lvl.parts() {
                        return Ok(None);
                    }
                    self.open_part()?;
                }
            }
        }
    }
}

impl Gen for PagedGen<'_> {
    fn fill(&mut self, points: &mut Vec<P3>, jobs: &mut Vec<Job>, max: usize) -> Result<bool> {
        let before = jobs.len();
        while !self.done && (jobs.len() == before || points.len() + CHUNK as usize <= max) {
            let at = points.len();
            let start = self.idx;
            while self.idx - start < CHUNK {
                match self.next_point()? {
                    Some(p) => {
                        points.push(p);
                        self.idx += 1;
                    }
                    None => break,
                }
            }
            let len = (self.idx - start) as usize;
            if len > 0 {
                jobs.push(Job { start, len, at });
            }
            if len < CHUNK as usize {
                self.next_kind();
            }
        }
        Ok(jobs.len() > before)
    }
    fn counts(&self) -> (u64, u64, u64) {
        (self.nv, self.ne, self.nf)
    }
}

/// Where one direction looks for closest points.
enum Target<'a> {
    Mem(&'a Bvh),
    Paged { lvl: &'a PagedLevel, cache: &'a Cache, pool: rayon::ThreadPool },
}

/// A query worker's state against a paged target: the part of its last
/// answer, held (so the next, nearby query usually needs no cache lookup),
/// and the triangle slot there.
struct Worker {
    home: Option<(usize, Arc<Entry>)>,
    slot: u32,
    /// Box-tree nodes to visit, with their squared distance.
    stack: Vec<(u32, f64)>,
    /// Parts whose boxes come within `near_r` of part `near_of`'s box.
    near: Vec<u32>,
    near_r: f64,
    near_of: usize,
}

/// Squared distance from `p` to the box `b`.
#[inline]
fn box_dist2(b: &Aabb, p: P3) -> f64 {
    let e = |k: usize| (b.min[k] - p[k]).max(p[k] - b.max[k]).max(0.0);
    let (x, y, z) = (e(0), e(1), e(2));
    x * x + y * y + z * z
}

impl PagedLevel {
    /// Squared distance from `p` to the level: the home part first (which
    /// bounds the search), then the parts' box tree, nearer child first,
    /// each part searched only while its box is nearer than the best so far. A worker
    /// holds at most two entries at a time: its home and one other.
    fn closest(&self, cache: &Cache, p: P3, w: &mut Worker) -> Result<f64> {
        let (mut best2, mut best_part, mut best_slot) = (f64::INFINITY, usize::MAX, u32::MAX);
        let home = w.home.as_ref().map(|h| h.0);
        if let Some((hp, e)) = &w.home {
            if let Some((d, s, _)) = e.bvh().nearest_within(p, w.slot, f64::INFINITY) {
                (best2, best_part, best_slot) = (d, *hp, s);
            }
        }
        // With a home h and best distance d, a part m can only be nearer if
        // dist(p, box m) < d, so box m is within d + dist(p, box h) of box h:
        // the worker's list of parts near its home settles the query when
        // that sum is within the list's radius (consecutive queries share the
        // home, so the list is reused); else the whole box tree is walked.
        if let Some(h) = home {
            let reach = best2.sqrt() + box_dist2(&self.boxes[h], p).sqrt();
            if reach.is_finite() {
                if w.near_of != h || reach > w.near_r {
                    w.near_r = 2.0 * reach;
                    w.near_of = h;
                    w.near.clear();
                    let b = &self.boxes[h];
                    let r = w.near_r;
                    let grown = Aabb { min: b.min.map(|x| x - r), max: b.max.map(|x| x + r) };
                    let near = &mut w.near;
                    self.tree.overlapping(&grown, |m| {
                        if m != h {
                            near.push(m as u32)
                        }
                    });
                }
                // Nearest box first, so that later ones are pruned (and not loaded).
                w.stack.clear();
                for &m in &w.near {
                    let d = box_dist2(&self.boxes[m as usize], p);
                    if d < best2 {
                        w.stack.push((m, d));
                    }
                }
                w.stack.sort_unstable_by(|x, y| x.1.total_cmp(&y.1).then(x.0.cmp(&y.0)));
                for k in 0..w.stack.len() {
                    let (m, d) = w.stack[k];
                    if d >= best2 {
                        break;
                    }
                    let e = self.get_tgt(cache, m as usize)?;
                    if let Some((dd, s, _)) = e.bvh().nearest_within(p, u32::MAX, best2) {
                        (best2, best_part, best_slot) = (dd, m as usize, s);
                    }
                }
                return self.settle(cache, w, best2, best_part, best_slot);
            }
        }
        // Depth first, nearer child first, pruned by the best so far.
        w.stack.clear();
        if let Some(root) = self.tree.nodes.first() {
            w.stack.push((0, root.dist2(p)));
        }
        while let Some((ni, d)) = w.stack.pop() {
            if d >= best2 {
                continue;
            }
            let n = &self.tree.nodes[ni as usize];
            if n.count > 0 {
                let part = self.tree.items[n.start as usize] as usize;
                if Some(part) == home {
                    continue;
                }
                let e = self.get_tgt(cache, part)?;
                if let Some((dd, s, _)) = e.bvh().nearest_within(p, u32::MAX, best2) {
                    (best2, best_part, best_slot) = (dd, part, s);
                }
            } else {
                let (l, r) = (ni + 1, n.start);
                let (dl, dr) = (self.tree.nodes[l as usize].dist2(p), self.tree.nodes[r as usize].dist2(p));
                let (near, dn, far, df) = if dl <= dr { (l, dl, r, dr) } else { (r, dr, l, dl) };
                if df < best2 {
                    w.stack.push((far, df));
                }
                if dn < best2 {
                    w.stack.push((near, dn));
                }
            }
        }
        if best_part == usize::MAX {
            // Only with non-finite coordinates: answer like the in-memory index.
            let part = self.tree.items[0] as usize;
            let e = self.get_tgt(cache, part)?;
            let (d, s, _) = e.bvh().nearest(p, u32::MAX);
            (best2, best_part, best_slot) = (d, part, s);
        }
        self.settle(cache, w, best2, best_part, best_slot)
    }

    /// Makes the answer's part the worker's home.
    fn settle(&self, cache: &Cache, w: &mut Worker, best2: f64, part: usize, slot: u32) -> Result<f64> {
        if w.home.as_ref().map(|h| h.0) != Some(part) {
            w.home = None;
            w.home = Some((part, self.get_tgt(cache, part)?));
        }
        w.slot = slot;
        Ok(best2)
    }
}

impl Target<'_> {
    /// Squared distances of `points` (grouped in `jobs`) into `d2`.
    fn query(&self, points: &[P3], jobs: &[Job], d2: &mut [f64]) -> Result<()> {
        match self {
            Target::Mem(bvh) => {
                let mut rest = &mut d2[..];
                let mut work = Vec::with_capacity(jobs.len());
                for j in jobs {
                    let (head, tail) = rest.split_at_mut(j.len);
                    work.push((j.at, head));
                    rest = tail;
                }
                work.into_par_iter().for_each(|(at, out)| {
                    let mut hint = u32::MAX;
                    for (k, o) in out.iter_mut().enumerate() {
                        let (d, slot, _) = bvh.nearest(points[at + k], hint);
                        hint = slot;
                        *o = d;
                    }
                });
                Ok(())
            }
            Target::Paged { lvl, cache, pool } => {
                let b = lvl.bbox;
                let scale = [0, 1, 2].map(|k| {
                    let e = b.max[k] - b.min[k];
                    if e > 0.0 {
                        (1u64 << 21) as f64 / e
                    } else {
                        0.0
                    }
                });
                let q = |p: &P3, k: usize| (((p[k] - b.min[k]) * scale[k]).max(0.0) as u64).min((1 << 21) - 1);
                let answers: Vec<Vec<(u32, f64)>> = pool.install(|| {
                    let mut order: Vec<(u64, u32)> = points
                        .par_iter()
                        .enumerate()
                        .map(|(i, p)| (crate::lod::partition::morton3(q(p, 0), q(p, 1), q(p, 2)), i as u32))
                        .collect();
                    order.par_sort_unstable();
                    order
                        .par_chunks(PIECE)
                        .map_init(
                            || Worker { home: None, slot: u32::MAX, stack: Vec::new(), near: Vec::new(), near_r: 0.0, near_of: usize::MAX },
                            |w, piece| {
                                piece
                                    .iter()
                                    .map(|&(_, i)| Ok((i, lvl.closest(cache, points[i as usize], w)?)))
                                    .collect::<Result<Vec<_>>>()
                            },
                        )
                        .collect::<Result<Vec<_>>>()
                })?;
                for piece in answers {
                    for (i, d) in piece {
                        d2[i as usize] = d;
                    }
                }
                Ok(())
            }
        }
    }
}

/// Distances of one direction: batches from `gen`, closest points in
/// `target`, per-job sums combined in job order.
fn measure(gen: &mut dyn Gen, target: &Target, batch: usize, progress: &Progress) -> Result<Distances> {
    let mut points: Vec<P3> = Vec::new();
    let mut jobs: Vec<Job> = Vec::new();
    let mut d2: Vec<f64> = Vec::new();
    let mut acc = Acc::default();
    loop {
        points.clear();
        jobs.clear();
        if !gen.fill(&mut points, &mut jobs, batch)? {
            break;
        }
        d2.clear();
        d2.resize(points.len(), 0.0);
        target.query(&points, &jobs, &mut d2)?;
        let parts: Vec<Acc> = jobs
            .par_iter()
            .map(|j| {
                debug_assert!(j.start % CHUNK == 0 && j.len as u64 <= CHUNK);
                let mut a = Acc::default();
                for k in j.at..j.at + j.len {
                    a.add(d2[k], points[k]);
                }
                a
            })
            .collect();
        for p in &parts {
            if p.n > 0 && (acc.n == 0 || p.max > acc.max) {
                acc.max = p.max;
                acc.max_at = p.max_at;
            }
            acc.n += p.n;
            acc.sum += p.sum;
            acc.sum2 += p.sum2;
        }
        progress.inc(points.len() as u64);
    }
    let (nv, ne, nf) = gen.counts();
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
    measure(&mut MemGen::new(src, samples, seed), &Target::Mem(target), BATCH_MAX, progress)
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
    /// Present when an operand was a paged store level.
    pub paging: Option<PagingReport>,
}

/// One side of a comparison.
enum Operand<'a> {
    Mem(&'a Mesh),
    Paged(&'a PagedLevel),
}

impl Operand<'_> {
    fn faces(&self) -> u64 {
        match self {
            Operand::Mem(m) => m.triangles.len() as u64,
            Operand::Paged(l) => l.faces(),
        }
    }
}

/// What paging did (present when an operand is a store level). Cache
/// figures depend on thread scheduling; everything else in the report is a
/// function of the inputs, options and seed.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PagingReport {
    /// `--mem`.
    pub budget: u64,
    /// What the page cache got: the budget less the batch buffers and, with
    /// an explicit `--mem`, the PLY operands' estimated size.
    pub cache_budget: u64,
    /// Estimated bytes of the PLY operands held whole (mesh, index, plan).
    pub ply_estimate: u64,
    /// Samples per batch.
    pub batch_samples: u64,
    /// Largest resident cache bytes seen (entries and load reservations).
    pub peak_resident: u64,
    /// Node meshes read and indexed.
    pub loads: u64,
    /// Cache lookups answered without a read.
    pub hits: u64,
    pub evictions: u64,
    /// Times the cache could not get under its budget (0 unless a bug).
    pub overcommits: u64,
    /// Bytes read by loads, and by the opening scans.
    pub bytes_read: u64,
    pub scan_bytes: u64,
    /// Parts (cut nodes) of A and B when paged.
    pub parts_a: Option<u64>,
    pub parts_b: Option<u64>,
    /// Threads querying a paged target, A -> B and B -> A (0: in memory).
    pub query_threads: [u64; 2],
    /// Peak RSS of the process (VmHWM), where the OS tells.
    pub peak_rss: Option<u64>,
}

/// The memory budget of a comparison.
#[derive(Clone, Debug, PartialEq)]
pub struct MemOptions {
    /// Bytes (`--mem`, default [`DEFAULT_MEM`]).
    pub budget: u64,
    /// Given explicitly: then PLY operands, held whole, must fit it too.
    pub explicit: bool,
}

impl Default for MemOptions {
    fn default() -> Self {
        MemOptions { budget: DEFAULT_MEM, explicit: false }
    }
}

/// Estimated peak bytes of a PLY operand of `v` vertices and `f` faces held
/// whole: reading (56-byte vertices, 24-byte faces), the mesh (24 + 12),
/// its index (~165 per triangle at most) and its sample plan (~80 per face
/// with the edge sort).
pub fn ply_estimate(v: u64, f: u64) -> u64 {
    80 * v + 36 * f + Bvh::bytes_bound(f) + 8 * v + 80 * f
}

/// The paging setup of [`compare_operands`].
struct Paging<'a> {
    cache: &'a Cache,
    threads: usize,
    report: PagingReport,
}

/// Two-sided Metro distance between `a` and `b`, both in memory.
pub fn compare(a: &Mesh, b: &Mesh, opts: &Options) -> Result<Report> {
    for (m, name) in [(a, "A"), (b, "B")] {
        if m.triangles.is_empty() {
            return Err(Error::Usage(format!("metro: mesh {name} has no triangles")));
        }
        m.check_indices().map_err(|e| Error::Usage(format!("metro: mesh {name}: {e}")))?;
    }
    compare_operands(&Operand::Mem(a), &Operand::Mem(b), opts, BATCH_MAX, None)
}

/// Two-sided Metro distance between two sources: PLYs are loaded whole,
/// store levels are paged through one cache under `mem` (see the module
/// documentation). The samples, and so every figure, are those [`compare`]
/// gives for the same meshes in memory ([`load_store_level`] for a level).
pub fn compare_sources(sa: &Source, sb: &Source, opts: &Options, mem: &MemOptions) -> Result<Report> {
    let t0 = Instant::now();
    // A PLY over an explicit --mem is streamed into a scratch store of its
    // level 0 (the exact input) and then paged like any store level; one
    // that fits is held whole and counted against --mem.
    let mut scratch = Vec::new();
    let mut resolved = Vec::new();
    let mut ply_est = 0u64;
    for (s, name) in [(sa, "A"), (sb, "B")] {
        if let Source::Ply(p) = s {
            let h = crate::ply::read_header(p)?;
            let e = ply_estimate(h.vertex_count(), h.face_count());
            if mem.explicit && e > mem.budget {
                let (tmp, store) = level0_scratch_store(p, opts, mem)?;
                scratch.push(tmp);
                resolved.push(store);
                continue;
            }
            if !mem.explicit && e > mem.budget && crate::progress::visible(opts.quiet) {
                eprintln!(
                    "octolod: metro: note: {name} = {} is held in memory whole (about {}); for meshes larger than RAM \
                     build a store (`octolod build`) and pass STORE@0, which is paged under --mem",
                    p.display(),
                    crate::progress::mib(e)
                );
            }
            ply_est += e;
        }
        resolved.push(s.clone());
    }
    let (sa, sb) = (&resolved[0], &resolved[1]);
    // An eighth of the budget for batches (up to 1 M samples): a larger
    // batch visits each target part once for more queries.
    let batch = ((mem.budget / 8 / BATCH_BYTES_PER_SAMPLE) as usize / CHUNK as usize * CHUNK as usize)
        .clamp(CHUNK as usize, BATCH_MAX);
    let batch_bytes = batch as u64 * BATCH_BYTES_PER_SAMPLE;
    let held = if mem.explicit { ply_est } else { 0 };
    let cache_budget = mem.budget.saturating_sub(held).saturating_sub(batch_bytes);
    let cache = Cache::new(cache_budget);
    let threads = rayon::current_num_threads();
    let open = |s: &Source, op: u64| -> Result<Option<PagedLevel>> {
        match s {
            Source::Store(d, l) => Ok(Some(PagedLevel::open(d, *l, s.to_string(), op, &cache, threads, opts.quiet)?)),
            Source::Ply(_) => Ok(None),
        }
    };
    let (la, lb) = (open(sa, 0)?, open(sb, 1)?);
    let load = |s: &Source| -> Result<Option<Mesh>> {
        match s {
            Source::Ply(p) => Ok(Some(load_ply(p)?)),
            Source::Store(..) => Ok(None),
        }
    };
    let (ma, mb) = rayon::join(|| load(sa), || load(sb));
    let (ma, mb) = (ma?, mb?);
    let load_s = t0.elapsed().as_secs_f64();
    let a = match (&ma, &la) {
        (Some(m), _) => Operand::Mem(m),
        (None, Some(l)) => Operand::Paged(l),
        _ => unreachable!(),
    };
    let b = match (&mb, &lb) {
        (Some(m), _) => Operand::Mem(m),
        (None, Some(l)) => Operand::Paged(l),
        _ => unreachable!(),
    };
    for (o, name) in [(&a, "A"), (&b, "B")] {
        if o.faces() == 0 {
            return Err(Error::Usage(format!("metro: mesh {name} has no triangles")));
        }
    }
    // Each direction holds at most: a paged source's current part and one
    // earlier part (ownership test), or its current part while the target's
    // workers each hold two parts.
    for (src, tgt, dir) in [(&a, &b, "A -> B"), (&b, &a, "B -> A")] {
        let s = if let Operand::Paged(l) = src { l.max_src() } else { 0 };
        let t = if let Operand::Paged(l) = tgt { l.max_tgt() } else { 0 };
        let need = (2 * s).max(s + 2 * t);
        if need > cache_budget {
            let names = |o: &Operand| if let Operand::Paged(l) = o { l.name.clone() } else { String::new() };
            return Err(Error::Usage(format!(
                "metro: --mem {} leaves {} for the page cache (after {} of batch buffers{}), too little for {dir} \
                 ({}{}): its largest node needs up to {} as a sample source and {} as a query index; \
                 give --mem at least {}",
                crate::progress::mib(mem.budget),
                crate::progress::mib(cache_budget),
                crate::progress::mib(batch_bytes),
                if held > 0 { format!(" and {} for the PLY operands", crate::progress::mib(held)) } else { String::new() },
                names(src),
                if matches!(tgt, Operand::Paged(_)) { format!(" against {}", names(tgt)) } else { String::new() },
                crate::progress::mib(s),
                crate::progress::mib(t),
                crate::progress::mib(need + batch_bytes + held + (1 << 20)),
            )));
        }
    }
    let paged = la.is_some() || lb.is_some();
    let report = PagingReport {
        budget: mem.budget,
        cache_budget,
        ply_estimate: ply_est,
        batch_samples: batch as u64,
        parts_a: la.as_ref().map(|l| l.parts() as u64),
        parts_b: lb.as_ref().map(|l| l.parts() as u64),
        ..Default::default()
    };
    let paging = Paging { cache: &cache, threads, report };
    let mut r = compare_operands(&a, &b, opts, batch, paged.then_some(paging))?;
    r.a.source = sa.to_string();
    r.b.source = sb.to_string();
    r.seconds.load = load_s;
    Ok(r)
}

/// Streams PLY `p` into a scratch store of its level 0 (soup + octree under
/// `--mem`, no simplification; level 0 is the exact input). The store lives
/// as long as the returned directory guard.
fn level0_scratch_store(p: &Path, opts: &Options, mem: &MemOptions) -> Result<(crate::io::ScratchDir, Source)> {
    let tmp = crate::io::scratch_dir(p)?;
    let stem = p.file_stem().map(|x| x.to_string_lossy().into_owned()).unwrap_or_else(|| "input".into());
    let dir = tmp.path().join(format!("{stem}.level0.octolod"));
    if crate::progress::visible(opts.quiet) {
        eprintln!("octolod: metro: {} does not fit --mem: streaming it into a scratch store of its level 0", p.display());
    }
    // Leaves small enough that several nodes' query indexes (~250 B per
    // triangle) fit the page cache.
    let bo = crate::pipeline::BuildOptions {
        mem: mem.budget.max(crate::mem::MIN_BUDGET),
        leaf_tris: (mem.budget / 2048).clamp(256, 16384),
        levels: Some(0),
        quiet: opts.quiet,
        ..Default::default()
    };
    crate::pipeline::build_store(p, &dir, &bo)?;
    Ok((tmp, Source::Store(dir, 0)))
}

/// The two directions, then the report.
fn compare_operands(a: &Operand, b: &Operand, opts: &Options, batch: usize, paging: Option<Paging>) -> Result<Report> {
    let target = match opts.samples {
        Some(0) => return Err(Error::Usage("metro: --samples must be at least 1".into())),
        Some(n) => n,
        None => SAMPLES_PER_FACE * a.faces().max(b.faces()),
    };
    let seed_ab = mix64(opts.seed ^ 0xA70B);
    let seed_ba = mix64(opts.seed ^ 0xB70A);
    let mut bvh_s = 0.0;
    let mut threads_used = [0u64; 2];
    let mut direction = |src: &Operand, tgt: &Operand, seed: u64, name: &str, k: usize| -> Result<(Distances, Option<MeshSummary>, f64)> {
        let t0 = Instant::now();
        let bvh;
        let tg = match tgt {
            Operand::Mem(m) => {
                bvh = Bvh::new(m);
                Target::Mem(&bvh)
            }
            Operand::Paged(l) => {
                let p = paging.as_ref().expect("a paged operand comes with a cache");
                let hold = if let Operand::Paged(s) = src { s.max_src() } else { 0 };
                let t = ((p.cache.budget.saturating_sub(hold)) / (2 * l.max_tgt()).max(1)).clamp(1, p.threads as u64) as usize;
                threads_used[k] = t as u64;
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(t)
                    .build()
                    .map_err(|e| Error::Usage(format!("metro: cannot start {t} threads: {e}")))?;
                Target::Paged { lvl: l, cache: p.cache, pool }
            }
        };
        bvh_s += t0.elapsed().as_secs_f64();
        let t1 = Instant::now();
        let progress = Progress::items(target, name, opts.quiet);
        let (d, summary) = match src {
            Operand::Mem(m) => (measure(&mut MemGen::new(m, target, seed), &tg, batch, &progress)?, None),
            Operand::Paged(l) => {
                let p = paging.as_ref().expect("a paged operand comes with a cache");
                let mut g = PagedGen::new(l, p.cache, target, seed);
                let d = measure(&mut g, &tg, batch, &progress)?;
                (d, Some(g.summary()))
            }
        };
        progress.finish();
        Ok((d, summary, t1.elapsed().as_secs_f64()))
    };
    let (ab, sum_a, t_ab) = direction(a, b, seed_ab, "A -> B", 0)?;
    let (ba, sum_b, t_ba) = direction(b, a, seed_ba, "B -> A", 1)?;
    let summary = |o: &Operand, s: Option<MeshSummary>, name: &str| match o {
        Operand::Mem(m) => MeshSummary::of(m, name),
        Operand::Paged(_) => s.expect("a paged operand is summarised by its sampling"),
    };
    let (sa, sb) = (summary(a, sum_a, "A"), summary(b, sum_b, "B"));
    let mut u = sa.bbox;
    u.merge(&sb.bbox);
    let paging = paging.map(|p| {
        let c = p.cache;
        PagingReport {
            peak_resident: c.acct.peak.load(Relaxed),
            loads: c.loads.load(Relaxed),
            hits: c.hits.load(Relaxed),
            evictions: c.evictions.load(Relaxed),
            overcommits: c.overcommits.load(Relaxed),
            bytes_read: c.bytes_read.load(Relaxed),
            scan_bytes: c.scan_bytes.load(Relaxed),
            query_threads: threads_used,
            peak_rss: crate::progress::peak_rss(),
            ..p.report
        }
    });
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
        seconds: Timings { load: 0.0, bvh: bvh_s, a_to_b: t_ab, b_to_a: t_ba },
        paging,
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
                // A figure that is not a number never passes.
                Check { metric, option, threshold, limit, value, exceeded: !(value <= limit) }
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
        let paging = match &self.paging {
            None => String::new(),
            Some(p) => {
                let opt = |x: Option<u64>| x.map_or("null".to_string(), |v| v.to_string());
                format!(
                    ",\"paging\":{{\"budget\":{},\"cache_budget\":{},\"ply_estimate\":{},\"batch_samples\":{},\"peak_resident\":{},\"loads\":{},\"hits\":{},\"evictions\":{},\"overcommits\":{},\"bytes_read\":{},\"scan_bytes\":{},\"parts\":{{\"a\":{},\"b\":{}}},\"query_threads\":[{},{}],\"peak_rss\":{}}}",
                    p.budget,
                    p.cache_budget,
                    p.ply_estimate,
                    p.batch_samples,
                    p.peak_resident,
                    p.loads,
                    p.hits,
                    p.evictions,
                    p.overcommits,
                    p.bytes_read,
                    p.scan_bytes,
                    opt(p.parts_a),
                    opt(p.parts_b),
                    p.query_threads[0],
                    p.query_threads[1],
                    opt(p.peak_rss)
                )
            }
        };
        format!(
            "{{\"a\":{},\"b\":{},\"diagonal\":{},\"diagonal_of\":\"a\",\"union_diagonal\":{},\"seed\":{},\"samples_target\":{},\"a_to_b\":{},\"b_to_a\":{},\"combined\":{},\"hausdorff\":{},\"hausdorff_rel\":{},\"thresholds\":[{}],\"pass\":{}{}}}",
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
            !checks.iter().any(|c| c.exceeded),
            paging
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
        if let Some(p) = &self.paging {
            let parts = |n: Option<u64>| n.map_or("in memory".to_string(), |n| format!("{n} parts"));
            let _ = writeln!(
                s,
                "paging: --mem {} (cache {}), peak resident {}; A {}, B {}; {} loads ({} read, {} scanned), {} hits, {} evictions; query threads {}/{}",
                crate::progress::mib(p.budget),
                crate::progress::mib(p.cache_budget),
                crate::progress::mib(p.peak_resident),
                parts(p.parts_a),
                parts(p.parts_b),
                p.loads,
                crate::progress::mib(p.bytes_read),
                crate::progress::mib(p.scan_bytes),
                p.hits,
                p.evictions,
                p.query_threads[0],
                p.query_threads[1]
            );
        }
        let t = &self.seconds;
        let q = t.a_to_b + t.b_to_a;
        let _ = write!(
            s,
            "time: load {:.3} s, BVH {:.3} s, A -> B {:.3} s, B -> A {:.3} s; {:.3} M samples/s; peak RSS {}",
            t.load,
            t.bvh,
            t.a_to_b,
            t.b_to_a,
            self.combined.samples as f64 / 1e6 / q.max(1e-9),
            crate::progress::peak_rss().map_or("n/a".to_string(), crate::progress::mib)
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
/// [--max-rms Y] [--max-mean Z] [--mem SIZE]`.
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
    /// `--mem` (default [`DEFAULT_MEM`]): the page cache of store levels;
    /// given explicitly, PLY operands (held whole) must fit it too.
    pub mem: Option<String>,
    pub quiet: bool,
}

/// Most samples per direction `--samples` accepts (about an hour per
/// direction on two cores).
pub const MAX_SAMPLES: u64 = 10_000_000_000;

/// Runs the command: prints the table (or JSON) on stdout and each exceeded
/// threshold on stderr. Ok(false) when a threshold is exceeded (the binary
/// then exits with [`EXIT_THRESHOLD`]).
pub fn run_cli(args: &CliArgs) -> Result<bool> {
    let limits = Limits::parse(args.max_hausdorff.as_deref(), args.max_rms.as_deref(), args.max_mean.as_deref())?;
    if args.samples == Some(0) {
        return Err(Error::Usage("metro: --samples must be at least 1".into()));
    }
    if let Some(n) = args.samples.filter(|&n| n > MAX_SAMPLES) {
        return Err(Error::Usage(format!("metro: --samples {n} is more than {MAX_SAMPLES} per direction (hours of work); ask fewer")));
    }
    let mem = match &args.mem {
        Some(m) => MemOptions { budget: crate::mem::parse_budget(m, "--mem")?, explicit: true },
        None => MemOptions::default(),
    };
    let (sa, sb) = (Source::parse(&args.a)?, Source::parse(&args.b)?);
    let r = compare_sources(&sa, &sb, &Options { samples: args.samples, seed: args.seed, quiet: args.quiet }, &mem)?;
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
    fn sample_order_is_first_reference_and_first_occurrence() {
        // Two triangles sharing edge (2, 0); vertex 3 unreferenced.
        let m = Mesh::new(vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [9.0; 3], [1.0, 1.0, 0.0]], vec![[2, 0, 1], [1, 4, 2]]);
        assert_eq!(m.first_reference_vertices(), vec![2, 0, 1, 4]);
        // Edges as first met, directed as met: (2,0) (0,1) (1,2) then (1,4) (4,2).
        assert_eq!(first_occurrence_edges(&m.triangles, true), vec![[2, 0], [0, 1], [1, 2], [1, 4], [4, 2]]);
        assert_eq!(first_occurrence_edges(&m.triangles, false), first_occurrence_edges(&m.triangles, true));
    }

    #[test]
    fn box_tree_finds_every_overlapping_box() {
        let mut rng = Rng::new(3);
        let boxes: Vec<Aabb> = (0..300)
            .map(|k| {
                if k % 17 == 0 {
                    return Aabb::EMPTY;
                }
                let c = [rng.f64(), rng.f64(), rng.f64()];
                let h = 0.05 * rng.f64();
                Aabb { min: c.map(|x| x - h), max: c.map(|x| x + h) }
            })
            .collect();
        let tree = BoxTree::new(&boxes);
        for _ in 0..100 {
            let c = [rng.f64(), rng.f64(), rng.f64()];
            let q = Aabb { min: c.map(|x| x - 0.1), max: c.map(|x| x + 0.1) };
            let mut got = Vec::new();
            tree.overlapping(&q, |i| got.push(i));
            got.sort_unstable();
            let want: Vec<usize> = (0..boxes.len())
                .filter(|&i| !boxes[i].is_empty() && (0..3).all(|k| boxes[i].min[k] <= q.max[k] && q.min[k] <= boxes[i].max[k]))
                .collect();
            assert_eq!(got, want);
        }
    }

    #[test]
    fn cache_evicts_least_recently_used_and_keeps_held_entries() {
        let bvh = |n: usize| {
            let m = random_mesh(n, n as u64);
            Payload::Tgt(Bvh::build(&m, false))
        };
        let size = bvh(3).bytes();
        assert!(size > 0 && size <= Bvh::bytes_bound(3), "{size}");
        // Room for four entries.
        let budget = 4 * size + size / 2;
        let cache = Cache::new(budget);
        let held = cache.get(0, size, || Ok((bvh(3), 10))).unwrap();
        for k in 1..8u64 {
            let _ = cache.get(k, size, || Ok((bvh(3), 10))).unwrap();
            assert!(cache.acct.resident() <= budget);
        }
        assert!(cache.evictions.load(Relaxed) > 0);
        // Entry 0 was held all along: still cached, a hit.
        let again = cache.get(0, size, || panic!("held entries stay")).unwrap();
        assert!(Arc::ptr_eq(&held, &again));
        // Entry 1 was the least recently used of the others: gone.
        let mut reloaded = false;
        let _ = cache.get(1, size, || {
            reloaded = true;
            Ok((bvh(3), 10))
        });
        assert!(reloaded);
        assert!(cache.acct.peak.load(Relaxed) <= budget);
        assert_eq!(cache.overcommits.load(Relaxed), 0);
        drop((held, again));
        // A reservation larger than what can be freed is an overcommit.
        let r = cache.reserve(2 * budget);
        assert!(cache.overcommits.load(Relaxed) > 0);
        drop(r);
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

//! Metro's sample points on a mesh held in memory: which points, in which
//! order (the rules are in `docs/metro.md`, "Sample mix"), and the helpers the
//! paged levels share to give the same points part by part.
//!
//! Takes: a [`Mesh`], a sample budget and a seed. Gives: the samples of one
//! direction in order, a batch of whole [`Job`]s at a time ([`Gen`]).

use super::{CHUNK, EDGE_SHARE_MAX};
use crate::error::Result;
use crate::geom::{add, dist2, mix64, scale, sub, tri_area, Mesh, Rng, GOLDEN, P3};
use rayon::prelude::*;

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
pub(super) fn edge_density(left: u64, area: f64, total_len: f64) -> f64 {
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
pub(super) fn face_density(left: u64, area: f64) -> f64 {
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
pub(super) fn carry(acc: &mut f64, prev: &mut u64, x: f64, density: f64) -> u64 {
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
pub(super) fn seg_len(a: P3, b: P3) -> f64 {
    dist2(a, b).sqrt()
}

/// Sample `i` of the `n` equally spaced interior points of edge `ab`.
#[inline]
pub(super) fn edge_point(a: P3, b: P3, i: u64, n: u64) -> P3 {
    add(a, scale(sub(b, a), (i + 1) as f64 / (n + 1) as f64))
}

/// The per-face seed and stratification offset of face `fi` (global index).
#[inline]
pub(super) fn face_seed(seed: u64, fi: u64) -> (u64, f64) {
    let fseed = seed ^ mix64(fi.wrapping_mul(GOLDEN) ^ 0xFACE);
    (fseed, Rng::new(fseed).f64())
}

/// Sample `i` of a face's `n` stratified samples.
#[inline]
pub(super) fn face_point(c: &[P3; 3], fseed: u64, offset: f64, i: u64, n: u64) -> P3 {
    let mut rng = Rng::new(fseed.wrapping_add(mix64(i + 1)));
    face_sample(c, i, n, offset, &mut rng)
}

/// The distinct edges of `triangles` in the order of first occurrence
/// (face by face, corner `k` giving edge `(t[k], t[k+1])`), each directed as
/// first met.
pub(super) fn first_occurrence_edges(triangles: &[[u32; 3]], parallel: bool) -> Vec<[u32; 2]> {
    let occ = |(f, t): (usize, &[u32; 3])| {
        let t = *t;
        (0..3).map(move |k| {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            (((a.min(b) as u64) << 32) | a.max(b) as u64, 3 * f as u64 + k as u64)
        })
    };
    let mut keys: Vec<(u64, u64)> =
        if parallel { triangles.par_iter().enumerate().flat_map_iter(occ).collect() } else { triangles.iter().enumerate().flat_map(occ).collect() };
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
pub(super) struct Plan {
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

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Kind {
    Vertex,
    Edge,
    Face,
}

/// A run of consecutive samples of one kind, the unit of summation: it
/// starts at a multiple of [`CHUNK`] within its kind and holds at most
/// `CHUNK` samples, so the partial sums, added in job order, do not depend
/// on threads, batches or paging.
#[derive(Clone, Copy, Debug)]
pub(super) struct Job {
    /// Index of the first sample within its kind (a multiple of CHUNK).
    pub(super) start: u64,
    pub(super) len: usize,
    /// Offset of the first sample in the batch.
    pub(super) at: usize,
}

/// Produces the samples of one direction in order, a batch of whole jobs at a time.
pub(super) trait Gen {
    /// Appends whole jobs to `points`/`jobs` (at least one if any is left,
    /// no more than `max` samples unless a single job is larger). False when
    /// nothing was left.
    fn fill(&mut self, points: &mut Vec<P3>, jobs: &mut Vec<Job>, max: usize) -> Result<bool>;
    /// (vertex, edge, face) samples, final once `fill` returned false.
    fn counts(&self) -> (u64, u64, u64);
}

/// The samples of an in-memory mesh, from its [`Plan`], generated in parallel.
pub(super) struct MemGen<'a> {
    src: &'a Mesh,
    plan: Plan,
    /// (kind, first, end) of every job, in order.
    jobs: Vec<(Kind, u64, u64)>,
    next: usize,
}

impl<'a> MemGen<'a> {
    pub(super) fn new(src: &'a Mesh, target: u64, seed: u64) -> MemGen<'a> {
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

#[cfg(test)]
mod tests {
    use super::*;

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
                let q = if p[0] >= 0.5 {
                    1
                } else if p[1] >= 0.5 {
                    2
                } else if p[0] + p[1] <= 0.5 {
                    0
                } else {
                    3
                };
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
        let m = Mesh::new(vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0], [5.0, 5.0, 5.0]], vec![[0, 1, 2], [0, 2, 3]]);
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
}

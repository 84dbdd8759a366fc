//! Where each level's cells are: one octree per level over a cube that
//! moves by a third of its size from one level to the next, the adaptive
//! leaf tiling of that cube, and the histogram that predicts it.
//!
//! Takes: the input's bounding box, the level number, triangle centroids.
//! Gives: [`LevelCube`] (Morton keys and cell boxes of level L's octree),
//! [`Histogram`] (centroid counts at a fine depth, coarsened to fit memory)
//! and [`Tiling`] (the leaves of the adaptive cut "split while a cell holds
//! more than `leaf_tris` and is shallower than `max_depth`", tiling the
//! whole cube so that every point has a leaf).
//!
//! Why a third. All cubes have side `S = 1.5 R` (R: the input's largest
//! extent); even levels put their corner at `b − S/3`, odd levels at `b`
//! (b: the input's minimum corner), so both contain the input and
//! consecutive levels differ by `S/3` on every axis. A face of a depth-d
//! cell lies at `corner + k S / 2^d`; since `S/3 mod S/2^d` is `S/2^d × 1/3`
//! or `× 2/3` (the binary expansion of 1/3 is 0.0101…), every face of level
//! L's octree lies at least a third of the finer cell's side away from
//! every face of level L−1's, at any pair of depths. Level L−1's seams
//! (vertices shared by two of its nodes, within about one level-(L−1)
//! triangle of a level-(L−1) face) therefore lie inside level-L cells —
//! a third of a cell, i.e. dozens of triangles, from any level-L face —
//! except where a level-L face crosses them along a line; they are
//! simplified at level L. This is the regular-grid variant of Nexus's
//! per-level KD-trees with alternating split quantiles, made adaptive by
//! the octree.

use crate::geom::{demorton, morton3};
use crate::mesh::Aabb;
use rustc_hash::FxHashMap as HashMap;

/// Bits per axis of full-depth keys.
pub const KEY_DEPTH: u8 = 21;

/// Level L's octree cube.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LevelCube {
    pub origin: [f64; 3],
    pub size: f64,
}

impl LevelCube {
    /// The cube of `level` for an input with bounding box `b` (see the module doc).
    pub fn for_level(b: &Aabb, level: u32) -> LevelCube {
        let ext = (0..3).map(|k| b.max[k] - b.min[k]).fold(0.0, f64::max);
        let r = if ext > 0.0 && ext.is_finite() { ext * (1.0 + 1e-9) } else { 1.0 };
        let size = 1.5 * r;
        let shift = if level % 2 == 0 { size / 3.0 } else { 0.0 };
        LevelCube { origin: [0, 1, 2].map(|k| b.min[k] - shift), size }
    }

    /// Morton key of a point at [`KEY_DEPTH`] bits per axis (clamped into the cube).
    #[inline]
    pub fn key(&self, p: [f64; 3]) -> u64 {
        let [x, y, z] = self.coords(p);
        morton3(x, y, z)
    }

    /// The cell coordinates per axis at [`KEY_DEPTH`] of a point, as
    /// [`LevelCube::key`] interleaves them.
    #[inline]
    pub fn coords(&self, p: [f64; 3]) -> [u64; 3] {
        let n = (1u64 << KEY_DEPTH) as f64;
        // Truncation is the floor from 1 up; below 1 (NaN too) the cell is 0.
        // (No `floor`: without SSE4.1 it is a libm call per coordinate.)
        [0, 1, 2].map(|k| {
            let t = (p[k] - self.origin[k]) / self.size * n;
            if t >= 1.0 {
                // Through i64: one instruction (f64 → u64 is several
                // without AVX-512); same value, as t ≥ 1 and the result
                // is capped far below 2^63.
                ((t as i64) as u64).min((1 << KEY_DEPTH) - 1)
            } else {
                0
            }
        })
    }

    /// How many of `points` fall in each cell at `depth`, as sorted
    /// (cell path, count) runs: the same as counting `key(p) >> 3·(KEY_DEPTH
    /// − depth)`. A node's points span few cells per axis, so they are
    /// counted in a dense box of those cells when it is small (no Morton
    /// key or hashing per point), else hashed.
    pub fn cell_counts(&self, depth: u8, points: impl Iterator<Item = [f64; 3]>) -> Vec<(u64, u64)> {
        let sh = (KEY_DEPTH - depth.min(KEY_DEPTH)) as u32;
        let cells: Vec<[u32; 3]> = points.map(|p| self.coords(p).map(|c| (c >> sh) as u32)).collect();
        let (mut lo, mut hi) = ([u32::MAX; 3], [0u32; 3]);
        for c in &cells {
            for k in 0..3 {
                lo[k] = lo[k].min(c[k]);
                hi[k] = hi[k].max(c[k]);
            }
        }
        let mut runs: Vec<(u64, u64)> = Vec::new();
        if cells.is_empty() {
            return runs;
        }
        let ext = [0, 1, 2].map(|k| (hi[k] - lo[k]) as usize + 1);
        let boxed = ext[0].saturating_mul(ext[1]).saturating_mul(ext[2]);
        let path = |c: [u32; 3]| morton3(c[0] as u64, c[1] as u64, c[2] as u64);
        if boxed <= (4 * cells.len()).max(4096) {
            let mut count = vec![0u32; boxed];
            let at = |c: &[u32; 3]| ((c[2] - lo[2]) as usize * ext[1] + (c[1] - lo[1]) as usize) * ext[0] + (c[0] - lo[0]) as usize;
            for c in &cells {
                count[at(c)] += 1;
            }
            for (i, &n) in count.iter().enumerate().filter(|x| *x.1 > 0) {
                let c = [i % ext[0], (i / ext[0]) % ext[1], i / (ext[0] * ext[1])];
                runs.push((path([0, 1, 2].map(|k| lo[k] + c[k] as u32)), n as u64));
            }
            runs.sort_unstable();
        } else {
            // Spread over a sparse box (a terrain's relief, a scan's
            // depth): the paths sorted and counted in runs (hashing them,
            // then sorting the counts, cost more).
            let mut paths: Vec<u64> = cells.iter().map(|c| path(*c)).collect();
            paths.sort_unstable();
            for run in paths.chunk_by(|a, b| a == b) {
                runs.push((run[0], run.len() as u64));
            }
        }
        runs
    }

    /// The box of cell `path` at `depth`.
    pub fn cell(&self, path: u64, depth: u8) -> Aabb {
        let side = self.size / (1u64 << depth) as f64;
        let (x, y, z) = demorton(path);
        let lo = [0, 1, 2].map(|k| self.origin[k] + [x, y, z][k] as f64 * side);
        Aabb { min: lo, max: [0, 1, 2].map(|k| lo[k] + side) }
    }
}

/// Counts of full-depth keys at a coarser depth, coarsened further when
/// the map outgrows its entry cap (memory stays bounded whatever the input).
pub struct Histogram {
    depth: u8,
    cap: usize,
    map: HashMap<u64, u64>,
}

impl Histogram {
    /// Starts at `depth` (≤ [`KEY_DEPTH`]) with at most `cap` cells.
    pub fn new(depth: u8, cap: usize) -> Histogram {
        Histogram { depth: depth.min(KEY_DEPTH), cap: cap.max(64), map: HashMap::default() }
    }

    /// Room for `n` cells (at most the cap) up front: growing by
    /// rehashing, on the one thread that merges, cost as much as the
    /// counting itself.
    pub fn reserve(&mut self, n: usize) {
        self.map.reserve(n.min(self.cap));
    }

    #[inline]
    pub fn add(&mut self, key: u64, n: u64) {
        *self.map.entry(key >> (3 * (KEY_DEPTH - self.depth) as u32)).or_insert(0) += n;
        if self.map.len() > self.cap {
            self.coarsen();
        }
    }

    /// Adds sorted (key at `depth`, count) runs (e.g. from a worker thread).
    pub fn add_runs(&mut self, depth: u8, runs: &[(u64, u64)]) {
        let sh = 3 * depth.saturating_sub(self.depth) as u32;
        for &(k, n) in runs {
            *self.map.entry(k >> sh).or_insert(0) += n;
        }
        while self.map.len() > self.cap {
            self.coarsen();
        }
    }

    /// Adds another histogram's counts (e.g. from a worker thread).
    pub fn merge(&mut self, o: Histogram) {
        let mut o = o;
        while o.depth > self.depth {
            o.coarsen();
        }
        while self.depth > o.depth {
            self.coarsen();
        }
        for (k, n) in o.map {
            *self.map.entry(k).or_insert(0) += n;
        }
        while self.map.len() > self.cap {
            self.coarsen();
        }
    }

    fn coarsen(&mut self) {
        if self.depth == 0 {
            return;
        }
        self.depth -= 1;
        let old = std::mem::take(&mut self.map);
        for (k, n) in old {
            *self.map.entry(k >> 3).or_insert(0) += n;
        }
    }

    /// Most bytes a histogram of at most `cap` cells holds: a hash table
    /// of 17-byte buckets, a power of two at most 7/8 full, and the half
    /// as large one it outgrew while it is rehashed.
    pub fn max_bytes(cap: usize) -> u64 {
        let buckets = (cap.max(64) * 8 / 7 + 1).next_power_of_two() as u64;
        buckets * 17 * 3 / 2
    }

    pub fn total(&self) -> u64 {
        self.map.values().sum()
    }

    /// The depth the counts are kept at (at most the one asked for).
    pub fn depth(&self) -> u8 {
        self.depth
    }

    /// The top-down cut "split while a cell holds more than `limit` and is
    /// shallower than `max_depth` and the histogram's depth" below each of
    /// `roots` (sorted paths at `root_depth`, at most the histogram's
    /// depth): its non-empty leaves as (path, depth, count), in Morton order.
    pub fn cut(&self, roots: &[u64], root_depth: u8, limit: u64, max_depth: u8) -> Vec<(u64, u8, u64)> {
        self.cut_scaled(roots, root_depth, 1.0, limit, max_depth, false)
    }

    /// [`Histogram::cut`] on the counts × `scale` (predicted counts);
    /// with `keep_empty`, empty cells are leaves too (a tiling).
    fn cut_scaled(&self, roots: &[u64], root_depth: u8, scale: f64, limit: u64, max_depth: u8, keep_empty: bool) -> Vec<(u64, u8, u64)> {
        let mut cells: Vec<(u64, u64)> = self.map.iter().map(|(&k, &n)| (k, n)).collect();
        radix_sort_keys(&mut cells);
        let hd = self.depth;
        let max_depth = max_depth.min(hd);
        struct Rule {
            hd: u8,
            scale: f64,
            limit: u64,
            max_depth: u8,
            keep_empty: bool,
        }
        fn go(out: &mut Vec<(u64, u8, u64)>, cells: &[(u64, u64)], r: &Rule, path: u64, depth: u8) {
            let n: u64 = cells.iter().map(|c| c.1).sum();
            if n == 0 && !r.keep_empty {
                return;
            }
            if depth >= r.max_depth || (n as f64 * r.scale) <= r.limit as f64 {
                out.push((path, depth, n));
                return;
            }
            let sh = 3 * (r.hd - depth - 1) as u32;
            let mut rest = cells;
            for o in 0..8u64 {
                let child = path << 3 | o;
                let k = rest.partition_point(|c| c.0 >> sh == child);
                let (mine, tail) = rest.split_at(k);
                go(out, mine, r, child, depth + 1);
                rest = tail;
            }
        }
        let rule = Rule { hd, scale, limit, max_depth, keep_empty };
        let mut out = Vec::new();
        let sh = 3 * (hd - root_depth.min(hd)) as u32;
        let mut rest = &cells[..];
        for &root in roots {
            let from = rest.partition_point(|c| c.0 >> sh < root);
            rest = &rest[from..];
            let k = rest.partition_point(|c| c.0 >> sh == root);
            go(&mut out, &rest[..k], &rule, root, root_depth);
            rest = &rest[k..];
        }
        out
    }
}

/// Sorts `(key, value)` pairs with distinct keys by key: least
/// significant digit first, 11 bits a pass, up to the largest key's bits. The histograms' cuts
/// sort up to a million cells at a time between two passes of a level,
/// on one thread; this takes a fraction of a comparison sort's
/// instructions (at depth 10, 3 passes over the cells).
fn radix_sort_keys(v: &mut Vec<(u64, u64)>) {
    const DIGIT: u32 = 11;
    let bits = 64 - v.iter().map(|x| x.0).max().unwrap_or(0).leading_zeros();
    if v.len() < 256 || bits > 44 {
        v.sort_unstable();
        return;
    }
    let mut tmp = vec![(0u64, 0u64); v.len()];
    let mut shift = 0;
    while shift < bits {
        let mut count = [0usize; 1 << DIGIT];
        for &(k, _) in v.iter() {
            count[((k >> shift) & ((1 << DIGIT) - 1)) as usize] += 1;
        }
        let mut at = 0;
        for c in count.iter_mut() {
            let n = *c;
            *c = at;
            at += n;
        }
        for &x in v.iter() {
            let d = ((x.0 >> shift) & ((1 << DIGIT) - 1)) as usize;
            tmp[count[d]] = x;
            count[d] += 1;
        }
        std::mem::swap(v, &mut tmp);
        shift += DIGIT;
    }
}

/// One leaf of a tiling: the full-depth keys `start..end`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TileLeaf {
    pub path: u64,
    pub depth: u8,
    pub start: u64,
    pub end: u64,
}

/// The leaves of an adaptive octree cut, tiling the whole cube, in Morton order.
#[derive(Clone, Debug, Default)]
pub struct Tiling {
    pub leaves: Vec<TileLeaf>,
}

impl Tiling {
    pub(crate) fn leaf(path: u64, depth: u8) -> TileLeaf {
        let sh = 3 * (KEY_DEPTH - depth) as u32;
        TileLeaf { path, depth, start: path << sh, end: (path + 1) << sh }
    }

    /// The cut "split while the predicted count (histogram × `scale`)
    /// exceeds `leaf_tris` and the depth is below `max_depth` and the
    /// histogram's resolution".
    pub fn from_histogram(h: &Histogram, scale: f64, leaf_tris: u64, max_depth: u8) -> Tiling {
        let leaves = h.cut_scaled(&[0], 0, scale, leaf_tris, max_depth, true);
        Tiling { leaves: leaves.into_iter().map(|(path, depth, _)| Tiling::leaf(path, depth)).collect() }
    }

    /// A tiling given by its (non-empty) leaves, e.g. from the level-0 cut;
    /// the gaps between them are filled with the largest aligned cells.
    pub fn from_leaves(given: &[(u64, u8)]) -> Tiling {
        let mut t = Tiling::default();
        let mut at = 0u64;
        let end_all = 1u64 << (3 * KEY_DEPTH as u32);
        let fill = |t: &mut Tiling, from: u64, to: u64| {
            let mut a = from;
            while a < to {
                // Largest aligned block at `a` that fits before `to`.
                let mut d = 0u8;
                loop {
                    let sh = 3 * (KEY_DEPTH - d) as u32;
                    let size = 1u64 << sh;
                    if a % size == 0 && a + size <= to {
                        t.leaves.push(Tiling::leaf(a >> sh, d));
                        a += size;
                        break;
                    }
                    d += 1;
                }
            }
        };
        for &(path, depth) in given {
            let l = Tiling::leaf(path, depth);
            fill(&mut t, at, l.start);
            t.leaves.push(l);
            at = l.end;
        }
        fill(&mut t, at, end_all);
        t
    }

    /// The leaf holding full-depth key `key`.
    #[inline]
    pub fn locate(&self, key: u64) -> usize {
        self.leaves.partition_point(|l| l.end <= key)
    }

    /// [`Tiling::locate`], trying leaf `*last` first (consecutive
    /// triangles of a mesh mostly fall in the same leaf) and remembering
    /// the leaf found.
    #[inline]
    pub fn locate_near(&self, key: u64, last: &mut usize) -> usize {
        if let Some(l) = self.leaves.get(*last) {
            if l.start <= key && key < l.end {
                return *last;
            }
        }
        *last = self.locate(key);
        *last
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn consecutive_level_faces_are_a_third_of_a_cell_apart() {
        let b = Aabb { min: [-1.0, 2.0, 0.5], max: [3.0, 2.5, 1.0] };
        for level in 0..4u32 {
            let (a, c) = (LevelCube::for_level(&b, level), LevelCube::for_level(&b, level + 1));
            for k in 0..3 {
                assert!(a.origin[k] <= b.min[k] && a.origin[k] + a.size >= b.max[k]);
            }
            // Faces at depths da (level L) and dc (level L+1) along x.
            for da in 0..8u8 {
                for dc in 0..8u8 {
                    let fine = a.size / (1u64 << da.max(dc)) as f64;
                    let (sa, sc) = (a.size / (1u64 << da) as f64, c.size / (1u64 << dc) as f64);
                    for i in 0..=(1u64 << da) {
                        let fa = a.origin[0] + i as f64 * sa;
                        // Nearest level-(L+1) face.
                        let j = ((fa - c.origin[0]) / sc).round();
                        let d = (fa - (c.origin[0] + j * sc)).abs();
                        assert!(d >= fine / 3.0 - 1e-9 * a.size, "level {level} depths {da}/{dc}: faces {d} apart, cell {fine}");
                    }
                }
            }
        }
    }

    #[test]
    fn radix_sorted_keys_are_sorted() {
        let mut rng = crate::geom::Rng::new(3);
        for (n, bits) in [(10, 30), (300, 30), (5000, 30), (5000, 3), (4000, 63), (2000, 45)] {
            let mut keys: Vec<u64> = (0..n).map(|_| rng.next_u64() & ((1u64 << bits) - 1)).collect();
            keys.sort_unstable();
            keys.dedup();
            let mut v: Vec<(u64, u64)> = keys.iter().rev().map(|&k| (k, k ^ 0x55)).collect();
            let mut want = v.clone();
            want.sort_unstable();
            radix_sort_keys(&mut v);
            assert_eq!(v, want, "{n} keys of {bits} bits");
        }
    }

    #[test]
    fn cell_counts_are_the_shifted_keys_counted() {
        let cube = LevelCube { origin: [-1.0, 2.0, 0.5], size: 3.0 };
        let mut rng = crate::geom::Rng::new(7);
        let mut rnd = || rng.f64();
        // A small patch (dense box), a spread cloud (hashed), points outside the cube and NaN.
        let patch: Vec<[f64; 3]> = (0..3000).map(|_| [0.1 + 0.01 * rnd(), 2.5 + 0.02 * rnd(), 1.0 + 0.003 * rnd()]).collect();
        let cloud: Vec<[f64; 3]> = (0..3000).map(|_| [-1.0 + 3.0 * rnd(), 2.0 + 3.0 * rnd(), 0.5 + 3.0 * rnd()]).collect();
        let odd = vec![[-5.0, 2.1, 0.6], [9.0, 9.0, 9.0], [f64::NAN, 3.0, 1.0], [0.2, 2.5, 1.0]];
        for pts in [patch, cloud, odd, Vec::new()] {
            for depth in [0u8, 4, 10, KEY_DEPTH] {
                let mut want: std::collections::BTreeMap<u64, u64> = Default::default();
                for p in &pts {
                    *want.entry(cube.key(*p) >> (3 * (KEY_DEPTH - depth) as u32)).or_insert(0) += 1;
                }
                let got = cube.cell_counts(depth, pts.iter().copied());
                assert_eq!(got, want.into_iter().collect::<Vec<_>>(), "depth {depth}");
            }
        }
    }

    #[test]
    fn tilings_cover_every_key_once() {
        let mut h = Histogram::new(6, 1 << 20);
        let cube = LevelCube::for_level(&Aabb { min: [0.0; 3], max: [1.0; 3] }, 0);
        let mut rng = crate::geom::Rng::new(1);
        for _ in 0..20000 {
            let s = rng.next_u64();
            let p = [(s >> 11) as f64 / (1u64 << 53) as f64, 0.5, ((s >> 7) & 0xffff) as f64 / 65536.0];
            h.add(cube.key(p), 1);
        }
        let t = Tiling::from_histogram(&h, 1.0, 500, 10);
        assert!(t.leaves.len() > 8);
        assert_eq!(t.leaves[0].start, 0);
        assert_eq!(t.leaves.last().unwrap().end, 1u64 << 63);
        for w in t.leaves.windows(2) {
            assert_eq!(w[0].end, w[1].start);
        }
        assert_eq!(t.locate(0), 0);
        assert_eq!(t.locate((1u64 << 63) - 1), t.leaves.len() - 1);
        let f = Tiling::from_leaves(&[(5, 1), (8 * 6 + 3, 2)]);
        for w in f.leaves.windows(2) {
            assert_eq!(w[0].end, w[1].start);
        }
        assert_eq!(f.leaves.last().unwrap().end, 1u64 << 63);
        assert!(f.leaves.contains(&Tiling::leaf(5, 1)));
    }
}

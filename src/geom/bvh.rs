//! A bounding-volume hierarchy over a mesh's triangles, and one over boxes.
//!
//! Takes: a [`Mesh`] (or a list of boxes). Gives: the exact closest point
//! of the mesh to a query point ([`Bvh`]), or the boxes meeting a box
//! (`BoxTree`). Median split of triangle centroids along the longest
//! axis, at most 4 triangles a leaf, flattened depth-first into one array
//! with the left child next to its parent; subtrees above 64 K triangles
//! built in parallel. Queries walk nearest child first, skip any box
//! farther than the best distance so far, and may be seeded with a
//! triangle to try first (the previous query's, for queries in surface
//! order). The answer is the minimum over the triangles of their computed
//! distances whatever the seed, so indexes over different groupings of the
//! same triangles agree. A query for a maximum over many points may end at
//! the first triangle nearer than what could change it
//! (`Bvh::nearest_unless_below`). Inner boxes are the unions of their
//! children's, made bottom-up.

use super::tri::{closest_point_triangle_kind, TriKind};
use super::{dist2, Mesh, P3};
use crate::mesh::Aabb;
use rayon::prelude::*;
use std::mem::size_of;

/// Triangles per leaf at most.
const LEAF_TRIS: usize = 4;
/// Subtrees with more triangles than this are built in parallel.
const PAR_BUILD: usize = 64 * 1024;

#[derive(Clone, Copy, Debug)]
pub(crate) struct Node {
    pub(crate) min: P3,
    pub(crate) max: P3,
    /// Leaf: first triangle slot. Inner: index of the right child (the left
    /// child is the next node).
    pub(crate) start: u32,
    /// Leaf: triangle count (> 0). Inner: 0.
    pub(crate) count: u32,
}

impl Node {
    #[inline]
    pub(crate) fn dist2(&self, p: P3) -> f64 {
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
    pub(crate) fn build(mesh: &Mesh, parallel: bool) -> Bvh {
        let centroid = |t: usize| {
            let c = mesh.corners(t);
            ([0, 1, 2].map(|k| (c[0][k] + c[1][k] + c[2][k]) / 3.0), t as u32)
        };
        let n = mesh.triangles.len();
        let mut items: Vec<(P3, u32)> = if parallel { (0..n).into_par_iter().map(centroid).collect() } else { (0..n).map(centroid).collect() };
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
    pub(crate) fn bytes_bound(f: u64) -> u64 {
        let node = size_of::<Node>() as u64;
        node * f.max(1) + (size_of::<[P3; 3]>() + size_of::<TriKind>() + size_of::<u32>()) as u64 * f + size_of::<(P3, u32)>() as u64 * f
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
    pub(crate) fn nearest(&self, p: P3, hint: u32) -> (f64, u32, P3) {
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
    pub(crate) fn nearest_within(&self, p: P3, hint: u32, bound2: f64) -> Option<(f64, u32, P3)> {
        self.search(p, hint, bound2, f64::NEG_INFINITY)
    }

    /// The squared distance from `p` to the mesh and its triangle slot,
    /// exact when it is at least `stop2`; else some triangle found nearer
    /// than `stop2` (the search ends there). For a maximum over many points
    /// (a Hausdorff distance), where a point nearer than the largest kept
    /// so far cannot change it: most points end at their `hint` (the
    /// previous point's slot), one triangle test, no descent (the early
    /// break of Taha and Hanbury's Hausdorff algorithm). Requires a
    /// non-empty BVH with finite `p`; None otherwise.
    pub(crate) fn nearest_unless_below(&self, p: P3, hint: u32, stop2: f64) -> Option<(f64, u32)> {
        self.search(p, hint, f64::INFINITY, stop2).map(|(d, s, _)| (d, s))
    }

    /// The nearest triangle under `bound2`, the search ending as soon as
    /// one is found under `stop2` (NEG_INFINITY: never).
    fn search(&self, p: P3, hint: u32, bound2: f64, stop2: f64) -> Option<(f64, u32, P3)> {
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
                if best2 < stop2 {
                    return Some((best2, best, bq));
                }
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
                            if best2 < stop2 {
                                return Some((best2, best, bq));
                            }
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

    /// Every triangle whose closest point to `p` is at squared distance at
    /// most `r2`: `f(triangle, point, squared distance)`.
    pub fn within(&self, p: P3, r2: f64, mut f: impl FnMut(u32, P3, f64)) {
        if self.nodes.is_empty() {
            return;
        }
        let mut stack = vec![0u32];
        while let Some(node) = stack.pop() {
            let n = &self.nodes[node as usize];
            if !(n.dist2(p) <= r2) {
                continue;
            }
            if n.count > 0 {
                for s in n.start..n.start + n.count {
                    let q = self.tri_closest(s, p);
                    let d = dist2(p, q);
                    if d <= r2 {
                        f(self.ids[s as usize], q, d);
                    }
                }
            } else {
                stack.push(node + 1);
                stack.push(n.start);
            }
        }
    }
}

/// A hierarchy over boxes, one box a leaf: the top level of a paged mesh,
/// over its parts' exact bounds.
pub(crate) struct BoxTree {
    pub(crate) nodes: Vec<Node>,
    /// Leaf `start` indexes this; the values are part indices.
    pub(crate) items: Vec<u32>,
}

impl BoxTree {
    /// Over the non-empty `boxes`.
    pub(crate) fn new(boxes: &[Aabb]) -> BoxTree {
        let mut items: Vec<(P3, u32)> = boxes.iter().enumerate().filter(|(_, b)| !b.is_empty()).map(|(i, b)| (b.center(), i as u32)).collect();
        let mut nodes = Vec::with_capacity(2 * items.len());
        if !items.is_empty() {
            box_build(boxes, &mut items, 0, &mut nodes);
        }
        BoxTree { nodes, items: items.iter().map(|&(_, i)| i).collect() }
    }
    /// Calls `f` with every part whose box meets `b` (closed boxes).
    pub(crate) fn overlapping(&self, b: &Aabb, mut f: impl FnMut(usize)) {
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
pub(crate) fn inside(b: &Aabb, p: P3) -> bool {
    (0..3).all(|k| b.min[k] <= p[k] && p[k] <= b.max[k])
}

/// The box of the items' triangles.
fn bounds(mesh: &Mesh, items: &[(P3, u32)]) -> Aabb {
    let mut b = Aabb::EMPTY;
    for &(_, t) in items {
        for &i in &mesh.triangles[t as usize] {
            b.add(mesh.positions[i as usize]);
        }
    }
    b
}

/// Builds the subtree over `items` (whose first slot is `offset`), node
/// indices relative to the subtree's root. An inner node's box is the
/// union of its children's, made after them: each triangle's corners are
/// read once, at its leaf, not once per level (what the box of every node
/// from its items cost: a twentieth of a collapse build).
fn build(mesh: &Mesh, items: &mut [(P3, u32)], offset: usize) -> Vec<Node> {
    if items.len() <= PAR_BUILD {
        let mut out = Vec::with_capacity(2 * items.len() / LEAF_TRIS + 1);
        build_seq(mesh, items, offset, &mut out);
        return out;
    }
    let mid = split(items);
    let (l, r) = items.split_at_mut(mid);
    let (lv, rv) = rayon::join(|| build(mesh, l, offset), || build(mesh, r, offset + mid));
    let mut out = Vec::with_capacity(1 + lv.len() + rv.len());
    let right = 1 + lv.len() as u32;
    let (min, max) = union(&lv[0], &rv[0]);
    out.push(Node { min, max, start: right, count: 0 });
    out.extend(lv.into_iter().map(|n| n.shifted(1)));
    out.extend(rv.into_iter().map(|n| n.shifted(right)));
    out
}

fn build_seq(mesh: &Mesh, items: &mut [(P3, u32)], offset: usize, out: &mut Vec<Node>) {
    if items.len() <= LEAF_TRIS {
        let b = bounds(mesh, items);
        out.push(Node { min: b.min, max: b.max, start: offset as u32, count: items.len() as u32 });
        return;
    }
    let me = out.len();
    let mid = split(items);
    out.push(Node { min: [0.0; 3], max: [0.0; 3], start: 0, count: 0 });
    let (l, r) = items.split_at_mut(mid);
    build_seq(mesh, l, offset, out);
    let right = out.len();
    build_seq(mesh, r, offset + mid, out);
    let (min, max) = union(&out[me + 1], &out[right]);
    out[me] = Node { min, max, start: right as u32, count: 0 };
}

/// The box of two nodes' boxes.
fn union(a: &Node, b: &Node) -> (P3, P3) {
    (std::array::from_fn(|k| a.min[k].min(b.min[k])), std::array::from_fn(|k| a.max[k].max(b.max[k])))
}

/// The median split of `items` along the longest axis of their centroids'
/// bounds (ties broken by triangle index: deterministic).
fn split(items: &mut [(P3, u32)]) -> usize {
    let mut cb = Aabb::EMPTY;
    for &(c, _) in items.iter() {
        cb.add(c);
    }
    let axis = longest_axis(&cb);
    let mid = items.len() / 2;
    items.select_nth_unstable_by(mid, |x, y| x.0[axis].total_cmp(&y.0[axis]).then(x.1.cmp(&y.1)));
    mid
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::{closest_point_triangle, random_mesh, Rng};

    fn brute_closest(m: &Mesh, p: P3) -> f64 {
        (0..m.triangles.len())
            .map(|t| {
                let c = m.corners(t);
                dist2(p, closest_point_triangle(p, c[0], c[1], c[2]))
            })
            .fold(f64::INFINITY, f64::min)
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

    /// The early break: at or above the stop, the exact distance; below
    /// it, a distance below it whose triangle is that near, and never
    /// while the exact distance is at or above the stop.
    #[test]
    fn nearest_unless_below_is_exact_at_or_above_the_stop() {
        let m = random_mesh(900, 7);
        let bvh = Bvh::new(&m);
        let mut rng = Rng::new(77);
        let (mut hint, mut broke, mut exact) = (u32::MAX, 0, 0);
        for _ in 0..2000 {
            let p = [1.6 * rng.f64() - 0.3, 1.6 * rng.f64() - 0.3, 1.6 * rng.f64() - 0.3];
            let want = bvh.nearest(p, u32::MAX).0;
            let stop = want * (0.5 + rng.f64());
            let (d2, slot) = bvh.nearest_unless_below(p, hint, stop).unwrap();
            let c = &bvh.tris[slot as usize];
            assert_eq!(d2, dist2(p, closest_point_triangle_kind(p, c[0], c[1], c[2], bvh.kinds[slot as usize])));
            if want >= stop {
                assert_eq!(d2, want, "the exact distance at or above the stop");
                exact += 1;
            } else {
                assert!(d2 < stop && d2 >= want, "{d2} against stop {stop}, exact {want}");
                broke += (d2 > want) as usize;
            }
            hint = slot;
        }
        assert!(exact > 500 && broke > 100, "both cases met: {exact} exact, {broke} stopped early above the minimum");
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
            let want: Vec<usize> =
                (0..boxes.len()).filter(|&i| !boxes[i].is_empty() && (0..3).all(|k| boxes[i].min[k] <= q.max[k] && q.min[k] <= boxes[i].max[k])).collect();
            assert_eq!(got, want);
        }
    }
}

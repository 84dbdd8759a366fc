//! Which vertices a node shares with another node of its level — exactly —
//! and the normals of shared vertices summed over every node that holds them.
//!
//! Takes: each node's mesh, its partition cell and its *reach* (the largest
//! distance, per axis, from the point a triangle's node was chosen by —
//! its centroid, or at level 0 its first corner — to one of its corners).
//! Gives: per node, the positions it shares with another node of the level
//! (those are locked when it is simplified) with their full area-weighted
//! normal (so both sides of a seam shade alike).
//!
//! Why it finds all of them. A triangle belongs to the node whose cell
//! holds its centroid (level 0: its first corner). If position p is a
//! corner of a triangle of node N',
//! p is within N''s reach of N''s cell. So a position of node N that lies
//! in no other node's cell grown by that node's reach is in no other node:
//! only the *band* — positions inside another node's grown cell — can be
//! shared. Each node sends its band positions (with its partial normal)
//! through an external sort keyed by a hash of the position; positions
//! sent by two or more nodes are shared, exactly (bit-identical positions;
//! hash collisions are told apart by the full position). This needs no
//! adjacency and treats duplicated faces, non-manifold fans, touching
//! sheets and attribute seams alike: what matters is the position. The
//! mesh's own open border is never in it unless another node holds the
//! same position.

use crate::error::{IoContext, Result};
use crate::extsort::ExtSorter;
use crate::mesh::Aabb;
use rustc_hash::FxHashMap;
use std::io::{BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};

/// A static box tree answering "which boxes meet this box".
pub struct BoxIndex {
    boxes: Vec<Aabb>,
    /// (bounds, first, count or child): leaves hold `order[first..first+count]`.
    nodes: Vec<(Aabb, u32, u32, bool)>,
    order: Vec<u32>,
}

fn overlaps(a: &Aabb, b: &Aabb) -> bool {
    (0..3).all(|k| a.min[k] <= b.max[k] && b.min[k] <= a.max[k])
}

impl BoxIndex {
    pub fn new(boxes: Vec<Aabb>) -> BoxIndex {
        let mut order: Vec<u32> = (0..boxes.len() as u32).filter(|&i| !boxes[i as usize].is_empty()).collect();
        let mut ix = BoxIndex { boxes, nodes: Vec::new(), order: Vec::new() };
        if !order.is_empty() {
            let n = order.len();
            ix.build(&mut order, 0, n);
        }
        ix.order = order;
        ix
    }

    fn build(&mut self, order: &mut [u32], first: usize, n: usize) -> u32 {
        let mut b = Aabb::EMPTY;
        for &i in &order[first..first + n] {
            b.merge(&self.boxes[i as usize]);
        }
        let id = self.nodes.len() as u32;
        if n <= 4 {
            self.nodes.push((b, first as u32, n as u32, true));
            return id;
        }
        self.nodes.push((b, 0, 0, false));
        let axis = (0..3).max_by(|&x, &y| (b.max[x] - b.min[x]).total_cmp(&(b.max[y] - b.min[y]))).unwrap();
        let c = |i: &u32| {
            let bb = &self.boxes[*i as usize];
            bb.min[axis] + bb.max[axis]
        };
        order[first..first + n].sort_by(|x, y| c(x).total_cmp(&c(y)));
        let h = n / 2;
        let l = self.build(order, first, h);
        let r = self.build(order, first + h, n - h);
        self.nodes[id as usize].1 = l;
        self.nodes[id as usize].2 = r;
        id
    }

    /// Ids of the boxes meeting `q`.
    pub fn query(&self, q: &Aabb, out: &mut Vec<u32>) {
        out.clear();
        if self.nodes.is_empty() || q.is_empty() {
            return;
        }
        let mut stack = vec![0u32];
        while let Some(n) = stack.pop() {
            let (b, a, c, leaf) = &self.nodes[n as usize];
            if !overlaps(b, q) {
                continue;
            }
            if *leaf {
                for &i in &self.order[*a as usize..(*a + *c) as usize] {
                    if overlaps(&self.boxes[i as usize], q) {
                        out.push(i);
                    }
                }
            } else {
                stack.push(*a);
                stack.push(*c);
            }
        }
    }

    pub fn get(&self, i: usize) -> &Aabb {
        &self.boxes[i]
    }
}

/// The grown cells of one level's nodes.
pub struct Band {
    index: BoxIndex,
    /// Per node: its cell and how far it was grown.
    cells: Vec<(Aabb, f64)>,
}

impl Band {
    /// `cells[i]` = (cell, reach) of node i.
    pub fn new(cells: &[(Aabb, f64)]) -> Band {
        let grown = cells
            .iter()
            .map(|(c, r)| {
                let r = if r.is_finite() { r.max(0.0) } else { 0.0 };
                // A little more than the reach: centroids are rounded.
                let r = r * (1.0 + 1e-6) + 1e-12 * (c.max[0] - c.min[0]).abs();
                (Aabb { min: c.min.map(|x| x - r), max: c.max.map(|x| x + r) }, r)
            })
            .collect::<Vec<_>>();
        let index = BoxIndex::new(grown.iter().map(|g| g.0).collect());
        Band { index, cells: cells.iter().zip(&grown).map(|(c, g)| (c.0, g.1)).collect() }
    }

    /// For node `i` with content bounds `content`: a test "may position p
    /// be shared", i.e. is p inside another node's grown cell.
    pub fn tester(&self, i: usize, content: &Aabb) -> BandTest<'_> {
        let mut near = Vec::new();
        self.index.query(content, &mut near);
        near.retain(|&j| j as usize != i);
        // Cells tile the cube, so another node's grown cell reaches into
        // this cell by at most its growth: points deeper inside are in
        // none (a quick answer for most of a node's positions). Not when
        // another cell overlaps this one (a merge's union of shards'
        // levels): then every position is tested.
        let (cell, _) = self.cells[i];
        let overlaps_inside = |o: &Aabb| (0..3).all(|k| o.min[k] < cell.max[k] && cell.min[k] < o.max[k]);
        let inner = if near.iter().any(|&j| overlaps_inside(&self.cells[j as usize].0)) {
            Aabb::EMPTY
        } else {
            let grow = near.iter().map(|&j| self.cells[j as usize].1).fold(0.0, f64::max);
            let m = grow + 1e-9 * (cell.max[0] - cell.min[0]).abs();
            Aabb { min: cell.min.map(|x| x + m), max: cell.max.map(|x| x - m) }
        };
        BandTest { band: self, near, inner }
    }
}

pub struct BandTest<'a> {
    band: &'a Band,
    near: Vec<u32>,
    /// The node's cell less every near cell's growth (may be empty).
    inner: Aabb,
}

impl BandTest<'_> {
    #[inline]
    pub fn may_share(&self, p: [f64; 3]) -> bool {
        if (0..3).all(|k| p[k] > self.inner.min[k] && p[k] < self.inner.max[k]) {
            return false;
        }
        self.near.iter().any(|&j| {
            let b = self.band.index.get(j as usize);
            (0..3).all(|k| p[k] >= b.min[k] && p[k] <= b.max[k])
        })
    }
}

/// 64-bit hash of a position's bits.
#[inline]
pub fn pos_hash(p: [f64; 3]) -> u64 {
    let mut h = 0x9E37_79B9_7F4A_7C15u64;
    for x in p {
        h ^= x.to_bits();
        h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
        h ^= h >> 31;
    }
    h
}

/// Flag: the position was locked one level below.
pub const WAS_LOCKED: u32 = 1;

const REC1: usize = 56; // hash u64, node u32, flags u32, pos 3×f64, normal 3×f32, pad
const REC2: usize = 48; // node u64, pos 3×f64, normal 3×f32, flags u32

/// Collects band records of a level, then resolves them.
pub struct SharedSort {
    sorter: ExtSorter,
}

/// What resolving found.
#[derive(Clone, Copy, Debug, Default)]
pub struct SharedStats {
    /// Distinct band positions sent.
    pub candidates: u64,
    /// Positions held by two or more nodes.
    pub shared: u64,
    /// Of those, positions that were locked one level below too.
    pub shared_was_locked: u64,
}

impl SharedSort {
    pub fn new(mem: usize, dir: &Path) -> SharedSort {
        SharedSort { sorter: ExtSorter::new("band", REC1, mem, dir) }
    }

    /// One band position of `node`, with its partial normal and flags.
    pub fn push(&mut self, node: u32, p: [f64; 3], normal: [f32; 3], flags: u32) -> Result<()> {
        self.sorter.push_with(|b| {
            b[..8].copy_from_slice(&pos_hash(p).to_le_bytes());
            b[8..12].copy_from_slice(&node.to_le_bytes());
            b[12..16].copy_from_slice(&flags.to_le_bytes());
            for k in 0..3 {
                b[16 + 8 * k..24 + 8 * k].copy_from_slice(&p[k].to_le_bytes());
                b[40 + 4 * k..44 + 4 * k].copy_from_slice(&normal[k].to_le_bytes());
            }
            b[52..56].fill(0);
        })
    }

    /// Finds the shared positions and writes, sorted by node, (node,
    /// position, summed normal, flags) to `out`; readable with [`Resolved`].
    pub fn resolve(self, mem: usize, dir: &Path, out: PathBuf) -> Result<(Resolved, SharedStats)> {
        let mut st = SharedStats::default();
        let mut by_node = ExtSorter::new("shared", REC2, mem, dir);
        let mut group: Vec<(u32, [f64; 3], [f32; 3], u32)> = Vec::new();
        let mut group_hash = 0u64;
        let flush = |group: &mut Vec<(u32, [f64; 3], [f32; 3], u32)>, by_node: &mut ExtSorter, st: &mut SharedStats| -> Result<()> {
            // Split the hash group by exact position.
            group.sort_by(|a, b| {
                a.1.iter().zip(&b.1).map(|(x, y)| x.to_bits().cmp(&y.to_bits())).find(|o| o.is_ne()).unwrap_or(std::cmp::Ordering::Equal).then(a.0.cmp(&b.0))
            });
            let mut i = 0;
            while i < group.len() {
                let mut j = i;
                while j < group.len() && group[j].1.map(f64::to_bits) == group[i].1.map(f64::to_bits) {
                    j += 1;
                }
                st.candidates += 1;
                let g = &group[i..j];
                if g.iter().any(|r| r.0 != g[0].0) {
                    st.shared += 1;
                    let flags = g.iter().fold(0, |f, r| f | r.3);
                    if flags & WAS_LOCKED != 0 {
                        st.shared_was_locked += 1;
                    }
                    let mut n = [0f32; 3];
                    for r in g {
                        #[allow(clippy::needless_range_loop, reason = "axis loop over two arrays in lockstep")]
                        for k in 0..3 {
                            n[k] += r.2[k];
                        }
                    }
                    for r in g {
                        by_node.push_with(|b| {
                            b[..8].copy_from_slice(&(r.0 as u64).to_le_bytes());
                            for k in 0..3 {
                                b[8 + 8 * k..16 + 8 * k].copy_from_slice(&r.1[k].to_le_bytes());
                                b[32 + 4 * k..36 + 4 * k].copy_from_slice(&n[k].to_le_bytes());
                            }
                            b[44..48].copy_from_slice(&flags.to_le_bytes());
                        })?;
                    }
                }
                i = j;
            }
            group.clear();
            Ok(())
        };
        self.sorter.finish(|r| {
            let h = u64::from_le_bytes(r[..8].try_into().unwrap());
            if h != group_hash && !group.is_empty() {
                flush(&mut group, &mut by_node, &mut st)?;
            }
            group_hash = h;
            let f = |o: usize| f64::from_le_bytes(r[o..o + 8].try_into().unwrap());
            let g = |o: usize| f32::from_le_bytes(r[o..o + 4].try_into().unwrap());
            group.push((
                u32::from_le_bytes(r[8..12].try_into().unwrap()),
                [f(16), f(24), f(32)],
                [g(40), g(44), g(48)],
                u32::from_le_bytes(r[12..16].try_into().unwrap()),
            ));
            Ok(())
        })?;
        flush(&mut group, &mut by_node, &mut st)?;
        let file = std::fs::File::create(&out).ctx(&out, "create")?;
        let mut w = BufWriter::with_capacity(1 << 20, file);
        by_node.finish(|r| w.write_all(r).ctx(&out, "write"))?;
        w.flush().ctx(&out, "write")?;
        drop(w);
        let f = std::fs::File::open(&out).ctx(&out, "open")?;
        Ok((Resolved { path: out, r: BufReader::with_capacity(1 << 20, f), pending: None }, st))
    }
}

/// A node's shared positions: position bits → (summed normal, flags).
pub type SharedSet = FxHashMap<[u64; 3], ([f32; 3], u32)>;

/// One resolved record: (node, position bits, summed normal, flags).
type ResolvedRecord = (u32, [u64; 3], [f32; 3], u32);

/// Reads resolved records node by node, in node order.
pub struct Resolved {
    path: PathBuf,
    r: BufReader<std::fs::File>,
    pending: Option<ResolvedRecord>,
}

impl Resolved {
    fn next(&mut self) -> Result<Option<ResolvedRecord>> {
        if let Some(p) = self.pending.take() {
            return Ok(Some(p));
        }
        let mut b = [0u8; REC2];
        match self.r.read_exact(&mut b) {
            Ok(()) => {}
            Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => return Ok(None),
            Err(e) => return Err(e).ctx(&self.path, "read"),
        }
        let f = |o: usize| u64::from_le_bytes(b[o..o + 8].try_into().unwrap());
        let g = |o: usize| f32::from_le_bytes(b[o..o + 4].try_into().unwrap());
        Ok(Some((f(0) as u32, [f(8), f(16), f(24)], [g(32), g(36), g(40)], u32::from_le_bytes(b[44..48].try_into().unwrap()))))
    }

    /// The shared set of node `node`; nodes must be asked in increasing order.
    pub fn take(&mut self, node: u32) -> Result<SharedSet> {
        let mut s = SharedSet::default();
        while let Some(r) = self.next()? {
            if r.0 < node {
                continue;
            }
            if r.0 > node {
                self.pending = Some(r);
                break;
            }
            s.insert(r.1, (r.2, r.3));
        }
        Ok(s)
    }

    /// Another reader of the same records, from the start.
    pub fn reopen(&self) -> Result<Resolved> {
        let f = std::fs::File::open(&self.path).ctx(&self.path, "open")?;
        Ok(Resolved { path: self.path.clone(), r: BufReader::with_capacity(1 << 20, f), pending: None })
    }

    pub fn remove(self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_index_finds_exactly_the_overlapping_boxes() {
        let mut rng = crate::geom::Rng::new(7);
        let mut rnd = || rng.f64();
        let boxes: Vec<Aabb> = (0..300)
            .map(|_| {
                let c = [rnd(), rnd(), rnd()];
                let h = 0.05 * rnd();
                Aabb { min: c.map(|x| x - h), max: c.map(|x| x + h) }
            })
            .collect();
        let ix = BoxIndex::new(boxes.clone());
        let mut out = Vec::new();
        for _ in 0..50 {
            let c = [rnd(), rnd(), rnd()];
            let q = Aabb { min: c.map(|x| x - 0.1), max: c.map(|x| x + 0.1) };
            ix.query(&q, &mut out);
            let mut got = out.clone();
            got.sort();
            let want: Vec<u32> = (0..300).filter(|&i| overlaps(&boxes[i as usize], &q)).collect();
            assert_eq!(got, want);
        }
    }

    #[test]
    fn shared_positions_are_those_sent_by_two_nodes() {
        let d = tempfile::tempdir().unwrap();
        let mut s = SharedSort::new(1 << 10, d.path());
        let p = |x: f64| [x, 2.0 * x, -x];
        s.push(0, p(1.0), [1.0, 0.0, 0.0], 0).unwrap();
        s.push(1, p(1.0), [0.0, 1.0, 0.0], WAS_LOCKED).unwrap();
        s.push(2, p(1.0), [0.0, 0.0, 1.0], 0).unwrap();
        s.push(0, p(2.0), [1.0, 0.0, 0.0], 0).unwrap();
        s.push(3, p(3.0), [1.0, 0.0, 0.0], 0).unwrap();
        s.push(3, p(3.0), [1.0, 0.0, 0.0], 0).unwrap(); // same node twice: not shared
        for i in 0..100 {
            s.push(i % 7, p(10.0 + i as f64), [0.0; 3], 0).unwrap();
        }
        let (mut r, st) = s.resolve(1 << 10, d.path(), d.path().join("res.bin")).unwrap();
        assert_eq!(st.shared, 1);
        assert_eq!(st.shared_was_locked, 1);
        for node in 0..4u32 {
            let set = r.take(node).unwrap();
            if node < 3 {
                assert_eq!(set.len(), 1, "node {node}");
                assert_eq!(set[&crate::geom::pos_bits(p(1.0))].0, [1.0, 1.0, 1.0]);
            } else {
                assert!(set.is_empty());
            }
        }
    }
}

//! A store level opened for paging: the level's cut nodes are its parts,
//! read with one positioned read when needed and held in the shared
//! [`Cache`]; as a sample source ([`PagedGen`]: the samples the welded
//! level gives in memory, in the same order) and as a query target
//! ([`PagedLevel::query`]: the same minimum over the same triangles). How
//! parts are searched, sampled and budgeted: `docs/metro.md`, "Paged stores".
//!
//! Takes: a store directory and level, the cache. Gives: samples and
//! closest-point distances without loading the level whole.

use super::cache::{Cache, Entry, Payload};
use super::report::MeshSummary;
use super::sample::{carry, edge_density, edge_point, face_density, face_point, face_seed, first_occurrence_edges, seg_len, Gen, Job, Kind};
use super::CHUNK;
use crate::error::{Error, Result};
use crate::geom::bvh::{inside, BoxTree};
use crate::geom::{tri_area, Bvh, Mesh, P3};
use crate::mesh::IndexedMesh;
use crate::mesh::{Aabb, Vertex};
use crate::progress::Progress;
use crate::store::{NodeRec, Store};
use rayon::prelude::*;
use std::mem::size_of;
use std::path::Path;
use std::sync::atomic::Ordering::Relaxed;
use std::sync::Arc;

/// Queries per unit of parallel work against a paged target.
const PIECE: usize = 1024;

/// What a part holds when it serves as a sample source: its mesh welded in
/// first-reference order, its edges, and lookups for the ownership test.
pub(super) struct SrcPart {
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
        let mut sorted: Vec<([u64; 3], u32)> = positions.iter().enumerate().map(|(i, p)| (p.map(f64::to_bits), i as u32)).collect();
        sorted.sort_unstable();
        let mut edge_keys: Vec<u64> = edges.iter().map(|e| ((e[0].min(e[1]) as u64) << 32) | e[0].max(e[1]) as u64).collect();
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
    pub(super) fn bytes(&self) -> u64 {
        (self.positions.capacity() * size_of::<P3>()
            + self.triangles.capacity() * size_of::<[u32; 3]>()
            + self.edges.capacity() * size_of::<[u32; 2]>()
            + self.sorted.capacity() * size_of::<([u64; 3], u32)>()
            + self.edge_keys.capacity() * size_of::<u64>()) as u64
    }
}

/// A node mesh with bit-identical positions merged and unreferenced ones
/// dropped, vertices numbered in the order of first reference (the weld
/// [`Store::level_mesh`] does across the whole level, node by node).
fn weld_first_reference(m: &IndexedMesh) -> (Vec<P3>, Vec<[u32; 3]>) {
    let mut weld = crate::geom::Welder::with_capacity(m.vertices.len());
    let mut positions = Vec::with_capacity(m.vertices.len());
    let mut triangles = Vec::with_capacity(m.triangles.len());
    for t in &m.triangles {
        triangles.push(t.map(|v| weld.id(m.vertices[v as usize].pos, |p| positions.push(p))));
    }
    positions.shrink_to_fit();
    (positions, triangles)
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
    pub(super) name: String,
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
    pub(super) fn open(dir: &Path, level: u8, name: String, op: u64, cache: &Cache, threads: usize, quiet: bool) -> Result<PagedLevel> {
        let store = Store::open(dir)?;
        store.check_level(level)?;
        let nodes = store.level_nodes(level);
        let costs: Vec<PartCost> = nodes.iter().map(|&i| PartCost::of(&store.nodes[i])).collect();
        let max_load = costs.iter().map(|c| c.load).max().unwrap_or(0).max(1);
        let t = threads.min((cache.budget / max_load).max(1) as usize).max(1);
        let pool = rayon::ThreadPoolBuilder::new().num_threads(t).build().map_err(|e| Error::Usage(format!("metro: cannot start {t} threads: {e}")))?;
        let progress = Progress::items(nodes.len() as u64, if op == 0 { "scan A" } else { "scan B" }, quiet);
        let scanned: Vec<(Aabb, u64)> = pool.install(|| {
            (0..nodes.len())
                .into_par_iter()
                .map(|k| {
                    crate::io::signal::check()?;
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

    /// Bounds of the level's triangles.
    pub(super) fn bbox(&self) -> Aabb {
        self.bbox
    }

    pub fn parts(&self) -> usize {
        self.nodes.len()
    }
    pub fn faces(&self) -> u64 {
        *self.face_base.last().unwrap()
    }
    pub(super) fn max_src(&self) -> u64 {
        self.costs.iter().map(|c| c.src).max().unwrap_or(0)
    }
    pub(super) fn max_tgt(&self) -> u64 {
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
/// order as [`Plan`](super::sample::Plan) gives for the welded level in memory (parts in cut
/// order; in each, its owned vertices and edges in first-reference and
/// first-occurrence order, then its faces), with Metro's carried fractions
/// running across parts. Three passes over the parts: vertices (which also
/// totals the area and the owned edges' length, needed for the densities),
/// edges, faces.
pub(super) struct PagedGen<'a> {
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
    pub(super) fn new(lvl: &'a PagedLevel, cache: &'a Cache, target: u64, seed: u64) -> PagedGen<'a> {
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
    pub(super) fn summary(&self) -> MeshSummary {
        MeshSummary { source: self.lvl.name.clone(), vertices: self.nv, faces: self.lvl.faces(), area: self.area, bbox: self.lvl.bbox }
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

impl PagedLevel {
    /// Squared distances of `points` into `d2`: queries sorted along a
    /// Morton curve of the level's box, in pieces of [`PIECE`] per worker.
    pub(super) fn query(&self, cache: &Cache, pool: &rayon::ThreadPool, points: &[P3], d2: &mut [f64]) -> Result<()> {
        let b = self.bbox;
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
            let mut order: Vec<(u64, u32)> = points.par_iter().enumerate().map(|(i, p)| (crate::geom::morton3(q(p, 0), q(p, 1), q(p, 2)), i as u32)).collect();
            order.par_sort_unstable();
            order
                .par_chunks(PIECE)
                .map_init(
                    || Worker { home: None, slot: u32::MAX, stack: Vec::new(), near: Vec::new(), near_r: 0.0, near_of: usize::MAX },
                    |w, piece| piece.iter().map(|&(_, i)| Ok((i, self.closest(cache, points[i as usize], w)?))).collect::<Result<Vec<_>>>(),
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

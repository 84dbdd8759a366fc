//! The level builder: the steps of [`super`]'s doc as methods, run once per
//! level from the finest up.
//!
//! Takes: level 0 as partitioned leaves with their chunks, the options and
//! a [`NodeSimplifier`]. Gives: the store's packs as it goes, then the node
//! records with their children and parents lists (`finish`).
//! Per level: `nodes` (the level's partition, decided
//! when the level below was simplified), `shared_vertices`
//! (and the next level's histogram), `threshold`,
//! `partition_next`, `simplify_and_route`
//! (payloads, node errors and bounds, chunks for the next level),
//! `measure_far` and `advance`; at the end
//! `link_dag`.

use super::chunks::{split_by_target, ChunkEncoder, ChunkFile};
use super::measure::{remeasure_far, FarNode, NodeError};
use super::octree::{Level0, OctreeReport};
use super::ordered::ordered;
use super::partition::{Histogram, LevelCube, Tiling};
use super::shared::{Band, Resolved, SharedSet, SharedSort, SharedStats, WAS_LOCKED};
use super::simplifier::{NodeInput, NodeSimplifier};
use super::welded::Welded;
use super::{centroid, next_up_f32, tri_centroid, Built, LeafStats, LodOptions, HIST_DEPTH, MAX_LEVELS, SAMPLED_NODES};
use crate::error::{Error, Result};
use crate::geom::pos_bits;
use crate::geom::{cross, dot, sub};
use crate::io::ScratchDir;
use crate::manifest::{LevelReport, Normals};
use crate::mesh::{Aabb, AttrSet, IndexedMesh, VertexLayout};
use crate::progress::Progress;
use crate::store::{encode_payload, NodeRec, PackWriter, StoreHeader, NO_NODE};
use rayon::prelude::*;
use rustc_hash::{FxHashMap, FxHashSet};
use std::path::Path;
use std::sync::atomic::{AtomicU8, Ordering};
use std::time::Instant;

/// What stays fixed while the levels are built.
struct Config<'a, S> {
    opts: &'a LodOptions,
    dir: &'a Path,
    scratch: ScratchDir,
    simplifier: S,
    attrs: AttrSet,
    bbox: Aabb,
    /// Chunks' vertices: the input's attributes.
    layout: VertexLayout,
    /// Payloads' vertices: with normals, derived when the input has none.
    payload_layout: VertexLayout,
    derived: bool,
    /// Where the levels' normals come from (`auto` resolved by the caller,
    /// [`Normals::resolved`]).
    normals: Normals,
    /// Gathered vertices are welded by their bytes; with no attribute those
    /// are the position's, so each vertex is a position of its own.
    unique_positions: bool,
    /// Carried quadric values per vertex in the chunks.
    a_len: usize,
    hist_cap: usize,
    /// Nodes in flight in the ordered passes.
    batch: usize,
    /// A shard's positions shared with other shards: locked at every level
    /// like positions shared between nodes ([`LevelBuilder::for_shard`]).
    extra_locks: Option<FxHashSet<[u64; 3]>>,
    /// No level below this one is the top (a shard stops before it).
    min_top: u8,
}

impl<S> Config<'_, S> {
    /// Whether position `p` is locked for another shard.
    #[inline]
    fn extra_locked(&self, p: &[f64; 3]) -> bool {
        self.extra_locks.as_ref().is_some_and(|l| l.contains(&pos_bits(*p)))
    }
}

/// Two normals of one position more than [`CreaseProbe::CREASE_DEGREES`]
/// apart, or one of them unusable (zero, not finite) and not the other: a
/// crease (a hard edge, each side's faces keeping their own normal).
/// Averaged normals would blur it; carried ones keep each side's (its
/// wedges are seams of the quadric's attributes).
pub(crate) fn creased(a: [f32; 3], b: [f32; 3]) -> bool {
    let unit = |n: [f32; 3]| {
        let n = n.map(|x| x as f64);
        let l = dot(n, n).sqrt();
        (l > 0.0 && l.is_finite()).then(|| n.map(|x| x / l))
    };
    match (unit(a), unit(b)) {
        (Some(a), Some(b)) => dot(a, b) < CreaseProbe::CREASE_DEGREES.to_radians().cos(),
        (None, None) => false,
        _ => true,
    }
}

/// Creases in an input's normals, in one pass over its vertices: the one
/// test of `--normals auto` for whole builds (the soup stage's vertex
/// pass, [`crate::soup::SoupReport::smooth_normals`]) and sharded ones (the
/// plan's pass), so both decide alike. The positions whose hash falls in a
/// share that halves whenever [`CreaseProbe::POSITIONS`] are held, with
/// every vertex at each (a position is in or out whole), the first normal
/// kept; a later vertex there more than [`CreaseProbe::CREASE_DEGREES`]
/// off is a crease ([`creased`]). A fixed number of positions, not a share of
/// `--mem`: the decision is the input's alone (about 3 MB held).
pub(crate) struct CreaseProbe {
    /// Positions kept: hash & mask == 0.
    mask: u64,
    /// The first normal at each position kept, by the position's 64-bit
    /// hash (two positions sharing one would only add a crease: the safe
    /// side).
    first: rustc_hash::FxHashMap<u64, [f32; 3]>,
    cap: usize,
    creases: u64,
}

impl CreaseProbe {
    /// Wedges further apart than this make a crease.
    pub const CREASE_DEGREES: f64 = 10.0;

    /// Positions held at most.
    pub const POSITIONS: usize = 1 << 16;

    pub fn new() -> CreaseProbe {
        Self::with_cap(Self::POSITIONS)
    }

    fn with_cap(cap: usize) -> CreaseProbe {
        CreaseProbe { mask: 0, first: Default::default(), cap, creases: 0 }
    }

    fn hash(k: &[u64; 3]) -> u64 {
        crate::geom::mix64(k[0] ^ k[1].rotate_left(21) ^ k[2].rotate_left(42))
    }

    /// Every vertex of a batch: most positions fall outside the share and
    /// cost a hash. Inserts grow with log(vertices / held), so the probe is
    /// a fixed cost of tens of ms: `octolod soup` of a 2 M-triangle sphere
    /// with normals, `perf`, 9.7 % of the samples with a call per vertex
    /// and 24-byte keys, 5.8 % in this loop with 8-byte ones (its time
    /// 0.29-0.34 s, without a probe 0.27-0.36 s).
    pub fn add_all(&mut self, batch: &[crate::mesh::Vertex]) {
        for v in batch {
            let h = Self::hash(&pos_bits(v.pos));
            if h & self.mask == 0 {
                self.held(h, v.normal);
            }
        }
    }

    #[cfg(test)]
    fn add(&mut self, v: &crate::mesh::Vertex) {
        self.add_all(std::slice::from_ref(v));
    }

    /// A vertex at a position in the share.
    #[inline(never)]
    fn held(&mut self, h: u64, normal: [f32; 3]) {
        match self.first.entry(h) {
            std::collections::hash_map::Entry::Occupied(e) => self.creases += creased(*e.get(), normal) as u64,
            std::collections::hash_map::Entry::Vacant(e) => {
                e.insert(normal);
                if self.first.len() > self.cap {
                    self.mask = self.mask << 1 | 1;
                    let m = self.mask;
                    self.first.retain(|h, _| h & m == 0);
                }
            }
        }
    }

    /// Enough positions seen and no crease.
    pub fn smooth(&self) -> bool {
        self.creases == 0 && self.first.len() >= 64
    }
}

/// A level builder stopped before level `level` ([`LevelBuilder::pause`]):
/// what a shard hands the merge, which resumes the union of several.
pub struct Paused {
    /// The next level to build.
    pub level: u8,
    /// The next level's leaves (path, depth) with their triangles' stats.
    pub tiling: Vec<(u64, u8)>,
    pub leaves: Vec<LeafStats>,
    /// The next level's chunks, finished.
    pub chunks: ChunkFile,
    /// Nodes built so far with their children lists and measured errors.
    pub nodes: Vec<NodeRec>,
    pub children: Vec<Vec<u32>>,
    pub simp_err: Vec<f64>,
    pub reports: Vec<LevelReport>,
    pub leaf_scale: u64,
    pub octree: OctreeReport,
    /// The scratch directory the chunks are in, kept until they are moved.
    pub scratch: Option<ScratchDir>,
}

/// The level being built: its leaves and the chunks routed to them.
struct Current {
    tiling: Tiling,
    leaves: Vec<LeafStats>,
    chunks: ChunkFile,
}

/// The DAG so far, one entry per node.
#[derive(Default)]
struct Dag {
    nodes: Vec<NodeRec>,
    children: Vec<Vec<u32>>,
    /// Measured simplification error.
    simp_err: Vec<f64>,
}

/// One level's nodes: the non-empty leaves of its tiling.
struct LevelNodes {
    level: u8,
    /// Leaf of each node.
    pub ids: Vec<usize>,
    /// Id of its first node.
    pub base: usize,
    pub triangles: u64,
    /// The top level: not simplified.
    pub is_final: bool,
    cube: LevelCube,
    next_cube: LevelCube,
    band: Band,
}

/// [`LevelBuilder::shared_vertices`]'s result.
struct SharedPass {
    resolved: Resolved,
    stats: SharedStats,
    hist: Histogram,
}

/// [`LevelBuilder::simplify_and_route`]'s result.
struct Routed {
    /// The next level's chunks (`None` above the top).
    chunks: Option<ChunkFile>,
    leaves: Vec<LeafStats>,
    triangles: u64,
    far: Vec<FarNode>,
}

/// Builds the levels one by one (see the module doc).
pub struct LevelBuilder<'a, S> {
    cfg: Config<'a, S>,
    cur: Option<Current>,
    dag: Dag,
    reports: Vec<LevelReport>,
    /// Leaf size multiplier: doubles after a level that barely shrinks.
    leaf_scale: u64,
    octree: OctreeReport,
}

impl<'a, S: NodeSimplifier> LevelBuilder<'a, S> {
    /// Starts from level 0, partitioned.
    pub fn new(l0: Level0, dir: &'a Path, scratch: ScratchDir, opts: &'a LodOptions, simplifier: S) -> LevelBuilder<'a, S> {
        let attrs = l0.header.attrs;
        let threads = rayon::current_num_threads().max(1);
        let normals = match opts.params.normals {
            // Unresolved (no vertex pass tested the input): carried, as a
            // creased input's are.
            _ if !attrs.normal() || !simplifier.averages_normals() => Normals::Carry,
            n => n,
        };
        let cfg = Config {
            opts,
            dir,
            scratch,
            attrs,
            bbox: l0.header.bbox,
            layout: VertexLayout::new(attrs),
            payload_layout: VertexLayout::new(attrs.with(AttrSet::NORMAL, true)),
            derived: !attrs.normal(),
            normals,
            unique_positions: attrs.quadric_dim() == 3,
            a_len: simplifier.carried_len(),
            hist_cap: (opts.params.mem / 256).max(1 << 16) as usize,
            batch: threads * 4,
            simplifier,
            extra_locks: None,
            min_top: 0,
        };
        let cur = Current { tiling: l0.tiling, leaves: l0.leaves, chunks: l0.chunks };
        LevelBuilder { cfg, cur: Some(cur), dag: Dag::default(), reports: Vec::new(), leaf_scale: 1, octree: l0.report }
    }

    /// A shard's builder: `locks` (positions it shares with other shards)
    /// stay locked at every level, and no level below `stop` is the top.
    pub fn for_shard(mut self, locks: FxHashSet<[u64; 3]>, stop: u8) -> Self {
        self.cfg.extra_locks = Some(locks);
        self.cfg.min_top = stop;
        self
    }

    /// Stops between levels: the state [`LevelBuilder::resume`] takes.
    pub fn pause(mut self, level: u8) -> Paused {
        let cur = self.cur.take().expect("a current level");
        Paused {
            level,
            tiling: cur.tiling.leaves.iter().map(|l| (l.path, l.depth)).collect(),
            leaves: cur.leaves,
            chunks: cur.chunks,
            nodes: self.dag.nodes,
            children: self.dag.children,
            simp_err: self.dag.simp_err,
            reports: self.reports,
            leaf_scale: self.leaf_scale,
            octree: self.octree,
            scratch: Some(self.cfg.scratch),
        }
    }

    /// Goes on from a paused state (level 0's header gives the attributes
    /// and the box); the paused leaves need not tile the cube (the merge's
    /// union of shards' leaves may overlap): only the next levels' do.
    pub fn resume(
        p: Paused,
        header: crate::soup::format::SoupHeader,
        dir: &'a Path,
        scratch: ScratchDir,
        opts: &'a LodOptions,
        simplifier: S,
    ) -> LevelBuilder<'a, S> {
        let tiling = Tiling { leaves: p.tiling.iter().map(|&(path, depth)| Tiling::leaf(path, depth)).collect() };
        let l0 = Level0 { header, tiling, leaves: p.leaves, chunks: p.chunks, report: p.octree };
        let mut b = LevelBuilder::new(l0, dir, scratch, opts, simplifier);
        b.dag = Dag { nodes: p.nodes, children: p.children, simp_err: p.simp_err };
        b.reports = p.reports;
        b.leaf_scale = p.leaf_scale;
        b
    }

    /// Builds level `level`; false once it was the top.
    pub fn build_level(&mut self, level: u8) -> Result<bool> {
        let t0 = Instant::now();
        let lv = self.nodes(level)?;
        let progress = Progress::items(2 * lv.ids.len() as u64, &format!("level {level}"), self.cfg.opts.quiet);
        let mut rep = LevelReport { level, nodes: lv.ids.len() as u64, triangles: lv.triangles, error_min: f64::INFINITY, ..Default::default() };
        let mut shared = self.shared_vertices(&lv, &progress)?;
        let (tau, predicted) = self.threshold(&lv, &shared.resolved)?;
        let next_tiling = self.partition_next(&lv, &shared.hist, predicted);
        rep.tau = tau;
        let mut routed = self.simplify_and_route(&lv, &mut shared, tau, next_tiling.as_ref(), &mut rep, &progress)?;
        progress.finish();
        shared.resolved.remove();
        if rep.nodes == 0 {
            rep.error_min = 0.0;
        }
        rep.seconds = t0.elapsed().as_secs_f64();
        // Every node of this level simplified to nothing (a few triangles
        // left, all collapsed, as `--root-tris 1` asks): the level above
        // would be empty, so this one is the top and the root keeps its
        // triangles.
        if routed.triangles == 0 {
            if let Some(mut c) = routed.chunks.take() {
                c.finish(routed.leaves.len())?;
                c.remove();
                rep.tau = 0.0;
            }
        }
        self.reports.push(rep);
        match (routed.chunks.take(), next_tiling) {
            (Some(mut c), Some(tiling)) => {
                c.finish(tiling.leaves.len())?;
                let next = Current { tiling, leaves: routed.leaves, chunks: c };
                self.measure_far(&lv, next, routed.far, routed.triangles)?;
                Ok(true)
            }
            _ => {
                self.cur.take().expect("a current level").chunks.remove();
                Ok(false)
            }
        }
    }

    /// Step 1, partition: the level's nodes are its tiling's non-empty
    /// leaves (level 0's from the octree, later ones decided by
    /// [`LevelBuilder::partition_next`] one level below). An error when
    /// [`MAX_LEVELS`] is reached without a single root.
    fn nodes(&self, level: u8) -> Result<LevelNodes> {
        let cur = self.cur.as_ref().expect("a current level");
        let p = &self.cfg.opts.params;
        let ids: Vec<usize> = (0..cur.tiling.leaves.len()).filter(|&i| cur.leaves[i].tris > 0 || !cur.chunks.refs_of(i).is_empty()).collect();
        let triangles: u64 = ids.iter().map(|&i| cur.leaves[i].tris).sum();
        // A single node its simplifier could not shrink (one level below it
        // was the same single node, now at ≥ 95 % of its triangles: islands
        // of a texture atlas each keep a few) is the root too.
        let stalled = self.reports.last().is_some_and(|r| r.nodes == 1 && triangles as f64 >= 0.95 * r.triangles as f64);
        let is_final = level >= self.cfg.min_top && ((ids.len() == 1 && (triangles <= p.root_tris || stalled)) || p.levels == Some(level));
        if level == MAX_LEVELS && !is_final {
            // Once a silent stop: a top level of many nodes, no single root.
            return Err(Error::Usage(format!(
                "the levels did not come down to one node of at most --root-tris {} triangles within {MAX_LEVELS} levels \
                 (level {level} holds {triangles} triangles in {} nodes; --level-ratio {}): raise --level-ratio or --root-tris, or stop at --levels L",
                p.root_tris,
                ids.len(),
                p.level_ratio
            )));
        }
        let cube = LevelCube::for_level(&self.cfg.bbox, level as u32);
        let next_cube = LevelCube::for_level(&self.cfg.bbox, level as u32 + 1);
        let cell_of = |i: usize| cube.cell(cur.tiling.leaves[i].path, cur.tiling.leaves[i].depth);
        let band = Band::new(&ids.iter().map(|&i| (cell_of(i), cur.leaves[i].reach)).collect::<Vec<_>>());
        Ok(LevelNodes { level, ids, base: self.dag.nodes.len(), triangles, is_final, cube, next_cube, band })
    }

    /// Step 2, shared vertices: every node's positions that may be shared
    /// (in the band of another node's cell) with their partial normals go
    /// through an external sort that keeps those held by several nodes;
    /// the same pass counts the centroids for the next level's partition.
    fn shared_vertices(&self, lv: &LevelNodes, progress: &Progress) -> Result<SharedPass> {
        let (cfg, cur) = (&self.cfg, self.cur.as_ref().expect("a current level"));
        let mem = cfg.opts.params.mem;
        let mut sorter = SharedSort::new((mem / 4) as usize, cfg.scratch.path());
        let mut hist = Histogram::new(HIST_DEPTH, cfg.hist_cap);
        // At most a cell per triangle.
        if !lv.is_final {
            hist.reserve(lv.triangles as usize);
        }
        // The histogram's depth so far: it only coarsens (when it outgrows
        // its cells), so nodes count at it, not finer; the counts come out
        // the same, with fewer runs for the (serial) merge.
        let hist_depth = AtomicU8::new(hist.depth());
        ordered(
            lv.ids.len(),
            cfg.batch,
            |_| Ok(()),
            |k, ()| band_records(cur, lv, k, hist_depth.load(Ordering::Relaxed)),
            |k, r: Pass1| {
                let node = (lv.base + k) as u32;
                for (p, n, f) in r.records {
                    sorter.push(node, p, n, f)?;
                }
                hist.add_runs(r.hist_depth, &r.hist);
                hist_depth.store(hist.depth(), Ordering::Relaxed);
                progress.inc(1);
                Ok(())
            },
        )?;
        let (resolved, stats) = sorter.resolve((mem / 4) as usize, cfg.scratch.path(), cfg.scratch.path().join("shared.bin"))?;
        Ok(SharedPass { resolved, stats, hist })
    }

    /// Step 3, threshold: the simplifier's curves of a sample of nodes
    /// (every `SAMPLED_NODES`-th part of the level, with their exact locks)
    /// give the one limit for the whole level at which it keeps
    /// 1/`--level-ratio` of its triangles, and the share predicted there.
    fn threshold(&self, lv: &LevelNodes, resolved: &Resolved) -> Result<(f64, f64)> {
        if lv.is_final {
            return Ok((0.0, 1.0));
        }
        let (cfg, cur) = (&self.cfg, self.cur.as_ref().expect("a current level"));
        let stride = (lv.ids.len() / SAMPLED_NODES).max(1);
        let picked: Vec<usize> = (0..lv.ids.len()).filter(|k| k % stride == 0).collect();
        let mut reader = resolved.reopen()?;
        let sets = picked.iter().map(|&k| reader.take((lv.base + k) as u32)).collect::<Result<Vec<_>>>()?;
        let curves: Vec<Result<S::Curve>> = picked
            .par_iter()
            .zip(sets.par_iter())
            .map(|(&k, set)| {
                let g = cur.chunks.gather(lv.ids[k])?;
                let w = Welded::new(&g.mesh, cfg.unique_positions);
                let locked = w.locks_at(|pi| set.contains_key(&pos_bits(w.pos[pi])) || cfg.extra_locked(&w.pos[pi]));
                let carried = (lv.level > 0).then_some(&g.a[..]);
                Ok(cfg.simplifier.curve(&NodeInput { mesh: &g.mesh, carried, locked: &locked, pos_of: Some(&w.pos_of) }))
            })
            .collect();
        let curves = curves.into_iter().collect::<Result<Vec<_>>>()?;
        Ok(cfg.simplifier.choose_limit(&curves, 1.0 / cfg.opts.params.level_ratio))
    }

    /// Step 1 for the next level, before this one is simplified: its leaves
    /// from the histogram of this level's centroids scaled by the predicted
    /// share, so each simplified node routes its triangles straight to them.
    /// `None` above the top.
    fn partition_next(&self, lv: &LevelNodes, hist: &Histogram, predicted: f64) -> Option<Tiling> {
        if lv.is_final {
            return None;
        }
        let p = &self.cfg.opts.params;
        // One node when everything fits one leaf (the cut's root).
        Some(Tiling::from_histogram(hist, predicted, p.leaf_tris.saturating_mul(self.leaf_scale), p.max_depth))
    }

    /// Step 4, simplify and route: per node, in order, the payload (with
    /// normals from the whole neighbourhood when derived), its
    /// simplification down to `tau`, its measured error, and its output
    /// cut into chunks for the next level's leaves; the node records are
    /// appended as the results come in (error and bounds saturated over
    /// the children: step 5 of the module doc).
    fn simplify_and_route(
        &mut self,
        lv: &LevelNodes,
        shared: &mut SharedPass,
        tau: f64,
        next: Option<&Tiling>,
        rep: &mut LevelReport,
        progress: &Progress,
    ) -> Result<Routed> {
        let (cfg, cur, dag) = (&self.cfg, self.cur.as_ref().expect("a current level"), &mut self.dag);
        let mut pack = PackWriter::create(cfg.dir, lv.level as usize)?;
        let mut next_chunks = match next {
            Some(_) => Some(ChunkFile::create(cfg.scratch.path().join(format!("chunks-{}.bin", lv.level + 1)), cfg.layout, cfg.a_len)?),
            None => None,
        };
        let encoder = next_chunks.as_ref().map(ChunkFile::encoder);
        let mut routed = Routed { chunks: None, leaves: vec![LeafStats::default(); next.map_or(0, |t| t.leaves.len())], triangles: 0, far: Vec::new() };
        let (mut shared_occurrences, mut seam_only, mut prev_freed, mut positions) = (0u64, 0u64, 0u64, 0u64);
        let resolved = &mut shared.resolved;
        let diagonal = cfg.bbox.diagonal();
        ordered(
            lv.ids.len(),
            cfg.batch,
            |k| resolved.take((lv.base + k) as u32),
            |k, set| self_node(cfg, cur, lv, k, &set, tau, next, encoder.as_ref()),
            |k, r: Pass2| {
                let (offset, bytes) = pack.append(&r.payload)?;
                let mut bounds = r.content;
                // Each child's distance to the input plus how far its
                // simplification moved it, at most the input's extent.
                let mut error = 0.0f64;
                for &c in &r.children {
                    bounds.merge(&dag.nodes[c as usize].bounds);
                    error = error.max(dag.nodes[c as usize].error as f64 + dag.simp_err[c as usize]);
                }
                let error32 = next_up_f32(error.min(diagonal));
                rep.error_min = rep.error_min.min(error32 as f64);
                rep.error_max = rep.error_max.max(error32 as f64);
                rep.bytes += bytes as u64;
                rep.clamped += r.clamped;
                let leaf = &cur.tiling.leaves[lv.ids[k]];
                dag.nodes.push(NodeRec {
                    level: lv.level,
                    cell: lv.cube.cell(leaf.path, leaf.depth),
                    bounds,
                    error: error32,
                    offset,
                    bytes,
                    tris: r.tris,
                    verts: r.verts,
                    crc: crc32c::crc32c(&r.payload),
                    simp_tris: r.simp_tris,
                    first_child: 0,
                    child_count: 0,
                    first_parent: 0,
                    parent_count: 0,
                    part: 0,
                    patch_shift: 0,
                });
                dag.children.push(r.children);
                dag.simp_err.push(r.error);
                if !r.far.is_empty() || !r.far_reps.is_empty() {
                    routed.far.push(FarNode { node: dag.nodes.len() - 1 - lv.base, base: r.base, far: r.far, far_reps: r.far_reps });
                }
                shared_occurrences += r.shared;
                positions += r.positions;
                seam_only += r.seam_only;
                prev_freed += r.prev_freed;
                if let Some(file) = next_chunks.as_mut() {
                    for (target, bytes, st) in &r.routed {
                        file.append(*target, bytes)?;
                        let s = &mut routed.leaves[*target as usize];
                        s.tris += st.tris;
                        s.bounds.merge(&st.bounds);
                        s.reach = s.reach.max(st.reach);
                        routed.triangles += st.tris;
                    }
                }
                progress.inc(1);
                Ok(())
            },
        )?;
        pack.finish()?;
        let st = &shared.stats;
        rep.positions = positions - (shared_occurrences - st.shared);
        rep.set_locked(st.shared + seam_only, prev_freed + st.shared_was_locked, st.shared_was_locked);
        routed.chunks = next_chunks;
        Ok(routed)
    }

    /// Step 5's remeasure: nodes whose error a few far points set have
    /// them measured again against the whole next level or the level itself
    /// (the neighbour's surface there is what a cut draws); then `next`
    /// becomes the current level.
    fn measure_far(&mut self, lv: &LevelNodes, next: Current, far: Vec<FarNode>, next_triangles: u64) -> Result<()> {
        let old = self.cur.replace(next).expect("a current level");
        let new = self.cur.as_ref().expect("the next level");
        remeasure_far([(&new.chunks, &new.leaves[..]), (&old.chunks, &old.leaves[..])], &mut self.dag.simp_err[lv.base..], far)?;
        old.chunks.remove();
        self.advance(lv, next_triangles);
        Ok(())
    }

    /// A level that barely shrank (everything locked) doubles the next
    /// level's leaf size, so nodes merge until nothing is shared.
    fn advance(&mut self, lv: &LevelNodes, next_triangles: u64) {
        if next_triangles as f64 > 0.9 * lv.triangles as f64 {
            self.leaf_scale = self.leaf_scale.saturating_mul(2);
        }
    }

    /// Step 6, link the DAG: children lists in patch order and their
    /// inverse; the packs synced; the index's header.
    pub fn finish(self, store_id: u64) -> Result<Built> {
        let Dag { mut nodes, children: node_children, .. } = self.dag;
        let (children, parents) = link_dag(&mut nodes, &node_children);
        crate::store::sync_packs(self.cfg.dir, &nodes)?;
        let normals = self.cfg.normals;
        let header = StoreHeader {
            attrs: self.cfg.attrs,
            derived_normals: self.cfg.derived,
            levels: self.reports.len() as u32,
            nodes: nodes.len() as u64,
            root: nodes.len().saturating_sub(1) as u32,
            store_id,
            bbox: self.cfg.bbox,
        };
        let quadric_dim = super::quadric_attrs(self.cfg.attrs, normals).quadric_dim();
        Ok(Built { header, nodes, children, parents, levels: self.reports, octree: self.octree, normals, quadric_dim })
    }
}

/// Sets each node's `first_child`/`child_count` and `first_parent`/
/// `parent_count` into the flat children list (in the order given: patch
/// order) and parents list (by node id) it returns.
fn link_dag(nodes: &mut [NodeRec], node_children: &[Vec<u32>]) -> (Vec<u32>, Vec<u32>) {
    let mut children = Vec::new();
    let mut parent_lists: Vec<Vec<u32>> = vec![Vec::new(); nodes.len()];
    for (i, kids) in node_children.iter().enumerate() {
        nodes[i].first_child = children.len() as u32;
        nodes[i].child_count = kids.len() as u32;
        children.extend_from_slice(kids);
        for &c in kids {
            parent_lists[c as usize].push(i as u32);
        }
    }
    let mut parents = Vec::new();
    for (i, ps) in parent_lists.iter().enumerate() {
        nodes[i].first_parent = parents.len() as u32;
        nodes[i].parent_count = ps.len() as u32;
        parents.extend_from_slice(ps);
    }
    (children, parents)
}

/// Pass-1 result of one node.
struct Pass1 {
    records: Vec<([f64; 3], [f32; 3], u32)>,
    /// (key at `hist_depth`, count), sorted.
    hist: Vec<(u64, u64)>,
    hist_depth: u8,
}

/// Pass-2 result of one node.
#[derive(Default)]
struct Pass2 {
    payload: Vec<u8>,
    content: Aabb,
    tris: u32,
    verts: u32,
    simp_tris: u32,
    children: Vec<u32>,
    error: f64,
    /// The error without `far` ([`NodeError`]).
    base: f64,
    /// Input vertices setting the error, to measure against the whole next level.
    far: Vec<([f64; 3], f64)>,
    /// Representatives setting it, to measure against the whole level.
    far_reps: Vec<([f64; 3], f64)>,
    clamped: u64,
    /// Distinct positions in the node.
    positions: u64,
    shared: u64,
    seam_only: u64,
    prev_freed: u64,
    /// Encoded chunks for the next level: (target leaf, bytes, their stats).
    routed: Vec<(u32, Vec<u8>, LeafStats)>,
}

impl Pass2 {
    /// The node's measured error; its far points are kept only when a few
    /// of them set it (worth measuring again, `remeasure_far`).
    fn set_error(&mut self, ne: NodeError) {
        self.error = ne.error;
        self.base = ne.base;
        if ne.error > 2.0 * ne.base {
            self.far = ne.far;
            self.far_reps = ne.far_reps;
        }
    }
}

/// Pass 1 of one node (step 2): its band's positions with their partial
/// normals and flags, and its centroid counts at histogram depth `d`.
/// The node's chunks are read unwelded: only the positions in the band are
/// merged (by their bits, in the order the whole node's weld met them),
/// each with its triangles' normals summed in the same order, so the
/// records are the welded node's.
fn band_records(cur: &Current, lv: &LevelNodes, k: usize, d: u8) -> Result<Pass1> {
    let leaf = lv.ids[k];
    let test = lv.band.tester(k, &cur.leaves[leaf].bounds);
    let mut band: FxHashMap<[u64; 3], u32> = FxHashMap::default();
    let mut records: Vec<([f64; 3], [f64; 3], u32)> = Vec::new();
    let mut centroids = Vec::new();
    let mut ids = Vec::new();
    let scan = cur.chunks.scan(leaf)?;
    let (nv, nt) = scan.sizes();
    // The band is a part of the node: room for a quarter of its vertices,
    // grown when more.
    band.reserve(nv / 4);
    records.reserve(nv / 4);
    if !lv.is_final {
        centroids.reserve(nt);
    }
    scan.each(|pos, locked, tris| {
        ids.clear();
        for (v, p) in pos.iter().enumerate() {
            if !test.may_share(*p) {
                ids.push(u32::MAX);
                continue;
            }
            let n = records.len() as u32;
            let id = *band.entry(pos_bits(*p)).or_insert(n);
            if id == n {
                records.push((*p, [0.0; 3], 0));
            }
            if locked[v] {
                records[id as usize].2 = WAS_LOCKED;
            }
            ids.push(id);
        }
        for t in tris {
            let c = t.map(|v| pos[v as usize]);
            if !lv.is_final {
                centroids.push(centroid(c));
            }
            let at = t.map(|v| ids[v as usize]);
            if at == [u32::MAX; 3] {
                continue;
            }
            let n = cross(sub(c[1], c[0]), sub(c[2], c[0]));
            for k in 0..3 {
                // Once per position, as the welded node counts it.
                if at[k] != u32::MAX && !at[..k].contains(&at[k]) {
                    let r = &mut records[at[k] as usize].1;
                    for a in 0..3 {
                        r[a] += n[a];
                    }
                }
            }
        }
    })?;
    let records = records.into_iter().map(|(p, n, f)| (p, n.map(|x| x as f32), f)).collect();
    // Centroid counts at the histogram's depth, as sorted runs.
    let hist = if lv.is_final { Vec::new() } else { lv.next_cube.cell_counts(d, centroids.into_iter()) };
    Ok(Pass1 { records, hist, hist_depth: d })
}

/// Node `k` of the level (its shared positions `set`): its payload, its
/// simplification and the chunks it routes to the next level's leaves.
#[allow(clippy::too_many_arguments, reason = "the step's inputs, each read-only and distinct")]
fn self_node<S: NodeSimplifier>(
    cfg: &Config<S>,
    cur: &Current,
    lv: &LevelNodes,
    k: usize,
    set: &SharedSet,
    tau: f64,
    next: Option<&Tiling>,
    encoder: Option<&ChunkEncoder>,
) -> Result<Pass2> {
    let (leaf, id) = (lv.ids[k], lv.base + k);
    let mut g = cur.chunks.gather(leaf)?;
    let w = Welded::new(&g.mesh, cfg.unique_positions);
    let mut p2 = Pass2 { positions: w.pos.len() as u64, ..Default::default() };
    // Each position's shared record, looked up once.
    let hits: Vec<Option<&([f32; 3], u32)>> = w.pos.iter().map(|p| set.get(&pos_bits(*p))).collect();
    // A shard's positions shared with other shards count as shared.
    let shared_at = |pi: usize| hits[pi].is_some() || cfg.extra_locked(&w.pos[pi]);
    // Locks: shared positions (attribute seams simplify along themselves).
    let locked = w.locks_at(shared_at);
    for (pi, hit) in hits.iter().enumerate() {
        let (hit, sh) = (hit.is_some(), shared_at(pi));
        // Another shard's positions count with the seams (the level's
        // distinct shared positions come from the sort).
        p2.shared += hit as u64;
        p2.seam_only += (sh && !hit) as u64;
        p2.prev_freed += (w.was_locked(&g, pi) && !sh) as u64;
    }
    // The stored mesh, with normals from the whole neighbourhood. Set in
    // place: without input normals they are in neither the quadrics nor
    // the next level's chunks, and the simplified mesh's are reset as it is
    // stored (`as_stored`).
    if cfg.derived {
        for (v, x) in g.mesh.vertices.iter_mut().enumerate() {
            let pi = w.pos_of[v] as usize;
            let n = match hits[pi] {
                Some((n, _)) => n.map(|c| c as f64),
                None => w.normal[pi],
            };
            x.normal = unit(n);
        }
    }
    let patches: Vec<(u32, u32)> = if lv.level == 0 { vec![(NO_NODE, g.mesh.triangles.len() as u32)] } else { g.patches.clone() };
    encode_payload(if cfg.derived { &cfg.payload_layout } else { &cfg.layout }, &g.mesh, &patches, &mut p2.payload);
    p2.content = w.bounds;
    p2.tris = g.mesh.triangles.len() as u32;
    p2.verts = g.mesh.vertices.len() as u32;
    p2.children = if lv.level == 0 { Vec::new() } else { g.patches.iter().map(|p| p.0).collect() };
    let (Some(next), Some(file)) = (next, encoder) else { return Ok(p2) };
    // Positions as stored, so errors and welding see the same bits.
    let layout = &cfg.layout;
    let as_stored = |m: &mut IndexedMesh| {
        let mut vb = vec![0u8; layout.size];
        for v in m.vertices.iter_mut() {
            layout.encode(v, &mut vb);
            *v = layout.decode(&vb);
        }
    };
    let carried = (lv.level > 0).then_some(&g.a[..]);
    let s = cfg.simplifier.simplify(&NodeInput { mesh: &g.mesh, carried, locked: &locked, pos_of: Some(&w.pos_of) }, tau, &as_stored);
    p2.clamped = s.clamped;
    p2.set_error(s.error);
    let out = &s.mesh;
    let mut last = 0;
    let leaf_of: Vec<u32> = out.triangles.iter().map(|t| next.locate_near(lv.next_cube.key(tri_centroid(out, t)), &mut last) as u32).collect();
    p2.simp_tris = out.triangles.len() as u32;
    let mut routed = split_by_target(out, &s.carried, cfg.a_len, &s.locked, &leaf_of);
    if routed.is_empty() {
        // Everything collapsed: still give the node a parent.
        let c = w.bounds.center();
        routed.push((next.locate(lv.next_cube.key(c)) as u32, IndexedMesh::default(), Vec::new(), Vec::new()));
    }
    p2.routed = routed
        .into_iter()
        .map(|(target, m, a, l)| {
            let mut bytes = Vec::new();
            file.encode(target, id as u32, &m, &a, &l, &mut bytes);
            (target, bytes, super::leaf_stats(&m))
        })
        .collect();
    Ok(p2)
}

/// A unit f32 normal ((0, 0, 1) when the sum vanishes).
fn unit(n: [f64; 3]) -> [f32; 3] {
    let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    if l > 0.0 && l.is_finite() {
        n.map(|c| (c / l) as f32)
    } else {
        [0.0, 0.0, 1.0]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gen::{GenOptions, Generator, Shape};
    use crate::lod::octree::build_octree;
    use crate::lod::simplifier::ClusterNodes;
    use crate::manifest::BuildParams;
    use crate::soup::format::SoupWriter;
    use std::collections::HashMap;

    /// Every vertex at a kept position is compared, however many the
    /// share keeps: a crease is found whether or not the probe shrank.
    #[test]
    fn the_crease_probe_sees_wedges_apart_at_any_share() {
        let v = |i: u64, n: [f32; 3]| crate::mesh::Vertex { pos: [i as f64, (i * 7 % 13) as f64, 0.5], normal: n, ..Default::default() };
        for cap in [1 << 12, 100] {
            let mut p = CreaseProbe::with_cap(cap);
            for i in 0..5000 {
                p.add(&v(i, [0.0, 0.0, 1.0]));
                // A second wedge alike (a uv seam): no crease.
                p.add(&v(i, [0.0, 0.05, 1.0]));
            }
            assert!(p.smooth(), "cap {cap}: {} creases", p.creases);
            assert_eq!(p.mask != 0, cap < 5000, "cap {cap}");
            assert!(p.first.len() <= cap);
            for i in 0..5000 {
                p.add(&v(i, [1.0, 0.0, 0.0]));
            }
            assert!(!p.smooth() && p.creases as usize >= p.first.len(), "cap {cap}: {} creases over {}", p.creases, p.first.len());
        }
        assert!(!CreaseProbe::with_cap(100).smooth(), "nothing seen decides nothing");
    }

    /// A generated shape's soup in `dir`, and the options of a small build.
    fn setup(dir: &Path, shape: Shape, tris: u64) -> (std::path::PathBuf, LodOptions) {
        let (vs, fs) = Generator::new(&GenOptions { shape, tris, ..Default::default() }).mesh();
        let soup = dir.join("in.soup");
        let mut w = SoupWriter::create(&soup, AttrSet::POSITION_ONLY, false, true).unwrap();
        for f in &fs {
            w.push(&f.map(|v| vs[v as usize])).unwrap();
        }
        w.commit(vs.len() as u64, fs.len() as u64, 0).unwrap();
        let params = BuildParams { leaf_tris: 2000, root_tris: 1000, mem: 64 << 20, ..Default::default() };
        (soup, LodOptions { params, ..Default::default() })
    }

    fn builder<'a>(soup: &Path, store: &'a Path, opts: &'a LodOptions) -> LevelBuilder<'a, ClusterNodes> {
        std::fs::create_dir_all(store).unwrap();
        let scratch = crate::io::scratch_dir(store).unwrap();
        let bbox = crate::soup::format::SoupReader::open(soup).unwrap().header.bbox;
        let l0 = build_octree(soup, scratch.path().join("chunks-0.bin"), &LevelCube::for_level(&bbox, 0), &opts.octree(), None).unwrap();
        LevelBuilder::new(
            l0,
            store,
            scratch,
            opts,
            ClusterNodes { attrs: AttrSet::POSITION_ONLY, rel_tol: opts.rel_tol, share: 1.0 / opts.params.level_ratio, average_normals: false },
        )
    }

    #[test]
    fn one_level_step_by_step() {
        let d = tempfile::tempdir().unwrap();
        let (soup, opts) = setup(d.path(), Shape::Sphere, 20_000);
        let store = d.path().join("s.octolod");
        let mut b = builder(&soup, &store, &opts);
        let quiet = Progress::items(0, "", true);

        // Partition: every triangle in exactly one node.
        let lv = b.nodes(0).unwrap();
        let input = 20_000f64;
        assert!(lv.ids.len() >= 8 && !lv.is_final, "{} nodes", lv.ids.len());
        assert!((lv.triangles as f64 - input).abs() < 0.02 * input, "{} triangles", lv.triangles);

        // Shared vertices, exactly: a node's set is the positions it holds
        // that another node holds too.
        let mut shared = b.shared_vertices(&lv, &quiet).unwrap();
        assert_eq!(shared.hist.total(), lv.triangles, "every centroid counted");
        let cur = b.cur.as_ref().unwrap();
        let mut holders: HashMap<[u64; 3], u32> = HashMap::new();
        let per_node: Vec<Vec<[u64; 3]>> = lv
            .ids
            .iter()
            .map(|&leaf| {
                let w = Welded::new(&cur.chunks.gather(leaf).unwrap().mesh, true);
                w.pos.iter().map(|p| pos_bits(*p)).collect()
            })
            .collect();
        for ps in &per_node {
            for p in ps {
                *holders.entry(*p).or_insert(0) += 1;
            }
        }
        let mut reader = shared.resolved.reopen().unwrap();
        let mut total_shared = 0;
        for (k, ps) in per_node.iter().enumerate() {
            let set = reader.take((lv.base + k) as u32).unwrap();
            let want: Vec<&[u64; 3]> = ps.iter().filter(|p| holders[*p] >= 2).collect();
            assert_eq!(set.len(), want.len(), "node {k}");
            assert!(want.iter().all(|p| set.contains_key(*p)), "node {k}");
            total_shared += set.len();
        }
        assert!(total_shared > 0);

        // Threshold: the level keeps about half.
        let (tau, predicted) = b.threshold(&lv, &shared.resolved).unwrap();
        assert!(tau > 0.0 && (0.3..0.7).contains(&predicted), "tau {tau}, predicted {predicted}");
        let next = b.partition_next(&lv, &shared.hist, predicted).expect("a next level");
        assert!(!next.leaves.is_empty());

        // Simplify and route: half the triangles go up, each node recorded.
        let mut rep = LevelReport::default();
        let routed = b.simplify_and_route(&lv, &mut shared, tau, Some(&next), &mut rep, &quiet).unwrap();
        let kept = routed.triangles as f64 / lv.triangles as f64;
        assert!((0.3..0.7).contains(&kept), "{kept} of the triangles routed up");
        assert_eq!(routed.leaves.iter().map(|l| l.tris).sum::<u64>(), routed.triangles);
        assert_eq!(b.dag.nodes.len(), lv.ids.len());
        assert!(b.dag.simp_err.iter().all(|&e| (0.0..0.05).contains(&e)), "errors {:?}", b.dag.simp_err);
        assert!(rep.locked_fraction > 0.0 && rep.locked_fraction < 0.5, "locked {}", rep.locked_fraction);
        assert_eq!(rep.bytes, b.dag.nodes.iter().map(|n| n.bytes as u64).sum::<u64>());
    }

    #[test]
    fn levels_halve_up_to_one_root_and_link_both_ways() {
        let d = tempfile::tempdir().unwrap();
        let (soup, opts) = setup(d.path(), Shape::Terrain, 16_000);
        let store = d.path().join("s.octolod");
        let mut b = builder(&soup, &store, &opts);
        let mut level = 0;
        while b.build_level(level).unwrap() {
            level += 1;
        }
        let built = b.finish(7).unwrap();
        let r = &built.levels;
        assert!(r.len() >= 4, "{} levels", r.len());
        for w in r.windows(2) {
            let share = w[1].triangles as f64 / w[0].triangles as f64;
            assert!((0.3..0.75).contains(&share), "level {}: {share}", w[1].level);
        }
        let top = r.last().unwrap();
        assert!(top.nodes == 1 && top.triangles <= 1000);
        assert_eq!(built.header.store_id, 7);
        assert_eq!(built.header.root as usize, built.nodes.len() - 1);
        // Children and parents are each other's inverse; errors never shrink upwards.
        for (i, n) in built.nodes.iter().enumerate() {
            for &c in &built.children[n.first_child as usize..][..n.child_count as usize] {
                let cn = &built.nodes[c as usize];
                assert!(built.parents[cn.first_parent as usize..][..cn.parent_count as usize].contains(&(i as u32)));
                assert!(cn.level + 1 == n.level && cn.error <= n.error);
            }
        }
        assert_eq!(built.children.len(), built.parents.len());
    }

    #[test]
    fn link_dag_inverts_the_children_lists() {
        let rec = |level| NodeRec {
            level,
            cell: Aabb::EMPTY,
            bounds: Aabb::EMPTY,
            error: 0.0,
            offset: 0,
            bytes: 0,
            tris: 0,
            verts: 0,
            crc: 0,
            simp_tris: 0,
            first_child: 9,
            child_count: 9,
            first_parent: 9,
            parent_count: 9,
            part: 0,
            patch_shift: 0,
        };
        let mut nodes = vec![rec(0), rec(0), rec(0), rec(1), rec(1), rec(2)];
        let kids = vec![vec![], vec![], vec![], vec![0, 1], vec![1, 2], vec![4, 3]];
        let (children, parents) = link_dag(&mut nodes, &kids);
        assert_eq!(children, [0, 1, 1, 2, 4, 3]);
        assert_eq!(parents, [3, 3, 4, 4, 5, 5]);
        let of = |i: usize| (nodes[i].first_child, nodes[i].child_count, nodes[i].first_parent, nodes[i].parent_count);
        assert_eq!(of(0), (0, 0, 0, 1));
        assert_eq!(of(1), (0, 0, 1, 2));
        assert_eq!(of(5), (4, 2, 6, 0));
    }

    /// Two normals of a position more than 10° apart make a crease, or
    /// one usable and one not; alike ones, or two unusable, do not.
    #[test]
    fn creases_are_normals_apart() {
        let tilt = |deg: f64| [deg.to_radians().sin() as f32, 0.0, deg.to_radians().cos() as f32];
        assert!(!creased(tilt(0.0), tilt(9.0)) && !creased(tilt(0.0), tilt(-0.5)));
        assert!(!creased([0.0; 3], [0.0; 3]));
        assert!(creased(tilt(0.0), tilt(45.0)) && creased(tilt(3.0), tilt(45.0)));
        assert!(creased(tilt(0.0), [f32::NAN, 0.0, 1.0]));
    }
}

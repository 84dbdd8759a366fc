//! LOD stage (levels of detail v2): a DAG of levels that halve, each level
//! partitioned afresh so the previous level's seams are simplified, every
//! cut crack-free.
//!
//! Takes: the input's triangle soup (`.soup`), or level 0 already
//! partitioned by the soup stage ([`Level0Source`]), the memory budget and the
//! hierarchy's parameters ([`LodOptions`]). Gives: the store's payloads
//! (`level-L.pack`), its node records and children/parents lists, and a
//! report per level ([`LevelReport`]).
//!
//! Per level L (level 0 is the input):
//! 1. **Partition.** Level L's triangles are cut into the leaves of an
//!    adaptive octree (`--leaf-tris`, `--max-depth`) over level L's cube,
//!    which is shifted by a third of its size from level L−1's, so that no
//!    face of level L lies on (or near) a face of level L−1
//!    ([`partition`]'s doc proves the third). Level 0 is cut from counts
//!    of the triangles' first corners, then routed in one pass ([`octree`]:
//!    in `build`, both inside the soup stage); level L+1's
//!    leaves are decided *before* level L is simplified, from the
//!    histogram of level L's centroids scaled by the predicted reduction,
//!    so each simplified node can route its triangles straight to them as
//!    indexed [`chunks`] — one streaming pass, no sort per level.
//! 2. **Shared vertices, exactly.** A node locks the positions it shares
//!    with another node of the level and nothing else — never the mesh's
//!    own open border ([`shared`]: band positions through an external
//!    sort). Positions where a node holds several attribute variants
//!    (uv/normal/color seams) are locked too, so seams are never torn.
//! 3. **Levels that halve.** Each node is simplified by adaptive quadric
//!    clustering ([`cluster`]) down to one error threshold τ for the whole
//!    level, chosen so the level holds 1/`--level-ratio` of the triangles
//!    below it (τ from the split curves of a sample of nodes). A single
//!    threshold, rather than a fixed share per node, spends the reduction
//!    where it costs least: a small node that is mostly seam is not
//!    crushed to meet its share.
//! 4. **Quadrics from the input.** Every vertex carries the quadric of the
//!    input surface it stands for (a representative: the sum of its
//!    members'), so level L's representatives minimise the distance to the
//!    input's planes, not to level L−1's (whose chords lie inside curved
//!    surfaces): errors do not pile up from level to level. It is carried
//!    about the vertex's own position — matrix, half-gradient, residual
//!    ([`crate::quadric::carry_len`]) — so it stays exact where a
//!    representative was clamped into its box or solved at reduced rank.
//!    Only the input's planes are carried: the Garland–Heckbert border
//!    planes of level 0 go on the mesh's own open edges, never on a node's
//!    seams (planes there, carried up, once pulled every later level's
//!    clusters towards the old seams: 2–4× the RMS error with small nodes).
//! 5. **Error and bounds monotone on the DAG.** A node's error is the
//!    largest, over its children, of the child's error plus the measured
//!    error of the child's simplification (two-sided, vertex-sampled: input
//!    vertices to the simplified surface, representatives to the input
//!    surface; faces too next to the mesh's own open border, where
//!    clustering can fill or widen a small hole with every vertex still on
//!    the other surface: `BorderFaces`), at most the input's extent: each step's deviation is
//!    measured against the level it was made from, so the steps are added
//!    up (the triangle inequality) to bound the distance to the input
//!    itself. Taking only the largest, as Nexus and meshoptimizer's
//!    clusterlod do by default, measured up to 2.2× below metro's
//!    distance to the input (a 2 M scan's level 7); the sum measured
//!    1.1–2.3× above it from level 2 on (the README's "What E bounds").
//!    Its bounds hold its triangles and its children's bounds. Projected
//!    error therefore never grows from a node to its parent, along any
//!    path. A node whose error is set by a few points (input vertices far
//!    from its own output: a flap folded over a neighbour's surface,
//!    dropped as a fold; representatives far from its own input) has them
//!    measured again against the whole next level, or the whole level
//!    (`remeasure_far`): the neighbour's surface there is what a cut
//!    draws.
//! 6. **Patches.** Node N of level L+1 stores its triangles grouped by the
//!    level-L node (child) each came from; a cut draws, per selected node,
//!    the patches whose child is not selected ([`crate::store`]).
//! 7. **Normals without node patches.** When the input has no normals,
//!    each level's vertices get area-weighted normals from their whole
//!    neighbourhood at that level: shared positions sum the partial normals
//!    of every node that holds them (carried by the same sort that finds
//!    them), so both sides of a seam shade alike.
//!
//! **`--simplifier collapse`** (default `cluster`, everything above) swaps
//! step 3's node reduction for quadric edge collapse with attributes
//! ([`collapse`]: meshoptimizer's `simplifyWithUpdate`, the code `octolod
//! simplify --simplifier collapse` uses), the rest unchanged:
//! - *Target.* One absolute error limit for the whole level, chosen like
//!   τ: a sample of nodes is collapsed to seven shares of its triangles
//!   (0.85 … 0.15), giving each an (error, triangles) curve; the limit is
//!   where the sampled nodes together keep 1/`--level-ratio`, and every
//!   node collapses until its next collapse would exceed it. A fixed share
//!   per node (`triangles / ratio`, tried first) halves exactly but crushes
//!   small nodes that are mostly locked seam: on a 1 M sphere it left one
//!   spot 4.4e-4 off at level 1 (20× clustering's Hausdorff distance), the
//!   limit 1.7e-4. The curves cost seven collapses per sampled node (32 per
//!   level): the build takes about twice as long as with fixed shares.
//! - *Locks.* The same as clustering's: shared positions and attribute
//!   seams, kept bit-exact, so cuts stay crack-free. A triangle and one of
//!   opposite orientation on the same positions (a small torus's tube
//!   flattened) are dropped together, as clustering drops its folds.
//! - *No carried quadrics.* meshoptimizer builds its quadrics from the
//!   mesh it is given (level L−1's, not the input's), so the chunks
//!   between levels carry none (`a_len` 0). Errors are measured, not
//!   assumed, so piling up shows in the node errors.
//! - *Error.* Edge collapse keeps no member lists, so [`node_error`]'s
//!   neighbourhood bound does not apply; the node's error is the exact
//!   two-sided vertex-sampled distance through a BVH of each side, with
//!   the same face samples next to the border as clustering's
//!   ([`collapse::collapse_error`]); where a few far points set it (a
//!   flap dropped as a fold) they are measured again against the whole
//!   next level or the level itself (`remeasure_far`), as clustering's
//!   are; then saturated as in step 5.
//! - *Patches, bounds, attributes, normals.* Each node's output is routed
//!   to the next level as chunks tagged with the node, as with clustering,
//!   so patches by source child come out the same way. Positions are
//!   clamped into the node's input box, attributes into their ranges,
//!   normals renormalised; derived normals (step 7) are computed the same.
//!   The store format is unchanged; `store.json` records the simplifier.
//!
//! Levels stop at a single node of at most `--root-tris` triangles (or at
//! `--levels`), or at the last level whose simplification would leave
//! nothing (so the root always holds a triangle), within [`MAX_LEVELS`]
//! (more is an error naming `--level-ratio`). A level that barely shrinks (everything locked) doubles the
//! next level's leaf size, so nodes merge until nothing is shared.

pub mod chunks;
pub mod cluster;
pub mod collapse;
pub mod measure;
pub mod octree;
pub mod ordered;
pub mod partition;
pub mod shared;

use crate::error::{Error, Result};
use crate::geom::{cross, sub};
use crate::geom::{pos_bits, Welder};
use crate::manifest::{BuildParams, LevelReport, Simplifier};
use crate::mesh::IndexedMesh;
use crate::mesh::{Aabb, AttrSet, VertexLayout};
use crate::progress::Progress;
use crate::store::{encode_payload, NodeRec, PackWriter, StoreHeader, NO_NODE};
use chunks::{split_by_target, ChunkFile, Gathered};
use cluster::Splits;
use measure::{node_error, remeasure_far, FarNode, NodeError};
use octree::{build_octree, FirstCount, Level0, OctreeOptions, OctreeReport};
use ordered::ordered;
use partition::{Histogram, LevelCube, Tiling};
use rayon::prelude::*;
use shared::{Band, SharedSort, WAS_LOCKED};
use std::path::Path;
use std::time::Instant;

/// Parameters of the hierarchy.
#[derive(Clone, Debug)]
pub struct LodOptions {
    /// `build`'s options (sizes, ratio, budget, simplifier).
    pub params: BuildParams,
    /// Eigenvalue cut-off of the representatives' solve.
    pub rel_tol: f64,
    pub quiet: bool,
}

impl Default for LodOptions {
    fn default() -> Self {
        LodOptions { params: BuildParams::default(), rel_tol: 1e-3, quiet: true }
    }
}

/// Per leaf of a level's tiling: what its triangles add up to.
#[derive(Clone, Debug)]
pub struct LeafStats {
    pub tris: u64,
    pub bounds: Aabb,
    /// Largest distance per axis from the point a triangle's leaf was
    /// chosen by (its centroid; level 0: its first corner) to its corners.
    pub reach: f64,
}

impl LeafStats {
    /// Counts a triangle (corners `c`; `chosen_by`: the point its leaf was chosen by).
    #[inline]
    pub fn add_triangle(&mut self, c: [[f64; 3]; 3], chosen_by: [f64; 3]) {
        self.tris += 1;
        for p in c {
            self.bounds.add(p);
            for a in 0..3 {
                self.reach = self.reach.max((p[a] - chosen_by[a]).abs());
            }
        }
    }
}

impl Default for LeafStats {
    fn default() -> Self {
        LeafStats { tris: 0, bounds: Aabb::EMPTY, reach: 0.0 }
    }
}

/// What the builder gives the store.
pub struct Built {
    pub header: StoreHeader,
    pub nodes: Vec<NodeRec>,
    pub children: Vec<u32>,
    pub parents: Vec<u32>,
    pub levels: Vec<LevelReport>,
    pub octree: OctreeReport,
}

/// Most levels built: halving from 2^40 triangles takes 30. A build that
/// would need more (a `--level-ratio` near 1) is an error naming it, up
/// front when the ratio alone says so (`check_level_count`), else when
/// the level is reached.
pub const MAX_LEVELS: u8 = 64;

/// Depth of the centroid histograms that predict the next level's cells
/// (1024 cells per axis; coarsened when they outgrow their memory share).
const HIST_DEPTH: u8 = 10;

/// Nodes per level whose split curves choose the level's threshold.
const SAMPLED_NODES: usize = 32;

impl LodOptions {
    /// The level-0 partition's options.
    pub fn octree(&self) -> OctreeOptions {
        OctreeOptions { leaf_tris: self.params.leaf_tris, max_depth: self.params.max_depth, mem: self.params.mem, quiet: self.quiet }
    }
}

/// Where level 0 comes from.
pub enum Level0Source<'a> {
    /// A soup file, partitioned here; with level 0's first counting pass
    /// when it was done as the soup was made.
    Soup(&'a Path, Option<FirstCount>),
    /// Partitioned as the soup stage placed the triangles (no soup file).
    Routed(Level0),
}

/// Checks the hierarchy's parameters (the CLI calls it before any work):
/// `--level-ratio` a finite number above 1, `--root-tris` at least 1,
/// `--max-depth` within 1..=21.
pub fn check_params(p: &BuildParams) -> Result<()> {
    if !(p.level_ratio > 1.0 && p.level_ratio.is_finite()) {
        return Err(Error::Usage(format!("--level-ratio must be a number above 1, not {}", p.level_ratio)));
    }
    if p.root_tris == 0 {
        return Err(Error::Usage("--root-tris must be at least 1".into()));
    }
    if !(1..=partition::KEY_DEPTH).contains(&p.max_depth) {
        return Err(Error::Usage(format!("--max-depth must be within 1..={}, not {}", partition::KEY_DEPTH, p.max_depth)));
    }
    Ok(())
}

/// Fewest levels above level 0 that `triangles` need to reach a root of at
/// most `--root-tris` at `--level-ratio` (each level at best 1/ratio of the
/// one below); an error naming `--level-ratio` when that is more than
/// [`MAX_LEVELS`] and `--levels` does not stop the build sooner.
fn check_level_count(p: &BuildParams, triangles: u64) -> Result<()> {
    if p.levels.is_some_and(|l| l <= MAX_LEVELS) || triangles <= p.root_tris {
        return Ok(());
    }
    let needed = ((triangles as f64 / p.root_tris as f64).ln() / p.level_ratio.ln()).ceil();
    if needed > MAX_LEVELS as f64 {
        return Err(Error::Usage(format!(
            "--level-ratio {} would take at least {needed} levels to bring {triangles} triangles down to a root of --root-tris {}, \
             more than the {MAX_LEVELS} levels a store holds: raise --level-ratio (2 halves each level) or --root-tris, or stop at --levels L",
            p.level_ratio, p.root_tris
        )));
    }
    Ok(())
}

/// Builds every level from `input` into store directory `dir`.
pub fn build(input: Level0Source, dir: &Path, opts: &LodOptions) -> Result<Built> {
    check_params(&opts.params)?;
    let scratch = crate::io::scratch_dir(dir)?;
    let l0 = match input {
        Level0Source::Soup(soup, first) => {
            let bbox = crate::soup::format::SoupReader::open(soup)?.header.bbox;
            build_octree(soup, scratch.path().join("chunks-0.bin"), &LevelCube::for_level(&bbox, 0), &opts.octree(), first)?
        }
        Level0Source::Routed(l0) => l0,
    };
    let sh = l0.header;
    check_level_count(&opts.params, sh.triangles)?;
    let attrs = sh.attrs;
    let bbox = sh.bbox;
    let layout = VertexLayout::new(attrs);
    let derived = !attrs.normal();
    let payload_layout = VertexLayout::new(attrs.with(AttrSet::NORMAL, true));
    let dim = attrs.quadric_dim();
    // Gathered vertices are welded by their bytes; with no attribute those
    // are the position's, so each vertex is a position of its own.
    let unique_positions = dim == 3;
    // Edge collapse measures each level against the level below, so carried
    // quadrics would go unused: its chunks carry none.
    let a_len = match opts.params.simplifier {
        Simplifier::Cluster => crate::quadric::carry_len(dim),
        Simplifier::Collapse => 0,
    };
    let hist_cap = (opts.params.mem / 256).max(1 << 16) as usize;
    let cube = |l: u32| LevelCube::for_level(&bbox, l);
    let octree = l0.report.clone();
    let mut tiling = l0.tiling;
    let mut leaves = l0.leaves;
    let mut chunks = l0.chunks;

    let mut nodes: Vec<NodeRec> = Vec::new();
    let mut node_children: Vec<Vec<u32>> = Vec::new();
    // Per node: measured simplification error.
    let mut simp_err: Vec<f64> = Vec::new();
    let mut reports = Vec::new();
    let mut leaf_scale = 1u64;
    let threads = rayon::current_num_threads().max(1);
    let batch = threads * 4;

    for level in 0..=MAX_LEVELS {
        let t0 = Instant::now();
        let lc = cube(level as u32);
        let nc = cube(level as u32 + 1);
        let ids: Vec<usize> = (0..tiling.leaves.len()).filter(|&i| leaves[i].tris > 0 || !chunks.refs_of(i).is_empty()).collect();
        let base = nodes.len();
        let total: u64 = ids.iter().map(|&i| leaves[i].tris).sum();
        let is_final = (ids.len() == 1 && total <= opts.params.root_tris) || opts.params.levels == Some(level);
        if level == MAX_LEVELS && !is_final {
            // Once a silent stop: a top level of many nodes, no single root.
            return Err(Error::Usage(format!(
                "the levels did not come down to one node of at most --root-tris {} triangles within {MAX_LEVELS} levels \
                 (level {level} holds {total} triangles in {} nodes; --level-ratio {}): raise --level-ratio or --root-tris, or stop at --levels L",
                opts.params.root_tris,
                ids.len(),
                opts.params.level_ratio
            )));
        }
        let cell_of = |i: usize| lc.cell(tiling.leaves[i].path, tiling.leaves[i].depth);
        let band = Band::new(&ids.iter().map(|&i| (cell_of(i), leaves[i].reach)).collect::<Vec<_>>());
        let mut rep = LevelReport { level, nodes: ids.len() as u64, triangles: total, error_min: f64::INFINITY, ..Default::default() };

        // Pass 1: band positions (shared candidates, partial normals) and
        // the next level's histogram.
        let progress = Progress::items(2 * ids.len() as u64, &format!("level {level}"), opts.quiet);
        let mut sorter = SharedSort::new((opts.params.mem / 4) as usize, scratch.path());
        let mut hist = Histogram::new(HIST_DEPTH, hist_cap);
        // The histogram's depth so far: it only coarsens (when it outgrows
        // its cells), so nodes count at it, not finer; the counts come out
        // the same, with up to 8x fewer runs for the (serial) merge.
        let hist_depth = std::sync::atomic::AtomicU8::new(hist.depth());
        let stride = (ids.len() / SAMPLED_NODES).max(1);
        let mut samples: Vec<Curve> = Vec::new();
        let mut error_samples: Vec<collapse::ErrorCurve> = Vec::new();
        let mut positions_total = 0u64;
        ordered(
            ids.len(),
            batch,
            |_| Ok(()),
            |k, ()| {
                let leaf = ids[k];
                let g = chunks.gather_with(leaf, false)?;
                let w = Welded::new(&g.mesh, unique_positions);
                let test = band.tester(k, &leaves[leaf].bounds);
                let mut records = Vec::new();
                for (pi, p) in w.pos.iter().enumerate() {
                    if test.may_share(*p) {
                        let flags = if w.was_locked(&g, pi) { WAS_LOCKED } else { 0 };
                        records.push((*p, w.normal[pi].map(|x| x as f32), flags));
                    }
                }
                // Centroid counts at the histogram's depth, as sorted runs.
                let d = hist_depth.load(std::sync::atomic::Ordering::Relaxed);
                let h = if is_final { Vec::new() } else { nc.cell_counts(d, g.mesh.triangles.iter().map(|t| tri_centroid(&g.mesh, t))) };
                Ok(Pass1 { records, hist: h, hist_depth: d, positions: w.pos.len() as u64 })
            },
            |k, r: Pass1| {
                let node = (base + k) as u32;
                for (p, n, f) in r.records {
                    sorter.push(node, p, n, f)?;
                }
                hist.add_runs(r.hist_depth, &r.hist);
                hist_depth.store(hist.depth(), std::sync::atomic::Ordering::Relaxed);
                positions_total += r.positions;
                progress.inc(1);
                Ok(())
            },
        )?;
        let (mut resolved, sstats) = sorter.resolve((opts.params.mem / 4) as usize, scratch.path(), scratch.path().join("shared.bin"))?;

        // Error curves of a sample of nodes (edge collapse), with their exact locks.
        if !is_final && opts.params.simplifier == Simplifier::Collapse {
            let picked: Vec<usize> = (0..ids.len()).filter(|k| k % stride == 0).collect();
            let mut reader = resolved.reopen()?;
            let sets = picked.iter().map(|&k| reader.take((base + k) as u32)).collect::<Result<Vec<_>>>()?;
            let curves: Vec<Result<collapse::ErrorCurve>> = picked
                .par_iter()
                .zip(sets.par_iter())
                .map(|(&k, set)| {
                    let g = chunks.gather(ids[k])?;
                    let w = Welded::new(&g.mesh, unique_positions);
                    Ok(collapse::ErrorCurve::of(&g.mesh, &w.locks(set), attrs))
                })
                .collect();
            for c in curves {
                error_samples.push(c?);
            }
        }
        // Split curves of a sample of nodes, with their exact locks.
        if !is_final && opts.params.simplifier == Simplifier::Cluster {
            let picked: Vec<usize> = (0..ids.len()).filter(|k| k % stride == 0).collect();
            let mut reader = resolved.reopen()?;
            let sets = picked.iter().map(|&k| reader.take((base + k) as u32)).collect::<Result<Vec<_>>>()?;
            let curves: Vec<Result<Curve>> = picked
                .par_iter()
                .zip(sets.par_iter())
                .map(|(&k, set)| {
                    let g = chunks.gather(ids[k])?;
                    let w = Welded::new(&g.mesh, unique_positions);
                    let locked = w.locks(set);
                    let a = (level > 0).then_some(&g.a[..]);
                    let sp = Splits::new(&g.mesh, a, &locked, attrs, usize::MAX, 0.0);
                    Ok(Curve::of(&sp, g.mesh.triangles.len()))
                })
                .collect();
            for c in curves {
                samples.push(c?);
            }
        }

        // The level's threshold and the next level's leaves.
        let (tau, predicted) = match opts.params.simplifier {
            _ if is_final => (0.0, 1.0),
            Simplifier::Cluster => choose_tau(&samples, 1.0 / opts.params.level_ratio),
            Simplifier::Collapse => collapse::choose_limit(&error_samples, 1.0 / opts.params.level_ratio),
        };
        let next_tiling = if is_final {
            Tiling::default()
        } else {
            let leaf = opts.params.leaf_tris.saturating_mul(leaf_scale);
            // One node when everything fits one leaf (the cut's root).
            Tiling::from_histogram(&hist, predicted, leaf, opts.params.max_depth)
        };
        let mut next_leaves = vec![LeafStats::default(); next_tiling.leaves.len()];
        let mut next_chunks = if is_final { None } else { Some(ChunkFile::create(scratch.path().join(format!("chunks-{}.bin", level + 1)), layout, a_len)?) };
        rep.tau = tau;

        // Pass 2: final normals and payloads, simplification, routing.
        let mut pack = PackWriter::create(dir, level as usize)?;
        let mut shared_occurrences = 0u64;
        let mut seam_only = 0u64;
        let mut prev_freed = 0u64;
        let mut next_total = 0u64;
        let mut far_nodes: Vec<FarNode> = Vec::new();
        let encoder = next_chunks.as_ref().map(ChunkFile::encoder);
        ordered(
            ids.len(),
            batch,
            |k| resolved.take((base + k) as u32),
            |k, set| {
                let (leaf, id, set) = (ids[k], base + k, &set);
                let mut g = chunks.gather(leaf)?;
                let w = Welded::new(&g.mesh, unique_positions);
                let mut p2 = Pass2::default();
                // Each position's shared record, looked up once.
                let hits: Vec<Option<&([f32; 3], u32)>> = w.pos.iter().map(|p| set.get(&pos_bits(*p))).collect();
                // Locks: shared positions and attribute seams.
                let locked = w.locks_at(|pi| hits[pi].is_some());
                for (pi, hit) in hits.iter().enumerate() {
                    let sh = hit.is_some();
                    p2.shared += sh as u64;
                    p2.seam_only += (w.seam[pi] && !sh) as u64;
                    p2.prev_freed += (w.was_locked(&g, pi) && !sh) as u64;
                }
                // The stored mesh, with normals from the whole neighbourhood.
                // Set in place: without input normals they are in neither
                // the quadrics nor the next level's chunks, and the
                // simplified mesh's are reset as it is stored (`as_stored`).
                if derived {
                    for (v, x) in g.mesh.vertices.iter_mut().enumerate() {
                        let pi = w.pos_of[v] as usize;
                        let n = match hits[pi] {
                            Some((n, _)) => n.map(|c| c as f64),
                            None => w.normal[pi],
                        };
                        x.normal = unit(n);
                    }
                }
                let patches: Vec<(u32, u32)> = if level == 0 { vec![(NO_NODE, g.mesh.triangles.len() as u32)] } else { g.patches.clone() };
                encode_payload(if derived { &payload_layout } else { &layout }, &g.mesh, &patches, &mut p2.payload);
                p2.content = w.bounds;
                p2.tris = g.mesh.triangles.len() as u32;
                p2.verts = g.mesh.vertices.len() as u32;
                p2.children = if level == 0 { Vec::new() } else { g.patches.iter().map(|p| p.0).collect() };
                if !is_final {
                    // Positions as stored, so errors and welding see the same bits.
                    let as_stored = |m: &mut IndexedMesh| {
                        let mut vb = vec![0u8; layout.size];
                        for v in m.vertices.iter_mut() {
                            layout.encode(v, &mut vb);
                            *v = layout.decode(&vb);
                        }
                    };
                    // The simplified mesh, its carried quadrics and which
                    // of its vertices were locked.
                    let (out, qa, out_locked) = match opts.params.simplifier {
                        Simplifier::Cluster => {
                            let a = (level > 0).then_some(&g.a[..]);
                            let sp = Splits::to_threshold(&g.mesh, a, &locked, attrs, tau);
                            let mut no = sp.build(sp.steps(), opts.rel_tol);
                            p2.clamped = no.stats.clamped;
                            as_stored(&mut no.mesh);
                            p2.set_error(node_error(&g.mesh, &no));
                            let out_locked: Vec<bool> = no.kept_from.iter().map(|&k| k != u32::MAX).collect();
                            (no.mesh, no.a, out_locked)
                        }
                        Simplifier::Collapse => {
                            // Down to the level's error limit (τ).
                            let c = collapse::collapse(&g.mesh, &locked, attrs, 0, Some(tau));
                            let (mut out, from) = collapse::compact(&c.vertices, &collapse::unfold(&c.vertices, &c.triangles));
                            as_stored(&mut out);
                            p2.set_error(collapse::collapse_error(&g.mesh, &locked, &out, &from));
                            let out_locked: Vec<bool> = from.iter().map(|&f| locked[f as usize]).collect();
                            (out, Vec::new(), out_locked)
                        }
                    };
                    let out = &out;
                    let mut last = 0;
                    let leaf_of: Vec<u32> = out.triangles.iter().map(|t| next_tiling.locate_near(nc.key(tri_centroid(out, t)), &mut last) as u32).collect();
                    p2.simp_tris = out.triangles.len() as u32;
                    let file = encoder.as_ref().expect("a next level");
                    let mut routed = split_by_target(out, &qa, a_len, &out_locked, &leaf_of);
                    if routed.is_empty() {
                        // Everything collapsed: still give the node a parent.
                        let c = w.bounds.center();
                        routed.push((next_tiling.locate(nc.key(c)) as u32, IndexedMesh::default(), Vec::new(), Vec::new()));
                    }
                    p2.routed = routed
                        .into_iter()
                        .map(|(target, m, a, l)| {
                            let mut bytes = Vec::new();
                            file.encode(target, id as u32, &m, &a, &l, &mut bytes);
                            (target, bytes, leaf_stats(&m))
                        })
                        .collect();
                }
                Ok(p2)
            },
            |k, r: Pass2| {
                let leaf = ids[k];
                let (offset, bytes) = pack.append(&r.payload)?;
                let mut bounds = r.content;
                // Each child's distance to the input plus how far its
                // simplification moved it (step 5 of the module doc), at
                // most the input's extent.
                let mut error = 0.0f64;
                for &c in &r.children {
                    bounds.merge(&nodes[c as usize].bounds);
                    error = error.max(nodes[c as usize].error as f64 + simp_err[c as usize]);
                }
                let error32 = next_up_f32(error.min(bbox.diagonal()));
                rep.error_min = rep.error_min.min(error32 as f64);
                rep.error_max = rep.error_max.max(error32 as f64);
                rep.bytes += bytes as u64;
                rep.clamped += r.clamped;
                nodes.push(NodeRec {
                    level,
                    cell: cell_of(leaf),
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
                });
                node_children.push(r.children);
                simp_err.push(r.error);
                if !r.far.is_empty() || !r.far_reps.is_empty() {
                    far_nodes.push(FarNode { node: nodes.len() - 1 - base, base: r.base, far: r.far, far_reps: r.far_reps });
                }
                shared_occurrences += r.shared;
                seam_only += r.seam_only;
                prev_freed += r.prev_freed;
                if let Some(nc_file) = next_chunks.as_mut() {
                    for (target, bytes, st) in &r.routed {
                        nc_file.append(*target, bytes)?;
                        let s = &mut next_leaves[*target as usize];
                        s.tris += st.tris;
                        s.bounds.merge(&st.bounds);
                        s.reach = s.reach.max(st.reach);
                        next_total += st.tris;
                    }
                }
                progress.inc(1);
                Ok(())
            },
        )?;
        progress.finish();
        pack.finish()?;
        resolved.remove();
        rep.positions = positions_total - (shared_occurrences - sstats.shared);
        rep.set_locked(sstats.shared + seam_only, prev_freed + sstats.shared_was_locked, sstats.shared_was_locked);
        if rep.nodes == 0 {
            rep.error_min = 0.0;
        }
        rep.seconds = t0.elapsed().as_secs_f64();
        // Every node of this level simplified to nothing (a few triangles
        // left, all collapsed, as `--root-tris 1` asks): the level above
        // would be empty, so this one is the top and the root keeps its
        // triangles.
        let next_chunks = match next_chunks {
            Some(mut c) if next_total == 0 => {
                c.finish(next_tiling.leaves.len())?;
                c.remove();
                rep.tau = 0.0;
                None
            }
            c => c,
        };
        reports.push(rep);
        let old = std::mem::replace(
            &mut chunks,
            match next_chunks {
                Some(mut c) => {
                    c.finish(next_tiling.leaves.len())?;
                    c
                }
                None => {
                    chunks.remove();
                    break;
                }
            },
        );
        remeasure_far([(&chunks, &next_leaves[..]), (&old, &leaves[..])], &mut simp_err[base..], far_nodes)?;
        old.remove();
        if next_total as f64 > 0.9 * total as f64 {
            leaf_scale = leaf_scale.saturating_mul(2);
        }
        tiling = next_tiling;
        leaves = next_leaves;
    }

    // Children lists (patch order) and their inverse.
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
    crate::store::sync_packs(dir, reports.len())?;
    let header = StoreHeader {
        attrs,
        derived_normals: derived,
        levels: reports.len() as u32,
        nodes: nodes.len() as u64,
        root: nodes.len().saturating_sub(1) as u32,
        store_id: random_id(),
        bbox,
    };
    Ok(Built { header, nodes, children, parents, levels: reports, octree })
}

/// Pass-1 result of one node.
struct Pass1 {
    records: Vec<([f64; 3], [f32; 3], u32)>,
    /// (key at `hist_depth`, count), sorted.
    hist: Vec<(u64, u64)>,
    hist_depth: u8,
    positions: u64,
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
    shared: u64,
    seam_only: u64,
    prev_freed: u64,
    /// Encoded chunks for the next level: (target leaf, bytes, their stats).
    routed: Vec<(u32, Vec<u8>, LeafStats)>,
}

impl Pass2 {
    /// The node's measured error; its far points are kept only when a few
    /// of them set it (worth measuring again, [`remeasure_far`]).
    fn set_error(&mut self, ne: NodeError) {
        self.error = ne.error;
        self.base = ne.base;
        if ne.error > 2.0 * ne.base {
            self.far = ne.far;
            self.far_reps = ne.far_reps;
        }
    }
}

/// A node's vertices welded by position: per position its point, the
/// area-weighted normal of its triangles in the node, whether several
/// vertex variants sit there (an attribute seam), its bounds.
struct Welded {
    pos: Vec<[f64; 3]>,
    pos_of: Vec<u32>,
    normal: Vec<[f64; 3]>,
    seam: Vec<bool>,
    /// Vertices per position: `members[first[p]..first[p+1]]`.
    first: Vec<u32>,
    members: Vec<u32>,
    bounds: Aabb,
}

impl Welded {
    /// `unique`: no two vertices of `m` share a position (a gathered node
    /// without attributes), so none is looked up.
    fn new(m: &IndexedMesh, unique: bool) -> Welded {
        let mut pos = Vec::new();
        let mut bounds = Aabb::EMPTY;
        let pos_of: Vec<u32> = if unique {
            pos.extend(m.vertices.iter().map(|v| v.pos));
            (0..m.vertices.len() as u32).collect()
        } else {
            let mut weld = Welder::with_capacity(m.vertices.len());
            m.vertices.iter().map(|v| weld.id(v.pos, |p| pos.push(p))).collect()
        };
        let mut count = vec![0u32; pos.len() + 1];
        for &p in &pos_of {
            count[p as usize + 1] += 1;
        }
        let seam = (0..pos.len()).map(|p| count[p + 1] > 1).collect();
        for i in 0..pos.len() {
            count[i + 1] += count[i];
        }
        let mut members = vec![0u32; pos_of.len()];
        let mut next = count.clone();
        for (v, &p) in pos_of.iter().enumerate() {
            members[next[p as usize] as usize] = v as u32;
            next[p as usize] += 1;
        }
        let mut normal = vec![[0.0; 3]; pos.len()];
        for t in &m.triangles {
            let c = t.map(|v| m.vertices[v as usize].pos);
            for p in c {
                bounds.add(p);
            }
            let n = cross(sub(c[1], c[0]), sub(c[2], c[0]));
            let mut seen = [u32::MAX; 3];
            for (k, &v) in t.iter().enumerate() {
                let p = pos_of[v as usize];
                if !seen[..k].contains(&p) {
                    for a in 0..3 {
                        normal[p as usize][a] += n[a];
                    }
                }
                seen[k] = p;
            }
        }
        Welded { pos, pos_of, normal, seam, first: count, members, bounds }
    }

    /// Per vertex: locked (its position is shared, or an attribute seam).
    fn locks(&self, shared: &shared::SharedSet) -> Vec<bool> {
        self.locks_at(|p| shared.contains_key(&pos_bits(self.pos[p])))
    }

    /// [`Welded::locks`], given whether position `p` is shared.
    fn locks_at(&self, is_shared: impl Fn(usize) -> bool) -> Vec<bool> {
        let at: Vec<bool> = (0..self.pos.len()).map(|p| self.seam[p] || is_shared(p)).collect();
        self.pos_of.iter().map(|&p| at[p as usize]).collect()
    }

    fn verts_at(&self, p: usize) -> &[u32] {
        &self.members[self.first[p] as usize..self.first[p + 1] as usize]
    }

    fn was_locked(&self, g: &Gathered, p: usize) -> bool {
        !g.was_locked.is_empty() && self.verts_at(p).iter().any(|&v| g.was_locked[v as usize])
    }
}

/// Split curve of one sampled node: its triangles, and for split prefixes
/// (priority of the next split, triangles after the prefix).
struct Curve {
    tris: u64,
    prio: Vec<f64>,
    /// (steps, triangles) at sampled step counts, increasing.
    counts: Vec<(u32, f64)>,
}

impl Curve {
    fn of(sp: &Splits, tris: usize) -> Curve {
        let n = sp.steps();
        let mut steps: Vec<u32> = (0..=24).map(|j| ((n as u64 * j as u64 * j as u64) / (24 * 24)) as u32).collect();
        steps.dedup();
        let counts = steps.iter().map(|&s| (s, sp.count_at(s) as f64)).collect();
        Curve { tris: tris as u64, prio: sp.priorities().to_vec(), counts }
    }

    /// Triangles at threshold `tau`.
    fn at(&self, tau: f64) -> f64 {
        let s = self.prio.iter().position(|&p| !(p > tau)).unwrap_or(self.prio.len()) as u32;
        let k = self.counts.partition_point(|c| c.0 < s);
        if k == 0 {
            return self.counts[0].1;
        }
        if k >= self.counts.len() {
            return self.counts.last().unwrap().1;
        }
        let (a, b) = (self.counts[k - 1], self.counts[k]);
        let f = if b.0 > a.0 { (s - a.0) as f64 / (b.0 - a.0) as f64 } else { 1.0 };
        a.1 + f * (b.1 - a.1)
    }
}

/// The threshold at which the sampled nodes keep `share` of their
/// triangles, and the share they actually keep there.
fn choose_tau(samples: &[Curve], share: f64) -> (f64, f64) {
    let total: f64 = samples.iter().map(|c| c.tris as f64).sum();
    if total == 0.0 {
        return (0.0, 1.0);
    }
    let kept = |t: f64| samples.iter().map(|c| c.at(t)).sum::<f64>() / total;
    let hi0 = samples.iter().flat_map(|c| c.prio.first().copied()).fold(0.0, f64::max);
    if !(hi0 > 0.0) {
        return (0.0, kept(0.0));
    }
    let (mut lo, mut hi) = (hi0 * 1e-30, hi0 * 2.0);
    if kept(lo) <= share {
        return (0.0, kept(0.0));
    }
    for _ in 0..100 {
        let m = (lo * hi).sqrt();
        if kept(m) > share {
            lo = m;
        } else {
            hi = m;
        }
        if hi / lo < 1.0 + 1e-6 {
            break;
        }
    }
    (hi, kept(hi))
}

fn leaf_stats(m: &IndexedMesh) -> LeafStats {
    let mut s = LeafStats::default();
    for t in &m.triangles {
        s.add_triangle(t.map(|v| m.vertices[v as usize].pos), tri_centroid(m, t));
    }
    s
}

#[inline]
fn tri_centroid(m: &IndexedMesh, t: &[u32; 3]) -> [f64; 3] {
    let c = t.map(|v| m.vertices[v as usize].pos);
    [0, 1, 2].map(|k| (c[0][k] + c[1][k] + c[2][k]) / 3.0)
}

/// Triangles around each vertex: `around[first[v]..first[v + 1]]`.
pub(crate) fn vertex_triangles(nv: usize, tris: &[[u32; 3]]) -> (Vec<u32>, Vec<u32>) {
    let mut first = vec![0u32; nv + 1];
    for t in tris {
        for &v in t {
            first[v as usize + 1] += 1;
        }
    }
    for v in 0..nv {
        first[v + 1] += first[v];
    }
    let mut next = first.clone();
    let mut around = vec![0u32; first[nv] as usize];
    for (ti, t) in tris.iter().enumerate() {
        for &v in t {
            around[next[v as usize] as usize] = ti as u32;
            next[v as usize] += 1;
        }
    }
    (first, around)
}

/// The smallest f32 not below `x` (errors are stored as f32 and must stay conservative).
pub fn next_up_f32(x: f64) -> f32 {
    let f = x as f32;
    if (f as f64) < x {
        f32::from_bits(f.to_bits() + 1)
    } else {
        f
    }
}

fn random_id() -> u64 {
    use std::hash::{BuildHasher, Hasher};
    let mut h = std::collections::hash_map::RandomState::new().build_hasher();
    h.write_u128(std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_nanos()).unwrap_or(0));
    h.write_u32(std::process::id());
    h.finish()
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

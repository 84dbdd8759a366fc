//! Simplify stage: bottom-up levels of detail by generalized-quadric vertex
//! clustering that keeps every node's boundary edges.
//!
//! Takes: a store directory whose leaves hold their original triangles
//! (level 0) and the node records. Gives: one simplified mesh per node —
//! level 1 for leaves, `1 + max(child levels)` for internal nodes, up to the
//! root or `--levels` — in `level-L.pack`, with its geometric error.
//!
//! Per node ([`simplify_node`]):
//! * edges used by one triangle of the node — more precisely an odd number
//!   of them, which is the same on a manifold and stays right at
//!   non-manifold edges continuing into a neighbour — are **boundary
//!   edges** (shared with a neighbour node, real mesh borders, attribute
//!   seams); their vertices are locked and kept bit-exact;
//! * every other vertex falls in a cell of a `k×k×k` sub-grid of the node's
//!   cell (`--cluster-grid k`; k = 1 is the source design's one
//!   representative per node); each cluster's representative minimises the
//!   sum of the area-weighted generalized quadrics (Garland–Heckbert 1998)
//!   of its triangles over position + the attributes the mesh has, solved by
//!   a rank-revealing pseudo-inverse about the cluster mean and clamped into
//!   the sub-cell ([`crate::quadric`]);
//! * triangles are re-indexed and those whose corners merge are dropped;
//!   all others are kept (duplicates too), which makes the map a simplicial
//!   chain map: the output's boundary is exactly the input's boundary. In
//!   particular a boundary edge's triangle always survives (its third corner
//!   cannot map onto a locked vertex of that edge).
//!
//! A parent's input is the union of its children's simplified meshes,
//! welded on identical vertices: edges between siblings are then used twice
//! and get simplified, while the parent's outer boundary — original edges,
//! locked at every level — stays. Hence any cut of the tree, each region at
//! any level, joins without cracks.
//!
//! Error: the node's geometric error, a vertex-sampled two-sided Hausdorff
//! distance between its input and its output — input vertices to the output
//! surface (exact, through a BVH over the output), and output vertices to
//! the input surface (bounded above by each representative's distance to
//! the nearest input triangle of its own cluster, which needs no index) —
//! maxed with its children's so it never decreases towards the root — the
//! error a viewer turns into pixels (as meshoptimizer's clusterlod and
//! Nanite do). It is measured, not a strict bound: between samples and
//! across levels (a parent is measured against its children's meshes, not
//! the original) the true distance to the original can be larger; `octolod
//! metro` measures that. Vertex displacement (the bound used before) was
//! 10–60× larger, because representatives slide along the surface.

use crate::error::Result;
use crate::mesh::{Aabb, AttrSet, VertexLayout};
use crate::progress::Progress;
use crate::quadric::{AttrWeights, Quadric, QuadricSpace};
use crate::store::{encode_payload, read_slot, Cube, IndexedMesh, NodeRec, PackWriter, Slot, NO_NODE};
use rayon::prelude::*;
use std::collections::HashMap;
use std::path::Path;

#[derive(Clone, Debug)]
pub struct SimplifyOptions {
    /// Sub-grid resolution per axis inside each node's cell.
    pub cluster_grid: u32,
    /// Highest level to build (None: up to the root).
    pub levels: Option<u8>,
    /// Singular values below this fraction of the largest are dropped.
    pub rel_tol: f64,
    pub quiet: bool,
}

impl Default for SimplifyOptions {
    fn default() -> Self {
        SimplifyOptions { cluster_grid: 8, levels: None, rel_tol: 1e-3, quiet: true }
    }
}

/// What simplifying one node did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct NodeStats {
    pub boundary_edges: u64,
    pub locked: u64,
    pub clusters: u64,
    /// Representatives the solver had to pull back into their sub-cell.
    pub clamped: u64,
    /// Largest distance a vertex moved.
    pub error: f64,
}

/// Simplifies `mesh` inside `cell`; see the module doc.
pub fn simplify_node(
    mesh: &IndexedMesh,
    cell: &Aabb,
    attrs: AttrSet,
    k: u32,
    rel_tol: f64,
) -> (IndexedMesh, NodeStats) {
    let mut st = NodeStats::default();
    let nv = mesh.vertices.len();
    // Edge use counts.
    let mut edges: HashMap<(u32, u32), u32> = HashMap::with_capacity(mesh.triangles.len() * 2);
    for t in &mesh.triangles {
        for c in 0..3 {
            let (a, b) = (t[c], t[(c + 1) % 3]);
            *edges.entry((a.min(b), a.max(b))).or_insert(0) += 1;
        }
    }
    let mut locked = vec![false; nv];
    for (&(a, b), &n) in &edges {
        // The mod-2 boundary: used once on a manifold; 3, 5, ... times where
        // a non-manifold edge continues into a neighbour.
        if n % 2 == 1 {
            st.boundary_edges += 1;
            locked[a as usize] = true;
            locked[b as usize] = true;
        }
    }
    st.locked = locked.iter().filter(|&&l| l).count() as u64;

    // Clusters of the free vertices on the sub-grid.
    let k = k.max(1);
    let size = [0, 1, 2].map(|a| (cell.max[a] - cell.min[a]) / k as f64);
    let sub = |p: [f64; 3]| -> [u32; 3] {
        [0, 1, 2].map(|a| {
            let t = if size[a] > 0.0 { ((p[a] - cell.min[a]) / size[a]).floor() } else { 0.0 };
            (t.max(0.0) as u32).min(k - 1)
        })
    };
    let mut cluster_of = vec![u32::MAX; nv];
    let mut cells: HashMap<[u32; 3], u32> = HashMap::new();
    let mut cluster_cell: Vec<[u32; 3]> = Vec::new();
    let mut template: Vec<u32> = Vec::new();
    for v in 0..nv {
        if locked[v] {
            continue;
        }
        let c = sub(mesh.vertices[v].pos);
        let id = *cells.entry(c).or_insert_with(|| {
            cluster_cell.push(c);
            template.push(v as u32);
            (cluster_cell.len() - 1) as u32
        });
        cluster_of[v] = id;
    }
    st.clusters = cluster_cell.len() as u64;

    // Quadrics, in coordinates local to the cell centre.
    let origin = cell.center();
    let space = QuadricSpace::new(attrs, AttrWeights::for_extent(cell_diag(cell)), origin);
    let mut quadrics: Vec<Quadric> = (0..cluster_cell.len()).map(|_| Quadric::zero(space.dim)).collect();
    let embedded: Vec<_> = mesh.vertices.iter().map(|v| space.embed(v)).collect();
    for v in 0..nv {
        if cluster_of[v] != u32::MAX {
            quadrics[cluster_of[v] as usize].add_point(&embedded[v][..space.dim]);
        }
    }
    for t in &mesh.triangles {
        let cl = t.map(|v| cluster_of[v as usize]);
        if cl.iter().all(|&c| c == u32::MAX) {
            continue;
        }
        let q = Quadric::from_triangle(
            &space,
            &embedded[t[0] as usize][..space.dim],
            &embedded[t[1] as usize][..space.dim],
            &embedded[t[2] as usize][..space.dim],
        );
        for c in 0..3 {
            if cl[c] != u32::MAX && !cl[..c].contains(&cl[c]) {
                quadrics[cl[c] as usize].add(&q);
            }
        }
    }

    // Output vertices: locked ones as they are, then one per cluster.
    let mut out = IndexedMesh::default();
    let mut remap = vec![u32::MAX; nv];
    for v in 0..nv {
        if locked[v] {
            remap[v] = out.vertices.len() as u32;
            out.vertices.push(mesh.vertices[v]);
        }
    }
    let first_rep = out.vertices.len() as u32;
    for (c, q) in quadrics.iter().enumerate() {
        let cc = cluster_cell[c];
        let lo = [0, 1, 2].map(|a| cell.min[a] + cc[a] as f64 * size[a] - origin[a]);
        let hi = [0, 1, 2].map(|a| lo[a] + size[a]);
        let sol = q.solve(rel_tol, Some((lo, hi)));
        if sol.clamped {
            st.clamped += 1;
        }
        out.vertices.push(space.unembed(&sol.x[..space.dim], &mesh.vertices[template[c] as usize]));
    }
    for v in 0..nv {
        if cluster_of[v] != u32::MAX {
            remap[v] = first_rep + cluster_of[v];
            let (p, r) = (mesh.vertices[v].pos, out.vertices[remap[v] as usize].pos);
            let d = ((p[0] - r[0]).powi(2) + (p[1] - r[1]).powi(2) + (p[2] - r[2]).powi(2)).sqrt();
            st.error = st.error.max(d);
        }
    }
    // Every non-degenerate image is kept, duplicates included: clustering is
    // then a simplicial chain map, so the image's boundary is exactly the
    // (locked) boundary of the input — folded pairs must not be thinned out.
    for t in &mesh.triangles {
        let r = t.map(|v| remap[v as usize]);
        if r[0] != r[1] && r[1] != r[2] && r[0] != r[2] {
            out.triangles.push(r);
        }
    }
    // Output → input, bounded above without an index: each representative's
    // distance to the nearest input triangle of its own cluster.
    let stored = |p: [f64; 3]| as_stored(p, attrs.pos_f64());
    let mut rep_d2 = vec![f64::INFINITY; quadrics.len()];
    for t in &mesh.triangles {
        let c = t.map(|v| mesh.vertices[v as usize].pos);
        for &v in t {
            let cl = cluster_of[v as usize];
            if cl != u32::MAX {
                let r = stored(out.vertices[(first_rep + cl) as usize].pos);
                let q = crate::metro::closest_point_triangle(r, c[0], c[1], c[2]);
                let d2 = (0..3).map(|k| (r[k] - q[k]).powi(2)).sum::<f64>();
                rep_d2[cl as usize] = rep_d2[cl as usize].min(d2);
            }
        }
    }
    let out_to_in = rep_d2.iter().copied().filter(|d| d.is_finite()).fold(0.0, f64::max).sqrt();
    let out = compact(out);
    if let Some(d) = input_to_output(mesh, &out, attrs.pos_f64()) {
        st.error = d.max(out_to_in);
    }
    (out, st)
}

/// The input → output half of the geometric error: the largest distance
/// from the input's vertices to the output surface (exact closest points
/// through a BVH over the small output, as stored: f32 positions unless the
/// input had f64). None when either side has no triangles (the caller keeps
/// the displacement bound then).
fn input_to_output(input: &IndexedMesh, output: &IndexedMesh, f64_positions: bool) -> Option<f64> {
    use crate::metro::{Bvh, Mesh};
    if input.triangles.is_empty() || output.triangles.is_empty() {
        return None;
    }
    let a = Mesh::from_vertices(&input.vertices, input.triangles.clone());
    let b = Mesh::new(output.vertices.iter().map(|v| as_stored(v.pos, f64_positions)).collect(), output.triangles.clone());
    let tb = Bvh::new(&b);
    let d2 = a.referenced_vertices().iter().map(|&i| tb.closest(input.vertices[i as usize].pos).map_or(0.0, |c| c.dist2)).fold(0.0, f64::max);
    Some(d2.sqrt())
}

/// A position as the store keeps it: f32 unless the input had f64.
fn as_stored(p: [f64; 3], f64_positions: bool) -> [f64; 3] {
    if f64_positions {
        p
    } else {
        p.map(|x| x as f32 as f64)
    }
}

fn cell_diag(c: &Aabb) -> f64 {
    c.diagonal()
}

/// Drops unreferenced vertices.
fn compact(m: IndexedMesh) -> IndexedMesh {
    let mut map = vec![u32::MAX; m.vertices.len()];
    let mut out = IndexedMesh::default();
    for t in &m.triangles {
        let mut nt = [0u32; 3];
        for c in 0..3 {
            let v = t[c] as usize;
            if map[v] == u32::MAX {
                map[v] = out.vertices.len() as u32;
                out.vertices.push(m.vertices[v]);
            }
            nt[c] = map[v];
        }
        out.triangles.push(nt);
    }
    out
}

/// Concatenates meshes, welding bit-identical vertices (as encoded).
pub fn weld_union(layout: &VertexLayout, parts: &[IndexedMesh]) -> IndexedMesh {
    let mut out = IndexedMesh::default();
    let mut map: HashMap<Vec<u8>, u32> = HashMap::new();
    let mut buf = vec![0u8; layout.size];
    for p in parts {
        let ids: Vec<u32> = p
            .vertices
            .iter()
            .map(|v| {
                layout.encode(v, &mut buf);
                let next = out.vertices.len() as u32;
                *map.entry(buf.clone()).or_insert_with(|| {
                    out.vertices.push(*v);
                    next
                })
            })
            .collect();
        out.triangles.extend(p.triangles.iter().map(|t| t.map(|i| ids[i as usize])));
    }
    out
}

/// Figures for one built level.
#[derive(Clone, Debug, Default)]
pub struct LevelReport {
    pub level: u8,
    pub nodes: u64,
    pub triangles: u64,
    pub bytes: u64,
    pub error_min: f64,
    pub error_max: f64,
    pub clamped: u64,
    pub seconds: f64,
}

/// Assigns levels (leaf 1, parent 1 + max child) and builds every level's
/// meshes bottom-up into `dir`. Nodes are processed level by level, a few
/// per worker thread at a time, so memory in flight stays bounded.
pub fn build_levels(
    dir: &Path,
    cube: &Cube,
    attrs: AttrSet,
    nodes: &mut [NodeRec],
    opts: &SimplifyOptions,
) -> Result<Vec<LevelReport>> {
    let layout = VertexLayout::new(attrs);
    for i in (0..nodes.len()).rev() {
        let lvl = nodes[i].children.iter().filter(|&&c| c != NO_NODE).map(|&c| nodes[c as usize].level).max();
        nodes[i].level = lvl.map(|l| l + 1).unwrap_or(1);
    }
    let top = nodes.first().map(|n| n.level).unwrap_or(0);
    let top = opts.levels.map(|l| l.min(top)).unwrap_or(top);
    let total: u64 = nodes.iter().filter(|n| n.level <= top).count() as u64;
    let progress = Progress::items(total, "simplifying", opts.quiet);
    let batch = rayon::current_num_threads() * 4;
    let mut reports = Vec::new();
    for level in 1..=top {
        let t0 = std::time::Instant::now();
        let ids: Vec<usize> = (0..nodes.len()).filter(|&i| nodes[i].level == level).collect();
        let mut pack = PackWriter::create(dir, level as usize)?;
        let mut rep = LevelReport { level, error_min: f64::INFINITY, ..Default::default() };
        for chunk in ids.chunks(batch) {
            let snapshot: &[NodeRec] = nodes;
            let done: Vec<Result<(Vec<u8>, IndexedMesh, NodeStats, f64)>> = chunk
                .par_iter()
                .map(|&i| {
                    let n = &snapshot[i];
                    let (input, child_err) = if n.is_leaf() {
                        (read_slot(dir, &layout, 0, &n.orig)?, 0.0f64)
                    } else {
                        let mut parts = Vec::new();
                        let mut e = 0.0f64;
                        for &c in n.children.iter().filter(|&&c| c != NO_NODE) {
                            let cn = &snapshot[c as usize];
                            parts.push(read_slot(dir, &layout, cn.level as usize, &cn.simp)?);
                            e = e.max(cn.simp.error as f64);
                        }
                        (weld_union(&layout, &parts), e)
                    };
                    let cell = cube.cell(n.path, n.depth);
                    let (m, st) = simplify_node(&input, &cell, attrs, opts.cluster_grid, opts.rel_tol);
                    let mut payload = Vec::new();
                    encode_payload(&layout, &m, &mut payload);
                    Ok((payload, m, st, child_err))
                })
                .collect();
            for (&i, r) in chunk.iter().zip(done) {
                let (payload, m, st, child_err) = r?;
                let (offset, bytes) = pack.append(&payload)?;
                // Conservative and monotone: never below any child's error.
                let error = st.error.max(child_err);
                let error_f32 = next_up_f32(error);
                nodes[i].simp = Slot {
                    offset,
                    bytes,
                    tris: m.triangles.len() as u32,
                    verts: m.vertices.len() as u32,
                    error: error_f32,
                };
                rep.nodes += 1;
                rep.triangles += m.triangles.len() as u64;
                rep.bytes += bytes as u64;
                rep.error_min = rep.error_min.min(error);
                rep.error_max = rep.error_max.max(error);
                rep.clamped += st.clamped;
                progress.inc(1);
            }
        }
        pack.finish()?;
        rep.seconds = t0.elapsed().as_secs_f64();
        if rep.nodes == 0 {
            rep.error_min = 0.0;
        }
        reports.push(rep);
    }
    progress.finish();
    Ok(reports)
}

/// The smallest f32 not below `x` (errors are stored as f32 and must stay conservative).
fn next_up_f32(x: f64) -> f32 {
    let f = x as f32;
    if (f as f64) < x {
        f32::from_bits(f.to_bits() + 1)
    } else {
        f
    }
}

/// The nodes drawn for a whole-level view at `level`: each region at the
/// coarsest node whose level is ≤ `level` (level 0: the leaves' originals).
pub fn level_cut(nodes: &[NodeRec], level: u8) -> Vec<usize> {
    let mut out = Vec::new();
    let mut stack = vec![0usize];
    while let Some(i) = stack.pop() {
        let n = &nodes[i];
        let usable = if level == 0 { n.is_leaf() } else { n.level <= level && !n.simp.is_empty() };
        if usable || n.is_leaf() {
            out.push(i);
        } else {
            stack.extend(n.children.iter().rev().filter(|&&c| c != NO_NODE).map(|&c| c as usize));
        }
    }
    out.sort_unstable();
    out
}

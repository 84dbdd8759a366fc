//! One node's simplification: error-driven adaptive vertex clustering with
//! generalized quadrics (Garland–Heckbert 1998) that keeps locked vertices
//! bit-exact and stops at an error threshold or a triangle target.
//!
//! Takes: the node's indexed mesh, each vertex's propagated quadric matrix
//! (or none: its triangles' sum), which vertices are locked (shared with
//! another node of the level), each vertex's position id where the caller
//! welded them, the attribute set. Attribute seams are not locked: they
//! simplify along themselves, each side keeping its attributes (`Seams`). Gives: the split sequence ([`Splits`]) evaluated at any prefix —
//! by error threshold (the level builder) or by triangle target — and the
//! simplified mesh with each output vertex's quadric ([`Splits::build`]).
//!
//! Clusters: the free vertices' box is split in two, kd-tree fashion, always
//! the cluster whose quadric error at its members' mean is largest, at that
//! mean along the members' axis of largest variance. Unlike a uniform grid
//! (OOCS, meshoptimizer's `simplify_sloppy`) this spends clusters where the
//! surface curves, and binary splits keep neighbours within 2× in size
//! (octree splits: 8×). A prefix of the one sequence is chosen by threshold,
//! or by bisection for the first triangle count at or above a target. A
//! cell's split depends on its members alone, so the whole tree is made
//! first from positions, each cell's quadric is then the sum of its
//! children's, and the greedy order is replayed over the priorities
//! (`Splits::split_cells`): a member's quadric row is added about three
//! times in all instead of once per tree level, which made inputs with
//! attributes (66-value rows in R^9) cost far more than their positions
//! alone (issue 35; figures in `docs/build-costs.md`, "Attribute cost"). A
//! representative minimises its members' summed quadrics (each the quadric
//! of the input surface it stands for) inside its cluster box
//! ([`crate::quadric`]); matrices are carried in raw attribute units and
//! rescaled ([`scale_packed`]).
//!
//! Invariant: triangles whose corners merge are dropped, and so are a
//! triangle and one of opposite orientation on the same corners (a fold);
//! all others are kept. The map is then a simplicial chain map up to pairs,
//! so the output's mod-2 boundary is the image of the input's: no open edge
//! appears that the input did not have, the mesh's own open border is
//! simplified with the rest, and every triangle on an edge between two
//! locked vertices keeps that edge, which keeps a node's seams closed. Known
//! cost: a part thinner than a cluster collapses (its two sides fold and are
//! removed); the surface stays closed. Figures: `docs/levels-of-detail.md`.

use crate::mesh::IndexedMesh;
use crate::mesh::{Aabb, AttrSet, Vertex};
use crate::quadric::{carry_len, AttrWeights, Quadric, QuadricSpace, MAX_DIM};
use std::collections::BinaryHeap;
use std::sync::Arc;

/// A node's simplified mesh and where each of its vertices came from.
#[derive(Clone, Debug, Default)]
pub struct NodeOut {
    pub mesh: IndexedMesh,
    /// Carried quadric per output vertex ([`carry_len`] values about its position, raw attribute units).
    pub a: Vec<f64>,
    /// Per output vertex: the input vertex it is (kept), or `u32::MAX` for
    /// a representative.
    pub kept_from: Vec<u32>,
    /// Members (input vertices) of output vertex o:
    /// `members[members_first[o]..members_first[o + 1]]` (empty when kept).
    pub members_first: Vec<u32>,
    pub members: Vec<u32>,
    pub stats: ClusterStats,
    /// The distance its quadrics predict for the farthest representative:
    /// the largest over representatives of √(residual ÷ area), their summed
    /// quadric's error at their position over its weight (the trace of its
    /// position block). A measured error far above it is surface the
    /// quadrics did not see go (a thin part folded away, a floating piece
    /// merged into one point).
    pub predicted: f64,
    /// The same per output vertex: its representative's √(residual ÷
    /// area), 0 for a kept vertex.
    pub vertex_predicted: Vec<f64>,
    /// The input's triangles around each vertex
    /// (`vertex_triangles`) where the clustering made them (level
    /// 0's border planes): the node error's input side reuses them.
    pub in_fans: Option<Arc<(Vec<u32>, Vec<u32>)>>,
}

/// Figures of one node's clustering.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ClusterStats {
    /// Locked vertices referenced by the input.
    pub locked: u64,
    /// Clusters (representatives) in the output.
    pub clusters: u64,
    /// Representatives the solver pulled back into their box.
    pub clamped: u64,
}

/// A cluster box of the split sequence.
struct Cell {
    lo: [f64; 3],
    hi: [f64; 3],
    /// Members: `order[start..end]`.
    start: u32,
    end: u32,
    /// Split step at which the box was created (0: the root).
    created: u32,
    parent: u32,
    /// Its quadric: `cq[q * cl..(q + 1) * cl]` (a member's own row when
    /// it is one member's leaf).
    q: u32,
}

#[derive(PartialEq)]
pub(crate) struct Prio(pub f64, pub u32);
impl Eq for Prio {}
impl PartialOrd for Prio {
    fn partial_cmp(&self, o: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for Prio {
    fn cmp(&self, o: &Self) -> std::cmp::Ordering {
        self.0.total_cmp(&o.0).then(o.1.cmp(&self.1))
    }
}

/// The greedy split sequence of one node's free vertices, evaluated at any
/// prefix: by triangle target ([`Splits::steps_for_target`]) or by error
/// threshold ([`Splits::steps_for_error`]).
pub struct Splits<'a> {
    mesh: &'a IndexedMesh,
    space: QuadricSpace,
    cl: usize,
    /// Free vertex ids, and each vertex's slot in them (MAX: locked/unused).
    free: Vec<u32>,
    slot: Vec<u32>,
    cells: Vec<Cell>,
    /// Cells' quadrics ([`Cell::q`]).
    cq: Vec<f64>,
    /// Final (deepest) cell of each free vertex.
    leaf_of: Vec<u32>,
    /// Priority of split step `s` (1-based) at `prio[s - 1]`.
    prio: Vec<f64>,
    /// Each input vertex's quadric matrix (packed).
    va: Vec<f64>,
    /// Attribute seams, where the node has any.
    seams: Option<Seams>,
    /// Charts whose inner vertices may join a seam cluster: (root cell,
    /// anchor seam vertex's free index, cost, step the root is split at).
    merges: Vec<(u32, u32, f64, u32)>,
    /// The priority below which splitting stopped, and per step s the
    /// largest priority not split in a prefix of s steps (ordered splits).
    stop: f64,
    left_max: Vec<f64>,
    pub stats: ClusterStats,
    /// The mesh's triangles around each vertex, where made (level 0).
    in_fans: Option<Arc<(Vec<u32>, Vec<u32>)>>,
}

/// A node's attribute seams: positions holding several vertices (wedges:
/// one per side of a uv, normal or colour discontinuity).
///
/// Seam vertices simplify along their seams instead of being locked: they
/// are clustered among themselves (never with a chart's inner vertices, as
/// meshoptimizer collapses a seam vertex only along its seam), every cluster
/// is one position, and each of its wedges (members joined by the node's
/// edges inside the cluster) keeps its own attributes. Inner vertices are
/// clustered per chart (a connected piece of the node's index), so no
/// cluster mixes two uv islands and no priority is inflated by their
/// distance in the atlas.
struct Seams {
    /// Position id per vertex.
    pos_of: Vec<u32>,
    positions: usize,
    /// Vertex sits on a seam (its position holds another used vertex).
    seam: Vec<bool>,
}

impl Seams {
    /// The seams of `mesh` (positions `pos_of`, or welded here), or None
    /// when no position holds two used vertices.
    fn find(mesh: &IndexedMesh, pos_of: Option<&[u32]>, used: &[bool]) -> Option<Seams> {
        let pos_of: Vec<u32> = match pos_of {
            Some(p) => p.to_vec(),
            None => {
                let mut weld = crate::geom::Welder::with_capacity(mesh.vertices.len());
                mesh.vertices.iter().map(|v| weld.id(v.pos, |_| {})).collect()
            }
        };
        let positions = pos_of.iter().map(|&p| p as usize + 1).max().unwrap_or(0);
        let mut count = vec![0u8; positions];
        for (v, &p) in pos_of.iter().enumerate() {
            if used[v] {
                count[p as usize] = count[p as usize].saturating_add(1);
            }
        }
        if !count.iter().any(|&c| c > 1) {
            return None;
        }
        let seam = pos_of.iter().enumerate().map(|(v, &p)| used[v] && count[p as usize] > 1).collect();
        Some(Seams { pos_of, positions, seam })
    }
}

/// A root cell: its first and end rows and its local box.
type Root = (usize, usize, [f64; 3], [f64; 3]);

/// Union-find root with path halving.
pub(super) fn find_root(parent: &mut [u32], mut x: u32) -> u32 {
    while parent[x as usize] != x {
        parent[x as usize] = parent[parent[x as usize] as usize];
        x = parent[x as usize];
    }
    x
}

pub(super) fn union(parent: &mut [u32], a: u32, b: u32) {
    let (ra, rb) = (find_root(parent, a), find_root(parent, b));
    if ra != rb {
        parent[ra.max(rb) as usize] = ra.min(rb);
    }
}

/// Each vertex's chart: the smallest vertex of its connected piece of the
/// index (an unused vertex is its own).
pub(super) fn charts(mesh: &IndexedMesh) -> Vec<u32> {
    let mut parent: Vec<u32> = (0..mesh.vertices.len() as u32).collect();
    for t in &mesh.triangles {
        union(&mut parent, t[0], t[1]);
        union(&mut parent, t[1], t[2]);
    }
    (0..mesh.vertices.len() as u32).map(|v| find_root(&mut parent, v)).collect()
}

impl<'a> Splits<'a> {
    /// Runs the greedy splits until every cluster is exact (zero quadric
    /// error), a single point, or `max_clusters` clusters exist.
    /// `vertex_a`: each vertex's propagated quadric matrix (packed, see
    /// [`Quadric::at_point`]), or None to take the sum of its triangles'.
    /// Splitting stops at `max_clusters` clusters or when the largest
    /// priority left is ≤ `min_priority`.
    /// `pos_of`: each vertex's position id where the caller has welded
    /// them (else they are welded here when the mesh has attributes).
    pub fn new(
        mesh: &'a IndexedMesh,
        vertex_a: Option<&[f64]>,
        locked: &[bool],
        pos_of: Option<&[u32]>,
        attrs: AttrSet,
        max_clusters: usize,
        min_priority: f64,
    ) -> Splits<'a> {
        Self::grow(mesh, vertex_a, locked, pos_of, attrs, max_clusters, min_priority, true)
    }

    /// Every split whose priority is above `tau`, in no particular order:
    /// the partition is the same as the greedy sequence's prefix at `tau`
    /// (every cell above it is split, whatever the order, and its children
    /// do not depend on when), without a priority queue. Only
    /// `build(steps())` is meaningful on the result.
    pub fn to_threshold(mesh: &'a IndexedMesh, vertex_a: Option<&[f64]>, locked: &[bool], pos_of: Option<&[u32]>, attrs: AttrSet, tau: f64) -> Splits<'a> {
        Self::grow(mesh, vertex_a, locked, pos_of, attrs, usize::MAX, tau, false)
    }

    #[allow(clippy::too_many_arguments)]
    fn grow(
        mesh: &'a IndexedMesh,
        vertex_a: Option<&[f64]>,
        locked: &[bool],
        pos_of: Option<&[u32]>,
        attrs: AttrSet,
        max_clusters: usize,
        min_priority: f64,
        ordered: bool,
    ) -> Splits<'a> {
        let (mut sp, embedded, root) = Self::setup(mesh, vertex_a, locked, pos_of, attrs);
        if sp.free.is_empty() {
            return sp;
        }
        let rows = sp.member_rows(&embedded);
        let (rows, roots, root_of) = match &sp.seams {
            None => {
                let (lo, hi) = sp.space.local_bounds(&root);
                (rows, vec![(0, sp.free.len(), lo, hi)], Vec::new())
            }
            Some(_) => sp.class_roots(rows),
        };
        sp.split_cells(rows, &roots, max_clusters, min_priority, ordered);
        sp.stop = min_priority;
        if ordered {
            sp.left_max = vec![0.0; sp.prio.len() + 1];
            for k in (0..sp.prio.len()).rev() {
                sp.left_max[k] = sp.left_max[k + 1].max(sp.prio[k]);
            }
        }
        if !root_of.is_empty() {
            sp.find_merges(&embedded, &root_of);
        }
        sp
    }

    /// Charts that may join a seam cluster whole: a chart whose inner
    /// vertices form one cluster (its root cell never split) would keep
    /// one inner point and a fan of triangles to its border; joined to the
    /// seam cluster of its cheapest neighbouring seam vertex (its quadric
    /// there at most the level's threshold), the island keeps its border
    /// loop alone, as edge collapse leaves it (measured on a 1 M scan with
    /// a 16³-cell atlas: 3–7 % lower RMS at levels 6 and 7, none finer).
    /// `root_of[i]`: free vertex i's root cell (seam vertices' root first).
    fn find_merges(&mut self, embedded: &[[f64; MAX_DIM]], root_of: &[u32]) {
        let sm = self.seams.as_ref().expect("seams");
        let (dim, cl) = (self.space.dim, self.cl);
        let roots = root_of.iter().map(|&r| r as usize + 1).max().unwrap_or(0);
        let mut best: Vec<(f64, u32)> = vec![(f64::INFINITY, u32::MAX); roots];
        for t in &self.mesh.triangles {
            for k in 0..3 {
                for (x, y) in [(t[k], t[(k + 1) % 3]), (t[(k + 1) % 3], t[k])] {
                    let (fx, fy) = (self.slot[x as usize], self.slot[y as usize]);
                    if fx == u32::MAX || fy == u32::MAX || sm.seam[x as usize] || !sm.seam[y as usize] {
                        continue;
                    }
                    let r = root_of[fx as usize] as usize;
                    let at = self.cells[r].q as usize * cl;
                    let q = Quadric::from_coeffs(dim, &self.cq[at..at + cl]);
                    let cost = q.error(&embedded[y as usize]);
                    if cost < best[r].0 || (cost == best[r].0 && fy < best[r].1) {
                        best[r] = (cost, fy);
                    }
                }
            }
        }
        let mut split_at = vec![u32::MAX; roots];
        for c in &self.cells {
            if (c.parent as usize) < roots {
                split_at[c.parent as usize] = split_at[c.parent as usize].min(c.created);
            }
        }
        self.merges = (0..roots).filter(|&r| best[r].1 != u32::MAX).map(|r| (r as u32, best[r].1, best[r].0, split_at[r])).collect();
    }

    /// The threshold a prefix of `s` splits stands for.
    fn threshold_at(&self, s: u32) -> f64 {
        match self.left_max.get(s as usize) {
            Some(&m) if (s as usize) < self.prio.len() => m.max(self.stop),
            _ => self.stop,
        }
    }

    /// With seams: the rows ordered by class (seam vertices first, then
    /// each chart's inner vertices) and one root cell per class, over its
    /// members' box.
    fn class_roots(&self, rows: Rows) -> (Rows, Vec<Root>, Vec<u32>) {
        let sm = self.seams.as_ref().expect("seams");
        let nv = self.mesh.vertices.len();
        let chart = charts(self.mesh);
        let mut class_of_root = vec![u32::MAX; nv];
        let mut classes = 1u32;
        let class: Vec<u32> = self
            .free
            .iter()
            .map(|&v| {
                if sm.seam[v as usize] {
                    return 0;
                }
                let r = chart[v as usize] as usize;
                if class_of_root[r] == u32::MAX {
                    class_of_root[r] = classes;
                    classes += 1;
                }
                class_of_root[r]
            })
            .collect();
        // Counting sort of the rows by class.
        let mut first = vec![0usize; classes as usize + 1];
        for &c in &class {
            first[c as usize + 1] += 1;
        }
        for c in 0..classes as usize {
            first[c + 1] += first[c];
        }
        let mut next = first.clone();
        let nf = class.len();
        // The quadric rows stay in free order (read through `ids`).
        let mut out = Rows { q: rows.q, pts: vec![[0.0; 3]; nf], ids: vec![0; nf], cl: rows.cl };
        for i in 0..nf {
            let j = next[class[i] as usize];
            next[class[i] as usize] += 1;
            out.pts[j] = rows.pts[i];
            out.ids[j] = rows.ids[i];
        }
        let mut root_of = vec![u32::MAX; nf];
        let mut made = 0u32;
        let roots = (0..classes as usize)
            .filter(|&c| first[c + 1] > first[c])
            .map(|c| {
                // Root cells are made first, in this order: cell `made`.
                for &i in &out.ids[first[c]..first[c + 1]] {
                    root_of[i as usize] = made;
                }
                made += 1;
                let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
                for p in &out.pts[first[c]..first[c + 1]] {
                    for k in 0..3 {
                        lo[k] = lo[k].min(p[k]);
                        hi[k] = hi[k].max(p[k]);
                    }
                }
                (first[c], first[c + 1], lo, hi)
            })
            .collect();
        (out, roots, root_of)
    }

    /// The free (unlocked, used) vertices, the quadric space over their
    /// box, and every vertex's quadric (carried, or its triangles' planes
    /// plus border planes); also each vertex embedded and the free box.
    fn setup(
        mesh: &'a IndexedMesh,
        vertex_a: Option<&[f64]>,
        locked: &[bool],
        pos_of: Option<&[u32]>,
        attrs: AttrSet,
    ) -> (Splits<'a>, Vec<[f64; MAX_DIM]>, Aabb) {
        let nv = mesh.vertices.len();
        let mut stats = ClusterStats::default();
        let mut used = vec![false; nv];
        for t in &mesh.triangles {
            for &v in t {
                used[v as usize] = true;
            }
        }
        let seams = if attrs.quadric_dim() > 3 { Seams::find(mesh, pos_of, &used) } else { None };
        // A position is locked whole: every wedge with the one locked.
        let lock_all: Vec<bool>;
        let locked = match &seams {
            Some(sm) => {
                let mut at = vec![false; sm.positions];
                for (v, &p) in sm.pos_of.iter().enumerate() {
                    at[p as usize] |= locked[v];
                }
                lock_all = sm.pos_of.iter().map(|&p| at[p as usize]).collect();
                &lock_all[..]
            }
            None => locked,
        };
        stats.locked = (0..nv).filter(|&v| used[v] && locked[v]).count() as u64;
        let free: Vec<u32> = (0..nv as u32).filter(|&v| used[v as usize] && !locked[v as usize]).collect();
        let mut root = Aabb::EMPTY;
        for &v in &free {
            root.add(mesh.vertices[v as usize].pos);
        }
        let space = QuadricSpace::new(attrs, AttrWeights::for_extent(root.diagonal()), if root.is_empty() { [0.0; 3] } else { root.center() });
        let dim = space.dim;
        let cl = Quadric::coeff_len(dim);
        let mut slot = vec![u32::MAX; nv];
        for (i, &v) in free.iter().enumerate() {
            slot[v as usize] = i as u32;
        }
        let mut sp = Splits {
            mesh,
            space,
            cl,
            free,
            slot,
            cells: Vec::new(),
            cq: Vec::new(),
            leaf_of: Vec::new(),
            prio: Vec::new(),
            va: Vec::new(),
            seams,
            merges: Vec::new(),
            stop: 0.0,
            left_max: Vec::new(),
            stats,
            in_fans: None,
        };
        // Per vertex: its quadric matrix (propagated, or its triangles' sum).
        let embedded: Vec<[f64; MAX_DIM]> = mesh.vertices.iter().map(|v| sp.space.embed(v)).collect();
        let al = dim * (dim + 1) / 2;
        let cs = carry_len(dim);
        sp.va = match vertex_a {
            Some(a) => {
                // Carried in raw attribute units; this node weighs attributes
                // by its size: copied and rescaled in one pass.
                let f = carried_factors(dim, &attr_scale(&sp.space, false));
                let mut va = Vec::with_capacity(nv * cs);
                for v in a[..nv * cs].chunks_exact(cs) {
                    extend_scaled(&mut va, v, &f);
                }
                va
            }
            None => {
                // The input's planes pass through their corners: g = 0, e = 0,
                // so each triangle's matrix goes straight into its corners'
                // rows ([`crate::quadric::triangle_matrix`]).
                let mut va = vec![0.0f64; nv * cs];
                let mut m = [0.0; crate::quadric::MAX_COEFFS];
                for t in &mesh.triangles {
                    if crate::quadric::triangle_matrix(dim, &embedded[t[0] as usize], &embedded[t[1] as usize], &embedded[t[2] as usize], &mut m) {
                        for &v in t {
                            add(&mut va[v as usize * cs..v as usize * cs + al], &m[..al]);
                        }
                    }
                }
                let fans = super::vertex_triangles(nv, &mesh.triangles);
                add_border_planes(mesh, &fans, locked, sp.seams.as_ref().map(|s| &s.seam[..]), dim, cs, &mut va);
                sp.in_fans = Some(Arc::new(fans));
                va
            }
        };
        (sp, embedded, root)
    }

    /// Each free vertex's row: its quadric about its own position, in
    /// packed form, its local position and its free index.
    fn member_rows(&self, embedded: &[[f64; MAX_DIM]]) -> Rows {
        let (sp, mesh, cl) = (self, self.mesh, self.cl);
        let nf = sp.free.len();
        // Each row made on the stack and appended: the table is written
        // once, not zeroed first. Room for the split tree's sums after the
        // rows (at most one per member, [`Splits::split_cells`]).
        let mut vq = Vec::with_capacity(2 * nf * cl);
        let mut row = [0.0f64; crate::quadric::MAX_COEFFS];
        for &v in &sp.free {
            // A seam vertex's attributes are its wedge's own: only its
            // position error drives the seam's clusters.
            let seam = sp.seams.as_ref().is_some_and(|sm| sm.seam[v as usize]);
            sp.row_into(v, &embedded[v as usize], seam, &mut row[..cl]);
            vq.extend_from_slice(&row[..cl]);
        }
        // Members' rows (quadric, local position, free index) are kept in
        // cell order, each cell's members contiguous: a split reads and
        // swaps them in two sequential sweeps instead of gathering them
        // through an index (which cost a cache miss per member and level).
        Rows { q: vq, pts: sp.free.iter().map(|&v| sp.space.to_local(mesh.vertices[v as usize].pos)).collect(), ids: (0..nf as u32).collect(), cl }
    }

    /// The splits themselves: from one cell over the free box, the cell of
    /// largest priority is split at its members' mean along their axis of
    /// largest variance until `max_clusters` or `min_priority` (in priority
    /// order when `ordered`, else every cell above `min_priority`); then
    /// each member's deepest cell.
    /// `roots`: (first row, end row, local box) of each root cell.
    ///
    /// How: a cell's split (its mean, axis and two halves) depends on its
    /// members alone, never on when it is split, so the whole tree is made
    /// first from positions (`Tree::grow`: a member's 3 coordinates and id
    /// move per level, not its quadric row), each tree cell's quadric is
    /// then the sum of its two children's (its members' rows at a leaf:
    /// every sum still direct, no difference with a parent's), and the
    /// greedy sequence is last replayed over those priorities. Summing each
    /// member's row once per level it passes (as the splits were made) cost
    /// a row addition per member and level: 13 % of an attribute build's
    /// instructions (66-value rows in R^9), now about three row additions
    /// per member in all.
    fn split_cells(&mut self, mut rows: Rows, roots: &[Root], max_clusters: usize, min_priority: f64, ordered: bool) {
        let sp = self;
        let (cl, dim, nf) = (sp.cl, sp.space.dim, sp.free.len());
        let tree = Tree::grow(&mut rows, roots);
        // The error at the members' mean: measured better than the error
        // at the optimum on the scans and terrains tried (it also favours
        // compact clusters).
        let prio = |q: &[f64]| -> f64 { crate::quadric::packed_error_at_mean(dim, q) };
        // Quadrics bottom-up (children are made after their parent: in
        // reverse, a cell's children are summed before it), appended to
        // the members' rows in that order: tree cell t's quadric is row
        // `q_at[t]`. A one-member leaf's is its member's own row, not a
        // copy (half the tree's cells: 91 values each at dimension 11).
        let nt = tree.nodes.len();
        sp.cq = std::mem::take(&mut rows.q);
        let mut q_at = vec![0u32; nt];
        // Row lengths of every dimension a mesh can have: 3, 5, 6
        // (positions; +uv; +normal or colour), 8, 9 and 11 (+two or three
        // of them), so the sums unroll.
        const CL3: usize = Quadric::coeff_len(3);
        const CL5: usize = Quadric::coeff_len(5);
        const CL6: usize = Quadric::coeff_len(6);
        const CL8: usize = Quadric::coeff_len(8);
        const CL9: usize = Quadric::coeff_len(9);
        const CL11: usize = Quadric::coeff_len(11);
        for t in (0..nt).rev() {
            let at = sp.cq.len();
            let n = &tree.nodes[t];
            match n.child {
                u32::MAX if n.end - n.start == 1 => {
                    q_at[t] = rows.ids[n.start as usize];
                    continue;
                }
                u32::MAX => {
                    let ids = &rows.ids[n.start as usize..n.end as usize];
                    match cl {
                        CL3 => sum_rows::<CL3>(&mut sp.cq, ids, cl),
                        CL5 => sum_rows::<CL5>(&mut sp.cq, ids, cl),
                        CL6 => sum_rows::<CL6>(&mut sp.cq, ids, cl),
                        CL8 => sum_rows::<CL8>(&mut sp.cq, ids, cl),
                        CL9 => sum_rows::<CL9>(&mut sp.cq, ids, cl),
                        CL11 => sum_rows::<CL11>(&mut sp.cq, ids, cl),
                        _ => sum_rows::<0>(&mut sp.cq, ids, cl),
                    }
                }
                c => {
                    // The children's sum written into a zeroed row (not a
                    // copy of one child, then read again and added to): the
                    // same bits, one read of the new row fewer.
                    let (a, b) = (q_at[c as usize] as usize * cl, q_at[c as usize + 1] as usize * cl);
                    sum_two(&mut sp.cq, a, b, cl);
                }
            }
            q_at[t] = (at / cl) as u32;
        }
        // A cell's priority is taken when it is made: the cells below an
        // unsplit one (about half the tree at a level's threshold) never
        // need theirs.
        let prio_of = |cq: &[f64], t: usize| prio(&cq[q_at[t] as usize * cl..(q_at[t] as usize + 1) * cl]);
        // The greedy sequence over the tree: cells are numbered as they
        // are made (roots first, then each split's low and high child).
        let mut node_of: Vec<u32> = Vec::with_capacity(nt);
        let mut split = Vec::with_capacity(nt);
        sp.cells.reserve(nt);
        let mut heap = if ordered { Queue::Heap(BinaryHeap::new()) } else { Queue::Stack(Vec::new()) };
        for (r, &(start, end, rlo, rhi)) in roots.iter().enumerate() {
            let c = sp.cells.len();
            sp.cells.push(Cell { lo: rlo, hi: rhi, start: start as u32, end: end as u32, created: 0, parent: u32::MAX, q: q_at[r] });
            node_of.push(r as u32);
            split.push(false);
            heap.push(Prio(prio_of(&sp.cq, r), c as u32));
        }
        let mut clusters = roots.len();
        while clusters < max_clusters {
            let Some(Prio(p, c)) = heap.pop() else { break };
            if !(p > 0.0) || p <= min_priority {
                // Exact (flat, single points) or good enough; in priority
                // order, so is everything left.
                if ordered {
                    break;
                }
                continue;
            }
            let n = &tree.nodes[node_of[c as usize] as usize];
            if n.child == u32::MAX {
                // One member, or all on one side of their mean: the box
                // shrinks to the members' (no new cluster).
                if let Some((blo, bhi)) = n.shrunk {
                    let cell = &mut sp.cells[c as usize];
                    cell.lo = blo;
                    cell.hi = bhi;
                }
                continue;
            }
            sp.prio.push(p);
            let step = sp.prio.len() as u32;
            split[c as usize] = true;
            clusters -= 1;
            let id = sp.cells.len() as u32;
            let (lo, hi) = (sp.cells[c as usize].lo, sp.cells[c as usize].hi);
            for o in 0..2 {
                let t = n.child as usize + o;
                let (mut clo, mut chi) = (lo, hi);
                if o == 1 {
                    clo[n.axis as usize] = n.mid;
                } else {
                    chi[n.axis as usize] = n.mid;
                }
                let k = &tree.nodes[t];
                sp.cells.push(Cell { lo: clo, hi: chi, start: k.start, end: k.end, created: step, parent: c, q: q_at[t] });
                node_of.push(t as u32);
                split.push(false);
                heap.push(Prio(prio_of(&sp.cq, t), id + o as u32));
                clusters += 1;
            }
        }
        // Each member's deepest cell: the unsplit cell holding its row.
        sp.leaf_of = vec![0u32; nf];
        for (c, cell) in sp.cells.iter().enumerate() {
            if !split[c] {
                for &i in &rows.ids[cell.start as usize..cell.end as usize] {
                    sp.leaf_of[i as usize] = c as u32;
                }
            }
        }
    }

    /// Priority of each split step, in order.
    pub fn priorities(&self) -> &[f64] {
        &self.prio
    }

    /// Split steps run.
    pub fn steps(&self) -> u32 {
        self.prio.len() as u32
    }

    /// The prefix of splits whose priority is above `tau` (the greedy order
    /// is by priority, so this is an error threshold).
    pub fn steps_for_error(&self, tau: f64) -> u32 {
        self.prio.iter().position(|&p| !(p > tau)).unwrap_or(self.prio.len()) as u32
    }

    /// Cluster of each free vertex after `s` splits.
    fn assign(&self, s: u32) -> Vec<u32> {
        let mut a: Vec<u32> = (0..self.free.len())
            .map(|i| {
                let mut c = self.leaf_of[i];
                while self.cells[c as usize].created > s {
                    c = self.cells[c as usize].parent;
                }
                c
            })
            .collect();
        // Unsplit charts joining a seam cluster ([`Splits::find_merges`]).
        let t = self.threshold_at(s);
        let mut to = Vec::new();
        for &(root, anchor, cost, split_at) in &self.merges {
            if split_at > s && cost <= t {
                if to.is_empty() {
                    to = vec![u32::MAX; self.cells.len()];
                }
                to[root as usize] = a[anchor as usize];
            }
        }
        if !to.is_empty() {
            for c in a.iter_mut() {
                if to[*c as usize] != u32::MAX {
                    *c = to[*c as usize];
                }
            }
        }
        a
    }

    /// Per free vertex its wedge (a union-find root among free indices:
    /// members of one cluster joined by the node's edges inside it), and
    /// per cell whether it takes the wedge solve (it holds seam vertices or
    /// several wedges).
    fn wedges(&self, a: &[u32], sm: &Seams) -> (Vec<u32>, Vec<bool>) {
        let nf = self.free.len();
        let mut parent: Vec<u32> = (0..nf as u32).collect();
        for t in &self.mesh.triangles {
            for k in 0..3 {
                let (x, y) = (self.slot[t[k] as usize], self.slot[t[(k + 1) % 3] as usize]);
                if x != u32::MAX && y != u32::MAX && a[x as usize] == a[y as usize] {
                    union(&mut parent, x, y);
                }
            }
        }
        let root: Vec<u32> = (0..nf as u32).map(|i| find_root(&mut parent, i)).collect();
        let mut first = vec![u32::MAX; self.cells.len()];
        let mut multi = vec![false; self.cells.len()];
        for i in 0..nf {
            let c = a[i] as usize;
            multi[c] |= sm.seam[self.free[i] as usize];
            if first[c] == u32::MAX {
                first[c] = root[i];
            } else if first[c] != root[i] {
                multi[c] = true;
            }
        }
        (root, multi)
    }

    /// Output triangles after `s` splits.
    pub fn count_at(&self, s: u32) -> usize {
        if self.free.is_empty() {
            return self.mesh.triangles.len();
        }
        let a = self.assign(s);
        let point = self.landing(&a);
        self.mesh
            .triangles
            .iter()
            .filter(|t| {
                let r = t.map(&point);
                r[0] != r[1] && r[1] != r[2] && r[0] != r[2]
            })
            .count()
    }

    /// The point each vertex lands on under assignment `a` (as `compact`
    /// compares them): a kept vertex's own (its position where seams are
    /// welded), else its cluster's, numbered after the vertices.
    fn landing<'s>(&'s self, a: &'s [u32]) -> impl Fn(u32) -> usize + 's {
        let nv = self.mesh.vertices.len();
        let pos_of = self.seams.as_ref().map(|sm| &sm.pos_of[..]);
        move |v| match self.slot[v as usize] {
            u32::MAX => pos_of.map_or(v, |p| p[v as usize]) as usize,
            i => nv + a[i as usize] as usize,
        }
    }

    /// Output triangles after `s` splits as [`Splits::build`] leaves them:
    /// [`Splits::count_at`] less the folds (a triangle and one of opposite
    /// orientation on the same three output points, `unfold`) that
    /// `compact` drops. One pass over the vertices and triangles.
    pub fn built_count_at(&self, s: u32) -> usize {
        let a = if self.free.is_empty() { Vec::new() } else { self.assign(s) };
        let point = self.landing(&a);
        let images: Vec<[usize; 3]> = self.mesh.triangles.iter().map(|t| t.map(&point)).filter(|k| k[0] != k[1] && k[1] != k[2] && k[0] != k[2]).collect();
        unfold(&images).iter().filter(|&&k| k).count()
    }

    /// Output triangles after each of `steps` splits: [`Splits::count_at`]
    /// of each, from one pass over the triangles where no chart joins a
    /// seam cluster (`Splits::births`).
    pub fn counts_at(&self, steps: &[u32]) -> Vec<usize> {
        let count = self.counter();
        steps.iter().map(|&s| count(s)).collect()
    }

    /// [`Splits::count_at`] as a function of the prefix, read off the
    /// births (made once) where there are any.
    fn counter(&self) -> impl Fn(u32) -> usize + '_ {
        let births = self.births();
        move |s| match &births {
            Some(b) => b.partition_point(|&x| x <= s),
            None => self.count_at(s),
        }
    }

    /// Each triangle's birth, sorted: the fewest splits after which its
    /// corners are three distinct output vertices (`u32::MAX`: never), so
    /// that [`Splits::count_at`]`(s)` is the number of births at most `s`.
    /// Two free corners part when the cell that is their lowest common
    /// ancestor is split (its children are created at that step, and
    /// creation steps grow down the tree); a locked corner is apart from
    /// every free one, and from another locked one unless they are one
    /// position. One pass instead of one per prefix (a τ curve asks up to
    /// 25). `None` when charts join seam clusters (`merges`: the clusters
    /// then depend on the threshold too).
    fn births(&self) -> Option<Vec<u32>> {
        if !self.merges.is_empty() {
            return None;
        }
        if self.free.is_empty() {
            return Some(vec![0; self.mesh.triangles.len()]);
        }
        // The walks read parents alone: a compact table, not the cells.
        let parent: Vec<u32> = self.cells.iter().map(|c| c.parent).collect();
        let mut split_at = vec![u32::MAX; self.cells.len()];
        for c in &self.cells {
            if c.parent != u32::MAX {
                split_at[c.parent as usize] = c.created;
            }
        }
        let pos_of = self.seams.as_ref().map(|sm| &sm.pos_of[..]);
        // Cells are numbered as they are made, children after their
        // parent: walking up from the larger index meets the ancestor.
        let apart = |x: u32, y: u32| -> u32 {
            match (self.slot[x as usize], self.slot[y as usize]) {
                (u32::MAX, u32::MAX) => {
                    let key = |v: u32| pos_of.map_or(v, |p| p[v as usize]);
                    if key(x) == key(y) {
                        u32::MAX
                    } else {
                        0
                    }
                }
                (u32::MAX, _) | (_, u32::MAX) => 0,
                (i, j) => {
                    let (mut a, mut b) = (self.leaf_of[i as usize], self.leaf_of[j as usize]);
                    while a != b {
                        let up = if a > b { &mut a } else { &mut b };
                        let p = parent[*up as usize];
                        if p == u32::MAX {
                            return 0; // different roots
                        }
                        *up = p;
                    }
                    split_at[a as usize]
                }
            }
        };
        let mut b: Vec<u32> = self.mesh.triangles.iter().map(|t| apart(t[0], t[1]).max(apart(t[1], t[2])).max(apart(t[0], t[2]))).collect();
        b.sort_unstable();
        Some(b)
    }

    /// The fewest splits giving at least `target` triangles (all of them
    /// when even those give fewer), by bisection.
    pub fn steps_for_target(&self, target: usize) -> u32 {
        let n = self.steps();
        let count = self.counter();
        if count(n) <= target {
            return n;
        }
        let (mut lo, mut hi) = (0u32, n);
        while hi - lo > 1 {
            let m = lo + (hi - lo) / 2;
            if count(m) >= target {
                hi = m;
            } else {
                lo = m;
            }
        }
        if count(lo) >= target {
            lo
        } else {
            hi
        }
    }

    /// The simplified mesh after `s` splits: one representative per
    /// cluster, minimising its quadric inside its box.
    /// Also gives each output vertex's quadric matrix, where it came from
    /// and, for a representative, its members ([`NodeOut`]).
    pub fn build(&self, s: u32, rel_tol: f64) -> NodeOut {
        let mut st = self.stats;
        let nv = self.mesh.vertices.len();
        let dim = self.space.dim;
        let al = dim * (dim + 1) / 2;
        let cl = self.cl;
        let f = carried_factors(dim, &attr_scale(&self.space, true));
        let cs = carry_len(dim);
        let mut remap = vec![u32::MAX; nv];
        let mut rep_cell: Vec<u32> = Vec::new();
        let mut reps: Vec<Vertex> = Vec::new();
        let mut rep_of_free = vec![u32::MAX; self.free.len()];
        // A wedge representative's own matrix: its index in `wedge_a` (MAX:
        // its cell's).
        let mut rep_own_a: Vec<u32> = Vec::new();
        let mut wedge_a: Vec<f64> = Vec::new();
        // Per representative: half-gradient and residual of its quadric at
        // its position (the members' residuals added below).
        let mut rep_ge: Vec<f64> = Vec::new();
        // The least-squares uv of a cluster can overshoot the uvs it stands
        // for (a texture border); keep it inside the node's uv range, as
        // edge collapse does (colours are clamped by `unembed`, normals
        // renormalised).
        let uv_range = self.space.attrs.uv().then(|| {
            self.mesh
                .vertices
                .iter()
                .fold(([f32::MAX; 2], [f32::MIN; 2]), |(lo, hi), v| ([lo[0].min(v.uv[0]), lo[1].min(v.uv[1])], [hi[0].max(v.uv[0]), hi[1].max(v.uv[1])]))
        });
        if !self.free.is_empty() {
            // At most a representative per free vertex: reserved, not grown.
            let most = self.free.len();
            rep_cell.reserve(most);
            reps.reserve(most);
            rep_own_a.reserve(most);
            rep_ge.reserve(most * (dim + 1));
            let a = self.assign(s);
            let wedges = self.seams.as_ref().map(|sm| self.wedges(&a, sm));
            let mut rep_of_cell = vec![u32::MAX; self.cells.len()];
            for (i, &v) in self.free.iter().enumerate() {
                let c = a[i] as usize;
                if wedges.as_ref().is_some_and(|w| w.1[c]) {
                    continue; // below, wedge by wedge
                }
                if rep_of_cell[c] == u32::MAX {
                    rep_cell.push(c as u32);
                    let cell = &self.cells[c];
                    let k = &self.cq[cell.q as usize * cl..(cell.q as usize + 1) * cl];
                    let bounds = (cell.lo, cell.hi);
                    // Every dimension on arrays of its size
                    // (`solve_sized`); the general path where the box clamps.
                    let mut x = [0.0; MAX_DIM];
                    let mut ge = [0.0; MAX_DIM + 1];
                    let sized = match dim {
                        3 => sized_solve::<3>(k, rel_tol, bounds, &mut x, &mut ge),
                        5 => sized_solve::<5>(k, rel_tol, bounds, &mut x, &mut ge),
                        6 => sized_solve::<6>(k, rel_tol, bounds, &mut x, &mut ge),
                        8 => sized_solve::<8>(k, rel_tol, bounds, &mut x, &mut ge),
                        9 => sized_solve::<9>(k, rel_tol, bounds, &mut x, &mut ge),
                        11 => sized_solve::<11>(k, rel_tol, bounds, &mut x, &mut ge),
                        _ => false,
                    };
                    if !sized {
                        let q = Quadric::from_coeffs(dim, k);
                        let sol = q.solve(rel_tol, Some(bounds));
                        st.clamped += sol.clamped as u64;
                        x = sol.x;
                        ge[..dim].copy_from_slice(&q.half_gradient(&sol.x)[..dim]);
                        ge[dim] = sol.error;
                    }
                    rep_of_cell[c] = reps.len() as u32;
                    let mut r = self.space.unembed(&x[..dim], &self.mesh.vertices[v as usize]);
                    if let Some((lo, hi)) = uv_range {
                        r.uv = [r.uv[0].clamp(lo[0], hi[0]), r.uv[1].clamp(lo[1], hi[1])];
                    }
                    reps.push(r);
                    rep_own_a.push(u32::MAX);
                    rep_ge.extend_from_slice(&ge[..dim]);
                    rep_ge.push(ge[dim].max(0.0));
                }
                rep_ge[rep_of_cell[c] as usize * (dim + 1) + dim] += self.va[v as usize * cs + al + dim];
                remap[v as usize] = rep_of_cell[c];
                rep_of_free[i] = rep_of_cell[c];
            }
            if let Some((root, multi)) = &wedges {
                // Clusters holding seam vertices or several wedges: one
                // position for all (minimising the sum of each wedge's
                // position error with its attributes free), then each
                // wedge's attributes at that position from its own
                // members' quadrics. Sides of a seam share every position
                // (nothing tears) and keep their own attributes (no uv
                // island bleeds into another).
                let mut order: Vec<(u32, u32, u32)> = (0..self.free.len()).filter(|&i| multi[a[i] as usize]).map(|i| (a[i], root[i], i as u32)).collect();
                order.sort_unstable();
                let mut wk: Vec<f64> = Vec::new();
                let mut row = vec![0.0; cl];
                for group in order.chunk_by(|x, y| x.0 == y.0) {
                    let c = group[0].0 as usize;
                    let wedges: Vec<&[(u32, u32, u32)]> = group.chunk_by(|x, y| x.1 == y.1).collect();
                    wk.clear();
                    wk.resize(wedges.len() * cl, 0.0);
                    let mut sum = vec![0.0; cl];
                    for (w, members) in wedges.iter().enumerate() {
                        let k = &mut wk[w * cl..(w + 1) * cl];
                        for &(_, _, i) in members.iter() {
                            let v = self.free[i as usize];
                            self.row_into(v, &self.space.embed(&self.mesh.vertices[v as usize]), false, &mut row);
                            add(k, &row);
                        }
                        row.copy_from_slice(k);
                        crate::quadric::eliminate_attrs(dim, &mut row, rel_tol);
                        add(&mut sum, &row);
                    }
                    let cell = &self.cells[c];
                    let sol = Quadric::from_coeffs(dim, &sum).solve(rel_tol, Some((cell.lo, cell.hi)));
                    st.clamped += sol.clamped as u64;
                    for (w, members) in wedges.iter().enumerate() {
                        let k = &wk[w * cl..(w + 1) * cl];
                        let x = crate::quadric::attrs_at(dim, k, [sol.x[0], sol.x[1], sol.x[2]], rel_tol);
                        let q = Quadric::from_coeffs(dim, k);
                        let template = &self.mesh.vertices[self.free[members[0].2 as usize] as usize];
                        let mut r = self.space.unembed(&x[..dim], template);
                        if self.space.attrs.uv() {
                            // Inside the wedge's own uvs (its island).
                            let (mut lo, mut hi) = ([f32::MAX; 2], [f32::MIN; 2]);
                            for &(_, _, i) in members.iter() {
                                let uv = self.mesh.vertices[self.free[i as usize] as usize].uv;
                                for d in 0..2 {
                                    lo[d] = lo[d].min(uv[d]);
                                    hi[d] = hi[d].max(uv[d]);
                                }
                            }
                            r.uv = [r.uv[0].clamp(lo[0], hi[0]), r.uv[1].clamp(lo[1], hi[1])];
                        }
                        let id = reps.len() as u32;
                        reps.push(r);
                        rep_cell.push(c as u32);
                        rep_own_a.push((wedge_a.len() / al) as u32);
                        wedge_a.extend_from_slice(&k[..al]);
                        rep_ge.extend_from_slice(&q.half_gradient(&x)[..dim]);
                        let mut e = q.error(&x).max(0.0);
                        for &(_, _, i) in members.iter() {
                            let v = self.free[i as usize] as usize;
                            e += self.va[v * cs + al + dim];
                            remap[v] = id;
                            rep_of_free[i as usize] = id;
                        }
                        rep_ge.push(e);
                    }
                }
            }
        }
        st.clusters = reps.len() as u64;
        let mut predicted2 = 0.0f64;
        let mut rep_predicted2 = vec![0.0f64; reps.len()];
        for r in 0..reps.len() {
            let a = match rep_own_a[r] {
                u32::MAX => self.rep_a(rep_cell[r] as usize),
                w => &wedge_a[w as usize * al..(w as usize + 1) * al],
            };
            let area = (0..3).map(|k| a[diag_at(dim, k)]).sum::<f64>();
            let e = rep_ge[r * (dim + 1) + dim];
            if area > 0.0 && e.is_finite() {
                predicted2 = predicted2.max(e / area);
                rep_predicted2[r] = e / area;
            }
        }
        let (mesh, src) = compact(self.mesh, &remap, &reps, self.seams.as_ref().map(|sm| (sm, &rep_cell[..])));
        // Back to raw attribute units as they are copied out.
        let mut out_a = Vec::with_capacity(src.len() * cs);
        for &k in &src {
            if k < nv {
                extend_scaled(&mut out_a, &self.va[k * cs..(k + 1) * cs], &f);
            } else {
                let r = k - nv;
                let a = match rep_own_a[r] {
                    u32::MAX => self.rep_a(rep_cell[r] as usize),
                    w => &wedge_a[w as usize * al..(w as usize + 1) * al],
                };
                extend_scaled(&mut out_a, a, &f[..al]);
                extend_scaled(&mut out_a, &rep_ge[r * (dim + 1)..(r + 1) * (dim + 1)], &f[al..]);
            }
        }
        // Members of each representative (by output vertex), CSR.
        let mut out_of_rep = vec![u32::MAX; reps.len()];
        for (o, &k) in src.iter().enumerate() {
            if k >= nv {
                out_of_rep[k - nv] = o as u32;
            }
        }
        let mut members_first = vec![0u32; src.len() + 1];
        for &r in &rep_of_free {
            let o = out_of_rep[r as usize];
            if o != u32::MAX {
                members_first[o as usize + 1] += 1;
            }
        }
        for o in 0..src.len() {
            members_first[o + 1] += members_first[o];
        }
        let mut next = members_first.clone();
        let mut members = vec![0u32; members_first[src.len()] as usize];
        for (i, &r) in rep_of_free.iter().enumerate() {
            let o = out_of_rep[r as usize];
            if o != u32::MAX {
                members[next[o as usize] as usize] = self.free[i];
                next[o as usize] += 1;
            }
        }
        let kept_from = src.iter().map(|&k| if k < nv { k as u32 } else { u32::MAX }).collect();
        let vertex_predicted = src.iter().map(|&k| if k < nv { 0.0 } else { rep_predicted2[k - nv].sqrt() }).collect();
        NodeOut { mesh, a: out_a, kept_from, members_first, members, stats: st, predicted: predicted2.sqrt(), vertex_predicted, in_fans: self.in_fans.clone() }
    }

    /// Vertex `v`'s row (embedded at `p`): its quadric about its own
    /// position, packed, with attributes eliminated when `eliminate`
    /// ([`crate::quadric::eliminate_attrs`]).
    fn row_into(&self, v: u32, p: &[f64], eliminate: bool, q: &mut [f64]) {
        // Each dimension a mesh can have as a constant (`sized!`): the
        // loops unroll and the slices' bounds are checked once (row_into
        // was 6 % of the samples of a build with uvs, normals and colours).
        crate::quadric::sized!(self.space.dim, row_into_n(self, v, p, eliminate, q))
    }

    fn rep_a(&self, c: usize) -> &[f64] {
        let al = self.space.dim * (self.space.dim + 1) / 2;
        let at = self.cells[c].q as usize * self.cl;
        &self.cq[at..at + al]
    }
}

/// [`Splits::row_into`] at dimension `dim` (a constant where inlined).
#[inline(always)]
fn row_into_n(dim: usize, sp: &Splits, v: u32, p: &[f64], eliminate: bool, q: &mut [f64]) {
    let (p, q) = (&p[..dim], &mut q[..Quadric::coeff_len(dim)]);
    let (al, cs) = (dim * (dim + 1) / 2, carry_len(dim));
    // Cleared only for a seam vertex (most rows take the carried values as they are).
    let mut t: [f64; crate::quadric::MAX_COEFFS];
    let c = &sp.va[v as usize * cs..(v as usize + 1) * cs];
    let c = if eliminate {
        t = [0.0; crate::quadric::MAX_COEFFS];
        let t = &mut t[..cs];
        t.copy_from_slice(c);
        crate::quadric::eliminate_attrs(dim, t, crate::quadric::DEFAULT_REL_TOL);
        &t[..]
    } else {
        c
    };
    let a = &c[..al];
    // The trace stands for the area (only its being non-zero matters).
    let area = (0..dim).map(|k| a[diag_at(dim, k)]).sum::<f64>().max(f64::MIN_POSITIVE);
    crate::quadric::packed_at_point(dim, a, p, area, q);
    // The exact input quadric about p: its gradient there too (a
    // representative of a curved patch is not on its planes). The
    // residual e is left out, so priorities measure what a split
    // can still gain; the build adds the members' back.
    let g = &c[al..al + dim];
    let mut e = q[al + dim];
    for k in 0..dim {
        q[al + k] += g[k];
        e -= 2.0 * g[k] * p[k];
    }
    q[al + dim] = e;
}

/// Simplifies `mesh` towards `target` triangles (see the module doc).
/// `locked[v]` keeps vertex `v` as it is. A target at or above the input's
/// count returns the input unchanged (unreferenced vertices dropped).
pub fn cluster_node(mesh: &IndexedMesh, locked: &[bool], attrs: AttrSet, target: usize, rel_tol: f64) -> (IndexedMesh, ClusterStats) {
    let sp = Splits::new(mesh, None, locked, None, attrs, if target >= mesh.triangles.len() { 1 } else { usize::MAX }, 0.0);
    let s = if target >= mesh.triangles.len() { sp.steps() } else { sp.steps_for_target(target) };
    if target >= mesh.triangles.len() {
        let mut st = sp.stats;
        st.clusters = 0;
        return (compact(mesh, &vec![u32::MAX; mesh.vertices.len()], &[], None).0, st);
    }
    let o = sp.build(s, rel_tol);
    (o.mesh, o.stats)
}

/// The open edges (used by one triangle) whose smaller end is among
/// `from`, as (smaller end, other end, its triangle): found per smaller end
/// from the triangles around it, a few entries sorted per vertex instead of
/// a hash map of every edge (which cost ~100 ns a triangle at level 0).
pub(super) fn open_edges(mesh: &IndexedMesh, (first, around): (&[u32], &[u32]), from: impl IntoIterator<Item = u32>) -> Vec<(u32, u32, u32)> {
    let mut open = Vec::new();
    let mut ends: Vec<(u32, u32)> = Vec::new();
    for a in from {
        ends.clear();
        let mut last = u32::MAX;
        for &ti in &around[first[a as usize] as usize..first[a as usize + 1] as usize] {
            if ti == last {
                continue; // listed once per corner at a
            }
            last = ti;
            let t = mesh.triangles[ti as usize];
            for c in 0..3 {
                let (x, y) = (t[c], t[(c + 1) % 3]);
                if x == a && y > a {
                    ends.push((y, ti));
                } else if y == a && x > a {
                    ends.push((x, ti));
                }
            }
        }
        ends.sort_unstable();
        for run in ends.chunk_by(|x, y| x.0 == y.0) {
            if let [(b, ti)] = run {
                open.push((a, *b, *ti));
            }
        }
    }
    open
}

/// Weight of a border edge's constraint plane, per squared edge length
/// (a triangle's plane weighs its area, about half that).
const BORDER_WEIGHT: f64 = 1.0;

/// Weight of an attribute seam's edge planes, relative to a border's. Both
/// sides' triangles already hold a seam in the surface; its planes keep it
/// from sliding along the surface, where a texture seam that moves shows
/// texels of the wrong island. A trade, measured on a 1 M-triangle sphere
/// with a 16³-cell atlas (`metro --attributes`: mean uv difference at the
/// closest point; RMS relative to the diagonal), level 3:
///
/// | weight | RMS | mean uv difference |
/// |---:|---:|---:|
/// | 0.25 | 1.24e-5 | 0.0079 |
/// | 0.5 | 1.39e-5 | 0.0056 |
/// | 1 | 1.55e-5 | 0.0036 |
/// | 2 | 1.72e-5 | 0.0021 |
///
/// (level 7: 0.069, 0.057, 0.044, 0.038). Seams keep a border's weight:
/// half the texture error of 0.25 for a quarter more RMS, which stays far
/// below meshoptimizer's `simplify` on these inputs.
const SEAM_WEIGHT: f64 = 1.0;

/// Garland–Heckbert border constraints: for every edge used by one
/// triangle, unless both its ends are locked (the mesh's open border, not
/// a node's seams),
/// the plane through the edge perpendicular to its triangle, weighted by
/// the squared edge length, added to both corners' position block. Plane
/// quadrics alone let a cluster slide along a flat border, so borders would
/// retreat by a cluster; with these, moving off the border line costs.
/// An edge between two seam vertices (`seam`) is an attribute seam inside
/// the surface, not its border: its planes weigh [`SEAM_WEIGHT`].
fn add_border_planes(
    mesh: &IndexedMesh,
    (first, around): &(Vec<u32>, Vec<u32>),
    locked: &[bool],
    seam: Option<&[bool]>,
    dim: usize,
    stride: usize,
    va: &mut [f64],
) {
    for (a, b, ti) in open_edges(mesh, (&first[..], &around[..]), 0..mesh.vertices.len() as u32) {
        // An open edge between two locked vertices is a seam with another
        // node (or an attribute seam), not the mesh's border: a plane
        // there would be carried up with the vertices' quadrics and pull
        // the next level's clusters towards a line that is no border.
        if locked[a as usize] && locked[b as usize] {
            continue;
        }
        let t = mesh.triangles[ti as usize];
        let p = t.map(|v| mesh.vertices[v as usize].pos);
        let (pa, pb) = (mesh.vertices[a as usize].pos, mesh.vertices[b as usize].pos);
        let e = [0, 1, 2].map(|k| pb[k] - pa[k]);
        let u = [0, 1, 2].map(|k| p[1][k] - p[0][k]);
        let v = [0, 1, 2].map(|k| p[2][k] - p[0][k]);
        let nf = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]];
        let m = [e[1] * nf[2] - e[2] * nf[1], e[2] * nf[0] - e[0] * nf[2], e[0] * nf[1] - e[1] * nf[0]];
        let ml = (m[0] * m[0] + m[1] * m[1] + m[2] * m[2]).sqrt();
        let e2 = e[0] * e[0] + e[1] * e[1] + e[2] * e[2];
        if !(ml > 0.0 && ml.is_finite() && e2.is_finite()) {
            continue;
        }
        let m = m.map(|x| x / ml);
        let mut w = BORDER_WEIGHT * e2;
        if seam.is_some_and(|sm| sm[a as usize] && sm[b as usize]) {
            w *= SEAM_WEIGHT;
        }
        for &vtx in &[a, b] {
            let q = &mut va[vtx as usize * stride..(vtx as usize + 1) * stride];
            for i in 0..3 {
                for j in i..3 {
                    // Packed upper-triangular row-major index of (i, j).
                    q[diag_at(dim, i) + (j - i)] += w * m[i] * m[j];
                }
            }
        }
    }
}

/// Per-dimension factors between raw attribute units and this space's
/// weighted ones (positions 1; `inverse`: weighted → raw).
fn attr_scale(space: &QuadricSpace, inverse: bool) -> Vec<f64> {
    let w = &space.weights;
    let f = |x: f64| {
        let x = if x.is_finite() && x > 0.0 { x } else { 0.0 };
        if inverse {
            if x > 0.0 {
                1.0 / x
            } else {
                0.0
            }
        } else {
            x
        }
    };
    let mut d = vec![1.0; 3];
    let a = space.attrs;
    if a.uv() {
        d.extend([f(w.uv); 2]);
    }
    if a.normal() {
        d.extend([f(w.normal); 3]);
    }
    if a.color() {
        d.extend([f(w.color); 3]);
    }
    d
}

/// `A ← D A D` for a packed upper-triangular row-major matrix and diagonal `d`.
pub fn scale_packed(a: &mut [f64], dim: usize, d: &[f64]) {
    let mut k = 0;
    for i in 0..dim {
        for j in i..dim {
            a[k] *= d[i] * d[j];
            k += 1;
        }
    }
}

/// [`scale_packed`] for carried values (see [`carry_len`]): the matrix by
/// `d_i d_j`, the half-gradient by `d_i`, the residual unchanged.
pub fn scale_carried(c: &mut [f64], dim: usize, d: &[f64]) {
    let al = dim * (dim + 1) / 2;
    scale_packed(&mut c[..al], dim, d);
    for k in 0..dim {
        c[al + k] *= d[k];
    }
}

/// [`scale_carried`]'s factor of each carried value: `d_i d_j` for the
/// matrix, `d_i` for the half-gradient, 1 for the residual. Made once per
/// node: [`extend_scaled`] is then one multiplication a value, the same
/// bits as [`scale_carried`] (which forms `d_i d_j` again for every value
/// of every vertex: 3 % of an attribute build's instructions, with the
/// copy it followed).
fn carried_factors(dim: usize, d: &[f64]) -> Vec<f64> {
    let mut f = Vec::with_capacity(carry_len(dim));
    for i in 0..dim {
        for j in i..dim {
            f.push(d[i] * d[j]);
        }
    }
    f.extend_from_slice(&d[..dim]);
    f.push(1.0);
    f
}

/// Appends `src` times `f` (per value, `f.len() ≥ src.len()`) to `out`:
/// a copy and a rescale in one pass.
#[inline]
fn extend_scaled(out: &mut Vec<f64>, src: &[f64], f: &[f64]) {
    out.extend(src.iter().zip(f).map(|(x, f)| x * f));
}

/// Cells waiting to be split: by priority (the greedy sequence) or in any
/// order (a threshold's partition).
enum Queue {
    Heap(BinaryHeap<Prio>),
    Stack(Vec<Prio>),
}

impl Queue {
    fn push(&mut self, p: Prio) {
        match self {
            Queue::Heap(h) => h.push(p),
            Queue::Stack(s) => s.push(p),
        }
    }

    fn pop(&mut self) -> Option<Prio> {
        match self {
            Queue::Heap(h) => h.pop(),
            Queue::Stack(s) => s.pop(),
        }
    }
}

/// The free vertices' split data: quadric rows (`cl` each) in free order,
/// and local positions and free indices in cell order (permuted together).
struct Rows {
    q: Vec<f64>,
    pts: Vec<[f64; 3]>,
    ids: Vec<u32>,
    cl: usize,
}

impl Rows {
    /// The box of rows `start..end`'s points, unless they are all one
    /// point or the box is `lo..hi` already (then no split can separate them).
    fn shrunk_box(&self, start: usize, end: usize, lo: [f64; 3], hi: [f64; 3]) -> Option<([f64; 3], [f64; 3])> {
        let mut blo = [f64::INFINITY; 3];
        let mut bhi = [f64::NEG_INFINITY; 3];
        for p in &self.pts[start..end] {
            for k in 0..3 {
                blo[k] = blo[k].min(p[k]);
                bhi[k] = bhi[k].max(p[k]);
            }
        }
        if (0..3).all(|k| bhi[k] - blo[k] <= 0.0) || (0..3).all(|k| blo[k] == lo[k] && bhi[k] == hi[k]) {
            return None;
        }
        Some((blo, bhi))
    }

    /// Splits rows `start..end`'s points and ids in place (Hoare) at `mid`
    /// along `axis`: points below it first, each side's moments summed as
    /// its points are met; returns where the upper side starts. The
    /// quadric rows do not move (they are read through `ids`).
    fn partition(&mut self, start: usize, end: usize, axis: usize, mid: f64, mo: &mut [[f64; 6]; 2]) -> usize {
        let (mut i, mut j) = (start, end);
        // The sums in locals (registers), stored once at the end: summed
        // through `mo` they went to memory at every point.
        let (mut lo, mut hi) = (mo[0], mo[1]);
        let pts = &mut self.pts[..end];
        loop {
            while i < j && pts[i][axis] < mid {
                add_moments(&mut lo, pts[i]);
                i += 1;
            }
            while i < j && pts[j - 1][axis] >= mid {
                add_moments(&mut hi, pts[j - 1]);
                j -= 1;
            }
            if i >= j {
                *mo = [lo, hi];
                return i;
            }
            pts.swap(i, j - 1);
            self.ids.swap(i, j - 1);
            add_moments(&mut lo, pts[i]);
            add_moments(&mut hi, pts[j - 1]);
            i += 1;
            j -= 1;
        }
    }
}

/// A cell of the whole split tree, before the greedy order is known.
struct Node {
    /// Members: rows `start..end`.
    start: u32,
    end: u32,
    /// Its children's index (low, then high at `child + 1`), or MAX for a
    /// leaf: one member, or all members on one side of their mean.
    child: u32,
    axis: u8,
    mid: f64,
    /// A leaf of several members: its members' box where that is smaller
    /// than its own (it takes it when the sequence reaches it).
    shrunk: Option<([f64; 3], [f64; 3])>,
}

/// The split tree of every root down to single members: each cell split at
/// its members' mean along their axis of largest variance (see
/// [`Splits::split_cells`]). Roots are nodes `0..roots.len()`; children
/// come after their parent.
struct Tree {
    nodes: Vec<Node>,
}

impl Tree {
    fn grow(rows: &mut Rows, roots: &[Root]) -> Tree {
        let mut nodes = Vec::with_capacity(2 * rows.ids.len());
        // Per node: its box and its members' moments (sums of positions
        // and of their squares, kept as cells are made so a split reads
        // its members once).
        let mut boxes: Vec<([f64; 3], [f64; 3])> = Vec::with_capacity(2 * rows.ids.len());
        let mut moments: Vec<[f64; 6]> = Vec::with_capacity(2 * rows.ids.len());
        for &(start, end, lo, hi) in roots {
            let mut m = [0.0; 6];
            for p in &rows.pts[start..end] {
                add_moments(&mut m, *p);
            }
            nodes.push(Node { start: start as u32, end: end as u32, child: u32::MAX, axis: 0, mid: 0.0, shrunk: None });
            boxes.push((lo, hi));
            moments.push(m);
        }
        let mut todo: Vec<usize> = (0..nodes.len()).rev().collect();
        while let Some(t) = todo.pop() {
            let (start, end) = (nodes[t].start as usize, nodes[t].end as usize);
            if end - start < 2 {
                continue;
            }
            // Split at the members' mean along their axis of largest
            // variance (a binary kd-split: clusters of one level of
            // refinement differ by 2x in size, not 8x as octree splits do).
            let n = (end - start) as f64;
            let m = moments[t];
            let var = [0, 1, 2].map(|k| m[3 + k] / n - (m[k] / n).powi(2));
            let axis = (0..3).max_by(|&a, &b| var[a].total_cmp(&var[b])).unwrap();
            let mid = m[axis] / n;
            let mut mo = [[0.0; 6]; 2];
            let i = rows.partition(start, end, axis, mid, &mut mo);
            let (lo, hi) = boxes[t];
            if i == start || i == end {
                // All members on one side: a leaf whose box shrinks (the
                // same split again would find them on one side again).
                nodes[t].shrunk = rows.shrunk_box(start, end, lo, hi);
                continue;
            }
            let c = nodes.len();
            nodes[t].child = c as u32;
            nodes[t].axis = axis as u8;
            nodes[t].mid = mid;
            let (mut lhi, mut hlo) = (hi, lo);
            lhi[axis] = mid;
            hlo[axis] = mid;
            nodes.push(Node { start: start as u32, end: i as u32, child: u32::MAX, axis: 0, mid: 0.0, shrunk: None });
            nodes.push(Node { start: i as u32, end: end as u32, child: u32::MAX, axis: 0, mid: 0.0, shrunk: None });
            boxes.push((lo, lhi));
            boxes.push((hlo, hi));
            moments.extend(mo);
            todo.push(c + 1);
            todo.push(c);
        }
        Tree { nodes }
    }
}

/// Appends the sum of rows `ids` of `q` (`cl` values each, in that order;
/// members' rows) to `q`. `CL`: the row length when it is one of the
/// common ones (the sum then unrolls), 0 for any other (`cl`).
fn sum_rows<const CL: usize>(q: &mut Vec<f64>, ids: &[u32], cl: usize) {
    let cl = if CL > 0 { CL } else { cl };
    let at = q.len();
    q.extend_from_within(ids[0] as usize * cl..(ids[0] as usize + 1) * cl);
    let (done, acc) = q.split_at_mut(at);
    let row = |i: u32| &done[i as usize * cl..(i as usize + 1) * cl];
    for &i in &ids[1..] {
        add(acc, row(i));
    }
}

/// Appends rows `a..a + cl` and `b..b + cl` of `q`, summed, to `q`.
fn sum_two(q: &mut Vec<f64>, a: usize, b: usize, cl: usize) {
    let at = q.len();
    q.resize(at + cl, 0.0);
    let (done, new) = q.split_at_mut(at);
    for ((n, x), y) in new.iter_mut().zip(&done[a..a + cl]).zip(&done[b..b + cl]) {
        *n = x + y;
    }
}

/// Adds a point to a cell's sums of positions and of their squares.
#[inline]
fn add_moments(m: &mut [f64; 6], p: [f64; 3]) {
    for k in 0..3 {
        m[k] += p[k];
        m[3 + k] += p[k] * p[k];
    }
}

/// Index of the diagonal entry k in a packed upper-triangular row-major matrix.
fn diag_at(dim: usize, k: usize) -> usize {
    k * dim - k * k.saturating_sub(1) / 2
}

#[inline]
fn add(acc: &mut [f64], x: &[f64]) {
    for (a, b) in acc.iter_mut().zip(x) {
        *a += b;
    }
}

/// [`crate::quadric::solve_sized`] into `x` and `ge` (half-gradient, then
/// the error); false when the box clamps.
fn sized_solve<const N: usize>(k: &[f64], rel_tol: f64, bounds: ([f64; 3], [f64; 3]), x: &mut [f64], ge: &mut [f64]) -> bool {
    match crate::quadric::solve_sized::<N>(k, rel_tol, bounds) {
        Some((sx, g, e)) => {
            x[..N].copy_from_slice(&sx);
            ge[..N].copy_from_slice(&g);
            ge[N] = e;
            true
        }
        None => false,
    }
}

/// The output mesh: vertices kept where `remap[v] == MAX` (locked), else
/// representative `reps[remap[v]]`; triangles whose corners stay distinct;
/// unreferenced vertices dropped.
/// Also gives each output vertex's source: `v < nv` a kept vertex, `nv + r`
/// representative `r`.
/// With seams (`welded`: the seams and each representative's cell), the
/// corners' points decide what is dropped: a kept vertex's position, a
/// representative's cluster (its wedges are one point).
fn compact(mesh: &IndexedMesh, remap: &[u32], reps: &[Vertex], welded: Option<(&Seams, &[u32])>) -> (IndexedMesh, Vec<usize>) {
    let nv = mesh.vertices.len();
    // Output id per source: kept vertex v -> v, representative r -> nv + r.
    let key = |v: u32| if remap[v as usize] == u32::MAX { v as usize } else { nv + remap[v as usize] as usize };
    let distinct = |k: &[usize; 3]| k[0] != k[1] && k[1] != k[2] && k[0] != k[2];
    let (images, keep) = match welded {
        None => {
            let images: Vec<[usize; 3]> = mesh.triangles.iter().map(|t| t.map(key)).filter(distinct).collect();
            let keep = unfold(&images);
            (images, keep)
        }
        Some((sm, rep_cell)) => {
            let point = |v: u32| match remap[v as usize] {
                u32::MAX => sm.pos_of[v as usize] as usize,
                r => sm.positions + rep_cell[r as usize] as usize,
            };
            let (images, points): (Vec<[usize; 3]>, Vec<[usize; 3]>) =
                mesh.triangles.iter().map(|t| (t.map(key), t.map(point))).filter(|(_, p)| distinct(p)).unzip();
            let keep = unfold(&points);
            (images, keep)
        }
    };
    let mut map = vec![u32::MAX; nv + reps.len()];
    // Room for every image kept and each source once (an upper bound):
    // reserved, not grown by doubling.
    let most_v = (nv + reps.len()).min(3 * images.len());
    let mut out = IndexedMesh { vertices: Vec::with_capacity(most_v), triangles: Vec::with_capacity(images.len()) };
    let mut src = Vec::with_capacity(most_v);
    for (k, _) in images.iter().zip(&keep).filter(|(_, &x)| x) {
        let mut nt = [0u32; 3];
        for c in 0..3 {
            if map[k[c]] == u32::MAX {
                map[k[c]] = out.vertices.len() as u32;
                out.vertices.push(if k[c] < nv { mesh.vertices[k[c]] } else { reps[k[c] - nv] });
                src.push(k[c]);
            }
            nt[c] = map[k[c]];
        }
        out.triangles.push(nt);
    }
    (out, src)
}

/// Which triangle images to keep: a triangle and one of opposite orientation
/// on the same three vertices (a *fold*, made when clustering flattens a
/// thin part) are dropped together. Dropping pairs keeps every edge's use
/// count even-odd as it was (no crack can open), removes zero-volume fins
/// and the non-manifold edges and cancelled normals they bring. Copies of
/// the same orientation (duplicated input faces) are all kept.
pub(crate) fn unfold(images: &[[usize; 3]]) -> Vec<bool> {
    let mut keep = vec![true; images.len()];
    let sorted = |k: &[usize; 3]| {
        let mut s = *k;
        s.sort_unstable();
        s
    };
    // Triangles sharing their corners with another are rare. Two such
    // share their smallest corner: triangles are bucketed by it (a
    // counting sort, no hashing), and only buckets of two or more are
    // compared; the repeated ones are then sorted into groups.
    let ids = images.iter().map(|k| k[0].max(k[1]).max(k[2]) + 1).max().unwrap_or(0);
    let mut first = vec![0u32; ids + 1];
    for k in images {
        first[k[0].min(k[1]).min(k[2]) + 1] += 1;
    }
    for v in 0..ids {
        first[v + 1] += first[v];
    }
    let mut next = first.clone();
    let mut by_min = vec![0u32; images.len()];
    for (i, k) in images.iter().enumerate() {
        let m = k[0].min(k[1]).min(k[2]);
        by_min[next[m] as usize] = i as u32;
        next[m] += 1;
    }
    // (sorted corners, odd orientation, index) of every triangle whose
    // corners repeat.
    let mut keyed: Vec<([usize; 3], bool, u32)> = Vec::new();
    let mut bucket: Vec<([usize; 3], u32)> = Vec::new();
    for v in 0..ids {
        let b = &by_min[first[v] as usize..first[v + 1] as usize];
        if b.len() < 2 {
            continue;
        }
        bucket.clear();
        bucket.extend(b.iter().map(|&i| (sorted(&images[i as usize]), i)));
        bucket.sort_unstable();
        for run in bucket.chunk_by(|x, y| x.0 == y.0).filter(|r| r.len() > 1) {
            for &(s, t) in run {
                let k = images[t as usize];
                // Orientation: rotations of the sorted triple are even.
                let even = k == s || k == [s[1], s[2], s[0]] || k == [s[2], s[0], s[1]];
                keyed.push((s, !even, t));
            }
        }
    }
    keyed.sort_unstable();
    let mut i = 0;
    while i < keyed.len() {
        let mut j = i;
        while j < keyed.len() && keyed[j].0 == keyed[i].0 {
            j += 1;
        }
        if j - i > 1 {
            let g = &keyed[i..j];
            let split = g.partition_point(|x| !x.1);
            for (p, n) in g[..split].iter().zip(&g[split..]) {
                keep[p.2 as usize] = false;
                keep[n.2 as usize] = false;
            }
        }
        i = j;
    }
    keep
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fused_rescale_is_scale_carried_bit_for_bit() {
        let mut rng = crate::geom::Rng::from_state(7);
        for dim in [3, 5, 6, 8, 9, 11] {
            let cs = carry_len(dim);
            let d: Vec<f64> = (0..dim).map(|k| if k < 3 { 1.0 } else { rng.range(0.01, 30.0) }).collect();
            let src: Vec<f64> = (0..3 * cs).map(|_| rng.range(-5.0, 5.0)).collect();
            let mut want = src.clone();
            for v in want.chunks_exact_mut(cs) {
                scale_carried(v, dim, &d);
            }
            let f = carried_factors(dim, &d);
            let mut got = Vec::new();
            for v in src.chunks_exact(cs) {
                extend_scaled(&mut got, v, &f);
            }
            let bits = |s: &[f64]| s.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&got), bits(&want), "dim {dim}");
        }
    }

    /// A bumpy n×n grid with normals and colours varying over it.
    fn coloured_grid(n: u32) -> IndexedMesh {
        let mut m = IndexedMesh::default();
        for y in 0..=n {
            for x in 0..=n {
                let (fx, fy) = (x as f64 / n as f64, y as f64 / n as f64);
                let z = 0.1 * (7.0 * fx).sin() * (5.0 * fy).cos();
                let c = |t: f64| (255.0 * (0.5 + 0.5 * t)) as u8;
                let nrm = [-(0.7 * (7.0 * fx).cos()) as f32, 0.5, 1.0];
                m.vertices.push(Vertex { pos: [fx, fy, z], normal: nrm, color: [c((9.0 * fx).sin()), c((4.0 * fy).cos()), 128, 255], ..Default::default() });
            }
        }
        m.triangles = crate::geom::grid_triangles(n);
        m
    }

    /// A thin slab (a wavy sheet and its copy a hair below, facing the
    /// other way, their rims joined): clustering folds its two sides into
    /// pairs that `build` drops. The curves' built counts are `build`'s
    /// own at every prefix, folds and all.
    #[test]
    fn built_counts_are_what_build_keeps_folds_dropped() {
        let top = coloured_grid(12);
        let mut m = top.clone();
        let nv = top.vertices.len() as u32;
        for v in &top.vertices {
            let mut w = *v;
            w.pos[2] -= 1e-4;
            m.vertices.push(w);
        }
        for t in &top.triangles {
            m.triangles.push([t[0] + nv, t[2] + nv, t[1] + nv]);
        }
        // The rim: each border edge of the top joined to its copy.
        let n = 13u32;
        let rim: Vec<(u32, u32)> =
            (0..12).flat_map(|i| [(i, i + 1), (i * n + 12, (i + 1) * n + 12), (12 * n + i + 1, 12 * n + i), ((i + 1) * n, i * n)]).collect();
        for (a, b) in rim {
            m.triangles.push([b, a, a + nv]);
            m.triangles.push([b, a + nv, b + nv]);
        }
        let locked = vec![false; m.vertices.len()];
        let sp = Splits::new(&m, None, &locked, None, AttrSet::default(), usize::MAX, 0.0);
        let mut folded = 0;
        for s in 0..=sp.steps() {
            let built = sp.build(s, 1e-3).mesh.triangles.len();
            assert_eq!(sp.built_count_at(s), built, "step {s}");
            folded += (sp.count_at(s) > built) as u32;
        }
        assert!(folded > 0, "no prefix folds: the test no longer tests the folds");
    }

    #[test]
    fn tree_sums_are_their_members_rows_and_the_threshold_is_a_prefix() {
        let m = coloured_grid(24);
        let attrs = AttrSet(AttrSet::NORMAL | AttrSet::COLOR);
        let locked = vec![false; m.vertices.len()];
        let sp = Splits::new(&m, None, &locked, None, attrs, usize::MAX, 0.0);
        let (dim, cl) = (sp.space.dim, sp.cl);
        assert_eq!(cl, Quadric::coeff_len(9));
        // Every cell's quadric is its members' rows summed directly (the
        // members: the free vertices whose leaf lies below it).
        let mut row = vec![0.0; cl];
        let emb = |v: u32| sp.space.embed(&m.vertices[v as usize]);
        for (c, cell) in sp.cells.iter().enumerate() {
            let mut want = vec![0.0; cl];
            let mut members = 0;
            for (i, &v) in sp.free.iter().enumerate() {
                let mut k = sp.leaf_of[i];
                while k != c as u32 && sp.cells[k as usize].parent != u32::MAX {
                    k = sp.cells[k as usize].parent;
                }
                if k == c as u32 {
                    sp.row_into(v, &emb(v), false, &mut row);
                    add(&mut want, &row);
                    members += 1;
                }
            }
            assert_eq!(members, cell.end - cell.start, "cell {c}");
            let got = &sp.cq[cell.q as usize * cl..(cell.q as usize + 1) * cl];
            let scale = want.iter().fold(0.0f64, |a, x| a.max(x.abs()));
            for (g, w) in got.iter().zip(&want) {
                assert!((g - w).abs() <= 1e-12 * scale, "cell {c}: {g} vs {w}");
            }
            // Its priority: the error at the members' mean.
            if cell.created > 0 {
                let p = sp.prio[cell.created as usize - 1];
                let parent = &sp.cq[sp.cells[cell.parent as usize].q as usize * cl..][..cl];
                assert_eq!(p, crate::quadric::packed_error_at_mean(dim, parent), "cell {c}");
            }
        }
        // A threshold's partition is the greedy prefix at it.
        for share in [0.1, 0.3, 0.6] {
            let tau = sp.priorities()[(share * sp.priorities().len() as f64) as usize];
            let s = sp.steps_for_error(tau);
            let th = Splits::to_threshold(&m, None, &locked, None, attrs, tau);
            let (a, b) = (sp.build(s, 1e-3), th.build(th.steps(), 1e-3));
            assert_eq!(a.mesh.triangles, b.mesh.triangles, "tau {tau}");
            assert_eq!(a.a, b.a, "tau {tau}");
        }
    }

    #[test]
    fn counts_from_births_are_the_counts_of_each_prefix() {
        let m = coloured_grid(20);
        let nv = m.vertices.len();
        // Locked: the border row and a few scattered vertices.
        let locked: Vec<bool> = (0..nv).map(|v| v < 21 || v % 17 == 0).collect();
        for attrs in [AttrSet::default(), AttrSet(AttrSet::NORMAL | AttrSet::COLOR)] {
            for lock in [&vec![false; nv], &locked] {
                let sp = Splits::new(&m, None, lock, None, attrs, usize::MAX, 0.0);
                assert!(sp.births().is_some());
                let steps: Vec<u32> = (0..=sp.steps()).collect();
                let want: Vec<usize> = steps.iter().map(|&s| sp.count_at(s)).collect();
                assert_eq!(sp.counts_at(&steps), want);
                assert!(want[0] < want[steps.len() - 1], "the splits make triangles");
            }
        }
        // Seams: the grid cut along a column into two uv islands (wedges
        // of one position), the ones on the border locked.
        let mut cut = m.clone();
        let n = 21u32;
        let mut twin = vec![u32::MAX; nv];
        for y in 0..n {
            let v = y * n + 10;
            twin[v as usize] = cut.vertices.len() as u32;
            let mut w = cut.vertices[v as usize];
            w.uv = [0.9, 0.9];
            cut.vertices.push(w);
        }
        for t in cut.triangles.iter_mut() {
            if t.iter().any(|&v| v % n > 10) {
                for v in t.iter_mut() {
                    if twin[*v as usize] != u32::MAX {
                        *v = twin[*v as usize];
                    }
                }
            }
        }
        let lock: Vec<bool> = (0..cut.vertices.len()).map(|v| v < 21 || v == nv).collect();
        let sp = Splits::new(&cut, None, &lock, None, AttrSet(AttrSet::UV), usize::MAX, 0.0);
        assert!(sp.seams.is_some());
        let steps: Vec<u32> = (0..=sp.steps()).collect();
        let want: Vec<usize> = steps.iter().map(|&s| sp.count_at(s)).collect();
        assert_eq!(sp.counts_at(&steps), want);
    }
}

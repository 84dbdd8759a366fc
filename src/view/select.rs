//! Per-frame cut selection on the LOD DAG: which nodes to hold and which of
//! their patches to draw for a camera.
//!
//! Takes: the store's node index ([`Hierarchy`]: bounds, errors, children,
//! parents, triangle counts), a camera, the viewport, and which nodes are
//! ready on the GPU. Gives: the selection S — the roots and, with every
//! node, all its parents — the nodes to draw with the patches whose child
//! is not in S (a valid cut, hence crack-free: see [`crate::store`]), the
//! loads it wants, in priority order, and what to prefetch.
//!
//! The traversal is best-first from the roots: the selected node with the
//! largest projected error (stored object-space error × pixels per unit at
//! the distance to the nearest point of its bounds) is expanded first, as
//! long as its error exceeds `--max-error-px`. Expanding a node adds its
//! children to S, each with whatever ancestors it is missing (a child is
//! drawn only once every parent has handed it its part), provided they are
//! all resident and the triangle budget pays for them (a node costs its
//! triangles less its simplified mesh, which its parents stop drawing).
//! Otherwise the node keeps drawing its patch for that child — the coarser
//! geometry stays on screen while the finer loads — and the missing nodes
//! are requested. Errors are saturated upward and bounds contain children,
//! so the projected error never increases from a node to its parent and
//! the order is consistent. Boxes are culled only when entirely outside
//! one frustum plane. A node expanded in the previous frame keeps expanding
//! down to `hysteresis × max_error_px`, so a cut does not pop back and forth
//! at the threshold. `--distance-lod F` replaces the projected-error test
//! by the original design's distance rule: expand while the eye is nearer
//! than F × the node's cell diagonal.

use super::camera::{box_distance, Camera, Frustum};
use crate::mesh::Aabb;
use crate::store::Store;
use glam::DVec3;
use std::collections::BinaryHeap;

/// A node id (the viewer's draw and load unit).
pub type Unit = u32;

/// What the selection needs to know of a node.
#[derive(Clone, Debug)]
pub struct UnitInfo {
    pub level: u8,
    pub tris: u32,
    /// Triangles of its simplified mesh (what its parents draw for it).
    pub simp_tris: u32,
    pub verts: u32,
    pub bytes: u32,
    pub offset: u64,
    pub crc: u32,
    /// Its pack file's part and its payload's patch shift (`store::NodeRec`).
    pub part: u32,
    pub patch_shift: u32,
    /// Object-space error of the node's triangles (0 at level 0; the
    /// record's `f32`, kept as it is so the index stays 96 bytes a node).
    pub error: f32,
    /// Bounds of the node and its descendants.
    pub bounds: Aabb,
    /// Diagonal of the node's cell (distance-only mode).
    pub cell_diag: f32,
}

/// The DAG as the viewer sees it.
pub struct Hierarchy {
    pub units: Vec<UnitInfo>,
    children: Vec<u32>,
    parents: Vec<u32>,
    /// (first, count) into `children` / `parents` per node.
    child_at: Vec<(u32, u32)>,
    parent_at: Vec<(u32, u32)>,
    /// The top level's nodes (one unless the build stopped early).
    pub roots: Vec<Unit>,
    pub bounds: Aabb,
    /// Bytes per vertex of a GPU-ready mesh: [`super::GpuVertex`], plus
    /// 8 when uvs are loaded for a texture.
    pub vertex_bytes: u64,
}

impl Hierarchy {
    pub fn new(store: &Store) -> Hierarchy {
        let units = store
            .nodes
            .iter()
            .map(|n| UnitInfo {
                level: n.level,
                tris: n.tris,
                simp_tris: n.simp_tris,
                verts: n.verts,
                bytes: n.bytes,
                offset: n.offset,
                crc: n.crc,
                part: n.part,
                patch_shift: n.patch_shift,
                error: n.error,
                bounds: n.bounds,
                cell_diag: n.cell.diagonal() as f32,
            })
            .collect();
        let roots: Vec<Unit> = store.roots().into_iter().map(|r| r as Unit).collect();
        let mut bounds = Aabb::EMPTY;
        for &r in &roots {
            bounds.merge(&store.nodes[r as usize].bounds);
        }
        Hierarchy {
            units,
            children: store.children.clone(),
            parents: store.parents.clone(),
            child_at: store.nodes.iter().map(|n| (n.first_child, n.child_count)).collect(),
            parent_at: store.nodes.iter().map(|n| (n.first_parent, n.parent_count)).collect(),
            roots,
            bounds,
            vertex_bytes: std::mem::size_of::<super::GpuVertex>() as u64,
        }
    }

    pub fn children(&self, u: Unit) -> &[Unit] {
        let (f, c) = self.child_at[u as usize];
        &self.children[f as usize..(f + c) as usize]
    }

    pub fn parents(&self, u: Unit) -> &[Unit] {
        let (f, c) = self.parent_at[u as usize];
        &self.parents[f as usize..(f + c) as usize]
    }

    pub fn info(&self, u: Unit) -> &UnitInfo {
        &self.units[u as usize]
    }

    /// Every level-0 node (the input), for brute-force rendering.
    pub fn leaves(&self) -> Vec<Unit> {
        (0..self.units.len() as Unit).filter(|&u| self.units[u as usize].level == 0).collect()
    }

    /// Estimated bytes of a node's GPU-ready mesh (see `DrawMesh::bytes`).
    pub fn draw_bytes(&self, u: Unit) -> u64 {
        let s = self.info(u);
        s.verts as u64 * self.vertex_bytes + s.tris as u64 * 12
    }

    /// Bytes the index takes in memory (charged against the budget).
    pub fn bytes(&self) -> u64 {
        (self.units.len() * (std::mem::size_of::<UnitInfo>() + 16) + (self.children.len() + self.parents.len()) * 4) as u64
    }

    /// Triangles a node adds when it joins a selection (its own, less its
    /// simplified mesh that its parents stop drawing).
    fn cost(&self, u: Unit) -> i64 {
        let i = self.info(u);
        i.tris as i64 - if self.parents(u).is_empty() { 0 } else { i.simp_tris as i64 }
    }
}

/// Selection parameters.
#[derive(Clone, Debug)]
pub struct SelectOptions {
    /// Refine while the projected error exceeds this many pixels.
    pub max_error_px: f64,
    /// Most triangles a frame may draw.
    pub tri_budget: u64,
    /// Distance-only mode: refine while the eye is nearer than this × the
    /// node's cell diagonal (None: projected error).
    pub distance_lod: Option<f64>,
    /// A node expanded last frame stays expanded until its error falls below
    /// `hysteresis × max_error_px` (≤ 1).
    pub hysteresis: f64,
    /// Prefetch children of nodes whose error is within this factor of
    /// the threshold (at the eye predicted from camera motion too).
    pub prefetch: f64,
}

impl Default for SelectOptions {
    fn default() -> Self {
        SelectOptions { max_error_px: 1.0, tri_budget: 20_000_000, distance_lod: None, hysteresis: 0.7, prefetch: 0.5 }
    }
}

/// One frame's selection.
#[derive(Clone, Debug, Default)]
pub struct Selection {
    /// Membership of S per node.
    pub selected: Vec<bool>,
    /// Nodes to draw (selected, visible, with at least one drawn patch),
    /// in traversal order.
    pub cut: Vec<Unit>,
    /// Every selected node (all resident; kept from eviction).
    pub visited: Vec<Unit>,
    /// Loads wanted now, highest priority first: (node, priority).
    pub wanted: Vec<(Unit, f64)>,
    /// Resident nodes a wanted load would complete (a refinement needs a
    /// node with every ancestor it lacks, all at once): kept from eviction
    /// like the visited ones, or loading the rest could evict them, and
    /// with a budget that fits only part of such a group every frame
    /// would evict and load again without end.
    pub held: Vec<Unit>,
    /// Loads worth doing if memory is free (prefetch), after `wanted`.
    pub prefetch: Vec<(Unit, f64)>,
    /// Triangles the cut draws (all selected nodes' patches, visible or not).
    pub triangles: u64,
    /// Largest projected error on screen (pixels; distance mode: the
    /// largest distance ratio): over the drawn patches inside the frustum,
    /// each patch's node error projected at its child's bounds (the region
    /// it covers, by which the selection culls it). Patches a node draws
    /// for children outside the view do not count, although the node's own
    /// bounds may reach the eye: that error is off screen.
    pub max_error_px: f64,
    /// Expansions stopped by the triangle budget.
    pub budget_limited: u32,
}

impl Selection {
    /// Whether node `u` draws its patch from `child`.
    pub fn draws(&self, child: u32) -> bool {
        child == crate::store::NO_NODE || !self.selected.get(child as usize).copied().unwrap_or(false)
    }
}

#[derive(PartialEq)]
struct Cand(f64, Unit);
impl Eq for Cand {}
impl PartialOrd for Cand {
    fn partial_cmp(&self, o: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for Cand {
    fn cmp(&self, o: &Self) -> std::cmp::Ordering {
        self.0.total_cmp(&o.0).then(o.1.cmp(&self.1))
    }
}

/// Per-frame selection state (the previous selection, for hysteresis).
pub struct Selector {
    pub opts: SelectOptions,
    prev_expanded: Vec<bool>,
    prev_eye: Option<DVec3>,
}

impl Selector {
    pub fn new(opts: SelectOptions) -> Selector {
        Selector { opts, prev_expanded: Vec::new(), prev_eye: None }
    }

    /// The refinement priority of `u` seen from `eye` (pixels of projected
    /// error, or in distance mode the ratio cell size·F / distance).
    pub fn priority(&self, h: &Hierarchy, u: Unit, cam: &Camera, eye: DVec3, height_px: f64) -> f64 {
        self.priority_over(h, u, &h.info(u).bounds, cam, eye, height_px)
    }

    /// [`Selector::priority`] of node `u`'s triangles inside `region` (a
    /// patch: its child's bounds), seen from `eye`.
    pub fn priority_over(&self, h: &Hierarchy, u: Unit, region: &Aabb, cam: &Camera, eye: DVec3, height_px: f64) -> f64 {
        let i = h.info(u);
        let d = box_distance(region, eye);
        match self.opts.distance_lod {
            Some(f) => {
                if i.level == 0 {
                    0.0
                } else {
                    f * i.cell_diag as f64 / d.max(1e-12)
                }
            }
            None => i.error as f64 * cam.pixels_per_unit(d, height_px),
        }
    }

    fn threshold(&self) -> f64 {
        if self.opts.distance_lod.is_some() {
            1.0
        } else {
            self.opts.max_error_px
        }
    }

    /// Selects the cut for `cam`. `ready(u)` says whether node `u` can be
    /// drawn now (resident on the GPU). Never waits for anything.
    pub fn select(&mut self, h: &Hierarchy, cam: &Camera, viewport: (u32, u32), ready: &dyn Fn(Unit) -> bool) -> Selection {
        let n = h.units.len();
        let aspect = viewport.0 as f64 / viewport.1.max(1) as f64;
        let height = viewport.1.max(1) as f64;
        let frustum: Frustum = cam.frustum(aspect);
        let visible = |u: Unit| {
            let b = &h.info(u).bounds;
            box_distance(b, cam.eye) == 0.0 || !frustum.culls(b)
        };
        let predicted = match self.prev_eye {
            Some(p) => cam.eye + (cam.eye - p) * 8.0,
            None => cam.eye,
        };
        self.prev_eye = Some(cam.eye);
        if self.prev_expanded.len() != n {
            self.prev_expanded = vec![false; n];
        }
        let thr = self.threshold();
        let mut sel = Selection { selected: vec![false; n], ..Default::default() };
        let mut expanded = vec![false; n];
        let mut heap = BinaryHeap::new();
        let mut tris: i64 = 0;
        if h.roots.iter().any(|&r| !ready(r)) {
            sel.wanted.extend(h.roots.iter().filter(|&&r| !ready(r)).map(|&r| (r, f64::INFINITY)));
            self.prev_expanded = expanded;
            return sel;
        }
        let mut order: Vec<Unit> = Vec::new();
        for &root in &h.roots {
            sel.selected[root as usize] = true;
            tris += h.cost(root);
            heap.push(Cand(self.priority(h, root, cam, cam.eye, height), root));
            order.push(root);
        }
        let mut missing: Vec<Unit> = Vec::new();
        while let Some(Cand(p, u)) = heap.pop() {
            let t = if self.prev_expanded[u as usize] { thr * self.opts.hysteresis } else { thr };
            if p <= t || h.children(u).is_empty() || !visible(u) {
                continue;
            }
            expanded[u as usize] = true;
            for &c in h.children(u) {
                if sel.selected[c as usize] || !visible(c) {
                    continue;
                }
                // c with every ancestor it lacks, nearest first.
                missing.clear();
                let mut stack = vec![c];
                while let Some(x) = stack.pop() {
                    if sel.selected[x as usize] || missing.contains(&x) {
                        continue;
                    }
                    missing.push(x);
                    stack.extend(h.parents(x).iter().copied().filter(|&q| !sel.selected[q as usize]));
                }
                if missing.iter().any(|&x| !ready(x)) {
                    for &x in &missing {
                        if ready(x) {
                            sel.held.push(x);
                        } else {
                            sel.wanted.push((x, p));
                        }
                    }
                    continue;
                }
                let cost: i64 = missing.iter().map(|&x| h.cost(x)).sum();
                if tris + cost > self.opts.tri_budget as i64 {
                    sel.budget_limited += 1;
                    continue;
                }
                tris += cost;
                // Ancestors first, so S stays closed under parents.
                for &x in missing.iter().rev() {
                    sel.selected[x as usize] = true;
                    order.push(x);
                    heap.push(Cand(self.priority(h, x, cam, cam.eye, height), x));
                }
            }
        }
        sel.triangles = tris.max(0) as u64;
        for &u in &order {
            let kids = h.children(u);
            let draws_some = kids.is_empty() || kids.iter().any(|&c| !sel.selected[c as usize]);
            sel.visited.push(u);
            if !draws_some {
                continue;
            }
            if visible(u) {
                sel.cut.push(u);
            }
            if !kids.is_empty() {
                // The error on screen: the drawn patches in view only (see
                // `Selection::max_error_px`).
                if visible(u) {
                    for &c in kids {
                        if !sel.selected[c as usize] && visible(c) {
                            let pc = self.priority_over(h, u, &h.info(c).bounds, cam, cam.eye, height);
                            sel.max_error_px = sel.max_error_px.max(pc);
                        }
                    }
                }
                let p = self.priority(h, u, cam, cam.eye, height);
                // Prefetch: close to the threshold now or at the predicted eye.
                let pp = p.max(self.priority(h, u, cam, predicted, height));
                if pp > thr * self.opts.prefetch {
                    for &c in kids {
                        if !sel.selected[c as usize] && !ready(c) {
                            sel.prefetch.push((c, pp));
                        }
                    }
                }
            }
        }
        // Nearest / largest error first; each node once.
        sel.wanted.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
        dedup_keep_first(&mut sel.wanted);
        sel.prefetch.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
        dedup_keep_first(&mut sel.prefetch);
        self.prev_expanded = expanded;
        sel
    }
}

fn dedup_keep_first(v: &mut Vec<(Unit, f64)>) {
    let mut seen = std::collections::HashSet::new();
    v.retain(|(u, _)| seen.insert(*u));
}

//! Per-frame cut selection: which node meshes to draw for a camera.
//!
//! Takes: the store's node index turned into a hierarchy of *draw units*
//! (a node's simplified mesh, and for a leaf also its original triangles
//! one step finer), a camera, the viewport, and which units are ready on
//! the GPU. Gives: the cut to draw (an antichain covering every visible
//! part of the surface exactly once, hence crack-free: units share their
//! node-boundary edges bit for bit), the units it visited (to keep
//! resident), and the loads it wants, in priority order.
//!
//! The traversal is best-first from the always-resident roots: the unit
//! with the largest projected error (stored object-space error × pixels per
//! unit at the distance to the nearest point of its tight box) is refined
//! first, as long as its error exceeds `--max-error-px` and the triangle
//! budget can pay for the children's triangles minus its own. A unit whose
//! visible children are not all ready stays in the cut (the nearest
//! resident ancestor is drawn) and its children are requested. Boxes are
//! culled only when entirely outside one frustum plane. Units refined in the
//! previous frame use a lower threshold (hysteresis) so a cut does not pop
//! back and forth at the threshold. `--distance-lod F` replaces the
//! projected-error test by the original design's distance rule: refine
//! while the eye is nearer than F × the node's cell diagonal.

use super::camera::{box_distance, Camera, Frustum};
use crate::mesh::Aabb;
use crate::store::{NodeRec, Slot, Store};
use glam::DVec3;
use std::collections::{BinaryHeap, HashSet};

/// A draw unit id: `2 × node + 1` for a leaf's original triangles, `2 × node`
/// for a node's simplified mesh.
pub type Unit = u32;

pub fn unit_of(node: usize, orig: bool) -> Unit {
    (2 * node + orig as usize) as Unit
}

/// What a unit is and where its payload lives.
#[derive(Clone, Debug)]
pub struct UnitInfo {
    pub node: u32,
    /// Pack file level (0 for originals).
    pub pack: u8,
    /// Level shown in statistics: 0 original, else the simplified level.
    pub level: u8,
    pub slot: Slot,
    /// Object-space error bound against the original (0 for originals).
    pub error: f64,
    /// Tight bounds of the node's original triangles.
    pub bounds: Aabb,
    /// Diagonal of the node's octree cell (distance-only mode).
    pub cell_diag: f64,
    /// Children units (indices into `Hierarchy::child_list`).
    pub first_child: u32,
    pub child_count: u32,
}

/// Draw units of a store and their refinement tree.
pub struct Hierarchy {
    pub units: std::collections::HashMap<Unit, UnitInfo>,
    pub child_list: Vec<Unit>,
    pub roots: Vec<Unit>,
    pub bounds: Aabb,
}

impl Hierarchy {
    pub fn new(store: &Store) -> Hierarchy {
        let nodes = &store.nodes;
        let mut h = Hierarchy { units: Default::default(), child_list: Vec::new(), roots: Vec::new(), bounds: Aabb::EMPTY };
        if nodes.is_empty() {
            return h;
        }
        h.bounds = nodes[0].content;
        h.roots = reps(nodes, 0);
        for (i, n) in nodes.iter().enumerate() {
            if n.subtree_tris == 0 {
                continue;
            }
            let info = |orig: bool, first_child: u32, child_count: u32| {
                let (slot, level) = if orig { (n.orig, 0) } else { (n.simp, n.level) };
                UnitInfo {
                    node: i as u32,
                    pack: level,
                    level,
                    slot,
                    error: slot.error as f64,
                    bounds: n.content,
                    cell_diag: n.cell.diagonal(),
                    first_child,
                    child_count,
                }
            };
            if !n.simp.is_empty() {
                // A leaf refines to its own originals, an inner node to its children.
                let kids: Vec<Unit> = if n.is_leaf() { leaf_original(n, i) } else { child_reps(nodes, n) };
                let first_child = h.child_list.len() as u32;
                h.child_list.extend(&kids);
                h.units.insert(unit_of(i, false), info(false, first_child, kids.len() as u32));
            }
            if n.is_leaf() && !n.orig.is_empty() {
                h.units.insert(unit_of(i, true), info(true, 0, 0));
            }
        }
        h
    }

    pub fn children(&self, u: Unit) -> &[Unit] {
        let i = &self.units[&u];
        &self.child_list[i.first_child as usize..(i.first_child + i.child_count) as usize]
    }

    /// Every original-triangle unit (level 0), for brute-force rendering.
    pub fn leaves(&self) -> Vec<Unit> {
        let mut v: Vec<Unit> = self.units.keys().copied().filter(|u| u & 1 == 1).collect();
        v.sort_unstable();
        v
    }

    /// Estimated bytes of a unit's GPU-ready mesh (see `DrawMesh::bytes`).
    pub fn draw_bytes(&self, u: Unit) -> u64 {
        let s = &self.units[&u].slot;
        s.verts as u64 * std::mem::size_of::<super::GpuVertex>() as u64 + s.tris as u64 * 12
    }
}

/// The units standing for node `i`: its simplified mesh, or (no simplified
/// mesh) its original triangles for a leaf, or its children's units.
fn reps(nodes: &[NodeRec], i: usize) -> Vec<Unit> {
    let n = &nodes[i];
    if n.subtree_tris == 0 {
        vec![]
    } else if !n.simp.is_empty() {
        vec![unit_of(i, false)]
    } else if n.is_leaf() {
        leaf_original(n, i)
    } else {
        child_reps(nodes, n)
    }
}

fn leaf_original(n: &NodeRec, i: usize) -> Vec<Unit> {
    if n.orig.is_empty() {
        vec![]
    } else {
        vec![unit_of(i, true)]
    }
}

fn child_reps(nodes: &[NodeRec], n: &NodeRec) -> Vec<Unit> {
    n.children.iter().filter(|&&c| c != crate::store::NO_NODE).flat_map(|&c| reps(nodes, c as usize)).collect()
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
    /// A unit refined last frame stays refined until its error falls below
    /// `hysteresis × max_error_px` (≤ 1).
    pub hysteresis: f64,
    /// Prefetch children of cut units whose error is within this factor of
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
    /// Units to draw, in traversal order.
    pub cut: Vec<Unit>,
    /// Every unit the traversal went through (cut and refined ancestors).
    pub visited: Vec<Unit>,
    /// Loads wanted now, highest priority first: (unit, priority).
    pub wanted: Vec<(Unit, f64)>,
    /// Loads worth doing if memory is free (prefetch), after `wanted`.
    pub prefetch: Vec<(Unit, f64)>,
    /// Triangles in the cut.
    pub triangles: u64,
    /// Largest projected error left in the cut (pixels; distance mode: 0/1).
    pub max_error_px: f64,
    /// Refinements stopped by the triangle budget.
    pub budget_limited: u32,
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

/// Per-frame selection state (the previous cut, for hysteresis).
pub struct Selector {
    pub opts: SelectOptions,
    prev_refined: HashSet<Unit>,
    prev_eye: Option<DVec3>,
}

impl Selector {
    pub fn new(opts: SelectOptions) -> Selector {
        Selector { opts, prev_refined: HashSet::new(), prev_eye: None }
    }

    /// The refinement priority of `u` seen from `eye` (pixels of projected
    /// error, or in distance mode the ratio cell size·F / distance).
    pub fn priority(&self, h: &Hierarchy, u: Unit, cam: &Camera, eye: DVec3, height_px: f64) -> f64 {
        let i = &h.units[&u];
        let d = box_distance(&i.bounds, eye);
        match self.opts.distance_lod {
            Some(f) => {
                if i.child_count == 0 {
                    0.0
                } else {
                    f * i.cell_diag / d.max(1e-12)
                }
            }
            None => i.error * cam.pixels_per_unit(d, height_px),
        }
    }

    fn threshold(&self) -> f64 {
        if self.opts.distance_lod.is_some() {
            1.0
        } else {
            self.opts.max_error_px
        }
    }

    /// Selects the cut for `cam`. `ready(u)` says whether unit `u` can be
    /// drawn now (resident on the GPU). Never waits for anything.
    pub fn select(
        &mut self,
        h: &Hierarchy,
        cam: &Camera,
        viewport: (u32, u32),
        ready: &dyn Fn(Unit) -> bool,
    ) -> Selection {
        let aspect = viewport.0 as f64 / viewport.1.max(1) as f64;
        let height = viewport.1.max(1) as f64;
        let frustum: Frustum = cam.frustum(aspect);
        let visible = |u: Unit| {
            let b = &h.units[&u].bounds;
            box_distance(b, cam.eye) == 0.0 || !frustum.culls(b)
        };
        // Camera motion: predict where the eye will be a few frames ahead.
        let predicted = match self.prev_eye {
            Some(p) => cam.eye + (cam.eye - p) * 8.0,
            None => cam.eye,
        };
        self.prev_eye = Some(cam.eye);
        let thr = self.threshold();
        let mut sel = Selection::default();
        let mut refined = HashSet::new();
        let mut heap = BinaryHeap::new();
        for &r in &h.roots {
            if visible(r) {
                sel.triangles += h.units[&r].slot.tris as u64;
                heap.push(Cand(self.priority(h, r, cam, cam.eye, height), r));
            }
        }
        while let Some(Cand(p, u)) = heap.pop() {
            sel.visited.push(u);
            let t = if self.prev_refined.contains(&u) { thr * self.opts.hysteresis } else { thr };
            let kids = h.children(u);
            if p <= t || kids.is_empty() {
                self.leave_in_cut(h, u, p, cam, predicted, height, &mut sel, ready);
                continue;
            }
            let vis: Vec<Unit> = kids.iter().copied().filter(|&c| visible(c)).collect();
            let extra: i64 = vis.iter().map(|&c| h.units[&c].slot.tris as i64).sum::<i64>() - h.units[&u].slot.tris as i64;
            if sel.triangles as i64 + extra > self.opts.tri_budget as i64 {
                sel.budget_limited += 1;
                self.leave_in_cut(h, u, p, cam, predicted, height, &mut sel, ready);
                continue;
            }
            let missing: Vec<Unit> = vis.iter().copied().filter(|&c| !ready(c)).collect();
            if !missing.is_empty() {
                for c in missing {
                    sel.wanted.push((c, p));
                }
                sel.cut.push(u);
                sel.max_error_px = sel.max_error_px.max(p);
                continue;
            }
            sel.triangles = (sel.triangles as i64 + extra) as u64;
            refined.insert(u);
            for c in vis {
                heap.push(Cand(self.priority(h, c, cam, cam.eye, height), c));
            }
        }
        // Nearest / largest error first.
        sel.wanted.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
        sel.prefetch.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
        self.prev_refined = refined;
        sel
    }

    #[allow(clippy::too_many_arguments)]
    fn leave_in_cut(
        &self,
        h: &Hierarchy,
        u: Unit,
        p: f64,
        cam: &Camera,
        predicted: DVec3,
        height: f64,
        sel: &mut Selection,
        ready: &dyn Fn(Unit) -> bool,
    ) {
        sel.cut.push(u);
        if !h.children(u).is_empty() {
            sel.max_error_px = sel.max_error_px.max(p);
            // Prefetch: close to the threshold now or at the predicted eye.
            let pp = p.max(self.priority(h, u, cam, predicted, height));
            if pp > self.threshold() * self.opts.prefetch {
                for &c in h.children(u) {
                    if !ready(c) {
                        sel.prefetch.push((c, pp));
                    }
                }
            }
        }
    }
}

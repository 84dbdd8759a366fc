//! The out-of-core viewer: selection, paging, rendering.
//!
//! Takes: an octolod store (`nodes.bin` in memory, node payloads read on
//! demand). Gives: a frame-by-frame cut of the octree drawn with wgpu, in a
//! window (`octolod view`) or offscreen (`octolod render`), never holding more
//! than the RAM budget and never waiting on disk during a frame.
//!
//! * [`camera`] — camera, frustum and projected-error maths (f64, rendered
//!   relative to the store's centre so far-from-origin data stays exact);
//! * [`select`] — per-frame best-first cut selection with hysteresis;
//! * [`cache`] — the budgeted node cache and its background I/O threads;
//! * [`viewer`] — one frame's CPU work (poll, upload, select, request) and statistics;
//! * [`gpu`] — the wgpu renderer (offscreen and window surface);
//! * [`image`] — PNG output and image comparison (PSNR, differing pixels);
//! * [`texture`] — the store's textures (one per material slot), mipmapped
//!   and fitted to the budget together (CPU only: `tiles` makes its
//!   per-level copies with it too); [`order_by_material`] groups a node's
//!   triangles by material so each draw binds one texture;
//! * [`headless`] — `octolod render`: camera paths, statistics, reference renders;
//! * [`window`] — `octolod view`: the interactive window;
//! * [`quiet`] — keeps libwayland's "no desktop session" line out of successful runs.
//!
//! The `view` cargo feature (on by default) holds the parts that need wgpu,
//! winit and PNG output: `gpu`, `overlay`, `image`, `headless`, `window`
//! and `quiet`. The rest (camera maths and paths, [`camera::Up`] and
//! [`camera::guess_up`], selection, cache, the frame loop, [`DrawMesh`],
//! [`DEFAULT_COLOR`]) is plain CPU code, always built: `tiles` and `gltf`
//! use it, and a `--no-default-features` build is the headless tool.

pub mod cache;
pub mod camera;
#[cfg(feature = "view")]
pub mod gpu;
#[cfg(feature = "view")]
pub mod headless;
#[cfg(feature = "view")]
pub mod image;
#[cfg(feature = "view")]
pub mod overlay;
#[cfg(feature = "view")]
pub mod quiet;
pub mod select;
pub mod texture;
pub mod viewer;
#[cfg(feature = "view")]
pub mod window;

pub use viewer::{FrameStats, ViewOptions, Viewer};

use crate::mesh::AttrSet;
use crate::mesh::IndexedMesh;

/// One vertex as the GPU sees it: position relative to the store's origin
/// (f32), unit normal, RGBA8 color. 28 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct GpuVertex {
    pub pos: [f32; 3],
    pub normal: [f32; 3],
    pub color: [u8; 4],
}

/// A node's mesh ready for upload.
#[derive(Clone, Debug, Default)]
pub struct DrawMesh {
    pub vertices: Vec<GpuVertex>,
    pub indices: Vec<u32>,
    /// The node's patches (triangle ranges by child), in index order.
    pub patches: Vec<crate::store::Patch>,
    /// Texture coordinates per vertex, when a texture is shown (else
    /// empty): a second vertex buffer, so untextured stores pay nothing.
    pub uvs: Vec<[f32; 2]>,
    /// The triangles' materials as runs in index order, when they choose
    /// among textures (see [`order_by_material`]); empty: every triangle
    /// uses texture 0.
    pub materials: Vec<MaterialRun>,
}

/// Consecutive triangles `first..first + count` that share `material` (a
/// texture slot, or [`crate::mesh::Vertex::NO_TEXTURE`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct MaterialRun {
    pub first: u32,
    pub count: u32,
    pub material: u16,
}

/// Orders the triangles of `indices` (three per triangle) by material
/// (`material` of a triangle's first corner: a triangle's corners agree)
/// and gives the runs, so a mesh is drawn with one draw per material.
/// The order changes only inside each of `keep`'s triangle ranges (a
/// node's patches, drawn or skipped as a whole) and between them, never
/// across their bounds, and is stable: triangles of one material keep
/// their order. Adjacent runs of one material are merged.
pub fn order_by_material(indices: &mut [u32], keep: &[crate::store::Patch], material: impl Fn(u32) -> u16) -> Vec<MaterialRun> {
    let n = indices.len() / 3;
    let tris: &mut [[u32; 3]] = bytemuck::cast_slice_mut(&mut indices[..n * 3]);
    let mut bounds: Vec<usize> = vec![0, n];
    for p in keep {
        bounds.push((p.first as usize).min(n));
        bounds.push((p.first as usize).saturating_add(p.count as usize).min(n));
    }
    bounds.sort_unstable();
    bounds.dedup();
    let mut runs: Vec<MaterialRun> = Vec::new();
    for w in bounds.windows(2) {
        let span = &mut tris[w[0]..w[1]];
        span.sort_by_key(|t| material(t[0]));
        for (k, t) in span.iter().enumerate() {
            let (at, m) = ((w[0] + k) as u32, material(t[0]));
            match runs.last_mut() {
                Some(r) if r.material == m && r.first + r.count == at => r.count += 1,
                _ => runs.push(MaterialRun { first: at, count: 1, material: m }),
            }
        }
    }
    runs
}

/// One mesh to draw and the triangle ranges of it to draw.
pub struct DrawItem<'a, M> {
    pub mesh: &'a M,
    pub ranges: Vec<std::ops::Range<u32>>,
}

impl<'a, M> DrawItem<'a, M> {
    /// All of a mesh with `tris` triangles.
    #[allow(clippy::single_range_in_vec_init, reason = "one draw range, not a Vec of 0..tris")]
    pub fn whole(mesh: &'a M, tris: u32) -> DrawItem<'a, M> {
        DrawItem { mesh, ranges: vec![0..tris] }
    }
}

/// Color used when the store has no vertex colors.
pub const DEFAULT_COLOR: [u8; 4] = [200, 200, 205, 255];

impl DrawMesh {
    /// Bytes this mesh occupies (CPU copy, or its GPU buffers once uploaded).
    pub fn bytes(&self) -> u64 {
        (self.vertices.len() * std::mem::size_of::<GpuVertex>() + self.indices.len() * 4 + self.uvs.len() * 8) as u64
    }
    pub fn triangles(&self) -> usize {
        self.indices.len() / 3
    }
}

/// Converts a decoded payload to GPU form. Positions become f32 relative to
/// `origin` (the same subtraction for every node, so vertices shared by
/// neighbouring nodes stay bit-identical and the surface stays watertight).
/// Normals are the payload's when it has them (the input's, or computed at
/// build time from each vertex's whole neighbourhood, so both sides of a
/// node seam shade alike), else area-weighted vertex normals of this mesh;
/// colors the input's, else [`DEFAULT_COLOR`]; uvs when `attrs` has them
/// (the viewer drops them from `attrs` unless it shows a texture), and
/// with them, when `attrs` has [`AttrSet::MATERIAL`], the triangles
/// ordered by material ([`order_by_material`]).
pub fn draw_mesh(m: &IndexedMesh, attrs: AttrSet, origin: [f64; 3]) -> DrawMesh {
    draw_mesh_keeping(m, &[], attrs, origin)
}

/// [`draw_mesh`], ordering triangles by material only within `patches`.
fn draw_mesh_keeping(m: &IndexedMesh, patches: &[crate::store::Patch], attrs: AttrSet, origin: [f64; 3]) -> DrawMesh {
    let mut vertices: Vec<GpuVertex> = m
        .vertices
        .iter()
        .map(|v| GpuVertex {
            pos: [0, 1, 2].map(|k| (v.pos[k] - origin[k]) as f32),
            normal: if attrs.normal() { v.normal } else { [0.0; 3] },
            color: if attrs.color() { v.color } else { DEFAULT_COLOR },
        })
        .collect();
    if !attrs.normal() {
        // Area-weighted sum, plus the largest incident face normal for
        // vertices where the sum cancels (folded or duplicated faces, which
        // simplification keeps to stay crack-free).
        let mut acc = vec![[0f64; 3]; vertices.len()];
        let mut big = vec![([0f64; 3], 0f64); vertices.len()];
        for t in &m.triangles {
            let p = t.map(|i| m.vertices[i as usize].pos);
            let e1 = [0, 1, 2].map(|k| p[1][k] - p[0][k]);
            let e2 = [0, 1, 2].map(|k| p[2][k] - p[0][k]);
            let n = [e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]];
            let len2 = n[0] * n[0] + n[1] * n[1] + n[2] * n[2];
            if len2.is_finite() {
                for &i in t {
                    let i = i as usize;
                    for k in 0..3 {
                        acc[i][k] += n[k];
                    }
                    if len2 > big[i].1 {
                        big[i] = (n, len2);
                    }
                }
            }
        }
        for ((v, a), (b, b2)) in vertices.iter_mut().zip(&acc).zip(&big) {
            let a2 = a[0] * a[0] + a[1] * a[1] + a[2] * a[2];
            v.normal = normalize(if a2 < 1e-4 * b2 { *b } else { *a });
        }
    } else {
        for v in &mut vertices {
            v.normal = normalize(v.normal.map(|x| x as f64));
        }
    }
    let mut indices: Vec<u32> = m.triangles.iter().flat_map(|t| t.iter().copied()).collect();
    let uvs = if attrs.uv() { m.vertices.iter().map(|v| v.uv).collect() } else { Vec::new() };
    let materials = if attrs.uv() && attrs.material() {
        order_by_material(&mut indices, patches, |i| m.vertices.get(i as usize).map_or(0, |v| v.material))
    } else {
        Vec::new()
    };
    DrawMesh { vertices, indices, patches: patches.to_vec(), uvs, materials }
}

/// [`draw_mesh`] of a decoded node payload, keeping its patches (its
/// triangles are ordered by material within each patch).
pub fn draw_node(nm: &crate::store::NodeMesh, attrs: AttrSet, origin: [f64; 3]) -> DrawMesh {
    draw_mesh_keeping(&nm.mesh, &nm.patches, attrs, origin)
}

fn normalize(a: [f64; 3]) -> [f32; 3] {
    let l = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
    if l > 0.0 && l.is_finite() {
        a.map(|x| (x / l) as f32)
    } else {
        [0.0, 0.0, 1.0]
    }
}

/// Something resident on the GPU (or standing in for it in tests) whose
/// bytes count against the RAM budget.
pub trait GpuBytes {
    fn gpu_bytes(&self) -> u64;
}

impl GpuBytes for DrawMesh {
    fn gpu_bytes(&self) -> u64 {
        self.bytes()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::Vertex;

    #[test]
    fn folded_faces_get_a_face_normal_not_a_default() {
        let v = |x: f64, y: f64| Vertex { pos: [x, y, 0.0], ..Vertex::default() };
        // A triangle and its mirror (opposite winding) on top of it: the
        // area-weighted sum cancels at every vertex.
        let m = IndexedMesh { vertices: vec![v(0.0, 0.0), v(1.0, 0.0), v(0.0, 1.0)], triangles: vec![[0, 1, 2], [0, 2, 1]] };
        let d = draw_mesh(&m, AttrSet::POSITION_ONLY, [0.0; 3]);
        for g in &d.vertices {
            assert!(g.normal[2].abs() > 0.999, "{:?}", g.normal);
        }
        // A plain fan: the usual smooth normal, positions relative to the origin.
        let m =
            IndexedMesh { vertices: vec![Vertex { pos: [10.0, 10.0, 1.0], ..Vertex::default() }, v(11.0, 10.0), v(10.0, 11.0)], triangles: vec![[0, 1, 2]] };
        let d = draw_mesh(&m, AttrSet::POSITION_ONLY, [10.0, 10.0, 0.0]);
        assert_eq!(d.vertices[0].pos, [0.0, 0.0, 1.0]);
        let n = d.vertices[0].normal;
        assert!(((n[0] * n[0] + n[1] * n[1] + n[2] * n[2]) - 1.0).abs() < 1e-6);
        assert_eq!(d.indices, vec![0, 1, 2]);
        assert_eq!(d.bytes(), 3 * 28 + 12);
    }

    /// Issue 32: triangles are ordered by material inside each patch (a
    /// patch is drawn or skipped whole, so its range must hold the same
    /// triangles), stably, and the runs name each triangle's material.
    #[test]
    fn triangles_are_ordered_by_material_within_patches() {
        use crate::store::Patch;
        // Vertex k's material (a triangle's corners agree; corner 0 decides).
        let mat = [2u16, 0, 0, 1, 1, Vertex::NO_TEXTURE, 2, 0];
        // Triangles named by their first corner; the other corners repeat it.
        let first = [0u32, 1, 3, 2, /* patch 2 */ 5, 4, 6, 7, /* outside */ 3, 1];
        let mut idx: Vec<u32> = first.iter().flat_map(|&v| [v, v, v]).collect();
        let keep = [Patch { child: 10, first: 0, count: 4 }, Patch { child: 11, first: 4, count: 4 }];
        let runs = order_by_material(&mut idx, &keep, |v| mat[v as usize]);
        let order: Vec<u32> = idx.chunks(3).map(|t| t[0]).collect();
        // Patch 1: materials 2,0,1,0 -> 0,0,1,2 (the two 0s keep their order);
        // patch 2: NO_TEXTURE,1,2,0 -> 0,1,2,NO_TEXTURE; then 1,0 -> 0,1.
        assert_eq!(order, vec![1, 2, 3, 0, 7, 4, 6, 5, 1, 3]);
        let r = |first, count, material| MaterialRun { first, count, material };
        assert_eq!(runs, vec![r(0, 2, 0), r(2, 1, 1), r(3, 1, 2), r(4, 1, 0), r(5, 1, 1), r(6, 1, 2), r(7, 1, Vertex::NO_TEXTURE), r(8, 1, 0), r(9, 1, 1)]);
        // Every patch holds the same triangles as before.
        for p in &keep {
            let mut was: Vec<u32> = first[p.first as usize..][..p.count as usize].to_vec();
            let mut now: Vec<u32> = order[p.first as usize..][..p.count as usize].to_vec();
            was.sort();
            now.sort();
            assert_eq!(was, now);
        }
        // Runs cover every triangle once, in order, and match its material.
        let mut at = 0;
        for x in &runs {
            assert_eq!(x.first, at);
            for t in x.first..x.first + x.count {
                assert_eq!(mat[order[t as usize] as usize], x.material);
            }
            at += x.count;
        }
        assert_eq!(at as usize, first.len());
        // Without patches, one order over all: runs of one material merge.
        let mut idx: Vec<u32> = first.iter().flat_map(|&v| [v, v, v]).collect();
        let runs = order_by_material(&mut idx, &[], |v| mat[v as usize]);
        assert_eq!(runs, vec![r(0, 4, 0), r(4, 3, 1), r(7, 2, 2), r(9, 1, Vertex::NO_TEXTURE)]);
    }

    #[test]
    fn draw_node_orders_by_material_only_when_textured_materials_are_drawn() {
        let v = |x: f64, material: u16| Vertex { pos: [x, 0.0, x * x], material, ..Vertex::default() };
        let vertices = vec![v(0.0, 1), v(1.0, 1), v(2.0, 1), v(3.0, 0), v(4.0, 0), v(5.0, 0)];
        let nm = crate::store::NodeMesh {
            mesh: IndexedMesh { vertices, triangles: vec![[0, 1, 2], [3, 4, 5]] },
            patches: vec![crate::store::Patch { child: 3, first: 0, count: 2 }],
        };
        let attrs = AttrSet::POSITION_ONLY.with(AttrSet::UV, true).with(AttrSet::MATERIAL, true);
        let d = draw_node(&nm, attrs, [0.0; 3]);
        assert_eq!(d.indices, vec![3, 4, 5, 0, 1, 2]);
        assert_eq!(d.materials, vec![MaterialRun { first: 0, count: 1, material: 0 }, MaterialRun { first: 1, count: 1, material: 1 }]);
        assert_eq!(d.patches, nm.patches);
        assert_eq!(d.uvs.len(), 6);
        // Shaded (no uvs), or a store without materials: as stored, no runs.
        for attrs in [AttrSet::POSITION_ONLY.with(AttrSet::MATERIAL, true), AttrSet::POSITION_ONLY.with(AttrSet::UV, true)] {
            let d = draw_node(&nm, attrs, [0.0; 3]);
            assert_eq!(d.indices, vec![0, 1, 2, 3, 4, 5]);
            assert!(d.materials.is_empty());
        }
    }
}

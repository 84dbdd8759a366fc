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
//! * [`texture`] — the store's texture, mipmapped and fitted to the budget
//!   (CPU only: `tiles` makes its per-level copies with it too);
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
/// (the viewer drops them from `attrs` unless it shows a texture).
pub fn draw_mesh(m: &IndexedMesh, attrs: AttrSet, origin: [f64; 3]) -> DrawMesh {
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
    let indices = m.triangles.iter().flat_map(|t| t.iter().copied()).collect();
    let uvs = if attrs.uv() { m.vertices.iter().map(|v| v.uv).collect() } else { Vec::new() };
    DrawMesh { vertices, indices, patches: Vec::new(), uvs }
}

/// [`draw_mesh`] of a decoded node payload, keeping its patches.
pub fn draw_node(nm: &crate::store::NodeMesh, attrs: AttrSet, origin: [f64; 3]) -> DrawMesh {
    let mut d = draw_mesh(&nm.mesh, attrs, origin);
    d.patches = nm.patches.clone();
    d
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
}

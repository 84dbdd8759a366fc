//! A many-island texture atlas laid over any mesh, as photogrammetry tools
//! make them: the surface is cut into islands (here the cells of a k×k×k
//! grid over the box, by triangle centroid), each island is projected on
//! the plane facing its mean normal and packed into its own square tile of
//! the atlas, and every vertex on an island border is split into one vertex
//! per island (a uv seam along every island border, positions identical).
//!
//! Takes: an indexed mesh and the grid's cells per axis. Gives: the mesh
//! with per-vertex uvs and split seams, and the atlas's tiles per side (a
//! uv's tile is `floor(uv × tiles)`, so a triangle whose corners lie in
//! different tiles bleeds across islands). Built in memory: test and bench
//! inputs, not billions of triangles.

use crate::mesh::{IndexedMesh, Vertex};
use std::collections::HashMap;

/// Margin kept free inside each tile (of its side), so corners a little
/// outside their island's cell stay in its tile.
const MARGIN: f64 = 0.15;

/// `mesh` with a `cells`³-island atlas (see the module doc); also the
/// tiles per atlas side.
pub fn atlas(mesh: &IndexedMesh, cells: u32) -> (IndexedMesh, u32) {
    let cells = cells.max(1);
    let mut bb = crate::mesh::Aabb::EMPTY;
    for v in &mesh.vertices {
        bb.add(v.pos);
    }
    let size = [0, 1, 2].map(|k| ((bb.max[k] - bb.min[k]) / cells as f64).max(f64::MIN_POSITIVE));
    let cell_of = |p: [f64; 3]| [0, 1, 2].map(|k| (((p[k] - bb.min[k]) / size[k]).floor() as i64).clamp(0, cells as i64 - 1) as u32);
    // Island per triangle: the cell of its centroid, numbered densely.
    let mut ids: HashMap<[u32; 3], u32> = HashMap::new();
    let mut island = Vec::with_capacity(mesh.triangles.len());
    let mut normal: Vec<[f64; 3]> = Vec::new();
    let mut cell_at: Vec<[u32; 3]> = Vec::new();
    for t in &mesh.triangles {
        let p = t.map(|v| mesh.vertices[v as usize].pos);
        let c = cell_of([0, 1, 2].map(|k| (p[0][k] + p[1][k] + p[2][k]) / 3.0));
        let n = ids.len() as u32;
        let id = *ids.entry(c).or_insert_with(|| {
            normal.push([0.0; 3]);
            cell_at.push(c);
            n
        });
        let e1 = crate::geom::sub(p[1], p[0]);
        let e2 = crate::geom::sub(p[2], p[0]);
        let cr = crate::geom::cross(e1, e2);
        for k in 0..3 {
            normal[id as usize][k] += cr[k];
        }
        island.push(id);
    }
    let tiles = (ids.len() as f64).sqrt().ceil().max(1.0) as u32;
    // Projection axes per island: the two not facing its mean normal.
    let axes: Vec<[usize; 2]> = normal
        .iter()
        .map(|n| {
            let d = (0..3).max_by(|&a, &b| n[a].abs().total_cmp(&n[b].abs())).unwrap();
            [(d + 1) % 3, (d + 2) % 3]
        })
        .collect();
    let mut out = IndexedMesh::default();
    let mut split: HashMap<(u32, u32), u32> = HashMap::new();
    for (t, &id) in mesh.triangles.iter().zip(&island) {
        let nt = t.map(|v| {
            *split.entry((v, id)).or_insert_with(|| {
                let src = &mesh.vertices[v as usize];
                let (c, ax) = (cell_at[id as usize], axes[id as usize]);
                let (tx, ty) = (id % tiles, id / tiles);
                let local = ax.map(|k| (src.pos[k] - (bb.min[k] + c[k] as f64 * size[k])) / size[k]);
                let u = (tx as f64 + MARGIN + (1.0 - 2.0 * MARGIN) * local[0]) / tiles as f64;
                let w = (ty as f64 + MARGIN + (1.0 - 2.0 * MARGIN) * local[1]) / tiles as f64;
                out.vertices.push(Vertex { uv: [u as f32, w as f32], ..*src });
                out.vertices.len() as u32 - 1
            })
        });
        out.triangles.push(nt);
    }
    (out, tiles)
}

/// The atlas tile a uv lies in.
pub fn tile(uv: [f32; 2], tiles: u32) -> (i64, i64) {
    ((uv[0] as f64 * tiles as f64).floor() as i64, (uv[1] as f64 * tiles as f64).floor() as i64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gen::{GenOptions, Generator, Shape};
    use crate::mesh::AttrSet;

    #[test]
    fn islands_are_split_along_their_borders_and_tiled() {
        let (vertices, triangles) = Generator::new(&GenOptions { shape: Shape::Sphere, tris: 4000, attrs: AttrSet(AttrSet::UV), ..Default::default() }).mesh();
        let m = IndexedMesh { vertices, triangles };
        let (a, tiles) = atlas(&m, 4);
        assert_eq!(a.triangles.len(), m.triangles.len());
        assert!(a.vertices.len() > m.vertices.len() + 100, "{} vertices from {}", a.vertices.len(), m.vertices.len());
        assert!(tiles >= 4, "{tiles} tiles per side");
        // Same positions, every triangle inside one tile.
        for (t, s) in a.triangles.iter().zip(&m.triangles) {
            for k in 0..3 {
                assert_eq!(a.vertices[t[k] as usize].pos, m.vertices[s[k] as usize].pos);
            }
            let c = t.map(|v| tile(a.vertices[v as usize].uv, tiles));
            assert!(c[0] == c[1] && c[1] == c[2], "a triangle across tiles {c:?}");
        }
    }
}

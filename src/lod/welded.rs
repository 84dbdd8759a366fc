//! A node's vertices welded by position: what the level builder locks,
//! shares and derives normals from.

use super::chunks::Gathered;
use crate::geom::{cross, sub, Welder};
use crate::mesh::{Aabb, IndexedMesh};

/// A node's vertices welded by position: per position its point, the
/// area-weighted normal of its triangles in the node, the vertices there
/// (several: an attribute seam), its bounds.
pub(super) struct Welded {
    pub pos: Vec<[f64; 3]>,
    pub pos_of: Vec<u32>,
    pub normal: Vec<[f64; 3]>,
    /// Vertices per position: `members[first[p]..first[p+1]]`.
    first: Vec<u32>,
    members: Vec<u32>,
    pub bounds: Aabb,
}

impl Welded {
    /// `unique`: no two vertices of `m` share a position (a gathered node
    /// without attributes), so none is looked up.
    pub fn new(m: &IndexedMesh, unique: bool) -> Welded {
        let mut pos = Vec::new();
        let pos_of: Vec<u32> = if unique {
            pos.extend(m.vertices.iter().map(|v| v.pos));
            (0..m.vertices.len() as u32).collect()
        } else {
            let mut weld = Welder::with_capacity(m.vertices.len());
            m.vertices.iter().map(|v| weld.id(v.pos, |p| pos.push(p))).collect()
        };
        let (count, members) = if unique {
            // One vertex a position: the lists are the identity.
            ((0..=pos.len() as u32).collect(), (0..pos.len() as u32).collect())
        } else {
            let mut count = vec![0u32; pos.len() + 1];
            for &p in &pos_of {
                count[p as usize + 1] += 1;
            }
            for i in 0..pos.len() {
                count[i + 1] += count[i];
            }
            let mut members = vec![0u32; pos_of.len()];
            let mut next = count.clone();
            for (v, &p) in pos_of.iter().enumerate() {
                members[next[p as usize] as usize] = v as u32;
                next[p as usize] += 1;
            }
            (count, members)
        };
        let mut normal = vec![[0.0; 3]; pos.len()];
        // The bounds: of the vertices used (`super::used_bounds`).
        let mut used = vec![false; m.vertices.len()];
        for t in &m.triangles {
            let c = t.map(|v| m.vertices[v as usize].pos);
            for &v in t {
                used[v as usize] = true;
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
        Welded { pos, pos_of, normal, first: count, members, bounds: super::used_bounds(m, &used) }
    }

    /// Per vertex: locked (its position is shared). Attribute seams are not
    /// locked: the simplifier moves their wedges together.
    #[cfg(test)]
    pub fn locks(&self, shared: &super::shared::SharedSet) -> Vec<bool> {
        self.locks_at(|p| shared.contains_key(&crate::geom::pos_bits(self.pos[p])))
    }

    /// [`Welded::locks`], given whether position `p` is shared.
    pub fn locks_at(&self, is_shared: impl Fn(usize) -> bool) -> Vec<bool> {
        let at: Vec<bool> = (0..self.pos.len()).map(is_shared).collect();
        self.pos_of.iter().map(|&p| at[p as usize]).collect()
    }

    fn verts_at(&self, p: usize) -> &[u32] {
        &self.members[self.first[p] as usize..self.first[p + 1] as usize]
    }

    /// Position `p` was locked when the level below was simplified.
    pub fn was_locked(&self, g: &Gathered, p: usize) -> bool {
        !g.was_locked.is_empty() && self.verts_at(p).iter().any(|&v| g.was_locked[v as usize])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::pos_bits;
    use crate::lod::shared::SharedSet;
    use crate::mesh::Vertex;

    #[test]
    fn shared_positions_lock_every_variant_and_seams_stay_free() {
        // Two triangles sharing an edge whose second copy of vertex 1 has another uv (a seam).
        let v = |p: [f64; 3], u: f32| Vertex { pos: p, uv: [u, 0.0], ..Default::default() };
        let m = IndexedMesh {
            vertices: vec![v([0.0; 3], 0.0), v([1.0, 0.0, 0.0], 0.0), v([0.0, 1.0, 0.0], 0.0), v([1.0, 0.0, 0.0], 0.5), v([1.0, 1.0, 0.0], 0.0)],
            triangles: vec![[0, 1, 2], [3, 4, 2]],
        };
        let w = Welded::new(&m, false);
        assert_eq!(w.pos.len(), 4);
        assert_eq!(w.pos_of, [0, 1, 2, 1, 3]);
        assert_eq!(w.verts_at(1), [1, 3]);
        // Both triangles face +z: every position's normal points up.
        assert!(w.normal.iter().all(|n| n[2] > 0.0 && n[0] == 0.0 && n[1] == 0.0));
        assert_eq!(w.bounds.max, [1.0, 1.0, 0.0]);
        // A seam is not locked; a shared position locks every variant.
        assert_eq!(w.locks_at(|_| false), [false; 5]);
        assert_eq!(w.locks_at(|p| p == 3), [false, false, false, false, true]);
        assert_eq!(w.locks_at(|p| p == 1), [false, true, false, true, false]);
        let mut shared = SharedSet::default();
        shared.insert(pos_bits([0.0; 3]), ([0.0; 3], 0));
        assert_eq!(w.locks(&shared), [true, false, false, false, false]);
        // Unique positions (no attributes): no lookup, no seam.
        let u = Welded::new(&IndexedMesh { vertices: m.vertices[..3].to_vec(), triangles: vec![[0, 1, 2]] }, true);
        assert_eq!(u.pos_of, [0, 1, 2]);
        assert!((0..3).all(|p| u.verts_at(p).len() == 1));
    }
}

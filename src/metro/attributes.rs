//! Attribute error at the closest point (`octolod metro --attributes`):
//! how far a simplified mesh's uvs and colours are from the input's where
//! the surfaces meet, as the generalized-quadric papers report it, so a
//! claim about attributes is measured, not assumed.
//!
//! Takes: both operands whole with their attributes (a PLY, per-wedge uvs
//! split; a store level's nodes), samples per direction and the seed.
//! Gives: per direction and combined, the max, mean and RMS of the uv
//! difference (Euclidean, in uv units: 1 = the texture's width) and of the
//! colour difference (Euclidean over RGB in [0, 1]), for the attributes
//! both operands have. Samples: every used vertex of the source, then
//! uniform points of its triangles in proportion to their area; each one's
//! attributes interpolated on its source triangle, compared with the
//! target's interpolated at the closest point. Where both sides of a seam
//! meet, the closest point is ambiguous (a uv across the atlas at the same
//! distance): the best match among the triangles within twice the closest
//! distance counts, uv and colour each. Deterministic for a seed (fixed jobs, summed in order). In
//! memory only: both operands are held whole.

use crate::geom::{mix64, Bvh, Mesh, P3};
use crate::mesh::{AttrSet, IndexedMesh, Vertex};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Max, mean and RMS of one attribute's differences.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct AttrFigures {
    pub max: f64,
    pub mean: f64,
    pub rms: f64,
}

/// One direction's (or both's) attribute figures.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct AttrDirection {
    pub samples: u64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub uv: Option<AttrFigures>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub color: Option<AttrFigures>,
}

/// The `attributes` object of a metro report.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct AttrReport {
    pub a_to_b: AttrDirection,
    pub b_to_a: AttrDirection,
    pub combined: AttrDirection,
}

/// Sums of one attribute's differences.
#[derive(Clone, Copy, Default)]
struct Sums {
    max: f64,
    sum: f64,
    sum2: f64,
}

impl Sums {
    fn add(&mut self, d: f64) {
        self.max = self.max.max(d);
        self.sum += d;
        self.sum2 += d * d;
    }
    fn merge(&mut self, o: &Sums) {
        self.max = self.max.max(o.max);
        self.sum += o.sum;
        self.sum2 += o.sum2;
    }
    fn figures(&self, n: u64) -> AttrFigures {
        let n = n.max(1) as f64;
        AttrFigures { max: self.max, mean: self.sum / n, rms: (self.sum2 / n).sqrt() }
    }
}

/// Triangles per job (fixed: results do not depend on threads).
const JOB: usize = 4096;

/// Both directions' attribute differences between `a` and `b` for the
/// attributes in `attrs` (uv, colour; others are ignored), `samples` per
/// direction. None when neither attribute is in `attrs`.
pub fn attribute_errors(a: &IndexedMesh, b: &IndexedMesh, attrs: AttrSet, samples: u64, seed: u64) -> Option<AttrReport> {
    if !attrs.uv() && !attrs.color() {
        return None;
    }
    let (ab, s_ab) = one_way(a, b, attrs, samples, seed ^ 0xa7);
    let (ba, s_ba) = one_way(b, a, attrs, samples, seed ^ 0xb7);
    let dir = |s: &[Sums; 2], n: u64| AttrDirection { samples: n, uv: attrs.uv().then(|| s[0].figures(n)), color: attrs.color().then(|| s[1].figures(n)) };
    let mut both = s_ab;
    both[0].merge(&s_ba[0]);
    both[1].merge(&s_ba[1]);
    Some(AttrReport { a_to_b: dir(&s_ab, ab), b_to_a: dir(&s_ba, ba), combined: dir(&both, ab + ba) })
}

/// Samples on `src`, attributes compared with `dst`'s at the closest
/// point: (samples, [uv sums, colour sums]).
fn one_way(src: &IndexedMesh, dst: &IndexedMesh, attrs: AttrSet, samples: u64, seed: u64) -> (u64, [Sums; 2]) {
    let geo = Mesh::from_vertices(&dst.vertices, dst.triangles.clone());
    let bvh = Bvh::new(&geo);
    let tol = 1e-6 * geo.bbox().diagonal();
    let area = |t: &[u32; 3]| {
        let p = t.map(|v| src.vertices[v as usize].pos);
        let c = crate::geom::cross(crate::geom::sub(p[1], p[0]), crate::geom::sub(p[2], p[0]));
        0.5 * crate::geom::dot(c, c).sqrt()
    };
    let total: f64 = src.triangles.iter().map(area).filter(|a| a.is_finite()).sum();
    // Vertices first (each once, at its first triangle corner), then faces.
    let mut first_use = vec![u32::MAX; src.vertices.len()];
    for (ti, t) in src.triangles.iter().enumerate() {
        for &v in t {
            if first_use[v as usize] == u32::MAX {
                first_use[v as usize] = ti as u32;
            }
        }
    }
    let used = first_use.iter().filter(|&&t| t != u32::MAX).count() as u64;
    let faces = samples.saturating_sub(used) as f64;
    let jobs: Vec<(u64, [Sums; 2])> = src
        .triangles
        .par_chunks(JOB)
        .enumerate()
        .map(|(j, chunk)| {
            let mut n = 0u64;
            let mut s = [Sums::default(); 2];
            let mut take = |p: P3, x: &Vertex| {
                let Some(c) = bvh.closest(p) else { return };
                // At an attribute seam the closest point is ambiguous (both
                // sides meet there, and a simplified seam lies a little
                // off): every triangle within twice the closest distance
                // (or a millionth of the box) is a candidate, and the
                // best-matching one's attributes count.
                let r = (2.0 * c.dist2.sqrt()).max(tol);
                let (mut du, mut dc) = diff(x, &interpolate(dst, dst.triangles[c.triangle as usize], c.point));
                if du > 0.0 || dc > 0.0 {
                    bvh.within(p, r * r, |t, q, _| {
                        let (u, k) = diff(x, &interpolate(dst, dst.triangles[t as usize], q));
                        du = du.min(u);
                        dc = dc.min(k);
                    });
                }
                if attrs.uv() {
                    s[0].add(du);
                }
                if attrs.color() {
                    s[1].add(dc);
                }
                n += 1;
            };
            for (k, t) in chunk.iter().enumerate() {
                let ti = (j * JOB + k) as u32;
                for &v in t {
                    if first_use[v as usize] == ti && t.iter().position(|&w| w == v) == t.iter().rposition(|&w| w == v) {
                        let x = src.vertices[v as usize];
                        take(x.pos, &x);
                    }
                }
                let a = area(t);
                if !(a > 0.0 && total > 0.0) {
                    continue;
                }
                // Expected a × faces / total samples: the whole part, and
                // one more with the fraction's probability.
                let want = a / total * faces;
                let h = mix64(seed ^ mix64(ti as u64));
                let extra = ((h >> 11) as f64 / (1u64 << 53) as f64) < want.fract();
                let count = want.floor() as u64 + extra as u64;
                for i in 0..count {
                    let r = mix64(h ^ mix64(i + 1));
                    let (mut u, mut w) = ((r >> 40) as f64 / (1u64 << 24) as f64, ((r >> 16) & 0xff_ffff) as f64 / (1u64 << 24) as f64);
                    if u + w > 1.0 {
                        (u, w) = (1.0 - u, 1.0 - w);
                    }
                    let x = blend(src, *t, [1.0 - u - w, u, w]);
                    take(x.pos, &x);
                }
            }
            (n, s)
        })
        .collect();
    let mut n = 0;
    let mut s = [Sums::default(); 2];
    for (jn, js) in &jobs {
        n += jn;
        s[0].merge(&js[0]);
        s[1].merge(&js[1]);
    }
    (n, s)
}

/// The vertex at barycentric `w` of triangle `t` (position, uv, colour).
fn blend(m: &IndexedMesh, t: [u32; 3], w: [f64; 3]) -> Vertex {
    let v = t.map(|i| m.vertices[i as usize]);
    let mut out = v[0];
    out.pos = [0, 1, 2].map(|k| w[0] * v[0].pos[k] + w[1] * v[1].pos[k] + w[2] * v[2].pos[k]);
    out.uv = [0, 1].map(|k| (w[0] * v[0].uv[k] as f64 + w[1] * v[1].uv[k] as f64 + w[2] * v[2].uv[k] as f64) as f32);
    for k in 0..3 {
        out.color[k] = (w[0] * v[0].color[k] as f64 + w[1] * v[1].color[k] as f64 + w[2] * v[2].color[k] as f64).round().clamp(0.0, 255.0) as u8;
    }
    out
}

/// `dst`'s attributes at point `p` of its triangle `t` (barycentric).
fn interpolate(dst: &IndexedMesh, t: [u32; 3], p: P3) -> Vertex {
    let [a, b, c] = t.map(|i| dst.vertices[i as usize].pos);
    let (v0, v1, v2) = (crate::geom::sub(b, a), crate::geom::sub(c, a), crate::geom::sub(p, a));
    let dot = crate::geom::dot;
    let (d00, d01, d11, d20, d21) = (dot(v0, v0), dot(v0, v1), dot(v1, v1), dot(v2, v0), dot(v2, v1));
    let den = d00 * d11 - d01 * d01;
    let (u, w) = if den.abs() > 0.0 && den.is_finite() { ((d11 * d20 - d01 * d21) / den, (d00 * d21 - d01 * d20) / den) } else { (0.0, 0.0) };
    let (u, w) = (u.clamp(0.0, 1.0), w.clamp(0.0, 1.0));
    let s = (u + w).max(1.0);
    blend(dst, t, [1.0 - (u + w) / s, u / s, w / s])
}

/// (uv distance, colour distance in [0, 1] RGB) of two vertices.
fn diff(x: &Vertex, y: &Vertex) -> (f64, f64) {
    let du = ((x.uv[0] - y.uv[0]) as f64).hypot((x.uv[1] - y.uv[1]) as f64);
    let dc = (0..3).map(|k| ((x.color[k] as f64 - y.color[k] as f64) / 255.0).powi(2)).sum::<f64>().sqrt();
    (du, dc)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A flat grid with uv = (x, y) and colour red = 255 x.
    fn grid(n: u32, shift_uv: f32) -> IndexedMesh {
        let mut m = IndexedMesh::default();
        for j in 0..=n {
            for i in 0..=n {
                let (x, y) = (i as f64 / n as f64, j as f64 / n as f64);
                m.vertices.push(Vertex {
                    pos: [x, y, 0.0],
                    uv: [x as f32 + shift_uv, y as f32],
                    color: [(255.0 * x).round() as u8, 0, 0, 255],
                    ..Default::default()
                });
            }
        }
        m.triangles = crate::geom::grid_triangles(n);
        m
    }

    #[test]
    fn linear_attributes_measure_zero_and_a_shift_measures_itself() {
        let attrs = AttrSet(AttrSet::UV | AttrSet::COLOR);
        // A finer grid of the same linear attributes: zero up to rounding.
        let r = attribute_errors(&grid(8, 0.0), &grid(20, 0.0), attrs, 50_000, 1).unwrap();
        assert!(r.combined.uv.unwrap().max < 1e-5, "{r:?}");
        assert!(r.combined.color.unwrap().max <= 1.5 / 255.0 * 1.8, "{r:?}");
        assert!(r.combined.samples >= 2 * 50_000 - 2, "{r:?}");
        // uvs shifted by 0.01: every sample measures 0.01.
        let r = attribute_errors(&grid(8, 0.0), &grid(8, 0.01), attrs, 20_000, 1).unwrap();
        let uv = r.combined.uv.unwrap();
        assert!((uv.mean - 0.01).abs() < 1e-6 && (uv.max - 0.01).abs() < 1e-6, "{uv:?}");
        // Same seed, same figures; another seed, other face samples.
        let again = attribute_errors(&grid(8, 0.0), &grid(20, 0.0), attrs, 50_000, 1).unwrap();
        assert_eq!(attribute_errors(&grid(8, 0.0), &grid(20, 0.0), attrs, 50_000, 1).unwrap(), again);
        assert!(attribute_errors(&grid(8, 0.0), &grid(8, 0.0), AttrSet::default(), 100, 1).is_none());
    }
}

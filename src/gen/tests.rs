//! The generator's tests: counts, closedness, the hard cases, determinism,
//! the portable trigonometry and the streamed PLY.

use super::portable::{fcos, fsin};
use super::write::stream;
use super::*;
use crate::ply::write::{PlyWriteOptions, PlyWriter};
use crate::ply::Encoding;
use std::collections::HashMap;

fn gen(shape: Shape, tris: u64, seed: u64, attrs: u32) -> Generator {
    Generator::new(&GenOptions { shape, tris, seed, attrs: AttrSet(attrs) })
}

const ALL_ATTRS: u32 = AttrSet::NORMAL | AttrSet::COLOR | AttrSet::ALPHA | AttrSet::UV | AttrSet::POS_F64;

/// Directed edge counts.
fn edges(faces: &[[u32; 3]]) -> HashMap<(u32, u32), u32> {
    let mut m = HashMap::new();
    for f in faces {
        for k in 0..3 {
            *m.entry((f[k], f[(k + 1) % 3])).or_insert(0) += 1;
        }
    }
    m
}

/// Every edge used by exactly two faces, in opposite directions.
fn assert_closed_oriented(faces: &[[u32; 3]]) {
    let e = edges(faces);
    for (&(a, b), &n) in &e {
        assert_eq!(n, 1, "directed edge {a}->{b} used {n} times");
        assert_eq!(e.get(&(b, a)), Some(&1), "edge {a}-{b} has no opposite");
    }
    let mut und: HashMap<(u32, u32), u32> = HashMap::new();
    for &(a, b) in e.keys() {
        *und.entry((a.min(b), a.max(b))).or_insert(0) += 1;
    }
    assert!(und.values().all(|&n| n == 2));
}

fn all_referenced(nv: u64, faces: &[[u32; 3]]) -> bool {
    let mut used = vec![false; nv as usize];
    for f in faces {
        for &i in f {
            used[i as usize] = true;
        }
    }
    used.iter().all(|&u| u)
}

#[test]
fn counts_are_close_to_target() {
    for shape in Shape::ALL {
        for tris in [1000u64, 4321, 12_345, 100_000] {
            let g = gen(shape, tris, 7, 0);
            let nf = g.face_count();
            if shape == Shape::Single {
                assert_eq!((nf, g.vertex_count()), (1, 3));
                continue;
            }
            let err = nf.abs_diff(tris) as f64 / tris as f64;
            assert!(err <= 0.012, "{shape:?} tris {tris}: got {nf} ({:.2}%)", 100.0 * err);
        }
        // Tiny targets still give a valid mesh.
        for tris in [0u64, 1, 2, 5] {
            let g = gen(shape, tris, 7, 0);
            assert!(g.face_count() >= 1 && g.vertex_count() >= 3, "{shape:?} {tris}");
            let (v, f) = g.mesh();
            assert!(f.iter().flatten().all(|&i| (i as usize) < v.len()));
        }
    }
}

#[test]
fn large_targets_are_cheap_and_close() {
    for shape in Shape::ALL {
        for tris in [10_000_000u64, 1_000_000_000] {
            let g = gen(shape, tris, 1, 0);
            if shape != Shape::Single {
                let err = g.face_count().abs_diff(tris) as f64 / tris as f64;
                assert!(err < 0.01, "{shape:?} {tris}: {}", g.face_count());
            }
            assert!(g.vertex_count() <= u32::MAX as u64);
            // The last vertex and face are valid.
            let v = g.vertex(g.vertex_count() - 1);
            assert!(v.pos.iter().all(|c| c.is_finite()));
            let f = g.face(g.face_count() - 1);
            assert!(f.iter().all(|&i| (i as u64) < g.vertex_count()), "{shape:?} {f:?}");
        }
    }
}

#[test]
fn vertices_finite_indices_valid_attributes_sane() {
    for shape in Shape::ALL {
        let g = gen(shape, 3000, 3, ALL_ATTRS);
        let (vs, fs) = g.mesh();
        assert_eq!(vs.len() as u64, g.vertex_count());
        assert_eq!(fs.len() as u64, g.face_count());
        for v in &vs {
            assert!(v.pos.iter().all(|c| c.is_finite()), "{shape:?}");
            let l: f32 = v.normal.iter().map(|c| c * c).sum::<f32>().sqrt();
            assert!((l - 1.0).abs() < 1e-5, "{shape:?} normal {:?}", v.normal);
            assert!(v.uv.iter().all(|c| c.is_finite()));
        }
        assert!(fs.iter().flatten().all(|&i| (i as u64) < g.vertex_count()), "{shape:?}");
        // A scan keeps the vertices of its dropped cells, as scanners write them.
        assert_eq!(all_referenced(g.vertex_count(), &fs), shape != Shape::Scan, "{shape:?}: unreferenced vertices");
        if matches!(shape, Shape::Sphere | Shape::Terrain | Shape::Plane | Shape::Cylinder | Shape::Sheets | Shape::Open | Shape::Instances) {
            assert!(fs.iter().all(|f| f[0] != f[1] && f[1] != f[2] && f[0] != f[2]), "{shape:?} repeats an index");
        }
        // Alpha varies when requested, and is 255 otherwise.
        assert!(vs.iter().any(|v| v.color[3] != 255) || shape == Shape::Single);
        let g2 = gen(shape, 3000, 3, AttrSet::COLOR);
        assert!(g2.vertex(0).color[3] == 255 && g2.vertex(0).normal == [0.0; 3]);
    }
}

#[test]
fn sphere_like_meshes_are_closed() {
    for tris in [12u64, 100, 1000, 5000] {
        let g = gen(Shape::Sphere, tris, 1, 0);
        let (vs, fs) = g.mesh();
        assert_closed_oriented(&fs);
        // Euler characteristic of a sphere.
        assert_eq!(vs.len() as i64 - (fs.len() as i64 * 3 / 2) + fs.len() as i64, 2);
        // Outward: signed volume positive, close to that of a unit ball.
        let vol: f64 = fs
            .iter()
            .map(|f| {
                let [a, b, c] = f.map(|i| vs[i as usize].pos);
                let cr = [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
                dot(cr, c) / 6.0
            })
            .sum();
        if tris >= 1000 {
            assert!((vol - 4.0 / 3.0 * PI).abs() < 0.5, "volume {vol}");
        } else {
            assert!(vol > 0.5);
        }
        // No two vertices at the same place.
        let mut ps: Vec<[u64; 3]> = vs.iter().map(|v| v.pos.map(f64::to_bits)).collect();
        ps.sort();
        ps.dedup();
        assert_eq!(ps.len(), vs.len());
    }
    for tris in [50u64, 1000, 3000] {
        assert_closed_oriented(&gen(Shape::Instances, tris, 5, 0).mesh().1);
        assert_closed_oriented(&gen(Shape::Offset, tris, 5, 0).mesh().1);
    }
}

#[test]
fn open_shapes_have_borders() {
    for shape in [Shape::Open, Shape::Terrain, Shape::Plane, Shape::Cylinder, Shape::Sheets] {
        let (_, fs) = gen(shape, 2000, 1, 0).mesh();
        let e = edges(&fs);
        let border = e.keys().filter(|&&(a, b)| !e.contains_key(&(b, a))).count();
        assert!(border > 0, "{shape:?}");
        assert!(e.values().all(|&n| n == 1), "{shape:?}: a directed edge is used twice");
    }
}

#[test]
fn hard_cases_are_what_they_claim() {
    // Duplicates: each face exactly twice, the half a closed mesh.
    let (_, fs) = gen(Shape::Duplicates, 2000, 1, 0).mesh();
    let half = fs.len() / 2;
    assert_eq!(&fs[..half], &fs[half..]);
    assert_closed_oriented(&fs[..half]);
    // Slivers: thin strips and zero-area triangles with distinct indices.
    let (vs, fs) = gen(Shape::Slivers, 2000, 1, 0).mesh();
    let mut degenerate = 0;
    let mut min_aspect = f64::INFINITY;
    for f in &fs {
        assert!(f[0] != f[1] && f[1] != f[2] && f[0] != f[2]);
        let [a, b, c] = f.map(|i| vs[i as usize].pos);
        let area2 = ((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])).abs();
        if area2 == 0.0 {
            degenerate += 1;
        } else {
            let longest = [(a, b), (b, c), (c, a)].iter().map(|(p, q)| ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2)).sqrt()).fold(0.0, f64::max);
            min_aspect = min_aspect.min(area2 / (longest * longest));
        }
    }
    assert!(degenerate > 0);
    assert!(min_aspect < 1e-5, "{min_aspect}");
    // Sheets: two layers 1e-4 apart.
    let (vs, _) = gen(Shape::Sheets, 1000, 1, 0).mesh();
    let zs: std::collections::BTreeSet<u64> = vs.iter().map(|v| v.pos[2].to_bits()).collect();
    assert_eq!(zs.len(), 2);
    // Plane: flat.
    assert!(gen(Shape::Plane, 1000, 1, 0).mesh().0.iter().all(|v| v.pos[2] == 0.0));
    // Cylinder: radius 1.
    for v in gen(Shape::Cylinder, 1000, 1, 0).mesh().0 {
        assert!(((v.pos[0].powi(2) + v.pos[1].powi(2)).sqrt() - 1.0).abs() < 1e-8 && v.pos[2].abs() <= 1.0);
    }
    // Offset: near 1e6 with sub-1e-2 detail.
    let g = gen(Shape::Offset, 2000, 1, AttrSet::POS_F64);
    for v in g.mesh().0 {
        let r = v.pos.map(|c| c - 1e6);
        assert!(v.pos.iter().all(|&c| (c - 1e6).abs() < 0.6));
        assert!((dot(r, r).sqrt() - 0.5).abs() < 0.01);
    }
    // Fan: one edge shared by many triangles.
    let (_, fs) = gen(Shape::Fan, 1000, 1, 0).mesh();
    let spine = fs.iter().filter(|f| f.contains(&0) && f.contains(&1)).count();
    assert!(spine >= 400);
    let single = gen(Shape::Single, 1_000_000, 1, 0);
    assert_eq!(single.mesh().1, vec![[0, 1, 2]]);
}

#[test]
fn deterministic_per_seed() {
    for shape in Shape::ALL {
        let a = gen(shape, 5000, 42, ALL_ATTRS).mesh();
        let b = gen(shape, 5000, 42, ALL_ATTRS).mesh();
        assert_eq!(a, b, "{shape:?}");
    }
    for shape in [Shape::Sphere, Shape::Terrain, Shape::Instances, Shape::Offset, Shape::Open, Shape::Duplicates] {
        let a = gen(shape, 5000, 1, 0).mesh();
        let b = gen(shape, 5000, 2, 0).mesh();
        assert_eq!(a.1, b.1, "{shape:?}: connectivity does not depend on the seed");
        assert_ne!(a.0, b.0, "{shape:?}: seed changes nothing");
    }
    // Random access agrees with sequential generation.
    let g = gen(Shape::Instances, 5000, 9, ALL_ATTRS);
    let (vs, fs) = g.mesh();
    for i in (0..vs.len()).rev().step_by(97) {
        assert_eq!(g.vertex(i as u64), vs[i]);
    }
    for j in (0..fs.len()).rev().step_by(89) {
        assert_eq!(g.face(j as u64), fs[j]);
    }
}

#[test]
fn fast_sin_is_accurate() {
    for k in -2000..2000 {
        let x = k as f64 * 0.01237;
        assert!((fsin(x) - x.sin()).abs() < 1e-9, "{x}");
        assert!((fcos(x) - x.cos()).abs() < 1e-9, "{x}");
    }
}

#[test]
fn streamed_file_matches_in_memory_mesh() {
    let d = tempfile::tempdir().unwrap();
    for encoding in [Encoding::BinaryLe, Encoding::BinaryBe, Encoding::Ascii] {
        let opts = GenOptions { shape: Shape::Sphere, tris: 5000, seed: 3, attrs: AttrSet(ALL_ATTRS) };
        let wopts = PlyWriteOptions { encoding, ..Default::default() };
        let p = d.path().join("s.ply");
        let n = write(&opts, &wopts, &p, true, true).unwrap();
        let bytes = std::fs::read(&p).unwrap();
        assert_eq!(n as usize, bytes.len());
        let (vs, fs) = Generator::new(&opts).mesh();
        let mut expect = Vec::new();
        crate::ply::write::write_ply(&d.path().join("m.ply"), &PlyWriteOptions { attrs: opts.attrs, ..wopts.clone() }, &vs, &fs).unwrap();
        expect.extend(std::fs::read(d.path().join("m.ply")).unwrap());
        assert!(bytes == expect, "{encoding:?}");
    }
}

#[test]
fn chunked_stream_equals_sequential_writer() {
    for (shape, encoding, attrs) in [
        (Shape::Terrain, Encoding::BinaryLe, AttrSet::NORMAL),
        (Shape::Instances, Encoding::BinaryBe, AttrSet::COLOR | AttrSet::UV),
        (Shape::Fan, Encoding::Ascii, AttrSet::POS_F64 | AttrSet::NORMAL),
    ] {
        let g = gen(shape, 30_000, 2, attrs);
        let wopts = PlyWriteOptions { encoding, attrs: g.attrs(), ..Default::default() };
        let mut out = Vec::new();
        let n = stream(&g, &wopts, &mut out, true, 3000).unwrap();
        assert_eq!(n as usize, out.len());
        let mut w = PlyWriter::new(Vec::new(), &wopts, g.vertex_count(), g.face_count()).unwrap();
        for i in 0..g.vertex_count() {
            w.vertex(&g.vertex(i)).unwrap();
        }
        for j in 0..g.face_count() {
            w.face(&g.face(j)).unwrap();
        }
        assert!(w.finish().unwrap() == out, "{shape:?}");
    }
}

//! Levels of detail: hard cases stay finite and inside their nodes, any mixed
//! cut of the tree is crack-free, errors are monotone, attributes survive,
//! and level 0 gives back exactly the input.

use octolod::gen::{GenOptions, Generator, Shape};
use octolod::mesh::{AttrSet, Vertex, VertexLayout};
use octolod::pipeline::{build_store, extract, BuildOptions};
use octolod::ply::write::{write_ply, PlyWriteOptions};
use octolod::simplify::weld_union;
use octolod::store::{IndexedMesh, Store, NO_NODE};
use std::collections::HashMap;
use std::path::Path;

fn build(dir: &Path, shape: Shape, tris: u64, attrs: u32, leaf: u64, grid: u32) -> (Store, IndexedMesh) {
    let g = Generator::new(&GenOptions { shape, tris, seed: 5, attrs: AttrSet(attrs) });
    let (v, f) = g.mesh();
    let ply = dir.join(format!("{}.ply", shape.name()));
    write_ply(&ply, &PlyWriteOptions { attrs: AttrSet(attrs), ..Default::default() }, &v, &f).unwrap();
    let out = dir.join(format!("{}.octolod", shape.name()));
    build_store(
        &ply,
        &out,
        &BuildOptions { mem: 4 << 20, leaf_tris: leaf, max_depth: 12, cluster_grid: grid, levels: None, quiet: true, force: false },
    )
    .unwrap_or_else(|e| panic!("{}: {e}", shape.name()));
    let original = IndexedMesh { vertices: v, triangles: f };
    (Store::open(&out).unwrap(), original)
}

fn node_mesh(s: &Store, i: usize, simplified: bool) -> IndexedMesh {
    s.read_mesh(i, simplified).unwrap()
}

/// Edges used an odd number of times, as pairs of encoded vertices.
fn boundary(layout: &VertexLayout, m: &IndexedMesh) -> Vec<(Vec<u8>, Vec<u8>)> {
    let enc = |v: &Vertex| {
        let mut b = vec![0u8; layout.size];
        layout.encode(v, &mut b);
        b
    };
    let mut count: HashMap<(u32, u32), u32> = HashMap::new();
    // Triangles made degenerate by welding (corners bit-identical after f32
    // rounding) are invisible and do not change any edge's parity: skip them.
    for t in m.triangles.iter().filter(|t| t[0] != t[1] && t[1] != t[2] && t[0] != t[2]) {
        for c in 0..3 {
            let (a, b) = (t[c], t[(c + 1) % 3]);
            *count.entry((a.min(b), a.max(b))).or_default() += 1;
        }
    }
    let mut out: Vec<_> = count
        .into_iter()
        .filter(|&(_, n)| n % 2 == 1)
        .map(|((a, b), _)| {
            let (x, y) = (enc(&m.vertices[a as usize]), enc(&m.vertices[b as usize]));
            if x <= y { (x, y) } else { (y, x) }
        })
        .collect();
    out.sort();
    out
}

/// A pseudo-random cut: descend into a node with probability ~1/2.
fn random_cut(s: &Store, seed: u64) -> Vec<(usize, bool)> {
    let mut state = seed.wrapping_mul(0x9e3779b97f4a7c15) | 1;
    let mut rnd = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    let mut out = Vec::new();
    let mut stack = vec![0usize];
    while let Some(i) = stack.pop() {
        let n = &s.nodes[i];
        if n.is_leaf() {
            // A leaf is drawn simplified or original.
            out.push((i, rnd() % 2 == 0));
        } else if rnd() % 2 == 0 {
            out.push((i, true));
        } else {
            stack.extend(n.children.iter().filter(|&&c| c != NO_NODE).map(|&c| c as usize));
        }
    }
    out
}

/// Checks a store; returns how many representatives (new vertices) it saw.
fn check_store(s: &Store, original: &IndexedMesh, name: &str) -> usize {
    let cube = s.header.cube;
    let orig_welded = weld_union(&s.layout, std::slice::from_ref(original));
    let orig_boundary = boundary(&s.layout, &orig_welded);
    let enc = |v: &Vertex| {
        let mut b = vec![0u8; s.layout.size];
        s.layout.encode(v, &mut b);
        b
    };
    let originals: std::collections::HashSet<Vec<u8>> = orig_welded.vertices.iter().map(enc).collect();
    let mut reps = 0;
    for (i, n) in s.nodes.iter().enumerate() {
        assert!(!n.simp.is_empty() || n.simp.tris == 0, "{name}: node {i} has no simplified mesh");
        // Every vertex finite and within the node's cell or its original content.
        let cell = cube.cell(n.path, n.depth);
        let m = node_mesh(s, i, true);
        for v in &m.vertices {
            for a in 0..3 {
                assert!(v.pos[a].is_finite(), "{name}: node {i}: non-finite vertex");
                let lo = cell.min[a].min(n.content.min[a]);
                let hi = cell.max[a].max(n.content.max[a]);
                let slack = 1e-6 * (hi - lo).max(1e-300) + 1e-12 * v.pos[a].abs();
                assert!(v.pos[a] >= lo - slack && v.pos[a] <= hi + slack, "{name}: node {i}: vertex {:?} outside {:?}", v.pos, cell);
            }
            for x in v.normal.iter().chain(v.uv.iter()) {
                assert!(x.is_finite());
            }
            // A representative (not an original vertex kept on a boundary)
            // lies inside the node's own cell.
            if !originals.contains(&enc(v)) {
                reps += 1;
                for a in 0..3 {
                    let slack = 1e-6 * (cell.max[a] - cell.min[a]);
                    assert!(
                        v.pos[a] >= cell.min[a] - slack && v.pos[a] <= cell.max[a] + slack,
                        "{name}: node {i}: representative {:?} outside its cell {:?}",
                        v.pos,
                        cell
                    );
                }
            }
        }
        // Errors: finite, non-negative, monotone towards the root.
        assert!(n.simp.error.is_finite() && n.simp.error >= 0.0);
        if n.parent != NO_NODE {
            assert!(s.nodes[n.parent as usize].simp.error >= n.simp.error, "{name}: error not monotone at node {i}");
            assert!(s.nodes[n.parent as usize].level > n.level);
        }
    }
    // Mixed cuts: no boundary edge the original did not have.
    for seed in 1..=12 {
        let cut = random_cut(s, seed);
        let parts: Vec<_> = cut.iter().map(|&(i, simp)| node_mesh(s, i, simp)).collect();
        let welded = weld_union(&s.layout, &parts);
        let b = boundary(&s.layout, &welded);
        let extra: Vec<_> = b.iter().filter(|e| orig_boundary.binary_search(e).is_err()).collect();
        assert!(extra.is_empty(), "{name}: cut {seed} has {} boundary edges the original lacks (cracks)", extra.len());
    }
    reps
}

#[test]
fn closed_sphere_any_cut_is_watertight() {
    let d = tempfile::tempdir().unwrap();
    let (s, orig) = build(d.path(), Shape::Sphere, 30_000, AttrSet::NORMAL, 600, 4);
    assert!(s.nodes.len() > 20);
    assert!(check_store(&s, &orig, "sphere") > 100);
    // Triangle counts fall level by level.
    let tris: Vec<u64> = (0..=octolod::pipeline::top_level(&s)).map(|l| octolod::pipeline::level_triangles(&s, l)).collect();
    assert!(tris.windows(2).all(|w| w[1] < w[0]), "levels do not shrink: {tris:?}");
    assert!(*tris.last().unwrap() < tris[0] / 10, "{tris:?}");
}

#[test]
fn hard_cases_are_finite_bounded_and_crack_free() {
    let d = tempfile::tempdir().unwrap();
    for (shape, attrs) in [
        (Shape::Plane, 0),
        (Shape::Cylinder, AttrSet::UV),
        (Shape::Sheets, 0),
        (Shape::Slivers, 0),
        (Shape::Duplicates, 0),
        (Shape::Offset, AttrSet::POS_F64),
        (Shape::Single, 0),
        (Shape::Fan, 0),
        (Shape::Open, AttrSet::COLOR),
        (Shape::Terrain, AttrSet::NORMAL | AttrSet::COLOR | AttrSet::UV),
        (Shape::Instances, 0),
    ] {
        let (s, orig) = build(d.path(), shape, 8_000, attrs, 300, 3);
        let reps = check_store(&s, &orig, shape.name());
        if matches!(shape, Shape::Plane | Shape::Cylinder | Shape::Offset | Shape::Open | Shape::Terrain | Shape::Instances) {
            assert!(reps > 10, "{}: only {reps} representatives checked", shape.name());
        }
    }
}

#[test]
fn one_representative_per_node_reproduces_the_seed_behaviour() {
    // k = 1: every leaf's interior collapses to one vertex fanned to the boundary.
    let d = tempfile::tempdir().unwrap();
    let (s, orig) = build(d.path(), Shape::Terrain, 6_000, 0, 400, 1);
    assert!(check_store(&s, &orig, "terrain k=1") > 0);
    let enc = |v: &Vertex| {
        let mut b = vec![0u8; s.layout.size];
        s.layout.encode(v, &mut b);
        b
    };
    for (i, _) in s.nodes.iter().enumerate().filter(|(_, n)| n.is_leaf()) {
        let m = node_mesh(&s, i, true);
        let o = node_mesh(&s, i, false);
        let kept: std::collections::HashSet<Vec<u8>> = o.vertices.iter().map(enc).collect();
        let new = m.vertices.iter().filter(|v| !kept.contains(&enc(v))).count();
        assert!(new <= 1, "leaf {i}: {new} representatives with --cluster-grid 1");
        // A leaf whose every vertex is on a boundary edge cannot change.
        assert!(m.triangles.len() <= o.triangles.len(), "leaf {i} grew");
    }
    let l0 = octolod::pipeline::level_triangles(&s, 0);
    let l1 = octolod::pipeline::level_triangles(&s, 1);
    assert!(l1 < l0 / 2, "level 1 ({l1}) should be well below level 0 ({l0})");
}

#[test]
fn smooth_colors_survive_simplification() {
    let d = tempfile::tempdir().unwrap();
    let (s, orig) = build(d.path(), Shape::Sphere, 20_000, AttrSet::COLOR, 800, 4);
    // The generator colors by a smooth function of position: compare each
    // simplified vertex's color with the nearest original vertex's.
    let mut grid: HashMap<[i64; 3], Vec<usize>> = HashMap::new();
    let h = 0.05;
    let key = |p: [f64; 3]| p.map(|x| (x / h).floor() as i64);
    for (k, v) in orig.vertices.iter().enumerate() {
        grid.entry(key(v.pos)).or_default().push(k);
    }
    let mut worst = 0i32;
    let mut sum = 0f64;
    let mut n = 0f64;
    for i in 0..s.nodes.len() {
        for v in node_mesh(&s, i, true).vertices {
            let kk = key(v.pos);
            let mut best = (f64::INFINITY, 0usize);
            for dx in -1..=1 {
                for dy in -1..=1 {
                    for dz in -1..=1 {
                        for &c in grid.get(&[kk[0] + dx, kk[1] + dy, kk[2] + dz]).into_iter().flatten() {
                            let p = orig.vertices[c].pos;
                            let d2 = (0..3).map(|a| (p[a] - v.pos[a]).powi(2)).sum::<f64>();
                            if d2 < best.0 {
                                best = (d2, c);
                            }
                        }
                    }
                }
            }
            if best.0.is_finite() {
                let oc = orig.vertices[best.1].color;
                let e = (0..3).map(|a| (v.color[a] as i32 - oc[a] as i32).abs()).max().unwrap();
                worst = worst.max(e);
                sum += e as f64;
                n += 1.0;
            }
        }
    }
    assert!(n > 100.0);
    assert!(sum / n < 12.0, "mean color error {} of 255", sum / n);
    assert!(worst < 64, "worst color error {worst} of 255");
}

#[test]
fn level_zero_extract_gives_back_the_input_triangles() {
    let d = tempfile::tempdir().unwrap();
    let (s, orig) = build(d.path(), Shape::Open, 10_000, AttrSet::NORMAL | AttrSet::UV, 500, 4);
    let out = d.path().join("l0.ply");
    let (_, nf) = extract(&s, 0, &out, true, false).unwrap();
    assert_eq!(nf as usize, orig.triangles.len());
    let (_, back, _) = octolod::ply::read::read_all(&out).unwrap();
    let key = |vs: &[Vertex], t: [u64; 3]| {
        let mut k: Vec<u64> = Vec::new();
        // Rotate so the smallest encoded corner is first: the set of oriented triangles.
        let corners: Vec<Vec<u64>> = t
            .iter()
            .map(|&i| {
                let v = vs[i as usize];
                v.pos.iter().map(|x| (*x as f32).to_bits() as u64).chain(v.normal.iter().map(|x| x.to_bits() as u64)).chain(v.uv.iter().map(|x| x.to_bits() as u64)).collect()
            })
            .collect();
        let r = (0..3).min_by_key(|&r| corners[r].clone()).unwrap();
        for c in 0..3 {
            k.extend(&corners[(r + c) % 3]);
        }
        k
    };
    let mut a: Vec<_> = orig.triangles.iter().map(|t| key(&orig.vertices, t.map(|i| i as u64))).collect();
    let mut b: Vec<_> = back.triangles.iter().map(|&t| key(&back.vertices, t)).collect();
    a.sort();
    b.sort();
    assert!(a == b, "level 0 differs from the input");
}


#[test]
fn a_closed_object_inside_one_node_may_collapse_to_an_empty_node() {
    let d = tempfile::tempdir().unwrap();
    // One small torus, one leaf (the root), one representative: nothing is left.
    let (s, orig) = build(d.path(), Shape::Instances, 100, 0, 1000, 1);
    assert_eq!(s.nodes.len(), 1);
    assert!(orig.triangles.len() > 40);
    let root = &s.nodes[0];
    assert_eq!((root.level, root.simp.tris, root.simp.verts), (1, 0, 0));
    assert!(!root.simp.is_empty(), "an empty mesh is still a stored payload");
    assert!(node_mesh(&s, 0, true).triangles.is_empty());
    let out = d.path().join("empty.ply");
    assert_eq!(extract(&s, 1, &out, true, false).unwrap(), (0, 0));
    let (h, m, _) = octolod::ply::read::read_all(&out).unwrap();
    assert_eq!((h.face_count(), m.vertices.len()), (0, 0));
}

/// A leaf's stored error is its measured geometric error: at least the
/// distance of every original vertex to the simplified surface and of every
/// simplified vertex to the original, at most twice that, yet far below the
/// cell size — the
/// error a viewer can turn into pixels, not a loose bound.
#[test]
fn leaf_error_is_the_measured_surface_deviation() {
    use octolod::metro::{Bvh, Mesh};
    let dir = tempfile::tempdir().unwrap();
    let (s, _) = build(dir.path(), Shape::Sphere, 60_000, 0, 2048, 8);
    let (mut checked, mut tight) = (0, 0);
    for (i, n) in s.nodes.iter().enumerate() {
        if !n.is_leaf() || n.simp.tris == 0 {
            continue;
        }
        let (o, m) = (node_mesh(&s, i, false), node_mesh(&s, i, true));
        let (a, b) = (Mesh::from_vertices(&o.vertices, o.triangles.clone()), Mesh::from_vertices(&m.vertices, m.triangles.clone()));
        let (ta, tb) = (Bvh::new(&a), Bvh::new(&b));
        let d1 = a.referenced_vertices().iter().map(|&v| tb.closest(o.vertices[v as usize].pos).unwrap().dist2).fold(0.0, f64::max);
        let d2 = m.vertices.iter().map(|v| ta.closest(v.pos).unwrap().dist2).fold(0.0, f64::max);
        let d = d1.max(d2).sqrt();
        let e = n.simp.error as f64;
        assert!(e >= d * (1.0 - 1e-6), "node {i}: stored {e} below measured {d}");
        // The output → input half is an upper bound (nearest triangle of the
        // representative's own cluster): above the exact value, not far.
        assert!(e <= 2.0 * d + 1e-12, "node {i}: stored {e} far above measured {d}");
        tight += (e <= d * (1.0 + 1e-6) + 1e-12) as usize;
        assert!(e < 0.05 * n.cell.diagonal(), "node {i}: error {e} is not small against the cell {}", n.cell.diagonal());
        checked += 1;
    }
    assert!(checked > 10);
    assert!(tight * 2 >= checked, "the bound is exact on most leaves: {tight} of {checked}");
}

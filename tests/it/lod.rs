//! Levels of detail v2 (issue 9): every valid cut of the DAG is closed
//! where the input is, on smooth and hard inputs; DAG invariants; levels
//! halve; seams of one level are free at the next; level 0 is the input;
//! node errors are measured deviations; normals agree across seams.

use crate::common;
use crate::common::{build_with, crack_report, random_cut, Rng, SIMPLIFIERS};
use octolod::gen::Shape;
use octolod::manifest::Normals;
use octolod::mesh::IndexedMesh;
use octolod::mesh::{AttrSet, Vertex};
use octolod::pipeline::{extract, CutSpec};
use octolod::store::Store;
use std::collections::HashMap;

/// DAG invariants: parent error ≥ child, parent bounds ⊇ child bounds,
/// errors and vertices finite, vertices inside their node's bounds.
pub(crate) fn check_dag(s: &Store, name: &str) {
    for i in 0..s.nodes.len() {
        let n = &s.nodes[i];
        assert!(n.error.is_finite(), "{name}: node {i}: error {}", n.error);
        for &c in s.children_of(i) {
            let c = &s.nodes[c as usize];
            assert!(n.error >= c.error, "{name}: node {i}: error {} < child's {}", n.error, c.error);
            for k in 0..3 {
                assert!(n.bounds.min[k] <= c.bounds.min[k] && n.bounds.max[k] >= c.bounds.max[k], "{name}: node {i}: bounds do not contain a child's");
            }
        }
        // Bounded: inside the input's box, no error beyond its extent.
        let (bb, diag) = (&s.header.bbox, s.header.bbox.diagonal());
        let tol = 1e-6 * diag;
        assert!(n.error as f64 <= diag * (1.0 + 1e-6), "{name}: node {i}: error {} beyond the input's extent {diag}", n.error);
        for k in 0..3 {
            assert!(n.bounds.min[k] >= bb.min[k] - tol && n.bounds.max[k] <= bb.max[k] + tol, "{name}: node {i}: bounds outside the input's box");
        }
        let m = s.read_node(i).unwrap();
        for v in &m.mesh.vertices {
            for k in 0..3 {
                assert!(v.pos[k].is_finite(), "{name}: node {i}: non-finite vertex");
                assert!(v.pos[k] >= n.bounds.min[k] && v.pos[k] <= n.bounds.max[k], "{name}: node {i}: vertex outside its bounds");
            }
        }
    }
}

/// Random valid cuts, error cuts and whole levels: no crack.
pub(crate) fn check_cuts(s: &Store, input: &IndexedMesh, name: &str, closed: bool) {
    let mut rng = Rng::new(17);
    let mut cuts: Vec<(String, octolod::store::Cut)> = Vec::new();
    for seed in 1..=10 {
        cuts.push((format!("random {seed}"), random_cut(s, seed, 0.3 + 0.06 * seed as f64)));
    }
    let emax = s.nodes[s.root()].error as f64;
    for _ in 0..4 {
        let e = emax * rng.f64();
        cuts.push((format!("error {e:e}"), s.error_cut(e)));
    }
    for l in 0..=s.top_level() {
        cuts.push((format!("level {l}"), s.level_cut(l)));
    }
    let mut total_excess = 0;
    let mut total_edges = 0;
    for (what, cut) in &cuts {
        // Closed under parents.
        for i in 0..s.nodes.len() {
            if cut.selected[i] {
                assert!(s.parents_of(i).iter().all(|&p| cut.selected[p as usize]), "{name}: {what}: not a valid selection");
            }
        }
        let ((pos, tris), shared) = common::cut_mesh_parts(s, cut);
        assert_eq!(tris.len() as u64, cut.triangles(s), "{name}: {what}: triangle count");
        let r = crack_report(input, &pos, &tris, &shared);
        if r.cracks > 0 {
            let (a, b) = r.first.unwrap();
            for &i in &cut.drawn {
                let m = cut.drawn_mesh(&s.read_node(i).unwrap());
                let has = |p: [f64; 3]| m.vertices.iter().any(|v| v.pos == p);
                if has(a) || has(b) {
                    eprintln!("node {i} level {} has a:{} b:{}", s.nodes[i].level, has(a), has(b));
                }
            }
        }
        assert_eq!(r.cracks, 0, "{name}: {what}: {} crack edges ({r:?})", r.cracks);
        if closed {
            assert_eq!(r.open, 0, "{name}: {what}: {} open edges on a closed input", r.open);
        }
        total_excess += r.excess;
        total_edges += r.edges;
    }
    // On closed inputs, welded cuts are manifold where the input is: an edge
    // in more faces than the input's most-used edge stays rare: at most 1 %
    // of the edges over all cuts, 2 % for the many small tori (`instances`),
    // whose tubes vertex clustering pinches at coarse levels (1.6 % measured
    // over these cuts: its levels 1-4 alone are 1.8 %).
    if closed {
        let pct = if name.starts_with("instances") { 2 } else { 1 };
        assert!(total_excess * 100 <= total_edges * pct, "{name}: {total_excess} of {total_edges} edges in more faces than the input has");
    }
}

#[test]
fn closed_sphere_every_cut_is_closed_and_levels_halve() {
    for simp in SIMPLIFIERS {
        closed_sphere(simp);
    }
}

fn closed_sphere(simp: octolod::manifest::Simplifier) {
    let d = tempfile::tempdir().unwrap();
    let (s, input) = build_with(d.path(), Shape::Sphere, 40_000, 0, 1000, simp);
    let name = format!("sphere ({})", simp.name());
    check_dag(&s, &name);
    check_cuts(&s, &input, &name, true);
    let tris: Vec<u64> = (0..=s.top_level()).map(|l| s.level_triangles(l)).collect();
    for w in tris.windows(2) {
        let r = w[1] as f64 / w[0] as f64;
        assert!((0.35..=0.65).contains(&r), "{name}: levels do not halve: {tris:?}");
    }
    assert_eq!(s.level_nodes(s.top_level()).len(), 1);
    assert!(*tris.last().unwrap() <= 256, "{tris:?}");
    // Seams of one level are simplified at the next.
    let m = octolod::manifest::Manifest::read(&s.dir).unwrap();
    for l in &m.levels[1..] {
        if l.nodes >= 8 {
            assert!(
                l.prev_locked_still_fraction < 0.12,
                "{name}: level {}: {:.1}% of the previous seams still locked",
                l.level,
                100.0 * l.prev_locked_still_fraction
            );
        }
    }
}

#[test]
fn hard_cases_every_cut_is_crack_free() {
    let d = tempfile::tempdir().unwrap();
    for simp in SIMPLIFIERS {
        for (shape, attrs, closed) in [
            (Shape::Duplicates, 0, true),
            (Shape::Fan, 0, false),
            (Shape::Sheets, 0, false),
            (Shape::Offset, AttrSet::POS_F64, true),
            (Shape::Slivers, 0, false),
            (Shape::Terrain, AttrSet::NORMAL | AttrSet::COLOR | AttrSet::UV, false),
            (Shape::Open, AttrSet::COLOR, false),
            (Shape::Plane, 0, false),
            (Shape::Cylinder, AttrSet::UV, false),
            (Shape::Instances, 0, true),
            (Shape::Single, 0, false),
        ] {
            let (s, input) = build_with(d.path(), shape, 12_000, attrs, 400, simp);
            let name = format!("{} ({})", shape.name(), simp.name());
            check_dag(&s, &name);
            check_cuts(&s, &input, &name, closed);
            if shape != Shape::Single {
                assert!(s.top_level() >= 2, "{name}: only {} levels", s.top_level() + 1);
            }
        }
    }
}

#[test]
fn level_zero_is_the_input_and_max_error_cuts_hold_their_bound() {
    for simp in SIMPLIFIERS {
        level_zero_and_max_error_cuts(simp);
    }
}

fn level_zero_and_max_error_cuts(simp: octolod::manifest::Simplifier) {
    let d = tempfile::tempdir().unwrap();
    let (s, input) = build_with(d.path(), Shape::Open, 10_000, AttrSet::NORMAL | AttrSet::UV, 500, simp);
    let out = d.path().join("l0.ply");
    let (_, nf) = extract(&s, CutSpec::Level(0), &out, true, false).unwrap();
    assert_eq!(nf as usize, input.triangles.len());
    let (_, back, _) = octolod::ply::read::read_all(&out).unwrap();
    let key = |vs: &[Vertex], t: [u64; 3]| {
        let corners: Vec<Vec<u64>> = t
            .iter()
            .map(|&i| {
                let v = vs[i as usize];
                v.pos
                    .iter()
                    .map(|x| (*x as f32).to_bits() as u64)
                    .chain(v.normal.iter().map(|x| x.to_bits() as u64))
                    .chain(v.uv.iter().map(|x| x.to_bits() as u64))
                    .collect()
            })
            .collect();
        let r = (0..3).min_by_key(|&r| corners[r].clone()).unwrap();
        (0..3).flat_map(|c| corners[(r + c) % 3].clone()).collect::<Vec<u64>>()
    };
    let mut a: Vec<_> = input.triangles.iter().map(|t| key(&input.vertices, t.map(|i| i as u64))).collect();
    let mut b: Vec<_> = back.triangles.iter().map(|&t| key(&back.vertices, t)).collect();
    a.sort();
    b.sort();
    assert!(a == b, "level 0 differs from the input");
    // The cut at error E draws only nodes whose error is at most E.
    let e = s.nodes[s.root()].error as f64 * 0.3;
    let cut = s.error_cut(e);
    for &i in &cut.drawn {
        assert!(s.nodes[i].error as f64 <= e, "node {i} drawn with error {} > {e}", s.nodes[i].error);
    }
    let (_, nf) = extract(&s, CutSpec::MaxError(e), &d.path().join("e.ply"), true, false).unwrap();
    assert_eq!(nf, cut.triangles(&s));
    assert!(nf < input.triangles.len() as u64 && nf > s.nodes[s.root()].tris as u64);
}

/// A parent's error covers how far each of its patches lies from the child
/// it was simplified from (exact distances, representatives to surface).
#[test]
fn node_errors_cover_the_measured_deviation() {
    use octolod::geom::{Bvh, Mesh};
    for simp in SIMPLIFIERS {
        let d = tempfile::tempdir().unwrap();
        let (s, _) = build_with(d.path(), Shape::Terrain, 30_000, 0, 2000, simp);
        let mut checked = 0;
        for i in 0..s.nodes.len() {
            if s.nodes[i].level == 0 {
                continue;
            }
            let nm = s.read_node(i).unwrap();
            for p in &nm.patches {
                let child = s.read_node(p.child as usize).unwrap().mesh;
                let bvh = Bvh::new(&Mesh::from_vertices(&child.vertices, child.triangles.clone()));
                let tris = &nm.mesh.triangles[p.first as usize..(p.first + p.count) as usize];
                let mut worst = 0.0f64;
                for t in tris {
                    for &v in t {
                        worst = worst.max(bvh.closest(nm.mesh.vertices[v as usize].pos).unwrap().dist2.sqrt());
                    }
                }
                assert!(s.nodes[i].error as f64 >= worst * (1.0 - 1e-6), "{}: node {i}: error {} below the measured {worst}", simp.name(), s.nodes[i].error);
                checked += 1;
            }
        }
        assert!(checked > 10);
    }
}

#[test]
fn derived_normals_agree_across_node_seams() {
    for simp in SIMPLIFIERS {
        derived_normals(simp);
    }
}

fn derived_normals(simp: octolod::manifest::Simplifier) {
    let d = tempfile::tempdir().unwrap();
    let (s, _) = build_with(d.path(), Shape::Sphere, 20_000, 0, 800, simp);
    assert!(s.header.derived_normals);
    for l in 0..s.top_level() {
        let mut seen: std::collections::HashMap<[u64; 3], [u32; 3]> = Default::default();
        let (mut shared, mut inward, mut total) = (0, 0, 0);
        for i in s.level_nodes(l) {
            for v in s.read_node(i).unwrap().mesh.vertices {
                let n = v.normal.map(f32::to_bits);
                if let Some(old) = seen.insert(v.pos.map(f64::to_bits), n) {
                    shared += 1;
                    assert_eq!(old, n, "level {l}: two normals at {:?}", v.pos);
                }
                // Outward on a sphere around the origin.
                let dot: f64 = (0..3).map(|k| v.pos[k] * v.normal[k] as f64).sum();
                inward += (dot <= 0.0) as usize;
                total += 1;
            }
        }
        if s.level_nodes(l).len() > 1 {
            assert!(shared > 0, "level {l}: no shared vertex checked");
        }
        assert!(inward * 200 <= total, "level {l}: {inward} of {total} normals point inwards");
    }
}

#[test]
fn smooth_colors_survive_simplification() {
    for simp in SIMPLIFIERS {
        smooth_colors(simp);
    }
}

fn smooth_colors(simp: octolod::manifest::Simplifier) {
    let d = tempfile::tempdir().unwrap();
    let (s, input) = build_with(d.path(), Shape::Sphere, 20_000, AttrSet::COLOR, 800, simp);
    let bvh = octolod::geom::Bvh::new(&octolod::geom::Mesh::from_vertices(&input.vertices, input.triangles.clone()));
    let (mut sum, mut n, mut worst) = (0.0f64, 0.0f64, 0i32);
    for i in 0..s.nodes.len() {
        if s.nodes[i].level == 0 || s.nodes[i].level > 3 {
            continue;
        }
        for v in s.read_node(i).unwrap().mesh.vertices {
            let c = bvh.closest(v.pos).unwrap();
            let t = input.triangles[c.triangle as usize];
            let oc = input.vertices[t[0] as usize].color;
            let e = (0..3).map(|a| (v.color[a] as i32 - oc[a] as i32).abs()).max().unwrap();
            worst = worst.max(e);
            sum += e as f64;
            n += 1.0;
        }
    }
    assert!(n > 100.0);
    assert!(sum / n < 16.0, "{}: mean color error {} of 255", simp.name(), sum / n);
    assert!(worst < 96, "{}: worst color error {worst} of 255", simp.name());
}

/// Cutting a level into many nodes costs (almost) no accuracy: the same
/// sphere built with small nodes and with one node per level, each level
/// measured by metro against the input at (about) equal size. Seams of a
/// level-0 node once carried false border planes into the next levels'
/// quadrics and made small-node levels 2–4× worse.
#[test]
fn small_nodes_are_as_accurate_as_one_big_node() {
    use octolod::metro::Mesh;
    use octolod::pipeline::build_store;
    let d = tempfile::tempdir().unwrap();
    let (ply, input) = common::gen_ply(d.path(), Shape::Sphere, 200_000, 0);
    let a = Mesh::from_vertices(&input.vertices, input.triangles.clone());
    let mut rms = Vec::new();
    for leaf in [1024u64, 1 << 20] {
        let out = d.path().join(format!("s{leaf}.octolod"));
        build_store(&ply, &out, &common::build_options(common::BuildParams { mem: 64 << 20, leaf_tris: leaf, ..Default::default() })).unwrap();
        let s = Store::open(&out).unwrap();
        let per = sizes_and_rms(&a, &out, 2..=4);
        if leaf == 1024 {
            assert!(s.nodes.iter().filter(|n| n.level == 3).count() >= 8, "level 3 should have many nodes");
        }
        rms.push(per);
    }
    for (small, big) in rms[0].iter().zip(&rms[1]) {
        // RMS ∝ 1/size on a smooth surface: compare at equal size.
        let ratio = (small.1 * small.0) / (big.1 * big.0);
        assert!(ratio < 1.25, "small nodes {small:?} vs one node {big:?}: {ratio:.2}x");
    }
}

/// Per level of the store at `dir` in `levels`: its triangle count and
/// metro's combined RMS distance to the input `a` (200 K samples a direction).
fn sizes_and_rms(a: &octolod::metro::Mesh, dir: &std::path::Path, levels: std::ops::RangeInclusive<u8>) -> Vec<(f64, f64)> {
    use octolod::metro::{compare, load_store_level, Options};
    levels
        .map(|l| {
            let b = load_store_level(dir, l).unwrap();
            let r = compare(a, &b, &Options { samples: Some(200_000), ..Default::default() }).unwrap();
            (b.triangles.len() as f64, r.combined.rms)
        })
        .collect()
}

/// Normals that do not follow the coarse geometry (a rough terrain's) do
/// not buy its clusters: the terrain built with its normals is, level by
/// level at equal size, about as near the input as the same terrain built
/// without them. Normals weighed a hundredth of the cell made levels 2–5
/// of this terrain 1.14, 1.45, 1.97 and 1.88× farther in RMS; a
/// thousandth, 1.03, 1.08, 1.14 and 1.20×.
#[test]
fn rough_normals_do_not_take_the_clusters() {
    use octolod::metro::Mesh;
    let d = tempfile::tempdir().unwrap();
    let mut per = Vec::new();
    for attrs in [0, AttrSet::NORMAL] {
        let (ply, input) = common::gen_ply_seeded(d.path(), Shape::Terrain, 200_000, attrs, 1);
        // In the quadric, where the weight matters (`auto` averages them).
        let params = common::BuildParams { leaf_tris: 4000, normals: Normals::Carry, ..Default::default() };
        let dir = common::build_store_at(d.path(), &ply, &common::build_options(params));
        let a = Mesh::from_vertices(&input.vertices, input.triangles.clone());
        per.push(sizes_and_rms(&a, &dir, 2..=5));
    }
    for (l, (plain, normals)) in per[0].iter().zip(&per[1]).enumerate() {
        // RMS about ∝ 1/size at these levels: compare at equal size.
        let ratio = (normals.1 * normals.0) / (plain.1 * plain.0);
        assert!(ratio < 1.3, "level {}: with normals {normals:?}, without {plain:?}: {ratio:.2}x", l + 2);
    }
}

/// `--normals auto` averages a smooth sphere's normals out of the quadric
/// (dimension 3, not 6): level 0 keeps the input's bit for bit, the levels
/// above hold unit normals about as near the input's as carried ones. A
/// sphere whose normals are split along a crease carries them (dimension
/// 6), as `--normals carry` does.
#[test]
fn normals_are_averaged_out_of_the_quadric_unless_creased() {
    use octolod::geom::{Bvh, Mesh};
    use octolod::manifest::Manifest;
    let d = tempfile::tempdir().unwrap();
    let (ply, input) = common::gen_ply_seeded(d.path(), Shape::Sphere, 40_000, AttrSet::NORMAL, 3);
    let bvh = Bvh::new(&Mesh::from_vertices(&input.vertices, input.triangles.clone()));
    let key = |p: [f64; 3]| p.map(|x| (x as f32).to_bits());
    let given: HashMap<[u32; 3], [f32; 3]> = input.vertices.iter().map(|v| (key(v.pos), v.normal)).collect();
    let build = |ply: &std::path::Path, normals: Normals| {
        let dir = d.path().join(format!("{}-{}.octolod", ply.file_stem().unwrap().to_string_lossy(), normals.name()));
        let params = common::BuildParams { leaf_tris: 2000, normals, ..Default::default() };
        octolod::pipeline::build_store(ply, &dir, &common::build_options(params)).unwrap();
        (Store::open(&dir).unwrap(), Manifest::read(&dir).unwrap())
    };
    // Mean angle (degrees) of levels 1–4's normals from the input's at the
    // closest point; level 0's must be the input's own.
    let angle = |s: &Store| {
        let (mut sum, mut n) = (0.0f64, 0usize);
        for i in 0..s.nodes.len() {
            for v in s.read_node(i).unwrap().mesh.vertices {
                if s.nodes[i].level == 0 {
                    assert_eq!(given.get(&key(v.pos)), Some(&v.normal), "node {i}: level 0 keeps the input's normals");
                    continue;
                }
                if s.nodes[i].level > 4 {
                    continue;
                }
                let c = bvh.closest(v.pos).unwrap();
                let w = input.vertices[input.triangles[c.triangle as usize][0] as usize].normal;
                let nl = v.normal.iter().map(|&x| x as f64 * x as f64).sum::<f64>().sqrt();
                assert!((nl - 1.0).abs() < 1e-3, "node {i}: normal of length {nl}");
                let cos = (0..3).map(|k| w[k] as f64 * v.normal[k] as f64).sum::<f64>() / nl;
                sum += cos.clamp(-1.0, 1.0).acos().to_degrees();
                n += 1;
            }
        }
        assert!(n > 1000, "{n} vertices above level 0");
        sum / n as f64
    };
    let (s, m) = build(&ply, Normals::Auto);
    assert_eq!((m.params.normals, m.quadric_dim), (Normals::Average, 3));
    let averaged = angle(&s);
    let (s, m) = build(&ply, Normals::Carry);
    assert_eq!((m.params.normals, m.quadric_dim), (Normals::Carry, 6));
    let carried = angle(&s);
    eprintln!("sphere, levels 1-4: normals {averaged:.3}° from the input's averaged, {carried:.3}° carried");
    assert!(averaged < 1.2 * carried + 0.1, "averaged normals {averaged:.3}° from the input's, carried {carried:.3}°");
    // A crease: the wedges of every vertex with x > 0 face +x (a seam
    // along x = 0's side).
    let (cply, _) = common::creased_ply(d.path(), &input, |v| v.pos[0] > 0.0);
    let (_, m) = build(&cply, Normals::Auto);
    assert_eq!((m.params.normals, m.quadric_dim), (Normals::Carry, 6), "a creased sphere's normals are carried");
}

/// Normals, colours and uvs are carried through either simplifier: unit
/// normals that agree with the input's and colours near the input's at the
/// closest point (a smooth sphere); uvs near the input's and, with
/// collapse, inside its range (a terrain: no uv seam, where the nearest
/// input uv may lie across the wrap).
#[test]
fn attributes_are_carried() {
    use octolod::geom::{Bvh, Mesh};
    for simp in SIMPLIFIERS {
        for shape in [Shape::Sphere, Shape::Terrain] {
            let d = tempfile::tempdir().unwrap();
            // Carried (`auto` would average these).
            let (ply, input) = common::gen_ply(d.path(), shape, 20_000, AttrSet::NORMAL | AttrSet::COLOR | AttrSet::UV);
            let params = common::BuildParams {
                mem: 4 << 20,
                leaf_tris: 800,
                max_depth: 12,
                root_tris: 256,
                simplifier: simp,
                normals: Normals::Carry,
                ..Default::default()
            };
            let s = octolod::store::Store::open(&common::build_store_at(d.path(), &ply, &common::build_options(params))).unwrap();
            let name = format!("{} ({})", shape.name(), simp.name());
            assert!(s.header.attrs.normal() && s.header.attrs.color() && s.header.attrs.uv() && !s.header.derived_normals);
            let bvh = Bvh::new(&Mesh::from_vertices(&input.vertices, input.triangles.clone()));
            let (mut lo, mut hi) = ([f32::MAX; 2], [f32::MIN; 2]);
            for v in &input.vertices {
                for k in 0..2 {
                    lo[k] = lo[k].min(v.uv[k]);
                    hi[k] = hi[k].max(v.uv[k]);
                }
            }
            let (mut n, mut turned, mut color_sum, mut uv_worst, mut uv_outside) = (0usize, 0usize, 0.0f64, 0.0f32, 0usize);
            for i in 0..s.nodes.len() {
                if s.nodes[i].level == 0 || s.nodes[i].level > 3 {
                    continue;
                }
                for v in s.read_node(i).unwrap().mesh.vertices {
                    let len = (v.normal.iter().map(|x| x * x).sum::<f32>()).sqrt();
                    assert!((len - 1.0).abs() < 1e-3, "{name}: node {i}: normal of length {len}");
                    for k in 0..2 {
                        uv_outside += (v.uv[k] < lo[k] || v.uv[k] > hi[k]) as usize;
                    }
                    let c = bvh.closest(v.pos).unwrap();
                    let w = input.vertices[input.triangles[c.triangle as usize][0] as usize];
                    let dot: f32 = (0..3).map(|k| v.normal[k] * w.normal[k]).sum();
                    turned += (dot < 0.8) as usize;
                    color_sum += (0..3).map(|a| (v.color[a] as i32 - w.color[a] as i32).abs()).max().unwrap() as f64;
                    uv_worst = uv_worst.max((0..2).map(|k| (v.uv[k] - w.uv[k]).abs()).fold(0.0, f32::max));
                    n += 1;
                }
            }
            let color = color_sum / n as f64;
            eprintln!("{name}: {n} vertices, {turned} normals turned > 37°, mean color error {color:.2}, worst uv error {uv_worst}, {uv_outside} uvs outside the input's range");
            assert!(n > 1000, "{name}: {n} vertices");
            assert!(color < 16.0, "{name}: mean color error {color} of 255");
            if shape == Shape::Sphere {
                assert!(turned * 200 <= n, "{name}: {turned} of {n} normals turned by more than 37° from the input's");
            }
            // Collapse clamps uvs into the input's range. Clustering's
            // representatives solve uvs with the quadric and overshoot at
            // the terrain's border: printed, not asserted (known, issue 10).
            if shape == Shape::Terrain && simp == octolod::manifest::Simplifier::Collapse {
                assert_eq!(uv_outside, 0, "{name}: uvs outside the input's range");
                assert!(uv_worst < 0.1, "{name}: uv off by {uv_worst}");
            }
        }
    }
}

/// Issue 9 (b): a node's error is what a cut shows there. Clustering can
/// leave a flap (triangles folded back over a neighbour's surface); the
/// node holding it drops it one level up, and its vertices used to count
/// as far from that node's own output although the neighbour's surface
/// lies under them: 1.4e-3 at level 2 of this sphere where the level is
/// 2.7e-4 from the input (5.2×), carried by saturation to every ancestor.
/// Each level's largest node error now stays within 3× the level's
/// measured (metro, both directions) distance to the input.
#[test]
fn node_errors_are_not_inflated_by_flaps() {
    use octolod::manifest::Simplifier;
    let d = tempfile::tempdir().unwrap();
    let (ply, _) = common::gen_ply_seeded(d.path(), Shape::Sphere, 200_000, 0, 1);
    // Edge collapse keeps its far points too (its errors are exact BVH
    // distances, remeasured the same way).
    for simplifier in [Simplifier::Cluster, Simplifier::Collapse] {
        let params = common::BuildParams { mem: 16 << 20, leaf_tris: 2000, simplifier, ..Default::default() };
        let sub = d.path().join(format!("{simplifier:?}"));
        std::fs::create_dir(&sub).unwrap();
        let dir = common::build_store_at(&sub, &ply, &common::build_options(params));
        let levels = level_errors_and_distances(&dir, &ply, 1, 5000, Some(100_000));
        for &(l, err, h) in &levels {
            assert!(err <= 3.0 * h, "{simplifier:?} level {l}: largest node error {err:.3e} is {:.1}x the level's Hausdorff distance {h:.3e}", err / h);
        }
        assert!(levels.len() >= 4, "{simplifier:?}: {} levels checked", levels.len());
    }
}

/// A node's error bounds its distance to the input, not only to the level
/// it was made from: from level 2 on (level 1 is a single step, measured at
/// vertices) metro finds every whole level within its largest node error.
/// Taking the largest step instead of adding them up (Nexus's and
/// clusterlod's default) left the terrain's levels 1.2–1.4× and a scan's
/// up to 2.2× farther from the input than their errors said.
#[test]
fn node_errors_bound_the_distance_to_the_input() {
    let d = tempfile::tempdir().unwrap();
    for shape in [Shape::Terrain, Shape::Scan] {
        let sub = d.path().join(format!("{shape:?}"));
        std::fs::create_dir(&sub).unwrap();
        let (ply, _) = common::gen_ply_seeded(&sub, shape, 200_000, 0, 1);
        let params = common::BuildParams { leaf_tris: 2000, ..Default::default() };
        let dir = common::build_store_at(&sub, &ply, &common::build_options(params));
        let levels = level_errors_and_distances(&dir, &ply, 2, 2000, None);
        for &(l, err, h) in &levels {
            assert!(h <= err, "{shape:?} level {l}: metro puts it {h:.3e} from the input, {:.2}x its largest node error {err:.3e}", h / err);
        }
        assert!(levels.len() >= 4, "{shape:?}: {} levels checked", levels.len());
    }
}

/// Per level from `from` on, while it holds at least `min_tris` triangles:
/// (level, its largest node error, metro's two-sided Hausdorff distance
/// between the input `ply` and the level, `samples` per direction).
fn level_errors_and_distances(dir: &std::path::Path, ply: &std::path::Path, from: u8, min_tris: u64, samples: Option<u64>) -> Vec<(u8, f64, f64)> {
    use octolod::metro::Source;
    let s = Store::open(dir).unwrap();
    let mut out = Vec::new();
    for l in from..=s.top_level() {
        if s.level_triangles(l) < min_tris {
            break;
        }
        let err = s.level_nodes(l).into_iter().map(|i| s.nodes[i].error as f64).fold(0.0, f64::max);
        out.push((l, err, metro_max(Source::Ply(ply.to_path_buf()), Source::Store(dir.to_path_buf(), l), samples, 256 << 20)));
    }
    out
}

/// Metro's two-sided Hausdorff distance between `a` and `b` (`samples` per
/// direction, metro's default when None), under a `budget` of bytes.
fn metro_max(a: octolod::metro::Source, b: octolod::metro::Source, samples: Option<u64>, budget: u64) -> f64 {
    use octolod::metro::{self, MemOptions};
    let opts = metro::Options { samples, seed: 1, quiet: true };
    metro::compare_sources(&a, &b, &opts, &MemOptions { budget, explicit: false }).unwrap().combined.max
}

/// One-cell holes, a range scan's dropouts: a coarser level can fill one
/// (a point over the hole, half its width from the input) or widen it,
/// with every vertex still on the other surface, so vertex samples alone
/// put such nodes far below their distance to the input (a cut at E
/// measured 5.9 E by metro on this grid). Node errors sample the faces
/// next to the mesh's own border too: from level 2 on (level 1 is a single
/// step, vertex-sampled inside), the cut at every node's error is within
/// that error of the input by metro, for both simplifiers.
#[test]
fn cuts_over_small_holes_stay_within_their_error() {
    use octolod::metro::Source;
    use octolod::ply::write::{write_ply, PlyWriteOptions};
    let d = tempfile::tempdir().unwrap();
    // A 120 x 120 grid of a smooth wave far from the origin (double
    // positions), the cells with i·j ≡ 5 (mod 37) left out.
    let n = 120u32;
    let mut v = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            let (x, y) = (i as f64 / n as f64, j as f64 / n as f64);
            v.push(Vertex { pos: [x + 1e5, y - 3e5, 0.05 * (6.0 * x).sin() * (5.0 * y).cos()], ..Default::default() });
        }
    }
    let mut f = Vec::new();
    for j in 0..n {
        for i in 0..n {
            if (i * j) % 37 != 5 {
                let a = j * (n + 1) + i;
                f.push([a, a + 1, a + n + 2]);
                f.push([a, a + n + 2, a + n + 1]);
            }
        }
    }
    let ply = d.path().join("holes.ply");
    write_ply(&ply, &PlyWriteOptions { attrs: AttrSet(AttrSet::POS_F64), ..Default::default() }, &v, &f).unwrap();
    for simp in SIMPLIFIERS {
        let params = common::BuildParams { leaf_tris: 2000, simplifier: simp, ..Default::default() };
        let dir = common::build_store_at(d.path(), &ply, &common::build_options(params));
        let s = Store::open(&dir).unwrap();
        check_dag(&s, "holes");
        let mut errors: Vec<f32> = (2..=s.top_level()).flat_map(|l| s.level_nodes(l)).map(|i| s.nodes[i].error).collect();
        errors.sort_by(f32::total_cmp);
        errors.dedup();
        for (k, &e) in errors.iter().enumerate() {
            let e = e as f64;
            let out = d.path().join(format!("cut-{}-{k}.ply", simp.name()));
            extract(&s, CutSpec::MaxError(e), &out, true, false).unwrap();
            let h = metro_max(Source::Ply(ply.clone()), Source::Ply(out), None, 64 << 20);
            assert!(h <= e, "{}: the cut at error {e:.3e} is {h:.3e} from the input by metro ({:.2}x)", simp.name(), h / e);
        }
        assert!(errors.len() >= 5, "{}: {} cuts checked", simp.name(), errors.len());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

/// Issue 32: a many-island atlas (a uv seam along every island border, as
/// photogrammetry writes them) simplifies along its seams with either
/// simplifier: the levels halve, seams are not locked and shrink level by
/// level (locked, they stayed whole: 97 % of a textured scan's level 2),
/// every cut welded by position is closed (nothing tears), and no stored
/// triangle spans two islands' tiles (no island bleeds into another).
#[test]
fn atlas_seams_simplify_without_tears_or_bleeding() {
    for simp in SIMPLIFIERS {
        let d = tempfile::tempdir().unwrap();
        let base = common::gen_mesh(Shape::Sphere, 40_000, AttrSet::UV, 5);
        let (input, tiles) = octolod::gen::atlas::atlas(&base, 5);
        let ply = d.path().join("atlas.ply");
        let opts = octolod::ply::write::PlyWriteOptions { attrs: AttrSet(AttrSet::UV), ..Default::default() };
        octolod::ply::write::write_ply(&ply, &opts, &input.vertices, &input.triangles).unwrap();
        let s = common::build_from_with(d.path(), &ply, 1000, simp);
        let name = format!("atlas sphere ({})", simp.name());
        check_dag(&s, &name);
        check_cuts(&s, &input, &name, true);
        // Down to 10 triangles an island (about 100 islands): edge collapse
        // keeps each island's border loop, so a few levels below that stall
        // and the single node that no longer shrinks is the root.
        let tris: Vec<u64> = (0..=s.top_level()).map(|l| s.level_triangles(l)).collect();
        for w in tris.windows(2).filter(|w| w[0] >= 1000) {
            let r = w[1] as f64 / w[0] as f64;
            assert!((0.35..=0.65).contains(&r), "{name}: levels do not halve: {tris:?}");
        }
        assert!(*tris.last().unwrap() <= 400, "{name}: {tris:?}");
        let mut bleeding = 0;
        let manifest = octolod::manifest::Manifest::read(&s.dir).unwrap();
        let mut seams_at = Vec::new();
        for l in 0..=s.top_level() {
            // Positions holding vertices of several islands, this level.
            let mut islands: HashMap<[u64; 3], std::collections::HashSet<(i64, i64)>> = HashMap::new();
            for i in s.level_nodes(l) {
                let m = s.read_node(i).unwrap().mesh;
                for t in &m.triangles {
                    let c = t.map(|v| octolod::gen::atlas::tile(m.vertices[v as usize].uv, tiles));
                    bleeding += (c[0] != c[1] || c[1] != c[2]) as usize;
                    for (k, &v) in t.iter().enumerate() {
                        islands.entry(m.vertices[v as usize].pos.map(f64::to_bits)).or_default().insert(c[k]);
                    }
                }
            }
            let seams = islands.values().filter(|s| s.len() > 1).count();
            let locked = manifest.levels[l as usize].locked_fraction;
            eprintln!("{name}: level {l}: {} positions, {seams} on seams, {:.1}% locked", islands.len(), 100.0 * locked);
            // Only positions shared between nodes are locked (about 15 % at
            // 1000-triangle nodes); seams are not: were they, at least the
            // seams' share would be. Near the top, where a level's nodes
            // hold a few hundred triangles and most positions are on seams
            // (79 % at level 5), the shared share grows past a quarter.
            let seam_share = seams as f64 / islands.len().max(1) as f64;
            assert!(locked < 0.25f64.max(0.5 * seam_share), "{name}: level {l}: {:.1}% locked, {:.1}% on seams", 100.0 * locked, 100.0 * seam_share);
            seams_at.push(seams);
        }
        // Seams shrink level by level (slower than the surface at first:
        // they are lines, and their shape costs what a border's does), to
        // under a third of the input's by 1/16 of its triangles. Locked,
        // they stayed whole at every level.
        assert!(seams_at.windows(2).all(|w| w[1] <= w[0]), "{name}: seam positions per level {seams_at:?}");
        let l4 = tris.iter().position(|&t| t * 16 <= tris[0]).unwrap();
        assert!(seams_at[l4] * 3 <= seams_at[0], "{name}: seam positions per level {seams_at:?}");
        assert_eq!(bleeding, 0, "{name}: {bleeding} stored triangles span two islands");
    }
}

/// Issue 32's hard cases stay stable with either simplifier: uvs far
/// outside [0, 1], islands sharing (tiling) one tile's uvs, islands whose
/// uvs are all one point (degenerate uv triangles), vertices on three or
/// more islands. Every stored uv is finite and lies in the uv box of one
/// island that its triangle's corners all fit (no bleeding), a degenerate
/// island's uv stays its point exactly, and every cut is closed.
#[test]
fn hard_uv_cases_stay_stable() {
    let base = common::gen_mesh(Shape::Sphere, 20_000, AttrSet::UV, 3);
    let (mut input, tiles) = octolod::gen::atlas::atlas(&base, 4);
    let island = |uv: [f32; 2]| octolod::gen::atlas::tile(uv, tiles);
    // Vertices on three or more islands exist (cell corners).
    let mut at: HashMap<[u64; 3], std::collections::HashSet<(i64, i64)>> = HashMap::new();
    for v in &input.vertices {
        at.entry(v.pos.map(f64::to_bits)).or_default().insert(island(v.uv));
    }
    assert!(at.values().any(|s| s.len() >= 3), "no vertex on three islands");
    // Re-map islands: every third far outside [0, 1], every third one point,
    // every fifth onto tile (0, 0) (tiling).
    let mut boxes: HashMap<i64, ([f32; 2], [f32; 2])> = HashMap::new();
    let key = |t: (i64, i64)| t.0 * 1000 + t.1;
    let mut of_vertex = Vec::new();
    for v in input.vertices.iter_mut() {
        let t = island(v.uv);
        let k = key(t);
        let local = [v.uv[0] * tiles as f32 - t.0 as f32, v.uv[1] * tiles as f32 - t.1 as f32];
        v.uv = match k % 3 {
            0 => [local[0] + 7.0 + 3.0 * t.0 as f32, local[1] - 5.0 - 3.0 * t.1 as f32],
            1 => [0.25 + t.0 as f32 * 0.01, 0.75 + t.1 as f32 * 0.01],
            _ if k % 5 == 2 => local,
            _ => [v.uv[0] + 20.0, v.uv[1]],
        };
        of_vertex.push(k);
        let b = boxes.entry(k).or_insert(([f32::MAX; 2], [f32::MIN; 2]));
        for d in 0..2 {
            b.0[d] = b.0[d].min(v.uv[d]);
            b.1[d] = b.1[d].max(v.uv[d]);
        }
    }
    let points: std::collections::HashSet<[u32; 2]> = boxes.iter().filter(|(k, _)| *k % 3 == 1).map(|(_, b)| b.0.map(f32::to_bits)).collect();
    let d = tempfile::tempdir().unwrap();
    let ply = d.path().join("hard-uv.ply");
    let opts = octolod::ply::write::PlyWriteOptions { attrs: AttrSet(AttrSet::UV), ..Default::default() };
    octolod::ply::write::write_ply(&ply, &opts, &input.vertices, &input.triangles).unwrap();
    for simp in SIMPLIFIERS {
        let s = common::build_from_with(d.path(), &ply, 1000, simp);
        let name = format!("hard uvs ({})", simp.name());
        check_dag(&s, &name);
        check_cuts(&s, &input, &name, true);
        let inside = |uv: [f32; 2], b: &([f32; 2], [f32; 2])| (0..2).all(|k| uv[k] >= b.0[k] - 1e-6 && uv[k] <= b.1[k] + 1e-6);
        let (mut bled, mut moved_points) = (0, 0);
        for i in 1..s.nodes.len() {
            let m = s.read_node(i).unwrap().mesh;
            for t in &m.triangles {
                let c = t.map(|v| m.vertices[v as usize].uv);
                assert!(c.iter().flatten().all(|x| x.is_finite()), "{name}: a non-finite uv");
                bled += !boxes.values().any(|b| c.iter().all(|&uv| inside(uv, b))) as usize;
                // A corner inside a point island's box is that point.
                for uv in c {
                    let near_point = boxes.iter().any(|(k, b)| k % 3 == 1 && (0..2).all(|d| (uv[d] - b.0[d]).abs() < 0.004));
                    moved_points += (near_point && !points.contains(&uv.map(f32::to_bits))) as usize;
                }
            }
        }
        let _ = &of_vertex;
        assert_eq!(bled, 0, "{name}: {bled} stored triangles span islands");
        assert_eq!(moved_points, 0, "{name}: {moved_points} corners near a one-point island's uv but not on it");
    }
}

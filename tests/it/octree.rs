//! The out-of-core octree equals a straightforward top-down partition, keeps
//! every triangle exactly once (level 0 round-trips exactly), and does not
//! depend on the memory budget.

use crate::common::gen_mesh;
use octolod::gen::Shape;
use octolod::lod::octree::{build_octree, FirstCount, OctreeOptions};
use octolod::lod::partition::{LevelCube, KEY_DEPTH};
use octolod::mesh::{AttrSet, Vertex};
use octolod::ply::write::{write_ply, PlyWriteOptions};
use octolod::soup::format::SoupReader;
use octolod::soup::{build_soup, build_soup_tapped, SoupOptions};
use std::path::Path;

fn make_soup(dir: &Path, shape: Shape, tris: u64, attrs: u32) -> std::path::PathBuf {
    let m = gen_mesh(shape, tris, attrs, 3);
    let ply = dir.join("in.ply");
    write_ply(&ply, &PlyWriteOptions { attrs: AttrSet(attrs), ..Default::default() }, &m.vertices, &m.triangles).unwrap();
    let soup = dir.join("in.soup");
    build_soup(&ply, &soup, &SoupOptions::default()).unwrap();
    soup
}

/// Top-down reference: split while count > limit and depth < max.
fn reference(keys: &[u64], prefix: u64, d: u8, max: u8, limit: usize, out: &mut Vec<(u64, u8, usize)>) {
    if keys.is_empty() {
        return;
    }
    if keys.len() <= limit || d == max {
        out.push((prefix, d, keys.len()));
        return;
    }
    for oct in 0..8u64 {
        let child = prefix << 3 | oct;
        let sh = 3 * (max - d - 1) as u32;
        let sub: Vec<u64> = keys.iter().copied().filter(|k| k >> sh == child).collect();
        reference(&sub, child, d + 1, max, limit, out);
    }
}

fn tri_key(t: &[Vertex; 3]) -> Vec<u64> {
    t.iter().flat_map(|v| v.pos.iter().map(|x| x.to_bits()).chain(v.normal.iter().map(|x| x.to_bits() as u64))).collect()
}

fn check(shape: Shape, tris: u64, attrs: u32, limit: u64, max_depth: u8) {
    let dir = tempfile::tempdir().unwrap();
    let soup = make_soup(dir.path(), shape, tris, attrs);
    let (sh, all) = SoupReader::read_all(&soup).unwrap();
    let cube = LevelCube::for_level(&sh.bbox, 0);
    let mut results = Vec::new();
    for mem in [16 << 10, 64 << 20] {
        let l0 = build_octree(&soup, dir.path().join(format!("chunks-{mem}")), &cube, &OctreeOptions { leaf_tris: limit, max_depth, mem, quiet: true }, None)
            .unwrap();
        if mem == 16 << 10 && all.len() > 1000 {
            // Buffers of a quarter of the budget cannot hold a leaf, and
            // 128 cells (--mem / 128 bytes) not the deepest level.
            assert!(l0.report.chunks > l0.report.leaves, "tiny budget should spill partial leaves: {:?}", l0.report);
            let cells = |d: u8| {
                let mut c: Vec<u64> =
                    all.iter().map(|t| cube.key([0, 1, 2].map(|a| t.iter().map(|v| v.pos[a] / 3.0).sum::<f64>())) >> (3 * (KEY_DEPTH - d) as u32)).collect();
                c.sort();
                c.dedup();
                c.len()
            };
            if cells(l0.report.deepest) > 128 {
                assert!(l0.report.counting_passes > 1, "tiny budget should count in several passes: {:?}", l0.report);
            }
        } else {
            assert_eq!(l0.report.counting_passes, 1);
        }
        results.push(l0);
    }
    let l0 = &results[0];
    let leaves = |l: &octolod::lod::octree::Level0| -> Vec<(u64, u8, u64)> {
        l.tiling.leaves.iter().zip(&l.leaves).filter(|(_, s)| s.tris > 0).map(|(t, s)| (t.path, t.depth, s.tris)).collect()
    };
    assert_eq!(leaves(l0), leaves(&results[1]), "octree depends on the memory budget");
    // Counted as the soup is written (the external soup path, as `build`
    // does): the same soup, the same leaves, one counting pass fewer.
    let ply = dir.path().join("in.ply");
    for (k, mem) in [16u64 << 10, 64 << 20].into_iter().enumerate() {
        let opts = OctreeOptions { leaf_tris: limit, max_depth, mem, quiet: true };
        let mut first = FirstCount::new(&opts);
        let tapped = dir.path().join(format!("tapped-{mem}.soup"));
        let so = SoupOptions { mem: 1 << 20, force_external: true, ..Default::default() };
        build_soup_tapped(&ply, &tapped, &so, Some(&mut first)).unwrap();
        assert_eq!(std::fs::read(&tapped).unwrap(), std::fs::read(&soup).unwrap(), "the tap changed the soup");
        let t0 = build_octree(&tapped, dir.path().join(format!("chunks-t{mem}")), &cube, &opts, Some(first)).unwrap();
        assert_eq!(leaves(&t0), leaves(&results[k]), "counting as the soup is written changed the leaves");
        assert_eq!(t0.report.counting_passes + 1, results[k].report.counting_passes, "{:?}", t0.report);
    }
    // Routed as the soup is made (as `build` does): where one counting pass
    // is enough no soup file is written, and the leaves read exactly as
    // those of the partition that reads the soup.
    for (k, mem) in [16u64 << 10, 64 << 20].into_iter().enumerate() {
        let opts = OctreeOptions { leaf_tris: limit, max_depth, mem, quiet: true };
        let mut first = FirstCount::routing(&opts, dir.path().join(format!("chunks-r{mem}")), &ply);
        let routed = dir.path().join(format!("routed-{mem}.soup"));
        let so = SoupOptions { mem: 1 << 20, force_external: true, ..Default::default() };
        let rep = build_soup_tapped(&ply, &routed, &so, Some(&mut first)).unwrap();
        let one_pass = results[k].report.counting_passes == 1;
        assert_eq!(rep.written, !one_pass, "{:?}", results[k].report);
        assert_eq!(routed.exists(), rep.written);
        assert_eq!(rep.header, sh, "the routed soup's header differs from the written soup's");
        let r0 = match first.take_level0(&rep.header).unwrap() {
            Some(r0) => r0,
            None => build_octree(&routed, dir.path().join(format!("chunks-rs{mem}")), &cube, &opts, Some(first)).unwrap(),
        };
        assert_eq!(leaves(&r0), leaves(&results[k]), "routing as the soup is made changed the leaves");
        // Not routed: the partition still counts one pass fewer.
        let passes = if one_pass { 0 } else { results[k].report.counting_passes - 1 };
        assert_eq!(r0.report.counting_passes, passes, "{:?}", r0.report);
        for i in 0..r0.leaves.len() {
            let (a, b) = (r0.chunks.gather(i).unwrap().mesh, results[k].chunks.gather(i).unwrap().mesh);
            assert!(a.triangles == b.triangles && a.vertices == b.vertices, "leaf {i} reads differently when routed as the soup is made");
        }
    }
    // The tiling covers every key once.
    for w in l0.tiling.leaves.windows(2) {
        assert_eq!(w[0].end, w[1].start);
    }
    // Leaves equal the top-down reference partition of the triangles'
    // first corners.
    let mut keys: Vec<u64> = all.iter().map(|t| cube.key(t[0].pos) >> (3 * (KEY_DEPTH - max_depth) as u32)).collect();
    keys.sort();
    let mut want = Vec::new();
    reference(&keys, 0, 0, max_depth, limit as usize, &mut want);
    let got: Vec<(u64, u8, usize)> = leaves(l0).into_iter().map(|(p, d, n)| (p, d, n as usize)).collect();
    assert_eq!(got, want, "leaves differ from the top-down partition");
    assert_eq!(l0.report.leaves as usize, want.len());
    // Level 0 round trip: the union of the leaves' chunks is the soup, as a
    // set; every first corner lies in its leaf's cell, every corner in its
    // bounds and within its reach of the first.
    let mut got_tris = Vec::new();
    for (i, (t, st)) in l0.tiling.leaves.iter().zip(&l0.leaves).enumerate() {
        let g = l0.chunks.gather(i).unwrap();
        assert_eq!(g.mesh.triangles.len() as u64, st.tris);
        let cell = cube.cell(t.path, t.depth);
        for tri in &g.mesh.triangles {
            let tri = tri.map(|k| g.mesh.vertices[k as usize]);
            let c = tri[0].pos;
            #[allow(clippy::needless_range_loop, reason = "axis loop over the corner, cell and bounds in lockstep")]
            for a in 0..3 {
                let slack = 1e-9 * cube.size;
                assert!(c[a] >= cell.min[a] - slack && c[a] <= cell.max[a] + slack, "first corner outside its leaf cell");
                assert!(tri.iter().all(|v| v.pos[a] >= st.bounds.min[a] && v.pos[a] <= st.bounds.max[a]));
                assert!(tri.iter().all(|v| (v.pos[a] - c[a]).abs() <= st.reach));
            }
            got_tris.push(tri_key(&tri));
        }
    }
    let mut want_tris: Vec<Vec<u64>> = all.iter().map(tri_key).collect();
    got_tris.sort();
    want_tris.sort();
    assert!(got_tris == want_tris, "level 0 is not exactly the input triangles");
}

#[test]
fn sphere_partition_matches_reference_and_round_trips() {
    check(Shape::Sphere, 40_000, AttrSet::NORMAL, 1000, 12);
}

#[test]
fn offset_doubles_round_trip_exactly() {
    check(Shape::Offset, 20_000, AttrSet::POS_F64, 700, 10);
}

#[test]
fn max_depth_caps_splitting_with_overfull_leaves() {
    // Instances are many small objects: depth 3 forces leaves above the limit.
    check(Shape::Instances, 30_000, 0, 200, 3);
}

#[test]
fn single_triangle_is_a_root_leaf() {
    check(Shape::Single, 1, 0, 10, 8);
}

#[test]
fn duplicate_triangles_stay_duplicated() {
    check(Shape::Duplicates, 5_000, 0, 64, 21);
}

/// A vertex no face uses, outside the faces' box: the cells counted in the
/// soup stage's phase 2 (in the box of every vertex) are for the wrong
/// cube, so phase 3 counts again and the soup is written and routed from
/// the file; the leaves and their triangles are those of a partition that
/// never saw the stray vertex.
#[test]
fn a_stray_vertex_outside_the_faces_falls_back_to_the_written_soup() {
    let dir = tempfile::tempdir().unwrap();
    let octolod::mesh::IndexedMesh { vertices: mut v, triangles: f } = gen_mesh(Shape::Sphere, 20_000, 0, 5);
    v.push(Vertex { pos: [40.0, -3.0, 7.0], ..Default::default() });
    let ply = dir.path().join("stray.ply");
    write_ply(&ply, &PlyWriteOptions::default(), &v, &f).unwrap();
    let opts = OctreeOptions { leaf_tris: 500, max_depth: 12, mem: 64 << 20, quiet: true };
    let so = SoupOptions { mem: 1 << 20, force_external: true, ..Default::default() };
    let plain = dir.path().join("plain.soup");
    build_soup(&ply, &plain, &so).unwrap();
    let (sh, _) = SoupReader::read_all(&plain).unwrap();
    let cube = LevelCube::for_level(&sh.bbox, 0);
    let mut all_box = octolod::mesh::Aabb::EMPTY;
    v.iter().for_each(|v| all_box.add(v.pos));
    assert!(cube != LevelCube::for_level(&all_box, 0), "the stray vertex must move the cube");
    let want = build_octree(&plain, dir.path().join("chunks-p"), &cube, &opts, None).unwrap();

    let routed = dir.path().join("routed.soup");
    let mut first = FirstCount::routing(&opts, dir.path().join("chunks-r"), &ply);
    let rep = build_soup_tapped(&ply, &routed, &so, Some(&mut first)).unwrap();
    assert!(rep.written && routed.exists(), "a tap counted in the wrong cube must not route");
    assert_eq!(rep.header, sh);
    assert!(first.take_level0(&rep.header).unwrap().is_none());
    let got = build_octree(&routed, dir.path().join("chunks-g"), &cube, &opts, Some(first)).unwrap();
    // Counted in phase 3 instead: no counting pass here.
    assert_eq!((got.report.counting_passes, want.report.counting_passes), (0, 1));
    assert_eq!(got.report.leaves, want.report.leaves);
    for i in 0..want.leaves.len() {
        let (a, b) = (got.chunks.gather(i).unwrap().mesh, want.chunks.gather(i).unwrap().mesh);
        assert!(a.triangles == b.triangles && a.vertices == b.vertices, "leaf {i} differs");
    }
}

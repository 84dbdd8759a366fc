//! The out-of-core octree equals a straightforward top-down partition, keeps
//! every triangle exactly once (level 0 round-trips exactly), and does not
//! depend on the memory budget.

use octolod::gen::{GenOptions, Generator, Shape};
use octolod::mesh::{AttrSet, Vertex};
use octolod::octree::{build_octree, FirstCount, OctreeOptions};
use octolod::ply::write::{write_ply, PlyWriteOptions};
use octolod::soup::format::SoupReader;
use octolod::soup::{build_soup, build_soup_tapped, SoupOptions};
use octolod::lod::partition::{LevelCube, KEY_DEPTH};
use std::path::Path;

fn make_soup(dir: &Path, shape: Shape, tris: u64, attrs: u32) -> std::path::PathBuf {
    let g = Generator::new(&GenOptions { shape, tris, seed: 3, attrs: AttrSet(attrs) });
    let (v, f) = g.mesh();
    let ply = dir.join("in.ply");
    write_ply(&ply, &PlyWriteOptions { attrs: AttrSet(attrs), ..Default::default() }, &v, &f).unwrap();
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
                let mut c: Vec<u64> = all.iter().map(|t| cube.key([0, 1, 2].map(|a| t.iter().map(|v| v.pos[a] / 3.0).sum::<f64>())) >> (3 * (KEY_DEPTH - d) as u32)).collect();
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
    let leaves = |l: &octolod::octree::Level0| -> Vec<(u64, u8, u64)> {
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
    // The tiling covers every key once.
    for w in l0.tiling.leaves.windows(2) {
        assert_eq!(w[0].end, w[1].start);
    }
    // Leaves equal the top-down reference partition.
    let mut keys: Vec<u64> = all
        .iter()
        .map(|t| {
            let c = [0, 1, 2].map(|a| t.iter().map(|v| v.pos[a] / 3.0).sum::<f64>());
            cube.key(c) >> (3 * (KEY_DEPTH - max_depth) as u32)
        })
        .collect();
    keys.sort();
    let mut want = Vec::new();
    reference(&keys, 0, 0, max_depth, limit as usize, &mut want);
    let got: Vec<(u64, u8, usize)> = leaves(l0).into_iter().map(|(p, d, n)| (p, d, n as usize)).collect();
    assert_eq!(got, want, "leaves differ from the top-down partition");
    assert_eq!(l0.report.leaves as usize, want.len());
    // Level 0 round trip: the union of the leaves' chunks is the soup, as a
    // set; every centroid lies in its leaf's cell and every corner in its bounds.
    let mut got_tris = Vec::new();
    for (i, (t, st)) in l0.tiling.leaves.iter().zip(&l0.leaves).enumerate() {
        let g = l0.chunks.gather(i).unwrap();
        assert_eq!(g.mesh.triangles.len() as u64, st.tris);
        let cell = cube.cell(t.path, t.depth);
        for tri in &g.mesh.triangles {
            let tri = tri.map(|k| g.mesh.vertices[k as usize]);
            let c = [0, 1, 2].map(|a| tri.iter().map(|v| v.pos[a] / 3.0).sum::<f64>());
            for a in 0..3 {
                let slack = 1e-9 * cube.size;
                assert!(c[a] >= cell.min[a] - slack && c[a] <= cell.max[a] + slack, "centroid outside its leaf cell");
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

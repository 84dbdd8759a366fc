//! `octolod metro` against known answers: identical meshes, a plane against
//! its offset copy, a sphere against an inscribed icosphere, a store level
//! against the PLY it was built from; and the command line (JSON, thresholds
//! and exit codes, determinism).

use crate::common::cli::{err as text_err, octolod, out as text_out};
use crate::common::{build_options, build_store_at, gen_mesh, json, same_figure, BuildParams};
use octolod::gen::Shape;
use octolod::mesh::{AttrSet, Vertex};
use octolod::metro::{compare, Mesh, Options};
use octolod::ply::write::{write_ply, PlyWriteOptions};
use serde_json::Value;
use std::collections::HashMap;
use std::path::Path;

// ---------------------------------------------------------------------------
// Helpers.

fn generated(shape: Shape, tris: u64) -> Mesh {
    let m = gen_mesh(shape, tris, 0, 3);
    Mesh::from_vertices(&m.vertices, m.triangles)
}

/// A subdivided icosahedron with every vertex on the unit sphere.
fn icosphere(level: u32) -> Mesh {
    let g = (1.0 + 5f64.sqrt()) / 2.0;
    let mut pos: Vec<[f64; 3]> = [
        [-1.0, g, 0.0],
        [1.0, g, 0.0],
        [-1.0, -g, 0.0],
        [1.0, -g, 0.0],
        [0.0, -1.0, g],
        [0.0, 1.0, g],
        [0.0, -1.0, -g],
        [0.0, 1.0, -g],
        [g, 0.0, -1.0],
        [g, 0.0, 1.0],
        [-g, 0.0, -1.0],
        [-g, 0.0, 1.0],
    ]
    .into_iter()
    .map(unit)
    .collect();
    let mut tris: Vec<[u32; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..level {
        let mut mid: HashMap<(u32, u32), u32> = HashMap::new();
        let mut next = Vec::with_capacity(tris.len() * 4);
        for t in &tris {
            let mut m = [0u32; 3];
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                m[k] = *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                    let (p, q) = (pos[a as usize], pos[b as usize]);
                    pos.push(unit([p[0] + q[0], p[1] + q[1], p[2] + q[2]]));
                    pos.len() as u32 - 1
                });
            }
            next.extend([[t[0], m[0], m[2]], [t[1], m[1], m[0]], [t[2], m[2], m[1]], [m[0], m[1], m[2]]]);
        }
        tris = next;
    }
    Mesh::new(pos, tris)
}

fn unit(p: [f64; 3]) -> [f64; 3] {
    let l = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
    [p[0] / l, p[1] / l, p[2] / l]
}

fn opts(samples: Option<u64>) -> Options {
    Options { samples, seed: 1, quiet: true }
}

fn write_mesh(path: &Path, m: &Mesh) {
    let v: Vec<Vertex> = m.positions.iter().map(|&pos| Vertex { pos, ..Vertex::default() }).collect();
    let o = PlyWriteOptions { attrs: AttrSet::POSITION_ONLY.with(AttrSet::POS_F64, true), ..Default::default() };
    write_ply(path, &o, &v, &m.triangles).unwrap();
}

/// The value at `path` (keys joined by dots) of a JSON report.
fn get<'a>(j: &'a Value, path: &str) -> &'a Value {
    path.split('.').fold(j, |v, k| v.get(k).unwrap_or_else(|| panic!("no '{k}' in {path}: {j}")))
}

/// The number at `path` of a JSON report.
fn num(j: &Value, path: &str) -> f64 {
    let v = get(j, path);
    v.as_f64().unwrap_or_else(|| panic!("{path} is {v}, not a number"))
}

// ---------------------------------------------------------------------------
// Known answers in the library.

#[test]
fn identical_meshes_are_at_distance_zero() {
    for m in [generated(Shape::Sphere, 3000), generated(Shape::Terrain, 2000), icosphere(2)] {
        let r = compare(&m, &m, &opts(None)).unwrap();
        let diag = r.diagonal;
        assert!(diag > 0.0);
        assert_eq!(r.samples_target, 10 * m.triangles.len() as u64);
        for d in [&r.a_to_b, &r.b_to_a, &r.combined] {
            assert!(d.samples + 2 >= r.samples_target && d.face_samples > 0 && d.edge_samples > 0 && d.vertex_samples > 0, "{d:?}");
            assert!(d.max / diag < 1e-12 && d.mean / diag < 1e-12 && d.rms / diag < 1e-12, "{d:?}");
        }
    }
}

#[test]
fn plane_against_its_offset_copy_is_at_the_offset() {
    let a = generated(Shape::Plane, 2000);
    assert!(a.positions.iter().all(|p| p[2] == 0.0));
    let d = 0.0123;
    let mut b = a.clone();
    for p in &mut b.positions {
        p[2] += d;
    }
    // Shift A's triangulation relative to B's too: B with a coarser grid of
    // the same extent gives the same answer (every nearest point is still
    // straight above or below).
    let b_coarse = {
        let mut m = generated(Shape::Plane, 200);
        for p in &mut m.positions {
            p[2] += d;
        }
        m
    };
    for b in [&b, &b_coarse] {
        let r = compare(&a, b, &opts(None)).unwrap();
        for x in [&r.a_to_b, &r.b_to_a, &r.combined] {
            for (name, v) in [("max", x.max), ("mean", x.mean), ("rms", x.rms)] {
                assert!((v - d).abs() <= 1e-9 * d, "{name} = {v}, want {d}");
            }
        }
        assert!((r.diagonal - 2f64.sqrt()).abs() < 1e-12, "A's diagonal is sqrt 2: {}", r.diagonal);
        assert!((r.union_diagonal - (2.0 + d * d).sqrt()).abs() < 1e-12);
    }
}

#[test]
fn dense_sphere_against_inscribed_icosphere_matches_the_analytic_maximum() {
    let sphere = icosphere(5); // 20480 faces, vertices on the unit sphere
    let poly = icosphere(1); // 80 faces, inscribed
                             // The sphere's farthest point from the polyhedron lies straight above the
                             // foot of the face plane closest to the centre: 1 - min inradius.
    let h_min = poly
        .triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| poly.positions[i as usize]);
            let (u, v) = ([b[0] - a[0], b[1] - a[1], b[2] - a[2]], [c[0] - a[0], c[1] - a[1], c[2] - a[2]]);
            let n = unit([u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]);
            (n[0] * a[0] + n[1] * a[1] + n[2] * a[2]).abs()
        })
        .fold(f64::INFINITY, f64::min);
    let analytic = 1.0 - h_min;
    assert!(analytic > 0.04 && analytic < 0.1, "{analytic}");
    let r = compare(&sphere, &poly, &opts(Some(100_000))).unwrap();
    let ab = r.a_to_b.max;
    assert!((ab - analytic).abs() <= 0.01 * analytic, "A->B max {ab} vs analytic {analytic}");
    // Polyhedron -> sphere: the face foot is as far from the (slightly
    // inscribed) dense sphere.
    let ba = r.b_to_a.max;
    assert!((ba - analytic).abs() <= 0.01 * analytic, "B->A max {ba} vs analytic {analytic}");
    assert_eq!(r.combined.max, ab.max(ba));
    // The mean lies well inside (0, max).
    assert!(r.a_to_b.mean > 0.1 * analytic && r.a_to_b.mean < 0.7 * analytic, "{}", r.a_to_b.mean);
}

// ---------------------------------------------------------------------------
// The command line.

#[test]
fn thresholds_set_the_exit_code_and_json_has_the_fields() {
    let d = tempfile::tempdir().unwrap();
    let (a, b) = (d.path().join("a.ply"), d.path().join("b.ply"));
    write_mesh(&a, &icosphere(3));
    write_mesh(&b, &icosphere(2));
    let (a, b) = (a.to_str().unwrap(), b.to_str().unwrap());

    let o = octolod(&["metro", a, b, "--json", "--max-hausdorff", "1%"]);
    assert_eq!(o.status.code(), Some(0), "{}", text_err(&o));
    let j = json(&o.stdout);
    for k in ["a_to_b", "b_to_a", "combined"] {
        for f in ["max", "mean", "rms", "max_rel", "mean_rel", "rms_rel", "samples", "vertex_samples", "edge_samples", "face_samples"] {
            let _ = num(&j, &format!("{k}.{f}"));
        }
        let (rel, max, diag) = (num(&j, &format!("{k}.max_rel")), num(&j, &format!("{k}.max")), num(&j, "diagonal"));
        assert!(same_figure(rel, max / diag), "{k}: max_rel {rel}, max / diagonal {}", max / diag);
    }
    for k in ["a", "b"] {
        let _ = (num(&j, &format!("{k}.faces")), num(&j, &format!("{k}.vertices")), num(&j, &format!("{k}.diagonal")));
        assert_eq!(get(&j, &format!("{k}.bbox.min")).as_array().map(Vec::len), Some(3));
    }
    assert_eq!(num(&j, "a.faces"), 1280.0);
    assert_eq!(num(&j, "b.faces"), 320.0);
    assert_eq!(num(&j, "samples_target"), 12800.0);
    assert_eq!(get(&j, "diagonal_of"), "a");
    assert_eq!(get(&j, "pass"), &true);
    let h = num(&j, "hausdorff");
    assert_eq!(h, num(&j, "combined.max"));
    assert_eq!(h, num(&j, "a_to_b.max").max(num(&j, "b_to_a.max")));
    let diag = num(&j, "diagonal");
    assert!((diag - 2.0 * 3f64.sqrt()).abs() < 1e-3, "{diag}");
    // A 1 % limit passes, so the distance is below 3.46e-2; but it is not tiny.
    assert!(h > 1e-3 && h < 0.01 * diag, "{h}");
    assert!(text_err(&o).is_empty(), "{}", text_err(&o));
    let th = get(&j, "thresholds").as_array().unwrap();
    assert_eq!(th.len(), 1);
    assert_eq!(get(&th[0], "exceeded"), &false);
    assert!((num(&th[0], "limit") - 0.01 * diag).abs() < 1e-15);

    // An absolute limit below the distance fails with exit 3, naming it.
    let o = octolod(&["metro", a, b, "--max-hausdorff", "0.0001"]);
    assert_eq!(o.status.code(), Some(3), "{}", text_err(&o));
    assert!(text_err(&o).contains("--max-hausdorff"), "{}", text_err(&o));
    assert!(text_out(&o).contains("A -> B") && text_out(&o).contains("B -> A"), "{}", text_out(&o));
    // Percentages: just above and just below the measured relative figure.
    let pct = 100.0 * h / diag;
    let above = format!("{}%", pct * 1.01);
    let below = format!("{}%", pct * 0.99);
    assert_eq!(octolod(&["metro", a, b, "--max-hausdorff", &above]).status.code(), Some(0));
    let o = octolod(&["metro", a, b, "--max-hausdorff", &below, "--json"]);
    assert_eq!(o.status.code(), Some(3));
    let j = json(&o.stdout);
    assert_eq!(get(&j, "pass"), &false);
    // RMS and mean limits, only the exceeded one reported.
    let (rms, mean) = (num(&j, "combined.rms"), num(&j, "combined.mean"));
    let o = octolod(&["metro", a, b, "--max-rms", &format!("{}", rms * 0.9), "--max-mean", &format!("{}", mean * 1.1)]);
    assert_eq!(o.status.code(), Some(3));
    let e = text_err(&o);
    assert!(e.contains("--max-rms") && !e.contains("--max-mean"), "{e}");
    let o = octolod(&["metro", a, b, "--max-rms", &format!("{}", rms * 1.1), "--max-mean", &format!("{}", mean * 1.1)]);
    assert_eq!(o.status.code(), Some(0), "{}", text_err(&o));

    // Bad thresholds and arguments are usage errors: exit 1.
    for bad in [["--max-hausdorff", "abc"], ["--max-rms", "1%%"], ["--max-mean", "nan"], ["--samples", "0"]] {
        let o = octolod(&["metro", a, b, bad[0], bad[1]]);
        assert_eq!(o.status.code(), Some(1), "{bad:?}: {}", text_err(&o));
        assert!(text_out(&o).is_empty());
    }
    let o = octolod(&["metro", a, d.path().join("missing.ply").to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1));
}

#[test]
fn same_seed_same_json_and_the_seed_matters() {
    let d = tempfile::tempdir().unwrap();
    let (a, b) = (d.path().join("a.ply"), d.path().join("b.ply"));
    write_mesh(&a, &generated(Shape::Sphere, 4000));
    write_mesh(&b, &icosphere(3));
    let (a, b) = (a.to_str().unwrap(), b.to_str().unwrap());
    let run = |seed: &str| {
        let o = octolod(&["metro", a, b, "--json", "--seed", seed, "--samples", "30000"]);
        assert!(o.status.success(), "{}", text_err(&o));
        text_out(&o)
    };
    let (x, y, z) = (run("7"), run("7"), run("8"));
    assert_eq!(x, y);
    assert_ne!(x, z);
    let j = json(x.as_bytes());
    assert_eq!(num(&j, "seed"), 7.0);
    assert!((num(&j, "a_to_b.samples") - 30000.0).abs() <= 1.0);
}

#[test]
fn a_store_level_measures_zero_at_level_0_and_as_the_library_does_above() {
    let d = tempfile::tempdir().unwrap();
    let ply = d.path().join("s.ply");
    let m = generated(Shape::Sphere, 6000);
    write_mesh(&ply, &m);
    let store = small_leaves_store(d.path(), &ply);
    let (p, s) = (ply.to_str().unwrap(), store.to_str().unwrap());

    // Level 0 is the input, bit-exact: distance 0 both ways.
    let o = octolod(&["metro", p, &format!("{s}@0"), "--json"]);
    assert!(o.status.success(), "{}", text_err(&o));
    let j = json(&o.stdout);
    assert_eq!(num(&j, "a.faces"), num(&j, "b.faces"));
    assert_eq!(num(&j, "a.vertices"), num(&j, "b.vertices"), "store vertices are welded back");
    assert!(num(&j, "hausdorff_rel") < 1e-12, "{}", num(&j, "hausdorff_rel"));
    assert_eq!(get(&j, "b.source"), format!("{s}@0").as_str());

    // A simplified level: a real, bounded distance, and the same answer
    // through the library.
    let top = octolod::store::Store::open(&store).unwrap().top_level();
    assert!(top >= 2);
    let o = octolod(&["metro", &format!("{s}@1"), p, "--json"]);
    assert!(o.status.success(), "{}", text_err(&o));
    let j = json(&o.stdout);
    let h = num(&j, "hausdorff_rel");
    assert!(h > 1e-5 && h < 0.05, "{h}");
    let lvl = octolod::metro::load_store_level(&store, 1).unwrap();
    let lib = compare(&lvl, &octolod::metro::load_ply(&ply).unwrap(), &opts(None)).unwrap();
    assert!(same_figure(lib.combined.max, num(&j, "hausdorff")), "library {}, command {}", lib.combined.max, num(&j, "hausdorff"));

    // A level that does not exist, and a bare store directory: usage errors.
    let o = octolod(&["metro", p, &format!("{s}@{}", top + 1)]);
    assert_eq!(o.status.code(), Some(1));
    assert!(text_err(&o).contains("does not exist"), "{}", text_err(&o));
    let o = octolod(&["metro", p, s]);
    assert_eq!(o.status.code(), Some(1));
    assert!(text_err(&o).contains("@L"), "{}", text_err(&o));
}

// ---------------------------------------------------------------------------
// Paging: store levels through the page cache.

/// A store of a generated sphere with small leaves (many parts per level).
fn small_store(dir: &Path) -> (std::path::PathBuf, std::path::PathBuf) {
    let ply = dir.join("s.ply");
    write_mesh(&ply, &generated(Shape::Sphere, 20_000));
    let store = small_leaves_store(dir, &ply);
    (ply, store)
}

/// `dir/STEM.octolod` built from `ply` with 500-triangle leaves under 4 MiB.
fn small_leaves_store(dir: &Path, ply: &Path) -> std::path::PathBuf {
    build_store_at(dir, ply, &build_options(BuildParams { mem: 4 << 20, leaf_tris: 500, ..Default::default() }))
}

fn close_rel(x: f64, y: f64) -> bool {
    (x - y).abs() <= 1e-12 * x.abs().max(y.abs())
}

#[test]
fn paged_store_levels_equal_the_in_memory_path_under_a_tiny_budget() {
    use octolod::metro::{compare_sources, load_ply, load_store_level, MemOptions, Source};
    let d = tempfile::tempdir().unwrap();
    let (ply, store) = small_store(d.path());
    let top = octolod::store::Store::open(&store).unwrap().top_level();
    assert!(top >= 3, "{top}");
    let level = |l: u8| Source::Store(store.clone(), l);
    let load = |s: &Source| match s {
        Source::Ply(p) => load_ply(p).unwrap(),
        Source::Store(dir, l) => load_store_level(dir, *l).unwrap(),
    };
    // 2 MiB: the batch buffers take 0.75 MiB, the cache gets ~1.2 MiB, a
    // fraction of levels 0 and 1's node meshes and indexes.
    let tiny = MemOptions { budget: 2 << 20, explicit: false };
    for (k, (a, b)) in [(level(0), level(1)), (Source::Ply(ply.clone()), level(2)), (level(top), Source::Ply(ply.clone()))].into_iter().enumerate() {
        let mem = compare(&load(&a), &load(&b), &opts(None)).unwrap();
        let paged = compare_sources(&a, &b, &opts(None), &tiny).unwrap();
        let what = format!("{a} vs {b}");
        for (x, y) in [(&mem.a, &paged.a), (&mem.b, &paged.b)] {
            assert_eq!((x.vertices, x.faces, x.area, x.bbox), (y.vertices, y.faces, y.area, y.bbox), "{what}");
        }
        assert_eq!(mem.samples_target, paged.samples_target);
        for (x, y) in [(&mem.a_to_b, &paged.a_to_b), (&mem.b_to_a, &paged.b_to_a)] {
            // The same samples ...
            assert_eq!((x.samples, x.vertex_samples, x.edge_samples, x.face_samples), (y.samples, y.vertex_samples, y.edge_samples, y.face_samples), "{what}");
            // ... at the same distances: each the minimum over the same
            // triangles, summed in the same order (bit-identical here; the
            // tolerance allows a near-tie pruned differently by the two
            // hierarchies).
            for (m, u, v) in [("max", x.max, y.max), ("mean", x.mean, y.mean), ("rms", x.rms, y.rms)] {
                assert!(close_rel(u, v), "{what}: {m} {u} in memory, {v} paged");
            }
            assert!(x.max > 0.0, "{what}");
        }
        let p = paged.paging.as_ref().expect("paging figures");
        assert!(mem.paging.is_none());
        let parts = p.parts.a.unwrap_or(0) + p.parts.b.unwrap_or(0);
        assert!(p.peak_resident > 0 && p.peak_resident <= p.cache_budget, "{what}: {p:?}");
        // Every part is read at least once as a sample source and once as a
        // query index; levels 0 and 1 together are several times the cache,
        // so their parts are evicted and read again.
        assert!(p.loads >= 2 * parts, "{what}: {p:?}");
        if k == 0 {
            assert!(parts > 50, "{what}: {p:?}");
            assert!(p.evictions > 0 && p.loads > 2 * parts, "{what}: the budget forces re-reads: {p:?}");
        }
        assert_eq!(p.overcommits, 0, "{what}: {p:?}");
        assert!(p.bytes_read > 0 && p.scan_bytes > 0 && p.hits > 0, "{what}: {p:?}");
    }
}

#[test]
fn paged_cli_reports_the_cache_streams_big_plys_and_rejects_budgets_it_cannot_keep() {
    let d = tempfile::tempdir().unwrap();
    let (ply, store) = small_store(d.path());
    let (p, s) = (ply.to_str().unwrap(), store.to_str().unwrap());
    let (s0, s1) = (format!("{s}@0"), format!("{s}@1"));
    let run = |mem: &str| {
        let o = octolod(&["metro", &s0, &s1, "--json", "--mem", mem]);
        assert!(o.status.success(), "{}", text_err(&o));
        json(&o.stdout)
    };
    let (small, big) = (run("2M"), run("1G"));
    for j in [&small, &big] {
        for f in ["budget", "cache_budget", "peak_resident", "loads", "hits", "evictions", "bytes_read", "scan_bytes", "parts.a", "parts.b"] {
            let _ = num(j, &format!("paging.{f}"));
        }
        assert!(num(j, "paging.peak_resident") <= num(j, "paging.cache_budget"));
        assert_eq!(num(j, "paging.overcommits"), 0.0);
    }
    assert_eq!(num(&small, "paging.budget"), (2 << 20) as f64);
    assert!(num(&small, "paging.evictions") > 0.0);
    assert_eq!(num(&big, "paging.evictions"), 0.0, "1 GiB holds this store");
    // The budget changes how often nodes are read, never the figures.
    for k in ["a_to_b", "b_to_a", "combined"] {
        for f in ["samples", "vertex_samples", "edge_samples", "face_samples", "max", "mean", "rms"] {
            assert_eq!(num(&small, &format!("{k}.{f}")), num(&big, &format!("{k}.{f}")), "{k}.{f}");
        }
    }
    // A budget below two nodes' worth: a usage error naming what would do.
    let o = octolod(&["metro", &s0, &s1, "--mem", "800K"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(text_err(&o).contains("give --mem at least"), "{}", text_err(&o));
    assert!(text_out(&o).is_empty());
    // A PLY operand over an explicit budget is streamed into a scratch store
    // of its level 0 (exact input) and paged: same distances as the store's
    // level 0 up to sampling (vertex order differs), no scratch left behind.
    let o = octolod(&["metro", p, &s1, "--json", "--mem", "2M"]);
    assert!(o.status.success(), "{}", text_err(&o));
    let streamed = json(&o.stdout);
    assert!(num(&streamed, "paging.peak_resident") <= num(&streamed, "paging.cache_budget"));
    for f in ["max", "mean", "rms"] {
        let (x, y) = (num(&streamed, &format!("combined.{f}")), num(&small, &format!("combined.{f}")));
        assert!((x - y).abs() <= 0.05 * y, "combined.{f}: streamed PLY {x} vs store level 0 {y}");
    }
    let left: Vec<_> =
        std::fs::read_dir(d.path()).unwrap().filter_map(|e| e.ok()).filter(|e| e.file_name().to_string_lossy().starts_with(".octolod-scratch")).collect();
    assert!(left.is_empty(), "scratch store left behind");
    // PLYs only: no paging object, the JSON stays a pure function of the inputs.
    let o = octolod(&["metro", p, p, "--json", "--samples", "1000"]);
    assert!(o.status.success());
    assert!(!text_out(&o).contains("paging"));
}

/// Issue 32 item 4: `--attributes` measures the uv difference at the
/// closest point: 0 for a textured atlas against itself, small for a
/// fine level (both directions sampled), larger for a coarse one, and
/// absent from the JSON without the flag; the table prints it.
#[test]
fn attributes_are_measured_at_the_closest_point() {
    let d = tempfile::tempdir().unwrap();
    let (input, _) = octolod::gen::atlas::atlas(&gen_mesh(Shape::Sphere, 20_000, AttrSet::UV, 3), 4);
    let ply = d.path().join("atlas.ply");
    write_ply(&ply, &PlyWriteOptions { attrs: AttrSet(AttrSet::UV), ..Default::default() }, &input.vertices, &input.triangles).unwrap();
    let store = build_store_at(d.path(), &ply, &build_options(BuildParams { leaf_tris: 2000, ..Default::default() }));
    let uv = |b: &str, extra: &[&str]| -> Value {
        let mut args = vec!["--quiet", "metro", ply.to_str().unwrap(), b, "--json", "--samples", "200000"];
        args.extend_from_slice(extra);
        let o = octolod(&args);
        assert!(o.status.success(), "{}", text_err(&o));
        json(&o.stdout)
    };
    let same = uv(ply.to_str().unwrap(), &["--attributes"]);
    let a = &same["attributes"];
    assert_eq!(a["combined"]["uv"]["max"].as_f64(), Some(0.0), "{a}");
    assert!(a["combined"]["color"].is_null(), "no colours to compare: {a}");
    let level = |l: u8| uv(&format!("{}@{l}", store.display()), &["--attributes"])["attributes"]["combined"].clone();
    let (l1, l3) = (level(1), level(3));
    // Both directions sampled: each face takes its share's whole part and
    // one more with its fraction's probability, so a direction's count is
    // the target within a few times √(faces)/2 (about 70 here), never 10.
    assert!(l1["samples"].as_u64().unwrap().abs_diff(2 * 200_000) <= 1_000, "{l1}");
    let (m1, m3) = (l1["uv"]["mean"].as_f64().unwrap(), l3["uv"]["mean"].as_f64().unwrap());
    assert!(m1 > 0.0 && m1 < 1e-3, "level 1: mean uv difference {m1}");
    assert!(m3 > m1, "level 3 ({m3}) no worse than level 1 ({m1})");
    assert!(uv(&format!("{}@1", store.display()), &[]).get("attributes").is_none());
    let o = octolod(&["--quiet", "metro", ply.to_str().unwrap(), &format!("{}@2", store.display()), "--attributes", "--samples", "50000"]);
    assert!(text_out(&o).contains("attributes both: uv difference max"), "{}", text_out(&o));
}

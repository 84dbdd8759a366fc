//! `octolod simplify`: exact sizes (in memory and node by node), error
//! targets checked with metro, attributes carried, hard cases bounded, and
//! node-by-node results closed.

use crate::common::cli::{bin, measuring_child, run_measured};
use crate::common::{build_from, edge_counts, gen_ply, weld_positions};
use octolod::gen::Shape;
use octolod::manifest::Simplifier;
use octolod::mesh::IndexedMesh;
use octolod::mesh::{AttrSet, Vertex};
use octolod::simplify::{simplify_store, SimplifyOptions, SimplifyReport, Target};
use octolod::store::Store;
use std::collections::HashSet;
use std::path::Path;
use std::process::Command;

const BOTH: [Simplifier; 2] = [Simplifier::Collapse, Simplifier::Cluster];

fn opts(target: Target, simplifier: Simplifier, mem: u64) -> SimplifyOptions {
    SimplifyOptions { target, simplifier, mem, verify_samples: Some(200_000), force: false }
}

fn read(p: &Path) -> (AttrSet, IndexedMesh) {
    let (h, m, _) = octolod::ply::read::read_all(p).unwrap();
    let tris = m.triangles.iter().map(|t| t.map(|i| i as u32)).collect();
    (h.attrs, IndexedMesh { vertices: m.vertices, triangles: tris })
}

fn run(s: &Store, dir: &Path, name: &str, o: &SimplifyOptions) -> (SimplifyReport, AttrSet, IndexedMesh) {
    let out = dir.join(format!("{name}.ply"));
    let r = simplify_store(s, &out, o).unwrap_or_else(|e| panic!("{name}: {e}"));
    let (a, m) = read(&out);
    assert_eq!(r.triangles, m.triangles.len() as u64, "{name}");
    (r, a, m)
}

fn within_1pct(got: usize, n: u64) -> bool {
    (got as f64 - n as f64).abs() <= 0.01 * n as f64
}

/// Edges used once, after welding by position (0 on a closed result).
fn open_edges(m: &IndexedMesh) -> usize {
    let (_, t) = weld_positions(std::iter::once((&m.vertices[..], &m.triangles[..])));
    edge_counts(&t).values().filter(|&&n| n == 1).count()
}

fn bbox(v: &[Vertex]) -> octolod::mesh::Aabb {
    let mut b = octolod::mesh::Aabb::EMPTY;
    for x in v {
        b.add(x.pos);
    }
    b
}

/// Simplifies spheres of `tris` triangles in memory to each of `targets`
/// with both simplifiers: within 1 % of the target, reported reached, and
/// closed with collapse.
fn exact_counts_in_memory(cases: &[(u64, &[u64])]) {
    let dir = tempfile::tempdir().unwrap();
    for &(tris, targets) in cases {
        let (ply, _) = gen_ply(dir.path(), Shape::Sphere, tris, 0);
        let s = build_from(dir.path(), &ply, 16_384);
        for &n in targets {
            for simp in BOTH {
                let name = format!("exact-{tris}-{n}-{simp:?}");
                let (r, _, m) = run(&s, dir.path(), &name, &opts(Target::Tris(n), simp, 1 << 30));
                // A store level within 1 % of n that measures better is
                // returned instead of the reduction (see the test below).
                let level = r.choice.as_ref().is_some_and(|c| c.level_returned);
                assert_eq!(r.route, if level { "store-cut" } else { "in-memory" }, "{name}");
                assert!(within_1pct(m.triangles.len(), n), "{name}: {} triangles", m.triangles.len());
                assert!(r.reached, "{name}");
                // The sphere is closed; collapse keeps it closed.
                if simp == Simplifier::Collapse {
                    assert_eq!(open_edges(&m), 0, "{name}");
                }
            }
        }
    }
}

#[test]
fn exact_counts_in_memory_from_1e3_to_1e5() {
    exact_counts_in_memory(&[(1_000, &[500, 100]), (100_000, &[30_000, 1_000])]);
}

#[test]
#[ignore = "slow: 1 M triangles; run with --ignored"]
fn exact_counts_in_memory_at_1e6() {
    exact_counts_in_memory(&[(1_000_000, &[250_000, 5_000])]);
}

#[test]
fn exact_counts_node_by_node_under_a_small_budget_stay_closed() {
    let dir = tempfile::tempdir().unwrap();
    let (ply, input) = gen_ply(dir.path(), Shape::Sphere, 200_000, 0);
    let s = build_from(dir.path(), &ply, 4096);
    let diag = bbox(&input.vertices).diagonal();
    for simp in BOTH {
        // A budget that holds the output (60 K) but no level with >= 60 K
        // triangles (level 1 holds about 100 K).
        let n = 60_000;
        let mem = (1.1 * n as f64) as u64 * simp.bytes_per_triangle(s.header.attrs);
        let name = format!("per-node-{simp:?}");
        let (r, _, m) = run(&s, dir.path(), &name, &opts(Target::Tris(n), simp, mem));
        assert_eq!(r.route, "per-node", "{name}");
        assert!(within_1pct(m.triangles.len(), n), "{name}: {} triangles", m.triangles.len());
        let open = open_edges(&m);
        if simp == Simplifier::Collapse {
            assert_eq!(open, 0, "{name}: seams between nodes opened");
        } else {
            // Clustering may fold thin spots away, never open a seam.
            assert!(open <= m.triangles.len() / 1000, "{name}: {open} open edges");
        }
        let e = octolod::metro::compare(
            &octolod::metro::Mesh::from_vertices(&input.vertices, input.triangles.clone()),
            &octolod::metro::Mesh::from_vertices(&m.vertices, m.triangles.clone()),
            &octolod::metro::Options { samples: Some(200_000), ..Default::default() },
        )
        .unwrap();
        assert!(e.combined.max < 2e-3 * diag, "{name}: Hausdorff {:e}", e.combined.max / diag);
    }
}

/// The header's `comment octolod simplify ...` line of a PLY octolod wrote.
fn simplify_comment(p: &Path) -> String {
    let b = std::fs::read(p).unwrap();
    let head = String::from_utf8_lossy(&b[..b.windows(11).position(|w| w == b"end_header\n").unwrap()]).into_owned();
    head.lines().find_map(|l| l.strip_prefix("comment octolod simplify")).map(|c| format!("octolod simplify{c}")).unwrap()
}

#[test]
fn outputs_larger_than_the_budget_are_streamed_node_by_node_welded_and_closed() {
    let dir = tempfile::tempdir().unwrap();
    let (ply, input) = gen_ply(dir.path(), Shape::Sphere, 200_000, 0);
    assert!(edge_counts(&input.triangles).values().all(|&c| c == 2), "the input sphere is closed");
    let s = build_from(dir.path(), &ply, 4096);
    let (n, mem) = (100_000u64, 16u64 << 20);
    for simp in BOTH {
        // The output alone needs more than --mem in memory: this used to be refused.
        assert!(n * simp.bytes_per_triangle(s.header.attrs) > mem);
        let name = format!("streamed-{simp:?}");
        let (r, a, m) = run(&s, dir.path(), &name, &opts(Target::Tris(n), simp, mem));
        assert_eq!(r.route, "per-node", "{name}");
        assert!(r.reached && within_1pct(m.triangles.len(), n), "{name}: {} triangles, {r:?}", m.triangles.len());
        assert_eq!(r.vertices, m.vertices.len() as u64, "{name}");
        // Welded across the nodes as written (no welding here): no two
        // vertices alike, and every edge in two faces by index.
        let distinct: HashSet<[u64; 3]> = m.vertices.iter().map(|v| v.pos.map(f64::to_bits)).collect();
        assert_eq!(distinct.len(), m.vertices.len(), "{name}: vertices not welded");
        let edges = edge_counts(&m.triangles);
        if simp == Simplifier::Collapse {
            assert!(edges.values().all(|&c| c == 2), "{name}: {} edges not in exactly two faces", edges.values().filter(|&&c| c != 2).count());
        } else {
            // Clustering may fold thin spots away, never open a seam.
            let open = edges.values().filter(|&&c| c == 1).count();
            assert!(open <= m.triangles.len() / 1000, "{name}: {open} open edges");
        }
        // Byte for byte what the in-memory route's writer makes of that mesh.
        let out = dir.path().join(format!("{name}.ply"));
        let again = dir.path().join(format!("{name}-again.ply"));
        octolod::pipeline::write_mesh_ply(&again, a, &simplify_comment(&out), &m, false).unwrap();
        assert!(std::fs::read(&out).unwrap() == std::fs::read(&again).unwrap(), "{name}: not the bytes write_mesh_ply writes");
    }
    // Too little for the shared border and one node: a clear error, nothing written.
    let err = simplify_store(&s, &dir.path().join("tiny.ply"), &opts(Target::Tris(n), Simplifier::Collapse, 256 << 10)).unwrap_err();
    assert!(err.to_string().contains("--mem"), "{err}");
    assert!(!dir.path().join("tiny.ply").exists());
}

#[test]
fn target_error_is_met_when_measured_by_metro() {
    let dir = tempfile::tempdir().unwrap();
    let (ply, input) = gen_ply(dir.path(), Shape::Scan, 60_000, 0);
    let s = build_from(dir.path(), &ply, 4096);
    let diag = s.header.bbox.diagonal();
    for simp in BOTH {
        for rel in [2e-3, 5e-4] {
            let e = rel * diag;
            let name = format!("err-{simp:?}-{rel}");
            // Verified at metro's default density (10 × the larger face count).
            let o = SimplifyOptions { verify_samples: None, ..opts(Target::Error(e), simp, 1 << 30) };
            let (r, _, m) = run(&s, dir.path(), &name, &o);
            assert!(r.reached, "{name}: {r:?}");
            assert_eq!(r.verify_samples, Some(10 * input.triangles.len() as u64), "{name}: {r:?}");
            // Clustering offers the store's cuts only: below the finest
            // level's error (the scan's noise) it returns the input.
            if simp == Simplifier::Collapse || rel >= 2e-3 {
                assert!(m.triangles.len() < input.triangles.len(), "{name}: nothing removed");
            }
            let d = octolod::metro::compare(
                &octolod::metro::Mesh::from_vertices(&input.vertices, input.triangles.clone()),
                &octolod::metro::Mesh::from_vertices(&m.vertices, m.triangles.clone()),
                &octolod::metro::Options { samples: None, seed: 7, quiet: true },
            )
            .unwrap();
            assert!(d.combined.max <= e, "{name}: metro {:e} > {e:e}", d.combined.max);
        }
    }
}

#[test]
fn attributes_survive_both_simplifiers() {
    let dir = tempfile::tempdir().unwrap();
    let attrs = AttrSet::NORMAL | AttrSet::COLOR | AttrSet::UV;
    let (ply, input) = gen_ply(dir.path(), Shape::Sphere, 40_000, attrs);
    let s = build_from(dir.path(), &ply, 4096);
    let range = |k: usize| input.vertices.iter().fold((f32::MAX, f32::MIN), |(a, b), v| (a.min(v.uv[k]), b.max(v.uv[k])));
    let cmax = input.vertices.iter().map(|v| v.color[0]).max().unwrap();
    let cmin = input.vertices.iter().map(|v| v.color[0]).min().unwrap();
    for simp in BOTH {
        let name = format!("attrs-{simp:?}");
        let (_, a, m) = run(&s, dir.path(), &name, &opts(Target::Tris(4_000), simp, 1 << 30));
        assert_eq!(a.0 & attrs, attrs, "{name}: attributes lost");
        for v in &m.vertices {
            let l = glam::Vec3::from(v.normal).length();
            assert!((l - 1.0).abs() < 1e-3, "{name}: normal of length {l}");
            // Inside the input's uv range (clustering's least-squares uv
            // once overshot it by 1e-4).
            for k in 0..2 {
                let (lo, hi) = range(k);
                assert!(v.uv[k] >= lo && v.uv[k] <= hi, "{name}: uv {:?} outside [{lo}, {hi}]", v.uv);
            }
            assert!(v.color[0] >= cmin.saturating_sub(1) && v.color[0] <= cmax.saturating_add(1), "{name}: colour {:?}", v.color);
        }
        // Colours vary over the sphere; they are not flattened.
        let distinct: std::collections::HashSet<u8> = m.vertices.iter().map(|v| v.color[0]).collect();
        assert!(distinct.len() > 8, "{name}: {} distinct reds", distinct.len());
    }
}

#[test]
fn hard_cases_stay_finite_and_bounded_with_both_simplifiers() {
    let dir = tempfile::tempdir().unwrap();
    for (shape, attrs) in [
        (Shape::Plane, 0),
        (Shape::Cylinder, 0),
        (Shape::Sheets, 0),
        (Shape::Slivers, 0),
        (Shape::Offset, AttrSet::POS_F64),
        (Shape::Fan, 0),
        (Shape::Open, 0),
        (Shape::Duplicates, 0),
    ] {
        let (ply, input) = gen_ply(dir.path(), shape, 20_000, attrs);
        let s = build_from(dir.path(), &ply, 4096);
        let ib = bbox(&input.vertices);
        let n = (input.triangles.len() / 10).max(1) as u64;
        for simp in BOTH {
            let name = format!("{}-{simp:?}", shape.name());
            let out = dir.path().join(format!("{name}.ply"));
            let r = simplify_store(&s, &out, &opts(Target::Tris(n), simp, 1 << 30)).unwrap();
            let (_, m) = read(&out);
            // Clustering folds away parts thinner than a cluster (the two
            // sheets 1e-4 apart): then it must say it missed the target.
            assert!(!m.triangles.is_empty() || (simp == Simplifier::Cluster && !r.reached), "{name}: empty");
            assert!(m.triangles.len() as u64 <= n + n / 100 || !r.reached, "{name}: {} > {n} and reported reached", m.triangles.len());
            let tol = 1e-6 * ib.diagonal();
            for v in &m.vertices {
                assert!(v.pos.iter().all(|x| x.is_finite()), "{name}: non-finite vertex");
                for k in 0..3 {
                    assert!(v.pos[k] >= ib.min[k] - tol && v.pos[k] <= ib.max[k] + tol, "{name}: {:?} outside {ib:?}", v.pos);
                }
            }
        }
    }
}

#[test]
fn cli_targets_are_met_and_bad_requests_exit_1_or_2() {
    let dir = tempfile::tempdir().unwrap();
    let (ply, _) = gen_ply(dir.path(), Shape::Terrain, 30_000, 0);
    let out = dir.path().join("o.ply");
    let go = |args: &[&str]| Command::new(bin()).arg("--quiet").args(args).output().unwrap();
    let o = go(&["simplify", ply.to_str().unwrap(), "-o", out.to_str().unwrap(), "--target-ratio", "0.1", "--json"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let input = j["input_triangles"].as_u64().unwrap();
    let got = j["triangles"].as_u64().unwrap();
    assert!(within_1pct(got as usize, (input as f64 * 0.1).round() as u64), "{j}");
    assert_eq!(read(&out).1.triangles.len() as u64, got);
    // An existing output is not replaced without --force ...
    let o = go(&["simplify", ply.to_str().unwrap(), "-o", out.to_str().unwrap(), "--target-tris", "500"]);
    assert_eq!(o.status.code(), Some(1), "{}", String::from_utf8_lossy(&o.stderr));
    // ... and is with it.
    let o = go(&["--force", "simplify", ply.to_str().unwrap(), "-o", out.to_str().unwrap(), "--target-tris", "500", "--simplifier", "cluster"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(within_1pct(read(&out).1.triangles.len(), 500));
    // A target is required; two are refused.
    let o = go(&["simplify", ply.to_str().unwrap(), "-o", dir.path().join("x.ply").to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2));
    let o = go(&["simplify", ply.to_str().unwrap(), "-o", dir.path().join("x.ply").to_str().unwrap(), "--target-tris", "5", "--target-ratio", "0.5"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(!dir.path().join("x.ply").exists());
    // Error targets in % of the diagonal.
    let o = go(&["simplify", ply.to_str().unwrap(), "-o", dir.path().join("e.ply").to_str().unwrap(), "--target-error", "0.2%", "--json"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(j["reached"], true, "{j}");
    assert!(j["triangles"].as_u64().unwrap() < input, "{j}");
}

#[test]
fn the_command_writes_an_output_larger_than_mem_within_mem() {
    // In the measuring child (see `run_measured`): only the measurement.
    if measuring_child() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let (ply, _) = gen_ply(dir.path(), Shape::Sphere, 200_000, 0);
    let out = dir.path().join("o.ply");
    let (n, mem) = (100_000u64, 16u64 << 20);
    assert!(n * Simplifier::Collapse.bytes_per_triangle(octolod::mesh::AttrSet::POSITION_ONLY) > mem);
    let test = "the_command_writes_an_output_larger_than_mem_within_mem";
    let (r, peak) = simplify_within_mem(test, &ply, &out, &["--target-tris", &n.to_string(), "--leaf-tris", "4096"], mem);
    assert_eq!(r.route, "per-node", "{r:?}");
    assert!(r.reached && within_1pct(r.triangles as usize, n), "{r:?}");
    assert_eq!(read(&out).1.triangles.len() as u64, r.triangles);
    eprintln!("simplify 200 K -> 100 K triangles under --mem 16M: peak RSS {:.1} MiB", peak as f64 / (1 << 20) as f64);
}

/// `octolod --quiet simplify PLY -o OUT ARGS --mem MEM --json` run again
/// as test `test`'s measuring child (`run_measured`): its report and peak
/// RSS, once it succeeded within `mem` plus the process's fixed overhead
/// (see `octolod::mem`).
fn simplify_within_mem(test: &str, ply: &Path, out: &Path, args: &[&str], mem: u64) -> (SimplifyReport, u64) {
    let mem_arg = format!("{}M", mem >> 20);
    let mut all = vec!["--quiet", "simplify", ply.to_str().unwrap(), "-o", out.to_str().unwrap()];
    all.extend_from_slice(args);
    all.extend(["--mem", &mem_arg, "--json"]);
    let (code, stdout, stderr, peak) = run_measured(module_path!(), test, &all);
    assert_eq!(code, Some(0), "{args:?}: {stderr}");
    let r: SimplifyReport = serde_json::from_slice(&stdout).unwrap();
    assert!(peak <= mem + (64 << 20), "{args:?}: peak RSS {} MiB under --mem {mem_arg} ({r:?})", peak >> 20);
    (r, peak)
}

/// The in-memory routes budget by the mesh's attributes: a 200 K sphere
/// with normals and colours (quadric dimension 9) reduced by either
/// simplifier under `--mem 160M` stays within it. Clustering budgeted
/// 440 B a triangle whatever the dimension, so it reduced level 0 in
/// memory and peaked at 302 MiB.
#[test]
fn both_simplifiers_stay_within_mem_on_a_mesh_with_attributes() {
    let test = "both_simplifiers_stay_within_mem_on_a_mesh_with_attributes";
    if measuring_child() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let (ply, _) = gen_ply(dir.path(), Shape::Sphere, 200_000, AttrSet::NORMAL | AttrSet::COLOR);
    let mem = 160u64 << 20;
    for simp in ["cluster", "collapse"] {
        let out = dir.path().join(format!("{simp}.ply"));
        let (r, peak) = simplify_within_mem(test, &ply, &out, &["--target-tris", "60000", "--simplifier", simp], mem);
        assert!(r.reached && within_1pct(r.triangles as usize, 60_000), "{simp}: {r:?}");
        eprintln!("{simp}: 200 K sphere with normals and colours -> 60 K under --mem 160M: route {}, from {}, peak RSS {} MiB", r.route, r.start, peak >> 20);
    }
}

/// `simplify` is never worse than a store level of about the size asked:
/// asked exactly a level's size, both the level and the reduction are
/// measured (same samples) and the lower RMS is what is written; asked a
/// size no level is near, nothing is compared.
#[test]
fn a_level_of_about_the_size_asked_is_returned_when_it_measures_better() {
    let dir = tempfile::tempdir().unwrap();
    let (ply, _) = gen_ply(dir.path(), Shape::Scan, 60_000, 0);
    let s = build_from(dir.path(), &ply, 2000);
    let level = 2u8;
    let n = s.level_cut(level).triangles(&s);
    for simp in [Simplifier::Collapse, Simplifier::Cluster] {
        let name = format!("at-level-{}", simp.name());
        let (r, _, m) = run(&s, dir.path(), &name, &opts(Target::Tris(n), simp, 1 << 30));
        let c = r.choice.clone().unwrap_or_else(|| panic!("{name}: no comparison: {r:?}"));
        assert_eq!((c.level, c.level_triangles), (level, n), "{name}");
        assert!(c.level_rms > 0.0 && c.reduced_rms > 0.0, "{name}: {c:?}");
        assert_eq!(c.level_returned, c.level_rms < c.reduced_rms, "{name}: {c:?}");
        assert!(r.reached, "{name}: {r:?}");
        if c.level_returned {
            assert_eq!((r.route.as_str(), m.triangles.len() as u64), ("store-cut", n), "{name}");
            assert!(r.note.as_deref().is_some_and(|t| t.contains(&format!("level {level}"))), "{name}: {r:?}");
        } else {
            assert!(within_1pct(m.triangles.len(), n), "{name}");
        }
        eprintln!("{name}: level {level} RMS {:.3e}, reduction {:.3e}", c.level_rms, c.reduced_rms);
    }
    // Starting from level 1 (all --mem holds): compared the same way.
    let mem = s.level_cut(1).triangles(&s) * Simplifier::Collapse.bytes_per_triangle(s.header.attrs);
    let (r, _, m) = run(&s, dir.path(), "from-level-1", &opts(Target::Tris(n), Simplifier::Collapse, mem));
    let c = r.choice.clone().unwrap();
    assert_eq!(c.level_returned, c.level_rms < c.reduced_rms, "{c:?}");
    assert_eq!(m.triangles.len() as u64, r.triangles);
    eprintln!("from level 1: level {level} RMS {:.3e}, reduction {:.3e} ({:?})", c.level_rms, c.reduced_rms, r.start);
    // Halfway between two levels: no level within 1 %, no comparison.
    let between = (s.level_cut(1).triangles(&s) + n) / 2;
    let (r, _, _) = run(&s, dir.path(), "between", &opts(Target::Tris(between), Simplifier::Collapse, 1 << 30));
    assert!(r.choice.is_none(), "{r:?}");
}

/// Issue 32, item 2: `simplify` keeps a textured input's uvs and names its
/// texture (`comment TextureFile`, MeshLab's convention): the input's own
/// file, relative beside the output, absolute elsewhere (the scratch
/// store and its copy are gone by then).
#[test]
fn simplify_names_the_inputs_texture() {
    let d = tempfile::tempdir().unwrap();
    let ply = d.path().join("scan.ply");
    crate::common::cli::gen_with("scan", 8000, &ply, &["--atlas", "3", "--texture", "64"]);
    std::fs::create_dir(d.path().join("elsewhere")).unwrap();
    for (out, want) in [
        (d.path().join("small.ply"), "scan.png".to_string()),
        (d.path().join("elsewhere/small.ply"), d.path().canonicalize().unwrap().join("scan.png").display().to_string()),
    ] {
        let o = crate::common::cli::octolod(&["simplify", crate::common::cli::s(&ply), "-o", crate::common::cli::s(&out), "--target-tris", "2000", "--quiet"]);
        assert!(o.status.success(), "{}", crate::common::cli::err(&o));
        let h = octolod::ply::read_header(&out).unwrap();
        assert!(h.attrs.uv());
        assert_eq!(octolod::ply::texture_files(&h.comments), std::slice::from_ref(&want), "{}", out.display());
        assert!(crate::common::cli::names(out.parent().unwrap()).iter().all(|n| !n.contains("octolod")), "no scratch left");
    }
}

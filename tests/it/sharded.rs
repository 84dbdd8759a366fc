//! Sharded build (issue 34): `plan`, `build --plan --shard`, `merge` give
//! a store that opens like any other, whose DAG invariants and random cuts
//! hold, whose levels are within 10 % of the monolithic build's metro RMS;
//! shards are idempotent, a stale plan and foreign shards are refused, the
//! same plan gives the same store, a shard stays within its `--mem`.

use crate::common::cli::{err, gen, gen_with, measuring_child, octolod, octolod_ok, out, run_measured, s};
use crate::common::{gen_ply, json};
use crate::lod::{check_cuts, check_dag};
use octolod::gen::Shape;
use octolod::store::Store;
use std::path::{Path, PathBuf};

/// Plans `shards` shards of `input` (extra plan flags), builds each in
/// order and merges them into `store`; gives the shard directories.
fn sharded(d: &Path, input: &Path, shards: u32, extra: &[&str], store: &Path) -> Vec<PathBuf> {
    let plan = d.join("plan.json");
    let n = shards.to_string();
    let mut args = vec!["-q", "plan", s(input), "-o", s(&plan), "--shards", &n];
    args.extend_from_slice(extra);
    octolod_ok(&args);
    let dirs: Vec<PathBuf> = (0..shards).map(|i| d.join(format!("shard-{i}"))).collect();
    for (i, dir) in dirs.iter().enumerate() {
        octolod_ok(&["-q", "build", s(input), "--plan", s(&plan), "--shard", &i.to_string(), "-o", s(dir), "--mem", "64M"]);
    }
    let mut args = vec!["-q", "merge", s(&plan)];
    args.extend(dirs.iter().map(|p| s(p)));
    args.extend_from_slice(&["-o", s(store), "--mem", "64M"]);
    octolod_ok(&args);
    dirs
}

/// Combined metro RMS of `store@level` against `input`, and its triangles.
fn rms(input: &Path, store: &Path, level: u8) -> (f64, u64) {
    let o = octolod_ok(&["-q", "metro", s(input), &format!("{}@{level}", s(store)), "--json", "--samples", "400000"]);
    let j = json(&o.stdout);
    (j["combined"]["rms"].as_f64().unwrap(), j["b"]["faces"].as_u64().unwrap())
}

/// Every level of the sharded store within 10 % of the monolithic one's RMS
/// (at about its size), the same number of levels give or take one, a root
/// as small; DAG invariants and crack-free cuts.
fn against_monolithic(shape: Shape, tris: u64, leaf: u64, closed: bool, simplifier: &str) {
    against_monolithic_with(shape, tris, leaf, closed, simplifier, 0, &[]);
}

/// [`against_monolithic`] for an input with `attrs`, both builds given
/// `extra` flags; gives the sharded store (and the directory holding it).
fn against_monolithic_with(shape: Shape, tris: u64, leaf: u64, closed: bool, simplifier: &str, attrs: u32, extra: &[&str]) -> (tempfile::TempDir, Store) {
    let d = tempfile::tempdir().unwrap();
    let (input, input_mesh) = gen_ply(d.path(), shape, tris, attrs);
    let leaf = leaf.to_string();
    let mut flags = vec!["--leaf-tris", &leaf, "--simplifier", simplifier];
    flags.extend_from_slice(extra);
    let mono = d.path().join("mono.octolod");
    let mut args = vec!["-q", "build", s(&input), "-o", s(&mono), "--mem", "64M"];
    args.extend_from_slice(&flags);
    octolod_ok(&args);
    let store = d.path().join("sharded.octolod");
    sharded(d.path(), &input, 4, &flags, &store);
    let (m, sh) = (Store::open(&mono).unwrap(), Store::open(&store).unwrap());
    let name = format!("{} sharded ({simplifier})", shape.name());
    let plan = json(&std::fs::read(d.path().join("plan.json")).unwrap());
    assert!(plan["shard_levels"].as_u64().unwrap() >= 1, "{name}: the shards build levels");
    check_dag(&sh, &name);
    check_cuts(&sh, &input_mesh, &name, closed);
    assert_eq!(sh.level_triangles(0), m.level_triangles(0), "{name}: level 0 holds the input");
    assert!(sh.top_level().abs_diff(m.top_level()) <= 1, "{name}: {} levels against {}", sh.top_level(), m.top_level());
    assert_eq!(sh.level_nodes(sh.top_level()).len(), 1, "{name}: one root");
    assert!(sh.level_triangles(sh.top_level()) <= 4096, "{name}: root of {} triangles", sh.level_triangles(sh.top_level()));
    for l in 1..=sh.top_level().min(m.top_level()) {
        let ((rs, ts), (rm, tm)) = (rms(&input, &store, l), rms(&input, &mono, l));
        eprintln!("{name}: level {l}: sharded {ts} triangles RMS {rs:.3e}, monolithic {tm} triangles RMS {rm:.3e} ({:.3}x)", rs / rm);
        assert!((ts as f64 / tm as f64 - 1.0).abs() < 0.1, "{name}: level {l}: {ts} triangles against {tm}");
        assert!(rs <= 1.1 * rm, "{name}: level {l}: RMS {rs:e} against the monolithic {rm:e}");
    }
    (d, sh)
}

#[test]
fn a_sharded_terrain_is_as_good_as_a_monolithic_one() {
    against_monolithic(Shape::Terrain, 60_000, 500, false, "cluster");
}

/// With normals and no crease the plan resolves `--normals auto` to
/// average: the shards and the merge leave them out of the quadric
/// (dimension 3), and every level above 0 holds unit normals near the
/// sphere's.
#[test]
fn a_sharded_closed_sphere_has_closed_cuts() {
    let (_d, sh) = against_monolithic_with(Shape::Sphere, 40_000, 1000, true, "cluster", octolod::mesh::AttrSet::NORMAL, &[]);
    let plan = json(&std::fs::read(_d.path().join("plan.json")).unwrap());
    assert_eq!(plan["params"]["normals"], "average");
    let m = octolod::manifest::Manifest::read(&sh.dir).unwrap();
    assert_eq!((m.params.normals, m.quadric_dim), (octolod::manifest::Normals::Average, 3));
    let c = sh.header.bbox.center();
    for i in (0..sh.nodes.len()).filter(|&i| sh.nodes[i].level > 0) {
        for v in sh.read_node(i).unwrap().mesh.vertices {
            let r = [0, 1, 2].map(|k| v.pos[k] - c[k]);
            let cos = (0..3).map(|k| r[k] * v.normal[k] as f64).sum::<f64>() / (0..3).map(|k| r[k] * r[k]).sum::<f64>().sqrt();
            let len = (0..3).map(|k| v.normal[k] as f64 * v.normal[k] as f64).sum::<f64>().sqrt();
            assert!((len - 1.0).abs() < 1e-3 && cos > 0.7, "node {i}: normal {:?} at {:?}", v.normal, v.pos);
        }
    }
}

/// One crease test for `--normals auto` in whole and sharded builds (the
/// soup stage's and the plan's vertex pass): a sphere whose normals split
/// along the rim of a small cap (under 1 % of its positions, so most of
/// level 0's nodes never hold it) is carried by both; the same sphere
/// without the cap is averaged by both.
#[test]
fn whole_and_sharded_builds_resolve_auto_normals_alike() {
    use octolod::manifest::{Manifest, Normals};
    use octolod::mesh::AttrSet;
    let d = tempfile::tempdir().unwrap();
    let (smooth, input) = gen_ply(d.path(), Shape::Sphere, 60_000, AttrSet::NORMAL);
    let top = input.vertices.iter().map(|v| v.pos[2]).fold(f64::NEG_INFINITY, f64::max);
    let bottom = input.vertices.iter().map(|v| v.pos[2]).fold(f64::INFINITY, f64::min);
    // The cap's triangles take twins of their corners facing +x.
    let (cply, capped) = crate::common::creased_ply(d.path(), &input, |v| v.pos[2] >= top - 0.002 * (top - bottom));
    assert!(capped > 5 && capped * 100 < input.vertices.len(), "{capped} of {} positions in the cap", input.vertices.len());
    for (ply, want) in [(&smooth, Normals::Average), (&cply, Normals::Carry)] {
        let (store, plan) = (d.path().join("whole.octolod"), d.path().join("plan.json"));
        octolod_ok(&["-q", "--force", "build", s(ply), "-o", s(&store), "--mem", "64M", "--leaf-tris", "500"]);
        assert_eq!(Manifest::read(&store).unwrap().params.normals, want, "{}: whole build", ply.display());
        octolod_ok(&["-q", "--force", "plan", s(ply), "-o", s(&plan), "--shards", "4"]);
        let p = json(&std::fs::read(&plan).unwrap());
        assert_eq!(p["params"]["normals"], want.name(), "{}: plan", ply.display());
    }
}

#[test]
fn sharded_collapse_levels_are_as_good_as_monolithic_ones() {
    against_monolithic(Shape::Scan, 40_000, 1000, false, "collapse");
}

/// Every file of a directory by name, with a checksum of its content (the
/// timings of `store.json` and `shard.json` left out).
fn files(d: &Path) -> Vec<(String, u32)> {
    let mut v: Vec<(String, u32)> = std::fs::read_dir(d)
        .unwrap()
        .flatten()
        .map(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            let mut b = std::fs::read(e.path()).unwrap();
            if name.ends_with(".json") {
                let mut j = json(&b);
                strip_seconds(&mut j);
                b = j.to_string().into_bytes();
            }
            (name, crc32c::crc32c(&b))
        })
        .collect();
    v.sort();
    v
}

fn strip_seconds(j: &mut serde_json::Value) {
    match j {
        serde_json::Value::Object(m) => {
            m.retain(|k, _| k != "seconds");
            m.values_mut().for_each(strip_seconds);
        }
        serde_json::Value::Array(a) => a.iter_mut().for_each(strip_seconds),
        _ => {}
    }
}

#[test]
fn shards_are_idempotent_and_the_same_plan_gives_the_same_store() {
    let d = tempfile::tempdir().unwrap();
    let input = d.path().join("in.ply");
    gen_with("scan", 30_000, &input, &["--normals"]);
    let store = d.path().join("a.octolod");
    let dirs = sharded(d.path(), &input, 3, &["--leaf-tris", "1000"], &store);
    let plan = d.path().join("plan.json");
    // A finished shard is recognised and left as it is.
    let before = files(&dirs[1]);
    let o = octolod_ok(&["build", s(&input), "--plan", s(&plan), "--shard", "1", "-o", s(&dirs[1])]);
    assert!(out(&o).contains("already built"), "{}", out(&o));
    assert_eq!(files(&dirs[1]), before);
    // The same shards merged again (any order) give the same files; the
    // store's id is the plan's.
    let again = d.path().join("b.octolod");
    octolod_ok(&["-q", "merge", s(&plan), s(&dirs[2]), s(&dirs[0]), s(&dirs[1]), "-o", s(&again), "--mem", "64M"]);
    assert_eq!(files(&store), files(&again));
    let p = json(&std::fs::read(&plan).unwrap());
    assert_eq!(format!("{:016x}", Store::open(&store).unwrap().header.store_id), p["plan_id"].as_str().unwrap());
    // A shard rebuilt from scratch is byte-identical.
    let rebuilt = d.path().join("rebuilt");
    octolod_ok(&["-q", "build", s(&input), "--plan", s(&plan), "--shard", "1", "-o", s(&rebuilt)]);
    assert_eq!(files(&rebuilt), before);
    // Under a budget that sends the soup stage on its external path, the
    // shard's triangles are kept as they are placed (no whole soup is
    // written): the same chunks and packs.
    let external = d.path().join("external");
    octolod_ok(&["-q", "build", s(&input), "--plan", s(&plan), "--shard", "1", "-o", s(&external), "--mem", "256K"]);
    let payload = |v: Vec<(String, u32)>| v.into_iter().filter(|(n, _)| !n.starts_with("shard.")).collect::<Vec<_>>();
    assert_eq!(payload(files(&external)), payload(before.clone()));
    // The plan's shards are listed largest first, and add up to the input.
    let est: Vec<u64> = p["shards"].as_array().unwrap().iter().map(|x| x["est_triangles"].as_u64().unwrap()).collect();
    assert!(est.windows(2).all(|w| w[0] >= w[1]), "{est:?}");
    let total = p["triangles"].as_u64().unwrap();
    assert!(est.iter().sum::<u64>().abs_diff(total) <= 3, "{est:?} against {total}");
    assert!(est.iter().all(|&e| e.abs_diff(total / 3) < total / 30), "balanced: {est:?}");
}

#[test]
fn a_stale_plan_and_foreign_or_missing_shards_are_refused() {
    let d = tempfile::tempdir().unwrap();
    let input = d.path().join("in.ply");
    gen("terrain", 20_000, &input);
    let store = d.path().join("a.octolod");
    let dirs = sharded(d.path(), &input, 2, &["--leaf-tris", "1000"], &store);
    let plan = d.path().join("plan.json");
    // Another plan of the same input (3 shards, by --shard-tris): its
    // shards are not this plan's.
    let other = d.path().join("other.json");
    octolod_ok(&["-q", "plan", s(&input), "-o", s(&other), "--shard-tris", "7000", "--leaf-tris", "1000"]);
    assert_eq!(json(&std::fs::read(&other).unwrap())["shards"].as_array().unwrap().len(), 3);
    let foreign = d.path().join("foreign");
    octolod_ok(&["-q", "build", s(&input), "--plan", s(&other), "--shard", "0", "-o", s(&foreign)]);
    let out_path = d.path().join("m.octolod");
    for (shards, want) in [(vec![&dirs[0]], "missing"), (vec![&dirs[0], &dirs[0], &dirs[1]], "given twice"), (vec![&dirs[0], &foreign], "not of this plan")] {
        let mut args = vec!["-q", "merge", s(&plan)];
        args.extend(shards.iter().map(|p| s(p)));
        args.extend_from_slice(&["-o", s(&out_path)]);
        let o = octolod(&args);
        assert_ne!(o.status.code(), Some(0));
        assert!(err(&o).contains(want), "{want}: {}", err(&o));
        assert!(!out_path.exists(), "nothing left behind");
    }
    // An edited plan is refused.
    let text = std::fs::read_to_string(&plan).unwrap().replace("\"leaf_tris\": 1000", "\"leaf_tris\": 999");
    let edited = d.path().join("edited.json");
    std::fs::write(&edited, text).unwrap();
    let o = octolod(&["-q", "build", s(&input), "--plan", s(&edited), "--shard", "0", "-o", s(&d.path().join("x"))]);
    assert_eq!(o.status.code(), Some(1), "{}", err(&o));
    assert!(err(&o).contains("does not match its content"), "{}", err(&o));
    // The input changed since the plan: refused, nothing written.
    gen_with("terrain", 21_000, &input, &["--force"]);
    let fresh = d.path().join("fresh");
    let o = octolod(&["-q", "build", s(&input), "--plan", s(&plan), "--shard", "0", "-o", s(&fresh)]);
    assert_ne!(o.status.code(), Some(0));
    assert!(err(&o).contains("stale"), "{}", err(&o));
    assert!(!fresh.exists());
    // --force never replaces a directory that is not a shard.
    let user = d.path().join("user");
    std::fs::create_dir(&user).unwrap();
    std::fs::write(user.join("notes.txt"), "mine").unwrap();
    octolod_ok(&["-q", "plan", s(&input), "-o", s(&plan), "--shards", "2", "--force"]);
    let o = octolod(&["-q", "--force", "build", s(&input), "--plan", s(&plan), "--shard", "0", "-o", s(&user)]);
    assert_ne!(o.status.code(), Some(0));
    assert_eq!(std::fs::read_to_string(user.join("notes.txt")).unwrap(), "mine");
    // A non-finite coordinate: exit 1 naming the record, no plan written.
    let nan = d.path().join("nan.ply");
    std::fs::write(
        &nan,
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 nan 0\n0 1 0\n3 0 1 2\n",
    )
    .unwrap();
    let nan_plan = d.path().join("nan.json");
    let o = octolod(&["-q", "plan", s(&nan), "-o", s(&nan_plan)]);
    assert_eq!(o.status.code(), Some(1));
    assert!(err(&o).contains("record 1"), "{}", err(&o));
    assert!(!nan_plan.exists());
    // Nor a plan over a file that is not a plan.
    let o = octolod(&["-q", "--force", "plan", s(&input), "-o", s(&user.join("notes.txt"))]);
    assert_ne!(o.status.code(), Some(0));
    assert_eq!(std::fs::read_to_string(user.join("notes.txt")).unwrap(), "mine");
}

/// A shard task's peak RSS stays under its `--mem` (the figures' 2 × 10^7
/// terrain: 123 MiB under 128M, `tools/shard-figures.sh`); under a budget
/// below the process's own floor (code, libraries, thread stacks and what
/// glibc's two arenas keep, 20 to 30 MiB at 2 threads) within that floor
/// of it. The second case is a 2 M-triangle terrain, whose shard peaks at
/// 78-83 MiB when given 512M, so a shard that ignored a small budget fails
/// it; a 600 K-triangle shard peaked at 41-49 MiB under any budget, which
/// measured only the floor's jitter (33-41 MiB under 16M).
#[test]
fn a_shard_builds_within_its_mem() {
    if measuring_child() {
        return;
    }
    let d = tempfile::tempdir().unwrap();
    for (tris, mem, over) in [(600_000u64, 64u64 << 20, 0u64), (2_000_000, 24 << 20, 32 << 20)] {
        let input = d.path().join(format!("in-{tris}.ply"));
        gen("terrain", tris, &input);
        let m = format!("{}M", mem >> 20);
        let plan = d.path().join(format!("plan-{m}.json"));
        octolod_ok(&["-q", "plan", s(&input), "-o", s(&plan), "--shards", "2", "--mem", &m]);
        let dir = d.path().join(format!("shard-0-{m}"));
        let args = ["--quiet", "build", s(&input), "--plan", s(&plan), "--shard", "0", "-o", s(&dir), "--mem", &m];
        let (code, _, stderr, peak) = run_measured(module_path!(), "a_shard_builds_within_its_mem", &args);
        assert_eq!(code, Some(0), "{stderr}");
        eprintln!("shard 0 of a {tris}-triangle terrain under --mem {m}: peak RSS {:.1} MiB", peak as f64 / (1 << 20) as f64);
        assert!(peak <= mem + over, "peak RSS {} MiB under --mem {m}", peak >> 20);
    }
}

/// Bytes of the shards' level packs.
fn pack_bytes(dirs: &[PathBuf]) -> u64 {
    dirs.iter()
        .flat_map(|d| std::fs::read_dir(d).unwrap().flatten())
        .filter(|e| e.file_name().to_string_lossy().starts_with("level-"))
        .map(|e| e.metadata().unwrap().len())
        .sum()
}

/// Every node of `st` read: its mesh and patches (patch children as store ids).
fn all_nodes(st: &Store) -> Vec<octolod::store::NodeMesh> {
    (0..st.nodes.len()).map(|i| st.read_node(i).unwrap()).collect()
}

/// The merge links the shards' packs in as pack parts (no byte copied,
/// the same files), or with `--copy` concatenates them into the store's own
/// packs; both give the same nodes, patches naming the store's children,
/// in the store and in the viewer's loader. A linked store outlives its
/// shards, and `--force` replaces it without touching them.
#[test]
fn merged_packs_are_linked_in_place_or_copied() {
    use std::os::unix::fs::MetadataExt;
    let d = tempfile::tempdir().unwrap();
    let input = d.path().join("in.ply");
    gen("scan", 24_000, &input);
    let linked = d.path().join("linked.octolod");
    let dirs = sharded(d.path(), &input, 3, &["--leaf-tris", "1000", "--shard-levels", "3"], &linked);
    let plan = d.path().join("plan.json");
    let merge = |out: &Path, extra: &[&str]| {
        let mut args = vec!["-q", "merge", s(&plan)];
        args.extend(dirs.iter().map(|p| s(p)));
        args.extend_from_slice(&["-o", s(out), "--json"]);
        args.extend_from_slice(extra);
        json(&octolod_ok(&args).stdout)
    };
    let shard_files = || dirs.iter().map(|d| files(d)).collect::<Vec<_>>();
    let shards_before = shard_files();
    // Merged again over the first with --force: its pack parts are its own.
    let r = merge(&linked, &["--force"]);
    let shard_bytes = pack_bytes(&dirs);
    assert_eq!((r["linked_bytes"].as_u64(), r["copied_bytes"].as_u64()), (Some(shard_bytes), Some(0)), "{r}");
    assert_eq!(shard_files(), shards_before, "the shards are untouched");
    let st = Store::open(&linked).unwrap();
    let stop = json(&std::fs::read(&plan).unwrap())["shard_levels"].as_u64().unwrap() as u8;
    for (k, dir) in dirs.iter().enumerate() {
        for level in 0..stop {
            let (a, b) = (
                std::fs::metadata(octolod::store::pack_file_part(&linked, level, k as u32 + 1)).unwrap(),
                std::fs::metadata(dir.join(format!("level-{level}.pack"))).unwrap(),
            );
            assert_eq!((a.dev(), a.ino()), (b.dev(), b.ino()), "shard {k} level {level}: the same file");
        }
        assert!(!linked.join(format!("level-{}.part-{}.pack", stop, k + 1)).exists());
    }
    assert!(st.nodes.iter().any(|n| n.patch_shift != 0), "shard payloads keep their own ids");
    // --copy: one pack per level, the same nodes.
    let copied = d.path().join("copied.octolod");
    let r = merge(&copied, &["--copy"]);
    assert_eq!((r["linked_bytes"].as_u64(), r["copied_bytes"].as_u64()), (Some(0), Some(shard_bytes)), "{r}");
    assert!(!std::fs::read_dir(&copied).unwrap().flatten().any(|e| e.file_name().to_string_lossy().contains(".part-")));
    let sc = Store::open(&copied).unwrap();
    let nodes = all_nodes(&st);
    assert_eq!(nodes, all_nodes(&sc));
    for (i, m) in nodes.iter().enumerate() {
        let kids: Vec<u32> = m.patches.iter().map(|p| p.child).collect();
        let want = if st.nodes[i].level == 0 { vec![octolod::store::NO_NODE] } else { st.children_of(i).to_vec() };
        assert_eq!(kids, want, "node {i}");
    }
    // The viewer's loader reads the parts and shifts the patches too.
    #[cfg(feature = "view")]
    {
        use octolod::view::{cache::Cache, select::Hierarchy, DrawMesh};
        let h = Hierarchy::new(&st);
        let ctx = octolod::view::viewer::load_ctx(&st);
        let mut c: Cache<DrawMesh> = Cache::new(&linked, ctx, u64::MAX / 4, 1, std::time::Duration::ZERO);
        let units: Vec<u32> = (0..st.nodes.len() as u32).collect();
        c.pin(&h, &linked, ctx, &units).unwrap();
        for (i, m) in nodes.iter().enumerate() {
            assert_eq!(c.patches(i as u32), &m.patches[..], "node {i} in the viewer");
        }
    }
    // The linked store outlives its shards.
    drop((st, sc));
    for dir in &dirs {
        std::fs::remove_dir_all(dir).unwrap();
    }
    assert_eq!(all_nodes(&Store::open(&linked).unwrap()), nodes);
    octolod_ok(&["-q", "metro", s(&input), &format!("{}@1", s(&linked)), "--json", "--samples", "20000"]);
}

/// Shards on another filesystem than the store (here /dev/shm, a tmpfs)
/// cannot be linked: their packs are copied as parts, and the store reads
/// the same. Skipped where /dev/shm is missing or on the store's
/// filesystem.
#[test]
fn shards_on_another_filesystem_are_copied_as_parts() {
    use std::os::unix::fs::MetadataExt;
    let d = tempfile::tempdir().unwrap();
    let shm = Path::new("/dev/shm");
    if !shm.is_dir() || std::fs::metadata(shm).unwrap().dev() == std::fs::metadata(d.path()).unwrap().dev() {
        eprintln!("skipped: no /dev/shm on another filesystem than {}", d.path().display());
        return;
    }
    let Ok(far) = tempfile::tempdir_in(shm) else {
        eprintln!("skipped: /dev/shm is not writable");
        return;
    };
    let input = d.path().join("in.ply");
    gen("terrain", 20_000, &input);
    let plan = d.path().join("plan.json");
    octolod_ok(&["-q", "plan", s(&input), "-o", s(&plan), "--shards", "2", "--leaf-tris", "1000", "--shard-levels", "2"]);
    let dirs: Vec<PathBuf> = (0..2).map(|i| far.path().join(format!("shard-{i}"))).collect();
    for (i, dir) in dirs.iter().enumerate() {
        octolod_ok(&["-q", "build", s(&input), "--plan", s(&plan), "--shard", &i.to_string(), "-o", s(dir)]);
    }
    let store = d.path().join("s.octolod");
    let o = octolod_ok(&["-q", "merge", s(&plan), s(&dirs[0]), s(&dirs[1]), "-o", s(&store), "--json"]);
    let r = json(&o.stdout);
    let shard_bytes = pack_bytes(&dirs);
    assert_eq!((r["linked_bytes"].as_u64(), r["copied_bytes"].as_u64()), (Some(0), Some(shard_bytes)), "{r}");
    let nodes = all_nodes(&Store::open(&store).unwrap());
    assert!(store.join("level-0.part-1.pack").is_file() && store.join("level-1.part-2.pack").is_file());
    drop(far);
    assert_eq!(all_nodes(&Store::open(&store).unwrap()), nodes, "the copies outlive the shards");
}

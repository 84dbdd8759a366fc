//! The binaries as a script sees them: quiet when stderr is not a terminal,
//! a one-line summary, deterministic generator output, and generated files of
//! every shape and flavor ingesting to exactly the generated triangle count.

use octolod::gen::{GenOptions, Generator, Shape};
use octolod::mesh::AttrSet;
use std::process::Command;

fn octolod(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_octolod")).args(args).output().unwrap()
}

fn gen(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_octolod-gen")).args(args).output().unwrap()
}

#[test]
fn soup_is_silent_on_stderr_when_not_a_terminal_and_prints_one_summary_line() {
    let d = tempfile::tempdir().unwrap();
    let ply = d.path().join("s.ply");
    let out = gen(&["--shape", "sphere", "--tris", "5000", "-o", ply.to_str().unwrap()]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let soup = d.path().join("s.soup");
    // No --quiet: stderr is a pipe here, so no progress bar may appear.
    let o = octolod(&["soup", ply.to_str().unwrap(), "-o", soup.to_str().unwrap(), "--mem", "64K", "--external"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(o.stderr.is_empty(), "stderr not empty: {}", String::from_utf8_lossy(&o.stderr));
    let s = String::from_utf8_lossy(&o.stdout);
    assert_eq!(s.lines().count(), 1, "{s}");
    for part in ["faces in", "triangles out", "degenerate dropped", "external-sort path", "MB/s", "M tri/s", "peak RSS"] {
        assert!(s.contains(part), "summary lacks '{part}': {s}");
    }
}

#[test]
fn generator_is_deterministic_and_seeded() {
    let d = tempfile::tempdir().unwrap();
    let mut files = Vec::new();
    for (i, seed) in ["7", "7", "8"].iter().enumerate() {
        let p = d.path().join(format!("t{i}.ply"));
        let o = gen(&["--shape", "terrain", "--tris", "20000", "--seed", seed, "--normals", "--colors", "--quiet", "-o", p.to_str().unwrap()]);
        assert!(o.status.success());
        files.push(std::fs::read(&p).unwrap());
    }
    assert!(files[0] == files[1], "same seed, different bytes");
    assert!(files[0] != files[2], "different seed, same bytes");
}

#[test]
fn every_shape_and_flavor_ingests_to_the_generated_triangle_count() {
    let d = tempfile::tempdir().unwrap();
    let flavors: [(&str, &[&str], u32); 4] = [
        ("binary-le", &[], 0),
        ("binary-be", &["--double", "--normals"], AttrSet::POS_F64 | AttrSet::NORMAL),
        ("ascii", &["--colors", "--uvs"], AttrSet::COLOR | AttrSet::UV),
        ("binary-le", &["--alpha", "--uvs", "--uv-names", "st", "--float-colors"], AttrSet::COLOR | AttrSet::ALPHA | AttrSet::UV),
    ];
    for (k, shape) in Shape::ALL.iter().enumerate() {
        let (format, extra, attrs) = flavors[k % flavors.len()];
        let ply = d.path().join(format!("{}.ply", shape.name()));
        let mut args = vec!["--shape", shape.name(), "--tris", "3000", "--format", format, "--quiet", "-o", ply.to_str().unwrap()];
        args.extend_from_slice(extra);
        let o = gen(&args);
        assert!(o.status.success(), "{}: {}", shape.name(), String::from_utf8_lossy(&o.stderr));
        let g = Generator::new(&GenOptions { shape: *shape, tris: 3000, seed: 1, attrs: AttrSet(attrs) });
        let soup = d.path().join(format!("{}.soup", shape.name()));
        let o = octolod(&["soup", ply.to_str().unwrap(), "-o", soup.to_str().unwrap(), "--json", "--mem", "64K", "--external"]);
        assert!(o.status.success(), "{}: {}", shape.name(), String::from_utf8_lossy(&o.stderr));
        let s = String::from_utf8_lossy(&o.stdout);
        let (h, tris) = octolod::soup::format::SoupReader::read_all(&soup).unwrap();
        assert_eq!(h.attrs, AttrSet(attrs), "{}: attributes", shape.name());
        assert_eq!(h.triangles + h.degenerate, g.face_count(), "{}: {s}", shape.name());
        assert!(tris.iter().flatten().all(|v| v.pos.iter().all(|x| x.is_finite())));
        if *shape != Shape::Slivers {
            assert_eq!(h.degenerate, 0, "{}: generator made repeated-index faces", shape.name());
        }
    }
}

#[test]
fn build_info_extract_and_simplify() {
    let d = tempfile::tempdir().unwrap();
    let ply = d.path().join("s.ply");
    assert!(gen(&["--shape", "sphere", "--tris", "20000", "--normals", "--quiet", "-o", ply.to_str().unwrap()]).status.success());
    let store = d.path().join("s.octolod");
    let o = octolod(&["build", ply.to_str().unwrap(), "-o", store.to_str().unwrap(), "--mem", "1M", "--leaf-tris", "1000", "--level-ratio", "2"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let g = Generator::new(&GenOptions { shape: Shape::Sphere, tris: 20000, seed: 1, attrs: AttrSet(AttrSet::NORMAL) });
    let summary = String::from_utf8_lossy(&o.stdout);
    assert!(summary.contains(&format!("build: {} triangles", g.face_count())), "{summary}");
    for f in ["nodes.bin", "store.json", "level-0.pack", "level-1.pack"] {
        assert!(store.join(f).exists(), "{f} missing");
    }
    let info = octolod(&["info", store.to_str().unwrap()]);
    assert!(info.status.success());
    let text = String::from_utf8_lossy(&info.stdout);
    assert!(text.contains("quadric dimension 6"), "{text}");
    let level_lines: Vec<&str> = text.lines().filter(|l| l.trim_start().chars().next().is_some_and(|c| c.is_ascii_digit())).collect();
    assert!(level_lines.len() >= 3, "{text}");
    // Level 0 back out: every input triangle.
    let l0 = d.path().join("l0.ply");
    assert!(octolod(&["extract", store.to_str().unwrap(), "--level", "0", "-o", l0.to_str().unwrap()]).status.success());
    let (_, m, _) = octolod::ply::read::read_all(&l0).unwrap();
    assert_eq!(m.triangles.len() as u64, g.face_count());
    // A level that does not exist is a usage error naming the range.
    let bad = octolod(&["extract", store.to_str().unwrap(), "--level", "40", "-o", d.path().join("x.ply").to_str().unwrap()]);
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("levels 0..="));
    assert!(!d.path().join("x.ply").exists());
    // The cut at an error (here 0.2 % of the diagonal): between the root and level 0.
    let cut = d.path().join("cut.ply");
    let o = octolod(&["extract", store.to_str().unwrap(), "--max-error", "0.2%", "-o", cut.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (_, m, _) = octolod::ply::read::read_all(&cut).unwrap();
    assert!(m.triangles.len() > 300 && (m.triangles.len() as u64) < g.face_count(), "{}", m.triangles.len());
    // simplify: exactly the size asked (within 1 %).
    let small = d.path().join("small.ply");
    let o = octolod(&["simplify", ply.to_str().unwrap(), "-o", small.to_str().unwrap(), "--target-tris", "2000", "--leaf-tris", "1000", "--mem", "1M"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (_, m, _) = octolod::ply::read::read_all(&small).unwrap();
    assert!(m.triangles.len().abs_diff(2000) <= 20, "{}", m.triangles.len());
    // Only the outputs are left next to them (no scratch directories).
    let mut names: Vec<String> = std::fs::read_dir(d.path()).unwrap().map(|e| e.unwrap().file_name().into_string().unwrap()).collect();
    names.sort();
    assert_eq!(names, ["cut.ply", "l0.ply", "s.octolod", "s.ply", "small.ply"]);
}

#[test]
fn failed_build_leaves_no_store() {
    let d = tempfile::tempdir().unwrap();
    let ply = d.path().join("t.ply");
    std::fs::write(&ply, "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n").unwrap();
    let store = d.path().join("t.octolod");
    let o = octolod(&["build", ply.to_str().unwrap(), "-o", store.to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("vertex index 7 out of range"));
    assert_eq!(std::fs::read_dir(d.path()).unwrap().count(), 1, "a failed build left files behind");
}

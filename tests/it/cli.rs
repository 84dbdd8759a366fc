//! The binaries as a script sees them: quiet when stderr is not a terminal,
//! a one-line summary, deterministic generator output, and generated files of
//! every shape and flavor ingesting to exactly the generated triangle count.

use crate::common::cli::{err, gen, gen_with, names, octolod, octolod_ok, out, s};
use octolod::gen::{GenOptions, Generator, Shape};
use octolod::mesh::AttrSet;

#[test]
fn soup_is_silent_on_stderr_when_not_a_terminal_and_prints_one_summary_line() {
    let d = tempfile::tempdir().unwrap();
    let ply = d.path().join("s.ply");
    gen("sphere", 5000, &ply);
    let soup = d.path().join("s.soup");
    // No --quiet: stderr is a pipe here, so no progress bar may appear.
    let o = octolod_ok(&["soup", s(&ply), "-o", s(&soup), "--mem", "64K", "--external"]);
    assert!(o.stderr.is_empty(), "stderr not empty: {}", err(&o));
    let text = out(&o);
    assert_eq!(text.lines().count(), 1, "{text}");
    for part in ["faces in", "triangles out", "degenerate dropped", "external-sort path", "MB/s", "M tri/s", "peak RSS"] {
        assert!(text.contains(part), "summary lacks '{part}': {text}");
    }
}

#[test]
fn generator_is_deterministic_and_seeded() {
    let d = tempfile::tempdir().unwrap();
    let mut files = Vec::new();
    for (i, seed) in ["7", "7", "8"].iter().enumerate() {
        let p = d.path().join(format!("t{i}.ply"));
        gen_with("terrain", 20000, &p, &["--seed", seed, "--normals", "--colors"]);
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
        gen_with(shape.name(), 3000, &ply, &[&["--format", format][..], extra].concat());
        let g = Generator::new(&GenOptions { shape: *shape, tris: 3000, seed: 1, attrs: AttrSet(attrs) });
        let soup = d.path().join(format!("{}.soup", shape.name()));
        let text = out(&octolod_ok(&["soup", s(&ply), "-o", s(&soup), "--json", "--mem", "64K", "--external"]));
        let (h, tris) = octolod::soup::format::SoupReader::read_all(&soup).unwrap();
        assert_eq!(h.attrs, AttrSet(attrs), "{}: attributes", shape.name());
        assert_eq!(h.triangles + h.degenerate, g.face_count(), "{}: {text}", shape.name());
        assert!(tris.iter().flatten().all(|v| v.pos.iter().all(|x| x.is_finite())));
        if *shape != Shape::Slivers {
            assert_eq!(h.degenerate, 0, "{}: generator made repeated-index faces", shape.name());
        }
    }
}

/// The four commands a script chains, each giving what it reports: build
/// (the input's triangle count, every level's pack), info (the levels),
/// extract (level 0 is every input triangle, a cut at an error lies between
/// the root and level 0, a level out of range is a usage error) and
/// simplify (the size asked, within 1 %); only the outputs are left.
#[test]
fn build_info_extract_and_simplify_give_what_they_report_and_leave_only_outputs() {
    let d = tempfile::tempdir().unwrap();
    let ply = d.path().join("s.ply");
    gen_with("sphere", 20000, &ply, &["--normals"]);
    let store = d.path().join("s.octolod");
    let o = octolod_ok(&["build", s(&ply), "-o", s(&store), "--mem", "1M", "--leaf-tris", "1000", "--level-ratio", "2"]);
    let g = Generator::new(&GenOptions { shape: Shape::Sphere, tris: 20000, seed: 1, attrs: AttrSet(AttrSet::NORMAL) });
    let summary = out(&o);
    assert!(summary.contains(&format!("build: {} triangles", g.face_count())), "{summary}");
    for f in ["nodes.bin", "store.json", "level-0.pack", "level-1.pack"] {
        assert!(store.join(f).exists(), "{f} missing");
    }
    let text = out(&octolod_ok(&["info", s(&store)]));
    // Smooth normals are averaged out of the quadric (`--normals auto`).
    assert!(text.contains("quadric dimension 3), normals averaged"), "{text}");
    let ply_info = out(&octolod_ok(&["ply-info", s(&ply), "--header-only"]));
    assert!(ply_info.contains("quadric dimension: 6 (3 where build averages the normals)"), "{ply_info}");
    let level_lines: Vec<&str> = text.lines().filter(|l| l.trim_start().chars().next().is_some_and(|c| c.is_ascii_digit())).collect();
    assert!(level_lines.len() >= 3, "{text}");
    // Level 0 back out: every input triangle.
    let l0 = d.path().join("l0.ply");
    octolod_ok(&["extract", s(&store), "--level", "0", "-o", s(&l0)]);
    let (_, m, _) = octolod::ply::read::read_all(&l0).unwrap();
    assert_eq!(m.triangles.len() as u64, g.face_count());
    // A level that does not exist is a usage error naming the range.
    let bad = octolod(&["extract", s(&store), "--level", "40", "-o", s(&d.path().join("x.ply"))]);
    assert!(!bad.status.success());
    assert!(err(&bad).contains("levels 0..="), "{}", err(&bad));
    assert!(!d.path().join("x.ply").exists());
    // The cut at an error (here 0.2 % of the diagonal): between the root and level 0.
    let cut = d.path().join("cut.ply");
    octolod_ok(&["extract", s(&store), "--max-error", "0.2%", "-o", s(&cut)]);
    let (_, m, _) = octolod::ply::read::read_all(&cut).unwrap();
    assert!(m.triangles.len() > 300 && (m.triangles.len() as u64) < g.face_count(), "{}", m.triangles.len());
    // simplify: exactly the size asked (within 1 %).
    let small = d.path().join("small.ply");
    octolod_ok(&["simplify", s(&ply), "-o", s(&small), "--target-tris", "2000", "--leaf-tris", "1000", "--mem", "1M"]);
    let (_, m, _) = octolod::ply::read::read_all(&small).unwrap();
    assert!(m.triangles.len().abs_diff(2000) <= 20, "{}", m.triangles.len());
    // Only the outputs are left next to them (no scratch directories).
    assert_eq!(names(d.path()), ["cut.ply", "l0.ply", "s.octolod", "s.ply", "small.ply"]);
}

#[test]
fn failed_build_leaves_no_store() {
    let d = tempfile::tempdir().unwrap();
    let ply = d.path().join("t.ply");
    std::fs::write(&ply, "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n").unwrap();
    let store = d.path().join("t.octolod");
    let o = octolod(&["build", s(&ply), "-o", s(&store)]);
    assert!(!o.status.success());
    assert!(err(&o).contains("vertex index 7 out of range"), "{}", err(&o));
    assert_eq!(std::fs::read_dir(d.path()).unwrap().count(), 1, "a failed build left files behind");
}

/// `octolod-gen --atlas CELLS` writes a many-island atlas: uvs, seam
/// vertices split (more vertices than the shape's, same triangles), the
/// summary counting what it wrote; OBJ/STL output is refused.
#[test]
fn gen_atlas_writes_split_seams() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("atlas.ply");
    let o = crate::common::cli::octolod_gen(&["--shape", "sphere", "--tris", "5000", "--atlas", "3", "-q", "-o", s(&p)]);
    assert!(o.status.success(), "{}", err(&o));
    let (h, m, _) = octolod::ply::read::read_all(&p).unwrap();
    let plain = Generator::new(&GenOptions { shape: Shape::Sphere, tris: 5000, ..Default::default() });
    assert!(h.attrs.uv());
    assert_eq!(m.triangles.len() as u64, plain.face_count());
    assert!(m.vertices.len() as u64 > plain.vertex_count() + 100, "{} vertices", m.vertices.len());
    assert!(out(&o).contains(&format!("{} vertices", m.vertices.len())), "{}", out(&o));
    let obj =
        crate::common::cli::octolod_gen(&["--shape", "sphere", "--tris", "500", "--atlas", "3", "--format", "obj", "-q", "-o", s(&d.path().join("a.obj"))]);
    assert!(!obj.status.success() && err(&obj).contains("--atlas writes PLY only"), "{}", err(&obj));
}

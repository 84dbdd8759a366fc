//! Several textures end to end (issue 32): a scan-like input whose atlas
//! islands are spread over three textures (`octolod-gen --textures 3`,
//! MeshLab's face `texnumber`) is built and every level extracted as a
//! PLY; each level's faces keep the texture of the input surface under
//! them, the store holds all three images, and the levels neither tear
//! nor lock much.

use crate::common::cli::{gen_with, octolod_ok, s};
use crate::common::{crack_report, cut_mesh_parts, edge_counts, weld_positions};
use octolod::mesh::IndexedMesh;
use octolod::pipeline::CutSpec;
use std::collections::HashMap;

/// Per-triangle material (corner 0's) and centroid.
fn faces(m: &IndexedMesh) -> Vec<(u16, [f64; 3])> {
    m.triangles
        .iter()
        .map(|t| {
            let p = t.map(|i| m.vertices[i as usize].pos);
            (m.vertices[t[0] as usize].material, [0, 1, 2].map(|k| (p[0][k] + p[1][k] + p[2][k]) / 3.0))
        })
        .collect()
}

fn read(path: &std::path::Path) -> IndexedMesh {
    let (h, sink, _) = octolod::ply::read::read_all(path).unwrap();
    assert!(h.attrs.material(), "{}: attributes {}", path.display(), h.attrs.describe());
    IndexedMesh { vertices: sink.vertices, triangles: sink.triangles.iter().map(|t| t.map(|i| i as u32)).collect() }
}

/// Nearest-centroid lookups over the input's faces (a uniform grid).
struct Nearest {
    cell: f64,
    grid: HashMap<[i64; 3], Vec<usize>>,
    faces: Vec<(u16, [f64; 3])>,
}

impl Nearest {
    fn new(faces: Vec<(u16, [f64; 3])>, diag: f64) -> Nearest {
        let cell = diag / 128.0;
        let mut grid: HashMap<[i64; 3], Vec<usize>> = HashMap::new();
        for (i, f) in faces.iter().enumerate() {
            grid.entry(f.1.map(|x| (x / cell).floor() as i64)).or_default().push(i);
        }
        Nearest { cell, grid, faces }
    }

    fn material(&self, p: [f64; 3]) -> u16 {
        let k = p.map(|x| (x / self.cell).floor() as i64);
        let d2 = |q: [f64; 3]| (0..3).map(|a| (p[a] - q[a]).powi(2)).sum::<f64>();
        let mut best = (f64::INFINITY, u16::MAX);
        for r in 1i64.. {
            for x in -r..=r {
                for y in -r..=r {
                    for z in -r..=r {
                        for &i in self.grid.get(&[k[0] + x, k[1] + y, k[2] + z]).into_iter().flatten() {
                            let d = d2(self.faces[i].1);
                            if d < best.0 {
                                best = (d, self.faces[i].0);
                            }
                        }
                    }
                }
            }
            // Everything within r cells is seen: done once the best is closer.
            if best.0.sqrt() <= (r - 1) as f64 * self.cell || r > 128 {
                break;
            }
        }
        best.1
    }
}

#[test]
fn three_textures_survive_every_clustered_level() {
    three_textures_survive_every_level("cluster");
}

#[test]
fn three_textures_survive_every_collapsed_level() {
    three_textures_survive_every_level("collapse");
}

fn three_textures_survive_every_level(simplifier: &str) {
    let d = tempfile::tempdir().unwrap();
    let ply = d.path().join("scan.ply");
    gen_with("scan", 40_000, &ply, &["--atlas", "4", "--texture", "64", "--textures", "3"]);
    for k in 0..3 {
        assert!(d.path().join(format!("scan_{k}.png")).is_file());
    }
    let input = read(&ply);
    let in_faces = faces(&input);
    let per: Vec<usize> = (0..3u16).map(|k| in_faces.iter().filter(|f| f.0 == k).count()).collect();
    assert!(per.iter().all(|&n| n > in_faces.len() / 10), "triangles per texture {per:?}");
    let mut bb = octolod::mesh::Aabb::EMPTY;
    input.vertices.iter().for_each(|v| bb.add(v.pos));
    let nearest = Nearest::new(in_faces, bb.diagonal());
    let in_open = edge_counts(&weld_positions(std::iter::once((&input.vertices[..], &input.triangles[..]))).1).values().filter(|&&n| n == 1).count();

    let store = d.path().join("store");
    octolod_ok(&["build", s(&ply), "-o", s(&store), "--quiet", "--leaf-tris", "4000", "--simplifier", simplifier]);
    let m = octolod::manifest::Manifest::read(&store).unwrap();
    assert!(m.attributes.contains("material"), "attributes {}", m.attributes);
    assert_eq!(m.textures.iter().map(|t| t.name.as_str()).collect::<Vec<_>>(), ["scan_0.png", "scan_1.png", "scan_2.png"]);
    for t in &m.textures {
        let f = t.file.as_ref().unwrap_or_else(|| panic!("{} not copied", t.name));
        assert_eq!(std::fs::read(store.join(f)).unwrap(), std::fs::read(d.path().join(&t.name)).unwrap());
    }
    assert!(m.levels.len() >= 3, "{} levels", m.levels.len());
    let st = octolod::store::Store::open(&store).unwrap();
    for l in &m.levels {
        let out = d.path().join(format!("level{}.ply", l.level));
        octolod_ok(&["extract", s(&store), "--level", &l.level.to_string(), "-o", s(&out), "--quiet"]);
        let got = read(&out);
        assert_eq!(got.triangles.len() as u64, l.triangles, "level {}", l.level);
        // The same level as glTF (quantized, meshopt-compressed): a
        // primitive per material, read back through the glTF input, whose
        // image slots are the store's: the same triangles per texture.
        let glb = d.path().join(format!("level{}.glb", l.level));
        octolod_ok(&["extract", s(&store), "--level", &l.level.to_string(), "-o", s(&glb), "--quantize", "--compress", "--quiet"]);
        let (gh, gs, _) = octolod::input::read_all(&glb, 1 << 30).unwrap();
        assert!(gh.attrs.material(), "level {}: glTF attributes {}", l.level, gh.attrs.describe());
        let count = |ms: &mut dyn Iterator<Item = u16>| {
            let mut n = [0usize; 3];
            ms.for_each(|m| n[m as usize] += 1);
            n
        };
        let want = count(&mut got.triangles.iter().map(|t| got.vertices[t[0] as usize].material));
        assert_eq!(
            count(&mut gs.triangles.iter().map(|t| gs.vertices[t[0] as usize].material)),
            want,
            "level {}: triangles per texture, glTF against PLY",
            l.level
        );
        let sources = gh.texture_sources(&glb, true);
        for (k, src) in sources.iter().enumerate() {
            let octolod::manifest::TextureSource::Embedded { bytes, .. } = src else { panic!("slot {k}: {src:?}") };
            assert_eq!(bytes, &std::fs::read(store.join(format!("texture-{k}.png"))).unwrap(), "level {}: glTF image {k}", l.level);
        }
        // Every corner of a face carries the face's material.
        assert!(got.triangles.iter().all(|t| t.iter().all(|&i| got.vertices[i as usize].material == got.vertices[t[0] as usize].material)));
        let fs = faces(&got);
        let wrong = fs.iter().filter(|f| f.0 != nearest.material(f.1)).count();
        let frac = wrong as f64 / fs.len() as f64;
        let (_, tris) = weld_positions(std::iter::once((&got.vertices[..], &got.triangles[..])));
        let open = edge_counts(&tris).values().filter(|&&n| n == 1).count();
        // Odd edges away from the input's border where two nodes meet (the store's own parts).
        let ((pos, tris), shared) = cut_mesh_parts(&st, &CutSpec::Level(l.level).cut(&st).unwrap());
        let cracks = crack_report(&input, &pos, &tris, &shared);
        eprintln!(
            "{simplifier} level {}: {} triangles, texnumber mismatches {wrong} ({:.4} %), open edges {open} (input {in_open}), cracks {}, locked {:.4}",
            l.level,
            fs.len(),
            100.0 * frac,
            cracks.cracks,
            l.locked_fraction
        );
        // Level 0 holds the input's faces; coarser faces near an island
        // border may have their centroid nearer the next island's face.
        let bound = if l.level == 0 { 0.0 } else { 0.01 };
        assert!(frac <= bound, "level {}: {wrong} of {} faces sample another texture than the input under them", l.level, fs.len());
        assert!(open <= in_open, "level {}: {open} open edges, the input has {in_open}", l.level);
        assert_eq!(cracks.cracks, 0, "level {}: a tear at {:?}", l.level, cracks.first);
        assert!(l.locked_fraction < 0.10, "level {}: {:.3} of positions locked", l.level, l.locked_fraction);
    }
    // 3D Tiles: every slot gets its per-level copies, and the tiles'
    // primitives point at each of them.
    let web = d.path().join("web");
    octolod_ok(&["tiles", s(&store), "-o", s(&web), "--tile-tris", "2000", "--quiet"]);
    let names: Vec<String> = std::fs::read_dir(web.join("t")).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    for k in 0..3 {
        let copy = format!("texture-{k}-64.png");
        assert!(names.contains(&copy), "no {copy} among {names:?}");
        let used = names
            .iter()
            .filter(|n| n.ends_with(".glb"))
            .any(|n| std::fs::read(web.join("t").join(n)).unwrap().windows(copy.len()).any(|w| w == copy.as_bytes()));
        assert!(used, "no tile draws {copy}");
    }
}

/// `ply-info` lists the texture slots in material order, says whether
/// each image is beside the input, and counts each slot's triangles as the
/// decode finds them (a slot whose image is gone still counts).
#[test]
fn ply_info_lists_each_texture_slot_and_its_triangles() {
    let d = tempfile::tempdir().unwrap();
    let ply = d.path().join("scan.ply");
    gen_with("scan", 8_000, &ply, &["--atlas", "4", "--texture", "64", "--textures", "3"]);
    std::fs::remove_file(d.path().join("scan_1.png")).unwrap();
    let input = read(&ply);
    let per: Vec<usize> = (0..3u16).map(|k| input.triangles.iter().filter(|t| input.vertices[t[0] as usize].material == k).count()).collect();
    assert_eq!(per.iter().sum::<usize>(), input.triangles.len());
    let o = octolod_ok(&["ply-info", s(&ply)]);
    let text = String::from_utf8_lossy(&o.stdout);
    for line in
        ["textures: 3 (each face names its own)", "  texture 0: scan_0.png (found)", "  texture 1: scan_1.png (missing)", "  texture 2: scan_2.png (found)"]
    {
        assert!(text.lines().any(|l| l == line), "no line {line:?} in:\n{text}");
    }
    let want = format!("triangles per texture: 0: {}, 1: {}, 2: {}", per[0], per[1], per[2]);
    assert!(text.lines().any(|l| l == want), "no line {want:?} in:\n{text}");
}

/// Both soup paths give every corner its face's texnumber, byte for byte
/// alike: in memory, and external under a small budget (materials written
/// in triangle order in phase 1, patched in phase 3).
#[test]
fn both_soup_paths_carry_each_face_texnumber() {
    use octolod::soup::{build_soup, format::SoupReader, SoupOptions};
    let d = tempfile::tempdir().unwrap();
    let ply = d.path().join("scan.ply");
    gen_with("scan", 20_000, &ply, &["--atlas", "3", "--texture", "16", "--textures", "3", "--format", "ascii"]);
    let input = read(&ply);
    let want: Vec<u16> = faces(&input).iter().map(|f| f.0).collect();
    let mut soups = Vec::new();
    for (name, external) in [("mem.soup", false), ("ext.soup", true)] {
        let out = d.path().join(name);
        let rep = build_soup(&ply, &out, &SoupOptions { mem: 4 << 20, force_external: external, ..Default::default() }).unwrap();
        assert_eq!(rep.external, external);
        let (h, tris) = SoupReader::read_all(&out).unwrap();
        assert!(h.attrs.material(), "{}", h.attrs.describe());
        let got: Vec<u16> = tris.iter().map(|t| t[0].material).collect();
        assert!(tris.iter().all(|t| t.iter().all(|v| v.material == t[0].material)));
        // The soup keeps the faces' order: the same materials as the input's triangles.
        assert_eq!(got, want, "{name}");
        soups.push(std::fs::read(&out).unwrap());
    }
    assert!(soups[0] == soups[1], "the two paths' soups differ");
}

/// `build`'s default simplifier (`auto`) collapses a textured input and
/// clusters one without uvs; the store and a sharded build's plan record
/// the one used, never `auto`; an explicit choice is kept.
#[test]
fn the_default_simplifier_collapses_textured_inputs_and_clusters_the_rest() {
    let d = tempfile::tempdir().unwrap();
    let textured = d.path().join("atlas.ply");
    gen_with("scan", 6_000, &textured, &["--atlas", "4", "--texture", "64"]);
    let plain = d.path().join("plain.ply");
    gen_with("scan", 6_000, &plain, &[]);
    let recorded = |st: &std::path::Path| {
        let m: serde_json::Value = serde_json::from_slice(&std::fs::read(st.join("store.json")).unwrap()).unwrap();
        m["params"]["simplifier"].as_str().unwrap().to_string()
    };
    for (input, extra, want) in
        [(&textured, None, "collapse"), (&plain, None, "cluster"), (&textured, Some("cluster"), "cluster"), (&plain, Some("auto"), "cluster")]
    {
        let st = d.path().join(format!("{want}-{}.octolod", extra.unwrap_or("default")));
        let mut args = vec!["build", s(input), "-o", s(&st), "-q", "--leaf-tris", "1024"];
        if let Some(x) = extra {
            args.extend(["--simplifier", x]);
        }
        octolod_ok(&args);
        assert_eq!(recorded(&st), want, "{args:?}");
        let info = String::from_utf8_lossy(&octolod_ok(&["info", s(&st)]).stdout).to_string();
        assert!(info.lines().any(|l| l == format!("simplifier: {want}")), "{info}");
    }
    let plan = d.path().join("plan.json");
    octolod_ok(&["-q", "plan", s(&textured), "-o", s(&plan), "--shards", "2"]);
    let p: serde_json::Value = serde_json::from_slice(&std::fs::read(&plan).unwrap()).unwrap();
    assert_eq!(p["params"]["simplifier"], "collapse");
}

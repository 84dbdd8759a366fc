//! PLY flavors decode exactly, and the soup equals a straightforward
//! in-memory dereference for every budget, from tiny (many vertex slabs and
//! slot buckets) to large (in-memory path).

use crate::common::fixture;
use octolod::mesh::{AttrSet, Vertex, VertexLayout};
use octolod::ply::read::read_all;
use octolod::soup::format::SoupReader;
use octolod::soup::{build_soup, SoupOptions};
use std::io::Write;
use std::path::Path;

/// The mesh every fixture encodes (see fixtures/make_fixtures.py).
fn expected_vertex(i: u32) -> Vertex {
    let (bx, by, bz) = ((i & 1) as f64, ((i >> 1) & 1) as f64, ((i >> 2) & 1) as f64);
    Vertex {
        pos: [1.5 * bx - 0.25, 2.0 * by + 0.5, 0.125 - bz],
        normal: [(2.0 * bx - 1.0) as f32, (2.0 * by - 1.0) as f32, (2.0 * bz - 1.0) as f32],
        color: [(10 * i + 5) as u8, (200 - 20 * i) as u8, (7 * i) as u8, (255 - i) as u8],
        uv: [i as f32 / 8.0, 1.0 - i as f32 / 8.0],
        material: 0,
    }
}

const EXPECTED_TRIS: [[u64; 3]; 14] =
    [[0, 2, 3], [0, 3, 1], [4, 5, 7], [4, 7, 6], [0, 1, 5], [0, 5, 4], [2, 6, 7], [2, 7, 3], [0, 4, 6], [0, 6, 2], [1, 3, 7], [1, 7, 5], [4, 5, 7], [4, 7, 6]];

const FIXTURES: [(&str, u32); 6] = [
    ("cube_ascii.ply", 0),
    ("cube_le_attrs.ply", AttrSet::NORMAL | AttrSet::COLOR | AttrSet::UV),
    ("cube_be_double.ply", AttrSet::POS_F64 | AttrSet::NORMAL | AttrSet::COLOR | AttrSet::ALPHA | AttrSet::UV),
    // Its faces carry per-wedge uvs (MeshLab's `texcoord`), all 0.25.
    ("cube_all_types_le.ply", AttrSet::POS_F64 | AttrSet::UV),
    ("cube_extras_ascii.ply", AttrSet::NORMAL | AttrSet::COLOR | AttrSet::UV),
    ("cube_faces_first_be.ply", 0),
];

#[test]
fn every_fixture_flavor_decodes_exactly() {
    for (name, attrs) in FIXTURES {
        let (h, mesh, stats) = read_all(&fixture(name)).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(h.attrs, AttrSet(attrs), "{name}: attribute set");
        assert_eq!(mesh.vertices.len(), 8, "{name}");
        for (i, v) in mesh.vertices.iter().enumerate() {
            let e = expected_vertex(i as u32);
            assert_eq!(v.pos, e.pos, "{name}: vertex {i} position");
            if h.attrs.normal() {
                assert_eq!(v.normal, e.normal, "{name}: vertex {i} normal");
            }
            if h.attrs.color() {
                assert_eq!(v.color[..3], e.color[..3], "{name}: vertex {i} color");
                let alpha = if h.attrs.alpha() { e.color[3] } else { 255 };
                assert_eq!(v.color[3], alpha, "{name}: vertex {i} alpha");
            }
            if h.attrs.uv() {
                let want = if name == "cube_all_types_le.ply" { [0.25, 0.25] } else { e.uv };
                assert_eq!(v.uv, want, "{name}: vertex {i} uv");
            }
        }
        assert_eq!(mesh.triangles, EXPECTED_TRIS.to_vec(), "{name}: triangles");
        assert_eq!((stats.faces, stats.triangles, stats.degenerate, stats.polygons), (8, 14, 2, 7), "{name}");
        assert_eq!(stats.bytes, std::fs::metadata(fixture(name)).unwrap().len(), "{name}: whole file consumed");
    }
}

/// The reference: dereference every triangle in memory and encode its corners.
fn reference_soup(ply: &Path) -> (AttrSet, Vec<u8>) {
    let (h, mesh, _) = read_all(ply).unwrap();
    let l = VertexLayout::new(h.attrs);
    let mut out = vec![0u8; mesh.triangles.len() * 3 * l.size];
    for (t, tri) in mesh.triangles.iter().enumerate() {
        for c in 0..3 {
            l.encode(&mesh.vertices[tri[c] as usize], &mut out[(3 * t + c) * l.size..]);
        }
    }
    (h.attrs, out)
}

fn soup_bytes(path: &Path) -> (AttrSet, Vec<u8>) {
    let mut r = SoupReader::open(path).unwrap();
    let attrs = r.header.attrs;
    let mut all = Vec::new();
    let mut buf = Vec::new();
    while r.read_batch(&mut buf, 4096).unwrap() > 0 {
        all.extend_from_slice(&buf);
    }
    (attrs, all)
}

/// Builds the soup of `ply` under `opts`, checks its records against
/// [`reference_soup`], and gives the report and the whole file.
fn check_soup_file(ply: &Path, opts: &SoupOptions) -> (octolod::soup::SoupReport, Vec<u8>) {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.soup");
    let rep = build_soup(ply, &out, opts).unwrap_or_else(|e| panic!("{}: {e}", ply.display()));
    let (ra, reference) = reference_soup(ply);
    let (sa, soup) = soup_bytes(&out);
    assert_eq!(sa, ra, "{}: attribute set", ply.display());
    assert!(soup == reference, "{}: soup differs from the in-memory dereference (mem {})", ply.display(), opts.mem);
    assert_eq!(rep.header.triangles as usize * 3 * VertexLayout::new(sa).size, soup.len());
    // Only the soup is left: no scratch or partial files.
    let left: Vec<_> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(left, vec![std::ffi::OsString::from("out.soup")]);
    (rep, std::fs::read(&out).unwrap())
}

#[test]
fn fixture_soups_equal_reference_on_both_paths() {
    for (name, _) in FIXTURES {
        let p = fixture(name);
        let (mem, mem_file) = check_soup_file(&p, &SoupOptions::default());
        // Faces-first files cannot take the one-pass path.
        assert_eq!(mem.external, name.contains("faces_first"), "{name}");
        let (ext, ext_file) = check_soup_file(&p, &SoupOptions { mem: 64 << 10, force_external: true, ..Default::default() });
        assert!(ext.external);
        assert_eq!(ext.vertex_slabs, 1, "{name}: 8 vertices fit one slab");
        assert!(mem_file == ext_file, "{name}: the paths' soups differ");
        assert_eq!((mem.header.triangles, mem.header.degenerate), (14, 2));
        assert_eq!(mem.header.bbox, ext.header.bbox);
        assert_eq!(mem.header.bbox.min, [-0.25, 0.5, -0.875]);
        assert_eq!(mem.header.bbox.max, [1.25, 2.5, 0.125]);
    }
}

/// A grid mesh with shuffled vertex order (so corners reference vertices all
/// over the file), written by hand as binary big endian with normals, colors
/// and double positions, plus some quads and degenerate faces; the face
/// element comes first when `faces_first`.
fn write_shuffled_grid(path: &Path, n: u32, faces_first: bool) -> u64 {
    let nv = (n + 1) * (n + 1);
    // A permutation of vertex ids: multiply by a unit mod nv.
    let mut mult = 7919u64;
    while gcd(mult, nv as u64) != 1 {
        mult += 2;
    }
    let slot = |i: u32| ((i as u64 * mult) % nv as u64) as u32;
    let mut inv = vec![0u32; nv as usize];
    for i in 0..nv {
        inv[slot(i) as usize] = i;
    }
    let mut faces: Vec<Vec<u32>> = Vec::new();
    for y in 0..n {
        for x in 0..n {
            let a = y * (n + 1) + x;
            let (b, c, d) = (a + 1, a + n + 1, a + n + 2);
            if (x + y) % 5 == 0 {
                faces.push(vec![slot(a), slot(b), slot(d), slot(c)]);
            } else {
                faces.push(vec![slot(a), slot(b), slot(d)]);
                faces.push(vec![slot(a), slot(d), slot(c)]);
            }
            if (x * 7 + y) % 97 == 0 {
                faces.push(vec![slot(a), slot(a), slot(b)]);
            }
        }
    }
    let mut f = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let vertex_elem = format!("element vertex {nv}\nproperty double x\nproperty double y\nproperty double z\nproperty float nx\nproperty float ny\nproperty float nz\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n");
    let face_elem = format!("element face {}\nproperty list uchar int vertex_indices\n", faces.len());
    let (first, second) = if faces_first { (&face_elem, &vertex_elem) } else { (&vertex_elem, &face_elem) };
    write!(f, "ply\nformat binary_big_endian 1.0\n{first}{second}end_header\n").unwrap();
    let mut face_bytes = Vec::new();
    let mut tris = 0;
    for face in &faces {
        face_bytes.push(face.len() as u8);
        for &i in face {
            face_bytes.extend_from_slice(&(i as i32).to_be_bytes());
        }
        if face[0] != face[1] {
            tris += face.len() as u64 - 2;
        }
    }
    if faces_first {
        f.write_all(&face_bytes).unwrap();
    }
    for s in 0..nv {
        let i = inv[s as usize];
        let (x, y) = ((i % (n + 1)) as f64, (i / (n + 1)) as f64);
        for v in [x * 0.001 + 1e6, y * 0.001 - 1e6, (x * 0.1).sin() * 1e-4] {
            f.write_all(&v.to_be_bytes()).unwrap();
        }
        for v in [0.0f32, 0.0, 1.0] {
            f.write_all(&v.to_be_bytes()).unwrap();
        }
        f.write_all(&[(x as u32 % 256) as u8, (y as u32 % 256) as u8, 7]).unwrap();
    }
    if !faces_first {
        f.write_all(&face_bytes).unwrap();
    }
    tris
}

fn gcd(a: u64, b: u64) -> u64 {
    if b == 0 {
        a
    } else {
        gcd(b, a % b)
    }
}

#[test]
fn soup_is_exact_for_budgets_from_tiny_to_large() {
    let dir = tempfile::tempdir().unwrap();
    let ply = dir.path().join("grid.ply");
    let tris = write_shuffled_grid(&ply, 120, false);
    let mut in_memory = None;
    for (mem, external) in [(64 << 20, false), (64 << 10, true), (256 << 10, true), (4 << 20, true)] {
        let (rep, file) = check_soup_file(&ply, &SoupOptions { mem, force_external: external, ..Default::default() });
        assert_eq!(rep.header.triangles, tris);
        assert_eq!(rep.external, external);
        assert!(rep.header.attrs.pos_f64(), "far-from-origin doubles keep double precision");
        // Corner records: varints of the differences from the bucket's
        // previous index and slot, 2 to 15 bytes each (fewer than the
        // 8 bytes of fixed records, even on this shuffled grid).
        if external {
            assert!(rep.corner_bucket_bytes >= 3 * tris * 2 && rep.corner_bucket_bytes < 3 * tris * 8, "mem {mem}: {}", rep.corner_bucket_bytes);
        } else {
            assert_eq!(rep.corner_bucket_bytes, 0);
        }
        match mem {
            // The one-pass path: the reference for the external runs below.
            m if m == 64 << 20 => {
                assert_eq!((rep.vertex_slabs, rep.slot_buckets), (0, 0));
                in_memory = Some(file.clone());
            }
            m if m == 64 << 10 => {
                assert!(rep.vertex_slabs >= 20, "tiny budget must cut many vertex slabs: {}", rep.vertex_slabs);
                assert!(rep.slot_buckets >= 10, "tiny budget must distribute into many slot buckets: {}", rep.slot_buckets);
            }
            m if m == 256 << 10 => assert!(rep.vertex_slabs > 1 && rep.slot_buckets > 1, "{rep:?}"),
            // Every vertex in one slab.
            _ => assert_eq!(rep.vertex_slabs, 1),
        }
        // The whole file, header included, byte for byte the in-memory path's.
        assert!(in_memory.as_ref() == Some(&file), "mem {mem}: soup differs from the in-memory path's");
    }
    // Faces before vertices: corners are distributed before any vertex is
    // read; the same soup, whatever the budget.
    let faces_first = dir.path().join("grid-faces-first.ply");
    assert_eq!(write_shuffled_grid(&faces_first, 120, true), tris);
    for mem in [64 << 10, 64 << 20] {
        let (rep, file) = check_soup_file(&faces_first, &SoupOptions { mem, ..Default::default() });
        assert!(rep.external, "faces-first files take the external path");
        assert_eq!(rep.vertex_slabs > 1, mem == 64 << 10, "mem {mem}: {rep:?}");
        assert!(in_memory.as_ref() == Some(&file), "mem {mem}: faces-first soup differs from the in-memory path's");
    }
}

#[test]
fn position_only_soup_pays_nothing_for_attributes() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("c.soup");
    build_soup(&fixture("cube_ascii.ply"), &out, &SoupOptions::default()).unwrap();
    // 128-byte header + 14 triangles x 3 corners x 12 bytes.
    assert_eq!(std::fs::metadata(&out).unwrap().len(), 128 + 14 * 36);
}

/// A MeshLab-style textured PLY: an n×n grid whose faces carry per-wedge
/// uvs (`property list uchar float texcoord`, after the indices, or before
/// them with `tc_first`), each column of cells its own uv island (so a
/// vertex between columns has two uvs), the last cell one quad; and a
/// `comment TextureFile`. Gives each kept triangle's corner uvs in order.
fn write_wedge_ply(path: &Path, n: u32, ascii: bool, tc_first: bool) -> Vec<[[f32; 2]; 3]> {
    let nv = (n + 1) * (n + 1);
    let id = |x: u32, y: u32| y * (n + 1) + x;
    // Island per column: u offset by the column, v by the row.
    let uv = |col: u32, x: u32, y: u32| [col as f32 * 2.0 + (x - col) as f32 * 0.5, y as f32 / n as f32];
    let mut faces: Vec<(Vec<u32>, Vec<[f32; 2]>)> = Vec::new();
    for y in 0..n {
        for x in 0..n {
            let c = [(x, y), (x + 1, y), (x + 1, y + 1), (x, y + 1)];
            let idx: Vec<u32> = c.iter().map(|&(a, b)| id(a, b)).collect();
            let tc: Vec<[f32; 2]> = c.iter().map(|&(a, b)| uv(x, a, b)).collect();
            if x == n - 1 && y == n - 1 {
                faces.push((idx, tc));
            } else {
                faces.push((vec![idx[0], idx[1], idx[2]], vec![tc[0], tc[1], tc[2]]));
                faces.push((vec![idx[0], idx[2], idx[3]], vec![tc[0], tc[2], tc[3]]));
            }
        }
    }
    let mut f = std::fs::File::create(path).unwrap();
    let enc = if ascii { "ascii" } else { "binary_little_endian" };
    let (idx_p, tc_p) = ("property list uchar int vertex_indices\n", "property list uchar float texcoord\n");
    let props = if tc_first { format!("{tc_p}{idx_p}") } else { format!("{idx_p}{tc_p}") };
    write!(
        f,
        "ply\nformat {enc} 1.0\ncomment TextureFile atlas_0.png\ncomment TextureFile atlas 1.jpg\nelement vertex {nv}\nproperty float x\nproperty float y\nproperty float z\nelement face {}\n{props}end_header\n",
        faces.len()
    )
    .unwrap();
    for y in 0..=n {
        for x in 0..=n {
            let p = [x as f32, y as f32, ((x * y) % 3) as f32 * 0.25];
            if ascii {
                writeln!(f, "{} {} {}", p[0], p[1], p[2]).unwrap();
            } else {
                for c in p {
                    f.write_all(&c.to_le_bytes()).unwrap();
                }
            }
        }
    }
    for (idx, tc) in &faces {
        let mut parts: Vec<String> = Vec::new();
        let mut bytes: Vec<u8> = Vec::new();
        let idx_part = |parts: &mut Vec<String>, bytes: &mut Vec<u8>| {
            parts.push(format!("{} {}", idx.len(), idx.iter().map(|i| i.to_string()).collect::<Vec<_>>().join(" ")));
            bytes.push(idx.len() as u8);
            idx.iter().for_each(|i| bytes.extend((*i as i32).to_le_bytes()));
        };
        let tc_part = |parts: &mut Vec<String>, bytes: &mut Vec<u8>| {
            parts.push(format!("{} {}", 2 * tc.len(), tc.iter().map(|t| format!("{} {}", t[0], t[1])).collect::<Vec<_>>().join(" ")));
            bytes.push(2 * tc.len() as u8);
            tc.iter().flatten().for_each(|x| bytes.extend(x.to_le_bytes()));
        };
        if tc_first {
            tc_part(&mut parts, &mut bytes);
            idx_part(&mut parts, &mut bytes);
        } else {
            idx_part(&mut parts, &mut bytes);
            tc_part(&mut parts, &mut bytes);
        }
        if ascii {
            writeln!(f, "{}", parts.join(" ")).unwrap();
        } else {
            f.write_all(&bytes).unwrap();
        }
    }
    // Fan order: (0, k-1, k).
    faces.iter().flat_map(|(_, tc)| (2..tc.len()).map(move |k| [tc[0], tc[k - 1], tc[k]])).collect()
}

/// Issue 32: per-wedge uvs (MeshLab's face `texcoord`) become the soup
/// corners' uvs on both paths (the vertex table has none), the texture
/// names are read from the comments, and a face whose texcoord list is not
/// two values per corner (a list of another use) keeps its vertices' uvs.
#[test]
fn meshlab_wedge_texcoords_become_corner_uvs() {
    let d = tempfile::tempdir().unwrap();
    for (ascii, tc_first) in [(false, false), (true, false), (false, true)] {
        let p = d.path().join(format!("wedges-{ascii}-{tc_first}.ply"));
        let want = write_wedge_ply(&p, 12, ascii, tc_first);
        let h = octolod::ply::read_header(&p).unwrap();
        assert!(h.attrs.uv(), "wedge uvs make a mesh with uvs");
        assert_eq!(octolod::ply::texture_files(&h.comments), ["atlas_0.png", "atlas 1.jpg"]);
        let mut soups = Vec::new();
        for opts in [SoupOptions::default(), SoupOptions { mem: 64 << 10, force_external: true, ..Default::default() }] {
            let out = d.path().join("out.soup");
            let rep = build_soup(&p, &out, &SoupOptions { replace: true, ..opts.clone() }).unwrap();
            assert_eq!(rep.external, opts.force_external);
            let (sh, tris) = SoupReader::read_all(&out).unwrap();
            assert!(sh.attrs.uv());
            let got: Vec<[[f32; 2]; 3]> = tris.iter().map(|t| t.map(|v| v.uv)).collect();
            assert_eq!(got, want, "ascii {ascii}, texcoords first {tc_first}, external {}", opts.force_external);
            soups.push(std::fs::read(&out).unwrap());
        }
        assert!(soups[0] == soups[1], "the paths' soups differ");
    }
    // A triangle with 4 texcoord values keeps its vertices' uvs (u v).
    let odd = d.path().join("odd.ply");
    std::fs::write(
        &odd,
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nproperty float u\nproperty float v\nelement face 2\nproperty list uchar int vertex_indices\nproperty list uchar float texcoord\nend_header\n0 0 0 0.1 0.2\n1 0 0 0.3 0.4\n0 1 0 0.5 0.6\n3 0 1 2 6 0 0 1 0 0 1\n3 0 2 1 4 0 0 1 0\n",
    )
    .unwrap();
    for opts in [SoupOptions::default(), SoupOptions { mem: 64 << 10, force_external: true, ..Default::default() }] {
        let out = d.path().join("odd.soup");
        build_soup(&odd, &out, &SoupOptions { replace: true, ..opts }).unwrap();
        let (_, tris) = SoupReader::read_all(&out).unwrap();
        assert_eq!(tris.iter().map(|t| t.map(|v| v.uv)).collect::<Vec<_>>(), [[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]], [[0.1, 0.2], [0.5, 0.6], [0.3, 0.4]]]);
    }
    let (_, all, _) = octolod::ply::read::read_all(&odd).unwrap();
    // The vertices keep their uvs (a face uses them as they are); the wedges are new.
    assert_eq!(all.vertices.len(), 6, "one vertex per distinct uv at a vertex: {:?}", all.vertices);
}

/// Issue 32: a build keeps the textures a PLY names: the one found beside
/// the input is copied into the store (`texture-0.png`) and listed in the
/// manifest with the missing one; `--force` replaces such a store (the
/// copies are its own); an extracted PLY names the store's copy in its
/// `comment TextureFile`, relative to its folder; level 0 keeps the wedge
/// uvs (one vertex per side of each seam).
#[test]
fn a_build_keeps_the_named_textures() {
    let d = tempfile::tempdir().unwrap();
    let ply = d.path().join("textured.ply");
    let want = write_wedge_ply(&ply, 16, false, false);
    std::fs::write(d.path().join("atlas_0.png"), b"\x89PNG not really").unwrap();
    let out = d.path().join("textured.octolod");
    let opts = octolod::pipeline::BuildOptions::default();
    octolod::pipeline::build_store(&ply, &out, &opts).unwrap();
    let m = octolod::manifest::Manifest::read(&out).unwrap();
    assert_eq!(m.textures.len(), 2);
    assert_eq!((m.textures[0].name.as_str(), m.textures[0].file.as_deref(), m.textures[0].bytes), ("atlas_0.png", Some("texture-0.png"), 15));
    assert_eq!((m.textures[1].name.as_str(), m.textures[1].file.as_deref()), ("atlas 1.jpg", None));
    assert_eq!(std::fs::read(out.join("texture-0.png")).unwrap(), b"\x89PNG not really");
    // Level 0 holds the wedge uvs: every input corner's uv is a vertex's.
    let s = octolod::store::Store::open(&out).unwrap();
    let mut uvs = std::collections::HashSet::new();
    for i in s.level_nodes(0) {
        for v in s.read_node(i).unwrap().mesh.vertices {
            uvs.insert(v.uv.map(f32::to_bits));
        }
    }
    assert!(want.iter().flatten().all(|uv| uvs.contains(&uv.map(f32::to_bits))), "a wedge uv is missing at level 0");
    drop(s);
    // Replaced with --force: the texture copy is the store's own.
    octolod::pipeline::build_store(&ply, &out, &octolod::pipeline::BuildOptions { force: true, ..opts }).unwrap();
    assert!(out.join("texture-0.png").is_file());
    let s = octolod::store::Store::open(&out).unwrap();
    let top = s.top_level();
    let x = d.path().join("top.ply");
    octolod::pipeline::extract(&s, octolod::pipeline::CutSpec::Level(top), &x, true, false).unwrap();
    let h = octolod::ply::read_header(&x).unwrap();
    assert_eq!(octolod::ply::texture_files(&h.comments), ["textured.octolod/texture-0.png", "atlas 1.jpg"]);
    assert!(h.attrs.uv());
}

//! PLY flavors decode exactly, and the soup equals a straightforward
//! in-memory dereference for every budget, from tiny (many runs, multi-pass
//! merges) to large (in-memory path).

use octolod::mesh::{AttrSet, Vertex, VertexLayout};
use octolod::ply::read::read_all;
use octolod::soup::format::SoupReader;
use octolod::soup::{build_soup, SoupOptions};
use std::io::Write;
use std::path::{Path, PathBuf};

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures").join(name)
}

/// The mesh every fixture encodes (see fixtures/make_fixtures.py).
fn expected_vertex(i: u32) -> Vertex {
    let (bx, by, bz) = ((i & 1) as f64, ((i >> 1) & 1) as f64, ((i >> 2) & 1) as f64);
    Vertex {
        pos: [1.5 * bx - 0.25, 2.0 * by + 0.5, 0.125 - bz],
        normal: [(2.0 * bx - 1.0) as f32, (2.0 * by - 1.0) as f32, (2.0 * bz - 1.0) as f32],
        color: [(10 * i + 5) as u8, (200 - 20 * i) as u8, (7 * i) as u8, (255 - i) as u8],
        uv: [i as f32 / 8.0, 1.0 - i as f32 / 8.0],
    }
}

const EXPECTED_TRIS: [[u64; 3]; 14] = [
    [0, 2, 3], [0, 3, 1], [4, 5, 7], [4, 7, 6], [0, 1, 5], [0, 5, 4], [2, 6, 7], [2, 7, 3],
    [0, 4, 6], [0, 6, 2], [1, 3, 7], [1, 7, 5], [4, 5, 7], [4, 7, 6],
];

const FIXTURES: [(&str, u32); 6] = [
    ("cube_ascii.ply", 0),
    ("cube_le_attrs.ply", AttrSet::NORMAL | AttrSet::COLOR | AttrSet::UV),
    ("cube_be_double.ply", AttrSet::POS_F64 | AttrSet::NORMAL | AttrSet::COLOR | AttrSet::ALPHA | AttrSet::UV),
    ("cube_all_types_le.ply", AttrSet::POS_F64),
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
                assert_eq!(v.uv, e.uv, "{name}: vertex {i} uv");
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

fn check_soup(ply: &Path, opts: &SoupOptions) -> octolod::soup::SoupReport {
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
    rep
}

#[test]
fn fixture_soups_equal_reference_on_both_paths() {
    for (name, _) in FIXTURES {
        let p = fixture(name);
        let mem = check_soup(&p, &SoupOptions::default());
        // Faces-first files cannot take the one-pass path.
        assert_eq!(mem.external, name.contains("faces_first"), "{name}");
        let ext = check_soup(&p, &SoupOptions { mem: 64 << 10, force_external: true, max_fan_in: Some(2), ..Default::default() });
        assert!(ext.external);
        assert_eq!((mem.header.triangles, mem.header.degenerate), (14, 2));
        assert_eq!(mem.header.bbox, ext.header.bbox);
        assert_eq!(mem.header.bbox.min, [-0.25, 0.5, -0.875]);
        assert_eq!(mem.header.bbox.max, [1.25, 2.5, 0.125]);
    }
}

/// A grid mesh with shuffled vertex order (so corners reference vertices all
/// over the file), written by hand as binary big endian with normals, colors
/// and double positions, plus some quads and degenerate faces.
fn write_shuffled_grid(path: &Path, n: u32) -> u64 {
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
    write!(
        f,
        "ply\nformat binary_big_endian 1.0\nelement vertex {nv}\nproperty double x\nproperty double y\nproperty double z\nproperty float nx\nproperty float ny\nproperty float nz\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nelement face {}\nproperty list uchar int vertex_indices\nend_header\n",
        faces.len()
    )
    .unwrap();
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
    let mut tris = 0;
    for face in &faces {
        f.write_all(&[face.len() as u8]).unwrap();
        for &i in face {
            f.write_all(&(i as i32).to_be_bytes()).unwrap();
        }
        if face[0] != face[1] {
            tris += face.len() as u64 - 2;
        }
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
    let tris = write_shuffled_grid(&ply, 120);
    let mut seen_multipass = false;
    for (mem, fan, external) in [
        (64 << 10, Some(2), true),
        (64 << 10, None, true),
        (256 << 10, None, true),
        (4 << 20, None, true),
        (64 << 20, None, false),
    ] {
        let rep = check_soup(&ply, &SoupOptions { mem, force_external: external, max_fan_in: fan, ..Default::default() });
        assert_eq!(rep.header.triangles, tris);
        assert_eq!(rep.external, external);
        assert!(rep.header.attrs.pos_f64(), "far-from-origin doubles keep double precision");
        if mem == 64 << 10 {
            assert!(rep.sort_by_vertex.runs >= 20, "tiny budget must spill many runs: {:?}", rep.sort_by_vertex);
            assert!(rep.sort_by_vertex.merge_passes >= 2, "{:?}", rep.sort_by_vertex);
            assert!(rep.slot_buckets >= 10, "tiny budget must distribute into many slot buckets: {}", rep.slot_buckets);
            seen_multipass = true;
        }
        if !external {
            assert_eq!(rep.sort_by_vertex.runs, 0);
        }
    }
    assert!(seen_multipass);
}

#[test]
fn position_only_soup_pays_nothing_for_attributes() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("c.soup");
    build_soup(&fixture("cube_ascii.ply"), &out, &SoupOptions::default()).unwrap();
    // 128-byte header + 14 triangles x 3 corners x 12 bytes.
    assert_eq!(std::fs::metadata(&out).unwrap().len(), 128 + 14 * 36);
}

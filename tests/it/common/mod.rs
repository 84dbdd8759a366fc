//! The harness every test module shares: the fixture set (the hand-made
//! PLYs in `fixtures/`, generated meshes written as PLY, stores built from
//! them), running the binaries ([`cli`]), the crack checks for cuts, image
//! masks, reading JSON reports, and re-running one test of this binary in
//! a child process.
#![allow(dead_code)]

use octolod::gen::{GenOptions, Generator, Shape};
pub use octolod::manifest::BuildParams;
use octolod::manifest::Simplifier;
use octolod::mesh::IndexedMesh;
use octolod::mesh::{AttrSet, Vertex};
use octolod::pipeline::{build_store, BuildOptions};
use octolod::ply::write::{write_ply, PlyWriteOptions};
use octolod::store::{Cut, Store};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

pub mod cli;
#[cfg(feature = "view")]
pub mod gpu;
pub mod store_mutation;

/// A hand-made PLY of `fixtures/` (see fixtures/make_fixtures.py), or one
/// of the fuzzer's findings (`fuzz/NAME`: fixtures/fuzz/).
pub fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures").join(name)
}

/// The generator's mesh: `shape` with `tris` triangles, `attrs`, `seed`.
pub fn gen_mesh(shape: Shape, tris: u64, attrs: u32, seed: u64) -> IndexedMesh {
    let (vertices, triangles) = Generator::new(&GenOptions { shape, tris, seed, attrs: AttrSet(attrs) }).mesh();
    IndexedMesh { vertices, triangles }
}

/// Generates `shape` with `tris` triangles and `attrs`, writes it as
/// `dir/NAME.ply`; gives the path and the mesh.
pub fn gen_ply(dir: &Path, shape: Shape, tris: u64, attrs: u32) -> (PathBuf, IndexedMesh) {
    gen_ply_seeded(dir, shape, tris, attrs, 5)
}

/// [`gen_ply`] with the generator's seed given.
pub fn gen_ply_seeded(dir: &Path, shape: Shape, tris: u64, attrs: u32, seed: u64) -> (PathBuf, IndexedMesh) {
    let m = gen_mesh(shape, tris, attrs, seed);
    let ply = dir.join(format!("{}-{tris}-{attrs}.ply", shape.name()));
    write_ply(&ply, &PlyWriteOptions { attrs: AttrSet(attrs), ..Default::default() }, &m.vertices, &m.triangles).unwrap();
    (ply, m)
}

/// Both node simplifiers of the hierarchy, for tests run on each.
pub const SIMPLIFIERS: [Simplifier; 2] = [Simplifier::Cluster, Simplifier::Collapse];

/// `input` with a crease: the vertices `in_crease` picks get a twin whose
/// normal faces +x, taken by every triangle wholly among them, so the rim
/// of that region holds two wedges with normals apart. Written as
/// `dir/creased.ply` (positions and normals); gives its path and how many
/// vertices were twinned.
pub fn creased_ply(dir: &Path, input: &IndexedMesh, in_crease: impl Fn(&Vertex) -> bool) -> (PathBuf, usize) {
    let mut creased = input.clone();
    let twin: Vec<u32> = input
        .vertices
        .iter()
        .map(|v| {
            if !in_crease(v) {
                return u32::MAX;
            }
            creased.vertices.push(Vertex { normal: [1.0, 0.0, 0.0], ..*v });
            creased.vertices.len() as u32 - 1
        })
        .collect();
    for t in creased.triangles.iter_mut() {
        if t.iter().all(|&v| twin[v as usize] != u32::MAX) {
            *t = t.map(|v| twin[v as usize]);
        }
    }
    let ply = dir.join("creased.ply");
    write_ply(&ply, &PlyWriteOptions { attrs: AttrSet(AttrSet::NORMAL), ..Default::default() }, &creased.vertices, &creased.triangles).unwrap();
    (ply, creased.vertices.len() - input.vertices.len())
}

/// Builds a store from a PLY with small nodes (`leaf` triangles) under a small budget.
pub fn build_from(dir: &Path, ply: &Path, leaf: u64) -> Store {
    build_from_with(dir, ply, leaf, Simplifier::Cluster)
}

/// [`build_from`] with the hierarchy's node simplifier chosen.
pub fn build_from_with(dir: &Path, ply: &Path, leaf: u64, simplifier: Simplifier) -> Store {
    let suffix = if simplifier == Simplifier::Cluster { String::new() } else { format!("-{}", simplifier.name()) };
    let out = dir.join(format!("{}{suffix}.octolod", ply.file_stem().unwrap().to_string_lossy()));
    let params = BuildParams { mem: 4 << 20, leaf_tris: leaf, max_depth: 12, root_tris: 256, simplifier, ..Default::default() };
    build_store(ply, &out, &BuildOptions { params, ..Default::default() }).unwrap_or_else(|e| panic!("{} ({}): {e}", ply.display(), simplifier.name()));
    Store::open(&out).unwrap()
}

/// Quiet, non-forcing build options with these parameters.
pub fn build_options(params: BuildParams) -> BuildOptions {
    BuildOptions { params, ..Default::default() }
}

/// Builds `dir/STEM.octolod` from a PLY with the options given (default
/// simplifier); gives its path.
pub fn build_store_at(dir: &Path, ply: &Path, opts: &BuildOptions) -> PathBuf {
    let out = dir.join(format!("{}.octolod", ply.file_stem().unwrap().to_string_lossy()));
    build_store(ply, &out, opts).unwrap_or_else(|e| panic!("{}: {e}", ply.display()));
    out
}

/// Generates (with `seed`) and builds with the default build options but
/// `leaf` triangles per node: the viewer tests' store. Gives its path and the input.
pub fn default_store(dir: &Path, shape: Shape, tris: u64, attrs: u32, seed: u64, leaf: u64) -> (PathBuf, IndexedMesh) {
    let (ply, m) = gen_ply_seeded(dir, shape, tris, attrs, seed);
    (build_store_at(dir, &ply, &build_options(BuildParams { leaf_tris: leaf, ..Default::default() })), m)
}

/// Generates and builds; gives the store and the input.
pub fn build(dir: &Path, shape: Shape, tris: u64, attrs: u32, leaf: u64) -> (Store, IndexedMesh) {
    build_with(dir, shape, tris, attrs, leaf, Simplifier::Cluster)
}

/// [`build`] with the hierarchy's node simplifier chosen.
pub fn build_with(dir: &Path, shape: Shape, tris: u64, attrs: u32, leaf: u64, simplifier: Simplifier) -> (Store, IndexedMesh) {
    let (ply, m) = gen_ply(dir, shape, tris, attrs);
    (build_from_with(dir, &ply, leaf, simplifier), m)
}

pub use octolod::geom::Rng;

/// A random valid selection: from the root down, a node joins with
/// probability `p` once all its parents are in.
pub fn random_cut(s: &Store, seed: u64, p: f64) -> Cut {
    let mut rng = Rng::new(seed);
    let mut sel = vec![false; s.nodes.len()];
    for r in s.roots() {
        sel[r] = true;
    }
    for i in (0..s.nodes.len()).rev() {
        if !sel[i] && s.parents_of(i).iter().all(|&q| sel[q as usize]) && !s.parents_of(i).is_empty() && rng.f64() < p {
            sel[i] = true;
        }
    }
    Cut::from_selected(s, sel)
}

/// A mesh welded by position: the distinct positions and the triangles
/// indexing them.
pub type Welded = (Vec<[f64; 3]>, Vec<[u32; 3]>);

/// The triangles a cut draws, welded by position.
pub fn cut_mesh(s: &Store, cut: &Cut) -> Welded {
    cut_mesh_parts(s, cut).0
}

/// [`cut_mesh`], and per welded position whether two or more drawn nodes hold it.
pub fn cut_mesh_parts(s: &Store, cut: &Cut) -> (Welded, Vec<bool>) {
    let parts: Vec<IndexedMesh> = s.cut_meshes(cut).collect::<Result<_, _>>().unwrap();
    let (pos, tris) = weld_positions(parts.iter().map(|m| (&m.vertices[..], &m.triangles[..])));
    let index: HashMap<[u64; 3], usize> = pos.iter().enumerate().map(|(i, p)| (p.map(f64::to_bits), i)).collect();
    let mut owner = vec![usize::MAX; pos.len()];
    let mut shared = vec![false; pos.len()];
    for (k, m) in parts.iter().enumerate() {
        for t in &m.triangles {
            for &v in t {
                let i = index[&m.vertices[v as usize].pos.map(f64::to_bits)];
                if owner[i] == usize::MAX {
                    owner[i] = k;
                } else if owner[i] != k {
                    shared[i] = true;
                }
            }
        }
    }
    ((pos, tris), shared)
}

/// Meshes welded by exact position.
pub fn weld_positions<'a>(parts: impl Iterator<Item = (&'a [Vertex], &'a [[u32; 3]])>) -> Welded {
    let mut map: HashMap<[u64; 3], u32> = HashMap::new();
    let (mut pos, mut tris) = (Vec::new(), Vec::new());
    for (v, t) in parts {
        let ids: Vec<u32> = v
            .iter()
            .map(|x| {
                let n = pos.len() as u32;
                *map.entry(x.pos.map(f64::to_bits)).or_insert_with(|| {
                    pos.push(x.pos);
                    n
                })
            })
            .collect();
        tris.extend(t.iter().map(|t| t.map(|i| ids[i as usize])));
    }
    (pos, tris)
}

/// Uses of each undirected edge; triangles with repeated corners skipped.
pub fn edge_counts(tris: &[[u32; 3]]) -> HashMap<(u32, u32), u32> {
    let mut c = HashMap::new();
    for t in tris.iter().filter(|t| t[0] != t[1] && t[1] != t[2] && t[0] != t[2]) {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            *c.entry((a.min(b), a.max(b))).or_insert(0) += 1;
        }
    }
    c
}

fn seg_dist2(p: [f64; 3], a: [f64; 3], b: [f64; 3]) -> f64 {
    let ab = [0, 1, 2].map(|k| b[k] - a[k]);
    let ap = [0, 1, 2].map(|k| p[k] - a[k]);
    let l = ab.iter().map(|x| x * x).sum::<f64>();
    let t = if l > 0.0 { (ab.iter().zip(&ap).map(|(x, y)| x * y).sum::<f64>() / l).clamp(0.0, 1.0) } else { 0.0 };
    (0..3).map(|k| (a[k] + t * ab[k] - p[k]).powi(2)).sum()
}

/// What a crack check found in one cut.
#[derive(Debug, Default)]
pub struct CrackReport {
    /// Edges used an odd number of times away from the input's border.
    pub cracks: usize,
    /// Edges used once (open) in the cut.
    pub open: usize,
    /// Edges used more often than the input's most-used edge (and than 2).
    pub excess: usize,
    pub edges: usize,
    /// The first crack edge found.
    pub first: Option<([f64; 3], [f64; 3])>,
}

/// Checks a cut against the input: welded by position, an edge used an odd
/// number of times is a crack unless it lies on the input's own border
/// (within 3× its own length: its corners stand for clusters of border
/// vertices) or is a node's own simplified border (neither corner held by
/// two drawn nodes: a seam that failed to close has such corners at its
/// ends). On closed inputs no odd edge at all is allowed (`open` = 0).
/// `shared[v]`: position v is held by two or more drawn nodes.
pub fn crack_report(input: &IndexedMesh, pos: &[[f64; 3]], tris: &[[u32; 3]], shared: &[bool]) -> CrackReport {
    let (ip, it) = weld_positions(std::iter::once((&input.vertices[..], &input.triangles[..])));
    let ic = edge_counts(&it);
    let border: Vec<([f64; 3], [f64; 3])> = ic.iter().filter(|(_, &n)| n % 2 == 1).map(|(&(a, b), _)| (ip[a as usize], ip[b as usize])).collect();
    let max_in = ic.values().copied().max().unwrap_or(2).max(2);
    let c = edge_counts(tris);
    let mut r = CrackReport { edges: c.len(), ..Default::default() };
    // A coarse grid over the border edges for nearest-edge queries.
    let mut bb = octolod::mesh::Aabb::EMPTY;
    for p in &ip {
        bb.add(*p);
    }
    let cell = (bb.diagonal() / 64.0).max(1e-300);
    let key = |p: [f64; 3]| p.map(|x| (x / cell).floor() as i64);
    let mut grid: HashMap<[i64; 3], Vec<usize>> = HashMap::new();
    for (i, (a, b)) in border.iter().enumerate() {
        let (ka, kb) = (key(*a), key(*b));
        for x in ka[0].min(kb[0])..=ka[0].max(kb[0]) {
            for y in ka[1].min(kb[1])..=ka[1].max(kb[1]) {
                for z in ka[2].min(kb[2])..=ka[2].max(kb[2]) {
                    grid.entry([x, y, z]).or_default().push(i);
                }
            }
        }
    }
    for (&(a, b), &n) in &c {
        if n == 1 {
            r.open += 1;
        }
        if n > max_in {
            r.excess += 1;
        }
        if n % 2 == 1 {
            let (pa, pb) = (pos[a as usize], pos[b as usize]);
            let len = (0..3).map(|k| (pa[k] - pb[k]).powi(2)).sum::<f64>().sqrt();
            let tol = 3.0 * len + 1e-9 * bb.diagonal();
            let near = |p: [f64; 3]| {
                let k = key(p);
                let reach = (tol / cell).ceil() as i64 + 1;
                if ((2 * reach + 1) as f64).powi(3) > border.len() as f64 {
                    return border.iter().any(|e| seg_dist2(p, e.0, e.1) <= tol * tol);
                }
                for x in -reach..=reach {
                    for y in -reach..=reach {
                        for z in -reach..=reach {
                            for &e in grid.get(&[k[0] + x, k[1] + y, k[2] + z]).into_iter().flatten() {
                                if seg_dist2(p, border[e].0, border[e].1) <= tol * tol {
                                    return true;
                                }
                            }
                        }
                    }
                }
                false
            };
            let own_border = !shared[a as usize] && !shared[b as usize];
            if !(own_border || (near(pa) && near(pb))) {
                r.cracks += 1;
                r.first.get_or_insert((pa, pb));
            }
        }
    }
    r
}

/// Damages every payload below the store's top level (every 97th byte
/// flipped), so their loads fail their checksums; the roots stay intact.
pub fn corrupt_packs_below_top(store: &Path) {
    let st = Store::open(store).unwrap();
    for (l, part) in octolod::store::packs_of(&st.nodes).into_iter().filter(|&(l, _)| l < st.top_level()) {
        let p = octolod::store::pack_file_part(&st.dir, l, part);
        let mut b = std::fs::read(&p).unwrap();
        for i in (0..b.len()).step_by(97) {
            b[i] ^= 0x5a;
        }
        std::fs::write(&p, b).unwrap();
    }
}

/// This test binary run again for the one test `name` of module `module`
/// (its `module_path!()`), alone and with its output shown: how a test
/// runs part of itself in a fresh process (another environment, a small
/// address space).
pub fn this_test_again(module: &str, name: &str) -> std::process::Command {
    // libtest names a test by its path below the crate (`gpu::x`, not `it::gpu::x`).
    let below = module.split_once("::").map_or("", |(_, m)| m);
    let mut c = std::process::Command::new(std::env::current_exe().unwrap());
    c.args(["--exact", &format!("{below}::{name}"), "--nocapture", "--test-threads=1"]);
    c
}

/// Runs `f` on a thread of its own; fails the test when it is still
/// running after `secs` seconds (a hang), or when it panics.
pub fn finishes<T: Send + 'static>(secs: u64, what: &str, f: impl FnOnce() -> T + Send + 'static) -> T {
    let (tx, rx) = std::sync::mpsc::channel();
    let worker = std::thread::spawn(move || {
        let r = f();
        let _ = tx.send(());
        r
    });
    match rx.recv_timeout(std::time::Duration::from_secs(secs)) {
        Ok(()) | Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => worker.join().unwrap_or_else(|p| std::panic::resume_unwind(p)),
        Err(std::sync::mpsc::RecvTimeoutError::Timeout) => panic!("{what} still running after {secs} s"),
    }
}

/// Whether GPU tests are skipped explicitly (OCTOLOD_SKIP_GPU_TESTS=1,
/// for machines without a Vulkan or GL adapter); says so when they are.
pub fn gpu_tests_skipped() -> bool {
    let skip = std::env::var("OCTOLOD_SKIP_GPU_TESTS").as_deref() == Ok("1");
    if skip {
        eprintln!("OCTOLOD_SKIP_GPU_TESTS=1: skipping a GPU test");
    }
    skip
}

/// sRGB to linear, for a channel in [0, 1]: the transfer function's
/// inverse written out here, independently of the library's.
pub fn srgb_to_linear(c: f64) -> f64 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// Which pixels of an RGBA8 image are not the background `bg` (by colour).
pub fn mask(img: &[u8], bg: [u8; 4]) -> Vec<bool> {
    img.chunks_exact(4).map(|p| p[..3] != bg[..3]).collect()
}

/// The pixels of a `w` x `h` mask whose every neighbour within `r` (a
/// square) is in the mask too.
pub fn eroded(m: &[bool], w: u32, h: u32, r: i64) -> Vec<bool> {
    let at = |x: i64, y: i64| x >= 0 && y >= 0 && x < w as i64 && y < h as i64 && m[(y * w as i64 + x) as usize];
    (0..(w * h) as i64).map(|i| (-r..=r).all(|dy| (-r..=r).all(|dx| at(i % w as i64 + dx, i / w as i64 + dy)))).collect()
}

/// Parses a command's JSON output; panics with the text when it is not JSON.
pub fn json(text: &[u8]) -> serde_json::Value {
    serde_json::from_slice(text).unwrap_or_else(|e| panic!("{e}: {}", String::from_utf8_lossy(text)))
}

/// Whether two figures are equal up to `serde_json`'s float parsing (an
/// ulp or two off the nearest double without its `float_roundtrip`
/// feature): for a figure read from JSON against one computed here.
pub fn same_figure(a: f64, b: f64) -> bool {
    (a - b).abs() <= 4.0 * f64::EPSILON * a.abs().max(b.abs())
}

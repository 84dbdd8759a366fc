//! glTF output (`extract -o OUT.glb | OUT.gltf`, `octolod::gltf`): a small
//! reader here (GLB chunks, JSON, accessors, EXT_meshopt_compression views
//! decoded with the `meshopt` crate) checks every variant against the
//! store's cut, and the Khronos glTF validator must find no error in any.

use crate::common::cli::{err, names, octolod, s};
use crate::common::{self, srgb_to_linear};
use octolod::gen::Shape;
use octolod::gltf::{encode_glb, is_octolod_gltf, write_parts, GltfOptions};
use octolod::mesh::IndexedMesh;
use octolod::mesh::{AttrSet, Vertex};
use octolod::pipeline::{extract_as, weld_union, CutSpec};
use octolod::store::Store;
use serde_json::Value;
use std::path::{Path, PathBuf};

const ALL: u32 = AttrSet::NORMAL | AttrSet::COLOR | AttrSet::ALPHA | AttrSet::UV;

const VARIANTS: [GltfOptions; 4] = [
    GltfOptions { quantize: false, compress: false, textures: Vec::new() },
    GltfOptions { quantize: true, compress: false, textures: Vec::new() },
    GltfOptions { quantize: false, compress: true, textures: Vec::new() },
    GltfOptions { quantize: true, compress: true, textures: Vec::new() },
];

fn tag(o: &GltfOptions) -> &'static str {
    match (o.quantize, o.compress) {
        (false, false) => "plain",
        (true, false) => "quantize",
        (false, true) => "compress",
        (true, true) => "quantize-compress",
    }
}

// ------------------------------------------------------------------ reader

/// A parsed glTF: its JSON and its buffers' bytes (empty for a buffer with
/// no data, such as a meshopt fallback placeholder).
struct Gltf {
    json: Value,
    buffers: Vec<Option<Vec<u8>>>,
}

fn u32_at(b: &[u8], k: usize) -> u32 {
    u32::from_le_bytes(b[k..k + 4].try_into().unwrap())
}

/// Parses a GLB, checking its header and chunk framing.
fn parse_glb(b: &[u8]) -> Gltf {
    assert_eq!(&b[..4], b"glTF");
    assert_eq!(u32_at(b, 4), 2);
    assert_eq!(u32_at(b, 8) as usize, b.len(), "GLB length field");
    let jl = u32_at(b, 12) as usize;
    assert_eq!(&b[16..20], b"JSON");
    assert_eq!(jl % 4, 0);
    let json: Value = serde_json::from_slice(&b[20..20 + jl]).unwrap();
    let rest = &b[20 + jl..];
    let bin = if rest.is_empty() {
        None
    } else {
        let bl = u32_at(rest, 0) as usize;
        assert_eq!(&rest[4..8], b"BIN\0");
        assert_eq!(bl % 4, 0);
        assert_eq!(rest.len(), 8 + bl, "nothing after the BIN chunk");
        Some(rest[8..].to_vec())
    };
    let mut buffers = Vec::new();
    for (k, buf) in json["buffers"].as_array().unwrap().iter().enumerate() {
        let len = buf["byteLength"].as_u64().unwrap() as usize;
        if k == 0 && buf.get("uri").is_none() {
            let bin = bin.clone().expect("buffer 0 is the BIN chunk");
            assert!(bin.len() >= len && bin.len() <= len + 3, "BIN chunk {} for byteLength {len}", bin.len());
            buffers.push(Some(bin[..len].to_vec()));
        } else {
            assert!(buf.get("uri").is_none(), "a GLB here refers to no other file");
            buffers.push(None);
        }
    }
    Gltf { json, buffers }
}

/// Reads `.glb`, or `.gltf` with the files its buffers name.
fn read(path: &Path) -> Gltf {
    let bytes = std::fs::read(path).unwrap();
    if path.extension().unwrap() == "glb" {
        return parse_glb(&bytes);
    }
    let json: Value = serde_json::from_slice(&bytes).unwrap();
    let buffers = json["buffers"]
        .as_array()
        .unwrap()
        .iter()
        .map(|b| {
            b.get("uri").map(|u| {
                let d = std::fs::read(path.parent().unwrap().join(u.as_str().unwrap())).unwrap();
                assert_eq!(d.len() as u64, b["byteLength"].as_u64().unwrap());
                d
            })
        })
        .collect();
    Gltf { json, buffers }
}

macro_rules! by_stride {
    ($stride:expr, $f:ident, $($n:literal)*) => {
        match $stride {
            $($n => $f::<$n>,)*
            s => panic!("stride {s}"),
        }
    };
}

/// One vertex record of `N` bytes (arrays over 32 have no `Default`).
#[derive(Clone, Copy)]
struct Rec<const N: usize>([u8; N]);

impl<const N: usize> Default for Rec<N> {
    fn default() -> Self {
        Rec([0; N])
    }
}

fn decode_vertices<const N: usize>(enc: &[u8], count: usize) -> Vec<u8> {
    let v: Vec<Rec<N>> = meshopt::encoding::decode_vertex_buffer(enc, count).unwrap();
    v.iter().flat_map(|r| r.0).collect()
}

impl Gltf {
    fn view(&self, k: usize) -> &Value {
        &self.json["bufferViews"][k]
    }

    /// The bytes of bufferView `k`: decompressed when it is compressed.
    fn view_bytes(&self, k: usize) -> Vec<u8> {
        let v = self.view(k);
        let len = v["byteLength"].as_u64().unwrap() as usize;
        if let Some(c) = v["extensions"].get("EXT_meshopt_compression") {
            let buf = self.buffers[c["buffer"].as_u64().unwrap() as usize].as_ref().expect("compressed data");
            let off = c["byteOffset"].as_u64().unwrap_or(0) as usize;
            let enc = &buf[off..off + c["byteLength"].as_u64().unwrap() as usize];
            let (stride, count) = (c["byteStride"].as_u64().unwrap() as usize, c["count"].as_u64().unwrap() as usize);
            assert_eq!(stride * count, len, "the parent's byteLength is byteStride × count");
            if let Some(s) = v.get("byteStride") {
                assert_eq!(s.as_u64().unwrap() as usize, stride);
            }
            let out = match c["mode"].as_str().unwrap() {
                "ATTRIBUTES" => {
                    assert_eq!(enc[0], 0xa0, "vertex codec version 0, as EXT_meshopt_compression requires");
                    assert!(stride % 4 == 0 && stride <= 256);
                    by_stride!(stride, decode_vertices, 4 8 12 16 20 24 28 32 36 40 44 48)(enc, count)
                }
                "TRIANGLES" => {
                    assert_eq!(enc[0], 0xe1, "index codec version 1");
                    assert_eq!(count % 3, 0);
                    match stride {
                        2 => meshopt::encoding::decode_index_buffer::<u16>(enc, count).unwrap().iter().flat_map(|i| i.to_le_bytes()).collect(),
                        4 => meshopt::encoding::decode_index_buffer::<u32>(enc, count).unwrap().iter().flat_map(|i| i.to_le_bytes()).collect(),
                        s => panic!("index stride {s}"),
                    }
                }
                m => panic!("mode {m}"),
            };
            assert_eq!(out.len(), len);
            return out;
        }
        let buf = self.buffers[v["buffer"].as_u64().unwrap() as usize].as_ref().expect("view data");
        let off = v["byteOffset"].as_u64().unwrap_or(0) as usize;
        buf[off..off + len].to_vec()
    }

    /// Accessor `a`'s elements as numbers (raw stored values) and whether
    /// it is normalized, with its component type.
    fn accessor(&self, a: usize) -> (Vec<Vec<f64>>, bool, u64) {
        let acc = &self.json["accessors"][a];
        let view = acc["bufferView"].as_u64().unwrap() as usize;
        let data = self.view_bytes(view);
        let ct = acc["componentType"].as_u64().unwrap();
        let csize = match ct {
            5120 | 5121 => 1,
            5122 | 5123 => 2,
            5125 | 5126 => 4,
            _ => panic!("componentType {ct}"),
        };
        let n = match acc["type"].as_str().unwrap() {
            "SCALAR" => 1,
            "VEC2" => 2,
            "VEC3" => 3,
            "VEC4" => 4,
            t => panic!("type {t}"),
        };
        let stride = self.view(view).get("byteStride").map_or(csize * n, |s| s.as_u64().unwrap() as usize);
        let off = acc["byteOffset"].as_u64().unwrap_or(0) as usize;
        assert_eq!(off % csize, 0);
        let count = acc["count"].as_u64().unwrap() as usize;
        assert!(off + stride * (count - 1) + csize * n <= data.len(), "accessor {a} within its view");
        let comp = |b: &[u8]| -> f64 {
            match ct {
                5120 => b[0] as i8 as f64,
                5121 => b[0] as f64,
                5122 => i16::from_le_bytes([b[0], b[1]]) as f64,
                5123 => u16::from_le_bytes([b[0], b[1]]) as f64,
                5125 => u32::from_le_bytes(b[..4].try_into().unwrap()) as f64,
                _ => f32::from_le_bytes(b[..4].try_into().unwrap()) as f64,
            }
        };
        let els = (0..count).map(|i| (0..n).map(|c| comp(&data[off + i * stride + c * csize..])).collect()).collect();
        (els, acc["normalized"].as_bool().unwrap_or(false), ct)
    }

    fn extensions(&self, key: &str) -> Vec<String> {
        self.json[key].as_array().map(|a| a.iter().map(|x| x.as_str().unwrap().to_string()).collect()).unwrap_or_default()
    }
}

fn unnorm(x: f64, ct: u64) -> f64 {
    match ct {
        5120 => (x / 127.0).max(-1.0),
        5121 => x / 255.0,
        5122 => (x / 32767.0).max(-1.0),
        5123 => x / 65535.0,
        _ => x,
    }
}

/// A glTF's mesh, decoded: every primitive concatenated.
#[derive(Default, Debug)]
struct Decoded {
    /// Object-space positions (the node's transform applied).
    pos: Vec<[f64; 3]>,
    normal: Option<Vec<[f64; 3]>>,
    color: Option<Vec<Vec<f64>>>,
    uv: Option<Vec<[f64; 2]>>,
    tris: Vec<[u32; 3]>,
    /// Per primitive: vertices and index component type. Colours: linear,
    /// in [0,1].
    prims: Vec<(usize, u64)>,
    /// The translation and uniform scale of the node.
    translation: [f64; 3],
    scale: f64,
    /// Component types of POSITION, NORMAL, TEXCOORD_0 (0 when absent).
    types: [u64; 3],
}

fn decode(g: &Gltf) -> Decoded {
    let j = &g.json;
    assert_eq!(j["asset"]["version"], "2.0");
    assert_eq!(j["asset"]["extras"]["octolod"], "output");
    assert!(j["asset"]["generator"].as_str().unwrap().starts_with("octolod "));
    assert_eq!(j["scenes"].as_array().unwrap().len(), 1);
    assert_eq!(j["nodes"].as_array().unwrap().len(), 1);
    assert_eq!(j["meshes"].as_array().unwrap().len(), 1);
    let node = &j["nodes"][0];
    let t: Vec<f64> = node["translation"].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
    let sc: Vec<f64> = node.get("scale").map_or(vec![1.0; 3], |s| s.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect());
    assert!(sc[0] == sc[1] && sc[1] == sc[2], "uniform scale");
    let mut d = Decoded { translation: [t[0], t[1], t[2]], scale: sc[0], ..Default::default() };
    for p in j["meshes"][0]["primitives"].as_array().unwrap() {
        assert_eq!(p.get("mode").map_or(4, |m| m.as_u64().unwrap()), 4);
        let at = &p["attributes"];
        let (pos, pn, pct) = g.accessor(at["POSITION"].as_u64().unwrap() as usize);
        // min/max: the stored values' bounds.
        let acc = &j["accessors"][at["POSITION"].as_u64().unwrap() as usize];
        for c in 0..3 {
            let lo = pos.iter().map(|e| e[c]).fold(f64::INFINITY, f64::min);
            let hi = pos.iter().map(|e| e[c]).fold(f64::NEG_INFINITY, f64::max);
            // As f32: serde_json's default parser may miss a double by an
            // ulp; the stored values are f32 (or small integers) exactly.
            assert_eq!(acc["min"][c].as_f64().unwrap() as f32, lo as f32, "POSITION min");
            assert_eq!(acc["max"][c].as_f64().unwrap() as f32, hi as f32, "POSITION max");
        }
        d.types[0] = pct;
        let base = d.pos.len() as u32;
        let nv = pos.len();
        for e in &pos {
            let v = [0, 1, 2].map(|c| if pn { unnorm(e[c], pct) } else { e[c] });
            d.pos.push([0, 1, 2].map(|c| d.translation[c] + d.scale * v[c]));
        }
        if let Some(a) = at.get("NORMAL") {
            let (els, n, ct) = g.accessor(a.as_u64().unwrap() as usize);
            d.types[1] = ct;
            d.normal.get_or_insert_with(Vec::new).extend(els.iter().map(|e| [0, 1, 2].map(|c| if n { unnorm(e[c], ct) } else { e[c] })));
        }
        if let Some(a) = at.get("COLOR_0") {
            let (els, n, ct) = g.accessor(a.as_u64().unwrap() as usize);
            assert!(n && ct == 5123, "colors are normalized unsigned shorts");
            d.color.get_or_insert_with(Vec::new).extend(els.iter().map(|e| e.iter().map(|&x| unnorm(x, ct)).collect::<Vec<f64>>()));
        }
        assert_eq!(p["material"], 0, "every primitive uses the one material");
        if let Some(a) = at.get("TEXCOORD_0") {
            let (els, n, ct) = g.accessor(a.as_u64().unwrap() as usize);
            d.types[2] = ct;
            d.uv.get_or_insert_with(Vec::new).extend(els.iter().map(|e| [0, 1].map(|c| if n { unnorm(e[c], ct) } else { e[c] })));
        }
        let (idx, _, ict) = g.accessor(p["indices"].as_u64().unwrap() as usize);
        assert_eq!(idx.len() % 3, 0);
        for t in idx.chunks(3) {
            let t = [t[0][0] as u32, t[1][0] as u32, t[2][0] as u32];
            assert!(t.iter().all(|&i| (i as usize) < nv), "index within the primitive");
            d.tris.push(t.map(|i| i + base));
        }
        d.prims.push((nv, ict));
    }
    d
}

/// An sRGB-encoded colour with linear alpha, as glTF's linear COLOR_0.
fn linear_color(c: [u8; 4]) -> [f64; 4] {
    [srgb_to_linear(c[0] as f64 / 255.0), srgb_to_linear(c[1] as f64 / 255.0), srgb_to_linear(c[2] as f64 / 255.0), c[3] as f64 / 255.0]
}

/// The triangle rotated to start at its smallest index (winding kept).
fn canon(t: [u32; 3]) -> [u32; 3] {
    let k = (0..3).min_by_key(|&k| t[k]).unwrap();
    [t[k], t[(k + 1) % 3], t[(k + 2) % 3]]
}

fn unit(n: [f32; 3]) -> [f64; 3] {
    let d = n.map(f64::from);
    let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    if l > 0.0 {
        d.map(|x| x / l)
    } else {
        [0.0, 0.0, 1.0]
    }
}

/// Checks a decoded glTF against the mesh it was written from.
fn check(d: &Decoded, want: &IndexedMesh, attrs: AttrSet, opts: &GltfOptions, what: &str) {
    assert_eq!(d.pos.len(), want.vertices.len(), "{what}: vertices");
    assert_eq!(d.tris.len(), want.triangles.len(), "{what}: triangles");
    let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for v in &want.vertices {
        for c in 0..3 {
            lo[c] = lo[c].min(v.pos[c]);
            hi[c] = hi[c].max(v.pos[c]);
        }
    }
    let diag = (0..3).map(|c| (hi[c] - lo[c]).powi(2)).sum::<f64>().sqrt();
    let tol = if opts.quantize {
        assert_eq!(d.types[0], 5122, "{what}: int16 positions");
        // Half a quantization step, plus the doubles' own rounding.
        0.5 * d.scale / 32767.0 * (1.0 + 1e-9) + 1e-12 * diag.max(1.0)
    } else {
        assert_eq!(d.types[0], 5126, "{what}: float positions");
        1e-6 * diag
    };
    for (k, (a, b)) in d.pos.iter().zip(&want.vertices).enumerate() {
        for (c, (x, y)) in a.iter().zip(b.pos).enumerate() {
            assert!((x - y).abs() <= tol, "{what}: vertex {k} axis {c}: {x} vs {y} (tol {tol})");
        }
    }
    assert_eq!(d.normal.is_some(), attrs.normal(), "{what}: NORMAL present exactly when the store has normals");
    assert_eq!(d.color.is_some(), attrs.color(), "{what}: COLOR_0 present exactly when the store has colors");
    assert_eq!(d.uv.is_some(), attrs.uv(), "{what}: TEXCOORD_0 present exactly when the store has uvs");
    if let Some(n) = &d.normal {
        let ntol = if opts.quantize { 0.5 / 127.0 + 1e-6 } else { 1e-6 };
        assert_eq!(d.types[1], if opts.quantize { 5120 } else { 5126 });
        for (a, b) in n.iter().zip(&want.vertices) {
            let u = unit(b.normal);
            assert!((0..3).all(|c| (a[c] - u[c]).abs() <= ntol), "{what}: normal {a:?} vs {u:?}");
        }
    }
    if let Some(col) = &d.color {
        for (a, b) in col.iter().zip(&want.vertices) {
            assert_eq!(a.len(), if attrs.alpha() { 4 } else { 3 }, "{what}: VEC4 colors exactly with alpha");
            let lin = linear_color(b.color);
            assert!(a.iter().zip(&lin).all(|(x, y)| (x - y).abs() <= 0.5 / 65535.0 + 1e-12), "{what}: color {a:?} vs {lin:?} (sRGB {:?})", b.color);
        }
    }
    if let Some(uv) = &d.uv {
        let unit_uvs = want.vertices.iter().all(|v| v.uv.iter().all(|u| (0.0..=1.0).contains(u)));
        let q = opts.quantize && unit_uvs;
        assert_eq!(d.types[2], if q { 5123 } else { 5126 }, "{what}: uv storage");
        let utol = if q { 0.5 / 65535.0 + 1e-9 } else { 0.0 };
        for (a, b) in uv.iter().zip(&want.vertices) {
            // glTF's v runs down the image: TEXCOORD_0 is (u, 1 - v).
            let g = [b.uv[0], 1.0 - b.uv[1]];
            assert!((0..2).all(|c| (a[c] - g[c] as f64).abs() <= utol), "{what}: uv {a:?} vs {g:?} (octolod's {:?})", b.uv);
        }
    }
    // Same triangles in the same order with the same winding (meshopt's
    // triangle codec may rotate a triangle's corners).
    for (k, (a, b)) in d.tris.iter().zip(&want.triangles).enumerate() {
        if opts.compress {
            assert_eq!(canon(*a), canon(*b), "{what}: triangle {k}");
        } else {
            assert_eq!(a, b, "{what}: triangle {k}");
        }
    }
    for &(nv, ict) in &d.prims {
        assert_eq!(ict, if nv <= 65535 { 5123 } else { 5125 }, "{what}: u16 indices exactly up to 65535 vertices");
    }
}

/// Extensions used and required by a variant; a compressed file's
/// fallback buffer is a placeholder without data.
fn check_extensions(g: &Gltf, opts: &GltfOptions, what: &str) {
    let mut want = Vec::new();
    if opts.quantize {
        want.push("KHR_mesh_quantization".to_string());
    }
    if opts.compress {
        want.push("EXT_meshopt_compression".to_string());
    }
    assert_eq!(g.extensions("extensionsUsed"), want, "{what}");
    assert_eq!(g.extensions("extensionsRequired"), want, "{what}");
    let bufs = g.json["buffers"].as_array().unwrap();
    if opts.compress {
        assert_eq!(bufs.len(), 2, "{what}");
        assert!(bufs[1].get("uri").is_none() && g.buffers[1].is_none(), "{what}: placeholder fallback");
        assert_eq!(bufs[1]["extensions"]["EXT_meshopt_compression"]["fallback"], true);
        // Every view lives in the fallback buffer, within its byteLength,
        // and is compressed into buffer 0.
        let flen = bufs[1]["byteLength"].as_u64().unwrap();
        for v in g.json["bufferViews"].as_array().unwrap() {
            assert_eq!(v["buffer"], 1);
            assert!(v["byteOffset"].as_u64().unwrap() + v["byteLength"].as_u64().unwrap() <= flen);
            assert_eq!(v["extensions"]["EXT_meshopt_compression"]["buffer"], 0);
        }
    } else {
        assert_eq!(bufs.len(), 1, "{what}");
    }
}

/// The fallback buffer's content, rebuilt from the decompressed views
/// (each at its fallback offset).
fn fallback_bytes(g: &Gltf) -> Vec<u8> {
    let len = g.json["buffers"][1]["byteLength"].as_u64().unwrap() as usize;
    let mut out = vec![0u8; len];
    for k in 0..g.json["bufferViews"].as_array().unwrap().len() {
        // Views stored as they are (an embedded image) are not in the fallback.
        if g.view(k).get("extensions").is_none() {
            continue;
        }
        let off = g.view(k)["byteOffset"].as_u64().unwrap() as usize;
        let b = g.view_bytes(k);
        out[off..off + b.len()].copy_from_slice(&b);
    }
    out
}

// ----------------------------------------------------------------- fixtures

fn cut_parts(s: &Store, spec: CutSpec) -> Vec<IndexedMesh> {
    let cut = spec.cut(s).unwrap();
    s.cut_meshes(&cut).collect::<octolod::Result<Vec<_>>>().unwrap()
}

fn welded(s: &Store, spec: CutSpec) -> IndexedMesh {
    weld_union(&s.layout, cut_parts(s, spec))
}

/// The parts with triangles, concatenated as they come.
fn concatenated(parts: &[IndexedMesh]) -> IndexedMesh {
    let mut m = IndexedMesh::default();
    for p in parts.iter().filter(|p| !p.triangles.is_empty()) {
        let base = m.vertices.len() as u32;
        m.vertices.extend_from_slice(&p.vertices);
        m.triangles.extend(p.triangles.iter().map(|t| t.map(|i| i + base)));
    }
    m
}

/// A `w × h` grid over [0, 2]² at `origin`, uvs from -0.5 to 1.5 when
/// `wide_uv` (not quantizable), colors with alpha, tilted normals.
fn grid(w: u32, h: u32, origin: [f64; 3], wide_uv: bool) -> IndexedMesh {
    let mut m = IndexedMesh::default();
    for j in 0..h {
        for i in 0..w {
            let (u, v) = (i as f64 / (w - 1) as f64, j as f64 / (h - 1) as f64);
            let uv = if wide_uv { [(2.0 * u - 0.5) as f32, (2.0 * v - 0.5) as f32] } else { [u as f32, v as f32] };
            m.vertices.push(Vertex {
                pos: [origin[0] + 2.0 * u, origin[1] + 2.0 * v, origin[2] + 0.01 * (i % 7) as f64],
                normal: [0.1 * u as f32, 0.0, 2.0],
                color: [(i % 256) as u8, (j % 256) as u8, 7, (i * j % 256) as u8],
                uv,
                material: 0,
            });
        }
    }
    for j in 0..h - 1 {
        for i in 0..w - 1 {
            let a = j * w + i;
            m.triangles.push([a, a + 1, a + w + 1]);
            m.triangles.push([a, a + w + 1, a + w]);
        }
    }
    m
}

// -------------------------------------------------------------------- tests

#[test]
fn every_variant_of_a_level_matches_the_store_cut() {
    let d = tempfile::tempdir().unwrap();
    for (attrs, shape) in [(ALL, Shape::Sphere), (AttrSet::COLOR, Shape::Plane), (0, Shape::Terrain)] {
        let (s, _) = common::build(d.path(), shape, 6000, attrs, 800);
        let attrs = s.header.attrs;
        for spec in [CutSpec::Level(0), CutSpec::Level(1)] {
            let want = welded(&s, spec);
            let mut plain_bins: Vec<(String, Vec<u8>)> = Vec::new();
            for opts in VARIANTS {
                for ext in ["glb", "gltf"] {
                    let out = d.path().join(format!("{}-{}-{:?}.{ext}", shape.name(), tag(&opts), spec).replace([' ', '(', ')'], ""));
                    let (nv, nt) = extract_as(&s, spec, &out, true, false, &opts).unwrap();
                    assert_eq!((nv, nt), (want.vertices.len() as u64, want.triangles.len() as u64));
                    assert!(is_octolod_gltf(&out));
                    let what = format!("{} {} {spec:?} .{ext}", shape.name(), tag(&opts));
                    let g = read(&out);
                    check_extensions(&g, &opts, &what);
                    let dec = decode(&g);
                    assert_eq!(dec.prims.len(), 1, "{what}: a welded cut is one primitive");
                    check(&dec, &want, attrs, &opts, &what);
                    // The fallback's layout is the uncompressed file's
                    // buffer: its vertex bytes decode to the very same
                    // bytes, its triangles to the same up to rotation.
                    if !opts.compress {
                        plain_bins.push((format!("{}{ext}", opts.quantize), g.buffers[0].clone().unwrap()));
                    } else {
                        let plain = &plain_bins.iter().find(|(k, _)| *k == format!("{}{ext}", opts.quantize)).unwrap().1;
                        let fb = fallback_bytes(&g);
                        assert_eq!(fb.len(), plain.len(), "{what}: fallback length");
                        let views = g.json["bufferViews"].as_array().unwrap();
                        for v in views.iter().filter(|v| v["target"] == 34962) {
                            let (o, l) = (v["byteOffset"].as_u64().unwrap() as usize, v["byteLength"].as_u64().unwrap() as usize);
                            assert!(fb[o..o + l] == plain[o..o + l], "{what}: vertex bytes");
                        }
                    }
                    if ext == "gltf" {
                        let bin = out.with_extension("bin");
                        assert!(bin.is_file(), "{what}: the .bin beside");
                        assert_eq!(g.json["buffers"][0]["uri"], bin.file_name().unwrap().to_str().unwrap());
                    }
                }
            }
        }
    }
}

#[test]
fn a_streamed_cut_is_one_primitive_per_run_of_nodes() {
    let d = tempfile::tempdir().unwrap();
    let (s, _) = common::build(d.path(), Shape::Sphere, 8000, ALL, 500);
    let spec = CutSpec::MaxError(0.0);
    let parts = cut_parts(&s, spec);
    let want = concatenated(&parts);
    let cut = spec.cut(&s).unwrap();
    for opts in VARIANTS {
        // Through extract (--no-weld): the default run holds this whole cut.
        let out = d.path().join(format!("nw-{}.glb", tag(&opts)));
        let (nv, nt) = extract_as(&s, spec, &out, false, false, &opts).unwrap();
        assert_eq!((nv, nt), (want.vertices.len() as u64, want.triangles.len() as u64));
        let dec = decode(&read(&out));
        check(&dec, &want, s.header.attrs, &opts, &format!("no-weld {}", tag(&opts)));
        // Small runs: many primitives, none over the limit, whole nodes.
        for ext in ["glb", "gltf"] {
            let out = d.path().join(format!("runs-{}.{ext}", tag(&opts)));
            write_parts(&out, s.header.attrs, &opts, false, "runs", 1000, || s.cut_meshes(&cut)).unwrap();
            let g = read(&out);
            check_extensions(&g, &opts, "runs");
            let dec = decode(&g);
            assert!(dec.prims.len() > 3, "{} primitives", dec.prims.len());
            let sizes: Vec<usize> = parts.iter().filter(|p| !p.triangles.is_empty()).map(|p| p.vertices.len()).collect();
            let (mut k, mut total) = (0, 0);
            for &(nv, _) in &dec.prims {
                // Each primitive is a run of whole nodes.
                let mut n = 0;
                while n < nv {
                    n += sizes[k];
                    k += 1;
                }
                assert_eq!(n, nv);
                assert!(nv <= 1000 || sizes[k - 1] == nv, "a primitive over the limit is a single node");
                total += nv;
            }
            assert_eq!(total, want.vertices.len());
            check(&dec, &want, s.header.attrs, &opts, &format!("runs {} .{ext}", tag(&opts)));
        }
    }
}

#[test]
fn big_meshes_get_32_bit_indices_and_odd_uvs_stay_float() {
    // 300 × 240 = 72000 vertices: over u16.
    let m = grid(300, 240, [3.0, -4.0, 5.0], true);
    let attrs = AttrSet(ALL);
    for opts in VARIANTS {
        let mut b = Vec::new();
        encode_glb(&m, attrs, &opts, &mut b).unwrap();
        let g = parse_glb(&b);
        check_extensions(&g, &opts, tag(&opts));
        let dec = decode(&g);
        assert_eq!(dec.prims, vec![(72000, 5125)]);
        check(&dec, &m, attrs, &opts, &format!("grid {}", tag(&opts)));
    }
    // 255 × 257 = 65535 vertices: still u16.
    let m = grid(255, 257, [0.0; 3], false);
    let mut b = Vec::new();
    encode_glb(&m, AttrSet(0), &GltfOptions { quantize: true, compress: true, textures: Vec::new() }, &mut b).unwrap();
    let dec = decode(&parse_glb(&b));
    assert_eq!(dec.prims, vec![(65535, 5123)]);
    check(&dec, &m, AttrSet(0), &GltfOptions { quantize: true, compress: true, textures: Vec::new() }, "65535");
}

#[test]
fn a_mesh_far_from_the_origin_keeps_its_detail() {
    let d = tempfile::tempdir().unwrap();
    let (s, _) = common::build(d.path(), Shape::Offset, 4000, AttrSet::POS_F64 | AttrSet::NORMAL, 600);
    let want = welded(&s, CutSpec::Level(0));
    for opts in VARIANTS {
        let out = d.path().join(format!("far-{}.glb", tag(&opts)));
        extract_as(&s, CutSpec::Level(0), &out, true, false, &opts).unwrap();
        let dec = decode(&read(&out));
        assert!(dec.translation.iter().all(|t| (t - 1e6).abs() < 1.0), "{:?}", dec.translation);
        // check(): within 1e-6 of the diagonal (~1e-6 absolute here, where
        // f32 at 1e6 would be off by 0.06), or half an int16 step.
        check(&dec, &want, s.header.attrs, &opts, &format!("far {}", tag(&opts)));
        if opts.quantize {
            assert!(dec.scale < 1.0, "the step follows the mesh, not its distance: {}", dec.scale);
        }
    }
}

#[test]
fn only_our_own_gltf_is_replaced_and_only_with_force() {
    let d = tempfile::tempdir().unwrap();
    let (s, _) = common::build(d.path(), Shape::Sphere, 3000, 0, 1000);
    let dir = d.path().join("out");
    std::fs::create_dir(&dir).unwrap();
    let spec = CutSpec::Level(1);
    let opts = GltfOptions::default();
    let glb = dir.join("a.glb");
    extract_as(&s, spec, &glb, true, false, &opts).unwrap();
    let e = extract_as(&s, spec, &glb, true, false, &opts).unwrap_err().to_string();
    assert!(e.contains("--force"), "{e}");
    extract_as(&s, spec, &glb, true, true, &GltfOptions { quantize: true, compress: false, textures: Vec::new() }).unwrap();
    assert!(read(&glb).extensions("extensionsUsed").contains(&"KHR_mesh_quantization".to_string()));

    // A pair, replaced as a pair.
    let gltf = dir.join("b.gltf");
    extract_as(&s, spec, &gltf, true, false, &opts).unwrap();
    extract_as(&s, spec, &gltf, false, true, &GltfOptions { quantize: false, compress: true, textures: Vec::new() }).unwrap();
    assert_eq!(decode(&read(&gltf)).tris.len() as u64, s.level_triangles(1));
    assert_eq!(names(&dir), ["a.glb", "b.bin", "b.gltf"]);

    // Foreign files, even with --force: a GLB and a .gltf of another tool,
    // a .bin beside a new .gltf, a .bin an octolod .gltf does not name, a
    // directory, a PLY.
    let mut other = Vec::new();
    encode_glb(&grid(3, 3, [0.0; 3], false), AttrSet(0), &opts, &mut other).unwrap();
    let jl = u32::from_le_bytes(other[12..16].try_into().unwrap()) as usize;
    let text = String::from_utf8(other[20..20 + jl].to_vec()).unwrap().replace("\"octolod\":\"output\"", "\"octolod\":\"theirs\"");
    other[20..20 + jl].copy_from_slice(text.as_bytes());
    let theirs = dir.join("theirs.glb");
    std::fs::write(&theirs, &other).unwrap();
    assert!(!is_octolod_gltf(&theirs));
    let their_gltf = dir.join("theirs.gltf");
    std::fs::write(&their_gltf, r#"{"asset":{"version":"2.0","generator":"octolod 0.1.0"}}"#).unwrap();
    let lone_bin = dir.join("lone.bin");
    std::fs::write(&lone_bin, b"precious").unwrap();
    let renamed = dir.join("c.gltf");
    std::fs::copy(&gltf, &renamed).unwrap();
    std::fs::write(dir.join("c.bin"), b"precious too").unwrap();
    std::fs::create_dir(dir.join("d.glb")).unwrap();
    let ply = dir.join("e.glb");
    std::fs::write(&ply, "ply\nformat ascii 1.0\ncomment octolod-output\nend_header\n").unwrap();
    let before: Vec<(String, Vec<u8>)> =
        names(&dir).into_iter().filter(|n| !n.ends_with("d.glb")).map(|n| (n.clone(), std::fs::read(dir.join(&n)).unwrap())).collect();
    for (out, weld) in [(&theirs, true), (&their_gltf, false), (&dir.join("lone.gltf"), true), (&renamed, true), (&dir.join("d.glb"), true), (&ply, false)] {
        for force in [false, true] {
            let e = extract_as(&s, spec, out, weld, force, &opts).unwrap_err().to_string();
            assert!(e.contains("refusing"), "{}: {e}", out.display());
        }
    }
    let after: Vec<(String, Vec<u8>)> =
        names(&dir).into_iter().filter(|n| !n.ends_with("d.glb")).map(|n| (n.clone(), std::fs::read(dir.join(&n)).unwrap())).collect();
    assert_eq!(before, after, "nothing changed, nothing left behind");
}

#[test]
fn errors_leave_nothing_behind() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("x.gltf");
    let opts = GltfOptions { quantize: true, compress: true, textures: Vec::new() };
    // Empty: an error, not an empty file.
    let e = write_parts(&out, AttrSet(0), &opts, false, "e", 100, || std::iter::once(Ok(IndexedMesh::default()))).unwrap_err().to_string();
    assert!(e.contains("no triangles"), "{e}");
    let mut b = Vec::new();
    assert!(encode_glb(&IndexedMesh::default(), AttrSet(0), &opts, &mut b).is_err());
    // A broken index.
    let mut bad = grid(4, 4, [0.0; 3], false);
    bad.triangles[3][1] = 99;
    assert!(write_parts(&out, AttrSet(0), &opts, false, "e", 100, || std::iter::once(Ok(bad.clone()))).is_err());
    // Failing in the second pass, with the scratch files already open.
    for ext in ["glb", "gltf"] {
        let out = d.path().join(format!("y.{ext}"));
        for compress in [false, true] {
            let mut pass = 0;
            let e = write_parts(&out, AttrSet(ALL), &GltfOptions { quantize: false, compress, textures: Vec::new() }, false, "e", 20, || {
                pass += 1;
                let p = pass;
                (0..4).map(move |k| if p == 2 && k == 2 { Err(octolod::Error::Usage("gone".into())) } else { Ok(grid(4, 4, [k as f64; 3], false)) })
            });
            assert_eq!(e.unwrap_err().to_string(), "gone");
        }
    }
    assert!(names(d.path()).is_empty(), "{:?}", names(d.path()));
}

#[test]
fn the_cli_picks_the_format_by_extension_and_refuses_gltf_flags_for_ply() {
    let d = tempfile::tempdir().unwrap();
    let (st, _) = common::build(d.path(), Shape::Sphere, 3000, ALL, 1000);
    let store = st.dir.clone();
    let out = d.path().join("cli.glb");
    let o = octolod(&["extract", s(&store), "--level", "1", "--quantize", "--compress", "-o", s(&out)]);
    assert!(o.status.success(), "{}", err(&o));
    let dec = decode(&read(&out));
    assert_eq!(dec.tris.len() as u64, st.level_triangles(1));
    let out = d.path().join("cli.gltf");
    let o = octolod(&["extract", s(&store), "--max-error", "1%", "--no-weld", "-o", s(&out)]);
    assert!(o.status.success(), "{}", err(&o));
    assert!(out.with_extension("bin").is_file());
    let ply = d.path().join("cli.ply");
    for flag in ["--quantize", "--compress"] {
        let o = octolod(&["extract", s(&store), "--level", "1", flag, "-o", s(&ply)]);
        assert_eq!(o.status.code(), Some(1));
        let e = err(&o);
        assert!(e.contains("glTF") && e.contains(flag), "{e}");
        assert!(!ply.exists());
    }
    let o = octolod(&["extract", s(&store), "--level", "1", "-o", s(&ply)]);
    assert!(o.status.success(), "{}", err(&o));
    assert!(std::fs::read(&ply).unwrap().starts_with(b"ply\n"));
}

#[test]
fn colours_are_linear_normalized_unsigned_shorts_and_alpha_is_kept() {
    let v = |x: f64, y: f64, color: [u8; 4]| Vertex { pos: [x, y, 0.0], normal: [0.0, 0.0, 1.0], color, uv: [0.0, 0.0], material: 0 };
    let m = IndexedMesh {
        vertices: vec![v(0.0, 0.0, [0, 128, 255, 0]), v(1.0, 0.0, [128, 1, 13, 77]), v(0.0, 1.0, [255, 0, 128, 255])],
        triangles: vec![[0, 1, 2]],
    };
    // sRGB 128 is linear 0.21586050…
    let half = 0.2158605;
    for opts in VARIANTS {
        for (attrs, n) in [(AttrSet::COLOR, 3), (AttrSet::COLOR | AttrSet::ALPHA, 4), (ALL, 4)] {
            let what = format!("{} {attrs:#x}", tag(&opts));
            let mut b = Vec::new();
            encode_glb(&m, AttrSet(attrs), &opts, &mut b).unwrap();
            let g = parse_glb(&b);
            let a = g.json["meshes"][0]["primitives"][0]["attributes"]["COLOR_0"].as_u64().unwrap() as usize;
            let acc = &g.json["accessors"][a];
            assert_eq!(acc["componentType"], 5123, "{what}");
            assert_eq!(acc["normalized"], true, "{what}");
            assert_eq!(acc["type"], if n == 4 { "VEC4" } else { "VEC3" }, "{what}");
            assert_eq!(acc["byteOffset"].as_u64().unwrap() % 4, 0, "{what}: the record stays 4-byte aligned");
            let (els, _, _) = g.accessor(a);
            let lin = |k: usize, c: usize| els[k][c] / 65535.0;
            assert!(els.iter().all(|e| e.len() == n), "{what}");
            assert_eq!(lin(0, 0), 0.0, "{what}: sRGB 0");
            assert_eq!(lin(0, 2), 1.0, "{what}: sRGB 255");
            assert_eq!(lin(2, 0), 1.0, "{what}: sRGB 255");
            for (k, c) in [(0, 1), (1, 0), (2, 2)] {
                assert!((lin(k, c) - half).abs() <= 1.0 / 65535.0, "{what}: sRGB 128 reads back as {}", lin(k, c));
            }
            // The darkest tones keep their precision.
            assert!((lin(1, 1) - 1.0 / 255.0 / 12.92).abs() <= 0.5 / 65535.0 && els[1][1] > 0.0, "{what}: sRGB 1");
            assert!((lin(1, 2) - srgb_to_linear(13.0 / 255.0)).abs() <= 0.5 / 65535.0, "{what}: sRGB 13");
            if n == 4 {
                // Alpha: linear, unchanged (a byte a is a × 257 of 65535).
                for (k, want) in [(0, 0u8), (1, 77), (2, 255)] {
                    assert_eq!(els[k][3], want as f64 * 257.0, "{what}: alpha");
                }
            }
            let dec = decode(&g);
            check(&dec, &m, AttrSet(attrs), &opts, &what);
        }
    }
}

#[test]
fn every_primitive_uses_one_rough_double_sided_dielectric_material() {
    let d = tempfile::tempdir().unwrap();
    let (st, _) = common::build(d.path(), Shape::Sphere, 6000, AttrSet::COLOR, 500);
    let cut = CutSpec::MaxError(0.0).cut(&st).unwrap();
    let mut docs = Vec::new();
    for ext in ["glb", "gltf"] {
        let out = d.path().join(format!("m.{ext}"));
        write_parts(&out, st.header.attrs, &GltfOptions::default(), false, "m", 1000, || st.cut_meshes(&cut)).unwrap();
        docs.push(read(&out).json);
    }
    let mut b = Vec::new();
    encode_glb(&grid(3, 3, [0.0; 3], false), AttrSet(0), &GltfOptions { quantize: true, compress: true, textures: Vec::new() }, &mut b).unwrap();
    docs.push(parse_glb(&b).json);
    for (k, j) in docs.iter().enumerate() {
        let mats = j["materials"].as_array().unwrap();
        assert_eq!(mats.len(), 1);
        let m = mats[0].as_object().unwrap();
        let keys: Vec<&str> = m.keys().map(|k| k.as_str()).collect();
        assert_eq!(keys, ["pbrMetallicRoughness", "doubleSided"]);
        assert_eq!(m["doubleSided"], true);
        let pbr = m["pbrMetallicRoughness"].as_object().unwrap();
        assert_eq!(pbr.len(), 3, "{pbr:?}");
        let num = |v: &Value| v.as_f64().unwrap();
        let base: Vec<f64> = pbr["baseColorFactor"].as_array().unwrap().iter().map(num).collect();
        if k < 2 {
            // Vertex colours: white.
            assert_eq!(base, [1.0; 4]);
        } else {
            // None: octolod's grey (sRGB 200, 200, 205), linear.
            let want = [0.5776, 0.5776, 0.6105, 1.0];
            assert!(base.iter().zip(want).all(|(b, w)| (b - w).abs() < 1e-3), "{base:?}");
        }
        assert_eq!(num(&pbr["metallicFactor"]), 0.0);
        assert_eq!(num(&pbr["roughnessFactor"]), 1.0);
        let prims = j["meshes"][0]["primitives"].as_array().unwrap();
        assert!(!prims.is_empty());
        assert!(prims.iter().all(|p| p["material"] == 0), "every primitive uses material 0");
    }
    assert!(docs[0]["meshes"][0]["primitives"].as_array().unwrap().len() > 1, "a streamed cut: several primitives");
}

/// A GLB with its JSON changed by `f`.
fn glb_edited(glb: &[u8], f: impl FnOnce(&mut Value)) -> Vec<u8> {
    let mut g = parse_glb(glb);
    f(&mut g.json);
    let mut text = serde_json::to_vec(&g.json).unwrap();
    text.resize(text.len().div_ceil(4) * 4, b' ');
    let bin = g.buffers[0].clone().unwrap();
    let bin_len = bin.len().div_ceil(4) * 4;
    let mut out = b"glTF".to_vec();
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&((28 + text.len() + bin_len) as u32).to_le_bytes());
    out.extend_from_slice(&(text.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&text);
    out.extend_from_slice(&(bin_len as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&bin);
    out.resize(28 + text.len() + bin_len, 0);
    out
}

/// Every file in `dir` with its bytes (a symlink's target path).
fn snapshot(dir: &Path) -> Vec<(String, Vec<u8>)> {
    names(dir)
        .into_iter()
        .map(|n| {
            let p = dir.join(&n);
            let b = match std::fs::read_link(&p) {
                Ok(t) => t.to_string_lossy().as_bytes().to_vec(),
                Err(_) => std::fs::read(&p).unwrap(),
            };
            (n, b)
        })
        .collect()
}

#[test]
fn a_foreign_glb_or_a_gltf_whose_bin_is_not_its_own_is_never_replaced() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path().join("out");
    std::fs::create_dir(&dir).unwrap();
    let m = grid(4, 4, [0.0; 3], false);
    let opts = GltfOptions::default();
    let write = |out: &Path, force: bool| write_parts(out, AttrSet(0), &opts, force, "t", 100, || std::iter::once(Ok(m.clone())));
    // A GLB of another tool: no asset.extras at all.
    let mut ours = Vec::new();
    encode_glb(&m, AttrSet(0), &opts, &mut ours).unwrap();
    let theirs = dir.join("theirs.glb");
    std::fs::write(&theirs, glb_edited(&ours, |j| drop(j["asset"].as_object_mut().unwrap().remove("extras")))).unwrap();
    assert!(!is_octolod_gltf(&theirs));
    // .gltf files of ours whose buffer is not the .bin beside them; a
    // foreign .gltf naming the .bin beside it; a .bin that is a symlink.
    let f = dir.join("f.gltf");
    write(&f, false).unwrap();
    let mut j: Value = serde_json::from_slice(&std::fs::read(&f).unwrap()).unwrap();
    j["buffers"][0]["uri"] = "elsewhere.bin".into();
    std::fs::write(&f, serde_json::to_vec(&j).unwrap()).unwrap();
    std::fs::write(dir.join("f.bin"), b"someone else's buffer").unwrap();
    assert!(is_octolod_gltf(&f));
    let g = dir.join("g.gltf");
    write(&g, false).unwrap();
    let mut j: Value = serde_json::from_slice(&std::fs::read(&g).unwrap()).unwrap();
    j["asset"]["extras"] = serde_json::json!({"tool": "theirs"});
    std::fs::write(&g, serde_json::to_vec(&j).unwrap()).unwrap();
    let h = dir.join("h.gltf");
    write(&h, false).unwrap();
    std::fs::write(dir.join("precious.bin"), b"precious").unwrap();
    std::fs::remove_file(dir.join("h.bin")).unwrap();
    std::os::unix::fs::symlink("precious.bin", dir.join("h.bin")).unwrap();
    let before = snapshot(&dir);
    for (out, needle) in [(&theirs, "theirs.glb"), (&f, "f.bin"), (&g, "g.gltf"), (&h, "h.bin")] {
        for force in [false, true] {
            let e = write(out, force).unwrap_err().to_string();
            assert!(e.contains("refusing") && e.contains(needle), "{}: {e}", out.display());
            let e = octolod::io::check_output(out, octolod::io::OutputKind::Gltf, force).unwrap_err().to_string();
            assert!(e.contains("refusing"), "{e}");
        }
    }
    // A file output ending in '/': refused before any work.
    let slash = PathBuf::from(format!("{}/x.glb/", dir.display()));
    let e = write(&slash, true).unwrap_err().to_string();
    assert!(e.contains("ends with '/'"), "{e}");
    assert_eq!(snapshot(&dir), before, "nothing changed, nothing left behind");
    // Ours, naming its own .bin: replaced with --force.
    std::fs::remove_file(dir.join("h.bin")).unwrap();
    std::fs::remove_file(&h).unwrap();
    write(&h, false).unwrap();
    assert!(write(&h, false).unwrap_err().to_string().contains("--force"));
    write(&h, true).unwrap();
    assert_eq!(decode(&read(&h)).tris.len(), m.triangles.len());
}

#[test]
fn extract_into_an_opened_store_cannot_replace_its_files() {
    let d = tempfile::tempdir().unwrap();
    let (st, _) = common::build(d.path(), Shape::Sphere, 3000, 0, 1000);
    let spec = CutSpec::Level(1);
    let opts = GltfOptions::default();
    // An octolod .gltf whose buffer is named like the store's index.
    let elsewhere = d.path().join("elsewhere");
    std::fs::create_dir(&elsewhere).unwrap();
    extract_as(&st, spec, &elsewhere.join("nodes.gltf"), true, false, &opts).unwrap();
    let inside = st.dir.join("nodes.gltf");
    std::fs::copy(elsewhere.join("nodes.gltf"), &inside).unwrap();
    assert!(is_octolod_gltf(&inside));
    let before = snapshot(&st.dir);
    for force in [false, true] {
        let e = extract_as(&st, spec, &inside, true, force, &opts).unwrap_err().to_string();
        assert!(e.contains("an input of this command"), "{e}");
    }
    assert_eq!(snapshot(&st.dir), before);
    // Through the CLI, which opens (and so protects) the store itself.
    let store = st.dir.clone();
    drop(st);
    let o = octolod(&["extract", s(&store), "--level", "1", "-o", s(&inside), "--force"]);
    assert_eq!(o.status.code(), Some(1), "{}", err(&o));
    assert!(err(&o).contains("an input of this command"), "{}", err(&o));
    assert_eq!(snapshot(&store), before);
    Store::open(&store).unwrap();
}

// --------------------------------------------------------------- validator

/// The gltf-validator package: `OCTOLOD_GLTF_VALIDATOR_DIR` (the package,
/// or a prefix holding node_modules/gltf-validator), else web/node_modules.
/// `None` (skip) only with `OCTOLOD_SKIP_WEB_TESTS=1`.
fn validator() -> Option<PathBuf> {
    if std::env::var("OCTOLOD_SKIP_WEB_TESTS").as_deref() == Ok("1") {
        eprintln!("skipping the Khronos glTF validator: OCTOLOD_SKIP_WEB_TESTS=1");
        return None;
    }
    let dir = std::env::var_os("OCTOLOD_GLTF_VALIDATOR_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("web/node_modules/gltf-validator"));
    let dir = if dir.join("node_modules/gltf-validator").is_dir() { dir.join("node_modules/gltf-validator") } else { dir };
    assert!(
        dir.join("package.json").is_file(),
        "the Khronos glTF validator is not installed at {}: run `npm ci --prefix web` (or set OCTOLOD_SKIP_WEB_TESTS=1 to skip this test)",
        dir.display()
    );
    Some(dir)
}

/// `g` as a plain GLB: the decompressed views in buffer 0 at their
/// fallback offsets, without EXT_meshopt_compression.
fn decompressed_glb(g: &Gltf) -> Vec<u8> {
    let mut bin = fallback_bytes(g);
    let mut j = g.json.clone();
    // Views stored uncompressed in buffer 0 (an embedded image) follow.
    for (k, v) in j["bufferViews"].as_array_mut().unwrap().iter_mut().enumerate() {
        if v.get("extensions").is_none() {
            let bytes = g.view_bytes(k);
            bin.resize(bin.len().div_ceil(4) * 4, 0);
            v["byteOffset"] = bin.len().into();
            bin.extend_from_slice(&bytes);
        }
    }
    bin.resize(bin.len().div_ceil(4) * 4, 0);
    for key in ["extensionsUsed", "extensionsRequired"] {
        let v: Vec<Value> = j[key].as_array().unwrap().iter().filter(|x| *x != "EXT_meshopt_compression").cloned().collect();
        j.as_object_mut().unwrap().remove(key);
        if !v.is_empty() {
            j[key] = Value::Array(v);
        }
    }
    for v in j["bufferViews"].as_array_mut().unwrap() {
        v["buffer"] = 0.into();
        v.as_object_mut().unwrap().remove("extensions");
    }
    j["buffers"] = serde_json::json!([{"byteLength": bin.len()}]);
    let mut text = serde_json::to_vec(&j).unwrap();
    text.resize(text.len().div_ceil(4) * 4, b' ');
    let mut out = b"glTF".to_vec();
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&((28 + text.len() + bin.len()) as u32).to_le_bytes());
    out.extend_from_slice(&(text.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&text);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&bin);
    out
}

const VALIDATE_JS: &str = r#"
const path = require('path'), fs = require('fs');
const validator = require(process.argv[2]);
(async () => {
  for (const file of process.argv.slice(3)) {
    const r = await validator.validateBytes(new Uint8Array(fs.readFileSync(file)), {
      uri: file, maxIssues: 100,
      externalResourceFunction: (uri) => new Promise((ok, fail) => {
        try { ok(new Uint8Array(fs.readFileSync(path.resolve(path.dirname(file), decodeURIComponent(uri))))); }
        catch (e) { fail(String(e)); }
      }),
    });
    console.log(JSON.stringify({ file, errors: r.issues.numErrors, warnings: r.issues.numWarnings, infos: r.issues.numInfos,
      messages: r.issues.messages.map(m => `${['error', 'warning', 'info', 'hint'][m.severity]} ${m.code} ${m.pointer || ''}: ${m.message}`) }));
  }
})().catch(e => { console.error(String(e)); process.exit(2); });
"#;

#[test]
fn the_khronos_validator_finds_no_error_in_any_variant() {
    let Some(dir) = validator() else { return };
    let d = tempfile::tempdir().unwrap();
    let mut files = Vec::new();
    let (s, _) = common::build(d.path(), Shape::Sphere, 6000, ALL, 800);
    let (p, _) = common::build(d.path(), Shape::Plane, 3000, AttrSet::COLOR, 800);
    let (f, _) = common::build(d.path(), Shape::Offset, 3000, AttrSet::POS_F64 | AttrSet::NORMAL, 800);
    let cut = CutSpec::MaxError(0.0).cut(&s).unwrap();
    for opts in VARIANTS {
        for ext in ["glb", "gltf"] {
            for (store, name) in [(&s, "sphere"), (&p, "plane"), (&f, "far")] {
                let out = d.path().join(format!("{name}-{}.{ext}", tag(&opts)));
                extract_as(store, CutSpec::Level(1), &out, true, false, &opts).unwrap();
                files.push(out);
            }
            let out = d.path().join(format!("runs-{}.{ext}", tag(&opts)));
            write_parts(&out, s.header.attrs, &opts, false, "runs", 1000, || s.cut_meshes(&cut)).unwrap();
            files.push(out);
        }
        let out = d.path().join(format!("grid-{}.glb", tag(&opts)));
        let mut b = Vec::new();
        encode_glb(&grid(300, 240, [1e6, 2e6, -3e6], true), AttrSet(ALL), &opts, &mut b).unwrap();
        std::fs::write(&out, b).unwrap();
        files.push(out);
    }
    // Textured: the image embedded (extracts) or named by URI (tiles); one
    // texture, and three chosen per face (a primitive per material).
    let t = textured_store(d.path());
    let mt = {
        let dir = d.path().join("mt");
        std::fs::create_dir_all(&dir).unwrap();
        let ply = dir.join("tex3.ply");
        common::cli::gen_with("scan", 8000, &ply, &["--atlas", "4", "--texture", "64", "--textures", "3"]);
        let params = octolod::manifest::BuildParams { mem: 16 << 20, leaf_tris: 1024, ..Default::default() };
        Store::open(&common::build_store_at(&dir, &ply, &common::build_options(params))).unwrap()
    };
    assert!(mt.header.attrs.material());
    for (store, name) in [(&t, "textured"), (&mt, "materials")] {
        for opts in [&VARIANTS[0], &VARIANTS[3]] {
            for ext in ["glb", "gltf"] {
                let out = d.path().join(format!("{name}-{}.{ext}", tag(opts)));
                extract_as(store, CutSpec::Level(1), &out, true, false, opts).unwrap();
                files.push(out);
            }
        }
        let tiles = d.path().join(format!("{name}-tiles"));
        octolod::tiles::export(store, &tiles, &octolod::tiles::TilesOptions { tile_tris: 2000, ..Default::default() }).unwrap();
        let mut glbs: Vec<PathBuf> =
            std::fs::read_dir(tiles.join("t")).unwrap().map(|e| e.unwrap().path()).filter(|p| p.extension().unwrap() == "glb").collect();
        glbs.sort();
        files.extend(glbs.into_iter().step_by(3));
    }
    // The validator cannot read EXT_meshopt_compression: each compressed
    // file is also validated decompressed (its fallback filled in).
    for f in files.clone() {
        let g = read(&f);
        if !g.extensions("extensionsUsed").contains(&"EXT_meshopt_compression".to_string()) {
            continue;
        }
        let out = f.with_file_name(format!("{}-decompressed.glb", f.file_stem().unwrap().to_string_lossy()));
        std::fs::write(&out, decompressed_glb(&g)).unwrap();
        files.push(out);
    }
    let script = d.path().join("validate.cjs");
    std::fs::write(&script, VALIDATE_JS).unwrap();
    let o = std::process::Command::new("node")
        .arg(&script)
        .arg(&dir)
        .args(&files)
        .output()
        .unwrap_or_else(|e| panic!("cannot run node ({e}): install Node.js 18+, then `npm ci --prefix web`"));
    assert!(o.status.success(), "validator: {}", String::from_utf8_lossy(&o.stderr));
    let text = String::from_utf8(o.stdout).unwrap();
    let reports: Vec<Value> = text.lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert_eq!(reports.len(), files.len());
    let mut failed = Vec::new();
    for r in &reports {
        let name = Path::new(r["file"].as_str().unwrap()).file_name().unwrap().to_string_lossy().into_owned();
        eprintln!("{name}: {} errors, {} warnings, {} infos", r["errors"], r["warnings"], r["infos"]);
        for m in r["messages"].as_array().unwrap() {
            eprintln!("    {}", m.as_str().unwrap());
        }
        if r["errors"].as_u64() != Some(0) {
            failed.push(name);
        }
    }
    assert!(failed.is_empty(), "validator errors in {failed:?}");
}

/// A generated textured scan (atlas and baked texture) built into a store.
fn textured_store(dir: &Path) -> Store {
    let ply = dir.join("tex.ply");
    common::cli::gen_with("scan", 8000, &ply, &["--atlas", "4", "--texture", "128"]);
    let params = octolod::manifest::BuildParams { mem: 16 << 20, leaf_tris: 1024, ..Default::default() };
    Store::open(&common::build_store_at(dir, &ply, &common::build_options(params))).unwrap()
}

/// Issue 32, item 2: a glTF extract of a textured store embeds the store's
/// texture (no file beside it) as the material's base colour, sampled
/// with mipmaps and repeat; TEXCOORD_0 is glTF's (u, 1 − v) and octolod's
/// glTF reader turns it back. A tileset gets each level's copy of the
/// texture in `t/`, smaller for coarser levels, named by URI from every
/// GLB of the level.
#[test]
fn textured_stores_carry_their_texture_into_gltf_and_tiles() {
    let d = tempfile::tempdir().unwrap();
    let s = textured_store(d.path());
    let texture = std::fs::read(s.dir.join("texture-0.png")).unwrap();
    for (ext, opts) in [("glb", &VARIANTS[0]), ("gltf", &VARIANTS[0]), ("glb", &VARIANTS[3])] {
        let out = d.path().join(format!("x/tex-{}.{ext}", tag(opts)));
        std::fs::create_dir_all(out.parent().unwrap()).unwrap();
        extract_as(&s, CutSpec::Level(1), &out, true, false, opts).unwrap();
        let g = read(&out);
        let img = &g.json["images"][0];
        assert_eq!(img["mimeType"], "image/png", "{}", out.display());
        assert!(img.get("uri").is_none());
        let view = &g.json["bufferViews"][img["bufferView"].as_u64().unwrap() as usize];
        let (at, len) = (view["byteOffset"].as_u64().unwrap() as usize, view["byteLength"].as_u64().unwrap() as usize);
        assert_eq!(view["buffer"], 0);
        assert_eq!(&g.buffers[0].as_ref().unwrap()[at..at + len], &texture[..], "the store's image, byte for byte");
        let m = &g.json["materials"][0]["pbrMetallicRoughness"];
        assert_eq!(m["baseColorTexture"]["index"], 0);
        assert_eq!(m["baseColorFactor"], serde_json::json!([1.0, 1.0, 1.0, 1.0]));
        assert_eq!(g.json["samplers"][0]["minFilter"], 9987);
        assert_eq!(g.json["textures"][0]["source"], 0);
        // The reader gives back the store's uvs (v turned twice: within
        // an f32 step of 1) where they are stored as floats.
        if !opts.quantize {
            let (_, sink, _) = octolod::input::read_all(&out, 64 << 20).unwrap();
            let mut got: Vec<[f32; 2]> = sink.vertices.iter().map(|v| v.uv).collect();
            let cut = s.cut_meshes(&CutSpec::Level(1).cut(&s).unwrap()).collect::<octolod::Result<Vec<_>>>().unwrap();
            let mut want: Vec<[f32; 2]> = cut.iter().flat_map(|m| m.vertices.iter().map(|v| v.uv)).collect();
            for v in [&mut got, &mut want] {
                v.sort_unstable_by(|a, b| a[0].total_cmp(&b[0]).then(a[1].total_cmp(&b[1])));
                v.dedup_by(|a, b| a[0] == b[0] && (a[1] - b[1]).abs() <= 1.2e-7);
            }
            assert_eq!(got.len(), want.len(), "{}", out.display());
            let off = got.iter().zip(&want).filter(|(g, w)| g[0] != w[0] || (g[1] - w[1]).abs() > 1.2e-7).count();
            assert_eq!(off, 0, "{}: uvs that did not come back", out.display());
        }
    }
    assert_eq!(names(&d.path().join("x")).len(), 4, "three glTFs and one .bin, nothing else");
    // Tiles: per-level copies.
    let t = d.path().join("tiles");
    octolod::tiles::export(&s, &t, &octolod::tiles::TilesOptions { tile_tris: 2000, ..Default::default() }).unwrap();
    let names = names(&t.join("t"));
    let images: Vec<&String> = names.iter().filter(|n| n.ends_with(".png")).collect();
    assert_eq!(images.iter().map(|s| s.as_str()).collect::<Vec<_>>(), vec!["texture-0-128.png", "texture-0-64.png"], "{names:?}");
    assert_eq!(std::fs::read(t.join("t/texture-0-128.png")).unwrap(), texture, "the full-size copy is the store's file");
    let marker = std::fs::read_to_string(t.join(octolod::io::TILES_MARKER)).unwrap();
    assert!(marker.contains("t/texture-0-64.png"), "the marker lists the copies: {marker}");
    for n in names.iter().filter(|n| n.ends_with(".glb")) {
        let g = parse_glb(&std::fs::read(t.join("t").join(n)).unwrap());
        let level: u8 = n.split('-').next().unwrap().parse().unwrap();
        let uri = g.json["images"][0]["uri"].as_str().unwrap().to_string();
        assert_eq!(uri, format!("texture-0-{}.png", octolod::tiles::level_texture_side(128, level)), "{n}");
        assert!(t.join("t").join(&uri).is_file());
    }
}

/// Issue 32, item 2: a glTF's base colour image becomes the store's
/// texture, whether in its buffer (octolod's own extract, read back) or
/// a file it names by URI; its uvs come back (v turned twice).
#[test]
fn a_gltf_input_keeps_its_base_colour_image() {
    let d = tempfile::tempdir().unwrap();
    let s = textured_store(d.path());
    let texture = std::fs::read(s.dir.join("texture-0.png")).unwrap();
    let glb = d.path().join("x.glb");
    extract_as(&s, CutSpec::Level(0), &glb, true, false, &VARIANTS[0]).unwrap();
    // A .gltf naming the image by URI, in a subfolder, with a space.
    let gltf = d.path().join("y.gltf");
    extract_as(&s, CutSpec::Level(0), &gltf, true, false, &VARIANTS[0]).unwrap();
    let mut j: Value = serde_json::from_slice(&std::fs::read(&gltf).unwrap()).unwrap();
    j["images"][0] = serde_json::json!({"uri": "img/the%20skin.png"});
    std::fs::write(&gltf, serde_json::to_vec(&j).unwrap()).unwrap();
    std::fs::create_dir(d.path().join("img")).unwrap();
    std::fs::write(d.path().join("img/the skin.png"), &texture).unwrap();
    // `info-input` lists them.
    for (input, line) in [(&glb, "base colour image: images[0] texture-0 (image/png, in a buffer)"), (&gltf, "base colour image: img/the skin.png (found)")] {
        let o = octolod(&["info-input", input.to_str().unwrap()]);
        assert!(String::from_utf8_lossy(&o.stdout).contains(line), "{}", String::from_utf8_lossy(&o.stdout));
    }
    for (input, name) in [(&glb, "texture-0"), (&gltf, "img/the skin.png")] {
        let out = d.path().join(format!("{}.octolod", input.file_stem().unwrap().to_string_lossy()));
        octolod::pipeline::build_store(input, &out, &octolod::pipeline::BuildOptions::default()).unwrap();
        let m = octolod::manifest::Manifest::read(&out).unwrap();
        assert_eq!(m.textures.len(), 1, "{}", input.display());
        assert_eq!((m.textures[0].name.as_str(), m.textures[0].file.as_deref()), (name, Some("texture-0.png")));
        assert_eq!(std::fs::read(out.join("texture-0.png")).unwrap(), texture);
        let t = Store::open(&out).unwrap();
        assert!(t.header.attrs.uv());
        let uvs = |st: &Store| {
            let mut v: Vec<[f32; 2]> = st.level_nodes(0).into_iter().flat_map(|i| st.read_node(i).unwrap().mesh.vertices).map(|v| v.uv).collect();
            v.sort_unstable_by(|a, b| a[0].total_cmp(&b[0]).then(a[1].total_cmp(&b[1])));
            v.dedup_by(|a, b| a[0] == b[0] && (a[1] - b[1]).abs() <= 1.2e-7);
            v
        };
        let (a, b) = (uvs(&t), uvs(&s));
        assert_eq!(a.len(), b.len());
        assert!(a.iter().zip(&b).all(|(x, y)| x[0] == y[0] && (x[1] - y[1]).abs() <= 1.2e-7), "uvs changed through glTF");
    }
}

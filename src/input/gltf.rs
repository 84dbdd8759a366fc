//! glTF 2.0 input (`.glb`, or `.gltf` JSON with external buffers): see [`super`].
//!
//! Takes: a path. Gives: [`read_info`], a first look (the triangle
//! primitives reachable from the default scene, their vertex and triangle
//! counts, the attributes every one of them has), and [`read_body`], which
//! feeds a [`BodySink`] every primitive instance's vertices (a first pass,
//! positions and normals in world space: node transforms composed down the
//! hierarchy in f64), then its triangles offset by the vertices before it
//! (a second pass).
//!
//! Supported: the GLB container (JSON and BIN chunks) and `.gltf` with
//! buffers in files beside it (URIs relative to the file, %-escapes
//! decoded); modes 4 (triangles), 5 (strip) and 6 (fan), points and lines
//! skipped; indices `u8`/`u16`/`u32` or none; POSITION as `f32` or, under
//! KHR_mesh_quantization, (normalized) 8/16-bit integers; NORMAL, COLOR_0
//! (linear, stored as sRGB bytes) and TEXCOORD_0 (v turned to octolod's
//! v-up convention, MeshLab's) when every primitive has them; the base
//! colour images the primitives' materials use ([`GltfInfo::images`], by
//! URI or in a buffer: [`image_bytes`]), which a build keeps, each
//! primitive's vertices getting its image's slot in that list as their
//! material id ([`AttrSet::MATERIAL`], when the primitives use two
//! images, or a textured and an untextured material: those without a
//! base colour texture get [`Vertex::NO_TEXTURE`]); byte strides honoured; node `matrix` or T·R·S; a negative
//! determinant flips the winding; EXT_meshopt_compression bufferViews
//! (modes ATTRIBUTES, TRIANGLES, INDICES; filters OCTAHEDRAL, QUATERNION,
//! EXPONENTIAL, COLOR) decoded with the `meshopt` crate, fallback buffers
//! without data allowed. Refused with an error naming it: `data:` URIs,
//! sparse accessors, accessors without a bufferView, and any other
//! extension in `extensionsRequired` that changes geometry (Draco, ...).
//!
//! Accessors are read by positioned reads of just their byte range (a
//! compressed bufferView: its compressed range, decoded whole), so files
//! above 4 GiB work and memory stays per primitive. Bad input is an
//! error naming the file and the JSON path (and byte range) at fault.

use crate::error::{Error, Location, Result};
use crate::mesh::{AttrSet, Vertex};
use crate::ply::read::{BodySink, BodyStats};
use crate::progress::Progress;
use serde::Deserialize;
use std::collections::BTreeMap;
use std::fs::File;
use std::io::Read;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};

/// What [`read_info`] learned about a glTF file.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct GltfInfo {
    /// Vertices of every triangle primitive instance.
    pub vertices: u64,
    /// Triangles they make (degenerate ones included).
    pub triangles: u64,
    /// Triangle primitive instances (a mesh used by two nodes counts twice).
    pub primitives: u64,
    /// Attributes every primitive has.
    pub attrs: AttrSet,
    /// File size (the `.gltf`/`.glb`, not its buffers).
    pub bytes: u64,
    /// The base colour images of the materials the primitives use, in
    /// order of first use, each once.
    pub images: Vec<GltfImage>,
}

/// Where a base colour image is.
#[derive(Clone, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum GltfImage {
    /// A file, its URI relative to the glTF (%-escapes decoded).
    File(String),
    /// In a buffer: `images[index]`, with its MIME type and name.
    Embedded { index: usize, mime: String, name: Option<String> },
}

const GLB_MAGIC: &[u8; 4] = b"glTF";
const CHUNK_JSON: u32 = 0x4E4F_534A;
const CHUNK_BIN: u32 = 0x004E_4942;
/// Largest JSON accepted (a guard against reading a huge file whole).
const MAX_JSON: u64 = 1 << 30;
const BATCH: usize = 1 << 15;
/// Deepest node hierarchy followed (also stops cycles).
const MAX_DEPTH: usize = 1024;

/// Extensions in `extensionsRequired` that are read, or that do not change
/// the geometry (materials, textures, lights).
fn extension_ok(name: &str) -> bool {
    name == "KHR_mesh_quantization"
        || name == "EXT_meshopt_compression"
        || name.starts_with("KHR_materials_")
        || matches!(name, "KHR_texture_basisu" | "EXT_texture_webp" | "EXT_texture_avif" | "KHR_lights_punctual")
}

#[derive(Deserialize, Default)]
#[serde(default, rename_all = "camelCase")]
struct Doc {
    asset: Option<serde_json::Value>,
    scene: Option<usize>,
    scenes: Vec<Scene>,
    nodes: Vec<Node>,
    meshes: Vec<Mesh>,
    accessors: Vec<Accessor>,
    buffer_views: Vec<BufferView>,
    buffers: Vec<Buffer>,
    materials: Vec<MaterialDef>,
    textures: Vec<TextureDef>,
    images: Vec<ImageDef>,
    extensions_used: Vec<String>,
    extensions_required: Vec<String>,
}

#[derive(Deserialize, Default)]
#[serde(default)]
struct Scene {
    nodes: Vec<usize>,
}

#[derive(Deserialize, Default)]
#[serde(default)]
struct Node {
    children: Vec<usize>,
    mesh: Option<usize>,
    matrix: Option<[f64; 16]>,
    translation: Option<[f64; 3]>,
    rotation: Option<[f64; 4]>,
    scale: Option<[f64; 3]>,
}

#[derive(Deserialize, Default)]
#[serde(default)]
struct Mesh {
    primitives: Vec<Primitive>,
}

#[derive(Deserialize, Default)]
#[serde(default)]
struct Primitive {
    attributes: BTreeMap<String, usize>,
    indices: Option<usize>,
    mode: Option<u32>,
    material: Option<usize>,
}

#[derive(Deserialize, Default)]
#[serde(default, rename_all = "camelCase")]
struct MaterialDef {
    pbr_metallic_roughness: Option<PbrDef>,
}

#[derive(Deserialize, Default)]
#[serde(default, rename_all = "camelCase")]
struct PbrDef {
    base_color_texture: Option<TextureRefDef>,
}

#[derive(Deserialize, Default)]
#[serde(default)]
struct TextureRefDef {
    index: usize,
}

#[derive(Deserialize, Default)]
#[serde(default)]
struct TextureDef {
    source: Option<usize>,
}

#[derive(Deserialize, Default)]
#[serde(default, rename_all = "camelCase")]
struct ImageDef {
    uri: Option<String>,
    buffer_view: Option<usize>,
    mime_type: Option<String>,
    name: Option<String>,
}

#[derive(Deserialize, Default)]
#[serde(default, rename_all = "camelCase")]
struct Accessor {
    buffer_view: Option<usize>,
    byte_offset: u64,
    component_type: u32,
    normalized: bool,
    count: u64,
    #[serde(rename = "type")]
    kind: String,
    sparse: Option<serde_json::Value>,
}

#[derive(Deserialize, Default)]
#[serde(default, rename_all = "camelCase")]
struct BufferView {
    buffer: usize,
    byte_offset: u64,
    byte_length: u64,
    byte_stride: Option<u64>,
    extensions: BTreeMap<String, serde_json::Value>,
}

#[derive(Deserialize, Default)]
#[serde(default, rename_all = "camelCase")]
struct Buffer {
    uri: Option<String>,
    byte_length: u64,
    extensions: BTreeMap<String, serde_json::Value>,
}

/// A bufferView's `EXT_meshopt_compression` object.
#[derive(Deserialize, Default)]
#[serde(default, rename_all = "camelCase")]
struct Meshopt {
    buffer: usize,
    byte_offset: u64,
    byte_length: u64,
    byte_stride: u64,
    count: u64,
    mode: String,
    filter: Option<String>,
}

/// One triangle primitive instance: where it is, its world matrix (column-major).
struct Prim {
    what: String,
    m: [f64; 16],
    mode: u32,
    pos: usize,
    normal: Option<usize>,
    color: Option<usize>,
    uv: Option<usize>,
    indices: Option<usize>,
    material: Option<usize>,
    /// Its material's base colour image's slot in [`GltfInfo::images`]
    /// (None: no textured material).
    slot: Option<u16>,
    /// Vertices (the POSITION count) and index count (or the vertex count).
    verts: u64,
    corners: u64,
}

/// A buffer: the file holding it, where it starts, its length.
struct Buf {
    file: File,
    path: PathBuf,
    base: u64,
    len: u64,
}

/// The parsed document with its buffers opened.
struct Gltf {
    path: PathBuf,
    doc: Doc,
    /// `None`: a meshopt fallback buffer with no data.
    bufs: Vec<Option<Buf>>,
    prims: Vec<Prim>,
    attrs: AttrSet,
    bytes: u64,
    quantized: bool,
}

fn err(path: &Path, msg: impl Into<String>) -> Error {
    Error::input(Location { file: path.to_path_buf(), ..Default::default() }, msg)
}

fn err_at(path: &Path, offset: u64, msg: impl Into<String>) -> Error {
    Error::input(Location { file: path.to_path_buf(), offset: Some(offset), ..Default::default() }, msg)
}

/// Whether `head` (a file's first bytes) looks like glTF: the GLB magic,
/// or JSON (`{` first) that names an `"asset"`.
pub fn looks_like_gltf(head: &[u8]) -> bool {
    if head.starts_with(GLB_MAGIC) {
        return true;
    }
    let start = head.iter().position(|b| !b.is_ascii_whitespace()).unwrap_or(head.len());
    let s = &head[start..];
    let s = s.strip_prefix(b"\xEF\xBB\xBF".as_slice()).unwrap_or(s);
    s.first() == Some(&b'{') && s.windows(7).any(|w| w == b"\"asset\"")
}

/// Reads what a glTF file holds: its triangle primitives' counts and
/// common attributes (the JSON only; buffers are opened and their sizes
/// checked, not read).
pub fn read_info(path: &Path) -> Result<GltfInfo> {
    let g = Gltf::open(path)?;
    let vertices = g.prims.iter().map(|p| p.verts).sum();
    let triangles = g.prims.iter().map(|p| tri_count(p.mode, p.corners)).sum();
    Ok(GltfInfo { vertices, triangles, primitives: g.prims.len() as u64, attrs: g.attrs, bytes: g.bytes, images: g.base_color_images() })
}

/// The bytes of `images[index]` of the glTF `path` when stored in a buffer
/// (a GLB's BIN chunk or a `.bin`), as [`GltfInfo::images`] names it.
pub fn image_bytes(path: &Path, index: usize) -> Result<Vec<u8>> {
    let g = Gltf::open(path)?;
    let what = format!("images[{index}]");
    let bvi = g.doc.images.get(index).and_then(|i| i.buffer_view).ok_or_else(|| err(path, format!("{what}: no bufferView")))?;
    let bv = g.doc.buffer_views.get(bvi).ok_or_else(|| err(path, format!("{what}.bufferView: {bvi} of {}", g.doc.buffer_views.len())))?;
    let Some(Some(buf)) = g.bufs.get(bv.buffer) else {
        return Err(err(path, format!("{what}: bufferViews[{bvi}].buffer {} has no data", bv.buffer)));
    };
    let end = bv.byte_offset.saturating_add(bv.byte_length);
    if end > buf.len || bv.byte_length > MAX_JSON {
        return Err(err(path, format!("{what}: bufferViews[{bvi}] reads bytes {}..{end} of a {}-byte buffer", bv.byte_offset, buf.len)));
    }
    let mut out = vec![0u8; bv.byte_length as usize];
    read_exact_at(&buf.file, &buf.path, &mut out, buf.base + bv.byte_offset)?;
    Ok(out)
}

/// Reads the primitives of the glTF `path` that [`read_info`] described,
/// feeding `sink` every vertex, then every triangle (see the module
/// documentation).
pub fn read_body(path: &Path, info: &GltfInfo, sink: &mut dyn BodySink, progress: &Progress) -> Result<BodyStats> {
    let g = Gltf::open(path)?;
    let now = GltfInfo {
        vertices: g.prims.iter().map(|p| p.verts).sum(),
        triangles: g.prims.iter().map(|p| tri_count(p.mode, p.corners)).sum(),
        primitives: g.prims.len() as u64,
        attrs: g.attrs,
        bytes: g.bytes,
        images: g.base_color_images(),
    };
    if &now != info {
        return Err(err(path, "the file changed since it was first read"));
    }
    let mut stats = BodyStats { bytes: g.bytes, ..Default::default() };
    // First pass: vertices, a batch at a time.
    let mut first = 0u64;
    for p in &g.prims {
        g.vertices(p, first, sink, progress)?;
        first += p.verts;
    }
    stats.vertices = first;
    // Second pass: triangles; a triangle list's indices a batch at a time,
    // a strip's or fan's whole (their triangles reach back).
    let mut offset = 0u64;
    let mut tris: Vec<[u64; 3]> = Vec::with_capacity(BATCH);
    let mut idx: Vec<u64> = Vec::new();
    for p in &g.prims {
        let what = format!("{}.indices", p.what);
        let mut reader = p.indices.map(|a| g.reader(a, &what, &[1], &[5121, 5123, 5125])).transpose()?;
        let corners = reader.as_ref().map_or(p.verts, |r| r.count);
        let flip = det3(&p.m) < 0.0;
        let count = tri_count(p.mode, corners);
        // Corners read per step: a multiple of 3 for lists, all for strips and fans.
        let step = if p.mode == 4 { 3 * BATCH as u64 } else { corners.max(1) };
        let mut base = 0u64;
        while base < corners {
            let k = step.min(corners - base);
            // (`flip`: a mirroring transform turns the winding back.)
            let mut put = |t: [u64; 3]| -> Result<()> {
                stats.faces += 1;
                if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] {
                    stats.degenerate += 1;
                    return Ok(());
                }
                let t = if flip { [t[0], t[2], t[1]] } else { t };
                tris.push([t[0] + offset, t[1] + offset, t[2] + offset]);
                if tris.len() == BATCH {
                    sink.triangles(&tris)?;
                    stats.triangles += tris.len() as u64;
                    tris.clear();
                    crate::io::signal::check()?;
                }
                Ok(())
            };
            let bad = |i: u64, x: u64| err(&g.path, format!("{what}: index {i} is {x}, out of range (POSITION has {} vertices)", p.verts));
            match (p.mode, reader.as_mut()) {
                (4, Some(r)) => {
                    // A triangle list: straight from the read bytes.
                    let (t, stride) = (r.t, r.stride);
                    let (raw, n) = r.fetch(k as usize)?;
                    // One loop per index width, so the width is not chosen per index.
                    fn list<const S: usize>(
                        raw: &[u8],
                        stride: usize,
                        n: usize,
                        verts: u64,
                        put: &mut impl FnMut([u64; 3]) -> Result<()>,
                    ) -> Result<Option<usize>> {
                        let at = |i: usize| -> u64 {
                            let mut b = [0u8; 8];
                            b[..S].copy_from_slice(&raw[i * stride..i * stride + S]);
                            u64::from_le_bytes(b)
                        };
                        for j in 0..n / 3 {
                            let tri = [at(3 * j), at(3 * j + 1), at(3 * j + 2)];
                            if tri[0].max(tri[1]).max(tri[2]) >= verts {
                                return Ok(Some(3 * j + tri.iter().position(|&x| x >= verts).unwrap()));
                            }
                            put(tri)?;
                        }
                        Ok((n / 3 * 3..n).find(|&c| at(c) >= verts))
                    }
                    let out = match t {
                        5121 => list::<1>(raw, stride, n, p.verts, &mut put)?,
                        5123 => list::<2>(raw, stride, n, p.verts, &mut put)?,
                        _ => list::<4>(raw, stride, n, p.verts, &mut put)?,
                    };
                    if let Some(c) = out {
                        let e = &raw[c * stride..];
                        let x = match t {
                            5121 => e[0] as u64,
                            5123 => u16::from_le_bytes([e[0], e[1]]) as u64,
                            _ => u32::from_le_bytes([e[0], e[1], e[2], e[3]]) as u64,
                        };
                        return Err(bad(base + c as u64, x));
                    }
                }
                (_, r) => {
                    idx.clear();
                    match r {
                        Some(r) => {
                            if r.next_indices(k as usize, &mut idx)? >= p.verts {
                                let i = idx.iter().position(|&x| x >= p.verts).expect("an index past the vertices");
                                return Err(bad(base + i as u64, idx[i]));
                            }
                        }
                        None => idx.extend(base..base + k),
                    }
                    if p.mode == 4 {
                        for t in idx.chunks_exact(3) {
                            put([t[0], t[1], t[2]])?;
                        }
                    } else {
                        for i in 0..count as usize {
                            put(match p.mode {
                                5 if i % 2 == 0 => [idx[i], idx[i + 1], idx[i + 2]],
                                5 => [idx[i + 1], idx[i], idx[i + 2]],
                                _ => [idx[i + 1], idx[i + 2], idx[0]],
                            })?;
                        }
                    }
                }
            }
            base += k;
        }
        offset += p.verts;
    }
    if !tris.is_empty() {
        sink.triangles(&tris)?;
        stats.triangles += tris.len() as u64;
    }
    Ok(stats)
}

fn tri_count(mode: u32, corners: u64) -> u64 {
    match mode {
        4 => corners / 3,
        _ => corners.saturating_sub(2),
    }
}

fn mat_mul(a: &[f64; 16], b: &[f64; 16]) -> [f64; 16] {
    let mut r = [0.0; 16];
    for c in 0..4 {
        for row in 0..4 {
            r[c * 4 + row] = (0..4).map(|k| a[k * 4 + row] * b[c * 4 + k]).sum();
        }
    }
    r
}

const IDENTITY: [f64; 16] = [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0];

/// A node's local matrix (column-major): `matrix`, else T·R·S.
fn local(n: &Node) -> [f64; 16] {
    if let Some(m) = n.matrix {
        return m;
    }
    let [tx, ty, tz] = n.translation.unwrap_or([0.0; 3]);
    let [x, y, z, w] = n.rotation.unwrap_or([0.0, 0.0, 0.0, 1.0]);
    let [sx, sy, sz] = n.scale.unwrap_or([1.0; 3]);
    let r = [
        1.0 - 2.0 * (y * y + z * z),
        2.0 * (x * y + z * w),
        2.0 * (x * z - y * w),
        2.0 * (x * y - z * w),
        1.0 - 2.0 * (x * x + z * z),
        2.0 * (y * z + x * w),
        2.0 * (x * z + y * w),
        2.0 * (y * z - x * w),
        1.0 - 2.0 * (x * x + y * y),
    ];
    [r[0] * sx, r[1] * sx, r[2] * sx, 0.0, r[3] * sy, r[4] * sy, r[5] * sy, 0.0, r[6] * sz, r[7] * sz, r[8] * sz, 0.0, tx, ty, tz, 1.0]
}

/// Determinant of the upper-left 3×3 of a column-major 4×4.
fn det3(m: &[f64; 16]) -> f64 {
    m[0] * (m[5] * m[10] - m[9] * m[6]) - m[4] * (m[1] * m[10] - m[9] * m[2]) + m[8] * (m[1] * m[6] - m[5] * m[2])
}

/// The inverse-transpose of the upper-left 3×3 (row-major 3×3), for normals.
fn normal_matrix(m: &[f64; 16]) -> [[f64; 3]; 3] {
    // Cofactor matrix = det * inverse-transpose; the scale does not matter
    // as normals are renormalised (a negative determinant is kept by the sign).
    let a = |r: usize, c: usize| m[c * 4 + r];
    let mut co = [[0.0; 3]; 3];
    for (r, row) in co.iter_mut().enumerate() {
        for (c, v) in row.iter_mut().enumerate() {
            let (r1, r2) = ((r + 1) % 3, (r + 2) % 3);
            let (c1, c2) = ((c + 1) % 3, (c + 2) % 3);
            *v = a(r1, c1) * a(r2, c2) - a(r1, c2) * a(r2, c1);
        }
    }
    let s = if det3(m) < 0.0 { -1.0 } else { 1.0 };
    co.map(|row| row.map(|v| v * s))
}

fn percent_decode(s: &str) -> String {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%' && i + 2 < b.len() && s.is_char_boundary(i + 3) {
            if let Ok(v) = u8::from_str_radix(&s[i + 1..i + 3], 16) {
                out.push(v);
                i += 3;
                continue;
            }
        }
        out.push(b[i]);
        i += 1;
    }
    String::from_utf8_lossy(&out).into_owned()
}

fn components(kind: &str) -> Option<usize> {
    Some(match kind {
        "SCALAR" => 1,
        "VEC2" => 2,
        "VEC3" => 3,
        "VEC4" => 4,
        "MAT2" => 4,
        "MAT3" => 9,
        "MAT4" => 16,
        _ => return None,
    })
}

fn component_size(t: u32) -> Option<u64> {
    Some(match t {
        5120 | 5121 => 1,
        5122 | 5123 => 2,
        5125 | 5126 => 4,
        _ => return None,
    })
}

fn type_name(t: u32) -> String {
    match t {
        5120 => "i8".into(),
        5121 => "u8".into(),
        5122 => "i16".into(),
        5123 => "u16".into(),
        5125 => "u32".into(),
        5126 => "f32".into(),
        t => format!("componentType {t}"),
    }
}

impl Gltf {
    fn open(path: &Path) -> Result<Gltf> {
        let (mut file, len) = crate::io::open_regular(path, "open")?;
        let mut head = [0u8; 12];
        let n = file.read_at(&mut head, 0).map_err(|e| Error::io(path, "read", e))?;
        let (json, glb_bin) = if n >= 4 && &head[..4] == GLB_MAGIC {
            if n < 12 || len < 20 {
                return Err(err_at(path, 0, format!("GLB: {len} bytes is too short for the 12-byte header and a chunk header")));
            }
            let version = u32::from_le_bytes(head[4..8].try_into().unwrap());
            if version != 2 {
                return Err(err_at(path, 4, format!("GLB version {version}: only glTF 2.0 is read")));
            }
            let total = u32::from_le_bytes(head[8..12].try_into().unwrap()) as u64;
            if total != len {
                return Err(err_at(path, 8, format!("GLB header says {total} bytes, the file has {len}")));
            }
            let (jlen, jtype) = chunk_head(&file, path, 12)?;
            if jtype != CHUNK_JSON {
                return Err(err_at(path, 16, format!("GLB: the first chunk is of type {jtype:#010x}, not JSON")));
            }
            if 20 + jlen > len {
                return Err(err_at(path, 12, format!("GLB: the JSON chunk of {jlen} bytes runs past the end of the {len}-byte file")));
            }
            if jlen > MAX_JSON {
                return Err(err_at(path, 12, format!("GLB: a JSON chunk of {jlen} bytes is too large")));
            }
            let mut json = vec![0u8; jlen as usize];
            read_exact_at(&file, path, &mut json, 20)?;
            let next = 20 + jlen.div_ceil(4) * 4;
            let mut bin = None;
            if next + 8 <= len {
                let (blen, btype) = chunk_head(&file, path, next)?;
                if btype == CHUNK_BIN {
                    if next + 8 + blen > len {
                        return Err(err_at(path, next, format!("GLB: the BIN chunk of {blen} bytes runs past the end of the {len}-byte file")));
                    }
                    bin = Some((next + 8, blen));
                }
            }
            (json, bin)
        } else {
            if len > MAX_JSON {
                return Err(err(path, format!("a glTF JSON of {len} bytes is too large")));
            }
            let mut json = Vec::with_capacity(len as usize);
            file.read_to_end(&mut json).map_err(|e| Error::io(path, "read", e))?;
            (json, None)
        };
        let doc: Doc = serde_json::from_slice(&json).map_err(|e| err(path, format!("glTF JSON: {e}")))?;
        if doc.asset.is_none() {
            return Err(err(path, "glTF JSON has no 'asset' (not a glTF file?)"));
        }
        for e in &doc.extensions_required {
            if !extension_ok(e) {
                return Err(err(path, format!("extensionsRequired: extension {e} is not supported")));
            }
        }
        let quantized = doc.extensions_used.iter().any(|e| e == "KHR_mesh_quantization");
        let mut bufs = Vec::with_capacity(doc.buffers.len());
        for (i, b) in doc.buffers.iter().enumerate() {
            let what = format!("buffers[{i}]");
            let buf = match &b.uri {
                None if b.extensions.contains_key("EXT_meshopt_compression") && (i != 0 || glb_bin.is_none()) => {
                    bufs.push(None);
                    continue;
                }
                None => {
                    let Some((base, blen)) = glb_bin.filter(|_| i == 0) else {
                        return Err(err(path, format!("{what}: no uri and no GLB BIN chunk")));
                    };
                    if b.byte_length > blen {
                        return Err(err(path, format!("{what}: byteLength {} exceeds the {blen}-byte BIN chunk", b.byte_length)));
                    }
                    Buf { file: file.try_clone().map_err(|e| Error::io(path, "open", e))?, path: path.to_path_buf(), base, len: b.byte_length }
                }
                Some(u) if u.starts_with("data:") => {
                    return Err(err(path, format!("{what}: data: URIs are not supported (use a .glb or a .bin file)")));
                }
                Some(u) => {
                    let p = path.parent().unwrap_or(Path::new("")).join(percent_decode(u));
                    let (f, flen) = crate::io::open_regular(&p, "open")?;
                    if b.byte_length > flen {
                        return Err(err(path, format!("{what}: byteLength {} exceeds the {flen} bytes of {}", b.byte_length, p.display())));
                    }
                    Buf { file: f, path: p, base: 0, len: b.byte_length }
                }
            };
            bufs.push(Some(buf));
        }
        let mut g = Gltf { path: path.to_path_buf(), doc, bufs, prims: Vec::new(), attrs: AttrSet::POSITION_ONLY, bytes: len, quantized };
        g.collect()?;
        Ok(g)
    }

    /// Finds the triangle primitives of the default scene with their world matrices.
    /// See [`GltfInfo::images`]: the primitives' [`Gltf::textures`].
    fn base_color_images(&self) -> Vec<GltfImage> {
        self.textures().0
    }

    /// The base colour images the primitives' materials use, in order of
    /// first use, each once (a file by its URI, an image in a buffer by its
    /// index), and each primitive's slot in that list (None: its material
    /// has no base colour texture, or it leads nowhere: a `data:` URI, a
    /// missing texture or image; a texture is not geometry, so no error).
    /// Slots past [`Vertex::NO_TEXTURE`] − 1 are None too.
    fn textures(&self) -> (Vec<GltfImage>, Vec<Option<u16>>) {
        let d = &self.doc;
        let mut slot_of: BTreeMap<GltfImage, u16> = BTreeMap::new();
        let mut out = Vec::new();
        let mut slots = Vec::with_capacity(self.prims.len());
        for p in &self.prims {
            let image = p
                .material
                .and_then(|m| d.materials.get(m))
                .and_then(|m| m.pbr_metallic_roughness.as_ref())
                .and_then(|pbr| pbr.base_color_texture.as_ref())
                .and_then(|t| d.textures.get(t.index))
                .and_then(|t| t.source)
                .and_then(|i| Some((i, d.images.get(i)?)));
            let im = image.and_then(|(i, def)| match (&def.uri, def.buffer_view) {
                (Some(u), _) if !u.starts_with("data:") => Some(GltfImage::File(percent_decode(u))),
                (None, Some(_)) => Some(GltfImage::Embedded { index: i, mime: def.mime_type.clone().unwrap_or_default(), name: def.name.clone() }),
                _ => None,
            });
            let slot = im.and_then(|im| match slot_of.get(&im) {
                Some(&s) => Some(s),
                None if out.len() < Vertex::NO_TEXTURE as usize => {
                    let s = out.len() as u16;
                    slot_of.insert(im.clone(), s);
                    out.push(im);
                    Some(s)
                }
                None => None,
            });
            slots.push(slot);
        }
        (out, slots)
    }

    fn collect(&mut self) -> Result<()> {
        let d = &self.doc;
        let roots: Vec<usize> = match d.scene.or(if d.scenes.is_empty() { None } else { Some(0) }) {
            Some(s) => {
                let Some(sc) = d.scenes.get(s) else {
                    return Err(err(&self.path, format!("scene {s}: there are {} scenes", d.scenes.len())));
                };
                sc.nodes.clone()
            }
            None => {
                // No scene: every root node (not a child of another).
                let mut child = vec![false; d.nodes.len()];
                for n in &d.nodes {
                    for &c in &n.children {
                        if let Some(x) = child.get_mut(c) {
                            *x = true;
                        }
                    }
                }
                (0..d.nodes.len()).filter(|&i| !child[i]).collect()
            }
        };
        let mut prims = Vec::new();
        let mut stack: Vec<(usize, [f64; 16], usize)> = roots.iter().rev().map(|&r| (r, IDENTITY, 0)).collect();
        while let Some((ni, parent, depth)) = stack.pop() {
            let Some(n) = d.nodes.get(ni) else {
                return Err(err(&self.path, format!("node {ni}: there are {} nodes", d.nodes.len())));
            };
            if depth > MAX_DEPTH {
                return Err(err(&self.path, format!("nodes[{ni}]: the node hierarchy is deeper than {MAX_DEPTH} (a cycle?)")));
            }
            let m = mat_mul(&parent, &local(n));
            if let Some(mi) = n.mesh {
                let Some(mesh) = d.meshes.get(mi) else {
                    return Err(err(&self.path, format!("nodes[{ni}].mesh: mesh {mi} of {}", d.meshes.len())));
                };
                for (pi, p) in mesh.primitives.iter().enumerate() {
                    let what = format!("meshes[{mi}].primitives[{pi}]");
                    let mode = p.mode.unwrap_or(4);
                    if mode < 4 {
                        continue; // points and lines: no triangles
                    }
                    if mode > 6 {
                        return Err(err(&self.path, format!("{what}.mode: {mode} is not a glTF primitive mode")));
                    }
                    let Some(&pos) = p.attributes.get("POSITION") else {
                        return Err(err(&self.path, format!("{what}.attributes: no POSITION")));
                    };
                    let verts = self.accessor(pos, &format!("{what}.attributes.POSITION"))?.count;
                    let corners = match p.indices {
                        Some(a) => self.accessor(a, &format!("{what}.indices"))?.count,
                        None => verts,
                    };
                    if mode == 4 && corners % 3 != 0 {
                        return Err(err(&self.path, format!("{what}: {corners} corners is not a multiple of 3 (mode 4, triangles)")));
                    }
                    prims.push(Prim {
                        what,
                        m,
                        mode,
                        pos,
                        normal: p.attributes.get("NORMAL").copied(),
                        color: p.attributes.get("COLOR_0").copied(),
                        uv: p.attributes.get("TEXCOORD_0").copied(),
                        indices: p.indices,
                        material: p.material,
                        slot: None,
                        verts,
                        corners,
                    });
                }
            }
            for &c in n.children.iter().rev() {
                stack.push((c, m, depth + 1));
            }
        }
        let all = |f: fn(&Prim) -> bool| !prims.is_empty() && prims.iter().all(f);
        let mut attrs = AttrSet::POSITION_ONLY;
        attrs = attrs.with(AttrSet::NORMAL, all(|p| p.normal.is_some()));
        attrs = attrs.with(AttrSet::COLOR, all(|p| p.color.is_some()));
        attrs = attrs.with(AttrSet::UV, all(|p| p.uv.is_some()));
        let rgba = attrs.color() && prims.iter().all(|p| p.color.and_then(|c| self.doc.accessors.get(c)).is_some_and(|a| a.kind == "VEC4"));
        attrs = attrs.with(AttrSet::ALPHA, rgba);
        self.prims = prims;
        let (_, slots) = self.textures();
        for (p, s) in self.prims.iter_mut().zip(&slots) {
            p.slot = *s;
        }
        // Faces choose among textures when two primitives' slots differ
        // (two images, or a textured and an untextured one); one image on
        // every primitive is texture 0, what every vertex reads without
        // MATERIAL.
        let distinct: std::collections::BTreeSet<Option<u16>> = slots.into_iter().collect();
        attrs = attrs.with(AttrSet::MATERIAL, attrs.uv() && distinct.len() >= 2);
        self.attrs = attrs;
        Ok(())
    }

    fn accessor(&self, a: usize, what: &str) -> Result<&Accessor> {
        self.doc.accessors.get(a).ok_or_else(|| err(&self.path, format!("{what}: accessor {a} of {}", self.doc.accessors.len())))
    }

    /// Reads accessor `a` as f64 values (normalized ones mapped to [0,1] or
    /// [-1,1]), `ncomp` per element; `types` are the component types allowed.
    /// A reader of accessor `a` (checked: type among `ncomp` components,
    /// component type among `types`, its bytes inside its bufferView and
    /// buffer); an `EXT_meshopt_compression` view is decoded whole here.
    fn reader(&self, a: usize, what: &str, ncomp: &[usize], types: &[u32]) -> Result<AccReader<'_>> {
        let acc = self.accessor(a, what)?;
        let path = &self.path;
        let Some(nc) = components(&acc.kind).filter(|n| ncomp.contains(n)) else {
            return Err(err(path, format!("{what}: accessor {a} has type {}, not one of {ncomp:?} components", acc.kind)));
        };
        if !types.contains(&acc.component_type) {
            let allowed: Vec<String> = types.iter().map(|&t| type_name(t)).collect();
            return Err(err(
                path,
                format!("{what}: accessor {a} has components of {}, not supported here (allowed: {})", type_name(acc.component_type), allowed.join(", ")),
            ));
        }
        if acc.sparse.is_some() {
            return Err(err(path, format!("{what}: accessor {a} is sparse, which is not supported")));
        }
        let Some(bvi) = acc.buffer_view else {
            return Err(err(path, format!("{what}: accessor {a} has no bufferView, which is not supported")));
        };
        let Some(bv) = self.doc.buffer_views.get(bvi) else {
            return Err(err(path, format!("{what}: accessor {a}: bufferView {bvi} of {}", self.doc.buffer_views.len())));
        };
        let cs = component_size(acc.component_type).unwrap();
        let esize = cs * nc as u64;
        let count = acc.count;
        let (src, stride) = match bv.extensions.get("EXT_meshopt_compression") {
            Some(ext) => {
                let (raw, stride) = self.meshopt(a, bvi, bv, ext, what, esize, count)?;
                (Src::Decoded(raw), stride)
            }
            None => {
                let Some(Some(buf)) = self.bufs.get(bv.buffer) else {
                    return Err(err(path, format!("{what}: bufferViews[{bvi}]: buffer {} of {} (or one without data)", bv.buffer, self.bufs.len())));
                };
                let stride = bv.byte_stride.filter(|&s| s > 0).unwrap_or(esize);
                let span = span(stride, esize, count, what, a, path)?;
                let start = bv.byte_offset.saturating_add(acc.byte_offset);
                let end = start.saturating_add(span);
                if acc.byte_offset.saturating_add(span) > bv.byte_length || bv.byte_offset.saturating_add(bv.byte_length) > buf.len {
                    return Err(err(
                        path,
                        format!(
                            "{what}: accessor {a} reads bytes {start}..{end} of bufferView {bvi} (bytes {}..{} of a {}-byte buffer)",
                            bv.byte_offset,
                            bv.byte_offset.saturating_add(bv.byte_length),
                            buf.len
                        ),
                    ));
                }
                (Src::File { buf, start: buf.base + start }, stride)
            }
        };
        Ok(AccReader { src, raw: Vec::new(), stride: stride as usize, esize: esize as usize, nc, t: acc.component_type, norm: acc.normalized, count, next: 0 })
    }

    /// Decodes an `EXT_meshopt_compression` bufferView and gives the bytes
    /// accessor `a` reads from it (from its first element) and the stride.
    #[allow(clippy::too_many_arguments)]
    fn meshopt(&self, a: usize, bvi: usize, bv: &BufferView, ext: &serde_json::Value, what: &str, esize: u64, count: u64) -> Result<(Vec<u8>, u64)> {
        let path = &self.path;
        let here = format!("{what}: accessor {a}: bufferViews[{bvi}].extensions.EXT_meshopt_compression");
        let m: Meshopt = serde_json::from_value(ext.clone()).map_err(|e| err(path, format!("{here}: {e}")))?;
        let Some(Some(buf)) = self.bufs.get(m.buffer) else {
            return Err(err(path, format!("{here}: buffer {} of {} (or one without data)", m.buffer, self.bufs.len())));
        };
        let end = m.byte_offset.saturating_add(m.byte_length);
        if end > buf.len {
            return Err(err(path, format!("{here}: reads bytes {}..{end} of a {}-byte buffer", m.byte_offset, buf.len)));
        }
        let vs = m.byte_stride;
        let total = m.count.checked_mul(vs).filter(|&t| t <= bv.byte_length && t < (isize::MAX as u64) / 2);
        let ok_stride = match m.mode.as_str() {
            "ATTRIBUTES" => vs > 0 && vs % 4 == 0 && vs <= 256,
            _ => vs == 2 || vs == 4,
        };
        let Some(total) = total.filter(|_| ok_stride) else {
            return Err(err(
                path,
                format!("{here}: count {} × byteStride {vs} does not fit bufferView of {} bytes (or a bad stride)", m.count, bv.byte_length),
            ));
        };
        let mut src = vec![0u8; m.byte_length as usize];
        read_exact_at(&buf.file, &buf.path, &mut src, buf.base + m.byte_offset)?;
        let mut dst = vec![0u8; total as usize];
        let (n, vsz) = (m.count as usize, vs as usize);
        // SAFETY: dst holds count × stride bytes, src is a slice of its length.
        let rc = unsafe {
            let d = dst.as_mut_ptr().cast();
            match m.mode.as_str() {
                "ATTRIBUTES" => meshopt::ffi::meshopt_decodeVertexBuffer(d, n, vsz, src.as_ptr(), src.len()),
                "TRIANGLES" if n % 3 == 0 => meshopt::ffi::meshopt_decodeIndexBuffer(d, n, vsz, src.as_ptr(), src.len()),
                "INDICES" => meshopt::ffi::meshopt_decodeIndexSequence(d, n, vsz, src.as_ptr(), src.len()),
                _ => return Err(err(path, format!("{here}: mode {:?} with count {n} is not supported", m.mode))),
            }
        };
        if rc != 0 {
            return Err(err(path, format!("{here}: meshopt decoding failed (code {rc})")));
        }
        let filter = m.filter.as_deref().unwrap_or("NONE");
        let fits = match filter {
            "OCTAHEDRAL" | "COLOR" => vs == 4 || vs == 8,
            "QUATERNION" => vs == 8,
            _ => true,
        };
        if !fits || (filter != "NONE" && m.mode != "ATTRIBUTES") {
            return Err(err(path, format!("{here}: filter {filter} with byteStride {vs} and mode {} is not valid", m.mode)));
        }
        // SAFETY: dst holds count × stride bytes, strides checked above.
        unsafe {
            let d = dst.as_mut_ptr().cast();
            match filter {
                "NONE" => {}
                "OCTAHEDRAL" => meshopt::ffi::meshopt_decodeFilterOct(d, n, vsz),
                "QUATERNION" => meshopt::ffi::meshopt_decodeFilterQuat(d, n, vsz),
                "EXPONENTIAL" => meshopt::ffi::meshopt_decodeFilterExp(d, n, vsz),
                "COLOR" => meshopt::ffi::meshopt_decodeFilterColor(d, n, vsz),
                f => return Err(err(path, format!("{here}: filter {f} is not supported"))),
            }
        }
        let stride = bv.byte_stride.filter(|&s| s > 0).unwrap_or(esize);
        let acc = &self.doc.accessors[a];
        let span = span(stride, esize, count, what, a, path)?;
        let end = acc.byte_offset.saturating_add(span);
        if end > total.min(bv.byte_length) {
            return Err(err(
                path,
                format!("{here}: accessor {a} reads bytes {}..{end} of a {}-byte decoded bufferView", acc.byte_offset, total.min(bv.byte_length)),
            ));
        }
        dst.drain(..acc.byte_offset as usize);
        Ok((dst, stride))
    }

    /// A primitive's vertices in world space, to `sink` in batches of
    /// [`BATCH`] (each attribute read a batch at a time); `first`: the
    /// number of the primitive's first vertex.
    fn vertices(&self, p: &Prim, first: u64, sink: &mut dyn BodySink, progress: &Progress) -> Result<()> {
        let q: &[u32] = if self.quantized { &[5126, 5120, 5121, 5122, 5123] } else { &[5126] };
        let what = format!("{}.attributes.POSITION", p.what);
        let n = p.verts as usize;
        let mut pos = self.reader(p.pos, &what, &[3], q)?;
        let nq: &[u32] = if self.quantized { &[5126, 5120, 5122] } else { &[5126] };
        let mut nr = match (self.attrs.normal(), p.normal) {
            (true, Some(a)) => Some(self.reader(a, &format!("{}.attributes.NORMAL", p.what), &[3], nq)?),
            _ => None,
        };
        let mut col = match (self.attrs.color(), p.color) {
            (true, Some(a)) => Some(self.reader(a, &format!("{}.attributes.COLOR_0", p.what), &[3, 4], &[5126, 5121, 5123])?),
            _ => None,
        };
        let mut tex = match (self.attrs.uv(), p.uv) {
            (true, Some(a)) => Some(self.reader(a, &format!("{}.attributes.TEXCOORD_0", p.what), &[2], &[5126, 5121, 5123, 5120, 5122])?),
            _ => None,
        };
        for (r, attr) in [(&nr, "NORMAL"), (&col, "COLOR_0"), (&tex, "TEXCOORD_0")] {
            if let Some(r) = r {
                self.check_count(r.count as usize, n, &p.what, attr)?;
            }
        }
        let m = &p.m;
        let nm = normal_matrix(m);
        let material = if self.attrs.material() { p.slot.unwrap_or(Vertex::NO_TEXTURE) } else { 0 };
        let mut vs = vec![Vertex { material, ..Vertex::default() }; BATCH.min(n)];
        let mut done = 0usize;
        while done < n {
            let k = BATCH.min(n - done);
            let vs = &mut vs[..k];
            let mut bad = None;
            pos.each(k, |i, [x, y, z, _]| {
                if !(x.is_finite() && y.is_finite() && z.is_finite()) {
                    bad.get_or_insert((i, [x, y, z]));
                }
                vs[i].pos = [0, 1, 2].map(|r| m[r] * x + m[4 + r] * y + m[8 + r] * z + m[12 + r]);
            })?;
            if let Some((i, [x, y, z])) = bad {
                return Err(err(&self.path, format!("{what}: vertex {} has a non-finite position ({x}, {y}, {z})", done + i)));
            }
            if let Some(r) = nr.as_mut() {
                r.each(k, |i, [a0, a1, a2, _]| {
                    let w = nm.map(|row| row[0] * a0 + row[1] * a1 + row[2] * a2);
                    let l = (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt();
                    vs[i].normal = if l > 0.0 && l.is_finite() { w.map(|c| (c / l) as f32) } else { [0.0; 3] };
                })?;
            }
            if let Some(r) = col.as_mut() {
                let nc = r.nc;
                r.each(k, |i, c| {
                    let v = &mut vs[i];
                    for (out, &x) in v.color.iter_mut().zip(&c[..3]) {
                        *out = (crate::color::linear_to_srgb(x) * 255.0).round() as u8;
                    }
                    v.color[3] = if nc == 4 { (c[3].clamp(0.0, 1.0) * 255.0).round() as u8 } else { 255 };
                })?;
            }
            if let Some(r) = tex.as_mut() {
                // glTF's v runs down the image, octolod's up (MeshLab's).
                r.each(k, |i, [u, v, _, _]| vs[i].uv = [u as f32, (1.0 - v) as f32])?;
            }
            sink.vertices(first + done as u64, vs)?;
            progress.inc(k as u64);
            crate::io::signal::check()?;
            done += k;
        }
        Ok(())
    }

    fn check_count(&self, got: usize, want: usize, what: &str, attr: &str) -> Result<()> {
        if got != want {
            return Err(err(&self.path, format!("{what}.attributes.{attr}: {got} elements, POSITION has {want}")));
        }
        Ok(())
    }
}

/// Bytes `count` elements of `esize` bytes `stride` apart span.
fn span(stride: u64, esize: u64, count: u64, what: &str, a: usize, path: &Path) -> Result<u64> {
    if stride < esize {
        return Err(err(path, format!("{what}: accessor {a}: byteStride {stride} is less than the {esize}-byte element")));
    }
    let span = if count == 0 { 0 } else { stride.checked_mul(count - 1).and_then(|s| s.checked_add(esize)).unwrap_or(u64::MAX) };
    if span > isize::MAX as u64 / 2 {
        return Err(err(path, format!("{what}: accessor {a} of {span} bytes is too large")));
    }
    Ok(span)
}

fn chunk_head(file: &File, path: &Path, at: u64) -> Result<(u64, u32)> {
    let mut h = [0u8; 8];
    read_exact_at(file, path, &mut h, at)?;
    Ok((u32::from_le_bytes(h[..4].try_into().unwrap()) as u64, u32::from_le_bytes(h[4..].try_into().unwrap())))
}

/// Where an accessor's bytes come from.
enum Src<'a> {
    /// A buffer's file, from the accessor's first element.
    File { buf: &'a Buf, start: u64 },
    /// A decoded `EXT_meshopt_compression` view, from the first element.
    Decoded(Vec<u8>),
}

/// Reads a checked accessor ([`Gltf::reader`]) a run of elements at a
/// time, each run by one positioned read, its components converted to
/// f64 (normalized integers mapped to \[0,1\] or \[-1,1\]).
struct AccReader<'a> {
    src: Src<'a>,
    raw: Vec<u8>,
    stride: usize,
    esize: usize,
    nc: usize,
    t: u32,
    norm: bool,
    count: u64,
    /// The next element.
    next: u64,
}

impl AccReader<'_> {
    /// The bytes of the next `n` elements (fewer at the end), and how many.
    fn fetch(&mut self, n: usize) -> Result<(&[u8], usize)> {
        let n = n.min((self.count - self.next) as usize);
        if n == 0 {
            return Ok((&[], 0));
        }
        let first = self.next as usize * self.stride;
        let span = (n - 1) * self.stride + self.esize;
        self.next += n as u64;
        Ok(match &self.src {
            Src::Decoded(d) => (&d[first..first + span], n),
            Src::File { buf, start } => {
                self.raw.resize(span, 0);
                read_exact_at(&buf.file, &buf.path, &mut self.raw, start + first as u64)?;
                (&self.raw, n)
            }
        })
    }

    /// The next `n` indices (an unsigned scalar accessor) appended to
    /// `out`; gives the largest.
    fn next_indices(&mut self, n: usize, out: &mut Vec<u64>) -> Result<u64> {
        let (t, stride) = (self.t, self.stride);
        let (raw, n) = self.fetch(n)?;
        let mut max = 0u64;
        let mut keep = |x: u64| {
            max = max.max(x);
            x
        };
        match t {
            5121 => out.extend((0..n).map(|i| keep(raw[i * stride] as u64))),
            5123 => out.extend((0..n).map(|i| keep(u16::from_le_bytes([raw[i * stride], raw[i * stride + 1]]) as u64))),
            _ => out.extend((0..n).map(|i| keep(u32::from_le_bytes(raw[i * stride..i * stride + 4].try_into().unwrap()) as u64))),
        }
        Ok(max)
    }

    /// The next `n` elements (fewer at the end), each handed to `f` with
    /// its number in this run and its components (unused ones zero); gives
    /// how many.
    fn each(&mut self, n: usize, mut f: impl FnMut(usize, [f64; 4])) -> Result<usize> {
        let (stride, nc, norm, t) = (self.stride, self.nc, self.norm, self.t);
        let (raw, n) = self.fetch(n)?;
        // One loop per component type, so the conversion is not chosen per value.
        fn run<const S: usize>(raw: &[u8], stride: usize, n: usize, nc: usize, f: &mut impl FnMut(usize, [f64; 4]), conv: impl Fn([u8; S]) -> f64) {
            for i in 0..n {
                let e = &raw[i * stride..];
                let mut v = [0.0; 4];
                for (c, x) in v.iter_mut().enumerate().take(nc) {
                    *x = conv(e[c * S..c * S + S].try_into().unwrap());
                }
                f(i, v);
            }
        }
        let f = &mut f;
        match (t, norm) {
            (5120, true) => run::<1>(raw, stride, n, nc, f, |b| (b[0] as i8 as f64 / 127.0).max(-1.0)),
            (5120, false) => run::<1>(raw, stride, n, nc, f, |b| b[0] as i8 as f64),
            (5121, true) => run::<1>(raw, stride, n, nc, f, |b| b[0] as f64 / 255.0),
            (5121, false) => run::<1>(raw, stride, n, nc, f, |b| b[0] as f64),
            (5122, true) => run::<2>(raw, stride, n, nc, f, |b| (i16::from_le_bytes(b) as f64 / 32767.0).max(-1.0)),
            (5122, false) => run::<2>(raw, stride, n, nc, f, |b| i16::from_le_bytes(b) as f64),
            (5123, true) => run::<2>(raw, stride, n, nc, f, |b| u16::from_le_bytes(b) as f64 / 65535.0),
            (5123, false) => run::<2>(raw, stride, n, nc, f, |b| u16::from_le_bytes(b) as f64),
            (5125, _) => run::<4>(raw, stride, n, nc, f, |b| u32::from_le_bytes(b) as f64),
            _ if nc == 3 => run::<4>(raw, stride, n, 3, f, |b| f32::from_le_bytes(b) as f64),
            _ => run::<4>(raw, stride, n, nc, f, |b| f32::from_le_bytes(b) as f64),
        }
        Ok(n)
    }
}

fn read_exact_at(file: &File, path: &Path, buf: &mut [u8], at: u64) -> Result<()> {
    file.read_exact_at(buf, at).map_err(|e| {
        if e.kind() == std::io::ErrorKind::UnexpectedEof {
            err_at(path, at, format!("the file ends within the {} bytes read here", buf.len()))
        } else {
            Error::io(path, "read", e)
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::IndexedMesh;
    use crate::ply::read::CollectSink;
    use serde_json::{json, Value};

    fn glb(doc: &Value, bin: &[u8]) -> Vec<u8> {
        let mut j = serde_json::to_vec(doc).unwrap();
        while j.len() % 4 != 0 {
            j.push(b' ');
        }
        let mut b = bin.to_vec();
        while b.len() % 4 != 0 {
            b.push(0);
        }
        let total = 12 + 8 + j.len() + 8 + b.len();
        let mut out = Vec::new();
        out.extend_from_slice(b"glTF");
        out.extend_from_slice(&2u32.to_le_bytes());
        out.extend_from_slice(&(total as u32).to_le_bytes());
        out.extend_from_slice(&(j.len() as u32).to_le_bytes());
        out.extend_from_slice(&CHUNK_JSON.to_le_bytes());
        out.extend_from_slice(&j);
        out.extend_from_slice(&(b.len() as u32).to_le_bytes());
        out.extend_from_slice(&CHUNK_BIN.to_le_bytes());
        out.extend_from_slice(&b);
        out
    }

    fn f32s(v: &[f32]) -> Vec<u8> {
        v.iter().flat_map(|x| x.to_le_bytes()).collect()
    }

    const QUAD: [[f32; 3]; 4] = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]];
    const TRI: [[f32; 3]; 3] = [[0.0, 0.0, 5.0], [1.0, 0.0, 5.0], [0.0, 1.0, 5.0]];

    /// Two meshes: mesh 0 = a u16-indexed quad and a u32-indexed triangle
    /// read through a 16-byte stride; mesh 1 = a non-indexed triangle (the
    /// quad's first three corners) on a child node.
    fn sample() -> (Value, Vec<u8>) {
        let mut bin = f32s(&QUAD.concat()); // 0..48
        bin.extend([0u16, 1, 2, 0, 2, 3].iter().flat_map(|x| x.to_le_bytes())); // 48..60
        for p in TRI {
            // 60..108: stride 16
            bin.extend(f32s(&p));
            bin.extend([0xAAu8; 4]);
        }
        bin.extend([2u32, 1, 0].iter().flat_map(|x| x.to_le_bytes())); // 108..120
        let doc = json!({
            "asset": {"version": "2.0"},
            "scene": 0,
            "scenes": [{"nodes": [0]}],
            "nodes": [
                {"mesh": 0, "translation": [10.0, 0.0, 0.0], "scale": [2.0, 2.0, 2.0], "children": [1]},
                {"mesh": 1, "translation": [0.0, 0.0, 1.0]},
            ],
            "meshes": [
                {"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}, {"attributes": {"POSITION": 2}, "indices": 3, "mode": 4}]},
                {"primitives": [{"attributes": {"POSITION": 4}}]},
            ],
            "accessors": [
                {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3"},
                {"bufferView": 1, "componentType": 5123, "count": 6, "type": "SCALAR"},
                {"bufferView": 2, "componentType": 5126, "count": 3, "type": "VEC3"},
                {"bufferView": 3, "componentType": 5125, "count": 3, "type": "SCALAR"},
                {"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3"},
            ],
            "bufferViews": [
                {"buffer": 0, "byteOffset": 0, "byteLength": 48},
                {"buffer": 0, "byteOffset": 48, "byteLength": 12},
                {"buffer": 0, "byteOffset": 60, "byteLength": 48, "byteStride": 16},
                {"buffer": 0, "byteOffset": 108, "byteLength": 12},
            ],
            "buffers": [{"byteLength": 120}],
        });
        (doc, bin)
    }

    fn check_sample(path: &Path) {
        let info = read_info(path).unwrap();
        assert_eq!(
            info,
            GltfInfo {
                vertices: 10,
                triangles: 4,
                primitives: 3,
                attrs: AttrSet::POSITION_ONLY,
                images: Vec::new(),
                bytes: std::fs::metadata(path).unwrap().len()
            }
        );
        let mut sink = CollectSink::default();
        let stats = read_body(path, &info, &mut sink, &Progress::hidden()).unwrap();
        assert_eq!((stats.vertices, stats.triangles, stats.degenerate), (10, 4, 0));
        let parent = |p: [f32; 3]| [p[0] as f64 * 2.0 + 10.0, p[1] as f64 * 2.0, p[2] as f64 * 2.0];
        let mut want: Vec<[f64; 3]> = QUAD.iter().map(|&p| parent(p)).collect();
        want.extend(TRI.iter().map(|&p| parent(p)));
        want.extend(QUAD[..3].iter().map(|&p| parent([p[0], p[1], p[2] + 1.0])));
        let got: Vec<[f64; 3]> = sink.vertices.iter().map(|v| v.pos).collect();
        assert_eq!(got, want);
        assert_eq!(sink.triangles, vec![[0, 1, 2], [0, 2, 3], [6, 5, 4], [7, 8, 9]]);
        let (h, all, _) = super::super::read_all(path, 1 << 30).unwrap();
        assert_eq!((h.format, h.vertices, h.faces), (super::super::Format::Gltf, 10, 4));
        assert_eq!(all.triangles, sink.triangles);
    }

    #[test]
    fn glb_two_meshes_transforms_strides_and_index_widths() {
        let dir = tempfile::tempdir().unwrap();
        let (doc, bin) = sample();
        let p = dir.path().join("s.glb");
        std::fs::write(&p, glb(&doc, &bin)).unwrap();
        check_sample(&p);
        // Found by content too.
        let q = dir.path().join("s.mesh");
        std::fs::copy(&p, &q).unwrap();
        assert_eq!(super::super::Format::of(&q).unwrap(), super::super::Format::Gltf);
    }

    #[test]
    fn gltf_with_an_external_bin() {
        let dir = tempfile::tempdir().unwrap();
        let (mut doc, bin) = sample();
        doc["buffers"][0]["uri"] = json!("my%20data.bin");
        std::fs::write(dir.path().join("my data.bin"), &bin).unwrap();
        let p = dir.path().join("s.gltf");
        std::fs::write(&p, serde_json::to_vec_pretty(&doc).unwrap()).unwrap();
        check_sample(&p);
        let q = dir.path().join("s.txt");
        std::fs::copy(&p, &q).unwrap();
        assert_eq!(super::super::Format::of(&q).unwrap(), super::super::Format::Gltf);
    }

    /// The sample's data 5 GiB into a sparse external buffer (past GLB's
    /// 4 GiB limit and u32 offsets): read by positioned reads, the same mesh.
    #[test]
    fn an_external_bin_past_4_gib() {
        use std::os::unix::fs::FileExt;
        let dir = tempfile::tempdir().unwrap();
        let (mut doc, bin) = sample();
        let far = 5u64 << 30;
        let f = std::fs::File::create(dir.path().join("far.bin")).unwrap();
        f.set_len(far + bin.len() as u64).unwrap();
        f.write_all_at(&bin, far).unwrap();
        doc["buffers"][0] = json!({"uri": "far.bin", "byteLength": far + bin.len() as u64});
        for v in doc["bufferViews"].as_array_mut().unwrap() {
            let o = v["byteOffset"].as_u64().unwrap();
            v["byteOffset"] = json!(o + far);
        }
        let p = dir.path().join("far.gltf");
        std::fs::write(&p, serde_json::to_vec_pretty(&doc).unwrap()).unwrap();
        check_sample(&p);
    }

    #[test]
    fn strips_fans_rotation_and_mirroring() {
        let dir = tempfile::tempdir().unwrap();
        let bin = f32s(&QUAD.concat());
        let s = std::f64::consts::FRAC_1_SQRT_2;
        let doc = json!({
            "asset": {"version": "2.0"},
            "nodes": [
                {"mesh": 0, "rotation": [0.0, 0.0, s, s]},
                {"mesh": 1, "matrix": [-1.0,0.0,0.0,0.0, 0.0,1.0,0.0,0.0, 0.0,0.0,1.0,0.0, 0.0,0.0,0.0,1.0]},
            ],
            "meshes": [
                {"primitives": [{"attributes": {"POSITION": 0}, "mode": 5}]},
                {"primitives": [{"attributes": {"POSITION": 0}, "mode": 6}, {"attributes": {"POSITION": 0}, "mode": 1}]},
            ],
            "accessors": [{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3"}],
            "bufferViews": [{"buffer": 0, "byteLength": 48}],
            "buffers": [{"byteLength": 48}],
        });
        let p = dir.path().join("s.glb");
        std::fs::write(&p, glb(&doc, &bin)).unwrap();
        let (h, sink, _) = super::super::read_all(&p, 1 << 30).unwrap();
        assert_eq!((h.vertices, h.faces), (8, 4));
        // Strip: (0,1,2), (2,1,3); fan: (1,2,0), (2,3,0), mirrored: corners 2 and 3 swapped.
        assert_eq!(sink.triangles, vec![[0, 1, 2], [2, 1, 3], [5, 4, 6], [6, 4, 7]]);
        // 90° about z: (1,0,0) -> (0,1,0).
        let v = sink.vertices[1].pos;
        assert!((v[0]).abs() < 1e-12 && (v[1] - 1.0).abs() < 1e-12, "{v:?}");
        assert_eq!(sink.vertices[5].pos, [-1.0, 0.0, 0.0]);
    }

    fn grid(n: usize) -> IndexedMesh {
        let mut vertices = Vec::new();
        for y in 0..=n {
            for x in 0..=n {
                let (fx, fy) = (x as f64 / n as f64, y as f64 / n as f64);
                vertices.push(Vertex {
                    pos: [1000.0 + 3.0 * fx, -50.0 + 2.0 * fy, 7.0 + (fx * 6.0).sin() * 0.5],
                    normal: [0.0, 0.0, 1.0],
                    color: [(x * 20) as u8, (y * 20) as u8, 128, 255],
                    uv: [fx as f32, fy as f32],
                    material: 0,
                });
            }
        }
        let mut triangles = Vec::new();
        let w = (n + 1) as u32;
        for y in 0..n as u32 {
            for x in 0..n as u32 {
                let a = y * w + x;
                triangles.push([a, a + 1, a + w + 1]);
                triangles.push([a, a + w + 1, a + w]);
            }
        }
        IndexedMesh { vertices, triangles }
    }

    #[test]
    fn round_trips_octolods_own_writer() {
        let dir = tempfile::tempdir().unwrap();
        let mesh = grid(8);
        let attrs = AttrSet(AttrSet::NORMAL | AttrSet::COLOR | AttrSet::UV);
        let diag = 13f64.sqrt() * 1.2;
        let cases = [("a.glb", false, false), ("b.gltf", false, false), ("c.glb", true, false), ("d.glb", false, true), ("e.gltf", true, true)];
        for (name, quantize, compress) in cases {
            let p = dir.path().join(name);
            let opts = crate::gltf::GltfOptions { quantize, compress, textures: Vec::new() };
            crate::gltf::write_mesh(&p, &mesh, attrs, &opts, false, "m").unwrap();
            let (h, sink, stats) = super::super::read_all(&p, 1 << 30).unwrap();
            assert_eq!(h.format, super::super::Format::Gltf);
            assert_eq!(h.attrs, attrs, "{name}");
            assert_eq!(stats.triangles, mesh.triangles.len() as u64, "{name}");
            assert_eq!(sink.vertices.len(), mesh.vertices.len());
            // The meshopt index codec may rotate a triangle's corners (winding kept).
            let rot = |t: [u64; 3]| {
                let k = (0..3).min_by_key(|&k| t[k]).unwrap();
                [t[k], t[(k + 1) % 3], t[(k + 2) % 3]]
            };
            let tris: Vec<[u64; 3]> = mesh.triangles.iter().map(|t| rot(t.map(u64::from))).collect();
            let got: Vec<[u64; 3]> = sink.triangles.iter().map(|&t| rot(t)).collect();
            assert_eq!(got, tris, "{name}");
            let tol = if quantize { 1e-4 } else { 1e-6 } * diag;
            for (a, b) in sink.vertices.iter().zip(&mesh.vertices) {
                let d = (0..3).map(|k| (a.pos[k] - b.pos[k]).powi(2)).sum::<f64>().sqrt();
                assert!(d <= tol, "{name}: {:?} vs {:?}", a.pos, b.pos);
                assert_eq!(a.color[..3], b.color[..3], "{name}");
                assert!((a.normal[2] - 1.0).abs() < 1e-6);
                assert!((a.uv[0] - b.uv[0]).abs() < 1e-4 && (a.uv[1] - b.uv[1]).abs() < 1e-4);
            }
        }
        // A corrupt meshopt stream is an error naming the extension.
        let p = dir.path().join("f.glb");
        crate::gltf::write_mesh(&p, &mesh, attrs, &crate::gltf::GltfOptions { quantize: false, compress: true, textures: Vec::new() }, false, "m").unwrap();
        let mut bytes = std::fs::read(&p).unwrap();
        let jlen = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
        let bin = 20 + jlen + 8;
        bytes[bin] ^= 0xff; // the vertex stream's header byte
        let e = err_of(dir.path(), "f.glb", &bytes);
        assert!(e.contains("EXT_meshopt_compression") && e.contains("meshopt decoding failed"), "{e}");
    }

    #[test]
    fn meshopt_octahedral_normals() {
        let dir = tempfile::tempdir().unwrap();
        let normals: [[f32; 4]; 4] = [[0.0, 0.0, 1.0, 0.0], [0.6, 0.0, 0.8, 0.0], [0.0, -0.6, 0.8, 0.0], [-1.0, 0.0, 0.0, 0.0]];
        let flat: Vec<f32> = normals.concat();
        let mut filtered = [0i8; 16];
        let mut enc = vec![0u8; 1024];
        // SAFETY: 4 elements of 4 bytes (i8 × 4) and 4 floats each; enc is large enough.
        let n = unsafe {
            meshopt::ffi::meshopt_encodeFilterOct(filtered.as_mut_ptr().cast(), 4, 4, 8, flat.as_ptr());
            meshopt::ffi::meshopt_encodeVertexBuffer(enc.as_mut_ptr(), enc.len(), filtered.as_ptr().cast(), 4, 4)
        };
        assert!(n > 0);
        let mut bin = f32s(&QUAD.concat());
        bin.extend_from_slice(&enc[..n]);
        let doc = json!({
            "asset": {"version": "2.0"},
            "extensionsUsed": ["KHR_mesh_quantization", "EXT_meshopt_compression"],
            "extensionsRequired": ["KHR_mesh_quantization", "EXT_meshopt_compression"],
            "nodes": [{"mesh": 0}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "NORMAL": 1}, "indices": null, "mode": 6}]}],
            "accessors": [
                {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3"},
                {"bufferView": 1, "componentType": 5120, "normalized": true, "count": 4, "type": "VEC3"},
            ],
            "bufferViews": [
                {"buffer": 0, "byteLength": 48},
                {"buffer": 1, "byteLength": 16, "byteStride": 4, "extensions": {"EXT_meshopt_compression": {
                    "buffer": 0, "byteOffset": 48, "byteLength": n, "byteStride": 4, "count": 4, "mode": "ATTRIBUTES", "filter": "OCTAHEDRAL"}}},
            ],
            "buffers": [{"byteLength": 48 + n}, {"byteLength": 16, "extensions": {"EXT_meshopt_compression": {"fallback": true}}}],
        });
        let p = dir.path().join("n.glb");
        std::fs::write(&p, glb(&doc, &bin)).unwrap();
        let (h, sink, _) = super::super::read_all(&p, 1 << 30).unwrap();
        assert_eq!(h.attrs, AttrSet(AttrSet::NORMAL));
        assert_eq!(sink.triangles, vec![[1, 2, 0], [2, 3, 0]]);
        for (v, w) in sink.vertices.iter().zip(&normals) {
            for k in 0..3 {
                assert!((v.normal[k] - w[k]).abs() < 0.02, "{:?} vs {w:?}", v.normal);
            }
        }
    }

    /// A primitive larger than a batch (vertices and triangles both span
    /// several of [`BATCH`]) reads back exactly, through a bufferView
    /// stride; a bad index deep in a later batch is named by its number in
    /// the whole accessor.
    #[test]
    fn batches_span_large_primitives_and_name_late_indices() {
        let n = 300usize; // 90,000 vertices, 178,802 triangles
        let mut bin = Vec::new();
        for y in 0..n {
            for x in 0..n {
                // 16-byte stride: 3 floats and 4 bytes of padding.
                bin.extend(f32s(&[x as f32, y as f32, ((x * y) % 7) as f32]));
                bin.extend([0u8; 4]);
            }
        }
        let ib = bin.len();
        let mut tris = Vec::new();
        for y in 0..n - 1 {
            for x in 0..n - 1 {
                let v = (y * n + x) as u32;
                tris.push([v, v + 1, v + n as u32 + 1]);
                tris.push([v, v + n as u32 + 1, v + n as u32]);
            }
        }
        bin.extend(tris.iter().flatten().flat_map(|i| i.to_le_bytes()));
        let nv = n * n;
        let doc = json!({
            "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
            "buffers": [{"byteLength": bin.len()}],
            "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": ib, "byteStride": 16}, {"buffer": 0, "byteOffset": ib, "byteLength": bin.len() - ib}],
            "accessors": [{"bufferView": 0, "componentType": 5126, "count": nv, "type": "VEC3", "min": [0, 0, 0], "max": [n - 1, n - 1, 6]},
                          {"bufferView": 1, "componentType": 5125, "count": 3 * tris.len(), "type": "SCALAR"}]
        });
        assert!(nv > 2 * BATCH && tris.len() > 4 * BATCH);
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("grid.glb");
        std::fs::write(&p, glb(&doc, &bin)).unwrap();
        let info = read_info(&p).unwrap();
        let mut sink = CollectSink::default();
        let st = read_body(&p, &info, &mut sink, &Progress::hidden()).unwrap();
        assert_eq!((st.vertices, st.triangles), (nv as u64, tris.len() as u64));
        for (k, v) in sink.vertices.iter().enumerate() {
            assert_eq!(v.pos, [(k % n) as f64, (k / n) as f64, (((k % n) * (k / n)) % 7) as f64], "vertex {k}");
        }
        assert!(sink.triangles.iter().zip(&tris).all(|(a, b)| a.map(|i| i as u32) == *b));
        // Index number 400,001 (in the fifth batch of corners) out of range.
        let late = 400_001usize;
        let mut b2 = bin.clone();
        b2[ib + 4 * late..ib + 4 * late + 4].copy_from_slice(&(nv as u32).to_le_bytes());
        let e = err_of(d.path(), "late.glb", &glb(&doc, &b2));
        assert!(e.contains(&format!("indices: index {late} is {nv}, out of range")), "{e}");
    }

    fn err_of(dir: &Path, name: &str, bytes: &[u8]) -> String {
        let p = dir.join(name);
        std::fs::write(&p, bytes).unwrap();
        let r = read_info(&p).and_then(|i| read_body(&p, &i, &mut CollectSink::default(), &Progress::hidden()));
        let e = r.unwrap_err().to_string();
        assert!(e.contains(name), "{e}");
        e
    }

    #[test]
    fn errors_name_the_file_and_what() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let (doc, bin) = sample();
        let mut g = glb(&doc, &bin);
        g[8] ^= 4;
        assert!(err_of(d, "len.glb", &g).contains("GLB header says"));
        let mut g = glb(&doc, &bin);
        g[4] = 1;
        assert!(err_of(d, "ver.glb", &g).contains("version 1"));

        let mut bad = doc.clone();
        bad["accessors"][0]["count"] = json!(5);
        let e = err_of(d, "range.glb", &glb(&bad, &bin));
        assert!(e.contains("meshes[0].primitives[0].attributes.POSITION: accessor 0 reads bytes 0..60"), "{e}");

        let mut bad = doc.clone();
        bad["bufferViews"][0]["byteLength"] = json!(400);
        let e = err_of(d, "view.glb", &glb(&bad, &bin));
        assert!(e.contains("of a 120-byte buffer"), "{e}");

        let mut b2 = bin.clone();
        b2[48..50].copy_from_slice(&9u16.to_le_bytes());
        let e = err_of(d, "index.glb", &glb(&doc, &b2));
        assert!(e.contains("meshes[0].primitives[0].indices: index 0 is 9, out of range"), "{e}");

        let mut b2 = bin.clone();
        b2[4..8].copy_from_slice(&f32::NAN.to_le_bytes());
        let e = err_of(d, "nan.glb", &glb(&doc, &b2));
        assert!(e.contains("vertex 0 has a non-finite position"), "{e}");

        let mut bad = doc.clone();
        bad["accessors"][1]["componentType"] = json!(5126);
        let e = err_of(d, "ctype.glb", &glb(&bad, &bin));
        assert!(e.contains("indices: accessor 1 has components of f32, not supported"), "{e}");

        let mut bad = doc.clone();
        bad["accessors"][0]["componentType"] = json!(5122);
        let e = err_of(d, "quant.glb", &glb(&bad, &bin));
        assert!(e.contains("components of i16"), "{e}");

        let mut bad = doc.clone();
        bad["extensionsRequired"] = json!(["KHR_draco_mesh_compression"]);
        assert!(err_of(d, "ext.glb", &glb(&bad, &bin)).contains("extension KHR_draco_mesh_compression is not supported"));

        let mut bad = doc.clone();
        bad["buffers"][0]["uri"] = json!("data:application/octet-stream;base64,AAAA");
        assert!(err_of(d, "data.gltf", &serde_json::to_vec(&bad).unwrap()).contains("data: URIs are not supported"));

        let mut bad = doc.clone();
        bad["accessors"][0]["sparse"] = json!({"count": 1});
        assert!(err_of(d, "sparse.glb", &glb(&bad, &bin)).contains("sparse"));

        assert!(err_of(d, "json.gltf", b"{\"asset\": ").contains("glTF JSON"));
        assert!(err_of(d, "short.glb", b"glTF\x02\0\0\0").contains("too short"));
    }
}

//! glTF 2.0 output: one mesh, or a store cut given part by part, as a
//! binary `.glb` or as `.gltf` JSON with a `.bin` buffer beside it.
//!
//! Takes: [`IndexedMesh`]es (whole, or node by node in two passes), the
//! [`AttrSet`] saying which attributes are real, and [`GltfOptions`].
//! Gives: one scene, one node, one mesh of triangle primitives (one per
//! material, see below). POSITION
//! always; NORMAL (made unit length), COLOR_0 and TEXCOORD_0 only when the
//! set has them; optionally `quantize` (KHR_mesh_quantization) and
//! `compress` (EXT_meshopt_compression, which the file then requires).
//!
//! Invariants:
//! * Positions are `f32` relative to the bounding box's centre, the node's
//!   `translation` (JSON doubles), so a mesh 10^6 from the origin keeps its
//!   detail; triangles keep their order and winding; indices are `u16` up
//!   to 65535 vertices, else `u32`.
//! * Colours: octolod's sRGB-encoded [`Vertex::color`] bytes become linear
//!   COLOR_0 through the exact transfer function, as normalized `u16`, which
//!   keeps every sRGB byte apart and converts back to the same byte.
//! * Materials: not metallic, fully rough, double-sided. A mesh with
//!   [`AttrSet::MATERIAL`] (and uvs) has a primitive per material its
//!   triangles use (a triangle's material is its corner 0's
//!   [`Vertex::material`]), whose glTF material's base colour is texture
//!   slot `material` of [`GltfOptions::textures`]; [`Vertex::NO_TEXTURE`]
//!   or a slot without an image gets one untextured material (white under
//!   vertex colours, else octolod's grey). Without MATERIAL every face
//!   draws the first slot with an image. Each image is written once,
//!   referenced by URI or embedded in the buffer, sampled with mipmaps and
//!   repeat.
//! * A primitive per material has its own vertices (the part's vertices
//!   its triangles use, in the part's order) rather than index ranges
//!   into shared vertex accessors: materials already split vertices where
//!   they meet, so nothing is stored twice, and a reader that takes each
//!   primitive's accessors whole (octolod's own, Blender's) gets no
//!   unused vertices and each primitive tight bounds for culling; the
//!   cost, one vertex bufferView and accessors per primitive, is a few
//!   hundred bytes of JSON.
//! * uvs: octolod's are MeshLab's and OpenGL's (v = 0 at the image's bottom
//!   row), glTF's have v = 0 at the top: TEXCOORD_0 is (u, 1 − v), and the
//!   glTF reader turns it back.
//! * A whole mesh is one primitive per material ([`encode_glb`],
//!   [`write_mesh`]); a cut streamed ([`write_parts`]) is one primitive per
//!   material per run of whole nodes of at most [`STREAM_GROUP_VERTICES`]
//!   vertices, only one run in memory. Quantization and compression apply
//!   to each primitive's views.
//! * Every output carries `asset.extras.octolod = "output"`
//!   ([`is_octolod_gltf`]) and is written as every octolod output is
//!   ([`crate::io`], [`OutputKind::Gltf`]): a `.glb` through an
//!   [`AtomicFile`], a `.gltf` and its `.bin` through an [`AtomicGltfPair`];
//!   what may be replaced is decided there ([`check_output`]).
//!
//! Hand-written: JSON (serde_json) plus little-endian buffers; the codecs come
//! from the `meshopt` crate. The encodings and why: `docs/web.md`, "glTF output".

use crate::error::{Error, IoContext, Result};
use crate::io::{AtomicFile, AtomicGltfPair, OutputKind};
use crate::mesh::IndexedMesh;
use crate::mesh::{AttrSet, Vertex};
use serde_json::{json, Map, Value};
use std::borrow::Borrow;
use std::fs::{self, File};
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// Whether `path` is a glTF octolod wrote (recognised in [`crate::io`]).
pub use crate::io::is_octolod_gltf;

#[derive(Clone, Debug, Default, PartialEq)]
pub struct GltfOptions {
    /// KHR_mesh_quantization: integer positions, normals and (in \[0,1\]) uvs.
    pub quantize: bool,
    /// EXT_meshopt_compression on every vertex and index bufferView.
    pub compress: bool,
    /// The base colour textures by material id ([`Vertex::material`]:
    /// index = id, the store's texture slots, [`crate::manifest::store_textures`]);
    /// `None` for a slot without an image. Used when the mesh has uvs.
    pub textures: Vec<Option<GltfTexture>>,
}

/// A base colour texture: its image and name (the glTF image's `name`,
/// which clients such as three.js give the texture).
#[derive(Clone, Debug, PartialEq)]
pub struct GltfTexture {
    pub name: String,
    pub image: TextureImage,
}

/// Where a texture's image is.
#[derive(Clone, Debug, PartialEq)]
pub enum TextureImage {
    /// A file the client fetches: a URI reference relative to the glTF.
    Uri(String),
    /// In the glTF's own buffer (self-contained outputs).
    Embedded { bytes: std::sync::Arc<Vec<u8>>, mime: &'static str },
}

impl GltfTexture {
    /// The image's bytes to append to the buffer, when embedded.
    fn embedded(&self) -> Option<&[u8]> {
        match &self.image {
            TextureImage::Embedded { bytes, .. } => Some(bytes),
            TextureImage::Uri(_) => None,
        }
    }

    /// A texture embedding the image file at `path` (PNG or JPEG, by its
    /// first bytes), named `name`.
    pub fn embed_file(path: &Path, name: &str) -> Result<GltfTexture> {
        let bytes = fs::read(path).ctx(path, "read texture")?;
        let mime = image_mime(&bytes).ok_or_else(|| {
            Error::input(
                crate::error::Location { file: path.to_path_buf(), offset: Some(0), ..Default::default() },
                "a texture to embed in glTF must be PNG or JPEG",
            )
        })?;
        Ok(GltfTexture { name: name.to_string(), image: TextureImage::Embedded { bytes: std::sync::Arc::new(bytes), mime } })
    }
}

/// `image/png` or `image/jpeg` by the file's signature; the two glTF 2.0
/// core image types.
pub fn image_mime(bytes: &[u8]) -> Option<&'static str> {
    if bytes.starts_with(b"\x89PNG\r\n\x1a\n") {
        Some("image/png")
    } else if bytes.starts_with(&[0xFF, 0xD8, 0xFF]) {
        Some("image/jpeg")
    } else {
        None
    }
}

/// The two containers, chosen by the output's extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Container {
    /// `.glb`: one binary file.
    Glb,
    /// `.gltf`: JSON, with the buffer in a `.bin` of the same stem.
    Gltf,
}

impl Container {
    /// `.glb` or `.gltf` (any case); `None` for anything else.
    pub fn of(path: &Path) -> Option<Container> {
        let ext = path.extension()?.to_str()?.to_ascii_lowercase();
        match ext.as_str() {
            "glb" => Some(Container::Glb),
            "gltf" => Some(Container::Gltf),
            _ => None,
        }
    }
}

/// Vertices per primitive when a cut is streamed node by node (whole nodes
/// are grouped up to this; a larger node is a primitive of its own).
pub const STREAM_GROUP_VERTICES: u64 = 1 << 20;

/// The marker in `asset.extras` of every glTF octolod writes.
pub use crate::io::{GLTF_MARK_KEY as MARKER_KEY, GLTF_MARK_VALUE as MARKER_VALUE};

const GLB_MAGIC: &[u8; 4] = b"glTF";
const CHUNK_JSON: &[u8; 4] = b"JSON";
const CHUNK_BIN: &[u8; 4] = b"BIN\0";

const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
const BYTE: u32 = 5120;
const SHORT: u32 = 5122;
const UNSIGNED_SHORT: u32 = 5123;
const UNSIGNED_INT: u32 = 5125;
const FLOAT: u32 = 5126;

// ------------------------------------------------------------------ survey

/// A primitive: the triangles of one material in a run of whole parts,
/// with the vertices they use.
#[derive(Clone, Debug)]
struct Prim {
    material: u16,
    vertices: u64,
    triangles: u64,
    lo: [f64; 3],
    hi: [f64; 3],
}

/// A run of whole parts (those with triangles): one primitive per
/// material its triangles use, in material order.
#[derive(Clone, Debug)]
struct Group {
    parts: usize,
    vertices: u64,
    prims: Vec<Prim>,
}

impl Group {
    fn prim(&self, material: u16) -> Option<usize> {
        self.prims.binary_search_by_key(&material, |p| p.material).ok()
    }
}

/// One material's share of a part: the part's vertices it uses (in the
/// part's order; `None`: all of them, borrowed) and its triangles,
/// indexing that list.
struct Piece<'a> {
    material: u16,
    vertices: Option<Vec<u32>>,
    triangles: std::borrow::Cow<'a, [[u32; 3]]>,
}

impl Piece<'_> {
    /// The part's vertices this piece holds, in order.
    fn vertices<'m>(&'m self, m: &'m IndexedMesh) -> Box<dyn Iterator<Item = &'m Vertex> + 'm> {
        match &self.vertices {
            Some(v) => Box::new(v.iter().map(|&k| &m.vertices[k as usize])),
            None => Box::new(m.vertices.iter()),
        }
    }

    fn vertex_count(&self, m: &IndexedMesh) -> usize {
        self.vertices.as_ref().map_or(m.vertices.len(), |v| v.len())
    }
}

/// A triangle's material: corner 0's (the corners agree: vertices are
/// split where materials meet); 0 for every triangle without `materials`.
fn material_of(m: &IndexedMesh, t: &[u32; 3], materials: bool) -> u16 {
    if materials {
        m.vertices[t[0] as usize].material
    } else {
        0
    }
}

/// A part split by material, in material order. A part of one material
/// is one piece of all its vertices, in order (as a mesh without
/// materials always is); with several, each piece takes the vertices its
/// triangles use (a vertex no triangle uses is left out).
fn split_part(m: &IndexedMesh, materials: bool) -> Vec<Piece<'_>> {
    let first = m.triangles.first().map_or(0, |t| material_of(m, t, materials));
    if m.triangles.iter().all(|t| material_of(m, t, materials) == first) {
        return vec![Piece { material: first, vertices: None, triangles: std::borrow::Cow::Borrowed(&m.triangles) }];
    }
    let mut order: Vec<u32> = (0..m.triangles.len() as u32).collect();
    order.sort_by_key(|&k| material_of(m, &m.triangles[k as usize], materials));
    let mut local = vec![u32::MAX; m.vertices.len()];
    let mut pieces = Vec::new();
    for run in order.chunk_by(|&a, &b| material_of(m, &m.triangles[a as usize], materials) == material_of(m, &m.triangles[b as usize], materials)) {
        let material = material_of(m, &m.triangles[run[0] as usize], materials);
        let mut vertices: Vec<u32> = run.iter().flat_map(|&k| m.triangles[k as usize]).filter(|&v| std::mem::replace(&mut local[v as usize], 0) != 0).collect();
        vertices.sort_unstable();
        for (k, &v) in vertices.iter().enumerate() {
            local[v as usize] = k as u32;
        }
        let triangles = run.iter().map(|&k| m.triangles[k as usize].map(|v| local[v as usize])).collect();
        for &v in &vertices {
            local[v as usize] = u32::MAX;
        }
        pieces.push(Piece { material, vertices: Some(vertices), triangles });
    }
    pieces
}

/// What the first pass over the parts learns: counts, bounds, uv range
/// and the primitives.
#[derive(Clone, Debug)]
struct Survey {
    limit: u64,
    /// Triangles are grouped by material ([`AttrSet::MATERIAL`]).
    materials: bool,
    groups: Vec<Group>,
    vertices: u64,
    triangles: u64,
    lo: [f64; 3],
    hi: [f64; 3],
    /// Every uv lies in [0,1].
    uv_unit: bool,
}

impl Survey {
    fn new(limit: u64, attrs: AttrSet) -> Survey {
        Survey {
            limit: limit.max(1),
            materials: attrs.material(),
            groups: Vec::new(),
            vertices: 0,
            triangles: 0,
            lo: [f64::INFINITY; 3],
            hi: [f64::NEG_INFINITY; 3],
            uv_unit: true,
        }
    }

    /// The materials the primitives use, each once, in order.
    fn materials_used(&self) -> Vec<u16> {
        let mut v: Vec<u16> = self.groups.iter().flat_map(|g| g.prims.iter().map(|p| p.material)).collect();
        v.sort_unstable();
        v.dedup();
        v
    }

    /// Every primitive, in buffer order.
    fn prims(&self) -> impl Iterator<Item = &Prim> {
        self.groups.iter().flat_map(|g| &g.prims)
    }

    fn add(&mut self, m: &IndexedMesh) -> Result<()> {
        if m.triangles.is_empty() {
            return Ok(());
        }
        let nv = m.vertices.len() as u64;
        if nv > u32::MAX as u64 {
            return Err(Error::Usage(format!("a mesh of {nv} vertices does not fit 32-bit indices")));
        }
        for (k, t) in m.triangles.iter().enumerate() {
            if let Some(&i) = t.iter().find(|&&i| i as u64 >= nv) {
                return Err(Error::Usage(format!("triangle {k} uses vertex {i}, but the mesh has {nv} vertices")));
            }
        }
        let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
        for (k, v) in m.vertices.iter().enumerate() {
            if !v.pos.iter().all(|x| x.is_finite()) {
                return Err(Error::Usage(format!("vertex {k} has a non-finite position {:?}", v.pos)));
            }
            for a in 0..3 {
                lo[a] = lo[a].min(v.pos[a]);
                hi[a] = hi[a].max(v.pos[a]);
            }
            self.uv_unit &= v.uv.iter().all(|u| (0.0..=1.0).contains(u));
        }
        for a in 0..3 {
            self.lo[a] = self.lo[a].min(lo[a]);
            self.hi[a] = self.hi[a].max(hi[a]);
        }
        let pieces = split_part(m, self.materials);
        let kept: u64 = pieces.iter().map(|p| p.vertex_count(m) as u64).sum();
        let join = self.groups.last().is_some_and(|g| g.vertices + kept <= self.limit.min(u32::MAX as u64));
        if !join {
            self.groups.push(Group { parts: 0, vertices: 0, prims: Vec::new() });
        }
        let g = self.groups.last_mut().expect("a group");
        g.parts += 1;
        g.vertices += kept;
        for piece in &pieces {
            let k = match g.prim(piece.material) {
                Some(k) => k,
                None => {
                    let k = g.prims.partition_point(|p| p.material < piece.material);
                    g.prims.insert(k, Prim { material: piece.material, vertices: 0, triangles: 0, lo: [f64::INFINITY; 3], hi: [f64::NEG_INFINITY; 3] });
                    k
                }
            };
            let p = &mut g.prims[k];
            p.vertices += piece.vertex_count(m) as u64;
            p.triangles += piece.triangles.len() as u64;
            // A piece of the whole part has the part's bounds.
            let (plo, phi) = match &piece.vertices {
                None => (lo, hi),
                Some(_) => piece.vertices(m).fold(([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]), |(l, h), v| {
                    (std::array::from_fn(|a| l[a].min(v.pos[a])), std::array::from_fn(|a| h[a].max(v.pos[a])))
                }),
            };
            for a in 0..3 {
                p.lo[a] = p.lo[a].min(plo[a]);
                p.hi[a] = p.hi[a].max(phi[a]);
            }
        }
        self.vertices += kept;
        self.triangles += m.triangles.len() as u64;
        Ok(())
    }
}

// ------------------------------------------------------------------ layout

/// How each vertex is stored: one interleaved record of `stride` bytes
/// (every attribute at a multiple of 4, as glTF requires).
#[derive(Clone, Copy, Debug)]
struct Layout {
    attrs: AttrSet,
    quantize: bool,
    centre: [f64; 3],
    /// Quantized: the half extent that maps to ±32767; 1 otherwise.
    scale: f64,
    stride: usize,
    normal_at: Option<usize>,
    color_at: Option<usize>,
    /// Offset, and whether stored as normalized u16.
    uv_at: Option<(usize, bool)>,
}

impl Layout {
    fn new(attrs: AttrSet, opts: &GltfOptions, s: &Survey) -> Layout {
        let centre = [0, 1, 2].map(|a| s.lo[a] + 0.5 * (s.hi[a] - s.lo[a]));
        let half = (0..3).map(|a| 0.5 * (s.hi[a] - s.lo[a])).fold(0.0f64, f64::max);
        let scale = if opts.quantize && half > 0.0 && half.is_finite() { half } else { 1.0 };
        let mut off = if opts.quantize { 8 } else { 12 };
        let normal_at = attrs.normal().then(|| {
            let at = off;
            off += if opts.quantize { 4 } else { 12 };
            at
        });
        let color_at = attrs.color().then(|| {
            // u16 × 3 (padded) or × 4.
            let at = off;
            off += 8;
            at
        });
        let uv_at = attrs.uv().then(|| {
            let unorm = opts.quantize && s.uv_unit;
            let at = off;
            off += if unorm { 4 } else { 8 };
            (at, unorm)
        });
        Layout { attrs, quantize: opts.quantize, centre, scale, stride: off, normal_at, color_at, uv_at }
    }

    /// A stored float position (relative to the centre).
    fn pos_f32(&self, p: [f64; 3]) -> [f32; 3] {
        [0, 1, 2].map(|a| (p[a] - self.centre[a]) as f32)
    }

    /// A stored quantized position.
    fn pos_i16(&self, p: [f64; 3]) -> [i16; 3] {
        [0, 1, 2].map(|a| ((p[a] - self.centre[a]) / self.scale * 32767.0).round().clamp(-32767.0, 32767.0) as i16)
    }

    /// POSITION's min and max as JSON (the stored values: monotonic in
    /// the input, so the bounds' images are the images' bounds).
    fn pos_bounds(&self, lo: [f64; 3], hi: [f64; 3]) -> (Value, Value) {
        if self.quantize {
            (json!(self.pos_i16(lo)), json!(self.pos_i16(hi)))
        } else {
            let f = |p: [f64; 3]| json!(self.pos_f32(p).map(f64::from));
            (f(lo), f(hi))
        }
    }

    fn encode(&self, v: &Vertex, out: &mut [u8]) {
        let out = &mut out[..self.stride];
        out.fill(0);
        if self.quantize {
            for (a, q) in self.pos_i16(v.pos).iter().enumerate() {
                out[2 * a..2 * a + 2].copy_from_slice(&q.to_le_bytes());
            }
        } else {
            for (a, x) in self.pos_f32(v.pos).iter().enumerate() {
                out[4 * a..4 * a + 4].copy_from_slice(&x.to_le_bytes());
            }
        }
        if let Some(o) = self.normal_at {
            let n = unit(v.normal);
            if self.quantize {
                for a in 0..3 {
                    out[o + a] = ((n[a] * 127.0).round().clamp(-127.0, 127.0) as i8) as u8;
                }
            } else {
                for (a, x) in n.iter().enumerate() {
                    out[o + 4 * a..o + 4 * a + 4].copy_from_slice(&x.to_le_bytes());
                }
            }
        }
        if let Some(o) = self.color_at {
            let table = srgb_table();
            for a in 0..3 {
                out[o + 2 * a..o + 2 * a + 2].copy_from_slice(&table[v.color[a] as usize].to_le_bytes());
            }
            if self.attrs.alpha() {
                out[o + 6..o + 8].copy_from_slice(&(v.color[3] as u16 * 257).to_le_bytes());
            }
        }
        if let Some((o, unorm)) = self.uv_at {
            // glTF's v runs down the image (see the module doc).
            let uv = [v.uv[0], 1.0 - v.uv[1]];
            for a in 0..2 {
                if unorm {
                    let q = (uv[a] as f64 * 65535.0).round().clamp(0.0, 65535.0) as u16;
                    out[o + 2 * a..o + 2 * a + 2].copy_from_slice(&q.to_le_bytes());
                } else {
                    out[o + 4 * a..o + 4 * a + 4].copy_from_slice(&uv[a].to_le_bytes());
                }
            }
        }
    }

    /// The vertex attributes' accessors (semantic, byteOffset, componentType, type, normalized).
    fn attributes(&self) -> Vec<(&'static str, usize, u32, &'static str, bool)> {
        let mut v = vec![("POSITION", 0, if self.quantize { SHORT } else { FLOAT }, "VEC3", self.quantize)];
        if let Some(o) = self.normal_at {
            v.push(("NORMAL", o, if self.quantize { BYTE } else { FLOAT }, "VEC3", self.quantize));
        }
        if let Some(o) = self.color_at {
            v.push(("COLOR_0", o, UNSIGNED_SHORT, if self.attrs.alpha() { "VEC4" } else { "VEC3" }, true));
        }
        if let Some((o, unorm)) = self.uv_at {
            v.push(("TEXCOORD_0", o, if unorm { UNSIGNED_SHORT } else { FLOAT }, "VEC2", unorm));
        }
        v
    }
}

pub use crate::color::srgb_to_linear;

/// Each sRGB byte's linear value as normalized `u16`.
fn srgb_table() -> &'static [u16; 256] {
    static T: std::sync::OnceLock<[u16; 256]> = std::sync::OnceLock::new();
    T.get_or_init(|| std::array::from_fn(|b| (srgb_to_linear(b as f64 / 255.0) * 65535.0).round() as u16))
}

/// `n` made unit length (in f64); a zero or non-finite normal becomes +z,
/// since glTF requires unit normals.
fn unit(n: [f32; 3]) -> [f32; 3] {
    let d = n.map(f64::from);
    let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    if l > 0.0 && l.is_finite() {
        d.map(|x| (x / l) as f32)
    } else {
        [0.0, 0.0, 1.0]
    }
}

fn index_width(vertices: u64) -> usize {
    if vertices <= 65535 {
        2
    } else {
        4
    }
}

fn align4(x: u64) -> u64 {
    (x + 3) & !3
}

/// Where one primitive's two bufferViews lie in a buffer.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct Placed {
    vertex: (u64, u64),
    index: (u64, u64),
}

/// The uncompressed layout of every primitive (vertices, then indices,
/// each view starting at a multiple of 4) and the buffer's length.
fn raw_layout(s: &Survey, l: &Layout) -> (Vec<Placed>, u64) {
    let mut at = 0u64;
    let placed = s
        .prims()
        .map(|p| {
            let v = (at, p.vertices * l.stride as u64);
            at = align4(v.0 + v.1);
            let i = (at, 3 * p.triangles * index_width(p.vertices) as u64);
            at = align4(i.0 + i.1);
            Placed { vertex: v, index: i }
        })
        .collect();
    (placed, at)
}

// -------------------------------------------------------------- the buffer

/// A writer that knows its position.
struct Counted<W: Write> {
    w: W,
    at: u64,
}

impl<W: Write> Counted<W> {
    fn put(&mut self, b: &[u8]) -> std::io::Result<()> {
        self.w.write_all(b)?;
        self.at += b.len() as u64;
        Ok(())
    }
    fn pad4(&mut self) -> std::io::Result<()> {
        let n = (align4(self.at) - self.at) as usize;
        self.put(&[0u8; 3][..n])
    }
}

/// One primitive's data as its group is gathered.
#[derive(Default)]
struct PrimBuf {
    vertices: Vec<u8>,
    indices: Vec<u32>,
    base: u32,
}

/// meshopt's vertex codec, version 0 (the only one EXT_meshopt_compression
/// accepts; meshopt's default is now version 1).
fn compress_vertices(bytes: &[u8], stride: usize) -> Result<Vec<u8>> {
    macro_rules! by_stride {
        ($($n:literal)*) => {
            match stride {
                $($n => meshopt::encoding::encode_vertex_buffer_level(bytemuck::cast_slice::<u8, [u8; $n]>(bytes), 2, Some(0)),)*
                _ => unreachable!("vertex stride {stride}"),
            }
        };
    }
    by_stride!(4 8 12 16 20 24 28 32 36 40 44 48).map_err(|e| Error::Usage(format!("meshopt vertex encoding failed: {e:?}")))
}

/// Streams the primitives of `parts` (the survey's groups, in order, each
/// group's primitives in material order) into `w`, compressed or not;
/// gives where each primitive's views landed.
fn write_bin<W: Write, M: Borrow<IndexedMesh>>(
    w: &mut Counted<W>,
    path: &Path,
    s: &Survey,
    l: &Layout,
    compress: bool,
    parts: impl Iterator<Item = Result<M>>,
) -> Result<Vec<Placed>> {
    let mut placed = Vec::with_capacity(s.prims().count());
    let mut bufs: Vec<PrimBuf> = Vec::new();
    let mut group = 0usize;
    let mut parts_in = 0usize;
    let changed = || Error::Usage(format!("{}: the meshes changed between the two passes over them", path.display()));
    let flush = |buf: &mut PrimBuf, p: &Prim, w: &mut Counted<W>| -> Result<Placed> {
        if buf.base as u64 != p.vertices || buf.indices.len() as u64 != 3 * p.triangles {
            return Err(changed());
        }
        let mut out = Placed::default();
        let vstart = w.at;
        if compress {
            let c = compress_vertices(&buf.vertices, l.stride)?;
            w.put(&c).ctx(path, "write")?;
        } else {
            w.put(&buf.vertices).ctx(path, "write")?;
        }
        out.vertex = (vstart, w.at - vstart);
        w.pad4().ctx(path, "write")?;
        let istart = w.at;
        if compress {
            let c = meshopt::encoding::encode_index_buffer(&buf.indices, p.vertices as usize)
                .map_err(|e| Error::Usage(format!("meshopt index encoding failed: {e:?}")))?;
            w.put(&c).ctx(path, "write")?;
        } else {
            let width = index_width(p.vertices);
            let mut b = Vec::with_capacity(buf.indices.len() * width);
            for &i in &buf.indices {
                if width == 2 {
                    b.extend_from_slice(&(i as u16).to_le_bytes());
                } else {
                    b.extend_from_slice(&i.to_le_bytes());
                }
            }
            w.put(&b).ctx(path, "write")?;
        }
        out.index = (istart, w.at - istart);
        w.pad4().ctx(path, "write")?;
        Ok(out)
    };
    let mut record = vec![0u8; l.stride];
    for m in parts {
        let m = m?;
        let m = m.borrow();
        if m.triangles.is_empty() {
            continue;
        }
        let g = s.groups.get(group).ok_or_else(changed)?;
        if parts_in == 0 {
            bufs = g
                .prims
                .iter()
                .map(|p| PrimBuf {
                    vertices: Vec::with_capacity((p.vertices as usize).saturating_mul(l.stride)),
                    indices: Vec::with_capacity(3 * p.triangles as usize),
                    base: 0,
                })
                .collect();
        }
        for piece in split_part(m, s.materials) {
            let buf = &mut bufs[g.prim(piece.material).ok_or_else(changed)?];
            for v in piece.vertices(m) {
                l.encode(v, &mut record);
                buf.vertices.extend_from_slice(&record);
            }
            let base = buf.base;
            for t in piece.triangles.iter() {
                buf.indices.extend(t.iter().map(|&i| base + i));
            }
            buf.base = u32::try_from(base as u64 + piece.vertex_count(m) as u64).map_err(|_| changed())?;
        }
        parts_in += 1;
        if parts_in == g.parts {
            for (buf, p) in bufs.iter_mut().zip(&g.prims) {
                placed.push(flush(buf, p, w)?);
                *buf = PrimBuf::default();
            }
            group += 1;
            parts_in = 0;
        }
    }
    if group != s.groups.len() || parts_in != 0 {
        return Err(changed());
    }
    Ok(placed)
}

// ---------------------------------------------------------------- the JSON

/// The glTF document. `placed`: where the primitives' views are in buffer
/// 0 (for `compress`, the compressed streams; the uncompressed layout then
/// goes to the fallback buffer 1). `uri`: buffer 0's, for `.gltf`.
/// `image_at`: where each embedded texture image starts in buffer 0, by
/// material id (they end the buffer).
#[allow(clippy::too_many_arguments)]
fn document(
    s: &Survey,
    l: &Layout,
    opts: &GltfOptions,
    name: Option<&str>,
    placed: &[Placed],
    bin_len: u64,
    uri: Option<&str>,
    image_at: &[(u16, u64)],
) -> Value {
    let (raw, raw_len) = raw_layout(s, l);
    // The glTF materials: one per textured material id used (its image
    // once), then one untextured shared by the ids without an image.
    let used: Vec<(u16, Option<&GltfTexture>)> = s.materials_used().into_iter().map(|id| (id, texture_of(opts, l, s.materials, id))).collect();
    let textured = used.iter().filter(|u| u.1.is_some()).count();
    let mut material_index = Vec::with_capacity(used.len());
    let mut k = 0;
    for (id, t) in &used {
        material_index.push((*id, if t.is_some() { k } else { textured }));
        k += t.is_some() as usize;
    }
    let material_of = |id: u16| material_index.iter().find(|m| m.0 == id).map_or(textured, |m| m.1);
    let mut views = Vec::new();
    let mut accessors = Vec::new();
    let mut primitives = Vec::new();
    for (k, p) in s.prims().enumerate() {
        let width = index_width(p.vertices);
        let view = |raw: (u64, u64), stored: (u64, u64), stride: usize, target: u32, mode: &str, count: u64, with_stride: bool| {
            let mut v = Map::new();
            v.insert("buffer".into(), json!(if opts.compress { 1 } else { 0 }));
            v.insert("byteOffset".into(), json!(if opts.compress { raw.0 } else { stored.0 }));
            v.insert("byteLength".into(), json!(if opts.compress { raw.1 } else { stored.1 }));
            if with_stride {
                v.insert("byteStride".into(), json!(stride));
            }
            v.insert("target".into(), json!(target));
            if opts.compress {
                v.insert(
                    "extensions".into(),
                    json!({"EXT_meshopt_compression": {
                        "buffer": 0, "byteOffset": stored.0, "byteLength": stored.1,
                        "byteStride": stride, "mode": mode, "count": count,
                    }}),
                );
            }
            Value::Object(v)
        };
        let vview = views.len();
        views.push(view(raw[k].vertex, placed[k].vertex, l.stride, ARRAY_BUFFER, "ATTRIBUTES", p.vertices, true));
        let iview = views.len();
        views.push(view(raw[k].index, placed[k].index, width, ELEMENT_ARRAY_BUFFER, "TRIANGLES", 3 * p.triangles, false));
        let mut attributes = Map::new();
        for (semantic, offset, ctype, ty, normalized) in l.attributes() {
            let mut a = Map::new();
            a.insert("bufferView".into(), json!(vview));
            a.insert("byteOffset".into(), json!(offset));
            a.insert("componentType".into(), json!(ctype));
            if normalized {
                a.insert("normalized".into(), json!(true));
            }
            a.insert("count".into(), json!(p.vertices));
            a.insert("type".into(), json!(ty));
            if semantic == "POSITION" {
                let (lo, hi) = l.pos_bounds(p.lo, p.hi);
                a.insert("min".into(), lo);
                a.insert("max".into(), hi);
            }
            attributes.insert(semantic.into(), json!(accessors.len()));
            accessors.push(Value::Object(a));
        }
        let indices = accessors.len();
        accessors.push(json!({
            "bufferView": iview, "componentType": if width == 2 { UNSIGNED_SHORT } else { UNSIGNED_INT },
            "count": 3 * p.triangles, "type": "SCALAR",
        }));
        primitives.push(json!({"attributes": attributes, "indices": indices, "material": material_of(p.material), "mode": 4}));
    }
    let mut buffer0 = Map::new();
    if let Some(u) = uri {
        buffer0.insert("uri".into(), json!(u));
    }
    buffer0.insert("byteLength".into(), json!(bin_len));
    let mut buffers = vec![Value::Object(buffer0)];
    if opts.compress {
        buffers.push(json!({"byteLength": raw_len, "extensions": {"EXT_meshopt_compression": {"fallback": true}}}));
    }
    let mut node = Map::new();
    node.insert("mesh".into(), json!(0));
    node.insert("translation".into(), json!(l.centre));
    if l.quantize {
        node.insert("scale".into(), json!([l.scale, l.scale, l.scale]));
    }
    let mut mesh = Map::new();
    if let Some(n) = name {
        mesh.insert("name".into(), json!(n));
        node.insert("name".into(), json!(n));
    }
    mesh.insert("primitives".into(), Value::Array(primitives));
    let mut exts = Vec::new();
    if opts.quantize {
        exts.push("KHR_mesh_quantization");
    }
    if opts.compress {
        exts.push("EXT_meshopt_compression");
    }
    let mut doc = Map::new();
    doc.insert("asset".into(), json!({"version": "2.0", "generator": concat!("octolod ", env!("CARGO_PKG_VERSION")), "extras": {MARKER_KEY: MARKER_VALUE}}));
    if !exts.is_empty() {
        doc.insert("extensionsUsed".into(), json!(exts));
        doc.insert("extensionsRequired".into(), json!(exts));
    }
    doc.insert("scene".into(), json!(0));
    doc.insert("scenes".into(), json!([{"nodes": [0]}]));
    doc.insert("nodes".into(), json!([node]));
    doc.insert("meshes".into(), json!([mesh]));
    let mut materials = Vec::new();
    let (mut images, mut textures) = (Vec::new(), Vec::new());
    for (id, t) in &used {
        let Some(t) = t else { continue };
        let mut image = Map::new();
        image.insert("name".into(), json!(t.name));
        match (&t.image, image_at.iter().find(|a| a.0 == *id)) {
            (TextureImage::Uri(u), _) => {
                image.insert("uri".into(), json!(u));
            }
            (TextureImage::Embedded { bytes, mime }, Some(&(_, at))) => {
                image.insert("bufferView".into(), json!(views.len()));
                image.insert("mimeType".into(), json!(mime));
                views.push(json!({"buffer": 0, "byteOffset": at, "byteLength": bytes.len()}));
            }
            (TextureImage::Embedded { .. }, None) => unreachable!("an embedded image is placed in the buffer"),
        }
        let k = images.len();
        images.push(Value::Object(image));
        textures.push(json!({"source": k, "sampler": 0, "name": t.name}));
        let mut m = material(l.attrs.color());
        m["pbrMetallicRoughness"]["baseColorFactor"] = json!([1.0, 1.0, 1.0, 1.0]);
        m["pbrMetallicRoughness"]["baseColorTexture"] = json!({"index": k});
        materials.push(m);
    }
    if materials.len() < used.len() || used.is_empty() {
        materials.push(material(l.attrs.color()));
    }
    if !images.is_empty() {
        doc.insert("images".into(), Value::Array(images));
        // Linear filtering with trilinear mipmaps, repeating (uvs may tile).
        doc.insert("samplers".into(), json!([{"magFilter": 9729, "minFilter": 9987, "wrapS": 10497, "wrapT": 10497}]));
        doc.insert("textures".into(), Value::Array(textures));
    }
    doc.insert("materials".into(), Value::Array(materials));
    doc.insert("accessors".into(), Value::Array(accessors));
    doc.insert("bufferViews".into(), Value::Array(views));
    doc.insert("buffers".into(), Value::Array(buffers));
    Value::Object(doc)
}

/// The texture material `id`'s faces draw, when the mesh has uvs: with
/// per-face materials, slot `id` (none for [`Vertex::NO_TEXTURE`] or a
/// slot without an image); without, the first slot with an image, on
/// every face.
fn texture_of<'a>(opts: &'a GltfOptions, l: &Layout, materials: bool, id: u16) -> Option<&'a GltfTexture> {
    l.uv_at?;
    if materials {
        opts.textures.get(id as usize)?.as_ref()
    } else {
        opts.textures.iter().flatten().next()
    }
}

/// The images to embed (each once), by material id, in material order.
fn embedded_images<'a>(s: &Survey, l: &Layout, opts: &'a GltfOptions) -> Vec<(u16, &'a [u8])> {
    s.materials_used().into_iter().filter_map(|id| Some((id, texture_of(opts, l, s.materials, id)?.embedded()?))).collect()
}

/// An untextured material: not metallic, fully rough, double-sided (why:
/// `docs/web.md`, "glTF output"); white under vertex colours, else octolod's own grey
/// ([`crate::view::DEFAULT_COLOR`], linear), so a mesh without colours
/// looks in any client as it does in `view` and `render`.
fn material(colored: bool) -> Value {
    let base = if colored { [1.0; 3] } else { crate::view::DEFAULT_COLOR.map(|c| srgb_to_linear(c as f64 / 255.0))[..3].try_into().unwrap() };
    json!({
        "pbrMetallicRoughness": {"baseColorFactor": [base[0], base[1], base[2], 1.0], "metallicFactor": 0.0, "roughnessFactor": 1.0},
        "doubleSided": true,
    })
}

/// The JSON chunk's bytes, padded with spaces to a multiple of 4.
fn json_bytes(doc: &Value) -> Vec<u8> {
    let mut b = serde_json::to_vec(doc).expect("JSON of plain values");
    b.resize(align4(b.len() as u64) as usize, b' ');
    b
}

/// The GLB's 12-byte header and its JSON chunk (with both chunk headers'
/// worth of length counted); the BIN chunk of `bin_len` bytes follows.
/// An error naming `.gltf` when the whole would pass 4 GiB.
fn glb_head(json: &[u8], bin_len: u64, what: &str) -> Result<Vec<u8>> {
    let total = glb_total(json.len() as u64, bin_len);
    if total > u32::MAX as u64 {
        return Err(Error::Usage(format!("{what}: the GLB would be {total} bytes, over the format's 4 GiB limit; write a .gltf (JSON + .bin) instead")));
    }
    let mut h = Vec::with_capacity(28 + json.len());
    h.extend_from_slice(GLB_MAGIC);
    h.extend_from_slice(&2u32.to_le_bytes());
    h.extend_from_slice(&(total as u32).to_le_bytes());
    h.extend_from_slice(&(json.len() as u32).to_le_bytes());
    h.extend_from_slice(CHUNK_JSON);
    h.extend_from_slice(json);
    h.extend_from_slice(&(align4(bin_len) as u32).to_le_bytes());
    h.extend_from_slice(CHUNK_BIN);
    Ok(h)
}

fn glb_total(json_len: u64, bin_len: u64) -> u64 {
    12 + 8 + align4(json_len) + 8 + align4(bin_len)
}

// ------------------------------------------------------------- in memory

/// Encodes one mesh as a complete GLB (one scene, one node, one mesh: one
/// triangle primitive per material).
pub fn encode_glb(mesh: &IndexedMesh, attrs: AttrSet, opts: &GltfOptions, out: &mut Vec<u8>) -> Result<()> {
    let mut s = Survey::new(u64::MAX, attrs);
    s.add(mesh)?;
    if s.triangles == 0 {
        return Err(empty("the mesh"));
    }
    let l = Layout::new(attrs, opts, &s);
    let mut bin = Counted { w: Vec::new(), at: 0 };
    let placed = write_bin(&mut bin, Path::new("glb"), &s, &l, opts.compress, std::iter::once(Ok(mesh)))?;
    let image_at = put_images(&mut bin, Path::new("glb"), &embedded_images(&s, &l, opts))?;
    let doc = document(&s, &l, opts, None, &placed, bin.at, None, &image_at);
    let head = glb_head(&json_bytes(&doc), bin.at, "the mesh")?;
    out.reserve(head.len() + bin.w.len());
    out.extend_from_slice(&head);
    out.extend_from_slice(&bin.w);
    Ok(())
}

/// Where the embedded images will start when the geometry ends at
/// `geometry`, and where the buffer then ends ([`put_images`]' layout).
fn image_layout(images: &[(u16, &[u8])], geometry: u64) -> (Vec<(u16, u64)>, u64) {
    let mut at = geometry;
    let mut out = Vec::with_capacity(images.len());
    for (id, img) in images {
        at = align4(at);
        out.push((*id, at));
        at += img.len() as u64;
    }
    (out, if images.is_empty() { geometry } else { align4(at) })
}

/// Appends the embedded images behind the geometry, each starting at a
/// multiple of 4 and the buffer padded to one (a GLB's BIN chunk is);
/// gives where each starts, by material id.
fn put_images<W: Write>(bin: &mut Counted<W>, path: &Path, images: &[(u16, &[u8])]) -> Result<Vec<(u16, u64)>> {
    let mut out = Vec::with_capacity(images.len());
    for (id, img) in images {
        bin.pad4().ctx(path, "write")?;
        out.push((*id, bin.at));
        bin.put(img).ctx(path, "write")?;
    }
    bin.pad4().ctx(path, "write")?;
    Ok(out)
}

fn empty(what: &str) -> Error {
    Error::Usage(format!("{what} has no triangles: a glTF needs at least one (nothing written)"))
}

// ----------------------------------------------------------------- to files

/// Writes one mesh at `out` (`.glb`, or `.gltf` with its `.bin`) as one
/// primitive; `name` names the mesh and node. Gives (vertices, triangles).
pub fn write_mesh(out: &Path, mesh: &IndexedMesh, attrs: AttrSet, opts: &GltfOptions, force: bool, name: &str) -> Result<(u64, u64)> {
    write_parts(out, attrs, opts, force, name, u64::MAX, || std::iter::once(Ok(mesh)))
}

/// Writes the meshes `parts()` gives (called twice, each time giving the
/// same parts in the same order) as one glTF at `out`: one primitive per
/// run of whole parts holding at most `group_vertices` vertices, so only
/// one run is in memory at a time (parts without triangles are left out).
/// `out` is checked first ([`check_output`]); every file is written under
/// a temporary name and moved into place when complete (for `.gltf`, both
/// files once both are written, the `.bin` first: [`AtomicGltfPair`]).
/// Gives the vertices and triangles written.
pub fn write_parts<M, I, F>(out: &Path, attrs: AttrSet, opts: &GltfOptions, force: bool, name: &str, group_vertices: u64, mut parts: F) -> Result<(u64, u64)>
where
    M: Borrow<IndexedMesh>,
    I: Iterator<Item = Result<M>>,
    F: FnMut() -> I,
{
    let container = Container::of(out).ok_or_else(|| Error::Usage(format!("{}: a glTF output ends in .glb or .gltf", out.display())))?;
    check_output(out, force)?;
    let mut s = Survey::new(group_vertices, attrs);
    for m in parts() {
        s.add(m?.borrow())?;
    }
    if s.triangles == 0 {
        return Err(empty(&format!("{}: the cut", out.display())));
    }
    let l = Layout::new(attrs, opts, &s);
    let what = out.display().to_string();
    match container {
        Container::Glb if !opts.compress => {
            // Every length is known from the counts: the JSON first, then
            // the buffer streamed straight behind it.
            let mut file = AtomicFile::create(out, OutputKind::Gltf, force)?;
            let (raw, geometry) = raw_layout(&s, &l);
            let images = embedded_images(&s, &l, opts);
            let (image_at, len) = image_layout(&images, geometry);
            let head = glb_head(&json_bytes(&document(&s, &l, opts, Some(name), &raw, len, None, &image_at)), len, &what)?;
            file.writer().write_all(&head).ctx(out, "write")?;
            let mut bin = Counted { w: file.writer(), at: 0 };
            let placed = write_bin(&mut bin, out, &s, &l, false, parts())?;
            if bin.at != geometry || placed != raw || put_images(&mut bin, out, &images)? != image_at || bin.at != len {
                return Err(Error::Usage(format!("{what}: the buffer's size changed while it was written")));
            }
            file.commit()?;
        }
        Container::Glb => {
            // Compressed lengths are known only once compressed: the buffer
            // goes to a scratch file, then behind the JSON.
            let mut file = AtomicFile::create(out, OutputKind::Gltf, force)?;
            let scratch = crate::io::scratch_dir(out)?;
            let spool = scratch.path().join("buffer.bin");
            let f = File::create(&spool).ctx(&spool, "create")?;
            let mut bin = Counted { w: BufWriter::with_capacity(crate::io::SEQ_BUF, f), at: 0 };
            let placed = write_bin(&mut bin, &spool, &s, &l, true, parts())?;
            let image_at = put_images(&mut bin, &spool, &embedded_images(&s, &l, opts))?;
            let len = bin.at;
            drop(bin.w.into_inner().map_err(|e| e.into_error()).ctx(&spool, "write")?);
            let head = glb_head(&json_bytes(&document(&s, &l, opts, Some(name), &placed, len, None, &image_at)), len, &what)?;
            let w = file.writer();
            w.write_all(&head).ctx(out, "write")?;
            let mut f = File::open(&spool).ctx(&spool, "open")?;
            let copied = std::io::copy(&mut f, w).ctx(out, "write")?;
            if copied != len {
                return Err(Error::Usage(format!("{}: scratch buffer truncated", spool.display())));
            }
            drop(f);
            fs::remove_file(&spool).ctx(&spool, "remove")?;
            drop(scratch);
            file.commit()?;
        }
        Container::Gltf => {
            let mut pair = AtomicGltfPair::create(out, force)?;
            let bin_path = pair.bin_dest().to_path_buf();
            let mut bin = Counted { w: pair.bin(), at: 0 };
            let placed = write_bin(&mut bin, &bin_path, &s, &l, opts.compress, parts())?;
            let image_at = put_images(&mut bin, &bin_path, &embedded_images(&s, &l, opts))?;
            let len = bin.at;
            let uri = uri_of(&bin_path);
            let doc = document(&s, &l, opts, Some(name), &placed, len, Some(&uri), &image_at);
            let mut text = serde_json::to_vec_pretty(&doc).expect("JSON of plain values");
            text.push(b'\n');
            pair.json().write_all(&text).ctx(out, "write")?;
            pair.commit()?;
        }
    }
    Ok((s.vertices, s.triangles))
}

/// The `.bin` beside a `.gltf` ([`crate::io::gltf_bin_path`]).
pub fn bin_path(gltf: &Path) -> PathBuf {
    crate::io::gltf_bin_path(gltf)
}

/// A file name as a relative URI reference (percent-encoded but for
/// unreserved characters).
fn uri_of(p: &Path) -> String {
    use std::os::unix::ffi::OsStrExt;
    let name = p.file_name().map(|n| n.as_bytes()).unwrap_or(b"");
    let mut s = String::new();
    for &b in name {
        if b.is_ascii_alphanumeric() || b"-._~".contains(&b) {
            s.push(b as char);
        } else {
            s.push_str(&format!("%{b:02X}"));
        }
    }
    s
}

/// Refuses `out` unless it is free, or (with `force`) a glTF octolod wrote
/// and no input of the command; for a `.gltf`, also its `.bin`, which may
/// be replaced only when that glTF is octolod's and names it. Call before
/// any work (it is checked again as the files are moved into place). The
/// rules are [`crate::io::check_output`]'s for [`OutputKind::Gltf`].
pub fn check_output(out: &Path, force: bool) -> Result<()> {
    crate::io::check_output(out, OutputKind::Gltf, force)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tri() -> IndexedMesh {
        let v = |x: f64, y: f64| Vertex { pos: [x, y, 0.0], normal: [0.0, 0.0, 2.0], color: [1, 2, 3, 4], uv: [x as f32, y as f32], material: 0 };
        IndexedMesh { vertices: vec![v(0.0, 0.0), v(1.0, 0.0), v(0.0, 1.0)], triangles: vec![[0, 1, 2]] }
    }

    #[test]
    fn strides_and_attribute_offsets_are_multiples_of_four() {
        let mut s = Survey::new(u64::MAX, AttrSet(0));
        s.add(&tri()).unwrap();
        for bits in 0..64 {
            let Some(attrs) = AttrSet::from_bits(bits) else { continue };
            for quantize in [false, true] {
                let l = Layout::new(attrs, &GltfOptions { quantize, ..Default::default() }, &s);
                assert_eq!(l.stride % 4, 0);
                assert!(l.stride <= 48);
                assert!(l.attributes().iter().all(|a| a.1 % 4 == 0));
            }
        }
    }

    #[test]
    fn the_glb_size_limit_names_gltf() {
        assert!(glb_head(b"{}  ", u32::MAX as u64 - 40, "x").is_ok());
        let e = glb_head(b"{}  ", u32::MAX as u64, "x.glb").unwrap_err().to_string();
        assert!(e.contains("4 GiB") && e.contains(".gltf"), "{e}");
    }

    #[test]
    fn uris_are_percent_encoded() {
        assert_eq!(uri_of(Path::new("/a/b c#1%.bin")), "b%20c%231%25.bin");
        assert_eq!(uri_of(Path::new("x-y_z~.bin")), "x-y_z~.bin");
    }

    #[test]
    fn empty_and_broken_meshes_are_errors() {
        let mut out = Vec::new();
        assert!(encode_glb(&IndexedMesh::default(), AttrSet(0), &GltfOptions::default(), &mut out).is_err());
        let mut m = tri();
        m.triangles[0][2] = 3;
        assert!(encode_glb(&m, AttrSet(0), &GltfOptions::default(), &mut out).is_err());
        assert!(out.is_empty());
        encode_glb(&tri(), AttrSet(0), &GltfOptions::default(), &mut out).unwrap();
        assert_eq!(&out[..4], b"glTF");
        assert_eq!(u32::from_le_bytes(out[8..12].try_into().unwrap()) as usize, out.len());
    }

    /// A strip of 12 triangles, each with its own three vertices (so
    /// materials never share one), triangle k of material `mats[k]`.
    fn strip(mats: &[u16]) -> IndexedMesh {
        let mut m = IndexedMesh::default();
        for (k, &mat) in mats.iter().enumerate() {
            let x = k as f64;
            for (p, uv) in [([x, 0.0, 0.5 * x], [0.1, 0.2]), ([x + 1.0, 0.0, 0.0], [0.9, 0.2]), ([x, 1.0, 0.25], [0.1, 0.8])] {
                m.vertices.push(Vertex { pos: p, normal: [0.0, 0.0, 1.0], color: [9, 8, 7, 255], uv, material: mat });
            }
            let b = 3 * k as u32;
            m.triangles.push([b, b + 1, b + 2]);
        }
        m
    }

    /// The JSON and BIN chunks of a GLB.
    fn chunks(glb: &[u8]) -> (Value, Vec<u8>) {
        let u = |k: usize| u32::from_le_bytes(glb[k..k + 4].try_into().unwrap()) as usize;
        assert_eq!(&glb[..4], b"glTF");
        assert_eq!(u(8), glb.len());
        let jl = u(12);
        let json = serde_json::from_slice(&glb[20..20 + jl]).unwrap();
        let bl = u(20 + jl);
        (json, glb[28 + jl..28 + jl + bl].to_vec())
    }

    fn png(tag: u8) -> GltfTexture {
        let mut bytes = b"\x89PNG\r\n\x1a\n".to_vec();
        bytes.extend(std::iter::repeat_n(tag, 5 + tag as usize));
        GltfTexture { name: format!("img{tag}"), image: TextureImage::Embedded { bytes: std::sync::Arc::new(bytes), mime: "image/png" } }
    }

    const T: u16 = Vertex::NO_TEXTURE;
    /// 5 triangles of material 0, 3 of 2, 4 untextured, interleaved.
    const MATS: [u16; 12] = [0, 2, T, 0, 0, T, 2, T, 0, 2, T, 0];
    const UVM: u32 = AttrSet::UV | AttrSet::NORMAL | AttrSet::COLOR | AttrSet::MATERIAL;

    /// Slots 0 and 2 have images, 1 has none, 3's is used by no face.
    fn slots() -> GltfOptions {
        GltfOptions { textures: vec![Some(png(1)), None, Some(png(2)), Some(png(3))], ..Default::default() }
    }

    /// Checks a GLB of [`MATS`] drawn with [`slots`]: a primitive per
    /// material, in material order, with its triangles' indices; each
    /// textured material's image is its slot's, written once; the
    /// untextured one has no texture. Gives the JSON.
    fn check_materials(glb: &[u8], compressed: bool) -> Value {
        let (j, bin) = chunks(glb);
        let prims = j["meshes"][0]["primitives"].as_array().unwrap();
        assert_eq!(prims.len(), 3);
        let want = [(0u16, 5u64), (2, 3), (T, 4)];
        let opts = slots();
        for (p, (mat, tris)) in prims.iter().zip(want) {
            let ind = &j["accessors"][p["indices"].as_u64().unwrap() as usize];
            assert_eq!(ind["count"], 3 * tris, "material {mat}");
            // Its own vertices: the ones its triangles use.
            assert_eq!(j["accessors"][p["attributes"]["POSITION"].as_u64().unwrap() as usize]["count"], 3 * tris);
            let m = &j["materials"][p["material"].as_u64().unwrap() as usize]["pbrMetallicRoughness"];
            if mat == T {
                assert!(m.get("baseColorTexture").is_none(), "{m}");
                continue;
            }
            let tex = &j["textures"][m["baseColorTexture"]["index"].as_u64().unwrap() as usize];
            let img = &j["images"][tex["source"].as_u64().unwrap() as usize];
            let want = opts.textures[mat as usize].as_ref().unwrap();
            assert_eq!(img["name"], want.name.as_str());
            let view = &j["bufferViews"][img["bufferView"].as_u64().unwrap() as usize];
            let (at, len) = (view["byteOffset"].as_u64().unwrap() as usize, view["byteLength"].as_u64().unwrap() as usize);
            assert_eq!(&bin[at..at + len], want.embedded().unwrap(), "material {mat}'s image");
        }
        assert_eq!(j["materials"].as_array().unwrap().len(), 3);
        assert_eq!(j["images"].as_array().unwrap().len(), 2, "each used image once, the unused slot's not at all");
        assert_eq!(j["textures"].as_array().unwrap().len(), 2);
        let unused = png(3);
        assert!(!bin.windows(unused.embedded().unwrap().len()).any(|w| w == unused.embedded().unwrap()));
        let views = j["bufferViews"].as_array().unwrap();
        assert_eq!(views.len(), 3 * 2 + 2, "a vertex and an index view per primitive, one per image");
        assert_eq!(views.iter().filter(|v| v.get("extensions").is_some()).count(), if compressed { 6 } else { 0 });
        j
    }

    /// The reader's triangles (corner positions, rotated to start at the
    /// smallest x) in the file's order.
    fn read_back(path: &Path) -> Vec<[[i64; 3]; 3]> {
        let (_, sink, _) = crate::input::read_all(path, 1 << 26).unwrap();
        sink.triangles.iter().map(|t| rotated(t.map(|i| sink.vertices[i as usize].pos))).collect()
    }

    fn rotated(t: [[f64; 3]; 3]) -> [[i64; 3]; 3] {
        let q = t.map(|p| p.map(|x| (x * 1000.0).round() as i64));
        let k = (0..3).min_by_key(|&k| q[k]).unwrap();
        [q[k], q[(k + 1) % 3], q[(k + 2) % 3]]
    }

    #[test]
    fn each_material_is_a_primitive_drawing_its_own_texture() {
        let m = strip(&MATS);
        let dir = tempfile::tempdir().unwrap();
        // The triangles in material order, as the primitives hold them.
        let mut want: Vec<(u16, [[i64; 3]; 3])> =
            m.triangles.iter().map(|t| (m.vertices[t[0] as usize].material, rotated(t.map(|i| m.vertices[i as usize].pos)))).collect();
        want.sort_by_key(|w| w.0);
        let want: Vec<[[i64; 3]; 3]> = want.into_iter().map(|w| w.1).collect();
        for (quantize, compress) in [(false, false), (true, true), (false, true), (true, false)] {
            let opts = GltfOptions { quantize, compress, ..slots() };
            let mut glb = Vec::new();
            encode_glb(&m, AttrSet(UVM), &opts, &mut glb).unwrap();
            let j = check_materials(&glb, compress);
            assert_eq!(j["extensionsUsed"].as_array().map_or(0, |e| e.len()), quantize as usize + compress as usize);
            // octolod's reader decodes it (meshopt too): every triangle, in
            // the primitives' order, at its place.
            let p = dir.path().join(format!("m-{quantize}-{compress}.glb"));
            std::fs::write(&p, &glb).unwrap();
            assert_eq!(read_back(&p), want, "quantize {quantize}, compress {compress}");
            // Written to files the same way, whichever path writes them.
            for ext in ["glb", "gltf"] {
                let out = dir.path().join(format!("w-{quantize}-{compress}.{ext}"));
                assert_eq!(write_mesh(&out, &m, AttrSet(UVM), &opts, false, "m").unwrap(), (36, 12));
                assert_eq!(read_back(&out), want, "{}", out.display());
                if ext == "glb" {
                    check_materials(&std::fs::read(&out).unwrap(), compress);
                }
            }
        }
    }

    #[test]
    fn a_streamed_run_of_parts_merges_each_materials_triangles() {
        let dir = tempfile::tempdir().unwrap();
        let a = strip(&MATS[..6]);
        let b = strip(&MATS[6..]);
        for compress in [false, true] {
            let out = dir.path().join(format!("s-{compress}.glb"));
            let opts = GltfOptions { compress, ..slots() };
            // One run: the two parts' triangles of each material together.
            write_parts(&out, AttrSet(UVM), &opts, false, "s", u64::MAX, || [Ok(&a), Ok(&b)].into_iter()).unwrap();
            check_materials(&std::fs::read(&out).unwrap(), compress);
            // A run per part: each its own primitives, images still once.
            let out = dir.path().join(format!("r-{compress}.glb"));
            write_parts(&out, AttrSet(UVM), &opts, false, "s", 18, || [Ok(&a), Ok(&b)].into_iter()).unwrap();
            let (j, _) = chunks(&std::fs::read(&out).unwrap());
            let prims = j["meshes"][0]["primitives"].as_array().unwrap();
            let counts: Vec<u64> = prims.iter().map(|p| j["accessors"][p["indices"].as_u64().unwrap() as usize]["count"].as_u64().unwrap() / 3).collect();
            // Part a: 0 ×3, 2 ×1, untextured ×2; part b: 0 ×2, 2 ×2, untextured ×2.
            assert_eq!(counts, [3, 1, 2, 2, 2, 2]);
            let mats: Vec<u64> = prims.iter().map(|p| p["material"].as_u64().unwrap()).collect();
            assert_eq!(mats, [0, 1, 2, 0, 1, 2]);
            assert_eq!(j["images"].as_array().unwrap().len(), 2);
        }
    }

    #[test]
    fn without_materials_every_face_draws_the_first_image() {
        let mut m = strip(&MATS);
        // Material ids are not read without MATERIAL.
        let attrs = AttrSet(UVM & !AttrSet::MATERIAL);
        let opts = GltfOptions { textures: vec![None, Some(png(2)), Some(png(3))], ..Default::default() };
        let mut glb = Vec::new();
        encode_glb(&m, attrs, &opts, &mut glb).unwrap();
        let (j, _) = chunks(&glb);
        assert_eq!(j["meshes"][0]["primitives"].as_array().unwrap().len(), 1);
        assert_eq!(j["images"].as_array().unwrap().len(), 1);
        assert_eq!(j["images"][0]["name"], "img2");
        assert_eq!(j["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"]["index"], 0);
        // Nor without uvs, any texture; nor with no textures.
        for (attrs, opts) in [(AttrSet(AttrSet::MATERIAL), slots()), (AttrSet(UVM), GltfOptions::default())] {
            glb.clear();
            encode_glb(&m, attrs, &opts, &mut glb).unwrap();
            let (j, _) = chunks(&glb);
            assert!(j.get("images").is_none() && j.get("textures").is_none() && j.get("samplers").is_none());
            assert_eq!(j["materials"].as_array().unwrap().len(), 1);
            let n = j["meshes"][0]["primitives"].as_array().unwrap().len();
            assert_eq!(n, 3, "primitives stay per material even when all draw untextured");
        }
        // One material everywhere: one primitive, every vertex kept in order.
        for v in &mut m.vertices {
            v.material = 2;
        }
        m.vertices.push(m.vertices[0]);
        glb.clear();
        encode_glb(&m, AttrSet(UVM), &slots(), &mut glb).unwrap();
        let (j, _) = chunks(&glb);
        assert_eq!(j["meshes"][0]["primitives"].as_array().unwrap().len(), 1);
        assert_eq!(j["accessors"][0]["count"], 37, "an unused vertex is kept when the part has one material");
        assert_eq!(j["images"][0]["name"], "img2");
    }
}

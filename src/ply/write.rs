//! Streaming PLY writer: vertices and polygons in, a PLY file out, with the
//! mesh never held in memory.
//!
//! Takes: [`PlyWriteOptions`] (encoding, which vertex attributes, their PLY
//! types and names, comments, face index type), the element counts up front,
//! then each vertex and each face in order. Gives: a PLY header and body on
//! any [`Write`]; [`PlyWriter::finish`] checks that exactly the announced
//! number of vertices and faces were written. [`write_ply`] and
//! [`write_ply_polygons`] write a whole in-memory mesh atomically
//! ([`AtomicFile`]).
//!
//! Vertex properties, in order: `x`, (`quality` when
//! [`PlyWriteOptions::extra_vertex_quality`], to exercise readers), `y`, `z`
//! (`double` with [`AttrSet::POS_F64`], else `float`), `nx ny nz` (`float`),
//! `red green blue [alpha]` (`uchar`, or `float` in \[0,1\] with
//! [`PlyWriteOptions::float_colors`]), then the texture coordinates (`float`,
//! named per [`UvNames`]). Faces are `property list uchar <index> vertex_indices`,
//! then, with [`AttrSet::MATERIAL`], `property int texnumber` (MeshLab's
//! convention: the index of the face's `comment TextureFile` texture, -1
//! for [`Vertex::NO_TEXTURE`]); the material is not a vertex property.
//! Such faces are written with [`PlyWriter::face_material`] (a face's
//! material is its corner 0's); [`write_ply`] takes it from the vertices.
//!
//! Binary records are encoded into byte buffers ([`PlyEncoder`], which is
//! `Sync` so callers can encode chunks in parallel and hand the bytes over with
//! [`PlyWriter::raw_vertices`] / [`PlyWriter::raw_faces`]). ASCII floats use
//! Rust's shortest round-trip formatting, so they read back bit-exactly.

use super::{Encoding, Scalar};
use crate::error::{IoContext, Result};
use crate::io::{AtomicFile, OutputKind};
use crate::mesh::{AttrSet, Vertex};
use std::io::{self, Write};
use std::path::Path;

/// Names of the texture-coordinate properties.
#[allow(clippy::upper_case_acronyms)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum UvNames {
    /// `u`, `v`
    #[default]
    UV,
    /// `s`, `t`
    ST,
    /// `texture_u`, `texture_v`
    TextureUV,
}

impl UvNames {
    pub fn names(self) -> [&'static str; 2] {
        match self {
            UvNames::UV => ["u", "v"],
            UvNames::ST => ["s", "t"],
            UvNames::TextureUV => ["texture_u", "texture_v"],
        }
    }
}

/// What to write and how.
#[derive(Clone, Debug, PartialEq)]
pub struct PlyWriteOptions {
    pub encoding: Encoding,
    /// Vertex attributes written; `POS_F64` writes `double` positions.
    pub attrs: AttrSet,
    /// Colors as `float` in \[0,1\] instead of `uchar`.
    pub float_colors: bool,
    pub uv_names: UvNames,
    /// Item type of the face index list (`int` by default). Float types are
    /// accepted (to produce files readers must reject); counts are `uchar`.
    pub index_type: Scalar,
    pub comments: Vec<String>,
    /// Adds a `float quality` property (value 0.5) between `x` and `y`.
    pub extra_vertex_quality: bool,
}

impl Default for PlyWriteOptions {
    fn default() -> Self {
        PlyWriteOptions {
            encoding: Encoding::BinaryLe,
            attrs: AttrSet::POSITION_ONLY,
            float_colors: false,
            uv_names: UvNames::UV,
            index_type: Scalar::I32,
            comments: Vec::new(),
            extra_vertex_quality: false,
        }
    }
}

/// The complete header text (ending with `end_header\n`) for these options and counts.
pub fn header(opts: &PlyWriteOptions, n_vertices: u64, n_faces: u64) -> String {
    use std::fmt::Write as _;
    let a = opts.attrs;
    let mut h = String::with_capacity(512);
    h.push_str("ply\n");
    let _ = writeln!(h, "format {} 1.0", opts.encoding.header_name());
    // Marks the file as ours, so `--force` may replace it later: exactly
    // this line (see `io::OutputKind::recognise`).
    let _ = writeln!(h, "comment {}", crate::io::PLY_MARK);
    for c in opts.comments.iter().filter(|c| c.as_str() != crate::io::PLY_MARK) {
        let _ = writeln!(h, "comment {}", c.replace(['\n', '\r'], " "));
    }
    let _ = writeln!(h, "element vertex {n_vertices}");
    let pt = if a.pos_f64() { "double" } else { "float" };
    let _ = writeln!(h, "property {pt} x");
    if opts.extra_vertex_quality {
        h.push_str("property float quality\n");
    }
    let _ = writeln!(h, "property {pt} y");
    let _ = writeln!(h, "property {pt} z");
    if a.normal() {
        h.push_str("property float nx\nproperty float ny\nproperty float nz\n");
    }
    if a.color() {
        let ct = if opts.float_colors { "float" } else { "uchar" };
        for c in ["red", "green", "blue"] {
            let _ = writeln!(h, "property {ct} {c}");
        }
        if a.alpha() {
            let _ = writeln!(h, "property {ct} alpha");
        }
    }
    if a.uv() {
        for n in opts.uv_names.names() {
            let _ = writeln!(h, "property float {n}");
        }
    }
    let _ = writeln!(h, "element face {n_faces}");
    let _ = writeln!(h, "property list uchar {} vertex_indices", opts.index_type.name());
    if a.material() {
        h.push_str("property int texnumber\n");
    }
    h.push_str("end_header\n");
    h
}

/// Encodes vertex and face records into byte buffers. Cheap to clone, `Sync`:
/// encode chunks on several threads, then write them in order.
#[derive(Clone, Debug)]
pub struct PlyEncoder {
    encoding: Encoding,
    attrs: AttrSet,
    float_colors: bool,
    quality: bool,
    index: Scalar,
    vertex_size: usize,
    /// Faces end with an `int texnumber`.
    material: bool,
}

fn invalid_data(msg: String) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidData, msg)
}

impl PlyEncoder {
    pub fn new(opts: &PlyWriteOptions) -> PlyEncoder {
        let a = opts.attrs;
        let vertex_size = if a.pos_f64() { 24 } else { 12 }
            + if opts.extra_vertex_quality { 4 } else { 0 }
            + if a.normal() { 12 } else { 0 }
            + if a.color() { (3 + a.alpha() as usize) * if opts.float_colors { 4 } else { 1 } } else { 0 }
            + if a.uv() { 8 } else { 0 };
        PlyEncoder {
            encoding: opts.encoding,
            attrs: a,
            float_colors: opts.float_colors,
            quality: opts.extra_vertex_quality,
            index: opts.index_type,
            vertex_size,
            material: a.material(),
        }
    }

    pub fn encoding(&self) -> Encoding {
        self.encoding
    }

    /// Bytes per binary vertex record (None for ASCII).
    pub fn vertex_record_size(&self) -> Option<usize> {
        (self.encoding != Encoding::Ascii).then_some(self.vertex_size)
    }

    /// Bytes per binary face record of `n` indices (None for ASCII).
    pub fn face_record_size(&self, n: usize) -> Option<usize> {
        (self.encoding != Encoding::Ascii).then_some(1 + n * self.index.size() + 4 * self.material as usize)
    }

    /// A rough upper estimate of one vertex record's size, for sizing buffers.
    pub fn approx_vertex_size(&self) -> usize {
        match self.encoding {
            Encoding::Ascii => {
                let fields = 3 + self.quality as usize + 3 * self.attrs.normal() as usize + 2 * self.attrs.uv() as usize;
                let colors = if self.attrs.color() { 3 + self.attrs.alpha() as usize } else { 0 };
                let fw = if self.attrs.pos_f64() { 20 } else { 12 };
                fields * fw + colors * if self.float_colors { 12 } else { 4 }
            }
            _ => self.vertex_size,
        }
    }

    /// A rough upper estimate of one triangle record's size.
    pub fn approx_face_size(&self) -> usize {
        match self.encoding {
            Encoding::Ascii => 2 + 3 * 11 + 7 * self.material as usize,
            _ => 1 + 3 * self.index.size() + 4 * self.material as usize,
        }
    }

    /// Appends one vertex record to `out`.
    #[inline]
    pub fn vertex(&self, v: &Vertex, out: &mut Vec<u8>) {
        if self.encoding == Encoding::Ascii {
            self.vertex_ascii(v, out);
            return;
        }
        let be = self.encoding == Encoding::BinaryBe;
        let a = self.attrs;
        let mut rec = [0u8; 64];
        let mut at = 0usize;
        macro_rules! put {
            ($x:expr) => {{
                let b = if be { $x.to_be_bytes() } else { $x.to_le_bytes() };
                rec[at..at + b.len()].copy_from_slice(&b);
                at += b.len();
            }};
        }
        if a.pos_f64() {
            put!(v.pos[0]);
            if self.quality {
                put!(0.5f32);
            }
            put!(v.pos[1]);
            put!(v.pos[2]);
        } else {
            put!(v.pos[0] as f32);
            if self.quality {
                put!(0.5f32);
            }
            put!(v.pos[1] as f32);
            put!(v.pos[2] as f32);
        }
        if a.normal() {
            put!(v.normal[0]);
            put!(v.normal[1]);
            put!(v.normal[2]);
        }
        if a.color() {
            let n = 3 + a.alpha() as usize;
            if self.float_colors {
                for k in 0..n {
                    put!(v.color[k] as f32 / 255.0);
                }
            } else {
                rec[at..at + n].copy_from_slice(&v.color[..n]);
                at += n;
            }
        }
        if a.uv() {
            put!(v.uv[0]);
            put!(v.uv[1]);
        }
        debug_assert_eq!(at, self.vertex_size);
        out.extend_from_slice(&rec[..at]);
    }

    fn vertex_ascii(&self, v: &Vertex, out: &mut Vec<u8>) {
        let a = self.attrs;
        // Writes into a Vec never fail.
        if a.pos_f64() {
            let _ = write!(out, "{}", v.pos[0]);
            if self.quality {
                out.extend_from_slice(b" 0.5");
            }
            let _ = write!(out, " {} {}", v.pos[1], v.pos[2]);
        } else {
            let _ = write!(out, "{}", v.pos[0] as f32);
            if self.quality {
                out.extend_from_slice(b" 0.5");
            }
            let _ = write!(out, " {} {}", v.pos[1] as f32, v.pos[2] as f32);
        }
        if a.normal() {
            let _ = write!(out, " {} {} {}", v.normal[0], v.normal[1], v.normal[2]);
        }
        if a.color() {
            for k in 0..3 + a.alpha() as usize {
                if self.float_colors {
                    let _ = write!(out, " {}", v.color[k] as f32 / 255.0);
                } else {
                    let _ = write!(out, " {}", v.color[k]);
                }
            }
        }
        if a.uv() {
            let _ = write!(out, " {} {}", v.uv[0], v.uv[1]);
        }
        out.push(b'\n');
    }

    /// Appends one face record (a polygon of 1..=255 indices) to `out`. Fails
    /// with `InvalidInput` for an empty or too long polygon, and for a
    /// face of a mesh with materials (those need
    /// [`PlyEncoder::face_material`]), and `InvalidData` for an index the
    /// index type cannot hold; `out` is unchanged then.
    #[inline]
    pub fn face(&self, idx: &[u32], out: &mut Vec<u8>) -> io::Result<()> {
        if self.material {
            return Err(io::Error::new(io::ErrorKind::InvalidInput, "a face of a mesh with materials needs its material (face_material)"));
        }
        self.face_record(idx, 0, out)
    }

    /// [`PlyEncoder::face`] of a face whose material is `material` (its
    /// `texnumber`, -1 for [`Vertex::NO_TEXTURE`]; ignored without
    /// [`AttrSet::MATERIAL`]).
    #[inline]
    pub fn face_material(&self, idx: &[u32], material: u16, out: &mut Vec<u8>) -> io::Result<()> {
        self.face_record(idx, material, out)
    }

    fn face_record(&self, idx: &[u32], material: u16, out: &mut Vec<u8>) -> io::Result<()> {
        let texnumber: i32 = if material == Vertex::NO_TEXTURE { -1 } else { material as i32 };
        let be = self.encoding == Encoding::BinaryBe;
        let n = idx.len();
        if n == 0 || n > 255 {
            return Err(io::Error::new(io::ErrorKind::InvalidInput, format!("a face has {n} vertices; PLY lists with uchar counts hold 1..=255")));
        }
        // Fast path: triangles with 32-bit integer indices.
        if n == 3 && self.encoding != Encoding::Ascii && matches!(self.index, Scalar::I32 | Scalar::U32) {
            if self.index == Scalar::I32 && idx.iter().any(|&i| i > i32::MAX as u32) {
                return Err(self.range_error(idx));
            }
            let mut rec = [3u8; 17];
            for k in 0..3 {
                let b = if be { idx[k].to_be_bytes() } else { idx[k].to_le_bytes() };
                rec[1 + 4 * k..5 + 4 * k].copy_from_slice(&b);
            }
            rec[13..].copy_from_slice(&if be { texnumber.to_be_bytes() } else { texnumber.to_le_bytes() });
            out.extend_from_slice(&rec[..13 + 4 * self.material as usize]);
            return Ok(());
        }
        let max: u64 = match self.index {
            Scalar::I8 => i8::MAX as u64,
            Scalar::U8 => u8::MAX as u64,
            Scalar::I16 => i16::MAX as u64,
            Scalar::U16 => u16::MAX as u64,
            Scalar::I32 => i32::MAX as u64,
            Scalar::U32 => u32::MAX as u64,
            Scalar::F32 => 1 << 24,
            Scalar::F64 => u32::MAX as u64,
        };
        if idx.iter().any(|&i| i as u64 > max) {
            return Err(self.range_error(idx));
        }
        if self.encoding == Encoding::Ascii {
            let _ = write!(out, "{n}");
            for &i in idx {
                let _ = write!(out, " {i}");
            }
            if self.material {
                let _ = write!(out, " {texnumber}");
            }
            out.push(b'\n');
            return Ok(());
        }
        out.reserve(1 + n * self.index.size() + 4);
        out.push(n as u8);
        macro_rules! put {
            ($x:expr) => {{
                let x = $x;
                out.extend_from_slice(&if be { x.to_be_bytes() } else { x.to_le_bytes() });
            }};
        }
        for &i in idx {
            match self.index {
                Scalar::I8 => put!(i as i8),
                Scalar::U8 => put!(i as u8),
                Scalar::I16 => put!(i as i16),
                Scalar::U16 => put!(i as u16),
                Scalar::I32 => put!(i as i32),
                Scalar::U32 => put!(i),
                Scalar::F32 => put!(i as f32),
                Scalar::F64 => put!(i as f64),
            }
        }
        if self.material {
            put!(texnumber);
        }
        Ok(())
    }

    fn range_error(&self, idx: &[u32]) -> io::Error {
        let m = idx.iter().max().copied().unwrap_or(0);
        invalid_data(format!("vertex index {m} does not fit the face index type '{}'", self.index.name()))
    }
}

/// Flush the internal buffer to the sink once it holds this much.
const FLUSH_AT: usize = 1 << 18;

/// Streams one PLY: header at construction, then vertices, then faces.
pub struct PlyWriter<W: Write> {
    w: W,
    enc: PlyEncoder,
    buf: Vec<u8>,
    n_vertices: u64,
    n_faces: u64,
    vertices: u64,
    faces: u64,
    bytes: u64,
}

impl<W: Write> PlyWriter<W> {
    /// Writes the header for `n_vertices` vertices and `n_faces` faces.
    pub fn new(mut w: W, opts: &PlyWriteOptions, n_vertices: u64, n_faces: u64) -> io::Result<Self> {
        let h = header(opts, n_vertices, n_faces);
        w.write_all(h.as_bytes())?;
        Ok(PlyWriter {
            w,
            enc: PlyEncoder::new(opts),
            buf: Vec::with_capacity(FLUSH_AT + 4096),
            n_vertices,
            n_faces,
            vertices: 0,
            faces: 0,
            bytes: h.len() as u64,
        })
    }

    /// The record encoder, for encoding chunks elsewhere (e.g. in parallel).
    pub fn encoder(&self) -> &PlyEncoder {
        &self.enc
    }

    /// Bytes written so far, header included (buffered bytes count as written).
    pub fn bytes_written(&self) -> u64 {
        self.bytes + self.buf.len() as u64
    }

    fn check_vertices(&self, n: u64) -> io::Result<()> {
        if self.vertices + n > self.n_vertices {
            return Err(invalid_data(format!("more vertices written than the {} announced in the header", self.n_vertices)));
        }
        Ok(())
    }

    fn check_faces(&self, n: u64) -> io::Result<()> {
        if self.vertices != self.n_vertices {
            return Err(invalid_data(format!("face written after only {} of the {} vertices", self.vertices, self.n_vertices)));
        }
        if self.faces + n > self.n_faces {
            return Err(invalid_data(format!("more faces written than the {} announced in the header", self.n_faces)));
        }
        Ok(())
    }

    #[inline]
    fn maybe_flush(&mut self) -> io::Result<()> {
        if self.buf.len() >= FLUSH_AT {
            self.flush_buf()?;
        }
        Ok(())
    }

    fn flush_buf(&mut self) -> io::Result<()> {
        if !self.buf.is_empty() {
            self.w.write_all(&self.buf)?;
            self.bytes += self.buf.len() as u64;
            self.buf.clear();
        }
        Ok(())
    }

    /// Writes one vertex (only the attributes in the options' set).
    #[inline]
    pub fn vertex(&mut self, v: &Vertex) -> io::Result<()> {
        self.check_vertices(1)?;
        self.enc.vertex(v, &mut self.buf);
        self.vertices += 1;
        self.maybe_flush()
    }

    /// Writes one face: a polygon of 1..=255 vertex indices (not of a
    /// mesh with materials: see [`PlyWriter::face_material`]).
    #[inline]
    pub fn face(&mut self, idx: &[u32]) -> io::Result<()> {
        self.check_faces(1)?;
        self.enc.face(idx, &mut self.buf)?;
        self.faces += 1;
        self.maybe_flush()
    }

    /// Writes one face with its material (its `texnumber` with
    /// [`AttrSet::MATERIAL`]; ignored without).
    #[inline]
    pub fn face_material(&mut self, idx: &[u32], material: u16) -> io::Result<()> {
        self.check_faces(1)?;
        self.enc.face_material(idx, material, &mut self.buf)?;
        self.faces += 1;
        self.maybe_flush()
    }

    /// Writes `count` vertex records already encoded by [`Self::encoder`].
    pub fn raw_vertices(&mut self, bytes: &[u8], count: u64) -> io::Result<()> {
        self.check_vertices(count)?;
        self.flush_buf()?;
        self.w.write_all(bytes)?;
        self.bytes += bytes.len() as u64;
        self.vertices += count;
        Ok(())
    }

    /// Writes `count` face records already encoded by [`Self::encoder`].
    pub fn raw_faces(&mut self, bytes: &[u8], count: u64) -> io::Result<()> {
        self.check_faces(count)?;
        self.flush_buf()?;
        self.w.write_all(bytes)?;
        self.bytes += bytes.len() as u64;
        self.faces += count;
        Ok(())
    }

    /// Flushes and returns the sink; fails (`InvalidData`) unless exactly the
    /// announced numbers of vertices and faces were written.
    pub fn finish(mut self) -> io::Result<W> {
        if self.vertices != self.n_vertices || self.faces != self.n_faces {
            return Err(invalid_data(format!(
                "wrote {} vertices and {} faces but the header announces {} and {}",
                self.vertices, self.faces, self.n_vertices, self.n_faces
            )));
        }
        self.flush_buf()?;
        self.w.flush()?;
        Ok(self.w)
    }
}

/// Writes a triangle mesh to `path` atomically, replacing a PLY octolod
/// wrote there before (never anything else). With [`AttrSet::MATERIAL`]
/// each face's `texnumber` is its corner 0's material.
pub fn write_ply(path: &Path, opts: &PlyWriteOptions, vertices: &[Vertex], faces: &[[u32; 3]]) -> Result<()> {
    write_whole(path, opts, vertices, faces.len() as u64, faces.iter().map(|f| &f[..]))
}

/// Writes a polygon mesh (faces of 1..=255 vertices) to `path` atomically.
pub fn write_ply_polygons(path: &Path, opts: &PlyWriteOptions, vertices: &[Vertex], faces: &[Vec<u32>]) -> Result<()> {
    write_whole(path, opts, vertices, faces.len() as u64, faces.iter().map(|f| &f[..]))
}

fn write_whole<'a>(path: &Path, opts: &PlyWriteOptions, vertices: &[Vertex], n_faces: u64, faces: impl Iterator<Item = &'a [u32]>) -> Result<()> {
    let mut file = AtomicFile::create(path, OutputKind::Ply, true)?;
    let res: io::Result<()> = (|| {
        let mut w = PlyWriter::new(file.writer(), opts, vertices.len() as u64, n_faces)?;
        for v in vertices {
            w.vertex(v)?;
        }
        for f in faces {
            let m = f.first().and_then(|&i| vertices.get(i as usize)).map_or(0, |v| v.material);
            w.face_material(f, m)?;
        }
        w.finish()?;
        Ok(())
    })();
    res.ctx(path, "write")?;
    file.commit()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn v(x: f64, y: f64, z: f64) -> Vertex {
        Vertex { pos: [x, y, z], normal: [0.0, 0.0, 1.0], color: [10, 20, 30, 40], uv: [0.25, 0.5], material: 0 }
    }

    #[test]
    fn header_position_only_default() {
        let h = header(&PlyWriteOptions::default(), 3, 1);
        assert_eq!(
            h,
            "ply\nformat binary_little_endian 1.0\ncomment octolod-output\nelement vertex 3\nproperty float x\nproperty float y\n\
             property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
        );
    }

    #[test]
    fn header_all_attributes() {
        let opts = PlyWriteOptions {
            encoding: Encoding::Ascii,
            attrs: AttrSet(AttrSet::POS_F64 | AttrSet::NORMAL | AttrSet::COLOR | AttrSet::ALPHA | AttrSet::UV),
            float_colors: false,
            uv_names: UvNames::TextureUV,
            index_type: Scalar::U32,
            comments: vec!["made by test".into(), "two\nlines".into()],
            extra_vertex_quality: true,
        };
        let expect = "ply\nformat ascii 1.0\ncomment octolod-output\ncomment made by test\ncomment two lines\nelement vertex 7\n\
            property double x\nproperty float quality\nproperty double y\nproperty double z\n\
            property float nx\nproperty float ny\nproperty float nz\n\
            property uchar red\nproperty uchar green\nproperty uchar blue\nproperty uchar alpha\n\
            property float texture_u\nproperty float texture_v\n\
            element face 2\nproperty list uchar uint vertex_indices\nend_header\n";
        assert_eq!(header(&opts, 7, 2), expect);
        let opts2 = PlyWriteOptions {
            encoding: Encoding::BinaryBe,
            attrs: AttrSet(AttrSet::COLOR | AttrSet::UV),
            float_colors: true,
            uv_names: UvNames::ST,
            ..Default::default()
        };
        assert_eq!(
            header(&opts2, 0, 0),
            "ply\nformat binary_big_endian 1.0\ncomment octolod-output\nelement vertex 0\nproperty float x\nproperty float y\n\
             property float z\nproperty float red\nproperty float green\nproperty float blue\n\
             property float s\nproperty float t\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n"
        );
    }

    fn body(opts: &PlyWriteOptions, verts: &[Vertex], faces: &[&[u32]]) -> (usize, Vec<u8>) {
        let mut w = PlyWriter::new(Vec::new(), opts, verts.len() as u64, faces.len() as u64).unwrap();
        for x in verts {
            w.vertex(x).unwrap();
        }
        for f in faces {
            w.face(f).unwrap();
        }
        let n = w.bytes_written();
        let out = w.finish().unwrap();
        assert_eq!(n as usize, out.len());
        let hl = header(opts, verts.len() as u64, faces.len() as u64).len();
        assert_eq!(&out[..hl], header(opts, verts.len() as u64, faces.len() as u64).as_bytes());
        (hl, out)
    }

    #[test]
    fn binary_body_sizes() {
        let verts = [v(0.0, 0.0, 0.0), v(1.0, 0.0, 0.0), v(0.0, 1.0, 0.0), v(1.0, 1.0, 0.5)];
        let faces: [&[u32]; 3] = [&[0, 1, 2], &[1, 3, 2], &[0, 1, 3, 2]];
        let cases: [(u32, bool, bool, Scalar, usize); 6] = [
            (0, false, false, Scalar::I32, 12),
            (AttrSet::POS_F64, false, false, Scalar::I32, 24),
            (AttrSet::POS_F64, false, true, Scalar::U16, 28),
            (AttrSet::NORMAL | AttrSet::COLOR | AttrSet::UV, false, false, Scalar::U32, 12 + 12 + 3 + 8),
            (AttrSet::COLOR | AttrSet::ALPHA, true, false, Scalar::U8, 12 + 16),
            (AttrSet::POS_F64 | AttrSet::NORMAL | AttrSet::COLOR | AttrSet::ALPHA | AttrSet::UV, false, true, Scalar::I32, 24 + 4 + 12 + 4 + 8),
        ];
        for (bits, float_colors, quality, index_type, vsize) in cases {
            for encoding in [Encoding::BinaryLe, Encoding::BinaryBe] {
                let opts = PlyWriteOptions { encoding, attrs: AttrSet(bits), float_colors, index_type, extra_vertex_quality: quality, ..Default::default() };
                let (hl, out) = body(&opts, &verts, &faces);
                let fsize = 2 * (1 + 3 * index_type.size()) + (1 + 4 * index_type.size());
                assert_eq!(out.len() - hl, 4 * vsize + fsize, "attrs {bits} {encoding:?}");
                assert_eq!(PlyEncoder::new(&opts).vertex_record_size(), Some(vsize));
            }
        }
    }

    #[test]
    fn binary_values_and_endianness() {
        let le = PlyWriteOptions { attrs: AttrSet(AttrSet::COLOR), extra_vertex_quality: true, ..Default::default() };
        let (hl, out) = body(&le, &[v(1.5, -2.0, 3.0)], &[&[0, 0, 0]]);
        let b = &out[hl..];
        assert_eq!(&b[0..4], &1.5f32.to_le_bytes());
        assert_eq!(&b[4..8], &0.5f32.to_le_bytes());
        assert_eq!(&b[8..12], &(-2.0f32).to_le_bytes());
        assert_eq!(&b[12..16], &3.0f32.to_le_bytes());
        assert_eq!(&b[16..19], &[10, 20, 30]);
        assert_eq!(&b[19..], &[3, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0]);
        let be = PlyWriteOptions { encoding: Encoding::BinaryBe, attrs: AttrSet(AttrSet::POS_F64), ..Default::default() };
        let (hl, out) = body(&be, &[v(1.5, -2.0, 3.0)], &[&[0, 0, 0]]);
        let b = &out[hl..];
        assert_eq!(&b[0..8], &1.5f64.to_be_bytes());
        assert_eq!(&b[8..16], &(-2.0f64).to_be_bytes());
        assert_eq!(b.len(), 24 + 13);
    }

    #[test]
    fn ascii_round_trips_floats() {
        let opts = PlyWriteOptions {
            encoding: Encoding::Ascii,
            attrs: AttrSet(AttrSet::POS_F64 | AttrSet::NORMAL | AttrSet::COLOR | AttrSet::UV),
            ..Default::default()
        };
        let p = [1.0e6 + 1.0e-3, 0.1 + 0.2, -1.0e-30];
        let mut x = v(p[0], p[1], p[2]);
        x.normal = [0.6, 0.8, 1.0 / 3.0];
        x.uv = [0.1, 1.0e-8];
        let (hl, out) = body(&opts, &[x], &[&[0, 0, 0, 0, 0]]);
        let text = std::str::from_utf8(&out[hl..]).unwrap();
        let mut lines = text.lines();
        let f: Vec<&str> = lines.next().unwrap().split(' ').collect();
        assert_eq!(f.len(), 11);
        for k in 0..3 {
            assert_eq!(f[k].parse::<f64>().unwrap(), p[k]);
            assert_eq!(f[3 + k].parse::<f32>().unwrap(), x.normal[k]);
        }
        assert_eq!(&f[6..9], &["10", "20", "30"]);
        assert_eq!(f[9].parse::<f32>().unwrap(), 0.1f32);
        assert_eq!(f[10].parse::<f32>().unwrap(), 1.0e-8f32);
        assert_eq!(lines.next(), Some("5 0 0 0 0 0"));
        assert_eq!(lines.next(), None);
        // Single precision positions print the f32 value.
        let opts = PlyWriteOptions { encoding: Encoding::Ascii, extra_vertex_quality: true, ..Default::default() };
        let (hl, out) = body(&opts, &[v(0.1, 2.0, -3.5)], &[]);
        assert_eq!(std::str::from_utf8(&out[hl..]).unwrap(), "0.1 0.5 2 -3.5\n");
    }

    #[test]
    fn finish_rejects_wrong_counts() {
        let opts = PlyWriteOptions::default();
        let w = PlyWriter::new(Vec::new(), &opts, 2, 1).unwrap();
        assert_eq!(w.finish().unwrap_err().kind(), io::ErrorKind::InvalidData);
        let mut w = PlyWriter::new(Vec::new(), &opts, 1, 1).unwrap();
        w.vertex(&Vertex::default()).unwrap();
        assert_eq!(w.finish().unwrap_err().kind(), io::ErrorKind::InvalidData);
        let mut w = PlyWriter::new(Vec::new(), &opts, 1, 0).unwrap();
        w.vertex(&Vertex::default()).unwrap();
        assert_eq!(w.vertex(&Vertex::default()).unwrap_err().kind(), io::ErrorKind::InvalidData);
        assert_eq!(w.face(&[0, 0, 0]).unwrap_err().kind(), io::ErrorKind::InvalidData);
        assert!(w.finish().is_ok());
        // Faces before all vertices, bad polygon sizes, indices out of the type's range.
        let mut w = PlyWriter::new(Vec::new(), &opts, 2, 1).unwrap();
        w.vertex(&Vertex::default()).unwrap();
        assert_eq!(w.face(&[0, 0, 0]).unwrap_err().kind(), io::ErrorKind::InvalidData);
        w.vertex(&Vertex::default()).unwrap();
        assert_eq!(w.face(&[]).unwrap_err().kind(), io::ErrorKind::InvalidInput);
        assert_eq!(w.face(&[0; 256]).unwrap_err().kind(), io::ErrorKind::InvalidInput);
        assert_eq!(w.face(&[0, 1, u32::MAX]).unwrap_err().kind(), io::ErrorKind::InvalidData);
        w.face(&[0; 255]).unwrap();
        assert_eq!(w.finish().unwrap().len(), header(&opts, 2, 1).len() + 24 + 1 + 255 * 4);
        let u8opts = PlyWriteOptions { index_type: Scalar::U8, ..Default::default() };
        let mut w = PlyWriter::new(Vec::new(), &u8opts, 0, 1).unwrap();
        assert_eq!(w.face(&[1, 2, 256]).unwrap_err().kind(), io::ErrorKind::InvalidData);
    }

    #[test]
    fn write_ply_is_atomic_and_complete() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("m.ply");
        let verts = [v(0.0, 0.0, 0.0), v(1.0, 0.0, 0.0), v(0.0, 1.0, 0.0)];
        write_ply(&p, &PlyWriteOptions::default(), &verts, &[[0, 1, 2]]).unwrap();
        let len = std::fs::metadata(&p).unwrap().len() as usize;
        assert_eq!(len, header(&PlyWriteOptions::default(), 3, 1).len() + 36 + 13);
        let bad = write_ply_polygons(&p, &PlyWriteOptions::default(), &verts, &[vec![]]);
        assert!(bad.unwrap_err().to_string().contains("m.ply"));
        assert_eq!(std::fs::read_dir(d.path()).unwrap().count(), 1);
        assert_eq!(std::fs::metadata(&p).unwrap().len() as usize, len);
    }

    /// A face's material is written as `int texnumber` (not per vertex) and
    /// read back per triangle, polygons and NO_TEXTURE (-1) included.
    #[test]
    fn texnumber_round_trips() {
        let d = tempfile::tempdir().unwrap();
        let attrs = AttrSet(AttrSet::UV | AttrSet::MATERIAL);
        let mv = |x: f64, y: f64, m: u16| Vertex { material: m, ..v(x, y, 0.0) };
        // Two materials meeting along x = 1: vertices split there, as stores have them.
        let verts =
            vec![mv(0., 0., 2), mv(1., 0., 2), mv(1., 1., 2), mv(0., 1., 2), mv(1., 0., 0), mv(2., 0., 0), mv(1., 1., 0), mv(2., 2., Vertex::NO_TEXTURE)];
        let polys = vec![vec![0, 1, 2, 3], vec![4, 5, 6], vec![7, 5, 6]];
        let comments = vec!["TextureFile a.png".to_string(), "TextureFile b.png".into(), "TextureFile c.png".into()];
        for encoding in [Encoding::Ascii, Encoding::BinaryLe, Encoding::BinaryBe] {
            let opts = PlyWriteOptions { encoding, attrs, comments: comments.clone(), ..Default::default() };
            let h = header(&opts, 8, 3);
            assert!(h.ends_with("vertex_indices\nproperty int texnumber\nend_header\n"), "{h}");
            assert!(!h.contains("material"));
            let p = d.path().join("m.ply");
            write_ply_polygons(&p, &opts, &verts, &polys).unwrap();
            let (rh, m, _) = crate::ply::read::read_all(&p).unwrap();
            assert!(rh.attrs.material(), "{encoding:?}");
            let mats: Vec<[u16; 3]> = m.triangles.iter().map(|t| t.map(|i| m.vertices[i as usize].material)).collect();
            assert_eq!(mats, [[2; 3], [2; 3], [0; 3], [Vertex::NO_TEXTURE; 3]], "{encoding:?}");
            // Vertex 5 and 6 are used by material 0 and by NO_TEXTURE: split on reading.
            assert_eq!(m.vertices.len(), 10, "{encoding:?}");
            // write_ply (triangles) agrees with the encoder's polygon path.
            let tris: Vec<[u32; 3]> = m.triangles.iter().map(|t| t.map(|i| i as u32)).collect();
            write_ply(&p, &opts, &m.vertices, &tris).unwrap();
            let (_, m2, _) = crate::ply::read::read_all(&p).unwrap();
            let mats2: Vec<u16> = m2.triangles.iter().map(|t| m2.vertices[t[0] as usize].material).collect();
            assert_eq!(mats2, [2, 2, 0, Vertex::NO_TEXTURE]);
            assert_eq!(m2.vertices.len(), m.vertices.len());
        }
        // A bare face of a mesh with materials is refused, not written as texture 0.
        let enc = PlyEncoder::new(&PlyWriteOptions { attrs, ..Default::default() });
        assert!(enc.face(&[0, 1, 2], &mut Vec::new()).is_err());
        assert_eq!(enc.face_record_size(3), Some(17));
    }
}

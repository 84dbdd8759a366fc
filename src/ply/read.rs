//! Streaming PLY body decoder.
//!
//! Takes: a parsed [`PlyHeader`] and the file. Gives: batches of decoded
//! vertices (in index order) and of fan-triangulated triangles (in face
//! order) to a [`BodySink`], validating as it goes: non-finite coordinates,
//! negative or out-of-range indices, faces with fewer than three corners,
//! truncated bodies and trailing bytes (wrong header counts), a `texnumber`
//! naming no `comment TextureFile` texture, are errors naming
//! the file, element, record and byte offset. Triangles with a repeated
//! index are dropped and counted. A face's per-wedge `texcoord` and its
//! `texnumber` go to the sink beside each triangle batch
//! ([`BodySink::wedge_uvs`], [`BodySink::materials`]).
//!
//! Binary records are decoded through per-field (offset, type) tables
//! compiled from the header, over a large refillable buffer fed by plain
//! sequential `read`s (no mmap: file pages would count against the memory
//! budget), so decoding runs at memory speed. Extra properties and extra
//! elements are skipped by size.

use super::{color_names, face_index_prop, uv_names, ElementDef, Encoding, PlyHeader, PropDef, PropType, Scalar};
use crate::error::{Error, Location, Result};
use crate::io::SeqInput as Input;
use crate::mesh::{AttrSet, Vertex};
use crate::progress::Progress;
use std::path::Path;

/// Receives the body in batches.
pub trait BodySink {
    /// `batch[k]` is vertex number `first + k`.
    fn vertices(&mut self, first: u64, batch: &[Vertex]) -> Result<()>;
    /// Triangles in face order (polygons fan-triangulated, degenerate ones dropped).
    fn triangles(&mut self, batch: &[[u64; 3]]) -> Result<()>;
    /// Per-wedge uvs of the next [`BodySink::triangles`] batch, one per
    /// corner and triangle, when the faces carry them (MeshLab's face list
    /// `texcoord`): they replace the corners' vertex uvs, but for NaN ones
    /// (a face whose list is not two values per corner). Sinks that keep
    /// no uvs ignore them.
    fn wedge_uvs(&mut self, _batch: &[[[f32; 2]; 3]]) -> Result<()> {
        Ok(())
    }
    /// Material of each triangle of the next [`BodySink::triangles`]
    /// batch, when the input has [`AttrSet::MATERIAL`] (a PLY face's
    /// `texnumber`, -1 read as [`Vertex::NO_TEXTURE`]): every corner of
    /// the triangle takes it. Sinks that keep no materials ignore them.
    fn materials(&mut self, _batch: &[u16]) -> Result<()> {
        Ok(())
    }
}

/// What the body held.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BodyStats {
    pub vertices: u64,
    pub faces: u64,
    /// Triangles passed to the sink.
    pub triangles: u64,
    /// Triangles dropped because two corners had the same index.
    pub degenerate: u64,
    /// Faces with more than three corners (fan-triangulated).
    pub polygons: u64,
    /// Bytes read from the file.
    pub bytes: u64,
}

const BATCH: usize = 1 << 15;
const BUF: usize = 4 << 20;

/// How to read one scalar from a binary record.
#[derive(Clone, Copy)]
struct Field {
    off: usize,
    ty: Scalar,
}

#[inline(always)]
fn load<const N: usize>(b: &[u8], off: usize) -> [u8; N] {
    b[off..off + N].try_into().unwrap()
}

/// Defines a decoder of one binary scalar of any PLY type into `$out`.
macro_rules! scalar_decoder {
    ($(#[$doc:meta])* $name:ident -> $out:ty) => {
        $(#[$doc])*
        #[inline(always)]
        fn $name(b: &[u8], off: usize, ty: Scalar, be: bool) -> $out {
            macro_rules! rd {
                ($t:ty, $n:literal) => {{
                    let a = load::<$n>(b, off);
                    (if be { <$t>::from_be_bytes(a) } else { <$t>::from_le_bytes(a) }) as $out
                }};
            }
            match ty {
                Scalar::I8 => b[off] as i8 as $out,
                Scalar::U8 => b[off] as $out,
                Scalar::I16 => rd!(i16, 2),
                Scalar::U16 => rd!(u16, 2),
                Scalar::I32 => rd!(i32, 4),
                Scalar::U32 => rd!(u32, 4),
                Scalar::F32 => rd!(f32, 4),
                Scalar::F64 => rd!(f64, 8),
            }
        }
    };
}

scalar_decoder!(
    /// Value of a binary scalar as f64 (vertex properties).
    bin_f64 -> f64
);
scalar_decoder!(
    /// Integer value of a binary scalar (list counts and indices); float list types are rejected by the header check.
    bin_i64 -> i64
);

/// Maps a color channel of any type to 0..=255.
#[inline]
fn color_u8(x: f64, ty: Scalar) -> u8 {
    let v = match ty {
        Scalar::F32 | Scalar::F64 => x * 255.0,
        Scalar::U16 => x / 257.0,
        _ => x,
    };
    if v.is_nan() {
        0
    } else {
        v.round().clamp(0.0, 255.0) as u8
    }
}

/// Which vertex properties feed which [`Vertex`] fields (indices into the element's props).
struct VertexPlan {
    pos: [usize; 3],
    normal: Option<[usize; 3]>,
    color: Option<[usize; 3]>,
    alpha: Option<usize>,
    uv: Option<[usize; 2]>,
}

impl VertexPlan {
    fn new(e: &ElementDef, attrs: AttrSet) -> VertexPlan {
        let p = |n: &str| e.prop(n).expect("checked by header");
        VertexPlan {
            pos: [p("x"), p("y"), p("z")],
            normal: attrs.normal().then(|| [p("nx"), p("ny"), p("nz")]),
            color: attrs.color().then(|| color_names(e).unwrap().map(p)),
            alpha: attrs.alpha().then(|| p("alpha")),
            // (uvs may come from the faces' per-wedge `texcoord` instead)
            uv: attrs.uv().then(|| uv_names(e)).flatten().map(|n| n.map(p)),
        }
    }
}

/// Reads the whole body of `path` described by `header`, feeding `sink`.
pub fn read_body(path: &Path, header: &PlyHeader, sink: &mut dyn BodySink, progress: &Progress) -> Result<BodyStats> {
    let mut r = BodyReader {
        input: Input::open(path, header.body_offset, BUF)?,
        header,
        stats: BodyStats::default(),
        progress,
        reported: header.body_offset,
        tris: Vec::with_capacity(BATCH),
        wedges: Vec::new(),
        mats: Vec::new(),
        face_mat: 0,
        face_idx: Vec::new(),
        face_tc: Vec::new(),
        verts: Vec::with_capacity(BATCH),
    };
    for (ei, e) in header.elements.iter().enumerate() {
        if ei == header.vertex_elem {
            r.read_vertices(e, sink)?;
        } else if Some(ei) == header.face_elem {
            r.read_faces(e, sink)?;
        } else {
            r.skip_element(e)?;
        }
    }
    r.finish()
}

struct BodyReader<'a> {
    input: Input,
    header: &'a PlyHeader,
    stats: BodyStats,
    progress: &'a Progress,
    reported: u64,
    tris: Vec<[u64; 3]>,
    /// Per-wedge uvs of `tris` (faces with a `texcoord` list), else empty.
    wedges: Vec<[[f32; 2]; 3]>,
    /// Material of each of `tris` (faces with a `texnumber`), else empty.
    mats: Vec<u16>,
    /// The material of the face being read.
    face_mat: u16,
    /// One face's corners and texcoords (faces with a `texcoord` list or
    /// a `texnumber`, fanned once the whole record is read).
    face_idx: Vec<i64>,
    face_tc: Vec<f32>,
    verts: Vec<Vertex>,
}

impl BodyReader<'_> {
    fn loc(&self, elem: &str, record: u64, offset: u64) -> Location {
        Location { file: self.input.path.clone(), element: Some(elem.to_string()), record: Some(record), offset: Some(offset), line: None }
    }

    fn truncated(&self, elem: &ElementDef, record: u64) -> Error {
        Error::input(
            self.loc(&elem.name, record, self.input.offset()),
            format!("unexpected end of file: the header declares {} '{}' records but the body ends inside record {record}", elem.count, elem.name),
        )
    }

    /// Reports progress; a safe point for signals (after each batch).
    fn tick(&mut self) -> Result<()> {
        let off = self.input.offset();
        self.progress.inc(off - self.reported);
        self.reported = off;
        crate::io::signal::check()
    }

    fn finish(mut self) -> Result<BodyStats> {
        let binary = self.header.encoding != Encoding::Ascii;
        if binary {
            if !self.input.at_eof()? {
                let start = self.input.offset();
                let mut extra = self.input.avail() as u64;
                self.input.pos = self.input.end;
                while self.input.ensure(1)? {
                    extra += self.input.avail() as u64;
                    self.input.pos = self.input.end;
                }
                return Err(Error::input(
                    Location { file: self.input.path.clone(), offset: Some(start), ..Default::default() },
                    format!("{extra} unexpected bytes after the last element: the header's element counts are too small"),
                ));
            }
        } else {
            let mut t = AsciiTok { input: &mut self.input };
            if let Some((tok, off)) = t.next_token()? {
                let tok = String::from_utf8_lossy(&tok).into_owned();
                return Err(Error::input(
                    Location { file: self.input.path.clone(), offset: Some(off), ..Default::default() },
                    format!("unexpected data '{tok}' after the last element: the header's element counts are too small"),
                ));
            }
        }
        self.tick()?;
        self.stats.bytes = self.input.offset();
        Ok(self.stats)
    }

    // ---------------------------------------------------------------- vertices

    fn read_vertices(&mut self, e: &ElementDef, sink: &mut dyn BodySink) -> Result<()> {
        let plan = VertexPlan::new(e, self.header.attrs);
        match (self.header.encoding, e.fixed_size()) {
            (Encoding::Ascii, _) => self.read_vertices_ascii(e, &plan, sink),
            (enc, Some(size)) => self.read_vertices_fixed(e, &plan, size, enc == Encoding::BinaryBe, sink),
            (enc, None) => self.read_vertices_varying(e, &plan, enc == Encoding::BinaryBe, sink),
        }
    }

    fn check_vertex(&self, v: &Vertex, e: &ElementDef, record: u64, offset: u64) -> Result<()> {
        if !(v.pos[0].is_finite() && v.pos[1].is_finite() && v.pos[2].is_finite()) {
            return Err(Error::input(self.loc(&e.name, record, offset), format!("non-finite coordinate ({}, {}, {})", v.pos[0], v.pos[1], v.pos[2])));
        }
        Ok(())
    }

    fn flush_vertices(&mut self, sink: &mut dyn BodySink) -> Result<()> {
        if !self.verts.is_empty() {
            let first = self.stats.vertices;
            sink.vertices(first, &self.verts)?;
            self.stats.vertices += self.verts.len() as u64;
            self.verts.clear();
            self.tick()?;
        }
        Ok(())
    }

    #[allow(clippy::needless_range_loop, reason = "each property's slot filled from its field, arrays in lockstep")]
    fn read_vertices_fixed(&mut self, e: &ElementDef, plan: &VertexPlan, size: usize, be: bool, sink: &mut dyn BodySink) -> Result<()> {
        let mut offs = Vec::with_capacity(e.props.len());
        let mut o = 0;
        for p in &e.props {
            let PropType::Scalar(s) = p.ty else { unreachable!() };
            offs.push(Field { off: o, ty: s });
            o += s.size();
        }
        let f = |i: usize| offs[i];
        let pos = plan.pos.map(f);
        let normal = plan.normal.map(|a| a.map(f));
        let color = plan.color.map(|a| a.map(f));
        let alpha = plan.alpha.map(f);
        let uv = plan.uv.map(|a| a.map(f));
        let mut rec = 0u64;
        while rec < e.count {
            if !self.input.ensure(size)? {
                self.flush_vertices(sink)?;
                return Err(self.truncated(e, rec));
            }
            let n = ((self.input.avail() / size) as u64).min(e.count - rec).min((BATCH - self.verts.len()) as u64) as usize;
            let start = self.input.pos;
            for k in 0..n {
                let b = &self.input.buf[start + k * size..start + (k + 1) * size];
                let mut v = Vertex::default();
                for a in 0..3 {
                    v.pos[a] = bin_f64(b, pos[a].off, pos[a].ty, be);
                }
                if !(v.pos[0].is_finite() && v.pos[1].is_finite() && v.pos[2].is_finite()) {
                    let off = self.input.base + (start + k * size) as u64;
                    self.check_vertex(&v, e, rec + k as u64, off)?;
                }
                if let Some(nf) = normal {
                    for a in 0..3 {
                        v.normal[a] = bin_f64(b, nf[a].off, nf[a].ty, be) as f32;
                    }
                }
                if let Some(cf) = color {
                    for a in 0..3 {
                        v.color[a] = color_u8(bin_f64(b, cf[a].off, cf[a].ty, be), cf[a].ty);
                    }
                }
                if let Some(af) = alpha {
                    v.color[3] = color_u8(bin_f64(b, af.off, af.ty, be), af.ty);
                }
                if let Some(uf) = uv {
                    for a in 0..2 {
                        v.uv[a] = bin_f64(b, uf[a].off, uf[a].ty, be) as f32;
                    }
                }
                self.verts.push(v);
            }
            self.input.pos += n * size;
            rec += n as u64;
            if self.verts.len() == BATCH {
                self.flush_vertices(sink)?;
            }
        }
        self.flush_vertices(sink)
    }

    /// Binary vertex element with list properties (rare): decode record by record.
    fn read_vertices_varying(&mut self, e: &ElementDef, plan: &VertexPlan, be: bool, sink: &mut dyn BodySink) -> Result<()> {
        let mut vals = vec![0f64; e.props.len()];
        for rec in 0..e.count {
            let start = self.input.offset();
            for (pi, p) in e.props.iter().enumerate() {
                match p.ty {
                    PropType::Scalar(s) => {
                        if !self.input.ensure(s.size())? {
                            return Err(self.truncated(e, rec));
                        }
                        vals[pi] = bin_f64(&self.input.buf, self.input.pos, s, be);
                        self.input.pos += s.size();
                    }
                    PropType::List(c, s) => {
                        let n = self.read_bin_count(e, rec, c, be)?;
                        self.skip_bytes(e, rec, n.saturating_mul(s.size() as u64))?;
                    }
                }
            }
            self.push_assembled(plan, &vals, e, rec, start, sink)?;
        }
        self.flush_vertices(sink)
    }

    /// Builds the vertex of one record-by-record decoded record, validates and batches it.
    fn push_assembled(&mut self, plan: &VertexPlan, vals: &[f64], e: &ElementDef, rec: u64, start: u64, sink: &mut dyn BodySink) -> Result<()> {
        let v = assemble_vertex(plan, vals, e);
        self.check_vertex(&v, e, rec, start)?;
        self.verts.push(v);
        if self.verts.len() == BATCH {
            self.flush_vertices(sink)?;
        }
        Ok(())
    }

    fn read_vertices_ascii(&mut self, e: &ElementDef, plan: &VertexPlan, sink: &mut dyn BodySink) -> Result<()> {
        let mut vals = vec![0f64; e.props.len()];
        for rec in 0..e.count {
            self.input.skip_ws()?;
            let start = self.input.offset();
            for (pi, p) in e.props.iter().enumerate() {
                match p.ty {
                    PropType::Scalar(s) => vals[pi] = self.ascii_number(e, rec, s, &p.name)?,
                    PropType::List(c, s) => {
                        let n = self.ascii_count(e, rec, c, &p.name)?;
                        for _ in 0..n {
                            self.ascii_number(e, rec, s, &p.name)?;
                        }
                    }
                }
            }
            self.push_assembled(plan, &vals, e, rec, start, sink)?;
        }
        self.flush_vertices(sink)
    }

    // ------------------------------------------------------------------- faces

    fn read_faces(&mut self, e: &ElementDef, sink: &mut dyn BodySink) -> Result<()> {
        let idx_prop = face_index_prop(e).expect("checked by header");
        let be = self.header.encoding == Encoding::BinaryBe;
        let ascii = self.header.encoding == Encoding::Ascii;
        // The layout nearly every binary mesh uses: only `list uchar int|uint`.
        let fast = match e.props[..] {
            [PropDef { ty: PropType::List(Scalar::U8, s @ (Scalar::I32 | Scalar::U32)), .. }] if !ascii => Some(s),
            _ => None,
        };
        let mut rec = 0;
        while rec < e.count {
            if let Some(s) = fast {
                let done = self.triangle_records_fast(e.count - rec, s == Scalar::I32, be);
                rec += done;
                if self.tris.len() >= BATCH {
                    self.flush_triangles(sink)?;
                }
                if done > 0 {
                    continue;
                }
                if rec == e.count {
                    break;
                }
            }
            // Anything else (polygons, extra properties, ascii, a buffer
            // boundary, an error to report): one record the general way.
            self.read_face_record(e, rec, idx_prop, be, ascii, sink)?;
            rec += 1;
        }
        self.flush_triangles(sink)
    }

    /// Decodes buffered 13-byte triangle records (`3 i0 i1 i2`) in a tight
    /// loop; stops at anything unusual and leaves it to the general path.
    #[inline(never)]
    fn triangle_records_fast(&mut self, max: u64, signed: bool, be: bool) -> u64 {
        let nv = self.header.vertex_count();
        let buf = &self.input.buf[..self.input.end];
        let mut p = self.input.pos;
        let mut n = 0u64;
        let room = BATCH.saturating_sub(self.tris.len()) as u64;
        let max = max.min(room);
        let idx = |at: usize| -> u64 {
            let a: [u8; 4] = buf[at..at + 4].try_into().unwrap();
            let v = if be { u32::from_be_bytes(a) } else { u32::from_le_bytes(a) };
            // Negative signed indices become huge and fail the range check.
            if signed {
                v as i32 as i64 as u64
            } else {
                v as u64
            }
        };
        while n < max && p + 13 <= buf.len() && buf[p] == 3 {
            let t = [idx(p + 1), idx(p + 5), idx(p + 9)];
            if t[0] >= nv || t[1] >= nv || t[2] >= nv {
                break;
            }
            if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] {
                self.stats.degenerate += 1;
            } else {
                self.tris.push(t);
            }
            p += 13;
            n += 1;
        }
        self.input.pos = p;
        self.stats.faces += n;
        n
    }

    fn read_face_record(&mut self, e: &ElementDef, rec: u64, idx_prop: usize, be: bool, ascii: bool, sink: &mut dyn BodySink) -> Result<()> {
        if ascii {
            self.input.skip_ws()?;
        }
        let start = self.input.offset();
        let mut fan = Fan { first: 0, prev: 0, k: 0 };
        let tc_prop = super::wedge_uv_prop(e);
        let tex_prop = if self.header.attrs.material() { super::texnumber_prop(e) } else { None };
        // Faces whose corners need a later property are fanned at the record's end.
        let deferred = tc_prop.is_some() || tex_prop.is_some();
        if deferred {
            self.face_idx.clear();
            self.face_tc.clear();
            self.face_mat = 0;
        }
        for (pi, p) in e.props.iter().enumerate() {
            let want = pi == idx_prop;
            if Some(pi) == tex_prop {
                let PropType::Scalar(s) = p.ty else { unreachable!("checked by texnumber_prop") };
                let (x, at) = if ascii {
                    self.input.skip_ws()?;
                    let at = self.input.offset();
                    (self.ascii_number(e, rec, s, &p.name)? as i64, at)
                } else {
                    if !self.input.ensure(s.size())? {
                        return Err(self.truncated(e, rec));
                    }
                    let at = self.input.offset();
                    let x = bin_i64(&self.input.buf, self.input.pos, s, be);
                    self.input.pos += s.size();
                    (x, at)
                };
                self.face_mat = self.texnumber(x, e, rec, at)?;
                continue;
            }
            if Some(pi) == tc_prop {
                // Per-wedge uvs: 2 per corner, kept for the record's end.
                let PropType::List(c, s) = p.ty else { unreachable!("checked by wedge_uv_prop") };
                let n = if ascii { self.ascii_count(e, rec, c, &p.name)? } else { self.read_bin_count(e, rec, c, be)? };
                for _ in 0..n {
                    let x = if ascii {
                        self.ascii_number(e, rec, s, &p.name)?
                    } else {
                        if !self.input.ensure(s.size())? {
                            return Err(self.truncated(e, rec));
                        }
                        let x = bin_f64(&self.input.buf, self.input.pos, s, be);
                        self.input.pos += s.size();
                        x
                    };
                    self.face_tc.push(x as f32);
                }
                continue;
            }
            match (p.ty, ascii) {
                (PropType::Scalar(s), true) => {
                    self.ascii_number(e, rec, s, &p.name)?;
                }
                (PropType::Scalar(s), false) => self.skip_bytes(e, rec, s.size() as u64)?,
                (PropType::List(c, s), _) => {
                    let n = if ascii { self.ascii_count(e, rec, c, &p.name)? } else { self.read_bin_count(e, rec, c, be)? };
                    if !want {
                        if ascii {
                            for _ in 0..n {
                                self.ascii_number(e, rec, s, &p.name)?;
                            }
                        } else {
                            self.skip_bytes(e, rec, n.saturating_mul(s.size() as u64))?;
                        }
                        continue;
                    }
                    if n < 3 {
                        return Err(Error::input(self.loc(&e.name, rec, start), format!("face with {n} vertex index(es); a face needs at least 3")));
                    }
                    if n > 3 {
                        self.stats.polygons += 1;
                    }
                    if deferred {
                        // Wedge faces are fanned once their texcoords are read.
                        for _ in 0..n {
                            let x = if ascii {
                                self.ascii_number(e, rec, s, &p.name)? as i64
                            } else {
                                if !self.input.ensure(s.size())? {
                                    return Err(self.truncated(e, rec));
                                }
                                let i = bin_i64(&self.input.buf, self.input.pos, s, be);
                                self.input.pos += s.size();
                                i
                            };
                            self.face_idx.push(x);
                        }
                    } else if ascii {
                        for _ in 0..n {
                            let x = self.ascii_number(e, rec, s, &p.name)?;
                            self.fan_push(&mut fan, x as i64, e, rec, start, sink)?;
                        }
                    } else {
                        // Items are read as they arrive: a declared length never sizes a buffer.
                        let sz = s.size();
                        let mut left = n;
                        while left > 0 {
                            if !self.input.ensure(sz)? {
                                return Err(self.truncated(e, rec));
                            }
                            let k = ((self.input.avail() / sz) as u64).min(left) as usize;
                            for j in 0..k {
                                let i = bin_i64(&self.input.buf, self.input.pos + j * sz, s, be);
                                self.fan_push(&mut fan, i, e, rec, start, sink)?;
                            }
                            self.input.pos += k * sz;
                            left -= k as u64;
                        }
                    }
                }
            }
        }
        if deferred {
            self.fan_deferred(e, rec, start, tc_prop.is_some(), tex_prop.is_some(), sink)?;
        }
        self.stats.faces += 1;
        Ok(())
    }

    /// A face's `texnumber` as its material: -1 is [`Vertex::NO_TEXTURE`];
    /// anything else must name one of the header's `comment TextureFile`
    /// textures.
    fn texnumber(&self, x: i64, e: &ElementDef, rec: u64, at: u64) -> Result<u16> {
        let n = self.header.texture_count() as i64;
        match x {
            -1 => Ok(Vertex::NO_TEXTURE),
            // NO_TEXTURE (65535) is reserved: ids stop below it.
            _ if (0..n.min(Vertex::NO_TEXTURE as i64)).contains(&x) => Ok(x as u16),
            _ => Err(Error::input(
                self.loc(&e.name, rec, at),
                format!(
                    "texnumber {x} names no texture: the header's {n} 'comment TextureFile' line(s) allow 0..={} (or -1 for none)",
                    (n.min(Vertex::NO_TEXTURE as i64) - 1)
                ),
            )),
        }
    }

    /// Fans the face just read (`face_idx`) with its per-wedge uvs
    /// (`face_tc`, two per corner, when `wedges`) and its material
    /// (`face_mat`, when `material`).
    fn fan_deferred(&mut self, e: &ElementDef, rec: u64, start: u64, wedges: bool, material: bool, sink: &mut dyn BodySink) -> Result<()> {
        let n = self.face_idx.len();
        if wedges && self.face_tc.len() != 2 * n {
            // Not MeshLab's u and v per corner (a list of another use):
            // the corners keep their vertices' uvs (NaN marks it).
            self.face_tc.clear();
            self.face_tc.resize(2 * n, f32::NAN);
        }
        let nv = self.header.vertex_count();
        for &i in &self.face_idx {
            if i < 0 || i as u64 >= nv {
                return Err(self.bad_index(e, rec, start, i, nv));
            }
        }
        let uv = |k: usize, tc: &[f32]| [tc[2 * k], tc[2 * k + 1]];
        for k in 2..n {
            let c = [0, k - 1, k];
            let t = c.map(|j| self.face_idx[j] as u64);
            if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] {
                self.stats.degenerate += 1;
                continue;
            }
            self.tris.push(t);
            if wedges {
                self.wedges.push(c.map(|j| uv(j, &self.face_tc)));
            }
            if material {
                self.mats.push(self.face_mat);
            }
            if self.tris.len() == BATCH {
                self.flush_triangles(sink)?;
            }
        }
        Ok(())
    }

    /// Adds one polygon corner: validates it and emits the fan triangle it closes.
    #[inline]
    fn fan_push(&mut self, fan: &mut Fan, i: i64, e: &ElementDef, rec: u64, start: u64, sink: &mut dyn BodySink) -> Result<()> {
        let nv = self.header.vertex_count();
        if i < 0 || i as u64 >= nv {
            return Err(self.bad_index(e, rec, start, i, nv));
        }
        let i = i as u64;
        match fan.k {
            0 => fan.first = i,
            1 => fan.prev = i,
            _ => {
                let t = [fan.first, fan.prev, i];
                if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] {
                    self.stats.degenerate += 1;
                } else {
                    self.tris.push(t);
                    if self.tris.len() == BATCH {
                        self.flush_triangles(sink)?;
                    }
                }
                fan.prev = i;
            }
        }
        fan.k += 1;
        Ok(())
    }

    /// Skips `n` bytes of record `rec`, a buffer at a time.
    fn skip_bytes(&mut self, e: &ElementDef, rec: u64, n: u64) -> Result<()> {
        let mut left = n;
        while left > 0 {
            if !self.input.ensure(1)? {
                return Err(self.truncated(e, rec));
            }
            let k = (self.input.avail() as u64).min(left) as usize;
            self.input.pos += k;
            left -= k as u64;
        }
        Ok(())
    }

    fn bad_index(&self, e: &ElementDef, rec: u64, start: u64, i: i64, nv: u64) -> Error {
        let msg = if i < 0 { format!("negative vertex index {i}") } else { format!("vertex index {i} out of range (the file has {nv} vertices)") };
        Error::input(self.loc(&e.name, rec, start), msg)
    }

    fn flush_triangles(&mut self, sink: &mut dyn BodySink) -> Result<()> {
        if !self.tris.is_empty() {
            if !self.wedges.is_empty() {
                debug_assert_eq!(self.wedges.len(), self.tris.len());
                sink.wedge_uvs(&self.wedges)?;
                self.wedges.clear();
            }
            if !self.mats.is_empty() {
                debug_assert_eq!(self.mats.len(), self.tris.len());
                sink.materials(&self.mats)?;
                self.mats.clear();
            }
            sink.triangles(&self.tris)?;
            self.stats.triangles += self.tris.len() as u64;
            self.tris.clear();
            self.tick()?;
        }
        Ok(())
    }

    // ----------------------------------------------------------------- helpers

    fn read_bin_count(&mut self, e: &ElementDef, rec: u64, c: Scalar, be: bool) -> Result<u64> {
        if !self.input.ensure(c.size())? {
            return Err(self.truncated(e, rec));
        }
        let at = self.input.offset();
        let n = bin_i64(&self.input.buf, self.input.pos, c, be);
        if n < 0 || c.is_float() {
            return Err(Error::input(self.loc(&e.name, rec, at), format!("invalid list length {n}")));
        }
        self.input.pos += c.size();
        Ok(n as u64)
    }

    fn skip_element(&mut self, e: &ElementDef) -> Result<()> {
        let ascii = self.header.encoding == Encoding::Ascii;
        let be = self.header.encoding == Encoding::BinaryBe;
        if e.props.is_empty() {
            return Ok(()); // records of nothing: no bytes, whatever the count
        }
        if let (false, Some(size)) = (ascii, e.fixed_size()) {
            let size = size as u64;
            let total = e.count.saturating_mul(size);
            let mut done = 0u64;
            while done < total {
                if !self.input.ensure(1)? {
                    return Err(self.truncated(e, done / size));
                }
                let n = (self.input.avail() as u64).min(total - done);
                self.input.pos += n as usize;
                done += n;
                self.tick()?;
            }
            return Ok(());
        }
        for rec in 0..e.count {
            for p in &e.props {
                match (p.ty, ascii) {
                    (PropType::Scalar(s), true) => {
                        self.ascii_number(e, rec, s, &p.name)?;
                    }
                    (PropType::Scalar(s), false) => self.skip_bytes(e, rec, s.size() as u64)?,
                    (PropType::List(c, s), true) => {
                        let n = self.ascii_count(e, rec, c, &p.name)?;
                        for _ in 0..n {
                            self.ascii_number(e, rec, s, &p.name)?;
                        }
                    }
                    (PropType::List(c, s), false) => {
                        let n = self.read_bin_count(e, rec, c, be)?;
                        self.skip_bytes(e, rec, n.saturating_mul(s.size() as u64))?;
                    }
                }
            }
            if rec % 65536 == 0 {
                self.tick()?;
            }
        }
        Ok(())
    }

    fn ascii_number(&mut self, e: &ElementDef, rec: u64, ty: Scalar, prop: &str) -> Result<f64> {
        let mut t = AsciiTok { input: &mut self.input };
        let Some((tok, off)) = t.next_token()? else {
            return Err(self.truncated(e, rec));
        };
        let s = std::str::from_utf8(&tok).unwrap_or("");
        let parsed = if ty.is_float() { s.parse::<f64>().ok() } else { s.parse::<i64>().ok().map(|x| x as f64) };
        match parsed {
            // "inf"/"nan" literals go on to the coordinate checks; a
            // finite token that overflows its type (parsed as ±inf or out
            // of range) is an error here.
            Some(x) if ty.holds(x) || (ty.is_float() && (x.is_nan() || s.to_ascii_lowercase().contains("inf"))) => Ok(x),
            Some(_) => Err(Error::input(
                self.loc(&e.name, rec, off),
                format!("property '{prop}': '{}' is out of range for {}", String::from_utf8_lossy(&tok), ty.name()),
            )),
            None => {
                Err(Error::input(self.loc(&e.name, rec, off), format!("property '{prop}': '{}' is not a valid {}", String::from_utf8_lossy(&tok), ty.name())))
            }
        }
    }

    fn ascii_count(&mut self, e: &ElementDef, rec: u64, ty: Scalar, prop: &str) -> Result<u64> {
        let off = self.input.offset();
        let x = self.ascii_number(e, rec, ty, prop)?;
        if x < 0.0 {
            return Err(Error::input(self.loc(&e.name, rec, off), format!("invalid list length {x}")));
        }
        Ok(x as u64)
    }
}

fn assemble_vertex(plan: &VertexPlan, vals: &[f64], e: &ElementDef) -> Vertex {
    let ty = |i: usize| match e.props[i].ty {
        PropType::Scalar(s) => s,
        PropType::List(..) => unreachable!(),
    };
    let mut v = Vertex { pos: plan.pos.map(|i| vals[i]), ..Default::default() };
    if let Some(n) = plan.normal {
        v.normal = n.map(|i| vals[i] as f32);
    }
    if let Some(c) = plan.color {
        for a in 0..3 {
            v.color[a] = color_u8(vals[c[a]], ty(c[a]));
        }
    }
    if let Some(a) = plan.alpha {
        v.color[3] = color_u8(vals[a], ty(a));
    }
    if let Some(u) = plan.uv {
        v.uv = u.map(|i| vals[i] as f32);
    }
    v
}

/// Fan triangulation state of the polygon being read: (p0, p_k-1, p_k).
struct Fan {
    first: u64,
    prev: u64,
    k: u64,
}

/// Whitespace tokenizer over the buffered input (ascii bodies).
struct AsciiTok<'a> {
    input: &'a mut Input,
}

impl AsciiTok<'_> {
    /// Next token and its byte offset, or None at end of file.
    fn next_token(&mut self) -> Result<Option<(Vec<u8>, u64)>> {
        loop {
            if !self.input.ensure(1)? {
                return Ok(None);
            }
            let b = self.input.buf[self.input.pos];
            if b.is_ascii_whitespace() {
                self.input.pos += 1;
            } else {
                break;
            }
        }
        let off = self.input.offset();
        let mut tok = Vec::with_capacity(24);
        loop {
            if !self.input.ensure(1)? {
                break;
            }
            let b = self.input.buf[self.input.pos];
            if b.is_ascii_whitespace() {
                break;
            }
            tok.push(b);
            self.input.pos += 1;
            if tok.len() > 4096 {
                break;
            }
        }
        Ok(Some((tok, off)))
    }
}

/// A sink that collects everything in memory (tests, small inputs, `ply-info`).
#[derive(Default, Debug, Clone)]
pub struct CollectSink {
    pub vertices: Vec<Vertex>,
    pub triangles: Vec<[u64; 3]>,
    /// Per-wedge uvs of `triangles` (faces with a `texcoord` list) until
    /// [`CollectSink::split_wedges`] makes them vertices.
    pub wedges: Vec<[[f32; 2]; 3]>,
    /// Material of each of `triangles` (inputs with
    /// [`AttrSet::MATERIAL`]) until [`CollectSink::split_wedges`] gives
    /// it to their corners.
    pub materials: Vec<u16>,
}

impl CollectSink {
    /// Per-wedge uvs made vertices: one per distinct (vertex, uv) corner,
    /// the first uv met at a vertex taking the vertex itself (numbers kept
    /// where every corner agrees); NaN wedges keep the vertex's uv.
    ///
    /// With per-triangle materials, corners are split by (vertex, uv,
    /// material) the same way, so a vertex where materials meet becomes
    /// one per material and every triangle's corners carry its material.
    pub fn split_wedges(&mut self) {
        if !self.materials.is_empty() {
            return self.split_materials();
        }
        if self.wedges.is_empty() {
            return;
        }
        let mut ids: std::collections::HashMap<(u64, [u32; 2]), u64> = std::collections::HashMap::new();
        // A vertex a NaN corner uses keeps its own uv.
        let mut taken = vec![false; self.vertices.len()];
        for (t, w) in self.triangles.iter().zip(&self.wedges) {
            for c in 0..3 {
                taken[t[c] as usize] |= w[c].iter().any(|x| x.is_nan());
            }
        }
        for (t, w) in self.triangles.iter_mut().zip(&self.wedges) {
            for c in 0..3 {
                if w[c].iter().any(|x| x.is_nan()) {
                    continue;
                }
                let v = t[c] as usize;
                let key = (t[c], w[c].map(f32::to_bits));
                t[c] = match ids.get(&key) {
                    Some(&id) => id,
                    None if !taken[v] => {
                        taken[v] = true;
                        self.vertices[v].uv = w[c];
                        ids.insert(key, v as u64);
                        v as u64
                    }
                    None => {
                        let nv = Vertex { uv: w[c], ..self.vertices[v] };
                        self.vertices.push(nv);
                        let id = self.vertices.len() as u64 - 1;
                        ids.insert(key, id);
                        id
                    }
                };
            }
        }
        self.wedges = Vec::new();
    }
}

impl CollectSink {
    /// [`CollectSink::split_wedges`] with per-triangle materials (and
    /// maybe per-wedge uvs): one vertex per distinct (vertex, uv,
    /// material) corner, the first met taking the vertex itself.
    fn split_materials(&mut self) {
        debug_assert_eq!(self.materials.len(), self.triangles.len());
        let own: Vec<[f32; 2]> = self.vertices.iter().map(|v| v.uv).collect();
        let mut ids: std::collections::HashMap<(u64, [u32; 2], u16), u64> = std::collections::HashMap::new();
        let mut taken = vec![false; self.vertices.len()];
        for (k, t) in self.triangles.iter_mut().enumerate() {
            let m = self.materials[k];
            for c in 0..3 {
                let v = t[c] as usize;
                let uv = match self.wedges.get(k) {
                    Some(w) if !w[c].iter().any(|x| x.is_nan()) => w[c],
                    _ => own[v],
                };
                let key = (t[c], uv.map(f32::to_bits), m);
                t[c] = match ids.get(&key) {
                    Some(&id) => id,
                    None if !taken[v] => {
                        taken[v] = true;
                        self.vertices[v].uv = uv;
                        self.vertices[v].material = m;
                        ids.insert(key, v as u64);
                        v as u64
                    }
                    None => {
                        self.vertices.push(Vertex { uv, material: m, ..self.vertices[v] });
                        let id = self.vertices.len() as u64 - 1;
                        ids.insert(key, id);
                        id
                    }
                };
            }
        }
        self.wedges = Vec::new();
        self.materials = Vec::new();
    }
}

impl BodySink for CollectSink {
    fn vertices(&mut self, first: u64, batch: &[Vertex]) -> Result<()> {
        debug_assert_eq!(first, self.vertices.len() as u64);
        self.vertices.extend_from_slice(batch);
        Ok(())
    }
    fn triangles(&mut self, batch: &[[u64; 3]]) -> Result<()> {
        self.triangles.extend_from_slice(batch);
        Ok(())
    }
    fn wedge_uvs(&mut self, batch: &[[[f32; 2]; 3]]) -> Result<()> {
        self.wedges.extend_from_slice(batch);
        Ok(())
    }
    fn materials(&mut self, batch: &[u16]) -> Result<()> {
        self.materials.extend_from_slice(batch);
        Ok(())
    }
}

/// Reads a whole PLY into memory. For small meshes only.
pub fn read_all(path: &Path) -> Result<(PlyHeader, CollectSink, BodyStats)> {
    let header = super::read_header(path)?;
    let mut sink = CollectSink::default();
    let stats = read_body(path, &header, &mut sink, &Progress::hidden())?;
    sink.split_wedges();
    Ok((header, sink, stats))
}

#[cfg(test)]
mod tests {
    use super::*;

    const HEAD: &str = "comment TextureFile a.png\ncomment TextureFile b.png\nelement vertex 5\nproperty float x\nproperty float y\nproperty float z\nproperty float s\nproperty float t\nelement face 2\nproperty list uchar int vertex_indices\nproperty int texnumber\nend_header\n";
    const VERTS: [[f32; 5]; 5] = [[0., 0., 0., 0., 0.], [1., 0., 0., 1., 0.], [1., 1., 0., 1., 1.], [0., 1., 0., 0., 1.], [2., 0., 0., 0.5, 0.5]];
    /// A quad (texture 1) and a triangle (texture 0) sharing vertices 1 and 2.
    const FACES: [(&[i32], i32); 2] = [(&[0, 1, 2, 3], 1), (&[1, 4, 2], 0)];

    fn binary(faces: &[(&[i32], i32)]) -> Vec<u8> {
        let mut b = format!("ply\nformat binary_little_endian 1.0\n{HEAD}").into_bytes();
        for v in VERTS {
            v.iter().for_each(|x| b.extend_from_slice(&x.to_le_bytes()));
        }
        for (idx, tex) in faces {
            b.push(idx.len() as u8);
            idx.iter().for_each(|i| b.extend_from_slice(&i.to_le_bytes()));
            b.extend_from_slice(&tex.to_le_bytes());
        }
        b
    }

    fn ascii(faces: &[(&[i32], i32)]) -> Vec<u8> {
        let mut s = format!("ply\nformat ascii 1.0\n{HEAD}");
        for v in VERTS {
            s += &format!("{} {} {} {} {}\n", v[0], v[1], v[2], v[3], v[4]);
        }
        for (idx, tex) in faces {
            s += &format!("{} {} {tex}\n", idx.len(), idx.iter().map(|i| i.to_string()).collect::<Vec<_>>().join(" "));
        }
        s.into_bytes()
    }

    fn read(bytes: &[u8]) -> Result<(PlyHeader, CollectSink)> {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("m.ply");
        std::fs::write(&p, bytes).unwrap();
        read_all(&p).map(|(h, s, _)| (h, s))
    }

    #[test]
    fn texnumber_gives_each_triangle_its_material() {
        for bytes in [binary(&FACES), ascii(&FACES)] {
            let (h, m) = read(&bytes).unwrap();
            assert!(h.attrs.material() && h.attrs.uv(), "{}", h.attrs.describe());
            assert_eq!(h.texture_count(), 2);
            // The quad fans into two triangles that keep its texnumber.
            assert_eq!(m.triangles.len(), 3);
            let mats: Vec<[u16; 3]> = m.triangles.iter().map(|t| t.map(|i| m.vertices[i as usize].material)).collect();
            assert_eq!(mats, [[1; 3], [1; 3], [0; 3]]);
            // Vertices 1 and 2 are split where the materials meet, positions and uvs kept.
            assert_eq!(m.vertices.len(), 7);
            for t in &m.triangles {
                for &i in t {
                    let v = &m.vertices[i as usize];
                    let src = VERTS.iter().find(|s| s[0] as f64 == v.pos[0] && s[1] as f64 == v.pos[1]).unwrap();
                    assert_eq!(v.uv, [src[3], src[4]]);
                }
            }
        }
    }

    #[test]
    fn texnumber_minus_one_is_no_texture() {
        let faces: [(&[i32], i32); 2] = [(&[0, 1, 2, 3], -1), (&[1, 4, 2], 1)];
        let (_, m) = read(&binary(&faces)).unwrap();
        let mats: Vec<u16> = m.triangles.iter().map(|t| m.vertices[t[0] as usize].material).collect();
        assert_eq!(mats, [Vertex::NO_TEXTURE, Vertex::NO_TEXTURE, 1]);
    }

    #[test]
    fn texnumber_without_texture_comments_is_no_material() {
        let b = String::from_utf8(ascii(&FACES)).unwrap().replace("comment TextureFile a.png\ncomment TextureFile b.png\n", "");
        let (h, m) = read(b.as_bytes()).unwrap();
        assert!(!h.attrs.material() && h.attrs.uv());
        assert_eq!((m.vertices.len(), m.triangles.len()), (5, 3));
    }

    #[test]
    fn texnumber_out_of_range_names_record_and_offset() {
        let faces: [(&[i32], i32); 2] = [(&[0, 1, 2, 3], 1), (&[1, 4, 2], 2)];
        let b = binary(&faces);
        // Record 1's texnumber: its last 4 bytes.
        let at = b.len() - 4;
        let e = read(&b).unwrap_err().to_string();
        assert!(e.contains("element 'face' record 1") && e.contains(&format!("byte offset {at}")) && e.contains("texnumber 2"), "{e}");
        let a = ascii(&faces);
        let at = a.len() - 2;
        let e = read(&a).unwrap_err().to_string();
        assert!(e.contains("element 'face' record 1") && e.contains(&format!("byte offset {at}")) && e.contains("texnumber 2"), "{e}");
        let faces: [(&[i32], i32); 2] = [(&[0, 1, 2, 3], -2), (&[1, 4, 2], 0)];
        let e = read(&binary(&faces)).unwrap_err().to_string();
        assert!(e.contains("record 0") && e.contains("texnumber -2"), "{e}");
    }

    #[test]
    fn texnumber_with_wedge_texcoords() {
        // MeshLab's order: vertex_indices, texcoord, texnumber; positions only on the vertices.
        let s = "ply\nformat ascii 1.0\ncomment TextureFile a.png\ncomment TextureFile b.png\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\nelement face 2\nproperty list uchar int vertex_indices\nproperty list uchar float texcoord\nproperty int texnumber\nend_header\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2 6 0 0 .5 0 .5 .5 0\n3 0 2 3 6 0 0 .5 .5 0 .5 1\n";
        let (h, m) = read(s.as_bytes()).unwrap();
        assert!(h.attrs.material() && h.attrs.uv());
        let mats: Vec<u16> = m.triangles.iter().map(|t| m.vertices[t[0] as usize].material).collect();
        assert_eq!(mats, [0, 1]);
        // Shared corners 0 and 2 split: different materials (their uvs agree).
        assert_eq!(m.vertices.len(), 6);
        assert!(m.triangles.iter().all(|t| t.iter().all(|&i| m.vertices[i as usize].material == m.vertices[t[0] as usize].material)));
    }
}

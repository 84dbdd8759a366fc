//! PLY stage: streams any PLY (ascii, binary little/big endian, every scalar
//! type, extra properties and elements, polygons) into vertices and triangles.
//!
//! Takes: a path to a `.ply` file. Gives: a parsed [`PlyHeader`] (elements in
//! file order, the recognised attribute set, the body's byte offset) and a
//! body reader ([`read::PlyBody`]) that calls back once per vertex and once
//! per fan-triangulated triangle, never holding the mesh in memory.
//!
//! The header grammar is ply-rs-bw's (so `int8`…`float64` names, comments and
//! `obj_info` lines behave like the reference crate); the body is decoded here
//! with typed, offset-compiled decoders over large sequential buffers (no
//! per-element hash map), which is what makes binary ingest run at memory
//! speed. [`write`] writes PLY files (used by `extract`, the generator and
//! tests).

pub mod read;
pub mod write;

use crate::error::{Error, Location, Result};
use crate::mesh::AttrSet;
use std::io::Read;
use std::path::Path;

/// Body encoding.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Encoding {
    Ascii,
    BinaryLe,
    BinaryBe,
}

impl Encoding {
    pub fn header_name(self) -> &'static str {
        match self {
            Encoding::Ascii => "ascii",
            Encoding::BinaryLe => "binary_little_endian",
            Encoding::BinaryBe => "binary_big_endian",
        }
    }
}

/// PLY scalar types (`char`/`int8` … `double`/`float64`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    pub fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }
    pub fn is_float(self) -> bool {
        matches!(self, Scalar::F32 | Scalar::F64)
    }
    /// Whether the finite value `x` is representable in this type
    /// (integers in range; 1e39 overflows a `float`). False for NaN and
    /// infinities.
    pub fn holds(self, x: f64) -> bool {
        let (lo, hi) = match self {
            Scalar::I8 => (i8::MIN as f64, i8::MAX as f64),
            Scalar::U8 => (0.0, u8::MAX as f64),
            Scalar::I16 => (i16::MIN as f64, i16::MAX as f64),
            Scalar::U16 => (0.0, u16::MAX as f64),
            Scalar::I32 => (i32::MIN as f64, i32::MAX as f64),
            Scalar::U32 => (0.0, u32::MAX as f64),
            Scalar::F32 => (-(f32::MAX as f64), f32::MAX as f64),
            Scalar::F64 => (f64::MIN, f64::MAX),
        };
        (lo..=hi).contains(&x)
    }
    /// The classic PLY name (`uchar`, `int`, `float`, ...).
    pub fn name(self) -> &'static str {
        match self {
            Scalar::I8 => "char",
            Scalar::U8 => "uchar",
            Scalar::I16 => "short",
            Scalar::U16 => "ushort",
            Scalar::I32 => "int",
            Scalar::U32 => "uint",
            Scalar::F32 => "float",
            Scalar::F64 => "double",
        }
    }
    fn from_ply_rs(t: &ply_rs_bw::ply::ScalarType) -> Scalar {
        use ply_rs_bw::ply::ScalarType as S;
        match t {
            S::Char => Scalar::I8,
            S::UChar => Scalar::U8,
            S::Short => Scalar::I16,
            S::UShort => Scalar::U16,
            S::Int => Scalar::I32,
            S::UInt => Scalar::U32,
            S::Float => Scalar::F32,
            S::Double => Scalar::F64,
        }
    }
}

/// A property type: a scalar or a list (count type, item type).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PropType {
    Scalar(Scalar),
    List(Scalar, Scalar),
}

#[derive(Clone, Debug, PartialEq)]
pub struct PropDef {
    pub name: String,
    pub ty: PropType,
}

#[derive(Clone, Debug, PartialEq)]
pub struct ElementDef {
    pub name: String,
    pub count: u64,
    pub props: Vec<PropDef>,
}

impl ElementDef {
    pub fn prop(&self, name: &str) -> Option<usize> {
        self.props.iter().position(|p| p.name == name)
    }
    /// Record size when every property is a scalar (fixed-stride records).
    pub fn fixed_size(&self) -> Option<usize> {
        self.props
            .iter()
            .map(|p| match p.ty {
                PropType::Scalar(s) => Some(s.size()),
                PropType::List(..) => None,
            })
            .sum()
    }
}

/// Parsed header, plus what octolod recognised in it.
#[derive(Clone, Debug)]
pub struct PlyHeader {
    pub encoding: Encoding,
    /// Elements in file order.
    pub elements: Vec<ElementDef>,
    pub comments: Vec<String>,
    /// Byte offset of the first body byte.
    pub body_offset: u64,
    /// Index of the `vertex` element.
    pub vertex_elem: usize,
    /// Index of the `face` element (None: no faces declared).
    pub face_elem: Option<usize>,
    /// Attributes carried from the vertex element.
    pub attrs: AttrSet,
}

impl PlyHeader {
    pub fn vertex_count(&self) -> u64 {
        self.elements[self.vertex_elem].count
    }
    pub fn face_count(&self) -> u64 {
        self.face_elem.map(|i| self.elements[i].count).unwrap_or(0)
    }
}

/// Largest header we accept; real headers are a few hundred bytes.
const MAX_HEADER: usize = 1 << 20;

/// Reads and parses the header of `path`.
pub fn read_header(path: &Path) -> Result<PlyHeader> {
    let mut f = std::fs::File::open(path).map_err(|e| Error::io(path, "open", e))?;
    let mut buf = Vec::with_capacity(4096);
    let mut chunk = [0u8; 4096];
    let body_offset = loop {
        if let Some(end) = find_end_header(&buf) {
            break end;
        }
        if buf.len() > MAX_HEADER {
            return Err(Error::input(loc(path), "no 'end_header' line in the first 1 MiB: not a PLY header"));
        }
        let n = f.read(&mut chunk).map_err(|e| Error::io(path, "read", e))?;
        if n == 0 {
            let msg = if buf.starts_with(b"ply") {
                "unexpected end of file inside the header (missing 'end_header')"
            } else {
                "not a PLY file (does not start with 'ply')"
            };
            return Err(Error::input(loc(path), msg));
        }
        buf.extend_from_slice(&chunk[..n]);
    };
    parse_header(path, &buf[..body_offset], body_offset as u64)
}

fn loc(path: &Path) -> Location {
    Location { file: path.to_path_buf(), ..Default::default() }
}

/// What the grammar would let pass silently: a `format` version other
/// than 1.0, and duplicate elements or properties (its maps would merge
/// them into a misleading later error). Errors name both lines.
fn check_header_lines(path: &Path, text: &str) -> Result<()> {
    let at = |line: usize, msg: String| {
        let mut l = loc(path);
        l.line = Some(line as u64);
        Error::input(l, msg)
    };
    let mut elements: std::collections::HashMap<&str, usize> = std::collections::HashMap::new();
    let mut props: std::collections::HashMap<&str, usize> = std::collections::HashMap::new();
    let mut current: Option<&str> = None;
    for (i, line) in text.lines().enumerate() {
        let n = i + 1;
        let t: Vec<&str> = line.split_ascii_whitespace().collect();
        match t.first().copied() {
            Some("format") if t.len() >= 3 && t[2] != "1.0" => {
                return Err(at(n, format!("PLY format version {} is not supported (only 1.0)", t[2])));
            }
            Some("element") if t.len() >= 2 => {
                if let Some(first) = elements.insert(t[1], n) {
                    return Err(at(n, format!("element '{}' declared twice (lines {first} and {n})", t[1])));
                }
                current = Some(t[1]);
                props.clear();
            }
            Some("property") if t.len() >= 3 => {
                let name = t[t.len() - 1];
                if let Some(first) = props.insert(name, n) {
                    return Err(at(
                        n,
                        format!("property '{name}' of element '{}' declared twice (lines {first} and {n})", current.unwrap_or("?")),
                    ));
                }
            }
            Some("end_header") => break,
            _ => {}
        }
    }
    Ok(())
}

/// Offset just past the `end_header` line terminator, if present.
fn find_end_header(buf: &[u8]) -> Option<usize> {
    let mut start = 0;
    while start < buf.len() {
        let nl = buf[start..].iter().position(|&b| b == b'\n')? + start;
        let line = &buf[start..nl];
        let line = line.strip_suffix(b"\r").unwrap_or(line);
        if line.trim_ascii() == b"end_header" {
            return Some(nl + 1);
        }
        start = nl + 1;
    }
    None
}

/// Parses header bytes (ending with the `end_header` line) with ply-rs-bw's grammar.
pub fn parse_header(path: &Path, bytes: &[u8], body_offset: u64) -> Result<PlyHeader> {
    if !bytes.starts_with(b"ply") {
        return Err(Error::input(loc(path), "not a PLY file (does not start with 'ply')"));
    }
    if std::str::from_utf8(bytes).is_err() {
        return Err(Error::input(loc(path), "header is not valid text"));
    }
    check_header_lines(path, std::str::from_utf8(bytes).unwrap_or(""))?;
    let parser = ply_rs_bw::parser::Parser::<ply_rs_bw::ply::DefaultElement>::new();
    let mut reader = ply_rs_bw::parser::Reader::new(bytes);
    let h = parser.read_header(&mut reader).map_err(|e| {
        let mut l = loc(path);
        l.line = e.line().map(|x| x as u64);
        let msg = e.to_string();
        let msg = msg.split_once(": ").filter(|_| e.line().is_some()).map(|(_, m)| m.to_string()).unwrap_or(msg);
        Error::input(l, format!("unsupported or malformed header line: {}", msg.replace('\n', " ").replace('\t', "")))
    })?;
    let encoding = match h.encoding {
        ply_rs_bw::ply::Encoding::Ascii => Encoding::Ascii,
        ply_rs_bw::ply::Encoding::BinaryLittleEndian => Encoding::BinaryLe,
        ply_rs_bw::ply::Encoding::BinaryBigEndian => Encoding::BinaryBe,
    };
    let elements: Vec<ElementDef> = h
        .elements
        .values()
        .map(|e| ElementDef {
            name: e.name.clone(),
            count: e.count as u64,
            props: e
                .properties
                .values()
                .map(|p| PropDef {
                    name: p.name.clone(),
                    ty: match &p.data_type {
                        ply_rs_bw::ply::PropertyType::Scalar(s) => PropType::Scalar(Scalar::from_ply_rs(s)),
                        ply_rs_bw::ply::PropertyType::List(c, s) => {
                            PropType::List(Scalar::from_ply_rs(c), Scalar::from_ply_rs(s))
                        }
                    },
                })
                .collect(),
        })
        .collect();
    let comments = h.comments.clone();
    let elem_loc = |name: &str| Location { file: path.to_path_buf(), element: Some(name.to_string()), ..Default::default() };
    let vertex_elem = elements
        .iter()
        .position(|e| e.name == "vertex")
        .ok_or_else(|| Error::input(loc(path), "no 'vertex' element in the header"))?;
    let face_elem = elements.iter().position(|e| e.name == "face");
    let v = &elements[vertex_elem];
    for axis in ["x", "y", "z"] {
        match v.prop(axis).map(|i| v.props[i].ty) {
            None => return Err(Error::input(elem_loc("vertex"), format!("no '{axis}' property"))),
            Some(PropType::List(..)) => {
                return Err(Error::input(elem_loc("vertex"), format!("property '{axis}' is a list, expected a scalar")))
            }
            Some(PropType::Scalar(_)) => {}
        }
    }
    let scalar = |name: &str| match v.prop(name).map(|i| v.props[i].ty) {
        Some(PropType::Scalar(s)) => Some(s),
        _ => None,
    };
    let mut attrs = AttrSet::POSITION_ONLY;
    // Double positions stay double; so do 32-bit integer ones (beyond f32's 24-bit mantissa).
    if ["x", "y", "z"].iter().any(|a| matches!(scalar(a), Some(Scalar::F64 | Scalar::I32 | Scalar::U32))) {
        attrs = attrs.with(AttrSet::POS_F64, true);
    }
    if ["nx", "ny", "nz"].iter().all(|a| scalar(a).is_some()) {
        attrs = attrs.with(AttrSet::NORMAL, true);
    }
    if color_names(v).is_some() {
        attrs = attrs.with(AttrSet::COLOR, true);
        if v.prop("alpha").is_some_and(|i| matches!(v.props[i].ty, PropType::Scalar(_))) {
            attrs = attrs.with(AttrSet::ALPHA, true);
        }
    }
    if uv_names(v).is_some() {
        attrs = attrs.with(AttrSet::UV, true);
    }
    if let Some(fi) = face_elem {
        let f = &elements[fi];
        match face_index_prop(f) {
            Some(i) => {
                if let PropType::List(c, s) = f.props[i].ty {
                    if c.is_float() || s.is_float() {
                        return Err(Error::input(
                            elem_loc("face"),
                            format!("vertex index list uses a float type (list {} {})", c.name(), s.name()),
                        ));
                    }
                }
            }
            None => {
                return Err(Error::input(
                    elem_loc("face"),
                    "no 'vertex_indices' or 'vertex_index' list property",
                ))
            }
        }
    }
    Ok(PlyHeader { encoding, elements, comments, body_offset, vertex_elem, face_elem, attrs })
}

/// The color property names present (`red/green/blue` or `r/g/b` or `diffuse_*`).
pub(crate) fn color_names(v: &ElementDef) -> Option<[&'static str; 3]> {
    const SETS: [[&str; 3]; 3] =
        [["red", "green", "blue"], ["diffuse_red", "diffuse_green", "diffuse_blue"], ["r", "g", "b"]];
    SETS.into_iter().find(|set| {
        set.iter().all(|n| v.prop(n).is_some_and(|i| matches!(v.props[i].ty, PropType::Scalar(_))))
    })
}

/// The texture-coordinate property names present.
pub(crate) fn uv_names(v: &ElementDef) -> Option<[&'static str; 2]> {
    const SETS: [[&str; 2]; 4] = [["u", "v"], ["s", "t"], ["texture_u", "texture_v"], ["texture_s", "texture_t"]];
    SETS.into_iter().find(|set| {
        set.iter().all(|n| v.prop(n).is_some_and(|i| matches!(v.props[i].ty, PropType::Scalar(_))))
    })
}

/// Index of the face's vertex index list property.
pub(crate) fn face_index_prop(f: &ElementDef) -> Option<usize> {
    ["vertex_indices", "vertex_index"]
        .iter()
        .find_map(|n| f.prop(n).filter(|&i| matches!(f.props[i].ty, PropType::List(..))))
}

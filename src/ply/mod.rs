//! PLY stage: streams any PLY (ascii, binary little/big endian, every scalar
//! type, extra properties and elements, polygons) into vertices and triangles.
//!
//! Takes: a path to a `.ply` file. Gives: a parsed [`PlyHeader`] (elements in
//! file order, the recognised attribute set, the body's byte offset) and a
//! body reader ([`read::read_body`]) that calls back once per vertex and once
//! per fan-triangulated triangle, never holding the mesh in memory. Faces
//! may carry MeshLab's per-wedge `texcoord` and per-face `texnumber`
//! (which `comment TextureFile` texture they sample: [`AttrSet::MATERIAL`]).
//!
//! The header is read by a small grammar of our own ([`parse_header`]):
//! ply-rs-bw's rejected valid names (`.`, `:`, `$`, `/`, leading digits,
//! non-ASCII) and Latin-1 comments with raw parser dumps, and merged
//! duplicate declarations silently; ours names the line of every error,
//! and a unit test checks it agrees with ply-rs-bw on every header both
//! accept. The body is decoded here
//! with typed, offset-compiled decoders over large sequential buffers (no
//! per-element hash map), which is what makes binary ingest run at memory
//! speed. [`write`](mod@write) writes PLY files (used by `extract`, the generator and
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
    /// Attributes carried from the vertex element (and the faces: per-wedge
    /// `texcoord` gives uvs; `texnumber` with uvs and at least one `comment
    /// TextureFile` gives [`AttrSet::MATERIAL`]).
    pub attrs: AttrSet,
}

impl PlyHeader {
    pub fn vertex_count(&self) -> u64 {
        self.elements[self.vertex_elem].count
    }
    pub fn face_count(&self) -> u64 {
        self.face_elem.map(|i| self.elements[i].count).unwrap_or(0)
    }
    /// The textures the faces' `texnumber` chooses among (`comment
    /// TextureFile` lines, in order).
    pub fn texture_count(&self) -> usize {
        texture_files(&self.comments).len()
    }
}

/// Largest header we accept; real headers are a few hundred bytes.
const MAX_HEADER: usize = 1 << 20;

/// Reads and parses the header of `path`.
pub fn read_header(path: &Path) -> Result<PlyHeader> {
    let (mut f, file_len) = crate::io::open_regular(path, "open")?;
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
    let h = parse_header(path, &buf[..body_offset], body_offset as u64)?;
    check_body_size(path, &h, file_len)?;
    Ok(h)
}

/// Refuses a header whose element counts need more bytes than the file
/// holds (each record at least its fixed scalars and list counts in
/// binary, two bytes a value in ascii), before any reader sizes a buffer,
/// a bucket set or a scratch file from them.
fn check_body_size(path: &Path, h: &PlyHeader, file_len: u64) -> Result<()> {
    let avail = file_len.saturating_sub(h.body_offset) as u128;
    let mut need = 0u128;
    for e in &h.elements {
        let per = match h.encoding {
            Encoding::Ascii => 2 * e.props.len() as u128,
            _ => e
                .props
                .iter()
                .map(|p| match p.ty {
                    PropType::Scalar(s) | PropType::List(s, _) => s.size() as u128,
                })
                .sum(),
        };
        let before = need;
        need += e.count as u128 * per;
        // An ascii body's last value needs no separator after it.
        let floor = if h.encoding == Encoding::Ascii { need.saturating_sub(1) } else { need };
        if floor > avail {
            // The record the body ends in: exactly, for fixed-size binary
            // records; at the latest, where records can be longer.
            let record = ((avail.saturating_sub(before)) / per.max(1)) as u64;
            let exact = h.encoding != Encoding::Ascii && e.fixed_size().is_some();
            let l = Location {
                file: path.to_path_buf(),
                element: Some(e.name.clone()),
                record: exact.then_some(record),
                offset: Some(file_len),
                ..Default::default()
            };
            return Err(Error::input(
                l,
                format!(
                    "unexpected end of file: the header declares {} '{}' records, which with the elements before them need at least {floor} bytes, but the body holds {avail}{}",
                    e.count,
                    e.name,
                    if exact { String::new() } else { format!(" (it ends by record {record} at the latest)") }
                ),
            ));
        }
    }
    Ok(())
}

fn loc(path: &Path) -> Location {
    Location { file: path.to_path_buf(), ..Default::default() }
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

/// A scalar type name: the classic PLY names and the sized ones.
fn scalar_named(t: &[u8]) -> Option<Scalar> {
    Some(match t {
        b"char" | b"int8" => Scalar::I8,
        b"uchar" | b"uint8" => Scalar::U8,
        b"short" | b"int16" => Scalar::I16,
        b"ushort" | b"uint16" => Scalar::U16,
        b"int" | b"int32" => Scalar::I32,
        b"uint" | b"uint32" => Scalar::U32,
        b"float" | b"float32" => Scalar::F32,
        b"double" | b"float64" => Scalar::F64,
        _ => return None,
    })
}

const SCALAR_NAMES: &str = "char, uchar, short, ushort, int, uint, float, double (or int8 ... float64)";

/// The header's lines, read with PLY 1.0's grammar as Greg Turk's `ply.c`
/// reads it: whitespace-separated words, one declaration per line.
/// Element and property names are any run of non-space bytes (`.`, `:`,
/// `$`, `/`, a leading digit or non-ASCII text are all fine; bytes that
/// are not UTF-8 are kept as U+FFFD), comments and `obj_info` lines may
/// hold any bytes (Latin-1 is common). Every error names its line; a
/// duplicate element or property names both lines (merging them would
/// mislead a later error); a `format` version other than 1.0 is refused.
fn parse_lines(path: &Path, bytes: &[u8]) -> Result<(Encoding, Vec<ElementDef>, Vec<String>)> {
    let at = |line: usize, msg: String| {
        let mut l = loc(path);
        l.line = Some(line as u64);
        Error::input(l, msg)
    };
    let text = |t: &[u8]| String::from_utf8_lossy(t).into_owned();
    let mut encoding: Option<(Encoding, usize)> = None;
    let mut elements: Vec<ElementDef> = Vec::new();
    let mut element_line: std::collections::HashMap<String, usize> = std::collections::HashMap::new();
    let mut prop_line: std::collections::HashMap<String, usize> = std::collections::HashMap::new();
    let mut comments = Vec::new();
    for (i, raw) in bytes.split(|&b| b == b'\n').enumerate() {
        let n = i + 1;
        let raw = raw.strip_suffix(b"\r").unwrap_or(raw);
        let words: Vec<&[u8]> = raw.split(|b| b.is_ascii_whitespace()).filter(|w| !w.is_empty()).collect();
        if n == 1 {
            if words != [b"ply"] {
                return Err(at(n, "the first line must be 'ply'".into()));
            }
            continue;
        }
        let Some(&keyword) = words.first() else { continue };
        let malformed = |expected: &str| at(n, format!("malformed header line '{}': expected '{expected}'", text(raw).trim()));
        match keyword {
            b"comment" | b"obj_info" => {
                if keyword == b"comment" {
                    let rest = raw.trim_ascii_start().strip_prefix(b"comment").unwrap_or(b"");
                    comments.push(text(rest.trim_ascii()));
                }
            }
            b"format" => {
                if let Some((_, first)) = encoding {
                    return Err(at(n, format!("'format' declared twice (lines {first} and {n})")));
                }
                if words.len() != 3 {
                    return Err(malformed("format ascii|binary_little_endian|binary_big_endian 1.0"));
                }
                let enc = match words[1] {
                    b"ascii" => Encoding::Ascii,
                    b"binary_little_endian" => Encoding::BinaryLe,
                    b"binary_big_endian" => Encoding::BinaryBe,
                    other => return Err(at(n, format!("unknown format '{}' (expected ascii, binary_little_endian or binary_big_endian)", text(other)))),
                };
                if words[2] != b"1.0" {
                    return Err(at(n, format!("PLY format version {} is not supported (only 1.0)", text(words[2]))));
                }
                encoding = Some((enc, n));
            }
            b"element" => {
                if words.len() != 3 {
                    return Err(malformed("element <name> <count>"));
                }
                let name = text(words[1]);
                let count = std::str::from_utf8(words[2])
                    .ok()
                    .and_then(|c| c.parse::<u64>().ok())
                    .ok_or_else(|| at(n, format!("element '{name}': count '{}' is not a whole number below 2^64", text(words[2]))))?;
                if let Some(first) = element_line.insert(name.clone(), n) {
                    return Err(at(n, format!("element '{name}' declared twice (lines {first} and {n})")));
                }
                prop_line.clear();
                elements.push(ElementDef { name, count, props: Vec::new() });
            }
            b"property" => {
                let Some(e) = elements.last_mut() else {
                    return Err(at(n, "'property' before any 'element'".into()));
                };
                let scalar = |w: &[u8]| scalar_named(w).ok_or_else(|| at(n, format!("unknown property type '{}' (expected {SCALAR_NAMES})", text(w))));
                let (ty, name) = match words.len() {
                    3 if words[1] != b"list" => (PropType::Scalar(scalar(words[1])?), words[2]),
                    5 if words[1] == b"list" => {
                        let c = scalar(words[2])?;
                        if c.is_float() {
                            return Err(at(n, format!("list count type '{}' is not an integer type", text(words[2]))));
                        }
                        (PropType::List(c, scalar(words[3])?), words[4])
                    }
                    _ => return Err(malformed("property <type> <name>' or 'property list <count type> <item type> <name>")),
                };
                let name = text(name);
                if let Some(first) = prop_line.insert(name.clone(), n) {
                    return Err(at(n, format!("property '{name}' of element '{}' declared twice (lines {first} and {n})", e.name)));
                }
                e.props.push(PropDef { name, ty });
            }
            b"end_header" => {
                if words.len() != 1 {
                    return Err(malformed("end_header"));
                }
                break;
            }
            other => {
                return Err(at(
                    n,
                    format!(
                        "unsupported or malformed header line: unknown keyword '{}' (expected format, comment, obj_info, element, property or end_header)",
                        text(other)
                    ),
                ))
            }
        }
    }
    let Some((encoding, _)) = encoding else {
        return Err(Error::input(loc(path), "no 'format' line in the header"));
    };
    Ok((encoding, elements, comments))
}

/// Parses header bytes (ending with the `end_header` line).
pub fn parse_header(path: &Path, bytes: &[u8], body_offset: u64) -> Result<PlyHeader> {
    if !bytes.starts_with(b"ply") {
        return Err(Error::input(loc(path), "not a PLY file (does not start with 'ply')"));
    }
    let (encoding, elements, comments) = parse_lines(path, bytes)?;
    let elem_loc = |name: &str| Location { file: path.to_path_buf(), element: Some(name.to_string()), ..Default::default() };
    let vertex_elem = elements.iter().position(|e| e.name == "vertex").ok_or_else(|| Error::input(loc(path), "no 'vertex' element in the header"))?;
    let face_elem = elements.iter().position(|e| e.name == "face");
    let v = &elements[vertex_elem];
    for axis in ["x", "y", "z"] {
        match v.prop(axis).map(|i| v.props[i].ty) {
            None => return Err(Error::input(elem_loc("vertex"), format!("no '{axis}' property"))),
            Some(PropType::List(..)) => return Err(Error::input(elem_loc("vertex"), format!("property '{axis}' is a list, expected a scalar"))),
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
        // Per-wedge uvs (MeshLab's face `texcoord`) give the mesh uvs.
        if wedge_uv_prop(f).is_some() {
            attrs = attrs.with(AttrSet::UV, true);
        }
        // A face `texnumber` choosing among named textures gives each
        // face its material (only with uvs: without them there is nothing
        // to sample).
        if attrs.uv() && texnumber_prop(f).is_some() && !texture_files(&comments).is_empty() {
            attrs = attrs.with(AttrSet::MATERIAL, true);
        }
        match face_index_prop(f) {
            Some(i) => {
                if let PropType::List(c, s) = f.props[i].ty {
                    if c.is_float() || s.is_float() {
                        return Err(Error::input(elem_loc("face"), format!("vertex index list uses a float type (list {} {})", c.name(), s.name())));
                    }
                }
            }
            None => return Err(Error::input(elem_loc("face"), "no 'vertex_indices' or 'vertex_index' list property")),
        }
    }
    Ok(PlyHeader { encoding, elements, comments, body_offset, vertex_elem, face_elem, attrs })
}

/// The color property names present (`red/green/blue` or `r/g/b` or `diffuse_*`).
pub(crate) fn color_names(v: &ElementDef) -> Option<[&'static str; 3]> {
    const SETS: [[&str; 3]; 3] = [["red", "green", "blue"], ["diffuse_red", "diffuse_green", "diffuse_blue"], ["r", "g", "b"]];
    SETS.into_iter().find(|set| set.iter().all(|n| v.prop(n).is_some_and(|i| matches!(v.props[i].ty, PropType::Scalar(_)))))
}

/// The texture-coordinate property names present.
pub(crate) fn uv_names(v: &ElementDef) -> Option<[&'static str; 2]> {
    const SETS: [[&str; 2]; 4] = [["u", "v"], ["s", "t"], ["texture_u", "texture_v"], ["texture_s", "texture_t"]];
    SETS.into_iter().find(|set| set.iter().all(|n| v.prop(n).is_some_and(|i| matches!(v.props[i].ty, PropType::Scalar(_)))))
}

/// Index of the face's per-wedge uv list (`texcoord`, MeshLab's
/// convention: u and v per corner), when it is a list of numbers.
pub(crate) fn wedge_uv_prop(f: &ElementDef) -> Option<usize> {
    f.prop("texcoord").filter(|&i| matches!(f.props[i].ty, PropType::List(c, _) if !c.is_float()))
}

/// The textures a PLY names (`comment TextureFile NAME`, MeshLab's
/// convention; their order is the faces' `texnumber`).
pub fn texture_files(comments: &[String]) -> Vec<String> {
    comments.iter().filter_map(|c| c.strip_prefix("TextureFile").map(|n| n.trim().to_string())).filter(|n| !n.is_empty()).collect()
}

/// Index of the face's `texnumber` (MeshLab's convention: which of the
/// `comment TextureFile` textures the face samples, -1 for none), when it
/// is an integer scalar.
pub(crate) fn texnumber_prop(f: &ElementDef) -> Option<usize> {
    f.prop("texnumber").filter(|&i| matches!(f.props[i].ty, PropType::Scalar(s) if !s.is_float()))
}

/// Index of the face's vertex index list property.
pub(crate) fn face_index_prop(f: &ElementDef) -> Option<usize> {
    ["vertex_indices", "vertex_index"].iter().find_map(|n| f.prop(n).filter(|&i| matches!(f.props[i].ty, PropType::List(..))))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(bytes: &[u8]) -> Result<PlyHeader> {
        let end = find_end_header(bytes).unwrap_or(bytes.len());
        parse_header(Path::new("t.ply"), &bytes[..end], end as u64)
    }

    /// The reference grammar (ply-rs-bw) and ours agree on every bundled
    /// header: encoding, element names and counts, property names and types.
    #[test]
    fn agrees_with_ply_rs_on_the_bundled_headers() {
        use ply_rs_bw::ply::{PropertyType as P, ScalarType as S};
        let conv = |t: &S| match t {
            S::Char => Scalar::I8,
            S::UChar => Scalar::U8,
            S::Short => Scalar::I16,
            S::UShort => Scalar::U16,
            S::Int => Scalar::I32,
            S::UInt => Scalar::U32,
            S::Float => Scalar::F32,
            S::Double => Scalar::F64,
        };
        let root = Path::new(env!("CARGO_MANIFEST_DIR"));
        let mut checked = 0;
        for dir in ["fixtures", "fuzz/seeds"] {
            for entry in std::fs::read_dir(root.join(dir)).unwrap() {
                let p = entry.unwrap().path();
                if p.extension().is_none_or(|e| e != "ply") {
                    continue;
                }
                let bytes = std::fs::read(&p).unwrap();
                let ours = parse(&bytes).unwrap();
                let parser = ply_rs_bw::parser::Parser::<ply_rs_bw::ply::DefaultElement>::new();
                let theirs = parser.read_header(&mut ply_rs_bw::parser::Reader::new(&bytes[..])).unwrap();
                let enc = match theirs.encoding {
                    ply_rs_bw::ply::Encoding::Ascii => Encoding::Ascii,
                    ply_rs_bw::ply::Encoding::BinaryLittleEndian => Encoding::BinaryLe,
                    ply_rs_bw::ply::Encoding::BinaryBigEndian => Encoding::BinaryBe,
                };
                assert_eq!(ours.encoding, enc, "{}", p.display());
                let want: Vec<ElementDef> = theirs
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
                                    P::Scalar(s) => PropType::Scalar(conv(s)),
                                    P::List(c, s) => PropType::List(conv(c), conv(s)),
                                },
                            })
                            .collect(),
                    })
                    .collect();
                assert_eq!(ours.elements, want, "{}", p.display());
                assert_eq!(ours.comments, theirs.comments, "{}", p.display());
                checked += 1;
            }
        }
        assert!(checked >= 10, "only {checked} headers checked");
    }

    const TAIL: &str = "property float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n";

    #[test]
    fn any_non_space_name_is_accepted() {
        for name in ["a.b", "c:d", "$x", "dir/name", "3d", "höhe", "\u{e9}t\u{e9}"] {
            let h = format!("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty uchar {name}\n{TAIL}");
            let h = parse(h.as_bytes()).unwrap();
            assert_eq!(h.elements[0].props[1].name, name);
            let h = format!("ply\nformat ascii 1.0\nelement {name} 2\nproperty float {name}\nelement vertex 3\nproperty float x\n{TAIL}");
            let h = parse(h.as_bytes()).unwrap();
            assert_eq!((h.elements[0].name.as_str(), h.elements[0].count, h.vertex_elem), (name, 2, 1));
        }
    }

    #[test]
    fn latin1_comments_and_names_are_kept() {
        let mut h = b"ply\r\nformat binary_little_endian 1.0\r\ncomment caf\xe9 cr\xe8me\r\nobj_info \xff\xfe\r\nelement vertex 3\r\nproperty float x\r\nproperty short t\xe9\r\n".to_vec();
        h.extend_from_slice(TAIL.replace('\n', "\r\n").as_bytes());
        let h = parse(&h).unwrap();
        assert_eq!(h.encoding, Encoding::BinaryLe);
        assert_eq!(h.comments, ["caf\u{fffd} cr\u{fffd}me"]);
        assert_eq!(h.elements[0].props[1].name, "t\u{fffd}");
        assert_eq!(h.elements[0].props[1].ty, PropType::Scalar(Scalar::I16));
    }

    #[test]
    fn grammar_errors_name_their_line() {
        let ok = format!("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n{TAIL}");
        for (from, to, line, want) in [
            ("format ascii 1.0", "format ascii", 2, "expected 'format"),
            ("format ascii 1.0", "format ebcdic 1.0", 2, "unknown format 'ebcdic'"),
            ("format ascii 1.0", "format ascii 1.0\nformat ascii 1.0", 3, "'format' declared twice (lines 2 and 3)"),
            ("element vertex 3", "element vertex -3", 3, "count '-3'"),
            ("element vertex 3", "element vertex 99999999999999999999", 3, "count '99999999999999999999'"),
            ("element vertex 3", "element vertex", 3, "expected 'element <name> <count>'"),
            ("property float x", "property quaternion x", 4, "unknown property type 'quaternion'"),
            ("property float x", "property float x extra", 4, "malformed header line"),
            ("property list uchar int", "property list float int", 8, "list count type 'float'"),
            ("element vertex 3", "property float w\nelement vertex 3", 3, "'property' before any 'element'"),
            ("element face 1", "frobnicate 3\nelement face 1", 7, "unknown keyword 'frobnicate'"),
            ("end_header", "end_header now", 9, "expected 'end_header'"),
        ] {
            let bad = ok.replacen(from, to, 1);
            let e = parse(bad.as_bytes()).unwrap_err().to_string();
            assert!(e.contains(&format!("header line {line}")) && e.contains(want), "{to}: {e}");
        }
        let e = parse(b"ply\nelement vertex 3\nproperty float x\nend_header\n").unwrap_err().to_string();
        assert!(e.contains("no 'format' line"), "{e}");
        let e = parse(b"ply 1\nformat ascii 1.0\nend_header\n").unwrap_err().to_string();
        assert!(e.contains("header line 1") && e.contains("must be 'ply'"), "{e}");
    }
}

//! OBJ input (Wavefront): see [`super`].
//!
//! Takes: a path. Gives: [`read_info`], a first sequential pass that
//! counts and validates every line ([`ObjInfo`]), and [`read_body`], which
//! feeds a [`BodySink`] every vertex in index order, then every triangle,
//! as the PLY body reader does. [`looks_like_obj`] sniffs content.
//!
//! Lines read: `v x y z [w]` or `v x y z r g b` (colours as floats in
//! \[0,1\], mapped to bytes as PLY float colours are), `vt u [v [w]]`,
//! `vn x y z`, and `f` with corners `v`, `v/vt`, `v//vn` or `v/vt/vn`:
//! 1-based indices, a negative one counting back from the last of its
//! kind defined before that line. Polygons are fan-triangulated.
//! `o`, `g`, `s`, comments (`#` where a line or a token could
//! start), blank lines, `l` and `p` (lines and
//! points) and every keyword not named here are ignored without a word
//! (OBJ has many vendor keys); `mtllib` names are collected, and their
//! materials' `map_Kd` images make the texture list ([`texture_slots`]).
//!
//! Materials: `usemtl NAME` selects the material of the faces after it.
//! When the faces have uvs and choose among textures, the vertices get
//! [`AttrSet::MATERIAL`]: a face's material id is the slot of its
//! material's `map_Kd` image in [`ObjInfo::textures`] (the input's texture
//! list), or [`Vertex::NO_TEXTURE`] for a face before any `usemtl`, or
//! whose material has no `map_Kd` or is defined in no MTL file read. The
//! material joins the corner key, so a position used by two materials
//! becomes two vertices. MATERIAL is left off (every vertex reads material
//! 0, texture 0) when no face follows a `usemtl`, when there is no
//! texture, and when every face uses texture 0 (one textured material
//! whose image is first in the list): what every vertex reads without it. `\r\n` line
//! ends and `\` continuations are accepted. A malformed number, corner or
//! index (0, out of range, before the first definition), a non-finite
//! number, or a `v`, `vt`, `vn` or `f` line with the wrong number of items
//! is an error naming the file, the line and the byte offset.
//!
//! Two ways through the body:
//! * **positions only** (faces reference neither `vt` nor `vn`; with or
//!   without per-vertex colours), the common case for huge scans: streams
//!   in bounded memory whatever the size. The `v` lines are emitted as
//!   vertices in order; then the faces' triangles, by position index. When
//!   no `v` line follows the first `f` line (the usual layout) both happen
//!   in one pass; otherwise a second pass starts at the first `f` line.
//! * **corners** (faces reference `vt` or `vn`): every distinct
//!   (v, vt, vn, material) corner becomes one vertex. In memory when the position,
//!   texture-coordinate and normal tables and a hash map of the most
//!   corners there can be fit `mem` (numbered in order of first
//!   appearance; a second pass from the first face emits the triangles);
//!   otherwise out of core (`split.rs`): one pass spools the tables and the
//!   kept triangles' corners to scratch, distributed by position slab, and
//!   the corners are numbered slab by slab and joined with the tables by
//!   slab, within `mem` whatever the file's size.
//!
//! Either way a triangle two of whose corners share a position index is
//! dropped and counted as degenerate, as PLY's are.
//!
//! Input is read through a large refillable buffer by plain sequential
//! reads (no mmap: file pages would count against the memory budget), and
//! parsed in place: no allocation per line, decimal numbers of up to 15
//! digits converted exactly by one multiplication or division (Clinger's
//! fast path), longer ones by the standard library's correctly rounded
//! parser.

mod split;

use crate::error::{Error, Location, Result};
use crate::mesh::{AttrSet, Vertex};
use crate::ply::read::{BodySink, BodyStats};
use crate::progress::Progress;
use rustc_hash::FxHashMap;
use std::borrow::Cow;
use std::collections::{BTreeMap, HashSet};
use std::fs::File;
use std::io::{ErrorKind, Read, Seek, SeekFrom};
use std::path::Path;

/// What the first pass ([`read_info`]) found.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ObjInfo {
    /// `v` lines.
    pub positions: u64,
    /// `vt` lines.
    pub texcoords: u64,
    /// `vn` lines.
    pub normals: u64,
    /// `f` lines.
    pub faces: u64,
    /// Corners of all `f` lines.
    pub corners: u64,
    /// `COLOR` when every `v` line has r g b; `UV` / `NORMAL` when some
    /// face references a `vt` / `vn`; `POS_F64` when some coordinate is
    /// written more finely than `f32` holds (see [`needs_f64`]).
    pub attrs: AttrSet,
    /// Vertices the body will emit: exactly [`positions`](Self::positions)
    /// for a positions-only file; for a file whose faces reference `vt` or
    /// `vn` ([`ObjInfo::corner_vertices`]) an upper bound on the distinct
    /// (v, vt, vn) corners (the first pass keeps no table to count them;
    /// [`BodyStats::vertices`] gives the exact number).
    pub vertices: u64,
    /// `mtllib` file names, in order of first mention (at most
    /// [`MAX_MTLLIBS`]).
    pub mtllibs: Vec<String>,
    /// The texture images the materials name (`map_Kd`, relative to the
    /// OBJ's folder), each once: the input's texture list, whose index is
    /// a vertex's material id ([`texture_slots`]).
    pub textures: Vec<String>,
    /// Each textured material's slot in [`textures`](Self::textures), by
    /// name (the first `newmtl` of a name counts).
    pub material_slots: BTreeMap<String, u16>,
    /// The file's length.
    pub bytes: u64,
    /// Where the first `f` line starts, with the counts defined before it
    /// (None when there is no face).
    first_face: Option<Mark>,
    /// Some `v` line follows the first `f` line.
    v_after_faces: bool,
}

/// At most this many distinct `mtllib` names are kept.
pub const MAX_MTLLIBS: usize = 256;

/// A line start and what was defined before it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct Mark {
    offset: u64,
    line: u64,
    v: u64,
    vt: u64,
    vn: u64,
}

impl ObjInfo {
    /// Whether the faces reference `vt` or `vn`, so that the body's
    /// vertices are the distinct (v, vt, vn) corners.
    pub fn corner_vertices(&self) -> bool {
        self.attrs.uv() || self.attrs.normal()
    }

    /// Bytes [`read_body`] reads (one or two passes over parts of the
    /// file): the length of its progress bar.
    pub fn body_bytes(&self) -> u64 {
        match self.first_face {
            None => self.bytes,
            Some(m) if self.corner_vertices() || self.v_after_faces => self.bytes + (self.bytes - m.offset),
            Some(_) => self.bytes,
        }
    }

    /// Memory the corner path needs for its position, colour, texture
    /// coordinate and normal tables (what it allocates before reading).
    fn table_bytes(&self) -> u64 {
        let per_pos = 24 + if self.attrs.color() { 4 } else { 0 };
        self.positions
            .saturating_mul(per_pos)
            .saturating_add(if self.attrs.uv() { self.texcoords.saturating_mul(8) } else { 0 })
            .saturating_add(if self.attrs.normal() { self.normals.saturating_mul(12) } else { 0 })
    }
}

/// Memory counted per distinct corner on the corner paths: the hash map
/// entry (16-byte key: v, vt, vn and material; 4-byte value; a control
/// byte; at most 7/8 full and up to twice the entries after growth: 48)
/// and the 16-byte corner in the list that numbers them.
pub const CORNER_BYTES: u64 = 64;

/// At most this many distinct `usemtl` names are used by faces.
pub const MAX_MATERIALS: usize = 1 << 16;

const BUF: usize = 4 << 20;
/// Longest line (continuations included) accepted: bounds the buffer.
pub const MAX_LINE: usize = 64 << 20;
const BATCH: usize = 1 << 15;

// ------------------------------------------------------------------- lines

/// One logical line: `buf[s..e]`, without its `\n` (nor a `\r` before it);
/// continuations inside are blanked, so positions in it are file offsets
/// from `offset`.
#[derive(Clone, Copy)]
struct Line {
    s: usize,
    e: usize,
    offset: u64,
    /// 1-based number of its first physical line.
    number: u64,
}

/// Sequential buffered reader of logical lines, tracking file offsets and
/// line numbers, reporting progress and checking for signals per refill.
struct Lines<'a> {
    file: File,
    buf: Vec<u8>,
    /// Start of the next line in `buf`.
    pos: usize,
    end: usize,
    /// File offset of `buf[0]`.
    base: u64,
    eof: bool,
    /// Number of the next line.
    line: u64,
    path: &'a Path,
    progress: &'a Progress,
    /// File offset up to which progress was reported.
    reported: u64,
    /// Offset where this pass started.
    start: u64,
}

impl<'a> Lines<'a> {
    fn open(path: &'a Path, at: Mark, buf: usize, progress: &'a Progress) -> Result<Lines<'a>> {
        let (mut file, _) = crate::io::open_regular(path, "open")?;
        if at.offset > 0 {
            file.seek(SeekFrom::Start(at.offset)).map_err(|e| Error::io(path, "seek", e))?;
        }
        Ok(Lines {
            file,
            buf: vec![0; buf.max(16)],
            pos: 0,
            end: 0,
            base: at.offset,
            eof: false,
            line: at.line,
            path,
            progress,
            reported: at.offset,
            start: at.offset,
        })
    }

    fn offset(&self) -> u64 {
        self.base + self.pos as u64
    }

    /// Bytes consumed by this pass so far.
    fn consumed(&self) -> u64 {
        self.offset() - self.start
    }

    /// Reports progress; a safe point for signals.
    fn tick(&mut self) -> Result<()> {
        let off = self.offset();
        self.progress.inc(off - self.reported);
        self.reported = off;
        crate::io::signal::check()
    }

    /// The next logical line, or None at the end of the file.
    #[inline]
    fn next(&mut self) -> Result<Option<Line>> {
        // Where to look for the next '\n': nothing before it holds one.
        let mut scan = self.pos;
        let mut joined = 0u64;
        loop {
            if let Some(k) = memchr::memchr(b'\n', &self.buf[scan..self.end]) {
                let nl = scan + k;
                let mut e = nl;
                if e > self.pos && self.buf[e - 1] == b'\r' {
                    e -= 1;
                }
                if e > self.pos && self.buf[e - 1] == b'\\' {
                    // A continuation: blank `\`, `\r` and `\n` (same length, so
                    // offsets hold) and look on.
                    self.buf[e - 1..=nl].fill(b' ');
                    joined += 1;
                    scan = nl + 1;
                    continue;
                }
                return Ok(Some(self.take(e, nl + 1, joined)));
            }
            if self.eof {
                if self.pos == self.end {
                    return Ok(None);
                }
                let mut e = self.end;
                if self.buf[e - 1] == b'\r' {
                    e -= 1;
                }
                if e > self.pos && self.buf[e - 1] == b'\\' {
                    self.buf[e - 1] = b' ';
                }
                return Ok(Some(self.take(e, self.end, joined)));
            }
            let scanned = self.end - self.pos;
            self.refill()?;
            scan = self.pos + scanned;
        }
    }

    #[inline]
    fn take(&mut self, e: usize, next: usize, joined: u64) -> Line {
        let l = Line { s: self.pos, e, offset: self.offset(), number: self.line };
        self.line += 1 + joined;
        self.pos = next;
        l
    }

    #[cold]
    fn refill(&mut self) -> Result<()> {
        self.tick()?;
        if self.pos > 0 {
            self.buf.copy_within(self.pos..self.end, 0);
            self.base += self.pos as u64;
            self.end -= self.pos;
            self.pos = 0;
        }
        if self.end == self.buf.len() {
            if self.buf.len() >= MAX_LINE {
                let loc = Location { file: self.path.to_path_buf(), line: Some(self.line), offset: Some(self.base), ..Default::default() };
                return Err(Error::input(loc, format!("line longer than {} MiB", MAX_LINE >> 20)));
            }
            let n = (self.buf.len() * 2).min(MAX_LINE);
            self.buf.resize(n, 0);
        }
        loop {
            match self.file.read(&mut self.buf[self.end..]) {
                Ok(0) => self.eof = true,
                Ok(n) => self.end += n,
                Err(e) if e.kind() == ErrorKind::Interrupted => continue,
                Err(e) => return Err(Error::io(self.path, "read", e)),
            }
            return Ok(());
        }
    }

    /// The error at byte `at` of line `l`.
    fn err(&self, l: &Line, at: usize, msg: impl Into<String>) -> Error {
        err_at(self.path, l, at, msg)
    }
}

fn err_at(path: &Path, l: &Line, at: usize, msg: impl Into<String>) -> Error {
    let loc = Location { file: path.to_path_buf(), line: Some(l.number), offset: Some(l.offset + (at - l.s) as u64), ..Default::default() };
    Error::input(loc, msg)
}

fn changed(path: &Path, what: &str) -> Error {
    Error::input(Location { file: path.to_path_buf(), ..Default::default() }, format!("the file changed while it was read ({what})"))
}

// ----------------------------------------------------------------- tokens

#[inline(always)]
fn is_ws(c: u8) -> bool {
    matches!(c, b' ' | b'\t' | b'\r' | 0x0b | 0x0c)
}

#[inline(always)]
fn skip_ws(b: &[u8], mut i: usize) -> usize {
    while i < b.len() && is_ws(b[i]) {
        i += 1;
    }
    i
}

#[inline(always)]
fn token_end(b: &[u8], mut i: usize) -> usize {
    while i < b.len() && !is_ws(b[i]) {
        i += 1;
    }
    i
}

/// The token at `b[i]`, for messages (lossy, cut to 40 bytes).
fn token(b: &[u8], i: usize) -> String {
    let e = token_end(b, i).min(i + 40);
    String::from_utf8_lossy(&b[i..e]).into_owned()
}

#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Kw {
    V,
    Vt,
    Vn,
    F,
    Mtllib,
    Usemtl,
    Other,
}

/// The line's keyword and where its arguments start; None for a blank line.
#[inline]
fn keyword(b: &[u8], from: usize) -> Option<(Kw, usize)> {
    let i = skip_ws(b, from);
    if i == b.len() {
        return None;
    }
    let j = token_end(b, i);
    let kw = match &b[i..j] {
        b"v" => Kw::V,
        b"vt" => Kw::Vt,
        b"vn" => Kw::Vn,
        b"f" => Kw::F,
        b"mtllib" => Kw::Mtllib,
        b"usemtl" => Kw::Usemtl,
        _ => Kw::Other,
    };
    Some((kw, j))
}

/// The material a `usemtl` line names (its arguments from `b[at]`,
/// trimmed, as [`read_mtl`] reads `newmtl` names).
fn usemtl_name(b: &[u8], at: usize) -> Cow<'_, str> {
    let s = skip_ws(b, at);
    let mut e = b.len();
    while e > s && is_ws(b[e - 1]) {
        e -= 1;
    }
    String::from_utf8_lossy(&b[s..e])
}

/// The material id of the faces after a `usemtl` line: its material's
/// texture slot, or [`Vertex::NO_TEXTURE`] for a material without
/// `map_Kd` or one no MTL file defines.
fn usemtl_slot(info: &ObjInfo, b: &[u8], at: usize) -> u16 {
    info.material_slots.get(usemtl_name(b, at).as_ref()).copied().unwrap_or(Vertex::NO_TEXTURE)
}

// ---------------------------------------------------------------- numbers

const POW10: [f64; 23] = [1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15, 1e16, 1e17, 1e18, 1e19, 1e20, 1e21, 1e22];

/// Parses the decimal number token starting at `b[i]` (the standard
/// library's grammar: sign, digits, point, exponent, `inf`, `nan`);
/// gives its value and the index after it, or None when the token is not
/// a number. A mantissa of at most 2^53 with a power of ten within ±22 is
/// converted exactly by one multiplication or division (Clinger's fast
/// path); anything else goes to `str::parse`, which rounds correctly too.
#[inline]
fn parse_f64(b: &[u8], start: usize) -> Option<(f64, usize)> {
    let n = b.len();
    let mut i = start;
    let mut neg = false;
    if i < n && (b[i] == b'-' || b[i] == b'+') {
        neg = b[i] == b'-';
        i += 1;
    }
    let mut mant = 0u64;
    let mut exp = 0i64;
    let mut digits = false;
    // A digit that could not be kept in `mant`: the fast path is off.
    let mut lost = false;
    while i < n {
        let d = b[i].wrapping_sub(b'0');
        if d > 9 {
            break;
        }
        digits = true;
        if mant < 100_000_000_000_000_000 {
            mant = mant * 10 + d as u64;
        } else {
            exp += 1;
            lost |= d != 0;
        }
        i += 1;
    }
    if i < n && b[i] == b'.' {
        i += 1;
        while i < n {
            let d = b[i].wrapping_sub(b'0');
            if d > 9 {
                break;
            }
            digits = true;
            if mant < 100_000_000_000_000_000 {
                mant = mant * 10 + d as u64;
                exp -= 1;
            } else {
                lost |= d != 0;
            }
            i += 1;
        }
    }
    if !digits {
        return parse_f64_slow(b, start);
    }
    if i < n && (b[i] | 0x20) == b'e' {
        i += 1;
        let mut eneg = false;
        if i < n && (b[i] == b'-' || b[i] == b'+') {
            eneg = b[i] == b'-';
            i += 1;
        }
        let mut e = 0i64;
        let first = i;
        while i < n {
            let d = b[i].wrapping_sub(b'0');
            if d > 9 {
                break;
            }
            e = (e * 10 + d as i64).min(1 << 40);
            i += 1;
        }
        if i == first {
            return parse_f64_slow(b, start);
        }
        exp += if eneg { -e } else { e };
    }
    if i < n && !is_ws(b[i]) {
        return parse_f64_slow(b, start);
    }
    if !lost && mant <= 1 << 53 && (-22..=22).contains(&exp) {
        let m = mant as f64;
        let v = if exp >= 0 { m * POW10[exp as usize] } else { m / POW10[(-exp) as usize] };
        return Some((if neg { -v } else { v }, i));
    }
    if mant == 0 && !lost {
        return Some((if neg { -0.0 } else { 0.0 }, i));
    }
    parse_f64_slow(b, start)
}

#[cold]
#[inline(never)]
fn parse_f64_slow(b: &[u8], start: usize) -> Option<(f64, usize)> {
    let e = token_end(b, start);
    let s = std::str::from_utf8(&b[start..e]).ok()?;
    s.parse::<f64>().ok().map(|x| (x, e))
}

/// The numbers after a `v`, `vt` or `vn` keyword: their count (at most
/// `out.len()`), or the index of a token that is not a number, or of the
/// first one too many.
#[inline]
fn numbers(b: &[u8], mut i: usize, out: &mut [f64; 8]) -> Result<usize, (usize, bool)> {
    let mut k = 0;
    loop {
        i = skip_ws(b, i);
        if i == b.len() || b[i] == b'#' {
            return Ok(k);
        }
        if k == out.len() {
            return Err((i, true));
        }
        match parse_f64(b, i) {
            Some((x, j)) => {
                out[k] = x;
                k += 1;
                i = j;
            }
            None => return Err((i, false)),
        }
    }
}

/// Reads the numbers of a `v`, `vt` or `vn` line (`kw`) into `out`,
/// checking their count (a `v` line: exactly r g b too when `rgb`) and
/// that they are finite; gives the count.
fn line_numbers(lines: &Lines, l: &Line, b: &[u8], at: usize, kw: Kw, rgb: bool, out: &mut [f64; 8]) -> Result<usize> {
    let (what, want, counts): (&str, &str, &[usize]) = match kw {
        Kw::V => ("v", "x y z [w] or x y z r g b", if rgb { &[6] } else { &[3, 4, 6] }),
        Kw::Vt => ("vt", "u [v [w]]", &[1, 2, 3]),
        _ => ("vn", "x y z", &[3]),
    };
    let n = match numbers(b, at, out) {
        Ok(n) => n,
        Err((i, false)) => return Err(lines.err(l, l.s + i, format!("'{}' is not a number", token(b, i)))),
        Err((i, true)) => return Err(lines.err(l, l.s + i, format!("too many numbers on a '{what}' line (expected {want})"))),
    };
    if !counts.contains(&n) {
        return Err(lines.err(l, l.s + at, format!("a '{what}' line holds {want}; this one has {n} number(s)")));
    }
    if let Some(k) = out[..n].iter().position(|x| !x.is_finite()) {
        let list = out[..n].iter().map(|x| x.to_string()).collect::<Vec<_>>().join(", ");
        let name = match (kw, k) {
            (Kw::V, 0..=2) => "coordinate",
            (Kw::V, _) => "colour",
            (Kw::Vt, _) => "texture coordinate",
            _ => "normal",
        };
        return Err(lines.err(l, l.s + at, format!("non-finite {name} on a '{what}' line ({list})")));
    }
    Ok(n)
}

/// Maps a colour channel in \[0,1\] to a byte (as PLY float colours are).
#[inline]
fn color_u8(x: f64) -> u8 {
    (x * 255.0).round().clamp(0.0, 255.0) as u8
}

/// Whether a coordinate written as `tok` (value `x`) should be kept as
/// `f64`: `f32` changes its value, and the text is finer than `f32` can
/// tell apart — its last nonzero digit worth less than a tenth of the
/// `f32` spacing there (a shortest-round-trip `f32` writer never writes
/// that finely, so the writer had doubles: `512345.678` in metres, where
/// `f32` steps by 1/32) — or it is a whole number beyond `f32`'s 24-bit
/// mantissa (`16777217`). Text that an `f32` holds as finely as it is
/// written (`0.1`, `3.14159`) stays `f32`, as does any text of an exact
/// `f32` value however long (`%.6f` of `f32` data).
pub fn needs_f64(tok: &[u8], x: f64) -> bool {
    if (x as f32) as f64 == x || !x.is_finite() {
        return false;
    }
    let a = x.abs();
    if a > f32::MAX as f64 {
        return true;
    }
    if x == x.trunc() && a < 9_007_199_254_740_992.0 {
        return true;
    }
    if tok.len() < 8 {
        return false; // fewer than 8 digits are never finer than f32
    }
    // Place value of the last nonzero mantissa digit: 10^(point - 1 - j + exp).
    let mut digits = 0i64;
    let mut point = None;
    let mut last = None;
    let mut exp = 0i64;
    let mut i = 0;
    while i < tok.len() {
        match tok[i] {
            c @ b'0'..=b'9' => {
                if c != b'0' {
                    last = Some(digits);
                }
                digits += 1;
            }
            b'.' => point = Some(digits),
            b'e' | b'E' => {
                exp = std::str::from_utf8(&tok[i + 1..]).ok().and_then(|s| s.parse().ok()).unwrap_or(0);
                break;
            }
            _ => {}
        }
        i += 1;
    }
    let Some(j) = last else { return false };
    let place = point.unwrap_or(digits) - 1 - j + exp;
    // The f32 spacing at `a` is 2^k; 10^place < 2^k / 10 ⇔ place + 1 < k·log10(2).
    let k = ((a as f32).to_bits() >> 23) as i64 - 150;
    ((place + 1) as f64) < k.max(-149) as f64 * std::f64::consts::LOG10_2
}

// ---------------------------------------------------------------- corners

/// Index value meaning "no vt" / "no vn" in a [`Corner`].
const NONE: i64 = i64::MIN;

/// One face corner as written (1-based or negative indices; [`NONE`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Corner {
    v: i64,
    vt: i64,
    vn: i64,
    /// Index of its first byte in the line.
    at: usize,
}

/// A decimal integer at `b[i]` (optional sign, at most 18 digits) and the
/// index after it.
#[inline(always)]
fn parse_index(b: &[u8], mut i: usize) -> Option<(i64, usize)> {
    let n = b.len();
    let neg = i < n && b[i] == b'-';
    if i < n && (b[i] == b'-' || b[i] == b'+') {
        i += 1;
    }
    let first = i;
    let mut x = 0i64;
    while i < n {
        let d = b[i].wrapping_sub(b'0');
        if d > 9 {
            break;
        }
        if i - first == 18 {
            return None;
        }
        x = x * 10 + d as i64;
        i += 1;
    }
    if i == first {
        return None;
    }
    Some((if neg { -x } else { x }, i))
}

/// The next corner of a face line from `*i`: None at the end of the line,
/// Some(Err(at)) for a malformed one.
#[inline]
fn next_corner(b: &[u8], i: &mut usize) -> Option<Result<Corner, usize>> {
    let at = skip_ws(b, *i);
    if at == b.len() || b[at] == b'#' {
        *i = at;
        return None;
    }
    let parsed = parse_corner(b, at);
    Some(match parsed {
        Some((c, j)) => {
            *i = j;
            Ok(c)
        }
        None => Err(at),
    })
}

/// The corner at `b[at]` and the index after it.
#[inline(always)]
fn parse_corner(b: &[u8], at: usize) -> Option<(Corner, usize)> {
    let (v, mut j) = parse_index(b, at)?;
    let (mut vt, mut vn) = (NONE, NONE);
    if j < b.len() && b[j] == b'/' {
        j += 1;
        if j < b.len() && b[j] == b'/' {
            (vn, j) = parse_index(b, j + 1)?;
        } else {
            (vt, j) = parse_index(b, j)?;
            if j < b.len() && b[j] == b'/' {
                (vn, j) = parse_index(b, j + 1)?;
            }
        }
    }
    if j < b.len() && !is_ws(b[j]) {
        return None;
    }
    Some((Corner { v, vt, vn, at }, j))
}

const CORNER_FORMS: &str = "v, v/vt, v//vn or v/vt/vn with integer indices";

/// Kinds of index, for resolution and messages.
#[derive(Clone, Copy)]
enum Kind {
    Pos,
    Tex,
    Nrm,
}

impl Kind {
    fn name(self) -> &'static str {
        match self {
            Kind::Pos => "position",
            Kind::Tex => "texture coordinate",
            Kind::Nrm => "normal",
        }
    }
    fn key(self) -> &'static str {
        match self {
            Kind::Pos => "v",
            Kind::Tex => "vt",
            Kind::Nrm => "vn",
        }
    }
}

/// The 0-based index of `i` (1-based, or negative: relative to `defined`,
/// the count of its kind before this line), checked against `total` (the
/// file's count, when known), or the message saying why not.
#[inline]
fn resolve(i: i64, defined: u64, total: Option<u64>, kind: Kind) -> Result<u64, String> {
    if i > 0 {
        let z = (i - 1) as u64;
        match total {
            Some(t) if z >= t => Err(format!("{} index {i} out of range (the file has {t} '{}' lines)", kind.name(), kind.key())),
            _ => Ok(z),
        }
    } else if i < 0 {
        let back = i.unsigned_abs();
        if back > defined {
            Err(format!("relative {} index {i} reaches before the first '{}' line ({defined} defined before this line)", kind.name(), kind.key()))
        } else {
            Ok(defined - back)
        }
    } else {
        Err(format!("{} index 0: OBJ indices start at 1 (negative ones count back from the last defined)", kind.name()))
    }
}

// ---------------------------------------------------------------- pass 1

/// The largest positive index of one kind seen, and where (checked against
/// the count once the whole file is read: forward references are legal).
#[derive(Clone, Copy, Default)]
struct MaxRef {
    index: i64,
    line: u64,
    offset: u64,
}

impl MaxRef {
    #[inline]
    fn see(&mut self, i: i64, l: &Line, at: usize) {
        if i > self.index {
            *self = MaxRef { index: i, line: l.number, offset: l.offset + (at - l.s) as u64 };
        }
    }
    fn check(&self, path: &Path, total: u64, kind: Kind) -> Result<()> {
        if self.index > 0 && self.index as u64 > total {
            let loc = Location { file: path.to_path_buf(), line: Some(self.line), offset: Some(self.offset), ..Default::default() };
            return Err(Error::input(loc, resolve(self.index, 0, Some(total), kind).unwrap_err()));
        }
        Ok(())
    }
}

/// First sequential pass: counts every kind of line, validates every
/// number, corner and index, and works out the attributes (see [`ObjInfo`]).
pub fn read_info(path: &Path, progress: &Progress) -> Result<ObjInfo> {
    read_info_buf(path, progress, BUF)
}

fn read_info_buf(path: &Path, progress: &Progress, buf: usize) -> Result<ObjInfo> {
    let mut lines = Lines::open(path, Mark { line: 1, ..Default::default() }, buf, progress)?;
    let mut info = ObjInfo::default();
    let (mut all_rgb, mut f64_pos, mut uv, mut nrm) = (true, false, false, false);
    let mut max = [MaxRef::default(); 3];
    let mut nums = [0f64; 8];
    // The `usemtl` material in force (and whether a face used it yet), the
    // materials faces use, and whether some face comes before any `usemtl`.
    let (mut current, mut current_used): (Option<String>, bool) = (None, false);
    let mut used: HashSet<String> = HashSet::new();
    let mut untagged = false;
    while let Some(l) = lines.next()? {
        let b = &lines.buf[l.s..l.e];
        let Some((kw, at)) = keyword(b, 0) else { continue };
        match kw {
            Kw::V => {
                let n = line_numbers(&lines, &l, b, at, Kw::V, false, &mut nums)?;
                all_rgb &= n == 6;
                if !f64_pos {
                    // Re-scan the three coordinate tokens (only until one needs f64).
                    let mut i = at;
                    for &x in &nums[..3] {
                        i = skip_ws(b, i);
                        let e = token_end(b, i);
                        f64_pos |= needs_f64(&b[i..e], x);
                        i = e;
                    }
                }
                if info.first_face.is_some() {
                    info.v_after_faces = true;
                }
                info.positions += 1;
            }
            Kw::Vt => {
                line_numbers(&lines, &l, b, at, Kw::Vt, false, &mut nums)?;
                info.texcoords += 1;
            }
            Kw::Vn => {
                line_numbers(&lines, &l, b, at, Kw::Vn, false, &mut nums)?;
                info.normals += 1;
            }
            Kw::F => {
                if info.first_face.is_none() {
                    info.first_face = Some(Mark { offset: l.offset, line: l.number, v: info.positions, vt: info.texcoords, vn: info.normals });
                }
                let mut i = at;
                let mut k = 0u64;
                while let Some(c) = next_corner(b, &mut i) {
                    let c = c.map_err(|a| lines.err(&l, l.s + a, format!("'{}' is not a face corner ({CORNER_FORMS})", token(b, a))))?;
                    let at = l.s + c.at;
                    for (x, kind, defined, m) in [(c.v, Kind::Pos, info.positions, 0), (c.vt, Kind::Tex, info.texcoords, 1), (c.vn, Kind::Nrm, info.normals, 2)]
                    {
                        if x == NONE {
                            continue;
                        }
                        resolve(x, defined, None, kind).map_err(|msg| lines.err(&l, at, msg))?;
                        max[m].see(x, &l, at);
                    }
                    uv |= c.vt != NONE;
                    nrm |= c.vn != NONE;
                    k += 1;
                }
                if k < 3 {
                    return Err(lines.err(&l, l.s, format!("face with {k} corner(s); a face needs at least 3")));
                }
                match &current {
                    None => untagged = true,
                    Some(name) if !current_used => {
                        current_used = true;
                        if used.len() == MAX_MATERIALS && !used.contains(name) {
                            return Err(lines.err(&l, l.s, format!("faces use more than {MAX_MATERIALS} distinct 'usemtl' materials")));
                        }
                        used.insert(name.clone());
                    }
                    Some(_) => {}
                }
                info.faces += 1;
                info.corners += k;
            }
            Kw::Mtllib => {
                let mut i = at;
                loop {
                    i = skip_ws(b, i);
                    if i == b.len() || b[i] == b'#' {
                        break;
                    }
                    let e = token_end(b, i);
                    let name = String::from_utf8_lossy(&b[i..e]).into_owned();
                    if info.mtllibs.len() < MAX_MTLLIBS && !info.mtllibs.contains(&name) {
                        info.mtllibs.push(name);
                    }
                    i = e;
                }
            }
            Kw::Usemtl => {
                let name = usemtl_name(b, at);
                if current.as_deref() != Some(name.as_ref()) {
                    current = Some(name.into_owned());
                    current_used = false;
                }
            }
            Kw::Other => {}
        }
    }
    lines.tick()?;
    max[0].check(path, info.positions, Kind::Pos)?;
    max[1].check(path, info.texcoords, Kind::Tex)?;
    max[2].check(path, info.normals, Kind::Nrm)?;
    info.bytes = lines.offset();
    let mut attrs = AttrSet::POSITION_ONLY;
    attrs = attrs.with(AttrSet::POS_F64, f64_pos);
    attrs = attrs.with(AttrSet::COLOR, all_rgb && info.positions > 0);
    attrs = attrs.with(AttrSet::UV, uv);
    attrs = attrs.with(AttrSet::NORMAL, nrm);
    (info.textures, info.material_slots) = texture_slots(path, &info.mtllibs)?;
    // Faces choose among the textures (MATERIAL) when they have uvs, some
    // face follows a `usemtl`, and not every face uses texture 0 (which is
    // what every face reads without MATERIAL): one textured material in
    // slot 0 on every face, or no `usemtl` at all, leaves it off.
    let slot = |name: &String| info.material_slots.get(name).copied().unwrap_or(Vertex::NO_TEXTURE);
    let material = uv && !info.textures.is_empty() && !used.is_empty() && (untagged || used.iter().any(|n| slot(n) != 0));
    attrs = attrs.with(AttrSet::MATERIAL, material);
    info.attrs = attrs;
    info.vertices = if uv || nrm {
        // A corner's vt (vn) is one of the vt (vn) lines or none; its
        // material one of those used, or none.
        let options = |n: u64, used: bool| if used { n + 1 } else { 1 };
        let combos = info.positions.saturating_mul(options(info.texcoords, uv)).saturating_mul(options(info.normals, nrm));
        let combos = combos.saturating_mul(options(used.len() as u64, material));
        info.corners.min(combos)
    } else {
        info.positions
    };
    Ok(info)
}

// ------------------------------------------------------------------ body

/// Reads the body of `path` described by `info` (from [`read_info`] on the
/// same file), feeding `sink`: vertices in index order, then triangles.
/// `mem` bounds the corner path (see the module doc), which spills to a
/// scratch directory it makes inside `scratch` when its tables do not fit;
/// the positions-only path holds only its buffers whatever `mem` is.
pub fn read_body(path: &Path, info: &ObjInfo, mem: u64, scratch: &Path, sink: &mut dyn BodySink, progress: &Progress) -> Result<BodyStats> {
    read_body_buf(path, info, mem, scratch, sink, progress, BUF, false)
}

/// [`read_body`] with a buffer size and, for tests, the corner path forced
/// out of core.
#[allow(clippy::too_many_arguments)]
fn read_body_buf(
    path: &Path,
    info: &ObjInfo,
    mem: u64,
    scratch: &Path,
    sink: &mut dyn BodySink,
    progress: &Progress,
    buf: usize,
    external: bool,
) -> Result<BodyStats> {
    let mut out = Out { sink, stats: BodyStats::default(), tris: Vec::with_capacity(BATCH), verts: Vec::with_capacity(BATCH) };
    if info.corner_vertices() {
        if info.positions >= u32::MAX as u64 || info.texcoords >= u32::MAX as u64 || info.normals >= u32::MAX as u64 {
            return Err(Error::Usage(format!(
                "{}: more than {} 'v', 'vt' or 'vn' lines with faces referencing 'vt' or 'vn' are not supported",
                path.display(),
                u32::MAX - 1
            )));
        }
        if !external && corners_fit(info, mem) {
            read_corners(path, info, &mut out, progress, buf)?;
        } else {
            read_corners_external(path, info, mem, scratch, &mut out, progress, buf)?;
        }
    } else {
        read_positions(path, info, &mut out, progress, buf)?;
    }
    Ok(out.stats)
}

/// Batches for the sink, and the counts.
struct Out<'a> {
    sink: &'a mut dyn BodySink,
    stats: BodyStats,
    tris: Vec<[u64; 3]>,
    verts: Vec<Vertex>,
}

impl Out<'_> {
    #[inline]
    fn vertex(&mut self, v: Vertex) -> Result<()> {
        self.verts.push(v);
        if self.verts.len() == BATCH {
            self.flush_vertices()?;
        }
        Ok(())
    }

    fn flush_vertices(&mut self) -> Result<()> {
        if !self.verts.is_empty() {
            self.sink.vertices(self.stats.vertices, &self.verts)?;
            self.stats.vertices += self.verts.len() as u64;
            self.verts.clear();
            crate::io::signal::check()?;
        }
        Ok(())
    }

    /// Adds a triangle of output indices.
    #[inline]
    fn push_triangle(&mut self, t: [u64; 3]) -> Result<()> {
        self.tris.push(t);
        if self.tris.len() == BATCH {
            self.flush_triangles()?;
        }
        Ok(())
    }

    /// The last triangles out; the faces must be those the first pass
    /// counted (the file did not change in between).
    fn finish(&mut self, path: &Path, info: &ObjInfo, read: u64) -> Result<()> {
        self.flush_triangles()?;
        if self.stats.faces != info.faces {
            return Err(changed(path, "a different number of faces than in the first pass"));
        }
        self.stats.bytes = read;
        Ok(())
    }

    fn flush_triangles(&mut self) -> Result<()> {
        if !self.tris.is_empty() {
            self.sink.triangles(&self.tris)?;
            self.stats.triangles += self.tris.len() as u64;
            self.tris.clear();
            crate::io::signal::check()?;
        }
        Ok(())
    }
}

/// Where fan-triangulated faces go: the sink's batches ([`Out`]) or the
/// out-of-core corner spool ([`split::Spool`]).
trait Tris {
    /// Adds the triangle (`t` output indices, `p` their position indices)
    /// unless two corners share a position (counted as degenerate).
    fn triangle(&mut self, t: [u64; 3], p: [u64; 3]) -> Result<()>;
    /// The counts faces and polygons are added to.
    fn stats(&mut self) -> &mut BodyStats;
}

impl Tris for Out<'_> {
    #[inline]
    fn triangle(&mut self, t: [u64; 3], p: [u64; 3]) -> Result<()> {
        if p[0] == p[1] || p[1] == p[2] || p[0] == p[2] {
            self.stats.degenerate += 1;
            return Ok(());
        }
        self.push_triangle(t)
    }

    fn stats(&mut self) -> &mut BodyStats {
        &mut self.stats
    }
}

/// Fan triangulation state: the first and the previous corner (output
/// index, position index) and the corners seen.
#[derive(Default)]
struct Fan {
    first: (u64, u64),
    prev: (u64, u64),
    k: u64,
}

impl Fan {
    #[inline]
    fn push(&mut self, out: &mut impl Tris, c: (u64, u64)) -> Result<()> {
        match self.k {
            0 => self.first = c,
            1 => self.prev = c,
            _ => {
                out.triangle([self.first.0, self.prev.0, c.0], [self.first.1, self.prev.1, c.1])?;
                self.prev = c;
            }
        }
        self.k += 1;
        Ok(())
    }

    /// Ends a face line: counts it, and fails below three corners (the
    /// file changed since the first pass, which refused such faces).
    fn end(self, out: &mut impl Tris, lines: &Lines, l: &Line) -> Result<()> {
        if self.k < 3 {
            return Err(lines.err(l, l.s, format!("face with {} corner(s); a face needs at least 3", self.k)));
        }
        let stats = out.stats();
        stats.faces += 1;
        if self.k > 3 {
            stats.polygons += 1;
        }
        Ok(())
    }
}

/// The vertex of a `v` line (numbers already read), with its colour when
/// the file has colours.
#[inline]
fn position_vertex(nums: &[f64; 8], color: bool) -> Vertex {
    let mut v = Vertex { pos: [nums[0], nums[1], nums[2]], ..Default::default() };
    if color {
        v.color = [color_u8(nums[3]), color_u8(nums[4]), color_u8(nums[5]), 255];
    }
    v
}

/// The positions-only path: `v` lines as vertices in order, then the
/// faces' triangles by position index, in one pass when no `v` line
/// follows the first face, else two.
fn read_positions(path: &Path, info: &ObjInfo, out: &mut Out, progress: &Progress, buf: usize) -> Result<()> {
    let color = info.attrs.color();
    let one_pass = !info.v_after_faces;
    let mut nums = [0f64; 8];
    let mut lines = Lines::open(path, Mark { line: 1, ..Default::default() }, buf, progress)?;
    let mut seen = 0u64;
    let mut faces_started = false;
    while let Some(l) = lines.next()? {
        let b = &lines.buf[l.s..l.e];
        let Some((kw, at)) = keyword(b, 0) else { continue };
        match kw {
            Kw::V => {
                if faces_started || seen == info.positions {
                    return Err(changed(path, "more 'v' lines than in the first pass"));
                }
                line_numbers(&lines, &l, b, at, Kw::V, color, &mut nums)?;
                out.vertex(position_vertex(&nums, color))?;
                seen += 1;
                if !one_pass && seen == info.positions {
                    break;
                }
            }
            Kw::F if one_pass => {
                if !faces_started {
                    if seen != info.positions {
                        return Err(changed(path, "fewer 'v' lines before the faces than in the first pass"));
                    }
                    out.flush_vertices()?;
                    faces_started = true;
                }
                position_face(&lines, &l, b, at, seen, info.positions, out)?;
            }
            _ => {}
        }
    }
    let mut read = lines.consumed();
    lines.tick()?;
    drop(lines);
    if seen != info.positions {
        return Err(changed(path, "fewer 'v' lines than in the first pass"));
    }
    out.flush_vertices()?;
    if let (false, Some(m)) = (one_pass, info.first_face) {
        let mut lines = Lines::open(path, m, buf, progress)?;
        let mut defined = m.v;
        while let Some(l) = lines.next()? {
            let b = &lines.buf[l.s..l.e];
            match keyword(b, 0) {
                Some((Kw::V, _)) => defined += 1,
                Some((Kw::F, at)) => position_face(&lines, &l, b, at, defined, info.positions, out)?,
                _ => {}
            }
        }
        read += lines.consumed();
        lines.tick()?;
    }
    out.finish(path, info, read)
}

/// One `f` line on the positions-only path (`vt` and `vn` are ignored
/// there: no face of the file references them).
#[inline]
fn position_face(lines: &Lines, l: &Line, b: &[u8], at: usize, defined: u64, total: u64, out: &mut Out) -> Result<()> {
    let mut fan = Fan::default();
    let mut i = at;
    while let Some(c) = next_corner(b, &mut i) {
        let c = c.map_err(|a| lines.err(l, l.s + a, format!("'{}' is not a face corner ({CORNER_FORMS})", token(b, a))))?;
        let v = resolve(c.v, defined, Some(total), Kind::Pos).map_err(|msg| lines.err(l, l.s + c.at, msg))?;
        fan.push(out, (v, v))?;
    }
    fan.end(out, lines, l)
}

/// The first pass of the corner path reads into one of these: the `v`,
/// `vt` and `vn` tables, and each face's corners as (v, vt, vn,
/// material), 0-based, [`split::NONE`] for no vt or vn; the material is
/// the face's texture slot ([`usemtl_slot`]) when the file has
/// [`AttrSet::MATERIAL`], else 0.
trait CornerPass {
    fn position(&mut self, v: &Vertex) -> Result<()>;
    fn texcoord(&mut self, uv: [f32; 2]) -> Result<()>;
    fn normal(&mut self, n: [f32; 3]) -> Result<()>;
    fn corner(&mut self, k: [u32; 4]) -> Result<()>;
    fn face_end(&mut self, lines: &Lines, l: &Line) -> Result<()>;
}

/// A face corner's (v, vt, vn, material), checked against what is
/// defined so far (`defined`: v, vt, vn lines before this one).
fn corner_key(lines: &Lines, l: &Line, c: Corner, defined: [u64; 3], material: u16, info: &ObjInfo) -> Result<[u32; 4]> {
    let r = |x: i64, defined: u64, total: u64, kind: Kind| -> Result<u32> {
        if x == NONE {
            return Ok(split::NONE);
        }
        resolve(x, defined, Some(total), kind).map(|z| z as u32).map_err(|msg| lines.err(l, l.s + c.at, msg))
    };
    Ok([
        r(c.v, defined[0], info.positions, Kind::Pos)?,
        r(c.vt, defined[1], info.texcoords, Kind::Tex)?,
        r(c.vn, defined[2], info.normals, Kind::Nrm)?,
        material as u32,
    ])
}

/// The corner path's first pass over the whole file into `to`; gives the
/// bytes read.
fn corner_pass(path: &Path, info: &ObjInfo, to: &mut impl CornerPass, progress: &Progress, buf: usize) -> Result<u64> {
    let (color, uv, nrm) = (info.attrs.color(), info.attrs.uv(), info.attrs.normal());
    let mut nums = [0f64; 8];
    let mut n = [0u64; 3];
    let mut lines = Lines::open(path, Mark { line: 1, ..Default::default() }, buf, progress)?;
    let totals = [info.positions, info.texcoords, info.normals];
    let mut mat = first_material(info);
    while let Some(l) = lines.next()? {
        let b = &lines.buf[l.s..l.e];
        let Some((kw, at)) = keyword(b, 0) else { continue };
        let k = match kw {
            Kw::V => 0,
            Kw::Vt => 1,
            Kw::Vn => 2,
            Kw::F => {
                let mut i = at;
                while let Some(c) = next_corner(b, &mut i) {
                    let c = c.map_err(|a| lines.err(&l, l.s + a, format!("'{}' is not a face corner ({CORNER_FORMS})", token(b, a))))?;
                    to.corner(corner_key(&lines, &l, c, n, mat, info)?)?;
                }
                to.face_end(&lines, &l)?;
                continue;
            }
            Kw::Usemtl if info.attrs.material() => {
                mat = usemtl_slot(info, b, at);
                continue;
            }
            _ => continue,
        };
        if n[k] == totals[k] {
            return Err(changed(path, &format!("more '{}' lines than in the first pass", ["v", "vt", "vn"][k])));
        }
        match k {
            0 => {
                line_numbers(&lines, &l, b, at, Kw::V, color, &mut nums)?;
                to.position(&position_vertex(&nums, color))?;
            }
            1 if uv => {
                let c = line_numbers(&lines, &l, b, at, Kw::Vt, false, &mut nums)?;
                to.texcoord([nums[0] as f32, if c > 1 { nums[1] as f32 } else { 0.0 }])?;
            }
            2 if nrm => {
                line_numbers(&lines, &l, b, at, Kw::Vn, false, &mut nums)?;
                to.normal([nums[0] as f32, nums[1] as f32, nums[2] as f32])?;
            }
            _ => {}
        }
        n[k] += 1;
    }
    let read = lines.consumed();
    lines.tick()?;
    if n != totals {
        return Err(changed(path, "fewer 'v', 'vt' or 'vn' lines than in the first pass"));
    }
    Ok(read)
}

/// The material id of faces before any `usemtl`: none
/// ([`Vertex::NO_TEXTURE`]) with [`AttrSet::MATERIAL`], else 0.
fn first_material(info: &ObjInfo) -> u16 {
    if info.attrs.material() {
        Vertex::NO_TEXTURE
    } else {
        0
    }
}

/// Whether the corner path runs in memory: the tables and the map of the
/// most corners there can be ([`ObjInfo::vertices`]) fit `mem`; else
/// [`split`] runs it out of core.
fn corners_fit(info: &ObjInfo, mem: u64) -> bool {
    // (The in-memory path numbers corners in u32.)
    info.vertices < u32::MAX as u64 && info.table_bytes().saturating_add(info.vertices.saturating_mul(CORNER_BYTES)) <= mem
}

/// The corner path, in memory: one pass reads the `v`, `vt` and `vn`
/// tables and numbers the distinct (v, vt, vn) corners of the faces in
/// order of first appearance; the corners are emitted as vertices; a
/// second pass from the first face emits the triangles.
fn read_corners(path: &Path, info: &ObjInfo, out: &mut Out, progress: &Progress, buf: usize) -> Result<()> {
    struct Tables {
        pos: Vec<[f64; 3]>,
        rgb: Vec<[u8; 4]>,
        tex: Vec<[f32; 2]>,
        nor: Vec<[f32; 3]>,
        color: bool,
        /// Corners in order of first appearance, and their numbers.
        order: Vec<[u32; 4]>,
        ids: FxHashMap<[u32; 4], u32>,
        /// The first face's material (where the second pass starts).
        first_mat: Option<u16>,
    }
    impl CornerPass for Tables {
        fn position(&mut self, v: &Vertex) -> Result<()> {
            self.pos.push(v.pos);
            if self.color {
                self.rgb.push(v.color);
            }
            Ok(())
        }
        fn texcoord(&mut self, uv: [f32; 2]) -> Result<()> {
            self.tex.push(uv);
            Ok(())
        }
        fn normal(&mut self, n: [f32; 3]) -> Result<()> {
            self.nor.push(n);
            Ok(())
        }
        fn corner(&mut self, k: [u32; 4]) -> Result<()> {
            self.first_mat.get_or_insert(k[3] as u16);
            let next = self.order.len() as u32;
            if let std::collections::hash_map::Entry::Vacant(e) = self.ids.entry(k) {
                e.insert(next);
                self.order.push(k);
            }
            Ok(())
        }
        fn face_end(&mut self, _: &Lines, _: &Line) -> Result<()> {
            Ok(())
        }
    }
    let (color, uv, nrm) = (info.attrs.color(), info.attrs.uv(), info.attrs.normal());
    let cap = |on: bool, n: u64| if on { n as usize } else { 0 };
    let mut t = Tables {
        pos: Vec::with_capacity(info.positions as usize),
        rgb: Vec::with_capacity(cap(color, info.positions)),
        tex: Vec::with_capacity(cap(uv, info.texcoords)),
        nor: Vec::with_capacity(cap(nrm, info.normals)),
        color,
        order: Vec::with_capacity(info.vertices.min(info.positions) as usize),
        ids: FxHashMap::default(),
        first_mat: None,
    };
    t.ids.reserve(info.vertices.min(info.positions) as usize);
    let mut read = corner_pass(path, info, &mut t, progress, buf)?;
    // Missing attributes of a corner stay zero (uv 0,0, normal 0,0,0): a
    // zero normal is the one value no real normal has, so later stages can
    // tell "none given" from data, where an invented one (the face's) would
    // pass for data and split the corner per face; for uv nothing better
    // exists without the texture.
    for k in &t.order {
        let mut v = Vertex { pos: t.pos[k[0] as usize], material: k[3] as u16, ..Default::default() };
        if color {
            v.color = t.rgb[k[0] as usize];
        }
        if k[1] != split::NONE {
            v.uv = t.tex[k[1] as usize];
        }
        if k[2] != split::NONE {
            v.normal = t.nor[k[2] as usize];
        }
        out.vertex(v)?;
    }
    out.flush_vertices()?;
    let Tables { ids, first_mat, .. } = t;
    let m = info.first_face.unwrap_or(Mark { offset: info.bytes, line: 1, ..Default::default() });
    let mut lines = Lines::open(path, m, buf, progress)?;
    let mut n = [m.v, m.vt, m.vn];
    // The material in force at the first face: that of the last `usemtl`
    // before it, which the second pass starts after.
    let mut mat = first_mat.unwrap_or(first_material(info));
    while let Some(l) = lines.next()? {
        let b = &lines.buf[l.s..l.e];
        match keyword(b, 0) {
            Some((Kw::V, _)) => n[0] += 1,
            Some((Kw::Vt, _)) => n[1] += 1,
            Some((Kw::Vn, _)) => n[2] += 1,
            Some((Kw::Usemtl, at)) if info.attrs.material() => mat = usemtl_slot(info, b, at),
            Some((Kw::F, at)) => {
                let mut fan = Fan::default();
                let mut i = at;
                while let Some(c) = next_corner(b, &mut i) {
                    let c = c.map_err(|a| lines.err(&l, l.s + a, format!("'{}' is not a face corner ({CORNER_FORMS})", token(b, a))))?;
                    let k = corner_key(&lines, &l, c, n, mat, info)?;
                    let Some(&id) = ids.get(&k) else { return Err(changed(path, "a face corner not seen in the first pass")) };
                    fan.push(out, (id as u64, k[0] as u64))?;
                }
                fan.end(out, &lines, &l)?;
            }
            _ => {}
        }
    }
    read += lines.consumed();
    lines.tick()?;
    out.finish(path, info, read)
}

/// The corner path out of core ([`split`]): one pass spools the tables and
/// the kept triangles' corners (a corner's output index carries its vt and
/// vn, its position index its v); the spool then emits vertices and
/// triangles.
fn read_corners_external(path: &Path, info: &ObjInfo, mem: u64, scratch: &Path, out: &mut Out, progress: &Progress, buf: usize) -> Result<()> {
    struct External {
        spool: split::Spool,
        fan: Fan,
    }
    impl CornerPass for External {
        fn position(&mut self, v: &Vertex) -> Result<()> {
            self.spool.position(v)
        }
        fn texcoord(&mut self, uv: [f32; 2]) -> Result<()> {
            self.spool.texcoord(uv)
        }
        fn normal(&mut self, n: [f32; 3]) -> Result<()> {
            self.spool.normal(n)
        }
        fn corner(&mut self, k: [u32; 4]) -> Result<()> {
            // (Every corner of a face has the face's material.)
            self.spool.material = k[3] as u16;
            self.fan.push(&mut self.spool, ((k[1] as u64) << 32 | k[2] as u64, k[0] as u64))
        }
        fn face_end(&mut self, lines: &Lines, l: &Line) -> Result<()> {
            std::mem::take(&mut self.fan).end(&mut self.spool, lines, l)
        }
    }
    let counts = [info.positions, info.texcoords, info.normals];
    let spool = split::Spool::new(path, scratch, counts, info.attrs.uv(), info.attrs.normal(), mem)?;
    let mut e = External { spool, fan: Fan::default() };
    let read = corner_pass(path, info, &mut e, progress, buf)?;
    e.spool.finish(out)?;
    out.finish(path, info, read)
}

// -------------------------------------------------------------- materials

/// A material of an MTL file: its name and its diffuse texture
/// (`map_Kd`), as written.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Material {
    pub name: String,
    pub map_kd: Option<String>,
}

/// The OBJ `path`'s texture list and each textured material's slot in it,
/// from its `mtllib` files (relative to its folder) in order: every
/// material's `map_Kd` image, relative to the OBJ's folder, listed once
/// (materials naming the same image share its slot). An MTL file that
/// cannot be read names none. This one function gives both, so the list
/// a build copies into the store and the vertices' material ids agree.
pub fn texture_slots(path: &Path, mtllibs: &[String]) -> Result<(Vec<String>, BTreeMap<String, u16>)> {
    let base = crate::io::parent_dir(path);
    let mut names: Vec<String> = Vec::new();
    let mut slot_of: FxHashMap<String, u16> = FxHashMap::default();
    let mut slots = BTreeMap::new();
    let mut defined = HashSet::new();
    for lib in mtllibs {
        let Ok(mats) = read_mtl(&base.join(lib)) else { continue };
        let dir = Path::new(lib).parent().unwrap_or(Path::new(""));
        for m in mats {
            let first = defined.insert(m.name.clone());
            let Some(t) = m.map_kd else { continue };
            let name = dir.join(t).to_string_lossy().into_owned();
            let slot = match slot_of.get(&name) {
                Some(&s) => s,
                None => {
                    if names.len() >= Vertex::NO_TEXTURE as usize {
                        return Err(Error::Usage(format!(
                            "{}: its materials name more than {} distinct textures (a material id is 16 bits)",
                            path.display(),
                            Vertex::NO_TEXTURE
                        )));
                    }
                    let s = names.len() as u16;
                    slot_of.insert(name.clone(), s);
                    names.push(name);
                    s
                }
            };
            if first {
                slots.insert(m.name, slot);
            }
        }
    }
    Ok((names, slots))
}

/// Largest MTL file read (they are small text files; this bounds a mistake).
const MAX_MTL: u64 = 16 << 20;

/// The materials of the MTL file `path` (`newmtl` and `map_Kd` lines; the
/// rest ignored). `map_Kd` options (`-s u v w`, `-o`, `-bm x`, `-clamp on`
/// and the others of the MTL specification) are skipped; the rest of the
/// line is the file name, spaces included. The textures themselves are
/// for the textured-mesh work (issue 32): today `info-input` lists them.
pub fn read_mtl(path: &Path) -> Result<Vec<Material>> {
    let (f, len) = crate::io::open_regular(path, "open")?;
    if len > MAX_MTL {
        return Err(Error::input(Location { file: path.to_path_buf(), ..Default::default() }, format!("an MTL file of {len} bytes (at most {MAX_MTL} read)")));
    }
    let mut text = String::new();
    let mut bytes = Vec::with_capacity(len as usize);
    std::io::Read::read_to_end(&mut f.take(MAX_MTL), &mut bytes).map_err(|e| Error::io(path, "read", e))?;
    text.push_str(&String::from_utf8_lossy(&bytes));
    let mut out: Vec<Material> = Vec::new();
    for line in text.lines() {
        let line = line.trim();
        let Some((kw, rest)) = line.split_once(char::is_whitespace) else { continue };
        match kw {
            "newmtl" => out.push(Material { name: rest.trim().to_string(), map_kd: None }),
            "map_Kd" | "map_kd" => {
                let mut toks = rest.split_whitespace().peekable();
                let mut skipped = 0usize;
                while let Some(&t) = toks.peek() {
                    let args = match t {
                        "-blendu" | "-blendv" | "-cc" | "-clamp" | "-texres" | "-imfchan" | "-bm" | "-boost" | "-type" => 1,
                        "-mm" => 2,
                        "-o" | "-s" | "-t" => 3,
                        _ => break,
                    };
                    toks.next();
                    skipped += 1;
                    // Up to `args` numbers (`-o`, `-s`, `-t` take 1 to 3).
                    for _ in 0..args {
                        match toks.peek() {
                            Some(a) if args == 3 && a.parse::<f64>().is_err() => break,
                            Some(_) => {
                                toks.next();
                                skipped += 1;
                            }
                            None => break,
                        }
                    }
                }
                let name: Vec<&str> = rest.split_whitespace().skip(skipped).collect();
                if let (Some(m), false) = (out.last_mut(), name.is_empty()) {
                    m.map_kd = Some(name.join(" "));
                }
            }
            _ => {}
        }
    }
    Ok(out)
}

// ---------------------------------------------------------------- sniffing

/// Whether `head` (the first bytes of a file) looks like an OBJ: text
/// whose first line that is neither blank nor a comment starts with an
/// OBJ keyword (`v`, `vt`, `vn`, `vp`, `f`, `l`, `p`, `o`, `g`, `s`,
/// `mtllib`, `usemtl`) and a space; a head of comments only counts too.
/// PLY (`ply`) and STL (`solid`, binary) heads do not.
pub fn looks_like_obj(head: &[u8]) -> bool {
    if head.is_empty() || head.contains(&0) {
        return false;
    }
    let mut comments = false;
    let lines = head.iter().filter(|&&c| c == b'\n').count();
    for (n, raw) in head.split(|&c| c == b'\n').enumerate() {
        let complete = n < lines;
        let i = skip_ws(raw, 0);
        if i == raw.len() {
            continue;
        }
        if raw[i] == b'#' {
            comments = true;
            continue;
        }
        let e = token_end(raw, i);
        let known = matches!(&raw[i..e], b"v" | b"vt" | b"vn" | b"vp" | b"f" | b"l" | b"p" | b"o" | b"g" | b"s" | b"mtllib" | b"usemtl");
        // A cut last line counts once its keyword is whole.
        return known && (e < raw.len() || complete);
    }
    comments
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gen::{GenOptions, Generator, Shape};
    use crate::ply::read::CollectSink;
    use crate::ply::write::{write_ply, PlyWriteOptions};
    use crate::ply::Encoding;
    use std::fmt::Write as _;
    use std::path::PathBuf;

    type Read = (ObjInfo, CollectSink, BodyStats);

    /// Each triangle as its corners' vertices (bit patterns compared).
    fn corners(s: &CollectSink) -> Vec<[[u64; 12]; 3]> {
        let bits = |v: &Vertex| {
            let mut b = [0u64; 12];
            b[..3].copy_from_slice(&v.pos.map(f64::to_bits));
            b[3] = u32::from_le_bytes(v.color) as u64;
            b[4..6].copy_from_slice(&v.uv.map(|c| c.to_bits() as u64));
            b[6..9].copy_from_slice(&v.normal.map(|c| c.to_bits() as u64));
            b[9] = v.material as u64;
            b
        };
        s.triangles.iter().map(|t| t.map(|i| bits(&s.vertices[i as usize]))).collect()
    }

    fn read_buf(path: &Path, mem: u64, buf: usize) -> Result<Read> {
        let r = read_buf_path(path, mem, buf, false);
        if read_info_buf(path, &Progress::hidden(), buf).is_ok_and(|i| i.corner_vertices()) {
            // Out of core, with this budget and with a tiny one (many
            // slabs, sub-ranges, tables joined from disk): the same
            // triangles and corners, each distinct corner once; the same
            // errors.
            for m in [mem, 0] {
                match (&r, read_buf_path(path, m, buf, true)) {
                    (Ok(r), Ok(x)) => {
                        assert_eq!(corners(&x.1), corners(&r.1), "out of core, mem {m}");
                        // The in-memory path numbers every distinct (v, vt, vn), so its
                        // kept triangles' distinct numbers are the distinct corners.
                        let used: std::collections::HashSet<_> = r.1.triangles.iter().flatten().collect();
                        assert_eq!(x.2.vertices, used.len() as u64, "out of core, mem {m}");
                        assert_eq!((x.2.faces, x.2.polygons, x.2.degenerate, x.2.triangles), (r.2.faces, r.2.polygons, r.2.degenerate, r.2.triangles));
                    }
                    (Err(a), Err(b)) => assert_eq!(a.to_string(), b.to_string(), "out of core, mem {m}"),
                    (a, b) => panic!("out of core, mem {m}: {:?} against {:?}", a.as_ref().err(), b.err()),
                }
            }
        }
        r
    }

    fn read_buf_path(path: &Path, mem: u64, buf: usize, external: bool) -> Result<Read> {
        let p = Progress::hidden();
        let info = read_info_buf(path, &p, buf)?;
        let mut sink = CollectSink::default();
        let scratch = tempfile::tempdir().unwrap();
        let st = read_body_buf(path, &info, mem, scratch.path(), &mut sink, &p, buf, external);
        assert_eq!(std::fs::read_dir(scratch.path()).unwrap().count(), 0, "scratch left behind");
        let st = st?;
        assert_eq!(sink.vertices.len() as u64, st.vertices);
        assert_eq!(sink.triangles.len() as u64, st.triangles);
        assert!(sink.triangles.iter().flatten().all(|&i| i < st.vertices));
        if info.corner_vertices() {
            assert!(st.vertices <= info.vertices);
        } else {
            assert_eq!(st.vertices, info.vertices);
        }
        Ok((info, sink, st))
    }

    /// Reads `path` with the real buffer and with tiny ones (refills inside
    /// lines, numbers and continuations; buffer growth), which must agree.
    fn read_mem(path: &Path, mem: u64) -> Result<Read> {
        let r = read_buf(path, mem, BUF);
        for buf in [16, 23, 64] {
            match (&r, read_buf(path, mem, buf)) {
                (Ok(a), Ok(b)) => {
                    assert_eq!(a.0, b.0, "buffer {buf}");
                    assert_eq!((&a.1.vertices, &a.1.triangles), (&b.1.vertices, &b.1.triangles), "buffer {buf}");
                    assert_eq!(a.2.bytes, b.2.bytes, "buffer {buf}");
                }
                (Err(a), Err(b)) => assert_eq!(a.to_string(), b.to_string(), "buffer {buf}"),
                (a, b) => panic!("buffer {buf}: {:?} against {:?}", a.as_ref().err(), b.err()),
            }
        }
        r
    }

    fn read(path: &Path) -> Result<Read> {
        read_mem(path, 1 << 30)
    }

    fn file(text: &str) -> (tempfile::TempDir, PathBuf) {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("m.obj");
        std::fs::write(&p, text).unwrap();
        (d, p)
    }

    fn read_str(text: &str) -> Result<Read> {
        let (_d, p) = file(text);
        read(&p)
    }

    /// The error of reading `text`, with its line and offset.
    fn error(text: &str) -> (String, Option<u64>, Option<u64>) {
        let e = read_str(text).expect_err(text);
        let loc = e.location().cloned().unwrap_or_default();
        (e.to_string(), loc.line, loc.offset)
    }

    const QUAD: &str = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n";

    #[test]
    fn positions_and_negative_indices() {
        let (info, s, st) = read_str(&format!("{QUAD}f 1 2 3\nf -4 -2 -1\n")).unwrap();
        assert_eq!(s.triangles, vec![[0, 1, 2], [0, 2, 3]]);
        assert_eq!((info.positions, info.faces, info.corners, info.vertices, info.attrs), (4, 2, 6, 4, AttrSet::POSITION_ONLY));
        assert_eq!(s.vertices[2].pos, [1.0, 1.0, 0.0]);
        assert_eq!((st.faces, st.triangles, st.degenerate, st.polygons), (2, 2, 0, 0));
    }

    #[test]
    fn negative_indices_count_what_is_defined_before_the_line() {
        // v lines after faces: the two-pass layout.
        let t = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\nv 0 0 1\nv 1 0 1\nv 0 1 1\nf -3 -2 -1\nf 1 2 3\nf 6 5 -4\n";
        let (info, s, st) = read_str(t).unwrap();
        assert!(info.v_after_faces);
        assert_eq!(s.triangles, vec![[0, 1, 2], [3, 4, 5], [0, 1, 2], [5, 4, 2]]);
        assert_eq!(s.vertices.len(), 6);
        assert_eq!(s.vertices[5].pos, [0.0, 1.0, 1.0]);
        assert!(st.bytes > t.len() as u64 && st.bytes <= info.body_bytes());
        // A forward reference (legal OBJ) reads too.
        let (_, s, _) = read_str("f 1 2 3\nv 0 0 0\nv 1 0 0\nv 0 1 0\n").unwrap();
        assert_eq!(s.triangles, vec![[0, 1, 2]]);
    }

    #[test]
    fn every_corner_form_and_relative_attributes() {
        let t = format!(
            "{QUAD}vt 0 0\nvt 1 0\nvt 1 1\nvn 0 0 1\n\
             f 1/1 2/2 3/3\nf 1//1 2//1 4//1\nf 1/1/1 2/2/1 3/3/1\nf -4/-3/-1 -3/-2/-1 -2/-1/-1\nf 1 2 4\n"
        );
        let (info, s, st) = read_str(&t).unwrap();
        assert_eq!(info.attrs, AttrSet(AttrSet::UV | AttrSet::NORMAL));
        assert!(info.corner_vertices());
        assert_eq!((info.texcoords, info.normals, info.corners), (3, 1, 15));
        // Distinct (v, vt, vn) in order of first appearance.
        assert_eq!(st.vertices, 12);
        assert_eq!(s.triangles, vec![[0, 1, 2], [3, 4, 5], [6, 7, 8], [6, 7, 8], [9, 10, 11]]);
        let v = &s.vertices;
        assert_eq!((v[1].uv, v[1].normal), ([1.0, 0.0], [0.0; 3]));
        assert_eq!((v[5].pos, v[5].uv, v[5].normal), ([0.0, 1.0, 0.0], [0.0; 2], [0.0, 0.0, 1.0]));
        assert_eq!((v[8].pos, v[8].uv, v[8].normal), ([1.0, 1.0, 0.0], [1.0, 1.0], [0.0, 0.0, 1.0]));
        assert_eq!((v[9].pos, v[9].uv, v[9].normal), ([0.0; 3], [0.0; 2], [0.0; 3]));
        // Corners with and without vt of one position: two vertices, the
        // second with uv (0, 0).
        let (info, s, _) = read_str("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0.5 0.5\nf 1/1 2/1 3/1\nf 1 2 3\n").unwrap();
        assert_eq!((info.vertices, s.vertices.len()), (6, 6));
        assert_eq!((s.vertices[0].uv, s.vertices[3].uv, s.vertices[3].pos), ([0.5, 0.5], [0.0, 0.0], [0.0; 3]));
        assert_eq!(s.triangles, vec![[0, 1, 2], [3, 4, 5]]);
        // A single-number vt is (u, 0).
        let (_, s, _) = read_str("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0.25\nf 1/1 2/1 3/1\n").unwrap();
        assert_eq!(s.vertices[0].uv, [0.25, 0.0]);
    }

    /// A grid whose uv atlas is cut along every 7th column and whose
    /// normals are per face in one band: out of core with a tiny budget it
    /// spans many position slabs, slabs done in several sub-ranges, and
    /// both tables joined from disk (`read_buf` compares with the
    /// in-memory path).
    #[test]
    fn out_of_core_corners_span_slabs_sub_ranges_and_joins() {
        let n = 120usize;
        let mut t = String::new();
        for y in 0..n {
            for x in 0..n {
                let _ = writeln!(t, "v {x} {y} {}", (x * y) % 5);
            }
        }
        // One vt per position, and a second one for positions on a cut.
        let mut cut = vec![0usize; n * n];
        let mut vts = 0;
        for y in 0..n {
            for x in 0..n {
                let _ = writeln!(t, "vt {} {}", x as f32 / n as f32, y as f32 / n as f32);
                vts += 1;
                if x % 7 == 0 {
                    let _ = writeln!(t, "vt {} {}", x as f32 / n as f32 + 0.5, y as f32 / n as f32);
                    vts += 1;
                    cut[y * n + x] = vts;
                }
            }
        }
        let first_vt: Vec<usize> = {
            let mut k = 0;
            (0..n * n)
                .map(|i| {
                    k += 1;
                    let f = k;
                    if i % n % 7 == 0 {
                        k += 1;
                    }
                    f
                })
                .collect()
        };
        let _ = writeln!(t, "vn 0 0 1");
        for y in 0..n - 1 {
            for x in 0..n - 1 {
                let q = [y * n + x, y * n + x + 1, (y + 1) * n + x + 1, (y + 1) * n + x];
                // Faces right of a cut take its second vt.
                let vt = |i: usize| if cut[i] > 0 && i % n == x { cut[i] } else { first_vt[i] };
                let band = (y / 10) % 3 == 1;
                let c: Vec<String> = q.iter().map(|&i| if band { format!("{}/{}/1", i + 1, vt(i)) } else { format!("{}/{}", i + 1, vt(i)) }).collect();
                let _ = writeln!(t, "f {}", c.join(" "));
            }
        }
        let (_d, p) = file(&t);
        let info = read_info(&p, &Progress::hidden()).unwrap();
        assert_eq!((info.positions, info.texcoords, info.faces), ((n * n) as u64, vts as u64, ((n - 1) * (n - 1)) as u64));
        let (_, s, st) = read_buf(&p, 1 << 30, BUF).unwrap();
        assert_eq!(st.triangles, 2 * ((n - 1) * (n - 1)) as u64);
        // Every position is a vertex, and more where cuts or bands split it.
        assert!(st.vertices > (n * n) as u64 && s.vertices.iter().any(|v| v.normal == [0.0, 0.0, 1.0]));
    }

    #[test]
    fn cube_with_face_normals_splits_into_24_vertices() {
        let mut t = String::new();
        for i in 0..8 {
            let _ = writeln!(t, "v {} {} {}", i & 1, (i >> 1) & 1, (i >> 2) & 1);
        }
        let faces: [([u32; 4], [i32; 3]); 6] = [
            ([0, 2, 3, 1], [0, 0, -1]),
            ([4, 5, 7, 6], [0, 0, 1]),
            ([0, 1, 5, 4], [0, -1, 0]),
            ([2, 6, 7, 3], [0, 1, 0]),
            ([0, 4, 6, 2], [-1, 0, 0]),
            ([1, 3, 7, 5], [1, 0, 0]),
        ];
        for (_, n) in &faces {
            let _ = writeln!(t, "vn {} {} {}", n[0], n[1], n[2]);
        }
        for (k, (q, _)) in faces.iter().enumerate() {
            let _ = writeln!(t, "f {}", q.map(|v| format!("{}//{}", v + 1, k + 1)).join(" "));
        }
        let (info, s, st) = read_str(&t).unwrap();
        assert_eq!(info.attrs, AttrSet(AttrSet::NORMAL));
        assert_eq!((info.vertices, st.vertices, st.triangles, st.polygons, st.faces), (24, 24, 12, 6, 6));
        for (k, tri) in s.triangles.iter().enumerate() {
            let n = faces[k / 2].1.map(|c| c as f32);
            for &i in tri {
                assert_eq!(s.vertices[i as usize].normal, n);
            }
        }
        // Tables 8·24 + 6·12 bytes, and CORNER_BYTES per corner: exactly
        // enough memory reads in memory, a byte less out of core (the same
        // triangles, `read_mem` checks).
        let (_d, p) = file(&t);
        let need = 8 * 24 + 6 * 12 + 24 * CORNER_BYTES;
        assert!(corners_fit(&info, need) && !corners_fit(&info, need - 1));
        for mem in [need, need - 1, 100] {
            let (_, s2, st2) = read_mem(&p, mem).unwrap();
            assert_eq!(corners(&s2), corners(&s), "mem {mem}");
            assert_eq!((st2.vertices, st2.triangles, st2.faces), (st.vertices, st.triangles, st.faces), "mem {mem}");
        }
    }

    #[test]
    fn colours_polygons_and_degenerates() {
        let t = "v 0 0 0 1 0 0.5\nv 1 0 0 0 1 0\nv 1 1 0 0.2 0.2 2\nv 0 1 0 0 0 -1\nv 2 2 0 1 1 1\n\
                 f 1 2 3 4\nf 1 2 3 4 5\nf 1 2 2\nf 1 1 2 3\n";
        let (info, s, st) = read_str(t).unwrap();
        assert_eq!(info.attrs, AttrSet(AttrSet::COLOR));
        assert_eq!(s.vertices[0].color, [255, 0, 128, 255]);
        assert_eq!(s.vertices[2].color, [51, 51, 255, 255]);
        assert_eq!(s.vertices[3].color, [0, 0, 0, 255]);
        assert_eq!(s.triangles, vec![[0, 1, 2], [0, 2, 3], [0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 1, 2]]);
        assert_eq!((st.faces, st.polygons, st.triangles, st.degenerate), (4, 3, 6, 2));
        // Colours on only some v lines: none kept.
        let (info, s, _) = read_str("v 0 0 0 1 0 0\nv 1 0 0\nv 0 1 0 1\nf 1 2 3\n").unwrap();
        assert_eq!(info.attrs, AttrSet::POSITION_ONLY);
        assert_eq!(s.vertices[0].color, [0, 0, 0, 255]);
    }

    #[test]
    fn mtl_materials_and_their_diffuse_textures() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("m.mtl");
        std::fs::write(
            &p,
            "# Blender MTL\nnewmtl skin\nKd 0.8 0.8 0.8\nmap_Kd -s 1 1 1 -o 0 0 -bm 0.5 textures/skin atlas.png\n\
             newmtl plain\nKd 1 0 0\nnewmtl wood\r\nmap_Kd wood.jpg\r\n",
        )
        .unwrap();
        let m = read_mtl(&p).unwrap();
        let got: Vec<(&str, Option<&str>)> = m.iter().map(|m| (m.name.as_str(), m.map_kd.as_deref())).collect();
        assert_eq!(got, vec![("skin", Some("textures/skin atlas.png")), ("plain", None), ("wood", Some("wood.jpg"))]);
        assert!(read_mtl(&d.path().join("missing.mtl")).is_err());
    }

    /// `usemtl` picks each face's texture slot in the texture list (the
    /// list [`texture_slots`] gives, which the build copies), in memory and
    /// out of core alike (`read` compares them, materials included).
    #[test]
    fn usemtl_gives_each_face_its_textures_slot() {
        let d = tempfile::tempdir().unwrap();
        std::fs::create_dir_all(d.path().join("mat")).unwrap();
        std::fs::write(
            d.path().join("mat/a.mtl"),
            "newmtl unused\nmap_Kd unused.png\nnewmtl wood\nmap_Kd -s 2 2 wood.png\nnewmtl plain\nKd 1 0 0\n\
             newmtl stone\nmap_Kd tex/stone.jpg\nnewmtl wood2\nmap_Kd wood.png\nnewmtl wood\nmap_Kd not-this.png\n",
        )
        .unwrap();
        let p = d.path().join("m.obj");
        let t = "mtllib mat/a.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 0 0\nv 2 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n\
                 f 1/1 2/2 3/3\nusemtl wood\nf 1/1 3/3 4/4\nusemtl stone\nf 2/2 5/1 6/4 3/3\nusemtl plain\nf 1/1 2/2 4/4\n\
                 usemtl wood2\nf 3/3 6/4 4/4\nusemtl ghost\nf 5/1 6/4 4/4\n";
        std::fs::write(&p, t).unwrap();
        let (info, s, st) = read(&p).unwrap();
        assert_eq!(info.textures, vec!["mat/unused.png", "mat/wood.png", "mat/tex/stone.jpg", "mat/not-this.png"]);
        let slots: Vec<(&str, u16)> = info.material_slots.iter().map(|(k, v)| (k.as_str(), *v)).collect();
        assert_eq!(slots, vec![("stone", 2), ("unused", 0), ("wood", 1), ("wood2", 1)]);
        assert!(info.attrs.material() && info.attrs.uv());
        const N: u16 = Vertex::NO_TEXTURE;
        let mats: Vec<u16> = s.triangles.iter().map(|t| s.vertices[t[0] as usize].material).collect();
        assert_eq!(mats, vec![N, 1, 2, 2, N, 1, N]);
        for t in &s.triangles {
            assert!(t.iter().all(|&i| s.vertices[i as usize].material == s.vertices[t[0] as usize].material), "{t:?}");
        }
        // Position 3 with vt 3 under no material, wood, stone and wood2
        // (wood's slot): three vertices; 14 distinct (v, vt, material) in
        // all (wood2's corners are wood's, the same slot).
        let at = |p: [f64; 3]| s.vertices.iter().filter(|v| v.pos == p).map(|v| v.material).collect::<HashSet<_>>();
        assert_eq!(at([1.0, 1.0, 0.0]), HashSet::from([N, 1, 2]));
        assert_eq!(s.vertices.iter().filter(|v| v.pos == [1.0, 1.0, 0.0]).count(), 3);
        assert_eq!((st.vertices, st.triangles, st.faces, st.polygons), (14, 7, 6, 1));
        assert!(st.vertices <= info.vertices);

        // One textured material, first in the list, on every face: no
        // MATERIAL (every vertex reads texture 0); nor without `usemtl`.
        for (body, material) in [("usemtl unused\n", false), ("", false), ("usemtl wood\n", true), ("usemtl unused\nf 1/1 2/1 3/1\nusemtl plain\n", true)] {
            std::fs::write(&p, format!("mtllib mat/a.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nvt 0 0\n{body}f 1/1 2/1 3/1\n")).unwrap();
            let (info, s, _) = read(&p).unwrap();
            assert_eq!(info.attrs.material(), material, "{body:?}");
            if !material {
                assert!(s.vertices.iter().all(|v| v.material == 0));
            }
        }
        // Without uvs the materials change nothing.
        std::fs::write(&p, "mtllib mat/a.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nusemtl wood\nf 1 2 3\nusemtl stone\nf 3 2 1\n").unwrap();
        let (info, s, _) = read(&p).unwrap();
        assert!(!info.attrs.material() && s.vertices.len() == 3);
    }

    #[test]
    fn ignored_lines_and_mtllibs() {
        let t = "# a comment\nmtllib a.mtl b.mtl\no thing\ng group\ns 1\nusemtl red\nmtllib a.mtl\n\n   \n\
                 v 0 0 0\nv 1 0 0\nv 0 1 0\nvp 0.5\nl 1 2\np 3\ncstype bezier\nweird 1/2/3 x\nf 1 2 3 # trailing\n";
        let (info, s, _) = read_str(t).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(info.mtllibs, vec!["a.mtl".to_string(), "b.mtl".to_string()]);
        assert_eq!((info.positions, info.faces), (3, 1));
        assert_eq!(s.triangles, vec![[0, 1, 2]]);
        assert_eq!(info.bytes, t.len() as u64);
    }

    #[test]
    fn crlf_and_continuation_lines() {
        let plain = read_str(&format!("{QUAD}f 1 2 3 4\n")).unwrap();
        for t in [
            "v 0 0 0\r\nv 1 0 0\r\nv 1 1 0\r\nv 0 1 0\r\nf 1 2 3 4\r\n",
            "v 0 0 0\nv 1 \\\n0 0\nv 1 1 0\r\nv 0 1 0\nf 1 2 \\\r\n 3 \\\n4",
            "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1\\\n 2 3 4\\\n",
        ] {
            let r = read_str(t).unwrap_or_else(|e| panic!("{t:?}: {e}"));
            assert_eq!((&r.1.vertices, &r.1.triangles, r.2.polygons), (&plain.1.vertices, &plain.1.triangles, 1), "{t:?}");
        }
        // Lines after a continuation keep their physical numbers.
        let (msg, line, off) = error("v 0 0 0\nv 1 \\\n 0 0\nv 1 1 0\nf 1 2 0\n");
        assert_eq!((line, off), (Some(5), Some(33)), "{msg}");
        assert!(msg.contains("line 5 (byte offset 33)") && msg.contains("index 0"), "{msg}");
    }

    #[test]
    fn errors_name_line_and_offset() {
        let v3 = "v 0 0 0\nv 1 0 0\nv 0 1 0\n"; // 24 bytes
        let cases: &[(&str, u64, u64, &str)] = &[
            ("f 0 1 2\n", 4, 26, "position index 0"),
            ("f 1 2 9\n", 4, 30, "position index 9 out of range (the file has 3 'v' lines)"),
            ("f -4 -1 -2\n", 4, 26, "relative position index -4 reaches before the first 'v' line (3 defined before this line)"),
            ("vt 0 0\nf 1/1 2/2 3/1\n", 5, 37, "texture coordinate index 2 out of range"),
            ("f 1//1 2//1 3//1\n", 4, 26, "normal index 1 out of range (the file has 0 'vn' lines)"),
            ("v 1 2 x3\n", 4, 30, "'x3' is not a number"),
            ("v 1 2 1.5.2\n", 4, 30, "'1.5.2' is not a number"),
            ("v 1 2\n", 4, 25, "a 'v' line holds x y z [w] or x y z r g b; this one has 2"),
            ("v 1 2 3 4 5\n", 4, 25, "this one has 5"),
            ("v nan 0 0\n", 4, 25, "non-finite coordinate"),
            ("v 0 -inf 0\n", 4, 25, "non-finite coordinate"),
            ("v 0 0 0 1 0 inf\n", 4, 25, "non-finite colour"),
            ("vn 0 1e999 0\n", 4, 26, "non-finite normal"),
            ("vt 0 1 2 3\n", 4, 26, "a 'vt' line holds u [v [w]]; this one has 4"),
            ("f 1/2/3/4 2 3\n", 4, 26, "'1/2/3/4' is not a face corner"),
            ("f 1/ 2 3\n", 4, 26, "'1/' is not a face corner"),
            ("f 1 2 3x\n", 4, 30, "'3x' is not a face corner"),
            ("f 1 2 99999999999999999999\n", 4, 30, "is not a face corner"),
            ("f 1 2\n", 4, 24, "face with 2 corner(s)"),
        ];
        for &(tail, line, off, want) in cases {
            let (msg, l, o) = error(&format!("{v3}{tail}"));
            assert!(msg.contains(want), "{tail:?}: {msg}");
            assert!(msg.contains(&format!("m.obj: line {line} (byte offset {off}): ")), "{tail:?}: {msg}");
            assert_eq!((l, o), (Some(line), Some(off)), "{tail:?}: {msg}");
        }
        // The highest out-of-range index names its own line, even with later faces.
        let (msg, l, _) = error(&format!("{v3}f 1 2 7\nf 1 2 3\nf 8 2 3\nf 1 2 3\n"));
        assert_eq!(l, Some(6), "{msg}");
    }

    #[test]
    fn numbers_parse_as_the_standard_library_does() {
        let mut texts: Vec<String> = [
            "0",
            "-0",
            "+0",
            "-0.0",
            "1",
            "1.",
            ".5",
            "-.5",
            "+1e5",
            "1E+05",
            "1e-5",
            "00012.500",
            "9007199254740992",
            "9007199254740993",
            "123456789012345678901234567890",
            "0.000000000000000000000000001",
            "1e-400",
            "4.9e-324",
            "1.7976931348623157e308",
            "1e22",
            "1e23",
            "0.1",
            "0.30000000000000004",
            "1234567.891",
            "-987654.321e-3",
            "12345678901234567",
            "3.14159265358979323846264338327950288",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        let mut x = 0x9E37_79B9_7F4A_7C15u64;
        for _ in 0..20_000 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            let f = f64::from_bits(x);
            if !f.is_finite() {
                continue;
            }
            let g = (x % 2_000_001) as f64 / 1000.0 - 1000.0;
            texts.push(format!("{f}"));
            texts.push(format!("{f:e}"));
            texts.push(format!("{}", f as f32));
            texts.push(format!("{g}"));
            texts.push(format!("{g:.6}"));
            texts.push(format!("{:.9}", g as f32));
        }
        for t in &texts {
            let want: f64 = t.parse().unwrap();
            let (got, end) = parse_f64(t.as_bytes(), 0).unwrap_or_else(|| panic!("{t}"));
            assert_eq!((got.to_bits(), end), (want.to_bits(), t.len()), "{t}");
            let spaced = format!("{t} 7");
            assert_eq!(parse_f64(spaced.as_bytes(), 0).map(|(v, e)| (v.to_bits(), e)), Some((want.to_bits(), t.len())), "{t}");
        }
        for bad in ["", "-", ".", "e5", "1e", "1e+", "1x", "0x10", "1_0", "1..2", "--1", "1/2"] {
            assert!(parse_f64(bad.as_bytes(), 0).is_none(), "{bad}");
        }
        assert!(parse_f64(b"inf", 0).unwrap().0.is_infinite() && parse_f64(b"NaN", 0).unwrap().0.is_nan());
    }

    #[test]
    fn f64_positions_when_written_finer_than_f32() {
        for (t, want) in [
            ("0.1", false),
            ("3.14159", false),
            ("100.12346", false),
            ("-0.70710677", false),
            ("512345.6875", false),
            ("512345.687500", false),
            ("1.5e3", false),
            ("0.7071067811865476", true),
            ("512345.678", true),
            ("-4123456.78e-1", true),
            ("-4123456.25e-1", false),
            ("16777217", true),
            ("16777216", false),
        ] {
            let x: f64 = t.parse().unwrap();
            assert_eq!(needs_f64(t.as_bytes(), x), want, "{t}");
        }
        let (info, _, _) = read_str("v 512345.678 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\n").unwrap();
        assert_eq!(info.attrs, AttrSet(AttrSet::POS_F64));
    }

    /// A generated mesh written as PLY (ascii, by the PLY writer) and as OBJ
    /// with the same number text reads back the same.
    #[test]
    fn streams_what_the_ply_reader_reads() {
        let g = Generator::new(&GenOptions { shape: Shape::Sphere, tris: 2000, ..Default::default() });
        let (verts, faces) = g.mesh();
        let d = tempfile::tempdir().unwrap();
        for f64_pos in [true, false] {
            let attrs = AttrSet::POSITION_ONLY.with(AttrSet::POS_F64, f64_pos);
            let ply = d.path().join("m.ply");
            write_ply(&ply, &PlyWriteOptions { encoding: Encoding::Ascii, attrs, ..Default::default() }, &verts, &faces).unwrap();
            let (header, want, want_st) = crate::ply::read::read_all(&ply).unwrap();
            assert_eq!(header.attrs, attrs);
            let coord = |x: f64| if f64_pos { format!("{x}") } else { format!("{}", x as f32) };
            let mut vs = String::new();
            for v in &verts {
                let _ = writeln!(vs, "v {} {} {}", coord(v.pos[0]), coord(v.pos[1]), coord(v.pos[2]));
            }
            let nv = verts.len() as i64;
            // Absolute indices; negative ones; and with a v line after the
            // faces (the two-pass layout) and continuations.
            for layout in 0..3 {
                let mut t = vs.clone();
                for f in &faces {
                    let _ = match layout {
                        0 => writeln!(t, "f {} {} {}", f[0] + 1, f[1] + 1, f[2] + 1),
                        1 => writeln!(t, "f {} {} {}", f[0] as i64 - nv, f[1] as i64 - nv, f[2] as i64 - nv),
                        _ => writeln!(t, "f {} \\\n{} {}\r", f[0] + 1, f[1] + 1, f[2] + 1),
                    };
                }
                if layout == 2 {
                    t.push_str("v 0 0 0\n");
                }
                let (info, got, st) = read(&file(&t).1).unwrap();
                assert_eq!(info.attrs, attrs, "layout {layout}");
                assert_eq!(info.v_after_faces, layout == 2);
                assert_eq!(got.triangles, want.triangles, "layout {layout}");
                assert_eq!(got.vertices[..verts.len()], want.vertices[..], "layout {layout}");
                assert_eq!((st.faces, st.triangles, st.degenerate, st.polygons), (want_st.faces, want_st.triangles, want_st.degenerate, want_st.polygons));
            }
        }
    }

    /// Random edits of small files (what the fuzz target does, briefly):
    /// no panic, and whatever the first pass accepts the body reads (with
    /// the fuzz target's checks, through `read`'s buffer sizes).
    #[test]
    fn random_edits_never_panic() {
        let seeds = [
            "v 0 0 0 1 0 0\nv 1 0 0 0 1 0\nv 1 1 0 0 0 1\nv 0 1 0 .5 .5 .5\nf 1 2 3 4\nf -4 -3 -1\n",
            "v 0 0 0\r\nv 1 0 0\r\nv 0 1 0\r\nvt 0 0\r\nvt 1 0\r\nvn 0 0 1\r\nf 1/1/1 2/2/1 3/1/1\r\nf 1//1 3//1 \\\r\n 2//1\r\n",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\nv 0 0 1\nf 1 2 4 3\nf 2 2 3\n",
        ];
        let bits: [&[u8]; 20] =
            [b"v ", b"vt ", b"vn ", b"f ", b"/", b"//", b"-", b"\\\n", b"\r\n", b"\n", b"#", b"0", b"1", b"4", b"9", b"nan", b"1e999", b" ", b"\\", b"2.5"];
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("r.obj");
        let mut x = 0x2545_F491_4F6C_DD1Du64;
        let mut rnd = |n: usize| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x % n as u64) as usize
        };
        let (mut ok, mut corner) = (0, 0);
        for _ in 0..1000 {
            let mut t = seeds[rnd(seeds.len())].as_bytes().to_vec();
            for _ in 0..1 + rnd(3) {
                let at = rnd(t.len() + 1);
                match rnd(3) {
                    0 => drop(t.splice(at..at, bits[rnd(bits.len())].iter().copied())),
                    1 if at < t.len() => drop(t.remove(at)),
                    _ if at < t.len() => t[at] = bits[rnd(bits.len())][0],
                    _ => {}
                }
            }
            std::fs::write(&p, &t).unwrap();
            let Ok(info) = read_info_buf(&p, &Progress::hidden(), BUF) else { continue };
            let (info2, sink, st) = read_mem(&p, 1 << 20).unwrap_or_else(|e| panic!("{:?}: {e}", String::from_utf8_lossy(&t)));
            assert_eq!(info, info2);
            assert_eq!((st.faces, st.triangles + st.degenerate), (info.faces, info.corners - 2 * info.faces));
            assert!(sink.vertices.iter().all(|v| v.pos.iter().all(|c| c.is_finite())));
            ok += 1;
            corner += info.corner_vertices() as u32;
        }
        assert!(ok > 100 && corner > 30, "{ok} accepted, {corner} with corners");
    }

    #[test]
    fn sniffing() {
        for t in ["# Blender\nmtllib x.mtl\n", "v 1 2 3\n", "\n\no cube\nv 1", "# only comments\n# here", "  vt 0 0\n", "usemtl a\n"] {
            assert!(looks_like_obj(t.as_bytes()), "{t:?}");
        }
        for t in ["", "ply\nformat ascii 1.0\n", "solid cube\n  facet normal", "vertex 1 2 3\n", "v\0\0\0", "# c\nply\n", "mtll"] {
            assert!(!looks_like_obj(t.as_bytes()), "{t:?}");
        }
    }

    #[test]
    fn not_a_regular_file_or_missing() {
        assert!(matches!(read_info(Path::new("/nonexistent/m.obj"), &Progress::hidden()), Err(Error::Io { .. })));
        assert!(read_info(Path::new("/tmp"), &Progress::hidden()).is_err());
    }

    /// Decode speed against the PLY ascii reader on the same generated mesh
    /// (same number text): `cargo test --release --lib input::obj -- --ignored --nocapture`
    /// (`OBJ_SPEED_TRIS` sets the size).
    #[test]
    #[ignore = "a decode-speed measurement on a 2 M-triangle OBJ; run in release"]
    fn decode_speed_against_ply_ascii() {
        struct Count(u64, u64);
        impl BodySink for Count {
            fn vertices(&mut self, _: u64, b: &[Vertex]) -> Result<()> {
                self.0 += b.len() as u64;
                Ok(())
            }
            fn triangles(&mut self, b: &[[u64; 3]]) -> Result<()> {
                self.1 += b.len() as u64;
                Ok(())
            }
        }
        let tris = std::env::var("OBJ_SPEED_TRIS").ok().and_then(|s| s.parse().ok()).unwrap_or(2_000_000);
        let g = Generator::new(&GenOptions { shape: Shape::Sphere, tris, ..Default::default() });
        let (verts, faces) = g.mesh();
        let d = tempfile::tempdir().unwrap();
        let best = |f: &mut dyn FnMut() -> u64| {
            (0..3)
                .map(|_| {
                    let t = std::time::Instant::now();
                    let n = f();
                    (t.elapsed().as_secs_f64(), n)
                })
                .fold((f64::MAX, 0), |a, b| if b.0 < a.0 { b } else { a })
        };
        for f64_pos in [false, true] {
            let attrs = AttrSet::POSITION_ONLY.with(AttrSet::POS_F64, f64_pos);
            let ply = d.path().join("m.ply");
            write_ply(&ply, &PlyWriteOptions { encoding: Encoding::Ascii, attrs, ..Default::default() }, &verts, &faces).unwrap();
            let obj = d.path().join("m.obj");
            let mut t = String::with_capacity(64 * verts.len() + 32 * faces.len());
            let coord = |x: f64| if f64_pos { format!("{x}") } else { format!("{}", x as f32) };
            for v in &verts {
                let _ = writeln!(t, "v {} {} {}", coord(v.pos[0]), coord(v.pos[1]), coord(v.pos[2]));
            }
            for f in &faces {
                let _ = writeln!(t, "f {} {} {}", f[0] + 1, f[1] + 1, f[2] + 1);
            }
            std::fs::write(&obj, &t).unwrap();
            drop(t);
            let p = Progress::hidden();
            let (ply_s, ply_n) = best(&mut || {
                let h = crate::ply::read_header(&ply).unwrap();
                let mut c = Count(0, 0);
                crate::ply::read::read_body(&ply, &h, &mut c, &p).unwrap();
                c.1
            });
            let (info_s, _) = best(&mut || read_info(&obj, &p).unwrap().faces);
            let info = read_info(&obj, &p).unwrap();
            let (body_s, obj_n) = best(&mut || {
                let mut c = Count(0, 0);
                read_body(&obj, &info, 1 << 30, &std::env::temp_dir(), &mut c, &p).unwrap();
                c.1
            });
            assert_eq!(ply_n, obj_n);
            let (pb, ob) = (std::fs::metadata(&ply).unwrap().len() as f64 / 1e6, info.bytes as f64 / 1e6);
            println!(
                "{} positions, {} triangles: PLY ascii {pb:.1} MB in {ply_s:.3} s = {:.1} MB/s; OBJ {ob:.1} MB: read_info {info_s:.3} s = {:.1} MB/s, \
                 read_body {body_s:.3} s = {:.1} MB/s, both {:.3} s = {:.1} MB/s ({:.2}x PLY)",
                if f64_pos { "f64" } else { "f32" },
                obj_n,
                pb / ply_s,
                ob / info_s,
                ob / body_s,
                info_s + body_s,
                ob / (info_s + body_s),
                (ob / (info_s + body_s)) / (pb / ply_s)
            );
        }
    }
}

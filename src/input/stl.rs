//! STL input (binary and ascii): see [`super`].
//!
//! Takes: a path. Gives: [`read_info`], a first look (binary or ascii, the
//! triangle count, the solid name), and [`read_body`], which feeds a
//! [`BodySink`] every kept triangle's three corners as vertices (positions
//! only, in file order, numbered densely), then the triangles
//! `[3k, 3k+1, 3k+2]`, which are implicit and so cost no second read. STL
//! has no shared vertices: the soup stage dereferences the corners and the
//! level builder welds them by position bits. A triangle with two
//! bit-identical corners (f32 bits) is dropped and counted as degenerate,
//! as a welded PLY of the same mesh drops it for its repeated index.
//!
//! Binary or ascii is decided by size first (`84 + 50 * count` bytes, the
//! count at byte 80), since many binary exporters start their header with
//! `solid`, then by content (`solid` at the start and text only in the
//! first KiB). Ascii keywords are case-insensitive, any whitespace
//! separates tokens, a file may hold several solids, the facet normals are
//! skipped unread (some exporters write `nan` or `-1.#IND` there) and may be
//! left out (`facet` straight to `outer loop`). Coordinates are f32, so
//! `as f64` keeps them exact.
//!
//! Reads are sequential through bounded buffers, whatever the file size.
//! Bad input is an error naming the file, the facet (record), the byte
//! offset and, in ascii files, the line.

use crate::error::{Error, Location, Result};
use crate::io::SeqInput as Input;
use crate::mesh::Vertex;
use crate::ply::read::{BodySink, BodyStats};
use crate::progress::Progress;
use std::path::Path;

/// What [`read_info`] learned about an STL file.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct StlInfo {
    /// Binary (true) or ascii.
    pub binary: bool,
    /// Facets in the file: the header's count (binary) or the facets
    /// counted (ascii), degenerate ones included.
    pub triangles: u64,
    /// File size.
    pub bytes: u64,
    /// The first solid's name (ascii) or the header's text up to its first
    /// NUL (binary), trimmed.
    pub name: String,
}

/// Binary header: 80 bytes of text, then the u32 LE facet count.
const HEADER: usize = 84;
/// Binary facet record: normal, three corners (3 × f32 each), u16 attribute bytes.
const RECORD: usize = 50;
/// Bytes looked at to tell ascii from binary.
const SNIFF: usize = 1024;
/// Longest ascii token accepted (numbers with many digits fit easily).
const MAX_TOKEN: usize = 4096;
/// Longest solid name kept (the rest of a longer line is skipped).
const MAX_NAME: usize = 1024;
/// Vertices per sink batch (a multiple of 3: whole triangles).
const BATCH: usize = 3 << 13;
const BUF: usize = 4 << 20;

/// The element name in error locations.
const FACET: &str = "facet";

/// Reads what an STL file holds: binary or ascii, its facet count and name.
///
/// Binary files cost their 84-byte header and a size check; ascii ones one
/// pass that counts the facets and checks the keywords (not the numbers:
/// [`read_body`] reads those). A file that is neither is an error saying
/// why (a binary header whose count disagrees with the file size, a text
/// file not starting with `solid`, a truncated ascii file).
pub fn read_info(path: &Path) -> Result<StlInfo> {
    // A small buffer first: a binary file costs one short read.
    let mut input = Input::open(path, 0, SNIFF)?;
    let len = input.len;
    input.ensure(SNIFF.min(len as usize))?;
    let head = &input.buf[..input.end.min(SNIFF)];
    if let Some(count) = binary_count(head, len) {
        let text = &head[..80];
        let text = &text[..text.iter().position(|&b| b == 0).unwrap_or(80)];
        let name = String::from_utf8_lossy(text).trim().to_string();
        return Ok(StlInfo { binary: true, triangles: count, bytes: len, name });
    }
    if looks_ascii(head) {
        input.buf.resize(BUF, 0);
        let mut a = Ascii { input, line: 1, tok_line: 1, tok_off: 0 };
        let (triangles, name) = a.parse(None)?;
        return Ok(StlInfo { binary: false, triangles, bytes: len, name });
    }
    let loc = Location { file: path.to_path_buf(), ..Default::default() };
    if len < HEADER as u64 {
        return Err(Error::input(
            loc,
            format!("not an STL file: {len} bytes is too short for a binary STL (84-byte header) and it does not start with 'solid'"),
        ));
    }
    let count = u32::from_le_bytes(head[80..84].try_into().unwrap()) as u64;
    let want = HEADER as u64 + RECORD as u64 * count;
    let why = if len < want { "truncated, or the count at byte 80 is wrong" } else { "trailing bytes, or the count at byte 80 is wrong" };
    let solid = if starts_with_solid(head) { "; it starts with 'solid' but is not ascii text either" } else { "" };
    Err(Error::input(
        Location { offset: Some(80), ..loc },
        format!("not an STL file: binary STL of {count} triangles should be {want} bytes, is {len} ({why}){solid}"),
    ))
}

/// Reads the body of the STL file `path` that [`read_info`] described,
/// feeding `sink` every kept triangle's corners as vertices, then the
/// triangles (see the module documentation).
pub fn read_body(path: &Path, info: &StlInfo, sink: &mut dyn BodySink, progress: &Progress) -> Result<BodyStats> {
    read_body_buffered(path, info, sink, progress, BUF)
}

fn read_body_buffered(path: &Path, info: &StlInfo, sink: &mut dyn BodySink, progress: &Progress, buf: usize) -> Result<BodyStats> {
    let input = Input::open(path, 0, buf)?;
    if input.len != info.bytes {
        return Err(changed(path, format!("{} bytes, not the {} it had", input.len, info.bytes)));
    }
    let mut em = Emitter { sink, verts: Vec::with_capacity(BATCH), stats: BodyStats::default(), progress, reported: 0 };
    let end = if info.binary {
        read_binary(input, info.triangles, &mut em)?
    } else {
        let mut a = Ascii { input, line: 1, tok_line: 1, tok_off: 0 };
        let (facets, _) = a.parse(Some(&mut em))?;
        if facets != info.triangles {
            return Err(changed(path, format!("{facets} facets, not the {} it had", info.triangles)));
        }
        a.input.offset()
    };
    em.finish(end)
}

/// Whether `head` (the first bytes of a file of `file_len` bytes, up to a
/// KiB or so) looks like an STL: a binary header whose facet count matches
/// the file size, or ascii text starting with `solid` that holds `facet` or
/// `endsolid`. For files whose extension does not tell; check the formats
/// with a magic string (PLY's `ply`) first, since the binary test is only a
/// size match.
pub fn looks_like_stl(head: &[u8], file_len: u64) -> bool {
    if binary_count(head, file_len).is_some() {
        return true;
    }
    looks_ascii(head) && (contains_ignore_case(head, b"facet") || contains_ignore_case(head, b"endsolid"))
}

/// The facet count of a binary STL whose size matches it.
fn binary_count(head: &[u8], len: u64) -> Option<u64> {
    if head.len() < HEADER || len < HEADER as u64 {
        return None;
    }
    let count = u32::from_le_bytes(head[80..84].try_into().unwrap()) as u64;
    (HEADER as u64 + RECORD as u64 * count == len).then_some(count)
}

/// Ascii STL whitespace (C's `isspace`).
#[inline(always)]
fn is_ws(b: u8) -> bool {
    matches!(b, b' ' | b'\t' | b'\n' | b'\r' | b'\x0b' | b'\x0c')
}

/// `solid` (any case) as the first token.
fn starts_with_solid(head: &[u8]) -> bool {
    let s = &head[head.iter().position(|&b| !is_ws(b)).unwrap_or(head.len())..];
    s.len() >= 5 && s[..5].eq_ignore_ascii_case(b"solid") && s.get(5).is_none_or(|&b| is_ws(b))
}

/// Starts with `solid` and holds no control bytes (binary data nearly always does).
fn looks_ascii(head: &[u8]) -> bool {
    starts_with_solid(head) && !head.iter().any(|&b| (b < 0x20 && !is_ws(b)) || b == 0x7f)
}

fn contains_ignore_case(hay: &[u8], needle: &[u8]) -> bool {
    hay.windows(needle.len()).any(|w| w.eq_ignore_ascii_case(needle))
}

fn changed(path: &Path, what: String) -> Error {
    Error::input(Location { file: path.to_path_buf(), ..Default::default() }, format!("the file changed since it was first read: it now has {what}"))
}

fn facet_loc(path: &Path, rec: Option<u64>, offset: u64) -> Location {
    Location { file: path.to_path_buf(), element: rec.map(|_| FACET.to_string()), record: rec, offset: Some(offset), line: None }
}

/// Batches the kept triangles' corners for the sink and counts.
struct Emitter<'a> {
    sink: &'a mut dyn BodySink,
    verts: Vec<Vertex>,
    stats: BodyStats,
    progress: &'a Progress,
    /// File offset reported to `progress` so far.
    reported: u64,
}

impl Emitter<'_> {
    /// One facet: its corners, or a count if two are bit-identical.
    #[inline]
    fn push(&mut self, c: &[[f32; 3]; 3]) {
        self.stats.faces += 1;
        let bits = c.map(|p| p.map(f32::to_bits));
        if bits[0] == bits[1] || bits[1] == bits[2] || bits[0] == bits[2] {
            self.stats.degenerate += 1;
            return;
        }
        for p in c {
            self.verts.push(Vertex { pos: p.map(|x| x as f64), ..Default::default() });
        }
    }

    #[inline]
    fn full(&self) -> bool {
        self.verts.len() + 3 > BATCH
    }

    /// Hands the batch to the sink; reports progress up to file offset
    /// `at`; a safe point for signals.
    fn flush(&mut self, at: u64) -> Result<()> {
        if !self.verts.is_empty() {
            self.sink.vertices(self.stats.vertices, &self.verts)?;
            self.stats.vertices += self.verts.len() as u64;
            self.verts.clear();
        }
        self.progress.inc(at.saturating_sub(self.reported));
        self.reported = self.reported.max(at);
        crate::io::signal::check()
    }

    /// Flushes the last vertices, then gives the sink the implicit
    /// triangles `[3k, 3k+1, 3k+2]`.
    fn finish(mut self, end: u64) -> Result<BodyStats> {
        self.flush(end)?;
        let n = self.stats.vertices / 3;
        let mut tris: Vec<[u64; 3]> = Vec::with_capacity(BATCH.min(n as usize));
        let mut k = 0;
        while k < n {
            let m = (n - k).min(BATCH as u64);
            tris.clear();
            tris.extend((k..k + m).map(|t| [3 * t, 3 * t + 1, 3 * t + 2]));
            self.sink.triangles(&tris)?;
            k += m;
            crate::io::signal::check()?;
        }
        self.stats.triangles = n;
        self.stats.bytes = end;
        Ok(self.stats)
    }
}

#[inline(always)]
fn f32_at(b: &[u8], off: usize) -> f32 {
    f32::from_le_bytes(b[off..off + 4].try_into().unwrap())
}

/// The binary body: `count` 50-byte records after the header.
fn read_binary(mut input: Input, count: u64, em: &mut Emitter) -> Result<u64> {
    let want = HEADER as u64 + RECORD as u64 * count;
    if input.len != want {
        return Err(Error::input(
            Location { file: input.path.clone(), offset: Some(80), ..Default::default() },
            format!("binary STL of {count} triangles should be {want} bytes, is {}", input.len),
        ));
    }
    if !input.ensure(HEADER)? {
        return Err(changed(&input.path, "fewer than 84 bytes".into()));
    }
    input.pos += HEADER;
    let mut rec = 0u64;
    while rec < count {
        if !input.ensure(RECORD)? {
            return Err(Error::input(
                facet_loc(&input.path, Some(rec), input.offset()),
                format!("unexpected end of file inside facet {rec} of {count}: the file is shorter than it was"),
            ));
        }
        let room = (BATCH - em.verts.len()) / 3;
        let n = ((input.avail() / RECORD) as u64).min(count - rec).min(room as u64) as usize;
        let start = input.pos;
        for j in 0..n {
            let b = &input.buf[start + j * RECORD..start + (j + 1) * RECORD];
            let c = [0, 1, 2].map(|v| [0, 1, 2].map(|a| f32_at(b, 12 + 12 * v + 4 * a)));
            if !c.iter().flatten().all(|x| x.is_finite()) {
                let at = input.base + (start + j * RECORD) as u64;
                return Err(Error::input(facet_loc(&input.path, Some(rec + j as u64), at), format!("non-finite coordinate in corners {c:?}")));
            }
            em.push(&c);
        }
        input.pos += n * RECORD;
        rec += n as u64;
        if em.full() {
            em.flush(input.offset())?;
        }
    }
    if input.ensure(1)? {
        return Err(changed(&input.path, "more bytes than its 84-byte header and records".into()));
    }
    Ok(input.offset())
}

/// The ascii parser: a whitespace tokenizer that counts lines.
struct Ascii {
    input: Input,
    /// 1-based line of the next unread byte.
    line: u64,
    /// Line and file offset of the last token read.
    tok_line: u64,
    tok_off: u64,
}

/// A token's bytes in the input buffer, valid until the next read.
type Tok = std::ops::Range<usize>;

impl Ascii {
    /// Parses the whole file: with `em`, reads the coordinates and feeds
    /// the kept facets to it; without, only checks the keywords. Gives the
    /// facet count and the first solid's name.
    fn parse(&mut self, mut em: Option<&mut Emitter>) -> Result<(u64, String)> {
        let mut facets = 0u64;
        let mut name = None;
        loop {
            match self.token()? {
                None if name.is_some() => break,
                Some(t) if self.is(&t, "solid") => {
                    let n = self.rest_of_line(name.is_none())?;
                    name.get_or_insert_with(|| String::from_utf8_lossy(&n).trim().to_string());
                }
                t => return Err(self.unexpected(t, None, if name.is_some() { "'solid' or the end of the file" } else { "'solid'" })),
            }
            loop {
                match self.token()? {
                    Some(t) if self.is(&t, "facet") => {
                        self.facet(facets, em.as_deref_mut())?;
                        facets += 1;
                    }
                    Some(t) if self.is(&t, "endsolid") => {
                        self.rest_of_line(false)?;
                        break;
                    }
                    t => return Err(self.unexpected(t, None, "'facet' or 'endsolid'")),
                }
            }
        }
        Ok((facets, name.unwrap_or_default()))
    }

    /// One facet after its `facet` keyword.
    fn facet(&mut self, rec: u64, em: Option<&mut Emitter>) -> Result<()> {
        let t = self.token()?;
        match t {
            Some(t) if self.is(&t, "normal") => {
                for _ in 0..3 {
                    if self.token()?.is_none() {
                        return Err(self.unexpected(None, Some(rec), "a normal component"));
                    }
                }
                self.expect("outer", rec)?;
            }
            Some(t) if self.is(&t, "outer") => {}
            t => return Err(self.unexpected(t, Some(rec), "'normal' or 'outer'")),
        }
        self.expect("loop", rec)?;
        let mut c = [[0f32; 3]; 3];
        for p in &mut c {
            self.expect("vertex", rec)?;
            for x in p.iter_mut() {
                let t = self.token()?;
                let Some(t) = t else {
                    return Err(self.unexpected(None, Some(rec), "a coordinate"));
                };
                if em.is_some() {
                    *x = self.coordinate(t, rec)?;
                }
            }
        }
        self.expect("endloop", rec)?;
        self.expect("endfacet", rec)?;
        if let Some(em) = em {
            em.push(&c);
            if em.full() {
                em.flush(self.input.offset())?;
            }
        }
        Ok(())
    }

    #[inline]
    fn is(&self, t: &Tok, kw: &str) -> bool {
        self.input.buf[t.clone()].eq_ignore_ascii_case(kw.as_bytes())
    }

    fn expect(&mut self, kw: &str, rec: u64) -> Result<()> {
        match self.token()? {
            Some(t) if self.is(&t, kw) => Ok(()),
            t => Err(self.unexpected(t, Some(rec), &format!("'{kw}'"))),
        }
    }

    fn coordinate(&self, t: Tok, rec: u64) -> Result<f32> {
        let b = &self.input.buf[t];
        match std::str::from_utf8(b).ok().and_then(|s| s.parse::<f32>().ok()) {
            Some(x) if x.is_finite() => Ok(x),
            Some(_) => Err(self.error(Some(rec), format!("non-finite coordinate '{}' (f32)", shown(b)))),
            None => Err(self.error(Some(rec), format!("expected a coordinate, found '{}'", shown(b)))),
        }
    }

    /// "expected X, found Y" at the last token (or at the end of the file).
    fn unexpected(&mut self, t: Option<Tok>, rec: Option<u64>, what: &str) -> Error {
        match t {
            Some(t) => self.error(rec, format!("expected {what}, found '{}'", shown(&self.input.buf[t]))),
            None => {
                self.tok_off = self.input.offset();
                self.tok_line = self.line;
                self.error(rec, format!("expected {what}, found the end of the file"))
            }
        }
    }

    fn error(&self, rec: Option<u64>, msg: String) -> Error {
        Error::input(facet_loc(&self.input.path, rec, self.tok_off), format!("line {}: {msg}", self.tok_line))
    }

    /// The next token, or None at the end of the file.
    #[inline]
    fn token(&mut self) -> Result<Option<Tok>> {
        let inp = &mut self.input;
        loop {
            if inp.pos == inp.end && !inp.refill(1)? {
                return Ok(None);
            }
            let b = inp.buf[inp.pos];
            if !is_ws(b) {
                break;
            }
            self.line += (b == b'\n') as u64;
            inp.pos += 1;
        }
        self.tok_off = inp.offset();
        self.tok_line = self.line;
        let mut i = 0;
        loop {
            while inp.pos + i < inp.end && !is_ws(inp.buf[inp.pos + i]) {
                i += 1;
            }
            if i > MAX_TOKEN {
                let start = &inp.buf[inp.pos..inp.pos + 40];
                let msg = format!("line {}: a token longer than {MAX_TOKEN} bytes ('{}...')", self.tok_line, shown(start));
                return Err(Error::input(facet_loc(&inp.path, None, self.tok_off), msg));
            }
            if inp.pos + i < inp.end || inp.eof {
                break;
            }
            inp.refill(i + 1)?;
        }
        let t = inp.pos..inp.pos + i;
        inp.pos += i;
        Ok(Some(t))
    }

    /// Skips the rest of the line, its end included; gives its first
    /// [`MAX_NAME`] bytes when `keep`.
    fn rest_of_line(&mut self, keep: bool) -> Result<Vec<u8>> {
        let mut out = Vec::new();
        let inp = &mut self.input;
        loop {
            if inp.pos == inp.end && !inp.refill(1)? {
                return Ok(out);
            }
            let chunk = &inp.buf[inp.pos..inp.end];
            let (n, nl) = match chunk.iter().position(|&b| b == b'\n') {
                Some(k) => (k, true),
                None => (chunk.len(), false),
            };
            if keep && out.len() < MAX_NAME {
                out.extend_from_slice(&chunk[..n.min(MAX_NAME - out.len())]);
            }
            inp.pos += n + nl as usize;
            if nl {
                self.line += 1;
                return Ok(out);
            }
        }
    }
}

/// A token for a message: lossy text, cut at 40 bytes.
fn shown(b: &[u8]) -> String {
    let s = String::from_utf8_lossy(&b[..b.len().min(40)]).into_owned();
    if b.len() > 40 {
        s + "..."
    } else {
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gen::{GenOptions, Generator, Shape};
    use crate::ply::read::CollectSink;
    use std::fmt::Write as _;
    use std::fs::File;
    use std::io::Write as _;
    use std::path::PathBuf;

    type Tri = [[f32; 3]; 3];

    fn binary_bytes(header: &[u8], tris: &[Tri]) -> Vec<u8> {
        let mut b = vec![0u8; 80];
        b[..header.len()].copy_from_slice(header);
        b.extend_from_slice(&(tris.len() as u32).to_le_bytes());
        for t in tris {
            b.extend_from_slice(&[0u8; 12]); // normal
            for p in t {
                for x in p {
                    b.extend_from_slice(&x.to_le_bytes());
                }
            }
            b.extend_from_slice(&[0u8; 2]);
        }
        b
    }

    /// `{:e}` writes the shortest form that reads back bit-exact.
    fn ascii_text(solids: &[(&str, &[Tri])]) -> String {
        let mut s = String::new();
        for (name, tris) in solids {
            writeln!(s, "solid {name}").unwrap();
            for t in *tris {
                writeln!(s, "  facet normal 0 0 1\n    outer loop").unwrap();
                for p in t {
                    writeln!(s, "      vertex {:e} {:e} {:e}", p[0], p[1], p[2]).unwrap();
                }
                writeln!(s, "    endloop\n  endfacet").unwrap();
            }
            writeln!(s, "endsolid {name}").unwrap();
        }
        s
    }

    fn write(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, bytes).unwrap();
        p
    }

    fn read(path: &Path) -> Result<(StlInfo, CollectSink, BodyStats)> {
        let info = read_info(path)?;
        let mut sink = CollectSink::default();
        let stats = read_body(path, &info, &mut sink, &Progress::hidden())?;
        Ok((info, sink, stats))
    }

    /// Reads with a tiny buffer too (every token and record across refills) and checks both agree.
    fn read_both(path: &Path) -> Result<(StlInfo, CollectSink, BodyStats)> {
        let (info, sink, stats) = read(path)?;
        let mut small = CollectSink::default();
        let s2 = read_body_buffered(path, &info, &mut small, &Progress::hidden(), 7)?;
        assert_eq!(s2, stats);
        assert_eq!(small.vertices, sink.vertices);
        assert_eq!(small.triangles, sink.triangles);
        Ok((info, sink, stats))
    }

    fn err(r: Result<impl std::fmt::Debug>) -> (String, Location) {
        match r.expect_err("should fail") {
            Error::Input { loc, msg } => (msg, loc),
            e => panic!("not an input error: {e}"),
        }
    }

    fn corners(sink: &CollectSink) -> Vec<[[f64; 3]; 3]> {
        sink.triangles.iter().map(|t| t.map(|i| sink.vertices[i as usize].pos)).collect()
    }

    fn check_stream(sink: &CollectSink, stats: &BodyStats) {
        assert_eq!(sink.vertices.len() as u64, stats.vertices);
        assert_eq!(stats.vertices, 3 * stats.triangles);
        assert_eq!(stats.triangles + stats.degenerate, stats.faces);
        assert_eq!(stats.polygons, 0);
        let want: Vec<[u64; 3]> = (0..stats.triangles).map(|k| [3 * k, 3 * k + 1, 3 * k + 2]).collect();
        assert_eq!(sink.triangles, want);
        for v in &sink.vertices {
            assert_eq!(*v, Vertex { pos: v.pos, ..Default::default() });
        }
    }

    fn sample() -> Vec<Tri> {
        vec![
            [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
            [[1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]],
            [[0.1, 0.2, 0.3], [0.1, 0.2, 0.3], [5.0, 6.0, 7.0]], // degenerate
            [[-1.5e-7, 3.4e38, -0.0], [1e-45, -2.5, 1.0 / 3.0], [7.0, 8.0, 9.0]],
            [[2.0, 2.0, 2.0], [3.0, 3.0, 3.0], [2.0, 2.0, 2.0]], // degenerate (first and last)
        ]
    }

    #[test]
    fn binary_and_ascii_give_the_same_streams() {
        let d = tempfile::tempdir().unwrap();
        let tris = sample();
        let b = write(d.path(), "m.stl", &binary_bytes(b"made by a test", &tris));
        let a = write(d.path(), "a.stl", ascii_text(&[("cube", &tris)]).as_bytes());
        let (bi, bs, bst) = read_both(&b).unwrap();
        let (ai, as_, ast) = read_both(&a).unwrap();
        assert_eq!(bi, StlInfo { binary: true, triangles: 5, bytes: 84 + 250, name: "made by a test".into() });
        assert_eq!(ai, StlInfo { binary: false, triangles: 5, bytes: std::fs::metadata(&a).unwrap().len(), name: "cube".into() });
        check_stream(&bs, &bst);
        assert_eq!(bs.vertices, as_.vertices);
        assert_eq!(bs.triangles, as_.triangles);
        assert_eq!(BodyStats { bytes: 0, ..bst }, BodyStats { bytes: 0, ..ast });
        assert_eq!(bst, BodyStats { vertices: 9, faces: 5, triangles: 3, degenerate: 2, polygons: 0, bytes: 334 });
        assert_eq!(ast.bytes, ai.bytes);
        let kept = [0, 1, 3].map(|k| tris[k].map(|p| p.map(|x| x as f64)));
        assert_eq!(corners(&bs), kept);
        // Bit-exact, signed zero and subnormal included.
        assert_eq!(bs.vertices[9 - 3].pos[2].to_bits(), (-0.0f64).to_bits());
        assert_eq!(bs.vertices[9 - 3 + 1].pos[0], 1e-45f32 as f64);
    }

    #[test]
    fn binary_header_starting_with_solid() {
        let d = tempfile::tempdir().unwrap();
        let tris = sample();
        let p = write(d.path(), "s.stl", &binary_bytes(b"solid exported by CAD   ", &tris));
        let (info, sink, stats) = read_both(&p).unwrap();
        assert!(info.binary);
        assert_eq!(info.name, "solid exported by CAD");
        assert_eq!(stats.triangles, 3);
        check_stream(&sink, &stats);
        // Even a header of text: the size decides.
        let mut h = [b' '; 80];
        h[..5].copy_from_slice(b"solid");
        let p = write(d.path(), "t.stl", &binary_bytes(&h, &tris[..1]));
        let (info, sink, _) = read_both(&p).unwrap();
        assert!(info.binary && info.name == "solid" && sink.vertices.len() == 3);
        // With a wrong size, it is neither.
        let mut b = binary_bytes(b"solid x", &tris);
        b.truncate(b.len() - 10);
        let (msg, loc) = err(read_info(&write(d.path(), "u.stl", &b)));
        assert!(msg.contains("binary STL of 5 triangles should be 334 bytes, is 324") && msg.contains("starts with 'solid'"), "{msg}");
        assert_eq!(loc.offset, Some(80));
    }

    #[test]
    fn several_ascii_solids_number_on() {
        let d = tempfile::tempdir().unwrap();
        let tris = sample();
        let one = ascii_text(&[("first part", &tris[..2]), ("second", &tris[2..]), ("", &[])]);
        let p = write(d.path(), "multi.stl", one.as_bytes());
        let (info, sink, stats) = read_both(&p).unwrap();
        assert_eq!((info.triangles, info.name.as_str()), (5, "first part"));
        check_stream(&sink, &stats);
        assert_eq!(stats.triangles, 3);
        assert_eq!(corners(&sink)[2], tris[3].map(|p| p.map(|x| x as f64)));
    }

    #[test]
    fn ascii_case_and_whitespace() {
        let d = tempfile::tempdir().unwrap();
        let text = "  \r\n\tSOLID  Mixed Case Name \r\nFacet Normal -nan -1.#IND 0\r\n OUTER\tLOOP\r\n\
                    VERTEX 1 2 3\x0bvertex +4.0E0 5. .6e1\x0c\r\nvertex\t7\t8\t9 endloop endfacet\r\n\
                    facet outer loop vertex 0 0 0 vertex 1 0 0 vertex 0 1 0 endloop endfacet\
                    \r\nENDsolid Mixed Case Name";
        let p = write(d.path(), "c.stl", text.as_bytes());
        let (info, sink, stats) = read_both(&p).unwrap();
        assert_eq!(info, StlInfo { binary: false, triangles: 2, bytes: text.len() as u64, name: "Mixed Case Name".into() });
        check_stream(&sink, &stats);
        assert_eq!(corners(&sink)[0], [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.0]]);
        assert_eq!(corners(&sink)[1], [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
        // A one-line "solid" with no name and no facets.
        let p = write(d.path(), "e.stl", b"solid\nendsolid\n");
        let (info, sink, stats) = read_both(&p).unwrap();
        assert_eq!((info.triangles, info.name.as_str(), stats.faces, sink.vertices.len()), (0, "", 0, 0));
    }

    #[test]
    fn degenerate_triangles_are_dropped_and_counted() {
        let d = tempfile::tempdir().unwrap();
        let z = [0.0f32; 3];
        let tris: Vec<Tri> = vec![
            [z, z, z],
            [[1.0, 0.0, 0.0], z, [1.0, 0.0, 0.0]],
            [[0.0, 0.0, 0.0], [-0.0, 0.0, 0.0], [1.0, 1.0, 1.0]], // distinct bits: kept
            [[1.0, 0.0, 0.0], [1.0, f32::from_bits(1), 0.0], [1.0, 0.0, f32::from_bits(1)]], // kept
            [[4.0, 4.0, 4.0], [5.0, 5.0, 5.0], [5.0, 5.0, 5.0]],
        ];
        for (name, bytes) in [("d.stl", binary_bytes(b"", &tris)), ("d-ascii.stl", ascii_text(&[("d", &tris)]).into_bytes())] {
            let p = write(d.path(), name, &bytes);
            let (_, sink, stats) = read_both(&p).unwrap();
            assert_eq!((stats.faces, stats.triangles, stats.degenerate, stats.vertices), (5, 2, 3, 6), "{name}");
            check_stream(&sink, &stats);
            assert_eq!(corners(&sink), [2, 3].map(|k| tris[k].map(|p| p.map(|x| x as f64))), "{name}");
        }
    }

    #[test]
    fn truncated_binary_is_an_error() {
        let d = tempfile::tempdir().unwrap();
        let tris: Vec<Tri> = (0..12).map(|k| [[k as f32, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]).collect();
        let mut b = binary_bytes(b"binary", &tris);
        b.truncate(600);
        let (msg, loc) = err(read_info(&write(d.path(), "t.stl", &b)));
        assert!(msg.contains("binary STL of 12 triangles should be 684 bytes, is 600") && msg.contains("truncated"), "{msg}");
        assert_eq!(loc.offset, Some(80));
        // Trailing bytes.
        let mut b = binary_bytes(b"binary", &tris);
        b.extend_from_slice(b"\0\0\0");
        let (msg, _) = err(read_info(&write(d.path(), "x.stl", &b)));
        assert!(msg.contains("should be 684 bytes, is 687") && msg.contains("trailing"), "{msg}");
        // Shorter than a header.
        let (msg, loc) = err(read_info(&write(d.path(), "h.stl", &[0u8; 50])));
        assert!(msg.contains("50 bytes is too short"), "{msg}");
        assert_eq!(loc.offset, None);
        // The file changed between read_info and read_body.
        let p = write(d.path(), "c.stl", &binary_bytes(b"", &tris));
        let info = read_info(&p).unwrap();
        std::fs::write(&p, binary_bytes(b"", &tris[..11])).unwrap();
        let (msg, _) = err(read_body(&p, &info, &mut CollectSink::default(), &Progress::hidden()));
        assert!(msg.contains("changed"), "{msg}");
    }

    #[test]
    fn truncated_ascii_is_an_error() {
        let d = tempfile::tempdir().unwrap();
        let text = ascii_text(&[("t", &sample())]);
        // Cut inside the second facet's loop, after its third vertex line.
        let cut = text.match_indices("vertex").nth(5).map(|(i, _)| i + text[i..].find('\n').unwrap() + 1).unwrap();
        let p = write(d.path(), "t.stl", &text.as_bytes()[..cut]);
        let (msg, loc) = err(read_info(&p));
        // solid (1), facet 0 (2-8), facet 1: facet (9), outer (10), 3 vertices (11-13), endloop would be line 14.
        assert_eq!(msg, "line 14: expected 'endloop', found the end of the file");
        assert_eq!((loc.element.as_deref(), loc.record, loc.offset), (Some("facet"), Some(1), Some(cut as u64)));
        // A fourth vertex where 'endloop' belongs.
        let bad = text.replacen("    endloop", "      vertex 1 2 3\n    endloop", 2);
        let bad = bad.replacen("      vertex 1 2 3\n    endloop", "    endloop", 1);
        let p = write(d.path(), "v.stl", bad.as_bytes());
        let (msg, loc) = err(read_info(&p));
        assert_eq!(msg, "line 14: expected 'endloop', found 'vertex'");
        let off = bad.match_indices("vertex").nth(6).unwrap().0;
        assert_eq!((loc.record, loc.offset), (Some(1), Some(off as u64)));
        // No endsolid.
        let p = write(d.path(), "e.stl", text.trim_end().rsplit_once('\n').unwrap().0.as_bytes());
        let (msg, _) = err(read_info(&p));
        assert!(msg.ends_with("expected 'facet' or 'endsolid', found the end of the file"), "{msg}");
    }

    #[test]
    fn garbage_is_an_error() {
        let d = tempfile::tempdir().unwrap();
        let (msg, _) = err(read_info(&write(d.path(), "g.stl", &b"hello world, ".repeat(10))));
        assert!(msg.contains("binary STL of") && msg.contains("should be"), "{msg}");
        assert!(!msg.contains("starts with 'solid'"), "{msg}");
        let (msg, _) = err(read_info(&write(d.path(), "p.ply", b"ply\nformat ascii 1.0\nend_header\n")));
        assert!(msg.contains("does not start with 'solid'"), "{msg}");
        // Ascii: a word where a keyword belongs, a bad number, junk after endsolid.
        let text = ascii_text(&[("g", &sample()[..2])]);
        let p = write(d.path(), "k.stl", text.replacen("outer loop", "outer hoop", 1).as_bytes());
        let (msg, loc) = err(read_info(&p));
        assert_eq!((msg.as_str(), loc.record), ("line 3: expected 'loop', found 'hoop'", Some(0)));
        let p = write(d.path(), "n.stl", text.replacen("vertex 1e0", "vertex 1x0", 1).as_bytes());
        let info = read_info(&p).unwrap(); // numbers are read by read_body
        let (msg, loc) = err(read_body(&p, &info, &mut CollectSink::default(), &Progress::hidden()));
        assert_eq!((msg.as_str(), loc.record), ("line 5: expected a coordinate, found '1x0'", Some(0)));
        let p = write(d.path(), "j.stl", format!("{text}junk\n").as_bytes());
        let (msg, loc) = err(read_info(&p));
        assert_eq!(msg, format!("line {}: expected 'solid' or the end of the file, found 'junk'", text.lines().count() + 1));
        assert_eq!((loc.record, loc.offset), (None, Some(text.len() as u64)));
        // An endless token.
        let mut long = b"solid x\nfacet normal ".to_vec();
        long.resize(20_000, b'7');
        let (msg, _) = err(read_info(&write(d.path(), "l.stl", &long)));
        assert!(msg.contains("longer than"), "{msg}");
        // Binary data after an ascii-looking first KiB.
        let mut b = text.clone().into_bytes();
        b.resize(2000, b' ');
        b.extend_from_slice(&[0, 1, 2, 3]);
        let (msg, _) = err(read_info(&write(d.path(), "b.stl", &b)));
        assert!(msg.contains("found '\0"), "{msg}");
    }

    #[test]
    fn non_finite_coordinates_are_errors() {
        let d = tempfile::tempdir().unwrap();
        let mut tris = sample();
        tris[3][1][2] = f32::NAN;
        let p = write(d.path(), "nan.stl", &binary_bytes(b"", &tris));
        let info = read_info(&p).unwrap();
        let (msg, loc) = err(read_body(&p, &info, &mut CollectSink::default(), &Progress::hidden()));
        assert!(msg.starts_with("non-finite coordinate"), "{msg}");
        assert_eq!((loc.element.as_deref(), loc.record, loc.offset), (Some("facet"), Some(3), Some(84 + 3 * 50)));
        tris[3][1][2] = f32::INFINITY;
        let p = write(d.path(), "inf.stl", &binary_bytes(b"", &tris));
        let (msg, loc) = err(read_body(&p, &info, &mut CollectSink::default(), &Progress::hidden()));
        assert!(msg.contains("inf"), "{msg}");
        assert_eq!(loc.record, Some(3));
        // Ascii: nan, inf, and a number too large for f32.
        for (tok, name) in [("NaN", "n.stl"), ("-inf", "i.stl"), ("1e39", "o.stl")] {
            let text = ascii_text(&[("x", &sample())]).replacen("vertex 1e0 1e0 0e0", &format!("vertex 1e0 {tok} 0e0"), 1);
            let p = write(d.path(), name, text.as_bytes());
            let info = read_info(&p).unwrap();
            let (msg, loc) = err(read_body(&p, &info, &mut CollectSink::default(), &Progress::hidden()));
            assert_eq!(msg, format!("line 12: non-finite coordinate '{tok}' (f32)"));
            let off = text.find(&format!(" {tok} ")).unwrap() + 1;
            assert_eq!((loc.record, loc.offset), (Some(1), Some(off as u64)));
        }
    }

    #[test]
    fn one_triangle() {
        let d = tempfile::tempdir().unwrap();
        let t: Tri = [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.5]];
        for (name, bytes) in [("1.stl", binary_bytes(b"one", &[t])), ("1a.stl", ascii_text(&[("one", &[t])]).into_bytes())] {
            let (info, sink, stats) = read_both(&write(d.path(), name, &bytes)).unwrap();
            assert_eq!((info.triangles, info.name.as_str()), (1, "one"));
            assert_eq!(stats, BodyStats { vertices: 3, faces: 1, triangles: 1, degenerate: 0, polygons: 0, bytes: bytes.len() as u64 });
            assert_eq!(corners(&sink), [t.map(|p| p.map(|x| x as f64))]);
            assert_eq!(sink.triangles, [[0, 1, 2]]);
        }
    }

    #[test]
    fn empty_binary_reads_as_zero_triangles() {
        let d = tempfile::tempdir().unwrap();
        let p = write(d.path(), "0.stl", &binary_bytes(b"solid empty", &[]));
        let (info, sink, stats) = read_both(&p).unwrap();
        assert_eq!(info, StlInfo { binary: true, triangles: 0, bytes: 84, name: "solid empty".into() });
        assert_eq!(stats, BodyStats { bytes: 84, ..Default::default() });
        assert!(sink.vertices.is_empty() && sink.triangles.is_empty());
    }

    #[test]
    fn generated_mesh_round_trips_bit_exact() {
        let d = tempfile::tempdir().unwrap();
        // Over BATCH / 3 triangles, so the vertices come in several batches.
        for tris in [2000, 12_000] {
            let (verts, faces) = Generator::new(&GenOptions { shape: Shape::Sphere, tris, ..Default::default() }).mesh();
            let soup: Vec<Tri> = faces.iter().map(|f| f.map(|i| verts[i as usize].pos.map(|x| x as f32))).collect();
            let p = write(d.path(), "g.stl", &binary_bytes(b"generated", &soup));
            let (info, sink, stats) = read_both(&p).unwrap();
            assert_eq!(info.triangles, faces.len() as u64);
            check_stream(&sink, &stats);
            let bits = |t: &[[f64; 3]; 3]| t.map(|p| p.map(f64::to_bits));
            let want: Vec<_> = soup
                .iter()
                .map(|t| t.map(|p| p.map(|x| x as f64)))
                .filter(|t| {
                    let b = bits(t);
                    b[0] != b[1] && b[1] != b[2] && b[0] != b[2]
                })
                .collect();
            assert_eq!(stats.degenerate, faces.len() as u64 - want.len() as u64);
            let got = corners(&sink);
            assert_eq!(got.len(), want.len());
            assert!(got.iter().zip(&want).all(|(g, w)| bits(g) == bits(w)));
            // The ascii form of the same soup gives the same stream.
            let a = write(d.path(), "g-ascii.stl", ascii_text(&[("generated", &soup)]).as_bytes());
            let (_, asink, astats) = read(&a).unwrap();
            assert_eq!(BodyStats { bytes: 0, ..astats }, BodyStats { bytes: 0, ..stats });
            assert!(asink.vertices.iter().zip(&sink.vertices).all(|(a, b)| a.pos.map(f64::to_bits) == b.pos.map(f64::to_bits)));
        }
    }

    #[test]
    fn sniffing() {
        let tris = sample();
        let b = binary_bytes(b"solid but binary", &tris);
        assert!(looks_like_stl(&b, b.len() as u64));
        assert!(!looks_like_stl(&b, b.len() as u64 + 1));
        assert!(!looks_like_stl(&b[..50], b.len() as u64));
        let a = ascii_text(&[("x", &tris)]);
        assert!(looks_like_stl(a.as_bytes(), a.len() as u64));
        assert!(looks_like_stl(&a.as_bytes()[..40], a.len() as u64));
        assert!(looks_like_stl(b"solid\nendsolid\n", 15));
        assert!(!looks_like_stl(b"solid waste report, page 1", 26));
        assert!(!looks_like_stl(b"solidity facet", 14));
        assert!(!looks_like_stl(b"ply\nformat binary_little_endian 1.0\n", 1000));
        assert!(!looks_like_stl(b"", 0));
    }

    #[test]
    fn sink_errors_stop_the_read() {
        struct Fail;
        impl BodySink for Fail {
            fn vertices(&mut self, _: u64, _: &[Vertex]) -> Result<()> {
                Err(Error::Usage("sink full".into()))
            }
            fn triangles(&mut self, _: &[[u64; 3]]) -> Result<()> {
                Ok(())
            }
        }
        let d = tempfile::tempdir().unwrap();
        let p = write(d.path(), "s.stl", &binary_bytes(b"", &sample()));
        let info = read_info(&p).unwrap();
        let e = read_body(&p, &info, &mut Fail, &Progress::hidden()).unwrap_err();
        assert!(matches!(e, Error::Usage(_)));
    }

    /// The fuzz seeds read, and random mutations of them and of the
    /// test files (flips, cuts, insertions) give an error or a consistent
    /// stream, never a panic: a short stand-in for `fuzz/stl_parse`.
    #[test]
    fn fuzz_seeds_and_mutations() {
        let d = tempfile::tempdir().unwrap();
        let seeds = Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/seeds");
        let mut inputs: Vec<Vec<u8>> = Vec::new();
        for e in std::fs::read_dir(&seeds).unwrap() {
            let p = e.unwrap().path();
            if p.extension().is_some_and(|x| x == "stl") {
                let (info, sink, stats) = read_both(&p).unwrap();
                check_stream(&sink, &stats);
                assert_eq!(stats.faces, info.triangles);
                inputs.push(std::fs::read(&p).unwrap());
            }
        }
        assert_eq!(inputs.len(), 3);
        inputs.push(binary_bytes(b"solid x", &sample()));
        inputs.push(ascii_text(&[("a", &sample()), ("b", &sample()[..1])]).into_bytes());
        let mut rng = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = |n: usize| {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            (rng % n.max(1) as u64) as usize
        };
        let p = d.path().join("m.stl");
        let mut accepted = 0;
        for it in 0..3000 {
            let mut b = inputs[it % inputs.len()].clone();
            for _ in 0..1 + next(4) {
                let at = next(b.len() + 1);
                match next(4) {
                    0 if at < b.len() => b[at] ^= 1 << next(8),
                    1 => b.truncate(at),
                    2 => b.insert(at, [b' ', b'\n', b'0', b'e', 0, 0xff][next(6)]),
                    _ if at < b.len() => b[at] = b"solidfacetnormalouterloopvertexendloopendfacet"[next(46)],
                    _ => {}
                }
            }
            std::fs::write(&p, &b).unwrap();
            let sniffed = looks_like_stl(&b[..b.len().min(SNIFF)], b.len() as u64);
            let Ok(info) = read_info(&p) else { continue };
            assert!(!info.binary || sniffed);
            if let Ok((_, sink, stats)) = read_both(&p) {
                check_stream(&sink, &stats);
                assert_eq!((stats.faces, stats.bytes), (info.triangles, b.len() as u64));
                assert!(sink.vertices.iter().all(|v| v.pos.iter().all(|c| c.is_finite())));
                accepted += 1;
            }
        }
        assert!(accepted > 100, "{accepted}");
    }

    /// Decode speed: `cargo test --release --lib input::stl::tests::speed -- --ignored --nocapture`.
    #[test]
    #[ignore = "writes 2 M-triangle files (about 100 MB binary, 450 MB ascii); run in release"]
    fn speed() {
        struct Null;
        impl BodySink for Null {
            fn vertices(&mut self, _: u64, b: &[Vertex]) -> Result<()> {
                std::hint::black_box(b);
                Ok(())
            }
            fn triangles(&mut self, b: &[[u64; 3]]) -> Result<()> {
                std::hint::black_box(b);
                Ok(())
            }
        }
        let d = tempfile::tempdir().unwrap();
        let n = 2_000_000u64;
        let g = Generator::new(&GenOptions { shape: Shape::Sphere, tris: n, ..Default::default() });
        let tri = |k: u64| g.face(k).map(|i| g.vertex(i as u64).pos.map(|x| x as f32));
        let bp = d.path().join("speed.stl");
        let ap = d.path().join("speed-ascii.stl");
        {
            let mut w = std::io::BufWriter::new(File::create(&bp).unwrap());
            w.write_all(&[0u8; 80]).unwrap();
            w.write_all(&(g.face_count() as u32).to_le_bytes()).unwrap();
            let mut a = std::io::BufWriter::new(File::create(&ap).unwrap());
            writeln!(a, "solid speed").unwrap();
            for k in 0..g.face_count() {
                let t = tri(k);
                w.write_all(&[0u8; 12]).unwrap();
                writeln!(a, "facet normal 0.000000e+00 0.000000e+00 1.000000e+00\n outer loop").unwrap();
                for p in t {
                    for x in p {
                        w.write_all(&x.to_le_bytes()).unwrap();
                    }
                    writeln!(a, "  vertex {:e} {:e} {:e}", p[0], p[1], p[2]).unwrap();
                }
                w.write_all(&[0u8; 2]).unwrap();
                writeln!(a, " endloop\nendfacet").unwrap();
            }
            writeln!(a, "endsolid speed").unwrap();
        }
        for p in [&bp, &ap] {
            let t0 = std::time::Instant::now();
            let info = read_info(p).unwrap();
            let t_info = t0.elapsed().as_secs_f64();
            let mut best = f64::MAX;
            let mut stats = BodyStats::default();
            for _ in 0..3 {
                let t = std::time::Instant::now();
                stats = read_body(p, &info, &mut Null, &Progress::hidden()).unwrap();
                best = best.min(t.elapsed().as_secs_f64());
            }
            let mb = info.bytes as f64 / 1e6;
            println!(
                "{}: {} triangles, {mb:.0} MB: read_info {t_info:.3} s ({:.0} MB/s), read_body best of 3 {best:.3} s ({:.0} MB/s, {:.1} M triangles/s)",
                if info.binary { "binary" } else { "ascii" },
                stats.triangles,
                mb / t_info,
                mb / best,
                stats.faces as f64 / best / 1e6
            );
        }
    }
}

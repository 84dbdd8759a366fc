//! The triangle-soup file format, defined here and nowhere else.
//!
//! Takes/gives: `.soup` files. Layout (all little-endian):
//!
//! | offset | size | field |
//! |---|---|---|
//! | 0 | 8 | magic `OCTSOUP\0` |
//! | 8 | 4 | version (1) |
//! | 12 | 4 | attribute bits ([`AttrSet`]) |
//! | 16 | 4 | corner size in bytes ([`VertexLayout::size`]) |
//! | 20 | 4 | record size (3 × corner size) |
//! | 24 | 8 | triangle count |
//! | 32 | 8 | input vertex count |
//! | 40 | 8 | input face count |
//! | 48 | 8 | degenerate triangles dropped |
//! | 56 | 48 | bbox min xyz, max xyz (f64) of the soup's corners |
//! | 104 | 24 | reserved (zero) |
//! | 128 | … | `triangles` records of 3 corners, each a packed [`VertexLayout`] |
//!
//! Records carry exactly the attributes of the input: a position-only float
//! mesh costs 36 bytes per triangle. Positions keep the input's precision.

use crate::error::{Error, IoContext, Location, Result};
use crate::io::{AtomicFile, SEQ_BUF};
use crate::mesh::{Aabb, AttrSet, Vertex, VertexLayout};
use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

pub const MAGIC: [u8; 8] = crate::io::SOUP_MAGIC;
pub const VERSION: u32 = 1;
pub const HEADER_SIZE: usize = 128;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SoupHeader {
    pub attrs: AttrSet,
    pub triangles: u64,
    pub input_vertices: u64,
    pub input_faces: u64,
    pub degenerate: u64,
    pub bbox: Aabb,
}

impl SoupHeader {
    pub fn layout(&self) -> VertexLayout {
        VertexLayout::new(self.attrs)
    }
    pub fn record_size(&self) -> usize {
        3 * self.layout().size
    }

    pub fn to_bytes(&self) -> [u8; HEADER_SIZE] {
        let mut b = [0u8; HEADER_SIZE];
        let l = self.layout();
        b[0..8].copy_from_slice(&MAGIC);
        b[8..12].copy_from_slice(&VERSION.to_le_bytes());
        b[12..16].copy_from_slice(&self.attrs.0.to_le_bytes());
        b[16..20].copy_from_slice(&(l.size as u32).to_le_bytes());
        b[20..24].copy_from_slice(&(3 * l.size as u32).to_le_bytes());
        b[24..32].copy_from_slice(&self.triangles.to_le_bytes());
        b[32..40].copy_from_slice(&self.input_vertices.to_le_bytes());
        b[40..48].copy_from_slice(&self.input_faces.to_le_bytes());
        b[48..56].copy_from_slice(&self.degenerate.to_le_bytes());
        for k in 0..3 {
            b[56 + 8 * k..64 + 8 * k].copy_from_slice(&self.bbox.min[k].to_le_bytes());
            b[80 + 8 * k..88 + 8 * k].copy_from_slice(&self.bbox.max[k].to_le_bytes());
        }
        b
    }

    pub fn from_bytes(path: &Path, b: &[u8]) -> Result<SoupHeader> {
        let bad = |msg: String| Error::input(Location { file: path.to_path_buf(), offset: Some(0), ..Default::default() }, msg);
        if b.len() < HEADER_SIZE || b[0..8] != MAGIC {
            return Err(bad("not an octolod soup file (bad magic)".into()));
        }
        let u32_at = |o: usize| u32::from_le_bytes(b[o..o + 4].try_into().unwrap());
        let u64_at = |o: usize| u64::from_le_bytes(b[o..o + 8].try_into().unwrap());
        let f64_at = |o: usize| f64::from_le_bytes(b[o..o + 8].try_into().unwrap());
        if u32_at(8) != VERSION {
            return Err(bad(format!("soup version {} is not supported (expected {VERSION})", u32_at(8))));
        }
        let attrs = AttrSet::from_bits(u32_at(12)).ok_or_else(|| bad(format!("unknown attribute bits {:#x}", u32_at(12))))?;
        let l = VertexLayout::new(attrs);
        if u32_at(16) as usize != l.size || u32_at(20) as usize != 3 * l.size {
            return Err(bad("record size does not match the attribute set".into()));
        }
        Ok(SoupHeader {
            attrs,
            triangles: u64_at(24),
            input_vertices: u64_at(32),
            input_faces: u64_at(40),
            degenerate: u64_at(48),
            bbox: Aabb { min: [f64_at(56), f64_at(64), f64_at(72)], max: [f64_at(80), f64_at(88), f64_at(96)] },
        })
    }
}

/// Writes a soup sequentially; the header is completed on `commit`.
pub struct SoupWriter {
    out: AtomicFile,
    header: SoupHeader,
    layout: VertexLayout,
}

impl SoupWriter {
    /// An existing soup is replaced only when `force` is set (see `io::check_output`).
    /// `scratch`: not synced to disk on commit ([`AtomicFile::scratch`]).
    pub fn create(path: &Path, attrs: AttrSet, force: bool, scratch: bool) -> Result<SoupWriter> {
        let mut out = AtomicFile::create(path, crate::io::OutputKind::Soup, force)?;
        if scratch {
            out = out.scratch();
        }
        let header = SoupHeader { attrs, triangles: 0, input_vertices: 0, input_faces: 0, degenerate: 0, bbox: Aabb::EMPTY };
        out.write_all(&[0u8; HEADER_SIZE]).ctx(path, "write")?;
        Ok(SoupWriter { out, header, layout: VertexLayout::new(attrs) })
    }

    pub fn layout(&self) -> VertexLayout {
        self.layout
    }

    /// Appends one triangle given as three encoded corners (3 × layout size bytes).
    #[inline]
    pub fn push_encoded(&mut self, rec: &[u8]) -> Result<()> {
        let s = self.layout.size;
        for c in 0..3 {
            self.header.bbox.add(self.layout.position(&rec[c * s..]));
        }
        self.header.triangles += 1;
        // The path is only needed for the error: no allocation per triangle.
        self.out.write_all(&rec[..3 * s]).map_err(|e| Error::io(self.out.dest(), "write", e))
    }

    pub fn push(&mut self, tri: &[Vertex; 3]) -> Result<()> {
        let mut rec = [0u8; 3 * 56];
        let s = self.layout.size;
        for c in 0..3 {
            self.layout.encode(&tri[c], &mut rec[c * s..]);
        }
        self.push_encoded(&rec[..3 * s])
    }

    /// Completes the header with the input's figures and renames into place.
    pub fn commit(mut self, input_vertices: u64, input_faces: u64, degenerate: u64) -> Result<SoupHeader> {
        self.header.input_vertices = input_vertices;
        self.header.input_faces = input_faces;
        self.header.degenerate = degenerate;
        let dest = self.out.dest().to_path_buf();
        let w = self.out.writer();
        w.flush().ctx(&dest, "write")?;
        let f = w.get_mut();
        f.seek(SeekFrom::Start(0)).ctx(&dest, "seek")?;
        f.write_all(&self.header.to_bytes()).ctx(&dest, "write")?;
        f.seek(SeekFrom::End(0)).ctx(&dest, "seek")?;
        let h = self.header;
        self.out.commit()?;
        Ok(h)
    }
}

/// Sequential soup reader.
pub struct SoupReader {
    pub header: SoupHeader,
    path: PathBuf,
    r: BufReader<File>,
    left: u64,
}

impl SoupReader {
    pub fn open(path: &Path) -> Result<SoupReader> {
        let f = File::open(path).ctx(path, "open")?;
        let len = f.metadata().ctx(path, "stat")?.len();
        let mut r = BufReader::with_capacity(SEQ_BUF, f);
        let mut hb = [0u8; HEADER_SIZE];
        r.read_exact(&mut hb).map_err(|_| Error::input(Location { file: path.to_path_buf(), ..Default::default() }, "file too short for a soup header"))?;
        let header = SoupHeader::from_bytes(path, &hb)?;
        let want = HEADER_SIZE as u64 + header.triangles * header.record_size() as u64;
        if len != want {
            return Err(Error::input(
                Location { file: path.to_path_buf(), ..Default::default() },
                format!("soup is {len} bytes but its header promises {want} ({} triangles)", header.triangles),
            ));
        }
        Ok(SoupReader { header, path: path.to_path_buf(), r, left: header.triangles })
    }

    /// Reads up to `max` triangles' records into `buf` (replacing its content); returns how many.
    pub fn read_batch(&mut self, buf: &mut Vec<u8>, max: usize) -> Result<usize> {
        let n = (self.left.min(max as u64)) as usize;
        buf.resize(n * self.header.record_size(), 0);
        self.r.read_exact(buf).ctx(&self.path, "read")?;
        self.left -= n as u64;
        Ok(n)
    }

    /// Every triangle decoded. For small soups (tests, tools).
    pub fn read_all(path: &Path) -> Result<(SoupHeader, Vec<[Vertex; 3]>)> {
        let mut r = SoupReader::open(path)?;
        let l = r.header.layout();
        let mut buf = Vec::new();
        let mut out = Vec::with_capacity(r.header.triangles as usize);
        while r.read_batch(&mut buf, 1 << 16)? > 0 {
            for rec in buf.chunks_exact(3 * l.size) {
                out.push([0, 1, 2].map(|c| l.decode(&rec[c * l.size..])));
            }
        }
        Ok((r.header, out))
    }
}

//! OBJ corners out of core: the corner path of [`super`] when the `v`,
//! `vt` and `vn` tables with the map of distinct (v, vt, vn, material)
//! corners do not fit `--mem` (the material: the face's texture slot,
//! 0 without [`AttrSet::MATERIAL`](crate::mesh::AttrSet::MATERIAL)).
//!
//! Takes: the body pass's tables and kept triangles ([`Spool`]). Gives:
//! the sink's vertices (one per distinct corner of a kept triangle), then
//! its triangles, in phases over scratch files, each within the budget:
//! 1. the body pass writes the tables to packed files and each kept
//!    triangle's corners to the bucket of their position's *slab* (a
//!    consecutive range of `v` numbers);
//! 2. slab by slab, with the slab's positions in memory, the distinct
//!    corners are numbered in order of first appearance and written as
//!    vertices, and each corner's vertex number is placed at its slot
//!    (3·triangle + corner); `vt` and `vn` values come from memory when
//!    their table fits a sixteenth of the budget, else they are requested
//!    by table slab (a slab whose corners would overfill the map is done
//!    in several sub-ranges of `v`, reading its bucket again);
//! 3. each requested table is joined slab by slab, its values placed by
//!    vertex number;
//! 4. the vertices are emitted in order, then the triangles in slot order.
//!
//! Like the soup stage (whose [`buckets`](crate::io::buckets) it uses),
//! records are distributed by dense keys, never sorted, and the disk is
//! read and written in sequence. The vertices are numbered by slab, not
//! as the in-memory path numbers them, and corners only degenerate
//! triangles use make no vertex; the triangles and their corners'
//! attributes are the same.

use super::{Out, Tris, CORNER_BYTES};
use crate::error::{Error, IoContext, Result};
use crate::io::buckets::{read_records, BucketFiles, SlotBuckets};
use crate::io::{ScratchDir, SEQ_BUF};
use crate::mesh::Vertex;
use crate::ply::read::BodyStats;
use rustc_hash::FxHashMap;
use std::fs::File;
use std::io::{BufReader, BufWriter, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

/// A corner record: v, vt, vn (u32, [`NONE`] for none), its slot (u64)
/// and its material (u16).
const CREC: usize = 22;
/// A packed position: 3 × f64 and a colour.
const PREC: usize = 28;
/// A vertex as phase 2 writes it: position, colour, uv, normal, material.
const VREC: usize = 50;
/// A table request: vertex number (u64) and table index (u32).
const RREC: usize = 12;
/// Absent `vt` / `vn`.
pub(super) const NONE: u32 = u32::MAX;
/// Most buckets per set (each an open file with its write buffer).
const MAX_BUCKETS: u64 = 256;

/// One attribute table (`vt` or `vn`) on disk: its file, element size,
/// length and slab size for the join.
struct Table {
    path: PathBuf,
    file: Option<BufWriter<File>>,
    elem: usize,
    len: u64,
    per: u64,
    /// Whether phase 2 looks values up in memory (the table fits
    /// [`Spool::budget`] / 16) rather than requesting them.
    in_memory: bool,
}

impl Table {
    fn new(dir: &Path, name: &str, elem: usize, len: u64, budget: u64, path: &Path) -> Result<Table> {
        let per = (budget / 4 / elem as u64).max(1);
        let in_memory = len * elem as u64 <= budget / 16;
        if !in_memory && len.div_ceil(per) > MAX_BUCKETS {
            return Err(too_small(path, name, len * elem as u64 * 4 / MAX_BUCKETS, budget));
        }
        let p = dir.join(format!("{name}.bin"));
        let f = File::create(&p).ctx(&p, "create scratch file")?;
        Ok(Table { path: p, file: Some(BufWriter::with_capacity(SEQ_BUF, f)), elem, len, per, in_memory })
    }

    fn push(&mut self, b: &[u8]) -> Result<()> {
        let f = self.file.as_mut().expect("written before it is closed");
        f.write_all(b).ctx(&self.path, "write scratch file")
    }

    fn close(&mut self) -> Result<()> {
        if let Some(f) = self.file.take() {
            f.into_inner().map_err(|e| e.into_error()).ctx(&self.path, "write scratch file")?;
        }
        Ok(())
    }

    /// Elements `first..first + n`, read from the file.
    fn slab(&self, first: u64, n: u64) -> Result<Vec<u8>> {
        read_at(&self.path, first * self.elem as u64, (n * self.elem as u64) as usize)
    }

    /// The bucket of index `i` (absent ones go to bucket 0).
    fn bucket(&self, i: u32) -> usize {
        if i == NONE {
            0
        } else {
            (i as u64 / self.per) as usize
        }
    }

    fn buckets(&self) -> usize {
        self.len.div_ceil(self.per).max(1) as usize
    }
}

fn too_small(path: &Path, what: &str, need: u64, budget: u64) -> Error {
    Error::Usage(format!(
        "{}: its faces reference texture coordinates or normals, so each distinct (v, vt, vn) corner becomes a vertex, \
         out of core in slabs of its '{what}' table; at most {MAX_BUCKETS} slabs are open at once, which needs --mem of at \
         least {} MiB here (it is {} MiB)",
        path.display(),
        need.div_ceil(1 << 20),
        budget >> 20
    ))
}

fn read_at(path: &Path, offset: u64, len: usize) -> Result<Vec<u8>> {
    let mut f = File::open(path).ctx(path, "open scratch file")?;
    f.seek(SeekFrom::Start(offset)).ctx(path, "seek scratch file")?;
    let mut b = vec![0u8; len];
    f.read_exact(&mut b).ctx(path, "read scratch file")?;
    Ok(b)
}

/// Phase 1's target: the tables and the kept triangles' corners, spooled.
pub(super) struct Spool {
    dir: ScratchDir,
    budget: u64,
    positions: u64,
    pos: Table,
    tex: Option<Table>,
    nor: Option<Table>,
    per_slab: u64,
    corners: BucketFiles,
    triangles: u64,
    /// Faces, polygons and degenerate triangles counted by the body pass.
    stats: BodyStats,
    /// The material of the corners pushed next (the face's: the body pass
    /// sets it before each corner).
    pub material: u16,
}

impl Spool {
    /// A spool in a scratch directory inside `scratch` for the file `input`
    /// of `positions` `v`, `texcoords` `vt` (0: no uv) and `normals` `vn`
    /// (0: no normal) lines; `uv` / `normal`: whether faces reference them.
    pub fn new(input: &Path, scratch: &Path, counts: [u64; 3], uv: bool, normal: bool, mem: u64) -> Result<Spool> {
        let budget = mem.max(1 << 16);
        let [positions, texcoords, normals] = counts;
        let per_slab = (budget / 8 / PREC as u64).max(1);
        if positions.div_ceil(per_slab) > MAX_BUCKETS {
            return Err(too_small(input, "v", positions * PREC as u64 * 8 / MAX_BUCKETS, budget));
        }
        let dir = crate::io::scratch_in(scratch)?;
        let pos = Table::new(dir.path(), "v", PREC, positions, budget, input)?;
        let tex = if uv { Some(Table::new(dir.path(), "vt", 8, texcoords, budget, input)?) } else { None };
        let nor = if normal { Some(Table::new(dir.path(), "vn", 12, normals, budget, input)?) } else { None };
        let n_slabs = positions.div_ceil(per_slab).max(1) as usize;
        let corners = BucketFiles::create(dir.path(), "corners", n_slabs, CREC, (budget / 4) as usize)?;
        Ok(Spool { dir, budget, positions, pos, tex, nor, per_slab, corners, triangles: 0, stats: BodyStats::default(), material: 0 })
    }

    pub fn position(&mut self, v: &Vertex) -> Result<()> {
        let mut b = [0u8; PREC];
        for (k, c) in v.pos.iter().enumerate() {
            b[8 * k..8 * k + 8].copy_from_slice(&c.to_le_bytes());
        }
        b[24..].copy_from_slice(&v.color);
        self.pos.push(&b)
    }

    pub fn texcoord(&mut self, uv: [f32; 2]) -> Result<()> {
        let t = self.tex.as_mut().expect("uv table when faces reference vt");
        t.push(&[uv[0].to_le_bytes(), uv[1].to_le_bytes()].concat())
    }

    pub fn normal(&mut self, n: [f32; 3]) -> Result<()> {
        let t = self.nor.as_mut().expect("normal table when faces reference vn");
        t.push(&[n[0].to_le_bytes(), n[1].to_le_bytes(), n[2].to_le_bytes()].concat())
    }

    /// Phases 2–4: the vertices, then the triangles, to `out`.
    pub fn finish(mut self, out: &mut Out) -> Result<()> {
        self.pos.close()?;
        for t in [&mut self.tex, &mut self.nor].into_iter().flatten() {
            t.close()?;
        }
        let Spool { dir, budget, positions, pos, tex, nor, per_slab, corners, triangles, stats, .. } = self;
        let dir = dir.path();
        let b = budget as usize;
        let buckets = corners.finish()?;
        let mut slots = SlotBuckets::new(dir, "slots", 3 * triangles, 8, b / 2, b / 8)?;
        let tex = tex.map(|t| Attr::new(dir, t, b)).transpose()?;
        let nor = nor.map(|t| Attr::new(dir, t, b)).transpose()?;
        let mut attrs = [tex, nor];

        // Phase 2: number the distinct corners, slab by slab.
        let vpath = dir.join("vertices.bin");
        let mut vfile = BufWriter::with_capacity(SEQ_BUF, File::create(&vpath).ctx(&vpath, "create scratch file")?);
        let mut map: FxHashMap<[u32; 4], u64> = FxHashMap::default();
        let mut chunk = vec![0u8; (SEQ_BUF / CREC) * CREC];
        let mut next = 0u64;
        for (s, (path, count)) in buckets.iter().enumerate() {
            let first = s as u64 * per_slab;
            let n = per_slab.min(positions - first.min(positions));
            let slab = pos.slab(first, n)?;
            for (lo, hi) in sub_ranges(path, *count, first, n, budget / 4 / CORNER_BYTES, &mut chunk)? {
                map.clear();
                read_records(path, CREC, *count, &mut chunk, |r| {
                    let key = [0, 1, 2, 5].map(|k| match k {
                        5 => u16::from_le_bytes([r[20], r[21]]) as u32,
                        _ => u32::from_le_bytes(r[4 * k..4 * k + 4].try_into().unwrap()),
                    });
                    if (key[0] as u64) < lo || key[0] as u64 >= hi {
                        return Ok(());
                    }
                    let slot = u64::from_le_bytes(r[12..20].try_into().unwrap());
                    let id = match map.get(&key) {
                        Some(&id) => id,
                        None => {
                            let id = next;
                            next += 1;
                            map.insert(key, id);
                            let mut v = [0u8; VREC];
                            let at = (key[0] as u64 - first) as usize * PREC;
                            v[..PREC].copy_from_slice(&slab[at..at + PREC]);
                            v[48..50].copy_from_slice(&(key[3] as u16).to_le_bytes());
                            for (a, (k, off)) in attrs.iter_mut().zip([(key[1], PREC), (key[2], PREC + 8)]) {
                                if let Some(a) = a {
                                    a.lookup(id, k, &mut v[off..off + a.table.elem])?;
                                }
                            }
                            vfile.write_all(&v).ctx(&vpath, "write scratch file")?;
                            id
                        }
                    };
                    slots.push(slot, &id.to_le_bytes())
                })?;
                crate::io::signal::check()?;
            }
            let _ = std::fs::remove_file(path);
        }
        drop((map, chunk));
        vfile.into_inner().map_err(|e| e.into_error()).ctx(&vpath, "write scratch file")?;

        // Phase 3: join the requested tables.
        let mut joined = Vec::new();
        for (a, off) in attrs.into_iter().zip([PREC, PREC + 8]) {
            if let Some(a) = a.filter(|a| a.requests.is_some()) {
                let e = a.table.elem;
                let p = a.join(dir, next, b)?;
                joined.push((BufReader::with_capacity(SEQ_BUF, File::open(&p).ctx(&p, "open scratch file")?), off, e, p));
            }
        }

        crate::mem::trim();
        // Phase 4: vertices in order, then triangles in slot order.
        let mut vread = BufReader::with_capacity(SEQ_BUF, File::open(&vpath).ctx(&vpath, "open scratch file")?);
        let mut rec = [0u8; VREC];
        for _ in 0..next {
            vread.read_exact(&mut rec).ctx(&vpath, "read scratch file")?;
            for (r, off, e, p) in joined.iter_mut() {
                r.read_exact(&mut rec[*off..*off + *e]).ctx(p, "read scratch file")?;
            }
            out.vertex(decode(&rec))?;
        }
        out.flush_vertices()?;
        drop((vread, joined));
        slots.finish(|ids| {
            for t in ids.chunks_exact(24) {
                out.push_triangle([0, 1, 2].map(|c| u64::from_le_bytes(t[8 * c..8 * c + 8].try_into().unwrap())))?;
            }
            Ok(())
        })?;
        out.stats.faces += stats.faces;
        out.stats.polygons += stats.polygons;
        out.stats.degenerate += stats.degenerate;
        Ok(())
    }
}

/// The `v` ranges `[lo, hi)` of a slab (`first..first + n`) whose corners
/// fit `entries` map entries: the whole slab when its records do, else
/// ranges cut by a count of the records per `v`.
fn sub_ranges(path: &Path, count: u64, first: u64, n: u64, entries: u64, chunk: &mut [u8]) -> Result<Vec<(u64, u64)>> {
    if count <= entries.max(1) {
        return Ok(vec![(first, first + n)]);
    }
    let mut per_v = vec![0u64; n as usize];
    read_records(path, CREC, count, chunk, |r| {
        per_v[(u32::from_le_bytes(r[..4].try_into().unwrap()) as u64 - first) as usize] += 1;
        Ok(())
    })?;
    let mut ranges = Vec::new();
    let (mut lo, mut acc) = (first, 0u64);
    for (k, &c) in per_v.iter().enumerate() {
        let v = first + k as u64;
        if acc > 0 && acc + c > entries {
            ranges.push((lo, v));
            (lo, acc) = (v, 0);
        }
        acc += c;
    }
    ranges.push((lo, first + n));
    Ok(ranges)
}

fn decode(r: &[u8; VREC]) -> Vertex {
    let f64_at = |o: usize| f64::from_le_bytes(r[o..o + 8].try_into().unwrap());
    let f32_at = |o: usize| f32::from_le_bytes(r[o..o + 4].try_into().unwrap());
    Vertex {
        pos: [f64_at(0), f64_at(8), f64_at(16)],
        color: r[24..28].try_into().unwrap(),
        uv: [f32_at(28), f32_at(32)],
        normal: [f32_at(36), f32_at(40), f32_at(44)],
        material: u16::from_le_bytes([r[48], r[49]]),
    }
}

/// A `vt` or `vn` table in phase 2: in memory, or requested by slab.
struct Attr {
    table: Table,
    values: Option<Vec<u8>>,
    requests: Option<BucketFiles>,
}

impl Attr {
    fn new(dir: &Path, table: Table, budget: usize) -> Result<Attr> {
        if table.in_memory {
            let values = Some(table.slab(0, table.len)?);
            return Ok(Attr { table, values, requests: None });
        }
        let name = format!("{}-requests", table.path.file_stem().and_then(|s| s.to_str()).unwrap_or("table"));
        let requests = Some(BucketFiles::create(dir, &name, table.buckets(), RREC, budget / 16)?);
        Ok(Attr { table, values: None, requests })
    }

    /// Vertex `id`'s value of index `i` into `out` (zero when absent), or
    /// its request.
    fn lookup(&mut self, id: u64, i: u32, out: &mut [u8]) -> Result<()> {
        let e = self.table.elem;
        if let Some(v) = &self.values {
            if i != NONE {
                out.copy_from_slice(&v[i as usize * e..(i as usize + 1) * e]);
            }
            return Ok(());
        }
        let b = self.table.bucket(i);
        let r = self.requests.as_mut().expect("requests when not in memory").record(b)?;
        r[..8].copy_from_slice(&id.to_le_bytes());
        r[8..].copy_from_slice(&i.to_le_bytes());
        Ok(())
    }

    /// Phase 3 for a requested table: every vertex's value, in vertex
    /// order, into a file.
    fn join(self, dir: &Path, vertices: u64, budget: usize) -> Result<PathBuf> {
        let e = self.table.elem;
        let name = self.table.path.file_stem().and_then(|s| s.to_str()).unwrap_or("table").to_string();
        let out_path = dir.join(format!("{name}-joined.bin"));
        let mut out = BufWriter::with_capacity(SEQ_BUF, File::create(&out_path).ctx(&out_path, "create scratch file")?);
        let req = self.requests.expect("joined only when requested");
        let mut placed = SlotBuckets::new(dir, &format!("{name}-placed"), vertices, e, budget / 2, budget / 8)?;
        let mut chunk = vec![0u8; (SEQ_BUF / RREC) * RREC];
        let zero = vec![0u8; e];
        for (b, (path, count)) in req.finish()?.iter().enumerate() {
            let first = b as u64 * self.table.per;
            let n = self.table.per.min(self.table.len - first.min(self.table.len));
            let slab = self.table.slab(first, n)?;
            read_records(path, RREC, *count, &mut chunk, |r| {
                let id = u64::from_le_bytes(r[..8].try_into().unwrap());
                let i = u32::from_le_bytes(r[8..12].try_into().unwrap());
                let v = if i == NONE { &zero[..] } else { &slab[(i as u64 - first) as usize * e..][..e] };
                placed.push(id, v)
            })?;
            let _ = std::fs::remove_file(path);
            crate::io::signal::check()?;
        }
        placed.finish(|b| out.write_all(b).ctx(&out_path, "write scratch file"))?;
        out.into_inner().map_err(|e| e.into_error()).ctx(&out_path, "write scratch file")?;
        Ok(out_path)
    }
}

impl Tris for Spool {
    #[inline]
    fn triangle(&mut self, t: [u64; 3], p: [u64; 3]) -> Result<()> {
        if p[0] == p[1] || p[1] == p[2] || p[0] == p[2] {
            self.stats.degenerate += 1;
            return Ok(());
        }
        let slot0 = 3 * self.triangles;
        for c in 0..3 {
            let v = p[c];
            let r = self.corners.record((v / self.per_slab) as usize)?;
            r[..4].copy_from_slice(&(v as u32).to_le_bytes());
            r[4..8].copy_from_slice(&((t[c] >> 32) as u32).to_le_bytes());
            r[8..12].copy_from_slice(&(t[c] as u32).to_le_bytes());
            r[12..20].copy_from_slice(&(slot0 + c as u64).to_le_bytes());
            r[20..22].copy_from_slice(&self.material.to_le_bytes());
        }
        self.triangles += 1;
        Ok(())
    }

    fn stats(&mut self) -> &mut BodyStats {
        &mut self.stats
    }
}

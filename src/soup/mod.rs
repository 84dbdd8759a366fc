//! Soup stage: indexed PLY → triangle soup under a fixed memory budget.
//!
//! Takes: a PLY path, an output path and a budget (`--mem`). Gives: a `.soup`
//! file ([`format`](mod@format)) whose records are the input's triangles in face order
//! (polygons fan-triangulated, degenerate triangles dropped and counted),
//! each corner carrying exactly the input's attributes, plus a [`SoupReport`].
//!
//! Two paths, same output byte for byte: **in memory** (one pass, faces
//! dereferenced on the fly) when the vertex table fits in ¾ of the budget and
//! vertices precede faces; **external** otherwise, in three phases:
//! 1. one pass over the PLY: vertices to a packed vertex file, each corner
//!    to the bucket file of its vertex's *slab* (a consecutive index range);
//! 2. slab by slab: the slab's vertices in memory, its corners dereferenced
//!    there and distributed to bucket files by slot range (slot = 3·triangle + corner);
//! 3. each slot range placed in memory and written out as triangles, in order.
//!
//! Phases 1 and 2 each run on two threads (`io::relay`): one
//! reads (the PLY; a slab's corners) and hands batches to the other, which
//! codes them into their bucket files in order.
//!
//! Invariants of the external path: the disk is only read and written in
//! sequence; no record is ever compared or merged (corners are distributed by
//! dense keys, never sorted); the only random access (corner → vertex) is in
//! RAM; each phase holds within the budget.
//!
//! A [`SoupTap`] sees the external path's corners (phase 2) and triangles
//! (phase 3) and holds its [`SoupTap::reserve`] out of the budget: `build`
//! counts and fills level 0's octree cells this way, and then no soup file is
//! written ([`TapMode::Takes`], [`SoupReport::written`]).
//!
//! Faces' per-wedge uvs and per-face materials (a PLY's `texcoord` and
//! `texnumber`) replace their corners' vertex uvs and materials: on the
//! in-memory path batch by batch; on the external path written in
//! triangle order in phase 1 and patched in, in the same order, in phase 3.
//!
//! The records, the budget split and the tap in detail: `docs/ply-and-soup.md`.

pub mod format;

use crate::error::{Error, IoContext, Location, Result};
use crate::input::{Format, InputHeader};
use crate::io::buckets::{get_varint, put_varint, read_varying, unzigzag, zigzag, BucketFiles, SlotBuckets};
use crate::io::relay::Hand;
use crate::io::SEQ_BUF;
use crate::lod::level::CreaseProbe;
use crate::mesh::{Aabb, Vertex, VertexLayout};
use crate::ply::read::{BodySink, BodyStats};
use crate::progress::Progress;
use format::{SoupHeader, SoupWriter};
use std::fs::File;
use std::io::{BufWriter, Read, Write};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Options for [`build_soup`].
#[derive(Clone, Debug)]
pub struct SoupOptions {
    /// Working-memory budget in bytes.
    pub mem: u64,
    pub quiet: bool,
    /// Take the external path even when the input fits (tests, benchmarks).
    pub force_external: bool,
    /// Replace an existing soup at the output path (`--force`).
    pub replace: bool,
    /// The soup is the caller's scratch (`build`'s, removed once the levels
    /// are built): not synced to disk when it is complete.
    pub scratch: bool,
}

impl Default for SoupOptions {
    fn default() -> Self {
        SoupOptions { mem: crate::mem::DEFAULT_BUDGET, quiet: true, force_external: false, replace: false, scratch: false }
    }
}

/// What a soup build did.
#[derive(Clone, Debug)]
pub struct SoupReport {
    pub header: SoupHeader,
    pub body: BodyStats,
    pub input_bytes: u64,
    pub external: bool,
    /// Vertex slabs, each with a bucket file of corners (0 on the in-memory path).
    pub vertex_slabs: u64,
    /// Bytes written to the slabs' corner bucket files.
    pub corner_bucket_bytes: u64,
    /// Slot-range bucket files of the distribution by slot (0: placed in memory).
    pub slot_buckets: u64,
    /// Bytes written to slot bucket files.
    pub slot_bucket_bytes: u64,
    /// Seconds in (read PLY + distribute corners by slab, join slabs +
    /// distribute by slot, place + write soup).
    pub phase_seconds: [f64; 3],
    pub seconds: f64,
    /// False when a [`SoupTap`] took phase 3's triangles and no soup file
    /// was written (the header is still the soup's).
    pub written: bool,
    /// With input normals: whether they have no crease, as the vertex pass
    /// saw them (`lod::level::CreaseProbe`); `build` resolves
    /// `--normals auto` from it. `None` without normals.
    pub smooth_normals: Option<bool>,
}

impl SoupReport {
    /// The one-line summary printed at the end of `octolod soup`.
    pub fn summary(&self, peak_rss: Option<u64>) -> String {
        let mb_s = self.input_bytes as f64 / 1e6 / self.seconds.max(1e-9);
        let mt_s = self.body.triangles as f64 / 1e6 / self.seconds.max(1e-9);
        format!(
            "soup: {} faces in, {} triangles out, {} degenerate dropped, {} path, {:.2} s, {:.1} MB/s, {:.2} M tri/s, peak RSS {}",
            self.body.faces,
            self.header.triangles,
            self.header.degenerate,
            if self.external { "external-sort" } else { "in-memory" },
            self.seconds,
            mb_s,
            mt_s,
            peak_rss.map(crate::progress::mib).unwrap_or_else(|| "n/a".into())
        )
    }
}

/// `octolod soup --json`: one object on stdout, these fields in this order.
/// Rates are per second of the whole run; numbers print at full precision.
#[derive(Clone, Debug, serde::Serialize)]
pub struct SoupJson {
    /// Faces read from the PLY (polygons count once).
    pub faces: u64,
    /// Triangles written to the soup.
    pub triangles: u64,
    /// Degenerate triangles dropped.
    pub degenerate: u64,
    /// Faces with more than three corners (fan-triangulated).
    pub polygons: u64,
    /// Vertices read from the PLY.
    pub vertices: u64,
    /// Size of the input PLY in bytes.
    pub input_bytes: u64,
    /// True when the external path ran.
    pub external: bool,
    /// Wall-clock seconds of the whole soup build.
    pub seconds: f64,
    /// Input megabytes (10^6) per second.
    pub mb_per_s: f64,
    /// Million input triangles per second.
    pub mtris_per_s: f64,
    /// Peak RSS of the process in bytes (0 where the OS does not tell).
    pub peak_rss_bytes: u64,
    /// The `--mem` budget in bytes.
    pub mem_budget_bytes: u64,
    /// Vertex slabs of the external path (0 on the in-memory path).
    pub vertex_slabs: u64,
    /// Slot-range bucket files of the distribution by slot.
    pub slot_buckets: u64,
    /// Scratch bytes written: corner and slot bucket files (not the vertex file).
    pub spilled_bytes: u64,
    /// Seconds in (read PLY + distribute corners by slab, join slabs +
    /// distribute by slot, place + write soup).
    pub phase_seconds: [f64; 3],
}

impl SoupReport {
    /// The `--json` report of a run under budget `mem`, given the peak RSS.
    pub fn json(&self, mem: u64, peak_rss: Option<u64>) -> SoupJson {
        let secs = self.seconds.max(1e-9);
        SoupJson {
            faces: self.body.faces,
            triangles: self.header.triangles,
            degenerate: self.header.degenerate,
            polygons: self.body.polygons,
            vertices: self.body.vertices,
            input_bytes: self.input_bytes,
            external: self.external,
            seconds: self.seconds,
            mb_per_s: self.input_bytes as f64 / 1e6 / secs,
            mtris_per_s: self.body.triangles as f64 / 1e6 / secs,
            peak_rss_bytes: peak_rss.unwrap_or(0),
            mem_budget_bytes: mem,
            vertex_slabs: self.vertex_slabs,
            slot_buckets: self.slot_buckets,
            spilled_bytes: self.corner_bucket_bytes + self.slot_bucket_bytes,
            phase_seconds: self.phase_seconds,
        }
    }
}

/// Sees the soup's corners and triangles on the external path, so `build`
/// partitions level 0 without reading the soup back
/// ([`crate::lod::octree::FirstCount`]): phase 2 shows it each triangle's first
/// corner (with the bounding box of the input's vertices beforehand), phase
/// 3 the triangles in soup order (with the soup's own bounding box
/// beforehand). A tap that takes the triangles ([`TapMode::Takes`]) is
/// the only consumer of phase 3: the soup file is not written at all.
pub trait SoupTap {
    /// Most bytes the tap holds while it sees corners or triangles (taken
    /// from the budget of phases 2 and 3).
    fn reserve(&self) -> u64;
    /// Before phase 2: the bounding box of every vertex the input declares
    /// (referenced or not) and the vertex layout.
    fn begin_corners(&mut self, _vertices: &Aabb, _layout: VertexLayout) {}
    /// Phase 2: the positions of triangles' first corners, in no order.
    fn first_corners(&mut self, _positions: &[[f64; 3]]) {}
    /// Before phase 3's first triangle: the soup's bounding box (its
    /// header's) and vertex layout; says whether the tap takes the triangles.
    fn begin(&mut self, bbox: &Aabb, layout: VertexLayout) -> Result<TapMode>;
    /// Soup records (whole triangles), in soup order.
    fn triangles(&mut self, records: &[u8]) -> Result<()>;
}

/// What a [`SoupTap`] does with phase 3's triangles.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TapMode {
    /// It looks at them; the soup is written as usual.
    Sees,
    /// It consumes them: no soup file is written ([`SoupReport::written`] false).
    Takes,
}

/// Triangles patched with their wedge uvs and materials at a time in phase 3.
const WEDGE_BATCH: usize = 1 << 14;

/// First corners per batch shown to a [`SoupTap`] in phase 2.
const CORNER_BATCH: usize = 1 << 16;

/// I/O buffers held besides the budgeted memory, and the batches between
/// the two threads of phases 1 and 2 (at most `RELAY_DEPTH + 2` of them, a
/// phase-2 record at most 64 bytes: a slot and the largest vertex, 50).
const IO_RESERVE: u64 = 6 * SEQ_BUF as u64 + ((RELAY_DEPTH + 2) * RELAY_CORNERS * 64) as u64;

/// Builds a soup from `input` into `output`; see the module doc.
pub fn build_soup(input: &Path, output: &Path, opts: &SoupOptions) -> Result<SoupReport> {
    build_soup_tapped(input, output, opts, None)
}

/// [`build_soup`], showing the triangles to `tap` as they are written
/// when the external path runs (the in-memory path never begins it).
pub fn build_soup_tapped(input: &Path, output: &Path, opts: &SoupOptions, tap: Option<&mut dyn SoupTap>) -> Result<SoupReport> {
    let t0 = Instant::now();
    if opts.mem < crate::mem::MIN_BUDGET {
        return Err(Error::Usage(format!("--mem must be at least {} bytes", crate::mem::MIN_BUDGET)));
    }
    let _input = crate::io::protect(input);
    crate::io::check_output(output, crate::io::OutputKind::Soup, opts.replace)?;
    let input_bytes = crate::io::open_regular(input, "open")?.1;
    // An OBJ (or ascii STL) is counted in a first pass over the file.
    let scan = Progress::bytes(input_bytes, "scanning", opts.quiet || Format::of(input)? == Format::Ply);
    let header = crate::input::read_header(input, &scan)?;
    scan.finish();
    check_has_faces(input, &header)?;
    let layout = VertexLayout::new(header.attrs);
    let vertex_table = header.vertex_count().saturating_mul(layout.size as u64);
    let vertices_first = header.vertices_first;
    let in_memory = !opts.force_external && vertices_first && vertex_table <= opts.mem / 4 * 3;
    let progress = Progress::bytes(input_bytes, "reading", opts.quiet);
    let mut report =
        if in_memory { build_in_memory(input, output, &header, opts, &progress)? } else { build_external(input, output, &header, opts, &progress, tap)? };
    progress.finish();
    report.input_bytes = input_bytes;
    report.seconds = t0.elapsed().as_secs_f64();
    Ok(report)
}

fn check_has_faces(input: &Path, header: &InputHeader) -> Result<()> {
    if header.face_count() == 0 {
        let loc = Location { file: input.to_path_buf(), element: Some("face".into()), offset: Some(header.body_offset), ..Default::default() };
        return Err(Error::input(loc, "the file declares no faces: nothing to turn into a triangle soup"));
    }
    Ok(())
}

fn no_triangles_error(input: &Path, header: &InputHeader, body: &BodyStats) -> Error {
    let loc = Location { file: input.to_path_buf(), element: Some("face".into()), ..Default::default() };
    Error::input(loc, format!("all {} faces are degenerate (repeated vertex indices): no triangle left", header.face_count().max(body.faces)))
}

// ------------------------------------------------------------------ in memory

struct InMemorySink<'a> {
    table: Vec<u8>,
    layout: VertexLayout,
    soup: &'a mut SoupWriter,
    rec: Vec<u8>,
    /// Per-wedge uvs of the next triangle batch.
    wedges: Vec<[[f32; 2]; 3]>,
    /// Per-triangle materials of the next triangle batch.
    mats: Vec<u16>,
    /// With normals: their creases.
    probe: Option<CreaseProbe>,
}

impl BodySink for InMemorySink<'_> {
    fn vertices(&mut self, first: u64, batch: &[Vertex]) -> Result<()> {
        probe_all(&mut self.probe, batch);
        let s = self.layout.size;
        debug_assert_eq!(self.table.len(), first as usize * s);
        let at = self.table.len();
        self.table.resize(at + batch.len() * s, 0);
        for (k, v) in batch.iter().enumerate() {
            self.layout.encode(v, &mut self.table[at + k * s..]);
        }
        Ok(())
    }
    fn triangles(&mut self, batch: &[[u64; 3]]) -> Result<()> {
        let s = self.layout.size;
        let wedges = std::mem::take(&mut self.wedges);
        let mats = std::mem::take(&mut self.mats);
        for (k, t) in batch.iter().enumerate() {
            for (c, &v) in t.iter().enumerate() {
                let i = v as usize * s;
                self.rec[c * s..(c + 1) * s].copy_from_slice(&self.table[i..i + s]);
                if let Some(w) = wedges.get(k).filter(|w| !w[c][0].is_nan()) {
                    self.layout.set_uv(&mut self.rec[c * s..], w[c]);
                }
                if let Some(&m) = mats.get(k) {
                    set_material(&self.layout, &mut self.rec[c * s..(c + 1) * s], m);
                }
            }
            self.soup.push_encoded(&self.rec)?;
        }
        Ok(())
    }
    fn wedge_uvs(&mut self, batch: &[[[f32; 2]; 3]]) -> Result<()> {
        self.wedges.clear();
        self.wedges.extend_from_slice(batch);
        Ok(())
    }
    fn materials(&mut self, batch: &[u16]) -> Result<()> {
        self.mats.clear();
        self.mats.extend_from_slice(batch);
        Ok(())
    }
}

/// Shows a batch of vertices to the crease probe, where there is one.
fn probe_all(probe: &mut Option<CreaseProbe>, batch: &[Vertex]) {
    if let Some(p) = probe {
        p.add_all(batch);
    }
}

/// Sets the material of one encoded vertex `rec` (the layout's last two
/// bytes, little endian; see [`VertexLayout`]).
fn set_material(layout: &VertexLayout, rec: &mut [u8], m: u16) {
    debug_assert!(layout.attrs.material());
    rec[layout.size - 2..layout.size].copy_from_slice(&m.to_le_bytes());
}

fn build_in_memory(input: &Path, output: &Path, header: &InputHeader, opts: &SoupOptions, progress: &Progress) -> Result<SoupReport> {
    let layout = VertexLayout::new(header.attrs);
    let mut soup = SoupWriter::create(output, header.attrs, opts.replace, opts.scratch)?;
    let mut sink = InMemorySink {
        table: Vec::with_capacity(header.vertex_count() as usize * layout.size),
        layout,
        soup: &mut soup,
        rec: vec![0; 3 * layout.size],
        wedges: Vec::new(),
        mats: Vec::new(),
        probe: header.attrs.normal().then(CreaseProbe::new),
    };
    // The vertex table takes up to ¾ of the budget (see `build_soup_tapped`); the reader holds the rest.
    let scratch = crate::io::parent_dir(output);
    let body = crate::input::read_body(input, header, opts.mem / 4, &scratch, &mut sink, progress)?;
    let smooth_normals = sink.probe.take().map(|p| p.smooth());
    drop(sink);
    if body.triangles == 0 {
        return Err(no_triangles_error(input, header, &body));
    }
    let h = soup.commit(body.vertices, body.faces, body.degenerate)?;
    Ok(SoupReport {
        header: h,
        body,
        input_bytes: 0,
        external: false,
        vertex_slabs: 0,
        corner_bucket_bytes: 0,
        slot_buckets: 0,
        slot_bucket_bytes: 0,
        phase_seconds: [0.0; 3],
        seconds: 0.0,
        written: true,
        smooth_normals,
    })
}

// ------------------------------------------------------------------- external

/// A corner record of the external path, in its slab's bucket: the
/// vertex's index within its slab, as the zigzag varint of its difference
/// from the bucket's previous record's, then the slot's difference from
/// the previous slot (slots only grow within a bucket), a varint. On the
/// scans and terrains we read a triangle's vertices are near the previous
/// triangle's, so a record takes 2-4 bytes; fixed records took 8 (a u32
/// index, a u32 slot) or 12 (u64 slots), and phases 1 and 2 are bound by
/// the bytes they write and read back (the kernel's copy into the page
/// cache was a whole core while the caller used half of one).
const MAX_CORNER_REC: usize = 5 + 10;

/// Writes corner (`local`, `slot`) after `prev` into `out`; gives its length.
#[inline]
fn put_corner(out: &mut [u8], prev: &mut (u32, u64), local: u32, slot: u64) -> usize {
    let d = local as i64 - prev.0 as i64;
    let n = put_varint(out, zigzag(d));
    let n = n + put_varint(&mut out[n..], slot - prev.1);
    *prev = (local, slot);
    n
}

/// The corner record at the start of `b` after `prev` (see [`put_corner`]):
/// (local, slot) and its length; None for a record cut short.
#[inline]
fn get_corner(b: &[u8], prev: &mut (u32, u64)) -> Option<(u32, u64, usize)> {
    let (z, n) = get_varint(b)?;
    let (ds, m) = get_varint(&b[n..])?;
    let local = (prev.0 as i64 + unzigzag(z)) as u32;
    let slot = prev.1.checked_add(ds)?;
    *prev = (local, slot);
    Some((local, slot, n + m))
}

/// Phase 1's sink on the reading thread: vertices to the vertex file (and
/// wedge uvs, materials to theirs); triangles handed in batches of
/// [`RELAY_TRIS`] to the [`CornerBuckets`] on another thread.
struct ExternalSink<'a> {
    layout: VertexLayout,
    vfile: BufWriter<File>,
    vpath: &'a Path,
    vbuf: Vec<u8>,
    hand: Hand<Vec<[u64; 3]>>,
    /// The bounding box of every vertex (as encoded), for a tap.
    bbox: Aabb,
    /// Per-wedge uvs in triangle order (faces with a `texcoord` list):
    /// written in sequence, applied in sequence by phase 3.
    wedges: Option<BufWriter<File>>,
    wpath: PathBuf,
    /// Per-triangle materials (u16) in triangle order, likewise.
    mats: Option<BufWriter<File>>,
    mpath: PathBuf,
    /// With normals: their creases.
    probe: Option<CreaseProbe>,
}

/// Triangles a phase-1 batch hands over (192 KB; a phase-2 batch of as
/// many corners is larger).
const RELAY_TRIS: usize = 8192;
/// Corners a phase-2 batch hands over (each its slot and vertex bytes).
const RELAY_CORNERS: usize = 8192;
/// Batches queued between the two threads of phases 1 and 2 (at most
/// two more exist: one being filled, one being read).
const RELAY_DEPTH: usize = 2;

/// Phase 1's corner distributor: each triangle's corners to their vertex
/// slab's bucket, in triangle order.
struct CornerBuckets {
    /// Vertices per slab.
    per_slab: u64,
    /// One bucket of corner records per vertex slab, and each bucket's
    /// last record (`put_corner`).
    corners: BucketFiles,
    prev: Vec<(u32, u64)>,
    next_tri: u64,
}

impl CornerBuckets {
    fn add(&mut self, batch: &[[u64; 3]]) -> Result<()> {
        for t in batch {
            let slot0 = self.next_tri * 3;
            for (c, &vi) in t.iter().enumerate() {
                // Indices were checked against the vertex count by the reader.
                let (slab, local) = ((vi / self.per_slab) as usize, (vi % self.per_slab) as u32);
                let r = self.corners.room(slab, MAX_CORNER_REC)?;
                let n = put_corner(r, &mut self.prev[slab], local, slot0 + c as u64);
                self.corners.commit(slab, n);
            }
            self.next_tri += 1;
        }
        Ok(())
    }
}

impl BodySink for ExternalSink<'_> {
    fn wedge_uvs(&mut self, batch: &[[[f32; 2]; 3]]) -> Result<()> {
        if self.wedges.is_none() {
            let f = File::create(&self.wpath).ctx(&self.wpath, "create wedge uv file")?;
            self.wedges = Some(BufWriter::with_capacity(SEQ_BUF, f));
        }
        let w = self.wedges.as_mut().expect("just made");
        let bytes: Vec<u8> = batch.iter().flatten().flatten().flat_map(|x| x.to_le_bytes()).collect();
        w.write_all(&bytes).ctx(&self.wpath, "write wedge uv file")
    }
    fn materials(&mut self, batch: &[u16]) -> Result<()> {
        if self.mats.is_none() {
            let f = File::create(&self.mpath).ctx(&self.mpath, "create material file")?;
            self.mats = Some(BufWriter::with_capacity(SEQ_BUF, f));
        }
        let w = self.mats.as_mut().expect("just made");
        let bytes: Vec<u8> = batch.iter().flat_map(|m| m.to_le_bytes()).collect();
        w.write_all(&bytes).ctx(&self.mpath, "write material file")
    }
    fn vertices(&mut self, _first: u64, batch: &[Vertex]) -> Result<()> {
        probe_all(&mut self.probe, batch);
        let s = self.layout.size;
        self.vbuf.resize(batch.len() * s, 0);
        for (k, v) in batch.iter().enumerate() {
            self.layout.encode(v, &mut self.vbuf[k * s..]);
            self.bbox.add(self.layout.position(&self.vbuf[k * s..]));
        }
        self.vfile.write_all(&self.vbuf).ctx(self.vpath, "write vertex file")
    }
    fn triangles(&mut self, batch: &[[u64; 3]]) -> Result<()> {
        for part in batch.chunks(RELAY_TRIS) {
            let mut b = self.hand.spare().unwrap_or_else(|| Vec::with_capacity(RELAY_TRIS));
            b.clear();
            b.extend_from_slice(part);
            self.hand.send(b)?;
        }
        Ok(())
    }
}

/// The external path: three phases (see the module doc), each a function
/// below, in a scratch directory next to `output`.
fn build_external(
    input: &Path,
    output: &Path,
    header: &InputHeader,
    opts: &SoupOptions,
    progress: &Progress,
    mut tap: Option<&mut dyn SoupTap>,
) -> Result<SoupReport> {
    let scratch = crate::io::scratch_dir(output)?;
    let plan = ExternalPlan::new(header, opts, tap.as_ref().map_or(0, |t| t.reserve()));

    let t0 = Instant::now();
    let slabs = distribute_by_slab(input, header, opts, progress, &plan, scratch.path())?;
    progress.finish();
    let body = slabs.body;
    let smooth_normals = slabs.smooth_normals;

    let t1 = Instant::now();
    crate::mem::trim();
    let joined = join_slabs(&plan, scratch.path(), slabs, opts.quiet, &mut tap)?;

    let t2 = Instant::now();
    crate::mem::trim();
    let corner_bucket_bytes = joined.corner_bucket_bytes;
    let written = write_slots(output, opts, plan.layout, &body, joined, &mut tap)?;
    let phase_seconds = [(t1 - t0).as_secs_f64(), (t2 - t1).as_secs_f64(), t2.elapsed().as_secs_f64()];
    Ok(SoupReport {
        header: written.header,
        body,
        input_bytes: 0,
        external: true,
        vertex_slabs: plan.n_slabs as u64,
        corner_bucket_bytes,
        slot_buckets: written.slot_buckets,
        slot_bucket_bytes: written.slot_bucket_bytes,
        phase_seconds,
        seconds: 0.0,
        written: written.mode == TapMode::Sees,
        smooth_normals,
    })
}

/// How the external path splits its budget and cuts the vertex indices into slabs.
struct ExternalPlan {
    layout: VertexLayout,
    /// The budget less the I/O buffers.
    budget: usize,
    /// What phases 2 and 3 hold: the budget less what the tap holds beside them.
    held: usize,
    n_vertices: u64,
    /// Vertices per slab: consecutive index ranges whose vertex bytes fit half of `held`.
    per_slab: u64,
    n_slabs: usize,
}

impl ExternalPlan {
    /// `reserve`: what a tap holds beside phases 2 and 3 ([`SoupTap::reserve`]).
    fn new(header: &InputHeader, opts: &SoupOptions, reserve: u64) -> ExternalPlan {
        let layout = VertexLayout::new(header.attrs);
        // --mem is the whole process's: what it holds already (code,
        // libraries, stacks, the reader's buffers) comes off with the I/O
        // buffers. Phase 3's placing fills what is left, and a 2 × 10^7
        // soup at --mem 128M peaked at 133 MiB without this.
        let base = crate::progress::current_rss().unwrap_or(0);
        let budget = opts.mem.saturating_sub(IO_RESERVE + base).max(opts.mem / 2) as usize;
        let held = budget.saturating_sub(reserve as usize).max(budget / 4);
        let n_vertices = header.vertex_count();
        let per_slab = ((held / 2 / layout.size) as u64).clamp(1, u32::MAX as u64);
        let n_slabs = n_vertices.div_ceil(per_slab).max(1) as usize;
        ExternalPlan { layout, budget, held, n_vertices, per_slab, n_slabs }
    }
}

/// What phase 1 leaves for phase 2.
struct SlabCorners {
    body: BodyStats,
    /// The packed vertex file, in index order.
    vpath: PathBuf,
    /// Each slab's bucket file of corner records, and its record count.
    buckets: Vec<(PathBuf, u64)>,
    /// The bounding box of every vertex (as encoded), for a tap.
    vertex_bbox: Aabb,
    /// The per-wedge uv file, when the faces carry uvs.
    wedges: Option<PathBuf>,
    /// The per-triangle material file, when the faces carry materials.
    materials: Option<PathBuf>,
    /// [`SoupReport::smooth_normals`].
    smooth_normals: Option<bool>,
}

/// Phase 1: one pass over the PLY; vertices to the vertex file, corners
/// distributed by vertex slab.
fn distribute_by_slab(input: &Path, header: &InputHeader, opts: &SoupOptions, progress: &Progress, plan: &ExternalPlan, scratch: &Path) -> Result<SlabCorners> {
    let vpath = scratch.join("vertices.bin");
    let vfile = File::create(&vpath).ctx(&vpath, "create vertex file")?;
    let buckets = CornerBuckets {
        per_slab: plan.per_slab,
        corners: BucketFiles::create(scratch, "corners", plan.n_slabs, MAX_CORNER_REC, plan.budget)?,
        prev: vec![(0, 0); plan.n_slabs],
        next_tri: 0,
    };
    // The reader holds what the corner buckets' and the vertex file's buffers leave.
    let reader_mem = opts.mem.saturating_sub(buckets.corners.buffer_bytes() + SEQ_BUF as u64);
    // This thread reads and parses; the corners are coded into their
    // buckets on another (each was about half of phase 1).
    let (read, buckets) = crate::io::relay::relay(
        RELAY_DEPTH,
        |hand| {
            let mut sink = ExternalSink {
                layout: plan.layout,
                vfile: BufWriter::with_capacity(SEQ_BUF, vfile),
                vpath: &vpath,
                vbuf: Vec::new(),
                hand,
                bbox: Aabb::EMPTY,
                wedges: None,
                wpath: scratch.join("wedges.bin"),
                mats: None,
                mpath: scratch.join("materials.bin"),
                probe: header.attrs.normal().then(CreaseProbe::new),
            };
            let body = crate::input::read_body(input, header, reader_mem, scratch, &mut sink, progress)?;
            // The hand dropped here ends the distributor's input.
            let ExternalSink { vfile, bbox, wedges, wpath, mats, mpath, probe, .. } = sink;
            Ok((body, vfile, bbox, (wedges, wpath), (mats, mpath), probe.map(|p| p.smooth())))
        },
        move |take| {
            let mut buckets = buckets;
            take.each(|b| buckets.add(b))?;
            Ok(buckets)
        },
    )?;
    let (body, vfile, bbox, (wedges, wpath), (mats, mpath), smooth_normals) = read;
    if body.triangles == 0 {
        return Err(no_triangles_error(input, header, &body));
    }
    vfile.into_inner().map_err(|e| e.into_error()).ctx(&vpath, "write vertex file")?;
    let wedges = match wedges {
        Some(w) => {
            w.into_inner().map_err(|e| e.into_error()).ctx(&wpath, "write wedge uv file")?;
            Some(wpath)
        }
        None => None,
    };
    let materials = match mats {
        Some(w) => {
            w.into_inner().map_err(|e| e.into_error()).ctx(&mpath, "write material file")?;
            Some(mpath)
        }
        None => None,
    };
    Ok(SlabCorners { body, buckets: buckets.corners.finish()?, vpath, vertex_bbox: bbox, wedges, materials, smooth_normals })
}

/// What phase 2 leaves for phase 3.
struct Joined {
    /// Every corner's vertex, distributed by slot.
    buckets: SlotBuckets,
    /// The soup's bounding box (its corners'), for the tap.
    bbox: Aabb,
    /// Bytes read back from (and written to) the slabs' corner buckets.
    corner_bucket_bytes: u64,
    /// The per-wedge uv file, when the faces carry uvs.
    wedges: Option<PathBuf>,
    /// The per-triangle material file, when the faces carry materials.
    materials: Option<PathBuf>,
}

/// Phase 2: slab by slab, the slab's vertices in memory (read in sequence
/// from the vertex file), its corners dereferenced and distributed by slot;
/// the tap sees each triangle's first corner.
fn join_slabs(plan: &ExternalPlan, scratch: &Path, slabs: SlabCorners, quiet: bool, tap: &mut Option<&mut dyn SoupTap>) -> Result<Joined> {
    let SlabCorners { body, vpath, buckets: corner_buckets, vertex_bbox, wedges, materials, .. } = slabs;
    let (layout, s, per_slab, n_vertices) = (plan.layout, plan.layout.size, plan.per_slab, plan.n_vertices);
    let n_corners = body.triangles * 3;
    let join_progress = Progress::items(n_corners, "joining", quiet);
    // Phase 3 places a slot range beside what the tap holds.
    let buckets = SlotBuckets::new(scratch, "slots", n_corners, s, plan.held, plan.held / 2)?;
    // This thread reads the slabs and dereferences their corners; another
    // appends them to the slot buckets (each about half of phase 2). A
    // batch holds `RELAY_CORNERS` records: the slot (8 bytes), the vertex.
    let rec = 8 + s;
    let ((corner_bucket_bytes, bbox), buckets) = crate::io::relay::relay(
        RELAY_DEPTH,
        |hand| {
            let mut vfile = File::open(&vpath).ctx(&vpath, "open vertex file")?;
            let mut slab = vec![0u8; per_slab.min(n_vertices) as usize * s];
            let mut chunk = vec![0u8; SEQ_BUF];
            let mut done = 0u64;
            let mut corner_bucket_bytes = 0;
            let mut bbox = Aabb::EMPTY;
            let with_bbox = tap.is_some();
            if let Some(t) = tap.as_mut() {
                t.begin_corners(&vertex_bbox, layout);
            }
            // First corners waiting to be shown to the tap.
            let mut firsts: Vec<[f64; 3]> = Vec::with_capacity(if with_bbox { CORNER_BATCH } else { 0 });
            let mut batch: Vec<u8> = Vec::with_capacity(RELAY_CORNERS * rec);
            // The body may hold fewer vertices than the header's count (an OBJ's
            // corner count is an upper bound on its distinct corners); the slabs
            // past them are empty.
            debug_assert!(body.vertices <= n_vertices);
            for (k, (path, records)) in corner_buckets.into_iter().enumerate() {
                let n = body.vertices.saturating_sub(k as u64 * per_slab).min(per_slab) as usize;
                let slab = &mut slab[..n * s];
                vfile.read_exact(slab).ctx(&vpath, "read vertex file")?;
                let mut prev = (0u32, 0u64);
                let bytes = read_varying(&path, MAX_CORNER_REC, records, &mut chunk, |k, r| {
                    let Some((local, slot, len)) = get_corner(r, &mut prev).filter(|c| (c.0 as usize) < n && c.1 < n_corners) else {
                        let at = Location { file: path.clone(), element: Some("corner record".into()), record: Some(k), ..Default::default() };
                        return Err(Error::input(at, "damaged scratch corner record"));
                    };
                    let local = local as usize;
                    let v = &slab[local * s..(local + 1) * s];
                    if let Some(t) = tap.as_mut() {
                        let p = layout.position(v);
                        bbox.add(p);
                        if slot % 3 == 0 {
                            firsts.push(p);
                            if firsts.len() == CORNER_BATCH {
                                t.first_corners(&firsts);
                                firsts.clear();
                            }
                        }
                    }
                    batch.extend_from_slice(&slot.to_le_bytes());
                    batch.extend_from_slice(v);
                    if batch.len() == RELAY_CORNERS * rec {
                        let next = hand.spare().unwrap_or_else(|| Vec::with_capacity(RELAY_CORNERS * rec));
                        hand.send(std::mem::replace(&mut batch, next))?;
                        batch.clear();
                    }
                    done += 1;
                    if done % 65536 == 0 {
                        join_progress.set(done);
                        crate::io::signal::check()?;
                    }
                    Ok(len)
                })?;
                let _ = std::fs::remove_file(&path);
                corner_bucket_bytes += bytes;
            }
            if !batch.is_empty() {
                hand.send(batch)?;
            }
            debug_assert_eq!(done, n_corners);
            if let Some(t) = tap.as_mut() {
                t.first_corners(&firsts);
            }
            Ok((corner_bucket_bytes, bbox))
        },
        move |take| {
            let mut buckets = buckets;
            take.each(|b| b.chunks_exact(rec).try_for_each(|r| buckets.push(u64::from_le_bytes(r[..8].try_into().expect("8 bytes")), &r[8..])))?;
            Ok(buckets)
        },
    )?;
    let _ = std::fs::remove_file(&vpath);
    join_progress.finish();
    Ok(Joined { buckets, bbox, corner_bucket_bytes, wedges, materials })
}

/// What phase 3 wrote.
struct Written {
    /// The soup's header (also when the tap took the triangles and no file was written).
    header: SoupHeader,
    slot_buckets: u64,
    slot_bucket_bytes: u64,
    mode: TapMode,
}

/// Phase 3: each slot range placed in memory, written as triangles in order
/// to the soup and shown to the tap; no soup file when the tap takes them.
fn write_slots(
    output: &Path,
    opts: &SoupOptions,
    layout: VertexLayout,
    body: &BodyStats,
    joined: Joined,
    tap: &mut Option<&mut dyn SoupTap>,
) -> Result<Written> {
    let Joined { buckets, bbox, wedges, materials, .. } = joined;
    let s = layout.size;
    // Per-wedge uvs and per-triangle materials, read in sequence beside the triangles in order.
    let open = |p: &Option<PathBuf>, what: &'static str| -> Result<_> {
        Ok(match p {
            Some(p) => Some((std::io::BufReader::with_capacity(SEQ_BUF, File::open(p).ctx(p, what)?), p.clone())),
            None => None,
        })
    };
    let mut wedges = open(&wedges, "open wedge uv file")?;
    let mut mats = open(&materials, "open material file")?;
    let mut patched: Vec<u8> = Vec::new();
    let mut uvs = [0u8; 24];
    let mut mat = [0u8; 2];
    let write_progress = Progress::items(body.triangles, "writing", opts.quiet);
    let mode = match tap.as_mut() {
        Some(t) => t.begin(&bbox, layout)?,
        None => TapMode::Sees,
    };
    let mut soup = match mode {
        TapMode::Sees => Some(SoupWriter::create(output, layout.attrs, opts.replace, opts.scratch)?),
        TapMode::Takes => None,
    };
    let mut written = 0u64;
    let slot_buckets = buckets.len();
    let slot_bucket_bytes = buckets.finish(|all| {
        // With wedge uvs or materials, a few thousand triangles at a time are patched.
        let patch = wedges.is_some() || mats.is_some();
        let step = if patch { WEDGE_BATCH * 3 * s } else { all.len().max(1) };
        for tris in all.chunks(step) {
            let tris = if patch {
                patched.clear();
                patched.extend_from_slice(tris);
                for tri in patched.chunks_exact_mut(3 * s) {
                    if let Some((r, p)) = wedges.as_mut() {
                        r.read_exact(&mut uvs).ctx(&*p, "read wedge uv file")?;
                        for c in 0..3 {
                            let f = |k: usize| f32::from_le_bytes(uvs[4 * k..4 * k + 4].try_into().unwrap());
                            if !f(2 * c).is_nan() {
                                layout.set_uv(&mut tri[c * s..], [f(2 * c), f(2 * c + 1)]);
                            }
                        }
                    }
                    if let Some((r, p)) = mats.as_mut() {
                        r.read_exact(&mut mat).ctx(&*p, "read material file")?;
                        for c in 0..3 {
                            set_material(&layout, &mut tri[c * s..(c + 1) * s], u16::from_le_bytes(mat));
                        }
                    }
                }
                &patched[..]
            } else {
                tris
            };
            if let Some(soup) = soup.as_mut() {
                for tri in tris.chunks_exact(3 * s) {
                    soup.push_encoded(tri)?;
                }
            }
            if let Some(t) = tap.as_mut() {
                t.triangles(tris)?;
            }
            written += (tris.len() / (3 * s)) as u64;
        }
        write_progress.set(written);
        crate::io::signal::check()
    })?;
    write_progress.finish();
    debug_assert_eq!(written, body.triangles);
    let header = match soup {
        Some(soup) => soup.commit(body.vertices, body.faces, body.degenerate)?,
        // The header the soup would have had: the same corners' box.
        None => {
            SoupHeader { attrs: layout.attrs, triangles: written, input_vertices: body.vertices, input_faces: body.faces, degenerate: body.degenerate, bbox }
        }
    };
    Ok(Written { header, slot_buckets, slot_bucket_bytes, mode })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn corner_records_round_trip_at_any_index_and_slot() {
        // Indices up and down within a slab, slots past 2^32 (wider than the
        // fixed 4-byte slots were).
        let corners = [(5u32, 0u64), (0, 1), (u32::MAX, 2), (7, 9), (7, 1 << 33), (u32::MAX - 1, (1 << 33) + 3), (0, u64::MAX / 2)];
        let mut buf = vec![0u8; MAX_CORNER_REC * corners.len()];
        let (mut prev, mut at) = ((0, 0), 0);
        for &(l, s) in &corners {
            at += put_corner(&mut buf[at..], &mut prev, l, s);
        }
        let (mut prev, mut off) = ((0, 0), 0);
        for &(l, s) in &corners {
            let (gl, gs, n) = get_corner(&buf[off..at], &mut prev).unwrap();
            assert_eq!((gl, gs), (l, s));
            assert!(n <= MAX_CORNER_REC);
            off += n;
        }
        assert_eq!(off, at);
        // A record cut short is refused, not misread.
        let mut prev = (0, 0);
        let n = put_corner(&mut buf, &mut prev, 1 << 20, 1 << 40);
        assert!(get_corner(&buf[..n - 1], &mut (0, 0)).is_none());
    }
}

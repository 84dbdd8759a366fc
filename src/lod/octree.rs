//! Octree stage: triangle soup → the level-0 partition (the adaptive octree
//! of the input), each leaf's triangles as indexed chunks for the LOD builder.
//!
//! Takes: a `.soup` (or the soup stage's corners and triangles as it makes
//! them: [`FirstCount`]), `--leaf-tris`, `--max-depth`, the memory budget,
//! and the level-0 cube ([`crate::lod::partition::LevelCube`]).
//! Gives: the leaves (a [`Tiling`] of the level-0 cube with, per leaf, its
//! triangle count, bounds and reach), their triangles in a
//! [`ChunkFile`] (indexed, exactly equal corners welded).
//!
//! Invariants:
//! * Every triangle lives in exactly one leaf, chosen by its first corner;
//!   nothing is replicated. The first corner rather than the centroid
//!   because the soup stage knows it in phase 2, before a triangle's corners
//!   meet, so `build` counts and routes inside the soup stage and never
//!   writes the soup; it only makes the reach ([`crate::lod::shared`]) a
//!   little larger.
//! * The leaves are exactly the top-down rule's ("split while a cell holds
//!   more than `leaf_tris` and is shallower than `max_depth`") on the exact
//!   counts, and a leaf reads the same (triangles in soup order, vertices in
//!   first appearance), whatever the budget.
//! * Sequential passes, no sort: **counting** first corners in a
//!   [`Histogram`] that coarsens to fit, cells still too full counted again
//!   alone ([`Histogram::cut`]); **routing** each triangle to its leaf's
//!   buffer, written as chunks when the leaf is complete or the buffers
//!   outgrow their share, welded on reading ([`ChunkFile::gather`]). In
//!   `build` the soup stage does both ([`SoupTap`]) when one count suffices.
//! * Memory: the histogram's share, the buffers' quarter, one batch of the
//!   soup; in the soup stage, taken from phases 2 and 3 ([`SoupTap::reserve`]).
//!
//! Passes, shares and figures: `docs/levels-of-detail.md`, "Level 0: the octree".

use super::chunks::ChunkFile;
use super::partition::{Histogram, LevelCube, Tiling, KEY_DEPTH};
use super::LeafStats;
use crate::error::{Error, Location, Result};
use crate::mesh::{Aabb, VertexLayout};
use crate::progress::Progress;
use crate::soup::format::{SoupHeader, SoupReader};
use crate::soup::{SoupTap, TapMode};
use crate::store::NO_NODE;
use rayon::prelude::*;
use std::path::Path;
use std::path::PathBuf;

#[derive(Clone, Debug)]
pub struct OctreeOptions {
    pub leaf_tris: u64,
    pub max_depth: u8,
    pub mem: u64,
    pub quiet: bool,
}

impl Default for OctreeOptions {
    fn default() -> Self {
        OctreeOptions { leaf_tris: 16384, max_depth: 16, mem: crate::mem::DEFAULT_BUDGET, quiet: true }
    }
}

#[derive(Clone, Debug, Default)]
pub struct OctreeReport {
    pub leaves: u64,
    pub deepest: u8,
    /// Leaves at `max_depth` holding more than `leaf_tris` triangles.
    pub overfull_leaves: u64,
    /// Counting passes over the soup (the routing pass not included; the
    /// first is none when the cells were counted as the soup was written).
    pub counting_passes: u32,
    /// Chunks written (one per leaf unless the buffers outgrew the budget).
    pub chunks: u64,
    pub chunk_bytes: u64,
    pub seconds: f64,
}

/// The level-0 partition.
pub struct Level0 {
    pub header: SoupHeader,
    pub tiling: Tiling,
    pub leaves: Vec<LeafStats>,
    pub chunks: ChunkFile,
    pub report: OctreeReport,
}

/// Depths below the open cells counted per pass (1024 cells per axis).
const COUNT_DEPTHS: u8 = 10;

/// Most triangles per batch read from the soup.
const BATCH: usize = 1 << 16;

/// Calls `f` with each batch of the soup's records and their centroids'
/// keys. A reader thread reads the next batches (two at most) while `f`
/// works on this one.
fn scan(soup: &Path, cube: &LevelCube, batch: usize, progress: &Progress, mut f: impl FnMut(&[u8], &[u64]) -> Result<()>) -> Result<()> {
    let mut reader = SoupReader::open(soup)?;
    let layout = reader.header.layout();
    let rec = reader.header.record_size();
    std::thread::scope(|scope| {
        let (tx, rx) = std::sync::mpsc::sync_channel::<Result<Vec<u8>>>(2);
        scope.spawn(move || loop {
            let mut buf = Vec::new();
            let r = reader.read_batch(&mut buf, batch);
            let end = !matches!(r, Ok(n) if n > 0);
            if !matches!(r, Ok(0)) && tx.send(r.map(|_| buf)).is_err() {
                return; // the consumer stopped
            }
            if end {
                return;
            }
        });
        let mut keys = Vec::new();
        for buf in rx {
            let buf = buf?;
            buf.par_chunks_exact(rec).map(|t| cube.key(anchor(&layout, t))).collect_into_vec(&mut keys);
            f(&buf, &keys)?;
            progress.inc((buf.len() / rec) as u64);
            crate::io::signal::check()?;
        }
        Ok(())
    })
}

/// Adds the full-depth keys `keys` that pass `keep` to `hist`, as sorted
/// runs of (cell, count): few hash-map updates per batch.
fn count_keys(hist: &mut Histogram, keys: &[u64], keep: impl Fn(u64) -> bool + Sync) {
    let sh = 3 * (KEY_DEPTH - hist.depth()) as u32;
    let mut cells: Vec<u64> = keys.iter().filter(|&&k| keep(k)).map(|&k| k >> sh).collect();
    cells.par_sort_unstable();
    let mut runs: Vec<(u64, u64)> = Vec::new();
    for c in cells {
        match runs.last_mut() {
            Some(r) if r.0 == c => r.1 += 1,
            _ => runs.push((c, 1)),
        }
    }
    hist.add_runs(hist.depth(), &runs);
}

/// The first counting pass, done by the soup stage as it makes the soup
/// (a [`SoupTap`]), so the partition does not read the soup once more to
/// count; and, when it is made with [`FirstCount::routing`] and one
/// counting pass is enough, the routing pass too, so `build` never writes
/// the soup at all.
///
/// The cells are counted in phase 2, from each triangle's first corner as
/// it is joined with its vertex, in the cube of the input's vertices; that
/// is the soup's cube unless some vertex no triangle uses lies outside the
/// triangles' box (then phase 3 counts again, in the soup's cube, as it
/// writes the triangles). The counts are the pass's own: a histogram's
/// cells do not depend on the order or batching of its keys.
pub struct FirstCount {
    opts: OctreeOptions,
    /// Where level 0's chunks go when the tap routes the triangles, and
    /// the input, named in errors.
    route: Option<(PathBuf, PathBuf)>,
    state: TapState,
    /// Time spent routing (in phase 3, and finishing).
    busy: std::time::Duration,
}

enum TapState {
    Idle,
    /// Phase 2: first corners counted in the cube of the input's vertices.
    Corners(Counted),
    /// Phase 3: triangles counted as they are written (another cube).
    Triangles(Counted),
    /// Counted for the soup's cube; the partition reads the soup to route.
    Counted(Counted),
    /// Phase 3: triangles routed to their leaves as they are placed.
    Routing {
        cube: LevelCube,
        layout: VertexLayout,
        routing: Box<Routing>,
        keys: Vec<u64>,
    },
}

struct Counted {
    cube: LevelCube,
    layout: VertexLayout,
    hist: Histogram,
    keys: Vec<u64>,
}

impl Counted {
    fn new(cube: LevelCube, layout: VertexLayout, opts: &OctreeOptions) -> Counted {
        Counted { cube, layout, hist: Histogram::new(opts.max_depth.min(COUNT_DEPTHS), count_cap(opts.mem)), keys: Vec::new() }
    }
}

impl FirstCount {
    /// For a partition with `opts` that reads the soup to route; counts
    /// nothing until begun.
    pub fn new(opts: &OctreeOptions) -> FirstCount {
        FirstCount { opts: opts.clone(), route: None, state: TapState::Idle, busy: Default::default() }
    }

    /// For a partition done entirely in the soup stage where it can be:
    /// chunks are written to `chunk_path`; `input` is named in errors.
    pub fn routing(opts: &OctreeOptions, chunk_path: PathBuf, input: &Path) -> FirstCount {
        FirstCount { route: Some((chunk_path, input.to_path_buf())), ..FirstCount::new(opts) }
    }

    /// The level-0 partition, when the tap routed the soup's triangles
    /// (`header`: the soup's, as the soup stage reports it); None when the
    /// partition is still to be made from the soup file.
    pub fn take_level0(&mut self, header: &SoupHeader) -> Result<Option<Level0>> {
        if !matches!(self.state, TapState::Routing { .. }) {
            return Ok(None);
        }
        let TapState::Routing { routing, .. } = std::mem::replace(&mut self.state, TapState::Idle) else { unreachable!() };
        let t0 = std::time::Instant::now();
        let source = self.route.as_ref().map(|r| r.1.clone()).unwrap_or_default();
        let mut l0 = routing.finish(*header, &source)?;
        l0.report.seconds = (self.busy + t0.elapsed()).as_secs_f64();
        Ok(Some(l0))
    }

    /// The counts, if they are for `cube` and `layout`.
    fn counted(self, cube: &LevelCube, layout: &VertexLayout) -> Option<Counted> {
        match self.state {
            TapState::Counted(c) | TapState::Triangles(c) if c.cube == *cube && c.layout.size == layout.size => Some(c),
            _ => None,
        }
    }
}

impl SoupTap for FirstCount {
    fn reserve(&self) -> u64 {
        // The histogram, and a batch's keys and cells (8 bytes a triangle);
        // or the routing's buffers.
        let count = Histogram::max_bytes(count_cap(self.opts.mem)) + 16 * BATCH as u64;
        match self.route {
            Some(_) => count.max(Routing::reserve(self.opts.mem)),
            None => count,
        }
    }

    fn begin_corners(&mut self, vertices: &Aabb, layout: VertexLayout) {
        self.state = TapState::Corners(Counted::new(LevelCube::for_level(vertices, 0), layout, &self.opts));
    }

    fn first_corners(&mut self, positions: &[[f64; 3]]) {
        if let TapState::Corners(c) = &mut self.state {
            let cube = &c.cube;
            positions.par_iter().map(|&p| cube.key(p)).collect_into_vec(&mut c.keys);
            count_keys(&mut c.hist, &c.keys, |_| true);
        }
    }

    fn begin(&mut self, bbox: &Aabb, layout: VertexLayout) -> Result<TapMode> {
        let t0 = std::time::Instant::now();
        let cube = LevelCube::for_level(bbox, 0);
        let state = std::mem::replace(&mut self.state, TapState::Idle);
        let (state, mode) = match state {
            TapState::Corners(c) if c.cube == cube && c.layout.size == layout.size => {
                let mut found = Vec::new();
                let deeper = cut_pass(&c.hist, &[0], 0, &self.opts, &mut found);
                match &self.route {
                    Some((chunk_path, _)) if deeper.is_empty() && check_options(&self.opts).is_ok() => {
                        drop(c);
                        let routing = Routing::new(found, chunk_path.clone(), layout, &self.opts, 0)?;
                        (TapState::Routing { cube, layout, routing: Box::new(routing), keys: Vec::new() }, TapMode::Takes)
                    }
                    _ => (TapState::Counted(c), TapMode::Sees),
                }
            }
            _ => (TapState::Triangles(Counted::new(cube, layout, &self.opts)), TapMode::Sees),
        };
        self.state = state;
        self.busy += t0.elapsed();
        Ok(mode)
    }

    /// Counts or routes soup records (whole triangles), a bounded batch at a time.
    fn triangles(&mut self, records: &[u8]) -> Result<()> {
        let t0 = std::time::Instant::now();
        let batch = |layout: &VertexLayout| (batch_tris(self.opts.mem, 3 * layout.size), 3 * layout.size);
        match &mut self.state {
            TapState::Triangles(c) => {
                let (n, rec) = batch(&c.layout);
                for part in records.chunks(n * rec) {
                    let (cube, layout) = (&c.cube, &c.layout);
                    part.par_chunks_exact(rec).map(|t| cube.key(anchor(layout, t))).collect_into_vec(&mut c.keys);
                    count_keys(&mut c.hist, &c.keys, |_| true);
                }
            }
            TapState::Routing { cube, layout, routing, keys } => {
                let (n, rec) = batch(layout);
                for part in records.chunks(n * rec) {
                    part.par_chunks_exact(rec).map(|t| cube.key(anchor(layout, t))).collect_into_vec(keys);
                    routing.push(part, keys)?;
                }
                self.busy += t0.elapsed();
            }
            _ => {}
        }
        Ok(())
    }
}

/// Triangles per batch of the soup (records of `rec` bytes): within an
/// eighth of budget `mem`.
fn batch_tris(mem: u64, rec: usize) -> usize {
    ((mem / 8) as usize / rec).clamp(16, BATCH)
}

/// Cells a counting histogram may hold under budget `mem`.
fn count_cap(mem: u64) -> usize {
    ((mem / 128) as usize).max(64)
}

fn check_options(opts: &OctreeOptions) -> Result<()> {
    if opts.leaf_tris == 0 {
        return Err(Error::Usage("--leaf-tris must be at least 1".into()));
    }
    if opts.max_depth > KEY_DEPTH {
        return Err(Error::Usage(format!("--max-depth must be at most {KEY_DEPTH}")));
    }
    Ok(())
}

/// Applies the top-down rule to a counting pass over cells `open` (at
/// `open_depth`): leaves go to `found`; gives the cells left at the
/// histogram's depth still holding too many, to count again deeper.
fn cut_pass(hist: &Histogram, open: &[u64], open_depth: u8, opts: &OctreeOptions, found: &mut Vec<(u64, u8, u64)>) -> Vec<u64> {
    let hd = hist.depth();
    let mut deeper = Vec::new();
    for (path, depth, n) in hist.cut(open, open_depth, opts.leaf_tris, opts.max_depth) {
        if depth == hd && depth < opts.max_depth && n > opts.leaf_tris {
            deeper.push(path);
        } else {
            found.push((path, depth, n));
        }
    }
    deeper
}

/// Cuts `soup` into the level-0 leaves; chunks are written to `chunk_path`.
/// `first`: the first counting pass, done as the soup was written (for
/// this cube and these options), or None to read the soup for it.
pub fn build_octree(soup: &Path, chunk_path: std::path::PathBuf, cube: &LevelCube, opts: &OctreeOptions, first: Option<FirstCount>) -> Result<Level0> {
    let t0 = std::time::Instant::now();
    check_options(opts)?;
    let sh = SoupReader::open(soup)?.header;
    let layout = sh.layout();
    let rec = sh.record_size();
    let batch = batch_tris(opts.mem, rec);

    // Pass 1 (and more where needed): count, cut.
    let mut found: Vec<(u64, u8, u64)> = Vec::new();
    // Cells still to cut: groups of sorted paths at one depth, each group
    // small enough that its cells' children fit the histogram's share.
    let cap = count_cap(opts.mem);
    // Counted as the soup was written (for this cube and layout), or not.
    let mut first = first.and_then(|f| f.counted(cube, &layout));
    let mut todo: Vec<(u8, Vec<u64>)> = vec![(0, vec![0])];
    let mut passes = 0u32;
    while let Some((open_depth, mut open)) = todo.pop() {
        if open.len() > cap / 8 {
            let rest = open.split_off(cap / 8);
            todo.push((open_depth, rest));
        }
        // Room for every open cell's eight children: each pass goes deeper.
        let depth = opts.max_depth.min(open_depth + COUNT_DEPTHS);
        let mut hist = Histogram::new(depth, cap);
        hist.reserve(sh.triangles as usize);
        let progress = Progress::items(sh.triangles, "counting", opts.quiet);
        let sh_open = 3 * (KEY_DEPTH - open_depth) as u32;
        let all = open_depth == 0;
        match first.take().filter(|_| all) {
            // Counted as the soup was written.
            Some(c) => hist = c.hist,
            None => {
                passes += 1;
                scan(soup, cube, batch, &progress, |_, keys| {
                    count_keys(&mut hist, keys, |k| all || open.binary_search(&(k >> sh_open)).is_ok());
                    Ok(())
                })?
            }
        }
        progress.finish();
        let deeper = cut_pass(&hist, &open, open_depth, opts, &mut found);
        if !deeper.is_empty() {
            todo.push((hist.depth(), deeper));
        }
    }

    // Pass 2: route each triangle to its leaf's buffer, write chunks.
    let progress = Progress::items(sh.triangles, "partitioning", opts.quiet);
    let mut routing = Routing::new(found, chunk_path, layout, opts, passes)?;
    scan(soup, cube, batch, &progress, |buf, keys| routing.push(buf, keys))?;
    progress.finish();
    let mut l0 = routing.finish(sh, soup)?;
    l0.report.seconds = t0.elapsed().as_secs_f64();
    Ok(l0)
}

/// The routing pass: batches of soup records, with their keys, go to
/// their leaves' buffers; a buffer becomes a chunk when its leaf is
/// complete, or when the buffers outgrow their share (see the module doc).
struct Routing {
    /// The leaves (path, depth, triangles), in key order.
    found: Vec<(u64, u8, u64)>,
    tiling: Tiling,
    /// Triangles per tiling leaf.
    want: Vec<u64>,
    router: Router,
    /// Complete leaves waiting for a few more, to be encoded in parallel.
    pending: Vec<usize>,
    group: usize,
    /// Bytes the buffers may hold.
    budget: usize,
    targets: Vec<u32>,
    counting_passes: u32,
    leaf_tris: u64,
}

impl Routing {
    fn new(mut found: Vec<(u64, u8, u64)>, chunk_path: PathBuf, layout: VertexLayout, opts: &OctreeOptions, counting_passes: u32) -> Result<Routing> {
        let leaf_start = |&(path, depth, _): &(u64, u8, u64)| path << (3 * (KEY_DEPTH - depth) as u32);
        found.sort_unstable_by_key(leaf_start);
        let tiling = Tiling::from_leaves(&found.iter().map(|l| (l.0, l.1)).collect::<Vec<_>>());
        let mut want = vec![0u64; tiling.leaves.len()];
        for l in &found {
            want[tiling.locate(leaf_start(l))] = l.2;
        }
        let n = tiling.leaves.len();
        Ok(Routing {
            found,
            tiling,
            want,
            router: Router {
                bufs: vec![Vec::new(); n],
                got: vec![0; n],
                stats: vec![LeafStats::default(); n],
                buffered: 0,
                chunks: ChunkFile::create(chunk_path, layout, 0)?,
                count: 0,
                layout,
            },
            pending: Vec::new(),
            group: 4 * rayon::current_num_threads().max(1),
            budget: (opts.mem / 4) as usize,
            targets: Vec::new(),
            counting_passes,
            leaf_tris: opts.leaf_tris,
        })
    }

    /// Most bytes it holds under budget `mem`: the buffers' quarter, as
    /// much again while a batch of them is encoded, a batch's targets.
    fn reserve(mem: u64) -> u64 {
        mem / 2 + 4 * BATCH as u64
    }

    /// Routes a batch of records (`keys`: their anchors' keys).
    fn push(&mut self, buf: &[u8], keys: &[u64]) -> Result<()> {
        let rec = 3 * self.router.layout.size;
        let (tiling, router) = (&self.tiling, &mut self.router);
        self.targets.resize(keys.len(), 0);
        self.targets.par_chunks_mut(4096).zip(keys.par_chunks(4096)).for_each(|(t, k)| {
            let mut last = 0;
            for (t, &k) in t.iter_mut().zip(k) {
                *t = tiling.locate_near(k, &mut last) as u32;
            }
        });
        for (&t, tri) in self.targets.iter().zip(buf.chunks_exact(rec)) {
            let t = t as usize;
            let b = &mut router.bufs[t];
            if b.capacity() == 0 {
                // Room for the rest of the leaf at once: grown by doubling,
                // each copy went to fresh pages (a quarter of a build's page
                // faults). Untouched room takes no memory.
                b.reserve_exact((self.want[t] - router.got[t]) as usize * rec);
            }
            b.extend_from_slice(tri);
            router.got[t] += 1;
            if router.got[t] == self.want[t] {
                self.pending.push(t);
            }
        }
        router.buffered += buf.len();
        if self.pending.len() >= self.group {
            router.flush(std::mem::take(&mut self.pending))?;
        }
        let budget = self.budget;
        if router.buffered > budget {
            let mut by_size: Vec<(usize, usize)> = router.bufs.iter().enumerate().filter(|b| !b.1.is_empty()).map(|(t, b)| (b.len(), t)).collect();
            by_size.sort_unstable_by(|a, b| b.cmp(a));
            let mut left = router.buffered;
            let picked = by_size
                .into_iter()
                .take_while(|&(n, _)| {
                    let go = left > budget / 2;
                    left -= n;
                    go
                })
                .map(|x| x.1)
                .collect();
            router.flush(picked)?;
            // Pending leaves written by the spill are done.
            self.pending.retain(|&t| !router.bufs[t].is_empty());
        }
        Ok(())
    }

    /// Writes the last chunks; the partition of the soup with `header`
    /// (`source`: the file named if a leaf missed triangles).
    fn finish(self, header: SoupHeader, source: &Path) -> Result<Level0> {
        let Routing { found, tiling, want, mut router, pending, counting_passes, leaf_tris, .. } = self;
        router.flush(pending)?;
        if router.got != want {
            return Err(Error::input(Location { file: source.to_path_buf(), ..Default::default() }, "the soup changed while it was read"));
        }
        let Router { mut chunks, stats, count, .. } = router;
        chunks.finish(tiling.leaves.len())?;
        let report = OctreeReport {
            leaves: found.len() as u64,
            deepest: found.iter().map(|l| l.1).max().unwrap_or(0),
            overfull_leaves: found.iter().filter(|l| l.2 > leaf_tris).count() as u64,
            counting_passes,
            chunks: count,
            chunk_bytes: chunks.bytes(),
            seconds: 0.0,
        };
        Ok(Level0 { header, tiling, leaves: stats, chunks, report })
    }
}

/// Per-leaf buffers of the routing pass.
struct Router {
    bufs: Vec<Vec<u8>>,
    got: Vec<u64>,
    stats: Vec<LeafStats>,
    /// Bytes held in `bufs`.
    buffered: usize,
    chunks: ChunkFile,
    count: u64,
    layout: VertexLayout,
}

impl Router {
    /// Writes the buffers of leaves `ts` as chunks (encoded in parallel).
    fn flush(&mut self, ts: Vec<usize>) -> Result<()> {
        let parts: Vec<(usize, Vec<u8>)> = ts.into_iter().map(|t| (t, std::mem::take(&mut self.bufs[t]))).collect();
        let (layout, chunks) = (&self.layout, &self.chunks);
        let encoded: Vec<(usize, usize, Vec<u8>, LeafStats)> = parts
            .into_par_iter()
            .map(|(t, data)| {
                let mut bytes = Vec::new();
                chunks.encode_soup(t as u32, NO_NODE, &data, &mut bytes);
                (t, data.len(), bytes, part_stats(layout, &data))
            })
            .collect();
        for (t, n, bytes, st) in encoded {
            self.chunks.append(t as u32, &bytes)?;
            self.buffered -= n;
            self.count += 1;
            let s = &mut self.stats[t];
            s.tris += st.tris;
            s.bounds.merge(&st.bounds);
            s.reach = s.reach.max(st.reach);
        }
        Ok(())
    }
}

/// Count, bounds and reach of soup records.
fn part_stats(layout: &VertexLayout, data: &[u8]) -> LeafStats {
    let mut st = LeafStats::default();
    for t in data.chunks_exact(3 * layout.size) {
        st.add_triangle([0, 1, 2].map(|k| layout.position(&t[k * layout.size..])), anchor(layout, t));
    }
    st
}

/// The point a triangle's leaf is chosen by: its first corner (see the
/// module doc for why not the centroid).
#[inline]
fn anchor(layout: &VertexLayout, t: &[u8]) -> [f64; 3] {
    layout.position(t)
}

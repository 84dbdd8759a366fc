//! Octree stage: triangle soup → the level-0 partition (the adaptive octree
//! of the input), each leaf's triangles as indexed chunks for the LOD builder.
//!
//! Takes: a `.soup`, `--leaf-tris`, `--max-depth`, the memory budget, and
//! the level-0 cube ([`crate::lod::partition::LevelCube`]).
//! Gives: the leaves (a [`Tiling`] of the level-0 cube with, per leaf, its
//! triangle count, bounds and reach), their triangles in a
//! [`ChunkFile`] (indexed, exactly equal corners welded). Every triangle
//! lives in exactly one leaf, chosen by its centroid; nothing is replicated.
//!
//! Out of core, in sequential passes over the soup and no sort:
//! 1. **Counting.** The centroids' Morton keys in the level-0 cube are
//!    counted in a [`Histogram`] ten levels below the cells being cut (at
//!    most `max_depth`), which coarsens itself to fit its memory share
//!    (`--mem` / 128 bytes' worth of cells); the
//!    top-down rule "split while a cell holds more than `leaf_tris` and is
//!    shallower than `max_depth`" is applied to the counts
//!    ([`Histogram::cut`]). Cells left at the histogram's depth still
//!    holding too many are counted again, alone, in another pass at a finer
//!    depth, until none is left (at most `--mem` / 1 KiB cells per pass,
//!    so their children fit the histogram). One pass suffices unless the
//!    input is dense beyond the histogram's depth (the 120 M-triangle sphere under
//!    `--mem 512M`: one). The leaves are exactly the top-down rule's on the
//!    exact counts, whatever the budget. In `build`, the first pass is
//!    done by the soup stage as it writes the soup's triangles on its
//!    external path ([`FirstCount`], a [`SoupTap`]), so large inputs read
//!    the soup once here, to route it (5–6 s less at 120 M triangles).
//! 2. **Routing.** One pass sends each triangle to its leaf's buffer (the
//!    tiling's binary search); a buffer becomes a chunk when its leaf is
//!    complete (its count is known; complete leaves are encoded a few at a
//!    time, in parallel), and when the buffers together outgrow
//!    a quarter of the budget the largest are written as chunks until they
//!    hold an eighth. A leaf is read back by [`ChunkFile::gather`], which
//!    welds its chunks; triangles keep the soup's order within a leaf, and
//!    vertices their first appearance, so a leaf reads the same whatever
//!    the budget.
//!
//! Why not a sort: the external Morton sort this stage used before wrote
//! and read the soup twice more (runs, merge) and compared every key:
//! 46 s of the 120 M-triangle build at `--mem 512M`. Counting needs one
//! read of the soup and a hash map the size of the cells.
//!
//! Memory: the histogram's share, the buffers' quarter (and as much again
//! while a batch of them is encoded), one batch of the soup.

use crate::error::{Error, Location, Result};
use super::chunks::ChunkFile;
use super::partition::{Histogram, LevelCube, Tiling, KEY_DEPTH};
use super::LeafStats;
use crate::mesh::{Aabb, VertexLayout};
use crate::soup::SoupTap;
use crate::progress::Progress;
use crate::soup::format::{SoupHeader, SoupReader};
use crate::store::NO_NODE;
use rayon::prelude::*;
use std::path::Path;

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
            buf.par_chunks_exact(rec).map(|t| cube.key(centroid(&layout, t))).collect_into_vec(&mut keys);
            f(&buf, &keys)?;
            progress.inc((buf.len() / rec) as u64);
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

/// The first counting pass, fed with the soup's triangles by whoever
/// writes them (the soup stage's last phase, once the soup's bounding box
/// is known: a [`SoupTap`]), so the partition does not read the soup once
/// more to count. The counts are the pass's own: a histogram's cells do
/// not depend on the order or batching of its keys.
pub struct FirstCount {
    opts: OctreeOptions,
    counted: Option<Counted>,
}

struct Counted {
    cube: LevelCube,
    layout: VertexLayout,
    hist: Histogram,
    keys: Vec<u64>,
}

impl FirstCount {
    /// For a partition with `opts`; counts nothing until begun.
    pub fn new(opts: &OctreeOptions) -> FirstCount {
        FirstCount { opts: opts.clone(), counted: None }
    }
}

impl SoupTap for FirstCount {
    fn reserve(&self) -> u64 {
        // The histogram, and a batch's keys and cells (8 bytes a triangle).
        Histogram::max_bytes(count_cap(self.opts.mem)) + 16 * BATCH as u64
    }

    fn begin(&mut self, bbox: &Aabb, layout: VertexLayout) {
        let hist = Histogram::new(self.opts.max_depth.min(COUNT_DEPTHS), count_cap(self.opts.mem));
        self.counted = Some(Counted { cube: LevelCube::for_level(bbox, 0), layout, hist, keys: Vec::new() });
    }

    /// Counts soup records (whole triangles), a bounded batch at a time.
    fn triangles(&mut self, records: &[u8]) {
        let Some(c) = self.counted.as_mut() else { return };
        let rec = 3 * c.layout.size;
        for part in records.chunks(batch_tris(self.opts.mem, rec) * rec) {
            let (cube, layout) = (&c.cube, &c.layout);
            part.par_chunks_exact(rec).map(|t| cube.key(centroid(layout, t))).collect_into_vec(&mut c.keys);
            count_keys(&mut c.hist, &c.keys, |_| true);
        }
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

/// Cuts `soup` into the level-0 leaves; chunks are written to `chunk_path`.
/// `first`: the first counting pass, done as the soup was written (for
/// this cube and these options), or None to read the soup for it.
pub fn build_octree(
    soup: &Path,
    chunk_path: std::path::PathBuf,
    cube: &LevelCube,
    opts: &OctreeOptions,
    first: Option<FirstCount>,
) -> Result<Level0> {
    let t0 = std::time::Instant::now();
    if opts.leaf_tris == 0 {
        return Err(Error::Usage("--leaf-tris must be at least 1".into()));
    }
    if opts.max_depth > KEY_DEPTH {
        return Err(Error::Usage(format!("--max-depth must be at most {KEY_DEPTH}")));
    }
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
    let mut first = first.and_then(|f| f.counted).filter(|c| c.cube == *cube && c.layout.size == layout.size);
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
        let hd = hist.depth();
        let mut next = Vec::new();
        for (path, depth, n) in hist.cut(&open, open_depth, opts.leaf_tris, opts.max_depth) {
            if depth == hd && depth < opts.max_depth && n > opts.leaf_tris {
                next.push(path);
            } else {
                found.push((path, depth, n));
            }
        }
        if !next.is_empty() {
            todo.push((hd, next));
        }
    }
    let leaf_start = |&(path, depth, _): &(u64, u8, u64)| path << (3 * (KEY_DEPTH - depth) as u32);
    found.sort_unstable_by_key(leaf_start);
    let tiling = Tiling::from_leaves(&found.iter().map(|l| (l.0, l.1)).collect::<Vec<_>>());
    // Triangles per tiling leaf.
    let mut want = vec![0u64; tiling.leaves.len()];
    for l in &found {
        want[tiling.locate(leaf_start(l))] = l.2;
    }

    // Pass 2: route each triangle to its leaf's buffer, write chunks.
    let progress = Progress::items(sh.triangles, "partitioning", opts.quiet);
    let mut router = Router {
        bufs: vec![Vec::new(); tiling.leaves.len()],
        got: vec![0; tiling.leaves.len()],
        stats: vec![LeafStats::default(); tiling.leaves.len()],
        buffered: 0,
        chunks: ChunkFile::create(chunk_path, layout, 0)?,
        count: 0,
        layout,
    };
    let budget = (opts.mem / 4) as usize;
    // Complete leaves wait for a few more, to be encoded in parallel.
    let mut pending: Vec<usize> = Vec::new();
    let group = 4 * rayon::current_num_threads().max(1);
    scan(soup, cube, batch, &progress, |buf, keys| {
        let mut targets = vec![0u32; keys.len()];
        targets.par_chunks_mut(4096).zip(keys.par_chunks(4096)).for_each(|(t, k)| {
            let mut last = 0;
            for (t, &k) in t.iter_mut().zip(k) {
                *t = tiling.locate_near(k, &mut last) as u32;
            }
        });
        for (&t, tri) in targets.iter().zip(buf.chunks_exact(rec)) {
            let t = t as usize;
            router.bufs[t].extend_from_slice(tri);
            router.got[t] += 1;
            if router.got[t] == want[t] {
                pending.push(t);
            }
        }
        router.buffered += buf.len();
        if pending.len() >= group {
            router.flush(std::mem::take(&mut pending))?;
        }
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
            pending.retain(|&t| !router.bufs[t].is_empty());
        }
        Ok(())
    })?;
    router.flush(pending)?;
    progress.finish();
    if router.got != want {
        return Err(Error::input(Location { file: soup.to_path_buf(), ..Default::default() }, "the soup changed while it was read"));
    }
    let Router { mut chunks, stats, count, .. } = router;
    chunks.finish(tiling.leaves.len())?;
    let report = OctreeReport {
        leaves: found.len() as u64,
        deepest: found.iter().map(|l| l.1).max().unwrap_or(0),
        overfull_leaves: found.iter().filter(|l| l.2 > opts.leaf_tris).count() as u64,
        counting_passes: passes,
        chunks: count,
        chunk_bytes: chunks.bytes(),
        seconds: t0.elapsed().as_secs_f64(),
    };
    Ok(Level0 { header: sh, tiling, leaves: stats, chunks, report })
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
        st.add_triangle([0, 1, 2].map(|k| layout.position(&t[k * layout.size..])), centroid(layout, t));
    }
    st
}

fn centroid(layout: &VertexLayout, t: &[u8]) -> [f64; 3] {
    let mut c = [0.0; 3];
    for k in 0..3 {
        let p = layout.position(&t[k * layout.size..]);
        for a in 0..3 {
            c[a] += p[a] / 3.0;
        }
    }
    c
}


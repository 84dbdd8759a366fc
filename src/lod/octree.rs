//! Octree stage: triangle soup → the level-0 partition (the adaptive octree
//! of the input), each leaf's triangles as one chunk for the LOD builder.
//!
//! Takes: a `.soup`, `--leaf-tris`, `--max-depth`, the memory budget, and
//! the level-0 cube ([`crate::lod::partition::LevelCube`]).
//! Gives: the leaves (a [`Tiling`] of the level-0 cube with, per leaf, its
//! triangle count, bounds and reach), their triangles in a
//! [`ChunkFile`] (one chunk per leaf, indexed, exactly equal corners
//! welded). Every triangle lives in exactly one leaf, chosen by its centroid;
//! nothing is replicated.
//!
//! Out of core in two sequential passes:
//! 1. external sort of the triangles by the Morton code of their centroid
//!    in the level-0 cube — the octree's depth-first order, in which every
//!    node is a contiguous run;
//! 2. one scan that cuts leaves with a lookahead of only `leaf_tris + 1`
//!    triangles: the node that starts at the next triangle is a leaf iff the
//!    triangle `leaf_tris` places ahead is outside it (the node holds at most
//!    `leaf_tris`) or it is at `max_depth`; otherwise it splits, and the same
//!    test runs one level deeper. This is exactly the top-down rule "split
//!    while more than `leaf_tris` and shallower than `max_depth`".
//!
//! Memory: the sort's budget, plus one window of `leaf_tris + 1` triangles
//! and one record per leaf.

use crate::error::{Error, Result};
use crate::extsort::{ExtSorter, SortStats};
use super::chunks::ChunkFile;
use super::partition::{LevelCube, Tiling, KEY_DEPTH};
use super::LeafStats;
use crate::mesh::VertexLayout;
use crate::progress::Progress;
use crate::soup::format::{SoupHeader, SoupReader};
use crate::store::{IndexedMesh, NO_NODE};
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
    pub sort: SortStats,
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

/// Cuts `soup` into the level-0 leaves; chunks are written to `chunk_path`.
pub fn build_octree(
    soup: &Path,
    scratch: &Path,
    chunk_path: std::path::PathBuf,
    cube: &LevelCube,
    opts: &OctreeOptions,
) -> Result<Level0> {
    let t0 = std::time::Instant::now();
    if opts.leaf_tris == 0 {
        return Err(Error::Usage("--leaf-tris must be at least 1".into()));
    }
    if opts.max_depth > KEY_DEPTH {
        return Err(Error::Usage(format!("--max-depth must be at most {KEY_DEPTH}")));
    }
    let mut reader = SoupReader::open(soup)?;
    let sh = reader.header;
    let layout = sh.layout();
    let rec = sh.record_size();

    // Pass 1: sort triangles by the Morton code of their centroid.
    let progress = Progress::items(sh.triangles, "sorting", opts.quiet);
    let mut sorter = ExtSorter::new("morton", 8 + rec, opts.mem as usize, scratch);
    let mut buf = Vec::new();
    loop {
        let n = reader.read_batch(&mut buf, 1 << 16)?;
        if n == 0 {
            break;
        }
        for t in buf.chunks_exact(rec) {
            let key = cube.key(centroid(&layout, t));
            sorter.push_with(|b| {
                b[..8].copy_from_slice(&key.to_le_bytes());
                b[8..].copy_from_slice(t);
            })?;
        }
        progress.inc(n as u64);
    }
    progress.finish();

    // Pass 2: cut leaves, write their chunks.
    let progress = Progress::items(sh.triangles, "partitioning", opts.quiet);
    let mut cutter = Cutter {
        max_depth: opts.max_depth,
        limit: opts.leaf_tris as usize,
        rec,
        keys: Vec::new(),
        khead: 0,
        data: Vec::new(),
        prev: None,
        open: None,
        leaves: Vec::new(),
        chunks: ChunkFile::create(chunk_path, layout, 0)?,
        layout,
        payload: Vec::new(),
        progress: &progress,
        overfull: 0,
    };
    let sort = sorter.finish(|r| cutter.push(u64::from_le_bytes(r[..8].try_into().unwrap()), &r[8..]))?;
    cutter.finish()?;
    progress.finish();
    let Cutter { leaves, mut chunks, overfull, .. } = cutter;
    let tiling = Tiling::from_leaves(&leaves.iter().map(|l| (l.0, l.1)).collect::<Vec<_>>());
    // Stats per tiling leaf (the gaps are empty leaves).
    let mut stats = vec![LeafStats::default(); tiling.leaves.len()];
    let mut given = leaves.iter().peekable();
    let mut remap = Vec::with_capacity(leaves.len());
    for (i, tl) in tiling.leaves.iter().enumerate() {
        if let Some(l) = given.peek() {
            if (l.0, l.1) == (tl.path, tl.depth) {
                stats[i] = l.2.clone();
                remap.push(i as u32);
                given.next();
            }
        }
    }
    chunks.retarget(&remap);
    chunks.finish(tiling.leaves.len())?;
    let report = OctreeReport {
        leaves: leaves.len() as u64,
        deepest: leaves.iter().map(|l| l.1).max().unwrap_or(0),
        overfull_leaves: overfull,
        sort,
        chunk_bytes: chunks.bytes(),
        seconds: t0.elapsed().as_secs_f64(),
    };
    Ok(Level0 { header: sh, tiling, leaves: stats, chunks, report })
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

/// The open leaf (at max depth, possibly longer than the window).
struct OpenLeaf {
    path: u64,
    depth: u8,
    data: Vec<u8>,
}

struct Cutter<'a> {
    max_depth: u8,
    limit: usize,
    rec: usize,
    /// Lookahead window: keys[khead..] and the matching triangle bytes.
    keys: Vec<u64>,
    khead: usize,
    data: Vec<u8>,
    /// Key of the last triangle given to a leaf.
    prev: Option<u64>,
    open: Option<OpenLeaf>,
    /// (path, depth, stats) of the non-empty leaves, in Morton order; chunk
    /// targets are indices into this list until `finish` retargets them.
    leaves: Vec<(u64, u8, LeafStats)>,
    chunks: ChunkFile,
    layout: VertexLayout,
    payload: Vec<u8>,
    progress: &'a Progress,
    overfull: u64,
}

impl Cutter<'_> {
    #[inline]
    fn prefix(&self, key: u64, d: u8) -> u64 {
        key >> (3 * (KEY_DEPTH - d) as u32)
    }

    fn window(&self) -> usize {
        self.keys.len() - self.khead
    }

    fn push(&mut self, key: u64, tri: &[u8]) -> Result<()> {
        let window_empty = self.window() == 0;
        if let Some(open) = &mut self.open {
            if key >> (3 * (KEY_DEPTH - open.depth) as u32) == open.path && window_empty {
                open.data.extend_from_slice(tri);
                self.prev = Some(key);
                return Ok(());
            }
            self.close_open()?;
        }
        self.keys.push(key);
        self.data.extend_from_slice(tri);
        while self.window() > self.limit && self.open.is_none() {
            self.decide()?;
        }
        Ok(())
    }

    fn finish(&mut self) -> Result<()> {
        while self.window() > 0 {
            if self.open.is_some() {
                self.close_open()?;
            }
            self.decide()?;
        }
        self.close_open()
    }

    /// Chooses the leaf that starts at the window's first triangle.
    fn decide(&mut self) -> Result<()> {
        let k0 = self.keys[self.khead];
        let mut d = match self.prev {
            None => 0,
            Some(p) => (0..=self.max_depth).find(|&d| self.prefix(p, d) != self.prefix(k0, d)).unwrap_or(self.max_depth),
        };
        while d < self.max_depth {
            let beyond = self.khead + self.limit;
            if beyond >= self.keys.len() || self.prefix(self.keys[beyond], d) != self.prefix(k0, d) {
                break;
            }
            d += 1;
        }
        let p = self.prefix(k0, d);
        let n = self.keys[self.khead..].iter().take_while(|&&k| self.prefix(k, d) == p).count();
        let bytes = self.data[self.khead * self.rec..(self.khead + n) * self.rec].to_vec();
        self.prev = Some(self.keys[self.khead + n - 1]);
        self.khead += n;
        if self.khead > 4096 && self.khead * 2 > self.keys.len() {
            self.keys.drain(..self.khead);
            self.data.drain(..self.khead * self.rec);
            self.khead = 0;
        }
        self.open = Some(OpenLeaf { path: p, depth: d, data: bytes });
        if d < self.max_depth || self.window() > 0 {
            self.close_open()?;
        }
        Ok(())
    }

    fn close_open(&mut self) -> Result<()> {
        let Some(leaf) = self.open.take() else { return Ok(()) };
        let n = leaf.data.len() / self.rec;
        if n > self.limit {
            self.overfull += 1;
        }
        let mut st = LeafStats::default();
        for t in leaf.data.chunks_exact(self.rec) {
            let c = centroid(&self.layout, t);
            for k in 0..3 {
                let p = self.layout.position(&t[k * self.layout.size..]);
                st.bounds.add(p);
                for a in 0..3 {
                    st.reach = st.reach.max((p[a] - c[a]).abs());
                }
            }
        }
        st.tris = n as u64;
        let mesh = index_triangles(&self.layout, &leaf.data);
        let target = self.leaves.len() as u32;
        self.chunks.encode(target, NO_NODE, &mesh, &[], &vec![false; mesh.vertices.len()], &mut self.payload);
        self.chunks.append(target, &self.payload)?;
        self.leaves.push((leaf.path, leaf.depth, st));
        self.progress.inc(n as u64);
        Ok(())
    }
}

/// Soup triangles → indexed mesh (exactly equal corners share a vertex).
pub fn index_triangles(layout: &VertexLayout, soup: &[u8]) -> IndexedMesh {
    let s = layout.size;
    let mut map: rustc_hash::FxHashMap<&[u8], u32> = rustc_hash::FxHashMap::with_capacity_and_hasher(soup.len() / (3 * s), Default::default());
    let mut mesh = IndexedMesh::default();
    for t in soup.chunks_exact(3 * s) {
        let mut tri = [0u32; 3];
        for c in 0..3 {
            let key = &t[c * s..(c + 1) * s];
            let next = mesh.vertices.len() as u32;
            tri[c] = *map.entry(key).or_insert_with(|| {
                mesh.vertices.push(layout.decode(key));
                next
            });
        }
        mesh.triangles.push(tri);
    }
    mesh
}


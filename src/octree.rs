//! Octree stage: triangle soup → adaptive octree of leaves on disk (level 0).
//!
//! Takes: a `.soup`, `--leaf-tris`, `--max-depth` and the memory budget.
//! Gives: the store's node records (depth-first pre-order, root first) and
//! the level-0 pack file: each leaf's original triangles as one indexed,
//! page-aligned payload. Every triangle lives in exactly one leaf, chosen by
//! its centroid; nothing is replicated.
//!
//! Out of core in two sequential passes:
//! 1. external sort of the triangles by the Morton code of their centroid
//!    (quantised in the root cube at `max_depth` bits per axis) — this is
//!    the octree's depth-first order, and every node is a contiguous run;
//! 2. one scan that cuts leaves with a lookahead of only `leaf_tris + 1`
//!    triangles: the node that starts at the next triangle is a leaf iff the
//!    triangle `leaf_tris` places ahead is outside it (the node holds at most
//!    `leaf_tris`) or it is at `max_depth`; otherwise it splits, and the same
//!    test runs one level deeper. This is exactly the top-down rule "split
//!    while more than `leaf_tris` and shallower than `max_depth`".
//!
//! Memory: the sort's budget, plus one window of `leaf_tris + 1` triangles
//! and the node records (~T / leaf_tris of them).

use crate::error::{Error, Result};
use crate::extsort::{ExtSorter, SortStats};
use crate::mesh::{Aabb, VertexLayout};
use crate::progress::Progress;
use crate::soup::format::{SoupHeader, SoupReader};
use crate::store::{encode_payload, Cube, IndexedMesh, NodeRec, PackWriter, Slot, NO_NODE};
use std::collections::HashMap;
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
        OctreeOptions { leaf_tris: 16384, max_depth: 16, mem: 256 << 20, quiet: true }
    }
}

#[derive(Clone, Debug, Default)]
pub struct OctreeReport {
    pub leaves: u64,
    pub nodes: u64,
    pub deepest: u8,
    /// Leaves at `max_depth` holding more than `leaf_tris` triangles.
    pub overfull_leaves: u64,
    pub sort: SortStats,
    pub pack_bytes: u64,
    pub seconds: f64,
}

/// Builds the octree of `soup` into `dir` (level-0 pack); returns the cube and nodes.
pub fn build_octree(soup: &Path, dir: &Path, opts: &OctreeOptions) -> Result<(SoupHeader, Cube, Vec<NodeRec>, OctreeReport)> {
    let t0 = std::time::Instant::now();
    if opts.leaf_tris == 0 {
        return Err(Error::Usage("--leaf-tris must be at least 1".into()));
    }
    if opts.max_depth > 21 {
        return Err(Error::Usage("--max-depth must be at most 21 (63-bit Morton codes)".into()));
    }
    let mut reader = SoupReader::open(soup)?;
    let sh = reader.header;
    let cube = Cube::around(&sh.bbox, opts.max_depth);
    let layout = sh.layout();
    let rec = sh.record_size();
    let scratch = crate::io::scratch_dir(dir)?;

    // Pass 1: sort triangles by the Morton code of their centroid.
    let progress = Progress::items(sh.triangles, "sorting", opts.quiet);
    let mut sorter = ExtSorter::new("morton", 8 + rec, opts.mem as usize, scratch.path());
    let mut buf = Vec::new();
    loop {
        let n = reader.read_batch(&mut buf, 1 << 16)?;
        if n == 0 {
            break;
        }
        for t in buf.chunks_exact(rec) {
            let mut c = [0.0; 3];
            for k in 0..3 {
                let p = layout.position(&t[k * layout.size..]);
                for a in 0..3 {
                    c[a] += p[a] / 3.0;
                }
            }
            let key = cube.morton(c);
            sorter.push_with(|b| {
                b[..8].copy_from_slice(&key.to_le_bytes());
                b[8..].copy_from_slice(t);
            })?;
        }
        progress.inc(n as u64);
    }
    progress.finish();

    // Pass 2: cut leaves, write their payloads.
    let progress = Progress::items(sh.triangles, "partitioning", opts.quiet);
    let mut cutter = Cutter {
        depth: opts.max_depth,
        limit: opts.leaf_tris as usize,
        rec,
        keys: Vec::new(),
        khead: 0,
        data: Vec::new(),
        prev: None,
        open: None,
        leaves: Vec::new(),
        pack: PackWriter::create(dir, 0)?,
        layout,
        payload: Vec::new(),
        progress: &progress,
        overfull: 0,
    };
    let sort = sorter.finish(|r| cutter.push(u64::from_le_bytes(r[..8].try_into().unwrap()), &r[8..]))?;
    cutter.finish()?;
    progress.finish();
    let Cutter { leaves, pack, overfull, .. } = cutter;
    let pack_bytes = pack.finish()?;
    let nodes = assemble(&leaves, &cube);
    let report = OctreeReport {
        leaves: leaves.len() as u64,
        nodes: nodes.len() as u64,
        deepest: nodes.iter().map(|n| n.depth).max().unwrap_or(0),
        overfull_leaves: overfull,
        sort,
        pack_bytes,
        seconds: t0.elapsed().as_secs_f64(),
    };
    Ok((sh, cube, nodes, report))
}

/// A finished leaf, in Morton order.
struct Leaf {
    path: u64,
    depth: u8,
    slot: Slot,
    content: Aabb,
}

/// The open leaf (at max depth, possibly longer than the window).
struct OpenLeaf {
    path: u64,
    depth: u8,
    data: Vec<u8>,
}

struct Cutter<'a> {
    depth: u8,
    limit: usize,
    rec: usize,
    /// Lookahead window: keys[khead..] and the matching triangle bytes.
    keys: Vec<u64>,
    khead: usize,
    data: Vec<u8>,
    /// Key of the last triangle given to a leaf.
    prev: Option<u64>,
    open: Option<OpenLeaf>,
    leaves: Vec<Leaf>,
    pack: PackWriter,
    layout: VertexLayout,
    payload: Vec<u8>,
    progress: &'a Progress,
    overfull: u64,
}

impl Cutter<'_> {
    #[inline]
    fn prefix(&self, key: u64, d: u8) -> u64 {
        key >> (3 * (self.depth - d) as u32)
    }

    fn window(&self) -> usize {
        self.keys.len() - self.khead
    }

    fn push(&mut self, key: u64, tri: &[u8]) -> Result<()> {
        let window_empty = self.window() == 0;
        if let Some(open) = &mut self.open {
            if key >> (3 * (self.depth - open.depth) as u32) == open.path && window_empty {
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
            Some(p) => (0..=self.depth).find(|&d| self.prefix(p, d) != self.prefix(k0, d)).unwrap_or(self.depth),
        };
        while d < self.depth {
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
        if d < self.depth || self.window() > 0 {
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
        let (mesh, content) = index_triangles(&self.layout, &leaf.data);
        encode_payload(&self.layout, &mesh, &mut self.payload);
        let (offset, bytes) = self.pack.append(&self.payload)?;
        self.leaves.push(Leaf {
            path: leaf.path,
            depth: leaf.depth,
            slot: Slot { offset, bytes, tris: mesh.triangles.len() as u32, verts: mesh.vertices.len() as u32, error: 0.0 },
            content,
        });
        self.progress.inc(n as u64);
        Ok(())
    }
}

/// Soup triangles → indexed mesh (exactly equal corners share a vertex) and their bounds.
pub fn index_triangles(layout: &VertexLayout, soup: &[u8]) -> (IndexedMesh, Aabb) {
    let s = layout.size;
    let mut map: HashMap<&[u8], u32> = HashMap::with_capacity(soup.len() / (3 * s));
    let mut mesh = IndexedMesh::default();
    let mut bb = Aabb::EMPTY;
    for t in soup.chunks_exact(3 * s) {
        let mut tri = [0u32; 3];
        for c in 0..3 {
            let key = &t[c * s..(c + 1) * s];
            let next = mesh.vertices.len() as u32;
            tri[c] = *map.entry(key).or_insert_with(|| {
                let v = layout.decode(key);
                bb.add(v.pos);
                mesh.vertices.push(v);
                next
            });
        }
        mesh.triangles.push(tri);
    }
    (mesh, bb)
}

/// Builds the node records (depth-first pre-order) from the leaves in Morton order.
fn assemble(leaves: &[Leaf], cube: &Cube) -> Vec<NodeRec> {
    let max_depth = cube.depth;
    let new_node = |path: u64, depth: u8, parent: u32| NodeRec {
        path,
        depth,
        parent,
        children: [NO_NODE; 8],
        cell: cube.cell(path, depth),
        content: Aabb::EMPTY,
        subtree_tris: 0,
        orig: Slot::default(),
        simp: Slot::default(),
        level: 0,
    };
    let mut nodes: Vec<NodeRec> = Vec::with_capacity(leaves.len() * 8 / 7 + 1);
    if leaves.len() == 1 && leaves[0].depth == 0 {
        let mut n = new_node(0, 0, NO_NODE);
        n.orig = leaves[0].slot;
        n.content = leaves[0].content;
        n.subtree_tris = leaves[0].slot.tris as u64;
        return vec![n];
    }
    nodes.push(new_node(0, 0, NO_NODE));
    let mut stack: Vec<u32> = vec![0];
    for leaf in leaves {
        // Pop to the deepest open ancestor of this leaf.
        loop {
            let top = &nodes[*stack.last().unwrap() as usize];
            if leaf.depth > top.depth && leaf.path >> (3 * (leaf.depth - top.depth) as u32) == top.path {
                break;
            }
            stack.pop();
        }
        // Create the missing internal nodes, then the leaf.
        let top_depth = nodes[*stack.last().unwrap() as usize].depth;
        for d in top_depth + 1..=leaf.depth {
            let parent = *stack.last().unwrap();
            let path = leaf.path >> (3 * (leaf.depth - d) as u32);
            let id = nodes.len() as u32;
            nodes[parent as usize].children[(path & 7) as usize] = id;
            nodes.push(new_node(path, d, parent));
            stack.push(id);
        }
        let id = *stack.last().unwrap() as usize;
        nodes[id].orig = leaf.slot;
        nodes[id].content = leaf.content;
        nodes[id].subtree_tris = leaf.slot.tris as u64;
        stack.pop();
    }
    debug_assert!(nodes.iter().all(|n| n.depth <= max_depth));
    // Bounds and counts up the tree (children have larger ids than parents).
    for i in (1..nodes.len()).rev() {
        let (c, t, p) = (nodes[i].content, nodes[i].subtree_tris, nodes[i].parent as usize);
        nodes[p].content.merge(&c);
        nodes[p].subtree_tris += t;
    }
    nodes
}

//! The on-disk store `NAME.octolod/`: the node index and the node payloads.
//!
//! Takes: node records and indexed meshes from the octree and simplify
//! stages. Gives: a directory any later stage (extract, viewer, metro) can
//! open and read node by node:
//!
//! * `nodes.bin` — a 64-byte header (magic `OCTLODIX`, version, attribute
//!   set, node count, level count, root cube, Morton depth) and one fixed
//!   [`NodeRec`] of 192 bytes per node in depth-first pre-order (so a
//!   subtree is a contiguous id range and the root is node 0);
//! * `level-L.pack` — the payloads of level L, each starting on a 4 KiB
//!   page boundary and read with one sequential read of its byte range;
//! * `store.json` — a human-readable manifest (format version, attributes,
//!   per-level figures, build parameters and timings).
//!
//! Pack files rather than one file per node: a 10^9-triangle mesh has ~10^5
//! leaves per level, and a directory of 10^5–10^6 small files costs inodes,
//! open() calls and metadata seeks; page-aligned ranges in a few large files
//! give the same "one node = one sequential read" with `pread`, keep
//! sibling nodes adjacent (depth-first order) for read-ahead, and are what
//! Nanite-style streaming does with its fixed-size pages.
//!
//! A payload is an indexed mesh: `u32 vertex count, u32 triangle count,
//! u32 index size (2 or 4), u32 reserved`, the vertex table in the store's
//! [`VertexLayout`] (positions in the input's precision, so level 0 is
//! exact), then the triangles' indices (u16 when the node has ≤ 65 535
//! vertices, else u32), all little-endian.

use crate::error::{Error, IoContext, Location, Result};
use crate::mesh::{Aabb, AttrSet, Vertex, VertexLayout};
use std::fs::File;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

pub const MAGIC: [u8; 8] = *b"OCTLODIX";
pub const VERSION: u32 = 1;
pub const PAGE: u64 = 4096;
pub const NO_NODE: u32 = u32::MAX;
const HEADER: usize = 64;
const NODE_REC: usize = 256;

/// Where one level's mesh of a node lives.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Slot {
    pub offset: u64,
    pub bytes: u32,
    pub tris: u32,
    pub verts: u32,
    /// Conservative object-space error of this mesh against the original.
    pub error: f32,
}

impl Slot {
    pub fn is_empty(&self) -> bool {
        self.bytes == 0
    }
}

/// One octree node.
#[derive(Clone, Debug, PartialEq)]
pub struct NodeRec {
    /// Morton path of the cell (3 bits per level from the root).
    pub path: u64,
    pub depth: u8,
    pub parent: u32,
    pub children: [u32; 8],
    /// The node's octree cell (derivable from `path`, `depth` and the root
    /// cube; stored so readers need not recompute it).
    pub cell: Aabb,
    /// Tight bounds of the original triangles under this node.
    pub content: Aabb,
    /// Original triangles under this node (leaf: its own).
    pub subtree_tris: u64,
    /// Level-0 mesh: the original triangles (leaves only), in `level-0.pack`.
    pub orig: Slot,
    /// The node's simplified mesh, in `level-{level}.pack`; empty when not built.
    pub simp: Slot,
    /// Level of `simp`: 1 for leaves, 1 + the highest child level otherwise.
    pub level: u8,
}

impl NodeRec {
    pub fn is_leaf(&self) -> bool {
        self.children.iter().all(|&c| c == NO_NODE)
    }
}

/// The root cube and Morton quantisation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cube {
    pub center: [f64; 3],
    pub half: f64,
    /// Bits per axis of the Morton code (= maximum depth).
    pub depth: u8,
}

impl Cube {
    /// The smallest cube around `b`, slightly enlarged so that the maximum
    /// corner quantises inside.
    pub fn around(b: &Aabb, depth: u8) -> Cube {
        let ext = (0..3).map(|k| b.max[k] - b.min[k]).fold(0.0, f64::max);
        let half = if ext > 0.0 { ext * 0.5 * (1.0 + 1e-9) + f64::MIN_POSITIVE } else { 1.0 };
        Cube { center: b.center(), half, depth }
    }

    /// Cell bounds of node `path` at `depth`.
    pub fn cell(&self, path: u64, depth: u8) -> Aabb {
        let n = 1u64 << depth;
        let size = 2.0 * self.half / n as f64;
        let (x, y, z) = demorton(path);
        let lo = [0, 1, 2].map(|k| self.center[k] - self.half + [x, y, z][k] as f64 * size);
        Aabb { min: lo, max: [0, 1, 2].map(|k| lo[k] + size) }
    }

    /// Morton code of a point at full depth.
    pub fn morton(&self, p: [f64; 3]) -> u64 {
        let n = 1u64 << self.depth;
        let q = |k: usize| {
            let t = (p[k] - (self.center[k] - self.half)) / (2.0 * self.half);
            ((t * n as f64).floor().max(0.0) as u64).min(n - 1)
        };
        morton3(q(0), q(1), q(2))
    }
}

fn spread(mut x: u64) -> u64 {
    x &= 0x1f_ffff;
    x = (x | x << 32) & 0x1f00000000ffff;
    x = (x | x << 16) & 0x1f0000ff0000ff;
    x = (x | x << 8) & 0x100f00f00f00f00f;
    x = (x | x << 4) & 0x10c30c30c30c30c3;
    (x | x << 2) & 0x1249249249249249
}

fn compact(mut x: u64) -> u64 {
    x &= 0x1249249249249249;
    x = (x ^ (x >> 2)) & 0x10c30c30c30c30c3;
    x = (x ^ (x >> 4)) & 0x100f00f00f00f00f;
    x = (x ^ (x >> 8)) & 0x1f0000ff0000ff;
    x = (x ^ (x >> 16)) & 0x1f00000000ffff;
    (x ^ (x >> 32)) & 0x1f_ffff
}

/// Interleaves x, y, z bits (x lowest).
pub fn morton3(x: u64, y: u64, z: u64) -> u64 {
    spread(x) | spread(y) << 1 | spread(z) << 2
}

pub fn demorton(m: u64) -> (u64, u64, u64) {
    (compact(m), compact(m >> 1), compact(m >> 2))
}

/// An indexed mesh, the content of one payload.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct IndexedMesh {
    pub vertices: Vec<Vertex>,
    pub triangles: Vec<[u32; 3]>,
}

/// Encodes a payload (see the module doc).
pub fn encode_payload(layout: &VertexLayout, m: &IndexedMesh, out: &mut Vec<u8>) {
    out.clear();
    let wide = m.vertices.len() > u16::MAX as usize;
    out.extend_from_slice(&(m.vertices.len() as u32).to_le_bytes());
    out.extend_from_slice(&(m.triangles.len() as u32).to_le_bytes());
    out.extend_from_slice(&(if wide { 4u32 } else { 2u32 }).to_le_bytes());
    out.extend_from_slice(&0u32.to_le_bytes());
    let at = out.len();
    out.resize(at + m.vertices.len() * layout.size, 0);
    for (k, v) in m.vertices.iter().enumerate() {
        layout.encode(v, &mut out[at + k * layout.size..]);
    }
    for t in &m.triangles {
        for &i in t {
            if wide {
                out.extend_from_slice(&i.to_le_bytes());
            } else {
                out.extend_from_slice(&(i as u16).to_le_bytes());
            }
        }
    }
}

/// Decodes a payload; errors name the store file and offset.
pub fn decode_payload(layout: &VertexLayout, b: &[u8], file: &Path, offset: u64) -> Result<IndexedMesh> {
    let bad = |msg: &str| Error::input(Location { file: file.to_path_buf(), offset: Some(offset), ..Default::default() }, msg);
    if b.len() < 16 {
        return Err(bad("payload shorter than its header"));
    }
    let u = |o: usize| u32::from_le_bytes(b[o..o + 4].try_into().unwrap()) as usize;
    let (nv, nt, isz) = (u(0), u(4), u(8));
    if isz != 2 && isz != 4 {
        return Err(bad("payload index size is neither 2 nor 4"));
    }
    let need = 16 + nv * layout.size + nt * 3 * isz;
    if b.len() < need {
        return Err(bad("payload truncated"));
    }
    let vertices = (0..nv).map(|k| layout.decode(&b[16 + k * layout.size..])).collect();
    let ib = &b[16 + nv * layout.size..];
    let mut triangles = Vec::with_capacity(nt);
    for t in 0..nt {
        let mut tri = [0u32; 3];
        for c in 0..3 {
            let o = (3 * t + c) * isz;
            tri[c] = if isz == 4 {
                u32::from_le_bytes(ib[o..o + 4].try_into().unwrap())
            } else {
                u16::from_le_bytes(ib[o..o + 2].try_into().unwrap()) as u32
            };
            if tri[c] as usize >= nv {
                return Err(bad("payload index out of range"));
            }
        }
        triangles.push(tri);
    }
    Ok(IndexedMesh { vertices, triangles })
}

/// Store-wide facts.
#[derive(Clone, Debug, PartialEq)]
pub struct StoreHeader {
    pub attrs: AttrSet,
    pub levels: u32,
    pub cube: Cube,
    pub nodes: u64,
}

/// Appends page-aligned payloads to one level's pack file.
pub struct PackWriter {
    path: PathBuf,
    w: std::io::BufWriter<File>,
    pos: u64,
}

impl PackWriter {
    pub fn create(dir: &Path, level: usize) -> Result<PackWriter> {
        let path = pack_file(dir, level);
        let f = File::create(&path).ctx(&path, "create pack file")?;
        Ok(PackWriter { w: std::io::BufWriter::with_capacity(crate::io::SEQ_BUF, f), path, pos: 0 })
    }
    /// Writes one payload at the next page boundary; returns (offset, bytes).
    pub fn append(&mut self, payload: &[u8]) -> Result<(u64, u32)> {
        let pad = (PAGE - self.pos % PAGE) % PAGE;
        if pad > 0 {
            self.w.write_all(&vec![0u8; pad as usize]).ctx(&self.path, "write pack file")?;
            self.pos += pad;
        }
        let off = self.pos;
        self.w.write_all(payload).ctx(&self.path, "write pack file")?;
        self.pos += payload.len() as u64;
        Ok((off, payload.len() as u32))
    }
    pub fn finish(self) -> Result<u64> {
        let f = self.w.into_inner().map_err(|e| e.into_error()).ctx(&self.path, "write pack file")?;
        f.sync_all().ctx(&self.path, "sync")?;
        Ok(self.pos)
    }
}

fn put_aabb(b: &mut Vec<u8>, a: &Aabb) {
    for v in a.min.iter().chain(a.max.iter()) {
        b.extend_from_slice(&v.to_le_bytes());
    }
}

/// Writes `nodes.bin`.
pub fn write_index(dir: &Path, h: &StoreHeader, nodes: &[NodeRec]) -> Result<()> {
    let path = dir.join("nodes.bin");
    let mut b = Vec::with_capacity(HEADER + nodes.len() * NODE_REC);
    b.extend_from_slice(&MAGIC);
    b.extend_from_slice(&VERSION.to_le_bytes());
    b.extend_from_slice(&h.attrs.0.to_le_bytes());
    b.extend_from_slice(&(nodes.len() as u64).to_le_bytes());
    b.extend_from_slice(&h.levels.to_le_bytes());
    b.extend_from_slice(&(h.cube.depth as u32).to_le_bytes());
    for c in h.cube.center {
        b.extend_from_slice(&c.to_le_bytes());
    }
    b.extend_from_slice(&h.cube.half.to_le_bytes());
    b.resize(HEADER, 0);
    for n in nodes {
        let at = b.len();
        b.extend_from_slice(&n.path.to_le_bytes());
        b.extend_from_slice(&[n.depth, n.level, 0, 0]);
        b.extend_from_slice(&n.parent.to_le_bytes());
        for c in n.children {
            b.extend_from_slice(&c.to_le_bytes());
        }
        put_aabb(&mut b, &n.content);
        b.extend_from_slice(&n.subtree_tris.to_le_bytes());
        for s in [&n.orig, &n.simp] {
            b.extend_from_slice(&s.offset.to_le_bytes());
            b.extend_from_slice(&s.bytes.to_le_bytes());
            b.extend_from_slice(&s.tris.to_le_bytes());
            b.extend_from_slice(&s.verts.to_le_bytes());
            b.extend_from_slice(&s.error.to_le_bytes());
        }
        put_aabb(&mut b, &n.cell);
        debug_assert!(b.len() - at <= NODE_REC);
        b.resize(at + NODE_REC, 0);
    }
    let mut f = File::create(&path).ctx(&path, "create")?;
    f.write_all(&b).ctx(&path, "write")?;
    f.sync_all().ctx(&path, "sync")
}

/// An opened store: the index in memory, payloads read on demand.
pub struct Store {
    pub dir: PathBuf,
    pub header: StoreHeader,
    pub nodes: Vec<NodeRec>,
    pub layout: VertexLayout,
}

impl Store {
    pub fn open(dir: &Path) -> Result<Store> {
        let path = dir.join("nodes.bin");
        let mut b = Vec::new();
        File::open(&path).ctx(&path, "open store index")?.read_to_end(&mut b).ctx(&path, "read")?;
        let bad = |msg: String| Error::input(Location { file: path.clone(), ..Default::default() }, msg);
        if b.len() < HEADER || b[..8] != MAGIC {
            return Err(bad("not an octolod store index (bad magic)".into()));
        }
        let u32_at = |o: usize| u32::from_le_bytes(b[o..o + 4].try_into().unwrap());
        let u64_at = |o: usize| u64::from_le_bytes(b[o..o + 8].try_into().unwrap());
        let f64_at = |o: usize| f64::from_le_bytes(b[o..o + 8].try_into().unwrap());
        if u32_at(8) != VERSION {
            return Err(bad(format!("store version {} is not supported (expected {VERSION})", u32_at(8))));
        }
        let attrs = AttrSet::from_bits(u32_at(12)).ok_or_else(|| bad("unknown attribute bits".into()))?;
        let n = u64_at(16) as usize;
        if b.len() != HEADER + n * NODE_REC {
            return Err(bad(format!("index holds {} bytes, expected {} for {n} nodes", b.len(), HEADER + n * NODE_REC)));
        }
        let header = StoreHeader {
            attrs,
            nodes: n as u64,
            levels: u32_at(24),
            cube: Cube { center: [f64_at(32), f64_at(40), f64_at(48)], half: f64_at(56), depth: u32_at(28) as u8 },
        };
        let mut nodes = Vec::with_capacity(n);
        for i in 0..n {
            let o = HEADER + i * NODE_REC;
            let mut children = [NO_NODE; 8];
            for (k, c) in children.iter_mut().enumerate() {
                *c = u32_at(o + 16 + 4 * k);
            }
            let aabb = |o: usize| Aabb {
                min: [f64_at(o), f64_at(o + 8), f64_at(o + 16)],
                max: [f64_at(o + 24), f64_at(o + 32), f64_at(o + 40)],
            };
            let slot = |p: usize| Slot {
                offset: u64_at(p),
                bytes: u32_at(p + 8),
                tris: u32_at(p + 12),
                verts: u32_at(p + 16),
                error: f32::from_le_bytes(b[p + 20..p + 24].try_into().unwrap()),
            };
            nodes.push(NodeRec {
                path: u64_at(o),
                depth: b[o + 8],
                parent: u32_at(o + 12),
                children,
                cell: aabb(o + 152),
                content: aabb(o + 48),
                subtree_tris: u64_at(o + 96),
                orig: slot(o + 104),
                simp: slot(o + 128),
                level: b[o + 9],
            });
        }
        Ok(Store { dir: dir.to_path_buf(), layout: VertexLayout::new(attrs), header, nodes })
    }

    pub fn pack_path(&self, level: usize) -> PathBuf {
        pack_file(&self.dir, level)
    }

    /// Reads node `id`'s original (`simplified == false`, leaves) or
    /// simplified mesh with one positioned read.
    pub fn read_mesh(&self, id: usize, simplified: bool) -> Result<IndexedMesh> {
        let n = &self.nodes[id];
        let (s, level) = if simplified { (n.simp, n.level as usize) } else { (n.orig, 0) };
        read_slot(&self.dir, &self.layout, level, &s)
    }
}

/// The pack file of `level` in store directory `dir`.
pub fn pack_file(dir: &Path, level: usize) -> PathBuf {
    dir.join(format!("level-{level}.pack"))
}

/// Reads one payload of `dir`'s level-`level` pack.
pub fn read_slot(dir: &Path, layout: &VertexLayout, level: usize, s: &Slot) -> Result<IndexedMesh> {
    use std::os::unix::fs::FileExt;
    if s.is_empty() {
        return Ok(IndexedMesh::default());
    }
    let path = pack_file(dir, level);
    let f = File::open(&path).ctx(&path, "open pack file")?;
    let mut b = vec![0u8; s.bytes as usize];
    f.read_exact_at(&mut b, s.offset).ctx(&path, "read pack file")?;
    decode_payload(layout, &b, &path, s.offset)
}

//! The stream between levels: *chunks*, each the part of one node's output
//! that falls in one cell of the next level, as a small indexed mesh.
//!
//! Takes: triangles routed to leaves of a [`super::partition::Tiling`] —
//! from the octree cut (level 0: one chunk per leaf, the input's
//! triangles) or from a node's simplified mesh (level L + 1). Gives: for
//! each leaf, its triangles welded into one indexed mesh with, per vertex,
//! its propagated quadric and whether it was locked one level below,
//! grouped into patches by source node ([`ChunkFile::gather`]).
//!
//! Format (temp file, little-endian): per chunk `u32 target leaf, u32
//! source node, u32 vertex count, u32 triangle count`, then per vertex the
//! vertex in the store's input layout, `a_len` f32 of its quadric about its
//! position (packed upper-triangle matrix, half-gradient, residual:
//! [`crate::quadric::carry_len`]; attribute dimensions unweighted) and one flag
//! byte (bit 0: locked at the source's level), then 3 indices per triangle,
//! `u16` when the chunk has at most 65,535 vertices (nearly always: a chunk
//! is part of one leaf), else `u32` — the store payload's rule
//! ([`crate::store::index_width`]). The narrow indices
//! cut level 0's chunks by a third and later levels' by a sixth: bytes that
//! are copied into fresh page cache and back (costs in
//! `docs/build-costs.md`).
//!
//! Why chunks rather than a triangle soup sorted again for every level:
//! a soup repeats each vertex in about six triangles, and with a quadric
//! per vertex (24 bytes for positions) that would be ~120 bytes per
//! triangle through an external sort per level; chunks are indexed
//! (~30 bytes per triangle) and need no sort, because the next level's
//! cells are decided before the nodes are simplified (predicted from a
//! histogram, [`super::partition`]). A leaf's chunks come from the few
//! nodes of the level below that overlap it; they are read with one
//! positioned read each, in the next level's Morton order.

use crate::error::{Error, IoContext, Location, Result};
use crate::mesh::IndexedMesh;
use crate::mesh::VertexLayout;
use crate::store::{index_at, index_width, push_indices};
use rustc_hash::FxHashMap;
use std::fs::File;
use std::path::PathBuf;

/// Where one chunk lives.
#[derive(Clone, Copy, Debug)]
pub struct ChunkRef {
    pub target: u32,
    pub offset: u64,
    pub bytes: u32,
}

/// A chunk file being written, then read by target.
pub struct ChunkFile {
    path: PathBuf,
    /// Written behind: the routing and the level passes make the next
    /// chunks while the kernel copies these.
    w: Option<crate::io::FileWriteBehind>,
    pos: u64,
    layout: VertexLayout,
    /// Quadric matrix values per vertex (0: none stored, level 0).
    a_len: usize,
    refs: Vec<ChunkRef>,
    /// After `finish`: `refs` sorted by target, and each target's first ref.
    by_target: Vec<u32>,
    reader: Option<File>,
}

/// One leaf's gathered triangles.
#[derive(Clone, Debug, Default)]
pub struct Gathered {
    pub mesh: IndexedMesh,
    /// Quadric matrix per vertex (`a_len` each; empty when none were stored).
    pub a: Vec<f64>,
    /// Vertex was locked one level below.
    pub was_locked: Vec<bool>,
    /// (source node, triangle count), in triangle order.
    pub patches: Vec<(u32, u32)>,
}

impl ChunkFile {
    pub fn create(path: PathBuf, layout: VertexLayout, a_len: usize) -> Result<ChunkFile> {
        let f = File::create(&path).ctx(&path, "create chunk file")?;
        Ok(ChunkFile {
            w: Some(crate::io::FileWriteBehind::new(path.clone(), f, "write chunk file")),
            path,
            pos: 0,
            layout,
            a_len,
            refs: Vec::new(),
            by_target: Vec::new(),
            reader: None,
        })
    }

    pub fn a_len(&self) -> usize {
        self.a_len
    }

    /// Encodes one chunk into `out` (see the module doc). `a` holds
    /// `a_len` values per vertex, `locked` one flag per vertex.
    pub fn encode(&self, target: u32, source: u32, m: &IndexedMesh, a: &[f32], locked: &[bool], out: &mut Vec<u8>) {
        self.encoder().encode(target, source, m, a, locked, out)
    }

    /// What encoding needs, apart from the file (so workers can encode
    /// while the file is appended to).
    pub fn encoder(&self) -> ChunkEncoder {
        ChunkEncoder { layout: self.layout, a_len: self.a_len }
    }

    /// Encodes soup records (`3 × layout.size` bytes per triangle, the
    /// store's vertex layout) as one chunk with no quadrics and nothing
    /// locked: corners with identical bytes become one vertex, in order of
    /// first appearance. The same bytes as indexing the triangles and
    /// [`ChunkFile::encode`], without decoding a vertex.
    pub fn encode_soup(&self, target: u32, source: u32, soup: &[u8], out: &mut Vec<u8>) {
        debug_assert_eq!(self.a_len, 0);
        let vs = self.layout.size;
        let tris = soup.len() / (3 * vs);
        let mut map = ByteIds::new(vs, tris);
        let mut verts: Vec<u8> = Vec::with_capacity(tris * (vs + 1));
        let mut ids: Vec<u32> = Vec::with_capacity(tris * 3);
        for corner in soup.chunks_exact(vs).take(3 * tris) {
            let id = map.id(corner, || {
                verts.extend_from_slice(corner);
                verts.push(0);
            });
            ids.push(id);
        }
        out.clear();
        let nv = verts.len() / (vs + 1);
        for x in [target, source, nv as u32, tris as u32] {
            out.extend_from_slice(&x.to_le_bytes());
        }
        out.extend_from_slice(&verts);
        push_indices(out, nv, ids.iter().copied());
    }

    /// Appends an encoded chunk.
    pub fn append(&mut self, target: u32, bytes: &[u8]) -> Result<()> {
        let w = self.w.as_mut().expect("chunk file already finished");
        w.write_all(bytes)?;
        self.refs.push(ChunkRef { target, offset: self.pos, bytes: bytes.len() as u32 });
        self.pos += bytes.len() as u64;
        Ok(())
    }

    /// Renumbers the targets of the chunks written so far (`map[old]`).
    pub fn retarget(&mut self, map: &[u32]) {
        for r in &mut self.refs {
            r.target = map[r.target as usize];
        }
    }

    /// Ends writing; chunks become readable by target (`targets` leaves).
    pub fn finish(&mut self, targets: usize) -> Result<()> {
        if let Some(w) = self.w.take() {
            w.finish()?;
        }
        self.refs.sort_by_key(|r| (r.target, r.offset));
        self.by_target = vec![0; targets + 1];
        for r in &self.refs {
            self.by_target[r.target as usize + 1] += 1;
        }
        for i in 0..targets {
            self.by_target[i + 1] += self.by_target[i];
        }
        self.reader = Some(File::open(&self.path).ctx(&self.path, "open chunk file")?);
        Ok(())
    }

    /// The file's path.
    pub fn path(&self) -> &std::path::Path {
        &self.path
    }

    /// Every chunk, by target once finished (a shard's state lists them).
    pub fn refs(&self) -> &[ChunkRef] {
        &self.refs
    }

    /// Bytes written.
    pub fn bytes(&self) -> u64 {
        self.pos
    }

    /// Chunks of leaf `t`.
    pub fn refs_of(&self, t: usize) -> &[ChunkRef] {
        &self.refs[self.by_target[t] as usize..self.by_target[t + 1] as usize]
    }

    /// Reads leaf `t`'s chunks and welds them: vertices with identical
    /// bytes become one (their quadric matrices add up, as each chunk
    /// carries its share of the vertex's fan), triangles stay in chunk
    /// order, one patch per chunk.
    pub fn gather(&self, t: usize) -> Result<Gathered> {
        self.gather_with(t, true)
    }

    /// Leaf `t`'s chunks as read, in order, each checked against its
    /// header: (offset, bytes).
    fn read_leaf(&self, t: usize) -> Result<Vec<(u64, Vec<u8>)>> {
        use std::os::unix::fs::FileExt;
        let f = self.reader.as_ref().expect("chunk file not finished");
        let rec = record_size(&self.layout, self.a_len);
        self.refs_of(t)
            .iter()
            .map(|r| {
                let mut b = vec![0u8; r.bytes as usize];
                f.read_exact_at(&mut b, r.offset).ctx(&self.path, "read chunk file")?;
                let ok = b.len() >= 16 && {
                    let (nv, nt) = (field(&b, 8), field(&b, 12));
                    b.len() as u64 == 16 + nv as u64 * rec as u64 + nt as u64 * 3 * index_width(nv) as u64
                };
                if !ok {
                    return Err(self.damaged(r.offset));
                }
                Ok((r.offset, b))
            })
            .collect()
    }

    fn damaged(&self, offset: u64) -> Error {
        Error::input(Location { file: self.path.clone(), offset: Some(offset), ..Default::default() }, "damaged chunk")
    }

    /// One chunk's (source node, vertex count, triangles), its corners
    /// checked against its vertex count.
    fn chunk_triangles(&self, offset: u64, b: &[u8], mut each: impl FnMut([usize; 3])) -> Result<(u32, usize, usize)> {
        let (source, nv, nt) = (field(b, 4) as u32, field(b, 8), field(b, 12));
        let iw = index_width(nv);
        let rec = record_size(&self.layout, self.a_len);
        for tri in b[16 + nv * rec..].chunks_exact(3 * iw) {
            let tri = [0, 1, 2].map(|j| index_at(tri, iw, j) as usize);
            if tri.iter().any(|&i| i >= nv) {
                return Err(self.damaged(offset));
            }
            each(tri);
        }
        Ok((source, nv, nt))
    }

    /// [`ChunkFile::gather`], the carried quadrics summed only when
    /// `quadrics` (`a` is empty otherwise).
    pub fn gather_with(&self, t: usize, quadrics: bool) -> Result<Gathered> {
        let bufs = self.read_leaf(t)?;
        let mut g = Gathered::default();
        let vs = self.layout.size;
        let rec = record_size(&self.layout, self.a_len);
        let total_v: usize = bufs.iter().map(|(_, b)| field(b, 8)).sum();
        let mut map = ByteIds::new(vs, total_v);
        // Room for every record up front (shared ones merge, so at most
        // this): growing by doubling copied the node's vertices and, for
        // clustering, their carried quadrics (55 values a vertex with
        // normals and colours) a few times over. (Counts checked against
        // the bytes read.)
        let room_t: usize = bufs.iter().map(|(_, b)| field(b, 12)).sum();
        g.mesh.vertices.reserve(total_v);
        g.was_locked.reserve(total_v);
        g.mesh.triangles.reserve(room_t);
        if quadrics {
            g.a.reserve(total_v * self.a_len);
        }
        let mut ids = Vec::new();
        for (offset, b) in &bufs {
            let nv = field(b, 8);
            ids.clear();
            for k in 0..nv {
                let v = &b[16 + k * rec..16 + (k + 1) * rec];
                let mut fresh = false;
                let id = map.id(&v[..vs], || {
                    g.mesh.vertices.push(self.layout.decode(&v[..vs]));
                    g.was_locked.push(false);
                    fresh = true;
                });
                if quadrics {
                    let carried = v[vs..vs + 4 * self.a_len].chunks_exact(4).map(|x| f32::from_le_bytes(x.try_into().unwrap()) as f64);
                    if fresh {
                        // A vertex's first record: its values added to zero
                        // (the same bits, a negative zero made positive),
                        // without zeroing its row first.
                        g.a.extend(carried.map(|x| 0.0 + x));
                    } else {
                        let at = id as usize * self.a_len;
                        for (a, x) in g.a[at..at + self.a_len].iter_mut().zip(carried) {
                            *a += x;
                        }
                    }
                }
                g.was_locked[id as usize] |= v[rec - 1] & 1 != 0;
                ids.push(id);
            }
            let (source, _, nt) = self.chunk_triangles(*offset, b, |tri| g.mesh.triangles.push(tri.map(|i| ids[i])))?;
            g.patches.push((source, nt as u32));
        }
        Ok(g)
    }

    /// Leaf `t`'s chunks read, to be scanned one by one, unwelded and
    /// positions only ([`LeafScan::each`]): what the shared-vertex pass
    /// needs, without welding the node (a chunk's vertices are distinct;
    /// the same vertex in two chunks is merged by the caller, for the few
    /// positions it keeps).
    pub fn scan(&self, t: usize) -> Result<LeafScan<'_>> {
        Ok(LeafScan { file: self, bufs: self.read_leaf(t)? })
    }

    /// Removes the file.
    pub fn remove(self) {
        drop(self.reader);
        let _ = std::fs::remove_file(&self.path);
    }
}

/// A chunk's header field at byte `at` (0: target leaf, 4: source, 8:
/// vertices, 12: triangles).
pub(crate) fn field(b: &[u8], at: usize) -> usize {
    u32::from_le_bytes(b[at..at + 4].try_into().unwrap()) as usize
}

/// Bytes of one chunk vertex record: the vertex, its carried values
/// (`a_len` f32s) and its flags byte.
fn record_size(layout: &VertexLayout, a_len: usize) -> usize {
    layout.size + 4 * a_len + 1
}

/// A leaf's chunks as read ([`ChunkFile::scan`]).
pub struct LeafScan<'a> {
    file: &'a ChunkFile,
    bufs: Vec<(u64, Vec<u8>)>,
}

impl LeafScan<'_> {
    /// Vertices and triangles, summed over the chunks.
    pub fn sizes(&self) -> (usize, usize) {
        self.bufs.iter().fold((0, 0), |(v, t), (_, b)| (v + field(b, 8), t + field(b, 12)))
    }

    /// Each chunk's vertex positions, whether each was locked one level
    /// below, and its triangles (indices into that chunk's vertices).
    pub fn each(&self, mut f: impl FnMut(&[[f64; 3]], &[bool], &[[u32; 3]])) -> Result<()> {
        let file = self.file;
        let (vs, rec) = (file.layout.size, record_size(&file.layout, file.a_len));
        let most = |at: usize| self.bufs.iter().map(|(_, b)| field(b, at)).max().unwrap_or(0);
        let (mut pos, mut locked, mut tris) = (Vec::with_capacity(most(8)), Vec::with_capacity(most(8)), Vec::with_capacity(most(12)));
        for (offset, b) in &self.bufs {
            let nv = field(b, 8);
            pos.clear();
            locked.clear();
            tris.clear();
            for v in b[16..16 + nv * rec].chunks_exact(rec) {
                pos.push(file.layout.position(&v[..vs]));
                locked.push(v[rec - 1] & 1 != 0);
            }
            file.chunk_triangles(*offset, b, |tri| tris.push(tri.map(|i| i as u32)))?;
            f(&pos, &locked, &tris);
        }
        Ok(())
    }
}

/// [`ChunkFile::encode`] without the file.
#[derive(Clone, Copy, Debug)]
pub struct ChunkEncoder {
    layout: VertexLayout,
    a_len: usize,
}

impl ChunkEncoder {
    /// See [`ChunkFile::encode`].
    pub fn encode(&self, target: u32, source: u32, m: &IndexedMesh, a: &[f32], locked: &[bool], out: &mut Vec<u8>) {
        out.clear();
        // Its exact size up front (grown by doubling it was copied over).
        let iw = crate::store::index_width(m.vertices.len());
        out.reserve(16 + m.vertices.len() * record_size(&self.layout, self.a_len) + 3 * m.triangles.len() * iw);
        for x in [target, source, m.vertices.len() as u32, m.triangles.len() as u32] {
            out.extend_from_slice(&x.to_le_bytes());
        }
        let vs = self.layout.size;
        let mut buf = vec![0u8; vs];
        for (k, v) in m.vertices.iter().enumerate() {
            self.layout.encode(v, &mut buf);
            out.extend_from_slice(&buf);
            for x in &a[k * self.a_len..(k + 1) * self.a_len] {
                out.extend_from_slice(&x.to_le_bytes());
            }
            out.push(locked[k] as u8);
        }
        push_indices(out, m.vertices.len(), m.triangles.iter().flatten().copied());
    }
}

/// Splits a node's simplified mesh into chunks by target leaf, dividing
/// each vertex's quadric matrix among the chunks that hold it in
/// proportion to its triangles in each (so sums over chunks are kept).
/// `leaf_of[t]` is triangle t's target. Returns (target, mesh, a, locked)
/// per chunk, in target order.
pub fn split_by_target(m: &IndexedMesh, a: &[f64], a_len: usize, locked: &[bool], leaf_of: &[u32]) -> Vec<(u32, IndexedMesh, Vec<f32>, Vec<bool>)> {
    let nv = m.vertices.len();
    let mut order: Vec<usize> = (0..m.triangles.len()).collect();
    order.sort_by_key(|&t| leaf_of[t]);
    // Triangles per vertex overall, for the shares.
    let mut deg = vec![0u32; nv];
    for t in &m.triangles {
        for &v in t {
            deg[v as usize] += 1;
        }
    }
    let mut out = Vec::new();
    let mut map = vec![u32::MAX; nv];
    let mut local_deg: Vec<u32> = Vec::new();
    let mut i = 0;
    while i < order.len() {
        let target = leaf_of[order[i]];
        let mut j = i;
        let mut cm = IndexedMesh::default();
        let mut src: Vec<usize> = Vec::new();
        local_deg.clear();
        while j < order.len() && leaf_of[order[j]] == target {
            let t = m.triangles[order[j]];
            let nt = t.map(|v| {
                let v = v as usize;
                if map[v] == u32::MAX {
                    map[v] = cm.vertices.len() as u32;
                    cm.vertices.push(m.vertices[v]);
                    src.push(v);
                    local_deg.push(0);
                }
                local_deg[map[v] as usize] += 1;
                map[v]
            });
            cm.triangles.push(nt);
            j += 1;
        }
        let mut ca = vec![0f32; src.len() * a_len];
        let mut cl = vec![false; src.len()];
        for (k, &v) in src.iter().enumerate() {
            let share = local_deg[k] as f64 / deg[v].max(1) as f64;
            for q in 0..a_len {
                ca[k * a_len + q] = (a[v * a_len + q] * share) as f32;
            }
            cl[k] = locked[v];
            map[v] = u32::MAX;
        }
        out.push((target, cm, ca, cl));
        i = j;
    }
    out
}

/// Ids of byte strings of one length (vertex records), numbered in order
/// of first appearance. The vertex sizes a layout can have (12 to 36 bytes)
/// are keyed as arrays: hashed and compared inline, where a slice key
/// costs a `memcmp` call per probe (measured dear in the level-0 routing:
/// `docs/build-costs.md`, "Partition").
enum ByteIds<'a> {
    K12(FxHashMap<[u8; 12], u32>),
    K16(FxHashMap<[u8; 16], u32>),
    K20(FxHashMap<[u8; 20], u32>),
    K24(FxHashMap<[u8; 24], u32>),
    K28(FxHashMap<[u8; 28], u32>),
    K32(FxHashMap<[u8; 32], u32>),
    K36(FxHashMap<[u8; 36], u32>),
    Any(FxHashMap<&'a [u8], u32>),
}

impl<'a> ByteIds<'a> {
    /// For keys of `len` bytes, room for `n` of them.
    fn new(len: usize, n: usize) -> ByteIds<'a> {
        fn map<K>(n: usize) -> FxHashMap<K, u32> {
            FxHashMap::with_capacity_and_hasher(n, Default::default())
        }
        match len {
            12 => ByteIds::K12(map(n)),
            16 => ByteIds::K16(map(n)),
            20 => ByteIds::K20(map(n)),
            24 => ByteIds::K24(map(n)),
            28 => ByteIds::K28(map(n)),
            32 => ByteIds::K32(map(n)),
            36 => ByteIds::K36(map(n)),
            _ => ByteIds::Any(map(n)),
        }
    }

    /// The id of `key` (of the length given to [`ByteIds::new`]); `new` is
    /// called when it is met for the first time.
    #[inline]
    fn id(&mut self, key: &'a [u8], new: impl FnOnce()) -> u32 {
        macro_rules! get {
            ($m:expr, $k:expr) => {{
                let next = $m.len() as u32;
                *$m.entry($k).or_insert_with(|| {
                    new();
                    next
                })
            }};
        }
        match self {
            ByteIds::K12(m) => get!(m, key.try_into().unwrap()),
            ByteIds::K16(m) => get!(m, key.try_into().unwrap()),
            ByteIds::K20(m) => get!(m, key.try_into().unwrap()),
            ByteIds::K24(m) => get!(m, key.try_into().unwrap()),
            ByteIds::K28(m) => get!(m, key.try_into().unwrap()),
            ByteIds::K32(m) => get!(m, key.try_into().unwrap()),
            ByteIds::K36(m) => get!(m, key.try_into().unwrap()),
            ByteIds::Any(m) => get!(m, key),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::{AttrSet, Vertex};

    /// `encode_soup` writes what indexing the triangles (first appearance,
    /// identical bytes shared) and `encode` write, attributes included.
    #[test]
    fn soup_records_encode_as_indexed_chunks() {
        let attrs = AttrSet(AttrSet::NORMAL | AttrSet::UV | AttrSet::COLOR);
        let layout = VertexLayout::new(attrs);
        let dir = tempfile::tempdir().unwrap();
        let file = ChunkFile::create(dir.path().join("c.bin"), layout, 0).unwrap();
        let mut rng = crate::geom::Rng::new(5);
        let pool: Vec<Vertex> = (0..40)
            .map(|_| Vertex {
                pos: [0, 1, 2].map(|_| rng.range(-1.0, 1.0)),
                normal: [0, 1, 2].map(|_| rng.range(-1.0, 1.0) as f32),
                uv: [rng.range(0.0, 1.0) as f32, rng.range(0.0, 1.0) as f32],
                color: [0, 1, 2, 3].map(|_| (rng.next_u64() % 256) as u8),
                material: 0,
            })
            .collect();
        let mut soup = Vec::new();
        let mut buf = vec![0u8; layout.size];
        let mut mesh = IndexedMesh::default();
        let mut index: FxHashMap<Vec<u8>, u32> = FxHashMap::default();
        for _ in 0..100 {
            let mut t = [0u32; 3];
            for c in &mut t {
                let v = &pool[(rng.next_u64() % pool.len() as u64) as usize];
                layout.encode(v, &mut buf);
                soup.extend_from_slice(&buf);
                let n = mesh.vertices.len() as u32;
                *c = *index.entry(buf.clone()).or_insert_with(|| {
                    mesh.vertices.push(layout.decode(&buf));
                    n
                });
            }
            mesh.triangles.push(t);
        }
        let (mut a, mut b) = (Vec::new(), Vec::new());
        file.encode_soup(7, 3, &soup, &mut a);
        file.encode(7, 3, &mesh, &[], &vec![false; mesh.vertices.len()], &mut b);
        assert!(mesh.vertices.len() < 300 && mesh.vertices.len() > 20);
        assert_eq!(a, b);
        // Narrow indices: the header, the vertex records and 2 bytes an index.
        assert_eq!(a.len(), 16 + mesh.vertices.len() * (layout.size + 1) + 100 * 3 * 2);
    }

    /// Chunks of up to 65,535 vertices carry u16 indices, larger ones u32;
    /// both read back as written.
    #[test]
    fn narrow_and_wide_chunks_read_back() {
        let layout = VertexLayout::new(AttrSet(0));
        let dir = tempfile::tempdir().unwrap();
        let mut file = ChunkFile::create(dir.path().join("c.bin"), layout, 1).unwrap();
        let strip = |nv: u32| IndexedMesh {
            vertices: (0..nv).map(|i| Vertex { pos: [i as f64, (i % 2) as f64, 0.0], ..Default::default() }).collect(),
            triangles: (0..nv - 2).map(|i| if i % 2 == 0 { [i, i + 1, i + 2] } else { [i + 1, i, i + 2] }).collect(),
        };
        let meshes = [strip(u16::MAX as u32), strip(u16::MAX as u32 + 1), strip(5)];
        let mut bytes = Vec::new();
        for (t, m) in meshes.iter().enumerate() {
            let a: Vec<f32> = (0..m.vertices.len()).map(|i| i as f32).collect();
            let locked: Vec<bool> = (0..m.vertices.len()).map(|i| i % 3 == 0).collect();
            file.encode(t as u32, 9, m, &a, &locked, &mut bytes);
            let iw = if m.vertices.len() <= u16::MAX as usize { 2 } else { 4 };
            assert_eq!(bytes.len(), 16 + m.vertices.len() * (12 + 4 + 1) + m.triangles.len() * 3 * iw);
            file.append(t as u32, &bytes).unwrap();
        }
        file.finish(meshes.len()).unwrap();
        for (t, m) in meshes.iter().enumerate() {
            let g = file.gather(t).unwrap();
            assert_eq!(g.mesh.triangles, m.triangles, "chunk {t}");
            assert!(g.mesh.vertices.iter().zip(&m.vertices).all(|(a, b)| a.pos == b.pos), "chunk {t}");
            assert_eq!(g.a, (0..m.vertices.len()).map(|i| i as f64).collect::<Vec<_>>());
            assert_eq!(g.was_locked, (0..m.vertices.len()).map(|i| i % 3 == 0).collect::<Vec<_>>());
            assert_eq!(g.patches, vec![(9, m.triangles.len() as u32)]);
        }
    }

    #[test]
    fn scans_see_what_gathers_weld_and_both_reject_damaged_chunks() {
        // Two chunks of one leaf sharing two vertices (locked in one of
        // them), a third leaf whose chunk's last index is out of range.
        let layout = VertexLayout::new(AttrSet(0));
        let dir = tempfile::tempdir().unwrap();
        let mut file = ChunkFile::create(dir.path().join("c.bin"), layout, 0).unwrap();
        let v = |x: f64, y: f64| Vertex { pos: [x, y, 0.5], ..Default::default() };
        let a = IndexedMesh { vertices: vec![v(0.0, 0.0), v(1.0, 0.0), v(0.0, 1.0)], triangles: vec![[0, 1, 2]] };
        let b = IndexedMesh { vertices: vec![v(1.0, 0.0), v(1.0, 1.0), v(0.0, 1.0)], triangles: vec![[0, 1, 2]] };
        let mut bytes = Vec::new();
        for (m, locked) in [(&a, [false, true, true]), (&b, [false, false, false])] {
            file.encode(0, 3, m, &[], &locked, &mut bytes);
            file.append(0, &bytes).unwrap();
        }
        file.encode(1, 4, &a, &[], &[false; 3], &mut bytes);
        let n = bytes.len();
        bytes[n - 2..].copy_from_slice(&7u16.to_le_bytes());
        file.append(1, &bytes).unwrap();
        file.finish(2).unwrap();
        let g = file.gather_with(0, false).unwrap();
        assert_eq!((g.mesh.vertices.len(), g.mesh.triangles.len()), (4, 2));
        let scan = file.scan(0).unwrap();
        assert_eq!(scan.sizes(), (6, 2));
        let mut seen = Vec::new();
        scan.each(|pos, locked, tris| seen.push((pos.to_vec(), locked.to_vec(), tris.to_vec()))).unwrap();
        assert_eq!(seen.len(), 2);
        assert_eq!(seen[0].0, a.vertices.iter().map(|v| v.pos).collect::<Vec<_>>());
        assert_eq!(seen[0].1, [false, true, true]);
        assert_eq!(seen[1].2, b.triangles);
        // Welded, the shared vertices keep the flag either chunk gave them.
        assert_eq!(g.was_locked, [false, true, true, false]);
        for e in [file.gather(1).err(), file.scan(1).and_then(|s| s.each(|_, _, _| ())).err()] {
            let e = e.expect("a damaged chunk is an error").to_string();
            assert!(e.contains("damaged chunk") && e.contains("c.bin"), "{e}");
        }
    }
}

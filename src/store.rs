//! The on-disk store `NAME.octolod/` (format version 2; 3 where a merged
//! sharded store links its shards' packs in as parts): a DAG of levels of
//! detail, and the cut queries every reader shares.
//!
//! Takes: node records and indexed meshes from the LOD builder
//! ([`crate::lod`]). Gives: a directory that `extract`, `metro`, `info` and
//! the viewer open and read node by node, and the questions they ask of it:
//! which nodes make a whole level (and its welded mesh), which make the cut
//! at an error, which patches of a node a cut draws ([`Cut`]) and the
//! meshes a cut draws.
//!
//! Invariants:
//! * Files: `nodes.bin` (a [`StoreHeader`], one fixed-size [`NodeRec`] per
//!   node, then the children and parents lists), `level-L.pack` (each
//!   payload on a [`PAGE`] boundary, read with one positioned read), in a
//!   merged store `level-L.part-P.pack` (a shard's pack, named by the
//!   record's part, its patch ids shifted by the record's patch shift) and
//!   `store.json`; all little-endian. Nodes are numbered level by level from
//!   the finest (level 0 = the input, bit-exact); the root is the last node.
//! * A node's payload is its triangles *at its level*, grouped into patches
//!   by the finer node (child) each part was simplified from (a level-0
//!   node: one patch, child [`NO_NODE`]), its vertices in
//!   [`Store::payload_layout`]. Its record's counts give its exact size and
//!   its CRC-32C, in the record, is checked on every read.
//! * Cuts. A *selection* S holds the root and, with every node, all of its
//!   parents; it draws, for each node of S, the patches whose child is not
//!   in S (a level-0 node draws everything). Seams were kept exactly, so any
//!   such cut is closed wherever the input is (Batched Multi-Triangulation,
//!   Cignoni et al. 2005). The whole level L is S = every node of level ≥ L;
//!   the cut at object-space error E adds every node a parent of which has
//!   error > E (with its missing ancestors): every drawn patch has error ≤ E.
//!
//! Byte layout, why pack files, what opening checks: `docs/store-format.md`.

use crate::error::{Error, IoContext, Location, Result};
use crate::geom::Mesh;
use crate::mesh::{Aabb, AttrSet, IndexedMesh, VertexLayout};
use std::fs::File;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

pub const MAGIC: [u8; 8] = crate::io::STORE_MAGIC;
/// The newest format version this octolod writes and reads. Version 3 is
/// version 2 with two record fields that were zero there: a node's pack
/// part and patch shift (a merged sharded store's); a store that uses
/// neither is written as version 2, so older readers still open it.
pub const VERSION: u32 = 3;
/// The oldest version read (2: levels of detail v2).
const OLDEST: u32 = 2;
pub const PAGE: u64 = 4096;
pub const NO_NODE: u32 = u32::MAX;
const HEADER: usize = 128;
/// Flag bit: payload vertices carry normals computed at build time.
const FLAG_DERIVED_NORMALS: u32 = 1;

/// Store-wide facts.
#[derive(Clone, Debug, PartialEq)]
pub struct StoreHeader {
    /// The input's attributes (what `extract` writes, what the quadric models).
    pub attrs: AttrSet,
    /// Payloads carry normals computed at build time (the input had none).
    pub derived_normals: bool,
    /// Number of levels (top level + 1).
    pub levels: u32,
    pub nodes: u64,
    /// Id of the last node: the root (the coarsest level's single node,
    /// or one of the top level's nodes when `--levels` stopped early).
    pub root: u32,
    /// Random id of this build; a reader that finds another one in the
    /// files stops (the store was rewritten under it).
    pub store_id: u64,
    /// Bounding box of the input.
    pub bbox: Aabb,
}

/// One node of the DAG.
#[derive(Clone, Debug, PartialEq)]
pub struct NodeRec {
    pub level: u8,
    /// The partition cell the node's triangles' centroids lie in.
    pub cell: Aabb,
    /// Bounds of the node's triangles and of every descendant's (saturated,
    /// so a parent's bounds contain its children's).
    pub bounds: Aabb,
    /// Object-space error of the node's triangles against the input
    /// (measured, maxed over descendants: never below a child's).
    pub error: f32,
    /// Payload in pack file `part` of its level ([`pack_file_part`]).
    pub offset: u64,
    pub bytes: u32,
    pub tris: u32,
    pub verts: u32,
    pub crc: u32,
    /// Triangles of the node's simplified mesh: what its parents' patches
    /// from it hold together (0 for the root).
    pub simp_tris: u32,
    /// Children: `Store::children[first_child..][..child_count]`.
    pub first_child: u32,
    pub child_count: u32,
    /// Parents: `Store::parents[first_parent..][..parent_count]`.
    pub first_parent: u32,
    pub parent_count: u32,
    /// Which of its level's pack files holds the payload: 0 the store's
    /// own `level-L.pack`, p > 0 `level-L.part-p.pack` (a shard's pack,
    /// linked in place by `merge`).
    pub part: u32,
    /// Added (wrapping) to the payload's patch child ids to give store
    /// ids: a shard's payloads name children by the shard's own ids, and
    /// the merge keeps the bytes as they are (0 in every other store).
    pub patch_shift: u32,
}

impl NodeRec {
    /// Appends the record's [`NODE_REC`] bytes (the layout in
    /// `docs/store-format.md`); the shard state stores records this way too.
    pub fn encode(&self, b: &mut Vec<u8>) {
        let at = b.len();
        b.extend_from_slice(&[self.level, 0, 0, 0]);
        put_aabb(b, &self.cell);
        put_aabb(b, &self.bounds);
        b.extend_from_slice(&self.error.to_le_bytes());
        b.extend_from_slice(&self.offset.to_le_bytes());
        let w = [self.bytes, self.tris, self.verts, self.crc, self.first_child, self.child_count, self.first_parent, self.parent_count, self.simp_tris];
        for x in w.into_iter().chain([self.part, self.patch_shift]) {
            b.extend_from_slice(&x.to_le_bytes());
        }
        debug_assert!(b.len() - at <= NODE_REC);
        b.resize(at + NODE_REC, 0);
    }

    /// Decodes the record at the start of `b` (at least [`NODE_REC`] bytes).
    pub fn decode(b: &[u8]) -> NodeRec {
        let u32_at = |o: usize| u32::from_le_bytes(b[o..o + 4].try_into().unwrap());
        let f64_at = |o: usize| f64::from_le_bytes(b[o..o + 8].try_into().unwrap());
        let aabb = |o: usize| Aabb { min: [f64_at(o), f64_at(o + 8), f64_at(o + 16)], max: [f64_at(o + 24), f64_at(o + 32), f64_at(o + 40)] };
        let w = |k: usize| u32_at(112 + 4 * k);
        NodeRec {
            level: b[0],
            cell: aabb(4),
            bounds: aabb(52),
            error: f32::from_le_bytes(b[100..104].try_into().unwrap()),
            offset: u64::from_le_bytes(b[104..112].try_into().unwrap()),
            bytes: w(0),
            tris: w(1),
            verts: w(2),
            crc: w(3),
            first_child: w(4),
            child_count: w(5),
            first_parent: w(6),
            parent_count: w(7),
            simp_tris: w(8),
            part: w(9),
            patch_shift: w(10),
        }
    }
}

/// Bytes of a [`NodeRec`] in `nodes.bin` and in a shard's state.
pub const NODE_REC: usize = 160;

/// One patch of a node: the triangles `first..first + count` came from `child`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Patch {
    pub child: u32,
    pub first: u32,
    pub count: u32,
}

/// A decoded payload.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct NodeMesh {
    pub mesh: IndexedMesh,
    pub patches: Vec<Patch>,
}

/// Encodes a payload (layout: `docs/store-format.md`). `patches` are (child, count) in order.
pub fn encode_payload(layout: &VertexLayout, m: &IndexedMesh, patches: &[(u32, u32)], out: &mut Vec<u8>) {
    out.clear();
    let nv = m.vertices.len();
    // Its exact size up front: grown by doubling, the payload was copied
    // over a few times.
    out.reserve(16 + 8 * patches.len() + nv * layout.size + 3 * m.triangles.len() * index_width(nv));
    for x in [nv as u32, m.triangles.len() as u32, index_width(nv) as u32, patches.len() as u32] {
        out.extend_from_slice(&x.to_le_bytes());
    }
    for &(c, n) in patches {
        out.extend_from_slice(&c.to_le_bytes());
        out.extend_from_slice(&n.to_le_bytes());
    }
    let at = out.len();
    out.resize(at + m.vertices.len() * layout.size, 0);
    for (k, v) in m.vertices.iter().enumerate() {
        layout.encode(v, &mut out[at + k * layout.size..]);
    }
    push_indices(out, nv, m.triangles.iter().flatten().copied());
}

/// Bytes of a vertex index in a mesh of `nv` vertices, as payloads and the
/// LOD builder's chunks store them: 2 while every index fits a `u16`, else 4.
pub fn index_width(nv: usize) -> usize {
    if nv > u16::MAX as usize {
        4
    } else {
        2
    }
}

/// Appends vertex indices of a mesh of `nv` vertices, [`index_width`]
/// bytes each, little-endian.
pub fn push_indices(out: &mut Vec<u8>, nv: usize, ids: impl Iterator<Item = u32>) {
    if index_width(nv) == 2 {
        for i in ids {
            out.extend_from_slice(&(i as u16).to_le_bytes());
        }
    } else {
        for i in ids {
            out.extend_from_slice(&i.to_le_bytes());
        }
    }
}

/// Index `k` of indices written `width` bytes each ([`push_indices`]).
#[inline]
pub fn index_at(b: &[u8], width: usize, k: usize) -> u32 {
    let o = k * width;
    if width == 4 {
        u32::from_le_bytes(b[o..o + 4].try_into().unwrap())
    } else {
        u16::from_le_bytes(b[o..o + 2].try_into().unwrap()) as u32
    }
}

/// Decodes a payload, checking every count, index and coordinate; errors
/// name the pack file and offset.
pub fn decode_payload(layout: &VertexLayout, b: &[u8], file: &Path, offset: u64) -> Result<NodeMesh> {
    let bad = |msg: String| Error::input(Location { file: file.to_path_buf(), offset: Some(offset), ..Default::default() }, msg);
    if b.len() < 16 {
        return Err(bad("payload shorter than its header".into()));
    }
    let u = |o: usize| u32::from_le_bytes(b[o..o + 4].try_into().unwrap()) as usize;
    let (nv, nt, isz, np) = (u(0), u(4), u(8), u(12));
    if isz != 2 && isz != 4 {
        return Err(bad("payload index size is neither 2 nor 4".into()));
    }
    let need = (np as u64) * 8 + (nv as u64) * layout.size as u64 + (nt as u64) * 3 * isz as u64 + 16;
    if (b.len() as u64) < need {
        return Err(bad(format!("payload truncated: {} bytes, its counts need {need}", b.len())));
    }
    let mut patches = Vec::with_capacity(np);
    let mut first = 0u64;
    for p in 0..np {
        let (child, count) = (u(16 + 8 * p) as u32, u(20 + 8 * p) as u32);
        patches.push(Patch { child, first: first as u32, count });
        first += count as u64;
    }
    if first != nt as u64 {
        return Err(bad(format!("patches hold {first} triangles, the payload {nt}")));
    }
    let vb = 16 + 8 * np;
    let mut vertices = Vec::with_capacity(nv);
    for k in 0..nv {
        let v = layout.decode(&b[vb + k * layout.size..]);
        if !v.pos.iter().all(|x| x.is_finite()) {
            return Err(bad(format!("vertex {k} has a non-finite coordinate")));
        }
        vertices.push(v);
    }
    let ib = &b[vb + nv * layout.size..];
    let mut triangles = Vec::with_capacity(nt);
    for t in 0..nt {
        let mut tri = [0u32; 3];
        for (c, i) in tri.iter_mut().enumerate() {
            *i = index_at(ib, isz, 3 * t + c);
            if *i as usize >= nv {
                return Err(bad(format!("triangle {t} index {} out of range ({nv} vertices)", *i)));
            }
        }
        triangles.push(tri);
    }
    Ok(NodeMesh { mesh: IndexedMesh { vertices, triangles }, patches })
}

/// Turns a payload's patch child ids into store ids ([`NodeRec::patch_shift`]).
pub fn shift_patches(patches: &mut [Patch], shift: u32) {
    for p in patches.iter_mut().filter(|p| p.child != NO_NODE) {
        p.child = p.child.wrapping_add(shift);
    }
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
        let len = u32::try_from(payload.len()).map_err(|_| Error::Usage(format!("{}: a node payload over 4 GiB", self.path.display())))?;
        self.w.write_all(payload).ctx(&self.path, "write pack file")?;
        self.pos += payload.len() as u64;
        Ok((off, len))
    }
    /// Flushes the pack (not synced: see [`sync_packs`]); returns its size.
    pub fn finish(self) -> Result<u64> {
        self.w.into_inner().map_err(|e| e.into_error()).ctx(&self.path, "write pack file")?;
        Ok(self.pos)
    }
}

/// Syncs the pack files of levels `0..levels` in `dir` to disk: once, when
/// every level is written, so no level waits for its own pack's writeback
/// (the kernel writes each back while the next levels are built). Done
/// before the index that makes the store readable, so a store that opens
/// has its payload on disk. (No slower than syncing each pack when
/// complete: `docs/build-costs.md`, "Syncs".)
pub fn sync_packs(dir: &Path, nodes: &[NodeRec]) -> Result<()> {
    for (level, part) in packs_of(nodes) {
        let path = pack_file_part(dir, level, part);
        File::open(&path).ctx(&path, "open pack file")?.sync_all().ctx(&path, "sync")?;
    }
    Ok(())
}

/// The (level, part) pack files `nodes` have payloads in, in order.
pub fn packs_of(nodes: &[NodeRec]) -> std::collections::BTreeSet<(u8, u32)> {
    nodes.iter().map(|n| (n.level, n.part)).collect()
}

/// The format version a store of `nodes` is written as: 2 unless a node
/// uses a field version 3 added.
pub fn format_version(nodes: &[NodeRec]) -> u32 {
    if nodes.iter().any(|n| n.part != 0 || n.patch_shift != 0) {
        VERSION
    } else {
        OLDEST
    }
}

/// The pack file of `level` in store directory `dir`.
pub fn pack_file(dir: &Path, level: usize) -> PathBuf {
    dir.join(format!("level-{level}.pack"))
}

/// Pack file `part` of `level` (see [`NodeRec::part`]).
pub fn pack_file_part(dir: &Path, level: u8, part: u32) -> PathBuf {
    if part == 0 {
        pack_file(dir, level as usize)
    } else {
        dir.join(pack_part_name(level, part))
    }
}

/// The name of pack file `part` > 0 of `level`.
pub fn pack_part_name(level: u8, part: u32) -> String {
    format!("level-{level}.part-{part}.pack")
}

/// Header bytes 36..40 of `nodes.bin`: the highest part number any node
/// uses (0 when every payload is in the store's own packs).
pub const HEADER_PARTS_AT: usize = 36;
/// The most pack parts per level a store may have.
pub const MAX_PARTS: u32 = 1 << 16;

fn put_aabb(b: &mut Vec<u8>, a: &Aabb) {
    for v in a.min.iter().chain(a.max.iter()) {
        b.extend_from_slice(&v.to_le_bytes());
    }
}

/// Writes `nodes.bin`.
pub fn write_index(dir: &Path, h: &StoreHeader, nodes: &[NodeRec], children: &[u32], parents: &[u32]) -> Result<()> {
    let path = dir.join("nodes.bin");
    let mut b = Vec::with_capacity(HEADER + nodes.len() * NODE_REC + 4 * (children.len() + parents.len()));
    b.extend_from_slice(&MAGIC);
    for x in [format_version(nodes), h.attrs.0, if h.derived_normals { FLAG_DERIVED_NORMALS } else { 0 }, h.levels] {
        b.extend_from_slice(&x.to_le_bytes());
    }
    b.extend_from_slice(&(nodes.len() as u64).to_le_bytes());
    b.extend_from_slice(&h.root.to_le_bytes());
    b.extend_from_slice(&nodes.iter().map(|n| n.part).max().unwrap_or(0).to_le_bytes());
    b.extend_from_slice(&h.store_id.to_le_bytes());
    b.extend_from_slice(&(children.len() as u64).to_le_bytes());
    b.extend_from_slice(&(parents.len() as u64).to_le_bytes());
    put_aabb(&mut b, &h.bbox);
    b.resize(HEADER, 0);
    for n in nodes {
        n.encode(&mut b);
    }
    for &c in children.iter().chain(parents) {
        b.extend_from_slice(&c.to_le_bytes());
    }
    let mut f = File::create(&path).ctx(&path, "create")?;
    f.write_all(&b).ctx(&path, "write")?;
    f.sync_all().ctx(&path, "sync")
}

/// An opened store: the index in memory, payloads read on demand.
pub struct Store {
    /// No output of this process replaces the directory while it is open.
    _protect: crate::io::Protected,
    /// Pack files, opened once when the store is opened: a store rewritten
    /// in place later (`build --force` swaps the directory) cannot mix its
    /// new payloads into this reader's old index.
    packs: std::collections::BTreeMap<(u8, u32), File>,
    pub dir: PathBuf,
    pub header: StoreHeader,
    pub nodes: Vec<NodeRec>,
    pub children: Vec<u32>,
    pub parents: Vec<u32>,
    /// Layout of the input's attributes (what extract writes).
    pub layout: VertexLayout,
    /// Layout of payload vertices (input attributes + derived normals).
    pub payload_layout: VertexLayout,
}

impl Store {
    /// Opens and validates the index (see `validate`).
    pub fn open(dir: &Path) -> Result<Store> {
        let path = dir.join("nodes.bin");
        let (mut f, len) = crate::io::open_regular(&path, "open store index")?;
        let bad = |msg: String| Error::input(Location { file: path.clone(), ..Default::default() }, msg);
        // The header first: the sizes it declares are checked against the
        // files (the index's length, the packs' pages) before the index is
        // read, so a damaged or sparse index never sizes an allocation.
        let mut b = vec![0u8; HEADER];
        if len < HEADER as u64 || f.read_exact(&mut b).is_err() || b[..8] != MAGIC {
            return Err(bad("not an octolod store index (bad magic)".into()));
        }
        let u32_at = |o: usize| u32::from_le_bytes(b[o..o + 4].try_into().unwrap());
        let u64_at = |o: usize| u64::from_le_bytes(b[o..o + 8].try_into().unwrap());
        let f64_at = |o: usize| f64::from_le_bytes(b[o..o + 8].try_into().unwrap());
        let aabb = |o: usize| Aabb { min: [f64_at(o), f64_at(o + 8), f64_at(o + 16)], max: [f64_at(o + 24), f64_at(o + 32), f64_at(o + 40)] };
        let version = u32_at(8);
        if !(OLDEST..=VERSION).contains(&version) {
            return Err(bad(format!(
                "store format version {version}; this octolod reads versions {OLDEST} to {VERSION}: rebuild the store with `octolod build`{}",
                if version < OLDEST { " (levels of detail v2 changed the format)" } else { " of this version" }
            )));
        }
        let parts = u32_at(HEADER_PARTS_AT);
        if parts > MAX_PARTS || (version < 3 && parts != 0) {
            return Err(bad(format!("{parts} pack parts declared (a version {version} store has 0 to {})", if version < 3 { 0 } else { MAX_PARTS })));
        }
        let attrs = AttrSet::from_bits(u32_at(12)).ok_or_else(|| bad("unknown attribute bits".into()))?;
        let flags = u32_at(16);
        let n = u64_at(24);
        let (nc, np) = (u64_at(48), u64_at(56));
        let expect = (n.checked_mul(NODE_REC as u64))
            .and_then(|x| x.checked_add(HEADER as u64))
            .and_then(|x| nc.checked_add(np).and_then(|l| l.checked_mul(4)).and_then(|l| x.checked_add(l)));
        if expect != Some(len) {
            return Err(bad(format!("index holds {len} bytes, its header declares {n} nodes and {nc} + {np} links")));
        }
        let levels = u32_at(20);
        if levels == 0 || levels > 256 {
            return Err(bad(format!("{levels} levels declared (a store has 1 to 256)")));
        }
        if len > MAX_INDEX {
            return Err(bad(format!("an index of {len} bytes: larger than any store octolod builds ({MAX_INDEX} bytes)")));
        }
        let n = n as usize;
        let header = StoreHeader {
            attrs,
            derived_normals: flags & FLAG_DERIVED_NORMALS != 0,
            levels,
            nodes: n as u64,
            root: u32_at(32),
            store_id: u64_at(40),
            bbox: aabb(64),
        };
        b.resize(len as usize, 0);
        f.read_exact(&mut b[HEADER..]).ctx(&path, "read")?;
        let u32_at = |o: usize| u32::from_le_bytes(b[o..o + 4].try_into().unwrap());
        let nodes: Vec<NodeRec> = (0..n).map(|i| NodeRec::decode(&b[HEADER + i * NODE_REC..])).collect();
        if let Some((i, r)) = nodes.iter().enumerate().find(|(_, r)| r.part > parts || (version < 3 && r.patch_shift != 0)) {
            return Err(bad(format!("node {i}: pack part {} or patch shift {} beyond what the header declares", r.part, r.patch_shift)));
        }
        // Every payload starts a page of its pack.
        let mut packs = std::collections::BTreeMap::new();
        let mut pages = 0u64;
        for (level, part) in packs_of(&nodes) {
            let p = pack_file_part(dir, level, part);
            let (f, plen) = crate::io::open_regular(&p, "open pack file")?;
            pages += plen.div_ceil(PAGE);
            packs.insert((level, part), f);
        }
        if n as u64 > pages {
            return Err(bad(format!("{n} nodes declared, but the packs hold only {pages} pages (each payload starts one)")));
        }
        let lists = HEADER + n * NODE_REC;
        let list = |from: usize, len: u64| (0..len as usize).map(|k| u32_at(from + 4 * k)).collect::<Vec<u32>>();
        let children = list(lists, nc);
        let parents = list(lists + 4 * nc as usize, np);
        let payload_attrs = attrs.with(AttrSet::NORMAL, attrs.normal() || header.derived_normals);
        let mut s = Store {
            _protect: crate::io::protect(dir),
            packs: std::collections::BTreeMap::new(),
            dir: dir.to_path_buf(),
            layout: VertexLayout::new(attrs),
            payload_layout: VertexLayout::new(payload_attrs),
            header,
            nodes,
            children,
            parents,
        };
        s.validate().map_err(bad)?;
        s.packs = packs;
        s.check_pack_ranges()?;
        Ok(s)
    }

    /// Every node's payload lies inside its level's pack file (so no read
    /// asks for more than the file holds, whatever the record says).
    fn check_pack_ranges(&self) -> Result<()> {
        let mut len = std::collections::BTreeMap::new();
        for (&k, f) in &self.packs {
            len.insert(k, f.metadata().ctx(pack_file_part(&self.dir, k.0, k.1), "open pack file")?.len());
        }
        for (i, n) in self.nodes.iter().enumerate() {
            // The record's counts give the payload's exact size (see the
            // module doc): damaged counts are an error here, not a node no
            // budget can load.
            let patches = if n.level == 0 { 1 } else { n.child_count as u64 };
            let want = 16 + 8 * patches + n.verts as u64 * self.payload_layout.size as u64 + 3 * n.tris as u64 * index_width(n.verts as usize) as u64;
            if want != n.bytes as u64 {
                return Err(Error::input(
                    Location { file: self.dir.join("nodes.bin"), ..Default::default() },
                    format!(
                        "node {i}: its record's {} vertices, {} triangles and {patches} patches need a payload of {want} bytes, the record says {}",
                        n.verts, n.tris, n.bytes
                    ),
                ));
            }
            let have = len[&(n.level, n.part)];
            if n.offset.checked_add(n.bytes as u64).is_none_or(|e| e > have) {
                return Err(Error::input(
                    Location { file: self.pack_path_of(i), offset: Some(n.offset), ..Default::default() },
                    format!("node {i}: payload of {} bytes at {} lies beyond the pack file's {have} bytes", n.bytes, n.offset),
                ));
            }
        }
        Ok(())
    }

    /// Checks the index: ids and list ranges in range, children one level
    /// finer and listing the node as parent (and the converse), levels at
    /// most the top, the top level's nodes and only they without parents
    /// (so every node reaches a root), finite bounds and errors, errors
    /// and bounds monotone (a parent's error ≥ and bounds ⊇ each child's).
    fn validate(&self) -> std::result::Result<(), String> {
        let n = self.nodes.len();
        if n == 0 {
            return Err("the store has no nodes".into());
        }
        if self.header.root as usize != n - 1 {
            return Err(format!("root {} is not the last node ({})", self.header.root, n - 1));
        }
        let b = &self.header.bbox;
        if !(b.min.iter().chain(&b.max).all(|x| x.is_finite()) && (0..3).all(|k| b.min[k] <= b.max[k])) {
            return Err(format!("the input's bounding box {:?} .. {:?} is not a finite, non-empty box", b.min, b.max));
        }
        let top = self.header.levels.checked_sub(1).ok_or("zero levels")?;
        for (i, nd) in self.nodes.iter().enumerate() {
            let range_ok = |first: u32, count: u32, len: usize| (first as u64 + count as u64) <= len as u64;
            if !range_ok(nd.first_child, nd.child_count, self.children.len()) || !range_ok(nd.first_parent, nd.parent_count, self.parents.len()) {
                return Err(format!("node {i}: children or parents list out of range"));
            }
            if nd.level as u32 > top {
                return Err(format!("node {i}: level {} above the top level {top}", nd.level));
            }
            if (nd.level as u32 == top) != (nd.parent_count == 0) {
                return Err(format!("node {i}: the top level's nodes (the roots) and only they have no parent"));
            }
            if !(nd.error.is_finite() && nd.error >= 0.0 && aabb_finite(&nd.bounds)) {
                return Err(format!("node {i}: non-finite error or bounds"));
            }
            for &c in self.children_of(i) {
                let c = c as usize;
                let ch = self.nodes.get(c).ok_or_else(|| format!("node {i}: child {c} out of range"))?;
                if ch.level as u32 + 1 != nd.level as u32 {
                    return Err(format!("node {i} (level {}): child {c} is at level {}", nd.level, ch.level));
                }
                if !self.parents_of(c).contains(&(i as u32)) {
                    return Err(format!("node {i}: child {c} does not list it as a parent"));
                }
                if ch.error > nd.error {
                    return Err(format!("node {i}: error {} below its child {c}'s {}", nd.error, ch.error));
                }
                if !ch.bounds.is_empty() && (0..3).any(|k| ch.bounds.min[k] < nd.bounds.min[k] || ch.bounds.max[k] > nd.bounds.max[k]) {
                    return Err(format!("node {i}: bounds do not contain its child {c}'s"));
                }
            }
            for &p in self.parents_of(i) {
                let pn = self.nodes.get(p as usize).ok_or_else(|| format!("node {i}: parent {p} out of range"))?;
                // pn is not validated yet (it may come later): widen before adding.
                let range = pn.first_child as usize..pn.first_child as usize + pn.child_count as usize;
                if !self.children.get(range).is_some_and(|l| l.contains(&(i as u32))) {
                    return Err(format!("node {i}: parent {p} does not list it as a child"));
                }
            }
        }
        Ok(())
    }

    /// The last node, a root (the only one unless `--levels` stopped early).
    pub fn root(&self) -> usize {
        self.header.root as usize
    }

    /// The top level's nodes: every selection holds them.
    pub fn roots(&self) -> Vec<usize> {
        let top = self.top_level();
        (0..self.nodes.len()).filter(|&i| self.nodes[i].level == top).collect()
    }

    /// The highest level (the root's).
    pub fn top_level(&self) -> u8 {
        self.nodes[self.root()].level
    }

    pub fn children_of(&self, i: usize) -> &[u32] {
        let n = &self.nodes[i];
        &self.children[n.first_child as usize..n.first_child as usize + n.child_count as usize]
    }

    pub fn parents_of(&self, i: usize) -> &[u32] {
        let n = &self.nodes[i];
        &self.parents[n.first_parent as usize..n.first_parent as usize + n.parent_count as usize]
    }

    /// The pack file holding node `id`'s payload.
    pub fn pack_path_of(&self, id: usize) -> PathBuf {
        let n = &self.nodes[id];
        pack_file_part(&self.dir, n.level, n.part)
    }

    /// Reads node `id`'s payload with one positioned read, checking its CRC.
    pub fn read_node(&self, id: usize) -> Result<NodeMesh> {
        let n = &self.nodes[id];
        let bytes = read_at(&self.packs[&(n.level, n.part)], &self.pack_path_of(id), n.offset, n.bytes)?;
        self.decode_node(id, &bytes)
    }

    /// Decodes node `id`'s payload bytes (read by the caller), checking the
    /// CRC and that the counts match the node record.
    pub fn decode_node(&self, id: usize, bytes: &[u8]) -> Result<NodeMesh> {
        let n = &self.nodes[id];
        let path = self.pack_path_of(id);
        let bad = |msg: String| Error::input(Location { file: path.clone(), offset: Some(n.offset), ..Default::default() }, format!("node {id}: {msg}"));
        if crc32c::crc32c(bytes) != n.crc {
            return Err(bad("payload checksum mismatch (the store is damaged or was rewritten)".into()));
        }
        let mut m = decode_payload(&self.payload_layout, bytes, &path, n.offset)?;
        shift_patches(&mut m.patches, n.patch_shift);
        if m.mesh.vertices.len() != n.verts as usize || m.mesh.triangles.len() != n.tris as usize {
            return Err(bad(format!(
                "payload holds {} vertices and {} triangles, the index says {} and {}",
                m.mesh.vertices.len(),
                m.mesh.triangles.len(),
                n.verts,
                n.tris
            )));
        }
        let kids = self.children_of(id);
        let expect_child = |k: usize| if n.level == 0 { NO_NODE } else { kids[k] };
        if m.patches.len() != if n.level == 0 { 1 } else { kids.len() } || m.patches.iter().enumerate().any(|(k, p)| p.child != expect_child(k)) {
            return Err(bad("payload patches do not match the node's children".into()));
        }
        Ok(m)
    }

    /// Nodes of the whole level `level`.
    pub fn level_nodes(&self, level: u8) -> Vec<usize> {
        (0..self.nodes.len()).filter(|&i| self.nodes[i].level == level).collect()
    }

    /// Triangles of the whole level `level`.
    pub fn level_triangles(&self, level: u8) -> u64 {
        self.nodes.iter().filter(|n| n.level == level).map(|n| n.tris as u64).sum()
    }

    /// A usage error unless the store has `level`.
    pub fn check_level(&self, level: u8) -> Result<()> {
        let top = self.top_level();
        if level > top {
            return Err(Error::Usage(format!("the store has levels 0..={top}; level {level} does not exist")));
        }
        Ok(())
    }

    /// The whole level `level` as a cut (every node of level ≥ `level`).
    pub fn level_cut(&self, level: u8) -> Cut {
        let selected: Vec<bool> = self.nodes.iter().map(|n| n.level >= level).collect();
        Cut::from_selected(self, selected)
    }

    /// The whole level `level` in memory, as metro measures it: its cut's
    /// node meshes concatenated in cut order, bit-identical positions
    /// welded (numbered in the order of first appearance), attributes
    /// dropped. A usage error for a level the store lacks; an input error
    /// for an empty level.
    pub fn level_mesh(&self, level: u8) -> Result<Mesh> {
        self.check_level(level)?;
        let loc = |file: PathBuf| Location { file, ..Default::default() };
        let mut mesh = Mesh::default();
        let mut weld = crate::geom::Welder::default();
        for i in self.level_nodes(level) {
            let m = self.read_node(i)?.mesh;
            let ids: Vec<u32> = m.vertices.iter().map(|v| weld.id(v.pos, |p| mesh.positions.push(p))).collect();
            for t in &m.triangles {
                if t.iter().any(|&k| k as usize >= ids.len()) {
                    return Err(Error::input(loc(self.pack_path_of(i)), format!("node {i}: vertex index out of range")));
                }
                mesh.triangles.push(t.map(|k| ids[k as usize]));
            }
        }
        if mesh.triangles.is_empty() {
            return Err(Error::input(loc(self.dir.clone()), format!("level {level} has no triangles to measure")));
        }
        Ok(mesh)
    }

    /// The meshes `cut` draws, node by node (the drawn patches of each).
    pub fn cut_meshes<'a>(&'a self, cut: &'a Cut) -> impl Iterator<Item = Result<IndexedMesh>> + 'a {
        // Each node is a safe point for signals (extract, metro, simplify).
        cut.drawn.iter().map(move |&i| crate::io::signal::check().and_then(|()| self.read_node(i)).map(|nm| cut.drawn_mesh(&nm)))
    }

    /// The cut at object-space error `e` (see the module doc).
    pub fn error_cut(&self, e: f64) -> Cut {
        let mut selected = vec![false; self.nodes.len()];
        for r in self.roots() {
            selected[r] = true;
        }
        // Parents have higher ids (levels are numbered upward), so one pass
        // from the top down sees every parent before its children.
        for i in (0..self.nodes.len()).rev() {
            if !selected[i] && self.parents_of(i).iter().any(|&p| self.nodes[p as usize].error as f64 > e) {
                self.select_with_ancestors(i, &mut selected);
            }
        }
        Cut::from_selected(self, selected)
    }

    /// Adds `i` and every missing ancestor to `selected`.
    pub fn select_with_ancestors(&self, i: usize, selected: &mut [bool]) {
        let mut stack = vec![i];
        while let Some(j) = stack.pop() {
            if !selected[j] {
                selected[j] = true;
                stack.extend(self.parents_of(j).iter().map(|&p| p as usize).filter(|&p| !selected[p]));
            }
        }
    }
}

fn aabb_finite(b: &Aabb) -> bool {
    b.is_empty() || b.min.iter().chain(b.max.iter()).all(|x| x.is_finite())
}

/// Reads `bytes` at `offset` of the open pack `f` (named `path` in errors)
/// with one positioned read.
fn read_at(f: &File, path: &Path, offset: u64, bytes: u32) -> Result<Vec<u8>> {
    use std::os::unix::fs::FileExt;
    let mut b = vec![0u8; bytes as usize];
    f.read_exact_at(&mut b, offset).ctx(path, "read pack file")?;
    Ok(b)
}

/// A valid cut of a store: the selected nodes and, per selected node, which
/// of its patches it draws.
#[derive(Clone, Debug)]
pub struct Cut {
    pub selected: Vec<bool>,
    /// (node, draws every patch) for the selected nodes that draw something.
    pub drawn: Vec<usize>,
}

impl Cut {
    pub fn from_selected(store: &Store, selected: Vec<bool>) -> Cut {
        let drawn = (0..store.nodes.len())
            .filter(|&i| selected[i] && (store.nodes[i].level == 0 || store.children_of(i).iter().any(|&c| !selected[c as usize])))
            .collect();
        Cut { selected, drawn }
    }

    /// Whether node `i` draws its patch from `child` in this cut.
    pub fn draws(&self, child: u32) -> bool {
        child == NO_NODE || !self.selected[child as usize]
    }

    /// Triangles the cut draws: every selected node's, less, for each
    /// selected node but the roots, its simplified mesh (the patches its
    /// parents, all selected, no longer draw).
    pub fn triangles(&self, store: &Store) -> u64 {
        (0..store.nodes.len())
            .filter(|&i| self.selected[i])
            .map(|i| store.nodes[i].tris as i64 - if store.nodes[i].parent_count == 0 { 0 } else { store.nodes[i].simp_tris as i64 })
            .sum::<i64>()
            .max(0) as u64
    }

    /// The part of node `i`'s mesh this cut draws: its vertices (all) and
    /// the triangles of the drawn patches.
    pub fn drawn_mesh(&self, nm: &NodeMesh) -> IndexedMesh {
        let mut out = IndexedMesh { vertices: nm.mesh.vertices.clone(), triangles: Vec::new() };
        for p in &nm.patches {
            if self.draws(p.child) {
                out.triangles.extend_from_slice(&nm.mesh.triangles[p.first as usize..(p.first + p.count) as usize]);
            }
        }
        out
    }
}

/// Largest `nodes.bin` read: 2.6 × 10^7 nodes, a store of some 10^11
/// triangles (the index is read whole).
const MAX_INDEX: u64 = 4 << 30;

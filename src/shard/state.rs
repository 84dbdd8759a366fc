//! A built shard on disk: `shard.state` (binary, little-endian: what the
//! merge resumes from), `shard.json` (the same for people, with the level
//! reports), `chunks.bin` (its top level's chunks) and `level-L.pack` for
//! the levels it built.
//!
//! `shard.state`: magic `OCTSHARD`, u32 version, u64 plan id (byte 12),
//! u32 shard (byte 20), u8 next level (byte 24), u32 attributes, u32 carried
//! values per chunk vertex, the box (6 × f64), u64 triangles of the whole
//! input and of the shard, u64 leaf scale; then the leaves (path, depth,
//! triangles, bounds, reach), the chunks (target, offset, bytes), the nodes
//! (record, measured error, children), the octree report's counts (no
//! timing: a shard rebuilt is byte-identical). Floats are
//! written as their bits, so the merge resumes from exactly what the shard
//! left.

use crate::error::{Error, IoContext, Location, Result};
use crate::io::SHARD_MAGIC;
use crate::lod::chunks::ChunkRef;
use crate::lod::level::Paused;
use crate::lod::octree::OctreeReport;
use crate::lod::LeafStats;
use crate::manifest::LevelReport;
use crate::mesh::{Aabb, AttrSet};
use crate::store::{NodeRec, NODE_REC};
use std::path::{Path, PathBuf};

const VERSION: u32 = 2;
/// Largest `shard.state` read.
const MAX_STATE: u64 = 4 << 30;

/// What a shard's files say of it, apart from its chunk file.
pub struct ShardState {
    pub plan_id: u64,
    pub shard: u32,
    pub attrs: AttrSet,
    pub a_len: u32,
    pub bbox: Aabb,
    /// Triangles of the whole input, and of this shard.
    pub input_triangles: u64,
    pub triangles: u64,
    /// The level the shard stopped before, with everything below it.
    pub level: u8,
    pub tiling: Vec<(u64, u8)>,
    pub leaves: Vec<LeafStats>,
    pub refs: Vec<ChunkRef>,
    pub nodes: Vec<NodeRec>,
    pub children: Vec<Vec<u32>>,
    pub simp_err: Vec<f64>,
    pub leaf_scale: u64,
    pub octree: OctreeReport,
    pub reports: Vec<LevelReport>,
}

/// `shard.json`: the shard for people (and the Ray driver).
#[derive(serde::Serialize, serde::Deserialize)]
pub struct ShardJson {
    pub format: String,
    pub plan_id: String,
    pub shard: u32,
    pub complete: bool,
    pub triangles: u64,
    /// Positions locked because another shard holds them too.
    pub boundary_positions: u64,
    pub levels: Vec<LevelReport>,
    pub nodes: u64,
    pub seconds: f64,
}

struct Enc(Vec<u8>);

impl Enc {
    fn u8(&mut self, x: u8) {
        self.0.push(x);
    }
    fn u32(&mut self, x: u32) {
        self.0.extend_from_slice(&x.to_le_bytes());
    }
    fn u64(&mut self, x: u64) {
        self.0.extend_from_slice(&x.to_le_bytes());
    }
    fn f64(&mut self, x: f64) {
        self.u64(x.to_bits());
    }
    fn aabb(&mut self, b: &Aabb) {
        for x in b.min.iter().chain(&b.max) {
            self.f64(*x);
        }
    }
}

struct Dec<'a> {
    b: &'a [u8],
    at: usize,
    file: &'a Path,
}

impl Dec<'_> {
    fn take(&mut self, n: usize) -> Result<&[u8]> {
        if self.b.len() - self.at < n {
            return Err(Error::input(Location { file: self.file.to_path_buf(), offset: Some(self.at as u64), ..Default::default() }, "shard state ends early"));
        }
        self.at += n;
        Ok(&self.b[self.at - n..self.at])
    }
    fn u8(&mut self) -> Result<u8> {
        Ok(self.take(1)?[0])
    }
    fn u32(&mut self) -> Result<u32> {
        Ok(u32::from_le_bytes(self.take(4)?.try_into().unwrap()))
    }
    fn u64(&mut self) -> Result<u64> {
        Ok(u64::from_le_bytes(self.take(8)?.try_into().unwrap()))
    }
    fn f64(&mut self) -> Result<f64> {
        Ok(f64::from_bits(self.u64()?))
    }
    fn aabb(&mut self) -> Result<Aabb> {
        let v: Vec<f64> = (0..6).map(|_| self.f64()).collect::<Result<_>>()?;
        Ok(Aabb { min: [v[0], v[1], v[2]], max: [v[3], v[4], v[5]] })
    }
    /// A count of items of at least `each` bytes that must fit the rest.
    fn count(&mut self, each: usize) -> Result<usize> {
        let n = self.u64()?;
        if n > ((self.b.len() - self.at) / each.max(1)) as u64 {
            return Err(Error::input(
                Location { file: self.file.to_path_buf(), offset: Some(self.at as u64), ..Default::default() },
                format!("a count of {n} does not fit the shard state"),
            ));
        }
        Ok(n as usize)
    }
}

impl ShardState {
    /// Encodes the state.
    fn encode(&self) -> Vec<u8> {
        let mut e = Enc(Vec::new());
        e.0.extend_from_slice(&SHARD_MAGIC);
        e.u32(VERSION);
        e.u64(self.plan_id);
        e.u32(self.shard);
        e.u8(self.level);
        e.u32(self.attrs.0);
        e.u32(self.a_len);
        e.aabb(&self.bbox);
        e.u64(self.input_triangles);
        e.u64(self.triangles);
        e.u64(self.leaf_scale);
        e.u64(self.tiling.len() as u64);
        for ((path, depth), l) in self.tiling.iter().zip(&self.leaves) {
            e.u64(*path);
            e.u8(*depth);
            e.u64(l.tris);
            e.aabb(&l.bounds);
            e.f64(l.reach);
        }
        e.u64(self.refs.len() as u64);
        for r in &self.refs {
            e.u32(r.target);
            e.u64(r.offset);
            e.u32(r.bytes);
        }
        e.u64(self.nodes.len() as u64);
        for ((n, kids), err) in self.nodes.iter().zip(&self.children).zip(&self.simp_err) {
            n.encode(&mut e.0);
            e.f64(*err);
            e.u64(kids.len() as u64);
            for &c in kids {
                e.u32(c);
            }
        }
        let o = &self.octree;
        for x in [o.leaves, o.deepest as u64, o.overfull_leaves, o.counting_passes as u64, o.chunks, o.chunk_bytes] {
            e.u64(x);
        }
        // No timing: a shard rebuilt from scratch is byte-identical.
        e.0
    }

    fn decode(b: &[u8], file: &Path) -> Result<ShardState> {
        let mut d = Dec { b, at: 0, file };
        let bad = |msg: &str| Error::input(Location { file: file.to_path_buf(), ..Default::default() }, msg.to_string());
        if d.take(8)? != SHARD_MAGIC || d.u32()? != VERSION {
            return Err(bad("not an octolod shard state of this version"));
        }
        let (plan_id, shard, level, attrs, a_len) = (d.u64()?, d.u32()?, d.u8()?, AttrSet(d.u32()?), d.u32()?);
        let (bbox, input_triangles, triangles, leaf_scale) = (d.aabb()?, d.u64()?, d.u64()?, d.u64()?);
        let n = d.count(65)?;
        let (mut tiling, mut leaves) = (Vec::with_capacity(n), Vec::with_capacity(n));
        for _ in 0..n {
            tiling.push((d.u64()?, d.u8()?));
            leaves.push(LeafStats { tris: d.u64()?, bounds: d.aabb()?, reach: d.f64()? });
        }
        let n = d.count(16)?;
        let refs = (0..n).map(|_| Ok(ChunkRef { target: d.u32()?, offset: d.u64()?, bytes: d.u32()? })).collect::<Result<Vec<_>>>()?;
        if refs.iter().any(|r| r.target as usize >= tiling.len()) {
            return Err(bad("a chunk targets a leaf the shard does not have"));
        }
        let n = d.count(NODE_REC + 16)?;
        let (mut nodes, mut children, mut simp_err) = (Vec::with_capacity(n), Vec::with_capacity(n), Vec::with_capacity(n));
        for _ in 0..n {
            let rec = NodeRec::decode(d.take(NODE_REC)?);
            simp_err.push(d.f64()?);
            let k = d.count(4)?;
            let kids = (0..k).map(|_| d.u32()).collect::<Result<Vec<_>>>()?;
            if rec.level >= level || rec.part != 0 || kids.iter().any(|&c| c as usize >= nodes.len()) {
                return Err(bad("a node's level, pack or children do not fit the shard"));
            }
            children.push(kids);
            nodes.push(rec);
        }
        let o: Vec<u64> = (0..6).map(|_| d.u64()).collect::<Result<_>>()?;
        let octree = OctreeReport {
            leaves: o[0],
            deepest: o[1] as u8,
            overfull_leaves: o[2],
            counting_passes: o[3] as u32,
            chunks: o[4],
            chunk_bytes: o[5],
            seconds: 0.0,
        };
        if d.at != b.len() {
            return Err(bad("trailing bytes after the shard state"));
        }
        Ok(ShardState {
            plan_id,
            shard,
            attrs,
            a_len,
            bbox,
            input_triangles,
            triangles,
            level,
            tiling,
            leaves,
            refs,
            nodes,
            children,
            simp_err,
            leaf_scale,
            octree,
            reports: Vec::new(),
        })
    }

    /// The state of a paused builder: its chunk file is moved into `dir`.
    #[allow(clippy::too_many_arguments, reason = "the shard's identity and its figures, each distinct")]
    pub fn from_paused(
        p: Paused,
        dir: &Path,
        plan_id: u64,
        shard: u32,
        attrs: AttrSet,
        bbox: Aabb,
        input_triangles: u64,
        triangles: u64,
    ) -> Result<ShardState> {
        let dest = dir.join("chunks.bin");
        std::fs::rename(p.chunks.path(), &dest).ctx(&dest, "move the shard's chunks into")?;
        Ok(ShardState {
            plan_id,
            shard,
            attrs,
            a_len: p.chunks.a_len() as u32,
            bbox,
            input_triangles,
            triangles,
            level: p.level,
            tiling: p.tiling,
            leaves: p.leaves,
            refs: p.chunks.refs().to_vec(),
            nodes: p.nodes,
            children: p.children,
            simp_err: p.simp_err,
            leaf_scale: p.leaf_scale,
            octree: p.octree,
            reports: p.reports,
        })
    }

    /// Writes `shard.state` and `shard.json` into `dir` (synced, with the packs).
    pub fn write(&self, dir: &Path, boundary_positions: u64, seconds: f64) -> Result<()> {
        crate::store::sync_packs(dir, &self.nodes)?;
        let path = dir.join("shard.state");
        write_synced(&path, &self.encode())?;
        let j = ShardJson {
            format: "octolod-shard".into(),
            plan_id: format!("{:016x}", self.plan_id),
            shard: self.shard,
            complete: true,
            triangles: self.triangles,
            boundary_positions,
            levels: self.reports.clone(),
            nodes: self.nodes.len() as u64,
            seconds,
        };
        write_synced(&dir.join("shard.json"), serde_json::to_string_pretty(&j).expect("serializes").as_bytes())
    }

    /// Reads a shard directory's state (and its reports from `shard.json`).
    pub fn read(dir: &Path) -> Result<ShardState> {
        let path = dir.join("shard.state");
        let b = crate::io::read_bounded(&path, MAX_STATE, "a shard state")?;
        let mut s = ShardState::decode(&b, &path)?;
        let jpath = dir.join("shard.json");
        let j: ShardJson = serde_json::from_slice(&crate::io::read_bounded(&jpath, 64 << 20, "a shard report")?)
            .map_err(|e| Error::input(Location { file: jpath.clone(), ..Default::default() }, format!("not a shard report: {e}")))?;
        if !j.complete || j.shard != s.shard || j.plan_id != format!("{:016x}", s.plan_id) {
            return Err(Error::input(Location { file: jpath, ..Default::default() }, "does not match shard.state"));
        }
        s.reports = j.levels;
        Ok(s)
    }

    /// The shard's chunk file.
    pub fn chunks_path(dir: &Path) -> PathBuf {
        dir.join("chunks.bin")
    }
}

fn write_synced(path: &Path, b: &[u8]) -> Result<()> {
    use std::io::Write;
    let mut f = std::fs::File::create(path).ctx(path, "create")?;
    f.write_all(b).ctx(path, "write")?;
    f.sync_all().ctx(path, "sync")
}

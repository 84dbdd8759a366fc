//! `octolod merge PLAN SHARD... -o STORE`: one store from a plan's shards.
//!
//! The shards' nodes are renumbered level by level (the store's nodes are
//! in level order), their level packs concatenated page-aligned into the
//! store's (`copy_file_range`: a reflink on filesystems that have them),
//! and the union of their top levels — each shard's leaves, overlapping
//! cells allowed, and their chunks with targets and sources renumbered —
//! becomes the current level of one level builder, which goes on to the
//! root as a monolithic build does from there: the shards' boundary
//! positions, locked below, are shared positions of the union like any
//! other and simplify from here up.

use super::plan::Plan;
use super::state::ShardState;
use crate::error::{Error, IoContext, Location, Result};
use crate::io::{AtomicDir, OutputKind};
use crate::lod::chunks::ChunkFile;
use crate::lod::level::{LevelBuilder, Paused};
use crate::lod::octree::OctreeReport;
use crate::lod::simplifier::NodeSimplifier;
use crate::lod::{build_levels, with_simplifier, Built, LodOptions, WithSimplifier};
use crate::manifest::{LevelReport, Manifest, ManifestSeconds};
use crate::mesh::VertexLayout;
use crate::soup::format::SoupHeader;
use crate::store::{pack_file, write_index, PAGE};
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// What the merge did.
#[derive(Clone, Debug, serde::Serialize)]
pub struct MergeReport {
    pub shards: usize,
    pub nodes: u64,
    pub levels: usize,
    /// Triangles of the union of the shards' top levels: what the merge simplified.
    pub merged_triangles: u64,
    /// Bytes of the shards' packs copied.
    pub copied_bytes: u64,
    pub seconds: f64,
    pub level_reports: Vec<LevelReport>,
}

/// Merges `shards` (directories, any order) of `plan` into store `out`.
pub fn merge(plan: &Plan, shards: &[PathBuf], out: &Path, mem: u64, quiet: bool, force: bool) -> Result<MergeReport> {
    let t0 = Instant::now();
    let _protect: Vec<_> = shards.iter().map(|d| crate::io::protect(d)).collect();
    let (states, dirs) = read_shards(plan, shards)?;
    let dir = AtomicDir::create(out, OutputKind::Store, force)?;
    let stop = plan.shard_levels;
    let map = renumber(&states, stop);
    let (copied_bytes, pack_base) = concat_packs(&dirs, dir.path(), stop)?;
    let mut states = states;
    renumber_patches(&mut states, &map, &pack_base, dir.path())?;
    let mut lo = LodOptions { params: plan.params.clone(), quiet, ..Default::default() };
    lo.params.mem = mem;
    let scratch = crate::io::scratch_dir(dir.path())?;
    let first = &states[0];
    let chunks = union_chunks(&states, &dirs, &map, scratch.path().join(format!("chunks-{stop}.bin")), stop)?;
    let merged_triangles = states.iter().map(|s| s.leaves.iter().map(|l| l.tris).sum::<u64>()).sum();
    let paused = union_state(&states, &map, &pack_base, chunks, stop);
    let header = SoupHeader {
        attrs: first.attrs,
        triangles: states.iter().map(|s| s.triangles).sum(),
        input_vertices: 0,
        input_faces: 0,
        degenerate: 0,
        bbox: first.bbox,
    };
    let attrs = first.attrs;
    let built = with_simplifier(&lo, attrs, Resume { paused, header, dir: dir.path(), scratch, lo: &lo, stop, id: plan.store_id() })?;
    write_index(dir.path(), &built.header, &built.nodes, &built.children, &built.parents)?;
    let seconds = t0.elapsed().as_secs_f64();
    let disk_bytes = crate::pipeline::dir_bytes(dir.path());
    let manifest = Manifest {
        format: "octolod-store".into(),
        version: crate::store::VERSION,
        input: plan.input.path.clone(),
        attributes: attrs.describe(),
        quadric_dim: attrs.quadric_dim(),
        derived_normals: built.header.derived_normals,
        nodes: built.nodes.len() as u64,
        triangles: header.triangles,
        params: lo.params.clone(),
        seconds: ManifestSeconds { soup: 0.0, partition: 0.0, levels: seconds, total: seconds },
        disk_bytes,
        levels: built.levels.clone(),
    };
    manifest.write(dir.path())?;
    dir.commit()?;
    Ok(MergeReport {
        shards: states.len(),
        nodes: built.nodes.len() as u64,
        levels: built.levels.len(),
        merged_triangles,
        copied_bytes,
        seconds,
        level_reports: built.levels,
    })
}

/// The union's levels from the shards' top up to the root.
struct Resume<'a> {
    paused: Paused,
    header: SoupHeader,
    dir: &'a Path,
    scratch: crate::io::ScratchDir,
    lo: &'a LodOptions,
    stop: u8,
    id: u64,
}

impl WithSimplifier for Resume<'_> {
    type Out = Result<Built>;
    fn run<S: NodeSimplifier>(self, s: S) -> Result<Built> {
        build_levels(LevelBuilder::resume(self.paused, self.header, self.dir, self.scratch, self.lo, s), self.stop, self.id)
    }
}

/// Every shard of the plan, once, complete, of this plan, alike.
fn read_shards(plan: &Plan, dirs: &[PathBuf]) -> Result<(Vec<ShardState>, Vec<PathBuf>)> {
    let n = plan.shards.len();
    let mut by_index: Vec<Option<(ShardState, PathBuf)>> = (0..n).map(|_| None).collect();
    let at = |d: &Path, msg: String| Error::input(Location { file: d.to_path_buf(), ..Default::default() }, msg);
    for d in dirs {
        let s = ShardState::read(d)?;
        if s.plan_id != plan.store_id() {
            return Err(at(d, format!("a shard of plan {:016x}, not of this plan ({})", s.plan_id, plan.plan_id)));
        }
        if s.level != plan.shard_levels {
            return Err(at(d, format!("stopped before level {}, the plan says {}", s.level, plan.shard_levels)));
        }
        match by_index.get_mut(s.shard as usize) {
            Some(slot @ None) => *slot = Some((s, d.clone())),
            Some(Some(_)) => return Err(at(d, format!("shard {} given twice", s.shard))),
            None => return Err(at(d, format!("shard {} is not in the plan's 0..{n}", s.shard))),
        }
    }
    let missing: Vec<String> = by_index.iter().enumerate().filter(|(_, s)| s.is_none()).map(|(i, _)| i.to_string()).collect();
    if !missing.is_empty() {
        return Err(Error::Usage(format!("shards {} of the plan's {n} are missing", missing.join(", "))));
    }
    let (states, dirs): (Vec<ShardState>, Vec<PathBuf>) = by_index.into_iter().flatten().unzip();
    let s0 = &states[0];
    if let Some(s) = states.iter().find(|s| (s.attrs, s.a_len, s.bbox) != (s0.attrs, s0.a_len, s0.bbox)) {
        return Err(Error::Usage(format!("shard {} was built with other attributes or another box than shard 0", s.shard)));
    }
    Ok((states, dirs))
}

/// Per shard, its local node id → the store's (level order, then shard order).
fn renumber(states: &[ShardState], stop: u8) -> Vec<Vec<u32>> {
    let mut map: Vec<Vec<u32>> = states.iter().map(|s| vec![0; s.nodes.len()]).collect();
    let mut next = 0u32;
    for level in 0..stop {
        for (k, s) in states.iter().enumerate() {
            for (i, n) in s.nodes.iter().enumerate() {
                if n.level == level {
                    map[k][i] = next;
                    next += 1;
                }
            }
        }
    }
    map
}

/// The store's level packs: each shard's, in shard order, page-aligned.
/// Gives the bytes copied and where each shard's pack of each level starts.
#[allow(clippy::needless_range_loop, reason = "one pack per level, each shard's part of it")]
fn concat_packs(dirs: &[PathBuf], out: &Path, stop: u8) -> Result<(u64, Vec<Vec<u64>>)> {
    use std::io::Seek;
    let mut copied = 0u64;
    let mut base = vec![vec![0u64; stop as usize]; dirs.len()];
    for level in 0..stop as usize {
        let dest = pack_file(out, level);
        let mut w = std::fs::File::create(&dest).ctx(&dest, "create pack file")?;
        let mut pos = 0u64;
        for (k, d) in dirs.iter().enumerate() {
            let src = pack_file(d, level);
            let mut r = std::fs::File::open(&src).ctx(&src, "open pack file")?;
            pos += (PAGE - pos % PAGE) % PAGE;
            w.seek(std::io::SeekFrom::Start(pos)).ctx(&dest, "seek")?;
            base[k][level] = pos;
            let n = std::io::copy(&mut r, &mut w).ctx(&src, "copy pack file")?;
            pos += n;
            copied += n;
        }
        w.set_len(pos).ctx(&dest, "write pack file")?;
    }
    Ok((copied, base))
}

/// A payload's patches name its children by shard-local ids: each is
/// rewritten in the store's pack with the store's id, and the node's
/// checksum with it.
fn renumber_patches(states: &mut [ShardState], map: &[Vec<u32>], pack_base: &[Vec<u64>], out: &Path) -> Result<()> {
    let mut files: Vec<std::fs::File> = Vec::new();
    for level in 0..pack_base.first().map_or(0, |b| b.len()) {
        let p = pack_file(out, level);
        files.push(std::fs::OpenOptions::new().read(true).write(true).open(&p).ctx(&p, "open pack file")?);
    }
    let mut b = Vec::new();
    for (k, s) in states.iter_mut().enumerate() {
        for n in s.nodes.iter_mut().filter(|n| n.level > 0) {
            let level = n.level as usize;
            let (f, at) = (&files[level], pack_base[k][level] + n.offset);
            let path = pack_file(out, level);
            let bad = || Error::input(Location { file: path.clone(), offset: Some(at), ..Default::default() }, "a shard's payload is damaged");
            b.resize(n.bytes as usize, 0);
            f.read_exact_at(&mut b, at).ctx(&path, "read pack file")?;
            if b.len() < 16 || crc32c::crc32c(&b) != n.crc {
                return Err(bad());
            }
            let np = u32::from_le_bytes(b[12..16].try_into().unwrap()) as usize;
            if b.len() < 16 + 8 * np {
                return Err(bad());
            }
            for p in 0..np {
                let o = 16 + 8 * p;
                let local = u32::from_le_bytes(b[o..o + 4].try_into().unwrap()) as usize;
                let id = *map[k].get(local).ok_or_else(bad)?;
                b[o..o + 4].copy_from_slice(&id.to_le_bytes());
            }
            f.write_all_at(&b[..16 + 8 * np], at).ctx(&path, "write pack file")?;
            n.crc = crc32c::crc32c(&b);
        }
    }
    Ok(())
}

/// The union of the shards' top-level chunks: leaf `i` of shard `k` becomes
/// leaf `base_k + i`, a chunk's source node its store id.
fn union_chunks(states: &[ShardState], dirs: &[PathBuf], map: &[Vec<u32>], path: PathBuf, stop: u8) -> Result<ChunkFile> {
    let s0 = &states[0];
    let mut out = ChunkFile::create(path, VertexLayout::new(s0.attrs), s0.a_len as usize)?;
    let mut leaf_base = 0u32;
    for ((s, d), m) in states.iter().zip(dirs).zip(map) {
        let src = ShardState::chunks_path(d);
        let f = std::fs::File::open(&src).ctx(&src, "open chunk file")?;
        let mut refs = s.refs.clone();
        refs.sort_by_key(|r| r.offset);
        let mut b = Vec::new();
        for r in &refs {
            b.resize(r.bytes as usize, 0);
            f.read_exact_at(&mut b, r.offset).ctx(&src, "read chunk file")?;
            let bad = || Error::input(Location { file: src.clone(), offset: Some(r.offset), ..Default::default() }, "damaged chunk");
            if b.len() < 16 || u32::from_le_bytes(b[0..4].try_into().unwrap()) != r.target {
                return Err(bad());
            }
            let target = leaf_base + r.target;
            b[0..4].copy_from_slice(&target.to_le_bytes());
            if stop > 0 {
                let source = u32::from_le_bytes(b[4..8].try_into().unwrap()) as usize;
                let id = *m.get(source).ok_or_else(bad)?;
                b[4..8].copy_from_slice(&id.to_le_bytes());
            }
            out.append(target, &b)?;
        }
        leaf_base += s.tiling.len() as u32;
    }
    out.finish(leaf_base as usize)?;
    Ok(out)
}

/// The builder's state for the union: nodes in store order with their
/// children, the leaves side by side, the levels' reports added up.
fn union_state(states: &[ShardState], map: &[Vec<u32>], pack_base: &[Vec<u64>], chunks: ChunkFile, stop: u8) -> Paused {
    let total: usize = states.iter().map(|s| s.nodes.len()).sum();
    let mut nodes = vec![None; total];
    let mut children = vec![Vec::new(); total];
    let mut simp_err = vec![0.0; total];
    for (k, s) in states.iter().enumerate() {
        for (i, n) in s.nodes.iter().enumerate() {
            let g = map[k][i] as usize;
            let mut n = n.clone();
            n.offset += pack_base[k][n.level as usize];
            nodes[g] = Some(n);
            children[g] = s.children[i].iter().map(|&c| map[k][c as usize]).collect();
            simp_err[g] = s.simp_err[i];
        }
    }
    let mut reports: Vec<LevelReport> = Vec::new();
    for level in 0..stop as usize {
        let mut r = LevelReport { level: level as u8, error_min: f64::INFINITY, ..Default::default() };
        for s in states {
            let Some(x) = s.reports.get(level) else { continue };
            r.nodes += x.nodes;
            r.triangles += x.triangles;
            r.positions += x.positions;
            r.bytes += x.bytes;
            r.error_min = r.error_min.min(x.error_min);
            r.error_max = r.error_max.max(x.error_max);
            r.tau = r.tau.max(x.tau);
            r.seconds += x.seconds;
            r.locked += (x.locked_fraction * x.positions as f64).round() as u64;
        }
        if r.nodes == 0 {
            r.error_min = 0.0;
        }
        let locked = r.locked;
        r.set_locked(locked, 0, 0);
        reports.push(r);
    }
    let mut octree = OctreeReport::default();
    for s in states {
        let o = &s.octree;
        octree.leaves += o.leaves;
        octree.deepest = octree.deepest.max(o.deepest);
        octree.overfull_leaves += o.overfull_leaves;
        octree.counting_passes = octree.counting_passes.max(o.counting_passes);
        octree.chunks += o.chunks;
        octree.chunk_bytes += o.chunk_bytes;
        octree.seconds += o.seconds;
    }
    Paused {
        level: stop,
        tiling: states.iter().flat_map(|s| s.tiling.iter().copied()).collect(),
        leaves: states.iter().flat_map(|s| s.leaves.iter().cloned()).collect(),
        chunks,
        nodes: nodes.into_iter().map(|n| n.expect("every node numbered")).collect(),
        children,
        simp_err,
        reports,
        leaf_scale: states.iter().map(|s| s.leaf_scale).max().unwrap_or(1),
        octree,
        scratch: None,
    }
}

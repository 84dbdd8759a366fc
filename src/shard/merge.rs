//! `octolod merge PLAN SHARD... -o STORE`: one store from a plan's shards.
//!
//! The shards' nodes are renumbered level by level (the store's nodes are
//! in level order). Their level packs are taken as they are: hard-linked
//! into the store as pack parts (`level-L.part-P.pack`, P = shard + 1; no
//! byte copied, and the store stays whole when the shards are deleted),
//! copied part by part where a link cannot be made (another filesystem),
//! or, with `--copy`, concatenated page-aligned into the store's own
//! `level-L.pack` (`copy_file_range`: a reflink on filesystems that have
//! them). Payload bytes are never rewritten: a payload names its children
//! by the shard's ids, and its record's patch shift turns them into the
//! store's (`store::NodeRec::patch_shift`). The union of their top levels — each shard's leaves, overlapping
//! cells allowed, and their chunks with targets and sources renumbered —
//! becomes the current level of one level builder, which goes on to the
//! root as a monolithic build does from there: the shards' boundary
//! positions, locked below, are shared positions of the union like any
//! other and simplify from here up.

use super::plan::Plan;
use super::state::ShardState;
use crate::error::{Error, IoContext, Location, Result};
use crate::io::{AtomicDir, OutputKind};
use crate::lod::chunks::{self, ChunkFile};
use crate::lod::level::{LevelBuilder, Paused};
use crate::lod::octree::OctreeReport;
use crate::lod::simplifier::NodeSimplifier;
use crate::lod::{build_levels, with_simplifier, Built, LodOptions, WithSimplifier};
use crate::manifest::{BuildParams, LevelReport, Manifest, ManifestSeconds};
use crate::mesh::VertexLayout;
use crate::soup::format::SoupHeader;
use crate::store::{pack_file, pack_file_part, write_index, MAX_PARTS, PAGE};
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
    /// Bytes of the shards' packs hard-linked into the store (no copy).
    pub linked_bytes: u64,
    /// Bytes of the shards' packs copied (`--copy`, or where no link could be made).
    pub copied_bytes: u64,
    pub seconds: f64,
    pub level_reports: Vec<LevelReport>,
}

/// How to merge.
#[derive(Clone, Copy, Debug, Default)]
pub struct MergeOptions {
    /// Working-memory budget of the levels the merge builds.
    pub mem: u64,
    pub quiet: bool,
    /// Replace an existing store at the output.
    pub force: bool,
    /// Concatenate the shards' packs into the store's own instead of
    /// linking them in as parts.
    pub copy: bool,
}

/// Merges `shards` (directories, any order) of `plan` into store `out`.
pub fn merge(plan: &Plan, shards: &[PathBuf], out: &Path, o: MergeOptions) -> Result<MergeReport> {
    let MergeOptions { mem, quiet, force, copy } = o;
    let t0 = Instant::now();
    let _protect: Vec<_> = shards.iter().map(|d| crate::io::protect(d)).collect();
    let (mut states, dirs) = read_shards(plan, shards)?;
    let dir = AtomicDir::create(out, OutputKind::Store, force)?;
    let stop = plan.shard_levels;
    let map = renumber(&states, stop);
    let placed = if copy { concat_packs(&dirs, dir.path(), stop)? } else { link_packs(&dirs, dir.path(), stop)? };
    place_nodes(&mut states, &dirs, &map, &placed)?;
    let mut lo = LodOptions { params: plan.params.clone(), quiet, ..Default::default() };
    lo.params.mem = mem;
    let scratch = crate::io::scratch_dir(dir.path())?;
    let first = &states[0];
    let chunks = union_chunks(&states, &dirs, &map, scratch.path().join(format!("chunks-{stop}.bin")), stop)?;
    let merged_triangles = states.iter().map(|s| s.leaves.iter().map(|l| l.tris).sum::<u64>()).sum();
    let paused = union_state(&states, &map, chunks, stop);
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
        version: crate::store::format_version(&built.nodes),
        input: plan.input.path.clone(),
        attributes: attrs.describe(),
        quadric_dim: built.quadric_dim,
        derived_normals: built.header.derived_normals,
        nodes: built.nodes.len() as u64,
        triangles: header.triangles,
        params: BuildParams { normals: built.normals, ..lo.params.clone() },
        seconds: ManifestSeconds { soup: 0.0, partition: 0.0, levels: seconds, total: seconds },
        disk_bytes,
        levels: built.levels.clone(),
        textures: Vec::new(),
    };
    manifest.write(dir.path())?;
    dir.commit()?;
    Ok(MergeReport {
        shards: states.len(),
        nodes: built.nodes.len() as u64,
        levels: built.levels.len(),
        merged_triangles,
        linked_bytes: placed.linked,
        copied_bytes: placed.copied,
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

/// Where the shards' payloads went: per shard and level, the pack part
/// and the offset its pack starts at there; the bytes linked and copied.
struct Placed {
    at: Vec<Vec<(u32, u64)>>,
    linked: u64,
    copied: u64,
}

/// `--copy`: the store's level packs, each shard's in shard order, page-aligned.
#[allow(clippy::needless_range_loop, reason = "one pack per level, each shard's part of it")]
fn concat_packs(dirs: &[PathBuf], out: &Path, stop: u8) -> Result<Placed> {
    use std::io::Seek;
    let mut copied = 0u64;
    let mut at = vec![vec![(0u32, 0u64); stop as usize]; dirs.len()];
    for level in 0..stop as usize {
        let dest = pack_file(out, level);
        let mut w = std::fs::File::create(&dest).ctx(&dest, "create pack file")?;
        let mut pos = 0u64;
        for (k, d) in dirs.iter().enumerate() {
            let src = pack_file(d, level);
            let mut r = std::fs::File::open(&src).ctx(&src, "open pack file")?;
            pos += (PAGE - pos % PAGE) % PAGE;
            w.seek(std::io::SeekFrom::Start(pos)).ctx(&dest, "seek")?;
            at[k][level] = (0, pos);
            let n = std::io::copy(&mut r, &mut w).ctx(&src, "copy pack file")?;
            pos += n;
            copied += n;
        }
        w.set_len(pos).ctx(&dest, "write pack file")?;
    }
    Ok(Placed { at, linked: 0, copied })
}

/// Each shard's level packs, hard-linked into the store as pack parts
/// (shard k's are part k + 1); copied where a link cannot be made (the
/// shard on another filesystem, or one without links).
fn link_packs(dirs: &[PathBuf], out: &Path, stop: u8) -> Result<Placed> {
    let (mut linked, mut copied) = (0u64, 0u64);
    let mut at = vec![vec![(0u32, 0u64); stop as usize]; dirs.len()];
    for (k, d) in dirs.iter().enumerate() {
        let part = u32::try_from(k + 1)
            .ok()
            .filter(|&p| p <= MAX_PARTS)
            .ok_or_else(|| Error::Usage(format!("more than {MAX_PARTS} shards to link: merge with --copy")))?;
        for level in 0..stop {
            let (src, dest) = (pack_file(d, level as usize), pack_file_part(out, level, part));
            let bytes = std::fs::metadata(&src).ctx(&src, "open pack file")?.len();
            if std::fs::hard_link(&src, &dest).is_ok() {
                linked += bytes;
            } else {
                copied += std::fs::copy(&src, &dest).ctx(&dest, "copy pack file")?;
            }
            at[k][level as usize] = (part, 0);
        }
    }
    Ok(Placed { at, linked, copied })
}

/// Each shard node's record as the store's: its pack part and offset
/// there, and the patch shift that turns the shard's child ids in its
/// payload into store ids (the shard's level is numbered contiguously, and
/// so is its share of the store's level: one shift per shard and level).
fn place_nodes(states: &mut [ShardState], dirs: &[PathBuf], map: &[Vec<u32>], placed: &Placed) -> Result<()> {
    for (k, s) in states.iter_mut().enumerate() {
        for (i, n) in s.nodes.iter_mut().enumerate() {
            let (part, base) = placed.at[k][n.level as usize];
            n.part = part;
            n.offset += base;
            let kids = &s.children[i];
            let shift = kids.first().map_or(0, |&c| map[k][c as usize].wrapping_sub(c));
            if kids.iter().any(|&c| map[k][c as usize].wrapping_sub(c) != shift) {
                return Err(Error::input(
                    Location { file: dirs[k].join("shard.state"), ..Default::default() },
                    format!("node {i}: its children are not numbered contiguously in their level (a damaged shard state)"),
                ));
            }
            n.patch_shift = shift;
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
            if b.len() < 16 || chunks::field(&b, 0) != r.target as usize {
                return Err(bad());
            }
            let target = leaf_base + r.target;
            b[0..4].copy_from_slice(&target.to_le_bytes());
            if stop > 0 {
                let source = chunks::field(&b, 4);
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
fn union_state(states: &[ShardState], map: &[Vec<u32>], chunks: ChunkFile, stop: u8) -> Paused {
    let total: usize = states.iter().map(|s| s.nodes.len()).sum();
    let mut nodes = vec![None; total];
    let mut children = vec![Vec::new(); total];
    let mut simp_err = vec![0.0; total];
    for (k, s) in states.iter().enumerate() {
        for (i, n) in s.nodes.iter().enumerate() {
            let g = map[k][i] as usize;
            nodes[g] = Some(n.clone());
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

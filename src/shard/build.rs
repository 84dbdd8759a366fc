//! `octolod build IN --plan PLAN --shard I -o DIR`: one shard's levels.
//!
//! The whole input is made into a soup (the soup stage, under `--mem`);
//! the shard keeps the triangles whose first corner lies in its region
//! (as level 0 chooses a triangle's leaf by its first corner), and locks
//! every corner of a triangle whose corners lie in different regions and
//! touch its own: a position two shards hold is such a corner (a triangle
//! with all corners in one region belongs to it), so both shards keep it,
//! bit-exact, at every level. Level 0 is partitioned on the whole input's
//! cube, and levels `0..shard_levels` are built as a monolithic build
//! would, then the builder pauses: its top level's chunks and the DAG so
//! far are the shard's output ([`super::state`]).

use super::plan::Plan;
use super::state::ShardState;
use crate::error::{Error, IoContext, Result};
use crate::geom::pos_bits;
use crate::io::{AtomicDir, OutputKind};
use crate::lod::level::{LevelBuilder, Paused};
use crate::lod::octree::build_octree;
use crate::lod::partition::LevelCube;
use crate::lod::simplifier::NodeSimplifier;
use crate::lod::{with_simplifier, LodOptions, WithSimplifier};
use crate::soup::format::{SoupReader, SoupWriter};
use crate::soup::SoupOptions;
use rustc_hash::FxHashSet;
use std::path::Path;
use std::time::Instant;

/// What one shard's build did.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ShardReport {
    pub shard: u32,
    /// Already complete in the output directory: nothing was done.
    pub skipped: bool,
    pub triangles: u64,
    pub input_triangles: u64,
    pub boundary_positions: u64,
    pub levels: u8,
    pub nodes: u64,
    pub seconds: f64,
}

/// How one shard is built: the command's own options (the plan gives the rest).
#[derive(Clone, Copy, Debug)]
pub struct ShardOptions {
    /// `--mem`, bytes.
    pub mem: u64,
    pub quiet: bool,
    /// Replace an existing shard of another plan (`--force`).
    pub force: bool,
}

/// Builds shard `shard` of `plan` (read from `plan_path`) from `input` into `out`.
pub fn build_shard(input: &Path, plan: &Plan, plan_path: &Path, shard: u32, out: &Path, opts: ShardOptions) -> Result<ShardReport> {
    let ShardOptions { mem, quiet, force } = opts;
    let t0 = Instant::now();
    if shard as usize >= plan.shards.len() {
        return Err(Error::Usage(format!("--shard {shard}: the plan has shards 0..{}", plan.shards.len())));
    }
    plan.input.check(&super::plan::InputId::of(input)?, plan_path)?;
    if let Some(s) = ShardState::read(out).ok().filter(|s| s.plan_id == plan.store_id() && s.shard == shard) {
        return Ok(ShardReport {
            shard,
            skipped: true,
            triangles: s.triangles,
            input_triangles: s.input_triangles,
            boundary_positions: 0,
            levels: s.level,
            nodes: s.nodes.len() as u64,
            seconds: t0.elapsed().as_secs_f64(),
        });
    }
    let _input = crate::io::protect(input);
    let dir = AtomicDir::create(out, OutputKind::Shard, force)?;
    let whole = dir.path().join("input.soup");
    let mine = dir.path().join("shard.soup");
    let soup_opts = SoupOptions { mem, quiet, scratch: true, ..Default::default() };
    // On the soup's external path the shard's triangles are kept as they
    // are placed (the whole soup is never written); on the in-memory path
    // (small inputs) the whole soup is written and filtered.
    let mut tap = RegionTap { plan, shard, out: mine.clone(), w: None, layout: None, locks: FxHashSet::default() };
    let soup = crate::soup::build_soup_tapped(input, &whole, &soup_opts, Some(&mut tap))?;
    let locks = if soup.written {
        let locks = keep_region(&whole, &mine, plan, shard)?;
        std::fs::remove_file(&whole).ctx(&whole, "remove")?;
        locks
    } else {
        let w = tap.w.take().expect("the tap took the triangles");
        w.commit(soup.header.input_vertices, soup.header.input_faces, soup.header.degenerate)?;
        tap.locks
    };
    let bbox = soup.header.bbox;
    if SoupReader::open(&mine)?.header.triangles == 0 {
        std::fs::remove_file(&mine).ctx(&mine, "remove")?;
        return empty_shard(dir, plan, shard, soup.header, t0);
    }
    let mut lo = LodOptions { params: plan.params.clone(), quiet, ..Default::default() };
    lo.params.mem = mem;
    let scratch = crate::io::scratch_dir(dir.path())?;
    let mut l0 = build_octree(&mine, scratch.path().join("chunks-0.bin"), &LevelCube::for_level(&bbox, 0), &lo.octree(), None)?;
    std::fs::remove_file(&mine).ctx(&mine, "remove")?;
    let triangles = l0.header.triangles;
    // The whole input's box: every shard's cells are the monolithic build's.
    l0.header.bbox = bbox;
    let attrs = l0.header.attrs;
    let stop = plan.shard_levels;
    let n_locks = locks.len() as u64;
    let paused = with_simplifier(&lo, attrs, ShardLevels { l0, dir: dir.path(), scratch, lo: &lo, locks, stop, shard })?;
    let state = ShardState::from_paused(paused, dir.path(), plan.store_id(), shard, attrs, bbox, soup.header.triangles, triangles)?;
    let seconds = t0.elapsed().as_secs_f64();
    state.write(dir.path(), n_locks, seconds)?;
    dir.commit()?;
    Ok(ShardReport {
        shard,
        skipped: false,
        triangles,
        input_triangles: soup.header.triangles,
        boundary_positions: n_locks,
        levels: stop,
        nodes: state.nodes.len() as u64,
        seconds,
    })
}

/// A shard whose region holds no triangle (the plan's sample said some):
/// no node, an empty top level, empty packs.
fn empty_shard(dir: AtomicDir, plan: &Plan, shard: u32, whole: crate::soup::format::SoupHeader, t0: Instant) -> Result<ShardReport> {
    let layout = whole.layout();
    struct CarriedLen;
    impl WithSimplifier for CarriedLen {
        type Out = usize;
        fn run<S: NodeSimplifier>(self, s: S) -> usize {
            s.carried_len()
        }
    }
    let lo = LodOptions { params: plan.params.clone(), ..Default::default() };
    let a_len = if plan.shard_levels == 0 { 0 } else { with_simplifier(&lo, whole.attrs, CarriedLen) };
    let mut chunks = crate::lod::chunks::ChunkFile::create(dir.path().join("chunks.tmp"), layout, a_len)?;
    chunks.finish(0)?;
    for level in 0..plan.shard_levels as usize {
        crate::store::PackWriter::create(dir.path(), level)?.finish()?;
    }
    let paused = Paused {
        level: plan.shard_levels,
        tiling: Vec::new(),
        leaves: Vec::new(),
        chunks,
        nodes: Vec::new(),
        children: Vec::new(),
        simp_err: Vec::new(),
        reports: Vec::new(),
        leaf_scale: 1,
        octree: Default::default(),
        scratch: None,
    };
    let state = ShardState::from_paused(paused, dir.path(), plan.store_id(), shard, whole.attrs, whole.bbox, whole.triangles, 0)?;
    let seconds = t0.elapsed().as_secs_f64();
    state.write(dir.path(), 0, seconds)?;
    dir.commit()?;
    Ok(ShardReport {
        shard,
        skipped: false,
        triangles: 0,
        input_triangles: whole.triangles,
        boundary_positions: 0,
        levels: plan.shard_levels,
        nodes: 0,
        seconds,
    })
}

/// A shard's levels `0..stop` with the other shards' positions locked,
/// then paused.
struct ShardLevels<'a> {
    l0: crate::lod::octree::Level0,
    dir: &'a Path,
    scratch: crate::io::ScratchDir,
    lo: &'a LodOptions,
    locks: FxHashSet<[u64; 3]>,
    stop: u8,
    shard: u32,
}

impl WithSimplifier for ShardLevels<'_> {
    type Out = Result<Paused>;
    fn run<S: NodeSimplifier>(self, s: S) -> Result<Paused> {
        let b = LevelBuilder::new(self.l0, self.dir, self.scratch, self.lo, s);
        build_to(b, self.locks, self.stop, self.shard)
    }
}

fn build_to<S: NodeSimplifier>(b: LevelBuilder<S>, locks: FxHashSet<[u64; 3]>, stop: u8, shard: u32) -> Result<Paused> {
    let mut b = b.for_shard(locks, stop);
    for level in 0..stop {
        if !b.build_level(level)? {
            return Err(Error::Usage(format!(
                "shard {shard} simplified to nothing at level {level}, below the plan's --shard-levels {stop}: plan fewer shards or fewer shard levels"
            )));
        }
    }
    Ok(b.pause(stop))
}

/// Keeps the shard's triangles as the soup stage places them.
struct RegionTap<'a> {
    plan: &'a Plan,
    shard: u32,
    out: std::path::PathBuf,
    w: Option<SoupWriter>,
    layout: Option<crate::mesh::VertexLayout>,
    locks: FxHashSet<[u64; 3]>,
}

impl crate::soup::SoupTap for RegionTap<'_> {
    fn reserve(&self) -> u64 {
        // The soup writer's buffer; the locks are few (the shard's border).
        2 * crate::io::SEQ_BUF as u64
    }
    fn begin(&mut self, _bbox: &crate::mesh::Aabb, layout: crate::mesh::VertexLayout) -> Result<crate::soup::TapMode> {
        self.w = Some(SoupWriter::create(&self.out, layout.attrs, false, true)?);
        self.layout = Some(layout);
        Ok(crate::soup::TapMode::Takes)
    }
    fn triangles(&mut self, records: &[u8]) -> Result<()> {
        let (w, layout) = (self.w.as_mut().expect("begun"), self.layout.expect("begun"));
        for rec in records.chunks_exact(3 * layout.size) {
            keep_triangle(self.plan, self.shard, &layout, rec, w, &mut self.locks)?;
        }
        Ok(())
    }
}

/// Keeps one soup record when its first corner is in `shard`'s region, and
/// locks its corners when it straddles regions, one of them `shard`'s.
#[inline]
fn keep_triangle(plan: &Plan, shard: u32, layout: &crate::mesh::VertexLayout, rec: &[u8], w: &mut SoupWriter, locks: &mut FxHashSet<[u64; 3]>) -> Result<()> {
    let c = [0, 1, 2].map(|k| layout.position(&rec[k * layout.size..]));
    let region = c.map(|p| plan.shard_of(p));
    if region[0] == shard {
        w.push_encoded(rec)?;
    }
    if region.contains(&shard) && (region[1] != region[0] || region[2] != region[0]) {
        locks.extend(c.map(pos_bits));
    }
    Ok(())
}

/// Copies the triangles of `whole` whose first corner lies in `shard`'s
/// region into soup `mine`; gives the positions to lock (see the module doc).
fn keep_region(whole: &Path, mine: &Path, plan: &Plan, shard: u32) -> Result<FxHashSet<[u64; 3]>> {
    let mut r = SoupReader::open(whole)?;
    let h = r.header;
    let layout = h.layout();
    let mut w = SoupWriter::create(mine, h.attrs, false, true)?;
    let mut locks = FxHashSet::default();
    let mut buf = Vec::new();
    while r.read_batch(&mut buf, 1 << 15)? > 0 {
        for rec in buf.chunks_exact(3 * layout.size) {
            keep_triangle(plan, shard, &layout, rec, &mut w, &mut locks)?;
        }
    }
    w.commit(h.input_vertices, h.input_faces, h.degenerate)?;
    Ok(locks)
}

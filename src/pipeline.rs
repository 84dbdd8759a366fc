//! Whole-pipeline commands: PLY → store (`build`), store → PLY (`extract`),
//! and the level choice behind `simplify`.
//!
//! Takes: paths and options from the CLI. Gives: a complete
//! `NAME.octolod/` directory (written under a temporary name and renamed
//! only when every stage succeeded) with a `store.json` manifest, or one
//! indexed PLY of a whole level.

use crate::error::{Error, IoContext, Result};
use crate::io::{AtomicDir, OutputKind};
use crate::octree::{build_octree, OctreeOptions, OctreeReport};
use crate::ply::write::{PlyWriteOptions, PlyWriter};
use crate::simplify::{build_levels, level_cut, weld_union, LevelReport, SimplifyOptions};
use crate::soup::{build_soup, SoupOptions, SoupReport};
use crate::store::{read_slot, write_index, IndexedMesh, NodeRec, Slot, Store, StoreHeader};
use std::io::Write;
use std::path::Path;
use std::time::Instant;

#[derive(Clone, Debug)]
pub struct BuildOptions {
    pub mem: u64,
    pub leaf_tris: u64,
    pub max_depth: u8,
    pub cluster_grid: u32,
    pub levels: Option<u8>,
    pub quiet: bool,
    /// Replace an existing store at the output path (`--force`).
    pub force: bool,
}

impl Default for BuildOptions {
    fn default() -> Self {
        BuildOptions { mem: 512 << 20, leaf_tris: 16384, max_depth: 16, cluster_grid: 8, levels: None, quiet: true, force: false }
    }
}

#[derive(Clone, Debug)]
pub struct BuildReport {
    pub soup: SoupReport,
    pub octree: OctreeReport,
    pub levels: Vec<LevelReport>,
    /// Seconds: soup, octree, simplification, total.
    pub seconds: [f64; 4],
    pub disk_bytes: u64,
}

/// PLY → store, every stage under `opts.mem`.
pub fn build_store(input: &Path, output: &Path, opts: &BuildOptions) -> Result<BuildReport> {
    let t0 = Instant::now();
    let out = AtomicDir::create(output, OutputKind::Store, opts.force)?;
    let soup_path = out.path().join("input.soup");
    let soup = build_soup(input, &soup_path, &SoupOptions { mem: opts.mem, quiet: opts.quiet, ..Default::default() })?;
    let t1 = Instant::now();
    let (sh, cube, mut nodes, octree) = build_octree(
        &soup_path,
        out.path(),
        &OctreeOptions { leaf_tris: opts.leaf_tris, max_depth: opts.max_depth, mem: opts.mem, quiet: opts.quiet },
    )?;
    std::fs::remove_file(&soup_path).ctx(&soup_path, "remove")?;
    let t2 = Instant::now();
    let levels = build_levels(
        out.path(),
        &cube,
        sh.attrs,
        &mut nodes,
        &SimplifyOptions { cluster_grid: opts.cluster_grid, levels: opts.levels, quiet: opts.quiet, ..Default::default() },
    )?;
    let t3 = Instant::now();
    let header = StoreHeader { attrs: sh.attrs, levels: levels.len() as u32 + 1, cube, nodes: nodes.len() as u64 };
    write_index(out.path(), &header, &nodes)?;
    let seconds = [(t1 - t0).as_secs_f64(), (t2 - t1).as_secs_f64(), (t3 - t2).as_secs_f64(), t0.elapsed().as_secs_f64()];
    let disk_bytes = dir_bytes(out.path());
    let report = BuildReport { soup, octree, levels, seconds, disk_bytes };
    write_manifest(out.path(), input, opts, &header, &report)?;
    out.commit()?;
    Ok(report)
}

fn dir_bytes(d: &Path) -> u64 {
    std::fs::read_dir(d)
        .map(|it| it.filter_map(|e| e.ok()).filter_map(|e| e.metadata().ok()).map(|m| m.len()).sum())
        .unwrap_or(0)
}

fn write_manifest(dir: &Path, input: &Path, o: &BuildOptions, h: &StoreHeader, r: &BuildReport) -> Result<()> {
    let path = dir.join("store.json");
    let levels: Vec<String> = std::iter::once(format!(
        "    {{\"level\": 0, \"nodes\": {}, \"triangles\": {}, \"bytes\": {}, \"error_min\": 0, \"error_max\": 0, \"seconds\": {:.3}}}",
        r.octree.leaves, r.soup.header.triangles, r.octree.pack_bytes, r.octree.seconds
    ))
    .chain(r.levels.iter().map(|l| {
        format!(
            "    {{\"level\": {}, \"nodes\": {}, \"triangles\": {}, \"bytes\": {}, \"error_min\": {:e}, \"error_max\": {:e}, \"seconds\": {:.3}}}",
            l.level, l.nodes, l.triangles, l.bytes, l.error_min, l.error_max, l.seconds
        )
    }))
    .collect();
    let s = format!(
        "{{\n  \"format\": \"octolod-store\",\n  \"version\": {},\n  \"input\": {:?},\n  \"attributes\": {:?},\n  \"quadric_dim\": {},\n  \"nodes\": {},\n  \"leaves\": {},\n  \"deepest\": {},\n  \"triangles\": {},\n  \"root_cube\": {{\"center\": [{}, {}, {}], \"half\": {}}},\n  \"params\": {{\"mem\": {}, \"leaf_tris\": {}, \"max_depth\": {}, \"cluster_grid\": {}, \"levels\": {}}},\n  \"seconds\": {{\"soup\": {:.3}, \"octree\": {:.3}, \"simplify\": {:.3}, \"total\": {:.3}}},\n  \"disk_bytes\": {},\n  \"levels\": [\n{}\n  ]\n}}\n",
        crate::store::VERSION,
        input.display().to_string(),
        h.attrs.describe(),
        h.attrs.quadric_dim(),
        h.nodes,
        r.octree.leaves,
        r.octree.deepest,
        r.soup.header.triangles,
        h.cube.center[0],
        h.cube.center[1],
        h.cube.center[2],
        h.cube.half,
        o.mem,
        o.leaf_tris,
        o.max_depth,
        o.cluster_grid,
        o.levels.map(|l| l.to_string()).unwrap_or_else(|| "null".into()),
        r.seconds[0],
        r.seconds[1],
        r.seconds[2],
        r.seconds[3],
        r.disk_bytes,
        levels.join(",\n")
    );
    let mut f = std::fs::File::create(&path).ctx(&path, "create")?;
    f.write_all(s.as_bytes()).ctx(&path, "write")
}

/// The mesh node `n` contributes to a whole-level view at `level`: its
/// original triangles for level 0 (and when it has no simplified mesh),
/// else its simplified mesh. Returns (pack level, slot).
pub fn level_slot(n: &NodeRec, level: u8) -> (usize, Slot) {
    if level == 0 || n.simp.is_empty() {
        (0, n.orig)
    } else {
        (n.level as usize, n.simp)
    }
}

/// Reads node `i`'s mesh for a whole-level view at `level` (see [`level_slot`]).
pub fn read_level_mesh(store: &Store, i: usize, level: u8) -> Result<IndexedMesh> {
    let (pack, slot) = level_slot(&store.nodes[i], level);
    read_slot(&store.dir, &store.layout, pack, &slot)
}

/// A usage error unless the store has `level`.
pub fn check_level(store: &Store, level: u8) -> Result<()> {
    let top = top_level(store);
    if level > top {
        return Err(Error::Usage(format!("the store has levels 0..={top}; level {level} does not exist")));
    }
    Ok(())
}

/// Triangles a whole-level view at `level` would draw.
pub fn level_triangles(store: &Store, level: u8) -> u64 {
    level_cut(&store.nodes, level).iter().map(|&i| level_slot(&store.nodes[i], level).1.tris as u64).sum()
}

/// The highest level present in the store.
pub fn top_level(store: &Store) -> u8 {
    store.nodes.iter().filter(|n| !n.simp.is_empty()).map(|n| n.level).max().unwrap_or(0)
}

/// Writes a whole level as one indexed PLY (binary little endian, with the
/// store's attributes). Vertices shared by neighbouring nodes are welded
/// (bit-identical vertices become one) unless `weld` is false, which
/// streams node by node without holding the level in memory. An existing
/// PLY octolod wrote at `out` is replaced only when `force` is set.
pub fn extract(store: &Store, level: u8, out: &Path, weld: bool, force: bool) -> Result<(u64, u64)> {
    check_level(store, level)?;
    let cut = level_cut(&store.nodes, level);
    let read = |i: usize| read_level_mesh(store, i, level);
    let opts = PlyWriteOptions {
        attrs: store.header.attrs,
        index_type: crate::ply::Scalar::U32,
        comments: vec![format!("octolod level {level} of {}", store.dir.display())],
        ..Default::default()
    };
    let mut file = crate::io::AtomicFile::create(out, OutputKind::Ply, force)?;
    let (nv, nf) = if weld {
        let parts = cut.iter().map(|&i| read(i)).collect::<Result<Vec<_>>>()?;
        let m = weld_union(&store.layout, &parts);
        let mut w = PlyWriter::new(file.writer(), &opts, m.vertices.len() as u64, m.triangles.len() as u64).ctx(out, "write")?;
        for v in &m.vertices {
            w.vertex(v).ctx(out, "write")?;
        }
        for t in &m.triangles {
            w.face(t).ctx(out, "write")?;
        }
        w.finish().ctx(out, "write")?;
        (m.vertices.len() as u64, m.triangles.len() as u64)
    } else {
        let slot = |i: usize| level_slot(&store.nodes[i], level).1;
        let nv: u64 = cut.iter().map(|&i| slot(i).verts as u64).sum();
        let nf: u64 = cut.iter().map(|&i| slot(i).tris as u64).sum();
        let mut w = PlyWriter::new(file.writer(), &opts, nv, nf).ctx(out, "write")?;
        // PLY puts all vertices before all faces: two passes over the nodes.
        for &i in &cut {
            for v in &read(i)?.vertices {
                w.vertex(v).ctx(out, "write")?;
            }
        }
        let mut base = 0u32;
        for &i in &cut {
            let m = read(i)?;
            for t in &m.triangles {
                w.face(&t.map(|i| i + base)).ctx(out, "write")?;
            }
            base += m.vertices.len() as u32;
        }
        w.finish().ctx(out, "write")?;
        (nv, nf)
    };
    file.commit()?;
    Ok((nv, nf))
}

/// The level whose whole-level triangle count is nearest `target`.
pub fn nearest_level(store: &Store, target: u64) -> u8 {
    (0..=top_level(store))
        .min_by_key(|&l| level_triangles(store, l).abs_diff(target))
        .unwrap_or(0)
}

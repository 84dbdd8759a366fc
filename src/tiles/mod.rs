//! `octolod tiles`: a store as a 3D Tiles 1.1 tileset (`tileset.json` and one
//! GLB per tile), for CesiumJS, Cesium for Unreal/Unity, 3DTilesRendererJS.
//!
//! Takes: an opened store and [`TilesOptions`]. Gives: a directory written
//! atomically (an [`AtomicDir`] of kind `Tiles`) and a [`TilesReport`].
//!
//! The mapping. 3D Tiles refines a tile into its own children only
//! (REPLACE); a store is a DAG, whose shared subtrees a client would
//! instantiate once per path from the root ([`dag_instances`]). Instead each
//! level is cut into nested cells of one adaptive octree over the store's
//! cube: the cells of level L split those of level L + 1 while they hold
//! more than `tile_tris` of level L's triangles (by centroid), so every
//! level-(L-1) cell lies in one level-L cell and the tiles form a tree.
//!
//! Invariants:
//! * A tile holds every triangle of its level that reaches into its cell,
//!   exactly as the store has them: whatever level each cell is drawn at,
//!   the surface inside every cell is covered.
//! * A skirt along every edge where the tile's content stops (not along the
//!   mesh's own open borders), twice as long as the coarser of the tile's
//!   and its parent's errors, closes the slit between neighbours drawn at
//!   different levels (Chunked LOD's skirts, the normal as "down"):
//!   overlaps stay within the errors; no hole opens.
//! * Positions stay in the store's frame (the root `transform` turns the up
//!   axis to +Z; GLBs are Y-up); `geometricError` is monotone, 0 at level 0;
//!   boxes enclose the content and the children's boxes.
//! * Out of core: one counting and one writing pass over each level, a few
//!   nodes per thread in memory whatever the store's size.
//!
//! * Textures: a store with textures (and uvs) gets copies of each in
//!   `t/` (`texture-K-SIDE`, K its slot) at the resolution each level
//!   needs ([`level_texture_side`]: the full image at levels 0 and 1,
//!   halved every two levels, as a level's triangles halve, down to 64
//!   texels), each GLB having a primitive per material whose glTF material
//!   names its level's copy of that material's texture by URI
//!   ([`tile_glb`]), so a far view fetches small images and tiles of a
//!   level share them (browsers cache them; CesiumJS shares them). The
//!   full-size copy is the store's file; the others are made without the
//!   full image in memory: the largest is decoded straight at its size
//!   (a PNG row by row, [`crate::view::texture::decode`]), the smaller
//!   ones are its mip chain.
//!
//! Why a tree of cells, the skirts, frames, textures and costs: `docs/web.md`.

use crate::error::{Error, Result};
use crate::gltf::{encode_glb, GltfOptions};
use crate::io::{AtomicDir, OutputKind};
use crate::mesh::IndexedMesh;
use crate::mesh::{Aabb, Vertex};
use crate::progress::Progress;
use crate::store::Store;
use glam::DVec3;
use rayon::prelude::*;
use rustc_hash::{FxHashMap, FxHashSet};
use std::path::Path;
use std::time::Instant;

/// Settings of one export.
#[derive(Clone, Debug)]
pub struct TilesOptions {
    pub quantize: bool,
    pub compress: bool,
    /// Working-memory budget (bounds the tiles written at once).
    pub mem: u64,
    /// Split a level's cell while it holds more triangles than this.
    pub tile_tris: u64,
    /// The model's up axis (`auto`: as `view` picks it).
    pub up: crate::view::camera::Up,
    pub quiet: bool,
    /// Replace an existing tileset directory octolod wrote.
    pub force: bool,
}

impl Default for TilesOptions {
    fn default() -> Self {
        TilesOptions {
            quantize: false,
            compress: false,
            mem: crate::mem::DEFAULT_BUDGET,
            tile_tris: 32768,
            up: crate::view::camera::Up::Auto,
            quiet: true,
            force: false,
        }
    }
}

/// What an export wrote.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct TilesReport {
    pub tiles: u64,
    /// Tiles with content (a GLB).
    pub contents: u64,
    /// Triangles written, skirts included, and the skirts' share.
    pub triangles: u64,
    pub skirt_triangles: u64,
    /// Store triangles over all levels (what the tiles hold, skirts aside).
    pub store_triangles: u64,
    /// Everything written: GLBs, texture copies and `tileset.json`.
    pub tileset_bytes: u64,
    /// The texture copies (each level's; see [`level_texture_side`]).
    pub texture_bytes: u64,
    pub store_bytes: u64,
    /// Deepest tile (the root is 0).
    pub depth: u32,
    pub seconds: f64,
    /// Store triangles per second, in millions.
    pub mtris_per_s: f64,
    /// Node reads per node (a node reaching several cells is read by each).
    pub read_amplification: f64,
}

/// Deepest octree level a cell may reach.
const MAX_DEPTH: u32 = 20;

/// A cell of the octree over the store's cube: `code` holds `depth`
/// levels of 3-bit child indices (Morton order).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
struct Cell {
    depth: u32,
    code: u64,
}

impl Cell {
    const ROOT: Cell = Cell { depth: 0, code: 0 };
    fn children(self) -> impl Iterator<Item = Cell> {
        (0..8u64).map(move |k| Cell { depth: self.depth + 1, code: self.code << 3 | k })
    }
    /// The ancestor of `self` at `depth` (≤ its own).
    fn ancestor(self, depth: u32) -> Cell {
        Cell { depth, code: self.code >> (3 * (self.depth - depth)) }
    }
    #[cfg(test)]
    fn contains(self, other: Cell) -> bool {
        other.depth >= self.depth && other.ancestor(self.depth) == self
    }
}

/// The octree's cube and the map from positions to cells.
struct Cube {
    min: DVec3,
    size: f64,
}

impl Cube {
    fn around(b: &Aabb) -> Cube {
        let (lo, hi) = (DVec3::from(b.min), DVec3::from(b.max));
        let size = (hi - lo).max_element().max(1e-12) * (1.0 + 1e-9);
        let c = 0.5 * (lo + hi);
        Cube { min: c - DVec3::splat(0.5 * size), size }
    }
    /// The cell at `depth` holding `p` (clamped into the cube).
    fn cell(&self, p: DVec3, depth: u32) -> Cell {
        let n = (1u64 << depth) as f64;
        let q = ((p - self.min) / self.size * n).floor();
        let idx = |x: f64| (x.max(0.0) as u64).min((1u64 << depth) - 1);
        let (x, y, z) = (idx(q.x), idx(q.y), idx(q.z));
        let mut code = 0u64;
        for b in (0..depth).rev() {
            code = code << 3 | ((x >> b) & 1) << 2 | ((y >> b) & 1) << 1 | ((z >> b) & 1);
        }
        Cell { depth, code }
    }
    fn bounds(&self, c: Cell) -> Aabb {
        let (mut x, mut y, mut z) = (0u64, 0u64, 0u64);
        for b in (0..c.depth).rev() {
            let k = (c.code >> (3 * b)) & 7;
            x = x << 1 | (k >> 2) & 1;
            y = y << 1 | (k >> 1) & 1;
            z = z << 1 | k & 1;
        }
        let s = self.size / (1u64 << c.depth) as f64;
        let lo = self.min + DVec3::new(x as f64, y as f64, z as f64) * s;
        Aabb { min: lo.to_array(), max: (lo + DVec3::splat(s)).to_array() }
    }
}

fn centroid(m: &IndexedMesh, t: &[u32; 3]) -> DVec3 {
    t.iter().map(|&i| DVec3::from(m.vertices[i as usize].pos)).sum::<DVec3>() / 3.0
}

fn boxes_meet(a: &Aabb, b: &Aabb) -> bool {
    !a.is_empty() && !b.is_empty() && (0..3).all(|k| a.min[k] <= b.max[k] && b.min[k] <= a.max[k])
}

/// One level's triangles per cell code at the fine depth, with the largest
/// error of the nodes holding them: code → (triangles, error).
type CellCounts = FxHashMap<u64, (u64, f64)>;

/// Cells of one level: the tiles' cells (sorted) with their largest node
/// errors.
struct LevelCut {
    cells: Vec<Cell>,
    error: Vec<f64>,
    /// The largest triangle extent of the level (how far a triangle whose
    /// centroid is in a cell reaches out of it).
    reach: f64,
}

/// Counts one level's triangles per cell at depth `fine` (by centroid), with
/// the largest error of the nodes holding them; and the level's reach.
fn count_level(store: &Store, level: u8, cube: &Cube, fine: u32, progress: &Progress) -> Result<(CellCounts, f64)> {
    let ids = store.level_nodes(level);
    let parts: Vec<Result<(CellCounts, f64)>> = ids
        .par_chunks(8)
        .map(|chunk| {
            let mut m: CellCounts = FxHashMap::default();
            let mut reach = 0.0f64;
            for &i in chunk {
                crate::io::signal::check()?;
                let node = store.read_node(i)?;
                let e = store.nodes[i].error as f64;
                for t in &node.mesh.triangles {
                    let c = centroid(&node.mesh, t);
                    for &v in t {
                        reach = reach.max((DVec3::from(node.mesh.vertices[v as usize].pos) - c).abs().max_element());
                    }
                    let slot = m.entry(cube.cell(c, fine).code).or_insert((0, 0.0));
                    slot.0 += 1;
                    slot.1 = slot.1.max(e);
                }
                progress.inc(1);
            }
            Ok((m, reach))
        })
        .collect();
    let mut all: CellCounts = FxHashMap::default();
    let mut reach = 0.0f64;
    for p in parts {
        let (m, r) = p?;
        reach = reach.max(r);
        for (k, (n, e)) in m {
            let s = all.entry(k).or_insert((0, 0.0));
            s.0 += n;
            s.1 = s.1.max(e);
        }
    }
    Ok((all, reach))
}

/// Splits the cells of the level above (`coarse`) while they hold more
/// than `tile_tris` of this level's triangles. Cells holding none stay (as
/// tiles without content), so the cells always cover the whole cube and a
/// finer level's triangles always have a cell.
fn cut_level(coarse: &[Cell], counts: &CellCounts, fine: u32, tile_tris: u64) -> (Vec<Cell>, Vec<f64>) {
    // Per-cell sums at every depth up to `fine`, from the fine counts.
    let mut sums: FxHashMap<Cell, (u64, f64)> = FxHashMap::default();
    for (&code, &(n, e)) in counts {
        let leaf = Cell { depth: fine, code };
        for d in 0..=fine {
            let s = sums.entry(leaf.ancestor(d)).or_insert((0, 0.0));
            s.0 += n;
            s.1 = s.1.max(e);
        }
    }
    let (mut cells, mut error) = (Vec::new(), Vec::new());
    let mut stack: Vec<Cell> = coarse.to_vec();
    while let Some(c) = stack.pop() {
        let (n, e) = sums.get(&c).copied().unwrap_or((0, 0.0));
        if n > tile_tris && c.depth < fine {
            stack.extend(c.children());
        } else {
            cells.push(c);
            error.push(e);
        }
    }
    let mut order: Vec<usize> = (0..cells.len()).collect();
    order.sort_by_key(|&k| cells[k]);
    (order.iter().map(|&k| cells[k]).collect(), order.iter().map(|&k| error[k]).collect())
}

/// One tile of the tree.
#[derive(Clone, Debug)]
struct Tile {
    level: u8,
    error: f64,
    bounds: Aabb,
    content: Option<String>,
    children: Vec<usize>,
}

/// The rotation taking `up` to +Z, as rows (a right-handed frame whose
/// third axis is `up`).
fn up_to_z(up: DVec3) -> [DVec3; 3] {
    let e3 = up.normalize_or(DVec3::Z);
    let e1 = if e3.z.abs() > 0.9 {
        DVec3::X * e3.z.signum()
    } else if e3.y.abs() > 0.9 {
        // Y up: X stays east, so a Y-up scan stands as in Y-up viewers.
        DVec3::X
    } else {
        DVec3::Y * e3.x.signum()
    };
    let e1 = (e1 - e3 * e1.dot(e3)).normalize();
    let e2 = e3.cross(e1);
    [e1, e2, e3]
}

/// Model coordinates to the glTF frame: clients turn glTF's Y-up to the
/// tileset's Z-up with (x, y, z) → (x, -z, y); its inverse is applied here.
fn to_gltf(p: [f64; 3]) -> [f64; 3] {
    [p[0], p[2], -p[1]]
}

/// How many tile instances a client would create if each DAG node were a
/// tile listed under every parent (its subtree shared through an external
/// tileset), per node: the number of paths from a root, averaged. The
/// reason the export is a tree of cells (see the module doc).
pub fn dag_instances(store: &Store) -> f64 {
    let n = store.nodes.len();
    let mut paths = vec![0f64; n];
    // Parents have higher ids than their children.
    for i in (0..n).rev() {
        let ps = store.parents_of(i);
        paths[i] = if ps.is_empty() { 1.0 } else { ps.iter().map(|&p| paths[p as usize]).sum() };
    }
    let leaves = store.level_nodes(0);
    leaves.iter().map(|&i| paths[i]).sum::<f64>() / leaves.len().max(1) as f64
}

/// The tile tree of a store, before any content is written: the cells of
/// every level, nested, with their errors (see the module doc).
pub struct Plan {
    cube: Cube,
    cuts: Vec<LevelCut>,
    /// Tiles, the top level's first; a tile's children come after it.
    pub tiles: Vec<PlanTile>,
    /// The model's up axis.
    pub up: DVec3,
}

/// One tile of a [`Plan`].
#[derive(Clone, Debug)]
pub struct PlanTile {
    pub level: u8,
    cell: Cell,
    /// The cell's box (content reaches out of it by up to a triangle).
    pub cell_bounds: Aabb,
    /// The tile's largest node error, raised to its children's; 0 at level 0.
    pub error: f64,
    /// Skirt length: twice the coarser of its and its parent's errors.
    pub skirt: f64,
    pub children: Vec<usize>,
    pub parent: Option<usize>,
}

/// Plans the tiles of `store`: one counting pass over every level, top
/// down (see the module doc).
pub fn plan(store: &Store, o: &TilesOptions) -> Result<Plan> {
    if o.tile_tris < 256 {
        return Err(Error::Usage(format!("--tile-tris {} is below the minimum 256", o.tile_tris)));
    }
    let bounds = store.header.bbox;
    let cube = Cube::around(&bounds);
    let top = store.top_level();
    let level0 = store.level_triangles(0).max(1);
    // Counting cells hold about 1/64 of a tile of level 0 (a surface: 4x
    // the cells per depth).
    let fine = ((64.0 * level0 as f64 / o.tile_tris as f64).max(1.0).log(4.0).ceil() as u32).clamp(1, MAX_DEPTH);
    let progress = Progress::items(store.nodes.len() as u64, "counting", o.quiet);
    let mut cuts: Vec<LevelCut> = Vec::new();
    let mut coarse = vec![Cell::ROOT];
    for level in (0..=top).rev() {
        let (counts, reach) = count_level(store, level, &cube, fine, &progress)?;
        let (cells, error) = cut_level(&coarse, &counts, fine, o.tile_tris);
        coarse = cells.clone();
        cuts.push(LevelCut { cells, error, reach });
    }
    cuts.reverse(); // cuts[level]
    progress.finish();

    // The tree: a level-L tile's children are the level-(L-1) tiles in its cell.
    let mut tiles: Vec<PlanTile> = Vec::new();
    let mut first = vec![0usize; top as usize + 2];
    for level in (0..=top).rev() {
        first[level as usize] = tiles.len();
        let c = &cuts[level as usize];
        for k in 0..c.cells.len() {
            tiles.push(PlanTile {
                level,
                cell: c.cells[k],
                cell_bounds: cube.bounds(c.cells[k]),
                error: if level == 0 { 0.0 } else { c.error[k] },
                skirt: 0.0,
                children: Vec::new(),
                parent: None,
            });
        }
    }
    for level in 1..=top {
        let above: FxHashMap<Cell, usize> = cuts[level as usize].cells.iter().enumerate().map(|(k, &c)| (c, k)).collect();
        for (k, &c) in cuts[level as usize - 1].cells.iter().enumerate() {
            // The cells nest: one ancestor (or the cell itself) is above.
            let p = (0..=c.depth).rev().find_map(|d| above.get(&c.ancestor(d)).copied()).expect("cells nest level to level");
            let (pt, ct) = (first[level as usize] + p, first[level as usize - 1] + k);
            tiles[pt].children.push(ct);
            tiles[ct].parent = Some(pt);
        }
    }
    // Errors monotone from the leaves up (children have higher indices).
    for t in (0..tiles.len()).rev() {
        let m = tiles[t].children.iter().map(|&c| tiles[c].error).fold(0.0, f64::max);
        tiles[t].error = tiles[t].error.max(m);
    }
    for t in 0..tiles.len() {
        let p = tiles[t].parent.map_or(0.0, |p| tiles[p].error);
        tiles[t].skirt = 2.0 * tiles[t].error.max(p);
    }
    Ok(Plan { cube, cuts, tiles, up: o.up.resolve(&bounds) })
}

/// A tile's content: its level's triangles reaching into its cell, welded,
/// then its skirt's triangles; `None` when the level has no triangle there.
pub fn tile_content(store: &Store, plan: &Plan, t: usize) -> Result<Option<TileMesh>> {
    tile_content_cached(store, plan, t, &NodeCache::new(0))
}

/// [`tile_content`], reading nodes through `cache`.
fn tile_content_cached(store: &Store, plan: &Plan, t: usize, cache: &NodeCache) -> Result<Option<TileMesh>> {
    let tile = &plan.tiles[t];
    let reach = plan.cuts[tile.level as usize].reach;
    // Nodes holding a triangle beside the content's edge too (to tell a cut
    // edge from the mesh's own border): a node's triangles have their
    // centroids in its cell, so they lie within `reach` of it.
    let near_box = grow(&tile.cell_bounds, 3.0 * reach);
    let near: Vec<usize> = store.level_nodes(tile.level).into_iter().filter(|&i| boxes_meet(&store.nodes[i].cell, &near_box)).collect();
    let tm = tile_mesh(store, &near, &plan.cube, tile.cell, tile.skirt, reach, cache)?;
    Ok((!tm.mesh.triangles.is_empty()).then_some(tm))
}

fn grow(b: &Aabb, by: f64) -> Aabb {
    Aabb { min: (DVec3::from(b.min) - DVec3::splat(by)).to_array(), max: (DVec3::from(b.max) + DVec3::splat(by)).to_array() }
}

/// The cached nodes: node → (mesh, bytes, last use); with the bytes used
/// and the use clock, the [`NodeCache`]'s state.
type CachedNodes = FxHashMap<usize, (std::sync::Arc<IndexedMesh>, u64, u64)>;

/// Decoded nodes shared by the tiles being made (a node reaching several
/// cells is read once while it stays in the cache): least recently used
/// out first, within a byte budget.
struct NodeCache {
    budget: u64,
    inner: std::sync::Mutex<(CachedNodes, u64, u64)>,
}

impl NodeCache {
    fn new(budget: u64) -> NodeCache {
        NodeCache { budget, inner: std::sync::Mutex::new((FxHashMap::default(), 0, 0)) }
    }
    /// Node `i`'s mesh; whether it was read (not found in the cache).
    fn get(&self, store: &Store, i: usize) -> Result<(std::sync::Arc<IndexedMesh>, bool)> {
        {
            let mut g = self.inner.lock().unwrap_or_else(|e| e.into_inner());
            let (map, _, clock) = &mut *g;
            *clock += 1;
            let now = *clock;
            if let Some(e) = map.get_mut(&i) {
                e.2 = now;
                return Ok((e.0.clone(), false));
            }
        }
        let m = std::sync::Arc::new(store.read_node(i)?.mesh);
        let bytes = (m.vertices.len() * std::mem::size_of::<Vertex>() + m.triangles.len() * 12) as u64;
        if bytes <= self.budget / 2 {
            let mut g = self.inner.lock().unwrap_or_else(|e| e.into_inner());
            let (map, used, clock) = &mut *g;
            while *used + bytes > self.budget && !map.is_empty() {
                let old = map.iter().min_by_key(|(_, e)| e.2).map(|(&k, _)| k).expect("not empty");
                *used -= map.remove(&old).map_or(0, |e| e.1);
            }
            *used += bytes;
            map.insert(i, (m.clone(), bytes, *clock));
        }
        Ok((m, true))
    }
}

/// A tile made in parallel: its index and, when it has content, its GLB
/// bytes and mesh.
type MadeTile = (usize, Option<(Vec<u8>, TileMesh)>);

/// Writes the tileset; see the module doc.
pub fn export(store: &Store, out: &Path, o: &TilesOptions) -> Result<TilesReport> {
    let t0 = Instant::now();
    let plan = plan(store, o)?;
    let dir = AtomicDir::create(out, OutputKind::Tiles, o.force)?;
    std::fs::create_dir(dir.path().join("t")).map_err(|e| Error::io(dir.path().join("t"), "create directory", e))?;
    let top = store.top_level();
    let attrs = store.payload_layout.attrs;
    let mut rep_texture_bytes = 0u64;
    let slots = crate::manifest::store_textures(&store.dir);
    let textures = level_textures(&slots, attrs, dir.path(), top, &mut rep_texture_bytes)?;
    // Each level's glTF options: its copies of every texture slot.
    let level_opts: Vec<GltfOptions> = textures.into_iter().map(|textures| GltfOptions { quantize: o.quantize, compress: o.compress, textures }).collect();
    let mut rep = TilesReport { store_triangles: (0..=top).map(|l| store.level_triangles(l)).sum(), texture_bytes: rep_texture_bytes, ..Default::default() };
    rep.tileset_bytes += rep.texture_bytes;
    let n = plan.tiles.len();
    let mut contents: Vec<Option<(String, Aabb)>> = vec![None; n];
    let mut reads = 0u64;
    let progress = Progress::items(n as u64, "writing", o.quiet);
    // Half the budget caches decoded nodes (a node reaches a few cells);
    // tiles go level by level in Morton order, so neighbours share them.
    let cache = NodeCache::new(o.mem / 2);
    let fine = plan.tiles.iter().map(|t| t.cell.depth).max().unwrap_or(0);
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by_key(|&t| (std::cmp::Reverse(plan.tiles[t].level), plan.tiles[t].cell.code << (3 * (fine - plan.tiles[t].cell.depth))));
    // A window of tiles at a time, in parallel: each holds a few nodes.
    let window = (4 * rayon::current_num_threads()).max(2);
    for chunk in order.chunks(window) {
        let made: Vec<Result<MadeTile>> = chunk
            .par_iter()
            .map(|&t| {
                crate::io::signal::check()?;
                let Some(tm) = tile_content_cached(store, &plan, t, &cache)? else { return Ok((t, None)) };
                let level = plan.tiles[t].level as usize;
                let glb = tile_glb(&tm.mesh, attrs, &level_opts[level.min(level_opts.len() - 1)])?;
                Ok((t, Some((glb, tm))))
            })
            .collect();
        for m in made {
            let (t, content) = m?;
            if let Some((glb, tm)) = content {
                let tile = &plan.tiles[t];
                let name = format!("t/{}-{}-{:x}.glb", tile.level, tile.cell.depth, tile.cell.code);
                let p = dir.path().join(&name);
                std::fs::write(&p, &glb).map_err(|e| Error::io(&p, "write", e))?;
                rep.contents += 1;
                rep.triangles += tm.mesh.triangles.len() as u64;
                rep.skirt_triangles += tm.skirt;
                rep.tileset_bytes += glb.len() as u64;
                reads += tm.reads;
                contents[t] = Some((name, tm.bounds));
            }
            progress.inc(1);
        }
    }
    progress.finish();
    let mut tiles: Vec<Tile> = plan
        .tiles
        .iter()
        .zip(contents)
        .map(|(p, c)| Tile {
            level: p.level,
            error: p.error,
            bounds: c.as_ref().map_or(Aabb::EMPTY, |c| c.1),
            content: c.map(|c| c.0),
            children: p.children.clone(),
        })
        .collect();
    // Bounds enclose the children's (children have higher indices).
    for t in (0..tiles.len()).rev() {
        let mut b = tiles[t].bounds;
        for &c in &tiles[t].children {
            b.merge(&tiles[c].bounds);
        }
        tiles[t].bounds = b;
    }
    // Tiles with neither content nor content below them are dropped.
    let keep: Vec<bool> = tiles.iter().map(|t| !t.bounds.is_empty()).collect();
    let json = tileset_json(store, &tiles, &keep, plan.up, &mut rep);
    let ts = dir.path().join("tileset.json");
    let text = serde_json::to_string(&json).expect("the tileset serializes");
    rep.tileset_bytes += text.len() as u64;
    std::fs::write(&ts, text).map_err(|e| Error::io(&ts, "write", e))?;
    rep.tiles = count_tiles(&json["root"]);
    rep.store_bytes = dir_bytes(&store.dir);
    rep.seconds = t0.elapsed().as_secs_f64();
    rep.mtris_per_s = rep.store_triangles as f64 / 1e6 / rep.seconds.max(1e-9);
    rep.read_amplification = reads as f64 / store.nodes.len().max(1) as f64;
    dir.commit()?;
    Ok(rep)
}

/// The side of level `level`'s copy of a `side`-texel texture: the whole
/// image at levels 0 and 1, then halved every two levels (a level has
/// half the triangles of the one below, so each triangle covers twice the
/// area: the texels it needs per side shrink by √2 a level), never below
/// 64 texels (nor above the image).
pub fn level_texture_side(side: u32, level: u8) -> u32 {
    let shrunk = side >> (level / 2).min(31);
    shrunk.max(64).min(side)
}

/// A tile's GLB: its mesh (in the store's frame) turned to glTF's Y-up
/// frame, its folds facing their normals (`face_their_normals`), one
/// primitive per material drawing its level's copy of the material's
/// texture (`opts`: the level's [`GltfOptions`]).
pub fn tile_glb(mesh: &IndexedMesh, attrs: crate::mesh::AttrSet, opts: &GltfOptions) -> Result<Vec<u8>> {
    let mut g = mesh.clone();
    face_their_normals(&mut g);
    for v in &mut g.vertices {
        v.pos = to_gltf(v.pos);
        v.normal = to_gltf(v.normal.map(|x| x as f64)).map(|x| x as f32);
    }
    let mut glb = Vec::new();
    encode_glb(&g, attrs, opts, &mut glb)?;
    Ok(glb)
}

/// Writes each level's copy of the store's textures `slots` (by material
/// id, [`crate::manifest::store_textures`]) into `dir/t/`
/// (`texture-K-SIDE.EXT` for slot K; levels of one size share a file; the
/// full size is the store's own file, unchanged) and gives each level's
/// glTF textures by material id (levels `0..=top`); none when `attrs` has
/// no uvs. Without [`crate::mesh::AttrSet::MATERIAL`] every face draws the
/// first slot with an image, so only that one is copied. A slot without an
/// image, or (with a warning) whose image does not decode, is `None`: its
/// faces are drawn untextured. One image is decoded at a time, straight
/// at the size of its largest copy that is not the file itself (a PNG row
/// by row: an 8192² atlas holds its 4096² copy, not 256 MiB). Copies of a
/// PNG are PNG, of anything else JPEG (quality 90).
fn level_textures(
    slots: &[Option<(String, std::path::PathBuf)>],
    attrs: crate::mesh::AttrSet,
    dir: &Path,
    top: u8,
    bytes_written: &mut u64,
) -> Result<Vec<Vec<Option<crate::gltf::GltfTexture>>>> {
    use crate::gltf::{GltfTexture, TextureImage};
    let mut out: Vec<Vec<Option<GltfTexture>>> = vec![vec![None; slots.len()]; top as usize + 1];
    if !attrs.uv() {
        return Ok(out);
    }
    let first = slots.iter().position(|s| s.is_some());
    for (k, slot) in slots.iter().enumerate() {
        let Some((file, src)) = slot else { continue };
        if !attrs.material() && Some(k) != first {
            continue;
        }
        // Its signature: the file itself is only copied.
        let mut head = Vec::with_capacity(8);
        std::fs::File::open(src)
            .and_then(|f| std::io::Read::read_to_end(&mut std::io::Read::take(f, 8), &mut head))
            .map_err(|e| Error::io(src, "read texture", e))?;
        let bad = |what: String| Error::input(crate::error::Location { file: src.clone(), ..Default::default() }, what);
        let mime = crate::gltf::image_mime(&head);
        let png = mime == Some("image/png");
        // The chain level each level's copy takes (the first no larger than
        // its side), from the full size alone.
        let mips = |(w, h): (u32, u32)| -> Vec<u32> {
            let mut sides = vec![(w, h)];
            while let Some(&s) = sides.last().filter(|&&s| s != (1, 1)) {
                sides.push(crate::view::texture::halve(s));
            }
            let pick = |side: u32| sides.iter().position(|l| l.0.max(l.1) <= side).unwrap_or(sides.len() - 1) as u32;
            (0..=top).map(|level| pick(level_texture_side(w.max(h), level))).collect()
        };
        // Decoded straight at the largest copy that is not the file itself
        // (the full size never lies in memory whole; see
        // `view::texture::decode`); the smaller copies are its chain. With
        // no such copy the file is still decoded, small, to check it.
        let first_mip = |full: (u32, u32)| match mime {
            None => 0,
            Some(_) => mips(full).into_iter().filter(|&m| m > 0).min().unwrap_or(1),
        };
        let r = match crate::view::texture::decode::decode_reduced(src, first_mip) {
            Ok(r) => r,
            Err(crate::view::texture::decode::DecodeError::Read(e)) => return Err(Error::io(src, "read texture", e)),
            Err(crate::view::texture::decode::DecodeError::Decode(e)) => {
                // The geometry is the tileset; a texture it cannot carry is left out.
                eprintln!("warning: {}; the tiles draw its faces without it", bad(format!("cannot decode the texture: {e}")));
                continue;
            }
        };
        let (w, h) = r.full;
        let chain = crate::view::texture::MipChain::new(file, r.level.width, r.level.height, r.level.rgba);
        let ext = if png { "png" } else { "jpg" };
        // Mip levels already written (levels of one size share a file).
        let mut written: Vec<u32> = Vec::new();
        for (level, mip) in (0..=top).zip(mips((w, h))) {
            // Level 0 is the file itself (copied), or (no PNG or JPEG
            // signature) decoded whole.
            let l = if mip == 0 && mime.is_some() { None } else { Some(&chain.levels[(mip - r.dropped) as usize]) };
            let side = l.map_or(w.max(h), |l| l.width.max(l.height));
            let stem = format!("texture-{k}-{side}");
            let name = format!("{stem}.{ext}");
            if !written.contains(&mip) {
                let path = dir.join("t").join(&name);
                match l {
                    None => std::fs::copy(src, &path).map(drop).map_err(|e| Error::io(&path, "write", e))?,
                    Some(l) => encode_image(&path, l, png)?,
                }
                *bytes_written += std::fs::metadata(&path).map_err(|e| Error::io(&path, "stat", e))?.len();
                written.push(mip);
            }
            out[level as usize][k] = Some(GltfTexture { name: stem, image: TextureImage::Uri(name) });
        }
    }
    Ok(out)
}

/// Writes one mip level as PNG or JPEG (quality 90, alpha dropped).
fn encode_image(path: &Path, l: &crate::view::texture::MipLevel, png: bool) -> Result<()> {
    use ::image::ImageEncoder;
    let f = std::fs::File::create(path).map_err(|e| Error::io(path, "create", e))?;
    let mut w = std::io::BufWriter::new(f);
    let r = if png {
        ::image::codecs::png::PngEncoder::new(&mut w).write_image(&l.rgba, l.width, l.height, ::image::ExtendedColorType::Rgba8)
    } else {
        let rgb: Vec<u8> = l.rgba.chunks_exact(4).flat_map(|p| [p[0], p[1], p[2]]).collect();
        ::image::codecs::jpeg::JpegEncoder::new_with_quality(&mut w, 90).write_image(&rgb, l.width, l.height, ::image::ExtendedColorType::Rgb8)
    };
    r.map_err(|e| Error::Usage(format!("{}: cannot encode the texture copy: {e}", path.display())))?;
    std::io::Write::flush(&mut w).map_err(|e| Error::io(path, "write", e))
}

/// Turns the few triangles that face against their vertex normals (the
/// rare folds a coarse level keeps) to face with them. octolod's shader lights both sides by the vertex
/// normals; a glTF client lights a back face with the normals reversed, so
/// a fold shows as a dark speck there. A display format only: the store
/// and `extract` keep the triangles as they are.
fn face_their_normals(m: &mut IndexedMesh) {
    for t in &mut m.triangles {
        let p = t.map(|i| DVec3::from(m.vertices[i as usize].pos));
        let n: DVec3 = t.iter().map(|&i| DVec3::from(m.vertices[i as usize].normal.map(|x| x as f64))).sum();
        if (p[1] - p[0]).cross(p[2] - p[0]).dot(n) < 0.0 {
            t.swap(1, 2);
        }
    }
}

fn count_tiles(t: &serde_json::Value) -> u64 {
    1 + t["children"].as_array().map_or(0, |c| c.iter().map(count_tiles).sum())
}

fn dir_bytes(d: &Path) -> u64 {
    std::fs::read_dir(d).map(|it| it.filter_map(|e| e.ok()).filter_map(|e| e.metadata().ok()).map(|m| m.len()).sum()).unwrap_or(0)
}

/// A tile's mesh (its level's triangles, then its skirt's), its bounds,
/// how many of its triangles are skirt and how many nodes it read.
#[derive(Clone, Debug)]
pub struct TileMesh {
    pub mesh: IndexedMesh,
    pub bounds: Aabb,
    pub skirt: u64,
    pub reads: u64,
}

/// An edge by its end positions' bits, in either direction.
type EdgeKey = ([u64; 3], [u64; 3]);

fn edge_key(a: &Vertex, b: &Vertex) -> EdgeKey {
    let (pa, pb) = (a.pos.map(f64::to_bits), b.pos.map(f64::to_bits));
    if pa <= pb {
        (pa, pb)
    } else {
        (pb, pa)
    }
}

/// The level's triangles that reach into `cell`, from `near` (the level's
/// nodes reaching it), welded, with skirts of length `skirt` along the
/// edges where the content stops.
#[allow(clippy::too_many_arguments)]
fn tile_mesh(store: &Store, near: &[usize], cube: &Cube, cell: Cell, skirt: f64, reach: f64, cache: &NodeCache) -> Result<TileMesh> {
    let cb = cube.bounds(cell);
    // Triangles sharing an edge with the content lie within `reach` of it.
    let ring = grow(&cb, 2.0 * reach);
    // Every edge near the content with how many triangles use it: an edge
    // the cell cut has a triangle outside the tile; one on the mesh's own
    // border has a single triangle in the whole level.
    let mut uses: FxHashMap<EdgeKey, u32> = FxHashMap::default();
    let mut parts = Vec::new();
    let mut reads = 0;
    for &i in near {
        let (node, read) = cache.get(store, i)?;
        reads += read as u64;
        let mut keep = Vec::new();
        for t in &node.triangles {
            let mut tb = Aabb::EMPTY;
            for &v in t {
                tb.add(node.vertices[v as usize].pos);
            }
            if !boxes_meet(&tb, &ring) {
                continue;
            }
            for k in 0..3 {
                *uses.entry(edge_key(&node.vertices[t[k] as usize], &node.vertices[t[(k + 1) % 3] as usize])).or_insert(0) += 1;
            }
            if boxes_meet(&tb, &cb) {
                keep.push(*t);
            }
        }
        if !keep.is_empty() {
            parts.push(IndexedMesh { vertices: node.vertices.clone(), triangles: keep });
        }
    }
    let mut mesh = crate::pipeline::weld_union(&store.payload_layout, &parts);
    drop(parts);
    // The tile's own edges used once: cut by the cell unless the level uses
    // them once too.
    let mut own: FxHashMap<EdgeKey, (u32, [u32; 2])> = FxHashMap::default();
    for t in &mesh.triangles {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            let e = own.entry(edge_key(&mesh.vertices[a as usize], &mesh.vertices[b as usize])).or_insert((0, [a, b]));
            e.0 += 1;
        }
    }
    let cut: FxHashSet<EdgeKey> = own.iter().filter(|(k, (n, _))| *n == 1 && uses.get(*k).copied().unwrap_or(0) > 1).map(|(k, _)| *k).collect();
    let mut edges: Vec<[u32; 2]> = own.iter().filter(|(k, _)| cut.contains(*k)).map(|(_, (_, e))| *e).collect();
    edges.sort_unstable();
    let tris_before = mesh.triangles.len();
    // Skirt vertices: each cut edge's ends, moved into the surface; the
    // strip starts a twentieth of its length below the edge, so it never
    // shares the edge's pixels with the surface beside it (a depth tie the
    // strip's back side won there, as dark pixels).
    let mut lowered: FxHashMap<(u32, bool), u32> = FxHashMap::default();
    let mut lower = |mesh: &mut IndexedMesh, v: u32, bottom: bool| -> u32 {
        *lowered.entry((v, bottom)).or_insert_with(|| {
            let mut w = mesh.vertices[v as usize];
            let n = DVec3::from(w.normal.map(|x| x as f64)).normalize_or_zero();
            w.pos = (DVec3::from(w.pos) - n * if bottom { skirt } else { 0.05 * skirt }).to_array();
            mesh.vertices.push(w);
            (mesh.vertices.len() - 1) as u32
        })
    };
    for e in &edges {
        let [la, lb] = [lower(&mut mesh, e[0], true), lower(&mut mesh, e[1], true)];
        let [a, b] = [lower(&mut mesh, e[0], false), lower(&mut mesh, e[1], false)];
        // One winding, facing away from the content (a→b runs as in its
        // counter-clockwise triangle, so the content lies to the left): the
        // side a viewer sees through a slit is the front, shaded with the
        // surface's normals. (Two windings under a double-sided material
        // fight for the same pixels, the back one dark.)
        mesh.triangles.extend([[a, la, lb], [a, lb, b]]);
    }
    let mut bounds = Aabb::EMPTY;
    for v in &mesh.vertices {
        bounds.add(v.pos);
    }
    let skirt_tris = (mesh.triangles.len() - tris_before) as u64;
    Ok(TileMesh { mesh, bounds, skirt: skirt_tris, reads })
}

/// `tileset.json` for the kept tiles; fills the report's depth.
fn tileset_json(store: &Store, tiles: &[Tile], keep: &[bool], up: DVec3, rep: &mut TilesReport) -> serde_json::Value {
    use serde_json::json;
    fn bv(b: &Aabb) -> serde_json::Value {
        let c = b.center();
        let h = (0..3).map(|k| (0.5 * (b.max[k] - b.min[k])).max(1e-9)).collect::<Vec<f64>>();
        json!({ "box": [c[0], c[1], c[2], h[0], 0.0, 0.0, 0.0, h[1], 0.0, 0.0, 0.0, h[2]] })
    }
    // A tile without content (its level has no triangle in its cell)
    // would draw nothing where it is not refined: its children take its
    // place under its parent.
    fn kids(tiles: &[Tile], keep: &[bool], t: usize, depth: u32, max_depth: &mut u32) -> Vec<serde_json::Value> {
        let mut v = Vec::new();
        for &c in tiles[t].children.iter().filter(|&&c| keep[c]) {
            if tiles[c].content.is_none() {
                v.extend(kids(tiles, keep, c, depth, max_depth));
            } else {
                v.push(tile(tiles, keep, c, depth, max_depth));
            }
        }
        v
    }
    fn tile(tiles: &[Tile], keep: &[bool], t: usize, depth: u32, max_depth: &mut u32) -> serde_json::Value {
        *max_depth = (*max_depth).max(depth);
        let x = &tiles[t];
        // No content (only a root can be so): showing nothing errs by the
        // tile's size, so it refines unless the whole tile is tiny.
        let error = if x.content.is_some() { x.error } else { x.error.max(x.bounds.diagonal()) };
        let mut j = json!({ "boundingVolume": bv(&x.bounds), "geometricError": error });
        if let Some(uri) = &x.content {
            j["content"] = json!({ "uri": uri });
        }
        let k = kids(tiles, keep, t, depth + 1, max_depth);
        if !k.is_empty() {
            j["children"] = serde_json::Value::Array(k);
        }
        j
    }
    let mut depth = 0;
    let roots: Vec<usize> = (0..tiles.len()).filter(|&t| tiles[t].level == store.top_level() && keep[t]).collect();
    let mut root = if roots.len() == 1 {
        tile(tiles, keep, roots[0], 0, &mut depth)
    } else {
        // Several top cells: a root without content above them.
        let mut b = Aabb::EMPTY;
        for &r in &roots {
            b.merge(&tiles[r].bounds);
        }
        let k: Vec<serde_json::Value> = roots.iter().map(|&r| tile(tiles, keep, r, 1, &mut depth)).collect();
        json!({ "boundingVolume": bv(&b), "geometricError": b.diagonal(), "children": k })
    };
    let r = up_to_z(up);
    // Column-major: the columns are the images of X, Y, Z.
    let transform: Vec<f64> = (0..3).flat_map(|col| (0..3).map(move |row| r[row][col]).chain([0.0])).chain([0.0, 0.0, 0.0, 1.0]).collect();
    root["refine"] = json!("REPLACE");
    root["transform"] = json!(transform);
    let top_error = root["geometricError"].as_f64().unwrap_or(0.0);
    rep.depth = depth;
    let b = &store.header.bbox;
    let b_diag = b.diagonal();
    json!({
        "asset": {
            "version": "1.1",
            "generator": format!("octolod {}", env!("CARGO_PKG_VERSION")),
            "extras": { "octolod": { "up": [up.x, up.y, up.z], "bounds": { "min": b.min, "max": b.max }, "attributes": store.header.attrs.describe() } }
        },
        // The error of drawing nothing: the model's size.
        "geometricError": top_error.max(b_diag),
        "root": root,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cells_nest_and_map_positions() {
        let cube = Cube::around(&Aabb { min: [0.0; 3], max: [8.0, 4.0, 2.0] });
        let p = DVec3::new(7.9, 0.1, 1.9);
        let c = cube.cell(p, 3);
        assert!(Cell::ROOT.contains(c) && c.ancestor(1).contains(c));
        let b = cube.bounds(c);
        assert!((0..3).all(|k| b.min[k] <= p[k] && p[k] <= b.max[k]), "{b:?}");
        for d in 0..3 {
            assert_eq!(cube.cell(p, d), c.ancestor(d));
        }
        assert_eq!(Cell::ROOT.children().filter(|k| k.contains(c)).count(), 1);
    }

    #[test]
    fn up_axes_turn_to_z_right_handed() {
        for up in [DVec3::X, DVec3::Y, DVec3::Z, -DVec3::X, -DVec3::Y, -DVec3::Z, DVec3::new(1.0, 2.0, 3.0)] {
            let r = up_to_z(up);
            let img = DVec3::new(r[0].dot(up), r[1].dot(up), r[2].dot(up)) / up.length();
            assert!((img - DVec3::Z).length() < 1e-12, "{up}");
            assert!((r[0].cross(r[1]) - r[2]).length() < 1e-12);
        }
        // The glTF frame and its Y-up → Z-up turn round-trip.
        let p = [1.0, 2.0, 3.0];
        let g = to_gltf(p);
        assert_eq!([g[0], -g[2], g[1]], p);
    }

    /// The file names in `d`, sorted.
    fn names(d: &Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(d).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
        v.sort();
        v
    }

    /// A `side`² PNG at `path`.
    fn png(path: &Path, side: u32) {
        ::image::RgbaImage::from_fn(side, side, |x, y| ::image::Rgba([x as u8, y as u8, 7, 255])).save(path).unwrap();
    }

    /// Issue 32: every texture slot gets its per-level copies, named by
    /// slot; a slot without an image or whose image does not decode draws
    /// untextured; without per-face materials only the first image is copied.
    #[test]
    fn each_texture_slot_gets_its_level_copies() {
        use crate::gltf::TextureImage;
        use crate::mesh::AttrSet;
        let d = tempfile::tempdir().unwrap();
        let (src, out) = (d.path().join("store"), d.path().join("out"));
        std::fs::create_dir_all(&src).unwrap();
        std::fs::create_dir_all(out.join("t")).unwrap();
        png(&src.join("texture-0.png"), 256);
        png(&src.join("texture-2.png"), 128);
        std::fs::write(src.join("texture-3.png"), b"not an image").unwrap();
        let slot = |f: &str| Some((f.to_string(), src.join(f)));
        let slots = vec![slot("texture-0.png"), None, slot("texture-2.png"), slot("texture-3.png")];
        let uris = |v: &[Option<crate::gltf::GltfTexture>]| -> Vec<Option<String>> {
            v.iter()
                .map(|t| {
                    t.as_ref().map(|t| match &t.image {
                        TextureImage::Uri(u) => u.clone(),
                        TextureImage::Embedded { .. } => panic!("tiles name their images"),
                    })
                })
                .collect()
        };
        let mut bytes = 0;
        let attrs = AttrSet(AttrSet::UV | AttrSet::MATERIAL);
        let levels = level_textures(&slots, attrs, &out, 4, &mut bytes).unwrap();
        assert_eq!(levels.len(), 5);
        let s = |x: &str| Some(x.to_string());
        assert_eq!(uris(&levels[0]), [s("texture-0-256.png"), None, s("texture-2-128.png"), None]);
        assert_eq!(uris(&levels[1]), [s("texture-0-256.png"), None, s("texture-2-128.png"), None]);
        assert_eq!(uris(&levels[2]), [s("texture-0-128.png"), None, s("texture-2-64.png"), None]);
        assert_eq!(uris(&levels[4]), [s("texture-0-64.png"), None, s("texture-2-64.png"), None]);
        let files = names(&out.join("t"));
        assert_eq!(files, ["texture-0-128.png", "texture-0-256.png", "texture-0-64.png", "texture-2-128.png", "texture-2-64.png"]);
        let total: u64 = files.iter().map(|f| std::fs::metadata(out.join("t").join(f)).unwrap().len()).sum();
        assert_eq!(bytes, total);
        assert_eq!(std::fs::read(out.join("t/texture-2-128.png")).unwrap(), std::fs::read(src.join("texture-2.png")).unwrap(), "full size: the store's file");
        // Without MATERIAL: the first slot with an image only.
        let out2 = d.path().join("out2");
        std::fs::create_dir_all(out2.join("t")).unwrap();
        let levels = level_textures(&slots[1..], AttrSet(AttrSet::UV), &out2, 1, &mut 0).unwrap();
        assert_eq!(uris(&levels[1]), [None, s("texture-1-128.png"), None]);
        assert_eq!(names(&out2.join("t")), ["texture-1-128.png"]);
        // Without uvs: nothing.
        let levels = level_textures(&slots, AttrSet(AttrSet::MATERIAL), &out2, 1, &mut 0).unwrap();
        assert!(levels.iter().flatten().all(|t| t.is_none()));
    }

    /// A tile of a mesh with materials: a primitive per material, each
    /// drawing its level's copy of its texture by URI.
    #[test]
    fn a_tile_draws_each_material_with_its_levels_copy() {
        use crate::gltf::{GltfTexture, TextureImage};
        use crate::mesh::AttrSet;
        let mats = [1u16, 0, Vertex::NO_TEXTURE, 1, 1];
        let mut m = IndexedMesh::default();
        for (k, &material) in mats.iter().enumerate() {
            let x = k as f64;
            for p in [[x, 0.0, 0.0], [x + 1.0, 0.0, 0.0], [x, 1.0, 0.0]] {
                m.vertices.push(Vertex { pos: p, normal: [0.0, 0.0, 1.0], uv: [0.5, 0.5], material, ..Default::default() });
            }
            m.triangles.push([3 * k as u32, 3 * k as u32 + 1, 3 * k as u32 + 2]);
        }
        let uri = |u: &str| Some(GltfTexture { name: u.trim_end_matches(".jpg").into(), image: TextureImage::Uri(u.into()) });
        for compress in [false, true] {
            let opts = GltfOptions { quantize: compress, compress, textures: vec![uri("texture-0-64.jpg"), uri("texture-1-128.jpg")] };
            let glb = tile_glb(&m, AttrSet(AttrSet::UV | AttrSet::NORMAL | AttrSet::MATERIAL), &opts).unwrap();
            let jl = u32::from_le_bytes(glb[12..16].try_into().unwrap()) as usize;
            let j: serde_json::Value = serde_json::from_slice(&glb[20..20 + jl]).unwrap();
            let prims = j["meshes"][0]["primitives"].as_array().unwrap();
            let got: Vec<(u64, Option<&str>)> = prims
                .iter()
                .map(|p| {
                    let n = j["accessors"][p["indices"].as_u64().unwrap() as usize]["count"].as_u64().unwrap() / 3;
                    let mat = &j["materials"][p["material"].as_u64().unwrap() as usize]["pbrMetallicRoughness"];
                    let img = mat["baseColorTexture"]["index"]
                        .as_u64()
                        .map(|t| j["images"][j["textures"][t as usize]["source"].as_u64().unwrap() as usize]["uri"].as_str().unwrap());
                    (n, img)
                })
                .collect();
            assert_eq!(got, [(1, Some("texture-0-64.jpg")), (3, Some("texture-1-128.jpg")), (1, None)]);
            assert_eq!(j["images"].as_array().unwrap().len(), 2);
        }
    }
}

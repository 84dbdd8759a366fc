//! LOD stage (levels of detail v2): a DAG of levels that halve, each level
//! partitioned afresh so the previous level's seams are simplified, every
//! cut crack-free (a batched multi-triangulation, Cignoni et al. 2005).
//!
//! Takes: the input's triangle soup (`.soup`), or level 0 already
//! partitioned by the soup stage ([`Level0Source`]), the memory budget and the
//! hierarchy's parameters ([`LodOptions`]). Gives: the store's payloads
//! (`level-L.pack`), its node records and children/parents lists, and a
//! report per level ([`LevelReport`]).
//!
//! [`build`] runs [`level::LevelBuilder`]'s steps once per level:
//! 1. *partition* — an adaptive octree per level over a cube shifted by a
//!    third of its size from the level below's ([`partition`], [`octree`]);
//! 2. *shared vertices* — a node locks exactly the positions it shares
//!    with another node of its level, and its attribute seams ([`shared`]);
//! 3. *threshold* — one error limit for the level, from a sample of nodes'
//!    curves, so that it holds 1/`--level-ratio` of the triangles below;
//! 4. *simplify and route* — each node reduced by its [`simplifier`]
//!    (quadric clustering with the input's quadrics carried, [`cluster`];
//!    or edge collapse, [`collapse`]), its output routed as [`chunks`] to
//!    the next level's cells, predicted before this level is simplified;
//! 5. *measure* — a node's error is the largest over its children of the
//!    child's error plus its measured simplification error ([`measure`]),
//!    so projected error never grows towards the root;
//! 6. *link the DAG* — children lists in patch order and their inverse.
//!
//! Invariants: shared positions stay bit-exact, so every cut is closed
//! wherever the input is; bounds and errors are monotone from leaf to root;
//! memory stays within `--mem`. Design, proofs and costs:
//! `docs/levels-of-detail.md`.

pub mod chunks;
pub mod cluster;
pub mod collapse;
pub mod level;
pub mod measure;
pub mod octree;
pub mod ordered;
pub mod partition;
pub mod shared;
pub mod simplifier;
mod welded;

use crate::error::{Error, Result};
use crate::manifest::{BuildParams, LevelReport, Simplifier};
use crate::mesh::{Aabb, IndexedMesh};
use crate::store::{NodeRec, StoreHeader};
use level::LevelBuilder;
use octree::{build_octree, FirstCount, Level0, OctreeOptions, OctreeReport};
use partition::LevelCube;
use simplifier::{ClusterNodes, CollapseNodes, NodeSimplifier};
use std::path::Path;

/// Parameters of the hierarchy.
#[derive(Clone, Debug)]
pub struct LodOptions {
    /// `build`'s options (sizes, ratio, budget, simplifier).
    pub params: BuildParams,
    /// Eigenvalue cut-off of the representatives' solve.
    pub rel_tol: f64,
    pub quiet: bool,
}

impl Default for LodOptions {
    fn default() -> Self {
        LodOptions { params: BuildParams::default(), rel_tol: 1e-3, quiet: true }
    }
}

/// Per leaf of a level's tiling: what its triangles add up to.
#[derive(Clone, Debug)]
pub struct LeafStats {
    pub tris: u64,
    pub bounds: Aabb,
    /// Largest distance per axis from the point a triangle's leaf was
    /// chosen by (its centroid; level 0: its first corner) to its corners.
    pub reach: f64,
}

impl LeafStats {
    /// Counts a triangle (corners `c`; `chosen_by`: the point its leaf was chosen by).
    #[inline]
    pub fn add_triangle(&mut self, c: [[f64; 3]; 3], chosen_by: [f64; 3]) {
        self.tris += 1;
        for p in c {
            self.bounds.add(p);
            for a in 0..3 {
                self.reach = self.reach.max((p[a] - chosen_by[a]).abs());
            }
        }
    }
}

impl Default for LeafStats {
    fn default() -> Self {
        LeafStats { tris: 0, bounds: Aabb::EMPTY, reach: 0.0 }
    }
}

/// What the builder gives the store.
pub struct Built {
    pub header: StoreHeader,
    pub nodes: Vec<NodeRec>,
    pub children: Vec<u32>,
    pub parents: Vec<u32>,
    pub levels: Vec<LevelReport>,
    pub octree: OctreeReport,
    /// How the levels' normals were made (`auto` resolved; `carry` for an
    /// input without normals, whose levels derive theirs).
    pub normals: crate::manifest::Normals,
    /// The quadrics' dimension (without derived normals).
    pub quadric_dim: usize,
}

/// Most levels built: halving from 2^40 triangles takes 30. A build that
/// would need more (a `--level-ratio` near 1) is an error naming it, up
/// front when the ratio alone says so (`check_level_count`), else when
/// the level is reached.
pub const MAX_LEVELS: u8 = 64;

/// Depth of the centroid histograms that predict the next level's cells
/// (1024 cells per axis; coarsened when they outgrow their memory share).
const HIST_DEPTH: u8 = 10;

/// Nodes per level whose split curves choose the level's threshold.
const SAMPLED_NODES: usize = 32;

impl LodOptions {
    /// The level-0 partition's options.
    pub fn octree(&self) -> OctreeOptions {
        OctreeOptions { leaf_tris: self.params.leaf_tris, max_depth: self.params.max_depth, mem: self.params.mem, quiet: self.quiet }
    }
}

/// Where level 0 comes from.
pub enum Level0Source<'a> {
    /// A soup file, partitioned here; with level 0's first counting pass
    /// when it was done as the soup was made.
    Soup(&'a Path, Option<FirstCount>),
    /// Partitioned as the soup stage placed the triangles (no soup file).
    Routed(Level0),
}

/// Checks the hierarchy's parameters (the CLI calls it before any work):
/// `--level-ratio` a finite number above 1, `--root-tris` at least 1,
/// `--max-depth` within 1..=21.
pub fn check_params(p: &BuildParams) -> Result<()> {
    if !(p.level_ratio > 1.0 && p.level_ratio.is_finite()) {
        return Err(Error::Usage(format!("--level-ratio must be a number above 1, not {}", p.level_ratio)));
    }
    if p.root_tris == 0 {
        return Err(Error::Usage("--root-tris must be at least 1".into()));
    }
    if !(1..=partition::KEY_DEPTH).contains(&p.max_depth) {
        return Err(Error::Usage(format!("--max-depth must be within 1..={}, not {}", partition::KEY_DEPTH, p.max_depth)));
    }
    Ok(())
}

/// Fewest levels above level 0 that `triangles` need to reach a root of at
/// most `--root-tris` at `--level-ratio` (each level at best 1/ratio of the
/// one below); an error naming `--level-ratio` when that is more than
/// [`MAX_LEVELS`] and `--levels` does not stop the build sooner.
fn check_level_count(p: &BuildParams, triangles: u64) -> Result<()> {
    if p.levels.is_some_and(|l| l <= MAX_LEVELS) || triangles <= p.root_tris {
        return Ok(());
    }
    let needed = ((triangles as f64 / p.root_tris as f64).ln() / p.level_ratio.ln()).ceil();
    if needed > MAX_LEVELS as f64 {
        return Err(Error::Usage(format!(
            "--level-ratio {} would take at least {needed} levels to bring {triangles} triangles down to a root of --root-tris {}, \
             more than the {MAX_LEVELS} levels a store holds: raise --level-ratio (2 halves each level) or --root-tris, or stop at --levels L",
            p.level_ratio, p.root_tris
        )));
    }
    Ok(())
}

/// Builds every level from `input` into store directory `dir`: level 0
/// partitioned, then the level builder's steps once per level
/// ([`level::LevelBuilder`]) with the chosen node simplifier, then the DAG
/// linked.
pub fn build(input: Level0Source, dir: &Path, opts: &LodOptions) -> Result<Built> {
    check_params(&opts.params)?;
    let scratch = crate::io::scratch_dir(dir)?;
    let l0 = match input {
        Level0Source::Soup(soup, first) => {
            let bbox = crate::soup::format::SoupReader::open(soup)?.header.bbox;
            build_octree(soup, scratch.path().join("chunks-0.bin"), &LevelCube::for_level(&bbox, 0), &opts.octree(), first)?
        }
        Level0Source::Routed(l0) => l0,
    };
    check_level_count(&opts.params, l0.header.triangles)?;
    let attrs = l0.header.attrs;
    struct Whole<'a> {
        l0: Level0,
        dir: &'a Path,
        scratch: crate::io::ScratchDir,
        opts: &'a LodOptions,
    }
    impl WithSimplifier for Whole<'_> {
        type Out = Result<Built>;
        fn run<S: NodeSimplifier>(self, s: S) -> Result<Built> {
            build_levels(LevelBuilder::new(self.l0, self.dir, self.scratch, self.opts, s), 0, random_id())
        }
    }
    with_simplifier(opts, attrs, Whole { l0, dir, scratch, opts })
}

/// Work generic over the node simplifier (a generic closure, as a trait):
/// [`with_simplifier`] runs it with the one `--simplifier` chose.
pub trait WithSimplifier {
    type Out;
    fn run<S: NodeSimplifier>(self, s: S) -> Self::Out;
}

/// The one place a simplifier is chosen: runs `w` with `opts`' simplifier
/// for a mesh with `attrs` (a new simplifier is a type and a line here).
/// With `--normals average` clustering leaves normals out of its quadrics
/// (`auto` is resolved by the caller from the input's creases,
/// [`crate::manifest::Normals::resolved`]; unresolved, they are carried).
pub fn with_simplifier<W: WithSimplifier>(opts: &LodOptions, attrs: crate::mesh::AttrSet, w: W) -> W::Out {
    match opts.params.simplifier.resolve(attrs) {
        Simplifier::Cluster | Simplifier::Auto => {
            let mut s = ClusterNodes { attrs, rel_tol: opts.rel_tol, share: 1.0 / opts.params.level_ratio, average_normals: false };
            if attrs.normal() && opts.params.normals == crate::manifest::Normals::Average {
                s.average_normals();
            }
            w.run(s)
        }
        Simplifier::Collapse => w.run(CollapseNodes { attrs, share: 1.0 / opts.params.level_ratio }),
    }
}

/// The attributes the quadrics model for an input with `attrs` whose
/// normals were `normals` (resolved; averaged ones are not modelled).
pub fn quadric_attrs(attrs: crate::mesh::AttrSet, normals: crate::manifest::Normals) -> crate::mesh::AttrSet {
    attrs.with(crate::mesh::AttrSet::NORMAL, attrs.normal() && normals != crate::manifest::Normals::Average)
}

/// Builds the levels from `from` up to the top, then links the DAG under
/// store id `id` (a whole build from level 0, a merge from the shards' top).
pub fn build_levels<S: NodeSimplifier>(mut b: LevelBuilder<S>, from: u8, id: u64) -> Result<Built> {
    for level in from..=MAX_LEVELS {
        if !b.build_level(level)? {
            break;
        }
    }
    b.finish(id)
}

fn leaf_stats(m: &IndexedMesh) -> LeafStats {
    let mut s = LeafStats { tris: m.triangles.len() as u64, ..Default::default() };
    // The reach per corner; the bounds once per vertex used (the same box
    // as over the corners, at a third of the comparisons).
    let mut used = vec![false; m.vertices.len()];
    for t in &m.triangles {
        let c = tri_centroid(m, t);
        for &v in t {
            used[v as usize] = true;
            let p = m.vertices[v as usize].pos;
            for a in 0..3 {
                s.reach = s.reach.max((p[a] - c[a]).abs());
            }
        }
    }
    s.bounds = used_bounds(m, &used);
    s
}

/// The box of the vertices flagged `used` (those of the triangles: the
/// same box as over every corner, a comparison per vertex rather than per
/// corner).
fn used_bounds(m: &IndexedMesh, used: &[bool]) -> Aabb {
    let mut b = Aabb::EMPTY;
    for (v, _) in used.iter().enumerate().filter(|u| *u.1) {
        b.add(m.vertices[v].pos);
    }
    b
}

#[inline]
fn tri_centroid(m: &IndexedMesh, t: &[u32; 3]) -> [f64; 3] {
    centroid(t.map(|v| m.vertices[v as usize].pos))
}

#[inline]
fn centroid(c: [[f64; 3]; 3]) -> [f64; 3] {
    [0, 1, 2].map(|k| (c[0][k] + c[1][k] + c[2][k]) / 3.0)
}

/// Triangles around each vertex: `around[first[v]..first[v + 1]]`.
pub(crate) fn vertex_triangles(nv: usize, tris: &[[u32; 3]]) -> (Vec<u32>, Vec<u32>) {
    let mut first = vec![0u32; nv + 1];
    for t in tris {
        for &v in t {
            first[v as usize + 1] += 1;
        }
    }
    for v in 0..nv {
        first[v + 1] += first[v];
    }
    let mut next = first.clone();
    let mut around = vec![0u32; first[nv] as usize];
    for (ti, t) in tris.iter().enumerate() {
        for &v in t {
            around[next[v as usize] as usize] = ti as u32;
            next[v as usize] += 1;
        }
    }
    (first, around)
}

/// The smallest f32 not below `x` (errors are stored as f32 and must stay conservative).
pub fn next_up_f32(x: f64) -> f32 {
    let f = x as f32;
    if (f as f64) < x {
        f32::from_bits(f.to_bits() + 1)
    } else {
        f
    }
}

fn random_id() -> u64 {
    use std::hash::{BuildHasher, Hasher};
    let mut h = std::collections::hash_map::RandomState::new().build_hasher();
    h.write_u128(std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_nanos()).unwrap_or(0));
    h.write_u32(std::process::id());
    h.finish()
}

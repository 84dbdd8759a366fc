//! Reduce stage (`octolod simplify`): one mesh of the size or error asked,
//! from a store's cuts, under the memory budget.
//!
//! Takes: a built store (its level 0 is the exact input), a target
//! ([`Target`]: a triangle count, a ratio of the input's, or an error in
//! object space), a node simplifier ([`Simplifier`]) and `--mem`. Gives:
//! the simplified mesh (welded, the input's attributes) and a
//! [`ReduceReport`] saying which route was taken and whether the target
//! was met.
//!
//! **Route for a size N.** The levels halve, so some level holds between N
//! and 2N triangles. Starting finer costs time but gives the simplifier more
//! to choose from, so the start is the *finest* level with at least N
//! triangles whose whole mesh fits the budget ([`Simplifier::bytes_per_triangle`]
//! estimates what the welded mesh and the simplifier need per triangle); it
//! is welded and reduced in memory to exactly N. When no such level fits,
//! the start is the coarsest level with at least N triangles and each of
//! its nodes gets a share of N proportional to its triangles; nodes are
//! reduced in parallel with the vertices they share with another node of
//! the cut locked (found exactly: positions on some node's open edges, kept
//! when two nodes hold them; the mesh's own open border is not locked), then welded
//! — bit-identical locked vertices make the seams close — and a last pass
//! over the welded result, now small, settles the remainder to exactly N
//! with nothing locked. That result (N triangles) must fit the budget.
//!
//! **Route for an error E.** `cluster` returns the store's cut at error E
//! (the coarsest valid cut whose saturated node errors are ≤ E);
//! `collapse` starts from the cut at E/4 and collapses with an absolute
//! error limit of 3E/4. Either way the result is *measured* with
//! [`crate::metro`] against level 0 (Hausdorff, both directions, vertex,
//! edge and face samples) and, while it exceeds E, the limit is lowered and
//! the mesh rebuilt, down to the input itself.
//!
//! **Simplifiers.** `collapse` is quadric edge collapse with attributes
//! ([`crate::lod::collapse`], shared with `build --simplifier collapse`):
//! meshoptimizer's `simplifyWithUpdate` (vertex positions and attributes
//! re-placed optimally, locked vertices kept bit-exact, normals, colours and
//! uvs weighted into the quadric, attribute seams kept closed). Positions
//! go to meshoptimizer as f32 relative to the mesh's centre, so inputs far
//! from the origin keep their precision; locked vertices are restored from
//! their f64 originals. `cluster` is the hierarchy's generalized-quadric
//! adaptive clustering ([`crate::lod::cluster`]) stopped at the first split
//! count giving at least N triangles. When a simplifier cannot reach N
//! without breaking the topology (`collapse` then retries once, allowed to
//! remove small disconnected parts), the report says so.

use crate::error::{Error, Result};
use crate::lod::cluster::{cluster_node, Splits};
use crate::lod::shared::pos_bits;
use crate::mesh::AttrSet;
use crate::metro::{self, MemOptions, Source};
use crate::pipeline::{weld_union, write_mesh_ply};
use crate::store::{Cut, IndexedMesh, Store};
use rayon::prelude::*;
use rustc_hash::{FxHashMap, FxHashSet};
use std::path::Path;


pub use crate::store::Simplifier;

/// What `simplify` needs to know of each simplifier.
impl Simplifier {
    /// Bytes held per triangle of a mesh reduced in memory: the welded mesh
    /// (≈ 0.5 vertices × 64 B + 12 B), the weld map and the simplifier's
    /// working set. Measured peaks on the 12 M-triangle sphere reduced whole:
    /// `collapse` 1.97 GB (164 B per triangle: f32 positions, quadrics,
    /// edge tables), `cluster` 4.74 GB (395 B: per-vertex quadrics and the
    /// split sequence's cells); with a margin.
    pub fn bytes_per_triangle(self) -> u64 {
        match self {
            Simplifier::Collapse => 240,
            Simplifier::Cluster => 440,
        }
    }
}

/// What to reduce to.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Target {
    /// This many triangles (within 1 %).
    Tris(u64),
    /// This fraction of the input's triangles.
    Ratio(f64),
    /// The smallest mesh whose measured two-sided Hausdorff distance to
    /// the input is at most this (object space).
    Error(f64),
}

/// What one node (or the whole mesh) is reduced to.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Goal {
    Tris(usize),
    /// Absolute error limit (object space); `collapse` only.
    Error(f64),
}

#[derive(Clone, Debug)]
pub struct ReduceOptions {
    pub target: Target,
    pub simplifier: Simplifier,
    pub mem: u64,
    /// Metro samples per direction when an error target is verified.
    pub verify_samples: u64,
    pub force: bool,
}

/// What `simplify` did (`octolod simplify --json` prints it; the bench reads it back).
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct ReduceReport {
    /// `in-memory`, `per-node` or `store-cut`.
    pub route: String,
    /// The cut it started from (`level 3`, `max error 1e-4`).
    pub start: String,
    pub start_triangles: u64,
    pub input_triangles: u64,
    /// The triangle count asked (size targets).
    pub target_triangles: Option<u64>,
    /// The error asked (error targets; object space).
    pub target_error: Option<f64>,
    pub vertices: u64,
    pub triangles: u64,
    /// The target was met (size within 1 %, or measured error ≤ E).
    pub reached: bool,
    /// Why not, or what was done instead.
    pub note: Option<String>,
    /// Measured Hausdorff distance to the input (error targets).
    pub hausdorff: Option<f64>,
    /// Meshes built and measured (error targets).
    pub tries: u32,
}

/// `octolod simplify` after the build: writes the reduced mesh to `out`.
pub fn simplify_store(store: &Store, out: &Path, o: &ReduceOptions) -> Result<ReduceReport> {
    let input = store.level_triangles(0);
    let (mesh, mut rep) = match o.target {
        Target::Tris(n) => reduce_to_count(store, n, o)?,
        Target::Ratio(r) => {
            if !(r > 0.0 && r.is_finite()) {
                return Err(Error::Usage(format!("--target-ratio must be > 0, not {r}")));
            }
            reduce_to_count(store, (r * input as f64).round().max(1.0) as u64, o)?
        }
        Target::Error(e) => {
            if !(e >= 0.0 && e.is_finite()) {
                return Err(Error::Usage(format!("--target-error must be ≥ 0 and finite, not {e}")));
            }
            reduce_to_error(store, e, o)?
        }
    };
    rep.input_triangles = input;
    rep.vertices = mesh.vertices.len() as u64;
    rep.triangles = mesh.triangles.len() as u64;
    if let Some(n) = rep.target_triangles {
        let off = rep.triangles.abs_diff(n) as f64;
        rep.reached = off <= 0.01 * n as f64 || (n >= input && rep.triangles == input);
        if !rep.reached && rep.note.is_none() {
            rep.note = Some(format!("{} of {n} triangles: the {:?} simplifier could not go further without breaking the surface", rep.triangles, o.simplifier));
        }
    }
    let comment = format!("octolod simplify ({:?}, {}) of {}", o.simplifier, rep.start, store.dir.display());
    write_mesh_ply(out, store.header.attrs, &comment, &mesh, o.force)?;
    Ok(rep)
}

fn reduce_to_count(store: &Store, n: u64, o: &ReduceOptions) -> Result<(IndexedMesh, ReduceReport)> {
    let input = store.level_triangles(0);
    let mut rep = ReduceReport { target_triangles: Some(n), ..Default::default() };
    if n >= input {
        let cut = store.level_cut(0);
        rep.route = "in-memory".into();
        rep.start = "level 0".into();
        rep.start_triangles = input;
        rep.note = Some(format!("asked {n} triangles of an input of {input}: the input is returned"));
        return Ok((load_cut(store, &cut, o)?, rep));
    }
    // Levels with at least n triangles (level 0 always is one).
    let levels: Vec<(u8, u64)> =
        (0..=store.top_level()).map(|l| (l, store.level_cut(l).triangles(store))).filter(|&(_, t)| t >= n).collect();
    let fits = |t: u64| t.saturating_mul(o.simplifier.bytes_per_triangle()) <= o.mem;
    let (level, tris) = match levels.iter().find(|&&(_, t)| fits(t)) {
        Some(&lt) => {
            rep.route = "in-memory".into();
            lt
        }
        None => {
            rep.route = "per-node".into();
            *levels.last().unwrap()
        }
    };
    rep.start = format!("level {level}");
    rep.start_triangles = tris;
    let cut = store.level_cut(level);
    let mesh = reduce_cut(store, &cut, Goal::Tris(n as usize), o)?;
    Ok((mesh, rep))
}

fn reduce_to_error(store: &Store, e: f64, o: &ReduceOptions) -> Result<(IndexedMesh, ReduceReport)> {
    let mut rep = ReduceReport { target_error: Some(e), ..Default::default() };
    let scratch = crate::io::scratch_dir(&store.dir)?;
    let candidate = scratch.path().join("candidate.ply");
    let mut limit = e;
    for attempt in 1..=8u32 {
        rep.tries = attempt;
        let last = attempt == 8 || limit <= 0.0;
        let (cut, mesh) = match o.simplifier {
            Simplifier::Cluster => {
                let cut = if last { store.level_cut(0) } else { store.error_cut(limit) };
                rep.route = "store-cut".into();
                rep.start = if last { "level 0".into() } else { format!("max error {limit:.3e}") };
                let m = load_cut(store, &cut, o)?;
                (cut, m)
            }
            Simplifier::Collapse => {
                let cut = if last { store.level_cut(0) } else { store.error_cut(0.25 * limit) };
                rep.start = if last { "level 0".into() } else { format!("max error {:.3e}", 0.25 * limit) };
                let tris = cut.triangles(store);
                rep.route = if tris.saturating_mul(o.simplifier.bytes_per_triangle()) <= o.mem { "in-memory" } else { "per-node" }.into();
                let m = if last { load_cut(store, &cut, o)? } else { reduce_cut(store, &cut, Goal::Error(0.75 * limit), o)? };
                (cut, m)
            }
        };
        rep.start_triangles = cut.triangles(store);
        write_mesh_ply(&candidate, store.header.attrs, "octolod simplify candidate", &mesh, true)?;
        let mopts = metro::Options { samples: Some(o.verify_samples), seed: 1, quiet: true };
        let r = metro::compare_sources(
            &Source::Store(store.dir.clone(), 0),
            &Source::Ply(candidate.clone()),
            &mopts,
            &MemOptions { budget: o.mem, explicit: false },
        )?;
        let h = r.combined.max;
        rep.hausdorff = Some(h);
        // A 5 % margin: metro's face samples are random, and another run
        // with more samples may find a slightly larger maximum.
        if h <= 0.95 * e || last {
            rep.reached = h <= e;
            if attempt > 1 {
                rep.note = Some(format!("met after {attempt} tries (the error limit lowered to {limit:.3e})"));
            }
            return Ok((mesh, rep));
        }
        // Lower the limit in proportion to the overshoot (at least by 30 %).
        limit *= (e / h).min(0.7);
    }
    unreachable!()
}

/// The cut's meshes welded into one (must fit `mem`).
fn load_cut(store: &Store, cut: &Cut, o: &ReduceOptions) -> Result<IndexedMesh> {
    check_fits(cut.triangles(store), o, "the mesh")?;
    let parts = store.cut_meshes(cut).collect::<Result<Vec<_>>>()?;
    Ok(weld_union(&store.layout, &parts))
}

fn check_fits(tris: u64, o: &ReduceOptions, what: &str) -> Result<()> {
    let (need, mem) = (tris.saturating_mul(o.simplifier.bytes_per_triangle()), o.mem);
    if need > mem {
        return Err(Error::Usage(format!(
            "{what} of {tris} triangles needs about {} MiB in memory, more than --mem {} MiB; raise --mem or ask for fewer triangles",
            need >> 20,
            mem >> 20
        )));
    }
    Ok(())
}

/// Reduces a cut to `goal`: whole in memory when it fits, else node by node
/// with shared vertices locked and a last pass over the welded result (see
/// the module doc).
pub fn reduce_cut(store: &Store, cut: &Cut, goal: Goal, o: &ReduceOptions) -> Result<IndexedMesh> {
    let attrs = store.header.attrs;
    let tris = cut.triangles(store);
    if tris.saturating_mul(o.simplifier.bytes_per_triangle()) <= o.mem {
        let m = load_cut(store, cut, o)?;
        return Ok(reduce_mesh(&m, &vec![false; m.vertices.len()], attrs, goal, o.simplifier));
    }
    if let Goal::Tris(n) = goal {
        check_fits(n as u64, o, "the output")?;
    }
    // Pass 1: a position two parts share is on an open edge of at least
    // one of them (unless both cover it wholly: a doubled surface); so take
    // the positions on open edges, then count the parts holding each.
    let mut border: FxHashSet<[u64; 3]> = FxHashSet::default();
    for m in store.cut_meshes(cut) {
        border.extend(open_edge_positions(&m?));
    }
    let mut count: FxHashMap<[u64; 3], u32> = FxHashMap::default();
    for m in store.cut_meshes(cut) {
        let held: FxHashSet<[u64; 3]> = m?.vertices.iter().map(|v| pos_bits(v.pos)).filter(|k| border.contains(k)).collect();
        for k in held {
            *count.entry(k).or_insert(0) += 1;
        }
    }
    drop(border);
    count.retain(|_, c| *c >= 2);
    let shared: FxHashSet<[u64; 3]> = count.into_keys().collect();
    // Pass 2: each part reduced to its share, in parallel batches.
    let batch = 4 * rayon::current_num_threads().max(1);
    let mut parts = Vec::new();
    for ids in cut.drawn.chunks(batch) {
        let done: Vec<IndexedMesh> = ids
            .par_iter()
            .map(|&i| -> Result<IndexedMesh> {
                let m = cut.drawn_mesh(&store.read_node(i)?);
                let locked: Vec<bool> = m.vertices.iter().map(|v| shared.contains(&pos_bits(v.pos))).collect();
                let g = match goal {
                    Goal::Tris(n) => Goal::Tris(((n as f64) * m.triangles.len() as f64 / tris.max(1) as f64).round() as usize),
                    g => g,
                };
                Ok(reduce_mesh(&m, &locked, attrs, g, o.simplifier))
            })
            .collect::<Result<_>>()?;
        parts.extend(done);
    }
    let welded = weld_union(&store.layout, &parts);
    drop(parts);
    match goal {
        Goal::Tris(n) if welded.triangles.len() > n => {
            Ok(reduce_mesh(&welded, &vec![false; welded.vertices.len()], attrs, goal, o.simplifier))
        }
        _ => Ok(welded),
    }
}

/// Positions of the vertices on edges used by exactly one triangle.
fn open_edge_positions(m: &IndexedMesh) -> FxHashSet<[u64; 3]> {
    let mut edges: FxHashMap<(u32, u32), u32> = FxHashMap::default();
    // Edges by position, so split attribute copies count as one vertex.
    let mut id: FxHashMap<[u64; 3], u32> = FxHashMap::default();
    let canon: Vec<u32> = m
        .vertices
        .iter()
        .map(|v| {
            let n = id.len() as u32;
            *id.entry(pos_bits(v.pos)).or_insert(n)
        })
        .collect();
    for t in &m.triangles {
        for k in 0..3 {
            let (a, b) = (canon[t[k] as usize], canon[t[(k + 1) % 3] as usize]);
            if a != b {
                *edges.entry((a.min(b), a.max(b))).or_insert(0) += 1;
            }
        }
    }
    let mut on = vec![false; id.len()];
    for (&(a, b), &c) in &edges {
        if c == 1 {
            on[a as usize] = true;
            on[b as usize] = true;
        }
    }
    m.vertices.iter().zip(&canon).filter(|(_, &c)| on[c as usize]).map(|(v, _)| pos_bits(v.pos)).collect()
}

/// Reduces one mesh in memory to `goal`, keeping `locked` vertices
/// bit-exact. Unreferenced vertices are dropped.
pub fn reduce_mesh(mesh: &IndexedMesh, locked: &[bool], attrs: AttrSet, goal: Goal, simplifier: Simplifier) -> IndexedMesh {
    match (simplifier, goal) {
        (Simplifier::Cluster, Goal::Tris(n)) => cluster_to_count(mesh, locked, attrs, n.max(1)),
        // Clustering has no error-limited mode of its own: the error route
        // takes store cuts for it.
        (Simplifier::Cluster, Goal::Error(_)) => compact(mesh, &mesh.triangles),
        (Simplifier::Collapse, g) => collapse(mesh, locked, attrs, g),
    }
}

/// Clustering to `n` triangles: the split count is chosen on the split
/// sequence's predicted counts, which ignore the folds and duplicates the
/// build then drops, so the target is corrected from what the build gave
/// (a few rounds; the count is monotone enough in the splits).
fn cluster_to_count(mesh: &IndexedMesh, locked: &[bool], attrs: AttrSet, n: usize) -> IndexedMesh {
    if n >= mesh.triangles.len() {
        return cluster_node(mesh, locked, attrs, n, crate::quadric::DEFAULT_REL_TOL).0;
    }
    let sp = Splits::new(mesh, None, locked, attrs, usize::MAX, 0.0);
    let mut ask = n;
    let mut best: Option<IndexedMesh> = None;
    for _ in 0..6 {
        let out = sp.build(sp.steps_for_target(ask), crate::quadric::DEFAULT_REL_TOL).mesh;
        let got = out.triangles.len();
        if best.as_ref().is_none_or(|b| got.abs_diff(n) < b.triangles.len().abs_diff(n)) {
            best = Some(out);
        }
        if got.abs_diff(n) * 200 <= n || got == 0 {
            break;
        }
        ask = ((ask as f64) * n as f64 / got as f64).round().max(1.0) as usize;
    }
    best.unwrap_or_default()
}

/// Quadric edge collapse ([`crate::lod::collapse`], shared with the
/// hierarchy's `build --simplifier collapse`), compacted.
fn collapse(mesh: &IndexedMesh, locked: &[bool], attrs: AttrSet, goal: Goal) -> IndexedMesh {
    let (n, e) = match goal {
        Goal::Tris(n) => (n, None),
        Goal::Error(e) => (0, Some(e)),
    };
    let c = crate::lod::collapse::collapse(mesh, locked, attrs, n, e);
    crate::lod::collapse::compact(&c.vertices, &c.triangles).0
}

/// `tris` over `mesh.vertices`, unreferenced vertices dropped.
fn compact(mesh: &IndexedMesh, tris: &[[u32; 3]]) -> IndexedMesh {
    crate::lod::collapse::compact(&mesh.vertices, tris).0
}

//! Reduce stage (`octolod simplify`): one mesh of the size or error asked,
//! from a store's cuts, under the memory budget.
//!
//! Takes: a built store (level 0 is the exact input), a [`Target`] (a
//! triangle count, a ratio of the input's, or an object-space error), a
//! node [`Simplifier`] and `--mem`. Gives: the simplified mesh (welded, the
//! input's attributes) and a [`SimplifyReport`]: the route taken, and
//! whether the target was met.
//!
//! **Size N.** The start is the *finest* level with at least N triangles
//! whose welded mesh fits the budget ([`Simplifier::bytes_per_triangle`]),
//! reduced in memory to exactly N; when none fits, the coarsest level with
//! at least N, reduced node by node and streamed ([`SpooledPly`]: the bytes
//! [`write_mesh_ply`] writes), so the output need not fit either. That route
//! holds only the positions two nodes share (found exactly and locked;
//! `SHARED_BYTES` each) and a batch of nodes: each node gets a share of N,
//! the remainder is settled over the spilled parts (to within 0.25 % of N,
//! at most `SETTLE_ROUNDS` more rounds), and the parts are welded at the
//! shared positions, whose locked vertices are bit-identical: seams close.
//! **Never worse than a level:** on the in-memory route, when a store
//! level holds within [`LEVEL_NEAR`] of N triangles, it and the reduction
//! are both measured against the input ([`CHOICE_SAMPLES`] metro samples
//! per direction, same seed) and the lower RMS is returned
//! ([`SimplifyReport::choice`]).
//!
//! **Error E.** `cluster` returns the store's cut at E; `collapse` starts
//! from the cut at E/4 with an absolute limit of 3E/4. The result is
//! *measured* with [`crate::metro`] against level 0 and rebuilt with a lower
//! limit while it exceeds E, down to the input; the coarsest level is tried
//! first when E is at least `COARSEST_FIRST` of its recorded error.
//!
//! **Simplifiers.** `collapse`: quadric edge collapse with attributes
//! ([`crate::lod::collapse`], meshoptimizer's `simplifyWithUpdate`), locked
//! vertices kept bit-exact; `cluster`: adaptive clustering
//! ([`crate::lod::cluster`]) stopped at the first split count giving at
//! least N triangles. The steps in full, and figures: `docs/simplify.md`.

use crate::error::{Error, IoContext, Result};
use crate::geom::{pos_bits, Welder};
use crate::io::ScratchDir;
use crate::lod::cluster::{cluster_node, Splits};
use crate::mesh::IndexedMesh;
use crate::mesh::{AttrSet, VertexLayout};
use crate::metro::{self, MemOptions, Source};
use crate::pipeline::{weld_union, write_mesh_ply, SpooledPly, VertexWelder};
use crate::store::{decode_payload, encode_payload, Cut, Store, NO_NODE};
use rayon::prelude::*;
use rustc_hash::{FxHashMap, FxHashSet};
use std::fs::File;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};

use crate::manifest::Simplifier;

/// What `simplify` needs to know of each simplifier.
impl Simplifier {
    /// Bytes held per triangle of a mesh with `attrs` reduced in memory:
    /// the welded mesh (≈ 0.5 vertices × 64 B + 12 B), the weld map and the
    /// simplifier's working set, which grows with the attributes
    /// (`collapse`: f32 positions and attributes, meshoptimizer's quadrics
    /// and attribute gradients, edge tables; `cluster`: per-vertex quadric
    /// rows and the split tree's cell quadrics, `coeff_len(dim)` values
    /// each). Fitted to peak RSS of `simplify --target-tris 300000 --mem
    /// 512M` from 1 M-triangle spheres, positions only and with normals and
    /// colours (2026-12-06: cluster 528 and 1,354 B a triangle, collapse
    /// 224 and 347), plus 15 %. A figure for positions alone (440 and
    /// 240 B) had let the cluster route take 1.35 GB under `--mem 512M`.
    pub fn bytes_per_triangle(self, attrs: AttrSet) -> u64 {
        let dim = attrs.quadric_dim();
        let fitted = match self {
            Simplifier::Collapse => 224.0 + 20.5 * (dim - 3) as f64,
            // Auto is resolved before any size is asked; the larger figure.
            Simplifier::Cluster | Simplifier::Auto => 344.0 + 18.4 * crate::quadric::Quadric::coeff_len(dim) as f64,
        };
        (1.15 * fitted).ceil() as u64
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
pub struct SimplifyOptions {
    pub target: Target,
    pub simplifier: Simplifier,
    pub mem: u64,
    /// Metro samples per direction when an error target is verified; None:
    /// metro's own default (10 × the larger face count), the budget of a
    /// plain `octolod metro` run, so its check agrees with the result's.
    pub verify_samples: Option<u64>,
    pub force: bool,
}

/// What `simplify` did (`octolod simplify --json` prints it; the bench reads it back).
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct SimplifyReport {
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
    /// Metro samples per direction of the last measurement (error targets).
    pub verify_samples: Option<u64>,
    /// Size targets on the in-memory route with a store level within
    /// [`LEVEL_NEAR`] of N: both measured against the input, the better
    /// returned.
    pub choice: Option<LevelChoice>,
}

/// The level against the reduction (see [`SimplifyReport::choice`]).
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct LevelChoice {
    pub level: u8,
    pub level_triangles: u64,
    /// Two-sided metro RMS against level 0 (the input), the same samples
    /// for both ([`CHOICE_SAMPLES`] per direction).
    pub level_rms: f64,
    pub reduced_rms: f64,
    /// The level was returned.
    pub level_returned: bool,
}

/// A store level with a triangle count this close to N (a share of N: the
/// size contract's 1 %, so a returned level meets the target like the
/// reduction) is measured against the reduction to N, and returned when it
/// is more accurate: a level is built from the whole hierarchy below it, and a
/// reduction from a finer level to about its size was measured up to 2.4×
/// its RMS (collapse, 237 K triangles of a 12 M sphere).
pub const LEVEL_NEAR: f64 = 0.01;

/// Metro samples per direction for that choice: enough to rank two meshes
/// whose RMS differ by a few per cent, cheap next to the reduction.
pub const CHOICE_SAMPLES: u64 = 200_000;

/// A reduction's result: in memory, or already spooled into the output
/// (the per-node route for a size; see the module doc).
enum Reduced {
    Mesh(IndexedMesh),
    Spooled(Box<SpooledPly>),
}

impl Reduced {
    fn counts(&self) -> (u64, u64) {
        match self {
            Reduced::Mesh(m) => (m.vertices.len() as u64, m.triangles.len() as u64),
            Reduced::Spooled(p) => p.counts(),
        }
    }
}

/// Checks `simplify`'s own options, before any work (the CLI calls it
/// before it builds the scratch store): `--target-tris` at least 1,
/// `--target-ratio` in (0, 1], `--verify-samples` from 1 to
/// [`metro::MAX_SAMPLES`] (as metro's `--samples`).
pub fn check_options(target_tris: Option<u64>, target_ratio: Option<f64>, verify_samples: Option<u64>) -> Result<()> {
    if target_tris == Some(0) {
        return Err(Error::Usage("simplify: --target-tris must be at least 1 (0 would write an empty mesh)".into()));
    }
    if let Some(r) = target_ratio.filter(|r| !(*r > 0.0 && *r <= 1.0)) {
        return Err(Error::Usage(format!("simplify: --target-ratio must be in (0, 1] (a share of the input's triangles), not {r}")));
    }
    if verify_samples == Some(0) {
        return Err(Error::Usage("simplify: --verify-samples must be at least 1".into()));
    }
    if let Some(n) = verify_samples.filter(|&n| n > metro::MAX_SAMPLES) {
        return Err(Error::Usage(format!("simplify: --verify-samples {n} is more than {} per direction (hours of work); ask fewer", metro::MAX_SAMPLES)));
    }
    Ok(())
}

/// `octolod simplify` after the build: writes the reduced mesh to `out`.
pub fn simplify_store(store: &Store, out: &Path, o: &SimplifyOptions) -> Result<SimplifyReport> {
    let o = &SimplifyOptions { simplifier: o.simplifier.resolve(store.header.attrs), ..o.clone() };
    let input = store.level_triangles(0);
    match o.target {
        Target::Tris(n) => check_options(Some(n), None, o.verify_samples)?,
        Target::Ratio(r) => check_options(None, Some(r), o.verify_samples)?,
        Target::Error(_) => check_options(None, None, o.verify_samples)?,
    }
    let (result, mut rep) = match o.target {
        Target::Tris(n) => reduce_to_count(store, n, out, o)?,
        Target::Ratio(r) => reduce_to_count(store, (r * input as f64).round().max(1.0) as u64, out, o)?,
        Target::Error(e) => {
            if !(e >= 0.0 && e.is_finite()) {
                return Err(Error::Usage(format!("--target-error must be ≥ 0 and finite, not {e}")));
            }
            let (m, rep) = reduce_to_error(store, e, o)?;
            (Reduced::Mesh(m), rep)
        }
    };
    rep.input_triangles = input;
    (rep.vertices, rep.triangles) = result.counts();
    if let Some(n) = rep.target_triangles {
        rep.reached = within_1pct(rep.triangles, n) || (n >= input && rep.triangles == input);
        if !rep.reached && rep.note.is_none() {
            rep.note = Some(format!("{} of {n} triangles: the {:?} simplifier could not go further without breaking the surface", rep.triangles, o.simplifier));
        }
    }
    // The input's textures are named (MeshLab's convention) when uvs are kept.
    let mut comments = vec![format!("octolod simplify ({:?}, {}) of {}", o.simplifier, rep.start, store.dir.display())];
    if store.header.attrs.uv() {
        comments.extend(crate::pipeline::source_texture_comments(store, out));
    }
    match result {
        Reduced::Mesh(m) => crate::pipeline::write_mesh_ply_with(
            out,
            &crate::ply::write::PlyWriteOptions { comments, ..crate::pipeline::mesh_ply_options(store.header.attrs, "") },
            &m,
            o.force,
        ),
        Reduced::Spooled(p) => p.finish(&comments),
    }?;
    Ok(rep)
}

/// `got` is within 1 % of `n`: a size target is met.
fn within_1pct(got: u64, n: u64) -> bool {
    got.abs_diff(n) as f64 <= 0.01 * n as f64
}

fn reduce_to_count(store: &Store, n: u64, out: &Path, o: &SimplifyOptions) -> Result<(Reduced, SimplifyReport)> {
    let input = store.level_triangles(0);
    let mut rep = SimplifyReport { target_triangles: Some(n), ..Default::default() };
    if n >= input {
        let cut = store.level_cut(0);
        rep.route = "in-memory".into();
        rep.start = "level 0".into();
        rep.start_triangles = input;
        rep.note = Some(format!("asked {n} triangles of an input of {input}: the input is returned"));
        return Ok((Reduced::Mesh(load_cut(store, &cut, o)?), rep));
    }
    // Levels with at least n triangles (level 0 always is one).
    let levels: Vec<(u8, u64)> = (0..=store.top_level()).map(|l| (l, store.level_cut(l).triangles(store))).filter(|&(_, t)| t >= n).collect();
    let fits = |t: u64| t.saturating_mul(o.simplifier.bytes_per_triangle(store.header.attrs)) <= o.mem;
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
    if rep.route == "in-memory" {
        let reduced = reduce_cut(store, &cut, Goal::Tris(n as usize), o)?;
        return level_or_reduced(store, n, reduced, rep, o);
    }
    let r = per_node_to_count(store, &cut, n, o, Some(out))?;
    let got = r.counts().1;
    if matches!(r, Reduced::Spooled(_)) && !within_1pct(got, n) && got > n {
        rep.note = Some(format!(
            "{got} of {n} triangles: the borders between the nodes reduced one by one are kept exactly (so the seams stay closed) and hold more; \
             a --mem that holds {got} triangles (about {} MiB) lets a last pass over the whole result go further",
            got.saturating_mul(o.simplifier.bytes_per_triangle(store.header.attrs)) >> 20
        ));
    }
    Ok((r, rep))
}

/// The in-memory route's end: the reduction to `n`, or a store level
/// within [`LEVEL_NEAR`] of `n` when it measures better (see
/// [`SimplifyReport::choice`]; `docs/simplify.md`).
fn level_or_reduced(store: &Store, n: u64, reduced: IndexedMesh, mut rep: SimplifyReport, o: &SimplifyOptions) -> Result<(Reduced, SimplifyReport)> {
    let near = (0..=store.top_level())
        .map(|l| (l, store.level_cut(l).triangles(store)))
        .filter(|&(_, t)| t.abs_diff(n) as f64 <= LEVEL_NEAR * n as f64 && t.saturating_mul(o.simplifier.bytes_per_triangle(store.header.attrs)) <= o.mem)
        .min_by_key(|&(_, t)| t.abs_diff(n));
    let Some((level, level_tris)) = near else { return Ok((Reduced::Mesh(reduced), rep)) };
    let cut = store.level_cut(level);
    let level_mesh = load_cut(store, &cut, o)?;
    let scratch = crate::io::scratch_dir(&store.dir)?;
    let level_rms = rms_against_input(store, scratch.path(), &level_mesh, o)?;
    let reduced_rms = rms_against_input(store, scratch.path(), &reduced, o)?;
    let level_returned = level_rms < reduced_rms;
    rep.choice = Some(LevelChoice { level, level_triangles: level_tris, level_rms, reduced_rms, level_returned });
    if !level_returned {
        return Ok((Reduced::Mesh(reduced), rep));
    }
    rep.route = "store-cut".into();
    rep.start = format!("level {level}");
    rep.start_triangles = level_tris;
    rep.note = Some(format!(
        "level {level} ({level_tris} triangles, within {}% of {n}) measures RMS {level_rms:.3e} against the input, the reduction to {n} {reduced_rms:.3e}: the level is returned",
        LEVEL_NEAR * 100.0
    ));
    Ok((Reduced::Mesh(level_mesh), rep))
}

/// `mesh`'s two-sided metro RMS against level 0 ([`CHOICE_SAMPLES`] per
/// direction, seed 1), through a PLY in `scratch`.
fn rms_against_input(store: &Store, scratch: &Path, mesh: &IndexedMesh, o: &SimplifyOptions) -> Result<f64> {
    let p = scratch.join("choice.ply");
    write_mesh_ply(&p, store.header.attrs, "octolod simplify candidate", mesh, true)?;
    let mopts = metro::Options { samples: Some(CHOICE_SAMPLES), seed: 1, quiet: true };
    let r = metro::compare_sources(&Source::Store(store.dir.clone(), 0), &Source::Ply(p.clone()), &mopts, &MemOptions { budget: o.mem, explicit: false })?;
    let _ = std::fs::remove_file(&p);
    Ok(r.combined.rms)
}

/// Error targets at least this share of the coarsest level's recorded
/// node error measure that level first: the recorded errors add each
/// step's measured deviation, so they lie above metro's distance, but
/// rarely by more than 1 / `COARSEST_FIRST` (figures: `docs/simplify.md`).
const COARSEST_FIRST: f64 = 0.25;

fn reduce_to_error(store: &Store, e: f64, o: &SimplifyOptions) -> Result<(IndexedMesh, SimplifyReport)> {
    let mut rep = SimplifyReport { target_error: Some(e), ..Default::default() };
    let scratch = crate::io::scratch_dir(&store.dir)?;
    let candidate = scratch.path().join("candidate.ply");
    // The candidate's two-sided Hausdorff distance to level 0, and the
    // samples per direction it took.
    let measure = |mesh: &IndexedMesh| -> Result<(f64, u64)> {
        write_mesh_ply(&candidate, store.header.attrs, "octolod simplify candidate", mesh, true)?;
        let mopts = metro::Options { samples: o.verify_samples, seed: 1, quiet: true };
        let r = metro::compare_sources(
            &Source::Store(store.dir.clone(), 0),
            &Source::Ply(candidate.clone()),
            &mopts,
            &MemOptions { budget: o.mem, explicit: false },
        )?;
        Ok((r.combined.max, r.samples_target))
    };
    // The coarsest level is the smallest mesh on offer: when it is within
    // E it is the answer, whatever the simplifier (an error limit that
    // large once collapsed the whole mesh away). Measured first when E may
    // hold it.
    let top = store.top_level();
    let top_error = store.level_nodes(top).iter().map(|&i| store.nodes[i].error as f64).fold(0.0, f64::max);
    if top > 0 && e >= COARSEST_FIRST * top_error {
        let cut = store.level_cut(top);
        let mesh = load_cut(store, &cut, o)?;
        let (h, samples) = measure(&mesh)?;
        rep.tries = 1;
        rep.hausdorff = Some(h);
        rep.verify_samples = Some(samples);
        if h <= e {
            rep.route = "store-cut".into();
            rep.start = format!("level {top}");
            rep.start_triangles = cut.triangles(store);
            rep.reached = true;
            rep.note = Some(format!("the coarsest level (level {top}) measures {h:.3e}, within the error asked"));
            return Ok((mesh, rep));
        }
    }
    let mut limit = e;
    for attempt in 1..=8u32 {
        crate::io::signal::check()?;
        rep.tries += 1;
        let last = attempt == 8 || limit <= 0.0;
        let (cut, mesh) = match o.simplifier {
            Simplifier::Cluster | Simplifier::Auto => {
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
                rep.route = if tris.saturating_mul(o.simplifier.bytes_per_triangle(store.header.attrs)) <= o.mem { "in-memory" } else { "per-node" }.into();
                let m = if last { load_cut(store, &cut, o)? } else { reduce_cut(store, &cut, Goal::Error(0.75 * limit), o)? };
                (cut, m)
            }
        };
        rep.start_triangles = cut.triangles(store);
        if mesh.triangles.is_empty() && !last {
            // Everything collapsed within the limit: too coarse to measure.
            limit *= 0.5;
            continue;
        }
        let (h, samples) = measure(&mesh)?;
        rep.hausdorff = Some(h);
        rep.verify_samples = Some(samples);
        // A 5 % margin: metro's face samples are random, and another run
        // with more samples may find a slightly larger maximum.
        if h <= 0.95 * e || last {
            rep.reached = h <= e;
            if rep.tries > 1 {
                rep.note = Some(format!("met after {} tries (the error limit lowered to {limit:.3e})", rep.tries));
            }
            return Ok((mesh, rep));
        }
        // Lower the limit in proportion to the overshoot (at least by 30 %).
        limit *= (e / h).min(0.7);
    }
    unreachable!()
}

/// The cut's meshes welded into one (must fit `mem`).
fn load_cut(store: &Store, cut: &Cut, o: &SimplifyOptions) -> Result<IndexedMesh> {
    check_fits(store, cut.triangles(store), o, "the mesh")?;
    let parts = store.cut_meshes(cut).collect::<Result<Vec<_>>>()?;
    Ok(weld_union(&store.layout, &parts))
}

fn check_fits(store: &Store, tris: u64, o: &SimplifyOptions, what: &str) -> Result<()> {
    let (need, mem) = (tris.saturating_mul(o.simplifier.bytes_per_triangle(store.header.attrs)), o.mem);
    if need > mem {
        return Err(Error::Usage(format!(
            "{what} of {tris} triangles needs about {} MiB in memory, more than --mem {} MiB; raise --mem or ask for fewer triangles",
            need >> 20,
            mem >> 20
        )));
    }
    Ok(())
}

/// Reduces a cut to `goal`, the result in memory: whole in memory when it
/// fits, else node by node with shared vertices locked, welded (and, for a
/// size, settled; see the module doc). `simplify --target-tris` streams
/// its per-node result to the output instead.
pub fn reduce_cut(store: &Store, cut: &Cut, goal: Goal, o: &SimplifyOptions) -> Result<IndexedMesh> {
    let attrs = store.header.attrs;
    let tris = cut.triangles(store);
    if tris.saturating_mul(o.simplifier.bytes_per_triangle(store.header.attrs)) <= o.mem {
        let m = load_cut(store, cut, o)?;
        return Ok(reduce_mesh(&m, &vec![false; m.vertices.len()], attrs, goal, o.simplifier));
    }
    match goal {
        Goal::Tris(n) => match per_node_to_count(store, cut, n as u64, o, None)? {
            Reduced::Mesh(m) => Ok(m),
            Reduced::Spooled(_) => unreachable!("no output given"),
        },
        Goal::Error(_) => {
            let mut pn = PerNode::new(store, cut, o)?;
            let all: Vec<usize> = (0..cut.drawn.len()).collect();
            pn.reduce(&all, |_, _| goal)?;
            pn.welded()
        }
    }
}

/// The per-node route for `n` triangles (see the module doc): parts
/// reduced node by node and spilled, the remainder settled over the spilled
/// parts; then, when the shares could not come within 1 % of `n` and the
/// whole result fits `--mem`, one last pass over it in memory with nothing
/// locked; else the parts welded into `out` as they are read back (in
/// memory without `out`).
fn per_node_to_count(store: &Store, cut: &Cut, n: u64, o: &SimplifyOptions, out: Option<&Path>) -> Result<Reduced> {
    let mut pn = PerNode::new(store, cut, o)?;
    pn.reduce_to(n)?;
    let total = pn.total();
    if total > n && !within_1pct(total, n) && check_fits(store, total, o, "the result").is_ok() {
        let m = pn.welded()?;
        drop(pn);
        let m = reduce_mesh(&m, &vec![false; m.vertices.len()], store.header.attrs, Goal::Tris(n as usize), o.simplifier);
        return Ok(Reduced::Mesh(m));
    }
    match out {
        Some(out) => Ok(Reduced::Spooled(Box::new(pn.spool(out, o.force)?))),
        None => Ok(Reduced::Mesh(pn.welded()?)),
    }
}

/// Bytes held per position of the shared set: its entry (and, while it is
/// built, the count of every node-border position), and the output weld
/// map's entry for the vertex there (its encoded bytes as the key); with
/// the hash tables' slack.
const SHARED_BYTES: u64 = 256;

/// Rounds of [`PerNode::reduce_to`] after the first pass.
const SETTLE_ROUNDS: usize = 3;

/// A cut reduced node by node: the positions shared between its nodes
/// (locked in every reduction), and each drawn node's reduced part spilled
/// to a scratch file, with what was asked of it and what it gave.
struct PerNode<'a> {
    store: &'a Store,
    cut: &'a Cut,
    o: &'a SimplifyOptions,
    shared: FxHashSet<[u64; 3]>,
    /// Nodes reduced at once: what `--mem` holds beside the shared set.
    batch: usize,
    spill: Spill,
    /// Per drawn node (in `cut.drawn` order): triangles drawn, asked, and
    /// held by its spilled part.
    drawn: Vec<u64>,
    asked: Vec<u64>,
    got: Vec<u64>,
}

impl<'a> PerNode<'a> {
    /// Finds the shared positions and sizes the batches; a usage error when
    /// the shared set and one node do not fit `--mem` together.
    fn new(store: &'a Store, cut: &'a Cut, o: &'a SimplifyOptions) -> Result<PerNode<'a>> {
        let shared = shared_positions(store, cut, o.mem)?;
        let shared_bytes = shared.len() as u64 * SHARED_BYTES;
        let node_tris = cut.drawn.iter().map(|&i| store.nodes[i].tris as u64).max().unwrap_or(0).max(1);
        let node_bytes = node_tris * o.simplifier.bytes_per_triangle(store.header.attrs);
        let fit = o.mem.saturating_sub(shared_bytes) / node_bytes;
        if fit == 0 {
            return Err(Error::Usage(format!(
                "reducing node by node holds the {} positions shared between nodes (about {} MiB) and one node of up to {node_tris} triangles \
                 at a time (about {} MiB), more than --mem {} MiB; raise --mem",
                shared.len(),
                shared_bytes >> 20,
                node_bytes >> 20,
                o.mem >> 20
            )));
        }
        let batch = fit.min(4 * rayon::current_num_threads().max(1) as u64) as usize;
        let parts = cut.drawn.len();
        Ok(PerNode { store, cut, o, shared, batch, spill: Spill::create(store, parts)?, drawn: vec![0; parts], asked: vec![0; parts], got: vec![0; parts] })
    }

    /// Triangles of the spilled parts.
    fn total(&self) -> u64 {
        self.got.iter().sum()
    }

    /// Reduces drawn nodes `jobs` (indices into `cut.drawn`), in parallel
    /// batches, each to `goal(job, its triangles)` with the shared
    /// positions locked, and spills the parts. A node is read from its
    /// spilled part when that holds more than asked, else from the store.
    fn reduce(&mut self, jobs: &[usize], goal: impl Fn(usize, usize) -> Goal + Sync) -> Result<()> {
        let attrs = self.store.header.attrs;
        for chunk in jobs.chunks(self.batch) {
            crate::io::signal::check()?;
            let done: Vec<(usize, u64, u64, Vec<u8>)> = chunk
                .par_iter()
                .map(|&k| -> Result<_> {
                    let from_spill = self.spill.has(k) && matches!(goal(k, self.drawn[k] as usize), Goal::Tris(a) if (a as u64) < self.got[k]);
                    let m = if from_spill { self.spill.read(k)? } else { self.cut.drawn_mesh(&self.store.read_node(self.cut.drawn[k])?) };
                    let drawn = if from_spill { self.drawn[k] } else { m.triangles.len() as u64 };
                    let g = goal(k, drawn as usize);
                    let locked: Vec<bool> = m.vertices.iter().map(|v| self.shared.contains(&pos_bits(v.pos))).collect();
                    let r = reduce_mesh(&m, &locked, attrs, g, self.o.simplifier);
                    let asked = if let Goal::Tris(a) = g { a as u64 } else { 0 };
                    Ok((k, drawn, asked, self.spill.encode(&r)))
                })
                .collect::<Result<_>>()?;
            for (k, drawn, asked, bytes) in done {
                self.got[k] = self.spill.put(k, &bytes)?;
                (self.drawn[k], self.asked[k]) = (drawn, asked);
            }
        }
        Ok(())
    }

    /// Reduces every node to its share of `n` (proportional to its
    /// triangles), then settles the remainder: nodes whose locked vertices
    /// kept them above their share keep what they have, the others share
    /// what is left and are reduced again (from their spilled part, or from
    /// the store when they must grow), until the total is within 0.25 % of
    /// `n` or [`SETTLE_ROUNDS`] have passed.
    fn reduce_to(&mut self, n: u64) -> Result<()> {
        let total = self.cut.triangles(self.store).max(1);
        let all: Vec<usize> = (0..self.cut.drawn.len()).collect();
        self.reduce(&all, |_, t| Goal::Tris(((n as f64) * t as f64 / total as f64).round() as usize))?;
        // Stuck: the node missed its share by over 1 % (its locked vertices
        // kept it above, or the simplifier's last step overshot).
        let stuck_at = |got: u64, asked: u64| got.abs_diff(asked) > asked / 100;
        let mut stuck: Vec<bool> = (0..all.len()).map(|k| stuck_at(self.got[k], self.asked[k])).collect();
        for _ in 0..SETTLE_ROUNDS {
            if self.total().abs_diff(n) * 400 <= n {
                break;
            }
            let free: Vec<usize> = all.iter().copied().filter(|&k| !stuck[k]).collect();
            let kept: u64 = all.iter().filter(|&&k| stuck[k]).map(|&k| self.got[k]).sum();
            let room = n.saturating_sub(kept).max(free.len() as u64);
            let shares = apportion(&free.iter().map(|&k| self.drawn[k]).collect::<Vec<_>>(), room);
            let mut ask = vec![0u64; all.len()];
            for (&k, &a) in free.iter().zip(&shares) {
                ask[k] = a.max(1);
            }
            let jobs: Vec<usize> = free.into_iter().filter(|&k| ask[k].abs_diff(self.got[k]) > self.got[k] / 1000).collect();
            if jobs.is_empty() {
                break;
            }
            self.reduce(&jobs, |k, _| Goal::Tris(ask[k] as usize))?;
            for &k in &jobs {
                stuck[k] = stuck_at(self.got[k], self.asked[k]);
            }
        }
        Ok(())
    }

    /// The spilled parts welded in memory ([`weld_union`]).
    fn welded(&self) -> Result<IndexedMesh> {
        let parts = (0..self.cut.drawn.len()).map(|k| self.spill.read(k)).collect::<Result<Vec<_>>>()?;
        Ok(weld_union(&self.store.layout, &parts))
    }

    /// The spilled parts written into a [`SpooledPly`] at `out`, one at a
    /// time: vertices at shared positions are welded across parts (by
    /// their encoded bytes, attributes included), the others within their
    /// part only.
    fn spool(&self, out: &Path, force: bool) -> Result<SpooledPly> {
        let mut ply = SpooledPly::create(out, self.store.header.attrs, force)?;
        let mut weld = VertexWelder::new(&self.store.layout);
        for k in 0..self.cut.drawn.len() {
            let part = self.spill.read(k)?;
            let (v, t) = weld.add(&part, |v| self.shared.contains(&pos_bits(v.pos)));
            for x in &v {
                ply.vertex(x)?;
            }
            // A face's material is its corner 0's (the welder keeps triangle order).
            for (x, src) in t.iter().zip(&part.triangles) {
                ply.face(x, part.vertices[src[0] as usize].material)?;
            }
        }
        Ok(ply)
    }
}

/// `total` split in proportion to `weights`, rounded so that the shares
/// add up to it (largest remainders first); all zero when the weights are.
fn apportion(weights: &[u64], total: u64) -> Vec<u64> {
    let sum: u64 = weights.iter().sum();
    if sum == 0 {
        return vec![0; weights.len()];
    }
    let exact: Vec<f64> = weights.iter().map(|&w| w as f64 * total as f64 / sum as f64).collect();
    let mut shares: Vec<u64> = exact.iter().map(|x| x.floor() as u64).collect();
    let mut order: Vec<usize> = (0..weights.len()).collect();
    order.sort_by(|&a, &b| (exact[b] - exact[b].floor()).total_cmp(&(exact[a] - exact[a].floor())));
    let left = total.saturating_sub(shares.iter().sum());
    for &k in order.iter().take(left as usize) {
        shares[k] += 1;
    }
    shares
}

/// The positions two or more drawn nodes of `cut` hold, found exactly: a
/// position two parts share is on an open edge of at least one of them
/// (unless both cover it wholly: a doubled surface), so take the positions
/// on open edges, then count the parts holding each. A usage error when
/// they do not fit `mem`.
fn shared_positions(store: &Store, cut: &Cut, mem: u64) -> Result<FxHashSet<[u64; 3]>> {
    let mut count: FxHashMap<[u64; 3], u32> = FxHashMap::default();
    for m in store.cut_meshes(cut) {
        for k in open_edge_positions(&m?) {
            count.entry(k).or_insert(0);
        }
        if count.len() as u64 * SHARED_BYTES > mem {
            return Err(Error::Usage(format!(
                "the positions on the nodes' borders (over {} so far, about {SHARED_BYTES} bytes each) need more than --mem {} MiB; raise --mem",
                count.len(),
                mem >> 20
            )));
        }
    }
    for m in store.cut_meshes(cut) {
        let held: FxHashSet<[u64; 3]> = m?.vertices.iter().map(|v| pos_bits(v.pos)).filter(|k| count.contains_key(k)).collect();
        for k in held {
            *count.get_mut(&k).expect("a border position") += 1;
        }
    }
    Ok(count.into_iter().filter(|&(_, c)| c >= 2).map(|(k, _)| k).collect())
}

/// Reduced parts spilled to one scratch file next to the store, appended as
/// they come (a part reduced again is appended anew), each encoded as a
/// one-patch store payload in the payload layout (lossless: derived normals
/// kept).
struct Spill {
    _dir: ScratchDir,
    path: PathBuf,
    file: File,
    layout: VertexLayout,
    end: u64,
    /// Per part: offset and length of its latest copy.
    at: Vec<Option<(u64, usize)>>,
}

impl Spill {
    fn create(store: &Store, parts: usize) -> Result<Spill> {
        let dir = crate::io::scratch_dir(&store.dir)?;
        let path = dir.path().join("parts");
        let file = File::options().read(true).write(true).create_new(true).open(&path).ctx(&path, "create")?;
        Ok(Spill { _dir: dir, path, file, layout: store.payload_layout, end: 0, at: vec![None; parts] })
    }

    fn has(&self, k: usize) -> bool {
        self.at[k].is_some()
    }

    fn encode(&self, m: &IndexedMesh) -> Vec<u8> {
        let mut b = Vec::new();
        encode_payload(&self.layout, m, &[(NO_NODE, m.triangles.len() as u32)], &mut b);
        b
    }

    /// Appends part `k`'s bytes (from [`Spill::encode`]); gives its triangles.
    fn put(&mut self, k: usize, bytes: &[u8]) -> Result<u64> {
        self.file.write_all_at(bytes, self.end).ctx(&self.path, "write")?;
        self.at[k] = Some((self.end, bytes.len()));
        self.end += bytes.len() as u64;
        Ok(u32::from_le_bytes(bytes[4..8].try_into().expect("a payload header")) as u64)
    }

    fn read(&self, k: usize) -> Result<IndexedMesh> {
        let (off, len) = self.at[k].expect("part spilled");
        let mut b = vec![0u8; len];
        self.file.read_exact_at(&mut b, off).ctx(&self.path, "read")?;
        Ok(decode_payload(&self.layout, &b, &self.path, off)?.mesh)
    }
}

/// Positions of the vertices on edges used by exactly one triangle.
fn open_edge_positions(m: &IndexedMesh) -> FxHashSet<[u64; 3]> {
    let mut edges: FxHashMap<(u32, u32), u32> = FxHashMap::default();
    // Edges by position, so split attribute copies count as one vertex.
    let mut id = Welder::default();
    let canon: Vec<u32> = m.vertices.iter().map(|v| id.id(v.pos, |_| {})).collect();
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
    match (simplifier.resolve(attrs), goal) {
        (Simplifier::Cluster | Simplifier::Auto, Goal::Tris(n)) => cluster_to_count(mesh, locked, attrs, n.max(1)),
        // Clustering has no error-limited mode of its own: the error route
        // takes store cuts for it.
        (Simplifier::Cluster | Simplifier::Auto, Goal::Error(_)) => compact(mesh, &mesh.triangles),
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
    let sp = Splits::new(mesh, None, locked, None, attrs, usize::MAX, 0.0);
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The choice itself: a reduction measuring worse than the level of its
    /// size (here the level shifted by 1 % of the box) gives way to the
    /// level; one measuring the same (the level itself) is kept.
    #[test]
    fn a_worse_reduction_gives_way_to_the_level() {
        use crate::gen::{GenOptions, Shape};
        use crate::manifest::BuildParams;
        use crate::pipeline::{build_store, BuildOptions};
        let d = tempfile::tempdir().unwrap();
        let ply = d.path().join("s.ply");
        let g = GenOptions { shape: Shape::Sphere, tris: 20_000, ..Default::default() };
        crate::gen::write(&g, &Default::default(), &ply, true, false).unwrap();
        let out = d.path().join("s.octolod");
        let params = BuildParams { mem: 64 << 20, leaf_tris: 2000, ..Default::default() };
        build_store(&ply, &out, &BuildOptions { params, ..Default::default() }).unwrap();
        let st = Store::open(&out).unwrap();
        let o = SimplifyOptions { target: Target::Tris(1), simplifier: Simplifier::Collapse, mem: 1 << 30, verify_samples: None, force: false };
        let level = 2;
        let n = st.level_cut(level).triangles(&st);
        let at_level = load_cut(&st, &st.level_cut(level), &o).unwrap();
        let mut shifted = at_level.clone();
        let shift = 0.01 * st.header.bbox.diagonal();
        for v in &mut shifted.vertices {
            v.pos[0] += shift;
        }
        let (r, rep) = level_or_reduced(&st, n, shifted, SimplifyReport::default(), &o).unwrap();
        let c = rep.choice.unwrap();
        assert!(c.level_returned && c.level_rms < c.reduced_rms, "{c:?}");
        assert_eq!((rep.route.as_str(), r.counts().1), ("store-cut", n));
        let (_, rep) = level_or_reduced(&st, n, at_level, SimplifyReport::default(), &o).unwrap();
        let c = rep.choice.unwrap();
        assert!(!c.level_returned && c.level_rms == c.reduced_rms, "{c:?}");
    }

    #[test]
    fn apportion_adds_up_in_proportion() {
        assert_eq!(apportion(&[1, 1, 1], 10), [4, 3, 3]);
        assert_eq!(apportion(&[3, 1], 4), [3, 1]);
        assert_eq!(apportion(&[0, 0], 5), [0, 0]);
        assert_eq!(apportion(&[], 5), Vec::<u64>::new());
        let w: Vec<u64> = (1..=97).map(|k| k * k % 89 + 1).collect();
        for total in [0, 1, 96, 1_000, 123_457] {
            let s = apportion(&w, total);
            assert_eq!(s.iter().sum::<u64>(), total);
            let sum: u64 = w.iter().sum();
            for (x, &wi) in s.iter().zip(&w) {
                assert!((*x as f64 - wi as f64 * total as f64 / sum as f64).abs() < 1.0);
            }
        }
    }
}

//! Metro: the two-sided surface distance between two triangle meshes, after
//! Cignoni, Rocchini and Scopigno, "Metro: measuring error on simplified
//! surfaces" (1998), sampled as vcglib's `metro` does.
//!
//! Takes: two operands `A` and `B`, each a PLY path (held whole, or paged
//! through a scratch store of its level 0 when it does not fit `--mem`) or
//! `STORE@L` (level `L`'s whole-level cut, welded, paged part by part), a
//! sample budget (default [`SAMPLES_PER_FACE`] × the larger face count), a
//! seed and `--mem`. Gives: a [`Report`]: per direction (`A -> B`: samples
//! on A, distance to the closest point of B) and combined, the maximum
//! (Hausdorff), mean and RMS distance, absolute and relative to A's
//! bounding-box diagonal; thresholds exit with [`EXIT_THRESHOLD`].
//!
//! Invariants:
//! * Samples: every used vertex, then edge points at the face-sample spacing
//!   (at most [`EDGE_SHARE_MAX`] of what the vertices leave), then
//!   stratified face points by area; exactly the budget in all.
//! * Distances are to the exact closest point ([`crate::geom`]); never NaN.
//! * Every figure is bit-identical for a seed whatever the threads, batches
//!   or memory budget: samples are hashed from (seed, direction, face,
//!   sample) and summed in fixed jobs of [`CHUNK`], combined in job order. A
//!   paged level gives the samples and distances of the level in memory.
//! * A distance at most [`snap_distance`] ([`SNAP_ULPS`] ulps of the largest
//!   coordinate) is rounding and counts as 0: a mesh against itself
//!   measures 0 wherever it lies.
//!
//! Files: this one (operands, options, the comparison, [`run`]), `sample.rs`,
//! `measure.rs` (one direction), `paged.rs`, `cache.rs`, `report.rs`.
//! Sampling, paging, complexity, rounding and figures: `docs/metro.md`.

pub mod attributes;
mod cache;
mod measure;
mod paged;
mod report;
mod sample;

pub use crate::geom::Mesh;
pub use measure::{one_sided, snap_distance, Distances, SNAP_ULPS};
pub use report::{Check, JsonBox, JsonCheck, JsonDistances, JsonMesh, JsonParts, JsonReport, Limits, MeshSummary, PagingReport, Report, Threshold, Timings};

use crate::error::{Error, Location, Result};
use crate::geom::{mix64, Bvh};
use crate::mesh::AttrSet;
use crate::progress::Progress;
use cache::Cache;
use measure::{measure, Target};
use paged::PagedGen;
use paged::PagedLevel;
use sample::MemGen;
use std::fmt;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering::Relaxed;
use std::time::Instant;

/// Exit status of `octolod metro` when a threshold is exceeded (1 is an error).
pub const EXIT_THRESHOLD: u8 = 3;
/// Default samples per direction per face of the larger mesh (Metro's 10).
pub const SAMPLES_PER_FACE: u64 = 10;
/// Samples per parallel work item; fixed, so results do not depend on threads.
pub const CHUNK: u64 = 16 * 1024;
/// Most of the non-vertex budget the edges may take (Metro has no cap: its
/// edges take the whole budget below a few samples a face, leaving the face
/// interiors unsampled; `docs/metro.md`, "Sample mix").
pub const EDGE_SHARE_MAX: f64 = 0.9;

/// Default `--mem`: every command's ([`crate::mem::DEFAULT_BUDGET`]).
pub const DEFAULT_MEM: u64 = crate::mem::DEFAULT_BUDGET;
/// Samples at most per batch (queried together, sorted along a Morton curve
/// when the target is paged).
const BATCH_MAX: usize = 1 << 20;
/// Bytes a batch costs per sample: the point, its distance, its sort key.
const BATCH_BYTES_PER_SAMPLE: u64 = 48;

/// Where a metro operand comes from.
#[derive(Clone, Debug, PartialEq)]
pub enum Source {
    Ply(PathBuf),
    /// A store directory and a level.
    Store(PathBuf, u8),
}

impl Source {
    /// `PATH.ply` (or `.stl`, `.obj`) or `STORE@L`. A spec is a store when the part before the
    /// last `@` is a directory (or the whole spec names nothing and the part
    /// after `@` is a number); a bare store directory is a usage error.
    pub fn parse(spec: &str) -> Result<Source> {
        if let Some((dir, level)) = spec.rsplit_once('@') {
            let numeric = !level.is_empty() && level.bytes().all(|c| c.is_ascii_digit());
            if Path::new(dir).is_dir() || (numeric && !Path::new(spec).exists()) {
                let l: u8 = level.parse().map_err(|_| Error::Usage(format!("'{spec}': the level after '@' must be a number from 0 to 255, not '{level}'")))?;
                return Ok(Source::Store(PathBuf::from(dir), l));
            }
        }
        if Path::new(spec).is_dir() {
            return Err(Error::Usage(format!("'{spec}' is a directory; name a store level as {spec}@L (e.g. {spec}@0)")));
        }
        Ok(Source::Ply(PathBuf::from(spec)))
    }
    /// The operand whole with its attributes (a PLY's per-wedge uvs
    /// split; a store level's nodes side by side), and its attribute set.
    pub fn load_full(&self) -> Result<(crate::mesh::IndexedMesh, AttrSet)> {
        match self {
            Source::Ply(p) => {
                let (h, sink, _) = crate::input::read_all(p, crate::mem::DEFAULT_BUDGET)?;
                let triangles = sink.triangles.iter().map(|t| t.map(|i| i as u32)).collect();
                Ok((crate::mesh::IndexedMesh { vertices: sink.vertices, triangles }, h.attrs))
            }
            Source::Store(d, l) => {
                let s = crate::store::Store::open(d)?;
                s.check_level(*l)?;
                let mut m = crate::mesh::IndexedMesh::default();
                for part in s.cut_meshes(&s.level_cut(*l)) {
                    let part = part?;
                    let base = m.vertices.len() as u32;
                    m.vertices.extend_from_slice(&part.vertices);
                    m.triangles.extend(part.triangles.iter().map(|t| t.map(|i| i + base)));
                }
                Ok((m, s.header.attrs))
            }
        }
    }

    pub fn load(&self) -> Result<Mesh> {
        match self {
            Source::Ply(p) => load_ply(p),
            Source::Store(d, l) => load_store_level(d, *l),
        }
    }
}

impl fmt::Display for Source {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Source::Ply(p) => write!(f, "{}", p.display()),
            Source::Store(d, l) => write!(f, "{}@{l}", d.display()),
        }
    }
}

fn loc(path: &Path) -> Location {
    Location { file: path.to_path_buf(), ..Default::default() }
}

/// Reads a whole input file (PLY, STL or OBJ; polygons fan-triangulated,
/// triangles with a repeated index dropped).
pub fn load_ply(path: &Path) -> Result<Mesh> {
    let (_, sink, _) = crate::input::read_all(path, crate::mem::DEFAULT_BUDGET)?;
    if sink.vertices.len() as u64 > u32::MAX as u64 + 1 {
        return Err(Error::input(loc(path), format!("{} vertices: metro takes at most 2^32", sink.vertices.len())));
    }
    let mesh = Mesh { positions: sink.vertices.iter().map(|v| v.pos).collect(), triangles: sink.triangles.iter().map(|t| t.map(|i| i as u32)).collect() };
    if mesh.triangles.is_empty() {
        return Err(Error::input(loc(path), "no triangles to measure"));
    }
    Ok(mesh)
}

/// Level `level` of the store at `dir` in memory ([`Store::level_mesh`]:
/// the whole-level cut's node meshes, bit-identical positions welded).
///
/// [`Store::level_mesh`]: crate::store::Store::level_mesh
pub fn load_store_level(dir: &Path, level: u8) -> Result<Mesh> {
    crate::store::Store::open(dir)?.level_mesh(level)
}

// ---------------------------------------------------------------------------
// The two-sided comparison.

/// What to measure.
#[derive(Clone, Debug)]
pub struct Options {
    /// Samples per direction; None: [`SAMPLES_PER_FACE`] × the larger face count.
    pub samples: Option<u64>,
    pub seed: u64,
    pub quiet: bool,
}

impl Default for Options {
    fn default() -> Self {
        Options { samples: None, seed: 1, quiet: true }
    }
}

/// One side of a comparison.
enum Operand<'a> {
    Mem(&'a Mesh),
    Paged(&'a PagedLevel),
}

impl Operand<'_> {
    fn faces(&self) -> u64 {
        match self {
            Operand::Mem(m) => m.triangles.len() as u64,
            Operand::Paged(l) => l.faces(),
        }
    }
    fn bbox(&self) -> crate::mesh::Aabb {
        match self {
            Operand::Mem(m) => m.bbox(),
            Operand::Paged(l) => l.bbox(),
        }
    }
}

/// The memory budget of a comparison.
#[derive(Clone, Debug, PartialEq)]
pub struct MemOptions {
    /// Bytes (`--mem`, default [`DEFAULT_MEM`]).
    pub budget: u64,
    /// Given explicitly: then PLY operands, held whole, must fit it too.
    pub explicit: bool,
}

impl Default for MemOptions {
    fn default() -> Self {
        MemOptions { budget: DEFAULT_MEM, explicit: false }
    }
}

/// Estimated peak bytes of a PLY operand of `v` vertices and `f` faces held
/// whole: reading (56-byte vertices, 24-byte faces), the mesh (24 + 12),
/// its index (~165 per triangle at most) and its sample plan (~80 per face
/// with the edge sort).
pub fn ply_estimate(v: u64, f: u64) -> u64 {
    80 * v + 36 * f + Bvh::bytes_bound(f) + 8 * v + 80 * f
}

/// The paging setup of [`compare_operands`].
struct Paging<'a> {
    cache: &'a Cache,
    threads: usize,
    report: PagingReport,
}

/// Two-sided Metro distance between `a` and `b`, both in memory.
pub fn compare(a: &Mesh, b: &Mesh, opts: &Options) -> Result<Report> {
    for (m, name) in [(a, "A"), (b, "B")] {
        if m.triangles.is_empty() {
            return Err(Error::Usage(format!("metro: mesh {name} has no triangles")));
        }
        m.check_indices().map_err(|e| Error::Usage(format!("metro: mesh {name}: {e}")))?;
    }
    compare_operands(&Operand::Mem(a), &Operand::Mem(b), opts, BATCH_MAX, None)
}

/// Two-sided Metro distance between two sources: PLYs are loaded whole,
/// store levels are paged through one cache under `mem` (see the module
/// documentation). The samples, and so every figure, are those [`compare`]
/// gives for the same meshes in memory ([`load_store_level`] for a level).
pub fn compare_sources(sa: &Source, sb: &Source, opts: &Options, mem: &MemOptions) -> Result<Report> {
    let t0 = Instant::now();
    // A PLY over an explicit --mem is streamed into a scratch store of its
    // level 0 (the exact input) and then paged like any store level; one
    // that fits is held whole and counted against --mem.
    let mut scratch = Vec::new();
    let mut resolved = Vec::new();
    let mut ply_est = 0u64;
    for (s, name) in [(sa, "A"), (sb, "B")] {
        if let Source::Ply(p) = s {
            let h = crate::input::read_header(p, &crate::progress::Progress::hidden())?;
            let e = ply_estimate(h.vertex_count(), h.face_count());
            if mem.explicit && e > mem.budget {
                let (tmp, store) = level0_scratch_store(p, opts, mem)?;
                scratch.push(tmp);
                resolved.push(store);
                continue;
            }
            if !mem.explicit && e > mem.budget && crate::progress::visible(opts.quiet) {
                eprintln!(
                    "octolod: metro: note: {name} = {} is held in memory whole (about {}); for meshes larger than RAM \
                     build a store (`octolod build`) and pass STORE@0, which is paged under --mem",
                    p.display(),
                    crate::progress::mib(e)
                );
            }
            ply_est += e;
        }
        resolved.push(s.clone());
    }
    let (sa, sb) = (&resolved[0], &resolved[1]);
    // An eighth of the budget for batches (up to 1 M samples): a larger
    // batch visits each target part once for more queries.
    let batch = ((mem.budget / 8 / BATCH_BYTES_PER_SAMPLE) as usize / CHUNK as usize * CHUNK as usize).clamp(CHUNK as usize, BATCH_MAX);
    let batch_bytes = batch as u64 * BATCH_BYTES_PER_SAMPLE;
    let held = if mem.explicit { ply_est } else { 0 };
    let cache_budget = mem.budget.saturating_sub(held).saturating_sub(batch_bytes);
    let cache = Cache::new(cache_budget);
    let threads = rayon::current_num_threads();
    let open = |s: &Source, op: u64| -> Result<Option<PagedLevel>> {
        match s {
            Source::Store(d, l) => Ok(Some(PagedLevel::open(d, *l, s.to_string(), op, &cache, threads, opts.quiet)?)),
            Source::Ply(_) => Ok(None),
        }
    };
    let (la, lb) = (open(sa, 0)?, open(sb, 1)?);
    let load = |s: &Source| -> Result<Option<Mesh>> {
        match s {
            Source::Ply(p) => Ok(Some(load_ply(p)?)),
            Source::Store(..) => Ok(None),
        }
    };
    let (ma, mb) = rayon::join(|| load(sa), || load(sb));
    let (ma, mb) = (ma?, mb?);
    let load_s = t0.elapsed().as_secs_f64();
    let a = match (&ma, &la) {
        (Some(m), _) => Operand::Mem(m),
        (None, Some(l)) => Operand::Paged(l),
        _ => unreachable!(),
    };
    let b = match (&mb, &lb) {
        (Some(m), _) => Operand::Mem(m),
        (None, Some(l)) => Operand::Paged(l),
        _ => unreachable!(),
    };
    for (o, name) in [(&a, "A"), (&b, "B")] {
        if o.faces() == 0 {
            return Err(Error::Usage(format!("metro: mesh {name} has no triangles")));
        }
    }
    // Each direction holds at most: a paged source's current part and one
    // earlier part (ownership test), or its current part while the target's
    // workers each hold two parts.
    for (src, tgt, dir) in [(&a, &b, "A -> B"), (&b, &a, "B -> A")] {
        let s = if let Operand::Paged(l) = src { l.max_src() } else { 0 };
        let t = if let Operand::Paged(l) = tgt { l.max_tgt() } else { 0 };
        let need = (2 * s).max(s + 2 * t);
        if need > cache_budget {
            let names = |o: &Operand| if let Operand::Paged(l) = o { l.name.clone() } else { String::new() };
            return Err(Error::Usage(format!(
                "metro: --mem {} leaves {} for the page cache (after {} of batch buffers{}), too little for {dir} \
                 ({}{}): its largest node needs up to {} as a sample source and {} as a query index; \
                 give --mem at least {}",
                crate::progress::mib(mem.budget),
                crate::progress::mib(cache_budget),
                crate::progress::mib(batch_bytes),
                if held > 0 { format!(" and {} for the PLY operands", crate::progress::mib(held)) } else { String::new() },
                names(src),
                if matches!(tgt, Operand::Paged(_)) { format!(" against {}", names(tgt)) } else { String::new() },
                crate::progress::mib(s),
                crate::progress::mib(t),
                crate::progress::mib(need + batch_bytes + held + (1 << 20)),
            )));
        }
    }
    let paged = la.is_some() || lb.is_some();
    let report = PagingReport {
        budget: mem.budget,
        cache_budget,
        ply_estimate: ply_est,
        batch_samples: batch as u64,
        parts: JsonParts { a: la.as_ref().map(|l| l.parts() as u64), b: lb.as_ref().map(|l| l.parts() as u64) },
        ..Default::default()
    };
    let paging = Paging { cache: &cache, threads, report };
    let mut r = compare_operands(&a, &b, opts, batch, paged.then_some(paging))?;
    r.a.source = sa.to_string();
    r.b.source = sb.to_string();
    r.seconds.load = load_s;
    Ok(r)
}

/// Streams PLY `p` into a scratch store of its level 0 (soup + octree under
/// `--mem`, no simplification; level 0 is the exact input). The store lives
/// as long as the returned directory guard.
fn level0_scratch_store(p: &Path, opts: &Options, mem: &MemOptions) -> Result<(crate::io::ScratchDir, Source)> {
    // Next to the input (its file system has room for a copy of it); in the
    // system's temp directory when the input's directory is not writable.
    let tmp = match crate::io::scratch_dir(p) {
        Ok(t) => t,
        Err(e) => crate::io::scratch_in(&std::env::temp_dir()).map_err(|_| e)?,
    };
    let stem = p.file_stem().map(|x| x.to_string_lossy().into_owned()).unwrap_or_else(|| "input".into());
    let dir = tmp.path().join(format!("{stem}.level0.octolod"));
    if crate::progress::visible(opts.quiet) {
        eprintln!("octolod: metro: {} does not fit --mem: streaming it into a scratch store of its level 0", p.display());
    }
    // Leaves small enough that several nodes' query indexes (~250 B per
    // triangle) fit the page cache.
    let params = crate::manifest::BuildParams {
        mem: mem.budget.max(crate::mem::MIN_BUDGET),
        leaf_tris: (mem.budget / 2048).clamp(256, 16384),
        levels: Some(0),
        ..Default::default()
    };
    let bo = crate::pipeline::BuildOptions { params, quiet: opts.quiet, force: false };
    crate::pipeline::build_store(p, &dir, &bo)?;
    Ok((tmp, Source::Store(dir, 0)))
}

/// The two directions, then the report.
fn compare_operands(a: &Operand, b: &Operand, opts: &Options, batch: usize, paging: Option<Paging>) -> Result<Report> {
    let target = match opts.samples {
        Some(0) => return Err(Error::Usage("metro: --samples must be at least 1".into())),
        Some(n) => n,
        None => SAMPLES_PER_FACE * a.faces().max(b.faces()),
    };
    // Distances within rounding of the coordinates count as 0 (module doc).
    let snap = snap_distance(&[a.bbox(), b.bbox()]);
    let seed_ab = mix64(opts.seed ^ 0xA70B);
    let seed_ba = mix64(opts.seed ^ 0xB70A);
    let mut bvh_s = 0.0;
    let mut threads_used = [0u64; 2];
    let mut direction = |src: &Operand, tgt: &Operand, seed: u64, name: &str, k: usize| -> Result<(Distances, Option<MeshSummary>, f64)> {
        let t0 = Instant::now();
        let bvh;
        let tg = match tgt {
            Operand::Mem(m) => {
                bvh = Bvh::new(m);
                Target::Mem(&bvh)
            }
            Operand::Paged(l) => {
                let p = paging.as_ref().expect("a paged operand comes with a cache");
                let hold = if let Operand::Paged(s) = src { s.max_src() } else { 0 };
                let t = ((p.cache.budget.saturating_sub(hold)) / (2 * l.max_tgt()).max(1)).clamp(1, p.threads as u64) as usize;
                threads_used[k] = t as u64;
                let pool = rayon::ThreadPoolBuilder::new().num_threads(t).build().map_err(|e| Error::Usage(format!("metro: cannot start {t} threads: {e}")))?;
                Target::Paged { lvl: l, cache: p.cache, pool }
            }
        };
        bvh_s += t0.elapsed().as_secs_f64();
        let t1 = Instant::now();
        let progress = Progress::items(target, name, opts.quiet);
        let (d, summary) = match src {
            Operand::Mem(m) => (measure(&mut MemGen::new(m, target, seed), &tg, batch, snap, &progress)?, None),
            Operand::Paged(l) => {
                let p = paging.as_ref().expect("a paged operand comes with a cache");
                let mut g = PagedGen::new(l, p.cache, target, seed);
                let d = measure(&mut g, &tg, batch, snap, &progress)?;
                (d, Some(g.summary()))
            }
        };
        progress.finish();
        Ok((d, summary, t1.elapsed().as_secs_f64()))
    };
    let (ab, sum_a, t_ab) = direction(a, b, seed_ab, "A -> B", 0)?;
    let (ba, sum_b, t_ba) = direction(b, a, seed_ba, "B -> A", 1)?;
    let summary = |o: &Operand, s: Option<MeshSummary>, name: &str| match o {
        Operand::Mem(m) => MeshSummary::of(m, name),
        Operand::Paged(_) => s.expect("a paged operand is summarised by its sampling"),
    };
    let (sa, sb) = (summary(a, sum_a, "A"), summary(b, sum_b, "B"));
    let mut u = sa.bbox;
    u.merge(&sb.bbox);
    let paging = paging.map(|p| {
        let c = p.cache;
        PagingReport {
            peak_resident: c.acct.peak.load(Relaxed),
            loads: c.loads.load(Relaxed),
            hits: c.hits.load(Relaxed),
            evictions: c.evictions.load(Relaxed),
            overcommits: c.overcommits.load(Relaxed),
            bytes_read: c.bytes_read.load(Relaxed),
            scan_bytes: c.scan_bytes.load(Relaxed),
            query_threads: threads_used,
            peak_rss: crate::progress::peak_rss(),
            ..p.report
        }
    });
    Ok(Report {
        diagonal: sa.bbox.diagonal(),
        union_diagonal: u.diagonal(),
        a: sa,
        b: sb,
        seed: opts.seed,
        samples_target: target,
        combined: ab.combine(&ba),
        a_to_b: ab,
        b_to_a: ba,
        seconds: Timings { load: 0.0, bvh: bvh_s, a_to_b: t_ab, b_to_a: t_ba },
        paging,
        attributes: None,
    })
}

/// Most samples per direction `--samples` accepts (about an hour per
/// direction on two cores).
pub const MAX_SAMPLES: u64 = 10_000_000_000;

impl Options {
    /// Options with the sample count checked: at least 1, at most
    /// [`MAX_SAMPLES`].
    pub fn checked(samples: Option<u64>, seed: u64, quiet: bool) -> Result<Options> {
        if samples == Some(0) {
            return Err(Error::Usage("metro: --samples must be at least 1".into()));
        }
        if let Some(n) = samples.filter(|&n| n > MAX_SAMPLES) {
            return Err(Error::Usage(format!("metro: --samples {n} is more than {MAX_SAMPLES} per direction (hours of work); ask fewer")));
        }
        Ok(Options { samples, seed, quiet })
    }
}

impl MemOptions {
    /// From `--mem` (a size like `512M`, checked against the machine's
    /// memory): explicit when given, else the default budget.
    pub fn parse(mem: Option<&str>) -> Result<MemOptions> {
        Ok(match mem {
            Some(m) => MemOptions { budget: crate::mem::parse_budget(m, "--mem")?, explicit: true },
            None => MemOptions::default(),
        })
    }
}

/// A whole `octolod metro` run, as the binary parses it.
#[derive(Clone, Debug)]
pub struct RunOptions {
    /// The reference mesh.
    pub a: Source,
    /// The compared mesh.
    pub b: Source,
    pub options: Options,
    pub mem: MemOptions,
    /// Thresholds on the combined figures.
    pub limits: Limits,
    /// Print one JSON object ([`JsonReport`]) instead of the table.
    pub json: bool,
    /// Also measure attributes ([`attributes`]).
    pub attributes: bool,
}

/// Compares, prints the table (or JSON) on stdout and each exceeded
/// threshold on stderr. Ok(false) when a threshold is exceeded (the binary
/// then exits with [`EXIT_THRESHOLD`]).
pub fn run(o: &RunOptions) -> Result<bool> {
    let mut r = compare_sources(&o.a, &o.b, &o.options, &o.mem)?;
    if o.attributes {
        let (a, aa) = o.a.load_full()?;
        let (b, ba) = o.b.load_full()?;
        let common = AttrSet(aa.0 & ba.0 & (AttrSet::UV | AttrSet::COLOR));
        r.attributes = attributes::attribute_errors(&a, &b, common, r.samples_target, o.options.seed);
        if r.attributes.is_none() && !o.options.quiet {
            eprintln!("octolod: metro: --attributes: {} and {} share no uv or colour", o.a, o.b);
        }
    }
    let mut out = std::io::stdout().lock();
    let text = if o.json { r.to_json(&o.limits) } else { r.table() };
    let _ = writeln!(out, "{text}");
    let _ = out.flush();
    let checks = r.check(&o.limits);
    let mut ok = true;
    for c in checks.iter().filter(|c| c.exceeded) {
        ok = false;
        eprintln!("octolod: metro: {} {:.6e} exceeds {} {} (limit {:.6e})", c.metric, c.value, c.option, c.threshold, c.limit);
    }
    Ok(ok)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::random_mesh;

    #[test]
    fn results_do_not_depend_on_thread_count() {
        let a = random_mesh(300, 11);
        let b = random_mesh(200, 12);
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| compare(&a, &b, &Options { samples: Some(3 * CHUNK + 123), seed: 4, quiet: true }).unwrap())
        };
        let (r1, r3) = (run(1), run(3));
        assert_eq!(r1.to_json(&Limits::default()), r3.to_json(&Limits::default()));
        assert_eq!(r1.combined.sum.to_bits(), r3.combined.sum.to_bits());
        assert!(r1.combined.max > 0.0);
        let r_other = compare(&a, &b, &Options { samples: Some(3 * CHUNK + 123), seed: 5, quiet: true }).unwrap();
        assert_ne!(r1.combined.sum, r_other.combined.sum, "the seed changes the face samples");
    }

    /// Issue "Reliability v2" item 13f: a mesh against itself must measure
    /// 0, not the rounding (`--max-hausdorff 0` must pass), also far from
    /// the origin, where the rounding grows with the coordinates.
    #[test]
    fn identical_meshes_measure_zero_anywhere_and_real_offsets_still_show() {
        // A wavy 40 × 40 grid over [0, 1]², scaled and moved.
        let grid = |scale: f64, offset: f64, shift: f64| {
            let n = 40u32;
            let mut positions = Vec::new();
            for j in 0..=n {
                for i in 0..=n {
                    let (x, y) = (i as f64 / n as f64, j as f64 / n as f64);
                    let z = 0.1 * (7.0 * x).sin() * (5.0 * y).cos();
                    positions.push([x * scale + offset, y * scale - offset, z * scale + 0.5 * offset + shift]);
                }
            }
            Mesh::new(positions, crate::geom::grid_triangles(n))
        };
        let opts = Options { samples: Some(200_000), seed: 3, quiet: true };
        for (scale, offset) in [(1.0, 0.0), (0.9, 1.0), (3.0, 100.0), (10.0, 1e6), (1.0, -3e9)] {
            let m = grid(scale, offset, 0.0);
            let r = compare(&m, &m, &opts).unwrap();
            for d in [r.a_to_b, r.b_to_a, r.combined] {
                assert_eq!((d.max, d.mean, d.rms, d.sum, d.sum2), (0.0, 0.0, 0.0, 0.0, 0.0), "offset {offset}");
            }
            assert!(r.check(&Limits::parse(Some("0"), Some("0"), Some("0")).unwrap()).iter().all(|c| !c.exceeded));
        }
        // A real offset far above the rounding still measures.
        for shift in [1e-9, 1e-12] {
            let r = compare(&grid(1.0, 0.0, 0.0), &grid(1.0, 0.0, shift), &opts).unwrap();
            assert!(r.combined.max > 0.5 * shift && r.combined.max <= 1.01 * shift, "shift {shift}: {}", r.combined.max);
            assert!(r.combined.mean > 0.0 && r.combined.rms > 0.0);
        }
        assert_eq!(snap_distance(&[crate::mesh::Aabb { min: [-2.0, 0.0, 0.0], max: [1.0, 1.0, 1.0] }]), 2.0 * SNAP_ULPS * f64::EPSILON);
    }
}

//! `octolod plan`: one streaming pass over the input that splits its box
//! into shards of about equal triangle counts (a kd-tree of median splits
//! over a uniform sample of the vertices), ordered largest first, with the
//! input's identity so a plan made for another file is refused.

use crate::error::{Error, IoContext, Location, Result};
use crate::geom::Rng;
use crate::lod::level::CreaseProbe;
use crate::manifest::BuildParams;
use crate::mesh::{Aabb, Vertex};
use crate::ply::read::BodySink;
use crate::progress::Progress;
use std::io::Read;
use std::path::Path;

/// The `format` of a plan file.
pub const PLAN_FORMAT: &str = "octolod-plan";
const PLAN_VERSION: u32 = 1;
/// Largest plan file read (a plan is a few KiB per thousand shards).
const MAX_PLAN: u64 = 64 << 20;
/// Most shards a plan makes.
pub const MAX_SHARDS: u32 = 65_536;
/// Most vertices sampled for the split (24 bytes each).
const MAX_SAMPLE: usize = 1 << 21;
/// Bytes of the input's start hashed into its identity.
const HEAD_BYTES: usize = 64 << 10;

/// What a plan knows of its input: a stale plan (the file changed) is refused.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct InputId {
    /// As given to `plan` (for people; the other fields decide).
    pub path: String,
    pub bytes: u64,
    /// Modification time, nanoseconds since the epoch.
    pub mtime_ns: u64,
    /// FNV-1a of the first 64 KiB (the header and the first records).
    pub head_fnv: String,
}

impl InputId {
    /// The identity of `path` now.
    pub fn of(path: &Path) -> Result<InputId> {
        let (mut f, bytes) = crate::io::open_regular(path, "open")?;
        let mtime_ns =
            f.metadata().ctx(path, "stat")?.modified().ok().and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok()).map_or(0, |d| d.as_nanos() as u64);
        let mut head = vec![0u8; HEAD_BYTES.min(bytes as usize)];
        f.read_exact(&mut head).ctx(path, "read")?;
        Ok(InputId { path: path.display().to_string(), bytes, mtime_ns, head_fnv: format!("{:016x}", fnv1a(&head)) })
    }

    /// An error unless `now` is the same file's content as when planned.
    pub fn check(&self, now: &InputId, plan: &Path) -> Result<()> {
        if (self.bytes, self.mtime_ns, &self.head_fnv) != (now.bytes, now.mtime_ns, &now.head_fnv) {
            return Err(Error::Usage(format!(
                "{}: the plan is stale: {} changed since it was planned ({} bytes, modified at {} ns; now {} bytes at {} ns{}); run `octolod plan` again",
                plan.display(),
                now.path,
                self.bytes,
                self.mtime_ns,
                now.bytes,
                now.mtime_ns,
                if self.head_fnv != now.head_fnv { ", another header" } else { "" }
            )));
        }
        Ok(())
    }
}

/// One node of the split: a shard, or a plane with the two sides.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Split {
    Shard(u32),
    /// Positions with `p[axis] < f64::from_bits(at_bits)` go to node
    /// `below`, the others to `above` (`at` for people).
    Plane {
        axis: u8,
        at_bits: u64,
        at: f64,
        below: u32,
        above: u32,
    },
}

/// One shard of the plan.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ShardPlan {
    pub index: u32,
    /// Triangles expected (the input's, by the sample's share).
    pub est_triangles: u64,
    /// Box of its sampled vertices.
    pub sample_box: [f64; 6],
}

/// A sharded build's plan (`PLAN.json`).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Plan {
    pub format: String,
    pub version: u32,
    /// FNV-1a of the plan's other fields: the store id of the build, checked
    /// by every shard and by the merge.
    pub plan_id: String,
    pub input: InputId,
    /// The build's parameters (`--mem` is each command's own).
    pub params: BuildParams,
    /// Levels each shard builds (0..shard_levels); the merge builds the rest.
    pub shard_levels: u8,
    pub triangles: u64,
    pub vertices: u64,
    /// The kd-tree; node 0 is the root.
    pub split: Vec<Split>,
    /// Largest first.
    pub shards: Vec<ShardPlan>,
    pub seconds: f64,
}

/// `plan`'s options.
#[derive(Clone, Debug)]
pub struct PlanOptions {
    pub params: BuildParams,
    pub shards: u32,
    /// Instead of `shards`: as many shards as hold about this many
    /// triangles each (`--shard-tris`).
    pub shard_tris: Option<u64>,
    /// Levels the shards build; default: as many as leave the smallest
    /// shard at least four leaves' worth of triangles.
    pub shard_levels: Option<u8>,
    pub quiet: bool,
}

/// FNV-1a, 64 bits: stable across runs and machines (unlike `std`'s hasher).
pub fn fnv1a(b: &[u8]) -> u64 {
    b.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &x| (h ^ x as u64).wrapping_mul(0x0000_0100_0000_01b3))
}

impl Plan {
    /// The shard that holds position `p`.
    pub fn shard_of(&self, p: [f64; 3]) -> u32 {
        let mut at = 0usize;
        loop {
            match &self.split[at] {
                Split::Shard(s) => return *s,
                Split::Plane { axis, at_bits, below, above, .. } => {
                    at = if p[*axis as usize] < f64::from_bits(*at_bits) { *below } else { *above } as usize;
                }
            }
        }
    }

    /// The store id the plan's build gets.
    pub fn store_id(&self) -> u64 {
        u64::from_str_radix(&self.plan_id, 16).unwrap_or(0)
    }

    fn content_id(&self) -> String {
        let mut p = self.clone();
        p.plan_id.clear();
        p.seconds = 0.0;
        format!("{:016x}", fnv1a(serde_json::to_string(&p).expect("a plan serializes").as_bytes()))
    }

    /// Reads and checks a plan file.
    pub fn read(path: &Path) -> Result<Plan> {
        let bad = |msg: String| Error::input(Location { file: path.to_path_buf(), ..Default::default() }, msg);
        let text = crate::io::read_bounded(path, MAX_PLAN, "a plan")?;
        let p: Plan = serde_json::from_slice(&text).map_err(|e| bad(format!("not an octolod plan: {e}")))?;
        if p.format != PLAN_FORMAT || p.version != PLAN_VERSION {
            return Err(bad(format!("format {:?} version {}: not an octolod plan of version {PLAN_VERSION}", p.format, p.version)));
        }
        if p.content_id() != p.plan_id {
            return Err(bad(format!("plan id {} does not match its content (edited?)", p.plan_id)));
        }
        p.check_split().map_err(bad)?;
        Ok(p)
    }

    /// Every split node reached once, every shard index a leaf once.
    fn check_split(&self) -> std::result::Result<(), String> {
        let n = self.shards.len();
        let mut seen = vec![false; n];
        let mut stack = vec![(0u32, 0u32)];
        let mut visited = 0usize;
        while let Some((at, depth)) = stack.pop() {
            visited += 1;
            if depth > 64 || visited > self.split.len() {
                return Err("the split is not a tree".into());
            }
            match self.split.get(at as usize) {
                Some(Split::Shard(s)) if (*s as usize) < n && !seen[*s as usize] => seen[*s as usize] = true,
                Some(Split::Plane { axis, below, above, .. }) if *axis < 3 => {
                    stack.push((*below, depth + 1));
                    stack.push((*above, depth + 1));
                }
                _ => return Err(format!("split node {at} is missing or repeats a shard")),
            }
        }
        let mut idx: Vec<u32> = self.shards.iter().map(|s| s.index).collect();
        idx.sort_unstable();
        if !seen.iter().all(|&s| s) || idx != (0..n as u32).collect::<Vec<_>>() {
            return Err("shards and split do not match".into());
        }
        Ok(())
    }

    /// Writes the plan (atomically; never over a file that is not a plan
    /// unless it is absent).
    pub fn write(&self, out: &Path, force: bool) -> Result<()> {
        let mut f = crate::io::AtomicFile::create(out, crate::io::OutputKind::Plan, force)?;
        use std::io::Write;
        let text = serde_json::to_string_pretty(self).expect("a plan serializes");
        f.writer().write_all(text.as_bytes()).ctx(out, "write")?;
        f.writer().write_all(b"\n").ctx(out, "write")?;
        f.commit()
    }
}

/// Bounding box and a uniform sample of the vertices (reservoir).
struct Sampler {
    bbox: Aabb,
    seen: u64,
    cap: usize,
    sample: Vec<[f64; 3]>,
    rng: Rng,
    triangles: u64,
    file: std::path::PathBuf,
    /// With input normals: their creases, for `--normals auto`.
    probe: Option<CreaseProbe>,
}

impl BodySink for Sampler {
    fn vertices(&mut self, first: u64, batch: &[Vertex]) -> Result<()> {
        if let Some(k) = batch.iter().position(|v| !v.pos.iter().all(|x| x.is_finite())) {
            return Err(Error::input(
                Location { file: self.file.clone(), element: Some("vertex".into()), record: Some(first + k as u64), ..Default::default() },
                "a non-finite coordinate",
            ));
        }
        if let Some(p) = &mut self.probe {
            p.add_all(batch);
        }
        for v in batch {
            self.bbox.add(v.pos);
            if self.sample.len() < self.cap {
                self.sample.push(v.pos);
            } else {
                let j = self.rng.next_u64() % (self.seen + 1);
                if (j as usize) < self.cap {
                    self.sample[j as usize] = v.pos;
                }
            }
            self.seen += 1;
        }
        Ok(())
    }
    fn triangles(&mut self, batch: &[[u64; 3]]) -> Result<()> {
        self.triangles += batch.len() as u64;
        Ok(())
    }
}

/// Median splits of `pts` into `count` shards numbered from `first`; appends
/// the nodes to `split` and returns the subtree's root.
fn split_into(pts: &mut [[f64; 3]], first: u32, count: u32, split: &mut Vec<Split>, out: &mut Vec<(u32, Vec<[f64; 3]>)>) -> u32 {
    let me = split.len() as u32;
    if count == 1 {
        split.push(Split::Shard(first));
        out.push((first, pts.to_vec()));
        return me;
    }
    split.push(Split::Shard(u32::MAX));
    let mut b = Aabb::EMPTY;
    for p in pts.iter() {
        b.add(*p);
    }
    let below_n = count / 2;
    let k = (pts.len() as u64 * below_n as u64 / count as u64) as usize;
    // The longest axis whose median plane splits near the target: many
    // points on one plane (a grid's rows, a flat part) can leave an axis
    // unable to, and then the next longest is tried.
    let mut axes = [0usize, 1, 2];
    if !b.is_empty() {
        axes.sort_by(|&i, &j| (b.max[j] - b.min[j]).total_cmp(&(b.max[i] - b.min[i])));
    }
    let mut best: Option<(usize, f64, usize)> = None;
    for axis in axes {
        let (at, off) = plane(pts, axis, k);
        if best.is_none_or(|b| off < b.2) {
            best = Some((axis, at, off));
        }
        if off <= pts.len() / 100 {
            break;
        }
    }
    let (axis, at, _) = best.expect("three axes tried");
    // The side is the rule `p[axis] < at`, not the selection's order.
    let mut i = 0;
    for j in 0..pts.len() {
        if pts[j][axis] < at {
            pts.swap(i, j);
            i += 1;
        }
    }
    let (lo, hi) = pts.split_at_mut(i);
    let below = split_into(lo, first, below_n, split, out);
    let above = split_into(hi, first + below_n, count - below_n, split, out);
    split[me as usize] = Split::Plane { axis: axis as u8, at_bits: at.to_bits(), at, below, above };
    me
}

/// The plane across `axis` with about `k` of `pts` below it (`p[axis] <
/// at`), and how far from `k` its count is.
fn plane(pts: &mut [[f64; 3]], axis: usize, k: usize) -> (f64, usize) {
    if pts.is_empty() {
        return (0.0, 0);
    }
    let kk = k.min(pts.len() - 1);
    pts.select_nth_unstable_by(kk, |a, c| a[axis].total_cmp(&c[axis]));
    let at = pts[kk][axis];
    let below = pts.iter().filter(|p| p[axis] < at).count();
    let upto = pts.iter().filter(|p| p[axis] <= at).count();
    if upto.abs_diff(k) < below.abs_diff(k) {
        (next_up(at), upto.abs_diff(k))
    } else {
        (at, below.abs_diff(k))
    }
}

/// The smallest f64 above finite `x` (`f64::next_up`, newer than the MSRV).
fn next_up(x: f64) -> f64 {
    if x == 0.0 {
        f64::from_bits(1)
    } else if x > 0.0 {
        f64::from_bits(x.to_bits() + 1)
    } else {
        f64::from_bits(x.to_bits() - 1)
    }
}

/// `octolod plan`: reads `input` once and writes the plan to `out`.
pub fn plan(input: &Path, out: &Path, opts: &PlanOptions, force: bool) -> Result<Plan> {
    let t0 = std::time::Instant::now();
    if opts.shards == 0 || opts.shards > MAX_SHARDS {
        return Err(Error::Usage(format!("--shards must be within 1..={MAX_SHARDS}, not {}", opts.shards)));
    }
    if opts.shard_tris == Some(0) {
        return Err(Error::Usage("--shard-tris must be at least 1".into()));
    }
    crate::lod::check_params(&opts.params)?;
    let _input = crate::io::protect(input);
    crate::io::check_output(out, crate::io::OutputKind::Plan, force)?;
    let id = InputId::of(input)?;
    let progress = Progress::bytes(id.bytes, "planning", opts.quiet);
    let header = crate::input::read_header(input, &progress)?;
    let cap = ((opts.params.mem / 4 / 24) as usize).clamp(1 << 12, MAX_SAMPLE);
    let probe = header.attrs.normal().then(CreaseProbe::new);
    let mut s = Sampler { bbox: Aabb::EMPTY, seen: 0, cap, sample: Vec::new(), rng: Rng::new(0x5eed_0c70), triangles: 0, file: input.to_path_buf(), probe };
    let scratch = crate::io::scratch_dir(out)?;
    let stats = crate::input::read_body(input, &header, opts.params.mem, scratch.path(), &mut s, &progress)?;
    progress.finish();
    if s.triangles == 0 || s.sample.is_empty() {
        return Err(Error::input(Location { file: input.to_path_buf(), ..Default::default() }, "no triangles to plan"));
    }
    let simplifier = opts.params.simplifier.resolve(header.attrs);
    // Without normals there is nothing to average: `carry` (a plan never
    // records `auto`).
    let normals = opts.params.normals.resolved(simplifier, Some(s.probe.as_ref().is_some_and(CreaseProbe::smooth)));
    let mut split = Vec::new();
    let mut parts = Vec::new();
    let total = s.sample.len() as u64;
    let count = match opts.shard_tris {
        Some(t) => s.triangles.div_ceil(t).clamp(1, MAX_SHARDS as u64) as u32,
        None => opts.shards,
    };
    split_into(&mut s.sample, 0, count, &mut split, &mut parts);
    let mut shards: Vec<ShardPlan> = parts
        .into_iter()
        .map(|(index, pts)| {
            let mut b = Aabb::EMPTY;
            for p in &pts {
                b.add(*p);
            }
            let sample_box = if b.is_empty() { [0.0; 6] } else { [b.min[0], b.min[1], b.min[2], b.max[0], b.max[1], b.max[2]] };
            ShardPlan { index, est_triangles: (s.triangles as f64 * pts.len() as f64 / total as f64).round() as u64, sample_box }
        })
        .collect();
    shards.sort_by(|a, b| b.est_triangles.cmp(&a.est_triangles).then(a.index.cmp(&b.index)));
    let shard_levels = opts.shard_levels.unwrap_or_else(|| default_shard_levels(&opts.params, shards.iter().map(|s| s.est_triangles).min().unwrap_or(0)));
    if let Some(l) = opts.params.levels {
        if shard_levels > l {
            return Err(Error::Usage(format!("--shard-levels {shard_levels} is above --levels {l}")));
        }
    }
    let mut p = Plan {
        format: PLAN_FORMAT.into(),
        version: PLAN_VERSION,
        plan_id: String::new(),
        input: id,
        // Every shard and the merge use the one simplifier the input's
        // attributes choose (a plan never records `auto`).
        // `--normals auto` is resolved here too, from the pass's creases,
        // so every shard and the merge agree.
        params: BuildParams { simplifier, normals, ..opts.params.clone() },
        shard_levels,
        triangles: s.triangles,
        vertices: stats.vertices,
        split,
        shards,
        seconds: 0.0,
    };
    p.plan_id = p.content_id();
    p.seconds = t0.elapsed().as_secs_f64();
    p.write(out, force)?;
    Ok(p)
}

/// Levels a shard builds: as many as leave the smallest shard at least four
/// leaves' worth of triangles at its top (the merge then starts from nodes
/// of about a leaf each, as a monolithic build's level there).
fn default_shard_levels(p: &BuildParams, smallest: u64) -> u8 {
    let mut l = 0u8;
    let mut t = smallest as f64;
    while t / p.level_ratio >= 4.0 * p.leaf_tris as f64 && l < crate::lod::MAX_LEVELS / 2 && p.levels.is_none_or(|m| l < m) {
        t /= p.level_ratio;
        l += 1;
    }
    l
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plan_of(split: Vec<Split>, n: u32) -> Plan {
        let mut p = Plan {
            format: PLAN_FORMAT.into(),
            version: PLAN_VERSION,
            plan_id: String::new(),
            input: InputId { path: "x".into(), bytes: 1, mtime_ns: 2, head_fnv: "3".into() },
            params: BuildParams::default(),
            shard_levels: 0,
            triangles: 10,
            vertices: 10,
            split,
            shards: (0..n).map(|index| ShardPlan { index, est_triangles: 1, sample_box: [0.0; 6] }).collect(),
            seconds: 0.0,
        };
        p.plan_id = p.content_id();
        p
    }

    #[test]
    fn the_split_balances_the_sample_and_places_every_point_where_it_was_counted() {
        let mut rng = Rng::new(3);
        // Clustered points, with ties on one axis (a flat sheet).
        let pts: Vec<[f64; 3]> = (0..20_000).map(|i| [rng.f64().powi(3), if i % 2 == 0 { 0.5 } else { rng.f64() }, 0.0]).collect();
        for n in [1u32, 2, 3, 5, 16] {
            let (mut split, mut parts) = (Vec::new(), Vec::new());
            split_into(&mut pts.clone(), 0, n, &mut split, &mut parts);
            let p = plan_of(split, n);
            p.check_split().unwrap();
            let mut counts = vec![0usize; n as usize];
            for (s, part) in &parts {
                for q in part {
                    assert_eq!(p.shard_of(*q), *s, "{n} shards: a point counted in {s}");
                }
                counts[*s as usize] = part.len();
            }
            assert_eq!(counts.iter().sum::<usize>(), pts.len());
            let even = pts.len() / n as usize;
            assert!(counts.iter().all(|&c| c.abs_diff(even) <= even / 50 + 1), "{n} shards: {counts:?}");
        }
    }

    #[test]
    fn a_plan_reads_back_and_an_edited_one_is_refused() {
        let d = tempfile::tempdir().unwrap();
        let (mut split, mut parts) = (Vec::new(), Vec::new());
        split_into(&mut [[0.1, 0.2, 0.3], [0.7, 0.1, 0.9], [0.5, 0.5, 0.5]], 0, 2, &mut split, &mut parts);
        let p = plan_of(split, 2);
        let path = d.path().join("p.json");
        p.write(&path, false).unwrap();
        assert_eq!(Plan::read(&path).unwrap(), p);
        // Floats read back bit for bit (the id is over their text).
        let text = std::fs::read_to_string(&path).unwrap().replace("\"mtime_ns\": 2", "\"mtime_ns\": 4");
        std::fs::write(&path, text).unwrap();
        assert!(Plan::read(&path).unwrap_err().to_string().contains("does not match its content"));
        // A plan whose shards and split disagree is refused.
        let mut q = plan_of(vec![Split::Shard(0)], 2);
        q.plan_id = q.content_id();
        std::fs::write(&path, serde_json::to_string(&q).unwrap()).unwrap();
        assert!(Plan::read(&path).is_err());
    }
}

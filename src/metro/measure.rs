//! One direction of a comparison: samples from a [`Gen`], their closest
//! points in a [`Target`] (a mesh's BVH, or a paged level), and the sums
//! combined in job order so every figure is bit-identical whatever the
//! threads, batches or paging.
//!
//! Takes: a sample generator and a target. Gives: the direction's
//! [`Distances`].

use super::cache::Cache;
use super::paged::PagedLevel;
use super::sample::{Gen, Job, MemGen};
use super::{BATCH_MAX, CHUNK};
use crate::error::{Error, Result};
use crate::geom::{Bvh, Mesh, P3};
use crate::mesh::Aabb;
use crate::progress::Progress;
use rayon::prelude::*;

/// Distances of one direction.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Distances {
    pub samples: u64,
    pub vertex_samples: u64,
    pub edge_samples: u64,
    pub face_samples: u64,
    /// Hausdorff (one-sided, or two-sided for the combined figures).
    pub max: f64,
    pub mean: f64,
    pub rms: f64,
    /// Where the maximum was found (a sample on the source mesh).
    pub max_at: P3,
    /// Sum and sum of squares of the distances (for combining).
    pub sum: f64,
    pub sum2: f64,
}

impl Distances {
    pub(super) fn combine(&self, o: &Distances) -> Distances {
        let samples = self.samples + o.samples;
        let (sum, sum2) = (self.sum + o.sum, self.sum2 + o.sum2);
        let (max, max_at) = if o.max > self.max { (o.max, o.max_at) } else { (self.max, self.max_at) };
        Distances {
            samples,
            vertex_samples: self.vertex_samples + o.vertex_samples,
            edge_samples: self.edge_samples + o.edge_samples,
            face_samples: self.face_samples + o.face_samples,
            max,
            mean: if samples > 0 { sum / samples as f64 } else { 0.0 },
            rms: if samples > 0 { (sum2 / samples as f64).sqrt() } else { 0.0 },
            max_at,
            sum,
            sum2,
        }
    }
}

#[derive(Clone, Copy, Default)]
struct Acc {
    n: u64,
    sum: f64,
    sum2: f64,
    max: f64,
    max_at: P3,
}

impl Acc {
    /// Counts a sample at squared distance `d2`; distances at most `snap`
    /// are rounding and count as 0 ([`snap_distance`]).
    #[inline]
    fn add(&mut self, d2: f64, p: P3, snap: f64) {
        let mut d = d2.sqrt();
        let mut d2 = d2;
        if d <= snap {
            (d, d2) = (0.0, 0.0);
        }
        if self.n == 0 || d > self.max {
            self.max = d;
            self.max_at = p;
        }
        self.n += 1;
        self.sum += d;
        self.sum2 += d2;
    }
}

/// Where one direction looks for closest points.
pub(super) enum Target<'a> {
    Mem(&'a Bvh),
    Paged { lvl: &'a PagedLevel, cache: &'a Cache, pool: rayon::ThreadPool },
}

impl Target<'_> {
    /// Squared distances of `points` (grouped in `jobs`) into `d2`.
    fn query(&self, points: &[P3], jobs: &[Job], d2: &mut [f64]) -> Result<()> {
        match self {
            Target::Mem(bvh) => {
                let mut rest = &mut d2[..];
                let mut work = Vec::with_capacity(jobs.len());
                for j in jobs {
                    let (head, tail) = rest.split_at_mut(j.len);
                    work.push((j.at, head));
                    rest = tail;
                }
                work.into_par_iter().for_each(|(at, out)| {
                    let mut hint = u32::MAX;
                    for (k, o) in out.iter_mut().enumerate() {
                        let (d, slot, _) = bvh.nearest(points[at + k], hint);
                        hint = slot;
                        *o = d;
                    }
                });
                Ok(())
            }
            Target::Paged { lvl, cache, pool } => lvl.query(cache, pool, points, d2),
        }
    }
}

/// Distances of one direction: batches from `gen`, closest points in
/// `target`, per-job sums combined in job order.
pub(super) fn measure(gen: &mut dyn Gen, target: &Target, batch: usize, snap: f64, progress: &Progress) -> Result<Distances> {
    let mut points: Vec<P3> = Vec::new();
    let mut jobs: Vec<Job> = Vec::new();
    let mut d2: Vec<f64> = Vec::new();
    let mut acc = Acc::default();
    loop {
        points.clear();
        jobs.clear();
        // Each batch is a safe point for signals.
        crate::io::signal::check()?;
        if !gen.fill(&mut points, &mut jobs, batch)? {
            break;
        }
        d2.clear();
        d2.resize(points.len(), 0.0);
        target.query(&points, &jobs, &mut d2)?;
        let parts: Vec<Acc> = jobs
            .par_iter()
            .map(|j| {
                debug_assert!(j.start % CHUNK == 0 && j.len as u64 <= CHUNK);
                let mut a = Acc::default();
                for k in j.at..j.at + j.len {
                    a.add(d2[k], points[k], snap);
                }
                a
            })
            .collect();
        for p in &parts {
            if p.n > 0 && (acc.n == 0 || p.max > acc.max) {
                acc.max = p.max;
                acc.max_at = p.max_at;
            }
            acc.n += p.n;
            acc.sum += p.sum;
            acc.sum2 += p.sum2;
        }
        progress.inc(points.len() as u64);
    }
    let (nv, ne, nf) = gen.counts();
    let n = acc.n.max(1) as f64;
    Ok(Distances {
        samples: acc.n,
        vertex_samples: nv,
        edge_samples: ne,
        face_samples: nf,
        max: acc.max,
        mean: acc.sum / n,
        rms: (acc.sum2 / n).sqrt(),
        max_at: acc.max_at,
        sum: acc.sum,
        sum2: acc.sum2,
    })
}

/// One-sided distances from `src`'s samples to the mesh `target` indexes:
/// about `samples` samples (see [`super`]), from `seed`.
pub fn one_sided(src: &Mesh, target: &Bvh, samples: u64, seed: u64, progress: &Progress) -> Result<Distances> {
    if target.is_empty() {
        return Err(Error::Usage("metro: the target mesh has no triangles".into()));
    }
    if src.triangles.is_empty() {
        return Err(Error::Usage("metro: the source mesh has no triangles".into()));
    }
    src.check_indices().map_err(|m| Error::Usage(format!("metro: source mesh: {m}")))?;
    // Every sample lies on `src`, and a distance near the rounding is to
    // a point of `target` near it: `src`'s coordinates set the scale.
    let snap = snap_distance(&[src.bbox()]);
    measure(&mut MemGen::new(src, samples, seed), &Target::Mem(target), BATCH_MAX, snap, progress)
}

/// Distances at most this are rounding, not distance, and count as 0:
/// [`SNAP_ULPS`] × `f64::EPSILON` × the largest coordinate magnitude of the
/// boxes (why: `docs/metro.md`, "Rounding").
pub fn snap_distance(boxes: &[Aabb]) -> f64 {
    let m =
        boxes.iter().filter(|b| !b.is_empty()).flat_map(|b| b.min.iter().chain(b.max.iter())).map(|x| x.abs()).filter(|x| x.is_finite()).fold(0.0, f64::max);
    SNAP_ULPS * f64::EPSILON * m
}

/// Rounding allowance of [`snap_distance`], in units of `f64::EPSILON` × the
/// coordinates' magnitude.
pub const SNAP_ULPS: f64 = 64.0;

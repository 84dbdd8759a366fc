//! Quadric edge collapse of one mesh (or node) with attributes and locked
//! vertices: the `collapse` simplifier of both `octolod simplify`
//! ([`crate::simplify`]) and `octolod build` ([`super`]).
//!
//! Takes: an indexed mesh, a lock flag per vertex, the attribute set, a
//! triangle target and optionally an absolute error limit. Gives: the
//! re-placed vertices (same indexing as the input: meshoptimizer keeps
//! the vertex buffer and moves survivors in place) and the surviving
//! triangles over them, so a caller knows which input vertex each output
//! vertex is and which triangles came from where.
//!
//! meshoptimizer's `simplifyWithUpdate`: vertex positions and attributes
//! re-placed optimally, locked vertices kept bit-exact, normals, colours
//! and uvs weighted into the quadric, attribute seams kept closed; to a
//! triangle count also lightly regularised (well-shaped triangles; 3.4–4.6×
//! lower RMS on smooth 2 M spheres, `docs/simplify.md`).
//! Positions go to meshoptimizer as f32 relative to the mesh's centre, so
//! inputs far from the origin keep their precision; locked vertices are
//! restored from their f64 originals. Results are clamped into the input's
//! box and attribute ranges; normals are renormalised.

use crate::mesh::IndexedMesh;
use crate::mesh::{Aabb, AttrSet, Vertex};

/// Weights of the attribute channels against position error (which
/// meshoptimizer measures relative to the mesh's extent): unit normals and
/// 0..1 colours, so a normal turned by ~60° or a colour channel off by 1
/// costs about as much as a 25 % (normals) / 50 % (colours) deviation.
const NORMAL_WEIGHT: f32 = 0.25;
const COLOR_WEIGHT: f32 = 0.5;
const UV_WEIGHT: f32 = 1.0;

/// A collapsed mesh over the input's vertex indices.
pub struct Collapsed {
    /// Every input vertex, survivors re-placed (locked ones unchanged).
    pub vertices: Vec<Vertex>,
    /// The surviving triangles, over `vertices`.
    pub triangles: Vec<[u32; 3]>,
    /// meshoptimizer's error of the result: absolute (object space, with
    /// the weighted attribute terms) when an error limit was given, else
    /// relative to the mesh's extent.
    pub error: f64,
}

/// Collapses `mesh` towards `target_tris` triangles (0 with an error limit:
/// as far as the limit allows), keeping `locked` vertices bit-exact. With
/// no error limit the collapse is lightly regularised (well-shaped
/// triangles); with no error limit, no lock and the target missed
/// (topology stopped it), a second pass may remove small disconnected parts.
pub fn collapse(mesh: &IndexedMesh, locked: &[bool], attrs: AttrSet, target_tris: usize, max_error: Option<f64>) -> Collapsed {
    if mesh.triangles.is_empty() {
        return Collapsed { vertices: mesh.vertices.clone(), triangles: Vec::new(), error: 0.0 };
    }
    let mut input = Input::new(mesh, locked, attrs);
    let Input { bb, c, na, .. } = input;
    // Positions and index are worked on in place; the attributes' input
    // values stay for their ranges below.
    let (mut pos, mut idx) = (std::mem::take(&mut input.pos), std::mem::take(&mut input.idx));
    let mut attr = input.attr.clone();
    // To a count (`simplify`), with meshoptimizer's light regularisation,
    // which keeps triangles well shaped: on a smooth 2 M sphere it took
    // the RMS at 186 K triangles from 5.7x MeshLab's quadric edge collapse
    // to 1.25x (the unregularised collapse leaves slivers whose chords cut
    // the curve); on the 1 M noisy scan it moved RMS by -4.4 % (97 K) and
    // +6.8 % (487 K). To an error limit (the hierarchy's levels) without:
    // there it cost the scan's level 1 19 % in RMS (figures:
    // docs/simplify.md, "Regularised collapse").
    let (count, err, opts) = match max_error {
        None => (3 * target_tris, f32::MAX, meshopt::SimplifyOptions::RegularizeLight),
        Some(e) => (3 * target_tris, e as f32, meshopt::SimplifyOptions::ErrorAbsolute),
    };
    let mut result_error = input.run(&mut idx, &mut pos, &mut attr, count, err, opts);
    if max_error.is_none() {
        let n = target_tris;
        if idx.len() / 3 > n + n / 100 && !locked.iter().any(|&l| l) {
            // Topology stopped it: allow removing small disconnected parts
            // (never with locks: a part may be a piece of a seam).
            result_error = input.run(&mut idx, &mut pos, &mut attr, count, err, opts | meshopt::SimplifyOptions::Prune);
        }
    }
    let attr0 = &input.attr;
    // Optimal placement may step a hair outside (a convex part's chords);
    // results stay inside the input's box and attribute ranges.
    let mut lo = vec![f32::MAX; na];
    let mut hi = vec![f32::MIN; na];
    for t in &mesh.triangles {
        for &v in t {
            let v = v as usize;
            for k in 0..na {
                lo[k] = lo[k].min(attr0[v * na + k]);
                hi[k] = hi[k].max(attr0[v * na + k]);
            }
        }
    }
    // Updated uvs can overshoot their island (a far or tiled atlas): each
    // stays in the uv box of its chart (the input piece its index joins).
    let chart_box = attrs.uv().then(|| chart_uv_boxes(mesh));
    let mut verts = mesh.vertices.clone();
    for (i, v) in verts.iter_mut().enumerate() {
        if locked.get(i).copied().unwrap_or(false) {
            continue;
        }
        v.pos = std::array::from_fn(|k| (c[k] + pos[i][k] as f64).clamp(bb.min[k], bb.max[k]));
        for k in 0..na {
            attr[i * na + k] = attr[i * na + k].clamp(lo[k], hi[k]);
        }
        let a = &attr[i * na..(i + 1) * na];
        let mut k = 0;
        if attrs.normal() {
            let n = glam::Vec3::from_slice(&a[0..3]);
            v.normal = if n.length_squared() > 0.0 { n.normalize().to_array() } else { v.normal };
            k = 3;
        }
        if attrs.color() {
            for ch in 0..3 {
                v.color[ch] = (a[k + ch].clamp(0.0, 1.0) * 255.0).round() as u8;
            }
            k += 3;
            if attrs.alpha() {
                v.color[3] = (a[k].clamp(0.0, 1.0) * 255.0).round() as u8;
                k += 1;
            }
        }
        if attrs.uv() {
            v.uv = [a[k], a[k + 1]];
            if let Some((chart, boxes)) = &chart_box {
                let (lo, hi) = boxes[chart[i] as usize];
                v.uv = [v.uv[0].clamp(lo[0], hi[0]), v.uv[1].clamp(lo[1], hi[1])];
            }
        }
    }
    let triangles = idx.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect();
    Collapsed { vertices: verts, triangles, error: result_error as f64 }
}

/// What meshoptimizer's collapse takes of a mesh, made once for several
/// runs (a sampled node's error curve collapses it seven times): positions
/// about the box centre in f32, weighted attributes, locks, the index.
struct Input {
    bb: Aabb,
    c: [f64; 3],
    pos: Vec<[f32; 3]>,
    weights: Vec<f32>,
    na: usize,
    attr: Vec<f32>,
    lock: Vec<meshopt::SimplifyVertex>,
    idx: Vec<u32>,
}

impl Input {
    fn new(mesh: &IndexedMesh, locked: &[bool], attrs: AttrSet) -> Input {
        let mut bb = Aabb::default();
        for t in &mesh.triangles {
            for &v in t {
                bb.add(mesh.vertices[v as usize].pos);
            }
        }
        let c = bb.center();
        let pos: Vec<[f32; 3]> = mesh.vertices.iter().map(|v| std::array::from_fn(|k| (v.pos[k] - c[k]) as f32)).collect();
        let mut weights: Vec<f32> = Vec::new();
        if attrs.normal() {
            weights.extend([NORMAL_WEIGHT; 3]);
        }
        if attrs.color() {
            weights.extend([COLOR_WEIGHT; 3]);
            if attrs.alpha() {
                weights.push(COLOR_WEIGHT);
            }
        }
        if attrs.uv() {
            weights.extend([UV_WEIGHT; 2]);
        }
        let na = weights.len();
        let mut attr: Vec<f32> = Vec::with_capacity(mesh.vertices.len() * na);
        for v in &mesh.vertices {
            if attrs.normal() {
                attr.extend(v.normal);
            }
            if attrs.color() {
                attr.extend(v.color[..3].iter().map(|&x| x as f32 / 255.0));
                if attrs.alpha() {
                    attr.push(v.color[3] as f32 / 255.0);
                }
            }
            if attrs.uv() {
                attr.extend(v.uv);
            }
        }
        let lock = locked.iter().map(|&l| if l { meshopt::SimplifyVertex::Lock } else { meshopt::SimplifyVertex::None }).collect();
        let idx = mesh.triangles.iter().flatten().copied().collect();
        Input { bb, c, pos, weights, na, attr, lock, idx }
    }

    /// One collapse of `idx` (truncated to what is left), `pos` and `attr`
    /// updated in place; gives meshoptimizer's result error.
    #[allow(clippy::too_many_arguments)]
    fn run(&self, idx: &mut Vec<u32>, pos: &mut [[f32; 3]], attr: &mut [f32], count: usize, err: f32, opts: meshopt::SimplifyOptions) -> f32 {
        let mut result_error = 0f32;
        let n = meshopt::simplify_with_update(idx, pos, attr, &self.weights, self.na * 4, Some(&self.lock), count, err, opts, Some(&mut result_error));
        idx.truncate(n);
        result_error
    }
}

/// A uv box: low and high corners.
type UvBox = ([f32; 2], [f32; 2]);

/// Each vertex's chart (a connected piece of the index) and each chart's
/// uv box (empty charts: unused vertices, a box of their own uv).
fn chart_uv_boxes(mesh: &IndexedMesh) -> (Vec<u32>, Vec<UvBox>) {
    let n = mesh.vertices.len();
    let chart = super::cluster::charts(mesh);
    let mut boxes = vec![([f32::MAX; 2], [f32::MIN; 2]); n];
    for (v, &c) in chart.iter().enumerate() {
        let (uv, b) = (mesh.vertices[v].uv, &mut boxes[c as usize]);
        b.0 = [b.0[0].min(uv[0]), b.0[1].min(uv[1])];
        b.1 = [b.1[0].max(uv[0]), b.1[1].max(uv[1])];
    }
    (chart, boxes)
}

/// Error curve of one sampled node: its triangles, and (error, triangles)
/// after collapsing to a few shares of them, errors absolute and made
/// non-decreasing (fewer triangles never cost less).
pub struct ErrorCurve {
    pub tris: u64,
    pub points: Vec<(f64, f64)>,
}

/// Shares of a sampled node's triangles its curve is measured at, as
/// multiples of the share the level keeps (1/`--level-ratio`; at the
/// default ratio 2: 0.7, 0.48, 0.27), at most [`CURVE_MAX_SHARE`]. Each
/// point is a collapse of the node, and the curves were a fifth to a
/// third of a collapse build. Between its points a curve follows a power
/// law ([`ErrorCurve::at`]): three points so interpolated put each level
/// nearer its share than five did linearly (Stanford dragon, the README's
/// 2 M sphere with uvs, normals and colours, a 500 K atlas scan: level
/// after level 0.45–0.50 of the one below against 0.44–0.50), for 7–11 %
/// less build time (`docs/build-costs.md`, "Collapse builds").
const CURVE_FACTORS: [f64; 3] = [1.4, 0.96, 0.54];
/// Largest share a curve point is measured at.
const CURVE_MAX_SHARE: f64 = 0.95;

impl ErrorCurve {
    /// Each point is [`collapse`] to an error limit of `f32::MAX` (only the
    /// count stops it), but the mesh is prepared once and only the count
    /// and error are kept: the output's vertices are not made.
    /// `share`: the share of its triangles the level keeps (the curve's
    /// points are around it, `CURVE_FACTORS`).
    pub fn of(mesh: &IndexedMesh, locked: &[bool], attrs: AttrSet, share: f64) -> ErrorCurve {
        let n = mesh.triangles.len();
        let mut points: Vec<(f64, f64)> = Vec::new();
        if n == 0 {
            points.resize(CURVE_FACTORS.len(), (0.0, 0.0));
            return ErrorCurve { tris: 0, points };
        }
        let input = Input::new(mesh, locked, attrs);
        let (mut pos, mut attr, mut idx) = (Vec::new(), Vec::new(), Vec::new());
        let mut worst = 0.0f64;
        for s in CURVE_FACTORS.map(|f| (f * share).min(CURVE_MAX_SHARE)) {
            pos.clone_from(&input.pos);
            attr.clone_from(&input.attr);
            idx.clone_from(&input.idx);
            let e = input.run(&mut idx, &mut pos, &mut attr, 3 * (s * n as f64).round() as usize, f32::MAX, meshopt::SimplifyOptions::ErrorAbsolute);
            worst = worst.max(e as f64);
            points.push((worst, (idx.len() / 3) as f64));
        }
        ErrorCurve { tris: n as u64, points }
    }

    /// Triangles left at error limit `e`: from the whole node at error 0
    /// linearly to the first point, then a power law between each two
    /// points (log triangles linear in log error: collapse's counts fall
    /// about as the inverse of the error, a convex curve whose chord
    /// overstated the triangles kept, so levels came out smaller than their
    /// share); no further than the last point.
    pub fn at(&self, e: f64) -> f64 {
        let mut prev = (0.0, self.tris as f64);
        for &(pe, pt) in &self.points {
            if e < pe {
                if prev.0 > 0.0 && prev.1 > 0.0 && pt > 0.0 {
                    // A power law between two measured points: log tris
                    // linear in log error.
                    let f = (e / prev.0).ln() / (pe / prev.0).ln();
                    return prev.1 * (pt / prev.1).powf(f);
                }
                let f = if pe > prev.0 { (e - prev.0) / (pe - prev.0) } else { 1.0 };
                return prev.1 + f * (pt - prev.1);
            }
            prev = (pe, pt.min(prev.1));
        }
        prev.1
    }
}

/// The error limit at which the sampled nodes keep `share` of their
/// triangles, and the share they keep there (bisection on the curves).
pub fn choose_limit(samples: &[ErrorCurve], share: f64) -> (f64, f64) {
    let total: f64 = samples.iter().map(|c| c.tris as f64).sum();
    if total == 0.0 {
        return (0.0, 1.0);
    }
    let kept = |e: f64| samples.iter().map(|c| c.at(e)).sum::<f64>() / total;
    let hi0 = samples.iter().flat_map(|c| c.points.last().map(|p| p.0)).fold(0.0, f64::max);
    if !(hi0 > 0.0 && hi0.is_finite()) || kept(hi0) > share {
        // The samples cannot reach the share: the largest error measured.
        return (hi0.max(0.0), kept(hi0.max(0.0)));
    }
    let (mut lo, mut hi) = (0.0, hi0);
    for _ in 0..60 {
        let m = 0.5 * (lo + hi);
        if kept(m) > share {
            lo = m;
        } else {
            hi = m;
        }
    }
    (hi, kept(hi))
}

/// `tris` less its folds: a triangle and one of opposite orientation on the
/// same three positions (edge collapse flattens a thin part — a small
/// torus's tube — into such pairs, as clustering does) are dropped
/// together, as [`super::cluster`] drops them: every edge's use count keeps
/// its parity, so no crack opens, and the zero-volume fins and the
/// non-manifold edges they bring go.
pub fn unfold(vertices: &[Vertex], tris: &[[u32; 3]]) -> Vec<[u32; 3]> {
    let mut weld = crate::geom::Welder::default();
    let images: Vec<[usize; 3]> = tris.iter().map(|t| t.map(|v| weld.id(vertices[v as usize].pos, |_| {}) as usize)).collect();
    let keep = super::cluster::unfold(&images);
    tris.iter().zip(keep).filter(|(_, k)| *k).map(|(t, _)| *t).collect()
}

/// `tris` over `vertices`, unreferenced vertices dropped; also gives, per
/// output vertex, the index it had.
pub fn compact(vertices: &[Vertex], tris: &[[u32; 3]]) -> (IndexedMesh, Vec<u32>) {
    let mut map = vec![u32::MAX; vertices.len()];
    let mut out = IndexedMesh::default();
    let mut from = Vec::new();
    for t in tris {
        let nt = t.map(|i| {
            let i = i as usize;
            if map[i] == u32::MAX {
                map[i] = out.vertices.len() as u32;
                out.vertices.push(vertices[i]);
                from.push(i as u32);
            }
            map[i]
        });
        out.triangles.push(nt);
    }
    (out, from)
}

/// The two-sided, vertex-sampled distance between a node's input and its
/// collapsed output (`from[o]`: the input vertex output vertex o is; a
/// locked one sits on both sides): the largest distance from a referenced
/// input vertex to the output surface and from an output vertex to the
/// input surface, exact (closest points through a BVH of each side), and
/// from the face samples next to the mesh's own open border
/// (`BorderFaces`: on a grid with one-cell holes the vertices alone let a
/// level-1 cut exceed its error by metro). Edge
/// collapse keeps no member lists, so the neighbourhood bound of
/// [`super::measure::node_error`] does not apply. An empty output has the
/// input's extent as its error. Also gives each side's farthest points, as
/// [`super::measure::node_error`] does, for
/// `remeasure_far`.
pub fn collapse_error(input: &IndexedMesh, locked: &[bool], output: &IndexedMesh, from: &[u32]) -> super::measure::NodeError {
    use super::measure::{Farthest, NodeError};
    use crate::geom::{Bvh, Mesh};
    if input.triangles.is_empty() {
        return NodeError::default();
    }
    let mut used = vec![false; input.vertices.len()];
    let mut bbox = Aabb::EMPTY;
    for t in &input.triangles {
        for &v in t {
            used[v as usize] = true;
            bbox.add(input.vertices[v as usize].pos);
        }
    }
    if output.triangles.is_empty() {
        let e = bbox.diagonal();
        return NodeError { error: e, base: e, ..Default::default() };
    }
    let is_locked = |v: usize| locked.get(v).copied().unwrap_or(false);
    let mut on_output = vec![false; input.vertices.len()];
    for &f in from {
        on_output[f as usize] = is_locked(f as usize);
    }
    // Faces next to the mesh's own open border too (as node_error samples
    // them, [`super::measure::BorderFaces`]): the free input vertices whose
    // fan does not close, and the output vertices that are one.
    let mut border = super::measure::open_fans(input.vertices.len(), &input.triangles);
    for (v, b) in border.iter_mut().enumerate() {
        *b &= !is_locked(v);
    }
    let touched: Vec<bool> = from.iter().map(|&f| border[f as usize]).collect();
    let samples = super::measure::BorderFaces::new(input, output, &border, &touched);
    // One side's measured points (the vertices `keep` selects, then its
    // samples, numbered after them) against the other side's surface
    // (its BVH dropped before the other is built): the largest distances
    // (squared) kept for `remeasure_far`, as node_error keeps them, and
    // `rest` the largest of the others.
    let farthest = |side: &IndexedMesh, keep: &dyn Fn(usize) -> bool, samples: &[([f64; 3], u32)], other: &IndexedMesh| {
        let bvh = Bvh::new(&Mesh::from_vertices(&other.vertices, other.triangles.clone()));
        let n = side.vertices.len();
        let points = side.vertices.iter().enumerate().filter(|&(v, _)| keep(v)).map(|(v, x)| (v, x.pos));
        let mut top = Farthest::default();
        // A point nearer than `moot_below` cannot change `top`: its search
        // ends at the first triangle that shows it (mostly the previous
        // point's, the hint), and it is not pushed. The same `top` as
        // pushing every exact distance.
        let mut hint = u32::MAX;
        for (id, p) in points.chain(samples.iter().enumerate().map(|(k, s)| (n + k, s.0))) {
            let moot = top.moot_below();
            if let Some((d2, slot)) = bvh.nearest_unless_below(p, hint, moot) {
                hint = slot;
                if d2 >= moot {
                    top.push(d2, id as u32);
                }
            }
        }
        top
    };
    let top = farthest(input, &|v| used[v] && !on_output[v], &samples.input, output);
    let top_r = farthest(output, &|o| !is_locked(from[o] as usize), &samples.output, input);
    let error = top.max().max(top_r.max()).sqrt();
    let base = top.rest.max(top_r.rest).sqrt();
    let far = top.points(|v| samples.input_point(input, v));
    let far_reps = top_r.points(|o| samples.output_point(output, o));
    NodeError { error, base, far, far_reps }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gen::{GenOptions, Generator, Shape};

    /// RMS over the input's vertices of their distance to the output
    /// (brute force: small meshes only).
    fn vertex_rms(input: &IndexedMesh, v: &[Vertex], tris: &[[u32; 3]]) -> f64 {
        use crate::geom::tri::closest_point_triangle;
        let picked: Vec<&Vertex> = input.vertices.iter().step_by(37).collect();
        let s: f64 = picked
            .iter()
            .map(|p| {
                tris.iter()
                    .map(|t| {
                        let q = closest_point_triangle(p.pos, v[t[0] as usize].pos, v[t[1] as usize].pos, v[t[2] as usize].pos);
                        (0..3).map(|k| (q[k] - p.pos[k]).powi(2)).sum::<f64>()
                    })
                    .fold(f64::INFINITY, f64::min)
            })
            .sum();
        (s / picked.len() as f64).sqrt()
    }

    /// To a count, the collapse is regularised: on a smooth sphere the
    /// input lies closer to its output than to the unregularised
    /// collapse's (error-limited mode, the same count).
    #[test]
    fn collapse_to_a_count_is_regularised() {
        let (vs, fs) = Generator::new(&GenOptions { shape: Shape::Sphere, tris: 200_000, ..Default::default() }).mesh();
        let mesh = IndexedMesh { vertices: vs, triangles: fs };
        let locked = vec![false; mesh.vertices.len()];
        let reg = collapse(&mesh, &locked, AttrSet::POSITION_ONLY, 20_000, None);
        let plain = collapse(&mesh, &locked, AttrSet::POSITION_ONLY, 20_000, Some(f32::MAX as f64));
        for out in [&reg, &plain] {
            assert!(out.triangles.len().abs_diff(20_000) <= 200, "{}", out.triangles.len());
        }
        let (e_reg, e_plain) = (vertex_rms(&mesh, &reg.vertices, &reg.triangles), vertex_rms(&mesh, &plain.vertices, &plain.triangles));
        eprintln!("input vertices to output, RMS: regularised {e_reg:.3e}, plain {e_plain:.3e}");
        assert!(e_reg < 0.8 * e_plain, "regularised {e_reg:.3e} against {e_plain:.3e}");
    }

    /// Between two measured points a curve follows a power law, exactly
    /// where the counts do (a chord would overstate them in between).
    #[test]
    fn curves_interpolate_power_laws_exactly() {
        let law = |e: f64| 1000.0 / e;
        let c = ErrorCurve { tris: 10_000, points: [0.2, 0.5, 1.0].iter().map(|&e| (e, law(e))).collect() };
        for e in [0.25, 0.3, 0.45, 0.7, 0.9] {
            assert!((c.at(e) - law(e)).abs() < 1e-9 * law(e), "at {e}: {} against {}", c.at(e), law(e));
        }
        // From the whole node at error 0 to the first point: linear.
        assert!((c.at(0.1) - 7500.0).abs() < 1e-9);
        assert_eq!(c.at(2.0), law(1.0));
        // A point that kept nothing, then one that kept some (the counts
        // are not forced down between points): a count, never NaN.
        let c = ErrorCurve { tris: 100, points: vec![(0.1, 0.0), (0.2, 10.0)] };
        assert!(c.at(0.15).is_finite(), "{}", c.at(0.15));
    }

    /// A curve's points bracket the share its level keeps, whatever the
    /// ratio, so the limit is interpolated, not taken past the last point;
    /// and the limit it gives keeps about that share of the node.
    #[test]
    fn curves_bracket_the_level_share() {
        let (vs, fs) = Generator::new(&GenOptions { shape: Shape::Sphere, tris: 20_000, ..Default::default() }).mesh();
        let mesh = IndexedMesh { vertices: vs, triangles: fs };
        let locked = vec![false; mesh.vertices.len()];
        let n = mesh.triangles.len() as f64;
        for share in [0.5, 0.25, 0.125, 0.8] {
            let c = ErrorCurve::of(&mesh, &locked, AttrSet::POSITION_ONLY, share);
            let (first, last) = (c.points[0].1 / n, c.points.last().unwrap().1 / n);
            assert!(first > share && last < share, "share {share}: points from {first:.3} to {last:.3}");
            assert!(first <= CURVE_MAX_SHARE + 0.01, "share {share}: first point at {first:.3}");
            let (limit, predicted) = choose_limit(std::slice::from_ref(&c), share);
            assert!((predicted - share).abs() < 0.01, "share {share}: predicted {predicted:.3}");
            let kept = collapse(&mesh, &locked, AttrSet::POSITION_ONLY, 0, Some(limit)).triangles.len() as f64 / n;
            assert!((kept - share).abs() < 0.25 * share, "share {share}: the limit kept {kept:.3}");
        }
    }
}

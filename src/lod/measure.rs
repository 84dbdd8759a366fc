//! A node's measured simplification error: how far its simplified mesh
//! lies from its input, both ways, and the far points worth measuring
//! again once the neighbours are known.
//!
//! Takes: a node's input mesh and its simplified output — with each input
//! vertex's image and each representative's members (clustering,
//! [`node_error`]), or each output vertex's source (edge collapse,
//! [`super::collapse::collapse_error`]). Gives: [`NodeError`] (the error,
//! what remains without its few farthest points, and those points), and
//! `remeasure_far`, which measures those points again against the whole
//! next level, or the level itself, where they stand out.
//!
//! Samples: the input's vertices against the output, the output's
//! vertices against the input, and faces next to the mesh's own open
//! border (`BorderFaces`) and over its holes. Hand-written searches over each side's vertex
//! fans rather than a BVH per node: the neighbourhoods are known from the
//! clustering and most searches end at their first exact distance (costs
//! in `docs/build-costs.md`).

use super::chunks::ChunkFile;
use super::cluster::Prio;
use super::{cluster, tri_centroid, vertex_triangles, LeafStats};
use crate::error::Result;
use crate::mesh::Aabb;
use crate::mesh::IndexedMesh;
use rayon::prelude::*;
use std::collections::BinaryHeap;

/// The node's simplification error: the largest distance from an input
/// vertex to the output surface near it (the output triangles around the
/// images of the vertex and of its neighbours), and from a representative
/// to the input surface near it (the input triangles around its members
/// and their neighbours): upper bounds of the exact distances, tight on
/// the surfaces tried (a test compares them with exact BVH distances),
/// with no index over either mesh. Kept vertices are at distance 0.
///
/// Next to the mesh's own open border, faces are sampled too
/// (`BorderFaces`): there clustering can fill a small hole, or move its
/// rim, while every vertex stays on the other surface.
///
/// Also gives the input points (vertices or face samples) that set the
/// error (those farther than a quarter of it from the output), so the
/// level can measure them again against the whole next level
/// ([`NodeError`], `remeasure_far`).
pub fn node_error(input: &IndexedMesh, out: &cluster::NodeOut) -> NodeError {
    let output = &out.mesh;
    if input.triangles.is_empty() {
        return NodeError::default();
    }
    let image = images(input, out);
    // Made once with level 0's border planes, else here.
    let made;
    let (in_first, in_around) = match &out.in_fans {
        Some(f) if f.0.len() == input.vertices.len() + 1 && f.1.len() == 3 * input.triangles.len() => (&f.0, &f.1),
        _ => {
            made = vertex_triangles(input.vertices.len(), &input.triangles);
            (&made.0, &made.1)
        }
    };
    let border = BorderFaces::of_clusters(input, out, &image, (in_first, in_around));
    let Some(top) = input_side(input, out, &image, (in_first, in_around), &border) else {
        // Everything collapsed: the input's extent is the error.
        let mut bbox = Aabb::EMPTY;
        for v in (0..input.vertices.len()).filter(|&v| in_first[v + 1] > in_first[v]) {
            bbox.add(input.vertices[v].pos);
        }
        let e = bbox.diagonal();
        return NodeError { error: e, base: e, ..Default::default() };
    };
    let in_d2 = top.max();
    let in_fans = InFans { input, first: in_first, around: in_around };
    let (r2, rest_r, top_r) = reps_side(&in_fans, out, &border, top.rest);
    // The far points: those with the largest bounds; every other one is
    // within `rest` (input side) or `rest_r` (representatives).
    let base = top.rest.max(rest_r).sqrt();
    let far = top.points(|v| border.input_point(input, v));
    let far_reps = top_r.map_or_else(Vec::new, |t| t.points(|o| border.output_point(output, o)));
    NodeError { error: in_d2.max(r2).sqrt(), base, far, far_reps }
}

/// Per input vertex: the output vertex it became (kept, or a member of a
/// representative); `u32::MAX` when it is in no cluster.
fn images(input: &IndexedMesh, out: &cluster::NodeOut) -> Vec<u32> {
    let output = &out.mesh;
    let nv = input.vertices.len();
    let mut image = vec![u32::MAX; nv];
    for (o, &k) in out.kept_from.iter().enumerate() {
        if k != u32::MAX {
            image[k as usize] = o as u32;
        }
    }
    for o in 0..output.vertices.len() {
        for &m in &out.members[out.members_first[o] as usize..out.members_first[o + 1] as usize] {
            image[m as usize] = o as u32;
        }
    }
    image
}

/// The input side of [`node_error`]: input vertices (then samples of the
/// faces next to the border) to the output triangles around their images,
/// their largest bounds kept. `None` when the output has no triangle.
fn input_side(input: &IndexedMesh, out: &cluster::NodeOut, image: &[u32], (in_first, in_around): (&[u32], &[u32]), border: &BorderFaces) -> Option<Farthest> {
    use crate::geom::{Bvh, Mesh};
    let output = &out.mesh;
    if output.triangles.is_empty() {
        return None;
    }
    let nv = input.vertices.len();
    let (out_first, out_around) = vertex_triangles(output.vertices.len(), &output.triangles);
    let fans = OutFans::new(output, image, &out_first, &out_around);
    // The vertex (or sample) whose search last met each output triangle
    // (each is measured once per vertex, though it lies in up to three fans).
    let mut met = vec![u32::MAX; output.triangles.len()];
    let mut whole: Option<Bvh> = None;
    // The MAX_FAR largest bounds (squared) of input vertices, smallest on
    // top: a vertex's search stops once its bound falls to the smallest of
    // them (it can no longer enter), so every bound kept is a full one, and
    // `rest` (the largest of all others) is what the error would be without
    // them.
    let mut top = Farthest::default();
    // The exact distance to the whole output, through a BVH built once: for
    // a point whose images lost every triangle (their clusters folded away).
    let mut exact = |p: [f64; 3]| -> Option<f64> {
        if output.triangles.is_empty() {
            return None;
        }
        let bvh = whole.get_or_insert_with(|| Bvh::new(&Mesh::from_vertices(&output.vertices, output.triangles.clone())));
        bvh.closest(p).map(|c| c.dist2)
    };
    // Input vertices to the output triangles around their image (an upper
    // bound of the distance to the whole output surface).
    for v in 0..nv {
        if in_first[v + 1] == in_first[v] {
            continue;
        }
        let p = input.vertices[v].pos;
        let o = image[v] as usize;
        if o < output.vertices.len() && out.kept_from[o] == v as u32 {
            continue; // kept as it is: on the output
        }
        // The output triangles around the images of v and of its neighbours
        // cover v's surroundings.
        let around = in_around[in_first[v] as usize..in_first[v + 1] as usize].iter().flat_map(|&t| input.triangles[t as usize]);
        let best = fans.nearest(p, std::iter::once(v as u32).chain(around), &mut met, v as u32, top.floor());
        if let Some(d) = if best.is_finite() { Some(best) } else { exact(p) } {
            top.push(d, v as u32);
        }
    }
    // Samples of the input faces next to the border, searched like their
    // corners (numbered after the vertices).
    for (k, &(p, t)) in border.input.iter().enumerate() {
        let t = input.triangles[t as usize];
        let around = t
            .iter()
            .flat_map(|&w| in_around[in_first[w as usize] as usize..in_first[w as usize + 1] as usize].iter())
            .flat_map(|&x| input.triangles[x as usize]);
        let best = fans.nearest(p, t.into_iter().chain(around), &mut met, (nv + k) as u32, top.floor());
        if let Some(d) = if best.is_finite() { Some(best) } else { exact(p) } {
            top.push(d, (nv + k) as u32);
        }
    }
    Some(top)
}

/// The representatives' side of [`node_error`], given the input side's
/// `rest`: the largest bound (squared), what remains without the far
/// representatives, and those (when a second pass looked for them).
fn reps_side(in_fans: &InFans, out: &cluster::NodeOut, border: &BorderFaces, rest: f64) -> (f64, f64, Option<Farthest>) {
    let (input, output) = (in_fans.input, &out.mesh);
    // The representatives' side. A first pass finds its maximum, each
    // search stopping once it cannot raise it (cheap); only when that
    // maximum stands out against the input side's (over 4× the distance
    // of its 65th largest) is a second pass run for the representatives'
    // own largest bounds (a representative can sit over a neighbour's
    // surface too), each search stopping at the smallest of those.
    // The representative (or sample) whose search last met each input triangle.
    let mut met_in = vec![u32::MAX; input.triangles.len()];
    let no = output.vertices.len();
    let members = |o: usize| -> &[u32] {
        match out.kept_from[o] {
            u32::MAX => &out.members[out.members_first[o] as usize..out.members_first[o + 1] as usize],
            _ => std::slice::from_ref(&out.kept_from[o]),
        }
    };
    let mut reps_pass = |top_r: &mut Option<Farthest>| -> f64 {
        met_in.fill(u32::MAX);
        let mut r2 = 0.0f64;
        let push = |best: f64, id: usize, r2: &mut f64, top_r: &mut Option<Farthest>| {
            if best.is_finite() {
                *r2 = r2.max(best);
                if let Some(t) = top_r.as_mut() {
                    t.push(best, id as u32);
                }
            }
        };
        for o in 0..no {
            let ms = &out.members[out.members_first[o] as usize..out.members_first[o + 1] as usize];
            if ms.is_empty() {
                continue;
            }
            // The input triangles around the members and their neighbours.
            let low = top_r.as_ref().map_or(r2, Farthest::floor);
            let best = in_fans.nearest(output.vertices[o].pos, &[ms], &mut met_in, o as u32, low);
            push(best, o, &mut r2, top_r);
        }
        // Samples of the output faces next to the border (numbered after
        // the output vertices), against the input around their corners'
        // members.
        for (k, &(p, t)) in border.output.iter().enumerate() {
            let t = output.triangles[t as usize];
            let low = top_r.as_ref().map_or(r2, Farthest::floor);
            // The corners' member nearest to p first: the search mostly
            // stops in its fan.
            let groups = t.map(|o| members(o as usize));
            let near = groups
                .iter()
                .flat_map(|g| g.iter())
                .min_by(|&&a, &&b| crate::geom::dist2(p, input.vertices[a as usize].pos).total_cmp(&crate::geom::dist2(p, input.vertices[b as usize].pos)));
            let first = near.map_or(&[][..], std::slice::from_ref);
            let best = in_fans.nearest(p, &[first, groups[0], groups[1], groups[2]], &mut met_in, (no + k) as u32, low);
            push(best, no + k, &mut r2, top_r);
        }
        r2
    };
    let mut top_r = None;
    let r2 = reps_pass(&mut top_r);
    let rest_r = if r2 > 16.0 * rest {
        let mut t = Some(Farthest::default());
        reps_pass(&mut t);
        top_r = t;
        top_r.as_ref().map_or(0.0, |t| t.rest)
    } else {
        r2
    };
    (r2, rest_r, top_r)
}

/// The output triangles around each output vertex, with each triangle's
/// centroid and bounding-sphere radius about it: |p − c| − r is a lower
/// bound of p's distance to the triangle, so a triangle that cannot beat
/// the best distance so far is skipped.
struct OutFans<'a> {
    output: &'a IndexedMesh,
    image: &'a [u32],
    first: &'a [u32],
    around: &'a [u32],
    sphere: Vec<([f64; 3], f64)>,
}

impl<'a> OutFans<'a> {
    fn new(output: &'a IndexedMesh, image: &'a [u32], first: &'a [u32], around: &'a [u32]) -> OutFans<'a> {
        let sphere = output
            .triangles
            .iter()
            .map(|t| {
                let c = tri_centroid(output, t);
                let r2 = t.iter().map(|&x| crate::geom::dist2(c, output.vertices[x as usize].pos)).fold(0.0, f64::max);
                // A hair wider than computed: rounding must not skip a triangle.
                (c, r2.sqrt() * (1.0 + 1e-9))
            })
            .collect();
        OutFans { output, image, first, around, sphere }
    }

    /// The smallest squared distance from `p` to the output triangles
    /// around the images of the input vertices `seeds` (infinite when they
    /// have none), each triangle measured once per `stamp` (`met`); the
    /// search stops once it is at most `low` (it cannot be among the
    /// largest).
    fn nearest(&self, p: [f64; 3], seeds: impl Iterator<Item = u32>, met: &mut [u32], stamp: u32, low: f64) -> f64 {
        use crate::geom::dist2;
        let output = self.output;
        let mut best = f64::INFINITY;
        let mut best_root = f64::INFINITY;
        // Neighbours come once per triangle around a seed and often share
        // an image: each image's fan is met once.
        let mut seen = [u32::MAX; 32];
        let mut n_seen = 0;
        for w in seeds {
            let o = self.image[w as usize] as usize;
            if o >= output.vertices.len() || seen[..n_seen].contains(&(o as u32)) {
                continue;
            }
            if n_seen < seen.len() {
                seen[n_seen] = o as u32;
                n_seen += 1;
            }
            let fan = &self.around[self.first[o] as usize..self.first[o + 1] as usize];
            // The triangle whose centroid is nearest first: usually the one
            // under p, so the search mostly stops after one distance.
            let near = fan
                .iter()
                .enumerate()
                .filter(|&(_, &ti)| met[ti as usize] != stamp)
                .map(|(k, &ti)| (dist2(p, self.sphere[ti as usize].0), k))
                .min_by(|a, b| a.0.total_cmp(&b.0))
                .map_or(0, |m| m.1);
            for k in std::iter::once(near).chain((0..fan.len()).filter(|&k| k != near)) {
                let ti = fan[k] as usize;
                if met[ti] == stamp {
                    continue;
                }
                met[ti] = stamp;
                let (c, r) = self.sphere[ti];
                let reach = (r + best_root) * (1.0 + 1e-9);
                if dist2(p, c) > reach * reach {
                    continue; // cannot come nearer than the best so far
                }
                let d = tri_dist2(p, output.triangles[ti].map(|x| output.vertices[x as usize].pos));
                if d < best {
                    best = d;
                    best_root = d.sqrt();
                }
                if best <= low {
                    return best; // cannot be among the largest
                }
            }
        }
        best
    }
}

/// The input triangles around each input vertex.
struct InFans<'a> {
    input: &'a IndexedMesh,
    first: &'a [u32],
    around: &'a [u32],
}

impl InFans<'_> {
    /// The smallest squared distance from `p` to the input triangles
    /// around the vertices of `groups` (ring 0) and then around their
    /// neighbours (ring 1), each triangle measured once per `stamp`
    /// (`met`); the search stops once it is at most `low`.
    fn nearest(&self, p: [f64; 3], groups: &[&[u32]], met: &mut [u32], stamp: u32, low: f64) -> f64 {
        let input = self.input;
        let fan = |v: u32| &self.around[self.first[v as usize] as usize..self.first[v as usize + 1] as usize];
        let mut best = f64::INFINITY;
        for ring in 0..2 {
            for ms in groups {
                for &m in *ms {
                    // Ring 0: the member itself; ring 1: its neighbours.
                    let (own, around) = if ring == 0 { (Some(m), &[][..]) } else { (None, fan(m)) };
                    for w in own.into_iter().chain(around.iter().flat_map(|&t| input.triangles[t as usize])) {
                        for &ti in fan(w) {
                            if std::mem::replace(&mut met[ti as usize], stamp) == stamp {
                                continue; // met before (rings overlap)
                            }
                            best = best.min(tri_dist2(p, input.triangles[ti as usize].map(|x| input.vertices[x as usize].pos)));
                            if best <= low {
                                return best; // cannot raise the maximum, or be among the largest
                            }
                        }
                    }
                }
            }
        }
        best
    }
}

/// Squared distance from `p` to the triangle `c`.
#[inline]
fn tri_dist2(p: [f64; 3], c: [[f64; 3]; 3]) -> f64 {
    crate::geom::dist2(p, crate::geom::closest_point_triangle(p, c[0], c[1], c[2]))
}

/// Face samples of a node's simplification next to the mesh's own open
/// border, each with the triangle it lies on.
///
/// Why: vertex samples miss what clustering does to small holes (a range
/// scan's dropouts). Where a hole is about a cluster wide, its rim's
/// vertices merge and the output's triangles can span it (a point over the
/// hole, half its width from the input) or leave an input face beside it
/// uncovered, with every vertex still on the other surface. On a grid
/// with one-cell holes (`tests/it/lod.rs`,
/// `cuts_over_small_holes_stay_within_their_error`) vertices alone let a
/// cut at `--max-error` E exceed E by metro; with these samples every cut
/// from level 2 on is within E (`docs/levels-of-detail.md`, "Small holes").
///
/// Which faces: the border vertices are the free input vertices whose fan
/// does not close ([`open_fans`]; a node's seams are locked, so they are
/// not border). Their images are the output vertices that can change the
/// topology; samples go on the output triangles at those images and on
/// the input triangles at border vertices. Elsewhere the input surface is
/// closed around every cluster and corners suffice. On a closed input
/// this costs one pass over the triangles.
///
/// Where: each such triangle's edge midpoints and centroid
/// ([`crate::geom::face_samples`]); lattices of up to 8 steps a side on
/// the output triangles found no more on that grid. On a closed input this
/// costs nothing (no border); costs in `docs/build-costs.md`.
pub(crate) struct BorderFaces {
    pub input: Vec<([f64; 3], u32)>,
    pub output: Vec<([f64; 3], u32)>,
}

impl BorderFaces {
    /// A clustered node's: `image` maps each input vertex to its output
    /// vertex (kept, or the representative of its cluster).
    fn of_clusters(input: &IndexedMesh, out: &cluster::NodeOut, image: &[u32], fans: (&[u32], &[u32])) -> BorderFaces {
        let no = out.mesh.vertices.len();
        let open = open_fans(input.vertices.len(), &input.triangles);
        let mut border = open.clone();
        let mut touched = vec![false; no];
        for (v, b) in border.iter_mut().enumerate() {
            let o = image[v] as usize;
            if *b && o < no && out.kept_from[o] != v as u32 {
                touched[o] = true;
            } else {
                *b = false; // kept (locked): a seam, not a border
            }
        }
        let mut f = Self::new(input, &out.mesh, &border, &touched);
        f.output.extend(hole_centres(input, out, image, fans, &open, &border));
        f
    }

    /// Samples on the input triangles at a `border` vertex (free input
    /// vertices on the mesh's open border) and on the output triangles at
    /// a `touched` vertex (output vertices that stand for one).
    pub(crate) fn new(input: &IndexedMesh, output: &IndexedMesh, border: &[bool], touched: &[bool]) -> BorderFaces {
        let mut f = BorderFaces { input: Vec::new(), output: Vec::new() };
        if !border.contains(&true) && !touched.contains(&true) {
            return f;
        }
        let samples = |m: &IndexedMesh, at: &[bool], out: &mut Vec<([f64; 3], u32)>| {
            for (ti, t) in m.triangles.iter().enumerate() {
                if t.iter().any(|&v| at[v as usize]) {
                    let c = t.map(|v| m.vertices[v as usize].pos);
                    out.extend(crate::geom::face_samples(c).map(|p| (p, ti as u32)));
                }
            }
        };
        samples(input, border, &mut f.input);
        samples(output, touched, &mut f.output);
        f
    }

    /// Input point `id` (as numbered for [`Farthest`]): a vertex of
    /// `input`, or input sample `id − input.vertices.len()`.
    pub(crate) fn input_point(&self, input: &IndexedMesh, id: u32) -> [f64; 3] {
        point(&input.vertices, &self.input, id)
    }

    /// Output point `id`: a vertex of `output`, or output sample
    /// `id − output.vertices.len()`.
    pub(crate) fn output_point(&self, output: &IndexedMesh, id: u32) -> [f64; 3] {
        point(&output.vertices, &self.output, id)
    }
}

/// Samples of the output over the input's holes: per piece of the input's
/// open border (vertices joined by open edges) with a free vertex on it,
/// the output point nearest the piece's centroid, on the output triangles
/// around the piece's images. A cluster can span a small hole with one
/// triangle whose corners and [`crate::geom::face_samples`] all lie near
/// the rim while the point over the hole's middle is half the hole's width
/// from the input (a 120² grid with one-cell holes: a cut measured 1.45×
/// its error by metro before these samples). Each sample lies on the
/// output, so it can raise the error only towards the exact distance.
fn hole_centres(
    input: &IndexedMesh,
    out: &cluster::NodeOut,
    image: &[u32],
    (first, around): (&[u32], &[u32]),
    open: &[bool],
    free: &[bool],
) -> Vec<([f64; 3], u32)> {
    use crate::geom::tri::closest_point_triangle;
    let output = &out.mesh;
    let nv = input.vertices.len();
    if !free.contains(&true) || output.triangles.is_empty() {
        return Vec::new();
    }
    // Border vertices joined by open edges (both ends of one are on the
    // border, so its smaller end is among them).
    let mut parent: Vec<u32> = (0..nv as u32).collect();
    for (a, b, _) in cluster::open_edges(input, (first, around), (0..nv as u32).filter(|&v| open[v as usize])) {
        if open[b as usize] {
            cluster::union(&mut parent, a, b);
        }
    }
    // Per piece with a free vertex: its centroid and its images.
    let mut piece_of = vec![u32::MAX; nv];
    let mut sums: Vec<([f64; 3], f64)> = Vec::new();
    for v in (0..nv).filter(|&v| open[v]) {
        let r = cluster::find_root(&mut parent, v as u32) as usize;
        if piece_of[r] == u32::MAX {
            piece_of[r] = sums.len() as u32;
            sums.push(([0.0; 3], 0.0));
        }
        let k = piece_of[r] as usize;
        piece_of[v] = piece_of[r];
        let p = input.vertices[v].pos;
        for (s, x) in sums[k].0.iter_mut().zip(p) {
            *s += x;
        }
        sums[k].1 += 1.0;
    }
    let mut has_free = vec![false; sums.len()];
    for v in (0..nv).filter(|&v| free[v]) {
        has_free[piece_of[v] as usize] = true;
    }
    let centre: Vec<[f64; 3]> = sums.iter().map(|(s, n)| s.map(|x| x / n)).collect();
    // The pieces each output vertex stands for (most stand for none).
    let mut pieces_of: std::collections::HashMap<u32, Vec<u32>> = std::collections::HashMap::new();
    for v in (0..nv).filter(|&v| open[v] && has_free[piece_of[v] as usize]) {
        let o = image[v];
        if (o as usize) < output.vertices.len() {
            let e = pieces_of.entry(o).or_default();
            if !e.contains(&piece_of[v]) {
                e.push(piece_of[v]);
            }
        }
    }
    let mut best: Vec<(f64, [f64; 3], u32)> = vec![(f64::INFINITY, [0.0; 3], u32::MAX); sums.len()];
    for (ti, t) in output.triangles.iter().enumerate() {
        let c = t.map(|o| output.vertices[o as usize].pos);
        for o in t {
            for &k in pieces_of.get(o).map_or(&[][..], |v| &v[..]) {
                let q = closest_point_triangle(centre[k as usize], c[0], c[1], c[2]);
                let d = crate::geom::dist2(q, centre[k as usize]);
                if d < best[k as usize].0 {
                    best[k as usize] = (d, q, ti as u32);
                }
            }
        }
    }
    best.into_iter().filter(|b| b.2 != u32::MAX).map(|(_, q, t)| (q, t)).collect()
}

/// Point `id` of a side: its vertex, or the sample numbered after them.
fn point(vertices: &[crate::mesh::Vertex], samples: &[([f64; 3], u32)], id: u32) -> [f64; 3] {
    match vertices.get(id as usize) {
        Some(v) => v.pos,
        None => samples[id as usize - vertices.len()].0,
    }
}

/// Vertices whose oriented fan does not close: per vertex, the sum over
/// its triangles of hash(next corner) − hash(previous corner) (wrapping),
/// which cancels around a closed, consistently oriented fan (also one
/// repeated, or two fans sharing the vertex) and not along an open border.
/// Inconsistent orientation reads as open: more samples, never fewer.
pub(crate) fn open_fans(nv: usize, tris: &[[u32; 3]]) -> Vec<bool> {
    use crate::geom::mix64;
    let mut s = vec![0u64; nv];
    for t in tris {
        let h = t.map(|v| mix64(v as u64));
        for c in 0..3 {
            let a = t[c] as usize;
            s[a] = s[a].wrapping_add(h[(c + 1) % 3]).wrapping_sub(h[(c + 2) % 3]);
        }
    }
    s.into_iter().map(|x| x != 0).collect()
}

/// The [`MAX_FAR`] largest bounds (squared) seen, with the point each
/// belongs to, smallest on top; `rest` is the largest of all the others.
#[derive(Default)]
pub(super) struct Farthest {
    top: BinaryHeap<std::cmp::Reverse<(Prio, u32)>>,
    pub rest: f64,
}

impl Farthest {
    /// Bound `b` of point `v` (points come in increasing order).
    pub fn push(&mut self, b: f64, v: u32) {
        if self.top.len() >= MAX_FAR && self.top.peek().is_some_and(|r| b.total_cmp(&r.0 .0 .0).is_lt()) {
            // It would be popped right away (indices only grow, so ties go in).
            self.rest = self.rest.max(b);
            return;
        }
        self.top.push(std::cmp::Reverse((Prio(b, 0), v)));
        if self.top.len() > MAX_FAR {
            if let Some(r) = self.top.pop() {
                self.rest = self.rest.max(r.0 .0 .0);
            }
        }
    }

    /// A bound below this changes nothing pushed (it would join `rest`,
    /// already larger): `rest` once `MAX_FAR` are kept, else none.
    pub fn moot_below(&self) -> f64 {
        if self.top.len() < MAX_FAR {
            f64::NEG_INFINITY
        } else {
            self.rest
        }
    }

    /// What a bound must exceed to be kept (0 until `MAX_FAR` are).
    pub fn floor(&self) -> f64 {
        if self.top.len() < MAX_FAR {
            0.0
        } else {
            self.top.peek().map_or(0.0, |r| r.0 .0 .0)
        }
    }

    /// The largest bound seen.
    pub fn max(&self) -> f64 {
        self.top.iter().map(|r| r.0 .0 .0).fold(self.rest, f64::max)
    }

    /// The kept points (through `pos`) with their distances.
    pub fn points(self, pos: impl Fn(u32) -> [f64; 3]) -> Vec<([f64; 3], f64)> {
        self.top.into_iter().map(|r| (pos(r.0 .1), r.0 .0 .0.sqrt())).collect()
    }
}

/// Far points a node keeps for [`remeasure_far`]: its input vertices with
/// the largest distances to its output.
const MAX_FAR: usize = 64;

/// A level's simplification errors (`errors`, one per node of the level)
/// whose far points ([`NodeError`]) are measured again, for the nodes whose
/// error stands out (over twice the level's median): input vertices
/// against the whole next level (`levels[0]`: its chunks and leaf bounds),
/// representatives against the whole level itself (`levels[1]`).
///
/// Why: clustering a level can leave a *flap*, triangles folded back over
/// a neighbouring node's surface (on the surface, 1e-5 from the input,
/// but over the neighbour's area). The node holding them drops them one
/// level up (they form folds), so their vertices are far from *its*
/// output, 4e-3 on a 2 M-triangle sphere's level-1 node where the level as
/// a whole was 3e-5 from the input; saturation then carried 4e-3 to every
/// ancestor and the viewer refined far more than needed. Measured against
/// the next level, which holds the neighbour's surface under the flap, the
/// error is what the cut shows: a cut draws, around the flap, the
/// neighbour's surface at its own level (or finer), within its own error.
pub(super) fn remeasure_far(levels: [(&ChunkFile, &[LeafStats]); 2], errors: &mut [f64], far_nodes: Vec<FarNode>) -> Result<()> {
    use crate::geom::{Bvh, Mesh};
    if far_nodes.is_empty() {
        return Ok(());
    }
    let mut sorted: Vec<f64> = errors.to_vec();
    sorted.sort_unstable_by(f64::total_cmp);
    let median = sorted[sorted.len() / 2];
    let picked: Vec<FarNode> = far_nodes.into_iter().filter(|f| errors[f.node] > 2.0 * median).collect();
    // The largest distance from `pts` to one level's surface near them.
    let measure = |(file, leaves): (&ChunkFile, &[LeafStats]), pts: &[([f64; 3], f64)]| -> Result<f64> {
        if pts.is_empty() {
            return Ok(0.0);
        }
        let near = |b: &Aabb, p: [f64; 3], r: f64| (0..3).all(|k| p[k] >= b.min[k] - r && p[k] <= b.max[k] + r);
        // Only triangles within some point's bound can change its result
        // (it is capped at the bound), so only those go in the BVH.
        let mut mesh = Mesh { positions: Vec::new(), triangles: Vec::new() };
        for l in (0..leaves.len()).filter(|&l| leaves[l].tris > 0 && pts.iter().any(|&(p, d)| near(&leaves[l].bounds, p, d))) {
            let g = file.gather_with(l, false)?;
            let close: Vec<&(_, f64)> = pts.iter().filter(|&&(p, d)| near(&leaves[l].bounds, p, d)).collect();
            let off = mesh.positions.len() as u32;
            mesh.positions.extend(g.mesh.vertices.iter().map(|v| v.pos));
            mesh.triangles.extend(
                g.mesh
                    .triangles
                    .iter()
                    .filter(|t| {
                        let mut b = Aabb::EMPTY;
                        for &x in t.iter() {
                            b.add(g.mesh.vertices[x as usize].pos);
                        }
                        close.iter().any(|&&(p, d)| near(&b, p, d))
                    })
                    .map(|t| t.map(|x| x + off)),
            );
        }
        let bvh = Bvh::new(&mesh);
        Ok(pts.iter().map(|&(p, d)| bvh.closest(p).map_or(d, |c| c.dist2.sqrt().min(d))).fold(0.0, f64::max))
    };
    let remeasured: Vec<Result<(usize, f64)>> =
        picked.par_iter().map(|f| Ok((f.node, f.base.max(measure(levels[0], &f.far)?).max(measure(levels[1], &f.far_reps)?)))).collect();
    for r in remeasured {
        let (i, e) = r?;
        errors[i] = errors[i].min(e);
    }
    Ok(())
}

/// A node whose error a few far points set ([`NodeError`]), kept for
/// [`remeasure_far`]: its index in the level, and its error without them.
pub(super) struct FarNode {
    pub node: usize,
    pub base: f64,
    pub far: Vec<([f64; 3], f64)>,
    pub far_reps: Vec<([f64; 3], f64)>,
}

/// [`node_error`]'s result.
#[derive(Clone, Debug, Default)]
pub struct NodeError {
    /// The node's simplification error (both directions).
    pub error: f64,
    /// What remains of it without the far input vertices: the
    /// representatives' side, and every other input vertex.
    pub base: f64,
    /// The input vertices farthest from the node's own output, with that
    /// distance (an upper bound).
    pub far: Vec<([f64; 3], f64)>,
    /// The representatives farthest from the node's own input, likewise.
    pub far_reps: Vec<([f64; 3], f64)>,
}

#[cfg(test)]
mod tests {
    use super::open_fans;

    /// Clusters spanning one-cell holes of a grid: the node error sees the
    /// output over a hole's middle. Against dense samples of every output
    /// face measured exactly (a BVH over the input), at a quarter of the
    /// grid: 0.86× with the samples over holes, 0.51× without them (every
    /// corner and face sample near a rim). Where no hole is spanned the
    /// vertices-and-border samples give 0.82–0.97× on such grids (the
    /// output faces' inner points; the level measures its far points again).
    #[test]
    fn errors_see_the_holes_a_cluster_spans() {
        use crate::geom::{Bvh, Mesh};
        use crate::mesh::{AttrSet, IndexedMesh, Vertex};
        let n = 120u32;
        let mut mesh = IndexedMesh::default();
        for j in 0..=n {
            for i in 0..=n {
                let (x, y) = (i as f64 / n as f64, j as f64 / n as f64);
                mesh.vertices.push(Vertex { pos: [x, y, 0.05 * (6.0 * x).sin() * (5.0 * y).cos()], ..Default::default() });
            }
        }
        for j in 0..n {
            for i in 0..n {
                if (i * j) % 31 != 2 {
                    let a = j * (n + 1) + i;
                    mesh.triangles.push([a, a + 1, a + n + 2]);
                    mesh.triangles.push([a, a + n + 2, a + n + 1]);
                }
            }
        }
        let locked = vec![false; mesh.vertices.len()];
        let sp = super::cluster::Splits::new(&mesh, None, &locked, None, AttrSet::POSITION_ONLY, usize::MAX, 0.0);
        let out = sp.build(sp.steps_for_target(mesh.triangles.len() / 4), 1e-3);
        let e = super::node_error(&mesh, &out).error;
        // Every output face on a 12-step barycentric grid.
        let bvh = Bvh::new(&Mesh::from_vertices(&mesh.vertices, mesh.triangles.clone()));
        let mut h = 0.0f64;
        for t in &out.mesh.triangles {
            let c = t.map(|v| out.mesh.vertices[v as usize].pos);
            for a in 0..=12 {
                for b in 0..=12 - a {
                    let (u, v) = (a as f64 / 12.0, b as f64 / 12.0);
                    let p = [0, 1, 2].map(|k| c[0][k] + u * (c[1][k] - c[0][k]) + v * (c[2][k] - c[0][k]));
                    h = h.max(bvh.closest(p).unwrap().dist2.sqrt());
                }
            }
        }
        // The hole's half-width, about (1/120)/2, is what is to be seen.
        assert!(h > 1e-3, "{h}");
        assert!(e >= 0.75 * h, "node error {e:.3e} against {h:.3e} measured densely ({:.2}x)", e / h);
    }

    #[test]
    fn open_fans_find_the_border_and_nothing_else() {
        // A closed tetrahedron (consistently oriented): no open fan, also
        // with every face twice.
        let tet = [[0, 2, 1], [0, 1, 3], [1, 2, 3], [2, 0, 3]];
        assert_eq!(open_fans(4, &tet), vec![false; 4]);
        let twice: Vec<[u32; 3]> = tet.iter().chain(tet.iter()).copied().collect();
        assert_eq!(open_fans(4, &twice), vec![false; 4]);
        // One face removed: its three corners are on the border, the apex
        // opposite it is not.
        assert_eq!(open_fans(4, &tet[1..]), vec![true, true, true, false]);
        // A strip: every vertex is on its border; a vertex with no triangle is not.
        assert_eq!(open_fans(5, &[[0, 1, 2], [2, 1, 3]]), vec![true, true, true, true, false]);
    }
}

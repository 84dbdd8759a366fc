//! The exact closest point on a triangle, whatever its shape.
//!
//! Takes: a point and a triangle's corners. Gives: the closest point of the
//! triangle. Ericson's Voronoi-region method (Real-Time Collision Detection
//! §5.1.5) for well-shaped triangles; thin triangles (height below 1e-3 of
//! the longest edge) use a plane projection with an edge-sign inside test
//! and fall back to the edges, and degenerate ones (height at most 1e-8 of
//! the longest edge: collinear or coincident corners) are the union of
//! their three edges as segments, so no input produces NaN. Also the
//! points that sample a face besides its corners ([`face_samples`]).

use super::{add, cross, dist2, dot, scale, sub, P3};

/// Closest point to `p` on segment `ab` (a zero-length segment is its point).
#[inline]
pub fn closest_point_segment(p: P3, a: P3, b: P3) -> P3 {
    let ab = sub(b, a);
    let l = dot(ab, ab);
    if l <= 0.0 {
        return a;
    }
    let t = (dot(sub(p, a), ab) / l).clamp(0.0, 1.0);
    add(a, scale(ab, t))
}

/// How a triangle's closest point is computed; see [`TriKind::of`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TriKind {
    /// Ericson's Voronoi-region method.
    Regular,
    /// Plane projection with an exact inside test, else the edges.
    Thin,
    /// The union of the three edges as segments.
    Degenerate,
}

impl TriKind {
    /// By the ratio of the height over the longest edge to that edge,
    /// `h/L`: regular when at least 1e-3 (Ericson's barycentrics then
    /// round to ~1e-10 relative), degenerate when at most 1e-8 (where the
    /// computed normal's rounding, ~1e-16/(h/L), would cost more than
    /// ignoring the interior, ≤ h), thin in between.
    #[inline]
    pub fn of(a: P3, b: P3, c: P3) -> TriKind {
        let (ab, ac, bc) = (sub(b, a), sub(c, a), sub(c, b));
        let n = cross(ab, ac);
        let nn = dot(n, n); // (2 area)² = (L h)²
        let e = dot(ab, ab).max(dot(ac, ac)).max(dot(bc, bc));
        let ll = e * e;
        if nn.is_nan() || nn <= 1e-16 * ll || nn <= 0.0 {
            TriKind::Degenerate
        } else if nn < 1e-6 * ll {
            TriKind::Thin
        } else {
            TriKind::Regular
        }
    }
}

/// Closest point to `p` on the triangle `abc`, whatever its shape.
#[inline]
pub fn closest_point_triangle(p: P3, a: P3, b: P3, c: P3) -> P3 {
    closest_point_triangle_kind(p, a, b, c, TriKind::of(a, b, c))
}

#[inline]
pub(crate) fn closest_point_triangle_kind(p: P3, a: P3, b: P3, c: P3, kind: TriKind) -> P3 {
    match kind {
        TriKind::Regular => ericson(p, a, b, c),
        TriKind::Thin => {
            let n = cross(sub(b, a), sub(c, a));
            let inside = dot(cross(sub(b, a), sub(p, a)), n) >= 0.0 && dot(cross(sub(c, b), sub(p, b)), n) >= 0.0 && dot(cross(sub(a, c), sub(p, c)), n) >= 0.0;
            if inside {
                let t = dot(sub(p, a), n) / dot(n, n);
                sub(p, scale(n, t))
            } else {
                closest_on_edges(p, a, b, c)
            }
        }
        TriKind::Degenerate => closest_on_edges(p, a, b, c),
    }
}

#[inline]
fn closest_on_edges(p: P3, a: P3, b: P3, c: P3) -> P3 {
    let mut best = closest_point_segment(p, a, b);
    let mut d = dist2(p, best);
    for q in [closest_point_segment(p, b, c), closest_point_segment(p, c, a)] {
        let e = dist2(p, q);
        if e < d {
            d = e;
            best = q;
        }
    }
    best
}

/// Ericson, Real-Time Collision Detection §5.1.5 (non-degenerate triangles).
#[inline]
fn ericson(p: P3, a: P3, b: P3, c: P3) -> P3 {
    let ab = sub(b, a);
    let ac = sub(c, a);
    let ap = sub(p, a);
    let d1 = dot(ab, ap);
    let d2 = dot(ac, ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = sub(p, b);
    let d3 = dot(ab, bp);
    let d4 = dot(ac, bp);
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return add(a, scale(ab, d1 / (d1 - d3)));
    }
    let cp = sub(p, c);
    let d5 = dot(ab, cp);
    let d6 = dot(ac, cp);
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return add(a, scale(ac, d2 / (d2 - d6)));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return add(b, scale(sub(c, b), w));
    }
    let denom = va + vb + vc;
    if denom.is_nan() || denom <= 0.0 {
        return closest_on_edges(p, a, b, c);
    }
    let v = vb / denom;
    let w = vc / denom;
    add(a, add(scale(ab, v), scale(ac, w)))
}

/// Samples of triangle `c`'s face besides its corners: the midpoints of its
/// three edges and its centroid (where a triangle's corners alone would
/// not do: a point over a hole the triangle spans, a face its neighbours'
/// corners do not cover).
#[inline]
pub fn face_samples(c: [P3; 3]) -> [P3; 4] {
    let mid = |a: P3, b: P3| [0, 1, 2].map(|k| 0.5 * (a[k] + b[k]));
    [mid(c[0], c[1]), mid(c[1], c[2]), mid(c[2], c[0]), [0, 1, 2].map(|k| (c[0][k] + c[1][k] + c[2][k]) / 3.0)]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::Rng;

    /// Closest point by dense parametric search plus local refinement (reference).
    fn reference_d2(p: P3, a: P3, b: P3, c: P3) -> f64 {
        let mut best = f64::INFINITY;
        let n = 200;
        for i in 0..=n {
            for j in 0..=(n - i) {
                let (u, v) = (i as f64 / n as f64, j as f64 / n as f64);
                let q = add(a, add(scale(sub(b, a), u), scale(sub(c, a), v)));
                best = best.min(dist2(p, q));
            }
        }
        for (s, e) in [(a, b), (b, c), (c, a)] {
            best = best.min(dist2(p, closest_point_segment(p, s, e)));
        }
        best
    }

    fn close(a: P3, b: P3) -> bool {
        dist2(a, b).sqrt() <= 1e-12
    }

    #[test]
    fn point_triangle_vertex_edge_and_face_regions() {
        let (a, b, c) = ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]);
        assert_eq!(TriKind::of(a, b, c), TriKind::Regular);
        let cases: [(P3, P3); 8] = [
            ([-1.0, -1.0, 1.0], a),                 // vertex a
            ([2.0, -0.5, -3.0], b),                 // vertex b
            ([-0.2, 3.0, 0.5], c),                  // vertex c
            ([0.5, -1.0, 0.0], [0.5, 0.0, 0.0]),    // edge ab
            ([-2.0, 0.25, 1.0], [0.0, 0.25, 0.0]),  // edge ca
            ([1.0, 1.0, 0.0], [0.5, 0.5, 0.0]),     // edge bc
            ([0.25, 0.25, 3.0], [0.25, 0.25, 0.0]), // face, above
            ([0.1, 0.2, -2.0], [0.1, 0.2, 0.0]),    // face, below
        ];
        for (p, want) in cases {
            let q = closest_point_triangle(p, a, b, c);
            assert!(close(q, want), "p {p:?}: got {q:?}, want {want:?}");
            // Every corner order gives the same point.
            assert!(close(closest_point_triangle(p, b, c, a), want));
            assert!(close(closest_point_triangle(p, c, b, a), want));
        }
    }

    #[test]
    fn point_triangle_degenerate_and_thin() {
        // Collinear, c beyond b: the closest point is on segment bc.
        let (a, b, c) = ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]);
        assert_eq!(TriKind::of(a, b, c), TriKind::Degenerate);
        for (p, want) in [([1.8, 1.0, 0.0], [1.8, 0.0, 0.0]), ([3.0, 0.0, 1.0], c), ([-1.0, 2.0, 0.0], a)] {
            for q in [closest_point_triangle(p, a, b, c), closest_point_triangle(p, c, a, b), closest_point_triangle(p, b, c, a)] {
                assert!(q.iter().all(|x| x.is_finite()));
                assert!(close(q, want), "p {p:?}: got {q:?}, want {want:?}");
            }
        }
        // Repeated corner, and all three coincident.
        let q = closest_point_triangle([0.5, 1.0, 0.0], a, a, b);
        assert!(close(q, [0.5, 0.0, 0.0]), "{q:?}");
        let q = closest_point_triangle([1.0, 2.0, 3.0], b, b, b);
        assert_eq!(q, b);
        // A thin sliver (aspect 1e-7): inside the face, and just outside it.
        let (a, b, c) = ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.5, 1e-7, 0.0]);
        assert_eq!(TriKind::of(a, b, c), TriKind::Thin);
        let q = closest_point_triangle([0.5, 5e-8, 1.0], a, b, c);
        assert!(close(q, [0.5, 5e-8, 0.0]), "{q:?}");
        let q = closest_point_triangle([0.5, 1.0, 0.0], a, b, c);
        assert!(close(q, c), "{q:?}");
        let q = closest_point_triangle([0.25, -1.0, 0.0], a, b, c);
        assert!(close(q, [0.25, 0.0, 0.0]), "{q:?}");
    }

    #[test]
    fn point_triangle_matches_a_dense_reference_on_random_triangles() {
        let mut rng = Rng::new(7);
        let mut r = || 2.0 * rng.f64() - 1.0;
        for k in 0..300 {
            let a = [r(), r(), r()];
            let b = [r(), r(), r()];
            // Every third triangle thin or degenerate.
            let c = match k % 3 {
                0 => [r(), r(), r()],
                1 => add(a, scale(sub(b, a), 1.7)),
                _ => add(add(a, scale(sub(b, a), 0.3)), [1e-5 * r(), 1e-5 * r(), 1e-5 * r()]),
            };
            let p = [2.0 * r(), 2.0 * r(), 2.0 * r()];
            let q = closest_point_triangle(p, a, b, c);
            let d = dist2(p, q).sqrt();
            let want = reference_d2(p, a, b, c).sqrt();
            let longest = [dist2(a, b), dist2(b, c), dist2(c, a)].into_iter().fold(0.0, f64::max).sqrt();
            // The grid reference is an upper bound, within its spacing.
            assert!(d <= want + 1e-12, "case {k}: {d} > reference {want}");
            assert!(d >= want - longest / 150.0, "case {k}: {d} far below reference {want}");
            // The point lies on the triangle: its distance to it is ~0.
            let back = dist2(q, closest_point_triangle(q, a, b, c)).sqrt();
            assert!(back < 1e-9, "case {k}: returned point is {back} off the triangle");
        }
    }
}

//! Unit tests of the quadric module: embedding, accumulation, solve,
//! box minimisation and the eigen-decomposition.

use super::*;
use crate::geom::{add, scale};

/// The tests' random points: [`crate::geom::Rng`] from a raw state.
struct Rng(crate::geom::Rng);
impl Rng {
    fn at(state: u64) -> Rng {
        Rng(crate::geom::Rng::from_state(state))
    }
    fn next(&mut self) -> f64 {
        self.0.f64()
    }
    fn range(&mut self, a: f64, b: f64) -> f64 {
        self.0.range(a, b)
    }
    fn vec3(&mut self, a: f64, b: f64) -> [f64; 3] {
        [self.range(a, b), self.range(a, b), self.range(a, b)]
    }
}

fn norm(a: [f64; 3]) -> f64 {
    dot3(a, a).sqrt()
}
fn unit(a: [f64; 3]) -> [f64; 3] {
    scale(a, 1.0 / norm(a))
}
fn dist(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum::<f64>().sqrt()
}
fn vpos(p: [f64; 3]) -> Vertex {
    Vertex { pos: p, ..Vertex::default() }
}
fn pos_space(origin: [f64; 3]) -> QuadricSpace {
    QuadricSpace::new(AttrSet::POSITION_ONLY, AttrWeights::default(), origin)
}
/// Orthonormal frame (a, u, w) with a along `dir`.
fn frame(dir: [f64; 3]) -> ([f64; 3], [f64; 3], [f64; 3]) {
    let a = unit(dir);
    let t = if a[0].abs() < 0.9 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] };
    let u = unit(cross(a, t));
    (a, u, cross(a, u))
}

struct TestMesh {
    verts: Vec<Vertex>,
    tris: Vec<[usize; 3]>,
}

impl TestMesh {
    fn new() -> TestMesh {
        TestMesh { verts: Vec::new(), tris: Vec::new() }
    }
    /// (nu+1)×(nv+1) grid of `f(i, j)`, two triangles per quad.
    fn grid(&mut self, nu: usize, nv: usize, mut f: impl FnMut(usize, usize) -> Vertex) {
        let b = self.verts.len();
        for j in 0..=nv {
            for i in 0..=nu {
                self.verts.push(f(i, j));
            }
        }
        let id = |i: usize, j: usize| b + j * (nu + 1) + i;
        for j in 0..nv {
            for i in 0..nu {
                self.tris.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
                self.tris.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
            }
        }
    }
    fn triangles(&self, s: &QuadricSpace) -> Quadric {
        let e: Vec<_> = self.verts.iter().map(|v| s.embed(v)).collect();
        let mut q = Quadric::zero(s.dim);
        for t in &self.tris {
            q.add_triangle(&e[t[0]], &e[t[1]], &e[t[2]]);
        }
        q
    }
    /// Triangles plus every vertex as a point.
    fn quadric(&self, s: &QuadricSpace) -> Quadric {
        let mut q = self.triangles(s);
        for v in &self.verts {
            q.add_point(&s.embed(v));
        }
        q
    }
    fn area(&self) -> f64 {
        self.tris
            .iter()
            .map(|t| {
                let [p, q, r] = t.map(|i| self.verts[i].pos);
                0.5 * norm(cross(sub(q, p), sub(r, p)))
            })
            .sum()
    }
}

#[test]
fn dimension_follows_attributes_and_embedding_round_trips() {
    let dims = [
        (AttrSet::POSITION_ONLY, 3),
        (AttrSet(AttrSet::UV), 5),
        (AttrSet(AttrSet::NORMAL), 6),
        (AttrSet(AttrSet::COLOR), 6),
        (AttrSet(AttrSet::COLOR | AttrSet::ALPHA | AttrSet::POS_F64), 6),
        (AttrSet(AttrSet::UV | AttrSet::NORMAL), 8),
        (AttrSet(AttrSet::NORMAL | AttrSet::COLOR), 9),
        (AttrSet(AttrSet::UV | AttrSet::NORMAL | AttrSet::COLOR), 11),
    ];
    let v = Vertex { pos: [1e6 + 0.5, -3.0, 2.25], normal: [0.0, 0.6, 0.8], color: [10, 128, 255, 7], uv: [0.25, 0.75], material: 0 };
    for (attrs, d) in dims {
        let s = QuadricSpace::new(attrs, AttrWeights { uv: 2.0, normal: 3.0, color: 5.0 }, [1e6, -4.0, 2.0]);
        assert_eq!(s.dim, d);
        assert_eq!(Quadric::zero(s.dim).coeffs().len(), (d + 1) * (d + 2) / 2 + d + 2);
        let x = s.embed(&v);
        assert_eq!(&x[..3], &[0.5, 1.0, 0.25]);
        assert!(x[d..].iter().all(|&c| c == 0.0));
        let mut at = 3;
        if attrs.uv() {
            assert_eq!(s.uv_at(), Some(at));
            assert_eq!(&x[at..at + 2], &[0.5, 1.5]);
            at += 2;
        }
        if attrs.normal() {
            assert_eq!(s.normal_at(), Some(at));
            assert!(dist(&x[at..at + 3], &[0.0, 1.8, 2.4]) < 1e-6);
            at += 3;
        }
        if attrs.color() {
            assert_eq!(s.color_at(), Some(at));
            assert!(dist(&x[at..at + 3], &[50.0 / 255.0, 640.0 / 255.0, 5.0]) < 1e-12);
            at += 3;
        }
        assert_eq!(at, d);
        let template = Vertex { color: [1, 2, 3, 7], normal: [1.0, 0.0, 0.0], uv: [9.0, 9.0], ..Vertex::default() };
        let w = s.unembed(&x, &template);
        assert_eq!(w.pos, v.pos);
        assert_eq!(w.color[3], 7);
        if attrs.color() {
            assert_eq!(w.color, v.color);
        }
        if attrs.uv() {
            assert_eq!(w.uv, v.uv);
        } else {
            assert_eq!(w.uv, template.uv);
        }
        if attrs.normal() {
            assert!(dist(&w.normal.map(|c| c as f64), &[0.0, 0.6, 0.8]) < 1e-6);
        } else {
            assert_eq!(w.normal, template.normal);
        }
    }
    // Decoding clamps colors and renormalises normals.
    let s = QuadricSpace::new(AttrSet(AttrSet::NORMAL | AttrSet::COLOR), AttrWeights::uniform(0.5), [0.0; 3]);
    let mut x = [0.0; MAX_DIM];
    x[3..6].copy_from_slice(&[0.0, 0.0, 0.1]);
    x[6..9].copy_from_slice(&[-0.2, 0.7, f64::NAN]);
    let w = s.unembed(&x, &Vertex::default());
    assert_eq!(w.normal, [0.0, 0.0, 1.0]);
    assert_eq!(w.color, [0, 255, 0, 255]);
}

#[test]
fn single_triangle_plane() {
    let s = pos_space([0.0; 3]);
    let (p, q, r) = ([0.1, 0.2, 0.3], [1.1, -0.4, 0.9], [0.3, 0.8, -0.5]);
    let (ep, eq, er) = (s.embed(&vpos(p)), s.embed(&vpos(q)), s.embed(&vpos(r)));
    let mut quad = Quadric::from_triangle(&s, &ep, &eq, &er);
    let n = cross(sub(q, p), sub(r, p));
    let area = 0.5 * norm(n);
    let n = unit(n);
    assert!((quad.area() - area).abs() < 1e-15);
    // Q is the area-weighted squared distance to the plane.
    for t in [0.0, 0.3, -2.0] {
        let x = add(add(scale(add(p, q), 0.3), scale(r, 0.4)), scale(n, t));
        assert!((quad.error(&x) - area * t * t).abs() < 1e-13, "t={t}");
    }
    for pt in [&ep, &eq, &er] {
        quad.add_point(pt);
    }
    let sol = quad.solve(DEFAULT_REL_TOL, None);
    assert_eq!(sol.rank, 1);
    assert!(!sol.clamped);
    assert!(sol.error < 1e-15 * area, "{}", sol.error);
    let centroid = scale(add(add(p, q), r), 1.0 / 3.0);
    assert!(dist(&sol.x[..3], &centroid) < 1e-14);
    // With the mean off the plane, the solve projects it onto the plane.
    let mut off = Quadric::from_triangle(&s, &ep, &eq, &er);
    let m = add(centroid, scale(n, 0.7));
    off.add_point(&m);
    let sol = off.solve(DEFAULT_REL_TOL, None);
    assert!(dist(&sol.x[..3], &centroid) < 1e-14);
    // Same quadric in a higher dimension: rank n - 2.
    let s6 = QuadricSpace::new(AttrSet(AttrSet::COLOR), AttrWeights::uniform(0.5), [0.0; 3]);
    let vs = [p, q, r].map(|pos| Vertex { pos, color: [40, 90, 200, 255], ..Vertex::default() });
    let e = vs.map(|v| s6.embed(&v));
    let q6 = Quadric::from_triangle(&s6, &e[0], &e[1], &e[2]);
    assert_eq!(q6.solve(DEFAULT_REL_TOL, None).rank, 4);
    assert!((q6.area() - area).abs() < 1e-15);
    // Constant color: moving along the geometric normal by t, or off the
    // color by dc, costs area * (t² + dc²).
    for (t, dc) in [(0.0, 0.0), (0.3, 0.0), (-2.0, 0.1), (0.0, 0.25)] {
        let mut x = e[0];
        for c in 0..3 {
            x[c] += t * n[c];
        }
        x[4] += dc;
        assert!((q6.error(&x) - area * (t * t + dc * dc)).abs() < 1e-13, "t={t} dc={dc}");
    }
}

#[test]
fn flat_grid_is_rank_one_and_keeps_the_in_plane_mean() {
    let s = pos_space([0.0; 3]);
    let (nrm, t1, t2) = frame([0.3, -0.5, 0.8]);
    let p0 = [0.2, 0.1, -0.4];
    let mut m = TestMesh::new();
    m.grid(20, 15, |i, j| {
        let u = i as f64 * 0.05 + 0.01 * (i as f64).sin();
        let v = j as f64 * 0.07 + 0.01 * (j as f64 * 1.3).cos();
        vpos(add(p0, add(scale(t1, u), scale(t2, v))))
    });
    let mut q = m.triangles(&s);
    assert!((q.area() - m.area()).abs() < 1e-12);
    // Points off the plane: the mean must be projected onto it.
    for v in &m.verts {
        q.add_point(&s.embed(&vpos(add(v.pos, scale(nrm, 0.05)))));
    }
    let sol = q.solve(DEFAULT_REL_TOL, None);
    assert_eq!(sol.rank, 1);
    let mean = q.mean();
    let expect = sub([mean[0], mean[1], mean[2]], scale(nrm, 0.05));
    assert!(dist(&sol.x[..3], &expect) < 1e-12, "{:?} vs {:?}", sol.x, expect);
    assert!(dot3(nrm, sub([sol.x[0], sol.x[1], sol.x[2]], p0)).abs() < 1e-12);
    assert!(sol.error < 1e-15 * m.area(), "{}", sol.error);
}

#[test]
fn cylinder_is_rank_two_on_the_axis_at_the_axial_mean() {
    let s = pos_space([0.0; 3]);
    let (ax, u, w) = frame([0.2, 0.1, 1.0]);
    let c = [0.3, -0.2, 0.1];
    let radius = 0.5;
    let levels = [0.0, 0.1, 0.35, 0.4, 1.2];
    let nseg = 24;
    let point = |i: usize, z: f64| {
        let th = std::f64::consts::TAU * i as f64 / nseg as f64;
        add(add(c, scale(ax, z)), add(scale(u, radius * th.cos()), scale(w, radius * th.sin())))
    };
    let mut m = TestMesh::new();
    m.grid(nseg, levels.len() - 1, |i, j| vpos(point(i % nseg, levels[j])));
    let mut q = m.triangles(&s);
    // Biased mean: only half of the ring, so the mean is off the axis.
    let mut axial = 0.0;
    let mut cnt = 0.0;
    for (j, &z) in levels.iter().enumerate() {
        for i in 0..nseg / 2 {
            q.add_point(&s.embed(&vpos(point(i, z + 0.01 * j as f64))));
            axial += z + 0.01 * j as f64;
            cnt += 1.0;
        }
    }
    let mean = q.mean();
    let off_axis = {
        let d = sub([mean[0], mean[1], mean[2]], c);
        norm(sub(d, scale(ax, dot3(d, ax))))
    };
    assert!(off_axis > 0.1 * radius, "test must start off the axis");
    let sol = q.solve(DEFAULT_REL_TOL, None);
    assert_eq!(sol.rank, 2);
    let d = sub([sol.x[0], sol.x[1], sol.x[2]], c);
    let along = dot3(d, ax);
    assert!(norm(sub(d, scale(ax, along))) < 1e-9 * radius, "off axis by {}", norm(sub(d, scale(ax, along))));
    assert!((along - axial / cnt).abs() < 1e-12, "{along} vs {}", axial / cnt);
}

/// Three orthogonal faces meeting at `k`, rotated by the frame of `dir`.
fn cube_corner(k: [f64; 3], dir: [f64; 3], size: f64) -> TestMesh {
    let (a, u, w) = frame(dir);
    let axes = [a, u, w];
    let mut m = TestMesh::new();
    for f in 0..3 {
        let (e1, e2) = (axes[(f + 1) % 3], axes[(f + 2) % 3]);
        m.grid(4, 4, |i, j| vpos(add(k, add(scale(e1, size * i as f64 / 4.0), scale(e2, size * j as f64 / 4.0)))));
    }
    m
}

#[test]
fn cube_corner_is_rank_three_and_exact() {
    let s = pos_space([0.0; 3]);
    let k = [0.25, -0.4, 0.6];
    let m = cube_corner(k, [0.4, 0.7, -0.2], 0.5);
    let q = m.quadric(&s);
    assert!(dist(&q.mean()[..3], &k) > 0.1);
    let sol = q.solve(DEFAULT_REL_TOL, None);
    assert_eq!(sol.rank, 3);
    assert!(dist(&sol.x[..3], &k) < 1e-14, "{:?}", sol.x);
    assert!(sol.error < 1e-14 * m.area(), "{}", sol.error);
}

#[test]
fn nearly_parallel_sheets_stay_between() {
    let s = pos_space([0.0; 3]);
    let gap = 1e-4;
    let mut m = TestMesh::new();
    m.grid(10, 10, |i, j| vpos([i as f64 / 10.0, j as f64 / 10.0, 0.0]));
    m.grid(10, 10, |i, j| vpos([i as f64 / 10.0, j as f64 / 10.0, gap + 1e-5 * i as f64 / 10.0]));
    let q = m.quadric(&s);
    let sol = q.solve(DEFAULT_REL_TOL, None);
    assert!(sol.x.iter().all(|v| v.is_finite()));
    assert_eq!(sol.rank, 1, "the 1e-5 tilt is below the cut-off");
    assert!(sol.x[2] > 0.0 && sol.x[2] < gap + 1e-5, "z = {}", sol.x[2]);
    let mid = 0.5 * (gap + 1e-5 * sol.x[0]);
    assert!((sol.x[2] - mid).abs() < 0.01 * gap, "z = {} vs mid {mid}", sol.x[2]);
    assert!(sol.error < m.area() * gap * gap, "error {}", sol.error);
    assert!(dist(&sol.x[..2], &q.mean()[..2]) < 1e-9);
    // Keeping the tilt (tiny rel_tol): the sheets intersect at x = -10;
    // the unbounded answer is finite, the bounded one stays in the cell.
    let sol = q.solve(1e-12, None);
    assert_eq!(sol.rank, 2);
    assert!(sol.x.iter().all(|v| v.is_finite()));
    assert!((sol.x[0] + 10.0).abs() < 0.1, "x = {}", sol.x[0]);
    let sol = q.solve(1e-12, Some(([0.0; 3], [1.0; 3])));
    assert!(sol.clamped);
    assert!(sol.x[..3].iter().all(|&v| (0.0..=1.0).contains(&v)));
    assert!(sol.x[2] > 0.0 && sol.x[2] < gap, "z = {}", sol.x[2]);
}

#[test]
fn degenerate_triangles_contribute_nothing_and_never_nan() {
    let p = [0.1, 0.2, 0.3];
    let d = [0.3, -0.1, 0.2];
    let bad: Vec<[[f64; 3]; 3]> = vec![
        [p, p, p],
        [p, p, add(p, d)],
        [p, add(p, d), p],
        [p, add(p, d), add(p, scale(d, 2.0))],
        [p, add(p, scale(d, 1e-300)), add(p, d)],
        [[f64::NAN, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        [[f64::INFINITY, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        [[1e300, 0.0, 0.0], [-1e300, 1e300, 0.0], [0.0, -1e300, 1e300]],
    ];
    for attrs in [AttrSet::POSITION_ONLY, AttrSet(AttrSet::COLOR), AttrSet(AttrSet::UV | AttrSet::NORMAL | AttrSet::COLOR)] {
        let s = QuadricSpace::new(attrs, AttrWeights::uniform(0.3), [0.0; 3]);
        for (ti, t) in bad.iter().enumerate() {
            // Attributes differ per corner: collinear positions still count zero.
            let vs: Vec<Vertex> = t
                .iter()
                .enumerate()
                .map(|(c, &pos)| Vertex { pos, color: [50 * c as u8, 0, 90, 255], uv: [c as f32, 0.5], normal: [0.0, 0.0, 1.0], material: 0 })
                .collect();
            let e: Vec<_> = vs.iter().map(|v| s.embed(v)).collect();
            let q = Quadric::from_triangle(&s, &e[0], &e[1], &e[2]);
            assert!(q.coeffs().iter().all(|&c| c == 0.0), "attrs {attrs:?} triangle {ti}: {q:?}");
            let sol = q.solve(DEFAULT_REL_TOL, Some(([-1.0; 3], [1.0; 3])));
            assert!(sol.x.iter().all(|v| v.is_finite()) && sol.rank == 0 && sol.error == 0.0);
        }
        // Slivers: tiny but nonzero area; finite, tiny, never NaN.
        let mut q = Quadric::zero(s.dim);
        for h in [1e-12, 1e-100, 1e-250] {
            let vs = [p, add(p, [1.0, 0.0, 0.0]), add(p, [0.5, h, 0.0])].map(vpos);
            let e = vs.map(|v| s.embed(&v));
            q.add_triangle(&e[0], &e[1], &e[2]);
            assert!(q.coeffs().iter().all(|c| c.is_finite()));
            assert!(q.area() <= 0.5 * 1e-12 + 1e-15);
        }
        q.add_point(&s.embed(&vpos(p)));
        q.add_point(&[f64::NAN; MAX_DIM]);
        assert_eq!(q.count(), 1.0);
        let sol = q.solve(DEFAULT_REL_TOL, None);
        assert!(sol.x.iter().all(|v| v.is_finite()) && sol.error.is_finite());
    }
    // Empty quadric, no points: the local origin.
    let sol = Quadric::zero(3).solve(DEFAULT_REL_TOL, None);
    assert_eq!((sol.x, sol.rank, sol.clamped), ([0.0; MAX_DIM], 0, false));
    // Empty quadric with points outside the bounds: clamped mean.
    let mut q = Quadric::zero(3);
    q.add_point(&[5.0, 0.5, -7.0]);
    let sol = q.solve(DEFAULT_REL_TOL, Some(([-1.0; 3], [1.0; 3])));
    assert!(sol.clamped);
    assert_eq!(&sol.x[..3], &[1.0, 0.5, -1.0]);
}

#[test]
fn far_from_origin_is_exact_in_local_coordinates() {
    // Three planes with integer normals through k (~1e6), sampled at
    // multiples of h = 2^-12 so every vertex is exactly on its plane.
    let k = [1.0e6 + 0.37e-3, -2.0e6 + 0.11e-3, 5.0e5 - 0.23e-3];
    let h = 1.0 / 4096.0;
    let planes: [([f64; 3], [f64; 3]); 3] = [
        ([1.0, -1.0, 0.0], [0.0, 0.0, 1.0]), // normal (1, 1, 0)
        ([0.0, 1.0, -1.0], [1.0, 0.0, 0.0]), // normal (0, 1, 1)
        ([1.0, 0.0, -1.0], [0.0, 1.0, 0.0]), // normal (1, 0, 1)
    ];
    let mut m = TestMesh::new();
    for (t1, t2) in planes {
        m.grid(4, 4, |i, j| vpos(add(k, add(scale(t1, h * i as f64), scale(t2, h * j as f64)))));
    }
    for v in &m.verts {
        for c in 0..3 {
            let off = v.pos[c] - k[c];
            assert_eq!(off, (off / h).round() * h, "vertex not exact");
        }
    }
    let origin = add(k, [3e-4, 2e-4, 4e-4]);
    let s = pos_space(origin);
    let q = m.quadric(&s);
    let expect = sub(k, origin); // exact (Sterbenz)
    let sol = q.solve(DEFAULT_REL_TOL, None);
    assert_eq!(sol.rank, 3);
    let detail = 1e-3;
    let err = dist(&sol.x[..3], &expect);
    assert!(err < 1e-9 * detail, "local error {err}");
    let world = s.unembed(&sol.x, &Vertex::default()).pos;
    for c in 0..3 {
        assert!((world[c] - k[c]).abs() <= 2.0 * f64::EPSILON * k[c].abs(), "world {world:?}");
    }
    // For contrast only: the same solve in world coordinates.
    let sw = pos_space([0.0; 3]);
    let solw = m.quadric(&sw).solve(DEFAULT_REL_TOL, None);
    println!("corner at 1e6: local-frame error {err:.3e}, world-frame error {:.3e}", dist(&solw.x[..3], &k));

    // A noisy bumpy patch at 1e6 in a 1e-3 cell, with bounds: finite and inside.
    let cell = Aabb { min: [1.0e6, 1.0e6, 1.0e6], max: [1.0e6 + 1e-3, 1.0e6 + 1e-3, 1.0e6 + 1e-3] };
    let s = pos_space(cell.center());
    let bounds = s.local_bounds(&cell);
    let mut rng = Rng::at(7);
    for trial in 0..50 {
        let mut m = TestMesh::new();
        let amp = rng.range(0.0, 3e-4);
        let tilt = rng.range(-2.0, 2.0);
        m.grid(6, 6, |i, j| {
            let (x, y) = (i as f64 / 6.0 * 1e-3, j as f64 / 6.0 * 1e-3);
            let z = 5e-4 + tilt * (x - 5e-4) + amp * ((i * 7 + j * 3) as f64).sin();
            vpos(add(cell.min, [x, y, z]))
        });
        let sol = m.quadric(&s).solve(DEFAULT_REL_TOL, Some(bounds));
        assert!(sol.x.iter().all(|v| v.is_finite()), "trial {trial}");
        for c in 0..3 {
            assert!(sol.x[c] >= bounds.0[c] && sol.x[c] <= bounds.1[c], "trial {trial}: {:?}", sol.x);
        }
        let w = s.unembed(&sol.x, &Vertex::default()).pos;
        for c in 0..3 {
            let ulp = 2.0 * f64::EPSILON * 1e6;
            assert!(w[c] >= cell.min[c] - ulp && w[c] <= cell.max[c] + ulp);
        }
    }
}

#[test]
fn clamping_minimises_inside_the_box() {
    // Wedge: z = 0 and z = 0.2 x + 0.3 meet at x = -1.5, outside [-1, 1].
    let s = pos_space([0.0; 3]);
    let mut m = TestMesh::new();
    m.grid(8, 8, |i, j| vpos([-1.0 + i as f64 / 4.0, -1.0 + j as f64 / 4.0, 0.0]));
    m.grid(8, 8, |i, j| {
        let x = -1.0 + i as f64 / 4.0;
        vpos([x, -1.0 + j as f64 / 4.0, 0.2 * x + 0.3])
    });
    let q = m.quadric(&s);
    let free = q.solve(DEFAULT_REL_TOL, None);
    assert_eq!(free.rank, 2);
    assert!((free.x[0] + 1.5).abs() < 1e-9 && free.x[2].abs() < 1e-9, "{:?}", free.x);
    let bounds = ([-1.0; 3], [1.0; 3]);
    let sol = q.solve(DEFAULT_REL_TOL, Some(bounds));
    assert!(sol.clamped);
    assert_eq!(sol.x[0], -1.0);
    assert!(sol.x[2] > 0.0 && sol.x[2] < 0.1, "z = {}", sol.x[2]);
    assert!((sol.x[1] - q.mean()[1]).abs() < 1e-12);
    let naive = [-1.0, free.x[1], 0.0];
    assert!(sol.error < 0.6 * q.error(&naive), "{} vs naive {}", sol.error, q.error(&naive));
    assert!((sol.error - q.error(&sol.x)).abs() <= 1e-15 * (1.0 + sol.error));

    // Fuzz: random near-degenerate clusters and boxes, every cut-off.
    let mut rng = Rng::at(42);
    let attrsets = [AttrSet::POSITION_ONLY, AttrSet(AttrSet::COLOR), AttrSet(AttrSet::UV | AttrSet::NORMAL | AttrSet::COLOR)];
    for trial in 0..3000 {
        let attrs = attrsets[trial % 3];
        let s = QuadricSpace::new(attrs, AttrWeights::for_extent(1.0), [0.0; 3]);
        let mut q = Quadric::zero(s.dim);
        let ntri = 1 + trial % 4;
        let flat = rng.range(0.0, 1.0) < 0.5;
        for _ in 0..ntri {
            let mut vs = [0; 3].map(|_| Vertex {
                pos: rng.vec3(-1.0, 1.0),
                normal: rng.vec3(-1.0, 1.0).map(|c| c as f32),
                color: [0; 4].map(|_| (rng.next() * 255.0) as u8),
                uv: [rng.next() as f32, rng.next() as f32],
                material: 0,
            });
            if flat {
                for v in &mut vs {
                    v.pos[2] = 1e-7 * v.pos[0];
                }
            }
            let e = vs.map(|v| s.embed(&v));
            q.add_triangle(&e[0], &e[1], &e[2]);
            for x in &e {
                q.add_point(x);
            }
        }
        let lo = rng.vec3(-3.0, 2.0);
        let hi = add(lo, rng.vec3(0.0, 1.0));
        let rel_tol = [1e-12, 1e-6, 1e-3][trial % 3];
        let sol = q.solve(rel_tol, Some((lo, hi)));
        assert!(sol.x.iter().all(|v| v.is_finite()) && sol.error.is_finite(), "trial {trial}");
        for c in 0..3 {
            assert!(sol.x[c] >= lo[c] && sol.x[c] <= hi[c], "trial {trial} outside");
        }
        let unb = q.solve(rel_tol, None);
        let inside = (0..3).all(|c| unb.x[c] >= lo[c] && unb.x[c] <= hi[c]);
        assert_eq!(sol.clamped, !inside, "trial {trial}");
        if sol.clamped {
            // Never worse than clamping the unconstrained minimiser.
            let mut naive = unb.x;
            for c in 0..3 {
                naive[c] = naive[c].clamp(lo[c], hi[c]);
            }
            let tol = 1e-9 * (1.0 + q.error(&naive));
            assert!(sol.error <= q.error(&naive) + tol, "trial {trial}: {} > naive {}", sol.error, q.error(&naive));
        } else {
            assert_eq!(sol.x, unb.x);
        }
    }
}

/// Planar patch z = 0.2x + 0.1y on a unit square with colors affine in position.
fn color_ramp(i: usize, j: usize) -> [f64; 3] {
    [20.0 + 25.0 * i as f64, 30.0 + 10.0 * j as f64, 200.0 - 10.0 * i as f64 - 5.0 * j as f64]
}
fn ramp_at(p: &[f64]) -> [f64; 3] {
    // i = 8 x, j = 8 y.
    let (i, j) = (8.0 * p[0], 8.0 * p[1]);
    [20.0 + 25.0 * i, 30.0 + 10.0 * j, 200.0 - 10.0 * i - 5.0 * j]
}
fn plane_z(x: f64, y: f64) -> f64 {
    0.2 * x + 0.1 * y
}

#[test]
fn color_ramp_is_reproduced() {
    let origin = [0.5, 0.5, 0.15];
    let s = QuadricSpace::new(AttrSet(AttrSet::COLOR), AttrWeights::for_extent(3f64.sqrt()), origin);
    assert_eq!(s.dim, 6);
    let mut m = TestMesh::new();
    m.grid(8, 8, |i, j| {
        let (x, y) = (i as f64 / 8.0, j as f64 / 8.0);
        let c = color_ramp(i, j).map(|c| c as u8);
        Vertex { pos: [x, y, plane_z(x, y)], color: [c[0], c[1], c[2], 255], ..Vertex::default() }
    });
    let ci = s.color_at().unwrap();
    // Consistent points (a biased subset): solution is the mean, color = ramp there.
    let mut q = m.triangles(&s);
    for v in m.verts.iter().filter(|v| v.pos[0] < 0.4) {
        q.add_point(&s.embed(v));
    }
    let sol = q.solve(DEFAULT_REL_TOL, None);
    assert_eq!(sol.rank, 4);
    assert!(dist(&sol.x[..6], &q.mean()[..6]) < 1e-12);
    let world = s.unembed(&sol.x, &Vertex::default());
    let want = ramp_at(&world.pos);
    for c in 0..3 {
        let got = sol.x[ci + c] * 255.0 / s.weights.color;
        assert!((got - want[c]).abs() < 1.0, "channel {c}: {got} vs {}", want[c]);
        assert!((world.color[c] as f64 - want[c]).abs() <= 1.0);
    }
    // Points with wrong colors (+40): the quadric pulls the color back onto the ramp.
    let mut q = m.triangles(&s);
    for v in &m.verts {
        let mut w = *v;
        w.color = [v.color[0].saturating_add(40), v.color[1].saturating_add(40), v.color[2].saturating_add(40), 255];
        q.add_point(&s.embed(&w));
    }
    let sol = q.solve(DEFAULT_REL_TOL, None);
    let world = s.unembed(&sol.x, &Vertex::default());
    assert!((world.pos[2] - plane_z(world.pos[0], world.pos[1])).abs() < 1e-12, "off the plane");
    let want = ramp_at(&world.pos);
    for c in 0..3 {
        let got = sol.x[ci + c] * 255.0 / s.weights.color;
        assert!((got - want[c]).abs() < 1.0, "channel {c}: {got} vs {}", want[c]);
    }
}

#[test]
fn uv_and_full_attribute_ramps_are_reproduced() {
    let uv_of = |x: f64, y: f64| [0.1 + 0.5 * x + 0.25 * y, 0.9 - 0.75 * y];
    let (nrm, _, _) = frame([-0.2, -0.1, 1.0]);
    for attrs in [AttrSet(AttrSet::UV), AttrSet(AttrSet::UV | AttrSet::NORMAL | AttrSet::COLOR)] {
        let s = QuadricSpace::new(attrs, AttrWeights::for_extent(1.5), [0.5, 0.5, 0.0]);
        let mut m = TestMesh::new();
        m.grid(8, 8, |i, j| {
            let (x, y) = (i as f64 / 8.0, j as f64 / 8.0);
            let c = color_ramp(i, j).map(|c| c as u8);
            Vertex { pos: [x, y, plane_z(x, y)], uv: uv_of(x, y).map(|c| c as f32), normal: nrm.map(|c| c as f32), color: [c[0], c[1], c[2], 255], material: 0 }
        });
        let mut q = m.triangles(&s);
        for v in &m.verts {
            let mut w = *v;
            w.uv = [w.uv[0] + 0.2, w.uv[1] - 0.1];
            w.normal = [0.0, 1.0, 0.0];
            q.add_point(&s.embed(&w));
        }
        let sol = q.solve(DEFAULT_REL_TOL, None);
        assert_eq!(sol.rank, s.dim - 2);
        let v = s.unembed(&sol.x, &Vertex::default());
        assert!((v.pos[2] - plane_z(v.pos[0], v.pos[1])).abs() < 1e-12);
        let want = uv_of(v.pos[0], v.pos[1]);
        for c in 0..2 {
            assert!((v.uv[c] as f64 - want[c]).abs() < 1e-6, "uv {:?} vs {want:?}", v.uv);
        }
        if attrs.normal() {
            assert!(dist(&v.normal.map(|c| c as f64), &nrm) < 1e-6, "normal {:?}", v.normal);
            let want = ramp_at(&v.pos);
            for c in 0..3 {
                assert!((v.color[c] as f64 - want[c]).abs() <= 1.0, "color {:?} vs {want:?}", v.color);
            }
        }
    }
}

#[test]
fn quadrics_add_and_errors_are_nonnegative() {
    let mut rng = Rng::at(3);
    for attrs in [AttrSet::POSITION_ONLY, AttrSet(AttrSet::NORMAL | AttrSet::COLOR), AttrSet(AttrSet::UV | AttrSet::NORMAL | AttrSet::COLOR)] {
        let s = QuadricSpace::new(attrs, AttrWeights::for_extent(2.0), [0.1, 0.2, 0.3]);
        let tri = |rng: &mut Rng| {
            [0; 3].map(|_| {
                s.embed(&Vertex {
                    pos: rng.vec3(-1.0, 1.0),
                    normal: rng.vec3(-1.0, 1.0).map(|c| c as f32),
                    color: [0; 4].map(|_| (rng.next() * 255.0) as u8),
                    uv: [rng.next() as f32, rng.next() as f32],
                    material: 0,
                })
            })
        };
        let (t1, t2) = (tri(&mut rng), tri(&mut rng));
        let q1 = Quadric::from_triangle(&s, &t1[0], &t1[1], &t1[2]);
        let q2 = Quadric::from_triangle(&s, &t2[0], &t2[1], &t2[2]);
        let mut sum = q1.clone();
        sum.add(&q2);
        let mut inplace = Quadric::zero(s.dim);
        inplace.add_triangle(&t1[0], &t1[1], &t1[2]);
        inplace.add_triangle(&t2[0], &t2[1], &t2[2]);
        assert_eq!(sum.coeffs(), inplace.coeffs());
        let mut flat = vec![0.0; Quadric::coeff_len(s.dim)];
        q1.add_into(&mut flat);
        q2.add_into(&mut flat);
        assert_eq!(Quadric::from_coeffs(s.dim, &flat).coeffs(), sum.coeffs());
        for _ in 0..200 {
            let x = tri(&mut rng)[0];
            let (e1, e2, es) = (q1.error(&x), q2.error(&x), sum.error(&x));
            assert!(e1 >= 0.0 && e2 >= 0.0);
            assert!((es - (e1 + e2)).abs() <= 1e-12 * (1.0 + es), "{es} vs {}", e1 + e2);
        }
        // Each corner lies on its own triangle's plane.
        for x in &t1 {
            assert!(q1.error(x) < 1e-14, "{}", q1.error(x));
        }
    }
}

#[test]
fn position_fast_path_matches_the_general_construction() {
    let mut rng = Rng::at(11);
    for _ in 0..500 {
        let t = [rng.vec3(-2.0, 2.0), rng.vec3(-2.0, 2.0), rng.vec3(-2.0, 2.0)];
        let mut fast = Quadric::zero(3);
        fast.add_triangle(&t[0], &t[1], &t[2]);
        let mut general = Quadric::zero(3);
        let area = 0.5 * norm(cross(sub(t[1], t[0]), sub(t[2], t[0])));
        let p = t.map(|v| {
            let mut x = [0.0; PAD];
            x[..3].copy_from_slice(&v);
            x
        });
        general.add_triangle_general(&p[0], &p[1], &p[2], area);
        for (a, b) in fast.coeffs().iter().zip(general.coeffs()) {
            assert!((a - b).abs() < 1e-12 * (1.0 + a.abs()), "{fast:?} vs {general:?}");
        }
    }
}

#[test]
fn reorigin_matches_building_in_the_new_frame() {
    let mut rng = Rng::at(5);
    let attrs = AttrSet(AttrSet::UV | AttrSet::COLOR);
    let (o1, o2) = ([1.0, 2.0, 3.0], [1.5, 1.0, 3.25]);
    let (s1, s2) = (QuadricSpace::new(attrs, AttrWeights::for_extent(1.0), o1), QuadricSpace::new(attrs, AttrWeights::for_extent(1.0), o2));
    let mut m = TestMesh::new();
    m.grid(5, 5, |_, _| Vertex {
        pos: add(o1, rng.vec3(-0.5, 0.5)),
        color: [0; 4].map(|_| (rng.next() * 255.0) as u8),
        uv: [rng.next() as f32, rng.next() as f32],
        ..Vertex::default()
    });
    let mut q1 = m.quadric(&s1);
    let q2 = m.quadric(&s2);
    q1.reorigin(sub(o2, o1));
    for (a, b) in q1.coeffs().iter().zip(q2.coeffs()) {
        assert!((a - b).abs() < 1e-12 * (1.0 + b.abs()), "{a} vs {b}");
    }
    let (x1, x2) = (q1.solve(DEFAULT_REL_TOL, None), q2.solve(DEFAULT_REL_TOL, None));
    assert!(dist(&x1.x, &x2.x) < 1e-9);
}

#[test]
fn eigen_decomposition_reconstructs() {
    let mut rng = Rng::at(9);
    for trial in 0..300 {
        let n = 1 + trial % MAX_DIM;
        // A = Σ w v vᵀ over a random (possibly rank-deficient) set of vectors.
        let mut a = [[0.0; MAX_DIM]; MAX_DIM];
        let terms = 1 + trial % (n + 2);
        for _ in 0..terms {
            let v: Vec<f64> = (0..n).map(|_| rng.range(-1.0, 1.0)).collect();
            let w = rng.range(0.0, 10.0);
            for i in 0..n {
                for j in 0..n {
                    a[i][j] += w * v[i] * v[j];
                }
            }
        }
        let e = Eigen::new(&a, n);
        assert!(e.iters <= 12, "trial {trial}: {} iterations", e.iters);
        let scale = e.vals[..n].iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-300);
        for i in 0..n {
            for j in 0..n {
                let r: f64 = (0..n).map(|k| e.vecs[i][k] * e.vals[k] * e.vecs[j][k]).sum();
                assert!((r - a[i][j]).abs() < 1e-13 * scale, "trial {trial} reconstruction");
                let o: f64 = (0..n).map(|k| e.vecs[k][i] * e.vecs[k][j]).sum();
                assert!((o - (i == j) as u8 as f64).abs() < 1e-13, "trial {trial} orthogonality");
            }
        }
        let rank = e.pinv_apply(1e-9, &[1.0; MAX_DIM], &mut [0.0; MAX_DIM]);
        assert!(rank <= terms.min(n));
    }
    // Highly repeated eigenvalues: one 11-d triangle quadric (9 equal).
    let s = QuadricSpace::new(AttrSet(AttrSet::UV | AttrSet::NORMAL | AttrSet::COLOR), AttrWeights::uniform(0.7), [0.0; 3]);
    for _ in 0..100 {
        let v = [0; 3].map(|_| {
            s.embed(&Vertex {
                pos: rng.vec3(-1.0, 1.0),
                normal: rng.vec3(-1.0, 1.0).map(|c| c as f32),
                color: [0; 4].map(|_| (rng.next() * 255.0) as u8),
                uv: [rng.next() as f32, rng.next() as f32],
                material: 0,
            })
        });
        let q = Quadric::from_triangle(&s, &v[0], &v[1], &v[2]);
        let e = Eigen::new(&q.matrix(), 11);
        assert!(e.iters <= 12, "{} iterations", e.iters);
        let mut vals = e.vals;
        vals.sort_by(f64::total_cmp);
        assert!(vals[..2].iter().all(|v| v.abs() < 1e-13 * q.area()));
        assert!(vals[2..].iter().all(|v| (v - q.area()).abs() < 1e-13 * q.area()));
    }
}

fn unit3(v: [f64; 3]) -> [f64; 3] {
    let l = crate::geom::dot(v, v).sqrt();
    scale(v, 1.0 / l)
}

/// Symmetric 3×3 matrices that stress a closed-form solver: random ranks
/// 1–3, repeated eigenvalues (flat: one plane; cylinder: planes around an
/// axis; isotropic), two parallel sheets, tiny next to huge entries.
fn hard_3x3(rng: &mut Rng, trial: usize) -> [[f64; 3]; 3] {
    let mut a = [[0.0; 3]; 3];
    let add_dir = |a: &mut [[f64; 3]; 3], v: [f64; 3], w: f64| {
        for i in 0..3 {
            for j in 0..3 {
                a[i][j] += w * v[i] * v[j];
            }
        }
    };
    let axis = unit3(rng.vec3(-1.0, 1.0));
    match trial % 6 {
        // Random rank 1..3.
        0 | 1 => {
            for _ in 0..1 + trial % 3 {
                add_dir(&mut a, rng.vec3(-1.0, 1.0), rng.range(0.0, 10.0));
            }
        }
        // Flat: one plane normal, several times (rank 1, two zero eigenvalues).
        2 => {
            for _ in 0..4 {
                add_dir(&mut a, axis, rng.range(0.5, 2.0));
            }
        }
        // Cylinder: normals perpendicular to an axis (two equal eigenvalues
        // up to sampling, one zero).
        3 => {
            let u = unit3(crate::geom::cross(axis, [0.3, 0.5, 0.7]));
            let v = crate::geom::cross(axis, u);
            for k in 0..12 {
                let t = k as f64 * std::f64::consts::PI / 6.0;
                add_dir(&mut a, add(scale(u, t.cos()), scale(v, t.sin())), 1.0);
            }
        }
        // Isotropic (three equal eigenvalues) plus a nudge.
        4 => {
            for k in 0..3 {
                let mut e = [0.0; 3];
                e[k] = 1.0;
                add_dir(&mut a, e, 3.0);
            }
            add_dir(&mut a, axis, 1e-9 * (trial % 5) as f64);
        }
        // Near rank 1 at a huge scale with a tiny second direction (two
        // near-parallel sheets' planes).
        _ => {
            add_dir(&mut a, axis, 1e12);
            let tilt = unit3(add(axis, scale(rng.vec3(-1.0, 1.0), 1e-7)));
            add_dir(&mut a, tilt, 1e12);
        }
    }
    a
}

#[test]
fn closed_form_3x3_eigen_is_orthonormal_and_reconstructs() {
    let mut rng = Rng::at(31);
    for trial in 0..3000 {
        let a = hard_3x3(&mut rng, trial);
        let (vals, vecs) = eigen::eigen3(&a);
        let scale = a.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-300);
        for i in 0..3 {
            for j in 0..3 {
                let r: f64 = (0..3).map(|k| vecs[i][k] * vals[k] * vecs[j][k]).sum();
                assert!((r - a[i][j]).abs() < 1e-12 * scale, "trial {trial} reconstruction: {r} vs {}", a[i][j]);
                let o: f64 = (0..3).map(|k| vecs[k][i] * vecs[k][j]).sum();
                assert!((o - (i == j) as u8 as f64).abs() < 1e-12, "trial {trial} orthogonality");
            }
        }
        // Same eigenvalues as the general decomposition.
        let mut big = [[0.0; MAX_DIM]; MAX_DIM];
        for i in 0..3 {
            big[i][..3].copy_from_slice(&a[i]);
        }
        let e = Eigen::new(&big, 3);
        let mut jv = [e.vals[0], e.vals[1], e.vals[2]];
        jv.sort_by(f64::total_cmp);
        let mut vals = vals;
        vals.sort_by(f64::total_cmp);
        for k in 0..3 {
            assert!((jv[k] - vals[k]).abs() < 1e-12 * scale, "trial {trial}: {jv:?} vs {vals:?}");
        }
    }
    // Zero and diagonal matrices, and one that is not finite.
    assert_eq!(eigen::eigen3(&[[0.0; 3]; 3]).0, [0.0; 3]);
    assert_eq!(eigen::eigen3(&[[2.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 5.0]]).0, [2.0, -1.0, 5.0]);
    // A rotation of diag(0, 0, 7) and of diag(1e-30, 1, 1): exact ranks survive.
    let (vals, _) = eigen::eigen3(&[[7.0 / 3.0; 3]; 3]);
    let mut vals = vals;
    vals.sort_by(f64::total_cmp);
    assert!(vals[0].abs() < 1e-14 && vals[1].abs() < 1e-14 && (vals[2] - 7.0).abs() < 1e-14, "{vals:?}");
    assert!(eigen::eigen3(&[[f64::NAN, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]).0.iter().all(|v| v.is_nan()));
}

/// The sized solve (closed-form eigen at dimension 3) minimises like the
/// general one on rank-deficient, far-off-origin and attribute quadrics,
/// and leaves clamping to it.
#[test]
fn sized_solve_matches_the_general_solve() {
    let mut rng = Rng::at(77);
    let check = |q: &Quadric, lo: [f64; 3], hi: [f64; 3], what: &str| {
        let k = q.coeffs();
        let general = q.solve(DEFAULT_REL_TOL, Some((lo, hi)));
        let sized = match q.dim() {
            3 => solve_sized::<3>(k, DEFAULT_REL_TOL, (lo, hi)).map(|(x, g, e)| (x.to_vec(), g.to_vec(), e)),
            5 => solve_sized::<5>(k, DEFAULT_REL_TOL, (lo, hi)).map(|(x, g, e)| (x.to_vec(), g.to_vec(), e)),
            6 => solve_sized::<6>(k, DEFAULT_REL_TOL, (lo, hi)).map(|(x, g, e)| (x.to_vec(), g.to_vec(), e)),
            8 => solve_sized::<8>(k, DEFAULT_REL_TOL, (lo, hi)).map(|(x, g, e)| (x.to_vec(), g.to_vec(), e)),
            9 => solve_sized::<9>(k, DEFAULT_REL_TOL, (lo, hi)).map(|(x, g, e)| (x.to_vec(), g.to_vec(), e)),
            11 => solve_sized::<11>(k, DEFAULT_REL_TOL, (lo, hi)).map(|(x, g, e)| (x.to_vec(), g.to_vec(), e)),
            _ => unreachable!(),
        };
        match sized {
            None => assert!(general.clamped, "{what}: sized gave up on an unclamped solve"),
            Some((x, g, e)) => {
                assert!(!general.clamped, "{what}: sized kept a clamped solve");
                let n = q.dim();
                let size = (0..3).map(|k| hi[k] - lo[k]).fold(0.0, f64::max);
                for i in 0..n {
                    assert!((x[i] - general.x[i]).abs() <= 1e-9 * size.max(1.0), "{what}: x {x:?} vs {:?}", &general.x[..n]);
                }
                let hg = q.half_gradient(&general.x);
                // Both are ~0 at a minimiser: compared at the scale of their terms.
                let big = |s: &[f64]| s.iter().fold(0.0f64, |m, v| m.max(v.abs()));
                let al = n * (n + 1) / 2;
                let gs = big(&k[al..al + n]) + big(&k[..al]) * big(&general.x[..n]);
                for i in 0..n {
                    assert!((g[i] - hg[i]).abs() <= 1e-9 * gs, "{what}: gradient {g:?} vs {:?}", &hg[..n]);
                }
                let es = k[al + n].abs() + gs * big(&general.x[..n]);
                assert!((e - general.error).abs() <= 1e-9 * general.error + 1e-12 * es, "{what}: error {e} vs {}", general.error);
            }
        }
    };
    let s3 = QuadricSpace::new(AttrSet(0), AttrWeights::uniform(1.0), [0.0; 3]);
    for trial in 0..600 {
        // Triangles of a flat patch, a cylinder, two parallel sheets, or random,
        // around a centre far from the origin or not.
        let far = if trial % 2 == 0 { 0.0 } else { 1e6 };
        let c = rng.vec3(-1.0, 1.0);
        let mut q = Quadric::zero(3);
        let pt = |rng: &mut Rng, kind: usize| -> [f64; 3] {
            let p = rng.vec3(-0.1, 0.1);
            let p = match kind {
                0 => [p[0], p[1], 0.0],
                1 => {
                    let t = p[0] * 10.0;
                    [t.cos() * 0.1, t.sin() * 0.1, p[2]]
                }
                2 => [p[0], p[1], if rng.next() < 0.5 { 0.0 } else { 1e-4 }],
                _ => p,
            };
            add(add(p, c), [far; 3])
        };
        for _ in 0..1 + trial % 7 {
            let kind = trial % 4;
            let v = [pt(&mut rng, kind), pt(&mut rng, kind), pt(&mut rng, kind)];
            let e = v.map(|p| s3.embed(&Vertex { pos: [p[0] - far, p[1] - far, p[2] - far], ..Default::default() }));
            q.add_triangle(&e[0], &e[1], &e[2]);
            for p in &e {
                q.add_point(p);
            }
        }
        let m = q.mean();
        let half = if trial % 5 == 0 { 1e-3 } else { 1.0 };
        check(&q, [m[0] - half, m[1] - half, m[2] - half], [m[0] + half, m[1] + half, m[2] + half], &format!("dim 3 trial {trial}"));
    }
    for (attrs, trials) in [
        (AttrSet(AttrSet::UV), 200),
        (AttrSet(AttrSet::NORMAL), 200),
        (AttrSet(AttrSet::UV | AttrSet::COLOR), 100),
        (AttrSet(AttrSet::NORMAL | AttrSet::COLOR), 100),
        (AttrSet(AttrSet::UV | AttrSet::NORMAL | AttrSet::COLOR), 100),
    ] {
        let s = QuadricSpace::new(attrs, AttrWeights::uniform(0.5), [0.0; 3]);
        for trial in 0..trials {
            let mut q = Quadric::zero(s.dim);
            for _ in 0..1 + trial % 5 {
                let v = [0; 3].map(|_| {
                    s.embed(&Vertex {
                        pos: rng.vec3(-1.0, 1.0),
                        normal: unit3(rng.vec3(-1.0, 1.0)).map(|c| c as f32),
                        uv: [rng.next() as f32, rng.next() as f32],
                        color: [0; 4].map(|_| (rng.next() * 255.0) as u8),
                        material: 0,
                    })
                });
                q.add_triangle(&v[0], &v[1], &v[2]);
                for p in &v {
                    q.add_point(p);
                }
            }
            check(&q, [-2.0; 3], [2.0; 3], &format!("dim {} trial {trial}", s.dim));
        }
    }
}

/// Eliminating the attributes gives min over them at every position, and
/// [`attrs_at`] finds that minimum: on random uv + colour quadrics (dim 8)
/// of a few triangles, at random positions.
#[test]
fn eliminated_attributes_are_their_minimum_at_every_position() {
    let space = QuadricSpace::new(AttrSet(AttrSet::UV | AttrSet::COLOR), AttrWeights::uniform(1.0), [0.0; 3]);
    let dim = space.dim;
    assert_eq!(dim, 8);
    let mut rng = Rng::at(91);
    for case in 0..20 {
        let mut q = Quadric::zero(dim);
        for _ in 0..3 {
            let pts: Vec<[f64; MAX_DIM]> = (0..3)
                .map(|_| {
                    let mut x = [0.0; MAX_DIM];
                    for k in 0..dim {
                        x[k] = rng.range(-1.0, 1.0);
                    }
                    x
                })
                .collect();
            q.add_triangle(&pts[0], &pts[1], &pts[2]);
            q.add_point(&pts[0]);
        }
        let mut k = q.coeffs().to_vec();
        eliminate_attrs(dim, &mut k, 1e-9);
        let e = Quadric::from_coeffs(dim, &k);
        for _ in 0..5 {
            let p = rng.vec3(-1.0, 1.0);
            let x = attrs_at(dim, q.coeffs(), p, 1e-9);
            assert_eq!(&x[..3], &p[..]);
            let best = q.error(&x);
            let mut px = [0.0; MAX_DIM];
            px[..3].copy_from_slice(&p);
            // Q'(p) (attributes ignored: their rows are zero) = min_s Q(p, s).
            let reduced = e.error(&px);
            assert!((reduced - best).abs() <= 1e-9 * (1.0 + best), "case {case}: {reduced} vs {best}");
            // And it is a minimum: moving an attribute costs.
            for d in 3..dim {
                let mut y = x;
                y[d] += 1e-3;
                assert!(q.error(&y) >= best - 1e-12, "case {case}: attribute {d} not at its minimum");
            }
        }
    }
}

/// The attribute-eliminating solve ([`schur_pinv`]) is the exact inverse
/// where A is well conditioned (same step as the full pseudo-inverse), is
/// taken on curved patches with normals and colours (the common case it
/// speeds up), keeps a flat patch's in-plane position at the mean, and
/// gives way to the full decomposition when the attribute block is
/// singular.
#[test]
fn schur_solve_matches_the_full_pseudo_inverse() {
    let mut rng = Rng::at(31);
    let s = QuadricSpace::new(AttrSet(AttrSet::NORMAL | AttrSet::COLOR), AttrWeights::uniform(0.3), [0.0; 3]);
    let n = s.dim;
    let mut compared = 0;
    for trial in 0..200 {
        // A cap of a sphere of radius 1..4, curved enough or not, with
        // normals from the sphere and colours varying over it.
        let (radius, spread) = (rng.range(1.0, 4.0), rng.range(0.05, 0.6));
        let vert = |rng: &mut Rng| {
            let d = unit3([rng.range(-spread, spread), rng.range(-spread, spread), 1.0]);
            let c = [0; 4].map(|_| (rng.next() * 255.0) as u8);
            Vertex { pos: scale(d, radius), normal: d.map(|c| c as f32), color: c, uv: [0.0; 2], material: 0 }
        };
        let mut q = Quadric::zero(n);
        for _ in 0..12 {
            let v = [0; 3].map(|_| s.embed(&vert(&mut rng)));
            q.add_triangle(&v[0], &v[1], &v[2]);
            q.add_point(&v[0]);
        }
        let a = q.matrix();
        let mean = q.mean();
        let rhs = half_gradient_at(&a, q.b(), &mean, n).map(|g| -g);
        let mut schur = [0.0; MAX_DIM];
        let rank = schur_pinv(&a, n, DEFAULT_REL_TOL, &rhs, &mut schur).unwrap_or_else(|| panic!("trial {trial}: attribute block singular"));
        let eig = Eigen::new(&a, n);
        let mut full = [0.0; MAX_DIM];
        let full_rank = eig.pinv_apply(DEFAULT_REL_TOL, &rhs, &mut full);
        let lmax = eig.vals[..n].iter().fold(0.0f64, |m, &v| m.max(v));
        let lmin = eig.vals[..n].iter().fold(f64::INFINITY, |m, &v| m.min(v));
        if lmin > 1e-2 * lmax {
            // Well conditioned: both are A⁻¹ r.
            assert_eq!((rank, full_rank), (n, n), "trial {trial}");
            let scale = full[..n].iter().fold(1e-12f64, |m, v| m.max(v.abs()));
            assert!(dist(&schur[..n], &full[..n]) < 1e-9 * scale, "trial {trial}: {:?} vs {:?}", &schur[..n], &full[..n]);
            compared += 1;
        }
        // Either way the step solves the attribute rows exactly (the
        // attributes are optimal for the position).
        let x: Vec<f64> = (0..n).map(|i| mean[i] + schur[i]).collect();
        let g = q.half_gradient(&x);
        let gs = (0..n).map(|i| q.b()[i].abs() + (0..n).map(|j| (a[i][j] * x[j]).abs()).sum::<f64>()).fold(0.0, f64::max);
        assert!(g[3..n].iter().all(|v| v.abs() < 1e-10 * gs), "trial {trial}: attribute gradient {:?}", &g[3..n]);
    }
    assert!(compared >= 20, "only {compared} well-conditioned trials");
    // A flat patch with a colour ramp: the Schur complement is rank one,
    // the in-plane position stays at the mean.
    let mut q = Quadric::zero(n);
    for _ in 0..10 {
        let v = [0; 3].map(|_| {
            let (x, y) = ((rng.next() * 255.0).round(), (rng.next() * 255.0).round());
            let c = [x as u8, y as u8, 60, 255];
            s.embed(&Vertex { pos: [x / 255.0, y / 255.0, 0.5], normal: [0.0, 0.0, 1.0], color: c, uv: [0.0; 2], material: 0 })
        });
        q.add_triangle(&v[0], &v[1], &v[2]);
        q.add_point(&v[1]);
    }
    let sol = q.solve(DEFAULT_REL_TOL, None);
    assert_eq!(sol.rank, 1 + n - 3);
    let m = q.mean();
    assert!(dist(&sol.x[..2], &m[..2]) < 1e-12 && (sol.x[2] - 0.5).abs() < 1e-12, "{:?}", &sol.x[..3]);
    // One tiny triangle whose colour changes across it: its plane in R^n
    // is nearly all colour, so its attribute block is nearly singular (the
    // colour's in-plane directions cost almost nothing) and the full
    // decomposition answers, with rank n − 2.
    let v = [([0.0, 0.0, 0.0], [9, 200, 40, 255]), ([1e-3, 0.0, 0.0], [250, 20, 40, 255]), ([0.0, 1e-3, 0.0], [9, 10, 240, 255])]
        .map(|(p, c)| s.embed(&Vertex { pos: p, normal: [0.3, 0.1, 0.9], color: c, uv: [0.0; 2], material: 0 }));
    let one = Quadric::from_triangle(&s, &v[0], &v[1], &v[2]);
    assert!(schur_pinv(&one.matrix(), n, DEFAULT_REL_TOL, &[1.0; MAX_DIM], &mut [0.0; MAX_DIM]).is_none());
    assert_eq!(one.solve(DEFAULT_REL_TOL, None).rank, n - 2);
}

/// Random embedded points of dimension `n` (attributes in ±1).
fn random_point(rng: &mut Rng, n: usize) -> [f64; MAX_DIM] {
    let mut x = [0.0; MAX_DIM];
    for v in x[..n].iter_mut() {
        *v = rng.range(-1.0, 1.0);
    }
    x
}

#[test]
fn triangle_matrix_is_add_triangles_matrix_bit_for_bit() {
    let mut rng = Rng::at(17);
    for n in [3, 4, 5, 6, 8, 9, 11] {
        for trial in 0..300 {
            let mut t = [0; 3].map(|_| random_point(&mut rng, n));
            match trial % 10 {
                // Degenerate: a repeated corner, collinear corners, a NaN.
                0 => t[2] = t[0],
                1 => {
                    for k in 0..n {
                        t[2][k] = 0.5 * (t[0][k] + t[1][k]);
                    }
                }
                2 => t[1][0] = f64::NAN,
                _ => {}
            }
            let mut q = Quadric::zero(n);
            q.add_triangle(&t[0], &t[1], &t[2]);
            let mut m = [f64::INFINITY; MAX_COEFFS];
            let added = triangle_matrix(n, &t[0], &t[1], &t[2], &mut m);
            assert_eq!(added, q.area() > 0.0, "dim {n} trial {trial}");
            if added {
                let bits = |s: &[f64]| s.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&m[..a_len(n)]), bits(q.matrix_packed()), "dim {n} trial {trial}");
            } else {
                assert!(m.iter().all(|v| *v == f64::INFINITY), "untouched");
            }
        }
    }
}

#[test]
fn sized_packed_kernels_match_the_general_loops() {
    let mut rng = Rng::at(23);
    for n in [3, 4, 5, 6, 7, 8, 9, 10, 11] {
        for _ in 0..50 {
            let t = [0; 3].map(|_| random_point(&mut rng, n));
            let mut q = Quadric::zero(n);
            q.add_triangle(&t[0], &t[1], &t[2]);
            let p = random_point(&mut rng, n);
            // `sized!` picks a constant-dimension copy; a dimension hidden
            // from the optimiser takes the general loop: the same bits.
            let hidden = std::hint::black_box(n);
            let mut fast = [0.0; MAX_COEFFS];
            let mut general = [0.0; MAX_COEFFS];
            packed_at_point(n, q.matrix_packed(), &p, 0.25, &mut fast);
            packed_at_point_n(hidden, q.matrix_packed(), &p, 0.25, &mut general);
            assert_eq!(fast.map(f64::to_bits), general.map(f64::to_bits), "dim {n}");
            // And both are `Quadric::at_point`'s values.
            let reference = Quadric::at_point(n, q.matrix_packed(), &p, 0.25);
            for (a, b) in fast[..Quadric::coeff_len(n)].iter().zip(reference.coeffs()) {
                assert!((a - b).abs() <= 1e-12 * (1.0 + b.abs()), "dim {n}: {a} vs {b}");
            }
            let x = random_point(&mut rng, n);
            assert_eq!(packed_value(&fast, n, &x).to_bits(), packed_value_n(hidden, &fast, &x).to_bits(), "dim {n}");
            let mean = packed_error_at_mean(n, &fast);
            assert!((mean - reference.error(&reference.mean())).abs() <= 1e-12 * (1.0 + mean.abs()), "dim {n}");
        }
    }
}

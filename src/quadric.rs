//! Generalized quadric error metric (Garland & Heckbert 1998, "Simplifying
//! surfaces with color and texture using quadric error metrics") for vertex
//! clustering.
//!
//! Takes: triangles and vertices of one cluster (cell), embedded as points of
//! R^n by a [`QuadricSpace`]. Gives: the accumulated [`Quadric`] and its
//! minimiser ([`Quadric::solve`]), decoded back into a [`Vertex`].
//!
//! # Space
//! A vertex is a point of R^n, n = [`AttrSet::quadric_dim`]: position (3,
//! *local* to the space's `origin`, normally the cell centre, so that a mesh at
//! 1e6 with 1e-3 detail keeps its precision), then uv (2) if present, normal
//! (3) if present, color rgb (3, as `u8 / 255`) if present, in that order.
//! Alpha is not modelled. Attribute coordinates are multiplied by
//! [`AttrWeights`] so that they are commensurate with positions (see
//! [`AttrWeights::for_extent`]) and divided again when decoding.
//!
//! # Quadric
//! For a triangle p, q, r of R^n with orthonormal in-plane frame e1, e2:
//! `A = I − e1e1ᵀ − e2e2ᵀ`, `b = −A p`, `c = pᵀA p`, so that
//! `Q(v) = vᵀAv + 2bᵀv + c` is the squared distance of v from the triangle's
//! plane in R^n. Each triangle is weighted by its area *in position space*;
//! triangles whose position area is zero (duplicate or collinear corners) or
//! that hold a non-finite coordinate contribute nothing. Everything is
//! accumulated in f64.
//!
//! # Memory
//! A [`Quadric`] is a fixed-capacity, heap-free struct (736 bytes whatever the
//! dimension) whose coefficients are packed at the front of one array; every
//! loop is bounded by the dimension, so a position-only quadric costs 15 adds,
//! not 91. For large per-cell tables, store only the live coefficients
//! ([`Quadric::coeffs`], [`Quadric::from_coeffs`], [`Quadric::add_into`]):
//!
//! | dim | attributes            | paper coefficients (A, b, c) | stored f64 | packed bytes |
//! |-----|-----------------------|------------------------------|-----------:|-------------:|
//! | 3   | position              | 6 + 3 + 1 = 10               | 15         | 120          |
//! | 5   | + uv                  | 15 + 5 + 1 = 21              | 28         | 224          |
//! | 6   | + normal *or* color   | 21 + 6 + 1 = 28              | 36         | 288          |
//! | 8   | + uv + normal/color   | 36 + 8 + 1 = 45              | 55         | 440          |
//! | 9   | + normal + color      | 45 + 9 + 1 = 55              | 66         | 528          |
//! | 11  | + uv + normal + color | 66 + 11 + 1 = 78             | 91         | 728          |
//!
//! "Stored" adds the total area, the sum of the cluster's embedded points (n)
//! and their count, used for the mean: `(n+1)(n+2)/2 + n + 2` values.
//!
//! # Solve
//! The minimiser uses a symmetric eigen-decomposition of A (cyclic Jacobi,
//! accurate to working precision for these ≤ 11×11 PSD matrices, no heap) and
//! a pseudo-inverse that drops eigenvalues below `rel_tol` times the largest.
//! The minimum-norm correction is taken about the cluster mean m:
//! `x = m + A⁺(−b − A m)`, so rank-deficient directions (along a flat sheet,
//! along a crease) stay at the mean, as in Lindstrom's / VTK's quadric
//! clustering. If cell bounds are given and the position falls outside them,
//! the position is re-optimised inside the box (exact minimisation of the
//! quadric, with attributes at their optimum for each position, over the
//! box's faces, edges and corners) and the solution is flagged `clamped`.
// Index loops mirror the formulas; negated comparisons are deliberate
// (`!(x > 0.0)` is also true for NaN).
#![allow(clippy::needless_range_loop, clippy::neg_cmp_op_on_partial_ord)]

use crate::mesh::{Aabb, AttrSet, Vertex};

/// Largest quadric dimension: position 3 + uv 2 + normal 3 + color 3.
pub const MAX_DIM: usize = 11;

/// Stored coefficients for [`MAX_DIM`]: see [`Quadric::coeff_len`].
pub const MAX_COEFFS: usize = MAX_DIM * (MAX_DIM + 1) / 2 + 2 * MAX_DIM + 3;

/// Default relative eigenvalue cut-off of [`Quadric::solve`].
pub const DEFAULT_REL_TOL: f64 = 1e-3;

/// Triangles with area ≤ this × (longest edge)², i.e. height ≤ ~2.3e-13 ×
/// longest edge (a thousand ulps), are degenerate and contribute nothing.
const DEGENERATE_REL_AREA: f64 = 1024.0 * f64::EPSILON;

/// Smallest relative cut-off actually used (below it, roundoff-level
/// eigenvalues would be inverted).
const MIN_REL_TOL: f64 = 1e-12;

/// Scales applied to attribute coordinates before they enter the quadric
/// (positions are never scaled). A weight ≤ 0 or non-finite switches the
/// attribute off: its coordinates are 0 and decoding takes the template's.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AttrWeights {
    /// Multiplies u and v (usually in 0..1).
    pub uv: f64,
    /// Multiplies the unit normal's components.
    pub normal: f64,
    /// Multiplies r, g, b in 0..1 (`u8 / 255`).
    pub color: f64,
}

impl AttrWeights {
    /// Fraction of the extent used by [`AttrWeights::for_extent`].
    pub const EXTENT_FRACTION: f64 = 0.1;

    /// The same weight for every attribute.
    pub fn uniform(w: f64) -> AttrWeights {
        AttrWeights { uv: w, normal: w, color: w }
    }

    /// Weights for a cell (or mesh) whose bounding-box diagonal is `diag`:
    /// every attribute weight is `diag * 0.1` ([`Self::EXTENT_FRACTION`]).
    /// A full color swing (0 → 1) or a full uv swing then counts like a
    /// positional offset of a tenth of the diagonal, and a 90° normal change
    /// (|Δn| = √2) like 0.14 diagonals, so attribute discontinuities inform
    /// the solution without dominating the geometry. A non-finite or zero
    /// `diag` gives weight 0.1.
    pub fn for_extent(diag: f64) -> AttrWeights {
        let d = if diag.is_finite() && diag != 0.0 { diag.abs() } else { 1.0 };
        AttrWeights::uniform(d * Self::EXTENT_FRACTION)
    }
}

impl Default for AttrWeights {
    /// Unit weights.
    fn default() -> Self {
        AttrWeights::uniform(1.0)
    }
}

#[inline]
fn live(w: f64) -> bool {
    w.is_finite() && w > 0.0
}

/// How vertices map into R^n: which attributes, their weights, and the local
/// origin subtracted from positions.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct QuadricSpace {
    pub attrs: AttrSet,
    /// `attrs.quadric_dim()`.
    pub dim: usize,
    pub weights: AttrWeights,
    /// World position of the local origin (normally the cell centre).
    pub origin: [f64; 3],
}

impl QuadricSpace {
    pub fn new(attrs: AttrSet, weights: AttrWeights, origin: [f64; 3]) -> QuadricSpace {
        QuadricSpace { attrs, dim: attrs.quadric_dim(), weights, origin }
    }

    /// Offset of uv in an embedded point, if the space has uvs.
    pub fn uv_at(&self) -> Option<usize> {
        self.attrs.uv().then_some(3)
    }
    /// Offset of the normal in an embedded point, if the space has normals.
    pub fn normal_at(&self) -> Option<usize> {
        self.attrs.normal().then_some(3 + 2 * self.attrs.uv() as usize)
    }
    /// Offset of rgb in an embedded point, if the space has colors.
    pub fn color_at(&self) -> Option<usize> {
        self.attrs.color().then_some(3 + 2 * self.attrs.uv() as usize + 3 * self.attrs.normal() as usize)
    }

    /// World position → local coordinates.
    #[inline]
    pub fn to_local(&self, p: [f64; 3]) -> [f64; 3] {
        [p[0] - self.origin[0], p[1] - self.origin[1], p[2] - self.origin[2]]
    }

    /// Local coordinates → world position.
    #[inline]
    pub fn to_world(&self, x: [f64; 3]) -> [f64; 3] {
        [x[0] + self.origin[0], x[1] + self.origin[1], x[2] + self.origin[2]]
    }

    /// A world box in local coordinates, as `bounds` for [`Quadric::solve`].
    pub fn local_bounds(&self, b: &Aabb) -> ([f64; 3], [f64; 3]) {
        (self.to_local(b.min), self.to_local(b.max))
    }

    /// The vertex as a point of R^n (first `dim` entries; the rest are 0).
    #[inline]
    pub fn embed(&self, v: &Vertex) -> [f64; MAX_DIM] {
        let mut x = [0.0; MAX_DIM];
        x[..3].copy_from_slice(&self.to_local(v.pos));
        let w = &self.weights;
        let mut i = 3;
        if self.attrs.uv() {
            if live(w.uv) {
                x[i] = v.uv[0] as f64 * w.uv;
                x[i + 1] = v.uv[1] as f64 * w.uv;
            }
            i += 2;
        }
        if self.attrs.normal() {
            if live(w.normal) {
                for k in 0..3 {
                    x[i + k] = v.normal[k] as f64 * w.normal;
                }
            }
            i += 3;
        }
        if self.attrs.color() && live(w.color) {
            for k in 0..3 {
                x[i + k] = v.color[k] as f64 * (w.color / 255.0);
            }
        }
        x
    }

    /// A point of R^n back to a vertex: position plus origin; uv unscaled;
    /// normal unscaled and renormalised; color unscaled, rounded and clamped
    /// to 0..=255. Alpha, attributes the space lacks, and attributes that
    /// cannot be decoded (zero weight, zero-length normal, non-finite) come
    /// from `template`.
    pub fn unembed(&self, x: &[f64], template: &Vertex) -> Vertex {
        let mut v = *template;
        v.pos = self.to_world([x[0], x[1], x[2]]);
        let w = &self.weights;
        if let (Some(i), true) = (self.uv_at(), live(w.uv)) {
            let uv = [x[i] / w.uv, x[i + 1] / w.uv];
            if uv.iter().all(|c| c.is_finite()) {
                v.uv = uv.map(|c| c as f32);
            }
        }
        if let (Some(i), true) = (self.normal_at(), live(w.normal)) {
            let n = [x[i] / w.normal, x[i + 1] / w.normal, x[i + 2] / w.normal];
            let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            if len.is_finite() && len > 1e-12 {
                v.normal = n.map(|c| (c / len) as f32);
            }
        }
        if let (Some(i), true) = (self.color_at(), live(w.color)) {
            for k in 0..3 {
                let c = x[i + k] * (255.0 / w.color);
                if !c.is_nan() {
                    v.color[k] = c.round().clamp(0.0, 255.0) as u8;
                }
            }
        }
        v
    }
}

/// [`Quadric::at_point`] written straight into stored coefficients
/// (`out.len() ≥ coeff_len(dim)`, overwritten): no struct, no copies — the
/// form hot loops use.
pub fn packed_at_point(dim: usize, a: &[f64], p: &[f64], area: f64, out: &mut [f64]) {
    let al = a_len(dim);
    out[..al].copy_from_slice(&a[..al]);
    let mut ap = [0.0; MAX_DIM];
    let mut k = 0;
    for i in 0..dim {
        for j in i..dim {
            let v = a[k];
            ap[i] += v * p[j];
            if j != i {
                ap[j] += v * p[i];
            }
            k += 1;
        }
    }
    let mut c = 0.0;
    for i in 0..dim {
        out[al + i] = -ap[i];
        c += ap[i] * p[i];
    }
    out[al + dim] = c;
    out[al + dim + 1] = area;
    let s = al + dim + 2;
    out[s..s + dim].copy_from_slice(&p[..dim]);
    out[s + dim] = 1.0;
}

/// `Q(mean)` of stored coefficients (mean of the added points; 0 without
/// points), clamped to ≥ 0: [`Quadric::error`] at [`Quadric::mean`]
/// without building a [`Quadric`].
pub fn packed_error_at_mean(dim: usize, k: &[f64]) -> f64 {
    let al = a_len(dim);
    let s = al + dim + 2;
    let cnt = k[s + dim];
    if !(cnt > 0.0) {
        return k[al + dim].max(0.0);
    }
    let mut x = [0.0; MAX_DIM];
    for i in 0..dim {
        x[i] = k[s + i] / cnt;
    }
    let mut e = 0.0;
    let mut at = 0;
    for i in 0..dim {
        let mut row = 0.5 * k[at] * x[i];
        at += 1;
        for j in i + 1..dim {
            row += k[at] * x[j];
            at += 1;
        }
        e += 2.0 * x[i] * row;
    }
    for i in 0..dim {
        e += 2.0 * k[al + i] * x[i];
    }
    e += k[al + dim];
    if e > 0.0 && e.is_finite() {
        e
    } else {
        0.0
    }
}

/// Minimiser found by [`Quadric::solve`], in local embedded coordinates
/// (decode with [`QuadricSpace::unembed`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Solution {
    /// First `dim` entries used; the rest are 0.
    pub x: [f64; MAX_DIM],
    /// Rank of A kept by the pseudo-inverse (0 for an empty quadric: x is
    /// then the mean).
    pub rank: usize,
    /// The unconstrained minimiser's position was outside the bounds; `x` is
    /// the best point inside them.
    pub clamped: bool,
    /// `Q(x)`.
    pub error: f64,
}

/// Accumulated generalized quadric of one cluster, plus the total triangle
/// area and the sum and count of the cluster's embedded points (for the mean).
///
/// Layout of the live coefficients (`coeff_len(dim)` f64): A packed
/// upper-triangular row-major (`dim(dim+1)/2`), b (`dim`), c, area, point sum
/// (`dim`), point count.
#[derive(Clone)]
pub struct Quadric {
    dim: usize,
    k: [f64; MAX_COEFFS],
}

#[inline]
const fn a_len(n: usize) -> usize {
    n * (n + 1) / 2
}

/// Values a vertex carries from level to level (see [`crate::lod`]): its
/// quadric about its own position `p`, `Q(x) = (x−p)ᵀA(x−p) + 2gᵀ(x−p) + e`
/// — the packed matrix A, the half-gradient g = ∇Q(p)/2 and the residual
/// e = Q(p). Relative to `p`, so far from the origin nothing cancels.
pub const fn carry_len(dim: usize) -> usize {
    a_len(dim) + dim + 1
}

type Mat = [[f64; MAX_DIM]; MAX_DIM];

impl Quadric {
    /// Number of stored f64 for a dimension: `(n+1)(n+2)/2 + n + 2`
    /// (15 for 3, 28 for 5, 36 for 6, 55 for 8, 66 for 9, 91 for 11).
    pub const fn coeff_len(dim: usize) -> usize {
        a_len(dim) + 2 * dim + 3
    }

    /// The empty quadric (Q ≡ 0, no area, no points).
    pub fn zero(dim: usize) -> Quadric {
        assert!((1..=MAX_DIM).contains(&dim), "quadric dimension {dim} outside 1..={MAX_DIM}");
        Quadric { dim, k: [0.0; MAX_COEFFS] }
    }

    /// The area-weighted quadric of one triangle given by embedded points
    /// (length ≥ `space.dim`, e.g. from [`QuadricSpace::embed`]).
    pub fn from_triangle(space: &QuadricSpace, p: &[f64], q: &[f64], r: &[f64]) -> Quadric {
        let mut out = Quadric::zero(space.dim);
        out.add_triangle(p, q, r);
        out
    }

    /// Rebuilds a quadric from [`Quadric::coeffs`].
    pub fn from_coeffs(dim: usize, coeffs: &[f64]) -> Quadric {
        let mut out = Quadric::zero(dim);
        let l = Self::coeff_len(dim);
        out.k[..l].copy_from_slice(&coeffs[..l]);
        out
    }

    pub fn dim(&self) -> usize {
        self.dim
    }
    /// The live coefficients (`coeff_len(dim)` values), for compact storage.
    pub fn coeffs(&self) -> &[f64] {
        &self.k[..Self::coeff_len(self.dim)]
    }
    /// Adds this quadric into stored coefficients (`acc.len() ≥ coeff_len`).
    pub fn add_into(&self, acc: &mut [f64]) {
        let l = Self::coeff_len(self.dim);
        for (a, s) in acc[..l].iter_mut().zip(&self.k[..l]) {
            *a += s;
        }
    }
    /// Sum of triangle areas (position space).
    pub fn area(&self) -> f64 {
        self.k[a_len(self.dim) + self.dim + 1]
    }
    /// Number of points added with [`Quadric::add_point`].
    pub fn count(&self) -> f64 {
        self.k[Self::coeff_len(self.dim) - 1]
    }
    /// True when no triangle area has been accumulated.
    pub fn is_empty(&self) -> bool {
        !(self.area() > 0.0)
    }
    /// Mean of the added points (all zero, i.e. the local origin, if none).
    pub fn mean(&self) -> [f64; MAX_DIM] {
        let n = self.dim;
        let mut m = [0.0; MAX_DIM];
        let cnt = self.count();
        if cnt > 0.0 {
            let s = a_len(n) + n + 2;
            for i in 0..n {
                m[i] = self.k[s + i] / cnt;
            }
            if !m.iter().all(|v| v.is_finite()) {
                m = [0.0; MAX_DIM];
            }
        }
        m
    }

    /// A, expanded to a full symmetric matrix.
    fn matrix(&self) -> Mat {
        let n = self.dim;
        let mut a = [[0.0; MAX_DIM]; MAX_DIM];
        let mut k = 0;
        for i in 0..n {
            for j in i..n {
                a[i][j] = self.k[k];
                a[j][i] = self.k[k];
                k += 1;
            }
        }
        a
    }
    fn b(&self) -> &[f64] {
        let s = a_len(self.dim);
        &self.k[s..s + self.dim]
    }

    /// The quadric `(x − p)ᵀ A (x − p)` of a point `p` (embedded, length ≥
    /// dim) carrying the packed upper-triangular matrix `a` (`dim(dim+1)/2`
    /// values, as [`Quadric::matrix_packed`] gives): zero error and zero
    /// gradient at `p`. Counts `p` once for the mean; `area` is recorded as
    /// the quadric's area.
    pub fn at_point(dim: usize, a: &[f64], p: &[f64], area: f64) -> Quadric {
        let mut q = Quadric::zero(dim);
        let al = a_len(dim);
        q.k[..al].copy_from_slice(&a[..al]);
        let full = q.matrix();
        let mut c = 0.0;
        for i in 0..dim {
            let ap: f64 = (0..dim).map(|j| full[i][j] * p[j]).sum();
            q.k[al + i] = -ap;
            c += ap * p[i];
        }
        q.k[al + dim] = c;
        q.k[al + dim + 1] = area;
        q.add_point(p);
        q
    }

    /// A cheap estimate of the minimum of Q: `Q(m) − gᵀ(A + εI)⁻¹g` with m
    /// the points' mean, g the gradient there and ε = 1e-6 × trace(A) / n
    /// (a regularised Cholesky step instead of the eigen solve). Always
    /// finite and ≥ 0; exact for full-rank A up to the regularisation.
    pub fn min_estimate(&self) -> f64 {
        let n = self.dim;
        let m = self.mean();
        let q0 = self.error(&m);
        if !(q0 > 0.0) {
            return 0.0;
        }
        let mut a = self.matrix();
        let b = self.b();
        let mut g = [0.0; MAX_DIM];
        let mut tr = 0.0;
        for i in 0..n {
            g[i] = b[i] + (0..n).map(|j| a[i][j] * m[j]).sum::<f64>();
            tr += a[i][i];
        }
        let eps = 1e-6 * tr / n as f64 + f64::MIN_POSITIVE;
        for i in 0..n {
            a[i][i] += eps;
        }
        // Cholesky in place (lower), then solve L Lᵀ y = g.
        for j in 0..n {
            let mut d = a[j][j];
            for k in 0..j {
                d -= a[j][k] * a[j][k];
            }
            if !(d > 0.0) {
                return q0;
            }
            let d = d.sqrt();
            a[j][j] = d;
            for i in j + 1..n {
                let mut v = a[i][j];
                for k in 0..j {
                    v -= a[i][k] * a[j][k];
                }
                a[i][j] = v / d;
            }
        }
        let mut y = [0.0; MAX_DIM];
        for i in 0..n {
            let mut v = g[i];
            for k in 0..i {
                v -= a[i][k] * y[k];
            }
            y[i] = v / a[i][i];
        }
        // gᵀ(A+εI)⁻¹g = |L⁻¹g|².
        let drop: f64 = y[..n].iter().map(|v| v * v).sum();
        let r = q0 - drop;
        if r.is_finite() && r > 0.0 {
            r
        } else {
            0.0
        }
    }

    /// A packed upper-triangular, row-major (`dim(dim+1)/2` values).
    pub fn matrix_packed(&self) -> &[f64] {
        &self.k[..a_len(self.dim)]
    }

    /// Adds another quadric of the same dimension.
    #[inline]
    pub fn add(&mut self, other: &Quadric) {
        assert_eq!(self.dim, other.dim, "adding quadrics of different dimensions");
        let l = Self::coeff_len(self.dim);
        for (a, s) in self.k[..l].iter_mut().zip(&other.k[..l]) {
            *a += s;
        }
    }

    /// Accumulates one embedded point of the cluster into the mean used as the
    /// solve's reference. Non-finite points are ignored.
    #[inline]
    pub fn add_point(&mut self, x: &[f64]) {
        let n = self.dim;
        let x = &x[..n];
        if !x.iter().all(|v| v.is_finite()) {
            return;
        }
        let s = a_len(n) + n + 2;
        for i in 0..n {
            self.k[s + i] += x[i];
        }
        self.k[s + n] += 1.0;
    }

    /// Adds the area-weighted quadric of triangle p, q, r (embedded points,
    /// length ≥ dim) in place; the allocation-free form of
    /// `add(&from_triangle(..))`. Triangles with zero area in position
    /// (duplicate or collinear corners, up to roundoff) or a non-finite
    /// coordinate add nothing.
    #[inline]
    pub fn add_triangle(&mut self, p: &[f64], q: &[f64], r: &[f64]) {
        let n = self.dim;
        if n == 3 {
            let (p, q, r) = (&p[..3], &q[..3], &r[..3]);
            // v * 0 is NaN exactly for non-finite v: one branch for all values.
            let probe = |s: &[f64]| s[0] * 0.0 + s[1] * 0.0 + s[2] * 0.0;
            if probe(p) + probe(q) + probe(r) != 0.0 {
                return;
            }
            if let Some((nrm, len, area)) = position_area(p, q, r) {
                self.add_plane3(p, q, r, nrm, len, area);
            }
        } else {
            let pad = |s: &[f64]| {
                let mut v = [0.0; PAD];
                v[..n].copy_from_slice(&s[..n]);
                v
            };
            let (p, q, r) = (pad(p), pad(q), pad(r));
            let zero = [0.0; PAD];
            let probe = |v: &[f64; PAD]| dot(v, &zero);
            if probe(&p) + probe(&q) + probe(&r) != 0.0 {
                return;
            }
            if let Some((_, _, area)) = position_area(&p, &q, &r) {
                self.add_triangle_general(&p, &q, &r, area);
            }
        }
    }

    /// Position-only fast path: A = w nnᵀ, b = −w (n·g) n, c = w (n·g)².
    #[inline]
    fn add_plane3(&mut self, p: &[f64], q: &[f64], r: &[f64], nrm: [f64; 3], len: f64, w: f64) {
        let il = 1.0 / len;
        let nn = [nrm[0] * il, nrm[1] * il, nrm[2] * il];
        let t = 1.0 / 3.0;
        let g = [(p[0] + q[0] + r[0]) * t, (p[1] + q[1] + r[1]) * t, (p[2] + q[2] + r[2]) * t];
        let d = dot3(nn, g);
        let k = &mut self.k;
        k[0] += w * nn[0] * nn[0];
        k[1] += w * nn[0] * nn[1];
        k[2] += w * nn[0] * nn[2];
        k[3] += w * nn[1] * nn[1];
        k[4] += w * nn[1] * nn[2];
        k[5] += w * nn[2] * nn[2];
        let wd = w * d;
        k[6] -= wd * nn[0];
        k[7] -= wd * nn[1];
        k[8] -= wd * nn[2];
        k[9] += wd * d;
        k[10] += w;
    }

    /// Any dimension (points zero-padded to [`PAD`]): Gram–Schmidt frame of
    /// the triangle in R^n, based at the longest edge.
    /// A = w (I − e1e1ᵀ − e2e2ᵀ), d = A g (g the centroid), b = −w d,
    /// c = w |d|² (A is a projector, so gᵀAg = |Ag|² ≥ 0).
    fn add_triangle_general(&mut self, p: &[f64; PAD], q: &[f64; PAD], r: &[f64; PAD], w: f64) {
        let n = self.dim;
        let (lpq, lqr, lrp) = (dist2(p, q), dist2(q, r), dist2(r, p));
        let (base, tip, third) = if lpq >= lqr && lpq >= lrp {
            (p, q, r)
        } else if lqr >= lrp {
            (q, r, p)
        } else {
            (r, p, q)
        };
        let mut e1 = [0.0; PAD];
        let mut e2 = [0.0; PAD];
        for i in 0..PAD {
            e1[i] = tip[i] - base[i];
            e2[i] = third[i] - base[i];
        }
        if !normalize(&mut e1) {
            return;
        }
        // Twice-is-enough Gram–Schmidt.
        for _ in 0..2 {
            let t = dot(&e2, &e1);
            for i in 0..PAD {
                e2[i] -= t * e1[i];
            }
        }
        if !normalize(&mut e2) {
            return;
        }
        let mut d = [0.0; PAD];
        for i in 0..PAD {
            d[i] = (p[i] + q[i] + r[i]) * (1.0 / 3.0);
        }
        let (g1, g2) = (dot(&d, &e1), dot(&d, &e2));
        for i in 0..PAD {
            d[i] -= g1 * e1[i] + g2 * e2[i];
        }
        let (mut rows, k) = self.k.split_at_mut(a_len(n));
        for i in 0..n {
            let (row, tail) = rows.split_at_mut(n - i);
            rows = tail;
            let (a1, a2) = (w * e1[i], w * e2[i]);
            row[0] += w - a1 * e1[i] - a2 * e2[i];
            for ((kk, x1), x2) in row[1..].iter_mut().zip(&e1[i + 1..n]).zip(&e2[i + 1..n]) {
                *kk -= a1 * x1 + a2 * x2;
            }
        }
        for i in 0..n {
            k[i] -= w * d[i];
        }
        k[n] += w * dot(&d, &d);
        k[n + 1] += w;
    }

    /// Re-expresses the quadric (and point sum) in a frame whose origin is the
    /// old one plus `shift` (local positions decrease by `shift`), e.g. to
    /// merge a child cell's quadric into its parent's frame.
    pub fn reorigin(&mut self, shift: [f64; 3]) {
        let n = self.dim;
        let mut s = [0.0; MAX_DIM];
        s[..3].copy_from_slice(&shift);
        // Q'(y) = Q(y + s): A' = A, b' = A s + b, c' = Q(s).
        let a = self.matrix();
        let c_new = self.error(&s);
        let bo = a_len(n);
        for i in 0..n {
            let as_i: f64 = (0..3).map(|j| a[i][j] * s[j]).sum();
            self.k[bo + i] += as_i;
        }
        self.k[bo + n] = c_new;
        let cnt = self.count();
        let so = bo + n + 2;
        for i in 0..3 {
            self.k[so + i] -= cnt * s[i];
        }
    }

    /// `Q(x) = xᵀAx + 2bᵀx + c` for an embedded point (length ≥ dim), clamped
    /// to ≥ 0 (negative values are roundoff).
    /// Half the gradient at `x`: `A x + b`.
    pub fn half_gradient(&self, x: &[f64]) -> [f64; MAX_DIM] {
        let a = self.matrix();
        let b = self.b();
        let mut g = [0.0; MAX_DIM];
        for i in 0..self.dim {
            g[i] = b[i] + (0..self.dim).map(|j| a[i][j] * x[j]).sum::<f64>();
        }
        g
    }

    pub fn error(&self, x: &[f64]) -> f64 {
        let n = self.dim;
        let x = &x[..n];
        let mut s = 0.0;
        let mut at = 0;
        for i in 0..n {
            let mut row = 0.5 * self.k[at] * x[i];
            at += 1;
            for j in i + 1..n {
                row += self.k[at] * x[j];
                at += 1;
            }
            s += 2.0 * x[i] * row;
        }
        for i in 0..n {
            s += 2.0 * self.k[at + i] * x[i];
        }
        s += self.k[at + n];
        if s < 0.0 {
            0.0
        } else {
            s
        }
    }

    /// Minimiser of Q: rank-revealing eigen solve about the cluster mean m,
    /// `x = m + A⁺(−b − A m)`, dropping eigenvalues below `rel_tol` times the
    /// largest (`rel_tol` is floored at 1e-12; [`DEFAULT_REL_TOL`] = 1e-3).
    ///
    /// With `bounds = Some((lo, hi))` (local coordinates, normally the cell
    /// box) the position is kept inside the box: if the unconstrained
    /// minimiser is outside, the quadric (with attributes at their optimum
    /// for each position) is minimised over the box and `clamped` is set.
    /// The result is always finite and, with bounds, within them.
    pub fn solve(&self, rel_tol: f64, bounds: Option<([f64; 3], [f64; 3])>) -> Solution {
        let n = self.dim;
        let rel_tol = if rel_tol.is_finite() { rel_tol.max(MIN_REL_TOL) } else { DEFAULT_REL_TOL };
        let mean = self.mean();
        let a = self.matrix();
        let b = self.b();
        let mut x = mean;
        let mut rank = 0;
        if !self.is_empty() {
            let mut rhs = [0.0; MAX_DIM];
            for i in 0..n {
                rhs[i] = -b[i] - (0..n).map(|j| a[i][j] * mean[j]).sum::<f64>();
            }
            let eig = Eigen::new(&a, n);
            let mut dx = [0.0; MAX_DIM];
            rank = eig.pinv_apply(rel_tol, &rhs, &mut dx);
            for i in 0..n {
                x[i] += dx[i];
            }
            if !x.iter().all(|v| v.is_finite()) {
                x = mean;
                rank = 0;
            }
        }
        let Some((lo, hi)) = bounds else {
            return Solution { x, rank, clamped: false, error: self.error(&x) };
        };
        let (lo, hi) = ([0, 1, 2].map(|k| lo[k].min(hi[k])), [0, 1, 2].map(|k| lo[k].max(hi[k])));
        if (0..3).all(|k| x[k] >= lo[k] && x[k] <= hi[k]) {
            return Solution { x, rank, clamped: false, error: self.error(&x) };
        }
        if rank > 0 {
            x = self.box_minimise(&a, &mean, &x, lo, hi, rel_tol);
        }
        for k in 0..3 {
            x[k] = clamp(x[k], lo[k], hi[k]);
        }
        if !x.iter().all(|v| v.is_finite()) {
            x = mean;
            for k in 0..3 {
                x[k] = clamp(x[k], lo[k], hi[k]);
            }
        }
        Solution { x, rank, clamped: true, error: self.error(&x) }
    }

    /// Minimises Q over positions in the box [lo, hi], with attributes at
    /// their conditional optimum `xa(y) = u + M y` for position y. The reduced
    /// quadric in y is minimised exactly on each of the box's 27 faces (the
    /// interior, 6 faces, 12 edges, 8 corners); the best feasible candidate
    /// wins, with the clamped unconstrained minimiser and the clamped mean as
    /// extra (always feasible) candidates.
    fn box_minimise(
        &self,
        a: &Mat,
        mean: &[f64; MAX_DIM],
        xstar: &[f64; MAX_DIM],
        lo: [f64; 3],
        hi: [f64; 3],
        rel_tol: f64,
    ) -> [f64; MAX_DIM] {
        let n = self.dim;
        let na = n - 3;
        let b = self.b();
        // Attribute response to position: u (na) and M (na × 3).
        let mut u = [0.0; MAX_DIM];
        let mut m = [[0.0; 3]; MAX_DIM];
        if na > 0 {
            let mut aaa = [[0.0; MAX_DIM]; MAX_DIM];
            for i in 0..na {
                for j in 0..na {
                    aaa[i][j] = a[3 + i][3 + j];
                }
            }
            let e = Eigen::new(&aaa, na);
            let mut r = [0.0; MAX_DIM];
            let mut t = [0.0; MAX_DIM];
            for i in 0..na {
                r[i] = -b[3 + i] - (0..na).map(|j| aaa[i][j] * mean[3 + j]).sum::<f64>();
            }
            e.pinv_apply(rel_tol, &r, &mut t);
            for i in 0..na {
                u[i] = mean[3 + i] + t[i];
            }
            for k in 0..3 {
                for i in 0..na {
                    r[i] = -a[3 + i][k];
                }
                e.pinv_apply(rel_tol, &r, &mut t);
                for i in 0..na {
                    m[i][k] = t[i];
                }
            }
        }
        // x = E y + f with E = [I; M], f = [0; u].
        let e_at = |i: usize, k: usize| if i < 3 { (i == k) as u8 as f64 } else { m[i - 3][k] };
        let f_at = |i: usize| if i < 3 { 0.0 } else { u[i - 3] };
        let mut ae = [[0.0; 3]; MAX_DIM];
        let mut afb = [0.0; MAX_DIM];
        for i in 0..n {
            for l in 0..3 {
                ae[i][l] = (0..n).map(|j| a[i][j] * e_at(j, l)).sum();
            }
            afb[i] = b[i] + (0..n).map(|j| a[i][j] * f_at(j)).sum::<f64>();
        }
        let mut h = [[0.0; 3]; 3];
        let mut g = [0.0; 3];
        for k in 0..3 {
            for l in 0..3 {
                h[k][l] = (0..n).map(|i| e_at(i, k) * ae[i][l]).sum();
            }
            g[k] = (0..n).map(|i| e_at(i, k) * afb[i]).sum();
        }
        let qred = |y: &[f64; 3]| -> f64 {
            let mut s = 0.0;
            for k in 0..3 {
                s += 2.0 * g[k] * y[k] + y[k] * (0..3).map(|l| h[k][l] * y[l]).sum::<f64>();
            }
            s
        };
        let start = [0, 1, 2].map(|k| clamp(mean[k], lo[k], hi[k]));
        let naive = [0, 1, 2].map(|k| clamp(xstar[k], lo[k], hi[k]));
        let mut best = naive;
        let mut best_q = qred(&naive);
        let qs = qred(&start);
        if !(best_q <= qs) {
            best = start;
            best_q = qs;
        }
        for code in 0..27usize {
            let state = [code % 3, (code / 3) % 3, code / 9];
            let mut y = [0.0; 3];
            let mut free = [0usize; 3];
            let mut nf = 0;
            for k in 0..3 {
                match state[k] {
                    1 => y[k] = lo[k],
                    2 => y[k] = hi[k],
                    _ => {
                        free[nf] = k;
                        nf += 1;
                    }
                }
            }
            if nf > 0 {
                let mut hf = [[0.0; MAX_DIM]; MAX_DIM];
                let mut r = [0.0; MAX_DIM];
                for (ii, &i) in free[..nf].iter().enumerate() {
                    let mut ri = -g[i];
                    for l in 0..3 {
                        if state[l] != 0 {
                            ri -= h[i][l] * y[l];
                        }
                    }
                    for (jj, &j) in free[..nf].iter().enumerate() {
                        hf[ii][jj] = h[i][j];
                        ri -= h[i][j] * start[j];
                    }
                    r[ii] = ri;
                }
                let mut dy = [0.0; MAX_DIM];
                Eigen::new(&hf, nf).pinv_apply(rel_tol, &r, &mut dy);
                let mut feasible = true;
                for (ii, &i) in free[..nf].iter().enumerate() {
                    let v = start[i] + dy[ii];
                    let slack = 1e-9 * (hi[i] - lo[i]);
                    if !(v >= lo[i] - slack && v <= hi[i] + slack) {
                        feasible = false;
                    }
                    y[i] = clamp(v, lo[i], hi[i]);
                }
                if !feasible {
                    continue;
                }
            }
            let q = qred(&y);
            if q < best_q {
                best_q = q;
                best = y;
            }
        }
        let mut x = [0.0; MAX_DIM];
        x[..3].copy_from_slice(&best);
        for i in 0..na {
            x[3 + i] = u[i] + (0..3).map(|k| m[i][k] * best[k]).sum::<f64>();
        }
        x
    }
}

impl std::fmt::Debug for Quadric {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Quadric")
            .field("dim", &self.dim)
            .field("area", &self.area())
            .field("count", &self.count())
            .field("coeffs", &self.coeffs())
            .finish()
    }
}

#[inline]
fn clamp(v: f64, lo: f64, hi: f64) -> f64 {
    if v < lo {
        lo
    } else if v > hi {
        hi
    } else {
        v
    }
}

#[inline]
fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

#[inline]
fn dot3(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Zero-padded width of the general path's vectors: a multiple of 4 ≥
/// [`MAX_DIM`], so reductions run as four short independent chains.
const PAD: usize = 12;

/// Dot product of padded vectors with four accumulators (reductions are
/// the latency bottleneck of the general triangle path).
#[inline]
fn dot(a: &[f64; PAD], b: &[f64; PAD]) -> f64 {
    let mut acc = [0.0; 4];
    for c in 0..PAD / 4 {
        for l in 0..4 {
            acc[l] += a[4 * c + l] * b[4 * c + l];
        }
    }
    (acc[0] + acc[1]) + (acc[2] + acc[3])
}

#[inline]
fn dist2(a: &[f64; PAD], b: &[f64; PAD]) -> f64 {
    let mut d = [0.0; PAD];
    for i in 0..PAD {
        d[i] = a[i] - b[i];
    }
    dot(&d, &d)
}

/// Position-space normal (unnormalised), its length and the triangle area,
/// or `None` when the triangle is degenerate: zero or non-finite area, or
/// collinear up to roundoff (height below ~2e-13 of the longest edge, where
/// the plane would be noise).
#[inline]
fn position_area(p: &[f64], q: &[f64], r: &[f64]) -> Option<([f64; 3], f64, f64)> {
    let u = [q[0] - p[0], q[1] - p[1], q[2] - p[2]];
    let v = [r[0] - p[0], r[1] - p[1], r[2] - p[2]];
    let w = [r[0] - q[0], r[1] - q[1], r[2] - q[2]];
    let nrm = cross(u, v);
    let len = dot3(nrm, nrm).sqrt();
    let area = 0.5 * len;
    let longest2 = dot3(u, u).max(dot3(v, v)).max(dot3(w, w));
    (area > DEGENERATE_REL_AREA * longest2 && area.is_finite()).then_some((nrm, len, area))
}

/// Normalises in place; false (vector untouched) if its length is 0 or not
/// finite.
fn normalize(v: &mut [f64; PAD]) -> bool {
    let len = dot(v, v).sqrt();
    if !(len > 0.0 && len.is_finite()) {
        return false;
    }
    let inv = 1.0 / len;
    for c in v {
        *c *= inv;
    }
    true
}

/// Symmetric eigen-decomposition of an n×n (n ≤ MAX_DIM) matrix by cyclic
/// Jacobi rotations: `A = V diag(vals) Vᵀ`, eigenvectors in V's columns.
struct Eigen {
    n: usize,
    vals: [f64; MAX_DIM],
    vecs: Mat,
    /// Sweeps used (for tests).
    #[cfg_attr(not(test), allow(dead_code))]
    sweeps: usize,
}

impl Eigen {
    fn new(a: &Mat, n: usize) -> Eigen {
        let mut a = *a;
        let mut v = [[0.0; MAX_DIM]; MAX_DIM];
        for i in 0..n {
            v[i][i] = 1.0;
        }
        let mut sweeps = 0;
        while sweeps < 50 {
            let mut off = 0.0;
            let mut diag = 0.0;
            for p in 0..n {
                diag += a[p][p] * a[p][p];
                for q in p + 1..n {
                    off += a[p][q] * a[p][q];
                }
            }
            // Converged (or NaN: stop rather than spin).
            if !(off > 1e-32 * diag) {
                break;
            }
            sweeps += 1;
            for p in 0..n {
                for q in p + 1..n {
                    let apq = a[p][q];
                    if apq == 0.0 {
                        continue;
                    }
                    // Negligible next to both diagonal entries: drop it
                    // rather than churn on roundoff.
                    if apq.abs() <= 1e-18 * (a[p][p].abs() + a[q][q].abs()) {
                        a[p][q] = 0.0;
                        a[q][p] = 0.0;
                        continue;
                    }
                    let theta = (a[q][q] - a[p][p]) / (2.0 * apq);
                    let t = if theta.abs() > 1e150 {
                        0.5 / theta
                    } else {
                        theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt())
                    };
                    let c = 1.0 / (t * t + 1.0).sqrt();
                    let s = t * c;
                    for k in 0..n {
                        let (akp, akq) = (a[k][p], a[k][q]);
                        a[k][p] = c * akp - s * akq;
                        a[k][q] = s * akp + c * akq;
                    }
                    for k in 0..n {
                        let (apk, aqk) = (a[p][k], a[q][k]);
                        a[p][k] = c * apk - s * aqk;
                        a[q][k] = s * apk + c * aqk;
                    }
                    a[p][q] = 0.0;
                    a[q][p] = 0.0;
                    for k in 0..n {
                        let (vkp, vkq) = (v[k][p], v[k][q]);
                        v[k][p] = c * vkp - s * vkq;
                        v[k][q] = s * vkp + c * vkq;
                    }
                }
            }
        }
        let mut vals = [0.0; MAX_DIM];
        for i in 0..n {
            vals[i] = a[i][i];
        }
        Eigen { n, vals, vecs: v, sweeps }
    }

    /// `out = A⁺ r`, keeping eigenvalues > rel_tol · λmax; returns the rank
    /// kept (0, and out = 0, when λmax ≤ 0 or not finite).
    fn pinv_apply(&self, rel_tol: f64, r: &[f64], out: &mut [f64]) -> usize {
        let n = self.n;
        out[..n].fill(0.0);
        let lmax = self.vals[..n].iter().fold(0.0f64, |m, &v| m.max(v));
        if !(lmax > 0.0 && lmax.is_finite()) {
            return 0;
        }
        let thr = rel_tol * lmax;
        let mut rank = 0;
        for i in 0..n {
            let l = self.vals[i];
            if l > thr {
                let coef = (0..n).map(|k| self.vecs[k][i] * r[k]).sum::<f64>() / l;
                for k in 0..n {
                    out[k] += coef * self.vecs[k][i];
                }
                rank += 1;
            }
        }
        rank
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// splitmix64 in [0, 1).
    struct Rng(u64);
    impl Rng {
        fn next(&mut self) -> f64 {
            self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
            let mut z = self.0;
            z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
            ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
        }
        fn range(&mut self, a: f64, b: f64) -> f64 {
            a + (b - a) * self.next()
        }
        fn vec3(&mut self, a: f64, b: f64) -> [f64; 3] {
            [self.range(a, b), self.range(a, b), self.range(a, b)]
        }
    }

    fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
        [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
    }
    fn add(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
        [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
    }
    fn scale(a: [f64; 3], s: f64) -> [f64; 3] {
        [a[0] * s, a[1] * s, a[2] * s]
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
        let v = Vertex {
            pos: [1e6 + 0.5, -3.0, 2.25],
            normal: [0.0, 0.6, 0.8],
            color: [10, 128, 255, 7],
            uv: [0.25, 0.75],
        };
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
        for attrs in
            [AttrSet::POSITION_ONLY, AttrSet(AttrSet::COLOR), AttrSet(AttrSet::UV | AttrSet::NORMAL | AttrSet::COLOR)]
        {
            let s = QuadricSpace::new(attrs, AttrWeights::uniform(0.3), [0.0; 3]);
            for (ti, t) in bad.iter().enumerate() {
                // Attributes differ per corner: collinear positions still count zero.
                let vs: Vec<Vertex> = t
                    .iter()
                    .enumerate()
                    .map(|(c, &pos)| Vertex {
                        pos,
                        color: [50 * c as u8, 0, 90, 255],
                        uv: [c as f32, 0.5],
                        normal: [0.0, 0.0, 1.0],
                    })
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
        let mut rng = Rng(7);
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
        let mut rng = Rng(42);
        let attrsets =
            [AttrSet::POSITION_ONLY, AttrSet(AttrSet::COLOR), AttrSet(AttrSet::UV | AttrSet::NORMAL | AttrSet::COLOR)];
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
            w.color =
                [v.color[0].saturating_add(40), v.color[1].saturating_add(40), v.color[2].saturating_add(40), 255];
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
                Vertex {
                    pos: [x, y, plane_z(x, y)],
                    uv: uv_of(x, y).map(|c| c as f32),
                    normal: nrm.map(|c| c as f32),
                    color: [c[0], c[1], c[2], 255],
                }
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
        let mut rng = Rng(3);
        for attrs in [
            AttrSet::POSITION_ONLY,
            AttrSet(AttrSet::NORMAL | AttrSet::COLOR),
            AttrSet(AttrSet::UV | AttrSet::NORMAL | AttrSet::COLOR),
        ] {
            let s = QuadricSpace::new(attrs, AttrWeights::for_extent(2.0), [0.1, 0.2, 0.3]);
            let tri = |rng: &mut Rng| {
                [0; 3].map(|_| {
                    s.embed(&Vertex {
                        pos: rng.vec3(-1.0, 1.0),
                        normal: rng.vec3(-1.0, 1.0).map(|c| c as f32),
                        color: [0; 4].map(|_| (rng.next() * 255.0) as u8),
                        uv: [rng.next() as f32, rng.next() as f32],
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
        let mut rng = Rng(11);
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
        let mut rng = Rng(5);
        let attrs = AttrSet(AttrSet::UV | AttrSet::COLOR);
        let (o1, o2) = ([1.0, 2.0, 3.0], [1.5, 1.0, 3.25]);
        let (s1, s2) = (
            QuadricSpace::new(attrs, AttrWeights::for_extent(1.0), o1),
            QuadricSpace::new(attrs, AttrWeights::for_extent(1.0), o2),
        );
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
        let mut rng = Rng(9);
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
            assert!(e.sweeps <= 12, "trial {trial}: {} sweeps", e.sweeps);
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
        let s = QuadricSpace::new(
            AttrSet(AttrSet::UV | AttrSet::NORMAL | AttrSet::COLOR),
            AttrWeights::uniform(0.7),
            [0.0; 3],
        );
        for _ in 0..100 {
            let v = [0; 3].map(|_| {
                s.embed(&Vertex {
                    pos: rng.vec3(-1.0, 1.0),
                    normal: rng.vec3(-1.0, 1.0).map(|c| c as f32),
                    color: [0; 4].map(|_| (rng.next() * 255.0) as u8),
                    uv: [rng.next() as f32, rng.next() as f32],
                })
            });
            let q = Quadric::from_triangle(&s, &v[0], &v[1], &v[2]);
            let e = Eigen::new(&q.matrix(), 11);
            assert!(e.sweeps <= 12, "{} sweeps", e.sweeps);
            let mut vals = e.vals;
            vals.sort_by(f64::total_cmp);
            assert!(vals[..2].iter().all(|v| v.abs() < 1e-13 * q.area()));
            assert!(vals[2..].iter().all(|v| (v - q.area()).abs() < 1e-13 * q.area()));
        }
    }

    #[test]
    fn bench_from_triangle_and_add() {
        println!("size_of::<Quadric>() = {} bytes", std::mem::size_of::<Quadric>());
        for (attrs, iters) in [
            (AttrSet::POSITION_ONLY, 2_000_000usize),
            (AttrSet(AttrSet::UV | AttrSet::NORMAL | AttrSet::COLOR), 400_000),
        ] {
            let s = QuadricSpace::new(attrs, AttrWeights::for_extent(1.0), [0.0; 3]);
            let mut rng = Rng(1);
            let pts: Vec<[f64; MAX_DIM]> = (0..1024)
                .map(|_| {
                    s.embed(&Vertex {
                        pos: rng.vec3(-1.0, 1.0),
                        normal: [0.0, 0.0, 1.0],
                        color: [10, 20, 30, 255],
                        uv: [rng.next() as f32, 0.5],
                    })
                })
                .collect();
            let mut acc = Quadric::zero(s.dim);
            let t0 = std::time::Instant::now();
            for i in 0..iters {
                let (p, q, r) = (&pts[i % 1024], &pts[(i + 1) % 1024], &pts[(i + 7) % 1024]);
                acc.add(&Quadric::from_triangle(&s, std::hint::black_box(p), q, r));
            }
            let t1 = t0.elapsed().as_nanos() as f64 / iters as f64;
            let t0 = std::time::Instant::now();
            for i in 0..iters {
                let (p, q, r) = (&pts[i % 1024], &pts[(i + 1) % 1024], &pts[(i + 7) % 1024]);
                acc.add_triangle(std::hint::black_box(p), q, r);
            }
            let t2 = t0.elapsed().as_nanos() as f64 / iters as f64;
            let solves = 20_000;
            let t0 = std::time::Instant::now();
            for _ in 0..solves {
                std::hint::black_box(std::hint::black_box(&acc).solve(DEFAULT_REL_TOL, None));
            }
            let t3 = t0.elapsed().as_nanos() as f64 / solves as f64;
            println!(
                "dim {:2}: from_triangle+add {t1:.1} ns/op, add_triangle {t2:.1} ns/op, solve {t3:.0} ns/op (area {:.3e}, {} coeffs)",
                s.dim,
                acc.area(),
                Quadric::coeff_len(s.dim)
            );
        }
    }
}

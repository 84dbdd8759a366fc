//! Generalized quadric error metric (Garland & Heckbert 1998, "Simplifying
//! surfaces with color and texture using quadric error metrics") for vertex
//! clustering.
//!
//! Takes: triangles and vertices of one cluster (cell), embedded as points of
//! R^n by a [`QuadricSpace`]. Gives: the accumulated [`Quadric`] and its
//! minimiser ([`Quadric::solve`]), decoded back into a [`Vertex`].
//!
//! Invariants:
//! * A vertex is a point of R^n, n = [`AttrSet::quadric_dim`]: position
//!   (*local* to the space's `origin`, normally the cell centre, so a mesh
//!   at 1e6 with 1e-3 detail keeps its precision), then uv, normal and
//!   colour when present, scaled by [`AttrWeights`] to be commensurate with
//!   positions. Alpha is not modelled.
//! * A triangle p, q, r with orthonormal in-plane frame e1, e2 gives
//!   `A = I − e1e1ᵀ − e2e2ᵀ`, `b = −A p`, `c = pᵀA p`: `Q(v) = vᵀAv + 2bᵀv + c`
//!   is the squared distance of v from its plane in R^n, weighted by its
//!   area *in position space*; triangles of zero position area or with a
//!   non-finite coordinate add nothing. Everything is accumulated in f64.
//! * A [`Quadric`] is fixed-size and heap-free, every loop bounded by the
//!   dimension; large per-cell tables store only the live coefficients
//!   ([`Quadric::coeffs`], [`Quadric::from_coeffs`], [`Quadric::add_into`]).
//! * The minimiser is taken about the cluster mean m, `x = m + A⁺(−b − A m)`,
//!   the pseudo-inverse dropping eigenvalues below `rel_tol` times the
//!   largest, so rank-deficient directions (a flat sheet, a crease) stay at
//!   the mean, as in Lindstrom's / VTK's quadric clustering. With
//!   attributes, the position's pseudo-inverse is taken on the
//!   attribute-eliminated 3×3 quadric (its Schur complement) and the
//!   attributes solved for that position. Given cell
//!   bounds, a minimiser outside them is re-optimised exactly inside the box
//!   and flagged `clamped`.
//!
//! The space, the coefficient table and the solver: `docs/levels-of-detail.md`,
//! "Quadrics".
// Index loops mirror the formulas. (Negated comparisons, `!(x > 0.0)` true
// for NaN, are allowed crate-wide in lib.rs.)
#![allow(clippy::needless_range_loop)]

use crate::geom::{cross, dot as dot3, sub};
use crate::mesh::{Aabb, AttrSet, Vertex};

mod eigen;
use eigen::Eigen;

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
    /// Fraction of the extent a full uv swing weighs
    /// ([`AttrWeights::for_extent`]).
    pub const EXTENT_FRACTION: f64 = 0.1;
    /// Fraction of the extent a full colour swing weighs
    /// ([`AttrWeights::for_extent`]).
    pub const SHADING_FRACTION: f64 = 0.01;
    /// Fraction of the extent a unit change of the normal weighs
    /// ([`AttrWeights::for_extent`]).
    pub const NORMAL_FRACTION: f64 = 0.001;

    /// The same weight for every attribute.
    pub fn uniform(w: f64) -> AttrWeights {
        AttrWeights { uv: w, normal: w, color: w }
    }

    /// Weights for a cell (or mesh) whose bounding-box diagonal is `diag`:
    /// a full uv swing counts like a positional offset of a tenth of the
    /// diagonal ([`Self::EXTENT_FRACTION`]: uvs address a texture, where a
    /// small shift shows), a full colour swing (0 → 1) like a hundredth
    /// ([`Self::SHADING_FRACTION`]) and a unit change of the normal (60°)
    /// like a thousandth ([`Self::NORMAL_FRACTION`]), so attribute
    /// variation informs the solution without buying its clusters with
    /// geometry. Colours and normals weighed a tenth until 2026-12-06: at
    /// coarse levels, where cells are large, that spent the clusters on
    /// sub-LSB colour and sub-degree normal changes; a hundredth cut the
    /// README's 2 M sphere's and a 1 M scan's Hausdorff distance 2–4× and
    /// their RMS up to 4.7×. Normals a hundredth until 2026-12-07: a rough
    /// surface's normals (a terrain's, a scan's) still took its coarse
    /// clusters; a thousandth cut a 1 M terrain's RMS up to 2.3× and a 1 M
    /// scan's Hausdorff distance up to 3.9× at coarse levels, normals as
    /// near the input's (0.97–1.01× over levels 2–8); a smooth sphere's
    /// coarsest levels, where the normals' spread stood in for curvature,
    /// lost up to 1.17× in RMS. Measured in `docs/levels-of-detail.md`,
    /// "Quadrics". A non-finite or zero `diag` counts as 1.
    pub fn for_extent(diag: f64) -> AttrWeights {
        let d = if diag.is_finite() && diag != 0.0 { diag.abs() } else { 1.0 };
        AttrWeights { uv: d * Self::EXTENT_FRACTION, normal: d * Self::NORMAL_FRACTION, color: d * Self::SHADING_FRACTION }
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

/// Calls `$f` with the dimension `$n` as a constant where it is one a mesh
/// can have (3, 5, 6, 8, 9, 11: positions; +uv; +normal or colour; +two or
/// three of them), else with `$n` itself. The callee is
/// `#[inline(always)]`: each arm is a copy whose loops have constant bounds
/// and unroll, doing the same operations in the same order as the general
/// one (the same bits); a loop over a runtime dimension spent most of its
/// instructions on loop control and bounds checks.
macro_rules! sized {
    ($n:expr, $f:ident($($arg:expr),*)) => {
        match $n {
            3 => $f(3, $($arg),*),
            5 => $f(5, $($arg),*),
            6 => $f(6, $($arg),*),
            8 => $f(8, $($arg),*),
            9 => $f(9, $($arg),*),
            11 => $f(11, $($arg),*),
            n => $f(n, $($arg),*),
        }
    };
}
pub(crate) use sized;

/// [`Quadric::at_point`] written straight into stored coefficients
/// (`out.len() ≥ coeff_len(dim)`, overwritten): no struct, no copies — the
/// form hot loops use.
pub fn packed_at_point(dim: usize, a: &[f64], p: &[f64], area: f64, out: &mut [f64]) {
    sized!(dim, packed_at_point_n(a, p, area, out))
}

#[inline(always)]
fn packed_at_point_n(dim: usize, a: &[f64], p: &[f64], area: f64, out: &mut [f64]) {
    let al = a_len(dim);
    let (a, p, out) = (&a[..al], &p[..dim], &mut out[..Quadric::coeff_len(dim)]);
    out[..al].copy_from_slice(a);
    // A·p from the packed rows, the diagonal entry apart (no branch per
    // entry); the same additions in the same order as entry by entry.
    let mut ap = [0.0; MAX_DIM];
    let mut rest = a;
    for i in 0..dim {
        let (row, tail) = rest.split_at(dim - i);
        let pi = p[i];
        ap[i] += row[0] * pi;
        for (j, &v) in (i + 1..dim).zip(&row[1..]) {
            ap[i] += v * p[j];
            ap[j] += v * pi;
        }
        rest = tail;
    }
    let mut c = 0.0;
    for i in 0..dim {
        out[al + i] = -ap[i];
        c += ap[i] * p[i];
    }
    out[al + dim] = c;
    out[al + dim + 1] = area;
    let s = al + dim + 2;
    out[s..s + dim].copy_from_slice(p);
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
    let e = sized!(dim, packed_value_n(k, &x));
    if e > 0.0 && e.is_finite() {
        e
    } else {
        0.0
    }
}

/// Index of (i, j), i ≤ j, in a packed upper-triangular row-major n×n matrix.
#[inline]
fn packed_index(n: usize, i: usize, j: usize) -> usize {
    i * n - i * i.saturating_sub(1) / 2 + j - i
}

/// Eliminates the attribute coordinates (3..`dim`) of a quadric
/// `Q(x) = xᵀAx + 2 lᵀx + c` stored as A packed, then `l`, then `c` (the
/// leading values of stored coefficients and of carried values alike):
/// afterwards `Q'(p) = min_s Q(p, s)` over the attributes s (the Schur
/// complement `A_pp − A_ps A_ss⁺ A_sp`, eigenvalues of `A_ss` below
/// `rel_tol` × its largest dropped), and the attribute rows, columns and
/// linear terms are zero. This is the position error of a vertex whose
/// attributes may take any value: a wedge of an attribute seam, whose sides
/// keep their own attributes while they share one position. Works on the
/// carried form as well (x the offset from the vertex, `l` the half-gradient).
pub fn eliminate_attrs(dim: usize, k: &mut [f64], rel_tol: f64) {
    if dim <= 3 {
        return;
    }
    let (a, rest) = k.split_at_mut(a_len(dim));
    let (lin, rest) = rest.split_at_mut(dim);
    let cst = &mut rest[0];
    let k = dim - 3;
    let mut s: Mat = [[0.0; MAX_DIM]; MAX_DIM];
    for i in 0..k {
        for j in i..k {
            let v = a[packed_index(dim, 3 + i, 3 + j)];
            s[i][j] = v;
            s[j][i] = v;
        }
    }
    let eig = Eigen::new(&s, k);
    let rel_tol = solve_rel_tol(rel_tol);
    // Y = A_ss⁺ [A_sp | l_s], one column at a time.
    let mut y = [[0.0; MAX_DIM]; 4];
    for (col, yc) in y.iter_mut().enumerate() {
        let mut r = [0.0; MAX_DIM];
        for i in 0..k {
            r[i] = if col < 3 { a[packed_index(dim, col, 3 + i)] } else { lin[3 + i] };
        }
        eig.pinv_apply(rel_tol, &r[..k], &mut yc[..k]);
    }
    // A_ps = A_spᵀ: entry (p, 3 + i) of the packed matrix.
    let aps = |p: usize, i: usize, a: &[f64]| a[packed_index(dim, p, 3 + i)];
    let mut app = [[0.0; 3]; 3];
    let mut lp = [0.0; 3];
    for p in 0..3 {
        for q in p..3 {
            app[p][q] = a[packed_index(dim, p, q)] - (0..k).map(|i| aps(p, i, a) * y[q][i]).sum::<f64>();
        }
        lp[p] = lin[p] - (0..k).map(|i| aps(p, i, a) * y[3][i]).sum::<f64>();
    }
    *cst -= (0..k).map(|i| lin[3 + i] * y[3][i]).sum::<f64>();
    for i in 0..dim {
        for j in i..dim {
            a[packed_index(dim, i, j)] = if j < 3 { app[i][j] } else { 0.0 };
        }
    }
    lin[..3].copy_from_slice(&lp);
    lin[3..dim].fill(0.0);
}

/// The attributes minimising stored coefficients `k` (dimension `dim`) with
/// the position held at `pos` (local): `x = (pos, s)`, `s` from the
/// attribute block's pseudo-inverse about the points' mean (so attributes
/// the quadric does not constrain stay at the mean). Finite always.
pub fn attrs_at(dim: usize, k: &[f64], pos: [f64; 3], rel_tol: f64) -> [f64; MAX_DIM] {
    let mut x = packed_mean::<MAX_DIM>(k, dim);
    x[..3].copy_from_slice(&pos);
    if dim <= 3 || !(k[a_len(dim) + dim + 1] > 0.0) {
        return x;
    }
    let n = dim - 3;
    let a = packed_matrix::<MAX_DIM>(k, dim);
    let g = half_gradient_at(&a, &k[a_len(dim)..a_len(dim) + dim], &x, dim);
    let mut s: Mat = [[0.0; MAX_DIM]; MAX_DIM];
    let mut r = [0.0; MAX_DIM];
    for i in 0..n {
        for j in 0..n {
            s[i][j] = a[3 + i][3 + j];
        }
        r[i] = -g[3 + i];
    }
    let mut dx = [0.0; MAX_DIM];
    Eigen::new(&s, n).pinv_apply(solve_rel_tol(rel_tol), &r[..n], &mut dx[..n]);
    if dx[..n].iter().all(|v| v.is_finite()) {
        for i in 0..n {
            x[3 + i] += dx[i];
        }
    }
    x
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

/// `Q(x)` of stored coefficients `k` (see [`Quadric::coeff_len`]).
#[inline]
fn packed_value(k: &[f64], n: usize, x: &[f64]) -> f64 {
    sized!(n, packed_value_n(k, x))
}

/// [`packed_value`], inlined so a constant `n` unrolls it (see `sized!`).
#[inline(always)]
fn packed_value_n(n: usize, k: &[f64], x: &[f64]) -> f64 {
    let x = &x[..n];
    let k = &k[..a_len(n) + n + 1];
    let mut s = 0.0;
    let mut at = 0;
    for i in 0..n {
        let mut row = 0.5 * k[at] * x[i];
        at += 1;
        for j in i + 1..n {
            row += k[at] * x[j];
            at += 1;
        }
        s += 2.0 * x[i] * row;
    }
    for i in 0..n {
        s += 2.0 * k[at + i] * x[i];
    }
    s + k[at + n]
}

/// [`packed_value`] floored at 0 (as [`Quadric::error`]).
#[inline]
fn packed_error(k: &[f64], n: usize, x: &[f64]) -> f64 {
    let s = packed_value(k, n, x);
    if s < 0.0 {
        0.0
    } else {
        s
    }
}

/// The mean of the points added to stored coefficients `k` of dimension
/// `n` (0 without points, or when not finite), in `M`-sized storage.
fn packed_mean<const M: usize>(k: &[f64], n: usize) -> [f64; M] {
    let mut m = [0.0; M];
    let cnt = k[Quadric::coeff_len(n) - 1];
    if cnt > 0.0 {
        let s = a_len(n) + n + 2;
        for i in 0..n {
            m[i] = k[s + i] / cnt;
        }
        if !m.iter().all(|v| v.is_finite()) {
            m = [0.0; M];
        }
    }
    m
}

/// The symmetric matrix A of stored coefficients `k` of dimension `n`, in
/// the leading n×n block of `M`-sized storage.
fn packed_matrix<const M: usize>(k: &[f64], n: usize) -> [[f64; M]; M] {
    let mut a = [[0.0; M]; M];
    let mut at = 0;
    for i in 0..n {
        for j in i..n {
            a[i][j] = k[at];
            a[j][i] = k[at];
            at += 1;
        }
    }
    a
}

/// `b + A x` (the half-gradient of Q at x) in the first `n` entries.
fn half_gradient_at<const M: usize>(a: &[[f64; M]; M], b: &[f64], x: &[f64], n: usize) -> [f64; M] {
    let mut g = [0.0; M];
    for i in 0..n {
        g[i] = b[i] + (0..n).map(|j| a[i][j] * x[j]).sum::<f64>();
    }
    g
}

/// `out = A⁺ r` for an n×n quadric matrix (n > 3, leading block of `a`)
/// by eliminating the attributes: `A = [[P, C], [Cᵀ, S]]` (P the 3×3
/// position block, S the attribute block), `S` factored `LDLᵀ`, the
/// position from the Schur complement `P − C S⁻¹ Cᵀ` (the position error
/// with the attributes at their optimum, as [`eliminate_attrs`] and the box
/// solve take it) by its closed-form eigen-decomposition and the
/// pseudo-inverse keeping eigenvalues above `rel_tol` times its largest,
/// then the attributes at their optimum for that position. Returns the
/// rank kept (the position block's plus n − 3), or None when S has a
/// pivot at or below `rel_tol` times its largest diagonal entry (nearly
/// singular, or not finite): the caller takes the full eigen-decomposition.
/// About a sixth of the work of the full decomposition at dimension 9,
/// whose QL steps were a fifth of a build with normals and colours
/// (`docs/build-costs.md`). Inlined: with a constant `n` (the sized
/// solve) its loops unroll.
#[inline(always)]
fn schur_pinv<const M: usize>(a: &[[f64; M]; M], n: usize, rel_tol: f64, r: &[f64], out: &mut [f64]) -> Option<usize> {
    let k = n - 3;
    // LDLᵀ of S, L unit lower triangular (strictly lower part in `l`).
    let mut l = [[0.0; M]; M];
    let mut d = [0.0; M];
    let dmax = (0..k).fold(0.0f64, |m, i| m.max(a[3 + i][3 + i]));
    if !(dmax > 0.0 && dmax.is_finite()) {
        return None;
    }
    let thr = rel_tol * dmax;
    for j in 0..k {
        let mut dj = a[3 + j][3 + j];
        for p in 0..j {
            dj -= l[j][p] * l[j][p] * d[p];
        }
        if !(dj > thr) {
            return None;
        }
        d[j] = dj;
        for i in j + 1..k {
            let mut v = a[3 + i][3 + j];
            for p in 0..j {
                v -= l[i][p] * l[j][p] * d[p];
            }
            l[i][j] = v / dj;
        }
    }
    // Y = S⁻¹ [Cᵀ | r_s]: columns 0..3 the attributes' response to the
    // position, column 3 to the right-hand side. The four columns are
    // substituted together, each with the same operations in the same
    // order as alone (the same bits): one column at a time, each step
    // waited on the one before it (a chain of k multiply-subtracts), and
    // these substitutions were a third of a cluster solve at dimension 11.
    let mut y = [[0.0; 4]; M];
    for i in 0..k {
        y[i] = [a[3 + i][0], a[3 + i][1], a[3 + i][2], r[3 + i]];
    }
    for i in 0..k {
        let mut yi = y[i];
        for p in 0..i {
            for c in 0..4 {
                yi[c] -= l[i][p] * y[p][c];
            }
        }
        y[i] = yi;
    }
    for i in 0..k {
        for c in 0..4 {
            y[i][c] /= d[i];
        }
    }
    for i in (0..k).rev() {
        let mut yi = y[i];
        for p in i + 1..k {
            for c in 0..4 {
                yi[c] -= l[p][i] * y[p][c];
            }
        }
        y[i] = yi;
    }
    let mut sp = [[0.0; 3]; 3];
    let mut rp = [0.0; 3];
    for p in 0..3 {
        for q in p..3 {
            let v = a[p][q] - (0..k).map(|i| a[p][3 + i] * y[i][q]).sum::<f64>();
            sp[p][q] = v;
            sp[q][p] = v;
        }
        rp[p] = r[p] - (0..k).map(|i| a[p][3 + i] * y[i][3]).sum::<f64>();
    }
    let (vals, vecs) = eigen::eigen3(&sp);
    // The cut-off relative to A's scale (its largest diagonal entry, a
    // lower bound of its largest eigenvalue), not the complement's: as with
    // the full pseudo-inverse, directions A barely constrains stay at the
    // mean. Relative to the complement alone, coarse levels of a 2 M sphere
    // with normals and colours measured up to 3.7× the RMS of the full
    // pseudo-inverse; with A's diagonal (or six power steps for λmax, the
    // same results), 0.95–1.004×.
    let smax = vals.iter().fold(0.0f64, |m, &v| m.max(v));
    let amax = (0..n).fold(0.0f64, |m, i| m.max(a[i][i]));
    let rel = if smax > 0.0 && amax > smax { rel_tol * amax / smax } else { rel_tol };
    let mut dp = [0.0; 3];
    let rank = eigen::apply_pinv(&vals, &vecs, rel, &rp, &mut dp);
    out[..3].copy_from_slice(&dp);
    for i in 0..k {
        out[3 + i] = y[i][3] - (0..3).map(|p| y[i][p] * dp[p]).sum::<f64>();
    }
    Some(rank + k)
}

/// The eigenvalue cut-off a solve uses for `rel_tol`.
fn solve_rel_tol(rel_tol: f64) -> f64 {
    if rel_tol.is_finite() {
        rel_tol.max(MIN_REL_TOL)
    } else {
        DEFAULT_REL_TOL
    }
}

/// A solve's position box with each axis's ends in order.
fn ordered_box((lo, hi): ([f64; 3], [f64; 3])) -> ([f64; 3], [f64; 3]) {
    ([0, 1, 2].map(|k| lo[k].min(hi[k])), [0, 1, 2].map(|k| lo[k].max(hi[k])))
}

/// Whether the position part of `x` lies in the box.
fn in_box(x: &[f64], lo: [f64; 3], hi: [f64; 3]) -> bool {
    (0..3).all(|k| x[k] >= lo[k] && x[k] <= hi[k])
}

/// [`Quadric::solve`] of stored coefficients of dimension `N`, when its
/// unconstrained minimiser lies in `bounds`: the minimiser, the half-gradient
/// there ([`Quadric::half_gradient`]) and `Q` there, on arrays of the
/// quadric's own size (the general path copies and clears `MAX_DIM`-sized
/// quadrics and matrices per solve, a large share of a small solve's time:
/// `docs/build-costs.md`). The same operations as the general path, so the
/// same bits, except at N = 3, whose eigen-decomposition is the closed form
/// (`eigen3`, cheaper than the general decomposition), and where the
/// attribute block is nearly singular (the general path's decomposition,
/// on arrays of size N). None when the
/// minimiser must be clamped into the box (the caller takes the general
/// path, which minimises over the box).
pub fn solve_sized<const N: usize>(k: &[f64], rel_tol: f64, bounds: ([f64; 3], [f64; 3])) -> Option<([f64; N], [f64; N], f64)> {
    let al = a_len(N);
    let rel_tol = solve_rel_tol(rel_tol);
    let mean = packed_mean::<N>(k, N);
    let a = packed_matrix::<N>(k, N);
    let b = &k[al..al + N];
    let mut x = mean;
    if k[al + N + 1] > 0.0 {
        // A dx = −(b + A mean).
        let rhs = half_gradient_at(&a, b, &mean, N).map(|g| -g);
        let mut dx = [0.0; N];
        if N == 3 || schur_pinv(&a, N, rel_tol, &rhs, &mut dx).is_none() {
            eigen::pinv_apply_sized::<N>(&a, rel_tol, &rhs, &mut dx);
        }
        for i in 0..N {
            x[i] += dx[i];
        }
        if !x.iter().all(|v| v.is_finite()) {
            x = mean;
        }
    }
    let (lo, hi) = ordered_box(bounds);
    if !in_box(&x, lo, hi) {
        return None;
    }
    Some((x, half_gradient_at(&a, b, &x, N), packed_error(k, N, &x)))
}

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

    /// Back to the empty quadric of its dimension, clearing only the
    /// coefficients it uses (a loop over many triangles reuses one).
    pub fn clear(&mut self) {
        self.k[..Self::coeff_len(self.dim)].fill(0.0);
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
        packed_mean(&self.k, self.dim)
    }

    /// A, expanded to a full symmetric matrix.
    fn matrix(&self) -> Mat {
        packed_matrix(&self.k, self.dim)
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
            if let Some((nrm, len, area)) = plane3(p, q, r) {
                self.add_plane3(p, q, r, nrm, len, area);
            }
        } else if let Some(([p, q, r], area)) = padded(n, p, q, r) {
            self.add_triangle_general(&p, &q, &r, area);
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
        let Some((e1, e2)) = triangle_frame(p, q, r) else {
            return;
        };
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
        half_gradient_at(&self.matrix(), self.b(), x, self.dim)
    }

    pub fn error(&self, x: &[f64]) -> f64 {
        packed_error(&self.k, self.dim, x)
    }

    /// Minimiser of Q: rank-revealing eigen solve about the cluster mean m,
    /// `x = m + A⁺(−b − A m)`, dropping eigenvalues below `rel_tol` times the
    /// largest (`rel_tol` is floored at 1e-12; [`DEFAULT_REL_TOL`] = 1e-3).
    /// With attributes whose block is well conditioned (almost always: each
    /// triangle's attribute block has rank ≥ dim − 5), the position comes
    /// from the attribute-eliminated 3×3 quadric and the attributes are
    /// solved exactly for it (`schur_pinv`); the pseudo-inverse's cut-off
    /// stays relative to the whole matrix's scale (its largest diagonal
    /// entry), as in the full decomposition, not to the 3×3 block's.
    ///
    /// With `bounds = Some((lo, hi))` (local coordinates, normally the cell
    /// box) the position is kept inside the box: if the unconstrained
    /// minimiser is outside, the quadric (with attributes at their optimum
    /// for each position) is minimised over the box and `clamped` is set.
    /// The result is always finite and, with bounds, within them.
    pub fn solve(&self, rel_tol: f64, bounds: Option<([f64; 3], [f64; 3])>) -> Solution {
        let n = self.dim;
        let rel_tol = solve_rel_tol(rel_tol);
        let mean = self.mean();
        let a = self.matrix();
        let mut x = mean;
        let mut rank = 0;
        if !self.is_empty() {
            // A dx = −(b + A mean).
            let rhs = half_gradient_at(&a, self.b(), &mean, n).map(|g| -g);
            let mut dx = [0.0; MAX_DIM];
            rank = match (n > 3).then(|| schur_pinv(&a, n, rel_tol, &rhs, &mut dx)).flatten() {
                Some(r) => r,
                None => Eigen::new(&a, n).pinv_apply(rel_tol, &rhs, &mut dx),
            };
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
        let (lo, hi) = ordered_box((lo, hi));
        if in_box(&x, lo, hi) {
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
    fn box_minimise(&self, a: &Mat, mean: &[f64; MAX_DIM], xstar: &[f64; MAX_DIM], lo: [f64; 3], hi: [f64; 3], rel_tol: f64) -> [f64; MAX_DIM] {
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
                let mut hf = [[0.0; 3]; 3];
                let mut r = [0.0; 3];
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
                let mut dy = [0.0; 3];
                eigen::pinv_apply_small(&hf, nf, rel_tol, &r, &mut dy);
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
        f.debug_struct("Quadric").field("dim", &self.dim).field("area", &self.area()).field("count", &self.count()).field("coeffs", &self.coeffs()).finish()
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

/// The orthonormal frame (e1, e2) of triangle p, q, r in R^n (zero-padded
/// to [`PAD`]), based at its longest edge, or None where it has none.
#[inline]
fn triangle_frame(p: &[f64; PAD], q: &[f64; PAD], r: &[f64; PAD]) -> Option<([f64; PAD], [f64; PAD])> {
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
        return None;
    }
    // Twice-is-enough Gram–Schmidt.
    for _ in 0..2 {
        let t = dot(&e2, &e1);
        for i in 0..PAD {
            e2[i] -= t * e1[i];
        }
    }
    if !normalize(&mut e2) {
        return None;
    }
    Some((e1, e2))
}

/// The packed matrix A (`dim(dim+1)/2` values into `out`) of triangle p, q,
/// r's quadric: what [`Quadric::add_triangle`] adds to a zero quadric's A,
/// the same bits; false (`out` untouched) where it adds nothing.
///
/// For level 0, whose vertex quadrics are their triangles' matrices alone
/// (the planes pass through the corners: no gradient, no residual). Why it
/// wins over `add_triangle` into a cleared [`Quadric`] then adding its
/// matrix to each corner: no clearing of the whole coefficient array, no
/// b, c and area the caller drops, and a constant dimension (`sized!`), so
/// the fill unrolls; with attributes (R^9) that was 7 % of a build's
/// instructions.
pub fn triangle_matrix(dim: usize, p: &[f64], q: &[f64], r: &[f64], out: &mut [f64]) -> bool {
    sized!(dim, triangle_matrix_n(p, q, r, out))
}

#[inline(always)]
fn triangle_matrix_n(n: usize, p: &[f64], q: &[f64], r: &[f64], out: &mut [f64]) -> bool {
    let out = &mut out[..a_len(n)];
    if n == 3 {
        let Some((nrm, len, w)) = plane3(p, q, r) else {
            return false;
        };
        // As `add_plane3`, each entry added to zero.
        let il = 1.0 / len;
        let nn = [nrm[0] * il, nrm[1] * il, nrm[2] * il];
        let mut k = 0;
        for i in 0..3 {
            for j in i..3 {
                out[k] = 0.0 + w * nn[i] * nn[j];
                k += 1;
            }
        }
        return true;
    }
    let Some(([p, q, r], w)) = padded(n, p, q, r) else {
        return false;
    };
    let Some((e1, e2)) = triangle_frame(&p, &q, &r) else {
        return false;
    };
    // As `add_triangle_general`'s rows, each entry added to zero; each
    // row a slice zipped with the frame's tails (no index arithmetic or
    // bounds check per entry: a third of this function's instructions at
    // dimension 9 were those).
    let mut rest = out;
    for i in 0..n {
        let (a1, a2) = (w * e1[i], w * e2[i]);
        let (row, tail) = rest.split_at_mut(n - i);
        row[0] = 0.0 + (w - a1 * e1[i] - a2 * e2[i]);
        for (o, (x, y)) in row[1..].iter_mut().zip(e1[i + 1..n].iter().zip(&e2[i + 1..n])) {
            *o = 0.0 - (a1 * x + a2 * y);
        }
        rest = tail;
    }
    true
}

/// A triangle in R^3 that adds to a quadric: its plane (`position_area`:
/// normal, its length, area) when every coordinate is finite and the area
/// is not zero. The one check [`Quadric::add_triangle`] and
/// [`triangle_matrix`] make.
#[inline(always)]
fn plane3(p: &[f64], q: &[f64], r: &[f64]) -> Option<([f64; 3], f64, f64)> {
    let (p, q, r) = (&p[..3], &q[..3], &r[..3]);
    // v * 0 is NaN exactly for non-finite v: one branch for all values.
    let probe = |s: &[f64]| s[0] * 0.0 + s[1] * 0.0 + s[2] * 0.0;
    if probe(p) + probe(q) + probe(r) != 0.0 {
        return None;
    }
    position_area(p, q, r)
}

/// A triangle in R^n (n > 3) that adds to a quadric: its corners
/// zero-padded to [`PAD`] and its position area, when every coordinate is
/// finite and the area is not zero ([`plane3`]'s check, in any dimension).
#[inline(always)]
fn padded(n: usize, p: &[f64], q: &[f64], r: &[f64]) -> Option<([[f64; PAD]; 3], f64)> {
    let pad = |s: &[f64]| {
        let mut v = [0.0; PAD];
        v[..n].copy_from_slice(&s[..n]);
        v
    };
    let (p, q, r) = (pad(p), pad(q), pad(r));
    let zero = [0.0; PAD];
    let probe = |v: &[f64; PAD]| dot(v, &zero);
    if probe(&p) + probe(&q) + probe(&r) != 0.0 {
        return None;
    }
    let (_, _, area) = position_area(&p, &q, &r)?;
    Some(([p, q, r], area))
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
    let (p, q, r) = ([p[0], p[1], p[2]], [q[0], q[1], q[2]], [r[0], r[1], r[2]]);
    let (u, v, w) = (sub(q, p), sub(r, p), sub(r, q));
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

#[cfg(test)]
mod tests;

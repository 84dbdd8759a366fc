//! Symmetric eigen-decomposition for the quadric solve: Householder
//! tridiagonalisation and implicit QL for any size ([`tridiagonal_ql`]), a
//! closed form for 3×3 ([`eigen3`]).

use super::{Mat, MAX_DIM};
use crate::geom::{cross, dot};

/// Symmetric eigen-decomposition of an n×n (n ≤ MAX_DIM) matrix
/// ([`tridiagonal_ql`]): `A = V diag(vals) Vᵀ`, eigenvectors in V's columns.
pub(super) struct Eigen {
    pub(super) n: usize,
    pub(super) vals: [f64; MAX_DIM],
    pub(super) vecs: Mat,
    /// The most QL iterations one eigenvalue took (for tests).
    #[cfg_attr(not(test), allow(dead_code))]
    pub(super) iters: usize,
}

impl Eigen {
    pub(super) fn new(a: &Mat, n: usize) -> Eigen {
        // Every dimension a mesh can have (positions; +uv; +normal or
        // colour; +uv and one of them; +normal and colour; all) runs on
        // arrays of its own size: unrolled, in registers, without
        // copying and clearing MAX_DIM² matrices per solve. Same arithmetic,
        // same results as on MAX_DIM arrays (which the box-constrained
        // solves' reduced sizes use).
        match n {
            3 => Self::sized::<3>(a, n),
            5 => Self::sized::<5>(a, n),
            6 => Self::sized::<6>(a, n),
            8 => Self::sized::<8>(a, n),
            9 => Self::sized::<9>(a, n),
            _ => Self::sized::<MAX_DIM>(a, n),
        }
    }

    fn sized<const N: usize>(a: &Mat, n: usize) -> Eigen {
        let mut m = [[0.0; N]; N];
        for i in 0..n {
            m[i][..n].copy_from_slice(&a[i][..n]);
        }
        let (l, v, iters) = tridiagonal_ql(m, n);
        let mut vals = [0.0; MAX_DIM];
        let mut vecs = [[0.0; MAX_DIM]; MAX_DIM];
        for i in 0..n {
            vals[i] = l[i];
            vecs[i][..n].copy_from_slice(&v[i][..n]);
        }
        Eigen { n, vals, vecs, iters }
    }

    /// `out = A⁺ r`, keeping eigenvalues > rel_tol · λmax; returns the rank
    /// kept (0, and out = 0, when λmax ≤ 0 or not finite).
    pub(super) fn pinv_apply(&self, rel_tol: f64, r: &[f64], out: &mut [f64]) -> usize {
        apply_pinv(&self.vals[..self.n], &self.vecs, rel_tol, r, out)
    }
}

/// [`Eigen::new`] then [`Eigen::pinv_apply`] for a box solve's reduced
/// system (`n` = 1 to 3 free coordinates, the leading block of `h`): on
/// arrays of its own size, the same arithmetic as on `MAX_DIM` ones (the
/// same results) without clearing and copying `MAX_DIM`² matrices for each
/// of a clamped solve's 27 faces, which made those solves 8.6 % of level
/// 0's simplify-and-route on a terrain (about 6 % of its representatives
/// clamp, each 33 K instructions).
/// Other `n`: rank 0, `out` untouched.
pub(super) fn pinv_apply_small(h: &[[f64; 3]; 3], n: usize, rel_tol: f64, r: &[f64], out: &mut [f64]) -> usize {
    fn run<const N: usize>(h: &[[f64; 3]; 3], rel_tol: f64, r: &[f64], out: &mut [f64]) -> usize {
        let mut m = [[0.0; N]; N];
        for i in 0..N {
            m[i].copy_from_slice(&h[i][..N]);
        }
        let (l, v, _) = tridiagonal_ql(m, N);
        apply_pinv(&l, &v, rel_tol, r, out)
    }
    match n {
        1 => run::<1>(h, rel_tol, r, out),
        2 => run::<2>(h, rel_tol, r, out),
        3 => run::<3>(h, rel_tol, r, out),
        _ => 0,
    }
}

/// `out = V diag(1/λ) Vᵀ r` over the eigenpairs with λ > rel_tol · λmax
/// (`vals[i]`, column i of `vecs`; `n = vals.len()`); returns how many (0,
/// and out = 0, when λmax ≤ 0 or not finite).
pub(super) fn apply_pinv<const M: usize>(vals: &[f64], vecs: &[[f64; M]], rel_tol: f64, r: &[f64], out: &mut [f64]) -> usize {
    let n = vals.len();
    out[..n].fill(0.0);
    let lmax = vals.iter().fold(0.0f64, |m, &v| m.max(v));
    if !(lmax > 0.0 && lmax.is_finite()) {
        return 0;
    }
    let thr = rel_tol * lmax;
    let mut rank = 0;
    for i in 0..n {
        let l = vals[i];
        if l > thr {
            let coef = (0..n).map(|k| vecs[k][i] * r[k]).sum::<f64>() / l;
            for k in 0..n {
                out[k] += coef * vecs[k][i];
            }
            rank += 1;
        }
    }
    rank
}

/// [`Eigen::pinv_apply`] of an N×N matrix, on arrays of that size. N = 3
/// (positions only, most of a build's solves) uses the closed-form
/// decomposition [`eigen3`]; other sizes the same QL steps as
/// [`Eigen::new`] (same results).
pub(super) fn pinv_apply_sized<const N: usize>(a: &[[f64; N]; N], rel_tol: f64, r: &[f64; N], out: &mut [f64; N]) -> usize {
    let (vals, v) = if N == 3 {
        let mut vals = [0.0; N];
        let mut v = [[0.0; N]; N];
        let mut a3 = [[0.0; 3]; 3];
        for i in 0..3 {
            a3[i].copy_from_slice(&a[i][..3]);
        }
        let (l, vecs) = eigen3(&a3);
        vals[..3].copy_from_slice(&l);
        for i in 0..3 {
            v[i][..3].copy_from_slice(&vecs[i]);
        }
        (vals, v)
    } else {
        let (vals, v, _) = tridiagonal_ql(*a, N);
        (vals, v)
    };
    apply_pinv(&vals, &v, rel_tol, r, out)
}

/// √(a² + b²): directly where neither square can overflow or lose the
/// larger operand to underflow, else libm's `hypot` (which scales, at
/// several times the cost: it was 9 % of a build with normals and colours).
#[inline]
fn hypot(a: f64, b: f64) -> f64 {
    let m = a.abs().max(b.abs());
    if m > 1e-150 && m < 1e150 {
        (a * a + b * b).sqrt()
    } else {
        a.hypot(b)
    }
}

/// Symmetric eigen-decomposition by Householder tridiagonalisation and
/// the implicit QL algorithm with Wilkinson-like shifts (EISPACK's `tred2`
/// and `tql2`, as in JAMA): eigenvalues, eigenvectors in V's columns, and
/// the most QL iterations one eigenvalue took. About a fifth of the work
/// of the cyclic Jacobi sweeps it replaced at dimension 9 (they rotate
/// every pair, each rotation two square roots and two divisions, and were
/// 36 % of a build with normals and colours). A non-finite matrix gives non-finite eigenvalues (iterations
/// are capped), which the pseudo-inverse treats as rank 0. Works on the
/// leading n×n block of `a` (n ≤ N; the rest of V is left zero).
fn tridiagonal_ql<const N: usize>(a: [[f64; N]; N], n: usize) -> ([f64; N], [[f64; N]; N], usize) {
    // The sized arrays are called with n == N: a constant bound lets the
    // loops unroll.
    let n = if N < MAX_DIM { N } else { n };
    let mut v = [[0.0; N]; N];
    for i in 0..n {
        v[i][..n].copy_from_slice(&a[i][..n]);
    }
    let mut d = [0.0; N];
    let mut e = [0.0; N];
    if n == 0 {
        return (d, v, 0);
    }
    // tred2: Householder reduction to tridiagonal form, V accumulating.
    d[..n].copy_from_slice(&v[n - 1][..n]);
    for i in (1..n).rev() {
        let mut scale = 0.0;
        let mut h = 0.0;
        for k in 0..i {
            scale += d[k].abs();
        }
        if scale == 0.0 {
            e[i] = d[i - 1];
            for j in 0..i {
                d[j] = v[i - 1][j];
                v[i][j] = 0.0;
                v[j][i] = 0.0;
            }
        } else {
            for k in 0..i {
                d[k] /= scale;
                h += d[k] * d[k];
            }
            let f = d[i - 1];
            let mut g = h.sqrt();
            if f > 0.0 {
                g = -g;
            }
            e[i] = scale * g;
            h -= f * g;
            d[i - 1] = f - g;
            for j in 0..i {
                e[j] = 0.0;
            }
            for j in 0..i {
                let f = d[j];
                v[j][i] = f;
                let mut g = e[j] + v[j][j] * f;
                for k in j + 1..i {
                    g += v[k][j] * d[k];
                    e[k] += v[k][j] * f;
                }
                e[j] = g;
            }
            let mut f = 0.0;
            for j in 0..i {
                e[j] /= h;
                f += e[j] * d[j];
            }
            let hh = f / (h + h);
            for j in 0..i {
                e[j] -= hh * d[j];
            }
            for j in 0..i {
                let (f, g) = (d[j], e[j]);
                for k in j..i {
                    v[k][j] -= f * e[k] + g * d[k];
                }
                d[j] = v[i - 1][j];
                v[i][j] = 0.0;
            }
        }
        d[i] = h;
    }
    for i in 0..n - 1 {
        v[n - 1][i] = v[i][i];
        v[i][i] = 1.0;
        let h = d[i + 1];
        if h != 0.0 {
            for k in 0..=i {
                d[k] = v[k][i + 1] / h;
            }
            for j in 0..=i {
                let mut g = 0.0;
                for k in 0..=i {
                    g += v[k][i + 1] * v[k][j];
                }
                for k in 0..=i {
                    v[k][j] -= g * d[k];
                }
            }
        }
        for k in 0..=i {
            v[k][i + 1] = 0.0;
        }
    }
    for j in 0..n {
        d[j] = v[n - 1][j];
        v[n - 1][j] = 0.0;
    }
    v[n - 1][n - 1] = 1.0;
    e[0] = 0.0;
    // tql2: implicit QL on the tridiagonal (d, e), rotations into V.
    for i in 1..n {
        e[i - 1] = e[i];
    }
    e[n - 1] = 0.0;
    let mut f = 0.0;
    let mut tst1 = 0.0f64;
    let eps = f64::EPSILON;
    let mut most = 0;
    for l in 0..n {
        tst1 = tst1.max(d[l].abs() + e[l].abs());
        let mut m = l;
        // e[n − 1] is 0, so m stops there (or at n − 1 when NaN compares false).
        while m < n - 1 && !(e[m].abs() <= eps * tst1) {
            m += 1;
        }
        if m > l {
            let mut iter = 0;
            loop {
                iter += 1;
                let g = d[l];
                let mut p = (d[l + 1] - g) / (2.0 * e[l]);
                let mut r = hypot(p, 1.0);
                if p < 0.0 {
                    r = -r;
                }
                d[l] = e[l] / (p + r);
                d[l + 1] = e[l] * (p + r);
                let dl1 = d[l + 1];
                let h = g - d[l];
                for di in d.iter_mut().take(n).skip(l + 2) {
                    *di -= h;
                }
                f += h;
                p = d[m];
                let (mut c, mut c2, mut c3) = (1.0, 1.0, 1.0);
                let el1 = e[l + 1];
                let (mut s, mut s2) = (0.0, 0.0);
                for i in (l..m).rev() {
                    c3 = c2;
                    c2 = c;
                    s2 = s;
                    let g = c * e[i];
                    let h = c * p;
                    r = hypot(p, e[i]);
                    e[i + 1] = s * r;
                    s = e[i] / r;
                    c = p / r;
                    p = c * d[i] - s * g;
                    d[i + 1] = h + s * (c * g + s * d[i]);
                    for row in v.iter_mut().take(n) {
                        let h = row[i + 1];
                        row[i + 1] = s * row[i] + c * h;
                        row[i] = c * row[i] - s * h;
                    }
                }
                p = -s * s2 * c3 * el1 * e[l] / dl1;
                e[l] = s * p;
                d[l] = c * p;
                if !(e[l].abs() > eps * tst1) || iter >= 60 {
                    break;
                }
            }
            most = most.max(iter);
        }
        d[l] += f;
        e[l] = 0.0;
    }
    (d, v, most)
}

/// The Jacobi rotation (cosine, sine, tangent) that zeroes `apq` of the
/// symmetric 2×2 block [[app, apq], [apq, aqq]] (apq ≠ 0), the smaller of
/// the two angles (Golub & Van Loan, 8.5.2).
#[inline]
fn rotation(app: f64, aqq: f64, apq: f64) -> (f64, f64, f64) {
    let theta = (aqq - app) / (2.0 * apq);
    let t = if theta.abs() > 1e150 { 0.5 / theta } else { theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt()) };
    let c = 1.0 / (t * t + 1.0).sqrt();
    (c, t * c, t)
}

/// Eigenvalues and eigenvectors (V's columns) of a symmetric 3×3 matrix,
/// without iterating. The eigenvalue farthest from the other two comes from
/// the trigonometric solution of the characteristic cubic (D. Eberly, "A
/// Robust Eigensolver for 3×3 Symmetric Matrices", Geometric Tools 2014;
/// that root is well conditioned, unlike the other two when they nearly
/// coincide) and its eigenvector from the largest cross product of rows of
/// A − λI; the other two are one Jacobi rotation of A restricted to that
/// vector's orthogonal complement. V is orthonormal to roundoff and each
/// eigenvalue is its vector's Rayleigh quotient, accurate to a few ulps of
/// the largest entry, however the eigenvalues cluster (flat: two zeros;
/// cylinder: two equal). Cheaper than the general decomposition, which it replaces
/// at dimension 3 (`docs/build-costs.md`).
pub(super) fn eigen3(a: &[[f64; 3]; 3]) -> ([f64; 3], [[f64; 3]; 3]) {
    let (a00, a01, a02, a11, a12, a22) = (a[0][0], a[0][1], a[0][2], a[1][1], a[1][2], a[2][2]);
    let max_abs = a00.abs().max(a01.abs()).max(a02.abs()).max(a11.abs()).max(a12.abs()).max(a22.abs());
    let identity = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    if !a.iter().flatten().all(|v| v.is_finite()) {
        return ([f64::NAN; 3], identity); // the solve then keeps nothing
    }
    if max_abs == 0.0 {
        return ([0.0; 3], identity);
    }
    let s = 1.0 / max_abs;
    let (a00, a01, a02, a11, a12, a22) = (a00 * s, a01 * s, a02 * s, a11 * s, a12 * s, a22 * s);
    let norm = a01 * a01 + a02 * a02 + a12 * a12;
    if norm == 0.0 {
        return ([a[0][0], a[1][1], a[2][2]], identity);
    }
    let m = [[a00, a01, a02], [a01, a11, a12], [a02, a12, a22]];
    let q = (a00 + a11 + a22) / 3.0;
    let (b00, b11, b22) = (a00 - q, a11 - q, a22 - q);
    let p = ((b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * norm) / 6.0).sqrt();
    let c00 = b11 * b22 - a12 * a12;
    let c01 = a01 * b22 - a12 * a02;
    let c02 = a01 * a12 - b11 * a02;
    let half_det = ((b00 * c00 - a01 * c01 + a02 * c02) / (p * p * p) * 0.5).clamp(-1.0, 1.0);
    let angle = half_det.acos() / 3.0;
    // The largest root when the cubic leans that way, else the smallest:
    // the one apart from the other two.
    const TWO_THIRDS_PI: f64 = 2.094_395_102_393_195_5;
    let beta = if half_det >= 0.0 { angle.cos() * 2.0 } else { (angle + TWO_THIRDS_PI).cos() * 2.0 };
    let w = vector_of(&m, q + p * beta);
    // The complement's basis (u, v) and A there: [[puu, puv], [puv, pvv]].
    let u = if w[0].abs() > w[1].abs() {
        let l = 1.0 / (w[0] * w[0] + w[2] * w[2]).sqrt();
        [-w[2] * l, 0.0, w[0] * l]
    } else {
        let l = 1.0 / (w[1] * w[1] + w[2] * w[2]).sqrt();
        [0.0, w[2] * l, -w[1] * l]
    };
    let v = cross(w, u);
    let mul = |x: [f64; 3]| [dot(m[0], x), dot(m[1], x), dot(m[2], x)];
    let (aw, au, av) = (mul(w), mul(u), mul(v));
    let (puu, puv, pvv) = (dot(u, au), dot(u, av), dot(v, av));
    // One Jacobi rotation diagonalises the 2×2 block.
    let (e1, e2, l1, l2) = if puv == 0.0 {
        (u, v, puu, pvv)
    } else {
        let (c, sn, t) = rotation(puu, pvv, puv);
        let e1 = [0, 1, 2].map(|k| c * u[k] - sn * v[k]);
        let e2 = [0, 1, 2].map(|k| sn * u[k] + c * v[k]);
        (e1, e2, puu - t * puv, pvv + t * puv)
    };
    let vals = [dot(w, aw), l1, l2].map(|x| x * max_abs);
    let vecs = [[w[0], e1[0], e2[0]], [w[1], e1[1], e2[1]], [w[2], e1[2], e2[2]]];
    (vals, vecs)
}

/// Unit eigenvector of a simple eigenvalue: the largest cross product of
/// two rows of A − λI.
fn vector_of(m: &[[f64; 3]; 3], val: f64) -> [f64; 3] {
    let r0 = [m[0][0] - val, m[0][1], m[0][2]];
    let r1 = [m[0][1], m[1][1] - val, m[1][2]];
    let r2 = [m[0][2], m[1][2], m[2][2] - val];
    let c = [cross(r0, r1), cross(r0, r2), cross(r1, r2)];
    let d = c.map(|x| dot(x, x));
    let k = if d[0] >= d[1] && d[0] >= d[2] {
        0
    } else if d[1] >= d[2] {
        1
    } else {
        2
    };
    if !(d[k] > 0.0) {
        return [1.0, 0.0, 0.0];
    }
    let l = 1.0 / d[k].sqrt();
    c[k].map(|x| x * l)
}

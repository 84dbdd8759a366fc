//! Symmetric eigen-decomposition (cyclic Jacobi) for the quadric solve.

use super::{Mat, MAX_DIM};

/// Symmetric eigen-decomposition of an n×n (n ≤ MAX_DIM) matrix by cyclic
/// Jacobi rotations: `A = V diag(vals) Vᵀ`, eigenvectors in V's columns.
pub(super) struct Eigen {
    pub(super) n: usize,
    pub(super) vals: [f64; MAX_DIM],
    pub(super) vecs: Mat,
    /// Sweeps used (for tests).
    #[cfg_attr(not(test), allow(dead_code))]
    pub(super) sweeps: usize,
}

impl Eigen {
    pub(super) fn new(a: &Mat, n: usize) -> Eigen {
        // The common dimensions (positions; +uv; +normal or colour) run on
        // arrays of their own size: unrolled, in registers, without
        // copying and clearing MAX_DIM² matrices per solve (a few per cent
        // of a build). Same arithmetic, same results.
        match n {
            3 => Self::sized::<3>(a, n),
            5 => Self::sized::<5>(a, n),
            6 => Self::sized::<6>(a, n),
            _ => Self::sized::<MAX_DIM>(a, n),
        }
    }

    fn sized<const N: usize>(a: &Mat, n: usize) -> Eigen {
        let mut m = [[0.0; N]; N];
        let mut v = [[0.0; N]; N];
        for i in 0..n {
            m[i][..n].copy_from_slice(&a[i][..n]);
            v[i][i] = 1.0;
        }
        let sweeps = jacobi(&mut m, &mut v, n);
        let mut vals = [0.0; MAX_DIM];
        let mut vecs = [[0.0; MAX_DIM]; MAX_DIM];
        for i in 0..n {
            vals[i] = m[i][i];
            vecs[i][..n].copy_from_slice(&v[i][..n]);
        }
        Eigen { n, vals, vecs, sweeps }
    }

    /// `out = A⁺ r`, keeping eigenvalues > rel_tol · λmax; returns the rank
    /// kept (0, and out = 0, when λmax ≤ 0 or not finite).
    pub(super) fn pinv_apply(&self, rel_tol: f64, r: &[f64], out: &mut [f64]) -> usize {
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

/// Cyclic Jacobi on the leading n×n block (n ≤ N) of `a`, accumulating the
/// rotations in `v`; returns the sweeps used.
fn jacobi<const N: usize>(a: &mut [[f64; N]; N], v: &mut [[f64; N]; N], n: usize) -> usize {
    // The sized arrays are called with n == N: a constant bound lets the
    // loops unroll (same operations in the same order).
    let n = if N < MAX_DIM { N } else { n };
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
                let t = if theta.abs() > 1e150 { 0.5 / theta } else { theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt()) };
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
    sweeps
}

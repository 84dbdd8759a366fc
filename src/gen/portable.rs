//! Portable randomness and trigonometry for the generator: per-index
//! hashing and a sequential parameter generator on splitmix64
//! (`geom::mix64`), and `sin`/`cos` as plain IEEE arithmetic, so
//! generated meshes are identical on every platform.

use crate::geom::{dot, mix64, GOLDEN};
use std::f64::consts::{FRAC_PI_2, PI, TAU};

/// A uniform in [0,1) from hashing (a, b).
#[inline]
pub(super) fn hash_unit(a: u64, b: u64) -> f64 {
    (mix64(a ^ mix64(b)) >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// Sequential generator for per-mesh parameters. Not [`crate::geom::Rng`]:
/// its stream is part of what a seed means (every generated benchmark input
/// and fixture), so it stays bit-for-bit what it was.
pub(super) struct Rng(u64);

impl Rng {
    pub(super) fn new(seed: u64, salt: u64) -> Rng {
        Rng(mix64(seed ^ mix64(salt)))
    }
    pub(super) fn unit(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(GOLDEN);
        hash_unit(self.0, 0)
    }
    pub(super) fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }
}

/// sin(x), |error| < 1e-9 for |x| up to ~1e6: range reduction plus a degree-13
/// odd polynomial. Plain IEEE arithmetic, so identical on every platform.
#[inline]
pub(super) fn fsin(x: f64) -> f64 {
    let k = round(x * (1.0 / TAU));
    let mut r = x - k * TAU;
    if r > FRAC_PI_2 {
        r = PI - r;
    } else if r < -FRAC_PI_2 {
        r = -PI - r;
    }
    let r2 = r * r;
    r * (1.0
        + r2 * (-1.0 / 6.0 + r2 * (1.0 / 120.0 + r2 * (-1.0 / 5040.0 + r2 * (1.0 / 362_880.0 + r2 * (-1.0 / 39_916_800.0 + r2 * (1.0 / 6_227_020_800.0)))))))
}

/// `x.round()` for |x| < 2^62 without a libm call (half away from zero).
#[inline]
pub(super) fn round(x: f64) -> f64 {
    (x + 0.5f64.copysign(x)) as i64 as f64
}

#[inline]
pub(super) fn fcos(x: f64) -> f64 {
    fsin(x + FRAC_PI_2)
}

/// `p` scaled to unit length.
#[inline]
pub(super) fn normalize(p: [f64; 3]) -> [f64; 3] {
    let l = dot(p, p).sqrt();
    [p[0] / l, p[1] / l, p[2] / l]
}

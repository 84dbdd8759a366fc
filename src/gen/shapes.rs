//! The generator's building blocks: seeded plane waves, grid and box
//! dimensions for a target triangle count, the cube-sphere lattice and the
//! torus every instance is made of.

use super::portable::{fcos, fsin, normalize, Rng};
use crate::geom::dot;
use std::f64::consts::{PI, TAU};

/// A sum of plane waves `a·sin(f·(d·p) + φ)`: smooth seeded detail.
#[derive(Clone, Debug)]
pub(super) struct Waves {
    w: Vec<([f64; 3], f64, f64, f64)>, // direction, frequency, phase, amplitude
}

impl Waves {
    pub(super) fn none() -> Waves {
        Waves { w: Vec::new() }
    }
    /// `n` waves with directions on the unit sphere (or in the xy plane).
    pub(super) fn random(rng: &mut Rng, n: usize, planar: bool, freq: (f64, f64), amp: f64) -> Waves {
        let w = (0..n)
            .map(|_| {
                let d = if planar {
                    let t = rng.range(0.0, TAU);
                    [fcos(t), fsin(t), 0.0]
                } else {
                    let z = rng.range(-1.0, 1.0);
                    let t = rng.range(0.0, TAU);
                    let s = (1.0 - z * z).max(0.0).sqrt();
                    [s * fcos(t), s * fsin(t), z]
                };
                (d, rng.range(freq.0, freq.1), rng.range(0.0, TAU), amp)
            })
            .collect();
        Waves { w }
    }
    /// Multi-octave planar waves for terrain.
    pub(super) fn octaves(rng: &mut Rng, octaves: usize, per: usize, base_freq: f64, amp: f64) -> Waves {
        let mut all = Vec::new();
        for o in 0..octaves {
            let f = base_freq * (1u64 << o) as f64;
            let a = amp * 0.5f64.powi(o as i32) / per as f64;
            all.extend(Waves::random(rng, per, true, (0.8 * f, 1.25 * f), a).w);
        }
        Waves { w: all }
    }
    /// Value at `p`, and its gradient when `grad`.
    #[inline]
    pub(super) fn eval(&self, p: [f64; 3], grad: bool) -> (f64, [f64; 3]) {
        let mut v = 0.0;
        let mut g = [0.0; 3];
        for &(d, f, ph, a) in &self.w {
            let s = f * dot(d, p) + ph;
            v += a * fsin(s);
            if grad {
                let c = a * f * fcos(s);
                for k in 0..3 {
                    g[k] += c * d[k];
                }
            }
        }
        (v, g)
    }
}

// ---------------------------------------------------------------------------
// Building blocks.

/// Chooses `(w, h)` with `w*h ≈ quads` and `w/h ≈ ratio`, as close to the
/// target as a small search finds.
pub(super) fn grid_dims(quads: f64, ratio: f64, min_w: u64) -> (u64, u64) {
    let quads = quads.max(1.0);
    let w0 = (quads * ratio).sqrt().max(min_w as f64);
    let lo = ((w0 * 0.8).floor() as u64).max(min_w);
    let hi = (w0 * 1.25).ceil() as u64 + 1;
    let mut best = (f64::INFINITY, min_w, 1);
    for w in lo..=hi {
        let h = ((quads / w as f64).round() as u64).max(1);
        let err = ((w * h) as f64 - quads).abs() + 1e-9 * (w as f64 - w0).abs();
        if err < best.0 {
            best = (err, w, h);
        }
    }
    (best.1, best.2)
}

/// Box dimensions `[n0, n1, n2]` for a cube-sphere whose triangle count
/// `count(n0, n1, n2)` (homogeneous of degree 2) is closest to `target`.
pub(super) fn box_dims(target: u64, count: impl Fn(u64, u64, u64) -> u64) -> [u64; 3] {
    let unit = count(1, 1, 1) as f64;
    let n0 = (target as f64 / unit).sqrt().max(1.0);
    let mut best = (u64::MAX, u64::MAX, [1, 1, 1]);
    let mut consider = |a: u64, b: u64, c: u64| {
        let err = count(a, b, c).abs_diff(target);
        let shape = c * 1000 / a; // prefer cubic among equals
        if (err, shape) < (best.0, best.1) {
            best = (err, shape, [a, b, c]);
        }
    };
    if n0 <= 40.0 {
        let amax = (n0 * 1.5) as u64 + 2;
        for a in 1..=amax {
            for b in a..=2 * a {
                for c in b..=2 * a {
                    consider(a, b, c);
                }
            }
        }
    } else {
        let r = n0.round() as u64;
        for a in r - 2..=r + 1 {
            let base = count(a, a, a);
            let step = count(a, a, a + 1) - base;
            let c = if target >= base { a + (target - base + step / 2) / step } else { a.saturating_sub((base - target + step / 2) / step).max(1) };
            for cc in c.saturating_sub(1).max(1)..=c + 1 {
                consider(a, a, cc);
            }
        }
    }
    best.2
}

/// The lattice points on the surface of the box [0,n0]×[0,n1]×[0,n2], indexed
/// as: bottom (z = 0) interior, then one ring per z layer from 0 to n2, then
/// the top (z = n2) interior. Each cube face is a grid of quads over them.
#[derive(Clone, Debug)]
pub(super) struct BoxLattice {
    pub(super) n: [u64; 3],
    pub(super) ring: u64,
    pub(super) interior: u64,
    /// Quad offsets of the six faces (-X, +X, -Y, +Y, -Z, +Z), plus the total.
    pub(super) qoff: [u64; 7],
    /// Equal-angle warp of each axis' lattice coordinate into [-1, 1].
    pub(super) warp: [Vec<f64>; 3],
}

impl BoxLattice {
    pub(super) fn new(n: [u64; 3]) -> BoxLattice {
        let [n0, n1, _] = n;
        let dims = Self::face_dims(n);
        let mut qoff = [0u64; 7];
        for f in 0..6 {
            qoff[f + 1] = qoff[f] + dims[f].0 * dims[f].1;
        }
        let warp = n.map(|m| {
            (0..=m)
                .map(|k| {
                    if k == 0 {
                        -1.0
                    } else if k == m {
                        1.0
                    } else if 2 * k == m {
                        0.0
                    } else {
                        (PI / 4.0 * (2.0 * k as f64 / m as f64 - 1.0)).tan()
                    }
                })
                .collect()
        });
        BoxLattice { n, ring: 2 * n0 + 2 * n1, interior: (n0 - 1) * (n1 - 1), qoff, warp }
    }
    /// (s extent, t extent) of each face's quad grid.
    pub(super) fn face_dims([n0, n1, n2]: [u64; 3]) -> [(u64, u64); 6] {
        [(n2, n1), (n1, n2), (n0, n2), (n2, n0), (n1, n0), (n0, n1)]
    }
    pub(super) fn vertex_count(&self) -> u64 {
        2 * self.interior + (self.n[2] + 1) * self.ring
    }
    #[inline]
    pub(super) fn ring_index(&self, a: u64, b: u64) -> u64 {
        let [n0, n1, _] = self.n;
        if b == 0 {
            a
        } else if a == n0 {
            n0 + b
        } else if b == n1 {
            n0 + n1 + (n0 - a)
        } else {
            2 * n0 + n1 + (n1 - b)
        }
    }
    #[inline]
    pub(super) fn index(&self, [a, b, c]: [u64; 3]) -> u64 {
        let [n0, n1, n2] = self.n;
        if a > 0 && a < n0 && b > 0 && b < n1 {
            let k = (a - 1) + (b - 1) * (n0 - 1);
            if c == 0 {
                k
            } else {
                debug_assert_eq!(c, n2);
                self.interior + (n2 + 1) * self.ring + k
            }
        } else {
            self.interior + c * self.ring + self.ring_index(a, b)
        }
    }
    #[inline]
    pub(super) fn point(&self, i: u64) -> [u64; 3] {
        let [n0, n1, n2] = self.n;
        let rings = (n2 + 1) * self.ring;
        if i < self.interior {
            [1 + i % (n0 - 1), 1 + i / (n0 - 1), 0]
        } else if i < self.interior + rings {
            let j = i - self.interior;
            let c = j / self.ring;
            let k = j % self.ring;
            let (a, b) = if k < n0 {
                (k, 0)
            } else if k < n0 + n1 {
                (n0, k - n0)
            } else if k < 2 * n0 + n1 {
                (n0 - (k - n0 - n1), n1)
            } else {
                (0, n1 - (k - 2 * n0 - n1))
            };
            [a, b, c]
        } else {
            let k = i - self.interior - rings;
            [1 + k % (n0 - 1), 1 + k / (n0 - 1), n2]
        }
    }
    /// Lattice point of corner (s, t) of face `f`; faces are oriented so that
    /// s × t points outward.
    #[inline]
    pub(super) fn face_point(&self, f: usize, s: u64, t: u64) -> [u64; 3] {
        let [n0, n1, n2] = self.n;
        match f {
            0 => [0, t, s],
            1 => [n0, s, t],
            2 => [s, 0, t],
            3 => [t, n1, s],
            4 => [t, s, 0],
            _ => [s, t, n2],
        }
    }
    /// Triangle `j` (two per quad, faces in order -X, +X, -Y, +Y, -Z, +Z).
    #[inline]
    pub(super) fn face(&self, j: u64) -> [u32; 3] {
        let q = j / 2;
        let mut f = 0;
        while q >= self.qoff[f + 1] {
            f += 1;
        }
        let ns = Self::face_dims(self.n)[f].0;
        let l = q - self.qoff[f];
        let (s, t) = (l % ns, l / ns);
        let p = |s, t| self.index(self.face_point(f, s, t)) as u32;
        if j & 1 == 0 {
            [p(s, t), p(s + 1, t), p(s + 1, t + 1)]
        } else {
            [p(s, t), p(s + 1, t + 1), p(s, t + 1)]
        }
    }
    /// Unit direction of vertex `i`.
    #[inline]
    pub(super) fn direction(&self, i: u64) -> [f64; 3] {
        let [a, b, c] = self.point(i);
        normalize([self.warp[0][a as usize], self.warp[1][b as usize], self.warp[2][c as usize]])
    }
}

/// A closed torus (major radius 1, minor 0.35) as an `a × b` quad grid.
#[derive(Clone, Debug)]
pub(super) struct Torus {
    pub(super) a: u64,
    pub(super) b: u64,
    pub(super) pos: Vec<[f64; 3]>,
    pub(super) normal: Vec<[f64; 3]>,
    pub(super) uv: Vec<[f64; 2]>,
}

impl Torus {
    pub(super) fn new(a: u64, b: u64) -> Torus {
        let (mut pos, mut normal, mut uv) = (Vec::new(), Vec::new(), Vec::new());
        for j in 0..b {
            for i in 0..a {
                let th = TAU * i as f64 / a as f64;
                let ph = TAU * j as f64 / b as f64;
                let (ct, st, cp, sp) = (fcos(th), fsin(th), fcos(ph), fsin(ph));
                let rr = 1.0 + 0.35 * cp;
                pos.push([rr * ct, rr * st, 0.35 * sp]);
                normal.push([cp * ct, cp * st, sp]);
                uv.push([i as f64 / a as f64, j as f64 / b as f64]);
            }
        }
        Torus { a, b, pos, normal, uv }
    }
    pub(super) fn vertex_count(&self) -> u64 {
        self.a * self.b
    }
    pub(super) fn face_count(&self) -> u64 {
        2 * self.a * self.b
    }
    #[inline]
    pub(super) fn face(&self, j: u64) -> [u64; 3] {
        let q = j / 2;
        let (i, k) = (q % self.a, q / self.a);
        let (i1, k1) = ((i + 1) % self.a, (k + 1) % self.b);
        let v = |i, k| i + k * self.a;
        if j & 1 == 0 {
            [v(i, k), v(i1, k), v(i1, k1)]
        } else {
            [v(i, k), v(i1, k1), v(i, k1)]
        }
    }
}

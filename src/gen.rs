//! Deterministic procedural meshes, from one triangle to 10^9, for tests,
//! benchmarks and the `octolod-gen` tool.
//!
//! Takes: [`GenOptions`] (shape, target triangle count, seed, attributes).
//! Gives: a [`Generator`], a random-access indexed mesh whose `vertex(i)` and
//! `face(j)` are pure functions of the options and the index (randomness comes
//! from hashing the seed with the index, trigonometry from a portable
//! polynomial), so the output is identical whatever the chunking or thread
//! count and nothing is ever held in memory; and [`write`], which streams a
//! generated mesh to a PLY with parallel chunk encoding.
//!
//! Shapes: smooth closed ones ([`Shape::Sphere`], [`Shape::Terrain`],
//! [`Shape::Instances`]) and hard cases for numerical robustness (flat,
//! rank-2, nearly coincident sheets, slivers and collinear triangles,
//! duplicated faces, far from the origin, a single triangle, non-manifold
//! fans, an open sphere). See [`Shape`] for each.

use crate::error::{IoContext, Result};
use crate::io::AtomicFile;
use crate::mesh::{AttrSet, Vertex};
use crate::ply::write::{PlyEncoder, PlyWriteOptions, PlyWriter};
use crate::ply::Encoding;
use crate::progress::Progress;
use rayon::prelude::*;
use std::io::{self, Write};
use std::path::Path;

/// Which procedural mesh to generate.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Shape {
    /// Closed sphere of radius ~1 with smooth seeded bumps (amplitude ~0.05),
    /// a cube-sphere with shared seam vertices.
    Sphere,
    /// Heightfield over [0,1]² with smooth multi-octave seeded height; open border.
    Terrain,
    /// Many closed tori (~48–160 triangles each), randomly placed, rotated
    /// and scaled in [0,100]³.
    Instances,
    /// Flat grid in z = 0 over [0,1]²; open border (rank-1 quadrics).
    Plane,
    /// Open tube, radius 1, z in [-1,1] (rank-2 quadrics).
    Cylinder,
    /// Two parallel open grids over [0,1]², 1e-4 apart (z = 0 facing down,
    /// z = 1e-4 facing up).
    Sheets,
    /// Grid of strips with aspect ratio 1e-6, plus zero-area triangles made
    /// of three distinct collinear vertices.
    Slivers,
    /// A closed sphere in which every face appears twice (same indices).
    Duplicates,
    /// Sphere of radius 0.5 centred at (1e6, 1e6, 1e6) with 1e-3 detail
    /// (meaningful only with double positions).
    Offset,
    /// Exactly one triangle.
    Single,
    /// Non-manifold: a "book" of triangles sharing one edge, and a fan disc
    /// whose centre is one end of that edge.
    Fan,
    /// A sphere with one cap (a whole cube-face patch) removed; open border.
    Open,
    /// A range scan: a depth-image grid over [0,1]² of a bumpy dome with
    /// a thin ridge, per-vertex scanner noise, holes (dropouts) and a long
    /// ragged silhouette border; unreferenced vertices stay in the file.
    Scan,
}

impl Shape {
    /// The command-line name (`sphere`, `terrain`, ...).
    pub fn name(self) -> &'static str {
        match self {
            Shape::Sphere => "sphere",
            Shape::Terrain => "terrain",
            Shape::Instances => "instances",
            Shape::Plane => "plane",
            Shape::Cylinder => "cylinder",
            Shape::Sheets => "sheets",
            Shape::Slivers => "slivers",
            Shape::Duplicates => "duplicates",
            Shape::Offset => "offset",
            Shape::Single => "single",
            Shape::Fan => "fan",
            Shape::Open => "open",
            Shape::Scan => "scan",
        }
    }
    pub const ALL: [Shape; 13] = [
        Shape::Sphere,
        Shape::Terrain,
        Shape::Instances,
        Shape::Plane,
        Shape::Cylinder,
        Shape::Sheets,
        Shape::Slivers,
        Shape::Duplicates,
        Shape::Offset,
        Shape::Single,
        Shape::Fan,
        Shape::Open,
        Shape::Scan,
    ];
}

/// What to generate.
#[derive(Clone, Debug)]
pub struct GenOptions {
    pub shape: Shape,
    /// Target triangle count: approximate (within ~1% from 1000 on), exact
    /// for fixed shapes ([`Shape::Single`]). Clamped to [1, [`MAX_TRIS`]].
    pub tris: u64,
    pub seed: u64,
    /// Attributes to emit; `POS_F64` means double positions when written.
    pub attrs: AttrSet,
}

impl Default for GenOptions {
    fn default() -> Self {
        GenOptions { shape: Shape::Sphere, tris: 1000, seed: 1, attrs: AttrSet::POSITION_ONLY }
    }
}

/// Largest accepted target (vertex indices must fit in u32).
pub const MAX_TRIS: u64 = 4_000_000_000;

// ---------------------------------------------------------------------------
// Portable randomness and trigonometry.

#[inline]
fn splitmix64(x: u64) -> u64 {
    let mut z = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// A uniform in [0,1) from hashing (a, b).
#[inline]
fn hash_unit(a: u64, b: u64) -> f64 {
    (splitmix64(a ^ splitmix64(b)) >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// Sequential generator for per-mesh parameters.
struct Rng(u64);

impl Rng {
    fn new(seed: u64, salt: u64) -> Rng {
        Rng(splitmix64(seed ^ splitmix64(salt)))
    }
    fn unit(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        hash_unit(self.0, 0)
    }
    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }
}

use std::f64::consts::{FRAC_PI_2, PI, TAU};

/// sin(x), |error| < 1e-9 for |x| up to ~1e6: range reduction plus a degree-13
/// odd polynomial. Plain IEEE arithmetic, so identical on every platform.
#[inline]
fn fsin(x: f64) -> f64 {
    let k = round(x * (1.0 / TAU));
    let mut r = x - k * TAU;
    if r > FRAC_PI_2 {
        r = PI - r;
    } else if r < -FRAC_PI_2 {
        r = -PI - r;
    }
    let r2 = r * r;
    r * (1.0
        + r2 * (-1.0 / 6.0
            + r2 * (1.0 / 120.0
                + r2 * (-1.0 / 5040.0
                    + r2 * (1.0 / 362_880.0 + r2 * (-1.0 / 39_916_800.0 + r2 * (1.0 / 6_227_020_800.0)))))))
}

/// `x.round()` for |x| < 2^62 without a libm call (half away from zero).
#[inline]
fn round(x: f64) -> f64 {
    (x + 0.5f64.copysign(x)) as i64 as f64
}

#[inline]
fn fcos(x: f64) -> f64 {
    fsin(x + FRAC_PI_2)
}

#[inline]
fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[inline]
fn normalize(p: [f64; 3]) -> [f64; 3] {
    let l = dot(p, p).sqrt();
    [p[0] / l, p[1] / l, p[2] / l]
}

/// A sum of plane waves `a·sin(f·(d·p) + φ)`: smooth seeded detail.
#[derive(Clone, Debug)]
struct Waves {
    w: Vec<([f64; 3], f64, f64, f64)>, // direction, frequency, phase, amplitude
}

impl Waves {
    fn none() -> Waves {
        Waves { w: Vec::new() }
    }
    /// `n` waves with directions on the unit sphere (or in the xy plane).
    fn random(rng: &mut Rng, n: usize, planar: bool, freq: (f64, f64), amp: f64) -> Waves {
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
    fn octaves(rng: &mut Rng, octaves: usize, per: usize, base_freq: f64, amp: f64) -> Waves {
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
    fn eval(&self, p: [f64; 3], grad: bool) -> (f64, [f64; 3]) {
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
fn grid_dims(quads: f64, ratio: f64, min_w: u64) -> (u64, u64) {
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
fn box_dims(target: u64, count: impl Fn(u64, u64, u64) -> u64) -> [u64; 3] {
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
            let c = if target >= base {
                a + (target - base + step / 2) / step
            } else {
                a.saturating_sub((base - target + step / 2) / step).max(1)
            };
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
struct BoxLattice {
    n: [u64; 3],
    ring: u64,
    interior: u64,
    /// Quad offsets of the six faces (-X, +X, -Y, +Y, -Z, +Z), plus the total.
    qoff: [u64; 7],
    /// Equal-angle warp of each axis' lattice coordinate into [-1, 1].
    warp: [Vec<f64>; 3],
}

impl BoxLattice {
    fn new(n: [u64; 3]) -> BoxLattice {
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
    fn face_dims([n0, n1, n2]: [u64; 3]) -> [(u64, u64); 6] {
        [(n2, n1), (n1, n2), (n0, n2), (n2, n0), (n1, n0), (n0, n1)]
    }
    fn vertex_count(&self) -> u64 {
        2 * self.interior + (self.n[2] + 1) * self.ring
    }
    #[inline]
    fn ring_index(&self, a: u64, b: u64) -> u64 {
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
    fn index(&self, [a, b, c]: [u64; 3]) -> u64 {
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
    fn point(&self, i: u64) -> [u64; 3] {
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
    fn face_point(&self, f: usize, s: u64, t: u64) -> [u64; 3] {
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
    fn face(&self, j: u64) -> [u32; 3] {
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
    fn direction(&self, i: u64) -> [f64; 3] {
        let [a, b, c] = self.point(i);
        normalize([self.warp[0][a as usize], self.warp[1][b as usize], self.warp[2][c as usize]])
    }
}

/// A closed torus (major radius 1, minor 0.35) as an `a × b` quad grid.
#[derive(Clone, Debug)]
struct Torus {
    a: u64,
    b: u64,
    pos: Vec<[f64; 3]>,
    normal: Vec<[f64; 3]>,
    uv: Vec<[f64; 2]>,
}

impl Torus {
    fn new(a: u64, b: u64) -> Torus {
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
    fn vertex_count(&self) -> u64 {
        self.a * self.b
    }
    fn face_count(&self) -> u64 {
        2 * self.a * self.b
    }
    #[inline]
    fn face(&self, j: u64) -> [u64; 3] {
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

#[derive(Clone, Debug)]
enum Kind {
    /// Sphere, Open, Duplicates, Offset.
    Sphere { lat: BoxLattice, waves: Waves, radius: f64, center: [f64; 3], open: bool, dup: bool },
    /// Terrain and Plane: a (w+1)×(h+1) vertex grid over [0,1]².
    Grid { w: u64, h: u64, waves: Waves },
    Cylinder { s: u64, h: u64 },
    Sheets { w: u64, h: u64 },
    /// `w` columns of sliver quads per row, `dg` collinear triangles per row.
    Slivers { w: u64, h: u64, dg: u64 },
    Instances { torus: Torus, count: u64 },
    /// `p` pages on the spine edge, `q` triangles in the fan disc.
    Fan { p: u64, q: u64 },
    /// A (w+1)×(h+1) vertex grid; the kept cells follow an mx × my coarse
    /// mask: `prefix[cy * (mx+1) + cx]` kept fine cells left of coarse
    /// column cx in a fine row of coarse row cy; `col_first[cx]` the first
    /// fine column of cx; `row_off[t]` kept cells before fine row t.
    Scan { w: u64, h: u64, waves: Waves, noise: f64, mx: u64, my: u64, col_first: Vec<u64>, prefix: Vec<u64>, row_off: Vec<u64> },
    Single,
}

/// A random-access procedural mesh; see the module documentation.
#[derive(Clone, Debug)]
pub struct Generator {
    shape: Shape,
    seed: u64,
    attrs: AttrSet,
    kind: Kind,
    nv: u64,
    nf: u64,
}

/// Sheets are this far apart.
const SHEET_GAP: f64 = 1e-4;
/// Aspect ratio (height / length) of the sliver strips.
const SLIVER_ASPECT: f64 = 1e-6;
/// At most this many sliver rows, so rows stay distinct in f32.
const SLIVER_MAX_ROWS: u64 = 1 << 17;
const OFFSET_CENTER: f64 = 1e6;

impl Generator {
    pub fn new(opts: &GenOptions) -> Generator {
        let tris = opts.tris.clamp(1, MAX_TRIS);
        let t = tris as f64;
        let mut rng = Rng::new(opts.seed, opts.shape as u64 + 1);
        let sphere_count = |a: u64, b: u64, c: u64| 4 * (a * b + b * c + a * c);
        let kind = match opts.shape {
            Shape::Sphere | Shape::Open | Shape::Duplicates | Shape::Offset => {
                let (open, dup) = (opts.shape == Shape::Open, opts.shape == Shape::Duplicates);
                let n = if open {
                    box_dims(tris, |a, b, c| sphere_count(a, b, c) - 2 * a * b)
                } else if dup {
                    box_dims(tris, |a, b, c| 2 * sphere_count(a, b, c))
                } else {
                    box_dims(tris, sphere_count)
                };
                let (radius, center, waves) = if opts.shape == Shape::Offset {
                    // 1e-3 absolute detail on radius 0.5.
                    (0.5, [OFFSET_CENTER; 3], Waves::random(&mut rng, 6, false, (6.0, 20.0), 2e-3 / 6f64.sqrt()))
                } else {
                    (1.0, [0.0; 3], Waves::random(&mut rng, 6, false, (2.0, 7.0), 0.05 / 6f64.sqrt()))
                };
                Kind::Sphere { lat: BoxLattice::new(n), waves, radius, center, open, dup }
            }
            Shape::Terrain | Shape::Plane => {
                let (w, h) = grid_dims(t / 2.0, 1.0, 1);
                let waves =
                    if opts.shape == Shape::Terrain { Waves::octaves(&mut rng, 5, 2, TAU * 1.5, 0.12) } else { Waves::none() };
                Kind::Grid { w, h, waves }
            }
            Shape::Cylinder => {
                let (s, h) = grid_dims(t / 2.0, PI, 3);
                Kind::Cylinder { s, h }
            }
            Shape::Sheets => {
                let (w, h) = grid_dims(t / 4.0, 1.0, 1);
                Kind::Sheets { w, h }
            }
            Shape::Slivers => {
                let w = 8u64.max(tris.div_ceil(2 * SLIVER_MAX_ROWS));
                let dg = (w / 8).max(1);
                let h = ((t / (2 * w + dg) as f64).round() as u64).max(1);
                Kind::Slivers { w, h, dg }
            }
            Shape::Instances => {
                let mut best = (u64::MAX, u64::MAX, 10, 4);
                for a in 6..=24u64 {
                    for b in 4..=12u64 {
                        let per = 2 * a * b;
                        if !(48..=160).contains(&per) {
                            continue;
                        }
                        let k = ((t / per as f64).round() as u64).max(1);
                        let key = ((k * per).abs_diff(tris), per.abs_diff(80));
                        if key < (best.0, best.1) {
                            best = (key.0, key.1, a, b);
                        }
                    }
                }
                let torus = Torus::new(best.2, best.3);
                let count = ((t / torus.face_count() as f64).round() as u64).max(1);
                Kind::Instances { torus, count }
            }
            Shape::Fan => {
                let p = (tris / 2).max(1);
                let q = (tris - tris / 2).max(3);
                Kind::Fan { p, q }
            }
            Shape::Single => Kind::Single,
            Shape::Scan => {
                let waves = Waves::octaves(&mut rng, 4, 2, TAU * 2.0, 0.03);
                let holes: Vec<([f64; 2], f64)> = (0..7).map(|_| ([rng.range(0.2, 0.8), rng.range(0.2, 0.8)], rng.range(0.02, 0.06))).collect();
                let phase = rng.range(0.0, TAU);
                // Which cells the scanner saw, on a coarse mask grid (so
                // building is O(rows + mask), whatever the triangle count).
                let m = SCAN_MASK;
                let coarse: Vec<bool> =
                    (0..m * m).map(|i| scan_keeps((i % m) as f64 / m as f64 + 0.5 / m as f64, (i / m) as f64 / m as f64 + 0.5 / m as f64, &holes, phase)).collect();
                let share = (coarse.iter().filter(|&&k| k).count() as f64 / (m * m) as f64).max(0.01);
                let (w, h) = grid_dims(t / 2.0 / share, 1.0, 4);
                let (mx, my) = (m.min(w), m.min(h));
                let col_first: Vec<u64> = (0..=mx).map(|c| c * w / mx).collect();
                let sampled = |cx: u64, cy: u64| coarse[((cy * m / my) * m + cx * m / mx) as usize];
                // A grid too small to sample the mask keeps everything.
                let none = (0..my).all(|cy| (0..mx).all(|cx| !sampled(cx, cy)));
                let seen = |cx: u64, cy: u64| none || sampled(cx, cy);
                let mut prefix = Vec::with_capacity(((mx + 1) * my) as usize);
                for cy in 0..my {
                    let mut acc = 0u64;
                    for cx in 0..mx {
                        prefix.push(acc);
                        if seen(cx, cy) {
                            acc += col_first[cx as usize + 1] - col_first[cx as usize];
                        }
                    }
                    prefix.push(acc);
                }
                let mut row_off = Vec::with_capacity(h as usize + 1);
                let mut kept = 0u64;
                for tt in 0..h {
                    row_off.push(kept);
                    kept += prefix[((tt * my / h) * (mx + 1) + mx) as usize];
                }
                row_off.push(kept);
                Kind::Scan { w, h, waves, noise: 0.15 / w as f64, mx, my, col_first, prefix, row_off }
            }
        };
        let (nv, nf) = match &kind {
            Kind::Sphere { lat, open, dup, .. } => {
                let [n0, n1, _] = lat.n;
                let closed = 2 * lat.qoff[6];
                if *open {
                    (lat.vertex_count() - lat.interior, closed - 2 * n0 * n1)
                } else if *dup {
                    (lat.vertex_count(), 2 * closed)
                } else {
                    (lat.vertex_count(), closed)
                }
            }
            Kind::Grid { w, h, .. } => ((w + 1) * (h + 1), 2 * w * h),
            Kind::Cylinder { s, h } => (s * (h + 1), 2 * s * h),
            Kind::Sheets { w, h } => (2 * (w + 1) * (h + 1), 4 * w * h),
            Kind::Slivers { w, h, dg } => ((w + 1) * (h + 1), (2 * w + dg) * h),
            Kind::Instances { torus, count } => (count * torus.vertex_count(), count * torus.face_count()),
            Kind::Fan { p, q } => (2 + p + q, p + q),
            Kind::Single => (3, 1),
            Kind::Scan { w, h, row_off, .. } => ((w + 1) * (h + 1), 2 * row_off[*h as usize]),
        };
        assert!(nv <= u32::MAX as u64 + 1, "{nv} vertices do not fit u32 indices");
        Generator { shape: opts.shape, seed: opts.seed, attrs: opts.attrs, kind, nv, nf }
    }

    pub fn shape(&self) -> Shape {
        self.shape
    }
    pub fn attrs(&self) -> AttrSet {
        self.attrs
    }
    pub fn vertex_count(&self) -> u64 {
        self.nv
    }
    pub fn face_count(&self) -> u64 {
        self.nf
    }

    /// Vertex `i` (< `vertex_count()`); attributes outside the set keep their defaults.
    pub fn vertex(&self, i: u64) -> Vertex {
        debug_assert!(i < self.nv);
        let a = self.attrs;
        match &self.kind {
            Kind::Sphere { lat, waves, radius, center, .. } => {
                let u = lat.direction(i);
                let (d, g) = waves.eval(u, a.normal());
                let r = radius * (1.0 + d);
                let pos = [center[0] + r * u[0], center[1] + r * u[1], center[2] + r * u[2]];
                self.make(
                    pos,
                    u,
                    || {
                        // Normal of the radial surface r(u) = R(1 + d(u)).
                        let gu = dot(g, u);
                        [0, 1, 2].map(|k| u[k] - (g[k] - gu * u[k]) / (1.0 + d))
                    },
                    || [u[1].atan2(u[0]) / TAU + 0.5, u[2].clamp(-1.0, 1.0).acos() / PI],
                )
            }
            Kind::Grid { w, h, waves } => {
                let (s, t) = (i % (w + 1), i / (w + 1));
                let (x, y) = (s as f64 / *w as f64, t as f64 / *h as f64);
                let (z, g) = waves.eval([x, y, 0.0], a.normal());
                self.make([x, y, z], [x, y, z], || [-g[0], -g[1], 1.0], || [x, y])
            }
            Kind::Scan { w, h, waves, noise, .. } => {
                let (s, t) = (i % (w + 1), i / (w + 1));
                let (x, y) = (s as f64 / *w as f64, t as f64 / *h as f64);
                let (zw, g) = waves.eval([x, y, 0.0], a.normal());
                // A dome, the waves, a thin ridge along a curve, scanner noise.
                let (dx, dy) = (x - 0.5, y - 0.5);
                let dome = 0.35 * (1.0 - 2.0 * (dx * dx + dy * dy)).max(0.0).sqrt();
                let rd = (y - 0.3 - 0.35 * x - 0.08 * fsin(6.0 * x)).abs();
                let ridge = 0.05 * (-(rd / 0.004) * (rd / 0.004)).exp();
                let z = dome + zw + ridge + noise * (2.0 * hash_unit(self.seed ^ 0x5CA7, i) - 1.0);
                self.make([x, y, z], [x, y, z], || [-g[0], -g[1], 1.0], || [x, y])
            }
            Kind::Cylinder { s, h } => {
                let (k, r) = (i % s, i / s);
                let th = TAU * k as f64 / *s as f64;
                let (c, sn) = (fcos(th), fsin(th));
                let z = -1.0 + 2.0 * r as f64 / *h as f64;
                self.make([c, sn, z], [c, sn, z], || [c, sn, 0.0], || [k as f64 / *s as f64, r as f64 / *h as f64])
            }
            Kind::Sheets { w, h } => {
                let per = (w + 1) * (h + 1);
                let (sheet, l) = (i / per, i % per);
                let (s, t) = (l % (w + 1), l / (w + 1));
                let (x, y) = (s as f64 / *w as f64, t as f64 / *h as f64);
                let (z, nz) = if sheet == 0 { (0.0, -1.0) } else { (SHEET_GAP, 1.0) };
                self.make([x, y, z], [x, y, z], || [0.0, 0.0, nz], || [x, y])
            }
            Kind::Slivers { w, h, .. } => {
                let (s, t) = (i % (w + 1), i / (w + 1));
                let x = s as f64 / *w as f64;
                let y = t as f64 * (SLIVER_ASPECT / *w as f64);
                self.make([x, y, 0.0], [x, t as f64 / *h as f64, 0.0], || [0.0, 0.0, 1.0], || [x, t as f64 / *h as f64])
            }
            Kind::Instances { torus, .. } => {
                let (inst, l) = (i / torus.vertex_count(), (i % torus.vertex_count()) as usize);
                let (rot, scale, tr) = self.instance_transform(inst);
                let p = torus.pos[l];
                let rp = mat_mul(&rot, p);
                let pos = [0, 1, 2].map(|k| tr[k] + scale * rp[k]);
                self.make(pos, pos.map(|c| c / 10.0), || mat_mul(&rot, torus.normal[l]), || torus.uv[l])
            }
            Kind::Fan { p, q } => {
                let (pos, n, uv) = if i == 0 {
                    ([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0])
                } else if i == 1 {
                    ([0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 1.0])
                } else if i < 2 + p {
                    let f = (i - 2) as f64 / *p as f64;
                    let th = TAU * f;
                    let (c, s) = (fcos(th), fsin(th));
                    ([c, s, 0.5], [-s, c, 0.0], [f, 0.5])
                } else {
                    let f = (i - 2 - p) as f64 / *q as f64;
                    let th = TAU * f;
                    ([1.5 * fcos(th), 1.5 * fsin(th), 0.0], [0.0, 0.0, 1.0], [f, 0.0])
                };
                self.make(pos, pos, || n, || uv)
            }
            Kind::Single => {
                let pos = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]][i as usize];
                self.make(pos, pos, || [0.0, 0.0, 1.0], || [pos[0], pos[1]])
            }
        }
    }

    /// Triangle `j` (< `face_count()`), wound outward where there is an outside.
    pub fn face(&self, j: u64) -> [u32; 3] {
        debug_assert!(j < self.nf);
        match &self.kind {
            Kind::Sphere { lat, dup, .. } => {
                let closed = 2 * lat.qoff[6];
                lat.face(if *dup { j % closed } else { j })
            }
            Kind::Grid { w, .. } => grid_face(*w, j, 0, false),
            Kind::Cylinder { s, .. } => {
                let q = j / 2;
                let (k, r) = (q % s, q / s);
                let k1 = (k + 1) % s;
                let v = |k: u64, r: u64| (k + r * s) as u32;
                if j & 1 == 0 {
                    [v(k, r), v(k1, r), v(k1, r + 1)]
                } else {
                    [v(k, r), v(k1, r + 1), v(k, r + 1)]
                }
            }
            Kind::Sheets { w, h } => {
                let per = 2 * w * h;
                let sheet = j / per;
                grid_face(*w, j % per, sheet * (w + 1) * (h + 1), sheet == 0)
            }
            Kind::Slivers { w, dg, .. } => {
                let per = 2 * w + dg;
                let (row, r) = (j / per, j % per);
                if r < 2 * w {
                    grid_face(*w, row * 2 * w + r, 0, false)
                } else {
                    let k = r - 2 * w;
                    let v = |s: u64| (s + row * (w + 1)) as u32;
                    [v(2 * k), v(2 * k + 1), v(2 * k + 2)]
                }
            }
            Kind::Instances { torus, .. } => {
                let (inst, l) = (j / torus.face_count(), j % torus.face_count());
                torus.face(l).map(|v| (v + inst * torus.vertex_count()) as u32)
            }
            Kind::Fan { p, q } => {
                if j < *p {
                    [0, 1, (2 + j) as u32]
                } else {
                    let k = j - p;
                    let ring = |k: u64| (2 + p + k % q) as u32;
                    [0, ring(k), ring(k + 1)]
                }
            }
            Kind::Single => [0, 1, 2],
            Kind::Scan { w, h, mx, my, col_first, prefix, row_off, .. } => {
                let q = j / 2;
                let t = row_off.partition_point(|&o| o <= q) as u64 - 1;
                let k = q - row_off[t as usize];
                let cy = t * my / h;
                let row = &prefix[(cy * (mx + 1)) as usize..((cy + 1) * (mx + 1)) as usize];
                // The coarse column holding the k-th kept cell (kept columns only grow the prefix).
                let cx = row.partition_point(|&p| p <= k) - 1;
                let s = col_first[cx] + (k - row[cx]);
                grid_face(*w, 2 * (s + t * w) + (j & 1), 0, false)
            }
        }
    }

    /// The whole mesh in memory (for small tests).
    pub fn mesh(&self) -> (Vec<Vertex>, Vec<[u32; 3]>) {
        ((0..self.nv).map(|i| self.vertex(i)).collect(), (0..self.nf).map(|j| self.face(j)).collect())
    }

    /// Rotation, scale and translation of instance `k`.
    #[inline]
    fn instance_transform(&self, k: u64) -> ([[f64; 3]; 3], f64, [f64; 3]) {
        let r = |n: u64| hash_unit(self.seed ^ 0x1234_5678_9ABC_DEF0, k.wrapping_mul(8).wrapping_add(n));
        // Uniform random rotation (Shoemake).
        let (u1, u2, u3) = (r(0), r(1), r(2));
        let (s1, s2) = ((1.0 - u1).sqrt(), u1.sqrt());
        let (t2, t3) = (TAU * u2, TAU * u3);
        let (x, y, z, w) = (s1 * fsin(t2), s1 * fcos(t2), s2 * fsin(t3), s2 * fcos(t3));
        let rot = [
            [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - z * w), 2.0 * (x * z + y * w)],
            [2.0 * (x * y + z * w), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - x * w)],
            [2.0 * (x * z - y * w), 2.0 * (y * z + x * w), 1.0 - 2.0 * (x * x + y * y)],
        ];
        let scale = 0.5 + 1.5 * r(3);
        (rot, scale, [100.0 * r(4), 100.0 * r(5), 100.0 * r(6)])
    }

    /// Fills the requested attributes: unit normal, color from the smooth
    /// function of `cpos` (a shape-local position), uv.
    #[inline]
    fn make(&self, pos: [f64; 3], cpos: [f64; 3], normal: impl FnOnce() -> [f64; 3], uv: impl FnOnce() -> [f64; 2]) -> Vertex {
        let a = self.attrs;
        let mut v = Vertex { pos, ..Vertex::default() };
        if a.normal() {
            let n = normal();
            let l = dot(n, n).sqrt();
            v.normal = if l.is_finite() && l > 1e-300 {
                [(n[0] / l) as f32, (n[1] / l) as f32, (n[2] / l) as f32]
            } else {
                [0.0, 0.0, 1.0]
            };
        }
        if a.color() {
            let c = |x: f64| round(255.0 * (0.5 + 0.5 * fsin(x))).clamp(0.0, 255.0) as u8;
            let [x, y, z] = cpos;
            v.color = [
                c(3.0 * x),
                c(3.0 * y + 1.0),
                c(3.0 * z + 2.0),
                if a.alpha() { c(2.0 * (x + y + z) + 0.5) } else { 255 },
            ];
        }
        if a.uv() {
            let t = uv();
            v.uv = [t[0] as f32, t[1] as f32];
        }
        v
    }
}

#[inline]
fn mat_mul(m: &[[f64; 3]; 3], p: [f64; 3]) -> [f64; 3] {
    [dot(m[0], p), dot(m[1], p), dot(m[2], p)]
}

/// Side of the scan's coarse visibility mask.
const SCAN_MASK: u64 = 512;

/// Whether the scan keeps the cell centred at (x, y): inside a ragged
/// silhouette and outside the holes and a dropout band.
fn scan_keeps(x: f64, y: f64, holes: &[([f64; 2], f64)], phase: f64) -> bool {
    let (dx, dy) = (x - 0.5, y - 0.5);
    let r = (dx * dx + dy * dy).sqrt();
    let ang = dy.atan2(dx);
    let edge = 0.46 + 0.025 * fsin(7.0 * ang + phase) + 0.012 * fsin(23.0 * ang + 2.0 * phase);
    if r > edge {
        return false;
    }
    if holes.iter().any(|(c, rad)| (x - c[0]).powi(2) + (y - c[1]).powi(2) < rad * rad) {
        return false;
    }
    // A dropout band (a shadowed strip), broken in places.
    let band = (x + 0.6 * y - 0.95 - 0.02 * fsin(15.0 * y)).abs();
    !(band < 0.008 && fsin(40.0 * y + phase) > -0.3)
}

/// Triangle `j` of a grid `w` quads wide with vertices `base + s + t(w+1)`,
/// counter-clockwise seen from +z (or from -z when `flip`).
#[inline]
fn grid_face(w: u64, j: u64, base: u64, flip: bool) -> [u32; 3] {
    let q = j / 2;
    let (s, t) = (q % w, q / w);
    let v = |s: u64, t: u64| (base + s + t * (w + 1)) as u32;
    let f = if j & 1 == 0 { [v(s, t), v(s + 1, t), v(s + 1, t + 1)] } else { [v(s, t), v(s + 1, t + 1), v(s, t + 1)] };
    if flip {
        [f[0], f[2], f[1]]
    } else {
        f
    }
}

// ---------------------------------------------------------------------------
// Streaming to PLY.

/// Target size of one encoded chunk.
const CHUNK_BYTES: usize = 4 << 20;

#[derive(Clone, Copy)]
enum Job {
    Vertices(u64, u64),
    Faces(u64, u64),
}

/// Chunks of about `chunk_bytes` encoded bytes covering all vertices, then all faces.
fn make_jobs(g: &Generator, enc: &PlyEncoder, chunk_bytes: usize) -> Vec<Job> {
    let (nv, nf) = (g.vertex_count(), g.face_count());
    let vchunk = (chunk_bytes / enc.approx_vertex_size().max(1)).clamp(64, 1 << 20) as u64;
    let fchunk = (chunk_bytes / enc.approx_face_size().max(1)).clamp(64, 1 << 20) as u64;
    let mut jobs = Vec::new();
    for a in (0..nv).step_by(vchunk as usize) {
        jobs.push(Job::Vertices(a, (a + vchunk).min(nv)));
    }
    for a in (0..nf).step_by(fchunk as usize) {
        jobs.push(Job::Faces(a, (a + fchunk).min(nf)));
    }
    jobs
}

fn encode(g: &Generator, enc: &PlyEncoder, job: Job, buf: &mut Vec<u8>) -> io::Result<()> {
    buf.clear();
    match job {
        Job::Vertices(a, b) => {
            buf.reserve((b - a) as usize * enc.approx_vertex_size());
            for i in a..b {
                enc.vertex(&g.vertex(i), buf);
            }
        }
        Job::Faces(a, b) => {
            buf.reserve((b - a) as usize * enc.approx_face_size());
            for j in a..b {
                enc.face(&g.face(j), buf)?;
            }
        }
    }
    Ok(())
}

/// Streams the generated mesh as a PLY to `w`: windows of chunks (a few MiB
/// each) are encoded in parallel with rayon while a writer thread writes the
/// finished chunks in order from a bounded queue, so memory stays at about two
/// windows whatever the mesh size. `wopts.attrs` is used as given (see
/// [`write`]). Returns the bytes written.
pub fn write_to<W: Write + Send>(g: &Generator, wopts: &PlyWriteOptions, w: W, quiet: bool) -> io::Result<u64> {
    stream(g, wopts, w, quiet, CHUNK_BYTES)
}

fn stream<W: Write + Send>(
    g: &Generator,
    wopts: &PlyWriteOptions,
    w: W,
    quiet: bool,
    chunk_bytes: usize,
) -> io::Result<u64> {
    let (nv, nf) = (g.vertex_count(), g.face_count());
    let mut pw = PlyWriter::new(w, wopts, nv, nf)?;
    let enc = pw.encoder().clone();
    let total_bytes = match (enc.vertex_record_size(), enc.face_record_size(3)) {
        (Some(vs), Some(fs)) if enc.encoding() != Encoding::Ascii => Some(pw.bytes_written() + nv * vs as u64 + nf * fs as u64),
        _ => None,
    };
    let progress = match total_bytes {
        Some(n) => Progress::bytes(n, "generate", quiet),
        None => Progress::items(nv + nf, "generate", quiet),
    };
    let jobs = make_jobs(g, &enc, chunk_bytes);
    // Encoders work on windows of `window` chunks in parallel; a dedicated
    // writer thread takes finished chunks in order from a bounded queue, so
    // writing overlaps encoding and at most ~2 windows are in memory.
    let window = rayon::current_num_threads().clamp(2, 16);
    let by_bytes = total_bytes.is_some();
    let (to_writer, queue) = std::sync::mpsc::sync_channel::<(Job, Vec<u8>)>(window);
    let (recycle, spare) = std::sync::mpsc::channel::<Vec<u8>>();
    std::thread::scope(|scope| -> io::Result<u64> {
        let progress = &progress;
        let writer = scope.spawn(move || -> io::Result<PlyWriter<W>> {
            for (job, buf) in queue {
                let n = match job {
                    Job::Vertices(a, b) => {
                        pw.raw_vertices(&buf, b - a)?;
                        b - a
                    }
                    Job::Faces(a, b) => {
                        pw.raw_faces(&buf, b - a)?;
                        b - a
                    }
                };
                progress.inc(if by_bytes { buf.len() as u64 } else { n });
                let _ = recycle.send(buf);
            }
            Ok(pw)
        });
        let mut encoded = Ok(());
        'outer: for group in jobs.chunks(window) {
            let mut next: Vec<(Job, Vec<u8>)> =
                group.iter().map(|&j| (j, spare.try_recv().unwrap_or_default())).collect();
            encoded = next.par_iter_mut().try_for_each(|(job, buf)| encode(g, &enc, *job, buf));
            if encoded.is_err() {
                break;
            }
            for item in next {
                if to_writer.send(item).is_err() {
                    break 'outer; // the writer failed; its error is reported below
                }
            }
        }
        drop(to_writer);
        let pw = writer.join().expect("writer thread panicked")?;
        encoded?;
        progress.finish();
        let n = pw.bytes_written();
        pw.finish()?;
        Ok(n)
    })
}

/// Streams the mesh for `opts` to a PLY at `path` (atomically: the file
/// appears only when complete), with a progress bar by bytes unless `quiet`.
/// The vertex attributes written are `opts.attrs` (they replace
/// `wopts.attrs`); everything else comes from `wopts`. Returns bytes written.
/// An existing PLY that octolod wrote is replaced only when `force` is set.
pub fn write(opts: &GenOptions, wopts: &PlyWriteOptions, path: &Path, quiet: bool, force: bool) -> Result<u64> {
    let g = Generator::new(opts);
    let wopts = PlyWriteOptions { attrs: opts.attrs, ..wopts.clone() };
    let mut file = AtomicFile::create(path, crate::io::OutputKind::Ply, force)?;
    let n = write_to(&g, &wopts, file.writer(), quiet).ctx(path, "write")?;
    file.commit()?;
    Ok(n)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;

    fn gen(shape: Shape, tris: u64, seed: u64, attrs: u32) -> Generator {
        Generator::new(&GenOptions { shape, tris, seed, attrs: AttrSet(attrs) })
    }

    const ALL_ATTRS: u32 = AttrSet::NORMAL | AttrSet::COLOR | AttrSet::ALPHA | AttrSet::UV | AttrSet::POS_F64;

    /// Directed edge counts.
    fn edges(faces: &[[u32; 3]]) -> HashMap<(u32, u32), u32> {
        let mut m = HashMap::new();
        for f in faces {
            for k in 0..3 {
                *m.entry((f[k], f[(k + 1) % 3])).or_insert(0) += 1;
            }
        }
        m
    }

    /// Every edge used by exactly two faces, in opposite directions.
    fn assert_closed_oriented(faces: &[[u32; 3]]) {
        let e = edges(faces);
        for (&(a, b), &n) in &e {
            assert_eq!(n, 1, "directed edge {a}->{b} used {n} times");
            assert_eq!(e.get(&(b, a)), Some(&1), "edge {a}-{b} has no opposite");
        }
        let mut und: HashMap<(u32, u32), u32> = HashMap::new();
        for &(a, b) in e.keys() {
            *und.entry((a.min(b), a.max(b))).or_insert(0) += 1;
        }
        assert!(und.values().all(|&n| n == 2));
    }

    fn all_referenced(nv: u64, faces: &[[u32; 3]]) -> bool {
        let mut used = vec![false; nv as usize];
        for f in faces {
            for &i in f {
                used[i as usize] = true;
            }
        }
        used.iter().all(|&u| u)
    }

    #[test]
    fn counts_are_close_to_target() {
        for shape in Shape::ALL {
            for tris in [1000u64, 4321, 12_345, 100_000] {
                let g = gen(shape, tris, 7, 0);
                let nf = g.face_count();
                if shape == Shape::Single {
                    assert_eq!((nf, g.vertex_count()), (1, 3));
                    continue;
                }
                let err = nf.abs_diff(tris) as f64 / tris as f64;
                assert!(err <= 0.012, "{shape:?} tris {tris}: got {nf} ({:.2}%)", 100.0 * err);
            }
            // Tiny targets still give a valid mesh.
            for tris in [0u64, 1, 2, 5] {
                let g = gen(shape, tris, 7, 0);
                assert!(g.face_count() >= 1 && g.vertex_count() >= 3, "{shape:?} {tris}");
                let (v, f) = g.mesh();
                assert!(f.iter().flatten().all(|&i| (i as usize) < v.len()));
            }
        }
    }

    #[test]
    fn large_targets_are_cheap_and_close() {
        for shape in Shape::ALL {
            for tris in [10_000_000u64, 1_000_000_000] {
                let g = gen(shape, tris, 1, 0);
                if shape != Shape::Single {
                    let err = g.face_count().abs_diff(tris) as f64 / tris as f64;
                    assert!(err < 0.01, "{shape:?} {tris}: {}", g.face_count());
                }
                assert!(g.vertex_count() <= u32::MAX as u64);
                // The last vertex and face are valid.
                let v = g.vertex(g.vertex_count() - 1);
                assert!(v.pos.iter().all(|c| c.is_finite()));
                let f = g.face(g.face_count() - 1);
                assert!(f.iter().all(|&i| (i as u64) < g.vertex_count()), "{shape:?} {f:?}");
            }
        }
    }

    #[test]
    fn vertices_finite_indices_valid_attributes_sane() {
        for shape in Shape::ALL {
            let g = gen(shape, 3000, 3, ALL_ATTRS);
            let (vs, fs) = g.mesh();
            assert_eq!(vs.len() as u64, g.vertex_count());
            assert_eq!(fs.len() as u64, g.face_count());
            for v in &vs {
                assert!(v.pos.iter().all(|c| c.is_finite()), "{shape:?}");
                let l: f32 = v.normal.iter().map(|c| c * c).sum::<f32>().sqrt();
                assert!((l - 1.0).abs() < 1e-5, "{shape:?} normal {:?}", v.normal);
                assert!(v.uv.iter().all(|c| c.is_finite()));
            }
            assert!(fs.iter().flatten().all(|&i| (i as u64) < g.vertex_count()), "{shape:?}");
            // A scan keeps the vertices of its dropped cells, as scanners write them.
            assert_eq!(all_referenced(g.vertex_count(), &fs), shape != Shape::Scan, "{shape:?}: unreferenced vertices");
            if matches!(
                shape,
                Shape::Sphere | Shape::Terrain | Shape::Plane | Shape::Cylinder | Shape::Sheets | Shape::Open | Shape::Instances
            ) {
                assert!(fs.iter().all(|f| f[0] != f[1] && f[1] != f[2] && f[0] != f[2]), "{shape:?} repeats an index");
            }
            // Alpha varies when requested, and is 255 otherwise.
            assert!(vs.iter().any(|v| v.color[3] != 255) || shape == Shape::Single);
            let g2 = gen(shape, 3000, 3, AttrSet::COLOR);
            assert!(g2.vertex(0).color[3] == 255 && g2.vertex(0).normal == [0.0; 3]);
        }
    }

    #[test]
    fn sphere_like_meshes_are_closed() {
        for tris in [12u64, 100, 1000, 5000] {
            let g = gen(Shape::Sphere, tris, 1, 0);
            let (vs, fs) = g.mesh();
            assert_closed_oriented(&fs);
            // Euler characteristic of a sphere.
            assert_eq!(vs.len() as i64 - (fs.len() as i64 * 3 / 2) + fs.len() as i64, 2);
            // Outward: signed volume positive, close to that of a unit ball.
            let vol: f64 = fs
                .iter()
                .map(|f| {
                    let [a, b, c] = f.map(|i| vs[i as usize].pos);
                    let cr = [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
                    dot(cr, c) / 6.0
                })
                .sum();
            if tris >= 1000 {
                assert!((vol - 4.0 / 3.0 * PI).abs() < 0.5, "volume {vol}");
            } else {
                assert!(vol > 0.5);
            }
            // No two vertices at the same place.
            let mut ps: Vec<[u64; 3]> = vs.iter().map(|v| v.pos.map(f64::to_bits)).collect();
            ps.sort();
            ps.dedup();
            assert_eq!(ps.len(), vs.len());
        }
        for tris in [50u64, 1000, 3000] {
            assert_closed_oriented(&gen(Shape::Instances, tris, 5, 0).mesh().1);
            assert_closed_oriented(&gen(Shape::Offset, tris, 5, 0).mesh().1);
        }
    }

    #[test]
    fn open_shapes_have_borders() {
        for shape in [Shape::Open, Shape::Terrain, Shape::Plane, Shape::Cylinder, Shape::Sheets] {
            let (_, fs) = gen(shape, 2000, 1, 0).mesh();
            let e = edges(&fs);
            let border = e.keys().filter(|&&(a, b)| !e.contains_key(&(b, a))).count();
            assert!(border > 0, "{shape:?}");
            assert!(e.values().all(|&n| n == 1), "{shape:?}: a directed edge is used twice");
        }
    }

    #[test]
    fn hard_cases_are_what_they_claim() {
        // Duplicates: each face exactly twice, the half a closed mesh.
        let (_, fs) = gen(Shape::Duplicates, 2000, 1, 0).mesh();
        let half = fs.len() / 2;
        assert_eq!(&fs[..half], &fs[half..]);
        assert_closed_oriented(&fs[..half]);
        // Slivers: thin strips and zero-area triangles with distinct indices.
        let (vs, fs) = gen(Shape::Slivers, 2000, 1, 0).mesh();
        let mut degenerate = 0;
        let mut min_aspect = f64::INFINITY;
        for f in &fs {
            assert!(f[0] != f[1] && f[1] != f[2] && f[0] != f[2]);
            let [a, b, c] = f.map(|i| vs[i as usize].pos);
            let area2 = ((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])).abs();
            if area2 == 0.0 {
                degenerate += 1;
            } else {
                let longest = [(a, b), (b, c), (c, a)]
                    .iter()
                    .map(|(p, q)| ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2)).sqrt())
                    .fold(0.0, f64::max);
                min_aspect = min_aspect.min(area2 / (longest * longest));
            }
        }
        assert!(degenerate > 0);
        assert!(min_aspect < 1e-5, "{min_aspect}");
        // Sheets: two layers 1e-4 apart.
        let (vs, _) = gen(Shape::Sheets, 1000, 1, 0).mesh();
        let zs: std::collections::BTreeSet<u64> = vs.iter().map(|v| v.pos[2].to_bits()).collect();
        assert_eq!(zs.len(), 2);
        // Plane: flat.
        assert!(gen(Shape::Plane, 1000, 1, 0).mesh().0.iter().all(|v| v.pos[2] == 0.0));
        // Cylinder: radius 1.
        for v in gen(Shape::Cylinder, 1000, 1, 0).mesh().0 {
            assert!(((v.pos[0].powi(2) + v.pos[1].powi(2)).sqrt() - 1.0).abs() < 1e-8 && v.pos[2].abs() <= 1.0);
        }
        // Offset: near 1e6 with sub-1e-2 detail.
        let g = gen(Shape::Offset, 2000, 1, AttrSet::POS_F64);
        for v in g.mesh().0 {
            let r = v.pos.map(|c| c - 1e6);
            assert!(v.pos.iter().all(|&c| (c - 1e6).abs() < 0.6));
            assert!((dot(r, r).sqrt() - 0.5).abs() < 0.01);
        }
        // Fan: one edge shared by many triangles.
        let (_, fs) = gen(Shape::Fan, 1000, 1, 0).mesh();
        let spine = fs.iter().filter(|f| f.contains(&0) && f.contains(&1)).count();
        assert!(spine >= 400);
        let single = gen(Shape::Single, 1_000_000, 1, 0);
        assert_eq!(single.mesh().1, vec![[0, 1, 2]]);
    }

    #[test]
    fn deterministic_per_seed() {
        for shape in Shape::ALL {
            let a = gen(shape, 5000, 42, ALL_ATTRS).mesh();
            let b = gen(shape, 5000, 42, ALL_ATTRS).mesh();
            assert_eq!(a, b, "{shape:?}");
        }
        for shape in [Shape::Sphere, Shape::Terrain, Shape::Instances, Shape::Offset, Shape::Open, Shape::Duplicates] {
            let a = gen(shape, 5000, 1, 0).mesh();
            let b = gen(shape, 5000, 2, 0).mesh();
            assert_eq!(a.1, b.1, "{shape:?}: connectivity does not depend on the seed");
            assert_ne!(a.0, b.0, "{shape:?}: seed changes nothing");
        }
        // Random access agrees with sequential generation.
        let g = gen(Shape::Instances, 5000, 9, ALL_ATTRS);
        let (vs, fs) = g.mesh();
        for i in (0..vs.len()).rev().step_by(97) {
            assert_eq!(g.vertex(i as u64), vs[i]);
        }
        for j in (0..fs.len()).rev().step_by(89) {
            assert_eq!(g.face(j as u64), fs[j]);
        }
    }

    #[test]
    fn fast_sin_is_accurate() {
        for k in -2000..2000 {
            let x = k as f64 * 0.01237;
            assert!((fsin(x) - x.sin()).abs() < 1e-9, "{x}");
            assert!((fcos(x) - x.cos()).abs() < 1e-9, "{x}");
        }
    }

    #[test]
    fn streamed_file_matches_in_memory_mesh() {
        let d = tempfile::tempdir().unwrap();
        for encoding in [Encoding::BinaryLe, Encoding::BinaryBe, Encoding::Ascii] {
            let opts = GenOptions { shape: Shape::Sphere, tris: 5000, seed: 3, attrs: AttrSet(ALL_ATTRS) };
            let wopts = PlyWriteOptions { encoding, ..Default::default() };
            let p = d.path().join("s.ply");
            let n = write(&opts, &wopts, &p, true, true).unwrap();
            let bytes = std::fs::read(&p).unwrap();
            assert_eq!(n as usize, bytes.len());
            let (vs, fs) = Generator::new(&opts).mesh();
            let mut expect = Vec::new();
            crate::ply::write::write_ply(&d.path().join("m.ply"), &PlyWriteOptions { attrs: opts.attrs, ..wopts.clone() }, &vs, &fs)
                .unwrap();
            expect.extend(std::fs::read(d.path().join("m.ply")).unwrap());
            assert!(bytes == expect, "{encoding:?}");
        }
    }

    #[test]
    fn chunked_stream_equals_sequential_writer() {
        for (shape, encoding, attrs) in [
            (Shape::Terrain, Encoding::BinaryLe, AttrSet::NORMAL),
            (Shape::Instances, Encoding::BinaryBe, AttrSet::COLOR | AttrSet::UV),
            (Shape::Fan, Encoding::Ascii, AttrSet::POS_F64 | AttrSet::NORMAL),
        ] {
            let g = gen(shape, 30_000, 2, attrs);
            let wopts = PlyWriteOptions { encoding, attrs: g.attrs(), ..Default::default() };
            let mut out = Vec::new();
            let n = stream(&g, &wopts, &mut out, true, 3000).unwrap();
            assert_eq!(n as usize, out.len());
            let mut w = PlyWriter::new(Vec::new(), &wopts, g.vertex_count(), g.face_count()).unwrap();
            for i in 0..g.vertex_count() {
                w.vertex(&g.vertex(i)).unwrap();
            }
            for j in 0..g.face_count() {
                w.face(&g.face(j)).unwrap();
            }
            assert!(w.finish().unwrap() == out, "{shape:?}");
        }
    }
}

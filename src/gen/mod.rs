//! Deterministic procedural meshes, from one triangle to 10^9, for tests,
//! benchmarks and the `octolod-gen` tool.
//!
//! Takes: [`GenOptions`] (shape, target triangle count, seed, attributes).
//! Gives: a [`Generator`], a random-access indexed mesh whose `vertex(i)` and
//! `face(j)` are pure functions of the options and the index (randomness comes
//! from hashing the seed with the index, trigonometry from a portable
//! polynomial), so the output is identical whatever the chunking or thread
//! count and nothing is ever held in memory; and [`write`](fn@write), which streams a
//! generated mesh to a PLY with parallel chunk encoding.
//!
//! Shapes: smooth closed ones ([`Shape::Sphere`], [`Shape::Terrain`],
//! [`Shape::Instances`]) and hard cases for numerical robustness (flat,
//! rank-2, nearly coincident sheets, slivers and collinear triangles,
//! duplicated faces, far from the origin, a single triangle, non-manifold
//! fans, an open sphere). See [`Shape`] for each.

pub mod atlas;
mod portable;
mod shapes;
#[cfg(test)]
mod tests;
mod write;

pub use write::{write, write_other, write_to, OtherFormat};

use crate::geom::dot;
use crate::mesh::{AttrSet, Vertex};
use portable::{fcos, fsin, hash_unit, round, Rng};
use shapes::{box_dims, grid_dims, BoxLattice, Torus, Waves};
use std::f64::consts::{PI, TAU};

/// Which procedural mesh to generate; [`Shape::about`] describes each
/// (octolod-gen's `--help` shows the same text).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Shape {
    Sphere,
    Terrain,
    Instances,
    Plane,
    Cylinder,
    Sheets,
    Slivers,
    Duplicates,
    Offset,
    Single,
    Fan,
    Open,
    Scan,
}

impl Shape {
    /// What the shape is (one paragraph; octolod-gen's `--help` text).
    pub fn about(self) -> &'static str {
        match self {
            Shape::Sphere => "Closed sphere of radius ~1 with smooth seeded bumps (amplitude ~0.05), a cube-sphere with shared seam vertices.",
            Shape::Terrain => "Heightfield over [0,1]² with smooth multi-octave seeded height; open border.",
            Shape::Instances => "Many closed tori (~48–160 triangles each), randomly placed, rotated and scaled in [0,100]³.",
            Shape::Plane => "Flat grid in z = 0 over [0,1]²; open border (rank-1 quadrics).",
            Shape::Cylinder => "Open tube, radius 1, z in [-1,1] (rank-2 quadrics).",
            Shape::Sheets => "Two parallel open grids over [0,1]², 1e-4 apart (z = 0 facing down, z = 1e-4 facing up).",
            Shape::Slivers => "Grid of strips with aspect ratio 1e-6, plus zero-area triangles made of three distinct collinear vertices.",
            Shape::Duplicates => "A closed sphere in which every face appears twice (same indices).",
            Shape::Offset => "Sphere of radius 0.5 centred at (1e6, 1e6, 1e6) with 1e-3 detail (meaningful only with double positions).",
            Shape::Single => "Exactly one triangle.",
            Shape::Fan => "Non-manifold: a \"book\" of triangles sharing one edge, and a fan disc whose centre is one end of that edge.",
            Shape::Open => "A sphere with one cap (a whole cube-face patch) removed; open border.",
            Shape::Scan => "A range scan: a depth-image grid over [0,1]² of a bumpy dome with a thin ridge, per-vertex scanner noise, holes (dropouts) and a long ragged silhouette border; unreferenced vertices stay in the file.",
        }
    }
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

#[derive(Clone, Debug)]
enum Kind {
    /// Sphere, Open, Duplicates, Offset.
    Sphere {
        lat: BoxLattice,
        waves: Waves,
        radius: f64,
        center: [f64; 3],
        open: bool,
        dup: bool,
    },
    /// Terrain and Plane: a (w+1)×(h+1) vertex grid over [0,1]².
    Grid {
        w: u64,
        h: u64,
        waves: Waves,
    },
    Cylinder {
        s: u64,
        h: u64,
    },
    Sheets {
        w: u64,
        h: u64,
    },
    /// `w` columns of sliver quads per row, `dg` collinear triangles per row.
    Slivers {
        w: u64,
        h: u64,
        dg: u64,
    },
    Instances {
        torus: Torus,
        count: u64,
    },
    /// `p` pages on the spine edge, `q` triangles in the fan disc.
    Fan {
        p: u64,
        q: u64,
    },
    /// A (w+1)×(h+1) vertex grid; the kept cells follow an mx × my coarse
    /// mask: `prefix[cy * (mx+1) + cx]` kept fine cells left of coarse
    /// column cx in a fine row of coarse row cy; `col_first[cx]` the first
    /// fine column of cx; `row_off[t]` kept cells before fine row t.
    Scan {
        w: u64,
        h: u64,
        waves: Waves,
        noise: f64,
        mx: u64,
        my: u64,
        col_first: Vec<u64>,
        prefix: Vec<u64>,
        row_off: Vec<u64>,
    },
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

impl Kind {
    /// The shape's parameters for about `tris` triangles (already clamped),
    /// drawing from `rng`, the generator's seeded stream, in a fixed order.
    fn new(shape: Shape, tris: u64, rng: &mut Rng) -> Kind {
        let t = tris as f64;
        match shape {
            Shape::Sphere | Shape::Open | Shape::Duplicates | Shape::Offset => Kind::sphere(shape, tris, rng),
            Shape::Terrain | Shape::Plane => {
                let (w, h) = grid_dims(t / 2.0, 1.0, 1);
                let waves = if shape == Shape::Terrain { Waves::octaves(rng, 5, 2, TAU * 1.5, 0.12) } else { Waves::none() };
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
            Shape::Instances => Kind::instances(tris),
            Shape::Fan => {
                let p = (tris / 2).max(1);
                let q = (tris - tris / 2).max(3);
                Kind::Fan { p, q }
            }
            Shape::Single => Kind::Single,
            Shape::Scan => Kind::scan(tris, rng),
        }
    }

    /// Sphere, Open, Duplicates and Offset: a cube-sphere lattice sized so
    /// the shape's own face count (a cap fewer, or every face twice) is near `tris`.
    fn sphere(shape: Shape, tris: u64, rng: &mut Rng) -> Kind {
        let sphere_count = |a: u64, b: u64, c: u64| 4 * (a * b + b * c + a * c);
        let (open, dup) = (shape == Shape::Open, shape == Shape::Duplicates);
        let n = if open {
            box_dims(tris, |a, b, c| sphere_count(a, b, c) - 2 * a * b)
        } else if dup {
            box_dims(tris, |a, b, c| 2 * sphere_count(a, b, c))
        } else {
            box_dims(tris, sphere_count)
        };
        let (radius, center, waves) = if shape == Shape::Offset {
            // 1e-3 absolute detail on radius 0.5.
            (0.5, [OFFSET_CENTER; 3], Waves::random(rng, 6, false, (6.0, 20.0), 2e-3 / 6f64.sqrt()))
        } else {
            (1.0, [0.0; 3], Waves::random(rng, 6, false, (2.0, 7.0), 0.05 / 6f64.sqrt()))
        };
        Kind::Sphere { lat: BoxLattice::new(n), waves, radius, center, open, dup }
    }

    /// Instances: the torus (48..=160 triangles, nearest 80 on ties) whose
    /// whole copies come nearest `tris`, and how many copies.
    fn instances(tris: u64) -> Kind {
        let t = tris as f64;
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

    /// Scan: the depth grid and its kept-cell tables (see [`Kind::Scan`]).
    fn scan(tris: u64, rng: &mut Rng) -> Kind {
        let t = tris as f64;
        let waves = Waves::octaves(rng, 4, 2, TAU * 2.0, 0.03);
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

    /// Vertex and face counts.
    fn counts(&self) -> (u64, u64) {
        match self {
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
        }
    }
}

impl Generator {
    pub fn new(opts: &GenOptions) -> Generator {
        let tris = opts.tris.clamp(1, MAX_TRIS);
        let mut rng = Rng::new(opts.seed, opts.shape as u64 + 1);
        let kind = Kind::new(opts.shape, tris, &mut rng);
        let (nv, nf) = kind.counts();
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
            v.normal = if l.is_finite() && l > 1e-300 { [(n[0] / l) as f32, (n[1] / l) as f32, (n[2] / l) as f32] } else { [0.0, 0.0, 1.0] };
        }
        if a.color() {
            let c = |x: f64| round(255.0 * (0.5 + 0.5 * fsin(x))).clamp(0.0, 255.0) as u8;
            let [x, y, z] = cpos;
            v.color = [c(3.0 * x), c(3.0 * y + 1.0), c(3.0 * z + 2.0), if a.alpha() { c(2.0 * (x + y + z) + 0.5) } else { 255 }];
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

//! Quadric throughput: `from_triangle` + `add`, `add_triangle` and `solve`,
//! in ns per operation, for position-only (dim 3) and all-attribute (dim 11)
//! quadrics. A plain `main` (no criterion, `harness = false`); it was a
//! `#[test]` inside `src/quadric.rs` before, which timed itself on every
//! `cargo test`. Run with `cargo bench --bench quadric`.

use octolod::mesh::{AttrSet, Vertex};
use octolod::quadric::{AttrWeights, Quadric, QuadricSpace, DEFAULT_REL_TOL, MAX_DIM};
use std::hint::black_box;
use std::time::Instant;

/// splitmix64 in [0, 1) (the unit tests' generator, same points).
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
}

fn main() {
    println!("size_of::<Quadric>() = {} bytes", std::mem::size_of::<Quadric>());
    for (attrs, iters) in [
        (AttrSet::POSITION_ONLY, 2_000_000usize),
        (AttrSet(AttrSet::UV | AttrSet::NORMAL | AttrSet::COLOR), 400_000),
    ] {
        let s = QuadricSpace::new(attrs, AttrWeights::for_extent(1.0), [0.0; 3]);
        let mut rng = Rng(1);
        let pts: Vec<[f64; MAX_DIM]> = (0..1024)
            .map(|_| {
                let pos = [rng.range(-1.0, 1.0), rng.range(-1.0, 1.0), rng.range(-1.0, 1.0)];
                s.embed(&Vertex { pos, normal: [0.0, 0.0, 1.0], color: [10, 20, 30, 255], uv: [rng.next() as f32, 0.5] })
            })
            .collect();
        let mut acc = Quadric::zero(s.dim);
        let t0 = Instant::now();
        for i in 0..iters {
            let (p, q, r) = (&pts[i % 1024], &pts[(i + 1) % 1024], &pts[(i + 7) % 1024]);
            acc.add(&Quadric::from_triangle(&s, black_box(p), q, r));
        }
        let t1 = t0.elapsed().as_nanos() as f64 / iters as f64;
        let t0 = Instant::now();
        for i in 0..iters {
            let (p, q, r) = (&pts[i % 1024], &pts[(i + 1) % 1024], &pts[(i + 7) % 1024]);
            acc.add_triangle(black_box(p), q, r);
        }
        let t2 = t0.elapsed().as_nanos() as f64 / iters as f64;
        let solves = 20_000;
        let t0 = Instant::now();
        for _ in 0..solves {
            black_box(black_box(&acc).solve(DEFAULT_REL_TOL, None));
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

//! Quadric throughput: `from_triangle` + `add`, `add_triangle` and `solve`,
//! in ns per operation, for position-only (dim 3) and all-attribute (dim 11)
//! quadrics. A plain `main` (no criterion, `harness = false`); it was a
//! `#[test]` inside `src/quadric.rs` before, which timed itself on every
//! `cargo test`. Run with `cargo bench --bench quadric`.

use octolod::mesh::{AttrSet, Vertex};
use octolod::quadric::{AttrWeights, Quadric, QuadricSpace, DEFAULT_REL_TOL, MAX_DIM};
use std::hint::black_box;
use std::time::Instant;

fn main() {
    println!("size_of::<Quadric>() = {} bytes", std::mem::size_of::<Quadric>());
    for (attrs, iters) in [(AttrSet::POSITION_ONLY, 2_000_000usize), (AttrSet(AttrSet::UV | AttrSet::NORMAL | AttrSet::COLOR), 400_000)] {
        let s = QuadricSpace::new(attrs, AttrWeights::for_extent(1.0), [0.0; 3]);
        // The unit tests' generator and start: the same points.
        let mut rng = octolod::geom::Rng::from_state(1);
        let pts: Vec<[f64; MAX_DIM]> = (0..1024)
            .map(|_| {
                let pos = [rng.range(-1.0, 1.0), rng.range(-1.0, 1.0), rng.range(-1.0, 1.0)];
                s.embed(&Vertex { pos, normal: [0.0, 0.0, 1.0], color: [10, 20, 30, 255], uv: [rng.f64() as f32, 0.5], material: 0 })
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

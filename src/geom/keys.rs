//! Keys: a position's bits (under which bit-identical positions weld),
//! the one position welder, and Morton (Z-order) keys of integer cells.

use super::P3;
use rustc_hash::FxHashMap;

/// Position bits: equal exactly when the positions are bit-identical (so
/// `-0.0` and `0.0` differ, and a NaN equals only itself).
#[inline]
pub fn pos_bits(p: P3) -> [u64; 3] {
    p.map(f64::to_bits)
}

/// Welds bit-identical positions, numbering them in the order they are met
/// (every weld in the crate: a node's positions, a level's, an unfold's).
#[derive(Default)]
pub struct Welder {
    ids: FxHashMap<[u64; 3], u32>,
}

impl Welder {
    /// Room for `n` distinct positions.
    pub fn with_capacity(n: usize) -> Welder {
        Welder { ids: FxHashMap::with_capacity_and_hasher(n, Default::default()) }
    }

    /// The id of `p`; `new` is called the first time `p` is met (to store it).
    #[inline]
    pub fn id(&mut self, p: P3, new: impl FnOnce(P3)) -> u32 {
        let next = self.ids.len() as u32;
        *self.ids.entry(pos_bits(p)).or_insert_with(|| {
            new(p);
            next
        })
    }

    /// Distinct positions met so far.
    pub fn len(&self) -> usize {
        self.ids.len()
    }

    pub fn is_empty(&self) -> bool {
        self.ids.is_empty()
    }
}

/// The low 21 bits of `x`, two zero bits after each.
fn spread(mut x: u64) -> u64 {
    x &= 0x1f_ffff;
    x = (x | x << 32) & 0x1f00000000ffff;
    x = (x | x << 16) & 0x1f0000ff0000ff;
    x = (x | x << 8) & 0x100f00f00f00f00f;
    x = (x | x << 4) & 0x10c30c30c30c30c3;
    (x | x << 2) & 0x1249249249249249
}

/// The inverse of `spread`.
fn compact(mut x: u64) -> u64 {
    x &= 0x1249249249249249;
    x = (x ^ (x >> 2)) & 0x10c30c30c30c30c3;
    x = (x ^ (x >> 4)) & 0x100f00f00f00f00f;
    x = (x ^ (x >> 8)) & 0x1f0000ff0000ff;
    x = (x ^ (x >> 16)) & 0x1f00000000ffff;
    (x ^ (x >> 32)) & 0x1f_ffff
}

/// Interleaves x, y, z bits (x lowest).
pub fn morton3(x: u64, y: u64, z: u64) -> u64 {
    spread(x) | spread(y) << 1 | spread(z) << 2
}

/// The x, y, z of a Morton key.
pub fn demorton(m: u64) -> (u64, u64, u64) {
    (compact(m), compact(m >> 1), compact(m >> 2))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn morton_round_trips_and_interleaves_x_lowest() {
        assert_eq!(morton3(1, 0, 0), 1);
        assert_eq!(morton3(0, 1, 0), 2);
        assert_eq!(morton3(0, 0, 1), 4);
        for (x, y, z) in [(0, 0, 0), (1, 2, 3), (0x1f_ffff, 0, 0x12345), (0x1f_ffff, 0x1f_ffff, 0x1f_ffff)] {
            assert_eq!(demorton(morton3(x, y, z)), (x, y, z));
        }
    }

    #[test]
    fn welder_numbers_positions_by_first_appearance_and_bits() {
        let mut w = Welder::default();
        let mut kept = Vec::new();
        let ids: Vec<u32> = [[1.0, 2.0, 3.0], [0.0, 0.0, 0.0], [1.0, 2.0, 3.0], [-0.0, 0.0, 0.0]].iter().map(|&p| w.id(p, |p| kept.push(p))).collect();
        assert_eq!(ids, [0, 1, 0, 2]);
        assert_eq!(kept.len(), 3);
        assert_eq!(w.len(), 3);
    }
}

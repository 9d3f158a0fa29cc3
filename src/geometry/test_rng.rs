//! The geometry tests' seeded generator (xorshift64*): enough for sampling test points, and
//! below every layer that could lend one.

use nalgebra::Point3;

/// Deterministic xorshift64* generator; the seed must not be 0.
pub(crate) struct Rng(pub(crate) u64);

impl Rng {
    /// Uniform in [0, 1).
    pub(crate) fn next(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Uniform in [lo, hi).
    pub(crate) fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.next()
    }

    /// Uniform in the cube [lo, hi)³.
    pub(crate) fn point(&mut self, lo: f64, hi: f64) -> Point3<f64> {
        Point3::new(self.range(lo, hi), self.range(lo, hi), self.range(lo, hi))
    }
}

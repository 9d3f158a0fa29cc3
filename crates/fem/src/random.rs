//! A small, seeded, portable pseudo-random number generator (xoshiro256++ seeded through
//! SplitMix64) with uniform and Gaussian samples. The sequence depends only on the seed, so
//! synthetic clouds and test data are reproducible across platforms and thread counts. It
//! sits below every other module: the synthetic data and every module's tests draw from it.

use nalgebra::{Point3, Vector3};

/// Seeded xoshiro256++ generator. Not cryptographic; for synthetic and test data only.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Rng {
    s: [u64; 4],
}

/// One SplitMix64 step: advances `state` and returns the next output.
fn splitmix64(state: &mut u64) -> u64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

impl Rng {
    /// A generator whose whole sequence is determined by `seed` (any value, including 0).
    pub fn new(seed: u64) -> Self {
        let mut sm = seed;
        let s = [
            splitmix64(&mut sm),
            splitmix64(&mut sm),
            splitmix64(&mut sm),
            splitmix64(&mut sm),
        ];
        Self { s }
    }

    /// The next 64 uniformly distributed bits.
    pub fn next_u64(&mut self) -> u64 {
        let s = &mut self.s;
        let result = s[0].wrapping_add(s[3]).rotate_left(23).wrapping_add(s[0]);
        let t = s[1] << 17;
        s[2] ^= s[0];
        s[3] ^= s[1];
        s[1] ^= s[2];
        s[0] ^= s[3];
        s[2] ^= t;
        s[3] = s[3].rotate_left(45);
        result
    }

    /// Uniform sample in `[0, 1)` with 53 random bits.
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Uniform sample in `[lo, hi)`.
    pub fn uniform_in(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.uniform()
    }

    /// Uniform integer in `0..n` (`n > 0`), by Lemire's multiply-and-reject method (unbiased).
    pub fn below(&mut self, n: usize) -> usize {
        assert!(n > 0, "Rng::below(0)");
        let n = n as u64;
        loop {
            let m = (self.next_u64() as u128) * (n as u128);
            let low = m as u64;
            if low >= n.wrapping_neg() % n {
                return (m >> 64) as usize;
            }
        }
    }

    /// Standard normal sample (mean 0, standard deviation 1) by the Box–Muller transform.
    ///
    /// Each call draws two fresh uniforms and returns the cosine branch, so the stream position
    /// after a call does not depend on earlier calls (simpler to reason about than caching).
    pub fn gaussian(&mut self) -> f64 {
        // 1 - u lies in (0, 1], so the logarithm is finite.
        let u1 = 1.0 - self.uniform();
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }

    /// Isotropic 3-D Gaussian vector with standard deviation `sigma` along every axis (so its
    /// component along any fixed direction, e.g. a surface normal, also has deviation `sigma`).
    pub fn gaussian_vector(&mut self, sigma: f64) -> Vector3<f64> {
        Vector3::new(self.gaussian(), self.gaussian(), self.gaussian()) * sigma
    }

    /// A direction uniformly distributed on the unit sphere (a normalised Gaussian vector).
    pub fn unit_vector(&mut self) -> Vector3<f64> {
        loop {
            let v = self.gaussian_vector(1.0);
            let n = v.norm();
            if n > 1e-6 {
                return v / n;
            }
        }
    }

    /// A point uniformly distributed (by area) on the triangle `[a, b, c]`: two uniforms
    /// reflected into the lower half of the unit square are its barycentric coordinates.
    pub fn point_on_triangle(&mut self, [a, b, c]: &[Point3<f64>; 3]) -> Point3<f64> {
        let (mut u, mut v) = (self.uniform(), self.uniform());
        if u + v > 1.0 {
            (u, v) = (1.0 - u, 1.0 - v);
        }
        a + (b - a) * u + (c - a) * v
    }

    /// A point uniformly distributed in the cube `[lo, hi)³`.
    pub fn point_in_cube(&mut self, lo: f64, hi: f64) -> Point3<f64> {
        Point3::new(
            self.uniform_in(lo, hi),
            self.uniform_in(lo, hi),
            self.uniform_in(lo, hi),
        )
    }

    /// Shuffles `items` in place (Fisher–Yates).
    pub fn shuffle<T>(&mut self, items: &mut [T]) {
        for i in (1..items.len()).rev() {
            let j = self.below(i + 1);
            items.swap(i, j);
        }
    }
}

/// FNV-1a (64 bits) of `bytes`: a stable hash for seeds and cache keys, the same on every run
/// and machine; not a security measure.
pub fn fnv1a(bytes: impl IntoIterator<Item = u8>) -> u64 {
    bytes.into_iter().fold(0xcbf2_9ce4_8422_2325, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The published FNV-1a 64-bit test vectors: "" and "a".
    #[test]
    fn fnv1a_matches_the_reference_vectors() {
        assert_eq!(fnv1a([]), 0xcbf2_9ce4_8422_2325);
        assert_eq!(fnv1a(*b"a"), 0xaf63_dc4c_8601_ec8c);
        assert_eq!(fnv1a(*b"foobar"), 0x8594_4171_f739_67e8);
    }

    #[test]
    fn same_seed_same_stream_different_seed_different_stream() {
        let a: Vec<u64> = (0..8)
            .map({
                let mut r = Rng::new(7);
                move |_| r.next_u64()
            })
            .collect();
        let b: Vec<u64> = (0..8)
            .map({
                let mut r = Rng::new(7);
                move |_| r.next_u64()
            })
            .collect();
        let c: Vec<u64> = (0..8)
            .map({
                let mut r = Rng::new(8);
                move |_| r.next_u64()
            })
            .collect();
        assert_eq!(a, b);
        assert_ne!(a, c);
    }

    #[test]
    fn uniform_and_gaussian_moments() {
        let mut r = Rng::new(1);
        let n = 200_000;
        let u: Vec<f64> = (0..n).map(|_| r.uniform()).collect();
        assert!(u.iter().all(|&x| (0.0..1.0).contains(&x)));
        let mean = u.iter().sum::<f64>() / n as f64;
        assert!((mean - 0.5).abs() < 0.005, "{mean}");
        let g: Vec<f64> = (0..n).map(|_| r.gaussian()).collect();
        let gm = g.iter().sum::<f64>() / n as f64;
        let gv = g.iter().map(|x| (x - gm).powi(2)).sum::<f64>() / n as f64;
        assert!(gm.abs() < 0.01, "{gm}");
        assert!((gv - 1.0).abs() < 0.02, "{gv}");
    }

    /// Directions have unit length and no preferred side (mean within 3 standard errors of 0:
    /// each component of a uniform direction has variance 1/3); points on a triangle fall
    /// inside it with the centroid as their mean; points in a cube stay in it.
    #[test]
    fn directions_triangle_and_cube_samples_are_uniform() {
        let mut r = Rng::new(3);
        let n = 100_000;
        let mut sum = Vector3::zeros();
        for _ in 0..n {
            let d = r.unit_vector();
            assert!((d.norm() - 1.0).abs() < 1e-12);
            sum += d;
        }
        let bound = 3.0 * (1.0 / 3.0 / n as f64).sqrt();
        assert!((sum / n as f64).amax() < bound, "{sum}");
        let tri = [
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(3.0, 0.0, 0.0),
            Point3::new(0.0, 3.0, 0.0),
        ];
        let mut mean = Vector3::zeros();
        for _ in 0..n {
            let p = r.point_on_triangle(&tri);
            assert!(p.x >= 0.0 && p.y >= 0.0 && p.x + p.y <= 3.0 + 1e-12 && p.z == 0.0);
            mean += p.coords / n as f64;
        }
        // Each coordinate of a uniform point on this triangle has variance 1/2.
        let bound = 3.0 * (0.5 / n as f64).sqrt();
        assert!(
            (mean - Vector3::new(1.0, 1.0, 0.0)).amax() < bound,
            "{mean}"
        );
        for _ in 0..1000 {
            let p = r.point_in_cube(-2.0, 1.0);
            assert!(p.iter().all(|&c| (-2.0..1.0).contains(&c)));
        }
    }

    #[test]
    fn below_covers_range_uniformly() {
        let mut r = Rng::new(3);
        let mut counts = [0usize; 5];
        for _ in 0..50_000 {
            counts[r.below(5)] += 1;
        }
        for c in counts {
            assert!((9_500..10_500).contains(&c), "{counts:?}");
        }
        let mut v: Vec<usize> = (0..100).collect();
        r.shuffle(&mut v);
        let mut s = v.clone();
        s.sort();
        assert_eq!(s, (0..100).collect::<Vec<_>>());
        assert_ne!(v, s);
    }
}

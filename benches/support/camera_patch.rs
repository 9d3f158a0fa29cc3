//! The cloud the neighbour-list and change-test benchmarks share: a camera's patch of 680
//! points (the phantom's warm clouds) on a curved 12 × 9 cm surface with 1.5 mm noise, m.

use livereg::random::Rng;
use nalgebra::Point3;

/// 680 points drawn from `rng` (the stream continues after them).
pub fn camera_patch(rng: &mut Rng) -> Vec<Point3<f64>> {
    (0..680)
        .map(|_| {
            let (x, y) = (rng.uniform_in(0.0, 0.12), rng.uniform_in(0.0, 0.09));
            let z = 0.03 * (25.0 * x).sin() * (15.0 * y).cos() + 0.0015 * rng.gaussian();
            Point3::new(x, y, z)
        })
        .collect()
}

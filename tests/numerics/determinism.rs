//! Assembly results do not depend on the number of threads.

use crate::common;

use common::*;
use livereg::grid::IntegrationMode;
use livereg::mechanics::{LawKind, Need, VolumetricIntegration};
use livereg::mesh::primitives::icosphere;
use nalgebra::Point3;

#[test]
fn residual_and_tangent_are_identical_with_one_and_two_threads() {
    let s = icosphere(Point3::origin(), 0.05, 4);
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let mut p = problem(
                &s,
                &options(0.012, 3, IntegrationMode::WeightedCell),
                material(LawKind::NeoHookean, 4500.0, 0.49),
                VolumetricIntegration::Reduced,
            );
            let u = Rng(3).vec(p.dofs(), 1e-3);
            let mut r = vec![0.0; p.dofs()];
            let mut k = p.new_tangent();
            let e = p
                .evaluate(&u, 1.0, Need::Tangent, Some(&mut r), Some(&mut k))
                .unwrap();
            (e.potential, r, k.values)
        })
    };
    let (e1, r1, k1) = run(1);
    let (e2, r2, k2) = run(2);
    assert_eq!(e1.to_bits(), e2.to_bits());
    assert_eq!(r1, r2);
    assert_eq!(k1, k2);
}

//! The accuracy and speed table quoted in `FastWinding::eval`: the fast winding number on a
//! 20,480-triangle unit sphere at 2,000 random points of the cube [−2, 2]³ farther than 1 % of
//! the radius from the surface, against the exact sum of solid angles
//! (`winding_number_brute`), for each far-field expansion order and accuracy parameter β.
//! Prints the maximum error and the time per query. Run:
//!
//! `cargo run --release --example winding_accuracy`

use livereg::geometry::{shapes, winding_number_brute, Aabb, Bvh, ExpansionOrder, FastWinding};
use livereg::random::Rng;
use nalgebra::Point3;

fn main() {
    let (vertices, triangles) = shapes::icosphere(5, 1.0);
    let corners: Vec<[Point3<f64>; 3]> = triangles.iter().map(|t| t.map(|i| vertices[i])).collect();
    let boxes: Vec<Aabb> = corners.iter().map(Aabb::from_points).collect();
    let bvh = Bvh::build(&boxes, 4);
    let mut rng = Rng::new(5);
    let points: Vec<Point3<f64>> = (0..2000)
        .map(|_| {
            Point3::new(
                rng.uniform_in(-2.0, 2.0),
                rng.uniform_in(-2.0, 2.0),
                rng.uniform_in(-2.0, 2.0),
            )
        })
        .filter(|p| (p.coords.norm() - 1.0).abs() > 0.01)
        .collect();
    let exact: Vec<f64> = points
        .iter()
        .map(|p| winding_number_brute(&corners, p))
        .collect();
    println!(
        "{} triangles, {} points farther than 1 % of the radius from the sphere",
        corners.len(),
        points.len()
    );
    let fast = FastWinding::new(&bvh, &corners);
    for order in [
        ExpansionOrder::Dipole,
        ExpansionOrder::FirstOrder,
        ExpansionOrder::SecondOrder,
    ] {
        for beta in [1.5, 2.0, 2.5, 3.0, 4.0] {
            let start = std::time::Instant::now();
            let max_error = points
                .iter()
                .zip(&exact)
                .map(|(p, e)| (fast.eval(&bvh, p, beta, order) - e).abs())
                .fold(0.0f64, f64::max);
            println!(
                "{order:?} beta {beta}: max error {max_error:.3e}, {:.2} µs per query",
                start.elapsed().as_secs_f64() * 1e6 / points.len() as f64
            );
        }
    }
}

//! The trilinear 8-node hexahedron on a cubic cell (thesis §2.3, eq. 4.3–4.5).

use nalgebra::{SMatrix, Vector3};

/// Reference coordinates of the 8 corners, in `[-1, 1]³`; x varies fastest.
pub const CORNERS: [[f64; 3]; 8] = [
    [-1.0, -1.0, -1.0],
    [1.0, -1.0, -1.0],
    [-1.0, 1.0, -1.0],
    [1.0, 1.0, -1.0],
    [-1.0, -1.0, 1.0],
    [1.0, -1.0, 1.0],
    [-1.0, 1.0, 1.0],
    [1.0, 1.0, 1.0],
];

/// The 1D two-point Gauss abscissa `1/√3`.
pub const GAUSS_2: f64 = 0.577_350_269_189_625_8;

/// Reference coordinates of the 2×2×2 Gauss points; point `I` lies in the first-level sub-cell
/// (octant) that contains corner `I` (the ordering eq. 4.12–4.13 relies on). Each has weight 1.
pub fn gauss_points() -> [Vector3<f64>; 8] {
    CORNERS.map(|c| Vector3::new(c[0], c[1], c[2]) * GAUSS_2)
}

/// Trilinear shape values `N_a(ξ)`, a = 0..8 (dimensionless; they sum to 1).
pub fn shape_values(xi: &Vector3<f64>) -> [f64; 8] {
    CORNERS.map(|c| 0.125 * (1.0 + c[0] * xi[0]) * (1.0 + c[1] * xi[1]) * (1.0 + c[2] * xi[2]))
}

/// Shape-function gradients with respect to the physical rest coordinates for a cubic cell of
/// edge `h`: row `a` is `∇_X N_a`, in 1/length (the Jacobian is the constant `h/2 · I`).
pub fn shape_gradients(xi: &Vector3<f64>, h: f64) -> SMatrix<f64, 8, 3> {
    let s = 2.0 / h;
    let mut g = SMatrix::<f64, 8, 3>::zeros();
    for (a, c) in CORNERS.iter().enumerate() {
        let f = [1.0 + c[0] * xi[0], 1.0 + c[1] * xi[1], 1.0 + c[2] * xi[2]];
        g[(a, 0)] = 0.125 * c[0] * f[1] * f[2] * s;
        g[(a, 1)] = 0.125 * f[0] * c[1] * f[2] * s;
        g[(a, 2)] = 0.125 * f[0] * f[1] * c[2] * s;
    }
    g
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn partition_of_unity_and_kronecker_property() {
        let xi = Vector3::new(0.3, -0.7, 0.1);
        assert!((shape_values(&xi).iter().sum::<f64>() - 1.0).abs() < 1e-15);
        for (a, c) in CORNERS.iter().enumerate() {
            let n = shape_values(&Vector3::from(*c));
            for (b, v) in n.iter().enumerate() {
                assert_eq!(*v, if a == b { 1.0 } else { 0.0 });
            }
        }
    }

    #[test]
    fn gradients_match_finite_differences_and_reproduce_linear_fields() {
        let h = 0.3;
        let xi = Vector3::new(0.2, 0.5, -0.4);
        let g = shape_gradients(&xi, h);
        let eps = 1e-6;
        for d in 0..3 {
            let mut p = xi;
            let mut m = xi;
            p[d] += eps;
            m[d] -= eps;
            let (np, nm) = (shape_values(&p), shape_values(&m));
            for a in 0..8 {
                let fd = (np[a] - nm[a]) / (2.0 * eps) * 2.0 / h;
                assert!((fd - g[(a, d)]).abs() < 1e-8);
            }
        }
        // A linear field f(X) = v·X sampled at the corners has gradient v everywhere.
        let v = Vector3::new(1.5, -2.0, 0.25);
        let mut grad = Vector3::zeros();
        for (a, c) in CORNERS.iter().enumerate() {
            let x = Vector3::from(*c) * (h / 2.0);
            grad += g.row(a).transpose() * v.dot(&x);
        }
        assert!((grad - v).norm() < 1e-12);
    }
}

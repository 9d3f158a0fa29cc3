//! How far the registered deformation could be a pose change instead.

use nalgebra::Point3;

use super::kabsch;

/// Root mean square over `rest` (the inputs' length unit) of how far the rigid motion that best carries the seen
/// vertices' rest positions onto their registered ones moves the surface: the part of the
/// registered deformation a pose change could explain as well. `seen`: indices into `rest`
/// and `deformed` of the vertices the cloud lies on. The fit is trimmed to the best-fitting
/// `keep` share (0–1] of the seen vertices, so a local dent does not count. `None` when fewer
/// than 3 seen vertices or a degenerate set leave the motion undetermined.
pub fn rigid_share_of_deformation(
    rest: &[Point3<f64>],
    deformed: &[Point3<f64>],
    seen: &[usize],
    keep: f64,
) -> Option<f64> {
    let mut kept: Vec<usize> = seen.to_vec();
    let mut fit = None;
    for _ in 0..3 {
        let source: Vec<Point3<f64>> = kept.iter().map(|&i| rest[i]).collect();
        let target: Vec<Point3<f64>> = kept.iter().map(|&i| deformed[i]).collect();
        let t = kabsch(&source, &target, None)?;
        let mut residual: Vec<(f64, usize)> = seen
            .iter()
            .map(|&i| ((t.apply(&rest[i]) - deformed[i]).norm_squared(), i))
            .collect();
        residual.sort_by(|a, b| a.0.total_cmp(&b.0));
        let n = ((seen.len() as f64 * keep).ceil() as usize).clamp(3, seen.len());
        kept = residual[..n].iter().map(|r| r.1).collect();
        fit = Some(t);
    }
    let t = fit?;
    let sum: f64 = rest.iter().map(|p| (t.apply(p) - p).norm_squared()).sum();
    Some((sum / rest.len().max(1) as f64).sqrt())
}

#[cfg(test)]
mod tests {
    use nalgebra::{Rotation3, Unit, Vector3};

    use super::*;
    use crate::registration::RigidTransform;

    /// A sphere's vertices (Fibonacci lattice), radius 50.
    fn sphere(n: usize) -> Vec<Point3<f64>> {
        let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
        (0..n)
            .map(|i| {
                let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
                let r = (1.0 - z * z).sqrt();
                let a = golden * i as f64;
                Point3::new(50.0 * r * a.cos(), 50.0 * r * a.sin(), 50.0 * z + 5.0)
            })
            .collect()
    }

    /// A rigid motion of the whole body is returned whole: its RMS displacement over the
    /// surface, computed directly.
    #[test]
    fn a_rigid_motion_is_all_rigid_share() {
        let rest = sphere(400);
        let axis = Unit::new_normalize(Vector3::new(0.2, -0.4, 1.0));
        let t = RigidTransform::new(
            Rotation3::from_axis_angle(&axis, 0.15),
            Vector3::new(3.0, -7.0, 2.0),
        );
        let moved = t.apply_all(&rest);
        let expected = (rest
            .iter()
            .zip(&moved)
            .map(|(p, q)| (q - p).norm_squared())
            .sum::<f64>()
            / rest.len() as f64)
            .sqrt();
        let seen: Vec<usize> = (0..rest.len()).filter(|&i| rest[i].z > 30.0).collect();
        let share = rigid_share_of_deformation(&rest, &moved, &seen, 0.75).unwrap();
        assert!(
            (share - expected).abs() < 1e-9 * expected,
            "{share} vs {expected}"
        );
    }

    /// A dent on a fifth of the seen vertices, the rest unmoved: the trimmed fit leaves it
    /// out and reports no rigid share; the untrimmed fit is pulled toward it.
    #[test]
    fn a_local_dent_is_not_a_rigid_share() {
        let rest = sphere(2000);
        let seen: Vec<usize> = (0..rest.len()).filter(|&i| rest[i].z > 20.0).collect();
        let dent_centre = Point3::new(0.0, 0.0, 55.0);
        let mut dented = rest.clone();
        let mut dented_count = 0;
        for &i in &seen {
            let d = (rest[i] - dent_centre).norm();
            if d < 15.0 {
                dented[i].z -= 20.0 * (1.0 - d / 15.0);
                dented_count += 1;
            }
        }
        assert!(
            dented_count * 5 < seen.len(),
            "{dented_count} of {}",
            seen.len()
        );
        let trimmed = rigid_share_of_deformation(&rest, &dented, &seen, 0.75).unwrap();
        let whole = rigid_share_of_deformation(&rest, &dented, &seen, 1.0).unwrap();
        assert!(trimmed < 1e-9, "trimmed {trimmed}");
        assert!(whole > 0.3, "untrimmed {whole}");
    }

    /// Too few seen vertices leave the motion undetermined.
    #[test]
    fn two_vertices_determine_nothing() {
        let rest = sphere(10);
        assert!(rigid_share_of_deformation(&rest, &rest, &[0, 1], 0.75).is_none());
    }
}

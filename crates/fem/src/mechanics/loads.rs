//! Dead loads: surface tractions integrated on the surface triangles and moved to the grid
//! through H (thesis eq. 4.14–4.17), and gravity weighted by the inside volume.

use nalgebra::{Point3, Vector3};

use crate::geometry::Aabb;
use crate::grid::hex8::{gauss_points, shape_values};
use crate::grid::{Embedding, EmbeddingError, WeightedCellGrid};
use crate::mesh::TriSurface;

/// A point sampling a piece of surface: its position and the area it stands for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceSample {
    /// Position (surface units).
    pub point: Point3<f64>,
    /// Area represented (surface units²).
    pub area: f64,
}

/// Samples the part of `surface` inside `region`: each triangle is split into `m²` similar
/// sub-triangles with edges at most `spacing`, and the centroid of every sub-triangle inside
/// the box is kept with the sub-triangle's area (a midpoint rule, exact for constant
/// tractions on the covered area).
pub fn sample_surface_in_box(
    surface: &TriSurface,
    region: &Aabb,
    spacing: f64,
) -> Vec<SurfaceSample> {
    samples_by_triangle(surface, region, spacing)
        .into_iter()
        .map(|(_, s)| s)
        .collect()
}

/// [`sample_surface_in_box`] with the triangle each sample lies on.
pub fn samples_by_triangle(
    surface: &TriSurface,
    region: &Aabb,
    spacing: f64,
) -> Vec<(usize, SurfaceSample)> {
    let mut out = Vec::new();
    for t in 0..surface.triangles.len() {
        let [a, b, c] = surface.corners(t);
        let lo = a.inf(&b).inf(&c);
        let hi = a.sup(&b).sup(&c);
        if (0..3).any(|d| hi[d] < region.min[d] || lo[d] > region.max[d]) {
            continue;
        }
        let longest = (b - a).norm().max((c - b).norm()).max((a - c).norm());
        let m = ((longest / spacing).ceil() as usize).clamp(1, 256);
        let area = 0.5 * (b - a).cross(&(c - a)).norm() / (m * m) as f64;
        let (eu, ev) = ((b - a) / m as f64, (c - a) / m as f64);
        for i in 0..m {
            for j in 0..(m - i) {
                // Upward sub-triangle (i, j), and the downward one beside it.
                let p = a + eu * (i as f64 + 1.0 / 3.0) + ev * (j as f64 + 1.0 / 3.0);
                push_if_inside(&mut out, region, t, p, area);
                if i + j + 1 < m {
                    let q = a + eu * (i as f64 + 2.0 / 3.0) + ev * (j as f64 + 2.0 / 3.0);
                    push_if_inside(&mut out, region, t, q, area);
                }
            }
        }
    }
    out
}

fn push_if_inside(
    out: &mut Vec<(usize, SurfaceSample)>,
    region: &Aabb,
    triangle: usize,
    p: Point3<f64>,
    area: f64,
) {
    if (0..3).all(|d| p[d] >= region.min[d] && p[d] <= region.max[d]) {
        out.push((triangle, SurfaceSample { point: p, area }));
    }
}

/// Grid forces (N, 3 per node) of a dead traction `value` (Pa) on the surface inside
/// `region`: `T = H Tˢ` with `Tˢ_j = value · A_j` at each surface sample (eq. 4.17).
pub fn traction_forces(
    grid: &WeightedCellGrid,
    surface: &TriSurface,
    region: &Aabb,
    value: Vector3<f64>,
    forces: &mut [f64],
) -> Result<usize, EmbeddingError> {
    let samples = sample_surface_in_box(surface, region, 0.25 * grid.grid.cell_size);
    let points: Vec<Point3<f64>> = samples.iter().map(|s| s.point).collect();
    let emb = Embedding::new(grid, &points)?;
    let f: Vec<Vector3<f64>> = samples.iter().map(|s| value * s.area).collect();
    emb.spread_forces(&f, forces);
    Ok(samples.len())
}

/// Grid forces (N, 3 per node) of a dead pressure `pressure` (Pa) on the part of `surface`
/// inside `region` (the whole surface when `None`): every rest-area sample of area `A` on a
/// triangle with outward unit normal `n` carries the force `−p n A` (a positive pressure pushes
/// the surface inwards; `surface` must be outward-oriented), moved to the grid through H like
/// [`traction_forces`]. The load is dead: normals and areas are those of the rest surface.
/// Returns the number of surface samples loaded.
///
/// On a closed surface a uniform pressure has zero resultant force and moment (up to
/// round-off); on an open patch the resultant is `−p` times the patch's vector area.
pub fn pressure_forces(
    grid: &WeightedCellGrid,
    surface: &TriSurface,
    region: Option<&Aabb>,
    pressure: f64,
    forces: &mut [f64],
) -> Result<usize, EmbeddingError> {
    let everywhere = Aabb {
        min: Point3::from(Vector3::repeat(f64::NEG_INFINITY)),
        max: Point3::from(Vector3::repeat(f64::INFINITY)),
    };
    let region = region.unwrap_or(&everywhere);
    let samples = samples_by_triangle(surface, region, 0.25 * grid.grid.cell_size);
    let points: Vec<Point3<f64>> = samples.iter().map(|(_, s)| s.point).collect();
    let emb = Embedding::new(grid, &points)?;
    let f: Vec<Vector3<f64>> = samples
        .iter()
        .map(|(t, s)| {
            let n = surface.scaled_normal(*t);
            let len = n.norm();
            if len > 0.0 {
                n * (-pressure * s.area / len)
            } else {
                Vector3::zeros()
            }
        })
        .collect();
    emb.spread_forces(&f, forces);
    Ok(samples.len())
}

/// Grid forces (N) of gravity `g` (m/s²) on material of density `rho` (kg/m³): the consistent
/// nodal loads `f_a = Σ_I ρ g v_I N_a(ξ_I)` with `v_I` the inside volume of octant `I`, so
/// that the total is exactly `ρ g V_inside`.
pub fn gravity_forces(grid: &WeightedCellGrid, rho: f64, g: Vector3<f64>, forces: &mut [f64]) {
    let v8 = grid.grid.cell_size.powi(3) / 8.0;
    let gp = gauss_points();
    let n_at: Vec<[f64; 8]> = gp.iter().map(shape_values).collect();
    for cell in &grid.cells {
        for (i, frac) in cell.octant_fractions.iter().enumerate() {
            let m = rho * frac * v8;
            for (a, &node) in cell.nodes.iter().enumerate() {
                for d in 0..3 {
                    forces[3 * node + d] += m * g[d] * n_at[i][a];
                }
            }
        }
    }
}

/// Grid forces (N) of a body force density `b(X)` (N/m³, X in m): `f_a = Σ_q b(X_q) N_a(ξ_q) w_q`
/// over the grid's own integration points (so the load is integrated exactly as the stiffness).
pub fn body_forces(
    grid: &WeightedCellGrid,
    b: impl Fn(&Point3<f64>) -> Vector3<f64>,
    forces: &mut [f64],
) {
    for (c, cell) in grid.cells.iter().enumerate() {
        for q in grid.quadrature.cell(c) {
            let x = grid.grid.to_physical(cell.coords, &q.xi);
            let bx = b(&x) * q.weight;
            for (a, n) in shape_values(&q.xi).iter().enumerate() {
                for d in 0..3 {
                    forces[3 * cell.nodes[a] + d] += n * bx[d];
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::GridOptions;
    use crate::mesh::primitives::{cylinder_surface, icosphere};

    fn total(forces: &[f64]) -> Vector3<f64> {
        forces.chunks(3).fold(Vector3::zeros(), |acc, f| {
            acc + Vector3::new(f[0], f[1], f[2])
        })
    }

    #[test]
    fn gravity_totals_weight_of_the_inside_volume() {
        let s = icosphere(Point3::new(0.001, 0.0, -0.002), 0.05, 4);
        let g = WeightedCellGrid::build(
            &s,
            &GridOptions {
                cell_size: 0.015,
                subdivisions: 3,
                ..Default::default()
            },
        )
        .unwrap();
        let mut f = vec![0.0; 3 * g.node_count()];
        let gv = Vector3::new(0.0, 0.0, -9.81);
        gravity_forces(&g, 1000.0, gv, &mut f);
        let expected = gv * 1000.0 * g.stats().volume;
        assert!((total(&f) - expected).norm() < 1e-12 * expected.norm());
        // And the inside volume is close to the sphere's.
        assert!((g.stats().volume / s.signed_volume() - 1.0).abs() < 0.01);
    }

    #[test]
    fn traction_totals_value_times_loaded_area() {
        // The end disc of a cylinder (polygon area) under a uniform traction.
        let s = cylinder_surface(0.05, 0.0, 0.2, 32, 8);
        let g = WeightedCellGrid::build(
            &s,
            &GridOptions {
                cell_size: 0.02,
                ..Default::default()
            },
        )
        .unwrap();
        let region = Aabb {
            min: Point3::new(-1.0, -1.0, 0.2 - 1e-6),
            max: Point3::new(1.0, 1.0, 0.2 + 1e-6),
        };
        let t = Vector3::new(3.0, -30.0, 1.0);
        let mut f = vec![0.0; 3 * g.node_count()];
        traction_forces(&g, &s, &region, t, &mut f).unwrap();
        let area = 0.5 * 32.0 * 0.05f64.powi(2) * (std::f64::consts::TAU / 32.0).sin();
        assert!((total(&f) - t * area).norm() < 1e-12 * (t * area).norm());
    }

    /// Σ_a X_a × f_a over the grid nodes: the moment about the origin.
    fn moment(g: &WeightedCellGrid, forces: &[f64]) -> Vector3<f64> {
        g.node_positions()
            .iter()
            .zip(forces.chunks(3))
            .fold(Vector3::zeros(), |acc, (x, f)| {
                acc + x.coords.cross(&Vector3::new(f[0], f[1], f[2]))
            })
    }

    #[test]
    fn uniform_pressure_on_a_closed_surface_has_no_resultant() {
        // Off-centre sphere, so that the moment about the origin is not zero by symmetry alone.
        let s = icosphere(Point3::new(0.013, -0.007, 0.021), 0.05, 3);
        let g = WeightedCellGrid::build(
            &s,
            &GridOptions {
                cell_size: 0.015,
                ..Default::default()
            },
        )
        .unwrap();
        let p = 1500.0;
        let mut f = vec![0.0; 3 * g.node_count()];
        let n = pressure_forces(&g, &s, None, p, &mut f).unwrap();
        assert!(n > s.triangles.len());
        // Scale of the individual forces: p × area, and p × area × lever arm.
        let area = 4.0 * std::f64::consts::PI * 0.05f64.powi(2);
        let magnitude: f64 = f.iter().map(|v| v.abs()).sum();
        assert!(magnitude > 0.1 * p * area, "the nodes do carry forces");
        assert!(total(&f).norm() < 1e-12 * p * area, "{:?}", total(&f));
        assert!(
            moment(&g, &f).norm() < 1e-12 * p * area * 0.1,
            "{:?}",
            moment(&g, &f)
        );
        // Positive pressure pushes inwards: the nodes above the centre are pushed down.
        let centre = Point3::new(0.013, -0.007, 0.021);
        let down: f64 = g
            .node_positions()
            .iter()
            .zip(f.chunks(3))
            .filter(|(x, _)| x.z > centre.z + 0.03)
            .map(|(_, v)| v[2])
            .sum();
        assert!(down < 0.0);
    }

    #[test]
    fn pressure_on_an_open_patch_totals_minus_p_times_vector_area() {
        // Half of a cylinder's side wall (x > 0, caps excluded): its vector area is that of
        // the chain from angle −90° to +90° swept along the axis, 2 R H along +x, whatever the
        // number of segments.
        let (r, z0, h) = (0.05, -0.03, 0.12);
        let s = cylinder_surface(r, z0, h, 32, 6);
        let g = WeightedCellGrid::build(
            &s,
            &GridOptions {
                cell_size: 0.02,
                ..Default::default()
            },
        )
        .unwrap();
        let region = Aabb {
            min: Point3::new(1e-9, -1.0, z0 + 1e-6),
            max: Point3::new(1.0, 1.0, z0 + h - 1e-6),
        };
        let p = -800.0; // suction: pulls outwards
        let mut f = vec![0.0; 3 * g.node_count()];
        pressure_forces(&g, &s, Some(&region), p, &mut f).unwrap();
        let expected = Vector3::new(-p * 2.0 * r * h, 0.0, 0.0);
        assert!(
            (total(&f) - expected).norm() < 1e-12 * expected.norm(),
            "{:?} vs {expected:?}",
            total(&f)
        );
    }

    #[test]
    fn surface_samples_cover_the_area_in_the_box_once() {
        let s = icosphere(Point3::origin(), 1.0, 3);
        let everything = Aabb {
            min: Point3::new(-2.0, -2.0, -2.0),
            max: Point3::new(2.0, 2.0, 2.0),
        };
        let samples = sample_surface_in_box(&s, &everything, 0.05);
        let area: f64 = samples.iter().map(|x| x.area).sum();
        let exact = s.area();
        assert!((area - exact).abs() < 1e-12 * exact);
        assert!(
            samples.len() > s.triangles.len() * 4,
            "triangles are subdivided to the spacing"
        );
    }
}

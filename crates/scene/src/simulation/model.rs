//! A scene turned into a mechanical model in SI units: surface, grid, material, loads, fixed
//! regions and embedded probes and structures. The model type itself is the registration
//! crate's [`Model`] (what registration reads); this module builds one from a scene
//! ([`build_model`], [`FromScene`](super::FromScene)).

use nalgebra::{Point3, Vector3};

use crate::geometry::Aabb;
use crate::grid::{Embedding, GridOptions, WeightedCellGrid};
use crate::mechanics::loads::{gravity_forces, traction_forces};
use crate::mechanics::{
    Material, NewtonSettings, PenaltySprings, StaticProblem, VolumetricIntegration,
};
use crate::mesh::{read_points, read_surface, validate, SurfaceReport, TriSurface};
use crate::scene::{FixedRegion, LoadedScene, PointSource, Scene};

use super::point_hold::point_hold_stiffness;

use livereg_registration::DEFAULT_FIXED_PENALTY_FACTOR;
pub use livereg_registration::{EmbeddedStructure, Model, ModelError};

/// The model of a scene: the registration crate's [`Model`], under the name the scene layer
/// has always given it.
pub type SceneModel = Model;

/// Options of the grid from `[grid]`.
pub(crate) fn grid_options(scene: &Scene, scale: f64) -> GridOptions {
    GridOptions {
        cell_size: scene.grid.cell_size * scale,
        subdivisions: scene.grid.subdivisions,
        mode: scene.grid.integration,
        min_fraction: scene.grid.min_fraction,
        origin_offset: scene.grid.origin_offset,
    }
}

/// Material from `[material]`.
pub(crate) fn material(scene: &Scene) -> Result<(Material, VolumetricIntegration), ModelError> {
    let m = Material::from_young_poisson(
        scene.material.law,
        scene.material.young_modulus,
        scene.material.poisson_ratio,
    )
    .map_err(|e| ModelError::Invalid(format!("material: {e}")))?;
    Ok((m, scene.material.volumetric))
}

/// Newton settings from `[solver]`.
pub(crate) fn newton_settings(scene: &Scene) -> NewtonSettings {
    let s = &scene.solver;
    NewtonSettings {
        load_steps: s.load_steps as usize,
        max_iterations: s.max_newton_iterations as usize,
        residual_tolerance: s.residual_tolerance,
        displacement_tolerance: s.displacement_tolerance,
        max_bisections: s.max_bisections as usize,
        line_search: s.line_search,
        linear_solver: s.linear_solver,
        projected_tangent: s.projected_tangent,
        mixed_precision: s.mixed_precision,
        step_stabilization: s.step_stabilization,
    }
}

fn to_point(p: [f64; 3], scale: f64) -> Point3<f64> {
    Point3::new(p[0] * scale, p[1] * scale, p[2] * scale)
}

fn region_box(min: [f64; 3], max: [f64; 3], scale: f64) -> Aabb {
    Aabb {
        min: to_point(min, scale),
        max: to_point(max, scale),
    }
}

/// Points of a point source, in metres.
fn source_points(
    source: &PointSource,
    scene: &LoadedScene,
    scale: f64,
) -> Result<Vec<Point3<f64>>, ModelError> {
    match source {
        PointSource::Inline(v) => Ok(v.iter().map(|p| to_point(*p, scale)).collect()),
        PointSource::File(path) => {
            let mut pts = read_points(&scene.resolve(path))?;
            for p in &mut pts {
                p.coords *= scale;
            }
            Ok(pts)
        }
    }
}

/// `pts` (m) embedded in `grid`; an error names `what` when a point lies outside it.
fn embed(
    what: String,
    pts: &[Point3<f64>],
    grid: &WeightedCellGrid,
) -> Result<Embedding, ModelError> {
    Embedding::new(grid, pts).map_err(|source| ModelError::Embedding { what, source })
}

/// The model's surface read from `path`, in metres (`scale` metres per scene unit) and
/// oriented outwards, with the validation report of the file as read.
fn read_model_surface(
    path: &std::path::Path,
    scale: f64,
) -> Result<(TriSurface, SurfaceReport), ModelError> {
    let mut surface = read_surface(path)?;
    let report = validate(&surface);
    surface.scale(scale);
    if surface.signed_volume() < 0.0 {
        crate::mesh::orient_outward(&mut surface);
    }
    Ok((surface, report))
}

/// Grid forces (N, 3 per node) of `[load]`: each `traction` box's dead traction on the
/// surface (a box that holds no part of it is an error) and gravity.
fn external_loads(
    loaded: &LoadedScene,
    grid: &WeightedCellGrid,
    surface: &TriSurface,
) -> Result<Vec<f64>, ModelError> {
    let scene = &loaded.scene;
    let scale = loaded.length_scale();
    let mut external = vec![0.0; 3 * grid.node_count()];
    for (i, t) in scene.load.traction.iter().enumerate() {
        let b = region_box(t.bbox.min, t.bbox.max, scale);
        let n = traction_forces(grid, surface, &b, Vector3::from(t.value), &mut external).map_err(
            |source| ModelError::Embedding {
                what: format!("load.traction[{i}]"),
                source,
            },
        )?;
        if n == 0 {
            return Err(ModelError::Invalid(format!(
                "{}: load.traction[{i}]: the box holds no part of the surface",
                loaded.path.display()
            )));
        }
    }
    let g = Vector3::from(scene.load.gravity);
    if g.norm() > 0.0 {
        gravity_forces(grid, scene.material.density, g, &mut external);
    }
    Ok(external)
}

/// The penalty springs of `[[boundary.fixed]]`, one set per entry in order. A box holds its
/// surface samples at a spring density of κE/h per unit area; points each get β E A / h
/// ([`point_hold_stiffness`]: the hold acts through a layer of tissue half a cell thick), and
/// the points that fall in one grid cell act as one spring on their mean displacement of their
/// summed stiffness ([`PenaltySprings::lumped_per_cell`]): held point by point, eight or more
/// points clamp the whole cell, so a ligament given as its vertices would hold up to a cell
/// beyond itself (`tests/numerics/ligament_hold.rs`). The entry's or `[solver]`'s stiffness
/// replaces the default per sample or point; a region that holds nothing is an error.
fn fixed_regions(
    loaded: &LoadedScene,
    grid: &WeightedCellGrid,
    surface: &TriSurface,
) -> Result<Vec<PenaltySprings>, ModelError> {
    let scene = &loaded.scene;
    let scale = loaded.length_scale();
    let young = scene.material.young_modulus;
    let h = grid.grid.cell_size;
    let mut springs = Vec::new();
    for (i, f) in scene.boundary.fixed.iter().enumerate() {
        let key = format!("boundary.fixed[{i}]");
        let set = match f.region() {
            Some(FixedRegion::Box(b)) => {
                let region = region_box(b.min, b.max, scale);
                let density = DEFAULT_FIXED_PENALTY_FACTOR * young / h;
                let set = PenaltySprings::fixed_surface_region(grid, surface, &region, density)
                    .map_err(|source| ModelError::Embedding {
                        what: key.clone(),
                        source,
                    })?;
                set.map(|mut s| {
                    if let Some(k) = f.stiffness.or(scene.solver.penalty_stiffness) {
                        s.stiffness.iter_mut().for_each(|v| *v = k);
                    }
                    s
                })
            }
            Some(FixedRegion::Points(src)) => {
                let pts = source_points(src, loaded, scale)?;
                let k = match f.stiffness.or(scene.solver.penalty_stiffness) {
                    Some(k) => vec![k; pts.len()],
                    None => point_hold_stiffness(&pts, young, h),
                };
                let emb = embed(key.clone(), &pts, grid)?;
                (!pts.is_empty()).then(|| PenaltySprings::fixed(emb, k).lumped_per_cell())
            }
            None => {
                return Err(ModelError::Invalid(format!(
                    "{}: {key}: give exactly one of box or points",
                    loaded.path.display()
                )))
            }
        };
        match set {
            Some(s) => springs.push(s),
            None => {
                return Err(ModelError::Invalid(format!(
                    "{}: {key}: the region holds no point of the surface",
                    loaded.path.display()
                )))
            }
        }
    }
    Ok(springs)
}

/// The springs of `[[boundary.support]]` (elastic beds), one set per entry in order; a box
/// that holds no part of the surface is an error.
fn supports(
    loaded: &LoadedScene,
    grid: &WeightedCellGrid,
    surface: &TriSurface,
) -> Result<Vec<PenaltySprings>, ModelError> {
    let scale = loaded.length_scale();
    let mut springs = Vec::new();
    for (i, sup) in loaded.scene.boundary.support.iter().enumerate() {
        let key = format!("boundary.support[{i}]");
        let region = region_box(sup.bbox.min, sup.bbox.max, scale);
        let set = PenaltySprings::support_surface_region(
            grid,
            surface,
            &region,
            sup.stiffness,
            sup.sliding,
        )
        .map_err(|source| ModelError::Embedding {
            what: key.clone(),
            source,
        })?
        .ok_or_else(|| {
            ModelError::Invalid(format!(
                "{}: {key}: the box holds no part of the surface",
                loaded.path.display()
            ))
        })?;
        springs.push(set);
    }
    Ok(springs)
}

/// `model.structures`, each read (points or a mesh, metres) and embedded in `grid`.
fn embedded_structures(
    loaded: &LoadedScene,
    grid: &WeightedCellGrid,
) -> Result<Vec<EmbeddedStructure>, ModelError> {
    let scale = loaded.length_scale();
    let mut structures = Vec::new();
    for s in &loaded.scene.model.structures {
        let (points, triangles) = match (&s.points, &s.mesh) {
            (Some(p), None) => (
                source_points(&PointSource::File(p.clone()), loaded, scale)?,
                None,
            ),
            (None, Some(m)) => {
                let mut mesh = read_surface(&loaded.resolve(m))?;
                mesh.scale(scale);
                (mesh.vertices, Some(mesh.triangles))
            }
            _ => {
                return Err(ModelError::Invalid(format!(
                    "{}: model.structures '{}': give exactly one of points or mesh",
                    loaded.path.display(),
                    s.name
                )))
            }
        };
        let embedding = embed(format!("model.structures '{}'", s.name), &points, grid)?;
        structures.push(EmbeddedStructure {
            name: s.name.clone(),
            embedding,
            triangles,
        });
    }
    Ok(structures)
}

/// Reads the scene's files and builds the model, stage by stage: the surface (metres,
/// outward), the grid around it, the dead loads, the boundary springs, the probes and the
/// internal structures, each embedded in the grid; with the validation report of the surface
/// file as read.
pub fn build_model(loaded: &LoadedScene) -> Result<(Model, SurfaceReport), ModelError> {
    let scene = &loaded.scene;
    let scale = loaded.length_scale();
    let surface_path = loaded.resolve(&scene.model.surface);
    let (surface, surface_report) = read_model_surface(&surface_path, scale)?;
    let grid =
        WeightedCellGrid::build(&surface, &grid_options(scene, scale)).map_err(|source| {
            ModelError::Grid {
                file: surface_path.clone(),
                source,
            }
        })?;
    let (material, volumetric) = material(scene)?;
    let surface_embedding = embed(
        format!("{}: surface vertices", surface_path.display()),
        &surface.vertices,
        &grid,
    )?;
    let external = external_loads(loaded, &grid, &surface)?;
    let mut springs = fixed_regions(loaded, &grid, &surface)?;
    springs.extend(supports(loaded, &grid, &surface)?);
    let mut probe_points = Vec::new();
    for p in &scene.probe {
        probe_points.extend(source_points(&p.points, loaded, scale)?);
    }
    let probes = embed("probe".into(), &probe_points, &grid)?;
    let structures = embedded_structures(loaded, &grid)?;

    let mut problem = StaticProblem::new(grid, material, volumetric);
    problem.external = external;
    problem.springs = springs;
    let model = Model {
        length_scale: scale,
        surface,
        surface_embedding,
        problem,
        newton: newton_settings(scene),
        probes,
        structures,
    };
    Ok((model, surface_report))
}

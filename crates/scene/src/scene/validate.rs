//! Value checks on a parsed scene. Each problem names the dotted key and the offending value.

use std::path::Path;

use super::error::Problem;
use super::types::{
    BoundarySpec, BoxRegion, Camera, GridSpec, LoadSpec, MaterialSpec, ModelSpec, PointSource,
    RegistrationSpec, Scene, SolverSpec, Vec3,
};

/// Extensions accepted for surfaces (`model.surface`, `model.structures[].mesh`), lower case:
/// those [`crate::mesh::read_surface`] reads.
pub const SURFACE_EXTENSIONS: &[&str] = &crate::mesh::SURFACE_EXTENSIONS;
/// Extensions accepted for point files, lower case: those [`crate::mesh::read_points`] reads.
pub const POINT_EXTENSIONS: &[&str] = &crate::mesh::POINT_EXTENSIONS;
/// Largest `grid.subdivisions`: a cut cell is split into up to 8^L sub-cells (8^6 = 262 144).
pub const MAX_SUBDIVISIONS: u32 = 6;
/// Largest `solver.step_stabilization` γ accepted: far beyond it the badly cut cells' nodes
/// barely move per step and registration steps only slow down.
pub const MAX_STEP_STABILIZATION: f64 = 1e4;
/// Largest `solver.load_steps`.
pub const MAX_LOAD_STEPS: u32 = 10_000;
/// Largest `registration.still_frames`: the union of that many clouds is registered, so the
/// pairing's cost grows with it.
pub(super) const MAX_STILL_FRAMES: u32 = 16;
/// Largest `solver.max_bisections` (an increment halved 30 times is ~1e-9 of a load step).
pub const MAX_BISECTIONS: u32 = 30;

struct Checker {
    problems: Vec<Problem>,
}

impl Checker {
    fn fail(&mut self, key: impl Into<String>, message: impl Into<String>) {
        self.problems.push(Problem {
            key: key.into(),
            message: message.into(),
        });
    }

    /// Finite, else a problem; returns whether it is finite.
    fn finite(&mut self, key: &str, v: f64) -> bool {
        if v.is_finite() {
            true
        } else {
            self.fail(key, format!("must be a finite number, got {v}"));
            false
        }
    }

    fn positive(&mut self, key: &str, v: f64, unit: &str) {
        if self.finite(key, v) && v <= 0.0 {
            self.fail(key, format!("must be > 0{unit}, got {v}"));
        }
    }

    fn vec3(&mut self, key: &str, v: &Vec3) -> bool {
        if v.iter().all(|x| x.is_finite()) {
            true
        } else {
            self.fail(key, format!("must hold finite numbers, got {v:?}"));
            false
        }
    }

    fn bbox(&mut self, key: &str, b: &BoxRegion) {
        if !(self.vec3(key, &b.min) && self.vec3(key, &b.max)) {
            return;
        }
        let bad: Vec<&str> = (0..3)
            .filter(|&k| b.min[k] > b.max[k])
            .map(|k| ["x", "y", "z"][k])
            .collect();
        if !bad.is_empty() {
            self.fail(
                key,
                format!(
                    "inverted box [{:?}, {:?}]: min > max on axis {} (write [[min x, min y, min z], [max x, max y, max z]])",
                    b.min,
                    b.max,
                    bad.join(", ")
                ),
            );
        }
    }

    fn extension(&mut self, key: &str, p: &Path, allowed: &[&str], what: &str) {
        if p.as_os_str().is_empty() {
            self.fail(key, "the path is empty");
            return;
        }
        let ext = p
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        match ext {
            Some(e) if allowed.contains(&e.as_str()) => {}
            _ => self.fail(
                key,
                format!(
                    "`{}`: unsupported {what} format (expected one of .{})",
                    p.display(),
                    allowed.join(" .")
                ),
            ),
        }
    }

    fn points(&mut self, key: &str, p: &PointSource) {
        match p {
            PointSource::File(f) => self.extension(key, f, POINT_EXTENSIONS, "point file"),
            PointSource::Inline(pts) => {
                if pts.is_empty() {
                    self.fail(key, "the inline point list is empty");
                }
                for (i, q) in pts.iter().enumerate() {
                    self.vec3(&format!("{key}[{i}]"), q);
                }
            }
        }
    }

    fn tolerance(&mut self, key: &str, v: f64) {
        if self.finite(key, v) && !(v > 0.0 && v < 1.0) {
            self.fail(key, format!("must be in (0, 1) (relative), got {v}"));
        }
    }

    fn at_least_one(&mut self, key: &str, v: u32) {
        if v < 1 {
            self.fail(key, format!("must be >= 1, got {v}"));
        }
    }
}

/// Check every value of `scene` (ranges, finiteness, consistency, path extensions) without
/// touching the file system. Returns all problems found, section by section; empty when valid.
pub fn validate_scene(scene: &Scene) -> Vec<Problem> {
    let mut c = Checker {
        problems: Vec::new(),
    };
    check_model(&mut c, &scene.model);
    check_structures(&mut c, &scene.model);
    check_grid(&mut c, &scene.grid);
    check_material(&mut c, &scene.material);
    check_boundary(&mut c, &scene.boundary);
    check_load(&mut c, &scene.load);
    check_solver(&mut c, &scene.solver);
    for (i, p) in scene.probe.iter().enumerate() {
        c.points(&format!("probe[{i}].points"), &p.points);
    }
    if let Some(r) = &scene.registration {
        check_registration(&mut c, r);
        if let Some(cam) = &r.camera {
            check_camera(&mut c, cam);
        }
    }
    c.problems
}

/// `[model]`: exactly one of a surface or a labelled segmentation, with the keys each needs.
fn check_model(c: &mut Checker, m: &ModelSpec) {
    match (&m.segmentation, m.surface.as_os_str().is_empty()) {
        (None, true) => c.fail(
            "model.surface",
            "missing: give `surface` (a closed triangle surface) or `segmentation` with `label`",
        ),
        (None, false) => c.extension("model.surface", &m.surface, SURFACE_EXTENSIONS, "surface"),
        (Some(seg), true) => {
            let name = seg.to_string_lossy().to_ascii_lowercase();
            if ![".nii", ".nii.gz", ".nrrd"]
                .iter()
                .any(|e| name.ends_with(e))
            {
                c.fail(
                    "model.segmentation",
                    format!(
                        "`{}`: unsupported labelmap format (expected .nii .nii.gz .nrrd .seg.nrrd)",
                        seg.display()
                    ),
                );
            }
            if m.label.is_none() {
                c.fail(
                    "model.label",
                    "`model.segmentation` needs the organ's `label` (a value or a segment name)",
                );
            }
        }
        (Some(_), false) => c.fail(
            "model",
            "both `surface` and `segmentation` are given; give exactly one",
        ),
    }
    if m.segmentation.is_none() {
        for key in [
            ("model.label", m.label.is_some()),
            ("model.target_triangles", m.target_triangles.is_some()),
        ]
        .iter()
        .filter(|k| k.1)
        {
            c.fail(key.0, "only meaningful with `model.segmentation`");
        }
    }
}

/// `[[model.structures]]`: unique names, exactly one source each, label sources only with a
/// segmentation.
fn check_structures(c: &mut Checker, m: &ModelSpec) {
    let mut seen: Vec<&str> = Vec::new();
    for (i, s) in m.structures.iter().enumerate() {
        let k = format!("model.structures[{i}]");
        let name = s.name.trim();
        if name.is_empty() {
            c.fail(format!("{k}.name"), "the structure name is empty");
        } else if seen.contains(&name) {
            c.fail(
                format!("{k}.name"),
                format!(
                    "duplicate structure name {:?} (names must be unique)",
                    s.name
                ),
            );
        } else {
            seen.push(name);
        }
        let from_labels = s.mesh_label.is_some() || s.points_label.is_some();
        if from_labels && m.segmentation.is_none() {
            c.fail(
                &k,
                format!(
                    "structure {:?}: `mesh_label` / `points_label` need `model.segmentation`",
                    s.name
                ),
            );
        }
        let given = [
            s.points.is_some(),
            s.mesh.is_some(),
            s.mesh_label.is_some(),
            s.points_label.is_some(),
        ]
        .iter()
        .filter(|g| **g)
        .count();
        match (&s.points, &s.mesh) {
            _ if given > 1 => c.fail(
                &k,
                format!(
                    "structure {:?} has more than one of `points`, `mesh`, `mesh_label`, \
                     `points_label`; give exactly one",
                    s.name
                ),
            ),
            (Some(p), None) => {
                c.extension(&format!("{k}.points"), p, POINT_EXTENSIONS, "point file")
            }
            (None, Some(m)) => c.extension(&format!("{k}.mesh"), m, SURFACE_EXTENSIONS, "mesh"),
            _ if given == 1 => {}
            _ => c.fail(
                &k,
                format!(
                    "structure {:?} has neither `points` nor `mesh`; give exactly one",
                    s.name
                ),
            ),
        }
    }
}

/// `[grid]`: cell size, subdivision depth, cut-cell floor and origin offset in range.
fn check_grid(c: &mut Checker, g: &GridSpec) {
    // Omitted: derived from the surface at load time.
    if !g.cell_size_omitted() {
        c.positive("grid.cell_size", g.cell_size, " (scene units)");
    }
    if g.subdivisions > MAX_SUBDIVISIONS {
        c.fail(
            "grid.subdivisions",
            format!(
                "must be <= {MAX_SUBDIVISIONS}, got {}: a cut cell is split into up to 8^L sub-cells (8^{} = {})",
                g.subdivisions,
                g.subdivisions,
                8f64.powi(g.subdivisions.min(1000) as i32)
            ),
        );
    }
    if c.finite("grid.min_fraction", g.min_fraction) && !(0.0..0.5).contains(&g.min_fraction) {
        c.fail(
            "grid.min_fraction",
            format!("must be in [0, 0.5), got {}", g.min_fraction),
        );
    }
    if c.vec3("grid.origin_offset", &g.origin_offset)
        && !g.origin_offset.iter().all(|x| (0.0..1.0).contains(x))
    {
        c.fail(
            "grid.origin_offset",
            format!(
                "each component must be in [0, 1) (cell units), got {:?}",
                g.origin_offset
            ),
        );
    }
}

/// `[material]`: a positive Young's modulus, ν in (−1, 0.5), a density ≥ 0.
fn check_material(c: &mut Checker, m: &MaterialSpec) {
    c.positive("material.young_modulus", m.young_modulus, " Pa");
    let nu = m.poisson_ratio;
    if c.finite("material.poisson_ratio", nu) {
        if nu >= 0.5 {
            c.fail(
                "material.poisson_ratio",
                format!(
                    "must be < 0.5, got {nu}: 0.5 is perfectly incompressible (λ = ∞); use <= 0.499 for nearly incompressible tissue"
                ),
            );
        } else if nu <= -1.0 {
            c.fail("material.poisson_ratio", format!("must be > -1, got {nu}"));
        }
    }
    if c.finite("material.density", m.density) && m.density < 0.0 {
        c.fail(
            "material.density",
            format!("must be >= 0 kg/m³, got {}", m.density),
        );
    }
}

/// `[[boundary.fixed]]` (a box or points, positive stiffness) and `[[boundary.support]]`.
fn check_boundary(c: &mut Checker, b: &BoundarySpec) {
    for (i, f) in b.fixed.iter().enumerate() {
        let k = format!("boundary.fixed[{i}]");
        match (&f.bbox, &f.points) {
            (Some(_), Some(_)) => c.fail(
                &k,
                "has both `box` and `points`; give exactly one (use two [[boundary.fixed]] entries for both)",
            ),
            (None, None) => c.fail(&k, "has neither `box` nor `points`; give exactly one"),
            _ => {}
        }
        if let Some(b) = &f.bbox {
            c.bbox(&format!("{k}.box"), b);
        }
        if let Some(p) = &f.points {
            c.points(&format!("{k}.points"), p);
        }
        if let Some(s) = f.stiffness {
            c.positive(&format!("{k}.stiffness"), s, " N/m");
        }
    }

    for (i, f) in b.support.iter().enumerate() {
        let k = format!("boundary.support[{i}]");
        c.bbox(&format!("{k}.box"), &f.bbox);
        c.positive(&format!("{k}.stiffness"), f.stiffness, " N/m³");
    }
}

/// `[load]`: finite gravity and tractions on valid boxes.
fn check_load(c: &mut Checker, l: &LoadSpec) {
    c.vec3("load.gravity", &l.gravity);
    for (i, t) in l.traction.iter().enumerate() {
        let k = format!("load.traction[{i}]");
        c.bbox(&format!("{k}.box"), &t.bbox);
        c.vec3(&format!("{k}.value"), &t.value);
    }
}

/// `[solver]`: load steps, iteration caps, tolerances and stabilisation in range.
fn check_solver(c: &mut Checker, s: &SolverSpec) {
    if !(1..=MAX_LOAD_STEPS).contains(&s.load_steps) {
        c.fail(
            "solver.load_steps",
            format!("must be in 1..={MAX_LOAD_STEPS}, got {}", s.load_steps),
        );
    }
    c.at_least_one("solver.max_newton_iterations", s.max_newton_iterations);
    c.tolerance("solver.residual_tolerance", s.residual_tolerance);
    c.tolerance("solver.displacement_tolerance", s.displacement_tolerance);
    if s.max_bisections > MAX_BISECTIONS {
        c.fail(
            "solver.max_bisections",
            format!("must be <= {MAX_BISECTIONS}, got {}", s.max_bisections),
        );
    }
    if let Some(k) = s.penalty_stiffness {
        c.positive("solver.penalty_stiffness", k, " N/m");
    }
    if c.finite("solver.step_stabilization", s.step_stabilization)
        && !(0.0..=MAX_STEP_STABILIZATION).contains(&s.step_stabilization)
    {
        c.fail(
            "solver.step_stabilization",
            format!(
                "must be in [0, {MAX_STEP_STABILIZATION}], got {}",
                s.step_stabilization
            ),
        );
    }
}

/// `[registration]` (the camera apart): weights, penalty ramp, iteration caps and lengths in
/// range.
fn check_registration(c: &mut Checker, r: &RegistrationSpec) {
    if c.finite("registration.alpha", r.alpha) && !(0.0..=1.0).contains(&r.alpha) {
        c.fail(
            "registration.alpha",
            format!("must be in [0, 1], got {}", r.alpha),
        );
    }
    if let Some(k0) = r.penalty_start {
        c.positive("registration.penalty_start", k0, " N/m");
    }
    if let Some(k1) = r.penalty_end {
        c.positive("registration.penalty_end", k1, " N/m");
    }
    c.positive("registration.penalty_scale", r.penalty_scale, "");
    if let (Some(k0), Some(k1)) = (r.penalty_start, r.penalty_end) {
        if k0.is_finite() && k1.is_finite() && k0 > k1 {
            c.fail(
                "registration.penalty_end",
                format!("must be >= penalty_start ({k0}), got {k1} (the ramp raises the penalty)"),
            );
        }
    }
    c.at_least_one("registration.penalty_steps", r.penalty_steps);
    c.at_least_one("registration.max_icp_iterations", r.max_icp_iterations);
    c.at_least_one("registration.still_frames", r.still_frames);
    if r.still_frames > MAX_STILL_FRAMES {
        c.fail(
            "registration.still_frames",
            format!("must be at most {MAX_STILL_FRAMES}, got {}", r.still_frames),
        );
    }
    if let Some(d) = r.max_pair_distance {
        c.positive("registration.max_pair_distance", d, " scene units");
    }
    if let Some(d) = r.max_pose_uncertainty {
        c.positive("registration.max_pose_uncertainty", d, " scene units");
    }
    if let Some(d) = r.max_expected_error {
        c.positive("registration.max_expected_error", d, " scene units");
    }
    if let Some(b) = r.time_budget_ms {
        c.positive("registration.time_budget_ms", b, " ms");
    }
    if let Some(d) = r.contact_radius {
        c.positive("registration.contact_radius", d, " scene units");
    }
    if let Some(n) = r.refit_factorizations {
        c.at_least_one("registration.refit_factorizations", n);
    }
    if let Some(d) = r.normal_radius {
        if !(d.is_finite() && d >= 0.0) {
            c.fail(
                "registration.normal_radius",
                format!("must be a length >= 0 scene units (0: vertex normals), got {d}"),
            );
        }
    }
    if let Some(f) = r.coarse_to_fine {
        if !(f.is_finite() && f > 1.0 && f <= 4.0) {
            c.fail(
                "registration.coarse_to_fine",
                format!("must be a cell-size factor in (1, 4], got {f}"),
            );
        }
    }
    if let Some(n) = r.max_cloud_points {
        if n < 3 {
            c.fail(
                "registration.max_cloud_points",
                format!("must be >= 3, got {n}"),
            );
        }
    }
}

/// `[registration.camera]`: finite, a look-at point apart from the position, an up vector
/// not along the view.
fn check_camera(c: &mut Checker, cam: &Camera) {
    let ok = c.vec3("registration.camera.position", &cam.position)
        & c.vec3("registration.camera.look_at", &cam.look_at);
    let view = [
        cam.look_at[0] - cam.position[0],
        cam.look_at[1] - cam.position[1],
        cam.look_at[2] - cam.position[2],
    ];
    let norm = |v: &Vec3| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if ok && norm(&view) == 0.0 {
        c.fail(
            "registration.camera.look_at",
            format!("must differ from position, both are {:?}", cam.position),
        );
    }
    if let Some(up) = &cam.up {
        if c.vec3("registration.camera.up", up) {
            let cross = [
                view[1] * up[2] - view[2] * up[1],
                view[2] * up[0] - view[0] * up[2],
                view[0] * up[1] - view[1] * up[0],
            ];
            if norm(up) == 0.0 {
                c.fail("registration.camera.up", "must not be the zero vector");
            } else if ok && norm(&view) > 0.0 && norm(&cross) <= 1e-9 * norm(up) * norm(&view) {
                c.fail(
                    "registration.camera.up",
                    format!("{up:?} is parallel to the viewing direction {view:?}"),
                );
            }
        }
    }
}

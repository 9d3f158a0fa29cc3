//! [`ModelConfig`]: one point of the speed-versus-accuracy sweep — a registration model
//! (grid, integration, law, linear solver, penalty schedule) applied on top of a scene.

use serde::Serialize;

use crate::grid::IntegrationMode;
use crate::linalg::SolverKind;
use crate::mechanics::LawKind;
use crate::scene::{validate_scene, LoadedScene, RegistrationSpec, Scene};

/// Changes to a scene's registration model; `None` keeps the scene's value. The scene with
/// every field `None` and factors 1 is the *default configuration*.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ModelConfig {
    /// Short name, unique in a sweep (chart label).
    pub name: String,
    /// Multiplies the scene's cell size (`None`: 1).
    pub cell_size_factor: Option<f64>,
    /// Octree levels on cut cells.
    pub subdivisions: Option<u32>,
    /// Integration of cut cells.
    pub integration: Option<IntegrationMode>,
    /// Constitutive law.
    pub law: Option<LawKind>,
    /// Poisson's ratio.
    pub poisson_ratio: Option<f64>,
    /// Linear solver of the Newton steps.
    pub linear_solver: Option<SolverKind>,
    /// Steps of the cold frames' penalty ramp.
    pub penalty_steps: Option<u32>,
    /// Multiplies both ends of the penalty ramp: the automatic 0.02 E h … 2 E h through
    /// `registration.penalty_scale` (so the cloud-noise weight stays), the scene's
    /// `penalty_start`/`penalty_end` where given.
    pub penalty_factor: Option<f64>,
    /// Grid origin shift in cell units (moves the surface against the grid: cuts cells
    /// differently).
    pub origin_offset: Option<[f64; 3]>,
    /// Coarse-to-fine start of cold frames with this factor on the cell size.
    pub coarse_to_fine: Option<f64>,
    /// Fictitious-domain weight α of cut cells' outside parts (`grid.min_fraction`).
    pub min_fraction: Option<f64>,
    /// Cut-cell step stabilisation γ (`solver.step_stabilization`).
    pub step_stabilization: Option<f64>,
    /// Median/MAD pruning of rigid ICP pairs (`registration.robust_pruning`).
    pub robust_pruning: Option<bool>,
    /// Warm-frame refactorisation on a helper thread
    /// (`registration.background_factorization`).
    pub background_factorization: Option<bool>,
    /// Removal of isolated cloud points (`registration.remove_isolated_points`).
    pub remove_isolated_points: Option<bool>,
    /// Single-precision factorisations in warm frames (`solver.mixed_precision`).
    pub mixed_precision: Option<bool>,
}

/// The registration model a [`ModelConfig`] resolves to on a scene: what the report shows.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ResolvedConfig {
    /// Cell edge, mm.
    pub cell_size_mm: f64,
    /// Octree levels on cut cells.
    pub subdivisions: u32,
    /// Integration of cut cells.
    pub integration: IntegrationMode,
    /// Constitutive law.
    pub law: LawKind,
    /// Poisson's ratio.
    pub poisson_ratio: f64,
    /// Linear solver.
    pub linear_solver: SolverKind,
    /// Steps of the cold penalty ramp.
    pub penalty_steps: u32,
    /// Factor on the penalty ramp (1: the scene's).
    pub penalty_factor: f64,
    /// Grid origin shift, cell units.
    pub origin_offset: [f64; 3],
    /// Coarse-to-fine factor on the cell size (`None`: off).
    pub coarse_to_fine: Option<f64>,
    /// Fictitious-domain weight α of cut cells' outside parts.
    pub min_fraction: f64,
    /// Cut-cell step stabilisation γ (0: off).
    pub step_stabilization: f64,
    /// Median/MAD pruning of rigid ICP pairs (else mean + 2σ).
    pub robust_pruning: bool,
    /// Warm-frame refactorisation on a helper thread.
    pub background_factorization: bool,
    /// Isolated cloud points removed before registration.
    pub remove_isolated_points: bool,
    /// Single-precision factorisations in warm frames.
    pub mixed_precision: bool,
}

impl ModelConfig {
    /// The scene as it is, named `default`.
    pub fn scene_default() -> Self {
        Self {
            name: "default".into(),
            ..Self::default()
        }
    }

    /// Whether this is the scene's own model (no change).
    pub fn is_default(&self) -> bool {
        Self {
            name: self.name.clone(),
            ..Self::default()
        } == *self
    }

    /// `scene` with this configuration's changes, validated (the message names the
    /// configuration and the scene key that became invalid).
    pub fn apply(&self, scene: &LoadedScene) -> Result<LoadedScene, String> {
        let mut out = scene.clone();
        self.apply_to(&mut out.scene)?;
        Ok(out)
    }

    /// Applies the changes to a scene (every change is unit-free), and validates it (see
    /// [`ModelConfig::apply`]).
    pub fn apply_to(&self, s: &mut Scene) -> Result<(), String> {
        if let Some(f) = self.cell_size_factor {
            s.grid.cell_size *= f;
        }
        if let Some(v) = self.subdivisions {
            s.grid.subdivisions = v;
        }
        if let Some(v) = self.integration {
            s.grid.integration = v;
        }
        if let Some(v) = self.law {
            s.material.law = v;
        }
        if let Some(v) = self.poisson_ratio {
            s.material.poisson_ratio = v;
        }
        if let Some(v) = self.linear_solver {
            s.solver.linear_solver = v;
        }
        if let Some(v) = self.origin_offset {
            s.grid.origin_offset = v;
        }
        if let Some(v) = self.min_fraction {
            s.grid.min_fraction = v;
        }
        if let Some(v) = self.step_stabilization {
            s.solver.step_stabilization = v;
        }
        if let Some(v) = self.mixed_precision {
            s.solver.mixed_precision = v;
        }
        if self.penalty_steps.is_some()
            || self.penalty_factor.is_some()
            || self.coarse_to_fine.is_some()
            || self.robust_pruning.is_some()
            || self.background_factorization.is_some()
            || self.remove_isolated_points.is_some()
        {
            let r = s.registration.get_or_insert_with(RegistrationSpec::default);
            if let Some(v) = self.robust_pruning {
                r.robust_pruning = v;
            }
            if let Some(v) = self.background_factorization {
                r.background_factorization = v;
            }
            if let Some(v) = self.remove_isolated_points {
                r.remove_isolated_points = v;
            }
            if let Some(v) = self.penalty_steps {
                r.penalty_steps = v;
            }
            if let Some(v) = self.coarse_to_fine {
                r.coarse_to_fine = Some(v);
            }
            if let Some(f) = self.penalty_factor {
                // Given stiffnesses times f; the automatic ends through the scale, which
                // keeps the noise weight.
                r.penalty_start = r.penalty_start.map(|k| f * k);
                r.penalty_end = r.penalty_end.map(|k| f * k);
                r.penalty_scale *= f;
            }
        }
        let problems = validate_scene(s);
        if let Some(p) = problems.first() {
            return Err(format!("configuration `{}`: {p}", self.name));
        }
        Ok(())
    }

    /// What this configuration resolves to on `scene` (call with the result of
    /// [`ModelConfig::apply`]).
    pub fn resolved(&self, applied: &LoadedScene) -> ResolvedConfig {
        let s = &applied.scene;
        ResolvedConfig {
            cell_size_mm: s.grid.cell_size * applied.length_scale() * 1e3,
            subdivisions: s.grid.subdivisions,
            integration: s.grid.integration,
            law: s.material.law,
            poisson_ratio: s.material.poisson_ratio,
            linear_solver: s.solver.linear_solver,
            penalty_steps: s
                .registration
                .as_ref()
                .map_or(crate::scene::defaults::penalty_steps(), |r| r.penalty_steps),
            penalty_factor: self.penalty_factor.unwrap_or(1.0),
            origin_offset: s.grid.origin_offset,
            coarse_to_fine: s.registration.as_ref().and_then(|r| r.coarse_to_fine),
            min_fraction: s.grid.min_fraction,
            step_stabilization: s.solver.step_stabilization,
            robust_pruning: s
                .registration
                .as_ref()
                .map_or(crate::scene::defaults::robust_pruning(), |r| {
                    r.robust_pruning
                }),
            background_factorization: s
                .registration
                .as_ref()
                .is_some_and(|r| r.background_factorization),
            remove_isolated_points: s
                .registration
                .as_ref()
                .map_or(crate::scene::defaults::remove_isolated_points(), |r| {
                    r.remove_isolated_points
                }),
            mixed_precision: s.solver.mixed_precision,
        }
    }
}

/// The sweep of `livereg bench`: the default and, one axis at a time, cell size (×0.75, ×1.5,
/// ×2), subdivision level (1 to 4), integration (finite-cell, full-cell), fictitious weight α
/// (10⁻⁴, 10⁻³, 10⁻², 3·10⁻², 10⁻¹), cut-cell step stabilisation γ (0, 10, 30, 100, 300,
/// 1000), law (neo-Hookean, SVK, linear, corotated), linear solver (LDLᵀ,
/// Jacobi-CG), penalty ramp (1 and 5 steps), the other pair-pruning rule (mean + 2σ or
/// median/MAD), isolated cloud points kept (or removed), background factorisation, mixed
/// precision, coarse-to-fine start (cells ×2) — changes already equal to the scene's value
/// are left out. `quick`: the default, cell ×1.5 and ×2, finite-cell, full-cell, no stabilisation
/// and neo-Hookean.
pub fn sweep_configs(scene: &LoadedScene, quick: bool) -> Vec<ModelConfig> {
    let s = &scene.scene;
    // The scene's own values of the registration settings the sweep flips.
    let base = ModelConfig::scene_default().resolved(scene);
    let mut out = vec![ModelConfig::scene_default()];
    out.extend(cell_size_configs(quick));
    if !quick {
        out.extend(subdivision_configs(s));
    }
    out.extend(integration_configs(s));
    if !quick {
        out.extend(min_fraction_configs(s));
    }
    out.extend(stabilization_configs(s, quick));
    out.extend(law_configs(s, quick));
    if !quick {
        out.extend(solver_and_registration_configs(s, &base));
    }
    out
}

/// A configuration named `name` that changes nothing yet.
fn named(name: &str) -> ModelConfig {
    ModelConfig {
        name: name.to_string(),
        ..ModelConfig::default()
    }
}

/// The cell size factors of the sweep (×0.75, ×1.5, ×2; `quick`: ×1.5, ×2).
fn cell_size_configs(quick: bool) -> Vec<ModelConfig> {
    let cells: &[f64] = if quick {
        &[1.5, 2.0]
    } else {
        &[0.75, 1.5, 2.0]
    };
    cells
        .iter()
        .map(|&f| ModelConfig {
            cell_size_factor: Some(f),
            ..named(&format!("cell x{f}"))
        })
        .collect()
}

/// Subdivision levels 1 to 4, but for the scene's own.
fn subdivision_configs(s: &Scene) -> Vec<ModelConfig> {
    [1, 2, 3, 4]
        .into_iter()
        .filter(|&l| l != s.grid.subdivisions)
        .map(|l| ModelConfig {
            subdivisions: Some(l),
            ..named(&format!("subdiv {l}"))
        })
        .collect()
}

/// The integrations of cut cells (weighted-cell, finite-cell, full-cell), but for the
/// scene's own.
fn integration_configs(s: &Scene) -> Vec<ModelConfig> {
    [
        IntegrationMode::WeightedCell,
        IntegrationMode::FiniteCell,
        IntegrationMode::FullCell,
    ]
    .into_iter()
    .filter(|&m| m != s.grid.integration)
    .map(|m| ModelConfig {
        integration: Some(m),
        ..named(m.name())
    })
    .collect()
}

/// Fictitious-domain weights α (10⁻⁴, 10⁻³, 10⁻², 3·10⁻², 10⁻¹), but for the scene's own.
fn min_fraction_configs(s: &Scene) -> Vec<ModelConfig> {
    [1e-4, 1e-3, 1e-2, 3e-2, 1e-1]
        .into_iter()
        .filter(|&a| a != s.grid.min_fraction)
        .map(|a| ModelConfig {
            min_fraction: Some(a),
            ..named(&format!("alpha {a:e}"))
        })
        .collect()
}

/// Cut-cell step stabilisations γ (0, 10, 30, 100, 300, 1000; `quick`: 0), but for the
/// scene's own.
fn stabilization_configs(s: &Scene, quick: bool) -> Vec<ModelConfig> {
    let gammas: &[f64] = if quick {
        &[0.0]
    } else {
        &[0.0, 10.0, 30.0, 100.0, 300.0, 1000.0]
    };
    gammas
        .iter()
        .filter(|&&g| g != s.solver.step_stabilization)
        .map(|&g| ModelConfig {
            step_stabilization: Some(g),
            ..named(&format!("stabilization {g}"))
        })
        .collect()
}

/// Constitutive laws (neo-Hookean, SVK, linear, corotated, Mooney–Rivlin; `quick`:
/// neo-Hookean and corotated), but for the scene's own.
fn law_configs(s: &Scene, quick: bool) -> Vec<ModelConfig> {
    let laws: &[LawKind] = if quick {
        &[LawKind::NeoHookean, LawKind::Corotated]
    } else {
        &[
            LawKind::NeoHookean,
            LawKind::Svk,
            LawKind::Linear,
            LawKind::Corotated,
            LawKind::MooneyRivlin,
        ]
    };
    laws.iter()
        .filter(|&&l| l != s.material.law)
        .map(|&l| ModelConfig {
            law: Some(l),
            ..named(law_name(l))
        })
        .collect()
}

/// The solver and registration settings, each against the scene's own (`base`): linear
/// solvers (LDLᵀ, Jacobi-CG), penalty ramps of 1 and 5 steps, the other pair-pruning rule,
/// the other treatment of isolated cloud points, and — where the scene has them off —
/// background factorisation, mixed precision and a coarse-to-fine start (cells ×2).
fn solver_and_registration_configs(s: &Scene, base: &ResolvedConfig) -> Vec<ModelConfig> {
    let mut out = Vec::new();
    for k in [SolverKind::Ldlt, SolverKind::JacobiCg] {
        if k != s.solver.linear_solver {
            out.push(ModelConfig {
                linear_solver: Some(k),
                ..named(solver_name(k))
            });
        }
    }
    for n in [1, 5] {
        if n != base.penalty_steps {
            out.push(ModelConfig {
                penalty_steps: Some(n),
                ..named(&format!("ramp {n}"))
            });
        }
    }
    out.push(ModelConfig {
        robust_pruning: Some(!base.robust_pruning),
        ..named(if base.robust_pruning {
            "mean-2sigma pruning"
        } else {
            "median-mad pruning"
        })
    });
    out.push(ModelConfig {
        remove_isolated_points: Some(!base.remove_isolated_points),
        ..named(if base.remove_isolated_points {
            "isolated points kept"
        } else {
            "isolated points removed"
        })
    });
    if !base.background_factorization {
        out.push(ModelConfig {
            background_factorization: Some(true),
            ..named("background factorisation")
        });
    }
    if !base.mixed_precision {
        out.push(ModelConfig {
            mixed_precision: Some(true),
            ..named("mixed precision")
        });
    }
    if base.coarse_to_fine.is_none() {
        out.push(ModelConfig {
            coarse_to_fine: Some(2.0),
            ..named("coarse-to-fine")
        });
    }
    out
}

/// The scene-file name of a law.
pub fn law_name(l: LawKind) -> &'static str {
    match l {
        LawKind::Linear => "linear",
        LawKind::Corotated => "corotated",
        LawKind::Svk => "svk",
        LawKind::NeoHookean => "neo-hookean",
        LawKind::MooneyRivlin => "mooney-rivlin",
    }
}

/// The scene-file name of a linear solver.
pub fn solver_name(k: SolverKind) -> &'static str {
    match k {
        SolverKind::Auto => "auto",
        SolverKind::Cholesky => "cholesky",
        SolverKind::Ldlt => "ldlt",
        SolverKind::JacobiCg => "jacobi-cg",
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::load_scene;

    fn phantom() -> LoadedScene {
        let p = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("fixtures/liver_phantom/scene.toml");
        load_scene(&p).unwrap()
    }

    #[test]
    fn default_changes_nothing_and_each_axis_changes_its_key() {
        let scene = phantom();
        let d = ModelConfig::scene_default();
        assert!(d.is_default());
        assert_eq!(d.apply(&scene).unwrap().scene, scene.scene);
        let c = ModelConfig {
            name: "x".into(),
            cell_size_factor: Some(2.0),
            law: Some(LawKind::Svk),
            penalty_factor: Some(10.0),
            ..ModelConfig::default()
        };
        assert!(!c.is_default());
        let a = c.apply(&scene).unwrap();
        assert_eq!(a.scene.grid.cell_size, 2.0 * scene.scene.grid.cell_size);
        assert_eq!(a.scene.material.law, LawKind::Svk);
        // The automatic ramp stays automatic (so its noise weight stays), scaled by 10, and
        // the session's stages get the scale.
        let r = a.scene.registration.as_ref().unwrap();
        assert_eq!((r.penalty_start, r.penalty_end), (None, None));
        assert_eq!(r.penalty_scale, 10.0);
        let settings = crate::simulation::session_settings(&a.scene, a.length_scale());
        assert_eq!(settings.cold.penalty_scale, 10.0);
        assert_eq!(settings.warm.penalty_scale, 10.0);
        // Stiffnesses a scene gives are multiplied themselves.
        let mut given = scene.clone();
        let g = given.scene.registration.as_mut().unwrap();
        (g.penalty_start, g.penalty_end) = (Some(3.0), Some(300.0));
        let a = c.apply(&given).unwrap();
        let r = a.scene.registration.as_ref().unwrap();
        assert_eq!((r.penalty_start, r.penalty_end), (Some(30.0), Some(3000.0)));
        assert!((c.resolved(&a).cell_size_mm - 2.0 * scene.scene.grid.cell_size).abs() < 1e-9);
    }

    /// α, γ and the pruning rule reach the scene keys the session reads, and the report shows
    /// them.
    #[test]
    fn alpha_and_pruning_change_their_scene_keys() {
        let scene = phantom();
        // The phantom keeps the default: median/MAD pruning in rigid ICP.
        assert!(scene
            .scene
            .registration
            .as_ref()
            .is_some_and(|r| r.robust_pruning));
        let c = ModelConfig {
            name: "x".into(),
            min_fraction: Some(1e-3),
            step_stabilization: Some(0.0),
            robust_pruning: Some(false),
            ..ModelConfig::default()
        };
        let a = c.apply(&scene).unwrap();
        assert_eq!(a.scene.grid.min_fraction, 1e-3);
        assert_eq!(a.scene.solver.step_stabilization, 0.0);
        assert!(!a.scene.registration.as_ref().unwrap().robust_pruning);
        let r = c.resolved(&a);
        assert_eq!((r.min_fraction, r.robust_pruning), (1e-3, false));
        assert_eq!(r.step_stabilization, 0.0);
        let settings = crate::simulation::session_settings(&a.scene, a.length_scale());
        assert!(!settings.rigid.robust_pruning);
        let default = crate::simulation::session_settings(&scene.scene, 1e-3);
        assert!(default.rigid.robust_pruning);
        // The rigid key leaves the non-rigid stage alone: with the default cloud → surface
        // term warm frames prune at median/MAD, a cold frame at mean + 2σ.
        assert!(settings.warm.robust_pruning && !settings.cold.robust_pruning);
        let bad = ModelConfig {
            name: "bad alpha".into(),
            min_fraction: Some(0.5),
            ..ModelConfig::default()
        };
        let e = bad.apply(&scene).unwrap_err();
        assert!(
            e.contains("bad alpha") && e.contains("grid.min_fraction"),
            "{e}"
        );
    }

    #[test]
    fn an_invalid_change_names_the_configuration_and_key() {
        let c = ModelConfig {
            name: "bad".into(),
            poisson_ratio: Some(0.5),
            ..ModelConfig::default()
        };
        let e = c.apply(&phantom()).unwrap_err();
        assert!(
            e.contains("bad") && e.contains("material.poisson_ratio"),
            "{e}"
        );
    }

    #[test]
    fn sweep_names_are_unique_and_skip_the_scenes_own_values() {
        let scene = phantom();
        for quick in [true, false] {
            let c = sweep_configs(&scene, quick);
            let mut names: Vec<&str> = c.iter().map(|c| c.name.as_str()).collect();
            names.sort();
            names.dedup();
            assert_eq!(names.len(), c.len());
            assert!(c[0].is_default());
            assert!(c[1..].iter().all(|c| !c.is_default()));
            // The phantom is weighted-cell and neo-Hookean: neither appears as a change.
            assert!(!names.contains(&"weighted-cell") && !names.contains(&"neo-hookean"));
            // Nor does its own fictitious weight (the default 1e-2) as an α row.
            assert!(!names.contains(&"alpha 1e-2"));
            for x in &c {
                x.apply(&scene).unwrap();
            }
        }
    }
}

//! Tests of scene parsing, validation, error messages and the simulate report.

use crate::mechanics::Outcome;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

use super::*;
use crate::scene::PoseUpdate;

/// The scene example of `docs/contracts.md` ("Scene file"), verbatim.
const CONTRACT_EXAMPLE: &str = r#"units = "m"                      # "m" | "cm" | "mm"

[model]
surface = "liver.obj"            # closed triangle surface: .obj .stl .ply .off .vtk .vtp, Gmsh 2.2 .msh (its triangles)

[[model.structures]]             # internal structures, carried along by the deformation
name = "nodes"
points = "targets.xyz"           # a point file (format below); or: mesh = "tumour.obj"

[grid]
cell_size = 0.01                 # edge of a cubic cell, in scene units; optional: omitted, a default derived from the surface
subdivisions = 4                 # octree levels used on cut cells
integration = "weighted-cell"    # "weighted-cell" | "finite-cell" | "full-cell" (cut cells counted as full)

[material]
law = "neo-hookean"              # "neo-hookean" | "svk" | "corotated" | "linear"
young_modulus = 4500.0           # Pa
poisson_ratio = 0.49
density = 1000.0                 # kg/m³, for gravity

[[boundary.fixed]]               # parts that keep their rest position (ligaments, a clamped face)
box = [[-1.0, -1.0, -0.001], [1.0, 1.0, 0.001]]   # the part of the surface inside this box
# or: points = "fixed.xyz"       # these points (on or inside the surface) are held in place

[[load.traction]]                # dead load: force per unit rest area on the surface inside the box
box = [[-1.0, -1.0, 0.079], [1.0, 1.0, 0.081]]
value = [0.0, -30.0, 0.0]

[load]
gravity = [0.0, 0.0, 0.0]        # m/s²

[solver]                         # all optional
load_steps = 10

[[probe]]                        # points whose displacement `simulate` reports
points = [[0.0, 0.0, 0.08]]

[registration]                   # all optional
rigid = "icp"                    # "icp" | "none" (the clouds are already in the model's frame)
camera = { position = [0.0, 0.0, 0.5], look_at = [0.0, 0.0, 0.0] }   # omit when unknown
"#;

/// A scratch directory removed on drop.
struct TempDir(PathBuf);

impl TempDir {
    fn new() -> TempDir {
        static N: AtomicUsize = AtomicUsize::new(0);
        let dir = std::env::temp_dir().join(format!(
            "livereg-scene-test-{}-{}",
            std::process::id(),
            N.fetch_add(1, Ordering::Relaxed)
        ));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        TempDir(dir)
    }

    fn write(&self, name: &str, text: &str) -> PathBuf {
        let p = self.0.join(name);
        std::fs::write(&p, text).unwrap();
        p
    }

    /// A directory with the files the contract example names.
    fn with_model() -> TempDir {
        let d = TempDir::new();
        d.write("liver.obj", "");
        d.write("targets.xyz", "");
        d
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// A small valid scene; tests splice bad bits into it.
const MINIMAL: &str = r#"
[model]
surface = "liver.obj"

[grid]
cell_size = 0.01

[material]
young_modulus = 4500.0
poisson_ratio = 0.45
"#;

fn load_toml(dir: &TempDir, text: &str) -> Result<LoadedScene, SceneError> {
    let p = dir.write("scene.toml", text);
    load_scene(&p)
}

/// Load `text` as `scene.toml`, expect an error, check its message holds every `needles`.
fn toml_error(text: &str, needles: &[&str]) -> SceneError {
    let dir = TempDir::with_model();
    let err = load_toml(&dir, text).expect_err("the scene should be rejected");
    let msg = err.to_string();
    assert!(msg.contains("scene.toml"), "no file name in: {msg}");
    for n in needles {
        assert!(msg.contains(n), "{n:?} missing from: {msg}");
    }
    assert!(!msg.contains('\n'), "message is not one line: {msg}");
    err
}

#[test]
fn contract_example_parses_with_documented_defaults() {
    let dir = TempDir::with_model();
    let loaded = load_toml(&dir, CONTRACT_EXAMPLE).unwrap();
    let s = &loaded.scene;
    let abs_dir = std::path::absolute(&dir.0).unwrap();
    assert_eq!(loaded.dir, abs_dir);
    assert_eq!(loaded.path, abs_dir.join("scene.toml"));
    assert_eq!(s.units, Units::Metres);
    assert_eq!(loaded.length_scale(), 1.0);
    assert_eq!(s.model.surface, abs_dir.join("liver.obj"));
    assert!(s.model.surface.is_absolute());
    assert_eq!(s.model.structures.len(), 1);
    assert_eq!(s.model.structures[0].name, "nodes");
    assert_eq!(
        s.model.structures[0].points,
        Some(abs_dir.join("targets.xyz"))
    );
    assert_eq!(s.model.structures[0].mesh, None);

    assert_eq!(s.grid.cell_size, 0.01);
    assert_eq!(s.grid.subdivisions, 4);
    assert_eq!(s.grid.integration, IntegrationMode::WeightedCell);
    assert_eq!(s.grid.min_fraction, 1e-2);
    assert_eq!(s.grid.origin_offset, [0.0; 3]);

    assert_eq!(s.material.law, LawKind::NeoHookean);
    assert_eq!(s.material.young_modulus, 4500.0);
    assert_eq!(s.material.poisson_ratio, 0.49);
    assert_eq!(s.material.density, 1000.0);
    assert_eq!(s.material.volumetric, VolumetricIntegration::Reduced);

    assert_eq!(s.boundary.fixed.len(), 1);
    let f = &s.boundary.fixed[0];
    let b = BoxRegion {
        min: [-1.0, -1.0, -0.001],
        max: [1.0, 1.0, 0.001],
    };
    assert_eq!(f.bbox, Some(b));
    assert_eq!(f.region(), Some(FixedRegion::Box(&b)));
    assert_eq!(f.points, None);
    assert_eq!(f.stiffness, None);

    assert_eq!(s.load.traction.len(), 1);
    assert_eq!(s.load.traction[0].bbox.min, [-1.0, -1.0, 0.079]);
    assert_eq!(s.load.traction[0].bbox.max, [1.0, 1.0, 0.081]);
    assert_eq!(s.load.traction[0].value, [0.0, -30.0, 0.0]);
    assert_eq!(s.load.gravity, [0.0; 3]);

    assert_eq!(
        s.solver,
        SolverSpec {
            load_steps: 10,
            max_newton_iterations: 30,
            residual_tolerance: 1e-8,
            displacement_tolerance: 1e-8,
            max_bisections: 6,
            line_search: true,
            linear_solver: SolverKind::Auto,
            projected_tangent: true,
            mixed_precision: false,
            step_stabilization: 100.0,
            penalty_stiffness: None,
        }
    );
    assert_eq!(s.solver, SolverSpec::default());

    assert_eq!(s.probe.len(), 1);
    assert_eq!(
        s.probe[0].points,
        PointSource::Inline(vec![[0.0, 0.0, 0.08]])
    );

    let r = s.registration.as_ref().unwrap();
    assert_eq!(r.rigid, RigidMode::Icp);
    assert_eq!(
        r.camera,
        Some(Camera {
            position: [0.0, 0.0, 0.5],
            look_at: [0.0, 0.0, 0.0],
            up: None
        })
    );
    assert_eq!(r.alpha, 0.75);
    assert_eq!(r.penalty_start, None);
    assert_eq!(r.penalty_end, None);
    assert_eq!(r.penalty_steps, 3);
    assert_eq!(r.max_icp_iterations, 10);
    assert_eq!(r.pose, PoseUpdate::Hold);
    let d = RegistrationSpec::default();
    assert_eq!(
        RegistrationSpec {
            camera: r.camera.clone(),
            ..d
        },
        *r
    );
}

#[test]
fn minimal_scene_defaults() {
    let dir = TempDir::with_model();
    let s = load_toml(&dir, MINIMAL).unwrap().scene;
    assert_eq!(s.units, Units::Metres);
    assert!(s.model.structures.is_empty());
    assert_eq!(s.grid, {
        let mut g = GridSpec::with_cell_size(0.01);
        g.subdivisions = 3;
        g
    });
    assert_eq!(
        s.material,
        MaterialSpec {
            poisson_ratio: 0.45,
            ..MaterialSpec::new(LawKind::NeoHookean, 4500.0, 0.45)
        }
    );
    assert_eq!(s.boundary, BoundarySpec::default());
    assert_eq!(s.load, LoadSpec::default());
    assert_eq!(s.solver, SolverSpec::default());
    assert!(s.probe.is_empty());
    assert_eq!(s.registration, None);
}

#[test]
fn every_key_can_be_set() {
    let dir = TempDir::with_model();
    dir.write("tumour.OBJ", "");
    dir.write("fixed.csv", "");
    dir.write("probe.txt", "");
    let text = r#"
units = "mm"
[model]
surface = "liver.obj"
structures = [
  { name = "tumour", mesh = "tumour.OBJ" },
  { name = "nodes", points = "targets.xyz" },
]
[grid]
cell_size = 8
subdivisions = 0
integration = "finite-cell"
min_fraction = 0.0
origin_offset = [0.5, 0.25, 0.999]
[material]
law = "svk"
young_modulus = 3000
poisson_ratio = -0.2
density = 0
volumetric = "full"
[boundary]
fixed = [
  { points = "fixed.csv", stiffness = 1e4 },
  { points = [[1, 2, 3], [4, 5, 6]] },
  { box = [[0, 0, 0], [0, 0, 0]] },
]
[load]
gravity = [0, 0, -9.81]
traction = [{ box = [[-1, -1, -1], [1, 1, 1]], value = [1, 2, 3] }]
[solver]
load_steps = 10000
max_newton_iterations = 1
residual_tolerance = 1e-6
displacement_tolerance = 0.5
max_bisections = 0
line_search = false
linear_solver = "jacobi-cg"
penalty_stiffness = 1e5
[[probe]]
points = "probe.txt"
[[probe]]
points = [[0, 0, 0]]
[registration]
rigid = "none"
camera = { position = [0, 0, 500], look_at = [0, 0, 0], up = [0, 1, 0] }
alpha = 1
penalty_start = 10
penalty_end = 1e4
penalty_steps = 1
max_icp_iterations = 7
"#;
    let l = load_toml(&dir, text).unwrap();
    let s = &l.scene;
    let abs = |n: &str| std::path::absolute(dir.0.join(n)).unwrap();
    assert_eq!(s.units, Units::Millimetres);
    assert_eq!(l.length_scale(), 0.001);
    assert_eq!(Units::Centimetres.to_metres(), 0.01);
    assert_eq!(s.model.structures[0].mesh, Some(abs("tumour.OBJ")));
    assert_eq!(s.grid.cell_size, 8.0);
    assert_eq!(s.grid.subdivisions, 0);
    assert_eq!(s.grid.integration, IntegrationMode::FiniteCell);
    assert_eq!(s.grid.origin_offset, [0.5, 0.25, 0.999]);
    assert_eq!(s.material.law, LawKind::Svk);
    assert_eq!(s.material.volumetric, VolumetricIntegration::Full);
    assert_eq!(
        s.boundary.fixed[0].points,
        Some(PointSource::File(abs("fixed.csv")))
    );
    assert_eq!(s.boundary.fixed[0].stiffness, Some(1e4));
    assert_eq!(
        s.boundary.fixed[1].points,
        Some(PointSource::Inline(vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]))
    );
    assert_eq!(s.load.gravity, [0.0, 0.0, -9.81]);
    assert_eq!(s.solver.linear_solver, SolverKind::JacobiCg);
    assert!(!s.solver.line_search);
    assert_eq!(s.solver.penalty_stiffness, Some(1e5));
    assert_eq!(s.probe[0].points, PointSource::File(abs("probe.txt")));
    let r = s.registration.as_ref().unwrap();
    assert_eq!(r.rigid, RigidMode::Identity);
    assert_eq!(r.camera.as_ref().unwrap().up, Some([0.0, 1.0, 0.0]));
    assert_eq!(r.max_icp_iterations, 7);
    assert_eq!(s.material.lame_mu(), 3000.0 / (2.0 * 0.8));
}

/// The contract example written as JSON by hand.
const CONTRACT_EXAMPLE_JSON: &str = r#"{
  "units": "m",
  "model": {
    "surface": "liver.obj",
    "structures": [{"name": "nodes", "points": "targets.xyz"}]
  },
  "grid": {"cell_size": 0.01, "subdivisions": 4, "integration": "weighted-cell"},
  "material": {"law": "neo-hookean", "young_modulus": 4500.0, "poisson_ratio": 0.49,
               "density": 1000.0},
  "boundary": {"fixed": [{"box": [[-1.0, -1.0, -0.001], [1.0, 1.0, 0.001]]}]},
  "load": {
    "traction": [{"box": [[-1.0, -1.0, 0.079], [1.0, 1.0, 0.081]], "value": [0.0, -30.0, 0.0]}],
    "gravity": [0.0, 0.0, 0.0]
  },
  "solver": {"load_steps": 10},
  "probe": [{"points": [[0.0, 0.0, 0.08]]}],
  "registration": {"rigid": "icp",
                   "camera": {"position": [0.0, 0.0, 0.5], "look_at": [0.0, 0.0, 0.0]}}
}"#;

#[test]
fn json_scene_equals_toml_scene() {
    let dir = TempDir::with_model();
    let from_toml = load_toml(&dir, CONTRACT_EXAMPLE).unwrap();
    let p = dir.write("scene.json", CONTRACT_EXAMPLE_JSON);
    let from_json = load_scene(&p).unwrap();
    assert_eq!(from_toml.scene, from_json.scene);
    assert_eq!(from_toml.dir, from_json.dir);
}

#[test]
fn scene_round_trips_through_toml_and_json() {
    let s = parse_scene(CONTRACT_EXAMPLE, SceneFormat::Toml, Path::new("x.toml")).unwrap();
    let toml_text = toml::to_string(&s).unwrap();
    let back = parse_scene(&toml_text, SceneFormat::Toml, Path::new("y.toml")).unwrap();
    assert_eq!(s, back, "{toml_text}");
    let json_text = serde_json::to_string_pretty(&s).unwrap();
    let back = parse_scene(&json_text, SceneFormat::Json, Path::new("y.json")).unwrap();
    assert_eq!(s, back, "{json_text}");
}

#[test]
fn units_are_parsed_and_scaled() {
    for (u, scale) in [("m", 1.0), ("cm", 0.01), ("mm", 0.001)] {
        let dir = TempDir::with_model();
        let l = load_toml(&dir, &format!("units = \"{u}\"\n{MINIMAL}")).unwrap();
        assert_eq!(l.length_scale(), scale);
        assert_eq!(l.scene.units.as_str(), u);
    }
    toml_error(
        &format!("units = \"inch\"\n{MINIMAL}"),
        &["units", "inch", "`mm`"],
    );
}

/// The contact refit's scene keys reach the session's settings, lengths in metres; omitted,
/// the session's defaults.
#[test]
fn the_contact_refit_keys_reach_the_session_settings() {
    let dir = TempDir::with_model();
    let text = format!(
        "units = \"mm\"\n{}",
        MINIMAL.replace(
            "[material]",
            "[registration]\ncontact_radius = 45\nrefit_factorizations = 4\n\n[material]"
        )
    );
    let l = load_toml(&dir, &text).unwrap();
    let s = crate::simulation::session_settings(&l.scene, l.length_scale());
    assert!((s.contact_radius - 0.045).abs() < 1e-15);
    assert_eq!(s.refit_factorizations, 4);
    let l = load_toml(&dir, MINIMAL).unwrap();
    let s = crate::simulation::session_settings(&l.scene, l.length_scale());
    let d = livereg_registration::session::SessionSettings::default();
    assert_eq!(s.contact_radius, d.contact_radius);
    assert_eq!(s.refit_factorizations, d.refit_factorizations);
}

#[test]
fn unknown_top_level_key() {
    let e = toml_error(&format!("colour = \"red\"\n{MINIMAL}"), &["colour", ":1:"]);
    assert!(
        matches!(e, SceneError::Parse { line: Some(1), .. }),
        "{e:?}"
    );
}

#[test]
fn unknown_nested_key() {
    let text = MINIMAL.replace("cell_size = 0.01", "cellsize = 0.01");
    let e = toml_error(&text, &["cellsize", "grid.cellsize", "cell_size"]);
    // `cellsize` is on line 6.
    assert!(
        matches!(e, SceneError::Parse { line: Some(6), .. }),
        "{e:?}"
    );
    let e = toml_error(
        &format!("{MINIMAL}\n[[boundary.fixed]]\nbox = [[0,0,0],[1,1,1]]\nstiff = 3\n"),
        &["stiff", "boundary.fixed[0].stiff"],
    );
    assert!(
        matches!(e, SceneError::Parse { line: Some(14), .. }),
        "{e:?}"
    );
    toml_error(
        &format!("{MINIMAL}\n[registration]\ncamera = {{ position = [0,0,1], look_at = [0,0,0], fov = 60 }}\n"),
        &["fov", "registration.camera"],
    );
}

#[test]
fn wrong_type_names_line_and_key() {
    let text = MINIMAL.replace("cell_size = 0.01", "cell_size = \"small\"");
    let e = toml_error(&text, &["scene.toml:6:", "grid.cell_size", "string"]);
    match e {
        SceneError::Parse {
            line, column, key, ..
        } => {
            assert_eq!(line, Some(6));
            assert_eq!(column, Some(13));
            assert_eq!(key.as_deref(), Some("grid.cell_size"));
        }
        other => panic!("{other:?}"),
    }
    toml_error(
        &MINIMAL.replace("poisson_ratio = 0.45", "poisson_ratio = 0.45\nlaw = 3"),
        &["material.law", ":11:"],
    );
}

/// Without `grid.cell_size` the cell size is derived from the enclosed volume: a cube of edge
/// 0.09 m encloses 7.29e-4 m³, whose cube root over 9 is 0.01 m.
#[test]
fn omitted_cell_size_is_derived_from_the_surface() {
    let dir = TempDir::with_model();
    let cube = crate::mesh::primitives::box_surface(
        nalgebra::Point3::new(0.0, 0.0, 0.0),
        nalgebra::Point3::new(0.09, 0.09, 0.09),
        2,
    );
    crate::mesh::write_obj(&dir.0.join("liver.obj"), &cube).unwrap();
    let loaded = load_toml(&dir, &MINIMAL.replace("cell_size = 0.01", "")).unwrap();
    assert!((loaded.scene.grid.cell_size - 0.01).abs() < 1e-12);
}

#[test]
fn missing_required_keys() {
    // An omitted cell size is derived from the surface; an empty surface file cannot give one.
    toml_error(
        &MINIMAL.replace("cell_size = 0.01", ""),
        &[
            "grid.cell_size",
            "omitted",
            "cannot be derived",
            "liver.obj",
        ],
    );
    toml_error(
        &MINIMAL.replace("surface = \"liver.obj\"", ""),
        &[
            "model.surface",
            "missing: give `surface`",
            "or `segmentation`",
        ],
    );
    let e = toml_error("units = \"m\"\n", &["missing field `model`"]);
    assert!(
        matches!(&e, SceneError::Parse { key: Some(k), .. } if k == "model"),
        "{e:?}"
    );
    toml_error(
        &format!("{MINIMAL}\n[registration]\ncamera = {{ position = [0, 0, 1] }}\n"),
        &["registration.camera.look_at", "missing field `look_at`"],
    );
    toml_error(
        &format!(
            "{MINIMAL}\n[[load.traction]]\nbox = [[0, 0, 0], [1, 1, 1]]\nvalue = [0, 0, 1]\n\
             [[load.traction]]\nbox = [[0, 0, 0], [1, 1, 1]]\n"
        ),
        &["load.traction[1].value", "missing field `value`"],
    );
    toml_error(&format!("{MINIMAL}\n[[probe]]\n"), &["probe[0].points"]);
}

#[test]
fn negative_cell_size() {
    let e = toml_error(
        &MINIMAL.replace("cell_size = 0.01", "cell_size = -0.01"),
        &["grid.cell_size", "-0.01", "> 0"],
    );
    assert_eq!(e.problems().len(), 1);
    toml_error(
        &MINIMAL.replace("cell_size = 0.01", "cell_size = nan"),
        &["grid.cell_size", "finite", "NaN"],
    );
}

#[test]
fn poisson_ratio_one_half_is_rejected_with_hint() {
    toml_error(
        &MINIMAL.replace("poisson_ratio = 0.45", "poisson_ratio = 0.5"),
        &["material.poisson_ratio", "0.5", "0.499"],
    );
    toml_error(
        &MINIMAL.replace("poisson_ratio = 0.45", "poisson_ratio = -1"),
        &["material.poisson_ratio", "-1"],
    );
    let dir = TempDir::with_model();
    load_toml(
        &dir,
        &MINIMAL.replace("poisson_ratio = 0.45", "poisson_ratio = 0.499"),
    )
    .unwrap();
}

#[test]
fn inverted_box() {
    toml_error(
        &format!("{MINIMAL}\n[[boundary.fixed]]\nbox = [[0, 1, 0], [1, 0, 1]]\n"),
        &[
            "boundary.fixed[0].box",
            "inverted",
            "axis y",
            "[0.0, 1.0, 0.0]",
        ],
    );
    toml_error(
        &format!("{MINIMAL}\n[[load.traction]]\nbox = [[0, 0, 2], [1, 1, 1]]\nvalue = [0, 0, 1]\n"),
        &["load.traction[0].box", "axis z"],
    );
}

#[test]
fn missing_surface_file() {
    let dir = TempDir::new();
    let e = load_toml(&dir, MINIMAL).unwrap_err();
    let msg = e.to_string();
    let expected = std::path::absolute(dir.0.join("liver.obj")).unwrap();
    assert!(msg.contains("scene.toml"), "{msg}");
    assert!(msg.contains("model.surface"), "{msg}");
    assert!(msg.contains(&expected.display().to_string()), "{msg}");
    assert!(msg.contains("not found"), "{msg}");
}

#[test]
fn missing_point_files_are_named() {
    let text = format!(
        "{MINIMAL}\n[[model.structures]]\nname = \"a\"\npoints = \"nope.xyz\"\n[[probe]]\npoints = \"gone.csv\"\n"
    );
    let e = toml_error(
        &text,
        &[
            "model.structures[0].points",
            "nope.xyz",
            "probe[0].points",
            "gone.csv",
        ],
    );
    assert_eq!(e.problems().len(), 2, "{e}");
}

#[test]
fn unknown_law_lists_allowed_names() {
    toml_error(
        &MINIMAL.replace("young_modulus", "law = \"mooney\"\nyoung_modulus"),
        &[
            "material.law",
            "mooney",
            "neo-hookean",
            "svk",
            "corotated",
            "linear",
        ],
    );
}

#[test]
fn duplicate_structure_names() {
    toml_error(
        &format!(
            "{MINIMAL}\n[[model.structures]]\nname = \"nodes\"\npoints = \"targets.xyz\"\n\
             [[model.structures]]\nname = \"nodes\"\nmesh = \"liver.obj\"\n"
        ),
        &["model.structures[1].name", "duplicate", "\"nodes\""],
    );
    toml_error(
        &format!("{MINIMAL}\n[[model.structures]]\nname = \" \"\npoints = \"targets.xyz\"\n"),
        &["model.structures[0].name", "empty"],
    );
    toml_error(
        &format!("{MINIMAL}\n[[model.structures]]\nname = \"n\"\n"),
        &["model.structures[0]", "neither"],
    );
}

#[test]
fn fixed_region_with_both_box_and_points() {
    toml_error(
        &format!(
            "{MINIMAL}\n[[boundary.fixed]]\nbox = [[0, 0, 0], [1, 1, 1]]\npoints = [[0, 0, 0]]\n"
        ),
        &["boundary.fixed[0]", "both `box` and `points`"],
    );
    toml_error(
        &format!("{MINIMAL}\n[[boundary.fixed]]\nstiffness = 10.0\n"),
        &["boundary.fixed[0]", "neither"],
    );
}

#[test]
fn toml_syntax_error_has_line_and_column() {
    let text = MINIMAL.replace("cell_size = 0.01", "cell_size = = 0.01");
    let e = toml_error(&text, &["scene.toml:6:", "syntax error"]);
    match e {
        SceneError::Parse {
            line,
            column,
            format,
            ..
        } => {
            assert_eq!(format, SceneFormat::Toml);
            assert_eq!(line, Some(6));
            assert_eq!(column, Some(13));
        }
        other => panic!("{other:?}"),
    }
    let e = toml_error("[model\nsurface = \"liver.obj\"\n", &["scene.toml:1:7:"]);
    assert!(matches!(e, SceneError::Parse { .. }));
}

#[test]
fn json_errors_name_key_and_line() {
    let dir = TempDir::with_model();
    let bad = CONTRACT_EXAMPLE_JSON.replace("\"cell_size\": 0.01", "\"cellsize\": 0.01");
    let msg = load_scene(&dir.write("scene.json", &bad))
        .unwrap_err()
        .to_string();
    assert!(msg.contains("scene.json:7:"), "{msg}");
    assert!(msg.contains("grid.cellsize"), "{msg}");

    let bad = CONTRACT_EXAMPLE_JSON.replace("\"load_steps\": 10", "\"load_steps\": \"ten\"");
    let msg = load_scene(&dir.write("scene.json", &bad))
        .unwrap_err()
        .to_string();
    assert!(msg.contains("scene.json:15:"), "{msg}");
    assert!(msg.contains("solver.load_steps"), "{msg}");

    let bad = CONTRACT_EXAMPLE_JSON.replace(
        "\"value\": [0.0, -30.0, 0.0]",
        "\"value\": [0.0, \"x\", 0.0]",
    );
    let msg = load_scene(&dir.write("scene.json", &bad))
        .unwrap_err()
        .to_string();
    assert!(msg.contains("load.traction[0].value[1]"), "{msg}");

    let bad = CONTRACT_EXAMPLE_JSON.replace("\"young_modulus\": 4500.0, ", "");
    let msg = load_scene(&dir.write("scene.json", &bad))
        .unwrap_err()
        .to_string();
    assert!(msg.contains("material.young_modulus"), "{msg}");

    let msg = load_scene(&dir.write("scene.json", "{\"units\": \"m\",\n \"model\": }"))
        .unwrap_err()
        .to_string();
    assert!(msg.contains("scene.json:2:"), "{msg}");
    assert!(msg.contains("syntax error"), "{msg}");
}

#[test]
fn other_extension_is_read_as_toml_and_says_so() {
    let dir = TempDir::with_model();
    let p = dir.write("scene.cfg", MINIMAL);
    load_scene(&p).unwrap();
    let p = dir.write("scene.cfg", CONTRACT_EXAMPLE_JSON);
    let msg = load_scene(&p).unwrap_err().to_string();
    assert!(msg.contains("scene.cfg"), "{msg}");
    assert!(msg.contains("read as TOML"), "{msg}");
}

#[test]
fn unreadable_scene_file() {
    let dir = TempDir::new();
    let e = load_scene(&dir.0.join("absent.toml")).unwrap_err();
    assert!(matches!(e, SceneError::Read { .. }));
    assert!(e.to_string().contains("absent.toml"));
}

#[test]
fn range_checks() {
    let cases: &[(&str, &str, &[&str])] = &[
        (
            "subdivisions = 7",
            "grid",
            &["grid.subdivisions", "7", "8^"],
        ),
        ("min_fraction = 0.5", "grid", &["grid.min_fraction", "0.5"]),
        (
            "origin_offset = [0, 1, 0]",
            "grid",
            &["grid.origin_offset", "[0, 1)"],
        ),
        (
            "young_modulus = 0.0",
            "material",
            &["material.young_modulus", "got 0"],
        ),
        ("density = -1", "material", &["material.density", "-1"]),
        ("load_steps = 0", "solver", &["solver.load_steps", "0"]),
        (
            "load_steps = 10001",
            "solver",
            &["solver.load_steps", "10001"],
        ),
        (
            "residual_tolerance = 1.0",
            "solver",
            &["solver.residual_tolerance", "(0, 1)"],
        ),
        (
            "displacement_tolerance = 0",
            "solver",
            &["solver.displacement_tolerance"],
        ),
        (
            "max_newton_iterations = 0",
            "solver",
            &["solver.max_newton_iterations"],
        ),
        (
            "max_bisections = 31",
            "solver",
            &["solver.max_bisections", "31"],
        ),
        (
            "penalty_stiffness = -5",
            "solver",
            &["solver.penalty_stiffness", "-5"],
        ),
        ("gravity = [0, 0, inf]", "load", &["load.gravity", "finite"]),
        (
            "alpha = 1.5",
            "registration",
            &["registration.alpha", "1.5"],
        ),
        (
            "penalty_start = 100\npenalty_end = 10",
            "registration",
            &["registration.penalty_end", "100"],
        ),
        (
            "penalty_scale = 0",
            "registration",
            &["registration.penalty_scale", "must be > 0"],
        ),
        (
            "contact_radius = -3",
            "registration",
            &["registration.contact_radius", "-3"],
        ),
        (
            "refit_factorizations = 0",
            "registration",
            &["registration.refit_factorizations", ">= 1", "0"],
        ),
        (
            "camera = { position = [0, 0, 1], look_at = [0, 0, 1] }",
            "registration",
            &["registration.camera.look_at"],
        ),
        (
            "camera = { position = [0, 0, 1], look_at = [0, 0, 0], up = [0, 0, 2] }",
            "registration",
            &["registration.camera.up", "parallel"],
        ),
    ];
    for (line, table, needles) in cases {
        let key = line.split(' ').next().unwrap();
        let text = if let Some(old) = MINIMAL.lines().find(|l| l.starts_with(&format!("{key} ="))) {
            MINIMAL.replace(old, line)
        } else if MINIMAL.contains(&format!("[{table}]")) {
            MINIMAL.replace(&format!("[{table}]"), &format!("[{table}]\n{line}"))
        } else {
            format!("{MINIMAL}\n[{table}]\n{line}\n")
        };
        toml_error(&text, needles);
    }
}

#[test]
fn several_problems_are_reported_together() {
    let text = MINIMAL
        .replace("cell_size = 0.01", "cell_size = 0")
        .replace("poisson_ratio = 0.45", "poisson_ratio = 0.7");
    let e = toml_error(&text, &["grid.cell_size", "material.poisson_ratio"]);
    assert_eq!(e.problems().len(), 2);
}

#[test]
fn points_accept_path_or_inline_list() {
    let dir = TempDir::with_model();
    dir.write("fixed.xyz", "0 0 0\n");
    let text = format!(
        "{MINIMAL}\n[[boundary.fixed]]\npoints = \"fixed.xyz\"\n\
         [[boundary.fixed]]\npoints = [[0.0, 0.0, 0.0], [1, 2, 3]]\n\
         [[probe]]\npoints = \"targets.xyz\"\n[[probe]]\npoints = [[0, 0, 0.08]]\n"
    );
    let s = load_toml(&dir, &text).unwrap().scene;
    let abs = |n: &str| std::path::absolute(dir.0.join(n)).unwrap();
    assert_eq!(
        s.boundary.fixed[0].points,
        Some(PointSource::File(abs("fixed.xyz")))
    );
    assert_eq!(
        s.boundary.fixed[1].points,
        Some(PointSource::Inline(vec![[0.0; 3], [1.0, 2.0, 3.0]]))
    );
    assert!(matches!(
        s.boundary.fixed[1].region(),
        Some(FixedRegion::Points(PointSource::Inline(_)))
    ));
    assert_eq!(s.probe[0].points, PointSource::File(abs("targets.xyz")));
    assert_eq!(
        s.probe[1].points,
        PointSource::Inline(vec![[0.0, 0.0, 0.08]])
    );
    // The same in JSON.
    let json = r#"{"model": {"surface": "liver.obj"}, "grid": {"cell_size": 0.01},
        "material": {"young_modulus": 1.0, "poisson_ratio": 0.3},
        "boundary": {"fixed": [{"points": "fixed.xyz"}, {"points": [[1, 2, 3]]}]},
        "probe": [{"points": "targets.xyz"}, {"points": [[0, 0, 0.08]]}]}"#;
    let j = load_scene(&dir.write("s.json", json)).unwrap().scene;
    assert_eq!(j.boundary.fixed[0].points, s.boundary.fixed[0].points);
    assert_eq!(j.probe, s.probe);
}

#[test]
fn bad_points_values() {
    toml_error(
        &format!("{MINIMAL}\n[[probe]]\npoints = 3\n"),
        &["probe[0].points", "point file path", "inline list"],
    );
    toml_error(
        &format!("{MINIMAL}\n[[probe]]\npoints = [[0, 0]]\n"),
        &["probe[0].points"],
    );
    toml_error(
        &format!("{MINIMAL}\n[[probe]]\npoints = []\n"),
        &["probe[0].points", "empty"],
    );
    toml_error(
        &format!("{MINIMAL}\n[[probe]]\npoints = \"probe.wrl\"\n"),
        &["probe[0].points", "probe.wrl", ".xyz"],
    );
    toml_error(
        &MINIMAL.replace("liver.obj", "liver.wrl"),
        &["model.surface", "liver.wrl", ".obj"],
    );
}

#[test]
fn simulate_report_uses_contract_keys_in_order() {
    let r = SimulateReport {
        converged: true,
        newton_iterations: 37,
        load_steps: 10,
        wall_ms: 84.2,
        grid: GridSummary {
            nodes: 1234,
            cells: 900,
            cut_cells: 310,
        },
        probes: vec![ProbeResult {
            point: [0.0, 0.0, 0.08],
            displacement: [0.0, -0.0123, -0.0004],
        }],
        max_displacement: 0.0131,
        outcome: Outcome::Converged.name().to_string(),
        message: None,
        bisections: 0,
    };
    let json = r.to_json();
    let contract = r#"{"converged":true,"newton_iterations":37,"load_steps":10,"wall_ms":84.2,"grid":{"nodes":1234,"cells":900,"cut_cells":310},"probes":[{"point":[0.0,0.0,0.08],"displacement":[0.0,-0.0123,-0.0004]}],"max_displacement":0.0131"#;
    assert!(json.starts_with(contract), "{json}");
    assert_eq!(
        &json[contract.len()..],
        r#","outcome":"converged","bisections":0}"#
    );
    // The contract's own example (no extras) deserialises, and round trips.
    let example = r#"{"converged": true, "newton_iterations": 37, "load_steps": 10, "wall_ms": 84.2,
 "grid": {"nodes": 1234, "cells": 900, "cut_cells": 310},
 "probes": [{"point": [0.0, 0.0, 0.08], "displacement": [0.0, -0.0123, -0.0004]}],
 "max_displacement": 0.0131, "outcome": "converged"}"#;
    let back: SimulateReport = serde_json::from_str(example).unwrap();
    assert_eq!(back, r);
    let failed = SimulateReport {
        converged: false,
        outcome: Outcome::Inverted.name().to_string(),
        message: Some("J <= 0 in cell 12".into()),
        bisections: 6,
        ..r
    };
    let json = failed.to_json();
    assert!(
        json.ends_with(r#""outcome":"inverted","message":"J <= 0 in cell 12","bisections":6}"#),
        "{json}"
    );
}

#[test]
fn line_column_counts_characters() {
    use super::error::line_column;
    assert_eq!(line_column("abc", 0), (1, 1));
    assert_eq!(line_column("a\nbc", 3), (2, 2));
    assert_eq!(line_column("é = 1\nx", 3), (1, 3));
    assert_eq!(line_column("ab", 99), (1, 3));
}

#[test]
fn examples_in_the_scene_reference_parse() {
    let doc = include_str!("../../../../docs/scene.md");
    let mut blocks = 0;
    for (fence, format) in [
        ("```toml\n", SceneFormat::Toml),
        ("```json\n", SceneFormat::Json),
    ] {
        for (i, _) in doc.match_indices(fence) {
            let body = &doc[i + fence.len()..];
            let body = &body[..body.find("```").unwrap()];
            let scene = parse_scene(body, format, Path::new("scene.md"))
                .unwrap_or_else(|e| panic!("{e}\n{body}"));
            let problems = validate_scene(&scene);
            assert!(problems.is_empty(), "{problems:?}\n{body}");
            blocks += 1;
        }
    }
    assert_eq!(blocks, 3);
    let first = doc.find("```toml\n").unwrap() + 8;
    assert!(doc[first..].starts_with(CONTRACT_EXAMPLE));
}

#[test]
fn load_scene_str_resolves_against_the_given_path() {
    let dir = TempDir::with_model();
    let notional = dir.0.join("never-written.toml");
    let l = load_scene_str(MINIMAL, SceneFormat::Toml, &notional).unwrap();
    assert_eq!(l.path, std::path::absolute(&notional).unwrap());
    assert_eq!(l.resolve(Path::new("liver.obj")), l.scene.model.surface);
    assert_eq!(
        l.resolve(Path::new("/abs/x.obj")),
        PathBuf::from("/abs/x.obj")
    );
    let e = load_scene_str("[model", SceneFormat::Toml, &notional).unwrap_err();
    assert!(e.to_string().contains("never-written.toml:1:"), "{e}");
}

#[test]
fn max_pose_uncertainty_must_be_a_positive_length() {
    toml_error(
        &format!("{MINIMAL}\n[registration]\nmax_pose_uncertainty = -1.0\n"),
        &["registration.max_pose_uncertainty", "-1"],
    );
}

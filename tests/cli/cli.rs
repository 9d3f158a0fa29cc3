//! The `livereg` binary: the bundled scenes run, and every malformed scene, mesh or value gives
//! a non-zero exit and a one-line message naming the file and the problem (never a panic).

use std::path::{Path, PathBuf};

use crate::common;
use common::livereg;

/// A fresh directory under the system temp dir.
fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("livereg-cli-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

const CUBE_OBJ: &str = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n\
f 1 3 2\nf 1 4 3\nf 5 6 7\nf 5 7 8\nf 1 2 6\nf 1 6 5\nf 2 3 7\nf 2 7 6\nf 3 4 8\nf 3 8 7\nf 4 1 5\nf 4 5 8\n";

const GOOD_SCENE: &str = r#"
units = "cm"
[model]
surface = "cube.obj"
[grid]
cell_size = 0.25
subdivisions = 2
[material]
law = "neo-hookean"
young_modulus = 3000.0
poisson_ratio = 0.45
[[boundary.fixed]]
box = [[-1.0, -1.0, -0.0001], [2.0, 2.0, 0.0001]]
[[load.traction]]
box = [[-1.0, -1.0, 0.9999], [2.0, 2.0, 1.0001]]
value = [50.0, 0.0, 0.0]
[[probe]]
points = [[0.5, 0.5, 1.0]]
"#;

fn write_case(dir: &Path, scene: &str, mesh: &str) -> PathBuf {
    std::fs::write(dir.join("cube.obj"), mesh).unwrap();
    let p = dir.join("scene.toml");
    std::fs::write(&p, scene).unwrap();
    p
}

#[test]
fn a_good_scene_prints_the_contract_json() {
    let d = scratch("good");
    let scene = write_case(&d, GOOD_SCENE, CUBE_OBJ);
    let out_dir = d.join("out");
    let (code, stdout, stderr) = livereg(&[
        "simulate",
        scene.to_str().unwrap(),
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{stderr}");
    let v: serde_json::Value = serde_json::from_str(stdout.trim()).expect("one JSON object");
    assert_eq!(v["converged"], true);
    for key in [
        "newton_iterations",
        "load_steps",
        "wall_ms",
        "max_displacement",
    ] {
        assert!(v[key].is_number(), "{key}");
    }
    assert_eq!(v["grid"]["cells"], 64);
    // 50 Pa shear on the top of a 1 cm cube held at its base (E = 3 kPa, ν = 0.45): the top
    // centre's displacement along +x (cm, scene units) against an independent solve,
    // quadratic tetrahedra in scikit-fem refined to 16 × 16 × 16 (0.1118 cm; 4 / 8 / 12 / 16:
    // 0.1091 / 0.1110 / 0.1116 / 0.1118, `fixtures/reference/cube_shear.py`). The grid
    // converges to it from below, as trilinear cells do (linear law): 4 / 8 / 12 / 16 / 20
    // cells a side 0.1056 / 0.1097 / 0.1108 / 0.1113 / 0.1116 cm; this scene's neo-Hookean
    // law gives 0.1055 cm on its 4 cells (−5.6 %). The boxes are
    // 0.1 µm thin: a box reaching 0.01 cm past the faces (as this scene had) also loads and
    // holds strips of the side faces, by more of their area as the cells (and the surface
    // samples) shrink, and the same scene went 0.1056 / 0.1140 / 0.1068 cm on 4 / 8 / 16
    // cells. Pure shear alone, τ/G · H, would be 0.048 cm.
    let reference: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(
            Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/reference/cube_shear.json"),
        )
        .expect("fixtures/reference/cube_shear.json"),
    )
    .expect("reference JSON");
    let want = reference["dx_cm"].as_f64().expect("dx_cm");
    let dx = v["probes"][0]["displacement"][0].as_f64().unwrap();
    assert!(
        (0.92 * want..=1.01 * want).contains(&dx),
        "displacement {dx} cm, reference {want} cm"
    );
    assert!(out_dir.join("deformed.obj").exists());
}

/// Each case: (what, scene text, mesh text, words the message must contain).
#[test]
fn malformed_input_fails_cleanly_with_a_message_naming_file_and_problem() {
    let cases: Vec<(&str, String, &str, Vec<&str>)> = vec![
        (
            "unknown key",
            GOOD_SCENE.replace("subdivisions = 2", "subdivisions = 2\ncellsize = 3"),
            CUBE_OBJ,
            vec!["scene.toml", "cellsize"],
        ),
        (
            "negative cell size",
            GOOD_SCENE.replace("cell_size = 0.25", "cell_size = -0.25"),
            CUBE_OBJ,
            vec!["scene.toml", "cell_size"],
        ),
        (
            "string for number",
            GOOD_SCENE.replace("young_modulus = 3000.0", "young_modulus = \"soft\""),
            CUBE_OBJ,
            vec!["scene.toml", "young_modulus"],
        ),
        (
            "incompressible",
            GOOD_SCENE.replace("poisson_ratio = 0.45", "poisson_ratio = 0.5"),
            CUBE_OBJ,
            vec!["scene.toml", "poisson_ratio"],
        ),
        (
            "unknown law",
            GOOD_SCENE.replace("neo-hookean", "mooney"),
            CUBE_OBJ,
            vec!["scene.toml", "mooney"],
        ),
        (
            "missing mesh",
            GOOD_SCENE.replace("cube.obj", "absent.obj"),
            CUBE_OBJ,
            vec!["absent.obj"],
        ),
        (
            "toml syntax",
            GOOD_SCENE.replace("[grid]", "[grid"),
            CUBE_OBJ,
            vec!["scene.toml"],
        ),
        (
            "bad face index",
            GOOD_SCENE.to_string(),
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n",
            vec!["cube.obj", "9"],
        ),
        (
            "nan vertex",
            GOOD_SCENE.to_string(),
            "v 0 0 nan\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
            vec!["cube.obj"],
        ),
        (
            "garbage mesh",
            GOOD_SCENE.to_string(),
            "\u{0}\u{1}garbage",
            vec!["cube.obj"],
        ),
        (
            "empty mesh",
            GOOD_SCENE.to_string(),
            "# nothing\n",
            vec!["cube.obj"],
        ),
        (
            "fixed box misses the surface",
            GOOD_SCENE.replace(
                "[[-1.0, -1.0, -0.0001], [2.0, 2.0, 0.0001]]",
                "[[5.0, 5.0, 5.0], [6.0, 6.0, 6.0]]",
            ),
            CUBE_OBJ,
            vec!["scene.toml", "boundary.fixed[0]"],
        ),
        (
            "probe outside",
            GOOD_SCENE.replace("[[0.5, 0.5, 1.0]]", "[[0.5, 0.5, 9.0]]"),
            CUBE_OBJ,
            vec!["probe"],
        ),
        (
            "cells too small",
            GOOD_SCENE.replace("cell_size = 0.25", "cell_size = 0.0001"),
            CUBE_OBJ,
            vec!["cell size"],
        ),
    ];
    for (i, (what, scene, mesh, words)) in cases.into_iter().enumerate() {
        let d = scratch(&format!("bad{i}"));
        let path = write_case(&d, &scene, mesh);
        let (code, _stdout, stderr) = livereg(&["simulate", path.to_str().unwrap()]);
        assert_ne!(code, 0, "{what}: should fail");
        assert!(!stderr.contains("panicked"), "{what}: panicked: {stderr}");
        assert_eq!(
            stderr.trim().lines().count(),
            1,
            "{what}: one line expected: {stderr}"
        );
        for w in words {
            assert!(stderr.contains(w), "{what}: message lacks '{w}': {stderr}");
        }
    }
}

#[test]
fn missing_scene_and_unknown_command_fail() {
    let (code, _, stderr) = livereg(&["simulate", "/nonexistent/scene.toml"]);
    assert_ne!(code, 0);
    assert!(stderr.contains("/nonexistent/scene.toml"), "{stderr}");
    let (code, _, _) = livereg(&["frobnicate"]);
    assert_ne!(code, 0);
}

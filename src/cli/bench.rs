//! `livereg bench`: the speed-versus-accuracy sweep. Every configuration of
//! [`sweep_configs`] registers the same workloads — the phantom's synthetic scenarios (truth
//! from a different discretisation and law), or the user's scene, frames and truth — and
//! `DIR/bench.json`, `DIR/bench.png` and `DIR/bench.svg` show TRE against ms per frame with
//! the Pareto front.

use std::path::{Path, PathBuf};

use nalgebra::Point3;
use serde::de::IntoDeserializer;
use serde::Deserialize;

use super::progress::bar;
use super::register::frame_inputs;
use crate::benchmark::config::law_name;
use crate::benchmark::force_truths::{
    force_truth_cases, force_truths_dir, force_truths_table, parse_cloud_noise, run_force_truth,
    CameraMotion, ForceTruthMetrics, ForceTruthOptions, TruthSet,
};
use crate::benchmark::indentation::{
    indentation_cases, indentation_chart_point, indentation_table, run_indentation,
    IndentationMetrics, IndentationVariant,
};
use crate::benchmark::indentation_stability::{
    run_indentation_matrix, IndentationStabilityOptions, IndentationStabilityReport,
};
use crate::benchmark::ModelConfig;
use crate::benchmark::{
    run_matrix, run_sweep, sweep_configs, Axis, BenchReport, StabilityOptions, StabilityReport,
    Workload,
};
use crate::charts::pareto::write_chart;
use crate::evaluation::read_truth;
use crate::mechanics::LawKind;
use crate::scene::{load_scene, LoadedScene, PoseUpdate};
use crate::synthetic::indentation::{
    bundled_fixture_dir, INDENTATION_LAWS, INDENTATION_SEQUENCES, INDENTATION_STICKING_LAWS,
};
use crate::synthetic::{generate_sequence, ScenarioKind, SequenceSpec};

/// Arguments of `livereg bench`.
#[derive(Debug, Clone, clap::Args)]
pub struct BenchArgs {
    /// Where bench.json, bench.png and bench.svg go.
    #[arg(long, default_value = "bench-out")]
    pub out: PathBuf,
    /// A short sweep (6 configurations, one scenario, 3 frames) that finishes in minutes.
    #[arg(long)]
    pub quick: bool,
    /// The scene whose model is varied (default: the bundled phantom, written to DIR/phantom).
    #[arg(long, value_name = "SCENE")]
    pub scene: Option<PathBuf>,
    /// The user's frames (a directory of point files or an MCAP recording) instead of the
    /// synthetic scenarios; needs `--truth`.
    #[arg(long, value_name = "PATH", requires = "truth")]
    pub frames: Option<PathBuf>,
    /// Truth of `--frames` (the truth format of `livereg eval`).
    #[arg(long, value_name = "FILE", requires = "frames")]
    pub truth: Option<PathBuf>,
    /// Synthetic scenarios to run (comma-separated; default all, `--quick`: tool-push).
    #[arg(long, value_delimiter = ',')]
    pub scenarios: Vec<String>,
    /// Frames per synthetic scenario (default 10, `--quick`: 3).
    #[arg(long)]
    pub frame_count: Option<usize>,
    /// Only these configurations of the sweep (comma-separated names, e.g. `default,finite-cell`).
    #[arg(long, value_delimiter = ',')]
    pub only: Vec<String>,
    /// Timing passes over all configurations (default 3, `--quick`: 1): each frame's time is
    /// its median over the passes, which steadies the chart's time axis against noise.
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=20))]
    pub repeats: Option<u32>,
    /// Constitutive law of the synthetic ground truth (default neo-Hookean, the truth of
    /// every recorded table; `mooney-rivlin` is none of the registration laws, so no law is
    /// graded against itself). With `--indentation` also `linear-sticking` and
    /// `neo-hookean-sticking`: the fixture's truths with a no-slip tool.
    #[arg(long, value_name = "LAW", value_parser = parse_truth_law)]
    pub truth_law: Option<String>,
    /// Run the stability matrix instead of the sweep (writes stability.json and
    /// stability.md); with `--quick`, its reduced form (two values per axis). With
    /// `--indentation`: the tool-indentation class's matrix (stability-indentation.json and
    /// stability-indentation.md).
    #[arg(long, conflicts_with_all = ["frames", "only"])]
    pub stability: bool,
    /// Run the tool-indentation class instead: the sequences of
    /// `fixtures/liver_indentation` (truth from a tetrahedral FE solve) registered with the
    /// scene (default: that fixture's scene) and each configuration of `--only` (default:
    /// the scene as it is); writes indentation.json and indentation.md. With `--stability`,
    /// its stability matrix instead.
    #[arg(long, conflicts_with = "frames")]
    pub indentation: bool,
    /// With `--indentation`: the variants (`no-camera`, `camera`, `rigid-icp`; default all).
    #[arg(long, value_delimiter = ',', requires = "indentation")]
    pub variants: Vec<String>,
    /// With `--indentation --stability`: register every N-th frame of each sequence, counted
    /// back from its last (default 1, `--quick`: 10); `--frame-count` then keeps the last
    /// that many of them.
    #[arg(long, value_name = "N", requires = "indentation", value_parser = clap::value_parser!(u32).range(1..))]
    pub frame_stride: Option<u32>,
    /// Run the force-driven tetrahedral FE truths of `fixtures/liver_force` instead (six
    /// livers, a load on a small vertex patch pushing up to 63 mm deep, noise-free 500-point
    /// clouds of 15 % of the surface), each with its liver's scene of its law; writes
    /// force-truths.json and force-truths.md. `--frame-count` keeps the first N frames.
    #[arg(long, conflicts_with_all = ["frames", "indentation", "stability", "only"])]
    pub force_truths: bool,
    /// With `--force-truths`: the cases of the fixture's SPLIT.md set (`tuning`, `test`,
    /// default `all`): defaults are chosen on `tuning`, reports quote `test`.
    #[arg(long, value_name = "SET", requires = "force_truths")]
    pub set: Option<String>,
    /// With `--force-truths`: this cell size (mm) instead of the derived one.
    #[arg(long, value_name = "MM", requires = "force_truths")]
    pub cell_size: Option<f64>,
    /// With `--force-truths`: the clouds and truths seen by a camera turning by up to DEG
    /// degrees and moving by up to MM millimetres over each sequence (e.g. `10,20`),
    /// registered with `rigid = "icp"`.
    #[arg(long, value_name = "DEG,MM", requires = "force_truths")]
    pub moving_camera: Option<String>,
    /// With `--moving-camera`: `registration.pose` (`hold`, `track`, `follow`; default the
    /// scene's).
    #[arg(long, value_name = "MODE", requires = "moving_camera")]
    pub pose: Option<String>,
    /// With `--force-truths`: Gaussian noise added to every cloud point, MM per axis (1σ,
    /// seeded per case and frame), on the fixture's noise-free clouds.
    #[arg(long = "noise", value_name = "MM", requires = "force_truths")]
    pub cloud_noise: Option<String>,
}

/// Runs `livereg bench`; prints the table and writes the report and chart (the sweep's
/// report; `None` for `--stability`).
pub fn run(args: &BenchArgs) -> Result<Option<BenchReport>, String> {
    std::fs::create_dir_all(&args.out).map_err(|e| {
        format!(
            "{}: cannot create the output directory: {e}",
            args.out.display()
        )
    })?;
    if args.indentation && args.stability {
        return run_indentation_stability(args).map(|_| None);
    }
    if args.indentation {
        return run_indentation_bench(args).map(|_| None);
    }
    if args.force_truths {
        return run_force_truths_bench(args).map(|_| None);
    }
    let scene = match &args.scene {
        Some(p) => load_scene(p).map_err(|e| e.to_string())?,
        None => {
            let dir = args.out.join("phantom");
            crate::phantom::write_phantom(&dir).map_err(|e| e.to_string())?;
            load_scene(&dir.join("scene.toml")).map_err(|e| e.to_string())?
        }
    };
    if args.stability {
        return run_stability(args, &scene).map(|_| None);
    }
    let mut configs = sweep_configs(&scene, args.quick);
    if !args.only.is_empty() {
        for name in &args.only {
            if !configs.iter().any(|c| &c.name == name) {
                return Err(format!(
                    "--only: no configuration `{name}` (known: {})",
                    configs
                        .iter()
                        .map(|c| c.name.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                ));
            }
        }
        configs.retain(|c| args.only.contains(&c.name));
    }
    let workloads = match (&args.frames, &args.truth) {
        (Some(frames), Some(truth)) => vec![user_workload(frames, truth)?],
        _ => synthetic_workloads(
            &scene,
            &args.scenarios,
            frame_count(args)?,
            args.quick,
            0,
            truth_law_kind(args)?,
        )?,
    };
    let repeats = args
        .repeats
        .map_or(if args.quick { 1 } else { 3 }, |r| r as usize);
    let pb = bar((configs.len() + 1) * repeats, "bench");
    let mut progress = |name: &str| {
        pb.set_message(name.to_string());
        pb.inc(1);
    };
    let report = run_sweep(
        &scene,
        &configs,
        &workloads,
        true,
        args.quick,
        repeats,
        &mut progress,
    );
    pb.finish_and_clear();
    write_report(&report, &args.out)?;
    print!("{}", report.table());
    println!(
        "default on the Pareto front: {}; {:.0} s; artefacts in {}",
        if report.default_on_front { "yes" } else { "no" },
        report.wall_s,
        args.out.display()
    );
    Ok(Some(report))
}

/// `livereg bench --stability`: the matrix on `scene`, written to `stability.json` and
/// `stability.md` in the output directory.
pub fn run_stability(args: &BenchArgs, scene: &LoadedScene) -> Result<StabilityReport, String> {
    let mut options = StabilityOptions::standard(args.quick);
    options.truth_law = truth_law_kind(args)?;
    if let Some(n) = args.frame_count {
        if n == 0 {
            return Err("--frame-count must be >= 1".into());
        }
        options.frames = n;
    }
    if !args.scenarios.is_empty() {
        // The matrix disturbs one scenario: the first named.
        options.scenario = ScenarioKind::parse_list(&args.scenarios)?[0];
    }
    let cells: usize = Axis::ALL
        .iter()
        .map(|a| a.values(options.reduced).len())
        .sum::<usize>()
        * options.methods.len();
    let pb = bar(cells, "stability");
    let mut progress = |what: &str| {
        pb.set_message(what.to_string());
        pb.inc(1);
    };
    let report = run_matrix(scene, &options, &mut progress);
    pb.finish_and_clear();
    let table = report.markdown();
    write_json_and_table(&args.out, "stability", &report, &table)?;
    print!("{table}");
    print_matrix_summary(
        report.cells.len(),
        report.crashes,
        report.non_finite_frames,
        report.wall_s,
        &args.out,
    );
    Ok(report)
}

/// `livereg bench --indentation`: the tool-indentation class, each configuration of `--only`
/// (default: the scene itself) on every sequence × truth law (`--truth-law`: one) × variant;
/// writes `indentation.json` and `indentation.md`.
pub fn run_indentation_bench(args: &BenchArgs) -> Result<Vec<IndentationMetrics>, String> {
    let dir = bundled_fixture_dir();
    let scene_path = args.scene.clone().unwrap_or_else(|| dir.join("scene.toml"));
    let scene = load_scene(&scene_path).map_err(|e| e.to_string())?;
    let variants = indentation_variants(args)?;
    let laws: Vec<&str> = match &args.truth_law {
        Some(l) => vec![l.as_str()],
        None => INDENTATION_LAWS.to_vec(),
    };
    for l in &laws {
        check_indentation_law(l)?;
    }
    let sequences: Vec<&str> = if args.scenarios.is_empty() {
        INDENTATION_SEQUENCES.to_vec()
    } else {
        args.scenarios.iter().map(String::as_str).collect()
    };
    let cases = indentation_cases(&dir, &sequences, &laws, &variants, args.frame_count)?;
    let configs: Vec<ModelConfig> = if args.only.is_empty() {
        vec![ModelConfig::scene_default()]
    } else {
        let all = sweep_configs(&scene, false);
        args.only
            .iter()
            .map(|n| {
                all.iter()
                    .find(|c| &c.name == n)
                    .cloned()
                    .ok_or_else(|| format!("--only: no configuration `{n}`"))
            })
            .collect::<Result<_, _>>()?
    };
    let pb = bar(cases.len() * configs.len(), "indentation");
    let mut rows = Vec::new();
    let mut points = Vec::new();
    for c in &configs {
        let applied = c.apply(&scene)?;
        let mut progress = |name: &str| {
            pb.set_message(format!("{} {name}", c.name));
            pb.inc(1);
        };
        let metrics = run_indentation(&applied, &cases, &mut progress)?;
        points.push(indentation_chart_point(
            &c.name,
            c.name == ModelConfig::scene_default().name,
            &metrics,
        ));
        for mut m in metrics {
            m.workload = format!("{} {}", c.name, m.workload);
            rows.push(m);
        }
    }
    pb.finish_and_clear();
    // A chart of one configuration says nothing the table does not.
    if points.len() > 1 {
        write_chart(
        &points,
        &format!(
            "livereg bench --indentation: mean node error vs warm ms per frame ({} cases, {} cores)",
            cases.len(),
            std::thread::available_parallelism().map_or(1, |n| n.get())
        ),
        Some(&args.out.join("indentation.png")),
        Some(&args.out.join("indentation.svg")),
    )?;
    }
    let table = indentation_table(&rows);
    write_json_and_table(&args.out, "indentation", &rows, &table)?;
    print!("{table}");
    Ok(rows)
}

/// `livereg bench --force-truths`: every case of the set (module
/// [`crate::benchmark::force_truths`]), written to `force-truths.json` and `force-truths.md`.
pub fn run_force_truths_bench(args: &BenchArgs) -> Result<Vec<ForceTruthMetrics>, String> {
    let set = TruthSet::from_name(args.set.as_deref().unwrap_or("all"))?;
    // The scene file's names for `registration.pose`, read by the scene's own deserialiser.
    let pose = args
        .pose
        .as_deref()
        .map(|p| {
            PoseUpdate::deserialize(p.into_deserializer())
                .map_err(|e: serde::de::value::Error| format!("--pose: {e}"))
        })
        .transpose()?;
    let options = ForceTruthOptions {
        cell_size: args.cell_size,
        moving_camera: args
            .moving_camera
            .as_deref()
            .map(CameraMotion::parse)
            .transpose()?,
        pose,
        max_frames: args.frame_count,
        cloud_noise: args
            .cloud_noise
            .as_deref()
            .map(parse_cloud_noise)
            .transpose()?,
    };
    let cases = force_truth_cases(&force_truths_dir(), set)?;
    let pb = bar(cases.len(), "force truths");
    let mut rows = Vec::with_capacity(cases.len());
    for case in &cases {
        pb.set_message(case.name.clone());
        rows.push(run_force_truth(case, &options).map_err(|e| format!("{}: {e}", case.name))?);
        pb.inc(1);
    }
    pb.finish_and_clear();
    let table = force_truths_table(&rows);
    write_json_and_table(&args.out, "force-truths", &rows, &table)?;
    print!("{table}");
    Ok(rows)
}

/// `--variants` (default: all).
fn indentation_variants(args: &BenchArgs) -> Result<Vec<IndentationVariant>, String> {
    if args.variants.is_empty() {
        return Ok(IndentationVariant::ALL.to_vec());
    }
    args.variants
        .iter()
        .map(|v| {
            IndentationVariant::from_name(v).ok_or_else(|| {
                format!("--variants: unknown `{v}` (known: no-camera, camera, rigid-icp)")
            })
        })
        .collect()
}

/// Whether the indentation fixture has a truth with law `law`.
fn check_indentation_law(law: &str) -> Result<(), String> {
    if INDENTATION_LAWS.contains(&law) || INDENTATION_STICKING_LAWS.contains(&law) {
        return Ok(());
    }
    Err(format!(
        "--truth-law {law}: the indentation truth exists for {}, {}",
        INDENTATION_LAWS.join(", "),
        INDENTATION_STICKING_LAWS.join(", ")
    ))
}

/// `livereg bench --indentation --stability`: the tool-indentation class's stability matrix
/// on the scene (default: the fixture's), written to `stability-indentation.json` and
/// `stability-indentation.md` in the output directory.
pub fn run_indentation_stability(args: &BenchArgs) -> Result<IndentationStabilityReport, String> {
    let dir = bundled_fixture_dir();
    let scene_path = args.scene.clone().unwrap_or_else(|| dir.join("scene.toml"));
    let scene = load_scene(&scene_path).map_err(|e| e.to_string())?;
    let mut options = IndentationStabilityOptions::standard(args.quick);
    if let Some(l) = &args.truth_law {
        check_indentation_law(l)?;
        options.truth_law = l.clone();
    }
    if !args.scenarios.is_empty() {
        options.sequences = args.scenarios.clone();
    }
    options.variants = indentation_variants(args)?;
    if let Some(n) = args.frame_stride {
        options.stride = n as usize;
    }
    if let Some(n) = args.frame_count {
        options.max_frames = Some(n);
    }
    options.validate()?;
    let pb = bar(options.rows().len() * options.variants.len(), "stability");
    let mut progress = |what: &str| {
        pb.set_message(what.to_string());
        pb.inc(1);
    };
    let report = run_indentation_matrix(&scene, &dir, &options, &mut progress)?;
    pb.finish_and_clear();
    let table = report.markdown();
    write_json_and_table(&args.out, "stability-indentation", &report, &table)?;
    print!("{table}");
    print_matrix_summary(
        report.cells.len(),
        report.crashes,
        report.non_finite_frames,
        report.wall_s,
        &args.out,
    );
    Ok(report)
}

/// The last line of a stability matrix run: cells, crashes, frames with non-finite output,
/// wall time (s) and where the files are.
fn print_matrix_summary(cells: usize, crashes: usize, non_finite: usize, wall_s: f64, out: &Path) {
    println!(
        "{cells} cells, {crashes} crashed, {non_finite} frames with non-finite output; \
         {wall_s:.0} s; artefacts in {}",
        out.display()
    );
}

/// Writes `value` as `<stem>.json` and `table` as `<stem>.md` into `out`; errors name the file.
fn write_json_and_table(
    out: &Path,
    stem: &str,
    value: &impl serde::Serialize,
    table: &str,
) -> Result<(), String> {
    let json = serde_json::to_string_pretty(value).map_err(|e| e.to_string())?;
    for (ext, text) in [("json", json.as_str()), ("md", table)] {
        let path = out.join(format!("{stem}.{ext}"));
        std::fs::write(&path, text).map_err(|e| format!("{}: {e}", path.display()))?;
    }
    Ok(())
}

/// Frames per synthetic scenario.
fn frame_count(args: &BenchArgs) -> Result<usize, String> {
    let n = args.frame_count.unwrap_or(if args.quick { 3 } else { 10 });
    if n == 0 {
        return Err("--frame-count must be >= 1".into());
    }
    Ok(n)
}

/// Writes `bench.json`, `bench.png` and `bench.svg` into `out`.
pub fn write_report(report: &BenchReport, out: &Path) -> Result<(), String> {
    let json = serde_json::to_string_pretty(report).map_err(|e| e.to_string())?;
    let path = out.join("bench.json");
    std::fs::write(&path, json).map_err(|e| format!("{}: {e}", path.display()))?;
    let title = format!(
        "livereg bench{}: TRE vs ms per frame ({} cores, {})",
        if report.quick { " --quick" } else { "" },
        report.machine.cores,
        report.machine.profile
    );
    write_chart(
        &report.chart_points(),
        &title,
        Some(&out.join("bench.png")),
        Some(&out.join("bench.svg")),
    )
}

/// The synthetic scenarios of `scene` (`names`, default all; `--quick`: tool-push) with
/// `frames` frames each; `seed_offset` is added to each scenario's cloud seed (0: the
/// defaults of [`SequenceSpec::phantom_default`]); `truth_law` replaces the truth model's law.
pub fn synthetic_workloads(
    scene: &LoadedScene,
    names: &[String],
    frames: usize,
    quick: bool,
    seed_offset: u64,
    truth_law: Option<LawKind>,
) -> Result<Vec<Workload>, String> {
    let kinds = if names.is_empty() && quick {
        vec![ScenarioKind::ToolPush]
    } else {
        ScenarioKind::parse_list(names)?
    };
    let pb = bar(kinds.len(), "truth");
    let mut out = Vec::new();
    for kind in kinds {
        pb.set_message(kind.name());
        let mut spec = SequenceSpec::phantom_default(kind);
        spec.frames = frames;
        spec.cloud.seed = spec.cloud.seed.wrapping_add(seed_offset);
        if let Some(law) = truth_law {
            spec.truth.law = law;
        }
        let seq = generate_sequence(scene, &spec).map_err(|e| format!("{}: {e}", kind.name()))?;
        out.push(Workload::from_sequence(&seq, scene.length_scale()));
        pb.inc(1);
    }
    pb.finish_and_clear();
    Ok(out)
}

/// The user's frames (directory or recording) and truth file as a workload.
pub fn user_workload(frames: &Path, truth: &Path) -> Result<Workload, String> {
    let inputs = frame_inputs(frames)?;
    let mut list = Vec::with_capacity(inputs.len());
    for input in &inputs {
        list.push(
            input
                .read()
                .map_err(|(source, e)| format!("{}: frame {source}: {e}", frames.display()))?,
        );
    }
    let records = read_truth(truth).map_err(|e| e.to_string())?;
    let mut truth_frames = vec![None; list.len()];
    for r in records {
        let slot = truth_frames.get_mut(r.frame).ok_or_else(|| {
            format!(
                "{}: truth for frame {} but {} has {} frames",
                truth.display(),
                r.frame,
                frames.display(),
                list.len()
            )
        })?;
        *slot = Some(
            r.structures
                .into_iter()
                .map(|(n, pts)| (n, pts.into_iter().map(Point3::from).collect()))
                .collect(),
        );
    }
    let truth_frames = truth_frames
        .into_iter()
        .enumerate()
        .map(|(k, t)| t.ok_or_else(|| format!("{}: no truth for frame {k}", truth.display())))
        .collect::<Result<Vec<_>, _>>()?;
    Ok(Workload {
        name: frames
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "frames".into()),
        frames: list,
        truth: truth_frames,
        max_displacement_mm: None,
        truth_law: None,
    })
}

/// A law by its scene-file name (`--truth-law`).
/// `--truth-law`: a law's name, or one of the indentation fixture's sticking-tool truths.
fn parse_truth_law(name: &str) -> Result<String, String> {
    if INDENTATION_STICKING_LAWS.contains(&name) {
        return Ok(name.to_string());
    }
    parse_law(name).map(|_| name.to_string())
}

/// `--truth-law` as a law, for the sweep and the stability matrix (the sticking-tool truths
/// exist only for `--indentation`).
fn truth_law_kind(args: &BenchArgs) -> Result<Option<LawKind>, String> {
    args.truth_law
        .as_deref()
        .map(|l| {
            parse_law(l).map_err(|e| format!("--truth-law: {e} (`{l}` only with --indentation)"))
        })
        .transpose()
}

fn parse_law(name: &str) -> Result<LawKind, String> {
    LawKind::ALL
        .into_iter()
        .find(|&l| law_name(l) == name)
        .ok_or_else(|| {
            let names: Vec<&str> = LawKind::ALL.into_iter().map(law_name).collect();
            format!("unknown law `{name}`: expected one of {}", names.join(", "))
        })
}

//! `livereg calibrate SCENE --target-tre MM | --budget-ms MS`: picks, from candidate models
//! registered on synthetic deformations of the scene's own model, the cheapest that meets
//! the TRE target (or the most accurate within the latency budget), writes it into a scene
//! file beside the original, and checks it on fresh frames (other cloud seeds, other
//! intermediate loads) it was not chosen on.

use std::path::{Path, PathBuf};

use super::bench::synthetic_workloads;
use super::progress::bar;
use crate::benchmark::calibrate::{candidates, choose, CalibrationReport, Goal};
use crate::benchmark::sweep::{run_config, run_sweep};
use crate::benchmark::ModelConfig;
use crate::scene::{load_scene, parse_scene, LoadedScene, SceneFormat};

/// Arguments of `livereg calibrate`.
#[derive(Debug, Clone, clap::Args)]
#[command(group = clap::ArgGroup::new("goal").required(true).args(["target_tre", "budget_ms"]))]
pub struct CalibrateArgs {
    /// The scene to calibrate (it must have a camera: `[registration] camera`).
    pub scene: PathBuf,
    /// Largest acceptable mean target registration error, mm.
    #[arg(long, value_name = "MM")]
    pub target_tre: Option<f64>,
    /// Largest acceptable time per frame (95th percentile), ms.
    #[arg(long, value_name = "MS")]
    pub budget_ms: Option<f64>,
    /// The scene file to write (default: SCENE's name with `.calibrated` before the extension,
    /// in SCENE's directory so that its relative paths still hold).
    #[arg(long, value_name = "FILE")]
    pub out: Option<PathBuf>,
    /// Frames per synthetic scenario (default 4).
    #[arg(long, default_value_t = 4)]
    pub frames: usize,
    /// Fewer candidates (weighted-cell only, cells ×2, ×1.5, ×1).
    #[arg(long)]
    pub quick: bool,
    /// Scenarios to calibrate on (comma-separated; default all).
    #[arg(long, value_delimiter = ',')]
    pub scenarios: Vec<String>,
}

/// Runs `livereg calibrate`: prints the report as one JSON object.
pub fn run(args: &CalibrateArgs) -> Result<CalibrationReport, String> {
    let goal = match (args.target_tre, args.budget_ms) {
        (Some(t), None) => Goal::TargetTre(t),
        (None, Some(b)) => Goal::BudgetMs(b),
        _ => return Err("give exactly one of --target-tre and --budget-ms".into()),
    }
    .validate()?;
    if args.frames == 0 {
        return Err("--frames must be >= 1".into());
    }
    let scene = load_scene(&args.scene).map_err(|e| e.to_string())?;
    let workloads = synthetic_workloads(&scene, &args.scenarios, args.frames, false, 0, None)?;
    let configs = candidates(args.quick);
    let pb = bar(configs.len(), "calibrate");
    let mut progress = |name: &str| {
        pb.set_message(name.to_string());
        pb.inc(1);
    };
    let sweep = run_sweep(
        &scene,
        &configs,
        &workloads,
        false,
        args.quick,
        1,
        &mut progress,
    );
    pb.finish_and_clear();
    let index = choose(&sweep.configs, goal)?;
    let chosen = &configs[index];
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| calibrated_path(&args.scene));
    write_scene(&scene, chosen, &out)?;
    // Fresh frames: other cloud seeds and one more frame per scenario, so that the loads
    // fall between the calibration frames' loads.
    eprintln!("livereg: checking `{}` on fresh frames…", chosen.name);
    let fresh = synthetic_workloads(&scene, &args.scenarios, args.frames + 1, false, 7919, None)?;
    let check = run_config(&scene, chosen, &fresh);
    let validated = check
        .metrics
        .ok_or_else(|| check.error.unwrap_or_else(|| "the check run failed".into()))?;
    let c = &sweep.configs[index];
    let predicted = c.metrics.clone().expect("chosen among those with numbers");
    let report = CalibrationReport {
        goal,
        chosen: chosen.name.clone(),
        config: c
            .config
            .clone()
            .expect("a configuration with numbers resolved"),
        predicted_tre_upper_mm: predicted.tre_upper_mm(),
        predicted,
        validated_meets_goal: goal.met_by(&validated),
        validated,
        candidates: sweep.configs.clone(),
        scene: out.display().to_string(),
    };
    println!(
        "{}",
        serde_json::to_string(&report).map_err(|e| e.to_string())?
    );
    eprintln!(
        "livereg: chose `{}`: predicted {:.2} mm (at most {:.2}) at {:.0} ms per frame (warm \
         p95 {:.0}); on fresh frames {:.2} mm at {:.0} ms (warm p95 {:.0}); wrote {}",
        report.chosen,
        report.predicted.tre_mean_mm,
        report.predicted_tre_upper_mm,
        report.predicted.ms_p50,
        report.predicted.warm_ms_p95,
        report.validated.tre_mean_mm,
        report.validated.ms_p50,
        report.validated.warm_ms_p95,
        out.display()
    );
    Ok(report)
}

/// `dir/name.calibrated.ext` for `dir/name.ext`.
fn calibrated_path(scene: &Path) -> PathBuf {
    let stem = scene
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "scene".into());
    let ext = scene
        .extension()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "toml".into());
    scene.with_file_name(format!("{stem}.calibrated.{ext}"))
}

/// Writes the scene file of `loaded` with `config` applied to `out`, in the original's
/// format. Paths are kept as written when `out` is in the original's directory, and made
/// absolute otherwise. The file is loaded back to check it.
fn write_scene(loaded: &LoadedScene, config: &ModelConfig, out: &Path) -> Result<(), String> {
    let text = std::fs::read_to_string(&loaded.path)
        .map_err(|e| format!("{}: {e}", loaded.path.display()))?;
    let (format, _) = SceneFormat::from_path(&loaded.path);
    let same_dir = std::path::absolute(out)
        .ok()
        .and_then(|p| p.parent().map(Path::to_path_buf))
        .is_some_and(|d| d == loaded.dir);
    let mut scene = if same_dir {
        parse_scene(&text, format, &loaded.path).map_err(|e| e.to_string())?
    } else {
        loaded.scene.clone()
    };
    config.apply_to(&mut scene)?;
    let (out_format, _) = SceneFormat::from_path(out);
    let body = match out_format {
        SceneFormat::Toml => toml::to_string(&scene).map_err(|e| e.to_string())?,
        SceneFormat::Json => serde_json::to_string_pretty(&scene).map_err(|e| e.to_string())?,
    };
    let header = format!(
        "# Written by `livereg calibrate` from {} (configuration `{}`).\n",
        loaded.path.display(),
        config.name
    );
    let body = match out_format {
        SceneFormat::Toml => format!("{header}{body}"),
        SceneFormat::Json => body,
    };
    std::fs::write(out, body).map_err(|e| format!("{}: {e}", out.display()))?;
    load_scene(out)
        .map(|_| ())
        .map_err(|e| format!("the calibrated scene does not load back: {e}"))
}

//! `livereg demo [--out DIR]`: the bundled phantom end to end. For each scenario it simulates
//! a ground-truth sequence (finer finite-cell grid, ν = 0.49: not the registration model),
//! registers it rigidly only and with the biomechanical stage, and reports TRE without
//! registration, after rigid and after non-rigid, and ms per frame. The full pipeline's run of
//! each scenario is recorded (`DIR/<scenario>/recording.mcap`) and, with `--rerun`, visualised.

use crate::simulation::FromScene;
use std::path::{Path, PathBuf};

use serde::Serialize;

use super::register::{
    frame_files, recorder_for, register_files, register_inputs, session_for, summarize, FrameInput,
    FrameObserver, RegisterSummary,
};
use super::vtk_series::VtkSeriesWriter;
use super::RerunArgs;
use crate::benchmark::indentation::{IndentationFrameMetrics, IndentationMetrics};
use crate::charts::per_frame::{none_rigid_non_rigid, with_expected_error, write_per_frame_chart};
use crate::charts::surface_view::{write_surface_view, SurfaceView};
use crate::evaluation::{
    evaluate, read_truth, DiagnosticsRecord, EvalReport, ResultRecord, RigidRecord, TruthRecord,
};
use crate::mesh::TriSurface;
use crate::registration::RigidTransform;
use crate::scene::{load_scene, LoadedScene};
use crate::session::FrameResult;
use crate::synthetic::{
    generate_sequence, write_sequence, ScenarioKind, SequenceSpec, SyntheticSequence,
};

/// One scenario's numbers (lengths in mm, the phantom's units).
#[derive(Debug, Clone, Serialize)]
pub struct ScenarioSummary {
    /// Scenario name.
    pub scenario: String,
    /// Frames.
    pub frames: usize,
    /// Largest surface displacement of the truth, mm.
    pub max_displacement_mm: f64,
    /// Mean target TRE with the model left where it is (no registration), mm.
    pub tre_none_mm: f64,
    /// Mean target TRE after rigid ICP only, mm.
    pub tre_rigid_mm: f64,
    /// Mean target TRE after rigid + non-rigid registration, mm.
    pub tre_non_rigid_mm: f64,
    /// 95th percentile of the non-rigid TRE over all targets and frames, mm.
    pub tre_non_rigid_p95_mm: f64,
    /// Median / 95th percentile wall time per frame of the full pipeline, ms.
    pub ms_p50: f64,
    /// See `ms_p50`.
    pub ms_p95: f64,
    /// Frames of the full pipeline that failed.
    pub failed: usize,
    /// Time to simulate the truth, ms.
    pub truth_ms: f64,
}

/// Runs the demo into `out`; `only` restricts the scenarios (names), `frames` per scenario.
pub fn run(out: &Path, frames: usize, only: &[String]) -> Result<Vec<ScenarioSummary>, String> {
    run_with(out, frames, only, &RerunArgs::default(), None)
}

/// [`run`] with rerun output as `rerun` asks (one stream; entities under each scenario's
/// name), and VTK series (`--vtk`) in a subdirectory of `vtk` per scenario.
pub fn run_with(
    out: &Path,
    frames: usize,
    only: &[String],
    rerun: &RerunArgs,
    vtk: Option<&Path>,
) -> Result<Vec<ScenarioSummary>, String> {
    #[allow(unused_variables)]
    let stream = rerun.stream("livereg-demo")?;
    if frames == 0 {
        return Err("--frames must be >= 1".into());
    }
    let (kinds, indentation) = selected_scenarios(only)?;
    let phantom_dir = out.join("phantom");
    crate::phantom::write_phantom(&phantom_dir).map_err(|e| e.to_string())?;
    let loaded = load_scene(&phantom_dir.join("scene.toml")).map_err(|e| e.to_string())?;
    let demo = PhantomDemo {
        loaded: &loaded,
        scale: loaded.length_scale(),
        out,
        frames,
        vtk,
        #[cfg(feature = "rerun")]
        stream: stream.as_ref(),
    };
    let mut summaries = Vec::new();
    for kind in kinds {
        summaries.push(demo.run_scenario(kind)?);
    }
    if indentation {
        summaries.extend(run_indentation_demo(out, vtk)?);
    }
    write_summaries(out, &summaries)?;
    Ok(summaries)
}

/// The phantom scenarios `only` names (all when it is empty; none when it names only the
/// tool-indentation class), and whether the tool-indentation class runs.
fn selected_scenarios(only: &[String]) -> Result<(Vec<ScenarioKind>, bool), String> {
    let indentation = only.is_empty() || only.iter().any(|n| n == INDENTATION_SCENARIO);
    let phantom_only: Vec<String> = only
        .iter()
        .filter(|n| n.as_str() != INDENTATION_SCENARIO)
        .cloned()
        .collect();
    let kinds = if !only.is_empty() && phantom_only.is_empty() {
        Vec::new()
    } else {
        ScenarioKind::parse_list(&phantom_only)?
    };
    Ok((kinds, indentation))
}

/// Prints the table of `summaries`, writes them to `out/summary.json` and names `out`.
fn write_summaries(out: &Path, summaries: &[ScenarioSummary]) -> Result<(), String> {
    println!("{}", table(summaries));
    let json = serde_json::to_string_pretty(summaries).map_err(|e| e.to_string())?;
    let summary_path: PathBuf = out.join("summary.json");
    std::fs::write(&summary_path, json).map_err(|e| format!("{}: {e}", summary_path.display()))?;
    println!("artefacts in {}", out.display());
    Ok(())
}

/// What the demo's phantom scenarios share.
struct PhantomDemo<'a> {
    /// The bundled phantom's scene.
    loaded: &'a LoadedScene,
    /// Metres per scene unit of the phantom.
    scale: f64,
    /// The demo's directory (one subdirectory per scenario).
    out: &'a Path,
    /// Frames per scenario.
    frames: usize,
    /// Directory of the VTK series (one subdirectory per scenario), when asked for.
    vtk: Option<&'a Path>,
    /// The rerun stream, when asked for.
    #[cfg(feature = "rerun")]
    stream: Option<&'a rerun::RecordingStream>,
}

/// One scenario's mean target errors against the truth, per frame and overall (mm).
struct ScenarioErrors {
    /// With the model left where it is (no registration).
    none: EvalReport,
    /// After rigid ICP only.
    rigid: EvalReport,
    /// After rigid + non-rigid registration.
    full: EvalReport,
}

impl PhantomDemo<'_> {
    /// One scenario end to end in `DIR/<scenario>/`: simulates the truth, registers it
    /// rigidly only and with the full pipeline, grades both and no registration, and
    /// draws the per-frame chart and the last frame's view.
    fn run_scenario(&self, kind: ScenarioKind) -> Result<ScenarioSummary, String> {
        let dir = self.out.join(kind.name());
        let (seq, files, truth) = self.simulate(kind, &dir)?;
        let mut rigid_session = session_for(self.loaded, None, true)?;
        let rigid_path = dir.join("results_rigid.jsonl");
        let rigid = register_files(&mut rigid_session, &files, &rigid_path, "rigid")?;
        let path = dir.join("results.jsonl");
        let full = self.register_full(kind, &dir, &files, &path, &truth)?;
        let errors = self.errors(&seq, &truth, &rigid, &full)?;
        let s = summarize(&full, &path);
        write_error_chart(&dir, kind, &errors, &full)?;
        self.write_last_view(&dir, kind, &seq, &full)?;
        Ok(self.summary(kind, &seq, &errors, &s))
    }

    /// Simulates the scenario's ground truth and writes it to `dir`: the sequence, its
    /// frame files (in order) and its truth records as read back.
    fn simulate(
        &self,
        kind: ScenarioKind,
        dir: &Path,
    ) -> Result<(SyntheticSequence, Vec<PathBuf>, Vec<TruthRecord>), String> {
        let frames = self.frames;
        let mut spec = SequenceSpec::phantom_default(kind);
        spec.frames = frames;
        eprintln!(
            "{}: simulating the ground truth ({frames} frames)…",
            kind.name()
        );
        let seq = generate_sequence(self.loaded, &spec).map_err(|e| e.to_string())?;
        write_sequence(&seq, dir, self.scale).map_err(|e| format!("{}: {e}", dir.display()))?;
        let files = frame_files(&dir.join(crate::synthetic::sequence::FRAMES_DIR))?.frames;
        let truth = read_truth(dir.join(crate::synthetic::sequence::TRUTH_FILE))
            .map_err(|e| e.to_string())?;
        Ok((seq, files, truth))
    }

    /// Registers the frame `files` with the full pipeline (rigid + non-rigid): results to
    /// `path`, the recording to `dir/recording.mcap`, and the VTK series and rerun entities
    /// (with the truth `truth`) when asked for.
    fn register_full(
        &self,
        kind: ScenarioKind,
        dir: &Path,
        files: &[PathBuf],
        path: &Path,
        #[cfg_attr(not(feature = "rerun"), allow(unused_variables))] truth: &[TruthRecord],
    ) -> Result<Vec<FrameResult>, String> {
        let mut session = session_for(self.loaded, None, false)?;
        let mut recorder = recorder_for(
            &dir.join("recording.mcap"),
            self.loaded,
            "demo",
            None,
            false,
        )?;
        #[cfg(feature = "rerun")]
        let mut visualiser = self.stream.map(|s| {
            crate::visualisation::Visualiser::new(
                s.clone(),
                kind.name(),
                &session,
                Some(truth.to_vec()),
            )
        });
        let inputs: Vec<FrameInput> = files.iter().cloned().map(FrameInput::File).collect();
        let mut vtk_series = match self.vtk {
            Some(v) => Some(VtkSeriesWriter::create(&v.join(kind.name()), &session)?),
            None => None,
        };
        let full = {
            let mut observers: Vec<&mut dyn FrameObserver> = vec![&mut recorder];
            if let Some(v) = vtk_series.as_mut() {
                observers.push(v);
            }
            #[cfg(feature = "rerun")]
            if let Some(v) = visualiser.as_mut() {
                observers.push(v);
            }
            register_inputs(&mut session, &inputs, path, kind.name(), &mut observers)?
        };
        recorder.finish().map_err(|e| e.to_string())?;
        Ok(full)
    }

    /// The target errors with no registration, after the `rigid` results and after the
    /// `full` ones, against `truth`.
    fn errors(
        &self,
        seq: &SyntheticSequence,
        truth: &[TruthRecord],
        rigid: &[FrameResult],
        full: &[FrameResult],
    ) -> Result<ScenarioErrors, String> {
        let records = |rs: &[FrameResult]| -> Vec<ResultRecord> {
            rs.iter()
                .map(|r| ResultRecord::from_frame(r, self.scale))
                .collect()
        };
        let none = self.rest_records(seq, truth);
        let eval = |r: &[ResultRecord]| evaluate(r, truth).map_err(|e| e.to_string());
        Ok(ScenarioErrors {
            none: eval(&none)?,
            rigid: eval(&records(rigid))?,
            full: eval(&records(full))?,
        })
    }

    /// "No registration" as results: for each truth frame, the identity pose and the
    /// structures at rest (scene units).
    fn rest_records(&self, seq: &SyntheticSequence, truth: &[TruthRecord]) -> Vec<ResultRecord> {
        let scale = self.scale;
        truth
            .iter()
            .map(|t| ResultRecord {
                frame: t.frame,
                source: "rest".into(),
                wall_ms: 0.0,
                converged: true,
                rigid: RigidRecord::from_transform(&RigidTransform::identity(), scale),
                diagnostics: DiagnosticsRecord::default(),
                contact_force: None,
                expected_error: None,
                structures: seq
                    .rest_structures
                    .iter()
                    .map(|(n, pts)| {
                        (
                            n.clone(),
                            pts.iter()
                                .map(|p| [p.x / scale, p.y / scale, p.z / scale])
                                .collect(),
                        )
                    })
                    .collect(),
            })
            .collect()
    }

    /// The last frame's registered surface coloured by its distance to the truth (mm),
    /// beside the truth, in `dir/surface_view.{png,svg}` (nothing without a frame).
    fn write_last_view(
        &self,
        dir: &Path,
        kind: ScenarioKind,
        seq: &SyntheticSequence,
        full: &[FrameResult],
    ) -> Result<(), String> {
        let scale = self.scale;
        if let (Some(last), Some(k)) = (full.last(), seq.frames.len().checked_sub(1)) {
            let truth_surface = {
                let mut t = seq.truth_surface(k);
                t.scale(1.0 / scale);
                t
            };
            let registered = TriSurface::new(last.surface.clone(), truth_surface.triangles.clone());
            let error: Vec<f64> = registered
                .vertices
                .iter()
                .zip(&truth_surface.vertices)
                .map(|(a, b)| (a - b).norm() * scale * 1e3)
                .collect();
            write_view(
                dir,
                kind.name(),
                &registered,
                &error,
                &truth_surface,
                seq.camera.view_direction().into_inner(),
            )?;
        }
        Ok(())
    }

    /// The scenario's row: largest truth displacement and errors in mm, the full
    /// pipeline's times per frame in ms (`s`).
    fn summary(
        &self,
        kind: ScenarioKind,
        seq: &SyntheticSequence,
        errors: &ScenarioErrors,
        s: &RegisterSummary,
    ) -> ScenarioSummary {
        ScenarioSummary {
            scenario: kind.name().into(),
            frames: self.frames,
            max_displacement_mm: seq
                .frames
                .iter()
                .map(|f| f.max_displacement)
                .fold(0.0, f64::max)
                / self.scale,
            tre_none_mm: errors.none.overall.mean,
            tre_rigid_mm: errors.rigid.overall.mean,
            tre_non_rigid_mm: errors.full.overall.mean,
            tre_non_rigid_p95_mm: errors.full.overall.p95,
            ms_p50: s.p50_ms,
            ms_p95: s.p95_ms,
            failed: s.failed,
            truth_ms: seq.truth_ms,
        }
    }
}

/// The mean target error per frame (mm) with no registration, after rigid and after
/// non-rigid, with the `full` results' expected error, in `dir/error_per_frame.{png,svg}`.
fn write_error_chart(
    dir: &Path,
    kind: ScenarioKind,
    errors: &ScenarioErrors,
    full: &[FrameResult],
) -> Result<(), String> {
    let per_frame = |e: &EvalReport| -> Vec<f64> { e.frames.iter().map(|f| f.mean).collect() };
    write_per_frame_chart(
        &with_expected_error(
            none_rigid_non_rigid(
                per_frame(&errors.none),
                per_frame(&errors.rigid),
                per_frame(&errors.full),
            ),
            full.iter()
                .map(|r| r.expected_error.map(|e| e.expected))
                .collect(),
        ),
        &format!("{}: mean target error per frame", kind.name()),
        Some(&dir.join("error_per_frame.png")),
        Some(&dir.join("error_per_frame.svg")),
    )
}

/// Name of the tool-indentation scenario in `demo --scenarios`.
pub const INDENTATION_SCENARIO: &str = "tool-indentation";

/// The registered surface coloured by error beside the truth, `DIR/surface_view.{png,svg}`.
fn write_view(
    dir: &Path,
    name: &str,
    registered: &TriSurface,
    error_mm: &[f64],
    truth: &TriSurface,
    view: nalgebra::Vector3<f64>,
) -> Result<(), String> {
    let mut sorted = error_mm.to_vec();
    sorted.sort_by(f64::total_cmp);
    let scale_mm = crate::evaluation::percentile(&sorted, 0.99).max(1.0);
    write_surface_view(
        &SurfaceView {
            registered,
            error_mm,
            truth,
            view,
            scale_mm,
        },
        &format!("{name}: last frame"),
        Some(&dir.join("surface_view.png")),
        Some(&dir.join("surface_view.svg")),
    )
}

/// The tool-indentation class in the demo: each sequence of the bundled
/// tet-FE truth (linear law), clouds without a camera pose, registered with the fixture's
/// scene (every default) and rigidly only (rigid ICP tracking); the per-frame chart and the
/// deepest frame's view go to `DIR/tool-indentation/<sequence>/`.
fn run_indentation_demo(out: &Path, vtk: Option<&Path>) -> Result<Vec<ScenarioSummary>, String> {
    use crate::benchmark::indentation::{
        indentation_cases, indentation_metrics, indentation_workload, scene_for, IndentationVariant,
    };
    use crate::benchmark::run::sample_of;
    use crate::benchmark::run_workload;
    use crate::evaluation::Summary;
    use crate::synthetic::indentation::{bundled_fixture_dir, INDENTATION_SEQUENCES};
    let fixture = bundled_fixture_dir();
    let scene = load_scene(&fixture.join("scene.toml")).map_err(|e| e.to_string())?;
    let scale = scene.length_scale();
    let cases = indentation_cases(
        &fixture,
        &INDENTATION_SEQUENCES,
        &["linear"],
        &[IndentationVariant::NoCamera],
        None,
    )?;
    let mut rows = Vec::new();
    for case in &cases {
        let name = format!("{INDENTATION_SCENARIO}/{}", case.truth.sequence);
        eprintln!("{name}: registering {} frames…", case.frames.len());
        let dir = out.join(&name);
        std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        let workload = indentation_workload(&case.truth, &case.frames, scale, false);
        let deepest = (0..case.truth.len())
            .max_by(|&a, &b| {
                case.truth.frames[a]
                    .depth
                    .total_cmp(&case.truth.frames[b].depth)
            })
            .unwrap_or(0);
        let mut rigid =
            crate::session::Session::from_scene(&scene_for(&scene, IndentationVariant::RigidIcp))
                .map_err(|e| e.to_string())?;
        rigid.settings.non_rigid = false;
        let rigid_samples = run_workload(&mut rigid, &workload, scale);
        // The full pipeline frame by frame, keeping the deepest frame's registered surface.
        let mut full = crate::session::Session::from_scene(&scene_for(&scene, case.variant))
            .map_err(|e| e.to_string())?;
        let mut vtk_series = match vtk {
            Some(v) => Some(VtkSeriesWriter::create(&v.join(&name), &full)?),
            None => None,
        };
        let mut samples = Vec::new();
        let mut deepest_surface = Vec::new();
        for (k, (frame, truth)) in workload.frames.iter().zip(&workload.truth).enumerate() {
            let r = full.register(frame);
            if let Some(v) = vtk_series.as_mut() {
                v.write_frame(k, &r)?;
            }
            samples.push(sample_of(&r, truth, scale));
            if k == deepest {
                deepest_surface = r.surface;
            }
        }
        let offset = case
            .variant
            .offset()
            .unwrap_or_else(RigidTransform::identity);
        let grade = |s| indentation_metrics(&name, &case.truth, &case.frames, &offset, s);
        let (m, m_rigid) = (grade(&samples), grade(&rigid_samples));
        let per_frame = |m: &IndentationMetrics,
                         f: fn(&IndentationFrameMetrics) -> f64|
         -> Vec<f64> { m.frames.iter().map(f).collect() };
        write_per_frame_chart(
            &with_expected_error(
                none_rigid_non_rigid(
                    per_frame(&m, |f| f.none_mean_mm),
                    per_frame(&m_rigid, |f| f.mean_mm),
                    per_frame(&m, |f| f.mean_mm),
                ),
                m.frames.iter().map(|f| f.expected_error_mm).collect(),
            ),
            &format!("{name}: mean node error per frame (tet-FE truth, linear)"),
            Some(&dir.join("error_per_frame.png")),
            Some(&dir.join("error_per_frame.svg")),
        )?;
        // The view of the deepest frame (surface vertex i is truth node i).
        let registered = TriSurface::new(deepest_surface, case.truth.surface.triangles.clone());
        let mut truth = case.truth.deformed_surface(deepest);
        truth.scale(1.0 / scale);
        let error = &samples[deepest].tre_mm[..case.truth.surface.vertices.len()];
        write_view(
            &dir,
            &name,
            &registered,
            error,
            &truth,
            case.truth.frames[deepest].tool_direction,
        )?;
        let times: Vec<f64> = samples.iter().map(|s| s.wall_ms).collect();
        let (ms_p50, ms_p95) = Summary::of(&times).map_or((0.0, 0.0), |t| (t.median, t.p95));
        rows.push(ScenarioSummary {
            scenario: name,
            frames: case.frames.len(),
            max_displacement_mm: workload.max_displacement_mm.unwrap_or(0.0),
            tre_none_mm: m.none_mean_mm,
            tre_rigid_mm: m_rigid.mean_mm,
            tre_non_rigid_mm: m.mean_mm,
            tre_non_rigid_p95_mm: m.p95_mm,
            ms_p50,
            ms_p95,
            failed: m.failed_frames,
            truth_ms: 0.0,
        });
    }
    Ok(rows)
}

/// The demo's table: one row per scenario, TRE in mm and ms per frame.
pub fn table(rows: &[ScenarioSummary]) -> String {
    let mut s = format!(
        "{:<18} {:>7} {:>9} {:>10} {:>10} {:>12} {:>9} {:>9} {:>7}\n",
        "scenario",
        "frames",
        "max disp",
        "TRE none",
        "TRE rigid",
        "TRE nonrigid",
        "ms p50",
        "ms p95",
        "failed"
    );
    for r in rows {
        s.push_str(&format!(
            "{:<18} {:>7} {:>6.1} mm {:>7.2} mm {:>7.2} mm {:>9.2} mm {:>9.1} {:>9.1} {:>7}\n",
            r.scenario,
            r.frames,
            r.max_displacement_mm,
            r.tre_none_mm,
            r.tre_rigid_mm,
            r.tre_non_rigid_mm,
            r.ms_p50,
            r.ms_p95,
            r.failed
        ));
    }
    // One mean line per scenario class: the phantom's target TRE and the tool-indentation
    // class's node error are different measures on different livers.
    let (indentation, phantom): (Vec<&ScenarioSummary>, Vec<&ScenarioSummary>) = rows
        .iter()
        .partition(|r| r.scenario.starts_with(INDENTATION_SCENARIO));
    for (label, class) in [
        ("mean TRE", phantom),
        ("tool-indentation mean node error", indentation),
    ] {
        if class.is_empty() {
            continue;
        }
        let n = class.len() as f64;
        let mean = |f: fn(&ScenarioSummary) -> f64| class.iter().map(|r| f(r)).sum::<f64>() / n;
        let (rigid, full) = (mean(|r| r.tre_rigid_mm), mean(|r| r.tre_non_rigid_mm));
        s.push_str(&format!(
            "{label}: rigid {rigid:.2} mm, non-rigid {full:.2} mm ({:.0} % of rigid)\n",
            100.0 * full / rigid
        ));
    }
    s
}

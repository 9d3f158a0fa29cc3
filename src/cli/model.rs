//! `livereg model SEGMENTATION --label LIVER [--mesh NAME=LABEL]… [--points NAME=LABEL]…
//! --out DIR`: the patient model straight from a segmentation labelmap (NIfTI or NRRD, as 3D
//! Slicer, ITK-SNAP or an AI contouring tool writes it): the organ's closed surface, tumours as
//! closed meshes, vessels as points, all in LPS millimetres, with a scene file naming them.
//! Prints a JSON summary on stdout.

use std::collections::HashSet;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::mesh::vtk::VtkPolyData;
use crate::mesh::{write_obj, write_points, write_vtk, TriSurface};
use crate::segmentation::{
    default_request, derive_model_from, read_labelmap, DerivedModel, LabelRef, ModelRequest,
    SurfaceOptions,
};

/// Surface file format of `model`'s output.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ModelFormat {
    /// Wavefront OBJ.
    Obj,
    /// VTK XML PolyData (ParaView, 3D Slicer).
    Vtp,
    /// Legacy VTK.
    Vtk,
}

impl ModelFormat {
    fn extension(self) -> &'static str {
        match self {
            ModelFormat::Obj => "obj",
            ModelFormat::Vtp => "vtp",
            ModelFormat::Vtk => "vtk",
        }
    }
}

/// Arguments of `model`.
#[derive(Debug, Clone, clap::Args)]
pub struct ModelArgs {
    /// The labelmap: `.nii`, `.nii.gz`, `.nrrd` or `.seg.nrrd` (docs/segmentation.md).
    pub segmentation: PathBuf,
    /// The organ: a label value or a segment name (repeat to unite several labels). Without
    /// it (and without --mesh / --points) the model is read off the labelmap: the segment
    /// named like "liver" (else the only label, else label 1) is the organ, every other label
    /// a structure — points when its name says vessel, vein, artery, portal, hepatic or cava,
    /// a closed mesh otherwise.
    #[arg(long)]
    pub label: Vec<String>,
    /// A structure as a closed mesh, e.g. `--mesh tumour=2` or `--mesh "tumour=Tumor 1"`
    /// (repeatable; labels separated by `+` are united).
    #[arg(long = "mesh", value_name = "NAME=LABEL")]
    pub meshes: Vec<String>,
    /// A structure as points (the centres of its voxels), e.g. `--points vessels=3`.
    #[arg(long = "points", value_name = "NAME=LABEL")]
    pub points: Vec<String>,
    /// Triangles of the organ surface after decimation (0: keep every marching-cubes
    /// triangle).
    #[arg(long, default_value_t = 20_000)]
    pub target_triangles: usize,
    /// Taubin λ|μ smoothing pairs applied to the organ surface before decimation (0: no
    /// smoothing; docs/segmentation.md, "Options").
    #[arg(long, default_value_t = crate::segmentation::Taubin::default().iterations)]
    pub smoothing: usize,
    /// Most points per point structure.
    #[arg(long, default_value_t = crate::segmentation::DEFAULT_MAX_POINTS)]
    pub max_points: usize,
    /// Surface file format.
    #[arg(long, value_enum, default_value = "obj")]
    pub format: ModelFormat,
    /// Output directory (created).
    #[arg(long, default_value = "model-out")]
    pub out: PathBuf,
}

/// What `model` wrote (printed as JSON).
#[derive(Debug, Clone, Serialize)]
pub struct ModelSummary {
    /// The organ surface file.
    pub surface: PathBuf,
    /// Its vertices and triangles.
    pub vertices: usize,
    /// Triangles.
    pub triangles: usize,
    /// Enclosed volume, millilitres.
    pub volume_ml: f64,
    /// Closed, manifold and consistently oriented.
    pub watertight: bool,
    /// Structure name → file.
    pub structures: Vec<(String, PathBuf)>,
    /// The scene file written.
    pub scene: PathBuf,
    /// Labelmap dimensions.
    pub dims: [usize; 3],
    /// Reading the labelmap, ms.
    pub read_ms: f64,
    /// Extracting, smoothing and decimating, ms.
    pub derive_ms: f64,
}

/// `NAME=LABEL[+LABEL…]` as a name and labels.
pub fn named_labels(flag: &str, s: &str) -> Result<(String, Vec<LabelRef>), String> {
    let (name, labels) = s
        .split_once('=')
        .ok_or_else(|| format!("{flag} {s:?}: expected NAME=LABEL"))?;
    let name = name.trim();
    if name.is_empty() {
        return Err(format!("{flag} {s:?}: the name is empty"));
    }
    let labels: Vec<LabelRef> = labels
        .split('+')
        .map(str::trim)
        .filter(|l| !l.is_empty())
        .map(LabelRef::from)
        .collect();
    if labels.is_empty() {
        return Err(format!("{flag} {s:?}: no label after '='"));
    }
    Ok((name.to_string(), labels))
}

/// Runs the command.
pub fn run(args: &ModelArgs) -> Result<ModelSummary, String> {
    let t0 = std::time::Instant::now();
    let map = read_labelmap(&args.segmentation).map_err(|e| e.to_string())?;
    let read_ms = t0.elapsed().as_secs_f64() * 1e3;
    let mut request = if args.label.is_empty() {
        if !args.meshes.is_empty() || !args.points.is_empty() {
            return Err("--mesh and --points need the organ's --label".into());
        }
        default_request(&map, &args.segmentation).map_err(|e| e.to_string())?
    } else {
        explicit_request(args)?
    };
    request.organ_options.target_triangles = args.target_triangles;
    request.organ_options.taubin.iterations = args.smoothing;
    request.organ_options.smooth = args.smoothing > 0;
    request.max_points = args.max_points.max(1);
    let model = derive_model_from(&map, &args.segmentation, &request, read_ms)
        .map_err(|e| e.to_string())?;
    drop(map);
    write_model(args, &model)
}

/// The request the flags name.
fn explicit_request(args: &ModelArgs) -> Result<ModelRequest, String> {
    Ok(ModelRequest {
        organ: args
            .label
            .iter()
            .map(|l| LabelRef::from(l.as_str()))
            .collect(),
        meshes: args
            .meshes
            .iter()
            .map(|m| named_labels("--mesh", m))
            .collect::<Result<_, _>>()?,
        points: args
            .points
            .iter()
            .map(|m| named_labels("--points", m))
            .collect::<Result<_, _>>()?,
        organ_options: SurfaceOptions {
            target_triangles: args.target_triangles,
            ..SurfaceOptions::default()
        },
        max_points: args.max_points.max(1),
    })
}

/// Writes `model` into `args.out` with its scene; the summary, also printed.
fn write_model(args: &ModelArgs, model: &DerivedModel) -> Result<ModelSummary, String> {
    std::fs::create_dir_all(&args.out)
        .map_err(|e| format!("{}: cannot create: {e}", args.out.display()))?;
    let ext = args.format.extension();
    let mut taken = HashSet::new();
    let mut stem = |name: &str| super::vtk_series::unique_stem(name, &mut taken);
    let surface_name = format!("{}.{ext}", stem("liver"));
    write_surface(&args.out.join(&surface_name), &model.surface, args.format)?;
    let mut structures = Vec::new();
    let mut scene = format!(
        "# Derived by `livereg model` from {} (LPS millimetres).\n\
         # Add the boundary conditions ([[boundary.fixed]]: ligaments, vena cava) and the\n\
         # camera of your setup before registering (docs/scene.md).\nunits = \"mm\"\n\n\
         [model]\nsurface = \"{surface_name}\"\n",
        args.segmentation
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default()
    );
    for (name, mesh) in &model.meshes {
        let file = format!("{}.{ext}", stem(name));
        write_surface(&args.out.join(&file), mesh, args.format)?;
        let _ = write!(
            scene,
            "\n[[model.structures]]\nname = {name:?}\nmesh = \"{file}\"\n"
        );
        structures.push((name.clone(), args.out.join(file)));
    }
    for (name, points) in &model.points {
        let file = format!("{}.xyz", stem(name));
        let path = args.out.join(&file);
        write_points(&path, points).map_err(|e| e.to_string())?;
        let _ = write!(
            scene,
            "\n[[model.structures]]\nname = {name:?}\npoints = \"{file}\"\n"
        );
        structures.push((name.clone(), path));
    }
    scene.push_str(
        "\n[material]\nlaw = \"neo-hookean\"\nyoung_modulus = 4500.0\npoisson_ratio = 0.45\n\n\
         [registration]\nrigid = \"icp\"\n",
    );
    let scene_path = args.out.join("scene.toml");
    std::fs::write(&scene_path, scene)
        .map_err(|e| format!("{}: cannot write: {e}", scene_path.display()))?;
    let summary = ModelSummary {
        surface: args.out.join(surface_name),
        vertices: model.surface.vertices.len(),
        triangles: model.surface.triangles.len(),
        volume_ml: model.report.signed_volume * 1e-3,
        watertight: model.report.watertight,
        structures,
        scene: scene_path,
        dims: model.dims,
        read_ms: model.read_ms,
        derive_ms: model.derive_ms,
    };
    println!(
        "{}",
        serde_json::to_string(&summary).map_err(|e| e.to_string())?
    );
    Ok(summary)
}

/// Writes `s` to `path` in `format`.
fn write_surface(path: &Path, s: &TriSurface, format: ModelFormat) -> Result<(), String> {
    match format {
        ModelFormat::Obj => write_obj(path, s),
        ModelFormat::Vtp | ModelFormat::Vtk => write_vtk(
            path,
            &VtkPolyData {
                points: &s.vertices,
                triangles: &s.triangles,
                arrays: &[],
            },
        ),
    }
    .map_err(|e| e.to_string())
}

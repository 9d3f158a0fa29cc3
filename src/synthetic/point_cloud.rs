//! Synthetic intra-operative point clouds: area-uniform samples of a surface, restricted to
//! what a [`Camera`] sees (optionally to a smaller connected patch), with Gaussian noise,
//! uniform outliers and an unknown rigid camera-to-model offset. Lengths in metres.

use nalgebra::{Matrix3, Point3, Rotation3, Vector3};

use super::error::SynthError;
use crate::geometry::visibility::{check_surface, VisibleSurface};
use crate::geometry::Camera;
use crate::mesh::TriSurface;
use crate::random::Rng;

/// Square metres per square centimetre.
const M2_PER_CM2: f64 = 1e-4;
/// Margin by which the outlier box exceeds the visible part on every side, metres (3 cm).
pub const OUTLIER_MARGIN: f64 = 0.03;
/// Largest number of surface samples [`synthesize_cloud`] will draw (guards against a surface
/// in millimetres being taken for metres).
pub const MAX_SAMPLES: usize = 10_000_000;

/// What cloud to synthesize. `CloudSpec::default()` gives 1 sample/cm², no noise, no
/// outliers, the whole visible part, no offset, seed 0.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CloudSpec {
    /// Surface samples per cm² of surface area (default 1.0); the cloud holds about
    /// `density_per_cm2 × visible area in cm²` inliers.
    pub density_per_cm2: f64,
    /// Standard deviation of the isotropic Gaussian noise added to each inlier, metres, per
    /// axis (so also along the surface normal); default 0.
    pub noise_sigma: f64,
    /// Share of the final cloud that is outliers, in `[0, 1)`; outliers are uniform in the
    /// bounding box of the (noise-free) kept surface samples grown by [`OUTLIER_MARGIN`].
    pub outlier_fraction: f64,
    /// If set, in `(0, 1]`: keep only a connected-ish patch of the visible samples — those
    /// nearest (Euclidean) to the visible sample closest to the optical axis — whose area is
    /// this fraction of the WHOLE surface area. Asking for more than is visible is an error.
    pub visible_fraction: Option<f64>,
    /// Rigid transform `p ↦ R p + t` (t in metres) applied to every point last, to simulate
    /// an unknown camera-to-model transform.
    pub rigid_offset: Option<(Rotation3<f64>, Vector3<f64>)>,
    /// Seed of the random stream; the cloud is a deterministic function of all inputs.
    pub seed: u64,
}

impl Default for CloudSpec {
    fn default() -> Self {
        Self {
            density_per_cm2: 1.0,
            noise_sigma: 0.0,
            outlier_fraction: 0.0,
            visible_fraction: None,
            rigid_offset: None,
            seed: 0,
        }
    }
}

impl CloudSpec {
    /// Checks every parameter's range (finite positive density, finite non-negative noise,
    /// outlier fraction in `[0, 1)`, visible fraction in `(0, 1]`, a proper finite rotation
    /// and finite translation).
    pub fn validate(&self) -> Result<(), SynthError> {
        let bad = |m: String| Err(SynthError::InvalidSpec(m));
        if !(self.density_per_cm2.is_finite() && self.density_per_cm2 > 0.0) {
            return bad(format!(
                "density_per_cm2 {} must be finite and > 0",
                self.density_per_cm2
            ));
        }
        if !(self.noise_sigma.is_finite() && self.noise_sigma >= 0.0) {
            return bad(format!(
                "noise_sigma {} m must be finite and >= 0",
                self.noise_sigma
            ));
        }
        if !(0.0..1.0).contains(&self.outlier_fraction) {
            return bad(format!(
                "outlier_fraction {} is outside [0, 1)",
                self.outlier_fraction
            ));
        }
        if let Some(f) = self.visible_fraction {
            if !(f > 0.0 && f <= 1.0) {
                return bad(format!("visible_fraction {f} is outside (0, 1]"));
            }
        }
        if let Some((r, t)) = &self.rigid_offset {
            let m = r.matrix();
            let finite = m.iter().chain(t.iter()).all(|v| v.is_finite());
            let orthonormal = (m.transpose() * m - Matrix3::identity()).norm() < 1e-9
                && (m.determinant() - 1.0).abs() < 1e-9;
            if !finite || !orthonormal {
                return bad(format!(
                    "rigid_offset must be a finite proper rotation and translation \
                     (rotation {:?}, translation {:?})",
                    m.as_slice(),
                    t.as_slice()
                ));
            }
        }
        Ok(())
    }

    /// Samples per square metre.
    pub fn density_per_m2(&self) -> f64 {
        self.density_per_cm2 / M2_PER_CM2
    }
}

/// A synthesized cloud with its ground truth. The three vectors are parallel.
#[derive(Debug, Clone, PartialEq)]
pub struct SyntheticCloud {
    /// The points, metres, in random order, after noise and the rigid offset.
    pub points: Vec<Point3<f64>>,
    /// Whether each point is an outlier.
    pub is_outlier: Vec<bool>,
    /// The surface triangle each inlier was sampled on (`None` for outliers).
    pub source_triangle: Vec<Option<usize>>,
    /// Area of the surface the camera sees, m², estimated as visible samples / density
    /// (before the patch restriction).
    pub visible_area: f64,
    /// Area the inliers represent, m² (inliers / density): the patch area when
    /// `visible_fraction` is set, otherwise equal to `visible_area`.
    pub patch_area: f64,
    /// Total area of the surface, m² (exact sum of triangle areas).
    pub surface_area: f64,
}

impl SyntheticCloud {
    /// Number of outliers.
    pub fn outlier_count(&self) -> usize {
        self.is_outlier.iter().filter(|&&o| o).count()
    }

    /// Number of inliers (surface samples).
    pub fn inlier_count(&self) -> usize {
        self.points.len() - self.outlier_count()
    }

    /// The inliers (noisy surface samples), in cloud order.
    pub fn inliers(&self) -> Vec<Point3<f64>> {
        inliers_of(&self.points, &self.is_outlier)
    }
}

/// The points of `points` not flagged in `is_outlier` (parallel to it), in order.
pub(crate) fn inliers_of(points: &[Point3<f64>], is_outlier: &[bool]) -> Vec<Point3<f64>> {
    points
        .iter()
        .zip(is_outlier)
        .filter(|(_, &o)| !o)
        .map(|(p, _)| *p)
        .collect()
}

/// Uniform sample of triangle `[a, b, c]` from two uniforms in `[0, 1)`.
fn sample_triangle([a, b, c]: [Point3<f64>; 3], r1: f64, r2: f64) -> Point3<f64> {
    let s = r1.sqrt();
    Point3::from(a.coords * (1.0 - s) + b.coords * (s * (1.0 - r2)) + c.coords * (s * r2))
}

/// Area-uniform samples of `surface` at `density_per_m2`, with their triangles.
///
/// Counts are systematic (stratified) rather than Poisson: with one random offset `u`, triangle
/// `t` gets `⌊C_t + u⌋ − ⌊C_{t−1} + u⌋` samples, `C_t` being the cumulative expected count, so
/// each count is `⌊λ_t⌋` or `⌈λ_t⌉` with mean `λ_t` and the total is within 1 of
/// `density × area` — far less variance than Poisson for the same mean.
fn sample_surface(
    surface: &TriSurface,
    areas: &[f64],
    density_per_m2: f64,
    rng: &mut Rng,
) -> (Vec<Point3<f64>>, Vec<usize>) {
    let u0 = rng.uniform();
    let mut cumulative = 0.0;
    let mut issued = 0u64;
    let mut points = Vec::new();
    let mut tris = Vec::new();
    for (t, &area) in areas.iter().enumerate() {
        cumulative += area * density_per_m2;
        let upto = (cumulative + u0).floor() as u64;
        let n = upto.saturating_sub(issued);
        issued = issued.max(upto);
        let corners = surface.corners(t);
        for _ in 0..n {
            let (r1, r2) = (rng.uniform(), rng.uniform());
            points.push(sample_triangle(corners, r1, r2));
            tris.push(t);
        }
    }
    (points, tris)
}

/// Indices (into `points`) of the `k` points nearest to the point closest to the camera's
/// optical axis, in increasing index order.
fn nearest_patch(camera: &Camera, points: &[Point3<f64>], k: usize) -> Vec<usize> {
    let axis = camera.view_direction();
    let off_axis = |p: &Point3<f64>| {
        let d = p - camera.position;
        let along = d.dot(&axis);
        ((d - axis.into_inner() * along).norm_squared(), along)
    };
    let seed = (0..points.len())
        .min_by(|&i, &j| {
            let (a, b) = (off_axis(&points[i]), off_axis(&points[j]));
            a.0.total_cmp(&b.0)
                .then(a.1.total_cmp(&b.1))
                .then(i.cmp(&j))
        })
        .expect("at least one point");
    let centre = points[seed];
    let mut order: Vec<(f64, usize)> = points
        .iter()
        .enumerate()
        .map(|(i, p)| ((p - centre).norm_squared(), i))
        .collect();
    order.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    let mut keep: Vec<usize> = order[..k].iter().map(|&(_, i)| i).collect();
    keep.sort_unstable();
    keep
}

/// Synthesizes the partial, noisy cloud that `camera` would capture of `surface` (metres).
///
/// Steps, all driven by one random stream seeded with `spec.seed` (so the result is
/// deterministic and independent of the number of threads):
/// 1. sample the surface uniformly by area at `spec.density_per_cm2` (see the stratified
///    counts in the module source);
/// 2. keep the samples visible from the camera ([`VisibleSurface::visible`]);
/// 3. if `spec.visible_fraction` is set, keep the patch of visible samples nearest to the
///    one closest to the optical axis, sized to that fraction of the whole surface area;
/// 4. add isotropic Gaussian noise of deviation `spec.noise_sigma` per axis;
/// 5. add `round(f · n / (1 − f))` outliers (f = `outlier_fraction`, n inliers), uniform in
///    the kept samples' bounding box grown by 3 cm, and shuffle the cloud;
/// 6. apply `spec.rigid_offset`.
///
/// Errors: empty or invalid surface, invalid camera or spec, more than [`MAX_SAMPLES`]
/// samples, nothing visible, or a patch larger than the visible area.
pub fn synthesize_cloud(
    surface: &TriSurface,
    camera: &Camera,
    spec: &CloudSpec,
) -> Result<SyntheticCloud, SynthError> {
    check_surface(surface)?;
    camera.validate()?;
    spec.validate()?;

    let areas: Vec<f64> = (0..surface.triangles.len())
        .map(|t| surface.triangle_area(t))
        .collect();
    let surface_area: f64 = areas.iter().sum();
    let density = spec.density_per_m2();
    let expected = surface_area * density;
    if !expected.is_finite() || expected > MAX_SAMPLES as f64 {
        return Err(SynthError::InvalidSpec(format!(
            "{} samples/cm² over {:.4} m² of surface would draw {expected:.3e} samples \
             (more than {MAX_SAMPLES}); is the surface in metres?",
            spec.density_per_cm2, surface_area
        )));
    }

    let mut rng = Rng::new(spec.seed);
    let (samples, sample_tris) = sample_surface(surface, &areas, density, &mut rng);
    let visible_surface = VisibleSurface::new(surface)?;
    let visible = visible_surface.visible(camera, &samples);
    let (mut kept, mut kept_tris): (Vec<Point3<f64>>, Vec<usize>) = samples
        .iter()
        .zip(&sample_tris)
        .zip(&visible)
        .filter(|(_, &v)| v)
        .map(|((p, &t), _)| (*p, t))
        .unzip();
    if kept.is_empty() {
        return Err(SynthError::NothingVisible {
            samples: samples.len(),
            camera: format!("{:?}", camera.position.coords.as_slice()),
            look_at: format!("{:?}", camera.look_at.coords.as_slice()),
        });
    }
    let visible_area = kept.len() as f64 / density;

    if let Some(fraction) = spec.visible_fraction {
        let requested_area = fraction * surface_area;
        let k = (requested_area * density).round() as usize;
        if k > kept.len() {
            return Err(SynthError::PatchTooLarge {
                requested: fraction,
                requested_area_cm2: requested_area / M2_PER_CM2,
                visible_area_cm2: visible_area / M2_PER_CM2,
                visible_fraction: visible_area / surface_area,
            });
        }
        let k = k.max(1);
        let keep = nearest_patch(camera, &kept, k);
        kept = keep.iter().map(|&i| kept[i]).collect();
        kept_tris = keep.iter().map(|&i| kept_tris[i]).collect();
    }
    let patch_area = kept.len() as f64 / density;

    // Outlier box from the noise-free kept samples.
    let (lo, hi) = kept
        .iter()
        .fold((kept[0], kept[0]), |(lo, hi), p| (lo.inf(p), hi.sup(p)));
    let margin = Vector3::repeat(OUTLIER_MARGIN);
    let (lo, hi) = (lo - margin, hi + margin);

    let inliers = kept.len();
    let mut entries: Vec<(Point3<f64>, Option<usize>)> = kept
        .into_iter()
        .zip(kept_tris)
        .map(|(p, t)| {
            let p = if spec.noise_sigma > 0.0 {
                p + rng.gaussian_vector(spec.noise_sigma)
            } else {
                p
            };
            (p, Some(t))
        })
        .collect();

    let f = spec.outlier_fraction;
    let outliers = (f * inliers as f64 / (1.0 - f)).round() as usize;
    for _ in 0..outliers {
        let p = Point3::new(
            rng.uniform_in(lo.x, hi.x),
            rng.uniform_in(lo.y, hi.y),
            rng.uniform_in(lo.z, hi.z),
        );
        entries.push((p, None));
    }
    rng.shuffle(&mut entries);

    if let Some((r, t)) = &spec.rigid_offset {
        for (p, _) in &mut entries {
            *p = r * *p + t;
        }
    }

    let points = entries.iter().map(|e| e.0).collect();
    let source_triangle: Vec<Option<usize>> = entries.iter().map(|e| e.1).collect();
    let is_outlier = source_triangle.iter().map(|t| t.is_none()).collect();
    Ok(SyntheticCloud {
        points,
        is_outlier,
        source_triangle,
        visible_area,
        patch_area,
        surface_area,
    })
}

//! Proper rigid motions `x ↦ R x + t` (rotation, then translation), in metres and radians.

use nalgebra::{Matrix3, Matrix4, Point3, Rotation3, Vector3};
use serde::{Deserialize, Serialize};

/// How far (max-abs entry of `RᵀR − I`, and `|det R − 1|`) a matrix may be from a rotation to
/// be accepted by [`RigidTransform::from_matrix4`] or deserialisation; it is then re-projected
/// onto the nearest rotation. Generous enough for matrices printed with ~7 significant digits.
pub const ROTATION_TOLERANCE: f64 = 1e-5;

/// A proper rigid motion `x ↦ rotation · x + translation` (no reflection, no scale).
///
/// Lengths are in metres, angles in radians. Serialises as
/// `{"rotation": [[r00, r01, r02], [r10, r11, r12], [r20, r21, r22]], "translation": [tx, ty, tz]}`
/// with the rotation matrix row-major (the `results.jsonl` contract's shape); deserialisation
/// rejects non-finite values and matrices that are not rotations (see [`ROTATION_TOLERANCE`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(into = "TransformRepr", try_from = "TransformRepr")]
pub struct RigidTransform {
    /// The rotation `R` (applied first).
    pub rotation: Rotation3<f64>,
    /// The translation `t`, metres (applied after the rotation).
    pub translation: Vector3<f64>,
}

impl Default for RigidTransform {
    fn default() -> Self {
        Self::identity()
    }
}

impl RigidTransform {
    /// The transform from a rotation and a translation (metres).
    pub fn new(rotation: Rotation3<f64>, translation: Vector3<f64>) -> Self {
        Self {
            rotation,
            translation,
        }
    }

    /// The identity motion.
    pub fn identity() -> Self {
        Self::new(Rotation3::identity(), Vector3::zeros())
    }

    /// A pure translation (metres).
    pub fn from_translation(translation: Vector3<f64>) -> Self {
        Self::new(Rotation3::identity(), translation)
    }

    /// The image `R p + t` of a point.
    pub fn apply(&self, p: &Point3<f64>) -> Point3<f64> {
        self.rotation * p + self.translation
    }

    /// The image `R v` of a direction (translation ignored).
    pub fn apply_vector(&self, v: &Vector3<f64>) -> Vector3<f64> {
        self.rotation * v
    }

    /// The images of many points.
    pub fn apply_all(&self, points: &[Point3<f64>]) -> Vec<Point3<f64>> {
        points.iter().map(|p| self.apply(p)).collect()
    }

    /// `self ∘ other`: the motion applying `other` first, then `self`
    /// (`x ↦ self.apply(other.apply(x))`), like the matrix product `self · other`.
    pub fn compose(&self, other: &RigidTransform) -> RigidTransform {
        RigidTransform::new(
            self.rotation * other.rotation,
            self.rotation * other.translation + self.translation,
        )
    }

    /// The inverse motion `x ↦ Rᵀ (x − t)`.
    pub fn inverse(&self) -> RigidTransform {
        let r_inv = self.rotation.inverse();
        RigidTransform::new(r_inv, -(r_inv * self.translation))
    }

    /// The homogeneous 4×4 matrix `[R t; 0 1]`.
    pub fn to_matrix4(&self) -> Matrix4<f64> {
        let mut m = Matrix4::identity();
        m.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(self.rotation.matrix());
        m.fixed_view_mut::<3, 1>(0, 3).copy_from(&self.translation);
        m
    }

    /// The motion of a homogeneous 4×4 matrix `[R t; 0 1]`; `None` unless every entry is finite,
    /// the last row is `[0 0 0 1]` and `R` is a rotation within [`ROTATION_TOLERANCE`] (it is then
    /// re-projected onto the nearest rotation).
    pub fn from_matrix4(m: &Matrix4<f64>) -> Option<RigidTransform> {
        if m.iter().any(|x| !x.is_finite()) {
            return None;
        }
        let last = m.fixed_view::<1, 4>(3, 0);
        if (last[0].abs().max(last[1].abs()).max(last[2].abs())) > ROTATION_TOLERANCE
            || (last[3] - 1.0).abs() > ROTATION_TOLERANCE
        {
            return None;
        }
        let r: Matrix3<f64> = m.fixed_view::<3, 3>(0, 0).into_owned();
        let t: Vector3<f64> = m.fixed_view::<3, 1>(0, 3).into_owned();
        Some(RigidTransform::new(checked_rotation(&r)?, t))
    }

    /// The angle of the rotation, radians in `[0, π]`.
    pub fn rotation_angle(&self) -> f64 {
        rotation_angle(&self.rotation)
    }

    /// The length of the translation, metres.
    pub fn translation_norm(&self) -> f64 {
        self.translation.norm()
    }

    /// The angle of the relative rotation `selfᵀ · other.rotation`, radians in `[0, π]`: how
    /// far apart the two orientations are.
    pub fn rotation_angle_to(&self, other: &RigidTransform) -> f64 {
        rotation_angle(&(self.rotation.inverse() * other.rotation))
    }

    /// The distance between the two translations, metres.
    pub fn translation_distance_to(&self, other: &RigidTransform) -> f64 {
        (self.translation - other.translation).norm()
    }

    /// `true` when every entry is finite.
    pub fn is_finite(&self) -> bool {
        self.rotation.matrix().iter().all(|x| x.is_finite())
            && self.translation.iter().all(|x| x.is_finite())
    }

    /// Re-projects the rotation onto SO(3) (removes round-off drift after many compositions).
    pub fn renormalized(mut self) -> RigidTransform {
        self.rotation.renormalize();
        self
    }
}

/// The angle of a rotation, radians in `[0, π]`, accurate near 0 (unlike `acos` of the trace,
/// which loses half the digits there): `atan2(|vee(R − Rᵀ)| / 2, (tr R − 1) / 2)`.
fn rotation_angle(r: &Rotation3<f64>) -> f64 {
    let m = r.matrix();
    let s = Vector3::new(
        m[(2, 1)] - m[(1, 2)],
        m[(0, 2)] - m[(2, 0)],
        m[(1, 0)] - m[(0, 1)],
    )
    .norm()
        / 2.0;
    let c = (m.trace() - 1.0) / 2.0;
    s.atan2(c)
}

/// `r` re-projected onto the nearest rotation if it is one within [`ROTATION_TOLERANCE`].
fn checked_rotation(r: &Matrix3<f64>) -> Option<Rotation3<f64>> {
    let orth = (r.transpose() * r - Matrix3::identity()).amax();
    let det_error = (r.determinant() - 1.0).abs();
    if orth.is_nan()
        || orth > ROTATION_TOLERANCE
        || det_error.is_nan()
        || det_error > ROTATION_TOLERANCE
    {
        return None;
    }
    let mut rot = Rotation3::from_matrix_unchecked(*r);
    rot.renormalize();
    Some(rot)
}

/// Serde shape of [`RigidTransform`]: row-major rotation rows and the translation.
#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct TransformRepr {
    rotation: [[f64; 3]; 3],
    translation: [f64; 3],
}

impl From<RigidTransform> for TransformRepr {
    fn from(t: RigidTransform) -> Self {
        let m = t.rotation.matrix();
        TransformRepr {
            rotation: [0, 1, 2].map(|i| [m[(i, 0)], m[(i, 1)], m[(i, 2)]]),
            translation: [t.translation.x, t.translation.y, t.translation.z],
        }
    }
}

impl TryFrom<TransformRepr> for RigidTransform {
    type Error = String;

    fn try_from(r: TransformRepr) -> Result<Self, String> {
        let values = r.rotation.iter().flatten().chain(r.translation.iter());
        if values.clone().any(|x| !x.is_finite()) {
            return Err("rigid transform has a non-finite entry".into());
        }
        let rows = r.rotation;
        let m = Matrix3::from_fn(|i, j| rows[i][j]);
        let rotation = checked_rotation(&m).ok_or_else(|| {
            format!(
                "rigid transform 'rotation' is not a rotation matrix (RᵀR = I and det R = 1 \
                 within {ROTATION_TOLERANCE}): {rows:?}"
            )
        })?;
        Ok(RigidTransform::new(rotation, Vector3::from(r.translation)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Unit;

    fn sample() -> RigidTransform {
        RigidTransform::new(
            Rotation3::from_axis_angle(&Unit::new_normalize(Vector3::new(1.0, -2.0, 0.5)), 0.7),
            Vector3::new(0.01, -0.02, 0.03),
        )
    }

    #[test]
    fn compose_inverse_and_matrix_agree() {
        let a = sample();
        let b = RigidTransform::new(
            Rotation3::from_axis_angle(&Vector3::y_axis(), -0.3),
            Vector3::new(-0.05, 0.0, 0.02),
        );
        let p = Point3::new(0.1, 0.2, -0.3);
        let ab = a.compose(&b);
        assert!((ab.apply(&p) - a.apply(&b.apply(&p))).norm() < 1e-15);
        let m = a.to_matrix4() * b.to_matrix4();
        assert!((m - ab.to_matrix4()).amax() < 1e-15);
        let id = a.compose(&a.inverse());
        assert!(id.rotation_angle() < 1e-12 && id.translation_norm() < 1e-15);
        let back = RigidTransform::from_matrix4(&a.to_matrix4()).unwrap();
        assert!(back.rotation_angle_to(&a) < 1e-12 && back.translation_distance_to(&a) < 1e-15);
        assert!((a.rotation_angle() - 0.7).abs() < 1e-12);
        assert!((a.translation_norm() - 0.0014f64.sqrt()).abs() < 1e-15);
    }

    #[test]
    fn from_matrix4_rejects_non_rigid() {
        let mut m = sample().to_matrix4();
        m[(0, 0)] *= 1.1; // scale
        assert!(RigidTransform::from_matrix4(&m).is_none());
        let mut m = Matrix4::identity();
        m[(0, 0)] = -1.0; // reflection
        assert!(RigidTransform::from_matrix4(&m).is_none());
        let mut m = Matrix4::identity();
        m[(3, 0)] = 0.5; // projective row
        assert!(RigidTransform::from_matrix4(&m).is_none());
        let mut m = Matrix4::identity();
        m[(1, 3)] = f64::NAN;
        assert!(RigidTransform::from_matrix4(&m).is_none());
    }

    #[test]
    fn serde_is_row_major_contract_shape() {
        let t = RigidTransform::new(
            Rotation3::from_axis_angle(&Vector3::z_axis(), std::f64::consts::FRAC_PI_2),
            Vector3::new(1.0, 2.0, 3.0),
        );
        let v: serde_json::Value = serde_json::to_value(t).unwrap();
        let rows = v["rotation"].as_array().unwrap();
        // Rz(90°) = [[0,-1,0],[1,0,0],[0,0,1]]: row 0 has the −1.
        assert!((rows[0][1].as_f64().unwrap() + 1.0).abs() < 1e-15);
        assert!((rows[1][0].as_f64().unwrap() - 1.0).abs() < 1e-15);
        assert_eq!(v["translation"], serde_json::json!([1.0, 2.0, 3.0]));
        let back: RigidTransform = serde_json::from_value(v).unwrap();
        assert!(back.rotation_angle_to(&t) < 1e-15 && back.translation_distance_to(&t) == 0.0);

        let bad = r#"{"rotation": [[2,0,0],[0,1,0],[0,0,1]], "translation": [0,0,0]}"#;
        let err = serde_json::from_str::<RigidTransform>(bad).unwrap_err();
        assert!(err.to_string().contains("not a rotation"), "{err}");
    }
}

//! The synthetic depth camera: a position, a target, an up hint and a circular field-of-view
//! cone. Lengths in metres.

use nalgebra::{Isometry3, Point3, Rotation3, Translation3, UnitQuaternion, UnitVector3, Vector3};

use super::view_error::ViewError;

/// Default full cone angle of the field of view, degrees.
pub const DEFAULT_FOV_DEG: f64 = 70.0;

/// Sine of the smallest angle allowed between `up` and the view direction.
const MIN_UP_SINE: f64 = 1e-6;

/// Largest coordinate magnitude of `position` and `look_at`, metres (1,000 km: far beyond any
/// operating room, and small enough that every distance computed from them is finite).
pub(crate) const MAX_CAMERA_COORDINATE_M: f64 = 1e6;

/// A pinhole depth camera with a circular field of view.
///
/// The fields are public for convenience; [`Camera::validate`] checks them (the generator
/// calls it). Camera frame convention (OpenCV): +z along the view direction, +x to the right,
/// +y down in the image, so that `up` maps to −y.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// Optical centre, metres.
    pub position: Point3<f64>,
    /// A point on the optical axis, metres (must differ from `position`).
    pub look_at: Point3<f64>,
    /// Up hint (any length, not parallel to the view direction); only orients [`Camera::pose`].
    pub up: Vector3<f64>,
    /// Full apex angle of the field-of-view cone, degrees, in `(0, 180)` (default 70).
    pub fov_deg: f64,
}

impl Camera {
    /// A validated camera at `position` looking at `look_at` with up hint `up` and full
    /// cone angle `fov_deg` degrees.
    pub fn new(
        position: Point3<f64>,
        look_at: Point3<f64>,
        up: Vector3<f64>,
        fov_deg: f64,
    ) -> Result<Self, ViewError> {
        let camera = Self {
            position,
            look_at,
            up,
            fov_deg,
        };
        camera.validate()?;
        Ok(camera)
    }

    /// A validated camera with the default field of view ([`DEFAULT_FOV_DEG`]) and an up hint
    /// chosen automatically: world +z, or world +y when the view is (nearly) vertical.
    pub fn looking_at(position: Point3<f64>, look_at: Point3<f64>) -> Result<Self, ViewError> {
        let d = look_at - position;
        let up = if d.norm() > 0.0 && d.normalize().z.abs() > 0.9 {
            Vector3::y()
        } else {
            Vector3::z()
        };
        Self::new(position, look_at, up, DEFAULT_FOV_DEG)
    }

    /// The same camera with a different full cone angle (degrees), validated.
    pub fn with_fov(self, fov_deg: f64) -> Result<Self, ViewError> {
        Self::new(self.position, self.look_at, self.up, fov_deg)
    }

    /// Checks that every value is finite, `position ≠ look_at`, `up` is non-zero and not
    /// parallel to the view direction, and `0 < fov_deg < 180`.
    pub fn validate(&self) -> Result<(), ViewError> {
        let bad = |m: String| Err(ViewError::InvalidCamera(m));
        let finite = self.position.iter().all(|v| v.is_finite())
            && self.look_at.iter().all(|v| v.is_finite())
            && self.up.iter().all(|v| v.is_finite());
        if !finite {
            return bad(format!(
                "non-finite value (position {:?}, look_at {:?}, up {:?})",
                self.position.coords.as_slice(),
                self.look_at.coords.as_slice(),
                self.up.as_slice()
            ));
        }
        for (name, p) in [("position", &self.position), ("look_at", &self.look_at)] {
            if p.iter().any(|c| c.abs() > MAX_CAMERA_COORDINATE_M) {
                return bad(format!(
                    "{name} {:?} is out of range: camera coordinates must be within ±{MAX_CAMERA_COORDINATE_M:e}",
                    p.coords.as_slice()
                ));
            }
        }
        let d = self.look_at - self.position;
        let scale = self.position.coords.norm().max(self.look_at.coords.norm());
        if d.norm() <= 1e-12 * scale.max(1.0) {
            return bad(format!(
                "position and look_at coincide at {:?}",
                self.position.coords.as_slice()
            ));
        }
        if self.up.norm() == 0.0 {
            return bad("the up vector is zero".into());
        }
        if d.normalize().cross(&self.up.normalize()).norm() < MIN_UP_SINE {
            return bad(format!(
                "the up vector {:?} is parallel to the view direction {:?}",
                self.up.as_slice(),
                d.normalize().as_slice()
            ));
        }
        if !(self.fov_deg > 0.0 && self.fov_deg < 180.0) {
            return bad(format!(
                "fov_deg {} is outside (0, 180) degrees",
                self.fov_deg
            ));
        }
        Ok(())
    }

    /// Unit vector from `position` towards `look_at` (the optical axis).
    pub fn view_direction(&self) -> UnitVector3<f64> {
        UnitVector3::new_normalize(self.look_at - self.position)
    }

    /// Half the cone angle, radians.
    pub fn half_angle_rad(&self) -> f64 {
        0.5 * self.fov_deg.to_radians()
    }

    /// Camera-to-world rigid transform (OpenCV frame: +z forward, +x right, +y down).
    /// `pose() * Point3::origin()` is `position`; `pose() * Vector3::z()` is the view
    /// direction.
    pub fn pose(&self) -> Isometry3<f64> {
        let z = self.view_direction().into_inner();
        let x = z.cross(&self.up).normalize();
        let y = z.cross(&x);
        let rot = Rotation3::from_basis_unchecked(&[x, y, z]);
        Isometry3::from_parts(
            Translation3::from(self.position.coords),
            UnitQuaternion::from_rotation_matrix(&rot),
        )
    }

    /// World-to-camera rigid transform (inverse of [`Camera::pose`]).
    pub fn view(&self) -> Isometry3<f64> {
        self.pose().inverse()
    }

    /// Whether `p` lies inside the field-of-view cone (angle to the optical axis at most half
    /// the cone angle). The optical centre itself is not in view.
    pub fn in_field_of_view(&self, p: &Point3<f64>) -> bool {
        let d = p - self.position;
        let len = d.norm();
        if len == 0.0 {
            return false;
        }
        d.dot(&self.view_direction()) >= len * self.half_angle_rad().cos()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn validation_rejects_degenerate_cameras() {
        let p = Point3::new(0.0, 0.0, 1.0);
        let o = Point3::origin();
        let err = |c: Result<Camera, ViewError>| c.unwrap_err().to_string();
        assert!(err(Camera::new(p, p, Vector3::y(), 70.0)).contains("coincide"));
        assert!(err(Camera::new(p, o, Vector3::z(), 70.0)).contains("parallel"));
        assert!(err(Camera::new(p, o, Vector3::zeros(), 70.0)).contains("zero"));
        assert!(err(Camera::new(p, o, Vector3::y(), 180.0)).contains("fov_deg 180"));
        assert!(err(Camera::new(p, o, Vector3::y(), 0.0)).contains("fov_deg 0"));
        assert!(
            err(Camera::new(p, o, Vector3::new(f64::NAN, 0.0, 0.0), 70.0)).contains("non-finite")
        );
        let far = Point3::new(1e300, 0.0, 0.0);
        let e = err(Camera::new(far, o, Vector3::z(), 70.0));
        assert!(e.contains("position") && e.contains("out of range"), "{e}");
        let e = err(Camera::new(o, far, Vector3::z(), 70.0));
        assert!(e.contains("look_at") && e.contains("out of range"), "{e}");
        assert!(
            Camera::looking_at(p, o).is_ok(),
            "vertical view gets +y as up"
        );
    }

    #[test]
    fn pose_maps_camera_axes_to_world() {
        let c = Camera::new(
            Point3::new(1.0, 2.0, 3.0),
            Point3::new(4.0, 2.0, 3.0),
            Vector3::z(),
            60.0,
        )
        .unwrap();
        let pose = c.pose();
        assert!((pose * Point3::origin() - c.position).norm() < 1e-15);
        assert!((pose * Vector3::z() - Vector3::x()).norm() < 1e-12);
        // Looking along +x with +z up: image right is world −y, image down is world −z.
        assert!((pose * Vector3::x() + Vector3::y()).norm() < 1e-12);
        assert!((pose * Vector3::y() + Vector3::z()).norm() < 1e-12);
        let q = Point3::new(0.5, -0.25, 7.0);
        assert!((c.view() * (pose * q) - q).norm() < 1e-12);
    }

    #[test]
    fn field_of_view_cone() {
        let c = Camera::new(
            Point3::origin(),
            Point3::new(0.0, 0.0, 1.0),
            Vector3::y(),
            90.0,
        )
        .unwrap();
        assert!(c.in_field_of_view(&Point3::new(0.0, 0.0, 1.0)));
        assert!(c.in_field_of_view(&Point3::new(0.99, 0.0, 1.0)));
        assert!(!c.in_field_of_view(&Point3::new(1.01, 0.0, 1.0)));
        assert!(!c.in_field_of_view(&Point3::new(0.0, 0.0, -1.0)));
        assert!(!c.in_field_of_view(&Point3::origin()));
    }
}

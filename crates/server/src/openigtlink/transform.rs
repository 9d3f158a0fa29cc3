//! TRANSFORM (spec "Transform Message"): a 4×4 homogeneous rigid or affine transform.
//!
//! Content, 48 bytes: twelve big-endian float32 `R11 R21 R31 R12 R22 R32 R13 R23 R33 TX TY TZ`
//! — the three columns of the upper 3×3 part, then the translation, in millimetres. The last row
//! is implied `0 0 0 1`.

use nalgebra::{Isometry3, Matrix3, Matrix4, Rotation3, Translation3, UnitQuaternion};

use super::error::IgtlError;
use super::message::MessageContent;
use super::wire::{finite, to_f32, Reader};

/// Content size of a TRANSFORM in bytes.
pub(crate) const TRANSFORM_CONTENT_SIZE: usize = 48;

/// A TRANSFORM message's content: a homogeneous matrix whose translation is in millimetres.
/// Values travel as float32 (about 7 significant digits).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TransformMessage {
    /// The 4×4 matrix; its last row is ignored when encoding and decoded as `0 0 0 1`.
    pub matrix: Matrix4<f64>,
}

impl TransformMessage {
    /// From a homogeneous matrix (translation in mm).
    pub fn from_matrix(matrix: Matrix4<f64>) -> Self {
        Self { matrix }
    }

    /// From a rigid transform (translation in mm).
    pub fn from_isometry(isometry: &Isometry3<f64>) -> Self {
        Self {
            matrix: isometry.to_homogeneous(),
        }
    }

    /// The rigid transform, if the 3×3 part is a proper rotation within `tolerance`:
    /// ‖RᵀR − I‖_F ≤ tolerance and det R > 0 (float32 transmission leaves about 1e-6). The rotation
    /// is re-orthonormalised to the nearest one. Otherwise [`IgtlError::NotRigid`].
    pub fn to_isometry(&self, tolerance: f64) -> Result<Isometry3<f64>, IgtlError> {
        let r: Matrix3<f64> = self.matrix.fixed_view::<3, 3>(0, 0).into_owned();
        let orthogonality_error = (r.transpose() * r - Matrix3::identity()).norm();
        let determinant = r.determinant();
        if !(orthogonality_error <= tolerance && determinant > 0.0) {
            return Err(IgtlError::NotRigid {
                orthogonality_error,
                determinant,
                tolerance,
            });
        }
        let rotation = Rotation3::from_matrix_eps(&r, 1e-12, 100, Rotation3::identity());
        let t = self.matrix.fixed_view::<3, 1>(0, 3);
        Ok(Isometry3::from_parts(
            Translation3::new(t[0], t[1], t[2]),
            UnitQuaternion::from_rotation_matrix(&rotation),
        ))
    }
}

impl MessageContent for TransformMessage {
    const TYPE_NAME: &'static str = "TRANSFORM";

    /// Writes the 12 float32; a value that is not finite in float32 is [`IgtlError::NonFinite`].
    fn encode_content(&self, out: &mut Vec<u8>) -> Result<(), IgtlError> {
        for column in 0..4 {
            for row in 0..3 {
                let index = column * 3 + row;
                let value = to_f32(self.matrix[(row, column)], "TRANSFORM element", index)?;
                out.extend_from_slice(&value.to_be_bytes());
            }
        }
        Ok(())
    }

    /// Reads exactly 48 bytes ([`IgtlError::ContentSize`] otherwise); NaN or infinite elements
    /// are [`IgtlError::NonFinite`].
    fn decode_content(content: &[u8]) -> Result<Self, IgtlError> {
        if content.len() != TRANSFORM_CONTENT_SIZE {
            return Err(IgtlError::ContentSize {
                type_name: Self::TYPE_NAME,
                actual: content.len() as u64,
                expected: format!("{TRANSFORM_CONTENT_SIZE} bytes"),
            });
        }
        let mut reader = Reader::new(content);
        let mut matrix = Matrix4::identity();
        for column in 0..4 {
            for row in 0..3 {
                let index = column * 3 + row;
                matrix[(row, column)] =
                    finite(reader.f32("TRANSFORM")?, "TRANSFORM element", index)?;
            }
        }
        Ok(Self { matrix })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    fn pose() -> Isometry3<f64> {
        Isometry3::new(
            Vector3::new(12.5, -40.0, 310.25),
            Vector3::new(0.3, -0.2, 1.1),
        )
    }

    #[test]
    fn layout_is_columns_then_translation() {
        let mut m = Matrix4::identity();
        m[(0, 1)] = 2.0; // R12
        m[(1, 0)] = 3.0; // R21
        m[(0, 3)] = 7.0; // TX
        m[(2, 3)] = 9.0; // TZ
        let mut out = Vec::new();
        TransformMessage::from_matrix(m)
            .encode_content(&mut out)
            .unwrap();
        let values: Vec<f32> = out
            .chunks(4)
            .map(|c| f32::from_be_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        assert_eq!(
            values,
            vec![1.0, 3.0, 0.0, 2.0, 1.0, 0.0, 0.0, 0.0, 1.0, 7.0, 0.0, 9.0]
        );
        assert_eq!(TransformMessage::decode_content(&out).unwrap().matrix, m);
    }

    #[test]
    fn isometry_round_trip_within_float32() {
        let mut out = Vec::new();
        TransformMessage::from_isometry(&pose())
            .encode_content(&mut out)
            .unwrap();
        let back = TransformMessage::decode_content(&out)
            .unwrap()
            .to_isometry(1e-5)
            .unwrap();
        assert!((back.translation.vector - pose().translation.vector).norm() < 1e-4);
        assert!(back.rotation.angle_to(&pose().rotation) < 1e-6);
    }

    #[test]
    fn errors() {
        assert!(matches!(
            TransformMessage::decode_content(&[0; 47]),
            Err(IgtlError::ContentSize {
                type_name: "TRANSFORM",
                actual: 47,
                ..
            })
        ));
        let mut out = Vec::new();
        TransformMessage::from_isometry(&pose())
            .encode_content(&mut out)
            .unwrap();
        out[40..44].copy_from_slice(&f32::NAN.to_be_bytes());
        assert!(matches!(
            TransformMessage::decode_content(&out),
            Err(IgtlError::NonFinite { index: 10, .. })
        ));
        let scaled = TransformMessage::from_matrix(Matrix4::new_scaling(2.0));
        assert!(matches!(
            scaled.to_isometry(1e-5),
            Err(IgtlError::NotRigid { .. })
        ));
        let mut mirror = Matrix4::identity();
        mirror[(0, 0)] = -1.0;
        assert!(matches!(
            TransformMessage::from_matrix(mirror).to_isometry(1e-5),
            Err(IgtlError::NotRigid { .. })
        ));
        let mut huge = Matrix4::identity();
        huge[(0, 3)] = 1e300;
        assert!(matches!(
            TransformMessage::from_matrix(huge).encode_content(&mut Vec::new()),
            Err(IgtlError::NonFinite { index: 9, .. })
        ));
    }
}

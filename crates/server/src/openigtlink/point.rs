//! POINT (spec "Point Message"): fiducials or landmarks.
//!
//! Content: a sequence of 136-byte elements, each big-endian:
//!
//! | offset | size | field    | type                                  |
//! |-------:|-----:|----------|---------------------------------------|
//! | 0      | 64   | NAME     | `char[64]`, NUL padded                  |
//! | 64     | 32   | GROUP    | `char[32]` ("Landmark", "Fiducial", …)  |
//! | 96     | 4    | RGBA     | u8 × 4                                |
//! | 100    | 12   | X, Y, Z  | float32 × 3, millimetres              |
//! | 112    | 4    | DIAMETER | float32, millimetres (may be 0)       |
//! | 116    | 20   | OWNER    | `char[20]`, id of the owner image       |
//!
//! Strings are decoded as UTF-8 up to the first NUL (pyigtl writes UTF-8).

use nalgebra::Point3;

use super::error::IgtlError;
use super::message::MessageContent;
use super::wire::{decode_fixed_str, finite, put_fixed_str, to_f32, Reader};

/// Size of one POINT element in bytes.
pub(crate) const POINT_ELEMENT_SIZE: usize = 136;

/// One point of a POINT message.
#[derive(Debug, Clone, PartialEq)]
pub struct PointElement {
    /// Name or description (at most 64 bytes of UTF-8).
    pub name: String,
    /// Group name, e.g. "Landmark" (at most 32 bytes).
    pub group: String,
    /// Colour, RGBA.
    pub rgba: [u8; 4],
    /// Position in millimetres.
    pub position: Point3<f64>,
    /// Diameter in millimetres (0 allowed).
    pub diameter: f64,
    /// Id of the owner image (at most 20 bytes).
    pub owner: String,
}

impl PointElement {
    /// A point with the given name and position (mm): empty group and owner, opaque yellow
    /// (pyigtl's default colour), diameter 0.
    pub fn new(name: impl Into<String>, position: Point3<f64>) -> Self {
        Self {
            name: name.into(),
            group: String::new(),
            rgba: [255, 255, 0, 255],
            position,
            diameter: 0.0,
            owner: String::new(),
        }
    }
}

/// A POINT message's content: zero or more elements.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct PointMessage {
    /// The points, in message order.
    pub points: Vec<PointElement>,
}

impl PointMessage {
    /// The positions alone (mm), e.g. as a point cloud.
    pub fn positions(&self) -> Vec<Point3<f64>> {
        self.points.iter().map(|p| p.position).collect()
    }
}

impl MessageContent for PointMessage {
    const TYPE_NAME: &'static str = "POINT";

    /// Writes 136 bytes per element. Strings longer than their field or containing NUL, and
    /// coordinates or diameters not finite in float32, are errors.
    fn encode_content(&self, out: &mut Vec<u8>) -> Result<(), IgtlError> {
        out.reserve(self.points.len() * POINT_ELEMENT_SIZE);
        for (i, point) in self.points.iter().enumerate() {
            put_fixed_str(out, &point.name, 64, "POINT name", false)?;
            put_fixed_str(out, &point.group, 32, "POINT group", false)?;
            out.extend_from_slice(&point.rgba);
            for axis in 0..3 {
                let value = to_f32(point.position[axis], "POINT position", i * 3 + axis)?;
                out.extend_from_slice(&value.to_be_bytes());
            }
            let diameter = to_f32(point.diameter, "POINT diameter", i)?;
            out.extend_from_slice(&diameter.to_be_bytes());
            put_fixed_str(out, &point.owner, 20, "POINT owner", false)?;
        }
        Ok(())
    }

    /// Reads elements; a content size that is not a multiple of 136 is
    /// [`IgtlError::ContentSize`], non-finite floats [`IgtlError::NonFinite`], invalid UTF-8
    /// [`IgtlError::InvalidName`].
    fn decode_content(content: &[u8]) -> Result<Self, IgtlError> {
        if !content.len().is_multiple_of(POINT_ELEMENT_SIZE) {
            return Err(IgtlError::ContentSize {
                type_name: Self::TYPE_NAME,
                actual: content.len() as u64,
                expected: format!("a multiple of {POINT_ELEMENT_SIZE} bytes"),
            });
        }
        let count = content.len() / POINT_ELEMENT_SIZE;
        let mut reader = Reader::new(content);
        let mut points = Vec::with_capacity(count);
        for i in 0..count {
            let name = decode_fixed_str(reader.take(64, "POINT element")?, "POINT name", false)?;
            let group = decode_fixed_str(reader.take(32, "POINT element")?, "POINT group", false)?;
            let mut rgba = [0u8; 4];
            rgba.copy_from_slice(reader.take(4, "POINT element")?);
            let mut xyz = [0.0; 3];
            for (axis, value) in xyz.iter_mut().enumerate() {
                *value = finite(reader.f32("POINT element")?, "POINT position", i * 3 + axis)?;
            }
            let diameter = finite(reader.f32("POINT element")?, "POINT diameter", i)?;
            let owner = decode_fixed_str(reader.take(20, "POINT element")?, "POINT owner", false)?;
            points.push(PointElement {
                name,
                group,
                rgba,
                position: Point3::from(xyz),
                diameter,
                owner,
            });
        }
        Ok(Self { points })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> PointMessage {
        let mut a = PointElement::new("Tip", Point3::new(1.5, -2.25, 300.0));
        a.group = "Landmark".to_owned();
        a.rgba = [1, 2, 3, 4];
        a.diameter = 2.5;
        a.owner = "CT".to_owned();
        let b = PointElement::new("x".repeat(64), Point3::new(0.0, 0.0, -1.0));
        PointMessage { points: vec![a, b] }
    }

    #[test]
    fn round_trip_and_layout() {
        let mut out = Vec::new();
        sample().encode_content(&mut out).unwrap();
        assert_eq!(out.len(), 2 * POINT_ELEMENT_SIZE);
        assert_eq!(&out[0..4], b"Tip\0");
        assert_eq!(&out[64..72], b"Landmark");
        assert_eq!(&out[96..100], &[1, 2, 3, 4]);
        assert_eq!(&out[100..104], &1.5f32.to_be_bytes());
        assert_eq!(&out[112..116], &2.5f32.to_be_bytes());
        assert_eq!(&out[116..118], b"CT");
        assert_eq!(PointMessage::decode_content(&out).unwrap(), sample());
        assert!(PointMessage::decode_content(&[]).unwrap().points.is_empty());
    }

    #[test]
    fn errors() {
        assert!(matches!(
            PointMessage::decode_content(&[0; 137]),
            Err(IgtlError::ContentSize {
                type_name: "POINT",
                actual: 137,
                ..
            })
        ));
        let mut too_long = sample();
        too_long.points[0].owner = "o".repeat(21);
        assert!(matches!(
            too_long.encode_content(&mut Vec::new()),
            Err(IgtlError::NameTooLong {
                field: "POINT owner",
                length: 21,
                max: 20
            })
        ));
        let mut out = Vec::new();
        sample().encode_content(&mut out).unwrap();
        out[136 + 108..136 + 112].copy_from_slice(&f32::INFINITY.to_be_bytes());
        assert!(matches!(
            PointMessage::decode_content(&out),
            Err(IgtlError::NonFinite {
                field: "POINT position",
                index: 5
            })
        ));
        let mut out = Vec::new();
        sample().encode_content(&mut out).unwrap();
        out[0] = 0xFF;
        assert!(matches!(
            PointMessage::decode_content(&out),
            Err(IgtlError::InvalidName {
                field: "POINT name",
                ..
            })
        ));
    }
}

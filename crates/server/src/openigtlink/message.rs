//! A whole message: header fields, the body's extended header and metadata (header version 2),
//! and the typed content.
//!
//! Body layout (spec "Message Header", "Extended Header Fields" and "Metadata Fields"):
//! - header version 1: the content alone;
//! - header version 2: a 12-byte extended header `EXT_HEADER_SIZE: u16 (12),
//!   METADATA_HEADER_SIZE: u16, METADATA_SIZE: u32, MSG_ID: u32`, then the content, then the
//!   metadata index (`METADATA_HEADER_SIZE` bytes) and key/value bytes (`METADATA_SIZE` bytes).
//!   The content size is `BODY_SIZE − EXT_HEADER_SIZE − METADATA_HEADER_SIZE − METADATA_SIZE`.
//!   This is the layout of the OpenIGTLink library and pyigtl; the spec page's table of the
//!   extended header differs (it lists a u16 metadata size and a reserved u32), the library wins.

use super::crc64::crc64;
use super::error::IgtlError;
use super::header::{Header, HeaderVersion, Timestamp, DEVICE_NAME_SIZE, HEADER_SIZE};
use super::metadata::Metadata;
use super::point::PointMessage;
use super::polydata::PolyDataMessage;
use super::status::StatusMessage;
use super::transform::TransformMessage;
use super::wire::{check_fixed_str, Reader};

/// Size of the extended header written by this codec (and the smallest accepted).
pub const EXTENDED_HEADER_SIZE: usize = 12;

/// The content codec of one message type.
pub trait MessageContent: Sized {
    /// The header's TYPE for this content, e.g. "TRANSFORM".
    const TYPE_NAME: &'static str;

    /// Appends the encoded content (big-endian, spec layout) to `out`.
    fn encode_content(&self, out: &mut Vec<u8>) -> Result<(), IgtlError>;

    /// Decodes a whole content section (exactly the content bytes, without extended header or
    /// metadata).
    fn decode_content(content: &[u8]) -> Result<Self, IgtlError>;
}

/// The typed content of a message this codec supports.
#[derive(Debug, Clone, PartialEq)]
pub enum Content {
    /// TRANSFORM.
    Transform(TransformMessage),
    /// POINT.
    Point(PointMessage),
    /// POLYDATA.
    PolyData(PolyDataMessage),
    /// STATUS.
    Status(StatusMessage),
}

impl Content {
    /// The header TYPE of this content.
    pub fn type_name(&self) -> &'static str {
        match self {
            Content::Transform(_) => TransformMessage::TYPE_NAME,
            Content::Point(_) => PointMessage::TYPE_NAME,
            Content::PolyData(_) => PolyDataMessage::TYPE_NAME,
            Content::Status(_) => StatusMessage::TYPE_NAME,
        }
    }

    /// Appends the encoded content to `out`.
    pub fn encode(&self, out: &mut Vec<u8>) -> Result<(), IgtlError> {
        match self {
            Content::Transform(c) => c.encode_content(out),
            Content::Point(c) => c.encode_content(out),
            Content::PolyData(c) => c.encode_content(out),
            Content::Status(c) => c.encode_content(out),
        }
    }

    /// Decodes content of type `type_name`. Any other type (IMAGE, STRING, GET_TRANSFORM, …) is
    /// [`IgtlError::UnsupportedMessageType`] carrying the type and `device_name`.
    pub fn decode(type_name: &str, device_name: &str, content: &[u8]) -> Result<Self, IgtlError> {
        match type_name {
            TransformMessage::TYPE_NAME => {
                TransformMessage::decode_content(content).map(Content::Transform)
            }
            PointMessage::TYPE_NAME => PointMessage::decode_content(content).map(Content::Point),
            PolyDataMessage::TYPE_NAME => {
                PolyDataMessage::decode_content(content).map(Content::PolyData)
            }
            StatusMessage::TYPE_NAME => StatusMessage::decode_content(content).map(Content::Status),
            _ => Err(IgtlError::UnsupportedMessageType {
                type_name: type_name.to_owned(),
                device_name: device_name.to_owned(),
            }),
        }
    }
}

impl From<TransformMessage> for Content {
    fn from(c: TransformMessage) -> Self {
        Content::Transform(c)
    }
}

impl From<PointMessage> for Content {
    fn from(c: PointMessage) -> Self {
        Content::Point(c)
    }
}

impl From<PolyDataMessage> for Content {
    fn from(c: PolyDataMessage) -> Self {
        Content::PolyData(c)
    }
}

impl From<StatusMessage> for Content {
    fn from(c: StatusMessage) -> Self {
        Content::Status(c)
    }
}

/// A message: device name, timestamp, message id and metadata (header version 2 only), content.
#[derive(Debug, Clone, PartialEq)]
pub struct Message {
    /// DEVICE_NAME: printable US-ASCII, at most 20 characters (see `docs/openigtlink.md` for the
    /// names livereg uses).
    pub device_name: String,
    /// TIME_STAMP (seconds since 1970, 2⁻³² s resolution).
    pub timestamp: Timestamp,
    /// MSG_ID of the extended header (header version 2; 0 with version 1).
    pub message_id: u32,
    /// Metadata (header version 2; empty with version 1).
    pub metadata: Metadata,
    /// The typed content.
    pub content: Content,
}

impl Message {
    /// A message stamped with the current time, message id 0 and no metadata.
    pub fn new(device_name: impl Into<String>, content: impl Into<Content>) -> Self {
        Self {
            device_name: device_name.into(),
            timestamp: Timestamp::now(),
            message_id: 0,
            metadata: Metadata::new(),
            content: content.into(),
        }
    }

    /// Encodes header and body with the given header version. Version 1 has no extended header:
    /// the message id is dropped and non-empty metadata is [`IgtlError::MetadataNeedsVersion2`].
    /// Version 2 always writes the extended header and a metadata index (2 bytes when empty).
    pub fn encode(&self, version: HeaderVersion) -> Result<Vec<u8>, IgtlError> {
        check_fixed_str(&self.device_name, DEVICE_NAME_SIZE, "device name", true)?;
        let mut body = Vec::new();
        match version {
            HeaderVersion::V1 => {
                if !self.metadata.is_empty() {
                    return Err(IgtlError::MetadataNeedsVersion2 {
                        entries: self.metadata.len(),
                    });
                }
                self.content.encode(&mut body)?;
            }
            HeaderVersion::V2 => {
                let (index, data) = self.metadata.encode()?;
                body.extend_from_slice(&(EXTENDED_HEADER_SIZE as u16).to_be_bytes());
                body.extend_from_slice(&(index.len() as u16).to_be_bytes());
                body.extend_from_slice(&(data.len() as u32).to_be_bytes());
                body.extend_from_slice(&self.message_id.to_be_bytes());
                self.content.encode(&mut body)?;
                body.extend_from_slice(&index);
                body.extend_from_slice(&data);
            }
        }
        let header = Header {
            version,
            type_name: self.content.type_name().to_owned(),
            device_name: self.device_name.clone(),
            timestamp: self.timestamp,
            body_size: body.len() as u64,
            crc: crc64(&body),
        };
        let mut bytes = Vec::with_capacity(HEADER_SIZE + body.len());
        bytes.extend_from_slice(&header.encode()?);
        bytes.extend_from_slice(&body);
        Ok(bytes)
    }

    /// Decodes a message from its decoded header and its body. Checks, in order: the body's
    /// length equals BODY_SIZE ([`IgtlError::Truncated`] otherwise), the CRC
    /// ([`IgtlError::CrcMismatch`]), for version 2 the extended header and metadata sizes against
    /// the body ([`IgtlError::InvalidField`]), the metadata, then the content (unsupported types
    /// are [`IgtlError::UnsupportedMessageType`]).
    pub fn decode(header: &Header, body: &[u8]) -> Result<Self, IgtlError> {
        if body.len() as u64 != header.body_size {
            return Err(IgtlError::Truncated {
                section: "body",
                expected: header.body_size,
                actual: body.len() as u64,
            });
        }
        let computed = crc64(body);
        if computed != header.crc {
            return Err(IgtlError::CrcMismatch {
                expected: header.crc,
                computed,
            });
        }
        Self::decode_checked_body(header, body)
    }

    /// [`Message::decode`] for a body whose length and CRC were already verified.
    pub(crate) fn decode_checked_body(header: &Header, body: &[u8]) -> Result<Self, IgtlError> {
        let (message_id, metadata, content) = split_body(header.version, body)?;
        let content = Content::decode(&header.type_name, &header.device_name, content)?;
        Ok(Self {
            device_name: header.device_name.clone(),
            timestamp: header.timestamp,
            message_id,
            metadata,
            content,
        })
    }
}

/// Splits a body into message id, metadata and content bytes.
fn split_body(version: HeaderVersion, body: &[u8]) -> Result<(u32, Metadata, &[u8]), IgtlError> {
    if version == HeaderVersion::V1 {
        return Ok((0, Metadata::new(), body));
    }
    if body.len() < EXTENDED_HEADER_SIZE {
        return Err(IgtlError::InvalidField {
            field: "BODY_SIZE",
            value: body.len() as u64,
            expected: format!("at least {EXTENDED_HEADER_SIZE} (the extended header of version 2)"),
        });
    }
    let mut reader = Reader::new(body);
    let extended_size = usize::from(reader.u16("extended header")?);
    let metadata_header_size = usize::from(reader.u16("extended header")?);
    let metadata_size = reader.u32("extended header")? as usize;
    let message_id = reader.u32("extended header")?;
    if extended_size < EXTENDED_HEADER_SIZE || extended_size > body.len() {
        return Err(IgtlError::InvalidField {
            field: "EXT_HEADER_SIZE",
            value: extended_size as u64,
            expected: format!(
                "between {EXTENDED_HEADER_SIZE} and the body size {}",
                body.len()
            ),
        });
    }
    let available = body.len() - extended_size;
    let metadata_total = metadata_header_size as u64 + metadata_size as u64;
    if metadata_total > available as u64 {
        return Err(IgtlError::InvalidField {
            field: "METADATA_HEADER_SIZE + METADATA_SIZE",
            value: metadata_total,
            expected: format!(
                "at most {available} (body size {} minus extended header {extended_size})",
                body.len()
            ),
        });
    }
    let content_end = body.len() - metadata_total as usize;
    let content = &body[extended_size..content_end];
    let index = &body[content_end..content_end + metadata_header_size];
    let data = &body[content_end + metadata_header_size..];
    let metadata = Metadata::decode(index, data)?;
    Ok((message_id, metadata, content))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Isometry3, Point3, Vector3};

    /// A transform whose elements are exact in float32, so that round trips compare equal.
    fn transform_message() -> Message {
        let matrix = Isometry3::new(Vector3::new(1.0, 2.0, 3.0), Vector3::new(0.1, 0.2, 0.3))
            .to_homogeneous()
            .map(|v| f64::from(v as f32));
        let mut message = Message::new("LiverToReference", TransformMessage::from_matrix(matrix));
        message.timestamp = Timestamp {
            seconds: 1_700_000_000,
            fraction: 1 << 31,
        };
        message
    }

    fn decode(bytes: &[u8]) -> Result<Message, IgtlError> {
        let mut header_bytes = [0u8; HEADER_SIZE];
        header_bytes.copy_from_slice(&bytes[..HEADER_SIZE]);
        Message::decode(&Header::decode(&header_bytes)?, &bytes[HEADER_SIZE..])
    }

    #[test]
    fn version_1_body_is_the_content() {
        let bytes = transform_message().encode(HeaderVersion::V1).unwrap();
        assert_eq!(bytes.len(), HEADER_SIZE + 48);
        assert_eq!(&bytes[42..50], &48u64.to_be_bytes());
        assert_eq!(&bytes[50..58], &crc64(&bytes[58..]).to_be_bytes());
        assert_eq!(decode(&bytes).unwrap(), transform_message());
    }

    #[test]
    fn version_2_layout_with_metadata() {
        let mut message = transform_message();
        message.message_id = 77;
        message.metadata.insert("units", "mm");
        let bytes = message.encode(HeaderVersion::V2).unwrap();
        let body = &bytes[HEADER_SIZE..];
        assert_eq!(&body[0..2], &[0, 12]);
        assert_eq!(&body[2..4], &[0, 10]); // 2 + 8
        assert_eq!(&body[4..8], &7u32.to_be_bytes()); // "units" + "mm"
        assert_eq!(&body[8..12], &77u32.to_be_bytes());
        assert_eq!(body.len(), 12 + 48 + 10 + 7);
        assert_eq!(&body[body.len() - 7..], b"unitsmm");
        assert_eq!(decode(&bytes).unwrap(), message);
        // Without metadata: a 2-byte empty index.
        let bytes = transform_message().encode(HeaderVersion::V2).unwrap();
        assert_eq!(bytes.len(), HEADER_SIZE + 12 + 48 + 2);
        assert_eq!(decode(&bytes).unwrap(), transform_message());
    }

    #[test]
    fn metadata_needs_version_2() {
        let mut message = transform_message();
        message.metadata.insert("a", "b");
        assert!(matches!(
            message.encode(HeaderVersion::V1),
            Err(IgtlError::MetadataNeedsVersion2 { entries: 1 })
        ));
    }

    /// Re-signs a modified body so that the CRC passes and the later checks are reached.
    fn resign(bytes: &mut [u8]) {
        let crc = crc64(&bytes[HEADER_SIZE..]);
        bytes[50..58].copy_from_slice(&crc.to_be_bytes());
    }

    #[test]
    fn body_errors() {
        let good = transform_message().encode(HeaderVersion::V2).unwrap();
        let mut bad = good.clone();
        bad[HEADER_SIZE + 20] ^= 1;
        assert!(matches!(decode(&bad), Err(IgtlError::CrcMismatch { .. })));

        let mut bad = good.clone();
        bad[HEADER_SIZE..HEADER_SIZE + 2].copy_from_slice(&11u16.to_be_bytes());
        resign(&mut bad);
        assert!(matches!(
            decode(&bad),
            Err(IgtlError::InvalidField {
                field: "EXT_HEADER_SIZE",
                value: 11,
                ..
            })
        ));

        let mut bad = good.clone();
        bad[HEADER_SIZE + 4..HEADER_SIZE + 8].copy_from_slice(&u32::MAX.to_be_bytes());
        resign(&mut bad);
        assert!(matches!(
            decode(&bad),
            Err(IgtlError::InvalidField {
                field: "METADATA_HEADER_SIZE + METADATA_SIZE",
                ..
            })
        ));

        // Metadata that eats into the content: the content size no longer fits TRANSFORM.
        let mut bad = good.clone();
        bad[HEADER_SIZE + 2..HEADER_SIZE + 4].copy_from_slice(&6u16.to_be_bytes());
        resign(&mut bad);
        assert!(decode(&bad).is_err());

        // A version 2 body shorter than the extended header.
        let mut short = good[..HEADER_SIZE + 8].to_vec();
        short[42..50].copy_from_slice(&8u64.to_be_bytes());
        resign(&mut short);
        assert!(matches!(
            decode(&short),
            Err(IgtlError::InvalidField {
                field: "BODY_SIZE",
                value: 8,
                ..
            })
        ));

        // BODY_SIZE disagreeing with the bytes given.
        assert!(matches!(
            decode(&good[..good.len() - 1]),
            Err(IgtlError::Truncated {
                section: "body",
                ..
            })
        ));
    }

    #[test]
    fn unsupported_types_carry_their_names() {
        let mut bytes = transform_message().encode(HeaderVersion::V1).unwrap();
        bytes[2..14].copy_from_slice(b"IMAGE\0\0\0\0\0\0\0");
        match decode(&bytes) {
            Err(e @ IgtlError::UnsupportedMessageType { .. }) => {
                assert!(e.keeps_stream_in_sync());
                let status = e.to_status();
                assert_eq!(
                    status.code,
                    super::super::status::status_code::UNKNOWN_INSTRUCTION
                );
                assert!(status.message.contains("IMAGE"), "{}", status.message);
                match e {
                    IgtlError::UnsupportedMessageType {
                        type_name,
                        device_name,
                    } => {
                        assert_eq!(type_name, "IMAGE");
                        assert_eq!(device_name, "LiverToReference");
                    }
                    _ => unreachable!(),
                }
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn all_contents_round_trip_in_both_versions() {
        let contents: Vec<Content> = vec![
            transform_message().content,
            PointMessage {
                points: vec![super::super::point::PointElement::new(
                    "p",
                    Point3::new(1.0, 2.0, 3.0),
                )],
            }
            .into(),
            PolyDataMessage::from_point_cloud(&[Point3::new(1.0, 2.0, 3.0)], true)
                .unwrap()
                .into(),
            StatusMessage::ok("ready").into(),
        ];
        for content in contents {
            for version in [HeaderVersion::V1, HeaderVersion::V2] {
                let mut message = transform_message();
                message.content = content.clone();
                let back = decode(&message.encode(version).unwrap()).unwrap();
                assert_eq!(back, message, "{} {version:?}", content.type_name());
            }
        }
    }
}

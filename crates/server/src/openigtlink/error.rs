//! Errors of the OpenIGTLink codec: each names the field, the value found and what was expected.

use super::status::{status_code, StatusMessage};

/// Everything that can go wrong while reading or writing an OpenIGTLink message.
///
/// Decoding never panics: every malformed input ends in one of these variants. Use
/// [`IgtlError::keeps_stream_in_sync`] to know whether a connection can go on reading after the
/// error (the whole body was consumed) and [`IgtlError::to_status`] to build the STATUS reply.
#[derive(Debug, thiserror::Error)]
pub enum IgtlError {
    /// The underlying reader or writer failed (not an end of file inside a message: that is
    /// [`IgtlError::Truncated`]).
    #[error("I/O error: {0}")]
    Io(#[from] std::io::Error),

    /// The input ended before a section was complete.
    #[error("truncated {section}: needed {expected} bytes, only {actual} available")]
    Truncated {
        /// The section being read (e.g. "header", "body", "POINT element").
        section: &'static str,
        /// Bytes the section needs.
        expected: u64,
        /// Bytes that were available.
        actual: u64,
    },

    /// The header's version field is neither 1 nor 2 (OpenIGTLink header versions; protocol
    /// versions 1 and 2 use header version 1, protocol version 3 uses header version 2).
    #[error("unsupported header version {version} (expected 1 or 2)")]
    UnsupportedVersion {
        /// The version field as received.
        version: u16,
    },

    /// The header announces a body larger than the caller's limit; nothing was allocated.
    #[error("body size {body_size} bytes exceeds the limit of {max} bytes")]
    BodyTooLarge {
        /// BODY_SIZE from the header.
        body_size: u64,
        /// The caller's maximum.
        max: u64,
    },

    /// The CRC-64 of the body differs from the header's CRC field.
    #[error("CRC-64 mismatch: header says {expected:#018x}, body gives {computed:#018x}")]
    CrcMismatch {
        /// CRC field of the header.
        expected: u64,
        /// CRC-64/ECMA-182 computed over the received body.
        computed: u64,
    },

    /// A fixed-size name field (header TYPE or DEVICE_NAME, or a content string) is malformed.
    #[error("invalid {field}: {reason}")]
    InvalidName {
        /// Which field ("type name", "device name", "POINT name", ...).
        field: &'static str,
        /// What is wrong, with the offending byte or position.
        reason: String,
    },

    /// A string is too long for its fixed-size or length-prefixed field (encoding side).
    #[error("{field} is {length} bytes long, at most {max} allowed")]
    NameTooLong {
        /// Which field.
        field: &'static str,
        /// Its length in bytes (UTF-8).
        length: usize,
        /// The field's capacity.
        max: usize,
    },

    /// The message type is well framed but not one this codec decodes (only TRANSFORM, POINT,
    /// POLYDATA and STATUS are). The body was fully read and its CRC checked, so the stream is
    /// still in sync: answer with a STATUS (see [`IgtlError::to_status`]) and go on.
    #[error("unsupported message type {type_name:?} (device {device_name:?})")]
    UnsupportedMessageType {
        /// The header's TYPE field.
        type_name: String,
        /// The header's DEVICE_NAME field.
        device_name: String,
    },

    /// A numeric field has a value outside what the specification allows.
    #[error("invalid {field}: {value}, expected {expected}")]
    InvalidField {
        /// The field (e.g. "extended header size", "POLYDATA SIZE_POLYGONS").
        field: &'static str,
        /// The value found.
        value: u64,
        /// What was expected, in words.
        expected: String,
    },

    /// The content section's size does not fit the message type.
    #[error("{type_name} content is {actual} bytes, expected {expected}")]
    ContentSize {
        /// The message type.
        type_name: &'static str,
        /// Content size found (body minus extended header and metadata).
        actual: u64,
        /// What was expected, in words.
        expected: String,
    },

    /// A float (coordinate, matrix element, diameter) is NaN or infinite.
    #[error("non-finite {field} at index {index}")]
    NonFinite {
        /// Which field.
        field: &'static str,
        /// Index of the offending element (flattened).
        index: usize,
    },

    /// A metadata value uses a character encoding this codec does not decode (only US-ASCII, 3,
    /// and UTF-8, 106, are).
    #[error("metadata value of key {key:?} has encoding {encoding}, expected 3 (US-ASCII) or 106 (UTF-8)")]
    UnsupportedMetadataEncoding {
        /// The entry's key.
        key: String,
        /// VALUE_ENCODING (an IANA MIBenum).
        encoding: u16,
    },

    /// Metadata cannot be sent with header version 1 (it has no extended header).
    #[error("metadata ({entries} entries) needs header version 2")]
    MetadataNeedsVersion2 {
        /// Number of metadata entries that would be lost.
        entries: usize,
    },

    /// A TRANSFORM's 3×3 part is not a rotation within the tolerance.
    #[error("TRANSFORM is not rigid: |RᵀR − I| = {orthogonality_error:e}, det R = {determinant}, tolerance {tolerance:e}")]
    NotRigid {
        /// Frobenius norm of RᵀR − I.
        orthogonality_error: f64,
        /// Determinant of R.
        determinant: f64,
        /// The caller's tolerance.
        tolerance: f64,
    },
}

impl IgtlError {
    /// Whether the reader is still at a message boundary after this error, so that the
    /// connection can go on (answering with a STATUS). True for errors found after the whole body
    /// was read (unsupported type, content and metadata errors, CRC mismatch); false for header
    /// errors, a stream ending inside a header or body, I/O errors and a refused body size, after
    /// which the connection should be closed.
    pub fn keeps_stream_in_sync(&self) -> bool {
        match self {
            // The framing's own truncations; a section inside the content (e.g. "POLYDATA
            // points") is short within a body that was read whole.
            IgtlError::Truncated { section, .. } => !matches!(*section, "header" | "body"),
            IgtlError::Io(_)
            | IgtlError::UnsupportedVersion { .. }
            | IgtlError::BodyTooLarge { .. } => false,
            // Header name errors are raised before the body is read.
            IgtlError::InvalidName { field, .. } => !matches!(*field, "type name" | "device name"),
            IgtlError::CrcMismatch { .. }
            | IgtlError::NameTooLong { .. }
            | IgtlError::UnsupportedMessageType { .. }
            | IgtlError::InvalidField { .. }
            | IgtlError::ContentSize { .. }
            | IgtlError::NonFinite { .. }
            | IgtlError::UnsupportedMetadataEncoding { .. }
            | IgtlError::MetadataNeedsVersion2 { .. }
            | IgtlError::NotRigid { .. } => true,
        }
    }

    /// The OpenIGTLink status code (see [`status_code`]) that best describes this error.
    pub fn status_code(&self) -> u16 {
        match self {
            IgtlError::UnsupportedMessageType { .. } => status_code::UNKNOWN_INSTRUCTION,
            IgtlError::CrcMismatch { .. } => status_code::CHECKSUM_ERROR,
            IgtlError::BodyTooLarge { .. } => status_code::RESOURCE_ERROR,
            IgtlError::UnsupportedVersion { .. } => status_code::UNKNOWN_VERSION,
            IgtlError::Io(_) | IgtlError::Truncated { .. } => status_code::TIME_OUT,
            _ => status_code::CONFIG_ERROR,
        }
    }

    /// A STATUS message reporting this error: code from [`IgtlError::status_code`], sub-code 0,
    /// error name "Error" (or "Unsupported" for an unsupported type), and this error's text.
    pub fn to_status(&self) -> StatusMessage {
        let error_name = match self {
            IgtlError::UnsupportedMessageType { .. } => "Unsupported",
            _ => "Error",
        };
        StatusMessage {
            code: self.status_code(),
            subcode: 0,
            error_name: error_name.to_owned(),
            message: self.to_string().replace('\0', " "),
        }
    }
}

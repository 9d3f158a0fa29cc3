//! OpenIGTLink codec (protocol version 3.0, header versions 1 and 2): the 58-byte header, the
//! extended header and metadata, and the TRANSFORM, POINT, POLYDATA and STATUS messages, with
//! framing over byte slices and `tokio` streams. A pure codec: no server, no sockets of its own.
//!
//! All numbers are big-endian; lengths are millimetres and times seconds since 1970 (32.32 fixed
//! point). Decoding never panics and bounds-checks every length before using it; see
//! `docs/openigtlink.md` for the protocol subset, units and device names.
//!
//! - [`Header`], [`HeaderVersion`], [`Timestamp`]: the header;
//! - [`crc64()`]: the body checksum (CRC-64/ECMA-182);
//! - [`Metadata`]: header version 2 key/value metadata;
//! - [`Message`], [`Content`], the [`MessageContent`] trait: a message and its body layout;
//! - [`TransformMessage`], [`PointMessage`], [`PolyDataMessage`], [`StatusMessage`] (with
//!   [`status_code`]): the message contents;
//! - [`read_message`], [`write_message`], [`decode_message`] and the raw [`Frame`]s of
//!   [`read_frame`] and [`decode_frame`]: reading and writing messages, with a body size limit;
//! - [`conventions`]: livereg's device names and metadata keys;
//! - [`IgtlError`]: what went wrong.

pub mod conventions;
pub(crate) mod crc64;
pub(crate) mod error;
pub(crate) mod framing;
pub(crate) mod header;
pub(crate) mod message;
pub(crate) mod metadata;
pub(crate) mod point;
pub(crate) mod polydata;
pub(crate) mod status;
pub(crate) mod transform;
mod wire;

pub use crc64::crc64;
pub use error::IgtlError;
pub use framing::{
    decode_frame, decode_message, read_frame, read_message, write_message, Frame, ReceivedMessage,
};
pub use header::{Header, HeaderVersion, Timestamp, HEADER_SIZE};
pub use message::{Content, Message, MessageContent, EXTENDED_HEADER_SIZE};
pub use metadata::{Metadata, MAX_METADATA_ENTRIES};
pub use point::{PointElement, PointMessage};
pub use polydata::{AttributeKind, PolyDataAttribute, PolyDataMessage};
pub use status::{status_code, StatusMessage};
pub use transform::TransformMessage;

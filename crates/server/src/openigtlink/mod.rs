//! OpenIGTLink codec (protocol version 3.0, header versions 1 and 2): the 58-byte header, the
//! extended header and metadata, and the TRANSFORM, POINT, POLYDATA and STATUS messages, with
//! framing over byte slices and `tokio` streams. A pure codec: no server, no sockets of its own.
//!
//! All numbers are big-endian; lengths are millimetres and times seconds since 1970 (32.32 fixed
//! point). Decoding never panics and bounds-checks every length before using it; see
//! `docs/openigtlink.md` for the protocol subset, units and device names.
//!
//! - [`header`]: the header, [`HeaderVersion`], [`Timestamp`];
//! - [`crc64()`]: the body checksum (CRC-64/ECMA-182);
//! - [`metadata`]: header version 2 key/value metadata;
//! - [`message`]: [`Message`], [`Content`], the [`MessageContent`] trait, body layout;
//! - [`transform`], [`point`], [`polydata`], [`status`]: the message contents;
//! - [`framing`]: reading and writing messages, with a body size limit;
//! - [`conventions`]: livereg's device names and metadata keys;
//! - [`IgtlError`], in [`error`].

pub mod conventions;
pub mod crc64;
pub mod error;
pub mod framing;
pub mod header;
pub mod message;
pub mod metadata;
pub mod point;
pub mod polydata;
pub mod status;
pub mod transform;
mod wire;

pub use crc64::crc64;
pub use error::IgtlError;
pub use framing::{
    decode_frame, decode_message, read_frame, read_message, write_message, Frame, ReceivedMessage,
};
pub use header::{Header, HeaderVersion, Timestamp, HEADER_SIZE};
pub use message::{Content, Message, MessageContent, EXTENDED_HEADER_SIZE};
pub use metadata::Metadata;
pub use point::{PointElement, PointMessage};
pub use polydata::{AttributeKind, PolyDataAttribute, PolyDataMessage};
pub use status::{status_code, StatusMessage};
pub use transform::TransformMessage;

//! STATUS (spec "Status Message"): the sender's status or the answer to a failed request.
//!
//! Content, big-endian: `C: u16` status code, `SUB_CODE: i64` (device specific), `ERROR_NAME:
//! char[20]` NUL padded, then `MESSAGE`: the rest of the content, a NUL-terminated string.

use super::error::IgtlError;
use super::message::MessageContent;
use super::wire::{check_text, decode_fixed_str, put_fixed_str, Reader};

/// Size of the fixed part (code, sub-code, error name) of a STATUS content.
pub(crate) const STATUS_FIXED_SIZE: usize = 30;

/// The status codes of the spec ("Status Message", "Status codes"), with the names of the
/// OpenIGTLink library's `IGTL_STATUS_*` constants.
pub mod status_code {
    /// 0: invalid packet (not used).
    pub const INVALID: u16 = 0;
    /// 1: OK (default status).
    pub const OK: u16 = 1;
    /// 2: unknown error.
    pub const UNKNOWN_ERROR: u16 = 2;
    /// 3: panic mode (emergency).
    pub const PANIC_MODE: u16 = 3;
    /// 4: not found (file, configuration, device, …).
    pub const NOT_FOUND: u16 = 4;
    /// 5: access denied.
    pub const ACCESS_DENIED: u16 = 5;
    /// 6: busy.
    pub const BUSY: u16 = 6;
    /// 7: time out / connection lost.
    pub const TIME_OUT: u16 = 7;
    /// 8: overflow / can't be reached.
    pub const OVERFLOW: u16 = 8;
    /// 9: checksum error.
    pub const CHECKSUM_ERROR: u16 = 9;
    /// 10: configuration error.
    pub const CONFIG_ERROR: u16 = 10;
    /// 11: not enough resource (memory, storage, …).
    pub const RESOURCE_ERROR: u16 = 11;
    /// 12: illegal/unknown instruction (feature not implemented, unknown command).
    pub const UNKNOWN_INSTRUCTION: u16 = 12;
    /// 13: device not ready (starting up).
    pub const NOT_READY: u16 = 13;
    /// 14: manual mode (device does not accept commands).
    pub const MANUAL_MODE: u16 = 14;
    /// 15: device disabled.
    pub const DISABLED: u16 = 15;
    /// 16: device not present.
    pub const NOT_PRESENT: u16 = 16;
    /// 17: device version not known.
    pub const UNKNOWN_VERSION: u16 = 17;
    /// 18: hardware failure.
    pub const HARDWARE_FAILURE: u16 = 18;
    /// 19: exiting / shut down in progress.
    pub const SHUT_DOWN: u16 = 19;
}

/// A STATUS message's content.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StatusMessage {
    /// Status code, one of [`status_code`].
    pub code: u16,
    /// Device-specific sub-code.
    pub subcode: i64,
    /// Short error name, e.g. "OK" or "Error" (at most 20 bytes of UTF-8).
    pub error_name: String,
    /// Free text (no NUL inside).
    pub message: String,
}

impl StatusMessage {
    /// An OK status (code 1, error name "OK") with a message.
    pub fn ok(message: impl Into<String>) -> Self {
        Self {
            code: status_code::OK,
            subcode: 0,
            error_name: "OK".to_owned(),
            message: message.into(),
        }
    }
}

impl MessageContent for StatusMessage {
    const TYPE_NAME: &'static str = "STATUS";

    /// Writes 30 bytes of fixed fields, the message and a terminating NUL.
    fn encode_content(&self, out: &mut Vec<u8>) -> Result<(), IgtlError> {
        check_text(&self.message, "STATUS message", false)?;
        out.extend_from_slice(&self.code.to_be_bytes());
        out.extend_from_slice(&self.subcode.to_be_bytes());
        put_fixed_str(out, &self.error_name, 20, "STATUS error name", false)?;
        out.extend_from_slice(self.message.as_bytes());
        out.push(0);
        Ok(())
    }

    /// Reads the fixed fields (content shorter than 30 bytes is [`IgtlError::ContentSize`]); the
    /// message runs to its first NUL, or to the end of the content if it has none.
    fn decode_content(content: &[u8]) -> Result<Self, IgtlError> {
        if content.len() < STATUS_FIXED_SIZE {
            return Err(IgtlError::ContentSize {
                type_name: Self::TYPE_NAME,
                actual: content.len() as u64,
                expected: format!("at least {STATUS_FIXED_SIZE} bytes"),
            });
        }
        let mut reader = Reader::new(content);
        let code = reader.u16("STATUS")?;
        let subcode = reader.i64("STATUS")?;
        let error_name = decode_fixed_str(reader.take(20, "STATUS")?, "STATUS error name", false)?;
        let rest = reader.take(reader.remaining(), "STATUS")?;
        let message = decode_fixed_str(rest, "STATUS message", false)?;
        Ok(Self {
            code,
            subcode,
            error_name,
            message,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_layout() {
        let status = StatusMessage {
            code: status_code::CONFIG_ERROR,
            subcode: -42,
            error_name: "ConfigError".to_owned(),
            message: "no scene loaded — übrigens".to_owned(),
        };
        let mut out = Vec::new();
        status.encode_content(&mut out).unwrap();
        assert_eq!(&out[0..2], &[0, 10]);
        assert_eq!(&out[2..10], &(-42i64).to_be_bytes());
        assert_eq!(&out[10..21], b"ConfigError");
        assert_eq!(out.len(), 30 + status.message.len() + 1);
        assert_eq!(*out.last().unwrap(), 0);
        assert_eq!(StatusMessage::decode_content(&out).unwrap(), status);
        // Without terminator, and with an empty message.
        out.pop();
        assert_eq!(StatusMessage::decode_content(&out).unwrap(), status);
        assert_eq!(
            StatusMessage::decode_content(&out[..30]).unwrap().message,
            ""
        );
    }

    #[test]
    fn errors() {
        assert!(matches!(
            StatusMessage::decode_content(&[0; 29]),
            Err(IgtlError::ContentSize {
                type_name: "STATUS",
                actual: 29,
                ..
            })
        ));
        let mut status = StatusMessage::ok("a\0b");
        assert!(matches!(
            status.encode_content(&mut Vec::new()),
            Err(IgtlError::InvalidName {
                field: "STATUS message",
                ..
            })
        ));
        status.message.clear();
        status.error_name = "e".repeat(21);
        assert!(matches!(
            status.encode_content(&mut Vec::new()),
            Err(IgtlError::NameTooLong {
                field: "STATUS error name",
                ..
            })
        ));
    }
}

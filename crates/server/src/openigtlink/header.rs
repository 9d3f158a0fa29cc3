//! The 58-byte message header (spec "Message Header") and its timestamp (spec "Time Stamp Field
//! in Header").
//!
//! Layout, big-endian, no padding between fields:
//!
//! | offset | size | field       | type                                              |
//! |-------:|-----:|-------------|---------------------------------------------------|
//! | 0      | 2    | V           | u16 header version (1 or 2)                       |
//! | 2      | 12   | TYPE        | `char[12]`, US-ASCII, NUL padded                    |
//! | 14     | 20   | DEVICE_NAME | `char[20]`, US-ASCII, NUL padded                    |
//! | 34     | 8    | TIME_STAMP  | u32 seconds since 1970 UTC, u32 fraction (2⁻³² s) |
//! | 42     | 8    | BODY_SIZE   | u64 bytes of body following the header            |
//! | 50     | 8    | CRC         | u64 CRC-64/ECMA-182 of the body                   |

use super::error::IgtlError;
use super::wire::{decode_fixed_str, put_fixed_str, Reader};

/// Size of the header in bytes.
pub const HEADER_SIZE: usize = 58;
/// Size of the TYPE field in bytes (longest type name).
pub(crate) const TYPE_NAME_SIZE: usize = 12;
/// Size of the DEVICE_NAME field in bytes (longest device name).
pub(crate) const DEVICE_NAME_SIZE: usize = 20;

/// The header version field (spec "Message Header", "Header version number"). It is not the
/// protocol version: protocol versions 1 and 2 use header version 1, protocol version 3 uses
/// header version 2, whose body starts with the extended header and ends with metadata.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum HeaderVersion {
    /// Header version 1 (protocols 1 and 2): the body is the content alone.
    V1 = 1,
    /// Header version 2 (protocol 3): extended header, content, metadata.
    V2 = 2,
}

impl HeaderVersion {
    /// The value of the version field.
    pub fn as_u16(self) -> u16 {
        self as u16
    }

    /// Parses the version field; any value other than 1 or 2 is
    /// [`IgtlError::UnsupportedVersion`].
    pub fn from_u16(version: u16) -> Result<Self, IgtlError> {
        match version {
            1 => Ok(HeaderVersion::V1),
            2 => Ok(HeaderVersion::V2),
            _ => Err(IgtlError::UnsupportedVersion { version }),
        }
    }
}

/// A timestamp: unsigned 32.32 fixed-point seconds since 1970-01-01 00:00:00 UTC (spec "Time
/// Stamp Field in Header"); 0 means "unused". It wraps in 2106.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub struct Timestamp {
    /// Whole seconds since the Unix epoch (the high 32 bits of the field).
    pub seconds: u32,
    /// Fraction of a second in units of 2⁻³² s (the low 32 bits).
    pub fraction: u32,
}

impl Timestamp {
    /// The "unused" timestamp, 0.
    pub const ZERO: Timestamp = Timestamp {
        seconds: 0,
        fraction: 0,
    };

    /// From the 64-bit field.
    pub fn from_u64(raw: u64) -> Self {
        Self {
            seconds: (raw >> 32) as u32,
            fraction: raw as u32,
        }
    }

    /// To the 64-bit field.
    pub fn to_u64(self) -> u64 {
        (u64::from(self.seconds) << 32) | u64::from(self.fraction)
    }

    /// From seconds since the Unix epoch (fraction truncated to 2⁻³² s). Negative and NaN times
    /// give 0; times past the 2106 wrap give the largest timestamp.
    pub fn from_secs_f64(seconds: f64) -> Self {
        if seconds.is_nan() || seconds <= 0.0 {
            return Self::ZERO;
        }
        if seconds >= 4_294_967_296.0 {
            return Self {
                seconds: u32::MAX,
                fraction: u32::MAX,
            };
        }
        let whole = seconds.floor();
        let fraction = ((seconds - whole) * 4_294_967_296.0)
            .floor()
            .min(u32::MAX as f64);
        Self {
            seconds: whole as u32,
            fraction: fraction as u32,
        }
    }

    /// Seconds since the Unix epoch.
    pub fn as_secs_f64(self) -> f64 {
        f64::from(self.seconds) + f64::from(self.fraction) / 4_294_967_296.0
    }

    /// The current system time.
    pub fn now() -> Self {
        let since_epoch = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap_or_default();
        Self::from_secs_f64(since_epoch.as_secs_f64())
    }
}

/// A decoded header. Names are validated (printable US-ASCII, at most 12 and 20 bytes); the body
/// size is checked against the caller's limit by the framing functions, not here.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Header {
    /// The header version.
    pub version: HeaderVersion,
    /// TYPE, e.g. "TRANSFORM" (at most 12 ASCII characters).
    pub type_name: String,
    /// DEVICE_NAME (at most 20 ASCII characters; may be empty).
    pub device_name: String,
    /// TIME_STAMP.
    pub timestamp: Timestamp,
    /// BODY_SIZE in bytes.
    pub body_size: u64,
    /// CRC of the body (CRC-64/ECMA-182, see [`super::crc64()`]).
    pub crc: u64,
}

impl Header {
    /// Decodes the 58 header bytes. Errors: [`IgtlError::UnsupportedVersion`] for a version other
    /// than 1 or 2, [`IgtlError::InvalidName`] for a TYPE or DEVICE_NAME that is not printable
    /// US-ASCII up to its first NUL (a name filling its whole field without NUL is accepted), or
    /// an empty TYPE.
    pub fn decode(bytes: &[u8; HEADER_SIZE]) -> Result<Self, IgtlError> {
        let mut reader = Reader::new(bytes);
        let version = HeaderVersion::from_u16(reader.u16("header")?)?;
        let type_name =
            decode_fixed_str(reader.take(TYPE_NAME_SIZE, "header")?, "type name", true)?;
        if type_name.is_empty() {
            return Err(IgtlError::InvalidName {
                field: "type name",
                reason: "empty".to_owned(),
            });
        }
        let device_name = decode_fixed_str(
            reader.take(DEVICE_NAME_SIZE, "header")?,
            "device name",
            true,
        )?;
        let timestamp = Timestamp::from_u64(reader.u64("header")?);
        let body_size = reader.u64("header")?;
        let crc = reader.u64("header")?;
        Ok(Self {
            version,
            type_name,
            device_name,
            timestamp,
            body_size,
            crc,
        })
    }

    /// Encodes the header. Errors: [`IgtlError::NameTooLong`] or [`IgtlError::InvalidName`] when a
    /// name is too long, empty (TYPE) or not printable US-ASCII.
    pub fn encode(&self) -> Result<[u8; HEADER_SIZE], IgtlError> {
        if self.type_name.is_empty() {
            return Err(IgtlError::InvalidName {
                field: "type name",
                reason: "empty".to_owned(),
            });
        }
        let mut out = Vec::with_capacity(HEADER_SIZE);
        out.extend_from_slice(&self.version.as_u16().to_be_bytes());
        put_fixed_str(&mut out, &self.type_name, TYPE_NAME_SIZE, "type name", true)?;
        put_fixed_str(
            &mut out,
            &self.device_name,
            DEVICE_NAME_SIZE,
            "device name",
            true,
        )?;
        out.extend_from_slice(&self.timestamp.to_u64().to_be_bytes());
        out.extend_from_slice(&self.body_size.to_be_bytes());
        out.extend_from_slice(&self.crc.to_be_bytes());
        let mut bytes = [0u8; HEADER_SIZE];
        bytes.copy_from_slice(&out);
        Ok(bytes)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Header {
        Header {
            version: HeaderVersion::V2,
            type_name: "TRANSFORM".to_owned(),
            device_name: "LiverToReference".to_owned(),
            timestamp: Timestamp {
                seconds: 1_700_000_000,
                fraction: 0x8000_0000,
            },
            body_size: 60,
            crc: 0x0123_4567_89AB_CDEF,
        }
    }

    #[test]
    fn round_trip_and_layout() {
        let bytes = sample().encode().unwrap();
        assert_eq!(&bytes[0..2], &[0, 2]);
        assert_eq!(&bytes[2..11], b"TRANSFORM");
        assert!(bytes[11..14].iter().all(|&b| b == 0));
        assert_eq!(&bytes[14..30], b"LiverToReference");
        assert_eq!(&bytes[34..38], &1_700_000_000u32.to_be_bytes());
        assert_eq!(&bytes[38..42], &[0x80, 0, 0, 0]);
        assert_eq!(&bytes[42..50], &60u64.to_be_bytes());
        assert_eq!(&bytes[50..58], &0x0123_4567_89AB_CDEFu64.to_be_bytes());
        assert_eq!(Header::decode(&bytes).unwrap(), sample());
    }

    #[test]
    fn full_length_names_without_terminator() {
        let mut header = sample();
        header.type_name = "ABCDEFGHIJKL".to_owned();
        header.device_name = "01234567890123456789".to_owned();
        let bytes = header.encode().unwrap();
        assert_eq!(Header::decode(&bytes).unwrap(), header);
        header.device_name.push('X');
        assert!(matches!(
            header.encode(),
            Err(IgtlError::NameTooLong {
                field: "device name",
                length: 21,
                max: 20
            })
        ));
    }

    #[test]
    fn bytes_after_the_terminator_are_padding() {
        let mut bytes = sample().encode().unwrap();
        bytes[12] = b'Z'; // after "TRANSFORM\0"
        assert_eq!(Header::decode(&bytes).unwrap().type_name, "TRANSFORM");
    }

    #[test]
    fn unknown_versions_are_refused() {
        for version in [0u16, 3, 4, 0x0100, u16::MAX] {
            let mut bytes = sample().encode().unwrap();
            bytes[0..2].copy_from_slice(&version.to_be_bytes());
            match Header::decode(&bytes) {
                Err(IgtlError::UnsupportedVersion { version: v }) => assert_eq!(v, version),
                other => panic!("version {version}: {other:?}"),
            }
        }
    }

    #[test]
    fn non_ascii_and_empty_names_are_refused() {
        let mut bytes = sample().encode().unwrap();
        bytes[14] = 0xC3; // UTF-8 lead byte in the device name
        match Header::decode(&bytes) {
            Err(IgtlError::InvalidName { field, reason }) => {
                assert_eq!(field, "device name");
                assert!(
                    reason.contains("0xc3") && reason.contains("position 0"),
                    "{reason}"
                );
            }
            other => panic!("{other:?}"),
        }
        let mut bytes = sample().encode().unwrap();
        bytes[3] = b'\n';
        assert!(matches!(
            Header::decode(&bytes),
            Err(IgtlError::InvalidName {
                field: "type name",
                ..
            })
        ));
        let mut bytes = sample().encode().unwrap();
        bytes[2] = 0;
        assert!(matches!(
            Header::decode(&bytes),
            Err(IgtlError::InvalidName {
                field: "type name",
                ..
            })
        ));
        let mut header = sample();
        header.device_name = "Leber-é".to_owned();
        assert!(matches!(
            header.encode(),
            Err(IgtlError::InvalidName {
                field: "device name",
                ..
            })
        ));
    }

    #[test]
    fn timestamp_conversions() {
        let t = Timestamp::from_secs_f64(1_700_000_000.25);
        assert_eq!(t.seconds, 1_700_000_000);
        assert_eq!(t.fraction, 0x4000_0000);
        assert_eq!(t.as_secs_f64(), 1_700_000_000.25);
        assert_eq!(Timestamp::from_u64(t.to_u64()), t);
        assert_eq!(Timestamp::from_secs_f64(-1.0), Timestamp::ZERO);
        assert_eq!(Timestamp::from_secs_f64(f64::NAN), Timestamp::ZERO);
        assert_eq!(Timestamp::from_secs_f64(1e12).seconds, u32::MAX);
        assert!(Timestamp::now().seconds > 1_600_000_000);
    }
}

//! Big-endian primitives shared by the message codecs: a bounds-checked cursor over a byte slice,
//! fixed-size string fields, and float checks. Crate-private.

use super::error::IgtlError;

/// A cursor over a byte slice; every read checks the remaining length first.
pub(crate) struct Reader<'a> {
    bytes: &'a [u8],
    position: usize,
}

impl<'a> Reader<'a> {
    pub(crate) fn new(bytes: &'a [u8]) -> Self {
        Self { bytes, position: 0 }
    }

    /// Bytes not read yet.
    pub(crate) fn remaining(&self) -> usize {
        self.bytes.len() - self.position
    }

    /// Takes the next `count` bytes, or [`IgtlError::Truncated`] naming `section`.
    pub(crate) fn take(
        &mut self,
        count: usize,
        section: &'static str,
    ) -> Result<&'a [u8], IgtlError> {
        if count > self.remaining() {
            return Err(IgtlError::Truncated {
                section,
                expected: count as u64,
                actual: self.remaining() as u64,
            });
        }
        let slice = &self.bytes[self.position..self.position + count];
        self.position += count;
        Ok(slice)
    }

    pub(crate) fn u8(&mut self, section: &'static str) -> Result<u8, IgtlError> {
        Ok(self.take(1, section)?[0])
    }

    pub(crate) fn u16(&mut self, section: &'static str) -> Result<u16, IgtlError> {
        let b = self.take(2, section)?;
        Ok(u16::from_be_bytes([b[0], b[1]]))
    }

    pub(crate) fn u32(&mut self, section: &'static str) -> Result<u32, IgtlError> {
        let b = self.take(4, section)?;
        Ok(u32::from_be_bytes([b[0], b[1], b[2], b[3]]))
    }

    pub(crate) fn u64(&mut self, section: &'static str) -> Result<u64, IgtlError> {
        let b = self.take(8, section)?;
        let mut a = [0u8; 8];
        a.copy_from_slice(b);
        Ok(u64::from_be_bytes(a))
    }

    pub(crate) fn i64(&mut self, section: &'static str) -> Result<i64, IgtlError> {
        Ok(self.u64(section)? as i64)
    }

    pub(crate) fn f32(&mut self, section: &'static str) -> Result<f32, IgtlError> {
        Ok(f32::from_bits(self.u32(section)?))
    }
}

/// Decodes a fixed-size character field: the text runs to the first NUL, or fills the whole
/// field when there is none (a name of exactly the field's size, as C `strncpy` writes it). Bytes
/// after the first NUL are padding and ignored. The text must be valid UTF-8; with `ascii_only`
/// it must be printable US-ASCII (0x20..=0x7E), as the header's TYPE and DEVICE_NAME are.
pub(crate) fn decode_fixed_str(
    field_bytes: &[u8],
    field: &'static str,
    ascii_only: bool,
) -> Result<String, IgtlError> {
    let end = field_bytes
        .iter()
        .position(|&b| b == 0)
        .unwrap_or(field_bytes.len());
    let text = &field_bytes[..end];
    if ascii_only {
        if let Some(position) = text.iter().position(|&b| !(0x20..=0x7e).contains(&b)) {
            return Err(IgtlError::InvalidName {
                field,
                reason: format!(
                    "byte {:#04x} at position {position} is not printable US-ASCII",
                    text[position]
                ),
            });
        }
    }
    match std::str::from_utf8(text) {
        Ok(s) => Ok(s.to_owned()),
        Err(e) => Err(IgtlError::InvalidName {
            field,
            reason: format!("invalid UTF-8 at byte {}", e.valid_up_to()),
        }),
    }
}

/// Checks a string for a fixed-size field of `size` bytes (NUL padded, NUL termination optional
/// when it fills the field): at most `size` bytes, no NUL inside, printable ASCII if `ascii_only`.
pub(crate) fn check_fixed_str(
    text: &str,
    size: usize,
    field: &'static str,
    ascii_only: bool,
) -> Result<(), IgtlError> {
    if text.len() > size {
        return Err(IgtlError::NameTooLong {
            field,
            length: text.len(),
            max: size,
        });
    }
    check_text(text, field, ascii_only)
}

/// No NUL inside; printable ASCII if `ascii_only`.
pub(crate) fn check_text(
    text: &str,
    field: &'static str,
    ascii_only: bool,
) -> Result<(), IgtlError> {
    if let Some(position) = text
        .bytes()
        .position(|b| b == 0 || (ascii_only && !(0x20..=0x7e).contains(&b)))
    {
        let byte = text.as_bytes()[position];
        return Err(IgtlError::InvalidName {
            field,
            reason: if byte == 0 {
                format!("NUL byte at position {position}")
            } else {
                format!("byte {byte:#04x} at position {position} is not printable US-ASCII")
            },
        });
    }
    Ok(())
}

/// Appends `text` NUL-padded to `size` bytes (after [`check_fixed_str`]).
pub(crate) fn put_fixed_str(
    out: &mut Vec<u8>,
    text: &str,
    size: usize,
    field: &'static str,
    ascii_only: bool,
) -> Result<(), IgtlError> {
    check_fixed_str(text, size, field, ascii_only)?;
    out.extend_from_slice(text.as_bytes());
    out.resize(out.len() + (size - text.len()), 0);
    Ok(())
}

/// Converts a finite f64 to the f32 sent on the wire; NaN, infinities and values beyond the f32
/// range are refused with [`IgtlError::NonFinite`].
pub(crate) fn to_f32(value: f64, field: &'static str, index: usize) -> Result<f32, IgtlError> {
    let single = value as f32;
    if single.is_finite() {
        Ok(single)
    } else {
        Err(IgtlError::NonFinite { field, index })
    }
}

/// Checks a received f32.
pub(crate) fn finite(value: f32, field: &'static str, index: usize) -> Result<f64, IgtlError> {
    if value.is_finite() {
        Ok(f64::from(value))
    } else {
        Err(IgtlError::NonFinite { field, index })
    }
}

/// Converts a length to the u32 of a size or count field.
pub(crate) fn to_u32(value: usize, field: &'static str) -> Result<u32, IgtlError> {
    u32::try_from(value).map_err(|_| IgtlError::InvalidField {
        field,
        value: value as u64,
        expected: format!("at most {}", u32::MAX),
    })
}

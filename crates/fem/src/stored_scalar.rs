//! Numbers as binary files store them: the integer and floating-point types of PLY, VTK XML,
//! NIfTI and NRRD data, their byte order, and their value as an `f64`.
//!
//! Each file format names its types its own way (PLY `uchar`, VTK `UInt8`, NRRD `unsigned
//! char`, NIfTI datatype 2); its reader maps those names onto [`StoredScalar`] and decodes
//! through it, so the byte-level decoding exists once.

/// The storage type of one number in a file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StoredScalar {
    /// `i8`.
    I8,
    /// `u8`.
    U8,
    /// `i16`.
    I16,
    /// `u16`.
    U16,
    /// `i32`.
    I32,
    /// `u32`.
    U32,
    /// `i64`.
    I64,
    /// `u64`.
    U64,
    /// `f32`.
    F32,
    /// `f64`.
    F64,
}

/// Byte order of multi-byte numbers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ByteOrder {
    /// Least significant byte first.
    Little,
    /// Most significant byte first.
    Big,
}

impl ByteOrder {
    /// `Big` when `big_endian`, else `Little`.
    pub fn big_if(big_endian: bool) -> Self {
        if big_endian {
            Self::Big
        } else {
            Self::Little
        }
    }
}

impl StoredScalar {
    /// Bytes per number.
    pub fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::I64 | Self::U64 | Self::F64 => 8,
        }
    }

    /// A floating-point type.
    pub fn is_float(self) -> bool {
        matches!(self, Self::F32 | Self::F64)
    }

    /// The number stored in the first [`Self::size`] bytes of `bytes`, as an `f64` (exact for
    /// every type but 64-bit integers beyond 2⁵³). Panics if `bytes` is shorter than that:
    /// callers slice by `size()`.
    #[inline]
    pub fn decode(self, bytes: &[u8], order: ByteOrder) -> f64 {
        macro_rules! num {
            ($t:ty, $n:expr) => {{
                let a: [u8; $n] = bytes[..$n].try_into().expect("sliced by size()");
                (match order {
                    ByteOrder::Little => <$t>::from_le_bytes(a),
                    ByteOrder::Big => <$t>::from_be_bytes(a),
                }) as f64
            }};
        }
        match self {
            Self::I8 => bytes[0] as i8 as f64,
            Self::U8 => bytes[0] as f64,
            Self::I16 => num!(i16, 2),
            Self::U16 => num!(u16, 2),
            Self::I32 => num!(i32, 4),
            Self::U32 => num!(u32, 4),
            Self::I64 => num!(i64, 8),
            Self::U64 => num!(u64, 8),
            Self::F32 => num!(f32, 4),
            Self::F64 => num!(f64, 8),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every type decodes what the standard library encoded, in both byte orders.
    #[test]
    fn decodes_what_to_bytes_encoded() {
        // (type, value, little-endian bytes, big-endian bytes), encoded by the standard library.
        macro_rules! case {
            ($ty:ident, $t:ty, $v:expr) => {
                (
                    StoredScalar::$ty,
                    ($v as $t) as f64,
                    <$t>::to_le_bytes($v).to_vec(),
                    <$t>::to_be_bytes($v).to_vec(),
                )
            };
        }
        let cases = [
            case!(I8, i8, -5),
            case!(U8, u8, 250),
            case!(I16, i16, -1234),
            case!(U16, u16, 60000),
            case!(I32, i32, -70000),
            case!(U32, u32, 4_000_000_000),
            case!(I64, i64, -(1i64 << 40)),
            case!(U64, u64, 1u64 << 50),
            case!(F32, f32, 1.5),
            case!(F64, f64, -0.1),
        ];
        for (ty, value, le, be) in cases {
            assert_eq!(le.len(), ty.size(), "{ty:?}");
            assert_eq!(ty.decode(&le, ByteOrder::Little), value, "{ty:?} little");
            assert_eq!(ty.decode(&be, ByteOrder::Big), value, "{ty:?} big");
        }
        assert!(StoredScalar::F32.is_float() && !StoredScalar::U64.is_float());
        assert_eq!(ByteOrder::big_if(true), ByteOrder::Big);
    }
}

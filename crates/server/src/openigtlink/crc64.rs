//! The body checksum of the OpenIGTLink header (spec "Message Header", field CRC): CRC-64 as in
//! ECMA-182 — polynomial 0x42F0E1EBA9EA3693, initial value 0, no reflection, no final XOR — over
//! the whole body (extended header, content and metadata). This is the `crc` crate's
//! `CRC_64_ECMA_182` and pyigtl's `crcmod.mkCrcFun(0x142F0E1EBA9EA3693, rev=False, initCrc=0,
//! xorOut=0)`; the tests compare it with an independent bitwise implementation and with pyigtl.

use crc::{Crc, CRC_64_ECMA_182};

const ECMA_182: Crc<u64> = Crc::<u64>::new(&CRC_64_ECMA_182);

/// CRC-64/ECMA-182 of `bytes`, as carried in the header's CRC field. The empty body's CRC is 0.
pub fn crc64(bytes: &[u8]) -> u64 {
    ECMA_182.checksum(bytes)
}

#[cfg(test)]
mod tests {
    use super::crc64;

    /// An independent, bit-at-a-time MSB-first CRC (the textbook long division), written without
    /// the `crc` crate.
    fn bitwise_reference(bytes: &[u8]) -> u64 {
        const POLY: u64 = 0x42F0_E1EB_A9EA_3693;
        let mut register = 0u64;
        for &byte in bytes {
            register ^= u64::from(byte) << 56;
            for _ in 0..8 {
                register = if register & (1 << 63) != 0 {
                    (register << 1) ^ POLY
                } else {
                    register << 1
                };
            }
        }
        register
    }

    #[test]
    fn known_answer_check_string() {
        // The catalogue "check" value of CRC-64/ECMA-182 over ASCII "123456789"; pyigtl's crcmod
        // function gives the same (tests/server/openigtlink_pyigtl.rs checks it live).
        assert_eq!(crc64(b"123456789"), 0x6C40_DF5F_0B49_7347);
        assert_eq!(bitwise_reference(b"123456789"), 0x6C40_DF5F_0B49_7347);
        assert_eq!(crc64(b""), 0);
    }

    #[test]
    fn agrees_with_bitwise_reference() {
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        for length in 0..300usize {
            let bytes: Vec<u8> = (0..length)
                .map(|_| {
                    state ^= state << 13;
                    state ^= state >> 7;
                    state ^= state << 17;
                    (state >> 24) as u8
                })
                .collect();
            assert_eq!(crc64(&bytes), bitwise_reference(&bytes), "length {length}");
        }
    }
}

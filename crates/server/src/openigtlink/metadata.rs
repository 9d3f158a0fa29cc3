//! Header version 2 metadata (spec "Message Header", "Metadata Fields"): key/value pairs at the
//! end of the body.
//!
//! Layout, big-endian: the metadata header (index) is `INDEX_COUNT: u16`, then per entry
//! `KEY_SIZE: u16, VALUE_ENCODING: u16, VALUE_SIZE: u32` (8 bytes); the metadata proper follows
//! with, per entry in index order, the key bytes then the value bytes. The extended header holds
//! the index's size (`METADATA_HEADER_SIZE = 2 + 8 × count`, u16) and the key/value bytes' size
//! (`METADATA_SIZE`, u32). `VALUE_ENCODING` is an IANA MIBenum: 3 = US-ASCII, 106 = UTF-8.
//! Keys are sent as UTF-8 bytes (the spec says ASCII; ASCII keys are the same bytes).

use super::error::IgtlError;
use super::wire::Reader;

/// IANA MIBenum of US-ASCII (ANSI_X3.4-1968), the spec's recommended value encoding.
pub(crate) const ENCODING_US_ASCII: u16 = 3;
/// IANA MIBenum of UTF-8.
pub(crate) const ENCODING_UTF8: u16 = 106;
/// Most entries a message can carry: the index size is a u16 (2 + 8 × 8191 ≤ 65535).
pub const MAX_METADATA_ENTRIES: usize = (u16::MAX as usize - 2) / 8;

/// Metadata of a message: ordered key/value strings, keys unique (inserting an existing key
/// replaces its value; decoding a repeated key keeps the last value, as dict-based readers do).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Metadata {
    entries: Vec<(String, String)>,
}

impl Metadata {
    /// No entries.
    pub fn new() -> Self {
        Self::default()
    }

    /// Number of entries.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// Whether there are no entries.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// The value of `key`, if present.
    pub fn get(&self, key: &str) -> Option<&str> {
        self.entries
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
    }

    /// Sets `key` to `value`, replacing an existing value in place (order kept).
    pub fn insert(&mut self, key: impl Into<String>, value: impl Into<String>) {
        let key = key.into();
        let value = value.into();
        match self.entries.iter_mut().find(|(k, _)| *k == key) {
            Some(entry) => entry.1 = value,
            None => self.entries.push((key, value)),
        }
    }

    /// The entries in order.
    pub fn iter(&self) -> impl Iterator<Item = (&str, &str)> {
        self.entries.iter().map(|(k, v)| (k.as_str(), v.as_str()))
    }

    /// Encodes to `(index, key/value bytes)`. A value is sent as US-ASCII (3) when it is ASCII,
    /// otherwise as UTF-8 (106). Errors when there are more than [`MAX_METADATA_ENTRIES`]
    /// entries, a key exceeds 65535 bytes or the key/value bytes exceed `u32::MAX`.
    pub fn encode(&self) -> Result<(Vec<u8>, Vec<u8>), IgtlError> {
        if self.entries.len() > MAX_METADATA_ENTRIES {
            return Err(IgtlError::InvalidField {
                field: "metadata INDEX_COUNT",
                value: self.entries.len() as u64,
                expected: format!("at most {MAX_METADATA_ENTRIES} entries"),
            });
        }
        let mut index = Vec::with_capacity(2 + 8 * self.entries.len());
        let mut data = Vec::new();
        index.extend_from_slice(&(self.entries.len() as u16).to_be_bytes());
        for (key, value) in &self.entries {
            let key_size = u16::try_from(key.len()).map_err(|_| IgtlError::NameTooLong {
                field: "metadata key",
                length: key.len(),
                max: u16::MAX as usize,
            })?;
            let value_size = u32::try_from(value.len()).map_err(|_| IgtlError::NameTooLong {
                field: "metadata value",
                length: value.len(),
                max: u32::MAX as usize,
            })?;
            let encoding = if value.is_ascii() {
                ENCODING_US_ASCII
            } else {
                ENCODING_UTF8
            };
            index.extend_from_slice(&key_size.to_be_bytes());
            index.extend_from_slice(&encoding.to_be_bytes());
            index.extend_from_slice(&value_size.to_be_bytes());
            data.extend_from_slice(key.as_bytes());
            data.extend_from_slice(value.as_bytes());
        }
        if u32::try_from(data.len()).is_err() {
            return Err(IgtlError::InvalidField {
                field: "METADATA_SIZE",
                value: data.len() as u64,
                expected: format!("at most {}", u32::MAX),
            });
        }
        Ok((index, data))
    }

    /// Decodes from the index (`METADATA_HEADER_SIZE` bytes) and key/value bytes (`METADATA_SIZE`
    /// bytes). An empty index means no metadata. The index must be exactly `2 + 8 × count` bytes
    /// and the sizes it lists must add up to exactly the key/value bytes. Keys are UTF-8; values
    /// are decoded by their encoding (US-ASCII must be ASCII; other encodings are
    /// [`IgtlError::UnsupportedMetadataEncoding`]).
    pub fn decode(index: &[u8], data: &[u8]) -> Result<Self, IgtlError> {
        let mut metadata = Metadata::new();
        if index.is_empty() {
            if !data.is_empty() {
                return Err(IgtlError::InvalidField {
                    field: "METADATA_SIZE",
                    value: data.len() as u64,
                    expected: "0 when METADATA_HEADER_SIZE is 0".to_owned(),
                });
            }
            return Ok(metadata);
        }
        let mut index_reader = Reader::new(index);
        let count = usize::from(index_reader.u16("metadata header")?);
        if index.len() != 2 + 8 * count {
            return Err(IgtlError::InvalidField {
                field: "METADATA_HEADER_SIZE",
                value: index.len() as u64,
                expected: format!("{} (2 + 8 × INDEX_COUNT {count})", 2 + 8 * count),
            });
        }
        let mut sizes = Vec::with_capacity(count);
        let mut total = 0u64;
        for _ in 0..count {
            let key_size = usize::from(index_reader.u16("metadata header")?);
            let encoding = index_reader.u16("metadata header")?;
            let value_size = index_reader.u32("metadata header")?;
            total += key_size as u64 + u64::from(value_size);
            sizes.push((key_size, encoding, value_size as usize));
        }
        if total != data.len() as u64 {
            return Err(IgtlError::InvalidField {
                field: "METADATA_SIZE",
                value: data.len() as u64,
                expected: format!("{total} (sum of KEY_SIZE and VALUE_SIZE of the index)"),
            });
        }
        let mut data_reader = Reader::new(data);
        for (key_size, encoding, value_size) in sizes {
            let key_bytes = data_reader.take(key_size, "metadata key")?;
            let key = std::str::from_utf8(key_bytes)
                .map_err(|e| IgtlError::InvalidName {
                    field: "metadata key",
                    reason: format!("invalid UTF-8 at byte {}", e.valid_up_to()),
                })?
                .to_owned();
            let value_bytes = data_reader.take(value_size, "metadata value")?;
            let value = match encoding {
                ENCODING_US_ASCII if value_bytes.is_ascii() => {
                    String::from_utf8_lossy(value_bytes).into_owned()
                }
                ENCODING_US_ASCII => {
                    return Err(IgtlError::InvalidName {
                        field: "metadata value",
                        reason: format!("value of key {key:?} is declared US-ASCII but is not"),
                    })
                }
                ENCODING_UTF8 => std::str::from_utf8(value_bytes)
                    .map_err(|e| IgtlError::InvalidName {
                        field: "metadata value",
                        reason: format!(
                            "value of key {key:?}: invalid UTF-8 at byte {}",
                            e.valid_up_to()
                        ),
                    })?
                    .to_owned(),
                other => {
                    return Err(IgtlError::UnsupportedMetadataEncoding {
                        key,
                        encoding: other,
                    })
                }
            };
            metadata.insert(key, value);
        }
        Ok(metadata)
    }
}

impl<K: Into<String>, V: Into<String>> FromIterator<(K, V)> for Metadata {
    fn from_iter<I: IntoIterator<Item = (K, V)>>(iter: I) -> Self {
        let mut metadata = Metadata::new();
        for (k, v) in iter {
            metadata.insert(k, v);
        }
        metadata
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_layout() {
        let metadata: Metadata = [("units", "mm"), ("Städte", "Zürich")]
            .into_iter()
            .collect();
        let (index, data) = metadata.encode().unwrap();
        assert_eq!(index.len(), 2 + 16);
        assert_eq!(&index[0..2], &[0, 2]);
        // "units": key 5 bytes, ASCII, value 2 bytes
        assert_eq!(&index[2..10], &[0, 5, 0, 3, 0, 0, 0, 2]);
        // "Städte" (7 UTF-8 bytes), UTF-8, "Zürich" (7 bytes)
        assert_eq!(&index[10..18], &[0, 7, 0, 106, 0, 0, 0, 7]);
        assert_eq!(&data[0..7], b"unitsmm");
        assert_eq!(Metadata::decode(&index, &data).unwrap(), metadata);
        assert_eq!(metadata.get("Städte"), Some("Zürich"));
    }

    #[test]
    fn empty_forms() {
        assert!(Metadata::decode(&[], &[]).unwrap().is_empty());
        assert!(Metadata::decode(&[0, 0], &[]).unwrap().is_empty());
        assert!(matches!(
            Metadata::decode(&[], &[1]),
            Err(IgtlError::InvalidField {
                field: "METADATA_SIZE",
                ..
            })
        ));
    }

    #[test]
    fn inconsistent_sizes_are_refused() {
        let metadata: Metadata = [("k", "v")].into_iter().collect();
        let (index, data) = metadata.encode().unwrap();
        assert!(matches!(
            Metadata::decode(&index[..9], &data),
            Err(IgtlError::InvalidField {
                field: "METADATA_HEADER_SIZE",
                value: 9,
                ..
            })
        ));
        assert!(matches!(
            Metadata::decode(&index, &data[..1]),
            Err(IgtlError::InvalidField {
                field: "METADATA_SIZE",
                value: 1,
                ..
            })
        ));
        let mut bad = index.clone();
        bad[4..6].copy_from_slice(&1000u16.to_be_bytes());
        match Metadata::decode(&bad, &data) {
            Err(IgtlError::UnsupportedMetadataEncoding { key, encoding }) => {
                assert_eq!((key.as_str(), encoding), ("k", 1000));
            }
            other => panic!("{other:?}"),
        }
        let mut not_ascii = data.clone();
        not_ascii[1] = 0xFF;
        assert!(matches!(
            Metadata::decode(&index, &not_ascii),
            Err(IgtlError::InvalidName {
                field: "metadata value",
                ..
            })
        ));
    }

    #[test]
    fn insert_replaces() {
        let mut metadata = Metadata::new();
        metadata.insert("a", "1");
        metadata.insert("b", "2");
        metadata.insert("a", "3");
        assert_eq!(
            metadata.iter().collect::<Vec<_>>(),
            vec![("a", "3"), ("b", "2")]
        );
    }
}

//! Framing: one message at a time from a byte slice or a `tokio` stream, and writing messages.
//!
//! Reading a message goes: 58 header bytes → header checks (version 1 or 2, names) → BODY_SIZE
//! against the caller's `max_body_size`, before any allocation for the body → the body (the
//! async reader grows its buffer with the bytes actually received, never to the announced size
//! up front) → CRC-64 → extended header and metadata → content. Every error after the body was
//! read leaves the stream at the next message ([`IgtlError::keeps_stream_in_sync`]).

use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};

use super::crc64::crc64;
use super::error::IgtlError;
use super::header::{Header, HeaderVersion, HEADER_SIZE};
use super::message::Message;

/// A framed message whose header is decoded and whose body's length and CRC are verified, but
/// whose body is not yet interpreted.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Frame {
    /// The decoded header.
    pub header: Header,
    /// The body (BODY_SIZE bytes).
    pub body: Vec<u8>,
}

impl Frame {
    /// Interprets the body (see [`Message::decode`], less the length and CRC checks already
    /// done when the frame was read); the version is the header's, so a reply can
    /// use the same one.
    pub fn decode(&self) -> Result<ReceivedMessage, IgtlError> {
        Ok(ReceivedMessage {
            version: self.header.version,
            message: Message::decode_checked_body(&self.header, &self.body)?,
        })
    }
}

/// A decoded message with the header version it came with.
#[derive(Debug, Clone, PartialEq)]
pub struct ReceivedMessage {
    /// Header version of the received message.
    pub version: HeaderVersion,
    /// The message.
    pub message: Message,
}

fn check_body_size(header: &Header, max_body_size: u64) -> Result<(), IgtlError> {
    if header.body_size > max_body_size {
        return Err(IgtlError::BodyTooLarge {
            body_size: header.body_size,
            max: max_body_size,
        });
    }
    Ok(())
}

fn check_crc(header: &Header, body: &[u8]) -> Result<(), IgtlError> {
    let computed = crc64(body);
    if computed != header.crc {
        return Err(IgtlError::CrcMismatch {
            expected: header.crc,
            computed,
        });
    }
    Ok(())
}

/// Reads one frame from the start of `bytes`, returning it and the number of bytes it took
/// (header + body). Errors: [`IgtlError::Truncated`] when `bytes` ends inside the header or the
/// body, [`IgtlError::BodyTooLarge`] when BODY_SIZE exceeds `max_body_size`, header errors, and
/// [`IgtlError::CrcMismatch`].
pub fn decode_frame(bytes: &[u8], max_body_size: u64) -> Result<(Frame, usize), IgtlError> {
    let header_bytes: &[u8; HEADER_SIZE] = bytes
        .get(..HEADER_SIZE)
        .and_then(|h| h.try_into().ok())
        .ok_or(IgtlError::Truncated {
            section: "header",
            expected: HEADER_SIZE as u64,
            actual: bytes.len() as u64,
        })?;
    let header = Header::decode(header_bytes)?;
    check_body_size(&header, max_body_size)?;
    let available = (bytes.len() - HEADER_SIZE) as u64;
    if header.body_size > available {
        return Err(IgtlError::Truncated {
            section: "body",
            expected: header.body_size,
            actual: available,
        });
    }
    let end = HEADER_SIZE + header.body_size as usize;
    let body = bytes[HEADER_SIZE..end].to_vec();
    check_crc(&header, &body)?;
    Ok((Frame { header, body }, end))
}

/// Reads and decodes one message from the start of `bytes` (see [`decode_frame`] and
/// [`Message::decode`]), returning it and the number of bytes it took.
pub fn decode_message(
    bytes: &[u8],
    max_body_size: u64,
) -> Result<(ReceivedMessage, usize), IgtlError> {
    let (frame, used) = decode_frame(bytes, max_body_size)?;
    Ok((frame.decode()?, used))
}

/// Reads one frame from `reader`. `Ok(None)` on a clean end of stream before the first header
/// byte; an end of stream inside the header or body is [`IgtlError::Truncated`]. Other errors as
/// [`decode_frame`]. No time limit: wrap the call in `tokio::time::timeout` for one.
pub async fn read_frame<R: AsyncRead + Unpin>(
    reader: &mut R,
    max_body_size: u64,
) -> Result<Option<Frame>, IgtlError> {
    let mut header_bytes = [0u8; HEADER_SIZE];
    let mut filled = 0;
    while filled < HEADER_SIZE {
        let n = reader.read(&mut header_bytes[filled..]).await?;
        if n == 0 {
            if filled == 0 {
                return Ok(None);
            }
            return Err(IgtlError::Truncated {
                section: "header",
                expected: HEADER_SIZE as u64,
                actual: filled as u64,
            });
        }
        filled += n;
    }
    let header = Header::decode(&header_bytes)?;
    check_body_size(&header, max_body_size)?;
    // Start small and grow with what arrives: a peer announcing a large body but sending little
    // costs little memory.
    let mut body = Vec::with_capacity(header.body_size.min(64 * 1024) as usize);
    let read = (&mut *reader)
        .take(header.body_size)
        .read_to_end(&mut body)
        .await?;
    if (read as u64) < header.body_size {
        return Err(IgtlError::Truncated {
            section: "body",
            expected: header.body_size,
            actual: read as u64,
        });
    }
    check_crc(&header, &body)?;
    Ok(Some(Frame { header, body }))
}

/// Reads and decodes one message from `reader` (see [`read_frame`] and [`Frame::decode`]).
pub async fn read_message<R: AsyncRead + Unpin>(
    reader: &mut R,
    max_body_size: u64,
) -> Result<Option<ReceivedMessage>, IgtlError> {
    match read_frame(reader, max_body_size).await? {
        Some(frame) => frame.decode().map(Some),
        None => Ok(None),
    }
}

/// Encodes `message` with header `version` (see [`Message::encode`]) and writes it to `writer`,
/// flushing afterwards.
pub async fn write_message<W: AsyncWrite + Unpin>(
    writer: &mut W,
    message: &Message,
    version: HeaderVersion,
) -> Result<(), IgtlError> {
    let bytes = message.encode(version)?;
    writer.write_all(&bytes).await?;
    writer.flush().await?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::openigtlink::{
        Content, PointElement, PointMessage, PolyDataMessage, StatusMessage, Timestamp,
        TransformMessage,
    };
    use nalgebra::{Matrix4, Point3};

    const MAX: u64 = 1 << 20;

    fn messages() -> Vec<Message> {
        let mut status = Message::new("", StatusMessage::ok("ready"));
        status.metadata.insert("units", "mm");
        let mut all = vec![
            Message::new(
                "Tracker",
                TransformMessage::from_matrix(Matrix4::identity()),
            ),
            Message::new(
                "Fiducials",
                PointMessage {
                    points: vec![PointElement::new("A", Point3::new(1.0, 2.0, 3.0))],
                },
            ),
            Message::new(
                "IntraopCloud",
                PolyDataMessage::from_point_cloud(&[Point3::new(4.0, 5.0, 6.0)], false).unwrap(),
            ),
            status,
        ];
        for (i, message) in all.iter_mut().enumerate() {
            message.timestamp = Timestamp {
                seconds: 1_700_000_000 + i as u32,
                fraction: 12345,
            };
        }
        all
    }

    fn stream() -> Vec<u8> {
        let mut bytes = Vec::new();
        for (i, message) in messages().iter().enumerate() {
            let version = if message.metadata.is_empty() && i % 2 == 0 {
                HeaderVersion::V1
            } else {
                HeaderVersion::V2
            };
            bytes.extend(message.encode(version).unwrap());
        }
        bytes
    }

    #[test]
    fn slice_reads_consecutive_messages() {
        let bytes = stream();
        let mut offset = 0;
        let mut decoded = Vec::new();
        while offset < bytes.len() {
            let (received, used) = decode_message(&bytes[offset..], MAX).unwrap();
            decoded.push(received.message);
            offset += used;
        }
        assert_eq!(decoded, messages());
    }

    #[tokio::test]
    async fn async_reads_consecutive_messages_then_none() {
        let bytes = stream();
        let mut reader = &bytes[..];
        let mut decoded = Vec::new();
        while let Some(received) = read_message(&mut reader, MAX).await.unwrap() {
            decoded.push(received.message);
        }
        assert_eq!(decoded, messages());
    }

    #[tokio::test]
    async fn write_then_read_over_a_duplex_pipe() {
        let (mut client, mut server) = tokio::io::duplex(256);
        let sent = messages();
        let to_send = sent.clone();
        let writer = tokio::spawn(async move {
            for message in &to_send {
                write_message(&mut client, message, HeaderVersion::V2)
                    .await
                    .unwrap();
            }
        });
        for expected in &sent {
            let received = read_message(&mut server, MAX).await.unwrap().unwrap();
            assert_eq!(received.version, HeaderVersion::V2);
            assert_eq!(&received.message, expected);
        }
        writer.await.unwrap();
        assert!(read_message(&mut server, MAX).await.unwrap().is_none());
    }

    #[tokio::test]
    async fn huge_body_size_is_refused_before_reading() {
        let mut bytes = messages()[0].encode(HeaderVersion::V1).unwrap();
        bytes[42..50].copy_from_slice(&(1u64 << 30).to_be_bytes());
        match read_frame(&mut &bytes[..], MAX).await {
            Err(IgtlError::BodyTooLarge { body_size, max }) => {
                assert_eq!((body_size, max), (1 << 30, MAX));
            }
            other => panic!("{other:?}"),
        }
        bytes[42..50].copy_from_slice(&u64::MAX.to_be_bytes());
        assert!(matches!(
            decode_frame(&bytes, MAX),
            Err(IgtlError::BodyTooLarge {
                body_size: u64::MAX,
                ..
            })
        ));
        // A header announcing 1 GB and a limit that allows it: the reader does not allocate
        // 1 GB up front, it fails as truncated once the stream ends.
        bytes[42..50].copy_from_slice(&(1u64 << 30).to_be_bytes());
        assert!(matches!(
            read_frame(&mut &bytes[..], u64::MAX).await,
            Err(IgtlError::Truncated { section: "body", expected, actual: 48 }) if expected == 1 << 30
        ));
    }

    #[tokio::test]
    async fn truncation_and_corruption_give_specific_errors() {
        let bytes = messages()[1].encode(HeaderVersion::V2).unwrap();
        for cut in [1, 30, HEADER_SIZE - 1] {
            assert!(matches!(
                read_frame(&mut &bytes[..cut], MAX).await,
                Err(IgtlError::Truncated {
                    section: "header",
                    ..
                })
            ));
            assert!(matches!(
                decode_frame(&bytes[..cut], MAX),
                Err(IgtlError::Truncated {
                    section: "header",
                    ..
                })
            ));
        }
        for cut in [HEADER_SIZE, HEADER_SIZE + 5, bytes.len() - 1] {
            assert!(matches!(
                read_frame(&mut &bytes[..cut], MAX).await,
                Err(IgtlError::Truncated {
                    section: "body",
                    ..
                })
            ));
            assert!(matches!(
                decode_frame(&bytes[..cut], MAX),
                Err(IgtlError::Truncated {
                    section: "body",
                    ..
                })
            ));
        }
        let mut bad = bytes.clone();
        *bad.last_mut().unwrap() ^= 0x40;
        let error = read_frame(&mut &bad[..], MAX).await.unwrap_err();
        assert!(matches!(error, IgtlError::CrcMismatch { .. }));
        assert!(error.keeps_stream_in_sync());
        let mut bad = bytes.clone();
        bad[0..2].copy_from_slice(&3u16.to_be_bytes());
        let error = decode_frame(&bad, MAX).unwrap_err();
        assert!(matches!(
            error,
            IgtlError::UnsupportedVersion { version: 3 }
        ));
        assert!(!error.keeps_stream_in_sync());
    }

    #[tokio::test]
    async fn malformed_content_keeps_the_stream_in_sync() {
        // A POLYDATA whose NPOINTS exceeds its content, correctly framed and signed.
        let mut bytes = messages()[2].encode(HeaderVersion::V1).unwrap();
        bytes[HEADER_SIZE..HEADER_SIZE + 4].copy_from_slice(&1000u32.to_be_bytes());
        let crc = crc64(&bytes[HEADER_SIZE..]);
        bytes[50..58].copy_from_slice(&crc.to_be_bytes());
        bytes.extend(messages()[0].encode(HeaderVersion::V2).unwrap());
        let mut reader = &bytes[..];
        let error = read_message(&mut reader, MAX).await.unwrap_err();
        assert!(matches!(
            error,
            IgtlError::Truncated {
                section: "POLYDATA points",
                ..
            }
        ));
        assert!(error.keeps_stream_in_sync());
        let next = read_message(&mut reader, MAX).await.unwrap().unwrap();
        assert_eq!(next.message, messages()[0]);
    }

    #[tokio::test]
    async fn unsupported_type_keeps_the_stream_in_sync() {
        let mut image = messages()[0].encode(HeaderVersion::V1).unwrap();
        image[2..14].copy_from_slice(b"STRING\0\0\0\0\0\0");
        let mut bytes = image;
        bytes.extend(messages()[3].encode(HeaderVersion::V2).unwrap());
        let mut reader = &bytes[..];
        let error = read_message(&mut reader, MAX).await.unwrap_err();
        assert!(matches!(
            &error,
            IgtlError::UnsupportedMessageType { type_name, device_name }
                if type_name == "STRING" && device_name == "Tracker"
        ));
        assert!(error.keeps_stream_in_sync());
        let next = read_message(&mut reader, MAX).await.unwrap().unwrap();
        assert!(matches!(next.message.content, Content::Status(_)));
    }

    #[tokio::test]
    async fn random_and_mutated_inputs_never_panic() {
        let mut rng = crate::random::Rng::new(0x2545_F491_4F6C_DD1D);
        let valid = stream();
        let mut outcomes = [0usize; 2];
        for round in 0..4000 {
            let bytes: Vec<u8> = if round % 2 == 0 {
                let length = (rng.next_u64() % 400) as usize;
                (0..length).map(|_| rng.next_u64() as u8).collect()
            } else {
                // Mutate a valid stream: flip bytes, then re-sign the first body so that the
                // mutation reaches the body decoders, not only the CRC check.
                let mut bytes = valid.clone();
                for _ in 0..(1 + rng.next_u64() % 6) {
                    let at = (rng.next_u64() as usize) % bytes.len();
                    bytes[at] = rng.next_u64() as u8;
                }
                let body_size = u64::from_be_bytes(bytes[42..50].try_into().unwrap());
                if let Some(body) = usize::try_from(body_size)
                    .ok()
                    .and_then(|n| bytes.get(HEADER_SIZE..HEADER_SIZE.checked_add(n)?))
                {
                    let crc = crc64(body);
                    bytes[50..58].copy_from_slice(&crc.to_be_bytes());
                }
                let cut = (rng.next_u64() as usize) % (bytes.len() + 1);
                bytes.truncate(cut.max(bytes.len() / 2));
                bytes
            };
            let slice_result = decode_message(&bytes, MAX);
            outcomes[usize::from(slice_result.is_ok())] += 1;
            let mut reader = &bytes[..];
            // Bounded: each successful read consumes at least the 58 header bytes.
            for _ in 0..bytes.len() / HEADER_SIZE + 1 {
                match read_message(&mut reader, MAX).await {
                    Ok(Some(_)) => {}
                    Ok(None) => break,
                    Err(e) if e.keeps_stream_in_sync() => {}
                    Err(_) => break,
                }
            }
        }
        // Both paths were exercised.
        assert!(outcomes[0] > 0 && outcomes[1] > 0, "{outcomes:?}");
    }
}

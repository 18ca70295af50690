//! One frame ⇄ bytes: `COBS( version ‖ postcard(frame) ‖ CRC-32C_le(version ‖ postcard) ) ‖ 0x00`.
//! Both directions work in caller buffers and never allocate.

use super::{Frame, LinkError, Rejection, LINK_VERSION, MAX_FRAME_BODY, MAX_FRAME_ENCODED};

/// CRC-32C (Castagnoli, `CRC_32_ISCSI`), the CRC postcard's `use-crc` flavours use; it detects
/// every burst of up to 32 bits and, for frames of this length, every error of up to 5 bits.
///
/// Computed here with the `crc` crate rather than through postcard's `to_slice_crc32` /
/// `from_bytes_crc32` (so the workspace does not enable postcard's `use-crc`): the frame CRC
/// covers the version byte, which is outside postcard's payload, and the receiver must check
/// the CRC *before* the version and the postcard layout, reporting both CRC values
/// ([`Rejection::Crc`]) and refusing trailing bytes. postcard's CRC flavour deserialises first
/// and then reports a bare `DeserializeBadCrc` (a damaged frame would be counted as `Decode`),
/// and ignores bytes after the CRC. The encoder could use it with a digest pre-fed with the
/// version byte (same bytes), but one CRC path for both directions is simpler to keep right.
pub const CRC: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISCSI);

/// Encodes `frame` with the current [`LINK_VERSION`] into `out`, delimiter included, and
/// returns the number of bytes written. `out` of [`MAX_FRAME_ENCODED`] bytes always suffices.
pub fn encode(frame: &Frame, out: &mut [u8]) -> Result<usize, LinkError> {
    encode_with_version(LINK_VERSION, frame, out)
}

/// Like [`encode`] with an explicit version byte: for the version-mismatch tests and for
/// speaking to an older peer.
pub fn encode_with_version(version: u8, frame: &Frame, out: &mut [u8]) -> Result<usize, LinkError> {
    frame.validate().map_err(LinkError::Invalid)?;
    let mut body = [0u8; MAX_FRAME_BODY];
    body[0] = version;
    let n = postcard::to_slice(frame, &mut body[1..MAX_FRAME_BODY - 4])
        .map_err(|_| LinkError::Serialize)?
        .len();
    let crc = CRC.checksum(&body[..1 + n]);
    body[1 + n..1 + n + 4].copy_from_slice(&crc.to_le_bytes());
    let body = &body[..1 + n + 4];
    // COBS adds one byte per started 254-byte block; plus the delimiter.
    let needed = body.len() + body.len() / 254 + 2;
    debug_assert!(needed <= MAX_FRAME_ENCODED);
    if out.len() < needed {
        return Err(LinkError::BufferTooSmall {
            needed,
            got: out.len(),
        });
    }
    let used = cobs::try_encode(body, out).map_err(|_| LinkError::BufferTooSmall {
        needed,
        got: out.len(),
    })?;
    out[used] = 0;
    Ok(used + 1)
}

/// Appends `frame`, encoded with the current [`LINK_VERSION`] and delimiter included, to the
/// fixed-capacity `out` (e.g. a transmit buffer collecting several frames) and returns the
/// number of bytes appended. If the frame does not fit in the remaining capacity, `out` is left
/// as it was and the error is [`LinkError::BufferTooSmall`] with `got` = the remaining capacity.
/// An empty `heapless::Vec<u8, MAX_FRAME_ENCODED>` always suffices.
pub fn encode_into<const N: usize>(
    frame: &Frame,
    out: &mut heapless::Vec<u8, N>,
) -> Result<usize, LinkError> {
    encode_into_with_version(LINK_VERSION, frame, out)
}

/// Like [`encode_into`] with an explicit version byte (see [`encode_with_version`]).
pub fn encode_into_with_version<const N: usize>(
    version: u8,
    frame: &Frame,
    out: &mut heapless::Vec<u8, N>,
) -> Result<usize, LinkError> {
    let start = out.len();
    // Expose the spare capacity as a slice (filling to N cannot exceed the capacity), encode
    // into it, then keep exactly the bytes written.
    out.resize(N, 0).map_err(|_| LinkError::Serialize)?;
    let result = encode_with_version(version, frame, &mut out[start..]);
    out.truncate(start + *result.as_ref().unwrap_or(&0));
    result
}

/// Decodes the COBS bytes of one frame (delimiter stripped) in place and checks length, CRC,
/// version, postcard layout (no bytes left over) and content.
pub fn decode(encoded: &mut [u8]) -> Result<Frame, Rejection> {
    let len = cobs::decode_in_place(encoded).map_err(|_| Rejection::Cobs)?;
    let body = &encoded[..len];
    if len < 1 + 1 + 4 {
        return Err(Rejection::TooShort { len });
    }
    let (payload, trailer) = body.split_at(len - 4);
    let received = u32::from_le_bytes([trailer[0], trailer[1], trailer[2], trailer[3]]);
    let computed = CRC.checksum(payload);
    if computed != received {
        return Err(Rejection::Crc { computed, received });
    }
    if payload[0] != LINK_VERSION {
        return Err(Rejection::Version { found: payload[0] });
    }
    let (frame, rest) =
        postcard::take_from_bytes::<Frame>(&payload[1..]).map_err(|_| Rejection::Decode)?;
    if !rest.is_empty() {
        return Err(Rejection::Decode);
    }
    frame.validate().map_err(Rejection::Invalid)?;
    // The hello's version field repeats the frame's version byte: a disagreement is an
    // inconsistent (or forged) identity, refused rather than trusted.
    if let Frame::Hello(h) = frame {
        if h.protocol_version != u16::from(payload[0]) {
            return Err(Rejection::HelloVersionMismatch {
                frame_version: payload[0],
                hello_version: h.protocol_version,
            });
        }
    }
    Ok(frame)
}

//! Encoding a [`ModelRecord`] into a caller's buffer and decoding one, borrowed and validated,
//! from bytes. Neither direction allocates.
//!
//! Encoding uses the record's serde derive (postcard). Decoding walks the payload field by field
//! in the same order, so a malformed payload is reported with the field it broke in; the test
//! suite checks that the walk and postcard's own `from_bytes` agree on arbitrary payloads.

use postcard::de_flavors::Slice;
use postcard::Deserializer;
use serde::Deserialize;

use super::container::{self, HEADER_LEN};
use super::error::{Capacity, Field, MalformedKind, ModelError};
use super::record::{
    Blend, F32s, ModelRecord, ParameterLayout, ParameterSets, Provenance, U32s, Units,
};
use super::validate::validate;

/// Bytes [`encode`] writes for `record`: header, payload and CRC. Does not validate.
pub fn encoded_len(record: &ModelRecord) -> Result<usize, ModelError> {
    let payload = postcard::serialize_with_flavor(record, postcard::ser_flavors::Size::default())
        .map_err(|e| ModelError::Malformed {
        field: Field::Record,
        kind: e.into(),
    })?;
    container::container_len(payload)
}

/// Validates `record` (see [`validate`](super::validate)) and writes it as a model container
/// into the front of `out`; returns the number of bytes written. Never allocates; a short `out`
/// gives [`ModelError::CapacityExceeded`] with [`Capacity::OutputBuffer`] and leaves `out` in an
/// unspecified state. An invalid record is never written, so whatever `encode` writes decodes.
pub fn encode(record: &ModelRecord, out: &mut [u8]) -> Result<usize, ModelError> {
    validate(record)?;
    let total = encoded_len(record)?;
    let available = out.len();
    let out = out.get_mut(..total).ok_or(ModelError::CapacityExceeded {
        what: Capacity::OutputBuffer,
        needed: total,
        available,
    })?;
    let payload_len = total - HEADER_LEN - container::CRC_LEN;
    let written = postcard::to_slice(record, &mut out[HEADER_LEN..HEADER_LEN + payload_len])
        .map_err(|e| ModelError::Malformed {
            field: Field::Record,
            kind: e.into(),
        })?
        .len();
    if written != payload_len {
        // serialized_size and to_slice run the same serializer; a difference is a postcard bug,
        // reported rather than written as a container with a wrong length.
        return Err(ModelError::Malformed {
            field: Field::Record,
            kind: MalformedKind::BadEncoding,
        });
    }
    // container_len checked that the payload length fits u32.
    Ok(container::seal(out, payload_len as u32))
}

/// Parses a model container, checks its CRC, deserialises the record borrowing all arrays and
/// strings from `bytes` (no copy, no allocation) and validates it: a model that decodes is safe
/// to run. Errors say what is wrong and where (see [`ModelError`]).
pub fn decode(bytes: &[u8]) -> Result<ModelRecord<'_>, ModelError> {
    let payload = container::open(bytes)?;
    let record = decode_payload(payload)?;
    validate(&record)?;
    Ok(record)
}

/// Deserialises a payload field by field (the order of `ModelRecord`'s serde derive).
fn decode_payload(payload: &[u8]) -> Result<ModelRecord<'_>, ModelError> {
    let mut w = Walker {
        de: Deserializer::from_flavor(Slice::new(payload)),
    };
    let units = match w.variant(Field::Units)? {
        0 => Units::Si,
        found => return Err(unknown(Field::Units, found)),
    };
    let provenance = Provenance {
        tool: w.take(Field::ProvenanceTool)?,
        created: w.take(Field::ProvenanceCreated)?,
        source: w.take(Field::ProvenanceSource)?,
        notes: w.take(Field::ProvenanceNotes)?,
    };
    let node_count = w.take(Field::NodeCount)?;
    let element_count = w.take(Field::ElementCount)?;
    let rest_positions = F32s(w.take(Field::RestPositions)?);
    let node_tags = U32s(w.take(Field::NodeTags)?);
    let tets = U32s(w.take(Field::Tets)?);
    let fixed_nodes = U32s(w.take(Field::FixedNodes)?);
    let surface_triangles = U32s(w.take(Field::SurfaceTriangles)?);
    let c_packed = F32s(w.take(Field::CPacked)?);
    let d_packed = F32s(w.take(Field::DPacked)?);
    let layout = match w.variant(Field::ParameterLayout)? {
        0 => ParameterLayout::Global,
        1 => ParameterLayout::PerElement,
        found => return Err(unknown(Field::ParameterLayout, found)),
    };
    let parameters = ParameterSets {
        layout,
        count: w.take(Field::ParameterCount)?,
        lambda: F32s(w.take(Field::Lambda)?),
        alpha: F32s(w.take(Field::Alpha)?),
    };
    let blend = match w.variant(Field::Blend)? {
        0 => Blend::None,
        1 => Blend::Deformation {
            centres: F32s(w.take(Field::BlendCentres)?),
            weights_lambda: F32s(w.take(Field::BlendWeightsLambda)?),
            weights_alpha: F32s(w.take(Field::BlendWeightsAlpha)?),
        },
        2 => Blend::Strain {
            decay: w.take(Field::StrainDecay)?,
            neighbours: w.take(Field::StrainNeighbours)?,
            neighbour_index: U32s(w.take(Field::NeighbourIndex)?),
            neighbour_weight: F32s(w.take(Field::NeighbourWeight)?),
            centres: F32s(w.take(Field::BlendCentres)?),
            weights_lambda: F32s(w.take(Field::BlendWeightsLambda)?),
            weights_alpha: F32s(w.take(Field::BlendWeightsAlpha)?),
        },
        found => return Err(unknown(Field::Blend, found)),
    };
    let rest = w.de.finalize().map_err(|e| ModelError::Malformed {
        field: Field::Record,
        kind: e.into(),
    })?;
    if !rest.is_empty() {
        return Err(ModelError::PayloadTrailingBytes { extra: rest.len() });
    }
    Ok(ModelRecord {
        units,
        provenance,
        node_count,
        element_count,
        rest_positions,
        node_tags,
        tets,
        fixed_nodes,
        surface_triangles,
        c_packed,
        d_packed,
        parameters,
        blend,
    })
}

fn unknown(field: Field, found: u32) -> ModelError {
    ModelError::Malformed {
        field,
        kind: MalformedKind::UnknownVariant { found },
    }
}

/// A postcard deserializer that names the field it is reading when it fails.
struct Walker<'de> {
    de: Deserializer<'de, Slice<'de>>,
}

impl<'de> Walker<'de> {
    fn take<T: Deserialize<'de>>(&mut self, field: Field) -> Result<T, ModelError> {
        T::deserialize(&mut self.de).map_err(|e| ModelError::Malformed {
            field,
            kind: e.into(),
        })
    }

    /// An enum discriminant: postcard writes the variant index as a varint u32.
    fn variant(&mut self, field: Field) -> Result<u32, ModelError> {
        self.take::<u32>(field)
    }
}

//! Round trips (model → bytes → model, exact) and the exact bytes of the tiny model documented
//! in `MODEL-FORMAT.md`.

mod common;

use common::{grid_mesh, model_on, tiny_model, BlendKind, Encoded};
use palpate_protocol::model::{decode, encode, encoded_len, Capacity, ModelError, ParameterLayout};

/// Every blend variant with every parameter layout round-trips exactly (PartialEq on the whole
/// record, so every field and every byte of every array), borrows its arrays from the input
/// (zero-copy) and re-encodes to the same bytes.
#[test]
fn round_trip_all_blends_and_layouts() {
    let mesh = grid_mesh(2, 1, 1, 0.05);
    for layout in [ParameterLayout::Global, ParameterLayout::PerElement] {
        for blend in [BlendKind::None, BlendKind::Deformation, BlendKind::Strain] {
            let owned = model_on(&mesh, layout, blend, 3);
            let record = owned.record();
            let bytes = owned.encode();
            assert_eq!(bytes.len(), encoded_len(&record).unwrap());
            let decoded = decode(&bytes).unwrap_or_else(|e| panic!("{layout:?}/{blend:?}: {e}"));
            assert_eq!(decoded, record, "{layout:?}/{blend:?}");
            // Zero-copy: the decoded arrays point into `bytes`.
            let range = bytes.as_ptr_range();
            assert!(range.contains(&decoded.c_packed.0.as_ptr()));
            assert!(range.contains(&decoded.provenance.notes.as_ptr()));
            let mut again = vec![0u8; bytes.len()];
            assert_eq!(encode(&decoded, &mut again).unwrap(), bytes.len());
            assert_eq!(again, bytes);
        }
    }
}

/// A larger model (6 × 4 × 3 cubes, 432 tets, 3 sets of per-element strain blending) also
/// round-trips: multi-byte varint lengths everywhere.
#[test]
fn round_trip_larger_model() {
    let mesh = grid_mesh(6, 4, 3, 0.01);
    let owned = model_on(&mesh, ParameterLayout::PerElement, BlendKind::Strain, 3);
    let bytes = owned.encode();
    assert_eq!(decode(&bytes).unwrap(), owned.record());
}

/// `encode` into a buffer one byte short reports exactly what it needed; a longer buffer is
/// written at its front.
#[test]
fn encode_capacity() {
    let owned = tiny_model();
    let record = owned.record();
    let len = encoded_len(&record).unwrap();
    let mut short = vec![0u8; len - 1];
    assert_eq!(
        encode(&record, &mut short),
        Err(ModelError::CapacityExceeded {
            what: Capacity::OutputBuffer,
            needed: len,
            available: len - 1
        })
    );
    let mut long = vec![0xAAu8; len + 10];
    assert_eq!(encode(&record, &mut long).unwrap(), len);
    assert_eq!(&long[len..], &[0xAA; 10]);
    assert_eq!(decode(&long[..len]).unwrap(), record);
}

fn varint(mut v: usize, out: &mut Vec<u8>) {
    while v >= 0x80 {
        out.push((v as u8 & 0x7F) | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

fn bytes_field(b: &[u8], out: &mut Vec<u8>) {
    varint(b.len(), out);
    out.extend_from_slice(b);
}

/// The tiny model's bytes built by hand from the rules in `MODEL-FORMAT.md` (varints, byte
/// strings, discriminants), independently of the encoder.
fn tiny_model_by_hand() -> Vec<u8> {
    let m = tiny_model();
    let mut p = Vec::new();
    p.push(0x00); // units = Si
    bytes_field(b"palpate", &mut p);
    bytes_field(b"2026-11-22", &mut p);
    bytes_field(b"unit tet", &mut p);
    bytes_field(b"", &mut p);
    p.push(4); // node_count
    p.push(1); // element_count
    for arr in [
        &m.rest_positions,
        &m.node_tags,
        &m.tets,
        &m.fixed_nodes,
        &m.surface_triangles,
        &m.c_packed,
        &m.d_packed,
    ] {
        bytes_field(arr, &mut p);
    }
    p.push(0x00); // layout = Global
    p.push(1); // count
    bytes_field(&20_000f32.to_le_bytes(), &mut p);
    bytes_field(&6_000f32.to_le_bytes(), &mut p);
    p.push(0x00); // blend = None
    let mut out = b"PALP".to_vec();
    out.extend_from_slice(&[0x01, 0x00, 0x01, 0x00]);
    out.extend_from_slice(&(p.len() as u32).to_le_bytes());
    out.extend_from_slice(&p);
    let crc = common::crc32c(&out);
    out.extend_from_slice(&crc.to_le_bytes());
    out
}

/// The hex dump between the markers in MODEL-FORMAT.md, as bytes.
fn documented_tiny_model() -> Vec<u8> {
    let doc = include_str!("../MODEL-FORMAT.md");
    let start = doc
        .find("<!-- tiny-model-hex-begin -->")
        .expect("begin marker");
    let end = doc.find("<!-- tiny-model-hex-end -->").expect("end marker");
    let mut out = Vec::new();
    for line in doc[start..end]
        .lines()
        .filter(|l| l.len() > 6 && l.as_bytes()[4] == b':')
    {
        for h in line[5..].split_whitespace() {
            out.push(
                u8::from_str_radix(h, 16).unwrap_or_else(|_| panic!("bad hex {h:?} in {line:?}")),
            );
        }
    }
    out
}

/// `oooo: xx xx …` lines of 16 bytes, the format of the dump in MODEL-FORMAT.md.
fn hex_dump(bytes: &[u8]) -> String {
    let mut s = String::new();
    for (i, chunk) in bytes.chunks(16).enumerate() {
        s += &format!("{:04x}:", 16 * i);
        for b in chunk {
            s += &format!(" {b:02x}");
        }
        s += "\n";
    }
    s
}

/// Exact bytes: the encoder's output equals the hand-built bytes and the documented hex dump.
#[test]
fn tiny_model_exact_bytes() {
    let encoded = tiny_model().encode();
    let by_hand = tiny_model_by_hand();
    assert_eq!(encoded, by_hand);
    if encoded != documented_tiny_model() {
        panic!(
            "MODEL-FORMAT.md's hex dump differs from the encoder; the encoder writes:\n{}",
            hex_dump(&encoded)
        );
    }
    // Spot checks against the spec's offsets: header, 312-byte C_e as varint b8 02.
    assert_eq!(
        &encoded[..12],
        &[
            0x50,
            0x41,
            0x4c,
            0x50,
            1,
            0,
            1,
            0,
            (encoded.len() - 16) as u8,
            ((encoded.len() - 16) >> 8) as u8,
            0,
            0
        ]
    );
    assert_eq!(encoded.len(), 834);
    assert_eq!(decode(&encoded).unwrap(), tiny_model().record());
}

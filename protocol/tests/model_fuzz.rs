//! Property tests: `decode` never panics, whatever the bytes, and whatever it accepts is valid,
//! re-encodes, and agrees with postcard's own deserialiser.

mod common;

use common::{grid_mesh, model_on, reseal, tiny_model, wrap, BlendKind, Encoded};
use palpate_protocol::model::{decode, encode, validate, ModelError, ModelRecord, ParameterLayout};
use proptest::prelude::*;

/// Valid models of every blend kind and layout (small, so many cases run quickly).
fn seeds() -> Vec<Vec<u8>> {
    let mesh = grid_mesh(1, 1, 1, 0.02);
    let mut out = vec![tiny_model().encode()];
    for layout in [ParameterLayout::Global, ParameterLayout::PerElement] {
        for blend in [BlendKind::None, BlendKind::Deformation, BlendKind::Strain] {
            out.push(model_on(&mesh, layout, blend, 2).encode());
        }
    }
    out
}

/// Whatever `decode` accepts must be valid and survive encode → decode unchanged.
fn check_accepted(bytes: &[u8]) {
    if let Ok(record) = decode(bytes) {
        assert_eq!(validate(&record), Ok(()));
        let mut out = vec![0u8; bytes.len() + 64];
        let n = encode(&record, &mut out).expect("a decoded model re-encodes");
        assert_eq!(decode(&out[..n]).unwrap(), record);
    }
}

/// The field walk in `decode` and postcard's serde derive agree on every payload: both accept
/// (with the same record, up to trailing bytes) or both reject.
fn check_against_postcard(payload: &[u8]) {
    let container = wrap(payload);
    let ours = decode(&container);
    let theirs = postcard::take_from_bytes::<ModelRecord>(payload);
    match (&ours, &theirs) {
        (Err(ModelError::Malformed { .. }), Err(_)) => {}
        (Err(ModelError::PayloadTrailingBytes { extra }), Ok((_, rest))) => {
            assert_eq!(*extra, rest.len())
        }
        (Ok(r), Ok((p, rest))) => {
            assert!(rest.is_empty());
            assert_eq!(r, p);
        }
        // Parsed by both, then rejected by validation.
        (Err(ModelError::InvalidContent { .. }), Ok((p, rest))) => {
            assert!(rest.is_empty());
            assert!(validate(p).is_err());
        }
        _ => panic!("decode {ours:?} vs postcard {theirs:?}"),
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    #[test]
    fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..600)) {
        check_accepted(&bytes);
    }

    /// Arbitrary bytes behind a valid header prefix, so the length and CRC checks run.
    #[test]
    fn arbitrary_bytes_after_header_never_panic(rest in proptest::collection::vec(any::<u8>(), 0..600)) {
        let mut bytes = b"PALP\x01\x00\x01\x00".to_vec();
        bytes.extend_from_slice(&((rest.len().saturating_sub(8)) as u32).to_le_bytes());
        bytes.extend_from_slice(&rest);
        check_accepted(&bytes);
    }

    /// Valid containers around arbitrary payloads (correct CRC), so the payload parser and the
    /// validator see garbage.
    #[test]
    fn arbitrary_payloads_never_panic(payload in proptest::collection::vec(any::<u8>(), 0..600)) {
        check_accepted(&wrap(&payload));
        check_against_postcard(&payload);
    }

    /// Byte mutations of valid models, with the CRC left alone (detected as corruption) or
    /// recomputed (so the mutation reaches the parser and the validator).
    #[test]
    fn mutated_models_never_panic(
        seed in 0usize..7,
        edits in proptest::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..6),
        fix_crc in any::<bool>(),
    ) {
        let mut bytes = seeds().swap_remove(seed);
        for (at, value) in &edits {
            let i = at.index(bytes.len());
            bytes[i] = *value;
        }
        let original_len = bytes.len();
        if fix_crc {
            reseal(&mut bytes);
            let payload = &bytes[12..original_len - 4];
            check_against_postcard(payload);
        } else {
            // Without a fixed CRC an edit outside the header can only be a CRC mismatch.
            if edits.iter().all(|(at, _)| at.index(original_len) >= 12) && decode(&bytes).is_err() {
                let crc_error = matches!(decode(&bytes), Err(ModelError::CrcMismatch { .. }));
                prop_assert!(crc_error);
            }
        }
        check_accepted(&bytes);
    }

    /// Payload mutations that keep a correct CRC: a changed f32 or index somewhere in a valid
    /// model is either still valid or rejected with a typed error, never a panic.
    #[test]
    fn mutated_payload_words(
        seed in 0usize..7,
        at in any::<prop::sample::Index>(),
        word in prop_oneof![
            Just(f32::NAN.to_bits()), Just(f32::INFINITY.to_bits()), Just((-1.0f32).to_bits()),
            Just(0u32), Just(u32::MAX), any::<u32>()
        ],
    ) {
        let mut bytes = seeds().swap_remove(seed);
        let n = bytes.len();
        let i = 12 + at.index(n - 16 - 3);
        bytes[i..i + 4].copy_from_slice(&word.to_le_bytes());
        reseal(&mut bytes);
        check_accepted(&bytes);
        check_against_postcard(&bytes[12..n - 4]);
    }

    /// Truncation or extension at any length gives Truncated / TrailingBytes, never a panic.
    #[test]
    fn resized_models(seed in 0usize..7, cut in any::<prop::sample::Index>(), extra in 1usize..20) {
        let bytes = seeds().swap_remove(seed);
        let len = cut.index(bytes.len());
        let needed = if len < 12 { 12 } else { bytes.len() };
        prop_assert_eq!(decode(&bytes[..len]), Err(ModelError::Truncated { needed, available: len }));
        let mut longer = bytes.clone();
        longer.extend(std::iter::repeat_n(0u8, extra));
        prop_assert_eq!(decode(&longer), Err(ModelError::TrailingBytes { extra }));
    }
}

//! Every `ModelError` variant produced by a targeted corruption, with the exact error expected.

mod common;

use common::{
    grid_mesh, model_on, reseal, set_f32, set_u32, tiny_model, u32_bytes, wrap, BlendKind, Encoded,
    OwnedBlend, OwnedModel,
};
use palpate_protocol::model::{
    decode, encode, node_coverage_scratch_len, validate, validate_node_coverage, Capacity, Field,
    Invalid, MalformedKind, ModelError, ParameterLayout,
};

fn invalid(what: Invalid) -> Result<(), ModelError> {
    Err(ModelError::InvalidContent { what })
}

/// What `decode` says of a field it cannot read.
fn malformed<T>(field: Field, kind: MalformedKind) -> Result<T, ModelError> {
    Err(ModelError::Malformed { field, kind })
}

/// What `validate` says of a value that is not a finite number.
fn non_finite(array: Field, position: u64) -> Result<(), ModelError> {
    invalid(Invalid::NonFinite { array, position })
}

/// Decodes the unvalidated encoding of `m` (a well-formed container with a correct CRC) and
/// checks that `decode`, `validate` and `encode` all report the same content error.
fn content_error(m: &OwnedModel) -> ModelError {
    let bytes = m.encode_unchecked();
    let err = decode(&bytes).expect_err("corrupted model decoded");
    assert_eq!(validate(&m.record()).map(|_| ()), Err(err));
    let mut out = vec![0u8; bytes.len()];
    assert_eq!(
        encode(&m.record(), &mut out),
        Err(err),
        "encode must refuse what decode refuses"
    );
    err
}

/// One hexahedron (five tetrahedra), global parameters, two sets blended by `blend`.
fn cube(blend: BlendKind) -> OwnedModel {
    model_on(&grid_mesh(1, 1, 1, 0.05), ParameterLayout::Global, blend, 2)
}

fn grid() -> OwnedModel {
    model_on(
        &grid_mesh(2, 2, 1, 0.05),
        ParameterLayout::Global,
        BlendKind::None,
        1,
    )
}

#[test]
fn crc_is_crc32c() {
    // The standard check value of CRC-32C (iSCSI), as stated in MODEL-FORMAT.md.
    assert_eq!(common::crc32c(b"123456789"), 0xE306_9283);
}

#[test]
fn bad_magic() {
    let mut b = tiny_model().encode();
    b[0] = b'X';
    assert_eq!(decode(&b), Err(ModelError::BadMagic { found: *b"XALP" }));
    let e = decode(&b).unwrap_err().to_string();
    assert_eq!(
        e,
        "not a palpate model: magic bytes are 58 41 4c 50, expected \"PALP\""
    );
}

#[test]
fn unsupported_version_and_wrong_kind() {
    let good = tiny_model().encode();
    for v in [0u16, 2, 0xFFFF] {
        let mut b = good.clone();
        b[4..6].copy_from_slice(&v.to_le_bytes());
        reseal(&mut b);
        assert_eq!(
            decode(&b),
            Err(ModelError::UnsupportedVersion {
                found: v,
                supported: 1
            })
        );
    }
    let mut b = good.clone();
    b[6..8].copy_from_slice(&2u16.to_le_bytes());
    reseal(&mut b);
    assert_eq!(decode(&b), Err(ModelError::WrongKind { found: 2 }));
}

/// Every proper prefix of a valid model is reported as truncated, with the length it needed.
#[test]
fn truncated_at_every_length() {
    let b = tiny_model().encode();
    for len in 0..b.len() {
        let needed = if len < 12 { 12 } else { b.len() };
        assert_eq!(
            decode(&b[..len]),
            Err(ModelError::Truncated {
                needed,
                available: len
            }),
            "len {len}"
        );
    }
    let mut long = b.clone();
    long.extend_from_slice(&[0, 0, 0]);
    assert_eq!(decode(&long), Err(ModelError::TrailingBytes { extra: 3 }));
}

/// Every single-bit flip is detected, and the error names the part of the container hit:
/// header fields by their own checks, payload and CRC bits by the CRC (CRC-32 detects every
/// single-bit error, so no flip may get through to the payload parser).
#[test]
fn single_bit_flips() {
    let good = tiny_model().encode();
    let n = good.len();
    let stored = u32::from_le_bytes(good[n - 4..].try_into().unwrap());
    for byte in 0..n {
        for bit in 0..8 {
            let mut b = good.clone();
            b[byte] ^= 1 << bit;
            let err = decode(&b).unwrap_err();
            match byte {
                0..=3 => assert!(
                    matches!(err, ModelError::BadMagic { .. }),
                    "{byte}.{bit}: {err:?}"
                ),
                4..=5 => assert!(
                    matches!(err, ModelError::UnsupportedVersion { .. }),
                    "{byte}.{bit}: {err:?}"
                ),
                6..=7 => assert!(
                    matches!(err, ModelError::WrongKind { .. }),
                    "{byte}.{bit}: {err:?}"
                ),
                8..=11 => {
                    let len = u32::from_le_bytes(b[8..12].try_into().unwrap()) as usize;
                    if len + 16 > n {
                        assert_eq!(
                            err,
                            ModelError::Truncated {
                                needed: len + 16,
                                available: n
                            }
                        );
                    } else {
                        assert_eq!(
                            err,
                            ModelError::TrailingBytes {
                                extra: n - len - 16
                            }
                        );
                    }
                }
                _ if byte >= n - 4 => {
                    let flipped = u32::from_le_bytes(b[n - 4..].try_into().unwrap());
                    assert_eq!(
                        err,
                        ModelError::CrcMismatch {
                            stored: flipped,
                            computed: stored
                        }
                    );
                }
                _ => assert_eq!(
                    err,
                    ModelError::CrcMismatch {
                        stored,
                        computed: common::crc32c(&b[..n - 4])
                    },
                    "{byte}.{bit}"
                ),
            }
        }
    }
}

/// Payload syntax errors (correct CRC, so the parser runs) name the field.
#[test]
fn malformed_payloads_name_the_field() {
    let good = tiny_model().encode();
    let payload = &good[12..good.len() - 4];

    // units discriminant 1 does not exist.
    let mut p = payload.to_vec();
    p[0] = 1;
    assert_eq!(
        decode(&wrap(&p)),
        malformed(Field::Units, MalformedKind::UnknownVariant { found: 1 })
    );
    // A provenance string that is not UTF-8 (byte 0xFF inside "palpate").
    let mut p = payload.to_vec();
    p[2] = 0xFF;
    assert_eq!(
        decode(&wrap(&p)),
        malformed(Field::ProvenanceTool, MalformedKind::BadUtf8)
    );
    // Blend discriminant (the last payload byte) 3 does not exist.
    let mut p = payload.to_vec();
    *p.last_mut().unwrap() = 3;
    assert_eq!(
        decode(&wrap(&p)),
        malformed(Field::Blend, MalformedKind::UnknownVariant { found: 3 })
    );
    // Cut inside d_packed (payload offset 0x1f7 − 12 + 100).
    let p = &payload[..0x1f7 - 12 + 100];
    assert_eq!(
        decode(&wrap(p)),
        malformed(Field::DPacked, MalformedKind::UnexpectedEnd)
    );
    // node_count as an over-long varint (6 continuation bytes).
    let mut p = payload[..0x2a - 12].to_vec();
    p.extend_from_slice(&[0xFF; 6]);
    p.extend_from_slice(&payload[0x2a - 12 + 1..]);
    assert_eq!(
        decode(&wrap(&p)),
        malformed(Field::NodeCount, MalformedKind::BadVarint)
    );
    // One byte too many after the record.
    let mut p = payload.to_vec();
    p.push(0);
    assert_eq!(
        decode(&wrap(&p)),
        Err(ModelError::PayloadTrailingBytes { extra: 1 })
    );
    let msg = decode(&wrap(&payload[..0x1f7 - 12 + 100]))
        .unwrap_err()
        .to_string();
    assert_eq!(
        msg,
        "malformed model payload in field `d_packed`: the payload ends inside it"
    );
}

#[test]
fn index_out_of_range_names_array_and_element() {
    let mut m = grid();
    let n = m.node_count;
    set_u32(&mut m.tets, 4 * 5 + 2, n);
    let err = content_error(&m);
    assert_eq!(
        err,
        ModelError::InvalidContent {
            what: Invalid::IndexOutOfRange {
                array: Field::Tets,
                position: 22,
                index: n,
                bound: n
            }
        }
    );
    assert_eq!(
        err.to_string(),
        format!(
            "invalid model: tets[22] (element 5, corner 2): index {n} out of range (must be < {n})"
        )
    );

    let mut m = grid();
    set_u32(&mut m.surface_triangles, 7, 10_000);
    assert_eq!(
        validate(&m.record()),
        invalid(Invalid::IndexOutOfRange {
            array: Field::SurfaceTriangles,
            position: 7,
            index: 10_000,
            bound: n
        })
    );
    let mut m = grid();
    let last = m.fixed_nodes.len() / 4 - 1;
    set_u32(&mut m.fixed_nodes, last, n + 3);
    assert_eq!(
        validate(&m.record()),
        invalid(Invalid::IndexOutOfRange {
            array: Field::FixedNodes,
            position: last as u64,
            index: n + 3,
            bound: n
        })
    );
    let mut m = model_on(
        &grid_mesh(2, 1, 1, 0.05),
        ParameterLayout::PerElement,
        BlendKind::Strain,
        2,
    );
    if let OwnedBlend::Strain {
        neighbour_index, ..
    } = &mut m.blend
    {
        set_u32(neighbour_index, 9, 12);
    }
    assert_eq!(
        content_error(&m),
        ModelError::InvalidContent {
            what: Invalid::IndexOutOfRange {
                array: Field::NeighbourIndex,
                position: 9,
                index: 12,
                bound: 12
            }
        }
    );
}

#[test]
fn non_finite_values_are_located() {
    let mut m = grid();
    set_f32(&mut m.rest_positions, 3 * 5 + 1, f32::NAN);
    let err = content_error(&m);
    assert_eq!(
        err,
        ModelError::InvalidContent {
            what: Invalid::NonFinite {
                array: Field::RestPositions,
                position: 16
            }
        }
    );
    assert_eq!(
        err.to_string(),
        "invalid model: rest_positions[16] (node 5, y): not a finite number"
    );

    let mut m = grid();
    set_f32(&mut m.d_packed, 78 * 3 + 10, f32::INFINITY);
    assert_eq!(validate(&m.record()), non_finite(Field::DPacked, 244));

    let mut m = grid();
    set_f32(&mut m.lambda, 0, f32::NEG_INFINITY);
    assert_eq!(validate(&m.record()), non_finite(Field::Lambda, 0));

    let mut m = cube(BlendKind::Deformation);
    if let OwnedBlend::Deformation { weights_alpha, .. } = &mut m.blend {
        set_f32(weights_alpha, 1, f32::NAN);
    }
    assert_eq!(
        validate(&m.record()),
        non_finite(Field::BlendWeightsAlpha, 1)
    );

    let mut m = cube(BlendKind::Strain);
    if let OwnedBlend::Strain { decay, .. } = &mut m.blend {
        *decay = f32::NAN;
    }
    assert_eq!(validate(&m.record()), non_finite(Field::StrainDecay, 0));
    assert_eq!(
        validate(&m.record()).unwrap_err().to_string(),
        "invalid model: blend.decay: not a finite number"
    );
}

#[test]
fn negative_values() {
    // C_e diagonal entry (7, 7) of element 4: packed position 7·12 − 7·6/2 = 63.
    let mut m = grid();
    set_f32(&mut m.c_packed, 78 * 4 + 63, -1.0);
    assert_eq!(
        content_error(&m),
        ModelError::InvalidContent {
            what: Invalid::Negative {
                array: Field::CPacked,
                position: 375,
                value: -1.0
            }
        }
    );
    // An off-diagonal C entry may be negative (it is for every real element), D's diagonal too.
    let mut m = grid();
    set_f32(&mut m.c_packed, 78 * 4 + 64, -1.0);
    set_f32(&mut m.d_packed, 78 * 4 + 63, -1.0);
    assert_eq!(validate(&m.record()), Ok(()));

    let mut m = cube(BlendKind::Strain);
    if let OwnedBlend::Strain { decay, .. } = &mut m.blend {
        *decay = -2.0;
    }
    assert_eq!(
        validate(&m.record()),
        invalid(Invalid::Negative {
            array: Field::StrainDecay,
            position: 0,
            value: -2.0
        })
    );
    let mut m = cube(BlendKind::Strain);
    if let OwnedBlend::Strain {
        neighbour_weight, ..
    } = &mut m.blend
    {
        set_f32(neighbour_weight, 3, -0.5);
    }
    assert_eq!(
        validate(&m.record()),
        invalid(Invalid::Negative {
            array: Field::NeighbourWeight,
            position: 3,
            value: -0.5
        })
    );
}

/// An inverted element (two nodes swapped) is reported with its index and its signed volume.
#[test]
fn inverted_element() {
    let mut m = grid();
    let (a, b) = (4 * 7 + 1, 4 * 7 + 2);
    let (va, vb) = (
        m.tets[4 * a..4 * a + 4].to_vec(),
        m.tets[4 * b..4 * b + 4].to_vec(),
    );
    m.tets[4 * a..4 * a + 4].copy_from_slice(&vb);
    m.tets[4 * b..4 * b + 4].copy_from_slice(&va);
    let err = content_error(&m);
    let ModelError::InvalidContent {
        what: Invalid::Inverted { element, volume },
    } = err
    else {
        panic!("{err:?}")
    };
    assert_eq!(element, 7);
    // Kuhn tets of a cube of edge h have volume h³/6; h = 0.05 is exact to f32 rounding (1e-7).
    let expected = -0.05f64.powi(3) / 6.0;
    assert!(
        (volume - expected).abs() < 1e-6 * expected.abs(),
        "{volume}"
    );
    assert_eq!(
        err.to_string(),
        "invalid model: element 7: inverted rest element (signed volume -2.08e-5 m³)"
    );
}

/// A flat element (four coplanar nodes) is ZeroVolume, not Inverted; the relative tolerance
/// separates a sliver of 1e-7 ℓ³ (rejected) from one of 1e-4 ℓ³ (accepted).
#[test]
fn zero_volume_element() {
    let mut m = grid();
    // Nodes 0, 1, 2 lie on the x axis and node 3 (x = 0, y = h) is in the z = 0 plane too.
    m.tets[4 * 4 * 9..4 * 4 * 10].copy_from_slice(&u32_bytes(&[0, 1, 2, 3]));
    assert_eq!(
        content_error(&m),
        ModelError::InvalidContent {
            what: Invalid::ZeroVolume {
                element: 9,
                volume: 0.0
            }
        }
    );

    // Tiny model with node 3 lowered to height z: ℓ = √2 (edge 1–2), V = z/6.
    for (z, ok) in [
        (1e-7f32, false),
        (-1e-7, false),
        (1e-4, true),
        (-1e-4, false),
    ] {
        let mut m = tiny_model();
        set_f32(&mut m.rest_positions, 11, z);
        let r = validate(&m.record());
        let volume = z as f64 / 6.0;
        match (ok, r) {
            (true, Ok(())) => {}
            (
                false,
                Err(ModelError::InvalidContent {
                    what:
                        Invalid::ZeroVolume {
                            element: 0,
                            volume: v,
                        },
                }),
            ) if z.abs() < 1e-6 => {
                assert!((v - volume).abs() < 1e-15, "{v}")
            }
            (
                false,
                Err(ModelError::InvalidContent {
                    what:
                        Invalid::Inverted {
                            element: 0,
                            volume: v,
                        },
                }),
            ) if z < -1e-6 => {
                assert!((v - volume).abs() < 1e-15, "{v}")
            }
            (_, r) => panic!("z = {z}: {r:?}"),
        }
    }
}

#[test]
fn repeated_node_in_a_tet() {
    let mut m = grid();
    let node = u32::from_le_bytes(m.tets[4 * 4 * 3..4 * 4 * 3 + 4].try_into().unwrap());
    set_u32(&mut m.tets, 4 * 3 + 2, node);
    let err = content_error(&m);
    assert_eq!(
        err,
        ModelError::InvalidContent {
            what: Invalid::RepeatedNode { element: 3, node }
        }
    );
    assert_eq!(
        err.to_string(),
        format!("invalid model: element 3: node {node} appears twice")
    );
}

#[test]
fn degenerate_surface_triangle() {
    let mut m = grid();
    // Nodes 0, 1, 2 are collinear on the x axis.
    set_u32(&mut m.surface_triangles, 3 * 2, 0);
    set_u32(&mut m.surface_triangles, 3 * 2 + 1, 1);
    set_u32(&mut m.surface_triangles, 3 * 2 + 2, 2);
    assert_eq!(
        content_error(&m),
        ModelError::InvalidContent {
            what: Invalid::DegenerateTriangle {
                triangle: 2,
                area: 0.0
            }
        }
    );
}

/// Unphysical parameters name the set and (per-element layout) the element.
#[test]
fn unphysical_parameters() {
    let mut m = model_on(
        &grid_mesh(2, 1, 1, 0.05),
        ParameterLayout::PerElement,
        BlendKind::Deformation,
        3,
    );
    let t = m.element_count as usize;
    // Set 2, element 5: ν = 0.6.
    set_f32(
        &mut m.alpha,
        2 * t + 5,
        0.6 * f32::from_le_bytes(m.lambda[4 * (2 * t + 5)..][..4].try_into().unwrap()),
    );
    let err = content_error(&m);
    let ModelError::InvalidContent {
        what:
            Invalid::Unphysical {
                set: 2,
                element: Some(5),
                ..
            },
    } = err
    else {
        panic!("{err:?}")
    };
    assert!(
        err.to_string()
            .starts_with("invalid model: parameter set 2, element 5: unphysical λ = "),
        "{err}"
    );

    for (lambda, alpha) in [
        (-1000.0f32, -100.0f32),
        (0.0, 0.0),
        (1000.0, -1000.0),
        (1000.0, 500.0),
    ] {
        let mut m = grid();
        set_f32(&mut m.lambda, 0, lambda);
        set_f32(&mut m.alpha, 0, alpha);
        assert_eq!(
            validate(&m.record()),
            invalid(Invalid::Unphysical {
                set: 0,
                element: None,
                lambda,
                alpha
            })
        );
    }
    // Just inside the bounds is accepted: ν = −0.99 and ν = 0.49.
    for alpha in [-990.0f32, 490.0] {
        let mut m = grid();
        set_f32(&mut m.lambda, 0, 1000.0);
        set_f32(&mut m.alpha, 0, alpha);
        assert_eq!(validate(&m.record()), Ok(()));
    }
}

#[test]
fn length_errors() {
    let mut m = grid();
    m.node_tags.truncate(m.node_tags.len() - 4);
    let n = m.node_count as u64;
    assert_eq!(
        content_error(&m),
        ModelError::InvalidContent {
            what: Invalid::LengthMismatch {
                array: Field::NodeTags,
                expected: n,
                found: n - 1
            }
        }
    );
    let mut m = grid();
    m.c_packed.push(0);
    let bytes = m.c_packed.len() as u64;
    assert_eq!(
        validate(&m.record()),
        invalid(Invalid::PartialValue {
            array: Field::CPacked,
            bytes
        })
    );
    let mut m = grid();
    m.surface_triangles.extend_from_slice(&u32_bytes(&[0]));
    let found = m.surface_triangles.len() as u64 / 4;
    assert_eq!(
        validate(&m.record()),
        invalid(Invalid::LengthNotMultiple {
            array: Field::SurfaceTriangles,
            found,
            multiple: 3
        })
    );
    let mut m = grid();
    m.element_count += 1;
    let t = m.element_count as u64;
    assert_eq!(
        validate(&m.record()),
        invalid(Invalid::LengthMismatch {
            array: Field::Tets,
            expected: 4 * t,
            found: 4 * (t - 1)
        })
    );

    let mut m = grid();
    m.element_count = 0;
    assert_eq!(validate(&m.record()), invalid(Invalid::NoElements));
    let mut m = grid();
    m.count = 0;
    assert_eq!(validate(&m.record()), invalid(Invalid::NoParameterSet));
    let mut m = grid();
    m.count = 2;
    m.lambda = common::f32_bytes(&[1000.0, 1000.0]);
    m.alpha = common::f32_bytes(&[300.0, 300.0]);
    assert_eq!(
        content_error(&m),
        ModelError::InvalidContent {
            what: Invalid::UnblendedSetCount { count: 2 }
        }
    );

    let mut m = cube(BlendKind::Strain);
    if let OwnedBlend::Strain { neighbours, .. } = &mut m.blend {
        *neighbours = 0;
    }
    assert_eq!(validate(&m.record()), invalid(Invalid::NoNeighbours));
    let mut m = cube(BlendKind::Deformation);
    if let OwnedBlend::Deformation { centres, .. } = &mut m.blend {
        centres.truncate(centres.len() - 12);
    }
    let expected = 2 * 3 * m.node_count as u64;
    assert_eq!(
        validate(&m.record()),
        invalid(Invalid::LengthMismatch {
            array: Field::BlendCentres,
            expected,
            found: expected - 3
        })
    );
}

#[test]
fn fixed_node_errors() {
    let mut m = grid();
    m.fixed_nodes.clear();
    let err = content_error(&m);
    assert_eq!(
        err,
        ModelError::InvalidContent {
            what: Invalid::NoFixedNode
        }
    );
    assert_eq!(
        err.to_string(),
        "invalid model: no fixed (Dirichlet) node: the static stiffness matrix would be singular"
    );

    let mut m = grid();
    m.fixed_nodes = u32_bytes(&(0..m.node_count).collect::<Vec<_>>());
    assert_eq!(
        content_error(&m),
        ModelError::InvalidContent {
            what: Invalid::NoFreeNode
        }
    );

    let mut m = grid();
    m.fixed_nodes = u32_bytes(&[0, 1, 4, 3]);
    assert_eq!(
        content_error(&m),
        ModelError::InvalidContent {
            what: Invalid::FixedNodesNotIncreasing {
                position: 3,
                previous: 4,
                index: 3
            }
        }
    );
    // A repeated fixed node is the same error.
    let mut m = grid();
    m.fixed_nodes = u32_bytes(&[0, 1, 1]);
    assert_eq!(
        validate(&m.record()),
        invalid(Invalid::FixedNodesNotIncreasing {
            position: 2,
            previous: 1,
            index: 1
        })
    );
}

/// A free node outside every tet passes `decode` (it needs memory to find) but not
/// `validate_node_coverage`; a fixed orphan is harmless and accepted.
#[test]
fn orphan_free_node() {
    let mut m = grid();
    let n = m.node_count;
    // Append node n at a fresh position, belonging to no tet.
    m.node_count += 1;
    m.rest_positions
        .extend_from_slice(&common::f32_bytes(&[1.0, 1.0, 1.0]));
    m.node_tags.extend_from_slice(&u32_bytes(&[99_999]));
    let bytes = m.encode();
    let record = decode(&bytes).unwrap();
    let mut scratch = vec![0xFFu8; node_coverage_scratch_len(record.node_count)];
    let err = validate_node_coverage(&record, &mut scratch).unwrap_err();
    assert_eq!(
        err,
        ModelError::InvalidContent {
            what: Invalid::OrphanNode { node: n }
        }
    );
    assert_eq!(
        err.to_string(),
        format!("invalid model: node {n} is free but belongs to no tetrahedron: the stiffness matrix would be singular")
    );
    let needed = scratch.len();
    assert_eq!(
        validate_node_coverage(&record, &mut scratch[..needed - 1]),
        Err(ModelError::CapacityExceeded {
            what: Capacity::Scratch,
            needed,
            available: needed - 1
        })
    );
    // Fixing the orphan makes it harmless (its dofs are removed).
    let mut fixed: Vec<u32> = m
        .fixed_nodes
        .chunks(4)
        .map(|b| u32::from_le_bytes(b.try_into().unwrap()))
        .collect();
    fixed.push(n);
    m.fixed_nodes = u32_bytes(&fixed);
    let bytes = m.encode();
    assert_eq!(
        validate_node_coverage(&decode(&bytes).unwrap(), &mut scratch),
        Ok(())
    );
    // Every valid grid model covers all its nodes.
    let g = grid();
    assert_eq!(validate_node_coverage(&g.record(), &mut scratch), Ok(()));
}

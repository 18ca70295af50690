//! Content validation: the checks that make "a model that decodes is safe to run" true.
//!
//! Checks run in stages, each relying on the ones before it (lengths before indexing, indices
//! before geometry), and the first problem found is reported:
//! 1. array lengths: whole 4-byte values, consistent with `node_count`, `element_count`,
//!    `parameters.count` and the blend's neighbour count;
//! 2. indices: every node index below `node_count`, neighbour indices below `element_count`,
//!    no repeated node in a tetrahedron, fixed nodes strictly increasing, at least one fixed and
//!    one free node;
//! 3. numbers: every float finite; C_e diagonals, neighbour weights and strain decay ≥ 0;
//! 4. geometry: every rest tetrahedron positively oriented with volume above
//!    [`MIN_RELATIVE_VOLUME`] · ℓ³, every surface triangle with area above [`MIN_RELATIVE_AREA`] · ℓ²;
//! 5. parameters: every (λ, α) of every set (and element) physical.

use super::error::{Capacity, Field, Invalid, ModelError};
use super::record::{Blend, F32s, ModelRecord, ParameterLayout, U32s};

/// A rest tetrahedron must have |V_e| > `MIN_RELATIVE_VOLUME` · ℓ³, ℓ its longest edge (a
/// regular tetrahedron has V = ℓ³/(6√2) ≈ 0.118 ℓ³).
///
/// Why 1e-6 and not smaller: the runtime recomputes element geometry in f32. Measured over
/// 2 million random nearly flat tetrahedra (scales 1 mm–10 m, offsets up to 10 m), the f32
/// determinant puts V off by at most 8.3e-9 ℓ³ (a few f32 ulps), so above 1e-6 ℓ³ the sign and
/// magnitude of V_e are reliable in f32 with a margin of 100×, and the runtime's own check
/// (`tet_geometry`, |V| > 1e-9 ℓ³) always accepts an element that passes here. No mesher
/// produces such slivers on purpose.
pub const MIN_RELATIVE_VOLUME: f64 = 1e-6;

/// A surface triangle must have area > `MIN_RELATIVE_AREA` · ℓ², ℓ its longest edge. Any face of
/// a tetrahedron that passes [`MIN_RELATIVE_VOLUME`] passes this (area ≥ 3V/ℓ ≥ 3e-6 ℓ²), so
/// only triangles that are not faces of valid elements fail it; their normals would be undefined.
pub const MIN_RELATIVE_AREA: f64 = 1e-6;

/// Number of values of a packed symmetric 12 × 12 element matrix.
const PACKED_LEN: u64 = 78;

/// Checks that `record` is safe to run (see the module docs for the list and order of checks).
/// [`decode`](super::decode) calls this on every record it returns, and
/// [`encode`](super::encode) on every record it writes; call it directly to check a record before
/// writing it elsewhere.
pub fn validate(record: &ModelRecord) -> Result<(), ModelError> {
    lengths(record)?;
    indices(record)?;
    numbers(record)?;
    geometry(record)?;
    parameters(record)?;
    Ok(())
}

/// The number of whole values in a byte array.
fn values(array: Field, bytes: &[u8]) -> Result<u64, Invalid> {
    // Not `is_multiple_of`: the workspace's rust-version is 1.85.
    let whole = bytes.len() / 4;
    if 4 * whole != bytes.len() {
        return Err(Invalid::PartialValue {
            array,
            bytes: bytes.len() as u64,
        });
    }
    Ok(whole as u64)
}

fn exact(array: Field, bytes: &[u8], expected: u64) -> Result<(), Invalid> {
    let found = values(array, bytes)?;
    if found != expected {
        return Err(Invalid::LengthMismatch {
            array,
            expected,
            found,
        });
    }
    Ok(())
}

fn lengths(r: &ModelRecord) -> Result<(), Invalid> {
    let n = r.node_count as u64;
    let t = r.element_count as u64;
    if t == 0 {
        return Err(Invalid::NoElements);
    }
    exact(Field::RestPositions, r.rest_positions.0, 3 * n)?;
    exact(Field::NodeTags, r.node_tags.0, n)?;
    exact(Field::Tets, r.tets.0, 4 * t)?;
    values(Field::FixedNodes, r.fixed_nodes.0)?;
    let tris = values(Field::SurfaceTriangles, r.surface_triangles.0)?;
    if tris % 3 != 0 {
        return Err(Invalid::LengthNotMultiple {
            array: Field::SurfaceTriangles,
            found: tris,
            multiple: 3,
        });
    }
    exact(Field::CPacked, r.c_packed.0, PACKED_LEN * t)?;
    exact(Field::DPacked, r.d_packed.0, PACKED_LEN * t)?;

    let p = &r.parameters;
    let sets = p.count as u64;
    if sets == 0 {
        return Err(Invalid::NoParameterSet);
    }
    let per_set = match p.layout {
        ParameterLayout::Global => 1,
        ParameterLayout::PerElement => t,
    };
    // count and element_count are u32, so their product fits u64; products of three may not,
    // hence the saturating multiplications below (a saturated expectation never matches).
    exact(Field::Lambda, p.lambda.0, sets * per_set)?;
    exact(Field::Alpha, p.alpha.0, sets * per_set)?;

    match r.blend {
        Blend::None => {
            if sets != 1 {
                return Err(Invalid::UnblendedSetCount { count: p.count });
            }
        }
        Blend::Deformation {
            centres,
            weights_lambda,
            weights_alpha,
        } => {
            exact(Field::BlendCentres, centres.0, sets.saturating_mul(3 * n))?;
            exact(Field::BlendWeightsLambda, weights_lambda.0, sets)?;
            exact(Field::BlendWeightsAlpha, weights_alpha.0, sets)?;
        }
        Blend::Strain {
            decay: _,
            neighbours,
            neighbour_index,
            neighbour_weight,
            centres,
            weights_lambda,
            weights_alpha,
        } => {
            if neighbours == 0 {
                return Err(Invalid::NoNeighbours);
            }
            let k = neighbours as u64;
            exact(Field::NeighbourIndex, neighbour_index.0, t * k)?;
            exact(Field::NeighbourWeight, neighbour_weight.0, t * k)?;
            exact(
                Field::BlendCentres,
                centres.0,
                sets.saturating_mul(t).saturating_mul(6),
            )?;
            exact(Field::BlendWeightsLambda, weights_lambda.0, t * sets)?;
            exact(Field::BlendWeightsAlpha, weights_alpha.0, t * sets)?;
        }
    }
    Ok(())
}

fn in_range(array: Field, indices: U32s, bound: u32) -> Result<(), Invalid> {
    for (position, index) in indices.iter().enumerate() {
        if index >= bound {
            return Err(Invalid::IndexOutOfRange {
                array,
                position: position as u64,
                index,
                bound,
            });
        }
    }
    Ok(())
}

fn indices(r: &ModelRecord) -> Result<(), Invalid> {
    let n = r.node_count;
    in_range(Field::Tets, r.tets, n)?;
    for (element, b) in r.tets.0.chunks_exact(16).enumerate() {
        let v = |i: usize| u32::from_le_bytes([b[4 * i], b[4 * i + 1], b[4 * i + 2], b[4 * i + 3]]);
        let nodes = [v(0), v(1), v(2), v(3)];
        for i in 0..4 {
            for j in (i + 1)..4 {
                if nodes[i] == nodes[j] {
                    return Err(Invalid::RepeatedNode {
                        element: element as u32,
                        node: nodes[i],
                    });
                }
            }
        }
    }

    in_range(Field::FixedNodes, r.fixed_nodes, n)?;
    let mut previous: Option<u32> = None;
    for (position, index) in r.fixed_nodes.iter().enumerate() {
        if let Some(previous) = previous {
            if index <= previous {
                return Err(Invalid::FixedNodesNotIncreasing {
                    position: position as u64,
                    previous,
                    index,
                });
            }
        }
        previous = Some(index);
    }
    // Strictly increasing and in range: the fixed nodes are distinct, so the free nodes number
    // node_count − fixed.
    if r.fixed_nodes.is_empty() {
        return Err(Invalid::NoFixedNode);
    }
    if r.fixed_nodes.len() as u64 >= n as u64 {
        return Err(Invalid::NoFreeNode);
    }

    in_range(Field::SurfaceTriangles, r.surface_triangles, n)?;
    if let Blend::Strain {
        neighbour_index, ..
    } = r.blend
    {
        in_range(Field::NeighbourIndex, neighbour_index, r.element_count)?;
    }
    Ok(())
}

fn finite(array: Field, values: F32s) -> Result<(), Invalid> {
    match values.iter().position(|v| !v.is_finite()) {
        Some(position) => Err(Invalid::NonFinite {
            array,
            position: position as u64,
        }),
        None => Ok(()),
    }
}

fn non_negative(array: Field, values: F32s) -> Result<(), Invalid> {
    for (position, value) in values.iter().enumerate() {
        if value < 0.0 {
            return Err(Invalid::Negative {
                array,
                position: position as u64,
                value,
            });
        }
    }
    Ok(())
}

/// Position of diagonal entry (i, i) in a packed upper triangle (row-major): rows 0..i hold
/// 12 + 11 + … + (13 − i) entries.
const fn packed_diagonal(i: u64) -> u64 {
    i * 12 - i * (i.saturating_sub(1)) / 2
}

fn numbers(r: &ModelRecord) -> Result<(), Invalid> {
    finite(Field::RestPositions, r.rest_positions)?;
    finite(Field::CPacked, r.c_packed)?;
    finite(Field::DPacked, r.d_packed)?;
    // C_e = V_e B_eᵀ F B_e is positive semi-definite (F is), so its diagonal cannot be negative;
    // D_e's diagonal can (G has −1 on its diagonal).
    for e in 0..r.element_count as u64 {
        for i in 0..12 {
            let position = e * PACKED_LEN + packed_diagonal(i);
            let value = r.c_packed.get(position as usize).unwrap_or(0.0);
            if value < 0.0 {
                return Err(Invalid::Negative {
                    array: Field::CPacked,
                    position,
                    value,
                });
            }
        }
    }
    finite(Field::Lambda, r.parameters.lambda)?;
    finite(Field::Alpha, r.parameters.alpha)?;
    match r.blend {
        Blend::None => {}
        Blend::Deformation {
            centres,
            weights_lambda,
            weights_alpha,
        } => {
            finite(Field::BlendCentres, centres)?;
            finite(Field::BlendWeightsLambda, weights_lambda)?;
            finite(Field::BlendWeightsAlpha, weights_alpha)?;
        }
        Blend::Strain {
            decay,
            neighbour_weight,
            centres,
            weights_lambda,
            weights_alpha,
            ..
        } => {
            if !decay.is_finite() {
                return Err(Invalid::NonFinite {
                    array: Field::StrainDecay,
                    position: 0,
                });
            }
            if decay < 0.0 {
                return Err(Invalid::Negative {
                    array: Field::StrainDecay,
                    position: 0,
                    value: decay,
                });
            }
            finite(Field::NeighbourWeight, neighbour_weight)?;
            // w_{e,e'} = exp(−c‖c_e − c_e'‖²) > 0; a negative weight could make the locally
            // weighted strain distance (eq. 6.10) negative and its square root NaN.
            non_negative(Field::NeighbourWeight, neighbour_weight)?;
            finite(Field::BlendCentres, centres)?;
            finite(Field::BlendWeightsLambda, weights_lambda)?;
            finite(Field::BlendWeightsAlpha, weights_alpha)?;
        }
    }
    Ok(())
}

/// Rest position of node `i` in f64 (indices are checked before this runs).
fn node(r: &ModelRecord, i: u32) -> [f64; 3] {
    let at = |k: usize| r.rest_positions.get(3 * i as usize + k).unwrap_or(0.0) as f64;
    [at(0), at(1), at(2)]
}

// Written out on purpose: the protocol crate is no_std with no linear-algebra dependency
// (the fitter crates use nalgebra::Vector3 for the same operations).
fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Longest edge of the polygon/polyhedron spanned by `x` (all pairs).
fn longest_edge(x: &[[f64; 3]]) -> f64 {
    let mut longest: f64 = 0.0;
    for i in 0..x.len() {
        for j in (i + 1)..x.len() {
            let d = sub(x[j], x[i]);
            longest = longest.max(libm::sqrt(dot(d, d)));
        }
    }
    longest
}

fn geometry(r: &ModelRecord) -> Result<(), Invalid> {
    for (element, b) in r.tets.0.chunks_exact(16).enumerate() {
        let v = |i: usize| u32::from_le_bytes([b[4 * i], b[4 * i + 1], b[4 * i + 2], b[4 * i + 3]]);
        let x = [node(r, v(0)), node(r, v(1)), node(r, v(2)), node(r, v(3))];
        // 6V = det[x1 − x0, x2 − x0, x3 − x0] (the runtime's `signed_volume`).
        let (a, bb, c) = (sub(x[1], x[0]), sub(x[2], x[0]), sub(x[3], x[0]));
        let volume = dot(a, cross(bb, c)) / 6.0;
        let l = longest_edge(&x);
        let tol = MIN_RELATIVE_VOLUME * l * l * l;
        let element = element as u32;
        if volume.abs() <= tol {
            return Err(Invalid::ZeroVolume { element, volume });
        }
        if volume < 0.0 {
            return Err(Invalid::Inverted { element, volume });
        }
    }
    for (triangle, b) in r.surface_triangles.0.chunks_exact(12).enumerate() {
        let v = |i: usize| u32::from_le_bytes([b[4 * i], b[4 * i + 1], b[4 * i + 2], b[4 * i + 3]]);
        let x = [node(r, v(0)), node(r, v(1)), node(r, v(2))];
        let n = cross(sub(x[1], x[0]), sub(x[2], x[0]));
        let area = 0.5 * libm::sqrt(dot(n, n));
        let l = longest_edge(&x);
        if area <= MIN_RELATIVE_AREA * l * l {
            return Err(Invalid::DegenerateTriangle {
                triangle: triangle as u32,
                area,
            });
        }
    }
    Ok(())
}

fn parameters(r: &ModelRecord) -> Result<(), Invalid> {
    let p = &r.parameters;
    let per_set = match p.layout {
        ParameterLayout::Global => 1,
        ParameterLayout::PerElement => r.element_count as usize,
    };
    for (i, (lambda, alpha)) in p.lambda.iter().zip(p.alpha.iter()).enumerate() {
        let (l, a) = (lambda as f64, alpha as f64);
        // ν = α/λ (eq. 3.39); written without dividing so λ = 0 cannot produce NaN.
        let physical = l > 0.0 && a > -l && a < 0.5 * l;
        if !physical {
            let element = match p.layout {
                ParameterLayout::Global => None,
                ParameterLayout::PerElement => Some((i % per_set) as u32),
            };
            return Err(Invalid::Unphysical {
                set: (i / per_set) as u32,
                element,
                lambda,
                alpha,
            });
        }
    }
    Ok(())
}

/// Bytes of scratch [`validate_node_coverage`] needs for `node_count` nodes (one bit per node).
pub const fn node_coverage_scratch_len(node_count: u32) -> usize {
    (node_count as usize).div_ceil(8)
}

/// Checks that every free node belongs to at least one tetrahedron; an orphan free node has no
/// stiffness, so the system matrix would be singular ([`Invalid::OrphanNode`]).
///
/// [`validate`] (and so [`decode`](super::decode)) cannot check this without memory; this
/// takes one bit per node of caller scratch ([`node_coverage_scratch_len`] bytes, else
/// [`ModelError::CapacityExceeded`] with [`Capacity::Scratch`]). Call it on a record that passed
/// [`validate`]: a loader when it sizes its storage, a writer before it writes.
pub fn validate_node_coverage(record: &ModelRecord, scratch: &mut [u8]) -> Result<(), ModelError> {
    let needed = node_coverage_scratch_len(record.node_count);
    let available = scratch.len();
    let marks = scratch
        .get_mut(..needed)
        .ok_or(ModelError::CapacityExceeded {
            what: Capacity::Scratch,
            needed,
            available,
        })?;
    marks.fill(0);
    let mut mark = |node: u32| {
        // Out-of-range indices were rejected by `validate`; ignore them rather than panic if the
        // caller skipped it.
        if let Some(m) = marks.get_mut(node as usize / 8) {
            *m |= 1 << (node % 8);
        }
    };
    record.tets.iter().for_each(&mut mark);
    record.fixed_nodes.iter().for_each(&mut mark);
    for node in 0..record.node_count {
        if marks[node as usize / 8] & (1 << (node % 8)) == 0 {
            return Err(Invalid::OrphanNode { node }.into());
        }
    }
    Ok(())
}

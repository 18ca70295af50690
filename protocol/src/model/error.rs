//! Every way a model byte string (or a record about to be written) can be wrong: one flat,
//! documented error enum, [`ModelError`], with small `Copy` enums saying where and why.

use core::fmt;

/// Why a model could not be encoded or decoded. The first problem found is reported; checks run
/// in the order of `MODEL-FORMAT.md` §"Decoding order".
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum ModelError {
    /// The first four bytes are not `PALP`: this is not a palpate model.
    BadMagic {
        /// The four bytes found instead.
        found: [u8; 4],
    },
    /// The container's format version is not the one this build reads.
    UnsupportedVersion {
        /// Version in the container header.
        found: u16,
        /// [`MODEL_FORMAT_VERSION`](super::MODEL_FORMAT_VERSION) of this build.
        supported: u16,
    },
    /// The container holds something other than a model (kind ≠ 1).
    WrongKind {
        /// Kind in the container header.
        found: u16,
    },
    /// The byte string ends before the container does (header, or the payload length it states,
    /// plus the CRC). `needed` saturates at `usize::MAX` on targets where it would overflow.
    Truncated {
        /// Bytes the container needs.
        needed: usize,
        /// Bytes given.
        available: usize,
    },
    /// Bytes follow the container's CRC.
    TrailingBytes {
        /// Number of extra bytes.
        extra: usize,
    },
    /// The CRC-32 (iSCSI) over header and payload does not match the stored one: the bytes were
    /// corrupted.
    CrcMismatch {
        /// CRC stored in the container.
        stored: u32,
        /// CRC computed over the bytes read.
        computed: u32,
    },
    /// The payload is not a valid postcard encoding of a model record (despite a good CRC, so
    /// the writer was wrong, not the medium).
    Malformed {
        /// The record field being read when the encoding went wrong.
        field: Field,
        /// What was wrong with it.
        kind: MalformedKind,
    },
    /// The payload decodes to a record but has bytes left over after it.
    PayloadTrailingBytes {
        /// Number of unread payload bytes.
        extra: usize,
    },
    /// A buffer or a length field is too small for the model.
    CapacityExceeded {
        /// Which buffer or field.
        what: Capacity,
        /// Bytes needed.
        needed: usize,
        /// Bytes available.
        available: usize,
    },
    /// The record is well formed but not safe to run.
    InvalidContent {
        /// What is wrong, and where.
        what: Invalid,
    },
}

/// A buffer or length field that can be too small, for [`ModelError::CapacityExceeded`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum Capacity {
    /// The caller's output buffer given to [`encode`](super::encode).
    OutputBuffer,
    /// The container's u32 payload-length field (payload larger than 4 GiB − 1).
    PayloadLength,
    /// The scratch buffer given to [`validate_node_coverage`](super::validate_node_coverage).
    Scratch,
}

/// How a payload failed to parse, for [`ModelError::Malformed`] (postcard's deserialisation
/// errors, narrowed to the ones a model payload can hit).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum MalformedKind {
    /// The payload ends inside the field (a length prefix points past the end).
    UnexpectedEnd,
    /// A varint is longer than its type allows or overflows it.
    BadVarint,
    /// A string is not valid UTF-8.
    BadUtf8,
    /// An enum discriminant names no variant this version knows.
    UnknownVariant {
        /// The discriminant found.
        found: u32,
    },
    /// Any other invalid encoding.
    BadEncoding,
}

impl From<postcard::Error> for MalformedKind {
    fn from(e: postcard::Error) -> Self {
        match e {
            postcard::Error::DeserializeUnexpectedEnd => Self::UnexpectedEnd,
            postcard::Error::DeserializeBadVarint => Self::BadVarint,
            postcard::Error::DeserializeBadUtf8 => Self::BadUtf8,
            _ => Self::BadEncoding,
        }
    }
}

/// A field of [`ModelRecord`](super::ModelRecord), in encoding order, named as in the record.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum Field {
    /// The record as a whole (only for failures not tied to one field).
    Record,
    /// `units`.
    Units,
    /// `provenance.tool`.
    ProvenanceTool,
    /// `provenance.created`.
    ProvenanceCreated,
    /// `provenance.source`.
    ProvenanceSource,
    /// `provenance.notes`.
    ProvenanceNotes,
    /// `node_count`.
    NodeCount,
    /// `element_count`.
    ElementCount,
    /// `rest_positions`.
    RestPositions,
    /// `node_tags`.
    NodeTags,
    /// `tets`.
    Tets,
    /// `fixed_nodes`.
    FixedNodes,
    /// `surface_triangles`.
    SurfaceTriangles,
    /// `c_packed`.
    CPacked,
    /// `d_packed`.
    DPacked,
    /// `parameters.layout`.
    ParameterLayout,
    /// `parameters.count`.
    ParameterCount,
    /// `parameters.lambda`.
    Lambda,
    /// `parameters.alpha`.
    Alpha,
    /// `blend` (its variant discriminant).
    Blend,
    /// `blend.centres` (Deformation or Strain).
    BlendCentres,
    /// `blend.weights_lambda`.
    BlendWeightsLambda,
    /// `blend.weights_alpha`.
    BlendWeightsAlpha,
    /// `blend.decay` (Strain).
    StrainDecay,
    /// `blend.neighbours` (Strain).
    StrainNeighbours,
    /// `blend.neighbour_index` (Strain).
    NeighbourIndex,
    /// `blend.neighbour_weight` (Strain).
    NeighbourWeight,
}

impl Field {
    /// The field's path in the record, e.g. `parameters.lambda`.
    pub const fn name(self) -> &'static str {
        match self {
            Field::Record => "record",
            Field::Units => "units",
            Field::ProvenanceTool => "provenance.tool",
            Field::ProvenanceCreated => "provenance.created",
            Field::ProvenanceSource => "provenance.source",
            Field::ProvenanceNotes => "provenance.notes",
            Field::NodeCount => "node_count",
            Field::ElementCount => "element_count",
            Field::RestPositions => "rest_positions",
            Field::NodeTags => "node_tags",
            Field::Tets => "tets",
            Field::FixedNodes => "fixed_nodes",
            Field::SurfaceTriangles => "surface_triangles",
            Field::CPacked => "c_packed",
            Field::DPacked => "d_packed",
            Field::ParameterLayout => "parameters.layout",
            Field::ParameterCount => "parameters.count",
            Field::Lambda => "parameters.lambda",
            Field::Alpha => "parameters.alpha",
            Field::Blend => "blend",
            Field::BlendCentres => "blend.centres",
            Field::BlendWeightsLambda => "blend.weights_lambda",
            Field::BlendWeightsAlpha => "blend.weights_alpha",
            Field::StrainDecay => "blend.decay",
            Field::StrainNeighbours => "blend.neighbours",
            Field::NeighbourIndex => "blend.neighbour_index",
            Field::NeighbourWeight => "blend.neighbour_weight",
        }
    }
}

/// Why a well-formed record is not safe to run, and where, for [`ModelError::InvalidContent`].
/// Positions count values (not bytes) from the start of the array; elements, nodes, triangles
/// and sets are 0-based indices.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum Invalid {
    /// An array's byte length is not a multiple of 4, so it is not a whole number of values.
    PartialValue {
        /// The array.
        array: Field,
        /// Its byte length.
        bytes: u64,
    },
    /// An array holds a different number of values than the counts require.
    LengthMismatch {
        /// The array.
        array: Field,
        /// Values required by `node_count`, `element_count`, `parameters.count`, … .
        expected: u64,
        /// Values present.
        found: u64,
    },
    /// An array's value count is not a multiple of its record size (e.g. 3 for triangles).
    LengthNotMultiple {
        /// The array.
        array: Field,
        /// Values present.
        found: u64,
        /// Required multiple.
        multiple: u32,
    },
    /// `element_count` is 0: a model needs at least one tetrahedron.
    NoElements,
    /// `parameters.count` is 0: a model needs at least one parameter set.
    NoParameterSet,
    /// `blend` is `None` (a linear material) but there is not exactly one parameter set.
    UnblendedSetCount {
        /// `parameters.count`.
        count: u32,
    },
    /// `blend.neighbours` is 0: each element's strain neighbourhood includes at least itself.
    NoNeighbours,
    /// An index is not below its bound (`node_count` for node indices, `element_count` for
    /// neighbour indices).
    IndexOutOfRange {
        /// The index array.
        array: Field,
        /// Position of the index in the array.
        position: u64,
        /// The index found.
        index: u32,
        /// The exclusive bound.
        bound: u32,
    },
    /// `fixed_nodes` is not strictly increasing (so it may repeat a node).
    FixedNodesNotIncreasing {
        /// Position in `fixed_nodes` of the offending index.
        position: u64,
        /// The index before it.
        previous: u32,
        /// The offending index.
        index: u32,
    },
    /// A tetrahedron uses the same node twice.
    RepeatedNode {
        /// The element.
        element: u32,
        /// The repeated node index.
        node: u32,
    },
    /// A value is NaN or infinite.
    NonFinite {
        /// The array (or scalar field, position 0).
        array: Field,
        /// Position of the value.
        position: u64,
    },
    /// A value that must be ≥ 0 is negative (C_e diagonal, neighbour weight, strain decay).
    Negative {
        /// The array (or scalar field, position 0).
        array: Field,
        /// Position of the value.
        position: u64,
        /// The value.
        value: f32,
    },
    /// A rest tetrahedron is flat: |V_e| ≤ [`MIN_RELATIVE_VOLUME`](super::MIN_RELATIVE_VOLUME) · ℓ³
    /// (ℓ its longest edge).
    ZeroVolume {
        /// The element.
        element: u32,
        /// Its signed rest volume (m³), computed in f64 from the stored f32 positions.
        volume: f64,
    },
    /// A rest tetrahedron is inverted: V_e < −[`MIN_RELATIVE_VOLUME`](super::MIN_RELATIVE_VOLUME) · ℓ³
    /// (its nodes are not positively oriented).
    Inverted {
        /// The element.
        element: u32,
        /// Its signed rest volume (m³).
        volume: f64,
    },
    /// A surface triangle has (nearly) zero area: area ≤
    /// [`MIN_RELATIVE_AREA`](super::MIN_RELATIVE_AREA) · ℓ² (repeated or collinear nodes).
    DegenerateTriangle {
        /// The triangle.
        triangle: u32,
        /// Its area (m²).
        area: f64,
    },
    /// A parameter pair is not a physical isotropic material: it needs λ > 0 and
    /// −1 < ν = α/λ < 0.5 (seed 000 eq. 3.39), so that K_e = λ C_e + α D_e is positive definite
    /// on non-rigid motions.
    Unphysical {
        /// The parameter set.
        set: u32,
        /// The element, for per-element parameters; `None` for global ones.
        element: Option<u32>,
        /// λ (Pa).
        lambda: f32,
        /// α (Pa).
        alpha: f32,
    },
    /// No fixed (Dirichlet) node: the static stiffness matrix would be singular (rigid motions
    /// are free).
    NoFixedNode,
    /// Every node is fixed: there is nothing to simulate.
    NoFreeNode,
    /// A free node belongs to no tetrahedron, so it has no stiffness and the system matrix would
    /// be singular (found by [`validate_node_coverage`](super::validate_node_coverage)).
    OrphanNode {
        /// The node.
        node: u32,
    },
}

impl fmt::Display for ModelError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            ModelError::BadMagic { found } => write!(
                f,
                "not a palpate model: magic bytes are {:02x} {:02x} {:02x} {:02x}, expected \"PALP\"",
                found[0], found[1], found[2], found[3]
            ),
            ModelError::UnsupportedVersion { found, supported } => write!(
                f,
                "model format version {found} is not supported (this build reads version {supported})"
            ),
            ModelError::WrongKind { found } => {
                write!(f, "container kind {found} is not a model (kind 1)")
            }
            ModelError::Truncated { needed, available } => write!(
                f,
                "model truncated: the container needs {needed} bytes, only {available} given"
            ),
            ModelError::TrailingBytes { extra } => {
                write!(f, "{extra} unexpected bytes after the model container's CRC")
            }
            ModelError::CrcMismatch { stored, computed } => write!(
                f,
                "model corrupted: stored CRC-32 {stored:#010x}, computed {computed:#010x}"
            ),
            ModelError::Malformed { field, kind } => {
                write!(f, "malformed model payload in field `{}`: {kind}", field.name())
            }
            ModelError::PayloadTrailingBytes { extra } => {
                write!(f, "{extra} unread bytes after the model record inside the payload")
            }
            ModelError::CapacityExceeded { what, needed, available } => {
                let what = match what {
                    Capacity::OutputBuffer => "output buffer",
                    Capacity::PayloadLength => "payload length field",
                    Capacity::Scratch => "scratch buffer",
                };
                write!(f, "{what} too small: {needed} bytes needed, {available} available")
            }
            ModelError::InvalidContent { what } => write!(f, "invalid model: {what}"),
        }
    }
}

impl core::error::Error for ModelError {}

impl fmt::Display for MalformedKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            MalformedKind::UnexpectedEnd => f.write_str("the payload ends inside it"),
            MalformedKind::BadVarint => f.write_str("bad varint"),
            MalformedKind::BadUtf8 => f.write_str("string is not valid UTF-8"),
            MalformedKind::UnknownVariant { found } => write!(f, "unknown variant {found}"),
            MalformedKind::BadEncoding => f.write_str("bad encoding"),
        }
    }
}

impl fmt::Display for Field {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// Writes `array[position]` and, for arrays with a per-node or per-element structure, which node
/// or element the value belongs to.
fn write_at(f: &mut fmt::Formatter<'_>, array: Field, position: u64) -> fmt::Result {
    if array == Field::StrainDecay {
        // A scalar: no position to show.
        return write!(f, "{array}");
    }
    write!(f, "{array}[{position}]")?;
    match array {
        Field::RestPositions => {
            let axis = ["x", "y", "z"][(position % 3) as usize];
            write!(f, " (node {}, {axis})", position / 3)
        }
        Field::Tets => write!(f, " (element {}, corner {})", position / 4, position % 4),
        Field::SurfaceTriangles => {
            write!(f, " (triangle {}, corner {})", position / 3, position % 3)
        }
        Field::CPacked | Field::DPacked => {
            write!(
                f,
                " (element {}, packed entry {})",
                position / 78,
                position % 78
            )
        }
        _ => Ok(()),
    }
}

impl fmt::Display for Invalid {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Invalid::PartialValue { array, bytes } => write!(
                f,
                "{array}: byte length {bytes} is not a whole number of 4-byte values"
            ),
            Invalid::LengthMismatch { array, expected, found } => {
                write!(f, "{array}: {found} values, expected {expected}")
            }
            Invalid::LengthNotMultiple { array, found, multiple } => {
                write!(f, "{array}: {found} values, not a multiple of {multiple}")
            }
            Invalid::NoElements => f.write_str("no tetrahedra (element_count is 0)"),
            Invalid::NoParameterSet => f.write_str("no parameter set (parameters.count is 0)"),
            Invalid::UnblendedSetCount { count } => write!(
                f,
                "blend is None (linear material) but there are {count} parameter sets, expected 1"
            ),
            Invalid::NoNeighbours => {
                f.write_str("blend.neighbours is 0 (each element is its own neighbour)")
            }
            Invalid::IndexOutOfRange { array, position, index, bound } => {
                write_at(f, array, position)?;
                write!(f, ": index {index} out of range (must be < {bound})")
            }
            Invalid::FixedNodesNotIncreasing { position, previous, index } => write!(
                f,
                "fixed_nodes[{position}]: node {index} after node {previous}; fixed nodes must be strictly increasing"
            ),
            Invalid::RepeatedNode { element, node } => {
                write!(f, "element {element}: node {node} appears twice")
            }
            Invalid::NonFinite { array, position } => {
                write_at(f, array, position)?;
                f.write_str(": not a finite number")
            }
            Invalid::Negative { array, position, value } => {
                write_at(f, array, position)?;
                write!(f, ": {value:e} is negative")
            }
            Invalid::ZeroVolume { element, volume } => write!(
                f,
                "element {element}: flat (zero-volume) rest element (signed volume {volume:.2e} m³)"
            ),
            Invalid::Inverted { element, volume } => write!(
                f,
                "element {element}: inverted rest element (signed volume {volume:.2e} m³)"
            ),
            Invalid::DegenerateTriangle { triangle, area } => write!(
                f,
                "surface triangle {triangle}: degenerate (area {area:.2e} m²)"
            ),
            Invalid::Unphysical { set, element, lambda, alpha } => {
                write!(f, "parameter set {set}")?;
                if let Some(e) = element {
                    write!(f, ", element {e}")?;
                }
                write!(
                    f,
                    ": unphysical λ = {lambda:e} Pa, α = {alpha:e} Pa (ν = α/λ = {:.4}); need λ > 0 and −1 < ν < 0.5",
                    alpha as f64 / lambda as f64
                )
            }
            Invalid::NoFixedNode => f.write_str(
                "no fixed (Dirichlet) node: the static stiffness matrix would be singular",
            ),
            Invalid::NoFreeNode => f.write_str("every node is fixed: nothing can move"),
            Invalid::OrphanNode { node } => write!(
                f,
                "node {node} is free but belongs to no tetrahedron: the stiffness matrix would be singular"
            ),
        }
    }
}

impl From<Invalid> for ModelError {
    fn from(what: Invalid) -> Self {
        ModelError::InvalidContent { what }
    }
}

//! The runtime's error type.

use core::fmt;

/// What went wrong building or driving a [`crate::Runtime`].
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub enum RuntimeError {
    /// The caller's storage is too small (`what`: "f32" or "u32" storage).
    CapacityExceeded {
        /// Which storage pool.
        what: &'static str,
        /// Values needed.
        needed: usize,
        /// Values provided.
        available: usize,
    },
    /// An array of the model has the wrong length (the protocol's validator catches this first;
    /// the runtime re-checks because it may be handed a record that never went through decode).
    ModelShape {
        /// Which array.
        what: &'static str,
        /// Expected number of values.
        expected: usize,
        /// Found number of values.
        found: usize,
    },
    /// An index of the model is out of range.
    IndexOutOfRange {
        /// Which array.
        what: &'static str,
        /// Position in that array.
        position: usize,
        /// The offending index.
        index: u32,
        /// Exclusive bound.
        bound: usize,
    },
    /// A rest element is degenerate (zero volume, inverted or non-finite).
    BadElement {
        /// Element index.
        element: usize,
    },
    /// The element's C_e or D_e does not match its rest geometry (eq. 3.63): a model whose
    /// matrices were computed from another mesh would simulate something else than was fitted.
    InconsistentElementMatrix {
        /// Element index.
        element: usize,
        /// Largest relative difference found.
        relative_difference: f32,
    },
    /// A parameter set is unphysical (needs λ > 0 and −1 < α/λ < 0.5).
    UnphysicalParameters {
        /// Set index.
        set: usize,
        /// Element index (0 for global sets).
        element: usize,
    },
    /// A node index given by the caller is out of range.
    NodeOutOfRange {
        /// The index given.
        node: usize,
        /// Number of nodes.
        nodes: usize,
    },
    /// A number given by the caller is not finite (or a radius is not positive).
    NonFiniteInput {
        /// What was given.
        what: &'static str,
    },
    /// The model failed one of the protocol's checks (e.g. a free node that belongs to no
    /// tetrahedron, [`palpate_protocol::model::Invalid::OrphanNode`], whose stiffness would be
    /// zero and the system singular).
    InvalidModel(palpate_protocol::model::ModelError),
    /// The contact rule loads no free node (lumped rule: no free surface node within the radius;
    /// consistent rule: the probe ball touches no surface triangle with a free node).
    ContactCoversNoNode {
        /// Distance to the nearest free surface node (m).
        nearest: f32,
    },
}

impl RuntimeError {
    /// Checks entry `position` of the model's index array `what` against its exclusive `bound`:
    /// the one check every index array gets when a model is loaded.
    pub(crate) fn check_index(
        what: &'static str,
        position: usize,
        index: u32,
        bound: usize,
    ) -> Result<(), Self> {
        if index as usize >= bound {
            return Err(Self::IndexOutOfRange {
                what,
                position,
                index,
                bound,
            });
        }
        Ok(())
    }
}

impl fmt::Display for RuntimeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Self::CapacityExceeded { what, needed, available } => {
                write!(f, "{what} storage too small: needed {needed} values, {available} available")
            }
            Self::ModelShape { what, expected, found } => {
                write!(f, "model array {what}: expected {expected} values, found {found}")
            }
            Self::IndexOutOfRange { what, position, index, bound } => {
                write!(f, "model array {what}[{position}] = {index} is out of range (bound {bound})")
            }
            Self::BadElement { element } => write!(f, "element {element}: zero-volume, inverted or non-finite"),
            Self::InconsistentElementMatrix { element, relative_difference } => write!(
                f,
                "element {element}: C_e/D_e differ from its rest geometry by {relative_difference:e} (relative)"
            ),
            Self::UnphysicalParameters { set, element } => write!(
                f,
                "parameter set {set}, element {element}: unphysical (need λ > 0 and −1 < α/λ < 0.5)"
            ),
            Self::NodeOutOfRange { node, nodes } => write!(f, "node {node} out of range ({nodes} nodes)"),
            Self::NonFiniteInput { what } => write!(f, "{what} is not finite (or not positive)"),
            Self::InvalidModel(e) => write!(f, "invalid model: {e}"),
            Self::ContactCoversNoNode { nearest } => write!(
                f,
                "contact radius covers no free surface node (nearest is {nearest:e} m away)"
            ),
        }
    }
}

impl core::error::Error for RuntimeError {}

//! The model record: what a fitted palpate model contains (card: "per-element C_e/D_e, RBF
//! weights, strain centres"). Bulk arrays are little-endian byte strings borrowed from the
//! container, so decoding never allocates and never copies.

use serde::{Deserialize, Serialize};

/// Version of the model record layout. Bump on any change; only ever append enum variants.
pub const MODEL_FORMAT_VERSION: u16 = 1;

/// Physical units of every quantity in the model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Units {
    /// SI: metres, newtons, pascals, kilograms, seconds.
    Si,
}

/// Where a model came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Provenance<'a> {
    /// The tool and command that produced the model, e.g. `palpate 0.1.0 fit --material …`.
    pub tool: &'a str,
    /// Creation time, ISO 8601 UTC.
    pub created: &'a str,
    /// The data it was fitted from (dataset name or path).
    pub source: &'a str,
    /// Free-text notes (fit figures, warnings).
    pub notes: &'a str,
}

/// A little-endian `f32` array stored as raw bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct F32s<'a>(#[serde(borrow)] pub &'a [u8]);

/// A little-endian `u32` array stored as raw bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct U32s<'a>(#[serde(borrow)] pub &'a [u8]);

/// The accessors of a little-endian word array (`F32s`, `U32s`) and its writer.
macro_rules! le_words {
    ($array:ident, $word:ty, $write:ident) => {
        impl<'a> $array<'a> {
            /// Number of values (bytes / 4, rounded down; validation rejects a remainder).
            pub fn len(&self) -> usize {
                self.0.len() / 4
            }
            /// True when empty.
            pub fn is_empty(&self) -> bool {
                self.0.len() < 4
            }
            /// Value `i`, or `None` past the end.
            #[inline]
            pub fn get(&self, i: usize) -> Option<$word> {
                let b = self.0.get(4 * i..4 * i + 4)?;
                Some(<$word>::from_le_bytes([b[0], b[1], b[2], b[3]]))
            }
            /// All values in order.
            pub fn iter(&self) -> impl Iterator<Item = $word> + 'a {
                self.0
                    .chunks_exact(4)
                    .map(|b| <$word>::from_le_bytes([b[0], b[1], b[2], b[3]]))
            }
        }

        /// Writes `src` as little-endian bytes into `dst` (which must hold `4 * src.len()`
        /// bytes); returns the number of bytes written, or `None` if `dst` is too short.
        pub fn $write(src: &[$word], dst: &mut [u8]) -> Option<usize> {
            let n = 4 * src.len();
            let dst = dst.get_mut(..n)?;
            for (d, v) in dst.chunks_exact_mut(4).zip(src) {
                d.copy_from_slice(&v.to_le_bytes());
            }
            Some(n)
        }
    };
}

le_words!(F32s, f32, write_f32s);
le_words!(U32s, u32, write_u32s);

/// Whether parameter sets hold one (λ, α) pair or one per element (eqs. 3.36–3.38, 3.61).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum ParameterLayout {
    /// One (λ, α) for the whole object (homogeneous).
    Global,
    /// One (λ_e, α_e) per element (inhomogeneous).
    PerElement,
}

/// One or more fitted parameter sets. Linear materials have `count == 1`; non-linear materials
/// have one set per fitted measurement, blended at run time by [`Blend`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct ParameterSets<'a> {
    /// Global or per-element.
    pub layout: ParameterLayout,
    /// Number of sets.
    pub count: u32,
    /// λ values (Pa), set-major: `count × (1 | element_count)`.
    #[serde(borrow)]
    pub lambda: F32s<'a>,
    /// α values (Pa), same layout as `lambda`.
    #[serde(borrow)]
    pub alpha: F32s<'a>,
}

/// How parameter sets are blended at run time (seed 000 §6.2).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum Blend<'a> {
    /// Linear material: the single parameter set is used as is (§6.2.1–6.2.2).
    None,
    /// Non-linear homogeneous (§6.2.3, eqs. 6.2–6.5): λ = Σ_i w_i^λ φ(‖x − x̄_i‖), biharmonic
    /// φ(r) = r, centres x̄_i = fitted deformed node positions.
    Deformation {
        /// Centres: `count × 3 · node_count` deformed positions (m).
        #[serde(borrow)]
        centres: F32s<'a>,
        /// w^λ (`count` values).
        #[serde(borrow)]
        weights_lambda: F32s<'a>,
        /// w^α (`count` values).
        #[serde(borrow)]
        weights_alpha: F32s<'a>,
    },
    /// Non-linear inhomogeneous (§6.2.4, eqs. 6.7–6.11): per-element RBFs in strain space with
    /// the locally weighted strain distance ‖e − ē_l‖_e² = Σ_{e'} w_{e,e'} ‖ε_{e'} − ε̄^l_{e'}‖²,
    /// w_{e,e'} = exp(−c ‖c_e − c_{e'}‖²) over the `neighbours` nearest element centroids.
    Strain {
        /// Decay c (1/m²) of the spatial weighting.
        decay: f32,
        /// Neighbours per element k (including the element itself).
        neighbours: u32,
        /// Neighbour element indices: `element_count × k`.
        #[serde(borrow)]
        neighbour_index: U32s<'a>,
        /// Neighbour weights w_{e,e'}: `element_count × k`.
        #[serde(borrow)]
        neighbour_weight: F32s<'a>,
        /// Strain centres ε̄^l_e: `count × element_count × 6` (eq. 6.8).
        #[serde(borrow)]
        centres: F32s<'a>,
        /// w^λ_{e,l}: `element_count × count`.
        #[serde(borrow)]
        weights_lambda: F32s<'a>,
        /// w^α_{e,l}: `element_count × count`.
        #[serde(borrow)]
        weights_alpha: F32s<'a>,
    },
}

/// A complete palpate model.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ModelRecord<'a> {
    /// Units of every quantity.
    pub units: Units,
    /// What produced the model.
    #[serde(borrow)]
    pub provenance: Provenance<'a>,
    /// Number of nodes n.
    pub node_count: u32,
    /// Number of tetrahedra t.
    pub element_count: u32,
    /// Rest positions x₀: `3n` values (m).
    #[serde(borrow)]
    pub rest_positions: F32s<'a>,
    /// The mesh file's node tags (Gmsh), `n` values; CSV output names nodes by these.
    #[serde(borrow)]
    pub node_tags: U32s<'a>,
    /// Tetrahedra: `4t` node indices, positively oriented.
    #[serde(borrow)]
    pub tets: U32s<'a>,
    /// Fixed (Dirichlet) node indices.
    #[serde(borrow)]
    pub fixed_nodes: U32s<'a>,
    /// Boundary triangles: `3s` node indices, wound outward (probing and markers).
    #[serde(borrow)]
    pub surface_triangles: U32s<'a>,
    /// C_e = V_e B_eᵀ F B_e packed symmetric (78 values per element, upper triangle row-major).
    #[serde(borrow)]
    pub c_packed: F32s<'a>,
    /// D_e = V_e B_eᵀ G B_e packed the same way.
    #[serde(borrow)]
    pub d_packed: F32s<'a>,
    /// Fitted parameter sets.
    #[serde(borrow)]
    pub parameters: ParameterSets<'a>,
    /// Run-time blending of the sets.
    #[serde(borrow)]
    pub blend: Blend<'a>,
}

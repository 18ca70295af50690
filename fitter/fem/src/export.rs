//! Export of a fitted model as a palpate model file (`protocol::model`): rest mesh, fixed
//! nodes, surface, per-element C_e/D_e from the shared `element_cd` (packed symmetric), the fitted
//! parameter sets and the blending data, f64 → f32, with provenance (tool and command, UTC time,
//! source). Files are written atomically. Static fits ([`ModelBuffers::new`]) and motion fits
//! ([`ModelBuffers::from_mesh`]) share one record builder ([`ModelBuffers::build`]).

use std::path::Path;

use palpate_protocol::model::{
    encode, encoded_len, node_coverage_scratch_len, validate_node_coverage, ModelError,
    ModelRecord, OwnedBlend, OwnedModel, ParameterLayout,
};
use palpate_runtime::element::{element_cd, pack_symmetric, tet_geometry, TetGeometry, PACKED_LEN};

use crate::forward::{Material, StaticProblem};
use crate::mesh::Mesh;

/// Errors of the export.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    /// The record is not a valid model (names what and where).
    #[error("the fitted model is not a valid palpate model: {0}")]
    Model(#[from] ModelError),
    /// A node tag does not fit the format's u32.
    #[error("node {node} has tag {tag}, which does not fit in 32 bits")]
    Tag {
        /// Node index.
        node: usize,
        /// Its tag.
        tag: u64,
    },
    /// Parameter sets are inconsistent.
    #[error("parameter sets: {0}")]
    Sets(String),
    /// Writing the file failed.
    #[error("writing the model: {0}")]
    Write(String),
}

/// Blending data ready for export (seed 000 §6: the deformation-space and strain-space RBF
/// blends fitted by the static fit).
#[derive(Debug, Clone, PartialEq)]
pub enum BlendData {
    /// Linear material: no blending.
    None,
    /// Homogeneous non-linear: RBF over deformations.
    Deformation {
        /// `count × 3n` centres (m).
        centres: Vec<f64>,
        /// w^λ.
        weights_lambda: Vec<f64>,
        /// w^α.
        weights_alpha: Vec<f64>,
    },
    /// Inhomogeneous non-linear: per-element RBF in strain space.
    Strain {
        /// Decay c (1/m²).
        decay: f64,
        /// Neighbours per element k.
        neighbours: usize,
        /// `t × k` neighbour indices.
        neighbour_index: Vec<u32>,
        /// `t × k` weights w_{e,e'}.
        neighbour_weight: Vec<f64>,
        /// `count × t × 6` strain centres ε̄^l_e.
        centres: Vec<f64>,
        /// `t × count` w^λ_{e,l}.
        weights_lambda: Vec<f64>,
        /// `t × count` w^α_{e,l}.
        weights_alpha: Vec<f64>,
    },
}

/// Provenance strings of a model.
#[derive(Debug, Clone, Default)]
pub struct ProvenanceInfo {
    /// Tool and command line.
    pub tool: String,
    /// The data it was fitted from.
    pub source: String,
    /// Notes (fit figures, warnings).
    pub notes: String,
}

/// Owned little-endian buffers backing a [`ModelRecord`]: the protocol's [`OwnedModel`],
/// built only by this module's validating constructors.
#[derive(Debug, Clone)]
pub struct ModelBuffers {
    model: OwnedModel,
}

fn f32s(v: impl IntoIterator<Item = f64>) -> Vec<u8> {
    v.into_iter()
        .flat_map(|x| (x as f32).to_le_bytes())
        .collect()
}
fn u32s(v: impl IntoIterator<Item = u32>) -> Vec<u8> {
    v.into_iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// The current UTC time as ISO 8601 (from the system clock; civil date by Howard Hinnant's
/// days-from-civil inverse).
pub fn utc_now() -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs())
        .unwrap_or(0);
    let days = (secs / 86_400) as i64;
    let rem = secs % 86_400;
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + if m <= 2 { 1 } else { 0 };
    format!(
        "{y:04}-{m:02}-{d:02}T{:02}:{:02}:{:02}Z",
        rem / 3600,
        (rem / 60) % 60,
        rem % 60
    )
}

/// The geometry a model record is built from: rest mesh, per-element rest geometry, fixed nodes
/// and surface. Both the static fit ([`ModelBuffers::new`]) and the motion fit
/// ([`ModelBuffers::from_mesh`]) go through this one description.
#[derive(Debug, Clone, Copy)]
pub struct ModelGeometry<'a> {
    /// Rest positions (m).
    pub x0: &'a [[f64; 3]],
    /// Tetrahedra (node indices).
    pub tets: &'a [[usize; 4]],
    /// Rest geometry of each element (from the shared `tet_geometry`).
    pub geometry: &'a [TetGeometry<f64>],
    /// `fixed[i]`: node i is held at rest in the runtime.
    pub fixed: &'a [bool],
    /// Boundary triangles.
    pub surface: &'a [[usize; 3]],
}

impl ModelBuffers {
    /// Builds the buffers from a static problem, its node tags, fitted sets and blend.
    pub fn new(
        problem: &StaticProblem,
        node_tags: &[u64],
        sets: &[Material],
        blend: &BlendData,
        prov: &ProvenanceInfo,
    ) -> Result<Self, ExportError> {
        let geom = ModelGeometry {
            x0: &problem.x0,
            tets: &problem.tets,
            geometry: &problem.geometry,
            fixed: &problem.fixed,
            surface: &problem.surface,
        };
        Self::build(&geom, node_tags, sets, blend, prov)
    }

    /// Builds the buffers of a single parameter set (no blending) from a mesh, its fixed nodes
    /// (indices) and per-element or global thesis parameters (λ_e, α_e) — the motion fitter's
    /// export. The surface is the mesh boundary.
    pub fn from_mesh(
        mesh: &Mesh,
        fixed: &[usize],
        params: &Material,
        prov: &ProvenanceInfo,
    ) -> Result<Self, ExportError> {
        if fixed.is_empty() {
            return Err(ExportError::Sets(
                "no fixed nodes: the runtime needs at least one clamped node".into(),
            ));
        }
        Self::from_mesh_sets(
            mesh,
            fixed,
            std::slice::from_ref(params),
            &BlendData::None,
            prov,
        )
    }

    /// Builds the buffers from a mesh, its fixed nodes (indices, possibly none: the runtime's
    /// own refusal is then what a caller sees), parameter sets and blend. The rest geometry is
    /// computed here, the surface is the mesh boundary. [`Self::from_mesh`] and the runtime
    /// tests' models come through here.
    pub fn from_mesh_sets(
        mesh: &Mesh,
        fixed: &[usize],
        sets: &[Material],
        blend: &BlendData,
        prov: &ProvenanceInfo,
    ) -> Result<Self, ExportError> {
        let n = mesh.nodes.len();
        let mut is_fixed = vec![false; n];
        for &i in fixed {
            *is_fixed.get_mut(i).ok_or_else(|| {
                ExportError::Sets(format!("fixed node {i} out of range ({n} nodes)"))
            })? = true;
        }
        let mut geometry = Vec::with_capacity(mesh.tets.len());
        for (e, t) in mesh.tets.iter().enumerate() {
            if let Some(&node) = t.iter().find(|&&i| i >= n) {
                return Err(ExportError::Sets(format!(
                    "element {e} refers to node {node} ({n} nodes)"
                )));
            }
            let x = t.map(|i| nalgebra::Vector3::from(mesh.nodes[i]));
            geometry.push(tet_geometry(&x).map_err(|d| {
                ExportError::Sets(format!("element {e}: unusable rest geometry ({d:?})"))
            })?);
        }
        let surface = mesh.boundary_triangles();
        let geom = ModelGeometry {
            x0: &mesh.nodes,
            tets: &mesh.tets,
            geometry: &geometry,
            fixed: &is_fixed,
            surface: &surface,
        };
        Self::build(&geom, &mesh.node_tags, sets, blend, prov)
    }

    /// The one record-building path: element C_e/D_e from the shared `element_cd`, f64 → f32.
    pub fn build(
        geom: &ModelGeometry<'_>,
        node_tags: &[u64],
        sets: &[Material],
        blend: &BlendData,
        prov: &ProvenanceInfo,
    ) -> Result<Self, ExportError> {
        let t = geom.tets.len();
        let node_count = geom.x0.len();
        if node_tags.len() != node_count || geom.fixed.len() != node_count {
            return Err(ExportError::Sets(format!(
                "{} node tags and {} fixed flags for {node_count} nodes",
                node_tags.len(),
                geom.fixed.len()
            )));
        }
        if geom.geometry.len() != t {
            return Err(ExportError::Sets(format!(
                "{} element geometries for {t} elements",
                geom.geometry.len()
            )));
        }
        if sets.is_empty() {
            return Err(ExportError::Sets("no parameter set".into()));
        }
        let per_element = !sets[0].is_homogeneous();
        for (k, s) in sets.iter().enumerate() {
            if s.is_homogeneous() == per_element || (per_element && s.lambda.len() != t) {
                return Err(ExportError::Sets(format!(
                    "set {k} has {} values; all sets must be global or all per element ({t})",
                    s.lambda.len()
                )));
            }
        }
        let mut tags = Vec::with_capacity(node_tags.len());
        for (node, &tag) in node_tags.iter().enumerate() {
            tags.push(u32::try_from(tag).map_err(|_| ExportError::Tag { node, tag })?);
        }
        let mut c = Vec::with_capacity(t * PACKED_LEN * 4);
        let mut d = Vec::with_capacity(t * PACKED_LEN * 4);
        let mut buf = [0.0f64; PACKED_LEN];
        for g in geom.geometry {
            let (ce, de) = element_cd(g);
            pack_symmetric(&ce, &mut buf);
            c.extend(f32s(buf.iter().copied()));
            pack_symmetric(&de, &mut buf);
            d.extend(f32s(buf.iter().copied()));
        }
        let blend = match blend {
            BlendData::None => OwnedBlend::None,
            BlendData::Deformation {
                centres,
                weights_lambda,
                weights_alpha,
            } => OwnedBlend::Deformation {
                centres: f32s(centres.iter().copied()),
                weights_lambda: f32s(weights_lambda.iter().copied()),
                weights_alpha: f32s(weights_alpha.iter().copied()),
            },
            BlendData::Strain {
                decay,
                neighbours,
                neighbour_index,
                neighbour_weight,
                centres,
                weights_lambda,
                weights_alpha,
            } => OwnedBlend::Strain {
                decay: *decay as f32,
                neighbours: *neighbours as u32,
                neighbour_index: u32s(neighbour_index.iter().copied()),
                neighbour_weight: f32s(neighbour_weight.iter().copied()),
                centres: f32s(centres.iter().copied()),
                weights_lambda: f32s(weights_lambda.iter().copied()),
                weights_alpha: f32s(weights_alpha.iter().copied()),
            },
        };
        let model = OwnedModel {
            node_count: node_count as u32,
            element_count: t as u32,
            rest_positions: f32s(geom.x0.iter().flat_map(|p| p.iter().copied())),
            node_tags: u32s(tags),
            tets: u32s(geom.tets.iter().flat_map(|t| t.iter().map(|&n| n as u32))),
            fixed_nodes: u32s((0..node_count).filter(|&i| geom.fixed[i]).map(|i| i as u32)),
            surface_triangles: u32s(
                geom.surface
                    .iter()
                    .flat_map(|t| t.iter().map(|&n| n as u32)),
            ),
            c_packed: c,
            d_packed: d,
            layout: if per_element {
                ParameterLayout::PerElement
            } else {
                ParameterLayout::Global
            },
            count: sets.len() as u32,
            lambda: f32s(sets.iter().flat_map(|s| s.lambda.iter().copied())),
            alpha: f32s(sets.iter().flat_map(|s| s.alpha.iter().copied())),
            blend,
            tool: prov.tool.clone(),
            created: utc_now(),
            source: prov.source.clone(),
            notes: prov.notes.clone(),
        };
        Ok(Self { model })
    }

    /// The record borrowing these buffers.
    pub fn record(&self) -> ModelRecord<'_> {
        self.model.record()
    }

    /// Encodes (validating) into a byte vector.
    pub fn encode(&self) -> Result<Vec<u8>, ExportError> {
        let rec = self.record();
        let mut out = vec![0u8; encoded_len(&rec)?];
        let n = encode(&rec, &mut out)?;
        // The one check `encode` cannot make without memory, on the record it has validated:
        // every free node in some tet (an orphan makes K' singular; the runtime refuses it).
        let mut scratch = vec![0u8; node_coverage_scratch_len(rec.node_count)];
        validate_node_coverage(&rec, &mut scratch)?;
        out.truncate(n);
        Ok(out)
    }

    /// Encodes and writes atomically to `path`.
    pub fn write(&self, path: &Path) -> Result<usize, ExportError> {
        let bytes = self.encode()?;
        crate::io::atomic::write_atomic(path, &bytes)
            .map_err(|e| ExportError::Write(format!("{}: {e:#}", path.display())))?;
        Ok(bytes.len())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use palpate_protocol::model::Invalid;
    use palpate_runtime::material::LambdaAlpha;

    /// The unit corner tet, plus node 4 in no tet (fixed or free as asked), its face on z = 0
    /// fixed.
    fn with_extra_node(extra_fixed: bool) -> Result<Vec<u8>, ExportError> {
        let mesh = Mesh {
            nodes: vec![
                [0., 0., 0.],
                [1., 0., 0.],
                [0., 1., 0.],
                [0., 0., 1.],
                [2., 2., 2.],
            ],
            node_tags: (1..=5).collect(),
            tets: vec![[0, 1, 2, 3]],
            node_groups: Default::default(),
        };
        let mut fixed = vec![0, 1, 2];
        if extra_fixed {
            fixed.push(4);
        }
        let prov = ProvenanceInfo {
            tool: "test".into(),
            source: "test".into(),
            notes: String::new(),
        };
        let material = Material::homogeneous(LambdaAlpha {
            lambda: 2e4,
            alpha: 5e3,
        });
        ModelBuffers::from_mesh_sets(&mesh, &fixed, &[material], &BlendData::None, &prov)?.encode()
    }

    /// A free node in no tet would leave the runtime's K' singular: the writer refuses it,
    /// naming the node, as the format asks of a writer; fixed, the same node is harmless.
    #[test]
    fn an_orphan_free_node_is_never_written() {
        match with_extra_node(false) {
            Err(ExportError::Model(ModelError::InvalidContent {
                what: Invalid::OrphanNode { node: 4 },
            })) => {}
            other => panic!("expected the orphan node 4 refused, got {other:?}"),
        }
        assert!(with_extra_node(true).is_ok());
    }
}

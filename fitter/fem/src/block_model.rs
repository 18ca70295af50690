//! A generated benchmark and test object: a 10 × 10 × 5 cm block of about `tets` tetrahedra with
//! its bottom face fixed (the scenario of the VegaFEM anchor in ANCHORS.md), exported through the
//! same record builder as every fitted model ([`ModelBuffers`]), so benches, tests and the haptic
//! commands play exactly what a fit would export.

use palpate_protocol::model::ModelRecord;
use palpate_runtime::material::LambdaAlpha;

use crate::export::{ExportError, ModelBuffers, ProvenanceInfo};
use crate::forward::Material;
use crate::mesh::boxmesh::{box_mesh, cells_for_target};
use crate::mesh::Mesh;

/// Owned buffers of a generated block model.
pub struct BlockModel {
    /// The mesh.
    pub mesh: Mesh,
    /// Fixed nodes (the `bottom` group).
    pub fixed: Vec<usize>,
    buffers: ModelBuffers,
}

impl BlockModel {
    /// A homogeneous 10 × 10 × 5 cm block of about `tets` tetrahedra with the bottom fixed.
    pub fn block(tets: usize, p: LambdaAlpha) -> Result<Self, ExportError> {
        let size = [0.1, 0.1, 0.05];
        let mesh = box_mesh(size, cells_for_target(size, tets));
        let fixed = mesh
            .group("bottom")
            .map_err(|e| ExportError::Sets(format!("the generated block: {e}")))?
            .to_vec();
        let prov = ProvenanceInfo {
            tool: "palpate generated block".into(),
            source: format!("box mesh {:?} m, {} tets", size, mesh.tets.len()),
            notes: String::new(),
        };
        let buffers = ModelBuffers::from_mesh(&mesh, &fixed, &Material::homogeneous(p), &prov)?;
        Ok(Self {
            mesh,
            fixed,
            buffers,
        })
    }

    /// A block of `mesh` with `fixed` nodes whose model was built elsewhere (a blended model of
    /// the runtime bench, whose blend the static fitter makes).
    pub fn from_parts(mesh: Mesh, fixed: Vec<usize>, buffers: ModelBuffers) -> Self {
        Self {
            mesh,
            fixed,
            buffers,
        }
    }

    /// The model record borrowing the buffers.
    pub fn record(&self) -> ModelRecord<'_> {
        self.buffers.record()
    }
}

//! Builds in-memory model records from a mesh for runtime tests (the fitter's exporter does the
//! same for real models; this one lets runtime tests choose parameters and blends directly).

use nalgebra::Vector3;
use palpate_fem::mesh::Mesh;
use palpate_protocol::model::{
    Blend, F32s, ModelRecord, ParameterLayout, ParameterSets, Provenance, U32s, Units,
};
use palpate_runtime::element::{element_cd, pack_symmetric, tet_geometry, PACKED_LEN};

/// Little-endian bytes of f32 values.
pub fn f32_bytes(v: impl IntoIterator<Item = f32>) -> Vec<u8> {
    v.into_iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// Little-endian bytes of u32 values.
pub fn u32_bytes(v: impl IntoIterator<Item = u32>) -> Vec<u8> {
    v.into_iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// Owned byte arrays behind a [`ModelRecord`].
pub struct ModelBuffers {
    /// Node count.
    pub n: u32,
    /// Element count.
    pub t: u32,
    rest: Vec<u8>,
    tags: Vec<u8>,
    tets: Vec<u8>,
    fixed: Vec<u8>,
    tris: Vec<u8>,
    c: Vec<u8>,
    d: Vec<u8>,
    /// λ values (set-major).
    pub lambda: Vec<u8>,
    /// α values (set-major).
    pub alpha: Vec<u8>,
    /// Parameter layout.
    pub layout: ParameterLayout,
    /// Number of sets.
    pub sets: u32,
    /// Blend arrays (interpretation by `blend_kind`).
    pub blend_f: [Vec<u8>; 4],
    /// Neighbour indices for strain blending.
    pub blend_u: Vec<u8>,
    /// 0 none, 1 deformation, 2 strain.
    pub blend_kind: u8,
    /// Strain decay c.
    pub decay: f32,
    /// Strain-blend neighbours k.
    pub neighbours: u32,
}

impl ModelBuffers {
    /// A linear homogeneous model of `mesh` with the nodes of `fixed` fixed.
    pub fn homogeneous(mesh: &Mesh, fixed: &[usize], lambda: f64, alpha: f64) -> Self {
        let n = mesh.nodes.len();
        let t = mesh.tets.len();
        let mut c = Vec::with_capacity(4 * PACKED_LEN * t);
        let mut d = Vec::with_capacity(4 * PACKED_LEN * t);
        for tet in &mesh.tets {
            let x = tet.map(|i| Vector3::from(mesh.nodes[i]));
            let g = tet_geometry(&x).expect("valid test mesh");
            let (cm, dm) = element_cd(&g);
            let mut cp = [0.0f64; PACKED_LEN];
            let mut dp = [0.0f64; PACKED_LEN];
            pack_symmetric(&cm, &mut cp);
            pack_symmetric(&dm, &mut dp);
            c.extend(f32_bytes(cp.iter().map(|v| *v as f32)));
            d.extend(f32_bytes(dp.iter().map(|v| *v as f32)));
        }
        let tris = mesh.boundary_triangles();
        Self {
            n: n as u32,
            t: t as u32,
            rest: f32_bytes(mesh.nodes.iter().flat_map(|p| p.map(|v| v as f32))),
            tags: u32_bytes(mesh.node_tags.iter().map(|v| *v as u32)),
            tets: u32_bytes(mesh.tets.iter().flat_map(|t| t.map(|i| i as u32))),
            fixed: u32_bytes(fixed.iter().map(|i| *i as u32)),
            tris: u32_bytes(tris.iter().flat_map(|t| t.map(|i| i as u32))),
            c,
            d,
            lambda: f32_bytes([lambda as f32]),
            alpha: f32_bytes([alpha as f32]),
            layout: ParameterLayout::Global,
            sets: 1,
            blend_f: Default::default(),
            blend_u: Vec::new(),
            blend_kind: 0,
            decay: 0.0,
            neighbours: 0,
        }
    }

    /// The record borrowing these buffers.
    pub fn record(&self) -> ModelRecord<'_> {
        let blend = match self.blend_kind {
            1 => Blend::Deformation {
                centres: F32s(&self.blend_f[0]),
                weights_lambda: F32s(&self.blend_f[1]),
                weights_alpha: F32s(&self.blend_f[2]),
            },
            2 => Blend::Strain {
                decay: self.decay,
                neighbours: self.neighbours,
                neighbour_index: U32s(&self.blend_u),
                neighbour_weight: F32s(&self.blend_f[3]),
                centres: F32s(&self.blend_f[0]),
                weights_lambda: F32s(&self.blend_f[1]),
                weights_alpha: F32s(&self.blend_f[2]),
            },
            _ => Blend::None,
        };
        ModelRecord {
            units: Units::Si,
            provenance: Provenance {
                tool: "palpate-tests",
                created: "",
                source: "test mesh",
                notes: "",
            },
            node_count: self.n,
            element_count: self.t,
            rest_positions: F32s(&self.rest),
            node_tags: U32s(&self.tags),
            tets: U32s(&self.tets),
            fixed_nodes: U32s(&self.fixed),
            surface_triangles: U32s(&self.tris),
            c_packed: F32s(&self.c),
            d_packed: F32s(&self.d),
            parameters: ParameterSets {
                layout: self.layout,
                count: self.sets,
                lambda: F32s(&self.lambda),
                alpha: F32s(&self.alpha),
            },
            blend,
        }
    }
}

//! Average nodal pressure (Bonet & Burton 1998, "A simple average nodal pressure tetrahedral
//! element"): the linear tetrahedron's strain energy split into its deviatoric part, kept per
//! element, and its volumetric part, taken per node on the volume-weighted mean of the
//! volumetric strain over the node's patch,
//!
//! Π = Σ_e V_e μ_e ‖dev ε_e‖² + Σ_n ½ κ_n V_n θ_n²,  θ_n = Σ_{e∋n} (V_e/4) tr ε_e / V_n,
//! V_n = Σ_{e∋n} V_e/4.
//!
//! The incompressibility constraints are one per node instead of one per element — about a
//! sixth as many on a Kuhn mesh — which leaves the bending modes free at ν → ½. A linear field
//! has the same tr ε in every element, so θ_n equals it and the patch test passes.

use nalgebra::{DMatrix, Vector3};
use palpate_runtime::element::TetGeometry;

use super::discretisation::{add_isotropic, lame, Blocks};
use super::Material;

/// The element gradients and volumes, and per node its patch (the nodes its volumetric strain
/// depends on) and the gradient of θ_n V_n over the patch's dofs.
#[derive(Debug, Clone)]
pub(super) struct NodalPressure {
    grads: Vec<[Vector3<f64>; 4]>,
    volumes: Vec<f64>,
    /// Elements around each node (flattened, `patch_offsets`).
    elements: Vec<usize>,
    patch_offsets: Vec<usize>,
    /// g_n = ∂(V_n θ_n)/∂u over the patch's nodes, 3 per node, flattened like the blocks.
    g: Vec<f64>,
    g_offsets: Vec<usize>,
    /// V_n.
    node_volume: Vec<f64>,
    /// The node of each volumetric block (nodes in no element have none).
    block_node: Vec<usize>,
}

impl NodalPressure {
    /// The design and its blocks: one per element (deviatoric, 4 nodes), then one per node
    /// (volumetric, its patch's nodes).
    pub(super) fn new(
        tets: &[[usize; 4]],
        geometry: &[TetGeometry<f64>],
        node_count: usize,
    ) -> (Self, Blocks) {
        let mut blocks = Blocks::default();
        for t in tets {
            blocks.push(t);
        }
        let mut around: Vec<Vec<usize>> = vec![Vec::new(); node_count];
        for (e, t) in tets.iter().enumerate() {
            for &n in t {
                around[n].push(e);
            }
        }
        let mut elements = Vec::new();
        let mut patch_offsets = vec![0];
        let mut g = Vec::new();
        let mut g_offsets = vec![0];
        let mut node_volume = vec![0.0; node_count];
        let mut block_node = Vec::new();
        for (n, es) in around.iter().enumerate() {
            let mut patch: Vec<usize> = es.iter().flat_map(|&e| tets[e]).collect();
            patch.sort_unstable();
            patch.dedup();
            let mut gn = vec![0.0; 3 * patch.len()];
            for &e in es {
                let w = 0.25 * geometry[e].volume;
                node_volume[n] += w;
                for (k, &m) in tets[e].iter().enumerate() {
                    let p = patch
                        .binary_search(&m)
                        .expect("element node is in the patch");
                    for d in 0..3 {
                        // tr ε_e = Σ_k ∇φ_k · u_k.
                        gn[3 * p + d] += w * geometry[e].grad[k][d];
                    }
                }
            }
            elements.extend_from_slice(es);
            patch_offsets.push(elements.len());
            if !patch.is_empty() {
                blocks.push(&patch);
                block_node.push(n);
            }
            g.extend_from_slice(&gn);
            g_offsets.push(g.len());
        }
        (
            Self {
                grads: geometry.iter().map(|g| g.grad).collect(),
                volumes: geometry.iter().map(|g| g.volume).collect(),
                elements,
                patch_offsets,
                g,
                g_offsets,
                node_volume,
                block_node,
            },
            blocks,
        )
    }

    /// Adds block b: element b's deviatoric stiffness, or for b past the elements the
    /// volumetric stiffness κ_n g_n g_nᵀ / V_n of a node (nodes in no element have no block).
    pub(super) fn add_block(&self, b: usize, material: &Material, k: &mut DMatrix<f64>) {
        let ne = self.volumes.len();
        if b < ne {
            // dev: Lamé's λ replaced by −2μ/3 takes out the volumetric part κ (tr ε)², κ = λ + 2μ/3.
            let (_, mu) = lame(material, b);
            add_isotropic(k, &self.grads[b], self.volumes[b], -2.0 / 3.0 * mu, mu);
            return;
        }
        let n = self.block_node[b - ne];
        let es = &self.elements[self.patch_offsets[n]..self.patch_offsets[n + 1]];
        // κ_n: the patch's volume-weighted bulk modulus (the material may vary per element).
        let kappa = es
            .iter()
            .map(|&e| {
                let (lambda, mu) = lame(material, e);
                0.25 * self.volumes[e] * (lambda + 2.0 / 3.0 * mu)
            })
            .sum::<f64>()
            / self.node_volume[n];
        let gn = &self.g[self.g_offsets[n]..self.g_offsets[n + 1]];
        let s = kappa / self.node_volume[n];
        for i in 0..gn.len() {
            for j in 0..gn.len() {
                k[(i, j)] += s * gn[i] * gn[j];
            }
        }
    }
}

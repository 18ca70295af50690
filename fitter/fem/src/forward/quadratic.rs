//! Quadratic (10-node) tetrahedra: shape functions N_a = L_a (2L_a − 1) at the corners and
//! N_ab = 4 L_a L_b at the edge midpoints (L the barycentric coordinates, whose gradients are the
//! linear element's ∇φ), so strains vary linearly over an element and bending needs no element
//! to change its volume in a way it cannot. The stiffness integrand is quadratic on a
//! straight-sided element, so the 4-point rule of degree 2 integrates it exactly.

use nalgebra::{DMatrix, Vector3};
use palpate_runtime::element::TetGeometry;

use super::discretisation::{add_isotropic, lame};
use super::Material;
use crate::mesh::quadratic::QUADRATIC_EDGES;

/// The 4-point rule of degree 2 on a tetrahedron (Keast): barycentric coordinates (a, b, b, b)
/// and permutations, each with weight V/4.
const RULE_A: f64 = 0.585_410_196_624_968_5;
const RULE_B: f64 = 0.138_196_601_125_010_5;

/// The rest geometry of the quadratic elements: the corner gradients ∇L_a and the volume.
#[derive(Debug, Clone)]
pub(super) struct Quadratic {
    grads: Vec<[Vector3<f64>; 4]>,
    volumes: Vec<f64>,
}

/// Gradients of the ten shape functions at barycentric point `l`, corners first, then edges in
/// [`QUADRATIC_EDGES`] order.
pub(super) fn shape_gradients(g: &[Vector3<f64>; 4], l: [f64; 4]) -> [Vector3<f64>; 10] {
    let mut out = [Vector3::zeros(); 10];
    for a in 0..4 {
        out[a] = g[a] * (4.0 * l[a] - 1.0);
    }
    for (k, [a, b]) in QUADRATIC_EDGES.iter().enumerate() {
        out[4 + k] = (g[*b] * l[*a] + g[*a] * l[*b]) * 4.0;
    }
    out
}

impl Quadratic {
    pub(super) fn new(geometry: &[TetGeometry<f64>]) -> Self {
        Self {
            grads: geometry.iter().map(|g| g.grad).collect(),
            volumes: geometry.iter().map(|g| g.volume).collect(),
        }
    }

    /// Adds element e's 30 × 30 stiffness ∫ Bᵀ D B dV to `k`.
    pub(super) fn add_element(&self, e: usize, material: &Material, k: &mut DMatrix<f64>) {
        let (lambda, mu) = lame(material, e);
        let w = 0.25 * self.volumes[e];
        for q in 0..4 {
            let mut l = [RULE_B; 4];
            l[q] = RULE_A;
            let grads = shape_gradients(&self.grads[e], l);
            add_isotropic(k, &grads, w, lambda, mu);
        }
    }
}

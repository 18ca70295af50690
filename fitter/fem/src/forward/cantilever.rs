//! The clamped box cantilever under an end shear load, the bending case in which linear
//! tetrahedra lock as Poisson's ratio nears ½: the evidence for choosing a [`Discretisation`]
//! (tests, `palpate-lab bench discretisation`).
//!
//! The beam [0, L] × [0, b] × [0, h] is meshed with [`box_mesh`], clamped on x = 0 and loaded by
//! a uniform traction on x = L of total force P along −z, spread as each design's consistent
//! nodal loads. Its tip deflection is read as the load's work per unit force, δ = fᵀu / P (the
//! traction-weighted mean of u_z over the end face), which every design's solve converges to
//! from below.

use std::time::Instant;

use nalgebra::Matrix3;

use super::{Discretisation, DiscretisedModel, ForwardError, Material, StaticProblem};
use crate::mesh::boxmesh::box_mesh;
use crate::mesh::Mesh;

/// One cantilever: geometry, mesh, material and load.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cantilever {
    /// Length L, width b (y) and height h (z), m.
    pub size: [f64; 3],
    /// Cells per axis of the box mesh (six tetrahedra each).
    pub cells: [usize; 3],
    /// Young's modulus (Pa).
    pub young: f64,
    /// Poisson's ratio.
    pub poisson: f64,
    /// Total end load P (N), along −z.
    pub load: f64,
}

/// A solved cantilever and what the solve cost.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TipDeflection {
    /// δ = fᵀu / P (m).
    pub deflection: f64,
    /// Free dofs.
    pub dofs: usize,
    /// Nonzeros of the stiffness over the free dofs.
    pub nonzeros: usize,
    /// Building the model: element data, sparsity pattern, symbolic factorisation (s).
    pub setup_seconds: f64,
    /// One solve: assembly, numeric Cholesky, triangular solves (s): what a fitter pays per
    /// forward solve.
    pub solve_seconds: f64,
}

impl Cantilever {
    /// The mesh, its clamped nodes and the end face's boundary triangles.
    pub fn mesh(&self) -> (Mesh, Vec<usize>, Vec<[usize; 3]>) {
        let m = box_mesh(self.size, self.cells);
        let fixed = m.node_groups["left"].clone();
        let mut right = vec![false; m.nodes.len()];
        for &i in &m.node_groups["right"] {
            right[i] = true;
        }
        let end = m
            .boundary_triangles()
            .into_iter()
            .filter(|t| t.iter().all(|&i| right[i]))
            .collect();
        (m, fixed, end)
    }

    /// The end traction (Pa) that sums to the load.
    fn traction(&self) -> [f64; 3] {
        [0.0, 0.0, -self.load / (self.size[1] * self.size[2])]
    }

    /// Solves the cantilever with `design` (small strains).
    pub fn tip_deflection(&self, design: Discretisation) -> Result<TipDeflection, ForwardError> {
        let (m, fixed, end) = self.mesh();
        let material = Material::from_young_poisson(self.young, self.poisson);
        let t0 = Instant::now();
        let p = StaticProblem::new(&m, &fixed, &m.boundary_triangles())?;
        if design == Discretisation::Linear {
            let setup_seconds = t0.elapsed().as_secs_f64();
            // The linear triangle's consistent loads: a third of each triangle's force at each
            // corner.
            let mut f = vec![0.0; 3 * m.nodes.len()];
            for t in &end {
                let [a, b, c] = t.map(|i| nalgebra::Vector3::from(m.nodes[i]));
                let area = 0.5 * (b - a).cross(&(c - a)).norm();
                for &i in t {
                    f[3 * i + 2] += self.traction()[2] * area / 3.0;
                }
            }
            let t1 = Instant::now();
            let identities = vec![Matrix3::identity(); p.tets.len()];
            let factor = p.factorise(&material, &identities)?;
            let mut u = p.gather_free(&f);
            factor.solve_in_place(&mut u);
            let solve_seconds = t1.elapsed().as_secs_f64();
            let work = p
                .gather_free(&f)
                .iter()
                .zip(&u)
                .map(|(a, b)| a * b)
                .sum::<f64>();
            return Ok(TipDeflection {
                deflection: work / self.load,
                dofs: p.free_dofs(),
                nonzeros: factor.values().len(),
                setup_seconds,
                solve_seconds,
            });
        }
        let model = DiscretisedModel::new(&p, design)?;
        let setup_seconds = t0.elapsed().as_secs_f64();
        let f = model.traction_load(&end, self.traction());
        let t1 = Instant::now();
        let factor = model.factorise(&material)?;
        let u = model.displacement(&factor, &f)?;
        let solve_seconds = t1.elapsed().as_secs_f64();
        let work = u
            .iter()
            .enumerate()
            .map(|(i, d)| (0..3).map(|k| f[3 * i + k] * d[k]).sum::<f64>())
            .sum::<f64>();
        Ok(TipDeflection {
            deflection: work / self.load,
            dofs: model.free_dofs(),
            nonzeros: model.nonzeros(),
            setup_seconds,
            solve_seconds,
        })
    }

    /// Timoshenko's tip deflection of the end-loaded cantilever, P L³ / (3 E I) + P L / (κ G A),
    /// with Cowper's shear coefficient of a rectangle κ = 10 (1 + ν) / (12 + 11 ν). A 3-D beam
    /// clamped over its whole end face is a little stiffer (the clamp also stops the section's
    /// Poisson contraction), by an amount that grows with ν and shrinks with L/h.
    pub fn timoshenko(&self) -> f64 {
        let [l, b, h] = self.size;
        let (e, nu, p) = (self.young, self.poisson, self.load);
        let i = b * h.powi(3) / 12.0;
        let g = e / (2.0 * (1.0 + nu));
        let kappa = 10.0 * (1.0 + nu) / (12.0 + 11.0 * nu);
        p * l.powi(3) / (3.0 * e * i) + p * l / (kappa * g * b * h)
    }
}

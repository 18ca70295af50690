//! The dataset mesh's own discretisation error: how far the markers of a fitted model would move if
//! the same model were solved on the mesh refined once (every tetrahedron into eight,
//! [`crate::mesh::refine`]). Linear tetrahedra are too stiff at the dataset's resolution, most under
//! a concentrated probe load; a residual of that size is the mesh, not a missing physical effect.
//!
//! The estimate is u_h − u_{h/2} at the observed markers, with the measurement's probe contact
//! (the shared lumped rule on each mesh) and the model's homogeneous (λ, α). For displacements
//! converging as O(h²) it is ≈ 3/4 of the true error u_h − u; it is reported as measured.

use crate::dataset::refine::{refine_dataset, RefineError};
use crate::dataset::StaticDataset;
use crate::forward::{ForwardError, Load, Material, SolveOptions, StaticProblem};
use palpate_runtime::material::LambdaAlpha;

/// Marker-level difference between the model on the dataset mesh and on the mesh refined once.
#[derive(Debug, Clone)]
pub struct MeshError {
    /// RMS over all observed markers of all measurements (m).
    pub rms: f64,
    /// Largest marker difference (m).
    pub max: f64,
    /// RMS per measurement (id, m).
    pub per_measurement: Vec<(String, f64)>,
    /// Tetrahedra of the refined mesh.
    pub refined_tets: usize,
}

/// Why the estimate could not be made.
#[derive(Debug, thiserror::Error)]
pub enum MeshErrorError {
    /// A forward solve failed.
    #[error(transparent)]
    Forward(#[from] ForwardError),
    /// The dataset could not be carried over to the refined mesh.
    #[error(transparent)]
    Refine(#[from] RefineError),
}

/// Estimates the discretisation error of the homogeneous warped-linear model `material` on `ds`.
pub fn mesh_error(ds: &StaticDataset, material: LambdaAlpha) -> Result<MeshError, MeshErrorError> {
    mesh_error_against(ds, &refine_dataset(ds)?, material)
}

/// [`mesh_error`] against an already refined copy `fine` of `ds` ([`refine_dataset`]).
pub fn mesh_error_against(
    ds: &StaticDataset,
    fine: &StaticDataset,
    material: LambdaAlpha,
) -> Result<MeshError, MeshErrorError> {
    let coarse = StaticProblem::new(&ds.mesh, &ds.fixed_nodes, &ds.surface)?;
    let refined = StaticProblem::new(&fine.mesh, &fine.fixed_nodes, &fine.surface)?;
    let mat = Material::homogeneous(material);
    let opts = SolveOptions::default();
    let (mut sum2, mut count, mut max) = (0.0, 0usize, 0.0f64);
    let mut per = Vec::with_capacity(ds.measurements.len());
    for meas in &ds.measurements {
        let load = Load::contact(meas.contact, meas.force, meas.radius);
        let xc = coarse.solve(&mat, &load, &opts)?.x;
        let xf = refined.solve(&mat, &load, &opts)?.x;
        let (mut s2, mut c) = (0.0, 0usize);
        for &(k, _) in &meas.observed {
            let pc = ds.markers[k].interpolate(|i| xc[i]);
            let pf = fine.markers[k].interpolate(|i| xf[i]);
            let d2: f64 = (0..3).map(|d| (pc[d] - pf[d]).powi(2)).sum();
            s2 += d2;
            c += 1;
            max = max.max(d2.sqrt());
        }
        sum2 += s2;
        count += c;
        per.push((meas.id.clone(), (s2 / c.max(1) as f64).sqrt()));
    }
    Ok(MeshError {
        rms: (sum2 / count.max(1) as f64).sqrt(),
        max,
        per_measurement: per,
        refined_tets: fine.mesh.tets.len(),
    })
}

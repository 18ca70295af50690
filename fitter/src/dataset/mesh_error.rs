//! The dataset mesh's own discretisation error: how far the markers of a fitted model would move if
//! the same model were solved on the mesh refined once (every tetrahedron into eight,
//! [`crate::mesh::refine`]). Linear tetrahedra are too stiff at the dataset's resolution, most under
//! a concentrated probe load; a residual of that size is the mesh, not a missing physical effect.
//!
//! The estimate is u_h − u_{h/2} at the observed markers, with the measurement's probe contact
//! (the shared lumped rule on each mesh) and the model's homogeneous (λ, α). For displacements
//! converging as O(h²) it is ≈ 3/4 of the true error u_h − u; it is reported as measured.

use crate::dataset::embed::embed_point;
use crate::dataset::StaticDataset;
use crate::forward::{ForwardError, Load, Material, SolveOptions, StaticProblem};
use crate::mesh::refine::refine_with_midpoints;
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
    /// A marker could not be located on the refined surface.
    #[error("marker {0:?} does not lie on the refined mesh's surface")]
    Embed(String),
}

/// Estimates the discretisation error of the homogeneous warped-linear model `material` on `ds`.
pub fn mesh_error(ds: &StaticDataset, material: LambdaAlpha) -> Result<MeshError, MeshErrorError> {
    let (fine, mid) = refine_with_midpoints(&ds.mesh);
    // Fixed: the dataset's fixed nodes and the midpoints of edges between two of them.
    let fixed: std::collections::HashSet<usize> = ds.fixed_nodes.iter().copied().collect();
    let mut fixed_f = ds.fixed_nodes.clone();
    for (&(a, b), &m) in &mid {
        if fixed.contains(&a) && fixed.contains(&b) {
            fixed_f.push(m);
        }
    }
    fixed_f.sort_unstable();
    let surf_f = fine.boundary_triangles();
    let coarse = StaticProblem::new(&ds.mesh, &ds.fixed_nodes, &ds.surface)?;
    let refined = StaticProblem::new(&fine, &fixed_f, &surf_f)?;
    let emb: Vec<_> = ds
        .markers
        .iter()
        .map(|m| {
            embed_point(&fine, &surf_f, m.rest).ok_or_else(|| MeshErrorError::Embed(m.id.clone()))
        })
        .collect::<Result<_, _>>()?;
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
            let e = &emb[k];
            let mut pf = [0.0; 3];
            for (&n, &b) in e.triangle.iter().zip(&e.barycentric) {
                for d in 0..3 {
                    pf[d] += b * xf[n][d];
                }
            }
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
        refined_tets: fine.tets.len(),
    })
}

//! The approximation-error correction (Kaipio & Somersalo, "Statistical inverse problems:
//! discretization, model reduction and inverse crimes", J. Comput. Appl. Math. 198, 2007): fit on
//! the coarse dataset mesh, but add to every predicted marker the difference δ between the same
//! model solved on the mesh refined once and on the dataset mesh,
//!
//!   x̂_marker(θ) = x_h(θ) + δ,   δ = x_{h/2}(θ*) − x_h(θ*),
//!
//! evaluated at the current fit θ* and refreshed after every adopted effect. At θ = θ* the
//! corrected coarse model predicts exactly what the refined model does, and near θ* it moves as
//! the coarse model does: the candidate fits keep the coarse mesh's cost (the loop makes thousands
//! of solves) while the residual they are scored on no longer carries the coarse mesh's
//! discretisation error — which on the 648-tet specimen is two thirds of the noise floor and
//! otherwise gets absorbed by whichever candidate best mimics a softer mesh.
//!
//! Every model parameter means the same thing on both meshes (the material fields are functions
//! of element centroids over the same bounding box, the loads use the shared contact rule), so one
//! θ drives both solves.

use super::fit::{fit, Fitted};
use super::model::{Context, Model};
use super::DiagnoseError;
use palpate_fem::dataset::StaticDataset;

/// The refined-mesh side of the correction.
pub struct Correction {
    /// The model context on the refined dataset.
    fine: Context,
    /// The last refined solution per measurement (warm start of the next refresh).
    x: Option<Vec<Vec<[f64; 3]>>>,
}

impl Correction {
    /// Prepares the refined side from the refined dataset (same measurements, same markers).
    pub fn new(fine: &StaticDataset, grid: [usize; 3]) -> Result<Self, DiagnoseError> {
        Ok(Self {
            fine: Context::new(fine, grid)?,
            x: None,
        })
    }

    /// Places the inclusion candidate's blob where the coarse context has it (the sensitivity
    /// scan moves it after both contexts are built; the refined side must evaluate the same
    /// field, or δ compares two different models).
    pub fn set_inclusion_start(&mut self, p: [f64; 3]) {
        self.fine.inclusion.centre = p;
    }

    /// Measures the layer candidate's depth along `axis` on the refined side too (the scan
    /// picks the axis after both contexts are built).
    pub fn set_layer_axis(&mut self, axis: crate::statics::model::LayerAxis) {
        self.fine.set_layer_axis(axis);
    }

    /// Tetrahedra of the refined mesh.
    pub fn refined_tets(&self) -> usize {
        self.fine.problem.element_count()
    }

    /// δ at (`model`, `theta`) for every measurement of `coarse` (aligned with each
    /// measurement's observed markers), given the coarse solutions `xs` of all measurements.
    pub fn delta(
        &mut self,
        coarse: &Context,
        model: &Model,
        theta: &[f64],
        xs: &[Vec<[f64; 3]>],
    ) -> Result<Vec<Vec<[f64; 3]>>, DiagnoseError> {
        let all: Vec<usize> = (0..coarse.meas.len()).collect();
        if xs.len() != all.len() {
            return Err(DiagnoseError::Input(format!(
                "approximation-error correction needs the solutions of all {} measurements, got {}",
                all.len(),
                xs.len()
            )));
        }
        // δ compares the solves' states; a profiled effect's responses (the per-measurement
        // tilt's two more solves per measurement) are not part of it.
        let x = model.solve_states(&self.fine, theta, &all, self.x.as_deref())?;
        let delta = all
            .iter()
            .map(|&i| {
                coarse.meas[i]
                    .observed
                    .iter()
                    .map(|&(k, _)| {
                        let f = self.fine.markers[k].interpolate(|n| x[i][n]);
                        let c = coarse.markers[k].interpolate(|n| xs[i][n]);
                        [0, 1, 2].map(|d| f[d] - c[d])
                    })
                    .collect()
            })
            .collect();
        self.x = Some(x);
        Ok(delta)
    }
}

/// RMS of a correction over all observed markers (m).
pub fn delta_rms(delta: &[Vec<[f64; 3]>]) -> f64 {
    let (mut s, mut n) = (0.0, 0usize);
    for d in delta.iter().flatten() {
        s += d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
        n += 1;
    }
    (s / n.max(1) as f64).sqrt()
}

/// Largest marker correction |δ| over all observed markers (m).
pub fn delta_max(delta: &[Vec<[f64; 3]>]) -> f64 {
    delta
        .iter()
        .flatten()
        .map(|d| (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt())
        .fold(0.0, f64::max)
}

/// Refreshes the approximation-error correction at fit `f` (all measurements) and refits.
pub(super) fn refresh(
    ctx: &mut Context,
    corr: &mut Correction,
    f: &Fitted,
    iterations: usize,
) -> Result<Fitted, DiagnoseError> {
    ctx.correction = Some(corr.delta(ctx, &f.model, &f.theta, &f.sim.x)?);
    fit(
        ctx,
        &f.model,
        f.theta.clone(),
        &f.subset,
        Some(&f.sim.x),
        iterations,
    )
}

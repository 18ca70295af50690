//! The augmented forward model: the warped linear homogeneous FEM of seed 000 (the simplest model
//! a static dataset can be fitted with) plus any set of candidate effects, each adding a few
//! parameters. Parameters θ are dimensionless (each block has a documented scale) so one finite
//! difference step fits all.
//!
//! Layout: θ₀ = log E (Pa), θ₁ = s with ν = −1/4 + 3/4 · tanh(s) (any real θ is physical), then
//! one block per effect in the order of [`Model::effects`].
//!
//! What each effect adds is its own ([`super::candidates`]): the model calls the hooks of
//! [`StaticEffect`] of the effects it holds, in library order, at fixed places of the solve —
//! the force, the load, the material, the state-dependent equilibrium, the markers' embedding,
//! their motion, and the closed-form profiles over the simulated markers.

use nalgebra::Vector3;
use palpate_runtime::material::LambdaAlpha;
use rayon::prelude::*;
use serde::Serialize;

use super::candidates::{At, ResponseStates, ResponsesNear, StaticEffect};
use super::DiagnoseError;

pub use super::candidates::{Candidate, ALL_CANDIDATES, TILT_PROBE};
pub use super::context::{
    BlobScan, Context, Frame, InclusionStart, LayerAxis, LayerDepth, MeasData,
};
use palpate_fem::dataset::Marker;
use palpate_fem::forward::{Factorised, Load, Material, StaticProblem};
use std::sync::Arc;

/// A model: the base material plus an ordered set of effects.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct Model {
    /// Adopted effects, in adoption order.
    pub effects: Vec<Candidate>,
}

/// ν from θ₁.
pub fn poisson_of(s: f64) -> f64 {
    -0.25 + 0.75 * s.tanh()
}

/// θ₁ from ν.
pub fn s_of(nu: f64) -> f64 {
    ((nu + 0.25) / 0.75).clamp(-0.999_999, 0.999_999).atanh()
}

/// Simulated positions of a measurement: node positions and the observed markers' positions.
#[derive(Debug, Clone)]
pub struct Simulated {
    /// Node positions per simulated measurement.
    pub x: Vec<Vec<[f64; 3]>>,
    /// Simulated marker positions (per measurement, aligned with `observed`).
    pub markers: Vec<Vec<[f64; 3]>>,
    /// The markers re-embedded at the gravity candidate's rest-scan material points, one per
    /// marker (`None`: the dataset's own embedding).
    pub embedding: Option<Vec<Marker>>,
    /// [`Candidate::TiltEach`]: per measurement, the simulated markers' response to a unit
    /// tangential coefficient along t₁ and t₂ (m per unit of |f|).
    pub tilt: Option<Vec<[Vec<[f64; 3]>; 2]>>,
    /// The node positions of the solves `tilt` was read from (where nearby simulations start
    /// theirs).
    pub tilted: Option<ResponseStates>,
    /// The factorisation of K' each measurement's solve ended with (start of nearby solves).
    pub factors: Vec<Arc<Factorised>>,
}

impl Model {
    /// The base model.
    pub fn base() -> Self {
        Self {
            effects: Vec::new(),
        }
    }

    /// With one more effect.
    pub fn with(&self, c: Candidate) -> Self {
        let mut m = self.clone();
        m.effects.push(c);
        m
    }

    /// Total parameter count.
    pub fn param_count(&self, grid: [usize; 3]) -> usize {
        2 + self.effects.iter().map(|c| c.params(grid)).sum::<usize>()
    }

    /// Offset of effect `c`'s block in θ.
    pub fn offset(&self, c: Candidate, grid: [usize; 3]) -> Option<usize> {
        let mut o = 2;
        for &e in &self.effects {
            if e == c {
                return Some(o);
            }
            o += e.params(grid);
        }
        None
    }

    /// Whether θ_j changes the FEM solve.
    pub fn affects_solve(&self, j: usize, grid: [usize; 3]) -> bool {
        if j < 2 {
            return true;
        }
        let mut o = 2;
        for &e in &self.effects {
            let k = e.params(grid);
            if j < o + k {
                return e.affects_solve();
            }
            o += k;
        }
        false
    }

    fn block<'a>(&self, c: Candidate, theta: &'a [f64], grid: [usize; 3]) -> Option<&'a [f64]> {
        self.offset(c, grid).map(|o| &theta[o..o + c.params(grid)])
    }

    /// The effects the model holds with their θ blocks, in library order (the order their hooks
    /// compose in, whatever order they were adopted in).
    fn held<'a>(
        &'a self,
        theta: &'a [f64],
        grid: [usize; 3],
    ) -> impl Iterator<Item = (&'static dyn StaticEffect, &'a [f64])> + 'a {
        ALL_CANDIDATES
            .iter()
            .filter_map(move |&c| self.block(c, theta, grid).map(|b| (c.effect(), b)))
    }

    /// The force the model applies for measurement `i`.
    pub fn model_force(&self, ctx: &Context, theta: &[f64], i: usize) -> [f64; 3] {
        let f = ctx.meas[i].force;
        let fm = Vector3::from(f).norm();
        self.held(theta, ctx.grid)
            .fold(f, |out, (e, b)| e.force(ctx, b, fm, out))
    }

    /// The nodal force vector of measurement `i`'s probe carrying `force`: the dataset's contact
    /// rule (lumped onto the free surface nodes within the declared radius r), and the changes
    /// the effects make to it (a contact patch of another radius).
    pub fn load_vector(
        &self,
        ctx: &Context,
        theta: &[f64],
        i: usize,
        force: [f64; 3],
    ) -> Result<Vec<f64>, DiagnoseError> {
        let m = &ctx.meas[i];
        // The dataset's forces are finite (checked when read): a force that is not is the
        // model's, at parameters where an effect's law leaves the numbers (a calibration power
        // stepped far by a fit). The model is undefined there, as where it diverges: a trial step
        // the fit refuses, a held-out measurement the refit cannot predict — not bad input that
        // would end the diagnosis.
        if !force.iter().all(|v| v.is_finite()) {
            return Err(DiagnoseError::Diverged(format!(
                "measurement {:?}: the model's probe force {force:?} is not finite at these \
                 parameters",
                m.id
            )));
        }
        let problem = self.problem(ctx);
        let mut f = problem
            .force_vector(&Load::contact(m.point, force, m.radius))
            .map_err(|e| DiagnoseError::Input(format!("measurement {:?}: {e}", m.id)))?;
        for (e, b) in self.held(theta, ctx.grid) {
            e.load_change(problem, m, b, force, &mut f)?;
        }
        Ok(f)
    }

    /// [`Model::load_vector`] with the loads that act in every measurement (gravity).
    pub(in crate::statics) fn full_load(
        &self,
        ctx: &Context,
        theta: &[f64],
        i: usize,
        force: [f64; 3],
    ) -> Result<Vec<f64>, DiagnoseError> {
        let mut fvec = self.load_vector(ctx, theta, i, force)?;
        for (e, b) in self.held(theta, ctx.grid) {
            e.body_force(ctx, b, &mut fvec);
        }
        Ok(fvec)
    }

    /// The material of the solve at `theta` without the stiffening fixed point: the field
    /// candidates' log E on the base E (what [`crate::sensitivity`] differentiates).
    pub fn field_material(&self, ctx: &Context, theta: &[f64]) -> Result<Material, DiagnoseError> {
        let log_e = self.log_e_field(ctx, theta);
        self.material(ctx, theta, log_e.as_deref(), None)
    }

    /// Per-element log-E offsets of the spatial material effects (inhomogeneity, layer,
    /// inclusion); `None` without any.
    fn log_e_field(&self, ctx: &Context, theta: &[f64]) -> Option<Vec<f64>> {
        let mut fields = self
            .held(theta, ctx.grid)
            .filter(|(e, _)| e.material_field())
            .peekable();
        fields.peek()?;
        let mut out = vec![0.0; ctx.centroids.len()];
        for (e, b) in fields {
            e.add_log_e(ctx, b, &mut out);
        }
        Some(out)
    }

    /// The solve's material at `theta`: the field offsets `log_e` and the state-dependent ones
    /// `extra` on the base E, and the effects' changes to it (a foundation).
    pub(in crate::statics) fn material(
        &self,
        ctx: &Context,
        theta: &[f64],
        log_e: Option<&[f64]>,
        extra: Option<&[f64]>,
    ) -> Result<Material, DiagnoseError> {
        let mut m = self.bulk_material(theta, log_e, extra)?;
        for (e, b) in self.held(theta, ctx.grid) {
            e.material(ctx, theta, b, &mut m);
        }
        Ok(m)
    }

    /// The problem the model solves: the foundation's when it holds an effect solved on it.
    pub fn problem<'a>(&self, ctx: &'a Context) -> &'a StaticProblem {
        let on_foundation = self.effects.iter().any(|c| c.effect().on_foundation());
        match (&ctx.foundation, on_foundation) {
            (Some(p), true) => p,
            _ => &ctx.problem,
        }
    }

    /// (λ, α) per element (or one pair) at `theta`.
    fn bulk_material(
        &self,
        theta: &[f64],
        log_e: Option<&[f64]>,
        extra: Option<&[f64]>,
    ) -> Result<Material, DiagnoseError> {
        let nu = poisson_of(theta[1]);
        let check = |e: f64| {
            if e.is_finite() && e > 0.0 && e < 1e15 {
                Ok(LambdaAlpha::from_young_poisson(e, nu))
            } else {
                Err(DiagnoseError::Diverged(format!(
                    "Young's modulus {e:e} Pa left the physical range"
                )))
            }
        };
        match (log_e, extra) {
            (None, None) => Ok(Material::homogeneous(check(theta[0].exp())?)),
            _ => {
                let n = log_e
                    .map(|v| v.len())
                    .or(extra.map(|v| v.len()))
                    .unwrap_or(0);
                let ps: Result<Vec<_>, _> = (0..n)
                    .map(|e| {
                        check(
                            (theta[0] + log_e.map_or(0.0, |v| v[e]) + extra.map_or(0.0, |v| v[e]))
                                .exp(),
                        )
                    })
                    .collect();
                Ok(Material::per_element(&ps?))
            }
        }
    }

    /// Solves the measurements in `subset` (warm-started from `warm` if given: one x per
    /// measurement in `subset` order) and returns node and marker positions.
    pub fn simulate(
        &self,
        ctx: &Context,
        theta: &[f64],
        subset: &[usize],
        warm: Option<&[Vec<[f64; 3]>]>,
    ) -> Result<Simulated, DiagnoseError> {
        self.simulate_with(ctx, theta, subset, warm, None, None)
    }

    /// [`Model::simulate`] near `base` (a Jacobian column, a Levenberg–Marquardt trial):
    /// warm-started from its states and starting from its factorisations of K', which serve the
    /// nearby solves as long as they contract ([`StaticProblem::solve_forces_with`]).
    pub fn simulate_near(
        &self,
        ctx: &Context,
        theta: &[f64],
        subset: &[usize],
        base: &Simulated,
    ) -> Result<Simulated, DiagnoseError> {
        let hints = (base.factors.len() == subset.len()).then_some(base.factors.as_slice());
        let near = base
            .tilted
            .as_deref()
            .filter(|t| t.len() == subset.len() && base.x.len() == subset.len())
            .map(|t| (base.x.as_slice(), t));
        self.simulate_with(ctx, theta, subset, Some(&base.x), hints, near)
    }

    fn simulate_with(
        &self,
        ctx: &Context,
        theta: &[f64],
        subset: &[usize],
        warm: Option<&[Vec<[f64; 3]>]>,
        hints: Option<&[Arc<Factorised>]>,
        near: Option<ResponsesNear>,
    ) -> Result<Simulated, DiagnoseError> {
        let log_e = self.log_e_field(ctx, theta);
        let at = self.at(ctx, theta, log_e.as_deref());
        let (xs, factors) = self.solve_all(at, subset, warm, hints)?;
        let embedding = self
            .held(theta, ctx.grid)
            .find_map(|(e, b)| e.marker_embedding(at, b))
            .transpose()?;
        let (tilt, tilted) = match self
            .held(theta, ctx.grid)
            .find_map(|(e, _)| e.responses(at, subset, (&xs, &factors, embedding.as_deref()), near))
        {
            Some(r) => {
                let (t, s) = r?;
                (Some(t), Some(s))
            }
            None => (None, None),
        };
        Ok(Simulated {
            markers: self.markers_from(
                ctx,
                theta,
                subset,
                &xs,
                embedding.as_deref(),
                tilt.as_deref(),
            ),
            x: xs,
            factors,
            embedding,
            tilt,
            tilted,
        })
    }

    /// The model at `theta` on `ctx`, with its stiffness field `log_e`, as the hooks see it.
    fn at<'a>(&'a self, ctx: &'a Context, theta: &'a [f64], log_e: Option<&'a [f64]>) -> At<'a> {
        At {
            model: self,
            ctx,
            theta,
            log_e,
        }
    }

    /// The node positions of the measurements in `subset` at `theta` (warm-started from `warm`,
    /// one x per measurement in `subset` order), without the markers and the extra solves a
    /// profiled effect reads its responses from: what the approximation-error correction
    /// compares between meshes.
    pub fn solve_states(
        &self,
        ctx: &Context,
        theta: &[f64],
        subset: &[usize],
        warm: Option<&[Vec<[f64; 3]>]>,
    ) -> Result<Vec<Vec<[f64; 3]>>, DiagnoseError> {
        let log_e = self.log_e_field(ctx, theta);
        let at = self.at(ctx, theta, log_e.as_deref());
        Ok(self.solve_all(at, subset, warm, None)?.0)
    }

    /// Every measurement's solve ([`Model::solve_one`]) and the factorisation it ended with.
    fn solve_all(
        &self,
        at: At,
        subset: &[usize],
        warm: Option<&[Vec<[f64; 3]>]>,
        hints: Option<&[Arc<Factorised>]>,
    ) -> Result<(Vec<Vec<[f64; 3]>>, Vec<Arc<Factorised>>), DiagnoseError> {
        // Measurements are independent solves: one per core (the refined mesh of the
        // approximation-error correction spends most of its time here).
        Ok(subset
            .par_iter()
            .enumerate()
            .map(|(k, &i)| {
                let start = warm.map(|w| w[k].as_slice());
                self.solve_one(at, i, start, hints.and_then(|h| h.get(k)))
            })
            .collect::<Result<Vec<_>, _>>()?
            .into_iter()
            .unzip())
    }

    /// Solves measurement `i` at `at` (warm-started from `start`, from the factorisation `hint`):
    /// its node positions and the factorisation of K' the solve ended with.
    fn solve_one(
        &self,
        at: At,
        i: usize,
        start: Option<&[[f64; 3]]>,
        hint: Option<&Arc<Factorised>>,
    ) -> Result<(Vec<[f64; 3]>, Arc<Factorised>), DiagnoseError> {
        let (ctx, theta) = (at.ctx, at.theta);
        let m = &ctx.meas[i];
        let f = self.model_force(ctx, theta, i);
        let fvec = self.full_load(ctx, theta, i, f)?;
        let secant = self
            .held(theta, ctx.grid)
            .find(|(e, _)| e.state_dependent());
        // Warm-started (a Jacobian column, an LM trial, a held-out refit): the secant moduli
        // at the warm state are already close to the fixed point, so start there rather than
        // from the linear material (measured: a stiffening-only diagnosis of a 648-tet
        // specimen takes 14.8 s of CPU instead of 28 s, with identical scores).
        let m0 = match (secant, start) {
            (Some((e, b)), Some(w)) => e.secant_log_e(ctx, w, b),
            _ => None,
        };
        let mat = self.material(ctx, theta, at.log_e, m0.as_deref())?;
        let solved = self
            .problem(ctx)
            .solve_forces_with(&mat, &fvec, start, &ctx.solve, hint)?;
        let linear = (solved.solution.x, solved.factor);
        match secant {
            Some((e, b)) => e.equilibrium(at, b, (&fvec, &m.id), m0, linear),
            None => Ok(linear),
        }
    }

    /// [`Candidate::TiltEach`]'s marker responses at a simulation `sim` of this model (whether or
    /// not the model holds the candidate): what the power statement of a clean verdict needs.
    pub fn tilt_responses(
        &self,
        ctx: &Context,
        theta: &[f64],
        subset: &[usize],
        sim: &Simulated,
    ) -> Result<Vec<[Vec<[f64; 3]>; 2]>, DiagnoseError> {
        let log_e = self.log_e_field(ctx, theta);
        let at = self.at(ctx, theta, log_e.as_deref());
        super::candidates::tilt_each_responses(
            at,
            subset,
            (&sim.x, &sim.factors, sim.embedding.as_deref()),
            None,
        )
        .map(|(responses, _)| responses)
    }

    /// The material the model uses at the solved state `x` (the secant moduli of the
    /// state-dependent effect evaluated at x's strains): what the runtime export blends between.
    pub fn material_at(
        &self,
        ctx: &Context,
        theta: &[f64],
        x: &[[f64; 3]],
    ) -> Result<Material, DiagnoseError> {
        let log_e = self.log_e_field(ctx, theta);
        let extra = self
            .held(theta, ctx.grid)
            .find_map(|(e, b)| e.secant_log_e(ctx, x, b));
        self.material(ctx, theta, log_e.as_deref(), extra.as_deref())
    }

    /// Whether the model's material depends on the solved state (one material per state).
    pub fn state_dependent(&self) -> bool {
        self.effects.iter().any(|c| c.effect().state_dependent())
    }

    /// Marker positions from solved node positions: the effects' marker motion applied
    /// (the physical markers), then the profiled per-measurement effects (a gain per
    /// measurement, the tangential force of [`Candidate::TiltEach`] from its responses `tilt`,
    /// the rigid transform of [`Candidate::RegistrationEach`]).
    pub fn markers_from(
        &self,
        ctx: &Context,
        theta: &[f64],
        subset: &[usize],
        xs: &[Vec<[f64; 3]>],
        embedding: Option<&[Marker]>,
        tilt: Option<&[[Vec<[f64; 3]>; 2]]>,
    ) -> Vec<Vec<[f64; 3]>> {
        let mut sims: Vec<Vec<[f64; 3]>> = subset
            .iter()
            .zip(xs)
            .map(|(&i, x)| self.physical_markers(ctx, theta, i, x, embedding))
            .collect();
        for (e, _) in self.held(theta, ctx.grid) {
            e.scale_responses(ctx, subset, &mut sims);
        }
        sims.into_iter()
            .zip(subset)
            .enumerate()
            .map(|(k, (sim, &i))| {
                let responses = tilt.and_then(|t| t.get(k));
                self.held(theta, ctx.grid)
                    .fold(sim, |sim, (e, _)| e.profile(ctx, i, sim, responses))
            })
            .collect()
    }

    /// Measurement `i`'s observed markers on the solved positions `x`, with the mesh correction
    /// and the effects with parameters in θ that move markers (the support's motion, the global
    /// registration).
    pub(in crate::statics) fn physical_markers(
        &self,
        ctx: &Context,
        theta: &[f64],
        i: usize,
        x: &[[f64; 3]],
        embedding: Option<&[Marker]>,
    ) -> Vec<[f64; 3]> {
        let m = &ctx.meas[i];
        let f = self.model_force(ctx, theta, i);
        let delta = ctx.correction.as_ref().map(|c| &c[i]);
        m.observed
            .iter()
            .enumerate()
            .map(|(j, &(k, _))| {
                let marker = embedding.map_or(&ctx.markers[k], |e| &e[k]);
                let mut p = marker.interpolate(|n| x[n]);
                if let Some(d) = delta {
                    p = [0, 1, 2].map(|a| p[a] + d[j][a]);
                }
                self.held(theta, ctx.grid)
                    .fold(p, |p, (e, b)| e.move_marker(ctx, b, m, f, p))
            })
            .collect()
    }

    /// Scaled residuals (simulated − measured)/σ of `subset`, stacked.
    pub fn residuals(
        &self,
        ctx: &Context,
        subset: &[usize],
        markers: &[Vec<[f64; 3]>],
    ) -> Vec<f64> {
        let mut r = Vec::with_capacity(ctx.residual_len(subset));
        for (&i, sim) in subset.iter().zip(markers) {
            for (&(_, meas), p) in ctx.meas[i].observed.iter().zip(sim) {
                for d in 0..3 {
                    r.push((p[d] - meas[d]) / ctx.sigma);
                }
            }
        }
        r
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use palpate_fem::dataset::StaticDataset;

    /// A calibration power stepped far makes the model's probe force infinite: the model is
    /// undefined there, a divergence a fit refuses, not bad input that ends the diagnosis.
    #[test]
    fn a_non_finite_model_force_is_a_divergence() {
        let dir =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/dataset-example");
        let ds = StaticDataset::read(dir).unwrap();
        let ctx = Context::new(&ds, [2, 2, 2]).unwrap();
        let model = Model::base().with(Candidate::Calibration);
        // The measurement whose force is below the largest: (|f| / f_ref)^p overflows for p ≪ 0.
        let i = (0..ctx.meas.len())
            .find(|&i| Vector3::from(ctx.meas[i].force).norm() < 0.99 * ctx.frame.f_ref)
            .expect("the example's two pokes differ in force");
        let theta = [(2e4f64).ln(), s_of(0.3), -1e4];
        let force = model.model_force(&ctx, &theta, i);
        assert!(!force.iter().all(|v| v.is_finite()), "{force:?}");
        match model.simulate(&ctx, &theta, &[i], None) {
            Err(DiagnoseError::Diverged(why)) => assert!(why.contains("not finite"), "{why}"),
            other => panic!("expected a divergence, found {:?}", other.map(|_| ())),
        }
        // At a power the law keeps finite the same measurement solves.
        let theta = [(2e4f64).ln(), s_of(0.3), 0.5];
        model.simulate(&ctx, &theta, &[i], None).unwrap();
    }
}

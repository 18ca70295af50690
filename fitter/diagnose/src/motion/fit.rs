//! One model of the motion diagnosis: fitted on the first steps of the trajectory (the fitted
//! part), then simulated over the whole trajectory so the last steps are a forecast (the
//! held-out part). Residuals are kept per marker and step.

use super::MotionDiagnoseError;
use nalgebra::DMatrix;
use palpate_motion::dataset::MotionDataset;
use palpate_motion::model::{Material, Model, Observations, Param, ParamKind};
use palpate_motion::optimize::{fit, FitSettings};
use palpate_motion::sim::simulate_states;
use palpate_motion::time_offset;
use palpate_motion::MotionError;
use serde::Serialize;

/// Where the trajectory is cut: steps `1..=fit_steps` are fitted, `fit_steps+1..=steps` held out.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Split {
    /// Last fitted step.
    pub fit_steps: usize,
    /// Last simulated step.
    pub steps: usize,
}

/// Simulated marker states and residuals of one model over the whole trajectory.
#[derive(Debug, Clone, Default)]
pub struct Trajectory {
    /// Simulated marker positions, `pos[n][i]` at step n + 1 (m).
    pub pos: Vec<Vec<[f64; 3]>>,
    /// Simulated marker velocities (m/s).
    pub vel: Vec<Vec<[f64; 3]>>,
    /// Residual simulated − measured (m); `None` where the marker was not observed.
    pub res: Vec<Vec<Option<[f64; 3]>>>,
}

/// Marker error figures of one model.
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct Scores {
    /// Scalar residual entries (3 per observed marker) on the fitted steps.
    pub n_fit: usize,
    /// Σ‖e‖² on the fitted steps (m²).
    pub chi2_fit: f64,
    /// RMS marker error √(Σ‖e‖²/count) on the fitted steps (m).
    pub rms_fit: f64,
    /// Largest marker error on the fitted steps (m).
    pub max_fit: f64,
    /// Scalar residual entries on the held-out steps.
    pub n_held: usize,
    /// Σ‖e‖² on the held-out steps (m²).
    pub chi2_held: f64,
    /// RMS marker error on the held-out steps (m).
    pub rms_held: f64,
    /// Largest marker error on the held-out steps (m).
    pub max_held: f64,
}

/// A fitted model.
#[derive(Debug, Clone)]
pub struct FittedModel {
    /// Free (global) parameters.
    pub kinds: Vec<ParamKind>,
    /// Fitted values (linear), in the order of `kinds`, then each region's shear modulus
    /// ([`params_for`]).
    pub values: Vec<f64>,
    /// 1σ of the values (Gauss–Newton, `None` if JᵀJ is singular).
    pub sigma: Option<Vec<f64>>,
    /// The full material (fixed quantities included).
    pub material: Material,
    /// Error figures.
    pub scores: Scores,
    /// Residuals per marker and step.
    pub traj: Trajectory,
    /// Simulations the optimiser ran.
    pub evaluations: usize,
    /// Optimiser notes (failed trial points, why it stopped).
    pub failures: Vec<String>,
    /// Constant offsets of the markers from their declared places (m, per marker: observed =
    /// simulated + offset), when the marker-offsets effect is in the model.
    pub offsets: Option<Vec<[f64; 3]>>,
    /// The markers' time offset against the simulation (steps: the observation of step n is the
    /// simulated step n − r, [`palpate_motion::time_offset`]), when the time-offset effect is in
    /// the model.
    pub time_offset: Option<i64>,
}

impl FittedModel {
    /// Free parameters: the material's (a region's μ included), the shape of each region chosen
    /// from the data ([`REGION_SHAPE_PARAMS`]; a clamp layer's place is the clamps'), three per
    /// marker offset and one time offset.
    pub fn parameter_count(&self) -> usize {
        let chosen = self.material.regions.len() - self.material.scaled_regions.len();
        self.values.len()
            + REGION_SHAPE_PARAMS * chosen
            + self.offsets.as_ref().map_or(0, |o| 3 * o.len())
            + usize::from(self.time_offset.is_some())
    }
}

/// `ds` on the simulation's clock of a run observed `offset` steps late
/// ([`palpate_motion::time_offset::shifted`]; the rows seen before the start are dropped) and the
/// split moved with it: the fitted rows stay the fitted rows.
pub fn retimed(
    ds: &MotionDataset,
    split: Split,
    offset: i64,
) -> Result<(MotionDataset, Split), MotionError> {
    let (model, obs) = time_offset::shifted(&ds.model, &ds.obs, offset)?;
    let moved = |n: usize| (n as i64 - offset).clamp(0, model.steps as i64) as usize;
    let split = Split {
        fit_steps: moved(split.fit_steps),
        steps: model.steps,
    };
    let mut d = ds.clone();
    d.model = model;
    d.obs = obs;
    Ok((d, split))
}

/// [`run_trajectory`] of a run observed `offset` steps late: the simulation on its own clock,
/// read back row for row with `obs` (a row seen before the start sees the initial state, at rest),
/// so its residuals and scores compare with any other model's of the same data.
pub fn run_trajectory_at(
    model: &Model,
    mat: &Material,
    obs: &Observations,
    offset: i64,
) -> Result<Trajectory, MotionError> {
    if offset == 0 {
        return run_trajectory(model, mat, obs);
    }
    let sim = time_offset::Trajectory::simulate(&time_offset::shifted_model(model, offset)?, mat)?;
    let beyond =
        || MotionError::Invalid(format!("time offset {offset}: past the simulated horizon"));
    let mut t = Trajectory::default();
    for n in 0..model.steps {
        let s = n as i64 + 1 - offset;
        let p = sim.at(s).ok_or_else(beyond)?.to_vec();
        let v = sim.velocity_at(s).ok_or_else(beyond)?;
        let row = obs.markers.get(n);
        t.res.push(
            p.iter()
                .enumerate()
                .map(|(i, q)| {
                    row.and_then(|r| r[i])
                        .map(|o| [q[0] - o[0], q[1] - o[1], q[2] - o[2]])
                })
                .collect(),
        );
        t.pos.push(p);
        t.vel.push(v);
    }
    Ok(t)
}

/// `ds` with its marker observations moved by −`offsets` (the observed point of marker i is
/// its simulated place plus `offsets[i]`): the residuals of the adjusted data are those of the
/// model with offsets.
pub fn with_offsets(ds: &MotionDataset, offsets: &[[f64; 3]]) -> MotionDataset {
    let mut d = ds.clone();
    for row in &mut d.obs.markers {
        for (p, c) in row.iter_mut().zip(offsets) {
            if let Some(p) = p {
                for k in 0..3 {
                    p[k] -= c[k];
                }
            }
        }
    }
    d
}

/// Removes each marker's mean residual over the fitted steps from its residuals at every step —
/// the residuals of the data moved by the marker's best constant offset — and returns those
/// offsets (observed = simulated + offset, so the offset is the mean residual negated; zero for a
/// marker never observed on the fitted steps).
pub fn remove_marker_means(t: &mut Trajectory, split: Split, markers: usize) -> Vec<[f64; 3]> {
    let means = mean_residuals(t, split, markers);
    for row in &mut t.res {
        for (e, m) in row.iter_mut().zip(&means) {
            if let Some(e) = e {
                for k in 0..3 {
                    e[k] -= m[k];
                }
            }
        }
    }
    means.iter().map(|m| m.map(|v| -v)).collect()
}

/// Each marker's mean residual (simulated − observed) over the fitted steps; zero for a marker
/// never observed there.
fn mean_residuals(t: &Trajectory, split: Split, markers: usize) -> Vec<[f64; 3]> {
    let mut sum = vec![[0.0; 3]; markers];
    let mut count = vec![0usize; markers];
    for row in t.res.iter().take(split.fit_steps) {
        for (i, e) in row.iter().enumerate() {
            if let Some(e) = e {
                for k in 0..3 {
                    sum[i][k] += e[k];
                }
                count[i] += 1;
            }
        }
    }
    sum.iter()
        .zip(&count)
        .map(|(s, &c)| s.map(|v| if c > 0 { v / c as f64 } else { 0.0 }))
        .collect()
}

/// The model and observations restricted to the fitted steps.
pub fn fitted_part(ds: &MotionDataset, split: Split) -> (Model, Observations) {
    let mut m = ds.model.clone();
    m.steps = split.fit_steps;
    let mut o = ds.obs.clone();
    o.markers.truncate(split.fit_steps);
    o.forces.truncate(split.fit_steps);
    (m, o)
}

/// Simulates `mat` over the whole `model` and records marker states and residuals.
pub fn run_trajectory(
    model: &Model,
    mat: &Material,
    obs: &Observations,
) -> Result<Trajectory, MotionError> {
    let mut t = Trajectory::default();
    simulate_states(model, mat, |s| {
        let mut pos = Vec::with_capacity(model.markers.len());
        let mut vel = Vec::with_capacity(model.markers.len());
        let mut res = Vec::with_capacity(model.markers.len());
        for (i, m) in model.markers.iter().enumerate() {
            let p = model.marker_position(m, s.x);
            let v = model.marker_position(m, s.v);
            let target = obs.markers.get(s.n - 1).and_then(|r| r[i]);
            res.push(target.map(|q| [p[0] - q[0], p[1] - q[1], p[2] - q[2]]));
            pos.push(p);
            vel.push(v);
        }
        t.pos.push(pos);
        t.vel.push(vel);
        t.res.push(res);
        Ok(())
    })?;
    Ok(t)
}

/// Error figures of a trajectory.
pub fn scores(t: &Trajectory, split: Split) -> Scores {
    let mut s = Scores::default();
    let (mut cf, mut ch) = (0usize, 0usize);
    for (n, row) in t.res.iter().enumerate() {
        for e in row.iter().flatten() {
            let sq = e[0] * e[0] + e[1] * e[1] + e[2] * e[2];
            if n < split.fit_steps {
                s.chi2_fit += sq;
                s.max_fit = s.max_fit.max(sq.sqrt());
                cf += 1;
            } else {
                s.chi2_held += sq;
                s.max_held = s.max_held.max(sq.sqrt());
                ch += 1;
            }
        }
    }
    s.n_fit = 3 * cf;
    s.n_held = 3 * ch;
    s.rms_fit = (s.chi2_fit / cf.max(1) as f64).sqrt();
    s.rms_held = (s.chi2_held / ch.max(1) as f64).sqrt();
    s
}

/// The optimiser's parameters of a model with free `kinds` on `mat`: the global ones in the order
/// of `kinds`, then the shear modulus of each of the material's regions (a two-material body).
pub fn params_for(kinds: &[ParamKind], mat: &Material) -> Vec<Param> {
    let mut p = Param::globals(kinds);
    p.extend((0..mat.regions.len()).map(|r| Param::in_region(ParamKind::Mu, r)));
    p
}

/// Fits `kinds` (global) on the fitted steps from each start in `starts` (values for `kinds`;
/// the others stay as in `base`); with several starts each is screened for `screen_iters`
/// LBFGS iterations and the best is continued to `max_iters`. With free marker offsets
/// (`ds.obs.free_marker_offsets`, [`fit_with_offsets`]) the fit is of the reduced problem and the
/// offsets are read off at the fitted material.
pub fn fit_model(
    ds: &MotionDataset,
    split: Split,
    base: &Material,
    kinds: &[ParamKind],
    starts: &[Vec<f64>],
    max_iters: u64,
    screen_iters: u64,
) -> Result<FittedModel, MotionDiagnoseError> {
    let (model, obs) = fitted_part(ds, split);
    let params = params_for(kinds, base);
    let quiet = |_: usize, _: f64| {};
    let starts: Vec<Vec<f64>> = starts.iter().map(|q0| lambda_raised(kinds, q0)).collect();
    let run = |q0: &[f64], iters: u64| {
        let settings = FitSettings {
            max_iters: iters,
            ..Default::default()
        };
        fit(&model, base, &params, q0, &obs, &settings, &[], &quiet)
    };
    let mut best: Option<palpate_motion::optimize::FitResult> = None;
    let mut evaluations = 0;
    let mut notes = Vec::new();
    if starts.len() > 1 {
        for q0 in &starts {
            match run(q0, screen_iters) {
                Ok(r) => {
                    evaluations += r.evaluations + r.plain_evaluations;
                    if best.as_ref().is_none_or(|b| r.phi < b.phi) {
                        best = Some(r);
                    }
                }
                Err(e) => notes.push(format!("start {q0:?}: {e}")),
            }
        }
    }
    let q0 = best
        .as_ref()
        .map_or_else(|| starts[0].clone(), |b| b.q.clone());
    let r = run(&q0, max_iters)?;
    evaluations += r.evaluations + r.plain_evaluations;
    notes.extend(r.failures.iter().cloned());
    let mut material = base.clone();
    material.set(&params, &r.q);
    let mut traj = run_trajectory(&ds.model, &material, &ds.obs)?;
    // Free marker offsets: read off at the fitted material (each marker's mean residual on the
    // fitted steps, negated: observed = simulated + offset), and the residuals made those of
    // the data moved by them (each grows by its marker's offset); they take 3 degrees of
    // freedom per marker from the uncertainty's s².
    let offsets = ds
        .obs
        .free_marker_offsets
        .then(|| remove_marker_means(&mut traj, split, ds.model.markers.len()));
    let sc = scores(&traj, split);
    let offset_dof = if offsets.is_some() {
        let seen = (0..ds.model.markers.len())
            .filter(|&i| {
                traj.res
                    .iter()
                    .take(split.fit_steps)
                    .any(|row| row.get(i).is_some_and(Option::is_some))
            })
            .count();
        3 * seen
    } else {
        0
    };
    let dof = sc.n_fit.saturating_sub(offset_dof);
    let sigma = match &r.gauss_newton {
        // Levenberg–Marquardt ended on a simulation with the sensitivities: its Gauss–Newton
        // matrix is the JᵀJ the central differences would estimate, at no simulation's cost.
        Some(h) => {
            let wdt = obs.marker_weight * model.observation_interval();
            gauss_newton_sigma(h, wdt, &r.q, sc.chi2_fit, dof)
        }
        None => uncertainty(&model, &obs, base, kinds, &r.q, sc.chi2_fit, dof),
    };
    Ok(FittedModel {
        kinds: kinds.to_vec(),
        values: r.q,
        sigma,
        material,
        scores: sc,
        traj,
        evaluations,
        failures: notes,
        offsets,
        time_offset: None,
    })
}

/// The smallest λ/μ a fit of λ and μ starts from: Poisson's ratio 0.005. λ is fitted in ln λ,
/// whose gradient λ ∂Φ/∂λ vanishes as λ does: a misfit that a fit of the simplest model
/// explained by a body that does not resist a change of volume (λ → 10⁻⁸ Pa on a bar whose
/// clamp gives) left λ there for every later fit, the candidate that explains the misfit
/// included. From this start λ is within a few trust-region steps of any solid's, and a fit
/// whose data want it lower takes it there again. (A floor held during the fit, relative to
/// the start's μ, was tried: after a simplest fit that made the body rigid, μ 2·10¹² Pa on a
/// bar recorded out of step, it held λ where the time offset's refit could not bring μ back.)
pub const LAMBDA_START_RATIO: f64 = 0.01;

/// `q0` with λ raised to [`LAMBDA_START_RATIO`] × μ where `kinds` fits both and it lies below.
fn lambda_raised(kinds: &[ParamKind], q0: &[f64]) -> Vec<f64> {
    let mut q = q0.to_vec();
    let at = |k| kinds.iter().position(|&j| j == k);
    if let (Some(l), Some(m)) = (at(ParamKind::Lambda), at(ParamKind::Mu)) {
        q[l] = q[l].max(LAMBDA_START_RATIO * q[m]);
    }
    q
}

/// What choosing a second material's region from the data is charged, in parameters: as the
/// static inclusion's centre (3) and extent (1). The region is one of many partitions the sign
/// split could have drawn, picked because it fits; counting only its μ let a one-material body
/// whose marker offsets left a biased forecast take it (3 of 8 random draws,
/// `palpate-lab motion-confusion`).
pub const REGION_SHAPE_PARAMS: usize = 4;

/// Fits `kinds` together with a constant offset per marker (observed = simulated + offset).
/// The offsets are eliminated in closed form ([`palpate_motion::model::Observations::free_marker_offsets`]:
/// at any parameters each marker's best offset is its mean residual on the fitted steps), so one
/// fit of the parameters reaches the joint minimum over parameters and offsets ([`fit_model`]
/// reads the offsets off at the fitted material).
///
/// Before, the offsets and the material were alternated (offsets at fixed material, then the
/// material refitted, up to eight rounds): the two are correlated, the alternation crawled, and
/// what it left unfitted was adopted as a second effect on random specimens
/// (`palpate-lab motion-confusion`).
pub fn fit_with_offsets(
    ds: &MotionDataset,
    split: Split,
    base: &Material,
    kinds: &[ParamKind],
    start: &[f64],
    max_iters: u64,
) -> Result<FittedModel, MotionDiagnoseError> {
    let mut free = ds.clone();
    free.obs.free_marker_offsets = true;
    fit_model(&free, split, base, kinds, &[start.to_vec()], max_iters, 0)
}

/// Observed residual entries on the fitted steps as one vector.
fn residual_vector(
    model: &Model,
    obs: &Observations,
    mat: &Material,
) -> Result<Vec<f64>, MotionError> {
    let mut t = run_trajectory(model, mat, obs)?;
    if obs.free_marker_offsets {
        // The residuals of the reduced problem: each marker's mean removed (its free offset).
        let all = Split {
            fit_steps: t.res.len(),
            steps: t.res.len(),
        };
        remove_marker_means(&mut t, all, model.markers.len());
    }
    Ok(t.res
        .iter()
        .flat_map(|r| r.iter().flatten().flat_map(|e| e.iter().copied()))
        .collect())
}

/// Gauss–Newton 1σ of the values from the fit's own Gauss–Newton matrix `h` in z = ln q
/// ([`palpate_motion::optimize::FitResult::gauss_newton`]), which is JᵀJ weighted by `wdt`
/// (the marker term's weight times the observation interval): cov(z) = s² (h / wdt)⁻¹ with
/// s² = χ²/(n − k), σ_q = q σ_z — [`uncertainty`]'s figure, its J exact instead of differenced.
/// `None` when h is singular (an unidentified parameter) or n ≤ k.
fn gauss_newton_sigma(h: &[f64], wdt: f64, q: &[f64], chi2: f64, n: usize) -> Option<Vec<f64>> {
    let k = q.len();
    if n <= k || h.len() != k * k || wdt <= 0.0 {
        return None;
    }
    sigma_of(DMatrix::from_row_slice(k, k, h) / wdt, q, chi2, n)
}

/// σ_q = q σ_z with cov(z) = s² (JᵀJ)⁻¹, s² = χ²/(n − k) (n > k); `None` when JᵀJ is singular.
fn sigma_of(jtj: DMatrix<f64>, q: &[f64], chi2: f64, n: usize) -> Option<Vec<f64>> {
    let s2 = chi2 / (n - q.len()) as f64;
    let inv = jtj.cholesky()?.inverse();
    Some(
        q.iter()
            .enumerate()
            .map(|(i, v)| v * (s2 * inv[(i, i)]).max(0.0).sqrt())
            .collect(),
    )
}

/// Gauss–Newton 1σ of the values: cov(z) = s²(JᵀJ)⁻¹ with z = ln q, J by central differences
/// (step 1e-3 in z, i.e. 0.1 % of each value), s² = χ²/(n − k); σ_q = q σ_z. `None` when a
/// perturbed simulation fails or JᵀJ is singular (an unidentified parameter).
fn uncertainty(
    model: &Model,
    obs: &Observations,
    base: &Material,
    kinds: &[ParamKind],
    q: &[f64],
    chi2: f64,
    n: usize,
) -> Option<Vec<f64>> {
    let params = params_for(kinds, base);
    let k = params.len();
    if n <= k {
        return None;
    }
    let h: f64 = 1e-3;
    let mut cols = Vec::with_capacity(k);
    for j in 0..k {
        let mut r = [Vec::new(), Vec::new()];
        for (s, sign) in [1.0, -1.0].into_iter().enumerate() {
            let mut qq = q.to_vec();
            qq[j] *= (sign * h).exp();
            let mut mat = base.clone();
            mat.set(&params, &qq);
            r[s] = residual_vector(model, obs, &mat).ok()?;
        }
        cols.push(
            r[0].iter()
                .zip(&r[1])
                .map(|(a, b)| (a - b) / (2.0 * h))
                .collect::<Vec<f64>>(),
        );
    }
    let rows = cols[0].len();
    let j = DMatrix::from_fn(rows, k, |i, c| cols[c][i]);
    sigma_of(j.transpose() * &j, q, chi2, n)
}

#[cfg(test)]
impl FittedModel {
    /// An elastic fit of `material`'s global λ and μ at `values`, nothing simulated: the current
    /// model of a unit test.
    pub(crate) fn elastic(material: Material, values: [f64; 2]) -> Self {
        Self {
            kinds: vec![ParamKind::Lambda, ParamKind::Mu],
            values: values.to_vec(),
            sigma: None,
            material,
            scores: Default::default(),
            traj: Default::default(),
            evaluations: 0,
            failures: Vec::new(),
            offsets: None,
            time_offset: None,
        }
    }
}

/// For tests: a drawn specimen of the example bar (`models/motion-example`) with `effect`, its
/// split (the last quarter held out) and its one-material fit of λ and μ from the starting
/// values, as a round's current fit.
#[cfg(test)]
pub(crate) fn fitted_specimen(
    effect: palpate_specimen::motion::MotionEffect,
    seed: u64,
) -> (MotionDataset, Split, FittedModel) {
    let base = palpate_motion::dataset::load(
        &std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/motion-example"),
    )
    .unwrap();
    let (ds, _) = palpate_specimen::motion::motion_specimen(&base, effect, seed).unwrap();
    let steps = ds.model.steps;
    let split = Split {
        fit_steps: steps * 3 / 4,
        steps,
    };
    let ne = ds.model.tets.len();
    let start = palpate_motion::start::initial_values(&ds, None);
    let density = ds.config.density.unwrap_or(1000.0);
    let mat = Material::uniform(ne, start.lambda, start.mu, 0.0, 1.0, density);
    let kinds = [ParamKind::Lambda, ParamKind::Mu];
    let cur = fit_model(
        &ds,
        split,
        &mat,
        &kinds,
        &[vec![start.lambda, start.mu]],
        30,
        15,
    )
    .unwrap();
    (ds, split, cur)
}

#[cfg(test)]
mod tests {
    use super::*;
    use palpate_motion::scenario::{example_bar, example_truth, record};

    /// The 1σ read off Levenberg–Marquardt's own Gauss–Newton matrix against central
    /// differences of the residual (the independent reference, [`uncertainty`]): the example
    /// bar's λ, μ and viscosity fitted to noisy data, both within 1 % of each other.
    #[test]
    fn the_fits_gauss_newton_sigma_is_the_differenced_one() {
        let (_, mut model) = example_bar([1, 4, 1], 30).unwrap();
        model.newton.tol = 1e-11;
        let truth = example_truth(&model);
        let mut obs = record(&model, &truth, 2e-4, 5).unwrap();
        obs.forces.clear();
        let kinds = [ParamKind::Lambda, ParamKind::Mu, ParamKind::Nu];
        let params = params_for(&kinds, &truth);
        let settings = FitSettings {
            optimizer: palpate_motion::optimize::Optimizer::LevenbergMarquardt,
            ..Default::default()
        };
        let quiet = |_: usize, _: f64| {};
        let r = fit(
            &model,
            &truth,
            &params,
            &[1.5e4, 1.5e4, 20.0],
            &obs,
            &settings,
            &[],
            &quiet,
        )
        .unwrap();
        let h = r
            .gauss_newton
            .as_deref()
            .expect("Levenberg–Marquardt's matrix");
        let mut mat = truth.clone();
        mat.set(&params, &r.q);
        let res = residual_vector(&model, &obs, &mat).unwrap();
        let chi2: f64 = res.iter().map(|v| v * v).sum();
        let wdt = obs.marker_weight * model.observation_interval();
        let exact = gauss_newton_sigma(h, wdt, &r.q, chi2, res.len()).unwrap();
        let differenced = uncertainty(&model, &obs, &truth, &kinds, &r.q, chi2, res.len()).unwrap();
        for (k, (a, b)) in exact.iter().zip(&differenced).enumerate() {
            assert!(
                (a / b - 1.0).abs() < 0.01,
                "parameter {k}: σ {a:e} from the fit's matrix, {b:e} differenced"
            );
        }
    }
}

//! Predicting a run from a fitted material without refitting: the simulated trajectory against
//! the capture (every observed marker at every step), the elastostatic equilibrium under the
//! run's loads against where the capture came to rest, and the naive baseline a model must beat
//! — the final marker displacements extrapolated linearly in the load from the fitted runs.
//!
//! "Where the capture came to rest" is the mean of each marker over the last
//! [`FINAL_WINDOW_S`] of the run: a ring-down never quite stops, and one frame carries the
//! capture noise.

use super::fitted::FittedModel;
use super::model::{Material, Model, Observations};
use super::sim::equilibrium_from;
use super::time_offset::{shifted_model, Trajectory};
use super::MotionError;

/// Seconds at the end of a run averaged as its final rest state.
pub const FINAL_WINDOW_S: f64 = 0.5;

/// The scalar load of a run for the linear baseline: the dead loads acting at the end, projected
/// on gravity's direction (N; gravity itself is the same in every run of one object and sits in
/// the intercept). Without gravity, the loads' magnitude.
pub fn load_along_gravity(model: &Model) -> f64 {
    let g = model.gravity;
    let gn = g.iter().map(|v| v * v).sum::<f64>().sqrt();
    model
        .loads
        .iter()
        .filter(|l| l.from_step <= model.steps)
        .map(|l| {
            if gn > 0.0 {
                (0..3).map(|k| l.force[k] * g[k] / gn).sum::<f64>()
            } else {
                l.force.iter().map(|v| v * v).sum::<f64>().sqrt()
            }
        })
        .sum::<f64>()
        + 0.0 // −0.0 (no loads, negative gravity) prints as 0
}

/// Each marker's rest position (the registered places, embedded in the mesh).
pub fn rest_markers(model: &Model) -> Vec<[f64; 3]> {
    let x: Vec<f64> = model.nodes.iter().flatten().copied().collect();
    model
        .markers
        .iter()
        .map(|m| model.marker_position(m, &x))
        .collect()
}

/// Each marker's mean observed position over the last [`FINAL_WINDOW_S`] of the run (`None` for
/// a marker never seen in that window).
pub fn final_observed(model: &Model, obs: &Observations) -> Vec<Option<[f64; 3]>> {
    let window = ((FINAL_WINDOW_S / model.dt).round() as usize).max(1);
    let last = obs.markers.len();
    let from = last.saturating_sub(window);
    (0..model.markers.len())
        .map(|i| {
            let seen: Vec<[f64; 3]> = obs.markers[from..last]
                .iter()
                .filter_map(|row| row.get(i).copied().flatten())
                .collect();
            (!seen.is_empty()).then(|| {
                let n = seen.len() as f64;
                [0, 1, 2].map(|k| seen.iter().map(|p| p[k]).sum::<f64>() / n)
            })
        })
        .collect()
}

/// One marker's error statistics.
#[derive(Debug, Clone, PartialEq)]
pub struct MarkerError {
    /// The marker.
    pub name: String,
    /// RMS over the observed steps of the trajectory (m).
    pub trajectory_rms_m: f64,
    /// Distance between the predicted equilibrium and the observed rest state (m); `None` if
    /// the marker was not seen at the end.
    pub final_m: Option<f64>,
}

/// What one simulation of a run leaves for its readings: the markers at every step and the
/// state at the last. A fit's simulations record it ([`crate::gradient::Evaluation::simulated`])
/// so that the fitted run is read ([`assess`]) without being simulated again.
#[derive(Debug, Clone, Default)]
pub struct Simulated {
    /// Markers at steps 1..=steps (m).
    pub rows: Vec<Vec<[f64; 3]>>,
    /// Full-dof positions at the last step (a start for the equilibrium after the run).
    pub last: Vec<f64>,
}

impl Simulated {
    /// Records step `n`'s positions `x` (full dofs) of a simulation of `model`.
    pub fn record(&mut self, model: &Model, n: usize, x: &[f64]) {
        self.rows.push(
            model
                .markers
                .iter()
                .map(|m| model.marker_position(m, x))
                .collect(),
        );
        if n == model.steps {
            self.last = x.to_vec();
        }
    }
}

/// A prediction of one run and its errors against the capture.
#[derive(Debug, Clone)]
pub struct Prediction {
    /// RMS over every observed (step, marker) of ‖simulated − observed‖ (m).
    pub trajectory_rms_m: f64,
    /// Largest ‖simulated − observed‖ over the run (m).
    pub trajectory_max_m: f64,
    /// RMS over markers of ‖equilibrium − observed rest‖ (m).
    pub final_rms_m: f64,
    /// Largest of those (m).
    pub final_max_m: f64,
    /// Per marker.
    pub markers: Vec<MarkerError>,
    /// Simulated marker positions per step n = 1..=steps (m).
    pub simulated: Vec<Vec<[f64; 3]>>,
    /// Predicted equilibrium marker positions (m).
    pub equilibrium: Vec<[f64; 3]>,
    /// Observed rest state (m), as [`final_observed`].
    pub observed_final: Vec<Option<[f64; 3]>>,
}

fn dist(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>().sqrt()
}

fn rms(v: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut sq, mut n, mut max) = (0.0, 0usize, 0.0f64);
    for e in v {
        sq += e * e;
        n += 1;
        max = max.max(e);
    }
    (if n == 0 { 0.0 } else { (sq / n as f64).sqrt() }, max)
}

/// Simulates the run with `mat` and solves its final equilibrium; compares both with `obs`.
pub fn predict(
    model: &Model,
    mat: &Material,
    obs: &Observations,
) -> Result<Prediction, MotionError> {
    predict_offset(model, mat, obs, 0)
}

/// [`predict`] of a run whose observations are `offset` steps late against the simulation's
/// clock ([`crate::time_offset`]): the simulated markers are those of the steps the observations
/// saw, row for row with `obs` (the initial state for the rows seen before the start).
pub fn predict_offset(
    model: &Model,
    mat: &Material,
    obs: &Observations,
    offset: i64,
) -> Result<Prediction, MotionError> {
    let traj = if offset == 0 {
        Trajectory::simulate(model, mat)?
    } else {
        Trajectory::simulate(&shifted_model(model, offset)?, mat)?
    };
    let rows = traj.recorded(model.steps, offset).ok_or_else(|| {
        MotionError::Invalid(format!(
            "a time offset of {offset} steps reaches past the simulated horizon"
        ))
    })?;
    assess(
        model,
        mat,
        obs,
        Simulated {
            rows,
            last: traj.last,
        },
    )
}

/// The prediction of a run from a simulation of it already made (its markers at every step of
/// the run's clock and its last state, [`Simulated`]): the trajectory's errors against the
/// capture, and the equilibrium after it against the rest state.
pub fn assess(
    model: &Model,
    mat: &Material,
    obs: &Observations,
    sim: Simulated,
) -> Result<Prediction, MotionError> {
    let Simulated {
        rows: simulated,
        last,
    } = sim;
    if simulated.len() != model.steps {
        return Err(MotionError::Invalid(format!(
            "a simulation of {} steps read as a run of {}",
            simulated.len(),
            model.steps
        )));
    }
    // From the run's last state, near rest after a ring-down: Newton converges in a few steps
    // where a start from the undeformed shape would need load increments.
    let (x_eq, _) = equilibrium_from(model, mat, model.steps, last)?;
    let eq: Vec<[f64; 3]> = model
        .markers
        .iter()
        .map(|m| model.marker_position(m, &x_eq))
        .collect();
    let observed_final = final_observed(model, obs);
    let nm = model.markers.len();
    let mut per_marker = vec![(0.0, 0usize); nm];
    let mut all = Vec::new();
    for (row_sim, row_obs) in simulated.iter().zip(&obs.markers) {
        for i in 0..nm {
            if let Some(o) = row_obs.get(i).copied().flatten() {
                let e = dist(&row_sim[i], &o);
                per_marker[i].0 += e * e;
                per_marker[i].1 += 1;
                all.push(e);
            }
        }
    }
    let (trajectory_rms_m, trajectory_max_m) = rms(all.into_iter());
    let finals: Vec<Option<f64>> = (0..nm)
        .map(|i| observed_final[i].map(|o| dist(&eq[i], &o)))
        .collect();
    let (final_rms_m, final_max_m) = rms(finals.iter().flatten().copied());
    let markers = model
        .markers
        .iter()
        .enumerate()
        .map(|(i, m)| MarkerError {
            name: m.name.clone(),
            trajectory_rms_m: if per_marker[i].1 == 0 {
                0.0
            } else {
                (per_marker[i].0 / per_marker[i].1 as f64).sqrt()
            },
            final_m: finals[i],
        })
        .collect();
    Ok(Prediction {
        trajectory_rms_m,
        trajectory_max_m,
        final_rms_m,
        final_max_m,
        markers,
        simulated,
        equilibrium: eq,
        observed_final,
    })
}

/// The linear baseline: each marker's final displacement (rest state − rest position) as a
/// straight line in the load, least squares through the fitted runs `(load, displacements)`,
/// evaluated at `load`. `None` for a marker with fewer than two distinct loads behind it.
pub fn linear_baseline(
    fitted: &[(f64, Vec<Option<[f64; 3]>>)],
    load: f64,
) -> Vec<Option<[f64; 3]>> {
    let nm = fitted.iter().map(|(_, d)| d.len()).max().unwrap_or(0);
    (0..nm)
        .map(|i| {
            let pts: Vec<(f64, [f64; 3])> = fitted
                .iter()
                .filter_map(|(l, d)| d.get(i).copied().flatten().map(|u| (*l, u)))
                .collect();
            let n = pts.len() as f64;
            let lm = pts.iter().map(|p| p.0).sum::<f64>() / n.max(1.0);
            let sll = pts.iter().map(|p| (p.0 - lm).powi(2)).sum::<f64>();
            if pts.len() < 2 || sll <= 1e-12 * (1.0 + lm * lm) {
                return None;
            }
            Some([0, 1, 2].map(|k| {
                let um = pts.iter().map(|p| p.1[k]).sum::<f64>() / n;
                let slope = pts.iter().map(|p| (p.0 - lm) * (p.1[k] - um)).sum::<f64>() / sll;
                um + slope * (load - lm)
            }))
        })
        .collect()
}

/// The linear baseline's error on a run: each marker's rest state predicted by
/// [`linear_baseline`] through `fitted` (load, final displacement per marker, in `model`'s
/// marker order) at the run's load, against the observed rest state; the RMS over the markers
/// both know (`None` when none does).
pub fn baseline_rest_rms(
    fitted: &[(f64, Vec<Option<[f64; 3]>>)],
    model: &Model,
    obs: &Observations,
) -> Option<f64> {
    let rest = rest_markers(model);
    let predicted = linear_baseline(fitted, load_along_gravity(model));
    let errors: Vec<f64> = predicted
        .iter()
        .zip(final_observed(model, obs))
        .zip(&rest)
        .filter_map(|((b, f), r0)| {
            let (b, f) = (b.as_ref()?, f?);
            Some(dist(&[0, 1, 2].map(|k| r0[k] + b[k]), &f))
        })
        .collect();
    (!errors.is_empty()).then(|| rms(errors.into_iter()).0)
}

/// [`baseline_rest_rms`] through the runs a fitted model records (`fit.json`), each run's final
/// displacements matched to `model`'s markers by name: the fitted runs may list the markers in
/// another order, or lack some.
pub fn fitted_baseline_rms(fit: &FittedModel, model: &Model, obs: &Observations) -> Option<f64> {
    let fitted_runs: Vec<(f64, Vec<Option<[f64; 3]>>)> = fit
        .runs
        .iter()
        .map(|r| {
            let by_name = model
                .markers
                .iter()
                .map(|n| {
                    r.markers
                        .iter()
                        .position(|m| *m == n.name)
                        .and_then(|i| r.final_displacement_m.get(i).copied().flatten())
                })
                .collect();
            (r.load_n, by_name)
        })
        .collect();
    baseline_rest_rms(&fitted_runs, model, obs)
}

/// The shear modulus μ that best places every run's equilibrium (under its loads, Poisson's ratio
/// held at `poisson`) on the markers' observed rest state — the static fit from the ends of the
/// runs, no dynamics involved. A golden-section search on ln μ within a factor e² of `mu0`
/// (one parameter: no gradient needed); returns (μ, RMS of the rest-state residual, 1σ of μ from
/// the curvature with independent residuals).
pub fn fit_equilibria(
    runs: &[(&Model, &Observations)],
    base: &Material,
    poisson: f64,
    mu0: f64,
) -> Result<(f64, f64, f64), MotionError> {
    use super::golden_section::{golden_section, Stop};
    use super::model::{Param, ParamKind};
    let ratio = 2.0 * poisson / (1.0 - 2.0 * poisson);
    let targets: Vec<Vec<Option<[f64; 3]>>> =
        runs.iter().map(|(m, o)| final_observed(m, o)).collect();
    // Sum of squared rest-state distances and their count at μ = mu0·e^z.
    let cost = |z: f64| -> Result<(f64, usize), MotionError> {
        let mu = mu0 * z.exp();
        let mut mat = base.clone();
        mat.set(
            &[
                Param::global(ParamKind::Mu),
                Param::global(ParamKind::Lambda),
            ],
            &[mu, ratio * mu],
        );
        let mut sq = 0.0;
        let mut n = 0;
        for ((model, _), target) in runs.iter().zip(&targets) {
            let (x, _) = super::sim::equilibrium(model, &mat, model.steps)?;
            for (m, t) in model.markers.iter().zip(target) {
                if let Some(t) = t {
                    sq += dist(&model.marker_position(m, &x), t).powi(2);
                    n += 1;
                }
            }
        }
        Ok((sq, n))
    };
    let z = golden_section(|z| Ok(cost(z)?.0), -2.0, 2.0, Stop::Width(1e-4))?.midpoint();
    let (s0, n) = cost(z)?;
    let h = 2e-2;
    let (sp, sm) = (cost(z + h)?.0, cost(z - h)?.0);
    let curv = (sp - 2.0 * s0 + sm) / (h * h);
    // Each rest state is 3 scalar residuals; σ² of z = 2 s² / S'' with s² = S/(3n − 1).
    let dof = (3 * n).saturating_sub(1).max(1) as f64;
    let sd_z = if curv > 0.0 {
        (2.0 * (s0 / dof) / curv).sqrt()
    } else {
        f64::NAN
    };
    let mu = mu0 * z.exp();
    Ok((mu, (s0 / n.max(1) as f64).sqrt(), mu * sd_z))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A run read from the simulation a plain evaluation made ([`Simulated`]) is the run
    /// predicted afresh, to the bit: the same steps recorded, the same equilibrium from the same
    /// last state. A simulation of another length is refused, not read against the wrong steps.
    #[test]
    fn a_run_read_from_its_evaluation_is_the_run_predicted() {
        let (_, model) = crate::scenario::example_bar([1, 3, 1], 24).unwrap();
        let mat = crate::scenario::example_truth(&model);
        let obs = crate::scenario::record(&model, &mat, 1e-4, 7).unwrap();
        let ev = crate::gradient::evaluate(&model, &mat, &[], &obs, None).unwrap();
        let sim = ev.simulated.expect("an evaluation records its simulation");
        assert_eq!(sim.rows.len(), model.steps);
        let read = assess(&model, &mat, &obs, sim.clone()).unwrap();
        let fresh = predict(&model, &mat, &obs).unwrap();
        assert_eq!(read.simulated, fresh.simulated);
        assert_eq!(read.equilibrium, fresh.equilibrium);
        assert_eq!(read.trajectory_rms_m, fresh.trajectory_rms_m);
        assert_eq!(read.final_rms_m, fresh.final_rms_m);
        assert_eq!(read.markers, fresh.markers);
        let mut short = sim;
        short.rows.pop();
        assert!(assess(&model, &mat, &obs, short).is_err());
    }

    #[test]
    fn linear_baseline_is_the_line_through_two_loads_and_refuses_one() {
        let a = (0.0, vec![Some([0.0, 0.0, -1.0]), None]);
        let b = (2.0, vec![Some([0.0, 1.0, -3.0]), Some([1.0, 1.0, 1.0])]);
        let p = linear_baseline(&[a.clone(), b], 4.0);
        assert_eq!(p[0], Some([0.0, 2.0, -5.0]));
        assert_eq!(p[1], None, "one load behind marker 1");
        assert_eq!(linear_baseline(&[a.clone(), a], 1.0)[0], None);
    }

    /// `fit.json`'s runs list their markers in their own order: the baseline matches them to
    /// the run's markers by name. Marker i's displacement is (0, 0, i mm) at load 0 and 2 mm more
    /// at load 2 N, both runs listing the markers backwards; the run (load 0) rests where the
    /// line says except marker 0, 3 mm off: RMS over the 9 markers √(3²/9) = 1 mm. Matched by
    /// place in the list, marker i would take marker 8 − i's line and be |2i − 8| mm off.
    #[test]
    fn the_fitted_baseline_matches_markers_by_name() {
        let (_, model) = crate::scenario::example_bar([1, 2, 1], 4).unwrap();
        let names: Vec<String> = model.markers.iter().map(|m| m.name.clone()).collect();
        assert_eq!(names.len(), 9);
        let displacement = |i: usize, extra: f64| Some([0.0, 0.0, 1e-3 * i as f64 + extra]);
        let run = |load_n: f64| crate::fitted::FittedRun {
            dataset: format!("at {load_n} N"),
            load_n,
            rms_marker_m: 0.0,
            time_offset_s: 0.0,
            markers: names.iter().rev().cloned().collect(),
            final_displacement_m: (0..9)
                .rev()
                .map(|i| displacement(i, 1e-3 * load_n))
                .collect(),
        };
        let text = r#"{"format": "palpate-motion-fit/2", "datasets": [], "nodes": 0, "tets": 0,
            "lambda": [1e4], "mu": [2e4], "viscosity": [3.0], "h": [1.0], "density": [47.0],
            "poisson_fixed": null, "hanging_inertia": false, "fitted": ["mu"],
            "runtime_lambda_alpha": [], "rms_marker_m": 0.0, "rms_force_n": 0.0,
            "evaluations": 1, "runs": []}"#;
        let mut fit: FittedModel = serde_json::from_str(text).unwrap();
        fit.runs = vec![run(0.0), run(2.0)];
        let rest = rest_markers(&model);
        let row: Vec<Option<[f64; 3]>> = (0..9)
            .map(|i| {
                let off = if i == 0 { 3e-3 } else { 0.0 };
                displacement(i, off).map(|d| [0, 1, 2].map(|k| rest[i][k] + d[k]))
            })
            .collect();
        let obs = Observations {
            markers: vec![row; model.steps],
            ..Default::default()
        };
        let rms = fitted_baseline_rms(&fit, &model, &obs).unwrap();
        assert!((rms - 1e-3).abs() < 1e-12, "{rms}");
    }
}

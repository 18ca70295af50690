//! The power statements checked by injected refits. A statement of [`super::power`] is the
//! linearisation's at the final fit, and it is true only where the candidate's response is
//! linear up to its magnitude: on data palpate did not make, a stiffening whose response
//! saturates gained a ninth of the linearised χ² at twice its statement, and a 7-node stiffness
//! field was stated at factors e⁴–e¹¹ in modulus. So the report does not print a θ-candidate's
//! statement on the linearisation's word alone.
//!
//! Each parameter of each θ-candidate statement is put alone, at [`FACTORS`]`[0]` (twice) its
//! stated magnitude, into noise-free data: the final fit's own simulation with the candidate's
//! block moved from zero effect by that much, so the data hold the final model exactly plus the
//! effect's true, nonlinear signature. The selection rule's refits then judge it, the final
//! model's absorption linear and the candidate's search not:
//! - without the candidate: the final model's parameters take up what they can of the signature
//!   by a Gauss–Newton step on the final fit's Jacobian (one Jacobian for every check; the
//!   parameters move little, and a refit from the optimum crawls for many iterations in the
//!   directions the data barely fix, gaining nothing that moves ΔBIC);
//! - with it: a candidate the diagnosis places by its sensitivity scan (the layer, the
//!   inclusion) is searched for as the diagnosis searches — the final model refitted, the scan
//!   of the residual it leaves, the candidate refitted from there; any other starts at the effect
//!   put in (from zero effect, Levenberg–Marquardt on its one or two parameters reaches the same
//!   optimum in more iterations). Each refit stops when a step gains less than 10⁻⁵ of the final
//!   fit's χ² (data a model holds exactly would otherwise drive χ² toward zero to the cap). Such
//!   a start is where the data were made: its simulation is the one that made them, its χ² is
//!   zero, and the refit ends there without a Jacobian.
//!
//! ΔBIC = −Δχ²/s² + k ln n with s² the final fit's residual variance per entry: the effect on
//! top of this dataset's own residual, as the statement means it, without a draw of noise to
//! move it. Found (ΔBIC < −T, the shortlist): the statement stands, and larger effects move the
//! markers more. Not found: tried once more at four times; not found then, the report says this
//! dataset cannot be said to see the effect at that size.
//!
//! Twice the statement beyond [`StaticEffect::plausible_magnitude`](super::candidates::StaticEffect::plausible_magnitude)
//! (a material field more than a factor 10 from the body) is not put in: such a statement says
//! only that the dataset cannot see the effect at a plausible size.
//!
//! The per-measurement statements (`force-scale-each`, `registration-each`, `tilt-each`) are
//! expectations over effects that differ at random from measurement to measurement with RMS ε.
//! Each kind is put in as one such effect: its residual columns at the final fit (one per
//! measurement and direction) with alternating signs, at 2ε (then 4ε), and judged the same way,
//! the final model with the candidate refitted (its per-measurement parameters profiled in
//! closed form, as always).

use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;
use serde::Serialize;

use super::candidates::{At, PowerPoint};
use super::diagnose::locate_candidates;
use super::fit::{fit_from, fit_until, jacobian_columns, Fitted, Stop, FD_STEP};
use super::model::{Candidate, Context, Model, Simulated};
use super::power::{row_offsets, Detectable};
use super::{DiagnoseError, DiagnoseOptions};

/// The multiples of the linearised statement at which an effect is put in, in turn until found.
pub const FACTORS: [f64; 2] = [2.0, 4.0];

/// LM iterations of each refit at most.
const REFIT_ITERATIONS: usize = 40;

/// A refit has converged when a step gains less than this fraction of the final fit's χ²: a
/// ΔBIC known to 10⁻⁵ n, a few hundredths on a dataset of thousands of entries.
const REFIT_TOLERANCE: f64 = 1e-5;

/// What the injected refits made of one parameter's statement.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "check", rename_all = "snake_case")]
pub enum Checked {
    /// Not checked (no statement, or one with no single magnitude).
    NotChecked,
    /// Shortlisted when put in at `value` (in the parameter's unit), `factor` × the statement.
    Found {
        /// The magnitude put in.
        value: f64,
        /// Its multiple of the linearised statement.
        factor: f64,
        /// The rule's ΔBIC on the refits.
        delta_bic: f64,
    },
    /// Not shortlisted at any factor tried; the largest tried and its ΔBIC (`None`: a refit left
    /// the physical range).
    NotFound {
        /// The largest magnitude put in.
        value: f64,
        /// Its multiple of the linearised statement.
        factor: f64,
        /// The rule's ΔBIC on the refits there.
        delta_bic: Option<f64>,
    },
    /// Twice the statement is beyond the plausible size of the effect (θ units), not put in.
    Implausible {
        /// The plausible limit of |θ|.
        limit: f64,
    },
}

impl Checked {
    /// Found at the first factor tried.
    pub fn found_first(&self) -> bool {
        matches!(self, Checked::Found { factor, .. } if *factor == FACTORS[0])
    }

    /// The statement of parameter `name` whose linearised least magnitude is `min` (in `unit`),
    /// as the checks leave it true.
    pub fn statement(&self, name: &str, min: f64, unit: &str) -> String {
        let q = |v: f64| palpate_fem::numbers::quantity(v, unit);
        match self {
            Checked::NotChecked => format!("{name} ≥ {}", q(min)),
            Checked::Found { factor, .. } if *factor == FACTORS[0] => {
                format!("{name} ≥ {}, found when put in at {factor}×", q(min))
            }
            Checked::Found { value, factor, .. } => format!(
                "{name} ≥ {} by the linearisation, but found only at {factor}×, {}",
                q(min),
                q(*value)
            ),
            Checked::NotFound {
                value,
                factor,
                delta_bic,
            } => format!(
                "{name}: **not found** when put in at {factor}× the linearisation's {}, {}{}",
                q(min),
                q(*value),
                delta_bic.map_or(" (a refit diverged)".to_string(), |d| format!(
                    " (ΔBIC {d:.1})"
                ))
            ),
            Checked::Implausible { .. } => format!(
                "{name}: ≥ {} by the linearisation, beyond a plausible size",
                q(min)
            ),
        }
    }
}

/// One statement to check: where it is in the list, the candidate and what is put in.
struct Job {
    statement: usize,
    param: usize,
    candidate: Candidate,
    what: Put,
}

/// What a check puts into the data.
enum Put {
    /// A θ parameter of the candidate's block: its column, the linearised magnitude (θ units).
    Theta { column: usize, theta_min: f64 },
    /// A per-measurement kind: its residual columns at the final fit (units of σ, one per
    /// measurement and direction) and the stated RMS ε.
    Profiled { columns: Vec<Vec<f64>>, eps: f64 },
}

/// Checks every statement of `detectable` (made at the final fit `f` with the shortlist
/// threshold of `o`) by injected refits, and records the outcome on each parameter.
/// `progress` hears how many checks there are.
pub fn check_statements(
    ctx: &Context,
    f: &Fitted,
    detectable: &mut [Detectable],
    o: &DiagnoseOptions,
    progress: &mut dyn FnMut(&str),
) -> Result<(), DiagnoseError> {
    let grid = ctx.grid;
    let point = PowerPoint {
        at: At {
            model: &f.model,
            ctx,
            theta: &f.theta,
            log_e: None,
        },
        subset: &f.subset,
        sim: &f.sim,
    };
    let mut jobs = Vec::new();
    for (s, d) in detectable.iter().enumerate() {
        let c = d.candidate;
        let effect = c.effect();
        if let Some(kinds) = effect.profiled_columns(&point) {
            for (p, ((_, _, columns), param)) in kinds?.into_iter().zip(&d.params).enumerate() {
                if let Some(eps) = param.min {
                    let what = Put::Profiled { columns, eps };
                    jobs.push(Job {
                        statement: s,
                        param: p,
                        candidate: c,
                        what,
                    });
                }
            }
            continue;
        }
        if effect.power_start(grid).is_none() {
            continue;
        }
        let names = c.param_names(grid);
        for (p, (param, &column)) in d.params.iter().zip(&effect.live_columns(grid)).enumerate() {
            if let Some(min) = param.min {
                let theta_min = min / names[column].2;
                let what = Put::Theta { column, theta_min };
                jobs.push(Job {
                    statement: s,
                    param: p,
                    candidate: c,
                    what,
                });
            }
        }
    }
    if jobs.is_empty() {
        return Ok(());
    }
    progress(&format!(
        "checking {} statements by injected refits (each twice the size, refitted with and without)",
        jobs.len()
    ));
    let absorb = Absorption::at(ctx, f)?;
    let outcomes: Vec<Result<Checked, DiagnoseError>> = jobs
        .par_iter()
        .map(|job| match &job.what {
            Put::Theta { column, theta_min } => {
                check_theta(ctx, f, &absorb, (job.candidate, *column, *theta_min), o)
            }
            Put::Profiled { columns, eps } => {
                check_profiled(ctx, f, &absorb, (job.candidate, columns, *eps), o)
            }
        })
        .collect();
    for (job, outcome) in jobs.iter().zip(outcomes) {
        detectable[job.statement].params[job.param].checked = outcome?;
    }
    Ok(())
}

/// A θ parameter's check: column `column` of `c`'s block put in at each of [`FACTORS`] times
/// `theta_min` in turn until the rule finds it.
fn check_theta(
    ctx: &Context,
    f: &Fitted,
    absorb: &Absorption,
    (c, column, theta_min): (Candidate, usize, f64),
    o: &DiagnoseOptions,
) -> Result<Checked, DiagnoseError> {
    let effect = c.effect();
    let grid = ctx.grid;
    if let Some(limit) = effect.plausible_magnitude() {
        if FACTORS[0] * theta_min > limit {
            return Ok(Checked::Implausible { limit });
        }
    }
    let scale = c.param_names(grid)[column].2;
    let k = c.params(grid) as f64;
    let with = f.model.with(c);
    let start = effect.power_start(grid).expect("a θ statement");
    let mut data = ctx.clone();
    first_found(o, |factor| {
        let mut block = start.clone();
        block[column] += factor * theta_min;
        let mut theta = f.theta.clone();
        theta.extend(&block);
        let delta_bic = match unless_diverged(with.simulate_near(ctx, &theta, &f.subset, &f.sim))? {
            Some(sim) => {
                for (&i, markers) in f.subset.iter().zip(&sim.markers) {
                    for ((_, p), q) in data.meas[i].observed.iter_mut().zip(markers) {
                        *p = *q;
                    }
                }
                refit_gain(&mut data, f, absorb, (c, &block, Some(sim)), k, o)?
            }
            None => None,
        };
        Ok((factor * theta_min * scale, delta_bic))
    })
}

/// A per-measurement kind's check: its residual columns `columns` (at the final fit) summed
/// with alternating signs — over the measurements, and over the directions, so that the
/// pattern has RMS ε per parameter and no common part the fitted parameters would take up —
/// and put in at each of [`FACTORS`] times `eps` in turn until the rule finds it. Along the
/// candidate's own response: exact for a force scale and a translation, the linear response
/// for a rotation and a tilt.
fn check_profiled(
    ctx: &Context,
    f: &Fitted,
    absorb: &Absorption,
    (c, columns, eps): (Candidate, &[Vec<f64>], f64),
    o: &DiagnoseOptions,
) -> Result<Checked, DiagnoseError> {
    let m = f.subset.len().max(1);
    let n = columns.first().map_or(0, |c| c.len());
    let mut pattern = vec![0.0; n];
    for (j, col) in columns.iter().enumerate() {
        let sign = if (j % m + j / m).is_multiple_of(2) {
            1.0
        } else {
            -1.0
        };
        pattern
            .iter_mut()
            .zip(col)
            .for_each(|(p, v)| *p += sign * v);
    }
    let (offset, _) = row_offsets(ctx, &f.subset);
    let k = c.profiled(f.subset.len()) as f64;
    let mut data = ctx.clone();
    first_found(o, |factor| {
        let size = factor * eps * ctx.sigma;
        for (a, (&i, markers)) in f.subset.iter().zip(&f.sim.markers).enumerate() {
            for (j, ((_, p), q)) in data.meas[i].observed.iter_mut().zip(markers).enumerate() {
                *p = [0, 1, 2].map(|d| q[d] + size * pattern[offset[a] + 3 * j + d]);
            }
        }
        let delta_bic = refit_gain(&mut data, f, absorb, (c, &[], None), k, o)?;
        Ok((factor * eps, delta_bic))
    })
}

/// The first of [`FACTORS`] at which `put_in` (the magnitude put in and the rule's ΔBIC, `None`
/// where a refit diverged) is shortlisted, or the last tried.
fn first_found(
    o: &DiagnoseOptions,
    mut put_in: impl FnMut(f64) -> Result<(f64, Option<f64>), DiagnoseError>,
) -> Result<Checked, DiagnoseError> {
    let mut last = Checked::NotChecked;
    for factor in FACTORS {
        let (value, delta_bic) = put_in(factor)?;
        if let Some(d) = delta_bic.filter(|d| *d < -o.bic_threshold) {
            return Ok(Checked::Found {
                value,
                factor,
                delta_bic: d,
            });
        }
        last = Checked::NotFound {
            value,
            factor,
            delta_bic,
        };
    }
    Ok(last)
}

/// The final model's Jacobian at its fit and the pseudo-inverse of its normal matrix: what a
/// Gauss–Newton step of its parameters takes up of a residual.
struct Absorption {
    j: DMatrix<f64>,
    h_inv: Option<DMatrix<f64>>,
}

impl Absorption {
    fn at(ctx: &Context, f: &Fitted) -> Result<Self, DiagnoseError> {
        let r = f.model.residuals(ctx, &f.subset, &f.sim.markers);
        let all: Vec<usize> = (0..f.theta.len()).collect();
        let j = jacobian_columns(
            ctx, &f.model, &f.theta, &f.subset, &f.sim, &r, &all, FD_STEP,
        )?;
        let h = j.transpose() * &j;
        let h_inv = h.clone().pseudo_inverse(1e-12 * h.norm()).ok();
        Ok(Absorption { j, h_inv })
    }

    /// The χ² the parameters' Gauss–Newton step leaves of residual `r`.
    fn left(&self, r: &[f64]) -> f64 {
        let r = DVector::from_column_slice(r);
        match &self.h_inv {
            Some(inv) => (&r - &self.j * (inv * (self.j.transpose() * &r))).norm_squared(),
            None => r.norm_squared(),
        }
    }
}

/// The rule's ΔBIC on `data` for the final model of `f` with and without `c` (k its
/// parameters, `injected` its block in the data, `made` the simulation that made the data when
/// they are one), measured in the final fit's residual variance per entry; `None` where a refit
/// leaves the physical range.
///
/// A candidate the diagnosis starts where its sensitivity scan places it (the layer, the
/// inclusion: [`StaticEffect::placed_by_scan`](super::candidates::StaticEffect::placed_by_scan))
/// is searched for as the diagnosis searches: the final model refitted to these data, the scan
/// of the residual it leaves ([`locate_candidates`]), the candidate refitted from there — whether
/// the search finds the effect is part of the statement. Any other starts from zero effect in
/// the diagnosis, where Levenberg–Marquardt on its one or two parameters reaches the optimum it
/// reaches from the effect put in: it starts there, a few iterations from the end, and the
/// final model's refit without it is the Gauss–Newton step of `absorb`.
fn refit_gain(
    data: &mut Context,
    f: &Fitted,
    absorb: &Absorption,
    (c, injected, made): (Candidate, &[f64], Option<Simulated>),
    k: f64,
    o: &DiagnoseOptions,
) -> Result<Option<f64>, DiagnoseError> {
    let stop = Stop {
        max_iterations: REFIT_ITERATIONS,
        rel_tolerance: REFIT_TOLERANCE,
        chi2_floor: f.chi2,
    };
    let effect = c.effect();
    let augmented = f.model.with(c);
    let (chi2_without, theta, start) = if effect.placed_by_scan() {
        let refit = fit_until(
            data,
            &f.model,
            f.theta.clone(),
            &f.subset,
            Some(&f.sim.x),
            stop,
        );
        let Some(without) = unless_diverged(refit)? else {
            return Ok(None);
        };
        locate_candidates(data, None, &without, o, &mut |_| {});
        let mut theta = without.theta.clone();
        theta.extend(effect.fit_start(data, data.grid));
        (without.chi2, theta, Start::Near(without.sim.x))
    } else {
        // The final model's per-measurement effects (if any) profiled against these data; a
        // model that profiles nothing simulates these data as it simulated the dataset.
        let profiled;
        let at_fit = if profiles_nothing(&f.model, f.subset.len()) {
            &f.sim
        } else {
            let sim = f.model.simulate_near(data, &f.theta, &f.subset, &f.sim);
            let Some(sim) = unless_diverged(sim)? else {
                return Ok(None);
            };
            profiled = sim;
            &profiled
        };
        let r = f.model.residuals(data, &f.subset, &at_fit.markers);
        let mut theta = f.theta.clone();
        theta.extend(injected);
        // Started where the data were made, by a model that profiles nothing against them: the
        // simulation that made them is the refit's first, to the bit.
        let start = match made {
            Some(sim) if profiles_nothing(&augmented, f.subset.len()) => Start::Made(sim),
            _ => Start::Near(at_fit.x.clone()),
        };
        (absorb.left(&r), theta, start)
    };
    let refit = match start {
        Start::Made(sim) => fit_from(data, &augmented, theta, &f.subset, sim, stop),
        Start::Near(x) => fit_until(data, &augmented, theta, &f.subset, Some(&x), stop),
    };
    let Some(with) = unless_diverged(refit)? else {
        return Ok(None);
    };
    let n = f.n as f64;
    let s2 = f.chi2 / n.max(1.0);
    Ok(Some(-(chi2_without - with.chi2) / s2 + k * n.ln()))
}

/// Where a check's refit with the candidate starts from.
enum Start {
    /// The simulation that made the data, at the refit's first parameters.
    Made(Simulated),
    /// Node positions to warm-start its first simulation from.
    Near(Vec<Vec<[f64; 3]>>),
}

/// Whether `model`'s markers are its simulation's alone: no per-measurement effect profiled
/// against the observations of `measurements` measurements.
fn profiles_nothing(model: &Model, measurements: usize) -> bool {
    model.effects.iter().all(|e| e.profiled(measurements) == 0)
}

/// `Ok(None)` where a simulation or a refit left the physical range (no figure for the check,
/// which says so), the other errors as they are.
fn unless_diverged<T>(r: Result<T, DiagnoseError>) -> Result<Option<T>, DiagnoseError> {
    match r {
        Ok(v) => Ok(Some(v)),
        Err(DiagnoseError::Diverged(_)) => Ok(None),
        Err(e) => Err(e),
    }
}

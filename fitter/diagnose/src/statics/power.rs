//! What the diagnosis could have missed: for every candidate effect that the final model does not
//! hold, the smallest magnitude this dataset would have detected — the power statement a "clean"
//! verdict needs, since "no effect found" means little without "effects this large would have
//! been found".
//!
//! Linearised at the final fit θ̂ with the candidate's block at zero: the residual (in units of
//! σ) moves by J_b δ_b + J_c a for base changes δ_b and candidate parameters a. Refitting the base
//! with the candidate absorbs what J_b can explain, so the χ² a candidate of magnitude a leaves
//! unexplained is aᵀ S a with the Schur complement S = J_cᵀJ_c − J_cᵀJ_b (J_bᵀJ_b)⁻¹ J_bᵀJ_c.
//! With the other parameters of the block free, parameter j alone reaches Δχ² = a_j² / (S⁻¹)_jj.
//! The selection rule shortlists a candidate when ΔBIC = n ln(χ²_new/χ²_old) + k ln n < −T;
//! for a small gain n ln(χ²_new/χ²_old) ≈ −Δχ²/s² with s² = χ²_old/n, so parameter j is
//! detectable from
//!
//!   |a_j| ≥ √( s² (k ln n + T) (S⁻¹)_jj ).
//!
//! This is the shortlist's threshold only: the held-out gate asks more, so an effect must be at
//! least this large to be adopted (a lower bound of what would be adopted).
//!
//! Candidates profiled per measurement (`force-scale-each`, `registration-each`) have a
//! parameter per measurement and no single magnitude: their statement is for an effect that
//! varies at random from measurement to measurement with RMS ε per parameter (independent
//! between measurements and axes). Its expected gain is ε² tr S over the kind's columns (each
//! kind on its own: a registration's translations, its rotations), so ε is detectable on
//! average from ε ≥ √(s² (k ln n + T) / tr S),
//! k the candidate's profiled count. `tilt-each`'s columns are its probing solves' responses
//! (two more solves per measurement, made only for the statement).

use nalgebra::DMatrix;
use serde::Serialize;

use super::candidates::{At, PowerPoint};
use super::fit::{jacobian_columns, Fitted};
use super::model::{Candidate, Context, Model, Simulated, ALL_CANDIDATES};
use super::power_check::{Checked, FACTORS};
use super::DiagnoseError;

/// Secant step on the dimensionless θ (scaled so that 1 is a large effect: 1000 kg/m³, a factor
/// e in modulus, 1 mrad). Not the fit's 1e-4: a candidate whose markers barely respond (a gravity
/// preload under a rest scan taken under gravity moves the displacements only through the
/// rotations) would then see the solver's 1e-10 m tolerance as a column of ≈ 1e-2 per entry and
/// be called detectable on noise; at 0.05 that noise is 2e-5 per entry, and the secant measures
/// the response at a magnitude of the order of the statement's.
const FD_STEP: f64 = 0.05;

/// The smallest detectable magnitude of one parameter of a candidate.
#[derive(Debug, Clone, Serialize)]
pub struct DetectableParam {
    /// The parameter's name (as in the fitted parameter tables).
    pub name: String,
    /// Its unit ("" for dimensionless).
    pub unit: &'static str,
    /// Smallest |value| detectable in that unit (`None`: the dataset cannot tell this parameter
    /// from the fitted ones at any magnitude).
    pub min: Option<f64>,
    /// What the injected refits made of it ([`super::power_check`]).
    pub checked: Checked,
}

/// The power statement for one candidate.
#[derive(Debug, Clone, Serialize)]
pub struct Detectable {
    /// The candidate.
    pub candidate: Candidate,
    /// Its parameters' smallest detectable magnitudes.
    pub params: Vec<DetectableParam>,
    /// What the statement assumes beyond the linearisation (e.g. where an inclusion is placed).
    pub note: Option<&'static str>,
}

impl Detectable {
    /// One line for a report: the candidate and its detectable magnitudes (a range over many
    /// parameters of the same kind).
    pub fn describe(&self) -> String {
        let fmt = |p: &DetectableParam| match p.min {
            Some(v) => p.checked.statement(&p.name, v, p.unit),
            None => format!("{}: not separable from the fitted parameters", p.name),
        };
        let body = if self.params.len() > 6 {
            let mins: Vec<f64> = self.params.iter().filter_map(|p| p.min).collect();
            let lo = mins.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = mins.iter().copied().fold(0.0f64, f64::max);
            let kind = self.params[0]
                .name
                .split(" at ")
                .next()
                .unwrap_or("")
                .to_string();
            if mins.is_empty() {
                format!("{kind}: not separable from the fitted parameters")
            } else {
                format!(
                    "{kind} ≥ {}–{} over its {} nodes{}{}",
                    sig3(lo),
                    sig3(hi),
                    self.params.len(),
                    if mins.len() < self.params.len() {
                        format!(" ({} not separable)", self.params.len() - mins.len())
                    } else {
                        String::new()
                    },
                    checked_counts(&self.params)
                )
            }
        } else if self
            .params
            .iter()
            .all(|p| p.min.is_some() && p.checked.found_first())
        {
            // Each found at the first factor: the linearised figures, said once.
            let each = if self.params.len() > 1 { "each " } else { "" };
            let plain = self
                .params
                .iter()
                .map(|p| Checked::NotChecked.statement(&p.name, p.min.unwrap_or(0.0), p.unit));
            format!(
                "{}; {each}found when put in at {}×",
                plain.collect::<Vec<_>>().join(", "),
                FACTORS[0]
            )
        } else {
            self.params.iter().map(fmt).collect::<Vec<_>>().join(", ")
        };
        match self.note {
            Some(n) => format!("{}: {body} ({n})", self.candidate.name()),
            None => format!("{}: {body}", self.candidate.name()),
        }
    }
}

/// The injected checks of many parameters of one kind, counted: "; checked: 3 found at 2×, …".
fn checked_counts(params: &[DetectableParam]) -> String {
    let mut found = [0usize; FACTORS.len()];
    let (mut missed, mut implausible) = (0, 0);
    for p in params {
        match &p.checked {
            Checked::Found { factor, .. } => {
                if let Some(k) = FACTORS.iter().position(|f| f == factor) {
                    found[k] += 1;
                }
            }
            Checked::NotFound { .. } => missed += 1,
            Checked::Implausible { .. } => implausible += 1,
            Checked::NotChecked => {}
        }
    }
    let mut parts: Vec<String> = FACTORS
        .iter()
        .zip(found)
        .filter(|(_, k)| *k > 0)
        .map(|(f, k)| format!("{k} found at {f}×"))
        .collect();
    if missed > 0 {
        let largest = FACTORS[FACTORS.len() - 1];
        parts.push(format!("{missed} **not found** at {largest}×"));
    }
    if implausible > 0 {
        parts.push(format!(
            "{implausible} beyond a plausible size at {}× (not put in)",
            FACTORS[0]
        ));
    }
    if parts.is_empty() {
        String::new()
    } else {
        format!("; checked: {}", parts.join(", "))
    }
}

fn sig3(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let digits = (2 - v.abs().log10().floor() as i32).max(0) as usize;
    if v.abs() >= 1e5 || v.abs() < 1e-3 {
        format!("{v:.2e}")
    } else {
        format!("{v:.digits$}")
    }
}

/// The smallest detectable magnitudes of every θ-candidate the final fit `f` does not hold, at
/// the shortlist threshold `bic_threshold` (T above), then of every profiled one.
pub fn detectable(
    ctx: &Context,
    f: &Fitted,
    bic_threshold: f64,
) -> Result<Vec<Detectable>, DiagnoseError> {
    let candidates: Vec<(Candidate, Vec<f64>)> = ALL_CANDIDATES
        .iter()
        .copied()
        .filter(|c| !f.model.effects.contains(c))
        .filter_map(|c| c.effect().power_start(ctx.grid).map(|b| (c, b)))
        .collect();
    if candidates.is_empty() {
        return Ok(Vec::new());
    }
    // Every candidate at zero effect in one augmented model: the simulation is the final fit's.
    let mut model = f.model.clone();
    let mut theta = f.theta.clone();
    for (c, block) in &candidates {
        model = model.with(*c);
        theta.extend(block);
    }
    let subset = &f.subset;
    let sim = model.simulate_near(ctx, &theta, subset, &f.sim)?;
    let r0 = model.residuals(ctx, subset, &sim.markers);
    let n = r0.len();
    let chi2: f64 = r0.iter().map(|v| v * v).sum();
    let lin = Linearised {
        s2: chi2 / n.max(1) as f64,
        n,
        threshold: bic_threshold,
    };
    let (j, where_) = live_jacobian(ctx, f, (&model, &theta), &sim, &r0, &candidates)?;
    let jb = j.columns(0, f.theta.len()).into_owned();
    let hbb = jb.transpose() * &jb;
    let hbb_inv = hbb.clone().pseudo_inverse(1e-12 * hbb.norm()).ok();
    let mut out: Vec<Detectable> = where_
        .into_iter()
        .map(|(c, mine)| block_statement(ctx.grid, &lin, c, &mine, &j, (&jb, &hbb_inv)))
        .collect();
    let point = PowerPoint {
        at: At {
            model: &model,
            ctx,
            theta: &theta,
            log_e: None,
        },
        subset,
        sim: &sim,
    };
    // The profiled statements follow the θ ones, the last tried first.
    for &c in ALL_CANDIDATES.iter().rev() {
        if f.model.effects.contains(&c) {
            continue;
        }
        let Some(kinds) = c.effect().profiled_columns(&point) else {
            continue;
        };
        let need = lin.need(c.profiled(subset.len()) as f64);
        let params = kinds?
            .into_iter()
            .map(|(name, unit, cols)| {
                let t = trace(&cols, &jb, &hbb_inv);
                DetectableParam {
                    name: name.into(),
                    unit,
                    min: (t > 0.0 && t.is_finite()).then(|| (need / t).sqrt()),
                    checked: Checked::NotChecked,
                }
            })
            .collect();
        out.push(Detectable {
            candidate: c,
            params,
            note: Some("RMS over the measurements of an effect that differs in each"),
        });
    }
    Ok(out)
}

/// The linearisation's scale: the residual variance per entry s², the entries n and the
/// shortlist threshold T.
struct Linearised {
    s2: f64,
    n: usize,
    threshold: f64,
}

impl Linearised {
    /// The Δχ² a candidate of `k` parameters must explain to be shortlisted, s² (k ln n + T).
    fn need(&self, k: f64) -> f64 {
        self.s2 * (k * (self.n as f64).ln() + self.threshold)
    }
}

/// The Jacobian at the augmented model's point `(model, theta)`: the final model's parameters
/// (base and adopted), then the candidates' live columns, and where each candidate's are.
fn live_jacobian(
    ctx: &Context,
    f: &Fitted,
    (model, theta): (&Model, &[f64]),
    sim: &Simulated,
    r0: &[f64],
    candidates: &[(Candidate, Vec<f64>)],
) -> Result<(DMatrix<f64>, Vec<(Candidate, Vec<usize>)>), DiagnoseError> {
    let grid = ctx.grid;
    let mut cols: Vec<usize> = (0..f.theta.len()).collect();
    let mut where_: Vec<(Candidate, Vec<usize>)> = Vec::new();
    for &(c, _) in candidates {
        let o = model.offset(c, grid).expect("added above");
        let mine: Vec<usize> = c
            .effect()
            .live_columns(grid)
            .into_iter()
            .map(|j| {
                cols.push(o + j);
                cols.len() - 1
            })
            .collect();
        where_.push((c, mine));
    }
    let j = jacobian_columns(ctx, model, theta, &f.subset, sim, r0, &cols, FD_STEP)?;
    Ok((j, where_))
}

/// The power statement of θ-candidate `c` from its columns `mine` of `j`, against the fitted
/// parameters' columns `jb` (and the pseudo-inverse of their normal matrix).
fn block_statement(
    grid: [usize; 3],
    lin: &Linearised,
    c: Candidate,
    mine: &[usize],
    j: &DMatrix<f64>,
    (jb, hbb_inv): (&DMatrix<f64>, &Option<DMatrix<f64>>),
) -> Detectable {
    let effect = c.effect();
    let k = c.params(grid) as f64;
    let mut jc = DMatrix::zeros(lin.n, mine.len());
    for (a, &col) in mine.iter().enumerate() {
        jc.column_mut(a).copy_from(&j.column(col));
    }
    let hcc = jc.transpose() * &jc;
    let hcb = jc.transpose() * jb;
    let s = match hbb_inv {
        Some(inv) => &hcc - &hcb * inv * hcb.transpose(),
        None => hcc.clone(),
    };
    let need = lin.need(k);
    let s_inv = s.clone().try_inverse();
    let names = c.param_names(grid);
    let params = effect
        .live_columns(grid)
        .into_iter()
        .enumerate()
        .map(|(a, p)| {
            let (name, unit, scale) = names[p].clone();
            // A direction the fitted parameters already explain (S singular there, or S⁻¹
            // negative from round-off) is not detectable at any magnitude.
            let var = s_inv
                .as_ref()
                .map(|inv| inv[(a, a)])
                .filter(|v| v.is_finite() && *v > 0.0 && s[(a, a)] > 1e-12 * hcc[(a, a)]);
            DetectableParam {
                name,
                unit,
                min: var.map(|v| (need * v).sqrt() * scale),
                checked: Checked::NotChecked,
            }
        })
        .collect();
    Detectable {
        candidate: c,
        params,
        note: effect.power_note(),
    }
}

/// tr S of a set of columns against the fitted parameters' columns `jb`:
/// Σ ‖c‖² − (J_bᵀc)ᵀ H_bb⁻¹ (J_bᵀc).
fn trace(cols: &[Vec<f64>], jb: &DMatrix<f64>, hbb_inv: &Option<DMatrix<f64>>) -> f64 {
    cols.iter()
        .map(|c| {
            let c = nalgebra::DVector::from_column_slice(c);
            let bc = jb.transpose() * &c;
            c.norm_squared() - hbb_inv.as_ref().map_or(0.0, |inv| bc.dot(&(inv * &bc)))
        })
        .sum()
}

/// The first residual row of each measurement of `subset` in [`Model::residuals`]'s order, and
/// the number of rows.
pub(in crate::statics) fn row_offsets(ctx: &Context, subset: &[usize]) -> (Vec<usize>, usize) {
    let mut offset = Vec::with_capacity(subset.len());
    let mut n = 0;
    for &i in subset {
        offset.push(n);
        n += 3 * ctx.meas[i].observed.len();
    }
    (offset, n)
}

/// Residual columns (units of σ, in [`Model::residuals`]'s order) of a per-measurement
/// parameter at the simulated markers `sims`: one column per measurement of `subset`, its rows
/// `entry(marker index, simulated position, the measurement's marker centroid)`.
pub(in crate::statics) fn measurement_columns(
    ctx: &Context,
    subset: &[usize],
    sims: &[Vec<[f64; 3]>],
    entry: &dyn Fn(usize, [f64; 3], [f64; 3]) -> [f64; 3],
) -> Vec<Vec<f64>> {
    let (offset, n) = row_offsets(ctx, subset);
    subset
        .iter()
        .enumerate()
        .map(|(a, &i)| {
            let pts = &sims[a];
            let mut centre = [0.0; 3];
            for p in pts {
                (0..3).for_each(|d| centre[d] += p[d] / pts.len().max(1) as f64);
            }
            let mut col = vec![0.0; n];
            for (j, (&(k, _), p)) in ctx.meas[i].observed.iter().zip(pts).enumerate() {
                let e = entry(k, *p, centre);
                for d in 0..3 {
                    col[offset[a] + 3 * j + d] = e[d] / ctx.sigma;
                }
            }
            col
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn magnitudes_print_with_three_significant_digits() {
        assert_eq!(sig3(123.456), "123");
        assert_eq!(sig3(0.0123456), "0.0123");
        assert_eq!(sig3(2.5), "2.50");
        assert_eq!(sig3(2.5e-5), "2.50e-5");
        let d = Detectable {
            candidate: Candidate::Gravity,
            params: vec![DetectableParam {
                name: "density ρ".into(),
                unit: "kg/m³",
                min: Some(412.3),
                checked: Checked::NotChecked,
            }],
            note: None,
        };
        assert_eq!(d.describe(), "gravity: density ρ ≥ 412 kg/m³");
    }
}

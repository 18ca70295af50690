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

use super::fit::{jacobian_columns, Fitted};
use super::model::{Candidate, Context, ALL_CANDIDATES};
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
            Some(v) => format!("{} ≥ {}{}", p.name, sig3(v), unit_suffix(p.unit)),
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
                    "{kind} ≥ {}–{} over its {} nodes{}",
                    sig3(lo),
                    sig3(hi),
                    self.params.len(),
                    if mins.len() < self.params.len() {
                        format!(" ({} not separable)", self.params.len() - mins.len())
                    } else {
                        String::new()
                    }
                )
            }
        } else {
            self.params.iter().map(fmt).collect::<Vec<_>>().join(", ")
        };
        match self.note {
            Some(n) => format!("{}: {body} ({n})", self.candidate.name()),
            None => format!("{}: {body}", self.candidate.name()),
        }
    }
}

fn unit_suffix(unit: &str) -> String {
    if unit.is_empty() {
        String::new()
    } else {
        format!(" {unit}")
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

/// The columns of the candidates' blocks that carry their magnitude at zero effect: every
/// parameter, except the inclusion's position and radius, which are invisible at zero contrast
/// (its contrast is stated at the candidate's starting place).
fn live_columns(c: Candidate, grid: [usize; 3]) -> Vec<usize> {
    match c {
        Candidate::Inclusion => vec![0],
        _ => (0..c.params(grid)).collect(),
    }
}

/// The smallest detectable magnitudes of every θ-candidate the final fit `f` does not hold, at
/// the shortlist threshold `bic_threshold` (T above).
pub fn detectable(
    ctx: &Context,
    f: &Fitted,
    bic_threshold: f64,
) -> Result<Vec<Detectable>, DiagnoseError> {
    let grid = ctx.grid;
    let candidates: Vec<Candidate> = ALL_CANDIDATES
        .iter()
        .copied()
        .filter(|&c| c.params(grid) > 0 && !f.model.effects.contains(&c))
        // The fixed support is the foundation's limit ℓ_n → 0, not a point of its θ, and its
        // response vanishes there: no finite column states its power.
        .filter(|&c| c != Candidate::Support)
        .collect();
    if candidates.is_empty() {
        return Ok(Vec::new());
    }
    // Every candidate at zero effect in one augmented model: the simulation is the final fit's.
    let mut model = f.model.clone();
    for &c in &candidates {
        model = model.with(c);
    }
    let mut theta = f.theta.clone();
    for &c in &candidates {
        let mut block = c.start(grid);
        if c == Candidate::Inclusion {
            block[0] = 0.0;
        }
        theta.extend(block);
    }
    let subset = &f.subset;
    let sim = model.simulate_near(ctx, &theta, subset, &f.sim)?;
    let r0 = model.residuals(ctx, subset, &sim.markers);
    let n = r0.len();
    let chi2: f64 = r0.iter().map(|v| v * v).sum();
    let s2 = chi2 / n.max(1) as f64;

    // Columns: the final model's parameters (base and adopted), then the candidates' live ones.
    let kb = f.theta.len();
    let mut cols: Vec<usize> = (0..kb).collect();
    let mut where_: Vec<(Candidate, Vec<usize>)> = Vec::new();
    for &c in &candidates {
        let o = model.offset(c, grid).expect("added above");
        let mine: Vec<usize> = live_columns(c, grid)
            .into_iter()
            .map(|j| {
                cols.push(o + j);
                cols.len() - 1
            })
            .collect();
        where_.push((c, mine));
    }
    let j = jacobian_columns(ctx, &model, &theta, subset, &sim, &r0, &cols, FD_STEP)?;
    let jb = j.columns(0, kb).into_owned();
    let hbb = jb.transpose() * &jb;
    let hbb_inv = hbb.clone().pseudo_inverse(1e-12 * hbb.norm()).ok();

    let mut out = Vec::new();
    for (c, mine) in where_ {
        let k = c.params(grid) as f64;
        let mut jc = DMatrix::zeros(n, mine.len());
        for (a, &col) in mine.iter().enumerate() {
            jc.column_mut(a).copy_from(&j.column(col));
        }
        let hcc = jc.transpose() * &jc;
        let hcb = jc.transpose() * &jb;
        let s = match &hbb_inv {
            Some(inv) => &hcc - &hcb * inv * hcb.transpose(),
            None => hcc.clone(),
        };
        let need = s2 * (k * (n as f64).ln() + bic_threshold);
        let s_inv = s.clone().try_inverse();
        let names = c.param_names(grid);
        let params = live_columns(c, grid)
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
                }
            })
            .collect();
        out.push(Detectable {
            candidate: c,
            params,
            note: (c == Candidate::Inclusion).then_some(
                "r = h/2, centred a quarter deep below the mean contact point: its starting place",
            ),
        });
    }
    // tr S of a set of columns against the fitted parameters: Σ ‖c‖² − (J_bᵀc)ᵀ H_bb⁻¹ (J_bᵀc).
    let trace = |cols: &[Vec<f64>]| -> f64 {
        cols.iter()
            .map(|c| {
                let c = nalgebra::DVector::from_column_slice(c);
                let bc = jb.transpose() * &c;
                c.norm_squared() - hbb_inv.as_ref().map_or(0.0, |inv| bc.dot(&(inv * &bc)))
            })
            .sum()
    };
    let m = subset.len();
    for c in [
        Candidate::ForceScaleEach,
        Candidate::RegistrationEach,
        Candidate::TiltEach,
    ] {
        if f.model.effects.contains(&c) {
            continue;
        }
        let need = s2 * (c.profiled(m) as f64 * (n as f64).ln() + bic_threshold);
        let kinds = if c == Candidate::TiltEach {
            let tilt = model.tilt_responses(ctx, &theta, subset, &sim)?;
            vec![(
                "tangential coefficient per direction",
                "",
                tilt_columns(ctx, subset, &tilt),
            )]
        } else {
            per_measurement_columns(ctx, subset, &sim.markers, c)
        };
        let params = kinds
            .into_iter()
            .map(|(name, unit, cols)| {
                let t = trace(&cols);
                DetectableParam {
                    name: name.into(),
                    unit,
                    min: (t > 0.0 && t.is_finite()).then(|| (need / t).sqrt()),
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

/// `tilt-each`'s residual columns (units of σ, in [`Model::residuals`]'s order): per measurement
/// and tangent direction, its markers' response to a unit tangential coefficient (× |f|).
///
/// [`Model::residuals`]: super::model::Model::residuals
fn tilt_columns(ctx: &Context, subset: &[usize], tilt: &[[Vec<[f64; 3]>; 2]]) -> Vec<Vec<f64>> {
    let (offset, n) = row_offsets(ctx, subset);
    let mut out = Vec::with_capacity(2 * subset.len());
    for (a, responses) in tilt.iter().enumerate() {
        for resp in responses {
            let mut col = vec![0.0; n];
            for (j, p) in resp.iter().enumerate() {
                for d in 0..3 {
                    col[offset[a] + 3 * j + d] = p[d] / ctx.sigma;
                }
            }
            out.push(col);
        }
    }
    out
}

/// The first residual row of each measurement of `subset` in [`Model::residuals`]'s order, and
/// the number of rows.
///
/// [`Model::residuals`]: super::model::Model::residuals
fn row_offsets(ctx: &Context, subset: &[usize]) -> (Vec<usize>, usize) {
    let mut offset = Vec::with_capacity(subset.len());
    let mut n = 0;
    for &i in subset {
        offset.push(n);
        n += 3 * ctx.meas[i].observed.len();
    }
    (offset, n)
}

/// The residual columns (units of σ, in [`Model::residuals`]'s order) of a per-measurement
/// candidate's parameters at the simulated markers `sims`, grouped by kind: for
/// `force-scale-each` one column per measurement (its markers' displacement: a scale 1 + s
/// moves them by s times it); for `registration-each` a translation column per measurement and
/// axis, and a rotation column per measurement and axis (about its markers' centroid).
///
/// [`Model::residuals`]: super::model::Model::residuals
fn per_measurement_columns(
    ctx: &Context,
    subset: &[usize],
    sims: &[Vec<[f64; 3]>],
    c: Candidate,
) -> Vec<(&'static str, &'static str, Vec<Vec<f64>>)> {
    let (offset, n) = row_offsets(ctx, subset);
    // One column per measurement from `entry(k, marker position, centroid) -> 3 rows`.
    let columns = |entry: &dyn Fn(usize, [f64; 3], [f64; 3]) -> [f64; 3]| -> Vec<Vec<f64>> {
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
    };
    match c {
        Candidate::ForceScaleEach => vec![(
            "force scale s",
            "",
            columns(&|k, p, _| {
                let rest = ctx.marker_rest[k];
                [0, 1, 2].map(|d| p[d] - rest[d])
            }),
        )],
        Candidate::RegistrationEach => {
            let mut t = Vec::new();
            let mut r = Vec::new();
            for axis in 0..3 {
                t.extend(columns(&|_, _, _| {
                    let mut e = [0.0; 3];
                    e[axis] = 1.0;
                    e
                }));
                r.extend(columns(&|_, p, centre| {
                    let v = [0, 1, 2].map(|d| p[d] - centre[d]);
                    // e_axis × v
                    match axis {
                        0 => [0.0, -v[2], v[1]],
                        1 => [v[2], 0.0, -v[0]],
                        _ => [-v[1], v[0], 0.0],
                    }
                }));
            }
            vec![
                ("translation per axis", "m", t),
                ("rotation per axis", "rad", r),
            ]
        }
        _ => Vec::new(),
    }
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
            }],
            note: None,
        };
        assert_eq!(d.describe(), "gravity: density ρ ≥ 412 kg/m³");
    }
}

//! The runs room's fit screen ([`crate::screen`]): one Gauss–Newton evaluation of the fitted
//! runs at the current fit, with every open candidate's material parameters at their neutral
//! values (the current model), from which a continuous candidate's gain is predicted by one step
//! over the current parameters and its own. The other candidates predict themselves
//! ([`super::candidates`]).
//!
//! A damping law is predicted from no viscosity, where a ring-down's decay is far from linear in
//! it: one step from there under-stated the measured beam's damping three times over, below a
//! creep branch standing in for it. Its fit starts from the viscosity the measured ring-downs
//! show, so the screen also linearises the runs there, once a round, and predicts the law by the
//! better of the two steps: one Gauss–Newton step from its fit's own start, where the decay is
//! near linear in the viscosity, gains at least what that start already has.
//!
//! Creep's neutral value g = 0 is no branch at all, whose relaxed fraction has no sensitivity to
//! carry; the evaluation holds it at [`creep::SCREEN_FRACTION`] instead (the runs are the current
//! model's to about that fraction), where dr/dg is the slope at g = 0, and τ at its fit's start.

use palpate_motion::gradient::evaluate_gauss_newton;
use palpate_motion::model::{Material, Model, Observations, Param, ParamKind};
use palpate_motion::MotionError;

use super::candidates::{clamp_compliance, creep, damping, Effect};
use super::fit::{region_params, RunsModel};
use super::RunsFit;
use crate::screen::{self, Normal};
use crate::select::{heldout_delta_bic, Prediction};

/// Where the screen predicts a round's candidates: the current fit and, when a continuous
/// candidate is open, its linearisation.
pub(in crate::runs) struct ScreenPoint<'a> {
    /// The round.
    pub(in crate::runs) round: usize,
    /// The current fit.
    pub(in crate::runs) cur: &'a RunsFit,
    /// Fitted runs.
    pub(in crate::runs) runs: usize,
    /// The current fit's χ² (m²) and its scalar residual count.
    chi2: (f64, usize),
    /// The columns of `normals`: the current parameters (the first `own`: its global kinds, then
    /// its regions' μ), then every open candidate's.
    cols: Vec<Param>,
    /// The current model's parameters.
    own: usize,
    /// Each fitted run's Φ, gradient and Gauss–Newton matrix over `cols` (empty when no open
    /// candidate has a material parameter).
    normals: Vec<Normal>,
    /// With the clamp's give open: the same over `cols` and, last, the clamp layer's μ, the layer
    /// held at the body's moduli (so the current model); `normals` is this with the layer's
    /// column folded into μ's. Empty otherwise.
    layer_normals: Vec<Normal>,
    /// Each fitted run's marker χ² (m²) at the same evaluation.
    run_chi2: Vec<f64>,
    /// Whether the creep branch's relaxed fraction has its slope in `normals` (creep is open and
    /// not yet in the model).
    pub(in crate::runs) creep_slope: bool,
    /// With a damping law open on an undamped model: the fitted runs linearised at the damping
    /// fits' start ([`damping::start_of`]).
    damping_start: Option<DampingStart>,
}

/// The fitted runs linearised at a damping law's start: the current model with the viscosity
/// the measured ring-downs show.
struct DampingStart {
    /// The viscosity (Pa·s) and whence it comes.
    nu: f64,
    source: &'static str,
    /// The columns of `normals`: the current parameters (as [`ScreenPoint`]'s first `own`), then
    /// the viscosity and, with the power law open, its index.
    cols: Vec<Param>,
    /// Each fitted run's Φ, gradient and Gauss–Newton matrix over `cols`.
    normals: Vec<Normal>,
    /// Each fitted run's marker χ² (m²) at the same evaluation.
    run_chi2: Vec<f64>,
}

impl<'a> ScreenPoint<'a> {
    /// Linearises the fitted runs at `cur` over its parameters and those of `open` (at their
    /// neutral values: no viscosity, h = 1, no stiffening, the clamp layer as stiff as the
    /// body), when any of them has one; with a damping law open on an undamped model, also at
    /// its fit's start, side by side.
    pub(in crate::runs) fn new(
        room: &RunsModel,
        round: usize,
        cur: &'a RunsFit,
        open: &[Effect],
    ) -> Result<Self, MotionError> {
        let mut cols = Param::globals(&cur.kinds);
        cols.extend(region_params(&cur.material));
        let own = cols.len();
        for c in open {
            for k in c.kinds() {
                if !cols.contains(&Param::global(*k)) {
                    cols.push(Param::global(*k));
                }
            }
        }
        let mut mat = cur.material.clone();
        for p in &cols[own..] {
            let neutral = match p.kind {
                ParamKind::PowerH => 1.0,
                _ => 0.0,
            };
            mat.set(&[*p], &[neutral]);
        }
        let layer = if open.contains(&Effect::ClampCompliance) {
            clamp_compliance::open_layer(room, &cur.material).ok()
        } else {
            None
        };
        let linearised = open.iter().any(|c| !c.kinds().is_empty()) || layer.is_some();
        let creep_slope = linearised && open.contains(&Effect::Creep) && !cur.material.has_creep();
        if creep_slope {
            mat.set_uniform(ParamKind::CreepFraction, creep::SCREEN_FRACTION);
            mat.set_uniform(ParamKind::CreepTime, creep::start_time(room));
        }
        let mut params = cols.clone();
        if let Some(layer) = layer.clone() {
            // The layer a region of its own at the body's moduli: the same material.
            let r = mat.regions.len();
            let body_mu = mat.body_moduli().1;
            mat.regions.push(layer);
            mat.scaled_regions.push(r);
            mat.set(&[Param::in_region(ParamKind::Mu, r)], &[body_mu]);
            params.push(Param::in_region(ParamKind::Mu, r));
        }
        // The damping laws' start: the current model with the viscosity the ring-downs show,
        // over the current parameters, the viscosity and (the power law open) its index.
        let start = (open.iter().any(|c| c.kinds().contains(&ParamKind::Nu))
            && cur.material.get(ParamKind::Nu, 0) <= 0.0)
            .then(|| {
                let (nu, source) = damping::start_of(room, cur);
                let mut start = cur.material.clone();
                start.set(&[Param::global(ParamKind::Nu)], &[nu]);
                let mut start_cols = cols[..own].to_vec();
                start_cols.push(Param::global(ParamKind::Nu));
                if open.iter().any(|c| c.kinds().contains(&ParamKind::PowerH)) {
                    start_cols.push(Param::global(ParamKind::PowerH));
                }
                (nu, source, start, start_cols)
            });
        let runs = if linearised || start.is_some() {
            room.retimed(&cur.effects, &cur.offsets)?
        } else {
            Vec::new()
        };
        let nu = room.o.poisson;
        let (here, at_start) = rayon::join(
            || {
                linearised
                    .then(|| linearise(&runs, &mat, &params, nu))
                    .transpose()
            },
            || {
                start
                    .as_ref()
                    .map(|(_, _, m, c)| linearise(&runs, m, c, nu))
                    .transpose()
            },
        );
        let (mut normals, run_chi2) = here?.unwrap_or_default();
        let damping_start = match (start, at_start?) {
            (Some((nu, source, _, cols)), Some((normals, run_chi2))) => Some(DampingStart {
                nu,
                source,
                cols,
                normals,
                run_chi2,
            }),
            _ => None,
        };
        room.count(
            runs.len() * (usize::from(linearised) + usize::from(damping_start.is_some())),
            true,
        );
        let mut layer_normals = Vec::new();
        if layer.is_some() {
            // Moving the body's μ and the layer's together is moving the one μ of the current
            // model: the other candidates are predicted over that column.
            let layer_col = cols.len();
            layer_normals = normals;
            normals = layer_normals
                .iter()
                .map(|n| n.tie(0, layer_col, 1.0))
                .collect();
        }
        Ok(Self {
            round,
            cur,
            runs: room.fit.len(),
            chi2: cur.chi2(),
            own,
            cols,
            normals,
            layer_normals,
            run_chi2,
            creep_slope,
            damping_start,
        })
    }

    /// `linear`, the prediction of a damping law that frees `kinds` (`k` parameters), or one
    /// Gauss–Newton step from its fit's start where that gains more ([`better_of`]).
    pub(in crate::runs) fn started(
        &self,
        linear: Prediction,
        kinds: &[ParamKind],
        k: usize,
    ) -> Prediction {
        let Some(s) = &self.damping_start else {
            return linear;
        };
        let mut cols: Vec<usize> = (0..self.own).collect();
        cols.extend(
            kinds
                .iter()
                .filter_map(|k| s.cols.iter().position(|c| *c == Param::global(*k))),
        );
        let delta = screen::step(&s.normals, &cols);
        // A step that takes a modulus, the viscosity or the index to 0 or below leaves the law's
        // domain: the start as simulated is what is known there.
        let inside = cols.iter().zip(&delta).all(|(&c, d)| {
            let from = match s.cols[c].kind {
                ParamKind::Nu if c >= self.own => s.nu,
                ParamKind::PowerH if c >= self.own => 1.0,
                _ => self.cur.material.read(&[s.cols[c]])[0],
            };
            from + d > 0.0
        });
        let (chi2, how) = if inside {
            let change = screen::change(&s.normals, &cols, &delta);
            let chi2 = stepped_chi2(&s.normals, &s.run_chi2, change);
            (chi2, "one Gauss–Newton step from its fit's start")
        } else {
            (s.run_chi2.iter().sum(), "its fit's start simulated")
        };
        better_of(
            linear,
            self.delta_bic(chi2, k),
            &format!("{how}, viscosity {:.3e} Pa·s ({})", s.nu, s.source),
        )
    }

    /// ΔBIC of a candidate with `k` parameters whose fit would reach `chi2` (m²) on the fitted
    /// runs.
    pub(in crate::runs) fn delta_bic(&self, chi2: f64, k: usize) -> f64 {
        let (chi0, n) = self.chi2;
        heldout_delta_bic(chi0, chi2, n, k)
    }

    /// The prediction of a continuous candidate that frees `kinds` (`k` parameters): χ² after one
    /// Gauss–Newton step over the current parameters and `kinds` from their neutral values.
    pub(in crate::runs) fn stepped(&self, kinds: &[ParamKind], k: usize) -> Prediction {
        let how = "one Gauss–Newton step from the neutral value";
        self.stepped_to(kinds, k, how, None).0
    }

    /// [`Self::stepped`], its method told in `how`, and where its step takes the new parameter
    /// `land.0` from `land.1`, its value in the evaluation: `None` where the step holds it there or the screen
    /// has no linearisation. A fit whose own start is an arbitrary small value of its effect can
    /// start where the data point instead.
    pub(in crate::runs) fn stepped_to(
        &self,
        kinds: &[ParamKind],
        k: usize,
        how: &str,
        land: Option<(ParamKind, f64)>,
    ) -> (Prediction, Option<f64>) {
        if kinds.is_empty() || self.normals.is_empty() {
            return (
                Prediction::none("no parameter to linearise: always fitted"),
                None,
            );
        }
        let (cols, delta, held) = self.step_over(kinds);
        let landing = land.and_then(|(kind, neutral)| {
            let a = cols
                .iter()
                .position(|&c| c >= self.own && self.cols[c] == Param::global(kind))?;
            let value = neutral + delta[a];
            (value.is_finite() && value > neutral).then_some(value)
        });
        let how = if held.is_empty() {
            how.to_string()
        } else {
            format!("{how}; {} stepped below 0, held there", held.join(", "))
        };
        if cols.len() == self.own {
            let prediction = Prediction {
                delta_bic: Some(self.delta_bic(self.chi2.0, k)),
                how: screen::held_at_neutral(&how),
            };
            return (prediction, landing);
        }
        let change = screen::change(&self.normals, &cols, &delta);
        let prediction = Prediction {
            delta_bic: Some(self.delta_bic(self.chi2_after(&self.normals, change), k)),
            how,
        };
        (prediction, landing)
    }

    /// One Gauss–Newton step over the current parameters and `kinds` from their neutral values:
    /// the columns stepped, the step over them, and the names of the parameters held at their
    /// neutral values. A viscosity, a stiffening coefficient or a relaxed fraction cannot go
    /// below 0: a step that takes one there is taken again with it held at 0, where the
    /// candidate does best.
    fn step_over(&self, kinds: &[ParamKind]) -> (Vec<usize>, Vec<f64>, Vec<&'static str>) {
        let mut cols: Vec<usize> = (0..self.own).collect();
        cols.extend(
            kinds
                .iter()
                .filter_map(|k| self.cols.iter().position(|j| *j == Param::global(*k)))
                .filter(|&i| i >= self.own),
        );
        let own = self.own;
        let (delta, held) = screen::step_within_bounds(&self.normals, &mut cols, |col| {
            (col >= own).then(|| self.cols[col].kind)
        });
        (cols, delta, held)
    }

    /// The clamp's give (`k` parameters) as one Gauss–Newton step over the current parameters
    /// and the clamp layer's μ from the body's: nothing predicted where the step stiffens the
    /// layer (a refit of the current parameters, which the step also holds, is no gain of a
    /// clamp that gives).
    pub(in crate::runs) fn layer_stepped(&self, k: usize) -> Prediction {
        let Some(n) = self.layer_normals.first().map(Normal::len) else {
            return Prediction::none("no clamp layer to linearise: always fitted");
        };
        let layer = n - 1;
        let mut cols: Vec<usize> = (0..self.own).collect();
        cols.push(layer);
        let delta = screen::step(&self.layer_normals, &cols);
        if delta.last().is_none_or(|d| *d >= 0.0) {
            return Prediction {
                delta_bic: Some(self.delta_bic(self.chi2.0, k)),
                how: "one Gauss–Newton step from the layer at the body's μ stiffens the layer: no \
                      clamp that gives is predicted"
                    .into(),
            };
        }
        let change = screen::change(&self.layer_normals, &cols, &delta);
        Prediction {
            delta_bic: Some(self.delta_bic(self.chi2_after(&self.layer_normals, change), k)),
            how: "one Gauss–Newton step from the layer at the body's μ".into(),
        }
    }

    /// The fitted runs' χ² after a step that changes each run's Φ by `change` (m²).
    fn chi2_after(&self, normals: &[Normal], change: Vec<f64>) -> f64 {
        let stepped = stepped_chi2(normals, &self.run_chi2, change);
        // χ² in proportion to the current fit's, so that an evaluation's own rounding does not
        // count as a gain.
        let sim: f64 = self.run_chi2.iter().sum();
        self.chi2.0 * stepped / sim.max(f64::MIN_POSITIVE)
    }
}

/// The runs' summed marker χ² (m²) after a step that changes each run's Φ by `change`, from
/// their χ² `run_chi2` at the evaluation of `normals`.
fn stepped_chi2(normals: &[Normal], run_chi2: &[f64], change: Vec<f64>) -> f64 {
    // Each run's χ² and its Φ in proportion (the marker term's weight is the run's).
    normals
        .iter()
        .zip(run_chi2)
        .zip(change)
        .map(|((n, chi2), d)| {
            let scale = if n.phi > 0.0 { chi2 / n.phi } else { 0.0 };
            (chi2 + scale * d).max(0.0)
        })
        .sum()
}

/// Each run of `runs` linearised under `mat` over `params`, λ tied to μ (the first) at the held
/// Poisson's ratio `nu` (λ's column appended and folded into μ's): its Φ, gradient and
/// Gauss–Newton matrix over `params`, and its marker χ² (m²).
fn linearise(
    runs: &[(Model, Observations)],
    mat: &Material,
    params: &[Param],
    nu: f64,
) -> Result<(Vec<Normal>, Vec<f64>), MotionError> {
    let mut params = params.to_vec();
    params.push(Param::global(ParamKind::Lambda));
    let lambda_col = params.len() - 1;
    let ratio = 2.0 * nu / (1.0 - 2.0 * nu);
    use rayon::prelude::*;
    let parts: Vec<(Normal, f64)> = runs
        .par_iter()
        .map(|(m, obs)| {
            let (ev, gn) = evaluate_gauss_newton(m, mat, &params, obs)?;
            let chi2 = ev.rms_marker * ev.rms_marker * ev.marker_count as f64;
            let all = Normal {
                phi: ev.phi,
                grad: ev.grad.unwrap_or_default(),
                gn,
            };
            Ok((all.tie(0, lambda_col, ratio), chi2))
        })
        .collect::<Result<_, MotionError>>()?;
    Ok(parts.into_iter().unzip())
}

/// `linear`, a candidate's predicted ΔBIC, or `from_start`, the ΔBIC predicted from its fit's
/// start (`start` says how), where that is lower: the fit starts there and only goes down.
fn better_of(linear: Prediction, from_start: f64, start: &str) -> Prediction {
    match linear.delta_bic {
        Some(d) if d <= from_start => linear,
        d => Prediction {
            delta_bic: Some(from_start),
            how: format!(
                "{start}; one Gauss–Newton step from none predicted {:.1}",
                d.unwrap_or(f64::NAN)
            ),
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn step(d: Option<f64>) -> Prediction {
        Prediction {
            delta_bic: d,
            how: "one Gauss–Newton step from the neutral value".into(),
        }
    }

    /// The start replaces the step's prediction only where it gains more, and says both.
    #[test]
    fn a_damping_law_is_predicted_by_the_better_of_its_step_and_its_start() {
        let p = better_of(
            step(Some(-16692.1)),
            -23514.4,
            "its fit's start simulated, viscosity 1.733e2 Pa·s (given)",
        );
        assert_eq!(p.delta_bic, Some(-23514.4));
        assert_eq!(
            p.how,
            "its fit's start simulated, viscosity 1.733e2 Pa·s (given); one Gauss–Newton step \
             from none predicted -16692.1"
        );
        let q = better_of(
            step(Some(-4837.3)),
            -1194.7,
            "its fit's start simulated, viscosity 2.000e1 Pa·s (given)",
        );
        assert_eq!(q.delta_bic, Some(-4837.3));
        assert!(q.how.starts_with("one Gauss–Newton step"), "{}", q.how);
        let r = better_of(step(None), -50.0, "its fit's start simulated");
        assert_eq!(r.delta_bic, Some(-50.0));
    }
}

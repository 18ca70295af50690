//! The scan room's side of the selection engine ([`CandidateModel`]): a candidate fitted on top
//! of the current model, scored on the fitted points, predicted on the held-out ones, gated.

use palpate_scan::regions::search_regions;

use super::fit::{Evidence, Problem, ScanModel};
use super::{Effect, RoundRecord, ScanOptions, Tried, MIN_RATIO};
use crate::select::CandidateEffect as _;
use crate::select::{
    heldout_delta_bic, Candidate, CandidateModel, Current, Gate, GateDetail, HeldoutGate, Outcome,
    PassWords, Score, Verdict,
};
use crate::Error;

/// What the verdict keeps of a fitted candidate.
#[derive(Debug, Clone)]
pub struct Fitted {
    young_pa: Vec<f64>,
    bias_m: Option<f64>,
    scale: Option<f64>,
    largest_move_m: Option<f64>,
    split: Option<(String, f64)>,
    ratio: f64,
}

pub(super) struct ScanRoom<'p, 'a> {
    problem: &'p Problem<'a>,
    library: Vec<Effect>,
    gate: HeldoutGate,
    /// The mesh's error measured again at each adoption that changes the field: the effect, the
    /// RMS at the points and their noise (m).
    pub(super) remeasured: Vec<(Effect, f64, f64)>,
}

impl<'p, 'a> ScanRoom<'p, 'a> {
    pub(super) fn new(problem: &'p Problem<'a>, options: &ScanOptions) -> Self {
        let library = if options.candidates.is_empty() {
            <Effect as crate::select::CandidateEffect>::library()
        } else {
            options.candidates.clone()
        };
        Self {
            problem,
            library,
            gate: HeldoutGate {
                bic_threshold: options.bic_threshold,
                min_holdout_gain: options.min_holdout_gain,
            },
            remeasured: Vec::new(),
        }
    }
}

impl CandidateModel for ScanRoom<'_, '_> {
    type Candidate = Effect;
    type Fitted = ScanModel;
    type Held = Evidence;
    type Observed = ();
    type Summary = Fitted;
    type Detail = GateDetail;
    type Adoption = ();
    type Error = Error;

    fn observe(&mut self, _round: usize, _fitted: &ScanModel, _held: &Evidence) {}

    fn candidates(&mut self, current: &ScanModel, _adopted: &[Effect]) -> Vec<Effect> {
        self.library
            .iter()
            .copied()
            .filter(|e| !current.effects.contains(e))
            .collect()
    }

    fn fit_with(
        &mut self,
        _round: usize,
        current: &ScanModel,
        candidate: Effect,
    ) -> Result<Outcome<ScanModel>, Error> {
        let p = self.problem;
        if let Some(why) = p.not_identifiable(candidate) {
            return Ok(Outcome::NotFitted(why));
        }
        let mut effects = current.effects.clone();
        effects.push(candidate);
        let fitted = match candidate {
            Effect::SecondMaterial => {
                let states = p.states_with(None, &current.nuisance);
                let search = search_regions(&states, &current.fit, &p.settings)?;
                let Some(best) = search.best else {
                    return Ok(Outcome::NotFitted(
                        "no split of the object into two parts could be fitted".into(),
                    ));
                };
                p.fit(
                    &effects,
                    Some(&best.split),
                    Some((&ln_mu_of(&best.fit.mu), &current.nuisance)),
                )
            }
            _ => p.fit(
                &effects,
                current.split.as_ref(),
                Some((&ln_mu_of(&current.fit.mu), &current.nuisance)),
            ),
        };
        Ok(match fitted {
            Ok(m) => Outcome::Fitted(m),
            Err(e) => Outcome::NotFitted(format!("no fit: {e}")),
        })
    }

    fn score(&self, fitted: &ScanModel) -> Score {
        Score {
            chi2: fitted.score.chi2,
            n: fitted.score.n,
            k: self.problem.parameters(fitted),
        }
    }

    fn summarise(&self, f: &ScanModel) -> Fitted {
        let nodes: Vec<nalgebra::Vector3<f64>> = self
            .problem
            .dataset
            .mesh
            .nodes
            .iter()
            .map(|p| nalgebra::Vector3::from(*p))
            .collect();
        Fitted {
            young_pa: (0..f.fit.mu.len())
                .map(|k| f.fit.young_modulus(k))
                .collect(),
            bias_m: f
                .effects
                .contains(&Effect::DepthBias)
                .then_some(f.nuisance.bias_m),
            scale: f
                .effects
                .contains(&Effect::DepthScale)
                .then_some(f.nuisance.scale),
            largest_move_m: f.effects.contains(&Effect::CameraMoved).then(|| {
                f.nuisance
                    .rigid
                    .iter()
                    .map(|r| r.largest_move(&nodes))
                    .fold(0.0, f64::max)
            }),
            split: f
                .split
                .as_ref()
                .map(|s| (s.label.clone(), f.fit.mu[1] / f.fit.mu[0])),
            ratio: f.score.ratio(),
        }
    }

    fn heldout(
        &mut self,
        _round: usize,
        _candidate: Effect,
        fitted: &ScanModel,
    ) -> Result<Evidence, Error> {
        Ok(self.problem.held_out(fitted))
    }

    fn gate(&mut self, current: &Current<'_, Self>, c: &Candidate<'_, Self>) -> Gate<GateDetail> {
        let extra = self.problem.parameters(c.fitted) - self.problem.parameters(current.fitted);
        let held_dbic = heldout_delta_bic(current.held.chi2, c.held.chi2, c.held.n, extra);
        let gain = c.held.scaled_rms() / current.held.scaled_rms() - 1.0;
        let (mut passes, mut detail) =
            self.gate
                .judge(c.delta_bic, held_dbic, gain, PassWords::WithThresholds);
        if let Some(why) = implausible(self.problem, c.fitted) {
            passes = false;
            detail.reason = format!("fails: implausible, {why}; {}", detail.reason);
        }
        if c.candidate == Effect::SecondMaterial {
            let ratio = c.fitted.fit.mu[1] / c.fitted.fit.mu[0];
            if ratio.ln().abs() <= MIN_RATIO.ln() {
                passes = false;
                detail.reason = format!(
                    "fails: the two moduli are {ratio:.3}× apart, not more than {MIN_RATIO}× (a \
                     mesh's own error fits as a few per cent of stiffness){}",
                    detail
                        .reason
                        .strip_prefix("fails")
                        .or_else(|| detail.reason.strip_prefix("passes"))
                        .map(|r| format!("; gate{r}"))
                        .unwrap_or_default()
                );
            }
        }
        Gate {
            passes,
            heldout_delta_bic: held_dbic,
            heldout_rank: c.held.chi2,
            detail,
        }
    }

    /// A second material changes the object's field, and with it the mesh's error: the
    /// correction is measured again at the adopted model and the model refitted under it (the
    /// nuisances only move the scans, and leave it).
    fn adopt(
        &mut self,
        _current: &Current<'_, Self>,
        candidate: Effect,
        fitted: ScanModel,
        held: Evidence,
    ) -> Result<(ScanModel, Evidence, ()), Error> {
        let p = self.problem;
        if candidate != Effect::SecondMaterial || p.correction.borrow().is_none() {
            return Ok((fitted, held, ()));
        }
        let e = p.mesh_error(&fitted)?;
        log::info!(
            "mesh error measured again with {}: {:.4} mm RMS at the points ({:.2}× their noise)",
            candidate.label(),
            1e3 * e.rms_m,
            e.rms_m / e.noise_m
        );
        self.remeasured.push((candidate, e.rms_m, e.noise_m));
        *p.correction.borrow_mut() = Some(e.offsets);
        let refit = p.fit(
            &fitted.effects,
            fitted.split.as_ref(),
            Some((&ln_mu_of(&fitted.fit.mu), &fitted.nuisance)),
        )?;
        let held = p.held_out(&refit);
        Ok((refit, held, ()))
    }
}

/// A depth camera's scale error beyond this (relative) is outside any sensor's calibration: a
/// fit that wants it has traded it against the scans' turns.
pub const MAX_DEPTH_SCALE: f64 = 0.02;
/// A depth bias beyond this (m) likewise.
pub const MAX_DEPTH_BIAS_M: f64 = 5e-3;
/// A scan turned further than this (degrees) from its declared pose has paired the wrong faces
/// (the registration's own limit).
pub const MAX_TURN_DEG: f64 = 10.0;

/// Why a fitted model's nuisances are not a camera's, if they are not: a scale or bias of depth
/// beyond a sensor's calibration, a scan turned by more than [`MAX_TURN_DEG`].
fn implausible(p: &Problem<'_>, m: &ScanModel) -> Option<String> {
    let n = &m.nuisance;
    if m.effects.contains(&Effect::DepthScale) && n.scale.abs() > MAX_DEPTH_SCALE {
        return Some(format!(
            "a depth scale error of {:+.2} % (beyond ±{:.0} %)",
            100.0 * n.scale,
            100.0 * MAX_DEPTH_SCALE
        ));
    }
    if m.effects.contains(&Effect::DepthBias) && n.bias_m.abs() > MAX_DEPTH_BIAS_M {
        return Some(format!(
            "a depth bias of {:.2} mm (beyond ±{:.0} mm)",
            1e3 * n.bias_m,
            1e3 * MAX_DEPTH_BIAS_M
        ));
    }
    if m.effects.contains(&Effect::CameraMoved) {
        for (r, s) in n.rigid.iter().zip(&p.states) {
            if r.angle_deg() > MAX_TURN_DEG {
                return Some(format!(
                    "the scan of {:?} turned {:.1}° (beyond {MAX_TURN_DEG}°)",
                    s.name,
                    r.angle_deg()
                ));
            }
        }
    }
    None
}

fn ln_mu_of(mu: &[f64]) -> Vec<f64> {
    mu.iter().map(|m| m.ln()).collect()
}

/// The verdict's rounds as the report keeps them.
pub(super) fn records(verdict: &Verdict<ScanRoom<'_, '_>>) -> Vec<RoundRecord> {
    verdict
        .rounds
        .iter()
        .map(|r| {
            let adopted_dbic = r.adopted_attempt().map(|a| a.delta_bic);
            RoundRecord {
                round: r.round,
                model: r.model.clone(),
                tried: r
                    .attempts
                    .iter()
                    .enumerate()
                    .map(|(i, a)| {
                        let s = a.summary.as_ref();
                        Tried {
                            effect: a.candidate,
                            not_fitted: a.not_fitted.clone(),
                            delta_bic: a.delta_bic.is_finite().then_some(a.delta_bic),
                            young_pa: s.map(|s| s.young_pa.clone()).unwrap_or_default(),
                            bias_m: s.and_then(|s| s.bias_m),
                            scale: s.and_then(|s| s.scale),
                            largest_move_m: s.and_then(|s| s.largest_move_m),
                            split: s.and_then(|s| s.split.clone()),
                            fitted_ratio: s.map(|s| s.ratio),
                            heldout_ratio: a.held.map(|h| h.ratio()),
                            gate: a.gate.as_ref().map(|g| g.detail.clone()),
                            adopted: r.adopted == Some(i),
                            not_told_apart: r.adopted != Some(i)
                                && a.gate.as_ref().is_some_and(|g| g.passes)
                                && adopted_dbic
                                    .is_some_and(|b| (a.delta_bic - b).abs() < super::TOLD_APART),
                        }
                    })
                    .collect(),
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use palpate_scan::dataset::ScanDataset;
    use palpate_scan::fit::Design;
    use palpate_scan::synthetic::{write_strip_dataset, StripCase};

    /// A fitted model whose depth scale, bias or turn lies beyond a camera's is refused, saying
    /// which and by how much; within the limits it is not.
    #[test]
    fn nuisances_beyond_a_cameras_are_implausible() {
        let tmp = tempfile::tempdir().unwrap();
        let case = StripCase {
            cells: [4, 1, 1],
            design: Design::Linear,
            ..StripCase::default()
        };
        write_strip_dataset(tmp.path(), &case).unwrap();
        let ds = ScanDataset::read(tmp.path()).unwrap();
        let p = Problem::new(&ds, Design::Linear, &[300e3], 10).unwrap();
        let mut m = p.fit(&[], None, None).unwrap();
        m.effects = vec![Effect::DepthScale, Effect::DepthBias, Effect::CameraMoved];
        m.nuisance.scale = 0.019;
        m.nuisance.bias_m = 0.004;
        assert_eq!(implausible(&p, &m), None);
        m.nuisance.scale = 0.05;
        let why = implausible(&p, &m).unwrap();
        assert!(why.contains("+5.00 %"), "{why}");
        m.nuisance.scale = 0.0;
        m.nuisance.bias_m = -0.008;
        assert!(implausible(&p, &m).unwrap().contains("-8.00 mm"));
        m.nuisance.bias_m = 0.0;
        m.nuisance.rigid[1] = palpate_scan::registration::RigidTransform::about(
            nalgebra::Vector3::z(),
            12f64.to_radians(),
            nalgebra::Vector3::zeros(),
            nalgebra::Vector3::zeros(),
        );
        let why = implausible(&p, &m).unwrap();
        assert!(why.contains("\"twisted\" turned 12.0°"), "{why}");
    }
}

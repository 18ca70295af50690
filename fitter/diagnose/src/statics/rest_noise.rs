//! Noise in the rest scan: the markers' declared rest positions are a measurement too.
//!
//! Every simulated marker starts from its declared rest position, so an error e_k in that position
//! appears in marker k's residual in *every* measurement: r_ik = s_ik + e_k + n_ik, with s the
//! model's error (smooth over the object), n_ik the measurement's own noise (σ per axis,
//! independent) and e_k the rest scan's (τ per axis, independent between markers). The declared
//! floor σ√3 knows nothing of e_k, so a model that is right leaves a residual τ²/σ² above it —
//! 10 % in χ² for a rest scan averaged over ten frames — and an honest χ² test calls that
//! "unexplained" although no effect of the object is missing.
//!
//! What tells e_k from a model error is its structure: the same in every measurement (the
//! per-marker mean r̄_k holds it in full, and n̄_k only with variance σ²/m_k) and white from marker
//! to marker (a model error of the object is smooth). So the persistent field r̄_k goes through
//! the same local-nugget estimator as [`super::noise`]: at each marker, the affine extrapolation
//! from its neighbours' r̄_j cancels any locally linear s and leaves
//! d_k = r̄_k − Σ_j c_j r̄_j with E|d_k|² = 3 [σ² (1/m_k + Σ_j c_j²/m_j) + τ² (1 + Σ_j c_j²)].
//! τ̂² solves median_k |d_k|² / (3 (a_k + τ² b_k)) = median(χ²₃)/3 (0 when already below at τ = 0).
//!
//! The σ of a_k is the larger of the declared one and the within-marker nugget estimate σ̂_w —
//! the same estimator on r_ik − r̄_k, from which e_k cancels exactly, with
//! E|d|² = 3σ² [(1 − 1/m_k) + Σ_j c_j² (1 − 1/m_j)] — so a measurement noise a little above its
//! declared level is not read as a noisy rest scan.
//!
//! Decision: the median statistic at τ = 0 against its null distribution (a parametric simulation
//! of the persistent noise through the same extrapolation weights: the d_k of neighbouring markers
//! are correlated, so no textbook standard error applies); fired when it sits
//! [`RestNoiseOptions::z_limit`] standard deviations above the null and τ̂ ≥
//! [`RestNoiseOptions::margin`] σ (a smaller τ changes the floor by under half a percent).
//! Nothing in the model changes: the final residual is then judged under the covariance
//! σ² I + τ̂² 11ᵀ of each marker's residuals over its measurements
//! ([`super::ResidualCheck::with_rest_noise`]).

use serde::Serialize;

use crate::statics::noise::{
    extrapolation_weights, marker_spacing, median_over_gaussian, percentile, NoiseOptions,
};
use palpate_fem::rng::study_stream as rng;

/// Options of [`estimate_rest_noise`].
#[derive(Debug, Clone, Serialize)]
pub struct RestNoiseOptions {
    /// Standard deviations of the null distribution the statistic must exceed.
    pub z_limit: f64,
    /// Practical margin: fire only if τ̂ ≥ margin · σ.
    pub margin: f64,
    /// Parametric simulations for the null distribution and for the interval of τ̂.
    pub simulations: usize,
    /// Seed of the simulations (the estimate is deterministic).
    pub seed: u64,
    /// Neighbours farther than this many marker spacings are left out (wider than the
    /// per-measurement nugget's: the persistent field is smoother than one measurement's, and
    /// scattered layouts leave many markers without four neighbours within 2.5 spacings).
    pub max_lag: f64,
}

impl Default for RestNoiseOptions {
    fn default() -> Self {
        Self {
            z_limit: 3.0,
            margin: 0.1,
            simulations: 400,
            seed: 11,
            max_lag: 4.0,
        }
    }
}

/// The rest-scan finding of a diagnosis.
#[derive(Debug, Clone, Serialize)]
pub struct RestNoiseFinding {
    /// Estimated white noise τ̂ per axis of the declared rest positions (m).
    pub estimate: f64,
    /// Two-sided 95 % interval of τ̂ (m), parametric simulation at τ̂.
    pub interval: (f64, f64),
    /// The statistic at τ = 0 in standard deviations of its null distribution.
    pub z: f64,
    /// The measurement noise σ the null assumes (m): the declared σ or σ̂_w, the larger.
    pub sigma_null: f64,
    /// The within-marker nugget estimate σ̂_w of the measurements' own noise (m), if any.
    pub sigma_within: Option<f64>,
    /// Whether the rest scan's noise is significant (and large enough to matter).
    pub fired: bool,
    /// Markers whose persistent residual had a neighbourhood.
    pub markers: usize,
    /// Mean number of measurements a marker was seen in.
    pub mean_seen: f64,
    /// The smallest τ (m) this test would have fired on: where the statistic's expected rise,
    /// ≈ τ² median(b_k/a_k)/σ², reaches the null's mean plus [`RestNoiseOptions::z_limit`] of its
    /// standard deviations (and at least the margin) — the power statement of a test that did not
    /// fire.
    pub detectable: f64,
    /// The finding (or why not) in words.
    pub statement: String,
    /// Per marker seen: (measurements it was seen in, |mean residual| in m) — the evidence
    /// plot's points.
    #[serde(skip)]
    pub points: Vec<(f64, f64)>,
}

/// One persistent term: the extrapolation error d_k and its variance factors a_k (per σ²) and
/// b_k (per τ²).
struct Term {
    d2: f64,
    a: f64,
    b: f64,
}

/// median(|d|² / (3 (σ² a + τ² b))) over the Gaussian median, for σ² and τ².
fn statistic(terms: &[Term], sigma2: f64, tau2: f64) -> f64 {
    median_over_gaussian(
        terms
            .iter()
            .map(|t| t.d2 / (3.0 * (sigma2 * t.a + tau2 * t.b)))
            .collect(),
    )
}

/// τ̂² with statistic(σ², τ̂²) = 1, or 0 when the statistic is ≤ 1 without rest noise.
fn solve_tau2(terms: &[Term], sigma2: f64) -> f64 {
    if statistic(terms, sigma2, 0.0) <= 1.0 {
        return 0.0;
    }
    let mut hi = sigma2.max(f64::MIN_POSITIVE);
    while statistic(terms, sigma2, hi) > 1.0 && hi < 1e6 * sigma2 {
        hi *= 2.0;
    }
    let mut lo = 0.0;
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if statistic(terms, sigma2, mid) > 1.0 {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// Extrapolation errors of `values` through `weights` (per marker: its weights or none).
fn errors(values: &[[f64; 3]], weights: &[Option<Vec<(usize, f64)>>]) -> Vec<(usize, f64)> {
    weights
        .iter()
        .enumerate()
        .filter_map(|(k, w)| {
            let w = w.as_ref()?;
            let d2 = (0..3)
                .map(|d| {
                    (values[k][d] - w.iter().map(|&(j, c)| c * values[j][d]).sum::<f64>()).powi(2)
                })
                .sum();
            Some((k, d2))
        })
        .collect()
}

/// Tests the declared rest positions `rest` (per marker) for noise of their own from the final
/// `residuals` (per measurement: (marker, simulated − measured position) in m) and the
/// measurements' declared noise `sigma`. `None` when fewer than 20 markers were seen twice or
/// have a neighbourhood (too few for a median to say anything).
pub fn estimate_rest_noise(
    rest: &[[f64; 3]],
    residuals: &[Vec<(usize, [f64; 3])>],
    sigma: f64,
    noise: &NoiseOptions,
    o: &RestNoiseOptions,
) -> Option<RestNoiseFinding> {
    let noise = &NoiseOptions {
        max_lag: o.max_lag,
        ..noise.clone()
    };
    let nm = rest.len();
    let (seen, sum) = marker_sums(residuals, nm);
    // The persistent field over the markers seen at least once (local index → marker).
    let used: Vec<usize> = (0..nm).filter(|&k| seen[k] > 0).collect();
    if used.iter().filter(|&&k| seen[k] >= 2).count() < 20 {
        return None;
    }
    let points: Vec<[f64; 3]> = used.iter().map(|&k| rest[k]).collect();
    let inv_m: Vec<f64> = used.iter().map(|&k| 1.0 / seen[k] as f64).collect();
    let mean: Vec<[f64; 3]> = used
        .iter()
        .map(|&k| sum[k].map(|v| v / seen[k] as f64))
        .collect();
    let spacing = marker_spacing(std::iter::once(points.as_slice()))?;
    let weights: Vec<Option<Vec<(usize, f64)>>> = (0..points.len())
        .map(|i| extrapolation_weights(&points, i, spacing, noise))
        .collect();

    let sigma_within = within_sigma(residuals, &seen, (&used, &points, &mean), spacing, noise);
    let sigma_null = sigma_within.map_or(sigma, |s| s.max(sigma));
    let s2 = sigma_null * sigma_null;

    let factors = term_factors(&weights, &inv_m);
    let terms_of = |values: &[[f64; 3]]| -> Vec<Term> {
        errors(values, &weights)
            .into_iter()
            .map(|(i, d2)| {
                let (a, b) = factors[i].expect("errors only where weights exist");
                Term { d2, a, b }
            })
            .collect()
    };
    let terms = terms_of(&mean);
    if terms.len() < 20 {
        return None;
    }
    let t0 = statistic(&terms, s2, 0.0);
    let tau2 = solve_tau2(&terms, s2);

    let (null, at) = simulations(&inv_m, s2, tau2, &terms_of, o);
    let n = null.len().max(2) as f64;
    let null_mean = null.iter().sum::<f64>() / n;
    let null_sd = (null.iter().map(|v| (v - null_mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    let z = (t0 - null_mean) / null_sd;
    let estimate = tau2.sqrt();
    let interval = if at.len() >= 20 {
        (percentile(&at, 0.025), percentile(&at, 0.975))
    } else {
        (estimate, estimate)
    };
    let fired = z >= o.z_limit && estimate >= o.margin * sigma;
    let mut gain: Vec<f64> = terms.iter().map(|t| t.b / t.a).collect();
    gain.sort_by(f64::total_cmp);
    let rise = (null_mean - 1.0).max(0.0) + o.z_limit * null_sd;
    let detectable = (s2 * rise / gain[gain.len() / 2])
        .sqrt()
        .max(o.margin * sigma);
    let mean_seen = used.iter().map(|&k| seen[k] as f64).sum::<f64>() / used.len() as f64;
    let mut finding = RestNoiseFinding {
        estimate,
        interval,
        z,
        sigma_null,
        sigma_within,
        fired,
        markers: terms.len(),
        mean_seen,
        detectable,
        statement: String::new(),
        points: used
            .iter()
            .zip(&mean)
            .map(|(&k, r)| (seen[k] as f64, r.iter().map(|v| v * v).sum::<f64>().sqrt()))
            .collect(),
    };
    finding.statement = statement(&finding, sigma, o);
    Some(finding)
}

/// How often each of `nm` markers was seen in `residuals`, and the sum of its residuals.
fn marker_sums(residuals: &[Vec<(usize, [f64; 3])>], nm: usize) -> (Vec<usize>, Vec<[f64; 3]>) {
    let mut seen = vec![0usize; nm];
    let mut sum = vec![[0.0f64; 3]; nm];
    for r in residuals {
        for &(k, e) in r {
            seen[k] += 1;
            for d in 0..3 {
                sum[k][d] += e[d];
            }
        }
    }
    (seen, sum)
}

/// Each marker's variance factors (a, b) of its nugget term, E|d|² = 3 (a σ² + b τ²), from its
/// extrapolation `weights` and the 1/m_k of the markers `inv_m` (`None` without weights).
fn term_factors(weights: &[Option<Vec<(usize, f64)>>], inv_m: &[f64]) -> Vec<Option<(f64, f64)>> {
    weights
        .iter()
        .enumerate()
        .map(|(i, w)| {
            w.as_ref().map(|w| {
                let a = inv_m[i] + w.iter().map(|&(j, c)| c * c * inv_m[j]).sum::<f64>();
                let b = 1.0 + w.iter().map(|&(_, c)| c * c).sum::<f64>();
                (a, b)
            })
        })
        .collect()
}

/// The measurements' own σ from the within-marker deviations (the rest error cancels): the
/// markers seen at least twice (`seen` per marker; `used` the seen markers, their `points` and
/// `mean` residuals by local index). `None` with fewer than 20 terms.
fn within_sigma(
    residuals: &[Vec<(usize, [f64; 3])>],
    seen: &[usize],
    (used, points, mean): (&[usize], &[[f64; 3]], &[[f64; 3]]),
    spacing: f64,
    noise: &NoiseOptions,
) -> Option<f64> {
    let nm = seen.len();
    let inv_m: Vec<f64> = used.iter().map(|&k| 1.0 / seen[k] as f64).collect();
    let mut local = vec![usize::MAX; nm];
    for (i, &k) in used.iter().enumerate() {
        local[k] = i;
    }
    let mut within: Vec<Term> = Vec::new();
    for r in residuals {
        let members: Vec<(usize, [f64; 3])> = r
            .iter()
            .filter(|&&(k, _)| seen[k] >= 2)
            .map(|&(k, e)| {
                let i = local[k];
                (i, [0, 1, 2].map(|d| e[d] - mean[i][d]))
            })
            .collect();
        let pts: Vec<[f64; 3]> = members.iter().map(|&(i, _)| points[i]).collect();
        let vals: Vec<[f64; 3]> = members.iter().map(|&(_, w)| w).collect();
        let ws: Vec<Option<Vec<(usize, f64)>>> = (0..pts.len())
            .map(|j| extrapolation_weights(&pts, j, spacing, noise))
            .collect();
        for (j, d2) in errors(&vals, &ws) {
            let g = |q: usize| 1.0 - inv_m[members[q].0];
            let w = ws[j].as_ref().expect("errors only where weights exist");
            let a = g(j) + w.iter().map(|&(q, c)| c * c * g(q)).sum::<f64>();
            within.push(Term { d2, a, b: 0.0 });
        }
    }
    (within.len() >= 20).then(|| statistic(&within, 1.0, 0.0).sqrt())
}

/// Parametric simulations of the statistic: under the null (persistent noise σ²/m_k only, `s2`
/// σ², `inv_m` the 1/m_k) and the τ̂ of draws at `tau2` (for its interval, sorted).
fn simulations(
    inv_m: &[f64],
    s2: f64,
    tau2: f64,
    terms_of: &dyn Fn(&[[f64; 3]]) -> Vec<Term>,
    o: &RestNoiseOptions,
) -> (Vec<f64>, Vec<f64>) {
    let mut rng = rng(o.seed);
    let mut draw = |tau2: f64| -> Vec<[f64; 3]> {
        inv_m
            .iter()
            .map(|&f| {
                let sd = (s2 * f + tau2).sqrt();
                [0; 3].map(|_| sd * rng.normal())
            })
            .collect()
    };
    let null: Vec<f64> = (0..o.simulations)
        .map(|_| statistic(&terms_of(&draw(0.0)), s2, 0.0))
        .collect();
    let mut at: Vec<f64> = (0..o.simulations)
        .map(|_| solve_tau2(&terms_of(&draw(tau2)), s2).sqrt())
        .collect();
    at.sort_by(f64::total_cmp);
    (null, at)
}

/// The finding in words (`sigma` the declared marker noise).
fn statement(f: &RestNoiseFinding, sigma: f64, o: &RestNoiseOptions) -> String {
    let (estimate, interval, z, sigma_null) = (f.estimate, f.interval, f.z, f.sigma_null);
    let (mean_seen, detectable) = (f.mean_seen, f.detectable);
    let um = |v: f64| 1e6 * v;
    let within_words = match f.sigma_within {
        Some(s) => format!("{:.1} µm from the within-marker deviations", um(s)),
        None => "too few repeated markers for a within-marker estimate".into(),
    };
    if f.fired {
        format!(
            "the rest scan carries noise of its own: the part of each marker's residual that is the same in every measurement is white from marker to marker with τ̂ = {:.1} µm per axis (95 % interval {:.1}–{:.1} µm; {z:.1} standard deviations above what the measurements' own noise σ = {:.1} µm leaves in a mean over {mean_seen:.1} measurements; σ: declared {:.1} µm, {within_words}). The model is unchanged; the final residual is judged with that error in every marker's rest position",
            um(estimate), um(interval.0), um(interval.1), um(sigma_null), um(sigma)
        )
    } else {
        format!(
            "rest positions consistent with a noise-free rest scan: τ̂ = {:.1} µm per axis (95 % interval {:.1}–{:.1} µm), the persistent per-marker residual {z:+.1} standard deviations from what the measurements' own noise σ = {:.1} µm leaves (fired at ≥ {:.1} and τ̂ ≥ {:.2} σ; σ: declared {:.1} µm, {within_words}); a rest scan noisier than about {:.1} µm per axis would have been found",
            um(estimate), um(interval.0), um(interval.1), um(sigma_null), o.z_limit, o.margin, um(sigma), um(detectable)
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::statics::noise::tests::layout;

    /// Eight measurements of residuals: a bump of `bump` m under a moving contact (the model error
    /// a probe leaves, different in every measurement), a persistent smooth field of `smooth` m (a
    /// model error the same in every measurement: a slow tilt and a wide bump), measurement noise
    /// `sigma` and rest-scan noise `tau` per axis; each marker seen with probability 0.8.
    fn residuals(
        sigma: f64,
        tau: f64,
        bump: f64,
        smooth: f64,
        seed: u64,
    ) -> Vec<Vec<(usize, [f64; 3])>> {
        let pts = layout();
        let mut rng = rng(seed);
        let rest: Vec<[f64; 3]> = pts
            .iter()
            .map(|_| [0; 3].map(|_| tau * rng.normal()))
            .collect();
        (0..8)
            .map(|i| {
                let c = [0.02 + 0.005 * i as f64, 0.06 - 0.004 * i as f64, 0.04];
                let mut seen = Vec::new();
                for (k, &p) in pts.iter().enumerate() {
                    if rng.uniform() >= 0.8 {
                        continue;
                    }
                    let g = (-0.5 * crate::statics::noise::dist2(p, c) / 0.03f64.powi(2)).exp();
                    let w = (-0.5 * crate::statics::noise::dist2(p, [0.04, 0.04, 0.04])
                        / 0.05f64.powi(2))
                    .exp();
                    let r = [0, 1, 2].map(|d| {
                        bump * g * [0.3, -0.2, 1.0][d]
                            + smooth * (w + 5.0 * (p[0] - 0.04)) * [1.0, 0.5, -0.7][d]
                            + rest[k][d]
                            + sigma * rng.normal()
                    });
                    seen.push((k, r));
                }
                seen
            })
            .collect()
    }

    fn find(sigma_true: f64, tau: f64, smooth: f64, seed: u64) -> RestNoiseFinding {
        estimate_rest_noise(
            &layout(),
            &residuals(sigma_true, tau, 3e-4, smooth, seed),
            1e-4,
            &NoiseOptions::default(),
            &RestNoiseOptions::default(),
        )
        .expect("104 markers in 8 measurements")
    }

    #[test]
    fn rest_noise_is_found_and_measured() {
        // τ = 0.5 σ (a rest scan of four frames): 104 markers seen ≈ 6.3 times each. Measured
        // τ̂ 51–56 µm, z 11–15 on these seeds; 30 % is ≥ 1.5 interval half-widths.
        for seed in [1, 2, 3] {
            let f = find(1e-4, 5e-5, 0.0, seed);
            assert!(f.fired, "{}", f.statement);
            assert!((f.estimate / 5e-5 - 1.0).abs() < 0.3, "{}", f.statement);
            assert!(
                f.interval.0 < 5e-5 && 5e-5 < f.interval.1,
                "{}",
                f.statement
            );
        }
    }

    #[test]
    fn no_rest_noise_is_not_fired() {
        // Nothing in the rest scan; the measurements' noise declared right, declared 15 % low
        // (below the `noise` test's margin), or under a persistent smooth model error of 3 σ:
        // none of these is the rest scan's, and none may widen the floor. Measured z +0.4, +0.8,
        // −1.0 (σ̂_w 117 µm is what the null assumes), +1.7.
        for (sigma, smooth, seed) in [
            (1e-4, 0.0, 4),
            (1e-4, 0.0, 5),
            (1.15e-4, 0.0, 6),
            (1e-4, 3e-4, 7),
        ] {
            let f = find(sigma, 0.0, smooth, seed);
            assert!(!f.fired, "σ {sigma}, smooth {smooth}: {}", f.statement);
        }
    }

    /// The power statement is where the test starts firing: on the same layout and noise, a rest
    /// scan at 1.5× the stated detectable τ is found, one at half of it is not (stated 24.2 and
    /// 24.7 µm on these seeds, σ = 100 µm, 104 markers seen ≈ 6.4 times).
    #[test]
    fn detectable_tau_is_where_the_test_starts_firing() {
        for seed in [12, 13] {
            let d = find(1e-4, 0.0, 0.0, seed).detectable;
            assert!(d > 1e-5 && d < 5e-5, "detectable {d}");
            let above = find(1e-4, 1.5 * d, 0.0, seed);
            assert!(above.fired, "τ = {}: {}", 1.5 * d, above.statement);
            let below = find(1e-4, 0.5 * d, 0.0, seed);
            assert!(!below.fired, "τ = {}: {}", 0.5 * d, below.statement);
        }
    }

    #[test]
    fn too_few_repeated_markers_give_no_finding() {
        let one = vec![residuals(1e-4, 5e-5, 3e-4, 0.0, 8).remove(0)];
        let got = estimate_rest_noise(
            &layout(),
            &one,
            1e-4,
            &NoiseOptions::default(),
            &RestNoiseOptions::default(),
        );
        assert!(got.is_none());
    }

    /// The whitened χ² of [`crate::ResidualCheck::with_rest_noise`]: residuals that are the
    /// measurements' noise plus the rest scan's sit at the floor that holds both, while the
    /// floor of the measurements' noise alone calls them unexplained; with τ = 0 it is the
    /// plain check.
    #[test]
    fn residual_check_with_rest_noise_judges_both_noises() {
        use crate::ResidualCheck;
        let (sigma, tau) = (1e-4, 5e-5);
        for seed in [9, 10] {
            let r = residuals(sigma, tau, 0.0, 0.0, seed);
            let n: usize = r.iter().map(|m| 3 * m.len()).sum();
            let sum2: f64 = r
                .iter()
                .flatten()
                .map(|(_, e)| e.iter().map(|v| v * v).sum::<f64>())
                .sum();
            let rms = (sum2 / (n / 3) as f64).sqrt();
            let plain = ResidualCheck::new(rms, sigma * 3f64.sqrt(), n, 2, true);
            assert!(!plain.explained, "{plain:?}");
            let both = ResidualCheck::with_rest_noise(&r, sigma, 0.0, tau, 2, true);
            assert!(both.explained && both.z.abs() < 3.0, "{both:?}");
            assert!((both.ratio_noise - plain.ratio).abs() < 1e-12);
            let zero = ResidualCheck::with_rest_noise(&r, sigma, 0.0, 0.0, 2, true);
            assert!((zero.ratio - plain.ratio).abs() < 1e-12 && (zero.z - plain.z).abs() < 1e-9);
        }
    }
}

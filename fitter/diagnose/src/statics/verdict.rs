//! Whether the final static model's residual is what the noise alone would leave
//! ([`ResidualCheck`]), and the verdict in words.

use serde::Serialize;

/// Whether the final model's residual is what the declared marker noise alone would leave: a
/// verdict of "clean" must be true. With n scalar residuals of variance σ², χ²/n = (RMS / floor)²
/// has mean (n − k)/n ≈ 1 and standard deviation √(2/n); the residual is *unexplained* when it
/// sits more than [`ResidualCheck::Z_LIMIT`] standard deviations above.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct ResidualCheck {
    /// Final fitted RMS over the noise floor σ√3.
    pub ratio: f64,
    /// (ratio² − (n − k)/n) / √(2/n): standard deviations above the floor.
    pub z: f64,
    /// Scalar residuals n.
    pub n: usize,
    /// Whether σ was declared (otherwise there is no floor to judge against).
    pub judged: bool,
    /// Consistent with the noise floor (always true when not judged).
    pub explained: bool,
    /// RMS of what the mesh may still get wrong after the approximation-error correction (m),
    /// added to the floor in quadrature ([`ResidualCheck::with_discretisation`]); 0 without one.
    pub discretisation_m: f64,
    /// Final fitted RMS over the noise floor alone (= `ratio` when `discretisation_m` is 0).
    pub ratio_noise: f64,
    /// The rest scan's noise τ̂ per axis (m) the residual was judged with
    /// ([`ResidualCheck::with_rest_noise`]); 0 without.
    pub rest_noise_m: f64,
}

impl ResidualCheck {
    /// Standard deviations above the floor beyond which a residual is unexplained.
    pub const Z_LIMIT: f64 = 3.0;

    /// The check of a final RMS against `floor` over `n` residuals with `k` fitted parameters.
    pub fn new(rms: f64, floor: f64, n: usize, k: usize, judged: bool) -> Self {
        let ratio = rms / floor;
        let nn = n.max(1) as f64;
        let z = (ratio * ratio - (nn - k as f64).max(1.0) / nn) / (2.0 / nn).sqrt();
        ResidualCheck {
            ratio,
            z,
            n,
            judged,
            explained: !judged || z <= Self::Z_LIMIT,
            discretisation_m: 0.0,
            ratio_noise: ratio,
            rest_noise_m: 0.0,
        }
    }

    /// The check of `rms` against the noise floor widened by the mesh's remaining discretisation
    /// error: the approximation-error correction δ = x_{h/2} − x_h removes the part of the
    /// dataset mesh's error that one refinement sees; for linear tetrahedra converging as h² the
    /// error left, x_0 − x_{h/2}, is about δ/3 (Richardson), an error of the model the data
    /// cannot be asked to explain. Its RMS `remaining` joins the floor in quadrature, so a residual
    /// the mesh alone could leave is not called an unexplained effect — while the verdict still
    /// reports the ratio to the noise floor alone.
    pub fn with_discretisation(
        rms: f64,
        floor: f64,
        remaining: f64,
        n: usize,
        k: usize,
        judged: bool,
    ) -> Self {
        let widened = (floor * floor + remaining * remaining).sqrt();
        ResidualCheck {
            discretisation_m: remaining,
            ratio_noise: rms / floor,
            ..Self::new(rms, widened, n, k, judged)
        }
    }

    /// The check of `residuals` (per measurement: (marker, residual vector) in m) when every
    /// declared rest position carries white noise of `tau` per axis ([`super::rest_noise`]): marker k's
    /// residuals over its m_k measurements then have the covariance s² I + τ² 11ᵀ per axis, with
    /// s² = σ² + remaining²/3 (the mesh's remaining error as in
    /// [`ResidualCheck::with_discretisation`]), and the whitened
    /// χ² = Σ_k Σ_axes [Σ_i (r_ik − r̄_k)² / s² + m_k r̄_k² / (s² + m_k τ²)] has the mean n − k of
    /// the test [`ResidualCheck::new`] makes; `ratio` is √(χ²/n), the RMS over the floor that
    /// holds both noises.
    pub fn with_rest_noise(
        residuals: &[Vec<(usize, [f64; 3])>],
        sigma: f64,
        remaining: f64,
        tau: f64,
        k: usize,
        judged: bool,
    ) -> Self {
        let markers = residuals
            .iter()
            .flat_map(|r| r.iter().map(|&(m, _)| m + 1))
            .max()
            .unwrap_or(0);
        let mut seen = vec![0usize; markers];
        let mut sum = vec![[0.0f64; 3]; markers];
        let (mut total, mut n) = (0.0, 0usize);
        for r in residuals {
            for &(m, e) in r {
                seen[m] += 1;
                for d in 0..3 {
                    sum[m][d] += e[d];
                    total += e[d] * e[d];
                }
                n += 3;
            }
        }
        let s2 = sigma * sigma + remaining * remaining / 3.0;
        // Σ_i (r_i − r̄)² = Σ_i r_i² − m r̄², so χ² = (total − Σ m r̄²) / s² + Σ m r̄² / (s² + m τ²).
        let persistent: Vec<(f64, f64)> = (0..markers)
            .filter(|&m| seen[m] > 0)
            .map(|m| {
                let c = seen[m] as f64;
                (c, sum[m].iter().map(|v| v * v).sum::<f64>() / c)
            })
            .collect();
        let between: f64 = persistent.iter().map(|&(_, p)| p).sum();
        let chi2 = (total - between) / s2
            + persistent
                .iter()
                .map(|&(c, p)| p / (s2 + c * tau * tau))
                .sum::<f64>();
        let ratio = (chi2 / n.max(1) as f64).sqrt();
        let rms = (total / (n.max(1) / 3) as f64).sqrt();
        ResidualCheck {
            discretisation_m: remaining,
            ratio_noise: rms / (sigma * 3f64.sqrt()),
            rest_noise_m: tau,
            ..Self::new(ratio, 1.0, n, k, judged)
        }
    }

    /// The verdict's words for a diagnosis that adopted `adopted`.
    pub fn verdict(&self, adopted: &str) -> String {
        // With `noise` adopted the floor is σ̂√3, the one the nugget estimate re-measured; with
        // an approximation-error correction it is widened by the mesh's remaining error.
        let noise_name = if adopted.split(", ").any(|a| a == "noise") {
            "the re-estimated noise floor"
        } else {
            "the noise floor"
        };
        let rest = if self.rest_noise_m > 0.0 {
            format!(
                " with the rest scan's noise ({:.1} µm per axis in every marker's rest position)",
                1e6 * self.rest_noise_m
            )
        } else {
            String::new()
        };
        let floor = if self.discretisation_m > 0.0 {
            format!(
                "{noise_name}{rest} widened by the mesh's remaining discretisation error ({:.1} µm RMS: the residual is {:.2}× the noise floor alone, and effects smaller than that error cannot be told from the mesh's)",
                1e6 * self.discretisation_m,
                self.ratio_noise
            )
        } else if self.rest_noise_m > 0.0 {
            format!(
                "{noise_name}{rest} (the residual is {:.2}× the noise floor alone)",
                self.ratio_noise
            )
        } else {
            noise_name.to_string()
        };
        let words = match (adopted.is_empty(), self.explained) {
            (true, true) if self.judged => format!(
                "clean: no effect adopted, and the residual is {:.2}× {floor} ({:+.1}σ)",
                self.ratio, self.z
            ),
            (true, true) => "no effect adopted (no declared marker noise: whether the residual is noise cannot be judged)".into(),
            (true, false) => format!(
                "NOT clean: no candidate effect earns its place, but the residual is {:.2}× {floor} ({:.1}σ above it) — an effect the candidate library does not hold, or a mesh too coarse for the data",
                self.ratio, self.z
            ),
            (false, true) if self.judged => format!("adopted {adopted}; the residual is then {:.2}× {floor} ({:+.1}σ)", self.ratio, self.z),
            (false, true) => format!("adopted {adopted} (no declared marker noise: whether the rest of the residual is noise cannot be judged)"),
            (false, false) => format!(
                "adopted {adopted}, but the residual is still {:.2}× {floor} ({:.1}σ above it): more is missing than the library explains",
                self.ratio, self.z
            ),
        };
        // A residual far *below* its floor is as telling as one above it: noise cannot leave
        // less than itself, so the floor is overstated or the fit has taken part of the noise.
        if self.judged && self.z < -Self::Z_LIMIT {
            format!(
                "{words}; that is {:.1}σ below the floor, more than noise allows: the floor is overstated (σ declared too high{}) or the adopted effects fit part of the noise",
                -self.z,
                if self.discretisation_m > 0.0 {
                    ", or the mesh's remaining discretisation error over-estimated"
                } else {
                    ""
                }
            )
        } else {
            words
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// "Clean" only when the residual is the floor's: 1.00× and 1.01× of 3,672 residuals are
    /// (0.0σ, +0.9σ), 1.04× is +3.5σ above it (the independent generator's missed inclusion).
    #[test]
    fn residual_check_calls_clean_only_what_the_noise_explains() {
        let n = 3672;
        let ok = ResidualCheck::new(1.0, 1.0, n, 2, true);
        assert!(ok.explained && ok.z.abs() < 0.1, "{ok:?}");
        assert!(ok.verdict("").starts_with("clean"), "{}", ok.verdict(""));
        let near = ResidualCheck::new(1.01, 1.0, n, 2, true);
        assert!(near.explained, "{near:?}");
        let over = ResidualCheck::new(1.04, 1.0, n, 2, true);
        assert!(!over.explained && (over.z - 3.5).abs() < 0.2, "{over:?}");
        assert!(
            over.verdict("").starts_with("NOT clean"),
            "{}",
            over.verdict("")
        );
        assert!(over.verdict("gravity").contains("still 1.04×"));
        let blind = ResidualCheck::new(3.0, 1.0, n, 2, false);
        assert!(blind.explained && blind.verdict("").contains("cannot be judged"));
        // 0.96× of 3,672 residuals is 3.3σ below: said, not called clean without a word.
        let under = ResidualCheck::new(0.96, 1.0, n, 2, true);
        assert!(under.explained && under.z < -3.0, "{under:?}");
        assert!(
            under.verdict("").starts_with("clean") && under.verdict("").contains("below the floor"),
            "{}",
            under.verdict("")
        );
        assert!(!ok.verdict("").contains("below the floor"));
        let blind_under = ResidualCheck::new(0.5, 1.0, n, 2, false);
        assert!(!blind_under.verdict("").contains("below the floor"));
    }
}

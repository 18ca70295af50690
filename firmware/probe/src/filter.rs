//! First-order low-pass `y ← y + α (x − y)` with `α = 1 − exp(−2π f_c / f_s)` (the exact
//! discretisation of an RC filter sampled at `f_s`), applied to conductance: an FSR's
//! conductance is close to linear in force, so filtering there does not bias the force the way
//! filtering the (saturating) divider voltage would.

/// The filter state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LowPass {
    alpha: f32,
    state: Option<f32>,
}

impl LowPass {
    /// A filter with cut-off `cutoff_hz` at sample rate `rate_hz`; a cut-off of 0 (or at or
    /// above Nyquist) passes samples through.
    pub fn new(cutoff_hz: f32, rate_hz: f32) -> Self {
        let alpha = if cutoff_hz > 0.0 && cutoff_hz < 0.5 * rate_hz {
            1.0 - libm::expf(-2.0 * core::f32::consts::PI * cutoff_hz / rate_hz)
        } else {
            1.0
        };
        Self { alpha, state: None }
    }

    /// The smoothing factor α.
    pub fn alpha(&self) -> f32 {
        self.alpha
    }

    /// Filters one sample (the first sample initialises the state).
    pub fn update(&mut self, x: f32) -> f32 {
        let y = match self.state {
            Some(y) => y + self.alpha * (x - y),
            None => x,
        };
        self.state = Some(y);
        y
    }

    /// Forgets the state (next sample passes through).
    pub fn reset(&mut self) {
        self.state = None;
    }
}

//! The FSR front end and its force calibration, carried in the config frame and evaluated by
//! the firmware, the host simulator and the fitter with this one implementation.
//!
//! The FSR sits on top of a pull-down resistor `R_pd` fed from `V_s`; the ADC reads the divider
//! output `V = V_s · R_pd / (R_pd + R_fsr)`. Inverting gives the sensor's conductance
//! `G = 1 / R_fsr = V / (R_pd · (V_s − V))`, which for an FSR is close to proportional to force
//! (Interlink's integration guide), so the calibration curve maps conductance to force:
//! a power law `F = a · G^b` or a monotone piecewise-linear table (thesis §4.2, Fig. 4.4: a
//! fitted sensor response curve evaluated per reading).

use postcard::experimental::max_size::MaxSize;
use serde::{Deserialize, Serialize};

/// Most knots a monotone calibration table carries (fixed so the frame size is known at
/// compile time).
pub const MAX_KNOTS: usize = 12;

/// The voltage divider in front of the ADC.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Divider {
    /// Pull-down resistor in ohms (e.g. 10 000).
    pub r_pulldown_ohm: f32,
    /// Divider supply in volts (e.g. 3.3 on the nRF52840 board, 5.0 on the calibration rig).
    pub v_supply_v: f32,
}

impl Divider {
    /// FSR conductance in µS from the divider output voltage; `None` when `v ≥ v_supply`
    /// (zero sensor resistance: saturated) or when `v` is not finite.
    pub fn conductance_us(&self, v: f32) -> Option<f32> {
        let headroom = self.v_supply_v - v;
        if !(v.is_finite() && headroom > 0.0) {
            return None;
        }
        Some(1.0e6 * v.max(0.0) / (self.r_pulldown_ohm * headroom))
    }

    /// Divider output in volts for a sensor conductance in µS (the inverse of
    /// [`conductance_us`](Self::conductance_us)).
    pub fn voltage(&self, conductance_us: f32) -> f32 {
        let g_rpd = conductance_us.max(0.0) * 1.0e-6 * self.r_pulldown_ohm;
        self.v_supply_v * g_rpd / (1.0 + g_rpd)
    }
}

/// Force as a function of FSR conductance (µS → N).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ForceCurve {
    /// `F = gain · G^exponent` with `G` in µS and `F` in N.
    PowerLaw {
        /// Gain `a` in N / µS^b.
        gain: f32,
        /// Exponent `b` (dimensionless, 0 < b ≤ 5).
        exponent: f32,
    },
    /// Piecewise-linear through `(0, 0)` and the first `len` knots; beyond the last knot the
    /// last segment's slope continues.
    Monotone {
        /// Number of knots in use (2 ..= [`MAX_KNOTS`]).
        len: u8,
        /// Knot conductances in µS, strictly increasing.
        conductance_us: [f32; MAX_KNOTS],
        /// Knot forces in N, non-decreasing.
        force_n: [f32; MAX_KNOTS],
    },
}

/// Everything the firmware needs to turn a divider voltage into a force.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Calibration {
    /// The divider the curve was fitted for (conductance does not depend on it, so a curve
    /// fitted on a 5 V rig carries over to a 3.3 V board).
    pub divider: Divider,
    /// Conductance → force.
    pub curve: ForceCurve,
    /// Smallest force the fit supports, in N (below it the reading is flagged as out of range).
    pub usable_min_n: f32,
    /// Largest force the fit supports, in N.
    pub usable_max_n: f32,
}

/// Which value [`through_knots`] takes on a segment of no width.
#[derive(Clone, Copy)]
enum Step {
    /// The segment's start.
    Start,
    /// The segment's end.
    End,
}

/// The piecewise-linear function through (0, 0) and the knots `(xs[i], ys[i])` at `x`; past the
/// last knot the last segment goes on. On a segment of no width the value is its `step` end.
/// `xs` and `ys` are equally long and not empty.
fn through_knots(x: f32, xs: &[f32], ys: &[f32], step: Step) -> f32 {
    let n = xs.len();
    let (mut x0, mut y0) = (0.0f32, 0.0f32);
    for i in 0..n {
        let (x1, y1) = (xs[i], ys[i]);
        if x <= x1 || i + 1 == n {
            let dx = x1 - x0;
            return if dx > 0.0 {
                y0 + (y1 - y0) * (x - x0) / dx
            } else {
                match step {
                    Step::Start => y0,
                    Step::End => y1,
                }
            };
        }
        (x0, y0) = (x1, y1);
    }
    y0
}

impl ForceCurve {
    /// The knots in use of a table curve: (conductances, forces); empty for a power law.
    fn table(&self) -> (&[f32], &[f32]) {
        match self {
            ForceCurve::PowerLaw { .. } => (&[], &[]),
            ForceCurve::Monotone {
                len,
                conductance_us,
                force_n,
            } => {
                let n = (*len as usize).clamp(1, MAX_KNOTS);
                (&conductance_us[..n], &force_n[..n])
            }
        }
    }

    /// Force in N for a conductance in µS (negative conductances read as zero).
    pub fn force_n(&self, conductance_us: f32) -> f32 {
        let g = conductance_us.max(0.0);
        match *self {
            ForceCurve::PowerLaw { gain, exponent } => gain * libm::powf(g, exponent),
            ForceCurve::Monotone { .. } => {
                let (gs, fs) = self.table();
                through_knots(g, gs, fs, Step::End)
            }
        }
    }

    /// Conductance in µS that gives force `force_n` (the inverse used by the host-side probe
    /// simulator). On a flat table segment it returns the segment's start.
    pub fn conductance_us(&self, force_n: f32) -> f32 {
        let f = force_n.max(0.0);
        match *self {
            ForceCurve::PowerLaw { gain, exponent } => libm::powf(f / gain, 1.0 / exponent),
            ForceCurve::Monotone { .. } => {
                let (gs, fs) = self.table();
                through_knots(f, fs, gs, Step::Start)
            }
        }
    }

    /// Checks the curve is finite and monotone; names the first problem.
    pub fn validate(&self) -> Result<(), &'static str> {
        match *self {
            ForceCurve::PowerLaw { gain, exponent } => {
                if !(gain.is_finite() && gain > 0.0) {
                    return Err("power-law gain must be finite and > 0");
                }
                if !(exponent.is_finite() && exponent > 0.0 && exponent <= 5.0) {
                    return Err("power-law exponent must be in (0, 5]");
                }
            }
            ForceCurve::Monotone {
                len,
                conductance_us: ref gs,
                force_n: ref fs,
            } => {
                let n = len as usize;
                if !(2..=MAX_KNOTS).contains(&n) {
                    return Err("monotone table needs 2 ..= MAX_KNOTS knots");
                }
                let (mut g0, mut f0) = (0.0f32, 0.0f32);
                for i in 0..n {
                    if !(gs[i].is_finite() && fs[i].is_finite()) {
                        return Err("monotone table knot is not finite");
                    }
                    if gs[i] <= g0 && !(i == 0 && gs[i] == 0.0) {
                        return Err("monotone table conductances must increase strictly");
                    }
                    if fs[i] < f0 {
                        return Err("monotone table forces must not decrease");
                    }
                    (g0, f0) = (gs[i], fs[i]);
                }
            }
        }
        Ok(())
    }
}

impl Calibration {
    /// Force in N for a divider voltage, or `None` when the divider is saturated (`V ≥ V_s`).
    pub fn force_from_voltage(&self, v: f32) -> Option<f32> {
        self.divider
            .conductance_us(v)
            .map(|g| self.curve.force_n(g))
    }

    /// Checks every field; names the first problem.
    pub fn validate(&self) -> Result<(), &'static str> {
        let d = &self.divider;
        if !(d.r_pulldown_ohm.is_finite() && d.r_pulldown_ohm > 0.0) {
            return Err("divider pull-down must be finite and > 0 ohm");
        }
        if !(d.v_supply_v.is_finite() && d.v_supply_v > 0.0) {
            return Err("divider supply must be finite and > 0 V");
        }
        if !(self.usable_min_n.is_finite()
            && self.usable_max_n.is_finite()
            && self.usable_min_n >= 0.0
            && self.usable_min_n < self.usable_max_n)
        {
            return Err("usable force range must satisfy 0 <= min < max");
        }
        self.curve.validate()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn divider_round_trips_and_matches_the_fsr402_datasheet_points() {
        // Adafruit's FSR 402 table (10 kΩ pull-down at 5 V): 30 kΩ → 1.3 V, 1 kΩ → 4.5 V,
        // rounded to 0.1 V in the source, hence the 0.06 V tolerance.
        let d = Divider {
            r_pulldown_ohm: 10_000.0,
            v_supply_v: 5.0,
        };
        for (r, v) in [
            (30_000.0f32, 1.3f32),
            (6_000.0, 3.1),
            (1_000.0, 4.5),
            (250.0, 4.9),
        ] {
            let vv = d.voltage(1.0e6 / r);
            assert!((vv - v).abs() < 0.06, "R={r}: {vv} vs {v}");
            let g = d.conductance_us(vv).unwrap();
            assert!((g * r / 1.0e6 - 1.0).abs() < 1e-5, "round trip at R={r}");
        }
        assert_eq!(d.conductance_us(5.0), None);
        assert_eq!(d.conductance_us(f32::NAN), None);
    }

    #[test]
    fn curves_invert_and_validate() {
        let p = ForceCurve::PowerLaw {
            gain: 0.01,
            exponent: 1.2,
        };
        p.validate().unwrap();
        for f in [0.1f32, 1.0, 7.5, 40.0] {
            let g = p.conductance_us(f);
            assert!((p.force_n(g) / f - 1.0).abs() < 1e-5, "power law at {f} N");
        }
        let mut gs = [0.0; MAX_KNOTS];
        let mut fs = [0.0; MAX_KNOTS];
        gs[..3].copy_from_slice(&[100.0, 200.0, 400.0]);
        fs[..3].copy_from_slice(&[1.0, 3.0, 4.0]);
        let t = ForceCurve::Monotone {
            len: 3,
            conductance_us: gs,
            force_n: fs,
        };
        t.validate().unwrap();
        // Exact piecewise-linear values: through the origin, knots, and the last slope beyond.
        assert_eq!(t.force_n(50.0), 0.5);
        assert_eq!(t.force_n(150.0), 2.0);
        assert_eq!(t.force_n(600.0), 5.0);
        assert_eq!(t.conductance_us(3.5), 300.0);
        fs[1] = 0.5;
        let bad = ForceCurve::Monotone {
            len: 3,
            conductance_us: gs,
            force_n: fs,
        };
        assert_eq!(
            bad.validate(),
            Err("monotone table forces must not decrease")
        );
        assert!(ForceCurve::PowerLaw {
            gain: f32::NAN,
            exponent: 1.0
        }
        .validate()
        .is_err());
    }
}

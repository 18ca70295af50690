//! How a predicted run settles after its ring-down, and which way its rest error points: the
//! two figures that separate a stiffness error from the rest of a prediction's error.
//!
//! - **Settling** ([`settling`]): the markers that sag most (their measured rest displacement
//!   along gravity at least half the largest), their mean displacement along gravity, measured
//!   and simulated, averaged in windows of [`WINDOW_S`] from the moment the measured swing has
//!   decayed below [`SETTLED_FRACTION`] of its largest excursion from the measured rest, to the
//!   end of the run. A stress that relaxes (creep) shows here as a measured curve that keeps
//!   sinking while a purely elastic model's stays put; the windows average the small residual
//!   ringing out, so what is left is the slow drift.
//! - **Rest error by direction** ([`rest_error_directions`]): each marker's predicted rest
//!   position minus its measured one, split into its component along gravity and the rest. A
//!   modulus that is off moves markers along gravity; an error across it (the weight hung off
//!   centre, a twisted grip, a registration error) is one no stiffness can remove.

use crate::model::{Model, Observations};
use crate::predict::{final_observed, rest_markers};

/// Length of a settling window (s): a few periods of the ring-downs this is made for (0.13 s
/// and 0.23 s on the measured beam), so a window's mean carries little of the residual swing.
pub const WINDOW_S: f64 = 0.2;

/// The swing counts as decayed once the measured excursion from the rest state stays below this
/// fraction of its largest.
pub const SETTLED_FRACTION: f64 = 0.1;

/// Markers whose measured rest displacement along gravity is at least this fraction of the
/// largest one's are averaged (the free end's, on a cantilever).
const MOVING_FRACTION: f64 = 0.5;

/// The settling phase of a run, measured and predicted.
#[derive(Debug, Clone, PartialEq)]
pub struct Settling {
    /// The markers averaged (indices into the model's markers).
    pub markers: Vec<usize>,
    /// Time after the start at which the measured swing has decayed (s).
    pub from_s: f64,
    /// Per window: its centre (s), the measured and the simulated mean displacement along
    /// gravity (m).
    pub windows: Vec<(f64, f64, f64)>,
}

impl Settling {
    /// The largest |simulated − measured| over the windows (m).
    pub fn max_abs_error_m(&self) -> f64 {
        self.windows
            .iter()
            .map(|w| (w.2 - w.1).abs())
            .fold(0.0, f64::max)
    }

    /// How far the measured displacement moves over the windows (m): the slope of the least-
    /// squares line through the windows' means times their span, so that the residual ringing
    /// left in one window does not pass for a drift. The creep the capture shows after its
    /// ring-down.
    pub fn measured_drift_m(&self) -> f64 {
        self.drift(|w| w.1)
    }

    /// The same for the simulation (m).
    pub fn simulated_drift_m(&self) -> f64 {
        self.drift(|w| w.2)
    }

    fn drift(&self, value: impl Fn(&(f64, f64, f64)) -> f64) -> f64 {
        let n = self.windows.len() as f64;
        if self.windows.len() < 2 {
            return 0.0;
        }
        let tm = self.windows.iter().map(|w| w.0).sum::<f64>() / n;
        let vm = self.windows.iter().map(&value).sum::<f64>() / n;
        let stt = self.windows.iter().map(|w| (w.0 - tm).powi(2)).sum::<f64>();
        let stv = self
            .windows
            .iter()
            .map(|w| (w.0 - tm) * (value(w) - vm))
            .sum::<f64>();
        let span = self.windows[self.windows.len() - 1].0 - self.windows[0].0;
        stv / stt * span
    }
}

/// Unit vector along `g`, `None` without gravity.
fn unit(g: [f64; 3]) -> Option<[f64; 3]> {
    let n = g.iter().map(|v| v * v).sum::<f64>().sqrt();
    (n > 0.0).then(|| g.map(|v| v / n))
}

fn dot(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    (0..3).map(|k| a[k] * b[k]).sum()
}

/// The settling of a run: `simulated` holds the simulated markers row for row with
/// `obs.markers` (step n + 1 at row n, as [`crate::predict::Prediction::simulated`]). `None`
/// when the run has no gravity, no marker sags, or the swing never decays within the run.
pub fn settling(
    model: &Model,
    obs: &Observations,
    simulated: &[Vec<[f64; 3]>],
) -> Option<Settling> {
    let g = unit(model.gravity)?;
    let rest = rest_markers(model);
    let finals = final_observed(model, obs);
    let sag: Vec<f64> = (0..rest.len())
        .map(|i| {
            finals[i]
                .map(|f| dot(&[0, 1, 2].map(|k| f[k] - rest[i][k]), &g))
                .unwrap_or(0.0)
        })
        .collect();
    let largest = sag.iter().copied().fold(0.0, f64::max);
    if largest <= 0.0 {
        return None;
    }
    let markers: Vec<usize> = (0..sag.len())
        .filter(|&i| sag[i] >= MOVING_FRACTION * largest)
        .collect();
    let along = |p: &[f64; 3], i: usize| dot(&[0, 1, 2].map(|k| p[k] - rest[i][k]), &g);
    // Mean displacement along gravity of the chosen markers per row, where all of them are seen.
    let rows = obs.markers.len().min(simulated.len());
    let mean: Vec<Option<(f64, f64)>> = (0..rows)
        .map(|n| {
            let mut o = 0.0;
            let mut s = 0.0;
            for &i in &markers {
                let seen = obs.markers[n].get(i).copied().flatten()?;
                o += along(&seen, i);
                s += along(simulated[n].get(i)?, i);
            }
            let k = markers.len() as f64;
            Some((o / k, s / k))
        })
        .collect();
    let end: Vec<f64> = {
        let window = ((crate::predict::FINAL_WINDOW_S / model.dt).round() as usize).max(1);
        mean[rows.saturating_sub(window)..]
            .iter()
            .flatten()
            .map(|m| m.0)
            .collect()
    };
    if end.is_empty() {
        return None;
    }
    let rest_o = end.iter().sum::<f64>() / end.len() as f64;
    let excursion = |m: &Option<(f64, f64)>| m.map(|m| (m.0 - rest_o).abs());
    let largest_excursion = mean.iter().filter_map(excursion).fold(0.0, f64::max);
    // The first row after which every seen row's excursion stays below the threshold.
    let threshold = SETTLED_FRACTION * largest_excursion;
    let last_above = mean
        .iter()
        .rposition(|m| excursion(m).is_some_and(|e| e >= threshold))?;
    let from = last_above + 1;
    let per_window = ((WINDOW_S / model.dt).round() as usize).max(1);
    let windows: Vec<(f64, f64, f64)> = (from..rows)
        .step_by(per_window)
        .filter_map(|start| {
            let stop = (start + per_window).min(rows);
            // A last window shorter than half a window averages too little of the swing.
            if 2 * (stop - start) < per_window {
                return None;
            }
            let seen: Vec<(f64, f64)> = mean[start..stop].iter().flatten().copied().collect();
            if seen.is_empty() {
                return None;
            }
            let k = seen.len() as f64;
            let centre = (start + stop) as f64 / 2.0 * model.dt + model.dt / 2.0;
            Some((
                centre,
                seen.iter().map(|m| m.0).sum::<f64>() / k,
                seen.iter().map(|m| m.1).sum::<f64>() / k,
            ))
        })
        .collect();
    (!windows.is_empty()).then(|| Settling {
        markers,
        from_s: (from + 1) as f64 * model.dt,
        windows,
    })
}

/// The RMS over the markers of the predicted rest error's component along gravity and of the
/// rest of it (m): `(along, across)`. `None` without gravity or without a marker seen at rest.
pub fn rest_error_directions(
    model: &Model,
    obs: &Observations,
    equilibrium: &[[f64; 3]],
) -> Option<(f64, f64)> {
    let g = unit(model.gravity)?;
    let finals = final_observed(model, obs);
    let (mut along, mut across, mut n) = (0.0, 0.0, 0usize);
    for (e, f) in equilibrium.iter().zip(&finals) {
        let Some(f) = f else { continue };
        let d = [0, 1, 2].map(|k| e[k] - f[k]);
        let a = dot(&d, &g);
        along += a * a;
        across += (dot(&d, &d) - a * a).max(0.0);
        n += 1;
    }
    (n > 0).then(|| {
        let n = n as f64;
        ((along / n).sqrt(), (across / n).sqrt())
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenario::example_bar;

    /// Markers that sag along gravity by `w_i · D(t)`: a 5 Hz ring-down decaying in 0.3 s
    /// about 10 mm, measured with a creep of 0.3 mm (1 − e^(−t/1 s)) on top and simulated
    /// without it.
    fn ring_down(creep_m: f64) -> (Model, Observations, Vec<Vec<[f64; 3]>>, Vec<f64>) {
        let steps = 540; // 3 s at 180 Hz
        let (_, mut model) = example_bar([1, 2, 1], steps).unwrap();
        model.gravity = [0.0, 0.0, -9.81];
        let rest = rest_markers(&model);
        let weights: Vec<f64> = (0..rest.len()).map(|i| 0.2 + 0.1 * i as f64).collect();
        let d = |t: f64, creep: f64| {
            0.01 * (1.0 - (-t / 0.3).exp() * (std::f64::consts::TAU * 5.0 * t).cos())
                + creep * (1.0 - (-t).exp())
        };
        let at = |n: usize, creep: f64| -> Vec<[f64; 3]> {
            let t = (n + 1) as f64 * model.dt;
            rest.iter()
                .zip(&weights)
                .map(|(r, w)| [r[0], r[1], r[2] - w * d(t, creep)])
                .collect()
        };
        let obs = Observations {
            markers: (0..steps)
                .map(|n| at(n, creep_m).into_iter().map(Some).collect())
                .collect(),
            forces: vec![Vec::new(); steps],
            marker_weight: 1.0,
            force_weight: 1.0,
            free_marker_offsets: false,
            phi_precision: 0.0,
        };
        let simulated = (0..steps).map(|n| at(n, 0.0)).collect();
        (model, obs, simulated, weights)
    }

    /// The creep the capture has and the simulation lacks is what the windows show: the error
    /// of the last window is the creep's 0.3 mm (1 − e^(−t)) at its centre, to the residual
    /// ringing's share; the simulated curve does not drift, the measured one does; only the
    /// markers sagging at least half the most are averaged.
    #[test]
    fn the_windows_show_a_creep_the_simulation_lacks() {
        let (model, obs, sim, weights) = ring_down(3e-4);
        let s = settling(&model, &obs, &sim).expect("the swing decays within the run");
        let most = weights.iter().copied().fold(0.0, f64::max);
        let expected: Vec<usize> = (0..weights.len())
            .filter(|&i| weights[i] >= 0.5 * most)
            .collect();
        assert_eq!(s.markers, expected);
        // The swing about 10 mm decays as e^(−t/0.3): below 10 % of its largest excursion
        // (which includes the creep's share) after ≈ 0.3 ln 10 ≈ 0.7 s.
        assert!((0.4..1.0).contains(&s.from_s), "from {} s", s.from_s);
        let mean_w = s.markers.iter().map(|&i| weights[i]).sum::<f64>() / s.markers.len() as f64;
        let last = s.windows.last().unwrap();
        let creep_there = mean_w * 3e-4 * (1.0 - (-last.0).exp());
        // Measured sags more than simulated: simulated − measured is negative along gravity.
        assert!(
            ((last.2 - last.1) + creep_there).abs() < 0.05 * creep_there,
            "last window error {} m, creep {} m",
            last.2 - last.1,
            creep_there
        );
        assert!((s.max_abs_error_m() - creep_there).abs() < 0.05 * creep_there);
        // The ringing left in the windows is the same in both curves, so the difference of the
        // drifts is the creep's own least-squares drift over the windows.
        let creep = Settling {
            windows: s
                .windows
                .iter()
                .map(|w| (w.0, mean_w * 3e-4 * (1.0 - (-w.0).exp()), 0.0))
                .collect(),
            ..s.clone()
        };
        let drift = s.measured_drift_m() - s.simulated_drift_m();
        assert!(
            (drift - creep.measured_drift_m()).abs() < 0.05 * creep.measured_drift_m(),
            "{drift} against {}",
            creep.measured_drift_m()
        );
        assert!(creep.measured_drift_m() > 0.0);
    }

    /// A straight line's drift is its slope times the windows' span, whatever one window's
    /// ringing adds to it: 1 mm/s over 2 s with a 0.5 mm kick in the first window, against
    /// the 0.5 mm that the first and last windows alone would give.
    #[test]
    fn the_drift_is_the_least_squares_slope_over_the_span() {
        let mut windows: Vec<(f64, f64, f64)> = (0..11)
            .map(|k| {
                let t = 1.0 + 0.2 * k as f64;
                (t, 1e-3 * t, 0.0)
            })
            .collect();
        let line = Settling {
            markers: vec![0],
            from_s: 1.0,
            windows: windows.clone(),
        };
        assert!((line.measured_drift_m() - 2e-3).abs() < 1e-12);
        assert_eq!(line.simulated_drift_m(), 0.0);
        windows[0].1 += 5e-4;
        let kicked = Settling { windows, ..line };
        let d = kicked.measured_drift_m();
        assert!((1.6e-3..2e-3).contains(&d), "{d}");
    }

    /// Without the creep the prediction settles where the capture does: every window agrees.
    #[test]
    fn a_prediction_without_the_error_settles_on_the_capture() {
        let (model, obs, sim, _) = ring_down(0.0);
        let s = settling(&model, &obs, &sim).unwrap();
        assert!(s.max_abs_error_m() < 1e-12, "{}", s.max_abs_error_m());
    }

    /// A rest error of 3 mm along gravity and 4 mm across it on every marker splits into 3 and 4.
    #[test]
    fn the_rest_error_splits_along_and_across_gravity() {
        let (model, obs, _, _) = ring_down(0.0);
        let finals = final_observed(&model, &obs);
        let eq: Vec<[f64; 3]> = finals
            .iter()
            .map(|f| {
                let f = f.unwrap();
                [f[0] + 4e-3, f[1], f[2] - 3e-3]
            })
            .collect();
        let (along, across) = rest_error_directions(&model, &obs, &eq).unwrap();
        assert!((along - 3e-3).abs() < 1e-12 && (across - 4e-3).abs() < 1e-12);
        let mut flat = model.clone();
        flat.gravity = [0.0; 3];
        assert!(rest_error_directions(&flat, &obs, &eq).is_none());
        assert!(settling(
            &flat,
            &obs,
            &eq.iter().map(|_| eq.clone()).collect::<Vec<_>>()
        )
        .is_none());
    }
}

//! The runs' residual signature: per run, the RMS per marker, in the first and last quarter of
//! the run, and — on the marker that moves most — the ring-down's period and its amplitude ratio
//! per cycle, measured and simulated. A period the model gets wrong points at the mass (the
//! hanging weight's inertia); a decay it gets wrong at the damping, whose fit starts from the
//! viscosity the measured ring-downs show.

use palpate_motion::dataset::MotionDataset;
use palpate_motion::model::Material;
use palpate_motion::predict::{self, Prediction};
use palpate_motion::MotionError;
use serde::Serialize;

/// One run's residual, as the diagnosis reads it.
#[derive(Debug, Clone, Serialize)]
pub struct RunResidual {
    /// The run (its dataset directory).
    pub run: String,
    /// RMS over every observed (step, marker) (m).
    pub rms_m: f64,
    /// Sum of squared marker distances (m²) and the number of observed marker positions.
    pub chi2: f64,
    /// Observed marker positions.
    pub count: usize,
    /// RMS per marker over the run (m).
    pub per_marker_m: Vec<(String, f64)>,
    /// RMS over the first and the last quarter of the steps (m).
    pub early_m: f64,
    /// See `early_m`.
    pub late_m: f64,
    /// Predicted equilibrium against the markers' rest state at the end (RMS, m).
    pub final_rms_m: f64,
    /// Dead loads along gravity at the end of the run (N).
    pub load_n: f64,
    /// The marker that moves most (the ring-down is read on it).
    pub ring_marker: String,
    /// Ring-down period, measured and simulated (s); `None` when fewer than two half-cycles.
    pub period_s: (Option<f64>, Option<f64>),
    /// Amplitude ratio per cycle, measured and simulated.
    pub decay_per_cycle: (Option<f64>, Option<f64>),
    /// The run's time offset: its markers compared with the simulation this much later (s; 0
    /// without the time-offset effect).
    pub time_offset_s: f64,
    /// Displacement along gravity of `ring_marker` per step, measured (NaN = unseen) and
    /// simulated (m) — for the report's plots.
    #[serde(skip)]
    pub ring: (Vec<f64>, Vec<f64>),
    /// The simulated markers at every step the readings were made from, for a check at the same
    /// material that needs them again (the step error at the final model).
    #[serde(skip)]
    pub simulated: std::sync::Arc<Vec<Vec<[f64; 3]>>>,
}

/// The residual of one run under `mat`: simulated, compared, its ring-down read.
pub fn residual(
    name: &str,
    ds: &MotionDataset,
    mat: &Material,
) -> Result<RunResidual, MotionError> {
    let p = predict::predict(&ds.model, mat, &ds.obs)?;
    Ok(read_residual(name, ds, p, 0))
}

/// The residual of one run predicted as `p`, its markers compared `offset` steps late.
pub(in crate::runs) fn read_residual(
    name: &str,
    ds: &MotionDataset,
    p: Prediction,
    offset: i64,
) -> RunResidual {
    let nm = ds.model.markers.len();
    let steps = p.simulated.len();
    let mut per = vec![(0.0, 0usize); nm];
    let (mut early, mut late) = ((0.0, 0usize), (0.0, 0usize));
    let q = steps / 4;
    for (n, (sim, obs)) in p.simulated.iter().zip(&ds.obs.markers).enumerate() {
        for i in 0..nm {
            if let Some(o) = obs.get(i).copied().flatten() {
                let e2 = (0..3).map(|k| (sim[i][k] - o[k]).powi(2)).sum::<f64>();
                per[i].0 += e2;
                per[i].1 += 1;
                if n < q {
                    early.0 += e2;
                    early.1 += 1;
                }
                if n >= steps - q {
                    late.0 += e2;
                    late.1 += 1;
                }
            }
        }
    }
    let r = |(s, c): (f64, usize)| if c == 0 { 0.0 } else { (s / c as f64).sqrt() };
    let chi2: f64 = per.iter().map(|p| p.0).sum();
    let count: usize = per.iter().map(|p| p.1).sum();
    // The ring-down is read along gravity on the marker whose equilibrium moves most.
    let g = ds.model.gravity;
    let gn = g.iter().map(|v| v * v).sum::<f64>().sqrt().max(1e-300);
    let rest = predict::rest_markers(&ds.model);
    let along =
        |x: &[f64; 3], i: usize| (0..3).map(|k| (x[k] - rest[i][k]) * g[k] / gn).sum::<f64>();
    let tip = (0..nm)
        .max_by(|&a, &b| {
            along(&p.equilibrium[a], a)
                .abs()
                .total_cmp(&along(&p.equilibrium[b], b).abs())
        })
        .unwrap_or(0);
    let measured: Vec<f64> = ds
        .obs
        .markers
        .iter()
        .take(steps)
        .map(|row| {
            row.get(tip)
                .copied()
                .flatten()
                .map_or(f64::NAN, |o| along(&o, tip))
        })
        .collect();
    let simulated: Vec<f64> = p
        .simulated
        .iter()
        .map(|row| along(&row[tip], tip))
        .collect();
    let dt = ds.model.dt;
    let ring_m = ring_down(&measured, dt);
    let ring_s = ring_down(&simulated, dt);
    RunResidual {
        run: name.to_string(),
        rms_m: r((chi2, count)),
        chi2,
        count,
        per_marker_m: ds
            .model
            .markers
            .iter()
            .zip(&per)
            .map(|(m, &p)| (m.name.clone(), r(p)))
            .collect(),
        early_m: r(early),
        late_m: r(late),
        final_rms_m: p.final_rms_m,
        load_n: predict::load_along_gravity(&ds.model),
        ring_marker: ds
            .model
            .markers
            .get(tip)
            .map(|m| m.name.clone())
            .unwrap_or_default(),
        period_s: (ring_m.0, ring_s.0),
        decay_per_cycle: (ring_m.1, ring_s.1),
        time_offset_s: offset as f64 * ds.model.dt,
        ring: (measured, simulated),
        simulated: std::sync::Arc::new(p.simulated),
    }
}

/// A Newtonian viscosity on the scale the measured ring-downs show: for each run with a measured
/// period T and amplitude ratio a per cycle, the damping ratio ζ = −ln a / 2π of its first mode
/// and the Kelvin–Voigt viscosity that damps a mode of ω = 2π/T at ζ in a material of shear
/// modulus μ, ν = 2ζμ/ω (the viscous stress 2ν ε̇ beside the elastic 2μ ε; the motion fitter's
/// own start from a rest sag uses the same relation, `palpate_motion::start`); the geometric
/// mean over the runs. `None` when no run rings.
pub fn viscosity_from_ring_down(runs: &[RunResidual], mu: f64) -> Option<f64> {
    let logs: Vec<f64> = runs
        .iter()
        .filter_map(|r| {
            let (t, a) = (r.period_s.0?, r.decay_per_cycle.0?);
            (t > 0.0 && a > 0.0 && a < 1.0).then(|| {
                let zeta = -a.ln() / (2.0 * std::f64::consts::PI);
                (2.0 * zeta * mu * t / (2.0 * std::f64::consts::PI)).ln()
            })
        })
        .filter(|v| v.is_finite())
        .collect();
    (!logs.is_empty() && mu > 0.0).then(|| (logs.iter().sum::<f64>() / logs.len() as f64).exp())
}

/// The ring-down's period and decay per cycle: the motion crate's estimate, the one that also
/// chooses the simulation's time step from the capture ([`palpate_motion::timestep`]).
pub use palpate_motion::timestep::ring_down;

#[cfg(test)]
mod tests {
    use super::{ring_down, viscosity_from_ring_down, RunResidual};

    #[test]
    fn ring_down_reads_period_and_decay_of_a_damped_sine() {
        let dt = 0.01;
        let (period, ratio) = (0.25, 0.7f64);
        let s: Vec<f64> = (0..500)
            .map(|n| {
                let t = n as f64 * dt;
                5.0 + 3.0 * ratio.powf(t / period) * (2.0 * std::f64::consts::PI * t / period).cos()
            })
            .collect();
        let (p, d) = ring_down(&s, dt);
        assert!((p.unwrap() / period - 1.0).abs() < 0.01, "{p:?}");
        assert!((d.unwrap() / ratio - 1.0).abs() < 0.03, "{d:?}");
        assert_eq!(ring_down(&[1.0; 100], dt), (None, None));
    }

    /// The viscosity start: ν = 2ζμ/ω with ζ = −ln a/2π, the geometric mean over the runs that
    /// ring, `None` when none does. A single-degree-of-freedom check: a mode of ω = 2π/T whose
    /// amplitude falls by a per cycle has ζ/√(1−ζ²) = −ln a/2π; at a = 0.72 (the beam) ζ differs
    /// from −ln a/2π by 0.14 %, well inside what a start needs.
    #[test]
    fn viscosity_start_follows_the_ring_down() {
        let run = |t: Option<f64>, a: Option<f64>| RunResidual {
            run: String::new(),
            rms_m: 0.0,
            chi2: 0.0,
            count: 0,
            per_marker_m: Vec::new(),
            early_m: 0.0,
            late_m: 0.0,
            final_rms_m: 0.0,
            load_n: 0.0,
            ring_marker: String::new(),
            period_s: (t, None),
            decay_per_cycle: (a, None),
            time_offset_s: 0.0,
            ring: (Vec::new(), Vec::new()),
            simulated: Default::default(),
        };
        let mu = 4.6e4;
        let one = viscosity_from_ring_down(&[run(Some(0.13), Some(0.72))], mu).unwrap();
        let zeta = -(0.72f64).ln() / (2.0 * std::f64::consts::PI);
        let omega = 2.0 * std::f64::consts::PI / 0.13;
        assert!((one - 2.0 * zeta * mu / omega).abs() < 1e-9 * one, "{one}");
        // A run twice as damped at the same period: twice the viscosity; the mean is geometric.
        let two = viscosity_from_ring_down(&[run(Some(0.13), Some(0.72 * 0.72))], mu).unwrap();
        assert!((two / one - 2.0).abs() < 1e-12);
        let both = viscosity_from_ring_down(
            &[
                run(Some(0.13), Some(0.72)),
                run(Some(0.13), Some(0.72 * 0.72)),
            ],
            mu,
        )
        .unwrap();
        assert!((both / (one * two).sqrt() - 1.0).abs() < 1e-12);
        // No ring-down, a growing one, or none measured: no estimate.
        assert_eq!(viscosity_from_ring_down(&[run(None, None)], mu), None);
        assert_eq!(
            viscosity_from_ring_down(&[run(Some(0.13), Some(1.1))], mu),
            None
        );
        assert_eq!(viscosity_from_ring_down(&[], mu), None);
    }
}

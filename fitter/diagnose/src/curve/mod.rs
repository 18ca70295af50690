//! Diagnosis of measured 1-D curves: tension / relaxation records, material
//! stress–strain tests and FSR calibrations. Same mechanism as the static diagnosis: fit the
//! simplest model the data declares (force ∝ displacement, stress ∝ strain, FSR conductance ∝
//! force through the divider), read the residual's signature ([`signature`]), refit every
//! candidate effect of the library ([`candidates`], on the [`model`]) with a small Levenberg–Marquardt ([`lm`], [`fit`]),
//! adopt the best one only if it lowers BIC and the held-out RMS by a margin ([`select`](mod@select)), repeat,
//! and report ([`report`]).
//!
//! Nothing about which effect is present comes from anywhere but the data: the format is read
//! from the header ([`read`]), every candidate the format admits is tried on every dataset.

pub mod candidates;
pub mod fit;
pub mod lm;
pub mod model;
pub mod read;
pub mod report;
pub mod run;
pub mod select;
pub mod signature;

use model::{Family, Model, Scale};
use read::{CurveData, Format, Group};
use select::{param_values, select, Errors, ParamValue, Step};
use std::path::Path;
use std::time::Instant;

/// The curve diagnosis's errors: the crate's one [`crate::Error`] (the name kept for its callers).
pub type CurveError = crate::Error;

/// Options.
#[derive(Debug, Clone, serde::Serialize)]
pub struct CurveOptions {
    /// Gauge length L0 of tension data, mm (`None`: fitted by the hyperelastic candidates).
    pub gauge_mm: Option<f64>,
    /// ADC resolution of FSR balance data, bits: the smallest resolution assumed; raised to the
    /// smallest one that holds the largest count in the data (stated in the report).
    pub adc_bits: u32,
    /// Samples kept per file (time series are thinned, see [`read::decimate`]).
    pub max_points: usize,
    /// Most effects adopted.
    pub max_effects: usize,
    /// ΔBIC must be below −this.
    pub bic_threshold: f64,
    /// Held-out RMS must drop by at least this fraction.
    pub min_holdout_gain: f64,
    /// Candidate names to try (`None`: all).
    pub candidates: Option<Vec<String>>,
    /// LM iterations of a full fit.
    pub max_iterations: usize,
    /// LM iterations of each held-out refit (warm-started).
    pub holdout_iterations: usize,
    /// Diagnose stress–strain files of a directory jointly (one specimen).
    pub joint: bool,
    /// Diagnose every file of a directory on its own.
    pub per_file: bool,
}

impl Default for CurveOptions {
    fn default() -> Self {
        Self {
            gauge_mm: None,
            adc_bits: 10,
            max_points: 600,
            max_effects: 3,
            bic_threshold: 10.0,
            min_holdout_gain: 0.05,
            candidates: None,
            max_iterations: 60,
            holdout_iterations: 25,
            joint: false,
            per_file: false,
        }
    }
}

/// The diagnosis of one dataset.
#[derive(Debug, Clone, serde::Serialize)]
pub struct CurveDiagnosis {
    /// Dataset name.
    pub name: String,
    /// Format.
    pub format: Format,
    /// Source files.
    pub sources: Vec<String>,
    /// Files/runs.
    pub groups: Vec<String>,
    /// Samples used (after thinning) and samples read.
    pub samples: (usize, usize),
    /// Unit of the response and of every error figure.
    pub unit: String,
    /// Selection rule in words.
    pub criterion: String,
    /// Held-out scheme in words.
    pub holdout: String,
    /// Rounds.
    pub steps: Vec<Step>,
    /// Effects adopted, in order.
    pub adopted: Vec<String>,
    /// Simplest model and its errors.
    pub before_model: String,
    /// Errors of the simplest model.
    pub before: Errors,
    /// Final model.
    pub after_model: String,
    /// Errors of the final model.
    pub after: Errors,
    /// Parameters of the simplest model.
    pub before_params: Vec<ParamValue>,
    /// Parameters of the final model.
    pub final_params: Vec<ParamValue>,
    /// Per file/run: (name, samples, held-out RMS of the simplest model, of the final model).
    pub per_group: Vec<(String, usize, f64, f64)>,
    /// Caveats stated with the result.
    pub notes: Vec<String>,
    /// Options.
    pub options: CurveOptions,
    /// Wall-clock seconds.
    pub seconds: f64,
    /// The data used (for plots).
    #[serde(skip)]
    pub data: Vec<Group>,
    /// The selection (fits, held-out predictions).
    #[serde(skip)]
    pub selection: Option<select::Selection>,
}

/// Diagnoses one dataset.
pub fn diagnose(
    data: &CurveData,
    o: &CurveOptions,
    log: &mut dyn FnMut(&str),
) -> Result<CurveDiagnosis, CurveError> {
    let t0 = Instant::now();
    let ts = data.format.is_time_series();
    let groups: Vec<Group> = data
        .groups
        .iter()
        .map(|g| {
            if ts {
                read::decimate(g, o.max_points)
            } else {
                g.clone()
            }
        })
        .collect();
    check_plausible(data, &groups)?;
    let bits = adc_bits(data, &groups, o)?;
    let x_max = groups
        .iter()
        .flat_map(|g| g.x.iter())
        .fold(0.0f64, |m, v| m.max(v.abs()));
    if x_max <= 0.0 {
        return Err(CurveError::Input(format!(
            "{}: the load variable is zero everywhere",
            data.name
        )));
    }
    let scale = Scale {
        x_max,
        duration: groups
            .iter()
            .map(|g| g.t.last().unwrap_or(&0.0) - g.t.first().unwrap_or(&0.0))
            .fold(0.0, f64::max),
        order_mean: groups.iter().map(|g| g.order).sum::<f64>() / groups.len() as f64,
    };
    let family = Family::of(data.format, o.gauge_mm, bits);
    let sel = select(Model::simplest(family, scale), &groups, ts, o, log)
        .ok_or_else(|| CurveError::Fit(data.name.clone()))?;
    let notes = notes(data, o, bits);
    // A residual that is not a finite number is no verdict: never "clean" with RMS inf.
    if let Some(e) = sel
        .errors
        .iter()
        .find(|e| !(e.fitted_rms.is_finite() && e.heldout_rms.is_finite()))
    {
        return Err(CurveError::Input(format!(
            "{}: the fit's residual is not finite (fitted RMS {}, held out {}): the data's \
             magnitudes are outside what the models can represent",
            data.name, e.fitted_rms, e.heldout_rms
        )));
    }
    Ok(diagnosis(data, o, groups, sel, notes, t0))
}

/// The ADC resolution of FSR balance data: the option's, raised to the smallest one that holds
/// the largest count (other formats: the option's, unused).
fn adc_bits(data: &CurveData, groups: &[Group], o: &CurveOptions) -> Result<u32, CurveError> {
    let mut bits = o.adc_bits.clamp(1, 31);
    if data.format == Format::FsrBalance {
        let top = groups
            .iter()
            .flat_map(|g| g.y.iter())
            .fold(0.0f64, |m, &c| m.max(c));
        while bits < 31 && f64::from((1u32 << bits) - 1) < top {
            bits += 1;
        }
        if f64::from((1u32 << bits) - 1) < top {
            return Err(CurveError::Input(format!(
                "{}: {top} counts exceed any 31-bit converter",
                data.name
            )));
        }
    }
    Ok(bits)
}

/// The caveats stated with the result: the reader's repairs, then what the format implies.
fn notes(data: &CurveData, o: &CurveOptions, bits: u32) -> Vec<String> {
    let ts = data.format.is_time_series();
    let mut notes = data.warnings.clone();
    match data.format {
        Format::Tension => {
            notes.push("The cross-section is unknown: moduli are effective force scales (modulus × area, N); the stretch is λ = 1 + Δ/L0.".into());
            notes.push(match o.gauge_mm {
                Some(l) => format!("Gauge length L0 = {l} mm (given)."),
                None => "Gauge length not given (--gauge-length): L0 is a fitted parameter of every hyperelastic law.".into(),
            });
        }
        Format::StressStrain => notes.push(
            "Engineering (nominal) stress against engineering strain, λ = 1 + ε (uniaxial, incompressible forms).".into(),
        ),
        Format::FsrBalance => notes.push(format!(
            "Response in ADC counts of a {bits}-bit converter (N = {}: {} bits assumed, raised to hold the largest count); force = mass × {} m/s².",
            (1u32 << bits) - 1,
            o.adc_bits,
            read::G_STANDARD
        )),
        Format::FsrDatasheet => notes.push("Response is ln R: errors are in natural-log units (0.1 ≈ 10 % in R).".into()),
    }
    if ts {
        notes.push("Parameter uncertainties assume independent residuals; samples of a time series are correlated, so they are lower bounds.".into());
    }
    notes
}

/// The diagnosis of `data` from its selection (`groups`: the samples used; `t0`: when it began).
fn diagnosis(
    data: &CurveData,
    o: &CurveOptions,
    groups: Vec<Group>,
    sel: select::Selection,
    notes: Vec<String>,
    t0: Instant,
) -> CurveDiagnosis {
    let first = &sel.fits[0];
    let last = sel.fits.last().expect("at least the simplest fit");
    let unit = data.format.labels().1.to_string();
    let held_rms = |k: usize, gi: usize| {
        let g = &groups[gi];
        let h = &sel.heldout[k][gi];
        let s: f64 = g.y.iter().zip(h).map(|(y, p)| (p - y) * (p - y)).sum();
        (s / g.y.len().max(1) as f64).sqrt()
    };
    let per_group = (0..groups.len())
        .map(|gi| {
            (
                groups[gi].name.clone(),
                groups[gi].x.len(),
                held_rms(0, gi),
                held_rms(sel.heldout.len() - 1, gi),
            )
        })
        .collect();
    CurveDiagnosis {
        name: data.name.clone(),
        format: data.format,
        sources: data.sources.iter().map(|p| p.display().to_string()).collect(),
        groups: groups.iter().map(|g| g.name.clone()).collect(),
        samples: (
            groups.iter().map(|g| g.x.len()).sum(),
            data.groups.iter().map(|g| g.x.len()).sum(),
        ),
        unit,
        criterion: format!(
            "adopt the candidate with the lowest held-out RMS among those with ΔBIC < −{} (BIC = n ln(RSS/n) + k ln n) and a held-out RMS ≥ {:.0} % below the current model's; repeat until none passes (at most {} effects)",
            o.bic_threshold,
            100.0 * o.min_holdout_gain,
            o.max_effects
        ),
        holdout: sel.holdout.clone(),
        adopted: sel
            .steps
            .iter()
            .filter_map(|s| s.adopted.map(|c| c.name()))
            .collect(),
        before_model: first.model.describe(),
        before: sel.errors[0],
        after_model: last.model.describe(),
        after: *sel.errors.last().expect("non-empty"),
        before_params: param_values(first),
        final_params: param_values(last),
        steps: sel.steps.clone(),
        per_group,
        notes,
        options: o.clone(),
        seconds: t0.elapsed().as_secs_f64(),
        data: groups,
        selection: Some(sel),
    }
}

/// The largest magnitude a load or response may have: its square must not overflow in a
/// residual sum, and no instrument of these formats reads anywhere near it (stresses in MPa,
/// forces in N, ADC counts, ln Ω).
pub const MAX_MAGNITUDE: f64 = 1e12;

/// Refuses data no model can be fitted to honestly: magnitudes whose squares overflow, and a
/// tension or stress–strain response that is negative throughout (compression, or a sign
/// convention the hyperelastic tension laws do not share — a law would be "adopted" for it).
fn check_plausible(data: &CurveData, groups: &[Group]) -> Result<(), CurveError> {
    for g in groups {
        for (k, (&x, &y)) in g.x.iter().zip(&g.y).enumerate() {
            if !(x.abs() <= MAX_MAGNITUDE && y.abs() <= MAX_MAGNITUDE) {
                let line = g.line.get(k).copied().unwrap_or(0);
                return Err(CurveError::Input(format!(
                    "{} ({}) line {line}: value {:e} outside ±{MAX_MAGNITUDE:e}: not a \
                     measurement of this kind (check the units and columns)",
                    data.name,
                    g.name,
                    if x.abs() > MAX_MAGNITUDE { x } else { y }
                )));
            }
        }
    }
    if matches!(data.format, Format::Tension | Format::StressStrain) {
        let (mut positive, mut negative) = (0usize, 0usize);
        for y in groups.iter().flat_map(|g| g.y.iter()) {
            if *y > 0.0 {
                positive += 1;
            } else if *y < 0.0 {
                negative += 1;
            }
        }
        if negative > 0 && positive == 0 {
            let (_, label) = data.format.labels();
            return Err(CurveError::Input(format!(
                "{}: the {label} is negative in all {negative} samples: a tension test pulls \
                 (positive response); if this is a compression test or another sign \
                 convention, flip the sign of the column",
                data.name
            )));
        }
    }
    Ok(())
}

/// Reads `path` (file or directory) and diagnoses every dataset in it.
pub fn diagnose_path(
    path: &Path,
    o: &CurveOptions,
    log: &mut dyn FnMut(&str),
) -> Result<Vec<CurveDiagnosis>, CurveError> {
    let sets = read::read_path(path, o.joint, o.per_file)?;
    let mut out = Vec::new();
    for d in &sets {
        log(&format!(
            "{}: {} ({} files/runs, {} samples)",
            d.name,
            d.format.name(),
            d.groups.len(),
            d.len()
        ));
        out.push(diagnose(d, o, log)?);
    }
    Ok(out)
}

//! FSR calibration (thesis §4.2, Fig. 4.4): fit the sensor response — force against sensor
//! conductance — from balance readings or published points, report residuals, the usable
//! range and every point left out with the reason, and produce the
//! [`palpate_protocol::link::Calibration`] the probe's config frame carries.

pub mod data;
pub mod fit;

use data::{Format, Point, Rig};
use palpate_protocol::link::{Calibration, Divider, ForceCurve, MAX_KNOTS};
use serde::Serialize;

/// Errors of FSR calibration.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum FsrError {
    /// The file could not be read.
    #[error("reading {path}: {source}")]
    Io {
        /// File.
        path: String,
        /// Cause.
        source: std::io::Error,
    },
    /// The file's content is malformed.
    #[error("{file}:{line}: {what}")]
    Format {
        /// File.
        file: String,
        /// 1-based line.
        line: usize,
        /// What is wrong, expected vs found.
        what: String,
    },
    /// Too few usable points to fit.
    #[error("{file}: only {usable} usable points after rejections, need at least 2 ({rejected} rejected)")]
    TooFewPoints {
        /// File.
        file: String,
        /// Points left.
        usable: usize,
        /// Points rejected.
        rejected: usize,
    },
    /// The fitted curve failed validation.
    #[error("fitted curve is invalid: {0}")]
    InvalidCurve(&'static str),
}

/// Which fitted curve goes into the calibration.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum CurveChoice {
    /// `F = a · G^b`.
    Power,
    /// Monotone piecewise-linear (isotonic regression).
    Monotone,
}

impl CurveChoice {
    /// Every choice, in the order a command line lists them.
    pub const ALL: [CurveChoice; 2] = [CurveChoice::Power, CurveChoice::Monotone];

    /// The name a command line uses (`power`, `monotone`).
    pub fn name(self) -> &'static str {
        match self {
            CurveChoice::Power => "power",
            CurveChoice::Monotone => "monotone",
        }
    }
}

impl std::fmt::Display for CurveChoice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for CurveChoice {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Self::ALL
            .into_iter()
            .find(|c| c.name() == s)
            .ok_or_else(|| format!("{s:?} is not a curve (expected power or monotone)"))
    }
}

/// A point the fit left out, and why.
#[derive(Debug, Clone, Serialize)]
pub struct Rejected {
    /// The point.
    pub point: Point,
    /// Why.
    pub reason: String,
}

/// Residual summary of one curve over the fitted points, in N.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Residuals {
    /// Root mean square.
    pub rms_n: f64,
    /// Largest magnitude.
    pub max_abs_n: f64,
    /// RMS of `(F_fit − F) / F`.
    pub rms_relative: f64,
}

/// The full result.
#[derive(Debug, Clone, Serialize)]
pub struct FsrFit {
    /// Input file.
    pub source: String,
    /// What the file held.
    pub format: Format,
    /// Points read.
    pub points: usize,
    /// Points used in the fit.
    pub fitted: Vec<Point>,
    /// Points left out, with reasons.
    pub rejected: Vec<Rejected>,
    /// Power law `(a, b)`, G in µS, F in N.
    pub power_law: (f64, f64),
    /// Its residuals.
    pub power_law_residuals: Residuals,
    /// Monotone knots `(G µS, F N)`.
    pub monotone_knots: Vec<(f64, f64)>,
    /// Their residuals.
    pub monotone_residuals: Residuals,
    /// Usable range `(F_lo, F_hi)`, N.
    pub usable_range_n: (f64, f64),
    /// Points for which the stated divider voltage disagrees with the stated resistance by
    /// more than 0.1 V (published tables only), with the computed voltage.
    pub divider_disagreements: Vec<(usize, f64, f64)>,
    /// The calibration written for the probe.
    pub calibration: Calibration,
}

/// Options of a fit.
#[derive(Debug, Clone, Copy)]
pub struct FitOptions {
    /// The rig count-based files were recorded on.
    pub rig: Rig,
    /// The probe's divider the calibration is for.
    pub target: Divider,
    /// Curve to put in the calibration.
    pub curve: CurveChoice,
    /// Outlier threshold in robust standard deviations of the log residual.
    pub outlier_sigmas: f64,
}

fn residuals(pts: &[(f64, f64)], model: impl Fn(f64) -> f64) -> Residuals {
    let n = pts.len().max(1) as f64;
    let (mut s, mut m, mut r) = (0.0f64, 0.0f64, 0.0f64);
    for &(g, f) in pts {
        let e = model(g) - f;
        s += e * e;
        m = m.max(e.abs());
        r += (e / f) * (e / f);
    }
    Residuals {
        rms_n: (s / n).sqrt(),
        max_abs_n: m,
        rms_relative: (r / n).sqrt(),
    }
}

/// Fits a calibration to the points of `source`.
pub fn calibrate(
    source: &str,
    format: Format,
    points: Vec<Point>,
    opts: &FitOptions,
) -> Result<FsrFit, FsrError> {
    let total = points.len();
    // Usable range from all readings with a conductance (saturated ones as +∞).
    let has_runs = points.iter().any(|p| p.run.is_some());
    let all: Vec<(f64, f64)> = points
        .iter()
        .map(|p| (p.conductance_us.unwrap_or(f64::INFINITY), p.force_n))
        .collect();
    let (lo, hi) = fit::usable_range(&all, if has_runs { 2 } else { 1 })
        .or_else(|| fit::usable_range(&all, 1))
        .ok_or_else(|| FsrError::TooFewPoints {
            file: source.into(),
            usable: 0,
            rejected: total,
        })?;

    let mut rejected = Vec::new();
    let mut kept = Vec::new();
    for p in points {
        let reason = match p.conductance_us {
            None => Some(format!("ADC saturated at {} counts: divider at the supply, conductance unbounded", opts.rig.full_count())),
            Some(_) if p.force_n == 0.0 => Some("zero load: fixes the curve's origin (0, 0), carries no slope information".into()),
            Some(g) if g <= 0.0 => Some("no conduction under load (below the FSR's turn-on force)".into()),
            Some(_) if p.force_n < lo * (1.0 - 1e-9) => {
                Some(format!("below the usable range ({lo:.3} N): response not yet monotone across runs"))
            }
            Some(_) if p.force_n > hi * (1.0 + 1e-9) => {
                Some(format!("above the usable range ({hi:.3} N): response flattened / turned over (FSR saturation)"))
            }
            Some(_) => None,
        };
        match reason {
            Some(reason) => rejected.push(Rejected { point: p, reason }),
            None => kept.push(p),
        }
    }
    // Robust outlier pass on the log residual of a first power-law fit.
    let pairs = |v: &[Point]| {
        v.iter()
            .map(|p| (p.conductance_us.unwrap_or(0.0), p.force_n))
            .collect::<Vec<_>>()
    };
    let too_few = |kept: &[Point], rejected: &[Rejected]| FsrError::TooFewPoints {
        file: source.into(),
        usable: kept.len(),
        rejected: rejected.len(),
    };
    let (a0, b0) = fit::power_law(&pairs(&kept)).ok_or_else(|| too_few(&kept, &rejected))?;
    let logres: Vec<f64> = kept
        .iter()
        .map(|p| (p.force_n / (a0 * p.conductance_us.unwrap_or(0.0).powf(b0))).ln())
        .collect();
    let med = fit::median(&logres);
    let sigma = 1.4826 * fit::median(&logres.iter().map(|r| (r - med).abs()).collect::<Vec<_>>());
    if kept.len() >= 5 && sigma > 0.0 {
        let mut next = Vec::new();
        for (p, r) in kept.into_iter().zip(&logres) {
            let z = (r - med) / sigma;
            if z.abs() > opts.outlier_sigmas {
                rejected.push(Rejected {
                    reason: format!(
                        "outlier: log residual {z:+.1} robust σ (threshold {})",
                        opts.outlier_sigmas
                    ),
                    point: p,
                });
            } else {
                next.push(p);
            }
        }
        kept = next;
    }
    let pts = pairs(&kept);
    let (a, b) = fit::power_law(&pts).ok_or_else(|| too_few(&kept, &rejected))?;
    let blocks = fit::isotonic(&pts);
    let knots = fit::knots(&blocks, MAX_KNOTS);
    let power_res = residuals(&pts, |g| a * g.powf(b));
    let mono_res = residuals(&pts, |g| fit::eval_knots(&knots, g));

    let divider_disagreements = kept
        .iter()
        .chain(rejected.iter().map(|r| &r.point))
        .filter_map(|p| {
            let v = p.divider_v?;
            let g = p.conductance_us? * 1e-6 * opts.rig.r_pulldown_ohm;
            let want = opts.rig.v_supply_v * g / (1.0 + g);
            ((want - v).abs() > 0.1).then_some((p.line, v, want))
        })
        .collect();

    let curve = match opts.curve {
        CurveChoice::Power => ForceCurve::PowerLaw {
            gain: a as f32,
            exponent: b as f32,
        },
        CurveChoice::Monotone => {
            let mut gs = [0.0f32; MAX_KNOTS];
            let mut fs = [0.0f32; MAX_KNOTS];
            for (i, &(g, f)) in knots.iter().enumerate() {
                gs[i] = g as f32;
                fs[i] = f as f32;
            }
            ForceCurve::Monotone {
                len: knots.len() as u8,
                conductance_us: gs,
                force_n: fs,
            }
        }
    };
    let calibration = Calibration {
        divider: opts.target,
        curve,
        usable_min_n: lo as f32,
        usable_max_n: hi as f32,
    };
    calibration.validate().map_err(FsrError::InvalidCurve)?;
    rejected.sort_by_key(|r| r.point.line);
    Ok(FsrFit {
        source: source.into(),
        format,
        points: total,
        fitted: kept,
        rejected,
        power_law: (a, b),
        power_law_residuals: power_res,
        monotone_knots: knots,
        monotone_residuals: mono_res,
        usable_range_n: (lo, hi),
        divider_disagreements,
        calibration,
    })
}

/// Reads the `calibration` field of a file written by `palpate calibrate-fsr -o`.
pub fn read_calibration_json(path: &std::path::Path) -> Result<Calibration, FsrError> {
    let name = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|e| FsrError::Io {
        path: name.clone(),
        source: e,
    })?;
    #[derive(serde::Deserialize)]
    struct File {
        calibration: Calibration,
    }
    let f: File = serde_json::from_str(&text).map_err(|e| FsrError::Format {
        file: name.clone(),
        line: e.line(),
        what: format!("not a calibration file: {e}"),
    })?;
    f.calibration.validate().map_err(|what| FsrError::Format {
        file: name,
        line: 0,
        what: format!("calibration: {what}"),
    })?;
    Ok(f.calibration)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn synthetic_balance_runs_recover_the_law_and_reject_saturation() {
        // Three runs of an exact power law F = 0.05 · G^0.8 read by a 10-bit / 5 V / 10 kΩ rig
        // at 100 … 800 g, plus one saturated reading: the fit must recover a and b to the
        // quantisation of the counts (rounding to whole counts moves G by < 1 %, so a to 3 %
        // and b to 1 %) and reject exactly the saturated and zero points.
        let rig = Rig {
            adc_bits: 10,
            v_supply_v: 5.0,
            r_pulldown_ohm: 10_000.0,
        };
        let mut csv = String::from("run,adc_counts,reference_mass_g\n");
        for run in 1..=3 {
            csv += &format!("{run},0,0\n");
            for m in (100..=800).step_by(100) {
                let f = m as f64 * 1e-3 * data::G_STANDARD;
                let g: f64 = (f / 0.05).powf(1.0 / 0.8) * 1e-6 * 1e4;
                let counts = (1023.0 * g / (1.0 + g)).round();
                csv += &format!("{run},{counts},{m}\n");
            }
        }
        csv += "3,1023,1500\n";
        let (format, pts) = data::parse_csv(&csv, "synthetic.csv", &rig).unwrap();
        let opts = FitOptions {
            rig,
            target: Divider {
                r_pulldown_ohm: 1e4,
                v_supply_v: 3.3,
            },
            curve: CurveChoice::Power,
            outlier_sigmas: 3.5,
        };
        let fit = calibrate("synthetic.csv", format, pts, &opts).unwrap();
        let (a, b) = fit.power_law;
        assert!(
            (a / 0.05 - 1.0).abs() < 0.03 && (b - 0.8).abs() < 0.01,
            "a={a} b={b}"
        );
        assert_eq!(fit.rejected.len(), 4, "{:?}", fit.rejected);
        assert!(
            (fit.usable_range_n.0 - 0.981).abs() < 1e-9
                && (fit.usable_range_n.1 - 7.848).abs() < 1e-9
        );
        assert!(fit.power_law_residuals.rms_relative < 0.01);
    }

    #[test]
    fn malformed_rows_name_file_line_and_field() {
        let rig = Rig {
            adc_bits: 10,
            v_supply_v: 5.0,
            r_pulldown_ohm: 10_000.0,
        };
        let e = data::parse_csv("run,adc_counts,reference_mass_g\n1,12x,5\n", "f.csv", &rig)
            .unwrap_err();
        assert_eq!(
            e.to_string(),
            "f.csv:2: field \"adc_counts\" = \"12x\" is not a number"
        );
        let e = data::parse_csv("run,adc_counts,reference_mass_g\n1,2000,5\n", "f.csv", &rig)
            .unwrap_err();
        assert_eq!(
            e.to_string(),
            "f.csv:2: adc_counts 2000 above the 10-bit full scale 1023"
        );
        let e = data::parse_csv("a,b\n", "f.csv", &rig).unwrap_err();
        assert!(e.to_string().starts_with("f.csv:1: unknown header"));
    }

    /// A spreadsheet's table: columns in another order and case, fields quoted. The values are
    /// read by column name, and an error names the file, the line and the column as the file
    /// spells it.
    #[test]
    fn columns_by_name_in_any_order_and_quoted_fields() {
        let rig = Rig {
            adc_bits: 10,
            v_supply_v: 5.0,
            r_pulldown_ohm: 10_000.0,
        };
        let text = "\"Reference_Mass_g\",run,\"ADC_counts\"\n\"100\",2,\"500\"\n";
        let (format, pts) = data::parse_csv(text, "f.csv", &rig).unwrap();
        assert_eq!(format, Format::BalanceCounts);
        assert_eq!(
            (pts[0].line, pts[0].run, pts[0].counts),
            (2, Some(2), Some(500.0))
        );
        assert!((pts[0].force_n - 0.1 * data::G_STANDARD).abs() < 1e-12);
        let e = data::parse_csv(
            "divider_output_V,force_N,resistance_ohm\n1.5,2,300\n\"1.7\",3,\"3x0\"\n",
            "f.csv",
            &rig,
        )
        .unwrap_err();
        assert_eq!(
            e.to_string(),
            "f.csv:3: field \"resistance_ohm\" = \"3x0\" is not a number"
        );
    }
}

//! Reading FSR calibration tables: balance readings against sensor counts (thesis §4.2,
//! Fig. 4.4a) or published force/resistance points.

use super::FsrError;
use palpate_fem::io::csv;
use std::path::Path;

/// The rig a count-based calibration was recorded on.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Rig {
    /// ADC resolution in bits (full scale = 2^bits − 1 counts = supply).
    pub adc_bits: u32,
    /// Divider supply, V.
    pub v_supply_v: f64,
    /// Pull-down resistor, Ω.
    pub r_pulldown_ohm: f64,
}

impl Rig {
    /// The largest count (saturation).
    pub fn full_count(&self) -> f64 {
        f64::from((1u32 << self.adc_bits) - 1)
    }
    /// Divider voltage of a count.
    pub fn volts(&self, counts: f64) -> f64 {
        self.v_supply_v * counts / self.full_count()
    }
    /// Conductance in µS for a divider voltage, `None` at or above the supply.
    pub fn conductance_us(&self, v: f64) -> Option<f64> {
        (v < self.v_supply_v)
            .then(|| 1e6 * v.max(0.0) / (self.r_pulldown_ohm * (self.v_supply_v - v)))
    }
}

/// Standard gravity, m/s² (thesis §4.2: force = m · g).
pub const G_STANDARD: f64 = 9.81;

/// One calibration point.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Point {
    /// Line in the file (1-based, header = 1).
    pub line: usize,
    /// Run number, when the file has runs.
    pub run: Option<u32>,
    /// Raw ADC counts, when the file has them.
    pub counts: Option<f64>,
    /// Reference force, N.
    pub force_n: f64,
    /// Sensor conductance, µS (`None`: saturated, unbounded).
    pub conductance_us: Option<f64>,
    /// Divider output the file states, V (published points only).
    pub divider_v: Option<f64>,
}

/// What kind of table a file held.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum Format {
    /// `run,adc_counts,reference_mass_g`: balance calibration through an ADC.
    BalanceCounts,
    /// `force_N,resistance_ohm,divider_output_V`: published sensor points.
    ForceResistance,
}

/// Reads a calibration CSV; the header picks the format.
pub fn read_csv(path: &Path, rig: &Rig) -> Result<(Format, Vec<Point>), FsrError> {
    let text = std::fs::read_to_string(path).map_err(|e| FsrError::Io {
        path: path.display().to_string(),
        source: e,
    })?;
    parse_csv(&text, &path.display().to_string(), rig)
}

/// The two tables' columns, each format's in the order [`parse_csv`] reads them (lower case; a
/// file may spell them in any case and list them in any order).
const COLUMNS: [(Format, [&str; 3]); 2] = [
    (
        Format::BalanceCounts,
        ["run", "adc_counts", "reference_mass_g"],
    ),
    (
        Format::ForceResistance,
        ["force_n", "resistance_ohm", "divider_output_v"],
    ),
];

/// Parses calibration CSV text (`name` is used in errors): the shared CSV layer's records
/// (quoted fields, a spreadsheet's byte-order mark), the format told by the header's column
/// names in any order.
pub fn parse_csv(text: &str, name: &str, rig: &Rig) -> Result<(Format, Vec<Point>), FsrError> {
    let format_error = |line: usize, what: String| FsrError::Format {
        file: name.into(),
        line,
        what,
    };
    let records = csv::parse(text, false)
        .map_err(|(line, why)| format_error(line, format!("malformed CSV: {why}")))?;
    let mut records = records.into_iter();
    let (hline, header) = records
        .next()
        .ok_or_else(|| format_error(1, "empty file".into()))?;
    let cols: Vec<String> = header.iter().map(|c| c.to_ascii_lowercase()).collect();
    let same_set = |names: &[&str; 3]| {
        cols.len() == names.len() && names.iter().all(|n| cols.iter().any(|c| c == n))
    };
    let Some((format, names)) = COLUMNS.iter().find(|(_, names)| same_set(names)) else {
        return Err(format_error(
            hline,
            format!(
                "unknown header {:?}: expected the columns run,adc_counts,reference_mass_g or \
                 force_N,resistance_ohm,divider_output_V, in any order",
                header.join(",")
            ),
        ));
    };
    let format = *format;
    // Where each of the format's columns sits in this file.
    let at = names.map(|n| cols.iter().position(|c| c == n).unwrap_or_default());
    let mut points = Vec::new();
    for (line, f) in records {
        if f.len() != cols.len() {
            return Err(format_error(
                line,
                format!("expected {} fields, found {}", cols.len(), f.len()),
            ));
        }
        let num = |k: usize| -> Result<f64, FsrError> {
            let s = &f[at[k]];
            let v: f64 = s.parse().map_err(|_| {
                format_error(
                    line,
                    format!("field {:?} = {s:?} is not a number", header[at[k]]),
                )
            })?;
            if !v.is_finite() || v < 0.0 {
                return Err(format_error(
                    line,
                    format!("field {:?} = {v} must be finite and >= 0", header[at[k]]),
                ));
            }
            Ok(v)
        };
        points.push(match format {
            Format::BalanceCounts => {
                let counts = num(1)?;
                if counts > rig.full_count() {
                    return Err(FsrError::Format {
                        file: name.into(),
                        line,
                        what: format!(
                            "adc_counts {counts} above the {}-bit full scale {}",
                            rig.adc_bits,
                            rig.full_count()
                        ),
                    });
                }
                let conductance_us = if counts >= rig.full_count() {
                    None
                } else {
                    rig.conductance_us(rig.volts(counts))
                };
                Point {
                    line,
                    run: Some(num(0)? as u32),
                    counts: Some(counts),
                    force_n: num(2)? * 1e-3 * G_STANDARD,
                    conductance_us,
                    divider_v: None,
                }
            }
            Format::ForceResistance => {
                let r = num(1)?;
                if r == 0.0 {
                    return Err(FsrError::Format {
                        file: name.into(),
                        line,
                        what: "resistance_ohm must be > 0".into(),
                    });
                }
                Point {
                    line,
                    run: None,
                    counts: None,
                    force_n: num(0)?,
                    conductance_us: Some(1e6 / r),
                    divider_v: Some(num(2)?),
                }
            }
        });
    }
    if points.is_empty() {
        return Err(FsrError::Format {
            file: name.into(),
            line: hline + 1,
            what: "no data rows".into(),
        });
    }
    Ok((format, points))
}

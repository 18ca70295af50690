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

/// Parses calibration CSV text (`name` is used in errors).
pub fn parse_csv(text: &str, name: &str, rig: &Rig) -> Result<(Format, Vec<Point>), FsrError> {
    let mut lines = csv::records(text, false);
    let (_, header) = lines.next().ok_or_else(|| FsrError::Format {
        file: name.into(),
        line: 1,
        what: "empty file".into(),
    })?;
    let cols: Vec<String> = csv::fields(header)
        .into_iter()
        .map(str::to_ascii_lowercase)
        .collect();
    let format = match cols.iter().map(String::as_str).collect::<Vec<_>>().as_slice() {
        ["run", "adc_counts", "reference_mass_g"] => Format::BalanceCounts,
        ["force_n", "resistance_ohm", "divider_output_v"] => Format::ForceResistance,
        _ => {
            return Err(FsrError::Format {
                file: name.into(),
                line: 1,
                what: format!(
                    "unknown header {header:?}: expected run,adc_counts,reference_mass_g or force_N,resistance_ohm,divider_output_V"
                ),
            })
        }
    };
    let mut points = Vec::new();
    for (line, l) in lines {
        let f = csv::fields(l);
        let num = |k: usize| -> Result<f64, FsrError> {
            let s = f.get(k).ok_or_else(|| FsrError::Format {
                file: name.into(),
                line,
                what: format!("expected {} fields, found {}", cols.len(), f.len()),
            })?;
            let v: f64 = s.parse().map_err(|_| FsrError::Format {
                file: name.into(),
                line,
                what: format!("field {:?} = {s:?} is not a number", cols[k]),
            })?;
            if !v.is_finite() || v < 0.0 {
                return Err(FsrError::Format {
                    file: name.into(),
                    line,
                    what: format!("field {:?} = {v} must be finite and >= 0", cols[k]),
                });
            }
            Ok(v)
        };
        if f.len() != cols.len() {
            return Err(FsrError::Format {
                file: name.into(),
                line,
                what: format!("expected {} fields, found {}", cols.len(), f.len()),
            });
        }
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
            line: 2,
            what: "no data rows".into(),
        });
    }
    Ok((format, points))
}

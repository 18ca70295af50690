//! Reading measured curves: the header picks the format, every bad cell is reported with its
//! file, line and column (its position and name). Files are read through the one CSV layer of
//! the offline tools ([`palpate_fem::io::csv::parse`], the `csv` crate): columns found by their
//! header names in any order and any letter case, quoted fields (`"a,b"` is one field). A
//! directory contributes every `*.csv` it holds (not recursively).
//!
//! | header columns (any order, extra columns ignored) | format | x | y |
//! |---|---|---|---|
//! | `time_s, displacement_mm, force_N` | tension / relaxation | Δ (mm) | F (N) |
//! | `engineering_strain, engineering_stress_MPa` (+ `time_s`) | stress–strain | ε | P (MPa) |
//! | `run, adc_counts, reference_mass_g` | FSR balance runs | F = m g (N) | counts |
//! | `force_N, resistance_ohm` | FSR datasheet points | F (N) | ln R (ln Ω) |

use super::CurveError;
use palpate_fem::io::csv::{self, NumberError};
use std::path::{Path, PathBuf};

/// Standard gravity for balance readings, m/s².
pub const G_STANDARD: f64 = 9.81;

/// What kind of measurement a file holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum Format {
    /// Grip displacement and force against time (loading/unloading, relaxation).
    Tension,
    /// Engineering stress against engineering strain (material test of one specimen).
    StressStrain,
    /// FSR in a pull-down divider read by an ADC, pressed with a balance; several runs.
    FsrBalance,
    /// Published FSR force/resistance points.
    FsrDatasheet,
}

impl Format {
    /// Short name.
    pub fn name(self) -> &'static str {
        match self {
            Format::Tension => "tension",
            Format::StressStrain => "stress-strain",
            Format::FsrBalance => "fsr-balance",
            Format::FsrDatasheet => "fsr-datasheet",
        }
    }
    /// (x label, y label) with units.
    pub fn labels(self) -> (&'static str, &'static str) {
        match self {
            Format::Tension => ("displacement (mm)", "force (N)"),
            Format::StressStrain => ("engineering strain", "engineering stress (MPa)"),
            Format::FsrBalance => ("reference force (N)", "ADC counts"),
            Format::FsrDatasheet => ("force (N)", "ln resistance (ln Ω)"),
        }
    }
    /// Whether the samples form a time series (so rate effects can be integrated).
    pub fn is_time_series(self) -> bool {
        matches!(self, Format::Tension | Format::StressStrain)
    }
}

/// One file (or one run of a multi-run file): samples in recording order.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Group {
    /// File stem, or `file#run`.
    pub name: String,
    /// Run number (FSR) or position in the file list; used by the drift model.
    pub order: f64,
    /// Time, s (sample index when the format has no time).
    pub t: Vec<f64>,
    /// Load variable (see the module table).
    pub x: Vec<f64>,
    /// Measured response.
    pub y: Vec<f64>,
    /// 1-based line of each sample in its file.
    pub line: Vec<usize>,
}

/// A dataset of curves of one format.
#[derive(Debug, Clone, serde::Serialize)]
pub struct CurveData {
    /// Name (file stem or directory name + format).
    pub name: String,
    /// Format.
    pub format: Format,
    /// Groups (files or runs).
    pub groups: Vec<Group>,
    /// Source files.
    pub sources: Vec<PathBuf>,
    /// Repairs made while reading, with their location.
    pub warnings: Vec<String>,
}

impl CurveData {
    /// Number of samples.
    pub fn len(&self) -> usize {
        self.groups.iter().map(|g| g.x.len()).sum()
    }
    /// Whether there are no samples.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Whether `path` is something the curve diagnosis reads: a `.csv` file, or a directory with CSV
/// files and no `dataset.toml` (that one is a static FEM dataset).
pub fn is_curve_input(path: &Path) -> bool {
    if path.is_dir() {
        !path.join("dataset.toml").exists() && !csv_files(path).unwrap_or_default().is_empty()
    } else {
        path.extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("csv"))
    }
}

fn csv_files(dir: &Path) -> Result<Vec<PathBuf>, CurveError> {
    let rd = std::fs::read_dir(dir).map_err(|e| CurveError::Io {
        path: dir.display().to_string(),
        message: e.to_string(),
    })?;
    let mut v: Vec<PathBuf> = rd
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file() && p.extension().is_some_and(|e| e.eq_ignore_ascii_case("csv")))
        .collect();
    v.sort();
    Ok(v)
}

/// Reads the format of a CSV header line, `None` if it is none of the known ones.
pub fn detect(header: &str) -> Option<Format> {
    let cols = csv::parse(header, false)
        .ok()?
        .into_iter()
        .next()
        .map_or_else(Vec::new, |(_, fields)| names(&fields));
    format_of(&cols)
}

/// Column names as the formats spell them: lower case (`force_N` and `force_n` are one column).
fn names(header: &[String]) -> Vec<String> {
    header.iter().map(|c| c.to_ascii_lowercase()).collect()
}

fn format_of(cols: &[String]) -> Option<Format> {
    let has = |n: &str| cols.iter().any(|c| c == n);
    if has("run") && has("adc_counts") && has("reference_mass_g") {
        Some(Format::FsrBalance)
    } else if has("force_n") && has("resistance_ohm") {
        Some(Format::FsrDatasheet)
    } else if has("engineering_strain") && has("engineering_stress_mpa") {
        Some(Format::StressStrain)
    } else if has("time_s") && has("displacement_mm") && has("force_n") {
        Some(Format::Tension)
    } else {
        None
    }
}

/// The columns a format reads, by name: the load, response and run columns it needs and, for
/// stress–strain, the optional time.
fn needed(format: Format) -> &'static [&'static str] {
    match format {
        Format::Tension => &["time_s", "displacement_mm", "force_n"],
        Format::StressStrain => &["engineering_strain", "engineering_stress_mpa"],
        Format::FsrBalance => &["run", "adc_counts", "reference_mass_g"],
        Format::FsrDatasheet => &["force_n", "resistance_ohm"],
    }
}

/// One data row of a file being read: its cells and where it is, so every error names the file,
/// the line and the column (its 1-based position and its name).
struct Cells<'a> {
    file: &'a str,
    line: usize,
    cells: &'a [String],
    width: usize,
}

impl Cells<'_> {
    fn error(&self, message: String) -> CurveError {
        CurveError::Format {
            file: self.file.into(),
            line: self.line,
            message,
        }
    }

    /// The finite number in column `c` (0-based) named `col`.
    fn number(&self, c: usize, col: &str) -> Result<f64, CurveError> {
        let s = self.cells.get(c).ok_or_else(|| {
            self.error(format!(
                "column {} `{col}` missing: expected {} cells, found {}",
                c + 1,
                self.width,
                self.cells.len()
            ))
        })?;
        csv::finite(s).map_err(|e| {
            self.error(match e {
                NumberError::NotANumber => {
                    format!("column {} `{col}`: expected a number, found {s:?}", c + 1)
                }
                NumberError::NotFinite => {
                    format!("column {} `{col}`: value {s} is not finite", c + 1)
                }
            })
        })
    }

    fn bad(&self, c: usize, col: &str, what: String) -> CurveError {
        self.error(format!("column {} `{col}`: {what}", c + 1))
    }
}

/// Where a format's columns sit in one file.
struct Layout {
    format: Format,
    /// Position of each of [`needed`]'s columns.
    pos: Vec<usize>,
    /// Position of `time_s`, if the file has it.
    time: Option<usize>,
}

impl Layout {
    /// One sample of a row: (run, t, x, y); `t` of a stress–strain file without time is `None`.
    fn sample(&self, row: &Cells<'_>) -> Result<(f64, Option<f64>, f64, f64), CurveError> {
        let need = needed(self.format);
        let at = |k: usize| row.number(self.pos[k], need[k]);
        Ok(match self.format {
            Format::Tension => (0.0, Some(at(0)?), at(1)?, at(2)?),
            Format::StressStrain => {
                let t = match self.time {
                    Some(c) => Some(row.number(c, "time_s")?),
                    None => None,
                };
                (0.0, t, at(0)?, at(1)?)
            }
            Format::FsrBalance => {
                let (run, counts, mass) = (at(0)?, at(1)?, at(2)?);
                if counts < 0.0 {
                    let why = format!("expected ≥ 0 counts, found {counts}");
                    return Err(row.bad(self.pos[1], need[1], why));
                }
                if mass < 0.0 {
                    let why = format!("expected a mass ≥ 0 g, found {mass}");
                    return Err(row.bad(self.pos[2], need[2], why));
                }
                (run, Some(0.0), mass * 1e-3 * G_STANDARD, counts)
            }
            Format::FsrDatasheet => {
                let (f, r) = (at(0)?, at(1)?);
                if f <= 0.0 {
                    let why = format!("expected a force > 0 N, found {f}");
                    return Err(row.bad(self.pos[0], need[0], why));
                }
                if r <= 0.0 {
                    let why = format!("expected a resistance > 0 Ω, found {r}");
                    return Err(row.bad(self.pos[1], need[1], why));
                }
                (0.0, Some(0.0), f, r.ln())
            }
        })
    }
}

/// Parses one file's text into groups (`name` is used in errors and group names): the header
/// line names the columns, in any order and any letter case, extra columns ignored; fields may
/// be quoted (`"a,b"` is one field). Returns the format, the groups and warnings (repairs made,
/// with their location).
pub fn parse(text: &str, name: &str) -> Result<(Format, Vec<Group>, Vec<String>), CurveError> {
    let located = |line: usize, message: String| CurveError::Format {
        file: name.into(),
        line,
        message,
    };
    let records = csv::parse(text, false)
        .map_err(|(line, why)| located(line, format!("malformed CSV: {why}")))?;
    let mut records = records.into_iter();
    let (hline, header) = records
        .next()
        .ok_or_else(|| located(1, "empty file: expected a header line".into()))?;
    let cols = names(&header);
    let format = format_of(&cols).ok_or_else(|| {
        located(
            hline,
            format!(
                "unknown header {:?}: expected the columns `time_s,displacement_mm,force_N` \
                 (tension), `engineering_strain,engineering_stress_MPa` (stress–strain), \
                 `run,adc_counts,reference_mass_g` (FSR balance) or `force_N,resistance_ohm` \
                 (FSR points)",
                header.join(",")
            ),
        )
    })?;
    let idx = |n: &str| cols.iter().position(|c| c == n);
    let layout = Layout {
        format,
        pos: needed(format)
            .iter()
            .map(|n| idx(n).unwrap_or(usize::MAX))
            .collect(),
        time: idx("time_s"),
    };
    let stem = Path::new(name)
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| name.to_string());
    let mut groups: Vec<Group> = Vec::new();
    let mut warnings = Vec::new();
    for (line, cells) in records {
        let row = Cells {
            file: name,
            line,
            cells: &cells,
            width: cols.len(),
        };
        let (run, t, x, y) = layout.sample(&row)?;
        let gname = if format == Format::FsrBalance {
            format!("{stem}#run{run}")
        } else {
            stem.clone()
        };
        let g = match groups.iter().position(|g| g.name == gname) {
            Some(i) => &mut groups[i],
            None => {
                groups.push(Group {
                    name: gname,
                    order: run,
                    t: vec![],
                    x: vec![],
                    y: vec![],
                    line: vec![],
                });
                groups.last_mut().expect("just pushed")
            }
        };
        let t = if format.is_time_series() {
            // A stress–strain file without time counts samples (of its first group).
            let t = t.unwrap_or(g.t.len() as f64);
            check_time(&row, layout.time.unwrap_or(0), format, g, t, &mut warnings)?;
            t
        } else {
            g.t.len() as f64
        };
        g.t.push(t);
        g.x.push(x);
        g.y.push(y);
        g.line.push(line);
    }
    check_groups(&groups, name)?;
    if !warnings.is_empty() {
        retime(&mut groups);
    }
    Ok((format, groups, warnings))
}

/// Time must not go backwards within a group. Stress–strain: time is auxiliary (the load variable
/// is the strain), so a broken time column is repaired ([`retime`]) with a warning instead of
/// rejected.
fn check_time(
    row: &Cells<'_>,
    time_col: usize,
    format: Format,
    g: &Group,
    t: f64,
    warnings: &mut Vec<String>,
) -> Result<(), CurveError> {
    let Some(&prev) = g.t.last() else {
        return Ok(());
    };
    if t < prev && format == Format::StressStrain {
        if !warnings.iter().any(|w| w.starts_with(row.file)) {
            warnings.push(format!(
                "{}:{}: column `time_s` goes backwards ({t} s after {prev} s): time replaced by sample index × median positive step",
                row.file, row.line
            ));
        }
    } else if t < prev {
        let why = format!("time goes backwards: {t} s after {prev} s");
        return Err(row.bad(time_col, "time_s", why));
    }
    Ok(())
}

/// Every group needs 3 samples, and the file at least one group.
fn check_groups(groups: &[Group], name: &str) -> Result<(), CurveError> {
    for g in groups {
        if g.x.len() < 3 {
            return Err(CurveError::Format {
                file: name.into(),
                line: g.line.first().copied().unwrap_or(1),
                message: format!(
                    "{}: expected at least 3 samples, found {}",
                    g.name,
                    g.x.len()
                ),
            });
        }
    }
    if groups.is_empty() {
        return Err(CurveError::Format {
            file: name.into(),
            line: 2,
            message: "no data rows after the header".into(),
        });
    }
    Ok(())
}

/// Rebuilds each group's time from its sample index × its median positive step.
fn retime(groups: &mut [Group]) {
    for g in groups {
        let mut steps: Vec<f64> =
            g.t.windows(2)
                .map(|w| w[1] - w[0])
                .filter(|d| *d > 0.0)
                .collect();
        steps.sort_by(f64::total_cmp);
        let dt = steps.get(steps.len() / 2).copied().unwrap_or(1.0);
        let t0 = g.t[0];
        for (i, t) in g.t.iter_mut().enumerate() {
            *t = t0 + i as f64 * dt;
        }
    }
}

/// Reads one CSV file.
pub fn read_file(path: &Path) -> Result<CurveData, CurveError> {
    let text = std::fs::read_to_string(path).map_err(|e| CurveError::Io {
        path: path.display().to_string(),
        message: e.to_string(),
    })?;
    let (format, groups, warnings) = parse(&text, &path.display().to_string())?;
    let stem = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    Ok(CurveData {
        name: stem,
        format,
        groups,
        sources: vec![path.to_path_buf()],
        warnings,
    })
}

/// Reads a file, or every CSV of a directory grouped by format (one [`CurveData`] per format).
/// Files of one format in one directory are taken as tests of one specimen (one sensor), so they
/// share the model parameters — except stress–strain files, each a complete material test of its
/// own specimen, which are diagnosed one by one unless `joint` is set. `per_file` splits every
/// format into single files.
pub fn read_path(path: &Path, joint: bool, per_file: bool) -> Result<Vec<CurveData>, CurveError> {
    if !path.is_dir() {
        return Ok(vec![read_file(path)?]);
    }
    let files = csv_files(path)?;
    if files.is_empty() {
        return Err(CurveError::Input(format!(
            "{}: no .csv files in the directory",
            path.display()
        )));
    }
    let dir_name = path
        .file_name()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "curves".into());
    let mut out: Vec<CurveData> = Vec::new();
    let mut skipped: Vec<String> = Vec::new();
    // Index in `out` of the joint dataset of each format.
    let mut joint_of: Vec<(Format, usize)> = Vec::new();
    for f in &files {
        // In a directory, a CSV whose header is none of the formats (notes, exports of other
        // tools) is skipped with a warning; a recognised file with a bad cell is still an error.
        let head = std::fs::read_to_string(f)
            .ok()
            .and_then(|t| t.lines().find(|l| !l.trim().is_empty()).map(str::to_string));
        if head.as_deref().and_then(detect).is_none() {
            skipped.push(format!(
                "{}:1: header is none of the known formats: skipped",
                f.display()
            ));
            continue;
        }
        let mut d = read_file(f)?;
        let split = per_file || (d.format == Format::StressStrain && !joint);
        if split {
            out.push(d);
            continue;
        }
        match joint_of
            .iter()
            .find(|(fm, _)| *fm == d.format)
            .map(|&(_, i)| i)
        {
            Some(i) => {
                let o = &mut out[i];
                let base = o.groups.len() as f64;
                for g in &mut d.groups {
                    if d.format != Format::FsrBalance {
                        g.order = base;
                    }
                }
                o.groups.append(&mut d.groups);
                o.sources.push(f.clone());
                o.warnings.append(&mut d.warnings);
            }
            None => {
                d.name = format!("{dir_name}-{}", d.format.name());
                joint_of.push((d.format, out.len()));
                out.push(d);
            }
        }
    }
    if out.is_empty() {
        return Err(CurveError::Input(format!(
            "{}: no .csv file with a known header ({})",
            path.display(),
            skipped.join("; ")
        )));
    }
    for d in &mut out {
        d.warnings.extend(skipped.iter().cloned());
        if d.format != Format::FsrBalance {
            for (i, g) in d.groups.iter_mut().enumerate() {
                g.order = i as f64;
            }
        }
    }
    Ok(out)
}

/// Thins a time series to at most about `max_points` samples, keeping every sample where the
/// load variable or the time has advanced by 1/`max_points` of its range since the last kept
/// one: ramps keep their resolution in x, holds keep theirs in time. The first and last samples
/// are kept.
pub fn decimate(g: &Group, max_points: usize) -> Group {
    let n = g.x.len();
    if n <= max_points || max_points < 3 {
        return g.clone();
    }
    let range = |v: &[f64]| {
        let (lo, hi) = v
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
                (a.min(x), b.max(x))
            });
        (hi - lo).max(f64::MIN_POSITIVE)
    };
    // Half the budget for each axis: a sample advancing both counts once.
    let dx = 2.0 * range(&g.x) / max_points as f64;
    let dt = 2.0 * range(&g.t) / max_points as f64;
    let mut keep = vec![0usize];
    for i in 1..n {
        let k = *keep.last().expect("non-empty");
        if (g.x[i] - g.x[k]).abs() >= dx || (g.t[i] - g.t[k]).abs() >= dt || i == n - 1 {
            keep.push(i);
        }
    }
    let pick = |v: &[f64]| keep.iter().map(|&i| v[i]).collect::<Vec<_>>();
    Group {
        name: g.name.clone(),
        order: g.order,
        t: pick(&g.t),
        x: pick(&g.x),
        y: pick(&g.y),
        line: keep.iter().map(|&i| g.line[i]).collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::{parse, Format};
    use crate::Error;

    /// A field quoted because it holds a comma (a spreadsheet's note column) is one field, so
    /// the columns after it keep their places; the columns are found by name in any order and
    /// letter case.
    #[test]
    fn quoted_fields_hold_commas_and_columns_come_in_any_order() {
        let text = "specimen,Force_N,\"time_s\",displacement_mm\n\
                    \"strip A, 80 mm\",0.0,0.0,0.0\n\
                    \"strip A, 80 mm\",0.5,0.1,1.0\n\
                    \"strip A, 80 mm\",1.0,0.2,2.0\n";
        let (format, groups, warnings) = parse(text, "quoted.csv").unwrap();
        assert_eq!(format, Format::Tension);
        assert!(warnings.is_empty(), "{warnings:?}");
        let g = &groups[0];
        assert_eq!(
            (g.t.as_slice(), g.x.as_slice()),
            (&[0.0, 0.1, 0.2][..], &[0.0, 1.0, 2.0][..])
        );
        assert_eq!(
            (g.y.as_slice(), g.line.as_slice()),
            (&[0.0, 0.5, 1.0][..], &[2, 3, 4][..])
        );
    }

    /// A bad cell names the file, its line, and the column by position and name.
    #[test]
    fn a_bad_cell_names_file_line_and_column() {
        let text = "specimen,time_s,displacement_mm,force_N\n\
                    \"strip A, 80 mm\",0,0,0\n\
                    \"strip A, 80 mm\",0.1,0.5,abc\n";
        match parse(text, "bad.csv") {
            Err(Error::Format {
                file,
                line,
                message,
            }) => {
                assert_eq!((file.as_str(), line), ("bad.csv", 3));
                assert!(
                    message.starts_with("column 4 `force_n`: ") && message.contains("\"abc\""),
                    "{message}"
                );
            }
            other => panic!("expected a located format error, got {other:?}"),
        }
    }
}

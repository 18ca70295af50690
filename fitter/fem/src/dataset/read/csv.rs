//! A minimal CSV reader for the dataset files: comma-separated, no quoting (ids hold no commas),
//! blank lines and lines starting with `#` ignored, a header line that must name the columns
//! exactly. Every value it hands out knows its file, line and column name, so errors can say so.

use super::DatasetError;
use std::path::{Path, PathBuf};

/// One data row.
pub(super) struct Row<'a> {
    pub file: &'a Path,
    /// 1-based line number.
    pub line: usize,
    header: &'a [&'a str],
    fields: Vec<&'a str>,
}

impl<'a> Row<'a> {
    fn field_error(&self, col: usize, expected: &str) -> DatasetError {
        DatasetError::Field {
            file: self.file.to_path_buf(),
            line: self.line,
            field: self.header[col].to_string(),
            expected: expected.to_string(),
            found: format!("{:?}", self.fields[col]),
        }
    }

    /// Whether column `col` is present and non-empty in this row (optional trailing columns).
    pub fn has(&self, col: usize) -> bool {
        self.fields.get(col).is_some_and(|f| !f.is_empty())
    }

    /// A non-empty identifier.
    pub fn id(&self, col: usize) -> Result<&'a str, DatasetError> {
        let s = self.fields[col];
        if s.is_empty() {
            return Err(self.field_error(col, "a non-empty id"));
        }
        Ok(s)
    }

    /// A finite number.
    pub fn number(&self, col: usize) -> Result<f64, DatasetError> {
        match self.fields[col].parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(v),
            Ok(_) => {
                Err(self.field_error(col, "a finite number (NaN and infinities are not allowed)"))
            }
            Err(_) => Err(self.field_error(col, "a number")),
        }
    }

    /// Three finite numbers from consecutive columns.
    pub fn vec3(&self, col: usize) -> Result<[f64; 3], DatasetError> {
        Ok([
            self.number(col)?,
            self.number(col + 1)?,
            self.number(col + 2)?,
        ])
    }

    /// A finite, strictly positive number.
    pub fn positive(&self, col: usize) -> Result<f64, DatasetError> {
        let v = self.number(col)?;
        if v > 0.0 {
            Ok(v)
        } else {
            Err(self.field_error(col, "a positive number"))
        }
    }
}

/// A parsed CSV file: header checked, rows split.
pub(super) struct Table {
    pub file: PathBuf,
    text: String,
}

impl Table {
    /// Reads `file`.
    pub fn read(file: PathBuf) -> Result<Table, DatasetError> {
        let text = std::fs::read_to_string(&file).map_err(|source| DatasetError::Io {
            file: file.clone(),
            source,
        })?;
        Ok(Table { file, text })
    }

    /// The rows after checking that the header is the first `header.len() - optional` names
    /// followed by some of the `optional` ones; each row must have at least the required fields
    /// and at most as many as the header (a missing or empty optional field takes its default).
    pub fn rows<'a>(
        &'a self,
        header: &'a [&'a str],
        optional: usize,
    ) -> Result<Vec<Row<'a>>, DatasetError> {
        let mut lines = self
            .text
            .lines()
            .enumerate()
            .map(|(i, l)| (i + 1, l.trim()))
            .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'));
        let (hline, found) = lines.next().unwrap_or((1, ""));
        let cols: Vec<&str> = found.split(',').map(str::trim).collect();
        let required = header.len() - optional;
        let ok = cols.len() >= required
            && cols.len() <= header.len()
            && cols.iter().zip(header).all(|(a, b)| a == b);
        if !ok {
            let expected = if optional > 0 {
                format!("{} (the last {} optional)", header.join(","), optional)
            } else {
                header.join(",")
            };
            return Err(DatasetError::Field {
                file: self.file.clone(),
                line: hline,
                field: "header".into(),
                expected: format!("the header line {expected:?}"),
                found: format!("{found:?}"),
            });
        }
        let width = cols.len();
        let mut rows = Vec::new();
        for (line, l) in lines {
            let fields: Vec<&str> = l.split(',').map(str::trim).collect();
            if fields.len() < required || fields.len() > width {
                let count = if required >= width {
                    format!("{width}")
                } else {
                    format!("{required} to {width}")
                };
                return Err(DatasetError::Field {
                    file: self.file.clone(),
                    line,
                    field: "row".into(),
                    expected: format!(
                        "{count} comma-separated fields ({})",
                        header[..width].join(",")
                    ),
                    found: format!("{} fields: {l:?}", fields.len()),
                });
            }
            rows.push(Row {
                file: &self.file,
                line,
                header,
                fields,
            });
        }
        Ok(rows)
    }
}

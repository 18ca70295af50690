//! The one CSV layer of the offline tools: comma-separated, no quoting (ids and numbers hold no
//! commas), 1-based line numbers kept for every record so errors can name `file:line`.
//!
//! - [`records`] and [`fields`]: the tokenizer every reader uses (blank lines skipped; `#` comment
//!   lines skipped where the format allows them);
//! - [`finite`]: a finite number, or why not;
//! - [`Table`] / [`Row`]: a header that must name the columns exactly and typed fields whose
//!   errors read ``file:line: field `name`: expected …, found …`` ([`CsvError::Field`]) — the static
//!   datasets use it; the motion datasets, measured curves and FSR tables keep their own column
//!   rules (alternative headers, any column order, per-format messages) on top of the tokenizer.

use std::path::{Path, PathBuf};

/// The non-blank records of `text` as (1-based line, trimmed line); with `comments`, lines whose
/// first non-blank character is `#` are skipped too. A leading UTF-8 byte-order mark is not part
/// of the first record: spreadsheet programs (Excel's "CSV UTF-8") write one, and the header
/// check would otherwise read `\u{feff}marker` where `marker` is.
pub fn records(text: &str, comments: bool) -> impl Iterator<Item = (usize, &str)> {
    text.strip_prefix('\u{feff}')
        .unwrap_or(text)
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(move |(_, l)| !(l.is_empty() || (comments && l.starts_with('#'))))
}

/// The comma-separated fields of a record, each trimmed.
pub fn fields(record: &str) -> Vec<&str> {
    record.split(',').map(str::trim).collect()
}

/// Why a field is not a finite number.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NumberError {
    /// It does not parse as a number.
    NotANumber,
    /// It parses, but as NaN or an infinity.
    NotFinite,
}

/// A finite number from a field.
pub fn finite(s: &str) -> Result<f64, NumberError> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        Ok(_) => Err(NumberError::NotFinite),
        Err(_) => Err(NumberError::NotANumber),
    }
}

/// Errors of [`Table`]: the file could not be read, or a field is wrong.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CsvError {
    /// A file could not be read.
    #[error("{file}: cannot read: {source}")]
    Io {
        /// The file.
        file: PathBuf,
        /// The operating-system error.
        source: std::io::Error,
    },
    /// A value (or the header, or a row's field count) is malformed.
    #[error("{file}:{line}: field `{field}`: expected {expected}, found {found}")]
    Field {
        /// The file.
        file: PathBuf,
        /// 1-based line.
        line: usize,
        /// Column name (`header` or `row` for the shape of a line).
        field: String,
        /// What is allowed.
        expected: String,
        /// What the file holds.
        found: String,
    },
}

/// One data row.
pub struct Row<'a> {
    pub file: &'a Path,
    /// 1-based line number.
    pub line: usize,
    header: &'a [&'a str],
    fields: Vec<&'a str>,
}

impl<'a> Row<'a> {
    fn field_error(&self, col: usize, expected: &str) -> CsvError {
        CsvError::Field {
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
    pub fn id(&self, col: usize) -> Result<&'a str, CsvError> {
        let s = self.fields[col];
        if s.is_empty() {
            return Err(self.field_error(col, "a non-empty id"));
        }
        Ok(s)
    }

    /// A finite number.
    pub fn number(&self, col: usize) -> Result<f64, CsvError> {
        finite(self.fields[col]).map_err(|e| match e {
            NumberError::NotFinite => {
                self.field_error(col, "a finite number (NaN and infinities are not allowed)")
            }
            NumberError::NotANumber => self.field_error(col, "a number"),
        })
    }

    /// Three finite numbers from consecutive columns.
    pub fn vec3(&self, col: usize) -> Result<[f64; 3], CsvError> {
        Ok([
            self.number(col)?,
            self.number(col + 1)?,
            self.number(col + 2)?,
        ])
    }

    /// A finite, strictly positive number.
    pub fn positive(&self, col: usize) -> Result<f64, CsvError> {
        let v = self.number(col)?;
        if v > 0.0 {
            Ok(v)
        } else {
            Err(self.field_error(col, "a positive number"))
        }
    }
}

/// A parsed CSV file: header checked, rows split.
pub struct Table {
    pub file: PathBuf,
    text: String,
}

impl Table {
    /// Reads `file`.
    pub fn read(file: PathBuf) -> Result<Table, CsvError> {
        let text = std::fs::read_to_string(&file).map_err(|source| CsvError::Io {
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
    ) -> Result<Vec<Row<'a>>, CsvError> {
        let mut lines = records(&self.text, true);
        let (hline, found) = lines.next().unwrap_or((1, ""));
        let cols = fields(found);
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
            return Err(CsvError::Field {
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
            let fields = fields(l);
            if fields.len() < required || fields.len() > width {
                let count = if required >= width {
                    format!("{width}")
                } else {
                    format!("{required} to {width}")
                };
                return Err(CsvError::Field {
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

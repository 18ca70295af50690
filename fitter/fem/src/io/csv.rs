//! The one CSV layer of the offline tools, 1-based line numbers kept for every record so errors can
//! name `file:line`.
//!
//! - [`parse`]: whole files through the `csv` crate — quoted fields (`"m0"` is the id `m0`, and
//!   `"a,b"` one field), blank lines and `#` comment lines skipped; the dataset readers use it;
//! - [`records`] and [`fields`]: a line tokenizer without quoting, for the measured curves' tables
//!   (their readers sniff the header line before choosing columns);
//! - [`finite`]: a finite number, or why not;
//! - [`Table`] / [`Row`]: columns found by their header names in any order, and typed fields whose
//!   errors read ``file:line: field `name`: expected …, found …`` ([`CsvError::Field`]) — the static
//!   datasets use it; the motion datasets keep their own column rules (alternative headers) on top
//!   of [`parse`].

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

/// The non-blank records of a whole CSV file as (1-based line, fields), each field unquoted and
/// trimmed; with `comments`, lines starting with `#` are skipped. A leading UTF-8 byte-order mark
/// is dropped (see [`records`]). A malformed record is returned as its line and the reason.
pub fn parse(text: &str, comments: bool) -> Result<Vec<(usize, Vec<String>)>, (usize, String)> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    // Comment lines are blanked here rather than skipped by the csv reader, so that a record's
    // byte offset still counts every line before it: errors must name the file's line.
    let blanked: String;
    let text = if comments {
        blanked = text
            .split_inclusive('\n')
            .map(|l| {
                if l.trim_start().starts_with('#') {
                    if l.ends_with("\r\n") {
                        "\r\n"
                    } else if l.ends_with('\n') {
                        "\n"
                    } else {
                        ""
                    }
                } else {
                    l
                }
            })
            .collect();
        blanked.as_str()
    } else {
        text
    };
    let mut b = csv::ReaderBuilder::new();
    b.has_headers(false).flexible(true).trim(csv::Trim::All);
    let mut out = Vec::new();
    for rec in b.from_reader(text.as_bytes()).records() {
        // The line from the byte offset: the reader's own line count skips blank lines, and a
        // record's offset is where the reader began looking for it — before the line ends it
        // skipped on the way, which belong to the lines above.
        let line = |p: Option<&csv::Position>| {
            p.map_or(0, |p| {
                let bytes = text.as_bytes();
                let mut at = (p.byte() as usize).min(bytes.len());
                while at < bytes.len() && matches!(bytes[at], b'\r' | b'\n') {
                    at += 1;
                }
                bytes[..at].iter().filter(|&&c| c == b'\n').count() + 1
            })
        };
        let rec = rec.map_err(|e| (line(e.position()), e.to_string()))?;
        // A line of blanks (or of empty fields only) is not a record.
        if rec.iter().all(str::is_empty) {
            continue;
        }
        out.push((line(rec.position()), rec.iter().map(String::from).collect()));
    }
    Ok(out)
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

/// One data row, its fields in the order of the header the reader asked for.
pub struct Row<'a> {
    pub file: &'a Path,
    /// 1-based line number.
    pub line: usize,
    header: &'a [&'a str],
    /// An optional column the file does not have is an empty field.
    fields: Vec<String>,
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
    pub fn id(&self, col: usize) -> Result<&str, CsvError> {
        let s = self.fields[col].as_str();
        if s.is_empty() {
            return Err(self.field_error(col, "a non-empty id"));
        }
        Ok(s)
    }

    /// A finite number.
    pub fn number(&self, col: usize) -> Result<f64, CsvError> {
        finite(&self.fields[col]).map_err(|e| match e {
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

    /// A whole number ≥ 0 (a Gmsh node tag, a count).
    pub fn unsigned(&self, col: usize) -> Result<u64, CsvError> {
        self.fields[col]
            .parse()
            .map_err(|_| self.field_error(col, "a whole number >= 0"))
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

    /// Whether the file holds no record at all (only blank and `#` comment lines).
    pub fn is_blank(&self) -> bool {
        records(&self.text, true).next().is_none()
    }

    /// The rows, their fields in the order of `header`, whose last `optional` names may be
    /// missing from the file (their fields are then empty). The file's header line names its
    /// columns in any order; a column the reader does not know, a column named twice or a
    /// required column missing is an error naming the header's line. Each row holds at most as
    /// many fields as the header and at least up to its last required column.
    pub fn rows<'a>(
        &'a self,
        header: &'a [&'a str],
        optional: usize,
    ) -> Result<Vec<Row<'a>>, CsvError> {
        let records = parse(&self.text, true).map_err(|(line, why)| CsvError::Field {
            file: self.file.clone(),
            line,
            field: "row".into(),
            expected: "well-formed CSV (every quote closed)".into(),
            found: why,
        })?;
        let mut records = records.into_iter();
        let (hline, cols) = records.next().unwrap_or((1, Vec::new()));
        let required = header.len() - optional;
        // Where each of `header`'s columns sits in the file.
        let mut at: Vec<Option<usize>> = vec![None; header.len()];
        let mut problem = None;
        for (pos, name) in cols.iter().enumerate() {
            match header.iter().position(|h| h == name) {
                Some(k) if at[k].is_none() => at[k] = Some(pos),
                Some(_) => problem = Some(format!("column {name:?} named twice")),
                None => problem = Some(format!("unknown column {} {name:?}", pos + 1)),
            }
        }
        if let Some(k) = (0..required).find(|&k| at[k].is_none()) {
            problem.get_or_insert(format!("no column {:?}", header[k]));
        }
        if let Some(problem) = problem {
            let expected = if optional > 0 {
                format!("{} (the last {} optional)", header.join(","), optional)
            } else {
                header.join(",")
            };
            return Err(CsvError::Field {
                file: self.file.clone(),
                line: hline,
                field: "header".into(),
                expected: format!("the header line {expected:?}, its columns in any order"),
                found: format!("{:?}: {problem}", cols.join(",")),
            });
        }
        let width = cols.len();
        // A row may stop after the last required column (optional trailing fields left out).
        let needed = at[..required].iter().flatten().max().map_or(0, |p| p + 1);
        let mut rows = Vec::new();
        for (line, fields) in records {
            if fields.len() < needed || fields.len() > width {
                let count = if needed >= width {
                    format!("{width}")
                } else {
                    format!("{needed} to {width}")
                };
                return Err(CsvError::Field {
                    file: self.file.clone(),
                    line,
                    field: "row".into(),
                    expected: format!("{count} comma-separated fields ({})", cols.join(",")),
                    found: format!("{} fields: {:?}", fields.len(), fields.join(",")),
                });
            }
            let fields = at
                .iter()
                .map(|p| p.and_then(|p| fields.get(p).cloned()).unwrap_or_default())
                .collect();
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

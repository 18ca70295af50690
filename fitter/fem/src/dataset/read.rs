//! Reading and validating a static dataset folder (format: `docs/dataset.md`).
//!
//! Every rejection names the file, the line and the field, and says what was expected and what
//! was found. Checks, in order: `dataset.toml` (syntax, known keys, units = "SI", positive probe
//! radius, non-negative noise); the mesh (via [`read_msh`]: syntax, tetrahedra only, zero-volume or
//! inverted elements); the fixed group (present and not empty); `markers.csv` (numbers, duplicate
//! ids, distance to the surface); `contacts.csv` (numbers, duplicate measurement ids, positive
//! radius, a radius that loads at least one node under the runtime's contact rule);
//! `measurements.csv` (numbers, unknown markers, measurements without a contact, a marker measured
//! twice); finally every contact must have at least one measured marker.

use super::embed::{
    embed_point, embedding_tolerance, median_surface_edge, EMBED_TOLERANCE_FRACTION,
};
use super::{Marker, Measurement, StaticDataset};
use crate::io::csv::{CsvError, Table};
use crate::mesh::gmsh::{read_msh, MeshError};
use crate::mesh::Mesh;
use palpate_runtime::contact_rule::{contact_weights, lumped_surface_areas, ContactRuleError};
use serde::Deserialize;
use std::collections::HashMap;
use std::hash::Hash;
use std::path::{Path, PathBuf};
use toml::Spanned;

/// Name of the metadata file in a dataset folder.
pub const DATASET_TOML: &str = "dataset.toml";
/// Name of the marker file.
pub const MARKERS_CSV: &str = "markers.csv";
/// Name of the measured-positions file.
pub const MEASUREMENTS_CSV: &str = "measurements.csv";
/// Name of the contact file.
pub const CONTACTS_CSV: &str = "contacts.csv";

/// Why a dataset could not be read or written. Every variant names the file; those about content
/// also name the line (1-based) and the field.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DatasetError {
    /// A file could not be read.
    #[error("{file}: cannot read: {source}")]
    Io {
        /// The file.
        file: PathBuf,
        /// The operating-system error.
        source: std::io::Error,
    },
    /// `dataset.toml` is not valid TOML or misses/misspells a key.
    #[error("{file}:{line}: {message}")]
    Toml {
        /// The file.
        file: PathBuf,
        /// 1-based line.
        line: usize,
        /// The TOML parser's message (names the key).
        message: String,
    },
    /// A value is malformed or out of range.
    #[error("{file}:{line}: field `{field}`: expected {expected}, found {found}")]
    Field {
        /// The file.
        file: PathBuf,
        /// 1-based line.
        line: usize,
        /// Column or key name.
        field: String,
        /// What is allowed.
        expected: String,
        /// What the file holds.
        found: String,
    },
    /// An id appears twice where it must be unique.
    #[error("{file}:{line}: field `{field}`: {id:?} appears twice (first on line {first_line})")]
    DuplicateId {
        /// The file.
        file: PathBuf,
        /// 1-based line of the repetition.
        line: usize,
        /// The id column.
        field: String,
        /// The repeated id (for measurements.csv: "measurement/marker").
        id: String,
        /// Line of the first occurrence.
        first_line: usize,
    },
    /// `measurements.csv` names a marker that `markers.csv` does not define.
    #[error("{file}:{line}: field `marker`: unknown marker {marker:?} (not in markers.csv)")]
    UnknownMarker {
        /// The file.
        file: PathBuf,
        /// 1-based line.
        line: usize,
        /// The marker id.
        marker: String,
    },
    /// `measurements.csv` names a measurement that `contacts.csv` does not define.
    #[error("{file}:{line}: field `measurement`: measurement {measurement:?} has no contact in contacts.csv")]
    MeasurementWithoutContact {
        /// The file.
        file: PathBuf,
        /// 1-based line.
        line: usize,
        /// The measurement id.
        measurement: String,
    },
    /// A contact has no measured marker at all.
    #[error(
        "{file}:{line}: field `measurement`: contact {measurement:?} has no rows in measurements.csv; every measurement needs at least one observed marker"
    )]
    ContactWithoutMeasurements {
        /// The file (contacts.csv).
        file: PathBuf,
        /// 1-based line of the contact.
        line: usize,
        /// The measurement id.
        measurement: String,
    },
    /// A marker's rest position is too far from the mesh surface to embed it.
    #[error(
        "{file}:{line}: fields `x,y,z`: marker {marker:?} is {distance:.3e} m from the mesh surface; the tolerance is {tolerance:.3e} m ({fraction} × median surface edge {median_edge:.3e} m, plus the declared `marker_standoff`): markers on posts or stand-offs need `marker_standoff = <height in m>` in dataset.toml; otherwise check the units and frame",
        fraction = EMBED_TOLERANCE_FRACTION
    )]
    MarkerFarFromSurface {
        /// The file.
        file: PathBuf,
        /// 1-based line.
        line: usize,
        /// The marker id.
        marker: String,
        /// Its distance to the surface (m).
        distance: f64,
        /// The tolerance (m).
        tolerance: f64,
        /// The mesh's median boundary edge length (m).
        median_edge: f64,
    },
    /// The fixed group is missing from the mesh or holds no node.
    #[error("{file}:{line}: field `clamps`: {problem}")]
    FixedGroup {
        /// The file (dataset.toml).
        file: PathBuf,
        /// 1-based line of the key.
        line: usize,
        /// What is wrong.
        problem: String,
    },
    /// The contact rule loads no node for this contact.
    #[error(
        "{file}:{line}: field `radius`: contact {measurement:?} loads no node: no free surface node within {radius:.3e} m of the contact point (nearest at {nearest:.3e} m)"
    )]
    ContactCoversNoNode {
        /// The file (contacts.csv).
        file: PathBuf,
        /// 1-based line.
        line: usize,
        /// The measurement id.
        measurement: String,
        /// The probe radius used (m).
        radius: f64,
        /// Distance to the nearest free surface node (m).
        nearest: f64,
    },
    /// The mesh file is invalid (the error names the mesh file and where).
    #[error(transparent)]
    Mesh(#[from] MeshError),
    /// Writing a dataset file failed.
    #[error("{file}: cannot write: {message}")]
    Write {
        /// The file.
        file: PathBuf,
        /// The underlying error chain.
        message: String,
    },
}

impl From<CsvError> for DatasetError {
    fn from(e: CsvError) -> Self {
        match e {
            CsvError::Io { file, source } => DatasetError::Io { file, source },
            CsvError::Field {
                file,
                line,
                field,
                expected,
                found,
            } => DatasetError::Field {
                file,
                line,
                field,
                expected,
                found,
            },
        }
    }
}

/// `dataset.toml`, with the position of every value for error messages.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct DatasetToml {
    name: Spanned<String>,
    #[serde(default)]
    description: Option<String>,
    units: Spanned<String>,
    mesh: Spanned<String>,
    /// The fixed group; `clamps = ["group"]` (the motion datasets' key) says the same.
    #[serde(default)]
    fixed_group: Option<Spanned<String>>,
    #[serde(default)]
    clamps: Option<Spanned<Vec<String>>>,
    probe_radius: Spanned<f64>,
    #[serde(default)]
    marker_noise: Option<Spanned<f64>>,
    #[serde(default)]
    gravity: Option<Spanned<[f64; 3]>>,
    #[serde(default)]
    marker_standoff: Option<Spanned<f64>>,
}

fn line_of(text: &str, offset: usize) -> usize {
    text.as_bytes()[..offset.min(text.len())]
        .iter()
        .filter(|&&b| b == b'\n')
        .count()
        + 1
}

/// Where in `dataset.toml` a value stands, for errors that name its line.
struct TomlAt<'a> {
    file: &'a Path,
    text: &'a str,
}

impl TomlAt<'_> {
    fn line(&self, span: std::ops::Range<usize>) -> usize {
        line_of(self.text, span.start)
    }

    fn field(
        &self,
        key: &str,
        span: std::ops::Range<usize>,
        expected: &str,
        found: String,
    ) -> DatasetError {
        DatasetError::Field {
            file: self.file.to_path_buf(),
            line: self.line(span),
            field: key.to_string(),
            expected: expected.to_string(),
            found,
        }
    }

    fn fixed_group(&self, line: usize, problem: String) -> DatasetError {
        DatasetError::FixedGroup {
            file: self.file.to_path_buf(),
            line,
            problem,
        }
    }
}

/// The scalar fields of `dataset.toml`, checked.
struct Header {
    probe_radius: f64,
    marker_noise: Option<f64>,
    marker_standoff: Option<f64>,
    gravity: Option<[f64; 3]>,
}

impl StaticDataset {
    /// Reads and validates the dataset folder `dir` (see the module docs for the checks).
    pub fn read(dir: impl AsRef<Path>) -> Result<StaticDataset, DatasetError> {
        let dir = dir.as_ref();
        let toml_file = dir.join(DATASET_TOML);
        let text = std::fs::read_to_string(&toml_file).map_err(|source| DatasetError::Io {
            file: toml_file.clone(),
            source,
        })?;
        let meta: DatasetToml = toml::from_str(&text).map_err(|e| DatasetError::Toml {
            file: toml_file.clone(),
            line: e.span().map(|s| line_of(&text, s.start)).unwrap_or(1),
            message: e.message().trim().to_string(),
        })?;
        let toml_at = TomlAt {
            file: &toml_file,
            text: &text,
        };
        let header = check_header(&meta, &toml_at)?;
        let probe_radius = header.probe_radius;
        let mesh = read_msh(dir.join(meta.mesh.get_ref()))?;
        let (fixed_group, fixed_span) = fixed_group(&meta, &toml_at)?;
        let fixed_nodes = fixed_nodes(&mesh, &fixed_group, &fixed_span, &meta, &toml_at)?;
        let surface = mesh.boundary_triangles();

        // Lengths are bounded by the object: a probe wider than the whole mesh, or a marker
        // that moves farther than the object is long, is in other units or another frame.
        let size = crate::sanity::bounding_diagonal(&mesh.nodes);
        if probe_radius > size {
            return Err(toml_at.field(
                "probe_radius",
                meta.probe_radius.span(),
                &format!("a radius at most the mesh's size ({size:.4e} m box diagonal)"),
                format!("{} m", crate::sanity::show(probe_radius)),
            ));
        }
        let markers = read_markers(
            &dir.join(MARKERS_CSV),
            &mesh,
            &surface,
            header.marker_standoff,
        )?;
        let (mut measurements, contact_lines) = read_contacts(
            &dir.join(CONTACTS_CSV),
            &mesh,
            &surface,
            &fixed_nodes,
            probe_radius,
        )?;
        read_measurements(
            &dir.join(MEASUREMENTS_CSV),
            &markers,
            &mut measurements,
            size,
        )?;
        for (m, line) in measurements.iter().zip(contact_lines) {
            if m.observed.is_empty() {
                return Err(DatasetError::ContactWithoutMeasurements {
                    file: dir.join(CONTACTS_CSV),
                    line,
                    measurement: m.id.clone(),
                });
            }
        }
        Ok(StaticDataset {
            marker_standoff: header.marker_standoff,
            name: meta.name.into_inner(),
            description: meta.description.unwrap_or_default(),
            mesh,
            fixed_group,
            fixed_nodes,
            surface,
            probe_radius,
            marker_noise: header.marker_noise,
            gravity: header.gravity,
            markers,
            measurements,
        })
    }
}

/// Checks `dataset.toml`'s scalar fields: units, probe radius, marker noise and standoff,
/// gravity.
fn check_header(meta: &DatasetToml, toml_at: &TomlAt<'_>) -> Result<Header, DatasetError> {
    if meta.units.get_ref() != "SI" {
        return Err(toml_at.field(
            "units",
            meta.units.span(),
            "\"SI\" (metres, newtons, seconds)",
            format!("{:?}", meta.units.get_ref()),
        ));
    }
    let probe_radius = *meta.probe_radius.get_ref();
    if !(probe_radius.is_finite() && probe_radius > 0.0) {
        return Err(toml_at.field(
            "probe_radius",
            meta.probe_radius.span(),
            "a positive length in m",
            probe_radius.to_string(),
        ));
    }
    // An optional length, when given, must be finite and ≥ 0.
    let non_negative = |key: &str, value: &Option<Spanned<f64>>, expected: &str| match value {
        Some(s) if !(s.get_ref().is_finite() && *s.get_ref() >= 0.0) => {
            Err(toml_at.field(key, s.span(), expected, s.get_ref().to_string()))
        }
        Some(s) => Ok(Some(*s.get_ref())),
        None => Ok(None),
    };
    let marker_noise = non_negative(
        "marker_noise",
        &meta.marker_noise,
        "a non-negative length in m",
    )?;
    let marker_standoff = non_negative(
        "marker_standoff",
        &meta.marker_standoff,
        "a non-negative height in m",
    )?;
    let gravity = match &meta.gravity {
        Some(g) if !g.get_ref().iter().all(|v| v.is_finite()) => {
            return Err(toml_at.field(
                "gravity",
                g.span(),
                "three finite numbers (m/s²)",
                format!("{:?}", g.get_ref()),
            ))
        }
        Some(g) => Some(*g.get_ref()),
        None => None,
    };
    Ok(Header {
        probe_radius,
        marker_noise,
        marker_standoff,
        gravity,
    })
}

/// The fixed group's nodes: the group must be in the mesh and hold a node.
fn fixed_nodes(
    mesh: &Mesh,
    fixed_group: &str,
    fixed_span: &std::ops::Range<usize>,
    meta: &DatasetToml,
    toml_at: &TomlAt<'_>,
) -> Result<Vec<usize>, DatasetError> {
    match mesh.node_groups.get(fixed_group) {
        None => Err(toml_at.fixed_group(
            toml_at.line(fixed_span.clone()),
            format!(
                "the mesh {} has no physical group {:?} (groups present: {})",
                meta.mesh.get_ref(),
                fixed_group,
                mesh.node_groups
                    .keys()
                    .map(|k| format!("{k:?}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        )),
        Some(n) if n.is_empty() => Err(toml_at.fixed_group(
            toml_at.line(fixed_span.clone()),
            format!("physical group {fixed_group:?} of the mesh holds no node"),
        )),
        Some(n) => Ok(n.clone()),
    }
}

/// The fixed group's name and where it stands: one schema with the motion datasets,
/// `clamps = ["group"]` or the older `fixed_group`.
fn fixed_group(
    meta: &DatasetToml,
    toml_at: &TomlAt<'_>,
) -> Result<(String, std::ops::Range<usize>), DatasetError> {
    match (&meta.fixed_group, &meta.clamps) {
        (Some(g), None) => {
            log::warn!(
                "{}:{}: `fixed_group` is the older name of `clamps = [{:?}]`: read as that",
                toml_at.file.display(),
                toml_at.line(g.span()),
                g.get_ref()
            );
            Ok((g.get_ref().clone(), g.span()))
        }
        (None, Some(c)) if c.get_ref().len() == 1 => Ok((c.get_ref()[0].clone(), c.span())),
        (None, Some(c)) => Err(toml_at.fixed_group(
            toml_at.line(c.span()),
            format!(
                "`clamps` lists {} groups, a static dataset fixes exactly one: {:?}",
                c.get_ref().len(),
                c.get_ref()
            ),
        )),
        (Some(g), Some(_)) => Err(toml_at.fixed_group(
            toml_at.line(g.span()),
            "both `fixed_group` and `clamps` given: they say the same, give one".into(),
        )),
        (None, None) => Err(toml_at.fixed_group(
            0,
            "missing: give `clamps = [\"group\"]`, the clamped face's physical group (older name: `fixed_group`)"
                .into(),
        )),
    }
}

/// Notes that `key` stands on `line` of `file`; a key seen before is
/// [`DatasetError::DuplicateId`] of column `field`, shown as `id()`.
fn first_time<K: Eq + Hash>(
    first: &mut HashMap<K, usize>,
    key: K,
    file: &Path,
    line: usize,
    field: &str,
    id: impl FnOnce() -> String,
) -> Result<(), DatasetError> {
    if let Some(&first_line) = first.get(&key) {
        return Err(DatasetError::DuplicateId {
            file: file.to_path_buf(),
            line,
            field: field.into(),
            id: id(),
            first_line,
        });
    }
    first.insert(key, line);
    Ok(())
}

/// `markers.csv`: `marker,x,y,z`; each marker embedded in the surface. A declared stand-off
/// height widens the distance accepted from the surface by that height.
fn read_markers(
    file: &Path,
    mesh: &crate::mesh::Mesh,
    surface: &[[usize; 3]],
    standoff: Option<f64>,
) -> Result<Vec<Marker>, DatasetError> {
    let table = Table::read(file.to_path_buf())?;
    let rows = table.rows(&["marker", "x", "y", "z"], 0)?;
    let median_edge = median_surface_edge(mesh, surface);
    let tolerance = embedding_tolerance(mesh, surface) + standoff.unwrap_or(0.0);
    let mut first: HashMap<&str, usize> = HashMap::new();
    let mut markers = Vec::with_capacity(rows.len());
    for r in &rows {
        let id = r.id(0)?;
        first_time(&mut first, id, file, r.line, "marker", || id.into())?;
        let rest = r.vec3(1)?;
        let far = |distance: f64| DatasetError::MarkerFarFromSurface {
            file: file.to_path_buf(),
            line: r.line,
            marker: id.into(),
            distance,
            tolerance,
            median_edge,
        };
        // A mesh with tetrahedra always has boundary triangles; `None` cannot happen, but is
        // reported as "infinitely far" rather than a panic.
        let e = embed_point(mesh, surface, rest).ok_or_else(|| far(f64::INFINITY))?;
        if e.distance > tolerance {
            return Err(far(e.distance));
        }
        markers.push(Marker::embedded(id.into(), rest, &e, &mesh.nodes));
    }
    Ok(markers)
}

/// `contacts.csv`: `measurement,x,y,z,fx,fy,fz[,radius]`; checks the contact rule loads a node.
/// Returns the measurements (no observations yet) and their line numbers.
fn read_contacts(
    file: &Path,
    mesh: &crate::mesh::Mesh,
    surface: &[[usize; 3]],
    fixed: &[usize],
    default_radius: f64,
) -> Result<(Vec<Measurement>, Vec<usize>), DatasetError> {
    let table = Table::read(file.to_path_buf())?;
    let rows = table.rows(
        &["measurement", "x", "y", "z", "fx", "fy", "fz", "radius"],
        1,
    )?;
    // The runtime's rule (runtime/src/contact_rule.rs): free surface nodes within the radius,
    // weighted by lumped surface area.
    let mut areas = vec![0.0; mesh.nodes.len()];
    lumped_surface_areas(|i| mesh.nodes[i], surface.iter().copied(), &mut areas);
    let mut is_fixed = vec![false; mesh.nodes.len()];
    fixed.iter().for_each(|&i| is_fixed[i] = true);
    let mut first: HashMap<&str, usize> = HashMap::new();
    let mut out = Vec::with_capacity(rows.len());
    let mut lines = Vec::with_capacity(rows.len());
    for r in &rows {
        let id = r.id(0)?;
        first_time(&mut first, id, file, r.line, "measurement", || id.into())?;
        let contact = r.vec3(1)?;
        let force = r.vec3(4)?;
        let radius = if r.has(7) {
            r.positive(7)?
        } else {
            default_radius
        };
        let size = crate::sanity::bounding_diagonal(&mesh.nodes);
        if radius > size {
            return Err(DatasetError::Field {
                file: file.to_path_buf(),
                line: r.line,
                field: "radius".into(),
                expected: format!("a radius at most the mesh's size ({size:.4e} m box diagonal)"),
                found: format!("{} m", crate::sanity::show(radius)),
            });
        }
        match contact_weights(
            contact,
            radius,
            |i| mesh.nodes[i],
            &areas,
            |i| is_fixed[i],
            |_, _| {},
        ) {
            Ok(_) => {}
            Err(ContactRuleError::NoNodeInRadius { nearest }) => {
                return Err(DatasetError::ContactCoversNoNode {
                    file: file.to_path_buf(),
                    line: r.line,
                    measurement: id.into(),
                    radius,
                    nearest,
                })
            }
            Err(ContactRuleError::BadInput) => {
                // Unreachable after the checks above (finite contact, positive radius); report
                // it as a field error rather than panic.
                return Err(DatasetError::Field {
                    file: file.to_path_buf(),
                    line: r.line,
                    field: "radius".into(),
                    expected: "a positive radius and a finite contact point".into(),
                    found: format!("radius {radius}, contact {contact:?}"),
                });
            }
        }
        out.push(Measurement {
            id: id.into(),
            contact,
            force,
            radius,
            observed: Vec::new(),
        });
        lines.push(r.line);
    }
    Ok((out, lines))
}

/// `measurements.csv`: `measurement,marker,x,y,z`; observations sorted by marker index.
fn read_measurements(
    file: &Path,
    markers: &[Marker],
    measurements: &mut [Measurement],
    size: f64,
) -> Result<(), DatasetError> {
    let table = Table::read(file.to_path_buf())?;
    let rows = table.rows(&["measurement", "marker", "x", "y", "z"], 0)?;
    let marker_index: HashMap<&str, usize> = markers
        .iter()
        .enumerate()
        .map(|(i, m)| (m.id.as_str(), i))
        .collect();
    let measurement_index: HashMap<String, usize> = measurements
        .iter()
        .enumerate()
        .map(|(i, m)| (m.id.clone(), i))
        .collect();
    let mut first: HashMap<(usize, usize), usize> = HashMap::new();
    for r in &rows {
        let mid = r.id(0)?;
        let Some(&mi) = measurement_index.get(mid) else {
            return Err(DatasetError::MeasurementWithoutContact {
                file: file.to_path_buf(),
                line: r.line,
                measurement: mid.into(),
            });
        };
        let kid = r.id(1)?;
        let Some(&ki) = marker_index.get(kid) else {
            return Err(DatasetError::UnknownMarker {
                file: file.to_path_buf(),
                line: r.line,
                marker: kid.into(),
            });
        };
        first_time(&mut first, (mi, ki), file, r.line, "marker", || {
            format!("{mid}/{kid}")
        })?;
        let observed = r.vec3(2)?;
        let rest = markers[ki].rest;
        // Scaled so that a coordinate of 1e308 reads as such, not as an overflowed infinity.
        let d = [0, 1, 2].map(|k| observed[k] - rest[k]);
        let big = d.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let moved = if big > 0.0 {
            big * d.iter().map(|v| (v / big).powi(2)).sum::<f64>().sqrt()
        } else {
            0.0
        };
        if moved > size {
            // Positions in millimetres read as metres move ~1000 × the rest coordinates.
            let cause = if moved > 1e5 * size {
                "a value that is no position (a corrupt cell or a placeholder)"
            } else if moved > 100.0 * size {
                "positions in other units (millimetres? palpate reads metres)"
            } else {
                "displacements scaled up, or positions in another frame than markers.csv"
            };
            return Err(DatasetError::Field {
                file: file.to_path_buf(),
                line: r.line,
                field: "x,y,z".into(),
                expected: format!(
                    "a position within the object's size ({size:.4e} m box diagonal) of marker \
                     {kid:?}'s rest place ({:.4}, {:.4}, {:.4}) m",
                    rest[0], rest[1], rest[2]
                ),
                found: format!("a displacement of {moved:.4e} m: likely {cause}"),
            });
        }
        measurements[mi].observed.push((ki, observed));
    }
    for m in measurements.iter_mut() {
        m.observed.sort_by_key(|o| o.0);
    }
    Ok(())
}

#[cfg(test)]
mod tests;

//! The motion dataset writer (format: docs/motion-dataset.md), the one every producer of motion
//! datasets calls — the capture import, the example and evidence runs, the tests — so that what
//! is written is what [`super::load`] reads: `dataset.toml` from a [`DatasetToml`] with its keys
//! in one order, and the CSV files from rows on the step grid (t = n·dt, so every time is on the
//! grid the reader demands).
//!
//! [`write_files`] writes into a folder file by file, each atomically, `dataset.toml` last (a
//! folder whose `dataset.toml` is new holds a complete dataset); [`write_dataset`] stages a whole
//! new folder beside the target and swaps it in, so nothing is ever half-written.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use palpate_fem::io::atomic::{write_atomic, StagedDir};

use super::{DatasetError, DatasetToml, LoadToml};

/// How many decimals a CSV column is written with: `None`, the shortest text that reads back to
/// the same `f64` (exact round trip); `Some(d)`, `d` decimals (a capture's precision, rounded).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Decimals {
    /// Of the time column `t` (s).
    pub time: Option<usize>,
    /// Of every other number (positions, displacements, quaternions, forces).
    pub values: Option<usize>,
}

/// One row of `trajectories.csv` or `forces.csv`: a 3-vector of `name` at step `step`
/// (t = step·dt).
#[derive(Debug, Clone, PartialEq)]
pub struct StepRow {
    /// Step on the capture grid (t = step · dt).
    pub step: usize,
    /// Marker (trajectories) or clamp (forces).
    pub name: String,
    /// Position (m) or force (N).
    pub value: [f64; 3],
}

/// `clamps.csv`: the clamps' prescribed motion, one of its two layouts.
#[derive(Debug, Clone, PartialEq)]
pub enum ClampRows {
    /// `t,clamp,ux,uy,uz`: translations only (m).
    Displacements(Vec<StepRow>),
    /// `t,clamp,tx,ty,tz,qw,qx,qy,qz`: rigid poses, translation (m) and unit quaternion.
    Poses(Vec<(StepRow, [f64; 4])>),
}

/// Everything a motion dataset folder holds besides its mesh, which the caller writes or copies
/// (Gmsh, [`palpate_fem::mesh::gmsh::write_msh`]) under `config.mesh`.
#[derive(Debug, Clone)]
pub struct MotionDatasetFiles {
    /// Comment lines at the top of `dataset.toml` (without the `# `): where the data come from.
    pub comments: Vec<String>,
    /// `dataset.toml`. Keys left at `None` (and `[initial]` when `initial_declared` is false, a
    /// load's `from_t = 0` and `inertia = false`) are not written: the reader's defaults apply.
    pub config: DatasetToml,
    /// `markers.csv`: rest places (m), by marker name.
    pub markers: Vec<(String, [f64; 3])>,
    /// `trajectories.csv` (not written when empty).
    pub trajectories: Vec<StepRow>,
    /// `clamps.csv` (not written when `None`).
    pub clamps: Option<ClampRows>,
    /// `forces.csv` (not written when empty).
    pub forces: Vec<StepRow>,
    /// Decimals of the CSV columns.
    pub decimals: Decimals,
}

impl MotionDatasetFiles {
    /// A motion capture's dataset: its markers' rest places and tracked positions, as the
    /// capture import returns them (`palpate_capture::import::Imported`: (step after the
    /// release, marker, position) in the mesh frame), written at a capture's precision (1 µs in
    /// time, 0.1 µm in position) under `config` and the `comments` that say where they come
    /// from; no clamp motion, no forces.
    pub fn captured(
        config: DatasetToml,
        comments: Vec<String>,
        markers: Vec<(String, [f64; 3])>,
        trajectories: &[(usize, String, [f64; 3])],
    ) -> Self {
        Self {
            comments,
            config,
            markers,
            trajectories: trajectories
                .iter()
                .map(|(step, name, value)| StepRow {
                    step: *step,
                    name: name.clone(),
                    value: *value,
                })
                .collect(),
            clamps: None,
            forces: Vec::new(),
            decimals: Decimals {
                time: Some(6),
                values: Some(7),
            },
        }
    }
}

/// A number as TOML reads it back to the same `f64`: Rust's shortest round-trip text, in
/// exponent form where that text would be an integer too long for TOML's i64 or a long run of
/// zeros.
fn toml_number(v: f64) -> String {
    let a = v.abs();
    if a == 0.0 || (1e-5..1e15).contains(&a) {
        format!("{v}")
    } else {
        format!("{v:e}")
    }
}

fn toml_string(s: &str) -> String {
    toml::Value::String(s.to_string()).to_string()
}

fn toml_vec(v: &[f64]) -> String {
    format!(
        "[{}]",
        v.iter()
            .map(|x| toml_number(*x))
            .collect::<Vec<_>>()
            .join(", ")
    )
}

fn csv_number(v: f64, decimals: Option<usize>) -> String {
    match decimals {
        Some(d) => format!("{v:.d$}"),
        None => format!("{v}"),
    }
}

/// The text of `dataset.toml`: comments, then the keys in the order of the format's page, then
/// `[initial]`, then each `[[loads]]` (tables last: a key after a table header belongs to it).
pub fn dataset_toml(comments: &[String], c: &DatasetToml) -> String {
    let mut s = String::new();
    for line in comments {
        let _ = writeln!(s, "# {line}");
    }
    let mut key = |k: &str, v: Option<String>| {
        if let Some(v) = v {
            let _ = writeln!(s, "{k} = {v}");
        }
    };
    key("name", c.name.as_deref().map(toml_string));
    key("description", c.description.as_deref().map(toml_string));
    key("units", c.units.as_deref().map(toml_string));
    key("dt", Some(toml_number(c.dt)));
    key("steps", c.steps.map(|n| n.to_string()));
    key("substeps", c.substeps.map(|n| n.to_string()));
    key("scheme", c.scheme.as_deref().map(toml_string));
    key(
        "viscosity_form",
        c.viscosity_form.as_deref().map(toml_string),
    );
    key("static_start", c.static_start.map(|b| b.to_string()));
    key("mesh", Some(toml_string(&c.mesh)));
    key(
        "clamps",
        Some(format!(
            "[{}]",
            c.clamps
                .iter()
                .map(|n| toml_string(n))
                .collect::<Vec<_>>()
                .join(", ")
        )),
    );
    key("gravity", c.gravity.map(|g| toml_vec(&g)));
    key("density", c.density.map(toml_number));
    key("mass", c.mass.as_deref().map(toml_string));
    key("marker_noise", c.marker_noise.map(toml_number));
    key("marker_weight", c.marker_weight.map(toml_number));
    key("force_weight", c.force_weight.map(toml_number));
    if c.initial_declared {
        let i = &c.initial;
        let _ = write!(
            s,
            "\n[initial]\nlambda = {}\nmu = {}\nviscosity = {}\nh = {}\n",
            toml_number(i.lambda),
            toml_number(i.mu),
            toml_number(i.nu),
            toml_number(i.h)
        );
    }
    for l in &c.loads {
        s.push_str(&load_table(l));
    }
    s
}

fn load_table(l: &LoadToml) -> String {
    let mut s = String::from("\n[[loads]]\n");
    let mut key = |k: &str, v: Option<String>| {
        if let Some(v) = v {
            let _ = writeln!(s, "{k} = {v}");
        }
    };
    key("name", l.name.as_deref().map(toml_string));
    key("group", Some(toml_string(&l.group)));
    key("edge", l.edge.map(|e| toml_vec(&e)));
    key("force", l.force.map(|f| toml_vec(&f)));
    key("mass", l.mass.map(toml_number));
    key("from_t", (l.from_t != 0.0).then(|| toml_number(l.from_t)));
    key("inertia", l.inertia.then(|| "true".to_string()));
    key("lever_m", l.lever_m.filter(|d| *d != 0.0).map(toml_number));
    s
}

/// The CSV files' texts, by file name, in the order they are written.
fn csv_files(f: &MotionDatasetFiles) -> Vec<(&'static str, String)> {
    let Decimals { time, values } = f.decimals;
    let dt = f.config.dt;
    let t = |step: usize| csv_number(step as f64 * dt, time);
    let v = |x: f64| csv_number(x, values);
    let row = |s: &mut String, r: &StepRow| {
        let _ = writeln!(
            s,
            "{},{},{},{},{}",
            t(r.step),
            r.name,
            v(r.value[0]),
            v(r.value[1]),
            v(r.value[2])
        );
    };
    let mut out = Vec::new();
    let mut m = String::from("marker,x,y,z\n");
    for (name, p) in &f.markers {
        let _ = writeln!(m, "{name},{},{},{}", v(p[0]), v(p[1]), v(p[2]));
    }
    out.push(("markers.csv", m));
    if !f.trajectories.is_empty() {
        let mut s = String::from("t,marker,x,y,z\n");
        f.trajectories.iter().for_each(|r| row(&mut s, r));
        out.push(("trajectories.csv", s));
    }
    match &f.clamps {
        Some(ClampRows::Displacements(rows)) => {
            let mut s = String::from("t,clamp,ux,uy,uz\n");
            rows.iter().for_each(|r| row(&mut s, r));
            out.push(("clamps.csv", s));
        }
        Some(ClampRows::Poses(rows)) => {
            let mut s = String::from("t,clamp,tx,ty,tz,qw,qx,qy,qz\n");
            for (r, q) in rows {
                let _ = writeln!(
                    s,
                    "{},{},{},{},{},{},{},{},{}",
                    t(r.step),
                    r.name,
                    v(r.value[0]),
                    v(r.value[1]),
                    v(r.value[2]),
                    v(q[0]),
                    v(q[1]),
                    v(q[2]),
                    v(q[3])
                );
            }
            out.push(("clamps.csv", s));
        }
        None => {}
    }
    if !f.forces.is_empty() {
        let mut s = String::from("t,clamp,fx,fy,fz\n");
        f.forces.iter().for_each(|r| row(&mut s, r));
        out.push(("forces.csv", s));
    }
    out
}

/// Writes the dataset's files (not the mesh) into the folder `dir` (created if needed), each
/// atomically, `dataset.toml` last; returns the files written, in that order.
pub fn write_files(dir: &Path, f: &MotionDatasetFiles) -> Result<Vec<PathBuf>, DatasetError> {
    let mut written = Vec::new();
    let toml = dataset_toml(&f.comments, &f.config);
    for (name, text) in csv_files(f).into_iter().chain([("dataset.toml", toml)]) {
        let path = dir.join(name);
        write_atomic(&path, text.as_bytes())?;
        written.push(path);
    }
    Ok(written)
}

/// Writes a whole new dataset folder at `dir`: the mesh (Gmsh 4.1, under `config.mesh`) and the
/// files of `f`, staged beside `dir` and swapped in only when all are written, so a failure
/// leaves whatever was at `dir` as it was. Returns the files at their final paths.
pub fn write_dataset(
    dir: &Path,
    mesh: &palpate_fem::mesh::Mesh,
    f: &MotionDatasetFiles,
) -> Result<Vec<PathBuf>, DatasetError> {
    let staged = StagedDir::new(dir)?;
    let mesh_file = staged.path().join(&f.config.mesh);
    palpate_fem::mesh::gmsh::write_msh(mesh, &mesh_file).map_err(|e| DatasetError::Bad {
        file: mesh_file.clone(),
        line: 0,
        what: format!("writing the mesh: {e}"),
    })?;
    let mut files = vec![mesh_file];
    files.extend(write_files(staged.path(), f)?);
    let files = files.iter().map(|p| staged.final_path(p)).collect();
    staged.commit()?;
    Ok(files)
}

//! Motion dataset reader and its one writer ([`write_dataset`], [`write_files`]; format:
//! docs/motion-dataset.md).
//!
//! A directory with `dataset.toml`, `mesh.msh` (Gmsh 4.1, physical groups name the clamps),
//! `markers.csv` (`marker,x,y,z` rest) and any of `trajectories.csv` (`t,marker,x,y,z`),
//! `clamps.csv` (`t,clamp,tx,ty,tz,qw,qx,qy,qz` or `t,clamp,ux,uy,uz`) and `forces.csv`
//! (`t,clamp,fx,fy,fz`). Times must lie on the step grid t = n·dt (within 1e-3·dt); clamp poses
//! are linearly interpolated between given times (held after the last row); missing
//! trajectory rows are dropped frames.

use super::model::{DeadLoad, Model, Observations};
use super::timestep::TimeStep;
use palpate_fem::io::csv::{self, NumberError};
use palpate_fem::mesh::Mesh;
use serde::Deserialize;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

mod load;
mod write;
pub use load::load;
pub use write::{
    dataset_toml, write_dataset, write_files, ClampRows, Decimals, MotionDatasetFiles, StepRow,
};

/// Errors naming the file, line and field.
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    /// File unreadable.
    #[error("{file}: {source}")]
    Io {
        /// File.
        file: PathBuf,
        /// Cause.
        source: std::io::Error,
    },
    /// Bad content at a line (1-based; 0 = the file as a whole, printed without a line).
    #[error("{}{}: {what}", file.display(), line_suffix(*line))]
    Bad {
        /// File.
        file: PathBuf,
        /// Line.
        line: usize,
        /// What is wrong (field, expected vs found).
        what: String,
    },
    /// Writing a dataset failed (the file, the step, the operating system's error).
    #[error(transparent)]
    Write(#[from] palpate_fem::io::atomic::AtomicWriteError),
}

/// `:line` for a 1-based line, nothing for 0 (a finding about the whole file).
fn line_suffix(line: usize) -> String {
    if line == 0 {
        String::new()
    } else {
        format!(":{line}")
    }
}

/// `dataset.toml`. The keys it shares with the static datasets (`name`, `description`, `units`,
/// `mesh`, `clamps`, `marker_noise`, `gravity`) mean the same in both (docs/dataset.md).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DatasetToml {
    /// Short name, as in static datasets.
    #[serde(default)]
    pub name: Option<String>,
    /// Free text.
    #[serde(default)]
    pub description: Option<String>,
    /// Units: only "SI" (m, s, N, kg, Pa), as in static datasets.
    #[serde(default)]
    pub units: Option<String>,
    /// Declared marker noise σ per axis (m), as in static datasets: the floor of the marker
    /// error is σ√3.
    #[serde(default)]
    pub marker_noise: Option<f64>,
    /// Mesh file (default `mesh.msh`).
    #[serde(default = "default_mesh")]
    pub mesh: String,
    /// Time step = capture period (s).
    pub dt: f64,
    /// Steps to simulate (default: up to the last observation), counted in capture intervals.
    pub steps: Option<usize>,
    /// Simulation steps per capture interval `dt` (default: chosen from the capture's own
    /// oscillation, [`crate::timestep`]; 1 integrates at the capture rate).
    #[serde(default)]
    pub substeps: Option<usize>,
    /// Time integration scheme: `"bdf2"`, `"midpoint"` (default:
    /// [`crate::timestep::DATASET_DEFAULT`]) or `"alpha"` ([`crate::timestep::Scheme`]); the
    /// substeps chosen from the capture follow its rule.
    #[serde(default)]
    pub scheme: Option<String>,
    /// How the viscosity reads the velocity gradient: `"rest-gradient"` (default, Real2Sim's
    /// public code) or `"objective"` (the Green–Lagrange strain rate;
    /// [`crate::viscosity::Form`]).
    #[serde(default)]
    pub viscosity_form: Option<String>,
    /// Density (kg/m³), if known.
    pub density: Option<f64>,
    /// Gravity (m/s²). Not declared: (0, 0, −9.81), with a warning — a static dataset without
    /// `gravity` has none, so declare it.
    #[serde(default)]
    pub gravity: Option<[f64; 3]>,
    /// Clamp group names (physical groups in the mesh).
    pub clamps: Vec<String>,
    /// `"lumped"` (default) or `"consistent"`.
    #[serde(default)]
    pub mass: Option<String>,
    /// Start from elastostatic equilibrium (default true).
    #[serde(default)]
    pub static_start: Option<bool>,
    /// Weight of the marker term (default 1).
    pub marker_weight: Option<f64>,
    /// Weight of the force term (default 1).
    pub force_weight: Option<f64>,
    /// Initial guesses (Pa, Pa, Pa·s^h, -, kg/m³).
    #[serde(default)]
    pub initial: Initial,
    /// Known dead loads besides gravity (`[[loads]]` tables).
    #[serde(default)]
    pub loads: Vec<LoadToml>,
    /// Whether the file has an `[initial]` table (set by [`load`]): without one, the fit may
    /// estimate its start from the data (`palpate_motion::start`).
    #[serde(skip)]
    pub initial_declared: bool,
}

impl DatasetToml {
    /// A dataset header with only what has no default: the capture period `dt` (s) and the
    /// clamped groups; every other key left to the reader's default (mesh `mesh.msh`).
    pub fn new(dt: f64, clamps: Vec<String>) -> Self {
        Self {
            name: None,
            description: None,
            units: None,
            marker_noise: None,
            mesh: default_mesh(),
            dt,
            steps: None,
            substeps: None,
            scheme: None,
            viscosity_form: None,
            density: None,
            gravity: None,
            clamps,
            mass: None,
            static_start: None,
            marker_weight: None,
            force_weight: None,
            initial: Initial::default(),
            loads: Vec::new(),
            initial_declared: false,
        }
    }
}

/// One `[[loads]]` table: a known dead load on a physical group of the mesh, e.g. a weight hung
/// from the top edge of the free end:
///
/// ```toml
/// [[loads]]
/// name = "52 g weight"
/// group = "free_end"
/// edge = [1, 0, 0]   # only the group's nodes furthest along +x (its top edge)
/// mass = 0.052       # kg: the force is mass × gravity; or force = [fx, fy, fz] in N
/// from_t = 0.0       # s: acts from this time on (default 0, i.e. already at the start)
/// inertia = false    # whether the mass also moves with its nodes (default: a force only)
/// lever_m = 0.006    # the force acts 6 mm beyond the nodes along the long axis (default 0)
/// ```
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LoadToml {
    /// Name in reports (default: the group's name).
    pub name: Option<String>,
    /// Physical group of the mesh whose nodes carry the load.
    pub group: String,
    /// If given, only the group's nodes furthest along this direction carry it (an edge).
    pub edge: Option<[f64; 3]>,
    /// Total force (N).
    pub force: Option<[f64; 3]>,
    /// Hanging mass (kg): force = mass × gravity.
    pub mass: Option<f64>,
    /// Time the load comes on (s).
    #[serde(default)]
    pub from_t: f64,
    /// Whether the hanging `mass` also adds inertia (default false: a force only).
    #[serde(default)]
    pub inertia: bool,
    /// The force acts this far (m) beyond its nodes along the body's long axis, as from a hook
    /// standing off the end ([`crate::load_point`]); default 0, on the nodes.
    #[serde(default)]
    pub lever_m: Option<f64>,
}

/// Initial parameter guesses.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Initial {
    /// λ.
    pub lambda: f64,
    /// μ.
    pub mu: f64,
    /// The viscosity coefficient ν of eq. 17 (Pa·s^h), key `viscosity` (`nu` is still read, with
    /// a warning: ν is Poisson's ratio everywhere else).
    #[serde(rename = "viscosity", alias = "nu")]
    pub nu: f64,
    /// h.
    pub h: f64,
}

impl Default for Initial {
    fn default() -> Self {
        Self {
            lambda: 1e4,
            mu: 1e4,
            nu: 1.0,
            h: 1.0,
        }
    }
}

fn default_mesh() -> String {
    "mesh.msh".into()
}
/// Gravity of a motion dataset that does not declare it (m/s²).
pub const DEFAULT_GRAVITY: [f64; 3] = [0.0, 0.0, -9.81];

/// A loaded dataset.
#[derive(Debug, Clone)]
pub struct MotionDataset {
    /// Parsed `dataset.toml`.
    pub config: DatasetToml,
    /// The mesh.
    pub mesh: Mesh,
    /// The model (clamps, markers, time grid).
    pub model: Model,
    /// Observations.
    pub obs: Observations,
    /// How the simulation step was chosen (`model` and `obs` are already on that step).
    pub timestep: TimeStep,
}

impl MotionDataset {
    /// Capture intervals `dt` the dataset covers: `model.steps` counts simulation steps, of
    /// which there are `model.substeps` per interval.
    pub fn capture_steps(&self) -> usize {
        self.model.steps / self.model.substeps.max(1)
    }

    /// The dataset's extent in time, in one sentence that says both grids: "541 steps of 0.01 s
    /// (simulated in 1082 steps of 5.000 ms)" — the step count and `dt` as `dataset.toml` and
    /// the CSV files have them, then the simulation's when it takes several steps per interval.
    pub fn steps_sentence(&self) -> String {
        let capture = format!("{} steps of {} s", self.capture_steps(), self.config.dt);
        if self.model.substeps <= 1 {
            capture
        } else {
            format!(
                "{capture} (simulated in {} steps of {:.3} ms)",
                self.model.steps,
                1e3 * self.model.dt
            )
        }
    }
}

fn read(file: &Path) -> Result<String, DatasetError> {
    std::fs::read_to_string(file).map_err(|source| DatasetError::Io {
        file: file.into(),
        source,
    })
}

fn bad(file: &Path, line: usize, what: impl Into<String>) -> DatasetError {
    DatasetError::Bad {
        file: file.into(),
        line,
        what: what.into(),
    }
}

/// CSV rows after the header, their fields in the order of the header alternative the file's
/// header names (its columns in any order; fields unquoted by [`csv::parse`]).
fn csv(
    file: &Path,
    headers: &[&[&str]],
) -> Result<Option<(usize, Vec<(usize, Vec<String>)>)>, DatasetError> {
    if !file.exists() {
        return Ok(None);
    }
    let text = read(file)?;
    let records = csv::parse(&text, true).map_err(|(line, why)| bad(file, line, why))?;
    let mut lines = records.into_iter();
    let (hline, cols) = lines
        .next()
        .ok_or_else(|| bad(file, 1, "empty file (expected a header line)"))?;
    // The alternative whose names are the file's columns, each once, in any order.
    let which = headers
        .iter()
        .position(|h| {
            h.len() == cols.len()
                && h.iter()
                    .all(|n| cols.iter().filter(|c| c == n).count() == 1)
        })
        .ok_or_else(|| {
            bad(
                file,
                hline,
                format!(
                    "header {:?}, expected one of {} (columns in any order)",
                    cols,
                    headers
                        .iter()
                        .map(|h| h.join(","))
                        .collect::<Vec<_>>()
                        .join(" | ")
                ),
            )
        })?;
    let order: Vec<usize> = headers[which]
        .iter()
        .map(|n| cols.iter().position(|c| c == n).expect("matched above"))
        .collect();
    let n = headers[which].len();
    let mut rows = Vec::new();
    for (line, f) in lines {
        if f.len() != n {
            return Err(bad(
                file,
                line,
                format!("{} fields, expected {n} ({})", f.len(), cols.join(",")),
            ));
        }
        rows.push((line, order.iter().map(|&p| f[p].clone()).collect()));
    }
    Ok(Some((which, rows)))
}

fn num(file: &Path, line: usize, field: &str, s: &str) -> Result<f64, DatasetError> {
    csv::finite(s).map_err(|e| match e {
        NumberError::NotANumber => bad(
            file,
            line,
            format!("field {field}: expected a number, found {s:?}"),
        ),
        NumberError::NotFinite => bad(file, line, format!("field {field}: not finite ({s})")),
    })
}

/// The most steps a motion dataset may ask for. The forward simulation keeps every step's state
/// and the adjoint keeps its tape, so memory and time grow linearly with the step count: 100,000
/// steps is 100 s at 1 kHz or 17 min at 100 Hz of capture — far more than one fit can use, and
/// small enough that a typo in `t`, `dt` or `steps` is refused instead of allocating gigabytes.
pub const MAX_STEPS: usize = 100_000;

/// How far past the last observation `steps` may reach, as a multiple of the last observed
/// step: steps after the data carry no information for the fit.
pub const MAX_STEPS_PAST_DATA: usize = 2;

/// How far a marker may sit outside the mesh's bounding box, as a fraction of the box diagonal:
/// enough for markers on stand-offs, not for a marker in the wrong units or the wrong frame.
pub const MARKER_OUTSIDE_FRACTION: f64 = 0.25;

/// How far a tracked marker may be from its rest place, in box diagonals: a soft body swings its
/// markers by up to about its own length, never by twice its diagonal — a trajectory that does is
/// in other units (millimetres read as metres) or another frame than `markers.csv`.
pub const MARKER_MOVE_DIAGONALS: f64 = 2.0;

/// One kind of observed 3-vector series: rows `t, <name>, a, b, c` of a CSV file.
struct Series {
    /// What column 1 names (a marker, a clamp).
    name: &'static str,
    /// Where those names are declared.
    declared_in: &'static str,
    /// The vector's three fields.
    fields: [&'static str; 3],
}

/// trajectories.csv: marker positions.
const MARKER_POSITIONS: Series = Series {
    name: "marker",
    declared_in: "markers.csv",
    fields: ["x", "y", "z"],
};

/// forces.csv: clamp reaction forces.
const CLAMP_FORCES: Series = Series {
    name: "clamp",
    declared_in: "dataset.toml clamps",
    fields: ["fx", "fy", "fz"],
};

/// Reads the rows of a [`Series`] file into `out` (a row per step, a column per name as `index`
/// numbers them): a name given twice at the same step is an error, since the two rows would
/// silently overwrite each other; rows at step 0 or after the last step are not fitted.
fn read_series(
    file: &Path,
    rows: &[(usize, Vec<String>)],
    dt: f64,
    series: &Series,
    out: &mut [Vec<Option<[f64; 3]>>],
    index: impl Fn(&str) -> Option<usize>,
) -> Result<(), DatasetError> {
    let mut seen: HashMap<(usize, usize), usize> = HashMap::new();
    for (line, f) in rows {
        let n = step_of(file, *line, num(file, *line, "t", &f[0])?, dt)?;
        let i = index(&f[1]).ok_or_else(|| {
            bad(
                file,
                *line,
                format!(
                    "field {}: {:?} not in {}",
                    series.name, f[1], series.declared_in
                ),
            )
        })?;
        if let Some(first) = seen.insert((n, i), *line) {
            return Err(bad(
                file,
                *line,
                format!(
                    "{} {:?} at t = {} s is given twice (first at line {first})",
                    series.name, f[1], f[0]
                ),
            ));
        }
        if n >= 1 && n <= out.len() {
            let [a, b, c] = series.fields;
            out[n - 1][i] = Some([
                num(file, *line, a, &f[2])?,
                num(file, *line, b, &f[3])?,
                num(file, *line, c, &f[4])?,
            ]);
        }
    }
    Ok(())
}

fn step_of(file: &Path, line: usize, t: f64, dt: f64) -> Result<usize, DatasetError> {
    let n = (t / dt).round();
    if n < 0.0 || (t - n * dt).abs() > 1e-3 * dt {
        return Err(bad(
            file,
            line,
            format!("field t: {t} s is not on the step grid n·{dt} s"),
        ));
    }
    // Checked before the cast: `as usize` saturates, and the count sizes allocations.
    if n > MAX_STEPS as f64 {
        return Err(bad(
            file,
            line,
            format!(
                "field t: {t} s is step {n:.0} of dt = {dt} s; at most {MAX_STEPS} steps are \
                 supported (check the units of t and dt)"
            ),
        ));
    }
    Ok(n as usize)
}

/// Most substeps a dataset may declare (each multiplies the simulation's steps and its tape).
pub const MAX_DECLARED_SUBSTEPS: usize = 64;

/// The `i`-th `[[loads]]` table as a [`DeadLoad`] on free nodes, or an error naming the field.
fn dead_load(
    tf: &Path,
    i: usize,
    l: &LoadToml,
    mesh: &Mesh,
    model: &Model,
) -> Result<DeadLoad, DatasetError> {
    let at = |what: String| bad(tf, 0, format!("loads[{i}] (group {:?}): {what}", l.group));
    let force = match (l.force, l.mass) {
        (Some(f), None) if f.iter().all(|v| v.is_finite()) => f,
        (None, Some(m)) if m.is_finite() && m > 0.0 => model.gravity.map(|g| m * g),
        (Some(_), Some(_)) => return Err(at("give force or mass, not both".into())),
        (None, None) => return Err(at("give force = [fx, fy, fz] (N) or mass (kg)".into())),
        (Some(f), None) => return Err(at(format!("field force: not finite: {f:?}"))),
        (None, Some(m)) => {
            return Err(at(format!("field mass: must be finite and > 0, found {m}")))
        }
    };
    if !(l.from_t.is_finite() && l.from_t >= 0.0) {
        return Err(at(format!(
            "field from_t: must be finite and ≥ 0 s, found {}",
            l.from_t
        )));
    }
    let mut nodes = mesh
        .group(&l.group)
        .map_err(|e| at(format!("field group: {e}")))?
        .to_vec();
    if let Some(d) = l.edge {
        let norm = d.iter().map(|v| v * v).sum::<f64>().sqrt();
        if !(norm.is_finite() && norm > 0.0) {
            return Err(at(format!("field edge: not a direction: {d:?}")));
        }
        let along = |n: usize| (0..3).map(|k| mesh.nodes[n][k] * d[k] / norm).sum::<f64>();
        let (lo, hi) = nodes
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &n| {
                (a.min(along(n)), b.max(along(n)))
            });
        // The group's extent along the direction sets the tolerance: nodes of a meshed edge sit
        // on it to round-off, the next row of nodes a mesh size away.
        let tol = 1e-6 * (hi - lo).max(1e-9);
        nodes.retain(|&n| along(n) >= hi - tol);
    }
    let clamped = nodes
        .iter()
        .filter(|&&n| model.node_clamp[n] != usize::MAX)
        .count();
    if clamped > 0 {
        return Err(at(format!(
            "{clamped} of its {} nodes are clamped: a load on a clamp does nothing",
            nodes.len()
        )));
    }
    let from_step = (l.from_t / model.dt - 1e-9).ceil().max(0.0) as usize;
    if l.inertia && (l.mass.is_none() || from_step > 0) {
        return Err(at(
            "field inertia: only a mass present from the start (mass given, from_t = 0) can add inertia"
                .into(),
        ));
    }
    Ok(DeadLoad {
        name: l.name.clone().unwrap_or_else(|| l.group.clone()),
        nodes,
        force,
        from_step,
        mass: l.mass,
        inertia: l.inertia,
        lever: None,
    })
}

/// The mesh's bounding box (low and high corners, m) and its diagonal (m).
fn bounding_box(mesh: &Mesh) -> ([f64; 3], [f64; 3], f64) {
    let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for p in &mesh.nodes {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let diagonal = (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f64>().sqrt();
    (lo, hi, diagonal)
}

/// Refuses trajectory rows whose marker is farther from its rest place than
/// [`MARKER_MOVE_DIAGONALS`] box diagonals: the rest places passed [`check_markers_near_mesh`],
/// so such a row is in other units or another frame, and a fit would take it as motion (a
/// trajectory in millimetres was "explained" by marker offsets 10⁷ µm long).
fn check_trajectories_near_rest(
    file: &Path,
    rows: &[(usize, Vec<String>)],
    markers: &[(String, [f64; 3])],
    index: &HashMap<String, usize>,
    mesh: &Mesh,
) -> Result<(), DatasetError> {
    let (_, _, diagonal) = bounding_box(mesh);
    let allowed = MARKER_MOVE_DIAGONALS * diagonal;
    for (line, f) in rows {
        let Some(&i) = index.get(&f[1]) else {
            continue;
        };
        let p = [
            num(file, *line, "x", &f[2])?,
            num(file, *line, "y", &f[3])?,
            num(file, *line, "z", &f[4])?,
        ];
        let rest = markers[i].1;
        let moved = (0..3).map(|k| (p[k] - rest[k]).powi(2)).sum::<f64>().sqrt();
        if moved > allowed {
            return Err(bad(
                file,
                *line,
                format!(
                    "marker {:?} at t = {} s is {moved:.4e} m from its rest place in markers.csv \
                     ({:.4}, {:.4}, {:.4}) m; a marker may move at most {allowed:.4} m \
                     ({MARKER_MOVE_DIAGONALS} × the mesh's box diagonal {diagonal:.4} m) — check \
                     the units (metres) and the frame of trajectories.csv against markers.csv",
                    f[1], f[0], rest[0], rest[1], rest[2]
                ),
            ));
        }
    }
    Ok(())
}

/// Refuses a mesh 1000 × larger than its markers' spread: markers inside a mesh read in the
/// wrong units (millimetres taken as metres) pass [`check_markers_near_mesh`] because the mesh is
/// huge, but then sit in a corner of it.
fn check_marker_scale(
    file: &Path,
    markers: &[(String, [f64; 3])],
    mesh: &Mesh,
) -> Result<(), DatasetError> {
    if markers.len() < 2 {
        return Ok(());
    }
    let (_, _, diagonal) = bounding_box(mesh);
    let spread = palpate_fem::sanity::bounding_diagonal(
        &markers.iter().map(|(_, p)| *p).collect::<Vec<_>>(),
    );
    if spread > 0.0 && diagonal > MESH_MARKER_SCALE * spread {
        return Err(bad(
            file,
            0,
            format!(
                "the markers span {spread:.4e} m but the mesh is {diagonal:.4e} m across \
                 ({:.0} ×): the mesh is probably in millimetres and the markers in metres \
                 (palpate reads metres; scale the mesh by 0.001)",
                diagonal / spread
            ),
        ));
    }
    Ok(())
}

/// How many times the markers' spread the mesh's box diagonal may be: markers cover a good part
/// of the object they are stuck on; 1000 × is a unit mistake.
pub const MESH_MARKER_SCALE: f64 = 100.0;

/// Refuses markers far outside the body: a marker in other units or another frame would be
/// embedded by extrapolating a boundary element's shape functions and fitted as if it were real.
fn check_markers_near_mesh(
    file: &Path,
    rows: &[(usize, Vec<String>)],
    markers: &[(String, [f64; 3])],
    mesh: &Mesh,
) -> Result<(), DatasetError> {
    let (lo, hi, diagonal) = bounding_box(mesh);
    let allowed = MARKER_OUTSIDE_FRACTION * diagonal;
    for ((line, _), (name, p)) in rows.iter().zip(markers) {
        let outside = (0..3)
            .map(|k| (lo[k] - p[k]).max(p[k] - hi[k]).max(0.0).powi(2))
            .sum::<f64>()
            .sqrt();
        if outside > allowed {
            return Err(bad(
                file,
                *line,
                format!(
                    "marker {name:?} at ({:.4}, {:.4}, {:.4}) m lies {outside:.4} m outside the \
                     mesh's bounding box [{:.4}, {:.4}] × [{:.4}, {:.4}] × [{:.4}, {:.4}] m; \
                     markers may sit at most {allowed:.4} m ({MARKER_OUTSIDE_FRACTION} × the \
                     box diagonal) off the body (check units and frame)",
                    p[0], p[1], p[2], lo[0], hi[0], lo[1], hi[1], lo[2], hi[2]
                ),
            ));
        }
    }
    Ok(())
}

//! A scan dataset on disk (`docs/scan-dataset.md`): an object's rest mesh and the scans of it in
//! several states — hanging from clamps under its weight, held in a grip moved by a rigid motion
//! (twisted, bent), loaded by dead loads — described by `scans.toml`:
//!
//! ```toml
//! mesh = "mesh.msh"           # Gmsh; its physical groups are the node groups named below
//! poisson = 0.49              # optional; 0.49 (a silicone) when absent
//! density = 1100.0            # kg/m³
//! gravity = [0.0, 0.0, -9.81] # m/s², in the mesh's frame
//! rest = "rest"               # optional: a scan folder of the object unloaded
//! register = "fixed-part"     # optional: "none" (default), "fixed-part" or "rest"
//! register_band_m = 0.008     # optional: the fixed part's band (default a tenth of the
//!                             # mesh's diagonal, or the longest surface edge from a fixed
//!                             # node if longer)
//!
//! [[states]]
//! name = "twisted"            # optional, default "state <i>"
//! scan = "twist"              # a scan folder (`palpate import depth|cloud` writes one)
//! clamped = ["left"]          # groups held at rest
//! [states.held]               # optional: a group moved rigidly, x ↦ R(x − about) + about + translation
//! group = "right"
//! axis = [1.0, 0.0, 0.0]      # rotation axis (any length)
//! angle_deg = 45.0
//! about = [0.08, 0.01, 0.005] # m
//! translation = [0.0, 0.0, 0.0]
//! [[states.loads]]            # optional: a dead load spread evenly over a group's nodes
//! group = "tip"
//! force_n = [0.0, 0.0, -0.05]
//! ```
//!
//! Paths are relative to the dataset's folder. Every error names the file, the field and what
//! was expected against what was found.

use std::path::{Path, PathBuf};

use nalgebra::{Rotation3, Unit, Vector3};
use palpate_fem::mesh::Mesh;
use serde::Deserialize;

use crate::fit::{Design, LoadedObject, ScanState};
use crate::record::{read_scan, Scan, RECORD_FILE};
use crate::ScanError;

/// The dataset's description file.
pub const DATASET_FILE: &str = "scans.toml";
/// Poisson's ratio of a dataset that does not declare one: a silicone's, nearly incompressible.
pub const DEFAULT_POISSON: f64 = 0.49;

/// `scans.toml` as written (module doc).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScansToml {
    /// The mesh file (Gmsh `.msh`).
    pub mesh: String,
    /// Poisson's ratio; [`DEFAULT_POISSON`] when absent.
    pub poisson: Option<f64>,
    /// Density (kg/m³).
    pub density: f64,
    /// Gravity (m/s²).
    pub gravity: [f64; 3],
    /// A scan folder of the object at rest, unloaded.
    pub rest: Option<String>,
    /// How the scans are brought into the mesh's frame.
    #[serde(default)]
    pub register: Register,
    /// The fixed part's band (m): the surface within it of a clamped or held node.
    pub register_band_m: Option<f64>,
    /// The loaded states.
    pub states: Vec<StateToml>,
}

/// How a dataset's scans are brought into the mesh's frame (docs/scan-dataset.md).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Register {
    /// The scans are in the mesh's frame as imported.
    #[default]
    None,
    /// Each state's scan registered onto the surface near its clamped and held groups, placed
    /// where they are in that state; then a rigid correction of each scan fitted with the
    /// material ([`crate::dataset_fit`]).
    FixedPart,
    /// The rest scan registered onto the whole rest mesh, its motion applied to every scan
    /// (the camera not moved between scans); then the rigid correction.
    Rest,
}

impl Register {
    /// Its name in `scans.toml`.
    pub fn name(self) -> &'static str {
        match self {
            Self::None => "none",
            Self::FixedPart => "fixed-part",
            Self::Rest => "rest",
        }
    }
}

/// One `[[states]]` table.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StateToml {
    /// Its name in reports.
    pub name: Option<String>,
    /// The scan folder.
    pub scan: String,
    /// Groups held at rest.
    pub clamped: Vec<String>,
    /// A group moved rigidly.
    pub held: Option<HeldToml>,
    /// Dead loads.
    #[serde(default)]
    pub loads: Vec<LoadToml>,
}

/// A grip's rigid motion: x ↦ R(x − about) + about + translation, R the rotation by
/// `angle_deg` about `axis`.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HeldToml {
    /// The group held.
    pub group: String,
    /// Rotation axis (any non-zero length); needed with a non-zero angle.
    pub axis: Option<[f64; 3]>,
    /// Rotation angle (degrees, right-handed about `axis`).
    #[serde(default)]
    pub angle_deg: f64,
    /// The point the rotation turns about (m).
    #[serde(default)]
    pub about: [f64; 3],
    /// Translation after the rotation (m).
    #[serde(default)]
    pub translation: [f64; 3],
}

impl HeldToml {
    /// Where the motion takes the rest point `x`.
    pub fn apply(&self, x: [f64; 3]) -> [f64; 3] {
        let r = match self.axis {
            Some(a) if self.angle_deg != 0.0 => Rotation3::from_axis_angle(
                &Unit::new_normalize(Vector3::from(a)),
                self.angle_deg.to_radians(),
            ),
            _ => Rotation3::identity(),
        };
        let about = Vector3::from(self.about);
        (r * (Vector3::from(x) - about) + about + Vector3::from(self.translation)).into()
    }
}

/// A dead load on a group: `force_n` (N) in all, an equal share on each of its nodes.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LoadToml {
    /// The group.
    pub group: String,
    /// The total force (N).
    pub force_n: [f64; 3],
}

/// One state read and resolved on the mesh.
#[derive(Debug, Clone)]
pub struct DatasetState {
    /// Its name.
    pub name: String,
    /// Its scan folder.
    pub scan_dir: PathBuf,
    /// Its scan.
    pub scan: Scan,
    /// As declared.
    pub toml: StateToml,
    /// Clamped and held nodes of the linear mesh.
    pub fixed: Vec<usize>,
    /// Each fixed node's displacement (m).
    pub fixed_displacement: Vec<[f64; 3]>,
    /// Nodal dead loads (N).
    pub forces: Vec<(usize, [f64; 3])>,
}

/// A scan dataset, read and checked.
#[derive(Debug, Clone)]
pub struct ScanDataset {
    /// The folder.
    pub dir: PathBuf,
    /// The rest mesh.
    pub mesh: Mesh,
    /// Poisson's ratio.
    pub poisson: f64,
    /// Whether Poisson's ratio was declared (else [`DEFAULT_POISSON`]).
    pub poisson_declared: bool,
    /// Density (kg/m³).
    pub density: f64,
    /// Gravity (m/s²).
    pub gravity: [f64; 3],
    /// The rest scan, if any.
    pub rest: Option<Scan>,
    /// How the scans are brought into the mesh's frame.
    pub register: Register,
    /// The fixed part's band (m).
    pub register_band_m: f64,
    /// The states.
    pub states: Vec<DatasetState>,
}

/// Whether `path` is a scan dataset (a folder with [`DATASET_FILE`], or that file).
pub fn is_scan_dataset(path: &Path) -> bool {
    path.join(DATASET_FILE).is_file()
        || path.file_name().and_then(|f| f.to_str()) == Some(DATASET_FILE)
}

impl ScanDataset {
    /// Reads the dataset in the folder `path` (or its `scans.toml`), its mesh and every scan.
    pub fn read(path: &Path) -> Result<Self, ScanError> {
        let (dir, file) = if path.is_dir() {
            (path.to_path_buf(), path.join(DATASET_FILE))
        } else {
            (
                path.parent().unwrap_or(Path::new(".")).to_path_buf(),
                path.to_path_buf(),
            )
        };
        let text = std::fs::read_to_string(&file).map_err(|e| ScanError::io(&file, e))?;
        let t: ScansToml =
            toml::from_str(&text).map_err(|e| ScanError::format(&file, e.to_string()))?;
        let bad = |what: String| ScanError::format(&file, what);
        let poisson = t.poisson.unwrap_or(DEFAULT_POISSON);
        if !(poisson.is_finite() && poisson > -1.0 && poisson < 0.5) {
            return Err(bad(format!(
                "field poisson: expected a number in (−1, 0.5), found {poisson}"
            )));
        }
        if !(t.density.is_finite() && t.density > 0.0) {
            return Err(bad(format!(
                "field density: expected a positive number (kg/m³), found {}",
                t.density
            )));
        }
        if t.gravity.iter().any(|g| !g.is_finite()) {
            return Err(bad(format!(
                "field gravity: expected three finite numbers (m/s²), found {:?}",
                t.gravity
            )));
        }
        if t.register == Register::Rest && t.rest.is_none() {
            return Err(bad(
                "field register: \"rest\" registers the rest scan onto the rest mesh; expected a field rest naming its folder, found none".into(),
            ));
        }
        if let Some(b) = t.register_band_m {
            if !(b.is_finite() && b > 0.0) {
                return Err(bad(format!(
                    "field register_band_m: expected a positive distance (m), found {b}"
                )));
            }
        }
        if t.states.is_empty() {
            return Err(bad(
                "field states: expected at least one [[states]] table, found none".into(),
            ));
        }
        let mesh_path = dir.join(&t.mesh);
        let mesh = palpate_fem::mesh::gmsh::read_msh(&mesh_path)
            .map_err(|e| bad(format!("field mesh ({}): {e}", mesh_path.display())))?;
        let scan_at = |field: &str, folder: &str| -> Result<(PathBuf, Scan), ScanError> {
            let d = dir.join(folder);
            if !d.join(RECORD_FILE).is_file() {
                return Err(bad(format!(
                    "field {field}: expected a scan folder (with {RECORD_FILE}, as `palpate import depth|cloud` writes), found {:?}{}",
                    d.display().to_string(),
                    if d.exists() { "" } else { " (no such path)" }
                )));
            }
            let s = read_scan(&d).map_err(|e| bad(format!("field {field}: {e}")))?;
            Ok((d, s))
        };
        let rest = t
            .rest
            .as_deref()
            .map(|r| scan_at("rest", r).map(|(_, s)| s))
            .transpose()?;
        let mut states = Vec::new();
        for (i, s) in t.states.iter().enumerate() {
            let name = s.name.clone().unwrap_or_else(|| format!("state {}", i + 1));
            let at = |what: String| bad(format!("states[{i}] ({name:?}): {what}"));
            let group = |field: &str, g: &str| {
                mesh.group(g)
                    .map(<[usize]>::to_vec)
                    .map_err(|e| at(format!("field {field}: {e}")))
            };
            let (scan_dir, scan) = scan_at(&format!("states[{i}].scan"), &s.scan)?;
            if s.clamped.is_empty() && s.held.is_none() {
                return Err(at(
                    "fields clamped/held: expected at least one group holding the object, found none (it would fall)".into(),
                ));
            }
            let mut fixed = Vec::new();
            for g in &s.clamped {
                fixed.extend(group("clamped", g)?);
            }
            fixed.sort_unstable();
            fixed.dedup();
            let mut fixed_displacement = vec![[0.0; 3]; fixed.len()];
            if let Some(h) = &s.held {
                if h.angle_deg != 0.0
                    && h.axis.is_none_or(|a| {
                        Vector3::from(a).norm() == 0.0 || a.iter().any(|v| !v.is_finite())
                    })
                {
                    return Err(at(format!(
                        "field held.axis: expected a non-zero direction with angle_deg = {}, found {:?}",
                        h.angle_deg, h.axis
                    )));
                }
                let held = group("held.group", &h.group)?;
                if let Some(n) = held.iter().find(|n| fixed.binary_search(n).is_ok()) {
                    return Err(at(format!(
                        "field held.group: node {n} of group {:?} is also clamped; a node is either clamped or held",
                        h.group
                    )));
                }
                for n in held {
                    let x = mesh.nodes[n];
                    let y = h.apply(x);
                    fixed.push(n);
                    fixed_displacement.push([0, 1, 2].map(|k| y[k] - x[k]));
                }
            }
            let mut forces = Vec::new();
            for (j, l) in s.loads.iter().enumerate() {
                if l.force_n.iter().any(|f| !f.is_finite()) {
                    return Err(at(format!(
                        "field loads[{j}].force_n: expected three finite numbers (N), found {:?}",
                        l.force_n
                    )));
                }
                let nodes = group(&format!("loads[{j}].group"), &l.group)?;
                let share = 1.0 / nodes.len().max(1) as f64;
                forces.extend(nodes.iter().map(|&n| (n, l.force_n.map(|f| f * share))));
            }
            states.push(DatasetState {
                name,
                scan_dir,
                scan,
                toml: s.clone(),
                fixed,
                fixed_displacement,
                forces,
            });
        }
        let (lo, hi) = mesh.bounds();
        let diagonal = (Vector3::from(hi) - Vector3::from(lo)).norm();
        // A tenth of the object's size: enough surface to pin the scan, little of it bent; and
        // at least the longest surface edge from a fixed node, or a coarse mesh's band holds
        // no triangle but the clamped face itself, which the clamp hides.
        let mut fixed_nodes = vec![false; mesh.nodes.len()];
        for n in states.iter().flat_map(|s| s.fixed.iter()) {
            fixed_nodes[*n] = true;
        }
        let mut edge: f64 = 0.0;
        for tri in mesh.boundary_triangles() {
            for k in 0..3 {
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                if fixed_nodes[a] || fixed_nodes[b] {
                    let d = Vector3::from(mesh.nodes[a]) - Vector3::from(mesh.nodes[b]);
                    edge = edge.max(d.norm());
                }
            }
        }
        Ok(Self {
            dir,
            register: t.register,
            register_band_m: t
                .register_band_m
                .unwrap_or((0.1 * diagonal).max(1.01 * edge)),
            mesh,
            poisson,
            poisson_declared: t.poisson.is_some(),
            density: t.density,
            gravity: t.gravity,
            rest,
            states,
        })
    }

    /// State `i` as an object to fit, on `design`, Newton's tolerance `tol` (N).
    pub fn object(&self, i: usize, design: Design, tol: f64) -> LoadedObject<'_> {
        let s = &self.states[i];
        let mut o = LoadedObject::hanging(
            &self.mesh,
            s.fixed.clone(),
            self.density,
            self.gravity,
            self.poisson,
            design,
            tol,
        );
        o.fixed_displacement = s.fixed_displacement.clone();
        o.forces = s.forces.clone();
        // A held grip turned far is applied in more increments: each one's Newton starts
        // from the last equilibrium, and a tenth of a 60° twist is already a large step.
        if s.toml
            .held
            .as_ref()
            .is_some_and(|h| h.angle_deg.abs() > 20.0)
        {
            o.load_steps = 20;
        }
        o
    }

    /// State `i`'s fixed part ([`crate::registration::fixed_part_surface`]): the rest
    /// mesh's surface within [`Self::register_band_m`] of a clamped node, at rest, or of a held
    /// node, moved with its grip. Returns the nodes and the triangles.
    pub fn fixed_part(&self, i: usize) -> (Vec<[f64; 3]>, Vec<[usize; 3]>) {
        let s = &self.states[i];
        let held = s.toml.held.as_ref();
        let clamped =
            s.fixed.len() - held.map_or(0, |h| self.mesh.group(&h.group).map_or(0, <[usize]>::len));
        crate::registration::fixed_part_surface(
            &self.mesh,
            &s.fixed,
            self.register_band_m,
            |k, x| match held {
                Some(h) if k >= clamped => h.apply(x),
                _ => x,
            },
        )
    }

    /// Every state with its scan, ready for [`crate::fit::fit_states`].
    pub fn scan_states(&self, design: Design, tol: f64) -> Vec<ScanState<'_>> {
        (0..self.states.len())
            .map(|i| ScanState {
                name: self.states[i].name.clone(),
                object: self.object(i, design, tol),
                scan: self.states[i].scan.points.clone(),
            })
            .collect()
    }

    /// The weight of the object (N), from its mesh, density and gravity.
    pub fn weight(&self) -> f64 {
        let volume: f64 = self
            .mesh
            .tets
            .iter()
            .map(|t| palpate_fem::mesh::signed_volume(t.map(|n| self.mesh.nodes[n])).abs())
            .sum();
        volume * self.density * Vector3::from(self.gravity).norm()
    }
}

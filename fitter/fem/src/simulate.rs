//! One static interaction with the runtime — the same f32 warped-stiffness solver the haptic
//! loop runs — by incremental loading to equilibrium ([`simulate`]), and its one writer
//! ([`Simulation::write`]: the displacements as CSV with Gmsh node tags, the deformed mesh as
//! VTK for ParaView, a `summary.json`). `palpate simulate` parses its arguments into a
//! [`Request`], calls these and prints [`Simulation::sentence`].

use crate::export::{BlendData, ExportError, ModelBuffers, ProvenanceInfo};
use crate::forward::{ForwardError, Material, StaticProblem};
use crate::io::atomic::{write_atomic, write_atomic_with, AtomicWriteError};
use crate::io::csv::{CsvError, Table};
use crate::mesh::gmsh::MeshError;
use crate::mesh::vtk::{self, write_vtk, Field, VtkError};
use crate::mesh::Mesh;
use crate::runtime_storage::Storage;
use crate::sanity::{Findings, Refused};
use palpate_protocol::model::ModelRecord;
use palpate_runtime::material::LambdaAlpha;
use palpate_runtime::{
    ContactRule, Probe, Runtime, RuntimeConfig, RuntimeError, SolveStatus, TickReport,
};
use std::collections::{HashMap, HashSet};
use std::io::Write;
use std::path::{Path, PathBuf};

/// What went wrong, and where: the input file, line and field, or the tick.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SimulateError {
    /// The mesh of a homogeneous model could not be read.
    #[error("reading mesh {}", file.display())]
    ReadMesh {
        /// The mesh file.
        file: PathBuf,
        /// The reader's error.
        source: MeshError,
    },
    /// The clamped group is not in the mesh.
    #[error("mesh {}", file.display())]
    Group {
        /// The mesh file.
        file: PathBuf,
        /// The mesh's error, naming the groups it has.
        source: MeshError,
    },
    /// The clamped group holds no node.
    #[error("mesh {}: clamped group {group:?} (--clamps) has no nodes", file.display())]
    EmptyClamps {
        /// The mesh file.
        file: PathBuf,
        /// The group.
        group: String,
    },
    /// A homogeneous material outside E > 0, −1 < ν < 0.5.
    #[error("--young {young} --poisson {poisson}: need E > 0 and -1 < ν < 0.5")]
    Material {
        /// Young's modulus (Pa).
        young: f64,
        /// Poisson's ratio.
        poisson: f64,
    },
    /// The forward problem refused the mesh.
    #[error(transparent)]
    Forward(#[from] ForwardError),
    /// The model could not be built.
    #[error(transparent)]
    Export(#[from] ExportError),
    /// The node-force file could not be read as CSV.
    #[error(transparent)]
    Csv(#[from] CsvError),
    /// A node-force row names a node tag the model does not have.
    #[error("{}:{line}: field `node`: no node with Gmsh tag {tag} in the model", file.display())]
    UnknownNode {
        /// The node-force file.
        file: PathBuf,
        /// Its line.
        line: usize,
        /// The tag.
        tag: u64,
    },
    /// A nodal force beyond f32, which the runtime's forces are.
    #[error(
        "{}:{line}: field `{field}`: expected a force within f32 range, found {found:e} N",
        file.display()
    )]
    ForceRange {
        /// The node-force file.
        file: PathBuf,
        /// Its line.
        line: usize,
        /// The column.
        field: &'static str,
        /// The force read (N).
        found: f64,
    },
    /// A node-force file without rows.
    #[error(
        "{}: no force rows (expected a header `node,fx,fy,fz` and one line per loaded node, \
         Gmsh node tags and newtons)",
        file.display()
    )]
    NoForceRows {
        /// The node-force file.
        file: PathBuf,
    },
    /// A node-force file whose rows load no free node.
    #[error(
        "{}: {rows} force row(s), but none puts a non-zero force on a free node (the model \
         holds {fixed} fixed nodes, which do not move): nothing would be loaded",
        file.display()
    )]
    NothingLoaded {
        /// The node-force file.
        file: PathBuf,
        /// Its rows.
        rows: usize,
        /// The model's fixed nodes.
        fixed: usize,
    },
    /// The runtime refused the model or a load.
    #[error(transparent)]
    Runtime(#[from] RuntimeError),
    /// A flat probe without a direction.
    #[error("--flat-axis must not be zero")]
    FlatAxisZero,
    /// No load given.
    #[error("nothing to simulate: give --contact and --force, --probe, or --node-forces")]
    NothingToSimulate,
    /// A tick's solve was rejected.
    #[error(
        "the solve failed at tick {tick} (non-finite or indefinite): the load may invert elements"
    )]
    Rejected {
        /// The tick (1-based).
        tick: usize,
    },
    /// No tick ran.
    #[error("no tick ran")]
    NoTick,
    /// The result failed the sanity gates (nothing is written).
    #[error(transparent)]
    Refused(#[from] Refused),
    /// The output folder could not be made.
    #[error("creating {}", dir.display())]
    CreateDir {
        /// The folder.
        dir: PathBuf,
        /// The operating system's error.
        source: std::io::Error,
    },
    /// A file could not be written.
    #[error(transparent)]
    Write(#[from] AtomicWriteError),
    /// The VTK file could not be written.
    #[error(transparent)]
    Vtk(#[from] VtkError),
    /// The summary could not be serialised.
    #[error(transparent)]
    Json(#[from] serde_json::Error),
}

/// The mesh of a model record (rest positions, tets, node tags), for VTK output.
pub fn mesh_from_record(rec: &ModelRecord<'_>) -> Mesh {
    let n = rec.node_count as usize;
    let nodes = (0..n)
        .map(|i| [0, 1, 2].map(|k| rec.rest_positions.get(3 * i + k).unwrap_or(0.0) as f64))
        .collect();
    let tets = (0..rec.element_count as usize)
        .map(|e| [0, 1, 2, 3].map(|k| rec.tets.get(4 * e + k).unwrap_or(0) as usize))
        .collect();
    let node_tags = (0..n)
        .map(|i| rec.node_tags.get(i).unwrap_or(i as u32 + 1) as u64)
        .collect();
    Mesh {
        nodes,
        node_tags,
        tets,
        node_groups: Default::default(),
    }
}

/// Builds model buffers for a mesh file with a homogeneous material, clamped on `fixed_group`;
/// `tool` is the provenance's tool (the command and its version).
pub fn model_from_mesh(
    path: &Path,
    young: f64,
    poisson: f64,
    fixed_group: &str,
    tool: String,
) -> Result<ModelBuffers, SimulateError> {
    let mesh = crate::mesh::gmsh::read_msh(path).map_err(|source| SimulateError::ReadMesh {
        file: path.into(),
        source,
    })?;
    let fixed = mesh
        .group(fixed_group)
        .map_err(|source| SimulateError::Group {
            file: path.into(),
            source,
        })?
        .to_vec();
    if fixed.is_empty() {
        return Err(SimulateError::EmptyClamps {
            file: path.into(),
            group: fixed_group.into(),
        });
    }
    let p = LambdaAlpha::from_young_poisson(young, poisson);
    if !p.is_physical() {
        return Err(SimulateError::Material { young, poisson });
    }
    let surface = mesh.boundary_triangles();
    let problem = StaticProblem::new(&mesh, &fixed, &surface)?;
    let prov = ProvenanceInfo {
        tool,
        source: path.display().to_string(),
        notes: format!("homogeneous E = {young} Pa, ν = {poisson}"),
    };
    Ok(ModelBuffers::new(
        &problem,
        &mesh.node_tags,
        &[Material::homogeneous(p)],
        &BlendData::None,
        &prov,
    )?)
}

/// Reads `node,fx,fy,fz` (Gmsh tags; the header names the columns, in any order) into (node
/// index, force). A file with no record reads as no forces, which the caller refuses by name.
fn read_node_forces(path: &Path, tags: &[u64]) -> Result<Vec<(usize, [f32; 3])>, SimulateError> {
    let table = Table::read(path.to_path_buf())?;
    if table.is_blank() {
        return Ok(Vec::new());
    }
    let index: HashMap<u64, usize> = tags.iter().enumerate().map(|(i, t)| (*t, i)).collect();
    let mut out = Vec::new();
    for row in table.rows(&["node", "fx", "fy", "fz"], 0)? {
        let tag = row.unsigned(0)?;
        let node = *index.get(&tag).ok_or_else(|| SimulateError::UnknownNode {
            file: path.into(),
            line: row.line,
            tag,
        })?;
        // The runtime's forces are f32; a force beyond f32 is not finite there.
        let f = row.vec3(1)?.map(|v| v as f32);
        if let Some(k) = (0..3).find(|&k| !f[k].is_finite()) {
            return Err(SimulateError::ForceRange {
                file: path.into(),
                line: row.line,
                field: ["fx", "fy", "fz"][k],
                found: row.number(k + 1)?,
            });
        }
        out.push((node, f));
    }
    Ok(out)
}

/// Node forces read and judged before the runtime is built: a file with no rows, only zero
/// rows, or forces only on fixed nodes loads nothing, and "max |u| = 0" would read as a result.
fn loading_node_forces(
    path: &Path,
    record: &ModelRecord<'_>,
    tags: &[u64],
) -> Result<Vec<(usize, [f32; 3])>, SimulateError> {
    let forces = read_node_forces(path, tags)?;
    let fixed: HashSet<usize> = record.fixed_nodes.iter().map(|n| n as usize).collect();
    let loading = forces
        .iter()
        .filter(|(n, f)| !fixed.contains(n) && f.iter().any(|v| *v != 0.0))
        .count();
    if forces.is_empty() {
        return Err(SimulateError::NoForceRows { file: path.into() });
    }
    if loading == 0 {
        return Err(SimulateError::NothingLoaded {
            file: path.into(),
            rows: forces.len(),
            fixed: fixed.len(),
        });
    }
    Ok(forces)
}

/// A position-driven probe.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProbeRequest {
    /// Final position (m) of the probe: the sphere's centre, or a point of the flat face.
    pub position: [f64; 3],
    /// Radius (m).
    pub radius: f64,
    /// A flat punch pushing along this axis (normalised here; zero is refused) instead of a
    /// sphere.
    pub flat_axis: Option<[f64; 3]>,
}

/// What to simulate: the loads (any of them, at least one) and the solver's settings.
#[derive(Debug, Clone, PartialEq)]
pub struct Request {
    /// A force-driven contact: point on the rest surface (m), force (N), radius (m).
    pub contact: Option<([f64; 3], [f64; 3], f64)>,
    /// How the contact force is spread.
    pub contact_rule: ContactRule,
    /// Explicit nodal forces: a CSV file `node,fx,fy,fz` (Gmsh node tags, N).
    pub node_forces: Option<PathBuf>,
    /// A position-driven probe.
    pub probe: Option<ProbeRequest>,
    /// Stiffness warping (false: the linear model).
    pub warp: bool,
    /// Load increments of the incremental loading (at least 1).
    pub increments: usize,
}

/// A settled static interaction.
#[derive(Debug, Clone)]
pub struct Simulation {
    /// The model's mesh (rest positions, Gmsh node tags).
    pub mesh: Mesh,
    /// The runtime's displacements (m), three per node, as it computed them (f32).
    pub displacements: Vec<f32>,
    /// Young's modulus of each element (Pa) as the runtime holds it.
    pub young: Vec<f64>,
    /// Ticks run.
    pub ticks: usize,
    /// The last tick's report.
    pub last: TickReport,
    /// Whether the stiffness was warped.
    pub warp: bool,
    /// The sanity gates' warnings (their errors refuse the result).
    pub findings: Findings,
}

/// Runs `record` in the runtime under `request`'s loads until it settles, and judges the result
/// by the shared sanity gates: a load far outside the model's range, a solve that never settled,
/// a probe that touches nothing are errors, not results.
pub fn simulate(record: ModelRecord<'_>, request: &Request) -> Result<Simulation, SimulateError> {
    let mesh = mesh_from_record(&record);
    let increments = request.increments.max(1);
    let cfg = RuntimeConfig {
        warp: request.warp,
        tolerance: 1e-6,
        max_iterations: 20_000,
        rotation_iterations: 8,
        contact_rule: request.contact_rule,
        ..Default::default()
    };
    let node_forces = match &request.node_forces {
        Some(path) => loading_node_forces(path, &record, &mesh.node_tags)?,
        None => Vec::new(),
    };
    let mut storage = Storage::for_model(&record, &cfg);
    let mut rt = storage.runtime(record, cfg)?;
    apply_loads(&mut rt, request, &mesh, node_forces, increments)?;
    let cap = increments + 2000;
    let diagonal = crate::sanity::bounding_diagonal(&mesh.nodes);
    let (ticks, last, settled) = settle(&mut rt, cap, diagonal)?;
    let rep = last.ok_or(SimulateError::NoTick)?;
    let displacements = rt.displacements().to_vec();
    let young: Vec<f64> = (0..mesh.tets.len())
        .map(|e| {
            rt.element_parameters(e)
                .map(|(l, a)| {
                    LambdaAlpha {
                        lambda: l as f64,
                        alpha: a as f64,
                    }
                    .young()
                })
                .unwrap_or(0.0)
        })
        .collect();
    let sim = Simulation {
        mesh,
        displacements,
        young,
        ticks,
        last: rep,
        warp: request.warp,
        findings: Findings::default(),
    };
    let findings = sim.gates(settled, cap, request.probe.is_some());
    Ok(Simulation {
        findings: findings.into_result()?,
        ..sim
    })
}

/// Sets the request's loads on the runtime (the contact, the node forces, the probe) and the
/// load steps of the incremental loading; a request without any load is refused.
fn apply_loads(
    rt: &mut Runtime<'_>,
    request: &Request,
    mesh: &Mesh,
    node_forces: Vec<(usize, [f32; 3])>,
    increments: usize,
) -> Result<(), SimulateError> {
    let mut total_force = 0.0f64;
    let mut loads = 0;
    if let Some((c, f, radius)) = request.contact {
        rt.set_contact_force(c.map(|v| v as f32), f.map(|v| v as f32), radius as f32)?;
        total_force += (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt();
        loads += 1;
    }
    if request.node_forces.is_some() {
        for (node, f) in node_forces {
            rt.add_nodal_force(node, f)?;
            total_force += (f.iter().map(|v| (*v as f64).powi(2)).sum::<f64>()).sqrt();
        }
        loads += 1;
    }
    if let Some(p) = &request.probe {
        let (lo, hi) = mesh.bounds();
        let probe = match p.flat_axis {
            Some(a) => {
                let n = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
                if n == 0.0 {
                    return Err(SimulateError::FlatAxisZero);
                }
                Probe::Flat {
                    center: p.position.map(|v| v as f32),
                    axis: a.map(|v| (v / n) as f32),
                    radius: p.radius as f32,
                }
            }
            None => Probe::Sphere {
                center: p.position.map(|v| v as f32),
                radius: p.radius as f32,
            },
        };
        // Incremental loading of the probe: start just outside the body along the push direction
        // is not known in general, so move from the final position's distance to the bounding box.
        let travel = (0..3).map(|k| (hi[k] - lo[k]).abs()).fold(0.0, f64::max);
        rt.set_load_steps(f32::INFINITY, (travel / (10.0 * increments as f64)) as f32);
        rt.set_probe(probe)?;
        loads += 1;
    }
    if loads == 0 {
        return Err(SimulateError::NothingToSimulate);
    }
    if total_force > 0.0 {
        rt.set_load_steps((total_force / increments as f64) as f32, f32::INFINITY);
    }
    Ok(())
}

/// Ticks until the load is all applied and the last step is negligible (settled), the
/// displacements leave any sensible range, or `cap` ticks ran: returns the ticks, the last
/// tick's report and whether it settled. A rejected solve is an error.
fn settle(
    rt: &mut Runtime<'_>,
    cap: usize,
    diagonal: f64,
) -> Result<(usize, Option<TickReport>, bool), SimulateError> {
    let mut last = None;
    let mut ticks = 0;
    let mut settled = false;
    for _ in 0..cap {
        let rep = rt.tick();
        ticks += 1;
        if rep.status == SolveStatus::Rejected {
            return Err(SimulateError::Rejected { tick: ticks });
        }
        let umax = rt
            .displacements()
            .iter()
            .fold(0.0f32, |a, v| a.max(v.abs()));
        last = Some(rep);
        if rep.load_fraction >= 1.0
            && rep.step <= 1e-6 * umax.max(1e-12)
            && rep.status == SolveStatus::Converged
        {
            settled = true;
            break;
        }
        // Ten times the object's size is no deformation: stop instead of running to the cap.
        if !umax.is_finite() || f64::from(umax) > 10.0 * diagonal {
            break;
        }
    }
    Ok((ticks, last, settled))
}

impl Simulation {
    /// Each node's displacement (m) in f64.
    pub fn displacement_vectors(&self) -> Vec<[f64; 3]> {
        (0..self.mesh.nodes.len())
            .map(|i| [0, 1, 2].map(|k| self.displacements[3 * i + k] as f64))
            .collect()
    }

    /// The largest displacement's length (m).
    pub fn max_displacement(&self) -> f64 {
        self.displacement_vectors()
            .iter()
            .map(|d| (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt())
            .fold(0.0, f64::max)
    }

    /// The sanity gates on the result: displacements within the object's range, an incremental
    /// solve that settled within `cap` ticks, a probe that touches the object.
    fn gates(&self, settled: bool, cap: usize, probed: bool) -> Findings {
        let rep = &self.last;
        let mut findings =
            crate::sanity::check_displacements(&self.mesh.nodes, &self.displacement_vectors());
        if !settled {
            findings.error(
                "not-settled",
                format!(
                    "the incremental solve did not reach equilibrium within {} ticks (cap \
                     {cap}): load fraction {:.3}, last step {:.3e} m, relative residual {:.1e}",
                    self.ticks, rep.load_fraction, rep.step, rep.rel_residual
                ),
            );
        }
        if rep.contact_nodes == 0 && probed {
            let (lo, hi) = self.mesh.bounds();
            findings.error(
                "no-contact",
                format!(
                    "the probe touches no node of the object (bounding box [{:.4}, {:.4}] × \
                     [{:.4}, {:.4}] × [{:.4}, {:.4}] m): nothing would move",
                    lo[0], hi[0], lo[1], hi[1], lo[2], hi[2]
                ),
            );
        }
        findings
    }

    /// Writes `displacements.csv` (Gmsh node tags), `deformed.vtu` and `summary.json` into
    /// `dir` (made if missing) and returns their paths.
    pub fn write(&self, dir: &Path) -> Result<Vec<PathBuf>, SimulateError> {
        std::fs::create_dir_all(dir).map_err(|source| SimulateError::CreateDir {
            dir: dir.into(),
            source,
        })?;
        let u = &self.displacements;
        let csv = dir.join("displacements.csv");
        write_atomic_with(&csv, |w| {
            writeln!(w, "node,ux,uy,uz")?;
            for i in 0..self.mesh.nodes.len() {
                writeln!(
                    w,
                    "{},{:e},{:e},{:e}",
                    self.mesh.node_tags[i],
                    u[3 * i],
                    u[3 * i + 1],
                    u[3 * i + 2]
                )?;
            }
            Ok(())
        })?;
        // The rest mesh plus the displacement (write_vtk's convention): ParaView's Warp By
        // Vector then draws the deformed shape once.
        let vtu = dir.join("deformed.vtu");
        write_vtk(
            &vtu,
            &self.mesh,
            &[Field::vector(
                vtk::DISPLACEMENT,
                &self.displacement_vectors(),
            )],
            &[Field::scalar(vtk::YOUNG_MODULUS, &self.young)],
        )?;
        let rep = &self.last;
        let summary = serde_json::json!({
            "schema_version": 1,
            "kind": "simulation",
            "ticks": self.ticks,
            "status": format!("{:?}", rep.status),
            "rel_residual": rep.rel_residual,
            "max_displacement_m": self.max_displacement(),
            "probe_reaction_n": rep.reaction,
            "contact_nodes": rep.contact_nodes,
            "warp": self.warp,
        });
        let json = dir.join("summary.json");
        write_atomic(&json, serde_json::to_string_pretty(&summary)?.as_bytes())?;
        Ok(vec![csv, vtu, json])
    }

    /// One sentence for the user: the model's size, the ticks, how the last solve ended, the
    /// largest displacement and the probe's reaction.
    pub fn sentence(&self) -> String {
        let rep = &self.last;
        format!(
            "simulated {} nodes, {} tets in {} ticks ({}, relative residual {:.1e}); max |u| = {:.3} mm; probe reaction {:?} N",
            self.mesh.nodes.len(),
            self.mesh.tets.len(),
            self.ticks,
            match rep.status {
                SolveStatus::Converged => "converged",
                SolveStatus::BudgetExhausted => "stopped at its iteration budget",
                SolveStatus::Rejected => "rejected",
            },
            rep.rel_residual,
            self.max_displacement() * 1e3,
            rep.reaction
        )
    }
}

#[cfg(test)]
mod tests;

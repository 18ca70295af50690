//! `palpate simulate`: one static interaction with the runtime (the same f32 warped-stiffness
//! solver the haptic loop runs), by incremental loading to equilibrium; writes the displacements
//! as CSV (Gmsh node tags) and the deformed mesh as VTK for ParaView.

use anyhow::{bail, Context};
use palpate_fem::export::{ModelBuffers, ProvenanceInfo};
use palpate_fem::forward::{Material, StaticProblem};
use palpate_fem::io::atomic::write_atomic_with;
use palpate_fem::mesh::vtk::{self, write_vtk, Field};
use palpate_fem::mesh::Mesh;
use palpate_fem::runtime_storage::Storage;
use palpate_protocol::model::ModelRecord;
use palpate_runtime::material::LambdaAlpha;
use palpate_runtime::{ContactRule, Probe, RuntimeConfig, SolveStatus};
use palpate_static_fit::blend::BlendData;
use std::io::Write;
use std::path::{Path, PathBuf};

/// The contact rule on the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum RuleArg {
    /// Whole surface nodes within the radius, by lumped area.
    Lumped,
    /// Uniform pressure integrated consistently.
    Consistent,
}

/// Arguments of `palpate simulate`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// A fitted model: a runtime model (`.palp`), or a `fit.json` of `fit-motion` or `diagnose`
    /// (exported for the runtime on the mesh of a run it was fitted on); told apart by content.
    #[arg(long, conflicts_with_all = ["mesh", "young", "poisson", "clamps"])]
    pub model: Option<PathBuf>,
    /// A Gmsh 4.1 mesh (linear tetrahedra) to simulate with a homogeneous material.
    #[arg(long, requires_all = ["young", "poisson", "clamps"])]
    pub mesh: Option<PathBuf>,
    /// Young's modulus E (Pa) for `--mesh`.
    #[arg(long)]
    pub young: Option<f64>,
    /// Poisson ratio ν for `--mesh`.
    #[arg(long)]
    pub poisson: Option<f64>,
    /// The clamped face for `--mesh`: the name of the physical group whose nodes do not move
    /// (`--fixed` is its older name).
    #[arg(long, alias = "fixed", value_name = "GROUP")]
    pub clamps: Option<String>,
    /// Force-driven contact point x,y,z (m), on the rest surface.
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    pub contact: Option<[f64; 3]>,
    /// Contact force fx,fy,fz (N).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true, requires = "contact")]
    pub force: Option<[f64; 3]>,
    /// Contact radius (m): the force is spread over the free surface within it.
    #[arg(long, default_value_t = 0.015)]
    pub radius: f64,
    /// How the contact force is spread (runtime/src/contact_rule.rs): `lumped` (whole surface
    /// nodes within the radius by lumped area, the rule of static datasets and fits) or
    /// `consistent` (uniform pressure integrated on the surface inside the ball).
    #[arg(long, value_enum, default_value_t = RuleArg::Lumped)]
    pub contact_rule: RuleArg,
    /// Position-driven probe: final position x,y,z (m) of the probe (sphere centre, or a point
    /// of the flat face).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true, conflicts_with = "contact")]
    pub probe: Option<[f64; 3]>,
    /// Probe radius (m).
    #[arg(long, default_value_t = 0.01)]
    pub probe_radius: f64,
    /// Flat punch instead of a sphere, pushing along this unit axis (e.g. 0,0,-1).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    pub flat_axis: Option<[f64; 3]>,
    /// Explicit nodal forces: CSV with the header `node,fx,fy,fz` (columns in any order), Gmsh
    /// node tags and forces in N.
    #[arg(long)]
    pub node_forces: Option<PathBuf>,
    /// Linear model (no stiffness warping).
    #[arg(long)]
    pub no_warp: bool,
    /// Load increments of the incremental loading (docs/method.md), 1–1000: each increment is at
    /// least one solve, and a thousand already resolve any load path a static model can follow.
    #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(u32).range(1..=1000))]
    pub increments: u32,
    /// Output: the folder written.
    #[arg(
        short = 'o',
        long = "output",
        visible_alias = "out",
        value_name = "DIR",
        default_value = "simulate"
    )]
    pub out: PathBuf,
}

fn parse_vec3(s: &str) -> Result<[f64; 3], String> {
    let parts: Vec<&str> = s.split(',').collect();
    if parts.len() != 3 {
        return Err(format!(
            "expected three comma-separated numbers x,y,z, found {s:?}"
        ));
    }
    let mut v = [0.0; 3];
    for (k, p) in parts.iter().enumerate() {
        v[k] = p
            .trim()
            .parse::<f64>()
            .map_err(|e| format!("component {} ({p:?}): {e}", k + 1))?;
        if !v[k].is_finite() {
            return Err(format!("component {} is not finite", k + 1));
        }
    }
    Ok(v)
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

/// Builds model buffers for a mesh file with a homogeneous material.
pub fn model_from_mesh(
    path: &Path,
    young: f64,
    poisson: f64,
    fixed_group: &str,
) -> anyhow::Result<ModelBuffers> {
    let mesh = palpate_fem::mesh::gmsh::read_msh(path)
        .with_context(|| format!("reading mesh {}", path.display()))?;
    let fixed = mesh
        .group(fixed_group)
        .with_context(|| format!("mesh {}", path.display()))?
        .to_vec();
    if fixed.is_empty() {
        bail!(
            "mesh {}: clamped group {fixed_group:?} (--clamps) has no nodes",
            path.display()
        );
    }
    let p = LambdaAlpha::from_young_poisson(young, poisson);
    if !p.is_physical() {
        bail!("--young {young} --poisson {poisson}: need E > 0 and -1 < ν < 0.5");
    }
    let surface = mesh.boundary_triangles();
    let problem = StaticProblem::new(&mesh, &fixed, &surface)?;
    let prov = ProvenanceInfo {
        tool: format!("palpate {} simulate --mesh", env!("CARGO_PKG_VERSION")),
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
fn read_node_forces(path: &Path, tags: &[u64]) -> anyhow::Result<Vec<(usize, [f32; 3])>> {
    let table = palpate_fem::io::csv::Table::read(path.to_path_buf())?;
    if table.is_blank() {
        return Ok(Vec::new());
    }
    let index: std::collections::HashMap<u64, usize> =
        tags.iter().enumerate().map(|(i, t)| (*t, i)).collect();
    let mut out = Vec::new();
    for row in table.rows(&["node", "fx", "fy", "fz"], 0)? {
        let tag = row.unsigned(0)?;
        let node = *index.get(&tag).with_context(|| {
            format!(
                "{}:{}: field `node`: no node with Gmsh tag {tag} in the model",
                path.display(),
                row.line
            )
        })?;
        // The runtime's forces are f32; a force beyond f32 is not finite there.
        let f = row.vec3(1)?.map(|v| v as f32);
        if let Some(k) = (0..3).find(|&k| !f[k].is_finite()) {
            bail!(
                "{}:{}: field `{}`: expected a force within f32 range, found {:e} N",
                path.display(),
                row.line,
                ["fx", "fy", "fz"][k],
                row.number(k + 1)?
            );
        }
        out.push((node, f));
    }
    Ok(out)
}

/// Runs the command.
pub fn run(args: Args) -> anyhow::Result<()> {
    super::renamed::warn_if_used("--fixed", "--clamps");
    let bytes;
    let buffers;
    let record = match (&args.model, &args.mesh) {
        (Some(m), None) => {
            bytes = super::model_file::ModelFile::read(m, "simulate --model")?
                .into_runtime_bytes("simulate --model")?
                .1;
            palpate_protocol::model::decode(&bytes)
                .map_err(|e| anyhow::anyhow!("model {}: {e}", m.display()))?
        }
        (None, Some(mesh)) => {
            buffers = model_from_mesh(
                mesh,
                args.young.unwrap_or_default(),
                args.poisson.unwrap_or_default(),
                args.clamps.as_deref().unwrap_or_default(),
            )?;
            buffers.record()
        }
        _ => bail!(
            "give either --model FILE or --mesh FILE.msh --young E --poisson NU --clamps GROUP"
        ),
    };
    let mesh = mesh_from_record(&record);
    let increments = args.increments.max(1) as usize;
    let cfg = RuntimeConfig {
        warp: !args.no_warp,
        tolerance: 1e-6,
        max_iterations: 20_000,
        rotation_iterations: 8,
        contact_rule: match args.contact_rule {
            RuleArg::Lumped => ContactRule::Lumped,
            RuleArg::Consistent => ContactRule::Consistent,
        },
        ..Default::default()
    };
    // Node forces are read and judged before the runtime is built: a file with no rows, only
    // zero rows, or forces only on fixed nodes loads nothing, and "max |u| = 0" would read as a
    // result.
    let node_forces = match &args.node_forces {
        Some(path) => {
            let forces = read_node_forces(path, &mesh.node_tags)?;
            let fixed: std::collections::HashSet<usize> =
                record.fixed_nodes.iter().map(|n| n as usize).collect();
            let loading = forces
                .iter()
                .filter(|(n, f)| !fixed.contains(n) && f.iter().any(|v| *v != 0.0))
                .count();
            if forces.is_empty() {
                bail!(
                    "{}: no force rows (expected a header `node,fx,fy,fz` and one line per \
                     loaded node, Gmsh node tags and newtons)",
                    path.display()
                );
            }
            if loading == 0 {
                bail!(
                    "{}: {} force row(s), but none puts a non-zero force on a free node (the \
                     model holds {} fixed nodes, which do not move): nothing would be loaded",
                    path.display(),
                    forces.len(),
                    fixed.len()
                );
            }
            forces
        }
        None => Vec::new(),
    };
    let mut storage = Storage::for_model(&record, &cfg);
    let mut rt = storage.runtime(record, cfg)?;
    let mut total_force = 0.0f64;
    let mut loads = 0;
    if let (Some(c), Some(f)) = (args.contact, args.force) {
        rt.set_contact_force(c.map(|v| v as f32), f.map(|v| v as f32), args.radius as f32)?;
        total_force += (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt();
        loads += 1;
    }
    if args.node_forces.is_some() {
        for (node, f) in node_forces {
            rt.add_nodal_force(node, f)?;
            total_force += (f.iter().map(|v| (*v as f64).powi(2)).sum::<f64>()).sqrt();
        }
        loads += 1;
    }
    if let Some(p) = args.probe {
        let (lo, hi) = mesh.bounds();
        let probe = match args.flat_axis {
            Some(a) => {
                let n = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
                if n == 0.0 {
                    bail!("--flat-axis must not be zero");
                }
                Probe::Flat {
                    center: p.map(|v| v as f32),
                    axis: a.map(|v| (v / n) as f32),
                    radius: args.probe_radius as f32,
                }
            }
            None => Probe::Sphere {
                center: p.map(|v| v as f32),
                radius: args.probe_radius as f32,
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
        bail!("nothing to simulate: give --contact and --force, --probe, or --node-forces");
    }
    if total_force > 0.0 {
        rt.set_load_steps((total_force / increments as f64) as f32, f32::INFINITY);
    }
    let diagonal = palpate_fem::sanity::bounding_diagonal(&mesh.nodes);
    let mut last = None;
    let mut ticks = 0;
    let mut settled = false;
    let cap = increments + 2000;
    for _ in 0..cap {
        let rep = rt.tick();
        ticks += 1;
        if rep.status == SolveStatus::Rejected {
            bail!("the solve failed at tick {ticks} (non-finite or indefinite): the load may invert elements");
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
    let rep = last.context("no tick ran")?;
    let u = rt.displacements();
    let disp: Vec<[f64; 3]> = (0..mesh.nodes.len())
        .map(|i| [0, 1, 2].map(|k| u[3 * i + k] as f64))
        .collect();
    // Gates before anything is written: a load far outside the model's range, a solve that never
    // settled, a probe or contact that touches nothing are errors, not results.
    let mut findings = palpate_fem::sanity::check_displacements(&mesh.nodes, &disp);
    if !settled {
        findings.error(
            "not-settled",
            format!(
                "the incremental solve did not reach equilibrium within {ticks} ticks (cap {cap}): \
                 load fraction {:.3}, last step {:.3e} m, relative residual {:.1e}",
                rep.load_fraction, rep.step, rep.rel_residual
            ),
        );
    }
    if rep.contact_nodes == 0 && args.probe.is_some() {
        let (lo, hi) = mesh.bounds();
        findings.error(
            "no-contact",
            format!(
                "the probe touches no node of the object (bounding box [{:.4}, {:.4}] × [{:.4}, \
                 {:.4}] × [{:.4}, {:.4}] m): nothing would move",
                lo[0], hi[0], lo[1], hi[1], lo[2], hi[2]
            ),
        );
    }
    let findings = findings.into_result()?;
    for w in findings.warnings() {
        log::warn!("{w}");
    }
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    write_atomic_with(&args.out.join("displacements.csv"), |w| {
        writeln!(w, "node,ux,uy,uz")?;
        for i in 0..mesh.nodes.len() {
            writeln!(
                w,
                "{},{:e},{:e},{:e}",
                mesh.node_tags[i],
                u[3 * i],
                u[3 * i + 1],
                u[3 * i + 2]
            )?;
        }
        Ok(())
    })?;
    let params: Vec<f64> = (0..mesh.tets.len())
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
    // The rest mesh plus the displacement (write_vtk's convention): ParaView's Warp By Vector
    // then draws the deformed shape once.
    write_vtk(
        args.out.join("deformed.vtu"),
        &mesh,
        &[Field::vector(vtk::DISPLACEMENT, &disp)],
        &[Field::scalar(vtk::YOUNG_MODULUS, &params)],
    )?;
    let umax = disp
        .iter()
        .map(|d| (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt())
        .fold(0.0, f64::max);
    let summary = serde_json::json!({
        "schema_version": 1,
        "kind": "simulation",
        "ticks": ticks,
        "status": format!("{:?}", rep.status),
        "rel_residual": rep.rel_residual,
        "max_displacement_m": umax,
        "probe_reaction_n": rep.reaction,
        "contact_nodes": rep.contact_nodes,
        "warp": !args.no_warp,
    });
    palpate_fem::io::atomic::write_atomic(
        &args.out.join("summary.json"),
        serde_json::to_string_pretty(&summary)?.as_bytes(),
    )?;
    println!(
        "simulated {} nodes, {} tets in {ticks} ticks ({}, relative residual {:.1e}); max |u| = {:.3} mm; probe reaction {:?} N",
        mesh.nodes.len(),
        mesh.tets.len(),
        match rep.status {
            SolveStatus::Converged => "converged",
            SolveStatus::BudgetExhausted => "stopped at its iteration budget",
            SolveStatus::Rejected => "rejected",
        },
        rep.rel_residual,
        umax * 1e3,
        rep.reaction
    );
    log::info!(
        "wrote {}/displacements.csv, deformed.vtu, summary.json",
        args.out.display()
    );
    Ok(())
}

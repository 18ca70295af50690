//! `palpate simulate`: one static interaction with the runtime (the same f32 warped-stiffness
//! solver the haptic loop runs), by incremental loading to equilibrium; writes the displacements
//! as CSV (Gmsh node tags) and the deformed mesh as VTK for ParaView. The work is
//! `palpate_fem::simulate`'s: this parses, calls it and prints.

use anyhow::bail;
use palpate_fem::simulate::{model_from_mesh, simulate, ProbeRequest, Request};
use palpate_runtime::ContactRule;
use std::path::PathBuf;

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
                format!("palpate {} simulate --mesh", env!("CARGO_PKG_VERSION")),
            )?;
            buffers.record()
        }
        _ => bail!(
            "give either --model FILE or --mesh FILE.msh --young E --poisson NU --clamps GROUP"
        ),
    };
    let request = Request {
        contact: args
            .contact
            .zip(args.force)
            .map(|(c, f)| (c, f, args.radius)),
        contact_rule: match args.contact_rule {
            RuleArg::Lumped => ContactRule::Lumped,
            RuleArg::Consistent => ContactRule::Consistent,
        },
        node_forces: args.node_forces.clone(),
        probe: args.probe.map(|position| ProbeRequest {
            position,
            radius: args.probe_radius,
            flat_axis: args.flat_axis,
        }),
        warp: !args.no_warp,
        increments: args.increments.max(1) as usize,
    };
    let sim = simulate(record, &request)?;
    for w in sim.findings.warnings() {
        log::warn!("{w}");
    }
    sim.write(&args.out)?;
    println!("{}", sim.sentence());
    log::info!(
        "wrote {}/displacements.csv, deformed.vtu, summary.json",
        args.out.display()
    );
    Ok(())
}

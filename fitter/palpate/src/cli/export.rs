//! `palpate export --model fit.json --mesh object.msh --clamps <groups>`: a fitted material
//! as a runtime model (`.palp`) for any object of that material — another shape, or the fitted
//! object meshed again. The fit's modulus is its own mesh's; the material's is the one its
//! mesh-convergence check measured on quadratic elements (`fit.json`'s `converged`). On the new
//! mesh the runtime's per-element parameters are fitted to that material under probe presses
//! and the runtime's error against it is printed (`palpate_diagnose::runtime_match`).

use std::path::PathBuf;

use anyhow::Context;
use palpate_diagnose::runtime_match::match_fit_on;
use palpate_fem::export::{ModelBuffers, ProvenanceInfo};

use super::input_kind::{self, Kind};

/// Options.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The fitted material: a `fit.json` of `palpate fit-motion --mesh-convergence -o` or
    /// `palpate diagnose`, which records the material's modulus on quadratic elements.
    #[arg(long)]
    pub model: PathBuf,
    /// The object's tetrahedral mesh (Gmsh `.msh`, metres).
    #[arg(long)]
    pub mesh: PathBuf,
    /// The mesh's physical groups held fixed in the runtime, comma-separated.
    #[arg(long, value_delimiter = ',', required = true)]
    pub clamps: Vec<String>,
    /// Output: the runtime model.
    #[arg(
        short = 'o',
        long = "output",
        visible_alias = "out",
        value_name = "FILE",
        default_value = "model.palp"
    )]
    pub output: PathBuf,
}

/// Runs the command.
pub fn run(args: Args) -> anyhow::Result<()> {
    let fit = super::model_file::ModelFile::read(&args.model, "export --model")?
        .into_fit("export --model")?;
    input_kind::expect(&args.mesh, Kind::Gmsh, "export --mesh")?;
    super::output::check_writable(&args.output)?;
    let mesh = palpate_fem::mesh::gmsh::read_msh(&args.mesh)
        .with_context(|| format!("reading {}", args.mesh.display()))?;
    let mut fixed = Vec::new();
    for g in &args.clamps {
        fixed.extend_from_slice(
            mesh.group(g)
                .with_context(|| format!("{}", args.mesh.display()))?,
        );
    }
    fixed.sort_unstable();
    fixed.dedup();
    log::info!(
        "matching the runtime on {} ({} nodes, {} tets) to the material: 16 presses on \
         quadratic elements, then the static inverse",
        args.mesh.display(),
        mesh.nodes.len(),
        mesh.tets.len()
    );
    let m = match_fit_on(&fit, &mesh, &fixed).with_context(|| {
        format!(
            "exporting {} on {}",
            args.model.display(),
            args.mesh.display()
        )
    })?;
    println!("{}", m.markdown());
    let prov = ProvenanceInfo {
        tool: format!(
            "palpate {} {}",
            env!("CARGO_PKG_VERSION"),
            std::env::args().collect::<Vec<_>>().join(" ")
        ),
        source: args.model.display().to_string(),
        notes: format!(
            "the fitted material on {}; {}; {}",
            args.mesh.display(),
            palpate_motion::export::lost_in_export(
                &fit.material()
                    .map_err(|e| anyhow::anyhow!("{}: {e}", args.model.display()))?
            ),
            m.provenance()
        ),
    };
    let bytes = ModelBuffers::from_mesh(&mesh, &fixed, &m.material, &prov)
        .and_then(|b| b.write(&args.output))
        .with_context(|| format!("exporting {}", args.output.display()))?;
    log::info!(
        "wrote {} ({bytes} bytes): runtime model, parameters: {}",
        args.output.display(),
        m.chosen
    );
    Ok(())
}

//! `palpate export --model fit.json --mesh object.msh --clamps <groups>`: a fitted material
//! as a runtime model (`.palp`) for any object of that material — another shape, or the fitted
//! object meshed again. The fit's modulus is its own mesh's; the material's is the one its
//! mesh-convergence check measured on quadratic elements (`fit.json`'s `converged`). On the new
//! mesh the runtime's per-element parameters are fitted to that material under probe presses
//! and the runtime's error against it is printed (`palpate_diagnose::runtime_match`).

use std::path::PathBuf;

use anyhow::Context;
use palpate_diagnose::runtime_match::{match_runtime, MatchOptions};
use palpate_fem::export::{ModelBuffers, ProvenanceInfo};
use palpate_fem::forward::Material;
use palpate_motion::model::ParamKind;
use palpate_runtime::material::LambdaAlpha;

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
    let converged = fit.converged.clone().with_context(|| {
        format!(
            "{} records no converged modulus: fit it with `palpate fit-motion \
             --mesh-convergence` (or `palpate diagnose`, which checks it), so that its material, \
             not its mesh's, is what another mesh is given",
            args.model.display()
        )
    })?;
    let mat = fit
        .material()
        .map_err(|e| anyhow::anyhow!("{}: {e}", args.model.display()))?;
    let uniform = |k: ParamKind| {
        let v = &mat.values[k as usize];
        v.iter()
            .all(|x| (x - v[0]).abs() <= 1e-12 * v[0].abs())
            .then_some(v[0])
    };
    let (Some(lambda), Some(mu)) = (uniform(ParamKind::Lambda), uniform(ParamKind::Mu)) else {
        anyhow::bail!(
            "{}: its moduli vary between the elements of its own mesh, which another mesh does \
             not have; only a uniform material is carried",
            args.model.display()
        );
    };
    let mesh = palpate_fem::mesh::gmsh::read_msh(&args.mesh)
        .with_context(|| format!("reading {}", args.mesh.display()))?;
    let mut fixed = Vec::new();
    for g in &args.clamps {
        let nodes = mesh.node_groups.get(g).with_context(|| {
            format!(
                "{}: no physical group {g:?}; it has {:?}",
                args.mesh.display(),
                mesh.node_groups.keys().collect::<Vec<_>>()
            )
        })?;
        fixed.extend_from_slice(nodes);
    }
    fixed.sort_unstable();
    fixed.dedup();
    let as_fitted = Material::homogeneous(LambdaAlpha::from_lame(lambda, mu));
    log::info!(
        "matching the runtime on {} ({} nodes, {} tets) to the material: 16 presses on \
         quadratic elements, then the static inverse",
        args.mesh.display(),
        mesh.nodes.len(),
        mesh.tets.len()
    );
    let m = match_runtime(
        &mesh,
        &fixed,
        &as_fitted,
        &converged,
        &MatchOptions::default(),
    )
    .context("matching the runtime's model to the material")?;
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
            palpate_motion::export::lost_in_export(&mat),
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

//! `palpate info <file>`: what a palpate file is and where it came from — a runtime model
//! (`.palp`: format, sizes, material layout and range, blend, provenance, the runtime memory it
//! needs), a fitted motion model (`fit.json` of `fit-motion`/`diagnose`), or a dataset directory.
//! The last line is one JSON object with the same facts, for scripts.

use std::path::PathBuf;

use anyhow::Context;
use palpate_protocol::model::{Blend, ModelRecord};
use palpate_runtime::material::LambdaAlpha;

/// Options.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// A `.palp` model, a `fit.json` of `fit-motion`/`diagnose`, or a dataset directory.
    pub file: PathBuf,
}

/// Runs the command.
pub fn run(args: Args) -> anyhow::Result<()> {
    let path = &args.file;
    if path.is_dir() {
        return dataset(path);
    }
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    if bytes.starts_with(b"{") {
        return fitted(path, &bytes);
    }
    let record = palpate_protocol::model::decode(&bytes)
        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    model(path, &bytes, &record)
}

fn model(path: &std::path::Path, bytes: &[u8], r: &ModelRecord<'_>) -> anyhow::Result<()> {
    let p = &r.parameters;
    let young: Vec<f64> = (0..p.lambda.len())
        .filter_map(|i| {
            Some(
                LambdaAlpha {
                    lambda: p.lambda.get(i)? as f64,
                    alpha: p.alpha.get(i)? as f64,
                }
                .young(),
            )
        })
        .collect();
    let (lo, hi) = young
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
            (a.min(*v), b.max(*v))
        });
    let blend = match r.blend {
        Blend::None => "none (linear material)",
        Blend::Deformation { .. } => "deformation-space RBF (§6.2.3)",
        Blend::Strain { .. } => "strain-space RBF (§6.2.4)",
    };
    let cfg = palpate_runtime::RuntimeConfig::default();
    let need = palpate_runtime::StorageRequirement::for_model(r, &cfg);
    println!("{}: palpate model, {} bytes", path.display(), bytes.len());
    println!(
        "  mesh: {} nodes, {} tetrahedra, {} fixed nodes, {} surface triangles",
        r.node_count,
        r.element_count,
        r.fixed_nodes.len(),
        r.surface_triangles.len() / 3
    );
    println!(
        "  material: {:?}, {} parameter set(s); Young's modulus {:.4e}–{:.4e} Pa; blend: {blend}",
        p.layout, p.count, lo, hi
    );
    println!(
        "  provenance: {} | created {} | source {} | {}",
        r.provenance.tool, r.provenance.created, r.provenance.source, r.provenance.notes
    );
    println!(
        "  runtime memory with the default configuration: {} bytes",
        need.bytes()
    );
    let json = serde_json::json!({
        "kind": "palp",
        "bytes": bytes.len(),
        "nodes": r.node_count,
        "tets": r.element_count,
        "fixed_nodes": r.fixed_nodes.len(),
        "parameter_sets": p.count,
        "young_min_pa": lo,
        "young_max_pa": hi,
        "blend": blend,
        "tool": r.provenance.tool,
        "created": r.provenance.created,
        "source": r.provenance.source,
        "notes": r.provenance.notes,
        "runtime_bytes": need.bytes(),
    });
    println!("{json}");
    Ok(())
}

fn fitted(path: &std::path::Path, bytes: &[u8]) -> anyhow::Result<()> {
    let f: palpate_motion::fitted::FittedModel =
        serde_json::from_slice(bytes).with_context(|| {
            format!(
            "{}: JSON, but not a fitted motion model (the `fit.json` of fit-motion or diagnose)",
            path.display()
        )
        })?;
    let mu = f.mu.iter().sum::<f64>() / f.mu.len().max(1) as f64;
    let la = f.lambda.iter().sum::<f64>() / f.lambda.len().max(1) as f64;
    let e = mu * (3.0 * la + 2.0 * mu) / (la + mu);
    let nu = la / (2.0 * (la + mu));
    println!("{}: fitted motion model ({})", path.display(), f.format);
    println!("  mesh: {} nodes, {} tetrahedra", f.nodes, f.tets);
    println!(
        "  fitted: {}; E {:.4e} Pa, Poisson's ratio {:.3}{}; viscosity {:.4e} Pa·s^h, h {:.3}; density {:.1} kg/m³; hanging inertia {}",
        f.fitted.join(", "),
        e,
        nu,
        if f.poisson_fixed.is_some() { " (held)" } else { "" },
        f.viscosity.first().copied().unwrap_or(f64::NAN),
        f.h.first().copied().unwrap_or(f64::NAN),
        f.density.first().copied().unwrap_or(f64::NAN),
        f.hanging_inertia
    );
    println!(
        "  fitted on {} run(s): {}; marker RMS {:.3} mm",
        f.runs.len(),
        f.datasets.join(", "),
        1e3 * f.rms_marker_m
    );
    let json = serde_json::json!({
        "kind": "motion-fit",
        "nodes": f.nodes,
        "tets": f.tets,
        "young_pa": e,
        "poisson": nu,
        "viscosity": f.viscosity.first(),
        "h": f.h.first(),
        "hanging_inertia": f.hanging_inertia,
        "runs": f.datasets,
        "rms_marker_m": f.rms_marker_m,
    });
    println!("{json}");
    Ok(())
}

fn dataset(dir: &std::path::Path) -> anyhow::Result<()> {
    if let Ok(ds) = palpate_motion::dataset::load(dir) {
        let observed: usize = ds
            .obs
            .markers
            .iter()
            .map(|r| r.iter().filter(|m| m.is_some()).count())
            .sum();
        println!(
            "{}: motion dataset; {} nodes, {} tets; {} steps of {} s; {} markers ({} observations); clamps {:?}; {} dead load(s); gravity {:?}",
            dir.display(),
            ds.mesh.nodes.len(),
            ds.mesh.tets.len(),
            ds.model.steps,
            ds.model.dt,
            ds.model.markers.len(),
            observed,
            ds.config.clamps,
            ds.model.loads.len(),
            ds.model.gravity
        );
        println!(
            "{}",
            serde_json::json!({"kind": "motion-dataset", "nodes": ds.mesh.nodes.len(), "tets": ds.mesh.tets.len(), "steps": ds.model.steps, "dt": ds.model.dt, "markers": ds.model.markers.len(), "loads": ds.model.loads.len()})
        );
        return Ok(());
    }
    let ds = palpate_fem::dataset::StaticDataset::read(dir)
        .with_context(|| format!("{}: neither a motion nor a static dataset", dir.display()))?;
    println!(
        "{}: static dataset {:?}; {} nodes, {} tets; {} markers; {} measurements; marker noise {}",
        dir.display(),
        ds.name,
        ds.mesh.nodes.len(),
        ds.mesh.tets.len(),
        ds.markers.len(),
        ds.measurements.len(),
        ds.marker_noise
            .map(|s| format!("{:.1} µm", 1e6 * s))
            .unwrap_or_else(|| "not declared".into())
    );
    println!(
        "{}",
        serde_json::json!({"kind": "static-dataset", "name": ds.name, "nodes": ds.mesh.nodes.len(), "tets": ds.mesh.tets.len(), "markers": ds.markers.len(), "measurements": ds.measurements.len(), "marker_noise_m": ds.marker_noise})
    );
    Ok(())
}

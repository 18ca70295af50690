//! `palpate info <file>`: what a palpate file is and where it came from — a runtime model
//! (`.palp`: format, sizes, material layout and range, blend, provenance, the runtime memory it
//! needs), a fitted motion model (`fit.json` of `fit-motion`/`diagnose`), a dataset directory, or
//! a motion capture (C3D: its markers, rate, frames and gaps — what `palpate import c3d` will read),
//! or a Gmsh mesh (its size, extent, volume and the physical groups clamps and loads can name),
//! or a scan folder of `palpate import depth|cloud` (its points, bounds, units, camera, noise), or
//! a scan dataset (its mesh, material and states: what `palpate fit-scan` will fit).
//! The last line is one JSON object with the same facts, for scripts.

use std::path::PathBuf;

use anyhow::Context;
use palpate_fem::names::Elastic;
use palpate_protocol::model::{Blend, ModelRecord};
use palpate_runtime::material::LambdaAlpha;

/// The `schema_version` of the JSON line (`docs/json-outputs.md`).
const SCHEMA_VERSION: u32 = 1;

/// Options.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// A `.palp` model, a `fit.json` of `fit-motion`/`diagnose`, a dataset directory, a C3D
    /// capture, a Gmsh mesh (`.msh`), a scan folder (or its `scan.toml`), or a scan dataset
    /// (a folder with `scans.toml`).
    pub file: PathBuf,
}

/// Runs the command.
pub fn run(args: Args) -> anyhow::Result<()> {
    let path = &args.file;
    if super::import_scan::is_scan(path) {
        return super::import_scan::info(path);
    }
    if palpate_scan::dataset::is_scan_dataset(path) {
        return super::fit_scan::info(path);
    }
    if path.is_dir() {
        return dataset(path);
    }
    if super::input_kind::recognise(path) == Some(super::input_kind::Kind::Stl) {
        super::input_kind::expect_one_of(
            path,
            &[
                super::input_kind::Kind::Palp,
                super::input_kind::Kind::FitJson,
                super::input_kind::Kind::C3d,
                super::input_kind::Kind::Gmsh,
                super::input_kind::Kind::StaticDataset,
                super::input_kind::Kind::MotionDataset,
            ],
            "info",
        )?;
    }
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    if bytes.starts_with(b"{") {
        return fitted(path, &bytes);
    }
    if bytes.starts_with(b"$MeshFormat") {
        return mesh(path);
    }
    // A C3D file's header block starts with the parameter section's block number and the key
    // byte 0x50; a palpate model starts with "PALP".
    if bytes.get(1) == Some(&0x50) && !bytes.starts_with(b"PALP") {
        return capture(path);
    }
    let record = palpate_protocol::model::decode(&bytes)
        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    model(path, &bytes, &record)
}

/// A Gmsh mesh as palpate reads it: nodes, tetrahedra, extent, volume, what the reader repaired,
/// and the physical groups (the names `clamps`, `--clamps`, `--hang` and `group` refer to).
fn mesh(path: &std::path::Path) -> anyhow::Result<()> {
    let (m, report) = palpate_fem::mesh::gmsh::read_msh_with_report(path)?;
    let (lo, hi) = m.bounds();
    let extent = [0, 1, 2].map(|k| hi[k] - lo[k]);
    let volume: f64 = m
        .tets
        .iter()
        .map(|t| palpate_fem::mesh::signed_volume(t.map(|n| m.nodes[n])))
        .sum();
    let quadratic = if report.quadratic_tets > 0 {
        format!(
            "; {} 10-node tetrahedra read as their corners ({} edge nodes set aside, an edge \
             node up to {:.2} % of its edge's length off the midpoint: {})",
            report.quadratic_tets,
            report.edge_nodes,
            100.0 * report.largest_edge_bow,
            if report.largest_edge_bow > palpate_fem::mesh::gmsh::CURVED_EDGE {
                "curved edges taken straight"
            } else {
                "straight edges"
            }
        )
    } else {
        String::new()
    };
    println!(
        "{}: Gmsh mesh ({}); {} nodes, {} tetrahedra; extent {:.1} × {:.1} × {:.1} mm; volume {:.3e} m³; {} tetrahedra re-oriented, {} unused nodes dropped{quadratic}",
        path.display(),
        if report.binary { "binary" } else { "ASCII" },
        m.nodes.len(),
        m.tets.len(),
        1e3 * extent[0],
        1e3 * extent[1],
        1e3 * extent[2],
        volume,
        report.reoriented,
        report.dropped_nodes
    );
    println!("| physical group | nodes |\n|---|---|");
    for (name, nodes) in &m.node_groups {
        println!("| {name} | {} |", nodes.len());
    }
    let groups: serde_json::Map<String, serde_json::Value> = m
        .node_groups
        .iter()
        .map(|(n, v)| (n.clone(), serde_json::json!(v.len())))
        .collect();
    println!(
        "{}",
        serde_json::json!({"schema_version": SCHEMA_VERSION, "kind": "mesh", "format": "msh", "nodes": m.nodes.len(), "tets": m.tets.len(), "extent_m": extent, "volume_m3": volume, "reoriented": report.reoriented, "dropped_nodes": report.dropped_nodes, "quadratic_tets": report.quadratic_tets, "edge_nodes": report.edge_nodes, "largest_edge_bow": report.largest_edge_bow, "groups": groups})
    );
    Ok(())
}

/// A motion capture: markers, rate, frames, and each marker's gaps.
fn capture(path: &std::path::Path) -> anyhow::Result<()> {
    let c = palpate_capture::read_c3d(path)?;
    let frames = c.positions.len();
    println!(
        "{}: C3D motion capture; {} markers at {} Hz, {frames} frames ({:.2} s, first frame number {})",
        path.display(),
        c.labels.len(),
        c.rate_hz,
        frames as f64 / c.rate_hz.max(f64::MIN_POSITIVE),
        c.first_frame
    );
    println!("| marker | seen in frames | first seen | travel from its first place (mm) |\n|---|---|---|---|");
    let mut markers = Vec::new();
    for (k, label) in c.labels.iter().enumerate() {
        let seen: Vec<(usize, [f64; 3])> = c
            .positions
            .iter()
            .enumerate()
            .filter_map(|(f, row)| row.get(k).copied().flatten().map(|p| (f, p)))
            .collect();
        let travel = seen.first().map_or(0.0, |(_, p0)| {
            seen.iter()
                .map(|(_, p)| (0..3).map(|i| (p[i] - p0[i]).powi(2)).sum::<f64>().sqrt())
                .fold(0.0, f64::max)
        });
        println!(
            "| {label} | {} of {frames} | {} | {:.1} |",
            seen.len(),
            seen.first().map_or("never".into(), |(f, _)| f.to_string()),
            1e3 * travel
        );
        markers.push(
            serde_json::json!({"label": label, "frames_seen": seen.len(), "max_travel_m": travel}),
        );
    }
    println!(
        "import it onto a mesh: palpate import c3d {} --mesh M.msh --places P.csv --clamps G --gravity gx,gy,gz -o DIR",
        path.display()
    );
    println!(
        "{}",
        serde_json::json!({"schema_version": SCHEMA_VERSION, "kind": "capture", "format": "c3d", "markers": c.labels.len(), "rate_hz": c.rate_hz, "frames": frames, "first_frame": c.first_frame, "per_marker": markers})
    );
    Ok(())
}

/// The smallest and largest of `v`.
fn range(v: impl Iterator<Item = f64>) -> (f64, f64) {
    v.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
        (a.min(x), b.max(x))
    })
}

fn model(path: &std::path::Path, bytes: &[u8], r: &ModelRecord<'_>) -> anyhow::Result<()> {
    let p = &r.parameters;
    let elastic: Vec<Elastic> = (0..p.lambda.len())
        .filter_map(|i| {
            Some(Elastic::of(&LambdaAlpha {
                lambda: p.lambda.get(i)? as f64,
                alpha: p.alpha.get(i)? as f64,
            }))
        })
        .collect();
    let (lo, hi) = range(elastic.iter().map(|e| e.young_modulus_pa));
    let (nu_lo, nu_hi) = range(elastic.iter().map(|e| e.poisson_ratio));
    let (l_lo, l_hi) = range(elastic.iter().map(|e| e.lame_lambda_pa));
    let (m_lo, m_hi) = range(elastic.iter().map(|e| e.shear_modulus_pa));
    let blend = match r.blend {
        Blend::None => "none (linear material)",
        Blend::Deformation { .. } => {
            "deformation-space radial basis functions (the thesis' non-linear homogeneous material)"
        }
        Blend::Strain { .. } => {
            "strain-space radial basis functions (the thesis' non-linear inhomogeneous material)"
        }
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
        "  material: {:?}, {} parameter set(s); Young's modulus E {:.4e}–{:.4e} Pa, Poisson's ratio ν {:.4}–{:.4}; Lamé λ {:.4e}–{:.4e} Pa, shear modulus μ {:.4e}–{:.4e} Pa; blend: {blend}",
        p.layout, p.count, lo, hi, nu_lo, nu_hi, l_lo, l_hi, m_lo, m_hi
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
        "schema_version": SCHEMA_VERSION,
        "kind": "palp",
        "bytes": bytes.len(),
        "nodes": r.node_count,
        "tets": r.element_count,
        "fixed_nodes": r.fixed_nodes.len(),
        "parameter_sets": p.count,
        "young_modulus_min_pa": lo,
        "young_modulus_max_pa": hi,
        "poisson_ratio_min": nu_lo,
        "poisson_ratio_max": nu_hi,
        "lame_lambda_min_pa": l_lo,
        "lame_lambda_max_pa": l_hi,
        "shear_modulus_min_pa": m_lo,
        "shear_modulus_max_pa": m_hi,
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
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    let e = Elastic::from_lame(mean(&f.lambda), mean(&f.mu));
    println!("{}: fitted motion model ({})", path.display(), f.format);
    println!("  mesh: {} nodes, {} tetrahedra", f.nodes, f.tets);
    println!(
        "  fitted: {}; E {:.4e} Pa, Poisson's ratio ν {:.3}{}; Lamé λ {:.4e} Pa, shear modulus μ {:.4e} Pa; viscosity {:.4e} Pa·s^h, power-law index h {:.3}; density {:.1} kg/m³; hanging inertia {}; time offset per run {}",
        f.fitted.join(", "),
        e.young_modulus_pa,
        e.poisson_ratio,
        if f.poisson_fixed.is_some() { " (held)" } else { "" },
        e.lame_lambda_pa,
        e.shear_modulus_pa,
        f.viscosity.first().copied().unwrap_or(f64::NAN),
        f.h.first().copied().unwrap_or(f64::NAN),
        f.density.first().copied().unwrap_or(f64::NAN),
        f.hanging_inertia,
        f.time_offset
    );
    println!(
        "  fitted on {} run(s): {}; marker RMS {:.3} mm",
        f.runs.len(),
        f.datasets.join(", "),
        1e3 * f.rms_marker_m
    );
    let json = serde_json::json!({
        "schema_version": SCHEMA_VERSION,
        "kind": "motion-fit",
        "nodes": f.nodes,
        "tets": f.tets,
        "young_modulus_pa": e.young_modulus_pa,
        "poisson_ratio": e.poisson_ratio,
        "lame_lambda_pa": e.lame_lambda_pa,
        "shear_modulus_pa": e.shear_modulus_pa,
        "viscosity_pa_s_h": f.viscosity.first(),
        "power_law_index": f.h.first(),
        "density_kg_m3": f.density.first(),
        "hanging_inertia": f.hanging_inertia,
        "time_offset": f.time_offset,
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
            "{}: motion dataset; {} nodes, {} tets; {}; {} markers ({} observations); clamps {:?}; {} dead load(s); gravity {:?}",
            dir.display(),
            ds.mesh.nodes.len(),
            ds.mesh.tets.len(),
            ds.steps_sentence(),
            ds.model.markers.len(),
            observed,
            ds.config.clamps,
            ds.model.loads.len(),
            ds.model.gravity
        );
        println!("time step: {}", ds.timestep.describe());
        println!(
            "{}",
            serde_json::json!({"schema_version": SCHEMA_VERSION, "kind": "motion-dataset", "nodes": ds.mesh.nodes.len(), "tets": ds.mesh.tets.len(), "steps": ds.capture_steps(), "dt_s": ds.config.dt, "substeps": ds.model.substeps, "markers": ds.model.markers.len(), "loads": ds.model.loads.len()})
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
        serde_json::json!({"schema_version": SCHEMA_VERSION, "kind": "static-dataset", "name": ds.name, "nodes": ds.mesh.nodes.len(), "tets": ds.mesh.tets.len(), "markers": ds.markers.len(), "measurements": ds.measurements.len(), "marker_noise_m": ds.marker_noise})
    );
    Ok(())
}

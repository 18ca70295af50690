//! `palpate fit-scan <dataset> -o <dir>`: Young's modulus of an object from scans of it hanging,
//! held or twisted (a scan dataset, docs/scan-dataset.md), every state at once, on quadratic
//! tetrahedra by default; then a second material searched for (`--single-material` skips it).
//! Writes `fit.json`, `report.md`, each state's residual as VTU and drawn on its fitted surface,
//! and a histogram of the residual.

use std::path::{Path, PathBuf};

use anyhow::Context;
use palpate_diagnose::scans::report::file_stem;
use palpate_scan::dataset::ScanDataset;
use palpate_scan::dataset_fit::{fit_dataset, DatasetFit, DatasetFitOptions, StateSummary};
use palpate_scan::fit::Design;
use palpate_scan::residual_vtu::write_fit_residual;

/// Options.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The scan dataset: a folder with `scans.toml` (docs/scan-dataset.md).
    pub dataset: PathBuf,
    /// Element design: p2 (quadratic tetrahedra on the mesh's corners; linear ones lock in
    /// bending near incompressibility) or p1 (the mesh's own linear tetrahedra).
    #[arg(long, default_value = "p2", value_parser = ["p1", "p2"])]
    pub design: String,
    /// Fit one material only: do not search for a second.
    #[arg(long)]
    pub single_material: bool,
    /// Trial Young's moduli (kPa) to start from, the one whose surfaces lie nearest the scans
    /// (default: 10 kPa to 2.56 MPa, a factor 2 apart; a start 3× off may settle in a wrong
    /// pairing of the scan's faces with the model's).
    #[arg(long, value_delimiter = ',', value_name = "KPA")]
    pub starts: Vec<f64>,
    /// Gauss–Newton iterations at most.
    #[arg(long = "max-iterations", default_value_t = 30)]
    pub max_iter: usize,
    /// Output: the folder written (`fit.json`, `report.md`, `<state>-points.vtu`,
    /// `<state>-surface.vtu`, `<state>-residual.svg`/`.png`, `residual.svg`/`.png`).
    #[arg(
        short = 'o',
        long = "output",
        visible_alias = "out",
        value_name = "DIR",
        default_value = "scan-fit"
    )]
    pub output: PathBuf,
    #[command(flatten)]
    pub plots: super::output::PlotArgs,
}

/// Runs the fit and writes its folder.
pub fn run(args: Args) -> anyhow::Result<()> {
    args.plots.apply();
    if let Some(bad) = args.starts.iter().find(|s| !(s.is_finite() && **s > 0.0)) {
        anyhow::bail!(
            "--starts: every trial modulus must be a positive number of kPa, found {bad}"
        );
    }
    super::output::check_writable(&args.output.join("fit.json"))?;
    let dataset = ScanDataset::read(&args.dataset)?;
    let mut options = DatasetFitOptions {
        design: if args.design == "p1" {
            Design::Linear
        } else {
            Design::Quadratic
        },
        regions: !args.single_material,
        max_iter: args.max_iter,
        ..DatasetFitOptions::default()
    };
    if !args.starts.is_empty() {
        options.start_young = args.starts.iter().map(|e| 1e3 * e).collect();
    }
    if !dataset.poisson_declared {
        log::info!(
            "{}: no poisson given; ν = {} (a silicone's) is held",
            args.dataset.display(),
            dataset.poisson
        );
    }
    let fit = fit_dataset(&dataset, &options)?;
    let staged = super::output::Staged::new(&args.output)?;
    let files = write(&staged.path, &args.dataset, &dataset, &fit)?;
    for f in staged.commit(files)? {
        log::info!("wrote {}", f.display());
    }
    println!("{}", summary(&fit));
    println!("{}", fit.to_json());
    Ok(())
}

/// Writes the folder's files into `dir`; returns them.
fn write(
    dir: &Path,
    name: &Path,
    dataset: &ScanDataset,
    fit: &DatasetFit,
) -> anyhow::Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    let json = dir.join("fit.json");
    palpate_fem::io::atomic::write_atomic(
        &json,
        serde_json::to_string_pretty(&fit.to_json())?.as_bytes(),
    )
    .with_context(|| format!("writing {}", json.display()))?;
    files.push(json);
    let mut maps = Vec::new();
    for (i, s) in dataset.states.iter().enumerate() {
        let state_fit = fit.state_fit(i);
        let stem = file_stem(&s.name);
        files.extend(write_fit_residual(dir, &stem, &s.scan.points, &state_fit)?);
        let file = format!("{stem}-residual.svg");
        match residual_figure(&dir.join(&file), &fit.states[i], &state_fit) {
            Ok(f) => {
                files.extend(f);
                maps.push(Some(palpate_plot::shown(&file)));
            }
            Err(e) => {
                log::warn!("{}: the residual's map was not drawn: {e}", s.name);
                maps.push(None);
            }
        }
    }
    let values = fit.scaled_residuals();
    let figure = palpate_plot::shown("residual.svg");
    match palpate_plot::histogram(
        dir.join("residual.svg"),
        "Scan residual at the fit, every state (points with a weight)",
        "signed distance / noise σ",
        &values,
        41,
    ) {
        Ok(f) => files.extend(f),
        Err(e) => log::warn!("the residual's histogram was not drawn: {e}"),
    }
    let report = dir.join("report.md");
    palpate_fem::io::atomic::write_atomic(
        &report,
        fit.report_markdown(&name.display().to_string(), &figure, &maps)
            .as_bytes(),
    )
    .with_context(|| format!("writing {}", report.display()))?;
    files.push(report);
    Ok(files)
}

/// A state's residual drawn on its fitted surface, titled with its RMS against its noise.
fn residual_figure(
    path: &Path,
    state: &StateSummary,
    fit: &palpate_scan::fit::ScanFit,
) -> anyhow::Result<Vec<PathBuf>> {
    let title = format!(
        "{}: scan residual on the fitted surface, RMS {:.3} mm, noise {:.3} mm ({:.2}×)",
        state.name,
        1e3 * state.rms_m,
        1e3 * state.noise_m,
        state.ratio()
    );
    palpate_diagnose::scans::report::residual_figure(path, &title, fit).map_err(anyhow::Error::msg)
}

/// The lines printed on stdout before the JSON.
fn summary(fit: &DatasetFit) -> String {
    let s = &fit.single;
    let mut out = format!(
        "E = {:.1} kPa ± {:.1} kPa (one material, {}, ν = {}); residual RMS {:.3} mm against a noise floor of {:.3} mm ({:.2}×)",
        s.young_modulus(0) / 1e3,
        s.young_modulus(0) * s.sigma_ln_mu(0) / 1e3,
        fit.design.name(),
        fit.poisson,
        1e3 * fit.rms_m(),
        1e3 * fit.noise_m(),
        fit.rms_m() / fit.noise_m()
    );
    if let Some(b) = fit.search.as_ref().and_then(|r| r.best.as_ref()) {
        let adopted = fit.search.as_ref().is_some_and(|r| r.adopted);
        out.push_str(&format!(
            "\nsecond material {}: best split {}, E {:.1} / {:.1} kPa, ratio {:.3} ± {:.3}, ΔBIC {:.1}",
            if adopted { "found" } else { "not found" },
            b.split.label,
            b.fit.young_modulus(0) / 1e3,
            b.fit.young_modulus(1) / 1e3,
            b.ratio,
            b.ratio_sigma,
            b.delta_bic()
        ));
    }
    if let Some(r) = &fit.registration {
        for (sr, st) in r.states.iter().zip(&fit.states) {
            out.push_str(&format!(
                "\n  {}: registered ({}) by {:.3}° ({:.3} mm at most), RMS {:.3} mm on {} points, {} of 6 directions pinned",
                st.name,
                r.mode.name(),
                sr.registration.transform.angle_deg(),
                1e3 * sr.largest_move_m,
                1e3 * sr.registration.rms_m,
                sr.registration.used,
                sr.registration.pinned
            ));
        }
    }
    for st in &fit.states {
        out.push_str(&format!(
            "\n  {}: {} points ({} used), RMS {:.3} mm, noise {:.3} mm ({:.2}×)",
            st.name,
            st.points,
            st.used,
            1e3 * st.rms_m,
            1e3 * st.noise_m,
            st.ratio()
        ));
    }
    out
}

/// `palpate info` on a scan dataset: its mesh, material and states.
pub fn info(path: &Path) -> anyhow::Result<()> {
    let d = ScanDataset::read(path)?;
    println!(
        "{}: scan dataset, mesh {} nodes / {} tets, ν = {}{}, density {} kg/m³, gravity {:?} m/s², {} state(s){}",
        path.display(),
        d.mesh.nodes.len(),
        d.mesh.tets.len(),
        d.poisson,
        if d.poisson_declared { "" } else { " (default)" },
        d.density,
        d.gravity,
        d.states.len(),
        if d.rest.is_some() { ", a rest scan" } else { "" }
    );
    if d.register != palpate_scan::dataset::Register::None {
        println!(
            "  scans registered: {} (band {:.1} mm)",
            d.register.name(),
            1e3 * d.register_band_m
        );
    }
    let mut states = Vec::new();
    for s in &d.states {
        let held = s.toml.held.as_ref().map(|h| {
            format!(
                "; holds {:?} turned {}° about {:?} through {:?} m, moved {:?} m",
                h.group, h.angle_deg, h.axis, h.about, h.translation
            )
        });
        let loads: Vec<String> = s
            .toml
            .loads
            .iter()
            .map(|l| format!("{:?} N on {:?}", l.force_n, l.group))
            .collect();
        println!(
            "  {}: scan {} ({} points), clamped {:?}{}{}",
            s.name,
            s.scan_dir.display(),
            s.scan.points.points.len(),
            s.toml.clamped,
            held.unwrap_or_default(),
            if loads.is_empty() {
                String::new()
            } else {
                format!("; loads {}", loads.join(", "))
            }
        );
        states.push(serde_json::json!({
            "name": s.name, "scan": s.scan_dir.display().to_string(),
            "points": s.scan.points.points.len(), "clamped": s.toml.clamped,
            "held": s.toml.held.as_ref().map(|h| serde_json::json!({
                "group": h.group, "axis": h.axis, "angle_deg": h.angle_deg,
                "about_m": h.about, "translation_m": h.translation,
            })),
            "loads": s.toml.loads.iter().map(|l| serde_json::json!({"group": l.group, "force_n": l.force_n})).collect::<Vec<_>>(),
        }));
    }
    println!(
        "{}",
        serde_json::json!({
            "schema_version": 1, "kind": "scan dataset",
            "nodes": d.mesh.nodes.len(), "tets": d.mesh.tets.len(),
            "poisson": d.poisson, "poisson_declared": d.poisson_declared,
            "density_kg_m3": d.density, "gravity_m_s2": d.gravity,
            "rest_scan": d.rest.as_ref().map(|r| r.points.points.len()),
            "register": d.register.name(), "register_band_m": d.register_band_m,
            "states": states,
        })
    );
    Ok(())
}

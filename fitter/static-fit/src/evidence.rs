//! Evidence runs (not tests): recovery of a stiff inclusion, the regularisation trade-off of §5.1
//! (marker error and roughness against γ), and the bundled sponge's example dataset. Driven by
//! `palpate-lab bench fit --evidence DIR`.

use std::path::Path;

use palpate_runtime::material::LambdaAlpha;

use palpate_fem::forward::Material;

use super::regularisation::{roughness, spatial_pairs};
use super::synthetic::{synthesise, synthesise_on, Synthetic, SyntheticSpec};
use super::{fit_static, FitError, FitOptions, FitResult, Gammas, Layout, Method, Sets};

/// Σ(a − ā)(b − b̄), Σ(a − ā)², Σ(b − b̄)² over the pairs of `a` and `b`, the means taken as
/// sums over `n` (the parts of a correlation).
pub fn centred_products(a: &[f64], b: &[f64], n: f64) -> (f64, f64, f64) {
    let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        sab += (x - ma) * (y - mb);
        saa += (x - ma).powi(2);
        sbb += (y - mb).powi(2);
    }
    (sab, saa, sbb)
}

/// Pearson correlation of two equally long sequences.
pub fn correlation(a: &[f64], b: &[f64]) -> f64 {
    let (sab, saa, sbb) = centred_products(a, b, a.len().min(b.len()) as f64);
    sab / (saa * sbb).sqrt().max(1e-300)
}

/// log E per element of a material.
pub fn log_young(m: &Material, elements: usize) -> Vec<f64> {
    (0..elements)
        .map(|e| {
            let (lambda, alpha) = m.at(e);
            LambdaAlpha { lambda, alpha }.young().ln()
        })
        .collect()
}

/// Figures of an inclusion-recovery run.
#[derive(Debug, Clone, serde::Serialize)]
pub struct InclusionFigures {
    /// Correlation of fitted and true log E over elements.
    pub correlation: f64,
    /// RMS marker error of the fit (m).
    pub rms_m: f64,
    /// Noise floor σ√3 (m): the RMS of 3-D noise vectors.
    pub floor_m: f64,
    /// Fit time (s).
    pub seconds: f64,
}

/// The stiff-inclusion case: a 10 × 10 × 5 cm block, E = 20 kPa with a 60 kPa sphere (r = 3 cm at
/// the top centre), 4 contacts, markers on every free surface node, noise σ; fitted with the
/// displacement-based linear inhomogeneous inverse at spatial smoothness γ_s.
pub fn inclusion_case(
    cells: [usize; 3],
    noise: f64,
    gamma_s: f64,
) -> Result<(Synthetic, FitResult), FitError> {
    let mut spec = SyntheticSpec::block(cells);
    spec.noise = noise;
    spec.seed = 11;
    spec.inclusion = Some(([0.05, 0.05, 0.05], 0.03, 60_000.0));
    let syn = synthesise(&spec)?;
    let mut o = FitOptions::new(Method::Displacement, Layout::Inhomogeneous, Sets::Single);
    o.gammas = Some(Gammas::new(gamma_s, 0.0));
    o.initial = LambdaAlpha::from_young_poisson(20_000.0, 0.3);
    o.max_iterations = 15;
    let fit = fit_static(&syn.input, &o, |_, _| {})?;
    Ok((syn, fit))
}

/// Figures of [`inclusion_case`].
pub fn inclusion_figures(syn: &Synthetic, fit: &FitResult) -> InclusionFigures {
    let t = syn.input.problem.element_count();
    InclusionFigures {
        correlation: correlation(&log_young(&fit.params[0], t), &log_young(&syn.truth, t)),
        rms_m: fit.rms(),
        floor_m: syn.input.marker_noise.unwrap_or(0.0) * 3f64.sqrt(),
        seconds: fit.seconds,
    }
}

/// The §5.1 trade-off: for γ over a log grid, marker RMS error and roughness ‖L_s log E‖ of the
/// inclusion case; writes `tradeoff_error.svg`, `tradeoff_roughness.svg`, `tradeoff.json`.
pub fn tradeoff(dir: &Path, cells: [usize; 3]) -> Result<Vec<(f64, f64, f64, f64)>, FitError> {
    let mut rows = Vec::new();
    for k in 0..7 {
        let g = 10f64.powf(-2.0 + 4.0 * k as f64 / 6.0);
        let (syn, fit) = inclusion_case(cells, 1e-4, g)?;
        let t = syn.input.problem.element_count();
        let pairs = spatial_pairs(&syn.input.problem.tets);
        let rough = roughness(&pairs, &log_young(&fit.params[0], t));
        let f = inclusion_figures(&syn, &fit);
        log::info!(
            "γ_s = {g:9.3e}: rms {:.4} mm, roughness {rough:.3}, correlation {:.3}",
            f.rms_m * 1e3,
            f.correlation
        );
        rows.push((g, f.rms_m, rough, f.correlation));
    }
    let err: Vec<(f64, f64)> = rows.iter().map(|r| (r.0, r.1 * 1e3)).collect();
    let rough: Vec<(f64, f64)> = rows.iter().map(|r| (r.0, r.2)).collect();
    let axes = palpate_plot::Axes {
        x_log: true,
        y_log: true,
    };
    // The two trade-off figures: (file, title, y label, series name, points).
    for (file, title, y_label, name, points) in [
        (
            "tradeoff_error.svg",
            "§5.1 trade-off: marker RMS error vs γ_s (stiff inclusion, σ = 0.1 mm)",
            "RMS marker error (mm)",
            "rms error",
            &err,
        ),
        (
            "tradeoff_roughness.svg",
            "§5.1 trade-off: roughness ‖L_s log E‖ vs γ_s",
            "roughness",
            "roughness",
            &rough,
        ),
    ] {
        palpate_plot::lines_with(
            dir.join(file),
            title,
            "γ_s",
            y_label,
            &[palpate_plot::Series::new(
                name,
                points,
                palpate_plot::Style::LinePoints,
            )],
            axes,
        )?;
    }
    let json = serde_json::json!(rows.iter().map(|r| serde_json::json!({"gamma_s": r.0, "rms_m": r.1, "roughness": r.2, "correlation": r.3})).collect::<Vec<_>>());
    let file = dir.join("tradeoff.json");
    crate::write_file(&file, crate::to_json(&file, &json)?.as_bytes())?;
    Ok(rows)
}

/// Writes the example dataset of the bundled sponge (`models/sponge/sponge.msh`, bottom fixed):
/// homogeneous E = 20 kPa, ν = 0.3, four contacts on the top, 100 markers, σ = 0.1 mm; the ground
/// truth goes to `truth.toml` beside the dataset folder.
pub fn write_sponge_dataset(mesh_path: &Path, out_dir: &Path) -> Result<(), FitError> {
    let mesh = palpate_fem::mesh::gmsh::read_msh(mesh_path)?;
    let fixed = mesh.group("bottom")?.to_vec();
    let mut spec = SyntheticSpec::block([1, 1, 1]);
    spec.markers = 100;
    spec.noise = 1e-4;
    spec.seed = 2026;
    let syn = synthesise_on(mesh, fixed, &spec)?;
    let ds = syn.to_dataset("sponge-synthetic", "Synthetic static contacts on the bundled sponge: E = 20 kPa, nu = 0.3, sigma = 0.1 mm marker noise (see truth.toml)", 0.02);
    ds.write(out_dir)?;
    let truth = format!(
        "# Ground truth of the synthetic sponge dataset (made by `palpate-lab bench fit --evidence`).\nyoung_pa = {}\npoisson = {}\nmarker_noise_m = {}\nseed = {}\n",
        spec.young, spec.poisson, spec.noise, spec.seed
    );
    crate::write_file(&out_dir.join("truth.toml"), truth.as_bytes())?;
    Ok(())
}

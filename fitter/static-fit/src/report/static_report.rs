//! The static-fit report, after the thesis' Tables 7.1–7.3: per measurement E, ν, Lamé's λ and
//! μ (and, apart and named so, the thesis coefficients λ_F, α_G the fit solved for),
//! min/avg/max marker error and residual norm, as Markdown and JSON; plots (marker error per
//! measurement, E and ν histograms, the L-curve when γ was automatic) and a VTK file with
//! per-element E, ν and per-node marker error for ParaView.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use palpate_runtime::material::LambdaAlpha;

use crate::loo::HeldOut;
use crate::{FitInput, FitResult, GammaChoice};
use palpate_fem::mesh::{vtk, Mesh};
use palpate_fem::names::{Elastic, THESIS_PAIR, THESIS_PAIR_NOTE};

/// The `schema_version` of `report.json` (`docs/json-outputs.md`).
pub const SCHEMA_VERSION: u32 = 1;

/// One table row (one measurement). Inhomogeneous sets give the median over elements.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Row {
    /// Measurement id.
    pub id: String,
    /// Parameter set used.
    pub set: usize,
    /// Young's modulus E (Pa).
    pub young_modulus_pa: f64,
    /// Poisson's ratio ν.
    pub poisson_ratio: f64,
    /// Lamé's first parameter λ (Pa).
    pub lame_lambda_pa: f64,
    /// Shear modulus μ (Pa).
    pub shear_modulus_pa: f64,
    /// The thesis coefficient λ_F of K = λ_F·F + α_G·G (Pa; not Lamé's λ:
    /// [`palpate_fem::names::THESIS_PAIR_NOTE`]).
    pub thesis_lambda_f_pa: f64,
    /// The thesis coefficient α_G (Pa).
    pub thesis_alpha_g_pa: f64,
    /// Observed markers.
    pub markers: usize,
    /// Smallest marker error (m).
    pub min_m: f64,
    /// Mean marker error (m).
    pub mean_m: f64,
    /// Max marker error (m).
    pub max_m: f64,
    /// RMS marker error (m).
    pub rms_m: f64,
    /// ‖x(p) − x̄‖ over the observed markers (m): the displacement residual norm.
    pub residual_norm_m: f64,
    /// Force residual (N), force method only.
    pub force_residual_n: Option<f64>,
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    if v.is_empty() {
        f64::NAN
    } else {
        v[v.len() / 2]
    }
}

/// Table rows of a fit.
pub fn rows(fit: &FitResult) -> Vec<Row> {
    fit.per_measurement
        .iter()
        .map(|m| {
            let set = &fit.params[m.set];
            let pairs: Vec<LambdaAlpha> = set
                .lambda
                .iter()
                .zip(&set.alpha)
                .map(|(&lambda, &alpha)| LambdaAlpha { lambda, alpha })
                .collect();
            let res: f64 = m
                .marker_errors
                .iter()
                .map(|(_, e)| e.iter().map(|v| v * v).sum::<f64>())
                .sum::<f64>()
                .sqrt();
            let elastic: Vec<Elastic> = pairs.iter().map(Elastic::of).collect();
            Row {
                id: m.id.clone(),
                set: m.set,
                young_modulus_pa: median(elastic.iter().map(|e| e.young_modulus_pa).collect()),
                poisson_ratio: median(elastic.iter().map(|e| e.poisson_ratio).collect()),
                lame_lambda_pa: median(elastic.iter().map(|e| e.lame_lambda_pa).collect()),
                shear_modulus_pa: median(elastic.iter().map(|e| e.shear_modulus_pa).collect()),
                thesis_lambda_f_pa: median(pairs.iter().map(|p| p.lambda).collect()),
                thesis_alpha_g_pa: median(pairs.iter().map(|p| p.alpha).collect()),
                markers: m.marker_errors.len(),
                min_m: m.min,
                mean_m: m.mean,
                max_m: m.max,
                rms_m: m.rms,
                residual_norm_m: res,
                force_residual_n: m.force_residual,
            }
        })
        .collect()
}

/// Markdown of the report.
pub fn markdown(name: &str, command: &str, fit: &FitResult, loo: Option<&[HeldOut]>) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# Static fit: {name}\n");
    let _ = writeln!(s, "Command: `{command}`\n");
    let _ = writeln!(
        s,
        "Method {}, material {}, {}, warping {}, {:.2} s, {} iterations. Overall RMS marker error {:.4} mm.\n",
        fit.method,
        fit.layout,
        fit.sets,
        if fit.warp { "on" } else { "off" },
        fit.seconds,
        fit.history.len().saturating_sub(1),
        fit.rms() * 1e3
    );
    if !fit.converged || !fit.findings.0.is_empty() {
        let _ = writeln!(
            s,
            "**{}** Sanity findings:\n",
            if fit.converged {
                "Converged."
            } else {
                "NOT CONVERGED."
            }
        );
        for f in &fit.findings.0 {
            let _ = writeln!(s, "- {f}");
        }
        let _ = writeln!(s);
    }
    let g = fit.gammas;
    let _ = writeln!(
        s,
        "Regularisation weights (on the thesis coefficients λ_F, α_G): spatial γ_s = {:.3e}, {:.3e}; across measurements γ_m = {:.3e}, {:.3e}; choice: {}.\n",
        g.s_lambda,
        g.s_alpha,
        g.m_lambda,
        g.m_alpha,
        match &fit.gamma_choice {
            GammaChoice::User => "given by the user".to_string(),
            GammaChoice::NotNeeded =>
                "not needed (homogeneous, one set: overdetermined)".to_string(),
            GammaChoice::LCurve { grid, chosen } => format!(
                "L-curve corner, point {} of {} (see {})",
                chosen + 1,
                grid.len(),
                palpate_plot::shown("lcurve.svg")
            ),
        }
    );
    let _ = writeln!(s, "Inhomogeneous sets show the median over elements.\n");
    let _ = writeln!(s, "| measurement | set | E (Pa) | ν | Lamé λ (Pa) | μ (Pa) | markers | min (mm) | avg (mm) | max (mm) | rms (mm) | ‖x(p) − x̄‖ (mm) | force residual (N) |");
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    let rows = rows(fit);
    for r in &rows {
        let _ = writeln!(
            s,
            "| {} | {} | {:.1} | {:.4} | {:.1} | {:.1} | {} | {:.4} | {:.4} | {:.4} | {:.4} | {:.4} | {} |",
            r.id, r.set, r.young_modulus_pa, r.poisson_ratio, r.lame_lambda_pa, r.shear_modulus_pa, r.markers, r.min_m * 1e3, r.mean_m * 1e3, r.max_m * 1e3, r.rms_m * 1e3, r.residual_norm_m * 1e3,
            r.force_residual_n.map(|v| format!("{v:.4e}")).unwrap_or_else(|| "–".into())
        );
    }
    let mut heading = THESIS_PAIR.to_string();
    if let Some(first) = heading.get_mut(0..1) {
        first.make_ascii_uppercase();
    }
    let _ = writeln!(s, "\n### {heading}\n\n{THESIS_PAIR_NOTE}\n");
    let _ = writeln!(
        s,
        "| measurement | set | λ_F (Pa) | α_G (Pa) |\n|---|---|---|---|"
    );
    for r in &rows {
        let _ = writeln!(
            s,
            "| {} | {} | {:.1} | {:.1} |",
            r.id, r.set, r.thesis_lambda_f_pa, r.thesis_alpha_g_pa
        );
    }
    if let Some(loo) = loo {
        let _ = writeln!(s, "\n## Leave-one-out\n\nEach measurement held out in turn, the model fitted on the rest, the held-out contact synthesised with the forward model (the non-linear classes through the blend of the remaining sets).\n");
        let _ = writeln!(s, "| held out | set used | rms (mm) | max (mm) | training rms (mm) |\n|---|---|---|---|---|");
        for h in loo {
            let _ = writeln!(
                s,
                "| {} | {} | {:.4} | {:.4} | {:.4} |",
                h.residual.id,
                if h.blended {
                    "blend".to_string()
                } else {
                    h.residual.set.to_string()
                },
                h.residual.rms * 1e3,
                h.residual.max * 1e3,
                h.training_rms * 1e3
            );
        }
    }
    s
}

/// The figures of the fitted E and ν: none for one material (its value is in the table: a
/// histogram of one value says nothing), one bar per measurement for a homogeneous material per
/// measurement, histograms over the elements otherwise.
fn material_figures(
    dir: &Path,
    fit: &FitResult,
    e: &[f64],
    nu: &[f64],
) -> Result<Vec<PathBuf>, crate::FitError> {
    let mut files = Vec::new();
    let distinct = |v: &[f64]| {
        v.iter()
            .any(|x| (x - v[0]).abs() > 1e-9 * v[0].abs().max(1e-300))
    };
    if e.is_empty() || !(distinct(e) || distinct(nu)) {
        return Ok(files);
    }
    if fit.layout == crate::Layout::Homogeneous {
        // One value per set, set i fitted to measurement i.
        let label = |i: usize| {
            fit.per_measurement
                .iter()
                .find(|m| m.set == i)
                .map_or_else(|| format!("set {i}"), |m| m.id.clone())
        };
        let labels: Vec<String> = (0..e.len()).map(label).collect();
        let bars = |v: &[f64]| -> Vec<(&str, f64)> {
            labels
                .iter()
                .map(String::as_str)
                .zip(v.iter().copied())
                .collect()
        };
        files.extend(palpate_plot::bars(
            dir.join("young_hist.svg"),
            "Fitted Young's modulus per measurement",
            "Young's modulus E (Pa)",
            &bars(e),
        )?);
        files.extend(palpate_plot::bars(
            dir.join("poisson_hist.svg"),
            "Fitted Poisson's ratio per measurement",
            "Poisson's ratio ν",
            &bars(nu),
        )?);
        return Ok(files);
    }
    let bins = (e.len() as f64).sqrt().clamp(5.0, 40.0) as usize;
    files.extend(palpate_plot::histogram(
        dir.join("young_hist.svg"),
        "Fitted Young's modulus (all sets, all elements)",
        "Young's modulus E (Pa)",
        e,
        bins,
    )?);
    files.extend(palpate_plot::histogram(
        dir.join("poisson_hist.svg"),
        "Fitted Poisson's ratio (all sets, all elements)",
        "Poisson's ratio ν",
        nu,
        bins,
    )?);
    Ok(files)
}

/// Writes `report.md`, `report.json`, the plots and `fit.vtu` into `dir`; returns the files.
pub fn write_report(
    dir: &Path,
    name: &str,
    command: &str,
    mesh: &Mesh,
    input: &FitInput,
    fit: &FitResult,
    loo: Option<&[HeldOut]>,
) -> Result<Vec<PathBuf>, crate::FitError> {
    let mut files = Vec::new();
    let md = markdown(name, command, fit, loo);
    let p = dir.join("report.md");
    crate::write_file(&p, md.as_bytes())?;
    files.push(p);
    let json = serde_json::json!({
        "schema_version": SCHEMA_VERSION,
        "kind": "static-fit",
        "name": name,
        "command": command,
        "rows": rows(fit),
        "fit": fit,
        "leave_one_out": loo,
    });
    let p = dir.join("report.json");
    crate::write_file(&p, crate::to_json(&p, &json)?.as_bytes())?;
    files.push(p);
    // Plots.
    let bars: Vec<(String, f64)> = fit
        .per_measurement
        .iter()
        .map(|m| (m.id.clone(), m.rms * 1e3))
        .collect();
    let bar_refs: Vec<(&str, f64)> = bars.iter().map(|(a, b)| (a.as_str(), *b)).collect();
    files.extend(palpate_plot::bars(
        dir.join("marker_error.svg"),
        "RMS marker error per measurement",
        "RMS marker error (mm)",
        &bar_refs,
    )?);
    let all: Vec<LambdaAlpha> = fit
        .params
        .iter()
        .flat_map(|m| {
            m.lambda
                .iter()
                .zip(&m.alpha)
                .map(|(&lambda, &alpha)| LambdaAlpha { lambda, alpha })
        })
        .collect();
    let e: Vec<f64> = all.iter().map(|p| p.young()).collect();
    let nu: Vec<f64> = all.iter().map(|p| p.poisson()).collect();
    files.extend(material_figures(dir, fit, &e, &nu)?);
    if let GammaChoice::LCurve { grid, chosen } = &fit.gamma_choice {
        let pts: Vec<(f64, f64)> = grid.iter().map(|&(_, r, e)| (r, e)).collect();
        let pick = vec![pts[*chosen]];
        files.extend(palpate_plot::lines_with(
            dir.join("lcurve.svg"),
            "L-curve: marker residual vs roughness over γ",
            "marker residual norm ‖x(p) − x_measured‖ (m)",
            "roughness ‖L p‖ (Pa)",
            &[
                palpate_plot::Series::new("γ on the grid", &pts, palpate_plot::Style::LinePoints),
                palpate_plot::Series::new("chosen γ", &pick, palpate_plot::Style::Points),
            ],
            palpate_plot::Axes {
                x_log: true,
                y_log: true,
            },
        )?);
    }
    // VTK: first set's E, ν per element; per node the mean marker error norm over measurements,
    // spread to the nodes of each marker's triangle by barycentric weight.
    let first = &fit.params[0];
    let t = mesh.tets.len();
    let ev: Vec<f64> = (0..t)
        .map(|k| {
            let (l, a) = first.at(k);
            LambdaAlpha {
                lambda: l,
                alpha: a,
            }
            .young()
        })
        .collect();
    let nv: Vec<f64> = (0..t)
        .map(|k| {
            let (l, a) = first.at(k);
            a / l
        })
        .collect();
    let mut err = vec![0.0; mesh.nodes.len()];
    let mut wsum = vec![0.0; mesh.nodes.len()];
    for m in &fit.per_measurement {
        for (k, e) in &m.marker_errors {
            let mk = &input.markers[*k];
            let norm = (e[0] * e[0] + e[1] * e[1] + e[2] * e[2]).sqrt();
            for (b, &n) in mk.barycentric.iter().zip(&mk.triangle) {
                err[n] += b * norm;
                wsum[n] += b;
            }
        }
    }
    for (e, w) in err.iter_mut().zip(&wsum) {
        if *w > 0.0 {
            *e /= w;
        }
    }
    let p = dir.join("fit.vtu");
    vtk::write_vtk(
        &p,
        mesh,
        &[vtk::Field::scalar("marker_error_m", &err)],
        &[
            vtk::Field::scalar(vtk::YOUNG_MODULUS, &ev),
            vtk::Field::scalar(vtk::POISSON_RATIO, &nv),
        ],
    )?;
    files.push(p);
    Ok(files)
}

//! The static-fit report, after the thesis' Tables 7.1–7.3: per measurement λ, α, E, ν,
//! min/avg/max marker error and residual norm, as Markdown and JSON; plots (marker error per
//! measurement, E and ν histograms, the L-curve when γ was automatic) and a VTK file with
//! per-element E, ν and per-node marker error for ParaView.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use palpate_runtime::material::LambdaAlpha;

use crate::loo::HeldOut;
use crate::{FitInput, FitResult, GammaChoice};
use palpate_fem::mesh::{vtk, Mesh};

/// One table row (one measurement).
#[derive(Debug, Clone, serde::Serialize)]
pub struct Row {
    /// Measurement id.
    pub id: String,
    /// Parameter set used.
    pub set: usize,
    /// λ (Pa): the value, or the median over elements for inhomogeneous sets.
    pub lambda: f64,
    /// α (Pa), as λ.
    pub alpha: f64,
    /// Young's modulus E (Pa), as λ.
    pub young: f64,
    /// Poisson ratio ν, as λ.
    pub poisson: f64,
    /// Observed markers.
    pub markers: usize,
    /// Min / mean / max / RMS marker error (m).
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
            Row {
                id: m.id.clone(),
                set: m.set,
                lambda: median(pairs.iter().map(|p| p.lambda).collect()),
                alpha: median(pairs.iter().map(|p| p.alpha).collect()),
                young: median(pairs.iter().map(|p| p.young()).collect()),
                poisson: median(pairs.iter().map(|p| p.poisson()).collect()),
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
        "Method {:?}, material {:?} × {:?}, warping {}, {:.2} s, {} iterations. Overall RMS marker error {:.4} mm.\n",
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
        "γ_s^λ = {:.3e}, γ_s^α = {:.3e}, γ_m^λ = {:.3e}, γ_m^α = {:.3e}; choice: {}.\n",
        g.s_lambda,
        g.s_alpha,
        g.m_lambda,
        g.m_alpha,
        match &fit.gamma_choice {
            GammaChoice::User => "given by the user".to_string(),
            GammaChoice::NotNeeded =>
                "not needed (homogeneous, one set: overdetermined)".to_string(),
            GammaChoice::LCurve { grid, chosen } => format!(
                "L-curve corner, point {} of {} (see lcurve.svg)",
                chosen + 1,
                grid.len()
            ),
        }
    );
    let _ = writeln!(s, "Inhomogeneous sets show the median over elements.\n");
    let _ = writeln!(s, "| measurement | set | λ (Pa) | α (Pa) | E (Pa) | ν | markers | min (mm) | avg (mm) | max (mm) | rms (mm) | ‖x(p) − x̄‖ (mm) | force residual (N) |");
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    for r in rows(fit) {
        let _ = writeln!(
            s,
            "| {} | {} | {:.1} | {:.1} | {:.1} | {:.4} | {} | {:.4} | {:.4} | {:.4} | {:.4} | {:.4} | {} |",
            r.id, r.set, r.lambda, r.alpha, r.young, r.poisson, r.markers, r.min_m * 1e3, r.mean_m * 1e3, r.max_m * 1e3, r.rms_m * 1e3, r.residual_norm_m * 1e3,
            r.force_residual_n.map(|v| format!("{v:.4e}")).unwrap_or_else(|| "–".into())
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
    let p = dir.join("marker_error.svg");
    palpate_plot::bars(
        &p,
        "RMS marker error per measurement",
        "RMS error (mm)",
        &bar_refs,
    )?;
    files.push(p);
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
    let bins = (e.len() as f64).sqrt().clamp(1.0, 40.0) as usize;
    let p = dir.join("young_hist.svg");
    palpate_plot::histogram(
        &p,
        "Fitted Young's modulus (all sets, all elements)",
        "E (Pa)",
        &e,
        bins,
    )?;
    files.push(p);
    let p = dir.join("poisson_hist.svg");
    palpate_plot::histogram(
        &p,
        "Fitted Poisson ratio (all sets, all elements)",
        "ν",
        &nu,
        bins,
    )?;
    files.push(p);
    if let GammaChoice::LCurve { grid, chosen } = &fit.gamma_choice {
        let pts: Vec<(f64, f64)> = grid.iter().map(|&(_, r, e)| (r, e)).collect();
        let pick = vec![pts[*chosen]];
        let p = dir.join("lcurve.svg");
        palpate_plot::lines_with(
            &p,
            "L-curve: marker residual vs roughness over γ",
            "‖x(p) − x̄‖ (m)",
            "roughness ‖L p‖",
            &[
                palpate_plot::Series::new("grid", &pts, palpate_plot::Style::LinePoints),
                palpate_plot::Series::new("chosen", &pick, palpate_plot::Style::LinePoints),
            ],
            palpate_plot::Axes {
                x_log: true,
                y_log: true,
            },
        )?;
        files.push(p);
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

//! The scan room's report: `diagnosis.md` (the verdict, before/after, every candidate tried with
//! its gate, the residual drawn on each state's surface before and after) and `diagnosis.json`,
//! and the line `palpate diagnose` prints.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use palpate_scan::fit::{residuals, Linearisation, ScanFit};
use palpate_scan::residual_map::residual_map;
use palpate_scan::residual_vtu::write_fit_residual;

use super::fit::{Evidence, Problem, ScanModel};
use super::{Effect, ScanDiagnosis, EXPLAINED};
use crate::select::CandidateEffect as _;
use crate::Error;

/// The verdict in words.
pub fn verdict(d: &ScanDiagnosis) -> String {
    let adopted = adopted_words(d);
    let what = if adopted.is_empty() {
        "nothing adopted".to_string()
    } else {
        format!("adopted {}", adopted.join(" → "))
    };
    let status = if d.explained() {
        if adopted.is_empty() {
            "clean".to_string()
        } else {
            "explained".to_string()
        }
    } else {
        format!(
            "NOT explained: residual {:.2}× the noise fitted, {:.2}× held out (explained ≤ \
             {EXPLAINED}×){}",
            d.after.score.ratio(),
            d.after_held.ratio(),
            if adopted.is_empty() {
                ""
            } else {
                "; what was adopted may stand in for an effect the library lacks"
            }
        )
    };
    format!("{what}; {status}")
}

fn adopted(d: &ScanDiagnosis) -> Vec<String> {
    d.after
        .effects
        .iter()
        .skip(d.before.effects.len())
        .map(|e| e.label())
        .collect()
}

/// Each adoption in words, with the candidates these scans do not tell from it.
fn adopted_words(d: &ScanDiagnosis) -> Vec<String> {
    d.rounds
        .iter()
        .filter_map(|r| {
            let a = r.tried.iter().find(|t| t.adopted)?;
            let twins: Vec<String> = r
                .tried
                .iter()
                .filter(|t| t.not_told_apart)
                .map(|t| t.effect.label())
                .collect();
            Some(if twins.is_empty() {
                a.effect.label()
            } else {
                format!(
                    "{} (not told apart from {})",
                    a.effect.label(),
                    twins.join(", ")
                )
            })
        })
        .collect()
}

fn young(m: &ScanModel) -> String {
    (0..m.fit.mu.len())
        .map(|k| {
            format!(
                "{:.1} ± {:.1}",
                m.fit.young_modulus(k) / 1e3,
                m.fit.young_modulus(k) * m.fit.sigma_ln_mu(k) / 1e3
            )
        })
        .collect::<Vec<_>>()
        .join(" / ")
}

/// The line `palpate diagnose` prints for a scan dataset.
pub fn summary_line(name: &str, d: &ScanDiagnosis) -> String {
    format!(
        "{name}: {}; E {} kPa → {} kPa; residual/noise {:.2} → {:.2} fitted, {:.2} → {:.2} held out",
        verdict(d),
        young(&d.before),
        young(&d.after),
        d.before.score.ratio(),
        d.after.score.ratio(),
        d.before_held.ratio(),
        d.after_held.ratio()
    )
}

fn model_json(m: &ScanModel, held: &Evidence, states: &[String]) -> serde_json::Value {
    serde_json::json!({
        "effects": m.effects,
        "young_modulus_pa": (0..m.fit.mu.len()).map(|k| m.fit.young_modulus(k)).collect::<Vec<_>>(),
        "sigma_ln_young": (0..m.fit.mu.len()).map(|k| m.fit.sigma_ln_mu(k)).collect::<Vec<_>>(),
        "split": m.split.as_ref().map(|s| serde_json::json!({
            "label": s.label, "normal": s.normal, "point_m": s.point, "fraction": s.fraction,
            "elements": s.elements,
        })),
        "depth_bias_m": m.effects.contains(&Effect::DepthBias).then_some(m.nuisance.bias_m),
        "sigma_depth_bias_m": m.effects.contains(&Effect::DepthBias).then_some(m.bias_sd_m),
        "depth_scale": m.effects.contains(&Effect::DepthScale).then_some(m.nuisance.scale),
        "sigma_depth_scale": m.effects.contains(&Effect::DepthScale).then_some(m.scale_sd),
        "registrations": m.effects.contains(&Effect::CameraMoved).then(|| {
            m.nuisance.rigid.iter().zip(states).map(|(r, s)| serde_json::json!({
                "state": s, "angle_deg": r.angle_deg(),
                "translation_m": [r.translation.x, r.translation.y, r.translation.z],
            })).collect::<Vec<_>>()
        }),
        "fitted": evidence_json(&m.score),
        "held_out": evidence_json(held),
        "iterations_with_nuisances": m.iterations,
    })
}

fn evidence_json(e: &Evidence) -> serde_json::Value {
    serde_json::json!({
        "points": e.n, "chi2_truncated": e.chi2, "rms_m": e.rms_m, "noise_m": e.noise_m,
        "rms_over_noise": e.ratio(),
    })
}

/// `diagnosis.json`.
pub fn to_json(name: &str, d: &ScanDiagnosis) -> serde_json::Value {
    serde_json::json!({
        "kind": "scan diagnosis",
        "dataset": name,
        "tool": format!("palpate {}", crate::VERSION),
        "design": d.design.name(),
        "elements": d.elements,
        "poisson": d.poisson.0,
        "poisson_declared": d.poisson.1,
        "points_fitted": d.points.0,
        "points_held_out": d.points.1,
        "verdict": verdict(d),
        "explained": d.explained(),
        "adopted": adopted(d),
        "stop": d.stop,
        "before": model_json(&d.before, &d.before_held, &d.states),
        "after": model_json(&d.after, &d.after_held, &d.states),
        "rounds": d.rounds,
        "mesh_error": d.mesh_error.map(|(rms, noise, elements, e)| serde_json::json!({
            "rms_m": rms, "noise_m": noise, "refined_elements": elements,
            "young_modulus_uncorrected_pa": e, "corrected": true,
        })),
        "mesh_error_again": d.mesh_error_again.iter().map(|(e, rms, noise)| serde_json::json!({
            "adopted": e, "rms_m": rms, "noise_m": noise,
        })).collect::<Vec<_>>(),
    })
}

fn mm(v: Option<f64>) -> String {
    v.map_or("—".into(), |v| format!("{:.3}", 1e3 * v))
}

/// `diagnosis.md`; `maps` the residual figures (state, before, after) as the report shows them.
pub fn markdown(name: &str, d: &ScanDiagnosis, maps: &[(String, String, String)]) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# Scan diagnosis: {name}\n");
    let _ = writeln!(s, "**{}**\n", verdict(d));
    let _ = writeln!(
        s,
        "{} states, {} on {} tets, ν = {}{}; {} points fitted, {} held out (the odd cubes of a \
         checkerboard of a sixth of the object's size). Residuals are signed distances to the \
         fitted surface over each point's noise along the normal.\n",
        d.states.len(),
        d.design.name(),
        d.elements,
        d.poisson.0,
        if d.poisson.1 {
            ""
        } else {
            " (not declared: a silicone's)"
        },
        d.points.0,
        d.points.1
    );
    match d.mesh_error {
        Some((rms, noise, elements, e)) => {
            let _ = writeln!(
                s,
                "The mesh's own discretisation error, measured against the mesh refined once \
                 ({elements} tets) at the simplest model's fit: {:.3} mm RMS at the weighted \
                 points, {:.2}× their noise {:.3} mm. Every fit below is corrected by it (E \
                 without the correction: {:.1} kPa).\n",
                1e3 * rms,
                rms / noise,
                1e3 * noise,
                e / 1e3
            );
            for (effect, rms, noise) in &d.mesh_error_again {
                let _ = writeln!(
                    s,
                    "Measured again once {} was adopted: {:.3} mm RMS ({:.2}× the noise).\n",
                    effect.label(),
                    1e3 * rms,
                    rms / noise
                );
            }
        }
        None => {
            let _ = writeln!(
                s,
                "The mesh's own discretisation error was not measured (`--mesh dataset`): a \
                 coarse mesh's stiffness may be read as a candidate's effect.\n"
            );
        }
    }
    let _ = writeln!(
        s,
        "| | E (kPa) | effects | fitted RMS / noise | held-out RMS / noise |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|");
    for (what, m, h) in [
        ("before", &d.before, &d.before_held),
        ("after", &d.after, &d.after_held),
    ] {
        let _ = writeln!(
            s,
            "| {what} | {} | {} | {:.3} / {:.3} mm ({:.2}×) | {:.3} / {:.3} mm ({:.2}×) |",
            young(m),
            if m.effects.is_empty() {
                "—".to_string()
            } else {
                m.effects
                    .iter()
                    .map(|e| e.label())
                    .collect::<Vec<_>>()
                    .join(", ")
            },
            1e3 * m.score.rms_m,
            1e3 * m.score.noise_m,
            m.score.ratio(),
            1e3 * h.rms_m,
            1e3 * h.noise_m,
            h.ratio()
        );
    }
    if d.after.effects.contains(&Effect::DepthBias) {
        let _ = writeln!(
            s,
            "\nDepth bias: {:.3} ± {:.3} mm along the rays.",
            1e3 * d.after.nuisance.bias_m,
            1e3 * d.after.bias_sd_m
        );
    }
    if d.after.effects.contains(&Effect::DepthScale) {
        let _ = writeln!(
            s,
            "\nDepth scale: every depth read {:+.3} ± {:.3} % too far.",
            100.0 * d.after.nuisance.scale,
            100.0 * d.after.scale_sd
        );
    }
    if let Some(sp) = &d.after.split {
        let _ = writeln!(
            s,
            "\nSecond material: split by the {} ({} / {} elements), E₂/E₁ = {:.3}.",
            sp.label,
            sp.elements[0],
            sp.elements[1],
            d.after.fit.mu[1] / d.after.fit.mu[0]
        );
    }
    if d.after.effects.contains(&Effect::CameraMoved) {
        let _ = writeln!(
            s,
            "\nEach scan registered onto its clamped and held part:\n"
        );
        for (r, n) in d.after.nuisance.rigid.iter().zip(&d.states) {
            let _ = writeln!(
                s,
                "- {n}: turned {:.3}°, moved ({:.3}, {:.3}, {:.3}) mm",
                r.angle_deg(),
                1e3 * r.translation.x,
                1e3 * r.translation.y,
                1e3 * r.translation.z
            );
        }
    }
    let _ = writeln!(s, "\n## Candidates\n");
    let _ = writeln!(
        s,
        "| round | candidate | ΔBIC | E (kPa) | bias (mm) | scale (%) | largest move (mm) | split, E₂/E₁ | fitted / noise | held out / noise | gate |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|---|---|");
    for r in &d.rounds {
        for t in &r.tried {
            let mut gate = match (&t.not_fitted, &t.gate) {
                (Some(why), _) => why.clone(),
                (None, Some(g)) => g.reason.clone(),
                _ => "not gated".into(),
            };
            if t.not_told_apart {
                gate.push_str(&format!(
                    "; not told apart from the adopted effect (fitted ΔBIC within {})",
                    super::TOLD_APART
                ));
            }
            let _ = writeln!(
                s,
                "| {} | {}{} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
                r.round,
                t.effect.label(),
                if t.adopted { " **adopted**" } else { "" },
                t.delta_bic.map_or("—".into(), |v| format!("{v:.1}")),
                if t.young_pa.is_empty() {
                    "—".into()
                } else {
                    t.young_pa
                        .iter()
                        .map(|e| format!("{:.1}", e / 1e3))
                        .collect::<Vec<_>>()
                        .join(" / ")
                },
                mm(t.bias_m),
                t.scale.map_or("—".into(), |v| format!("{:+.3}", 100.0 * v)),
                mm(t.largest_move_m),
                t.split
                    .as_ref()
                    .map_or("—".into(), |(l, q)| format!("{l}, {q:.3}")),
                t.fitted_ratio.map_or("—".into(), |v| format!("{v:.2}")),
                t.heldout_ratio.map_or("—".into(), |v| format!("{v:.2}")),
                gate
            );
        }
    }
    let _ = writeln!(s, "\nThe search ended: {}.", d.stop);
    if !maps.is_empty() {
        let _ = writeln!(
            s,
            "\n## The residual on the surface\n\nEach state's fitted surface seen along its \
             thinnest axis, each triangle coloured by the mean signed distance (mm) of the points \
             nearest it (fitted and held out), before and after; `<state>-points.vtu` and \
             `<state>-surface.vtu` hold the residual after, for ParaView.\n"
        );
        for (state, before, after) in maps {
            let _ = writeln!(s, "{state}:\n\n{before}\n{after}\n");
        }
    }
    s
}

/// State `i`'s residual on every point at `model`'s fit, as the residual map takes it.
fn state_fit(problem: &Problem<'_>, model: &ScanModel, i: usize) -> ScanFit {
    let lin = &model.fit.states[i];
    let points = problem.all_points(i, model);
    ScanFit {
        mu: model.fit.mu[0],
        young_modulus: model.fit.young_modulus(0),
        iterations: model.fit.iterations,
        at_fit: Linearisation {
            equilibrium: lin.equilibrium.clone(),
            residuals: residuals(&lin.equilibrium, &points, problem.settings.max_distance),
            cost: f64::NAN,
            gradient: Vec::new(),
            hessian: Vec::new(),
        },
    }
}

/// A state's name as a file name: letters, digits, `-` and `_` kept, the rest `_`.
pub fn file_stem(name: &str) -> String {
    name.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect()
}

/// Draws each state's residual before and after into `dir`; returns the files and the report's
/// figure links.
#[allow(clippy::type_complexity)]
pub fn residual_maps(
    dir: &Path,
    problem: &Problem<'_>,
    d: &ScanDiagnosis,
) -> (Vec<PathBuf>, Vec<(String, String, String)>) {
    let mut files = Vec::new();
    let mut links = Vec::new();
    for (i, name) in d.states.iter().enumerate() {
        let mut pair = Vec::new();
        for (when, m) in [("before", &d.before), ("after", &d.after)] {
            let file = format!("{}-residual-{when}.svg", file_stem(name));
            let fit = state_fit(problem, m, i);
            if when == "after" {
                // For ParaView: the points with their residuals, the fitted surface with each
                // node's mean residual.
                let points = problem.all_points(i, m);
                match write_fit_residual(dir, &file_stem(name), &points, &fit) {
                    Ok(f) => files.extend(f),
                    Err(e) => log::warn!("{name}: the residual's VTU was not written: {e}"),
                }
            }
            match draw(&dir.join(&file), name, when, &fit) {
                Ok(f) => {
                    files.extend(f);
                    pair.push(palpate_plot::shown(&file));
                }
                Err(e) => {
                    log::warn!("{name}: the residual's map ({when}) was not drawn: {e}");
                    pair.push(format!("({when}: not drawn)"));
                }
            }
        }
        links.push((name.clone(), pair[0].clone(), pair[1].clone()));
    }
    (files, links)
}

fn draw(path: &Path, state: &str, when: &str, fit: &ScanFit) -> Result<Vec<PathBuf>, String> {
    residual_figure(
        path,
        &format!("{state}, {when}: scan residual on the fitted surface"),
        fit,
    )
}

/// A fit's residual drawn on its surface into `path` (SVG and PNG,
/// [`palpate_scan::residual_map`]): seen along the rest surface's thinnest axis, each triangle
/// coloured by the mean signed distance of the points nearest it, in mm.
pub fn residual_figure(path: &Path, title: &str, fit: &ScanFit) -> Result<Vec<PathBuf>, String> {
    let map = residual_map(fit).ok_or("the fitted surface has fewer than three nodes")?;
    let mm = |p: (f64, f64)| (1e3 * p.0, 1e3 * p.1);
    let triangles: Vec<[(f64, f64); 3]> = map.triangles.iter().map(|t| t.map(mm)).collect();
    let values: Vec<f64> = map.mean_m.iter().map(|v| 1e3 * v).collect();
    let axis = |a: [f64; 3]| {
        format!(
            "along ({:.2}, {:.2}, {:.2}) of the mesh's frame (mm)",
            a[0], a[1], a[2]
        )
        .replace("-0.00", "0.00")
    };
    let (x_label, y_label) = (axis(map.axes[0]), axis(map.axes[1]));
    palpate_plot::surface_map(
        path,
        &palpate_plot::SurfaceMap {
            title,
            x_label: &x_label,
            y_label: &y_label,
            value_label: "mean signed residual (mm)",
            triangles: &triangles,
            values: &values,
        },
    )
    .map_err(|e| e.to_string())
}

/// Writes `diagnosis.md`, `diagnosis.json` and the residual maps into `dir`.
pub fn write_report(
    dir: &Path,
    name: &str,
    problem: &Problem<'_>,
    d: &ScanDiagnosis,
) -> Result<Vec<PathBuf>, Error> {
    std::fs::create_dir_all(dir).map_err(|e| Error::Write(format!("{}: {e}", dir.display())))?;
    let (mut maps, links) = residual_maps(dir, problem, d);
    let mut files = crate::json::write_md_and_json(dir, &markdown(name, d, &links), || {
        serde_json::to_string_pretty(&to_json(name, d))
    })
    .map_err(Error::Write)?;
    files.append(&mut maps);
    Ok(files)
}

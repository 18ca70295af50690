//! Report of a motion diagnosis: `diagnosis.md`, `diagnosis.json`, `residual-vs-speed.svg`.

use super::floors::{of_values, OnFloor};
use super::{MotionDiagnoseError, MotionDiagnosis, Value};
use crate::json;
use palpate_fem::names::Elastic;
use palpate_fem::numbers;
use palpate_motion::model::ParamKind;
use palpate_plot::{lines, Series, Style};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// A trial's predicted ΔBIC for the table ("—": not predicted).
fn predicted(t: &super::Trial) -> String {
    t.predicted_delta_bic
        .map_or_else(|| "—".into(), |d| format!("{d:.1}"))
}

fn um(v: f64) -> String {
    format!("{:.1}", 1e6 * v)
}

/// A parameter's name and unit apart, as a table prints them (`Lamé λ`, `Pa`), "(fixed)" kept
/// with the name: a material parameter's from its label, any other's (offsets, a second
/// material) its name as it is and the unit [`unit`] knows by the name.
fn name_and_unit(name: &str) -> (String, String) {
    let (base, fixed) = match name.strip_suffix(" (fixed)") {
        Some(b) => (b, " (fixed)"),
        None => (name, ""),
    };
    let Some(kind) = ParamKind::parse(base) else {
        return (name.to_string(), unit(name).to_string());
    };
    match kind.label().rsplit_once(" (") {
        Some((n, u)) if u.ends_with(')') => (format!("{n}{fixed}"), u.trim_end_matches(')').into()),
        _ => (format!("{}{fixed}", kind.label()), unit(name).into()),
    }
}

/// A value and its 1σ (if known) in plain numbers, in one unit chosen from the value.
fn value_sd(v: &Value) -> (String, String, Option<String>) {
    let (name, unit) = name_and_unit(&v.name);
    let (value, sd) = numbers::value_and_sd(v.value, v.sigma.unwrap_or(f64::NAN), &unit);
    (name, value, v.sigma.map(|_| sd))
}

/// A table of `vals`; a value named in `on_floor` is marked as on its floor, its 1σ too.
fn value_table(md: &mut String, vals: &[Value], on_floor: &[OnFloor]) {
    md.push_str("| parameter | value | 1σ |\n|---|---|---|\n");
    let floored = |v: &Value| on_floor.iter().any(|f| f.parameter == v.name);
    for v in vals {
        let (name, value, sd) = value_sd(v);
        let (value, sd) = match (floored(v), sd) {
            (true, Some(sd)) => (
                format!("{value} (on its floor)"),
                format!("{sd} (the curvature there)"),
            ),
            (true, None) => (format!("{value} (on its floor)"), "—".into()),
            (false, sd) => (value, sd.unwrap_or_else(|| "—".into())),
        };
        let _ = writeln!(md, "| {name} | {value} | {sd} |");
    }
    let value = |kind: ParamKind| {
        vals.iter()
            .find(|v| v.name.strip_suffix(" (fixed)").unwrap_or(&v.name) == kind.name())
            .map(|v| v.value)
    };
    if let (Some(l), Some(m)) = (value(ParamKind::Lambda), value(ParamKind::Mu)) {
        let e = Elastic::from_lame(l, m);
        let lambda_floored = on_floor
            .iter()
            .any(|f| f.parameter == ParamKind::Lambda.name());
        let _ = writeln!(
            md,
            "\nYoung's modulus E = {}, Poisson's ratio ν = {:.4} (from Lamé's λ and μ{}).",
            numbers::pressure(e.young_modulus_pa),
            e.poisson_ratio,
            if lambda_floored {
                "; λ on its floor: ν is not measured"
            } else {
                ""
            }
        );
    }
}

/// The Markdown report.
pub fn markdown(r: &MotionDiagnosis) -> String {
    let mut md = String::new();
    let (ne, nm, steps, dt) = r.size;
    let _ = writeln!(md, "# Motion diagnosis: {}\n", r.dataset);
    let _ = writeln!(
        md,
        "{ne} tets, {nm} markers, {steps} steps of {dt:.5} s. Fitted steps 1–{}, held out (forecast) \
         steps {}–{steps}. Density {}.\n",
        r.split.fit_steps,
        r.split.fit_steps + 1,
        if r.density_declared {
            "declared in dataset.toml (held fixed unless a candidate frees it)"
        } else {
            "not declared: 1000 kg/m³ assumed"
        }
    );
    let _ = writeln!(md, "**Result**: {}.\n", r.verdict());
    let _ = writeln!(md, "**Mesh**: {}.\n", r.mesh.statement);
    let _ = writeln!(md, "**Time step**: {}.\n", r.time_step);
    let e = &r.fitted_step_error;
    let _ = writeln!(
        md,
        "**The step at the final model** (the markers at this step against half of it, by \
         Richardson's rule): {}.\n",
        match (&e.measured, &e.not_measured) {
            (Some(m), _) => m.describe(),
            (None, why) => format!("not measured: {}", why.as_deref().unwrap_or("")),
        }
    );
    for w in &r.relative {
        let _ = writeln!(md, "**Relative figures**: {w}.\n");
    }
    for f in &r.on_floor {
        let _ = writeln!(md, "**On a floor**: {}.\n", f.statement);
    }
    md.push_str("| marker error | simplest (elastic) | final | \n|---|---|---|\n");
    let _ = writeln!(
        md,
        "| RMS fitted (µm) | {} | {} |\n| max fitted (µm) | {} | {} |\n| RMS held out (µm) | {} | {} |\n| max held out (µm) | {} | {} |\n",
        um(r.before.rms_fit),
        um(r.after.rms_fit),
        um(r.before.max_fit),
        um(r.after.max_fit),
        um(r.before.rms_held),
        um(r.after.rms_held),
        um(r.before.max_held),
        um(r.after.max_held)
    );
    let _ = writeln!(md, "**Rule**: {}\n", r.rule);
    md.push_str("## Simplest model: Neo-Hookean, viscosity = 0 held fixed\n\n");
    value_table(&mut md, &r.before_values, &of_values(&r.before_values));
    for rd in &r.rounds {
        let _ = writeln!(
            md,
            "\n## Round {} (model: elastic{})\n",
            rd.round,
            rd.model
                .iter()
                .map(|m| format!(" + {m}"))
                .collect::<String>()
        );
        let s = &rd.signature;
        let _ = writeln!(md, "Signature: {}.\n", s.reading);
        let _ = writeln!(
            md,
            "- lag along the relative marker velocity: e ≈ {} s · u_rel, {:.1} % of the residual energy (ΔBIC {:.1})",
            numbers::plain(s.speed_coef_s),
            100.0 * s.speed_share,
            s.speed_dbic
        );
        let _ = writeln!(
            md,
            "- along the acceleration: e ≈ {} s² · a, {:.1} % of the residual energy (ΔBIC {:.1})",
            numbers::plain(s.accel_coef_s2),
            100.0 * s.accel_share,
            s.accel_dbic
        );
        let _ = writeln!(
            md,
            "- over time (RMS µm per eighth of the record): {} (last/first {:.2})",
            s.time_bins
                .iter()
                .map(|b| um(b.1))
                .collect::<Vec<_>>()
                .join(", "),
            s.drift_ratio
        );
        let _ = writeln!(
            md,
            "- per marker (RMS µm): {} (worst/median {:.2})\n",
            s.per_marker
                .iter()
                .map(|(n, v)| format!("{n} {}", um(*v)))
                .collect::<Vec<_>>()
                .join(", "),
            s.worst_marker_ratio
        );
        if let Some(why) = &rd.settled {
            let _ = writeln!(md, "No candidate tried: {why}.\n");
        }
        md.push_str("| candidate | k | predicted ΔBIC | RMS fitted (µm) | RMS held out (µm) | ΔBIC | held-out ΔBIC | held-out RMS | decision |\n|---|---|---|---|---|---|---|---|---|\n");
        for t in &rd.trials {
            if t.fitted {
                let _ = writeln!(
                    md,
                    "| {} | {} | {} | {} | {} | {:.1} | {:.1} | {:+.1} % | {} |",
                    t.candidate,
                    t.k,
                    predicted(t),
                    um(t.scores.rms_fit),
                    um(t.scores.rms_held),
                    t.delta_bic,
                    t.heldout_delta_bic,
                    100.0 * t.heldout_gain,
                    t.reason
                );
            } else {
                let _ = writeln!(
                    md,
                    "| {} | {} | {} | — | — | — | — | — | not fitted: {} |",
                    t.candidate,
                    t.k,
                    predicted(t),
                    t.reason
                );
            }
        }
        for t in rd.trials.iter().filter(|t| t.fitted) {
            let _ = writeln!(
                md,
                "\n{} fit: {}",
                t.candidate,
                t.values
                    .iter()
                    .map(|v| match value_sd(v) {
                        (name, value, Some(sd)) => format!("{name} = {value} ± {sd}"),
                        (name, value, None) => format!("{name} = {value}"),
                    })
                    .collect::<Vec<_>>()
                    .join(", ")
            );
        }
        let _ = writeln!(
            md,
            "\nAdopted: {}.",
            rd.adopted.as_deref().unwrap_or("nothing")
        );
    }
    md.push_str("\n## Final model\n\n");
    value_table(&mut md, &r.after_values, &r.on_floor);
    md.push_str(
        "\n1σ: Gauss–Newton s²(JᵀJ)⁻¹ on the fitted steps (J the markers' sensitivities to the \
         log parameters at the fit's last simulation, s² = χ²/(n − k)); marker errors within a \
         trajectory are correlated in time, so these are lower bounds. Values are those fitted on the fitted steps (the model whose \
         forecast is scored).\n",
    );
    let _ = writeln!(
        md,
        "\nFinal residual: {}.\n\n![residual vs speed]({})\n",
        r.final_signature.reading,
        palpate_plot::shown("residual-vs-speed.svg")
    );
    if let Some(f) = &r.mesh_floor {
        let _ = writeln!(
            md,
            "\n### The mesh's share of the residual\n\nThe final model simulated on the mesh \
             refined once ({} tetrahedra) and refitted on this mesh there, noise-free (its own \
             null), leaves {:.1} µm RMS on the fitted steps and {:.1} µm held out: what no \
             parameter of the model can take from this mesh's own error, which joins the noise \
             floor in quadrature in the verdict (the refined mesh's difference, not extrapolated \
             to the material: against a material this mesh errs by more). The residual is \
             {:.2}× / {:.2}× the noise floor alone; what stands above it by less than the mesh's \
             share cannot be told from the mesh's error on this mesh (refine it, or fit on \
             quadratic elements: `--motion-convergence`).",
            f.refined_tets,
            1e6 * f.null_rms_fit,
            1e6 * f.null_rms_held,
            r.residual_check.ratio_noise,
            r.heldout_check.ratio_noise
        );
    }
    if let Some(c) = &r.mesh_convergence {
        md.push_str(&c.markdown());
    }
    if let Some(c) = &r.motion_convergence {
        md.push_str(&c.markdown());
    }
    if r.options.mesh_null {
        let _ = writeln!(
            md,
            "\n### The parameters under one refinement (from the mesh's own null)\n\n{}",
            match &r.mesh_bias {
                Some(b) => format!("{}.", capitalised(&b.statement)),
                None => "Not measured: no null was made (the mesh refined once was not made, \
                         or the current model did not refit on it; the log says which)."
                    .to_string(),
            }
        );
    }
    md
}

/// `s` with its first letter in upper case.
fn capitalised(s: &str) -> String {
    let mut c = s.chars();
    c.next()
        .map(|f| f.to_uppercase().chain(c).collect())
        .unwrap_or_default()
}

/// The unit of a [`Value`] by its name.
fn unit(name: &str) -> &'static str {
    match ParamKind::parse(name.strip_suffix(" (fixed)").unwrap_or(name)) {
        Some(ParamKind::Lambda | ParamKind::Mu) => "Pa",
        Some(ParamKind::Nu) => "Pa·s^h",
        Some(ParamKind::Density) => "kg/m³",
        Some(_) => "",
        None if name.starts_with("marker offsets") => "m",
        None if name.starts_with("time offset") => "s",
        None => "",
    }
}

/// The text of `diagnosis.json`: the diagnosis with `schema_version`, units in the field names
/// (`rms_fit_m`, `chi2_fit_m2`; pairs as `<name>_<x unit>_<y unit>`), a `unit` beside every
/// parameter value, and the final material as Lamé's λ, μ and E, ν (`docs/json-outputs.md`).
pub fn json_text(r: &MotionDiagnosis) -> Result<String, serde_json::Error> {
    const SCORES: [(&str, &str); 6] = [
        ("chi2_fit", "chi2_fit_m2"),
        ("rms_fit", "rms_fit_m"),
        ("max_fit", "max_fit_m"),
        ("chi2_held", "chi2_held_m2"),
        ("rms_held", "rms_held_m"),
        ("max_held", "max_held_m"),
    ];
    const SIGNATURE: [(&str, &str); 3] = [
        ("time_bins", "time_bins_s_m"),
        ("per_marker", "per_marker_m"),
        ("speed_bins", "speed_bins_m_per_s_m"),
    ];
    let mut v = serde_json::to_value(r)?;
    for path in ["before", "after", "rounds[].trials[].scores"] {
        json::rename(&mut v, path, &SCORES);
    }
    for path in ["rounds[].signature", "final_signature"] {
        json::rename(&mut v, path, &SIGNATURE);
    }
    json::rename(
        &mut v,
        "",
        &[
            ("speed_before", "speed_before_m_per_s_m"),
            ("speed_after", "speed_after_m_per_s_m"),
        ],
    );
    json::rename(
        &mut v,
        "mesh_floor",
        &[
            ("null_rms_fit", "null_rms_fit_m"),
            ("null_rms_held", "null_rms_held_m"),
        ],
    );
    for path in [
        "before_values[]",
        "after_values[]",
        "rounds[].trials[].values[]",
    ] {
        json::each_object(&mut v, path, &mut |o| {
            let u = unit(o.get("name").and_then(|n| n.as_str()).unwrap_or(""));
            o.insert("unit".into(), u.into());
        });
    }
    if let Some(o) = v.as_object_mut() {
        let (tets, markers, steps, dt) = r.size;
        o.insert(
            "size".into(),
            serde_json::json!({"tets": tets, "markers": markers, "steps": steps, "dt_s": dt}),
        );
        let value = |kind: ParamKind| {
            r.after_values
                .iter()
                .find(|v| v.name.strip_suffix(" (fixed)").unwrap_or(&v.name) == kind.name())
                .map(|v| v.value)
        };
        if let (Some(l), Some(m)) = (value(ParamKind::Lambda), value(ParamKind::Mu)) {
            o.insert("elastic".into(), json::elastic(&Elastic::from_lame(l, m)));
        }
    }
    json::finish("motion-diagnosis", v)
}

/// Writes the report files into `dir`; returns their paths.
pub fn write_report(r: &MotionDiagnosis, dir: &Path) -> Result<Vec<PathBuf>, MotionDiagnoseError> {
    let w = |e: String| MotionDiagnoseError::Write(e);
    let mut out = crate::json::write_md_and_json(dir, &markdown(r), || json_text(r)).map_err(w)?;
    let p = dir.join("residual-vs-speed.svg");
    let scale = |v: &[(f64, f64)]| -> Vec<(f64, f64)> {
        v.iter().map(|&(x, y)| (1e3 * x, 1e6 * y)).collect()
    };
    let (b, a) = (scale(&r.speed_before), scale(&r.speed_after));
    let after_label = if r.adopted.is_empty() {
        "final (= elastic)".to_string()
    } else {
        format!("elastic + {}", r.adopted.join(" + "))
    };
    out.extend(
        lines(
            &p,
            "RMS marker residual vs marker speed relative to the clamp (octile bins)",
            "marker speed relative to the clamp |u_rel| (mm/s)",
            "RMS marker residual (µm)",
            &[
                Series::new("elastic (simplest)", &b, Style::LinePoints),
                Series::new(&after_label, &a, Style::LinePoints),
            ],
        )
        .map_err(|e| w(e.to_string()))?,
    );
    Ok(out)
}

/// The one-line summary of `r` the command prints: the verdict and the RMS marker errors before
/// and after (µm).
pub fn summary_line(r: &MotionDiagnosis) -> String {
    format!(
        "{}: {}; RMS marker error {:.1} → {:.1} µm fitted, {:.1} → {:.1} µm held out (forecast of the last {} steps)",
        r.dataset,
        r.verdict(),
        1e6 * r.before.rms_fit,
        1e6 * r.after.rms_fit,
        1e6 * r.before.rms_held,
        1e6 * r.after.rms_held,
        r.split.steps - r.split.fit_steps
    )
}

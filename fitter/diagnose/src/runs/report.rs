//! The runs diagnosis' report: `diagnosis.md` (verdict, before/after per run, the residual's
//! signature, parameters), `diagnosis.json`, `fit.json` (the final model for `palpate validate`)
//! and the ring-down of each held-out run measured against the simplest and the final model
//! (`ring-<run>.svg` and `.png`).

use super::{RunResidual, RunsDiagnosis, RunsError};
use crate::json;
use palpate_fem::io::atomic::write_atomic;
use palpate_fem::names::Elastic;
use palpate_fem::numbers;
use palpate_plot::{lines, Series, Style};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

fn mm(v: f64) -> String {
    format!("{:.3}", 1e3 * v)
}

fn opt(v: Option<f64>, d: usize) -> String {
    v.map_or("–".into(), |v| format!("{v:.d$}"))
}

fn rows(md: &mut String, before: &[RunResidual], after: &[RunResidual]) {
    for (b, a) in before.iter().zip(after) {
        let _ = writeln!(
            md,
            "| {} | {} → {} | {} → {} | {} → {} | {} | {} → {} | {} | {} → {} |",
            b.run,
            mm(b.rms_m),
            mm(a.rms_m),
            mm(b.early_m),
            mm(a.early_m),
            mm(b.final_rms_m),
            mm(a.final_rms_m),
            opt(b.period_s.0, 3),
            opt(b.period_s.1, 3),
            opt(a.period_s.1, 3),
            opt(b.decay_per_cycle.0, 2),
            opt(b.decay_per_cycle.1, 2),
            opt(a.decay_per_cycle.1, 2),
        );
    }
}

/// The adopted effects' names, in the order adopted.
fn adopted_names(r: &RunsDiagnosis, separator: &str) -> String {
    r.adopted
        .iter()
        .map(|e| e.name())
        .collect::<Vec<_>>()
        .join(separator)
}

/// The markdown report.
pub fn markdown(r: &RunsDiagnosis) -> String {
    let mut md = String::new();
    verdict(&mut md, r);
    candidates(&mut md, r);
    per_run(&mut md, r);
    parameters(&mut md, r);
    mesh_convergence(&mut md, r);
    md
}

/// The title, the verdict with the held-out figures, what the held-out runs test, the simplest
/// model and the adoption rule.
fn verdict(md: &mut String, r: &RunsDiagnosis) {
    let _ = writeln!(
        md,
        "# Diagnosis of {} runs\n",
        r.fitted_runs.len() + r.held_out_runs.len()
    );
    let _ = writeln!(
        md,
        "Fitted on {}; held out (predicted, never fitted): {}. {:.0} s.\n",
        r.fitted_runs.join(", "),
        r.held_out_runs.join(", "),
        r.seconds
    );
    let adopted = if r.adopted.is_empty() {
        "nothing adopted: no candidate predicts the held-out runs better".to_string()
    } else {
        format!("adopted {}", adopted_names(r, ", then "))
    };
    let _ = writeln!(
        md,
        "**Verdict: {adopted}.** Held-out marker RMS {} → {} mm, held-out rest-state RMS {} → {} mm \
         (fitted runs: {} → {} mm). The loop stopped: {}.\n",
        mm(r.heldout_rms_m.0),
        mm(r.heldout_rms_m.1),
        mm(r.heldout_final_rms_m.0),
        mm(r.heldout_final_rms_m.1),
        mm(r.fitted_rms_m.0),
        mm(r.fitted_rms_m.1),
        r.stop
    );
    let beyond = r.held_out_loads_beyond_fitted();
    let _ = if beyond.is_empty() && !r.held_out_runs.is_empty() {
        writeln!(
            md,
            "Every held-out run repeats a load of the fitted runs: the held-out figures test \
             repeatability, not extrapolation to other loads — a law that depends on the strain (the \
             stiffening) is checked only at the loads it was fitted on. Hold out a run at another load \
             (or predict one with `palpate validate`) to test that.\n"
        )
    } else if !beyond.is_empty() {
        writeln!(
            md,
            "Held-out loads that no fitted run carries: {} N — the held-out figures include \
             extrapolation in load.\n",
            beyond
                .iter()
                .map(|l| format!("{l:.3}"))
                .collect::<Vec<_>>()
                .join(", ")
        )
    } else {
        Ok(())
    };
    let _ = writeln!(md, "Time steps:\n");
    for (run, step) in &r.time_steps {
        let _ = writeln!(md, "- {run}: {step}.");
    }
    let _ = writeln!(
        md,
        "\nThe step's own error at the final model (the markers at this step against half of it, \
         by Richardson's rule), against the run's final residual:\n"
    );
    for e in &r.fitted_step_errors {
        let said = match (&e.measured, &e.not_measured) {
            (Some(m), _) => m.describe(),
            (None, why) => format!("not measured: {}", why.as_deref().unwrap_or("")),
        };
        let _ = writeln!(md, "- {}: {said}.", e.run);
    }
    let _ = writeln!(md);
    // The final record moves the weights when the simplest model did or the candidate was
    // adopted; asked as a candidate, the simplest model held them as forces.
    let weights = if !r.options.weights_move() {
        ", hanging weights as forces only"
    } else if r.model.hanging_inertia {
        ", each hung weight moving with its nodes (its declared mass)"
    } else {
        ""
    };
    let _ = writeln!(
        md,
        "The simplest model: Neo-Hookean, Poisson's ratio held at {} (the markers see bending, not \
         volume change), μ fitted, no damping{weights}. Adoption rule: ΔBIC \
         < −{} on the fitted runs, held-out ΔBIC < 0 and the held-out RMS down by ≥ {:.0} %.\n",
        r.options.poisson,
        r.options.bic_threshold,
        100.0 * r.options.min_holdout_gain
    );
}

/// Every candidate tried, round by round.
fn candidates(md: &mut String, r: &RunsDiagnosis) {
    let _ = writeln!(md, "## Candidates\n\n| round | effect | predicted ΔBIC | ΔBIC | fitted RMS (mm) | held-out RMS (mm) | verdict |\n|---|---|---|---|---|---|---|");
    for t in &r.trials {
        let _ = writeln!(
            md,
            "| {} | {}{} | {} | {} | {} | {} | {} |",
            t.round,
            t.effect.name(),
            if t.adopted { " (adopted)" } else { "" },
            t.predicted_delta_bic
                .map_or("–".into(), |d| format!("{d:.1}")),
            if t.delta_bic.is_nan() {
                "–".to_string()
            } else {
                format!("{:.1}", t.delta_bic)
            },
            t.rms_fit_m.map_or("–".into(), mm),
            t.rms_held_m.map_or("–".into(), mm),
            t.gate
                .as_ref()
                .map(|g| g.reason.clone())
                .or_else(|| t.not_fitted.clone())
                .unwrap_or_default()
        );
    }
}

/// Each run's residual before and after, and what an adopted effect adds to it.
fn per_run(md: &mut String, r: &RunsDiagnosis) {
    let _ = writeln!(
        md,
        "\n## Before → after, per run\n\nMarker RMS over the run, over its first quarter (the swing), \
         and of the predicted rest state against the last 0.5 s; the ring-down of the marker that \
         moves most, measured / simulated before → after.\n\n| run | RMS (mm) | first quarter (mm) | \
         rest state (mm) | period measured (s) | period simulated (s) | decay per cycle measured | \
         decay simulated |\n|---|---|---|---|---|---|---|---|"
    );
    rows(md, &r.before.0, &r.after.0);
    rows(md, &r.before.1, &r.after.1);
    // What an adopted effect has to say beyond the table (e.g. each run's time offset).
    for e in &r.adopted {
        if let Some(words) = e.effect().report(r) {
            let _ = writeln!(md, "{words}");
        }
    }
}

/// Whether the fitted modulus is the material's or the mesh's ([`crate::convergence`]).
fn mesh_convergence(md: &mut String, r: &RunsDiagnosis) {
    if let Some(c) = &r.mesh_convergence {
        md.push_str(&c.markdown());
    }
    if let Some(c) = &r.motion_convergence {
        md.push_str(&c.markdown());
    }
}

/// The final model's parameters and elastic constants, and the figures.
fn parameters(md: &mut String, r: &RunsDiagnosis) {
    let _ = writeln!(
        md,
        "\n## Parameters of the final model\n\n| parameter | value | 1σ |\n|---|---|---|"
    );
    for v in &r.values {
        let (value, sd) = numbers::value_and_sd(v.value, v.sd, &v.unit);
        let sd = if v.sd.is_finite() { sd } else { "–".into() };
        let _ = writeln!(md, "| {} | {value} | {sd} |", v.name);
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    let e = Elastic::from_lame(mean(&r.model.lambda), mean(&r.model.mu));
    let _ = writeln!(
        md,
        "\nElastic constants: Young's modulus E = {}, Poisson's ratio ν = {:.4}, Lamé λ = {}, shear modulus μ = {}.",
        numbers::pressure(e.young_modulus_pa),
        e.poisson_ratio,
        numbers::pressure(e.lame_lambda_pa),
        numbers::pressure(e.shear_modulus_pa)
    );
    let _ = writeln!(
        md,
        "\nThe 1σ is from the curvature of the objective with independent residuals: a lower bound, \
         since a ring-down's residuals are correlated in time; the spread of leave-one-run-out fits is \
         the realistic one.\n"
    );
    let _ = writeln!(
        md,
        "![period against load]({})\n",
        palpate_plot::shown("period-vs-load.svg")
    );
    for h in &r.after.1 {
        let file = palpate_plot::shown(&format!("ring-{}.svg", slug(&h.run)));
        let _ = writeln!(md, "![{}]({file})\n", h.run);
    }
}

fn slug(s: &str) -> String {
    let base = Path::new(s)
        .file_name()
        .map(|f| f.to_string_lossy().to_string())
        .unwrap_or_else(|| s.to_string());
    base.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '-'
            }
        })
        .collect()
}

/// The text of `diagnosis.json`: the diagnosis with `schema_version`, units in the field names and
/// the final material as Lamé's λ, μ and E, ν (`docs/json-outputs.md`); `model` is `fit.json`'s
/// record.
pub fn json_text(r: &RunsDiagnosis) -> Result<String, serde_json::Error> {
    let mut v = serde_json::to_value(r)?;
    json::rename(&mut v, "", &[("seconds", "run_time_s")]);
    json::rename(
        &mut v,
        "options",
        &[
            ("start_mu", "start_mu_pa"),
            ("start_viscosity", "start_viscosity_pa_s_h"),
        ],
    );
    for path in ["before[].[]", "after[].[]"] {
        json::rename(&mut v, path, &[("chi2", "chi2_m2"), ("ring", "ring_m")]);
    }
    if let Some(o) = v.as_object_mut() {
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
        let e = Elastic::from_lame(mean(&r.model.lambda), mean(&r.model.mu));
        o.insert("elastic".into(), json::elastic(&e));
    }
    json::finish("runs-diagnosis", v)
}

/// Writes the report into `dir`; returns the files written.
pub fn write_report(r: &RunsDiagnosis, dir: &Path, dt: f64) -> Result<Vec<PathBuf>, RunsError> {
    let w = |e: String| RunsError::Write(e);
    let mut out = crate::json::write_md_and_json(dir, &markdown(r), || json_text(r)).map_err(w)?;
    let p = dir.join("fit.json");
    let json = r.model.to_json().map_err(|e| w(e.to_string()))?;
    write_atomic(&p, json.as_bytes()).map_err(|e| w(e.to_string()))?;
    out.push(p);
    let after_name = if r.adopted.is_empty() {
        "final (= simplest)".to_string()
    } else {
        format!("+ {}", adopted_names(r, " + "))
    };
    // Every plot sets the measurement beside the simplest and the final model.
    let plot = |file: String, title: &str, axes: [&str; 2], series: &[Series]| {
        lines(dir.join(file), title, axes[0], axes[1], series).map_err(|e| w(e.to_string()))
    };
    // The variable that revealed the inertia: the ring-down period against the hanging load,
    // measured and simulated by the simplest and the final model, every run.
    let period = |v: &[RunResidual], measured: bool| -> Vec<(f64, f64)> {
        v.iter()
            .filter_map(|x| {
                let p = if measured { x.period_s.0 } else { x.period_s.1 };
                p.map(|p| (x.load_n, 1e3 * p))
            })
            .collect()
    };
    let all_before: Vec<RunResidual> = r.before.0.iter().chain(&r.before.1).cloned().collect();
    let all_after: Vec<RunResidual> = r.after.0.iter().chain(&r.after.1).cloned().collect();
    let (pm, p0, p1) = (
        period(&all_before, true),
        period(&all_before, false),
        period(&all_after, false),
    );
    if !pm.is_empty() {
        out.extend(plot(
            "period-vs-load.svg".into(),
            "Ring-down period against the hanging load (every run)",
            [
                "hanging load along gravity (N)",
                "period of the ring-down (ms)",
            ],
            &[
                Series::new("measured", &pm, Style::Points),
                Series::new("simplest model", &p0, Style::Points),
                Series::new(&after_name, &p1, Style::Points),
            ],
        )?);
    }
    for (b, a) in r.before.1.iter().zip(&r.after.1) {
        let pts = |v: &[f64]| -> Vec<(f64, f64)> {
            v.iter()
                .enumerate()
                .filter(|(_, y)| y.is_finite())
                .map(|(n, y)| ((n + 1) as f64 * dt, 1e3 * y))
                .collect()
        };
        let (m, s0, s1) = (pts(&b.ring.0), pts(&b.ring.1), pts(&a.ring.1));
        out.extend(plot(
            format!("ring-{}.svg", slug(&b.run)),
            &format!(
                "Held-out run {}: marker {} predicted",
                slug(&b.run),
                b.ring_marker
            ),
            ["time after release (s)", "displacement along gravity (mm)"],
            &[
                Series::new("measured", &m, Style::Points),
                Series::new("simplest model", &s0, Style::Line),
                Series::new(&after_name, &s1, Style::Line),
            ],
        )?);
    }
    Ok(out)
}

/// The one-line summary of `r` the command prints: the effects adopted and the held-out errors
/// before and after (mm).
pub fn summary_line(r: &RunsDiagnosis) -> String {
    format!(
        "runs diagnosis: adopted [{}]; held-out marker RMS {:.3} → {:.3} mm, held-out rest state {:.3} → {:.3} mm ({:.0} s)",
        r.adopted.iter().map(|e| e.name()).collect::<Vec<_>>().join(", "),
        1e3 * r.heldout_rms_m.0,
        1e3 * r.heldout_rms_m.1,
        1e3 * r.heldout_final_rms_m.0,
        1e3 * r.heldout_final_rms_m.1,
        r.seconds
    )
}

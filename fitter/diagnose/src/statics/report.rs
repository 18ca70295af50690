//! Writing a [`DiagnosisReport`]: `diagnosis.md` (step by step), `diagnosis.json` (everything),
//! and one SVG per adopted effect showing the residual against the variable that gave it away
//! (before and after adoption). All files go through `write_atomic`.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use super::json;
use super::model::Candidate;
use super::power_check::FACTORS;
use super::signature::Signature;
use super::{DiagnoseError, DiagnosisReport, Errors, Step};
use palpate_fem::io::atomic::write_atomic;
use palpate_fem::names::Elastic;
use palpate_fem::numbers;
use palpate_plot::{lines, Series, Style};
use palpate_runtime::material::LambdaAlpha;

fn um(v: f64) -> String {
    format!("{:.1}", v * 1e6)
}

/// The items, comma separated (the signature's lists).
fn comma(items: impl Iterator<Item = String>) -> String {
    items.collect::<Vec<_>>().join(", ")
}

fn error_rows(s: &mut String, label: &str, e: &Errors) {
    let _ = writeln!(
        s,
        "| {label} | {} | {} | {} | {} | {:.4} | {:.4} | {:.4} |",
        um(e.fitted_rms),
        um(e.fitted_max),
        um(e.heldout_rms),
        um(e.heldout_max),
        e.force_rms,
        e.force_max,
        e.heldout_force_rms
    );
}

/// The Markdown text of a report.
pub fn markdown(r: &DiagnosisReport, plots: &[(usize, String)]) -> String {
    let mut s = String::new();
    header(&mut s, r);
    detectable(&mut s, r);
    errors_table(&mut s, r);
    noise_sections(&mut s, r);
    final_parameters(&mut s, r);
    for st in &r.steps {
        round(&mut s, st, plots);
    }
    s
}

/// The verdict, the selection rule, the noise floor and the mesh the models were solved on.
fn header(s: &mut String, r: &DiagnosisReport) {
    let _ = writeln!(s, "# Diagnosis of `{}`\n", r.input.dataset);
    let verdict = format!(
        "**{}**",
        r.residual_check
            .verdict(&Candidate::names(&r.adopted, " → ", ""))
    );
    let _ = writeln!(
        s,
        "Verdict: {verdict}. Selection rule: {}.",
        r.input.criterion
    );
    let _ = writeln!(
        s,
        "Marker noise σ = {} µm ({}); noise floor of the RMS marker error σ√3 = {} µm. Run time {:.1} s.\n",
        um(r.input.sigma),
        if r.input.sigma_declared { "declared" } else { "not declared: 100 µm used to scale" },
        um(r.noise_floor),
        r.seconds
    );
    if let Some(m) = &r.mesh_error {
        let _ = writeln!(
            s,
            "Discretisation error of the dataset mesh: the simplest model solved again on the mesh refined once ({} tets) moves the markers by {} µm RMS (max {} µm). Residual structure of that size can be the mesh rather than a missing effect.\n",
            m.refined_tets,
            um(m.rms),
            um(m.max)
        );
    }
    let _ = writeln!(
        s,
        "Models solved on {} ({} tets{}); the simplest model's fitted RMS on the dataset's own mesh, uncorrected: {} µm.\n",
        r.solved_on.reason,
        r.solved_on.tets,
        r.solved_on
            .correction_rms
            .map(|c| format!("; final correction δ = {} µm RMS", um(c)))
            .unwrap_or_default(),
        um(r.solved_on.dataset_mesh_rms)
    );
}

/// The power statement: what the dataset would have detected.
fn detectable(s: &mut String, r: &DiagnosisReport) {
    if !r.detectable.is_empty() {
        let _ = writeln!(s, "## What this dataset could have detected\n");
        let _ = writeln!(
            s,
            "The residual is the noise's, so no further effect was adopted — but only effects at least this large would have been shortlisted (ΔBIC < −{}; linearised at the final fit, each parameter with the rest of its block free; the held-out gate asks more). Smaller effects of these kinds may be present. Each statement was checked: the effect put alone into noise-free data at {}× (then {}×) its size (a per-measurement one with signs alternating over the measurements), the final model refitted with and without it; a statement the refits do not bear out says so, and one beyond a plausible size is not put in:\n",
            r.options.bic_threshold,
            FACTORS[0],
            FACTORS[1]
        );
        for d in &r.detectable {
            let _ = writeln!(s, "- {}", d.describe());
        }
        let _ = writeln!(s);
    }
}

/// The simplest and the final model's errors.
fn errors_table(s: &mut String, r: &DiagnosisReport) {
    let _ = writeln!(s, "## Error before and after\n");
    let _ = writeln!(s, "Markers in µm; implied-force error in N (|s − 1|·|f|, s the best scale of simulated onto measured displacement). Held-out = leave-one-measurement-out.\n");
    let _ = writeln!(s, "| model | fitted RMS | fitted max | held-out RMS | held-out max | force RMS | force max | held-out force RMS |");
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|");
    error_rows(s, "simplest (linear homogeneous)", &r.before);
    error_rows(s, "final", &r.after);
}

/// The marker-noise and rest-scan findings.
fn noise_sections(s: &mut String, r: &DiagnosisReport) {
    if let Some(n) = &r.noise {
        let _ = writeln!(s, "\n## Marker noise\n");
        let _ = writeln!(
            s,
            "{}{}. Estimator: local nugget — at every marker an affine field is fitted to its {} nearest neighbours' residuals (same measurement) and extrapolated to the marker; the median of |d|²/(3(1 + v)) over its Gaussian value gives σ̂² ({} neighbourhoods in {} measurements); interval: bootstrap over measurements.",
            if n.fired { "**Adopted `noise`**: " } else { "" },
            n.statement,
            r.options.noise.neighbours,
            n.neighbourhoods,
            n.measurements
        );
        if !r.noise_evidence.is_empty() {
            let _ = writeln!(s, "\n![marker noise]({})", palpate_plot::shown("noise.svg"));
        }
    }
    if let Some(n) = &r.rest_noise {
        let _ = writeln!(s, "\n## Rest scan\n");
        let _ = writeln!(
            s,
            "{}{}. Estimator: the same local nugget on each marker's mean residual over its measurements ({} markers, seen in {:.1} measurements on average), whose white part is the rest positions' error plus σ²/m of the measurements'; null distribution and interval by simulation through the same neighbourhoods.",
            if n.fired { "**Adopted `rest-noise`**: " } else { "" },
            n.statement,
            n.markers,
            n.mean_seen
        );
        if !n.points.is_empty() {
            let _ = writeln!(s, "\n![rest scan]({})", palpate_plot::shown("rest.svg"));
        }
    }
}

/// Every parameter of the final model and its base material's constants.
fn final_parameters(s: &mut String, r: &DiagnosisReport) {
    let _ = writeln!(s, "\n## Final parameters (±1σ, Gauss–Newton covariance)\n");
    let _ = writeln!(s, "| parameter | value | ±1σ |\n|---|---|---|");
    for p in &r.final_params {
        let (value, sd) = numbers::value_and_sd(p.value, p.sd, &p.unit);
        let _ = writeln!(s, "| {} | {value} | {sd} |", p.name);
    }
    let (young, poisson) = r.young_poisson;
    let lame = Elastic::of(&LambdaAlpha::from_young_poisson(young, poisson));
    let _ = writeln!(
        s,
        "\nBase material: Young's modulus E = {}, Poisson's ratio ν = {:.3}; Lamé λ = {}, shear modulus μ = {}.",
        numbers::pressure(lame.young_modulus_pa),
        lame.poisson_ratio,
        numbers::pressure(lame.lame_lambda_pa),
        numbers::pressure(lame.shear_modulus_pa)
    );
    let id = &r.identifiability;
    if !id.degenerate.is_empty() || !id.relative.is_empty() {
        let _ = writeln!(
            s,
            "\n### What these data determine only relative to something else\n"
        );
        for d in &id.degenerate {
            let _ = writeln!(
                s,
                "- {} and {} are determined only in combination (correlation {:+.3}): each ±1σ above is mostly their trade-off, and either alone is known only relative to the other.",
                d.parameters[0], d.parameters[1], d.correlation
            );
        }
        for w in &id.relative {
            let _ = writeln!(s, "- {w}.");
        }
    }
}

/// One round: the residual signature, the candidates tried, the decision, the adoption and its
/// evidence plots.
/// The residual signature's lines of a round.
fn signature_lines(s: &mut String, sig: &Signature) {
    let _ = writeln!(s, "Residual signature:\n");
    let _ = writeln!(s, "- scale factor (measured/simulated displacement) vs force: correlation {:.2}; per measurement (|f| N → s): {}", sig.scale_vs_force,
        comma(sig.per_measurement.iter().map(|p| format!("{:.2}→{:.3}", p.force, p.scale))));
    let _ = writeln!(
        s,
        "- rigid-body part (one transform for all measurements): {:.0}% of the residual energy",
        100.0 * sig.rigid_fraction
    );
    let _ = writeln!(
        s,
        "- persistent part (same at a marker in every measurement): {:.0}%",
        100.0 * sig.persistent_fraction
    );
    let _ = writeln!(
        s,
        "- RMS vs distance from the contact (upper bin edge mm: µm): {}",
        comma(
            sig.vs_distance
                .iter()
                .map(|(d, r, _)| format!("{:.0}: {}", d * 1e3, um(*r)))
        )
    );
    let _ = writeln!(
        s,
        "- per measurement RMS (µm): {}",
        comma(
            sig.per_measurement
                .iter()
                .map(|p| format!("{} {}", p.id, um(p.rms)))
        )
    );
    let _ = writeln!(
        s,
        "- worst markers (RMS µm): {}\n",
        comma(
            sig.worst_markers
                .iter()
                .map(|(id, v)| format!("{id} {}", um(*v)))
        )
    );
}

/// The table of the candidates a round tried, and why any was not fitted.
fn tried_table(s: &mut String, st: &Step) {
    if !st.tried.is_empty() {
        let _ = writeln!(s, "| candidate | extra params | predicted ΔBIC | refit RMS µm | ΔBIC | held-out RMS µm | held-out ΔBIC | held-out paired t |\n|---|---|---|---|---|---|---|---|");
        for t in &st.tried {
            let predicted = t
                .predicted_delta_bic
                .map(|v| format!("{v:.1}"))
                .unwrap_or_else(|| "–".into());
            if t.not_fitted.is_some() {
                let why = if t.screened_out {
                    "screened out"
                } else {
                    "not fitted"
                };
                let _ = writeln!(
                    s,
                    "| {} | {} | {predicted} | {why} | – | – | – | – |",
                    t.candidate.name(),
                    t.extra_params
                );
                continue;
            }
            let _ = writeln!(
                s,
                "| {} | {} | {predicted} | {} | {:.1} | {} | {} | {} |",
                t.candidate.name(),
                t.extra_params,
                um(t.rms),
                t.delta_bic,
                t.heldout_rms.map(um).unwrap_or_else(|| "–".into()),
                t.heldout_delta_bic
                    .map(|v| format!("{v:.1}"))
                    .unwrap_or_else(|| "–".into()),
                t.heldout_t
                    .map(|v| format!("{v:.2}"))
                    .unwrap_or_else(|| "–".into())
            );
        }
    }
    // A screened-out candidate's prediction is in the table; what it means is said once.
    if st.tried.iter().any(|t| t.screened_out) {
        let _ = writeln!(
            s,
            "\nScreened out: predicted by one Gauss–Newton step at the current fit not to rank \
             among those fitted (the best predicted, those within the margin of the best, each \
             only when predicted to pay for its parameters); `--full-search` fits every one."
        );
    }
    for t in st
        .tried
        .iter()
        .filter(|t| t.not_fitted.is_some() && !t.screened_out)
    {
        let _ = writeln!(
            s,
            "\nNot fitted: {} — {}",
            t.candidate.name(),
            t.not_fitted.as_deref().unwrap_or_default()
        );
    }
}

fn round(s: &mut String, st: &Step, plots: &[(usize, String)]) {
    let model = Candidate::names(&st.model, " + ", "simplest");
    let _ = writeln!(s, "\n## Round {} (model: {model})\n", st.round);
    signature_lines(s, &st.signature);
    tried_table(s, st);
    let _ = writeln!(s, "\nDecision: {}", st.reason);
    if !st.ambiguous_with.is_empty() {
        let _ = writeln!(
            s,
            "\n**Ambiguous**: {} also explain(s) this residual and predict(s) the held-out measurements better than the adopted effect; more measurements (other contact points and force levels) are needed to tell them apart.",
            st.ambiguous_with.iter().map(|c| c.name()).collect::<Vec<_>>().join(", ")
        );
    }
    if let Some(a) = &st.after {
        let _ = writeln!(s, "\n| | fitted RMS | fitted max | held-out RMS | held-out max | force RMS | force max | held-out force RMS |\n|---|---|---|---|---|---|---|---|");
        error_rows(s, "before", &st.before);
        error_rows(s, "after", a);
        if !st.new_params.is_empty() {
            let _ = writeln!(s, "\nNew parameters:\n");
        }
        for p in &st.new_params {
            let (value, sd) = numbers::value_and_sd(p.value, p.sd, &p.unit);
            let sd = if p.sd.is_finite() {
                format!("± {sd}")
            } else {
                format!("(±1σ {sd})")
            };
            let _ = writeln!(s, "- {} = {value} {sd}", p.name);
        }
    }
    for (round, file) in plots {
        if *round == st.round {
            let _ = writeln!(s, "\n![evidence]({file})");
        }
    }
}

/// The text of `diagnosis.json`: the report with `schema_version`, units in the field names and
/// the base material as Lamé's λ, μ and E, ν (`docs/json-outputs.md`).
pub fn json_text(r: &DiagnosisReport) -> Result<String, serde_json::Error> {
    const ERRORS: [(&str, &str); 7] = [
        ("fitted_rms", "fitted_rms_m"),
        ("fitted_max", "fitted_max_m"),
        ("heldout_rms", "heldout_rms_m"),
        ("heldout_max", "heldout_max_m"),
        ("force_rms", "force_rms_n"),
        ("force_max", "force_max_n"),
        ("heldout_force_rms", "heldout_force_rms_n"),
    ];
    let mut v = serde_json::to_value(r)?;
    for path in ["before", "after", "steps[].before", "steps[].after"] {
        json::rename(&mut v, path, &ERRORS);
    }
    json::rename(
        &mut v,
        "",
        &[
            ("sigma", "sigma_m"),
            ("noise_floor", "noise_floor_m"),
            ("noise_evidence", "noise_evidence_m_m"),
            ("seconds", "run_time_s"),
        ],
    );
    json::rename(
        &mut v,
        "rest_noise",
        &[
            ("estimate", "estimate_m"),
            ("interval", "interval_m"),
            ("sigma_null", "sigma_null_m"),
            ("sigma_within", "sigma_within_m"),
            ("detectable", "detectable_m"),
        ],
    );
    json::rename(
        &mut v,
        "steps[].tried[]",
        &[
            ("rms", "rms_m"),
            ("heldout_rms", "heldout_rms_m"),
            ("heldout_force_rms", "heldout_force_rms_n"),
        ],
    );
    json::rename(
        &mut v,
        "steps[].signature",
        &[
            ("vs_distance", "vs_distance_m_m"),
            ("worst_markers", "worst_markers_m"),
        ],
    );
    json::rename(
        &mut v,
        "steps[].signature.per_measurement[]",
        &[
            ("force", "force_n"),
            ("rms", "rms_m"),
            ("max", "max_m"),
            ("rigid", "rigid_m"),
            ("mean", "mean_m"),
        ],
    );
    json::rename(&mut v, "mesh_error", &[("rms", "rms_m"), ("max", "max_m")]);
    json::rename(
        &mut v,
        "solved_on",
        &[
            ("correction_rms", "correction_rms_m"),
            ("dataset_mesh_rms", "dataset_mesh_rms_m"),
        ],
    );
    json::rename(
        &mut v,
        "noise",
        &[
            ("estimate", "estimate_m"),
            ("sd", "sd_m"),
            ("interval", "interval_m"),
            ("lower_bound", "lower_bound_m"),
            ("declared", "declared_m"),
            ("floor", "floor_m"),
            ("points", "points_m"),
        ],
    );
    if let Some(o) = v.as_object_mut() {
        // (E, ν) as a pair becomes the four constants, named.
        o.shift_remove("young_poisson");
        let (young, poisson) = r.young_poisson;
        o.insert(
            "elastic".into(),
            json::elastic(&Elastic::of(&LambdaAlpha::from_young_poisson(
                young, poisson,
            ))),
        );
    }
    json::finish("static-diagnosis", v)
}

/// Writes `diagnosis.md`, `diagnosis.json` and the evidence plots into `dir`; returns the paths.
pub fn write_report(r: &DiagnosisReport, dir: &Path) -> Result<Vec<PathBuf>, DiagnoseError> {
    std::fs::create_dir_all(dir)
        .map_err(|e| DiagnoseError::Write(format!("{}: {e}", dir.display())))?;
    let mut written = Vec::new();
    let plots = evidence_plots(r, dir, &mut written)?;
    noise_plot(r, dir, &mut written)?;
    rest_plot(r, dir, &mut written)?;
    let md = markdown(r, &plots);
    let json = json_text(r).map_err(|e| DiagnoseError::Write(e.to_string()))?;
    for (name, text) in [("diagnosis.md", md), ("diagnosis.json", json)] {
        let p = dir.join(name);
        write_atomic(&p, text.as_bytes())
            .map_err(|e| DiagnoseError::Write(format!("{}: {e:#}", p.display())))?;
        written.push(p);
    }
    Ok(written)
}

/// Each adopted effect's evidence before and after its adoption (`round<k>-<name>.svg`, added to
/// `written`); the plots by round, for the Markdown report.
fn evidence_plots(
    r: &DiagnosisReport,
    dir: &Path,
    written: &mut Vec<PathBuf>,
) -> Result<Vec<(usize, String)>, DiagnoseError> {
    let mut plots = Vec::new();
    for st in &r.steps {
        if let (Some(c), Some((xl, yl, before, after))) = (st.adopted, &st.evidence) {
            let file = format!("round{}-{}.svg", st.round, c.name());
            let path = dir.join(&file);
            let title = format!(
                "round {}: {} (before and after adoption)",
                st.round,
                c.name()
            );
            let style = if before.len() > 40 {
                Style::Points
            } else {
                Style::LinePoints
            };
            let mut b = before.clone();
            let mut a = after.clone();
            if style == Style::LinePoints {
                b.sort_by(|p, q| p.0.total_cmp(&q.0));
                a.sort_by(|p, q| p.0.total_cmp(&q.0));
            }
            written.extend(
                lines(
                    &path,
                    &title,
                    xl,
                    yl,
                    &[
                        Series::new("before", &b, style),
                        Series::new("after", &a, style),
                    ],
                )
                .map_err(|e| DiagnoseError::Write(e.to_string()))?,
            );
            plots.push((st.round, palpate_plot::shown(&file)));
        }
    }
    Ok(plots)
}

/// The noise test's nugget errors against distance, with the estimated and declared σ
/// (`noise.svg`, added to `written`), when noise was adopted.
fn noise_plot(
    r: &DiagnosisReport,
    dir: &Path,
    written: &mut Vec<PathBuf>,
) -> Result<(), DiagnoseError> {
    if let Some(n) = &r.noise {
        if !r.noise_evidence.is_empty() {
            let path = dir.join("noise.svg");
            let pts: Vec<(f64, f64)> = r
                .noise_evidence
                .iter()
                .map(|&(d, e)| (1e3 * d, 1e6 * e))
                .collect();
            let xmax = pts.iter().map(|p| p.0).fold(0.0, f64::max);
            let est = [(0.0, 1e6 * n.estimate), (xmax, 1e6 * n.estimate)];
            let declared: Vec<(f64, f64)> = n
                .declared
                .map(|d| vec![(0.0, 1e6 * d), (xmax, 1e6 * d)])
                .unwrap_or_default();
            let mut series = vec![
                Series::new("nugget error per marker", &pts, Style::Points),
                Series::new("estimated σ (nugget)", &est, Style::Line),
            ];
            if !declared.is_empty() {
                series.push(Series::new("declared σ", &declared, Style::Line));
            }
            written.extend(
                lines(
                    &path,
                    "marker noise: local prediction error |d|/√(3(1+v)) vs distance from the contact",
                    "distance from the contact (mm)",
                    "normalised nugget error (µm)",
                    &series,
                )
                .map_err(|e| DiagnoseError::Write(e.to_string()))?,
            );
        }
    }
    Ok(())
}

/// The rest-scan test's per-marker mean residuals with the RMS each noise alone would give
/// (`rest.svg`, added to `written`), when it ran.
fn rest_plot(
    r: &DiagnosisReport,
    dir: &Path,
    written: &mut Vec<PathBuf>,
) -> Result<(), DiagnoseError> {
    if let Some(n) = r.rest_noise.as_ref().filter(|n| !n.points.is_empty()) {
        // What each marker's mean residual would be (RMS) with the measurements' noise alone,
        // σ√(3/m), and with the rest scan's too, √(3(σ²/m + τ̂²)).
        let pts: Vec<(f64, f64)> = n.points.iter().map(|&(m, e)| (m, 1e6 * e)).collect();
        let top = pts.iter().map(|p| p.0).fold(1.0, f64::max);
        let curve = |tau: f64| -> Vec<(f64, f64)> {
            (0..=40)
                .map(|i| {
                    let m = 1.0 + (top - 1.0) * i as f64 / 40.0;
                    let s2 = n.sigma_null * n.sigma_null;
                    (m, 1e6 * (3.0 * (s2 / m + tau * tau)).sqrt())
                })
                .collect()
        };
        let (alone, both) = (curve(0.0), curve(n.estimate));
        written.extend(
            lines(
                dir.join("rest.svg"),
                "rest scan: each marker's mean residual over its measurements",
                "measurements the marker was seen in",
                "|mean residual| (µm)",
                &[
                    Series::new("marker", &pts, Style::Points),
                    Series::new(
                        "RMS expected: measurements' noise alone",
                        &alone,
                        Style::Line,
                    ),
                    Series::new(
                        "RMS expected: with the rest scan's estimated τ",
                        &both,
                        Style::Line,
                    ),
                ],
            )
            .map_err(|e| DiagnoseError::Write(e.to_string()))?,
        );
    }
    Ok(())
}

/// The summary the command prints for `r`: the verdict and RMS marker errors before and after
/// (µm), then, when the residual is explained, the smallest magnitude of each candidate the data
/// would have detected.
pub fn summary_lines(r: &DiagnosisReport) -> Vec<String> {
    let adopted: Vec<&str> = r.adopted.iter().map(|c| c.name()).collect();
    let mut lines = vec![format!(
        "{}: {}; RMS marker error {:.1} → {:.1} µm fitted, {:.1} → {:.1} µm held out (noise floor {:.1} µm)",
        r.input.dataset,
        r.residual_check.verdict(&adopted.join(", ")),
        1e6 * r.before.fitted_rms,
        1e6 * r.after.fitted_rms,
        1e6 * r.before.heldout_rms,
        1e6 * r.after.heldout_rms,
        1e6 * r.noise_floor
    )];
    if !r.detectable.is_empty() {
        lines.push(
            "  would have detected (smallest magnitudes; smaller effects of these kinds may be present):"
                .into(),
        );
        lines.extend(r.detectable.iter().map(|d| format!("    {}", d.describe())));
    }
    lines
}

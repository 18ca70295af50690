//! The report of a curve diagnosis: `diagnosis.md`, `diagnosis.json`, `curves.svg` (measured vs
//! the simplest and the final model) and one `residual-<round>-<variable>.svg` per adopted effect
//! (the residual before and after against the variable that gave the effect away).

use super::select::{resid_of, Selection, Step};
use super::signature::{evidence, Variable};
use super::{CurveDiagnosis, CurveError};
use palpate_fem::io::atomic::write_atomic;
use palpate_plot::{lines, Series, Style};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Plot points.
type Points = Vec<(f64, f64)>;

fn thin(v: Vec<(f64, f64)>, max: usize) -> Vec<(f64, f64)> {
    let stride = v.len().div_ceil(max.max(1)).max(1);
    v.into_iter().step_by(stride).collect()
}

fn g4(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let a = v.abs();
    if (1e-3..1e5).contains(&a) {
        format!("{v:.4}")
    } else {
        format!("{v:.4e}")
    }
}

/// The axis label of the mean loading rate for a load variable labelled `x_label` ("displacement
/// (mm)" → "mean loading rate of the displacement (mm/s)"; a quantity without a unit, like a
/// strain, gives 1/s).
fn rate_label(x_label: &str) -> String {
    match x_label.rsplit_once(" (") {
        Some((quantity, unit)) => {
            let unit = unit.trim_end_matches(')');
            format!("mean loading rate of the {quantity} ({unit}/s)")
        }
        None => format!("mean loading rate of the {x_label} (1/s)"),
    }
}

/// Writes the report into `dir`; returns the files written.
pub fn write_report(d: &CurveDiagnosis, dir: &Path) -> Result<Vec<PathBuf>, CurveError> {
    let werr = |e: palpate_fem::io::atomic::AtomicWriteError| CurveError::Write(e.to_string());
    let mut files = Vec::new();
    let ts = d.format.is_time_series();
    let (xl, yl) = d.format.labels();
    let sel = d
        .selection
        .as_ref()
        .ok_or_else(|| CurveError::Write("no selection".into()))?;
    let groups = &d.data;

    // Measured vs model, for up to 4 files spread over the list.
    let picks: Vec<usize> = if groups.len() <= 4 {
        (0..groups.len()).collect()
    } else {
        (0..4).map(|k| k * (groups.len() - 1) / 3).collect()
    };
    let first = &sel.fits[0];
    let last = sel.fits.last().expect("non-empty");
    let mut owned: Vec<(String, Points, Style)> = Vec::new();
    for &gi in &picks {
        let g = &groups[gi];
        let meas: Vec<(f64, f64)> = g.x.iter().copied().zip(g.y.iter().copied()).collect();
        let style = if ts { Style::Line } else { Style::Points };
        owned.push((format!("{} measured", g.name), thin(meas, 1000), style));
        for (lab, f) in [("simplest", first), ("final", last)] {
            if let Some(p) = f.model.predict(&f.theta, g) {
                let pts = g.x.iter().copied().zip(p).collect();
                owned.push((format!("{} {lab}", g.name), thin(pts, 1000), Style::Line));
            }
        }
    }
    let series: Vec<Series> = owned
        .iter()
        .map(|(n, p, s)| Series::new(n, p, *s))
        .collect();
    let curves = dir.join("curves.svg");
    files.extend(
        lines(
            &curves,
            &format!(
                "{}: measured vs {} / {}",
                d.name, d.before_model, d.after_model
            ),
            xl,
            yl,
            &series,
        )
        .map_err(|e| CurveError::Write(e.to_string()))?,
    );

    let plot_names = residual_plots(d, sel, dir, &mut files)?;
    let md = markdown(d, &plot_names);
    let mdp = dir.join("diagnosis.md");
    write_atomic(&mdp, md.as_bytes()).map_err(werr)?;
    files.push(mdp);
    let json = json_text(d).map_err(|e| CurveError::Write(e.to_string()))?;
    let jp = dir.join("diagnosis.json");
    write_atomic(&jp, json.as_bytes()).map_err(werr)?;
    files.push(jp);
    Ok(files)
}

/// The residual against the variable that gave each adopted effect away (or against the load
/// magnitude when clean), before and after: writes the plots, appends them to `files` and returns
/// their names as the report shows them.
fn residual_plots(
    d: &CurveDiagnosis,
    sel: &Selection,
    dir: &Path,
    files: &mut Vec<PathBuf>,
) -> Result<Vec<String>, CurveError> {
    let ts = d.format.is_time_series();
    let (xl, yl) = d.format.labels();
    let groups = &d.data;
    let mut plots: Vec<(usize, Variable)> = d
        .steps
        .iter()
        .enumerate()
        .filter_map(|(k, s)| s.evidence.map(|v| (k, v)))
        .collect();
    if plots.is_empty() {
        plots.push((usize::MAX, Variable::Magnitude));
    }
    let mut plot_names = Vec::new();
    for (k, var) in plots {
        let (before, after) = if k == usize::MAX {
            (&sel.fits[0], None)
        } else {
            (&sel.fits[k], Some(&sel.fits[k + 1]))
        };
        let mut owned: Vec<(String, Vec<(f64, f64)>)> = Vec::new();
        for (lab, f) in [("before", Some(before)), ("after", after)] {
            let Some(f) = f else { continue };
            for (name, pts) in evidence(var, groups, &resid_of(f, groups), ts) {
                owned.push((format!("{lab}: {name}"), thin(pts, 800)));
            }
        }
        let series: Vec<Series> = owned
            .iter()
            .filter(|(_, p)| !p.is_empty())
            .map(|(n, p)| Series::new(n, p, Style::Points))
            .collect();
        if series.is_empty() {
            continue;
        }
        let xv = match var {
            Variable::Magnitude | Variable::Top | Variable::Direction => xl.to_string(),
            Variable::Rate => rate_label(xl),
            Variable::HoldTime => "time since the hold began (s)".into(),
            Variable::Group => "run / file index".into(),
        };
        let tag = var.name().replace([' ', '/'], "-").replace("--", "-");
        let name = if k == usize::MAX {
            format!("residual-{tag}.svg")
        } else {
            format!("residual-round{}-{tag}.svg", k + 1)
        };
        let title = if k == usize::MAX {
            format!(
                "{}: residual of the simplest model vs {}",
                d.name,
                var.name()
            )
        } else {
            format!(
                "{}: residual before/after {} vs {}",
                d.name,
                d.steps[k].adopted.map(|c| c.name()).unwrap_or_default(),
                var.name()
            )
        };
        let p = dir.join(&name);
        files.extend(
            lines(
                &p,
                &title,
                &xv,
                &format!("residual, measured − model: {yl}"),
                &series,
            )
            .map_err(|e| CurveError::Write(e.to_string()))?,
        );
        plot_names.push(palpate_plot::shown(&name));
    }
    Ok(plot_names)
}

/// The text of `diagnosis.json`: the diagnosis with `schema_version`. The errors are in the
/// response's unit, which depends on the data (`unit`: N, MPa, ADC counts), so their names carry
/// no unit; times do (`run_time_s`).
pub fn json_text(d: &CurveDiagnosis) -> Result<String, serde_json::Error> {
    let mut v = serde_json::to_value(d)?;
    crate::json::rename(&mut v, "", &[("seconds", "run_time_s")]);
    crate::json::finish("curve-diagnosis", v)
}

fn markdown(d: &CurveDiagnosis, plots: &[String]) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# Curve diagnosis: {}\n", d.name);
    let _ = writeln!(
        s,
        "Format **{}**; {} file(s)/run(s); {} samples used of {} read. Response unit: {}.\n",
        d.format.name(),
        d.groups.len(),
        d.samples.0,
        d.samples.1,
        d.unit
    );
    let _ = writeln!(s, "Sources: {}\n", d.sources.join(", "));
    let _ = writeln!(
        s,
        "**Result: {}.**\n",
        if d.adopted.is_empty() {
            "clean — no effect adopted".to_string()
        } else {
            format!("adopted {}", d.adopted.join(", then "))
        }
    );
    let _ = writeln!(
        s,
        "| model | fitted RMS | fitted max | held-out RMS | held-out max |\n|---|---|---|---|---|"
    );
    for (m, e) in [(&d.before_model, &d.before), (&d.after_model, &d.after)] {
        let _ = writeln!(
            s,
            "| {m} | {} | {} | {} | {} |",
            g4(e.fitted_rms),
            g4(e.fitted_max),
            g4(e.heldout_rms),
            g4(e.heldout_max)
        );
    }
    let _ = writeln!(
        s,
        "\nHeld out: {}. Selection: {}.\n",
        d.holdout, d.criterion
    );
    let _ = writeln!(
        s,
        "Held-out RMS per file/run:\n\n| file/run | samples | {} | {} |\n|---|---|---|---|",
        d.before_model, d.after_model
    );
    for (n, k, b, a) in &d.per_group {
        let _ = writeln!(s, "| {n} | {k} | {} | {} |", g4(*b), g4(*a));
    }
    let _ = writeln!(s);
    for st in &d.steps {
        round(&mut s, st);
    }
    parameters(&mut s, d);
    let _ = writeln!(s, "## Notes\n");
    for n in &d.notes {
        let _ = writeln!(s, "- {n}");
    }
    let _ = writeln!(
        s,
        "\n## Plots\n\n- `{}`: measured vs the simplest and the final model",
        palpate_plot::shown("curves.svg")
    );
    for p in plots {
        let _ = writeln!(s, "- `{p}`");
    }
    let _ = writeln!(s, "\nWall-clock {:.1} s.", d.seconds);
    s
}

/// One round: the signature, every candidate tried, the decision.
fn round(s: &mut String, st: &Step) {
    let _ = writeln!(s, "## Round {}: {}\n", st.round, st.model);
    let _ = writeln!(
        s,
        "Residual RMS {}. Signature (strongest first):\n",
        g4(st.signature.rms)
    );
    let _ = writeln!(
        s,
        "| residual vs | share | points to | detail |\n|---|---|---|---|"
    );
    for sg in &st.signature.signals {
        let _ = writeln!(
            s,
            "| {} | {:.2} | {} | {} |",
            sg.variable.name(),
            sg.explained,
            sg.variable.points_to(),
            sg.detail
        );
    }
    let _ = writeln!(s, "\n| candidate | extra params | fitted RMS | ΔBIC | held-out RMS | gain | passes |\n|---|---|---|---|---|---|---|");
    for t in &st.tried {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {:.1} | {} | {:+.1} % | {} |",
            t.candidate,
            t.extra_params,
            g4(t.rms),
            t.delta_bic,
            g4(t.heldout_rms),
            100.0 * t.gain,
            if t.passed { "yes" } else { "no" }
        );
    }
    let _ = writeln!(s, "\n**Decision:** {}", st.reason);
    if let (Some(c), Some(e)) = (st.adopted, st.after) {
        let _ = writeln!(
            s,
            "\nEffect: {}. Evidence: residual vs {}. RMS {} → {} fitted, {} → {} held out.\n",
            c.words(),
            st.evidence.map_or("-", |v| v.name()),
            g4(st.before.fitted_rms),
            g4(e.fitted_rms),
            g4(st.before.heldout_rms),
            g4(e.heldout_rms)
        );
    } else {
        let _ = writeln!(s);
    }
}

/// The parameters of the final and of the simplest model.
fn parameters(s: &mut String, d: &CurveDiagnosis) {
    for (title, ps) in [
        ("Final model: ", &d.final_params),
        ("Simplest model: ", &d.before_params),
    ] {
        let m = if title.starts_with("Final") {
            &d.after_model
        } else {
            &d.before_model
        };
        let _ = writeln!(
            s,
            "## {title}{m}\n\n| parameter | value | ± 1σ | unit |\n|---|---|---|---|"
        );
        for p in ps.iter() {
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} |",
                p.name,
                g4(p.value),
                g4(p.sd),
                p.unit
            );
        }
        let _ = writeln!(s);
    }
}

/// The one-line summary of `d` the command prints: what was adopted and the RMS errors before and
/// after, in the curves' unit.
pub fn summary_line(d: &CurveDiagnosis) -> String {
    let fmt = |v: f64| format!("{v:.4e}");
    format!(
        "{}: {}; RMS {} → {} fitted, {} → {} held out ({})",
        d.name,
        if d.adopted.is_empty() {
            "clean (no effect adopted)".to_string()
        } else {
            format!("adopted {}", d.adopted.join(", "))
        },
        fmt(d.before.fitted_rms),
        fmt(d.after.fitted_rms),
        fmt(d.before.heldout_rms),
        fmt(d.after.heldout_rms),
        d.unit
    )
}

//! `palpate-lab beam-load-point`: where does a hanging weight act? A weight hung from a hook is a
//! force at the hook's point, which need not be the loaded group's nodes: a hook that stands off
//! the end face adds a moment the group's nodes cannot carry. This study moves each loaded run's
//! weights by a lever d along the body's long axis (`palpate_motion::load_point`, the product's
//! own), fits the shear modulus to the rest states at each d (`palpate_motion::rest_fit`) and
//! reports each run's own modulus beside the joint one — a modulus that does not depend on the
//! load is the sign of the right point — with the rest-state RMS of the fitted and held-out runs,
//! then the lever the `load-point` candidate reads (`load_point::fit_lever`). Import the runs
//! first (docs/results/beam/load-point.md has the commands).

use anyhow::Context as _;
use palpate_motion::dataset::{self, MotionDataset};
use palpate_motion::load_point::fit_lever;
use palpate_motion::rest_fit::{
    fit_shear_modulus, predict_rest, Design, RestSolve, RestState, StandOff,
};
use serde::Serialize;
use std::path::PathBuf;

/// Arguments of `palpate-lab beam-load-point`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The folder holding one imported dataset per run.
    #[arg(long)]
    pub datasets: PathBuf,
    /// The runs the modulus is fitted to.
    #[arg(long, value_delimiter = ',', default_values_t = ["gravity_V2_a".to_string(), "load52_V2_a".to_string()])]
    pub fit: Vec<String>,
    /// Runs only predicted at the fitted modulus.
    #[arg(long, value_delimiter = ',', default_values_t = ["gravity_V2_b".to_string(), "load52_V2_b".to_string()])]
    pub held_out: Vec<String>,
    /// Levers d of the hanging weights beyond their nodes along the long axis (mm).
    #[arg(long, value_delimiter = ',', default_values_t = [-5.0, 0.0, 5.0, 10.0, 15.0])]
    pub lever_mm: Vec<f64>,
    /// Poisson's ratio (held).
    #[arg(long, default_value_t = 0.49)]
    pub poisson: f64,
    /// Element design: P1 or P2.
    #[arg(long, default_value = "P1")]
    pub design: String,
    /// The rest state is the markers' mean over this many final seconds of each capture.
    #[arg(long, default_value_t = 0.5)]
    pub window: f64,
    /// How the markers on stand-offs follow the beam: `extrapolated` (the element's
    /// interpolation carried out to the marker) or `rigid-post`.
    #[arg(long, default_value = "extrapolated")]
    pub stand_off: String,
}

#[derive(Debug, Serialize)]
struct Row {
    lever_mm: f64,
    joint_young_pa: f64,
    per_run_young_pa: Vec<(String, f64)>,
    fitted_rms_m: Vec<(String, f64)>,
    held_out_rms_m: Vec<(String, f64)>,
}

fn mm(v: &[(String, f64)]) -> String {
    v.iter()
        .map(|(n, r)| format!("{n} {:.3}", 1e3 * r))
        .collect::<Vec<_>>()
        .join(", ")
}

/// The run's rest state with its hanging weights moved by `lever` (m).
fn moved(ds: &MotionDataset, base: &RestState, lever: f64) -> anyhow::Result<RestState> {
    let mut model = ds.model.clone();
    model.set_load_lever(lever)?;
    Ok(base.with_loads_of(&model))
}

/// Runs the study.
pub fn run(a: Args) -> anyhow::Result<()> {
    let design = match a.design.as_str() {
        "P1" => Design::Linear,
        "P2" => Design::Quadratic,
        d => anyhow::bail!("--design: expected P1 or P2, found {d:?}"),
    };
    let stand_off = match a.stand_off.as_str() {
        "extrapolated" => StandOff::Extrapolated,
        "rigid-post" => StandOff::RigidPost,
        s => anyhow::bail!("--stand-off: expected extrapolated or rigid-post, found {s:?}"),
    };
    let load = |r: &String| -> anyhow::Result<(String, MotionDataset, RestState)> {
        let dir = a.datasets.join(r);
        let ds = dataset::load(&dir).with_context(|| format!("reading {}", dir.display()))?;
        let mut s = RestState::of_dataset(&ds, a.window)
            .with_context(|| format!("rest state of {}", dir.display()))?;
        s.stand_off = stand_off;
        Ok((r.clone(), ds, s))
    };
    let fitted: Vec<_> = a.fit.iter().map(load).collect::<Result<_, _>>()?;
    let held: Vec<_> = a.held_out.iter().map(load).collect::<Result<_, _>>()?;
    let solve = RestSolve {
        load_steps: 4,
        tol: 1e-6,
    };
    let nu = a.poisson;
    let e_of = |mu: f64| 2.0 * mu * (1.0 + nu);
    println!("| lever (mm) | E joint (kPa) | E per run (kPa) | fitted rest RMS (mm) | held-out rest RMS (mm) |");
    println!("|---|---|---|---|---|");
    let mut rows = Vec::new();
    for &lever in &a.lever_mm {
        let d = 1e-3 * lever;
        let f: Vec<(String, RestState)> = fitted
            .iter()
            .map(|(n, ds, s)| Ok((n.clone(), moved(ds, s, d)?)))
            .collect::<anyhow::Result<_>>()?;
        let h: Vec<(String, RestState)> = held
            .iter()
            .map(|(n, ds, s)| Ok((n.clone(), moved(ds, s, d)?)))
            .collect::<anyhow::Result<_>>()?;
        let states: Vec<RestState> = f.iter().map(|(_, s)| s.clone()).collect();
        let joint = fit_shear_modulus(&states, design, nu, 46e3, &solve, 12)?;
        let mut per_run = Vec::new();
        for (n, s) in f.iter().chain(&h) {
            let one = fit_shear_modulus(std::slice::from_ref(s), design, nu, joint.mu, &solve, 12)?;
            per_run.push((n.clone(), e_of(one.mu)));
        }
        let fitted_rms: Vec<(String, f64)> = f
            .iter()
            .zip(&joint.predictions)
            .map(|((n, s), p)| (n.clone(), p.rms(s)))
            .collect();
        let mut held_rms = Vec::new();
        for (n, s) in &h {
            let p = predict_rest(s, design, joint.mu, nu, &solve, false)?;
            held_rms.push((n.clone(), p.rms(s)));
        }
        let row = Row {
            lever_mm: lever,
            joint_young_pa: e_of(joint.mu),
            per_run_young_pa: per_run,
            fitted_rms_m: fitted_rms,
            held_out_rms_m: held_rms,
        };
        println!(
            "| {lever} | {:.1} | {} | {} | {} |",
            row.joint_young_pa / 1e3,
            row.per_run_young_pa
                .iter()
                .map(|(n, e)| format!("{n} {:.1}", e / 1e3))
                .collect::<Vec<_>>()
                .join(", "),
            mm(&row.fitted_rms_m),
            mm(&row.held_out_rms_m)
        );
        rows.push(row);
    }
    let sets: Vec<&MotionDataset> = fitted.iter().map(|(_, ds, _)| ds).collect();
    let read = fit_lever(&sets, design, nu, 46e3, a.window)?;
    println!(
        "the lever the load-point candidate reads from the fitted runs: {:.2} mm ± {:.2} mm (E {:.1} kPa; rest RMS {:.3} → {:.3} mm; {} levers tried)",
        1e3 * read.offset_m,
        1e3 * read.sigma_m,
        e_of(read.mu) / 1e3,
        1e3 * read.rms_on_nodes_m,
        1e3 * read.rms_m,
        read.evaluations
    );
    println!(
        "{}",
        serde_json::json!({ "design": a.design, "poisson": nu, "rows": rows, "read": read })
    );
    Ok(())
}

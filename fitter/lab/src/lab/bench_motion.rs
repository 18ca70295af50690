//! `palpate-lab bench motion`: the MyFEM anchor problem (ANCHORS.md) — a 3 × 22 × 3 cm bar, 1,188
//! tets, density 47 kg/m³, gravity, base moving 1.5 cm·(1−cos 6πt) in x + 0.5 cm·(1−cos 10πt) in
//! z, BDF2 at Δt = 1/180 s for 90 steps, static start, 9 markers, 4 global log-parameters
//! (λ, μ, ν, h) fitted from (20k, 10k, 6, 1.3) to the truth (10k, 20k, 12, 1.0).

use palpate_motion::gradient::{evaluate, Method};
use palpate_motion::model::{Material, Param, ParamKind};
use palpate_motion::optimize::{fit, FitSettings, Optimizer};
use palpate_motion::scenario::{bar_model, nine_markers, record, two_sinusoids};
use std::time::Instant;

/// Options of the motion benchmark.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Time steps (the anchor uses 90 = 0.5 s at 180 Hz).
    #[arg(long, default_value_t = 90)]
    pub steps: usize,
    /// Repeats of each simulation timing (median and max are reported).
    #[arg(long, default_value_t = 5)]
    pub repeats: usize,
    /// Skip the optimisation (timings of single simulations only).
    #[arg(long)]
    pub no_optimize: bool,
}

fn peak_rss_bytes() -> u64 {
    // VmHWM: the process's peak resident set size (Linux); 0 where unavailable.
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines().find(|l| l.starts_with("VmHWM:")).and_then(|l| {
                l.split_whitespace()
                    .nth(1)
                    .and_then(|v| v.parse::<u64>().ok())
            })
        })
        .map(|kb| kb * 1024)
        .unwrap_or(0)
}

/// One optimisation's figures.
struct Optimised {
    seconds: f64,
    evaluations: usize,
    iterations: u64,
    rms: f64,
    fitted: Vec<f64>,
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

/// Runs the benchmark.
pub fn run(args: Args) -> anyhow::Result<()> {
    let size = [0.03, 0.22, 0.03];
    let dt = 1.0 / 180.0;
    let (_, model) = bar_model(
        size,
        [3, 22, 3],
        dt,
        args.steps,
        &two_sinusoids,
        &nine_markers(size),
    )?;
    let ne = model.tets.len();
    let truth = Material::uniform(ne, 1.0e4, 2.0e4, 12.0, 1.0, 47.0);
    let obs = record(&model, &truth, 0.0, 1)?;
    let params: Vec<Param> = [
        ParamKind::Lambda,
        ParamKind::Mu,
        ParamKind::Nu,
        ParamKind::PowerH,
    ]
    .into_iter()
    .map(Param::global)
    .collect();
    let q0 = [2.0e4, 1.0e4, 6.0, 1.3];
    let mut start = truth.clone();
    start.set(&params, &q0);
    let reps = args.repeats.max(1);
    let time =
        |m: Option<Method>| -> anyhow::Result<(Vec<f64>, palpate_motion::gradient::Evaluation)> {
            let mut t = Vec::new();
            let mut last = None;
            for _ in 0..reps {
                let t0 = Instant::now();
                let ev = evaluate(&model, &start, &params, &obs, m)?;
                t.push(t0.elapsed().as_secs_f64());
                last = Some(ev);
            }
            Ok((t, last.expect("at least one repeat")))
        };
    let (t_fwd, ev_fwd) = time(None)?;
    let (t_dir, ev_dir) = time(Some(Method::Direct))?;
    let (t_adj, ev_adj) = time(Some(Method::Adjoint))?;
    let (gd, ga) = (
        ev_dir.grad.clone().unwrap_or_default(),
        ev_adj.grad.clone().unwrap_or_default(),
    );
    let agree = gd
        .iter()
        .zip(&ga)
        .map(|(d, a)| (d - a).abs() / a.abs().max(1e-300))
        .fold(0.0, f64::max);
    println!(
        "motion benchmark: {} tets, {} nodes ({} free dofs), {} steps at 180 Hz, {} markers, {} threads",
        ne,
        model.nodes.len(),
        model.nfree,
        args.steps,
        model.markers.len(),
        rayon::current_num_threads()
    );
    println!("| run | median s | max s | Newton iterations | factorisations | notes |");
    println!("|---|---|---|---|---|---|");
    let mx = |v: &[f64]| v.iter().cloned().fold(0.0, f64::max);
    println!(
        "| forward simulation | {:.3} | {:.3} | {} | {} | {:.2} per step, max residual {:.1e} N |",
        median(t_fwd.clone()),
        mx(&t_fwd),
        ev_fwd.stats.newton_iterations,
        ev_fwd.stats.factorisations,
        ev_fwd.stats.newton_iterations as f64 / args.steps as f64,
        ev_fwd.stats.max_residual
    );
    println!(
        "| forward + direct gradient | {:.3} | {:.3} | {} | {} | sensitivities {} bytes |",
        median(t_dir.clone()),
        mx(&t_dir),
        ev_dir.stats.newton_iterations,
        ev_dir.stats.factorisations,
        ev_dir.stored_bytes
    );
    println!(
        "| forward + adjoint gradient | {:.3} | {:.3} | {} | {} | tape {} bytes ({} per step) |",
        median(t_adj.clone()),
        mx(&t_adj),
        ev_adj.stats.newton_iterations,
        ev_adj.stats.factorisations,
        ev_adj.stored_bytes,
        ev_adj.stored_bytes / args.steps.max(1)
    );
    println!("direct vs adjoint gradient: max relative difference {agree:.2e}");
    // Both optimisers from the same start: the paper's LBFGS (what the anchor ran) and
    // Levenberg–Marquardt on the Gauss–Newton matrix (palpate's default for global parameters).
    let optimise = |optimizer: Optimizer, label: &str| -> anyhow::Result<Option<Optimised>> {
        if args.no_optimize {
            return Ok(None);
        }
        let t0 = Instant::now();
        let settings = FitSettings {
            optimizer,
            method: Method::Adjoint,
            memory: 5,
            max_iters: 100,
            tol_grad: 1e-14,
            tol_cost: 1e-12,
            data_precision: true,
            smoothness: None,
            poisson: None,
            floors: Vec::new(),
        };
        let r = fit(
            &model,
            &truth,
            &params,
            &q0,
            &obs,
            &settings,
            &[],
            &|_, _| {},
        )?;
        let o = Optimised {
            seconds: t0.elapsed().as_secs_f64(),
            evaluations: r.evaluations,
            iterations: r.iterations,
            rms: r.eval.rms_marker,
            fitted: r.q.clone(),
        };
        println!(
            "| {label} | {:.2} | — | — | — | {} iterations, {} evaluations; fitted λ {:.1}, μ {:.1}, ν {:.4}, h {:.4}; RMS {:.2e} m |",
            o.seconds, o.iterations, o.evaluations, r.q[0], r.q[1], r.q[2], r.q[3], o.rms
        );
        for f in &r.failures {
            println!("  note: {f}");
        }
        Ok(Some(o))
    };
    let lbfgs = optimise(
        Optimizer::Lbfgs,
        "LBFGS optimisation (m = 5, Moré–Thuente strong Wolfe, adjoint)",
    )?;
    let lm = optimise(
        Optimizer::LevenbergMarquardt,
        "Levenberg–Marquardt optimisation (Gauss–Newton matrix from direct sensitivities)",
    )?;
    println!(
        "MyFEM anchor (same problem, one thread): forward 3.0–3.3 s, +adjoint 4.15 s, +direct 6.2 s, optimisation 137 s / 34 evaluations"
    );
    // The anchor was measured on another machine of this kind (ANCHORS.md): these ratios are a
    // cross-machine comparison, which can be off by the 3.5× spread ANCHORS.md reports.
    let (anchor_fwd, anchor_adj, anchor_opt) = (3.15, 4.15, 137.0);
    let ratio_opt = lbfgs.as_ref().map(|o| anchor_opt / o.seconds);
    let ratio_lm = lm.as_ref().map(|o| anchor_opt / o.seconds);
    println!(
        "anchor / palpate (cross-machine, not same-run): forward {:.1}×, +adjoint {:.1}×{}",
        anchor_fwd / median(t_fwd.clone()),
        anchor_adj / median(t_adj.clone()),
        ratio_opt.map_or(String::new(), |r| format!(", optimisation {r:.1}× (LBFGS)")),
    );
    if let Some(r) = ratio_lm {
        println!("anchor / palpate optimisation with Levenberg–Marquardt: {r:.1}× (cross-machine)");
    }
    let json = serde_json::json!({
        "schema_version": 1,
        "bench": "motion",
        "tets": ne,
        "nodes": model.nodes.len(),
        "steps": args.steps,
        "markers": model.markers.len(),
        "sim_seconds": median(t_fwd.clone()),
        "sim_grad_seconds_direct": median(t_dir),
        "sim_grad_seconds_adjoint": median(t_adj.clone()),
        "direct_adjoint_max_rel_diff": agree,
        "newton_iterations_adjoint": ev_adj.stats.newton_iterations,
        "factorisations_adjoint": ev_adj.stats.factorisations,
        "factorisations_forward": ev_fwd.stats.factorisations,
        "anchor_ratio_forward": anchor_fwd / median(t_fwd.clone()),
        "anchor_ratio_adjoint": anchor_adj / median(t_adj.clone()),
        "anchor_ratio_optimize": ratio_opt,
        "anchor_ratio_optimize_lm": ratio_lm,
        "adjoint_tape_bytes": ev_adj.stored_bytes,
        "optimize_seconds": lbfgs.as_ref().map(|o| o.seconds),
        "iterations": lbfgs.as_ref().map(|o| o.iterations),
        "evaluations": lbfgs.as_ref().map(|o| o.evaluations),
        "fitted": lbfgs.as_ref().map(|o| o.fitted.clone()),
        "rms_m": lbfgs.as_ref().map(|o| o.rms),
        "optimize_seconds_lm": lm.as_ref().map(|o| o.seconds),
        "iterations_lm": lm.as_ref().map(|o| o.iterations),
        "evaluations_lm": lm.as_ref().map(|o| o.evaluations),
        "fitted_lm": lm.as_ref().map(|o| o.fitted.clone()),
        "rms_m_lm": lm.as_ref().map(|o| o.rms),
        "peak_bytes": peak_rss_bytes(),
    });
    println!("{json}");
    Ok(())
}

/// Options of the integrator benchmark (`bench motion-schemes`).
#[derive(Debug, clap::Args)]
pub struct SchemesArgs {
    /// A motion dataset folder (e.g. the beam's gravity run, imported as in
    /// models/silicone-beam/README.md); its own `substeps` is ignored.
    pub dataset: std::path::PathBuf,
    /// The fitted material to simulate (`palpate fit-motion`'s JSON on the dataset's mesh).
    #[arg(long, default_value = "models/silicone-beam/fit.json")]
    pub material: std::path::PathBuf,
    /// Rounds of the alternating timings (medians are reported).
    #[arg(long, default_value_t = 3)]
    pub repeats: usize,
    /// BDF2 substeps of the converged reference.
    #[arg(long, default_value_t = 12)]
    pub reference_substeps: usize,
}

/// This process's CPU time (user + system, all threads) from /proc/self/stat, in seconds; 0
/// where unavailable.
fn process_cpu_seconds() -> f64 {
    // Fields after the parenthesised command name: state is the 3rd, utime the 14th, stime the
    // 15th of the whole line; in clock ticks (100 per second on Linux).
    std::fs::read_to_string("/proc/self/stat")
        .ok()
        .and_then(|s| {
            let rest = &s[s.rfind(')')? + 2..];
            let f: Vec<&str> = rest.split_whitespace().collect();
            let ticks = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
            Some(ticks / 100.0)
        })
        .unwrap_or(0.0)
}

/// One integrator configuration's simulation of the dataset: the markers at every capture frame
/// and at every step (the tip's), and the counters.
struct SchemeRun {
    frames: Vec<Vec<[f64; 3]>>,
    steps: Vec<[f64; 3]>,
}

/// Runs `palpate-lab bench motion-schemes`: BDF2 at its rule's substeps and at the converged
/// reference's, the midpoint rule at its rule's substeps and at the capture rate, each a forward
/// simulation and one with the direct gradient (Gauss–Newton), timed in alternation in this one
/// process; prints JSON.
pub fn run_schemes(args: SchemesArgs) -> anyhow::Result<()> {
    use palpate_motion::gradient::evaluate_gauss_newton_with;
    use palpate_motion::sim::{simulate_states, KeptSolve, StepSolve};
    use palpate_motion::timestep::{substeps_for_scheme, Scheme};
    let ds = palpate_motion::dataset::load(&args.dataset)?;
    let fitted: palpate_motion::fitted::FittedModel =
        serde_json::from_str(&std::fs::read_to_string(&args.material)?)?;
    let mat = fitted
        .material()
        .map_err(|e| anyhow::anyhow!("{}: {e}", args.material.display()))?;
    // Back to the capture rate: every configuration resamples from there.
    let k0 = ds.timestep.substeps;
    let mut base = ds.model.clone();
    base.dt *= k0 as f64;
    base.steps /= k0;
    base.substeps = 1;
    base.clamps.iter_mut().for_each(|c| {
        c.poses = c.poses.iter().step_by(k0).cloned().collect();
    });
    base.loads.iter_mut().for_each(|l| l.from_step /= k0);
    let obs = palpate_motion::model::Observations {
        markers: ds
            .obs
            .markers
            .iter()
            .skip(k0 - 1)
            .step_by(k0)
            .cloned()
            .collect(),
        forces: ds
            .obs
            .forces
            .iter()
            .skip(k0 - 1)
            .step_by(k0)
            .cloned()
            .collect(),
        ..ds.obs.clone()
    };
    anyhow::ensure!(
        mat.values[0].len() == base.tets.len(),
        "{}: {} elements, the dataset's mesh has {}",
        args.material.display(),
        mat.values[0].len(),
        base.tets.len()
    );
    let period = ds.timestep.period_s;
    let params: Vec<Param> = fitted
        .fitted
        .iter()
        .filter_map(|k| ParamKind::ALL.into_iter().find(|p| p.name() == k))
        .map(Param::global)
        .collect();
    let configs = [
        (
            "bdf2, its rule",
            Scheme::Bdf2,
            substeps_for_scheme(Scheme::Bdf2, base.dt, period),
        ),
        (
            "midpoint, its rule",
            Scheme::Midpoint,
            substeps_for_scheme(Scheme::Midpoint, base.dt, period),
        ),
        ("midpoint, capture rate", Scheme::Midpoint, 1),
        (
            "alpha, its rule",
            Scheme::Alpha,
            substeps_for_scheme(Scheme::Alpha, base.dt, period),
        ),
        ("alpha, capture rate", Scheme::Alpha, 1),
        ("bdf2, reference", Scheme::Bdf2, args.reference_substeps),
    ];
    let models: Vec<_> = configs
        .iter()
        .map(|&(_, scheme, k)| {
            let mut m = base.clone();
            m.scheme = scheme;
            m.resampled(&obs, k)
        })
        .collect();
    let record = |m: &palpate_motion::model::Model| -> anyhow::Result<SchemeRun> {
        let mut run = SchemeRun {
            frames: Vec::new(),
            steps: Vec::new(),
        };
        simulate_states(m, &mat, |s| {
            let at = |i: usize| m.marker_position(&m.markers[i], s.x);
            run.steps.push(at(0));
            if s.n % m.substeps == 0 {
                run.frames.push((0..m.markers.len()).map(at).collect());
            }
            Ok(())
        })?;
        Ok(run)
    };
    let runs: Vec<SchemeRun> = models
        .iter()
        .map(|(m, _)| record(m))
        .collect::<Result<_, _>>()?;
    let reference = runs.last().expect("a reference");
    let mut wall = vec![(Vec::new(), Vec::new()); configs.len()];
    let mut cpu = vec![(Vec::new(), Vec::new()); configs.len()];
    let mut counters = vec![None; configs.len()];
    // "direct_gradient" is timed with the kept-factor CG solves (`StepSolve::Kept`), and the
    // same evaluation with every converged step factorised afresh (`StepSolve::Fresh`) in the
    // same alternation, with the largest relative differences of the gradient and of the
    // Gauss–Newton matrix between the two.
    let mut fresh_cpu = vec![Vec::new(); configs.len()];
    let mut fresh = vec![None; configs.len()];
    for _ in 0..args.repeats.max(1) {
        for (i, (m, o)) in models.iter().enumerate() {
            let (c0, t0) = (process_cpu_seconds(), Instant::now());
            let fwd = evaluate(m, &mat, &params, o, None)?;
            wall[i].0.push(t0.elapsed().as_secs_f64());
            cpu[i].0.push(process_cpu_seconds() - c0);
            // The reference's gradient is not a candidate: its forward run is the reference.
            let grad = if i + 1 < configs.len() {
                let (c0, t0) = (process_cpu_seconds(), Instant::now());
                let (ev, h) = evaluate_gauss_newton_with(
                    m,
                    &mat,
                    &params,
                    o,
                    StepSolve::Kept(KeptSolve::EXACT),
                )?;
                wall[i].1.push(t0.elapsed().as_secs_f64());
                cpu[i].1.push(process_cpu_seconds() - c0);
                let c0 = process_cpu_seconds();
                let (ev_f, h_f) =
                    evaluate_gauss_newton_with(m, &mat, &params, o, StepSolve::Fresh)?;
                fresh_cpu[i].push(process_cpu_seconds() - c0);
                let rel = |a: &[f64], b: &[f64]| {
                    let scale = b.iter().fold(0.0f64, |s, v| s.max(v.abs()));
                    a.iter()
                        .zip(b)
                        .map(|(p, q)| (p - q).abs() / scale.max(f64::MIN_POSITIVE))
                        .fold(0.0, f64::max)
                };
                let g_diff = match (&ev.grad, &ev_f.grad) {
                    (Some(a), Some(b)) => rel(a, b),
                    _ => f64::NAN,
                };
                fresh[i] = Some((ev_f, g_diff, rel(&h, &h_f)));
                Some(ev)
            } else {
                None
            };
            counters[i] = Some((fwd, grad));
        }
    }
    let med = |v: &[f64]| {
        if v.is_empty() {
            None
        } else {
            Some(median(v.to_vec()))
        }
    };
    let rms_between = |a: &[Vec<[f64; 3]>], b: &[Vec<[f64; 3]>]| -> f64 {
        let (mut sq, mut n) = (0.0, 0usize);
        for (fa, fb) in a.iter().zip(b) {
            for (p, q) in fa.iter().zip(fb) {
                sq += (0..3).map(|k| (p[k] - q[k]).powi(2)).sum::<f64>();
                n += 1;
            }
        }
        (sq / n.max(1) as f64).sqrt()
    };
    // The alternating (−1)^n component of the first marker's step-by-step path: a scheme that
    // rang at the Nyquist frequency would show it here.
    let nyquist = |steps: &[[f64; 3]]| -> f64 {
        let n = steps.len().max(1) as f64;
        (0..3)
            .map(|k| {
                let mean = steps.iter().map(|p| p[k]).sum::<f64>() / n;
                let s: f64 = steps
                    .iter()
                    .enumerate()
                    .map(|(j, p)| if j % 2 == 0 { p[k] - mean } else { mean - p[k] })
                    .sum();
                (s / n).abs()
            })
            .fold(0.0, f64::max)
    };
    let rows: Vec<serde_json::Value> = configs
        .iter()
        .enumerate()
        .map(|(i, &(name, scheme, k))| {
            let (m, _) = &models[i];
            let (fwd, grad) = counters[i].as_ref().expect("timed");
            let spp = period.map(|p| p / m.dt);
            let per = |ev: &palpate_motion::gradient::Evaluation| {
                serde_json::json!({
                    "newton_iterations": ev.stats.newton_iterations,
                    "factorisations": ev.stats.factorisations,
                    "cg_iterations": ev.stats.cg_iterations,
                    "unconverged_steps": ev.stats.unconverged_steps,
                })
            };
            serde_json::json!({
                "config": name,
                "scheme": scheme.name(),
                "substeps": k,
                "steps": m.steps,
                "steps_per_period": spp,
                "predicted_period_ratio": spp.map(|n| scheme.oscillator_error(n).0),
                "predicted_amplitude_per_cycle": spp.map(|n| scheme.oscillator_error(n).1),
                "forward": per(fwd),
                "forward_wall_s_median": med(&wall[i].0),
                "forward_cpu_s_median": med(&cpu[i].0),
                "direct_gradient": grad.as_ref().map(per),
                "direct_wall_s_median": med(&wall[i].1),
                "direct_cpu_s_median": med(&cpu[i].1),
                "direct_fresh_factor": fresh[i].as_ref().map(|(ev, g, h)| serde_json::json!({
                    "newton_iterations": ev.stats.newton_iterations,
                    "factorisations": ev.stats.factorisations,
                    "cpu_s_median": med(&fresh_cpu[i]),
                    "gradient_max_rel_diff_vs_kept": g,
                    "gauss_newton_max_rel_diff_vs_kept": h,
                })),
                "marker_rms_vs_capture_mm": 1e3 * fwd.rms_marker,
                "marker_rms_vs_reference_mm": 1e3 * rms_between(&runs[i].frames, &reference.frames),
                "nyquist_component_um": 1e6 * nyquist(&runs[i].steps),
            })
        })
        .collect();
    let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    let json = serde_json::json!({
        "dataset": args.dataset.display().to_string(),
        "material": args.material.display().to_string(),
        "parameters": fitted.fitted,
        "capture_period_s": period,
        "repeats": args.repeats,
        "threads": rayon::current_num_threads(),
        "loadavg_at_end": load.trim(),
        "runs": rows,
    });
    println!("{}", serde_json::to_string_pretty(&json)?);
    Ok(())
}

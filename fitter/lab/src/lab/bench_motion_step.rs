//! `palpate-lab bench motion-step`: what a time step with sensitivities costs and what makes it
//! cheaper — the numeric factorisation of S = c M + a_x K + a_v D by each of faer's sparse
//! Cholesky variants, the gradient evaluation with S factorised at every converged step
//! (`StepSolve::Fresh`) against CG preconditioned with Newton's kept factor to a looser
//! tolerance (`StepSolve::Kept`), and whole Levenberg–Marquardt fits under each.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, CholeskySymbolicParams, SymbolicCholesky, SymmetricOrdering,
};
use faer::sparse::linalg::SupernodalThreshold;
use faer::sparse::{SparseColMat, Triplet};
use faer::{Conj, MatMut, Par, Side};
use palpate_motion::gradient::{evaluate_gauss_newton_with, set_step_solve};
use palpate_motion::model::{Material, Model, Observations, Param, ParamKind};
use palpate_motion::sim::{simulate_solving, KeptSolve, StepSolve};
use std::time::Instant;

/// Options of `bench motion-step`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// A motion dataset folder: the beam's gravity run imported as in BENCHMARKS.md ("Motion
    /// integrators"), simulated as imported.
    pub dataset: std::path::PathBuf,
    /// The material to simulate (`palpate fit-motion`'s JSON on the dataset's mesh); its fitted
    /// parameters are the gradient's.
    #[arg(long, default_value = "models/silicone-beam/fit.json")]
    pub material: std::path::PathBuf,
    /// Timed factorisations (each with one solve) per variant and matrix.
    #[arg(long, default_value_t = 200)]
    pub factorisations: usize,
    /// Rounds of the alternating gradient evaluations (medians are reported).
    #[arg(long, default_value_t = 3)]
    pub rounds: usize,
    /// Relative residuals of the kept-factor solves to compare with fresh factorisations.
    #[arg(long, value_delimiter = ',', default_value = "1e-10,1e-6,1e-4")]
    pub tolerances: Vec<f64>,
    /// Datasets of a whole fit of (μ, viscosity) at Poisson's ratio 0.49, run under each step
    /// solve (e.g. the beam's gravity_V2_a and load52_V2_a); none: no whole fits.
    #[arg(long = "fit")]
    pub fit: Vec<std::path::PathBuf>,
    /// Skip the factorisation variants.
    #[arg(long)]
    pub no_factorisations: bool,
}

/// CPU time (s) of the calling thread: the factorisations run on it alone.
pub(super) fn thread_cpu() -> f64 {
    let t = rustix::time::clock_gettime(rustix::time::ClockId::ThreadCPUTime);
    t.tv_sec as f64 + t.tv_nsec as f64 * 1e-9
}

/// CPU time (s) of the whole process: a gradient evaluation runs in a thread pool.
fn process_cpu() -> f64 {
    let t = rustix::time::clock_gettime(rustix::time::ClockId::ProcessCPUTime);
    t.tv_sec as f64 + t.tv_nsec as f64 * 1e-9
}

/// The `q` quantile of `v` (nearest rank).
pub(super) fn quantile(v: &[f64], q: f64) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(|a, b| a.total_cmp(b));
    s[((s.len() - 1) as f64 * q).round() as usize]
}

/// S at the converged state of step `at` of `model` under `mat`, on the model's pattern.
fn step_matrix(model: &Model, mat: &Material, at: usize) -> anyhow::Result<Vec<f64>> {
    let (c, ax, av) = model.scheme.coefficients(model.dt);
    let mvals = model.mass_values(mat);
    let mut s = None;
    let mut short = model.clone();
    short.steps = at.min(model.steps);
    simulate_solving(
        &short,
        mat,
        StepSolve::Fresh,
        |_, _| {},
        |v| {
            if v.n == short.steps {
                s = Some(
                    (0..mvals.len())
                        .map(|i| c * mvals[i] + ax * v.k[i] + av * v.d[i])
                        .collect::<Vec<f64>>(),
                );
            }
            Ok(())
        },
    )?;
    s.ok_or_else(|| anyhow::anyhow!("step {at}: the run has no such step"))
}

/// One factorisation variant's timings (thread CPU, s) of a numeric factorisation with one
/// solve, and the solve's relative residual.
struct Timed {
    name: String,
    cpu: Vec<f64>,
    wall: Vec<f64>,
    factor_values: usize,
    residual: f64,
}

/// Numeric factorisation + one solve of the matrix with `values` on `pattern`'s entries by
/// faer's sparse Cholesky: ordering AMD (applied to the matrix once, as the product does) or the
/// caller's numbering, supernodal or simplicial, LLᵀ or LDLᵀ.
fn time_variants(
    pattern: &palpate_motion::sparse::Pattern,
    values: &[f64],
    reps: usize,
) -> anyhow::Result<Vec<Timed>> {
    let n = pattern.n;
    let entries: Vec<(usize, usize)> = pattern.entries().collect();
    let full: Vec<Triplet<usize, usize, f64>> = entries
        .iter()
        .flat_map(|&(r, c)| [Triplet::new(r, c, 1.0), Triplet::new(c, r, 1.0)])
        .collect();
    let full = SparseColMat::<usize, f64>::try_new_from_triplets(n, n, &full)?;
    let amd = factorize_symbolic_cholesky(
        full.symbolic(),
        Side::Lower,
        SymmetricOrdering::Amd,
        Default::default(),
    )?;
    let amd_order: Vec<usize> = match amd.perm() {
        Some(p) => p.arrays().0.to_vec(),
        None => (0..n).collect(),
    };
    let b: Vec<f64> = (0..n).map(|i| (i as f64 * 0.37).sin() + 0.1).collect();
    let mut out = Vec::new();
    // Solves the product's way too (its own permutation copies and allocations included).
    {
        let (mut cpu, mut wall) = (Vec::new(), Vec::new());
        let mut x = b.clone();
        for _ in 0..reps {
            let (c0, t0) = (thread_cpu(), Instant::now());
            let f = pattern
                .factor(values)
                .ok_or_else(|| anyhow::anyhow!("S is not positive definite"))?;
            x.copy_from_slice(&b);
            f.solve_in_place(&mut x);
            cpu.push(thread_cpu() - c0);
            wall.push(t0.elapsed().as_secs_f64());
        }
        out.push(Timed {
            name: "product: Pattern::factor + solve (AMD, supernodal LLᵀ)".into(),
            cpu,
            wall,
            factor_values: pattern.factor_bytes() / 8,
            residual: residual(pattern, values, &x, &b),
        });
    }
    for (ordering, order) in [("amd", amd_order), ("natural", (0..n).collect())] {
        let mut internal = vec![0; n];
        for (i, &d) in order.iter().enumerate() {
            internal[d] = i;
        }
        let lower: Vec<Triplet<usize, usize, f64>> = entries
            .iter()
            .zip(values)
            .map(|(&(r, c), &v)| {
                let (ri, ci) = (internal[r], internal[c]);
                Triplet::new(ri.max(ci), ri.min(ci), v)
            })
            .collect();
        let a = SparseColMat::<usize, f64>::try_new_from_triplets(n, n, &lower)?;
        // The symbolic analysis reads the whole symmetric pattern (as the product's does).
        let both: Vec<Triplet<usize, usize, f64>> = lower
            .iter()
            .flat_map(|t| {
                [
                    Triplet::new(t.row, t.col, 1.0),
                    Triplet::new(t.col, t.row, 1.0),
                ]
            })
            .collect();
        let both = SparseColMat::<usize, f64>::try_new_from_triplets(n, n, &both)?;
        for (kind, threshold) in [
            ("supernodal", SupernodalThreshold::FORCE_SUPERNODAL),
            ("simplicial", SupernodalThreshold::FORCE_SIMPLICIAL),
        ] {
            let symbolic = factorize_symbolic_cholesky(
                both.symbolic(),
                Side::Lower,
                SymmetricOrdering::Identity,
                CholeskySymbolicParams {
                    supernodal_flop_ratio_threshold: threshold,
                    ..Default::default()
                },
            )?;
            for ldlt in [false, true] {
                let (cpu, wall, x) = time_one(&symbolic, &a, &b, &order, ldlt, reps)?;
                out.push(Timed {
                    name: format!("{ordering}, {kind} {}", if ldlt { "LDLᵀ" } else { "LLᵀ" }),
                    cpu,
                    wall,
                    factor_values: symbolic.len_val(),
                    residual: residual(pattern, values, &x, &b),
                });
            }
        }
    }
    Ok(out)
}

/// Times `reps` numeric factorisations of `a` (lower triangle, internal numbering) each with one
/// solve of `b` (caller's numbering, `order[i]` the caller's dof at internal position i);
/// returns thread CPU and wall seconds and the last solution.
fn time_one(
    symbolic: &SymbolicCholesky<usize>,
    a: &SparseColMat<usize, f64>,
    b: &[f64],
    order: &[usize],
    ldlt: bool,
    reps: usize,
) -> anyhow::Result<(Vec<f64>, Vec<f64>, Vec<f64>)> {
    let n = b.len();
    let par = Par::Seq;
    let mut l = vec![0.0; symbolic.len_val()];
    let need = if ldlt {
        symbolic.factorize_numeric_ldlt_scratch::<f64>(par, Default::default())
    } else {
        symbolic.factorize_numeric_llt_scratch::<f64>(par, Default::default())
    }
    .or(symbolic.solve_in_place_scratch::<f64>(1, par));
    let mut buf = MemBuffer::new(need);
    let (mut cpu, mut wall) = (Vec::new(), Vec::new());
    let mut y = vec![0.0; n];
    for _ in 0..reps {
        let (c0, t0) = (thread_cpu(), Instant::now());
        for (i, &d) in order.iter().enumerate() {
            y[i] = b[d];
        }
        let rhs = MatMut::from_column_major_slice_mut(&mut y, n, 1);
        if ldlt {
            symbolic
                .factorize_numeric_ldlt(
                    &mut l,
                    a.as_ref(),
                    Side::Lower,
                    Default::default(),
                    par,
                    MemStack::new(&mut buf),
                    Default::default(),
                )
                .map_err(|e| anyhow::anyhow!("LDLᵀ: {e:?}"))?
                .solve_in_place_with_conj(Conj::No, rhs, par, MemStack::new(&mut buf));
        } else {
            symbolic
                .factorize_numeric_llt(
                    &mut l,
                    a.as_ref(),
                    Side::Lower,
                    Default::default(),
                    par,
                    MemStack::new(&mut buf),
                    Default::default(),
                )
                .map_err(|e| anyhow::anyhow!("LLᵀ: {e:?}"))?
                .solve_in_place_with_conj(Conj::No, rhs, par, MemStack::new(&mut buf));
        }
        cpu.push(thread_cpu() - c0);
        wall.push(t0.elapsed().as_secs_f64());
    }
    let mut x = vec![0.0; n];
    for (i, &d) in order.iter().enumerate() {
        x[d] = y[i];
    }
    Ok((cpu, wall, x))
}

/// ‖b − S x‖/‖b‖ by the pattern's product (an independent check of every variant's solve).
fn residual(p: &palpate_motion::sparse::Pattern, s: &[f64], x: &[f64], b: &[f64]) -> f64 {
    let mut sx = vec![0.0; b.len()];
    p.mul_add(s, x, &mut sx);
    let r: f64 = sx.iter().zip(b).map(|(a, c)| (c - a).powi(2)).sum();
    (r / b.iter().map(|c| c * c).sum::<f64>()).sqrt()
}

fn timed_json(t: &Timed) -> serde_json::Value {
    serde_json::json!({
        "variant": t.name,
        "cpu_ms_median": 1e3 * quantile(&t.cpu, 0.5),
        "cpu_ms_p99": 1e3 * quantile(&t.cpu, 0.99),
        "wall_ms_median": 1e3 * quantile(&t.wall, 0.5),
        "factor_values": t.factor_values,
        "relative_residual": t.residual,
    })
}

/// The step solves compared: fresh factorisations, then the kept factor at each tolerance, then
/// at the loosest tolerance with the refresh policy and Newton reusing the solves' factors.
fn step_solves(tolerances: &[f64]) -> Vec<(String, StepSolve)> {
    let mut v = vec![("fresh".to_string(), StepSolve::Fresh)];
    for &t in tolerances {
        v.push((
            format!("kept, tol {t:.0e}"),
            StepSolve::Kept(KeptSolve::with_tolerance(t)),
        ));
    }
    if let Some(&t) = tolerances.last() {
        for k in [1, 2] {
            v.push((
                format!("kept, tol {t:.0e}, refresh above {k}, Newton reuses"),
                StepSolve::Kept(KeptSolve {
                    refresh_above: k,
                    newton_reuses: true,
                    ..KeptSolve::with_tolerance(t)
                }),
            ));
        }
    }
    v
}

/// Largest |a − b| over the largest |b|.
fn rel(a: &[f64], b: &[f64]) -> f64 {
    let scale = b.iter().fold(0.0f64, |s, v| s.max(v.abs()));
    a.iter()
        .zip(b)
        .map(|(p, q)| (p - q).abs() / scale.max(f64::MIN_POSITIVE))
        .fold(0.0, f64::max)
}

/// The gradient evaluations of the dataset under each step solve, alternating `rounds` times.
fn gradient_rows(
    model: &Model,
    mat: &Material,
    params: &[Param],
    obs: &Observations,
    solves: &[(String, StepSolve)],
    rounds: usize,
) -> anyhow::Result<Vec<serde_json::Value>> {
    let mut cpu = vec![Vec::new(); solves.len()];
    let mut last = vec![None; solves.len()];
    for _ in 0..rounds.max(1) {
        for (i, (_, solve)) in solves.iter().enumerate() {
            let c0 = process_cpu();
            let (ev, h) = evaluate_gauss_newton_with(model, mat, params, obs, *solve)?;
            cpu[i].push(process_cpu() - c0);
            last[i] = Some((ev, h));
        }
    }
    let (fresh, h_fresh) = last[0].clone().expect("evaluated");
    let g_fresh = fresh.grad.clone().unwrap_or_default();
    let np = params.len();
    Ok(solves
        .iter()
        .enumerate()
        .map(|(i, (name, _))| {
            let (ev, h) = last[i].as_ref().expect("evaluated");
            let g = ev.grad.clone().unwrap_or_default();
            // ‖J_p‖ = √H_pp: the relative error of each column's norm.
            let col_norm_err = (0..np)
                .map(|p| {
                    let (a, b) = (h[p * np + p].sqrt(), h_fresh[p * np + p].sqrt());
                    (a - b).abs() / b
                })
                .fold(0.0, f64::max);
            serde_json::json!({
                "solve": name,
                "cpu_s_median": quantile(&cpu[i], 0.5),
                "cpu_s_max": quantile(&cpu[i], 1.0),
                "cpu_ratio_vs_fresh": quantile(&cpu[i], 0.5) / quantile(&cpu[0], 0.5),
                "steps": model.steps,
                "newton_iterations": ev.stats.newton_iterations,
                "factorisations": ev.stats.factorisations,
                "cg_iterations": ev.stats.cg_iterations,
                "cg_iterations_per_step": ev.stats.cg_iterations as f64 / model.steps as f64,
                "phi_rel_diff_vs_fresh": (ev.phi - fresh.phi).abs() / fresh.phi,
                "gradient_max_rel_diff_vs_fresh": rel(&g, &g_fresh),
                "gauss_newton_max_rel_diff_vs_fresh": rel(h, &h_fresh),
                "jacobian_column_norm_max_rel_diff_vs_fresh": col_norm_err,
            })
        })
        .collect())
}

/// Whole fits of (μ, viscosity) at ν = 0.49 from the data's own start, one per step solve.
fn fit_rows(
    datasets: &[std::path::PathBuf],
    solves: &[(String, StepSolve)],
) -> anyhow::Result<Vec<serde_json::Value>> {
    use palpate_motion::optimize::FitSettings;
    use palpate_motion::request::{fit, FitRequest, NamedRun};
    let req = FitRequest {
        params: vec![ParamKind::Mu, ParamKind::Nu],
        settings: FitSettings {
            poisson: Some(0.49),
            ..Default::default()
        },
        ..Default::default()
    };
    let mut rows = Vec::new();
    let mut reference: Option<(f64, Vec<f64>)> = None;
    for (name, solve) in solves {
        let mut runs = datasets
            .iter()
            .map(|d| NamedRun::load(d))
            .collect::<Result<Vec<_>, _>>()?;
        set_step_solve(*solve);
        let (c0, t0) = (process_cpu(), Instant::now());
        let outcome = fit(&mut runs, &req, &|_, _| {});
        let (cpu, wall) = (process_cpu() - c0, t0.elapsed().as_secs_f64());
        set_step_solve(StepSolve::None);
        let o = outcome?;
        let q = o.result.q.clone();
        let phi = o.result.phi;
        let sigma = sigma(&runs, &o.fitted, &o.params, phi)?;
        let (phi0, q0) = reference.get_or_insert_with(|| (phi, q.clone())).clone();
        rows.push(serde_json::json!({
            "solve": name,
            "cpu_s": cpu,
            "wall_s": wall,
            "simulations": o.result.evaluations,
            "iterations": o.result.iterations,
            "phi": phi,
            "phi_rel_diff_vs_first": (phi - phi0).abs() / phi0,
            "fitted": q,
            "sigma_1": sigma,
            "shift_in_sigma_vs_first": q.iter().zip(&q0).zip(&sigma)
                .map(|((a, b), s)| (a - b).abs() / s).collect::<Vec<f64>>(),
        }));
    }
    Ok(rows)
}

/// 1σ of the fitted parameters from the Gauss–Newton matrix at the fit, s² H⁻¹ with s² =
/// 2Φ/(m − p) over the m observed marker coordinates (independent residuals).
fn sigma(
    runs: &[palpate_motion::request::NamedRun],
    mat: &Material,
    params: &[Param],
    phi: f64,
) -> anyhow::Result<Vec<f64>> {
    let np = params.len();
    let mut h = vec![0.0; np * np];
    let mut m = 0usize;
    for r in runs {
        let (_, hr) = evaluate_gauss_newton_with(
            &r.dataset.model,
            mat,
            params,
            &r.dataset.obs,
            StepSolve::Fresh,
        )?;
        h.iter_mut().zip(&hr).for_each(|(a, b)| *a += b);
        m += r
            .dataset
            .obs
            .markers
            .iter()
            .skip(r.dataset.model.substeps.max(1) - 1)
            .step_by(r.dataset.model.substeps.max(1))
            .map(|f| 3 * f.iter().filter(|t| t.is_some()).count())
            .sum::<usize>();
    }
    anyhow::ensure!(
        np == 2,
        "the 1σ here is written for two parameters, not {np}"
    );
    let det = h[0] * h[3] - h[1] * h[2];
    let s2 = 2.0 * phi / (m.saturating_sub(np).max(1)) as f64;
    Ok(vec![(s2 * h[3] / det).sqrt(), (s2 * h[0] / det).sqrt()])
}

/// Runs `palpate-lab bench motion-step`; prints JSON.
pub fn run(args: Args) -> anyhow::Result<()> {
    let ds = palpate_motion::dataset::load(&args.dataset)?;
    let fitted: palpate_motion::fitted::FittedModel =
        serde_json::from_str(&std::fs::read_to_string(&args.material)?)?;
    let mat = fitted
        .material()
        .map_err(|e| anyhow::anyhow!("{}: {e}", args.material.display()))?;
    let model = &ds.model;
    anyhow::ensure!(
        mat.values[0].len() == model.tets.len(),
        "{}: {} elements, the dataset's mesh has {}",
        args.material.display(),
        mat.values[0].len(),
        model.tets.len()
    );
    let params: Vec<Param> = fitted
        .fitted
        .iter()
        .filter_map(|k| ParamKind::ALL.into_iter().find(|p| p.name() == k))
        .map(Param::global)
        .collect();
    let load_start = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    let mut factorisation = Vec::new();
    if !args.no_factorisations {
        // The beam's S half-way through its run, and a generated bar of ≈ 1.5k tets (the
        // MyFEM anchor's cross-section, 28 cells long) a few steps into its motion.
        let beam = step_matrix(model, &mat, model.steps / 2)?;
        let size = [0.03, 0.28, 0.03];
        let (_, bar) = palpate_motion::scenario::bar_model(
            size,
            [3, 28, 3],
            1.0 / 180.0,
            20,
            &palpate_motion::scenario::two_sinusoids,
            &palpate_motion::scenario::nine_markers(size),
        )?;
        let bar_mat = Material::uniform(bar.tets.len(), 1.0e4, 2.0e4, 12.0, 1.0, 47.0);
        let bar_s = step_matrix(&bar, &bar_mat, 10)?;
        for (label, m, s) in [("beam", model, beam), ("bar", &bar, bar_s)] {
            let rows = time_variants(&m.pattern, &s, args.factorisations)?;
            factorisation.push(serde_json::json!({
                "matrix": label,
                "tets": m.tets.len(),
                "free_dofs": m.nfree,
                "stored_entries": m.pattern.nnz(),
                "variants": rows.iter().map(timed_json).collect::<Vec<_>>(),
            }));
        }
    }
    let solves = step_solves(&args.tolerances);
    let gradients = gradient_rows(model, &mat, &params, &ds.obs, &solves, args.rounds)?;
    let fits = if args.fit.is_empty() {
        Vec::new()
    } else {
        fit_rows(&args.fit, &solves)?
    };
    let load_end = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    let json = serde_json::json!({
        "bench": "motion-step",
        "dataset": args.dataset.display().to_string(),
        "material": args.material.display().to_string(),
        "parameters": fitted.fitted,
        "tets": model.tets.len(),
        "free_dofs": model.nfree,
        "steps": model.steps,
        "scheme": model.scheme.name(),
        "threads": rayon::current_num_threads(),
        "loadavg_at_start": load_start.trim(),
        "loadavg_at_end": load_end.trim(),
        "factorisation": factorisation,
        "gradient": gradients,
        "fits": fits,
    });
    println!("{}", serde_json::to_string_pretty(&json)?);
    Ok(())
}

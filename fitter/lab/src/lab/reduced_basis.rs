//! `palpate-lab reduced-basis`: how well can a small subspace hold a run's motion? The first gate of
//! a reduced-order motion model (subspace integration, Barbič & James 2005): a reduced simulation
//! can be no closer to the full one than the full trajectory's own projection onto the subspace.
//!
//! The run is simulated in full with a fitted material (`palpate_motion::sim::simulate_solving`);
//! its displacements u(t) = x(t) − x⁰ on the free dofs are projected M-orthogonally onto
//! - the r lowest vibration modes of the tangent at the start (K₀ φ = ω² M φ),
//! - those modes with the static responses to the run's loads added (K₀⁻¹ f for gravity and for the
//!   dead loads, the shapes a sagging or weighted body takes, which modes reach slowly),
//! - the r leading principal components of the trajectory itself (proper orthogonal decomposition,
//!   M-weighted): the best r-dimensional linear subspace for this run, a lower bound for any basis,
//!
//! and the markers placed from x⁰ + P u are compared with those of the full run. Then the run is
//! simulated in the POD subspace itself (Galerkin: BDF2 on x = x⁰ + Φ q with the full element pass
//! projected, ΦᵀMΦ q̈ = Φᵀ(f(x, ẋ) + f_ext), Newton on q with the projected tangent), with the
//! basis of the run's own material and, the basis kept, at a material moved from it (μ × 1.2, the
//! viscosity × 2: what a fit's iterations do to a basis made at their start). The creep branch is
//! left out of both materials (the reduced step has no history variables) and the clamps must hold
//! still. Prints one JSON row per basis and size: the marker error's RMS and maximum over the run
//! (mm), beside the largest marker displacement, and for the Galerkin runs the wall time of the
//! reduced and of the full simulation. Last the element pass itself is reduced (hyper-reduction
//! by energy-conserving sampling and weighting, ECSW, Farhat et al. 2014): a few elements with
//! weights ξ_e ≥ 0 such that Σ ξ_e Φ_eᵀ f_e matches Φᵀ f over snapshots of the full run to a
//! relative `--ecsw-tolerance` (non-negative least squares, Lawson & Hanson 1974), and the run
//! simulated with those elements alone, their tangent kept while Newton contracts; then with the
//! direct sensitivities of q to ln μ and ln ν, checked against central differences and timed
//! against the full run's Gauss–Newton evaluation.

use anyhow::Context as _;
use nalgebra::{DMatrix, DVector, SymmetricEigen};
use palpate_motion::fitted::{set_hanging_inertia, FittedModel};
use palpate_motion::forces::assemble;
use palpate_motion::model::{Material, Model, ParamKind};
use palpate_motion::sim::{simulate_solving, StepSolve};
use serde::Serialize;
use std::path::PathBuf;

/// Arguments of `palpate-lab reduced-basis`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// An imported motion dataset (`palpate import c3d …`).
    pub dataset: PathBuf,
    /// The fitted model whose material is simulated (`fit.json` of a fit or diagnosis).
    #[arg(long)]
    pub model: PathBuf,
    /// Basis sizes r.
    #[arg(long, value_delimiter = ',', default_values_t = [2usize, 5, 10, 20, 40])]
    pub sizes: Vec<usize>,
    /// ECSW's relative tolerance on the sampled reduced forces.
    #[arg(long, default_value_t = 1e-3)]
    pub ecsw_tolerance: f64,
}

/// One basis of one size.
#[derive(Debug, Serialize)]
struct Row {
    basis: String,
    size: usize,
    marker_rms_mm: f64,
    marker_max_mm: f64,
    largest_displacement_mm: f64,
    /// Galerkin rows: the reduced and the full simulation's wall time (s).
    #[serde(skip_serializing_if = "Option::is_none")]
    seconds_reduced_full: Option<(f64, f64)>,
    /// Hyper-reduced rows: the sampled elements, and per step the force passes over them (Newton
    /// iterations) and the tangent passes.
    #[serde(skip_serializing_if = "Option::is_none")]
    passes: Option<(usize, f64, f64)>,
    /// Sensitivity rows: the largest difference of dq/d(ln μ, ln ν) from central differences,
    /// relative to the largest difference quotient.
    #[serde(skip_serializing_if = "Option::is_none")]
    sensitivity_against_differences: Option<f64>,
}

/// Dense symmetric matrix of a free-pattern value array.
fn dense(model: &Model, values: &[f64]) -> DMatrix<f64> {
    let n = model.nfree;
    let mut m = DMatrix::zeros(n, n);
    for ((r, c), v) in model.pattern.entries().zip(values) {
        m[(r, c)] = *v;
        m[(c, r)] = *v;
    }
    m
}

/// Runs the study.
pub fn run(a: Args) -> anyhow::Result<()> {
    let mut ds = palpate_motion::dataset::load(&a.dataset)
        .with_context(|| format!("reading {}", a.dataset.display()))?;
    let text = std::fs::read_to_string(&a.model)
        .with_context(|| format!("reading {}", a.model.display()))?;
    let fit: FittedModel =
        serde_json::from_str(&text).with_context(|| format!("parsing {}", a.model.display()))?;
    if fit.hanging_inertia {
        set_hanging_inertia(&mut ds.model, true);
    }
    let mut mat = fit
        .material()
        .map_err(|e| anyhow::anyhow!("{}: {e}", a.model.display()))?;
    mat.set_uniform(ParamKind::CreepFraction, 0.0);
    if model_moves_clamps(&ds.model) {
        anyhow::bail!(
            "{}: the clamps move; the reduced step here holds them still",
            a.dataset.display()
        );
    }
    let model = &ds.model;
    let n = model.nfree;
    // The full run: x⁰ and the free dofs of every step.
    let (x0, states, full_seconds) = full_states(model, &mat)?;
    let steps: Vec<&Vec<f64>> = states.iter().map(|s| &s.0).collect();
    let free = |x: &[f64]| DVector::from_vec(model.restrict(x));
    let u: Vec<DVector<f64>> = steps.iter().map(|x| free(x) - free(&x0)).collect();
    // K₀ and M at the start; M = L Lᵀ, and the modes from L⁻¹ K₀ L⁻ᵀ.
    let mut f = vec![0.0; 3 * model.nodes.len()];
    let mut kv = vec![0.0; model.pattern.nnz()];
    let zero = vec![0.0; x0.len()];
    assemble(model, &mat, &x0, &zero, &mut f, Some(&mut kv), None)?;
    let k0 = dense(model, &kv);
    let m = dense(model, &model.mass_values(&mat));
    let l = m
        .clone()
        .cholesky()
        .context("the mass matrix is not positive definite")?
        .l();
    let l_inv = l
        .clone()
        .try_inverse()
        .context("the mass factor is singular")?;
    let a_sym = &l_inv * &k0 * l_inv.transpose();
    let eig = SymmetricEigen::new(0.5 * (&a_sym + a_sym.transpose()));
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&i, &j| eig.eigenvalues[i].total_cmp(&eig.eigenvalues[j]));
    let modes: Vec<DVector<f64>> = order
        .iter()
        .map(|&i| l_inv.transpose() * eig.eigenvectors.column(i))
        .collect();
    // Static responses to the run's loads: gravity, and the dead loads at the last step.
    let k0_chol = k0
        .clone()
        .cholesky()
        .context("the start's tangent is not positive definite")?;
    let mut statics = vec![k0_chol.solve(&free(&model.gravity_load(&mat)))];
    let mut dead = vec![0.0; 3 * model.nodes.len()];
    model.add_dead_loads(model.steps, &mut dead);
    if dead.iter().any(|v| *v != 0.0) {
        statics.push(k0_chol.solve(&free(&dead)));
    }
    // Proper orthogonal decomposition: the snapshots' M-weighted principal directions.
    let snaps = DMatrix::from_columns(&u);
    let lt_snaps = l.transpose() * &snaps;
    let svd = lt_snaps.svd(true, false);
    let lu = svd.u.context("no left singular vectors")?;
    let mut sv_order: Vec<usize> = (0..svd.singular_values.len()).collect();
    sv_order.sort_by(|&i, &j| svd.singular_values[j].total_cmp(&svd.singular_values[i]));
    let pod: Vec<DVector<f64>> = sv_order
        .iter()
        .map(|&i| l_inv.transpose() * lu.column(i))
        .collect();
    let markers_of = |x: &[f64]| -> Vec<[f64; 3]> {
        model
            .markers
            .iter()
            .map(|mk| model.marker_position(mk, x))
            .collect()
    };
    let full_markers: Vec<Vec<[f64; 3]>> = steps.iter().map(|x| markers_of(x)).collect();
    let rest_markers = markers_of(&x0);
    let largest = full_markers
        .iter()
        .flat_map(|row| row.iter().zip(&rest_markers))
        .map(|(p, q)| dist(p, q))
        .fold(0.0, f64::max);
    let mut rows = Vec::new();
    for &r in &a.sizes {
        let bases: [(&'static str, Vec<DVector<f64>>); 3] = [
            ("modes", modes.iter().take(r).cloned().collect()),
            (
                "modes + static load shapes",
                modes
                    .iter()
                    .take(r.saturating_sub(statics.len()))
                    .chain(&statics)
                    .cloned()
                    .collect(),
            ),
            (
                "trajectory POD (best possible)",
                pod.iter().take(r).cloned().collect(),
            ),
        ];
        for (name, basis) in bases {
            if basis.is_empty() {
                continue;
            }
            let (rms, max) = projection_error(model, &m, &basis, &u, &x0, &full_markers);
            rows.push(Row {
                basis: name.to_string(),
                size: basis.len(),
                marker_rms_mm: 1e3 * rms,
                marker_max_mm: 1e3 * max,
                largest_displacement_mm: 1e3 * largest,
                seconds_reduced_full: None,
                passes: None,
                sensitivity_against_differences: None,
            });
        }
    }
    // Galerkin runs in the POD subspace: at the basis' own material, then at a moved one.
    let mut moved = mat.clone();
    moved.set_uniform(ParamKind::Mu, 1.2 * mat.get(ParamKind::Mu, 0));
    moved.set_uniform(ParamKind::Lambda, 1.2 * mat.get(ParamKind::Lambda, 0));
    moved.set_uniform(ParamKind::Nu, 2.0 * mat.get(ParamKind::Nu, 0));
    let (_, moved_steps, moved_full_seconds) = full_run(model, &moved)?;
    let moved_markers: Vec<Vec<[f64; 3]>> = moved_steps.iter().map(|x| markers_of(x)).collect();
    let cases = [
        ("", &mat, &full_markers, full_seconds),
        (
            ", μ × 1.2, viscosity × 2",
            &moved,
            &moved_markers,
            moved_full_seconds,
        ),
    ];
    for &r in &a.sizes {
        let basis: Vec<DVector<f64>> = pod.iter().take(r).cloned().collect();
        for (moved_by, material, reference, full_s) in cases {
            let t = std::time::Instant::now();
            let reduced = galerkin_run(model, material, &x0, &basis)?;
            let secs = t.elapsed().as_secs_f64();
            let (rms, max) = marker_error(model, &reduced, reference);
            rows.push(Row {
                basis: format!("Galerkin on the POD{moved_by}"),
                size: basis.len(),
                marker_rms_mm: 1e3 * rms,
                marker_max_mm: 1e3 * max,
                largest_displacement_mm: 1e3 * largest,
                seconds_reduced_full: Some((secs, full_s)),
                passes: None,
                sensitivity_against_differences: None,
            });
        }
    }
    // Hyper-reduction: ECSW elements trained on the full run at the basis' own material.
    for &r in &a.sizes {
        let basis: Vec<DVector<f64>> = pod.iter().take(r).cloned().collect();
        let phi = DMatrix::from_columns(&basis);
        let sample = ecsw(model, &mat, &phi, &states, a.ecsw_tolerance)?;
        for (moved_by, material, reference, full_s) in cases {
            let t = std::time::Instant::now();
            let run = match sampled_run(model, material, &x0, &phi, &sample, None, FORWARD) {
                Ok(run) => run,
                Err(e) => {
                    eprintln!("ECSW{moved_by}, r = {r}, {} elements: {e}", sample.len());
                    continue;
                }
            };
            let secs = t.elapsed().as_secs_f64();
            let reduced: Vec<Vec<f64>> =
                run.qs.iter().map(|q| lifted(model, &phi, &x0, q)).collect();
            let (rms, max) = marker_error(model, &reduced, reference);
            rows.push(Row {
                basis: format!("ECSW on the POD{moved_by}"),
                size: r,
                marker_rms_mm: 1e3 * rms,
                marker_max_mm: 1e3 * max,
                largest_displacement_mm: 1e3 * largest,
                seconds_reduced_full: Some((secs, full_s)),
                passes: Some((sample.len(), run.force_passes, run.tangent_passes)),
                sensitivity_against_differences: None,
            });
        }
    }
    // The sampled run with its sensitivities to ln μ and ln ν, against central differences and
    // against the full run's direct sensitivities (the Gauss–Newton evaluation a fit makes).
    let lambda_per_mu = mat.get(ParamKind::Lambda, 0) / mat.get(ParamKind::Mu, 0);
    let params =
        palpate_motion::model::Param::globals(&[ParamKind::Mu, ParamKind::Lambda, ParamKind::Nu]);
    let t = std::time::Instant::now();
    palpate_motion::gradient::evaluate_gauss_newton(model, &mat, &params, &ds.obs)?;
    let full_with_sensitivities = t.elapsed().as_secs_f64();
    for &r in &a.sizes {
        let phi = DMatrix::from_columns(&pod.iter().take(r).cloned().collect::<Vec<_>>());
        let sample = ecsw(model, &mat, &phi, &states, a.ecsw_tolerance)?;
        let t = std::time::Instant::now();
        let run = sampled_run(model, &mat, &x0, &phi, &sample, Some(lambda_per_mu), TIMED)?;
        let secs = t.elapsed().as_secs_f64();
        let err = sensitivities_against_differences(
            model,
            &mat,
            &x0,
            &phi,
            &sample,
            lambda_per_mu,
            &run.sens,
        )?;
        rows.push(Row {
            basis: "ECSW on the POD, with dq/d(ln μ, ln ν)".into(),
            size: r,
            marker_rms_mm: f64::NAN,
            marker_max_mm: f64::NAN,
            largest_displacement_mm: 1e3 * largest,
            seconds_reduced_full: Some((secs, full_with_sensitivities)),
            passes: Some((sample.len(), run.force_passes, run.tangent_passes)),
            sensitivity_against_differences: Some(err),
        });
    }
    println!("{}", serde_json::to_string_pretty(&rows)?);
    Ok(())
}

/// Newton's stop in the timed sampled runs, (absolute, relative) in |Δq|: forward only, and with
/// sensitivities (whose difference check needs a tighter solve than a marker comparison).
const FORWARD: (f64, f64) = (1e-9, 1e-9);
const TIMED: (f64, f64) = (1e-11, 1e-11);

/// Newton's stop in the runs of a difference quotient: far below the quotient's step, so that the
/// quotient sees the scheme and not the solves' tolerance.
const CHECKED: (f64, f64) = (0.0, 1e-14);

/// The largest difference of `sens` (dq/d(ln μ, ln ν) of every step) from central differences
/// of the sampled run in ln μ (λ following) and ln ν, step 10⁻⁴, relative to the largest
/// difference quotient of each parameter.
fn sensitivities_against_differences(
    model: &Model,
    mat: &Material,
    x0: &[f64],
    phi: &DMatrix<f64>,
    sample: &[(usize, f64, DMatrix<f64>)],
    lambda_per_mu: f64,
    sens: &[DMatrix<f64>],
) -> anyhow::Result<f64> {
    let h = 1e-4;
    let mut worst = 0.0f64;
    for (j, kinds) in [
        (0, &[ParamKind::Mu, ParamKind::Lambda][..]),
        (1, &[ParamKind::Nu][..]),
    ] {
        let run = |sign: f64| -> anyhow::Result<Vec<DVector<f64>>> {
            let mut m = mat.clone();
            for &k in kinds {
                m.set_uniform(k, mat.get(k, 0) * (sign * h).exp());
            }
            Ok(sampled_run(model, &m, x0, phi, sample, Some(lambda_per_mu), CHECKED)?.qs)
        };
        let (up, down) = (run(1.0)?, run(-1.0)?);
        let fd: Vec<DVector<f64>> = up
            .iter()
            .zip(&down)
            .map(|(a, b)| (a - b) / (2.0 * h))
            .collect();
        let scale = fd.iter().map(|d| d.amax()).fold(0.0, f64::max);
        let diff = fd
            .iter()
            .zip(sens)
            .map(|(d, s)| (d - s.column(j)).amax())
            .fold(0.0, f64::max);
        worst = worst.max(diff / scale);
    }
    Ok(worst)
}

/// Whether some clamp's pose changes during the run.
fn model_moves_clamps(model: &Model) -> bool {
    model.clamps.iter().any(|c| {
        let first = c.poses[0].apply(&model.nodes[c.nodes[0]]);
        c.poses.iter().any(|p| {
            let q = p.apply(&model.nodes[c.nodes[0]]);
            dist(&q, &first) > 0.0
        })
    })
}

/// The full simulation of `mat`: x⁰, the positions (full dofs) of every step, its wall time (s).
fn full_run(model: &Model, mat: &Material) -> anyhow::Result<(Vec<f64>, Vec<Vec<f64>>, f64)> {
    let (x0, states, seconds) = full_states(model, mat)?;
    Ok((x0, states.into_iter().map(|s| s.0).collect(), seconds))
}

/// [`full_run`] with each step's velocities.
#[allow(clippy::type_complexity)]
fn full_states(
    model: &Model,
    mat: &Material,
) -> anyhow::Result<(Vec<f64>, Vec<(Vec<f64>, Vec<f64>)>, f64)> {
    let t = std::time::Instant::now();
    let mut x0 = Vec::new();
    let mut steps = Vec::new();
    simulate_solving(
        model,
        mat,
        StepSolve::None,
        |x, _| x0 = x.to_vec(),
        |s| {
            steps.push((s.x.to_vec(), s.v.to_vec()));
            Ok(())
        },
    )?;
    Ok((x0, steps, t.elapsed().as_secs_f64()))
}

/// Φ's rows of element `e`'s 12 dofs (zero rows for clamped dofs): 12 × r.
fn element_rows(model: &Model, phi: &DMatrix<f64>, e: usize) -> DMatrix<f64> {
    let r = phi.ncols();
    let mut out = DMatrix::zeros(12, r);
    for (a, &node) in model.tets[e].iter().enumerate() {
        for k in 0..3 {
            let fr = model.free[3 * node + k];
            if fr != usize::MAX {
                out.set_row(3 * a + k, &phi.row(fr));
            }
        }
    }
    out
}

/// Non-negative least squares min ‖A x − b‖, x ≥ 0, by Lawson and Hanson's active-set method,
/// stopped once ‖A x − b‖ ≤ `tol` ‖b‖: a sparse x, its support chosen greedily by the residual's
/// largest correlation.
fn nnls(a: &DMatrix<f64>, b: &DVector<f64>, tol: f64) -> DVector<f64> {
    let n = a.ncols();
    let mut x = DVector::zeros(n);
    let mut passive: Vec<usize> = Vec::new();
    let target = tol * b.norm();
    for _ in 0..n {
        let res = b - a * &x;
        if res.norm() <= target {
            break;
        }
        let w = a.transpose() * &res;
        let Some(j) = (0..n)
            .filter(|j| !passive.contains(j))
            .max_by(|&i, &k| w[i].total_cmp(&w[k]))
            .filter(|&j| w[j] > 0.0)
        else {
            break;
        };
        passive.push(j);
        loop {
            let ap =
                DMatrix::from_columns(&passive.iter().map(|&i| a.column(i)).collect::<Vec<_>>());
            // Singular values below 10⁻¹⁴ of the largest are dropped (relative: A's scale is the
            // basis', which the caller need not normalise).
            let svd = ap.svd(true, true);
            let eps = 1e-14 * svd.singular_values.max();
            let Ok(z) = svd.solve(b, eps) else {
                return x;
            };
            if z.iter().all(|v| *v > 0.0) {
                x.fill(0.0);
                for (k, &i) in passive.iter().enumerate() {
                    x[i] = z[k];
                }
                break;
            }
            let alpha = passive
                .iter()
                .enumerate()
                .filter(|(k, _)| z[*k] <= 0.0)
                .map(|(k, &i)| x[i] / (x[i] - z[k]))
                .fold(1.0, f64::min);
            for (k, &i) in passive.iter().enumerate() {
                x[i] += alpha * (z[k] - x[i]);
            }
            passive.retain(|&i| x[i] > 1e-15);
            if passive.is_empty() {
                break;
            }
        }
    }
    x
}

/// ECSW's elements and weights for `phi` from the full run's `states` (every `stride`-th).
fn ecsw(
    model: &Model,
    mat: &Material,
    phi: &DMatrix<f64>,
    states: &[(Vec<f64>, Vec<f64>)],
    tol: f64,
) -> anyhow::Result<Vec<(usize, f64, DMatrix<f64>)>> {
    let r = phi.ncols();
    let ne = model.tets.len();
    let stride = (states.len() / 60).max(1);
    let snaps: Vec<&(Vec<f64>, Vec<f64>)> = states.iter().step_by(stride).collect();
    let rows_e: Vec<DMatrix<f64>> = (0..ne).map(|e| element_rows(model, phi, e)).collect();
    let mut g = DMatrix::zeros(r * snaps.len(), ne);
    for (si, (x, v)) in snaps.iter().enumerate() {
        for (e, pe) in rows_e.iter().enumerate() {
            let fe = palpate_motion::forces::element_internal(model, mat, e, x, v)?;
            let c = pe.transpose() * DVector::from_row_slice(&fe);
            g.view_mut((si * r, e), (r, 1)).copy_from(&c);
        }
    }
    let b = g.column_sum();
    let xi = nnls(&g, &b, tol);
    Ok((0..ne)
        .filter(|&e| xi[e] > 0.0)
        .map(|e| (e, xi[e], rows_e[e].clone()))
        .collect())
}

/// Element `e`'s stiffness K_e = −∂f_e/∂x and damping D_e = −∂f_e/∂ẋ (12 × 12) at (x, ẋ).
fn element_tangents(
    model: &Model,
    mat: &Material,
    e: usize,
    x: &[f64],
    v: &[f64],
) -> anyhow::Result<(DMatrix<f64>, Option<DMatrix<f64>>)> {
    use palpate_motion::{elastic::ElasticState, hyperelastic, viscosity};
    let t = &model.rest[e];
    let fgrad = hyperelastic::deformation_gradient(t, &model.gather(e, x));
    let k = ElasticState::new(mat, e, fgrad)?.tangent(t);
    let dense12 = |m: [[f64; 12]; 12]| DMatrix::from_fn(12, 12, |i, j| m[i][j]);
    let nu = mat.get(ParamKind::Nu, e);
    let d = (nu > 0.0)
        .then(|| {
            let l = viscosity::velocity_gradient(t, &model.gather(e, v));
            viscosity::Rate::new(&l, mat.get(ParamKind::PowerH, e))
                .map(|r| dense12(viscosity::element_damping(t, &r, nu)))
        })
        .flatten();
    Ok((dense12(k), d))
}

/// What [`sampled_run`] returns.
struct SampledRun {
    /// q of every step.
    qs: Vec<DVector<f64>>,
    /// dq/d(ln μ, ln ν) of every step (r × 2; empty without sensitivities).
    sens: Vec<DMatrix<f64>>,
    /// Force passes over the sampled elements per step (Newton iterations).
    force_passes: f64,
    /// Tangent passes per step.
    tangent_passes: f64,
}

/// [`galerkin_run`] with the element pass sampled: the reduced forces Σ ξ_e Φ_eᵀ f_e(x, ẋ) and
/// tangent Σ ξ_e Φ_eᵀ (K_e + (3/(2Δt)) D_e) Φ_e of the sampled elements alone, the tangent kept
/// across Newton iterations and steps while the residual contracts 4× an iteration (as the full
/// run keeps its Newton matrix).
///
/// With `sensitivities` = Some(λ/μ), also the direct sensitivities of q to ln μ (λ following at
/// that fixed ratio) and to ln ν (the viscosity): at each converged step the sampled tangent's
/// parts K_r = −∂F/∂q and D_r = −∂F/∂w, and BDF2 differentiated,
/// J sₙ = ∂F/∂p + M_r [(3/(2Δt))(4sₙ₋₁ − sₙ₋₂) + (4ωₙ₋₁ − ωₙ₋₂)]/(2Δt) + D_r (4sₙ₋₁ − sₙ₋₂)/(2Δt)
/// with J = (9/(4Δt²)) M_r + K_r + (3/(2Δt)) D_r and ωₙ = (3sₙ − 4sₙ₋₁ + sₙ₋₂)/(2Δt): r × r
/// solves where the full run factorises its sparse S a step. J at the converged state is also
/// the next step's Newton matrix. Newton stops at |Δq| ≤ `tol`.0 + `tol`.1 |q|.
fn sampled_run(
    model: &Model,
    mat: &Material,
    x0: &[f64],
    phi: &DMatrix<f64>,
    sample: &[(usize, f64, DMatrix<f64>)],
    sensitivities: Option<f64>,
    tol: (f64, f64),
) -> anyhow::Result<SampledRun> {
    let r = phi.ncols();
    let dt = model.dt;
    let nd = x0.len();
    let (c, av) = (9.0 / (4.0 * dt * dt), 3.0 / (2.0 * dt));
    let mr = projected(model, phi, &model.mass_values(mat));
    let fgrav_r = phi.transpose() * DVector::from_vec(model.restrict(&model.gravity_load(mat)));
    let (mut x, mut v) = (x0.to_vec(), vec![0.0; nd]);
    let place = |q: &DVector<f64>, w: &DVector<f64>, x: &mut [f64], v: &mut [f64]| {
        for (e, _, pe) in sample {
            let (u, du) = (pe * q, pe * w);
            for (a, &node) in model.tets[*e].iter().enumerate() {
                for k in 0..3 {
                    x[3 * node + k] = x0[3 * node + k] + u[3 * a + k];
                    v[3 * node + k] = du[3 * a + k];
                }
            }
        }
    };
    // Σ ξ Φ_eᵀ K_e Φ_e and Σ ξ Φ_eᵀ D_e Φ_e at (x, v).
    let tangents = |x: &[f64], v: &[f64]| -> anyhow::Result<(DMatrix<f64>, DMatrix<f64>)> {
        let (mut kr, mut dr) = (DMatrix::zeros(r, r), DMatrix::zeros(r, r));
        for (e, xi, pe) in sample {
            let (k, d) = element_tangents(model, mat, *e, x, v)?;
            kr += *xi * (pe.transpose() * k * pe);
            if let Some(d) = d {
                dr += *xi * (pe.transpose() * d * pe);
            }
        }
        Ok((kr, dr))
    };
    let weight: std::collections::HashMap<usize, (f64, &DMatrix<f64>)> =
        sample.iter().map(|(e, xi, pe)| (*e, (*xi, pe))).collect();
    let mut kinds = vec![false; mat.slots()];
    for k in [ParamKind::Lambda, ParamKind::Mu, ParamKind::Nu] {
        kinds[k as usize] = true;
    }
    let (mut q1, mut q2) = (DVector::zeros(r), DVector::zeros(r));
    let (mut w1, mut w2) = (DVector::<f64>::zeros(r), DVector::<f64>::zeros(r));
    let (mut s1, mut s2) = (DMatrix::<f64>::zeros(r, 2), DMatrix::<f64>::zeros(r, 2));
    let (mut o1, mut o2) = (DMatrix::<f64>::zeros(r, 2), DMatrix::<f64>::zeros(r, 2));
    let mut kept: Option<nalgebra::LU<f64, nalgebra::Dyn, nalgebra::Dyn>> = None;
    let (mut qs, mut ss) = (Vec::with_capacity(model.steps), Vec::new());
    let (mut force_passes, mut tangent_passes) = (0usize, 0usize);
    let (mut fr, mut fe_r) = (DVector::zeros(r), DVector::zeros(r));
    for n in 1..=model.steps {
        let mut dead = vec![0.0; nd];
        model.add_dead_loads(n, &mut dead);
        let fext_r = &fgrav_r + phi.transpose() * DVector::from_vec(model.restrict(&dead));
        let mut q = &q1 + (&q1 - &q2);
        let mut prev = f64::INFINITY;
        for it in 0..50 {
            force_passes += 1;
            let w = (3.0 * &q - 4.0 * &q1 + &q2) / (2.0 * dt);
            let acc = (3.0 * &w - 4.0 * &w1 + &w2) / (2.0 * dt);
            place(&q, &w, &mut x, &mut v);
            fr.fill(0.0);
            for (e, xi, pe) in sample {
                let fe = palpate_motion::forces::element_internal(model, mat, *e, &x, &v)?;
                pe.tr_mul_to(&DVector::from_row_slice(&fe), &mut fe_r);
                fr.axpy(*xi, &fe_r, 1.0);
            }
            let res = &mr * acc - &fr - &fext_r;
            let nrm = res.norm();
            if kept.is_none() || (it > 0 && nrm > 0.25 * prev) {
                tangent_passes += 1;
                let (kr, dr) = tangents(&x, &v)?;
                kept = Some((c * &mr + kr + av * dr).lu());
            }
            let step = kept
                .as_ref()
                .and_then(|lu| lu.solve(&res))
                .context("a singular reduced tangent")?;
            q -= &step;
            prev = nrm;
            if step.norm() <= tol.0 + tol.1 * q.norm() {
                break;
            }
        }
        let w = (3.0 * &q - 4.0 * &q1 + &q2) / (2.0 * dt);
        qs.push(q.clone());
        let Some(lambda_per_mu) = sensitivities else {
            q2 = std::mem::replace(&mut q1, q);
            w2 = std::mem::replace(&mut w1, w);
            continue;
        };
        place(&q, &w, &mut x, &mut v);
        tangent_passes += 1;
        let (kr, dr) = tangents(&x, &v)?;
        let jac = (c * &mr + &kr + av * &dr).lu();
        // ∂F/∂(ln μ) (λ following) and ∂F/∂(ln ν) over the sampled elements.
        let mut dfdp = DMatrix::zeros(r, 2);
        let (mu, nu) = (mat.get(ParamKind::Mu, 0), mat.get(ParamKind::Nu, 0));
        palpate_motion::forces::param_derivatives(
            model,
            mat,
            &kinds,
            &x,
            &v,
            None,
            sample.iter().map(|s| s.0),
            |e, slot, g| {
                let (xi, pe) = weight[&e];
                let col = xi * (pe.transpose() * DVector::from_row_slice(g));
                let (j, scale) = match slot {
                    s if s == ParamKind::Mu as usize => (0, mu),
                    s if s == ParamKind::Lambda as usize => (0, lambda_per_mu * mu),
                    _ => (1, nu),
                };
                let mut target = dfdp.column_mut(j);
                target += scale * col;
            },
        )?;
        let hist_s = (4.0 * &s1 - &s2) / (2.0 * dt);
        let hist_o = (4.0 * &o1 - &o2) / (2.0 * dt);
        let rhs = dfdp + &mr * (av * &hist_s + hist_o) + &dr * hist_s;
        let s = jac.solve(&rhs).context("a singular reduced tangent")?;
        let o = (3.0 * &s - 4.0 * &s1 + &s2) / (2.0 * dt);
        kept = Some(jac);
        ss.push(s.clone());
        q2 = std::mem::replace(&mut q1, q);
        w2 = std::mem::replace(&mut w1, w);
        s2 = std::mem::replace(&mut s1, s);
        o2 = std::mem::replace(&mut o1, o);
    }
    let per_step = |k: usize| k as f64 / model.steps.max(1) as f64;
    Ok(SampledRun {
        qs,
        sens: ss,
        force_passes: per_step(force_passes),
        tangent_passes: per_step(tangent_passes),
    })
}

/// ΦᵀAΦ for the symmetric matrix A with `values` on the free pattern.
fn projected(model: &Model, phi: &DMatrix<f64>, values: &[f64]) -> DMatrix<f64> {
    let mut aphi = DMatrix::zeros(model.nfree, phi.ncols());
    for j in 0..phi.ncols() {
        let col: Vec<f64> = phi.column(j).iter().copied().collect();
        let mut y = vec![0.0; model.nfree];
        model.pattern.mul_add(values, &col, &mut y);
        aphi.set_column(j, &DVector::from_vec(y));
    }
    phi.transpose() * aphi
}

/// x⁰ + Φ q on the free dofs (full dofs; the clamped ones at x⁰).
fn lifted(model: &Model, phi: &DMatrix<f64>, x0: &[f64], q: &DVector<f64>) -> Vec<f64> {
    let u = phi * q;
    let mut x = x0.to_vec();
    for (d, &fr) in model.free.iter().enumerate() {
        if fr != usize::MAX {
            x[d] += u[fr];
        }
    }
    x
}

/// BDF2 in the subspace x = x⁰ + Φ q (free dofs; clamped ones held): at step n the velocity
/// w = (3 qₙ − 4 qₙ₋₁ + qₙ₋₂)/(2Δt) and ΦᵀMΦ (3 wₙ − 4 wₙ₋₁ + wₙ₋₂)/(2Δt) = Φᵀ(f(x, ẋ) + f_ext),
/// started at rest like the full run (qₙ₋₁ = qₙ₋₂ = 0). Newton on qₙ with the projected
/// tangent (9/(4Δt²)) ΦᵀMΦ + ΦᵀKΦ + (3/(2Δt)) ΦᵀDΦ. Returns every step's positions.
fn galerkin_run(
    model: &Model,
    mat: &Material,
    x0: &[f64],
    basis: &[DVector<f64>],
) -> anyhow::Result<Vec<Vec<f64>>> {
    let r = basis.len();
    let dt = model.dt;
    let nd = x0.len();
    let phi = DMatrix::from_columns(basis);
    let mvals = model.mass_values(mat);
    let mr = projected(model, &phi, &mvals);
    let vel_of = |w: &DVector<f64>| -> Vec<f64> {
        let u = &phi * w;
        let mut v = vec![0.0; nd];
        for (d, &fr) in model.free.iter().enumerate() {
            if fr != usize::MAX {
                v[d] = u[fr];
            }
        }
        v
    };
    let fgrav = model.gravity_load(mat);
    let (mut q1, mut q2) = (DVector::zeros(r), DVector::zeros(r));
    let (mut w1, mut w2) = (DVector::<f64>::zeros(r), DVector::<f64>::zeros(r));
    let mut f = vec![0.0; nd];
    let mut kv = vec![0.0; model.pattern.nnz()];
    let mut dv = vec![0.0; model.pattern.nnz()];
    let mut out = Vec::with_capacity(model.steps);
    for n in 1..=model.steps {
        let mut fext = fgrav.clone();
        model.add_dead_loads(n, &mut fext);
        let fext_r = phi.transpose() * DVector::from_vec(model.restrict(&fext));
        // Newton's start: the last step's velocity carried on.
        let mut q = &q1 + (&q1 - &q2);
        for _ in 0..20 {
            let w = (3.0 * &q - 4.0 * &q1 + &q2) / (2.0 * dt);
            let acc = (3.0 * &w - 4.0 * &w1 + &w2) / (2.0 * dt);
            let x = lifted(model, &phi, x0, &q);
            assemble(
                model,
                mat,
                &x,
                &vel_of(&w),
                &mut f,
                Some(&mut kv),
                Some(&mut dv),
            )?;
            let fr = phi.transpose() * DVector::from_vec(model.restrict(&f));
            let res = &mr * acc - fr - &fext_r;
            if res.norm() < model.newton.tol {
                break;
            }
            let jac = 9.0 / (4.0 * dt * dt) * &mr
                + projected(model, &phi, &kv)
                + 3.0 / (2.0 * dt) * projected(model, &phi, &dv);
            let step = jac.lu().solve(&res).context("a singular reduced tangent")?;
            q -= &step;
            // Φ is M-orthonormal: |Δq| is the update's kinetic-energy norm, in m·√kg.
            if step.norm() < 1e-12 * (1.0 + q.norm()) {
                break;
            }
        }
        let w = (3.0 * &q - 4.0 * &q1 + &q2) / (2.0 * dt);
        out.push(lifted(model, &phi, x0, &q));
        q2 = std::mem::replace(&mut q1, q);
        w2 = std::mem::replace(&mut w1, w);
    }
    Ok(out)
}

fn dist(p: &[f64; 3], q: &[f64; 3]) -> f64 {
    (0..3).map(|k| (p[k] - q[k]).powi(2)).sum::<f64>().sqrt()
}

/// The markers' error (RMS, max; m) when every u is replaced by its M-orthogonal projection onto
/// the span of `basis`.
fn projection_error(
    model: &Model,
    m: &DMatrix<f64>,
    basis: &[DVector<f64>],
    u: &[DVector<f64>],
    x0: &[f64],
    full_markers: &[Vec<[f64; 3]>],
) -> (f64, f64) {
    let phi = DMatrix::from_columns(basis);
    let gram = phi.transpose() * m * &phi;
    let Some(gram_chol) = gram.cholesky() else {
        return (f64::NAN, f64::NAN);
    };
    let projected: Vec<Vec<f64>> = u
        .iter()
        .map(|ui| {
            lifted(
                model,
                &phi,
                x0,
                &gram_chol.solve(&(phi.transpose() * (m * ui))),
            )
        })
        .collect();
    marker_error(model, &projected, full_markers)
}

/// The markers' error (RMS, max; m) of the positions `xs` (full dofs, one per step) against the
/// full run's markers `reference`.
fn marker_error(model: &Model, xs: &[Vec<f64>], reference: &[Vec<[f64; 3]>]) -> (f64, f64) {
    let (mut sum, mut count, mut max) = (0.0, 0usize, 0.0f64);
    for (x, row) in xs.iter().zip(reference) {
        for (mk, p) in model.markers.iter().zip(row) {
            let e = dist(&model.marker_position(mk, x), p);
            sum += e * e;
            count += 1;
            max = max.max(e);
        }
    }
    ((sum / count.max(1) as f64).sqrt(), max)
}

#[cfg(test)]
mod tests {
    use super::*;
    use palpate_motion::scenario::{bar_model, example_truth, EXAMPLE_BAR_SIZE, EXAMPLE_DT};

    /// The sampled run's sensitivities are the derivatives of the sampled run: on the example bar
    /// sagging from rest under gravity across it (clamp held, 60 steps, viscosity 300 Pa·s so
    /// that it matters), a basis of four snapshots of its full run (orthonormalised) and ECSW
    /// elements trained on it, dq/d(ln μ) and dq/d(ln ν) of every step agree with central
    /// differences to 10⁻⁵ of each parameter's largest difference quotient (measured: 3·10⁻⁹ and
    /// 4·10⁻⁷).
    #[test]
    fn sampled_sensitivities_match_central_differences() {
        let (_, mut model) = bar_model(
            EXAMPLE_BAR_SIZE,
            [1, 4, 1],
            EXAMPLE_DT,
            60,
            &|_| [0.0; 3],
            &[],
        )
        .unwrap();
        // Across the bar, and damped enough that the viscosity shapes the sag as much as μ does.
        model.gravity = [0.0, 0.0, -9.81];
        let mut mat = example_truth(&model);
        mat.set_uniform(ParamKind::Nu, 300.0);
        let (x0, states, _) = full_states(&model, &mat).unwrap();
        let snapshots: Vec<DVector<f64>> = [14, 29, 44, 59]
            .iter()
            .map(|&n| {
                DVector::from_vec(model.restrict(&states[n].0))
                    - DVector::from_vec(model.restrict(&x0))
            })
            .collect();
        let phi = DMatrix::from_columns(&snapshots).qr().q();
        let sample = ecsw(&model, &mat, &phi, &states, 1e-8).unwrap();
        assert!(!sample.is_empty());
        let ratio = mat.get(ParamKind::Lambda, 0) / mat.get(ParamKind::Mu, 0);
        let run = sampled_run(&model, &mat, &x0, &phi, &sample, Some(ratio), CHECKED).unwrap();
        let err =
            sensitivities_against_differences(&model, &mat, &x0, &phi, &sample, ratio, &run.sens)
                .unwrap();
        assert!(err < 1e-5, "{err:e}");
    }

    /// Lawson–Hanson against the exhaustive answer: every support of a 7 × 5 problem solved by
    /// least squares, the best feasible one kept. b is chosen so that the unconstrained solution
    /// has negative components (the bound is active), and then so that it is an exact
    /// non-negative combination with zeros (recovered exactly).
    #[test]
    fn nnls_matches_the_exhaustive_solution() {
        let a = DMatrix::from_fn(7, 5, |i, j| {
            ((i * 5 + j * 3) % 7) as f64 + 0.3 * (i as f64 - j as f64).abs()
        });
        let b = DVector::from_fn(7, |i, _| ((i * 4) % 5) as f64 - 1.5);
        let mut best = (f64::INFINITY, DVector::zeros(5));
        for mask in 1u32..32 {
            let cols: Vec<usize> = (0..5).filter(|j| mask & (1 << j) != 0).collect();
            let ap = DMatrix::from_columns(&cols.iter().map(|&j| a.column(j)).collect::<Vec<_>>());
            let z = ap.svd(true, true).solve(&b, 1e-14).unwrap();
            if z.iter().any(|v| *v < 0.0) {
                continue;
            }
            let mut x = DVector::zeros(5);
            for (k, &j) in cols.iter().enumerate() {
                x[j] = z[k];
            }
            let r = (&b - &a * &x).norm();
            if r < best.0 {
                best = (r, x);
            }
        }
        let unconstrained = a.clone().svd(true, true).solve(&b, 1e-14).unwrap();
        assert!(unconstrained.iter().any(|v| *v < 0.0), "{unconstrained}");
        let x = nnls(&a, &b, 0.0);
        assert!(x.iter().all(|v| *v >= 0.0));
        assert!(
            (&x - &best.1).norm() < 1e-9 * best.1.norm().max(1.0),
            "{x} against {}",
            best.1
        );
        let truth = DVector::from_vec(vec![0.0, 2.0, 0.0, 0.5, 1.0]);
        let exact = nnls(&a, &(&a * &truth), 1e-12);
        assert!((&exact - &truth).norm() < 1e-9, "{exact}");
    }
}

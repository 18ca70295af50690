//! The motion on quadratic tetrahedra against references it shares no code path with: a
//! nearly incompressible cantilever's first period against the Euler–Bernoulli beam (where
//! linear tetrahedra lock and ring far too fast), a heavily damped run's rest against the
//! quadratic static solver under the same gravity and hanging weight; and the forward-difference
//! fit on both discretisations, against the truth and against the sensitivity-based fitter.

use palpate_fem::mesh::boxmesh::box_mesh;
use palpate_fem::mesh::quadratic::QuadraticMesh;
use palpate_fem::mesh::Mesh;
use palpate_motion::difference_fit::{
    fit_by_differences, DifferenceFit, DifferenceRun, Forward, GlobalParam,
};
use palpate_motion::model::{
    Clamp, DeadLoad, MassKind, Material, Model, Observations, Param, ParamKind, Pose,
};
use palpate_motion::optimize::{fit, FitSettings, Optimizer};
use palpate_motion::quadratic_motion::QuadraticMotion;
use palpate_motion::quadratic_statics::{solve_static_quadratic, solve_static_quadratic_loaded};
use palpate_motion::refine::marker_paths;
use palpate_motion::scenario::{example_bar, observed, record};
use palpate_motion::sim::simulate_states;
use palpate_motion::statics::StaticProblem;
use palpate_motion::timestep::Scheme;
use palpate_motion::viscosity::Form;

const LENGTH: f64 = 0.1;
const SIDE: f64 = 0.01;
const YOUNG: f64 = 15e6;
const POISSON: f64 = 0.49;
const DENSITY: f64 = 1000.0;

fn lame() -> (f64, f64) {
    let mu = YOUNG / (2.0 * (1.0 + POISSON));
    (2.0 * mu * POISSON / (1.0 - 2.0 * POISSON), mu)
}

/// A 100 × 10 × 10 mm beam along x, clamped at x = 0, released from its rest shape under
/// gravity −z; markers at the free end's centre.
fn beam(cells: [usize; 3], dt: f64, steps: usize) -> (Mesh, Model) {
    let mesh = box_mesh([LENGTH, SIDE, SIDE], cells);
    let clamp = Clamp {
        name: "left".into(),
        nodes: mesh.node_groups["left"].clone(),
        poses: vec![Pose::identity(); steps + 1],
    };
    let mut model = Model::new(
        &mesh,
        vec![clamp],
        Vec::new(),
        dt,
        steps,
        [0.0, 0.0, -9.81],
        MassKind::Consistent,
    )
    .unwrap();
    model.static_start = false;
    model.markers = vec![model.marker_at("tip", [LENGTH, 0.5 * SIDE, 0.5 * SIDE])];
    (mesh, model)
}

/// The beam's static problem: clamped at x = 0, under its own weight.
fn clamped_under_gravity(mesh: &Mesh, lambda: f64, mu: f64) -> StaticProblem<'_> {
    crate::support::clamped_under_gravity(mesh, "left", lambda, mu, DENSITY)
}

/// The period of the tip's swing about `centre` (its static sag): twice the time between its
/// first two crossings of it, interpolated linearly between steps.
fn period(zs: &[f64], centre: f64, dt: f64) -> f64 {
    let crossings: Vec<f64> = zs
        .windows(2)
        .enumerate()
        .filter(|(_, w)| (w[0] - centre) * (w[1] - centre) < 0.0)
        .map(|(i, w)| (i as f64 + 1.0 + (centre - w[0]) / (w[1] - w[0])) * dt)
        .collect();
    assert!(
        crossings.len() >= 2,
        "the tip crossed its rest {} times",
        crossings.len()
    );
    2.0 * (crossings[1] - crossings[0])
}

/// At ν = 0.49 the first bending period of a beam with L/h = 10 is within 5 % of
/// Euler–Bernoulli's 2π/(1.8751² √(EI/(ρAL⁴))) on quadratic tetrahedra two cells deep, where
/// linear tetrahedra on the same mesh lock and ring more than twice as fast.
#[test]
fn a_nearly_incompressible_cantilever_rings_at_the_beam_period() {
    let omega =
        1.8751f64.powi(2) * (YOUNG * SIDE * SIDE / (12.0 * DENSITY)).sqrt() / (LENGTH * LENGTH);
    let beam_period = 2.0 * std::f64::consts::PI / omega;
    let dt = beam_period / 60.0;
    let (mesh, model) = beam([20, 2, 2], dt, 90);
    let (lambda, mu) = lame();
    let mat = Material::uniform(model.tets.len(), lambda, mu, 0.0, 1.0, DENSITY);
    let q = QuadraticMotion::new(&model).unwrap();
    let run = q.simulate(&mat).unwrap();
    assert_eq!(
        run.unconverged_steps, 0,
        "largest residual {:.1e} N",
        run.max_residual
    );
    let sag = {
        let mut p = clamped_under_gravity(&mesh, lambda, mu);
        p.tol = 1e-6;
        let s = solve_static_quadratic(&p).unwrap();
        let x: Vec<f64> = s.solution.positions.iter().flatten().copied().collect();
        q.marker_positions(&x)[0][2]
    };
    let zs: Vec<f64> = run.markers.iter().map(|m| m[0][2]).collect();
    let quadratic = period(&zs, sag, dt);
    let rel = quadratic / beam_period - 1.0;
    assert!(
        rel.abs() < 0.05,
        "quadratic period {quadratic:.4} s, beam {beam_period:.4} s ({:+.1} %)",
        100.0 * rel
    );

    let mut linear_z = Vec::new();
    simulate_states(&model, &mat, |s| {
        linear_z.push(model.marker_position(&model.markers[0], s.x)[2]);
        Ok(())
    })
    .unwrap();
    let mean = linear_z.iter().sum::<f64>() / linear_z.len() as f64;
    let linear = period(&linear_z, mean, dt);
    assert!(
        linear < 0.5 * beam_period,
        "linear period {linear:.4} s against the beam's {beam_period:.4} s"
    );
}

/// The beam of [`beam`] ten times stiffer than the ringing one's (a few millimetres of sag)
/// damped to rest under gravity and a 5 g weight hung from the free end's top edge (critically
/// damped in the first mode: ζ = ων/(2μ) ≈ 1), with `creep` (g, τ) on its law: the tip marker
/// at the end of the run, and where the quadratic static solver puts it under the same loads
/// with the law alone (a separate assembly: energy minimisation with its own gravity
/// integration; the weight given as the edge's consistent line load). Stepped by `scheme`.
fn damped_rest(scheme: Scheme, creep: Option<(f64, f64)>) -> ([f64; 3], [f64; 3]) {
    let (mesh, mut model) = beam([10, 1, 1], 0.0025, 200);
    model.scheme = scheme;
    let (lambda, mu) = lame();
    let top_end: Vec<usize> = mesh.node_groups["right"]
        .iter()
        .copied()
        .filter(|n| mesh.node_groups["top"].contains(n))
        .collect();
    let weight = 0.005 * 9.81;
    model.loads.push(DeadLoad {
        name: "5 g".into(),
        nodes: top_end.clone(),
        force: [0.0, 0.0, -weight],
        from_step: 0,
        mass: Some(0.005),
        inertia: true,
        lever: None,
    });
    let mut mat = Material::uniform(model.tets.len(), lambda, mu, 20_000.0, 1.0, DENSITY);
    if let Some((g, tau)) = creep {
        mat.set_uniform(ParamKind::CreepFraction, g);
        mat.set_uniform(ParamKind::CreepTime, tau);
    }
    let q = QuadraticMotion::new(&model).unwrap();
    let run = q.simulate(&mat).unwrap();
    let mut p = clamped_under_gravity(&mesh, lambda, mu);
    p.tol = 1e-5;
    // The weight on the edge's two corners and its midpoint as the consistent line load of a
    // quadratic edge: 1/6, 1/6, 2/3.
    let lifted = QuadraticMesh::from_linear(&mesh);
    assert_eq!(top_end.len(), 2);
    let key = [top_end[0].min(top_end[1]), top_end[0].max(top_end[1])];
    let mid = lifted.vertex_count + lifted.edges.iter().position(|&e| e == key).unwrap();
    let line = [
        (top_end[0], 1.0 / 6.0),
        (top_end[1], 1.0 / 6.0),
        (mid, 2.0 / 3.0),
    ];
    let extra: Vec<(usize, [f64; 3])> = line
        .iter()
        .map(|&(n, w)| (n, [0.0, 0.0, -w * weight]))
        .collect();
    let s = solve_static_quadratic_loaded(&p, &extra).unwrap();
    let x: Vec<f64> = s.solution.positions.iter().flatten().copied().collect();
    (run.markers.last().unwrap()[0], q.marker_positions(&x)[0])
}

/// Damped to rest in 0.5 s, the run comes to the quadratic static equilibrium to 0.1 % of the
/// sag under every scheme; with a creep branch (g = 1, τ = 20 ms: 12 creep times in the run) it
/// comes to the same rest, the law's own: a branch that has relaxed carries no stress.
#[test]
fn a_damped_run_comes_to_rest_at_the_quadratic_equilibrium() {
    let cases = [Scheme::Bdf2, Scheme::Midpoint, Scheme::Alpha]
        .into_iter()
        .flat_map(|s| [(s, None), (s, Some((1.0, 0.02)))]);
    for (scheme, creep) in cases {
        let (got, want) = damped_rest(scheme, creep);
        let sag = want[2] - 0.5 * SIDE;
        let err = (0..3)
            .map(|d| (got[d] - want[d]).powi(2))
            .sum::<f64>()
            .sqrt();
        assert!(sag < -1e-3, "sag {sag}");
        assert!(
            err < 1e-3 * sag.abs(),
            "{}, creep {creep:?}: rest {got:?} against {want:?} ({err:.2e} m of {sag:.2e})",
            scheme.name()
        );
    }
}

/// Every scheme swings the quadratic beam of [`beam`], lightly damped (ζ = ων/(2μ) = 0.02 in the
/// first mode), through the same motion: against BDF2 at 16 times the steps (320 per period), the
/// tip's path over two periods at 20 steps per period errs less under generalised-α than under
/// BDF2, and under the implicit midpoint rule by less than half as much — their period errors
/// are a third of BDF2's and they do not damp (`palpate_motion::timestep`). Measured: 0.18 mm
/// (BDF2), 0.029 mm (midpoint), 0.050 mm (generalised-α) of a 1.7 mm swing; the midpoint
/// rule's end-of-step positions taken as its force state put it 0.71 mm off.
#[test]
fn every_scheme_swings_the_quadratic_beam_to_the_same_motion() {
    let omega =
        1.8751f64.powi(2) * (YOUNG * SIDE * SIDE / (12.0 * DENSITY)).sqrt() / (LENGTH * LENGTH);
    let dt = 2.0 * std::f64::consts::PI / omega / 20.0;
    let steps = 40;
    let (lambda, mu) = lame();
    let viscosity = 2.0 * 0.02 * mu / omega;
    let path = |scheme: Scheme, k: usize| -> Vec<f64> {
        let (_, mut model) = beam([10, 2, 2], dt / k as f64, steps * k);
        model.scheme = scheme;
        let mat = Material::uniform(model.tets.len(), lambda, mu, viscosity, 1.0, DENSITY);
        let run = QuadraticMotion::new(&model)
            .unwrap()
            .simulate(&mat)
            .unwrap();
        assert_eq!(run.unconverged_steps, 0, "{}", scheme.name());
        run.markers
            .iter()
            .skip(k - 1)
            .step_by(k)
            .map(|m| m[0][2])
            .collect()
    };
    let reference = path(Scheme::Bdf2, 16);
    let swing = reference.iter().copied().fold(f64::INFINITY, f64::min) - 0.5 * SIDE;
    let error = |scheme: Scheme| {
        let p = path(scheme, 1);
        assert_eq!(p.len(), reference.len());
        let sq: f64 = p.iter().zip(&reference).map(|(a, b)| (a - b).powi(2)).sum();
        (sq / p.len() as f64).sqrt()
    };
    let (bdf2, midpoint, alpha) = (
        error(Scheme::Bdf2),
        error(Scheme::Midpoint),
        error(Scheme::Alpha),
    );
    assert!(
        midpoint < 0.5 * bdf2 && alpha < bdf2 && midpoint < 0.1 * swing.abs(),
        "tip path RMS against the reference: BDF2 {bdf2:.2e}, midpoint {midpoint:.2e}, \
         generalised-α {alpha:.2e} m; swing {swing:.2e} m"
    );
}

/// The beam of [`beam`] spun about its own axis by its clamp, without gravity: a quarter turn
/// ramped up smoothly over the first fifth of the run, then a steady spin. A rigid rotation
/// strains nothing, so an objective viscosity (the Green–Lagrange strain rate) puts no stress on
/// it and the free end follows the clamp; the rest-gradient reading of ∇v (Ḟ + Ḟᵀ ≠ 0 once the
/// body has turned) puts a stress of about ν ω on every element, a drag along the whole bar
/// that the clamp's end must twist it against (ν ω / μ ≈ 0.3 % times (L/a)² = 400). The lag of a
/// point on the free end's top edge behind the clamp's angle, averaged over the steady last
/// fifth (rad), under `form`; with every step converged.
fn spin_lag(form: Form) -> f64 {
    const VISCOSITY: f64 = 5_000.0;
    let steps = 100;
    let dt = 0.005;
    let (_, mut model) = beam([10, 1, 1], dt, steps);
    model.gravity = [0.0; 3];
    let c = 0.5 * SIDE;
    let ramp = steps / 5;
    let total = 0.5 * std::f64::consts::PI;
    // θ(t): ω ramped linearly to its steady value over the ramp, then steady.
    let omega = total / (dt * (steps as f64 - 0.5 * ramp as f64));
    let theta = |n: usize| {
        let t = n as f64 * dt;
        let tr = ramp as f64 * dt;
        if n <= ramp {
            0.5 * omega * t * t / tr
        } else {
            omega * (t - 0.5 * tr)
        }
    };
    model.clamps[0].poses = (0..=steps)
        .map(|n| {
            let r = nalgebra::Rotation3::from_axis_angle(&nalgebra::Vector3::x_axis(), theta(n));
            let centre = nalgebra::Vector3::new(0.0, c, c);
            Pose {
                r: *r.matrix(),
                t: centre - r * centre,
            }
        })
        .collect();
    model.markers = vec![model.marker_at("edge", [LENGTH, c, SIDE])];
    let (lambda, mu) = lame();
    let mut mat = Material::uniform(model.tets.len(), lambda, mu, VISCOSITY, 1.0, DENSITY);
    mat.viscous_form = form;
    let run = QuadraticMotion::new(&model)
        .unwrap()
        .simulate(&mat)
        .unwrap();
    assert_eq!(
        run.unconverged_steps, 0,
        "{form:?}: largest residual {:.1e} N",
        run.max_residual
    );
    let lags: Vec<f64> = (steps - ramp..=steps)
        .map(|n| {
            let p = run.markers[n - 1][0];
            let angle = (p[2] - c).atan2(p[1] - c) - 0.5 * std::f64::consts::PI;
            theta(n) - angle
        })
        .collect();
    lags.iter().sum::<f64>() / lags.len() as f64
}

/// The objective viscosity on quadratic tetrahedra does not resist a rigid spin: its free end's
/// lag is under 10⁻³ of the rest-gradient reading's, which lags by more than 0.1 rad (measured:
/// 0.79 rad against 1.4·10⁻⁷ rad).
#[test]
fn an_objective_viscosity_lets_a_spinning_beam_follow_its_clamp() {
    let rest = spin_lag(Form::RestGradient);
    let objective = spin_lag(Form::Objective);
    eprintln!("lag: rest-gradient {rest:.3e} rad, objective {objective:.3e} rad");
    assert!(rest > 0.1, "rest-gradient lag {rest:.3e} rad");
    assert!(
        objective.abs() < 1e-3 * rest,
        "objective lag {objective:.3e} rad against {rest:.3e} rad"
    );
}

/// The quadratic static solve converges where strains are tiny: the beam of [`beam`] under a
/// ten-thousandth of gravity (strains of order 10⁻⁸, a weight of 10⁻⁵ N) to 3·10⁻¹⁰ N, where
/// the volumetric energy's round-off (a sum of order (J − 1)² from terms of order J − 1) hides
/// the energy's decrease from the line search and the force residual's decrease is read
/// instead. Measured: reading the energy alone, the search gives up at 7.1·10⁻¹⁰ N; with the
/// residual it comes down to the forces' own round-off, 1.6·10⁻¹⁰ N.
#[test]
fn a_static_solve_at_tiny_strain_converges() {
    let mesh = box_mesh([LENGTH, SIDE, SIDE], [10, 1, 1]);
    let (lambda, mu) = lame();
    let mut p = clamped_under_gravity(&mesh, lambda, mu);
    p.gravity = [0.0, 0.0, -9.81e-4];
    p.tol = 3e-10;
    let s = solve_static_quadratic(&p).unwrap();
    assert!(s.solution.residual < 3e-10, "{}", s.solution.residual);
}

/// A creep branch that never relaxes (τ = 10⁶ s) makes the body (1 + g) times stiffer from a
/// stress-free start (Simo's branch: P = (1 + g) P⁰ while H follows S⁰): the shaken bar with
/// g = 0.5 moves as the bar with λ and μ × 1.5 and no branch, to 10⁻⁶ of its largest motion.
#[test]
fn a_creep_branch_that_never_relaxes_is_a_stiffer_body() {
    let (_, mut model) = example_bar([2, 4, 2], 60).unwrap();
    model.static_start = false;
    let q = QuadraticMotion::new(&model).unwrap();
    let mu = 2.0e4;
    let mut creeping = Material::uniform(model.tets.len(), mu * LAME_RATIO, mu, 12.0, 1.0, 1000.0);
    let mut stiffer = creeping.clone();
    creeping.set_uniform(ParamKind::CreepFraction, 0.5);
    creeping.set_uniform(ParamKind::CreepTime, 1e6);
    stiffer.set_uniform(ParamKind::Mu, 1.5 * mu);
    stiffer.set_uniform(ParamKind::Lambda, 1.5 * mu * LAME_RATIO);
    let (a, b) = (
        q.simulate(&creeping).unwrap(),
        q.simulate(&stiffer).unwrap(),
    );
    let rest = &model.markers;
    let mut largest: f64 = 0.0;
    let mut worst: f64 = 0.0;
    for (ra, rb) in a.markers.iter().zip(&b.markers) {
        for (i, (pa, pb)) in ra.iter().zip(rb).enumerate() {
            let at_rest = model.marker_position(&rest[i], &model.nodes.concat());
            for d in 0..3 {
                largest = largest.max((pb[d] - at_rest[d]).abs());
                worst = worst.max((pa[d] - pb[d]).abs());
            }
        }
    }
    assert!(largest > 1e-4, "the bar moved {largest} m");
    assert!(worst < 1e-6 * largest, "{worst:.2e} m of {largest:.2e} m");
}

/// The example bar shaken at its base, at ν = 0.49, with its truth (μ 20 kPa, viscosity
/// 12 Pa·s) and that truth's noise-free markers simulated on quadratic tetrahedra.
fn shaken_bar() -> (Model, Material, Observations) {
    let (_, mut model) = example_bar([2, 8, 2], 90).unwrap();
    model.static_start = false;
    let mu = 2.0e4;
    let truth = Material::uniform(model.tets.len(), mu * LAME_RATIO, mu, 12.0, 1.0, 1000.0);
    let q = QuadraticMotion::new(&model).unwrap();
    let run = q.simulate(&truth).unwrap();
    let obs = observed(&run.markers);
    (model, truth, obs)
}

/// λ/μ at ν = 0.49.
const LAME_RATIO: f64 = 2.0 * POISSON / (1.0 - 2.0 * POISSON);

const MU_VISCOSITY: [GlobalParam; 2] = [
    GlobalParam {
        kind: ParamKind::Mu,
        log: true,
    },
    GlobalParam {
        kind: ParamKind::Nu,
        log: true,
    },
];

/// μ and the viscosity of `obs` fitted by forward differences of `forward` from 30 % stiff and
/// half the viscosity.
fn fit_bar(obs: &Observations, base: &Material, forward: &Forward<'_>) -> DifferenceFit {
    let run = [DifferenceRun { obs, forward }];
    fit_by_differences(
        &run,
        base,
        &MU_VISCOSITY,
        &[2.6e4, 6.0],
        Some(POISSON),
        20,
        &|_, _| {},
    )
    .unwrap()
}

/// Fitted on quadratic tetrahedra by forward differences from 30 % stiff and half the
/// viscosity, the bar's own quadratic data give back its material; fitted on linear tetrahedra
/// of the same mesh they give a modulus far below it, the locked elements' (the beam's 138
/// against 266 kPa in docs/results/beam/convergence.md).
#[test]
fn a_fit_on_quadratic_elements_recovers_the_material_that_linear_ones_lock_away() {
    let (model, truth, obs) = shaken_bar();
    let base = truth.clone();
    let q = QuadraticMotion::new(&model).unwrap();
    let fit = fit_bar(&obs, &base, &|m: &Material| Ok(q.simulate(m)?.markers));
    let (mu, visc) = (fit.values[0], fit.values[1]);
    assert!((mu / 2.0e4 - 1.0).abs() < 1e-3, "μ {mu}");
    assert!((visc / 12.0 - 1.0).abs() < 1e-2, "viscosity {visc}");
    assert!(fit.rms < 1e-6, "RMS {} m", fit.rms);

    let locked = fit_bar(&obs, &base, &|m: &Material| marker_paths(&model, m));
    assert!(
        locked.values[0] < 0.8 * 2.0e4,
        "linear μ {}",
        locked.values[0]
    );
}

/// On linear tetrahedra the forward-difference fit and the fitter's own Levenberg–Marquardt on
/// direct sensitivities (`optimize::fit`, another code path from the simulation on) reach the
/// same material on the same data.
#[test]
fn the_difference_fit_and_the_sensitivity_fit_agree_on_linear_elements() {
    let (model, mut truth, _) = shaken_bar();
    truth.set_uniform(ParamKind::Mu, 1.5e4);
    truth.set_uniform(ParamKind::Lambda, 1.5e4 * LAME_RATIO);
    let mut obs = record(&model, &truth, 0.0, 1).unwrap();
    obs.forces.clear();
    let by_differences = fit_bar(&obs, &truth, &|m: &Material| marker_paths(&model, m));
    let settings = FitSettings {
        optimizer: Optimizer::LevenbergMarquardt,
        poisson: Some(POISSON),
        ..FitSettings::default()
    };
    let by_sensitivities = fit(
        &model,
        &truth,
        &Param::globals(&[ParamKind::Mu, ParamKind::Nu]),
        &[2.6e4, 6.0],
        &obs,
        &settings,
        &[],
        &|_, _| {},
    )
    .unwrap();
    for k in 0..2 {
        let (a, b) = (by_differences.values[k], by_sensitivities.q[k]);
        assert!((a / b - 1.0).abs() < 1e-3, "parameter {k}: {a} against {b}");
    }
    assert!((by_differences.values[0] / 1.5e4 - 1.0).abs() < 1e-3);
}

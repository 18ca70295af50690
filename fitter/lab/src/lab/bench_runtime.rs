//! `palpate-lab bench runtime`: the haptic tick on a generated block, the scenario of the VegaFEM
//! anchor (ANCHORS.md): 10 × 10 × 5 cm, E = 10 kPa, ν = 0.3, bottom fixed, 0.5 N spread over the
//! surface within 1.5 cm of a contact point that slides across the top face over the run —
//! by default with the consistent contact rule (a sliding probe's loads change continuously);
//! `--rule lumped` spreads it over whole nodes as the anchor did (loads jump at the rim).
//!
//! Measures, in one run: per-tick wall time and thread CPU time (p50/p99/max) of the runtime,
//! its PCG iterations and relative residual, its error against a converged solve of the same
//! tick, and the same tick done with faer's sparse Cholesky refactored per tick (the direct
//! baseline). `--compare` runs several solver settings side by side, tick by tick in the same
//! run (so machine noise hits them alike), including per-tick iteration budgets: a tick that
//! exhausts its budget keeps its iterate and reports its residual, and the bench reports that
//! tick's error against a converged solve and how far the run drifts from the converged run.

use faer::linalg::solvers::SolveCore;
use faer::sparse::{Pair, SparseColMat, SymbolicSparseColMat};
use faer::{Conj, Mat, Side};
use nalgebra::Vector3;
use palpate_fem::block_model::BlockModel;
use palpate_fem::runtime_storage::Storage;
use palpate_runtime::element::{element_stiffness, tet_geometry};
use palpate_runtime::material::LambdaAlpha;
use palpate_runtime::{
    ContactRule, Kernel, Preconditioner, Probe, Runtime, RuntimeConfig, SolveStatus,
    StorageRequirement,
};
use serde_json::json;
use std::time::Instant;

/// Arguments of `palpate-lab bench runtime`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Approximate number of tetrahedra of the generated block.
    #[arg(long, default_value_t = 5000)]
    pub tets: usize,
    /// Ticks of the probe path (1 kHz: 1,000 ticks = 1 s).
    #[arg(long, default_value_t = 1000)]
    pub ticks: usize,
    /// Ticks timed with the direct solver (each refactorises K').
    #[arg(long, default_value_t = 30)]
    pub direct_ticks: usize,
    /// PCG relative tolerance.
    #[arg(long, default_value_t = 1e-4)]
    pub tolerance: f32,
    /// Aggregates of the two-level preconditioner (0: block Jacobi only).
    #[arg(long, default_value_t = RuntimeConfig::default().coarse_aggregates)]
    pub aggregates: u32,
    /// Warm-started rotation-extraction iterations per tick.
    #[arg(long, default_value_t = RuntimeConfig::default().rotation_iterations)]
    pub rotation_iterations: u32,
    /// An element's rotation extraction stops once a step turns it by less than this multiple of
    /// the PCG's tolerance (rad; 0: every iteration; `RuntimeConfig::rotation_tolerance`).
    #[arg(long, default_value_t = RuntimeConfig::default().rotation_tolerance)]
    pub rotation_tolerance: f32,
    /// PCG iterations allowed per tick (the tick's budget). A tick that exhausts it keeps its
    /// iterate, reports its residual, and the next tick continues from there.
    #[arg(long, default_value_t = 100)]
    pub max_iterations: u32,
    /// Rebuild the block-Jacobi preconditioner after this much rotation (rad; 0: every tick).
    #[arg(long, default_value_t = RuntimeConfig::default().precond_refresh_angle)]
    pub precond_refresh_angle: f32,
    /// How the probe force becomes nodal forces (runtime/src/contact_rule.rs): `consistent`
    /// (uniform pressure integrated consistently, continuous in the contact point) or `lumped`
    /// (whole nodes within the radius by lumped area: the VegaFEM anchor scenario, whose loads
    /// jump when a node crosses the rim).
    #[arg(long, value_enum, default_value_t = Rule::Consistent)]
    pub rule: Rule,
    /// How the probe touches the object: `force` (a force spread by `--rule`) or `sphere` (a
    /// rigid sphere pressed 2 mm in, position-driven: the haptic device's case).
    #[arg(long, value_enum, default_value_t = Touch::Force)]
    pub touch: Touch,
    /// Skip the packed-matrix kernel run.
    #[arg(long)]
    pub gradient_only: bool,
    /// Compare solver settings tick by tick in one run: the converged solve, the per-tick
    /// budgets of `--budgets`, no predictor, the preconditioner rebuilt every tick, the coarse
    /// sizes of `--compare-aggregates`, one rotation iteration per tick.
    #[arg(long)]
    pub compare: bool,
    /// Coarse-space sizes compared by `--compare`.
    #[arg(long, value_delimiter = ',', default_values_t = vec![32u32])]
    pub compare_aggregates: Vec<u32>,
    /// Per-tick iteration budgets compared by `--compare`.
    #[arg(long, value_delimiter = ',', default_values_t = vec![6u32, 8, 10])]
    pub budgets: Vec<u32>,
    /// A non-linear (blended) model instead of the linear block: three sets (E = 10, 12, 15 kPa)
    /// with their centres the f64 deformations under 0.25, 0.5 and 1 N at the top face's centre,
    /// blended by the fitter's deformation-space RBF or its strain-space RBF (per-element sets, 8
    /// neighbours). Blended models re-blend every tick; their preconditioner's node blocks are
    /// rebuilt when the parameters and rotations have drifted. The direct baseline is skipped (it
    /// solves the linear block).
    #[arg(long, value_enum, default_value_t = BlendKind::None)]
    pub blend: BlendKind,
    /// Turn the energy line search of the warped solve off (`RuntimeConfig::line_search`).
    #[arg(long)]
    pub no_line_search: bool,
    /// PCG iterations a still tick may spend on the lumped probe's next predicted rim crossing
    /// (`RuntimeConfig::anticipation_iterations`; 0: off). The consistent rule has no crossings.
    #[arg(long, default_value_t = RuntimeConfig::default().anticipation_iterations)]
    pub anticipation: u32,
    /// Write the problem for a peer code into this folder and stop (the block as a VegaFEM
    /// `.veg`, its fixed nodes, the lumped rule's nodal forces of every tick:
    /// `fitter/lab/peers/vegafem/run.sh`).
    #[arg(long)]
    pub export_peer: Option<std::path::PathBuf>,
    /// Write the first variant's ticks to this CSV file (tick, wall and CPU µs, PCG iterations
    /// of its own and spent ahead, whether it started from an anticipated solve, load
    /// increments): which ticks are the slow ones.
    #[arg(long)]
    pub tick_log: Option<std::path::PathBuf>,
}

/// Which model the bench plays.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum BlendKind {
    /// The linear block (one set).
    None,
    /// Three homogeneous sets, deformation-space RBF (eqs. 6.2–6.5).
    Deformation,
    /// Three per-element sets, strain-space RBF (eqs. 6.7–6.11).
    Strain,
}

/// The blended block of `--blend` (see [`Args::blend`]).
fn blended_block(tets: usize, p: LambdaAlpha, kind: BlendKind) -> anyhow::Result<BlockModel> {
    use palpate_fem::export::{ModelBuffers, ProvenanceInfo};
    use palpate_fem::forward::{Load, Material, SolveOptions, StaticProblem};
    use palpate_static_fit::blend::for_fit;
    use palpate_static_fit::Layout;
    let base = BlockModel::block(tets, p)?;
    let (mesh, fixed) = (base.mesh.clone(), base.fixed.clone());
    let problem = StaticProblem::new(&mesh, &fixed, &mesh.boundary_triangles())?;
    let t = mesh.tets.len();
    let layout = match kind {
        BlendKind::Strain => Layout::Inhomogeneous,
        _ => Layout::Homogeneous,
    };
    let mut sets = Vec::new();
    let mut deformed = Vec::new();
    for (force, young) in [(0.25, 10e3), (0.5, 12e3), (1.0, 15e3)] {
        let q = LambdaAlpha::from_young_poisson(young, p.poisson());
        let set = match layout {
            Layout::Homogeneous => Material::homogeneous(q),
            Layout::Inhomogeneous => Material::per_element(&vec![q; t]),
        };
        let f = problem.force_vector(&Load::contact(
            [0.05, 0.05, 0.05],
            [0.0, 0.0, -force],
            RADIUS as f64,
        ))?;
        let x = problem
            .solve_forces(&set, &f, None, &SolveOptions::default())?
            .solution
            .x;
        sets.push(set);
        deformed.push(x);
    }
    let blend = for_fit(&problem, layout, &sets, &deformed)?;
    let prov = ProvenanceInfo {
        tool: "palpate-lab bench runtime".into(),
        source: format!("generated block, {t} tets, {kind:?} blend of 3 sets"),
        notes: String::new(),
    };
    let buffers = ModelBuffers::new(&problem, &mesh.node_tags, &sets, &blend, &prov)?;
    Ok(BlockModel::from_parts(mesh, fixed, buffers))
}

/// Contact rule of the scripted probe.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Rule {
    /// Uniform pressure, consistent nodal forces (continuous in the contact: a sliding probe).
    Consistent,
    /// The anchor's rule: free surface nodes within the radius by lumped area.
    Lumped,
}

impl Rule {
    fn runtime(self) -> ContactRule {
        match self {
            Rule::Consistent => ContactRule::Consistent,
            Rule::Lumped => ContactRule::Lumped,
        }
    }
}

/// Probe force (N) and radius (m) of the scenario.
const FORCE: [f32; 3] = [0.0, 0.0, -0.5];
const RADIUS: f32 = 0.015;

/// How the scripted probe touches the object.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Touch {
    /// Force-driven: 0.5 N spread by the contact rule (`--rule`).
    Force,
    /// Position-driven: a rigid sphere of 1 cm radius pressed 2 mm into the top face (hard
    /// frictionless contact, the runtime returns the reaction force), what a force-feedback
    /// device drives.
    Sphere,
}

/// Sphere probe of the position-driven scenario: radius and indentation (m).
const SPHERE_RADIUS: f32 = 0.01;
const SPHERE_DEPTH: f32 = 0.002;

/// Commands tick `k`'s contact (inside the timed region: it is part of the tick); the force rule is
/// the runtime's configured one.
fn command(rt: &mut Runtime<'_>, k: usize, ticks: usize, touch: Touch) -> anyhow::Result<()> {
    let c = contact_point(k, ticks);
    match touch {
        Touch::Force => {
            rt.set_contact_force(c, FORCE, RADIUS)?;
        }
        Touch::Sphere => rt.set_probe(Probe::Sphere {
            center: [c[0], c[1], c[2] + SPHERE_RADIUS - SPHERE_DEPTH],
            radius: SPHERE_RADIUS,
        })?,
    }
    Ok(())
}

/// Contact point of tick `k` of `ticks`: across the top face along y = 5 cm.
fn contact_point(k: usize, ticks: usize) -> [f32; 3] {
    let s = k as f32 / ticks.max(1) as f32;
    [0.02 + 0.06 * s, 0.05, 0.05]
}

fn percentile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let i = ((sorted.len() as f64 - 1.0) * q).round() as usize;
    sorted[i.min(sorted.len() - 1)]
}

fn sorted(v: &[f64]) -> Vec<f64> {
    let mut t = v.to_vec();
    t.sort_by(|a, b| a.total_cmp(b));
    t
}

/// CPU time of the calling thread (s), nanosecond resolution: unlike wall time it excludes the
/// time the thread waited for a core on a shared machine.
fn thread_cpu() -> f64 {
    let t = rustix::time::clock_gettime(rustix::time::ClockId::ThreadCPUTime);
    t.tv_sec as f64 + t.tv_nsec as f64 * 1e-9
}

fn rel_diff(a: &[f32], b: &[f32]) -> f64 {
    let mut num = 0.0f64;
    let mut den = 0.0f64;
    for (x, y) in a.iter().zip(b) {
        num += ((x - y) as f64).powi(2);
        den += (*y as f64).powi(2);
    }
    (num / den.max(1e-300)).sqrt()
}

/// One solver setting under test.
#[derive(Clone)]
struct Variant {
    name: String,
    cfg: RuntimeConfig,
}

/// What one variant did, tick by tick.
#[derive(Default)]
struct Record {
    wall_us: Vec<f64>,
    cpu_us: Vec<f64>,
    iters: Vec<u32>,
    /// PCG iterations each tick spent ahead, on a lumped probe's planned rim crossings.
    ahead: Vec<u32>,
    /// Whether each tick started from an anticipated solve.
    anticipated_ticks: Vec<bool>,
    /// Load increments of each tick.
    increments: Vec<u32>,
    /// Residual passes over the elements of each tick (0: a quiet tick).
    passes: Vec<u32>,
    capped: Vec<bool>,
    rel_res: Vec<f32>,
    /// ‖u − u_conv‖/‖u_conv‖ against a converged solve (tolerance 1e-9) of the same tick from
    /// the same state: every 50th tick and every tick that exhausted its budget.
    err_checked: Vec<(usize, f64)>,
    /// ‖u − u_A‖/‖u_A‖ against the first variant's state after the same tick (compare mode).
    drift: Vec<f64>,
    bytes: usize,
    /// The lowest z displacement after the last tick (m): what a peer solving the same ticks
    /// (`--export-peer`) must reproduce.
    final_min_uz: f64,
}

fn settle(rt: &mut Runtime<'_>, ticks: usize, touch: Touch) -> anyhow::Result<()> {
    // Settle the initial contact so the run measures steady haptic ticks.
    command(rt, 0, ticks, touch)?;
    for _ in 0..20 {
        rt.tick();
    }
    Ok(())
}

/// Runs the variants over the probe path. Interleaved: tick k of every variant, in rotating
/// order, before tick k + 1 of any. The timed pass touches nothing else.
fn timed_pass(
    model: &BlockModel,
    touch: Touch,
    variants: &[Variant],
    ticks: usize,
    interleave: bool,
) -> anyhow::Result<Vec<Record>> {
    let mut storage: Vec<(Vec<f32>, Vec<u32>)> = variants
        .iter()
        .map(|v| {
            let need = StorageRequirement::for_model(&model.record(), &v.cfg);
            (vec![0f32; need.f32s], vec![0u32; need.u32s])
        })
        .collect();
    let mut rts = Vec::new();
    for ((f, u), v) in storage.iter_mut().zip(variants) {
        rts.push(Runtime::new(model.record(), f, u, v.cfg)?);
    }
    let mut recs: Vec<Record> = rts
        .iter()
        .map(|rt| Record {
            bytes: rt.footprint_bytes(),
            ..Default::default()
        })
        .collect();
    let one_tick = |rt: &mut Runtime<'_>, rec: &mut Record, k: usize| -> anyhow::Result<()> {
        let c0 = thread_cpu();
        let t0 = Instant::now();
        command(rt, k, ticks, touch)?;

        let rep = rt.tick();
        let wall = t0.elapsed().as_secs_f64() * 1e6;
        rec.cpu_us.push((thread_cpu() - c0) * 1e6);
        rec.wall_us.push(wall);
        rec.iters.push(rep.iterations);
        rec.ahead.push(rep.iterations_ahead);
        rec.anticipated_ticks.push(rep.anticipated);
        rec.increments.push(rep.increments);
        rec.passes.push(rep.passes);
        rec.capped.push(rep.status == SolveStatus::BudgetExhausted);
        rec.rel_res.push(rep.rel_residual);
        Ok(())
    };
    if interleave {
        for rt in rts.iter_mut() {
            settle(rt, ticks, touch)?;
        }
        let m = rts.len();
        for k in 0..ticks {
            for j in 0..m {
                let v = (j + k) % m;
                one_tick(&mut rts[v], &mut recs[v], k)?;
            }
            for v in 0..m {
                let d = rel_diff(rts[v].displacements(), rts[0].displacements());
                recs[v].drift.push(d);
            }
        }
    } else {
        for (rt, rec) in rts.iter_mut().zip(recs.iter_mut()) {
            settle(rt, ticks, touch)?;
            for k in 0..ticks {
                one_tick(rt, rec, k)?;
            }
        }
    }
    Ok(recs)
}

/// Untimed replay of one variant (the runtime is deterministic, so it retraces the timed pass;
/// checked by the iteration counts): error against a converged solve of the same tick from the
/// same state, every 50th tick and at every tick that exhausted its budget.
fn accuracy_pass(
    model: &BlockModel,
    touch: Touch,
    variant: &Variant,
    ticks: usize,
    rec: &mut Record,
) -> anyhow::Result<()> {
    let need = StorageRequirement::for_model(&model.record(), &variant.cfg);
    let (mut f, mut u) = (vec![0f32; need.f32s], vec![0u32; need.u32s]);
    let mut rt = Runtime::new(model.record(), &mut f, &mut u, variant.cfg)?;
    let ref_cfg = RuntimeConfig {
        tolerance: 1e-9,
        max_iterations: 5000,
        ..variant.cfg
    };
    let (mut f2, mut u2) = (vec![0f32; need.f32s], vec![0u32; need.u32s]);
    let mut reference = Runtime::new(model.record(), &mut f2, &mut u2, ref_cfg)?;
    settle(&mut rt, ticks, touch)?;
    for k in 0..ticks {
        let check = k % 50 == 25 || rec.capped[k];
        if check {
            reference.copy_state_from(&rt)?;
        }
        command(&mut rt, k, ticks, touch)?;
        let rep = rt.tick();
        anyhow::ensure!(
            rep.iterations == rec.iters[k],
            "{}: replay of tick {k} took {} PCG iterations, the timed pass {} (not deterministic)",
            variant.name,
            rep.iterations,
            rec.iters[k]
        );
        if check {
            command(&mut reference, k, ticks, touch)?;
            reference.tick();
            rec.err_checked
                .push((k, rel_diff(rt.displacements(), reference.displacements())));
        }
    }
    rec.final_min_uz = rt
        .displacements()
        .iter()
        .skip(2)
        .step_by(3)
        .fold(0.0f64, |m, &u| m.min(u as f64));
    Ok(())
}

/// Summary figures of one variant.
struct Summary {
    wall: [f64; 3],
    cpu: [f64; 3],
    cpu_mean: f64,
    iters_mean: f64,
    iters: [u32; 3],
    capped: usize,
    max_res_converged: f32,
    max_res_capped: f32,
    err_converged: f64,
    err_capped: f64,
    drift_max: f64,
    drift_p99: f64,
    /// Tick CPU time against PCG iterations (the tick's own and those it spent ahead), least
    /// squares over the ticks: (µs per iteration, µs at zero iterations — the residual pass,
    /// rotations, predictor —, R²).
    per_iteration: (f64, f64, f64),
    /// Mean PCG iterations a tick spent ahead, on a lumped probe's planned rim crossings.
    ahead_mean: f64,
    /// Ticks that started from anticipated solves.
    anticipated: usize,
    /// Quiet ticks: no residual pass over the elements (`palpate_runtime::TickReport::passes`).
    quiet: usize,
}

/// Least-squares line y = a + b x: (b, a, R²).
fn line_fit(x: &[f64], y: &[f64]) -> (f64, f64, f64) {
    let n = x.len().min(y.len()) as f64;
    let (mx, my) = (x.iter().sum::<f64>() / n, y.iter().sum::<f64>() / n);
    let (mut sxy, mut sxx, mut syy) = (0.0, 0.0, 0.0);
    for (a, b) in x.iter().zip(y) {
        sxy += (a - mx) * (b - my);
        sxx += (a - mx) * (a - mx);
        syy += (b - my) * (b - my);
    }
    let slope = sxy / sxx;
    (slope, my - slope * mx, sxy * sxy / (sxx * syy))
}

fn summarise(r: &Record) -> Summary {
    let (w, c) = (sorted(&r.wall_us), sorted(&r.cpu_us));
    let mut it = r.iters.clone();
    it.sort_unstable();
    let pick = |q: f64| it[((it.len() as f64 - 1.0) * q).round() as usize];
    let fold32 = |f: &dyn Fn(usize) -> bool| {
        (0..r.rel_res.len())
            .filter(|&k| f(k))
            .fold(0.0f32, |a, k| a.max(r.rel_res[k]))
    };
    let errs = |capped: bool| {
        r.err_checked
            .iter()
            .filter(|(k, _)| r.capped[*k] == capped)
            .fold(0.0f64, |a, (_, e)| a.max(*e))
    };
    let d = sorted(&r.drift);
    Summary {
        wall: [
            percentile(&w, 0.5),
            percentile(&w, 0.99),
            *w.last().unwrap_or(&f64::NAN),
        ],
        cpu: [
            percentile(&c, 0.5),
            percentile(&c, 0.99),
            *c.last().unwrap_or(&f64::NAN),
        ],
        cpu_mean: r.cpu_us.iter().sum::<f64>() / r.cpu_us.len().max(1) as f64,
        iters_mean: r.iters.iter().map(|v| *v as f64).sum::<f64>() / r.iters.len().max(1) as f64,
        iters: [pick(0.5), pick(0.99), pick(1.0)],
        capped: r.capped.iter().filter(|c| **c).count(),
        max_res_converged: fold32(&|k| !r.capped[k]),
        max_res_capped: fold32(&|k| r.capped[k]),
        err_converged: errs(false),
        err_capped: errs(true),
        drift_max: *d.last().unwrap_or(&f64::NAN),
        drift_p99: percentile(&d, 0.99),
        per_iteration: line_fit(
            &r.iters
                .iter()
                .zip(&r.ahead)
                .map(|(&v, &a)| (v + a) as f64)
                .collect::<Vec<_>>(),
            &r.cpu_us,
        ),
        ahead_mean: r.ahead.iter().map(|v| *v as f64).sum::<f64>() / r.ahead.len().max(1) as f64,
        anticipated: r.anticipated_ticks.iter().filter(|&&a| a).count(),
        quiet: r.passes.iter().filter(|&&p| p == 0).count(),
    }
}

/// The same tick with a sparse direct solver: rotations from the runtime's state, f64 assembly of
/// K' and of the warped right-hand side, faer Cholesky refactored every tick (symbolic analysis
/// once, as a direct haptic loop would).
fn run_direct(model: &BlockModel, args: &Args, p: LambdaAlpha) -> anyhow::Result<Vec<f64>> {
    let cfg = RuntimeConfig {
        tolerance: args.tolerance,
        contact_rule: args.rule.runtime(),
        ..Default::default()
    };
    let rec = model.record();
    let mut storage = Storage::for_model(&rec, &cfg);
    let mut rt = storage.runtime(rec, cfg)?;
    let mesh = &model.mesh;
    let n = mesh.nodes.len();
    let mut dof = vec![usize::MAX; 3 * n];
    let mut nfree = 0;
    for i in 0..n {
        if !model.fixed.contains(&i) {
            for k in 0..3 {
                dof[3 * i + k] = nfree;
                nfree += 1;
            }
        }
    }
    let geo: Vec<_> = mesh
        .tets
        .iter()
        .map(|t| tet_geometry(&t.map(|i| Vector3::from(mesh.nodes[i]))).unwrap())
        .collect();
    let ke: Vec<_> = geo
        .iter()
        .map(|g| element_stiffness(g, p.lambda, p.alpha))
        .collect();
    // Pattern (lower triangle) once.
    let mut pairs = Vec::new();
    for t in &mesh.tets {
        for a in 0..12 {
            for b in 0..12 {
                let (r, c) = (dof[3 * t[a / 3] + a % 3], dof[3 * t[b / 3] + b % 3]);
                if r != usize::MAX && c != usize::MAX && r >= c {
                    pairs.push(Pair { row: r, col: c });
                }
            }
        }
    }
    let (symbolic, argsort) =
        SymbolicSparseColMat::<usize>::try_new_from_indices(nfree, nfree, &pairs)?;
    let llt_symbolic =
        faer::sparse::linalg::solvers::SymbolicLlt::try_new(symbolic.as_ref(), Side::Lower)?;
    let mut times = Vec::new();
    command(&mut rt, 0, args.ticks, Touch::Force)?;
    for _ in 0..20 {
        rt.tick();
    }
    let mut vals = vec![0.0f64; pairs.len()];
    let stride = (args.ticks / args.direct_ticks.max(1)).max(1);
    for k in (0..args.ticks).step_by(stride).take(args.direct_ticks) {
        let t0 = Instant::now();
        command(&mut rt, k, args.ticks, Touch::Force)?;
        // Rotations as the runtime computed them for its current state.
        let rots: Vec<[f32; 9]> = (0..mesh.tets.len())
            .map(|e| rt.element_rotation(e).unwrap_or([0.0; 9]))
            .collect();
        let mut rhs = Mat::<f64>::zeros(nfree, 1);
        let mut v = 0;
        let mut contact = vec![0.0f64; 3 * n];
        // The nodal forces the runtime was commanded (its rule), in f64.
        for (i, c) in contact.iter_mut().enumerate() {
            *c = rt.commanded_force(i / 3).map_or(0.0, |f| f[i % 3] as f64);
        }
        for (i, c) in contact.iter().enumerate() {
            if dof[i] != usize::MAX {
                rhs[(dof[i], 0)] += c;
            }
        }
        for (e, t) in mesh.tets.iter().enumerate() {
            let r = nalgebra::Matrix3::from_row_slice(&rots[e].map(|x| x as f64));
            let mut big = nalgebra::SMatrix::<f64, 12, 12>::zeros();
            for a in 0..4 {
                big.fixed_view_mut::<3, 3>(3 * a, 3 * a).copy_from(&r);
            }
            let rk = big * ke[e];
            let k_rot = rk * big.transpose();
            // K'' x₀ − K' x₀ term of the displacement form.
            let mut x0 = nalgebra::SVector::<f64, 12>::zeros();
            for (a, &node) in t.iter().enumerate() {
                x0.fixed_rows_mut::<3>(3 * a)
                    .copy_from(&Vector3::from(mesh.nodes[node]));
            }
            let corr = rk * x0 - k_rot * x0;
            for a in 0..12 {
                let ra = dof[3 * t[a / 3] + a % 3];
                if ra != usize::MAX {
                    rhs[(ra, 0)] += corr[a];
                }
                for b in 0..12 {
                    let cb = dof[3 * t[b / 3] + b % 3];
                    if ra != usize::MAX && cb != usize::MAX && ra >= cb {
                        vals[v] = k_rot[(a, b)];
                        v += 1;
                    }
                }
            }
        }
        let mat = SparseColMat::<usize, f64>::new_from_argsort(symbolic.clone(), &argsort, &vals)?;
        let llt = faer::sparse::linalg::solvers::Llt::try_new_with_symbolic(
            llt_symbolic.clone(),
            mat.as_ref(),
            Side::Lower,
        )
        .map_err(|e| anyhow::anyhow!("Cholesky failed: {e:?}"))?;
        llt.solve_in_place_with_conj(Conj::No, rhs.as_mut());
        times.push(t0.elapsed().as_secs_f64() * 1e6);
        std::hint::black_box(&rhs);
        rt.tick();
    }
    Ok(times)
}

/// The ticks of one record as CSV (`--tick-log`).
fn write_tick_log(path: &std::path::Path, r: &Record) -> anyhow::Result<()> {
    use std::fmt::Write as _;
    let mut out = String::from(
        "tick,wall_us,cpu_us,iterations,iterations_ahead,anticipated,increments,passes\n",
    );
    for k in 0..r.wall_us.len() {
        writeln!(
            out,
            "{k},{:.1},{:.1},{},{},{},{},{}",
            r.wall_us[k],
            r.cpu_us[k],
            r.iters[k],
            r.ahead[k],
            r.anticipated_ticks[k] as u8,
            r.increments[k],
            r.passes[k]
        )?;
    }
    std::fs::write(path, out).map_err(|e| anyhow::anyhow!("writing {}: {e}", path.display()))
}

/// Runs the benchmark.
pub fn run(args: Args) -> anyhow::Result<()> {
    let p = LambdaAlpha::from_young_poisson(10_000.0, 0.3);
    let model = match args.blend {
        BlendKind::None => BlockModel::block(args.tets, p)?,
        kind => blended_block(args.tets, p, kind)?,
    };
    let tets = model.mesh.tets.len();
    if let Some(dir) = &args.export_peer {
        anyhow::ensure!(
            args.touch == Touch::Force && args.blend == BlendKind::None,
            "--export-peer writes the force-driven linear block (no --touch sphere, no --blend)"
        );
        super::peer_export::export(
            &model,
            (10_000.0, 0.3),
            args.rule.runtime(),
            args.ticks,
            |k| contact_point(k, args.ticks),
            FORCE,
            RADIUS,
            dir,
        )?;
        println!(
            "wrote {tets} tets, {} fixed nodes and {} ticks of {:?}-rule loads into {}",
            model.fixed.len(),
            args.ticks,
            args.rule,
            dir.display()
        );
        return Ok(());
    }
    let dofs = 3 * (model.mesh.nodes.len() - model.fixed.len());
    println!(
        "palpate-lab bench runtime: {tets} tets, {dofs} free dofs, {} ticks, tolerance {:e}, {:?} contact rule, {:?} blend",
        args.ticks, args.tolerance, args.rule, args.blend
    );
    let base = RuntimeConfig {
        tolerance: args.tolerance,
        max_iterations: args.max_iterations,
        kernel: Kernel::Gradient,
        preconditioner: Preconditioner::BlockJacobi,
        coarse_aggregates: args.aggregates,
        rotation_iterations: args.rotation_iterations,
        rotation_tolerance: args.rotation_tolerance,
        precond_refresh_angle: args.precond_refresh_angle,
        contact_rule: args.rule.runtime(),
        line_search: !args.no_line_search,
        anticipation_iterations: args.anticipation,
        ..Default::default()
    };
    let mut variants = vec![Variant {
        name: if args.compare {
            "converged".into()
        } else {
            "gradient".into()
        },
        cfg: base,
    }];
    // Every other variant is the base with one setting changed.
    let mut vary = |name: String, change: &dyn Fn(&mut RuntimeConfig)| {
        let mut cfg = base;
        change(&mut cfg);
        variants.push(Variant { name, cfg });
    };
    if args.compare {
        for &b in &args.budgets {
            vary(format!("budget {b}"), &|c| c.max_iterations = b);
        }
        vary("no predictor".into(), &|c| c.predictor = false);
        vary("precond every tick".into(), &|c| {
            c.precond_refresh_angle = 0.0
        });
        for &m in &args.compare_aggregates {
            vary(format!("{m} aggregates"), &|c| c.coarse_aggregates = m);
        }
        vary("1 rotation iteration".into(), &|c| {
            c.rotation_iterations = 1
        });
        if args.rule == Rule::Lumped && args.anticipation > 0 {
            vary("no anticipation".into(), &|c| c.anticipation_iterations = 0);
        }
    } else if !args.gradient_only {
        vary("packed".into(), &|c| c.kernel = Kernel::Packed);
    }
    let mut recs = timed_pass(&model, args.touch, &variants, args.ticks, args.compare)?;
    if let Some(path) = &args.tick_log {
        write_tick_log(path, &recs[0])?;
    }
    for (v, r) in variants.iter().zip(recs.iter_mut()) {
        accuracy_pass(&model, args.touch, v, args.ticks, r)?;
    }
    // The direct baseline solves the force-driven tick (the sphere's contact constraints are not
    // in it): skipped for the sphere.
    let mut direct = if args.touch == Touch::Force && args.blend == BlendKind::None {
        run_direct(&model, &args, p)?
    } else {
        Vec::new()
    };
    direct.sort_by(|a, b| a.total_cmp(b));
    let sums: Vec<Summary> = recs.iter().map(summarise).collect();
    if args.compare {
        println!("tick by tick in one run, rotating order; drift = ‖u − u_converged‖/‖u_converged‖ after the same tick");
    }
    println!(
        "{:<20} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8} {:>6} {:>11} {:>6} {:>10} {:>10} {:>10} {:>10} {:>10}",
        "variant", "p50_us", "p99_us", "max_us", "cpu_p50", "cpu_p99", "cpu_max", "iters", "p50/p99/max",
        "capped", "res_conv", "err_conv", "res_capped", "err_capped", "drift_max"
    );
    for (v, s) in variants.iter().zip(&sums) {
        println!(
            "{:<20} {:>8.1} {:>8.1} {:>8.1} {:>8.1} {:>8.1} {:>8.1} {:>6.2} {:>11} {:>6} {:>10.2e} {:>10.2e} {:>10.2e} {:>10.2e} {:>10.2e}",
            v.name,
            s.wall[0],
            s.wall[1],
            s.wall[2],
            s.cpu[0],
            s.cpu[1],
            s.cpu[2],
            s.iters_mean,
            format!("{}/{}/{}", s.iters[0], s.iters[1], s.iters[2]),
            s.capped,
            s.max_res_converged,
            s.err_converged,
            s.max_res_capped,
            s.err_capped,
            s.drift_max,
        );
    }
    let g = &sums[0];
    for (v, s) in variants.iter().zip(&sums).skip(1) {
        println!(
            "ratio {} / {}: wall p50 {:.2} p99 {:.2}; CPU p50 {:.2} p99 {:.2} mean {:.2}",
            v.name,
            variants[0].name,
            s.wall[0] / g.wall[0],
            s.wall[1] / g.wall[1],
            s.cpu[0] / g.cpu[0],
            s.cpu[1] / g.cpu[1],
            s.cpu_mean / g.cpu_mean,
        );
    }
    for (v, r) in variants.iter().zip(&recs) {
        let slow: Vec<u32> = (0..r.iters.len())
            .filter(|&k| r.iters[k] >= 5)
            .map(|k| r.iters[k])
            .collect();
        println!(
            "{}: {} ticks with ≥ 5 PCG iterations ({:?}…); {} B runtime state ({:.0} B/element)",
            v.name,
            slow.len(),
            &slow[..slow.len().min(12)],
            r.bytes,
            r.bytes as f64 / tets as f64
        );
    }
    println!(
        "{:<20} {:>8.1} {:>8.1} {:>8.1}   (faer sparse Cholesky, refactored per tick, {} ticks); direct/{} p50 = {:.1}",
        "direct",
        percentile(&direct, 0.5),
        percentile(&direct, 0.99),
        direct.last().copied().unwrap_or(f64::NAN),
        direct.len(),
        variants[0].name,
        percentile(&direct, 0.5) / g.wall[0]
    );
    let variant_json: Vec<_> = variants
        .iter()
        .zip(&sums)
        .map(|(v, s)| {
            json!({
                "name": v.name,
                "max_iterations": v.cfg.max_iterations,
                "aggregates": v.cfg.coarse_aggregates,
                "precond_refresh_angle": v.cfg.precond_refresh_angle,
                "anticipation_iterations": v.cfg.anticipation_iterations,
                "p50_us": s.wall[0], "p99_us": s.wall[1], "max_us": s.wall[2],
                "cpu_p50_us": s.cpu[0], "cpu_p99_us": s.cpu[1], "cpu_max_us": s.cpu[2],
                "mean_pcg_iters": s.iters_mean, "p99_pcg_iters": s.iters[1], "max_pcg_iters": s.iters[2],
                "mean_pcg_iters_ahead": s.ahead_mean, "anticipated_ticks": s.anticipated,
                "quiet_ticks": s.quiet,
                "capped_ticks": s.capped,
                "rel_residual": s.max_res_converged,
                "max_rel_error_vs_converged": s.err_converged,
                "capped_max_rel_residual": s.max_res_capped,
                "capped_max_rel_error_vs_converged": s.err_capped,
                "drift_max": s.drift_max, "drift_p99": s.drift_p99,
            })
        })
        .collect();
    println!(
        "{}",
        json!({
            "schema_version": 1,
            "bench": "runtime",
            "blend": format!("{:?}", args.blend).to_lowercase(),
            "rule": format!("{:?}", args.rule).to_lowercase(),
            "touch": format!("{:?}", args.touch).to_lowercase(),
            "tets": tets,
            "dofs": dofs,
            "ticks": args.ticks,
            "kernel": "gradient",
            "p50_us": g.wall[0],
            "p99_us": g.wall[1],
            "max_us": g.wall[2],
            "cpu_p50_us": g.cpu[0],
            "cpu_p99_us": g.cpu[1],
            "cpu_mean_us": g.cpu_mean,
            "mean_pcg_iters": g.iters_mean,
            "max_pcg_iters": g.iters[2],
            "mean_pcg_iters_ahead": g.ahead_mean,
            "anticipated_ticks": g.anticipated,
            "quiet_ticks": g.quiet,
            "cpu_us_per_pcg_iteration": g.per_iteration.0,
            "cpu_us_outside_pcg": g.per_iteration.1,
            "per_iteration_fit_r2": g.per_iteration.2,
            "rel_residual": g.max_res_converged,
            "max_rel_error_vs_converged": g.err_converged,
            "capped_ticks": g.capped,
            "bytes": recs[0].bytes,
            "bytes_per_element": recs[0].bytes as f64 / tets as f64,
            "final_min_uz_m": recs[0].final_min_uz,
            "aggregates": args.aggregates,
            "max_iterations": args.max_iterations,
            "direct_p50_us": percentile(&direct, 0.5),
            "direct_p99_us": percentile(&direct, 0.99),
            "variants": variant_json,
        })
    );
    Ok(())
}

//! `palpate bench runtime`: the haptic tick on a generated block, the scenario of the VegaFEM
//! anchor (ANCHORS.md): 10 × 10 × 5 cm, E = 10 kPa, ν = 0.3, bottom fixed, 0.5 N spread over the
//! surface nodes within 1.5 cm of a contact point that moves across the top face over the run.
//!
//! Measures, in one run: per-tick wall time (p50/p99/max) of the runtime for each kernel, its PCG
//! iterations and relative residual, its error against a converged solve of the same tick, and
//! the same tick done with faer's sparse Cholesky refactored per tick (the direct baseline).

use crate::mesh::boxmesh::{box_mesh, cells_for_target};
use crate::mesh::Mesh;
use faer::linalg::solvers::SolveCore;
use faer::sparse::{Pair, SparseColMat, SymbolicSparseColMat};
use faer::{Conj, Mat, Side};
use nalgebra::Vector3;
use palpate_protocol::model::{
    Blend, F32s, ModelRecord, ParameterLayout, ParameterSets, Provenance, U32s, Units,
};
use palpate_runtime::element::{
    element_cd, element_stiffness, pack_symmetric, tet_geometry, PACKED_LEN,
};
use palpate_runtime::material::LambdaAlpha;
use palpate_runtime::{Kernel, Preconditioner, Runtime, RuntimeConfig, StorageRequirement};
use serde_json::json;
use std::time::Instant;

/// Arguments of `palpate bench runtime`.
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
    /// Skip the packed-matrix kernel run.
    #[arg(long)]
    pub gradient_only: bool,
}

/// Owned buffers of a benchmark model.
pub struct BenchModel {
    /// The mesh.
    pub mesh: Mesh,
    /// Fixed nodes.
    pub fixed: Vec<usize>,
    bytes: [Vec<u8>; 9],
}

impl BenchModel {
    /// A homogeneous block of about `tets` tetrahedra with the bottom fixed.
    pub fn block(tets: usize, p: LambdaAlpha) -> Self {
        let size = [0.1, 0.1, 0.05];
        let mesh = box_mesh(size, cells_for_target(size, tets));
        let fixed = mesh
            .group("bottom")
            .expect("box mesh has a bottom group")
            .to_vec();
        let le = |v: &mut Vec<u8>, x: f32| v.extend_from_slice(&x.to_le_bytes());
        let lu = |v: &mut Vec<u8>, x: u32| v.extend_from_slice(&x.to_le_bytes());
        let mut b: [Vec<u8>; 9] = Default::default();
        for p in &mesh.nodes {
            for k in 0..3 {
                le(&mut b[0], p[k] as f32);
            }
        }
        for t in &mesh.node_tags {
            lu(&mut b[1], *t as u32);
        }
        for t in &mesh.tets {
            for i in t {
                lu(&mut b[2], *i as u32);
            }
            let g = tet_geometry(&t.map(|i| Vector3::from(mesh.nodes[i])))
                .expect("box mesh tets are valid");
            let (c, d) = element_cd(&g);
            let (mut cp, mut dp) = ([0.0; PACKED_LEN], [0.0; PACKED_LEN]);
            pack_symmetric(&c, &mut cp);
            pack_symmetric(&d, &mut dp);
            cp.iter().for_each(|v| le(&mut b[5], *v as f32));
            dp.iter().for_each(|v| le(&mut b[6], *v as f32));
        }
        fixed.iter().for_each(|i| lu(&mut b[3], *i as u32));
        for tri in mesh.boundary_triangles() {
            tri.iter().for_each(|i| lu(&mut b[4], *i as u32));
        }
        le(&mut b[7], p.lambda as f32);
        le(&mut b[8], p.alpha as f32);
        Self {
            mesh,
            fixed,
            bytes: b,
        }
    }

    /// The model record borrowing the buffers.
    pub fn record(&self) -> ModelRecord<'_> {
        let b = &self.bytes;
        ModelRecord {
            units: Units::Si,
            provenance: Provenance {
                tool: "palpate bench runtime",
                created: "",
                source: "generated block",
                notes: "",
            },
            node_count: self.mesh.nodes.len() as u32,
            element_count: self.mesh.tets.len() as u32,
            rest_positions: F32s(&b[0]),
            node_tags: U32s(&b[1]),
            tets: U32s(&b[2]),
            fixed_nodes: U32s(&b[3]),
            surface_triangles: U32s(&b[4]),
            c_packed: F32s(&b[5]),
            d_packed: F32s(&b[6]),
            parameters: ParameterSets {
                layout: ParameterLayout::Global,
                count: 1,
                lambda: F32s(&b[7]),
                alpha: F32s(&b[8]),
            },
            blend: Blend::None,
        }
    }
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

struct KernelRun {
    name: &'static str,
    times_us: Vec<f64>,
    iters: Vec<u32>,
    rel_res: Vec<f32>,
    err_vs_converged: Vec<f64>,
    bytes: usize,
    /// Thread CPU time per tick (µs), mean over the run: robust to other load on the machine.
    cpu_mean_us: f64,
}

fn run_kernel(
    model: &BenchModel,
    args: &Args,
    kernel: Kernel,
    name: &'static str,
) -> anyhow::Result<KernelRun> {
    let cfg = RuntimeConfig {
        tolerance: args.tolerance,
        max_iterations: 100,
        kernel,
        preconditioner: Preconditioner::BlockJacobi,
        coarse_aggregates: args.aggregates,
        rotation_iterations: args.rotation_iterations,
        ..Default::default()
    };
    let rec = model.record();
    let need = StorageRequirement::for_model(&rec, &cfg);
    let (mut f, mut u) = (vec![0f32; need.f32s], vec![0u32; need.u32s]);
    let mut rt = Runtime::new(rec, &mut f, &mut u, cfg)?;
    let ref_cfg = RuntimeConfig {
        tolerance: 1e-9,
        max_iterations: 5000,
        ..cfg
    };
    let (mut f2, mut u2) = (vec![0f32; need.f32s], vec![0u32; need.u32s]);
    let mut reference = Runtime::new(model.record(), &mut f2, &mut u2, ref_cfg)?;
    // Settle the initial contact so the run measures steady haptic ticks.
    rt.set_contact_force(contact_point(0, args.ticks), [0.0, 0.0, -0.5], 0.015)?;
    for _ in 0..20 {
        rt.tick();
    }
    let mut run = KernelRun {
        name,
        times_us: Vec::new(),
        iters: Vec::new(),
        rel_res: Vec::new(),
        err_vs_converged: Vec::new(),
        bytes: rt.footprint_bytes(),
        cpu_mean_us: f64::NAN,
    };
    let mut cpu_total = 0.0;
    for k in 0..args.ticks {
        let check = k % 50 == 25;
        if check {
            reference.copy_state_from(&rt)?;
        }
        let c0 = crate::link::stats::thread_cpu_seconds();
        let t0 = Instant::now();
        rt.set_contact_force(contact_point(k, args.ticks), [0.0, 0.0, -0.5], 0.015)?;
        let rep = rt.tick();
        run.times_us.push(t0.elapsed().as_secs_f64() * 1e6);
        if let (Some(a), Some(b)) = (c0, crate::link::stats::thread_cpu_seconds()) {
            cpu_total += b - a;
        }
        run.iters.push(rep.iterations);
        run.rel_res.push(rep.rel_residual);
        if check {
            reference.set_contact_force(contact_point(k, args.ticks), [0.0, 0.0, -0.5], 0.015)?;
            reference.tick();
            let (a, b) = (rt.displacements(), reference.displacements());
            let mut num = 0.0f64;
            let mut den = 0.0f64;
            for i in 0..a.len() {
                num += ((a[i] - b[i]) as f64).powi(2);
                den += (b[i] as f64).powi(2);
            }
            run.err_vs_converged.push((num / den.max(1e-300)).sqrt());
        }
    }
    run.cpu_mean_us = cpu_total / args.ticks.max(1) as f64 * 1e6;
    Ok(run)
}

/// The same tick with a sparse direct solver: rotations from the runtime's state, f64 assembly of
/// K' and of the warped right-hand side, faer Cholesky refactored every tick (symbolic analysis
/// once, as a direct haptic loop would).
fn run_direct(model: &BenchModel, args: &Args, p: LambdaAlpha) -> anyhow::Result<Vec<f64>> {
    let cfg = RuntimeConfig {
        tolerance: args.tolerance,
        ..Default::default()
    };
    let rec = model.record();
    let need = StorageRequirement::for_model(&rec, &cfg);
    let (mut f, mut u) = (vec![0f32; need.f32s], vec![0u32; need.u32s]);
    let mut rt = Runtime::new(rec, &mut f, &mut u, cfg)?;
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
    rt.set_contact_force(contact_point(0, args.ticks), [0.0, 0.0, -0.5], 0.015)?;
    for _ in 0..20 {
        rt.tick();
    }
    let mut vals = vec![0.0f64; pairs.len()];
    let stride = (args.ticks / args.direct_ticks.max(1)).max(1);
    for k in (0..args.ticks).step_by(stride).take(args.direct_ticks) {
        rt.set_contact_force(contact_point(k, args.ticks), [0.0, 0.0, -0.5], 0.015)?;
        let t0 = Instant::now();
        // Rotations as the runtime computed them for its current state.
        let rots: Vec<[f32; 9]> = (0..mesh.tets.len())
            .map(|e| rt.element_rotation(e).unwrap_or([0.0; 9]))
            .collect();
        let mut rhs = Mat::<f64>::zeros(nfree, 1);
        let mut v = 0;
        let mut contact = vec![0.0f64; 3 * n];
        palpate_runtime::contact_rule::contact_weights(
            [contact_point(k, args.ticks)[0] as f64, 0.05, 0.05],
            0.015,
            |i| mesh.nodes[i],
            &(0..n).map(|i| rt.lumped_area(i) as f64).collect::<Vec<_>>(),
            |i| rt.is_fixed(i),
            |i, w| contact[3 * i + 2] = -0.5 * w,
        )
        .map_err(|e| anyhow::anyhow!("{e:?}"))?;
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
            for a in 0..4 {
                x0.fixed_rows_mut::<3>(3 * a)
                    .copy_from(&Vector3::from(mesh.nodes[t[a]]));
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

/// Runs the benchmark.
pub fn run(args: Args) -> anyhow::Result<()> {
    let p = LambdaAlpha::from_young_poisson(10_000.0, 0.3);
    let model = BenchModel::block(args.tets, p);
    let tets = model.mesh.tets.len();
    let dofs = 3 * (model.mesh.nodes.len() - model.fixed.len());
    println!(
        "palpate bench runtime: {tets} tets, {dofs} free dofs, {} ticks, tolerance {:e}",
        args.ticks, args.tolerance
    );
    let mut runs = vec![run_kernel(&model, &args, Kernel::Gradient, "gradient")?];
    if !args.gradient_only {
        runs.push(run_kernel(&model, &args, Kernel::Packed, "packed")?);
    }
    let mut direct = run_direct(&model, &args, p)?;
    direct.sort_by(|a, b| a.total_cmp(b));
    for r in &runs {
        let mut it = r.iters.clone();
        it.sort_unstable();
        let slow: Vec<usize> = (0..r.times_us.len())
            .filter(|&k| {
                r.times_us[k]
                    > 3.0
                        * percentile(
                            &{
                                let mut t = r.times_us.clone();
                                t.sort_by(|a, b| a.total_cmp(b));
                                t
                            },
                            0.5,
                        )
            })
            .collect();
        println!(
            "{}: PCG iterations p50 {} p99 {} max {}; {} ticks slower than 3× the median (iterations there: {:?})",
            r.name,
            it[it.len() / 2],
            it[(it.len() * 99) / 100],
            it[it.len() - 1],
            slow.len(),
            slow.iter().take(8).map(|&k| r.iters[k]).collect::<Vec<_>>()
        );
    }
    println!(
        "{:<10} {:>9} {:>9} {:>9} {:>10} {:>12} {:>14} {:>10}",
        "kernel", "p50_us", "p99_us", "max_us", "mean_iter", "max_rel_res", "max_err_conv", "bytes"
    );
    let mut summary = Vec::new();
    for r in &runs {
        let mut t = r.times_us.clone();
        t.sort_by(|a, b| a.total_cmp(b));
        let mean_it = r.iters.iter().map(|v| *v as f64).sum::<f64>() / r.iters.len().max(1) as f64;
        let max_res = r.rel_res.iter().fold(0.0f32, |a, v| a.max(*v));
        let max_err = r.err_vs_converged.iter().fold(0.0f64, |a, v| a.max(*v));
        println!(
            "{:<10} {:>9.1} {:>9.1} {:>9.1} {:>10.2} {:>12.2e} {:>14.2e} {:>10}",
            r.name,
            percentile(&t, 0.5),
            percentile(&t, 0.99),
            t.last().copied().unwrap_or(f64::NAN),
            mean_it,
            max_res,
            max_err,
            r.bytes
        );
        summary.push((
            percentile(&t, 0.5),
            percentile(&t, 0.99),
            *t.last().unwrap_or(&f64::NAN),
            mean_it,
            max_res,
            max_err,
            r.bytes,
            r.cpu_mean_us,
        ));
        println!("{:<10} mean wall {:.1} µs, mean thread CPU {:.1} µs per tick (CPU excludes time the thread waited for a core)", r.name, r.times_us.iter().sum::<f64>() / r.times_us.len().max(1) as f64, r.cpu_mean_us);
    }
    println!(
        "{:<10} {:>9.1} {:>9.1} {:>9.1}   (faer sparse Cholesky, refactored per tick, {} ticks)",
        "direct",
        percentile(&direct, 0.5),
        percentile(&direct, 0.99),
        direct.last().copied().unwrap_or(f64::NAN),
        direct.len()
    );
    let g = summary[0];
    let packed = summary.get(1).copied().unwrap_or((
        f64::NAN,
        f64::NAN,
        f64::NAN,
        f64::NAN,
        f32::NAN,
        f64::NAN,
        0,
        f64::NAN,
    ));
    println!(
        "ratios: packed/gradient p50 = {:.2}, direct/gradient p50 = {:.1}",
        packed.0 / g.0,
        percentile(&direct, 0.5) / g.0
    );
    println!(
        "{}",
        json!({
            "bench": "runtime",
            "tets": tets,
            "dofs": dofs,
            "ticks": args.ticks,
            "kernel": "gradient",
            "p50_us": g.0,
            "p99_us": g.1,
            "max_us": g.2,
            "mean_pcg_iters": g.3,
            "rel_residual": g.4,
            "max_rel_error_vs_converged": g.5,
            "bytes": g.6,
            "bytes_per_element": g.6 as f64 / tets as f64,
            "cpu_mean_us": g.7,
            "packed_p50_us": packed.0,
            "packed_p99_us": packed.1,
            "aggregates": args.aggregates,
            "direct_p50_us": percentile(&direct, 0.5),
            "direct_p99_us": percentile(&direct, 0.99),
        })
    );
    Ok(())
}

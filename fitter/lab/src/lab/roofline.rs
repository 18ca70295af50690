//! `palpate-lab bench roofline`: how far one PCG iteration of the haptic tick is from this
//! machine's limits. Measures, on one core (the tick is single-threaded), the f32 FMA peak of the
//! 8-lane AVX2 code the runtime compiles to and the read bandwidth at working sets that sit in
//! L1, L2, L3 and DRAM; counts, for the bench's block (`bench runtime`'s model), the floating-point
//! operations and bytes one PCG iteration moves; and prints the time each limit allows. The
//! measured time per iteration comes from `bench runtime` (its `cpu_us_per_pcg_iteration`, the
//! slope of tick CPU time over PCG iterations), so BENCHMARKS.md puts the two side by side.
//!
//! The counts are the kernels' own operations, read off `runtime/src` (an FMA counts 2; the
//! element pass per padded element, the vector passes per node, the coarse solve per
//! aggregate), and the bytes each pass streams from wherever its arrays live — gathers of node
//! vectors from cache are counted too, so the byte figure is what the core loads and stores,
//! not what DRAM delivers. This machine exposes no hardware counters to the VM (`perf stat`:
//! cycles "not supported"), so they are counted, not sampled.

use palpate_fem::block_model::BlockModel;
use palpate_runtime::kernel::LANES;
use palpate_runtime::material::LambdaAlpha;
use palpate_runtime::RuntimeConfig;
use serde_json::json;
use std::time::Instant;

/// Arguments of `palpate-lab bench roofline`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Approximate number of tetrahedra of the block (as `bench runtime --tets`).
    #[arg(long, default_value_t = 5000)]
    pub tets: usize,
    /// Aggregates of the two-level preconditioner (as `bench runtime --aggregates`).
    #[arg(long, default_value_t = RuntimeConfig::default().coarse_aggregates)]
    pub aggregates: u32,
    /// Seconds each machine measurement runs (best of three).
    #[arg(long, default_value_t = 0.3)]
    pub seconds: f64,
}

/// Element pass of the operator q = K'p per (padded) element, `runtime/src/kernel.rs`
/// `rotated_apply_lanes`: H = Σ_a (v_a − v_0) ĝ_aᵀ (9 differences + 27 FMA = 63), the scaled
/// stress (28), f_a = P ĝ_a for a = 1..3 (9 entries of a 3-term dot product, 45) and
/// f_0 = −Σ f_a (9): 145.
const FLOPS_PER_ELEMENT: f64 = 63.0 + 28.0 + 54.0;
/// Bytes per (padded) element and iteration: node ids (4 u32), ĝ (9 f32), V, λ, α (3 f32), the
/// gathered p (12 f32), the element forces stored (12 f32), then the node pass's incidences
/// (4 u32) and the element forces read back (12 f32).
const BYTES_PER_ELEMENT: f64 = 16.0 + 36.0 + 12.0 + 48.0 + 48.0 + 16.0 + 48.0;
/// Flops per node and iteration (`runtime/src/pcg.rs`, `two_level.rs`, `coarse.rs`): p·q (6), the
/// update pass x += αp, r_full −= αq, r −= αSq (18), ‖r‖² in f64 (6), z = B_i⁻¹ r_i (15), the
/// coarse restriction (18) and prolongation (21), r·z (6), p = z + βp (6).
const FLOPS_PER_NODE: f64 = 6.0 + 18.0 + 6.0 + 15.0 + 18.0 + 21.0 + 6.0 + 6.0;
/// Bytes per node and iteration: the node pass (incidence start 4, q stored 12), p·q (24), the
/// update pass (x, p, r_full, q, r read 60; x, r_full, r, z stored 48; B_i 24; the contact flag
/// 1), the restriction (aggregate id 4, r 12, x₀ 12), the prolongation (id 4, x₀ 12, z read and
/// stored 24), the filter of z (flag 1, z 24), r·z (24), p = z + βp (36).
const BYTES_PER_NODE: f64 = 16.0 + 24.0 + 133.0 + 28.0 + 40.0 + 25.0 + 24.0 + 36.0;

/// The f32 FMA throughput of one core (flop/s): 12 independent chains (enough to cover the FMA
/// latency on two ports) of 8-lane fused multiply-adds, written as `f32::mul_add` lane by lane —
/// the host build's `target-cpu=x86-64-v3` turns each chain into one 256-bit `vfmadd` per
/// round, as it does the runtime's 8-lane kernels (the workspace forbids `unsafe`, so no
/// intrinsics). Best of three runs of `seconds`.
fn fma_peak(seconds: f64) -> f64 {
    const CHAINS: usize = 12;
    const ROUNDS: usize = 1 << 14;
    let (b, c) = (
        std::hint::black_box(0.999_999f32),
        std::hint::black_box(1e-7f32),
    );
    let mut acc = [[1.0f32; LANES]; CHAINS];
    let mut best = 0.0f64;
    for _ in 0..3 {
        let t0 = Instant::now();
        let mut flops = 0.0f64;
        while t0.elapsed().as_secs_f64() < seconds {
            for _ in 0..ROUNDS {
                for a in acc.iter_mut() {
                    for x in a.iter_mut() {
                        *x = x.mul_add(b, c);
                    }
                }
            }
            acc = std::hint::black_box(acc);
            flops += (ROUNDS * CHAINS * LANES * 2) as f64;
        }
        best = best.max(flops / t0.elapsed().as_secs_f64());
    }
    std::hint::black_box(acc);
    best
}

/// Read bandwidth (bytes/s) of one core over an f32 array of `bytes`: the sum of every element
/// with 8 independent 8-lane partial sums, repeated for `seconds`, best of three.
fn read_bandwidth(bytes: usize, seconds: f64) -> f64 {
    let v: Vec<f32> = (0..bytes / 4).map(|i| (i % 7) as f32).collect();
    let mut best = 0.0f64;
    let mut sink = 0.0f32;
    for _ in 0..3 {
        let t0 = Instant::now();
        let mut moved = 0.0f64;
        while t0.elapsed().as_secs_f64() < seconds {
            let mut acc = [[0.0f32; 8]; 8];
            for chunk in std::hint::black_box(&v).chunks_exact(64) {
                for (a, x) in acc.iter_mut().zip(chunk.chunks_exact(8)) {
                    for l in 0..8 {
                        a[l] += x[l];
                    }
                }
            }
            sink += acc.iter().flatten().sum::<f32>();
            moved += (v.len() / 64 * 64 * 4) as f64;
        }
        best = best.max(moved / t0.elapsed().as_secs_f64());
    }
    std::hint::black_box(sink);
    best
}

/// Runs the roofline measurement and prints the table and its JSON line.
pub fn run(args: Args) -> anyhow::Result<()> {
    let block = BlockModel::block(args.tets, LambdaAlpha::from_young_poisson(1e4, 0.3))?;
    let (t, n) = (block.mesh.tets.len(), block.mesh.nodes.len());
    let padded = t.div_ceil(LANES) * LANES;
    let dim = 6.0 * args.aggregates as f64;
    // The coarse solve: forward and back substitution with the dense dim × dim factor.
    let coarse_flops = 2.0 * dim * dim;
    let coarse_bytes = 4.0 * dim * dim;
    let flops = FLOPS_PER_ELEMENT * padded as f64 + FLOPS_PER_NODE * n as f64 + coarse_flops;
    let bytes = BYTES_PER_ELEMENT * padded as f64 + BYTES_PER_NODE * n as f64 + coarse_bytes;
    eprintln!(
        "block: {t} tets ({padded} padded), {n} nodes, {} aggregates; per PCG iteration {:.3} Mflop, {:.3} MB",
        args.aggregates,
        flops / 1e6,
        bytes / 1e6
    );
    let peak = fma_peak(args.seconds);
    let levels: [(&str, usize); 4] = [
        ("L1 (24 KiB)", 24 << 10),
        ("L2 (1 MiB)", 1 << 20),
        ("L3 (32 MiB)", 32 << 20),
        ("DRAM (1 GiB)", 1 << 30),
    ];
    let bw: Vec<(&str, usize, f64)> = levels
        .iter()
        .map(|&(name, size)| (name, size, read_bandwidth(size, args.seconds)))
        .collect();
    println!(
        "one core, f32: FMA peak {:.1} GFLOP/s (8-lane AVX2)",
        peak / 1e9
    );
    println!(
        "{:<14} {:>10} {:>22}",
        "working set", "read GB/s", "µs per PCG iteration"
    );
    for (name, _, b) in &bw {
        println!("{name:<14} {:>10.1} {:>22.2}", b / 1e9, 1e6 * bytes / b);
    }
    println!("{:<14} {:>10} {:>22.2}", "FMA peak", "", 1e6 * flops / peak);
    println!(
        "{}",
        json!({
            "schema_version": 1,
            "bench": "roofline",
            "tets": t,
            "padded_tets": padded,
            "nodes": n,
            "aggregates": args.aggregates,
            "flops_per_pcg_iteration": flops,
            "bytes_per_pcg_iteration": bytes,
            "arithmetic_intensity_flop_per_byte": flops / bytes,
            "fma_peak_flops": peak,
            "read_bandwidth_bytes_per_s": bw.iter().map(|(name, size, b)| json!({
                "level": name, "bytes": size, "bytes_per_s": b,
                "us_per_pcg_iteration": 1e6 * bytes / b,
            })).collect::<Vec<_>>(),
            "us_per_pcg_iteration_at_fma_peak": 1e6 * flops / peak,
        })
    );
    Ok(())
}

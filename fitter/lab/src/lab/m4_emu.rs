//! `palpate-lab m4-emu`: the host side of the emulated Cortex-M4F run (`firmware/m4-emu`).
//!
//! `models` writes the generated block models the emulator bundles in its flash. `compare` reads
//! the emulator's transcript (semihosting output of `qemu-system-arm -M mps2-an386`), replays the
//! same probe press through the host runtime and the same scripted converter through the host's
//! probe library, and checks that every reaction force, iteration count, final displacement
//! field and link frame has the same bits as on the M4. It then turns the instructions per tick
//! the emulator counted into the board's cost model: a tick fits the 1 kHz budget of a 64 MHz
//! Cortex-M4F when `instructions × CPI ≤ 64,000` cycles, with CPI (cycles per instruction) an
//! assumption stated on the command line, and the largest block model that does is extrapolated
//! by a least-squares line through the models played (instructions per tick linear in the
//! tetrahedra, for the worst tick and the median one). A model named by `--must-hold` whose worst
//! tick misses its rate, or any difference from the host, fails the command.

use anyhow::{bail, ensure, Context as _};
use palpate_fem::block_model::BlockModel;
use palpate_probe::sim::{default_config, Profile, SimProbe};
use palpate_protocol::link::{codec, Frame, MAX_FRAME_ENCODED};
use palpate_runtime::material::LambdaAlpha;
use palpate_runtime::{Probe, Runtime, RuntimeConfig, StorageRequirement};
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The emulator's own hash of its state line, the same source on both sides.
#[path = "../../../../firmware/m4-emu/src/state_hash.rs"]
mod state_hash;
use state_hash::fnv1a;

/// The block's material: the runtime bench's (E = 10 kPa, ν = 0.3, a soft foam).
const YOUNG_PA: f64 = 10_000.0;
const POISSON: f64 = 0.3;

/// Arguments of `palpate-lab m4-emu`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// What to do.
    #[command(subcommand)]
    pub command: M4Command,
}

/// Subcommands of `palpate-lab m4-emu`.
#[derive(Debug, clap::Subcommand)]
pub enum M4Command {
    /// Writes the generated 10 × 10 × 5 cm block models the emulator bundles, one per size, as
    /// `block-<tets>.palp` (the sizes are targets; the file is named for the tets it holds).
    Models {
        /// Output folder.
        #[arg(long, default_value = "firmware/m4-emu/models")]
        out: PathBuf,
        /// Target tetrahedron counts.
        #[arg(long, value_delimiter = ',', default_value = "6,24,192")]
        tets: Vec<usize>,
    },
    /// Compares an emulator transcript with the host and prints the cost model.
    Compare {
        /// The emulator's semihosting output.
        transcript: PathBuf,
        /// Folder of the `.palp` models the emulator played (the same files it bundled).
        #[arg(long, default_value = "firmware/m4-emu/models")]
        models: PathBuf,
        /// Core clock of the board, MHz (nRF52840: 64).
        #[arg(long, default_value_t = 64.0)]
        mhz: f64,
        /// Tick rate to hold, Hz.
        #[arg(long, default_value_t = 1000.0)]
        rate_hz: f64,
        /// Cycles per instruction assumed for the Cortex-M4F (see firmware/m4-emu/README.md).
        #[arg(long, default_value_t = 1.5)]
        cpi: f64,
        /// RAM the board leaves for the runtime's storage, bytes.
        #[arg(long, default_value_t = 224 * 1024)]
        ram_bytes: usize,
        /// Models whose worst tick must hold the budget, as `NAME` (at `--rate-hz`) or
        /// `NAME@HZ`: the stated figures that CI checks.
        #[arg(long, value_delimiter = ',')]
        must_hold: Vec<String>,
    },
}

/// Runs a subcommand.
pub fn run(args: Args) -> anyhow::Result<()> {
    match args.command {
        M4Command::Models { out, tets } => write_models(&out, &tets),
        M4Command::Compare {
            transcript,
            models,
            mhz,
            rate_hz,
            cpi,
            ram_bytes,
            must_hold,
        } => compare(
            &transcript,
            &models,
            Budget {
                mhz,
                rate_hz,
                cpi,
                ram_bytes,
            },
            &must_hold,
        ),
    }
}

fn write_models(out: &Path, targets: &[usize]) -> anyhow::Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let p = LambdaAlpha::from_young_poisson(YOUNG_PA, POISSON);
    println!("model              nodes   tets  .palp B  runtime B");
    for &target in targets {
        let model = BlockModel::block(target, p)?;
        let rec = model.record();
        let need = StorageRequirement::for_model(&rec, &RuntimeConfig::default());
        let name = format!("block-{}", model.mesh.tets.len());
        let path = out.join(format!("{name}.palp"));
        let bytes = palpate_fem::export::ModelBuffers::from_mesh(
            &model.mesh,
            &model.fixed,
            &palpate_fem::forward::Material::homogeneous(p),
            &palpate_fem::export::ProvenanceInfo {
                tool: "palpate-lab m4-emu models".into(),
                source: format!(
                    "generated block 0.1 x 0.1 x 0.05 m, {} tets, E {YOUNG_PA} Pa, nu {POISSON}",
                    model.mesh.tets.len()
                ),
                notes: "bundled by firmware/m4-emu".into(),
            },
        )?
        .write(&path)?;
        println!(
            "{name:<16} {:>7} {:>6} {:>8} {:>10}",
            rec.node_count,
            rec.element_count,
            bytes,
            need.bytes()
        );
        log::info!("wrote {}", path.display());
    }
    Ok(())
}

/// The board the cost model is for.
#[derive(Debug, Clone, Copy, Serialize)]
struct Budget {
    mhz: f64,
    rate_hz: f64,
    cpi: f64,
    ram_bytes: usize,
}

impl Budget {
    /// Instructions one tick may take.
    fn instructions(&self) -> f64 {
        self.mhz * 1e6 / self.rate_hz / self.cpi
    }
}

/// One model's run on the emulator, as its transcript says.
#[derive(Debug, Default)]
struct ModelRun {
    nodes: usize,
    tets: usize,
    storage_bytes: usize,
    radius: f32,
    ticks: Vec<TickLine>,
    state_hash: Option<u64>,
}

#[derive(Debug, Clone, Copy)]
struct TickLine {
    center: [f32; 3],
    reaction: [f32; 3],
    iterations: u32,
    instructions: u64,
}

/// The probe part of the transcript.
#[derive(Debug, Default)]
struct ProbeRun {
    peak: f32,
    period_s: f32,
    noise: i16,
    duration_us: u64,
    frames: Vec<(Vec<u8>, u64)>,
}

#[derive(Debug, Default)]
struct Transcript {
    instructions_per_count: f64,
    timer: String,
    calibration: Option<(u64, u64)>,
    runs: BTreeMap<String, ModelRun>,
    order: Vec<String>,
    probe: Option<ProbeRun>,
    /// (elements, instructions) of `kernel::norm2_lanes` on the M4.
    kernel: Option<(u64, u64)>,
    done: bool,
}

fn f32_bits(s: &str, what: &str, line: usize) -> anyhow::Result<f32> {
    u32::from_str_radix(s, 16)
        .map(f32::from_bits)
        .with_context(|| {
            format!("transcript line {line}: {what}: expected f32 bits in hex, found {s:?}")
        })
}

fn int<T: std::str::FromStr>(s: &str, what: &str, line: usize) -> anyhow::Result<T> {
    s.parse().ok().with_context(|| {
        format!("transcript line {line}: {what}: expected an integer, found {s:?}")
    })
}

fn parse(text: &str) -> anyhow::Result<Transcript> {
    let mut t = Transcript::default();
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let Some(rest) = raw.strip_prefix("m4 ") else {
            continue;
        };
        let w: Vec<&str> = rest.split_whitespace().collect();
        let need = |n: usize| -> anyhow::Result<()> {
            ensure!(
                w.len() == n,
                "transcript line {line}: {:?} has {} fields, expected {n}",
                w.first().unwrap_or(&""),
                w.len()
            );
            Ok(())
        };
        match w.first().copied() {
            Some("timer") => {
                need(3)?;
                t.instructions_per_count = int(w[1], "instructions per count", line)?;
                t.timer = w[2].to_string();
            }
            Some("calibrate") => {
                need(3)?;
                t.calibration = Some((
                    int(w[1], "loop instructions", line)?,
                    int(w[2], "timer counts", line)?,
                ));
            }
            Some("model") => {
                need(5)?;
                let name = w[1].to_string();
                let run = ModelRun {
                    nodes: int(w[2], "nodes", line)?,
                    tets: int(w[3], "tets", line)?,
                    storage_bytes: int(w[4], "storage bytes", line)?,
                    ..ModelRun::default()
                };
                t.order.push(name.clone());
                t.runs.insert(name, run);
            }
            Some("press") => {
                need(3)?;
                let run = t.runs.get_mut(w[1]).with_context(|| {
                    format!("transcript line {line}: press of unknown model {}", w[1])
                })?;
                run.radius = f32_bits(w[2], "sphere radius", line)?;
            }
            Some("tick") => {
                need(10)?;
                let run = t.runs.get_mut(w[1]).with_context(|| {
                    format!("transcript line {line}: tick of unknown model {}", w[1])
                })?;
                let k: usize = int(w[2], "tick", line)?;
                ensure!(
                    k == run.ticks.len(),
                    "transcript line {line}: tick {k} of {} out of order (expected {})",
                    w[1],
                    run.ticks.len()
                );
                run.ticks.push(TickLine {
                    center: [
                        f32_bits(w[3], "probe centre x", line)?,
                        f32_bits(w[4], "probe centre y", line)?,
                        f32_bits(w[5], "probe centre z", line)?,
                    ],
                    reaction: [
                        f32_bits(w[6], "reaction x", line)?,
                        f32_bits(w[7], "reaction y", line)?,
                        f32_bits(w[8], "reaction z", line)?,
                    ],
                    iterations: 0,
                    instructions: 0,
                });
                // The iteration count and timer counts follow in one field "iters/counts".
                let (it, counts) = w[9].split_once('/').with_context(|| {
                    format!(
                        "transcript line {line}: expected iterations/counts, found {:?}",
                        w[9]
                    )
                })?;
                let last = run.ticks.last_mut().expect("pushed above");
                last.iterations = int(it, "iterations", line)?;
                let counts: u64 = int(counts, "timer counts", line)?;
                last.instructions = counts * t.instructions_per_count as u64;
            }
            Some("state") => {
                need(3)?;
                let run = t.runs.get_mut(w[1]).with_context(|| {
                    format!("transcript line {line}: state of unknown model {}", w[1])
                })?;
                run.state_hash = Some(u64::from_str_radix(w[2], 16).with_context(|| {
                    format!(
                        "transcript line {line}: expected a hex hash, found {:?}",
                        w[2]
                    )
                })?);
            }
            Some("probe") => {
                need(5)?;
                t.probe = Some(ProbeRun {
                    peak: f32_bits(w[1], "peak", line)?,
                    period_s: f32_bits(w[2], "period", line)?,
                    noise: int(w[3], "noise counts", line)?,
                    duration_us: int(w[4], "duration", line)?,
                    frames: Vec::new(),
                });
            }
            Some("frame") => {
                need(3)?;
                let probe = t.probe.as_mut().with_context(|| {
                    format!("transcript line {line}: frame before the probe line")
                })?;
                let hex = w[1];
                ensure!(
                    hex.len().is_multiple_of(2),
                    "transcript line {line}: odd hex length"
                );
                let bytes = (0..hex.len())
                    .step_by(2)
                    .map(|j| u8::from_str_radix(&hex[j..j + 2], 16))
                    .collect::<Result<Vec<u8>, _>>()
                    .with_context(|| format!("transcript line {line}: frame bytes {hex:?}"))?;
                let counts: u64 = int(w[2], "timer counts", line)?;
                probe
                    .frames
                    .push((bytes, counts * t.instructions_per_count as u64));
            }
            Some("kernel") => {
                need(4)?;
                let n: u64 = int(w[2], "elements", line)?;
                let counts: u64 = int(w[3], "timer counts", line)?;
                t.kernel = Some((n, counts * t.instructions_per_count as u64));
            }
            Some("done") => t.done = true,
            Some("note") => log::info!("emulator: {}", rest),
            Some("error") => bail!("transcript line {line}: the emulator reports {rest:?}"),
            other => bail!("transcript line {line}: unknown record {other:?}"),
        }
    }
    ensure!(
        t.done,
        "the transcript has no `m4 done` line: the emulated run did not finish"
    );
    Ok(t)
}

/// What one model's comparison found.
#[derive(Debug, Serialize)]
struct ModelFigures {
    model: String,
    nodes: usize,
    tets: usize,
    ticks: usize,
    reactions_equal_bits: usize,
    max_reaction_diff_n: f32,
    iterations_equal: usize,
    state_equal_bits: bool,
    runtime_storage_bytes: usize,
    m4_instructions_median: u64,
    m4_instructions_max: u64,
    m4_cycles_max_at_cpi: f64,
    holds_budget: bool,
    rate_held_worst_hz: f64,
    rate_held_median_hz: f64,
    host_us_median: f64,
}

fn compare_model(
    name: &str,
    run: &ModelRun,
    models: &Path,
    budget: &Budget,
) -> anyhow::Result<ModelFigures> {
    let path = models.join(format!("{name}.palp"));
    let bytes = std::fs::read(&path).with_context(|| format!("reading {}", path.display()))?;
    let rec = palpate_protocol::model::decode(&bytes)
        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    ensure!(
        rec.node_count as usize == run.nodes && rec.element_count as usize == run.tets,
        "{}: {} nodes, {} tets; the emulator played {} nodes, {} tets",
        path.display(),
        rec.node_count,
        rec.element_count,
        run.nodes,
        run.tets
    );
    let cfg = RuntimeConfig::default();
    let need = StorageRequirement::for_model(&rec, &cfg);
    ensure!(
        need.bytes() == run.storage_bytes,
        "{name}: the host runtime needs {} B of storage, the M4's said {} B",
        need.bytes(),
        run.storage_bytes
    );
    let (mut f, mut u) = (vec![0f32; need.f32s], vec![0u32; need.u32s]);
    let mut rt = Runtime::new(rec, &mut f, &mut u, cfg)?;
    let mut equal_bits = 0;
    let mut iterations_equal = 0;
    let mut max_diff = 0f32;
    let mut host_us = Vec::with_capacity(run.ticks.len());
    for (k, t) in run.ticks.iter().enumerate() {
        let t0 = Instant::now();
        rt.set_probe(Probe::Sphere {
            center: t.center,
            radius: run.radius,
        })
        .with_context(|| format!("{name}: tick {k}: set_probe"))?;
        let report = rt.tick();
        host_us.push(t0.elapsed().as_secs_f64() * 1e6);
        let same = (0..3).all(|i| report.reaction[i].to_bits() == t.reaction[i].to_bits());
        if same {
            equal_bits += 1;
        } else if equal_bits == k {
            log::warn!(
                "{name}: tick {k}: first reaction that differs: host {:?}, M4 {:?}",
                report.reaction,
                t.reaction
            );
        }
        if report.iterations == t.iterations {
            iterations_equal += 1;
        }
        for i in 0..3 {
            max_diff = max_diff.max((report.reaction[i] - t.reaction[i]).abs());
        }
    }
    let state_equal = run.state_hash == Some(fnv1a(rt.displacements()));
    let mut instr: Vec<u64> = run.ticks.iter().map(|t| t.instructions).collect();
    instr.sort_unstable();
    host_us.sort_by(f64::total_cmp);
    let max = instr.last().copied().unwrap_or(0);
    let median = instr.get(instr.len() / 2).copied().unwrap_or(0);
    let rate = |i: u64| budget.mhz * 1e6 / (i as f64 * budget.cpi);
    Ok(ModelFigures {
        model: name.to_string(),
        nodes: run.nodes,
        tets: run.tets,
        ticks: run.ticks.len(),
        reactions_equal_bits: equal_bits,
        max_reaction_diff_n: max_diff,
        iterations_equal,
        state_equal_bits: state_equal,
        runtime_storage_bytes: need.bytes(),
        m4_instructions_median: median,
        m4_instructions_max: max,
        m4_cycles_max_at_cpi: max as f64 * budget.cpi,
        holds_budget: (max as f64) <= budget.instructions(),
        rate_held_worst_hz: rate(max),
        rate_held_median_hz: rate(median),
        host_us_median: host_us.get(host_us.len() / 2).copied().unwrap_or(0.0),
    })
}

/// The probe comparison's figures.
#[derive(Debug, Serialize)]
struct ProbeFigures {
    frames: usize,
    frames_equal_bytes: usize,
    m4_instructions_per_sample_median: u64,
    m4_instructions_per_sample_max: u64,
}

fn compare_probe(p: &ProbeRun) -> anyhow::Result<ProbeFigures> {
    let profile = Profile::Press {
        peak: p.peak,
        period_s: p.period_s,
    };
    let mut sim = SimProbe::new(default_config(), profile, p.noise)
        .map_err(|e| anyhow::anyhow!("the host's simulated probe: {e:?}"))?;
    let mut host: Vec<Vec<u8>> = Vec::new();
    let mut encode = |frame: &Frame| -> anyhow::Result<()> {
        let mut buf = [0u8; MAX_FRAME_ENCODED];
        let n = codec::encode(frame, &mut buf)
            .map_err(|e| anyhow::anyhow!("encoding {frame:?}: {e:?}"))?;
        host.push(buf[..n].to_vec());
        Ok(())
    };
    encode(&sim.probe.hello())?;
    encode(&Frame::Config(*sim.probe.config()))?;
    let mut now = 0u64;
    while now <= p.duration_us {
        if let Some(s) = sim.step(now) {
            encode(&Frame::Sample(s))?;
            if let Some(f) = sim.probe.take_overrun() {
                encode(&f)?;
            }
        }
        now += 1000;
    }
    ensure!(
        host.len() == p.frames.len(),
        "probe: the host made {} frames, the M4 {}",
        host.len(),
        p.frames.len()
    );
    let mut equal = 0;
    for (k, (h, (m, _))) in host.iter().zip(&p.frames).enumerate() {
        if h == m {
            equal += 1;
        } else if equal == k {
            log::warn!("probe: frame {k} differs: host {h:02x?}, M4 {m:02x?}");
        }
    }
    // The hello and config frames are not samples: their cost is start-up, not per sample.
    let mut instr: Vec<u64> = p.frames.iter().skip(2).map(|(_, i)| *i).collect();
    instr.sort_unstable();
    Ok(ProbeFigures {
        frames: host.len(),
        frames_equal_bytes: equal,
        m4_instructions_per_sample_median: instr.get(instr.len() / 2).copied().unwrap_or(0),
        m4_instructions_per_sample_max: instr.last().copied().unwrap_or(0),
    })
}

/// The cost model: instructions per tick as a + b · tets, fitted by least squares over the models
/// played, for the worst tick and for the median one, each solved for the budget.
#[derive(Debug, Serialize)]
struct CostModel {
    budget_instructions_per_tick: f64,
    worst_fixed_instructions: f64,
    worst_instructions_per_tet: f64,
    largest_tets_by_time_worst: f64,
    median_fixed_instructions: f64,
    median_instructions_per_tet: f64,
    largest_tets_by_time_median: f64,
    storage_bytes_per_tet: f64,
    largest_tets_by_ram: f64,
}

/// Least-squares line y = a + b x.
fn line_fit(pts: &[(f64, f64)]) -> (f64, f64) {
    let n = pts.len() as f64;
    let (sx, sy) = pts.iter().fold((0.0, 0.0), |(a, b), p| (a + p.0, b + p.1));
    let (mx, my) = (sx / n, sy / n);
    let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let sxx: f64 = pts.iter().map(|p| (p.0 - mx) * (p.0 - mx)).sum();
    let b = sxy / sxx;
    (my - b * mx, b)
}

fn cost_model(figs: &[ModelFigures], budget: &Budget) -> Option<CostModel> {
    let sizes: std::collections::BTreeSet<usize> = figs.iter().map(|f| f.tets).collect();
    if sizes.len() < 2 {
        return None;
    }
    let pts = |y: &dyn Fn(&ModelFigures) -> f64| -> Vec<(f64, f64)> {
        figs.iter().map(|f| (f.tets as f64, y(f))).collect()
    };
    let (wa, wb) = line_fit(&pts(&|f| f.m4_instructions_max as f64));
    let (ma, mb) = line_fit(&pts(&|f| f.m4_instructions_median as f64));
    let (ra, rb) = line_fit(&pts(&|f| f.runtime_storage_bytes as f64));
    let b = budget.instructions();
    Some(CostModel {
        budget_instructions_per_tick: b,
        worst_fixed_instructions: wa,
        worst_instructions_per_tet: wb,
        largest_tets_by_time_worst: ((b - wa) / wb).max(0.0),
        median_fixed_instructions: ma,
        median_instructions_per_tet: mb,
        largest_tets_by_time_median: ((b - ma) / mb).max(0.0),
        storage_bytes_per_tet: rb,
        largest_tets_by_ram: (budget.ram_bytes as f64 - ra) / rb,
    })
}

#[derive(Debug, Serialize)]
struct Summary<'a> {
    schema_version: u32,
    budget: Budget,
    timer: &'a str,
    timer_instructions_per_count: f64,
    calibration_loop_instructions: Option<u64>,
    calibration_measured_instructions: Option<u64>,
    models: &'a [ModelFigures],
    probe: Option<ProbeFigures>,
    cost_model: Option<CostModel>,
    must_hold: &'a [String],
    norm2_lanes_instructions_per_element: Option<f64>,
}

fn compare(
    transcript: &Path,
    models: &Path,
    budget: Budget,
    must_hold: &[String],
) -> anyhow::Result<()> {
    let text = std::fs::read_to_string(transcript)
        .with_context(|| format!("reading {}", transcript.display()))?;
    let t = parse(&text).with_context(|| transcript.display().to_string())?;
    ensure!(
        t.instructions_per_count > 0.0,
        "{}: no `m4 timer` line (instructions per timer count)",
        transcript.display()
    );
    let mut figs = Vec::new();
    for name in &t.order {
        figs.push(compare_model(name, &t.runs[name], models, &budget)?);
    }
    let probe = t.probe.as_ref().map(compare_probe).transpose()?;
    let cost = cost_model(&figs, &budget);

    println!(
        "budget: {:.0} MHz / {:.0} Hz at CPI {} = {:.0} instructions per tick",
        budget.mhz,
        budget.rate_hz,
        budget.cpi,
        budget.instructions()
    );
    if let Some((expected, counts)) = t.calibration {
        println!(
            "timer: {} counts one per {} instructions; a {expected}-instruction loop measured {} instructions",
            t.timer,
            t.instructions_per_count,
            counts * t.instructions_per_count as u64
        );
    }
    println!("model        nodes  tets ticks  reaction bits  iters  state   M4 instr/tick (median, max)  cycles@CPI  budget  host µs/tick");
    for f in &figs {
        println!(
            "{:<12} {:>5} {:>5} {:>5} {:>7}/{:<6} {:>5} {:>6} {:>12} {:>12} {:>13.0} {:>6} {:>10.1}",
            f.model,
            f.nodes,
            f.tets,
            f.ticks,
            f.reactions_equal_bits,
            f.ticks,
            f.iterations_equal,
            if f.state_equal_bits { "same" } else { "DIFF" },
            f.m4_instructions_median,
            f.m4_instructions_max,
            f.m4_cycles_max_at_cpi,
            if f.holds_budget { "holds" } else { "misses" },
            f.host_us_median
        );
    }
    if let Some(p) = &probe {
        println!(
            "probe: {}/{} frames with the host's bytes; {} instructions per sample (median), {} (max)",
            p.frames_equal_bytes, p.frames, p.m4_instructions_per_sample_median, p.m4_instructions_per_sample_max
        );
    }
    if let Some(k) = t.kernel {
        println!(
            "f64 accumulation on the M4F: kernel::norm2_lanes over {} f32 took {} instructions ({:.0} per element)",
            k.0,
            k.1,
            k.1 as f64 / k.0 as f64
        );
    }
    if let Some(c) = &cost {
        println!(
            "cost model (least squares over {} models): worst tick ≈ {:.0} + {:.0} × tets, median tick ≈ {:.0} + {:.0} × tets instructions",
            figs.len(),
            c.worst_fixed_instructions,
            c.worst_instructions_per_tet,
            c.median_fixed_instructions,
            c.median_instructions_per_tet
        );
        println!(
            "  → at {:.0} Hz on {:.0} MHz (CPI {}): {:.0} tets by the worst tick, {:.0} by the median; RAM: {:.0} B/tet → {:.0} tets fit {} B",
            budget.rate_hz,
            budget.mhz,
            budget.cpi,
            c.largest_tets_by_time_worst,
            c.largest_tets_by_time_median,
            c.storage_bytes_per_tet,
            c.largest_tets_by_ram,
            budget.ram_bytes
        );
    }
    for f in &figs {
        println!(
            "rate held on the board: {} ({} tets): {:.0} Hz at its worst tick, {:.0} Hz at its median",
            f.model, f.tets, f.rate_held_worst_hz, f.rate_held_median_hz
        );
    }
    let summary = Summary {
        schema_version: 1,
        budget,
        timer: &t.timer,
        timer_instructions_per_count: t.instructions_per_count,
        calibration_loop_instructions: t.calibration.map(|c| c.0),
        calibration_measured_instructions: t
            .calibration
            .map(|c| c.1 * t.instructions_per_count as u64),
        models: &figs,
        probe,
        cost_model: cost,
        must_hold,
        norm2_lanes_instructions_per_element: t.kernel.map(|k| k.1 as f64 / k.0 as f64),
    };
    let mut failures = Vec::new();
    for f in &figs {
        if f.reactions_equal_bits != f.ticks || f.iterations_equal != f.ticks || !f.state_equal_bits
        {
            failures.push(format!(
                "{}: the M4 and the host differ ({} of {} reactions with the same bits, {} iteration counts equal, final state {})",
                f.model,
                f.reactions_equal_bits,
                f.ticks,
                f.iterations_equal,
                if f.state_equal_bits { "same" } else { "different" }
            ));
        }
    }
    if let Some(p) = &summary.probe {
        if p.frames_equal_bytes != p.frames {
            failures.push(format!(
                "probe: {} of {} frames differ from the host's",
                p.frames - p.frames_equal_bytes,
                p.frames
            ));
        }
    } else {
        failures.push("the transcript has no probe run".into());
    }
    for spec in must_hold {
        let (name, hz) = match spec.split_once('@') {
            Some((n, hz)) => (
                n,
                hz.parse::<f64>()
                    .with_context(|| format!("--must-hold {spec}: expected NAME@HZ"))?,
            ),
            None => (spec.as_str(), budget.rate_hz),
        };
        let cycles = budget.mhz * 1e6 / hz;
        match figs.iter().find(|f| f.model == name) {
            Some(f) if f.m4_cycles_max_at_cpi <= cycles => println!(
                "holds: {name}: worst tick {:.0} cycles ≤ {cycles:.0} ({hz} Hz at {} MHz, CPI {})",
                f.m4_cycles_max_at_cpi, budget.mhz, budget.cpi
            ),
            Some(f) => failures.push(format!(
                "{name}: worst tick {} instructions × CPI {} = {:.0} cycles exceeds the {cycles:.0}-cycle budget of {hz} Hz at {} MHz",
                f.m4_instructions_max, budget.cpi, f.m4_cycles_max_at_cpi, budget.mhz
            )),
            None => failures.push(format!("--must-hold {name}: not in the transcript")),
        }
    }
    println!("{}", serde_json::to_string(&summary)?);
    if !failures.is_empty() {
        bail!("{}", failures.join("; "));
    }
    Ok(())
}

//! A haptic session on a serial port: the runtime of a model driven, one solve per arriving
//! batch of force samples, for a set time; what `palpate haptic` prints is the
//! [`SessionReport`] this returns.

use crate::gate::ForceGate;
use crate::haptic::{Contact, HapticLoop};
use crate::port::{open, FrameReader};
use crate::stats::{thread_cpu_seconds, Percentiles};
use crate::{GateDecision, LinkHostError};
use palpate_fem::runtime_storage::Storage;
use palpate_protocol::link::{Frame, LinkStats};
use palpate_protocol::model::ModelRecord;
use palpate_runtime::{RuntimeConfig, SolveStatus};
use std::time::{Duration, Instant};

/// Where the samples come from, for how long, and how the force acts.
#[derive(Debug, Clone, PartialEq)]
pub struct SessionOptions {
    /// The serial device.
    pub port: String,
    /// Its baud rate.
    pub baud: u32,
    /// How long to run (s).
    pub seconds: f64,
    /// The contact the force drives.
    pub contact: Contact,
    /// Samples the gate holds a force through a dropout ([`ForceGate::new`]).
    pub hold: u32,
}

/// What a session measured.
#[derive(Debug, Clone, Copy)]
pub struct SessionReport {
    /// The model's nodes.
    pub nodes: usize,
    /// The model's tetrahedra.
    pub tets: usize,
    /// Frame arrival → solved state (µs).
    pub latency_us: Percentiles,
    /// PCG iterations per solve.
    pub iterations: Percentiles,
    /// Samples gated but superseded by a newer one in the same batch.
    pub superseded: u64,
    /// Solves whose force the gate fed through.
    pub fed: u64,
    /// Solves whose force the gate held through a dropout.
    pub held: u64,
    /// Solves after the gate released the contact.
    pub released: u64,
    /// Solves that did not converge.
    pub unconverged: u64,
    /// The largest relative residual of a solve.
    pub worst_rel_residual: f32,
    /// The link's frame statistics.
    pub stats: LinkStats,
    /// The loop thread's CPU time per wall second, where the platform says.
    pub cpu_fraction: Option<f64>,
}

/// Runs `record` under `config` driven by the force samples arriving on the serial port for
/// `options.seconds`; a probe speaking another protocol version is an error once two seconds
/// have brought no solve.
pub fn run_session(
    record: ModelRecord<'_>,
    config: RuntimeConfig,
    options: &SessionOptions,
) -> Result<SessionReport, LinkHostError> {
    let mut storage = Storage::for_model(&record, &config);
    let rt = storage
        .runtime(record, config)
        .map_err(LinkHostError::Runtime)?;
    let mut hl = HapticLoop::new(rt, ForceGate::new(options.hold, 100.0), options.contact);
    let port = &options.port;
    let mut reader = FrameReader::new(open(port, options.baud, Duration::from_millis(50))?);
    let (mut lat, mut iters) = (Vec::new(), Vec::new());
    let (mut fed, mut held, mut released, mut unconverged) = (0u64, 0u64, 0u64, 0u64);
    let mut worst_res = 0.0f32;
    let mut err = None;
    let t0 = Instant::now();
    let cpu0 = thread_cpu_seconds();
    let mut batch = Vec::new();
    while t0.elapsed().as_secs_f64() < options.seconds && err.is_none() {
        batch.clear();
        let mut arrival = None;
        reader
            .poll(|fr, at| {
                if let Frame::Sample(s) = fr {
                    batch.push(s);
                    arrival = Some(at);
                }
            })
            .map_err(|source| LinkHostError::Io {
                what: "reading",
                path: port.clone(),
                source,
            })?;
        if let Some(at) = arrival {
            // Several samples in one read (the host fell behind): all pass the gate, the newest
            // drives the solve.
            match hl.on_batch(&batch) {
                Ok(Some((d, rep))) => {
                    lat.push(at.elapsed().as_secs_f64() * 1e6);
                    iters.push(f64::from(rep.iterations));
                    worst_res = worst_res.max(rep.rel_residual);
                    unconverged += u64::from(rep.status != SolveStatus::Converged);
                    match d {
                        GateDecision::Feed(_) => fed += 1,
                        GateDecision::Hold(_) => held += 1,
                        GateDecision::Release => released += 1,
                    }
                }
                Ok(None) => {}
                Err(e) => err = Some(e),
            }
        }
        if lat.is_empty() && t0.elapsed() > Duration::from_secs(2) {
            if let Some(e) = reader.version_mismatch(port) {
                return Err(e);
            }
        }
    }
    if let Some(source) = err {
        return Err(LinkHostError::Contact {
            point: options.contact.point,
            source,
        });
    }
    let wall = t0.elapsed().as_secs_f64();
    Ok(SessionReport {
        nodes: hl.runtime.node_count(),
        tets: hl.runtime.element_count(),
        latency_us: Percentiles::of(&mut lat),
        iterations: Percentiles::of(&mut iters),
        superseded: hl.superseded,
        fed,
        held,
        released,
        unconverged,
        worst_rel_residual: worst_res,
        stats: *reader.stats(),
        cpu_fraction: cpu0.zip(thread_cpu_seconds()).map(|(a, b)| (b - a) / wall),
    })
}

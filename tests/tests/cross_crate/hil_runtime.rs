//! Hardware-in-the-loop: simulated probe → pty → host link → force gate → runtime. The probe is
//! pressed past saturation, its converter freezes and stops answering for a while, and the wire
//! corrupts 1 % of the bytes; the runtime must only ever be fed forces the probe vouched for
//! (or the fail-safe zero), and keep solving.

use palpate_fem::block_model::BlockModel;
use palpate_link::faults::FaultPlan;
use palpate_link::gate::ForceGate;
use palpate_link::haptic::{Contact, HapticLoop};
use palpate_link::sender::{AdcFault, AdcFaultKind, Pacing, SenderOptions};
use palpate_probe::sim::{default_config, Profile};
use palpate_protocol::link::status;
use palpate_runtime::material::LambdaAlpha;
use palpate_runtime::{RuntimeConfig, SolveStatus};
use palpate_tests::hil::{assert_link_invariants, run_link};
use palpate_tests::model::Storage;
use std::collections::HashMap;

fn run(fault: AdcFault, hold: u32) {
    // A stiff block (E = 10 MPa: the 250 N the saturated probe can report stays a small strain)
    // of ~200 tets, pressed on the top face centre.
    let model = BlockModel::block(200, LambdaAlpha::from_young_poisson(10e6, 0.3)).unwrap();
    let rec = model.record();
    let cfg = RuntimeConfig {
        max_iterations: 200,
        ..Default::default()
    };
    let mut storage = Storage::for_model(&rec, &cfg);
    let rt = storage.runtime(rec, cfg).unwrap();
    let contact = Contact {
        point: [0.05, 0.05, 0.05],
        direction: [0.0, 0.0, -1.0],
        radius: 0.02,
    };
    // Plausibility limit 300 N: above the ~248 N a saturated reading reports, so only the
    // status flags keep saturated forces out.
    let mut hl = HapticLoop::new(rt, ForceGate::new(hold, 300.0), contact);
    let mut statuses = Vec::new();
    let opts = SenderOptions {
        adc_fault: Some(fault),
        ..SenderOptions::clean(3.0, Pacing::AsFastAsPossible)
    };
    // Presses to 400 N once a second: saturates (≥ 0.99 V_s) above ~248 N.
    let profile = Profile::Press {
        peak: 400.0,
        period_s: 1.0,
    };
    let plan = FaultPlan {
        corrupt: 0.01,
        start_after: 50,
        stop_after: 2950,
        ..Default::default()
    };
    let run = run_link(
        default_config(),
        profile,
        2,
        opts,
        plan,
        11,
        None,
        |batch| {
            // One solve per sample (the sender is paced by the pty's back-pressure, so the runtime
            // sees every sample's gate decision, not only the newest of a read).
            for s in batch {
                let (_, rep) = hl.on_sample(s).expect("runtime accepts the contact");
                statuses.push(rep);
            }
        },
    );
    assert_link_invariants(&run);

    let sent: HashMap<u32, _> = run.sent.samples.iter().map(|s| (s.seq, *s)).collect();
    let trusted = |s: &palpate_protocol::link::ForceSample| s.status & status::UNTRUSTED == 0;
    let flagged = |bit: u8| {
        run.delivered
            .iter()
            .filter(|(s, _)| s.status & bit != 0)
            .count()
    };
    assert!(
        flagged(status::SATURATED) > 100,
        "the presses must saturate the probe"
    );
    match fault.kind {
        AdcFaultKind::Frozen => assert!(
            flagged(status::STUCK) > 50,
            "frozen converter must be flagged stuck"
        ),
        AdcFaultKind::Nack => assert!(
            flagged(status::ADC_ERROR) > 50,
            "NACKing converter must be flagged"
        ),
    }
    // What the runtime was fed: for a trusted sample its own force; otherwise the force of a
    // trusted sample at most `hold` delivered samples earlier, or zero. Never an untrusted one.
    let delivered_seqs: Vec<u32> = run.delivered.iter().map(|(s, _)| s.seq).collect();
    let mut last_trusted: Option<(usize, f32)> = None;
    let mut k = 0;
    // The ring holds the last COMMAND_HISTORY solves; this run is shorter, so it holds them all.
    assert!(
        hl.solves as usize <= palpate_link::haptic::COMMAND_HISTORY,
        "the run outgrew the command history"
    );
    for &(seq, force) in hl.commanded.oldest_ordered() {
        while k < delivered_seqs.len() && delivered_seqs[k] <= seq {
            let s = sent[&delivered_seqs[k]];
            if trusted(&s) && s.force_n <= 300.0 {
                last_trusted = Some((k, s.force_n));
            }
            k += 1;
        }
        let s = sent[&seq];
        if trusted(&s) {
            assert_eq!(force, s.force_n, "seq {seq}: trusted sample not fed as is");
        } else if force != 0.0 {
            let (at, f) = last_trusted.expect("a held force needs an earlier trusted one");
            assert_eq!(
                force, f,
                "seq {seq}: fed {force} N from an untrusted sample {s:?}"
            );
            assert!(
                k - 1 - at <= hold as usize,
                "seq {seq}: held for {} samples > {hold}",
                k - 1 - at
            );
        }
    }
    let held = hl
        .commanded
        .oldest_ordered()
        .filter(|(q, f)| !trusted(&sent[q]) && *f != 0.0)
        .count();
    let released = hl
        .commanded
        .oldest_ordered()
        .filter(|(q, f)| !trusted(&sent[q]) && *f == 0.0)
        .count();
    eprintln!(
        "{:?}: {} delivered, {} solves ({} superseded), {} on untrusted samples held, {} released",
        fault.kind,
        run.delivered.len(),
        hl.solves,
        hl.superseded,
        held,
        released
    );
    assert_eq!(
        hl.solves as usize,
        run.delivered.len(),
        "one solve per delivered sample"
    );
    assert!(
        held > 0 && released > 0,
        "both the hold and the release path must be exercised"
    );
    // The runtime kept solving: every tick converged or used its budget with finite results.
    assert!(
        statuses
            .iter()
            .all(|r| r.rel_residual.is_finite() && r.status != SolveStatus::Rejected),
        "bad tick"
    );
    assert!(hl.runtime.displacements().iter().all(|x| x.is_finite()));
}

#[test]
fn frozen_converter_saturation_and_corruption_never_reach_the_runtime() {
    run(
        AdcFault {
            at_s: 1.2,
            duration_s: 0.5,
            kind: AdcFaultKind::Frozen,
        },
        20,
    );
}

#[test]
fn nacking_converter_is_held_then_released() {
    run(
        AdcFault {
            at_s: 1.2,
            duration_s: 0.3,
            kind: AdcFaultKind::Nack,
        },
        20,
    );
}

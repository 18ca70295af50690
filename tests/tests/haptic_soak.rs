//! A soak of the haptic path: millions of force samples — ordinary, extreme and non-finite, with
//! dropped frames and the sequence number wrapping past u32::MAX — encoded as link frames, decoded
//! by the receiver, gated and solved by the runtime, fast-forwarded (no real-time pacing).
//!
//! Asserts what a session that runs for hours needs: after start-up nothing on the solving thread
//! allocates (a counting global allocator watches it), the state stays finite, the force fed to
//! the runtime stays within the gate's bound, and the link's counters account for every sample.
//! `PALPATE_SOAK_SAMPLES` sets the count (default 10⁶ here; BENCHMARKS.md has a 10⁷ run).

use palpate_fem::mesh::boxmesh::box_mesh;
use palpate_link::gate::ForceGate;
use palpate_link::haptic::{Contact, HapticLoop};
use palpate_protocol::link::codec::encode;
use palpate_protocol::link::{ForceSample, Frame, Receiver, MAX_FRAME_ENCODED};
use palpate_runtime::material::LambdaAlpha;
use palpate_runtime::{RuntimeConfig, SolveStatus};
use palpate_tests::alloc_watch::{self, Counting};
use palpate_tests::model::{self, Storage};

#[global_allocator]
static GLOBAL: Counting = Counting;

/// SplitMix64: the soak's own stream (reproducible, no allocation).
struct Stream(u64);
impl Stream {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    fn uniform(&mut self) -> f32 {
        (self.next() >> 40) as f32 / (1u64 << 24) as f32
    }
}

/// Resident set size of this process (bytes), from /proc.
fn rss_bytes() -> Option<usize> {
    let s = std::fs::read_to_string("/proc/self/statm").ok()?;
    let pages: usize = s.split_whitespace().nth(1)?.parse().ok()?;
    Some(pages * 4096)
}

#[test]
fn millions_of_samples_through_link_and_runtime_in_fixed_memory() {
    let samples: u64 = std::env::var("PALPATE_SOAK_SAMPLES")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1_000_000);
    let m = box_mesh([0.04, 0.04, 0.02], [2, 2, 1]);
    let fixed = m.group("bottom").unwrap().to_vec();
    let p = LambdaAlpha::from_young_poisson(10_000.0, 0.3);
    let buf = model::homogeneous(&m, &fixed, p.lambda, p.alpha);
    let cfg = RuntimeConfig {
        max_iterations: 100,
        ..Default::default()
    };
    let rec = buf.record();
    let mut storage = Storage::for_model(&rec, &cfg);
    let rt = storage.runtime(rec, cfg).unwrap();
    const MAX_FORCE: f32 = 100.0;
    let mut hl = HapticLoop::new(
        rt,
        ForceGate::new(20, MAX_FORCE),
        Contact {
            point: [0.02, 0.02, 0.02],
            direction: [0.0, 0.0, -1.0],
            radius: 0.015,
        },
    );
    let mut rx: Receiver = Receiver::new();
    let mut stream = Stream(12);
    let mut frame = [0u8; MAX_FRAME_ENCODED];
    let mut batch: heapless::Vec<ForceSample, 8> = heapless::Vec::new();
    // Start near the end of the sequence space: the wrap is part of every run.
    let mut seq: u32 = u32::MAX - 5_000;
    let (mut sent, mut dropped, mut solves, mut nonfinite_in) = (0u64, 0u64, 0u64, 0u64);
    let (mut max_u, mut max_reaction) = (0f32, 0f32);
    let mut rss_after_warmup = None;
    let t0 = std::time::Instant::now();
    for k in 0..samples {
        if k == 10_000 {
            // Warmed up: from here on the solving thread must not allocate.
            rss_after_warmup = rss_bytes();
            alloc_watch::watch(true);
        }
        let r = stream.uniform();
        let force_n = match (stream.next() % 1000) as u32 {
            0 => f32::NAN,
            1 => f32::INFINITY,
            2 => f32::NEG_INFINITY,
            3 => 1e30,
            4 => -1e30,
            5..=9 => 1e6 * r,
            _ => 5.0 * r,
        };
        let s = ForceSample {
            seq,
            timestamp_us: k * 1000,
            raw_counts: (r * 2000.0) as i16,
            force_n,
            status: if stream.next().is_multiple_of(5000) {
                1
            } else {
                0
            },
        };
        seq = seq.wrapping_add(1);
        // One frame in 2,000 is lost on the wire.
        if stream.next().is_multiple_of(2000) {
            dropped += 1;
            continue;
        }
        batch.clear();
        if force_n.is_finite() {
            let n = encode(&Frame::Sample(s), &mut frame).expect("a sample frame fits");
            sent += 1;
            rx.push_slice(&frame[..n], |fr| {
                if let Frame::Sample(s) = fr {
                    let _ = batch.push(s);
                }
            });
        } else {
            // The link refuses to encode (and the receiver to deliver) a non-finite force; fed
            // straight to the loop, as a host-side bug would, it must still never reach the
            // runtime. On the wire its sequence number is a gap.
            nonfinite_in += 1;
            let _ = batch.push(s);
        }
        if let Some((decision, rep)) = hl.on_batch(&batch).expect("the tick runs") {
            solves += 1;
            let fed = decision.force_n();
            assert!(
                fed.is_finite() && fed.abs() <= MAX_FORCE,
                "fed {fed} N at sample {k}"
            );
            assert!(
                rep.status != SolveStatus::Rejected,
                "tick rejected at sample {k}"
            );
            let reaction = rep.reaction.iter().map(|v| v * v).sum::<f32>().sqrt();
            assert!(reaction.is_finite(), "reaction at sample {k}");
            max_reaction = max_reaction.max(reaction);
        }
        if k % 4096 == 0 {
            let um = hl
                .runtime
                .displacements()
                .iter()
                .fold(0f32, |a, v| a.max(v.abs()));
            assert!(um.is_finite(), "displacement not finite at sample {k}");
            max_u = max_u.max(um);
        }
    }
    alloc_watch::watch(false);
    let seconds = t0.elapsed().as_secs_f64();
    let allocations = alloc_watch::allocations();
    let st = *rx.stats();
    let rss_end = rss_bytes();
    eprintln!(
        "soak: {samples} samples ({sent} sent, {dropped} dropped, {nonfinite_in} non-finite) → {solves} solves in {seconds:.1} s ({:.2} µs/sample); allocations after warm-up {allocations}; max |u| {max_u:.3e} m, max probe reaction {max_reaction:.3} N; link {st:?}; RSS {rss_after_warmup:?} → {rss_end:?} bytes",
        1e6 * seconds / samples as f64
    );
    assert_eq!(allocations, 0, "the haptic path allocated after start-up");
    assert_eq!(
        solves,
        sent + nonfinite_in,
        "one solve per delivered sample"
    );
    assert_eq!(st.samples, sent);
    assert_eq!(
        st.missing_samples,
        dropped + nonfinite_in,
        "every frame not on the wire counted, across the wrap"
    );
    assert_eq!(st.rejected(), 0);
    // The gate bounds the force (100 N on a 4 × 4 × 2 cm block of 10 kPa is a huge press, but a
    // bounded one): no node moves more than the block's own diagonal.
    let diagonal = (0.04f32 * 0.04 + 0.04 * 0.04 + 0.02 * 0.02).sqrt();
    assert!(
        max_u < diagonal,
        "displacements bounded by the gate: {max_u} m"
    );
    if let (Some(a), Some(b)) = (rss_after_warmup, rss_end) {
        assert!(b <= a + (1 << 20), "resident memory grew: {a} → {b} bytes");
    }
}

//! The storage a model asks for is the storage it runs in: for every configuration that sizes a
//! room differently (kernel, coarse space, anticipated rim crossings, strain-space blending), a
//! runtime in pools of exactly [`StorageRequirement::for_model`] values runs loaded and probed
//! ticks to the same displacements as one in roomy pools, and one value short is refused up front
//! with what was needed and what was given.
//!
//! Why this and not a sum of constants: an array sized one room too small shows only when a tick
//! indexes past it (a panic in the exactly-sized run), and a requirement larger than what is
//! carved shows only as a refusal the caller cannot explain. The per-node and per-element
//! constants are derived from the same layout, so comparing them with hand-written sums checks
//! nothing the compiler does not.

use palpate_fem::mesh::boxmesh::box_mesh;
use palpate_runtime::material::LambdaAlpha;
use palpate_runtime::{Kernel, Probe, Runtime, RuntimeConfig, RuntimeError, StorageRequirement};
use palpate_tests::model::{self, ModelBuffers};

/// A block on its fixed bottom, with one parameter set or two blended in strain space.
fn block(strain_blend: bool) -> ModelBuffers {
    let m = box_mesh([0.1, 0.1, 0.05], [4, 4, 2]);
    let fixed = m.group("bottom").unwrap().to_vec();
    let p0 = LambdaAlpha::from_young_poisson(10_000.0, 0.3);
    if !strain_blend {
        return model::homogeneous(&m, &fixed, p0.lambda, p0.alpha);
    }
    let p1 = LambdaAlpha::from_young_poisson(30_000.0, 0.3);
    let eps = [0.0, 0.0, -0.02, 0.0, 0.0, 0.01];
    model::strain_blend(&m, &fixed, [p0, p1], eps, |_, _| [0.5, 0.5])
}

/// The configurations that change what the layout carves.
fn configs() -> Vec<(&'static str, bool, RuntimeConfig)> {
    let d = RuntimeConfig::default();
    vec![
        ("default", false, d),
        (
            "packed kernel",
            false,
            RuntimeConfig {
                kernel: Kernel::Packed,
                ..d
            },
        ),
        (
            "coarse space of 16 aggregates",
            false,
            RuntimeConfig {
                coarse_aggregates: 16,
                ..d
            },
        ),
        (
            "anticipated rim crossings",
            false,
            RuntimeConfig {
                anticipation_iterations: 4,
                ..d
            },
        ),
        ("strain-space blend", true, d),
    ]
}

/// Ticks under a contact force sliding in steps (each held for a few ticks, so that the still
/// ticks plan the next rim crossings where anticipation is on), then under a sphere probe; the
/// displacements after each phase.
fn run(rt: &mut Runtime<'_>) -> Vec<Vec<f32>> {
    let mut out = Vec::new();
    for k in 0..12 {
        let x = 0.03 + 0.004 * k as f32;
        rt.set_contact_force([x, 0.05, 0.05], [0.0, 0.0, -0.4], 0.02)
            .unwrap();
        for _ in 0..4 {
            rt.tick();
        }
    }
    out.push(rt.displacements().to_vec());
    rt.reset();
    rt.set_probe(Probe::Sphere {
        center: [0.05, 0.05, 0.05 + 0.015 - 0.002],
        radius: 0.015,
    })
    .unwrap();
    for _ in 0..6 {
        rt.tick();
    }
    out.push(rt.displacements().to_vec());
    out
}

#[test]
fn a_runtime_runs_in_exactly_the_storage_it_asks_for() {
    for (name, strain, cfg) in configs() {
        let buf = block(strain);
        let need = StorageRequirement::for_model(&buf.record(), &cfg);

        // Roomy pools, filled with garbage the runtime must overwrite before it reads.
        let (mut f_big, mut u_big) = (
            vec![f32::NAN; need.f32s + 4096],
            vec![u32::MAX; need.u32s + 4096],
        );
        let mut roomy = Runtime::new(buf.record(), &mut f_big, &mut u_big, cfg).unwrap();
        let expected = run(&mut roomy);
        assert!(
            expected.iter().flatten().all(|v| v.is_finite())
                && expected[0].iter().any(|v| v.abs() > 1e-6),
            "{name}: the roomy run did not deform the block"
        );

        // Exactly the requirement: nothing indexes past a room, nothing differs.
        let (mut f, mut u) = (vec![f32::NAN; need.f32s], vec![u32::MAX; need.u32s]);
        let mut exact = Runtime::new(buf.record(), &mut f, &mut u, cfg).unwrap();
        assert_eq!(
            run(&mut exact),
            expected,
            "{name}: exact pools ran differently"
        );
    }
}

#[test]
fn one_value_short_is_refused_with_what_was_needed() {
    for (name, strain, cfg) in configs() {
        let buf = block(strain);
        let need = StorageRequirement::for_model(&buf.record(), &cfg);
        assert_eq!(need.bytes(), 4 * (need.f32s + need.u32s));

        let (mut f, mut u) = (vec![0f32; need.f32s - 1], vec![0u32; need.u32s]);
        match Runtime::new(buf.record(), &mut f, &mut u, cfg) {
            Err(e) => assert_eq!(
                e,
                RuntimeError::CapacityExceeded {
                    what: "f32",
                    needed: need.f32s,
                    available: need.f32s - 1
                },
                "{name}"
            ),
            Ok(_) => panic!("{name}: an f32 pool one value short was accepted"),
        }
        let (mut f, mut u) = (vec![0f32; need.f32s], vec![0u32; need.u32s - 1]);
        match Runtime::new(buf.record(), &mut f, &mut u, cfg) {
            Err(e) => assert_eq!(
                e,
                RuntimeError::CapacityExceeded {
                    what: "u32",
                    needed: need.u32s,
                    available: need.u32s - 1
                },
                "{name}"
            ),
            Ok(_) => panic!("{name}: a u32 pool one value short was accepted"),
        }
    }
}

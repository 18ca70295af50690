//! The runtime allocates nothing after construction: a counting global allocator watches
//! thousands of ticks with moving force-driven and position-driven contacts.
//!
//! Only allocations made on the thread that runs the ticks count: the test harness's own
//! thread allocates now and then (a few small blocks, at times that depend on how long the
//! test takes), and those are not the runtime's.

use palpate_fem::mesh::boxmesh::box_mesh;
use palpate_runtime::material::LambdaAlpha;
use palpate_runtime::{ContactRule, Probe, RuntimeConfig};
use palpate_tests::alloc_watch::{self, Counting};
use palpate_tests::model::{self, Storage};

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn thousands_of_ticks_allocate_nothing() {
    let m = box_mesh([0.1, 0.1, 0.05], [6, 6, 3]);
    let fixed = m.group("bottom").unwrap().to_vec();
    let p = LambdaAlpha::from_young_poisson(10_000.0, 0.3);
    let buf = model::homogeneous(&m, &fixed, p.lambda, p.alpha);
    // The watch works: a Vec made on this thread while watched is counted.
    alloc_watch::watch(true);
    let probe: Vec<u8> = std::hint::black_box(Vec::with_capacity(16));
    alloc_watch::watch(false);
    drop(probe);
    assert_eq!(alloc_watch::take_allocations(), 1);
    // Both force-driven contact rules (the consistent one integrates rim triangles every tick).
    for rule in [ContactRule::Lumped, ContactRule::Consistent] {
        let cfg = RuntimeConfig {
            load_step: 0.05,
            probe_step: 1e-4,
            contact_rule: rule,
            ..Default::default()
        };
        let mut storage = Storage::for_model(&buf.record(), &cfg);
        let mut rt = storage.runtime(buf.record(), cfg).unwrap();
        let before = alloc_watch::allocations();
        alloc_watch::watch(true);
        let (mut solved, mut ahead) = (0, 0);
        for k in 0..3000 {
            let s = k as f32 / 3000.0;
            if k < 1500 {
                rt.set_contact_force([0.02 + 0.06 * s, 0.05, 0.05], [0.0, 0.0, -0.5], 0.015)
                    .unwrap();
            } else {
                if k == 1500 {
                    rt.clear_loads();
                }
                rt.set_probe(Probe::Sphere {
                    center: [0.05, 0.02 + 0.06 * s, 0.058],
                    radius: 0.01,
                })
                .unwrap();
            }
            let rep = rt.tick();
            solved += rep.iterations;
            ahead += rep.iterations_ahead;
        }
        alloc_watch::watch(false);
        let after = alloc_watch::allocations();
        assert_eq!(
            after - before,
            0,
            "{rule:?}: the runtime allocated {} times during 3000 ticks",
            after - before
        );
        assert!(solved > 0);
        // The lumped probe's rim crossings were solved ahead (`anticipate.rs`) in these ticks too.
        assert_eq!(
            ahead > 0,
            rule == ContactRule::Lumped,
            "{rule:?}: {ahead} iterations ahead"
        );
        // The sphere really pressed the surface in the position-driven half.
        assert!(rt.reaction()[2] > 0.0, "reaction {:?}", rt.reaction());
    }
}

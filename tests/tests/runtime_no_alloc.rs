//! The runtime allocates nothing after construction: a counting global allocator watches
//! thousands of ticks with moving force-driven and position-driven contacts.
//!
//! Only allocations made on the thread that runs the ticks count: the test harness's own
//! thread allocates now and then (a few small blocks, at times that depend on how long the
//! test takes), and those are not the runtime's.

use palpate_fem::mesh::boxmesh::box_mesh;
use palpate_runtime::material::LambdaAlpha;
use palpate_runtime::{ContactRule, Probe, Runtime, RuntimeConfig, StorageRequirement};
use palpate_tests::model;
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicUsize, Ordering};

struct Counting;
static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);
std::thread_local! {
    /// Set on the ticking thread while it is watched (const-initialised: reading it from the
    /// allocator never allocates).
    static WATCHED: Cell<bool> = const { Cell::new(false) };
}

fn count() {
    if WATCHED.with(|w| w.get()) {
        ALLOCATIONS.fetch_add(1, Ordering::SeqCst);
    }
}

#[allow(unsafe_code)]
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count();
        // SAFETY: forwards to the system allocator with the caller's layout.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: ptr was allocated by System.alloc with this layout.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count();
        // SAFETY: forwards to the system allocator.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn thousands_of_ticks_allocate_nothing() {
    let m = box_mesh([0.1, 0.1, 0.05], [6, 6, 3]);
    let fixed = m.group("bottom").unwrap().to_vec();
    let p = LambdaAlpha::from_young_poisson(10_000.0, 0.3);
    let buf = model::homogeneous(&m, &fixed, p.lambda, p.alpha);
    // The watch works: a Vec made on this thread while watched is counted.
    WATCHED.with(|w| w.set(true));
    let probe: Vec<u8> = std::hint::black_box(Vec::with_capacity(16));
    WATCHED.with(|w| w.set(false));
    drop(probe);
    assert_eq!(ALLOCATIONS.swap(0, Ordering::SeqCst), 1);
    // Both force-driven contact rules (the consistent one integrates rim triangles every tick).
    for rule in [ContactRule::Lumped, ContactRule::Consistent] {
        let cfg = RuntimeConfig {
            load_step: 0.05,
            probe_step: 1e-4,
            contact_rule: rule,
            ..Default::default()
        };
        let need = StorageRequirement::for_model(&buf.record(), &cfg);
        let (mut fs, mut us) = (vec![0f32; need.f32s], vec![0u32; need.u32s]);
        let mut rt = Runtime::new(buf.record(), &mut fs, &mut us, cfg).unwrap();
        let before = ALLOCATIONS.load(Ordering::SeqCst);
        WATCHED.with(|w| w.set(true));
        let mut solved = 0;
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
        }
        WATCHED.with(|w| w.set(false));
        let after = ALLOCATIONS.load(Ordering::SeqCst);
        assert_eq!(
            after - before,
            0,
            "{rule:?}: the runtime allocated {} times during 3000 ticks",
            after - before
        );
        assert!(solved > 0);
        // The sphere really pressed the surface in the position-driven half.
        assert!(rt.reaction()[2] > 0.0, "reaction {:?}", rt.reaction());
    }
}

//! A counting global allocator for the no-allocation tests: it forwards to the system allocator
//! and counts the allocations (and reallocations) made on a thread while that thread is watched.
//!
//! Only the watched thread counts: the test harness's own thread allocates now and then (a few
//! small blocks, at times that depend on how long the test takes), and those are not the code
//! under test's. Each test binary installs it itself:
//!
//! ```ignore
//! #[global_allocator]
//! static GLOBAL: palpate_tests::alloc_watch::Counting = palpate_tests::alloc_watch::Counting;
//! ```

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicUsize, Ordering};

/// The counting allocator (install it with `#[global_allocator]` in the test binary).
pub struct Counting;

static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

std::thread_local! {
    /// Set on the watched thread (const-initialised: reading it from the allocator never
    /// allocates).
    static WATCHED: Cell<bool> = const { Cell::new(false) };
}

/// Starts (`true`) or stops (`false`) counting the allocations made on this thread.
pub fn watch(on: bool) {
    WATCHED.with(|w| w.set(on));
}

/// The allocations counted so far.
pub fn allocations() -> usize {
    ALLOCATIONS.load(Ordering::SeqCst)
}

/// The allocations counted so far, resetting the count to zero.
pub fn take_allocations() -> usize {
    ALLOCATIONS.swap(0, Ordering::SeqCst)
}

fn count() {
    if WATCHED.with(|w| w.get()) {
        ALLOCATIONS.fetch_add(1, Ordering::SeqCst);
    }
}

#[allow(unsafe_code)]
// SAFETY: every call forwards to the system allocator with the caller's arguments.
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

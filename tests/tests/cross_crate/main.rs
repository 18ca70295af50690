//! The tests that cross crates (a crate's own tests live in its `tests/` folder), one module per
//! subject, linked into one test binary: each separate integration-test file is its own
//! executable linked against every palpate crate, and linking them one by one cost CI more than
//! running them. The tests that install a counting global
//! allocator (`haptic_soak`, `readers_fuzz`, `runtime_no_alloc`) stay in binaries of their own,
//! so that no other test's allocations are counted.

mod capture_import;
mod contact_rule;
mod diagnose_export;
mod diagnose_independent_motion;
mod hil_link;
mod hil_runtime;
mod mesh_error;
mod motion_export;
mod runtime_anticipation;
mod runtime_evidence;
mod runtime_match_replay;
mod runtime_model_checks;
mod runtime_solver;
mod runtime_storage;
mod static_export_runtime;

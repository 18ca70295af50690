//! The cross-crate tests, one module per subject, linked into one test binary: each separate
//! integration-test file is its own executable linked against every palpate crate, and linking
//! twenty-odd of them cost CI more than running them. The tests that install a counting global
//! allocator (`haptic_soak`, `readers_fuzz`, `runtime_no_alloc`) stay in binaries of their own,
//! so that no other test's allocations are counted.

mod capture_import;
mod contact_rule;
mod diagnose_contact;
mod diagnose_curve;
mod diagnose_effects;
mod diagnose_equilibrium;
mod diagnose_export;
mod diagnose_gravity;
mod diagnose_independent;
mod diagnose_motion;
mod diagnose_noise;
mod diagnose_power;
mod diagnose_runs;
mod diagnose_sensitivity;
mod diagnose_sweep;
mod hil_link;
mod hil_runtime;
mod mesh_error;
mod motion_export;
mod runtime_anticipation;
mod runtime_evidence;
mod runtime_model_checks;
mod runtime_solver;
mod runtime_storage;
mod specimen_viscous;
mod static_export_runtime;

//! The `palpate` program's tests, one module per subject, linked into one test binary: each
//! integration-test file is its own executable linked against the program's dependencies, and
//! linking a dozen of them cost CI more than running their tests. A new subject is a new file
//! here and a `mod` line below (a file directly in `tests/` would be a binary of its own).

mod common;

mod cli_for_people;
mod csv_readers;
mod demo_readme;
mod diagnose_scan;
mod export_runtime;
mod fit_scan;
mod hostile_fuzz;
mod hostile_inputs;
mod import_steps;
mod mesh_convergence;
mod progress;
mod readme_facts;
mod refuses_nonsense;
mod scan_import;
mod vocabulary;
mod vtu_other_readers;

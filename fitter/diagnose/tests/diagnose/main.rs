//! The diagnosis' tests that run whole diagnoses (the unit tests sit beside their code), linked
//! into one binary: the static diagnosis on specimens with one injected effect each, on the
//! independent generator's datasets and on its noise and power limits; the motion, runs and
//! curve diagnoses. The specimens (`palpate-specimen`) are a dev-dependency: the stand-in objects
//! with a known truth the diagnosis is scored against.

mod support;

mod diagnose_contact;
mod diagnose_curve;
mod diagnose_effects;
mod diagnose_equilibrium;
mod diagnose_gravity;
mod diagnose_independent;
mod diagnose_mesh_null;
mod diagnose_motion;
mod diagnose_noise;
mod diagnose_power;
mod diagnose_runs;
mod diagnose_runs_clamp;
mod diagnose_runs_creep;
mod diagnose_scans;
mod diagnose_screen;
mod diagnose_sensitivity;
mod diagnose_tilt_responses;
mod diagnose_viscosity_form;
mod runtime_match;
mod specimen_viscous;

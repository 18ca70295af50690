#![cfg_attr(not(test), no_std)]
#![deny(missing_docs)]
//! palpate's runtime: the forward model that the fitter fits and the haptic loop plays back.
//!
//! A fixed-memory, allocation-free, warped-stiffness (corotational) linear FEM after Bächer 2008
//! (seed 000): element kernels, per-element rotations, incremental loading and a preconditioned
//! conjugate-gradient solve per tick, loaded from a `palpate-protocol` model.

pub mod contact_rule;
pub mod element;
pub mod material;
pub mod rotation;

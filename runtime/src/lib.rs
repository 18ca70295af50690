#![cfg_attr(not(test), no_std)]
#![deny(missing_docs)]
//! palpate's runtime: the forward model that the fitter fits and the haptic loop plays back.
//!
//! A fixed-memory, allocation-free, warped-stiffness (corotational) linear FEM after Bächer 2008
//! (seed 000): element kernels, per-element rotations, incremental loading and a preconditioned
//! conjugate-gradient solve per tick, loaded from a `palpate-protocol` model.
//!
//! ```text
//! let record = palpate_protocol::model::decode(&bytes)?;
//! let cfg = RuntimeConfig::default();
//! let need = StorageRequirement::for_model(&record, &cfg);
//! let (mut f, mut u) = (vec![0f32; need.f32s], vec![0u32; need.u32s]); // once, at start-up
//! let mut rt = Runtime::new(record, &mut f, &mut u, cfg)?;
//! rt.set_contact_force([0.05, 0.05, 0.05], [0.0, 0.0, -0.5], 0.015)?;
//! loop { let report = rt.tick(); /* render report.reaction … */ }
//! ```

pub mod anticipate;
pub mod blend;
pub mod coarse;
pub mod config;
pub mod contact_rule;
mod contact_set;
pub mod dense;
pub mod element;
mod element_state;
pub mod error;
pub mod kernel;
pub mod material;
mod nodes;
pub mod pcg;
pub mod rotation;
mod runtime;
mod stiffness;
pub mod storage;
mod tick;
mod two_level;

pub use config::{Kernel, Preconditioner, RuntimeConfig};
pub use contact_rule::ContactRule;
pub use contact_set::Probe;
pub use error::RuntimeError;
pub use runtime::Runtime;
pub use storage::StorageRequirement;
pub use tick::{SolveStatus, TickReport};

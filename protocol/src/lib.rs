#![cfg_attr(not(test), no_std)]
#![deny(missing_docs)]
//! palpate's byte formats, `no_std` and allocation-free:
//!
//! - [`model`]: the compact, versioned model the fitter exports and the runtime loads
//!   (postcard inside a checked container; see `MODEL-FORMAT.md`).
//! - [`link`]: the probe's wire protocol (postcard + COBS + CRC-32 frames; see `LINK-FORMAT.md`).
//!
//! The host-only feature `alloc` adds owned storage for a model record (`model::OwnedModel`),
//! shared by the fitter's export and these tests; the firmware builds without it.

#[cfg(feature = "alloc")]
extern crate alloc;

pub mod link;
pub mod model;

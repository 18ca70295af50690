#![cfg_attr(not(test), no_std)]
#![deny(missing_docs)]
//! palpate's byte formats, `no_std` and allocation-free:
//!
//! - [`model`]: the compact, versioned model the fitter exports and the runtime loads
//!   (postcard inside a checked container; see `MODEL-FORMAT.md`).
//! - [`link`]: the probe's wire protocol (postcard + COBS + CRC-32 frames; see `LINK-FORMAT.md`).

pub mod link;
pub mod model;

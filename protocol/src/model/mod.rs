//! The model format: a [`ModelRecord`] encoded with postcard inside a checked container
//! (magic, version, length, CRC-32). See `protocol/MODEL-FORMAT.md`.

mod record;

pub use record::*;

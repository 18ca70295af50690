//! The model format: a [`ModelRecord`] encoded with postcard inside a checked container
//! (magic, version, length, CRC-32). See `protocol/MODEL-FORMAT.md`.

mod codec;
mod container;
mod error;
mod record;
mod validate;

pub use codec::{decode, encode, encoded_len};
pub use container::{CRC_LEN, HEADER_LEN, KIND_MODEL, MAGIC};
pub use error::{Capacity, Field, Invalid, MalformedKind, ModelError};
pub use record::*;
pub use validate::{validate, MIN_RELATIVE_AREA, MIN_RELATIVE_VOLUME};

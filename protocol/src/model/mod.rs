//! The model format: a [`ModelRecord`] encoded with postcard inside a checked container
//! (magic, version, length, CRC-32). See `protocol/MODEL-FORMAT.md` for the exact bytes.
//!
//! - [`encode`] validates a record and writes it into the caller's buffer ([`encoded_len`] says
//!   how big it must be); nothing invalid is ever written.
//! - [`decode`] checks the container, borrows every array and string from the input (no
//!   allocation, no copy) and [`validate`]s the record: **a model that decodes is safe to run**.
//!   The one check that needs memory — every free node belongs to a tetrahedron — is
//!   [`validate_node_coverage`], with one bit of caller scratch per node; a loader should run it
//!   when it sizes its storage.
//! - Every failure is one variant of [`ModelError`], saying what and where.
//!
//! ```
//! use palpate_protocol::model::*;
//!
//! // The unit corner tetrahedron with its bottom face fixed, no allocation anywhere.
//! let mut rest = [0u8; 48];
//! write_f32s(&[0., 0., 0., 1., 0., 0., 0., 1., 0., 0., 0., 1.], &mut rest).unwrap();
//! let (mut tags, mut tets, mut fixed) = ([0u8; 16], [0u8; 16], [0u8; 12]);
//! write_u32s(&[1, 2, 3, 4], &mut tags).unwrap();
//! write_u32s(&[0, 1, 2, 3], &mut tets).unwrap();
//! write_u32s(&[0, 1, 2], &mut fixed).unwrap();
//! // The fitter stores C_e and D_e from `palpate_runtime::element::element_cd`; zeros keep
//! // this example short (validation only needs them finite with C_e's diagonal ≥ 0).
//! let (c, d) = ([0u8; 4 * 78], [0u8; 4 * 78]);
//! let (mut lambda, mut alpha) = ([0u8; 4], [0u8; 4]);
//! write_f32s(&[20_000.0], &mut lambda).unwrap(); // Pa
//! write_f32s(&[6_000.0], &mut alpha).unwrap(); // ν = α/λ = 0.3
//! let record = ModelRecord {
//!     units: Units::Si,
//!     provenance: Provenance { tool: "example", created: "2026-11-22", source: "-", notes: "" },
//!     node_count: 4,
//!     element_count: 1,
//!     rest_positions: F32s(&rest),
//!     node_tags: U32s(&tags),
//!     tets: U32s(&tets),
//!     fixed_nodes: U32s(&fixed),
//!     surface_triangles: U32s(&[]),
//!     c_packed: F32s(&c),
//!     d_packed: F32s(&d),
//!     parameters: ParameterSets {
//!         layout: ParameterLayout::Global,
//!         count: 1,
//!         lambda: F32s(&lambda),
//!         alpha: F32s(&alpha),
//!     },
//!     blend: Blend::None,
//! };
//!
//! let mut buf = [0u8; 1024];
//! let n = encode(&record, &mut buf)?;
//! assert_eq!(n, encoded_len(&record)?);
//! assert_eq!(decode(&buf[..n])?, record);
//!
//! // Corruption is a typed error, never a panic.
//! buf[40] ^= 0x10;
//! assert!(matches!(decode(&buf[..n]), Err(ModelError::CrcMismatch { .. })));
//! assert_eq!(
//!     decode(&buf[..n - 1]),
//!     Err(ModelError::Truncated { needed: n, available: n - 1 })
//! );
//! # Ok::<(), ModelError>(())
//! ```

mod codec;
mod container;
mod error;
#[cfg(feature = "alloc")]
mod owned;
mod record;
mod validate;

pub use codec::{decode, encode, encoded_len};
pub use container::{CRC_LEN, HEADER_LEN, KIND_MODEL, MAGIC};
pub use error::{Capacity, Field, Invalid, MalformedKind, ModelError};
#[cfg(feature = "alloc")]
pub use owned::{OwnedBlend, OwnedModel};
pub use record::*;
pub use validate::{
    node_coverage_scratch_len, validate, validate_node_coverage, MIN_RELATIVE_AREA,
    MIN_RELATIVE_VOLUME,
};

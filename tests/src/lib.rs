//! Shared helpers for palpate's cross-crate and hardware-in-the-loop tests (see `tests/tests/`).

pub mod model;
pub mod hil;

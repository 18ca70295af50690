//! Shared helpers for palpate's cross-crate and hardware-in-the-loop tests (see `tests/tests/`).

pub mod alloc_watch;
pub mod hil;
pub mod model;
pub mod motion;
pub mod settle;

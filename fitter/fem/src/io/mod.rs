//! File output helpers shared by every command: nothing is lost on a crash or error.

pub mod atomic;
pub mod csv;
pub mod json;
pub mod text;
pub use text::{parse_vec3, parse_vec3_f64};

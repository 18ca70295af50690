//! palpate's offline side: mesh and dataset I/O, the static (seed 000) and motion (seed 001)
//! fitters, the residual diagnosis, and the `palpate` command-line program's subcommands.

pub mod cli;
pub mod dataset;
pub mod export;
pub mod forward;
pub mod static_fit;
pub mod fsr;
pub mod io;
pub mod link;
pub mod mesh;
pub mod report;
pub mod plot;
pub mod motion;
pub mod specimen;
pub mod diagnose;

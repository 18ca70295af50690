//! palpate's offline side: mesh and dataset I/O, the static (seed 000) and motion (seed 001)
//! fitters, the residual diagnosis, and the `palpate` command-line program's subcommands.

pub mod cli;
pub mod dataset;
pub mod diagnose;
pub mod export;
pub mod forward;
pub mod fsr;
pub mod io;
pub mod link;
pub mod mesh;
pub mod motion;
pub mod plot;
pub mod report;
pub mod specimen;
pub mod static_fit;

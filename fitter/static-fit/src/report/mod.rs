//! Human- and machine-readable reports of fits.

pub mod static_report;
mod words;
